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
