//! The kinematics layer's error type: every variant names the joint, link, frame or field at fault
//! and carries the offending numbers, so the API layer can turn it into a precise problem+json.

use thiserror::Error;

/// Everything that can go wrong while building, loading or querying a kinematic model.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum KinematicsError {
    // ---- model construction -------------------------------------------------------------
    #[error("frame '{name}' is defined twice")]
    DuplicateFrame { name: String },
    #[error("joint '{name}' is defined twice")]
    DuplicateJoint { name: String },
    #[error("joint '{joint}' names parent frame #{parent}, which does not exist")]
    UnknownParentFrame { joint: String, parent: usize },
    #[error("joint '{joint}' has a zero-length axis")]
    ZeroAxis { joint: String },
    #[error("joint '{joint}': lower limit {lower} is above upper limit {upper}")]
    LimitsInverted {
        joint: String,
        lower: f64,
        upper: f64,
    },
    #[error("joint '{joint}': {field} must be non-negative, got {value}")]
    NegativeLimit {
        joint: String,
        field: &'static str,
        value: f64,
    },
    #[error("{path}: number is not finite ({value})")]
    NonFinite { path: String, value: f64 },
    #[error("joint '{joint}' mimics joint '{mimicked}', which does not exist")]
    MimicUnknownJoint { joint: String, mimicked: String },
    #[error("joint '{joint}' mimics joint '{mimicked}', which does not move (fixed)")]
    MimicOfFixed { joint: String, mimicked: String },
    #[error("joint '{joint}' is fixed but declares a mimic")]
    FixedJointMimic { joint: String },
    #[error("mimic chain through joint '{joint}' is a cycle")]
    MimicCycle { joint: String },

    // ---- URDF / files -------------------------------------------------------------------
    #[error("URDF is {size} bytes, over the limit of {limit} bytes")]
    UrdfTooLarge { size: usize, limit: usize },
    #[error("malformed URDF: {message}")]
    MalformedUrdf { message: String },
    #[error("joint '{joint}' names {role} link '{link}', which does not exist")]
    MissingLink {
        joint: String,
        role: &'static str,
        link: String,
    },
    #[error("URDF has several root links: {}", quoted(roots))]
    SeveralRoots { roots: Vec<String> },
    #[error("URDF has no root link (the joints form a cycle through link '{link}')")]
    Cycle { link: String },
    #[error(
        "joint '{joint}' has type '{kind}', which is not supported (revolute, continuous, prismatic, fixed)"
    )]
    UnsupportedJoint { joint: String, kind: String },
    #[error("link '{link}' has two parent joints ('{first}' and '{second}')")]
    TwoParents {
        link: String,
        first: String,
        second: String,
    },
    #[error("link '{link}': mesh '{path}' could not be read: {reason}")]
    MeshUnreadable {
        link: String,
        path: String,
        reason: String,
    },
    #[error("link '{link}': mesh '{path}' is malformed: {reason}")]
    MeshMalformed {
        link: String,
        path: String,
        reason: String,
    },
    #[error("link '{link}': {reason}")]
    BadGeometry { link: String, reason: String },
    #[error("file '{path}' could not be read: {reason}")]
    FileUnreadable { path: String, reason: String },

    // ---- system descriptors -------------------------------------------------------------
    #[error("descriptor field '{field}': {reason}")]
    Descriptor { field: String, reason: String },
    #[error("descriptor field '{field}': frame '{name}' does not exist in the model")]
    UnknownFrame { field: String, name: String },
    #[error("descriptor field '{field}': joint '{name}' is not an independent joint of the model")]
    UnknownJointInDescriptor { field: String, name: String },

    // ---- joint vectors ------------------------------------------------------------------
    #[error("joint vector has {got} values, the model has {expected} independent joints")]
    WrongLength { expected: usize, got: usize },
    #[error("joint vector names unknown joint '{name}' (the robot's joints: {known})")]
    UnknownJoint { name: String, known: String },
    #[error("joint vector names joint '{name}' twice")]
    RepeatedJoint { name: String },
    #[error("joint vector is missing joint '{name}'")]
    MissingJoint { name: String },
    #[error("joint '{joint}' value is not finite ({value})")]
    NonFiniteJointValue { joint: String, value: f64 },
}

/// Rejects NaN and infinities with the field path in the message.
pub(crate) fn check_finite(
    path: impl FnOnce() -> String,
    value: f64,
) -> Result<f64, KinematicsError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(KinematicsError::NonFinite {
            path: path(),
            value,
        })
    }
}

fn quoted(names: &[String]) -> String {
    names
        .iter()
        .map(|n| format!("'{n}'"))
        .collect::<Vec<_>>()
        .join(", ")
}
