use crate::helpers::spawn_app;

#[tokio::test]
async fn healthz_answers_ok_with_a_request_id() {
    let app = spawn_app().await;
    let res = app.get("/healthz").await;
    assert_eq!(res.status(), 200);
    assert!(res.headers().contains_key("x-request-id"));
    let body: serde_json::Value = res.json().await.unwrap();
    assert_eq!(body["status"], "ok");
}

#[tokio::test]
async fn readyz_answers_when_the_database_does() {
    let app = spawn_app().await;
    let res = app.get("/readyz").await;
    assert_eq!(res.status(), 200);
    let body: serde_json::Value = res.json().await.unwrap();
    assert_eq!(body["status"], "ready");
}

#[tokio::test]
async fn a_client_request_id_is_echoed_back() {
    let app = spawn_app().await;
    let res = app
        .client
        .get(app.url("/healthz"))
        .header("x-request-id", "abc-123")
        .send()
        .await
        .unwrap();
    assert_eq!(res.headers()["x-request-id"], "abc-123");
}

#[tokio::test]
async fn the_database_folder_is_created_when_missing() {
    let app = spawn_app().await;
    assert!(app._dir.path().join("db/test.db").exists());
}

#[tokio::test]
async fn swagger_ui_is_served_from_the_binary() {
    let app = spawn_app().await;
    let res = app.get("/docs/").await;
    assert_eq!(res.status(), 200);
    let html = res.text().await.unwrap();
    assert!(html.contains("swagger"), "{html}");
    // The vendored bundle, not a CDN, provides the script.
    let res = app.get("/docs/swagger-ui-bundle.js").await;
    assert_eq!(res.status(), 200);
}

/// Without seeding, the status says so, lists every bundled robot without a default model, and
/// counts jobs as `/v1/jobs` does.
#[tokio::test]
async fn status_reports_seeding_default_models_and_jobs() {
    let app = crate::helpers::spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await;
    let job = app.start_sleep_job(2, 5).await;
    app.wait_job(job["id"].as_str().unwrap(), |j| j["status"] == "succeeded")
        .await;
    let res = app.get("/v1/status").await;
    assert_eq!(res.status(), 200);
    let s: serde_json::Value = res.json().await.unwrap();
    assert_eq!(s["seeding"]["state"], "disabled", "{s}");
    assert_eq!(s["seeding"]["trained"], 0, "{s}");
    let robots: serde_json::Value = app.get("/v1/robots").await.json().await.unwrap();
    let ids = |v: &serde_json::Value| -> Vec<String> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|r| r["id"].as_str().unwrap().to_owned())
            .collect()
    };
    assert_eq!(ids(&s["robots"]), ids(&robots["items"]));
    assert_eq!(
        s["seeding"]["bundled"],
        robots["items"].as_array().unwrap().len()
    );
    for r in s["robots"].as_array().unwrap() {
        assert_eq!(r["default_model"]["state"], "none", "{r}");
        assert!(r["default_model"]["trained_at"].is_null(), "{r}");
    }
    let listed: serde_json::Value = app
        .get("/v1/jobs?status=succeeded&limit=100")
        .await
        .json()
        .await
        .unwrap();
    let succeeded = listed["items"].as_array().unwrap().len();
    assert_eq!(s["jobs"]["succeeded"], succeeded, "{s}");
    assert!(succeeded >= 1);
    assert_eq!(s["workers"], 0);
}
