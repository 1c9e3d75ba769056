//! `/v1/executions`: trajectories and closed-loop motions queued for bridge workers
//! (DESIGN §7): create (202), list, inspect (state, last feedback, tracking error summary),
//! follow (SSE), cancel, and the measured state history (`/feedback`, decimated and bounded by
//! the store's feedback recorder), through [`crate::service::executions`].

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::IntoResponse;
use axum::response::sse::{Event, KeepAlive, Sse};
use futures::Stream;
use serde::{Deserialize, Serialize};
use tokio::sync::watch;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use uuid::Uuid;

use super::page::{Listed, Listing, Page};
use super::{ApiError, AppState, Json, Path, Problem, Query};
use crate::bridge::protocol::{Feedback, TrajectoryPointSchema};
use crate::bridge::{Mode, TrackingSummary};
use crate::motion::TrajectoryPoint;
use crate::service::executions::{self as service, ExecutionState, ExecutionView, Source};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_executions, create_execution))
        .routes(routes!(get_execution))
        .routes(routes!(execution_events))
        .routes(routes!(cancel_execution))
        .routes(routes!(execution_feedback))
}

// ------------------------------------------------------------------------------------ DTOs

/// A trajectory given in the request.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct InlineTrajectory {
    /// The robot's independent joints in model order.
    pub joint_names: Vec<String>,
    #[schema(value_type = Vec<TrajectoryPointSchema>)]
    pub points: Vec<TrajectoryPoint>,
}

/// What to execute: a trajectory (stored `trajectory_id` or inline `trajectory`) in
/// `open_loop`, or a model's closed-loop law (`model_id` + `goal`, or a stored trajectory's
/// model and goal) in `closed_loop`.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CreateExecution {
    /// Robot system id, e.g. `wam_ihy`.
    pub robot: String,
    pub mode: crate::bridge::RequestedMode,
    /// A stored trajectory (`POST /v1/trajectories`).
    pub trajectory_id: Option<String>,
    /// An inline trajectory.
    pub trajectory: Option<InlineTrajectory>,
    /// A trained model (`closed_loop`).
    pub model_id: Option<String>,
    /// Goal of a `closed_loop` execution with `model_id` (every joint, any order).
    // The models' joint vector, so that the document's one `JointValues` (closed) is what
    // both endpoints read: a second, open struct of that name let `goal` take unknown fields.
    pub goal: Option<crate::service::models::JointValues>,
    /// Run on this worker only (default: any idle worker of the robot).
    pub worker: Option<String>,
}

/// An execution.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ExecutionDto {
    pub id: String,
    pub robot: String,
    pub mode: Mode,
    /// `queued`, `running`, `succeeded`, `failed`, `aborted`, `cancelled` or `interrupted`.
    pub state: String,
    /// Why it failed, aborted, was cancelled or interrupted.
    pub reason: Option<String>,
    /// `trajectory`, `model` or `stream` (a streaming execution: teleoperation).
    pub kind: String,
    /// The stored trajectory or model it came from (`inline` for an inline trajectory).
    pub source_id: String,
    /// The requested worker (None: any).
    pub worker: Option<String>,
    /// The worker that ran it.
    pub assigned_worker: Option<String>,
    pub cancel_requested: bool,
    /// The latest feedback (kept when interrupted).
    pub last_feedback: Option<Feedback>,
    pub tracking: Option<TrackingSummary>,
    /// Samples in the measured state history (`GET /v1/executions/{id}/feedback`).
    pub feedback_samples: u64,
    pub created_at: String,
    pub dispatched_at: Option<String>,
    pub finished_at: Option<String>,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct FeedbackQuery {
    /// Only samples with `t` greater than this (s; default: from the start). Pass the previous
    /// page's `next_since` to read the next page.
    pub since: Option<f64>,
    /// Page size, 1 to 5000 (default 1000).
    pub limit: Option<u32>,
}

/// One measured state (joint order of the history's `joint_names`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct FeedbackSampleDto {
    /// Seconds since the execution started on the worker.
    pub t: f64,
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    /// 0..1, as in the worker's feedback.
    pub progress: f64,
    /// Largest joint deviation from the reference (open loop) or the goal (closed loop).
    pub tracking_error: f64,
}

/// A page of an execution's measured state history, oldest first.
///
/// The history is the worker's feedback decimated to at most `max_rate_hz` samples per second
/// and bounded to `max_samples` per execution: when the bound is reached every other sample is
/// dropped and the rate halves, so it always spans the whole execution. Its last sample is the
/// last state the worker reported. Kept when the execution is interrupted (what was flushed,
/// every 250 ms, or at the disconnect).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct FeedbackHistoryDto {
    pub execution_id: String,
    /// The execution's state when read.
    pub state: String,
    pub joint_names: Vec<String>,
    /// Samples in the whole history.
    pub total: u64,
    pub max_rate_hz: f64,
    pub max_samples: u64,
    /// This page's samples, strictly increasing `t`.
    pub samples: Vec<FeedbackSampleDto>,
    /// `since` for the next page; null on the last page.
    pub next_since: Option<f64>,
}

/// The `state` parameter's schema: the names of [`ExecutionState::ALL`], the states the handler
/// accepts (any other value is a 400 naming `state`).
fn execution_states() -> utoipa::openapi::Object {
    utoipa::openapi::ObjectBuilder::new()
        .schema_type(utoipa::openapi::schema::Type::String)
        .enum_values(Some(ExecutionState::ALL.iter().map(|s| s.as_str())))
        .build()
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListExecutionsQuery {
    /// Only executions in this state.
    #[param(schema_with = execution_states)]
    pub state: Option<String>,
    /// Only executions of this robot.
    pub robot: Option<String>,
    /// Page size, 1 to 500 (default 50).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub limit: Option<u32>,
    /// Executions to skip (default 0).
    #[allow(dead_code)] // documents the parameter; `page::Listing` reads it
    pub offset: Option<u32>,
}

impl Listed for ExecutionDto {
    const PAGE: &'static str = "ExecutionList";
    const DESCRIPTION: Option<&'static str> = Some("A page of executions, newest first.");
    const COUNTED: bool = false;
}

/// A page of executions, newest first.
pub type ExecutionList = Page<ExecutionDto>;

// ------------------------------------------------------------------------------------ views

/// The execution as it stands (the stored row with the live feedback overlaid while it runs).
fn execution_dto(v: ExecutionView) -> ExecutionDto {
    let ExecutionView {
        row,
        last_feedback,
        tracking,
        feedback_samples,
    } = v;
    ExecutionDto {
        mode: row.mode,
        id: row.id,
        robot: row.robot,
        state: row.state.to_string(),
        reason: row.reason,
        kind: row.kind,
        source_id: row.source_id,
        worker: row.worker,
        assigned_worker: row.assigned_worker,
        cancel_requested: row.cancel_requested,
        last_feedback,
        tracking,
        feedback_samples,
        created_at: row.created_at,
        dispatched_at: row.dispatched_at,
        finished_at: row.finished_at,
    }
}

/// What the request names to run: exactly one of a stored trajectory, an inline one and a
/// model.
fn source(body: &mut CreateExecution) -> Result<Source, ApiError> {
    match (
        body.trajectory_id.take(),
        body.trajectory.take(),
        body.model_id.take(),
    ) {
        (Some(id), None, None) => Ok(Source::Trajectory(id)),
        (None, Some(t), None) => Ok(Source::Inline {
            joint_names: t.joint_names,
            points: t.points,
        }),
        (None, None, Some(id)) => Ok(Source::Model(id)),
        _ => Err(ApiError::invalid_field(
            "$.trajectory_id",
            "give exactly one of trajectory_id, trajectory and model_id",
        )),
    }
}

// ------------------------------------------------------------------------------------ handlers

/// Queue an execution for a bridge worker of the robot.
///
/// The execution stores its own resolved copy of what it runs. It is dispatched to an idle
/// connected worker of the robot (the requested one, if any) with the mode's capability; one
/// execution per worker at a time, oldest first. While no compatible worker is connected it
/// stays `queued`; after the configured queue timeout it fails with `no worker`.
#[utoipa::path(post, path = "/v1/executions", tag = "executions", request_body = CreateExecution,
    responses(
        (status = 202, description = "Queued; follow `Location`", body = ExecutionDto),
        (status = 400, description = "Malformed JSON", body = Problem, content_type = "application/problem+json"),
        (status = 422, description = "Invalid request (unknown robot, joint names, limits, ...)", body = Problem,
         content_type = "application/problem+json"),
    ))]
async fn create_execution(
    State(state): State<AppState>,
    Json(mut body): Json<CreateExecution>,
) -> Result<impl IntoResponse, ApiError> {
    let source = source(&mut body)?;
    let goal = body.goal;
    let dto = execution_dto(
        service::create(
            &state,
            &body.robot,
            body.mode.into(),
            source,
            goal,
            body.worker.as_deref(),
        )
        .await?,
    );
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/executions/{}", dto.id))],
        Json(dto),
    ))
}

/// List executions, newest first.
#[utoipa::path(get, path = "/v1/executions", tag = "executions", params(ListExecutionsQuery),
    responses(
        (status = 200, description = "A page of executions", body = ExecutionList),
        (status = 400, description = "Bad query parameter", body = Problem, content_type = "application/problem+json"),
    ))]
async fn list_executions(
    State(state): State<AppState>,
    Listing(q, page): Listing<ListExecutionsQuery>,
) -> Result<Json<ExecutionList>, ApiError> {
    let wanted =
        match &q.state {
            None => None,
            Some(s) => Some(ExecutionState::parse(s).ok_or_else(|| {
                ApiError::invalid_parameter("state", format!("unknown state '{s}'"))
            })?),
        };
    let items = service::list(&state, wanted, q.robot.as_deref(), page.limit, page.offset)
        .await?
        .into_iter()
        .map(execution_dto)
        .collect();
    Ok(Json(page.of(items, None)))
}

/// One execution: state, last feedback, tracking error summary.
#[utoipa::path(get, path = "/v1/executions/{id}", tag = "executions",
    params(("id" = Uuid, Path, description = "Execution id")),
    responses(
        (status = 200, description = "The execution", body = ExecutionDto),
        (status = 404, description = "Unknown execution", body = Problem, content_type = "application/problem+json"),
    ))]
async fn get_execution(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Json<ExecutionDto>, ApiError> {
    Ok(Json(execution_dto(
        service::get(&state, &id.to_string()).await?,
    )))
}

/// Cancel a queued or running execution.
///
/// A queued execution is `cancelled` at once; a running one is cancelled on its worker and
/// becomes `cancelled` when the worker confirms (follow the events).
#[utoipa::path(post, path = "/v1/executions/{id}/cancel", tag = "executions",
    params(("id" = Uuid, Path, description = "Execution id")),
    responses(
        (status = 202, description = "Cancellation requested", body = ExecutionDto),
        (status = 404, description = "Unknown execution", body = Problem, content_type = "application/problem+json"),
        (status = 409, description = "Already finished", body = Problem, content_type = "application/problem+json"),
    ))]
async fn cancel_execution(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<(StatusCode, Json<ExecutionDto>), ApiError> {
    let v = service::cancel(&state, &id.to_string()).await?;
    Ok((StatusCode::ACCEPTED, Json(execution_dto(v))))
}

/// Server-Sent Events of an execution until it finishes.
///
/// Each event's data is the execution (as in `GET /v1/executions/{id}`). Events named
/// `progress` carry `queued`/`running` snapshots with the latest feedback (updates are
/// coalesced); the stream ends with one event named `final`.
#[utoipa::path(get, path = "/v1/executions/{id}/events", tag = "executions",
    params(("id" = Uuid, Path, description = "Execution id")),
    responses(
        (status = 200, description = "`text/event-stream` of `progress` events, then one `final` event; data: the execution",
         body = ExecutionDto, content_type = "text/event-stream"),
        (status = 404, description = "Unknown execution", body = Problem, content_type = "application/problem+json"),
    ))]
async fn execution_events(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let key = id.to_string();
    let first = execution_dto(service::get(&state, &key).await?);
    // A finished execution gets its final event only; a live one is followed. The first event
    // is read after subscribing, so no change in between is missed.
    let rx = if ExecutionState::parse(&first.state).is_none_or(ExecutionState::is_final) {
        watch::channel(0).1
    } else {
        state.bridges.subscribe(&key)
    };
    let stream = futures::stream::unfold((Some(rx), 0u64, true), move |(rx, seq, first)| {
        let state = state.clone();
        let key = key.clone();
        async move {
            let mut rx = rx?;
            if !first {
                tokio::select! {
                    // A closed channel means the execution finished; a timeout re-reads
                    // the store in case a change was coalesced away.
                    _ = rx.changed() => {}
                    () = tokio::time::sleep(Duration::from_secs(1)) => {}
                    () = state.shutdown.wait() => return None,
                }
                // Coalesce bursts of feedback into one event per 20 ms.
                tokio::time::sleep(Duration::from_millis(20)).await;
                rx.borrow_and_update();
            }
            let dto = execution_dto(service::get(&state, &key).await.ok()?);
            let last = ExecutionState::parse(&dto.state).is_none_or(ExecutionState::is_final);
            let event = Event::default()
                .event(if last { "final" } else { "progress" })
                .id(seq.to_string())
                .json_data(&dto)
                .expect("an execution serialises");
            Some((
                Ok(event),
                (if last { None } else { Some(rx) }, seq + 1, false),
            ))
        }
    });
    Ok(Sse::new(stream).keep_alive(KeepAlive::default()))
}

/// The measured state history of an execution (joint positions and velocities, progress and
/// tracking error over time), oldest first, in pages.
#[utoipa::path(get, path = "/v1/executions/{id}/feedback", tag = "executions",
    params(("id" = Uuid, Path, description = "Execution id"), FeedbackQuery),
    responses(
        (status = 200, description = "A page of the history", body = FeedbackHistoryDto),
        (status = 400, description = "Bad `since` or `limit`", body = Problem, content_type = "application/problem+json"),
        (status = 404, description = "Unknown execution", body = Problem, content_type = "application/problem+json"),
    ))]
async fn execution_feedback(
    State(state): State<AppState>,
    Path(id): Path<Uuid>,
    Query(q): Query<FeedbackQuery>,
) -> Result<Json<FeedbackHistoryDto>, ApiError> {
    const MAX_PAGE: u32 = 5000;
    let limit = q.limit.unwrap_or(1000);
    if !(1..=MAX_PAGE).contains(&limit) {
        return Err(ApiError::invalid_parameter(
            "limit",
            format!("must be between 1 and {MAX_PAGE}, got {limit}"),
        ));
    }
    if let Some(s) = q.since
        && !s.is_finite()
    {
        return Err(ApiError::invalid_parameter(
            "since",
            format!("must be a finite number of seconds, got {s}"),
        ));
    }
    let key = id.to_string();
    let (row, joint_names, h) = service::feedback(&state, &key).await?;
    let from = q.since.map_or(0, |s| h.first_after(s));
    let to = (from + limit as usize).min(h.len());
    let samples: Vec<FeedbackSampleDto> = (from..to)
        .map(|i| {
            let s = h.sample(i);
            FeedbackSampleDto {
                t: s.t,
                positions: s.positions.to_vec(),
                velocities: s.velocities.to_vec(),
                progress: s.progress,
                tracking_error: s.tracking_error,
            }
        })
        .collect();
    let next_since = (to < h.len())
        .then(|| samples.last().map(|s| s.t))
        .flatten();
    Ok(Json(FeedbackHistoryDto {
        execution_id: key,
        state: row.state.to_string(),
        joint_names,
        total: h.len() as u64,
        max_rate_hz: service::MAX_RATE_HZ,
        max_samples: service::MAX_SAMPLES as u64,
        samples,
        next_since,
    }))
}
