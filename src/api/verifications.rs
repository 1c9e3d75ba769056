//! `/v1/verifications`: physics verification of many plans at once (issue 24 §3) — robots ×
//! objects × placements × task sets, each planned with `verify: true` and run on the robot's
//! physics worker, as a job; the result tabulates the grasp trials per system and object.

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use serde::Deserialize;
use utoipa::IntoParams;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem};
use crate::jobs::JobRecord;
use crate::service::verifications as service;
pub use crate::service::verifications::{VerificationIn, VerificationReport, VerificationSummary};

impl Listed for VerificationSummary {
    const PAGE: &'static str = "VerificationList";
}

pub type VerificationList = Page<VerificationSummary>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct VerificationQuery {
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Verifications to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

/// List verifications, newest first (what each asked; `GET /v1/verifications/{id}` has the
/// verdicts).
#[utoipa::path(get, path = "/v1/verifications", tag = "plans", params(VerificationQuery),
    responses((status = 200, description = "OK", body = VerificationList),
              (status = 400, description = "Bad query parameters (problem+json naming the parameter)", body = Problem, content_type = "application/problem+json")))]
async fn list_verifications(
    State(state): State<AppState>,
    Listing(_query, page): Listing<VerificationQuery>,
) -> Result<Json<VerificationList>, ApiError> {
    let (items, total) = service::list(&state, page.limit, page.offset).await?;
    Ok(Json(page.of(items, Some(total))))
}

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_verification, list_verifications))
        .routes(routes!(get_verification, delete_verification))
}

/// Verify many plans in physics (202, a job). Every combination of robot, object, placement
/// and task set is planned with `verify: true`, one robot's after another's end (the robots
/// side by side), and waits for its physics worker's trial; progress counts the finished
/// combinations (`GET /v1/jobs/{id}/events`). Each robot needs a connected worker with the
/// `grasp_trial` capability (409 otherwise), each object a `mass` and a `friction`. The job
/// takes no `--job-concurrency` slot (it waits for the workers; its plans are computed in turn
/// with the requests' at `--request-concurrency`).
#[utoipa::path(post, path = "/v1/verifications", tag = "plans", request_body = VerificationIn,
    responses((status = 202, description = "Accepted: the job, to follow at its Location", body = JobRecord),
              (status = 409, description = "A robot has no connected worker with the grasp_trial capability", body = Problem, content_type = "application/problem+json"),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_verification(
    State(state): State<AppState>,
    Json(body): Json<VerificationIn>,
) -> Result<Response, ApiError> {
    let job = service::submit(&state, &body).await?;
    Ok(super::accepted_job(job, None))
}

/// A verification: every combination with its plan and the trial's verdict as it stands, and
/// the counts per system and object (plans, feasible, held, not verified yet).
#[utoipa::path(get, path = "/v1/verifications/{id}", tag = "plans",
    params(("id" = String, Path, description = "Verification id (the job's result)")),
    responses((status = 200, description = "OK", body = VerificationReport),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_verification(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<VerificationReport>, ApiError> {
    Ok(Json(service::get(&state, &id).await?))
}

/// Delete a verification's report. Its plans (and their grasps, trajectories and executions)
/// stay: each is a plan of its own, deleted with `DELETE /v1/plans/{id}`.
#[utoipa::path(delete, path = "/v1/verifications/{id}", tag = "plans",
    params(("id" = String, Path, description = "Verification id")),
    responses((status = 204, description = "Deleted (its plans stay)"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn delete_verification(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service::delete(&state, &id).await?;
    Ok(StatusCode::NO_CONTENT)
}
