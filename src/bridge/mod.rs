//! Bridge workers: WebSocket protocol, dispatcher, persistent execution queue, simulated robot
//! (DESIGN §7).
//!
//! - [`protocol`]: the versioned JSON messages (shared by service and worker; OpenAPI schemas).
//! - [`hub`]: connected workers, the dispatcher over the SQLite queue
//!   ([`crate::store::executions`]), one task per connection.
//! - [`sim`] + [`worker`]: the reference worker (`reachgrasp bridge --sim`).
//!
//! Other resources queue executions with [`enqueue`] (the plans endpoint does).

pub mod hub;
pub mod protocol;
pub mod sim;
pub mod worker;

pub use hub::{Hub, HubSettings, TrackingSummary, WorkerSnapshot};
pub use protocol::{ExecutionPayload, Mode};

use crate::api::{ApiError, AppState, FieldError};

/// Most points an execution's trajectory may have (10 min at 100 Hz + margin).
pub const MAX_POINTS: usize = 100_000;

/// Where the parts of a payload came from, for error paths (`$.trajectory.points`, ...).
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

/// Checks a payload against the robot system (joint names and order, counts, finiteness,
/// increasing times, joint limits) and the mode. Every problem is reported with its path.
pub fn validate_payload(
    payload: &ExecutionPayload,
    mode: Mode,
    system: &crate::kinematics::System,
    robot: &str,
    paths: &PayloadPaths,
) -> Result<(), ApiError> {
    let model = &system.model;
    let names = model.joint_names();
    let n = names.len();
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    let mut errors = Vec::new();
    if payload.mode() != mode {
        errors.push(FieldError::new(
            "$.mode",
            format!(
                "a {} payload runs in {}, not {}",
                payload.kind(),
                payload.mode().as_str(),
                mode.as_str()
            ),
        ));
    }
    if payload.joint_names() != names {
        errors.push(FieldError::new(
            &paths.joint_names,
            format!(
                "must be robot '{robot}''s joints in model order {names:?}, got {:?}",
                payload.joint_names()
            ),
        ));
        return Err(ApiError::validation(errors));
    }
    let outside = |q: &[f64]| {
        q.iter()
            .zip(lo.iter().zip(hi))
            .position(|(&x, (&l, &h))| x < l - 1e-9 || x > h + 1e-9)
    };
    match payload {
        ExecutionPayload::Trajectory { points, .. } => {
            if points.is_empty() || points.len() > MAX_POINTS {
                errors.push(FieldError::new(
                    &paths.points,
                    format!("must have 1 to {MAX_POINTS} points, got {}", points.len()),
                ));
            }
            for (i, p) in points.iter().enumerate() {
                if errors.len() > 20 {
                    break;
                }
                let at = format!("{}[{i}]", paths.points);
                for (field, v) in [
                    ("positions", &p.positions),
                    ("velocities", &p.velocities),
                    ("accelerations", &p.accelerations),
                ] {
                    if v.len() != n {
                        errors.push(FieldError::new(
                            format!("{at}.{field}"),
                            format!("must have {n} values (one per joint), got {}", v.len()),
                        ));
                    } else if let Some(j) = v.iter().position(|x| !x.is_finite()) {
                        errors.push(FieldError::new(
                            format!("{at}.{field}[{j}]"),
                            "must be a finite number",
                        ));
                    }
                }
                if !p.t.is_finite() || p.t < 0.0 {
                    errors.push(FieldError::new(
                        format!("{at}.t"),
                        "must be finite and >= 0",
                    ));
                } else if i > 0 && p.t <= points[i - 1].t {
                    errors.push(FieldError::new(
                        format!("{at}.t"),
                        format!("times must increase: {} after {}", p.t, points[i - 1].t),
                    ));
                }
                if p.positions.len() == n
                    && let Some(j) = outside(&p.positions)
                {
                    errors.push(FieldError::new(
                        format!("{at}.positions[{j}]"),
                        format!(
                            "{} is outside joint '{}' limits [{}, {}]",
                            p.positions[j], names[j], lo[j], hi[j]
                        ),
                    ));
                }
            }
        }
        ExecutionPayload::Model { params, goal, .. } => {
            if params.n_joints() != n {
                errors.push(FieldError::new(
                    &paths.joint_names,
                    format!(
                        "the model's law covers {} joints, the robot has {n}",
                        params.n_joints()
                    ),
                ));
            }
            if goal.len() != n {
                errors.push(FieldError::new(
                    &paths.goal,
                    format!("must have {n} values (one per joint), got {}", goal.len()),
                ));
            } else if let Some(j) = goal.iter().position(|x| !x.is_finite()) {
                errors.push(FieldError::new(
                    format!("{}[{j}]", paths.goal),
                    "must be a finite number",
                ));
            } else if let Some(j) = outside(goal) {
                errors.push(FieldError::new(
                    format!("{}[{j}]", paths.goal),
                    format!(
                        "{} is outside joint '{}' limits [{}, {}]",
                        goal[j], names[j], lo[j], hi[j]
                    ),
                ));
            }
        }
    }
    if errors.is_empty() {
        Ok(())
    } else {
        Err(ApiError::validation(errors))
    }
}

/// Resolves a robot id for an execution (422 naming `$.robot` when unknown).
pub async fn robot_system(
    state: &AppState,
    robot: &str,
) -> Result<std::sync::Arc<crate::kinematics::System>, ApiError> {
    if crate::store::robots::get(&state.db, robot).await?.is_none() {
        return Err(ApiError::invalid_field(
            "$.robot",
            format!("unknown robot '{robot}'"),
        ));
    }
    crate::api::robots::system(state, robot).await
}

/// Checks and queues an execution with error paths of `paths`; returns its id.
pub async fn enqueue_checked(
    state: &AppState,
    robot: &str,
    mode: Mode,
    payload: ExecutionPayload,
    worker: Option<String>,
    paths: &PayloadPaths,
) -> Result<String, ApiError> {
    if let Some(w) = &worker
        && !hub::valid_worker_name(w)
    {
        return Err(ApiError::invalid_field(
            "$.worker",
            format!("'{w}' is not a worker name (1-64 letters, digits, '-', '_', '.')"),
        ));
    }
    let system = robot_system(state, robot).await?;
    validate_payload(&payload, mode, &system, robot, paths)?;
    state
        .bridges
        .insert(robot, mode, &payload, worker.as_deref())
        .await
}

/// Queue an execution (stored in SQLite, dispatched when a worker is free); returns its id.
pub async fn enqueue(
    state: &AppState,
    robot: &str,
    mode: Mode,
    payload: ExecutionPayload,
    worker: Option<String>,
) -> Result<String, ApiError> {
    enqueue_checked(
        state,
        robot,
        mode,
        payload,
        worker,
        &PayloadPaths::default(),
    )
    .await
}
