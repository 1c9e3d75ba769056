//! Regularised linear least-squares fit of the fictitious-obstacle spline `s` (DESIGN §5) and
//! the choice of `k` / shrink that certifies convergence.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::bspline::Local;
use super::{
    Certificate, CertificateKind, MAX_DIM, MotionError, NavigationFunction, TensorBSpline,
    no_critical_point,
};

/// Largest spline the dense normal equations accept (a Cholesky of this size takes ~1 s).
pub const MAX_COEFFICIENTS: usize = 3000;

/// Certificate safety margin: require `bound ≤ 2k(1 − MARGIN)`.
pub const MARGIN: f64 = 0.05;

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

/// Set the spline to `α(k·c_a + c_b)` and return its radial bound (positively homogeneous in
/// `α`, which makes the shrink factor a closed form).
#[allow(clippy::too_many_arguments)] // the fit, the candidate and the two balls
fn spline_bound(
    template: &mut TensorBSpline,
    fit: &SplineFit,
    k: f64,
    alpha: f64,
    center: &[f64],
    radius: f64,
    goal_center: &[f64],
    goal_radius: f64,
) -> f64 {
    for ((c, a), b) in template
        .coefficients_mut()
        .iter_mut()
        .zip(&fit.c_a)
        .zip(&fit.c_b)
    {
        *c = alpha * (k * a + b);
    }
    super::nf::refined_radial_bound(template, center, radius, goal_center, goal_radius)
}

/// Choose `k` (given, or automatically) and the shrink `α ≤ 1` so that the certificate holds with
/// margin: `α·S(k c_a + c_b) + B_0 ≤ 2k(1 − MARGIN)`, `S` the radial bound. Automatic `k`: the flow depends on
/// `s/k ≈ α c_a`, so the learned shaping is kept best by the largest admissible `α`; take the
/// smallest `k` (from 2 up) whose `α` is within 5 % of the best.
///
/// [`CertificateKind::NoCriticalPoint`]: from there, the largest `α ≤ 1` whose field the branch
/// and bound of [`no_critical_point`] certifies (`α = 1` tried first, then bisection between
/// the `γ`-decreasing `α`, which that certificate implies, and 1).
#[allow(clippy::too_many_arguments)] // the fit, the two balls, k, the kind and the group for errors
pub(crate) fn certify(
    mut template: TensorBSpline,
    fit: &SplineFit,
    center: Vec<f64>,
    radius: f64,
    goal_center: &[f64],
    goal_radius: f64,
    k: Option<f64>,
    kind: CertificateKind,
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
    let b0 = reach * reach / (2.0 * (radius * radius - reach * reach));
    let alpha_for = |k: f64, template: &mut TensorBSpline| -> Option<f64> {
        let room = 2.0 * k * (1.0 - MARGIN) - b0;
        if room <= 0.0 {
            return None;
        }
        let g = spline_bound(
            template,
            fit,
            k,
            1.0,
            &center,
            radius,
            goal_center,
            goal_radius,
        );
        Some(if g <= room { 1.0 } else { room / g })
    };
    let chosen_k = match k {
        Some(k) => k,
        None => {
            const CANDIDATES: [f64; 14] = [
                2., 3., 4., 5., 6., 8., 10., 12., 16., 20., 24., 32., 48., 64.,
            ];
            let alphas: Vec<f64> = CANDIDATES
                .iter()
                .map(|&k| alpha_for(k, &mut template).unwrap_or(0.0))
                .collect();
            let best = alphas.iter().cloned().fold(0.0, f64::max);
            CANDIDATES
                .iter()
                .zip(&alphas)
                .find(|(_, a)| **a >= 0.95 * best)
                .map(|(k, _)| *k)
                .unwrap_or(64.0)
        }
    };
    let alpha = alpha_for(chosen_k, &mut template).ok_or(MotionError::CertificateUnattainable {
        group,
        k: chosen_k,
        bound: b0,
    })?;
    // Guard the rounding of `room / g` so the stored certificate holds as computed.
    let mut alpha = alpha;
    let nf = loop {
        spline_bound(
            &mut template,
            fit,
            chosen_k,
            alpha,
            &center,
            radius,
            goal_center,
            goal_radius,
        );
        let nf = NavigationFunction {
            k: chosen_k,
            length_scale: 2.0 * radius,
            center: center.clone(),
            radius,
            spline: template.clone(),
        };
        if nf.certificate(goal_center, goal_radius, alpha).bound < 2.0 * chosen_k || alpha == 0.0 {
            break nf;
        }
        alpha *= 0.999;
    };
    let critical = no_critical_point(&nf, goal_center, goal_radius);
    if kind == CertificateKind::GammaDecreasing || !critical.holds {
        // γ decreasing implies no critical point; a failed branch and bound (budget) keeps the
        // closed-form certificate and says so
        let mut cert = nf.certificate(goal_center, goal_radius, alpha);
        cert.critical_points = Some(critical);
        return Ok((nf, cert));
    }
    let base = nf.clone();
    let with = |a: f64, template: &mut TensorBSpline| {
        for ((c, ca), cb) in template
            .coefficients_mut()
            .iter_mut()
            .zip(&fit.c_a)
            .zip(&fit.c_b)
        {
            *c = a * (chosen_k * ca + cb);
        }
        let nf = NavigationFunction {
            spline: template.clone(),
            ..base.clone()
        };
        let critical = no_critical_point(&nf, goal_center, goal_radius);
        (nf, critical)
    };
    let mut best = (nf, critical, alpha);
    let (full, full_critical) = with(1.0, &mut template);
    if full_critical.holds {
        best = (full, full_critical, 1.0);
    } else {
        let (mut lo, mut hi) = (alpha, 1.0);
        for _ in 0..CRITICAL_BISECTIONS {
            let mid = 0.5 * (lo + hi);
            let (nf, critical) = with(mid, &mut template);
            if critical.holds {
                lo = mid;
                best = (nf, critical, mid);
            } else {
                hi = mid;
            }
        }
    }
    let (nf, critical, alpha) = best;
    let mut cert = nf.certificate(goal_center, goal_radius, alpha);
    cert.kind = CertificateKind::NoCriticalPoint;
    cert.holds = critical.holds;
    cert.critical_points = Some(critical);
    Ok((nf, cert))
}

/// Bisection steps on the shrink under the navigation-function certificate (`α` to 1/256 of
/// the interval between the `γ`-decreasing shrink and 1).
const CRITICAL_BISECTIONS: usize = 8;
