//! Issue 22's retargeting figures (run with `cargo bench --bench retarget`):
//! 1. **In process, one thread**: a reachable keypoint stream onto the 16-joint four-finger hand
//!    on a fixed base (`robots/examples/ff16_hand.toml`): forward kinematics of a smooth random
//!    joint trajectory, 60 s at 100 Hz (`mapping::retarget::targets`), warm-started frame to
//!    frame. Frames/s (target ≥ 5,000), per-frame latency percentiles and the fingertip error
//!    (target median ≤ 1 mm). The same for an arm + hand system (wam_ihy) from a study
//!    demonstration's keypoints with elbow and shoulder.
//! 2. **Over the WebSocket**: the service on loopback (temp database, no seeding), the hand
//!    registered over HTTP, the same stream sent at 100 Hz for 60 s
//!    (`RETARGET_WS_SECONDS` to change), one malformed frame every 500; end-to-end latency
//!    (send to answer received), frames answered, refusals, and whether the stream stayed open
//!    (targets: median ≤ 2 ms, no frame dropped).
//! 3. **Teleoperation**: the same stream with `forward=true` to an in-process reference worker
//!    (`bridge::worker::run_worker`, the hand's URDF limits, 40 rad/s²): per frame the time from
//!    sending the keypoint frame to the worker decoding its setpoint, setpoints delivered and
//!    skipped, the execution's end state and the worker's tracking error (same duration).
//!
//! Not criterion: the figures are latency distributions and an error, so this prints its own.
//! The targets file for other tools: `RETARGET_DUMP=targets.json` writes the stream's keypoint
//! frames, joint values and fingertip targets (robot base frame) as JSON.

use std::path::Path;
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use reachgrasp::app::App;
use reachgrasp::config::Config;
use reachgrasp::human::KeypointFrame;
use reachgrasp::kinematics::{Data, System, forward_kinematics};
use reachgrasp::mapping::retarget::targets::reachable_stream;
use reachgrasp::mapping::{MappingModel, RetargetOptions, Retargeter};
use reachgrasp::service::retarget::KeypointFrameMsg;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

const RATE_HZ: f64 = 100.0;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn ff16() -> System {
    System::from_file(&root().join("robots/examples/ff16_hand.toml")).expect("ff16 descriptor")
}

fn frame_json(kp: &KeypointFrame, seq: u64) -> Value {
    serde_json::to_value(KeypointFrameMsg::new(kp, Some(seq))).expect("serialisable")
}

fn in_process() {
    let sys = ff16();
    let stream = reachable_stream(&sys, 60.0, RATE_HZ, 7).expect("reachable stream");
    if let Ok(path) = std::env::var("RETARGET_DUMP") {
        let m = sys.fingers.len();
        let doc = json!({
            "hand": "robots/hands/ff16.urdf",
            "joint_names": sys.model.joint_names(),
            "fingers": sys.fingers.iter().map(|f| f.name.clone()).collect::<Vec<_>>(),
            "rate_hz": RATE_HZ,
            "frames": stream.frames.iter().enumerate().map(|(k, f)| frame_json(f, k as u64)).collect::<Vec<_>>(),
            "joints": stream.joints,
            "targets": stream.targets.iter().map(|t| t[..m].iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>()).collect::<Vec<_>>(),
        });
        std::fs::write(&path, serde_json::to_vec(&doc).expect("json")).expect("write dump");
        println!("wrote {path}");
    }
    let mm = MappingModel::from_system(&sys).expect("mapping model");
    let mut r = Retargeter::new(mm, RetargetOptions::default()).expect("retargeter");
    let mut data = Data::new(&sys.model);
    let mut lat = Vec::with_capacity(stream.frames.len());
    let mut errors = Vec::with_capacity(4 * stream.frames.len());
    let t0 = Instant::now();
    let mut warm = Duration::ZERO;
    for (k, f) in stream.frames.iter().enumerate() {
        let t = Instant::now();
        r.push(f).expect("reachable frame");
        let dt = t.elapsed();
        if k > 0 {
            warm += dt;
            lat.push(dt.as_secs_f64() * 1e6);
        }
        forward_kinematics(&sys.model, &mut data, r.output());
        for (i, finger) in sys.fingers.iter().enumerate() {
            errors.push(
                (data.frame(finger.tip).translation.vector - stream.targets[k][i].coords).norm(),
            );
        }
    }
    let total = t0.elapsed();
    lat.sort_by(f64::total_cmp);
    errors.sort_by(f64::total_cmp);
    println!(
        "ff16 (16 joints, hand only), {} frames at {RATE_HZ} Hz, one thread, warm-started:",
        stream.frames.len()
    );
    println!(
        "  {:.0} frames/s warm ({:.0} with the first frame's multi-start); per frame p50 {:.1} us, p95 {:.1} us, p99 {:.1} us, max {:.1} us",
        lat.len() as f64 / warm.as_secs_f64(),
        stream.frames.len() as f64 / total.as_secs_f64(),
        percentile(&lat, 0.5),
        percentile(&lat, 0.95),
        percentile(&lat, 0.99),
        lat.last().copied().unwrap_or(0.0)
    );
    println!(
        "  fingertip error median {:.3} mm, p95 {:.3} mm, max {:.3} mm",
        percentile(&errors, 0.5) * 1e3,
        percentile(&errors, 0.95) * 1e3,
        errors.last().copied().unwrap_or(0.0) * 1e3
    );
}

const TOKEN: &str = "bench-token";

/// The service on loopback (temp database, no seeding) with the FF16 hand registered over
/// HTTP: its address, the hand's id, and the directory to keep alive.
async fn service() -> anyhow::Result<(std::net::SocketAddr, String, tempfile::TempDir)> {
    let dir = tempfile::tempdir()?;
    let config = Config {
        bind: "127.0.0.1:0".parse()?,
        db: dir.path().join("bench.db"),
        robots: root().join("robots"),
        log: "warn".into(),
        no_seed: true,
        bridge_token: Some(TOKEN.into()),
        ..Config::default()
    };
    let app = App::build(config).await?;
    let addr = app.local_addr();
    tokio::spawn(app.run_until(std::future::pending()));
    // Register the hand as a lab would (README "Retargeting").
    let mut descriptor: toml::Table = toml::from_str(&std::fs::read_to_string(
        root().join("robots/examples/ff16_hand.toml"),
    )?)?;
    descriptor.remove("urdf");
    let body = json!({
        "descriptor": descriptor,
        "urdf": std::fs::read_to_string(root().join("robots/hands/ff16.urdf"))?,
    });
    let client = reqwest::Client::new();
    let res = client
        .post(format!("http://{addr}/v1/robots"))
        .json(&body)
        .send()
        .await?;
    anyhow::ensure!(res.status().is_success(), "register: {}", res.text().await?);
    let id = res.json::<Value>().await?["id"]
        .as_str()
        .unwrap_or_default()
        .to_string();
    Ok((addr, id, dir))
}

async fn websocket(seconds: f64) -> anyhow::Result<()> {
    let (addr, id, _dir) = service().await?;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{addr}/v1/robots/{id}/retarget")).await?;
    let ready: Value = match ws.next().await {
        Some(Ok(Message::Text(t))) => serde_json::from_str(&t)?,
        other => anyhow::bail!("no ready message: {other:?}"),
    };
    anyhow::ensure!(ready["type"] == "ready", "{ready}");
    let sys = ff16();
    let stream = reachable_stream(&sys, seconds, RATE_HZ, 7)?;
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let start = tokio::time::Instant::now();
    let (mut rtt, mut server) = (Vec::new(), Vec::new());
    let (mut answered, mut refused, mut sent) = (0usize, 0usize, 0usize);
    for (k, f) in stream.frames.iter().enumerate() {
        tokio::time::sleep_until(start + period * k as u32).await;
        if k > 0 && k % 500 == 0 {
            // A malformed frame: refused, the stream goes on.
            ws.send(Message::Text(
                r#"{"seq": -1, "t": "soon", "points": []}"#.into(),
            ))
            .await?;
            match ws.next().await {
                Some(Ok(Message::Text(t))) => {
                    let v: Value = serde_json::from_str(&t)?;
                    anyhow::ensure!(v["type"] == "error", "malformed frame answered {v}");
                    refused += 1;
                }
                other => anyhow::bail!("stream ended after a malformed frame: {other:?}"),
            }
        }
        let text = frame_json(f, k as u64).to_string();
        let t = Instant::now();
        ws.send(Message::Text(text.into())).await?;
        sent += 1;
        match ws.next().await {
            Some(Ok(Message::Text(t2))) => {
                let us = t.elapsed().as_secs_f64() * 1e6;
                let v: Value = serde_json::from_str(&t2)?;
                anyhow::ensure!(
                    v["type"] == "joints" && v["seq"] == k as u64,
                    "frame {k}: {v}"
                );
                answered += 1;
                rtt.push(us);
                server.push(v["latency_us"].as_f64().unwrap_or(f64::NAN));
            }
            other => anyhow::bail!("frame {k}: {other:?}"),
        }
    }
    ws.close(None).await.ok();
    rtt.sort_by(f64::total_cmp);
    server.sort_by(f64::total_cmp);
    println!(
        "WebSocket, loopback, {sent} frames at {RATE_HZ} Hz ({seconds} s): answered {answered}, dropped {}, malformed refused {refused} (stream kept open)",
        sent - answered
    );
    println!(
        "  end to end p50 {:.0} us, p95 {:.0} us, p99 {:.0} us, max {:.0} us; server side p50 {:.0} us, p99 {:.0} us",
        percentile(&rtt, 0.5),
        percentile(&rtt, 0.95),
        percentile(&rtt, 0.99),
        rtt.last().copied().unwrap_or(0.0),
        percentile(&server, 0.5),
        percentile(&server, 0.99),
    );
    Ok(())
}

async fn teleoperation(seconds: f64) -> anyhow::Result<()> {
    use reachgrasp::bridge::worker::{WorkerEvent, WorkerOptions, run_worker};
    let (addr, id, _dir) = service().await?;
    let sys = ff16();
    let stream = reachable_stream(&sys, seconds, RATE_HZ, 7)?;
    let opts = RetargetOptions {
        speed_scale: Some(0.5),
        cutoff_hz: Some(8.0),
        ..RetargetOptions::default()
    };
    let mut first = Retargeter::new(MappingModel::from_system(&sys)?, opts)?;
    first.push(&stream.frames[0])?;
    let mut w = WorkerOptions::for_system(
        format!("ws://{addr}/v1/bridges/connect"),
        TOKEN,
        "bench-tele",
        &id,
        &sys,
        40.0,
    );
    w.initial = Some(first.output().to_vec());
    let (tx, mut events) = tokio::sync::mpsc::unbounded_channel();
    let worker = tokio::spawn(run_worker(w, Some(tx), std::future::pending()));
    while !matches!(events.recv().await, Some(WorkerEvent::Connected) | None) {}
    let (mut ws, _) = tokio_tungstenite::connect_async(format!(
        "ws://{addr}/v1/robots/{id}/retarget?forward=true&speed_scale=0.5&cutoff_hz=8"
    ))
    .await?;
    let ready: Value = match ws.next().await {
        Some(Ok(Message::Text(t))) => serde_json::from_str(&t)?,
        other => anyhow::bail!("no ready message: {other:?}"),
    };
    let exec = ready["execution_id"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    anyhow::ensure!(!exec.is_empty(), "no streaming execution: {ready}");
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let start = tokio::time::Instant::now();
    let mut sent_at = Vec::with_capacity(stream.frames.len());
    let mut outcome = std::collections::HashMap::<String, usize>::new();
    for (k, f) in stream.frames.iter().enumerate() {
        tokio::time::sleep_until(start + period * k as u32).await;
        let text = frame_json(f, k as u64).to_string();
        sent_at.push(Instant::now());
        ws.send(Message::Text(text.into())).await?;
        match ws.next().await {
            Some(Ok(Message::Text(t))) => {
                let v: Value = serde_json::from_str(&t)?;
                let s = v["forward"]["setpoint"]
                    .as_str()
                    .unwrap_or("none")
                    .to_owned();
                *outcome.entry(s).or_default() += 1;
            }
            other => anyhow::bail!("frame {k}: {other:?}"),
        }
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    ws.close(None).await.ok();
    let mut latency = Vec::new();
    let mut stats = None;
    while stats.is_none() {
        match tokio::time::timeout(Duration::from_secs(10), events.recv()).await {
            Ok(Some(WorkerEvent::Setpoint { seq, at, .. })) => {
                latency.push(at.duration_since(sent_at[seq as usize]).as_secs_f64() * 1e6);
            }
            Ok(Some(WorkerEvent::StreamEnded { stats: s, .. })) => stats = Some(s),
            Ok(Some(_)) => {}
            _ => anyhow::bail!("the stream did not end on the worker"),
        }
    }
    let stats = stats.unwrap_or_default();
    let client = reqwest::Client::new();
    let mut e = Value::Null;
    for _ in 0..100 {
        e = client
            .get(format!("http://{addr}/v1/executions/{exec}"))
            .send()
            .await?
            .json()
            .await?;
        if e["state"] != "running" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    worker.abort();
    latency.sort_by(f64::total_cmp);
    println!(
        "Teleoperation, loopback, {} frames at {RATE_HZ} Hz ({seconds} s) to an in-process worker: answers {:?}; worker took {} setpoints, {} missing, {} refused; execution {}",
        stream.frames.len(),
        outcome,
        stats.received,
        stats.missing,
        stats.refused,
        e["state"],
    );
    println!(
        "  frame sent to setpoint decoded on the worker: p50 {:.0} us, p95 {:.0} us, p99 {:.0} us, max {:.0} us; worker tracking error max {:.3} rad, rms {:.3} rad",
        percentile(&latency, 0.5),
        percentile(&latency, 0.95),
        percentile(&latency, 0.99),
        latency.last().copied().unwrap_or(0.0),
        e["tracking"]["max_error"].as_f64().unwrap_or(f64::NAN),
        e["tracking"]["rms_error"].as_f64().unwrap_or(f64::NAN),
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    in_process();
    let seconds = std::env::var("RETARGET_WS_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
    if seconds > 0.0 {
        tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()?
            .block_on(async {
                websocket(seconds).await?;
                teleoperation(seconds).await
            })?;
    }
    Ok(())
}
