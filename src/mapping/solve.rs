//! Trajectory solving: one bounded NLP per frame (eq. 6-7), warm-started from the previous frame.
//!
//! The first frame is a global problem (no previous solution): several starts, best kept. Every
//! later frame starts at the previous solution and its box is the joint limits intersected with a
//! step bound around it (`|q_k − q_{k−1}| ≤ scale · v_max · Δt`), so consecutive solutions cannot
//! jump to another IK branch. A frame that does not converge is solved as far as it gets, kept
//! (the trajectory stays continuous) and reported as `converged: false` — never hidden.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::MappingError;
use super::goals::MAX_FINGERS;
use super::objective::{
    Evaluator, FrameGoals, MappingModel, Objective, Term, Weights, swivel_angle,
};
use crate::geometry::{Category, CheckData, CollisionChecker, SignedDistance};
use crate::optim::{BoxReport, BoxSolver, PairOrder};
use nalgebra::Point3;

/// How far (rad, per joint) a batch's local first-frame solve may move from the reference
/// posture: a wrist flip (about π on two wrist joints) is another branch, not a nearby posture,
/// and an unbounded local solve slid into it on 12 of 25 pa10_ob4f demonstrations.
pub const FIRST_FRAME_RADIUS: f64 = 1.0;

/// Default of [`SolverOptions::first_frame_fallback`] (measured: see `probe_first_frame_reference`).
pub const FIRST_FRAME_FALLBACK: f64 = 2.0;

/// The first-frame posture a batch's demonstrations start from: the multi-start solution of the
/// first demonstration's first frame, and its objective (the weighted solve's, before the
/// fingertip-priority stage: the frame chain starts from it).
#[derive(Clone, Debug, PartialEq)]
pub struct StartReference {
    pub q: Vec<f64>,
    pub objective: f64,
}

/// Solver settings of a mapping run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverOptions {
    /// Stopping tolerance of the NLP solver on the (scaled) fixed-point residual, in joint units:
    /// 1e-4 rad moves a fingertip by well under 0.1 mm and keeps the warm-started objective
    /// within ~0.2 % (median frame) of a 1e-10 reference (measured by the tolerance probe test
    /// and the bench).
    pub tolerance: f64,
    /// Tolerance of the first frame, which has no warm start to lean on.
    pub first_frame_tolerance: f64,
    /// Iteration cap of a warm-started frame.
    pub max_iterations: usize,
    /// Iteration cap of each start of the first frame.
    pub first_frame_max_iterations: usize,
    /// Starts tried on the first frame (the mid-range configuration plus seeded random ones).
    pub first_frame_starts: usize,
    /// Seed of the first-frame random starts.
    pub seed: u64,
    /// A batch's first frames are solved locally from one reference posture
    /// ([`Mapper::solve_first_from`]); the multi-start runs instead only if that local solve's
    /// objective exceeds this factor times the reference frame's, and its result replaces the
    /// local one only if the local objective also exceeds this factor times the multi-start's.
    pub first_frame_fallback: f64,
    /// Joint step bound per frame as a multiple of `velocity limit · Δt`.
    pub step_scale: f64,
    /// Joint speed used for the step bound when a joint has no positive finite velocity limit.
    pub fallback_speed: f64,
    /// Weight of the clearance penalty `Σ max(0, margin − d)²` over the exact signed distances
    /// `d` of the robot's collision shapes to the support plane (every frame) and to the object
    /// (before `object_free_until` of the reach), per m². Not in the paper (its eq. 1-7 have no
    /// scene); without it a robot fingertip pad reaching the subject's fingertip resting on the
    /// table sinks its own radius into the table. Active only with [`MappingModel::geometry`].
    pub clearance_weight: f64,
    /// Distance below which the clearance penalty acts, m.
    pub clearance_margin: f64,
    /// Fraction of the demonstration's duration during which the object is kept out of (the
    /// final part is the grasp, where the fingers meet it).
    pub object_free_until: f64,
    /// Fingertip priority `K ≥ 1`: every frame's weighted solve (eq. 5 plus the clearance
    /// penalty) is followed by a second solve from its result with the fingertip position
    /// weight and the clearance weight multiplied by `K`, the other terms unchanged. As `K`
    /// grows this tends to the lexicographic solution: fingertips (kept clear of the scene)
    /// first, the anthropomorphism terms only in the self-motion they leave. One weighted sum
    /// trades about 7 mm of fingertip error for the elbow and swivel terms where those press
    /// against their joint-limit floors; solving the frame chain with the stiffer sum instead
    /// stops in worse minima (measured in `probe_fingertip_reachability`). `1` (the default)
    /// turns the stage off: the paper's single weighted sum. Off by default because the motion
    /// models learned from the prioritised mappings lost plans downstream (README, Mappings);
    /// `1000` is the measured setting. Not in the paper.
    pub fingertip_priority: f64,
    /// Iteration cap of the fingertip-priority stage.
    pub priority_max_iterations: usize,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            tolerance: 1e-4,
            first_frame_tolerance: 1e-7,
            max_iterations: 100,
            first_frame_max_iterations: 1000,
            first_frame_starts: 8,
            seed: 0x5eed,
            first_frame_fallback: FIRST_FRAME_FALLBACK,
            step_scale: 2.0,
            fallback_speed: 3.0,
            clearance_weight: 1e3,
            clearance_margin: 0.005,
            object_free_until: 0.9,
            fingertip_priority: 1.0,
            priority_max_iterations: 200,
        }
    }
}

impl SolverOptions {
    pub fn validate(&self) -> Result<(), MappingError> {
        let bad =
            |field: &'static str, value: f64| Err(MappingError::InvalidOption { field, value });
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return bad("tolerance", self.tolerance);
        }
        if !(self.first_frame_tolerance.is_finite() && self.first_frame_tolerance > 0.0) {
            return bad("first_frame_tolerance", self.first_frame_tolerance);
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
        if !(self.first_frame_fallback.is_finite() && self.first_frame_fallback >= 1.0) {
            return bad("first_frame_fallback", self.first_frame_fallback);
        }
        if !(self.step_scale.is_finite() && self.step_scale > 0.0) {
            return bad("step_scale", self.step_scale);
        }
        if !(self.fallback_speed.is_finite() && self.fallback_speed > 0.0) {
            return bad("fallback_speed", self.fallback_speed);
        }
        if !(self.clearance_weight.is_finite() && self.clearance_weight >= 0.0) {
            return bad("clearance_weight", self.clearance_weight);
        }
        if !(self.clearance_margin.is_finite() && self.clearance_margin >= 0.0) {
            return bad("clearance_margin", self.clearance_margin);
        }
        if !(self.object_free_until.is_finite() && (0.0..=1.0).contains(&self.object_free_until)) {
            return bad("object_free_until", self.object_free_until);
        }
        if !(self.fingertip_priority.is_finite() && self.fingertip_priority >= 1.0) {
            return bad("fingertip_priority", self.fingertip_priority);
        }
        if self.priority_max_iterations == 0 {
            return bad("priority_max_iterations", 0.0);
        }
        Ok(())
    }
}

/// What one frame's solve achieved. Equality treats NaN ("not measured") as equal to NaN.
#[derive(Clone, Copy, Debug)]
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
    /// Iterations of both stages (the weighted solve and the fingertip-priority one).
    pub iterations: usize,
    /// Whether the weighted solve (the frame chain's) converged.
    pub converged: bool,
    /// Elbow swivel angles ([`super::objective::swivel_angle`]) of the registered human arm and
    /// of the robot arm, and the absolute difference wrapped to `[0, π]`, rad (NaN without arm
    /// frames).
    pub swivel_human: f64,
    pub swivel_robot: f64,
    pub swivel_difference: f64,
    /// Lower bound on the human-elbow-to-robot-elbow distance at this frame: the distance from
    /// the human elbow to the circle the robot elbow can lie on given its shoulder, its wrist and
    /// its upper-arm and forearm lengths, m (NaN without arm frames).
    pub elbow_bound: f64,
    /// Smallest exact signed distance of any robot link or fingertip shape to the support plane
    /// and to the object (parry, URDF collision shapes; `src/geometry`), m. NaN when the mapping
    /// ran without geometry or the scene has no such member.
    pub support_clearance: f64,
    pub object_clearance: f64,
}

impl PartialEq for FrameMetrics {
    fn eq(&self, o: &Self) -> bool {
        let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
        let scalars = [
            (self.t, o.t),
            (self.elbow_distance, o.elbow_distance),
            (self.elbow_distance_mean, o.elbow_distance_mean),
            (self.objective, o.objective),
            (self.swivel_human, o.swivel_human),
            (self.swivel_robot, o.swivel_robot),
            (self.swivel_difference, o.swivel_difference),
            (self.elbow_bound, o.elbow_bound),
            (self.support_clearance, o.support_clearance),
            (self.object_clearance, o.object_clearance),
        ];
        self.fingers == o.fingers
            && self.iterations == o.iterations
            && self.converged == o.converged
            && scalars.iter().all(|&(a, b)| same(a, b))
            && (0..MAX_FINGERS).all(|i| {
                same(self.position_error[i], o.position_error[i])
                    && same(self.orientation_error[i], o.orientation_error[i])
            })
    }
}

/// Distance from `p` to the circle of points at `l1` from `s` and `l2` from `w` (closest point of
/// the sphere `‖x − s‖ = l1` when the two spheres do not meet).
pub fn elbow_circle_distance(
    s: &Point3<f64>,
    w: &Point3<f64>,
    l1: f64,
    l2: f64,
    p: &Point3<f64>,
) -> f64 {
    let axis = w - s;
    let d = axis.norm();
    if d < 1e-12 {
        return ((p - s).norm() - l1).abs();
    }
    let a = axis / d;
    let x = ((l1 * l1 - l2 * l2 + d * d) / (2.0 * d)).clamp(-l1, l1);
    let rho = (l1 * l1 - x * x).max(0.0).sqrt();
    let v = p - (s + a * x);
    let along = v.dot(&a);
    let across = (v - a * along).norm();
    (along * along + (across - rho).powi(2)).sqrt()
}

/// The reusable per-worker mapping solver: FK scratch, solver cache, bound buffers. Mapping a
/// frame allocates nothing.
pub struct Mapper {
    pub(super) eval: Evaluator,
    pub(super) solver: BoxSolver,
    pub(super) terms: Vec<Term>,
    /// `terms` with the orientation and anthropomorphism weights divided by
    /// [`SolverOptions::fingertip_priority`].
    pub(super) priority_terms: Vec<Term>,
    /// The weighted solve's posture at the last frame and its objective: the next frame's warm
    /// start (the frame chain runs on the weighted objective alone), and a batch's first-frame
    /// reference. Equal to `q` when the priority stage is off.
    pub(super) chain: Vec<f64>,
    /// Set by the first-frame solves only (the batch references need it; a warm-started frame
    /// would pay one more forward kinematics for nothing).
    pub(super) chain_objective: f64,
    /// The previous frame's output (`q`), whose step bound the priority stage keeps.
    pub(super) previous: Vec<f64>,
    pub(super) local_chain: Vec<f64>,
    /// The priority stage's start.
    pub(super) start: Vec<f64>,
    pub(super) options: SolverOptions,
    pub(super) lo: Vec<f64>,
    pub(super) hi: Vec<f64>,
    pub(super) step: Vec<f64>,
    pub(super) q: Vec<f64>,
    pub(super) orders: Vec<PairOrder>,
    pub(super) best: Vec<f64>,
    pub(super) local: Vec<f64>,
    /// Collision shapes for the exact clearance metrics (`None`: not measured).
    pub(super) geometry: Option<std::sync::Arc<crate::geometry::RobotGeometry>>,
    /// The current demonstration's scene (set by the trajectory mapping), its scratch, and
    /// whether the object is kept out of at the frame being solved.
    pub(super) clearance: Option<Clearance>,
}

/// The clearance penalty's state for one demonstration.
pub(super) struct Clearance {
    pub checker: CollisionChecker,
    pub data: CheckData,
    pub object: bool,
    /// `(pair, distance)` within the margin at the last evaluation; capacity = pair count.
    pub near: Vec<(usize, SignedDistance)>,
    pub tmp: Vec<f64>,
    /// The non-allowed support pairs, and the support and object pairs: the only pairs the
    /// penalty can see (self-collision pairs, most of the checker's, are never visited).
    support_pairs: Vec<usize>,
    scene_pairs: Vec<usize>,
    /// The checker's model is the objective's: the penalty reuses the objective's forward
    /// kinematics at the same point instead of running it a second time (it was half the
    /// whole mapping's time).
    shared_fk: bool,
}

impl Clearance {
    pub fn new(
        checker: CollisionChecker,
        model: &std::sync::Arc<crate::kinematics::Model>,
    ) -> Self {
        Self {
            data: checker.data(),
            near: Vec::with_capacity(checker.pairs().len()),
            support_pairs: checker.pairs_in(&[Category::Support]),
            scene_pairs: checker.pairs_in(&[Category::Support, Category::Object]),
            shared_fk: std::sync::Arc::ptr_eq(model, checker.robot().model()),
            checker,
            object: true,
            tmp: vec![0.0; model.nq()],
        }
    }

    /// `w Σ max(0, m − d)²` over the support (and object) pairs at `q`; `grad +=` its gradient.
    ///
    /// Exact: every pair whose exact (parry) signed distance is below the margin contributes;
    /// a pair is skipped only when its posed bounding spheres are the margin or more apart, a
    /// lower bound on its distance, so it could not contribute.
    pub(super) fn penalty(
        &mut self,
        eval: &mut Evaluator,
        q: &[f64],
        weight: f64,
        margin: f64,
        grad: Option<&mut [f64]>,
    ) -> f64 {
        if weight == 0.0 {
            return 0.0;
        }
        let pairs = if self.object {
            &self.scene_pairs
        } else {
            &self.support_pairs
        };
        self.near.clear();
        let near = &mut self.near;
        if self.shared_fk {
            eval.update(q);
            self.data.swap_kinematics(eval.kinematics_mut());
        } else {
            self.checker.update(&mut self.data, q);
        }
        self.checker
            .for_each_within_posed(&mut self.data, margin, pairs, |i, d| near.push((i, *d)));
        let mut value = 0.0;
        let mut grad = grad;
        for &(pair, d) in &self.near {
            let e = margin - d.distance;
            value += weight * e * e;
            if let Some(g) = grad.as_deref_mut() {
                self.tmp.fill(0.0);
                self.checker
                    .add_distance_gradient(&self.data, pair, &d, &mut self.tmp);
                for (gi, ti) in g.iter_mut().zip(&self.tmp) {
                    *gi -= 2.0 * weight * e * ti;
                }
            }
        }
        if self.shared_fk {
            self.data.swap_kinematics(eval.kinematics_mut());
        }
        value
    }
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
            geometry: mm.geometry.clone(),
            solver: BoxSolver::new(nq, options.tolerance),
            orders: mm.orders.clone(),
            eval: Evaluator::new(mm),
            terms: weights.terms(),
            priority_terms: {
                // Divided rather than the position and clearance weights multiplied: the same
                // minimiser at the weighted objective's scale, for which the tolerances and the
                // clearance weight were chosen.
                let k = options.fingertip_priority;
                Weights {
                    orientation: weights.orientation / k,
                    elbow: weights.elbow / k,
                    swivel: weights.swivel / k,
                    ..weights
                }
                .terms()
            },
            chain: vec![0.0; nq],
            chain_objective: f64::NAN,
            previous: vec![0.0; nq],
            local_chain: vec![0.0; nq],
            start: vec![0.0; nq],
            options,
            lo: vec![0.0; nq],
            hi: vec![0.0; nq],
            step: vec![0.0; nq],
            q: vec![0.0; nq],
            best: vec![0.0; nq],
            local: vec![0.0; nq],
            clearance: None,
        })
    }

    /// Measures the exact support and object clearances of every mapped frame with these
    /// collision shapes (built from the same model, e.g. `RobotGeometry::from_system`; the
    /// default is the [`MappingModel::geometry`]); `None` skips them (NaN in the metrics).
    pub fn with_geometry(
        mut self,
        geometry: Option<std::sync::Arc<crate::geometry::RobotGeometry>>,
    ) -> Self {
        self.geometry = geometry;
        self
    }

    pub fn model(&self) -> &MappingModel {
        self.eval.model()
    }

    pub fn terms(&self) -> &[Term] {
        &self.terms
    }

    /// Solves one frame inside `[lo, hi]` from `q` (updated in place), on the weighted
    /// objective or (`priority`) on the fingertip-priority one.
    fn solve_in_box(
        &mut self,
        goals: &FrameGoals,
        max_iter: usize,
        tolerance: f64,
        priority: bool,
    ) -> BoxReport {
        let Self {
            eval,
            solver,
            terms,
            priority_terms,
            lo,
            hi,
            q,
            orders,
            clearance,
            options,
            ..
        } = self;
        let (w, margin) = (options.clearance_weight, options.clearance_margin);
        let terms = if priority { priority_terms } else { terms };
        let mut f = |x: &[f64], g: Option<&mut [f64]>| match (g, clearance.as_mut()) {
            (Some(g), Some(c)) => {
                let v = eval.value_and_gradient(terms, goals, x, g);
                v + c.penalty(eval, x, w, margin, Some(g))
            }
            (Some(g), None) => eval.value_and_gradient(terms, goals, x, g),
            (None, Some(c)) => eval.value(terms, goals, x) + c.penalty(eval, x, w, margin, None),
            (None, None) => eval.value(terms, goals, x),
        };
        solver.solve(lo, hi, orders, &mut f, q, max_iter, tolerance)
    }

    /// Keeps the weighted solution in `q` as the chain, then runs the fingertip-priority stage
    /// inside `[lo, hi]` (the caller's box, which holds `previous`) from the point of the
    /// segment `previous → q` nearest `q` inside it. Returns the stage's iterations.
    ///
    /// Along the segment rather than joint by joint: clamping each arm joint on its own moves
    /// the hand somewhere neither posture put it (on one pa10_t42 frame both fingers 4 mm into
    /// the object from opposite sides, a pinch the box then kept the solve in).
    fn prioritise(&mut self, goals: &FrameGoals, tolerance: f64) -> usize {
        self.chain.copy_from_slice(&self.q);
        if self.options.fingertip_priority == 1.0 {
            return 0;
        }
        let mut along = 1.0_f64;
        for i in 0..self.q.len() {
            let (p, d) = (self.previous[i], self.q[i] - self.previous[i]);
            if p + d > self.hi[i] {
                along = along.min((self.hi[i] - p) / d);
            } else if p + d < self.lo[i] {
                along = along.min((self.lo[i] - p) / d);
            }
        }
        let along = along.max(0.0);
        for i in 0..self.q.len() {
            let x = self.previous[i] + along * (self.q[i] - self.previous[i]);
            self.q[i] = x.clamp(self.lo[i], self.hi[i]);
        }
        let before = self.deepest();
        self.start.copy_from_slice(&self.q);
        let max_iter = self.options.priority_max_iterations;
        let iterations = self
            .solve_in_box(goals, max_iter, tolerance, true)
            .iterations;
        // The penalty is a soft wall 5 mm deep: one long quasi-Newton step can cross it (on one
        // pa10_t42 frame the closed gripper jumped over the object's rim and held it between its
        // pads, 4 mm into it from both sides, where the two pads' pushes cancel). Fingertip
        // accuracy is never bought with penetration: such a result is dropped for its start.
        if self.deepest() < before.min(0.0) {
            self.q.copy_from_slice(&self.start);
        }
        iterations
    }

    /// The smallest exact signed distance of a penalised pair (support, and the object while it
    /// is kept out of) within the clearance margin at `q`; infinite without geometry or when
    /// none is that near.
    fn deepest(&mut self) -> f64 {
        let margin = self.options.clearance_margin;
        let Some(c) = self.clearance.as_mut() else {
            return f64::INFINITY;
        };
        c.penalty(&mut self.eval, &self.q, 1.0, margin, None);
        c.near
            .iter()
            .map(|(_, d)| d.distance)
            .fold(f64::INFINITY, f64::min)
    }

    /// First frame: several starts within the joint limits, best objective kept.
    pub fn solve_first(&mut self, goals: &FrameGoals, t: f64) -> FrameMetrics {
        let mm = self.eval.model();
        let (lower, upper) = (mm.lower.clone(), mm.upper.clone());
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
            self.lo.copy_from_slice(&lower);
            self.hi.copy_from_slice(&upper);
            let report = self.solve_in_box(
                goals,
                self.options.first_frame_max_iterations,
                self.options.first_frame_tolerance,
                false,
            );
            total_iter += report.iterations;
            let f = self.total_value(goals);
            if best.is_none_or(|(bf, _, _)| f < bf) {
                best = Some((f, report.iterations, report.converged));
                self.best.copy_from_slice(&self.q);
            }
        }
        let (_, _, converged) = best.expect("first_frame_starts ≥ 1 is validated");
        self.q.copy_from_slice(&self.best);
        self.lo.copy_from_slice(&lower);
        self.hi.copy_from_slice(&upper);
        self.previous.copy_from_slice(&self.q);
        self.chain_objective = self.eval.value(&self.terms, goals, &self.q);
        total_iter += self.prioritise(goals, self.options.first_frame_tolerance);
        self.metrics(goals, t, total_iter, converged)
    }

    /// First frame of one demonstration of a batch: a local solve inside the joint limits from
    /// the batch's reference posture, so near-identical rest poses map to near-identical robot
    /// postures instead of to whichever IK branch the multi-start happens to find. Falls back to
    /// [`Self::solve_first`] only when the local solve is much worse (see
    /// [`SolverOptions::first_frame_fallback`], comparing the weighted objectives of the chain
    /// postures); `iterations` counts both solves then.
    pub fn solve_first_from(
        &mut self,
        goals: &FrameGoals,
        t: f64,
        reference: &StartReference,
    ) -> FrameMetrics {
        let mm = &self.eval.mm;
        for (i, &r) in reference.q.iter().enumerate() {
            self.lo[i] = mm.lower[i].max(r - FIRST_FRAME_RADIUS);
            self.hi[i] = mm.upper[i].min(r + FIRST_FRAME_RADIUS);
        }
        self.q.copy_from_slice(&reference.q);
        let report = self.solve_in_box(
            goals,
            self.options.first_frame_max_iterations,
            self.options.first_frame_tolerance,
            false,
        );
        self.previous.copy_from_slice(&self.q);
        let local_objective = self.eval.value(&self.terms, goals, &self.q);
        self.chain_objective = local_objective;
        let extra = self.prioritise(goals, self.options.first_frame_tolerance);
        let local = self.metrics(goals, t, report.iterations + extra, report.converged);
        let factor = self.options.first_frame_fallback;
        // A reference objective of exactly 0 would make any residual "much worse"; the floor is
        // far below any real frame's objective (fingertip errors of ~1e-5 m).
        if local_objective <= factor * reference.objective.max(1e-10) {
            return local;
        }
        self.local.copy_from_slice(&self.q);
        self.local_chain.copy_from_slice(&self.chain);
        let mut multi = self.solve_first(goals, t);
        if local_objective > factor * self.chain_objective {
            multi.iterations += local.iterations;
            return multi;
        }
        self.q.copy_from_slice(&self.local);
        self.chain.copy_from_slice(&self.local_chain);
        self.chain_objective = local_objective;
        FrameMetrics {
            iterations: local.iterations + multi.iterations,
            ..local
        }
    }

    /// A later frame: warm start from the previous weighted solution inside the step-bounded
    /// box; then the fingertip-priority stage inside the same step bound around the previous
    /// output, so the output moves no faster than the chain may.
    pub fn solve_next(&mut self, goals: &FrameGoals, t: f64, dt: f64) -> FrameMetrics {
        self.previous.copy_from_slice(&self.q);
        self.q.copy_from_slice(&self.chain);
        let mm = &self.eval.mm;
        let (lower, upper, vmax) = (&mm.lower, &mm.upper, mm.model.velocity_limits());
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
        let report = self.solve_in_box(
            goals,
            self.options.max_iterations,
            self.options.tolerance,
            false,
        );
        let mm = &self.eval.mm;
        for i in 0..self.q.len() {
            self.lo[i] = mm.lower[i].max(self.previous[i] - self.step[i]);
            self.hi[i] = mm.upper[i].min(self.previous[i] + self.step[i]);
        }
        let extra = self.prioritise(goals, self.options.tolerance);
        self.metrics(goals, t, report.iterations + extra, report.converged)
    }

    /// The objective plus the clearance penalty at the current solution.
    fn total_value(&mut self, goals: &FrameGoals) -> f64 {
        let v = self.eval.value(&self.terms, goals, &self.q);
        let (w, m) = (self.options.clearance_weight, self.options.clearance_margin);
        match &mut self.clearance {
            Some(c) => v + c.penalty(&mut self.eval, &self.q, w, m, None),
            None => v,
        }
    }

    /// The current solution (the last solved frame's output).
    pub fn solution(&self) -> &[f64] {
        &self.q
    }

    /// The last frame's weighted solution (the frame chain's posture; [`Self::solution`] when
    /// the fingertip-priority stage is off) and, after a first-frame solve, its objective.
    pub fn chain(&self) -> (&[f64], f64) {
        (&self.chain, self.chain_objective)
    }

    /// Sets the warm start for [`Self::solve_next`] (output and chain).
    pub fn set_solution(&mut self, q: &[f64]) {
        self.q.copy_from_slice(q);
        self.chain.copy_from_slice(q);
    }

    fn metrics(
        &mut self,
        goals: &FrameGoals,
        t: f64,
        iterations: usize,
        converged: bool,
    ) -> FrameMetrics {
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
        let (mut swivel_human, mut swivel_robot, mut swivel_difference, mut elbow_bound) =
            (f64::NAN, f64::NAN, f64::NAN, f64::NAN);
        if let Some([s, e, w]) = self.eval.arm_points() {
            let up = nalgebra::Vector3::z();
            swivel_human = swivel_angle(&goals.shoulder, &goals.elbow, &goals.wrist, &up);
            swivel_robot = swivel_angle(&s, &e, &w, &up);
            let d = (swivel_robot - swivel_human).rem_euclid(std::f64::consts::TAU);
            swivel_difference = d.min(std::f64::consts::TAU - d);
            elbow_bound =
                elbow_circle_distance(&s, &w, (e - s).norm(), (w - e).norm(), &goals.elbow);
        }
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
            swivel_human,
            swivel_robot,
            swivel_difference,
            elbow_bound,
            support_clearance: f64::NAN,
            object_clearance: f64::NAN,
        }
    }
}

/// A box for random starts: the limits, or ±π where a joint is unbounded.
fn finite_range(l: f64, u: f64) -> (f64, f64) {
    let l = if l.is_finite() {
        l
    } else {
        -std::f64::consts::PI
    };
    let u = if u.is_finite() {
        u
    } else {
        std::f64::consts::PI
    };
    (l, u.max(l))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::objective::tests::toy_system;
    use nalgebra::{Point3, UnitQuaternion};

    /// Goals the robot meets exactly at `q*`: its own fingertip poses.
    fn goals_at(mm: &MappingModel, q: &[f64]) -> FrameGoals {
        let mut ev = Evaluator::new(mm.clone());
        ev.update(q);
        let mut g = FrameGoals::default();
        for i in 0..mm.fingers() {
            g.fingers[i].position = ev.tip_position(i);
            g.fingers[i].orientation = ev.tip_orientation(i);
        }
        g.elbow = Point3::new(0.3, -0.3, 0.5);
        g
    }

    fn random_q(mm: &MappingModel, rng: &mut ChaCha8Rng) -> Vec<f64> {
        (0..mm.lower.len())
            .map(|k| {
                let (l, u) = (mm.lower[k], mm.upper[k]);
                l + (u - l) * rng.random_range(0.15..0.85)
            })
            .collect()
    }

    #[test]
    fn first_frame_recovers_reachable_fingertip_goals() {
        let mm = toy_system();
        let w = Weights {
            position: 1.0,
            orientation: 1e-3,
            elbow: 0.0,
            swivel: 0.0,
        };
        let mut mapper = Mapper::new(mm.clone(), w, SolverOptions::default()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..3 {
            let q_star = random_q(&mm, &mut rng);
            let goals = goals_at(&mm, &q_star);
            let m = mapper.solve_first(&goals, 0.0);
            let worst = m.position_error[..m.fingers]
                .iter()
                .cloned()
                .fold(0.0, f64::max);
            assert!(
                worst < 2e-3,
                "fingertip error {worst} m, objective {}",
                m.objective
            );
            for (k, &x) in mapper.solution().iter().enumerate() {
                assert!(x >= mm.lower[k] && x <= mm.upper[k]);
            }
        }
    }

    #[test]
    fn next_frame_stays_within_the_step_bound_and_the_limits() {
        let mm = toy_system();
        let opts = SolverOptions {
            step_scale: 1.0,
            ..SolverOptions::default()
        };
        let mut mapper = Mapper::new(mm.clone(), Weights::default(), opts).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let q0 = random_q(&mm, &mut rng);
        mapper.set_solution(&q0);
        // A goal far away: the step bound must hold the solution back.
        let mut goals = goals_at(&mm, &random_q(&mm, &mut rng));
        goals.fingers[0].orientation = UnitQuaternion::identity();
        let dt = 0.01;
        let m = mapper.solve_next(&goals, dt, dt);
        let vmax = mm.model.velocity_limits();
        let mut moved = 0.0_f64;
        for (k, (&a, &b)) in q0.iter().zip(mapper.solution()).enumerate() {
            assert!(
                (b - a).abs() <= vmax[k] * dt * (1.0 + 1e-12),
                "joint {k} stepped {}",
                b - a
            );
            assert!(b >= mm.lower[k] && b <= mm.upper[k]);
            moved = moved.max((b - a).abs());
        }
        assert!(
            moved > 0.5 * 2.0 * dt,
            "the solution should move towards the goal"
        );
        assert!(m.iterations <= opts.max_iterations);
    }

    #[test]
    fn options_are_validated() {
        let bad = SolverOptions {
            tolerance: -1.0,
            ..SolverOptions::default()
        };
        assert!(matches!(
            Mapper::new(toy_system(), Weights::default(), bad),
            Err(MappingError::InvalidOption {
                field: "tolerance",
                ..
            })
        ));
        let bad = SolverOptions {
            first_frame_starts: 0,
            ..SolverOptions::default()
        };
        assert!(bad.validate().is_err());
    }
}
