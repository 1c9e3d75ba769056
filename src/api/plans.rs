//! `/v1/plans`: one request from object and task to a humanlike motion ending in a
//! task-specific grasp, and optionally its execution (issue 10).
//!
//! A plan runs synchronously: the grasp optimisation (tens of milliseconds for the bundled
//! systems) and one trajectory from the model (about a millisecond) fit well inside a request,
//! and a client gets its answer without polling a job. Order of work, so that bad input stores
//! nothing: the model and the start are checked first, then the grasp is computed, then the
//! trajectory to it; nothing is stored until then. The grasp, trajectory, execution (when
//! asked) and plan rows are then written in one transaction ([`crate::service::plans`]). An infeasible grasp, or one outside the
//! model's certified goal region, is not bad input: the plan is stored with `feasible: false`,
//! the reason, the grasp, and no trajectory.

use std::time::Instant;

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::grasps::{GraspDto, GraspIn, compute_grasp, grasp_dto};
use super::models::{
    AutoOr, CreateTrajectory, GoalIn, JointValues, Rejected, TrajectoryDto, check_start,
    compute_trajectory, trajectory_dto,
};
use super::{ApiError, AppState, Json, Path, Problem, Query};
use crate::bridge::{Mode, WorkerName};
use crate::service;
use crate::store::{grasps as grasp_repo, models as model_repo, plans as repo, trajectories};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_plan, list_plans))
        .routes(routes!(get_plan))
}

/// Where the trajectory starts.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum StartIn {
    /// A configuration: every independent joint of the robot once, any order.
    Configuration(JointValues),
    /// `"current"`: the measured state of the connected worker for the robot (the one named by
    /// `worker`, if given), as its last heartbeat or feedback reported it.
    Current(String),
}

/// Object and task in, humanlike motion to a task-specific grasp out.
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct PlanIn {
    /// Robot, object (`object_id` or inline `object`), task directions, quality measure and the
    /// grasp optimiser's settings: the body of `POST /v1/grasps`.
    #[serde(flatten)]
    pub grasp: GraspIn,
    /// Start of the motion: a configuration, or `"current"` (the connected worker's state).
    pub start: StartIn,
    /// Motion model id (default: the robot's default model).
    pub model: Option<String>,
    /// `"auto"` (learned from the demonstrations, default) or seconds.
    pub duration: Option<AutoOr>,
    /// Trajectory output rate, Hz (default 100).
    pub rate: Option<f64>,
    /// Queue the motion for execution on a bridge worker.
    #[serde(default)]
    pub execute: bool,
    /// Execution mode (default `open_loop`: follow the trajectory; `closed_loop`: the worker
    /// runs the model's control law to the grasp configuration).
    pub mode: Option<Mode>,
    /// Worker to execute on (default: any idle worker of the robot); also the worker whose
    /// state `"current"` reads.
    pub worker: Option<String>,
}

/// How long each step took (s).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlanTimings {
    pub grasp_s: f64,
    pub trajectory_s: f64,
    pub total_s: f64,
}

/// A stored plan with its grasp and trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlanDto {
    pub id: String,
    pub robot: String,
    /// The model the trajectory came from.
    pub model_id: Option<String>,
    /// A feasible grasp was found and a trajectory to it generated.
    pub feasible: bool,
    /// Why not, when `feasible` is false.
    pub reason: Option<String>,
    pub grasp: GraspDto,
    pub trajectory: Option<TrajectoryDto>,
    /// The queued execution (`GET /v1/executions/{id}`), when `execute` was asked.
    pub execution_id: Option<String>,
    pub timings: PlanTimings,
    pub created_at: String,
}

/// A plan in a listing (ids only).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlanSummaryDto {
    pub id: String,
    pub robot: String,
    pub model_id: Option<String>,
    pub feasible: bool,
    pub reason: Option<String>,
    pub grasp_id: String,
    pub trajectory_id: Option<String>,
    pub execution_id: Option<String>,
    pub created_at: String,
}

#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct PlanList {
    pub items: Vec<PlanSummaryDto>,
    pub total: i64,
    pub limit: u32,
    pub offset: u32,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PlanQuery {
    /// Only plans of this robot.
    pub robot: Option<String>,
    /// Page size, 1 to 500 (default 50).
    pub limit: Option<u32>,
    /// Plans to skip (default 0).
    pub offset: Option<u32>,
}

/// The model to plan with: the named one, or the robot's default. While first-start seeding
/// is still training the default, 503 `not-ready` names the job to watch.
async fn resolve_model(state: &AppState, body: &PlanIn) -> Result<String, ApiError> {
    if let Some(m) = &body.model {
        return Ok(m.clone());
    }
    let robot = &body.grasp.robot;
    if let Some(row) = model_repo::default_model_for(&state.db, robot).await? {
        return Ok(row.id);
    }
    if let Some(job) = state.seed.pending_job(robot) {
        return Err(ApiError::not_ready(
            format!(
                "the default model of '{robot}' is still being prepared by first-start seeding; \
                 retry when job {job} has finished (GET /v1/jobs/{job})"
            ),
            job,
        ));
    }
    Err(ApiError::invalid_field(
        "$.model",
        format!(
            "robot '{robot}' has no trained model; train one (POST /v1/models) or name one here"
        ),
    ))
}

/// The start configuration; `"current"` reads the connected worker's last measured state.
fn resolve_start(state: &AppState, body: &PlanIn) -> Result<JointValues, ApiError> {
    match &body.start {
        StartIn::Configuration(v) => Ok(v.clone()),
        StartIn::Current(s) if s == "current" => {
            let robot = &body.grasp.robot;
            let worker = state
                .bridges
                .workers()
                .into_iter()
                .filter(|w| w.robot == *robot && !w.positions.is_empty())
                .find(|w| body.worker.as_ref().is_none_or(|n| *n == w.name))
                .ok_or_else(|| {
                    ApiError::invalid_field(
                        "$.start",
                        match &body.worker {
                            Some(n) => format!(
                                "\"current\" needs worker '{n}' connected for robot '{robot}' and reporting its state"
                            ),
                            None => format!(
                                "\"current\" needs a worker connected for robot '{robot}' and reporting its state; give a configuration instead"
                            ),
                        },
                    )
                })?;
            Ok(JointValues {
                joint_names: worker.joint_names,
                positions: worker.positions,
            })
        }
        StartIn::Current(other) => Err(ApiError::invalid_field(
            "$.start",
            format!(
                "must be a configuration {{joint_names, positions}} or \"current\", got \"{other}\""
            ),
        )),
    }
}

/// Plans (and optionally queues) one grasping motion; the work of `POST /v1/plans` and
/// `reachgrasp plan`. Everything is computed first; the rows are then stored as one unit of
/// work ([`service::plans::store`]).
pub async fn plan(state: &AppState, body: &PlanIn) -> Result<PlanDto, ApiError> {
    let t0 = Instant::now();
    let robot = body.grasp.robot.clone();
    let worker = body.worker.as_deref().map(WorkerName::parse).transpose()?;
    super::robots::robot_field(state, &robot, "$.robot").await?;
    let model_id = resolve_model(state, body).await?;
    let start = resolve_start(state, body)?;
    let model_robot = check_start(state, &model_id, &start).await?;
    if model_robot != robot {
        return Err(ApiError::invalid_field(
            "$.model",
            format!("model '{model_id}' is of robot '{model_robot}', not '{robot}'"),
        ));
    }

    // A plan's grasp must land in the model's certified goal regions: the search starts at
    // their centre (the arm branch and hand posture the demonstrations end on) and keeps inside.
    let regions = super::models::goal_regions(state, &model_id).await?;
    let (new_grasp, result) = compute_grasp(state, &body.grasp, &regions).await?;
    let grasp_s = t0.elapsed().as_secs_f64();
    let mut reason = (!result.feasible).then(|| {
        format!(
            "no feasible grasp: {}",
            result.reason.as_deref().unwrap_or("no reason given")
        )
    });
    let mut trajectory = None;
    if reason.is_none() {
        let (joint_names, positions) = result
            .q_arm
            .iter()
            .chain(&result.q_hand)
            .map(|j| (j.name.clone(), j.value))
            .unzip();
        let request = CreateTrajectory {
            model: model_id.clone(),
            start: start.clone(),
            goal: GoalIn {
                joint_names: Some(joint_names),
                positions: Some(positions),
                grasp: None,
            },
            duration: body.duration.clone(),
            rate: body.rate,
        };
        match compute_trajectory(state, &request).await {
            Ok(t) => trajectory = Some(t),
            // The grasp is the goal: a goal the model cannot certify (outside its goal region
            // or its joint limits) makes the plan infeasible, not the request bad.
            Err(Rejected::Goal(e)) => {
                let why: Vec<&str> = e.errors().iter().map(|f| f.message.as_str()).collect();
                reason = Some(format!(
                    "the grasp is no goal the model can reach with its convergence guarantee: {}",
                    why.join("; ")
                ));
            }
            Err(Rejected::Other(e)) => return Err(e),
        }
    }
    let trajectory_s = t0.elapsed().as_secs_f64() - grasp_s;

    let execution = match (body.execute, &trajectory) {
        (true, Some(_)) => {
            let mode = body.mode.unwrap_or(Mode::OpenLoop);
            let law = match mode {
                Mode::OpenLoop => None,
                Mode::ClosedLoop => Some((
                    model_id.clone(),
                    model_repo::load_params(&state.db, &model_id)
                        .await?
                        .ok_or_else(|| {
                            ApiError::internal(anyhow::anyhow!(
                                "model {model_id} has no parameters"
                            ))
                        })?,
                )),
            };
            Some(service::plans::ExecutionRequest { mode, worker, law })
        }
        _ => None,
    };
    let timings = PlanTimings {
        grasp_s,
        trajectory_s,
        total_s: t0.elapsed().as_secs_f64(),
    };
    let rows = service::plans::PlanRows {
        grasp: new_grasp,
        trajectory,
        execution,
        plan: repo::NewPlan {
            robot: robot.clone(),
            model_id: Some(model_id.clone()),
            grasp_id: String::new(),
            trajectory_id: None,
            execution_id: None,
            feasible: reason.is_none(),
            reason: reason.clone(),
            request: request_json(body)?,
            timings: serde_json::to_string(&timings).map_err(ApiError::internal)?,
        },
    };
    let stored = service::plans::store(state, rows).await?;
    Ok(PlanDto {
        id: stored.plan.id,
        robot,
        model_id: Some(model_id),
        feasible: stored.plan.feasible,
        reason,
        grasp: grasp_dto(stored.grasp)?,
        trajectory: stored.trajectory.map(trajectory_dto).transpose()?,
        execution_id: stored.execution_id,
        timings,
        created_at: stored.plan.created_at,
    })
}

/// The request as stored with the plan (what was asked, including the resolved start).
fn request_json(body: &PlanIn) -> Result<String, ApiError> {
    let value = serde_json::json!({
        "robot": body.grasp.robot,
        "object_id": body.grasp.object_id,
        "inline_object": body.grasp.object.is_some(),
        "start": body.start,
        "model": body.model,
        "duration": body.duration,
        "rate": body.rate,
        "execute": body.execute,
        "mode": body.mode,
        "worker": body.worker,
    });
    serde_json::to_string(&value).map_err(ApiError::internal)
}

/// Plan a humanlike motion to a task-specific grasp of an object, and optionally execute it
/// (201). Synchronous: grasp optimisation, then a certified trajectory from the model (the
/// robot's default model unless one is named). An unreachable object is a stored plan with
/// `feasible: false` and the reason; a default model still being trained by first-start
/// seeding is 503 `not-ready` with the job to watch.
#[utoipa::path(post, path = "/v1/plans", tag = "plans", request_body = PlanIn,
    responses((status = 201, description = "Created", body = PlanDto),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json"),
              (status = 503, description = "Not ready yet (problem+json with the job to watch)", body = Problem, content_type = "application/problem+json")))]
async fn create_plan(
    State(state): State<AppState>,
    Json(body): Json<PlanIn>,
) -> Result<Response, ApiError> {
    let dto = plan(&state, &body).await?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/plans/{}", dto.id),
        dto,
    ))
}

/// One plan with its grasp and trajectory.
#[utoipa::path(get, path = "/v1/plans/{id}", tag = "plans",
    params(("id" = String, Path, description = "Plan id")),
    responses((status = 200, description = "OK", body = PlanDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_plan(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<PlanDto>, ApiError> {
    let row = repo::get(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("plan", &id))?;
    let grasp = grasp_repo::get_grasp(&state.db, &row.grasp_id)
        .await?
        .ok_or_else(|| {
            ApiError::conflict(format!(
                "the plan's grasp {} no longer exists",
                row.grasp_id
            ))
        })?;
    let trajectory = match &row.trajectory_id {
        Some(t) => Some(trajectory_dto(
            trajectories::get_trajectory(&state.db, t)
                .await?
                .ok_or_else(|| {
                    ApiError::conflict(format!("the plan's trajectory {t} no longer exists"))
                })?,
        )?),
        None => None,
    };
    Ok(Json(PlanDto {
        id: row.id,
        robot: row.robot,
        model_id: row.model_id,
        feasible: row.feasible,
        reason: row.reason,
        grasp: grasp_dto(grasp)?,
        trajectory,
        execution_id: row.execution_id,
        timings: serde_json::from_str(&row.timings).map_err(ApiError::internal)?,
        created_at: row.created_at,
    }))
}

/// List plans, newest first.
#[utoipa::path(get, path = "/v1/plans", tag = "plans", params(PlanQuery),
    responses((status = 200, description = "OK", body = PlanList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_plans(
    State(state): State<AppState>,
    Query(q): Query<PlanQuery>,
) -> Result<Json<PlanList>, ApiError> {
    let limit = super::extract::page_limit(q.limit)?;
    let offset = q.offset.unwrap_or(0);
    let (rows, total) =
        repo::list(&state.db, q.robot.as_deref(), limit.into(), offset.into()).await?;
    Ok(Json(PlanList {
        items: rows
            .into_iter()
            .map(|r| PlanSummaryDto {
                id: r.id,
                robot: r.robot,
                model_id: r.model_id,
                feasible: r.feasible,
                reason: r.reason,
                grasp_id: r.grasp_id,
                trajectory_id: r.trajectory_id,
                execution_id: r.execution_id,
                created_at: r.created_at,
            })
            .collect(),
        total,
        limit,
        offset,
    }))
}
