//! The real binary as a process: SIGKILL during a job, SIGTERM for a graceful stop.

use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use serde_json::{Value, json};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

struct Proc {
    child: Child,
    base_url: String,
}

/// Starts `reachgrasp` on an ephemeral port with JSON logs and the TEST-ONLY job routes, and
/// reads the bound address from its "listening" log line.
async fn start(db: &Path) -> Proc {
    let mut child = Command::new(env!("CARGO_BIN_EXE_reachgrasp"))
        .env("REACHGRASP_BIND", "127.0.0.1:0")
        .env("REACHGRASP_DB", db)
        .env("REACHGRASP_ROBOTS", db.with_file_name("no-robots"))
        .env("REACHGRASP_TEST_JOBS", "1")
        .env("REACHGRASP_NO_SEED", "1")
        .env("REACHGRASP_LOG_JSON", "1")
        .env("REACHGRASP_LOG", "info")
        .env("REACHGRASP_SHUTDOWN_GRACE", "5")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .expect("the binary starts");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let find = async {
        while let Some(line) = lines.next_line().await.unwrap() {
            if let Ok(v) = serde_json::from_str::<Value>(&line)
                && v["message"] == "listening"
            {
                return v["addr"].as_str().expect("addr field").to_owned();
            }
        }
        panic!("the process exited before listening");
    };
    let addr = tokio::time::timeout(Duration::from_secs(30), find)
        .await
        .expect("the process listens within 30 s");
    // Keep draining the logs so the child never blocks on a full pipe.
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    Proc {
        child,
        base_url: format!("http://{addr}"),
    }
}

async fn job(client: &reqwest::Client, base: &str, id: &str) -> Value {
    client
        .get(format!("{base}/v1/jobs/{id}"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap()
}

/// Starts a 20-second sleep job and waits until it runs.
async fn start_long_job(client: &reqwest::Client, base: &str) -> String {
    let res = client
        .post(format!("{base}/v1/_test/jobs/sleep"))
        .json(&json!({"steps": 2000, "step_ms": 10}))
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 202);
    let id = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    for _ in 0..400 {
        if job(client, base, &id).await["status"] == "running" {
            return id;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    panic!("the job did not start");
}

#[tokio::test]
async fn a_job_killed_with_sigkill_is_failed_interrupted_after_restart() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("data/reachgrasp.db");
    let client = reqwest::Client::new();

    let mut first = start(&db).await;
    let id = start_long_job(&client, &first.base_url).await;
    first.child.kill().await.expect("SIGKILL"); // std/tokio `kill` is SIGKILL on Unix
    first.child.wait().await.unwrap();

    let mut second = start(&db).await;
    let after = job(&client, &second.base_url, &id).await;
    assert_eq!(after["status"], "failed", "{after}");
    assert_eq!(after["error"]["reason"], "interrupted", "{after}");
    assert!(after["finished_at"].is_string());
    second.child.kill().await.unwrap();
}

#[cfg(unix)]
#[tokio::test]
async fn sigterm_stops_gracefully_and_records_the_running_job_as_interrupted() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("reachgrasp.db");
    let client = reqwest::Client::new();

    let mut first = start(&db).await;
    let id = start_long_job(&client, &first.base_url).await;
    let pid = first.child.id().expect("running child has a pid");
    let sent = std::process::Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .expect("the `kill` command exists");
    assert!(sent.success());
    let status = tokio::time::timeout(Duration::from_secs(20), first.child.wait())
        .await
        .expect("the process stops within the grace period")
        .unwrap();
    assert!(status.success(), "graceful stop exits 0, got {status}");

    let mut second = start(&db).await;
    let after = job(&client, &second.base_url, &id).await;
    assert_eq!(after["status"], "failed", "{after}");
    assert_eq!(after["error"]["reason"], "interrupted", "{after}");
    assert!(
        after["error"]["message"]
            .as_str()
            .unwrap()
            .contains("shut down"),
        "recorded by the stopping process itself, not by recovery: {after}"
    );
    second.child.kill().await.unwrap();
}

/// The CLI's grasp: `--direction x,y,z` (as its help documents) and `x y z` give the same
/// request; a user's mistake is one line on stderr and exit status 1, with no debug dump.
#[tokio::test]
async fn the_grasp_cli_takes_a_comma_separated_direction_and_reports_mistakes_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("cli.db");
    let robots = Path::new(env!("CARGO_MANIFEST_DIR")).join("robots");
    let grasp = |direction: &[&str]| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_reachgrasp"));
        c.arg("grasp")
            .args(["--robot", "wam_t42", "--object", "ball", "--kind", "force"])
            .arg("--direction")
            .args(direction)
            .arg("--db")
            .arg(&db)
            .arg("--robots")
            .arg(&robots)
            .args(["--log", "error"])
            .env_remove("RUST_BACKTRACE")
            .env_remove("RUST_LIB_BACKTRACE");
        async move { c.output().await.unwrap() }
    };
    let comma = grasp(&["0,0,1"]).await;
    assert!(comma.status.success(), "{comma:?}");
    let spaced = grasp(&["0", "0", "1"]).await;
    assert!(spaced.status.success(), "{spaced:?}");
    // the same grasp (deterministic), apart from how long it took
    let timeless = |out: &[u8]| {
        let mut v: Value = serde_json::from_slice(out).unwrap();
        v["time_s"] = Value::Null;
        v["solver"]["time_s"] = Value::Null;
        v
    };
    let (a, b) = (timeless(&comma.stdout), timeless(&spaced.stdout));
    assert_eq!(a, b);
    assert_eq!(a["feasible"], true, "{a}");

    let short = grasp(&["0,0"]).await;
    assert_eq!(short.status.code(), Some(1));
    let err = String::from_utf8(short.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("reachgrasp: error: --direction needs three numbers"),
        "{err}"
    );
}
