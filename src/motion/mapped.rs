//! Feeding the mapping's output and a robot's description into [`train`](super::train):
//! mapped trajectories become [`JointTrajectory`]s, the system gives the joint groups (arm, hand)
//! and the limits.

use super::{JointLimits, JointTrajectory};
use crate::kinematics::System;
use crate::mapping::MappedTrajectory;

/// Acceleration limit (rad/s², or m/s² for prismatic joints) used where the robot description
/// gives none: URDF has no acceleration limits and the system descriptors do not add them. 5 rad/s²
/// is below what the bundled arms' drives reach and well above the peak joint accelerations of
/// human reaching (≈ 2-3 rad/s² at 1 s movement times), so humanlike timings are rarely stretched.
pub const DEFAULT_ACCELERATION_LIMIT: f64 = 5.0;

/// Jerk limit (rad/s³) used where the robot description gives none (URDF has none, and neither
/// the WAM's nor the PA10's published data state one). Minimum-jerk human reaching peaks at
/// `60 d / T³`: 12 rad/s³ for a 1 rad joint motion in 1.7 s, 150 for 1.5 rad in 0.85 s. At 150 a
/// joint takes 1/30 s to reach the 5 rad/s² acceleration limit (no step changes of torque), and
/// the measured plans are slowed by jerk no more than by acceleration (at 50 jerk bound nearly
/// every plan of a 120-request survey). Configurable per model (`jerk_limit`).
pub const DEFAULT_JERK_LIMIT: f64 = 150.0;

/// Velocity limit used where the URDF gives none (a zero or missing `velocity` attribute).
pub const DEFAULT_VELOCITY_LIMIT: f64 = 1.0;

/// Position range used for unbounded (continuous) joints: one turn either way.
pub const UNBOUNDED_RANGE: f64 = 2.0 * std::f64::consts::PI;

impl From<&MappedTrajectory> for JointTrajectory {
    /// The same frames: `times`, and `positions` row-major in the mapping's joint order (the
    /// robot model's independent joints; check `joint_names` against the model before training).
    fn from(m: &MappedTrajectory) -> Self {
        JointTrajectory {
            times: m.times.clone(),
            positions: m.positions.clone(),
        }
    }
}

/// The joint groups of a system, each with its own PCA + NF: the arm's joints, then the hand's
/// independent joints (empty groups left out). The arm comes first so it drives the clock.
pub fn system_groups(system: &System) -> Vec<Vec<usize>> {
    [system.arm_joints.clone(), system.hand_joints.clone()]
        .into_iter()
        .filter(|g| !g.is_empty())
        .collect()
}

/// The motion layer's limits from the robot model (`Model` order): position and velocity limits
/// from the URDF (defaults above where absent or unbounded), one acceleration and one jerk limit
/// for all.
pub fn system_limits(system: &System, acceleration: f64, jerk: f64) -> JointLimits {
    let m = &system.model;
    let n = m.nq();
    let mut lower = m.lower_limits().to_vec();
    let mut upper = m.upper_limits().to_vec();
    for j in 0..n {
        if !lower[j].is_finite() {
            lower[j] = -UNBOUNDED_RANGE;
        }
        if !upper[j].is_finite() {
            upper[j] = UNBOUNDED_RANGE;
        }
    }
    let velocity = m
        .velocity_limits()
        .iter()
        .map(|&v| {
            if v > 0.0 && v.is_finite() {
                v
            } else {
                DEFAULT_VELOCITY_LIMIT
            }
        })
        .collect();
    JointLimits {
        lower,
        upper,
        velocity,
        acceleration: vec![acceleration; n],
        jerk: vec![jerk; n],
    }
}
