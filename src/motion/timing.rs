//! Time scaling: minimum-jerk profile, C² path interpolation, monotone phase maps.

use serde::{Deserialize, Serialize};

/// Minimum-jerk progress `m(τ) = 10τ³ − 15τ⁴ + 6τ⁵` on `τ ∈ [0, 1]` (zero velocity and
/// acceleration at both ends, the bell-shaped speed profile of human reaching).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MinimumJerk;

impl MinimumJerk {
    /// `(m, dm/dτ, d²m/dτ²)`.
    #[inline]
    pub fn eval(tau: f64) -> (f64, f64, f64) {
        let t = tau.clamp(0.0, 1.0);
        let t2 = t * t;
        let t3 = t2 * t;
        (
            t3 * (10.0 - 15.0 * t + 6.0 * t2),
            30.0 * t2 * (1.0 - t) * (1.0 - t),
            60.0 * t * (1.0 - 3.0 * t + 2.0 * t2),
        )
    }
}

/// Natural cubic spline through `nodes` equally spaced values on `[0, 1]`, several channels at
/// once (one per joint): C², so positions, velocities and accelerations of the timed path are
/// continuous.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NaturalCubic {
    nodes: usize,
    channels: usize,
    /// `nodes × channels` values and second derivatives.
    values: Vec<f64>,
    second: Vec<f64>,
}

impl NaturalCubic {
    /// `values` is `nodes × channels`, row-major; `nodes ≥ 2`.
    pub fn new(values: Vec<f64>, channels: usize) -> Self {
        let nodes = values.len() / channels;
        assert!(nodes >= 2);
        let h = 1.0 / (nodes - 1) as f64;
        let mut second = vec![0.0; values.len()];
        if nodes > 2 {
            // Thomas algorithm for M_{j-1} + 4 M_j + M_{j+1} = 6/h² Δ²y_j, M_0 = M_{N-1} = 0.
            let inner = nodes - 2;
            let mut cp = vec![0.0; inner];
            let mut dp = vec![0.0; inner];
            for c in 0..channels {
                for j in 0..inner {
                    let r = 6.0 / (h * h)
                        * (values[(j + 2) * channels + c] - 2.0 * values[(j + 1) * channels + c]
                            + values[j * channels + c]);
                    if j == 0 {
                        cp[0] = 0.25;
                        dp[0] = r / 4.0;
                    } else {
                        let m = 4.0 - cp[j - 1];
                        cp[j] = 1.0 / m;
                        dp[j] = (r - dp[j - 1]) / m;
                    }
                }
                for j in (0..inner).rev() {
                    let next = if j + 1 < inner {
                        second[(j + 2) * channels + c]
                    } else {
                        0.0
                    };
                    second[(j + 1) * channels + c] = dp[j] - cp[j] * next;
                }
            }
        }
        NaturalCubic {
            nodes,
            channels,
            values,
            second,
        }
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Value, first and second derivative of every channel at `x ∈ [0, 1]`.
    pub fn eval(&self, x: f64, p: &mut [f64], dp: &mut [f64], ddp: &mut [f64]) {
        let n = self.channels;
        let h = 1.0 / (self.nodes - 1) as f64;
        let x = x.clamp(0.0, 1.0);
        let j = ((x / h).floor() as usize).min(self.nodes - 2);
        let a = (j + 1) as f64 * h - x;
        let b = x - j as f64 * h;
        for c in 0..n {
            let y0 = self.values[j * n + c];
            let y1 = self.values[(j + 1) * n + c];
            let m0 = self.second[j * n + c];
            let m1 = self.second[(j + 1) * n + c];
            let c0 = y0 / h - m0 * h / 6.0;
            let c1 = y1 / h - m1 * h / 6.0;
            p[c] = m0 * a * a * a / (6.0 * h) + m1 * b * b * b / (6.0 * h) + c0 * a + c1 * b;
            dp[c] = -m0 * a * a / (2.0 * h) + m1 * b * b / (2.0 * h) - c0 + c1;
            ddp[c] = m0 * a / h + m1 * b / h;
        }
    }
}

/// Monotone piecewise-cubic Hermite interpolant (Fritsch–Carlson) of nondecreasing values on
/// equally spaced nodes over `[0, 1]`: a phase map that never runs backwards.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pchip {
    values: Vec<f64>,
    slopes: Vec<f64>,
}

impl Pchip {
    pub fn new(values: Vec<f64>) -> Self {
        let n = values.len();
        assert!(n >= 2);
        let h = 1.0 / (n - 1) as f64;
        let delta: Vec<f64> = values.windows(2).map(|w| (w[1] - w[0]) / h).collect();
        let mut slopes = vec![0.0; n];
        slopes[0] = delta[0];
        slopes[n - 1] = delta[n - 2];
        for j in 1..n - 1 {
            slopes[j] = if delta[j - 1] * delta[j] <= 0.0 {
                0.0
            } else {
                // harmonic mean keeps the interpolant monotone (Fritsch–Butland form)
                2.0 * delta[j - 1] * delta[j] / (delta[j - 1] + delta[j])
            };
        }
        for j in 0..n - 1 {
            if delta[j] == 0.0 {
                slopes[j] = 0.0;
                slopes[j + 1] = 0.0;
            } else {
                let a = slopes[j] / delta[j];
                let b = slopes[j + 1] / delta[j];
                let s = a * a + b * b;
                if s > 9.0 {
                    let t = 3.0 / s.sqrt();
                    slopes[j] = t * a * delta[j];
                    slopes[j + 1] = t * b * delta[j];
                }
            }
        }
        Pchip { values, slopes }
    }

    /// The identity map.
    pub fn identity() -> Self {
        Pchip::new(vec![0.0, 1.0])
    }

    /// `(H, H', H'')` at `x ∈ [0, 1]`.
    pub fn eval(&self, x: f64) -> (f64, f64, f64) {
        let n = self.values.len();
        let h = 1.0 / (n - 1) as f64;
        let x = x.clamp(0.0, 1.0);
        let j = ((x / h).floor() as usize).min(n - 2);
        let t = (x - j as f64 * h) / h;
        let (y0, y1) = (self.values[j], self.values[j + 1]);
        let (m0, m1) = (self.slopes[j] * h, self.slopes[j + 1] * h);
        let t2 = t * t;
        let t3 = t2 * t;
        let v = (2.0 * t3 - 3.0 * t2 + 1.0) * y0
            + (t3 - 2.0 * t2 + t) * m0
            + (-2.0 * t3 + 3.0 * t2) * y1
            + (t3 - t2) * m1;
        let d = (6.0 * t2 - 6.0 * t) * y0
            + (3.0 * t2 - 4.0 * t + 1.0) * m0
            + (-6.0 * t2 + 6.0 * t) * y1
            + (3.0 * t2 - 2.0 * t) * m1;
        let dd = (12.0 * t - 6.0) * y0
            + (6.0 * t - 4.0) * m0
            + (-12.0 * t + 6.0) * y1
            + (6.0 * t - 2.0) * m1;
        (v, d / h, dd / (h * h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolants_match_their_derivatives_and_nodes() {
        let values: Vec<f64> = (0..9)
            .flat_map(|j| {
                let x = j as f64 / 8.0;
                [x.sin(), x * x * x]
            })
            .collect();
        let s = NaturalCubic::new(values.clone(), 2);
        let (mut p, mut dp, mut ddp) = ([0.0; 2], [0.0; 2], [0.0; 2]);
        for j in 0..9 {
            s.eval(j as f64 / 8.0, &mut p, &mut dp, &mut ddp);
            assert!(
                (p[0] - values[2 * j]).abs() < 1e-12 && (p[1] - values[2 * j + 1]).abs() < 1e-12
            );
        }
        let h = 1e-6;
        let (mut p1, mut p2, mut t1, mut t2) = ([0.0; 2], [0.0; 2], [0.0; 2], [0.0; 2]);
        for &x in &[0.13, 0.5, 0.77] {
            s.eval(x, &mut p, &mut dp, &mut ddp);
            s.eval(x + h, &mut p1, &mut t1, &mut t2);
            s.eval(x - h, &mut p2, &mut t1, &mut t2);
            assert!(((p1[0] - p2[0]) / (2.0 * h) - dp[0]).abs() < 1e-6);
            let mut d1 = [0.0; 2];
            let mut d2 = [0.0; 2];
            s.eval(x + h, &mut p1, &mut d1, &mut t2);
            s.eval(x - h, &mut p2, &mut d2, &mut t2);
            assert!(((d1[1] - d2[1]) / (2.0 * h) - ddp[1]).abs() < 1e-5);
        }
        let m = Pchip::new(vec![0.0, 0.1, 0.5, 0.5, 0.9, 1.0]);
        let mut last = -1.0;
        for i in 0..=200 {
            let x = i as f64 / 200.0;
            let (v, d, _) = m.eval(x);
            assert!(v >= last - 1e-15 && d >= -1e-12);
            last = v;
            let (vp, dpv, _) = m.eval((x + h).min(1.0));
            let (vm, dmv, _) = m.eval((x - h).max(0.0));
            if x > 2e-6 && x < 1.0 - 2e-6 && ((x * 5.0).fract()).abs() > 1e-3 {
                let (_, _, dd) = m.eval(x);
                assert!(((vp - vm) / (2.0 * h) - d).abs() < 1e-5);
                assert!(((dpv - dmv) / (2.0 * h) - dd).abs() < 1e-3 * (1.0 + dd.abs()));
            }
        }
        let (m0, d0, _) = MinimumJerk::eval(0.0);
        let (m1, d1, _) = MinimumJerk::eval(1.0);
        assert!(m0 == 0.0 && (m1 - 1.0).abs() < 1e-15 && d0 == 0.0 && d1.abs() < 1e-12);
    }
}
