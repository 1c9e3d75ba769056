//! The closed-loop law `u(q) = W(−K_p ∇_y φ) + K_⊥ (I − W Wᵀ)(q_d − q)` (eq. 8 in PCA
//! coordinates, DESIGN §5), in a compact serialisable form a bridge worker runs locally.

use serde::{Deserialize, Serialize};

use super::{MAX_DIM, NavigationFunction, Pca};

/// One manifold's share of the law.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ControlGroup {
    /// Indices of this group's joints in the full joint vector.
    pub joints: Vec<usize>,
    /// μ (n_g) and W (n_g × d, row-major).
    pub mean: Vec<f64>,
    pub components: Vec<f64>,
    pub nf: NavigationFunction,
    /// `K_p` of this group.
    pub kp: f64,
}

/// Everything a worker needs to evaluate `u(q)` for a goal `q_d` (joint order of the model).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct ControlParams {
    /// The model's joint order (of `q`, `q_d` and `u`).
    pub joint_names: Vec<String>,
    /// `K_⊥`: gain of the off-manifold correction.
    pub k_perp: f64,
    pub groups: Vec<ControlGroup>,
}

impl ControlGroup {
    /// `K_p = rate·L²/2` so that near the goal, where `∇_y φ ≈ 2β^{-1/k}(y − y_d)/L²`, the
    /// on-manifold error decays at about `rate` (1/s).
    pub(crate) fn from_parts(
        joints: &[usize],
        pca: &Pca,
        nf: &NavigationFunction,
        rate: f64,
    ) -> Self {
        ControlGroup {
            kp: rate * nf.length_scale * nf.length_scale / 2.0,
            joints: joints.to_vec(),
            mean: pca.mean.clone(),
            components: pca.components.clone(),
            nf: nf.clone(),
        }
    }
}

impl ControlParams {
    pub fn n_joints(&self) -> usize {
        self.groups.iter().map(|g| g.joints.len()).sum()
    }

    /// Joint velocity command `u` (into `u[..n]`) for the measured `q` and the goal `q_d`.
    /// Allocation-free. Outside the workspace ball (a large perturbation) `∇_y φ` is not
    /// defined; there the on-manifold part falls back to the plain attractor `∇γ`, which
    /// brings the state back inside where the NF takes over.
    pub fn control(&self, q: &[f64], q_d: &[f64], u: &mut [f64]) {
        for g in &self.groups {
            let d = g.nf.dim();
            let mut y = [0.0; MAX_DIM];
            let mut yd = [0.0; MAX_DIM];
            let mut z = [0.0; MAX_DIM];
            for (i, &ji) in g.joints.iter().enumerate() {
                let e = q[ji] - g.mean[i];
                let ed = q_d[ji] - g.mean[i];
                let err = q_d[ji] - q[ji];
                for j in 0..d {
                    let w = g.components[i * d + j];
                    y[j] += w * e;
                    yd[j] += w * ed;
                    z[j] += w * err;
                }
            }
            let mut r2 = 0.0;
            for j in 0..d {
                r2 += (y[j] - g.nf.center[j]).powi(2);
            }
            let mut grad = [0.0; MAX_DIM];
            if r2 < g.nf.radius * g.nf.radius {
                g.nf.value_gradient(&y, &yd, &mut grad);
            } else {
                let l2 = g.nf.length_scale * g.nf.length_scale;
                for j in 0..d {
                    grad[j] = 2.0 * (y[j] - yd[j]) / l2;
                }
            }
            // v = −K_p ∇φ − K_⊥ Wᵀ(q_d − q) so that u = W v + K_⊥ (q_d − q)
            let mut v = [0.0; MAX_DIM];
            for j in 0..d {
                v[j] = -g.kp * grad[j] - self.k_perp * z[j];
            }
            for (i, &ji) in g.joints.iter().enumerate() {
                let mut s = self.k_perp * (q_d[ji] - q[ji]);
                for j in 0..d {
                    s += g.components[i * d + j] * v[j];
                }
                u[ji] = s;
            }
        }
    }
}
