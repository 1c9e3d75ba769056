//! First start and the README quickstart, end to end: seeding on an empty database (503
//! `not-ready` while it runs), the quickstart's curl calls exactly as the README writes them
//! against the live service and a real simulated worker, the executed plan, and a second start
//! that reuses what is stored.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use reachgrasp::app::App;
use reachgrasp::config::Config;
use serde_json::Value;
use tokio::process::Command;

use crate::helpers::{TestApp, spawn_app_with};

const TOKEN: &str = "lab-token";
/// The address the README's calls use.
const README_HOST: &str = "localhost:8080";

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The curl lines of the README block marked `quickstart-calls`.
fn quickstart_calls() -> Vec<String> {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let after = readme
        .split("<!-- quickstart-calls")
        .nth(1)
        .expect("README has the quickstart-calls marker");
    let block = after
        .split("```sh\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("a sh block follows the marker");
    let calls: Vec<String> = block
        .lines()
        .map(str::trim)
        .filter(|l| l.starts_with("curl "))
        .map(str::to_owned)
        .collect();
    assert!(calls.len() >= 5, "quickstart calls: {calls:?}");
    calls
}

async fn get_json(client: &reqwest::Client, url: &str) -> Value {
    client.get(url).send().await.unwrap().json().await.unwrap()
}

/// Polls `check` every 250 ms until it yields a value, for at most `limit`.
async fn wait_for<T, F, Fut>(what: &str, limit: Duration, mut check: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let start = Instant::now();
    loop {
        if let Some(v) = check().await {
            return v;
        }
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

async fn default_model(client: &reqwest::Client, base: &str, robot: &str) -> Option<String> {
    let list = get_json(client, &format!("{base}/v1/models?robot={robot}")).await;
    if let Some(failed) = list["items"]
        .as_array()?
        .iter()
        .find(|m| m["status"] == "failed")
    {
        panic!("seeding failed to train {robot}: {failed}");
    }
    list["items"].as_array()?.iter().find_map(|m| {
        (m["status"] == "succeeded" && m["default"] == true)
            .then(|| m["id"].as_str().unwrap().to_owned())
    })
}

async fn run_call(line: &str, host: &str) -> (bool, String) {
    let line = line.replace(README_HOST, host);
    let out = Command::new("sh")
        .arg("-c")
        .arg(&line)
        .current_dir(root())
        .stdin(Stdio::null())
        .output()
        .await
        .expect("sh runs (curl must be installed)");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn first_start_seeds_and_the_readme_quickstart_plans_and_executes() {
    let app = spawn_app_with(|c| {
        c.robots = root().join("robots");
        c.no_seed = false;
        c.bridge_token = Some(TOKEN.into());
    })
    .await;
    let base = app.base_url.clone();
    let host = base.trim_start_matches("http://").to_owned();
    let client = app.client.clone();

    // While seeding runs, a plan that needs the default model is 503 with the job to watch.
    let body: Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("examples/plan-bottle.json")).unwrap(),
    )
    .unwrap();
    let res = app.post_json("/v1/plans", &body).await;
    assert_eq!(res.status(), 503);
    let problem: Value = res.json().await.unwrap();
    assert_eq!(problem["type"], "urn:reachgrasp:problem:not-ready");
    let job = problem["job_id"].as_str().expect("job_id").to_owned();
    let job: Value = get_json(&client, &format!("{base}/v1/jobs/{job}")).await;
    assert!(job["kind"].is_string(), "{job}");

    // The status says so too: seeding runs, each bundled robot waits for a real job.
    let status = get_json(&client, &format!("{base}/v1/status")).await;
    assert_eq!(status["seeding"]["state"], "running", "{status}");
    assert_eq!(status["seeding"]["bundled"], 6, "{status}");
    let pending = status["seeding"]["pending"].as_array().unwrap();
    assert!(!pending.is_empty(), "{status}");
    for step in pending {
        let job = get_json(
            &client,
            &format!("{base}/v1/jobs/{}", step["job_id"].as_str().unwrap()),
        )
        .await;
        assert_eq!(job["kind"], step["kind"], "{step} vs {job}");
    }

    // Seeding finishes with a default model for every bundled system.
    let robots = [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ];
    let started = Instant::now();
    for robot in robots {
        wait_for(
            &format!("the default model of {robot}"),
            Duration::from_secs(900),
            || default_model(&client, &base, robot),
        )
        .await;
    }
    eprintln!(
        "seeding finished after {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let status = wait_for(
        "seeding done in /v1/status",
        Duration::from_secs(60),
        || async {
            let s = get_json(&client, &format!("{base}/v1/status")).await;
            (s["seeding"]["state"] == "done").then_some(s)
        },
    )
    .await;
    assert_eq!(status["seeding"]["trained"], 6, "{status}");
    let mut defaults = Vec::new();
    for robot in robots {
        let r = status["robots"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["id"] == robot)
            .unwrap_or_else(|| panic!("{robot} in {status}"));
        let model = &r["default_model"];
        assert_eq!(model["state"], "trained", "{r}");
        // "since when" is when the model's training job finished
        let id = model["id"].as_str().unwrap();
        let stored = get_json(&client, &format!("{base}/v1/models/{id}")).await;
        let job = get_json(
            &client,
            &format!("{base}/v1/jobs/{}", stored["job_id"].as_str().unwrap()),
        )
        .await;
        assert_eq!(model["trained_at"], job["finished_at"], "{r} vs {job}");
        defaults.push((robot, id.to_owned()));
    }
    default_models_converge_from_random_pairs(&app, &defaults).await;

    // With the seeded models, the pa10_ob4f bottle plan (force along z) from the zero posture
    // sweeps the index finger through the bottle when it runs into the grasp directly
    // (measured: its distal link 31.3 mm deep). Left to the service, the plan gets the approach
    // phase instead, with its straight final approach, and is collision-free; asked for no
    // approach phase, it stays the collision it is. (The grasp's seed is set: left to the
    // service, a grasp without a clear motion is replaced.)
    let bottle = "00000000-0000-4000-8000-000000000002";
    let plan = |standoff: Option<f64>| {
        let mut extra = serde_json::json!({"seed": 0});
        if let Some(s) = standoff {
            extra["approach_standoff"] = s.into();
        }
        zero_start_plan(&app, "pa10_ob4f", bottle, [0, 0, 1], "force", extra)
    };
    let direct = plan(Some(0.0)).await;
    assert_eq!(direct["feasible"], false, "{}", direct["reason"]);
    let hit = &direct["trajectory"]["report"]["clearance"]["object"];
    assert!(hit["distance_m"].as_f64().unwrap() < -1e-3, "{hit}");
    assert!(direct["trajectory"]["report"]["approach"].is_null());
    let chosen = plan(None).await;
    assert_eq!(chosen["feasible"], true, "{}", chosen["reason"]);
    let report = &chosen["trajectory"]["report"];
    assert_eq!(report["clearance"]["collision_free"], true, "{report}");
    let approach = &report["approach"];
    assert_eq!(approach["used"], true, "{approach}");
    assert_eq!(approach["straight_line"], true, "{approach}");
    let note = approach["note"].as_str().unwrap();
    assert!(
        note.contains("added because") && note.contains("inside 'bottle'"),
        "{note}"
    );

    // With the seeded pa10_t42 model, the bottle grasp of seed 0 (the default) for a force
    // along z has no collision-free motion from the zero posture (measured: a proximal finger
    // link inside the bottle). Left to the service, the plan drops it and takes seed 1's grasp;
    // with the seed set, the plan is that grasp's, infeasible.
    let bottle = "00000000-0000-4000-8000-000000000002";
    let bottle_plan = |seed: Option<u64>| {
        let extra = seed.map_or(serde_json::json!({}), |s| serde_json::json!({"seed": s}));
        zero_start_plan(&app, "pa10_t42", bottle, [0, 0, 1], "force", extra)
    };
    let pinned = bottle_plan(Some(0)).await;
    assert_eq!(pinned["feasible"], false, "{}", pinned["reason"]);
    assert!(
        pinned["reason"]
            .as_str()
            .unwrap()
            .contains("no collision-free motion"),
        "{}",
        pinned["reason"]
    );
    assert!(pinned["timings"]["rejected_grasps"].is_null());
    let chosen = bottle_plan(None).await;
    assert_eq!(chosen["feasible"], true, "{}", chosen["reason"]);
    assert_eq!(
        chosen["trajectory"]["report"]["clearance"]["collision_free"],
        true
    );
    let rejected = chosen["timings"]["rejected_grasps"].as_array().unwrap();
    assert_eq!(rejected.len(), 1, "{rejected:?}");
    assert_eq!(rejected[0]["seed"], 0);
    assert_eq!(rejected[0]["reason"], pinned["reason"]);
    assert_eq!(chosen["grasp"]["request"]["seed"], 1, "{}", chosen["grasp"]);
    // the plan's page lists the dropped grasp
    let page = client
        .get(format!(
            "{base}/ui/plans/{}",
            chosen["id"].as_str().unwrap()
        ))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        page.contains("grasps dropped") && page.contains("seed 0: no collision-free motion"),
        "the plan page does not list the dropped grasp"
    );

    // A slow motion in closed loop: the wam_t42 ball plan asked for 35 s. The worker allows its
    // 30 s to converge after the path's end; counted from the start, the plan's own run of the
    // law was cut off 0.19 rad short at 30 s and the plan was infeasible.
    let slow = zero_start_plan(
        &app,
        "wam_t42",
        "00000000-0000-4000-8000-000000000001",
        [0, 0, 1],
        "force",
        serde_json::json!({"duration": 35, "execute": true, "mode": "closed_loop"}),
    )
    .await;
    assert_eq!(slow["feasible"], true, "{}", slow["reason"]);
    let duration = slow["trajectory"]["report"]["duration"].as_f64().unwrap();
    assert!(duration > 34.9, "{duration}");
    assert!(slow["execution_id"].is_string(), "{slow}");

    // The README's worker, as the built binary.
    let mut worker = Command::new(env!("CARGO_BIN_EXE_reachgrasp"))
        .args(["bridge", "--sim", "--robot", "wam_ihy", "--token", TOKEN])
        .arg("--url")
        .arg(format!("ws://{host}/v1/bridges/connect"))
        .arg("--robots")
        .arg(root().join("robots"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    wait_for(
        "the worker to report its state",
        Duration::from_secs(60),
        || async {
            let list = get_json(&client, &format!("{base}/v1/bridges")).await;
            list["items"]
                .as_array()?
                .iter()
                .any(|w| {
                    w["robot"] == "wam_ihy"
                        && w["connected"] == true
                        && w["connection"]["positions"]
                            .as_array()
                            .is_some_and(|p| !p.is_empty())
                })
                .then_some(())
        },
    )
    .await;

    // Every call as written; the plans come back feasible, the ball plan with an execution.
    // Then the plans once more at once, while the first execution may still run: the ball plan
    // starts at `"current"`, where the robot will be after it, so both executions succeed.
    let calls = quickstart_calls();
    let again = calls.iter().filter(|l| l.contains("plan-")).cloned();
    let mut executions = Vec::new();
    for line in calls.clone().into_iter().chain(again) {
        let (ok, out) = run_call(&line, &host).await;
        assert!(ok, "`{line}` failed: {out}");
        let v: Value =
            serde_json::from_str(&out).unwrap_or_else(|e| panic!("`{line}`: {e}: {out}"));
        if line.contains("plan-") {
            assert_eq!(v["feasible"], true, "`{line}`: {}", v["reason"]);
            assert!(v["trajectory"]["points"].as_array().unwrap().len() > 10);
            assert!(v["grasp"]["result"]["feasible"] == true);
        }
        if line.contains("plan-ball") {
            executions.push(v["execution_id"].as_str().expect("execution id").to_owned());
        }
    }
    assert_eq!(executions.len(), 2, "the ball plan ran twice");
    for execution in &executions {
        let state = wait_for("the execution to end", Duration::from_secs(180), || async {
            let e = get_json(&client, &format!("{base}/v1/executions/{execution}")).await;
            let s = e["state"].as_str()?.to_owned();
            matches!(
                s.as_str(),
                "succeeded" | "failed" | "aborted" | "interrupted" | "cancelled"
            )
            .then_some(e)
        })
        .await;
        assert_eq!(state["state"], "succeeded", "{state}");
    }

    // A configuration far from where the robot is cannot be executed: 422 at the start, and
    // nothing is stored.
    let plans_before =
        get_json(&client, &format!("{base}/v1/plans?limit=1")).await["total"].clone();
    let mut far: Value = serde_json::from_str(
        &std::fs::read_to_string(root().join("examples/plan-bottle.json")).unwrap(),
    )
    .unwrap();
    far["execute"] = Value::Bool(true);
    far["start"]["positions"][3] = Value::from(2.0);
    let res = app.post_json("/v1/plans", &far).await;
    assert_eq!(res.status(), 422);
    let problem: Value = res.json().await.unwrap();
    let error = &problem["errors"][0];
    assert_eq!(error["path"], "$.start", "{problem}");
    let message = error["message"].as_str().unwrap();
    assert!(
        message.contains("start tolerance of 0.25 rad") && message.contains("\"current\""),
        "{message}"
    );
    let plans_after = get_json(&client, &format!("{base}/v1/plans?limit=1")).await["total"].clone();
    assert_eq!(plans_before, plans_after);
    worker.kill().await.unwrap();

    // A second start on the same database reuses the models: no seeding job is submitted.
    let db = app._dir.path().join("db/test.db");
    assert_reused(&db).await;
}

/// `POST /v1/plans` for `robot` from its zero posture, maximising `kind` along `direction` on
/// the stored `object`, with `extra`'s fields added to the body: the plan (201).
async fn zero_start_plan(
    app: &TestApp,
    robot: &str,
    object: &str,
    direction: [i32; 3],
    kind: &str,
    extra: Value,
) -> Value {
    let robot_doc: Value = app
        .get(&format!("/v1/robots/{robot}"))
        .await
        .json()
        .await
        .unwrap();
    let names = robot_doc["joint_names"].clone();
    let zero = vec![0.0; names.as_array().unwrap().len()];
    let mut body = serde_json::json!({"robot": robot, "object_id": object,
        "start": {"joint_names": names, "positions": zero},
        "task_directions": [{"direction": direction, "kind": kind, "goal": "maximize"}]});
    for (k, v) in extra.as_object().unwrap() {
        body[k] = v.clone();
    }
    let res = app.post_json("/v1/plans", &body).await;
    assert_eq!(res.status(), 201);
    res.json().await.unwrap()
}

async fn assert_reused(db: &Path) {
    let config = Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        db: db.to_owned(),
        robots: root().join("robots"),
        bridge_token: Some(TOKEN.into()),
        ..Config::default()
    };
    assert!(!config.no_seed);
    let app = App::build(config).await.unwrap();
    for robot in ["wam_ihy", "pa10_ob4f"] {
        assert!(
            app.state().seed.pending_job(robot).is_none(),
            "{robot} is being seeded again"
        );
    }
}

/// Issue 19's certificate claim on the seeded default models themselves: 10,000 random
/// (start, goal) pairs per system, each group's start uniform in 0.98 of its workspace ball and
/// its goal uniform in its certified goal region, integrated with the model's own flow settings.
/// Every flow must converge to within 1e-6 rad of its goal (PCA coordinates are orthonormal
/// joint-space coordinates, so that is the joint-space error on the manifold). The certificate
/// the models carry makes `γ` fall monotonically, so the pairs on which it rises are counted and
/// must be none: a rise would mean the stored certificate is wrong.
async fn default_models_converge_from_random_pairs(app: &TestApp, defaults: &[(&str, String)]) {
    use rand::{RngExt, SeedableRng};
    use reachgrasp::motion::{FlowPath, integrate_flow};
    use sqlx::sqlite::{SqliteConnectOptions, SqlitePoolOptions};

    let options = SqliteConnectOptions::new()
        .filename(app._dir.path().join("db/test.db"))
        .read_only(true);
    let pool = SqlitePoolOptions::new()
        .max_connections(1)
        .connect_with(options)
        .await
        .unwrap();
    for (robot, id) in defaults {
        let model = reachgrasp::store::models::load_model(&pool, id)
            .await
            .unwrap()
            .unwrap_or_else(|| panic!("{robot}: default model {id} stored"));
        let robot = robot.to_string();
        tokio::task::spawn_blocking(move || {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
            // uniform in a ball: a Gaussian direction, radius r·u^(1/d)
            let mut ball = |c: &[f64], r: f64| -> Vec<f64> {
                let d = c.len();
                let g: Vec<f64> = (0..d)
                    .map(|_| {
                        let (u1, u2): (f64, f64) =
                            (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
                        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
                    })
                    .collect();
                let norm = g.iter().map(|x| x * x).sum::<f64>().sqrt();
                let radius = r * rng.random_range(0.0f64..1.0).powf(1.0 / d as f64);
                c.iter()
                    .zip(&g)
                    .map(|(c, x)| c + radius * x / norm)
                    .collect()
            };
            let mut path = FlowPath::default();
            let (mut worst, mut rises, mut steps) = (0.0f64, 0usize, 0usize);
            for _ in 0..10_000 {
                for m in &model.manifolds {
                    let y0 = ball(&m.nf.center, 0.98 * m.nf.radius);
                    let yd = ball(&m.certificate.goal_center, m.certificate.goal_radius);
                    integrate_flow(&m.nf, &y0, &yd, &model.flow, &mut path);
                    assert!(
                        path.converged && path.final_error <= 1e-6,
                        "{robot}: from {y0:?} to {yd:?}: converged {}, error {}",
                        path.converged,
                        path.final_error
                    );
                    worst = worst.max(path.final_error);
                    steps = steps.max(path.steps);
                    rises += usize::from(path.gamma.windows(2).any(|w| w[1] > w[0]));
                }
            }
            eprintln!(
                "{robot}: 10,000 pairs converged, largest final error {worst:.2e}, most steps \
                 {steps}, flows on which γ rose {rises}"
            );
            assert_eq!(
                rises, 0,
                "{robot}: γ rose although the certificate says it cannot"
            );
        })
        .await
        .unwrap();
    }
}
