//! `/v1/jobs` through the TEST-ONLY sleep job.

use std::time::Duration;

use futures::StreamExt;
use serde_json::{Value, json};

use crate::helpers::{assert_problem, spawn_app, spawn_app_with};

#[tokio::test]
async fn a_submitted_job_is_listed_and_succeeds() {
    let app = spawn_app().await;
    let res = app
        .post_json("/v1/_test/jobs/sleep", &json!({"steps": 3, "step_ms": 5}))
        .await;
    assert_eq!(res.status(), 202);
    let location = res.headers()["location"].to_str().unwrap().to_owned();
    let job: Value = res.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_owned();
    assert_eq!(location, format!("/v1/jobs/{id}"));
    assert_eq!(job["kind"], "test.sleep");
    let done = app.wait_job(&id, |j| j["status"] == "succeeded").await;
    assert_eq!(done["progress"]["fraction"], 1.0);
    assert_eq!(done["progress"]["message"], "slept 3 steps");
    let list: Value = app
        .get("/v1/jobs?status=succeeded&kind=test.sleep")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(list["items"][0]["id"], id.as_str());
    let none: Value = app
        .get("/v1/jobs?status=running")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(none["items"].as_array().unwrap().len(), 0);
}

#[tokio::test]
async fn a_failing_job_reports_its_reason() {
    let app = spawn_app().await;
    let res = app
        .post_json(
            "/v1/_test/jobs/sleep",
            &json!({"steps": 3, "step_ms": 1, "fail_at": 1}),
        )
        .await;
    let id = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let done = app.wait_job(&id, |j| j["status"] == "failed").await;
    assert_eq!(done["error"]["reason"], "failed");
    assert!(
        done["error"]["message"]
            .as_str()
            .unwrap()
            .contains("step 1")
    );
}

#[tokio::test]
async fn events_stream_progress_until_one_final_event() {
    let app = spawn_app().await;
    let job = app.start_sleep_job(5, 40).await;
    let id = job["id"].as_str().unwrap();
    let res = app.get(&format!("/v1/jobs/{id}/events")).await;
    assert_eq!(res.status(), 200);
    assert!(
        res.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/event-stream")
    );
    let mut body = String::new();
    let mut stream = res.bytes_stream();
    let read = async {
        while let Some(chunk) = stream.next().await {
            body.push_str(&String::from_utf8_lossy(&chunk.unwrap()));
        }
    };
    tokio::time::timeout(Duration::from_secs(10), read)
        .await
        .expect("stream ends");
    let events: Vec<(String, Value)> = body
        .split("\n\n")
        .filter_map(|block| {
            let name = block.lines().find_map(|l| l.strip_prefix("event: "))?;
            let data = block.lines().find_map(|l| l.strip_prefix("data: "))?;
            Some((name.to_owned(), serde_json::from_str(data).unwrap()))
        })
        .collect();
    let finals: Vec<_> = events.iter().filter(|(n, _)| n == "final").collect();
    assert_eq!(finals.len(), 1, "{body}");
    assert_eq!(events.last().unwrap().0, "final");
    assert_eq!(events.last().unwrap().1["status"], "succeeded");
    assert!(
        events
            .iter()
            .any(|(n, j)| n == "progress" && j["status"] == "running"),
        "{body}"
    );
    // Fractions never go backwards.
    let fractions: Vec<f64> = events
        .iter()
        .map(|(_, j)| j["progress"]["fraction"].as_f64().unwrap())
        .collect();
    assert!(fractions.windows(2).all(|w| w[0] <= w[1]), "{fractions:?}");
    // A finished job answers with its final event only.
    let again = app
        .get(&format!("/v1/jobs/{id}/events"))
        .await
        .text()
        .await
        .unwrap();
    assert_eq!(again.matches("event: final").count(), 1);
    assert_eq!(again.matches("event: progress").count(), 0);
}

#[tokio::test]
async fn cancelling_a_running_job_ends_it_cancelled_and_a_second_cancel_conflicts() {
    let app = spawn_app().await;
    let job = app.start_sleep_job(1000, 10).await;
    let id = job["id"].as_str().unwrap();
    app.wait_job(id, |j| j["status"] == "running").await;
    let res = app
        .post_json(&format!("/v1/jobs/{id}/cancel"), &json!({}))
        .await;
    assert_eq!(res.status(), 202);
    let done = app.wait_job(id, |j| j["status"] == "cancelled").await;
    assert_eq!(done["cancel_requested"], true);
    let res = app
        .client
        .post(app.url(&format!("/v1/jobs/{id}/cancel")))
        .send()
        .await
        .unwrap();
    let p = assert_problem(res, 409, "conflict").await;
    assert!(p["detail"].as_str().unwrap().contains("cancelled"));
    // The conflict changed nothing.
    let after: Value = app
        .get(&format!("/v1/jobs/{id}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(after, done);
}

#[tokio::test]
async fn cancelling_a_succeeded_job_is_a_409_that_changes_nothing() {
    let app = spawn_app().await;
    let job = app.start_sleep_job(1, 1).await;
    let id = job["id"].as_str().unwrap();
    let done = app.wait_job(id, |j| j["status"] == "succeeded").await;
    let res = app
        .client
        .post(app.url(&format!("/v1/jobs/{id}/cancel")))
        .send()
        .await
        .unwrap();
    assert_problem(res, 409, "conflict").await;
    let after: Value = app
        .get(&format!("/v1/jobs/{id}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(after, done);
}

#[tokio::test]
async fn jobs_beyond_the_concurrency_limit_wait_queued() {
    let app = spawn_app_with(|c| c.job_concurrency = Some(1)).await;
    let first = app.start_sleep_job(1000, 10).await;
    let second = app.start_sleep_job(1, 1).await;
    let (a, b) = (
        first["id"].as_str().unwrap(),
        second["id"].as_str().unwrap(),
    );
    app.wait_job(a, |j| j["status"] == "running").await;
    let queued: Value = app
        .get(&format!("/v1/jobs/{b}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(queued["status"], "queued");
    app.client
        .post(app.url(&format!("/v1/jobs/{a}/cancel")))
        .send()
        .await
        .unwrap();
    app.wait_job(b, |j| j["status"] == "succeeded").await;
}
