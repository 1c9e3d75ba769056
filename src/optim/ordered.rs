//! Allocation-free PANOC entry for hot loops: a reusable solver over a box intersected with
//! pair orderings, borrowed bounds, one `FnMut` for cost and gradient.
//!
//! Why next to [`super::Solver`] rather than through it: [`super::Problem`] owns its bounds and
//! boxes its closures (an allocation per problem) and supports general constraints only through
//! the augmented Lagrangian method, which holds them approximately and only at convergence. The
//! motion mapping (paper eq. 6-7) solves thousands of frames per second (the ≥ 5,000 frames/s
//! bench) and needs (a) no allocation per frame and (b) the spread ordering (eq. 28) as an exact
//! projection, so it holds on every iterate like the joint limits. Both entries run the same
//! backend through `optim::panoc` and the same feasible set type ([`OrderedBox`]; with no pairs it is
//! the plain box the general adapter uses).
//!
//! Why PANOC (optimization_engine): the mapping problem is a smooth (up to the eq. 3 cone at zero
//! orientation error) nonconvex objective under simple bounds (eq. 7); PANOC needs only cost and
//! gradient, projects onto the feasible set exactly (every iterate respects the limits),
//! warm-starts well, and keeps all its buffers in a reusable cache.

use std::cell::RefCell;

use optimization_engine::constraints::Constraint;
use optimization_engine::core::ExitStatus;
use optimization_engine::panoc::PANOCCache;

/// L-BFGS memory: enough for the ~10-20 coupled joint coordinates of an arm-hand system.
const LBFGS_MEMORY: usize = 10;

/// `alpha · q[i] + beta · q[j] ≤ gamma` with `i ≠ j`: the spread ordering of eq. 28 written in
/// independent coordinates (a mimic-driven spread joint contributes its multiplier and offset).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairOrder {
    pub i: usize,
    pub j: usize,
    pub alpha: f64,
    pub beta: f64,
    pub gamma: f64,
}

/// The feasible set of one frame: a box intersected with pair orderings on disjoint coordinate
/// pairs. Its Euclidean projection is exact and cheap, so PANOC keeps every iterate feasible —
/// the spread ordering holds exactly, like the limits, instead of being penalised.
///
/// Projection (per pair, after clamping to the box): if the clamped point satisfies the
/// ordering it is the projection; otherwise the ordering is active at the projection (KKT), so
/// the projection is the point of the line `α y_i + β y_j = γ` inside the box nearest to the
/// original point — the foot of the perpendicular, clamped along the line to the box.
pub struct OrderedBox<'a> {
    pub lower: &'a [f64],
    pub upper: &'a [f64],
    pub pairs: &'a [PairOrder],
}

impl Constraint for OrderedBox<'_> {
    fn project(&self, x: &mut [f64]) -> optimization_engine::FunctionCallResult {
        // Pair coordinates must be projected from their unclamped values: remember them first.
        let mut saved = [(0.0, 0.0); MAX_PAIRS];
        for (s, p) in saved.iter_mut().zip(self.pairs) {
            *s = (x[p.i], x[p.j]);
        }
        for (k, v) in x.iter_mut().enumerate() {
            *v = v.max(self.lower[k]).min(self.upper[k]);
        }
        for (p, &(xi, xj)) in self.pairs.iter().zip(saved.iter()) {
            if p.alpha * x[p.i] + p.beta * x[p.j] <= p.gamma {
                continue;
            }
            project_pair(p, xi, xj, self.lower, self.upper, x);
        }
        Ok(())
    }

    fn is_convex(&self) -> bool {
        true
    }
}

/// Nearest point to `(xi, xj)` on `α y_i + β y_j = γ` within the box, written into `x`.
fn project_pair(p: &PairOrder, xi: f64, xj: f64, lower: &[f64], upper: &[f64], x: &mut [f64]) {
    let nn = p.alpha * p.alpha + p.beta * p.beta;
    let r = (p.alpha * xi + p.beta * xj - p.gamma) / nn;
    // Foot of the perpendicular and the line direction.
    let (yi, yj) = (xi - r * p.alpha, xj - r * p.beta);
    let (di, dj) = (p.beta, -p.alpha);
    let mut t_lo = f64::NEG_INFINITY;
    let mut t_hi = f64::INFINITY;
    for (y, d, l, u) in [
        (yi, di, lower[p.i], upper[p.i]),
        (yj, dj, lower[p.j], upper[p.j]),
    ] {
        if d.abs() > 1e-300 {
            let (a, b) = ((l - y) / d, (u - y) / d);
            t_lo = t_lo.max(a.min(b));
            t_hi = t_hi.min(a.max(b));
        }
    }
    let t = 0.0_f64.max(t_lo).min(t_hi);
    x[p.i] = (yi + t * di).max(lower[p.i]).min(upper[p.i]);
    x[p.j] = (yj + t * dj).max(lower[p.j]).min(upper[p.j]);
}

/// Most ordered pairs one hand can have (a 5-finger hand has 4 adjacent spread pairs).
pub const MAX_PAIRS: usize = 8;

/// Outcome of one solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoxReport {
    pub iterations: usize,
    pub converged: bool,
}

/// `f(x, Some(g))` writes `∇f(x)` into `g`; both forms return `f(x)`.
pub type CostAndGradient<'a> = dyn FnMut(&[f64], Option<&mut [f64]>) -> f64 + 'a;

/// Reusable PANOC scratch for problems of one size (see the module documentation).
pub struct BoxSolver {
    cache: PANOCCache,
    backup: Vec<f64>,
}

impl BoxSolver {
    pub fn new(n: usize, tolerance: f64) -> Self {
        Self {
            cache: PANOCCache::new(n, tolerance, LBFGS_MEMORY),
            backup: vec![0.0; n],
        }
    }

    /// Minimises `f` over `[lower, upper]` from `q` (overwritten with the best feasible iterate).
    /// `f(x, Some(g))` must write `∇f(x)` into `g`; both forms return `f(x)`.
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        lower: &[f64],
        upper: &[f64],
        pairs: &[PairOrder],
        f: &mut CostAndGradient<'_>,
        q: &mut [f64],
        max_iter: usize,
        tolerance: f64,
    ) -> BoxReport {
        self.backup.copy_from_slice(q);
        let f = RefCell::new(f);
        let bounds = OrderedBox {
            lower,
            upper,
            pairs,
        };
        let cost = |x: &[f64], c: &mut f64| {
            *c = (f.borrow_mut())(x, None);
            Ok(())
        };
        let grad = |x: &[f64], g: &mut [f64]| {
            (f.borrow_mut())(x, Some(g));
            Ok(())
        };
        let status = super::panoc(
            &mut self.cache,
            &bounds,
            grad,
            cost,
            q,
            max_iter,
            tolerance,
            None,
        );
        match status {
            Ok(s) => BoxReport {
                iterations: s.iterations(),
                converged: s.exit_status() == ExitStatus::Converged,
            },
            // A non-finite cost or gradient: keep the start point and report the failure.
            Err(_) => {
                q.copy_from_slice(&self.backup);
                BoxReport {
                    iterations: 0,
                    converged: false,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn feasible(c: &OrderedBox<'_>, y: &[f64]) -> bool {
        y.iter()
            .enumerate()
            .all(|(k, v)| *v >= c.lower[k] - 1e-12 && *v <= c.upper[k] + 1e-12)
            && c.pairs
                .iter()
                .all(|p| p.alpha * y[p.i] + p.beta * y[p.j] <= p.gamma + 1e-12)
    }

    /// The projection is feasible, idempotent, and satisfies the variational inequality
    /// `⟨x − P(x), y − P(x)⟩ ≤ 0` for every feasible `y` (which characterises it).
    #[test]
    fn ordered_box_projection_is_the_euclidean_projection() {
        let lower = [-1.0, -0.5, 0.0, -2.0, -1.0];
        let upper = [1.0, 0.8, 2.0, 2.0, 1.0];
        let pairs = [
            PairOrder {
                i: 0,
                j: 1,
                alpha: 1.0,
                beta: -1.0,
                gamma: 0.0,
            },
            PairOrder {
                i: 3,
                j: 2,
                alpha: 0.5,
                beta: 2.0,
                gamma: 1.0,
            },
        ];
        let c = OrderedBox {
            lower: &lower,
            upper: &upper,
            pairs: &pairs,
        };
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut ys = Vec::new();
        while ys.len() < 400 {
            let y: Vec<f64> = (0..5)
                .map(|k| rng.random_range(lower[k]..=upper[k]))
                .collect();
            if feasible(&c, &y) {
                ys.push(y);
            }
        }
        for _ in 0..300 {
            let x: Vec<f64> = (0..5).map(|_| rng.random_range(-4.0..4.0)).collect();
            let mut p = x.clone();
            c.project(&mut p).unwrap();
            assert!(feasible(&c, &p), "{p:?}");
            let mut pp = p.clone();
            c.project(&mut pp).unwrap();
            assert!(p.iter().zip(&pp).all(|(a, b)| (a - b).abs() < 1e-12));
            for y in &ys {
                let vi: f64 = (0..5).map(|k| (x[k] - p[k]) * (y[k] - p[k])).sum();
                assert!(vi <= 1e-9, "variational inequality violated: {vi}");
            }
        }
    }
}
