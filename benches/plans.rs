//! Issue 10's figures, measured on the real service over loopback (run with
//! `cargo bench --bench plans`):
//! - first-start seeding on an empty database (target ≤ 60 s on 2 cores);
//! - `POST /v1/plans` without execution for the seeded objects at reachable placements,
//!   one client (target median ≤ 150 ms);
//! - the same under 32 concurrent clients (target p99 ≤ 1 s, no errors).
//!
//! Not criterion: seeding is a one-off of tens of seconds and the concurrent phase measures a
//! latency distribution, so this prints its own table.

use std::time::{Duration, Instant};

use reachgrasp::app::App;
use reachgrasp::config::Config;
use serde_json::{Value, json};

const ROBOT: &str = "wam_ihy";
const CLIENTS: usize = 32;
const REQUESTS_PER_CLIENT: usize = 4;

fn percentile(sorted: &[f64], p: f64) -> f64 {
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

/// Plan requests: the seeded ball and bottle, and both at other reachable table placements.
fn requests(start: &Value) -> Vec<Value> {
    let mut out = Vec::new();
    for (object, dir, kind) in [
        (
            "00000000-0000-4000-8000-000000000001",
            [0.0, 0.0, 1.0],
            "force",
        ),
        (
            "00000000-0000-4000-8000-000000000002",
            [0.0, 1.0, 0.0],
            "velocity",
        ),
    ] {
        out.push(json!({"robot": ROBOT, "object_id": object, "start": start,
            "task_directions": [{"direction": dir, "kind": kind, "goal": "maximize"}]}));
    }
    for (x, y) in [(0.45, -0.1), (0.5, 0.1), (0.55, 0.0)] {
        out.push(json!({"robot": ROBOT, "start": start,
            "object": {"name": "ball", "shape": {"type": "sphere", "radius": 0.033},
                       "position": [x, y, 0.033], "support": {"normal": [0, 0, 1], "offset": 0.0}},
            "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}));
        out.push(json!({"robot": ROBOT, "start": start,
            "object": {"name": "bottle", "shape": {"type": "cylinder", "radius": 0.0325, "height": 0.2},
                       "position": [x, y, 0.1], "support": {"normal": [0, 0, 1], "offset": 0.0}},
            "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}]}));
    }
    out
}

async fn post(client: &reqwest::Client, url: &str, body: &Value) -> (f64, bool, Value) {
    let t = Instant::now();
    let res = client.post(url).json(body).send().await;
    let secs = t.elapsed().as_secs_f64();
    match res {
        Ok(r) => {
            let ok = r.status() == 201;
            (secs, ok, r.json().await.unwrap_or(Value::Null))
        }
        Err(e) => (secs, false, json!({"error": e.to_string()})),
    }
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(run())
}

async fn run() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let config = Config {
        bind: "127.0.0.1:0".parse()?,
        db: dir.path().join("bench.db"),
        robots: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots"),
        log: "warn".into(),
        ..Config::default()
    };
    let t0 = Instant::now();
    let app = App::build(config).await?;
    let base = format!("http://{}", app.local_addr());
    tokio::spawn(app.run_until(std::future::pending()));
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(120))
        .build()?;

    // Seeding: every bundled system has its default model.
    let robots = [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ];
    loop {
        let mut ready = 0;
        for r in robots {
            let v: Value = client
                .get(format!("{base}/v1/models?robot={r}"))
                .send()
                .await?
                .json()
                .await?;
            if v["items"]
                .as_array()
                .is_some_and(|a| a.iter().any(|m| m["status"] == "succeeded"))
            {
                ready += 1;
            }
        }
        if ready == robots.len() {
            break;
        }
        anyhow::ensure!(
            t0.elapsed() < Duration::from_secs(1800),
            "seeding did not finish"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let seeding = t0.elapsed().as_secs_f64();
    println!("first-start seeding (6 systems): {seeding:.1} s (target ≤ 60 s)");

    let robot: Value = client
        .get(format!("{base}/v1/robots/{ROBOT}"))
        .send()
        .await?
        .json()
        .await?;
    let names = robot["joint_names"].clone();
    let n = names.as_array().map_or(0, Vec::len);
    let start = json!({"joint_names": names, "positions": vec![0.0; n]});
    let bodies = requests(&start);
    let url = format!("{base}/v1/plans");

    // Warm-up, then one client.
    for b in &bodies {
        let (_, ok, v) = post(&client, &url, b).await;
        anyhow::ensure!(ok, "plan failed: {v}");
    }
    let mut seq = Vec::new();
    let mut feasible = 0;
    let mut reasons: Vec<String> = Vec::new();
    for _ in 0..4 {
        for b in &bodies {
            let (s, ok, v) = post(&client, &url, b).await;
            anyhow::ensure!(ok, "plan failed: {v}");
            feasible += usize::from(v["feasible"] == true);
            if v["feasible"] != true {
                let reason = v["reason"].as_str().unwrap_or("no reason").to_owned();
                if !reasons.contains(&reason) {
                    reasons.push(reason);
                }
            }
            seq.push(s);
        }
    }
    seq.sort_by(f64::total_cmp);
    println!(
        "POST /v1/plans, 1 client, {} requests ({feasible} feasible): median {:.1} ms, p90 {:.1} ms (target median ≤ 150 ms)",
        seq.len(),
        1e3 * percentile(&seq, 0.5),
        1e3 * percentile(&seq, 0.9)
    );
    for r in &reasons {
        println!("  infeasible: {r}");
    }

    // 32 concurrent clients.
    let t = Instant::now();
    let mut tasks = tokio::task::JoinSet::new();
    for c in 0..CLIENTS {
        let (client, url, bodies) = (client.clone(), url.clone(), bodies.clone());
        tasks.spawn(async move {
            let mut out = Vec::new();
            for k in 0..REQUESTS_PER_CLIENT {
                let b = &bodies[(c + k) % bodies.len()];
                let (s, ok, _) = post(&client, &url, b).await;
                out.push((s, ok));
            }
            out
        });
    }
    let mut all = Vec::new();
    let mut errors = 0;
    while let Some(r) = tasks.join_next().await {
        for (s, ok) in r? {
            all.push(s);
            errors += usize::from(!ok);
        }
    }
    let wall = t.elapsed().as_secs_f64();
    all.sort_by(f64::total_cmp);
    println!(
        "POST /v1/plans, {CLIENTS} concurrent clients, {} requests in {wall:.1} s: median {:.0} ms, p99 {:.0} ms, {errors} errors (target p99 ≤ 1 s, no errors)",
        all.len(),
        1e3 * percentile(&all, 0.5),
        1e3 * percentile(&all, 0.99)
    );
    Ok(())
}
