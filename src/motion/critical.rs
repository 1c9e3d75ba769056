//! The navigation-function certificate (issue 19): `φ` has no critical point in the workspace
//! other than the goal, for every goal in the goal region.
//!
//! **Theorem.** Let `B = {‖y − c‖ < R}` be the workspace ball, `G = {‖y_d − c_g‖ ≤ r_g} ⊂ B` the
//! goal region, `β = β_0 e^s` with `β_0 = R² − ‖y − c‖²` and `s` a C² spline, `k > 0`, and
//! `φ = γ/(γ^k + β)^{1/k}`, `γ = ‖y − y_d‖²`. If for every `y ∈ B` the point
//! `z(y) = y − 2k ∇log β(y)/‖∇log β(y)‖²` lies outside `G` (where `∇log β(y) = 0`, `z` is at
//! infinity), then for every `y_d ∈ G` and every start `y_0 ∈ B` the flow `ẏ = −∇φ` (or any
//! positive rescaling of it, such as [`NavigationFunction::flow`]) stays in `B` and converges to
//! `y_d`; `γ` may rise on the way.
//!
//! *Proof sketch.* `∇φ = β(γ^k + β)^{−1/k−1}(∇γ − (γ/k)∇log β)` and the prefactor is positive in
//! `B`, so `y ≠ y_d` is critical iff `2(y − y_d) = (γ/k)∇log β`. Taking norms,
//! `‖y − y_d‖ = 2k/‖∇log β‖`, and then `y − y_d = 2k∇log β/‖∇log β‖²`, i.e. `y_d = z(y)`: a
//! critical point other than the goal exists for some goal in `G` iff `z(B) ∩ G ≠ ∅`. In `B`,
//! `β > 0` gives `0 ≤ φ < 1`, while `φ → 1` at `∂B` (`β → 0`, `γ > 0` there since `y_d ∈ G`
//! lies inside): the boundary repels, because along the flow `φ̇ = −‖∇φ‖² ≤ 0` keeps the path in
//! the compact sublevel set `{φ ≤ φ(y_0)} ⊂ B`. `φ` is a Lyapunov function whose only critical
//! point in that set is `y_d`, so LaSalle's invariance principle gives convergence to `y_d`.
//!
//! **Computation** ([`no_critical_point`]). Two parts, both conservative:
//! - *Shell* `ρ_1 ≤ ‖y − c‖ < R`: with `‖∇log β‖ ≥ 2ρ/(R² − ρ²) − S` (`S` the spline's global
//!   gradient bound), `‖z(y) − c‖ ≥ ρ − 2k/(2ρ/(R² − ρ²) − S)`, which grows with `ρ` and tends to
//!   `R`; `ρ_1` is the smallest radius from which it exceeds `‖c_g − c‖ + r_g`.
//! - *Inside* `ρ_1`: branch and bound over boxes, starting from the spline's knot cells. On a box,
//!   `∇s` is enclosed by the cell's coefficient differences intersected with the centred form
//!   `∇s(m) ± H·w` (`H` the cell's second-derivative bounds, `w` the half-widths), `∇log β_0` by
//!   interval arithmetic; a box is cleared when `‖∇log β‖·‖y − y_d‖` cannot equal `2k`, or when
//!   the box enclosing `z` misses `G`; otherwise it is halved along its widest axis, up to a
//!   fixed box budget (an evaluation budget, so the answer does not depend on the machine).
//!
//! The classical certificate ([`NavigationFunction::certificate`], `γ` strictly decreasing)
//! implies this one (`(y − y_d)·∇log β < 2k` excludes `‖y − y_d‖‖∇log β‖ = 2k` with the two
//! parallel), not conversely.

use serde::{Deserialize, Serialize};

use super::{MAX_DIM, NavigationFunction};

/// Boxes the branch and bound may examine before it gives up (the certificate then does not
/// hold). The bundled systems' manifolds (2-3 components) need 230-42,000 at the
/// `γ`-decreasing shrink and up to the budget near the largest shrink it certifies; the budget
/// bounds training time.
pub const BOX_BUDGET: usize = 400_000;

/// Deepest halving of a knot cell.
const MAX_DEPTH: usize = 40;

/// The outcome of [`no_critical_point`]: stored with the model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CriticalPointCertificate {
    /// No critical point but the goal, for every goal in the goal region (proved).
    pub holds: bool,
    /// `ρ_1`: from this distance to the workspace centre outwards the workspace term alone
    /// rules critical points out.
    pub shell_radius: f64,
    /// Boxes examined by the branch and bound.
    pub boxes: usize,
    /// Deepest halving needed.
    pub depth: usize,
}

/// `[a, b]`-interval helpers (closed intervals, `lo ≤ hi`).
#[inline]
fn square(lo: f64, hi: f64) -> (f64, f64) {
    if lo >= 0.0 {
        (lo * lo, hi * hi)
    } else if hi <= 0.0 {
        (hi * hi, lo * lo)
    } else {
        (0.0, (lo * lo).max(hi * hi))
    }
}

/// `[lo, hi] / [p, q]` with `0 < p ≤ q`.
#[inline]
fn divide_positive(lo: f64, hi: f64, p: f64, q: f64) -> (f64, f64) {
    let a = if lo >= 0.0 { lo / q } else { lo / p };
    let b = if hi >= 0.0 { hi / p } else { hi / q };
    (a, b)
}

/// Squared distance from `p` to the box `[lo, hi]` (0 inside) and the squared distance to its
/// farthest corner.
#[inline]
fn box_distances(p: &[f64], lo: &[f64], hi: &[f64]) -> (f64, f64) {
    let mut near = 0.0;
    let mut far = 0.0;
    for i in 0..p.len() {
        let a = lo[i] - p[i];
        let b = hi[i] - p[i];
        if a > 0.0 {
            near += a * a;
        } else if b < 0.0 {
            near += b * b;
        }
        far += (a * a).max(b * b);
    }
    (near, far)
}

/// `ρ_1` (see the module docs), or `None` when even the boundary does not clear the goal region.
fn shell_radius(k: f64, radius: f64, spline_bound: f64, reach: f64) -> Option<f64> {
    let clears = |rho: f64| {
        let beta0 = radius * radius - rho * rho;
        let g = 2.0 * rho / beta0 - spline_bound;
        g > 0.0 && rho - 2.0 * k / g > reach
    };
    let mut hi = radius * (1.0 - 1e-9);
    if !clears(hi) {
        return None;
    }
    let mut lo = reach.min(hi);
    if clears(lo) {
        return Some(lo);
    }
    for _ in 0..80 {
        let mid = 0.5 * (lo + hi);
        if clears(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(hi)
}

/// Prove that `nf`'s `φ` has no critical point in its workspace ball other than the goal, for
/// every goal in the ball (`goal_center`, `goal_radius`); see the module docs.
pub fn no_critical_point(
    nf: &NavigationFunction,
    goal_center: &[f64],
    goal_radius: f64,
) -> CriticalPointCertificate {
    let d = nf.dim();
    let spline = &nf.spline;
    let (c, r, k, rg) = (&nf.center, nf.radius, nf.k, goal_radius);
    let offset = goal_center
        .iter()
        .zip(c)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    let mut out = CriticalPointCertificate {
        holds: false,
        shell_radius: r,
        boxes: 0,
        depth: 0,
    };
    if !(offset + rg < r && k > 0.0) {
        return out;
    }
    let Some(rho1) = shell_radius(k, r, spline.gradient_norm_bound(), offset + rg) else {
        return out;
    };
    out.shell_radius = rho1;
    let four_k2 = 4.0 * k * k;
    let n = spline.intervals();
    let mut cell = [0usize; MAX_DIM];
    let mut stack: Vec<([f64; MAX_DIM], [f64; MAX_DIM], usize)> = Vec::new();
    let (mut dlo, mut dhi) = ([0.0; MAX_DIM], [0.0; MAX_DIM]);
    let mut hess = [[0.0; MAX_DIM]; MAX_DIM];
    let mut gs = [0.0; MAX_DIM];
    for _ in 0..n.pow(d as u32) {
        let mut lo = [0.0; MAX_DIM];
        let mut hi = [0.0; MAX_DIM];
        for i in 0..d {
            lo[i] = spline.lower()[i] + cell[i] as f64 * spline.spacing()[i];
            hi[i] = lo[i] + spline.spacing()[i];
        }
        if box_distances(&c[..d], &lo[..d], &hi[..d]).0 < rho1 * rho1 {
            spline.cell_bounds(&cell[..d], &mut dlo, &mut dhi, &mut hess);
            stack.push((lo, hi, 0));
            while let Some((lo, hi, depth)) = stack.pop() {
                out.boxes += 1;
                out.depth = out.depth.max(depth);
                if out.boxes > BOX_BUDGET {
                    return out;
                }
                let (near_c, far_c) = box_distances(&c[..d], &lo[..d], &hi[..d]);
                if near_c >= rho1 * rho1 {
                    continue;
                }
                // ∇log β_0 = −2(y − c)/β_0 with β_0 ∈ [R² − min(far, ρ_1²), R² − near]
                let b_lo = r * r - far_c.min(rho1 * rho1);
                let b_hi = r * r - near_c;
                let mut m = [0.0; MAX_DIM];
                for i in 0..d {
                    m[i] = 0.5 * (lo[i] + hi[i]);
                }
                spline.value_gradient(&m[..d], &mut gs);
                let (mut n_lo, mut n_hi) = (0.0, 0.0);
                let mut g_lo = [0.0; MAX_DIM];
                let mut g_hi = [0.0; MAX_DIM];
                for i in 0..d {
                    let (a, b) =
                        divide_positive(-2.0 * (hi[i] - c[i]), -2.0 * (lo[i] - c[i]), b_lo, b_hi);
                    let spread: f64 = (0..d).map(|j| hess[i][j] * 0.5 * (hi[j] - lo[j])).sum();
                    let s_lo = dlo[i].max(gs[i] - spread);
                    let s_hi = dhi[i].min(gs[i] + spread);
                    g_lo[i] = a + s_lo;
                    g_hi[i] = b + s_hi;
                    let (q_lo, q_hi) = square(g_lo[i], g_hi[i]);
                    n_lo += q_lo;
                    n_hi += q_hi;
                }
                // a critical point needs ‖y − y_d‖²‖∇log β‖² = 4k², ‖y − y_d‖ ∈ [e_lo, e_hi]
                let (near_g, far_g) = box_distances(&goal_center[..d], &lo[..d], &hi[..d]);
                let e_hi = far_g.sqrt() + rg;
                let e_lo = (near_g.sqrt() - rg).max(0.0);
                if n_hi * e_hi * e_hi < four_k2 || n_lo * e_lo * e_lo > four_k2 {
                    continue;
                }
                // ... and z(y) = y − 2k∇log β/‖∇log β‖² ∈ G
                let p = n_lo.max(four_k2 / (e_hi * e_hi));
                let q = if e_lo > 0.0 {
                    n_hi.min(four_k2 / (e_lo * e_lo))
                } else {
                    n_hi
                };
                let mut z_lo = [0.0; MAX_DIM];
                let mut z_hi = [0.0; MAX_DIM];
                for i in 0..d {
                    let (h_lo, h_hi) =
                        divide_positive(2.0 * k * g_lo[i], 2.0 * k * g_hi[i], p, q.max(p));
                    z_lo[i] = lo[i] - h_hi;
                    z_hi[i] = hi[i] - h_lo;
                }
                if box_distances(&goal_center[..d], &z_lo[..d], &z_hi[..d]).0 > rg * rg {
                    continue;
                }
                if depth >= MAX_DEPTH {
                    return out;
                }
                let axis = (0..d)
                    .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
                    .unwrap_or(0);
                let mid = 0.5 * (lo[axis] + hi[axis]);
                let (mut hi_a, mut lo_b) = (hi, lo);
                hi_a[axis] = mid;
                lo_b[axis] = mid;
                stack.push((lo, hi_a, depth + 1));
                stack.push((lo_b, hi, depth + 1));
            }
        }
        for ci in cell.iter_mut().take(d) {
            *ci += 1;
            if *ci < n {
                break;
            }
            *ci = 0;
        }
    }
    out.holds = true;
    out
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Vector3};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::motion::{FlowOptions, FlowPath, TensorBSpline, integrate_flow};

    const CENTER: [f64; 3] = [0.1, -0.2, 0.05];

    fn nf_with(spline: TensorBSpline, k: f64) -> NavigationFunction {
        NavigationFunction {
            k,
            length_scale: 2.0,
            center: CENTER.to_vec(),
            radius: 1.0,
            spline,
        }
    }

    fn grid() -> TensorBSpline {
        let lower: Vec<f64> = CENTER.iter().map(|c| c - 1.0).collect();
        let upper: Vec<f64> = CENTER.iter().map(|c| c + 1.0).collect();
        TensorBSpline::zeros(&lower, &upper, 4)
    }

    /// `s(y) = w·y`: uniform cubic B-splines reproduce linear functions with the coefficient of
    /// basis `j` at its centre, `lower + (j − 1)h` per axis.
    fn linear(w: [f64; 3]) -> TensorBSpline {
        let mut s = grid();
        let per = s.intervals() + 3;
        let (lower, h) = (s.lower().to_vec(), s.spacing().to_vec());
        for (j, c) in s.coefficients_mut().iter_mut().enumerate() {
            *c = (0..3)
                .map(|i| w[i] * (lower[i] + (((j / per.pow(i as u32)) % per) as f64 - 1.0) * h[i]))
                .sum();
        }
        s
    }

    /// A linear field `∇s = w` with the goal region a tiny ball at the centre: critical points
    /// lie on the ray `c + t ŵ`, `t > 0`, where `2k/t = ‖w‖ − 2t/(R² − t²)` (the condition
    /// `2(y − y_d) = (γ/k)∇log β` along the ray), so one exists iff
    /// `‖w‖ ≥ w* = min_t 2t/(R² − t²) + 2k/t`. The certificate must fail above `w*` (sound)
    /// and hold a little below it (tight).
    #[test]
    fn linear_field_certificate_switches_at_the_closed_form_threshold() {
        let k = 2.0;
        let dir = {
            let v = [1.0, 2.0, -0.5];
            let n: f64 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            v.map(|x| x / n.sqrt())
        };
        let w_star = (1..100_000)
            .map(|i| {
                let t = i as f64 / 100_000.0;
                2.0 * t / (1.0 - t * t) + 2.0 * k / t
            })
            .fold(f64::INFINITY, f64::min);
        assert!((w_star - 8.4).abs() < 0.2, "{w_star}");
        // the construction is the linear field it claims (independent of the certificate)
        let probe = linear(dir.map(|x| 3.0 * x));
        let mut g = [0.0; 3];
        probe.value_gradient(&[0.3, -0.1, 0.2], &mut g);
        for i in 0..3 {
            assert!((g[i] - 3.0 * dir[i]).abs() < 1e-12, "{g:?}");
        }
        for (factor, expect) in [
            (0.0, true),
            (0.5, true),
            (0.9, true),
            (1.01, false),
            (1.5, false),
        ] {
            let nf = nf_with(linear(dir.map(|x| factor * w_star * x)), k);
            let cert = no_critical_point(&nf, &CENTER, 1e-4);
            assert_eq!(cert.holds, expect, "‖w‖ = {factor} w*: {cert:?}");
            if factor == 1.5 {
                // the root the closed form predicts is one: ∇φ vanishes there
                let t = (1..100_000)
                    .map(|i| i as f64 / 100_000.0)
                    .find(|t| 2.0 * k / t <= factor * w_star - 2.0 * t / (1.0 - t * t))
                    .unwrap();
                let y: Vec<f64> = (0..3).map(|i| CENTER[i] + t * dir[i]).collect();
                let mut grad = [0.0; 3];
                nf.value_gradient(&y, &CENTER, &mut grad);
                let mut far = [0.0; 3];
                let y_far: Vec<f64> = (0..3).map(|i| CENTER[i] + 0.5 * t * dir[i]).collect();
                nf.value_gradient(&y_far, &CENTER, &mut far);
                let norm = |v: &[f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
                assert!(norm(&grad) < 1e-3 * norm(&far), "{grad:?} vs {far:?}");
            }
        }
    }

    /// `s = a·x·(1 + b·y)` in coordinates relative to the centre (exactly representable).
    fn sheared(a: f64, b: f64) -> TensorBSpline {
        let mut s = grid();
        let per = s.intervals() + 3;
        let (lower, h) = (s.lower().to_vec(), s.spacing().to_vec());
        for (j, c) in s.coefficients_mut().iter_mut().enumerate() {
            let at = |i: usize| {
                lower[i] + (((j / per.pow(i as u32)) % per) as f64 - 1.0) * h[i] - CENTER[i]
            };
            *c = a * at(0) * (1.0 + b * at(1));
        }
        s
    }

    /// Sheared fields `s = a·x·(1 + b·y)`, goal region a small ball at the centre: the
    /// certificate holds exactly where an independent Newton search finds no critical point
    /// (sound where one exists, and not so conservative that it refuses where none does).
    #[test]
    fn sheared_fields_certificate_agrees_with_a_newton_search() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let (mut held, mut refused) = (0, 0);
        for a in [4.0, 6.0, 8.0] {
            for b in [0.0, 0.5, 1.0, 1.5, 2.0] {
                let nf = nf_with(sheared(a, b), 2.0);
                let cert = no_critical_point(&nf, &CENTER, 0.02);
                let root = (0..400).find_map(|_| {
                    let y0 = ball(&mut rng, &CENTER, 0.95);
                    newton_root(&nf, &y0, &CENTER)
                });
                assert_eq!(
                    cert.holds,
                    root.is_none(),
                    "a {a} b {b}: {cert:?}, root {root:?}"
                );
                if cert.holds {
                    held += 1;
                } else {
                    refused += 1;
                }
            }
        }
        assert!(held >= 5 && refused >= 5, "held {held}, refused {refused}");
    }

    fn ball(rng: &mut ChaCha8Rng, center: &[f64], radius: f64) -> Vec<f64> {
        loop {
            let v: Vec<f64> = (0..3).map(|_| rng.random_range(-1.0..1.0)).collect();
            if v.iter().map(|x| x * x).sum::<f64>() < 1.0 {
                return v.iter().zip(center).map(|(a, c)| c + a * radius).collect();
            }
        }
    }

    /// Damped Newton on the flow field `f(y) = −2(y − y_d) + (γ/k)∇log β` (zero exactly at the
    /// critical points of `φ`), Jacobian by central differences: an independent search.
    fn newton_root(nf: &NavigationFunction, start: &[f64], yd: &[f64]) -> Option<Vec<f64>> {
        let field = |y: &[f64]| {
            let mut f = [0.0; 3];
            nf.flow(y, yd, &mut f);
            Vector3::from(f)
        };
        let inside = |y: &[f64]| {
            y.iter()
                .zip(&nf.center)
                .map(|(a, c)| (a - c).powi(2))
                .sum::<f64>()
                < 0.999 * nf.radius * nf.radius
        };
        let mut y = Vector3::from_column_slice(start);
        for _ in 0..60 {
            let f = field(y.as_slice());
            if f.norm() < 1e-10 {
                return ((y - Vector3::from_column_slice(yd)).norm() > 1e-4)
                    .then(|| y.as_slice().to_vec());
            }
            let mut jac = Matrix3::zeros();
            for j in 0..3 {
                let mut a = y;
                let mut b = y;
                a[j] += 1e-7;
                b[j] -= 1e-7;
                jac.set_column(j, &((field(a.as_slice()) - field(b.as_slice())) / 2e-7));
            }
            let step = jac.lu().solve(&(-f))?;
            let mut t = 1.0;
            loop {
                let next = y + step * t;
                if inside(next.as_slice()) && field(next.as_slice()).norm() < f.norm() {
                    y = next;
                    break;
                }
                t *= 0.5;
                if t < 1e-6 {
                    return None;
                }
            }
        }
        None
    }

    /// Random fields of growing amplitude: wherever an independent Newton search finds a critical
    /// point the certificate must not hold; wherever it holds, the flow converges from random
    /// starts to random goals, also where the classical `γ`-decreasing bound fails. Paths on
    /// which `γ` rises are counted: on these fields none (`p = (y − y_d)·∇log β/k` stays below 2
    /// wherever the certificate holds; in the sheared family above every field with `p > 2`
    /// somewhere also has a critical point).
    #[test]
    fn certificate_is_sound_against_newton_and_its_flows_converge() {
        let mut rng = ChaCha8Rng::seed_from_u64(19);
        let (mut held, mut refuted, mut rising, mut beyond_classical) = (0, 0, 0, 0);
        let mut path = FlowPath::default();
        let opts = FlowOptions::default();
        for trial in 0..36 {
            let amplitude = [0.5, 2.0, 4.0, 8.0, 16.0, 32.0][trial % 6];
            let mut spline = grid();
            for c in spline.coefficients_mut() {
                *c = amplitude * rng.random_range(-0.5..0.5);
            }
            let nf = nf_with(spline, 2.0);
            let gc = ball(&mut rng, &CENTER, 0.3);
            let rg = 0.15;
            let cert = no_critical_point(&nf, &gc, rg);
            let mut root = None;
            'search: for _ in 0..12 {
                let yd = ball(&mut rng, &gc, rg);
                for _ in 0..12 {
                    let y0 = ball(&mut rng, &CENTER, 0.95);
                    if let Some(r) = newton_root(&nf, &y0, &yd) {
                        root = Some((r, yd));
                        break 'search;
                    }
                }
            }
            if let Some((r, yd)) = &root {
                refuted += 1;
                assert!(
                    !cert.holds,
                    "certified, but ∇φ = 0 at {r:?} for goal {yd:?}"
                );
            }
            if !cert.holds {
                continue;
            }
            held += 1;
            if !nf.certificate(&gc, rg, 1.0).gamma_decreasing {
                beyond_classical += 1;
            }
            for _ in 0..200 {
                let y0 = ball(&mut rng, &CENTER, 0.98);
                let yd = ball(&mut rng, &gc, rg);

                integrate_flow(&nf, &y0, &yd, &opts, &mut path);
                assert!(
                    path.converged,
                    "{y0:?} → {yd:?}: error {}",
                    path.final_error
                );
                if path.gamma.windows(2).any(|w| w[1] > w[0]) {
                    rising += 1;
                }
            }
        }
        println!(
            "held {held}, refuted {refuted}, beyond classical {beyond_classical}, γ rose on {rising} paths"
        );
        assert!(held > 0 && refuted > 0 && beyond_classical > 0);
    }
}
