//! The interactive 3-D viewer (WebGL, three.js vendored into the binary): pages at
//! `/ui/view/{plans,trajectories,mappings,executions}/{id}`, the scene each draws as JSON at
//! the same path plus `/scene.json`, and `POST /ui/view/robots/{robot}/pose` (link poses of
//! named joint positions) for the live view of an execution.
//!
//! These JSON routes are the dashboard's own, not part of the documented API (not in the
//! OpenAPI document): their shape follows what the page draws. The scene is computed by the
//! pure [`crate::figures::viewer`] from the service's URDF collision (and visual) shapes and FK,
//! so the browser only composes transforms; this module loads what a scene needs (the
//! trajectory, its plan's or goal grasp's object, support, obstacles, contacts and ellipsoids;
//! a mapping's demonstration; an execution's plan and measured history) and runs the build off
//! the async workers.

use std::sync::Arc;

use axum::Json;
use axum::Router;
use axum::extract::{Path, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use nalgebra::Isometry3;
use serde::Deserialize;

use super::html::{self, PageError, esc, link, short};
use crate::figures::viewer::{Track, ViewGrasp, ViewInput, pose_of, view_scene};
use crate::geometry::{ObstacleSpec, pose_from_parts};
use crate::grasp::{GraspResult, ObjectSpec};
use crate::kinematics::System;
use crate::service::Context as AppState;
use crate::store::payload::ExecutionPayload;
use crate::store::{grasps as grasp_repo, plans as plan_repo, trajectories as trajectory_repo};

const SCRIPT: &str = include_str!("../../assets/dashboard/viewer.js");
// three.js r187 from the npm registry (`three@0.187.0`); see assets/dashboard/vendor/README.md.
const THREE: &str = include_str!("../../assets/dashboard/vendor/three.module.js");
const THREE_CORE: &str = include_str!("../../assets/dashboard/vendor/three.core.js");
const ORBIT: &str = include_str!("../../assets/dashboard/vendor/OrbitControls.js");
const THREE_LICENSE: &str = include_str!("../../assets/dashboard/vendor/three-LICENSE");

/// The viewer's routes, merged into the dashboard's.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/assets/viewer.js", get(|| js(SCRIPT)))
        .route("/assets/vendor/three.module.js", get(|| js(THREE)))
        .route("/assets/vendor/three.core.js", get(|| js(THREE_CORE)))
        .route("/assets/vendor/OrbitControls.js", get(|| js(ORBIT)))
        .route("/assets/vendor/three-LICENSE", get(license))
        .route("/ui/view/plans/{id}", get(plan_page))
        .route("/ui/view/plans/{id}/scene.json", get(plan_scene))
        .route("/ui/view/trajectories/{id}", get(trajectory_page))
        .route(
            "/ui/view/trajectories/{id}/scene.json",
            get(trajectory_scene),
        )
        .route("/ui/view/mappings/{id}", get(mapping_page))
        .route("/ui/view/mappings/{id}/scene.json", get(mapping_scene))
        .route("/ui/view/executions/{id}", get(execution_page))
        .route("/ui/view/executions/{id}/scene.json", get(execution_scene))
        .route("/ui/view/robots/{robot}/pose", post(robot_pose))
}

async fn js(body: &'static str) -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, "text/javascript; charset=utf-8"),
            (header::CACHE_CONTROL, "max-age=300"),
        ],
        body,
    )
}

async fn license() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        THREE_LICENSE,
    )
}

type Page = Result<Response, PageError>;

/// The viewer page: canvas, playback controls, and where its scene (and live events) come from;
/// `note` (HTML) is shown above the canvas, for what the scene lacks.
fn viewer_page(
    title: &str,
    active: &str,
    scene: &str,
    live: Option<&str>,
    back: &str,
    note: Option<&str>,
) -> Response {
    let live_attr = live
        .map(|l| format!(" data-live=\"{}\"", esc(l)))
        .unwrap_or_default();
    let note = note
        .map(|n| format!("<p class=\"viewer-note\">{n}</p>"))
        .unwrap_or_default();
    let body = format!(
        "<style>\
         .viewer {{ background: #fff; border: 1px solid var(--line); padding: .5rem; }}\
         .viewer canvas {{ width: 100%; height: 560px; display: block; background: #eef2f6; }}\
         .viewer-controls {{ display: flex; gap: .8rem; align-items: center; flex-wrap: wrap; \
         padding-top: .5rem; color: var(--muted); font-size: .92rem; }}\
         .viewer-controls input[type=range] {{ flex: 1; min-width: 12rem; }}\
         .viewer-controls .time-readout {{ font-variant-numeric: tabular-nums; min-width: 9rem; }}\
         .viewer-legend {{ color: var(--muted); font-size: .88rem; }}\
         .viewer-note {{ background: #fff6d6; border-left: 4px solid #e0a800; \
         padding: .4rem .7rem; }}\
         </style>\
         <p>{back} · drag to orbit, scroll to zoom, right-drag to pan.</p>{note}\
         <div class=\"viewer\" data-scene=\"{s}\"{live_attr}>\
         <canvas class=\"viewer-canvas\"></canvas>\
         <div class=\"viewer-controls\">\
         <button type=\"button\" class=\"viewer-play\" disabled>Play</button>\
         <button type=\"button\" class=\"viewer-step\" disabled>Step</button>\
         <input type=\"range\" class=\"viewer-time\" min=\"0\" max=\"0\" value=\"0\" step=\"1\" \
         aria-label=\"time\" disabled>\
         <span class=\"time-readout\">loading…</span>\
         <label>ellipsoid <select class=\"viewer-ellipsoid\"><option value=\"velocity\">velocity\
         </option><option value=\"force\">force</option><option value=\"\">none</option></select>\
         </label>\
         <label><input type=\"checkbox\" class=\"viewer-contacts\" checked> contacts</label>\
         <label>links <select class=\"viewer-geometry\" title=\"visual geometry where the robot \
         has it, or the collision shapes the checks use\"><option value=\"collision\">collision\
         </option><option value=\"visual\">visual</option></select></label>\
         </div><p class=\"viewer-legend\"></p><p class=\"field-error viewer-error\"></p></div>\
         <script type=\"module\" src=\"/assets/viewer.js\"></script>",
        s = esc(scene),
    );
    html::ok(title, active, &body)
}

fn json_response(body: String) -> Response {
    (
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

/// What surrounds a motion: its object (with the support it rests on), obstacles, and the grasp
/// it ends in.
#[derive(Debug, Default)]
struct Surroundings {
    object: Option<ObjectSpec>,
    grasp: Option<GraspResult>,
    obstacles: Vec<ObstacleSpec>,
}

fn internal<E: std::fmt::Display>(e: E) -> PageError {
    PageError::internal(anyhow::anyhow!("{e}"))
}

fn obstacles_of(request: &str) -> Vec<ObstacleSpec> {
    serde_json::from_str::<serde_json::Value>(request)
        .ok()
        .and_then(|v| serde_json::from_value(v["obstacles"].clone()).ok())
        .unwrap_or_default()
}

async fn with_grasp(
    state: &AppState,
    s: &mut Surroundings,
    grasp_id: &str,
) -> Result<(), PageError> {
    if let Some(g) = grasp_repo::get_grasp(&state.db, grasp_id).await? {
        s.object = Some(serde_json::from_str(&g.object).map_err(internal)?);
        s.grasp = Some(serde_json::from_str(&g.result).map_err(internal)?);
    }
    Ok(())
}

/// A trajectory's surroundings: its plan's (object, grasp, obstacles), else its goal grasp's
/// object with the obstacles of its own request.
async fn trajectory_surroundings(
    state: &AppState,
    t: &trajectory_repo::StoredTrajectory,
) -> Result<Surroundings, PageError> {
    let users = {
        let mut conn = state.db.acquire().await?;
        trajectory_repo::users(&mut conn, &t.id).await?
    };
    let mut s = Surroundings {
        obstacles: obstacles_of(&t.request),
        ..Surroundings::default()
    };
    if let Some(plan_id) = users.plans.first()
        && let Some(plan) = plan_repo::get(&state.db, plan_id).await?
    {
        s = plan_surroundings(state, &plan).await?;
    } else if let Some(g) = serde_json::from_str::<serde_json::Value>(&t.request)
        .ok()
        .and_then(|v| v["goal"]["grasp"].as_str().map(str::to_owned))
    {
        with_grasp(state, &mut s, &g).await?;
    }
    Ok(s)
}

/// The motion to draw, owned (the build runs on a blocking thread).
struct OwnedTrack {
    joint_names: Vec<String>,
    times: Vec<f64>,
    positions: Vec<f64>,
}

impl OwnedTrack {
    fn of_points(joint_names: Vec<String>, points: &[crate::motion::TrajectoryPoint]) -> Self {
        OwnedTrack {
            joint_names,
            times: points.iter().map(|p| p.t).collect(),
            positions: points
                .iter()
                .flat_map(|p| p.positions.iter().copied())
                .collect(),
        }
    }
    fn track(&self) -> Track<'_> {
        Track {
            joint_names: &self.joint_names,
            times: &self.times,
            positions: &self.positions,
        }
    }
}

/// Builds the scene JSON off the async workers.
async fn build(
    title: String,
    robot: String,
    system: Arc<System>,
    track: Option<OwnedTrack>,
    s: Surroundings,
    human: Option<(Vec<crate::human::HumanFrame>, crate::mapping::Registration)>,
) -> Result<Response, PageError> {
    let json = tokio::task::spawn_blocking(move || -> Result<String, PageError> {
        let object = match &s.object {
            Some(o) => Some((
                o.shape.clone(),
                pose_from_parts("object.", &o.position, &o.orientation).map_err(internal)?,
            )),
            None => None,
        };
        let obstacles: Vec<(String, crate::geometry::ShapeSpec, Isometry3<f64>)> = s
            .obstacles
            .iter()
            .map(|o| {
                pose_from_parts("obstacle.", &o.position, &o.orientation)
                    .map(|p| (o.name.clone(), o.shape.clone(), p))
            })
            .collect::<Result<_, _>>()
            .map_err(internal)?;
        let joints: Vec<(String, f64)> = s
            .grasp
            .iter()
            .flat_map(|g| g.q_arm.iter().chain(&g.q_hand))
            .map(|j| (j.name.clone(), j.value))
            .collect();
        let scene = view_scene(&ViewInput {
            title: &title,
            robot: &robot,
            system: &system,
            track: track.as_ref().map(OwnedTrack::track),
            object: object.as_ref().map(|(shape, pose)| (shape, pose)),
            support: s.object.as_ref().and_then(|o| o.support),
            obstacles: &obstacles,
            grasp: s.grasp.as_ref().map(|g| ViewGrasp {
                joints: &joints,
                contacts: &g.contacts,
                ellipsoids: &g.arm_ellipsoids,
            }),
            human: human.as_ref().map(|(h, r)| (h.as_slice(), r)),
            fps: None,
        })
        .map_err(|e| PageError(crate::service::Error::Conflict(e.to_string())))?;
        serde_json::to_string(&scene).map_err(internal)
    })
    .await
    .map_err(internal)??;
    Ok(json_response(json))
}

async fn plan_page(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    if plan_repo::get(&state.db, &id).await?.is_none() {
        return Ok(html::not_found("plan", &id, "/ui/plans", "plans"));
    }
    Ok(viewer_page(
        &format!("Plan {} in 3-D", short(&id)),
        "/ui/plans",
        &format!("/ui/view/plans/{id}/scene.json"),
        None,
        &format!(
            "{} · {}",
            link(&format!("/ui/plans/{id}"), "the plan"),
            link(&format!("/v1/plans/{id}"), "JSON")
        ),
        None,
    ))
}

/// A plan's scene: its grasp's object (with its support), contacts and ellipsoids, and the
/// obstacles of its request.
async fn plan_surroundings(
    state: &AppState,
    plan: &plan_repo::PlanRow,
) -> Result<Surroundings, PageError> {
    let mut s = Surroundings {
        obstacles: obstacles_of(&plan.request),
        ..Surroundings::default()
    };
    with_grasp(state, &mut s, &plan.grasp_id).await?;
    Ok(s)
}

async fn plan_scene(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let plan = plan_repo::get(&state.db, &id)
        .await?
        .ok_or_else(|| crate::service::Error::not_found("plan", &id))?;
    let s = plan_surroundings(&state, &plan).await?;
    let track = match &plan.trajectory_id {
        Some(t) => trajectory_repo::get_trajectory(&state.db, t)
            .await?
            .map(|t| OwnedTrack::of_points(t.joint_names, &t.points)),
        None => None,
    };
    let system = state.robots.system(&plan.robot).await?;
    let title = format!(
        "plan {} on {}{}",
        short(&id),
        plan.robot,
        if plan.feasible { "" } else { " (infeasible)" }
    );
    build(title, plan.robot, system, track, s, None).await
}

async fn trajectory_page(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    if trajectory_repo::get_trajectory(&state.db, &id)
        .await?
        .is_none()
    {
        return Ok(html::not_found(
            "trajectory",
            &id,
            "/ui/trajectories",
            "trajectories",
        ));
    }
    Ok(viewer_page(
        &format!("Trajectory {} in 3-D", short(&id)),
        "/ui/trajectories",
        &format!("/ui/view/trajectories/{id}/scene.json"),
        None,
        &link(&format!("/ui/trajectories/{id}"), "Back to the trajectory"),
        None,
    ))
}

async fn trajectory_scene(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let t = trajectory_repo::get_trajectory(&state.db, &id)
        .await?
        .ok_or_else(|| crate::service::Error::not_found("trajectory", &id))?;
    let s = trajectory_surroundings(&state, &t).await?;
    let system = state.robots.system(&t.robot).await?;
    let title = format!("trajectory {} on {}", short(&id), t.robot);
    let track = OwnedTrack::of_points(t.joint_names, &t.points);
    build(title, t.robot, system, Some(track), s, None).await
}

#[derive(Debug, Deserialize)]
pub struct DemoQuery {
    demo: Option<usize>,
}

async fn mapping_page(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<DemoQuery>,
) -> Page {
    if crate::store::mappings::get_mapping(&state.db, &id)
        .await?
        .is_none()
    {
        return Ok(html::not_found("mapping", &id, "/ui/mappings", "mappings"));
    }
    let demo = q.demo.unwrap_or(0);
    Ok(viewer_page(
        &format!("Mapping {} in 3-D: human and robot (Fig. 2)", short(&id)),
        "/ui/mappings",
        &format!("/ui/view/mappings/{id}/scene.json?demo={demo}"),
        None,
        &link(&format!("/ui/mappings/{id}"), "Back to the mapping"),
        None,
    ))
}

async fn mapping_scene(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<DemoQuery>,
) -> Page {
    let index = q.demo.unwrap_or(0);
    let fig = crate::service::figures::mapping(&state, &id, index)
        .await?
        .map_err(|total| {
            crate::service::Error::not_found(
                "mapped demonstration",
                format!("{id}#{index} (of {total})"),
            )
        })?;
    let row = crate::store::mappings::get_mapping(&state.db, &id)
        .await?
        .ok_or_else(|| crate::service::Error::not_found("mapping", &id))?;
    let traj = fig.demo.trajectory;
    let registration = traj.registration;
    let s = Surroundings {
        object: registration.object.as_ref().map(|o| {
            let c = o.pose.translation.vector;
            let r = o.pose.rotation.quaternion();
            ObjectSpec {
                name: fig.demo.object_name.clone(),
                shape: crate::mapping::shape_spec(&o.shape),
                position: [c.x, c.y, c.z],
                orientation: [r.w, r.i, r.j, r.k],
                support: registration.support.map(|h| crate::geometry::SupportPlane {
                    normal: registration.up.into(),
                    offset: h,
                    friction: None,
                }),
                mass: None,
                friction: None,
            }
        }),
        ..Surroundings::default()
    };
    let title = format!(
        "mapping {} on {}: demonstration {index} ({}, position {}, trial {})",
        short(&id),
        row.robot,
        fig.demo.object_name,
        fig.demo.position_index,
        fig.demo.trial
    );
    let track = OwnedTrack {
        joint_names: traj.joint_names,
        times: traj.times,
        positions: traj.positions,
    };
    build(
        title,
        row.robot,
        fig.system,
        Some(track),
        s,
        Some((fig.human, registration)),
    )
    .await
}

/// What an execution is drawn in: the scene of the plan that queued it (whatever its mode),
/// else the surroundings of the stored trajectory it follows; an inline trajectory or a bare
/// model execution has none.
async fn execution_surroundings(
    state: &AppState,
    id: &str,
    payload: &ExecutionPayload,
) -> Result<Surroundings, PageError> {
    if let Some(plan) = plan_repo::of_execution(&state.db, id).await? {
        return plan_surroundings(state, &plan).await;
    }
    if let ExecutionPayload::Trajectory { trajectory_id, .. } = payload
        && let Some(t) = trajectory_repo::get_trajectory(&state.db, trajectory_id).await?
    {
        return trajectory_surroundings(state, &t).await;
    }
    Ok(Surroundings::default())
}

/// What the page says when an execution has nothing around the robot to draw.
pub const NO_SCENE: &str = "no scene: this execution was not made by a plan";

async fn execution_page(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let Some(payload) = crate::store::executions::payload(&state.db, &id).await? else {
        return Ok(html::not_found(
            "execution",
            &id,
            "/ui/executions",
            "executions",
        ));
    };
    let s = execution_surroundings(&state, &id, &payload).await?;
    let note = s.object.is_none().then(|| {
        format!(
            "<b>{NO_SCENE}</b> (it runs {}), so there is no object, support or obstacle to \
             draw: only the robot.",
            match &payload {
                ExecutionPayload::Trajectory { trajectory_id, .. } if trajectory_id == "inline" => {
                    "a trajectory given inline".to_owned()
                }
                ExecutionPayload::Trajectory { trajectory_id, .. } => {
                    format!("trajectory {}", esc(short(trajectory_id)))
                }
                ExecutionPayload::Model { model_id, .. } => {
                    format!("the control law of model {}", esc(short(model_id)))
                }
                ExecutionPayload::Stream { source, .. } => {
                    format!("setpoints streamed live from {}", esc(source))
                }
            }
        )
    });
    Ok(viewer_page(
        &format!("Execution {} in 3-D", short(&id)),
        "/ui/executions",
        &format!("/ui/view/executions/{id}/scene.json"),
        Some(&format!("/v1/executions/{id}/events")),
        &link(&format!("/ui/executions/{id}"), "Back to the execution"),
        note.as_deref(),
    ))
}

/// An execution's scene: its plan's (or trajectory's) surroundings, and as motion the measured
/// history when there is one (what the robot did), else what was sent (what it will do).
async fn execution_scene(State(state): State<AppState>, Path(id): Path<String>) -> Page {
    let (row, payload, history) = crate::service::executions::with_payload(&state, &id).await?;
    let joint_names = payload.joint_names().to_vec();
    let s = execution_surroundings(&state, &id, &payload).await?;
    let track = if history.is_empty() {
        match payload {
            ExecutionPayload::Trajectory { points, .. } if !points.is_empty() => {
                Some(OwnedTrack::of_points(joint_names, &points))
            }
            _ => None,
        }
    } else {
        let samples: Vec<_> = history.samples().collect();
        Some(OwnedTrack {
            joint_names,
            times: samples.iter().map(|x| x.t).collect(),
            positions: samples
                .iter()
                .flat_map(|x| x.positions.iter().copied())
                .collect(),
        })
    };
    let system = state.robots.system(&row.robot).await?;
    let title = format!(
        "execution {} on {} ({}; {})",
        short(&id),
        row.robot,
        row.state.as_str(),
        if history.is_empty() {
            "planned motion"
        } else {
            "measured motion"
        }
    );
    build(title, row.robot, system, track, s, None).await
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseIn {
    joint_names: Vec<String>,
    positions: Vec<f64>,
}

/// Link poses (the scene's link order, 7 values each) of a measured state.
async fn robot_pose(
    State(state): State<AppState>,
    Path(robot): Path<String>,
    Json(body): Json<PoseIn>,
) -> Result<Response, PageError> {
    let system = state.robots.system(&robot).await?;
    let poses =
        tokio::task::spawn_blocking(move || pose_of(&system, &body.joint_names, &body.positions))
            .await
            .map_err(internal)?
            .map_err(|e| PageError(crate::service::Error::invalid("$.positions", e.to_string())))?;
    Ok((StatusCode::OK, Json(serde_json::json!({ "links": poses }))).into_response())
}
