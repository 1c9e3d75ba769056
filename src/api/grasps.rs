//! `/v1/objects` (graspable objects, seeded with everyday objects) and `/v1/grasps`
//! (task-specific grasps, paper eq. 10-29; batches as jobs).

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiError, AppState, Json, Path, Problem};
use crate::grasp::GraspResult;
use crate::grasp::objects::ObjectSpec;
use crate::jobs::JobRecord;
use crate::service::grasps as service;
pub use crate::service::grasps::{
    BatchItemIn, GraspBatchIn, GraspIn, GraspSettings as GraspSettingsDto, MAX_BATCH, MeshIn,
    ObjectIn, TaskDirectionIn,
};
use crate::service::{GraspRow, ObjectRow};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_objects, create_object))
        .routes(routes!(get_object, delete_object))
        .routes(routes!(create_grasp))
        .routes(routes!(get_grasp))
        .routes(routes!(create_batch))
        .routes(routes!(get_batch))
}

// ---------------------------------------------------------------------------------------------
// DTOs

/// A stored object.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ObjectDto {
    pub id: String,
    pub name: String,
    /// True for the everyday objects present from the start.
    pub seeded: bool,
    pub spec: ObjectSpec,
    pub created_at: String,
}

/// A stored grasp.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GraspDto {
    pub id: String,
    pub robot: String,
    pub object_id: Option<String>,
    /// The object as used.
    pub object: ObjectSpec,
    /// The task settings as used.
    pub request: GraspSettingsDto,
    pub result: GraspResult,
    pub batch_id: Option<String>,
    pub created_at: String,
}

/// A finished batch.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct GraspBatchDto {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    pub count: i64,
    pub feasible: i64,
    /// Grasp ids in item order (`GET /v1/grasps/{id}`).
    pub grasps: Vec<String>,
    pub created_at: String,
}

// ---------------------------------------------------------------------------------------------
// Rendering

fn object_dto(row: ObjectRow) -> Result<ObjectDto, ApiError> {
    let spec: ObjectSpec = serde_json::from_str(&row.spec).map_err(ApiError::internal)?;
    Ok(ObjectDto {
        id: row.id,
        name: row.name,
        seeded: row.seeded,
        spec,
        created_at: row.created_at,
    })
}

pub(crate) fn grasp_dto(row: GraspRow) -> Result<GraspDto, ApiError> {
    Ok(GraspDto {
        id: row.id,
        robot: row.robot,
        object_id: row.object_id,
        object: serde_json::from_str(&row.object).map_err(ApiError::internal)?,
        request: serde_json::from_str(&row.request).map_err(ApiError::internal)?,
        result: GraspResult::from_stored(&row.result).map_err(ApiError::internal)?,
        batch_id: row.batch_id,
        created_at: row.created_at,
    })
}

// ---------------------------------------------------------------------------------------------
// Handlers

/// List objects (the seeded everyday objects first).
#[utoipa::path(get, path = "/v1/objects", tag = "grasps",
    responses((status = 200, description = "OK", body = Vec<ObjectDto>)))]
async fn list_objects(State(state): State<AppState>) -> Result<Json<Vec<ObjectDto>>, ApiError> {
    let rows = service::objects(&state).await?;
    Ok(Json(
        rows.into_iter().map(object_dto).collect::<Result<_, _>>()?,
    ))
}

/// Register an object: a primitive (sphere, cylinder, box, capsule) or a closed triangle mesh.
#[utoipa::path(post, path = "/v1/objects", tag = "grasps", request_body = ObjectIn,
    responses((status = 201, description = "Created", body = ObjectDto),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_object(
    State(state): State<AppState>,
    Json(body): Json<ObjectIn>,
) -> Result<Response, ApiError> {
    let dto = object_dto(service::create_object(&state, body).await?)?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/objects/{}", dto.id),
        dto,
    ))
}

/// One object.
#[utoipa::path(get, path = "/v1/objects/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Object id")),
    responses((status = 200, description = "OK", body = ObjectDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_object(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<ObjectDto>, ApiError> {
    Ok(Json(object_dto(service::object(&state, &id).await?)?))
}

/// Delete an object (grasps computed for it keep their own copy).
#[utoipa::path(delete, path = "/v1/objects/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Object id")),
    responses((status = 204, description = "Deleted"),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn delete_object(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    service::delete_object(&state, &id).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Compute a task-specific arm configuration and robust grasp (eq. 22-29) and store it. An
/// infeasible request (object out of reach, too large) is a stored result with
/// `feasible: false` and a reason.
#[utoipa::path(post, path = "/v1/grasps", tag = "grasps", request_body = GraspIn,
    responses((status = 201, description = "Created", body = GraspDto),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_grasp(
    State(state): State<AppState>,
    Json(body): Json<GraspIn>,
) -> Result<Response, ApiError> {
    let out = grasp_dto(service::create(&state, &body).await?)?;
    Ok(super::created(
        StatusCode::CREATED,
        format!("/v1/grasps/{}", out.id),
        out,
    ))
}

/// One stored grasp.
#[utoipa::path(get, path = "/v1/grasps/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Grasp id")),
    responses((status = 200, description = "OK", body = GraspDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_grasp(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<GraspDto>, ApiError> {
    let row = service::get(&state, &id).await?;
    Ok(Json(grasp_dto(row)?))
}

/// Compute many grasps (objects or placements) as a job; the result is a batch
/// (`GET /v1/grasps/batches/{id}`).
#[utoipa::path(post, path = "/v1/grasps/batch", tag = "grasps", request_body = GraspBatchIn,
    responses((status = 202, description = "Accepted: the job, to follow at its Location", body = JobRecord),
              (status = 422, description = "Invalid request (problem+json naming the field)", body = Problem, content_type = "application/problem+json")))]
async fn create_batch(
    State(state): State<AppState>,
    Json(body): Json<GraspBatchIn>,
) -> Result<Response, ApiError> {
    let job = service::submit_batch(&state, &body).await?;
    Ok(super::accepted_job(job, None))
}

/// A finished batch: counts and grasp ids in item order.
#[utoipa::path(get, path = "/v1/grasps/batches/{id}", tag = "grasps",
    params(("id" = String, Path, description = "Batch id")),
    responses((status = 200, description = "OK", body = GraspBatchDto),
              (status = 404, description = "No such resource", body = Problem, content_type = "application/problem+json")))]
async fn get_batch(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Json<GraspBatchDto>, ApiError> {
    let (b, grasps) = service::batch(&state, &id).await?;
    Ok(Json(GraspBatchDto {
        id: b.id,
        job_id: b.job_id,
        robot: b.robot,
        count: b.count,
        feasible: b.feasible,
        grasps,
        created_at: b.created_at,
    }))
}
