//! The approach phase of a plan (issue 18, item 3): a pre-grasp standoff along the approach
//! direction with the hand opened, checked against the service's own forward kinematics, and
//! its request field validated with nothing stored; and a robot's default-model state, which
//! says whether a plan may leave out `model`.

use serde_json::{Value, json};

use crate::helpers::{assert_problem, spawn_app_with, trained};

const ROBOT: &str = "wam_ihy";
const BALL: &str = "00000000-0000-4000-8000-000000000001";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plan_with_a_standoff_passes_a_pre_grasp_behind_its_grasp() {
    let app = spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await;
    // A robot says whether plans may leave out `model`: not before a model is trained (this
    // app does no first-start seeding), and then with the model they will use.
    let default_model = || async {
        let v: Value = app
            .get(&format!("/v1/robots/{ROBOT}"))
            .await
            .json()
            .await
            .unwrap();
        v["default_model"].clone()
    };
    let robots_page = || async { app.get("/ui/robots").await.text().await.unwrap() };
    assert_eq!(default_model().await["state"], "none");
    assert!(!robots_page().await.contains("model trained"));
    let (model, start) = trained(&app, ROBOT).await;
    let after = default_model().await;
    assert_eq!(after["state"], "trained", "{after}");
    assert_eq!(after["id"], model.as_str(), "{after}");
    // the dashboard's robot cards say the same
    let page = robots_page().await;
    assert!(page.contains(&format!("<b>{ROBOT}</b>")) && page.contains("model trained"));
    assert!(page.contains("no model yet"));
    let body = |standoff: Value| {
        json!({"robot": ROBOT, "object_id": BALL, "start": start, "approach_standoff": standoff,
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]})
    };

    // Out of range or not a number: 422 at the field, nothing stored.
    let before = app.total("/v1/plans").await;
    for bad in [json!(-0.01), json!(0.3), json!("far")] {
        let problem = assert_problem(
            app.post_json("/v1/plans", &body(bad)).await,
            422,
            "validation",
        )
        .await;
        assert_eq!(
            problem["errors"][0]["path"], "$.approach_standoff",
            "{problem}"
        );
    }
    assert_eq!(app.total("/v1/plans").await, before);

    // Without a standoff there is no approach phase.
    let direct: Value = app
        .post_json("/v1/plans", &body(json!(0.0)))
        .await
        .json()
        .await
        .unwrap();
    assert!(
        direct["trajectory"]["report"]["approach"].is_null(),
        "{direct}"
    );

    let res = app.post_json("/v1/plans", &body(json!(0.06))).await;
    assert_eq!(res.status(), 201);
    let plan: Value = res.json().await.unwrap();
    assert_eq!(plan["feasible"], true, "{plan}");
    let traj = &plan["trajectory"];
    let approach = &traj["report"]["approach"];
    assert_eq!(approach["used"], true, "{approach}");
    let standoff = approach["standoff_m"].as_f64().unwrap();
    assert!((0.03..=0.12).contains(&standoff), "{approach}");
    assert_eq!(
        traj["report"]["clearance"]["collision_free"], true,
        "{traj}"
    );

    // The pre-grasp's wrist (the grasp frame) sits `standoff_m` back along `direction` from the
    // grasp's, nearly as oriented, by the service's forward kinematics of both configurations.
    let robot: Value = app
        .get(&format!("/v1/robots/{ROBOT}"))
        .await
        .json()
        .await
        .unwrap();
    let wrist = robot["wrist_frame"].as_str().unwrap().to_owned();
    let tips: Vec<String> = robot["fingers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["tip_frame"].as_str().unwrap().to_owned())
        .collect();
    let names = traj["joint_names"].clone();
    // position and orientation of each of `frames` at `q`, by the service's FK
    let fk = |q: Value, frames: Vec<String>| {
        let body = json!({"joint_names": names, "positions": q, "frames": frames});
        let app = &app;
        async move {
            let v: Value = app
                .post_json(&format!("/v1/robots/{ROBOT}/fk"), &body)
                .await
                .json()
                .await
                .unwrap();
            let get = |f: &Value, k: &str, n: usize| -> Vec<f64> {
                (0..n).map(|i| f[k][i].as_f64().unwrap()).collect()
            };
            v["frames"]
                .as_array()
                .unwrap()
                .iter()
                .map(|f| (get(f, "position", 3), get(f, "orientation", 4)))
                .collect::<Vec<_>>()
        }
    };
    let points = traj["points"].as_array().unwrap();
    let grasp_q = points.last().unwrap()["positions"].clone();
    let pre_q = approach["pre_grasp"].clone();
    let (at_grasp, turn_grasp) = fk(grasp_q.clone(), vec![wrist.clone()]).await.remove(0);
    let (at_pre, turn_pre) = fk(pre_q.clone(), vec![wrist]).await.remove(0);
    let dir: Vec<f64> = (0..3)
        .map(|k| approach["direction"][k].as_f64().unwrap())
        .collect();
    let moved: Vec<f64> = (0..3).map(|k| at_pre[k] - at_grasp[k]).collect();
    let along: f64 = (0..3).map(|k| moved[k] * dir[k]).sum();
    let across = (0..3)
        .map(|k| (moved[k] - along * dir[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!((along - standoff).abs() < 1e-9, "{along} vs {standoff}");
    assert!(across <= 0.5 * along, "{across} beside {along}");
    let cos: f64 = (0..4).map(|k| turn_grasp[k] * turn_pre[k]).sum();
    assert!(
        2.0 * cos.abs().min(1.0).acos() <= 0.1 + 1e-9,
        "{turn_grasp:?} {turn_pre:?}"
    );
    // the hand is open wider there: its fingertips spread further apart than at the grasp
    let spread = |q: Value| {
        let frames = fk(q, tips.clone());
        async move {
            let p = frames.await;
            let mut s = 0.0;
            for a in 0..p.len() {
                for b in a + 1..p.len() {
                    s += (0..3)
                        .map(|k| (p[a].0[k] - p[b].0[k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                }
            }
            s
        }
    };
    let (open, closed) = (spread(pre_q).await, spread(grasp_q).await);
    assert!(open > closed, "{open} vs {closed}");

    // The trajectory's dashboard page shows the verdict and the approach.
    let page = app
        .get(&format!(
            "/ui/trajectories/{}",
            traj["id"].as_str().unwrap()
        ))
        .await
        .text()
        .await
        .unwrap();
    for want in [
        "Timing and clearance",
        "collision-free</dt><dd>yes",
        "pre-grasp",
    ] {
        assert!(page.contains(want), "{want} not on the page");
    }
}
