//! `/v1/plans`: one request from object and task to a humanlike motion ending in a
//! task-specific grasp, and optionally its execution (issue 10).
//!
//! A plan runs synchronously: the grasp optimisation (tens of milliseconds for the bundled
//! systems) and one trajectory from the model (about a millisecond) fit well inside a request,
//! and a client gets its answer without polling a job. Order of work, so that bad input stores
//! nothing: the model and the start are checked first, then the grasp is computed, then the
//! trajectory to it; nothing is stored until then. The grasp, trajectory, execution (when
//! asked) and plan rows are then written in one transaction ([`crate::service::plans`]). An
//! infeasible grasp, or one outside the model's certified goal region, is not bad input: the
//! plan is stored with `feasible: false`, the reason, the grasp, and no trajectory. A motion
//! that is not collision-free (exact, continuous check in the grasp's scene) makes the plan
//! `feasible: false` too, the reason naming the link, what it meets, when and how deep; that
//! trajectory is kept with the plan for inspection and never queued.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::grasps::{GraspDto, grasp_dto};
use super::models::{TrajectoryDto, trajectory_dto};
use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem};
use crate::service;
pub use crate::service::plans::{PlanIn, PlanTimings, StartIn, Verification};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_plan, list_plans))
        .routes(routes!(get_plan, delete_plan))
}

/// A stored plan with its grasp and trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct PlanDto {
    pub id: String,
    pub robot: String,
    /// The model the trajectory came from.
    pub model_id: Option<String>,
    /// A feasible grasp was found and a collision-free trajectory to it generated.
    pub feasible: bool,
    /// Why not, when `feasible` is false.
    pub reason: Option<String>,
    pub grasp: GraspDto,
    /// The motion to the grasp; on an infeasible plan, present only when it was generated and
    /// collides (kept for inspection, never executed).
    pub trajectory: Option<TrajectoryDto>,
    /// The queued execution (`GET /v1/executions/{id}`), when `execute` or `verify` was asked.
    pub execution_id: Option<String>,
    /// The physics check, when `verify` was asked: its execution's state and, once the physics
    /// worker reported, the grasp trial's verdict.
    pub verification: Option<Verification>,
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

impl Listed for PlanSummaryDto {
    const PAGE: &'static str = "PlanList";
}

pub type PlanList = Page<PlanSummaryDto>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct PlanQuery {
    /// Only plans of this robot.
    pub robot: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Plans to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

/// The answer to a plan, as `POST /v1/plans` and `reachgrasp plan` print it.
pub fn plan_dto(p: service::plans::Planned) -> Result<PlanDto, ApiError> {
    let service::plans::Planned {
        stored,
        reason,
        timings,
    } = p;
    Ok(PlanDto {
        id: stored.plan.id,
        robot: stored.plan.robot,
        model_id: stored.plan.model_id,
        feasible: stored.plan.feasible,
        reason,
        grasp: grasp_dto(stored.grasp)?,
        trajectory: stored.trajectory.map(trajectory_dto).transpose()?,
        execution_id: stored.execution_id,
        verification: stored.verification,
        timings,
        created_at: stored.plan.created_at,
    })
}

/// Plan a humanlike motion to a task-specific grasp of an object, and optionally execute it
/// (201). Synchronous: grasp optimisation, then a certified trajectory from the model (the
/// robot's default model unless one is named). An unreachable object, or a motion to the grasp
/// that collides, is a stored plan with `feasible: false` and the reason; a default model still
/// being trained by first-start seeding is 503 `not-ready` with the job to watch.
#[utoipa::path(post, path = "/v1/plans", tag = "plans", request_body = PlanIn,
    responses((status = 201, description = "Created", body = PlanDto),
              (status = 409, description = "Conflict with the stored state", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json"),
              (status = 503, description = "Not ready yet (problem+json with the job to watch)", body = Problem, content_type = "application/problem+json")))]
async fn create_plan(
    State(state): State<AppState>,
    Json(body): Json<PlanIn>,
) -> Result<Response, ApiError> {
    let dto = plan_dto(service::plans::plan(&state, &body).await?)?;
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
    let stored = service::plans::get(&state, &id).await?;
    let timings = serde_json::from_str(&stored.plan.timings).map_err(ApiError::internal)?;
    let reason = stored.plan.reason.clone();
    Ok(Json(plan_dto(service::plans::Planned {
        stored,
        reason,
        timings,
    })?))
}

/// Delete a plan with what it owns: its grasp, its trajectory and its execution (with the
/// execution's feedback). Refused (409) while the execution is queued or running.
#[utoipa::path(delete, path = "/v1/plans/{id}", tag = "plans",
    params(("id" = String, Path, description = "Plan id")),
    responses((status = 204, description = "Deleted, with its grasp, trajectory and execution"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json"),
              (status = 409, description = "Its execution is queued or running", body = Problem, content_type = "application/problem+json")))]
async fn delete_plan(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service::storage::delete_plan(&state, &id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// List plans, newest first.
#[utoipa::path(get, path = "/v1/plans", tag = "plans", params(PlanQuery),
    responses((status = 200, description = "OK", body = PlanList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_plans(
    State(state): State<AppState>,
    Listing(q, page): Listing<PlanQuery>,
) -> Result<Json<PlanList>, ApiError> {
    let (rows, total) =
        service::plans::list(&state, q.robot.as_deref(), page.limit, page.offset).await?;
    let items = rows
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
        .collect();
    Ok(Json(page.of(items, Some(total))))
}
