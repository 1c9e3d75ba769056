//! Issue 22 over HTTP: keypoint recordings as demonstrations (JSON and CSV) that map like glove
//! recordings, and the retargeting WebSocket (`GET /v1/robots/{id}/retarget`).

use std::path::Path;
use std::time::Duration;

use futures::{SinkExt, StreamExt};
use reachgrasp::human::csv::keypoints_to_csv;
use reachgrasp::human::keypoints::recording_of;
use reachgrasp::human::{
    HandKinematics, KeypointFrame, KeypointStream, StudyConfig, generate_study, ingest,
};
use reachgrasp::kinematics::System;
use reachgrasp::mapping::retarget::targets::reachable_stream;
use reachgrasp::mapping::{MappingModel, RetargetOptions, Retargeter};
use reachgrasp::service::retarget::KeypointFrameMsg;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::helpers::{TestApp, assert_problem, field_strings, spawn_app_with};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

async fn app() -> TestApp {
    spawn_app_with(|c| c.robots = root().join("robots")).await
}

/// Registers the FF16 hand on a fixed base as the README shows; its id.
async fn register_ff16(app: &TestApp) -> String {
    let res = app
        .post_json(
            "/v1/robots",
            &crate::helpers::hand_registration("ff16_hand", "ff16"),
        )
        .await;
    assert_eq!(res.status(), 201);
    let robot: Value = res.json().await.unwrap();
    robot["id"].as_str().unwrap().to_owned()
}

fn frame_json(kp: &KeypointFrame, seq: u64) -> Value {
    serde_json::to_value(KeypointFrameMsg::new(kp, Some(seq))).unwrap()
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn next(ws: &mut Ws) -> Value {
    match tokio::time::timeout(Duration::from_secs(20), ws.next())
        .await
        .expect("an answer in time")
    {
        Some(Ok(Message::Text(t))) => serde_json::from_str(t.as_str()).unwrap(),
        other => panic!("expected a text message, got {other:?}"),
    }
}

async fn connect(app: &TestApp, path: &str) -> Ws {
    let url = format!("{}{path}", app.base_url.replace("http://", "ws://"));
    tokio_tungstenite::connect_async(url).await.unwrap().0
}

/// A reachable stream onto the FF16 hand over the WebSocket: one answer per frame, in order,
/// equal to the in-process retargeter's joint values; malformed messages (bad JSON, a binary
/// message, 20 keypoints, a point of two values, time going back) are each answered with an
/// error naming the field, and the stream goes on unchanged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_keypoint_stream_is_retargeted_frame_by_frame_and_bad_frames_are_refused() {
    let app = app().await;
    let id = register_ff16(&app).await;
    let mut ws = connect(&app, &format!("/v1/robots/{id}/retarget")).await;
    let ready = next(&mut ws).await;
    assert_eq!(ready["type"], "ready", "{ready}");
    assert_eq!(ready["hand_only"], true);
    assert_eq!(ready["joint_names"].as_array().unwrap().len(), 16);
    assert_eq!(ready["keypoints"].as_array().unwrap().len(), 21);

    let sys = System::from_file(&root().join("robots/examples/ff16_hand.toml")).unwrap();
    let stream = reachable_stream(&sys, 2.0, 100.0, 5).unwrap();
    let mut local = Retargeter::new(
        MappingModel::from_system(&sys).unwrap(),
        RetargetOptions::default(),
    )
    .unwrap();
    let mut errors = Vec::new();
    for (k, f) in stream.frames.iter().enumerate() {
        if k % 40 == 7 {
            let bad: Vec<(Message, u16, Option<&str>)> = vec![
                (Message::Text("{not json".into()), 400, None),
                (Message::Binary(vec![1, 2, 3].into()), 400, None),
                (
                    Message::Text(
                        json!({"t": 100.0, "points": vec![[0.0_f64; 3]; 20]})
                            .to_string()
                            .into(),
                    ),
                    422,
                    Some("$.points"),
                ),
                (
                    Message::Text({
                        let mut v = frame_json(f, 9);
                        v["points"][3] = json!([0.1, 0.2]);
                        v.to_string().into()
                    }),
                    422,
                    Some("$.points[3]"),
                ),
                (
                    Message::Text(
                        json!({"seq": 9, "t": -1.0, "points": frame_json(f, 0)["points"]})
                            .to_string()
                            .into(),
                    ),
                    422,
                    Some("$.t"),
                ),
            ];
            for (msg, status, field) in bad {
                ws.send(msg).await.unwrap();
                let e = next(&mut ws).await;
                assert_eq!(e["type"], "error", "{e}");
                assert_eq!(e["status"], status, "{e}");
                if let Some(field) = field {
                    assert_eq!(e["field"], field, "{e}");
                }
            }
        }
        ws.send(Message::Text(frame_json(f, k as u64).to_string().into()))
            .await
            .unwrap();
        let a = next(&mut ws).await;
        assert_eq!(a["type"], "joints", "frame {k}: {a}");
        assert_eq!(a["seq"], k as u64);
        assert_eq!(a["index"], k as u64, "no frame dropped or counted twice");
        local.push(f).unwrap();
        let q: Vec<f64> = a["q"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(
            q,
            local.output(),
            "frame {k}: the service's answer is the retargeter's"
        );
        assert!(a["latency_us"].as_f64().unwrap() > 0.0);
        errors.extend(
            a["fingertip_error_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap()),
        );
    }
    errors.sort_by(f64::total_cmp);
    assert!(
        errors[errors.len() / 2] < 1e-3,
        "median fingertip error {}",
        errors[errors.len() / 2]
    );
    ws.close(None).await.unwrap();
}

/// Options are checked before the upgrade: a bad one is a 422 naming its parameter, an unknown
/// robot a 404, a plain GET a 400; an arm system refuses a frame without the arm.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retargeting_options_are_checked_before_the_upgrade_and_arm_systems_need_the_arm() {
    let app = app().await;
    let res = app
        .get("/v1/robots/wam_ihy/retarget?cutoff_hz=-2&placement=1,2")
        .await;
    let p = assert_problem(res, 422, "validation").await;
    let paths: Vec<&str> = field_strings(&p["errors"], "path");
    assert!(
        paths.contains(&"$.cutoff_hz") && paths.contains(&"$.placement"),
        "{p}"
    );
    let res = app.get("/v1/robots/no_such_robot/retarget").await;
    assert_eq!(res.status(), 404);
    let res = app.get("/v1/robots/wam_ihy/retarget?cutoff_hz=10").await;
    assert_eq!(res.status(), 400);

    let mut ws = connect(
        &app,
        "/v1/robots/wam_ihy/retarget?cutoff_hz=8&speed_scale=1",
    )
    .await;
    let ready = next(&mut ws).await;
    assert_eq!(ready["hand_only"], false, "{ready}");
    let kps = study_keypoints(3);
    let mut bare = frame_json(&kps.frames[0], 0);
    bare.as_object_mut().unwrap().remove("elbow");
    ws.send(Message::Text(bare.to_string().into()))
        .await
        .unwrap();
    let e = next(&mut ws).await;
    assert_eq!(e["field"], "$.elbow", "{e}");
    for (k, f) in kps.frames.iter().take(20).enumerate() {
        ws.send(Message::Text(frame_json(f, k as u64).to_string().into()))
            .await
            .unwrap();
        let a = next(&mut ws).await;
        assert_eq!(a["type"], "joints", "{a}");
        assert!(a["swivel_difference"].as_f64().is_some(), "{a}");
        assert_eq!(
            a["q"].as_array().unwrap().len(),
            ready["joint_names"].as_array().unwrap().len()
        );
    }
}

/// Maps one demonstration onto `robot` at 30 Hz and waits for the job to succeed.
async fn map_to_success(app: &TestApp, robot: &str, demonstration: &str) {
    let res = app
        .post_json(
            "/v1/mappings",
            &json!({"robot": robot, "demonstrations": [demonstration], "output_rate_hz": 30}),
        )
        .await;
    assert_eq!(res.status(), 202);
    let job: Value = res.json().await.unwrap();
    let done = app
        .wait_job(job["id"].as_str().unwrap(), |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
}

struct StudyKeypoints {
    stream: KeypointStream,
    frames: Vec<KeypointFrame>,
    input: reachgrasp::human::DemonstrationInput,
}

/// A study demonstration recorded as keypoints: its subject's hand model's joint centres at
/// every derived frame, with the elbow and shoulder.
fn study_keypoints(seed: u64) -> StudyKeypoints {
    let cfg = StudyConfig {
        seed,
        subjects: 1,
        positions: 1,
        trials: 1,
        rate_hz: 60.0,
        ..StudyConfig::default()
    };
    let input = generate_study(&cfg).unwrap().remove(0);
    let demo = ingest(&input).unwrap();
    let dims = demo.subject.hand_dims().unwrap();
    let mut hk = HandKinematics::new(&dims, demo.subject.handedness);
    let stream = recording_of(&demo).unwrap();
    let frames = demo
        .frames
        .iter()
        .zip(&demo.glove)
        .map(|(f, g)| KeypointFrame {
            t: f.t,
            points: hk.keypoints(&f.wrist, &g[..20]),
            wrist_orientation: None,
            elbow: Some(f.elbow),
            shoulder: Some(f.shoulder),
        })
        .collect();
    StudyKeypoints {
        stream,
        frames,
        input,
    }
}

/// A keypoint recording uploads as JSON and as CSV into the demonstration resource, its frames
/// are the derived kinematics (no glove angles), and it maps onto an arm-hand system like a glove
/// recording. Tracker and keypoints together, or neither, is a 422 naming the field.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn keypoint_recordings_are_demonstrations_that_map() {
    let app = app().await;
    let s = study_keypoints(4);
    let d = &s.input;
    let mut body = json!({"subject": d.subject, "object": d.object, "labels": d.labels,
                          "sync": {"rate_hz": 60.0}, "keypoints": s.stream});
    let res = app.post_json("/v1/demonstrations", &body).await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let demo: Value = res.json().await.unwrap();
    assert_eq!(demo["summary"]["source"], "keypoints", "{demo}");
    assert_eq!(demo["summary"]["arm"], true, "{demo}");
    let id = demo["id"].as_str().unwrap().to_owned();
    let frames: Value = app
        .get(&format!("/v1/demonstrations/{id}/frames?every=10"))
        .await
        .json()
        .await
        .unwrap();
    let first = &frames["frames"][0];
    assert_eq!(first["glove"].as_array().unwrap().len(), 0, "{first}");
    assert_eq!(first["fingertips"].as_array().unwrap().len(), 5);
    // The dashboard says what the recording is.
    let page = app
        .get(&format!("/ui/demonstrations/{id}"))
        .await
        .text()
        .await
        .unwrap();
    assert!(
        page.contains("synthetic (hand keypoints)")
            && page.contains("hand keypoints 103 (60.0 Hz), with elbow and shoulder"),
        "{page}"
    );

    // CSV, under another external id.
    let mut labels = d.labels.clone();
    labels.external_id = Some("kp-csv".into());
    let meta = json!({"subject": d.subject, "object": d.object, "labels": labels,
                      "sync": {"rate_hz": 60.0}});
    let form = reqwest::multipart::Form::new()
        .text("meta", meta.to_string())
        .part(
            "keypoints",
            reqwest::multipart::Part::text(keypoints_to_csv(&s.stream)).file_name("kp.csv"),
        );
    let res = app
        .client
        .post(app.url("/v1/demonstrations"))
        .multipart(form)
        .send()
        .await
        .unwrap();
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());

    // Both recordings at once, and neither.
    body["tracker"] = serde_json::to_value(&d.tracker).unwrap();
    body["labels"]["external_id"] = json!("kp-both");
    let p = assert_problem(
        app.post_json("/v1/demonstrations", &body).await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.keypoints", "{p}");
    body.as_object_mut().unwrap().remove("tracker");
    body.as_object_mut().unwrap().remove("keypoints");
    let p = assert_problem(
        app.post_json("/v1/demonstrations", &body).await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.tracker", "{p}");

    // It maps like a glove recording.
    map_to_success(&app, "wam_t42", &id).await;

    // The hand alone (no elbow, no shoulder): stored, refused by an arm system at submission
    // (the demonstration named), mapped by a hand on a fixed base.
    let mut hand = s.stream.clone();
    (hand.elbow, hand.shoulder) = (None, None);
    let mut labels = d.labels.clone();
    labels.external_id = Some("kp-hand".into());
    let res = app
        .post_json(
            "/v1/demonstrations",
            &json!({"subject": d.subject, "object": d.object, "labels": labels,
                    "sync": {"rate_hz": 60.0}, "keypoints": hand}),
        )
        .await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let hand_demo: Value = res.json().await.unwrap();
    assert_eq!(hand_demo["summary"]["arm"], false, "{hand_demo}");
    let hand_id = hand_demo["id"].as_str().unwrap().to_owned();
    let p = assert_problem(
        app.post_json(
            "/v1/mappings",
            &json!({"robot": "wam_t42", "demonstrations": [hand_id]}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.demonstrations[0]", "{p}");
    assert!(
        p["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("hand on a fixed base"),
        "{p}"
    );
    let ff16 = register_ff16(&app).await;
    map_to_success(&app, &ff16, &hand_id).await;
}
