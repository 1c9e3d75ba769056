//! `/v1/objects` and `/v1/grasps`: seeded objects, object CRUD, grasp requests and every
//! rejection of bad input.

use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, field_strings, spawn_app_with, strings};

async fn app() -> TestApp {
    spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await
}

const CUBE_OBJ: &str = "v 0 0 0\nv 0.05 0 0\nv 0.05 0.05 0\nv 0 0.05 0\nv 0 0 0.05\nv 0.05 0 0.05\nv 0.05 0.05 0.05\nv 0 0.05 0.05\n\
    f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

async fn objects(app: &TestApp) -> Vec<Value> {
    let res = app.get("/v1/objects").await;
    assert_eq!(res.status(), 200);
    res.json::<Vec<Value>>().await.unwrap()
}

async fn seeded_id(app: &TestApp, name: &str) -> String {
    objects(app)
        .await
        .into_iter()
        .find(|o| o["name"] == name)
        .unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned()
}

#[tokio::test]
async fn the_everyday_objects_are_seeded() {
    let app = app().await;
    let list = objects(&app).await;
    let names: Vec<&str> = list
        .iter()
        .filter(|o| o["seeded"] == true)
        .map(|o| o["name"].as_str().unwrap())
        .collect();
    for n in ["ball", "bottle", "kitchen_timer", "pencil", "sunglasses"] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    let bottle = list.iter().find(|o| o["name"] == "bottle").unwrap();
    assert_eq!(bottle["spec"]["shape"]["type"], "cylinder");
}

#[tokio::test]
async fn an_object_can_be_created_read_and_deleted() {
    let app = app().await;
    let res = app
        .post_json(
            "/v1/objects",
            &json!({"name": "orange", "shape": {"type": "sphere", "radius": 0.04}, "position": [0.5, 0.1, 0.04],
                    "support": {"normal": [0, 0, 1], "offset": 0.0}}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let created: Value = res.json().await.unwrap();
    let id = created["id"].as_str().unwrap().to_owned();
    let got: Value = app
        .get(&format!("/v1/objects/{id}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(got["spec"]["shape"]["radius"], 0.04);
    assert_eq!(got["seeded"], false);
    let del = app
        .client
        .delete(app.url(&format!("/v1/objects/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(del.status(), 204);
    assert_problem(
        app.get(&format!("/v1/objects/{id}")).await,
        404,
        "not-found",
    )
    .await;
    let again = app
        .client
        .delete(app.url(&format!("/v1/objects/{id}")))
        .send()
        .await
        .unwrap();
    assert_problem(again, 404, "not-found").await;
}

#[tokio::test]
async fn a_mesh_object_is_accepted_from_obj_text() {
    let app = app().await;
    let res = app
        .post_json("/v1/objects", &json!({"name": "cube", "mesh": {"format": "obj", "data": CUBE_OBJ}, "position": [0.5, 0.0, 0.025]}))
        .await;
    assert_eq!(res.status(), 201);
    let o: Value = res.json().await.unwrap();
    assert_eq!(o["spec"]["shape"]["type"], "mesh");
    assert_eq!(
        o["spec"]["shape"]["triangles"].as_array().unwrap().len(),
        12
    );
}

#[tokio::test]
async fn bad_objects_are_rejected_naming_the_field_and_nothing_is_stored() {
    let app = app().await;
    let before = objects(&app).await.len();
    let open_mesh: String = CUBE_OBJ.lines().take(13).collect::<Vec<_>>().join("\n");
    let cases = [
        (
            json!({"name": "x", "shape": {"type": "sphere", "radius": 0.0}, "position": [0.5, 0, 0.1]}),
            "$.shape.radius",
        ),
        (
            json!({"name": "x", "shape": {"type": "box", "size": [0.1, -0.1, 0.1]}, "position": [0.5, 0, 0.1]}),
            "$.shape.size[1]",
        ),
        (
            json!({"name": "x", "mesh": {"format": "obj", "data": open_mesh}, "position": [0.5, 0, 0.1]}),
            "$.mesh",
        ),
        (
            json!({"name": "x", "mesh": {"format": "obj", "data": "v 0 0 zero\n"}, "position": [0.5, 0, 0.1]}),
            "$.mesh",
        ),
        (
            json!({"name": "x", "mesh": {"format": "ply", "data": "ply"}, "position": [0.5, 0, 0.1]}),
            "$.mesh.format",
        ),
        (
            json!({"name": "x", "mesh": {"format": "stl", "data": "AAAA", "encoding": "base64"}, "position": [0.5, 0, 0.1]}),
            "$.mesh",
        ),
        (json!({"name": "x", "position": [0.5, 0, 0.1]}), "$.shape"),
    ];
    for (body, path) in cases {
        let p = assert_problem(app.post_json("/v1/objects", &body).await, 422, "validation").await;
        assert_eq!(p["errors"][0]["path"], path, "{p}");
    }
    assert_eq!(objects(&app).await.len(), before);
}

#[tokio::test]
async fn a_grasp_of_a_seeded_object_is_computed_stored_and_read_back() {
    let app = app().await;
    let ball = seeded_id(&app, "ball").await;
    let res = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": "wam_t42", "object_id": ball,
                    "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}],
                    "quality": "centroid_distance", "weights": {"tc": 1.0, "q": 1.0}, "starts": 4, "seed": 7}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let g: Value = res.json().await.unwrap();
    assert_eq!(g["result"]["feasible"], true, "{}", g["result"]["reason"]);
    assert_eq!(g["result"]["q_arm"].as_array().unwrap().len(), 7);
    assert!(g["result"]["q_arm"][0]["name"].is_string());
    assert_eq!(g["result"]["contacts"].as_array().unwrap().len(), 2);
    // The pads on the surface, judged on the exact link shapes (the verdict's measure; the
    // residual of the optimiser's sphere cover moves when the exact repair places the palm).
    let pad = g["result"]["exact"]["max_pad_distance"].as_f64().unwrap();
    assert!(pad <= 1e-3, "pads {pad} m from the ball");
    assert!(
        g["result"]["exact"]["max_object_penetration"]
            .as_f64()
            .unwrap()
            <= 1e-3
    );
    assert!(g["result"]["terms"]["tc"].as_f64().unwrap() > 0.0);
    assert_eq!(g["request"]["seed"], 7);
    let id = g["id"].as_str().unwrap();
    let back: Value = app
        .get(&format!("/v1/grasps/{id}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(back, g);
    assert_problem(
        app.get("/v1/grasps/00000000-0000-0000-0000-000000000000")
            .await,
        404,
        "not-found",
    )
    .await;
}

/// The pencil lying on the table: the iHY cannot put all three pads on it, so the grasp leaves
/// a finger idle, says which, and lists contacts for the others only; the ball keeps every
/// finger on it. Both read back as stored.
#[tokio::test]
async fn a_grasp_that_needs_fewer_fingers_names_the_idle_ones() {
    let app = app().await;
    for (object, idle) in [("pencil", true), ("ball", false)] {
        let id = seeded_id(&app, object).await;
        let res = app
            .post_json(
                "/v1/grasps",
                &json!({"robot": "wam_ihy", "object_id": id,
                        "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
            )
            .await;
        assert_eq!(res.status(), 201);
        let g: Value = res.json().await.unwrap();
        let r = &g["result"];
        assert_eq!(r["feasible"], true, "{object}: {}", r["reason"]);
        let on: Vec<&str> = field_strings(&r["contacts"], "finger");
        let off: Vec<&str> = strings(&r["idle_fingers"]);
        assert_eq!(!off.is_empty(), idle, "{object}: idle {off:?}");
        assert_eq!(on.len() + off.len(), 3, "{object}: {on:?} {off:?}");
        assert!(on.len() >= 2 && off.iter().all(|f| !on.contains(f)));
        let back: Value = app
            .get(&format!("/v1/grasps/{}", g["id"].as_str().unwrap()))
            .await
            .json()
            .await
            .unwrap();
        assert_eq!(back, g);
    }
}

#[tokio::test]
async fn an_unreachable_object_answers_feasible_false_with_a_reason() {
    let app = app().await;
    let res = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": "pa10_t42", "object": {"name": "far ball", "shape": {"type": "sphere", "radius": 0.03},
                    "position": [2.5, 0.0, 0.03]}, "starts": 2}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let g: Value = res.json().await.unwrap();
    assert_eq!(g["result"]["feasible"], false);
    assert!(
        g["result"]["reason"]
            .as_str()
            .unwrap()
            .contains("out of reach"),
        "{}",
        g["result"]["reason"]
    );
}

#[tokio::test]
async fn bad_grasp_requests_are_rejected_naming_the_field() {
    let app = app().await;
    let ball = seeded_id(&app, "ball").await;
    let base = json!({"robot": "wam_t42", "object_id": ball});
    let with = |patch: Value| {
        let mut b = base.clone();
        for (k, v) in patch.as_object().unwrap() {
            b[k] = v.clone();
        }
        b
    };
    let cases = [
        (with(json!({"robot": "no_such_robot"})), "$.robot"),
        (with(json!({"robot": "../../etc/passwd"})), "$.robot"),
        (
            with(json!({"object_id": "00000000-0000-0000-0000-00000000dead"})),
            "$.object_id",
        ),
        (
            with(
                json!({"object_id": null, "object": {"name": "b", "shape": {"type": "cylinder", "radius": 0.03, "height": -1.0}, "position": [0.5, 0, 0.1]}}),
            ),
            "$.object.shape.height",
        ),
        (
            with(
                json!({"task_directions": [{"direction": [0, 0, 0], "kind": "force", "goal": "maximize"}]}),
            ),
            "$.task_directions[0].direction",
        ),
        (with(json!({"weights": {"q": -1.0}})), "$.weights.q"),
        (with(json!({"quality": "polygon_area"})), "$.quality"),
        (with(json!({"starts": 0})), "$.starts"),
        (with(json!({"starts": 8, "max_starts": 4})), "$.max_starts"),
        (with(json!({"max_starts": 65})), "$.max_starts"),
    ];
    for (body, path) in cases {
        let p = assert_problem(app.post_json("/v1/grasps", &body).await, 422, "validation").await;
        assert_eq!(p["errors"][0]["path"], path, "{p}");
    }
    // JSON has no NaN: a NaN direction or weight cannot even be parsed.
    let raw = format!(
        r#"{{"robot":"wam_t42","object_id":"{ball}","task_directions":[{{"direction":[NaN,0,1],"kind":"force","goal":"maximize"}}]}}"#
    );
    let res = app
        .client
        .post(app.url("/v1/grasps"))
        .header("content-type", "application/json")
        .body(raw)
        .send()
        .await
        .unwrap();
    assert_problem(res, 400, "malformed-json").await;
}

#[tokio::test]
async fn a_batch_runs_as_a_job_and_stores_every_grasp() {
    let app = app().await;
    let ball = seeded_id(&app, "ball").await;
    let res = app
        .post_json(
            "/v1/grasps/batch",
            &json!({"robot": "wam_ihy", "starts": 2, "items": [
                {"object_id": ball},
                {"object": {"name": "b2", "shape": {"type": "sphere", "radius": 0.03}, "position": [0.45, -0.1, 0.03],
                            "support": {"normal": [0, 0, 1], "offset": 0.0}}}
            ]}),
        )
        .await;
    assert_eq!(res.status(), 202);
    let job: Value = res.json().await.unwrap();
    let id = job["id"].as_str().unwrap();
    let done = app
        .wait_job(id, |j| {
            j["status"] == "succeeded" || j["status"] == "failed"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let href = done["result"]["href"].as_str().unwrap();
    let batch: Value = app.get(href).await.json().await.unwrap();
    assert_eq!(batch["count"], 2);
    let ids = batch["grasps"].as_array().unwrap();
    assert_eq!(ids.len(), 2);
    let g: Value = app
        .get(&format!("/v1/grasps/{}", ids[1].as_str().unwrap()))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(g["object"]["name"], "b2");
    let bad = app
        .post_json(
            "/v1/grasps/batch",
            &json!({"robot": "wam_ihy", "items": []}),
        )
        .await;
    let p = assert_problem(bad, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.items");
}

#[tokio::test]
async fn a_registered_robot_can_grasp_and_is_then_held_by_its_grasps() {
    let app = app().await;
    let created: Value = app
        .post_json("/v1/robots", &crate::robots::wam_t42_body())
        .await
        .json()
        .await
        .unwrap();
    let id = created["id"].as_str().unwrap().to_owned();
    let ball = seeded_id(&app, "ball").await;
    let res = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": id, "object_id": ball, "starts": 2, "seed": 3}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let g: Value = res.json().await.unwrap();
    assert_eq!(g["robot"], id.as_str());
    assert_eq!(g["result"]["feasible"], true, "{}", g["result"]["reason"]);
    assert_eq!(g["result"]["contacts"].as_array().unwrap().len(), 2);
    // The stored grasp refers to the robot, so it can no longer be deleted.
    let del = app
        .client
        .delete(app.url(&format!("/v1/robots/{id}")))
        .send()
        .await
        .unwrap();
    assert_problem(del, 409, "conflict").await;
    // A batch resolves registered robots the same way.
    let res = app
        .post_json(
            "/v1/grasps/batch",
            &json!({"robot": id, "starts": 1, "items": [{"object_id": ball}]}),
        )
        .await;
    assert_eq!(res.status(), 202);
}

/// A lab's typos are named, not ignored: an unknown field in a plan or grasp body (`"exectue":
/// true` used to plan without executing) is a 422 at that field, and no plan is stored; an
/// unknown robot or object lists what there is; a seeded object may be named instead of its id.
#[tokio::test]
async fn typos_are_named_and_seeded_objects_go_by_name() {
    let app = app().await;
    let force = json!([{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]);
    let plans = app.total("/v1/plans").await;
    for (path, body, field) in [
        (
            "/v1/plans",
            json!({"robot": "wam_t42", "object_id": "ball", "start": "current", "exectue": true,
                   "task_directions": force}),
            "$.exectue",
        ),
        (
            "/v1/grasps",
            json!({"robot": "wam_t42", "object_id": "ball", "starts": 1,
                   "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize", "weight": 2}]}),
            "$.task_directions[0].weight",
        ),
        (
            "/v1/grasps",
            json!({"robot": "wam_t42", "object_id": "ball", "start": 1}),
            "$.start",
        ),
    ] {
        let p = assert_problem(app.post_json(path, &body).await, 422, "validation").await;
        assert_eq!(p["errors"][0]["path"], field, "{p}");
        assert!(
            p["errors"][0]["message"]
                .as_str()
                .unwrap()
                .contains("unknown field"),
            "{p}"
        );
    }
    let p = assert_problem(
        app.post_json(
            "/v1/grasps",
            &json!({"robot": "wam_t4", "object_id": "ball"}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.robot");
    assert!(p["detail"].as_str().unwrap().contains("wam_t42"), "{p}");
    let p = assert_problem(
        app.post_json(
            "/v1/grasps",
            &json!({"robot": "wam_t42", "object_id": "balll"}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.object_id");
    assert!(
        p["detail"].as_str().unwrap().contains("kitchen_timer"),
        "{p}"
    );
    assert_eq!(app.total("/v1/plans").await, plans);

    // the seeded ball by name is the seeded ball by id
    let res = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": "wam_t42", "object_id": "ball", "starts": 1, "task_directions": force}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let g: Value = res.json().await.unwrap();
    assert_eq!(
        g["object_id"],
        seeded_id(&app, "ball").await.as_str(),
        "{g}"
    );
}

/// An object stated without a support rests on the table the robot stands at (`z = 0`) when it
/// stands on or above it, and the grasp keeps off that table: without the default, wam_ihy takes
/// this cube with a fingertip on its bottom edge (contact at z = 0, normal 0.56 downward). An
/// object reaching below the table gets no default support.
#[tokio::test]
async fn an_object_without_a_support_rests_on_the_robot_table() {
    let app = app().await;
    let cube = json!({"name": "cube", "shape": {"type": "box", "size": [0.05, 0.05, 0.05]},
                      "position": [0.5, 0.0, 0.025]});
    let res = app.post_json("/v1/objects", &cube).await;
    assert_eq!(res.status(), 201);
    let created: Value = res.json().await.unwrap();
    assert_eq!(
        created["spec"]["support"],
        json!({"normal": [0.0, 0.0, 1.0], "offset": 0.0}),
        "{created}"
    );
    let g: Value = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": "wam_ihy", "object_id": created["id"], "seed": 1,
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(g["result"]["feasible"], true, "{}", g["result"]["reason"]);
    for c in g["result"]["contacts"].as_array().unwrap() {
        let z = c["point"][2].as_f64().unwrap();
        let nz = c["normal"][2].as_f64().unwrap();
        assert!(z > 0.005 && nz > -0.5, "a fingertip under the cube: {c}");
    }
    // a part hanging below the table's plane is held or mounted elsewhere: no default
    let hanging = json!({"name": "lamp", "shape": {"type": "sphere", "radius": 0.04},
                         "position": [0.5, 0.0, -0.3]});
    let created: Value = app
        .post_json("/v1/objects", &hanging)
        .await
        .json()
        .await
        .unwrap();
    assert!(created["spec"]["support"].is_null(), "{created}");
}
