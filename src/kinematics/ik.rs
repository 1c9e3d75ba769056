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
    /// A posture the redundant joints' self-motion is pulled towards (see [`IkPosture`]).
    pub posture: Option<IkPosture>,
    /// Largest change of any one joint in one step (rad); a joint's longer step is cut to it.
    /// Short steps follow the task error down from the seed instead of jumping across the
    /// configuration space, so a seeding heuristic stays near the branch it was seeded on.
    pub max_step: Option<f64>,
}

/// A rest posture for a redundant chain. Once the target is reached within tolerance, each step
/// moves the active joints by `gain (rest − q)` projected into the null space of the damped
/// task Jacobian, which leaves the target's pose unchanged to first order; such a step may leave
/// the tolerance by a bounded factor (the next, plain step takes it back) and is halved until it
/// stays within that. The solve does not stop at the first configuration within tolerance: it
/// goes on along the self-motion until a step moves no joint by more than 1e-9 rad or the
/// attempt's iterations are spent, and answers the last configuration within tolerance: the pose
/// solution nearest the rest posture that the flow reaches. Used by the grasp optimiser's contact
/// repair to back a grasp out of an object without leaving a goal region.
#[derive(Clone, Debug, PartialEq)]
pub struct IkPosture {
    /// Full configuration (`q` order); only the active joints' entries are read.
    pub rest: Vec<f64>,
    /// Fraction of the remaining posture error removed per step, in (0, 1].
    pub gain: f64,
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
            posture: None,
            max_step: None,
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

/// A posture solve has settled when its last step moved no joint by more than this (rad).
const POSTURE_SETTLED: f64 = 1e-9;
/// Posture steps may leave the tolerance by up to this factor (the answer never does): a step
/// along the self-motion errs at second order in its length, and requiring every step to stay
/// within a 1 µm tolerance would cut the pull to milliradians per step.
const POSTURE_BAND: f64 = 100.0;

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
    /// The posture pull of the current step (zero without a posture).
    pull: Vec<f64>,
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
            pull: vec![0.0; n],
        }
    }

    /// One damped least-squares step `Δq = Jᵀ (J Jᵀ + μ I)⁻¹ e` into `trial`, with joint limits
    /// handled as an active set instead of by clamping alone: a joint the step would carry past
    /// a limit is set on that limit, its motion is taken out of the task error and its column out
    /// of `J`, and the remaining joints are solved again (at most once per joint). Clamping alone
    /// leaves the other joints' motion planned for a step the blocked joint never makes, which
    /// stalled solves pinned against limits (the main cause of restarts). `false` when
    /// `J Jᵀ + μ I` is not positive definite.
    ///
    /// With a posture pull `p` (`with_pull`), the step is `p + Jᵀ (J Jᵀ + μ I)⁻¹ (e − J p)`:
    /// the pull less what of it the task sees, i.e. its (damped) null-space projection added to
    /// the task step. A blocked joint drops its pull with its column.
    fn clamped_step(
        &mut self,
        n: usize,
        lo: &[f64],
        hi: &[f64],
        e: &Vector6<f64>,
        mu: f64,
        with_pull: bool,
    ) -> bool {
        self.blocked.copy_from_slice(&self.active);
        self.blocked.iter_mut().for_each(|b| *b = !*b);
        let mut e = *e;
        for k in 0..n {
            self.trial[k] = self.q[k];
            if with_pull && !self.blocked[k] {
                e -= self.jac.column(k) * self.pull[k];
            }
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
                let t = if with_pull {
                    self.q[k] + self.pull[k] + self.jac.column(k).dot(&y)
                } else {
                    self.q[k] + self.jac.column(k).dot(&y)
                };
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
            let planned = if with_pull { self.pull[k] } else { 0.0 };
            e -= self.jac.column(k) * (at - self.q[k] - planned);
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
        let posture = opts.posture.as_ref();
        // Where posture steps may wander while the self-motion is pulled (see `IkPosture`).
        let in_band = |pe: f64, oe: f64| {
            (wp == 0.0 || pe <= POSTURE_BAND * opts.position_tolerance)
                && (wo == 0.0 || oe <= POSTURE_BAND * opts.orientation_tolerance)
        };
        if let Some(p) = posture {
            assert_eq!(
                p.rest.len(),
                n,
                "rest posture has the wrong length for this model"
            );
        }
        let better = |cost: f64, pe: f64, oe: f64, best_cost: f64, best_pe: f64, best_oe: f64| {
            if posture.is_some() {
                converged(pe, oe) || (!converged(best_pe, best_oe) && cost < best_cost)
            } else {
                cost < best_cost
            }
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
            // With a posture: the last accepted step moved no joint by more than this (rad), so
            // the self-motion has settled.
            let mut settled = false;
            for _ in 0..opts.max_iterations_per_attempt {
                // With a posture, a later configuration within tolerance is the better answer
                // (nearer the rest posture) even where its residual is not the smallest, and
                // one outside never replaces one within.
                if better(cost, pe, oe, best_cost, best_pe, best_oe) {
                    best_cost = cost;
                    (best_pe, best_oe) = (pe, oe);
                    self.best.copy_from_slice(&self.q);
                }
                if converged(pe, oe) && (posture.is_none() || settled) {
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
                // A posture step only from within tolerance: away from the target, the plain
                // task step (the solve without a posture) gets back to it first.
                let posture_now = posture.filter(|_| converged(pe, oe));
                if let Some(p) = posture_now {
                    for k in 0..n {
                        self.pull[k] = if self.active[k] {
                            p.gain * (p.rest[k] - self.q[k])
                        } else {
                            0.0
                        };
                    }
                }
                let mut improved = false;
                for _ in 0..8 {
                    if !self.clamped_step(n, lo, hi, &e, lambda * scale, posture_now.is_some()) {
                        lambda *= 10.0;
                        continue;
                    }
                    if let Some(m) = opts.max_step {
                        // Towards `q` stays within the limits both ends are within.
                        for k in 0..n {
                            self.trial[k] = self.q[k] + (self.trial[k] - self.q[k]).clamp(-m, m);
                        }
                    }
                    forward_kinematics(model, &mut self.data, &self.trial);
                    let (e2, pe2, oe2) = task_error(&self.data, target, wp, wo);
                    let c2 = e2.norm_squared();
                    // A posture step may raise the residual (second order in the step) within
                    // the band: the next, plain step takes it back.
                    let posture_step = posture_now.is_some() && in_band(pe2, oe2);
                    if c2 < cost || posture_step {
                        // Creeping progress (typically a local minimum) is better spent on a
                        // fresh random start.
                        stalls = if c2 > 0.95 * cost && !posture_step {
                            stalls + 1
                        } else {
                            0
                        };
                        if posture_now.is_some() {
                            let moved = (0..n)
                                .map(|k| (self.trial[k] - self.q[k]).abs())
                                .fold(0.0, f64::max);
                            settled = moved <= POSTURE_SETTLED;
                        }
                        std::mem::swap(&mut self.q, &mut self.trial);
                        (e, pe, oe, cost) = (e2, pe2, oe2, c2);
                        lambda = (lambda * 0.3).max(1e-9);
                        improved = true;
                        break;
                    }
                    // What errs in a posture step is the pull: its part the damped projection
                    // lets through and its second-order error both shrink with it, while more
                    // damping would let more of it through. Backtrack on the pull.
                    if posture_now.is_some() {
                        self.pull.iter_mut().for_each(|p| *p *= 0.5);
                    } else {
                        lambda *= 8.0;
                    }
                }
                if !improved || stalls >= 6 {
                    break;
                }
            }
            if better(cost, pe, oe, best_cost, best_pe, best_oe) {
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

    /// The pose of frame `f` at `q` as an IK target (FK into `data`).
    fn frame_target(model: &Model, data: &mut Data, f: FrameId, q: &[f64]) -> IkTarget {
        forward_kinematics(model, data, q);
        IkTarget {
            frame: f,
            point_in_frame: Vector3::zeros(),
            pose: *data.frame(f),
        }
    }

    /// The posture option's answer, checked by a second method: where no joint rests on a limit,
    /// the nearest point of the self-motion to the rest posture is where `q − rest` has no
    /// component in the null space of the (undamped) Jacobian, taken here from its SVD
    /// pseudo-inverse; the pose is checked by a fresh FK.
    #[test]
    fn a_posture_pulls_the_self_motion_to_the_point_nearest_the_rest_without_moving_the_pose() {
        use nalgebra::{DMatrix, DVector};
        let model = model_from_urdf_file(&robots_dir().join("arms/wam.urdf")).unwrap();
        let f = model.frame_id("wam_flange").unwrap();
        let n = model.nq();
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut solver = IkSolver::new(&model);
        let mut data = Data::new(&model);
        let mut jac = Matrix6xX::zeros(n);
        let null_part = |jac: &Matrix6xX<f64>, d: &DVector<f64>| {
            let j = DMatrix::from_column_slice(6, n, jac.as_slice());
            let pinv = j.clone().pseudo_inverse(1e-9).unwrap();
            d - &pinv * (&j * d)
        };
        let mut checked = 0;
        for _ in 0..10 {
            let q_true = random_q_within(&model, &mut rng);
            let target = frame_target(&model, &mut data, f, &q_true);
            frame_jacobian(&model, &data, f, &Vector3::zeros(), &mut jac);
            let rest: Vec<f64> = q_true
                .iter()
                .map(|&q| q + rng.random_range(-0.4..0.4))
                .collect();
            let d0 = DVector::from_iterator(n, (0..n).map(|k| q_true[k] - rest[k]));
            let null0 = null_part(&jac, &d0).norm();
            let opts = IkOptions {
                posture: Some(IkPosture {
                    rest: rest.clone(),
                    gain: 0.3,
                }),
                max_restarts: 0,
                max_iterations_per_attempt: 400,
                max_iterations: 400,
                ..IkOptions::default()
            };
            let r = solver.solve(&model, &target, &q_true, &opts, &mut rng);
            assert!(r.success, "{r:?}");
            forward_kinematics(&model, &mut data, &r.q);
            let x = data.frame(f);
            let pe = (x.translation.vector - target.pose.translation.vector).norm();
            let oe = (target.pose.rotation * x.rotation.inverse()).angle();
            assert!(
                pe <= opts.position_tolerance && oe <= opts.orientation_tolerance,
                "{pe} {oe}"
            );
            let dist = |q: &[f64]| (0..n).map(|k| (q[k] - rest[k]).powi(2)).sum::<f64>();
            assert!(
                dist(&r.q) < dist(&q_true),
                "moved away from the rest posture"
            );
            if (0..n).any(|k| r.q[k] - lo[k] < 1e-6 || hi[k] - r.q[k] < 1e-6) {
                continue;
            }
            frame_jacobian(&model, &data, f, &Vector3::zeros(), &mut jac);
            let d = DVector::from_iterator(n, (0..n).map(|k| r.q[k] - rest[k]));
            let null = null_part(&jac, &d).norm();
            assert!(
                null < 1e-6 && null0 > 1e-2,
                "null-space part {null} (was {null0})"
            );
            checked += 1;
        }
        assert!(checked >= 7, "only {checked} of 10 ended off the limits");
    }

    /// `max_step` bounds every joint's move per iteration: after `k` iterations no joint is
    /// farther than `k · max_step` from the seed, where the unbounded solve goes farther.
    #[test]
    fn max_step_bounds_every_joints_move_per_iteration() {
        let model = model_from_urdf_file(&robots_dir().join("arms/wam.urdf")).unwrap();
        let f = model.frame_id("wam_flange").unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut data = Data::new(&model);
        let mut solver = IkSolver::new(&model);
        let q_true = random_q_within(&model, &mut rng);
        let target = frame_target(&model, &mut data, f, &q_true);
        let seed = random_q_within(&model, &mut rng);
        let farthest = |q: &[f64]| {
            (0..model.nq())
                .map(|k| (q[k] - seed[k]).abs())
                .fold(0.0, f64::max)
        };
        let opts = |max_step| IkOptions {
            max_step,
            max_iterations_per_attempt: 10,
            max_iterations: 10,
            max_restarts: 0,
            ..IkOptions::default()
        };
        let free = solver.solve(&model, &target, &seed, &opts(None), &mut rng);
        assert!(farthest(&free.q) > 0.5, "{}", farthest(&free.q));
        let bounded = solver.solve(&model, &target, &seed, &opts(Some(0.05)), &mut rng);
        assert!(bounded.iterations <= 10);
        assert!(
            farthest(&bounded.q) <= 0.05 * bounded.iterations as f64 + 1e-12,
            "{} after {} iterations",
            farthest(&bounded.q),
            bounded.iterations
        );
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
