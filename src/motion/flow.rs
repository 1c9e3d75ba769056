//! Integration of the NF flow from a start to a goal in PCA coordinates.

use serde::{Deserialize, Serialize};

use super::{MAX_DIM, NavigationFunction};

/// Flow integration settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowOptions {
    /// Stop when `‖y − y_d‖ ≤ tolerance · R` (R the workspace radius).
    pub tolerance: f64,
    /// Relative local error per step (w.r.t. the current distance to the goal).
    pub relative_error: f64,
    /// Hard bound on accepted + rejected steps.
    pub max_steps: usize,
    /// Largest step displacement as a fraction of the start's distance to the goal (path
    /// resolution for the back-projection and timing).
    pub max_step_fraction: f64,
}

impl Default for FlowOptions {
    fn default() -> Self {
        FlowOptions {
            tolerance: 1e-8,
            relative_error: 1e-5,
            max_steps: 20_000,
            max_step_fraction: 0.04,
        }
    }
}

/// The integrated path: `points` (`len × d`, row-major), `γ` at each point.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FlowPath {
    pub dim: usize,
    pub points: Vec<f64>,
    pub gamma: Vec<f64>,
    pub converged: bool,
    /// `‖y_last − y_d‖` when integration stopped.
    pub final_error: f64,
    pub steps: usize,
}

impl FlowPath {
    pub fn len(&self) -> usize {
        self.gamma.len()
    }
    pub fn is_empty(&self) -> bool {
        self.gamma.is_empty()
    }
    pub fn point(&self, i: usize) -> &[f64] {
        &self.points[i * self.dim..(i + 1) * self.dim]
    }
}

/// `dy/ds = γf/‖f‖²`: the flow `f = −(∇γ − (γ/k)∇log β)` (parallel to `−∇φ`, so `φ` decreases
/// along it wherever `f ≠ 0`) at speed `γ/‖f‖`. Near the goal `f ≈ −2(y − y_d)`, so
/// `dy/ds ≈ −(y − y_d)/2` and `γ(s) ≈ γ_0 e^{−s}`. Neither `γ` nor `φ` serves as the parameter:
/// `γ` may rise under the navigation-function certificate ([`super::no_critical_point`]), and
/// `φ` is nearly flat (`≈ 1`) on the plateaus a large `k` makes, where a `φ`-decay parameter
/// would ask for steps of 10¹² workspace radii. Returns `false` where the field is not finite or
/// vanishes (outside the workspace, or a critical point).
#[inline]
fn rhs(nf: &NavigationFunction, y: &[f64], y_d: &[f64], out: &mut [f64]) -> bool {
    let d = nf.dim();
    let p = nf.flow(y, y_d, out);
    let (mut gamma, mut f2, mut r2) = (0.0, 0.0, 0.0);
    for i in 0..d {
        gamma += (y[i] - y_d[i]).powi(2);
        f2 += out[i] * out[i];
        r2 += (y[i] - nf.center[i]).powi(2);
    }
    let scale = gamma / f2;
    if !(r2 < nf.radius * nf.radius && p.is_finite() && scale.is_finite() && f2 > 0.0) {
        return false;
    }
    for o in out.iter_mut().take(d) {
        *o *= scale;
    }
    true
}

// Dormand–Prince 5(4) tableau (the field is autonomous, so the nodes c_i are not needed).
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [
        19372.0 / 6561.0,
        -25360.0 / 2187.0,
        64448.0 / 6561.0,
        -212.0 / 729.0,
        0.0,
        0.0,
    ],
    [
        9017.0 / 3168.0,
        -355.0 / 33.0,
        46732.0 / 5247.0,
        49.0 / 176.0,
        -5103.0 / 18656.0,
        0.0,
    ],
    [
        35.0 / 384.0,
        0.0,
        500.0 / 1113.0,
        125.0 / 192.0,
        -2187.0 / 6784.0,
        11.0 / 84.0,
    ],
];
const B5: [f64; 7] = [
    35.0 / 384.0,
    0.0,
    500.0 / 1113.0,
    125.0 / 192.0,
    -2187.0 / 6784.0,
    11.0 / 84.0,
    0.0,
];
const B4: [f64; 7] = [
    5179.0 / 57600.0,
    0.0,
    7571.0 / 16695.0,
    393.0 / 640.0,
    -92097.0 / 339200.0,
    187.0 / 2100.0,
    1.0 / 40.0,
];

/// Integrate the flow from `y0` to `y_d` (adaptive Dormand–Prince in the parameter of [`rhs`]),
/// writing into `out` (its buffers are reused). Steps are bounded by `opts.max_steps`.
pub fn integrate_flow(
    nf: &NavigationFunction,
    y0: &[f64],
    y_d: &[f64],
    opts: &FlowOptions,
    out: &mut FlowPath,
) {
    let d = nf.dim();
    debug_assert!(d <= MAX_DIM);
    out.dim = d;
    out.points.clear();
    out.gamma.clear();
    out.steps = 0;
    let dist = |y: &[f64]| -> f64 { (0..d).map(|i| (y[i] - y_d[i]).powi(2)).sum::<f64>().sqrt() };
    let mut y = [0.0; MAX_DIM];
    y[..d].copy_from_slice(&y0[..d]);
    let d0 = dist(&y);
    out.points.extend_from_slice(&y[..d]);
    out.gamma.push(d0 * d0);
    let stop = opts.tolerance * nf.radius;
    if d0 <= stop {
        out.converged = true;
        out.final_error = d0;
        return;
    }
    let max_disp = opts.max_step_fraction * d0;
    let mut h: f64 = 0.1;
    let mut k = [[0.0; MAX_DIM]; 7];
    let mut tmp = [0.0; MAX_DIM];
    let mut cur = d0;
    while out.steps < opts.max_steps {
        out.steps += 1;
        let mut ok = true;
        for stage in 0..7 {
            for i in 0..d {
                let mut v = y[i];
                for (j, kj) in k.iter().enumerate().take(stage) {
                    v += h * A[stage][j] * kj[i];
                }
                tmp[i] = v;
            }
            if !rhs(nf, &tmp, y_d, &mut k[stage]) {
                ok = false;
                break;
            }
        }
        if !ok {
            h *= 0.25;
            if h < 1e-12 {
                break;
            }
            continue;
        }
        let mut err: f64 = 0.0;
        let mut disp = 0.0;
        let mut y_new = [0.0; MAX_DIM];
        for i in 0..d {
            let mut hi = 0.0;
            let mut lo = 0.0;
            for s in 0..7 {
                hi += B5[s] * k[s][i];
                lo += B4[s] * k[s][i];
            }
            y_new[i] = y[i] + h * hi;
            err = err.max((h * (hi - lo)).abs());
            disp += (h * hi).powi(2);
        }
        let scale = opts.relative_error * cur + 1e-15 * nf.radius;
        let ratio = err / scale;
        let disp = disp.sqrt();
        if ratio > 1.0 || disp > max_disp {
            let f = (0.9 * ratio.powf(-0.2)).clamp(0.1, 0.9);
            let g = if disp > max_disp {
                0.9 * max_disp / disp
            } else {
                1.0
            };
            h *= f.min(g);
            continue;
        }
        y = y_new;
        cur = dist(&y);
        out.points.extend_from_slice(&y[..d]);
        out.gamma.push(cur * cur);
        if cur <= stop {
            out.converged = true;
            out.final_error = cur;
            return;
        }
        let grow = if ratio > 0.0 {
            (0.9 * ratio.powf(-0.2)).clamp(0.2, 5.0)
        } else {
            5.0
        };
        h = (h * grow).min(2.0);
    }
    out.converged = false;
    out.final_error = cur;
}
