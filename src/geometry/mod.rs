//! Exact geometry shared by grasps, mappings and trajectories (parry3d).
//!
//! - [`shapes`]: shape specs shared by objects and obstacles (primitives, closed meshes, OBJ/STL).

pub mod shapes;

pub use shapes::{
    BuiltShape, MAX_MESH_TRIANGLES, ShapeSpec, SupportPlane, build_shape, parse_obj, parse_stl,
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
