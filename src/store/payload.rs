//! What an execution carries (a trajectory or a model's control law), as queued in the
//! `executions` table and sent to bridge workers in `execute` messages. It lives with the store
//! because the queue persists it; [`crate::bridge::protocol`] re-exports it for the wire.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::motion::{ControlParams, TrajectoryPoint};

/// Execution mode.
// Stored (the `executions.mode` column) and sent as its snake_case name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema, sqlx::Type)]
#[serde(rename_all = "snake_case")]
#[sqlx(rename_all = "snake_case")]
pub enum Mode {
    /// Follow the forwarded trajectory (feedforward velocity + proportional tracking).
    OpenLoop,
    /// Run the model's closed-loop law `u(q)` on the measured state until the goal is reached.
    ClosedLoop,
    /// Follow joint setpoints streamed live (teleoperation: the retargeting WebSocket with
    /// `forward=true` sends each retargeted frame); never queued, it starts on an idle worker
    /// at once and ends when the stream does.
    Streaming,
}

/// The mode a plan or an execution request asks for (a streaming execution starts only from
/// the retargeting WebSocket, `GET /v1/robots/{id}/retarget?forward=true`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum RequestedMode {
    OpenLoop,
    ClosedLoop,
}

impl From<RequestedMode> for Mode {
    fn from(m: RequestedMode) -> Mode {
        match m {
            RequestedMode::OpenLoop => Mode::OpenLoop,
            RequestedMode::ClosedLoop => Mode::ClosedLoop,
        }
    }
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::OpenLoop => "open_loop",
            Mode::ClosedLoop => "closed_loop",
            Mode::Streaming => "streaming",
        }
    }
}

/// One timed point of a trajectory (the schema of `motion::TrajectoryPoint`): joint values in
/// the order of the trajectory's `joint_names`, radians (metres for prismatic joints), seconds.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryPointSchema {
    /// Time from the trajectory's start (s).
    pub t: f64,
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
}

/// What an execution runs: its own resolved copy, stored with the execution.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ExecutionPayload {
    /// A timed trajectory (open loop).
    Trajectory {
        /// Stored trajectory id, or `inline` for a trajectory given in the request.
        trajectory_id: String,
        joint_names: Vec<String>,
        #[schema(value_type = Vec<TrajectoryPointSchema>)]
        points: Vec<TrajectoryPoint>,
    },
    /// The model's closed-loop law and a goal (closed loop).
    Model {
        model_id: String,
        /// `ControlParams` of the model (as `GET /v1/models/{id}/params` returns them).
        params: ControlParams,
        /// Goal joint values in the order of `params.joint_names`.
        goal: Vec<f64>,
        /// The scene the law must keep clear of, for the worker's safety filter (absent: no
        /// scene, the plain law). A worker runs such a payload only if it announced the
        /// `safety_filter` capability.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        safety: Option<Box<SafetySpec>>,
        /// The open-loop motion the law runs (issue 19, "one motion"): the timed humanlike path
        /// the model generated for this start and goal, ending at `goal`. The worker follows it
        /// with a governed clock (`motion::PathFollower`: the clock waits while the robot is
        /// off the path, so after a push the motion resumes where it left the path) instead of
        /// running the bare law; a plan's closed loop and a stored trajectory run in closed
        /// loop carry it. A worker runs such a payload only if it announced `path_following`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        #[schema(value_type = Option<Vec<TrajectoryPointSchema>>)]
        path: Option<Vec<TrajectoryPoint>>,
    },
    /// Live joint setpoints (streaming): the worker receives them as `setpoint` messages after
    /// the `execute`, moves toward the latest one within its joint limits, holds where it is
    /// when none arrived for `hold_after_s`, and ends the execution on `end` (succeeded) or
    /// `cancel` (aborted).
    Stream {
        /// Where the setpoints come from (`retarget`: the retargeting WebSocket).
        source: String,
        joint_names: Vec<String>,
        /// The worker brakes to a stop when no setpoint arrived for this long, s (a lost
        /// teleoperation link must not leave the robot moving).
        hold_after_s: f64,
    },
}

/// The default of [`ExecutionPayload::Stream`]'s `hold_after_s`, s: a few frames of a 30-100 Hz
/// tracker.
pub const DEFAULT_HOLD_AFTER: f64 = 0.2;

/// What a worker's control-barrier-function safety filter keeps the closed-loop law clear of
/// (issue 18, `geometry::barrier`): the plan's object on its support, its obstacles
/// (robot base frame), and the filter's margins and gain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SafetySpec {
    /// The grasped object as the grasp was computed, with its support plane.
    pub object: Option<crate::grasp::ObjectSpec>,
    /// Further obstacles of the plan.
    #[serde(default)]
    pub obstacles: Vec<crate::geometry::ObstacleSpec>,
    /// Clearance kept from the object, the support and obstacles, m.
    pub margin_m: f64,
    /// Clearance kept between two links, m.
    pub self_margin_m: f64,
    /// Barrier gain `α`, 1/s (how fast a barrier may fall near its target, and how fast a
    /// pushed-in pair is driven back out).
    pub rate: f64,
    /// Deceleration the approach to a barrier is limited to farther out, m/s².
    pub braking_m_s2: f64,
    /// The grasp's pre-grasp (joint values in the model's order: the palm backed off along the
    /// approach direction, the hand opened). With it the worker runs the law in three stages,
    /// as the open-loop trajectory's approach phase moves: to the pre-grasp, then the arm to
    /// the grasp with the hand still open, then the hand closes. The law's own flow closes the
    /// hand while the arm is still on its way, through the object. Ignored with a `path` (which
    /// has the approach in it); plans send a path and no pre-grasp.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pre_grasp: Option<Vec<f64>>,
}

impl SafetySpec {
    /// The default filter around `object` and `obstacles`.
    pub fn new(
        object: Option<crate::grasp::ObjectSpec>,
        obstacles: Vec<crate::geometry::ObstacleSpec>,
    ) -> SafetySpec {
        let o = crate::geometry::barrier::BarrierOptions::default();
        SafetySpec {
            object,
            obstacles,
            margin_m: o.margin,
            self_margin_m: o.self_margin,
            rate: o.rate,
            braking_m_s2: o.braking,
            pre_grasp: None,
        }
    }

    /// The filter options these values give.
    pub fn options(&self) -> crate::geometry::barrier::BarrierOptions {
        crate::geometry::barrier::BarrierOptions {
            margin: self.margin_m,
            self_margin: self.self_margin_m,
            rate: self.rate,
            braking: self.braking_m_s2,
            ..crate::geometry::barrier::BarrierOptions::default()
        }
    }
}

/// A grasp trial in physics after the motion (issue 24): the scene the worker simulates and the
/// trial it runs there. Stored with the execution (its own copy: a later change of the object
/// never changes it) and sent in the `execute` message; such an execution goes only to a worker
/// with the `grasp_trial` capability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PhysicsTrial {
    pub scene: PhysicsScene,
    #[serde(default)]
    pub trial: TrialSpec,
    /// Fingers the trial does not close: the grasp's idle fingers, kept off the object (closing
    /// them would push it out of the others' pinch). Absent: every finger closes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub idle_fingers: Vec<String>,
}

/// What a physics worker builds around the robot (robot base frame): the object with its mass
/// and friction, the support plane it rests on, and further static obstacles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PhysicsScene {
    /// The grasped object as the grasp was computed; `mass` and `friction` are present.
    pub object: crate::grasp::ObjectSpec,
    /// The plane the object rests on (its `friction` absent: 0.5).
    pub support: Option<crate::geometry::SupportPlane>,
    #[serde(default)]
    pub obstacles: Vec<crate::geometry::ObstacleSpec>,
}

/// The grasp trial's moves after the hand has closed: lift the hand, hold, shake.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TrialSpec {
    /// How far the hand lifts the object, m, in (0, 0.3]; held means at least half of it.
    #[schema(exclusive_minimum = 0, maximum = 0.3)]
    pub lift: f64,
    /// How long the lifted object is held still, s, in [0, 10].
    #[schema(minimum = 0, maximum = 10)]
    pub hold_s: f64,
    /// Shakes after the hold (one along y, one along z, then alternating), 0 to 4.
    #[schema(minimum = 0, maximum = 4)]
    pub shakes: u32,
}

impl Default for TrialSpec {
    /// The grasp-synthesis field's lift-and-shake test: 10 cm, 2 s, two shakes.
    fn default() -> Self {
        TrialSpec {
            lift: 0.10,
            hold_s: 2.0,
            shakes: 2,
        }
    }
}

impl TrialSpec {
    /// The first field out of range, with what is wrong (`None`: valid).
    pub fn invalid_field(&self) -> Option<(&'static str, String)> {
        if !(self.lift.is_finite() && self.lift > 0.0 && self.lift <= 0.3) {
            return Some(("lift", format!("{} is not in (0, 0.3] m", self.lift)));
        }
        if !(self.hold_s.is_finite() && (0.0..=10.0).contains(&self.hold_s)) {
            return Some(("hold_s", format!("{} is not in [0, 10] s", self.hold_s)));
        }
        if self.shakes > 4 {
            return Some(("shakes", format!("{} is more than 4", self.shakes)));
        }
        None
    }
}

impl ExecutionPayload {
    pub fn joint_names(&self) -> &[String] {
        match self {
            ExecutionPayload::Trajectory { joint_names, .. } => joint_names,
            ExecutionPayload::Model { params, .. } => &params.joint_names,
            ExecutionPayload::Stream { joint_names, .. } => joint_names,
        }
    }

    /// The mode this payload can run in.
    pub fn mode(&self) -> Mode {
        match self {
            ExecutionPayload::Trajectory { .. } => Mode::OpenLoop,
            ExecutionPayload::Model { .. } => Mode::ClosedLoop,
            ExecutionPayload::Stream { .. } => Mode::Streaming,
        }
    }

    /// The path a closed-loop law follows (see [`ExecutionPayload::Model`]).
    pub fn law_path(&self) -> Option<&[TrajectoryPoint]> {
        match self {
            ExecutionPayload::Model { path, .. } => path.as_deref(),
            ExecutionPayload::Trajectory { .. } | ExecutionPayload::Stream { .. } => None,
        }
    }

    /// The safety filter this payload asks for (closed loop in a scene).
    pub fn safety(&self) -> Option<&SafetySpec> {
        match self {
            ExecutionPayload::Model { safety, .. } => safety.as_deref(),
            ExecutionPayload::Trajectory { .. } | ExecutionPayload::Stream { .. } => None,
        }
    }

    /// `trajectory`, `model` or `stream`.
    pub fn kind(&self) -> &'static str {
        match self {
            ExecutionPayload::Trajectory { .. } => "trajectory",
            ExecutionPayload::Model { .. } => "model",
            ExecutionPayload::Stream { .. } => "stream",
        }
    }

    /// The stored trajectory or model id (`inline` for an inline trajectory; a stream's
    /// source).
    pub fn source_id(&self) -> &str {
        match self {
            ExecutionPayload::Trajectory { trajectory_id, .. } => trajectory_id,
            ExecutionPayload::Model { model_id, .. } => model_id,
            ExecutionPayload::Stream { source, .. } => source,
        }
    }
}
