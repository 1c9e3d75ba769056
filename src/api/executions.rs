//! `/v1/executions`: trajectories and closed-loop motions queued for bridge workers
//! (DESIGN §7): create (202), list, inspect (state, last feedback, tracking error summary),
//! follow (SSE), cancel, and the measured state history (`/feedback`, decimated and bounded by
//! [`crate::store::feedback`]).

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
use super::{ApiError, AppState, FieldError, Json, Path, Problem, Query};
use crate::bridge::protocol::{Feedback, TrajectoryPointSchema};
use crate::bridge::{ExecutionPayload, Mode, TrackingSummary, WorkerName};
use crate::motion::TrajectoryPoint;
use crate::store::executions::{self as repo, ExecutionState};
use crate::store::feedback::{self, History};

/// Where the parts of a payload came from in a request, for error paths
/// (`$.trajectory.points`, ...).
#[derive(Debug, Clone)]
pub struct PayloadPaths {
    pub joint_names: String,
    pub points: String,
    pub goal: String,
}

impl Default for PayloadPaths {
    fn default() -> Self {
        PayloadPaths {
            joint_names: "$.payload.joint_names".into(),
            points: "$.payload.points".into(),
            goal: "$.payload.goal".into(),
        }
    }
}

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
pub struct InlineTrajectory {
    /// The robot's independent joints in model order.
    pub joint_names: Vec<String>,
    #[schema(value_type = Vec<TrajectoryPointSchema>)]
    pub points: Vec<TrajectoryPoint>,
}

/// Joint values with their names.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct JointValues {
    pub joint_names: Vec<String>,
    pub positions: Vec<f64>,
}

/// What to execute: a trajectory (stored `trajectory_id` or inline `trajectory`) in
/// `open_loop`, or a model's closed-loop law (`model_id` + `goal`, or a stored trajectory's
/// model and goal) in `closed_loop`.
#[derive(Debug, Clone, Deserialize, ToSchema)]
pub struct CreateExecution {
    /// Robot system id, e.g. `wam_ihy`.
    pub robot: String,
    pub mode: Mode,
    /// A stored trajectory (`POST /v1/trajectories`).
    pub trajectory_id: Option<String>,
    /// An inline trajectory.
    pub trajectory: Option<InlineTrajectory>,
    /// A trained model (`closed_loop`).
    pub model_id: Option<String>,
    /// Goal of a `closed_loop` execution with `model_id` (every joint, any order).
    pub goal: Option<JointValues>,
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
    /// `trajectory` or `model`.
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

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListExecutionsQuery {
    /// Only executions in this state.
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

/// The execution's view: the stored row with the live feedback overlaid while it runs.
pub async fn view(state: &AppState, row: repo::ExecutionRow) -> ExecutionDto {
    let crate::service::executions::ExecutionView {
        row,
        last_feedback,
        tracking,
        feedback_samples,
    } = crate::service::executions::view(state, row);
    ExecutionDto {
        mode: Mode::parse(&row.mode).unwrap_or(Mode::OpenLoop),
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

/// The measured state history of an execution: the live one (with what is not flushed yet)
/// while it runs, else the stored one.
pub async fn history(
    state: &AppState,
    row: &repo::ExecutionRow,
    n_joints: usize,
) -> Result<History, ApiError> {
    if row.state == ExecutionState::Running
        && let Some(h) = state.bridges.history(&row.id)
        && h.n_joints == n_joints
    {
        return Ok(h);
    }
    Ok(feedback::load(&state.db, &row.id, n_joints).await?)
}

async fn load(state: &AppState, id: &Uuid) -> Result<ExecutionDto, ApiError> {
    let row = repo::get(&state.db, &id.to_string())
        .await?
        .ok_or_else(|| ApiError::not_found("execution", id))?;
    Ok(view(state, row).await)
}

// ------------------------------------------------------------------------------------ payloads

/// Resolves the request into the payload the execution keeps, with error paths of the body.
async fn resolve(
    state: &AppState,
    body: CreateExecution,
) -> Result<(ExecutionPayload, PayloadPaths), ApiError> {
    let given = [
        body.trajectory_id.is_some(),
        body.trajectory.is_some(),
        body.model_id.is_some(),
    ];
    if given.iter().filter(|g| **g).count() != 1 {
        return Err(ApiError::invalid_field(
            "$.trajectory_id",
            "give exactly one of trajectory_id, trajectory and model_id",
        ));
    }
    if let Some(t) = body.trajectory {
        if body.goal.is_some() {
            return Err(ApiError::invalid_field(
                "$.goal",
                "a trajectory ends at its own last point; goal is only for model_id",
            ));
        }
        return Ok((
            ExecutionPayload::Trajectory {
                trajectory_id: "inline".into(),
                joint_names: t.joint_names,
                points: t.points,
            },
            PayloadPaths {
                joint_names: "$.trajectory.joint_names".into(),
                points: "$.trajectory.points".into(),
                goal: "$.goal".into(),
            },
        ));
    }
    stored::resolve(state, body).await
}

/// Orders named joint values like `names`; errors name `$.goal...`.
fn ordered_goal(goal: &JointValues, names: &[String]) -> Result<Vec<f64>, ApiError> {
    if goal.joint_names.len() != goal.positions.len() {
        return Err(ApiError::invalid_field(
            "$.goal.positions",
            format!(
                "{} positions for {} joint names",
                goal.positions.len(),
                goal.joint_names.len()
            ),
        ));
    }
    let mut errors = Vec::new();
    let mut out = Vec::with_capacity(names.len());
    for n in names {
        match goal.joint_names.iter().position(|g| g == n) {
            Some(i) => out.push(goal.positions[i]),
            None => errors.push(FieldError::new(
                "$.goal.joint_names",
                format!("joint '{n}' is missing"),
            )),
        }
    }
    for (i, g) in goal.joint_names.iter().enumerate() {
        if !names.contains(g) {
            errors.push(FieldError::new(
                format!("$.goal.joint_names[{i}]"),
                format!("'{g}' is not a joint of this robot"),
            ));
        }
    }
    if errors.is_empty() {
        Ok(out)
    } else {
        Err(ApiError::validation(errors))
    }
}

/// Stored trajectories and models (the `models` resource's store).
mod stored {
    use super::*;
    use crate::store::{models, trajectories};

    async fn params(
        state: &AppState,
        model_id: &str,
        robot: &str,
        path: &str,
    ) -> Result<crate::motion::ControlParams, ApiError> {
        let row = models::get_model(&state.db, model_id)
            .await?
            .ok_or_else(|| ApiError::invalid_field(path, format!("unknown model '{model_id}'")))?;
        if row.robot != robot {
            return Err(ApiError::invalid_field(
                path,
                format!(
                    "model '{model_id}' is for robot '{}', not '{robot}'",
                    row.robot
                ),
            ));
        }
        models::load_params(&state.db, model_id)
            .await?
            .ok_or_else(|| {
                ApiError::conflict(format!(
                    "model '{model_id}' is not trained (its job is {})",
                    row.status
                ))
            })
    }

    pub(super) async fn resolve(
        state: &AppState,
        body: CreateExecution,
    ) -> Result<(ExecutionPayload, PayloadPaths), ApiError> {
        if let Some(id) = &body.trajectory_id {
            if body.goal.is_some() {
                return Err(ApiError::invalid_field(
                    "$.goal",
                    "a stored trajectory brings its own goal; goal is only for model_id",
                ));
            }
            let t = trajectories::get_trajectory(&state.db, id)
                .await?
                .ok_or_else(|| {
                    ApiError::invalid_field("$.trajectory_id", format!("unknown trajectory '{id}'"))
                })?;
            if t.robot != body.robot {
                return Err(ApiError::invalid_field(
                    "$.trajectory_id",
                    format!(
                        "trajectory '{id}' is for robot '{}', not '{}'",
                        t.robot, body.robot
                    ),
                ));
            }
            let paths = PayloadPaths {
                joint_names: "$.trajectory_id".into(),
                points: "$.trajectory_id".into(),
                goal: "$.trajectory_id".into(),
            };
            return match body.mode {
                Mode::OpenLoop => Ok((
                    ExecutionPayload::Trajectory {
                        trajectory_id: t.id,
                        joint_names: t.joint_names,
                        points: t.points,
                    },
                    paths,
                )),
                Mode::ClosedLoop => {
                    let model_id = t.model_id.ok_or_else(|| {
                        ApiError::invalid_field(
                            "$.mode",
                            format!(
                                "trajectory '{id}' was not generated by a model, so it has no \
                                 closed-loop law; run it in open_loop"
                            ),
                        )
                    })?;
                    let params = params(state, &model_id, &body.robot, "$.trajectory_id").await?;
                    let goal = ordered_goal(
                        &JointValues {
                            joint_names: t.joint_names,
                            positions: t.goal,
                        },
                        &params.joint_names,
                    )
                    .map_err(|_| {
                        ApiError::invalid_field(
                            "$.trajectory_id",
                            "the trajectory's joints differ from its model's",
                        )
                    })?;
                    Ok((
                        ExecutionPayload::Model {
                            model_id,
                            params,
                            goal,
                        },
                        paths,
                    ))
                }
            };
        }
        let model_id = body
            .model_id
            .expect("resolve checked that one source is given");
        if body.mode != Mode::ClosedLoop {
            return Err(ApiError::invalid_field(
                "$.mode",
                "a model runs its law in closed_loop; for open_loop generate a trajectory \
                 (POST /v1/trajectories) and pass its trajectory_id",
            ));
        }
        let goal = body
            .goal
            .ok_or_else(|| ApiError::invalid_field("$.goal", "model_id needs a goal"))?;
        let params = params(state, &model_id, &body.robot, "$.model_id").await?;
        let goal = ordered_goal(&goal, &params.joint_names)?;
        Ok((
            ExecutionPayload::Model {
                model_id,
                params,
                goal,
            },
            PayloadPaths {
                joint_names: "$.model_id".into(),
                points: "$.model_id".into(),
                goal: "$.goal.positions".into(),
            },
        ))
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
    Json(body): Json<CreateExecution>,
) -> Result<impl IntoResponse, ApiError> {
    let robot = body.robot.clone();
    let mode = body.mode;
    let worker = body.worker.clone();
    let (payload, paths) = resolve(&state, body).await?;
    let worker = worker.as_deref().map(WorkerName::parse).transpose()?;
    let id = crate::service::executions::enqueue(&state, &robot, mode, payload, worker)
        .await
        .map_err(|e| match e {
            crate::service::Error::Payload(issues) => ApiError::payload(&issues, &paths),
            other => other.into(),
        })?;
    let dto = load(&state, &id.parse().map_err(ApiError::internal)?).await?;
    Ok((
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/executions/{id}"))],
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
    let rows = repo::list(
        &state.db,
        wanted,
        q.robot.as_deref(),
        page.limit,
        page.offset,
    )
    .await?;
    let mut items = Vec::with_capacity(rows.len());
    for r in rows {
        items.push(view(&state, r).await);
    }
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
    Ok(Json(load(&state, &id).await?))
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
    state.bridges.cancel(&id.to_string()).await?;
    Ok((StatusCode::ACCEPTED, Json(load(&state, &id).await?)))
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
    let first = load(&state, &id).await?;
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
            let row = repo::get(&state.db, &key).await.ok().flatten()?;
            let dto = view(&state, row).await;
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
    let row = repo::get(&state.db, &key)
        .await?
        .ok_or_else(|| ApiError::not_found("execution", id))?;
    let joint_names = repo::joint_names(&state.db, &key)
        .await?
        .ok_or_else(|| ApiError::not_found("execution", id))?;
    let h = history(&state, &row, joint_names.len()).await?;
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
        max_rate_hz: feedback::MAX_RATE_HZ,
        max_samples: feedback::MAX_SAMPLES as u64,
        samples,
        next_since,
    }))
}
