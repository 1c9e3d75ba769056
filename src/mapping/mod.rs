//! Human to humanlike robot motion mapping (paper eq. 1-7).
//!
//! Per frame: register the human data into the robot base frame ([`registration`]), assign the
//! fingertip goals ([`goals`]), and minimise `F = w_x·P + w_o·Σ d_o + w_D·D` (eq. 1-5) over the
//! independent joint coordinates inside the joint limits (eq. 6-7).
//!
//! - Couplings (eq. 26, URDF mimics) are substituted: the variables are the model's independent
//!   coordinates, and each driver's bounds are tightened by the limits of the joints it drives.
//! - Spread ordering (eq. 28): an ordering within one coordinate (the iHY's mirrored spread) is a
//!   bound; between two coordinates it is part of the feasible set, projected onto exactly
//!   (see [`crate::optim::OrderedBox`]) — a constraint, not a reparametrisation, so bounds stay simple boxes.
//! - Solver: PANOC (optimization_engine) per frame through the `optim` adapter's allocation-free
//!   entry ([`crate::optim::BoxSolver`]), warm-started; see [`solve`].
//!
//! Typical use: `MappingModel::from_system(&system)`, `anchor()`, then one [`Mapper`] per worker
//! (`Mapper::map(frames, &RegistrationSpec::default(), &anchor)`), or [`map_batch`] for many
//! demonstrations across threads. A batch is mapped consistently: every demonstration's first
//! frame is solved locally from the nearest already-solved first frame ([`batch_starts`],
//! [`Mapper::map_from`]), so one posture branch serves every subject and trial; a
//! demonstration mapped alone starts from its own multi-start solution.

pub mod goals;
pub mod objective;
pub mod registration;
pub mod retarget;
pub mod solve;
#[cfg(test)]
mod tests;
pub mod trajectory;

pub use goals::{CatmullRom4, FingerGoal, MAX_FINGERS};
pub use objective::{
    ArmFrames, Evaluator, FrameGoals, MappingModel, Objective, Term, Weights, quaternion_distance,
    swivel_angle, swivel_direction,
};
pub use registration::{
    ArmPoints, BodyAxes, HumanObject, Registration, RegistrationSpec, RobotAnchor, Scale,
    SceneRegistration, human_object,
};
pub use retarget::{RetargetError, RetargetOptions, RetargetStep, Retargeter};
pub use solve::{
    FIRST_FRAME_FALLBACK, FrameMetrics, Mapper, SolverOptions, StartReference,
    elbow_circle_distance,
};
pub use trajectory::{
    BatchItem, Cancelled, MappedTrajectory, batch_starts, map_batch, registration_for,
    resample_frames, scene_of, shape_spec,
};

/// Everything that can go wrong in the mapping layer; the API turns it into 4xx problem+json.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MappingError {
    #[error("the demonstration has no frames")]
    EmptyDemonstration,
    #[error("frame {frame}: {field} is not finite")]
    NonFinite { frame: usize, field: &'static str },
    #[error(
        "frame {frame}: the human {segment} has length {length} m; the arm cannot be registered \
         (a keypoint recording without elbow and shoulder maps only onto a hand on a fixed base)"
    )]
    DegenerateArm {
        frame: usize,
        segment: &'static str,
        length: f64,
    },
    #[error("registration: {reason}")]
    InvalidRegistration { reason: String },
    #[error("placement: {reason}")]
    InvalidPlacement { reason: String },
    #[error("{field} must be a positive finite number, got {value}")]
    InvalidFactor { field: &'static str, value: f64 },
    #[error("scale must be a positive finite number, got {value}")]
    InvalidScale { value: f64 },
    #[error("weight `{field}` must be finite and non-negative, got {value}")]
    InvalidWeight { field: &'static str, value: f64 },
    #[error("at least one weight must be positive")]
    AllWeightsZero,
    #[error("solver option `{field}` is invalid: {value}")]
    InvalidOption { field: &'static str, value: f64 },
    #[error("frame {frame}: time {t} does not increase past the previous frame's {previous}")]
    NonIncreasingTime { frame: usize, t: f64, previous: f64 },
    #[error(
        "joint `{joint}`: its limits and those of the joints it drives leave no range ({lower} > {upper})"
    )]
    EmptyJointRange {
        joint: String,
        lower: f64,
        upper: f64,
    },
    #[error("spread pair `{lower}` <= `{upper}` can never hold")]
    InfeasibleSpreadPair { lower: String, upper: String },
    #[error("spread pairs: {reason}")]
    UnsupportedSpreadPairs { reason: String },
    #[error("hand with {fingers} fingers and thumb {thumb} is not supported (1..=5 fingers)")]
    UnsupportedHand { fingers: usize, thumb: usize },
}
