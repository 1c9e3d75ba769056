//! Box-constrained NLP solve for one frame: PANOC (optimization_engine) with L-BFGS directions.
//!
//! Why PANOC: the mapping problem is a smooth (up to the eq. 3 cone at zero orientation error)
//! nonconvex objective under simple bounds (eq. 7); PANOC needs only cost and gradient, projects
//! onto the box exactly (every iterate respects the limits), warm-starts well, and keeps all its
//! buffers in a reusable cache — the hot loop allocates nothing.

use std::cell::RefCell;

use optimization_engine::Problem;
use optimization_engine::constraints::Rectangle;
use optimization_engine::core::ExitStatus;
use optimization_engine::panoc::{PANOCCache, PANOCOptimizer};

/// L-BFGS memory: enough for the ~10-20 coupled joint coordinates of an arm-hand system.
const LBFGS_MEMORY: usize = 10;

/// Outcome of one solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveReport {
    pub iterations: usize,
    pub converged: bool,
}

/// Reusable PANOC scratch for problems of one size.
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
    pub fn solve(
        &mut self,
        lower: &[f64],
        upper: &[f64],
        f: &mut dyn FnMut(&[f64], Option<&mut [f64]>) -> f64,
        q: &mut [f64],
        max_iter: usize,
    ) -> SolveReport {
        self.backup.copy_from_slice(q);
        let f = RefCell::new(f);
        let bounds = Rectangle::new(Some(lower), Some(upper));
        let cost = |x: &[f64], c: &mut f64| {
            *c = (f.borrow_mut())(x, None);
            Ok(())
        };
        let grad = |x: &[f64], g: &mut [f64]| {
            (f.borrow_mut())(x, Some(g));
            Ok(())
        };
        let problem = Problem::new(&bounds, grad, cost);
        let status = PANOCOptimizer::new(problem, &mut self.cache)
            .with_max_iter(max_iter)
            .solve(q);
        match status {
            Ok(s) => SolveReport {
                iterations: s.iterations(),
                converged: s.exit_status() == ExitStatus::Converged,
            },
            // A non-finite cost or gradient: keep the start point and report the failure.
            Err(_) => {
                q.copy_from_slice(&self.backup);
                SolveReport {
                    iterations: 0,
                    converged: false,
                }
            }
        }
    }
}
