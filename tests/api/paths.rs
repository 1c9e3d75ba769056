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

/// POSTs `body` and expects the single field error `(path, message)` exactly.
async fn assert_field(app: &TestApp, route: &str, body: Value, path: &str, message: &str) {
    let got = field_error(app, route, &body).await;
    assert_eq!(
        (got.0.as_str(), got.1.as_str()),
        (path, message),
        "{route}: {body}"
    );
}

/// Objects stored by requests (the seeded ones are always listed).
async fn stored_objects(app: &TestApp) -> usize {
    let list: Value = app.get("/v1/objects").await.json().await.unwrap();
    let items = list.as_array().expect("a list of objects");
    items.iter().filter(|o| o["seeded"] != true).count()
}

fn ball(position: Value) -> Value {
    json!({"name": "b", "shape": {"type": "sphere", "radius": 0.03}, "position": position})
}

/// A fixed-size array with too many items was left to the JSON reader, whose "trailing
/// characters" came back as a 400 malformed-JSON; it is a 422 at the array.
#[tokio::test]
async fn an_overlong_fixed_size_array_is_named_with_its_item_count() {
    let app = spawn_app().await;
    assert_field(
        &app,
        "/v1/objects",
        ball(json!([0.5, 0.0, 0.1, 9.0])),
        "$.position",
        "expected 3 items, got 4",
    )
    .await;
    let mut tilted = ball(json!([0.5, 0.0, 0.1]));
    tilted["orientation"] = json!([1.0, 0.0, 0.0, 0.0, 0.0]);
    assert_field(
        &app,
        "/v1/objects",
        tilted,
        "$.orientation",
        "expected 4 items, got 5",
    )
    .await;
    let mut supported = ball(json!([0.5, 0.0, 0.1]));
    supported["support"] = json!({"normal": [0.0, 0.0, 1.0, 0.0], "offset": 0.0});
    assert_field(
        &app,
        "/v1/objects",
        supported,
        "$.support.normal",
        "expected 3 items, got 4",
    )
    .await;
    // Inside a shape, and as the item of a list.
    let tetra = json!({"name": "t", "position": [0.5, 0.0, 0.1],
        "shape": {"type": "mesh", "vertices": [[0, 0, 0], [0.1, 0, 0, 0], [0, 0.1, 0], [0, 0, 0.1]],
                  "triangles": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}});
    assert_field(
        &app,
        "/v1/objects",
        tetra,
        "$.shape.vertices[1]",
        "expected 3 items, got 4",
    )
    .await;
    // Short arrays say the same.
    assert_field(
        &app,
        "/v1/objects",
        ball(json!([0.5, 0.0])),
        "$.position",
        "expected 3 items, got 2",
    )
    .await;
    assert_eq!(stored_objects(&app).await, 0);

    assert_field(
        &app,
        "/v1/plans",
        json!({"robot": "wam_ihy", "object_id": "ball", "start": start(),
               "obstacles": [{"name": "post", "shape": {"type": "sphere", "radius": 0.1},
                              "position": [0.4, 0.2, 0.3, 0.0]}]}),
        "$.obstacles[0].position",
        "expected 3 items, got 4",
    )
    .await;
    assert_field(
        &app,
        "/v1/plans",
        json!({"robot": "wam_ihy", "object_id": "ball", "start": start(),
               "elbow_reference": [0.1, 0.2, 0.3, 0.4]}),
        "$.elbow_reference",
        "expected 3 items, got 4",
    )
    .await;
    assert_eq!(app.total("/v1/plans").await, 0);
    assert_field(
        &app,
        "/v1/grasps",
        json!({"robot": "wam_ihy", "object_id": "ball",
               "task_directions": [{"direction": [0, 0, 1, 0], "kind": "velocity", "goal": "maximize"}]}),
        "$.task_directions[0].direction",
        "expected 3 items, got 4",
    )
    .await;
    assert_field(
        &app,
        "/v1/mappings",
        json!({"robot": "wam_ihy", "demonstrations": ["d"],
               "registration": {"transform": {"position": [0, 0, 0], "orientation": [1, 0, 0, 0, 0]}}}),
        "$.registration.transform.orientation",
        "expected 4 items, got 5",
    )
    .await;
    assert_field(
        &app,
        "/v1/robots/wam_ihy/ik",
        json!({"position": [0.5, 0.0, 0.3, 1.0]}),
        "$.position",
        "expected 3 items, got 4",
    )
    .await;
    // A spread pair `[a, b]` with a third name.
    assert_field(
        &app,
        "/v1/robots",
        json!({"urdf": "<robot/>", "descriptor": {"name": "x", "spread_pairs": [["a", "b", "c"]]}}),
        "$.descriptor.spread_pairs[0]",
        "expected 2 items, got 3",
    )
    .await;
    let jobs: Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0));
}

/// serde reads an internally tagged shape from a buffer, where the path was lost: every
/// error inside a shape was reported at the shape itself.
#[tokio::test]
async fn a_bad_field_inside_a_shape_is_named_below_the_shape() {
    let app = spawn_app().await;
    let big = "invalid type: string \"big\", expected f64";
    let mut object = ball(json!([0.5, 0.0, 0.1]));
    object["shape"] = json!({"type": "sphere", "radius": "big"});
    assert_field(&app, "/v1/objects", object.clone(), "$.shape.radius", big).await;
    // The tag after the field (as a client that sorts its keys sends it).
    let mut sorted = object.clone();
    sorted["shape"] = json!({"radius": "big", "type": "sphere"});
    assert_field(&app, "/v1/objects", sorted, "$.shape.radius", big).await;
    let mut mesh = object.clone();
    mesh["shape"] = json!({"type": "mesh", "vertices": [[0, 0, "x"]], "triangles": []});
    assert_field(
        &app,
        "/v1/objects",
        mesh,
        "$.shape.vertices[0][2]",
        "invalid type: string \"x\", expected f64",
    )
    .await;
    assert_field(
        &app,
        "/v1/objects",
        json!({"name": "b", "position": [0.5, 0.0, 0.1],
               "shape": {"type": "box", "size": [0.1, 0.1, 0.1, 0.1]}}),
        "$.shape.size",
        "expected 3 items, got 4",
    )
    .await;
    // A repeated key is still refused, at the key.
    let res = app
        .client
        .post(app.url("/v1/objects"))
        .header("content-type", "application/json")
        .body(
            r#"{"name": "b", "position": [0.5, 0.0, 0.1],
                "shape": {"type": "sphere", "radius": 0.1, "radius": 0.2}}"#,
        )
        .send()
        .await
        .unwrap();
    let p = assert_problem(res, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.shape.radius", "{p}");
    assert_eq!(p["errors"][0]["message"], "duplicate field `radius`", "{p}");
    assert_eq!(stored_objects(&app).await, 0);

    assert_field(
        &app,
        "/v1/grasps",
        json!({"robot": "wam_ihy", "object": object.clone()}),
        "$.object.shape.radius",
        big,
    )
    .await;
    assert_field(
        &app,
        "/v1/grasps/batch",
        json!({"robot": "wam_ihy", "items": [{"object_id": "ball"}, {"object": object.clone()}]}),
        "$.items[1].object.shape.radius",
        big,
    )
    .await;
    assert_field(
        &app,
        "/v1/plans",
        json!({"robot": "wam_ihy", "object": object, "start": start()}),
        "$.object.shape.radius",
        big,
    )
    .await;
    assert_field(
        &app,
        "/v1/plans",
        json!({"robot": "wam_ihy", "object_id": "ball", "start": start(),
               "obstacles": [{"name": "post", "position": [0.4, 0.2, 0.3],
                              "shape": {"type": "cylinder", "radius": 0.05, "height": "tall"}}]}),
        "$.obstacles[0].shape.height",
        "invalid type: string \"tall\", expected f64",
    )
    .await;
    assert_eq!(app.total("/v1/plans").await, 0);
}

/// An untagged selection or scale said "did not match any variant" at the field that holds it.
#[tokio::test]
async fn a_bad_selection_or_scale_of_a_mapping_names_the_field_inside() {
    let app = spawn_app().await;
    let expected_string = "invalid type: integer `5`, expected a string";
    assert_field(
        &app,
        "/v1/mappings",
        json!({"robot": "wam_ihy", "demonstrations": {"subject": 5}}),
        "$.demonstrations.subject",
        expected_string,
    )
    .await;
    assert_field(
        &app,
        "/v1/mappings",
        json!({"robot": "wam_ihy", "demonstrations": ["d1", 5]}),
        "$.demonstrations[1]",
        expected_string,
    )
    .await;
    assert_field(
        &app,
        "/v1/mappings",
        json!({"robot": "wam_ihy", "demonstrations": ["d1"], "registration": {"scale": [2]}}),
        "$.registration.scale",
        "invalid type: sequence, expected a positive number or \"auto\"",
    )
    .await;
    let jobs: Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0));
}

/// A plain enum given a number was serde_json's syntax error "expected value": a 400
/// malformed-JSON for a well-formed body.
#[tokio::test]
async fn a_number_for_a_named_choice_is_a_422_at_the_field() {
    let app = spawn_app().await;
    let message = "invalid type: integer `5`, expected string or map";
    assert_field(
        &app,
        "/v1/grasps",
        json!({"robot": "wam_ihy", "object_id": "ball", "quality": 5}),
        "$.quality",
        message,
    )
    .await;
    assert_field(
        &app,
        "/v1/plans",
        json!({"robot": "wam_ihy", "object_id": "ball", "start": start(), "mode": 5}),
        "$.mode",
        message,
    )
    .await;
    assert_field(
        &app,
        "/v1/demonstrations/synthetic",
        json!({"objects": ["ball", 5]}),
        "$.objects[1]",
        message,
    )
    .await;
    // A body that is not JSON at all stays a 400.
    let res = app
        .client
        .post(app.url("/v1/grasps"))
        .header("content-type", "application/json")
        .body(r#"{"robot": "wam_ihy", "object_id": "ball"} trailing"#)
        .send()
        .await
        .unwrap();
    assert_problem(res, 400, "malformed-json").await;
    let jobs: Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(jobs["items"].as_array().map(Vec::len), Some(0));
}

/// A study count out of range spoke of "the plausible adult range".
#[tokio::test]
async fn a_study_count_out_of_range_is_not_an_adult_measurement() {
    let app = spawn_app().await;
    let (path, message) = field_error(
        &app,
        "/v1/demonstrations/synthetic",
        &json!({"subjects": 0}),
    )
    .await;
    assert_eq!(path, "$.subjects");
    assert!(
        message.contains("outside the range a study allows"),
        "{message}"
    );
    assert!(!message.contains("adult"), "{message}");
}
