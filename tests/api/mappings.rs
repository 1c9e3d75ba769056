//! `/v1/mappings`: a mapping job on a small synthetic study (limits and couplings on every stored
//! frame, the data served back in pages), every rejection of bad input (4xx, nothing stored) and
//! cancellation (nothing stored).

use reachgrasp::human::{StudyConfig, generate_study};
use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, spawn_app_with, strings};

async fn app() -> TestApp {
    spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await
}

/// A small synthetic study (one subject, one position, `trials` trials); returns its job id.
async fn study(app: &TestApp, trials: u32) -> String {
    let res = app
        .post_json(
            "/v1/demonstrations/synthetic",
            &json!({"seed": 7, "subjects": 1, "positions": 1, "trials": trials}),
        )
        .await;
    assert_eq!(res.status(), 202);
    let job: Value = res.json().await.unwrap();
    let id = job["id"].as_str().unwrap().to_owned();
    let done = app
        .wait_job(&id, |j| j["status"] != "queued" && j["status"] != "running")
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    id
}

async fn demo_ids(app: &TestApp, job: &str) -> Vec<String> {
    let list: Value = app
        .get(&format!("/v1/demonstrations?job_id={job}"))
        .await
        .json()
        .await
        .unwrap();
    list["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["id"].as_str().unwrap().to_owned())
        .collect()
}

async fn mapping_count(app: &TestApp) -> u64 {
    let list: Value = app.get("/v1/mappings").await.json().await.unwrap();
    list["total"].as_u64().unwrap()
}

/// Submits a mapping job (202); returns the accepted job and the mapping's URL.
async fn submit_mapping(app: &TestApp, body: Value) -> (Value, String) {
    let res = app.post_json("/v1/mappings", &body).await;
    assert_eq!(res.status(), 202);
    let mapping_url = res.headers()["content-location"]
        .to_str()
        .unwrap()
        .to_owned();
    (res.json().await.unwrap(), mapping_url)
}

/// Two long sleep jobs: both job slots busy, so a job submitted next waits queued.
async fn occupy_job_slots(app: &TestApp) -> [Value; 2] {
    [
        app.start_sleep_job(400, 50).await,
        app.start_sleep_job(400, 50).await,
    ]
}

async fn mapping_jobs(app: &TestApp) -> usize {
    let list: Value = app.get("/v1/jobs").await.json().await.unwrap();
    let items = list
        .as_array()
        .or_else(|| list["items"].as_array())
        .cloned()
        .unwrap_or_default();
    items.iter().filter(|j| j["kind"] == "mapping").count()
}

#[tokio::test]
async fn a_mapping_job_stores_trajectories_within_the_limits_and_serves_them_in_pages() {
    let app = app().await;
    let job = study(&app, 2).await;
    let ids = demo_ids(&app, &job).await;
    assert_eq!(ids.len(), 2);

    let res = app
        .post_json(
            "/v1/mappings",
            &json!({"robot": "wam_ihy", "demonstrations": {"job_id": job, "synthetic": true},
                    "output_rate_hz": 30}),
        )
        .await;
    assert_eq!(res.status(), 202);
    let location = res.headers()["location"].to_str().unwrap().to_owned();
    let mapping_url = res.headers()["content-location"]
        .to_str()
        .unwrap()
        .to_owned();
    let accepted: Value = res.json().await.unwrap();
    let job_id = accepted["id"].as_str().unwrap().to_owned();
    assert_eq!(location, format!("/v1/jobs/{job_id}"));
    assert_eq!(accepted["kind"], "mapping");

    // The mapping is readable at once, with the job's status.
    let early: Value = app.get(&mapping_url).await.json().await.unwrap();
    assert_eq!(early["job_id"], job_id.as_str());
    assert_eq!(
        early["request"]["demonstrations"].as_array().unwrap().len(),
        2
    );

    let done = app
        .wait_job(&job_id, |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["result"]["href"], mapping_url.as_str());

    let robot: Value = app.get("/v1/robots/wam_ihy").await.json().await.unwrap();
    let joint_names: Vec<&str> = strings(&robot["joint_names"]);
    let joints = robot["joints"].as_array().unwrap();
    let limits = |name: &str| {
        let j = joints.iter().find(|j| j["name"] == name).unwrap();
        (
            j["lower"].as_f64().unwrap_or(f64::NEG_INFINITY),
            j["upper"].as_f64().unwrap_or(f64::INFINITY),
        )
    };

    let m: Value = app.get(&mapping_url).await.json().await.unwrap();
    assert_eq!(m["status"], "succeeded");
    let summary = &m["summary"];
    assert_eq!(summary["demonstrations"], 2);
    let page = &m["demonstrations"];
    assert_eq!(page["total"], 2);
    let items = page["items"].as_array().unwrap();
    assert_eq!(items.len(), 2);
    let mut frames_seen = 0;
    let mut worst_tip = 0.0_f64;
    for (k, item) in items.iter().enumerate() {
        assert_eq!(item["position"], k);
        assert_eq!(item["demonstration_id"], ids[k].as_str());
        let traj = &item["trajectory"];
        let names: Vec<&str> = strings(&traj["joint_names"]);
        assert_eq!(names, joint_names);
        let times = traj["times"].as_array().unwrap();
        let rows = traj["positions"].as_array().unwrap();
        assert!(times.len() > 5);
        assert_eq!(rows.len(), times.len());
        for w in times.windows(2) {
            let dt = w[1].as_f64().unwrap() - w[0].as_f64().unwrap();
            assert!((dt - 1.0 / 30.0).abs() < 1e-9, "output rate: dt {dt}");
        }
        for row in rows {
            let q: Vec<f64> = row
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            assert_eq!(q.len(), names.len());
            for (name, v) in names.iter().zip(&q) {
                let (lo, hi) = limits(name);
                assert!(*v >= lo - 1e-12 && *v <= hi + 1e-12, "{name} = {v}");
            }
            // Coupled joints follow their drivers and stay inside their own limits.
            for j in joints.iter().filter(|j| !j["mimic"].is_null()) {
                let mimic = &j["mimic"];
                let driver = names.iter().position(|n| *n == mimic["joint"]).unwrap();
                let v = mimic["multiplier"].as_f64().unwrap() * q[driver]
                    + mimic["offset"].as_f64().unwrap();
                let (lo, hi) = limits(j["name"].as_str().unwrap());
                assert!(v >= lo - 1e-12 && v <= hi + 1e-12, "{} = {v}", j["name"]);
            }
        }
        let metrics = &item["metrics"];
        let fingers = metrics["fingers"].as_u64().unwrap() as usize;
        assert_eq!(fingers, robot["fingers"].as_array().unwrap().len());
        for key in [
            "position_error",
            "orientation_error",
            "elbow_distance",
            "elbow_distance_mean",
            "objective",
            "iterations",
            "converged",
            "swivel_difference",
            "elbow_bound",
            "support_clearance",
            "object_clearance",
        ] {
            assert_eq!(metrics[key].as_array().unwrap().len(), times.len(), "{key}");
        }
        for e in metrics["position_error"].as_array().unwrap() {
            let e = e.as_array().unwrap();
            assert_eq!(e.len(), fingers);
            for x in e {
                worst_tip = worst_tip.max(x.as_f64().unwrap());
            }
        }
        assert_eq!(item["summary"]["frames"], times.len());
        frames_seen += times.len();
    }
    assert_eq!(summary["frames"], frames_seen);
    assert!((summary["max_fingertip_error_m"].as_f64().unwrap() - worst_tip).abs() < 1e-12);
    assert!(summary["mean_fingertip_error_m"].as_f64().unwrap() <= worst_tip);

    // Pages, one demonstration, summaries only.
    let second: Value = app
        .get(&format!("{mapping_url}?limit=1&offset=1"))
        .await
        .json()
        .await
        .unwrap();
    let p = &second["demonstrations"];
    assert_eq!(
        (p["total"].as_i64(), p["items"].as_array().unwrap().len()),
        (Some(2), 1)
    );
    assert_eq!(p["items"][0]["demonstration_id"], ids[1].as_str());
    let one: Value = app
        .get(&format!("{mapping_url}?demonstration={}", ids[0]))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(one["demonstrations"]["total"], 1);
    assert_eq!(one["demonstrations"]["items"][0], items[0]);
    let light: Value = app
        .get(&format!("{mapping_url}?trajectories=false"))
        .await
        .json()
        .await
        .unwrap();
    let li = &light["demonstrations"]["items"][0];
    assert!(li["trajectory"].is_null() && li["metrics"].is_null());
    assert_eq!(li["summary"], items[0]["summary"]);

    let list: Value = app
        .get("/v1/mappings?robot=wam_ihy&status=succeeded")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(list["total"], 1);
    assert_eq!(list["items"][0]["summary"], *summary);
    assert_problem(
        app.get(&format!("{mapping_url}?limit=0")).await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_problem(
        app.get("/v1/mappings/00000000-0000-4000-8000-00000000beef")
            .await,
        404,
        "not-found",
    )
    .await;

    // A demonstration a mapping uses cannot be deleted alone; with cascade the mapping goes too.
    let demo_url = app.url(&format!("/v1/demonstrations/{}", ids[0]));
    let res = app.client.delete(&demo_url).send().await.unwrap();
    assert_problem(res, 409, "conflict").await;
    let res = app
        .client
        .delete(format!("{demo_url}?cascade=true"))
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 204);
    assert_problem(app.get(&mapping_url).await, 404, "not-found").await;
}

/// A demonstration whose arm cannot be registered: the elbow sits on the shoulder throughout.
async fn upload_degenerate(app: &TestApp) -> String {
    let cfg = StudyConfig {
        subjects: 1,
        positions: 1,
        trials: 1,
        noise: false,
        ..StudyConfig::default()
    };
    let mut d = generate_study(&cfg).unwrap().remove(0);
    d.tracker.elbow = d.tracker.shoulder.clone();
    d.labels.external_id = Some("degenerate".into());
    let res = app
        .post_json("/v1/demonstrations", &serde_json::to_value(&d).unwrap())
        .await;
    assert_eq!(res.status(), 201);
    let v: Value = res.json().await.unwrap();
    v["id"].as_str().unwrap().to_owned()
}

#[tokio::test]
async fn bad_input_is_a_4xx_naming_the_field_and_stores_nothing() {
    let app = app().await;
    let job = study(&app, 1).await;
    let ids = demo_ids(&app, &job).await;
    let bad_arm = upload_degenerate(&app).await;
    let good = &ids[0];

    let cases: Vec<(Value, &str, &str)> = vec![
        (
            json!({"robot": "no_such_robot", "demonstrations": [good]}),
            "$.robot",
            "unknown robot",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good, "00000000-0000-4000-8000-000000000bad"]}),
            "$.demonstrations[1]",
            "unknown demonstration",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good, good]}),
            "$.demonstrations[1]",
            "twice",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": []}),
            "$.demonstrations",
            "at least one",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": {"subject": "nobody"}}),
            "$.demonstrations",
            "no stored demonstration",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good, bad_arm]}),
            "$.demonstrations[1]",
            "cannot be registered",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good], "weights": {"elbow": -0.5}}),
            "$.weights.elbow",
            "non-negative",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "weights": {"position": 0, "orientation": 0, "elbow": 0, "swivel": 0}}),
            "$.weights",
            "positive",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good], "weights": {"swivel": -1e-3}}),
            "$.weights.swivel",
            "non-negative",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "weights": {"fingertip_priority": 0.5}}),
            "$.weights.fingertip_priority",
            "at least 1",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "registration": {"placement": [3.0, 0.0, 0.3]}}),
            "$.registration.placement",
            "beyond its reach",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "registration": {"placement": [0.5, 0.0, -0.2]}}),
            "$.registration.placement",
            "under its support",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "registration": {"hand_scale": 0}}),
            "$.registration.hand_scale",
            "positive",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "registration": {"hand_scale": -1.5}}),
            "$.registration.hand_scale",
            "positive",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good], "output_rate_hz": 0}),
            "$.output_rate_hz",
            "(0, 500]",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good], "output_rate_hz": 5000}),
            "$.output_rate_hz",
            "(0, 500]",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good], "registration": {"scale": -2}}),
            "$.registration.scale",
            "positive",
        ),
        (
            json!({"robot": "wam_ihy", "demonstrations": [good],
                   "registration": {"transform": {"position": [0, 0, 0], "orientation": [0, 0, 0, 0]}}}),
            "$.registration.transform.orientation",
            "quaternion",
        ),
    ];
    for (body, path, words) in cases {
        let res = app.post_json("/v1/mappings", &body).await;
        let p = assert_problem(res, 422, "validation").await;
        let errors = p["errors"].as_array().unwrap();
        let e = errors
            .iter()
            .find(|e| e["path"] == path)
            .unwrap_or_else(|| panic!("no error at {path}: {p}"));
        assert!(
            e["message"].as_str().unwrap().contains(words),
            "{path}: `{}` should mention `{words}`",
            e["message"]
        );
    }
    // NaN is not JSON: the body itself is refused.
    let res = app
        .client
        .post(app.url("/v1/mappings"))
        .header("content-type", "application/json")
        .body(format!(
            r#"{{"robot": "wam_ihy", "demonstrations": ["{good}"], "weights": {{"position": NaN}}}}"#
        ))
        .send()
        .await
        .unwrap();
    assert!(res.status().is_client_error(), "{}", res.status());
    assert_eq!(mapping_count(&app).await, 0);
    assert_eq!(mapping_jobs(&app).await, 0);
}

#[tokio::test]
async fn a_cancelled_mapping_stores_no_trajectory() {
    let app = app().await;
    let job = study(&app, 1).await;
    let ids = demo_ids(&app, &job).await;
    // Both job slots busy: the mapping waits queued, so the cancellation surely comes first.
    let blockers = occupy_job_slots(&app).await;
    let (accepted, mapping_url) = submit_mapping(
        &app,
        json!({"robot": "wam_ihy", "demonstrations": ids, "output_rate_hz": 60}),
    )
    .await;
    let id = accepted["id"].as_str().unwrap().to_owned();
    let res = app
        .post_json(&format!("/v1/jobs/{id}/cancel"), &json!({}))
        .await;
    assert!(res.status().is_success(), "{}", res.status());
    for b in &blockers {
        let bid = b["id"].as_str().unwrap();
        app.post_json(&format!("/v1/jobs/{bid}/cancel"), &json!({}))
            .await;
    }
    let done = app
        .wait_job(&id, |j| j["status"] != "queued" && j["status"] != "running")
        .await;
    assert_eq!(done["status"], "cancelled");
    assert!(done["result"].is_null());
    let m: Value = app.get(&mapping_url).await.json().await.unwrap();
    assert_eq!(m["status"], "cancelled");
    assert!(m["summary"].is_null());
    assert_eq!(m["demonstrations"]["total"], 0);
    let list: Value = app
        .get("/v1/mappings?status=succeeded")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(list["total"], 0);
}

/// A mapping over a study's job takes the trials in the order the study generated them, the
/// same on every run: the study stores them under one timestamp, and a tie broken by the random
/// row id gave each run a different input order (and so a different model and different plans).
#[tokio::test]
async fn a_study_is_mapped_in_the_order_its_trials_were_generated() {
    let app = app().await;
    let cfg = json!({"seed": 11, "subjects": 1, "positions": 2, "trials": 3});
    let res = app.post_json("/v1/demonstrations/synthetic", &cfg).await;
    assert_eq!(res.status(), 202);
    let job: Value = res.json().await.unwrap();
    let job = job["id"].as_str().unwrap().to_owned();
    let done = app
        .wait_job(&job, |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // The reference order: the library's own generator, trial by trial.
    let expected: Vec<String> =
        generate_study(&serde_json::from_value::<StudyConfig>(cfg).unwrap())
            .unwrap()
            .into_iter()
            .map(|d| d.labels.external_id.unwrap())
            .collect();
    assert_eq!(expected.len(), 6);

    // Both job slots busy, so the mapping stays queued and is cancelled before it computes: the
    // order is fixed when the request is resolved.
    let blockers = occupy_job_slots(&app).await;
    let (accepted, mapping_url) = submit_mapping(
        &app,
        json!({"robot": "wam_ihy", "demonstrations": {"job_id": job}}),
    )
    .await;
    let m: Value = app.get(&mapping_url).await.json().await.unwrap();
    let mut got = Vec::new();
    for id in m["request"]["demonstrations"].as_array().unwrap() {
        let d: Value = app
            .get(&format!("/v1/demonstrations/{}", id.as_str().unwrap()))
            .await
            .json()
            .await
            .unwrap();
        got.push(d["external_id"].as_str().unwrap().to_owned());
    }
    assert_eq!(got, expected);
    let id = accepted["id"].as_str().unwrap();
    for j in std::iter::once(id).chain(blockers.iter().map(|b| b["id"].as_str().unwrap())) {
        app.post_json(&format!("/v1/jobs/{j}/cancel"), &json!({}))
            .await;
    }
}

/// A hand-only system registered as README "Mappings" shows (the descriptor of
/// `robots/examples/ihy_hand.toml` with the hand URDF as `urdf`) maps demonstrations: every
/// frame within the hand's limits, no swivel (no arm), no scene; a placement is a 422 naming it.
#[tokio::test]
async fn a_hand_only_system_registered_over_http_maps_demonstrations() {
    let app = app().await;
    let res = app
        .post_json(
            "/v1/robots",
            &crate::helpers::hand_registration("ihy_hand", "ihy"),
        )
        .await;
    assert_eq!(res.status(), 201);
    let robot: Value = res.json().await.unwrap();
    let id = robot["id"].as_str().unwrap().to_owned();
    assert_eq!(robot["arm_joints"].as_array().unwrap().len(), 0);

    let job = study(&app, 1).await;
    let res = app
        .post_json(
            "/v1/mappings",
            &json!({"robot": id, "demonstrations": {"job_id": job},
                    "registration": {"placement": [0.5, 0.0, 0.1]}}),
        )
        .await;
    let p = assert_problem(res, 422, "validation").await;
    let e = p["errors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["path"] == "$.registration.placement")
        .unwrap_or_else(|| panic!("no error at $.registration.placement: {p}"));
    assert!(e["message"].as_str().unwrap().contains("fixed base"), "{e}");
    assert_eq!(mapping_count(&app).await, 0);

    let (accepted, mapping_url) = submit_mapping(
        &app,
        json!({"robot": id, "demonstrations": {"job_id": job}, "output_rate_hz": 30}),
    )
    .await;
    let done = app
        .wait_job(accepted["id"].as_str().unwrap(), |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let m: Value = app.get(&mapping_url).await.json().await.unwrap();
    let item = &m["demonstrations"]["items"][0];
    let rows = item["trajectory"]["positions"].as_array().unwrap();
    assert!(rows.len() > 5);
    let joints = robot["joints"].as_array().unwrap();
    let names = item["trajectory"]["joint_names"].as_array().unwrap();
    for row in rows {
        for (name, v) in names.iter().zip(row.as_array().unwrap()) {
            let j = joints.iter().find(|j| j["name"] == *name).unwrap();
            let v = v.as_f64().unwrap();
            assert!(v >= j["lower"].as_f64().unwrap() - 1e-12, "{name} = {v}");
            assert!(v <= j["upper"].as_f64().unwrap() + 1e-12, "{name} = {v}");
        }
    }
    let metrics = &item["metrics"];
    assert!(
        metrics["swivel_difference"]
            .as_array()
            .unwrap()
            .iter()
            .all(Value::is_null)
    );
    assert!(
        metrics["converged"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|c| **c == true)
            .count()
            * 10
            >= rows.len() * 9
    );
}
