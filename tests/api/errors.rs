//! Every bad input gets the right 4xx problem+json and changes nothing.

use serde_json::json;

use crate::helpers::{TestApp, assert_problem, field_strings, spawn_app, spawn_app_with};

const SLEEP: &str = "/v1/_test/jobs/sleep";

async fn assert_no_jobs(app: &TestApp) {
    let list: serde_json::Value = app.get("/v1/jobs").await.json().await.unwrap();
    assert_eq!(list["items"].as_array().unwrap().len(), 0, "{list}");
}

async fn post_raw(app: &TestApp, content_type: &str, body: &str) -> reqwest::Response {
    app.client
        .post(app.url(SLEEP))
        .header("content-type", content_type)
        .body(body.to_owned())
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn malformed_json_is_a_400_problem() {
    let app = spawn_app().await;
    let res = post_raw(&app, "application/json", r#"{"steps": 3, "#).await;
    let p = assert_problem(res, 400, "malformed-json").await;
    assert!(p["detail"].as_str().unwrap().contains("not valid JSON"));
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn a_non_json_content_type_is_a_415_problem() {
    let app = spawn_app().await;
    let res = post_raw(&app, "text/plain", r#"{"steps": 3, "step_ms": 1}"#).await;
    assert_problem(res, 415, "unsupported-media-type").await;
    let res = app.client.post(app.url(SLEEP)).send().await.unwrap();
    assert_problem(res, 415, "unsupported-media-type").await;
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn a_missing_field_is_a_422_naming_the_field() {
    let app = spawn_app().await;
    let res = app.post_json(SLEEP, &json!({"steps": 3})).await;
    let p = assert_problem(res, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.step_ms");
    assert!(
        p["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("missing field")
    );
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn a_wrong_type_is_a_422_naming_the_field() {
    let app = spawn_app().await;
    let res = app
        .post_json(SLEEP, &json!({"steps": "many", "step_ms": 1}))
        .await;
    let p = assert_problem(res, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.steps");
    assert!(
        p["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("invalid type")
    );
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn out_of_range_values_are_422_listing_every_field() {
    let app = spawn_app().await;
    let res = app
        .post_json(SLEEP, &json!({"steps": 0, "step_ms": 100000}))
        .await;
    let p = assert_problem(res, 422, "validation").await;
    let paths: Vec<&str> = field_strings(&p["errors"], "path");
    assert_eq!(paths, ["$.steps", "$.step_ms"]);
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn an_oversized_body_is_a_413_problem() {
    let app = spawn_app_with(|c| c.body_limit = 1024).await;
    let padding = "x".repeat(4096);
    let res = app
        .post_json(SLEEP, &json!({"steps": 1, "step_ms": 1, "pad": padding}))
        .await;
    assert_problem(res, 413, "payload-too-large").await;
    assert_no_jobs(&app).await;
}

#[tokio::test]
async fn an_unknown_route_is_a_404_problem() {
    let app = spawn_app().await;
    let p = assert_problem(app.get("/v1/nothing-here").await, 404, "not-found").await;
    assert!(p["detail"].as_str().unwrap().contains("/v1/nothing-here"));
}

#[tokio::test]
async fn a_wrong_method_is_a_405_problem_with_allow() {
    let app = spawn_app().await;
    let res = app.client.delete(app.url("/v1/jobs")).send().await.unwrap();
    assert!(res.headers().contains_key("allow"));
    assert_problem(res, 405, "method-not-allowed").await;
}

#[tokio::test]
async fn an_unknown_job_id_is_a_404_problem() {
    let app = spawn_app().await;
    let id = uuid::Uuid::new_v4();
    let p = assert_problem(app.get(&format!("/v1/jobs/{id}")).await, 404, "not-found").await;
    assert!(p["detail"].as_str().unwrap().contains(&id.to_string()));
    let res = app
        .post_json(&format!("/v1/jobs/{id}/cancel"), &json!({}))
        .await;
    assert_problem(res, 404, "not-found").await;
    assert_problem(
        app.get(&format!("/v1/jobs/{id}/events")).await,
        404,
        "not-found",
    )
    .await;
}

#[tokio::test]
async fn a_malformed_job_id_is_a_400_naming_the_parameter() {
    let app = spawn_app().await;
    let p = assert_problem(
        app.get("/v1/jobs/not-a-uuid").await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "id");
}

#[tokio::test]
async fn bad_query_parameters_are_400_naming_the_parameter() {
    let app = spawn_app().await;
    let p = assert_problem(
        app.get("/v1/jobs?limit=lots").await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "limit");
    let p = assert_problem(app.get("/v1/jobs?limit=0").await, 400, "invalid-parameter").await;
    assert_eq!(p["errors"][0]["path"], "limit");
    assert_problem(
        app.get("/v1/jobs?status=sleeping").await,
        400,
        "invalid-parameter",
    )
    .await;
}

#[tokio::test]
async fn test_job_routes_are_absent_unless_enabled() {
    let app = spawn_app_with(|c| c.test_jobs = false).await;
    let res = app
        .post_json(SLEEP, &json!({"steps": 1, "step_ms": 1}))
        .await;
    assert_problem(res, 404, "not-found").await;
}
