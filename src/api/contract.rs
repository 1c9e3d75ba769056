//! The OpenAPI document states what the server enforces (issue 20, item 3).
//!
//! The routers' `utoipa::path` attributes document each operation's own answers. What every
//! operation can also answer comes from the layers around the handlers and from the
//! extractors, the same for all of them, so it is added here once rather than repeated in each
//! attribute (and cannot be forgotten in a new one):
//!
//! - `400` (malformed JSON, an unparsable path or query parameter) where a body or parameter
//!   is read; `404` where the path names a resource; `408`, `413`, `415` and `422` where a JSON
//!   body is read (body idle time, body limit, content type, field validation);
//! - `503` everywhere (shutting down, request timeout), `507` on writes (the database is full);
//! - the paging parameters' enforced ranges (`limit` 1 to [`MAX_PAGE`], `offset` 0 to
//!   [`MAX_OFFSET`]);
//! - the event stream of `GET /v1/jobs/{id}/events` as `text/event-stream` whose schema is one
//!   event (`event`, `data`, `id`, `retry`) with `data` the job as JSON (`contentSchema`),
//!   instead of claiming each event is a `JobRecord`.

use serde_json::{Value, json};

use super::page::{MAX_OFFSET, MAX_PAGE};

fn problem(description: &str) -> Value {
    json!({
        "description": description,
        "content": {
            "application/problem+json": {"schema": {"$ref": "#/components/schemas/Problem"}}
        }
    })
}

/// `N` of "1 to N" in a parameter's description.
fn documented_max(description: &str) -> Option<u64> {
    let rest = &description[description.find("1 to ")? + 5..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// Adds `status` with `description` unless the operation documents it already.
fn add(responses: &mut serde_json::Map<String, Value>, status: &str, description: &str) {
    responses
        .entry(status.to_owned())
        .or_insert_with(|| problem(description));
}

/// The document with what every operation can answer and the enforced parameter ranges.
///
/// It stays JSON from here on: utoipa's document model has no place for some of what is added
/// (a `oneOf` beside an object's `properties`) and would drop it on the way back.
pub fn complete(doc: utoipa::openapi::OpenApi) -> Value {
    let mut v = serde_json::to_value(&doc).expect("an OpenAPI document serializes");
    let paths = v
        .get_mut("paths")
        .and_then(Value::as_object_mut)
        .into_iter()
        .flatten();
    for (path, item) in paths {
        let Some(item) = item.as_object_mut() else {
            continue;
        };
        for (method, op) in item.iter_mut() {
            if !matches!(
                method.as_str(),
                "get" | "post" | "put" | "patch" | "delete" | "head" | "options"
            ) {
                continue;
            }
            complete_operation(path, method, op);
        }
    }
    if let Some(schemas) = v
        .pointer_mut("/components/schemas")
        .and_then(Value::as_object_mut)
    {
        constrain_schemas(schemas);
    }
    v
}

/// `{"type": "null"}` for `field`: absent or `null` (serde reads both as `None`).
fn absent(fields: &[&str]) -> Value {
    let props: serde_json::Map<String, Value> = fields
        .iter()
        .map(|f| ((*f).to_owned(), json!({"type": "null"})))
        .collect();
    Value::Object(props)
}

/// Exactly one of the alternatives: each names the field it requires (its schema) and the
/// fields that must then be absent or `null`.
fn exactly_one(alternatives: &[(&str, Value, &[&str])]) -> Value {
    let one_of: Vec<Value> = alternatives
        .iter()
        .map(|(field, schema, others)| {
            let mut props = absent(others);
            props[*field] = schema.clone();
            json!({"required": [field], "properties": props})
        })
        .collect();
    json!(one_of)
}

/// What the handlers enforce on request bodies and the derives cannot state: the one-of rules
/// between fields (each is a 422 naming the field), ranges of types owned by the numeric core
/// (whose derives stay free of API concerns) and the closed string sets read as strings.
fn constrain_schemas(schemas: &mut serde_json::Map<String, Value>) {
    let mut set = |schema: &str, pointer: &str, key: &str, value: Value| {
        let Some(target) = schemas.get_mut(schema) else {
            return;
        };
        if let Some(Value::Object(o)) = target.pointer_mut(pointer) {
            o.insert(key.to_owned(), value);
        }
    };
    let object_ref = json!({"$ref": "#/components/schemas/ObjectIn"});
    let id = json!({"type": "string", "minLength": 1});
    // `object_id` or an inline `object` (422 "give exactly one of object_id and object").
    let object_or_id = exactly_one(&[
        ("object_id", id.clone(), &["object"]),
        ("object", object_ref, &["object_id"]),
    ]);
    set("GraspIn", "", "oneOf", object_or_id.clone());
    set("BatchItemIn", "", "oneOf", object_or_id);
    // `shape` or `mesh` (422 "give exactly one of shape and mesh").
    set(
        "ObjectIn",
        "",
        "oneOf",
        exactly_one(&[
            (
                "shape",
                json!({"$ref": "#/components/schemas/ShapeSpec"}),
                &["mesh"],
            ),
            (
                "mesh",
                json!({"$ref": "#/components/schemas/MeshIn"}),
                &["shape"],
            ),
        ]),
    );
    set(
        "MeshIn",
        "/properties/format",
        "enum",
        json!(["obj", "stl"]),
    );
    // With `encoding: base64`, `data` is base64 (422 "invalid base64"; padding optional).
    let base64 = json!([
        {"properties": {"encoding": {"enum": ["text", null]}}},
        {"required": ["encoding"], "properties": {
            "encoding": {"const": "base64"},
            "data": {"pattern": "^([A-Za-z0-9+/]{4})*([A-Za-z0-9+/]{2}(==)?|[A-Za-z0-9+/]{3}=?)?$"}}},
    ]);
    for mesh in ["MeshIn", "MeshUpload"] {
        set(
            mesh,
            "/properties/encoding",
            "enum",
            json!(["text", "base64", null]),
        );
        set(mesh, "", "oneOf", base64.clone());
    }
    // A stored trajectory, an inline one, or a model's law in closed loop with its goal
    // (422 "give exactly one of trajectory_id, trajectory and model_id", "model_id needs a
    // goal", "a model runs its law in closed_loop", "goal is only for model_id").
    set(
        "CreateExecution",
        "",
        "oneOf",
        json!([
            {"required": ["trajectory_id"], "properties": {
                "trajectory_id": id, "trajectory": {"type": "null"},
                "model_id": {"type": "null"}, "goal": {"type": "null"}}},
            {"required": ["trajectory"], "properties": {
                "trajectory": {"$ref": "#/components/schemas/InlineTrajectory"},
                "trajectory_id": {"type": "null"}, "model_id": {"type": "null"},
                "goal": {"type": "null"}}},
            {"required": ["model_id", "goal"], "properties": {
                "model_id": id, "goal": {"$ref": "#/components/schemas/JointValues"},
                "mode": {"const": "closed_loop"},
                "trajectory_id": {"type": "null"}, "trajectory": {"type": "null"}}},
        ]),
    );
    // The grasp optimiser's weights (eq. 22) are finite and non-negative.
    for w in ["tc", "gc", "q", "d"] {
        set("Weights", &format!("/properties/{w}"), "minimum", json!(0));
    }
    // Target coordinates within ±1000 m.
    for (schema, field) in [
        ("ObstacleSpec", "position"),
        ("IkRequest", "position"),
        ("IkRequest", "point"),
        ("JacobianRequest", "point"),
        ("ManipulabilityRequest", "point"),
    ] {
        set(
            schema,
            &format!("/properties/{field}/items"),
            "minimum",
            json!(-1000),
        );
        set(
            schema,
            &format!("/properties/{field}/items"),
            "maximum",
            json!(1000),
        );
    }
    // Worker names: 1 to 64 letters, digits, '-', '_', '.'.
    let worker = json!("^[A-Za-z0-9._-]{1,64}$");
    set(
        "CreateExecution",
        "/properties/worker",
        "pattern",
        worker.clone(),
    );
    set("PlanIn", "/allOf/1/properties/worker", "pattern", worker);
    // `"auto"` or a number in the field's own range.
    let auto_or = |number: Value| json!({"oneOf": [{"type": "string", "enum": ["auto"]}, number, {"type": "null"}]});
    let seconds = auto_or(json!({"type": "number", "exclusiveMinimum": 0, "maximum": 60}));
    for (schema, pointer) in [
        ("CreateTrajectory", "/properties"),
        ("PlanIn", "/allOf/1/properties"),
    ] {
        set(schema, pointer, "duration", seconds.clone());
    }
    set(
        "CreateModel",
        "/properties",
        "k",
        auto_or(json!({"type": "number", "minimum": 1})),
    );
    set("AutoOr", "/oneOf/1", "enum", json!(["auto"]));
    // The registration's scale: a positive number or `"auto"`.
    set("ScaleIn", "/oneOf/0", "exclusiveMinimum", json!(0));
    set("ScaleIn", "/oneOf/1", "enum", json!(["auto"]));
    set(
        "RegistrationIn",
        "/properties/hand_scale",
        "exclusiveMinimum",
        json!(0),
    );
    // A mapping's demonstrations by id: 1 to MAX_DEMONSTRATIONS.
    set("SelectionIn", "/oneOf/0", "minItems", json!(1));
    set(
        "SelectionIn",
        "/oneOf/0",
        "maxItems",
        json!(crate::service::mappings::MAX_DEMONSTRATIONS),
    );
    // Object dimensions: positive lengths, each alone within the largest accepted object
    // (2 m across; the object as a whole is checked too, a 422 at `shape`).
    if let Some(Value::Array(alts)) = schemas
        .get_mut("ShapeSpec")
        .and_then(|s| s.get_mut("oneOf"))
    {
        for alt in alts.iter_mut() {
            for (field, max) in [("radius", 1.0), ("height", 2.0), ("length", 2.0)] {
                if let Some(Value::Object(p)) = alt.pointer_mut(&format!("/properties/{field}")) {
                    p.insert("exclusiveMinimum".into(), json!(0));
                    p.insert("maximum".into(), json!(max));
                }
            }
            for field in ["vertices", "triangles"] {
                if let Some(Value::Object(p)) =
                    alt.pointer_mut(&format!("/properties/{field}/items"))
                {
                    p.insert("minItems".into(), json!(3));
                    p.insert("maxItems".into(), json!(3));
                }
            }
            // Mesh vertex coordinates within 1e6 m (larger ones overflow the mesh checks).
            if let Some(Value::Object(p)) = alt.pointer_mut("/properties/vertices/items/items") {
                p.insert("minimum".into(), json!(-1e6));
                p.insert("maximum".into(), json!(1e6));
            }
            if let Some(Value::Object(p)) = alt.pointer_mut("/properties/size/items") {
                p.insert("exclusiveMinimum".into(), json!(0));
                p.insert("maximum".into(), json!(2.0));
            }
        }
    }
    // `"current"` and `"zero"` are the only words a plan's start takes.
    if let Some(Value::Array(alts)) = schemas.get_mut("StartIn").and_then(|s| s.get_mut("oneOf")) {
        for alt in alts.iter_mut() {
            if alt.get("type") == Some(&json!("string")) {
                alt["enum"] = json!([
                    crate::service::Keyword::Current.as_str(),
                    crate::service::Keyword::Zero.as_str()
                ]);
            }
        }
    }
    synthetic_study(schemas);
    flatten_plan(schemas);
    demonstration_streams(schemas);
    keypoint_recordings(schemas);
    robot_sources(schemas);
}

/// A keypoint recording's rows (21 points of 3 coordinates within 10 m, elbow and shoulder 3
/// coordinates, the wrist orientation 4 components), at least two samples, elbow and shoulder
/// together; and an upload is a tracker + glove recording or a keypoint recording, not both
/// (`human::demo`, `api::demonstrations`: 422 at `$.keypoints`, `$.tracker`, `$.glove`).
fn keypoint_recordings(schemas: &mut serde_json::Map<String, Value>) {
    let count = |n: usize| json!({"minItems": n, "maxItems": n});
    let limit = crate::human::keypoints::MAX_KEYPOINT_DISTANCE_M;
    let range = json!({"minimum": -limit, "maximum": limit});
    if let Some(Value::Object(rows)) = schemas
        .get_mut("KeypointStream")
        .and_then(|s| s.pointer_mut("/properties/points/items"))
    {
        rows.extend(
            count(crate::human::KEYPOINT_COUNT)
                .as_object()
                .cloned()
                .unwrap_or_default(),
        );
    }
    constrain_rows(
        schemas,
        "KeypointStream",
        "/properties/points/items",
        count(3),
        range.clone(),
    );
    for column in ["elbow", "shoulder"] {
        constrain_rows(
            schemas,
            "KeypointStream",
            &format!("/properties/{column}"),
            count(3),
            range.clone(),
        );
    }
    constrain_rows(
        schemas,
        "KeypointStream",
        "/properties/wrist_orientation",
        count(4),
        json!({}),
    );
    if let Some(Value::Object(k)) = schemas.get_mut("KeypointStream") {
        if let Some(Value::Object(t)) = k.get_mut("properties").and_then(|p| p.get_mut("t")) {
            t.insert("minItems".into(), json!(2));
        }
        k.insert(
            "dependentRequired".into(),
            json!({"elbow": ["shoulder"], "shoulder": ["elbow"]}),
        );
    }
    if let Some(Value::Object(upload)) = schemas.get_mut("DemonstrationUpload") {
        upload.insert(
            "oneOf".into(),
            json!([
                {"required": ["tracker", "glove"], "properties": {"keypoints": {"type": "null"}}},
                {"required": ["keypoints"], "properties": {
                    "tracker": {"type": "null"}, "glove": {"type": "null"}}},
            ]),
        );
    }
}

/// `items` (and the items' items) of an array at `pointer` in `schema`.
fn constrain_rows(
    schemas: &mut serde_json::Map<String, Value>,
    schema: &str,
    pointer: &str,
    row: Value,
    value: Value,
) {
    let Some(target) = schemas.get_mut(schema) else {
        return;
    };
    if let Some(Value::Object(o)) = target.pointer_mut(&format!("{pointer}/items")) {
        o.extend(row.as_object().cloned().unwrap_or_default());
    }
    if let Some(Value::Object(o)) = target.pointer_mut(&format!("{pointer}/items/items")) {
        o.extend(value.as_object().cloned().unwrap_or_default());
    }
}

/// The demonstration streams' row widths and per-value ranges (`human::demo` checks each row:
/// 3 coordinates within the tracker's 3 m, 4 quaternion components, 22 glove channels, a
/// calibrated angle within ±π), at least two samples per stream (one sample spans no frame),
/// and the glove's `angles` or `raw` + `calibration`. The object's pose and box edges are
/// checked per value too. What relates rows to each other (equal column lengths, increasing
/// times, overlap, a position's distance) is in the upload's description.
fn demonstration_streams(schemas: &mut serde_json::Map<String, Value>) {
    let count = |n: usize| json!({"minItems": n, "maxItems": n});
    let tracker = json!({"minimum": -crate::human::demo::MAX_POSITION_M,
                         "maximum": crate::human::demo::MAX_POSITION_M});
    for column in ["shoulder", "elbow", "wrist"] {
        constrain_rows(
            schemas,
            "TrackerStream",
            &format!("/properties/{column}"),
            count(3),
            tracker.clone(),
        );
    }
    constrain_rows(
        schemas,
        "TrackerStream",
        "/properties/wrist_orientation",
        count(4),
        json!({}),
    );
    let pi = std::f64::consts::PI;
    constrain_rows(
        schemas,
        "GloveStream",
        "/properties/angles",
        count(22),
        json!({"minimum": -pi, "maximum": pi}),
    );
    constrain_rows(
        schemas,
        "GloveStream",
        "/properties/raw",
        count(22),
        json!({}),
    );
    for stream in ["TrackerStream", "GloveStream"] {
        if let Some(Value::Object(t)) = schemas
            .get_mut(stream)
            .and_then(|s| s.pointer_mut("/properties/t"))
        {
            t.insert("minItems".into(), json!(2));
        }
    }
    if let Some(Value::Object(glove)) = schemas.get_mut("GloveStream") {
        // 422 "the glove stream needs either `angles`, or `raw` together with `calibration`".
        glove.insert(
            "oneOf".into(),
            json!([
                {"required": ["angles"], "properties": {
                    "angles": {"type": "array"},
                    "raw": {"type": "null"}, "calibration": {"type": "null"}}},
                {"required": ["raw", "calibration"], "properties": {
                    "raw": {"type": "array"},
                    "calibration": {"$ref": "#/components/schemas/GloveCalibration"},
                    "angles": {"type": "null"}}},
            ]),
        );
    }
    if let Some(Value::Object(p)) = schemas
        .get_mut("DemoPose")
        .and_then(|s| s.pointer_mut("/properties/position/items"))
    {
        p.extend(tracker.as_object().cloned().unwrap_or_default());
    }
    if let Some(Value::Array(alts)) = schemas
        .get_mut("ObjectShape")
        .and_then(|s| s.get_mut("oneOf"))
    {
        for alt in alts.iter_mut() {
            if let Some(Value::Object(p)) = alt.pointer_mut("/properties/size/items") {
                p.insert("minimum".into(), json!(1e-4));
                p.insert("maximum".into(), json!(2.0));
            }
            // `deny_unknown_fields` on the tagged enum refuses them in every variant; the
            // derive leaves its variants open.
            if let Value::Object(o) = alt {
                o.insert("additionalProperties".into(), json!(false));
            }
        }
    }
}

/// A robot is registered from `arm_urdf` + `hand_urdf` with a `descriptor.mount`, or from one
/// combined `urdf` with a `descriptor.wrist_frame` (422 "give either arm_urdf and hand_urdf,
/// or urdf", "required when the hand is a separate URDF", "required for a combined URDF").
fn robot_sources(schemas: &mut serde_json::Map<String, Value>) {
    // Spread pairs are `[a, b]` (any other length is a 422 "expected 2 items, got 3" at the
    // pair, `crate::wire::exact`).
    for (schema, pointer) in [
        ("SystemDescriptor", "/properties/spread_pairs/items"),
        ("RobotDetail", "/properties/spread_pairs/items"),
    ] {
        if let Some(Value::Object(pair)) =
            schemas.get_mut(schema).and_then(|s| s.pointer_mut(pointer))
        {
            pair.insert("minItems".into(), json!(2));
            pair.insert("maxItems".into(), json!(2));
        }
    }
    let Some(Value::Object(robot)) = schemas.get_mut("CreateRobot") else {
        return;
    };
    // At most MAX_MESHES meshes, each named by 1 to 512 bytes (a character count can only
    // state the lower bound exactly: a character is 1 to 4 bytes).
    if let Some(Value::Object(meshes)) = robot
        .get_mut("properties")
        .and_then(|p| p.get_mut("meshes"))
    {
        meshes.insert("maxProperties".into(), json!(super::robots::MAX_MESHES));
        meshes.insert(
            "propertyNames".into(),
            json!({"type": "string", "minLength": 1, "maxLength": 512}),
        );
    }
    let text = json!({"type": "string"});
    robot.insert(
        "oneOf".into(),
        json!([
            {"required": ["arm_urdf", "hand_urdf"], "properties": {
                "arm_urdf": text, "hand_urdf": text, "urdf": {"type": "null"},
                "descriptor": {"required": ["mount"], "properties": {
                    "mount": {"$ref": "#/components/schemas/Mount"}}}}},
            {"required": ["urdf"], "properties": {
                "urdf": text, "arm_urdf": {"type": "null"}, "hand_urdf": {"type": "null"},
                "descriptor": {"required": ["wrist_frame"], "properties": {
                    "wrist_frame": {"type": "string"}}}}},
        ]),
    );
}

/// The synthetic study request is the numeric core's `StudyConfig` read as is (so that errors
/// keep their paths); its derive stays free of API concerns, so its fields and the ranges
/// `StudyConfig::validate` enforces are stated here. The total (at most
/// [`MAX_DEMONSTRATIONS`](crate::human::synth::MAX_DEMONSTRATIONS) demonstrations) is a
/// cross-field rule no schema states.
fn synthetic_study(schemas: &mut serde_json::Map<String, Value>) {
    use crate::human::synth::{MAX_SUBJECTS, MAX_TRIALS, POSITIONS};
    let Some(Value::Object(study)) = schemas.get_mut("SyntheticRequest") else {
        return;
    };
    let description = study.get("description").cloned();
    let objects = ["ball", "bottle", "kitchen_timer", "pencil", "sunglasses"];
    *study = json!({
        "type": "object",
        "additionalProperties": false,
        "properties": {
            "seed": {"type": "integer", "minimum": 0, "maximum": u64::MAX,
                     "description": "Seed of the study (default 1): the same seed, the same study."},
            "subjects": {"type": "integer", "minimum": 1, "maximum": MAX_SUBJECTS,
                         "description": "Subjects (default 5)."},
            "positions": {"type": "integer", "minimum": 1, "maximum": POSITIONS,
                          "description": "Object positions (default 5)."},
            "trials": {"type": "integer", "minimum": 1, "maximum": MAX_TRIALS,
                       "description": "Trials per subject and position (default 10)."},
            "objects": {"type": "array", "minItems": 1, "maxItems": objects.len(),
                        "items": {"type": "string", "enum": objects},
                        "description": "Objects of the study (default all five)."},
            "full_factorial": {"type": "boolean",
                               "description": "Every object at every position (default false: counterbalanced)."},
            "noise": {"type": "boolean",
                      "description": "Sensor noise at the devices' stated accuracy (default true)."},
            "rate_hz": {"type": "number", "minimum": 1, "maximum": 1000,
                        "description": "Common output rate, Hz (default 120)."},
        },
    })
    .as_object()
    .cloned()
    .unwrap_or_default();
    if let Some(d) = description {
        study.insert("description".into(), d);
    }
}

/// A plan body is a grasp body and the plan's own fields at one level, and the server refuses
/// any other field (a typo such as `"exectue"` is a 422, not a plan that silently does not
/// execute). `allOf` cannot state that: each branch's `additionalProperties: false` would refuse
/// the other branch's fields. So the two are merged into one object schema, the grasp body's
/// `oneOf` (object or object id) kept.
fn flatten_plan(schemas: &mut serde_json::Map<String, Value>) {
    let Some(grasp) = schemas.get("GraspIn").cloned() else {
        return;
    };
    let Some(plan) = schemas.get_mut("PlanIn") else {
        return;
    };
    let own = plan.pointer("/allOf/1").cloned().unwrap_or(Value::Null);
    let mut properties = grasp["properties"].as_object().cloned().unwrap_or_default();
    if let Some(o) = own["properties"].as_object() {
        properties.extend(o.clone());
    }
    let required: Vec<Value> = [&grasp["required"], &own["required"]]
        .into_iter()
        .filter_map(Value::as_array)
        .flatten()
        .cloned()
        .collect();
    let mut merged = json!({
        "type": "object",
        "description": plan.get("description").cloned().unwrap_or(Value::Null),
        "properties": properties,
        "required": required,
        "additionalProperties": false,
    });
    if let Some(one_of) = grasp.get("oneOf") {
        merged["oneOf"] = one_of.clone();
    }
    *plan = merged;
}

fn complete_operation(path: &str, method: &str, op: &mut Value) {
    let body = op.get("requestBody").cloned();
    let json_body = body
        .as_ref()
        .and_then(|b| b.get("content"))
        .is_some_and(|c| c.get("application/json").is_some());
    if let Some(params) = op.get_mut("parameters").and_then(Value::as_array_mut) {
        for p in params.iter_mut() {
            let in_query = p.get("in").and_then(Value::as_str) == Some("query");
            let description = p.get("description").and_then(Value::as_str).unwrap_or("");
            let range = match p.get("name").and_then(Value::as_str) {
                // Each page size documents its own range ("Page size, 1 to 500"); the
                // handlers enforce exactly that range (tests/api/openapi.rs checks it).
                Some("limit") if in_query => Some((
                    1,
                    documented_max(description).unwrap_or(u64::from(MAX_PAGE)),
                )),
                Some("offset") if in_query => Some((0, u64::from(MAX_OFFSET))),
                _ => None,
            };
            if let (Some((lo, hi)), Some(schema)) = (range, p.get_mut("schema")) {
                schema["minimum"] = json!(lo);
                schema["maximum"] = json!(hi);
            }
        }
    }
    let has_params = op
        .get("parameters")
        .and_then(Value::as_array)
        .is_some_and(|p| !p.is_empty());
    let Some(responses) = op.get_mut("responses").and_then(Value::as_object_mut) else {
        return;
    };
    if has_params || body.is_some() {
        add(
            responses,
            "400",
            "Bad request: malformed JSON, or a path or query parameter that does not parse \
             (problem+json naming it)",
        );
    }
    if path.contains('{') {
        add(responses, "404", "No such resource (problem+json)");
    }
    if body.is_some() {
        add(
            responses,
            "408",
            "The request body stalled longer than the body idle time (problem+json)",
        );
        add(
            responses,
            "413",
            "The request body is larger than the body limit (problem+json)",
        );
        add(
            responses,
            "415",
            "The request body does not have the documented content type (problem+json)",
        );
    }
    if json_body {
        add(
            responses,
            "422",
            "Invalid request: well-formed JSON with bad values (problem+json naming each field)",
        );
    }
    add(
        responses,
        "503",
        "Service unavailable: shutting down, a dependency down, or the request took longer than \
         the request timeout (problem+json)",
    );
    if matches!(method, "post" | "put" | "patch" | "delete") {
        add(
            responses,
            "507",
            "Insufficient storage: the database is full; nothing was stored (problem+json)",
        );
    }
    // Server-Sent Events: the schema describes one event (what a conformance checker
    // validates each parsed event against), whose `data` is the documented JSON.
    if let Some(ok) = responses.get_mut("200")
        && let Some(stream) = ok
            .get_mut("content")
            .and_then(|c| c.get_mut("text/event-stream"))
    {
        let data = stream.pointer("/schema/$ref").cloned();
        let mut data_schema = json!({
            "type": "string",
            "contentMediaType": "application/json",
            "description": "The event's JSON payload",
        });
        if let Some(r) = data {
            data_schema["contentSchema"] = json!({"$ref": r});
        }
        stream["schema"] = json!({
            "type": "object",
            "description": "One Server-Sent Event: its name and, in `data`, the JSON it carries",
            "properties": {
                "event": {"type": "string"},
                "data": data_schema,
                "id": {"type": "string"},
                "retry": {"type": "integer", "minimum": 0},
            },
        });
    }
}
