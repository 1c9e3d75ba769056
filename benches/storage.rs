//! Issue 20's storage figures (run with `cargo bench --bench storage`, or in the dev profile
//! with `cargo test --bench storage`; it prints its own table):
//! - bytes one plan stores (plan, grasp and trajectory rows) before the compact trajectory
//!   layout (f64 points with velocities and accelerations, full-precision Cartesian paths) and
//!   after it, and the loss of the compact layout measured on real plans;
//! - the database size after 10,000 plans with the default retention (the periodic
//!   maintenance emulated every 500 plans: the retention sweep and a WAL checkpoint).
//!
//! The plans are real: a small synthetic study is mapped and trained over HTTP, plans are made
//! over HTTP, and the 10,000 are those plans' rows stored again through the plan use case's
//! store (so the bench measures storage, not planning).

#[path = "support/http.rs"]
mod http;

use std::time::{Duration, Instant};

use reachgrasp::app::App;
use reachgrasp::config::Config;
use reachgrasp::service::models::JointValues;
use reachgrasp::service::plans::{PlanRows, StoredPlan};
use reachgrasp::service::trajectories::{CreateTrajectory, GoalIn};
use reachgrasp::store::grasps::NewGrasp;
use reachgrasp::store::plans::NewPlan;
use reachgrasp::store::trajectories::{TrajectoryDraft, encode_points_exact};
use serde_json::{Value, json};

const ROBOT: &str = "wam_ihy";
const PLANS: usize = 10_000;
const MAINTENANCE_EVERY: usize = 500;

/// Bytes of every column of a plan's plan, grasp and trajectory rows.
async fn stored_bytes(pool: &sqlx::SqlitePool, plan: &str) -> i64 {
    let q = "SELECT \
        (SELECT length(id) + length(robot) + coalesce(length(model_id), 0) + length(grasp_id) \
          + coalesce(length(trajectory_id), 0) + coalesce(length(execution_id), 0) + 1 \
          + coalesce(length(reason), 0) + length(request) + length(timings) + length(created_at) \
          FROM plans WHERE id = ?1) + \
        (SELECT length(g.id) + length(g.robot) + coalesce(length(g.object_id), 0) + length(g.object) \
          + length(g.request) + length(g.result) + 1 + length(g.created_at) \
          FROM grasps g JOIN plans p ON p.grasp_id = g.id WHERE p.id = ?1) + \
        coalesce((SELECT length(t.id) + coalesce(length(t.model_id), 0) + length(t.robot) \
          + length(t.joint_names) + length(t.start) + length(t.goal) + length(t.points) \
          + coalesce(length(t.derivatives), 0) + 8 + length(t.request) + length(t.summary) \
          + length(t.created_at) \
          FROM trajectories t JOIN plans p ON p.trajectory_id = t.id WHERE p.id = ?1), 0)";
    sqlx::query_scalar(q)
        .bind(plan)
        .fetch_one(pool)
        .await
        .unwrap()
}

fn paths(summary: &str) -> Vec<f64> {
    let v: Value = serde_json::from_str(summary).unwrap();
    let mut out = Vec::new();
    for key in ["fingertip_paths", "elbow_paths"] {
        for p in v[key].as_array().unwrap() {
            for row in p["positions"].as_array().unwrap() {
                out.extend(row.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()));
            }
        }
    }
    out
}

fn file_len(path: &std::path::Path) -> u64 {
    std::fs::metadata(path).map(|m| m.len()).unwrap_or(0)
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
    let config = Config {
        bind: "127.0.0.1:0".parse()?,
        db: db.clone(),
        robots: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots"),
        log: "warn".into(),
        no_seed: true,
        // The bench runs the maintenance itself, at a fixed cadence in plans.
        maintenance_interval_secs: 24 * 3600,
        ..Config::default()
    };
    let retention = config.retention_max_count;
    let app = App::build(config).await?;
    let ctx = app.state().clone();
    let base = format!("http://{}", app.local_addr());
    tokio::spawn(app.run_until(std::future::pending()));
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(120))
        .build()?;

    let (model, start) = http::trained(&client, &base, ROBOT).await;

    // Real plans over HTTP.
    let mut bodies = vec![
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000001", "start": start,
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000002", "start": start,
               "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}]}),
    ];
    for (x, y) in [(0.45, -0.1), (0.5, 0.1), (0.55, 0.0)] {
        bodies.push(json!({"robot": ROBOT, "start": start,
            "object": {"name": "ball", "shape": {"type": "sphere", "radius": 0.033},
                       "position": [x, y, 0.033], "support": {"normal": [0, 0, 1], "offset": 0.0}},
            "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}));
    }
    let mut real: Vec<(StoredPlan, TrajectoryDraft)> = Vec::new();
    let (mut before_sum, mut after_sum) = (0i64, 0i64);
    let (mut max_q, mut max_dq, mut max_path) = (0f64, 0f64, 0f64);
    let mut points = 0usize;
    for body in &bodies {
        let res = client
            .post(format!("{base}/v1/plans"))
            .json(body)
            .send()
            .await?;
        anyhow::ensure!(res.status() == 201, "plan failed");
        let p: Value = res.json().await?;
        if p["feasible"] != true {
            continue;
        }
        let id = p["id"].as_str().unwrap();
        let stored = reachgrasp::service::plans::get(&ctx, id).await?;
        let traj = stored.trajectory.clone().unwrap();
        // The same trajectory again (deterministic), as the use case hands it to the store.
        let (draft, _) = reachgrasp::service::trajectories::compute(
            &ctx,
            &CreateTrajectory {
                model: model.clone(),
                start: JointValues {
                    joint_names: traj.joint_names.clone(),
                    positions: traj.start.clone(),
                },
                goal: GoalIn {
                    joint_names: Some(traj.joint_names.clone()),
                    positions: Some(traj.goal.clone()),
                    grasp: None,
                },
                duration: None,
                rate: None,
                obstacles: Vec::new(),
                approach_standoff: None,
            },
            None,
        )
        .await
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        anyhow::ensure!(
            draft.points.len() == traj.points.len(),
            "not the same trajectory"
        );
        let after = stored_bytes(&ctx.db, id).await;
        // Before: the f64 layout of every point, and the summary with full-precision paths.
        let n = draft.joint_names.len();
        let legacy_points = encode_points_exact(&draft.points, n)?.len() as i64;
        let (now_points, now_derivs): (i64, i64) = sqlx::query_as(
            "SELECT length(points), length(derivatives) FROM trajectories WHERE id = ?",
        )
        .bind(&traj.id)
        .fetch_one(&ctx.db)
        .await?;
        let before = after - now_points - now_derivs
            + legacy_points
            + (draft.summary.len() as i64 - traj.summary.len() as i64);
        before_sum += before;
        after_sum += after;
        for (a, b) in traj.points.iter().zip(&draft.points) {
            for (x, y) in a.positions.iter().zip(&b.positions) {
                max_q = max_q.max((x - y).abs());
            }
            for (x, y) in a
                .velocities
                .iter()
                .chain(&a.accelerations)
                .zip(b.velocities.iter().chain(&b.accelerations))
            {
                max_dq = max_dq.max((x - y).abs() / y.abs().max(1e-30));
            }
        }
        for (x, y) in paths(&traj.summary).iter().zip(paths(&draft.summary)) {
            max_path = max_path.max((x - y).abs());
        }
        points += traj.points.len();
        real.push((stored, draft));
    }
    anyhow::ensure!(!real.is_empty(), "no feasible plan");
    let k = real.len() as i64;
    println!(
        "real plans: {k} feasible of {}, {:.0} trajectory points each on average",
        bodies.len(),
        points as f64 / k as f64
    );
    println!(
        "bytes per plan (plan + grasp + trajectory rows): before {} B, after {} B ({:.0} % less)",
        before_sum / k,
        after_sum / k,
        100.0 * (1.0 - after_sum as f64 / before_sum as f64)
    );
    println!(
        "compaction loss: max abs joint position error {max_q:e} rad (times, start, goal exact); \
         velocities/accelerations max relative error {max_dq:.2e} (never larger in magnitude); \
         Cartesian paths max abs error {:.2} µm (each path's ends exact)",
        max_path * 1e6
    );

    // 10,000 plans with the default retention.
    let t0 = Instant::now();
    let mut peak_db = 0u64;
    for i in 0..PLANS {
        let (s, draft) = &real[i % real.len()];
        let rows = PlanRows {
            grasp: NewGrasp {
                robot: s.grasp.robot.clone(),
                object_id: s.grasp.object_id.clone(),
                object: s.grasp.object.clone(),
                request: s.grasp.request.clone(),
                result: s.grasp.result.clone(),
                feasible: s.grasp.feasible,
            },
            trajectory: Some(draft.clone()),
            execution: None,
            plan: NewPlan {
                robot: s.plan.robot.clone(),
                model_id: s.plan.model_id.clone(),
                grasp_id: String::new(),
                trajectory_id: None,
                execution_id: None,
                feasible: true,
                reason: None,
                request: s.plan.request.clone(),
                timings: s.plan.timings.clone(),
            },
        };
        reachgrasp::service::plans::store(&ctx, rows).await?;
        if (i + 1) % MAINTENANCE_EVERY == 0 {
            peak_db = peak_db.max(file_len(&db) + file_len(&db.with_extension("db-wal")));
            reachgrasp::service::storage::maintain(&ctx).await?;
        }
    }
    reachgrasp::service::storage::maintain(&ctx).await?;
    let secs = t0.elapsed().as_secs_f64();
    let plans: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM plans")
        .fetch_one(&ctx.db)
        .await?;
    let (pages, free): (i64, i64) = sqlx::query_as(
        "SELECT (SELECT page_count FROM pragma_page_count()), (SELECT freelist_count FROM pragma_freelist_count())",
    )
    .fetch_one(&ctx.db)
    .await?;
    let size = file_len(&db);
    let wal = file_len(&db.with_extension("db-wal"));
    println!(
        "after {PLANS} plans ({secs:.0} s) with the default retention (newest {retention}): \
         {plans} plans kept; database {:.1} MB ({pages} pages, {free} free), WAL {:.1} MB; \
         largest database + WAL seen {:.1} MB; without retention the plans alone would take \
         about {:.0} MB",
        size as f64 / 1e6,
        wal as f64 / 1e6,
        peak_db as f64 / 1e6,
        (after_sum / k) as f64 * PLANS as f64 / 1e6
    );
    Ok(())
}
