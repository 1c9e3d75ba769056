//! Every validation error names the exact field, in the request's own terms (issue 20): the
//! six bodies the conformance run found reported at `$`, at a field not in the request, or with
//! a message about serde's internals.

use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, spawn_app};

/// POSTs `body` to `path`, expects a 422 validation problem, and returns its one field error.
async fn field_error(app: &TestApp, path: &str, body: &Value) -> (String, String) {
    let p = assert_problem(app.post_json(path, body).await, 422, "validation").await;
    let errors = p["errors"].as_array().expect("errors");
    assert_eq!(errors.len(), 1, "{p}");
    (
        errors[0]["path"].as_str().unwrap().to_owned(),
        errors[0]["message"].as_str().unwrap().to_owned(),
    )
}

fn start() -> Value {
    json!({"joint_names": ["j1"], "positions": [0.0]})
}

#[tokio::test]
async fn a_wrong_type_in_a_plan_names_the_flat_field() {
    let app = spawn_app().await;
    let (path, message) = field_error(
        &app,
        "/v1/plans",
        &json!({"robot": 123, "object_id": "ball", "start": start()}),
    )
    .await;
    assert_eq!(path, "$.robot");
    assert!(message.contains("invalid type: integer `123`"), "{message}");
    let (path, _) = field_error(
        &app,
        "/v1/plans",
        &json!({"robot": "wam_ihy", "object_id": "ball", "start": start(), "starts": "four"}),
    )
    .await;
    assert_eq!(path, "$.starts");
    let list: Value = app.get("/v1/plans").await.json().await.unwrap();
    assert_eq!(list["total"], 0);
}

#[tokio::test]
async fn a_bad_plan_start_names_the_field_inside_the_configuration() {
    let app = spawn_app().await;
    let (path, message) = field_error(
        &app,
        "/v1/plans",
        &json!({"robot": "wam_ihy", "object_id": "ball",
                "start": {"joint_names": ["j1"], "positions": "zero"}}),
    )
    .await;
    assert_eq!(path, "$.start.positions");
    assert!(
        message.contains("invalid type: string \"zero\""),
        "{message}"
    );
    assert!(!message.contains("untagged"), "{message}");
    // Neither a configuration nor a string: the start itself, saying what it must be.
    let (path, message) = field_error(
        &app,
        "/v1/plans",
        &json!({"robot": "wam_ihy", "object_id": "ball", "start": 5}),
    )
    .await;
    assert_eq!(path, "$.start");
    assert!(message.contains("\"current\""), "{message}");
    assert!(!message.contains("untagged"), "{message}");
}

#[tokio::test]
async fn a_wrong_type_in_a_study_names_the_field() {
    let app = spawn_app().await;
    let (path, message) = field_error(
        &app,
        "/v1/demonstrations/synthetic",
        &json!({"subjects": "five"}),
    )
    .await;
    assert_eq!(path, "$.subjects");
    assert!(
        message.contains("invalid type: string \"five\""),
        "{message}"
    );
    let jobs: Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0));
}

/// A JSON array is no study, though a derived struct would read one as its fields in order
/// (a conformance run found `[]` accepted with a 202).
#[tokio::test]
async fn an_array_is_no_study() {
    let app = spawn_app().await;
    let (path, message) = field_error(&app, "/v1/demonstrations/synthetic", &json!([])).await;
    assert_eq!(path, "$");
    assert!(message.contains("a study object"), "{message}");
    let jobs: Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0));
}

#[tokio::test]
async fn a_huge_radius_is_out_of_range_at_the_radius() {
    let app = spawn_app().await;
    let (path, message) = field_error(
        &app,
        "/v1/objects",
        &json!({"name": "moon", "shape": {"type": "sphere", "radius": 1e308},
                "position": [0.5, 0.0, 0.1]}),
    )
    .await;
    assert_eq!(path, "$.shape.radius");
    assert!(message.contains("out of range"), "{message}");
    assert!(!message.contains("inf"), "{message}");
    // Inline in a grasp: the same field below `object`.
    let (path, _) = field_error(
        &app,
        "/v1/grasps",
        &json!({"robot": "wam_ihy",
                "object": {"name": "moon", "shape": {"type": "cylinder", "radius": 0.03, "height": 1e308},
                           "position": [0.5, 0.0, 0.1]}}),
    )
    .await;
    assert_eq!(path, "$.object.shape.height");
}

#[tokio::test]
async fn a_bad_mesh_triangle_is_named_in_the_shape_it_came_in() {
    let app = spawn_app().await;
    let vertices = json!([
        [0.0, 0.0, 0.0],
        [0.1, 0.0, 0.0],
        [0.0, 0.1, 0.0],
        [0.0, 0.0, 0.1]
    ]);
    let (path, message) = field_error(
        &app,
        "/v1/objects",
        &json!({"name": "tet", "position": [0.5, 0.0, 0.1],
                "shape": {"type": "mesh", "vertices": vertices,
                          "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 9], [1, 2, 3]]}}),
    )
    .await;
    assert_eq!(path, "$.shape.triangles[2]");
    assert!(message.contains("triangle 2"), "{message}");
    // An uploaded file: the problem is in the file, `mesh`, which is in the request.
    let obj = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\n";
    let (path, _) = field_error(
        &app,
        "/v1/objects",
        &json!({"name": "open", "position": [0.5, 0.0, 0.1],
                "mesh": {"format": "obj", "data": obj}}),
    )
    .await;
    assert_eq!(path, "$.mesh");
}
