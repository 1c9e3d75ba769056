//! A control-barrier-function safety filter on a joint velocity law (issue 18, item 3).
//!
//! A closed-loop law `u(q)` (the navigation function's flow, DESIGN §5) knows nothing of the
//! object, the support or obstacles. Each control period this filter replaces the law's command
//! `u₀` by the nearest command that keeps every monitored pair's barrier
//!
//! ```text
//! h_i(q) = d_i(q) − τ_i,   τ_i = m_i, or g_i − 0.5 mm for a pair closer than m_i at the goal
//! ```
//!
//! from falling faster than the arm can stop (`∇h_i · u ≥ −min(α h_i, √(2 A h_i))`, and
//! `∇h_i · u ≥ −α h_i` for a violated barrier, which drives it back), inside the joint velocity
//! bounds:
//!
//! ```text
//! u = argmin ½‖u − u₀‖²   s.t.   ∇h_i · u ≥ −γ(h_i)  (pairs within `influence` of their target),
//!                                |u_j| ≤ v_j.
//! ```
//!
//! `d_i` is the pair's exact signed distance (the URDF collision shape against the object, the
//! support half-space, an obstacle or a non-adjacent link) and `∇d_i` its gradient from the
//! witness points; `m_i` the margin (object, support, obstacles; a smaller one between links).
//! A pair that is closer than its margin at the goal `q_d` (the grasp's fingertip contacts, a
//! finger resting on the table, `g_i = d_i(q_d)`) may come as close as it is there, so the goal
//! stays admissible. With `h_i ≥ 0` and the constraint met, `h_i` stays non-negative (Nagumo).
//! The braking curve `√(2 A h)` keeps the command from asking the arm to stop faster than `A`
//! (the servo tracks a velocity command at its acceleration limit, not at once).
//!
//! A law run to several goals in turn ([`SafetyFilter::staged`]: an approach's pre-grasp, then
//! the grasp) lets each pair come as close as it is at any of them.
//!
//! A law that follows a path ([`SafetyFilter::filter_along`], the worker's path follower) is
//! filtered against its deviations from the path, not against the path: each near pair may
//! also approach as fast as it approaches on the path at the follower's clock,
//!
//! ```text
//! ∇h_i · u ≥ −γ(h_i) + min(0, ḋ_i(p(τ)))
//! ```
//!
//! (`ḋ_i(p(τ))` from the pair's distance at this and the last period's reference; only while
//! the pair is no closer than it is at the reference), so the path itself, checked exactly
//! with the plan, is always admissible. Where the robot is pushed off the path the clock
//! waits, the reference stands still and the barrier is the plain one. What this gives up: a
//! robot behind the path whose route meets a pair the path approaches may come closer than the
//! static target by at most what the path still approaches there; it is driven back at rate `α`
//! once it is closer than the path or the path stops approaching.
//!
//! What this does not give: the certified convergence of the unfiltered flow. Where the law
//! points into a barrier the filter slides along it or, against a wall the flow meets head-on,
//! stops (a boundary equilibrium); the run then ends by the worker's convergence timeout, safe
//! but not at the goal. A plan checks its timed trajectory, not the law's flow: measured on a
//! wam_ihy plan to the ball (tests/api/bridges.rs), the plain law passes 130 mm into the table;
//! filtered, it keeps out of everything but stops 0.1 rad short of the grasp, where its flow
//! closes a finger into the ball. Run in the approach's stages (the worker's, from the plan's
//! pre-grasp) the same law arrives. From a start whose hand is closed across the palm (that
//! plan's demonstrated start) the hand's flow opens the fingers into the thumb and the filter
//! holds them there: that start does not arrive.
//!
//! The projection is solved by Hildreth's dual coordinate ascent: one dual variable per
//! constraint, exact for one active constraint, converging to the projection otherwise; a
//! fixed number of sweeps (deterministic, no wall clock). Hand-rolled because the problem is a
//! Euclidean projection onto at most a few dozen half-spaces per period, solved 100 times a
//! second with no allocation, which a general QP crate does not offer.

use super::checker::{Category, CheckData, CollisionChecker};
use super::solid::SignedDistance;

/// Margins, gain and budget of a [`SafetyFilter`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BarrierOptions {
    /// Clearance kept from the object, the support and obstacles (m).
    pub margin: f64,
    /// Clearance kept between two links of the robot (m).
    pub self_margin: f64,
    /// A pair gets a constraint when it is closer than its target plus this (m). Far enough
    /// out that a link the law swings in fast is braked in time: the navigation function's
    /// flow turns the WAM's wrist at up to 4 rad/s, and with 0.3 m a pushed thumb reached the
    /// table 38 mm deep in 2 of 20 runs of a wam_ihy ball plan; with 0.5 m none did.
    pub influence: f64,
    /// `α` (1/s): how fast a barrier may fall towards zero near it, and how fast a violated one
    /// is restored.
    pub rate: f64,
    /// Deceleration a barrier's approach is limited to farther out (m/s²): `ḣ ≥ −√(2 A h)`, the
    /// speed from which the arm can still stop within `h`.
    pub braking: f64,
    /// Sweeps of the projection at most.
    pub sweeps: usize,
}

impl Default for BarrierOptions {
    fn default() -> Self {
        BarrierOptions {
            margin: 0.02,
            self_margin: 0.002,
            influence: 0.5,
            rate: 4.0,
            braking: 1.0,
            sweeps: 64,
        }
    }
}

/// What one filtered period did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BarrierStep {
    /// Constraints set up (pairs within their influence).
    pub constraints: usize,
    /// Constraints that changed the command.
    pub active: usize,
    /// Smallest barrier `h_i` of the monitored pairs (m; `f64::INFINITY` with none near).
    pub min_barrier: f64,
    /// Smallest exact distance of the monitored pairs (m; `f64::INFINITY` with none near).
    pub min_distance: f64,
    /// The pair of `min_distance` (index into [`CollisionChecker::pairs`]).
    pub closest: Option<usize>,
}

/// The filter of one execution: a checker of the robot in its scene, the goal and each pair's
/// clearance there, and scratch sized once (filtering allocates nothing).
pub struct SafetyFilter {
    checker: CollisionChecker,
    data: CheckData,
    opts: BarrierOptions,
    nq: usize,
    /// Per pair: `g_i`, its clearance at the goal (the closest of the goals) capped at its
    /// margin.
    goal_clearance: Vec<f64>,
    /// Per joint: the velocity bound of the command.
    velocity: Vec<f64>,
    near: Vec<(usize, SignedDistance)>,
    /// Constraint rows (gradients, row-major), right-hand sides, squared norms, duals.
    rows: Vec<f64>,
    rhs: Vec<f64>,
    norms: Vec<f64>,
    duals: Vec<f64>,
    /// Following a path ([`SafetyFilter::filter_along`]): the checker posed at the reference,
    /// per pair the period of its last distance there and that distance (`None`: never), and
    /// the period.
    reference: CheckData,
    reference_distance: Vec<Option<(u64, f64)>>,
    period: u64,
}

impl SafetyFilter {
    /// The filter for a motion to `goal` (model order) with joint velocity bounds `velocity`.
    pub fn new(
        checker: CollisionChecker,
        goal: &[f64],
        velocity: &[f64],
        opts: BarrierOptions,
    ) -> SafetyFilter {
        SafetyFilter::staged(checker, &[goal], velocity, opts)
    }

    /// The filter for a law run to several goals in turn (an approach's pre-grasp, then the
    /// grasp): a pair may come as close as it is at any of them, so each stays admissible.
    pub fn staged(
        checker: CollisionChecker,
        goals: &[&[f64]],
        velocity: &[f64],
        opts: BarrierOptions,
    ) -> SafetyFilter {
        let nq = checker.robot().model().nq();
        assert!(!goals.is_empty(), "at least one goal");
        assert!(
            goals.iter().all(|g| g.len() == nq),
            "one goal value per joint"
        );
        assert_eq!(velocity.len(), nq, "one velocity bound per joint");
        let mut data = checker.data();
        let pairs = checker.pairs().len();
        let mut goal_clearance: Vec<f64> = (0..pairs)
            .map(|i| pair_margin(&opts, checker.pairs()[i].category))
            .collect();
        for goal in goals {
            checker.update(&mut data, goal);
            for (i, g) in goal_clearance.iter_mut().enumerate() {
                if !checker.is_allowed(i) && checker.sphere_bound(&data, i) < *g {
                    *g = g.min(checker.pair_distance(&mut data, i).distance);
                }
            }
        }
        SafetyFilter {
            data,
            opts,
            nq,
            goal_clearance,
            velocity: velocity.to_vec(),
            near: Vec::with_capacity(pairs),
            rows: vec![0.0; pairs * nq],
            rhs: vec![0.0; pairs],
            norms: vec![0.0; pairs],
            duals: vec![0.0; pairs],
            reference: checker.data(),
            reference_distance: vec![None; pairs],
            period: 0,
            checker,
        }
    }

    pub fn checker(&self) -> &CollisionChecker {
        &self.checker
    }

    /// Replaces the command `u` (the law's, model order) at the measured `q` by the nearest
    /// safe one (see the module docs).
    pub fn filter(&mut self, q: &[f64], u: &mut [f64]) -> BarrierStep {
        self.filter_inner(q, None, u)
    }

    /// As [`SafetyFilter::filter`], for a law following a path whose reference (the path at
    /// the follower's clock) is `reference`, `dt` s after the last period: each near pair may
    /// also approach as fast as it does on the path there (`ḣ ≥ −γ(h) + min(0, ḋ_ref)`, the
    /// rate from the pair's distance at this and the last period's reference). The path is
    /// checked exactly; a static barrier alone brakes a pair the path brings to its closest at
    /// the goal exponentially (`ḣ ≥ −αh` while the path's `ḋ/h` grows as `3/(T − t)` on the
    /// minimum-jerk clock), and the follower, behind its clock, took another route into the
    /// grasp and stopped there (measured on a wam_ihy sunglasses plan: 0.029 rad short, the
    /// thumb on the frame). Where the clock waits (a push, `g → 0`) the reference stands still
    /// and the barrier is the plain one.
    pub fn filter_along(
        &mut self,
        q: &[f64],
        reference: &[f64],
        dt: f64,
        u: &mut [f64],
    ) -> BarrierStep {
        self.filter_inner(q, Some((reference, dt)), u)
    }

    fn filter_inner(
        &mut self,
        q: &[f64],
        along: Option<(&[f64], f64)>,
        u: &mut [f64],
    ) -> BarrierStep {
        let nq = self.nq;
        assert!(q.len() == nq && u.len() == nq, "one value per joint");
        let reach = self.opts.margin.max(self.opts.self_margin) + self.opts.influence;
        let near = &mut self.near;
        near.clear();
        self.checker
            .for_each_within(&mut self.data, q, reach, |i, d| near.push((i, *d)));
        let mut step = BarrierStep {
            min_barrier: f64::INFINITY,
            min_distance: f64::INFINITY,
            ..BarrierStep::default()
        };
        let mut rows = 0;
        // (the checker is posed at the reference once, for the first pair that needs it)
        let mut posed = false;
        self.period += 1;
        for k in 0..self.near.len() {
            let (i, d) = self.near[k];
            let m = pair_margin(&self.opts, self.checker.pairs()[i].category);
            let g = self.goal_clearance[i];
            // A pair closer than its margin at the goal (the grasp's contacts, a finger resting
            // on the table) may come as close as it is there, less a contact's tolerance.
            let target = if g < m { g - CONTACT_SLACK } else { m };
            let h = d.distance - target;
            step.min_barrier = step.min_barrier.min(h);
            if d.distance < step.min_distance {
                step.min_distance = d.distance;
                step.closest = Some(i);
            }
            if h >= self.opts.influence {
                continue;
            }
            let row = &mut self.rows[rows * nq..(rows + 1) * nq];
            row.fill(0.0);
            self.checker.add_distance_gradient(&self.data, i, &d, row);
            if row.iter().all(|x| x.abs() <= 1e-12) {
                // a pair no joint moves apart (a static link on the support, a link turning
                // about the vertical above it): nothing to filter
                continue;
            }
            let norm = row.iter().map(|x| x * x).sum::<f64>();
            self.norms[rows] = norm;
            // (along a path: as fast as the pair approaches there, from its distance at this
            // and the last period's reference; nothing the first period it is near)
            let path_rate = match along {
                Some((reference, dt)) => {
                    if !posed {
                        self.checker.update(&mut self.reference, reference);
                        posed = true;
                    }
                    let d_ref = self.checker.pair_distance(&mut self.reference, i).distance;
                    let last = self.reference_distance[i].replace((self.period, d_ref));
                    match last {
                        // (not for a pair already closer than the path has it: that is a
                        // deviation towards it, which the plain barrier brakes)
                        Some((at, before))
                            if at + 1 == self.period
                                && dt > 0.0
                                && d.distance >= d_ref - CONTACT_SLACK =>
                        {
                            ((d_ref - before) / dt).min(0.0)
                        }
                        _ => 0.0,
                    }
                }
                None => 0.0,
            };
            self.rhs[rows] = path_rate - approach_bound(&self.opts, h);
            rows += 1;
        }
        step.constraints = rows;
        // The nominal command inside the velocity bounds, its direction kept (a servo clamping
        // each joint on its own would turn it).
        let scale = u
            .iter()
            .zip(&self.velocity)
            .map(|(x, v)| x.abs() / v)
            .fold(1.0, f64::max);
        for x in u.iter_mut() {
            *x /= scale;
        }
        if rows > 0 {
            step.active = project(
                &self.rows[..rows * nq],
                &self.rhs[..rows],
                &self.norms[..rows],
                &self.velocity,
                &mut self.duals[..rows],
                u,
                self.opts.sweeps,
            );
        }
        step
    }
}

/// The fastest a barrier at `h` may fall: `min(αh, √(2Ah))` above zero (an exponential approach
/// near the target, a braking curve farther out, so the command never asks the arm to stop
/// faster than `A`), and `αh` below (a violated barrier is restored at rate `α`).
fn approach_bound(opts: &BarrierOptions, h: f64) -> f64 {
    if h > 0.0 {
        (opts.rate * h).min((2.0 * opts.braking * h).sqrt())
    } else {
        opts.rate * h
    }
}

/// How far below its clearance at the goal a contact pair may come in the final approach (m):
/// the tolerance of a contact.
const CONTACT_SLACK: f64 = 5e-4;

fn pair_margin(opts: &BarrierOptions, c: Category) -> f64 {
    match c {
        Category::SelfCollision => opts.self_margin,
        _ => opts.margin,
    }
}

/// Hildreth's method for `min ½‖u − u₀‖²` subject to `aᵢ·u ≥ bᵢ` (rows of `a`, squared norms
/// `norms`) and `|u_j| ≤ v_j`, from `u = u₀` in place. The bounds are handled exactly inside each
/// sweep as their own half-spaces (their duals are implicit in the clamp). Returns the number of
/// rows with a positive dual at the end.
pub fn project(
    a: &[f64],
    b: &[f64],
    norms: &[f64],
    bounds: &[f64],
    duals: &mut [f64],
    u: &mut [f64],
    sweeps: usize,
) -> usize {
    let n = u.len();
    duals.fill(0.0);
    // The bounds as dual variables too: u = u₀ + Σ λᵢ aᵢ + μ, with μ_j the bound's multiplier
    // (≤ 0 at the upper, ≥ 0 at the lower bound), so that a row's step can be undone by a bound
    // and the other way round (a plain clamp would not converge to the projection).
    let mut mu = [0.0f64; MAX_JOINTS];
    assert!(n <= MAX_JOINTS, "at most {MAX_JOINTS} joints");
    for _ in 0..sweeps {
        let mut change = 0.0f64;
        for (k, row) in a.chunks_exact(n).enumerate() {
            let r = b[k] - dot(row, u);
            let delta = (r / norms[k]).max(-duals[k]);
            if delta != 0.0 {
                duals[k] += delta;
                for j in 0..n {
                    u[j] += delta * row[j];
                }
                change = change.max(delta.abs() * norms[k].sqrt());
            }
        }
        for j in 0..n {
            // the bound's multiplier moves u_j back inside [-v, v]; released towards zero when
            // the rows no longer push it out
            let free = u[j] - mu[j];
            let clamped = free.clamp(-bounds[j], bounds[j]);
            let new_mu = clamped - free;
            change = change.max((new_mu - mu[j]).abs());
            mu[j] = new_mu;
            u[j] = clamped;
        }
        if change <= 1e-12 {
            break;
        }
    }
    duals.iter().filter(|&&l| l > 0.0).count()
}

/// Most joints a filtered law may have (the bundled systems have 9 to 16).
pub const MAX_JOINTS: usize = 64;

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// The projection by brute force over active sets (an independent method): for each subset
    /// of the constraints (rows and bounds) taken as equalities, the minimum-norm correction;
    /// the one that is feasible with non-negative multipliers is the optimum (KKT).
    fn brute_force(a: &[Vec<f64>], b: &[f64], u0: &[f64]) -> Vec<f64> {
        let n = u0.len();
        let m = a.len();
        let mut best: Option<(f64, Vec<f64>)> = None;
        for mask in 0u32..(1 << m) {
            let idx: Vec<usize> = (0..m).filter(|k| mask & (1 << k) != 0).collect();
            let u = if idx.is_empty() {
                u0.to_vec()
            } else {
                let am = DMatrix::from_fn(idx.len(), n, |r, c| a[idx[r]][c]);
                let res = DVector::from_fn(idx.len(), |r, _| {
                    b[idx[r]] - a[idx[r]].iter().zip(u0).map(|(x, y)| x * y).sum::<f64>()
                });
                let gram = &am * am.transpose();
                let Some(inv) = gram.try_inverse() else {
                    continue;
                };
                let lambda = inv * res;
                if lambda.iter().any(|&l| l < -1e-9) {
                    continue;
                }
                let du = am.transpose() * lambda;
                (0..n).map(|j| u0[j] + du[j]).collect()
            };
            let feasible = a
                .iter()
                .zip(b)
                .all(|(r, bk)| r.iter().zip(&u).map(|(x, y)| x * y).sum::<f64>() >= bk - 1e-9);
            if feasible {
                let cost: f64 = u.iter().zip(u0).map(|(x, y)| (x - y).powi(2)).sum();
                if best.as_ref().is_none_or(|(c, _)| cost < *c) {
                    best = Some((cost, u));
                }
            }
        }
        best.expect("a feasible problem").1
    }

    #[test]
    fn the_projection_matches_a_brute_force_kkt_solution() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 3;
        let bounds = [1.0, 0.8, 1.2];
        let mut worst = 0.0f64;
        for _ in 0..300 {
            let m = rng.random_range(1..=3);
            let rows: Vec<Vec<f64>> = (0..m)
                .map(|_| (0..n).map(|_| rng.random_range(-1.0..1.0)).collect())
                .collect();
            // feasible by construction: u = 0 satisfies a·u ≥ b for b ≤ 0 (a barrier that is
            // met; its rate term is −αh ≤ 0)
            let b: Vec<f64> = (0..m).map(|_| rng.random_range(-0.5..0.0)).collect();
            let u0: Vec<f64> = (0..n).map(|_| rng.random_range(-2.0..2.0)).collect();
            // the reference sees the bounds as rows too: u_j ≤ v_j and −u_j ≤ v_j
            let mut all = rows.clone();
            let mut all_b = b.clone();
            for j in 0..n {
                let mut e = vec![0.0; n];
                e[j] = -1.0;
                all.push(e.clone());
                all_b.push(-bounds[j]);
                e[j] = 1.0;
                all.push(e);
                all_b.push(-bounds[j]);
            }
            let want = brute_force(&all, &all_b, &u0);
            let flat: Vec<f64> = rows.iter().flatten().copied().collect();
            let norms: Vec<f64> = rows.iter().map(|r| dot(r, r)).collect();
            let mut duals = vec![0.0; m];
            let mut u = u0.clone();
            project(&flat, &b, &norms, &bounds, &mut duals, &mut u, 2000);
            let err = u
                .iter()
                .zip(&want)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            worst = worst.max(err);
        }
        assert!(
            worst < 1e-6,
            "largest difference from the KKT solution {worst}"
        );
    }

    #[test]
    fn one_constraint_is_projected_in_closed_form() {
        // a·u ≥ b with a = (3, 4): u = u₀ + max(0, (b − a·u₀)/|a|²) a
        let a = [3.0, 4.0];
        let u0 = [-1.0, -1.0];
        let b = [0.5];
        let mut u = u0;
        let mut duals = [0.0];
        let active = project(&a, &b, &[25.0], &[10.0, 10.0], &mut duals, &mut u, 1);
        let l = (0.5 - (-7.0)) / 25.0;
        assert_eq!(active, 1);
        assert!((u[0] - (-1.0 + 3.0 * l)).abs() < 1e-12);
        assert!((u[1] - (-1.0 + 4.0 * l)).abs() < 1e-12);
        // a command that already keeps it is left alone
        let mut u = [1.0, 1.0];
        assert_eq!(
            project(&a, &b, &[25.0], &[10.0, 10.0], &mut duals, &mut u, 8),
            0
        );
        assert_eq!(u, [1.0, 1.0]);
    }
}
