//! Seeded synthetic joint-space demonstrations with known structure, for tests and benchmarks
//! (the real training data are mapped human demonstrations). Arm: minimum-jerk transports from
//! a home region to one of several object positions along paths that bulge consistently (the
//! lifted-hand curvature of human reaching) in a 3-D latent space embedded in the arm's joints;
//! hand: an aperture closing towards the object size with a curved thumb swing, 2-D latent.

use nalgebra::DMatrix;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{JointLimits, JointTrajectory, MinimumJerk};

/// Synthetic study settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyntheticStudy {
    pub seed: u64,
    pub arm_joints: usize,
    pub hand_joints: usize,
    pub positions: usize,
    pub trials_per_position: usize,
    pub frames: usize,
    /// Joint-space noise (rad, uniform half-width).
    pub noise: f64,
}

impl Default for SyntheticStudy {
    fn default() -> Self {
        SyntheticStudy {
            seed: 1,
            arm_joints: 7,
            hand_joints: 4,
            positions: 5,
            trials_per_position: 10,
            frames: 100,
            noise: 0.003,
        }
    }
}

/// A generated study: demonstrations, the object-position label of each, joint limits, and the
/// joint groups (arm, hand).
pub struct SyntheticData {
    pub demos: Vec<JointTrajectory>,
    pub position_of: Vec<usize>,
    pub limits: JointLimits,
    pub groups: Vec<Vec<usize>>,
}

fn orthonormal(rows: usize, cols: usize, rng: &mut ChaCha8Rng) -> DMatrix<f64> {
    let a = DMatrix::<f64>::from_fn(rows, cols, |_, _| rng.random_range(-1.0..1.0));
    a.qr().q().columns(0, cols).into_owned()
}

/// Generate the study. Deterministic for a seed.
pub fn curved_study(study: &SyntheticStudy) -> SyntheticData {
    let mut rng = ChaCha8Rng::seed_from_u64(study.seed);
    let na = study.arm_joints;
    let nh = study.hand_joints;
    let n = na + nh;
    let arm_basis = orthonormal(na, 3, &mut rng);
    let hand_basis = if nh > 0 {
        orthonormal(nh, 2.min(nh), &mut rng)
    } else {
        DMatrix::zeros(0, 0)
    };
    let mean: Vec<f64> = (0..n).map(|j| 0.3 * ((j as f64) * 1.7).sin()).collect();
    let mut demos = Vec::new();
    let mut position_of = Vec::new();
    let u = |r: &mut ChaCha8Rng, w: f64| r.random_range(-w..w);
    for p in 0..study.positions {
        let frac = if study.positions > 1 {
            p as f64 / (study.positions - 1) as f64
        } else {
            0.5
        };
        // object positions on an arc in front of the home posture
        let goal_arm = [
            0.6,
            -0.5 + 1.0 * frac,
            0.15 * (std::f64::consts::PI * frac).sin(),
        ];
        let object_size = 0.3 + 0.4 * frac;
        for _ in 0..study.trials_per_position {
            let home = [
                -0.6 + u(&mut rng, 0.05),
                -0.2 + u(&mut rng, 0.05),
                -0.1 + u(&mut rng, 0.05),
            ];
            let goal: Vec<f64> = goal_arm.iter().map(|g| g + u(&mut rng, 0.03)).collect();
            let lift = 0.4 + u(&mut rng, 0.04);
            let dist = (0..3)
                .map(|i| (goal[i] - home[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            let duration = 0.6 + 0.5 * dist + u(&mut rng, 0.05);
            let mut times = Vec::with_capacity(study.frames);
            let mut positions = Vec::with_capacity(study.frames * n);
            for f in 0..study.frames {
                let tau = f as f64 / (study.frames - 1) as f64;
                let (m, _, _) = MinimumJerk::eval(tau);
                let bump = 4.0 * m * (1.0 - m);
                // consistent curvature: lift (third axis) and a sideways sweep (second axis)
                let z = [
                    home[0] + m * (goal[0] - home[0]),
                    home[1] + m * (goal[1] - home[1]) - 0.25 * bump,
                    home[2] + m * (goal[2] - home[2]) + lift * bump,
                ];
                // hand: aperture towards the object size while the thumb swings out and back
                // (curved, but never moving away from the final posture: a certified NF flow
                // decreases the distance to its goal monotonically, so an aperture overshoot
                // cannot be reproduced and is left out of the data)
                let h = [
                    0.1 + m * (object_size - 0.1),
                    -0.2 + 0.4 * m * frac + 0.3 * bump,
                ];
                times.push(tau * duration);
                for j in 0..na {
                    let mut v = mean[j] + u(&mut rng, study.noise);
                    for (k, zk) in z.iter().enumerate() {
                        v += arm_basis[(j, k)] * zk;
                    }
                    positions.push(v);
                }
                for j in 0..nh {
                    let mut v = mean[na + j] + u(&mut rng, study.noise);
                    for (k, hk) in h.iter().enumerate().take(hand_basis.ncols()) {
                        v += hand_basis[(j, k)] * hk;
                    }
                    positions.push(v);
                }
            }
            demos.push(JointTrajectory { times, positions });
            position_of.push(p);
        }
    }
    let limits = JointLimits {
        lower: mean.iter().map(|m| m - 2.5).collect(),
        upper: mean.iter().map(|m| m + 2.5).collect(),
        velocity: vec![2.0; n],
        acceleration: vec![8.0; n],
        jerk: vec![80.0; n],
    };
    let mut groups = vec![(0..na).collect::<Vec<_>>()];
    if nh > 0 {
        groups.push((na..n).collect());
    }
    SyntheticData {
        demos,
        position_of,
        limits,
        groups,
    }
}
