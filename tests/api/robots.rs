//! `/v1/robots`: the bundled library, registration with every rejection, and the kinematics
//! endpoints.

use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2};
use std::path::PathBuf;

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};
use reachgrasp::kinematics::{Data, NoMeshes, forward_kinematics, model_from_urdf_str};
use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, field_strings, spawn_app_with};

fn robots_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
}

async fn app() -> TestApp {
    spawn_app_with(|c| c.robots = robots_dir()).await
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(robots_dir().join(rel)).unwrap()
}

pub(crate) fn wam_t42_body() -> Value {
    let desc: Value =
        serde_json::to_value(toml::from_str::<toml::Value>(&read("systems/wam_t42.toml")).unwrap())
            .unwrap();
    json!({"descriptor": desc, "arm_urdf": read("arms/wam.urdf"), "hand_urdf": read("hands/t42.urdf")})
}

async fn count(app: &TestApp) -> usize {
    let list: Value = app.get("/v1/robots").await.json().await.unwrap();
    list["items"].as_array().unwrap().len()
}

async fn delete(app: &TestApp, path: &str) -> reqwest::Response {
    app.client.delete(app.url(path)).send().await.unwrap()
}

fn q_zero(detail: &Value) -> (Vec<Value>, Vec<f64>) {
    let names = detail["joint_names"].as_array().unwrap().clone();
    let n = names.len();
    (names, vec![0.3; n])
}

#[tokio::test]
async fn the_six_bundled_systems_are_listed_with_joints_fingers_and_couplings() {
    let app = app().await;
    let list: Value = app.get("/v1/robots").await.json().await.unwrap();
    let ids: Vec<&str> = field_strings(&list["items"], "id");
    for id in [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ] {
        assert!(ids.contains(&id), "{id} missing from {ids:?}");
    }
    let d: Value = app.get("/v1/robots/wam_ihy").await.json().await.unwrap();
    assert_eq!(d["bundled"], true);
    assert_eq!(d["arm_joints"].as_array().unwrap().len(), 7);
    assert_eq!(d["fingers"].as_array().unwrap().len(), 3);
    assert_eq!(d["thumb"], "thumb");
    assert_eq!(
        d["spread_pairs"][0],
        json!(["ihy_finger2_spread", "ihy_finger1_spread"])
    );
    let distal = d["joints"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["name"] == "ihy_finger1_distal")
        .unwrap();
    assert_eq!(distal["independent"], false);
    assert_eq!(distal["mimic"]["joint"], "ihy_finger1_proximal");
    assert_eq!(distal["mimic"]["multiplier"], 0.7);
    let j1 = d["joints"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["name"] == "wam_joint1")
        .unwrap();
    assert_eq!(j1["lower"], -2.6);
    assert!(j1["velocity"].as_f64().unwrap() > 0.0);
    assert_problem(app.get("/v1/robots/nope").await, 404, "not-found").await;
}

#[tokio::test]
async fn the_urdf_endpoint_serves_one_combined_urdf_that_loads_to_the_same_joints() {
    let app = app().await;
    let res = app.get("/v1/robots/pa10_ob4f/urdf").await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.headers()["content-type"], "application/xml");
    let text = res.text().await.unwrap();
    let model = model_from_urdf_str(&text, &NoMeshes).unwrap();
    let d: Value = app.get("/v1/robots/pa10_ob4f").await.json().await.unwrap();
    let names: Vec<String> = serde_json::from_value(d["joint_names"].clone()).unwrap();
    assert_eq!(model.joint_names(), names.as_slice());
}

#[tokio::test]
async fn fk_jacobian_and_manipulability_agree_with_the_library() {
    let app = app().await;
    let d: Value = app.get("/v1/robots/wam_t42").await.json().await.unwrap();
    let (names, q) = q_zero(&d);
    let fk: Value = app
        .post_json(
            "/v1/robots/wam_t42/fk",
            &json!({"joint_names": names, "positions": q, "frames": ["t42_left_tip"]}),
        )
        .await
        .json()
        .await
        .unwrap();
    let model = model_from_urdf_str(
        &app.get("/v1/robots/wam_t42/urdf")
            .await
            .text()
            .await
            .unwrap(),
        &NoMeshes,
    )
    .unwrap();
    let mut data = Data::new(&model);
    forward_kinematics(&model, &mut data, &q);
    let tip = data
        .frame(model.frame_id("t42_left_tip").unwrap())
        .translation
        .vector;
    for k in 0..3 {
        assert!((fk["frames"][0]["position"][k].as_f64().unwrap() - tip[k]).abs() < 1e-12);
    }
    let jac: Value = app
        .post_json(
            "/v1/robots/wam_t42/jacobian",
            &json!({"joint_names": names, "positions": q, "frame": "t42_base"}),
        )
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(jac["rows"].as_array().unwrap().len(), 6);
    // Hand joints do not move the hand base.
    assert_eq!(jac["rows"][0][8], 0.0);
    let m: Value = app
        .post_json(
            "/v1/robots/wam_t42/manipulability",
            &json!({"joint_names": names, "positions": q, "frame": "t42_base", "directions": [[1, 0, 0], [0, 0, 2]]}),
        )
        .await
        .json()
        .await
        .unwrap();
    assert!(m["manipulability"].as_f64().unwrap() > 0.0);
    let axes = m["semi_axes"].as_array().unwrap();
    assert!(axes[0].as_f64().unwrap() >= axes[2].as_f64().unwrap());
    assert_eq!(m["transmission"][1]["direction"], json!([0.0, 0.0, 1.0]));
}

#[tokio::test]
async fn ik_round_trips_and_an_unreachable_target_is_200_with_residuals() {
    let app = app().await;
    let d: Value = app.get("/v1/robots/pa10_t42").await.json().await.unwrap();
    let (names, q) = q_zero(&d);
    let fk: Value = app
        .post_json(
            "/v1/robots/pa10_t42/fk",
            &json!({"joint_names": names, "positions": q, "frames": ["t42_base"]}),
        )
        .await
        .json()
        .await
        .unwrap();
    let pose = &fk["frames"][0];
    let res = app
        .post_json(
            "/v1/robots/pa10_t42/ik",
            &json!({"position": pose["position"], "orientation": pose["orientation"], "time_budget_ms": 200}),
        )
        .await;
    assert_eq!(res.status(), 200);
    let ik: Value = res.json().await.unwrap();
    assert_eq!(ik["success"], true, "{ik}");
    assert!(ik["position_error"].as_f64().unwrap() <= 1e-6);
    assert_eq!(ik["joint_names"], Value::Array(names.clone()));
    let far = app
        .post_json(
            "/v1/robots/pa10_t42/ik",
            &json!({"position": [5.0, 0.0, 0.0], "max_restarts": 3}),
        )
        .await;
    assert_eq!(far.status(), 200);
    let far: Value = far.json().await.unwrap();
    assert_eq!(far["success"], false);
    assert!(far["position_error"].as_f64().unwrap() > 3.0);
    assert_eq!(far["positions"].as_array().unwrap().len(), names.len());
    // A target so far away that its residuals would overflow (a conformance run found `null`
    // errors in a 200 at 6e304 m) is refused at its coordinate.
    let absurd = assert_problem(
        app.post_json(
            "/v1/robots/pa10_t42/ik",
            &json!({"position": [0.0, -6.3e304, 0.0]}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(absurd["errors"][0]["path"], "$.position[1]", "{absurd}");
}

#[tokio::test]
async fn bad_joint_vectors_and_frames_are_422_naming_the_field_and_joint() {
    let app = app().await;
    let d: Value = app.get("/v1/robots/wam_t42").await.json().await.unwrap();
    let (names, q) = q_zero(&d);
    let fk = "/v1/robots/wam_t42/fk";
    let short = assert_problem(
        app.post_json(fk, &json!({"joint_names": names[..3], "positions": q[..3]}))
            .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(short["errors"][0]["path"], "$.positions");
    let mut unknown = names.clone();
    unknown[2] = json!("elbow_of_doom");
    let un = assert_problem(
        app.post_json(fk, &json!({"joint_names": unknown, "positions": q}))
            .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(un["errors"][0]["path"], "$.joint_names");
    assert!(un["detail"].as_str().unwrap().contains("elbow_of_doom"));
    let res = app
        .client
        .post(app.url(fk))
        .header("content-type", "application/json")
        .body(format!(
            "{{\"joint_names\": {}, \"positions\": [NaN{}]}}",
            Value::Array(names.clone()),
            ", 0".repeat(q.len() - 1)
        ))
        .send()
        .await
        .unwrap();
    assert_problem(res, 400, "malformed-json").await;
    let bad_frame = assert_problem(
        app.post_json(
            "/v1/robots/wam_t42/jacobian",
            &json!({"joint_names": names, "positions": q, "frame": "nose"}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(bad_frame["errors"][0]["path"], "$.frame");
    let bad_quat = assert_problem(
        app.post_json(
            "/v1/robots/wam_t42/ik",
            &json!({"position": [0.5, 0, 0.5], "orientation": [0, 0, 0, 0]}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(bad_quat["errors"][0]["path"], "$.orientation");
    let bad_dir = assert_problem(
        app.post_json(
            "/v1/robots/wam_t42/manipulability",
            &json!({"joint_names": names, "positions": q, "frame": "t42_base", "directions": [[1, 0]]}),
        )
        .await,
        422,
        "validation",
    )
    .await;
    assert_eq!(bad_dir["errors"][0]["path"], "$.directions[0]");
    assert_problem(
        app.post_json(
            "/v1/robots/nope/fk",
            &json!({"joint_names": [], "positions": []}),
        )
        .await,
        404,
        "not-found",
    )
    .await;
}

#[tokio::test]
async fn a_registered_system_can_be_used_and_deleted_but_bundled_ones_cannot() {
    let app = app().await;
    let before = count(&app).await;
    let res = app.post_json("/v1/robots", &wam_t42_body()).await;
    assert_eq!(res.status(), 201);
    let location = res.headers()["location"].to_str().unwrap().to_owned();
    let created: Value = res.json().await.unwrap();
    assert_eq!(created["bundled"], false);
    assert_eq!(count(&app).await, before + 1);
    let (names, q) = q_zero(&created);
    let fk = app
        .post_json(
            &format!("{location}/fk"),
            &json!({"joint_names": names, "positions": q}),
        )
        .await;
    assert_eq!(fk.status(), 200);
    assert_problem(delete(&app, "/v1/robots/wam_t42").await, 409, "conflict").await;
    assert_eq!(delete(&app, &location).await.status(), 204);
    assert_problem(app.get(&location).await, 404, "not-found").await;
    assert_problem(delete(&app, &location).await, 404, "not-found").await;

    // One combined URDF plus a descriptor with a wrist frame works too.
    let mut body = wam_t42_body();
    let combined = read("arms/wam.urdf")
        .rsplit_once("</robot>")
        .unwrap()
        .0
        .to_owned()
        + "<joint name=\"mount\" type=\"fixed\"><parent link=\"wam_flange\"/><child link=\"t42_base\"/></joint>"
        + read("hands/t42.urdf")
            .split_once("<robot name=\"openhand_t42\">")
            .unwrap()
            .1;
    body["descriptor"].as_object_mut().unwrap().remove("mount");
    body["descriptor"]["wrist_frame"] = json!("t42_base");
    let body = json!({"descriptor": body["descriptor"], "urdf": combined});
    assert_eq!(app.post_json("/v1/robots", &body).await.status(), 201);
}

#[tokio::test]
async fn a_system_still_referenced_elsewhere_cannot_be_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("refs.db");
    let app = spawn_app_with({
        let db = db.clone();
        move |c| {
            c.robots = robots_dir();
            c.db = db;
        }
    })
    .await;
    let created: Value = app
        .post_json("/v1/robots", &wam_t42_body())
        .await
        .json()
        .await
        .unwrap();
    let id = created["id"].as_str().unwrap().to_owned();
    // Another resource's table pointing at the robot, as later migrations will add.
    let pool = reachgrasp::store::connect(&db).await.unwrap();
    sqlx::query("CREATE TABLE referrers (robot_id TEXT NOT NULL REFERENCES robots(id))")
        .execute(&pool)
        .await
        .unwrap();
    sqlx::query("INSERT INTO referrers (robot_id) VALUES (?)")
        .bind(&id)
        .execute(&pool)
        .await
        .unwrap();
    assert_problem(
        delete(&app, &format!("/v1/robots/{id}")).await,
        409,
        "conflict",
    )
    .await;
    assert_eq!(app.get(&format!("/v1/robots/{id}")).await.status(), 200);
}

#[tokio::test]
async fn every_bad_registration_is_422_naming_the_field_and_stores_nothing() {
    let app = app().await;
    let before = count(&app).await;
    let arm = read("arms/wam.urdf");
    let hand = read("hands/t42.urdf");
    let cases: Vec<(&str, Value, &str, &str)> = vec![
        (
            "malformed XML",
            json!({"arm_urdf": "<robot name=\"x\"><link name=\"a\"></robot>"}),
            "$.arm_urdf",
            "",
        ),
        (
            "missing link",
            json!({"arm_urdf": arm.replace("<child link=\"wam_link3\"/>", "<child link=\"ghost\"/>")}),
            "$.arm_urdf",
            "wam_joint3",
        ),
        (
            "several roots",
            json!({"hand_urdf": hand.replace("<link name=\"t42_left_tip\"/>", "<link name=\"t42_left_tip\"/><link name=\"orphan\"/>")}),
            "$.hand_urdf",
            "orphan",
        ),
        (
            "cycle",
            json!({"arm_urdf": arm.replace("</robot>", "<joint name=\"loop\" type=\"fixed\"><parent link=\"wam_link7\"/><child link=\"wam_base_link\"/></joint></robot>")}),
            "$.arm_urdf",
            "",
        ),
        (
            "mimic of a missing joint",
            json!({"hand_urdf": hand.replace("<mimic joint=\"t42_left_proximal\"", "<mimic joint=\"t42_ghost\"")}),
            "$.hand_urdf",
            "t42_ghost",
        ),
        (
            "lower above upper",
            json!({"arm_urdf": arm.replace("lower=\"-2.6\" upper=\"2.6\"", "lower=\"2.7\" upper=\"2.6\"")}),
            "$.arm_urdf",
            "wam_joint1",
        ),
        (
            "NaN",
            json!({"arm_urdf": arm.replace("<origin xyz=\"0 0 0.346\"", "<origin xyz=\"0 NaN 0.346\"")}),
            "$.arm_urdf",
            "wam_joint1",
        ),
        (
            "infinity",
            json!({"hand_urdf": hand.replace("<box size=\"0.0625 ", "<box size=\"inf ")}),
            "$.hand_urdf",
            "t42_left_proximal",
        ),
        (
            "missing mesh",
            json!({"arm_urdf": arm.replace("<sphere radius=\"0.09\"/>", "<mesh filename=\"meshes/shoulder.stl\"/>")}),
            "$.arm_urdf",
            "wam_link1",
        ),
        (
            "over the size limit",
            json!({"arm_urdf": arm.replace("</robot>", &format!("<!--{}--></robot>", "x".repeat(5 << 20)))}),
            "$.arm_urdf",
            "limit",
        ),
        (
            "unknown tip frame",
            json!({"descriptor_patch": ["fingers", 0, "tip_frame", "nowhere"]}),
            "$.descriptor.fingers[0].tip_frame",
            "nowhere",
        ),
        (
            "unknown mount frame",
            json!({"descriptor_patch": ["mount", null, "parent_frame", "wam_nose"]}),
            "$.descriptor.mount.parent_frame",
            "wam_nose",
        ),
    ];
    for (what, patch, path, mention) in cases {
        let mut body = wam_t42_body();
        for key in ["arm_urdf", "hand_urdf"] {
            if let Some(v) = patch.get(key) {
                body[key] = v.clone();
            }
        }
        if let Some(p) = patch.get("descriptor_patch") {
            let target = match p[1].as_u64() {
                Some(i) => &mut body["descriptor"][p[0].as_str().unwrap()][i as usize],
                None => &mut body["descriptor"][p[0].as_str().unwrap()],
            };
            target[p[2].as_str().unwrap()] = p[3].clone();
        }
        let problem =
            assert_problem(app.post_json("/v1/robots", &body).await, 422, "validation").await;
        assert_eq!(problem["errors"][0]["path"], path, "{what}: {problem}");
        assert!(
            problem["detail"].as_str().unwrap().contains(mention),
            "{what}: {problem}"
        );
    }
    let mut no_urdf = wam_t42_body();
    no_urdf.as_object_mut().unwrap().remove("hand_urdf");
    assert_problem(
        app.post_json("/v1/robots", &no_urdf).await,
        422,
        "validation",
    )
    .await;
    let mut bad_desc = wam_t42_body();
    bad_desc["descriptor"]["fingers"] = json!("many");
    let p = assert_problem(
        app.post_json("/v1/robots", &bad_desc).await,
        422,
        "validation",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "$.descriptor.fingers");
    assert_eq!(count(&app).await, before, "nothing stored");
}

#[tokio::test]
async fn bundled_systems_sync_idempotently_and_a_changed_file_updates_its_entry() {
    let dir = tempfile::tempdir().unwrap();
    let robots = dir.path().join("robots");
    for sub in ["arms", "hands", "systems"] {
        std::fs::create_dir_all(robots.join(sub)).unwrap();
        for e in std::fs::read_dir(robots_dir().join(sub)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), robots.join(sub).join(e.file_name())).unwrap();
        }
    }
    let db = dir.path().join("sync.db");
    let start = |robots: PathBuf, db: PathBuf| {
        spawn_app_with(move |c| {
            c.robots = robots;
            c.db = db;
        })
    };
    let first = start(robots.clone(), db.clone()).await;
    let a: Value = first.get("/v1/robots/wam_ihy").await.json().await.unwrap();
    let b: Value = first.get("/v1/robots/pa10_t42").await.json().await.unwrap();
    let n = count(&first).await;
    let toml_path = robots.join("systems/wam_ihy.toml");
    let text = std::fs::read_to_string(&toml_path)
        .unwrap()
        .replace("name = \"Barrett WAM + iHY\"", "name = \"WAM with iHY\"");
    std::fs::write(&toml_path, text).unwrap();
    let second = start(robots.clone(), db.clone()).await;
    assert_eq!(count(&second).await, n, "no duplicates");
    let a2: Value = second.get("/v1/robots/wam_ihy").await.json().await.unwrap();
    let b2: Value = second
        .get("/v1/robots/pa10_t42")
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(a2["name"], "WAM with iHY");
    assert_ne!(a2["updated_at"], a["updated_at"]);
    assert_eq!(
        b2["updated_at"], b["updated_at"],
        "unchanged files are left alone"
    );
}

const TETRA_OBJ: &str =
    "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";

#[tokio::test]
async fn meshes_uploaded_with_a_registered_system_are_stored_and_reload_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("meshes.db");
    let spawn = || {
        let db = db.clone();
        spawn_app_with(move |c| {
            c.robots = robots_dir();
            c.db = db;
        })
    };
    let app = spawn().await;
    let mesh = "package://wam/meshes/shoulder.obj";
    let mut body = wam_t42_body();
    body["arm_urdf"] = json!(body["arm_urdf"].as_str().unwrap().replace(
        "<sphere radius=\"0.09\"/>",
        &format!("<mesh filename=\"{mesh}\"/>")
    ));
    let before = count(&app).await;
    // Referenced but not uploaded: 422 naming the link and the file.
    let p = assert_problem(app.post_json("/v1/robots", &body).await, 422, "validation").await;
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("wam_link1") && detail.contains(mesh), "{p}");
    // Undecodable upload: 422 naming the entry.
    body["meshes"] = json!({mesh: {"data": "@@@", "encoding": "base64"}});
    let p = assert_problem(app.post_json("/v1/robots", &body).await, 422, "validation").await;
    assert_eq!(
        p["errors"][0]["path"],
        format!("$.meshes['{mesh}'].data"),
        "{p}"
    );
    assert_eq!(count(&app).await, before);
    body["meshes"] = json!({mesh: {"data": TETRA_OBJ}});
    let res = app.post_json("/v1/robots", &body).await;
    assert_eq!(res.status(), 201);
    let id = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    // The file is served back as uploaded (a physics worker builds the link from it), by its
    // percent-encoded URDF filename; an unknown file or robot is a 404.
    let encoded: String = mesh
        .bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect();
    let res = app.get(&format!("/v1/robots/{id}/meshes/{encoded}")).await;
    assert_eq!(res.status(), 200);
    assert_eq!(res.text().await.unwrap(), TETRA_OBJ);
    for path in [
        format!("/v1/robots/{id}/meshes/none.obj"),
        format!("/v1/robots/no_such_robot/meshes/{encoded}"),
    ] {
        assert_eq!(app.get(&path).await.status(), 404, "{path}");
    }
    // A fresh process (empty cache) rebuilds the system from the stored URDF and meshes.
    let again = spawn().await;
    let detail: Value = again
        .get(&format!("/v1/robots/{id}"))
        .await
        .json()
        .await
        .unwrap();
    let (names, q) = q_zero(&detail);
    let fk = again
        .post_json(
            &format!("/v1/robots/{id}/fk"),
            &json!({"joint_names": names, "positions": q}),
        )
        .await;
    assert_eq!(fk.status(), 200);
    // The meshes go with the robot.
    assert_eq!(
        delete(&again, &format!("/v1/robots/{id}")).await.status(),
        204
    );
}

/// A registered robot's `<visual>` geometry: a missing visual mesh is refused like a collision
/// mesh; uploaded, it is drawn in the 3-D viewer's scene on its link, placed as the URDF says.
/// An execution of an inline trajectory has no plan, and its viewer page says there is no scene.
#[tokio::test]
async fn a_visual_mesh_registered_with_a_robot_is_in_the_viewer_scene_where_the_urdf_puts_it() {
    let app = app().await;
    let mesh = "package://wam/meshes/link1_visual.obj";
    let mut body = wam_t42_body();
    // On wam_link1 (the shoulder): the tetrahedron scaled (2, 3, 4), 1/2/3 cm off the link
    // origin and turned 90° about z; a box beside it.
    let visuals = format!(
        "<visual><origin xyz=\"0.01 0.02 0.03\" rpy=\"0 0 1.5707963267948966\"/>\
         <geometry><mesh filename=\"{mesh}\" scale=\"2 3 4\"/></geometry></visual>\
         <visual><origin xyz=\"0 0 -0.2\"/><geometry><box size=\"0.1 0.2 0.3\"/></geometry></visual>"
    );
    body["arm_urdf"] = json!(body["arm_urdf"].as_str().unwrap().replacen(
        "<collision><geometry><sphere radius=\"0.09\"/></geometry></collision>\n  </link>",
        &format!(
            "<collision><geometry><sphere radius=\"0.09\"/></geometry></collision>{visuals}\n  </link>"
        ),
        1
    ));
    assert!(body["arm_urdf"].as_str().unwrap().contains(mesh));
    let before = count(&app).await;
    let p = assert_problem(app.post_json("/v1/robots", &body).await, 422, "validation").await;
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("wam_link1") && detail.contains(mesh), "{p}");
    assert_eq!(p["errors"][0]["path"], "$.arm_urdf", "{p}");
    assert_eq!(count(&app).await, before, "nothing stored");
    body["meshes"] = json!({mesh: {"data": TETRA_OBJ}});
    let res = app.post_json("/v1/robots", &body).await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let robot = res.json::<Value>().await.unwrap();
    let id = robot["id"].as_str().unwrap().to_owned();
    let names = robot["joint_names"].as_array().unwrap().clone();

    // Joint 1 at 90°, every other joint at 0, held for a second (no worker: it stays queued
    // and the scene draws what was sent).
    let q: Vec<f64> = names
        .iter()
        .map(|n| if n == "wam_joint1" { FRAC_PI_2 } else { 0.0 })
        .collect();
    let zeros = vec![0.0; q.len()];
    let point =
        |t: f64| json!({"t": t, "positions": q, "velocities": zeros, "accelerations": zeros});
    let res = app
        .post_json(
            "/v1/executions",
            &json!({"robot": id, "mode": "open_loop",
                    "trajectory": {"joint_names": names, "points": [point(0.0), point(1.0)]}}),
        )
        .await;
    assert_eq!(res.status(), 202, "{}", res.text().await.unwrap());
    let execution = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let res = app
        .get(&format!("/ui/view/executions/{execution}/scene.json"))
        .await;
    assert_eq!(res.status(), 200);
    let scene: Value = res.json().await.unwrap();
    let links = scene["links"].as_array().unwrap();
    let k = links
        .iter()
        .position(|l| l["name"] == "wam_link1")
        .expect("wam_link1 is drawn");
    let link1 = &links[k];
    assert_eq!(
        link1["shapes"].as_array().unwrap().len(),
        1,
        "its collision sphere"
    );
    let visuals = link1["visuals"].as_array().unwrap();
    assert_eq!(visuals.len(), 2, "{link1}");
    let nums = |v: &Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let close = |got: &[f64], want: &[f64], what: &str| {
        assert_eq!(got.len(), want.len(), "{what}");
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-4, "{what}: {got:?} vs {want:?}");
        }
    };
    let h = FRAC_1_SQRT_2;
    // The mesh in the link frame: the URDF origin, rpy (0, 0, 90°) = q (cos 45°, 0, 0, sin 45°).
    let m = &visuals[0];
    assert_eq!(m["geometry"]["type"], "mesh");
    close(
        &nums(&m["pose"]),
        &[0.01, 0.02, 0.03, h, 0.0, 0.0, h],
        "mesh pose",
    );
    // The vertices scaled (2, 3, 4): (0.1, 0, 0) -> (0.2, 0, 0), (0, 0, 0.1) -> (0, 0, 0.4).
    let v = nums(&m["geometry"]["vertices"]);
    assert!(
        v.chunks(3)
            .any(|p| (p[0] - 0.2).abs() < 1e-6 && p[1] == 0.0 && p[2] == 0.0)
    );
    assert!(
        v.chunks(3)
            .any(|p| p[0] == 0.0 && p[1] == 0.0 && (p[2] - 0.4).abs() < 1e-6)
    );
    assert!(
        v.chunks(3)
            .any(|p| p[0] == 0.0 && (p[1] - 0.3).abs() < 1e-6 && p[2] == 0.0)
    );
    assert_eq!(m["geometry"]["indices"].as_array().unwrap().len(), 12);
    let b = &visuals[1];
    assert_eq!(
        b["geometry"],
        json!({"type": "box", "size": [0.1, 0.2, 0.3]})
    );
    close(
        &nums(&b["pose"]),
        &[0.0, 0.0, -0.2, 1.0, 0.0, 0.0, 0.0],
        "box pose",
    );
    // wam_link1 in the world at joint 1 = 90°: 0.346 m above the base, turned 90° about z.
    let frame0 = nums(&scene["frames"]["links"][0]);
    close(
        &frame0[7 * k..7 * k + 7],
        &[0.0, 0.0, 0.346, h, 0.0, 0.0, h],
        "wam_link1 pose",
    );
    // So the mesh's vertex (0.2, 0, 0) is at link (0.01, 0.22, 0.03) and, turned once more,
    // at world (-0.22, 0.01, 0.376): where the link pose and the shape pose put it.
    let iso = |p: &[f64]| {
        Isometry3::from_parts(
            Translation3::new(p[0], p[1], p[2]),
            UnitQuaternion::from_quaternion(Quaternion::new(p[3], p[4], p[5], p[6])),
        )
    };
    let world =
        iso(&frame0[7 * k..7 * k + 7]) * iso(&nums(&m["pose"])) * Point3::new(0.2, 0.0, 0.0);
    close(
        &[world.x, world.y, world.z],
        &[-0.22, 0.01, 0.376],
        "the vertex",
    );

    // No plan made it: the page says there is no scene, and the scene has no object.
    assert!(scene["object"].is_null() && scene["support"].is_null());
    let page = app
        .get(&format!("/ui/view/executions/{execution}"))
        .await
        .text()
        .await
        .unwrap();
    assert!(
        page.contains("no scene: this execution was not made by a plan"),
        "{page}"
    );
    assert!(page.contains("a trajectory given inline"), "{page}");
    assert!(
        page.contains("class=\"viewer-geometry\""),
        "the collision / visual switch"
    );
}
