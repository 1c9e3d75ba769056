use crate::helpers::spawn_app;

const REGENERATE: &str = "openapi/openapi.json is stale: regenerate it with \
                          `cargo run -- openapi > openapi/openapi.json` and commit it";

#[test]
fn openapi_document_is_up_to_date() {
    let committed =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/openapi/openapi.json"))
            .unwrap_or_else(|e| panic!("cannot read openapi/openapi.json ({e}); {REGENERATE}"));
    let committed: serde_json::Value = serde_json::from_str(&committed).expect(REGENERATE);
    let generated = serde_json::to_value(reachgrasp::api::openapi()).unwrap();
    assert!(committed == generated, "{REGENERATE}");
}

#[tokio::test]
async fn the_served_document_is_openapi_3_1_and_matches_the_generated_one() {
    let app = spawn_app().await;
    let res = app.get("/openapi.json").await;
    assert_eq!(res.status(), 200);
    let served: serde_json::Value = res.json().await.unwrap();
    assert!(served["openapi"].as_str().unwrap().starts_with("3.1"));
    assert_eq!(
        served,
        serde_json::to_value(reachgrasp::api::openapi()).unwrap()
    );
    for path in [
        "/healthz",
        "/readyz",
        "/v1/jobs",
        "/v1/jobs/{id}",
        "/v1/jobs/{id}/events",
        "/v1/jobs/{id}/cancel",
    ] {
        assert!(served["paths"].get(path).is_some(), "{path} missing");
    }
    // Test-only routes never appear in the document.
    assert!(served["paths"].get("/v1/_test/jobs/sleep").is_none());
}

/// OpenAPI 3.1 requires a `description` on every Response Object (4.8.17); a validator rejects
/// the document without one.
#[test]
fn every_response_has_a_description() {
    let doc = serde_json::to_value(reachgrasp::api::openapi()).unwrap();
    let mut missing = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (method, op) in ops.as_object().unwrap() {
            let Some(responses) = op.get("responses").and_then(|r| r.as_object()) else {
                continue;
            };
            for (status, response) in responses {
                if response
                    .get("description")
                    .and_then(|d| d.as_str())
                    .is_none()
                {
                    missing.push(format!("{method} {path} {status}"));
                }
            }
        }
    }
    assert!(
        missing.is_empty(),
        "responses without a description: {missing:?}"
    );
}

/// The Python interpreter with `openapi-spec-validator` (`.ci/run` makes `.ci/.venv`), if any.
fn validator_python() -> Option<std::path::PathBuf> {
    let venv = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/.venv/bin/python");
    let candidates = [
        std::env::var_os("REACHGRASP_OPENAPI_PYTHON").map(std::path::PathBuf::from),
        Some(venv),
        Some("python3".into()),
    ];
    candidates.into_iter().flatten().find(|py| {
        std::process::Command::new(py)
            .args(["-c", "import openapi_spec_validator"])
            .output()
            .is_ok_and(|o| o.status.success())
    })
}

/// The served document passes an OpenAPI 3.1 validator (openapi-spec-validator, which checks
/// the document against the 3.1 meta-schema and resolves every reference).
#[tokio::test]
async fn the_served_document_passes_an_openapi_3_1_validator() {
    let Some(python) = validator_python() else {
        assert!(
            std::env::var_os("CI").is_none(),
            "openapi-spec-validator is missing (.ci/run installs it in .ci/.venv)"
        );
        eprintln!("skipped: no Python with openapi-spec-validator (run .ci/run)");
        return;
    };
    let app = spawn_app().await;
    let served = app.get("/openapi.json").await.text().await.unwrap();
    let file = app._dir.path().join("served-openapi.json");
    std::fs::write(&file, served).unwrap();
    let out = std::process::Command::new(python)
        .args([
            "-c",
            "import sys, json\n\
             from openapi_spec_validator import validate\n\
             from openapi_spec_validator.validation import OpenAPIV31SpecValidator\n\
             validate(json.load(open(sys.argv[1])), cls=OpenAPIV31SpecValidator)\n\
             print('valid')",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the served document is not valid OpenAPI 3.1:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// What every operation can answer is documented: the layers' statuses on every operation,
/// the body statuses where a JSON body is read, and the event stream as text.
#[test]
fn every_operation_documents_what_the_layers_answer() {
    let doc = serde_json::to_value(reachgrasp::api::openapi()).unwrap();
    let mut missing = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (method, op) in ops.as_object().unwrap() {
            let responses = op["responses"].as_object().unwrap();
            let mut expected = vec!["503"];
            let json_body = op
                .pointer("/requestBody/content/application~1json")
                .is_some();
            if json_body {
                expected.extend(["400", "408", "413", "415", "422"]);
            }
            if path.contains('{') {
                expected.push("404");
            }
            if method != "get" {
                expected.push("507");
            }
            for status in expected {
                if !responses.contains_key(status) {
                    missing.push(format!("{method} {path} {status}"));
                }
            }
            assert!(
                !responses.contains_key("500"),
                "{method} {path} documents a 500"
            );
        }
    }
    assert!(missing.is_empty(), "undocumented statuses: {missing:?}");
    let events = &doc["paths"]["/v1/jobs/{id}/events"]["get"]["responses"]["200"]["content"];
    let event = &events["text/event-stream"]["schema"];
    assert_eq!(event["type"], "object");
    assert_eq!(
        event["properties"]["data"]["contentMediaType"],
        "application/json"
    );
    assert_eq!(
        event["properties"]["data"]["contentSchema"]["$ref"],
        "#/components/schemas/JobRecord"
    );
    assert!(events.get("application/json").is_none());
}

/// Paging parameters document the range the server enforces, and the server refuses what is
/// outside it (an offset above int32 was accepted).
#[tokio::test]
async fn paging_ranges_are_documented_and_enforced() {
    let doc = serde_json::to_value(reachgrasp::api::openapi()).unwrap();
    let params = doc["paths"]["/v1/plans"]["get"]["parameters"]
        .as_array()
        .unwrap();
    let schema = |name: &str| params.iter().find(|p| p["name"] == name).unwrap()["schema"].clone();
    assert_eq!(schema("limit")["minimum"], 1);
    assert_eq!(schema("limit")["maximum"], 500);
    assert_eq!(schema("offset")["minimum"], 0);
    assert_eq!(schema("offset")["maximum"], i64::from(i32::MAX));
    let mapping = &doc["paths"]["/v1/mappings/{id}"]["get"]["parameters"];
    let limit = mapping
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "limit")
        .unwrap();
    assert_eq!(limit["schema"]["maximum"], 100);

    let app = spawn_app().await;
    for (query, ok) in [
        ("limit=500&offset=2147483647", true),
        ("limit=501", false),
        ("limit=0", false),
        ("offset=2147483648", false),
    ] {
        let res = app.get(&format!("/v1/plans?{query}")).await;
        assert_eq!(res.status().is_success(), ok, "{query}: {}", res.status());
        if !ok {
            assert_eq!(res.status(), 400, "{query}");
        }
    }
    let id = uuid::Uuid::new_v4();
    let res = app
        .get(&format!("/v1/mappings/{id}?offset=2147483648"))
        .await;
    assert_eq!(res.status(), 400);
}

/// Every JSON request body the document lists (so a new endpoint cannot forget it) refuses an
/// unknown field with a 422 at that field, and the document says so with
/// `additionalProperties: false` (on each alternative where the body is a `oneOf`).
#[tokio::test]
async fn every_request_body_refuses_an_unknown_field_naming_it() {
    let app = crate::helpers::spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await;
    let doc = serde_json::to_value(reachgrasp::api::openapi()).unwrap();
    let schemas = &doc["components"]["schemas"];
    let resolve = |s: &serde_json::Value| resolve_ref(schemas, s);
    let mut checked = 0;
    let mut nested = 0;
    let mut open_schemas = Vec::new();
    let mut accepted = Vec::new();
    for (path, ops) in doc["paths"].as_object().unwrap() {
        for (method, op) in ops.as_object().unwrap() {
            let Some(schema) = op
                .pointer("/requestBody/content/application~1json/schema")
                .map(&resolve)
            else {
                continue;
            };
            // the document: closed objects, every alternative of a oneOf
            let mut alternatives = vec![schema.clone()];
            alternatives.extend(
                schema["oneOf"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .map(&resolve),
            );
            for alt in alternatives.iter().filter(|a| a["type"] == "object") {
                if alt["additionalProperties"] != false {
                    open_schemas.push(format!("{method} {path}"));
                }
            }
            // the server: ids that parse (a uuid where the parameter is one, else a robot)
            let mut url = path.clone();
            for p in op["parameters"].as_array().into_iter().flatten() {
                if p["in"] == "path" {
                    let name = p["name"].as_str().unwrap();
                    let value = if resolve(&p["schema"])["format"] == "uuid" {
                        "00000000-0000-4000-8000-00000000abcd"
                    } else {
                        "wam_ihy"
                    };
                    url = url.replace(&format!("{{{name}}}"), value);
                }
            }
            // the top level, then every closed object nested in it: the unknown field alone
            // inside it, so nothing else in the body can be refused first
            let mut probes = vec![(
                serde_json::json!({"zz_not_a_field": 1}),
                "$.zz_not_a_field".to_owned(),
            )];
            let mut seen = Vec::new();
            nested_probes(schemas, &schema, "$", &mut seen, &mut |body, at| {
                probes.push((body, format!("{at}.zz_not_a_field")));
            });
            for alt in &alternatives {
                nested_probes(schemas, alt, "$", &mut seen, &mut |body, at| {
                    probes.push((body, format!("{at}.zz_not_a_field")));
                });
            }
            probes.dedup_by(|a, b| a.1 == b.1);
            for (probe, expected) in probes {
                let res = app
                    .client
                    .request(method.to_uppercase().parse().unwrap(), app.url(&url))
                    .json(&probe)
                    .send()
                    .await
                    .unwrap();
                let status = res.status().as_u16();
                let body: serde_json::Value = res.json().await.unwrap_or_default();
                let named = body["errors"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .any(|e| e["path"] == expected.as_str());
                if status != 422 || !named {
                    accepted.push(format!(
                        "{method} {path} {probe} (expected {expected}): {status} {body}"
                    ));
                }
                if expected != "$.zz_not_a_field" {
                    nested += 1;
                }
            }
            checked += 1;
        }
    }
    assert!(
        checked >= 15,
        "only {checked} request bodies in the document"
    );
    // the demonstration upload alone has 10 closed nested objects, the robot descriptor 2
    assert!(nested >= 12, "only {nested} nested closed objects probed");
    assert!(
        accepted.is_empty(),
        "unknown field not refused by name:\n{}",
        accepted.join("\n")
    );
    assert!(
        open_schemas.is_empty(),
        "request bodies the document leaves open: {open_schemas:?}"
    );
}

/// For each closed object (`additionalProperties: false`) reachable from `schema`'s properties
/// (through `$ref`, a nullable `oneOf`, array items, and each alternative of a `oneOf` told
/// apart by a one-value `enum` tag), a body with an unknown field in that object alone and the
/// JSONPath of that object. `seen` stops recursion through self-referencing schemas.
fn nested_probes(
    schemas: &serde_json::Value,
    schema: &serde_json::Value,
    at: &str,
    seen: &mut Vec<String>,
    emit: &mut dyn FnMut(serde_json::Value, String),
) {
    let Some(props) = schema["properties"].as_object() else {
        return;
    };
    for (name, prop) in props {
        let (target, index) = closed_target(schemas, prop);
        for (object, tag) in target {
            let path = format!("{at}.{name}{index}");
            if seen.contains(&path) || path.matches('.').count() > 6 {
                continue;
            }
            seen.push(path.clone());
            let mut inner = serde_json::Map::new();
            if let Some((k, v)) = &tag {
                inner.insert(k.clone(), v.clone());
            }
            let wrap = |inner: serde_json::Value| {
                let value = if index.is_empty() {
                    inner
                } else {
                    serde_json::json!([inner])
                };
                serde_json::json!({ name.as_str(): value })
            };
            let mut with_unknown = inner.clone();
            with_unknown.insert("zz_not_a_field".into(), serde_json::json!(1));
            emit(wrap(with_unknown.into()), path.clone());
            nested_probes(schemas, &object, &path, seen, &mut |body, deeper| {
                let mut body_inner = inner.clone();
                if let Some(o) = body.as_object() {
                    body_inner.extend(o.clone());
                }
                emit(wrap(body_inner.into()), deeper)
            });
        }
    }
}

/// The closed objects a property holds (one, or one per tagged alternative, each with its
/// tag), and `[0]` when they are array items.
#[allow(clippy::type_complexity)]
fn closed_target(
    schemas: &serde_json::Value,
    prop: &serde_json::Value,
) -> (
    Vec<(serde_json::Value, Option<(String, serde_json::Value)>)>,
    &'static str,
) {
    let mut s = resolve_ref(schemas, prop);
    // a nullable reference: `oneOf: [{type: null}, X]`
    if let Some(alts) = s["oneOf"].as_array() {
        let non_null: Vec<_> = alts.iter().filter(|a| a["type"] != "null").collect();
        if non_null.len() == 1 && alts.len() == 2 {
            s = resolve_ref(schemas, non_null[0]);
        }
    }
    let mut index = "";
    let is_array = s["type"] == "array"
        || s["type"]
            .as_array()
            .is_some_and(|t| t.iter().any(|t| t == "array"));
    if is_array {
        s = resolve_ref(schemas, &s["items"]);
        index = "[0]";
    }
    if s["additionalProperties"] == false && s["properties"].is_object() {
        return (vec![(s, None)], index);
    }
    let mut out = Vec::new();
    for alt in s["oneOf"].as_array().into_iter().flatten() {
        let alt = resolve_ref(schemas, alt);
        if alt["additionalProperties"] != false {
            continue;
        }
        let tag = alt["properties"].as_object().and_then(|p| {
            p.iter().find_map(|(k, v)| match v["enum"].as_array() {
                Some(e)
                    if e.len() == 1 && alt["required"].as_array()?.contains(&k.clone().into()) =>
                {
                    Some((k.clone(), e[0].clone()))
                }
                _ => None,
            })
        });
        if tag.is_some() {
            out.push((alt, tag));
        }
    }
    (out, index)
}

fn resolve_ref<'a>(
    schemas: &'a serde_json::Value,
    mut s: &'a serde_json::Value,
) -> serde_json::Value {
    while let Some(r) = s.get("$ref").and_then(|r| r.as_str()) {
        s = &schemas[r.trim_start_matches("#/components/schemas/")];
    }
    s.clone()
}
