//! The 3-D viewer in a real headless Chromium (chromedriver + fantoccini, WebGL through
//! SwiftShader): a plan, its trajectory and its mapping draw (canvas pixels differ from the
//! background), one playback step moves the robot (pixels change), playing advances the clock,
//! and the view of an execution on the reference worker follows the measured pose live. The
//! scene's link poses are checked against `POST /v1/robots/{id}/fk`.
//!
//! Same rule as `tests/browser.rs`: needs Debian's `chromium` and `chromium-driver` (override
//! with `CHROMIUM` / `CHROMEDRIVER`); without them the browser part FAILS when `CI=true` and
//! skips with a loud message otherwise.

#[path = "support/chromium.rs"]
mod chromium;
#[path = "api/helpers.rs"]
#[allow(dead_code)]
mod helpers;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use fantoccini::{Client, Locator};
use reachgrasp::bridge::sim::{SimLimits, min_jerk};
use reachgrasp::bridge::worker::{WorkerOptions, run_worker};
use reachgrasp::kinematics::System;
use serde_json::{Value, json};

use helpers::TestApp;

const ROBOT: &str = "wam_ihy";
const TOKEN: &str = "viewer-bridge-token";

fn robots_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
}

fn system() -> System {
    System::from_file(&robots_dir().join("systems/wam_ihy.toml")).expect("wam_ihy loads")
}

async fn get_json(app: &TestApp, path: &str) -> Value {
    let res = app.get(path).await;
    assert_eq!(res.status(), 200, "GET {path}");
    res.json().await.unwrap()
}

/// Each link pose of frame `k` of a scene equals the service's FK (`/v1/robots/{id}/fk`) of the
/// motion's sample at that frame's time.
async fn assert_scene_is_fk(
    app: &TestApp,
    scene: &Value,
    names: &Value,
    positions: &Value,
    k: usize,
) {
    let links: Vec<String> = scene["links"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["name"].as_str().unwrap().to_owned())
        .collect();
    let res = app
        .post_json(
            &format!("/v1/robots/{ROBOT}/fk"),
            &json!({"joint_names": names, "positions": positions, "frames": links}),
        )
        .await;
    assert_eq!(res.status(), 200);
    let fk: Value = res.json().await.unwrap();
    let frame = scene["frames"]["links"][k].as_array().unwrap();
    for (i, name) in links.iter().enumerate() {
        let want = fk["frames"]
            .as_array()
            .unwrap()
            .iter()
            .find(|f| f["name"] == name.as_str())
            .unwrap_or_else(|| panic!("{name} not in the FK answer"));
        let got: Vec<f64> = frame[7 * i..7 * i + 7]
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        for a in 0..3 {
            let w = want["position"][a].as_f64().unwrap();
            assert!(
                (got[a] - w).abs() < 1e-4,
                "{name} position[{a}]: {} vs {w}",
                got[a]
            );
        }
        // q and -q are the same rotation.
        let dot: f64 = (0..4)
            .map(|a| got[3 + a] * want["orientation"][a].as_f64().unwrap())
            .sum();
        assert!(
            dot.abs() > 1.0 - 1e-4,
            "{name} orientation: {got:?} vs {want}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_viewer_draws_plays_back_and_follows_a_live_execution_in_headless_chromium() {
    let app = helpers::spawn_app_with(|c| {
        c.robots = robots_dir();
        c.bridge_token = Some(TOKEN.into());
        c.bridge_heartbeat_ms = 200;
    })
    .await;

    // A plan: grasp the seeded ball from where the demonstrations start.
    let (mapping, _, start) = helpers::trained_with_mapping(&app, ROBOT).await;
    let res = app
        .post_json(
            "/v1/plans",
            &json!({"robot": ROBOT, "object_id": "00000000-0000-4000-8000-000000000001",
                    "start": start,
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await;
    assert!(res.status().is_success(), "{}", res.text().await.unwrap());
    let plan: Value = res.json().await.unwrap();
    let plan_id = plan["id"].as_str().unwrap().to_owned();
    let trajectory_id = plan["trajectory"]["id"]
        .as_str()
        .or_else(|| plan["trajectory_id"].as_str())
        .unwrap_or_else(|| panic!("the plan has a trajectory: {plan}"))
        .to_owned();

    // The plan's scene: the object, its support, contacts and ellipsoids, and link poses that
    // are the service's FK at the trajectory's samples.
    let started = Instant::now();
    let res = app
        .get(&format!("/ui/view/plans/{plan_id}/scene.json"))
        .await;
    assert_eq!(res.status(), 200);
    let text = res.text().await.unwrap();
    println!(
        "plan scene: {} bytes in {:?} (HTTP, test build)",
        text.len(),
        started.elapsed()
    );
    let scene: Value = serde_json::from_str(&text).unwrap();
    assert!(scene["object"].is_object(), "the plan's object is drawn");
    assert!(scene["support"].is_object(), "the ball rests on a support");
    assert!(!scene["contacts"].as_array().unwrap().is_empty());
    assert!(!scene["ellipsoids"].as_array().unwrap().is_empty());
    let traj = get_json(&app, &format!("/v1/trajectories/{trajectory_id}")).await;
    let points = traj["points"].as_array().unwrap();
    let times: Vec<f64> = scene["frames"]["times"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_f64().unwrap())
        .collect();
    let t_end = points.last().unwrap()["time_from_start"]
        .as_f64()
        .or_else(|| points.last().unwrap()["t"].as_f64())
        .unwrap();
    assert!((times.last().unwrap() - t_end).abs() < 1e-4);
    // The first and the last frame are the trajectory's first and last samples exactly.
    assert_scene_is_fk(
        &app,
        &scene,
        &traj["joint_names"],
        &points[0]["positions"],
        0,
    )
    .await;
    assert_scene_is_fk(
        &app,
        &scene,
        &traj["joint_names"],
        &points.last().unwrap()["positions"],
        times.len() - 1,
    )
    .await;
    let unknown = app.get("/ui/view/plans/nope/scene.json").await;
    assert_eq!(unknown.status(), 404);
    assert_eq!(app.get("/ui/view/trajectories/nope").await.status(), 404);

    // Everything the page loads comes from the binary: three.js r187 and its licence, no CDN;
    // the trajectory's page links to its 3-D view.
    let three = app.get("/assets/vendor/three.core.js").await;
    assert!(
        three.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/javascript")
    );
    assert!(three.text().await.unwrap().contains("REVISION = '187'"));
    assert!(
        app.get("/assets/vendor/three-LICENSE")
            .await
            .text()
            .await
            .unwrap()
            .contains("MIT License")
    );
    let page = app
        .get(&format!("/ui/view/plans/{plan_id}"))
        .await
        .text()
        .await
        .unwrap();
    assert!(page.contains("src=\"/assets/viewer.js\""), "{page}");
    assert!(
        !page.contains("src=\"http"),
        "nothing loads from elsewhere: {page}"
    );
    let detail = app
        .get(&format!("/ui/trajectories/{trajectory_id}"))
        .await
        .text()
        .await
        .unwrap();
    assert!(detail.contains(&format!("href=\"/ui/view/trajectories/{trajectory_id}\"")));

    // A slow, 20-second trajectory to the same grasp (the viewer's timing target).
    let res = app
        .post_json(
            "/v1/trajectories",
            &json!({"model": plan["model_id"], "start": start,
                    "goal": {"grasp": plan["grasp"]["id"]}, "duration": 20.0}),
        )
        .await;
    assert!(res.status().is_success(), "{}", res.text().await.unwrap());
    let long: Value = res.json().await.unwrap();
    let long_id = long["id"].as_str().unwrap().to_owned();
    let started = Instant::now();
    let text = app
        .get(&format!("/ui/view/trajectories/{long_id}/scene.json"))
        .await
        .text()
        .await
        .unwrap();
    println!(
        "{} s trajectory scene: {} bytes in {:?} (HTTP, test build)",
        long["points"].as_array().unwrap().last().unwrap()["t"],
        text.len(),
        started.elapsed()
    );
    // A trajectory to a stored grasp is drawn with that grasp's object, support and contacts.
    let long_scene: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        long_scene["object"]["geometry"]["type"], "sphere",
        "the ball"
    );
    assert!(long_scene["support"].is_object());
    assert!(!long_scene["contacts"].as_array().unwrap().is_empty());

    // The browser part.
    if !chromium::available("the viewer browser test") {
        return;
    }
    // WebGL without a GPU: Chromium's software rasteriser.
    let browser = chromium::launch("1280,1000", &["--enable-unsafe-swiftshader"]).await;
    let outcome = drive(&browser.client, &app, &plan_id, &long_id, &mapping).await;
    browser.close("viewer-e2e.png").await;
    outcome.unwrap();
}

/// Counts the canvas pixels that differ from the background, per half, and keeps the image
/// for [`CHANGED`].
const SNAPSHOT: &str = "
    const cv = document.querySelector('.viewer canvas');
    const off = document.createElement('canvas');
    off.width = cv.width; off.height = cv.height;
    const g = off.getContext('2d');
    g.drawImage(cv, 0, 0);
    const d = g.getImageData(0, 0, cv.width, cv.height).data;
    let left = 0, right = 0;
    for (let i = 0; i < d.length; i += 4) {
        const bg = Math.abs(d[i] - 0xee) + Math.abs(d[i + 1] - 0xf2) + Math.abs(d[i + 2] - 0xf6) < 8;
        if (!bg) { if ((i / 4) % cv.width < cv.width / 2) left++; else right++; }
    }
    window.__lastPixels = d;
    return { pixels: cv.width * cv.height, left, right };";

/// How many pixels differ from the image [`SNAPSHOT`] kept (and keeps the new one).
const CHANGED: &str = "
    const cv = document.querySelector('.viewer canvas');
    const off = document.createElement('canvas');
    off.width = cv.width; off.height = cv.height;
    const g = off.getContext('2d');
    g.drawImage(cv, 0, 0);
    const d = g.getImageData(0, 0, cv.width, cv.height).data;
    const p = window.__lastPixels;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
        if (d[i] !== p[i] || d[i + 1] !== p[i + 1] || d[i + 2] !== p[i + 2]) n++;
    }
    window.__lastPixels = d;
    return n;";

async fn js(c: &Client, script: &str) -> Result<Value, String> {
    c.execute(script, vec![]).await.map_err(|e| e.to_string())
}

/// Opens a viewer page and waits until its first frame is drawn; returns the viewer's state.
async fn open(c: &Client, url: &str) -> Result<Value, String> {
    let t = Instant::now();
    c.goto(url).await.map_err(|e| e.to_string())?;
    c.wait()
        .at_most(Duration::from_secs(60))
        .for_element(Locator::Css(".viewer[data-ready=true]"))
        .await
        .map_err(|e| format!("{url}: the viewer did not draw: {e}"))?;
    let state = js(
        c,
        "const v = window.reachgraspViewer; \
         return {frames: v.frames, frame: v.frame, firstFrameMs: v.firstFrameMs, fetchMs: v.fetchMs, \
                 sinceNavigationMs: v.sinceNavigationMs, \
                 error: document.querySelector('.viewer-error').textContent};",
    )
    .await?;
    println!(
        "viewer {url}: {} frames, first frame drawn {:.0} ms after navigation start, {:.0} ms \
         after the viewer script started (scene fetched in {:.0} ms); page open {:?}",
        state["frames"],
        state["sinceNavigationMs"].as_f64().unwrap_or(f64::NAN),
        state["firstFrameMs"].as_f64().unwrap_or(f64::NAN),
        state["fetchMs"].as_f64().unwrap_or(f64::NAN),
        t.elapsed()
    );
    Ok(state)
}

/// The canvas draws something besides the background (in both halves for a mapping).
/// Opens the 3-D page of the execution `res` (an answer to `POST /v1/executions`) and checks
/// that it draws.
async fn open_execution(c: &Client, app: &TestApp, res: reqwest::Response) -> Result<(), String> {
    if res.status() != 202 {
        return Err(format!("execution refused: {}", res.text().await.unwrap()));
    }
    let id = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    open(c, &format!("{}/ui/view/executions/{id}", app.base_url)).await?;
    assert_draws(c, false).await
}

async fn assert_draws(c: &Client, both_halves: bool) -> Result<(), String> {
    let s = js(c, SNAPSHOT).await?;
    let total = s["pixels"].as_f64().unwrap();
    let (left, right) = (s["left"].as_f64().unwrap(), s["right"].as_f64().unwrap());
    if (left + right) / total < 0.02 {
        return Err(format!("the canvas is (nearly) all background: {s}"));
    }
    if both_halves && (left / total < 0.01 || right / total < 0.01) {
        return Err(format!("one side of the side-by-side view is empty: {s}"));
    }
    Ok(())
}

async fn changed(c: &Client) -> Result<u64, String> {
    Ok(js(c, CHANGED).await?.as_u64().unwrap_or(0))
}

/// Moves the slider to `k` as a user would (an `input` event).
async fn slide(c: &Client, k: u64) -> Result<(), String> {
    c.execute(
        "const s = document.querySelector('.viewer-time'); s.value = arguments[0]; \
         s.dispatchEvent(new Event('input'));",
        vec![json!(k)],
    )
    .await
    .map(|_| ())
    .map_err(|e| e.to_string())
}

async fn drive(
    c: &Client,
    app: &TestApp,
    plan: &str,
    trajectory: &str,
    mapping: &str,
) -> Result<(), String> {
    let base = &app.base_url;

    // The plan: draws; the slider to mid-motion and then one Step each move the robot.
    let state = open(c, &format!("{base}/ui/view/plans/{plan}")).await?;
    let frames = state["frames"].as_u64().unwrap();
    if frames < 10 {
        return Err(format!(
            "a plan's motion has more than a handful of frames: {state}"
        ));
    }
    assert_draws(c, false).await?;
    slide(c, frames / 2).await?;
    let moved = changed(c).await?;
    if moved < 50 {
        return Err(format!(
            "moving the slider to mid-motion changed {moved} pixels"
        ));
    }
    c.find(Locator::Css(".viewer-step"))
        .await
        .map_err(|e| e.to_string())?
        .click()
        .await
        .map_err(|e| e.to_string())?;
    let frame = js(c, "return window.reachgraspViewer.frame;").await?;
    if frame.as_u64() != Some(frames / 2 + 1) {
        return Err(format!(
            "Step went to frame {frame}, not {}",
            frames / 2 + 1
        ));
    }
    let stepped = changed(c).await?;
    if stepped == 0 {
        return Err("one playback step did not change the picture".into());
    }
    // The readout names the frame's time.
    let readout = c
        .find(Locator::Css(".time-readout"))
        .await
        .map_err(|e| e.to_string())?
        .text()
        .await
        .map_err(|e| e.to_string())?;
    if !readout.ends_with(" s") || !readout.contains(" / ") {
        return Err(format!("time readout: {readout:?}"));
    }

    // The 20 s trajectory: Play runs the clock.
    let state = open(c, &format!("{base}/ui/view/trajectories/{trajectory}")).await?;
    if state["frames"].as_u64().unwrap_or(0) < 300 {
        return Err(format!("a 20 s trajectory at 30 frames/s: {state}"));
    }
    assert_draws(c, false).await?;
    js(c, SNAPSHOT).await?;
    c.find(Locator::Css(".viewer-play"))
        .await
        .map_err(|e| e.to_string())?
        .click()
        .await
        .map_err(|e| e.to_string())?;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let frame = js(c, "return window.reachgraspViewer.frame;").await?;
    if frame.as_u64().unwrap_or(0) == 0 {
        return Err("Play did not advance the frame in 1.5 s".into());
    }
    if changed(c).await? == 0 {
        return Err("playing did not change the picture".into());
    }

    // The mapping: human and robot side by side, both drawn, one clock.
    let state = open(c, &format!("{base}/ui/view/mappings/{mapping}?demo=0")).await?;
    assert_draws(c, true).await?;
    slide(c, state["frames"].as_u64().unwrap() / 2).await?;
    if changed(c).await? < 50 {
        return Err("moving the mapping's slider did not move the human and the robot".into());
    }

    visual_toggle(c, app).await?;
    live_execution(c, app).await
}

/// A robot registered with `<visual>` geometry (the WAM's shoulder drawn as a 30 cm cube
/// instead of its 9 cm collision sphere) opens with its visual geometry, and the "links"
/// control switches to the collision shapes (pixels change) and back. A bundled robot has no
/// visuals: the control stays on the collision shapes and is disabled.
async fn visual_toggle(c: &Client, app: &TestApp) -> Result<(), String> {
    let read = |rel: &str| std::fs::read_to_string(robots_dir().join(rel)).unwrap();
    let desc: Value =
        serde_json::to_value(toml::from_str::<toml::Value>(&read("systems/wam_t42.toml")).unwrap())
            .unwrap();
    let sphere = "<collision><geometry><sphere radius=\"0.09\"/></geometry></collision>";
    let arm = read("arms/wam.urdf").replacen(
        sphere,
        &format!("{sphere}<visual><geometry><box size=\"0.3 0.3 0.3\"/></geometry></visual>"),
        1,
    );
    let res = app
        .post_json(
            "/v1/robots",
            &json!({"descriptor": desc, "arm_urdf": arm, "hand_urdf": read("hands/t42.urdf")}),
        )
        .await;
    if res.status() != 201 {
        return Err(format!("registration: {}", res.text().await.unwrap()));
    }
    let robot: Value = res.json().await.unwrap();
    let names = robot["joint_names"].clone();
    let n = names.as_array().unwrap().len();
    let point = |t: f64| {
        json!({"t": t, "positions": vec![0.2; n], "velocities": vec![0.0; n],
                                "accelerations": vec![0.0; n]})
    };
    let res = app
        .post_json(
            "/v1/executions",
            &json!({"robot": robot["id"], "mode": "open_loop",
                    "trajectory": {"joint_names": names, "points": [point(0.0), point(1.0)]}}),
        )
        .await;
    open_execution(c, app, res).await?;
    let control = "const s = document.querySelector('.viewer-geometry'); \
                   return {value: s.value, disabled: s.disabled};";
    let state = js(c, control).await?;
    if state != json!({"value": "visual", "disabled": false}) {
        return Err(format!("a robot with visuals opens on them: {state}"));
    }
    js(c, SNAPSHOT).await?;
    let choose = |v: &'static str| async move {
        c.find(Locator::Css(".viewer-geometry"))
            .await
            .map_err(|e| e.to_string())?
            .select_by_value(v)
            .await
            .map_err(|e| e.to_string())
    };
    choose("collision").await?;
    let to_collision = changed(c).await?;
    choose("visual").await?;
    let to_visual = changed(c).await?;
    println!("links control: {to_collision} pixels changed to collision, {to_visual} back");
    if to_collision < 200 || to_visual < 200 {
        return Err(format!(
            "switching between the visual cube and the collision sphere changed \
             {to_collision} / {to_visual} pixels"
        ));
    }
    // A bundled robot (no <visual>): collision shapes, control disabled.
    let plans: Value = get_json(app, "/v1/plans").await;
    let plan = plans["items"][0]["id"]
        .as_str()
        .unwrap_or_default()
        .to_owned();
    open(c, &format!("{}/ui/view/plans/{plan}", app.base_url)).await?;
    let state = js(c, control).await?;
    if state != json!({"value": "collision", "disabled": true}) {
        return Err(format!("a robot without visuals: {state}"));
    }
    Ok(())
}

/// An execution on the reference worker (in-process simulated robot): the live view poses the
/// robot from the measured state in the execution's events as they arrive.
async fn live_execution(c: &Client, app: &TestApp) -> Result<(), String> {
    let sys = system();
    let m = &sys.model;
    let home = SimLimits::new(m.lower_limits(), m.upper_limits(), m.velocity_limits(), 4.0).home();
    let mut target = home.clone();
    for (q, d) in target.iter_mut().zip([0.6, 0.5, -0.4, 0.7, 0.3, -0.5, 0.4]) {
        *q += d;
    }
    let ws = format!(
        "{}/v1/bridges/connect",
        app.base_url.replace("http://", "ws://")
    );
    let mut opts = WorkerOptions::for_system(&ws, TOKEN, "sim-view", ROBOT, &sys, 4.0);
    opts.backoff_initial = Duration::from_millis(50);
    let worker = tokio::spawn(run_worker(opts, None, std::future::pending()));
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let b = get_json(app, "/v1/bridges").await;
        if b["items"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w["name"] == "sim-view")
        {
            break;
        }
        if Instant::now() > deadline {
            return Err("the reference worker did not connect".into());
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let res = app
        .post_json(
            "/v1/executions",
            &json!({"robot": ROBOT, "mode": "open_loop",
                    "trajectory": {"joint_names": m.joint_names(),
                                   "points": min_jerk(&home, &target, 6.0, 100.0)}}),
        )
        .await;
    open_execution(c, app, res).await?;
    let live = |n: u64| async move {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let s = js(
                c,
                "const v = window.reachgraspViewer; return {n: v.liveUpdates, t: v.liveT ?? null, \
                 state: v.liveState ?? null};",
            )
            .await?;
            if s["n"].as_u64().unwrap_or(0) >= n {
                return Ok::<Value, String>(s);
            }
            if Instant::now() > deadline {
                return Err(format!("fewer than {n} live poses within 20 s: {s}"));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    let first = live(1).await?;
    js(c, SNAPSHOT).await?;
    // Later feedback: the robot has moved on.
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let later = live(first["n"].as_u64().unwrap() + 1).await?;
    if later["t"].as_f64() <= first["t"].as_f64() {
        return Err(format!(
            "the live time did not advance: {first} then {later}"
        ));
    }
    let moved = changed(c).await?;
    println!("live view: {first} then {later}: {moved} pixels changed");
    if moved < 50 {
        return Err(format!(
            "the live pose did not move the robot ({moved} pixels)"
        ));
    }
    worker.abort();
    Ok(())
}
