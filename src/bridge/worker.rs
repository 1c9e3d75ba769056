//! The reference bridge worker (`reachgrasp bridge --sim`): connects out to the service, says
//! hello, runs forwarded executions on a [`SimRobot`] at a fixed control rate, streams
//! feedback, sends heartbeats, and reconnects with exponential backoff when the connection
//! drops (e.g. the service restarts). The library function [`run_worker`] is what the binary,
//! the tests and the benchmark all run.

use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tokio::sync::mpsc;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::{HeaderValue, StatusCode, header};
use tokio_tungstenite::tungstenite::{self, Message};

use super::protocol::{
    Capability, ErrorCode, ExecutionResult, Heartbeat, Hello, Outcome, PROTOCOL_VERSION,
    ServiceMessage, WorkerMessage,
};
use super::sim::{Perturbation, Run, RunOptions, SimLimits, SimRobot};
use crate::grasp::HandArm;

/// Configuration of a simulated worker.
#[derive(Debug, Clone)]
pub struct WorkerOptions {
    /// `ws://host:port/v1/bridges/connect`.
    pub url: String,
    pub token: String,
    pub name: String,
    pub robot: String,
    pub joint_names: Vec<String>,
    pub limits: SimLimits,
    /// Initial positions (default: [`SimLimits::home`]).
    pub initial: Option<Vec<f64>>,
    /// Control rate (Hz).
    pub rate_hz: f64,
    /// Feedback rate (Hz, at most the control rate).
    pub feedback_hz: f64,
    pub run: RunOptions,
    pub perturb: Option<Perturbation>,
    pub capabilities: Vec<Capability>,
    /// The robot's collision model, for the safety filter of closed-loop laws with a scene
    /// (the worker announces `safety_filter` when it has one).
    pub geometry: Option<std::sync::Arc<HandArm>>,
    /// First reconnection delay; doubles up to `backoff_max`.
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
}

impl WorkerOptions {
    /// Defaults for a robot: 100 Hz control, 50 Hz feedback, open and closed loop and
    /// streaming, backoff 0.2 s → 5 s.
    pub fn new(
        url: impl Into<String>,
        token: impl Into<String>,
        name: impl Into<String>,
        robot: impl Into<String>,
        joint_names: Vec<String>,
        limits: SimLimits,
    ) -> WorkerOptions {
        WorkerOptions {
            url: url.into(),
            token: token.into(),
            name: name.into(),
            robot: robot.into(),
            joint_names,
            limits,
            initial: None,
            rate_hz: 100.0,
            feedback_hz: 50.0,
            run: RunOptions::default(),
            perturb: None,
            capabilities: vec![
                Capability::OpenLoop,
                Capability::ClosedLoop,
                Capability::PathFollowing,
                Capability::Streaming,
            ],
            geometry: None,
            backoff_initial: Duration::from_millis(200),
            backoff_max: Duration::from_secs(5),
        }
    }

    /// From a loaded arm-hand system: its joint names, position and velocity limits, and a
    /// uniform acceleration limit (the descriptor has none).
    pub fn for_system(
        url: impl Into<String>,
        token: impl Into<String>,
        name: impl Into<String>,
        robot: impl Into<String>,
        system: &crate::kinematics::System,
        acceleration_limit: f64,
    ) -> WorkerOptions {
        let m = &system.model;
        let limits = SimLimits::new(
            m.lower_limits(),
            m.upper_limits(),
            m.velocity_limits(),
            acceleration_limit,
        );
        let mut opts =
            WorkerOptions::new(url, token, name, robot, m.joint_names().to_vec(), limits);
        // A system the grasp model cannot describe (no hand) still runs both modes, only not a
        // law with a scene.
        if let Ok(sys) = HandArm::from_system(system) {
            opts.geometry = Some(std::sync::Arc::new(sys));
            opts.capabilities.push(Capability::SafetyFilter);
        }
        opts
    }
}

/// The service's HTTP base for its bridge URL (`ws://host:port/v1/bridges/connect` →
/// `http://host:port`; `wss` → `https`).
pub fn http_base(url: &str) -> Option<String> {
    let (scheme, rest) = url.split_once("://")?;
    let scheme = match scheme {
        "ws" => "http",
        "wss" => "https",
        _ => return None,
    };
    let authority = rest.split('/').next().filter(|a| !a.is_empty())?;
    Some(format!("{scheme}://{authority}"))
}

/// Loads a robot registered with the service over its HTTP API (`GET /v1/robots/{id}` for the
/// descriptor, `GET /v1/robots/{id}/urdf` for the combined URDF): what a worker on another
/// machine than the service (a container on the lab network) needs. Meshes are not fetched:
/// a registered system whose collision geometry uses uploaded meshes fails to build here with
/// a message naming the mesh.
pub async fn fetch_system(
    bridge_url: &str,
    robot: &str,
) -> anyhow::Result<crate::kinematics::System> {
    use anyhow::Context;
    let base = http_base(bridge_url)
        .with_context(|| format!("cannot derive the service's HTTP address from {bridge_url}"))?;
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(30))
        .build()?;
    // The id as one percent-encoded path segment, whatever characters it has.
    let base = reqwest::Url::parse(&base)?;
    let url = |tail: Option<&str>| -> anyhow::Result<reqwest::Url> {
        let mut u = base.clone();
        u.path_segments_mut()
            .map_err(|()| anyhow::anyhow!("{base} cannot carry a path"))?
            .extend(["v1", "robots", robot])
            .extend(tail);
        Ok(u)
    };
    let detail: serde_json::Value = client
        .get(url(None)?)
        .send()
        .await?
        .error_for_status()
        .with_context(|| format!("robot '{robot}' is not registered with the service at {base}"))?
        .json()
        .await?;
    let urdf = client
        .get(url(Some("urdf"))?)
        .send()
        .await?
        .error_for_status()?
        .text()
        .await?;
    let desc: crate::kinematics::SystemDescriptor =
        serde_json::from_value(detail["descriptor"].clone())
            .context("the service's robot detail has no readable descriptor")?;
    Ok(crate::kinematics::System::from_sources(
        desc,
        crate::kinematics::UrdfSources::Combined(&urdf),
        &crate::kinematics::NoMeshes,
    )?)
}

/// What happens inside a worker (for tests and the benchmark).
#[derive(Debug, Clone, PartialEq)]
pub enum WorkerEvent {
    Connected,
    /// An `execute` arrived (the instant it was decoded).
    Execute {
        id: String,
        at: Instant,
    },
    /// An execution ended on this worker (`kicks`: perturbations applied during it).
    Finished {
        id: String,
        outcome: Outcome,
        kicks: u32,
    },
    Cancelled {
        id: String,
    },
    /// A streaming execution's setpoint was taken (the instant it was decoded).
    Setpoint {
        id: String,
        seq: u64,
        at: Instant,
    },
    /// A streaming execution ended by `end`, with what it received.
    StreamEnded {
        id: String,
        stats: super::sim::StreamStats,
    },
    /// The service sent an error.
    Error {
        code: ErrorCode,
        message: String,
    },
    Disconnected {
        reason: String,
    },
}

/// Why the worker stopped for good.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WorkerError {
    #[error("invalid service URL {url}: {reason}")]
    Url { url: String, reason: String },
    #[error("the service refused the token (HTTP {0})")]
    Unauthorized(u16),
    #[error("the service refused the hello: {0}")]
    Refused(String),
}

enum SessionEnd {
    /// Reconnect after a backoff.
    Retry(String),
    /// The session was welcomed and later lost: reconnect, backoff starts over.
    Lost(String),
    Fatal(WorkerError),
    Stop,
}

/// Runs the worker until `stop` resolves or a fatal refusal (bad token, joint names, protocol
/// version). Connection losses are retried with exponential backoff (with jitter).
pub async fn run_worker(
    opts: WorkerOptions,
    events: Option<mpsc::UnboundedSender<WorkerEvent>>,
    stop: impl std::future::Future<Output = ()>,
) -> Result<(), WorkerError> {
    let mut request = opts
        .url
        .as_str()
        .into_client_request()
        .map_err(|e| WorkerError::Url {
            url: opts.url.clone(),
            reason: e.to_string(),
        })?;
    let bearer =
        HeaderValue::from_str(&format!("Bearer {}", opts.token)).map_err(|e| WorkerError::Url {
            url: opts.url.clone(),
            reason: format!("token is not a valid header value: {e}"),
        })?;
    request.headers_mut().insert(header::AUTHORIZATION, bearer);
    let initial = opts.initial.clone().unwrap_or_else(|| opts.limits.home());
    let mut robot = SimRobot::new(opts.limits.clone(), initial);
    let mut jitter = ChaCha8Rng::seed_from_u64(opts.name.bytes().map(u64::from).sum());
    let mut delay = opts.backoff_initial;
    let emit = |e: WorkerEvent| {
        if let Some(tx) = &events {
            let _ = tx.send(e);
        }
    };
    tokio::pin!(stop);
    loop {
        let attempt = tokio::select! {
            // Nagle off: feedback and results are small frames that must not wait for ACKs.
            r = tokio_tungstenite::connect_async_with_config(request.clone(), None, true) => r,
            () = &mut stop => return Ok(()),
        };
        let end = match attempt {
            Ok((ws, _)) => {
                let end = session(ws, &opts, &mut robot, &emit, &mut stop).await;
                match end {
                    SessionEnd::Lost(reason) => {
                        emit(WorkerEvent::Disconnected {
                            reason: reason.clone(),
                        });
                        delay = opts.backoff_initial;
                        SessionEnd::Retry(reason)
                    }
                    other => other,
                }
            }
            Err(tungstenite::Error::Http(resp))
                if matches!(
                    resp.status(),
                    StatusCode::UNAUTHORIZED | StatusCode::FORBIDDEN
                ) =>
            {
                SessionEnd::Fatal(WorkerError::Unauthorized(resp.status().as_u16()))
            }
            Err(e) => SessionEnd::Retry(e.to_string()),
        };
        match end {
            SessionEnd::Stop => return Ok(()),
            SessionEnd::Fatal(e) => {
                tracing::error!(error = %e, "bridge worker stopping");
                return Err(e);
            }
            SessionEnd::Retry(reason) | SessionEnd::Lost(reason) => {
                let wait = delay.mul_f64(jitter.random_range(0.8..1.2));
                tracing::warn!(reason = %reason, retry_in_ms = wait.as_millis() as u64, "bridge connection lost");
                // The robot keeps braking while disconnected.
                let dt = 1.0 / opts.rate_hz;
                let until = Instant::now() + wait;
                while Instant::now() < until {
                    tokio::select! {
                        () = tokio::time::sleep(Duration::from_secs_f64(dt)) => robot.hold(dt),
                        () = &mut stop => return Ok(()),
                    }
                }
                delay = (delay * 2).min(opts.backoff_max);
            }
        }
    }
}

fn text(m: &WorkerMessage) -> Message {
    Message::Text(
        serde_json::to_string(m)
            .expect("worker messages serialise")
            .into(),
    )
}

async fn session<S>(
    ws: tokio_tungstenite::WebSocketStream<S>,
    opts: &WorkerOptions,
    robot: &mut SimRobot,
    emit: &impl Fn(WorkerEvent),
    stop: &mut std::pin::Pin<&mut impl std::future::Future<Output = ()>>,
) -> SessionEnd
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    let (mut sink, mut stream) = ws.split();
    let hello = WorkerMessage::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        worker: opts.name.clone(),
        robot: opts.robot.clone(),
        joint_names: opts.joint_names.clone(),
        capabilities: opts.capabilities.clone(),
        start_tolerance: Some(opts.run.start_tolerance),
    });
    if let Err(e) = sink.send(text(&hello)).await {
        return SessionEnd::Retry(e.to_string());
    }
    let welcome = match tokio::time::timeout(Duration::from_secs(10), stream.next()).await {
        Err(_) => return SessionEnd::Retry("no welcome within 10 s".into()),
        Ok(None) => return SessionEnd::Retry("closed before welcome".into()),
        Ok(Some(Err(e))) => return SessionEnd::Retry(e.to_string()),
        Ok(Some(Ok(Message::Text(t)))) => serde_json::from_str::<ServiceMessage>(t.as_str()),
        Ok(Some(Ok(_))) => return SessionEnd::Retry("unexpected frame before welcome".into()),
    };
    let heartbeat_every = match welcome {
        Ok(ServiceMessage::Welcome(w)) => Duration::from_millis(w.heartbeat_interval_ms.max(10)),
        Ok(ServiceMessage::Error(e)) => {
            emit(WorkerEvent::Error {
                code: e.code,
                message: e.message.clone(),
            });
            return match e.code {
                ErrorCode::NameInUse | ErrorCode::ShuttingDown => SessionEnd::Retry(e.message),
                _ => SessionEnd::Fatal(WorkerError::Refused(e.message)),
            };
        }
        Ok(other) => return SessionEnd::Retry(format!("unexpected {other:?} before welcome")),
        Err(e) => return SessionEnd::Retry(format!("unreadable welcome: {e}")),
    };
    tracing::info!(worker = %opts.name, url = %opts.url, "bridge worker connected");
    emit(WorkerEvent::Connected);

    let dt = 1.0 / opts.rate_hz;
    let mut control = tokio::time::interval(Duration::from_secs_f64(dt));
    // Missed ticks are skipped, not bunched: the simulation advances one period per tick.
    control.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut heartbeat = tokio::time::interval(heartbeat_every);
    heartbeat.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let feedback_every = ((opts.rate_hz / opts.feedback_hz.max(1e-3)).round() as u64).max(1);
    let mut ticks = 0u64;
    let mut seq = 0u64;
    let mut run: Option<Run> = None;
    let mut perturb_seed = opts.perturb.map(|p| p.seed).unwrap_or(0);

    loop {
        let mut outgoing: Vec<WorkerMessage> = Vec::new();
        tokio::select! {
            frame = stream.next() => match frame {
                None => return SessionEnd::Lost("connection closed".into()),
                Some(Err(e)) => return SessionEnd::Lost(e.to_string()),
                Some(Ok(Message::Close(f))) => {
                    return SessionEnd::Lost(format!("closed by the service: {}",
                        f.map(|f| f.reason.to_string()).unwrap_or_default()));
                }
                Some(Ok(Message::Text(t))) => match serde_json::from_str::<ServiceMessage>(t.as_str()) {
                    Ok(ServiceMessage::Execute(ex)) => {
                        emit(WorkerEvent::Execute { id: ex.execution_id.clone(), at: Instant::now() });
                        if run.is_some() {
                            outgoing.push(WorkerMessage::Result(ExecutionResult {
                                execution_id: ex.execution_id.clone(),
                                outcome: Outcome::Failed,
                                reason: Some("the worker is busy with another execution".into()),
                                positions: robot.q.clone(),
                                safety: None,
                                physics: None,
                            }));
                        } else {
                            // Each execution gets its own perturbation sequence.
                            let perturb = opts.perturb.map(|p| {
                                perturb_seed = perturb_seed.wrapping_add(1);
                                Perturbation { seed: perturb_seed, ..p }
                            });
                            match Run::new(&ex, &opts.joint_names, robot, opts.run, perturb, opts.geometry.as_deref()) {
                                Ok(r) => {
                                    tracing::info!(execution = %ex.execution_id, mode = ex.mode.as_str(), "executing");
                                    run = Some(r);
                                }
                                Err(reason) => {
                                    tracing::warn!(execution = %ex.execution_id, %reason, "execution refused");
                                    emit(WorkerEvent::Finished { id: ex.execution_id.clone(), outcome: Outcome::Failed, kicks: 0 });
                                    outgoing.push(WorkerMessage::Result(ExecutionResult {
                                        execution_id: ex.execution_id,
                                        outcome: Outcome::Failed,
                                        reason: Some(reason),
                                        positions: robot.q.clone(),
                                        safety: None,
                                        physics: None,
                                    }));
                                }
                            }
                        }
                    }
                    Ok(ServiceMessage::Cancel(c)) => {
                        if run.as_ref().is_some_and(|r| r.id == c.execution_id) {
                            let safety = run.take().and_then(|r| r.safety_report());
                            emit(WorkerEvent::Cancelled { id: c.execution_id.clone() });
                            outgoing.push(WorkerMessage::Result(ExecutionResult {
                                execution_id: c.execution_id,
                                outcome: Outcome::Aborted,
                                reason: Some("cancelled".into()),
                                positions: robot.q.clone(),
                                safety,
                                physics: None,
                            }));
                        }
                    }
                    Ok(ServiceMessage::Setpoint(sp)) => {
                        let at = Instant::now();
                        if let Some(r) = run.as_mut().filter(|r| r.id == sp.execution_id) {
                            match r.setpoint(&sp, robot) {
                                Ok(()) => emit(WorkerEvent::Setpoint { id: sp.execution_id, seq: sp.seq, at }),
                                Err(reason) => tracing::debug!(%reason, "setpoint refused"),
                            }
                        }
                    }
                    Ok(ServiceMessage::End(end)) => {
                        if run.as_ref().is_some_and(|r| r.id == end.execution_id) {
                            let r = run.take().expect("checked");
                            let stats = r.stream_stats().unwrap_or_default();
                            tracing::info!(execution = %r.id, received = stats.received, "stream ended");
                            emit(WorkerEvent::StreamEnded { id: r.id.clone(), stats });
                            outgoing.push(WorkerMessage::Feedback(r.feedback(robot)));
                            outgoing.push(WorkerMessage::Result(ExecutionResult {
                                execution_id: end.execution_id,
                                outcome: Outcome::Succeeded,
                                reason: None,
                                positions: robot.q.clone(),
                                safety: None,
                                physics: None,
                            }));
                        }
                    }
                    Ok(ServiceMessage::Error(e)) => {
                        tracing::warn!(code = ?e.code, message = %e.message, "service error");
                        emit(WorkerEvent::Error { code: e.code, message: e.message.clone() });
                    }
                    Ok(ServiceMessage::Welcome(_)) => {}
                    Err(e) => tracing::warn!(error = %e, "unreadable service message"),
                },
                Some(Ok(_)) => {}
            },
            _ = control.tick() => {
                ticks += 1;
                if let Some(r) = &mut run {
                    let done = r.tick(robot, dt);
                    if ticks.is_multiple_of(feedback_every) || done.is_some() {
                        outgoing.push(WorkerMessage::Feedback(r.feedback(robot)));
                    }
                    if let Some((outcome, reason)) = done {
                        emit(WorkerEvent::Finished { id: r.id.clone(), outcome, kicks: r.kicks() });
                        tracing::info!(execution = %r.id, ?outcome, "execution finished");
                        outgoing.push(WorkerMessage::Result(ExecutionResult {
                            execution_id: r.id.clone(),
                            outcome,
                            reason,
                            positions: robot.q.clone(),
                            safety: r.safety_report(),
                            physics: None,
                        }));
                        run = None;
                    }
                } else {
                    robot.hold(dt);
                }
            }
            _ = heartbeat.tick() => {
                seq += 1;
                outgoing.push(WorkerMessage::Heartbeat(Heartbeat { seq, positions: robot.q.clone() }));
            }
            () = stop.as_mut() => {
                let _ = sink.send(Message::Close(None)).await;
                return SessionEnd::Stop;
            }
        }
        for m in &outgoing {
            if let Err(e) = sink.send(text(m)).await {
                return SessionEnd::Lost(e.to_string());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::http_base;

    #[test]
    fn the_http_base_comes_from_the_bridge_url() {
        assert_eq!(
            http_base("ws://10.0.0.5:8080/v1/bridges/connect").as_deref(),
            Some("http://10.0.0.5:8080")
        );
        assert_eq!(
            http_base("wss://lab.example/v1/bridges/connect").as_deref(),
            Some("https://lab.example")
        );
        assert_eq!(http_base("http://x/v1"), None);
        assert_eq!(http_base("ws:///v1"), None);
    }
}
