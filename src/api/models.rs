//! `/v1/models` (PCA + navigation-function motion models learned from stored mappings, paper
//! eq. 8-9; training is a job) and `/v1/trajectories` (humanlike trajectories generated from a
//! model, stored).
//!
//! Joint vectors travel as `{joint_names, positions}` (any order, every independent joint of the
//! robot once), as in `/v1/robots`; answers use the model's joint order and name it. A start or
//! goal the model cannot certify (outside the workspace or the goal region) is refused with 422:
//! no plan is made without the convergence guarantee.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem};
use crate::jobs::JobRecord;
use crate::motion::ControlParams;
use crate::service;
pub use crate::service::models::{
    AutoOr, CertificateDto, ControlGains, ControlRequest, CreateModel, DurationDto, FoldDto,
    GoalRegionDto, HeldOutDto, HeldOutSummaryDto, JointValues, MAX_DURATION, MAX_RATE,
    MAX_SPLINE_INTERVALS, ManifoldDto, ModelReportDto, held_out_folds,
};
use crate::service::trajectories::StoredTrajectory;
pub use crate::service::trajectories::{
    CreateTrajectory, FramePathDto, GoalIn, GroupErrorDto, TrajectoryReportDto,
};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_models, create_model))
        .routes(routes!(get_model))
        .routes(routes!(get_params))
        .routes(routes!(control))
        .routes(routes!(list_trajectories, create_trajectory))
        .routes(routes!(get_trajectory, delete_trajectory))
}

/// A model: its training request, status (the job's) and, once trained, its report.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelDto {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    /// `queued|running|succeeded|failed|cancelled` (the training job's).
    pub status: String,
    /// Explicitly marked as the robot's default.
    pub default: bool,
    /// The model's joint order.
    pub joint_names: Vec<String>,
    /// The training request as given (stored as the server read it, defaults not filled in).
    #[schema(value_type = CreateModel)]
    pub request: serde_json::Value,
    pub report: Option<ModelReportDto>,
    pub created_at: String,
}

impl Listed for ModelDto {
    const PAGE: &'static str = "ModelList";
}

pub type ModelList = Page<ModelDto>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ModelQuery {
    /// Only models of this robot.
    pub robot: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Models to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ControlResponse {
    /// Order of `u`: the model's joints.
    pub joint_names: Vec<String>,
    /// Joint velocity command, rad/s.
    pub u: Vec<f64>,
}

/// A timed point (model joint order).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PointDto {
    pub t: f64,
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
}

/// A stored trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryDto {
    pub id: String,
    pub model_id: Option<String>,
    pub robot: String,
    /// Order of every vector of `start`, `goal` and `points`.
    pub joint_names: Vec<String>,
    pub start: Vec<f64>,
    pub goal: Vec<f64>,
    pub points: Vec<PointDto>,
    pub report: TrajectoryReportDto,
    pub created_at: String,
}

/// A trajectory in a listing (no points).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectorySummaryDto {
    pub id: String,
    pub model_id: Option<String>,
    pub robot: String,
    pub duration: f64,
    pub converged: bool,
    pub stretched: bool,
    pub created_at: String,
}

impl Listed for TrajectorySummaryDto {
    const PAGE: &'static str = "TrajectoryList";
}

pub type TrajectoryList = Page<TrajectorySummaryDto>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct TrajectoryQuery {
    /// Only trajectories of this model.
    pub model: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Trajectories to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

fn model_dto(m: service::models::StoredModel) -> ModelDto {
    ModelDto {
        id: m.id,
        job_id: m.job_id,
        robot: m.robot,
        status: m.status,
        default: m.default,
        joint_names: m.joint_names,
        request: m.request,
        report: m.report,
        created_at: m.created_at,
    }
}

/// Train a motion model (PCA + navigation function per joint group) from stored mappings, as a
/// job (202). The model is listed at once with the job's status; the job's result points at it.
#[utoipa::path(post, path = "/v1/models", tag = "models", request_body = CreateModel,
    responses((status = 202, body = JobRecord, description = "Training job; `Content-Location` is the model"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_model(
    State(state): State<AppState>,
    Json(body): Json<CreateModel>,
) -> Result<Response, ApiError> {
    let (job, model_id) = service::models::train_model(&state, &body).await?;
    Ok(super::accepted_job(
        job,
        Some(format!("/v1/models/{model_id}")),
    ))
}

/// List models, newest first (pending and failed ones included, with their job's status).
#[utoipa::path(get, path = "/v1/models", tag = "models", params(ModelQuery),
    responses((status = 200, description = "OK", body = ModelList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_models(
    State(state): State<AppState>,
    Listing(q, page): Listing<ModelQuery>,
) -> Result<Json<ModelList>, ApiError> {
    let (rows, total) =
        service::models::list(&state, q.robot.as_deref(), page.limit, page.offset).await?;
    let items = rows.into_iter().map(model_dto).collect();
    Ok(Json(page.of(items, Some(total))))
}

/// One model: status, explained variance, training and held-out fit, certificates, goal regions.
#[utoipa::path(get, path = "/v1/models/{id}", tag = "models",
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, description = "OK", body = ModelDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_model(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ModelDto>, ApiError> {
    Ok(Json(model_dto(service::models::get(&state, &id).await?)))
}

/// The closed-loop law's parameters in the compact form a bridge worker runs locally (joint
/// names, `K_⊥`, per group: joint indices, PCA mean and basis, navigation function, `K_p`).
#[utoipa::path(get, path = "/v1/models/{id}/params", tag = "models",
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, body = ControlParams, description = "The model's closed-loop law (`motion::ControlParams`)"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, body = Problem, content_type = "application/problem+json", description = "Not trained (yet)")))]
async fn get_params(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ControlParams>, ApiError> {
    Ok(Json(service::models::params(&state, &id).await?))
}

/// Evaluate the closed-loop law `u(q)` for a measured state and a goal.
#[utoipa::path(post, path = "/v1/models/{id}/control", tag = "models", request_body = ControlRequest,
    params(("id" = String, Path, description = "Model id")),
    responses((status = 200, description = "OK", body = ControlResponse),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn control(
    State(state): State<AppState>,
    Path(id): Path<String>,
    Json(body): Json<ControlRequest>,
) -> Result<Json<ControlResponse>, ApiError> {
    let (joint_names, u) = service::models::control(&state, &id, &body).await?;
    Ok(Json(ControlResponse { joint_names, u }))
}

pub fn trajectory_dto(t: StoredTrajectory) -> Result<TrajectoryDto, ApiError> {
    Ok(TrajectoryDto {
        report: serde_json::from_str(&t.summary).map_err(ApiError::internal)?,
        id: t.id,
        model_id: t.model_id,
        robot: t.robot,
        joint_names: t.joint_names,
        start: t.start,
        goal: t.goal,
        points: t
            .points
            .into_iter()
            .map(|p| PointDto {
                t: p.t,
                positions: p.positions,
                velocities: p.velocities,
                accelerations: p.accelerations,
            })
            .collect(),
        created_at: t.created_at,
    })
}

/// Generate a humanlike trajectory from `start` to `goal` with a model and store it (201): flow
/// integration per manifold, back-projection keeping the exact start and goal, minimum-jerk
/// timing over the learned (or requested) duration, stretched where a joint limit would be
/// exceeded; fingertip and elbow paths by forward kinematics.
#[utoipa::path(post, path = "/v1/trajectories", tag = "trajectories", request_body = CreateTrajectory,
    responses((status = 201, description = "Created", body = TrajectoryDto),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_trajectory(
    State(state): State<AppState>,
    Json(body): Json<CreateTrajectory>,
) -> Result<Response, ApiError> {
    let dto = trajectory_dto(service::trajectories::create(&state, &body).await?)?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/trajectories/{}", dto.id),
        dto,
    ))
}

/// One stored trajectory with its points and report.
#[utoipa::path(get, path = "/v1/trajectories/{id}", tag = "trajectories",
    params(("id" = String, Path, description = "Trajectory id")),
    responses((status = 200, description = "OK", body = TrajectoryDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_trajectory(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<TrajectoryDto>, ApiError> {
    let t = service::trajectories::get(&state, &id).await?;
    Ok(Json(trajectory_dto(t)?))
}

/// Delete a trajectory. Refused (409) while a plan owns it (delete the plan) or an execution
/// of it is queued or running; finished executions keep their own copy of the points.
#[utoipa::path(delete, path = "/v1/trajectories/{id}", tag = "trajectories",
    params(("id" = String, Path, description = "Trajectory id")),
    responses((status = 204, description = "Deleted"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, description = "Owned by a plan or used by an unfinished execution", body = Problem, content_type = "application/problem+json")))]
async fn delete_trajectory(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service::storage::delete_trajectory(&state, &id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// List stored trajectories, newest first (without points).
#[utoipa::path(get, path = "/v1/trajectories", tag = "trajectories", params(TrajectoryQuery),
    responses((status = 200, description = "OK", body = TrajectoryList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_trajectories(
    State(state): State<AppState>,
    Listing(q, page): Listing<TrajectoryQuery>,
) -> Result<Json<TrajectoryList>, ApiError> {
    let (rows, total) =
        service::trajectories::list(&state, q.model.as_deref(), page.limit, page.offset).await?;
    let mut items = Vec::with_capacity(rows.len());
    for r in rows {
        let s: TrajectoryReportDto =
            serde_json::from_str(&r.summary).map_err(ApiError::internal)?;
        items.push(TrajectorySummaryDto {
            id: r.id,
            model_id: r.model_id,
            robot: r.robot,
            duration: r.duration,
            converged: s.converged,
            stretched: s.stretched,
            created_at: r.created_at,
        });
    }
    Ok(Json(page.of(items, Some(total))))
}
