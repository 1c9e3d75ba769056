//! Exact geometry: shapes, the scene in the robot base frame, the robot's collision shapes posed
//! by forward kinematics, allowed contacts, and exact signed distances between them (parry3d),
//! at a posture and continuously along a joint-space path.
//!
//! - [`shapes`]: shape specs shared by objects and obstacles (primitives, closed meshes, OBJ/STL).
//! - [`Scene`]: object, support plane (the half-space below it is solid), obstacles.
//! - [`RobotGeometry`]: `Model::collisions()` with link, finger, rigid body and speed bounds.
//! - [`CollisionChecker`]: every robot-scene and non-adjacent robot-robot pair, an
//!   [`AllowedContacts`] list, [`CollisionChecker::clearance`] (smallest signed distance overall
//!   and per [`Category`], pair and witness points) and [`CollisionChecker::check_path`]
//!   (conservative advancement along a [`JointPath`]).
//!
//! Units and signs: metres; a signed distance is positive when separated and negative when
//! penetrating (the penetration depth); witness points are world (robot base frame) points.
//! Immutable parts (`RobotGeometry`, `CollisionChecker`) are shared; per-thread scratch is a
//! [`CheckData`], so posture queries on primitives allocate nothing.

pub mod avoid;
pub mod barrier;
mod checker;
mod epa;
mod path;
mod robot;
mod scene;
pub mod shapes;
mod solid;
#[cfg(test)]
mod survey;
#[cfg(test)]
mod tests;

pub use checker::{
    AllowedContacts, Category, CheckData, Clearance, Closest, CollisionChecker, Member, Pair,
    PairLabel, Target,
};
pub use path::{JointPath, PathHit, PathOptions, PathReport, Polyline};
pub use robot::{LinkShape, RobotGeometry};
pub use scene::{ObstacleSpec, Plane, Scene, SceneShape, pose_from_parts};
pub use shapes::{
    BuiltShape, MAX_MESH_TRIANGLES, ShapeSpec, SupportPlane, build_shape, parse_obj, parse_stl,
};
pub use solid::{
    HalfSpace, QueryScratch, SignedDistance, Solid, half_space_distance, signed_distance,
};
/// Errors of the geometry layer: bad shape or scene input, named by field, carrying the numbers.
#[non_exhaustive]
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
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
}
