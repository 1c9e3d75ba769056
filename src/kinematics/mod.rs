//! Kinematics: URDF -> immutable `Model`; per-call scratch `Data`; FK, Jacobians, IK, manipulability.
//!
//! Conventions: the root frame of a model is the world origin; joint values in radians (revolute)
//! or metres (prismatic); `q` holds only the independent coordinates in [`Model::joint_names`]
//! order, mimic joints following `multiplier * q[driver] + offset`; 6-D quantities are ordered
//! linear then angular and expressed in the world frame.

mod algorithms;
mod error;
mod ik;
mod joint_vector;
pub mod manipulability;
mod mesh;
mod model;
#[cfg(test)]
mod robot_tests;
mod sincos;
mod system;
pub mod urdf;

pub use algorithms::{Data, add_point_jacobian_transpose, forward_kinematics, frame_jacobian};
pub use error::KinematicsError;
pub use ik::{IkOptions, IkPosture, IkReport, IkSolver, IkTarget};
pub use joint_vector::JointVector;
pub use manipulability::{
    Ellipsoid, force_transmission_ratio, manipulability, velocity_ellipsoid,
    velocity_transmission_ratio,
};
pub use model::{
    Actuation, Collision, FrameId, Joint, JointKind, JointLimits, Mimic, Model, ModelBuilder,
    Visual,
};
pub use system::{Finger, FingerSpec, Mount, SpreadPair, System, SystemDescriptor, UrdfSources};
pub use urdf::{
    DirMeshes, MapMeshes, MeshSource, NoMeshes, model_from_urdf_file, model_from_urdf_str,
};
