//! Obstacles in plan requests (issue 18, items 1 and 3): validated at their own fields with
//! nothing stored, every link's exact clearance against them reported with the trajectory, and
//! the humanlike path moved around one in its way.

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
    let (model, start) = trained(&app, ROBOT).await;

    // Bad obstacles: 422 at the field, nothing stored.
    let before = app.total("/v1/plans").await;
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
    assert_eq!(app.total("/v1/plans").await, before);

    // The same plan without obstacles, with one far away, and with a crate over the ball. The
    // plan is deterministic, so the trajectory is the same each time: a far obstacle changes
    // nothing else, and the crate over the ball (the grasp is inside it: no motion avoids it) is
    // met by the hand.
    let plan_from = |start: &Value, obstacles: Value| {
        let body = ball_plan(start, obstacles);
        let app = &app;
        async move {
            let res = app.post_json("/v1/plans", &body).await;
            assert_eq!(res.status(), 201);
            let v: Value = res.json().await.unwrap();
            assert_eq!(v["feasible"], true, "{v}");
            v
        }
    };
    let plan = |obstacles: Value| plan_from(&start, obstacles);
    let bare = plan(json!([])).await;
    let far = plan(
        json!([{"name": "far ball", "shape": {"type": "sphere", "radius": 0.1},
                            "position": [-1.5, -1.5, 0.5]}]),
    )
    .await;
    // (the crate over the ball: a stored plan, infeasible, with the colliding motion kept for
    // inspection and nothing queued though execution was asked)
    let mut body = ball_plan(
        &start,
        json!([{"name": "crate", "shape": {"type": "box", "size": [0.3, 0.3, 0.3]},
                "position": [0.5, 0.0, 0.15]}]),
    );
    body["execute"] = json!(true);
    let res = app.post_json("/v1/plans", &body).await;
    assert_eq!(res.status(), 201);
    let over: Value = res.json().await.unwrap();
    assert_eq!(over["feasible"], false, "{over}");
    assert!(over["execution_id"].is_null(), "{over}");
    let clearance = |v: &Value| v["trajectory"]["report"]["clearance"].clone();
    assert_eq!(bare["trajectory"]["points"], far["trajectory"]["points"]);
    assert!(clearance(&bare)["obstacle"].is_null());
    let hit = clearance(&far)["obstacle"].clone();
    assert_eq!(hit["other"], "far ball");
    // every link stays beyond the robot's reach from the base (the far ball is 2.1 m away, the
    // WAM with its hand reaches about 1.2 m)
    assert!(hit["distance_m"].as_f64().unwrap() > 0.5, "{hit}");
    // (the continuous check steps by the bounds of every pair, the far ball's too: the minima
    // are found at slightly different samples, within the check's tolerance)
    for key in ["object", "support", "self_collision"] {
        let (a, b) = (&clearance(&bare)[key], &clearance(&far)[key]);
        assert_eq!(
            (&a["link"], &a["other"]),
            (&b["link"], &b["other"]),
            "{key}"
        );
        let d = |v: &Value| v["distance_m"].as_f64().unwrap();
        assert!((d(a) - d(b)).abs() < 5e-4, "{key}: {a} vs {b}");
    }
    let hit = clearance(&over)["obstacle"].clone();
    assert_eq!(hit["other"], "crate");
    assert!(hit["distance_m"].as_f64().unwrap() < -0.01, "{hit}");
    assert_eq!(clearance(&over)["collision_free"], false);
    let closest = clearance(&over)["closest"].clone();
    assert_eq!(closest["other"], "crate");
    let reason = over["reason"].as_str().unwrap();
    let link = closest["link"].as_str().unwrap();
    assert!(
        reason.contains(&format!("link '{link}'")) && reason.contains("'crate'"),
        "{reason}"
    );
    // Its stored trajectory is not run on its own either (422 at the id, naming the same pair,
    // nothing queued), while a collision-free one of the same robot is queued.
    let executions = app.items("/v1/executions").await;
    let run = |v: &Value| json!({"robot": ROBOT, "mode": "open_loop", "trajectory_id": v["trajectory"]["id"]});
    let problem = assert_problem(
        app.post_json("/v1/executions", &run(&over)).await,
        422,
        "validation",
    )
    .await;
    assert_eq!(problem["errors"][0]["path"], "$.trajectory_id", "{problem}");
    let message = problem["errors"][0]["message"].as_str().unwrap();
    assert!(
        message.contains(&format!("link '{link}'")) && message.contains("'crate'"),
        "{message}"
    );
    assert_eq!(app.items("/v1/executions").await, executions);
    let res = app.post_json("/v1/executions", &run(&far)).await;
    assert_eq!(res.status(), 202);
    assert_eq!(app.items("/v1/executions").await, executions + 1);

    // A 4 cm ball centred on the thumb's path halfway, between the start (the arm stretched
    // up, all joints zero) and the object: the motion goes around it, its exact continuous
    // clearance (not the refinement's own sampled first-order model) keeping most of the 2 cm
    // margin, and still starts and ends where it did.
    let zero = json!({"joint_names": start["joint_names"],
                      "positions": vec![0.0; start["positions"].as_array().unwrap().len()]});
    let from_zero = |obstacles: Value| plan_from(&zero, obstacles);
    let bare = from_zero(json!([])).await;
    let thumb = &bare["trajectory"]["report"]["fingertip_paths"][0]["positions"];
    let n = thumb.as_array().unwrap().len();
    let halfway = thumb[n / 2].clone();
    let around = from_zero(
        json!([{"name": "post", "shape": {"type": "sphere", "radius": 0.04},
                                   "position": halfway}]),
    )
    .await;
    let avoidance = &around["trajectory"]["report"]["avoidance"];
    assert!(
        avoidance["below_target_before"].as_u64().unwrap() > 0,
        "{avoidance}"
    );
    let hit = clearance(&around)["obstacle"].clone();
    assert_eq!(hit["other"], "post");
    assert!(
        hit["distance_m"].as_f64().unwrap() > 0.01,
        "{hit} {avoidance}"
    );
    let last = |v: &Value| {
        v["trajectory"]["points"]
            .as_array()
            .unwrap()
            .last()
            .unwrap()["positions"]
            .clone()
    };
    assert_eq!(last(&around), last(&bare));
    let first = |v: &Value| v["trajectory"]["points"][0]["positions"].clone();
    assert_eq!(first(&around), first(&bare));

    // A start that already collides (a 4 cm ball around the thumb tip where the zero start
    // puts it, by the bare plan's own forward kinematics): no motion from there is safe. A
    // plan and a trajectory are 422 at `$.start` naming the pair, and nothing is stored.
    let on_thumb = json!([{"name": "post", "shape": {"type": "sphere", "radius": 0.04},
                           "position": thumb[0]}]);
    let (plans_before, trajectories_before) = (
        app.total("/v1/plans").await,
        app.total("/v1/trajectories").await,
    );
    let trajectory = json!({"model": model, "start": zero, "obstacles": on_thumb,
                            "goal": {"joint_names": bare["trajectory"]["joint_names"],
                                     "positions": last(&bare)}});
    for (path, body) in [
        ("/v1/plans", ball_plan(&zero, on_thumb.clone())),
        ("/v1/trajectories", trajectory),
    ] {
        let problem = assert_problem(app.post_json(path, &body).await, 422, "validation").await;
        assert_eq!(problem["errors"][0]["path"], "$.start", "{path}: {problem}");
        let message = problem["errors"][0]["message"].as_str().unwrap();
        assert!(
            message.contains("inside obstacle 'post'") && message.contains("start"),
            "{path}: {message}"
        );
    }
    assert_eq!(app.total("/v1/plans").await, plans_before);
    assert_eq!(app.total("/v1/trajectories").await, trajectories_before);
}
