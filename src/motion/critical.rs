//! The navigation-function certificate: `φ` has no critical point in the workspace ball but the
//! goal, for every goal in the goal region, and the workspace boundary repels.
//!
//! **Theorem.** Let `B` be the open workspace ball `(c, R)`, `G ⊂ B` the closed goal ball
//! `(g, r_g)`, `β = β_0 e^s > 0` on `B` with `β_0 = R² − ‖y − c‖²`, and
//! `F(y, y_d) = 2(y − y_d) − (γ/k)∇log β(y)`, `γ = ‖y − y_d‖²`. If `F(y, y_d) ≠ 0` for every
//! `y_d ∈ G` and `y ∈ B \ {y_d}`, then for every goal `y_d ∈ G` and start `y_0 ∈ B` the flow
//! `ẏ = −F` (parallel to `−∇φ`) stays in `B` and converges to `y_d`; `γ` may rise on the way.
//!
//! *Proof sketch.* `∇φ = β(γ^k + β)^{−1−1/k} F`, so the critical points of `φ` in `B` are the
//! zeros of `F`: only `y_d`, where `φ = 0` and the Hessian is `2β^{−1/k} I` (a non-degenerate
//! minimum). `φ` is smooth on `B`, `0 ≤ φ < 1` there and `φ → 1` at `∂B` (`β → 0`), so the
//! sublevel set `{φ ≤ φ(y_0)}` is a compact subset of `B`; along the flow
//! `φ̇ = −c(y)‖∇φ‖² ≤ 0` (`c > 0`), so the solution stays in that set and exists for all time,
//! and by LaSalle's invariance principle its ω-limit set lies in `{∇φ = 0} = {y_d}`. (This is
//! Rimon and Koditschek's navigation-function argument, ref. [39], with the learned field `s`
//! in `β`.) Nothing here asks `γ` to fall: the flow may move away from the goal, which is what
//! the demonstrations do (the hand opens before it closes).
//!
//! *How `F ≠ 0` is certified.* Write `h(y) = ∇log β(y)/k`. `F = 0` with `y ≠ y_d` forces
//! `y − y_d = (γ/2)h`, hence `‖y − y_d‖ = 2/‖h‖` and `y_d = y − 2h/‖h‖²`: every `y` is a
//! spurious critical point for at most one goal, the *critical goal* `y* (y) = y − 2h/‖h‖²`.
//! The certificate shows that `y*(y) ∉ G` for every `y ∈ B`:
//!
//! 1. *Shell* `ρ = ‖y − c‖ ≥ R_s`: `(y − c)·F = 2(y − c)·(y − y_d) + (γ/k)(2ρ²/β_0 − (y − c)·∇s)`.
//!    With `ρ_g = ‖g − c‖ + r_g`, the first term is at least `2ρ(ρ − ρ_g) > 0` for `ρ > ρ_g`, and
//!    the second is non-negative once `2ρ/β_0 ≥ S`, `S ≥ ‖∇s‖` the spline's global derivative
//!    bound; so for `ρ ≥ R_s = max(ρ_g, √(1/S² + R²) − 1/S)` the field points outward (`−F`
//!    inward): no critical point, and the boundary repels.
//! 2. *Inner ball* `ρ ≤ R_s`: branch and bound over boxes, starting from the spline's knot cells.
//!    On a box, interval bounds of `h` come from the mean-value form (the exact `∇s` at the box
//!    centre ± the cell's second-derivative bound × the half-widths, intersected with the cell's
//!    first-derivative bound) and interval arithmetic on `∇log β_0 = −2(y − c)/β_0`. A box is
//!    cleared when any of: `‖h‖_max · D_max < 2` (the critical distance `2/‖h‖` exceeds the
//!    farthest goal), `‖h‖_min · D_min > 2` (it is shorter than the nearest goal), or the
//!    interval box of `y*` misses `G`. Otherwise it is bisected along its longest side, within
//!    a depth and box budget (an iteration budget, not wall time); an undecided box fails the
//!    certificate.
//!
//! The bounds are conservative, so a field that passes has no spurious critical point; one with
//! a spurious critical point whose critical goal lies inside `G` can never pass (the test
//! `a_field_with_a_spurious_critical_point_is_refused` builds one).

use serde::{Deserialize, Serialize};

use super::{MAX_DIM, NavigationFunction};

/// Branch-and-bound limits (deterministic: counts, not time).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CriticalBudget {
    /// Bisections below a knot cell.
    pub max_depth: usize,
    /// Boxes examined in total.
    pub max_boxes: usize,
}

impl Default for CriticalBudget {
    fn default() -> Self {
        CriticalBudget {
            max_depth: 14,
            max_boxes: 400_000,
        }
    }
}

/// Outcome of [`check_critical_free`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CriticalCheck {
    /// No critical point of `φ` in the workspace but the goal, for every goal in the region.
    pub holds: bool,
    /// `R_s`: beyond it the field points outward analytically (the shell).
    pub shell_radius: f64,
    /// Boxes examined by the branch and bound.
    pub boxes: usize,
    /// Deepest bisection used.
    pub depth: usize,
}

#[derive(Clone, Copy)]
struct Cell {
    lo: [f64; MAX_DIM],
    hi: [f64; MAX_DIM],
    knot: [usize; MAX_DIM],
    depth: usize,
}

/// Interval `[a, b] / [c, e]` with `0 < c ≤ e`.
#[inline]
fn div_pos(a: f64, b: f64, c: f64, e: f64) -> (f64, f64) {
    let q = [a / c, a / e, b / c, b / e];
    (
        q.iter().cloned().fold(f64::INFINITY, f64::min),
        q.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// Squared distance from `p` to the box and from `p` to the box's farthest corner.
#[inline]
fn box_distances(lo: &[f64], hi: &[f64], p: &[f64], d: usize) -> (f64, f64) {
    let (mut near, mut far) = (0.0, 0.0);
    for i in 0..d {
        let (a, b) = (lo[i] - p[i], hi[i] - p[i]);
        if a > 0.0 {
            near += a * a;
        } else if b < 0.0 {
            near += b * b;
        }
        far += (a * a).max(b * b);
    }
    (near, far)
}

/// Certify that `φ` of `nf` has no critical point in its workspace ball other than the goal,
/// for every goal in the ball `(goal_center, goal_radius)` (see the module docs).
pub fn check_critical_free(
    nf: &NavigationFunction,
    goal_center: &[f64],
    goal_radius: f64,
    budget: &CriticalBudget,
) -> CriticalCheck {
    let d = nf.dim();
    let r = nf.radius;
    let c = &nf.center;
    let k = nf.k;
    let offset = (0..d)
        .map(|i| (goal_center[i] - c[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    let rho_g = offset + goal_radius;
    let fail = |shell: f64, boxes, depth| CriticalCheck {
        holds: false,
        shell_radius: shell,
        boxes,
        depth,
    };
    if !(rho_g < r && k > 0.0 && k.is_finite()) {
        return fail(r, 0, 0);
    }
    let s_bound = nf.spline.gradient_norm_bound();
    if !s_bound.is_finite() {
        return fail(r, 0, 0);
    }
    let shell = if s_bound > 0.0 {
        let inv = 1.0 / s_bound;
        ((inv * inv + r * r).sqrt() - inv).max(rho_g)
    } else {
        rho_g
    };
    let shell2 = shell * shell;
    let spline = &nf.spline;
    let n = spline.intervals();
    let spacing = spline.spacing();
    let lower = spline.lower();
    let mut stack: Vec<Cell> = Vec::new();
    let mut knot = [0usize; MAX_DIM];
    for _ in 0..n.pow(d as u32) {
        let mut cell = Cell {
            lo: [0.0; MAX_DIM],
            hi: [0.0; MAX_DIM],
            knot,
            depth: 0,
        };
        for i in 0..d {
            cell.lo[i] = lower[i] + knot[i] as f64 * spacing[i];
            cell.hi[i] = cell.lo[i] + spacing[i];
        }
        stack.push(cell);
        for kk in knot.iter_mut().take(d) {
            *kk += 1;
            if *kk < n {
                break;
            }
            *kk = 0;
        }
    }
    let mut boxes = 0usize;
    let mut deepest = 0usize;
    let (mut dlo, mut dhi, mut hess) = ([0.0; MAX_DIM], [0.0; MAX_DIM], [[0.0; MAX_DIM]; MAX_DIM]);
    let mut last_knot = [usize::MAX; MAX_DIM];
    while let Some(b) = stack.pop() {
        let (near_c, far_c) = box_distances(&b.lo, &b.hi, c, d);
        if near_c > shell2 {
            continue; // the shell's analytic bound covers it
        }
        boxes += 1;
        deepest = deepest.max(b.depth);
        if boxes > budget.max_boxes {
            return fail(shell, boxes, deepest);
        }
        if b.knot[..d] != last_knot[..d] {
            spline.cell_derivative_bounds(&b.knot[..d], &mut dlo, &mut dhi, &mut hess);
            last_knot = b.knot;
        }
        // ∇s on the box: mean-value form around the centre ∩ the cell's bound.
        let mut mid = [0.0; MAX_DIM];
        let mut half = [0.0; MAX_DIM];
        for i in 0..d {
            mid[i] = 0.5 * (b.lo[i] + b.hi[i]);
            half[i] = 0.5 * (b.hi[i] - b.lo[i]);
        }
        let mut gm = [0.0; MAX_DIM];
        spline.value_gradient(&mid[..d], &mut gm);
        // ∇log β_0 on the part of the box inside the inner ball (ρ ≤ R_s).
        let rho_max2 = far_c.min(shell2);
        let (b_lo, b_hi) = (r * r - rho_max2, r * r - near_c);
        let mut h_lo = [0.0; MAX_DIM];
        let mut h_hi = [0.0; MAX_DIM];
        for i in 0..d {
            let spread: f64 = (0..d).map(|j| hess[i][j] * half[j]).sum();
            let s_lo = (gm[i] - spread).max(dlo[i]);
            let s_hi = (gm[i] + spread).min(dhi[i]);
            let (w_lo, w_hi) =
                div_pos(-2.0 * (b.hi[i] - c[i]), -2.0 * (b.lo[i] - c[i]), b_lo, b_hi);
            h_lo[i] = (s_lo + w_lo) / k;
            h_hi[i] = (s_hi + w_hi) / k;
        }
        let (mut hmin2, mut hmax2) = (0.0, 0.0);
        for i in 0..d {
            if h_lo[i] > 0.0 {
                hmin2 += h_lo[i] * h_lo[i];
            } else if h_hi[i] < 0.0 {
                hmin2 += h_hi[i] * h_hi[i];
            }
            hmax2 += (h_lo[i] * h_lo[i]).max(h_hi[i] * h_hi[i]);
        }
        let (near_g, far_g) = box_distances(&b.lo, &b.hi, goal_center, d);
        let d_min = (near_g.sqrt() - goal_radius).max(0.0);
        let d_max = far_g.sqrt() + goal_radius;
        // `‖y − y_d‖ = 2/‖h‖` must lie in [d_min, d_max].
        let cleared = hmax2.sqrt() * d_max < 2.0
            || (d_min > 0.0 && hmin2.sqrt() * d_min > 2.0)
            || (hmin2 > 0.0 && {
                // interval box of y* = y − 2h/‖h‖², tested against the goal ball
                let mut dist2 = 0.0;
                for i in 0..d {
                    let (q_lo, q_hi) = {
                        let q = [
                            h_lo[i] / hmin2,
                            h_lo[i] / hmax2,
                            h_hi[i] / hmin2,
                            h_hi[i] / hmax2,
                        ];
                        (
                            q.iter().cloned().fold(f64::INFINITY, f64::min),
                            q.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
                        )
                    };
                    let (y_lo, y_hi) = (b.lo[i] - 2.0 * q_hi, b.hi[i] - 2.0 * q_lo);
                    let (a, e) = (y_lo - goal_center[i], y_hi - goal_center[i]);
                    if a > 0.0 {
                        dist2 += a * a;
                    } else if e < 0.0 {
                        dist2 += e * e;
                    }
                }
                dist2 > goal_radius * goal_radius
            });
        if cleared {
            continue;
        }
        if b.depth >= budget.max_depth {
            return fail(shell, boxes, deepest);
        }
        let axis = (0..d)
            .max_by(|&a, &e| half[a].total_cmp(&half[e]))
            .unwrap_or(0);
        let mut left = b;
        let mut right = b;
        left.hi[axis] = mid[axis];
        right.lo[axis] = mid[axis];
        left.depth += 1;
        right.depth += 1;
        stack.push(right);
        stack.push(left);
    }
    CriticalCheck {
        holds: true,
        shell_radius: shell,
        boxes,
        depth: deepest,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{FlowOptions, FlowPath, TensorBSpline, integrate_flow};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A navigation function on the ball `(c, R)` whose spline is the linear function `a·y`
    /// (exact in the cubic B-spline basis: coefficient `j` at its Greville abscissa
    /// `lower + (j − 1)h`), so `∇s = a` everywhere.
    fn linear_nf(center: &[f64], radius: f64, k: f64, a: &[f64]) -> NavigationFunction {
        let d = center.len();
        let lower: Vec<f64> = center.iter().map(|c| c - radius).collect();
        let upper: Vec<f64> = center.iter().map(|c| c + radius).collect();
        let mut spline = TensorBSpline::zeros(&lower, &upper, 4);
        let per = spline.intervals() + 3;
        let h = spline.spacing().to_vec();
        for (idx, c) in spline.coefficients_mut().iter_mut().enumerate() {
            let mut rest = idx;
            let mut v = 0.0;
            for i in 0..d {
                let j = rest % per;
                rest /= per;
                v += a[i] * (lower[i] + (j as f64 - 1.0) * h[i]);
            }
            *c = v;
        }
        NavigationFunction {
            k,
            length_scale: 2.0 * radius,
            center: center.to_vec(),
            radius,
            spline,
        }
    }

    #[test]
    fn a_field_with_a_spurious_critical_point_is_refused() {
        let center = [0.0, 0.0, 0.0];
        let (radius, k) = (2.0, 3.0);
        let goal_center = [0.3, -0.2, 0.1];
        let goal_radius = 0.4;
        // place a critical point at y for the goal y_d (inside the goal region): choose the
        // constant gradient a so that ∇log β(y)/k = 2(y − y_d)/γ exactly
        let y = [1.0, 0.5, -0.4];
        let yd = [0.45, -0.1, 0.2];
        let e: Vec<f64> = (0..3).map(|i| y[i] - yd[i]).collect();
        let gamma: f64 = e.iter().map(|x| x * x).sum();
        let rc2: f64 = y.iter().map(|x| x * x).sum();
        let beta0 = radius * radius - rc2;
        let a: Vec<f64> = (0..3)
            .map(|i| 2.0 * k * e[i] / gamma + 2.0 * y[i] / beta0)
            .collect();
        let nf = linear_nf(&center, radius, k, &a);
        // independent check of the construction: the flow (∝ −∇φ) vanishes at y
        let mut f = [0.0; 3];
        nf.flow(&y, &yd, &mut f);
        assert!(f.iter().all(|x| x.abs() < 1e-9), "{f:?}");
        let check = check_critical_free(&nf, &goal_center, goal_radius, &CriticalBudget::default());
        assert!(!check.holds, "{check:?}");
        // the same field at a twentieth of its strength moves the critical goal far away and
        // is certified; shrunk fields stay sound: flows from random starts converge
        let weak = linear_nf(
            &center,
            radius,
            k,
            &a.iter().map(|x| x / 20.0).collect::<Vec<_>>(),
        );
        let check =
            check_critical_free(&weak, &goal_center, goal_radius, &CriticalBudget::default());
        assert!(check.holds, "{check:?}");
    }

    #[test]
    fn the_bare_workspace_ball_is_certified_for_every_k_from_1() {
        for &k in &[1.0, 1.5, 2.0, 7.0, 64.0] {
            let nf = linear_nf(&[0.2, -0.1], 1.5, k, &[0.0, 0.0]);
            let check = check_critical_free(&nf, &[0.1, 0.3], 0.9, &CriticalBudget::default());
            assert!(check.holds, "k {k}: {check:?}");
        }
    }

    /// Brute-force reference: the critical goals `y*(y) = y − 2h/‖h‖²` of a fine grid of
    /// workspace points that land inside the goal ball (each is a spurious critical point).
    fn brute_force_hits(nf: &NavigationFunction, goal_center: &[f64], goal_radius: f64) -> usize {
        let (c, r) = (&nf.center, nf.radius);
        let mut hits = 0;
        for a in 0..300 {
            for b in 0..300 {
                let y = [
                    c[0] - r + 2.0 * r * a as f64 / 299.0,
                    c[1] - r + 2.0 * r * b as f64 / 299.0,
                ];
                if (y[0] - c[0]).powi(2) + (y[1] - c[1]).powi(2) >= r * r {
                    continue;
                }
                let mut g = [0.0; 2];
                nf.log_beta(&y, &mut g);
                let h = [g[0] / nf.k, g[1] / nf.k];
                let h2 = h[0] * h[0] + h[1] * h[1];
                let ys = [y[0] - 2.0 * h[0] / h2, y[1] - 2.0 * h[1] / h2];
                if (ys[0] - goal_center[0]).powi(2) + (ys[1] - goal_center[1]).powi(2)
                    < goal_radius * goal_radius
                {
                    hits += 1;
                }
            }
        }
        hits
    }

    /// Fields of random linear trend (0.5-8 per unit, any direction) plus random bumps: every
    /// field in which a brute-force grid finds a spurious critical point is refused, and from
    /// every certified one the flow converges for random (start, goal) pairs.
    #[test]
    fn certified_fields_converge_and_fields_with_critical_points_are_refused() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let center = [0.1, -0.2];
        let radius = 1.0;
        let goal_center = [0.2, -0.1];
        let goal_radius = 0.3;
        let (mut certified, mut refused, mut critical, mut rises) = (0, 0, 0, 0);
        let mut path = FlowPath::default();
        for trial in 0..60 {
            let slope = 0.5 + 7.5 * trial as f64 / 59.0;
            let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let a = [slope * angle.cos(), slope * angle.sin()];
            let mut nf = linear_nf(&center, radius, 1.0, &a);
            for c in nf.spline.coefficients_mut() {
                *c += rng.random_range(-0.3..0.3);
            }
            let check =
                check_critical_free(&nf, &goal_center, goal_radius, &CriticalBudget::default());
            let hits = brute_force_hits(&nf, &goal_center, goal_radius);
            if hits > 0 {
                critical += 1;
                assert!(
                    !check.holds,
                    "trial {trial}: {hits} critical points but {check:?}"
                );
            }
            if !check.holds {
                refused += 1;
                continue;
            }
            certified += 1;
            for _ in 0..200 {
                let y0: Vec<f64> = loop {
                    let v = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
                    if v[0] * v[0] + v[1] * v[1] < 0.99 {
                        break (0..2).map(|i| center[i] + radius * v[i]).collect();
                    }
                };
                let yd: Vec<f64> = loop {
                    let v = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
                    if v[0] * v[0] + v[1] * v[1] <= 1.0 {
                        break (0..2)
                            .map(|i| goal_center[i] + goal_radius * v[i])
                            .collect();
                    }
                };
                integrate_flow(&nf, &y0, &yd, &FlowOptions::default(), &mut path);
                assert!(path.converged, "trial {trial}: {:?}", path.final_error);
                assert!(path.final_error <= 1e-6);
                if path.gamma.windows(2).any(|w| w[1] > w[0]) {
                    rises += 1;
                }
            }
        }
        println!(
            "certified {certified}, refused {refused} ({critical} with brute-force critical points), flows where γ rose {rises}"
        );
        assert!(certified >= 5 && critical >= 5);
    }
}
