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
/// request; a user's mistake is one line on stderr and exit status 2, with no debug dump.
#[tokio::test]
async fn the_grasp_cli_takes_a_comma_separated_direction_and_reports_mistakes_in_one_line() {
    let robots = Path::new(env!("CARGO_MANIFEST_DIR")).join("robots");
    let grasp = |direction: &[&str]| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_reachgrasp"));
        c.arg("grasp")
            .args(["--robot", "wam_t42", "--object", "ball", "--kind", "force"])
            .arg("--direction")
            .args(direction)
            .arg("--robots")
            .arg(&robots)
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
    assert_eq!(short.status.code(), Some(2));
    let err = String::from_utf8(short.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("reachgrasp: error: --direction needs three numbers"),
        "{err}"
    );
}

fn cli(args: &[&str]) -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_reachgrasp"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE");
    c
}

/// The option lines of a `--help` text: `(flag, description)`. Clap puts a long description on
/// the line below its flag.
fn options(help: &str) -> Vec<(String, String)> {
    let lines: Vec<&str> = help.lines().map(str::trim).collect();
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        if !l.starts_with('-') {
            continue;
        }
        // "-h, --help  Print help": the flag ends at the first run of two spaces
        let (flag, text) = match l.split_once("  ") {
            Some((flag, text)) => (flag.trim(), text.trim()),
            None => {
                let below = lines.get(i + 1).filter(|n| !n.starts_with('-'));
                (*l, below.copied().unwrap_or(""))
            }
        };
        out.push((flag.to_owned(), text.to_owned()));
    }
    out
}

/// Each sub-command's help lists only what it reads (no service flag outside `serve`), and
/// every flag says what it is (more than its default).
#[test]
fn every_sub_command_lists_only_its_own_flags_each_described() {
    let service_only = [
        "--bind",
        "--body-limit",
        "--bridge-token",
        "--no-seed",
        "--retention-max-count",
    ];
    for sub in [
        "serve", "openapi", "ik", "bridge", "synth", "grasp", "map", "plan", "retarget",
    ] {
        let out = cli(&[sub, "--help"]).output().unwrap();
        assert!(out.status.success(), "{sub} --help: {out:?}");
        let help = String::from_utf8(out.stdout).unwrap();
        let opts = options(&help);
        assert!(
            opts.iter().any(|(f, _)| f.contains("--help")),
            "{sub}: {help}"
        );
        for (flag, text) in &opts {
            let said = text.split(" [").next().unwrap_or("").trim();
            assert!(
                !said.is_empty(),
                "{sub}: `{flag}` has no description:\n{help}"
            );
        }
        for f in service_only {
            let listed = opts.iter().any(|(flag, _)| flag.starts_with(f));
            assert_eq!(listed, sub == "serve", "{sub} --help and {f}:\n{help}");
        }
        assert!(!help.contains('\u{1b}'), "{sub}: colour codes into a pipe");
    }
    // `reachgrasp` alone serves: the top-level help has the service's flags
    let top = String::from_utf8(cli(&["--help"]).output().unwrap().stdout).unwrap();
    assert!(top.contains("--bind"), "{top}");
    // and a service flag after another sub-command is a mistake, not silently ignored
    let wrong = cli(&["synth", "--bind", "127.0.0.1:0"]).output().unwrap();
    assert_eq!(wrong.status.code(), Some(2));
    let err = String::from_utf8(wrong.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("'--bind'") && err.contains("reachgrasp synth --help"),
        "{err}"
    );
    assert!(!err.contains('\u{1b}'), "{err:?}");
}

/// The example file each reading sub-command's help names runs as it stands.
#[test]
fn the_example_files_the_help_names_run() {
    for (sub, example) in [
        ("ik", "examples/ik-targets.json"),
        ("grasp", "examples/grasp-ball.json"),
        ("map", "examples/demonstration.json"),
        ("plan", "examples/plan-bottle.json"),
        ("retarget", "examples/keypoints-ff16.json"),
    ] {
        let help = String::from_utf8(cli(&[sub, "--help"]).output().unwrap().stdout).unwrap();
        assert!(
            help.contains(example),
            "{sub} --help names {example}:\n{help}"
        );
    }
    let ik = cli(&[
        "ik",
        "--robot",
        "wam_ihy",
        "--targets",
        "examples/ik-targets.json",
    ])
    .output()
    .unwrap();
    assert!(ik.status.success(), "{ik:?}");
    let ik: Value = serde_json::from_slice(&ik.stdout).unwrap();
    let solved = ik["solutions"].as_array().unwrap();
    assert_eq!(solved.len(), 3);
    assert!(solved.iter().all(|s| s["success"] == true), "{ik}");

    let grasp = cli(&["grasp", "--request", "examples/grasp-ball.json"])
        .output()
        .unwrap();
    assert!(grasp.status.success(), "{grasp:?}");
    let grasps: Value = serde_json::from_slice(&grasp.stdout).unwrap();
    assert_eq!(grasps.as_array().unwrap().len(), 2);
    assert!(
        grasps
            .as_array()
            .unwrap()
            .iter()
            .all(|g| g["feasible"] == true),
        "{grasps}"
    );

    let map = cli(&[
        "map",
        "--robot",
        "wam_ihy",
        "--demo",
        "examples/demonstration.json",
        "--rate",
        "30",
    ])
    .output()
    .unwrap();
    assert!(map.status.success(), "{map:?}");
    let map: Value = serde_json::from_slice(&map.stdout).unwrap();
    assert_eq!(map["summary"]["demonstrations"], 1, "{map}");

    // The recorded FF16 stream (1 s of reachable targets, `cargo bench --bench retarget`'s
    // generator): the fingertips land on the targets.
    let rt = cli(&[
        "retarget",
        "--robot",
        "robots/examples/ff16_hand.toml",
        "--stream",
        "examples/keypoints-ff16.json",
    ])
    .output()
    .unwrap();
    assert!(rt.status.success(), "{rt:?}");
    let rt: Value = serde_json::from_slice(&rt.stdout).unwrap();
    assert_eq!(rt["frames"], 100, "{}", rt["frames"]);
    assert_eq!(rt["q"].as_array().unwrap().len(), 100);
    let median = rt["target_error_m"][0].as_f64().unwrap();
    assert!(median < 1e-3, "median fingertip error {median} m");

    // `synth --keypoints` writes keypoint recordings that ingest into the glove recordings'
    // fingertips (the same study, the same seed).
    let args = [
        "synth",
        "--subjects",
        "1",
        "--positions",
        "1",
        "--trials",
        "1",
        "--objects",
        "ball",
    ];
    let glove = cli(&args).output().unwrap();
    let kp = cli(&[&args[..], &["--keypoints"]].concat())
        .output()
        .unwrap();
    assert!(glove.status.success() && kp.status.success(), "{kp:?}");
    let glove: Vec<reachgrasp::human::DemonstrationInput> =
        serde_json::from_slice(&glove.stdout).unwrap();
    let docs: Value = serde_json::from_slice(&kp.stdout).unwrap();
    let doc = &docs[0];
    assert!(
        doc.get("tracker").is_none() && doc.get("glove").is_none(),
        "{doc}"
    );
    let kp: reachgrasp::human::DemonstrationInput = serde_json::from_value(doc.clone()).unwrap();
    let (a, b) = (
        reachgrasp::human::ingest(&glove[0]).unwrap(),
        reachgrasp::human::ingest(&kp).unwrap(),
    );
    assert_eq!(b.summary.source, reachgrasp::human::Source::Keypoints);
    assert_eq!(a.frames.len(), b.frames.len());
    for (x, y) in a.frames.iter().zip(&b.frames) {
        for (p, q) in x.fingertips.iter().zip(&y.fingertips) {
            assert!((p.translation.vector - q.translation.vector).norm() < 1e-9);
        }
    }

    // `plan` needs a database with trained models; without one it says so in one line
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("none.db");
    let plan = cli(&["plan", "--request", "examples/plan-bottle.json", "--db"])
        .arg(&db)
        .output()
        .unwrap();
    assert_eq!(plan.status.code(), Some(2), "{plan:?}");
    let err = String::from_utf8(plan.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("no database at"), "{err}");
}

/// Text logs into a pipe (a file, `docker logs`, a journal) carry no colour codes.
#[tokio::test]
async fn text_logs_into_a_pipe_have_no_colour_codes() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_reachgrasp"))
        .args(["--bind", "127.0.0.1:0", "--no-seed", "--log", "info"])
        .arg("--db")
        .arg(dir.path().join("t.db"))
        .arg("--robots")
        .arg(dir.path().join("no-robots"))
        .env_remove("REACHGRASP_LOG_JSON")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut seen = Vec::new();
    let listening = tokio::time::timeout(Duration::from_secs(30), async {
        while let Some(line) = lines.next_line().await.unwrap() {
            let done = line.contains("listening");
            seen.push(line);
            if done {
                return;
            }
        }
        panic!("exited before listening");
    })
    .await;
    assert!(listening.is_ok(), "no `listening` line in 30 s: {seen:?}");
    assert!(seen.iter().all(|l| !l.contains('\u{1b}')), "{seen:?}");
    child.kill().await.unwrap();
}
