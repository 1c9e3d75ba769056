//! Regularised linear least-squares fit of the fictitious-obstacle spline `s` (DESIGN §5) and
//! the choice of `k` / shrink that certifies convergence.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::bspline::Local;
use super::critical::{CriticalBudget, check_critical_free};
use super::{Certificate, MAX_DIM, MotionError, NavigationFunction, TensorBSpline};

/// Largest spline the dense normal equations accept (a Cholesky of this size takes ~1 s).
pub const MAX_COEFFICIENTS: usize = 3000;

/// The fit, split by linearity: with rows multiplied by `k`, the fitted coefficients are
/// `k·c_a + c_b`, `c_a` matching `λv + ∇γ` and `c_b` matching `−(γ/k)∇log β_0`
/// (one factorisation serves every `k`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplineFit {
    pub c_a: Vec<f64>,
    pub c_b: Vec<f64>,
    /// Demonstrated points used (moving, away from their goal).
    pub points: usize,
}

/// One demonstration in PCA coordinates: `frames × d` row-major; its goal is its last frame.
pub(crate) struct DemoY<'a> {
    pub y: &'a [f64],
}

/// Fit `(γ/k)∇s ≈ λv + ∇γ − (γ/k)∇log β_0` at every demonstrated point (v the unit demonstrated
/// velocity, λ = ‖∇γ‖, γ measured to that demonstration's own final point), with a second-
/// difference smoothness penalty plus a small ridge (so `s` → 0 away from data), both scaled by
/// `regularisation` × the mean diagonal of the data term.
pub(crate) fn fit_spline(
    template: &TensorBSpline,
    center: &[f64],
    radius: f64,
    demos: &[DemoY<'_>],
    regularisation: f64,
    goal_exclusion: f64,
    group: usize,
) -> Result<SplineFit, MotionError> {
    let d = template.dim();
    let nc = template.coefficients().len();
    let mut m = vec![0.0; nc * nc]; // lower triangle used, column-major
    let mut ra = vec![0.0; nc];
    let mut rb = vec![0.0; nc];
    let mut local = Local::new();
    let mut points = 0;
    let mut g = [[0.0; MAX_DIM]; 1024];
    for demo in demos {
        let frames = demo.y.len() / d;
        if frames < 3 {
            continue;
        }
        let goal = &demo.y[(frames - 1) * d..];
        let start_gamma: f64 = (0..d).map(|i| (demo.y[i] - goal[i]).powi(2)).sum();
        let min_gamma = goal_exclusion * goal_exclusion * start_gamma;
        let mut peak: f64 = 0.0;
        for j in 1..frames - 1 {
            let mut s2 = 0.0;
            for i in 0..d {
                let v = demo.y[(j + 1) * d + i] - demo.y[(j - 1) * d + i];
                s2 += v * v;
            }
            peak = peak.max(s2.sqrt());
        }
        if peak <= 0.0 {
            continue;
        }
        for j in 1..frames - 1 {
            let y = &demo.y[j * d..(j + 1) * d];
            let mut v = [0.0; MAX_DIM];
            let mut speed = 0.0;
            let mut gamma = 0.0;
            let mut rc2 = 0.0;
            for i in 0..d {
                v[i] = demo.y[(j + 1) * d + i] - demo.y[(j - 1) * d + i];
                speed += v[i] * v[i];
                gamma += (y[i] - goal[i]).powi(2);
                rc2 += (y[i] - center[i]).powi(2);
            }
            let speed = speed.sqrt();
            let beta0 = radius * radius - rc2;
            // Near-rest frames carry noise, not direction; points at their goal carry no row.
            // Points close to their own goal would demand `|∇s| ~ 1/‖y − y_d‖` (the final
            // approach is straight anyway); they inflate the certificate bound for every other
            // goal, so the last `goal_exclusion` fraction of the distance is left out.
            if speed < 0.05 * peak
                || gamma < 1e-12 * radius * radius
                || gamma < min_gamma
                || beta0 <= 0.0
            {
                continue;
            }
            points += 1;
            let lambda = 2.0 * gamma.sqrt();
            template.local(y, &mut local);
            let n = local.n;
            for a in 0..n {
                for i in 0..d {
                    g[a][i] = gamma * local.grad[a][i];
                }
            }
            let mut ta = [0.0; MAX_DIM];
            let mut tb = [0.0; MAX_DIM];
            for i in 0..d {
                ta[i] = lambda * v[i] / speed + 2.0 * (y[i] - goal[i]);
                tb[i] = gamma * 2.0 * (y[i] - center[i]) / beta0;
            }
            for a in 0..n {
                let ia = local.index[a];
                let mut sa = 0.0;
                let mut sb = 0.0;
                for i in 0..d {
                    sa += g[a][i] * ta[i];
                    sb += g[a][i] * tb[i];
                }
                ra[ia] += sa;
                rb[ia] += sb;
                for b in 0..n {
                    let ib = local.index[b];
                    if ib > ia {
                        continue;
                    }
                    let mut s = 0.0;
                    for i in 0..d {
                        s += g[a][i] * g[b][i];
                    }
                    m[ia + ib * nc] += s;
                }
            }
        }
    }
    let trace: f64 = (0..nc).map(|i| m[i + i * nc]).sum();
    if points == 0 || trace <= 0.0 {
        return Ok(SplineFit {
            c_a: vec![0.0; nc],
            c_b: vec![0.0; nc],
            points,
        });
    }
    let lam = regularisation.max(1e-12) * trace / nc as f64;
    // P-spline smoothness: squared second differences along each axis, plus a ridge.
    let per_axis = template.intervals() + 3;
    let mut stride = 1;
    for _axis in 0..d {
        for j in 0..nc {
            let pos = (j / stride) % per_axis;
            if pos == 0 || pos + 1 >= per_axis {
                continue;
            }
            let idx = [j - stride, j, j + stride];
            let w = [1.0, -2.0, 1.0];
            for a in 0..3 {
                for b in 0..3 {
                    if idx[b] <= idx[a] {
                        m[idx[a] + idx[b] * nc] += lam * w[a] * w[b];
                    }
                }
            }
        }
        stride *= per_axis;
    }
    for i in 0..nc {
        m[i + i * nc] += 0.01 * lam;
    }
    // mirror into the upper triangle (nalgebra's Cholesky reads the lower one, but keep the
    // matrix a faithful symmetric operand)
    for c in 0..nc {
        for r in 0..c {
            m[r + c * nc] = m[c + r * nc];
        }
    }
    let mat = DMatrix::from_vec(nc, nc, m);
    let chol = nalgebra::linalg::Cholesky::new(mat).ok_or(MotionError::SingularFit { group })?;
    let mut rhs = DMatrix::from_fn(nc, 2, |r, c| if c == 0 { ra[r] } else { rb[r] });
    chol.solve_mut(&mut rhs);
    Ok(SplineFit {
        c_a: rhs.column(0).iter().copied().collect(),
        c_b: rhs.column(1).iter().copied().collect(),
        points,
    })
}

/// Whether the navigation-function certificate holds for `s = α(k·c_a + c_b)` (the spline is
/// left holding that field).
#[allow(clippy::too_many_arguments)] // the fit, the candidate and the two balls
fn holds_for(
    template: &mut TensorBSpline,
    fit: &SplineFit,
    k: f64,
    alpha: f64,
    center: &[f64],
    radius: f64,
    goal_center: &[f64],
    goal_radius: f64,
) -> bool {
    for ((c, a), b) in template
        .coefficients_mut()
        .iter_mut()
        .zip(&fit.c_a)
        .zip(&fit.c_b)
    {
        *c = alpha * (k * a + b);
    }
    let nf = NavigationFunction {
        k,
        length_scale: 2.0 * radius,
        center: center.to_vec(),
        radius,
        spline: template.clone(),
    };
    check_critical_free(&nf, goal_center, goal_radius, &CriticalBudget::default()).holds
}

/// `k` candidates of the automatic choice (ascending).
const K_CANDIDATES: [f64; 8] = [2., 3., 4., 6., 8., 16., 32., 64.];

/// Bisection steps for the shrink factor when the unshrunk field is not certified.
const SHRINK_BISECTIONS: usize = 10;

/// Choose `k` (given, or automatically) and the shrink `α ≤ 1` so that the navigation-function
/// certificate holds for the field `s = α(k c_a + c_b)`. The flow depends on `s/k ≈ α c_a`, so
/// the learned shaping is kept whole at `α = 1`. Automatic `k`: the smallest candidate at which
/// the unshrunk field is certified (Rimon and Koditschek tune `k` upwards until the function is
/// a navigation function); when none is, the field is shrunk by bisection on `α` (the bare
/// workspace ball, `α = 0`, is a navigation function for every `k ≥ 1`: a critical point `y ≠ y_d`
/// of `γ/(γ^k + β_0)^{1/k}` needs `y_d = y + (kβ_0/ρ²)(y − c)`, at distance
/// `ρ + k(R² − ρ²)/ρ ≥ R` from the centre, outside the workspace). A given `k` keeps the field
/// whole if certified and shrinks it otherwise.
#[allow(clippy::too_many_arguments)] // the fit, the two balls, k and the group for errors
pub(crate) fn certify(
    mut template: TensorBSpline,
    fit: &SplineFit,
    center: Vec<f64>,
    radius: f64,
    goal_center: &[f64],
    goal_radius: f64,
    k: Option<f64>,
    group: usize,
) -> Result<(NavigationFunction, Certificate), MotionError> {
    let offset: f64 = goal_center
        .iter()
        .zip(&center)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    let reach = offset + goal_radius;
    if reach >= radius {
        return Err(MotionError::CertificateUnattainable {
            group,
            k: k.unwrap_or(0.0),
            bound: f64::INFINITY,
        });
    }
    let mut holds = |k: f64, alpha: f64, t: &mut TensorBSpline| {
        holds_for(t, fit, k, alpha, &center, radius, goal_center, goal_radius)
    };
    let shrink_at = |k: f64,
                     t: &mut TensorBSpline,
                     holds: &mut dyn FnMut(f64, f64, &mut TensorBSpline) -> bool|
     -> Option<f64> {
        if !holds(k, 0.0, t) {
            return None;
        }
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..SHRINK_BISECTIONS {
            let mid = 0.5 * (lo + hi);
            if holds(k, mid, t) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some(lo)
    };
    let (chosen_k, alpha) = match k {
        Some(k) => {
            if holds(k, 1.0, &mut template) {
                (k, 1.0)
            } else {
                let a = shrink_at(k, &mut template, &mut holds).ok_or(
                    MotionError::CertificateUnattainable {
                        group,
                        k,
                        bound: f64::NAN,
                    },
                )?;
                (k, a)
            }
        }
        None => match K_CANDIDATES.iter().find(|&&k| holds(k, 1.0, &mut template)) {
            Some(&k) => (k, 1.0),
            None => {
                let mut best: Option<(f64, f64)> = None;
                for &k in &[2.0, 8.0, 32.0] {
                    if let Some(a) = shrink_at(k, &mut template, &mut holds)
                        && best.is_none_or(|(_, b)| a > b)
                    {
                        best = Some((k, a));
                    }
                }
                best.ok_or(MotionError::CertificateUnattainable {
                    group,
                    k: 0.0,
                    bound: f64::NAN,
                })?
            }
        },
    };
    holds(chosen_k, alpha, &mut template);
    let nf = NavigationFunction {
        k: chosen_k,
        length_scale: 2.0 * radius,
        center,
        radius,
        spline: template,
    };
    let cert = nf.certificate(goal_center, goal_radius, alpha);
    Ok((nf, cert))
}
