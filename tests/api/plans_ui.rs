//! The plans pages of the dashboard over plain HTTP: the list (paged, with the form and the
//! compare checkboxes), a plan's page linking its grasp, trajectory and execution with their
//! numbers and figures, the comparison of two plans and of two grasps, and readable errors.

use serde_json::{Value, json};

use crate::helpers::{TestApp, spawn_app_with, trained};

const ROBOT: &str = "wam_ihy";
const BALL: &str = "00000000-0000-4000-8000-000000000001";
const BOTTLE: &str = "00000000-0000-4000-8000-000000000002";

async fn page(app: &TestApp, path: &str) -> (u16, String) {
    let res = app.get(path).await;
    let status = res.status().as_u16();
    let ct = res.headers()["content-type"].to_str().unwrap().to_owned();
    assert!(ct.starts_with("text/html"), "{path}: {ct}");
    (status, res.text().await.unwrap())
}

/// The number as the dashboard writes it (`html::num` with 5 digits).
fn five(v: &Value) -> String {
    format!("{:.5}", v.as_f64().expect("a number"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plan_pages_link_grasp_trajectory_and_execution_and_compare_side_by_side() {
    let app = spawn_app_with(|c| {
        c.robots = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("robots")
    })
    .await;

    // Before any plan: the list answers with the form and says it is empty; the overview
    // counts no plans and the navigation leads to the list.
    let (status, html) = page(&app, "/ui/plans").await;
    assert_eq!(status, 200);
    for needle in [
        "id=\"plan-form\"",
        "data-endpoint=\"/v1/plans\"",
        "data-path=\"$.task_directions[0].direction\"",
        "data-path=\"$.start\"",
        "data-path=\"$.execute\"",
        "0 of 0",
    ] {
        assert!(html.contains(needle), "{needle}");
    }
    // The bare prefix of the pages leads to the overview.
    let no_follow = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();
    for prefix in ["/ui", "/ui/"] {
        let res = no_follow.get(app.url(prefix)).send().await.unwrap();
        assert_eq!(res.status(), 308, "{prefix}");
        assert_eq!(res.headers()["location"], "/", "{prefix}");
    }
    let (_, home) = page(&app, "/").await;
    assert!(home.contains("<a href=\"/ui/plans\">Plans</a>"), "nav");
    assert!(
        home.contains("href=\"/ui/plans\"><span class=\"count\">0</span> plans"),
        "overview card"
    );

    let (_, start) = trained(&app, ROBOT).await;
    // Two plans (ball, bottle), the ball's execution queued (no worker is connected here).
    let bodies = [
        json!({"robot": ROBOT, "object_id": BALL, "start": start, "execute": true,
               "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        json!({"robot": ROBOT, "object_id": BOTTLE, "start": start,
               "task_directions": [{"direction": [0, 1, 0], "kind": "velocity", "goal": "maximize"}]}),
    ];
    let mut plans = Vec::new();
    for body in &bodies {
        let res = app.post_json("/v1/plans", body).await;
        assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
        plans.push(res.json::<Value>().await.unwrap());
    }

    // The list: both plans, newest first, each with its links and a compare checkbox.
    let (status, list) = page(&app, "/ui/plans").await;
    assert_eq!(status, 200);
    assert!(list.contains("1–2 of 2"), "pager");
    let (a, b) = (&plans[0], &plans[1]);
    for p in &plans {
        let id = p["id"].as_str().unwrap();
        assert!(list.contains(&format!("href=\"/ui/plans/{id}\"")), "{id}");
        assert!(
            list.contains(&format!("name=\"plans\" value=\"{id}\"")),
            "{id}"
        );
        let grasp = p["grasp"]["id"].as_str().unwrap();
        assert!(list.contains(&format!("href=\"/ui/grasps/{grasp}\"")));
    }
    let newer = list.find(b["id"].as_str().unwrap()).unwrap();
    let older = list.find(a["id"].as_str().unwrap()).unwrap();
    assert!(newer < older, "newest first");
    assert!(
        list.contains("ball") && list.contains("bottle"),
        "object names"
    );
    // A later page holds the older plan only.
    let (_, second) = page(&app, "/ui/plans?offset=1").await;
    assert!(second.contains("2–2 of 2"));
    assert!(second.contains(a["id"].as_str().unwrap()));
    assert!(!second.contains(&format!("/ui/plans/{}", b["id"].as_str().unwrap())));

    // Each plan's page: the request, the verdict, the grasp's numbers and figure, the
    // trajectory and the execution, each linked to its own page, and the 3-D view.
    for p in &plans {
        let id = p["id"].as_str().unwrap();
        let (status, html) = page(&app, &format!("/ui/plans/{id}")).await;
        assert_eq!(status, 200, "{id}");
        let grasp = &p["grasp"];
        let g = grasp["id"].as_str().unwrap();
        for needle in [
            format!("href=\"/ui/grasps/{g}\""),
            format!("data-src=\"/v1/grasps/{g}/plot.svg\""),
            format!("href=\"/ui/view/plans/{id}\""),
            format!("href=\"/v1/plans/{id}\""),
            five(&grasp["result"]["terms"]["cost"]),
            five(&grasp["result"]["residuals"]["max_surface_distance"]),
            five(&grasp["result"]["arm_ellipsoids"]["velocity_semi_axes"][0]),
        ] {
            assert!(html.contains(&needle), "{id}: {needle}");
        }
        assert_eq!(
            html.contains("<span class=\"ok\">feasible</span>"),
            p["feasible"] == true || grasp["result"]["feasible"] == true,
            "{id}"
        );
        match p["trajectory"]["id"].as_str() {
            Some(t) => {
                assert!(html.contains(&format!("href=\"/ui/trajectories/{t}\"")));
                assert!(html.contains(&format!("/v1/trajectories/{t}/plot.svg")));
                assert!(html.contains("Timing and clearance"), "report facts");
                let d = p["trajectory"]["report"]["duration"].as_f64().unwrap();
                assert!(html.contains(&format!("{d:.3} s")), "duration {d}");
            }
            None => assert!(html.contains("No motion was generated")),
        }
        match p["execution_id"].as_str() {
            Some(e) => {
                assert!(html.contains(&format!("href=\"/ui/executions/{e}\"")));
                assert!(
                    html.contains(&format!("data-execution=\"{e}\"")),
                    "live bar"
                );
                assert!(html.contains(&format!("/v1/executions/{e}/plot.svg")));
            }
            None => assert!(html.contains("Not executed: execution was")),
        }
    }
    // The ball plan asked to execute: queued whenever its motion was feasible.
    assert_eq!(a["execution_id"].is_string(), a["feasible"] == true, "{a}");

    // The form's start is robot-independent: "current" or "zero", never one robot's joints.
    let (_, list) = page(&app, "/ui/plans").await;
    let select = &list[list.find("name=\"start\"").unwrap()..];
    let select = &select[..select.find("</select>").unwrap()];
    assert_eq!(select.matches("<option").count(), 2, "{select}");
    // No worker is connected here, so there is no current state: "zero" is preselected.
    assert!(
        select.contains("value=\"&quot;zero&quot;\" selected"),
        "{select}"
    );
    assert!(
        select.contains("value=\"&quot;current&quot;\">"),
        "{select}"
    );
    assert!(!select.contains("joint_names"), "{select}");
    // What the form sends for "zero" plans from the chosen robot's zero configuration.
    let res = app
        .post_json(
            "/v1/plans",
            &json!({"robot": ROBOT, "object_id": BALL, "start": "zero",
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let zero: Value = res.json().await.unwrap();
    if let Some(points) = zero["trajectory"]["points"].as_array() {
        let first = points[0]["positions"].as_array().unwrap();
        assert!(first.iter().all(|v| v.as_f64() == Some(0.0)), "{first:?}");
    }

    // An execution a plan queued is drawn in the plan's scene whatever its mode: the closed
    // loop's payload is the model's law, with no trajectory to find the object through.
    let res = app
        .post_json(
            "/v1/plans",
            &json!({"robot": ROBOT, "object_id": BALL, "start": "zero", "execute": true,
                    "mode": "closed_loop",
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await;
    assert_eq!(res.status(), 201, "{}", res.text().await.unwrap());
    let closed: Value = res.json().await.unwrap();
    let open_e = a["execution_id"]
        .as_str()
        .expect("the ball plan was executed");
    let closed_e = closed["execution_id"]
        .as_str()
        .unwrap_or_else(|| panic!("the closed-loop plan was executed: {closed}"));
    let exec: Value = app
        .get(&format!("/v1/executions/{closed_e}"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(exec["mode"], "closed_loop", "{exec}");
    for (e, plan) in [(open_e, a), (closed_e, &closed)] {
        let res = app
            .get(&format!("/ui/view/executions/{e}/scene.json"))
            .await;
        assert_eq!(res.status(), 200, "{e}");
        let scene: Value = res.json().await.unwrap();
        assert_eq!(
            scene["object"]["geometry"]["type"], "sphere",
            "{e}: the ball"
        );
        let want = &plan["grasp"]["object"]["position"];
        for i in 0..3 {
            let (got, want) = (
                scene["object"]["pose"][i].as_f64().unwrap(),
                want[i].as_f64().unwrap(),
            );
            assert!((got - want).abs() < 1e-4, "{e}: object at {got} vs {want}");
        }
        assert!(scene["support"].is_object(), "{e}: the ball's support");
        assert_eq!(
            scene["contacts"].as_array().unwrap().len(),
            plan["grasp"]["result"]["contacts"]
                .as_array()
                .unwrap()
                .len(),
            "{e}"
        );
        let (_, html) = page(&app, &format!("/ui/view/executions/{e}")).await;
        assert!(!html.contains("no scene"), "{e}");
    }
    // A plan's trajectory run again by id in closed loop is held to the plan's rule: its law
    // is first run by the service, as a closed-loop plan's is (one that stops short is a 422,
    // nothing queued). The sunglasses for a force along z from the demonstrated start used to
    // stop 0.029 rad short, the thumb on the frame; with the safety filter guarding deviations
    // from the path rather than the path itself (`tests/api/bridges.rs`) it arrives and is
    // queued, as open loop is.
    let sunglasses = "00000000-0000-4000-8000-000000000005";
    let res = app
        .post_json(
            "/v1/plans",
            &json!({"robot": ROBOT, "object_id": sunglasses, "start": start,
                    "task_directions": [{"direction": [0, 0, 1], "kind": "force", "goal": "maximize"}]}),
        )
        .await;
    assert_eq!(res.status(), 201);
    let open: Value = res.json().await.unwrap();
    assert_eq!(open["feasible"], true, "{}", open["reason"]);
    let before = app.items("/v1/executions").await;
    let by_id = |mode: &str| json!({"robot": ROBOT, "mode": mode, "trajectory_id": open["trajectory"]["id"]});
    for mode in ["closed_loop", "open_loop"] {
        let res = app.post_json("/v1/executions", &by_id(mode)).await;
        assert_eq!(res.status(), 202, "{mode}: {}", res.text().await.unwrap());
    }
    assert_eq!(app.items("/v1/executions").await, before + 2);

    // A bare model execution posted to /v1/executions has no plan and so no object: the page
    // says so instead of drawing an empty scene.
    let res = app
        .post_json(
            "/v1/executions",
            &json!({"robot": ROBOT, "mode": "closed_loop", "model_id": closed["model_id"],
                    "goal": start}),
        )
        .await;
    assert_eq!(res.status(), 202, "{}", res.text().await.unwrap());
    let bare = res.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let scene: Value = app
        .get(&format!("/ui/view/executions/{bare}/scene.json"))
        .await
        .json()
        .await
        .unwrap();
    assert!(scene["object"].is_null(), "{}", scene["object"]);
    let (status, html) = page(&app, &format!("/ui/view/executions/{bare}")).await;
    assert_eq!(status, 200);
    assert!(
        html.contains("no scene: this execution was not made by a plan"),
        "{html}"
    );
    assert!(html.contains("the control law of model"), "{html}");

    // The comparison of the two plans: both columns, every cost term's row, both figures.
    let (ia, ib) = (a["id"].as_str().unwrap(), b["id"].as_str().unwrap());
    for query in [format!("plans={ia},{ib}"), format!("plans={ia}&plans={ib}")] {
        let (status, html) = page(&app, &format!("/ui/compare?{query}")).await;
        assert_eq!(status, 200, "{query}");
        assert!(html.contains("Compare 2 plans"), "{query}");
        for p in &plans {
            let id = p["id"].as_str().unwrap();
            let g = p["grasp"]["id"].as_str().unwrap();
            assert!(html.contains(&format!("href=\"/ui/plans/{id}\"")));
            assert!(html.contains(&format!("data-src=\"/v1/grasps/{g}/plot.svg\"")));
            assert!(html.contains(&five(&p["grasp"]["result"]["terms"]["tc"])));
        }
        for term in [
            "cost",
            "tc",
            "gc",
            "manipulability",
            "q_dc (m)",
            "max_object_penetration (m)",
            "exact.passed",
        ] {
            assert!(html.contains(&format!("<b>{term}</b>")), "{term}");
        }
        assert!(html.contains("arm velocity semi-axes"));
        // The difference column is the second minus the first.
        let (ca, cb) = (
            a["grasp"]["result"]["terms"]["cost"].as_f64().unwrap(),
            b["grasp"]["result"]["terms"]["cost"].as_f64().unwrap(),
        );
        assert!(html.contains(&format!("{:.5}", cb - ca)), "cost difference");
    }
    // Two grasps by id, ticked in the grasp list.
    let (ga, gb) = (
        a["grasp"]["id"].as_str().unwrap(),
        b["grasp"]["id"].as_str().unwrap(),
    );
    let (_, grasps) = page(&app, "/ui/grasps").await;
    for g in [ga, gb] {
        assert!(
            grasps.contains(&format!("name=\"grasps\" value=\"{g}\"")),
            "{g}"
        );
    }
    assert!(grasps.contains("action=\"/ui/compare\""));
    let (status, html) = page(&app, &format!("/ui/compare?grasps={ga},{gb}")).await;
    assert_eq!(status, 200);
    assert!(html.contains("Compare 2 grasps"));
    assert!(html.contains(&format!("href=\"/ui/grasps/{gb}\"")));

    // A plan's page offers the comparison with the other plan.
    let (_, html) = page(&app, &format!("/ui/plans/{ia}")).await;
    assert!(html.contains(&format!("<option value=\"{ib}\">")));

    // Readable errors: an unknown plan is a 404 page, one id is not a comparison, an unknown
    // id in a comparison names it.
    let (status, html) = page(&app, "/ui/plans/nope").await;
    assert_eq!(status, 404);
    assert!(html.contains("There is no plan with id <code>nope</code>"));
    let (status, html) = page(&app, &format!("/ui/compare?plans={ia}")).await;
    assert_eq!(status, 422);
    assert!(html.contains("Pick two to 4 plans"));
    let (status, html) = page(&app, &format!("/ui/compare?plans={ia},nope")).await;
    assert_eq!(status, 404);
    assert!(html.contains("There is no plan with id"));
    let (status, _) = page(&app, "/ui/compare").await;
    assert_eq!(status, 200, "the empty comparison is its form");

    let (_, home) = page(&app, "/").await;
    // The two compared, the one from "zero", the closed-loop one and the sunglasses.
    assert!(home.contains("href=\"/ui/plans\"><span class=\"count\">5</span> plans"));
}
