//! `/v1/plans`: a small study mapped and trained through the API, then plans: stored and linked,
//! unreachable objects answered with `feasible: false`, execution queued without a worker, and
//! every bad input refused with nothing stored.

use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, spawn_app_with, strings, trained};

const ROBOT: &str = "wam_ihy";

async fn app() -> TestApp {
    spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await
}

fn zeros(names: &Value) -> Value {
    let n = names.as_array().unwrap().len();
    json!({"joint_names": names, "positions": vec![0.0; n]})
}

fn ball_plan(start: &Value) -> Value {
    json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000001", "start": start,
           "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_link_grasp_trajectory_and_execution_and_refuse_bad_input() {
    let app = app().await;
    let robot: Value = app
        .get(&format!("/v1/robots/{ROBOT}"))
        .await
        .json()
        .await
        .unwrap();
    let start = zeros(&robot["joint_names"]);

    // No model yet (and no seeding in tests): the request names the missing piece.
    let body = assert_problem(
        app.post_json("/v1/plans", &ball_plan(&start)).await,
        422,
        "validation",
    )
    .await;
    assert_eq!(body["errors"][0]["path"], "$.model", "{body}");

    // A small study, mapped and trained through the API; plans start where the
    // demonstrations started (inside the model's workspace).
    let (model, start) = trained(&app, ROBOT).await;

    // A plan with the default model: grasp, trajectory ending exactly at it, all stored.
    let res = app.post_json("/v1/plans", &ball_plan(&start)).await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let location = res.headers()["location"].to_str().unwrap().to_owned();
    let plan: Value = res.json().await.unwrap();
    assert_eq!(plan["model_id"], model);
    assert!(plan["grasp"]["id"].is_string());
    if plan["feasible"] == true {
        let t = &plan["trajectory"];
        let points = t["points"].as_array().unwrap();
        let last = points.last().unwrap()["positions"].as_array().unwrap();
        let order: Vec<&str> = strings(&t["joint_names"]);
        let result = &plan["grasp"]["result"];
        for j in result["q_arm"]
            .as_array()
            .unwrap()
            .iter()
            .chain(result["q_hand"].as_array().unwrap())
        {
            let i = order.iter().position(|n| *n == j["name"]).unwrap();
            let v = last[i].as_f64().unwrap();
            assert!((v - j["value"].as_f64().unwrap()).abs() < 1e-9, "{j}");
        }
        assert_eq!(points[0]["positions"], start["positions"]);
        // The exact clearance along the path, in the grasp's scene. Its end is the grasp, in
        // the closing phase (where the pads may touch the object, reported as the closing
        // contact), so that is no larger than the grasp's own exact pad distances there.
        let c = &t["report"]["clearance"];
        assert_eq!(c["complete"], true, "{c}");
        assert!(c["collision_free"].is_boolean(), "{c}");
        let duration = t["report"]["duration"].as_f64().unwrap();
        let at = c["closest"]["time_s"].as_f64().unwrap();
        assert!((0.0..=duration + 1e-9).contains(&at), "{c}");
        let pad = result["contacts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|k| k["surface_distance"].as_f64().unwrap())
            .fold(f64::INFINITY, f64::min);
        assert!(
            c["closing_contact"]["distance_m"].as_f64().unwrap() <= pad + 1e-9,
            "{c} {pad}"
        );
        let closing = c["closing_from_s"].as_f64().unwrap();
        assert!((0.85 * duration..=0.9 * duration).contains(&closing), "{c}");
        assert!(c["support"]["distance_m"].is_number(), "{c}");
    } else {
        // A model of 15 demonstrations may not cover the optimiser's grasp; the plan says so.
        assert!(plan["trajectory"].is_null());
        assert!(plan["reason"].as_str().unwrap().contains("goal"), "{plan}");
    }
    let fetched: Value = app.get(&location).await.json().await.unwrap();
    assert_eq!(fetched["id"], plan["id"]);
    assert_eq!(fetched["grasp"]["id"], plan["grasp"]["id"]);
    assert_eq!(fetched["trajectory"]["id"], plan["trajectory"]["id"]);
    assert_eq!(app.total("/v1/plans").await, 1);

    // An object out of reach: a stored plan with feasible false and the reason, no trajectory.
    let far = json!({"robot": ROBOT, "start": start,
        "object": {"name": "far ball", "shape": {"type": "sphere", "radius": 0.033},
                   "position": [3.0, 0.0, 0.033]},
        "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]});
    let res = app.post_json("/v1/plans", &far).await;
    assert_eq!(res.status(), 201);
    let p: Value = res.json().await.unwrap();
    assert_eq!(p["feasible"], false);
    assert!(p["trajectory"].is_null());
    assert!(!p["reason"].as_str().unwrap().is_empty());
    assert_eq!(app.total("/v1/plans").await, 2);

    // Execution asked with no worker connected: the plan is stored, the execution waits queued.
    if plan["feasible"] == true {
        let mut body = ball_plan(&start);
        body["execute"] = json!(true);
        let res = app.post_json("/v1/plans", &body).await;
        assert_eq!(res.status(), 201);
        let p: Value = res.json().await.unwrap();
        let exec = p["execution_id"].as_str().expect("execution id");
        let e: Value = app
            .get(&format!("/v1/executions/{exec}"))
            .await
            .json()
            .await
            .unwrap();
        assert_eq!(e["state"], "queued", "{e}");
    }

    // With the base turned 2 rad the start is outside this small study's workspace (3.46 from
    // its centre, radius 2.55, when written): an open-loop plan enters the workspace along the
    // joint line first (reported); a closed-loop execution is refused at the start, its law
    // being certified inside the workspace only.
    if plan["feasible"] == true {
        let mut turned = zeros(&robot["joint_names"]);
        turned["positions"][0] = json!(2.0);
        let res = app.post_json("/v1/plans", &ball_plan(&turned)).await;
        assert_eq!(res.status(), 201);
        let p: Value = res.json().await.unwrap();
        let entry = &p["trajectory"]["report"]["workspace_entry"];
        assert!(
            entry["line_fraction"].as_f64().unwrap() > 0.0,
            "{}",
            p["reason"]
        );
        assert_eq!(
            p["trajectory"]["points"][0]["positions"],
            turned["positions"]
        );
        // In closed loop the worker runs this path (entry line included), so the plan is the
        // same and queues it with the path (it used to be a 422: the bare law has no entry).
        let mut body = ball_plan(&turned);
        body["execute"] = json!(true);
        body["mode"] = json!("closed_loop");
        let res = app.post_json("/v1/plans", &body).await;
        assert_eq!(res.status(), 201);
        let closed: Value = res.json().await.unwrap();
        assert_eq!(closed["feasible"], true, "{}", closed["reason"]);
        assert_eq!(
            closed["trajectory"]["report"]["workspace_entry"]["line_fraction"],
            entry["line_fraction"]
        );
        let id = closed["execution_id"].as_str().expect("queued");
        let exec: Value = app
            .get(&format!("/v1/executions/{id}"))
            .await
            .json()
            .await
            .unwrap();
        assert_eq!(exec["mode"], "closed_loop", "{exec}");
    }

    // Bad input: 4xx naming the field, nothing stored.
    let plans = app.total("/v1/plans").await;
    let trajectories = app.total("/v1/trajectories").await;
    let mut cases: Vec<(Value, &str)> = Vec::new();
    let mut b = ball_plan(&start);
    b["robot"] = json!("no_such_robot");
    cases.push((b, "$.robot"));
    let mut b = ball_plan(&start);
    b["object_id"] = json!("00000000-0000-4000-8000-0000000000ff");
    cases.push((b, "$.object_id"));
    let mut b = ball_plan(&start);
    b["model"] = json!("no-such-model");
    cases.push((b, "$.model"));
    let mut b = ball_plan(&start);
    b["start"]["positions"][1] = json!(9.0);
    cases.push((b, "$.start.positions[1]"));
    let mut b = ball_plan(&start);
    b["start"]["joint_names"][0] = json!("elbow_of_nobody");
    cases.push((b, "$.start.joint_names[0]"));
    let mut b = ball_plan(&start);
    b["start"] = json!("current");
    cases.push((b, "$.start"));
    let mut b = ball_plan(&start);
    b["start"] = json!("home");
    cases.push((b, "$.start"));
    let mut b = ball_plan(&start);
    b["worker"] = json!("bad name!");
    cases.push((b, "$.worker"));
    let mut b = ball_plan(&start);
    b["task_directions"][0]["direction"] = json!([0, 0, 0]);
    cases.push((b, "$.task_directions[0].direction"));
    for (body, path) in cases {
        let res = app.post_json("/v1/plans", &body).await;
        let status = res.status().as_u16();
        assert!(status == 422 || status == 404, "{path}: status {status}");
        let problem: Value = res.json().await.unwrap();
        let paths: Vec<&str> = problem["errors"]
            .as_array()
            .map(|e| e.iter().map(|f| f["path"].as_str().unwrap()).collect())
            .unwrap_or_default();
        assert!(paths.contains(&path), "{path} not in {problem}");
    }
    assert_eq!(app.total("/v1/plans").await, plans);
    assert_eq!(app.total("/v1/trajectories").await, trajectories);
    assert_problem(app.get("/v1/plans/nope").await, 404, "not-found").await;
}
