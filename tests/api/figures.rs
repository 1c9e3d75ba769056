//! Figures (`/v1/.../plot.svg`) and dashboard pages over HTTP: SVG content, range checks,
//! readable not-found pages.

use serde_json::{Value, json};

use crate::helpers::{TestApp, assert_problem, spawn_app_with};

async fn app() -> TestApp {
    spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await
}

/// Asserts an SVG response and returns its parsed polyline count.
/// The response's content type (empty when it has none).
fn content_type(res: &reqwest::Response) -> &str {
    res.headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
}

async fn svg_polylines(res: reqwest::Response) -> usize {
    assert_eq!(res.status(), 200);
    assert_eq!(res.headers()["content-type"], "image/svg+xml");
    let text = res.text().await.unwrap();
    let doc = roxmltree::Document::parse(&text).expect("well-formed SVG");
    assert_eq!(doc.root_element().tag_name().name(), "svg");
    doc.descendants()
        .filter(|n| n.has_tag_name("polyline"))
        .count()
}

#[tokio::test]
async fn robot_posture_is_svg_and_its_parameters_are_range_checked() {
    let app = app().await;
    let n = svg_polylines(app.get("/v1/robots/wam_ihy/plot.svg").await).await;
    assert!(n > 10, "{n} polylines");
    let turned = svg_polylines(
        app.get("/v1/robots/wam_ihy/plot.svg?azimuth=-120&elevation=60")
            .await,
    )
    .await;
    assert_eq!(turned, n);

    let p = assert_problem(
        app.get("/v1/robots/wam_ihy/plot.svg?azimuth=181").await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "azimuth");
    let p = assert_problem(
        app.get("/v1/robots/wam_ihy/plot.svg?elevation=-91").await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "elevation");
    let p = assert_problem(
        app.get("/v1/robots/wam_ihy/plot.svg?q=0,0").await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "q");
    assert_problem(app.get("/v1/robots/nope/plot.svg").await, 404, "not-found").await;
}

#[tokio::test]
async fn a_joint_value_outside_its_limits_is_named() {
    let app = app().await;
    let robot: Value = app.get("/v1/robots/wam_ihy").await.json().await.unwrap();
    let n = robot["joint_names"].as_array().unwrap().len();
    let mut q = vec!["0".to_owned(); n];
    q[0] = "99".into();
    let p = assert_problem(
        app.get(&format!("/v1/robots/wam_ihy/plot.svg?q={}", q.join(",")))
            .await,
        400,
        "invalid-parameter",
    )
    .await;
    let detail = p["detail"].as_str().unwrap();
    assert!(detail.contains("q[0]") && detail.contains("99"), "{detail}");
}

#[tokio::test]
async fn demonstration_and_grasp_figures_render_from_stored_data() {
    let app = app().await;
    let res = app
        .post_json(
            "/v1/demonstrations/synthetic",
            &json!({"subjects": 1, "positions": 1, "trials": 1}),
        )
        .await;
    assert_eq!(res.status(), 202);
    let job: Value = res.json().await.unwrap();
    let job = app
        .wait_job(job["id"].as_str().unwrap(), |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let demo = job["result"]["id"].as_str().unwrap();
    // Two panels, one series each (plus the axes' own lines).
    assert!(
        svg_polylines(
            app.get(&format!("/v1/demonstrations/{demo}/plot.svg"))
                .await
        )
        .await
            >= 2
    );
    assert_problem(
        app.get(&format!(
            "/v1/demonstrations/{}/plot.svg",
            uuid::Uuid::new_v4()
        ))
        .await,
        404,
        "not-found",
    )
    .await;

    let objects: Vec<Value> = app.get("/v1/objects").await.json().await.unwrap();
    let ball = objects.iter().find(|o| o["name"] == "ball").unwrap()["id"].clone();
    let res = app
        .post_json(
            "/v1/grasps",
            &json!({"robot": "wam_ihy", "object_id": ball, "starts": 1,
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let grasp: Value = res.json().await.unwrap();
    let id = grasp["id"].as_str().unwrap();
    let n = svg_polylines(
        app.get(&format!("/v1/grasps/{id}/plot.svg?ellipsoid=velocity"))
            .await,
    )
    .await;
    assert!(n > 10);
    let p = assert_problem(
        app.get(&format!("/v1/grasps/{id}/plot.svg?ellipsoid=both"))
            .await,
        400,
        "invalid-parameter",
    )
    .await;
    assert_eq!(p["errors"][0]["path"], "ellipsoid");

    // The detail pages show the figures and numbers.
    for page in [
        format!("/ui/grasps/{id}"),
        format!("/ui/demonstrations/{demo}"),
    ] {
        let res = app.get(&page).await;
        assert_eq!(res.status(), 200, "{page}");
        let html = res.text().await.unwrap();
        assert!(html.contains("plot.svg"), "{page}");
    }
    // The grasp page shows the exact check that decided `feasible`, with the value the API gave.
    let html = app
        .get(&format!("/ui/grasps/{id}"))
        .await
        .text()
        .await
        .unwrap();
    assert!(html.contains("Exact check") && html.contains("pad angle"));
    let balance = grasp["result"]["exact"]["normal_balance"].as_f64().unwrap();
    let at = html
        .find(">normal_balance<")
        .expect("normal_balance listed");
    assert!(
        html[at..at + 120].contains(&format!("{balance:.5}")),
        "{}",
        &html[at..at + 120]
    );
    // ... and whether it is firm, as the API says (`exact.firm`: the check passed and the
    // contacts' normal balance is at most 0.12), with the reason when it is not.
    let firm = grasp["result"]["exact"]["firm"].as_bool().unwrap();
    assert_eq!(
        firm,
        grasp["result"]["exact"]["passed"] == true && balance <= 0.12
    );
    let row = &html[html.find(">firm<").expect("firm listed")..];
    let row = &row[..row.find("</dd>").expect("a value")];
    let expected = if firm {
        ">yes"
    } else {
        ">no: the contact normals cannot balance"
    };
    assert!(row.contains(expected), "{row}");
    let list = app.get("/ui/grasps").await.text().await.unwrap();
    assert!(list.contains(&format!("/ui/grasps/{id}")));
}

#[tokio::test]
async fn dashboard_pages_and_assets_are_served_from_the_binary() {
    let app = app().await;
    let res = app.get("/").await;
    assert_eq!(res.status(), 200);
    assert!(content_type(&res).starts_with("text/html"));
    let html = res.text().await.unwrap();
    for needle in [
        "Generate a synthetic study",
        "/assets/app.js",
        "data-path=\"$.subjects\"",
    ] {
        assert!(html.contains(needle), "{needle}");
    }
    for (path, ct) in [
        ("/assets/app.js", "text/javascript"),
        ("/assets/style.css", "text/css"),
        ("/ui/robots", "text/html"),
        ("/ui/robots/wam_ihy", "text/html"),
        ("/ui/objects", "text/html"),
        ("/ui/demonstrations", "text/html"),
        ("/ui/jobs", "text/html"),
        ("/ui/mappings", "text/html"),
        ("/ui/models", "text/html"),
        ("/ui/trajectories", "text/html"),
        ("/ui/bridges", "text/html"),
        ("/ui/executions", "text/html"),
    ] {
        let res = app.get(path).await;
        assert_eq!(res.status(), 200, "{path}");
        assert!(content_type(&res).starts_with(ct), "{path}");
    }
}

#[tokio::test]
async fn unknown_ids_give_a_readable_not_found_page() {
    let app = app().await;
    for (path, what) in [
        ("/ui/robots/nope", "robot"),
        ("/ui/objects/nope", "object"),
        ("/ui/demonstrations/nope", "demonstration"),
        ("/ui/grasps/nope", "grasp"),
        ("/ui/jobs/nope", "job"),
        ("/ui/mappings/nope", "mapping"),
        ("/ui/models/nope", "model"),
        ("/ui/trajectories/nope", "trajectory"),
        ("/ui/executions/nope", "execution"),
    ] {
        let res = app.get(path).await;
        assert_eq!(res.status(), 404, "{path}");
        assert!(content_type(&res).starts_with("text/html"));
        let html = res.text().await.unwrap();
        assert!(
            html.contains(&format!("There is no {what} with id")),
            "{path}"
        );
        assert!(html.contains("<code>nope</code>"), "{path}");
    }
    // A dashboard path that is no page at all: an HTML page saying so, the API stays problem+json.
    let res = app.get("/ui/no-such-page").await;
    assert_eq!(res.status(), 404);
    assert!(content_type(&res).starts_with("text/html"));
    let html = res.text().await.unwrap();
    assert!(html.contains("There is no page at <code>/ui/no-such-page</code>"));
    let res = app.get("/v1/no-such-resource").await;
    assert_eq!(res.status(), 404);
    assert_eq!(content_type(&res), "application/problem+json");
}

#[tokio::test]
async fn figures_of_unknown_resources_are_404_problems() {
    let app = app().await;
    for path in [
        "/v1/mappings/nope/plot.svg",
        "/v1/models/nope/plot.svg",
        "/v1/trajectories/nope/plot.svg",
        "/v1/executions/nope/plot.svg",
        "/v1/grasps/nope/plot.svg",
    ] {
        assert_problem(app.get(path).await, 404, "not-found").await;
    }
    // The view is checked before anything is loaded.
    assert_problem(
        app.get("/v1/mappings/nope/plot.svg?azimuth=-200").await,
        400,
        "invalid-parameter",
    )
    .await;
}
