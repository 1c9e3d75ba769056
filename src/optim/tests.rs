use super::*;

fn rosenbrock(u: &[f64]) -> f64 {
    (1.0 - u[0]).powi(2) + 100.0 * (u[1] - u[0] * u[0]).powi(2)
}

fn rosenbrock_grad(u: &[f64], g: &mut [f64]) {
    g[0] = -2.0 * (1.0 - u[0]) - 400.0 * u[0] * (u[1] - u[0] * u[0]);
    g[1] = 200.0 * (u[1] - u[0] * u[0]);
}

#[test]
fn rosenbrock_unconstrained_minimum_inside_the_box_is_found() {
    let p = Problem::new(2, rosenbrock, rosenbrock_grad)
        .with_bounds(&[-2.0, -2.0], &[2.0, 2.0])
        .unwrap();
    let mut s = Solver::new(2, 0, Settings::default());
    let mut u = [-1.2, 1.0];
    let r = s.solve(&p, &mut u).unwrap();
    assert_eq!(r.status, SolveStatus::Converged);
    assert!(
        (u[0] - 1.0).abs() < 1e-4 && (u[1] - 1.0).abs() < 1e-4,
        "{u:?}"
    );
    assert!(r.cost < 1e-8);
    assert!(r.iterations > 0);
}

#[test]
fn rosenbrock_with_active_bound_stops_on_the_bound() {
    // With x ≤ 0.5 the minimiser is on the bound: x = 0.5, y = x² = 0.25 (∂f/∂y = 0 there and
    // ∂f/∂x = -1 < 0 points out of the box).
    let p = Problem::new(2, rosenbrock, rosenbrock_grad)
        .with_bounds(&[-2.0, -2.0], &[0.5, 2.0])
        .unwrap();
    let mut s = Solver::new(2, 0, Settings::default());
    let mut u = [-1.0, 1.5];
    let r = s.solve(&p, &mut u).unwrap();
    assert_eq!(r.status, SolveStatus::Converged);
    assert!((u[0] - 0.5).abs() < 1e-6, "{u:?}");
    assert!((u[1] - 0.25).abs() < 1e-4, "{u:?}");
}

#[test]
fn equality_constrained_quadratic_matches_closed_form() {
    // min ½‖x − a‖² s.t. Aᵀx = b has x* = a − A (AᵀA)⁻¹ (Aᵀa − b); with one row A = (1,1,1),
    // a = (1,2,3), b = 3: x* = a − (6 − 3)/3 · (1,1,1) = (0,1,2).
    let a = [1.0, 2.0, 3.0];
    let cost = |x: &[f64]| {
        0.5 * x
            .iter()
            .zip(&a)
            .map(|(xi, ai)| (xi - ai).powi(2))
            .sum::<f64>()
    };
    let grad = |x: &[f64], g: &mut [f64]| {
        for i in 0..3 {
            g[i] = x[i] - a[i];
        }
    };
    let cons = Constraints::new(
        1,
        0,
        |x: &[f64], r: &mut [f64]| r[0] = x[0] + x[1] + x[2] - 3.0,
        |_x: &[f64], d: &[f64], out: &mut [f64]| out.iter_mut().for_each(|o| *o = d[0]),
    );
    let p = Problem::new(3, cost, grad).with_constraints(cons);
    let mut s = Solver::new(3, 1, Settings::default());
    let mut u = [5.0, -4.0, 0.0];
    let r = s.solve(&p, &mut u).unwrap();
    assert_eq!(r.status, SolveStatus::Converged, "{r:?}");
    for (ui, ei) in u.iter().zip([0.0, 1.0, 2.0]) {
        assert!((ui - ei).abs() < 1e-4, "{u:?}");
    }
    assert!(r.max_constraint_violation < 1e-4);
    assert!((r.cost - 1.5).abs() < 1e-3);
    assert!(r.outer_iterations >= 1);
}

#[test]
fn inequality_constraint_projects_onto_the_disc_and_solver_is_reusable() {
    // min (x−2)² + (y−2)² s.t. x² + y² ≤ 1: x* = (1/√2, 1/√2).
    let cost = |x: &[f64]| (x[0] - 2.0).powi(2) + (x[1] - 2.0).powi(2);
    let grad = |x: &[f64], g: &mut [f64]| {
        g[0] = 2.0 * (x[0] - 2.0);
        g[1] = 2.0 * (x[1] - 2.0);
    };
    let cons = Constraints::new(
        0,
        1,
        |x: &[f64], r: &mut [f64]| r[0] = x[0] * x[0] + x[1] * x[1] - 1.0,
        |x: &[f64], d: &[f64], out: &mut [f64]| {
            out[0] = 2.0 * x[0] * d[0];
            out[1] = 2.0 * x[1] * d[0];
        },
    );
    let p = Problem::new(2, cost, grad)
        .with_bounds(&[-3.0, -3.0], &[3.0, 3.0])
        .unwrap()
        .with_constraints(cons);
    let mut s = Solver::new(2, 1, Settings::default());
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let mut first = [0.0; 2];
    for (k, start) in [[0.0, 0.0], [-2.0, 1.0]].iter().enumerate() {
        let mut u = *start;
        let r = s.solve(&p, &mut u).unwrap();
        assert_eq!(r.status, SolveStatus::Converged, "{r:?}");
        assert!((u[0] - h).abs() < 1e-3 && (u[1] - h).abs() < 1e-3, "{u:?}");
        assert!(r.max_constraint_violation < 1e-4);
        if k == 0 {
            first = u;
        } else {
            // A reused solver starts clean: both starts reach the same point.
            assert!((u[0] - first[0]).abs() < 1e-3 && (u[1] - first[1]).abs() < 1e-3);
        }
    }
}

#[test]
fn non_finite_cost_is_a_status_not_an_error() {
    let p = Problem::new(
        1,
        |x: &[f64]| x[0].ln(),
        |x: &[f64], g: &mut [f64]| g[0] = 1.0 / x[0],
    )
    .with_bounds(&[-1.0], &[1.0])
    .unwrap();
    let mut s = Solver::new(1, 0, Settings::default());
    let mut u = [-0.5];
    let r = s.solve(&p, &mut u).unwrap();
    assert_eq!(r.status, SolveStatus::NumericalFailure);
    assert_eq!(u[0], -0.5);
}

#[test]
fn malformed_problems_are_errors_naming_the_problem() {
    let f = |x: &[f64]| x[0] * x[0];
    let g = |x: &[f64], g: &mut [f64]| g[0] = 2.0 * x[0];
    assert_eq!(
        Problem::new(1, f, g).with_bounds(&[1.0], &[0.0]).err(),
        Some(OptimError::InvalidBounds {
            index: 0,
            lower: 1.0,
            upper: 0.0
        })
    );
    let p = Problem::new(1, f, g);
    let mut s = Solver::new(1, 0, Settings::default());
    assert!(matches!(
        s.solve(&p, &mut [f64::NAN]),
        Err(OptimError::NonFiniteStart { index: 0, .. })
    ));
    assert!(matches!(
        s.solve(&p, &mut [0.0, 1.0]),
        Err(OptimError::Dimension { got: 2, .. })
    ));
    let mut s1 = Solver::new(1, 2, Settings::default());
    assert!(matches!(
        s1.solve(&p, &mut [0.0]),
        Err(OptimError::ConstraintCount {
            got: 0,
            expected: 2
        })
    ));
}

#[test]
fn iteration_budget_exhaustion_is_reported() {
    let p = Problem::new(2, rosenbrock, rosenbrock_grad);
    let settings = Settings {
        max_inner_iterations: 3,
        ..Settings::default()
    };
    let mut s = Solver::new(2, 0, settings);
    let mut u = [-1.2, 1.0];
    let r = s.solve(&p, &mut u).unwrap();
    assert_eq!(r.status, SolveStatus::MaxIterations);
    assert!(r.iterations <= 3);
    assert!(r.cost.is_finite());
}
