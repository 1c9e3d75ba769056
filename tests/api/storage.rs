//! Bounded storage (issue 20): deleting plans and trajectories with what they own, retention,
//! and a full database (507, nothing lost, recovery when space returns).

use std::time::Duration;

use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, field_strings, spawn_app_with, trained};

const ROBOT: &str = "wam_ihy";

fn robots() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
}

/// Plan requests at reachable placements (as `benches/plans.rs`).
fn plan_requests(start: &Value) -> Vec<Value> {
    let mut out = vec![
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000001", "start": start,
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000002", "start": start,
               "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}]}),
    ];
    for (x, y) in [(0.45, -0.1), (0.5, 0.1), (0.55, 0.0)] {
        out.push(json!({"robot": ROBOT, "start": start,
            "object": {"name": "ball", "shape": {"type": "sphere", "radius": 0.033},
                       "position": [x, y, 0.033], "support": {"normal": [0, 0, 1], "offset": 0.0}},
            "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}));
    }
    out
}

/// The first plan request that gives a feasible plan (with a trajectory).
async fn feasible_request(app: &TestApp, start: &Value) -> Value {
    for body in plan_requests(start) {
        let res = app.post_json("/v1/plans", &body).await;
        assert_eq!(res.status(), 201);
        let p: Value = res.json().await.unwrap();
        if p["feasible"] == true {
            return body;
        }
    }
    panic!("no reachable plan among the requests");
}

async fn status_of(app: &TestApp, path: &str) -> u16 {
    app.get(path).await.status().as_u16()
}

async fn delete(app: &TestApp, path: &str) -> reqwest::Response {
    app.client.delete(app.url(path)).send().await.unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deleting_a_plan_deletes_what_it_owns_once_its_execution_has_finished() {
    let app = spawn_app_with(|c| c.robots = robots()).await;
    let (model, start) = trained(&app, ROBOT).await;
    let mut body = feasible_request(&app, &start).await;
    body["execute"] = json!(true);
    let res = app.post_json("/v1/plans", &body).await;
    assert_eq!(res.status(), 201);
    let plan: Value = res.json().await.unwrap();
    let id = plan["id"].as_str().unwrap();
    let grasp = plan["grasp"]["id"].as_str().unwrap();
    let trajectory = plan["trajectory"]["id"].as_str().unwrap();
    let execution = plan["execution_id"].as_str().unwrap();
    let plans_before = app.total("/v1/plans").await;

    // No worker: the execution waits queued, so neither the plan nor its trajectory can go.
    let p = assert_problem(
        delete(&app, &format!("/v1/plans/{id}")).await,
        409,
        "conflict",
    )
    .await;
    assert!(p["detail"].as_str().unwrap().contains(execution), "{p}");
    let p = assert_problem(
        delete(&app, &format!("/v1/trajectories/{trajectory}")).await,
        409,
        "conflict",
    )
    .await;
    assert!(p["detail"].as_str().unwrap().contains(id), "{p}");
    assert_eq!(status_of(&app, &format!("/v1/plans/{id}")).await, 200);
    assert_eq!(
        status_of(&app, &format!("/v1/executions/{execution}")).await,
        200
    );

    // Cancelled, it has finished: the plan goes with its grasp, trajectory and execution.
    let res = app
        .post_json(&format!("/v1/executions/{execution}/cancel"), &json!({}))
        .await;
    assert!(res.status().is_success(), "{}", res.status());
    for _ in 0..100 {
        let e: Value = app
            .get(&format!("/v1/executions/{execution}"))
            .await
            .json()
            .await
            .unwrap();
        if e["state"] != "queued" && e["state"] != "running" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let res = delete(&app, &format!("/v1/plans/{id}")).await;
    assert_eq!(res.status(), 204);
    assert_eq!(status_of(&app, &format!("/v1/plans/{id}")).await, 404);
    assert_eq!(status_of(&app, &format!("/v1/grasps/{grasp}")).await, 404);
    assert_eq!(
        status_of(&app, &format!("/v1/trajectories/{trajectory}")).await,
        404
    );
    assert_eq!(
        status_of(&app, &format!("/v1/executions/{execution}")).await,
        404
    );
    assert_eq!(app.total("/v1/plans").await, plans_before - 1);
    assert_problem(
        delete(&app, &format!("/v1/plans/{id}")).await,
        404,
        "not-found",
    )
    .await;

    // A trajectory no plan owns is deleted on its own; the other plans are untouched.
    let goal = &plan["trajectory"]["points"]
        .as_array()
        .unwrap()
        .last()
        .unwrap()["positions"];
    let res = app
        .post_json(
            "/v1/trajectories",
            &json!({"model": model, "start": start,
                    "goal": {"joint_names": plan["trajectory"]["joint_names"], "positions": goal}}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let t: Value = res.json().await.unwrap();
    let tid = t["id"].as_str().unwrap();
    assert_eq!(
        delete(&app, &format!("/v1/trajectories/{tid}"))
            .await
            .status(),
        204
    );
    assert_eq!(
        status_of(&app, &format!("/v1/trajectories/{tid}")).await,
        404
    );
    assert_problem(
        delete(&app, "/v1/trajectories/nope").await,
        404,
        "not-found",
    )
    .await;
    assert_eq!(app.total("/v1/plans").await, plans_before - 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retention_keeps_the_newest_plans_and_never_what_a_queued_execution_needs() {
    let app = spawn_app_with(|c| {
        c.robots = robots();
        c.retention_max_count = 2;
        // Not before the plans are made (the test triggers the runs below by waiting).
        c.maintenance_interval_secs = 1;
    })
    .await;
    let (_, start) = trained(&app, ROBOT).await;
    let body = feasible_request(&app, &start).await;
    // The oldest kept plan: its execution is queued (no worker).
    let mut queued = body.clone();
    queued["execute"] = json!(true);
    let res = app.post_json("/v1/plans", &queued).await;
    let kept: Value = res.json().await.unwrap();
    let kept_id = kept["id"].as_str().unwrap().to_owned();
    let mut newest = Vec::new();
    for _ in 0..3 {
        let p: Value = app
            .post_json("/v1/plans", &body)
            .await
            .json()
            .await
            .unwrap();
        newest.push(p["id"].as_str().unwrap().to_owned());
    }
    // Maintenance runs every second: wait (bounded) for the sweep.
    let mut plans = i64::MAX;
    for _ in 0..100 {
        plans = app.total("/v1/plans").await;
        if plans <= 3 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // The newest two, and the one whose execution is still queued (never deleted).
    assert_eq!(plans, 3);
    let list: Value = app.get("/v1/plans").await.json().await.unwrap();
    let ids: Vec<&str> = field_strings(&list["items"], "id");
    assert!(
        ids.contains(&newest[1].as_str()) && ids.contains(&newest[2].as_str()),
        "{list}"
    );
    assert!(ids.contains(&kept_id.as_str()), "{list}");
    let exec = kept["execution_id"].as_str().unwrap();
    assert_eq!(
        status_of(&app, &format!("/v1/executions/{exec}")).await,
        200
    );
    // What the expired plans owned went with them: only the kept plans' trajectories remain.
    assert_eq!(app.total("/v1/trajectories").await, 3);
}

/// A mesh object of `k` stacked tetrahedra-free boxes: a closed box mesh with `k` rings, so the
/// stored spec grows with `k` (a few kB each).
fn tall_box(name: &str, k: usize) -> Value {
    let mut vertices = Vec::new();
    for i in 0..=k {
        let z = 0.1 * i as f64 / k as f64;
        for (x, y) in [(0.0, 0.0), (0.03, 0.0), (0.03, 0.03), (0.0, 0.03)] {
            vertices.push(json!([x, y, z]));
        }
    }
    let mut triangles = vec![json!([0, 2, 1]), json!([0, 3, 2])];
    for i in 0..k {
        let (a, b) = (4 * i, 4 * (i + 1));
        for s in 0..4 {
            let (p, q) = (a + s, a + (s + 1) % 4);
            let (r, t) = (b + s, b + (s + 1) % 4);
            triangles.push(json!([p, q, t]));
            triangles.push(json!([p, t, r]));
        }
    }
    let top = 4 * k;
    triangles.push(json!([top, top + 1, top + 2]));
    triangles.push(json!([top, top + 2, top + 3]));
    json!({"name": name, "position": [0.5, 0.0, 0.05],
           "shape": {"type": "mesh", "vertices": vertices, "triangles": triangles}})
}

async fn objects(app: &TestApp) -> Vec<Value> {
    app.get("/v1/objects").await.json().await.unwrap()
}

#[tokio::test]
async fn a_full_database_is_507_loses_nothing_and_recovers_when_space_returns() {
    // The size of an empty database with its migrations, then a cap 256 kB above it.
    let first = spawn_app_with(|_| {}).await;
    let db = first._dir.path().join("db/test.db");
    let pool = reachgrasp::store::connect(&db).await.unwrap();
    // (its logical size: `max_page_count` caps pages, and the file alone misses whatever the
    // WAL still holds while the first app's connections keep a checkpoint from completing)
    let pages: i64 = sqlx::query_scalar("PRAGMA page_count")
        .fetch_one(&pool)
        .await
        .unwrap();
    let page_size: i64 = sqlx::query_scalar("PRAGMA page_size")
        .fetch_one(&pool)
        .await
        .unwrap();
    let empty = (pages * page_size) as u64;
    let cap = empty + 256 * 1024;
    let app = spawn_app_with(|c| {
        c.db = db.clone();
        c.db_max_bytes = Some(cap);
    })
    .await;

    // Fill until a write fails (bounded: 256 kB holds far fewer than 200 of these).
    let mut stored = Vec::new();
    let mut full = None;
    for i in 0..200 {
        let res = app
            .post_json("/v1/objects", &tall_box(&format!("box {i}"), 40))
            .await;
        if res.status() == 201 {
            stored.push(res.json::<Value>().await.unwrap());
        } else {
            full = Some(res);
            break;
        }
    }
    let full = full.expect("the capped database fills up");
    let p = assert_problem(full, 507, "insufficient-storage").await;
    assert!(p["detail"].as_str().unwrap().contains("full"), "{p}");
    assert!(stored.len() >= 2, "{} objects before the cap", stored.len());
    // Still full: the next write fails the same way, and no jobs or partial rows appear.
    let res = app
        .post_json("/v1/objects", &tall_box("one more", 40))
        .await;
    assert_problem(res, 507, "insufficient-storage").await;

    // Nothing stored was lost or changed, and the database is sound.
    let listed = objects(&app).await;
    for o in &stored {
        let same = listed
            .iter()
            .find(|l| l["id"] == o["id"])
            .expect("still listed");
        assert_eq!(same["spec"], o["spec"]);
    }
    assert_eq!(
        listed.iter().filter(|l| l["seeded"] == false).count(),
        stored.len()
    );
    let check = reachgrasp::store::retention::integrity_check(&pool)
        .await
        .unwrap();
    assert_eq!(check, "ok");
    assert_eq!(status_of(&app, "/readyz").await, 200);

    // Space returns by deleting: a delete works on a full database, then writes succeed.
    let gone = stored[0]["id"].as_str().unwrap();
    let res = delete(&app, &format!("/v1/objects/{gone}")).await;
    assert_eq!(res.status(), 204);
    let res = app
        .post_json("/v1/objects", &tall_box("after a delete", 40))
        .await;
    assert_eq!(res.status(), 201);

    // Space returns by raising the cap (a restart with a larger limit): writes succeed again.
    let bigger = spawn_app_with(|c| {
        c.db = db.clone();
        c.db_max_bytes = Some(cap + 4 * 1024 * 1024);
    })
    .await;
    for i in 0..3 {
        let res = bigger
            .post_json("/v1/objects", &tall_box(&format!("more {i}"), 40))
            .await;
        assert_eq!(res.status(), 201);
    }
    let check = reachgrasp::store::retention::integrity_check(&pool)
        .await
        .unwrap();
    assert_eq!(check, "ok");
}
