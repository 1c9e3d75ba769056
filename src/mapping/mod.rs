//! Human to humanlike robot motion mapping (paper eq. 1-7).
//!
//! Per frame: register the human data into the robot base frame ([`registration`]), assign the
//! fingertip goals ([`goals`]), and minimise `F = w_x·P + w_o·Σ d_o + w_D·D` (eq. 1-5) over the
//! independent joint coordinates inside the joint limits (eq. 6-7).

pub mod goals;
pub mod registration;

pub use goals::{CatmullRom4, FingerGoal, MAX_FINGERS};
pub use registration::{ArmPoints, BodyAxes, Registration, RegistrationSpec, RobotAnchor, Scale};

/// Everything that can go wrong in the mapping layer; the API turns it into 4xx problem+json.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MappingError {
    #[error("the demonstration has no frames")]
    EmptyDemonstration,
    #[error("frame {frame}: {field} is not finite")]
    NonFinite { frame: usize, field: &'static str },
    #[error(
        "frame {frame}: the human {segment} has length {length} m; the arm cannot be registered"
    )]
    DegenerateArm {
        frame: usize,
        segment: &'static str,
        length: f64,
    },
    #[error("registration: {reason}")]
    InvalidRegistration { reason: String },
    #[error("scale must be a positive finite number, got {value}")]
    InvalidScale { value: f64 },
}
