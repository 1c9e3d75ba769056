//! Black-box test harness: the real application on an ephemeral loopback port with a fresh
//! temporary database. Set `TEST_LOG=1` to see the service's logs.

use std::sync::Once;
use std::time::Duration;

use reachgrasp::app::App;
use reachgrasp::config::Config;
use serde_json::{Value, json};

pub struct TestApp {
    /// `http://127.0.0.1:<port>`, no trailing slash.
    pub base_url: String,
    pub client: reqwest::Client,
    /// Keeps the temporary database folder alive for the test's duration.
    pub _dir: tempfile::TempDir,
}

static TRACING: Once = Once::new();

/// Starts the app with test defaults: temp DB, `127.0.0.1:0`, job concurrency 2, no first-start
/// seeding, and the TEST-ONLY sleep-job route enabled.
pub async fn spawn_app() -> TestApp {
    spawn_app_with(|_| {}).await
}

/// Like [`spawn_app`], with `tweak` applied to the configuration first.
pub async fn spawn_app_with(tweak: impl FnOnce(&mut Config)) -> TestApp {
    TRACING.call_once(|| {
        if std::env::var_os("TEST_LOG").is_some() {
            let config = Config {
                log: "debug".into(),
                ..Config::default()
            };
            reachgrasp::app::init_tracing(&config.log, config.log_json).expect("tracing");
        }
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let mut config = Config {
        bind: "127.0.0.1:0".parse().unwrap(),
        db: dir.path().join("db/test.db"),
        robots: dir.path().join("robots-missing"),
        job_concurrency: Some(2),
        shutdown_grace_secs: 2,
        test_jobs: true,
        // Seeding trains six models; only the tests about it turn it on.
        no_seed: true,
        ..Config::default()
    };
    tweak(&mut config);
    let app = App::build(config).await.expect("app builds");
    let base_url = format!("http://{}", app.local_addr());
    tokio::spawn(app.run_until(std::future::pending()));
    TestApp {
        base_url,
        client: reqwest::Client::builder()
            .timeout(Duration::from_secs(30))
            .build()
            .unwrap(),
        _dir: dir,
    }
}

impl TestApp {
    pub fn url(&self, path: &str) -> String {
        format!("{}{}", self.base_url, path)
    }

    pub async fn get(&self, path: &str) -> reqwest::Response {
        self.client
            .get(self.url(path))
            .send()
            .await
            .expect("request")
    }

    /// The `total` of a list (`GET path`): how many rows match, whatever the page.
    pub async fn total(&self, path: &str) -> i64 {
        let v: Value = self.get(path).await.json().await.expect("list");
        v["total"].as_i64().expect("total")
    }

    /// How many items a list without a `total` answers (`GET path?limit=100`: one page, which
    /// is all there is in a test).
    pub async fn items(&self, path: &str) -> usize {
        let v: Value = self
            .get(&format!("{path}?limit=100"))
            .await
            .json()
            .await
            .expect("list");
        v["items"].as_array().expect("items").len()
    }

    pub async fn post_json(&self, path: &str, body: &Value) -> reqwest::Response {
        self.client
            .post(self.url(path))
            .header("content-type", "application/json")
            .body(body.to_string())
            .send()
            .await
            .expect("request")
    }

    /// Starts a TEST-ONLY sleep job and returns its JSON.
    pub async fn start_sleep_job(&self, steps: u32, step_ms: u64) -> Value {
        let res = self
            .post_json(
                "/v1/_test/jobs/sleep",
                &serde_json::json!({"steps": steps, "step_ms": step_ms}),
            )
            .await;
        assert_eq!(res.status(), 202);
        res.json().await.unwrap()
    }

    /// Polls `GET /v1/jobs/{id}` until `done(job)` or the deadline (panics then).
    pub async fn wait_job(&self, id: &str, done: impl Fn(&Value) -> bool) -> Value {
        for _ in 0..400 {
            let job: Value = self
                .get(&format!("/v1/jobs/{id}"))
                .await
                .json()
                .await
                .unwrap();
            if done(&job) {
                return job;
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
        panic!("job {id} did not reach the expected state within 10 s");
    }
}

/// The strings of a JSON array (a test expectation: anything else panics).
pub fn strings(v: &Value) -> Vec<&str> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|s| s.as_str().unwrap())
        .collect()
}

/// Field `key` of each item of a JSON array, as strings (a test expectation).
pub fn field_strings<'a>(v: &'a Value, key: &str) -> Vec<&'a str> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|item| item[key].as_str().unwrap())
        .collect()
}

/// Asserts that `res` is problem+json with `status` and slug `kind`, and returns the document.
pub async fn assert_problem(res: reqwest::Response, status: u16, kind: &str) -> Value {
    assert_eq!(res.status().as_u16(), status, "status");
    let ct = res
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_owned();
    assert_eq!(ct, "application/problem+json");
    let body: Value = res.json().await.expect("problem body is JSON");
    assert_eq!(
        body["type"],
        format!("urn:reachgrasp:problem:{kind}"),
        "{body}"
    );
    assert_eq!(body["status"], status);
    assert!(body["title"].as_str().is_some_and(|t| !t.is_empty()));
    assert!(body["detail"].as_str().is_some_and(|t| !t.is_empty()));
    body
}

/// Submits a job-creating POST and waits for it to succeed; returns the filled resource id.
pub async fn run_job(app: &TestApp, path: &str, body: Value) -> String {
    let res = app.post_json(path, &body).await;
    assert_eq!(res.status(), 202, "{path}");
    let resource = res
        .headers()
        .get("content-location")
        .map(|v| v.to_str().unwrap().rsplit('/').next().unwrap().to_owned());
    let job: Value = res.json().await.unwrap();
    let done = app
        .wait_job(job["id"].as_str().unwrap(), |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{path}: {done}");
    resource.unwrap_or_else(|| job["id"].as_str().unwrap().to_owned())
}

/// A small study (seed 5, 15 demonstrations) mapped onto `robot` and trained as its default
/// model; returns the model id and a start where the demonstrations started (inside the
/// model's workspace).
pub async fn trained(app: &TestApp, robot: &str) -> (String, Value) {
    let (_, model, start) = trained_with_mapping(app, robot).await;
    (model, start)
}

/// [`trained`], with the mapping the model learned from: `(mapping, model, start)`.
pub async fn trained_with_mapping(app: &TestApp, robot: &str) -> (String, String, Value) {
    let study = run_job(
        app,
        "/v1/demonstrations/synthetic",
        json!({"seed": 5, "subjects": 1, "positions": 5, "trials": 3}),
    )
    .await;
    let mapping = run_job(
        app,
        "/v1/mappings",
        json!({"robot": robot, "demonstrations": {"job_id": study}, "output_rate_hz": 20}),
    )
    .await;
    let model = run_job(
        app,
        "/v1/models",
        json!({"robot": robot, "mappings": [mapping], "held_out": false, "default": true}),
    )
    .await;
    let m: Value = app
        .get(&format!("/v1/mappings/{mapping}?limit=1"))
        .await
        .json()
        .await
        .unwrap();
    let t = &m["demonstrations"]["items"][0]["trajectory"];
    let start = json!({"joint_names": t["joint_names"], "positions": t["positions"][0]});
    (mapping, model, start)
}

/// The body of `POST /v1/robots` that registers a hand-only system as the README shows: the
/// example descriptor `robots/examples/{example}.toml` with the hand URDF
/// `robots/hands/{hand}.urdf` inline.
pub fn hand_registration(example: &str, hand: &str) -> Value {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut descriptor: toml::Table = toml::from_str(
        &std::fs::read_to_string(root.join(format!("robots/examples/{example}.toml"))).unwrap(),
    )
    .unwrap();
    descriptor.remove("urdf");
    let urdf = std::fs::read_to_string(root.join(format!("robots/hands/{hand}.urdf"))).unwrap();
    json!({"descriptor": serde_json::to_value(&descriptor).unwrap(), "urdf": urdf})
}
