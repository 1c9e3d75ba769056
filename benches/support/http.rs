//! What the service benches share: a job run to its end over HTTP, and a small study trained as
//! a robot's default model.

use std::time::Duration;

use serde_json::{Value, json};

/// Submits a job and waits for it; the id of what it stored (its `Content-Location`), else the
/// job's.
pub async fn run_job(client: &reqwest::Client, base: &str, path: &str, body: Value) -> String {
    let res = client
        .post(format!("{base}{path}"))
        .json(&body)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 202, "{path}");
    let resource = res
        .headers()
        .get("content-location")
        .map(|v| v.to_str().unwrap().rsplit('/').next().unwrap().to_owned());
    let job: Value = res.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_owned();
    for _ in 0..6000 {
        let j: Value = client
            .get(format!("{base}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if j["status"] != "queued" && j["status"] != "running" {
            assert_eq!(j["status"], "succeeded", "{path}: {j}");
            return resource.unwrap_or(id);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("job {id} did not finish");
}

/// A small study (seed 5, 15 demonstrations) mapped onto `robot` and trained as its default
/// model: the model id and a start where the demonstrations started.
pub async fn trained(client: &reqwest::Client, base: &str, robot: &str) -> (String, Value) {
    let study = run_job(
        client,
        base,
        "/v1/demonstrations/synthetic",
        json!({"seed": 5, "subjects": 1, "positions": 5, "trials": 3}),
    )
    .await;
    let mapping = run_job(
        client,
        base,
        "/v1/mappings",
        json!({"robot": robot, "demonstrations": {"job_id": study}, "output_rate_hz": 20}),
    )
    .await;
    let model = run_job(
        client,
        base,
        "/v1/models",
        json!({"robot": robot, "mappings": [mapping], "held_out": false, "default": true}),
    )
    .await;
    let m: Value = client
        .get(format!("{base}/v1/mappings/{mapping}?limit=1"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let t = &m["demonstrations"]["items"][0]["trajectory"];
    let start = json!({"joint_names": t["joint_names"], "positions": t["positions"][0]});
    (model, start)
}
