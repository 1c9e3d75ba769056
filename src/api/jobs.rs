//! `/v1/jobs`: list, inspect, follow (SSE) and cancel long-running jobs.

use std::convert::Infallible;

use axum::extract::State;
use axum::http::StatusCode;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures::Stream;
use serde::Deserialize;
use tokio::sync::watch;
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem};
use crate::jobs::{JobRecord, JobRunner, JobStatus};
use crate::service::jobs as service;
use crate::shutdown::Shutdown;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_jobs))
        .routes(routes!(get_job))
        .routes(routes!(job_events))
        .routes(routes!(cancel_job))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListJobsQuery {
    /// Only jobs with this status.
    pub status: Option<JobStatus>,
    /// Only jobs of this kind.
    pub kind: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Jobs to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

impl Listed for JobRecord {
    const PAGE: &'static str = "JobList";
    const DESCRIPTION: Option<&'static str> = Some("A page of jobs, newest first.");
    const COUNTED: bool = false;
}

/// A page of jobs, newest first.
pub type JobList = Page<JobRecord>;

/// List jobs, newest first.
#[utoipa::path(get, path = "/v1/jobs", tag = "jobs", params(ListJobsQuery),
    responses(
        (status = 200, description = "A page of jobs", body = JobList),
        (status = 400, description = "Bad query parameter", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn list_jobs(
    State(state): State<AppState>,
    Listing(q, page): Listing<ListJobsQuery>,
) -> Result<Json<JobList>, ApiError> {
    let items = service::list(&state, q.status, q.kind, page.limit, page.offset).await?;
    Ok(Json(page.of(items, None)))
}

/// One job: status, progress, error and result reference.
#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = JobRecord),
        (status = 400, description = "Malformed id", body = Problem,
         content_type = "application/problem+json"),
        (status = 404, description = "Unknown job", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn get_job(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Json<JobRecord>, ApiError> {
    Ok(Json(service::get(&state, id).await?))
}

/// Request cooperative cancellation of a queued or running job.
///
/// A queued job is cancelled before it starts; a running job stops at its next cancellation
/// check. Follow `/v1/jobs/{id}/events` or poll the job to see it become `cancelled`.
#[utoipa::path(post, path = "/v1/jobs/{id}/cancel", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 202, description = "Cancellation requested", body = JobRecord),
        (status = 404, description = "Unknown job", body = Problem,
         content_type = "application/problem+json"),
        (status = 409, description = "The job has already finished", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn cancel_job(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<(StatusCode, Json<JobRecord>), ApiError> {
    let record = service::cancel(&state, id).await?;
    Ok((StatusCode::ACCEPTED, Json(record)))
}

/// Server-Sent Events of a job's state until it finishes.
///
/// Each event's data is the job (as in `GET /v1/jobs/{id}`). Events named `progress` carry
/// `queued`/`running` snapshots (intermediate updates may be coalesced); the stream ends with
/// exactly one event named `final` carrying the finished job. A finished job gives only `final`.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs",
    params(("id" = Uuid, Path, description = "Job id")),
    responses(
        (status = 200, description = "`text/event-stream` of `progress` events, then one `final` event; data: the job as JSON",
         body = JobRecord, content_type = "text/event-stream"),
        (status = 404, description = "Unknown job", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn job_events(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    // Subscribe before reading the store: a job that finishes in between is then still seen.
    let live = state.jobs.subscribe(id);
    let start = match live {
        Some(rx) => Step::Live(rx),
        None => Step::Last(Box::new(service::get(&state, id).await?)),
    };
    let stream = events(start, state.jobs.clone(), state.shutdown.clone());
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

enum Step {
    /// Follow the live job.
    Live(watch::Receiver<JobRecord>),
    /// Send this record, then end.
    Last(Box<JobRecord>),
    Done,
}

fn to_event(record: &JobRecord, seq: u64) -> Event {
    let name = if record.status.is_final() {
        "final"
    } else {
        "progress"
    };
    Event::default()
        .event(name)
        .id(seq.to_string())
        .json_data(record)
        .expect("a job record always serializes")
}

fn events(
    start: Step,
    runner: JobRunner,
    shutdown: Shutdown,
) -> impl Stream<Item = Result<Event, Infallible>> {
    futures::stream::unfold((start, 0u64, true), move |(step, seq, first)| {
        let runner = runner.clone();
        let shutdown = shutdown.clone();
        async move {
            match step {
                Step::Done => None,
                Step::Last(record) => {
                    Some((Ok(to_event(&record, seq)), (Step::Done, seq + 1, false)))
                }
                Step::Live(mut rx) => {
                    if !first {
                        tokio::select! {
                            changed = rx.changed() => {
                                if changed.is_err() {
                                    // Sender gone without an unseen value: the job is settled
                                    // in the store; send what it holds.
                                    let id = rx.borrow().id;
                                    return match runner.get(id).await {
                                        Ok(record) => Some((
                                            Ok(to_event(&record, seq)),
                                            (Step::Done, seq + 1, false),
                                        )),
                                        Err(e) => {
                                            tracing::error!(error = %e, "cannot read a finished job");
                                            None
                                        }
                                    };
                                }
                            }
                            () = shutdown.wait() => return None,
                        }
                    }
                    let record = rx.borrow_and_update().clone();
                    let next = if record.status.is_final() {
                        Step::Done
                    } else {
                        Step::Live(rx)
                    };
                    Some((Ok(to_event(&record, seq)), (next, seq + 1, false)))
                }
            }
        }
    })
}
