//! Bridge workers: WebSocket protocol, dispatcher, persistent execution queue, simulated robot
//! (DESIGN §7).
//!
//! - [`protocol`]: the versioned JSON messages (shared by service and worker; OpenAPI schemas).
//! - [`client`]: the robot-client seam (`arci`-style trait, the WebSocket implementation over
//!   the hub, a recording fake, a URDF limit-checking decorator).
//! - [`hub`]: connected workers, the dispatcher over the SQLite queue
//!   ([`crate::store::executions`]), one task per connection.
//! - [`sim`] + [`worker`]: the reference worker (`reachgrasp bridge --sim`).
//!
//! Other resources queue executions with [`enqueue`] (the plans endpoint does).

pub mod client;
pub mod hub;
pub mod protocol;
pub mod sim;
pub mod worker;

pub use client::{
    Completion, FakeClient, Finished, HubClient, JointLimits, LimitChecked, Rejected, Trajectory,
    TrajectoryClient,
};
pub use hub::{Hub, HubSettings, StreamHandle, StreamSend, TrackingSummary, WorkerSnapshot};
pub use protocol::{ExecutionPayload, Mode, PhysicsScene, PhysicsTrial, RequestedMode, TrialSpec};

use crate::store::library::LibraryError;

/// Most points an execution's trajectory may have (10 min at 100 Hz + margin).
pub const MAX_POINTS: usize = 100_000;

/// A bridge worker's name: 1-64 letters, digits, `-`, `_` or `.` (checked once, here).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct WorkerName(String);

impl WorkerName {
    pub fn parse(name: &str) -> Result<WorkerName, BridgeError> {
        let ok = (1..=64).contains(&name.len())
            && name
                .bytes()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, b'-' | b'_' | b'.'));
        if ok {
            Ok(WorkerName(name.to_owned()))
        } else {
            Err(BridgeError::InvalidWorkerName(name.to_owned()))
        }
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Display for WorkerName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// The part of a payload a [`PayloadIssue`] is about; the caller knows where that part came
/// from in its own input and names it there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PayloadPart {
    /// The execution mode asked for.
    Mode,
    JointNames,
    Points,
    Goal,
    /// A stream's settings.
    Stream,
}

/// One problem with a payload: its part, where inside it (`[3].positions[2]`, or empty), and
/// what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PayloadIssue {
    pub part: PayloadPart,
    pub at: String,
    pub message: String,
}

impl PayloadIssue {
    fn new(part: PayloadPart, at: impl Into<String>, message: impl Into<String>) -> Self {
        PayloadIssue {
            part,
            at: at.into(),
            message: message.into(),
        }
    }
}

/// What the bridge layer reports; the API turns it into problem+json.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BridgeError {
    #[error("unknown robot '{0}'")]
    UnknownRobot(String),
    #[error("'{0}' is not a worker name (1-64 letters, digits, '-', '_', '.')")]
    InvalidWorkerName(String),
    #[error("the payload does not fit the robot: {}", .0.first().map_or("", |i| i.message.as_str()))]
    InvalidPayload(Vec<PayloadIssue>),
    /// No connected worker can take a stream now (none with the capability, or all busy).
    #[error("{0}")]
    NoWorker(String),
    #[error("no execution '{0}'")]
    UnknownExecution(String),
    #[error("execution {id} has already finished ({state})")]
    AlreadyFinished {
        id: String,
        state: crate::store::executions::ExecutionState,
    },
    #[error(transparent)]
    Store(#[from] sqlx::Error),
    #[error(transparent)]
    Library(LibraryError),
}

impl From<LibraryError> for BridgeError {
    fn from(e: LibraryError) -> Self {
        match e {
            LibraryError::UnknownRobot(id) => BridgeError::UnknownRobot(id),
            other => BridgeError::Library(other),
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
) -> Result<(), BridgeError> {
    use PayloadPart as P;
    let model = &system.model;
    let names = model.joint_names();
    let n = names.len();
    let (lo, hi) = (model.lower_limits(), model.upper_limits());
    let mut errors = Vec::new();
    if payload.mode() != mode {
        errors.push(PayloadIssue::new(
            P::Mode,
            "",
            format!(
                "a {} payload runs in {}, not {}",
                payload.kind(),
                payload.mode().as_str(),
                mode.as_str()
            ),
        ));
    }
    if payload.joint_names() != names {
        errors.push(PayloadIssue::new(
            P::JointNames,
            "",
            format!(
                "must be robot '{robot}''s joints in model order {names:?}, got {:?}",
                payload.joint_names()
            ),
        ));
        return Err(BridgeError::InvalidPayload(errors));
    }
    let outside = |q: &[f64]| {
        q.iter()
            .zip(lo.iter().zip(hi))
            .position(|(&x, (&l, &h))| x < l - 1e-9 || x > h + 1e-9)
    };
    match payload {
        ExecutionPayload::Trajectory { points, .. } => {
            if points.is_empty() || points.len() > MAX_POINTS {
                errors.push(PayloadIssue::new(
                    P::Points,
                    "",
                    format!("must have 1 to {MAX_POINTS} points, got {}", points.len()),
                ));
            }
            for (i, p) in points.iter().enumerate() {
                if errors.len() > 20 {
                    break;
                }
                let at = format!("[{i}]");
                for (field, v) in [
                    ("positions", &p.positions),
                    ("velocities", &p.velocities),
                    ("accelerations", &p.accelerations),
                ] {
                    if v.len() != n {
                        errors.push(PayloadIssue::new(
                            P::Points,
                            format!("{at}.{field}"),
                            format!("must have {n} values (one per joint), got {}", v.len()),
                        ));
                    } else if let Some(j) = v.iter().position(|x| !x.is_finite()) {
                        errors.push(PayloadIssue::new(
                            P::Points,
                            format!("{at}.{field}[{j}]"),
                            "must be a finite number",
                        ));
                    }
                }
                if !p.t.is_finite() || p.t < 0.0 {
                    errors.push(PayloadIssue::new(
                        P::Points,
                        format!("{at}.t"),
                        "must be finite and >= 0",
                    ));
                } else if i > 0 && p.t <= points[i - 1].t {
                    errors.push(PayloadIssue::new(
                        P::Points,
                        format!("{at}.t"),
                        format!("times must increase: {} after {}", p.t, points[i - 1].t),
                    ));
                }
                if p.positions.len() == n
                    && let Some(j) = outside(&p.positions)
                {
                    errors.push(PayloadIssue::new(
                        P::Points,
                        format!("{at}.positions[{j}]"),
                        format!(
                            "{} is outside joint '{}' limits [{}, {}]",
                            p.positions[j], names[j], lo[j], hi[j]
                        ),
                    ));
                }
            }
        }
        ExecutionPayload::Stream { hold_after_s, .. } => {
            if !(hold_after_s.is_finite() && (0.01..=10.0).contains(hold_after_s)) {
                errors.push(PayloadIssue::new(
                    P::Stream,
                    "hold_after_s",
                    format!("must be in [0.01, 10] s, got {hold_after_s}"),
                ));
            }
        }
        ExecutionPayload::Model { params, goal, .. } => {
            if params.n_joints() != n {
                errors.push(PayloadIssue::new(
                    P::JointNames,
                    "",
                    format!(
                        "the model's law covers {} joints, the robot has {n}",
                        params.n_joints()
                    ),
                ));
            }
            if goal.len() != n {
                errors.push(PayloadIssue::new(
                    P::Goal,
                    "",
                    format!("must have {n} values (one per joint), got {}", goal.len()),
                ));
            } else if let Some(j) = goal.iter().position(|x| !x.is_finite()) {
                errors.push(PayloadIssue::new(
                    P::Goal,
                    format!("[{j}]"),
                    "must be a finite number",
                ));
            } else if let Some(j) = outside(goal) {
                errors.push(PayloadIssue::new(
                    P::Goal,
                    format!("[{j}]"),
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
        Err(BridgeError::InvalidPayload(errors))
    }
}

/// Checks and queues an execution (stored in SQLite, dispatched when a worker is free);
/// returns its id. `hub` is anything that holds the hub (the service context does).
pub async fn enqueue(
    hub: &impl AsRef<Hub>,
    robot: &str,
    mode: Mode,
    payload: ExecutionPayload,
    worker: Option<WorkerName>,
) -> Result<String, BridgeError> {
    hub.as_ref().enqueue(robot, mode, payload, worker).await
}
