//! Pose inverse kinematics: damped least squares with Levenberg–Marquardt damping adaptation,
//! joint limits by projection, and random restarts within an iteration budget.
//!
//! Determinism: the budget is counted in iterations and restarts, never in time, so the same
//! request (target, seed, options, random seed) gives a bit-identical answer on an idle and on a
//! loaded machine. A wall-clock limit remains only as a safety net; a solve it cuts short says so
//! in [`IkReport::timed_out`] (and is then no longer reproducible).
//!
//! Why this method: for 6-row pose tasks on 7-DoF arms, the task-space DLS step
//! `Δq = Jᵀ (J Jᵀ + λ I)⁻¹ e` needs only a 6×6 Cholesky on the stack per iteration (no heap),
//! converges quadratically near a solution, stays well-defined at singularities thanks to `λ`,
//! and — with limits enforced by clamping after each step and restarts from uniformly random
//! configurations when progress stalls — solves practically every reachable pose well inside the
//! budget (see `benches/kinematics.rs`). The general NLP solver is not needed for a pure pose
//! target.

use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Matrix6, Matrix6xX, Point3, Vector3, Vector6};
use rand::{Rng, RngExt};

use super::algorithms::{Data, forward_kinematics, frame_jacobian};
use super::model::{FrameId, Model};

/// What to reach: the point `point_in_frame` of `frame`, with the frame's orientation, at `pose`
/// (world). The orientation is the frame's (rotation of `pose`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkTarget {
    pub frame: FrameId,
    pub point_in_frame: Vector3<f64>,
    pub pose: Isometry3<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct IkOptions {
    /// Weight on the position error (per metre). Zero ignores position.
    pub position_weight: f64,
    /// Weight on the orientation error (per radian). Zero ignores orientation.
    pub orientation_weight: f64,
    /// Success: position error ≤ this (m) ...
    pub position_tolerance: f64,
    /// ... and orientation error ≤ this (rad), counting only terms with non-zero weight.
    pub orientation_tolerance: f64,
    /// Iterations per attempt before a restart.
    pub max_iterations_per_attempt: usize,
    /// Attempts after the first (seeded) one.
    pub max_restarts: usize,
    /// Iterations over all attempts: the budget that ends a solve.
    pub max_iterations: usize,
    /// Safety net only: wall time after which a solve stops and reports
    /// [`IkReport::timed_out`]. Never reached by the iteration budget on a working machine
    /// (the default iteration budget ends every solve long before 2 s).
    pub time_budget: Duration,
    /// Which `q` entries may move (default: every coordinate that moves the target frame).
    pub active_joints: Option<Vec<usize>>,
}

impl Default for IkOptions {
    fn default() -> Self {
        Self {
            position_weight: 1.0,
            orientation_weight: 0.5,
            position_tolerance: 1e-6,
            orientation_tolerance: 1e-5,
            max_iterations_per_attempt: 60,
            max_restarts: 500,
            // A count, so the answer does not depend on load: 33 full attempts of 60
            // iterations (`benches/kinematics.rs` measures what that costs).
            max_iterations: 2_000,
            time_budget: Duration::from_secs(2),
            active_joints: None,
        }
    }
}

/// The solve report: non-convergence is a status, not an error.
#[derive(Clone, Debug, PartialEq)]
pub struct IkReport {
    pub success: bool,
    /// Best configuration found (within limits), in `q` order.
    pub q: Vec<f64>,
    /// Position residual of the best configuration, metres.
    pub position_error: f64,
    /// Orientation residual of the best configuration, radians.
    pub orientation_error: f64,
    /// Iterations over all attempts.
    pub iterations: usize,
    /// Attempts started from a random configuration.
    pub restarts: usize,
    pub elapsed: Duration,
    /// The wall-clock safety net ([`IkOptions::time_budget`]) ended the solve before its
    /// iteration budget did: the answer may differ on a less loaded machine.
    pub timed_out: bool,
}

/// Reusable IK scratch (one per worker). Allocates only in `new`.
#[derive(Clone, Debug)]
pub struct IkSolver {
    data: Data,
    jac: Matrix6xX<f64>,
    q: Vec<f64>,
    trial: Vec<f64>,
    best: Vec<f64>,
    active: Vec<bool>,
    /// Joints not moved by the current step: inactive, or held on a limit.
    blocked: Vec<bool>,
}

/// Weighted task error `[wp (p* − p); wo log(R* Rᵀ)]` and the two raw residuals.
fn task_error(data: &Data, t: &IkTarget, wp: f64, wo: f64) -> (Vector6<f64>, f64, f64) {
    let x = data.frame(t.frame);
    let p = x * Point3::from(t.point_in_frame);
    let dp = t.pose.translation.vector - p.coords;
    let dr = (t.pose.rotation * x.rotation.inverse()).scaled_axis();
    let e = Vector6::new(
        wp * dp.x,
        wp * dp.y,
        wp * dp.z,
        wo * dr.x,
        wo * dr.y,
        wo * dr.z,
    );
    (e, dp.norm(), dr.norm())
}

impl IkSolver {
    pub fn new(model: &Model) -> Self {
        let n = model.nq();
        Self {
            data: Data::new(model),
            jac: Matrix6xX::zeros(n),
            q: vec![0.0; n],
            trial: vec![0.0; n],
            best: vec![0.0; n],
            active: vec![false; n],
            blocked: vec![false; n],
        }
    }

    /// One damped least-squares step `Δq = Jᵀ (J Jᵀ + μ I)⁻¹ e` into `trial`, with joint limits
    /// handled as an active set instead of by clamping alone: a joint the step would carry past
    /// a limit is set on that limit, its motion is taken out of the task error and its column out
    /// of `J`, and the remaining joints are solved again (at most once per joint). Clamping alone
    /// leaves the other joints' motion planned for a step the blocked joint never makes, which
    /// stalled solves pinned against limits (the main cause of restarts). `false` when
    /// `J Jᵀ + μ I` is not positive definite.
    fn clamped_step(
        &mut self,
        n: usize,
        lo: &[f64],
        hi: &[f64],
        e: &Vector6<f64>,
        mu: f64,
    ) -> bool {
        self.blocked.copy_from_slice(&self.active);
        self.blocked.iter_mut().for_each(|b| *b = !*b);
        let mut e = *e;
        for k in 0..n {
            self.trial[k] = self.q[k];
        }
        for _pass in 0..=n {
            let mut m = Matrix6::zeros();
            for c in 0..n {
                if !self.blocked[c] {
                    let col = self.jac.column(c);
                    m.ger(1.0, &col, &col, 1.0);
                }
            }
            for i in 0..6 {
                m[(i, i)] += mu;
            }
            let Some(chol) = m.cholesky() else {
                return false;
            };
            let y = chol.solve(&e);
            let mut hit = None;
            let mut worst = 0.0;
            for k in 0..n {
                if self.blocked[k] {
                    continue;
                }
                let t = self.q[k] + self.jac.column(k).dot(&y);
                self.trial[k] = t;
                // The joint overshooting its limit the most (relative to its range) is blocked
                // first; the others may fit once it is.
                let over = (t - hi[k]).max(lo[k] - t) / (hi[k] - lo[k]).max(1e-9);
                if over > worst {
                    worst = over;
                    hit = Some(k);
                }
            }
            let Some(k) = hit else {
                return true;
            };
            let at = self.trial[k].clamp(lo[k], hi[k]);
            e -= self.jac.column(k) * (at - self.q[k]);
            self.trial[k] = at;
            self.blocked[k] = true;
        }
        for k in 0..n {
            self.trial[k] = self.trial[k].clamp(lo[k], hi[k]);
        }
        true
    }

    /// Solves from `seed` first, then from random configurations drawn with `rng` until success,
    /// the restart limit or the iteration budget (the wall-clock safety net aside). Inactive
    /// joints keep their seed values.
    pub fn solve(
        &mut self,
        model: &Model,
        target: &IkTarget,
        seed: &[f64],
        opts: &IkOptions,
        rng: &mut impl Rng,
    ) -> IkReport {
        let start = Instant::now();
        let mut timed_out = false;
        let n = model.nq();
        assert_eq!(seed.len(), n, "seed has the wrong length for this model");
        self.active.iter_mut().for_each(|a| *a = false);
        match &opts.active_joints {
            Some(list) => list.iter().for_each(|&k| self.active[k] = true),
            None => model
                .supporting_q(target.frame)
                .into_iter()
                .for_each(|k| self.active[k] = true),
        }
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let (wp, wo) = (opts.position_weight, opts.orientation_weight);
        let converged = |pe: f64, oe: f64| {
            (wp == 0.0 || pe <= opts.position_tolerance)
                && (wo == 0.0 || oe <= opts.orientation_tolerance)
        };
        let mut best_cost = f64::INFINITY;
        let (mut best_pe, mut best_oe) = (f64::INFINITY, f64::INFINITY);
        let mut iterations = 0;
        let mut restarts = 0;
        self.q.copy_from_slice(seed);
        for k in 0..n {
            self.q[k] = self.q[k].clamp(lo[k], hi[k]);
        }
        'attempts: loop {
            forward_kinematics(model, &mut self.data, &self.q);
            let (mut e, mut pe, mut oe) = task_error(&self.data, target, wp, wo);
            let mut cost = e.norm_squared();
            let mut lambda = 1e-3;
            let mut stalls = 0;
            for _ in 0..opts.max_iterations_per_attempt {
                if cost < best_cost {
                    best_cost = cost;
                    (best_pe, best_oe) = (pe, oe);
                    self.best.copy_from_slice(&self.q);
                }
                if converged(pe, oe) {
                    break 'attempts;
                }
                // The budget is checked every iteration, not only between attempts, so a slow
                // attempt cannot overrun it.
                if iterations >= opts.max_iterations {
                    break 'attempts;
                }
                if start.elapsed() >= opts.time_budget {
                    timed_out = true;
                    break 'attempts;
                }
                iterations += 1;
                frame_jacobian(
                    model,
                    &self.data,
                    target.frame,
                    &target.point_in_frame,
                    &mut self.jac,
                );
                // Weight rows, drop inactive columns.
                for c in 0..n {
                    let mut col = self.jac.column_mut(c);
                    if self.active[c] {
                        col.fixed_rows_mut::<3>(0).scale_mut(wp);
                        col.fixed_rows_mut::<3>(3).scale_mut(wo);
                    } else {
                        col.fill(0.0);
                    }
                }
                // Damping relative to the task scale, so λ is unit-free; retries raise it (LM).
                let scale = {
                    let mut t = 0.0;
                    for c in 0..n {
                        if self.active[c] {
                            t += self.jac.column(c).norm_squared();
                        }
                    }
                    t / 6.0 + 1e-12
                };
                let mut improved = false;
                for _ in 0..8 {
                    if !self.clamped_step(n, lo, hi, &e, lambda * scale) {
                        lambda *= 10.0;
                        continue;
                    }
                    forward_kinematics(model, &mut self.data, &self.trial);
                    let (e2, pe2, oe2) = task_error(&self.data, target, wp, wo);
                    let c2 = e2.norm_squared();
                    if c2 < cost {
                        // Creeping progress (typically a local minimum) is better spent on a
                        // fresh random start.
                        stalls = if c2 > 0.95 * cost { stalls + 1 } else { 0 };
                        std::mem::swap(&mut self.q, &mut self.trial);
                        (e, pe, oe, cost) = (e2, pe2, oe2, c2);
                        lambda = (lambda * 0.3).max(1e-9);
                        improved = true;
                        break;
                    }
                    lambda *= 8.0;
                }
                if !improved || stalls >= 6 {
                    break;
                }
            }
            if cost < best_cost {
                best_cost = cost;
                (best_pe, best_oe) = (pe, oe);
                self.best.copy_from_slice(&self.q);
            }
            if converged(best_pe, best_oe)
                || restarts >= opts.max_restarts
                || iterations >= opts.max_iterations
                || timed_out
            {
                break;
            }
            restarts += 1;
            for k in 0..n {
                if self.active[k] {
                    let (l, u) = (lo[k], hi[k]);
                    self.q[k] = if l.is_finite() && u.is_finite() && u > l {
                        rng.random_range(l..=u)
                    } else {
                        rng.random_range(-std::f64::consts::PI..=std::f64::consts::PI)
                    };
                } else {
                    self.q[k] = seed[k].clamp(lo[k], hi[k]);
                }
            }
        }
        IkReport {
            success: converged(best_pe, best_oe),
            q: self.best.clone(),
            position_error: best_pe,
            orientation_error: best_oe,
            iterations,
            restarts,
            elapsed: start.elapsed(),
            timed_out,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::model_from_urdf_file;
    use crate::kinematics::robot_tests::{load_system, random_q_within, robots_dir};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn round_trips(model: &Model, frame: FrameId, n: usize, seed: u64) -> usize {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut solver = IkSolver::new(model);
        let mut data = Data::new(model);
        let opts = IkOptions::default();
        let mut ok = 0;
        for _ in 0..n {
            let q_true = random_q_within(model, &mut rng);
            forward_kinematics(model, &mut data, &q_true);
            let target = IkTarget {
                frame,
                point_in_frame: Vector3::zeros(),
                pose: *data.frame(frame),
            };
            let seed_q = random_q_within(model, &mut rng);
            let r = solver.solve(model, &target, &seed_q, &opts, &mut rng);
            // Whatever the outcome: limits hold and the reported residuals are the true ones.
            for k in 0..model.nq() {
                assert!(r.q[k] >= model.lower_limits()[k] && r.q[k] <= model.upper_limits()[k]);
            }
            forward_kinematics(model, &mut data, &r.q);
            let pe = (data.frame(frame).translation.vector - target.pose.translation.vector).norm();
            let oe = (target.pose.rotation * data.frame(frame).rotation.inverse()).angle();
            assert!(
                (pe - r.position_error).abs() < 1e-12 && (oe - r.orientation_error).abs() < 1e-9
            );
            if r.success {
                assert!(pe <= opts.position_tolerance && oe <= opts.orientation_tolerance);
                ok += 1;
            }
        }
        ok
    }

    #[test]
    fn pose_ik_round_trips_on_both_arms() {
        for (file, flange) in [("wam.urdf", "wam_flange"), ("pa10.urdf", "pa10_flange")] {
            let model = model_from_urdf_file(&robots_dir().join("arms").join(file)).unwrap();
            let ok = round_trips(&model, model.frame_id(flange).unwrap(), 60, 1);
            assert!(ok >= 59, "{file}: {ok}/60");
        }
    }

    #[test]
    fn pose_ik_on_a_system_moves_only_the_arm_for_the_wrist_frame() {
        let s = load_system("pa10_ihy");
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut data = Data::new(&s.model);
        let q_true = random_q_within(&s.model, &mut rng);
        forward_kinematics(&s.model, &mut data, &q_true);
        let target = IkTarget {
            frame: s.wrist_frame,
            point_in_frame: Vector3::zeros(),
            pose: *data.frame(s.wrist_frame),
        };
        let seed = random_q_within(&s.model, &mut rng);
        let r = IkSolver::new(&s.model).solve(
            &s.model,
            &target,
            &seed,
            &IkOptions::default(),
            &mut rng,
        );
        assert!(r.success, "{r:?}");
        for &k in &s.hand_joints {
            assert_eq!(r.q[k], seed[k]);
        }
    }

    #[test]
    fn an_unreachable_target_reports_failure_with_the_best_residuals() {
        let model = model_from_urdf_file(&robots_dir().join("arms/wam.urdf")).unwrap();
        let f = model.frame_id("wam_flange").unwrap();
        let target = IkTarget {
            frame: f,
            point_in_frame: Vector3::zeros(),
            pose: Isometry3::translation(3.0, 0.0, 0.3),
        };
        let opts = IkOptions {
            max_restarts: 5,
            ..IkOptions::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let r = IkSolver::new(&model).solve(&model, &target, &model.neutral(), &opts, &mut rng);
        assert!(!r.success);
        // The flange reaches at most 0.55 + 0.3 + 0.06 m (plus the 45 mm elbow offsets) from the
        // shoulder at 0.346 m height, so no pose gets closer than about 2.08 m to the target.
        assert!(
            r.position_error > 2.0 && r.position_error < 2.5,
            "{}",
            r.position_error
        );
        assert_eq!(r.restarts, 5);
    }

    #[test]
    fn position_only_ik_ignores_orientation() {
        let model = model_from_urdf_file(&robots_dir().join("arms/pa10.urdf")).unwrap();
        let f = model.frame_id("pa10_flange").unwrap();
        let target = IkTarget {
            frame: f,
            point_in_frame: Vector3::new(0.0, 0.0, 0.1),
            pose: Isometry3::translation(0.5, 0.2, 0.6),
        };
        let opts = IkOptions {
            orientation_weight: 0.0,
            ..IkOptions::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let r = IkSolver::new(&model).solve(&model, &target, &model.neutral(), &opts, &mut rng);
        assert!(r.success && r.position_error <= 1e-6, "{r:?}");
    }
}
