//! Obstacles in plan requests (issue 18, item 1): validated at their own fields with nothing
//! stored, and every link's exact clearance against them reported with the trajectory.

use serde_json::{Value, json};

use crate::helpers::{assert_problem, spawn_app_with, trained};

const ROBOT: &str = "wam_ihy";
const BALL: &str = "00000000-0000-4000-8000-000000000001";

fn ball_plan(start: &Value, obstacles: Value) -> Value {
    json!({"robot": ROBOT, "object_id": BALL, "start": start, "obstacles": obstacles,
           "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_report_their_clearance_to_obstacles_and_refuse_bad_ones() {
    let app = spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await;
    let (_, start) = trained(&app, ROBOT).await;
    let plans = || async {
        let v: Value = app.get("/v1/plans").await.json().await.unwrap();
        v["total"].as_i64().unwrap()
    };

    // Bad obstacles: 422 at the field, nothing stored.
    let before = plans().await;
    let sphere = |r: Value| json!({"name": "s", "shape": {"type": "sphere", "radius": r}, "position": [1, 1, 1]});
    for (obstacles, path) in [
        (json!([sphere(json!(-0.1))]), "$.obstacles[0].shape.radius"),
        (
            json!([sphere(json!(0.1)), {"name": "b", "shape": {"type": "box", "size": [0.1, 0.0, 0.1]}, "position": [1, 1, 1]}]),
            "$.obstacles[1].shape.size[1]",
        ),
        (
            json!([{"name": "c", "shape": {"type": "cylinder", "radius": 0.1, "height": 0.2}, "position": [1, 1, 1], "orientation": [0, 0, 0, 0]}]),
            "$.obstacles[0].orientation",
        ),
        (
            json!([{"name": "", "shape": {"type": "sphere", "radius": 0.1}, "position": [1, 1, 1]}]),
            "$.obstacles[0].name",
        ),
        (json!(vec![sphere(json!(0.1)); 33]), "$.obstacles"),
        (json!([sphere(json!(1.5))]), "$.obstacles[0].shape.radius"),
    ] {
        let body = assert_problem(
            app.post_json("/v1/plans", &ball_plan(&start, obstacles))
                .await,
            422,
            "validation",
        )
        .await;
        assert_eq!(body["errors"][0]["path"], path, "{body}");
    }
    assert_eq!(plans().await, before);

    // The same plan without obstacles, with one far away, and with a crate over the ball. The
    // plan is deterministic, so the trajectory is the same each time: a far obstacle changes
    // nothing else, and the crate (which the motion does not yet avoid) is met by the hand.
    let plan = |obstacles: Value| {
        let body = ball_plan(&start, obstacles);
        let app = &app;
        async move {
            let res = app.post_json("/v1/plans", &body).await;
            assert_eq!(res.status(), 201);
            let v: Value = res.json().await.unwrap();
            assert_eq!(v["feasible"], true, "{v}");
            v
        }
    };
    let bare = plan(json!([])).await;
    let far = plan(
        json!([{"name": "far ball", "shape": {"type": "sphere", "radius": 0.1},
                            "position": [-1.5, -1.5, 0.5]}]),
    )
    .await;
    let over = plan(
        json!([{"name": "crate", "shape": {"type": "box", "size": [0.3, 0.3, 0.3]},
                             "position": [0.5, 0.0, 0.15]}]),
    )
    .await;
    let clearance = |v: &Value| v["trajectory"]["report"]["clearance"].clone();
    assert_eq!(bare["trajectory"]["points"], far["trajectory"]["points"]);
    assert!(clearance(&bare)["obstacle"].is_null());
    let hit = clearance(&far)["obstacle"].clone();
    assert_eq!(hit["other"], "far ball");
    // every link stays beyond the robot's reach from the base (the far ball is 2.1 m away, the
    // WAM with its hand reaches about 1.2 m)
    assert!(hit["distance_m"].as_f64().unwrap() > 0.5, "{hit}");
    for key in ["object", "support", "self_collision"] {
        assert_eq!(clearance(&bare)[key], clearance(&far)[key], "{key}");
    }
    let hit = clearance(&over)["obstacle"].clone();
    assert_eq!(hit["other"], "crate");
    assert!(hit["distance_m"].as_f64().unwrap() < -0.01, "{hit}");
    assert_eq!(clearance(&over)["collision_free"], false);
    assert_eq!(clearance(&over)["closest"]["other"], "crate");
}
