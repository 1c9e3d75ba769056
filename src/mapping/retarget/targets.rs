//! Reachable keypoint streams: the targets of the retargeting benchmark and tests (issue 22),
//! built the way the retargeting literature builds them — forward kinematics of a smooth random
//! joint trajectory of the robot hand — and turned into the 21 keypoints of a subject's hand
//! whose goal assignment (thumb to thumb, the spline for the rest, hand-only registration) gives
//! exactly those robot fingertips. A tool that maps fingertip positions directly can take
//! [`ReachableStream::targets`]; ours takes [`ReachableStream::frames`].

use std::f64::consts::PI;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use crate::human::keypoints::{DISTAL_JOINTS, KEYPOINT_COUNT, KeypointFrame, TIPS};
use crate::kinematics::{Data, System, forward_kinematics};
use crate::mapping::goals::{FingerGoal, MAX_FINGERS, finger_goals};
use crate::mapping::registration::hand_alignment;
use crate::mapping::{MappingError, MappingModel};

/// A keypoint stream with its targets.
#[derive(Debug, Clone)]
pub struct ReachableStream {
    pub frames: Vec<KeypointFrame>,
    /// The robot fingertip positions each frame's goals are (robot base frame, finger order).
    pub targets: Vec<[Point3<f64>; MAX_FINGERS]>,
    /// The joint trajectory they come from.
    pub joints: Vec<Vec<f64>>,
}

/// A smooth random joint trajectory inside the limits: per joint, the mid-range plus three
/// sines (0.15-0.9 Hz, seeded phases and weights) spanning at most 70 % of the range.
pub fn smooth_trajectory(sys: &System, seconds: f64, rate: f64, seed: u64) -> Vec<Vec<f64>> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (lo, hi) = (sys.model.lower_limits(), sys.model.upper_limits());
    let nq = sys.model.nq();
    let waves: Vec<[(f64, f64, f64); 3]> = (0..nq)
        .map(|_| {
            std::array::from_fn(|_| {
                (
                    rng.random_range(0.15..0.9),
                    rng.random_range(0.0..2.0 * PI),
                    rng.random_range(0.3..1.0),
                )
            })
        })
        .collect();
    let n = (seconds * rate).round() as usize;
    (0..n)
        .map(|k| {
            let t = k as f64 / rate;
            (0..nq)
                .map(|j| {
                    let (mid, half) = (0.5 * (lo[j] + hi[j]), 0.5 * (hi[j] - lo[j]));
                    let half = if half.is_finite() { half } else { PI };
                    let norm: f64 = waves[j].iter().map(|w| w.2).sum();
                    let s: f64 = waves[j]
                        .iter()
                        .map(|&(f, ph, a)| a * (2.0 * PI * f * t + ph).sin())
                        .sum();
                    let mid = if mid.is_finite() { mid } else { 0.0 };
                    mid + 0.7 * half * s / norm
                })
                .collect()
        })
        .collect()
}

/// The subject's wrist pose of the benchmark streams (any pose would do: a hand-only
/// registration is relative to it).
pub fn subject_wrist() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.42, 0.1, 0.25),
        UnitQuaternion::from_euler_angles(0.4, -0.3, 2.1),
    )
}

/// The human index-to-little tips whose spline points (equal arc-length spacing) are the robot's
/// non-thumb fingertips `p` (1 to 4 of them), up to 1e-10 m: the ends of the spline are the
/// outer robot fingers; the inner human tips (the middle tip `m`, the ring tip halfway from it
/// to the little tip) are solved for by Newton's method on the spline's midpoint, with a
/// finite-difference Jacobian and a halving line search.
fn spline_tips(p: &[Point3<f64>]) -> Option<[Point3<f64>; 4]> {
    let q0 = UnitQuaternion::identity();
    let thumb = (Point3::origin(), q0);
    match *p {
        [a] => Some([a; 4]),
        [a, b] => Some([a, a + (b - a) / 3.0, a + (b - a) * (2.0 / 3.0), b]),
        [a, b, c] => {
            let mut goals = [FingerGoal::default(); MAX_FINGERS];
            let mut residual = |m: &Vector3<f64>| {
                let m = Point3::from(*m);
                let r = m + (c - m) * 0.5;
                finger_goals(
                    &[thumb, (a, q0), (m, q0), (r, q0), (c, q0)],
                    4,
                    0,
                    &mut goals,
                );
                goals[2].position - b
            };
            let mut m = b.coords;
            let mut e = residual(&m);
            for _ in 0..50 {
                if e.norm() < 1e-12 {
                    let m = Point3::from(m);
                    return Some([a, m, m + (c - m) * 0.5, c]);
                }
                let h = 1e-7;
                let mut jac = nalgebra::Matrix3::zeros();
                for k in 0..3 {
                    let mut d = Vector3::zeros();
                    d[k] = h;
                    jac.set_column(k, &((residual(&(m + d)) - residual(&(m - d))) / (2.0 * h)));
                }
                let step = jac.lu().solve(&(-e))?;
                let mut s = 1.0;
                loop {
                    let next = m + step * s;
                    let en = residual(&next);
                    if en.norm() < e.norm() || s < 1e-6 {
                        m = next;
                        e = en;
                        break;
                    }
                    s *= 0.5;
                }
            }
            None
        }
        [a, b, c, d] => Some([a, b, c, d]),
        _ => None,
    }
}

/// A reachable stream for a hand on a fixed base (`seconds` at `rate`, joint trajectory seeded
/// by `seed`): the subject's wrist is [`subject_wrist`], the palm keypoints lie in its `xy`
/// plane (so the derived wrist frame is exactly it), each distal joint 25 mm behind its tip
/// along the robot fingertip frame's `x`. Frames whose inner spline tips cannot be solved for
/// (none seen) are an error.
pub fn reachable_stream(
    sys: &System,
    seconds: f64,
    rate: f64,
    seed: u64,
) -> Result<ReachableStream, MappingError> {
    let mm = MappingModel::from_system(sys)?;
    let Some(root) = mm.anchor().fixed_wrist else {
        return Err(MappingError::InvalidRegistration {
            reason: "reachable keypoint streams are built for a hand on a fixed base".into(),
        });
    };
    let hand_frame = Isometry3::from_parts(root.translation, root.rotation * hand_alignment());
    let w = subject_wrist();
    let to_human = |p: &Point3<f64>| w * (hand_frame.inverse() * p);
    let mut data = Data::new(&sys.model);
    let joints = smooth_trajectory(sys, seconds, rate, seed);
    let m = sys.fingers.len();
    let mut frames = Vec::with_capacity(joints.len());
    let mut targets = Vec::with_capacity(joints.len());
    for (k, q) in joints.iter().enumerate() {
        forward_kinematics(&sys.model, &mut data, q);
        let tips: Vec<Isometry3<f64>> = sys.fingers.iter().map(|f| *data.frame(f.tip)).collect();
        let pos: Vec<Point3<f64>> = tips
            .iter()
            .map(|t| Point3::from(t.translation.vector))
            .collect();
        let others: Vec<usize> = (0..m).filter(|&i| i != sys.thumb).collect();
        let rest: Vec<Point3<f64>> = others.iter().map(|&i| pos[i]).collect();
        let human = spline_tips(&rest).ok_or_else(|| MappingError::InvalidRegistration {
            reason: format!("frame {k}: no human tips put the spline on the robot's fingertips"),
        })?;
        let mut points = [Point3::origin(); KEYPOINT_COUNT];
        points[0] = Point3::from(w.translation.vector);
        let all = [pos[sys.thumb], human[0], human[1], human[2], human[3]];
        for (f, p) in all.iter().enumerate() {
            // The distal axis of the robot finger the human tip stands for (the nearest one on
            // the spline).
            let robot = if f == 0 {
                sys.thumb
            } else {
                others[((f - 1) * others.len()) / 4]
            };
            let axis = tips[robot].rotation * Vector3::x();
            points[TIPS[f]] = to_human(p);
            points[DISTAL_JOINTS[f]] = to_human(&(p - axis * 0.025));
            points[DISTAL_JOINTS[f] - 1] =
                Point3::from((points[DISTAL_JOINTS[f]].coords + points[0].coords) * 0.5);
        }
        // The thumb's CMC and the four MCPs in the wrist's `xy` plane (`y` ulnar, right hand).
        for (i, local) in [
            (1, Vector3::new(0.03, -0.03, 0.0)),
            (5, Vector3::new(0.085, -0.025, 0.0)),
            (9, Vector3::new(0.09, 0.0, 0.0)),
            (13, Vector3::new(0.085, 0.02, 0.0)),
            (17, Vector3::new(0.075, 0.04, 0.0)),
        ] {
            points[i] = w * Point3::from(local);
        }
        frames.push(KeypointFrame {
            t: k as f64 / rate,
            points,
            wrist_orientation: None,
            elbow: None,
            shoulder: None,
        });
        let mut t = [Point3::origin(); MAX_FINGERS];
        t[..m].copy_from_slice(&pos);
        targets.push(t);
    }
    Ok(ReachableStream {
        frames,
        targets,
        joints,
    })
}
