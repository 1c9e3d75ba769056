//! Human arm-hand model, anthropometry, demonstration formats, synthetic study generator
//! (paper §II-B, §II-D; DESIGN §4).
//!
//! # Frame conventions
//!
//! * **World / tracker frame.** Everything a demonstration carries and everything derived from it
//!   is expressed in the magnetic tracker's reference frame, in metres. The synthetic generator
//!   uses: origin on the table surface, `x` forward (away from the seated subject), `y` to the
//!   subject's left, `z` up.
//! * **Shoulder, elbow, wrist positions** are the joint centres measured by the three tracker
//!   sensors (the sensor-to-joint offset is assumed compensated by the acquisition software, as
//!   Liberty set-ups do with a per-sensor tip offset).
//! * **Wrist frame** (root of the hand model): origin at the wrist joint centre; `x` distal, from
//!   the wrist towards the middle-finger MCP joint; `z` the palmar normal (out of the palm);
//!   `y = z × x`, which points to the ulnar (little-finger) side of a right hand and to the radial
//!   (thumb) side of a left hand. The tracker's wrist sensor orientation *is* this frame (the
//!   sensor is mounted on the dorsum at the wrist and aligned with the third metacarpal).
//! * **Fingertip pose**: position of the tip of the distal phalanx; frame with `x` along the distal
//!   phalanx (pointing distally) and `z` the palmar (pad) normal of that phalanx.
//! * **Angles**: radians; flexion positive towards the palm; abduction positive away from the
//!   hand's middle axis (for the middle finger: towards the thumb); see [`model`] for every joint.
//! * **Quaternions** travel as `[w, x, y, z]`.

pub mod anthropometry;
pub mod csv;
pub mod demo;
pub mod derive;
pub mod error;
pub mod keypoints;
pub mod model;
pub mod resample;
pub mod storage;
pub mod synth;

pub use anthropometry::{ArmDims, FingerDims, HandDims};
pub use demo::{
    Demonstration, DemonstrationInput, GloveCalibration, GloveStream, Handedness, IngestSummary,
    KeypointStream, Labels, ObjectShape, ObjectSpec, Pose, Source, Subject, SyncOptions,
    TrackerStream, ingest,
};
pub use derive::HandKinematics;
pub use error::HumanError;
pub use keypoints::{KEYPOINT_COUNT, KEYPOINT_NAMES, KeypointFrame};
pub use model::{
    ARM_JOINTS, FINGER_NAMES, GLOVE_CHANNELS, HAND_DOF, JointSpec, arm_model, arm_spec, hand_model,
    hand_spec,
};
pub use storage::{FRAME_WIDTH, pack_frames, unpack_frames};
pub use synth::{
    ObjectKind, StudyConfig, generate_study, generate_study_with_progress, generate_trial,
};

use nalgebra::{Isometry3, Point3};

/// Derived human kinematics of one resampled frame, in the tracker (world) frame, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HumanFrame {
    /// Time on the common clock (the tracker's), seconds.
    pub t: f64,
    pub shoulder: Point3<f64>,
    pub elbow: Point3<f64>,
    /// Wrist frame (see the module documentation).
    pub wrist: Isometry3<f64>,
    /// Thumb, index, middle, ring, little: tip position and distal-phalanx frame
    /// (`x` along the distal phalanx, `z` the palmar normal).
    pub fingertips: [Isometry3<f64>; 5],
}

#[cfg(test)]
mod tests;
