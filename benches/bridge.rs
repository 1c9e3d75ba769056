//! Bridge performance over loopback, with the real service and the real worker code:
//!
//! 1. Dispatch latency: `POST /v1/executions` sent → the (idle) worker has decoded the
//!    `execute` message. Percentiles over a fixed run, then criterion's estimate. Target ≤ 5 ms.
//! 2. Load: 50 simulated workers, each running an execution and streaming feedback at 100 Hz
//!    (control at 100 Hz, heartbeats every second), for a fixed window. Reports the feedback
//!    rate the service received, the longest heartbeat gap any worker had, disconnects, and the
//!    CPU used by the service's threads and by the workers' threads. Target: no dropped
//!    heartbeats (every gap well under the 5 s timeout, no disconnect) on 2 cores.
//!
//! The service runs on its own 2-thread runtime (threads named `svc`), the workers on another
//! (`wrk`), so `/proc/self/task/*/stat` separates their CPU time.
//!
//! `cargo bench --bench bridge -- --warm-up-time 1 --measurement-time 3`
//! (`BRIDGE_BENCH_WORKERS`, `BRIDGE_BENCH_SECONDS` override 50 workers and the 8 s window.)

use std::path::Path;
use std::time::{Duration, Instant};

use criterion::Criterion;
use reachgrasp::app::App;
use reachgrasp::bridge::sim::{SimLimits, min_jerk};
use reachgrasp::bridge::worker::{WorkerEvent, WorkerOptions, run_worker};
use reachgrasp::config::Config;
use reachgrasp::kinematics::System;
use serde_json::{Value, json};
use tokio::sync::{mpsc, watch};

const TOKEN: &str = "bench-token";
const ROBOT: &str = "wam_ihy";

struct Service {
    base: String,
    ws: String,
    _dir: tempfile::TempDir,
}

fn start_service(rt: &tokio::runtime::Runtime) -> Service {
    let dir = tempfile::tempdir().unwrap();
    let config = Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        db: dir.path().join("bench.db"),
        robots: Path::new(env!("CARGO_MANIFEST_DIR")).join("robots"),
        log: "warn".into(),
        bridge_token: Some(TOKEN.into()),
        ..Config::default()
    };
    let app = rt.block_on(App::build(config)).expect("service builds");
    let addr = app.local_addr();
    rt.spawn(app.run_until(std::future::pending()));
    Service {
        base: format!("http://{addr}"),
        ws: format!("ws://{addr}/v1/bridges/connect"),
        _dir: dir,
    }
}

fn system() -> System {
    System::from_file(&Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml"))
        .unwrap()
}

fn home(s: &System) -> Vec<f64> {
    let m = &s.model;
    SimLimits::new(m.lower_limits(), m.upper_limits(), m.velocity_limits(), 4.0).home()
}

/// CPU seconds of this process's threads whose name starts with `prefix`.
fn cpu_seconds(prefix: &str) -> f64 {
    let tick = 100.0; // USER_HZ on Linux
    let mut total = 0.0;
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    for t in tasks.flatten() {
        let Ok(stat) = std::fs::read_to_string(t.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ... field 14 utime, 15 stime (after the closing parenthesis)
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        if !stat[open + 1..close].starts_with(prefix) {
            continue;
        }
        let rest: Vec<&str> = stat[close + 2..].split_whitespace().collect();
        let ut: f64 = rest.get(11).and_then(|v| v.parse().ok()).unwrap_or(0.0);
        let st: f64 = rest.get(12).and_then(|v| v.parse().ok()).unwrap_or(0.0);
        total += (ut + st) / tick;
    }
    total
}

/// One dispatch: POST, then the time until the worker decoded the `execute`; returns after the
/// worker finished it (so the next one finds it idle).
async fn once(
    client: &reqwest::Client,
    events: &mut mpsc::UnboundedReceiver<WorkerEvent>,
    body: &Value,
    base: &str,
) -> Duration {
    let t0 = Instant::now();
    let res = client
        .post(format!("{base}/v1/executions"))
        .json(body)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 202);
    let mut received = None;
    loop {
        match events.recv().await.expect("worker alive") {
            WorkerEvent::Execute { at, .. } => received = Some(at - t0),
            WorkerEvent::Finished { .. } => break,
            _ => {}
        }
    }
    received.expect("execute before finished")
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn main() {
    let svc = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("svc")
        .enable_all()
        .build()
        .unwrap();
    let wrk = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("wrk")
        .enable_all()
        .build()
        .unwrap();
    let service = start_service(&svc);
    let sys = system();
    let names = sys.model.joint_names().to_vec();
    let q0 = home(&sys);
    let client = reqwest::Client::new();

    // ------------------------------------------------------------------ 1. dispatch latency
    let (tx, mut events) = mpsc::unbounded_channel();
    let (stop_tx, stop_rx) = watch::channel(false);
    let stopped = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let opts = WorkerOptions::for_system(&service.ws, TOKEN, "lat-0", ROBOT, &sys, 4.0);
    wrk.spawn(run_worker(opts, Some(tx), stopped(stop_rx.clone())));
    // A one-point trajectory at the robot's position: it finishes on the first control tick.
    let body = json!({"robot": ROBOT, "mode": "open_loop",
        "trajectory": {"joint_names": names, "points": min_jerk(&q0, &q0, 0.0, 100.0)[..1]}});
    wrk.block_on(async {
        loop {
            if let Some(WorkerEvent::Connected) = events.recv().await {
                break;
            }
        }
    });
    let mut lat: Vec<f64> = (0..300)
        .map(|_| {
            wrk.block_on(once(&client, &mut events, &body, &service.base))
                .as_secs_f64()
                * 1e3
        })
        .collect();
    lat.sort_by(f64::total_cmp);
    println!(
        "dispatch latency POST -> worker received (ms, n = {}): p50 {:.3}  p95 {:.3}  p99 {:.3}  max {:.3}",
        lat.len(),
        percentile(&lat, 0.5),
        percentile(&lat, 0.95),
        percentile(&lat, 0.99),
        lat[lat.len() - 1]
    );
    let mut c = Criterion::default().configure_from_args();
    c.bench_function("bridge/dispatch_latency_post_to_worker", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                total += wrk.block_on(once(&client, &mut events, &body, &service.base));
            }
            total
        })
    });
    c.final_summary();

    // ------------------------------------------------------------------ 2. 50 workers at 100 Hz
    let workers: usize = std::env::var("BRIDGE_BENCH_WORKERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(50);
    let window: f64 = std::env::var("BRIDGE_BENCH_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(8.0);
    let (tx, mut load_events) = mpsc::unbounded_channel();
    for i in 0..workers {
        let mut o =
            WorkerOptions::for_system(&service.ws, TOKEN, format!("load-{i:02}"), ROBOT, &sys, 4.0);
        o.rate_hz = 100.0;
        o.feedback_hz = 100.0;
        wrk.spawn(run_worker(o, Some(tx.clone()), stopped(stop_rx.clone())));
    }
    wrk.block_on(async {
        let mut connected = 0;
        while connected < workers {
            if let Some(WorkerEvent::Connected) = load_events.recv().await {
                connected += 1;
            }
        }
    });
    // A slow reach per worker, longer than the window.
    let mut target = q0.clone();
    for (j, d) in [0.3, 0.2, -0.2, 0.3, 0.1, -0.2, 0.2].iter().enumerate() {
        target[j] += d;
    }
    let long = json!({"robot": ROBOT, "mode": "open_loop",
        "trajectory": {"joint_names": names, "points": min_jerk(&q0, &target, window + 6.0, 100.0)}});
    wrk.block_on(async {
        for _ in 0..workers {
            let r = client
                .post(format!("{}/v1/executions", service.base))
                .json(&long)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 202);
        }
    });
    let bridges = |client: reqwest::Client, base: String| async move {
        let v: Value = client
            .get(format!("{base}/v1/bridges"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        v["items"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|b| b["name"].as_str().unwrap().starts_with("load-"))
            .cloned()
            .collect::<Vec<Value>>()
    };
    // all busy, then measure
    wrk.block_on(async {
        for _ in 0..500 {
            let b = bridges(client.clone(), service.base.clone()).await;
            if b.iter().filter(|b| b["status"] == "busy").count() == workers {
                return;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        panic!("not every worker got an execution");
    });
    let before = wrk.block_on(bridges(client.clone(), service.base.clone()));
    let (svc0, wrk0, t0) = (cpu_seconds("svc"), cpu_seconds("wrk"), Instant::now());
    std::thread::sleep(Duration::from_secs_f64(window));
    let (svc1, wrk1, elapsed) = (cpu_seconds("svc"), cpu_seconds("wrk"), t0.elapsed());
    let after = wrk.block_on(bridges(client.clone(), service.base.clone()));
    let msgs = |v: &[Value]| -> u64 {
        v.iter()
            .map(|b| b["connection"]["messages"].as_u64().unwrap_or(0))
            .sum()
    };
    let heartbeats: u64 = after
        .iter()
        .map(|b| b["connection"]["heartbeats"].as_u64().unwrap_or(0))
        .sum::<u64>()
        - before
            .iter()
            .map(|b| b["connection"]["heartbeats"].as_u64().unwrap_or(0))
            .sum::<u64>();
    let max_gap = after
        .iter()
        .map(|b| {
            b["connection"]["max_heartbeat_gap_ms"]
                .as_f64()
                .unwrap_or(f64::NAN)
        })
        .fold(0.0, f64::max);
    let busy = after.iter().filter(|b| b["status"] == "busy").count();
    let mut disconnects = 0;
    while let Ok(e) = load_events.try_recv() {
        if matches!(e, WorkerEvent::Disconnected { .. }) {
            disconnects += 1;
        }
    }
    let secs = elapsed.as_secs_f64();
    let rate = (msgs(&after) - msgs(&before)) as f64 / secs;
    println!(
        "load: {workers} workers x 100 Hz feedback for {secs:.1} s: service received {rate:.0} msg/s \
         ({:.1} per worker per s), {heartbeats} heartbeats, longest heartbeat gap {max_gap:.0} ms \
         (interval 1000, timeout 5000), {disconnects} disconnects, {busy}/{workers} still running; \
         CPU: service threads {:.2} cores, worker threads {:.2} cores",
        rate / workers as f64,
        (svc1 - svc0) / secs,
        (wrk1 - wrk0) / secs,
    );
    stop_tx.send_replace(true);
    std::thread::sleep(Duration::from_millis(200));
}
