//! The closed-loop law a bridge worker runs locally (eq. 8 in PCA coordinates, DESIGN §5), in a
//! compact serialisable form.
//!
//! Two laws:
//! - [`ControlLaw::PhiDecay`] (models trained since the navigation-function certificate): per
//!   joint group, with `λ = 2·rate`,
//!   `ẏ = −λ φ ∇_y φ/‖∇_y φ‖²` (the flow's direction, at the speed that makes `φ̇ = −λφ`) and
//!   `u = W ẏ + J_R(y) ẏ − λ (z − δ_g)`, `z = r − R(y)` the state's offset from the learned
//!   curved manifold (`r = (I − W Wᵀ)(q − μ)`, `R` the learned curvature, zero without one) and
//!   `δ_g` the goal's. `φ` and the offset then decay at one rate, so the offset's remaining share
//!   is `φ(y)/φ(y_start)` and every group's `φ` ratio is the same: exactly the open-loop path of
//!   [`super::MotionModel::trajectory`] (the same flow, the same back-projection, the same
//!   coupling of the groups), from wherever the state is, also after a push. When the command
//!   exceeds a velocity limit it is scaled down as a whole, which changes the speed and keeps
//!   the path.
//! - [`ControlLaw::Gradient`] (stored parameters from before): `u = W(−K_p ∇_y φ) +
//!   K_⊥ (I − W Wᵀ)(q_d − q)`; on-manifold it follows the same flow lines, off-manifold it decays
//!   at its own rate, so its path differs from the open-loop one.

use serde::{Deserialize, Serialize};

use super::curvature::Curvature;
use super::{MAX_DIM, NavigationFunction, Pca};

/// Which law [`ControlParams::control`] evaluates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ControlLaw {
    /// `u = W(−K_p ∇φ) + K_⊥(I − W Wᵀ)(q_d − q)` (parameters stored before `phi_decay`).
    #[default]
    Gradient,
    /// `φ̇ = −λφ` along the flow, the off-manifold offset decaying at the same `λ`.
    PhiDecay,
}

/// One manifold's share of the law.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControlGroup {
    /// Indices of this group's joints in the full joint vector.
    pub joints: Vec<usize>,
    /// μ (n_g) and W (n_g × d, row-major).
    pub mean: Vec<f64>,
    pub components: Vec<f64>,
    pub nf: NavigationFunction,
    /// `K_p` of this group (the `gradient` law).
    pub kp: f64,
    /// Learned curvature of the manifold (the `phi_decay` law; absent: none).
    #[serde(default)]
    pub curvature: Option<Curvature>,
}

/// Everything a worker needs to evaluate `u(q)` for a goal `q_d` (joint order of the model).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControlParams {
    pub joint_names: Vec<String>,
    /// `K_⊥` of the `gradient` law.
    pub k_perp: f64,
    pub groups: Vec<ControlGroup>,
    #[serde(default)]
    pub law: ControlLaw,
    /// `λ` of the `phi_decay` law (1/s): `φ` and the off-manifold offset decay as `e^{−λt}`,
    /// the on-manifold distance near the goal as `e^{−λt/2}`.
    #[serde(default)]
    pub lambda: f64,
    /// Joint velocity limits (model order) the `phi_decay` command is scaled into as a whole;
    /// empty: no scaling.
    #[serde(default)]
    pub velocity_limits: Vec<f64>,
}

impl ControlGroup {
    /// `K_p = rate·L²/2` so that near the goal, where `∇_y φ ≈ 2β^{-1/k}(y − y_d)/L²`, the
    /// on-manifold error of the `gradient` law decays at about `rate` (1/s).
    pub(crate) fn from_parts(
        joints: &[usize],
        pca: &Pca,
        nf: &NavigationFunction,
        curvature: Option<&Curvature>,
        rate: f64,
    ) -> Self {
        ControlGroup {
            kp: rate * nf.length_scale * nf.length_scale / 2.0,
            joints: joints.to_vec(),
            mean: pca.mean.clone(),
            components: pca.components.clone(),
            nf: nf.clone(),
            curvature: curvature.cloned(),
        }
    }
}

/// Largest group size the allocation-free law handles.
pub const MAX_GROUP_JOINTS: usize = 64;

impl ControlParams {
    pub fn n_joints(&self) -> usize {
        self.groups.iter().map(|g| g.joints.len()).sum()
    }

    /// Joint velocity command `u` (into `u[..n]`) for the measured `q` and the goal `q_d`.
    /// Allocation-free. Outside the workspace ball (a large perturbation) `∇_y φ` is not
    /// defined; there the on-manifold part falls back to the plain attractor, which brings the
    /// state back inside where the NF takes over.
    pub fn control(&self, q: &[f64], q_d: &[f64], u: &mut [f64]) {
        match self.law {
            ControlLaw::Gradient => self.gradient_law(q, q_d, u),
            ControlLaw::PhiDecay => self.phi_decay_law(q, q_d, u),
        }
    }

    fn phi_decay_law(&self, q: &[f64], q_d: &[f64], u: &mut [f64]) {
        let lambda = self.lambda;
        for g in &self.groups {
            let d = g.nf.dim();
            let ng = g.joints.len().min(MAX_GROUP_JOINTS);
            let mut y = [0.0; MAX_DIM];
            let mut yd = [0.0; MAX_DIM];
            for (i, &ji) in g.joints.iter().enumerate().take(ng) {
                let e = q[ji] - g.mean[i];
                let ed = q_d[ji] - g.mean[i];
                for j in 0..d {
                    let w = g.components[i * d + j];
                    y[j] += w * e;
                    yd[j] += w * ed;
                }
            }
            let mut r2 = 0.0;
            for j in 0..d {
                r2 += (y[j] - g.nf.center[j]).powi(2);
            }
            let mut v = [0.0; MAX_DIM];
            if r2 < g.nf.radius * g.nf.radius {
                g.nf.phi_decay_velocity(&y[..d], &yd[..d], &mut v);
                for x in v.iter_mut().take(d) {
                    *x *= lambda;
                }
            } else {
                for j in 0..d {
                    v[j] = -0.5 * lambda * (y[j] - yd[j]);
                }
            }
            // off-manifold offsets of the state and the goal from the (curved) manifold
            let mut z = [0.0; MAX_GROUP_JOINTS];
            let mut jr = [0.0; MAX_GROUP_JOINTS];
            let (mut ry, mut ryd) = ([0.0; MAX_GROUP_JOINTS], [0.0; MAX_GROUP_JOINTS]);
            if let Some(c) = &g.curvature {
                c.eval(&y[..d], &mut ry[..ng]);
                c.eval(&yd[..d], &mut ryd[..ng]);
                c.directional(&y[..d], &v[..d], &mut jr[..ng]);
            }
            for (i, &ji) in g.joints.iter().enumerate().take(ng) {
                let (mut on, mut on_d) = (g.mean[i], g.mean[i]);
                for j in 0..d {
                    on += g.components[i * d + j] * y[j];
                    on_d += g.components[i * d + j] * yd[j];
                }
                // (z − δ_g): (q − on − R(y)) − (q_d − on_d − R(y_d))
                z[i] = (q[ji] - on - ry[i]) - (q_d[ji] - on_d - ryd[i]);
            }
            for (i, &ji) in g.joints.iter().enumerate().take(ng) {
                let mut s = jr[i] - lambda * z[i];
                for j in 0..d {
                    s += g.components[i * d + j] * v[j];
                }
                u[ji] = s;
            }
        }
        // one factor for all joints keeps the direction, hence the path
        let mut over: f64 = 1.0;
        for (j, &lim) in self.velocity_limits.iter().enumerate() {
            if lim > 0.0 {
                over = over.max(u[j].abs() / lim);
            }
        }
        if over > 1.0 {
            for x in u.iter_mut().take(self.velocity_limits.len()) {
                *x /= over;
            }
        }
    }

    fn gradient_law(&self, q: &[f64], q_d: &[f64], u: &mut [f64]) {
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

#[cfg(test)]
mod tests {
    use crate::motion::synthetic::{SyntheticStudy, curved_study};
    use crate::motion::{Components, TrainOptions, train};

    /// The `phi_decay` law's two defining rates, checked by finite differences along the
    /// commanded velocity (independently of how the law computes them): `φ̇ = −λφ` per group,
    /// and the off-manifold offset `z = (I − WWᵀ)(q − μ) − R(y)` approaches the goal's at rate `λ`.
    #[test]
    fn phi_and_the_offset_decay_at_the_commanded_rate() {
        let data = curved_study(&SyntheticStudy {
            seed: 2,
            trials_per_position: 4,
            frames: 50,
            ..SyntheticStudy::default()
        });
        let opts = TrainOptions {
            groups: data.groups.clone(),
            components: Components::VarianceThreshold(0.97),
            ..TrainOptions::default()
        };
        let (model, _) = train(&data.demos, &data.limits, &opts).unwrap();
        let n = model.n_joints;
        let mut params = model.control_params(vec![String::new(); n], 1.5, 2.0);
        params.velocity_limits.clear(); // no scaling: the raw law
        let lambda = params.lambda;
        let q = data.demos[1].frame(10, n).to_vec();
        let goal = data.demos[7].frame(49, n).to_vec();
        let mut u = vec![0.0; n];
        params.control(&q, &goal, &mut u);
        let eps = 1e-6;
        let q2: Vec<f64> = q.iter().zip(&u).map(|(a, b)| a + eps * b).collect();
        for m in &model.manifolds {
            let d = m.pca.d();
            let ng = m.joints.len();
            let gather = |v: &[f64]| m.joints.iter().map(|&j| v[j]).collect::<Vec<_>>();
            let offset = |v: &[f64]| {
                let mut y = vec![0.0; d];
                let mut r = vec![0.0; ng];
                m.pca.residual(&gather(v), &mut y, &mut r);
                let mut c = vec![0.0; ng];
                if let Some(curv) = &m.curvature {
                    curv.eval(&y, &mut c);
                }
                (y, r.iter().zip(&c).map(|(a, b)| a - b).collect::<Vec<_>>())
            };
            let (y1, z1) = offset(&q);
            let (y2, z2) = offset(&q2);
            let (yd, zd) = offset(&goal);
            let (p1, p2) = (m.nf.log_phi(&y1, &yd), m.nf.log_phi(&y2, &yd));
            let rate = (p2 - p1) / eps;
            assert!(
                (rate + lambda).abs() < 1e-4 * lambda,
                "dlogφ/dt {rate} vs −{lambda}"
            );
            for i in 0..ng {
                let dz = (z2[i] - z1[i]) / eps;
                let want = -lambda * (z1[i] - zd[i]);
                assert!(
                    (dz - want).abs() < 1e-5 + 1e-4 * want.abs(),
                    "{dz} vs {want}"
                );
            }
        }
    }
}
