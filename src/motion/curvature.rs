//! The learned curvature of the demonstrated manifold: the off-manifold residual
//! `r = (I − W Wᵀ)(q − μ)` as a quadratic function of the PCA coordinates, `R(y)`.
//!
//! Why: on mapped demonstrations 35-62 % of the arm's deviation from the straight joint line lies
//! off the linear PCA manifold; a linear back-projection `μ + W y` interpolates it linearly
//! between the ends, so neither the NF path nor a straight PCA line can carry it. The residual is
//! largely a smooth function of where the arm is on the manifold (the manifold of humanlike
//! postures is curved), so `q(y) = μ + W y + R(y)` carries it, goal-independently like the field.
//! `R` is orthogonal to `W`, so `y` is unchanged by it.

use serde::{Deserialize, Serialize};

use super::MAX_DIM;

/// Quadratic features of `y` (`1`, then `y_i y_j` for `i ≤ j`): at most 1 + 15.
pub const MAX_FEATURES: usize = 1 + MAX_DIM * (MAX_DIM + 1) / 2;

/// `R(y) = C·[1, y_i y_j (i ≤ j)]`, `C` (`n × features`, row-major) with columns orthogonal to
/// the PCA basis. (The linear terms are left out: the PCA residual is uncorrelated with `y`.)
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Curvature {
    pub dim: usize,
    pub n: usize,
    pub coefficients: Vec<f64>,
    /// Ridge of the fit, relative to the mean diagonal of the normal matrix.
    pub ridge: f64,
}

/// Feature count for `d` coordinates.
pub fn feature_count(d: usize) -> usize {
    1 + d * (d + 1) / 2
}

#[inline]
fn features(y: &[f64], d: usize, out: &mut [f64; MAX_FEATURES]) {
    out[0] = 1.0;
    let mut m = 1;
    for i in 0..d {
        for j in i..d {
            out[m] = y[i] * y[j];
            m += 1;
        }
    }
}

impl Curvature {
    /// Ridge fit to `(y, r)` samples (`ys`: rows of `d`, `rs`: rows of `n`), then every column
    /// projected off the PCA basis `w` (`n × d`, row-major) so that `R(y)` never moves `y`.
    pub fn fit(ys: &[f64], rs: &[f64], d: usize, n: usize, w: &[f64], ridge: f64) -> Self {
        let nf = feature_count(d);
        let rows = ys.len() / d.max(1);
        let mut xtx = nalgebra::DMatrix::<f64>::zeros(nf, nf);
        let mut xtr = nalgebra::DMatrix::<f64>::zeros(nf, n);
        let mut f = [0.0; MAX_FEATURES];
        for s in 0..rows {
            features(&ys[s * d..(s + 1) * d], d, &mut f);
            let r = &rs[s * n..(s + 1) * n];
            for a in 0..nf {
                for b in 0..nf {
                    xtx[(a, b)] += f[a] * f[b];
                }
                for i in 0..n {
                    xtr[(a, i)] += f[a] * r[i];
                }
            }
        }
        let mean_diag = (0..nf).map(|a| xtx[(a, a)]).sum::<f64>() / nf as f64;
        for a in 1..nf {
            xtx[(a, a)] += ridge * mean_diag.max(f64::MIN_POSITIVE);
        }
        let mut coefficients = vec![0.0; n * nf];
        if let Some(chol) = xtx.cholesky() {
            let sol = chol.solve(&xtr); // nf × n
            for i in 0..n {
                for a in 0..nf {
                    coefficients[i * nf + a] = sol[(a, i)];
                }
            }
            // (I − W Wᵀ) per feature column
            for a in 0..nf {
                let mut p = [0.0; MAX_DIM];
                for i in 0..n {
                    for j in 0..d {
                        p[j] += w[i * d + j] * coefficients[i * nf + a];
                    }
                }
                for i in 0..n {
                    for j in 0..d {
                        coefficients[i * nf + a] -= w[i * d + j] * p[j];
                    }
                }
            }
        }
        Curvature {
            dim: d,
            n,
            coefficients,
            ridge,
        }
    }

    /// `R(y)` into `out[..n]`.
    #[inline]
    pub fn eval(&self, y: &[f64], out: &mut [f64]) {
        let nf = feature_count(self.dim);
        let mut f = [0.0; MAX_FEATURES];
        features(y, self.dim, &mut f);
        for i in 0..self.n {
            let c = &self.coefficients[i * nf..(i + 1) * nf];
            out[i] = c.iter().zip(&f[..nf]).map(|(a, b)| a * b).sum();
        }
    }

    /// `J_R(y)·v` into `out[..n]` (the directional derivative, for the closed-loop law).
    #[inline]
    pub fn directional(&self, y: &[f64], v: &[f64], out: &mut [f64]) {
        let d = self.dim;
        let nf = feature_count(d);
        // d/dt (y_i y_j) = v_i y_j + y_i v_j
        let mut f = [0.0; MAX_FEATURES];
        let mut m = 1;
        for i in 0..d {
            for j in i..d {
                f[m] = v[i] * y[j] + y[i] * v[j];
                m += 1;
            }
        }
        for i in 0..self.n {
            let c = &self.coefficients[i * nf..(i + 1) * nf];
            out[i] = c[1..].iter().zip(&f[1..nf]).map(|(a, b)| a * b).sum();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_quadratic_residual_and_its_derivative() {
        // n = 3, d = 1, W = e_0: the residual lives in joints 1 and 2
        let w = [1.0, 0.0, 0.0];
        let truth = |y: f64| [0.0, 0.3 * y * y - 0.1, -0.2 * y * y + 0.05];
        let mut ys = Vec::new();
        let mut rs = Vec::new();
        for s in 0..41 {
            let y = -1.0 + s as f64 / 20.0;
            ys.push(y);
            rs.extend_from_slice(&truth(y));
        }
        let c = Curvature::fit(&ys, &rs, 1, 3, &w, 1e-12);
        let mut out = [0.0; 3];
        for &y in &[-0.7, 0.1, 0.9] {
            c.eval(&[y], &mut out);
            let t = truth(y);
            for i in 0..3 {
                assert!((out[i] - t[i]).abs() < 1e-9, "{out:?} vs {t:?}");
            }
            // directional derivative against central differences
            let h = 1e-6;
            let (mut p, mut m) = ([0.0; 3], [0.0; 3]);
            c.eval(&[y + h], &mut p);
            c.eval(&[y - h], &mut m);
            c.directional(&[y], &[1.0], &mut out);
            for i in 0..3 {
                assert!((out[i] - (p[i] - m[i]) / (2.0 * h)).abs() < 1e-6);
            }
        }
    }
}
