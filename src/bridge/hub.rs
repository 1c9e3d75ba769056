//! The service side: connected workers (in memory), the dispatcher over the SQLite queue, and
//! one task per WebSocket connection.
//!
//! Ownership rules: the dispatcher task is the only one that moves an execution `queued` →
//! `running` (so an execution is never sent twice; a stream, [`Hub::open_stream`], is never
//! queued: it claims an idle worker under the state lock and is stored `running` at once), and a
//! worker holds at most one execution
//! (it drives one physical robot; executions for the same robot system run in parallel on
//! different workers). Everything else (feedback, results, cancellation, disconnects) is
//! handled on the connection's own task; one misbehaving connection never blocks the others
//! (sends to a worker are `try_send` on a bounded channel, locks are never held across `.await`).

use std::collections::HashMap;
use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, WebSocket};
use futures::{Sink, SinkExt, Stream, StreamExt};
use serde::{Deserialize, Serialize};
use sqlx::SqlitePool;
use subtle::ConstantTimeEq;
use tokio::sync::{Notify, mpsc, watch};
use utoipa::ToSchema;

use super::protocol::{
    Capability, DEFAULT_START_TOLERANCE, ErrorCode, ErrorReply, Execute, ExecutionPayload,
    ExecutionResult, Feedback, Hello, Mode, Outcome, PROTOCOL_VERSION, PhysicsSummary,
    PhysicsTrial, ServiceMessage, Welcome, WorkerMessage, decode_worker_message,
};
use super::{BridgeError, WorkerName};
use crate::shutdown::Shutdown;
use crate::store::executions::{self as repo, ExecutionState};
use crate::store::feedback::{Chunk, History, Recorder};
use crate::store::library::{LibraryError, RobotLibrary};

/// Feedback, tracking and the new part of the feedback history are written to SQLite at most
/// this often per execution (the live view in memory is always current).
const FLUSH_EVERY: Duration = Duration::from_millis(250);
/// Bad frames tolerated on one connection before it is closed.
const MAX_ERRORS: u32 = 20;
/// A new connection must say `hello` within this time.
const HELLO_TIMEOUT: Duration = Duration::from_secs(10);
/// Outgoing frames queued per connection (a worker that stops reading is disconnected when full).
const OUTBOX: usize = 64;

/// Bridge settings resolved at start.
#[derive(Clone)]
pub struct HubSettings {
    /// The token workers present as `Authorization: Bearer <token>`.
    pub token: String,
    pub heartbeat_interval: Duration,
    pub heartbeat_timeout: Duration,
    /// Queued executions with no compatible worker connected fail after this long (None: never).
    pub queue_timeout: Option<Duration>,
}

/// Running-error statistics of an execution's feedback.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TrackingSummary {
    /// Feedback messages received.
    pub samples: u64,
    /// Largest reported tracking error.
    pub max_error: f64,
    /// Root mean square of the reported tracking errors.
    pub rms_error: f64,
    /// The latest reported tracking error.
    pub last_error: f64,
    /// Sum of squared errors (keeps `rms_error` exact across flushes).
    pub sum_squared: f64,
    /// The worker's safety filter report (a closed-loop law with a scene).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety: Option<super::protocol::SafetyReport>,
    /// What a physics worker measured (its simulator and the grasp trial).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub physics: Option<super::protocol::PhysicsSummary>,
}

impl TrackingSummary {
    fn add(&mut self, e: f64) {
        self.samples += 1;
        self.max_error = self.max_error.max(e);
        self.last_error = e;
        self.sum_squared += e * e;
        self.rms_error = (self.sum_squared / self.samples as f64).sqrt();
    }
}

/// A connected worker as `GET /v1/bridges` shows it.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct WorkerSnapshot {
    pub name: String,
    pub robot: String,
    pub joint_names: Vec<String>,
    pub capabilities: Vec<Capability>,
    pub connected_at: String,
    pub last_heartbeat_at: Option<String>,
    /// The execution it runs (None: idle).
    pub execution_id: Option<String>,
    /// Heartbeats received on this connection.
    pub heartbeats: u64,
    /// Longest time between two consecutive heartbeats on this connection (ms).
    pub max_heartbeat_gap_ms: f64,
    /// Frames received on this connection.
    pub messages: u64,
    /// Last measured positions (from heartbeats and feedback), joint order of `joint_names`.
    pub positions: Vec<f64>,
    /// The start tolerance the worker announced (rad; `None`: it named none, and
    /// [`DEFAULT_START_TOLERANCE`] applies).
    pub start_tolerance: Option<f64>,
}

impl WorkerSnapshot {
    /// Whether the worker announced capability `c`.
    pub fn can(&self, c: Capability) -> bool {
        self.capabilities.contains(&c)
    }

    /// The start tolerance that applies to this worker (rad).
    pub fn tolerance(&self) -> f64 {
        self.start_tolerance.unwrap_or(DEFAULT_START_TOLERANCE)
    }
}

/// A claimed worker: its connection, name and outbox.
type Claimed = (u64, String, mpsc::Sender<ServiceMessage>);

struct Worker {
    snapshot: WorkerSnapshot,
    last_heartbeat: Option<Instant>,
    tx: mpsc::Sender<ServiceMessage>,
}

struct Live {
    conn: u64,
    n_joints: usize,
    feedback: Option<Feedback>,
    tracking: TrackingSummary,
    /// The decimated, bounded measured state history (`store::feedback`).
    history: Recorder,
    last_flush: Instant,
    cancel_requested: bool,
}

#[derive(Default)]
struct State {
    workers: HashMap<u64, Worker>,
    live: HashMap<String, Live>,
    watchers: HashMap<String, watch::Sender<u64>>,
}

struct Inner {
    db: SqlitePool,
    robots: RobotLibrary,
    settings: HubSettings,
    state: Mutex<State>,
    wake: Notify,
    next_conn: AtomicU64,
}

/// The bridge hub (cheap to clone; lives in the service context).
#[derive(Clone)]
pub struct Hub(Arc<Inner>);

impl fmt::Debug for Hub {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Hub").finish_non_exhaustive()
    }
}

/// Constant-time comparison, so the token cannot be guessed byte by byte from response times
/// (only its length can leak, and that is not secret).
fn same_token(a: &str, b: &str) -> bool {
    a.as_bytes().ct_eq(b.as_bytes()).into()
}

fn error(code: ErrorCode, message: impl Into<String>, fatal: bool) -> ErrorReply {
    ErrorReply {
        code,
        message: message.into(),
        fatal,
        execution_id: None,
    }
}

impl Hub {
    pub fn new(db: SqlitePool, robots: RobotLibrary, settings: HubSettings) -> Hub {
        Hub(Arc::new(Inner {
            db,
            robots,
            settings,
            state: Mutex::new(State::default()),
            wake: Notify::new(),
            next_conn: AtomicU64::new(1),
        }))
    }

    pub fn settings(&self) -> &HubSettings {
        &self.0.settings
    }

    /// Whether an `Authorization` header value carries the configured token.
    pub fn authorized(&self, authorization: Option<&str>) -> bool {
        authorization
            .and_then(|v| v.strip_prefix("Bearer "))
            .is_some_and(|t| same_token(t.trim(), &self.0.settings.token))
    }

    pub(super) fn robots(&self) -> &RobotLibrary {
        &self.0.robots
    }

    /// Waits until execution `id` is in a final state and returns it. Woken by the execution's
    /// watcher; the periodic re-read only guards against a missed wake-up.
    pub async fn wait_final(&self, id: &str) -> Result<super::client::Finished, BridgeError> {
        let mut changes = self.subscribe(id);
        loop {
            let row = repo::get(&self.0.db, id)
                .await?
                .ok_or_else(|| BridgeError::UnknownExecution(id.to_owned()))?;
            if row.state.is_final() {
                return Ok(super::client::Finished {
                    state: row.state,
                    reason: row.reason,
                });
            }
            tokio::select! {
                changed = changes.changed() => {
                    if changed.is_err() {
                        // The final notification dropped the watcher; subscribe again in case
                        // the execution is live once more (requeued).
                        changes = self.subscribe(id);
                    }
                }
                () = tokio::time::sleep(Duration::from_secs(1)) => {}
            }
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // A panic while holding the lock leaves plain data behind; keep serving.
        self.0.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Wakes the dispatcher (a new execution, a free worker).
    pub fn wake(&self) {
        self.0.wake.notify_one();
    }

    /// Connected workers, by name.
    pub fn workers(&self) -> Vec<WorkerSnapshot> {
        let mut v: Vec<_> = self
            .lock()
            .workers
            .values()
            .map(|w| w.snapshot.clone())
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }

    /// The live feedback, tracking and kept history sample count of a running execution.
    pub fn live(&self, id: &str) -> Option<(Option<Feedback>, TrackingSummary, usize)> {
        self.lock()
            .live
            .get(id)
            .map(|l| (l.feedback.clone(), l.tracking.clone(), l.history.len()))
    }

    /// The measured state history of a running execution, including what is not flushed yet.
    pub fn history(&self, id: &str) -> Option<History> {
        self.lock().live.get(id).map(|l| l.history.history())
    }

    /// A receiver that changes whenever the execution's state or feedback does.
    pub fn subscribe(&self, id: &str) -> watch::Receiver<u64> {
        let mut s = self.lock();
        s.watchers
            .entry(id.to_owned())
            .or_insert_with(|| watch::channel(0).0)
            .subscribe()
    }

    fn touch(state: &mut State, id: &str, last: bool) {
        if last {
            if let Some(tx) = state.watchers.remove(id) {
                tx.send_modify(|v| *v += 1);
            }
        } else if let Some(tx) = state.watchers.get(id) {
            tx.send_modify(|v| *v += 1);
        }
    }

    fn notify_final(&self, id: &str) {
        Self::touch(&mut self.lock(), id, true);
    }

    // ------------------------------------------------------------------ queue and dispatch

    /// Checks a payload against the robot (see [`super::validate_payload`]), queues it and
    /// wakes the dispatcher; returns the execution id.
    pub async fn enqueue(
        &self,
        robot: &str,
        mode: Mode,
        payload: ExecutionPayload,
        worker: Option<WorkerName>,
    ) -> Result<String, BridgeError> {
        self.check(robot, mode, &payload).await?;
        let worker = worker.as_ref().map(WorkerName::as_str);
        let row = repo::insert(&self.0.db, robot, mode, &payload, worker).await?;
        self.wake();
        Ok(row.id)
    }

    /// [`super::validate_payload`] against the robot's system from the library.
    pub async fn check(
        &self,
        robot: &str,
        mode: Mode,
        payload: &ExecutionPayload,
    ) -> Result<(), BridgeError> {
        let system = self.0.robots.system(robot).await?;
        super::validate_payload(payload, mode, &system, robot)
    }

    /// Queues an execution already checked with [`Hub::check`] inside the caller's
    /// transaction (with a grasp trial in physics after the motion, if `trial`); the caller
    /// calls [`Hub::wake`] once it has committed.
    pub async fn insert_in(
        conn: &mut sqlx::SqliteConnection,
        robot: &str,
        mode: Mode,
        payload: &ExecutionPayload,
        worker: Option<&WorkerName>,
        trial: Option<&PhysicsTrial>,
    ) -> Result<String, BridgeError> {
        let worker = worker.map(WorkerName::as_str);
        Ok(repo::insert_in(conn, robot, mode, payload, worker, trial)
            .await?
            .id)
    }

    /// Starts the dispatcher task; it stops at shutdown.
    pub fn spawn_dispatcher(&self, shutdown: Shutdown) {
        let hub = self.clone();
        tokio::spawn(async move {
            loop {
                if let Err(e) = hub.dispatch().await {
                    tracing::error!(error = %e, "bridge dispatch failed");
                }
                tokio::select! {
                    () = hub.0.wake.notified() => {}
                    // Also runs periodically for the queue timeout.
                    () = tokio::time::sleep(Duration::from_secs(1)) => {}
                    () = shutdown.wait() => break,
                }
            }
        });
    }

    /// One pass over the queue: each queued execution goes to an idle compatible worker, or
    /// fails when it waited longer than the queue timeout with no compatible worker connected.
    async fn dispatch(&self) -> Result<(), sqlx::Error> {
        let queued = repo::queued(&self.0.db).await?;
        if queued.is_empty() {
            return Ok(());
        }
        let deadline = self.0.settings.queue_timeout.map(|t| {
            crate::store::format_timestamp(
                time::OffsetDateTime::now_utc()
                    - time::Duration::try_from(t).unwrap_or(time::Duration::ZERO),
            )
        });
        for row in queued {
            let cap = match row.mode {
                Mode::OpenLoop => Capability::OpenLoop,
                Mode::ClosedLoop => Capability::ClosedLoop,
                // Streams start on a claimed worker (`open_stream`) and are never queued.
                Mode::Streaming => continue,
            };
            // A law with a scene runs only where the worker filters it (an unfiltered law
            // could drive the arm into what the plan avoided). Only a closed-loop payload can
            // carry a scene, so only that one is read before a worker is picked; a queued
            // trajectory's points are read once it has a worker.
            let early = match row.mode {
                Mode::ClosedLoop => match repo::payload(&self.0.db, &row.id).await? {
                    Some(p) => Some(p),
                    None => continue,
                },
                Mode::OpenLoop | Mode::Streaming => None,
            };
            let filtered = early.as_ref().is_some_and(|p| p.safety().is_some());
            // A law with a path runs only where the worker follows it: a worker that ran the
            // bare law instead would drive another motion than the plan's.
            let follows = early.as_ref().is_some_and(|p| p.law_path().is_some());
            // A grasp trial needs a physics worker: a kinematic one would report the motion
            // as done and say nothing of the grasp.
            let physics = row.grasp_trial;
            let compatible = |w: &Worker| {
                let can = |c| w.snapshot.can(c);
                w.snapshot.robot == row.robot
                    && can(cap)
                    && (!filtered || can(Capability::SafetyFilter))
                    && (!follows || can(Capability::PathFollowing))
                    && (!physics || can(Capability::GraspTrial))
                    && row.worker.as_ref().is_none_or(|n| *n == w.snapshot.name)
            };
            let (pick, any) = self.claim(&row.id, compatible);
            let Some((conn, name, tx)) = pick else {
                if !any
                    && let Some(d) = &deadline
                    && row.created_at < *d
                {
                    let secs = self.0.settings.queue_timeout.unwrap_or_default().as_secs();
                    // What the execution needs beyond its mode, and why.
                    let needs: Vec<&str> = [
                        (
                            filtered,
                            "safety_filter (this closed-loop law runs in a scene)",
                        ),
                        (
                            follows,
                            "path_following (this closed-loop law runs the plan's path)",
                        ),
                        (
                            physics,
                            "grasp_trial (a physics worker: this execution ends in a grasp \
                             trial)",
                        ),
                    ]
                    .into_iter()
                    .filter_map(|(needed, what)| needed.then_some(what))
                    .collect();
                    let reason = format!(
                        "no worker: no compatible worker for robot '{}'{}{} connected within \
                         {secs} s",
                        row.robot,
                        row.worker
                            .as_ref()
                            .map(|w| format!(" named '{w}'"))
                            .unwrap_or_default(),
                        if needs.is_empty() {
                            String::new()
                        } else {
                            format!(" with the capabilities {}", needs.join(" and "))
                        }
                    );
                    if repo::finish(
                        &self.0.db,
                        &row.id,
                        ExecutionState::Failed,
                        Some(&reason),
                        None,
                        None,
                        None,
                    )
                    .await?
                    {
                        tracing::info!(execution = %row.id, "execution failed: no worker");
                        self.notify_final(&row.id);
                    }
                }
                continue;
            };
            let release = |hub: &Hub| hub.release(conn, &row.id);
            let payload = match early {
                Some(p) => p,
                None => match repo::payload(&self.0.db, &row.id).await {
                    Ok(Some(p)) => p,
                    Ok(None) => {
                        release(self);
                        continue;
                    }
                    Err(e) => {
                        release(self);
                        return Err(e);
                    }
                },
            };
            let trial = if physics {
                match repo::trial(&self.0.db, &row.id).await {
                    Ok(t) => t,
                    Err(e) => {
                        release(self);
                        return Err(e);
                    }
                }
            } else {
                None
            };
            let (scene, trial, idle_fingers) = match trial {
                Some(t) => (Some(Box::new(t.scene)), Some(t.trial), t.idle_fingers),
                None => (None, None, Vec::new()),
            };
            if !repo::mark_running(&self.0.db, &row.id, &name).await? {
                release(self); // cancelled meanwhile
                continue;
            }
            {
                let mut s = self.lock();
                s.live.insert(
                    row.id.clone(),
                    Live {
                        conn,
                        n_joints: payload.joint_names().len(),
                        feedback: None,
                        tracking: TrackingSummary::default(),
                        history: Recorder::new(payload.joint_names().len()),
                        last_flush: Instant::now(),
                        cancel_requested: false,
                    },
                );
                Self::touch(&mut s, &row.id, false);
            }
            let msg = ServiceMessage::Execute(Execute {
                execution_id: row.id.clone(),
                mode: row.mode,
                payload,
                scene,
                trial,
                idle_fingers,
            });
            if tx.try_send(msg).is_err() {
                // The connection is closing or not reading: put the execution back.
                release(self);
                repo::requeue(&self.0.db, &row.id).await?;
                continue;
            }
            tracing::info!(execution = %row.id, worker = %name, "execution dispatched");
        }
        Ok(())
    }

    /// Starts a streaming execution (`payload`: a `stream`) on an idle connected worker of
    /// `robot` with the `streaming` capability (the one named, if any): claims the worker,
    /// stores the execution as `running` and sends `execute`. The returned handle sends the
    /// setpoints and ends the stream. A stream is never queued: a teleoperator needs the robot
    /// now or a clear refusal ([`BridgeError::NoWorker`]).
    pub async fn open_stream(
        &self,
        robot: &str,
        worker: Option<&WorkerName>,
        payload: ExecutionPayload,
    ) -> Result<StreamHandle, BridgeError> {
        self.check(robot, Mode::Streaming, &payload).await?;
        let id = uuid::Uuid::new_v4().to_string();
        let (pick, any) = self.claim(&id, |w: &Worker| {
            w.snapshot.robot == robot
                && w.snapshot.can(Capability::Streaming)
                && worker.is_none_or(|n| n.as_str() == w.snapshot.name)
        });
        let (conn, name, tx) = pick.ok_or(any).map_err(|any| {
            let which = worker.map_or_else(String::new, |n| format!(" named '{n}'"));
            BridgeError::NoWorker(if any {
                format!(
                    "every connected worker{which} of robot '{robot}' with the streaming \
                     capability is busy; retry when one is idle (GET /v1/bridges)"
                )
            } else {
                format!(
                    "no worker{which} of robot '{robot}' with the streaming capability is \
                     connected (GET /v1/bridges lists the connected workers and what they can do)"
                )
            })
        })?;
        let release = |hub: &Hub| hub.release(conn, &id);
        if let Err(e) = repo::insert_running(&self.0.db, &id, robot, &payload, &name).await {
            release(self);
            return Err(e.into());
        }
        let n = payload.joint_names().len();
        {
            let mut s = self.lock();
            s.live.insert(
                id.clone(),
                Live {
                    conn,
                    n_joints: n,
                    feedback: None,
                    tracking: TrackingSummary::default(),
                    history: Recorder::new(n),
                    last_flush: Instant::now(),
                    cancel_requested: false,
                },
            );
            Self::touch(&mut s, &id, false);
        }
        let msg = ServiceMessage::Execute(Execute {
            execution_id: id.clone(),
            mode: Mode::Streaming,
            payload,
            scene: None,
            trial: None,
            idle_fingers: Vec::new(),
        });
        if tx.try_send(msg).is_err() {
            release(self);
            let why = format!("worker '{name}' is not reading its connection");
            repo::finish(
                &self.0.db,
                &id,
                ExecutionState::Failed,
                Some(&why),
                None,
                None,
                None,
            )
            .await?;
            self.notify_final(&id);
            return Err(BridgeError::NoWorker(why));
        }
        tracing::info!(execution = %id, worker = %name, "stream started");
        Ok(StreamHandle {
            hub: self.clone(),
            id,
            conn,
            worker: name,
            tx,
            seq: 0,
            last: None,
            sent: 0,
            skipped: 0,
            ended: false,
        })
    }

    /// Claims for execution `id` the idle worker `fits` accepts with the lowest connection
    /// number: its connection, name and outbox; and whether any connected worker fits at all.
    fn claim(&self, id: &str, fits: impl Fn(&Worker) -> bool) -> (Option<Claimed>, bool) {
        let mut s = self.lock();
        let any = s.workers.values().any(&fits);
        let pick = s
            .workers
            .iter_mut()
            .filter(|(_, w)| w.snapshot.execution_id.is_none() && fits(w))
            .min_by_key(|(c, _)| **c)
            .map(|(c, w)| {
                w.snapshot.execution_id = Some(id.to_owned());
                (*c, w.snapshot.name.clone(), w.tx.clone())
            });
        (pick, any)
    }

    /// Undoes a claim: forgets the execution's live state and frees worker `conn` if it still
    /// holds `id`.
    fn release(&self, conn: u64, id: &str) {
        let mut s = self.lock();
        s.live.remove(id);
        if let Some(w) = s.workers.get_mut(&conn)
            && w.snapshot.execution_id.as_deref() == Some(id)
        {
            w.snapshot.execution_id = None;
        }
    }

    /// Cancels a live execution: a queued one at once, a running one by asking its worker
    /// (it becomes `cancelled` when the worker confirms). Errors: unknown id, already final.
    pub async fn cancel(&self, id: &str) -> Result<(), BridgeError> {
        let row = repo::get(&self.0.db, id)
            .await?
            .ok_or_else(|| BridgeError::UnknownExecution(id.to_owned()))?;
        if row.state.is_final() {
            return Err(BridgeError::AlreadyFinished {
                id: id.to_owned(),
                state: row.state,
            });
        }
        if row.state == ExecutionState::Queued
            && repo::finish(
                &self.0.db,
                id,
                ExecutionState::Cancelled,
                Some("cancelled before it was dispatched"),
                None,
                None,
                None,
            )
            .await?
        {
            self.notify_final(id);
            return Ok(());
        }
        repo::set_cancel_requested(&self.0.db, id).await?;
        let tx = {
            let mut s = self.lock();
            let conn = s.live.get_mut(id).map(|l| {
                l.cancel_requested = true;
                l.conn
            });
            conn.and_then(|c| s.workers.get(&c).map(|w| w.tx.clone()))
        };
        if let Some(tx) = tx {
            // Full outbox: the worker is not reading and will be dropped by its heartbeat check.
            let _ = tx.try_send(ServiceMessage::Cancel(super::protocol::Cancel {
                execution_id: id.to_owned(),
            }));
        }
        Ok(())
    }

    // ------------------------------------------------------------------ connections

    /// Checks a hello against the robot library; returns the refusal to send otherwise.
    async fn check_hello(&self, hello: &Hello) -> Result<(), ErrorReply> {
        if hello.protocol_version != PROTOCOL_VERSION {
            return Err(error(
                ErrorCode::UnsupportedVersion,
                format!(
                    "protocol version {} is not supported; this service speaks {PROTOCOL_VERSION}",
                    hello.protocol_version
                ),
                true,
            ));
        }
        let refuse = |m: String| Err(error(ErrorCode::HelloRefused, m, true));
        if WorkerName::parse(&hello.worker).is_err() {
            return refuse(format!(
                "worker name '{}' must be 1-64 letters, digits, '-', '_' or '.'",
                hello.worker
            ));
        }
        if hello.capabilities.is_empty() {
            return refuse("capabilities must not be empty (open_loop, closed_loop)".into());
        }
        if let Some(t) = hello.start_tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return refuse(format!(
                "start_tolerance must be a positive joint distance in rad, got {t}"
            ));
        }
        let system = match self.0.robots.system(&hello.robot).await {
            Ok(s) => s,
            Err(e @ LibraryError::UnknownRobot(_)) => return refuse(e.to_string()),
            Err(LibraryError::Store(e)) => {
                tracing::error!(error = %e, "cannot read robots");
                return Err(error(ErrorCode::HelloRefused, "database unavailable", true));
            }
            Err(e) => {
                tracing::error!(error = %e, "cannot load a robot for a worker");
                return refuse(format!("robot '{}' cannot be loaded", hello.robot));
            }
        };
        let expected = system.model.joint_names();
        if hello.joint_names != expected {
            let detail = match expected
                .iter()
                .zip(&hello.joint_names)
                .position(|(a, b)| a != b)
            {
                Some(i) => format!(
                    "joint_names[{i}] is '{}', robot '{}' has '{}' there",
                    hello.joint_names[i], hello.robot, expected[i]
                ),
                None => format!(
                    "{} joint names given, robot '{}' has {}",
                    hello.joint_names.len(),
                    hello.robot,
                    expected.len()
                ),
            };
            return refuse(format!(
                "joint names do not match the robot: {detail} (expected {expected:?})"
            ));
        }
        Ok(())
    }

    fn register(&self, hello: &Hello, tx: mpsc::Sender<ServiceMessage>) -> Result<u64, ErrorReply> {
        let mut s = self.lock();
        if s.workers.values().any(|w| w.snapshot.name == hello.worker) {
            return Err(error(
                ErrorCode::NameInUse,
                format!("a worker named '{}' is already connected", hello.worker),
                true,
            ));
        }
        let conn = self.0.next_conn.fetch_add(1, Ordering::Relaxed);
        s.workers.insert(
            conn,
            Worker {
                snapshot: WorkerSnapshot {
                    name: hello.worker.clone(),
                    robot: hello.robot.clone(),
                    joint_names: hello.joint_names.clone(),
                    capabilities: hello.capabilities.clone(),
                    connected_at: crate::store::now(),
                    last_heartbeat_at: None,
                    execution_id: None,
                    heartbeats: 0,
                    max_heartbeat_gap_ms: 0.0,
                    messages: 1,
                    positions: Vec::new(),
                    start_tolerance: hello.start_tolerance,
                },
                last_heartbeat: None,
                tx,
            },
        );
        Ok(conn)
    }

    /// Removes a connection; its execution (if any) becomes `interrupted` with its last feedback.
    async fn disconnect(&self, conn: u64, why: &str) {
        let (name, held) = {
            let mut s = self.lock();
            let Some(w) = s.workers.remove(&conn) else {
                return;
            };
            let held = w
                .snapshot
                .execution_id
                .as_ref()
                .and_then(|id| s.live.remove(id).map(|l| (id.clone(), l)));
            (w.snapshot.name, held)
        };
        tracing::info!(worker = %name, reason = why, "bridge worker disconnected");
        if let Some((id, mut live)) = held {
            live.history.close();
            let history = live.history.pending();
            let fb = live
                .feedback
                .as_ref()
                .and_then(|f| serde_json::to_string(f).ok());
            let tr = serde_json::to_string(&live.tracking).ok();
            let reason = format!("worker '{name}' disconnected mid-execution: {why}");
            match repo::finish(
                &self.0.db,
                &id,
                ExecutionState::Interrupted,
                Some(&reason),
                fb.as_deref(),
                tr.as_deref(),
                history.as_ref(),
            )
            .await
            {
                Ok(_) => tracing::warn!(execution = %id, "execution interrupted"),
                Err(e) => {
                    tracing::error!(execution = %id, error = %e, "cannot record an interrupted execution")
                }
            }
            self.notify_final(&id);
        }
        if let Err(e) = repo::touch_bridge(&self.0.db, &name).await {
            tracing::warn!(error = %e, "cannot record the worker's last contact");
        }
        self.wake();
    }

    fn on_heartbeat(&self, conn: u64, positions: Vec<f64>) {
        let mut s = self.lock();
        if let Some(w) = s.workers.get_mut(&conn) {
            let now = Instant::now();
            if let Some(prev) = w.last_heartbeat {
                let gap = now.duration_since(prev).as_secs_f64() * 1e3;
                w.snapshot.max_heartbeat_gap_ms = w.snapshot.max_heartbeat_gap_ms.max(gap);
            }
            w.last_heartbeat = Some(now);
            w.snapshot.heartbeats += 1;
            w.snapshot.last_heartbeat_at = Some(crate::store::now());
            if positions.len() == w.snapshot.joint_names.len()
                && positions.iter().all(|x| x.is_finite())
            {
                w.snapshot.positions = positions;
            }
        }
    }

    fn holding_error(id: &str) -> ErrorReply {
        ErrorReply {
            code: ErrorCode::NotHolding,
            message: format!("this worker does not hold execution {id}"),
            fatal: false,
            execution_id: Some(id.to_owned()),
        }
    }

    async fn on_feedback(&self, conn: u64, fb: Feedback) -> Result<(), ErrorReply> {
        let flush = {
            let mut s = self.lock();
            let s = &mut *s;
            let Some(w) = s.workers.get_mut(&conn) else {
                return Ok(());
            };
            if w.snapshot.execution_id.as_deref() != Some(fb.execution_id.as_str()) {
                return Err(Self::holding_error(&fb.execution_id));
            }
            let Some(live) = s.live.get_mut(&fb.execution_id) else {
                return Err(Self::holding_error(&fb.execution_id));
            };
            let ok = fb.positions.len() == live.n_joints
                && fb.velocities.len() == live.n_joints
                && fb
                    .positions
                    .iter()
                    .chain(&fb.velocities)
                    .chain([&fb.t, &fb.progress, &fb.tracking_error])
                    .all(|x| x.is_finite())
                && fb.tracking_error >= 0.0;
            if !ok {
                return Err(ErrorReply {
                    code: ErrorCode::Malformed,
                    message: format!(
                        "feedback needs {} finite positions and velocities and finite t, progress, \
                         tracking_error >= 0",
                        live.n_joints
                    ),
                    fatal: false,
                    execution_id: Some(fb.execution_id.clone()),
                });
            }
            w.snapshot.positions.clone_from(&fb.positions);
            live.tracking.add(fb.tracking_error);
            live.history.record(
                fb.t,
                fb.progress,
                fb.tracking_error,
                &fb.positions,
                &fb.velocities,
            );
            let id = fb.execution_id.clone();
            live.feedback = Some(fb);
            let flush = (live.last_flush.elapsed() >= FLUSH_EVERY).then(|| {
                live.last_flush = Instant::now();
                (
                    id.clone(),
                    serde_json::to_string(&live.feedback).unwrap_or_default(),
                    serde_json::to_string(&live.tracking).unwrap_or_default(),
                    live.history.pending(),
                )
            });
            Self::touch(s, &id, false);
            flush
        };
        if let Some((id, fb, tr, chunk)) = flush {
            match repo::save_progress(&self.0.db, &id, &fb, &tr, chunk.as_ref()).await {
                Ok(true) => self.stored(&id, chunk.as_ref()),
                Ok(false) => {}
                // The chunk stays pending: the next flush (or the final one) writes it.
                Err(e) => tracing::warn!(execution = %id, error = %e, "cannot store feedback"),
            }
        }
        Ok(())
    }

    /// A flushed history chunk is in the database; later flushes write only what follows it.
    fn stored(&self, id: &str, chunk: Option<&Chunk>) {
        if let Some(c) = chunk
            && let Some(live) = self.lock().live.get_mut(id)
        {
            live.history.stored(c);
        }
    }

    async fn on_result(&self, conn: u64, r: ExecutionResult) -> Result<(), ErrorReply> {
        let mut live = {
            let mut s = self.lock();
            let Some(w) = s.workers.get_mut(&conn) else {
                return Ok(());
            };
            if w.snapshot.execution_id.as_deref() != Some(r.execution_id.as_str()) {
                return Err(Self::holding_error(&r.execution_id));
            }
            w.snapshot.execution_id = None;
            if r.positions.len() == w.snapshot.joint_names.len() {
                w.snapshot.positions.clone_from(&r.positions);
            }
            s.live.remove(&r.execution_id)
        };
        let history = live.as_mut().and_then(|l| {
            l.history.close();
            l.history.pending()
        });
        let cancel_requested = live.as_ref().is_some_and(|l| l.cancel_requested);
        let state = match r.outcome {
            Outcome::Succeeded => ExecutionState::Succeeded,
            Outcome::Failed => ExecutionState::Failed,
            Outcome::Aborted if cancel_requested => ExecutionState::Cancelled,
            Outcome::Aborted => ExecutionState::Aborted,
        };
        let fb = live
            .as_ref()
            .and_then(|l| l.feedback.as_ref())
            .and_then(|f| serde_json::to_string(f).ok());
        if let Some(l) = live.as_mut() {
            l.tracking.safety = r.safety.clone();
            l.tracking.physics = r.physics.as_ref().and_then(PhysicsSummary::read);
        }
        let tr = live
            .as_ref()
            .and_then(|l| serde_json::to_string(&l.tracking).ok());
        let reason = r.reason.as_deref().filter(|s| !s.is_empty());
        match repo::finish(
            &self.0.db,
            &r.execution_id,
            state,
            reason,
            fb.as_deref(),
            tr.as_deref(),
            history.as_ref(),
        )
        .await
        {
            Ok(_) => tracing::info!(execution = %r.execution_id, %state, "execution finished"),
            Err(e) => {
                tracing::error!(execution = %r.execution_id, error = %e, "cannot record a result")
            }
        }
        self.notify_final(&r.execution_id);
        self.wake();
        Ok(())
    }

    /// Serves one authenticated WebSocket connection until it closes.
    pub async fn serve(self, shutdown: Shutdown, socket: WebSocket) {
        let (sink, stream) = socket.split();
        self.serve_session(shutdown, sink, stream).await;
    }

    /// The session over any frame sink and stream (a WebSocket in service, channels in tests):
    /// handshake, then frames until either side ends it, then the worker is removed.
    pub async fn serve_session<Si, St, E>(self, shutdown: Shutdown, mut sink: Si, mut stream: St)
    where
        Si: Sink<Message> + Unpin,
        St: Stream<Item = Result<Message, E>> + Unpin,
        E: fmt::Display,
    {
        let Some((hello, conn, rx)) = self.handshake(&mut sink, &mut stream).await else {
            return;
        };
        let why = self
            .session(&shutdown, &hello, conn, rx, &mut sink, &mut stream)
            .await;
        self.disconnect(conn, &why).await;
    }

    /// Reads `hello`, admits the worker and answers `welcome`; on refusal sends the error,
    /// closes and returns None.
    async fn handshake<Si, St, E>(
        &self,
        sink: &mut Si,
        stream: &mut St,
    ) -> Option<(Hello, u64, mpsc::Receiver<ServiceMessage>)>
    where
        Si: Sink<Message> + Unpin,
        St: Stream<Item = Result<Message, E>> + Unpin,
    {
        let hello = match read_hello(stream).await? {
            Ok(h) => h,
            Err(e) => {
                refuse(sink, &e).await;
                return None;
            }
        };
        let (tx, rx) = mpsc::channel(OUTBOX);
        let admitted = match self.check_hello(&hello).await {
            Ok(()) => self.register(&hello, tx),
            Err(e) => Err(e),
        };
        let conn = match admitted {
            Ok(c) => c,
            Err(e) => {
                tracing::info!(worker = %hello.worker, reason = %e.message, "bridge hello refused");
                refuse(sink, &e).await;
                return None;
            }
        };
        let caps = serde_json::to_string(&hello.capabilities).unwrap_or_default();
        let names = serde_json::to_string(&hello.joint_names).unwrap_or_default();
        if let Err(e) =
            repo::upsert_bridge(&self.0.db, &hello.worker, &hello.robot, &names, &caps).await
        {
            tracing::warn!(error = %e, "cannot record the worker");
        }
        tracing::info!(worker = %hello.worker, robot = %hello.robot, "bridge worker connected");
        let welcome = ServiceMessage::Welcome(Welcome {
            protocol_version: PROTOCOL_VERSION,
            worker: hello.worker.clone(),
            heartbeat_interval_ms: self.0.settings.heartbeat_interval.as_millis() as u64,
            heartbeat_timeout_ms: self.0.settings.heartbeat_timeout.as_millis() as u64,
        });
        if sink.send(text(&welcome)).await.is_err() {
            self.disconnect(conn, "closed before welcome").await;
            return None;
        }
        self.wake();
        Some((hello, conn, rx))
    }

    /// Relays frames both ways until the connection ends; returns why it ended.
    async fn session<Si, St, E>(
        &self,
        shutdown: &Shutdown,
        hello: &Hello,
        conn: u64,
        mut rx: mpsc::Receiver<ServiceMessage>,
        sink: &mut Si,
        stream: &mut St,
    ) -> String
    where
        Si: Sink<Message> + Unpin,
        St: Stream<Item = Result<Message, E>> + Unpin,
        E: fmt::Display,
    {
        let mut errors = 0u32;
        let mut last_heard = Instant::now();
        let mut check = tokio::time::interval(self.0.settings.heartbeat_interval / 2);
        let stopping = shutdown.wait();
        tokio::pin!(stopping);
        loop {
            let reply = tokio::select! {
                frame = stream.next() => {
                    last_heard = Instant::now();
                    match self.on_frame(conn, frame).await {
                        Step::Reply(r) => r,
                        Step::End(why) => return why,
                        Step::Fatal(e) => {
                            refuse(sink, &e).await;
                            return e.message;
                        }
                    }
                }
                out = rx.recv() => match out {
                    Some(m) => {
                        if sink.send(text(&m)).await.is_err() {
                            return "send failed".into();
                        }
                        None
                    }
                    None => return "hub closed".into(),
                },
                _ = check.tick() => {
                    if last_heard.elapsed() > self.0.settings.heartbeat_timeout {
                        let e = error(ErrorCode::HeartbeatTimeout, format!(
                            "nothing received for {} ms", self.0.settings.heartbeat_timeout.as_millis()), true);
                        refuse(sink, &e).await;
                        return e.message;
                    }
                    None
                }
                () = &mut stopping => {
                    let e = error(ErrorCode::ShuttingDown, "the service is shutting down", true);
                    refuse(sink, &e).await;
                    return e.message;
                }
            };
            let Some(e) = reply else { continue };
            errors += 1;
            tracing::debug!(worker = %hello.worker, code = ?e.code, message = %e.message, "bad bridge message");
            if sink
                .send(text(&ServiceMessage::Error(e.clone())))
                .await
                .is_err()
            {
                return "send failed".into();
            }
            if errors >= MAX_ERRORS {
                let e = error(
                    ErrorCode::TooManyErrors,
                    format!("{MAX_ERRORS} bad messages; closing"),
                    true,
                );
                refuse(sink, &e).await;
                return e.message;
            }
        }
    }

    /// Handles one incoming frame of an admitted worker.
    async fn on_frame<E: fmt::Display>(
        &self,
        conn: u64,
        frame: Option<Result<Message, E>>,
    ) -> Step {
        if let Some(w) = self.lock().workers.get_mut(&conn) {
            w.snapshot.messages += 1;
        }
        let bad = |code, message: &str| Step::Reply(Some(error(code, message, false)));
        match frame {
            None => Step::End("connection closed".into()),
            Some(Err(e)) => Step::Fatal(error(
                ErrorCode::Oversized,
                format!("unreadable frame: {e}"),
                true,
            )),
            Some(Ok(Message::Close(_))) => Step::End("closed by the worker".into()),
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => Step::Reply(None),
            Some(Ok(Message::Binary(_))) => bad(
                ErrorCode::Malformed,
                "binary frames are not part of the protocol",
            ),
            Some(Ok(Message::Text(t))) => match decode_worker_message(t.as_str()) {
                Err(e) => Step::Reply(Some(error(e.code, e.message, false))),
                Ok(WorkerMessage::Hello(_)) => {
                    bad(ErrorCode::UnexpectedMessage, "`hello` was already received")
                }
                Ok(WorkerMessage::Heartbeat(h)) => {
                    self.on_heartbeat(conn, h.positions);
                    Step::Reply(None)
                }
                Ok(WorkerMessage::Feedback(f)) => {
                    Step::Reply(self.on_feedback(conn, f).await.err())
                }
                Ok(WorkerMessage::Result(r)) => Step::Reply(self.on_result(conn, r).await.err()),
            },
        }
    }
}

/// What the session does after a frame.
enum Step {
    /// Keep going, answering with this error (a bad but survivable frame) or nothing.
    Reply(Option<ErrorReply>),
    /// The worker went away.
    End(String),
    /// Send this error, close and end.
    Fatal(ErrorReply),
}

fn text(m: &ServiceMessage) -> Message {
    Message::Text(
        serde_json::to_string(m)
            .expect("service messages serialise")
            .into(),
    )
}

/// Sends a fatal error and closes (1001 going away when shutting down, else 1008 policy
/// violation). Send failures are ignored: the connection is ending anyway.
async fn refuse<Si: Sink<Message> + Unpin>(sink: &mut Si, e: &ErrorReply) {
    let _ = sink.send(text(&ServiceMessage::Error(e.clone()))).await;
    let close = Message::Close(Some(CloseFrame {
        code: if e.code == ErrorCode::ShuttingDown {
            1001
        } else {
            1008
        },
        reason: e.message.chars().take(120).collect::<String>().into(),
    }));
    let _ = sink.send(close).await;
}

/// The first frame, which must be a `hello` within [`HELLO_TIMEOUT`]. None: the connection
/// ended before saying anything (nothing to answer).
async fn read_hello<St, E>(stream: &mut St) -> Option<Result<Hello, ErrorReply>>
where
    St: Stream<Item = Result<Message, E>> + Unpin,
{
    let first = tokio::time::timeout(HELLO_TIMEOUT, stream.next()).await;
    Some(match first {
        Ok(Some(Ok(Message::Text(t)))) => match decode_worker_message(t.as_str()) {
            Ok(WorkerMessage::Hello(h)) => Ok(h),
            Ok(_) => Err(error(
                ErrorCode::UnexpectedMessage,
                "the first message must be `hello`",
                true,
            )),
            Err(e) => Err(error(e.code, e.message, true)),
        },
        Ok(Some(Ok(_))) => Err(error(
            ErrorCode::Malformed,
            "the first message must be a `hello` text frame",
            true,
        )),
        Ok(None | Some(Err(_))) => return None,
        Err(_) => Err(error(
            ErrorCode::UnexpectedMessage,
            "no `hello` within 10 s",
            true,
        )),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hub() -> Hub {
        // Never queried by the refusals below (they happen before any robot lookup).
        let db = SqlitePool::connect_lazy("sqlite::memory:").unwrap();
        Hub::new(
            db.clone(),
            RobotLibrary::new(db),
            HubSettings {
                token: "t".into(),
                heartbeat_interval: Duration::from_secs(1),
                heartbeat_timeout: Duration::from_secs(3),
                queue_timeout: None,
            },
        )
    }

    /// Runs a session fed with `frames`, then returns what the service sent.
    async fn session(frames: Vec<Message>) -> Vec<Message> {
        let (sink, sent) = futures::channel::mpsc::unbounded::<Message>();
        let stream = futures::stream::iter(frames.into_iter().map(Ok::<_, std::io::Error>));
        let (_trigger, shutdown) = Shutdown::new();
        let hub = hub();
        hub.clone().serve_session(shutdown, sink, stream).await;
        assert!(hub.workers().is_empty(), "a refused worker is not kept");
        sent.collect().await
    }

    fn error_then_close(sent: &[Message]) -> (ErrorReply, u16) {
        let [Message::Text(t), Message::Close(Some(close))] = sent else {
            panic!("expected an error and a close, got {sent:?}");
        };
        let ServiceMessage::Error(e) = serde_json::from_str(t.as_str()).unwrap() else {
            panic!("expected an error message, got {t}");
        };
        (e, close.code)
    }

    #[tokio::test]
    async fn a_session_that_does_not_start_with_hello_is_refused_and_closed() {
        let heartbeat = r#"{"type":"heartbeat","seq":1}"#;
        let sent = session(vec![Message::Text(heartbeat.into())]).await;
        let (e, code) = error_then_close(&sent);
        assert_eq!(e.code, ErrorCode::UnexpectedMessage);
        assert!(e.fatal);
        assert_eq!(code, 1008);
    }

    #[tokio::test]
    async fn a_hello_in_another_protocol_version_is_refused() {
        let hello = serde_json::json!({
            "type": "hello", "protocol_version": PROTOCOL_VERSION + 1, "worker": "w",
            "robot": "r", "joint_names": [], "capabilities": ["open_loop"],
        });
        let sent = session(vec![Message::Text(hello.to_string().into())]).await;
        let (e, code) = error_then_close(&sent);
        assert_eq!(e.code, ErrorCode::UnsupportedVersion);
        assert_eq!(code, 1008);
    }

    #[tokio::test]
    async fn a_binary_first_frame_is_malformed_and_a_silent_close_gets_no_answer() {
        let sent = session(vec![Message::Binary(vec![1, 2].into())]).await;
        assert_eq!(error_then_close(&sent).0.code, ErrorCode::Malformed);
        assert!(session(vec![]).await.is_empty());
    }

    #[test]
    fn tokens_compare_whole() {
        assert!(same_token("abc", "abc"));
        assert!(!same_token("abc", "abd"));
        assert!(!same_token("abc", "abcd"));
        assert!(!same_token("", "a"));
    }

    #[test]
    fn tracking_summary_is_exact() {
        let mut t = TrackingSummary::default();
        for e in [3.0, 4.0] {
            t.add(e);
        }
        assert_eq!(t.samples, 2);
        assert_eq!(t.max_error, 4.0);
        assert!((t.rms_error - (12.5f64).sqrt()).abs() < 1e-12);
        assert_eq!(t.last_error, 4.0);
    }

    #[test]
    fn worker_names_are_checked() {
        assert!(WorkerName::parse("sim-1.lab_a").is_ok());
        assert!(WorkerName::parse("").is_err());
        assert!(WorkerName::parse("a b").is_err());
        assert!(WorkerName::parse(&"x".repeat(65)).is_err());
    }
}

/// What became of a streamed setpoint (`StreamHandle::send`; the retargeting answers'
/// `forward.setpoint`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StreamSend {
    /// Queued to the worker.
    Sent,
    /// The worker's outbox was full (it reads slower than the stream): this setpoint is
    /// dropped, the next one carries on (the worker follows the latest).
    Skipped,
    /// The execution is over (cancelled, the worker disconnected or failed it).
    Closed,
}

/// The sending end of a streaming execution ([`Hub::open_stream`]). Ending it (or dropping it)
/// sends `end`: the worker stops and the execution succeeds.
pub struct StreamHandle {
    hub: Hub,
    id: String,
    conn: u64,
    worker: String,
    tx: mpsc::Sender<ServiceMessage>,
    seq: u64,
    last: Option<(f64, Vec<f64>)>,
    /// Setpoints sent and skipped so far.
    pub sent: u64,
    pub skipped: u64,
    ended: bool,
}

impl fmt::Debug for StreamHandle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("StreamHandle")
            .field("id", &self.id)
            .field("worker", &self.worker)
            .field("sent", &self.sent)
            .finish_non_exhaustive()
    }
}

impl StreamHandle {
    pub fn id(&self) -> &str {
        &self.id
    }

    pub fn worker(&self) -> &str {
        &self.worker
    }

    /// The worker's latest measured positions (heartbeat or feedback), when it sent any.
    pub fn measured(&self) -> Option<Vec<f64>> {
        self.hub
            .lock()
            .workers
            .get(&self.conn)
            .map(|w| w.snapshot.positions.clone())
            .filter(|p| !p.is_empty())
    }

    /// Whether the execution still runs on its worker.
    pub fn live(&self) -> bool {
        !self.ended && self.hub.lock().live.contains_key(&self.id)
    }

    /// The worker's latest feedback (measured positions, tracking error), if any arrived.
    pub fn feedback(&self) -> Option<Feedback> {
        self.hub
            .lock()
            .live
            .get(&self.id)
            .and_then(|l| l.feedback.clone())
    }

    /// Sends the next setpoint: positions at stream time `t`, with the finite-difference
    /// velocity from the previous one as feed-forward (zero for the first, and after a time
    /// that does not increase).
    pub fn send(&mut self, t: f64, positions: &[f64]) -> StreamSend {
        if !self.live() {
            return StreamSend::Closed;
        }
        let velocities = match &self.last {
            Some((t0, q0)) if t > *t0 => positions
                .iter()
                .zip(q0)
                .map(|(q, p)| (q - p) / (t - t0))
                .collect(),
            _ => vec![0.0; positions.len()],
        };
        let msg = ServiceMessage::Setpoint(super::protocol::Setpoint {
            execution_id: self.id.clone(),
            seq: self.seq,
            t,
            positions: positions.to_vec(),
            velocities,
        });
        self.seq += 1;
        self.last = Some((t, positions.to_vec()));
        match self.tx.try_send(msg) {
            Ok(()) => {
                self.sent += 1;
                StreamSend::Sent
            }
            Err(mpsc::error::TrySendError::Full(_)) => {
                self.skipped += 1;
                StreamSend::Skipped
            }
            Err(mpsc::error::TrySendError::Closed(_)) => StreamSend::Closed,
        }
    }

    /// Ends the stream: `end` to the worker (which stops and succeeds the execution); where
    /// that cannot be delivered, the execution is cancelled instead.
    pub async fn end(mut self) {
        self.finish().await;
    }

    async fn finish(&mut self) {
        if self.ended {
            return;
        }
        self.ended = true;
        end_stream(&self.hub, &self.id, &self.tx).await;
    }
}

/// Sends `end` for stream `id` (cancels it where that cannot be delivered); nothing when it is
/// already over.
async fn end_stream(hub: &Hub, id: &str, tx: &mpsc::Sender<ServiceMessage>) {
    if !hub.lock().live.contains_key(id) {
        return;
    }
    let end = ServiceMessage::End(super::protocol::End {
        execution_id: id.to_owned(),
    });
    let delivered = matches!(
        tokio::time::timeout(Duration::from_secs(1), tx.send(end)).await,
        Ok(Ok(()))
    );
    if !delivered && let Err(e) = hub.cancel(id).await {
        tracing::warn!(execution = %id, error = %e, "cannot end a stream");
    }
}

impl Drop for StreamHandle {
    fn drop(&mut self) {
        if self.ended {
            return;
        }
        self.ended = true;
        // Dropped without `end` (the sender's task ended abruptly): end it in the background so
        // the worker does not hold the execution forever. (A runtime shutting down drops the
        // task; the worker's hold then stops the robot, and its disconnect ends the execution.)
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            let (hub, id, tx) = (self.hub.clone(), self.id.clone(), self.tx.clone());
            rt.spawn(async move { end_stream(&hub, &id, &tx).await });
        }
    }
}
