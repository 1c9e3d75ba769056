//! `/v1/mappings`: human demonstrations mapped onto a robot arm-hand system (paper eq. 1-7) as a
//! job ([`crate::service::mappings`]), and the stored joint trajectories with their per-frame
//! metrics.

use axum::extract::State;
use axum::response::Response;
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem, Query};
use crate::jobs::{JobFailure, JobRecord};
use crate::service::mappings as service;
pub use crate::service::mappings::{
    DEFAULT_DEMO_PAGE, DemoFilterIn, FrameMetricsDto, JointTrajectoryDto, MAX_DEMO_PAGE,
    MAX_DEMONSTRATIONS, MAX_OUTPUT_RATE_HZ, MappedDemoDto, MappingIn, MappingRequestDto,
    MappingSummary, RegistrationDto, RegistrationIn, ScaleIn, SelectionIn, TransformIn, WeightsDto,
    WeightsIn, mapped_demo_dto,
};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_mappings, create_mapping))
        .routes(routes!(get_mapping))
}

/// Map demonstrations onto a robot (202 + job). The robot, every demonstration and the
/// registration of every demonstration are checked first: bad input is a 4xx naming the field and
/// nothing is stored. Poll the job or `GET /v1/mappings/{id}` (`Location` of the job, `result`
/// once it succeeded).
#[utoipa::path(post, path = "/v1/mappings", tag = "mappings", request_body = MappingIn,
    responses(
        (status = 202, description = "Job accepted; `Location` names it, `Content-Location` the mapping", body = JobRecord),
        (status = 400, description = "Malformed body", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Unknown robot or demonstration, empty selection, unregistrable demonstration, bad weights, registration or rate", body = Problem, content_type = "application/problem+json"),
    ))]
async fn create_mapping(
    State(state): State<AppState>,
    Json(body): Json<MappingIn>,
) -> Result<Response, ApiError> {
    let (job, mapping_id) = service::submit(&state, &body).await?;
    Ok(super::accepted_job(
        job,
        Some(format!("/v1/mappings/{mapping_id}")),
    ))
}

/// A page of a mapping's demonstrations.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct MappedDemoPage {
    pub items: Vec<MappedDemoDto>,
    pub total: i64,
    pub limit: u32,
    pub offset: u32,
}

/// A mapping: status (its job's), request, summary and a page of demonstrations.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct MappingDto {
    pub id: String,
    pub job_id: String,
    pub robot: String,
    /// `queued|running|succeeded|failed|cancelled`.
    pub status: String,
    pub request: MappingRequestDto,
    /// Set once succeeded.
    pub summary: Option<MappingSummary>,
    /// Why the job failed.
    pub error: Option<JobFailure>,
    pub created_at: String,
    /// Present in `GET /v1/mappings/{id}` (empty until succeeded).
    pub demonstrations: Option<MappedDemoPage>,
}

impl Listed for MappingDto {
    const PAGE: &'static str = "MappingList";
    const DESCRIPTION: Option<&'static str> = Some("A page of mappings, newest first.");
}

/// A page of mappings, newest first.
pub type MappingList = Page<MappingDto>;

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    /// Only this robot.
    pub robot: Option<String>,
    /// Only this status.
    #[param(value_type = Option<crate::jobs::JobStatus>)]
    pub status: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct GetQuery {
    /// Only this demonstration of the mapping.
    pub demonstration: Option<String>,
    /// Demonstrations per page, 1 to 100 (default 10).
    pub limit: Option<u32>,
    /// Demonstrations to skip (default 0).
    pub offset: Option<u32>,
    /// Include joint trajectories and per-frame metrics (default true); `false` gives only the
    /// per-demonstration summaries.
    pub trajectories: Option<bool>,
}

fn mapping_dto(m: service::StoredMapping, demonstrations: Option<MappedDemoPage>) -> MappingDto {
    MappingDto {
        id: m.id,
        job_id: m.job_id,
        robot: m.robot,
        status: m.status,
        request: m.request,
        summary: m.summary,
        error: m.error,
        created_at: m.created_at,
        demonstrations,
    }
}

/// A mapping: status, request, summary metrics and a page of its demonstrations, each with its
/// joint trajectory and per-frame metrics (`?trajectories=false` for summaries only;
/// `?demonstration=` for one). Page through all of them with `limit`/`offset`.
#[utoipa::path(get, path = "/v1/mappings/{id}", tag = "mappings",
    params(("id" = Uuid, Path, description = "Mapping id"), GetQuery),
    responses(
        (status = 200, description = "The mapping", body = MappingDto),
        (status = 400, description = "Bad id or parameter", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown mapping", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_mapping(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
    Query(q): Query<GetQuery>,
) -> Result<Json<MappingDto>, ApiError> {
    let limit = q.limit.unwrap_or(DEFAULT_DEMO_PAGE);
    if !(1..=MAX_DEMO_PAGE).contains(&limit) {
        return Err(ApiError::invalid_parameter(
            "limit",
            format!("must be between 1 and {MAX_DEMO_PAGE}, got {limit}"),
        ));
    }
    let offset = super::page::check_offset(q.offset.unwrap_or(0))?;
    let page = service::DemoPage {
        demonstration: q.demonstration.as_deref(),
        trajectories: q.trajectories.unwrap_or(true),
        limit,
        offset,
    };
    let (mapping, items, total) = service::get(&state, &id.to_string(), &page).await?;
    let page = MappedDemoPage {
        items,
        total,
        limit,
        offset,
    };
    Ok(Json(mapping_dto(mapping, Some(page))))
}

/// List mappings, newest first (status, request and summary; no trajectories).
#[utoipa::path(get, path = "/v1/mappings", tag = "mappings", params(ListQuery),
    responses(
        (status = 200, description = "A page of mappings", body = MappingList),
        (status = 400, description = "Bad query parameter", body = Problem, content_type = "application/problem+json"),
    ))]
async fn list_mappings(
    State(state): State<AppState>,
    Listing(q, page): Listing<ListQuery>,
) -> Result<Json<MappingList>, ApiError> {
    let status = match &q.status {
        None => None,
        Some(s) => Some(crate::jobs::JobStatus::parse(s).ok_or_else(|| {
            ApiError::invalid_parameter(
                "status",
                format!("unknown status '{s}' (queued, running, succeeded, failed or cancelled)"),
            )
        })?),
    };
    let (rows, total) =
        service::list(&state, q.robot.as_deref(), status, page.limit, page.offset).await?;
    let items = rows.into_iter().map(|m| mapping_dto(m, None)).collect();
    Ok(Json(page.of(items, Some(total))))
}
