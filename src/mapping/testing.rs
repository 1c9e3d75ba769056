//! Test-only simple human arm: a reach-to-grasp in the tracker frame (x forward, y left, z up).
//!
//! Two-link arm (shoulder fixed) whose wrist follows a minimum-jerk path to a target, elbow placed
//! by a natural swivel (hanging down and out), hand frame turned so the palm faces the object,
//! fingertips on an arc across the hand closing with the grasp aperture. Used where the `human`
//! generator is not the subject of the test (goal/registration plumbing, continuity, limits).

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::human::HumanFrame;

pub const UPPER_ARM: f64 = 0.30;
pub const FOREARM: f64 = 0.26;

/// A reach of `duration` seconds sampled at `rate` Hz from a rest wrist position to `target`.
pub fn reach(target: Vector3<f64>, duration: f64, rate: f64) -> Vec<HumanFrame> {
    let shoulder = Point3::new(0.0, -0.18, 1.40);
    let rest = shoulder + Vector3::new(0.25, 0.02, -0.45);
    let n = (duration * rate).round() as usize + 1;
    (0..n)
        .map(|k| {
            let t = k as f64 / rate;
            let s = (t / duration).clamp(0.0, 1.0);
            // Minimum-jerk progress.
            let p = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
            let wrist = rest + (shoulder + target - rest) * p;
            frame(t, shoulder, wrist, 0.09 - 0.03 * p, p)
        })
        .collect()
}

fn frame(t: f64, shoulder: Point3<f64>, wrist: Point3<f64>, aperture: f64, p: f64) -> HumanFrame {
    // Elbow on the circle of the two-link arm, swivelled towards "down and out".
    let sw = wrist - shoulder;
    let d = sw.norm().min(UPPER_ARM + FOREARM - 1e-3);
    let axis = sw.normalize();
    let a = (UPPER_ARM * UPPER_ARM - FOREARM * FOREARM + d * d) / (2.0 * d);
    let r = (UPPER_ARM * UPPER_ARM - a * a).max(0.0).sqrt();
    let pref = Vector3::new(0.0, -0.4, -1.0);
    let perp = (pref - axis * pref.dot(&axis)).normalize();
    let elbow = shoulder + axis * a + perp * r;
    let wrist = elbow + (wrist - elbow).normalize() * FOREARM;

    // Hand frame: x distal (along the forearm, pitched down a little as the reach ends), z palmar
    // normal facing the body midline (+y), y = z × x (radial side for a right hand, up-ish).
    let x = ((wrist - elbow).normalize() + Vector3::new(0.0, 0.0, -0.2 * p)).normalize();
    let z0 = Vector3::y();
    let z = (z0 - x * z0.dot(&x)).normalize();
    let y = z.cross(&x);
    let hand = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
        Matrix3::from_columns(&[x, y, z]),
    ));
    let wrist_iso = Isometry3::from_parts(Translation3::from(wrist.coords), hand);

    // Fingertips in the hand frame: thumb on the palmar side of the radial edge, the four
    // fingers on an arc across the hand, curling towards the palm as the aperture closes.
    let curl = 0.5 + 6.0 * (0.09 - aperture);
    let tip = |x_h: f64, y_h: f64, z_h: f64, flex: f64| {
        let local = Isometry3::from_parts(
            Translation3::new(x_h, y_h, z_h),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -flex),
        );
        wrist_iso * local
    };
    let fingertips = [
        tip(0.11, 0.045, 0.5 * aperture + 0.01, 0.2),
        tip(0.175, 0.025, 0.02 * curl, 0.6 * curl),
        tip(0.185, 0.005, 0.022 * curl, 0.6 * curl),
        tip(0.175, -0.015, 0.02 * curl, 0.6 * curl),
        tip(0.155, -0.032, 0.017 * curl, 0.6 * curl),
    ];
    HumanFrame {
        t,
        shoulder,
        elbow,
        wrist: wrist_iso,
        fingertips,
    }
}
