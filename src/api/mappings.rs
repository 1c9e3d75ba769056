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
use crate::store::mappings::{self as repo, DemoLabels, MappedDemoRow, StoredMappedDemo};

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

async fn mapping_dto(
    state: &AppState,
    row: repo::MappingRow,
    demonstrations: Option<MappedDemoPage>,
) -> Result<MappingDto, ApiError> {
    let request: MappingRequestDto = serde_json::from_str(&row.request)
        .map_err(|e| ApiError::internal(anyhow::anyhow!("mappings.request of {}: {e}", row.id)))?;
    let summary = row
        .summary
        .as_deref()
        .map(serde_json::from_str)
        .transpose()
        .map_err(|e| ApiError::internal(anyhow::anyhow!("mappings.summary of {}: {e}", row.id)))?;
    let error = if row.status == "failed" {
        match Uuid::parse_str(&row.job_id) {
            Ok(job) => state.jobs.get(job).await.ok().and_then(|j| j.error),
            Err(_) => None,
        }
    } else {
        None
    };
    Ok(MappingDto {
        id: row.id,
        job_id: row.job_id,
        robot: row.robot,
        status: row.status,
        request,
        summary,
        error,
        created_at: row.created_at,
        demonstrations,
    })
}

fn parse_summary(row: &MappedDemoRow) -> Result<MappingSummary, ApiError> {
    serde_json::from_str(&row.summary).map_err(|e| {
        ApiError::internal(anyhow::anyhow!(
            "mapping_demonstrations.summary of {}: {e}",
            row.demonstration_id
        ))
    })
}

fn labels_of(row: &MappedDemoRow, d: Option<&StoredMappedDemo>) -> DemoLabels {
    DemoLabels {
        demonstration_id: row.demonstration_id.clone(),
        subject_id: row.subject_id.clone(),
        object_name: row.object_name.clone(),
        task: row.task.clone(),
        position_index: d.map_or(row.position_index as u32, |d| d.position_index),
        trial: d.map_or(row.trial as u32, |d| d.trial),
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
    let id = id.to_string();
    let row = repo::get_mapping(&state.db, &id)
        .await?
        .ok_or_else(|| ApiError::not_found("mapping", &id))?;
    let demo = q.demonstration.as_deref();
    let (items, total) = if q.trajectories.unwrap_or(true) {
        let (rows, total) =
            repo::load_page(&state.db, &id, demo, i64::from(limit), i64::from(offset)).await?;
        let items = rows
            .iter()
            .map(|(meta, d)| {
                let mut dto = mapped_demo_dto(
                    meta.position as usize,
                    &labels_of(meta, Some(d)),
                    &d.trajectory,
                );
                dto.summary = parse_summary(meta)?;
                Ok(dto)
            })
            .collect::<Result<Vec<_>, ApiError>>()?;
        (items, total)
    } else {
        let (rows, total) =
            repo::list_demos(&state.db, &id, demo, i64::from(limit), i64::from(offset)).await?;
        let items = rows
            .iter()
            .map(|meta| {
                let l = labels_of(meta, None);
                Ok(MappedDemoDto {
                    position: meta.position as usize,
                    demonstration_id: l.demonstration_id,
                    subject_id: l.subject_id,
                    object_name: l.object_name,
                    task: l.task,
                    position_index: l.position_index,
                    trial: l.trial,
                    summary: parse_summary(meta)?,
                    registration: None,
                    trajectory: None,
                    metrics: None,
                })
            })
            .collect::<Result<Vec<_>, ApiError>>()?;
        (items, total)
    };
    let page = MappedDemoPage {
        items,
        total,
        limit,
        offset,
    };
    Ok(Json(mapping_dto(&state, row, Some(page)).await?))
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
    if let Some(s) = &q.status
        && crate::jobs::JobStatus::parse(s).is_none()
    {
        return Err(ApiError::invalid_parameter(
            "status",
            format!("unknown status '{s}' (queued, running, succeeded, failed or cancelled)"),
        ));
    }
    let (rows, total) = repo::list_mappings(
        &state.db,
        i64::from(page.limit),
        i64::from(page.offset),
        q.robot.as_deref(),
        q.status.as_deref(),
    )
    .await?;
    let mut items = Vec::with_capacity(rows.len());
    for row in rows {
        items.push(mapping_dto(&state, row, None).await?);
    }
    Ok(Json(page.of(items, Some(total))))
}
