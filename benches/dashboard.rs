//! Issue 21's dashboard figure: "first dashboard page <= 200 ms", with 200 stored plans. Run
//! with `cargo bench --bench dashboard`, or in the dev profile with `cargo test --bench
//! dashboard`; it prints its own table.
//!
//! Server time of `GET /`, `/ui/plans` (first and last page), a plan's page and a comparison,
//! measured on loopback from request to last byte (the pages are server-rendered; figures are
//! separate requests and not counted). "First" is the first request a freshly started service
//! answers on that database (its robot library cold); then the median and the slowest of 30
//! requests each.
//!
//! The plans are real: a small synthetic study is mapped and trained over HTTP, a few plans are
//! made over HTTP, and the 200 are those plans' rows stored again through the plan use case's
//! store (so the bench measures the pages, not planning).

#[path = "support/http.rs"]
mod http;

use std::time::{Duration, Instant};

use reachgrasp::app::App;
use reachgrasp::config::Config;
use reachgrasp::service::plans::PlanRows;
use reachgrasp::store::grasps::NewGrasp;
use reachgrasp::store::plans::NewPlan;
use serde_json::{Value, json};

const ROBOT: &str = "wam_ihy";
const PLANS: usize = 200;
const REPEATS: usize = 30;
const BUDGET_MS: f64 = 200.0;

/// Milliseconds from sending `GET path` to its last byte (asserting a 200 HTML page).
async fn time_page(client: &reqwest::Client, base: &str, path: &str) -> f64 {
    let t0 = Instant::now();
    let res = client.get(format!("{base}{path}")).send().await.unwrap();
    assert_eq!(res.status(), 200, "{path}");
    let body = res.text().await.unwrap();
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    assert!(body.starts_with("<!doctype html>"), "{path}");
    ms
}

fn config(db: &std::path::Path) -> anyhow::Result<Config> {
    Ok(Config {
        bind: "127.0.0.1:0".parse()?,
        db: db.to_owned(),
        robots: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots"),
        log: "warn".into(),
        no_seed: true,
        // Retention would delete nothing at 200 plans; no maintenance while timing.
        maintenance_interval_secs: 24 * 3600,
        ..Config::default()
    })
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(run())
}

async fn run() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let db = dir.path().join("bench.db");
    let app = App::build(config(&db)?).await?;
    let ctx = app.state().clone();
    let base = format!("http://{}", app.local_addr());
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(app.run_until(async {
        stopped.await.ok();
    }));
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(120))
        .build()?;

    let (_, start) = http::trained(&client, &base, ROBOT).await;

    // Real plans over HTTP, feasible or not (the list shows both).
    let bodies = [
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000001", "start": start,
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000002", "start": start,
               "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}]}),
        json!({"robot": ROBOT, "start": start,
               "object": {"name": "ball", "shape": {"type": "sphere", "radius": 0.033},
                          "position": [0.5, 0.1, 0.033], "support": {"normal": [0, 0, 1], "offset": 0.0}},
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
    ];
    let mut real = Vec::new();
    for body in &bodies {
        let res = client
            .post(format!("{base}/v1/plans"))
            .json(body)
            .send()
            .await?;
        anyhow::ensure!(res.status() == 201, "plan failed: {}", res.text().await?);
        let p: Value = res.json().await?;
        let stored = reachgrasp::service::plans::get(&ctx, p["id"].as_str().unwrap()).await?;
        real.push(stored);
    }
    let feasible = real.iter().filter(|s| s.plan.feasible).count();
    for i in real.len()..PLANS {
        let s = &real[i % real.len()];
        let rows = PlanRows {
            grasp: NewGrasp {
                robot: s.grasp.robot.clone(),
                object_id: s.grasp.object_id.clone(),
                object: s.grasp.object.clone(),
                request: s.grasp.request.clone(),
                result: s.grasp.result.clone(),
                feasible: s.grasp.feasible,
            },
            trajectory: s.trajectory.as_ref().map(|t| {
                reachgrasp::store::trajectories::TrajectoryDraft {
                    model_id: t.model_id.clone(),
                    robot: t.robot.clone(),
                    joint_names: t.joint_names.clone(),
                    points: t.points.clone(),
                    start: t.start.clone(),
                    goal: t.goal.clone(),
                    duration: t.duration,
                    request: t.request.clone(),
                    summary: t.summary.clone(),
                }
            }),
            execution: None,
            plan: NewPlan {
                robot: s.plan.robot.clone(),
                model_id: s.plan.model_id.clone(),
                grasp_id: String::new(),
                trajectory_id: None,
                execution_id: None,
                feasible: s.plan.feasible,
                reason: s.plan.reason.clone(),
                request: s.plan.request.clone(),
                timings: s.plan.timings.clone(),
            },
        };
        reachgrasp::service::plans::store(&ctx, rows).await?;
    }
    let (a, b) = (real[0].plan.id.clone(), real[1].plan.id.clone());
    stop.send(()).ok();
    server.await??;

    // A freshly started service on that database: its first answers, then steady state.
    let app = App::build(config(&db)?).await?;
    let base = format!("http://{}", app.local_addr());
    tokio::spawn(app.run_until(std::future::pending()));
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(60))
        .build()?;
    let pages = [
        "/".to_owned(),
        "/ui/plans".to_owned(),
        "/ui/plans?offset=150".to_owned(),
        format!("/ui/plans/{a}"),
        format!("/ui/compare?plans={a},{b}"),
    ];
    println!(
        "{PLANS} stored plans ({feasible} of {} distinct real plans feasible); server time per \
         page, request to last byte on loopback:",
        real.len()
    );
    println!(
        "{:<28} {:>10} {:>10} {:>10}",
        "page", "first ms", "median ms", "max ms"
    );
    let mut worst_first: f64 = 0.0;
    for path in &pages {
        let first = time_page(&client, &base, path).await;
        let mut times = Vec::with_capacity(REPEATS);
        for _ in 0..REPEATS {
            times.push(time_page(&client, &base, path).await);
        }
        times.sort_by(f64::total_cmp);
        let label = if path.len() > 28 {
            format!("{}…", &path[..27])
        } else {
            path.clone()
        };
        println!(
            "{label:<28} {first:>10.1} {:>10.1} {:>10.1}",
            times[REPEATS / 2],
            times[REPEATS - 1]
        );
        if path == "/" || path == "/ui/plans" {
            worst_first = worst_first.max(first);
        }
    }
    println!(
        "first dashboard page (the slower of / and /ui/plans, fresh service): {worst_first:.1} ms \
         (budget {BUDGET_MS} ms: {})",
        if worst_first <= BUDGET_MS {
            "met"
        } else {
            "MISSED"
        }
    );
    Ok(())
}
