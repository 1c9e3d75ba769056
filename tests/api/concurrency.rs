//! Concurrent writers: 100 write jobs of mixed kinds, uploads and deletes at once all succeed.
//!
//! SQLite in WAL mode has one writer at a time. A transaction that starts deferred, reads, and
//! only then writes cannot take the write lock once another connection has committed since its
//! read (SQLITE_BUSY_SNAPSHOT, at once, whatever the busy timeout), so such jobs used to end
//! `failed: internal` and such deletes answered 500. Every write transaction now starts
//! `BEGIN IMMEDIATE` and waits its turn (`store::begin_write`; the deterministic two-connection
//! case is a unit test there).

use futures::future::join_all;
use serde_json::{Value, json};

use crate::helpers::{TestApp, spawn_app_with};

fn finished(j: &Value) -> bool {
    j["status"] != "queued" && j["status"] != "running"
}

async fn submit(app: &TestApp, path: &str, body: Value) -> String {
    let res = app.post_json(path, &body).await;
    assert_eq!(res.status(), 202, "{path} {body}");
    let job: Value = res.json().await.unwrap();
    job["id"].as_str().unwrap().to_owned()
}

async fn study_ids(app: &TestApp, seed: u64, positions: u32) -> (String, Vec<String>) {
    let job = submit(
        app,
        "/v1/demonstrations/synthetic",
        json!({"seed": seed, "subjects": 1, "positions": positions, "trials": 2}),
    )
    .await;
    let done = app.wait_job(&job, finished).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let listed: Value = app
        .get(&format!("/v1/demonstrations?job_id={job}&limit=100"))
        .await
        .json()
        .await
        .unwrap();
    let ids = listed["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["id"].as_str().unwrap().to_owned())
        .collect();
    (job, ids)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_hundred_concurrent_write_jobs_uploads_and_deletes_all_succeed() {
    let app = spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots");
        c.job_concurrency = Some(6);
    })
    .await;
    // Demonstrations the mappings read, and others deleted while everything else writes.
    let (mapped, _) = study_ids(&app, 100, 1).await;
    let (_, victims) = study_ids(&app, 101, 5).await;
    assert_eq!(victims.len(), 10);

    // 60 studies (each stores its demonstrations in one transaction as it ends) and 40
    // mappings (each stores its trajectories), submitted at once.
    let studies = (0..60u64).map(|k| {
        submit(
            &app,
            "/v1/demonstrations/synthetic",
            json!({"seed": k, "subjects": 1, "positions": 1, "trials": 2}),
        )
    });
    let robots = ["wam_t42", "pa10_ihy"];
    let mappings = (0..40usize).map(|k| {
        submit(
            &app,
            "/v1/mappings",
            json!({"robot": robots[k % 2], "demonstrations": {"job_id": mapped},
                   "output_rate_hz": 30}),
        )
    });
    let (studies, mappings) = tokio::join!(join_all(studies), join_all(mappings));

    // Meanwhile: deletes one by one, and uploads read back.
    let mut deletes = Vec::new();
    for id in &victims {
        let res = app
            .client
            .delete(app.url(&format!("/v1/demonstrations/{id}")))
            .send()
            .await
            .unwrap();
        deletes.push(res.status().as_u16());
    }
    assert!(deletes.iter().all(|&s| s == 204), "deletes: {deletes:?}");

    let mut failed = Vec::new();
    for id in studies.iter().chain(&mappings) {
        let done = app.wait_job(id, finished).await;
        if done["status"] != "succeeded" {
            failed.push(done);
        }
    }
    assert!(
        failed.is_empty(),
        "{} of 100 jobs failed: {failed:?}",
        failed.len()
    );
    let listed: Value = app
        .get("/v1/demonstrations?synthetic=true&limit=1")
        .await
        .json()
        .await
        .unwrap();
    // 60 studies of 2 plus the mapped study's 2; the deleted ones are gone.
    assert_eq!(listed["total"], 60 * 2 + 2);
}
