//! The thin adapter over the NLP solver: the one place to swap solvers.
//!
//! A [`Problem`] is a cost and its gradient (closures writing into caller buffers), box bounds on
//! the decision variables, and optionally general constraints `F1(u) ∈ C` given as residuals:
//! the first `n_eq` must equal zero, the remaining `n_ineq` must be `≤ 0`. A [`Solver`] owns the
//! solver scratch (created once for a problem shape and reused by every solve) and returns a
//! [`SolveReport`] next to the solution; non-convergence is a [`SolveStatus`], not an error.
//!
//! Backend: `optimization_engine` (OpEn) — PANOC for box-constrained problems, its augmented
//! Lagrangian method (ALM, PANOC inner solver) when general constraints are present.
//! The ALM parametric cost `ψ(u; c, y) = f(u) + c/2 · dist²_C(F1(u) + y/c)` and its gradient
//! `∇f + c · JF1ᵀ (t − Π_C t)` are written here rather than taken from OpEn's `AlmFactory`
//! because the factory allocates fresh vectors on every evaluation; here they use scratch
//! buffers owned by the solver.
//!
//! Hot loops that solve thousands of small box problems a second (the motion mapping, one per
//! frame) use [`BoxSolver`] instead: the same PANOC backend through the same `panoc` call, with
//! borrowed bounds, no allocation per solve, and pair orderings projected exactly
//! ([`OrderedBox`]); see `ordered.rs` for why it is a second entry rather than a `Problem`.

use std::cell::RefCell;
use std::time::{Duration, Instant};

use optimization_engine::alm::{AlmCache, AlmOptimizer, AlmProblem};
use optimization_engine::constraints::{Constraint, Rectangle};
use optimization_engine::core::ExitStatus;
use optimization_engine::core::SolverStatus;
use optimization_engine::panoc::{PANOCCache, PANOCOptimizer};
use optimization_engine::{FunctionCallResult, SolverError};

mod ordered;
pub use ordered::{BoxReport, BoxSolver, CostAndGradient, MAX_PAIRS, OrderedBox, PairOrder};

/// Errors of the optimisation layer: only malformed problems. A solve that does not converge is
/// reported through [`SolveStatus`].
#[non_exhaustive]
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OptimError {
    /// A vector has the wrong length for the problem.
    #[error("{what} has length {got}, expected {expected}")]
    Dimension {
        /// Which vector.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The problem's dimension.
        expected: usize,
    },
    /// A bound is NaN or the lower bound exceeds the upper bound.
    #[error("bounds of variable {index} are invalid: lower {lower}, upper {upper}")]
    InvalidBounds {
        /// Variable index.
        index: usize,
        /// Lower bound.
        lower: f64,
        /// Upper bound.
        upper: f64,
    },
    /// The initial guess contains NaN or infinity.
    #[error("initial guess component {index} is not finite ({value})")]
    NonFiniteStart {
        /// Variable index.
        index: usize,
        /// Value found.
        value: f64,
    },
    /// The problem has general constraints of a different count than the solver was built for.
    #[error("problem has {got} general constraints, the solver was built for {expected}")]
    ConstraintCount {
        /// Constraints in the problem.
        got: usize,
        /// Constraints the solver's scratch was sized for.
        expected: usize,
    },
}

type CostFn<'a> = dyn Fn(&[f64]) -> f64 + 'a;
type GradFn<'a> = dyn Fn(&[f64], &mut [f64]) + 'a;
type ResidualFn<'a> = dyn Fn(&[f64], &mut [f64]) + 'a;
type JacTFn<'a> = dyn Fn(&[f64], &[f64], &mut [f64]) + 'a;

/// General constraints `F1(u) ∈ C`: `n_eq` equalities `r_i(u) = 0` followed by `n_ineq`
/// inequalities `r_i(u) ≤ 0`.
pub struct Constraints<'a> {
    n_eq: usize,
    n_ineq: usize,
    residuals: Box<ResidualFn<'a>>,
    jacobian_t: Box<JacTFn<'a>>,
}

impl<'a> Constraints<'a> {
    /// `residuals(u, r)` writes the `n_eq + n_ineq` residuals into `r`;
    /// `jacobian_t(u, d, out)` writes `J_F1(u)ᵀ d` (length of `u`) into `out`.
    pub fn new(
        n_eq: usize,
        n_ineq: usize,
        residuals: impl Fn(&[f64], &mut [f64]) + 'a,
        jacobian_t: impl Fn(&[f64], &[f64], &mut [f64]) + 'a,
    ) -> Self {
        Constraints {
            n_eq,
            n_ineq,
            residuals: Box::new(residuals),
            jacobian_t: Box::new(jacobian_t),
        }
    }

    /// Total number of residuals.
    pub fn len(&self) -> usize {
        self.n_eq + self.n_ineq
    }

    /// True when there are no residuals.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A smooth NLP: minimise `cost(u)` over `lower ≤ u ≤ upper` subject to optional [`Constraints`].
pub struct Problem<'a> {
    n: usize,
    cost: Box<CostFn<'a>>,
    gradient: Box<GradFn<'a>>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    constraints: Option<Constraints<'a>>,
}

impl<'a> Problem<'a> {
    /// An unbounded problem of dimension `n`. `cost(u)` returns the cost; `gradient(u, g)`
    /// writes `∇cost(u)` into `g`.
    pub fn new(
        n: usize,
        cost: impl Fn(&[f64]) -> f64 + 'a,
        gradient: impl Fn(&[f64], &mut [f64]) + 'a,
    ) -> Self {
        Problem {
            n,
            cost: Box::new(cost),
            gradient: Box::new(gradient),
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
            constraints: None,
        }
    }

    /// Box bounds (infinite entries allowed).
    pub fn with_bounds(mut self, lower: &[f64], upper: &[f64]) -> Result<Self, OptimError> {
        check_len("lower", lower.len(), self.n)?;
        check_len("upper", upper.len(), self.n)?;
        for (i, (&l, &u)) in lower.iter().zip(upper).enumerate() {
            if l.is_nan() || u.is_nan() || l > u {
                return Err(OptimError::InvalidBounds {
                    index: i,
                    lower: l,
                    upper: u,
                });
            }
        }
        self.lower.copy_from_slice(lower);
        self.upper.copy_from_slice(upper);
        Ok(self)
    }

    /// General constraints, handled by the augmented Lagrangian method.
    pub fn with_constraints(mut self, constraints: Constraints<'a>) -> Self {
        self.constraints = if constraints.is_empty() {
            None
        } else {
            Some(constraints)
        };
        self
    }

    /// Dimension of the decision vector.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Number of general constraint residuals.
    pub fn n_constraints(&self) -> usize {
        self.constraints.as_ref().map_or(0, Constraints::len)
    }

    /// Largest violation of the general constraints at `u` (`|r|` for equalities, `max(r, 0)`
    /// for inequalities); `scratch` must have `n_constraints()` entries.
    pub fn constraint_violation(&self, u: &[f64], scratch: &mut [f64]) -> f64 {
        match &self.constraints {
            None => 0.0,
            Some(c) => {
                (c.residuals)(u, scratch);
                violation(scratch, c.n_eq)
            }
        }
    }
}

fn violation(r: &[f64], n_eq: usize) -> f64 {
    r.iter().enumerate().fold(0.0_f64, |m, (i, &v)| {
        let viol = if i < n_eq { v.abs() } else { v.max(0.0) };
        if viol.is_nan() {
            f64::INFINITY
        } else {
            m.max(viol)
        }
    })
}

fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), OptimError> {
    if got == expected {
        Ok(())
    } else {
        Err(OptimError::Dimension {
            what,
            got,
            expected,
        })
    }
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// Stationarity and (if constrained) feasibility tolerances met.
    Converged,
    /// Iteration budget exhausted; the best iterate is returned.
    MaxIterations,
    /// Time budget exhausted; the best iterate is returned.
    OutOfTime,
    /// A cost, gradient or residual evaluation produced NaN/inf; the start is returned.
    NumericalFailure,
}

/// What a solve did, returned next to every solution.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SolveReport {
    /// How the solve ended.
    pub status: SolveStatus,
    /// Inner (PANOC) iterations, summed over outer iterations.
    pub iterations: usize,
    /// Outer (augmented Lagrangian) iterations; 0 for box-only problems.
    pub outer_iterations: usize,
    /// Cost `f(u)` at the returned point (without penalty terms).
    pub cost: f64,
    /// Norm of the last fixed-point residual of the inner solver (stationarity measure).
    pub stationarity: f64,
    /// Largest general-constraint violation at the returned point.
    pub max_constraint_violation: f64,
    /// Wall time of the solve.
    pub time: Duration,
}

/// Tolerances and budgets.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Stationarity tolerance (fixed-point residual) of the final inner problem.
    pub tolerance: f64,
    /// Feasibility tolerance of the general constraints (ALM `δ`).
    pub constraint_tolerance: f64,
    /// Inner iterations per inner problem.
    pub max_inner_iterations: usize,
    /// Outer augmented Lagrangian iterations.
    pub max_outer_iterations: usize,
    /// Initial ALM penalty parameter.
    pub initial_penalty: f64,
    /// ALM penalty growth factor when feasibility stalls.
    pub penalty_update_factor: f64,
    /// L-BFGS memory.
    pub lbfgs_memory: usize,
    /// Optional wall-time budget per solve.
    pub max_duration: Option<Duration>,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            tolerance: 1e-6,
            constraint_tolerance: 1e-5,
            max_inner_iterations: 500,
            max_outer_iterations: 30,
            initial_penalty: 10.0,
            penalty_update_factor: 5.0,
            lbfgs_memory: 10,
            max_duration: None,
        }
    }
}

struct AlmScratch {
    t: Vec<f64>,
    s: Vec<f64>,
    jt: Vec<f64>,
}

/// Solver scratch for one problem shape (`n` variables, `n_constraints` general residuals),
/// created once and reused for every solve (e.g. every start of a multi-start search).
pub struct Solver {
    n: usize,
    n1: usize,
    settings: Settings,
    panoc: Option<PANOCCache>,
    alm: Option<AlmCache>,
    scratch: RefCell<AlmScratch>,
    y0: Vec<f64>,
    y_lo: Vec<f64>,
    y_hi: Vec<f64>,
    c_lo: Vec<f64>,
    c_hi: Vec<f64>,
    residual: Vec<f64>,
}

/// Multipliers are kept in this box (OpEn needs a compact set `Y`).
const MULTIPLIER_BOUND: f64 = 1e12;

impl Solver {
    /// Scratch for problems with `n` variables and `n_constraints` general residuals.
    pub fn new(n: usize, n_constraints: usize, settings: Settings) -> Self {
        let panoc_cache = PANOCCache::new(n.max(1), settings.tolerance, settings.lbfgs_memory);
        let (panoc, alm) = if n_constraints == 0 {
            (Some(panoc_cache), None)
        } else {
            (None, Some(AlmCache::new(panoc_cache, n_constraints, 0)))
        };
        Solver {
            n,
            n1: n_constraints,
            settings,
            panoc,
            alm,
            scratch: RefCell::new(AlmScratch {
                t: vec![0.0; n_constraints],
                s: vec![0.0; n_constraints],
                jt: vec![0.0; n],
            }),
            y0: vec![0.0; n_constraints],
            y_lo: vec![-MULTIPLIER_BOUND; n_constraints],
            y_hi: vec![MULTIPLIER_BOUND; n_constraints],
            c_lo: vec![0.0; n_constraints],
            c_hi: vec![0.0; n_constraints],
            residual: vec![0.0; n_constraints],
        }
    }

    /// The settings this solver was built with.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Solve from the initial guess in `u` (projected onto the bounds first); the solution is
    /// written back into `u`. Only a malformed problem is an error.
    pub fn solve(
        &mut self,
        problem: &Problem<'_>,
        u: &mut [f64],
    ) -> Result<SolveReport, OptimError> {
        check_len("decision vector", u.len(), self.n)?;
        check_len("problem dimension", problem.n, self.n)?;
        if problem.n_constraints() != self.n1 {
            return Err(OptimError::ConstraintCount {
                got: problem.n_constraints(),
                expected: self.n1,
            });
        }
        if let Some((index, &value)) = u.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(OptimError::NonFiniteStart { index, value });
        }
        for ((x, &l), &h) in u.iter_mut().zip(&problem.lower).zip(&problem.upper) {
            *x = x.clamp(l, h);
        }
        let start = Instant::now();
        let mut report = match &problem.constraints {
            None => self.solve_box(problem, u),
            Some(c) => self.solve_alm(problem, c, u),
        };
        report.time = start.elapsed();
        Ok(report)
    }

    fn solve_box(&mut self, problem: &Problem<'_>, u: &mut [f64]) -> SolveReport {
        let bounds = OrderedBox {
            lower: &problem.lower,
            upper: &problem.upper,
            pairs: &[],
        };
        let cost = |x: &[f64], c: &mut f64| -> FunctionCallResult {
            *c = (problem.cost)(x);
            finite(*c)
        };
        let grad = |x: &[f64], g: &mut [f64]| -> FunctionCallResult {
            (problem.gradient)(x, g);
            finite_all(g)
        };
        let cache = self.panoc.as_mut().expect("box solver has a PANOC cache");
        let backup = u.to_vec();
        let result = panoc(
            cache,
            &bounds,
            grad,
            cost,
            u,
            self.settings.max_inner_iterations.max(1),
            self.settings.tolerance,
            self.settings.max_duration,
        );
        match result {
            Ok(st) => SolveReport {
                status: map_exit(st.exit_status()),
                iterations: st.iterations(),
                outer_iterations: 0,
                cost: (problem.cost)(u),
                stationarity: st.norm_fpr(),
                max_constraint_violation: 0.0,
                time: Duration::ZERO,
            },
            Err(_) => {
                u.copy_from_slice(&backup);
                failure_report(problem.cost.as_ref(), u, 0.0)
            }
        }
    }

    fn solve_alm(
        &mut self,
        problem: &Problem<'_>,
        cons: &Constraints<'_>,
        u: &mut [f64],
    ) -> SolveReport {
        let n_eq = cons.n_eq;
        for i in 0..self.n1 {
            self.c_lo[i] = if i < n_eq { 0.0 } else { f64::NEG_INFINITY };
            self.c_hi[i] = 0.0;
        }
        let set_c = Rectangle::new(Some(&self.c_lo), Some(&self.c_hi));
        let set_y = Rectangle::new(Some(&self.y_lo), Some(&self.y_hi));
        let bounds = Rectangle::new(Some(&problem.lower), Some(&problem.upper));
        let scratch = &self.scratch;
        // ψ(u; ξ), ξ = (c, y): OpEn evaluates it with c = 0 to recover f at the solution.
        let psi = |x: &[f64], xi: &[f64], val: &mut f64| -> FunctionCallResult {
            *val = (problem.cost)(x);
            finite(*val)?;
            let c = xi[0];
            if c > 0.0 {
                let mut sc = scratch.borrow_mut();
                let AlmScratch { t, s, .. } = &mut *sc;
                (cons.residuals)(x, t);
                finite_all(t)?;
                for (ti, yi) in t.iter_mut().zip(&xi[1..]) {
                    *ti += yi / c;
                }
                s.copy_from_slice(t);
                project_box(s, &self.c_lo, &self.c_hi);
                let d2: f64 = t.iter().zip(s.iter()).map(|(a, b)| (a - b) * (a - b)).sum();
                *val += 0.5 * c * d2;
            }
            Ok(())
        };
        let dpsi = |x: &[f64], xi: &[f64], g: &mut [f64]| -> FunctionCallResult {
            (problem.gradient)(x, g);
            finite_all(g)?;
            let c = xi[0];
            if c > 0.0 {
                let mut sc = scratch.borrow_mut();
                let AlmScratch { t, s, jt } = &mut *sc;
                (cons.residuals)(x, t);
                finite_all(t)?;
                for (ti, yi) in t.iter_mut().zip(&xi[1..]) {
                    *ti += yi / c;
                }
                s.copy_from_slice(t);
                project_box(s, &self.c_lo, &self.c_hi);
                for (ti, si) in t.iter_mut().zip(s.iter()) {
                    *ti -= si;
                }
                (cons.jacobian_t)(x, t, jt);
                for (gi, ji) in g.iter_mut().zip(jt.iter()) {
                    *gi += c * ji;
                }
                finite_all(g)?;
            }
            Ok(())
        };
        let f1 = |x: &[f64], r: &mut [f64]| -> FunctionCallResult {
            (cons.residuals)(x, r);
            finite_all(r)
        };
        let alm_problem = AlmProblem::new(
            bounds,
            Some(set_c),
            Some(set_y),
            psi,
            dpsi,
            Some(f1),
            None::<fn(&[f64], &mut [f64]) -> FunctionCallResult>,
            self.n1,
            0,
        );
        let cache = self
            .alm
            .as_mut()
            .expect("constrained solver has an ALM cache");
        let s = &self.settings;
        // The cache keeps (c, y) between solves: reset both so every start is independent.
        let mut opt = AlmOptimizer::new(cache, alm_problem)
            .with_initial_penalty(s.initial_penalty)
            .with_initial_lagrange_multipliers(&self.y0)
            .with_delta_tolerance(s.constraint_tolerance)
            .with_epsilon_tolerance(s.tolerance)
            .with_penalty_update_factor(s.penalty_update_factor)
            .with_max_outer_iterations(s.max_outer_iterations.max(1))
            .with_max_inner_iterations(s.max_inner_iterations.max(1));
        if let Some(d) = s.max_duration {
            opt = opt.with_max_duration(d);
        }
        let backup = u.to_vec();
        let result = opt.solve(u);
        match result {
            Ok(st) => {
                let viol = {
                    (cons.residuals)(u, &mut self.residual);
                    violation(&self.residual, n_eq)
                };
                let mut status = map_exit(st.exit_status());
                // OpEn's ALM stops on multiplier stagnation; insist on actual feasibility too.
                if status == SolveStatus::Converged
                    && viol > s.constraint_tolerance.max(1e-9) * 10.0
                {
                    status = SolveStatus::MaxIterations;
                }
                SolveReport {
                    status,
                    iterations: st.num_inner_iterations(),
                    outer_iterations: st.num_outer_iterations(),
                    cost: (problem.cost)(u),
                    stationarity: st.last_problem_norm_fpr(),
                    max_constraint_violation: viol,
                    time: Duration::ZERO,
                }
            }
            Err(_) => {
                u.copy_from_slice(&backup);
                (cons.residuals)(u, &mut self.residual);
                let viol = violation(&self.residual, n_eq);
                failure_report(problem.cost.as_ref(), u, viol)
            }
        }
    }
}

/// One PANOC run over the feasible set `bounds` from `u`: the single place both entries (the
/// general [`Solver`] and the hot-loop [`BoxSolver`]) call the backend.
#[allow(clippy::too_many_arguments)]
fn panoc<C, G, F>(
    cache: &mut PANOCCache,
    bounds: &C,
    grad: G,
    cost: F,
    u: &mut [f64],
    max_iter: usize,
    tolerance: f64,
    max_duration: Option<Duration>,
) -> Result<SolverStatus, SolverError>
where
    C: Constraint,
    G: Fn(&[f64], &mut [f64]) -> FunctionCallResult,
    F: Fn(&[f64], &mut f64) -> FunctionCallResult,
{
    let nlp = optimization_engine::Problem::new(bounds, grad, cost);
    let mut opt = PANOCOptimizer::new(nlp, cache)
        .with_tolerance(tolerance)
        .with_max_iter(max_iter);
    if let Some(d) = max_duration {
        opt = opt.with_max_duration(d);
    }
    opt.solve(u)
}

fn failure_report(cost: &CostFn<'_>, u: &[f64], viol: f64) -> SolveReport {
    SolveReport {
        status: SolveStatus::NumericalFailure,
        iterations: 0,
        outer_iterations: 0,
        cost: cost(u),
        stationarity: f64::INFINITY,
        max_constraint_violation: viol,
        time: Duration::ZERO,
    }
}

fn project_box(x: &mut [f64], lo: &[f64], hi: &[f64]) {
    for ((v, &l), &h) in x.iter_mut().zip(lo).zip(hi) {
        *v = v.max(l).min(h);
    }
}

fn map_exit(e: ExitStatus) -> SolveStatus {
    match e {
        ExitStatus::Converged => SolveStatus::Converged,
        ExitStatus::NotConvergedIterations => SolveStatus::MaxIterations,
        ExitStatus::NotConvergedOutOfTime => SolveStatus::OutOfTime,
    }
}

fn finite(v: f64) -> FunctionCallResult {
    if v.is_finite() {
        Ok(())
    } else {
        Err(SolverError::NotFiniteComputation("non-finite cost"))
    }
}

fn finite_all(v: &[f64]) -> FunctionCallResult {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(SolverError::NotFiniteComputation(
            "non-finite gradient or residual",
        ))
    }
}

#[cfg(test)]
mod tests;
