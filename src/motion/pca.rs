//! Principal components of joint-space samples (the low-dimensional manifold of §III-B).

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::MotionError;

/// How many principal components to keep.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Components {
    /// The fewest components whose cumulative explained variance reaches this fraction
    /// (the paper: 3 components explain more than 0.88 for both arm and hand).
    VarianceThreshold(f64),
    /// Exactly this many.
    Count(usize),
}

impl Default for Components {
    fn default() -> Self {
        Components::VarianceThreshold(0.88)
    }
}

/// `q ≈ μ + W y`, `W` with orthonormal columns; `y = Wᵀ(q − μ)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pca {
    /// Joint-space mean μ (n).
    pub mean: Vec<f64>,
    /// `W`, n × d, row-major (`components[i * d + j]` = joint i of component j).
    pub components: Vec<f64>,
    /// Fraction of the total variance explained by each kept component.
    pub explained_variance: Vec<f64>,
    /// Fraction explained by every component (n values, descending), for reports.
    pub all_explained_variance: Vec<f64>,
}

impl Pca {
    /// PCA of `samples` (rows of `n` joint values, row-major) via the SVD of the centred data.
    pub fn fit(
        samples: &[f64],
        n: usize,
        components: Components,
        max_components: usize,
    ) -> Result<Self, MotionError> {
        let rows = samples.len() / n.max(1);
        let wanted = match components {
            Components::Count(c) => {
                if c == 0 || c > n {
                    return Err(MotionError::InvalidOption {
                        field: "components",
                        value: c as f64,
                        reason: "must be between 1 and the number of joints in the group".into(),
                    });
                }
                c
            }
            Components::VarianceThreshold(t) => {
                if !(t > 0.0 && t <= 1.0) {
                    return Err(MotionError::InvalidOption {
                        field: "variance_threshold",
                        value: t,
                        reason: "must be in (0, 1]".into(),
                    });
                }
                1
            }
        };
        if rows < wanted + 1 || rows < 2 {
            return Err(MotionError::TooFewSamples {
                components: wanted,
                got: rows,
                needed: (wanted + 1).max(2),
            });
        }
        let mut mean = vec![0.0; n];
        for r in samples.chunks_exact(n) {
            for (m, x) in mean.iter_mut().zip(r) {
                *m += x;
            }
        }
        mean.iter_mut().for_each(|m| *m /= rows as f64);
        let centred = DMatrix::from_fn(rows, n, |r, c| samples[r * n + c] - mean[c]);
        let svd = nalgebra::SVD::new(centred, false, true);
        let v_t = svd.v_t.expect("SVD computed with V");
        let var: Vec<f64> = svd.singular_values.iter().map(|s| s * s).collect();
        let total: f64 = var.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        let mut all: Vec<f64> = var.iter().map(|v| v / total).collect();
        all.resize(n, 0.0);
        let d = match components {
            Components::Count(c) => c.min(v_t.nrows()),
            Components::VarianceThreshold(t) => {
                let mut acc = 0.0;
                let mut d = 0;
                for f in &all {
                    acc += f;
                    d += 1;
                    if acc >= t - 1e-12 {
                        break;
                    }
                }
                d
            }
        };
        if d > max_components {
            return Err(MotionError::TooManyComponents {
                needed: d,
                max: max_components,
            });
        }
        let mut w = vec![0.0; n * d];
        for j in 0..d {
            // Fix each component's sign (largest entry positive) so models are reproducible.
            let row = v_t.row(j);
            let mut big = 0.0f64;
            for x in row.iter() {
                if x.abs() > big.abs() {
                    big = *x;
                }
            }
            let sign = if big < 0.0 { -1.0 } else { 1.0 };
            for i in 0..n {
                w[i * d + j] = sign * row[i];
            }
        }
        Ok(Pca {
            mean,
            components: w,
            explained_variance: all[..d].to_vec(),
            all_explained_variance: all,
        })
    }

    pub fn n(&self) -> usize {
        self.mean.len()
    }
    pub fn d(&self) -> usize {
        self.explained_variance.len()
    }

    /// `y = Wᵀ(q − μ)`.
    #[inline]
    pub fn project(&self, q: &[f64], y: &mut [f64]) {
        let d = self.d();
        y[..d].iter_mut().for_each(|v| *v = 0.0);
        for (i, (qi, mi)) in q.iter().zip(&self.mean).enumerate() {
            let e = qi - mi;
            for j in 0..d {
                y[j] += self.components[i * d + j] * e;
            }
        }
    }

    /// `q = μ + W y`.
    #[inline]
    pub fn back_project(&self, y: &[f64], q: &mut [f64]) {
        let d = self.d();
        for (i, qi) in q.iter_mut().enumerate().take(self.n()) {
            let mut v = self.mean[i];
            for j in 0..d {
                v += self.components[i * d + j] * y[j];
            }
            *qi = v;
        }
    }

    /// Off-manifold residual `r = q − (μ + W Wᵀ(q − μ))`, and `y` as a by-product.
    pub fn residual(&self, q: &[f64], y: &mut [f64], r: &mut [f64]) {
        self.project(q, y);
        self.back_project(y, r);
        for (ri, qi) in r.iter_mut().zip(q) {
            *ri = qi - *ri;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_a_known_subspace_and_variances() {
        // samples = μ + A z with A's columns orthonormal, z with std 3, 2, 1 (+ tiny noise)
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 6;
        let a = nalgebra::DMatrix::<f64>::from_fn(n, 3, |_, _| rng.random_range(-1.0..1.0));
        let q = a.clone().qr().q();
        let mu: Vec<f64> = (0..n).map(|i| 0.1 * i as f64).collect();
        let scales = [3.0, 2.0, 1.0];
        let mut samples = Vec::new();
        for _ in 0..4000 {
            let z: Vec<f64> = scales
                .iter()
                .map(|s| s * rng.random_range(-1.0..1.0f64) * 3f64.sqrt())
                .collect();
            for i in 0..n {
                let mut v = mu[i] + 1e-4 * rng.random_range(-1.0..1.0);
                for j in 0..3 {
                    v += q[(i, j)] * z[j];
                }
                samples.push(v);
            }
        }
        let pca = Pca::fit(&samples, n, Components::VarianceThreshold(0.99), 5).unwrap();
        assert_eq!(pca.d(), 3);
        let total = 14.0;
        for (j, s) in scales.iter().enumerate() {
            assert!((pca.explained_variance[j] - s * s / total).abs() < 0.03);
        }
        // orthonormal columns spanning the same subspace as A
        let w = nalgebra::DMatrix::from_row_slice(n, 3, &pca.components);
        assert!((w.transpose() * &w - nalgebra::DMatrix::identity(3, 3)).norm() < 1e-10);
        let proj = &w * w.transpose();
        assert!((&proj * &q - &q).norm() < 1e-3);
        // project / back-project round trip for a point on the subspace
        let mut y = [0.0; 3];
        let mut back = vec![0.0; n];
        let mut r = vec![0.0; n];
        let point: Vec<f64> = (0..n)
            .map(|i| mu[i] + 0.5 * q[(i, 0)] - 0.2 * q[(i, 2)])
            .collect();
        pca.residual(&point, &mut y, &mut r);
        pca.back_project(&y, &mut back);
        for i in 0..n {
            assert!((back[i] + r[i] - point[i]).abs() < 1e-12);
            assert!(r[i].abs() < 1e-3);
        }
        // a fixed count is honoured; too many is refused
        assert_eq!(
            Pca::fit(&samples, n, Components::Count(2), 5).unwrap().d(),
            2
        );
        assert!(Pca::fit(&samples, n, Components::Count(6), 5).is_err());
    }
}
