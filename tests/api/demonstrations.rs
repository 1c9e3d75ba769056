//! `/v1/demonstrations`: uploads (JSON and multipart CSV), idempotency, queries, frames, delete,
//! the synthetic-study job, and every rejection (422 naming stream, sample index and field;
//! nothing stored).

use reachgrasp::human::csv::{glove_to_csv, tracker_to_csv};
use reachgrasp::human::{DemonstrationInput, StudyConfig, generate_study};
use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, spawn_app, spawn_app_with};

/// A short, noise-free synthetic demonstration (the upload format).
fn sample(external_id: &str) -> DemonstrationInput {
    let cfg = StudyConfig {
        subjects: 1,
        positions: 1,
        trials: 1,
        noise: false,
        ..StudyConfig::default()
    };
    let mut d = generate_study(&cfg).unwrap().remove(0);
    d.labels.external_id = Some(external_id.to_string());
    d.labels.synthetic = false;
    d
}

async fn upload(app: &TestApp, body: &DemonstrationInput) -> reqwest::Response {
    app.post_json("/v1/demonstrations", &serde_json::to_value(body).unwrap())
        .await
}

async fn upload_csv(app: &TestApp, d: &DemonstrationInput) -> reqwest::Response {
    let meta =
        json!({"subject": d.subject, "object": d.object, "labels": d.labels, "sync": d.sync});
    let form = reqwest::multipart::Form::new()
        .text("meta", meta.to_string())
        .part(
            "tracker",
            reqwest::multipart::Part::text(tracker_to_csv(&d.tracker)).file_name("tracker.csv"),
        )
        .part(
            "glove",
            reqwest::multipart::Part::text(glove_to_csv(&d.glove)).file_name("glove.csv"),
        );
    app.client
        .post(app.url("/v1/demonstrations"))
        .multipart(form)
        .send()
        .await
        .expect("request")
}

async fn total(app: &TestApp) -> u64 {
    let list: Value = app.get("/v1/demonstrations").await.json().await.unwrap();
    list["total"].as_u64().unwrap()
}

/// Asserts a 422 whose single field error has `path` and a message naming `words`, and that
/// nothing was stored.
async fn assert_rejected(app: &TestApp, res: reqwest::Response, path: &str, words: &[&str]) {
    let body = assert_problem(res, 422, "validation").await;
    assert_eq!(body["errors"][0]["path"], path, "{body}");
    let msg = body["errors"][0]["message"].as_str().unwrap();
    for w in words {
        assert!(msg.contains(w), "`{msg}` should mention `{w}`");
    }
    assert_eq!(total(app).await, 0);
}

#[tokio::test]
async fn a_json_upload_is_stored_with_its_summary_and_derived_frames() {
    let app = spawn_app().await;
    let d = sample("lab-1");
    let res = upload(&app, &d).await;
    assert_eq!(res.status(), 201);
    let location = res.headers()["location"].to_str().unwrap().to_string();
    let created: Value = res.json().await.unwrap();
    let id = created["id"].as_str().unwrap();
    assert_eq!(location, format!("/v1/demonstrations/{id}"));
    let s = &created["summary"];
    assert_eq!(s["rate_hz"], 120.0);
    assert!((s["tracker_rate_hz"].as_f64().unwrap() - 240.0).abs() < 1e-6);
    assert!((s["glove_rate_hz"].as_f64().unwrap() - 90.0).abs() < 1e-6);
    let frames = s["frames"].as_u64().unwrap();
    let duration = s["duration_s"].as_f64().unwrap();
    assert!(((frames - 1) as f64 / 120.0 - duration).abs() < 1e-9);
    assert_eq!(created["subject"]["id"], "S1");

    let got: Value = app.get(&location).await.json().await.unwrap();
    assert_eq!(got["id"], created["id"]);

    let all: Value = app
        .get(&format!("{location}/frames"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(all["frames"].as_array().unwrap().len() as u64, frames);
    let f0 = &all["frames"][0];
    assert_eq!(f0["fingertips"].as_array().unwrap().len(), 5);
    assert_eq!(f0["glove"].as_array().unwrap().len(), 22);
    assert_eq!(f0["wrist"]["orientation"].as_array().unwrap().len(), 4);
    let half: Value = app
        .get(&format!("{location}/frames?every=2"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(
        half["frames"].as_array().unwrap().len() as u64,
        frames.div_ceil(2)
    );
    assert_eq!(half["rate_hz"], 60.0);
    assert_eq!(half["frames"][1]["t"], all["frames"][2]["t"]);
    assert_problem(
        app.get(&format!("{location}/frames?every=0")).await,
        400,
        "invalid-parameter",
    )
    .await;
}

#[tokio::test]
async fn re_uploading_the_same_external_id_returns_the_existing_record() {
    let app = spawn_app().await;
    let d = sample("lab-dup");
    let first: Value = upload(&app, &d).await.json().await.unwrap();
    let res = upload(&app, &d).await;
    assert_eq!(res.status(), 200);
    let second: Value = res.json().await.unwrap();
    assert_eq!(first["id"], second["id"]);
    // Also through the CSV form.
    let res = upload_csv(&app, &d).await;
    assert_eq!(res.status(), 200);
    assert_eq!(total(&app).await, 1);
}

#[tokio::test]
async fn a_multipart_csv_upload_gives_the_same_frames_as_json() {
    let app = spawn_app().await;
    let json_doc: Value = upload(&app, &sample("as-json")).await.json().await.unwrap();
    let res = upload_csv(&app, &sample("as-csv")).await;
    assert_eq!(res.status(), 201);
    let csv_doc: Value = res.json().await.unwrap();
    // JSON number parsing may differ from CSV parsing in the last bit: compare with tolerance.
    let (sa, sb) = (&csv_doc["summary"], &json_doc["summary"]);
    assert_eq!(sa["frames"], sb["frames"]);
    for k in ["duration_s", "start_s", "tracker_rate_hz", "glove_rate_hz"] {
        assert!(
            (sa[k].as_f64().unwrap() - sb[k].as_f64().unwrap()).abs() < 1e-9,
            "{k}"
        );
    }
    let frames = |doc: &Value| {
        let id = doc["id"].as_str().unwrap().to_string();
        let app = &app;
        async move {
            let v: Value = app
                .get(&format!("/v1/demonstrations/{id}/frames"))
                .await
                .json()
                .await
                .unwrap();
            v["frames"].clone()
        }
    };
    let (a, b) = (frames(&json_doc).await, frames(&csv_doc).await);
    let tip = |v: &Value, k: usize| v[k]["fingertips"][1]["position"][0].as_f64().unwrap();
    for k in [0, 50, 100] {
        assert!((tip(&a, k) - tip(&b, k)).abs() < 1e-9);
    }
}

#[tokio::test]
async fn listing_filters_by_subject_object_and_synthetic_flag_and_pages() {
    let app = spawn_app().await;
    for k in 0..3 {
        let mut d = sample(&format!("lab-{k}"));
        d.subject.id = format!("P{}", k % 2);
        d.labels.synthetic = k == 2;
        assert_eq!(upload(&app, &d).await.status(), 201);
    }
    let q = |path: &'static str| {
        let app = &app;
        async move {
            let v: Value = app.get(path).await.json().await.unwrap();
            (
                v["total"].as_u64().unwrap(),
                v["items"].as_array().unwrap().len(),
            )
        }
    };
    assert_eq!(q("/v1/demonstrations?subject=P0").await, (2, 2));
    assert_eq!(q("/v1/demonstrations?synthetic=true").await, (1, 1));
    assert_eq!(
        q("/v1/demonstrations?object=ball&synthetic=false").await.0,
        2
    );
    assert_eq!(q("/v1/demonstrations?object=pencil").await.0, 0);
    assert_eq!(q("/v1/demonstrations?limit=2").await, (3, 2));
    assert_eq!(q("/v1/demonstrations?limit=2&offset=2").await, (3, 1));
    assert_problem(
        app.get("/v1/demonstrations?limit=0").await,
        400,
        "invalid-parameter",
    )
    .await;
}

#[tokio::test]
async fn delete_removes_it_and_refuses_while_a_mapping_uses_it_unless_cascading() {
    let app = spawn_app().await;
    let a: Value = upload(&app, &sample("del-a")).await.json().await.unwrap();
    let b: Value = upload(&app, &sample("del-b")).await.json().await.unwrap();
    let (a, b) = (a["id"].as_str().unwrap(), b["id"].as_str().unwrap());
    let res = app
        .client
        .delete(app.url(&format!("/v1/demonstrations/{a}")))
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 204);
    assert_problem(
        app.get(&format!("/v1/demonstrations/{a}")).await,
        404,
        "not-found",
    )
    .await;
    let res = app
        .client
        .delete(app.url(&format!("/v1/demonstrations/{a}")))
        .send()
        .await
        .unwrap();
    assert_problem(res, 404, "not-found").await;

    // A stored mapping (migration 0005) whose results include `b`. Written directly: mapping a
    // real study is what tests/api/mappings.rs does; here only the link matters.
    let db = sqlx::SqlitePool::connect(&format!(
        "sqlite:{}",
        app._dir.path().join("db/test.db").display()
    ))
    .await
    .unwrap();
    for sql in [
        "INSERT INTO jobs (id, kind, status, created_at) VALUES ('j1', 'mapping', 'succeeded', '2026')",
        "INSERT INTO mappings (id, job_id, robot, request, summary, created_at) \
         VALUES ('m1', 'j1', 'wam_ihy', '{}', '{}', '2026')",
        "INSERT INTO mapping_demonstrations (mapping_id, position, demonstration_id, subject_id, \
         object_name, task, position_index, trial, joint_names, frame_count, frames, metrics, \
         registration, summary) VALUES ('m1', 0, ?, 'S1', 'ball', 'grasp', 0, 0, '[]', 0, x'', \
         x'', '{}', '{}')",
    ] {
        let q = sqlx::query(sql);
        let q = if sql.contains('?') { q.bind(b) } else { q };
        q.execute(&db).await.unwrap();
    }
    let res = app
        .client
        .delete(app.url(&format!("/v1/demonstrations/{b}")))
        .send()
        .await
        .unwrap();
    let body = assert_problem(res, 409, "conflict").await;
    assert!(body["detail"].as_str().unwrap().contains("m1"));
    let res = app
        .client
        .delete(app.url(&format!("/v1/demonstrations/{b}?cascade=true")))
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 204);
    let left: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM mappings")
        .fetch_one(&db)
        .await
        .unwrap();
    assert_eq!(left, 0);
    assert_eq!(total(&app).await, 0);
}

#[tokio::test]
async fn a_synthetic_study_runs_as_a_job_and_repeating_it_stores_nothing_twice() {
    let app = spawn_app().await;
    let req = json!({"seed": 3, "subjects": 1, "positions": 2, "trials": 1});
    for _ in 0..2 {
        let res = app.post_json("/v1/demonstrations/synthetic", &req).await;
        assert_eq!(res.status(), 202);
        let job: Value = res.json().await.unwrap();
        let id = job["id"].as_str().unwrap();
        let done = app
            .wait_job(id, |j| j["status"] != "queued" && j["status"] != "running")
            .await;
        assert_eq!(done["status"], "succeeded", "{done}");
        assert_eq!(done["result"]["resource"], "demonstrations");
    }
    let list: Value = app
        .get("/v1/demonstrations?synthetic=true")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(list["total"], 2);
    assert!(
        list["items"][0]["external_id"]
            .as_str()
            .unwrap()
            .starts_with("synth-3-S1-")
    );
    let res = app
        .post_json("/v1/demonstrations/synthetic", &json!({"trials": 0}))
        .await;
    let body = assert_problem(res, 422, "validation").await;
    assert_eq!(body["errors"][0]["path"], "$.trials");
}

mod rejections {
    use super::*;

    #[tokio::test]
    async fn timestamps_that_do_not_increase() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.tracker.t[10] = d.tracker.t[9];
        let res = upload(&app, &d).await;
        assert_rejected(&app, res, "$.tracker.t[10]", &["tracker", "sample 10"]).await;
    }

    #[tokio::test]
    async fn nan_values_in_a_csv_file() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.glove.angles.as_mut().unwrap()[7][3] = f64::NAN;
        let res = upload_csv(&app, &d).await;
        assert_rejected(
            &app,
            res,
            "$.glove.angles[7]",
            &["glove", "sample 7", "angles[3]"],
        )
        .await;
    }

    #[tokio::test]
    async fn a_row_of_the_wrong_width() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.tracker.wrist[4].push(0.0);
        let res = upload(&app, &d).await;
        assert_rejected(
            &app,
            res,
            "$.tracker.wrist[4]",
            &["tracker", "sample 4", "wrist"],
        )
        .await;
        // The same in a CSV file: a short row.
        let mut d = sample("bad");
        d.tracker.elbow[6].pop();
        let res = upload_csv(&app, &d).await;
        assert_rejected(&app, res, "$.tracker.row[6]", &["tracker", "sample 6"]).await;
    }

    #[tokio::test]
    async fn a_gap_longer_than_the_limit() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.sync.max_gap_s = 0.05;
        for t in &mut d.glove.t[20..] {
            *t += 0.1;
        }
        let res = upload(&app, &d).await;
        assert_rejected(&app, res, "$.glove.t[20]", &["glove", "sample 20", "gap"]).await;
    }

    #[tokio::test]
    async fn a_glove_angle_beyond_180_degrees() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.glove.angles.as_mut().unwrap()[12][9] = 4.0;
        let res = upload(&app, &d).await;
        assert_rejected(
            &app,
            res,
            "$.glove.angles[12]",
            &["sample 12", "middle_mcp_flexion"],
        )
        .await;
    }

    #[tokio::test]
    async fn a_position_farther_than_three_metres() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.tracker.elbow[30] = vec![3.5, 0.0, 0.0];
        let res = upload(&app, &d).await;
        assert_rejected(&app, res, "$.tracker.elbow[30]", &["sample 30", "3 m"]).await;
    }

    #[tokio::test]
    async fn a_quaternion_that_cannot_be_normalised() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.tracker.wrist_orientation[2] = vec![0.0; 4];
        let res = upload(&app, &d).await;
        assert_rejected(
            &app,
            res,
            "$.tracker.wrist_orientation[2]",
            &["sample 2", "normalised"],
        )
        .await;
    }

    #[tokio::test]
    async fn an_empty_stream() {
        let app = spawn_app().await;
        let mut d = sample("bad");
        d.glove.t.clear();
        d.glove.angles = Some(vec![]);
        let res = upload(&app, &d).await;
        assert_rejected(&app, res, "$.glove", &["glove", "empty"]).await;
    }

    #[tokio::test]
    async fn a_body_over_the_size_limit() {
        let app = spawn_app_with(|c| c.body_limit = 64 * 1024).await;
        let res = upload(&app, &sample("big")).await;
        assert_problem(res, 413, "payload-too-large").await;
        assert_eq!(total(&app).await, 0);
    }

    #[tokio::test]
    async fn a_misspelt_nested_field_in_json_or_in_the_meta_part() {
        let app = spawn_app().await;
        let d = sample("typo");
        // The typo is the only problem: the same body without it is stored (checked last).
        let mut body = serde_json::to_value(&d).unwrap();
        body["subject"]["heigth"] = json!(1.8);
        let res = app.post_json("/v1/demonstrations", &body).await;
        assert_rejected(&app, res, "$.subject.heigth", &["unknown field `heigth`"]).await;
        let mut body = serde_json::to_value(&d).unwrap();
        body["object"]["pose"]["rotation"] = json!([1, 0, 0, 0]);
        let res = app.post_json("/v1/demonstrations", &body).await;
        assert_rejected(&app, res, "$.object.pose.rotation", &["unknown field"]).await;
        let mut body = serde_json::to_value(&d).unwrap();
        body["glove"]["calibraton"] = json!({"gain": vec![1.0; 22], "offset": vec![0.0; 22]});
        let res = app.post_json("/v1/demonstrations", &body).await;
        assert_rejected(&app, res, "$.glove.calibraton", &["unknown field"]).await;

        // the same recording as a multipart upload with the given `meta`
        let multipart = |meta: Value| {
            let form = reqwest::multipart::Form::new()
                .text("meta", meta.to_string())
                .text("tracker", tracker_to_csv(&d.tracker))
                .text("glove", glove_to_csv(&d.glove));
            app.client
                .post(app.url("/v1/demonstrations"))
                .multipart(form)
                .send()
        };
        let meta = json!({"subject": d.subject, "object": d.object,
                          "labels": {"task": "grasp", "trail": 3}});
        let res = multipart(meta).await.unwrap();
        assert_rejected(&app, res, "meta.labels.trail", &["unknown field `trail`"]).await;
        let meta = json!({"object": d.object, "labels": d.labels});
        let res = multipart(meta).await.unwrap();
        assert_rejected(&app, res, "meta.subject", &["missing field `subject`"]).await;

        assert_eq!(upload(&app, &d).await.status(), 201);
    }

    #[tokio::test]
    async fn a_missing_csv_part() {
        let app = spawn_app().await;
        let d = sample("bad");
        let meta = json!({"subject": d.subject, "object": d.object, "labels": d.labels});
        let form = reqwest::multipart::Form::new()
            .text("meta", meta.to_string())
            .text("tracker", tracker_to_csv(&d.tracker));
        let res = app
            .client
            .post(app.url("/v1/demonstrations"))
            .multipart(form)
            .send()
            .await
            .unwrap();
        assert_rejected(&app, res, "glove", &["missing"]).await;
    }
}

/// A bad upload whose `external_id` was already stored came back 200 with the stored record,
/// unvalidated: it is the same 422 as without a known id, and the stored record stays.
#[tokio::test]
async fn a_bad_upload_with_a_known_external_id_is_refused_as_without_it() {
    let app = spawn_app().await;
    let stored: Value = upload(&app, &sample("lab-known"))
        .await
        .json()
        .await
        .unwrap();
    let mut bad = sample("lab-known");
    bad.tracker.t[10] = bad.tracker.t[9];
    let known = assert_problem(upload(&app, &bad).await, 422, "validation").await;
    assert_eq!(known["errors"][0]["path"], "$.tracker.t[10]", "{known}");
    bad.labels.external_id = Some("lab-unknown".into());
    let unknown = assert_problem(upload(&app, &bad).await, 422, "validation").await;
    assert_eq!(known["errors"], unknown["errors"]);
    // An object out of range, and a short row in the CSV form.
    let mut bad = sample("lab-known");
    bad.object.shape = reachgrasp::human::ObjectShape::Sphere { radius: 5.0 };
    let p = assert_problem(upload(&app, &bad).await, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.object.shape.radius", "{p}");
    let mut bad = sample("lab-known");
    bad.tracker.elbow[6].pop();
    let p = assert_problem(upload_csv(&app, &bad).await, 422, "validation").await;
    assert_eq!(p["errors"][0]["path"], "$.tracker.row[6]", "{p}");
    assert_eq!(total(&app).await, 1);
    // A valid re-upload still answers the stored record.
    let res = upload(&app, &sample("lab-known")).await;
    assert_eq!(res.status(), 200);
    let again: Value = res.json().await.unwrap();
    assert_eq!(again, stored);
}

/// The object's shape is a tagged enum, read from a buffer where its errors lost their path
/// (`$.object.shape`); its pose holds fixed-size arrays, whose extra items were a 400.
#[tokio::test]
async fn a_bad_object_field_is_named_in_an_upload() {
    let app = spawn_app().await;
    let mut body = serde_json::to_value(sample("obj")).unwrap();
    body["object"]["shape"] = json!({"type": "cylinder", "radius": 0.03, "height": "tall"});
    let res = app.post_json("/v1/demonstrations", &body).await;
    assert_rejected(
        &app,
        res,
        "$.object.shape.height",
        &["invalid type: string \"tall\", expected f64"],
    )
    .await;
    let mut body = serde_json::to_value(sample("obj")).unwrap();
    body["object"]["pose"]["position"] = json!([0.1, 0.2, 0.3, 0.4]);
    let res = app.post_json("/v1/demonstrations", &body).await;
    assert_rejected(
        &app,
        res,
        "$.object.pose.position",
        &["expected 3 items, got 4"],
    )
    .await;
}
