//! The bridge wire protocol (version [`PROTOCOL_VERSION`]): JSON text frames over the WebSocket
//! at `/v1/bridges/connect`, each an object whose `type` names the message.
//!
//! Worker → service: [`WorkerMessage`] (`hello`, `heartbeat`, `feedback`, `result`).
//! Service → worker: [`ServiceMessage`] (`welcome`, `execute`, `cancel`, `error`, and for a
//! streaming execution `setpoint` and `end`).
//!
//! The first frame a worker sends is `hello`, carrying the protocol version it speaks; the
//! service answers `welcome` (or `error` with `fatal: true` and closes). These types are shared
//! by the service and the reference worker, and their schemas are in the OpenAPI document.
//! Pure data: no I/O here.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

#[cfg(test)]
use crate::motion::TrajectoryPoint;

/// The protocol version this build speaks (in `hello` and `welcome`).
pub const PROTOCOL_VERSION: u32 = 1;

/// Largest frame a worker may send (feedback and hello are small; a larger frame is refused
/// and the connection closed).
pub const MAX_WORKER_MESSAGE_BYTES: usize = 64 * 1024;

pub use crate::store::payload::{
    ExecutionPayload, Mode, PhysicsScene, PhysicsTrial, RequestedMode, TrajectoryPointSchema,
    TrialSpec,
};

/// What a worker can do (announced in `hello`); executions are only sent to a worker with the
/// capability of their mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Capability {
    OpenLoop,
    ClosedLoop,
    /// Runs a closed-loop law through the control-barrier-function safety filter of its
    /// payload's `safety` scene (a payload with a scene goes only to such a worker).
    SafetyFilter,
    /// Runs a closed-loop law along its payload's `path` (the open-loop humanlike motion,
    /// with a clock that waits while the robot is off it): a payload with a path goes only to
    /// such a worker. Added to protocol version 1 like `streaming`.
    PathFollowing,
    /// Follows live joint setpoints (a `stream` payload, then `setpoint` messages until `end`):
    /// teleoperation from the retargeting WebSocket. Added to protocol version 1 without a
    /// version change: a worker that does not announce it never receives either message.
    Streaming,
    /// Simulates the motion with contacts and then runs a grasp trial (close, lift, hold,
    /// shake) in the `execute` message's `scene`: executions with a `trial` go only to such a
    /// worker (a physics worker). Added to protocol version 1 like `streaming`.
    GraspTrial,
}

/// First message of a worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Hello {
    /// The protocol version the worker speaks (must be [`PROTOCOL_VERSION`]).
    pub protocol_version: u32,
    /// Unique name of the worker (1-64 characters: letters, digits, `-`, `_`, `.`).
    pub worker: String,
    /// Robot system id it drives (`GET /v1/robots`).
    pub robot: String,
    /// The system's independent joints in model order (as `GET /v1/robots/{id}` lists them).
    pub joint_names: Vec<String>,
    pub capabilities: Vec<Capability>,
    /// Largest joint deviation (rad) between the robot and a trajectory's first point that the
    /// worker accepts at the start of an execution. The service refuses (422) a plan with
    /// `execute: true` whose start is farther than this from where the worker will be; a
    /// worker that does not say gets [`DEFAULT_START_TOLERANCE`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_tolerance: Option<f64>,
}

/// The start tolerance assumed for a worker whose `hello` names none (rad; the reference
/// worker's default).
pub const DEFAULT_START_TOLERANCE: f64 = 0.25;

/// Liveness, sent every `heartbeat_interval_ms`; carries the measured positions so clients can
/// plan from the robot's current state (`GET /v1/bridges`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Heartbeat {
    pub seq: u64,
    #[serde(default)]
    pub positions: Vec<f64>,
}

/// Measured state during an execution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Feedback {
    pub execution_id: String,
    /// Seconds since the execution started on the worker.
    pub t: f64,
    /// Measured joint positions and velocities (joint order of the execution).
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    /// 0..1: time fraction of the trajectory (open loop) or of the initial distance to the goal
    /// covered (closed loop).
    pub progress: f64,
    /// Largest joint deviation from the reference (open loop) or from the goal (closed loop).
    pub tracking_error: f64,
}

/// How an execution ended on the worker.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Succeeded,
    Failed,
    /// Stopped before the end (a `cancel`, or the robot's own stop).
    Aborted,
}

/// The end of an execution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ExecutionResult {
    pub execution_id: String,
    pub outcome: Outcome,
    #[serde(default)]
    pub reason: Option<String>,
    /// Final measured positions.
    #[serde(default)]
    pub positions: Vec<f64>,
    /// What the safety filter did (a closed-loop law with a scene).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety: Option<SafetyReport>,
    /// A physics worker's report (the simulator, the motion in physics, the grasp trial; the
    /// MuJoCo worker's README has it in full). The service keeps what it reads of it
    /// ([`PhysicsSummary`]); a report it cannot read is dropped and the result still counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Object>)]
    pub physics: Option<serde_json::Value>,
}

/// What the service keeps of a physics worker's report: the simulator and the grasp trial's
/// verdict (`GET /v1/executions/{id}` under `tracking.physics`, and the execution's page).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct PhysicsSummary {
    /// The simulator, e.g. `mujoco`.
    pub engine: String,
    /// The grasp trial after the motion (absent when there was none: no object in the scene,
    /// or the motion did not arrive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trial: Option<TrialSummary>,
}

/// The grasp trial's verdict: close, lift, hold, two shakes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TrialSummary {
    /// The object is off the support, at least half the lift above where it started and
    /// touching the hand at the end.
    pub held: bool,
    /// The object moved more than the worker's threshold relative to the hand.
    pub slipped: bool,
    /// How far the object rose, m (the lift is 0.1 m).
    pub object_lift_m: f64,
    /// The object's displacement relative to the hand from the end of closing to the end, m.
    pub slip_m: f64,
    /// Mean total normal force on the object during the hold, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_force_total_mean_n: Option<f64>,
    /// Robot links touching the object after closing.
    #[serde(default)]
    pub contacts_after_close: Vec<String>,
    /// Share of the fingers' force limit the hand gripped with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grip: Option<f64>,
    /// The phase in which a slip raised the grip, if one did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grip_raised_in: Option<String>,
    /// Deepest overlap seen in the simulation, m, per pair kind (`hand_object`,
    /// `robot_support`, `object_support`, `robot_obstacle`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_penetration_m: Option<std::collections::BTreeMap<String, f64>>,
}

impl PhysicsSummary {
    /// What the service reads of a worker's report; None when it is not one.
    pub fn read(report: &serde_json::Value) -> Option<Self> {
        Self::deserialize(report).ok()
    }
}

/// The safety filter's account of a closed-loop execution (exact distances at the measured
/// states of the control periods; `geometry::barrier`). The filter monitors the pairs within
/// a few centimetres of their target; the distance fields are absent when none came that near.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct SafetyReport {
    /// Smallest barrier value `h = d − target` over the run, m: ≥ 0 when every monitored pair
    /// kept its target (the margin, falling to the grasp's own clearance near the goal); < 0
    /// after a push brought a pair inside it (the filter then drives it back out).
    pub min_barrier_m: Option<f64>,
    /// Smallest exact signed distance of a monitored pair, m (< 0: penetration; the grasp's
    /// fingertip contacts on the object at the goal are about 0).
    pub min_distance_m: Option<f64>,
    /// The robot link of `min_distance_m`.
    pub link: Option<String>,
    /// "object", "support", the obstacle's name or the other link's name.
    pub other: Option<String>,
    /// Time of `min_distance_m` from the execution's start, s.
    pub time_s: Option<f64>,
    /// Control periods run, and those in which the filter changed the law's command.
    pub periods: u64,
    pub filtered_periods: u64,
}

/// Messages a worker sends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum WorkerMessage {
    Hello(Hello),
    Heartbeat(Heartbeat),
    Feedback(Feedback),
    Result(ExecutionResult),
}

/// The service's answer to a valid `hello`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Welcome {
    pub protocol_version: u32,
    pub worker: String,
    /// Send a heartbeat at least this often.
    pub heartbeat_interval_ms: u64,
    /// A worker silent for this long is disconnected (its execution becomes `interrupted`).
    pub heartbeat_timeout_ms: u64,
}

/// Run an execution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Execute {
    pub execution_id: String,
    pub mode: Mode,
    pub payload: ExecutionPayload,
    /// The scene a physics worker simulates (robot base frame; sent with `trial`, only to a
    /// worker with the `grasp_trial` capability).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<Box<PhysicsScene>>,
    /// The grasp trial to run after the motion in `scene`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trial: Option<TrialSpec>,
    /// Fingers the trial leaves as they are instead of closing them: the grasp's idle fingers,
    /// kept off the object (absent: every finger closes).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub idle_fingers: Vec<String>,
}

/// The next joint setpoint of a streaming execution (sent as fast as the stream produces
/// them; the worker moves toward the latest within its limits and may skip stale ones).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Setpoint {
    pub execution_id: String,
    /// Consecutive from 0 within the execution (a gap: the service skipped a setpoint because
    /// the worker's outbox was full).
    pub seq: u64,
    /// Stream time of the setpoint, s (the retargeted frame's `t`).
    pub t: f64,
    /// Joint positions in the payload's `joint_names` order.
    pub positions: Vec<f64>,
    /// Feed-forward joint velocities (the finite difference to the previous setpoint; zero on
    /// the first).
    pub velocities: Vec<f64>,
}

/// The end of a streaming execution (the stream closed): the worker stops where it is and
/// answers with a `result`, outcome `succeeded`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct End {
    pub execution_id: String,
}

/// Stop an execution (the worker answers with a `result`, outcome `aborted`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct Cancel {
    pub execution_id: String,
}

/// Stable error codes of the `error` message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// Not JSON, a binary frame, or a known message with bad fields.
    Malformed,
    /// Larger than [`MAX_WORKER_MESSAGE_BYTES`].
    Oversized,
    /// `type` missing or not a worker message.
    UnknownType,
    /// `hello` with a protocol version the service does not speak.
    UnsupportedVersion,
    /// `hello` refused: unknown robot, wrong joint names, bad worker name or capabilities.
    HelloRefused,
    /// `hello` refused because a worker of that name is connected (retry later).
    NameInUse,
    /// A message out of order (anything before `hello`, a second `hello`).
    UnexpectedMessage,
    /// `feedback` or `result` for an execution the worker does not hold.
    NotHolding,
    /// Too many bad messages; the connection is closed.
    TooManyErrors,
    /// No heartbeat within the timeout.
    HeartbeatTimeout,
    /// The service is shutting down.
    ShuttingDown,
}

/// An error reply; with `fatal: true` the service closes the connection after sending it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ErrorReply {
    pub code: ErrorCode,
    pub message: String,
    pub fatal: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub execution_id: Option<String>,
}

/// Messages the service sends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServiceMessage {
    Welcome(Welcome),
    Execute(Execute),
    Cancel(Cancel),
    Error(ErrorReply),
    Setpoint(Setpoint),
    End(End),
}

/// Why a text frame is not a [`WorkerMessage`].
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeError {
    pub code: ErrorCode,
    pub message: String,
}

/// Parses a worker frame, telling unknown message types apart from malformed ones.
pub fn decode_worker_message(text: &str) -> Result<WorkerMessage, DecodeError> {
    if text.len() > MAX_WORKER_MESSAGE_BYTES {
        return Err(DecodeError {
            code: ErrorCode::Oversized,
            message: format!(
                "frame of {} bytes exceeds the limit of {MAX_WORKER_MESSAGE_BYTES}",
                text.len()
            ),
        });
    }
    match serde_json::from_str::<WorkerMessage>(text) {
        Ok(m) => Ok(m),
        Err(e) => {
            let value: serde_json::Value = serde_json::from_str(text).map_err(|e| DecodeError {
                code: ErrorCode::Malformed,
                message: format!("not JSON: {e}"),
            })?;
            let ty = value.get("type").and_then(|t| t.as_str());
            match ty {
                Some("hello" | "heartbeat" | "feedback" | "result") => Err(DecodeError {
                    code: ErrorCode::Malformed,
                    message: format!("invalid `{}` message: {e}", ty.unwrap_or_default()),
                }),
                Some(other) => Err(DecodeError {
                    code: ErrorCode::UnknownType,
                    message: format!(
                        "unknown message type `{other}` (hello, heartbeat, feedback, result)"
                    ),
                }),
                None => Err(DecodeError {
                    code: ErrorCode::UnknownType,
                    message: "the message has no string `type` field".into(),
                }),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip_with_a_type_tag() {
        let m = WorkerMessage::Feedback(Feedback {
            execution_id: "e".into(),
            t: 0.5,
            positions: vec![0.1, 0.2],
            velocities: vec![0.0, 0.0],
            progress: 0.25,
            tracking_error: 0.01,
        });
        let text = serde_json::to_string(&m).unwrap();
        assert!(text.contains("\"type\":\"feedback\""), "{text}");
        assert_eq!(decode_worker_message(&text).unwrap(), m);
        let s = ServiceMessage::Execute(Execute {
            execution_id: "e".into(),
            mode: Mode::OpenLoop,
            scene: None,
            trial: None,
            idle_fingers: Vec::new(),
            payload: ExecutionPayload::Trajectory {
                trajectory_id: "inline".into(),
                joint_names: vec!["a".into()],
                points: vec![TrajectoryPoint {
                    t: 0.0,
                    positions: vec![0.0],
                    velocities: vec![0.0],
                    accelerations: vec![0.0],
                }],
            },
        });
        let text = serde_json::to_string(&s).unwrap();
        assert!(text.contains("\"type\":\"execute\"") && text.contains("\"kind\":\"trajectory\""));
        assert_eq!(serde_json::from_str::<ServiceMessage>(&text).unwrap(), s);
    }

    #[test]
    fn bad_frames_are_classified() {
        assert_eq!(
            decode_worker_message("{not json").unwrap_err().code,
            ErrorCode::Malformed
        );
        assert_eq!(
            decode_worker_message(r#"{"type":"dance"}"#)
                .unwrap_err()
                .code,
            ErrorCode::UnknownType
        );
        assert_eq!(
            decode_worker_message(r#"{"seq":1}"#).unwrap_err().code,
            ErrorCode::UnknownType
        );
        let e = decode_worker_message(r#"{"type":"heartbeat","seq":"x"}"#).unwrap_err();
        assert_eq!(e.code, ErrorCode::Malformed);
        assert!(e.message.contains("heartbeat"), "{}", e.message);
        let big = format!(
            r#"{{"type":"heartbeat","seq":1,"pad":"{}"}}"#,
            "x".repeat(MAX_WORKER_MESSAGE_BYTES)
        );
        assert_eq!(
            decode_worker_message(&big).unwrap_err().code,
            ErrorCode::Oversized
        );
    }
}
