//! Trajectory solving: one bounded NLP per frame (eq. 6-7), warm-started from the previous frame.
//!
//! The first frame is a global problem (no previous solution): several starts, best kept. Every
//! later frame starts at the previous solution and its box is the joint limits intersected with a
//! step bound around it (`|q_k − q_{k−1}| ≤ scale · v_max · Δt`), so consecutive solutions cannot
//! jump to another IK branch. A frame that does not converge is solved as far as it gets, kept
//! (the trajectory stays continuous) and reported as `converged: false` — never hidden.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::MappingError;
use super::goals::{MAX_FINGERS, finger_goals};
use super::nlp::{BoxSolver, SolveReport};
use super::objective::{Evaluator, FrameGoals, MappingModel, Objective, Term, Weights};
use super::registration::{ArmPoints, Registration, RegistrationSpec, RobotAnchor};
use crate::human::HumanFrame;

/// Solver settings of a mapping run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverOptions {
    /// Stopping tolerance of the NLP solver on the (scaled) fixed-point residual.
    pub tolerance: f64,
    /// Iteration cap of a warm-started frame.
    pub max_iterations: usize,
    /// Iteration cap of each start of the first frame.
    pub first_frame_max_iterations: usize,
    /// Starts tried on the first frame (the mid-range configuration plus seeded random ones).
    pub first_frame_starts: usize,
    /// Seed of the first-frame random starts.
    pub seed: u64,
    /// Joint step bound per frame as a multiple of `velocity limit · Δt`.
    pub step_scale: f64,
    /// Joint speed used for the step bound when a joint has no positive finite velocity limit.
    pub fallback_speed: f64,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-6,
            max_iterations: 200,
            first_frame_max_iterations: 1000,
            first_frame_starts: 8,
            seed: 0x5eed,
            step_scale: 2.0,
            fallback_speed: 3.0,
        }
    }
}

impl SolverOptions {
    pub fn validate(&self) -> Result<(), MappingError> {
        let bad = |field: &'static str, value: f64| Err(MappingError::InvalidOption { field, value });
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return bad("tolerance", self.tolerance);
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", 0.0);
        }
        if self.first_frame_max_iterations == 0 {
            return bad("first_frame_max_iterations", 0.0);
        }
        if self.first_frame_starts == 0 {
            return bad("first_frame_starts", 0.0);
        }
        if !(self.step_scale.is_finite() && self.step_scale > 0.0) {
            return bad("step_scale", self.step_scale);
        }
        if !(self.fallback_speed.is_finite() && self.fallback_speed > 0.0) {
            return bad("fallback_speed", self.fallback_speed);
        }
        Ok(())
    }
}

/// What one frame's solve achieved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameMetrics {
    pub t: f64,
    /// Robot finger count `m`; the per-finger arrays are valid in `[0..fingers]`.
    pub fingers: usize,
    /// `‖x_i − x_goal_i‖` per robot finger, m.
    pub position_error: [f64; MAX_FINGERS],
    /// `d_o` of eq. 3 per robot finger, rad (half the rotation angle between the frames).
    pub orientation_error: [f64; MAX_FINGERS],
    /// `D` of eq. 4, m².
    pub elbow_distance: f64,
    /// Mean `‖s_j − s_elbow‖` over the eq. 4 joints, m.
    pub elbow_distance_mean: f64,
    /// `F` of eq. 5 at the solution.
    pub objective: f64,
    pub iterations: usize,
    pub converged: bool,
}

/// A demonstration mapped onto the robot.
#[derive(Clone, Debug, PartialEq)]
pub struct MappedTrajectory {
    /// Independent joints, the order of each row of `positions`.
    pub joint_names: Vec<String>,
    pub times: Vec<f64>,
    /// Row-major `frames × nq` joint positions.
    pub positions: Vec<f64>,
    pub metrics: Vec<FrameMetrics>,
    pub registration: Registration,
}

impl MappedTrajectory {
    pub fn nq(&self) -> usize {
        self.joint_names.len()
    }
    pub fn frame(&self, k: usize) -> &[f64] {
        let nq = self.nq();
        &self.positions[k * nq..(k + 1) * nq]
    }
    /// Indices of the frames that did not converge.
    pub fn unconverged(&self) -> impl Iterator<Item = usize> + '_ {
        self.metrics
            .iter()
            .enumerate()
            .filter(|(_, m)| !m.converged)
            .map(|(k, _)| k)
    }
}

/// The reusable per-worker mapping solver: FK scratch, solver cache, bound buffers. Mapping a
/// frame allocates nothing.
pub struct Mapper {
    eval: Evaluator,
    solver: BoxSolver,
    terms: Vec<Term>,
    options: SolverOptions,
    lo: Vec<f64>,
    hi: Vec<f64>,
    step: Vec<f64>,
    q: Vec<f64>,
    best: Vec<f64>,
}

impl Mapper {
    pub fn new(
        mm: MappingModel,
        weights: Weights,
        options: SolverOptions,
    ) -> Result<Self, MappingError> {
        weights.validate()?;
        options.validate()?;
        if mm.tips.is_empty() || mm.tips.len() > MAX_FINGERS || mm.thumb >= mm.tips.len() {
            return Err(MappingError::UnsupportedHand {
                fingers: mm.tips.len(),
                thumb: mm.thumb,
            });
        }
        let nq = mm.model.nq();
        Ok(Self {
            solver: BoxSolver::new(nq, options.tolerance),
            eval: Evaluator::new(mm),
            terms: weights.terms(),
            options,
            lo: vec![0.0; nq],
            hi: vec![0.0; nq],
            step: vec![0.0; nq],
            q: vec![0.0; nq],
            best: vec![0.0; nq],
        })
    }

    pub fn model(&self) -> &MappingModel {
        self.eval.model()
    }

    pub fn terms(&self) -> &[Term] {
        &self.terms
    }

    /// Goals of one human frame in the robot base frame.
    pub fn goals(&self, frame: &HumanFrame, reg: &Registration, out: &mut FrameGoals) {
        let tips: [_; 5] = std::array::from_fn(|i| {
            let iso = &frame.fingertips[i];
            (
                reg.point(&iso.translation.vector.into()),
                reg.orientation(&iso.rotation),
            )
        });
        let mm = self.eval.model();
        finger_goals(&tips, mm.fingers(), mm.thumb, &mut out.fingers);
        out.elbow = reg.point(&frame.elbow);
    }

    /// Solves one frame inside `[lo, hi]` from `q` (updated in place).
    fn solve_in_box(&mut self, goals: &FrameGoals, max_iter: usize) -> SolveReport {
        let Self {
            eval,
            solver,
            terms,
            lo,
            hi,
            q,
            ..
        } = self;
        let mut f = |x: &[f64], g: Option<&mut [f64]>| match g {
            Some(g) => eval.value_and_gradient(terms, goals, x, g),
            None => eval.value(terms, goals, x),
        };
        solver.solve(lo, hi, &mut f, q, max_iter)
    }

    /// Maps a whole demonstration.
    pub fn map(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
    ) -> Result<MappedTrajectory, MappingError> {
        self.map_cancellable(frames, spec, robot, &AtomicBool::new(false))
            .expect("never cancelled")
    }

    /// [`Self::map`], polling `cancel` between frames (`None` once cancelled).
    pub fn map_cancellable(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
        cancel: &AtomicBool,
    ) -> Option<Result<MappedTrajectory, MappingError>> {
        let reg = match registration_for(frames, spec, robot) {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        let nq = self.eval.nq();
        let mut out = MappedTrajectory {
            joint_names: self.eval.model().model.joint_names().to_vec(),
            times: Vec::with_capacity(frames.len()),
            positions: Vec::with_capacity(frames.len() * nq),
            metrics: Vec::with_capacity(frames.len()),
            registration: reg,
        };
        let mut goals = FrameGoals::default();
        for (k, frame) in frames.iter().enumerate() {
            if cancel.load(Ordering::Relaxed) {
                return None;
            }
            if let Err(e) = check_frame(k, frame) {
                return Some(Err(e));
            }
            if k > 0 && !(frame.t > frames[k - 1].t) {
                return Some(Err(MappingError::NonIncreasingTime {
                    frame: k,
                    t: frame.t,
                    previous: frames[k - 1].t,
                }));
            }
            self.goals(frame, &reg, &mut goals);
            let metrics = if k == 0 {
                self.solve_first(&goals, frame.t)
            } else {
                self.solve_next(&goals, frame.t, frame.t - frames[k - 1].t)
            };
            out.times.push(frame.t);
            out.positions.extend_from_slice(&self.q);
            out.metrics.push(metrics);
        }
        Some(Ok(out))
    }

    /// First frame: several starts within the joint limits, best objective kept.
    pub fn solve_first(&mut self, goals: &FrameGoals, t: f64) -> FrameMetrics {
        let model = self.eval.model().model.clone();
        let (lower, upper) = (model.lower_limits(), model.upper_limits());
        let mut rng = ChaCha8Rng::seed_from_u64(self.options.seed);
        let mut best: Option<(f64, usize, bool)> = None;
        let mut total_iter = 0;
        for start in 0..self.options.first_frame_starts {
            for i in 0..self.q.len() {
                let (l, u) = finite_range(lower[i], upper[i]);
                self.q[i] = if start == 0 {
                    0.5 * (l + u)
                } else {
                    rng.random_range(l..=u)
                };
            }
            self.lo.copy_from_slice(lower);
            self.hi.copy_from_slice(upper);
            let report = self.solve_in_box(goals, self.options.first_frame_max_iterations);
            total_iter += report.iterations;
            let f = self.eval.value(&self.terms, goals, &self.q);
            if best.is_none_or(|(bf, _, _)| f < bf) {
                best = Some((f, report.iterations, report.converged));
                self.best.copy_from_slice(&self.q);
            }
        }
        let (_, _, converged) = best.expect("first_frame_starts ≥ 1 is validated");
        self.q.copy_from_slice(&self.best);
        self.metrics(goals, t, total_iter, converged)
    }

    /// A later frame: warm start from the previous solution inside the step-bounded box.
    pub fn solve_next(&mut self, goals: &FrameGoals, t: f64, dt: f64) -> FrameMetrics {
        let model = self.eval.model().model.clone();
        let (lower, upper, vmax) = (
            model.lower_limits(),
            model.upper_limits(),
            model.velocity_limits(),
        );
        for i in 0..self.q.len() {
            let v = if vmax[i].is_finite() && vmax[i] > 0.0 {
                vmax[i]
            } else {
                self.options.fallback_speed
            };
            self.step[i] = self.options.step_scale * v * dt;
            self.lo[i] = lower[i].max(self.q[i] - self.step[i]);
            self.hi[i] = upper[i].min(self.q[i] + self.step[i]);
        }
        let report = self.solve_in_box(goals, self.options.max_iterations);
        self.metrics(goals, t, report.iterations, report.converged)
    }

    /// The current solution (the last solved frame).
    pub fn solution(&self) -> &[f64] {
        &self.q
    }

    /// Sets the warm start for [`Self::solve_next`].
    pub fn set_solution(&mut self, q: &[f64]) {
        self.q.copy_from_slice(q);
    }

    fn metrics(&mut self, goals: &FrameGoals, t: f64, iterations: usize, converged: bool) -> FrameMetrics {
        let objective = self.eval.value(&self.terms, goals, &self.q);
        let m = self.eval.model().fingers();
        let mut position_error = [0.0; MAX_FINGERS];
        let mut orientation_error = [0.0; MAX_FINGERS];
        for i in 0..m {
            position_error[i] = (self.eval.tip_position(i) - goals.fingers[i].position).norm();
            orientation_error[i] = super::objective::quaternion_distance(
                &self.eval.tip_orientation(i),
                &goals.fingers[i].orientation,
            )
            .0;
        }
        let n = self.eval.model().elbow_frames.len();
        let elbow_distance = self.eval.objective_value(Objective::ElbowDistance, goals);
        let elbow_distance_mean = if n == 0 {
            0.0
        } else {
            (0..n)
                .map(|j| (self.eval.elbow_point(j) - goals.elbow).norm())
                .sum::<f64>()
                / n as f64
        };
        FrameMetrics {
            t,
            fingers: m,
            position_error,
            orientation_error,
            elbow_distance,
            elbow_distance_mean,
            objective,
            iterations,
            converged,
        }
    }
}

/// A box for random starts: the limits, or ±π where a joint is unbounded.
fn finite_range(l: f64, u: f64) -> (f64, f64) {
    let l = if l.is_finite() { l } else { -std::f64::consts::PI };
    let u = if u.is_finite() { u } else { std::f64::consts::PI };
    (l, u.max(l))
}

fn check_frame(k: usize, f: &HumanFrame) -> Result<(), MappingError> {
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let fields: [(&'static str, bool); 5] = [
        ("t", f.t.is_finite()),
        ("shoulder", finite(f.shoulder.coords.as_slice())),
        ("elbow", finite(f.elbow.coords.as_slice())),
        (
            "wrist",
            finite(f.wrist.translation.vector.as_slice()) && finite(f.wrist.rotation.coords.as_slice()),
        ),
        (
            "fingertips",
            f.fingertips.iter().all(|t| {
                finite(t.translation.vector.as_slice()) && finite(t.rotation.coords.as_slice())
            }),
        ),
    ];
    for (field, ok) in fields {
        if !ok {
            return Err(MappingError::NonFinite { frame: k, field });
        }
    }
    Ok(())
}

/// The registration of a demonstration (its arm points, the spec, the robot).
pub fn registration_for(
    frames: &[HumanFrame],
    spec: &RegistrationSpec,
    robot: &RobotAnchor,
) -> Result<Registration, MappingError> {
    let points: Vec<ArmPoints> = frames
        .iter()
        .map(|f| ArmPoints {
            shoulder: f.shoulder,
            elbow: f.elbow,
            wrist: f.wrist.translation.vector.into(),
            middle_tip: f.fingertips[2].translation.vector.into(),
        })
        .collect();
    Registration::resolve(spec, &points, robot)
}

/// One demonstration of a batch.
#[derive(Clone, Copy, Debug)]
pub struct BatchItem<'a> {
    pub frames: &'a [HumanFrame],
    pub registration: &'a RegistrationSpec,
}

/// Batch mapping was cancelled through its flag.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("mapping cancelled after {completed} of {total} demonstrations")]
pub struct Cancelled {
    pub completed: usize,
    pub total: usize,
}

/// Maps many demonstrations across `threads` workers (each with its own [`Mapper`]), in input
/// order. `progress(done, total)` is called after each demonstration; `cancel` is polled between
/// demonstrations and between frames of one.
pub fn map_batch(
    mm: &MappingModel,
    robot: &RobotAnchor,
    items: &[BatchItem<'_>],
    weights: Weights,
    options: SolverOptions,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<Vec<Result<MappedTrajectory, MappingError>>, Cancelled> {
    let total = items.len();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let threads = threads.clamp(1, total.max(1));
    let mut results: Vec<Option<Result<MappedTrajectory, MappingError>>> = vec![None; total];
    let chunks: Vec<Vec<(usize, Result<MappedTrajectory, MappingError>)>> =
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|_| {
                    s.spawn(|| {
                        let mut mine = Vec::new();
                        let mut mapper = match Mapper::new(mm.clone(), weights, options) {
                            Ok(m) => m,
                            Err(e) => {
                                // Configuration errors apply to every item; report them all.
                                loop {
                                    let i = next.fetch_add(1, Ordering::Relaxed);
                                    if i >= total {
                                        return mine;
                                    }
                                    mine.push((i, Err(e.clone())));
                                }
                            }
                        };
                        loop {
                            if cancel.load(Ordering::Relaxed) {
                                return mine;
                            }
                            let i = next.fetch_add(1, Ordering::Relaxed);
                            if i >= total {
                                return mine;
                            }
                            let item = items[i];
                            let r = mapper.map_cancellable(item.frames, item.registration, robot, cancel);
                            match r {
                                Some(r) => {
                                    mine.push((i, r));
                                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                                    progress(d, total);
                                }
                                None => return mine,
                            }
                        }
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("mapping worker panicked"))
                .collect()
        });
    for chunk in chunks {
        for (i, r) in chunk {
            results[i] = Some(r);
        }
    }
    if cancel.load(Ordering::Relaxed) || results.iter().any(Option::is_none) {
        return Err(Cancelled {
            completed: done.load(Ordering::Relaxed),
            total,
        });
    }
    Ok(results.into_iter().map(|r| r.expect("checked above")).collect())
}
