//! Task-specific arm configurations and robust grasps (paper eq. 10-29).
//!
//! - [`objects`]: graspable objects as parry shapes with a pose and an optional support plane.
//! - [`indexes`]: manipulability, transmission ratios, TC/GC, grasp matrix, hand-object
//!   Jacobian, Q_DC and Q_AGP (eq. 12-21).
//! - [`clearance`]: the exact clearance of a trajectory in a grasp's scene.
//! - [`approach`]: the pre-grasp standoff and the approach phase of a plan's path.
//! - [`optimizer`]: the constrained problem of eq. 22-29 solved through [`crate::optim`],
//!   multi-start, best feasible result with every term and residual.

pub mod approach;
pub mod clearance;
pub mod indexes;
pub mod objects;
pub mod optimizer;
pub mod system;

pub use approach::{
    ApproachOptions, DEPARTURE_SHARE, PreGrasp, pre_grasp, shape_departure, shape_path,
};
pub use clearance::{
    Arrival, CLOSING_PRESS, ClearanceHit, PathClearance, PostureCollision, arrive_from_outside,
    avoid, closing_contacts, path_clearance, posture_collision, scene_checker,
};
pub use indexes::{Ellipsoids, Goal, TaskDirection, Transmission};
pub use objects::{Object, ObjectSpec, ShapeSpec, SupportPlane};
pub use optimizer::{
    Contact, DEFAULT_MAX_STARTS, ExactCheck, GoalRegion, GraspRequest, GraspResult, NamedJoint,
    QualityMeasure, Residuals, Terms, Weights, plan_grasp,
};
pub use system::{Finger, HandArm, JointValue, LinkSphere, SpreadOrder};

/// Errors of the grasp layer: bad requests, named by field and carrying the numbers.
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraspError {
    /// A length that must be positive is not.
    #[error("{field} must be a positive finite length, got {value}")]
    InvalidDimension {
        /// Field path.
        field: String,
        /// Value found.
        value: f64,
    },
    /// NaN or infinity where a number is required.
    #[error("{field} must be finite")]
    NonFinite {
        /// Field path.
        field: String,
    },
    /// A direction-like vector (orientation quaternion, plane normal) that is zero.
    #[error("{field} must not be the zero vector")]
    ZeroVector {
        /// Field path.
        field: String,
    },
    /// A mesh that cannot be parsed or indexed.
    #[error("malformed mesh: {reason}")]
    MalformedMesh {
        /// What is wrong.
        reason: String,
    },
    /// A mesh that is not a closed, consistently oriented 2-manifold.
    #[error("non-manifold mesh: {reason}")]
    NonManifoldMesh {
        /// What is wrong.
        reason: String,
    },
    /// A mesh over the size limit.
    #[error("mesh has {triangles} triangles, the limit is {limit}")]
    MeshTooLarge {
        /// Triangles found.
        triangles: usize,
        /// Limit.
        limit: usize,
    },
    /// A task direction that is zero or not finite.
    #[error("task_directions[{index}].direction must be a finite non-zero vector")]
    InvalidDirection {
        /// Index of the direction.
        index: usize,
    },
    /// A weight that is negative or not finite.
    #[error("weights.{field} must be finite and non-negative, got {value}")]
    InvalidWeight {
        /// Weight name.
        field: &'static str,
        /// Value found.
        value: f64,
    },
    /// A quality measure the hand cannot use.
    #[error("quality measure {measure} needs at least {needed} fingers, the hand has {fingers}")]
    UnusableQuality {
        /// Measure name.
        measure: &'static str,
        /// Fingers needed.
        needed: usize,
        /// Fingers of the hand.
        fingers: usize,
    },
    /// A request parameter out of range.
    #[error("{field}: {reason}")]
    InvalidParameter {
        /// Field path.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

impl From<crate::geometry::GeometryError> for GraspError {
    fn from(e: crate::geometry::GeometryError) -> Self {
        use crate::geometry::GeometryError as G;
        match e {
            G::InvalidDimension { field, value } => GraspError::InvalidDimension { field, value },
            G::NonFinite { field } => GraspError::NonFinite { field },
            G::MalformedMesh { reason } => GraspError::MalformedMesh { reason },
            G::NonManifoldMesh { reason } => GraspError::NonManifoldMesh { reason },
            G::MeshTooLarge { triangles, limit } => GraspError::MeshTooLarge { triangles, limit },
            // GeometryError is non_exhaustive only towards other crates; every variant is above.
        }
    }
}
