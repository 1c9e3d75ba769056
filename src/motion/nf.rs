//! The navigation function of eq. 9 in PCA coordinates, its flow and its convergence certificate
//! (DESIGN §5).

use serde::{Deserialize, Serialize};

use super::{CriticalPointCertificate, MAX_DIM, TensorBSpline};

/// Which theorem certifies a model's convergence.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CertificateKind {
    /// `γ` strictly decreases along the flow (`sup (y − y_d)·∇log β < 2k`): the field is
    /// shrunk until this closed-form bound holds. Models stored before the choice existed.
    #[default]
    GammaDecreasing,
    /// `φ` has no critical point but the goal ([`super::no_critical_point`]): navigation-function
    /// theory; `γ` may rise on the way, which lets the field keep more of its fit.
    NoCriticalPoint,
}

/// `φ = γ/(γ^k + β)^{1/k}` (eq. 9) with `γ = ‖y − y_d‖²` and `β = β_0·exp(s(y))`, where
/// `β_0 = R² − ‖y − c‖²` is the workspace ball (the outer boundary, positive inside) and `s` the
/// learned fictitious-obstacle field.
///
/// `φ` is evaluated in PCA coordinates divided by `length_scale` `L` (the workspace diameter,
/// so `γ ≤ 1` everywhere): the flow direction, hence every path and the certificate, is
/// invariant under that scaling, but `∇φ` is not — in raw units `γ^k` overwhelms `β` for large
/// `k` and the closed-loop law would stall away from the goal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct NavigationFunction {
    /// `k` of eq. 9.
    pub k: f64,
    /// `L`: PCA coordinates are divided by it before `φ` is evaluated.
    pub length_scale: f64,
    /// Workspace ball centre `c` and radius `R`.
    pub center: Vec<f64>,
    pub radius: f64,
    pub spline: TensorBSpline,
}

/// Convergence certificate. Closed-form part: along the flow,
/// `γ̇ = −2γ(2 − (y − y_d)·∇log β / k)`, so `γ` strictly decreases whenever
/// `bound ≥ sup (y − y_d)·∇log β` over the workspace ball and the goal region is below `2k`.
/// Navigation-function part ([`CriticalPointCertificate`]): no critical point but the goal,
/// which is all convergence needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Certificate {
    /// The theorem the field's shrink was chosen for; `holds` refers to it.
    #[serde(default)]
    pub kind: CertificateKind,
    pub k: f64,
    /// The spline's share: `sup (y − y_d)·∇s`, bounded cell by cell from the coefficient
    /// differences ([`TensorBSpline::radial_bound`]).
    pub spline_bound: f64,
    /// `ρ_g²/(2(R² − ρ_g²))`, `ρ_g = ‖g − c‖ + r_g`: the workspace ball's share
    /// (`sup (y−y_d)·∇log β_0`).
    pub workspace_bound: f64,
    /// `spline_bound + workspace_bound`.
    pub bound: f64,
    /// The certificate of `kind` holds.
    pub holds: bool,
    /// `bound < 2k`: `γ` strictly decreases (what `holds` meant before `kind` existed; the
    /// serde default reads models stored then, whose `holds` was exactly this).
    #[serde(default = "yes")]
    pub gamma_decreasing: bool,
    /// `2(2 − bound/k)`: with `gamma_decreasing`, `γ̇ ≤ −rate·γ` (no guaranteed decay if ≤ 0).
    pub decay_rate: f64,
    /// The branch and bound's result; absent in models stored before it existed.
    #[serde(default)]
    pub critical_points: Option<CriticalPointCertificate>,
    /// Factor the fitted spline was multiplied by to satisfy the certificate (1 = unshrunk).
    pub shrink: f64,
    /// Goal region: ball with this centre and radius (the certificate holds for goals in it).
    pub goal_center: Vec<f64>,
    pub goal_radius: f64,
    /// Workspace ball (starts must lie strictly inside).
    pub workspace_center: Vec<f64>,
    pub workspace_radius: f64,
}

fn yes() -> bool {
    true
}

/// Coefficient budget for refining the spline before bounding it.
const REFINE_BUDGET: usize = 60_000;

/// [`TensorBSpline::radial_bound`] after refining the grid (up to two halvings, within a
/// coefficient budget); the bound of the finer representation is the tighter one.
pub(crate) fn refined_radial_bound(
    spline: &TensorBSpline,
    center: &[f64],
    radius: f64,
    goal_center: &[f64],
    goal_radius: f64,
) -> f64 {
    let mut best = spline.radial_bound(center, radius, goal_center, goal_radius);
    let mut current = spline.clone();
    for _ in 0..2 {
        let next = TensorBSpline::coefficient_count(current.dim(), 2 * current.intervals());
        if next > REFINE_BUDGET {
            break;
        }
        current = current.refined();
        best = best.min(current.radial_bound(center, radius, goal_center, goal_radius));
    }
    best
}

impl NavigationFunction {
    pub fn dim(&self) -> usize {
        self.center.len()
    }

    /// `log β` and `∇log β` (into `g[..d]`); `-inf` outside the workspace ball.
    #[inline]
    pub fn log_beta(&self, y: &[f64], g: &mut [f64]) -> f64 {
        let d = self.dim();
        let mut r2 = 0.0;
        for i in 0..d {
            let e = y[i] - self.center[i];
            r2 += e * e;
        }
        let beta0 = self.radius * self.radius - r2;
        let s = self.spline.value_gradient(y, g);
        if beta0 <= 0.0 {
            return f64::NEG_INFINITY;
        }
        for i in 0..d {
            g[i] += -2.0 * (y[i] - self.center[i]) / beta0;
        }
        beta0.ln() + s
    }

    /// `φ(y)` and `∇_y φ` (into `grad[..d]`), with `γ` and `β` in the scaled coordinates
    /// (`γ = ‖y − y_d‖²/L²`, `β = β_0 e^s/L²`), evaluated in log space so large `k` cannot
    /// overflow `γ^k`: `∇φ = β(γ^k+β)^{-1/k-1}(∇γ − (γ/k)∇log β)`.
    pub fn value_gradient(&self, y: &[f64], y_d: &[f64], grad: &mut [f64]) -> f64 {
        let d = self.dim();
        let mut glb = [0.0; MAX_DIM];
        let l2 = self.length_scale * self.length_scale;
        let lb = self.log_beta(y, &mut glb) - l2.ln();
        let mut gamma = 0.0;
        for i in 0..d {
            let e = y[i] - y_d[i];
            gamma += e * e;
        }
        let gamma = gamma / l2;
        let k = self.k;
        let lg = gamma.ln();
        let a = k * lg;
        let (hi, lo) = if a > lb { (a, lb) } else { (lb, a) };
        let lse = hi + (lo - hi).exp().ln_1p();
        let factor = (lb - (1.0 + 1.0 / k) * lse).exp();
        for i in 0..d {
            grad[i] = factor * (2.0 * (y[i] - y_d[i]) / l2 - gamma / k * glb[i]);
        }
        (lg - lse / k).exp()
    }

    /// The flow `f = −(∇γ − (γ/k)∇log β)` (direction of `−∇φ`) into `f[..d]`; returns
    /// `p = (y − y_d)·∇log β / k`, so that `∇γ·f = −2γ(2 − p)`.
    #[inline]
    pub fn flow(&self, y: &[f64], y_d: &[f64], f: &mut [f64]) -> f64 {
        let d = self.dim();
        let mut glb = [0.0; MAX_DIM];
        self.log_beta(y, &mut glb);
        let mut gamma = 0.0;
        let mut dot = 0.0;
        for i in 0..d {
            let e = y[i] - y_d[i];
            gamma += e * e;
            dot += e * glb[i];
        }
        for i in 0..d {
            f[i] = -2.0 * (y[i] - y_d[i]) + gamma / self.k * glb[i];
        }
        dot / self.k
    }

    /// Closed-form bound on `sup (y − y_d)·∇log β` for `y` in the workspace ball and `y_d` in the
    /// goal ball `(goal_center, goal_radius)` (inside the workspace), and the resulting
    /// certificate.
    ///
    /// Spline part: [`TensorBSpline::radial_bound`] (per knot cell, from the coefficient
    /// differences, on a refined grid; never worse than `(R + r_g)·sqrt(Σ D_i²)`). Workspace part:
    /// `(y − y_d)·∇log β_0 = −2(y − y_d)·(y − c)/(R² − ρ²)` with `ρ = ‖y − c‖`; since
    /// `‖y_d − c‖ ≤ ρ_g = ‖g − c‖ + r_g` the numerator is at most `2(ρ_g ρ − ρ²)`, positive only
    /// for `ρ < ρ_g`, where it is at most `ρ_g²/2` and the denominator at least `R² − ρ_g²`.
    pub fn certificate(&self, goal_center: &[f64], goal_radius: f64, shrink: f64) -> Certificate {
        let r = self.radius;
        let rg = goal_radius;
        let offset: f64 = goal_center
            .iter()
            .zip(&self.center)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        let reach = offset + rg;
        let spline_bound = refined_radial_bound(&self.spline, &self.center, r, goal_center, rg);
        let workspace_bound = reach * reach / (2.0 * (r * r - reach * reach));
        let bound = spline_bound + workspace_bound;
        let holds = reach < r && bound < 2.0 * self.k;
        Certificate {
            kind: CertificateKind::GammaDecreasing,
            k: self.k,
            spline_bound,
            workspace_bound,
            bound,
            holds,
            gamma_decreasing: holds,
            decay_rate: 2.0 * (2.0 - bound / self.k),
            critical_points: None,
            shrink,
            goal_center: goal_center.to_vec(),
            goal_radius: rg,
            workspace_center: self.center.clone(),
            workspace_radius: r,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_nf(rng: &mut ChaCha8Rng, k: f64) -> NavigationFunction {
        let center = vec![0.1, -0.2, 0.05];
        let radius = 2.0;
        let lower: Vec<f64> = center.iter().map(|c| c - radius).collect();
        let upper: Vec<f64> = center.iter().map(|c| c + radius).collect();
        let mut spline = TensorBSpline::zeros(&lower, &upper, 4);
        for c in spline.coefficients_mut() {
            *c = rng.random_range(-0.5..0.5);
        }
        NavigationFunction {
            k,
            length_scale: 2.0 * radius,
            center,
            radius,
            spline,
        }
    }

    #[test]
    fn nf_gradient_matches_central_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for &k in &[2.0, 3.0, 7.5, 40.0] {
            let nf = random_nf(&mut rng, k);
            for _ in 0..40 {
                let y: Vec<f64> = (0..3).map(|_| rng.random_range(-1.0..1.0)).collect();
                let yd: Vec<f64> = (0..3).map(|_| rng.random_range(-0.8..0.8)).collect();
                let mut g = [0.0; 3];
                let phi = nf.value_gradient(&y, &yd, &mut g);
                // direct evaluation of eq. 9 as an independent reference
                let mut gl = [0.0; 3];
                let l2 = nf.length_scale * nf.length_scale;
                let beta = nf.log_beta(&y, &mut gl).exp() / l2;
                let gamma: f64 = y
                    .iter()
                    .zip(&yd)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
                    / l2;
                let direct = gamma / (gamma.powf(k) + beta).powf(1.0 / k);
                assert!((phi - direct).abs() < 1e-12 * (1.0 + direct));
                let h = 1e-6;
                for i in 0..3 {
                    let mut yp = y.clone();
                    let mut ym = y.clone();
                    yp[i] += h;
                    ym[i] -= h;
                    let mut tmp = [0.0; 3];
                    let fd = (nf.value_gradient(&yp, &yd, &mut tmp)
                        - nf.value_gradient(&ym, &yd, &mut tmp))
                        / (2.0 * h);
                    assert!(
                        (fd - g[i]).abs() < 1e-6 * (1.0 + fd.abs()),
                        "k {k}: {fd} vs {}",
                        g[i]
                    );
                }
                // the flow is parallel to −∇φ and satisfies ∇γ·f = −2γ(2 − p)
                let mut f = [0.0; 3];
                let p = nf.flow(&y, &yd, &mut f);
                let gamma = gamma * l2;
                let gn = (g.iter().map(|x| x * x).sum::<f64>()).sqrt();
                let fnorm = (f.iter().map(|x| x * x).sum::<f64>()).sqrt();
                let cos = -(0..3).map(|i| g[i] * f[i]).sum::<f64>() / (gn * fnorm);
                assert!((cos - 1.0).abs() < 1e-9);
                let gdot: f64 = (0..3).map(|i| 2.0 * (y[i] - yd[i]) * f[i]).sum();
                assert!((gdot + 2.0 * gamma * (2.0 - p)).abs() < 1e-9 * (1.0 + gdot.abs()));
            }
        }
    }

    #[test]
    fn certificate_bounds_the_sampled_supremum() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let nf = random_nf(&mut rng, 3.0);
        let rg = 0.7;
        let gc = vec![0.4, -0.1, 0.2];
        let cert = nf.certificate(&gc, rg, 1.0);
        let mut worst: f64 = f64::NEG_INFINITY;
        for _ in 0..20000 {
            // uniform-ish samples in the balls by rejection
            let y: Vec<f64> = loop {
                let v: Vec<f64> = (0..3).map(|_| rng.random_range(-1.0..1.0)).collect();
                if v.iter().map(|x| x * x).sum::<f64>() < 1.0 {
                    break v
                        .iter()
                        .zip(&nf.center)
                        .map(|(a, c)| c + a * 1.999)
                        .collect();
                }
            };
            let yd: Vec<f64> = loop {
                let v: Vec<f64> = (0..3).map(|_| rng.random_range(-1.0..1.0)).collect();
                if v.iter().map(|x| x * x).sum::<f64>() < 1.0 {
                    break v.iter().zip(&gc).map(|(a, c)| c + a * rg).collect();
                }
            };
            let mut f = [0.0; 3];
            let p = nf.flow(&y, &yd, &mut f) * nf.k;
            worst = worst.max(p);
        }
        assert!(
            worst <= cert.bound,
            "sampled {worst} > bound {}",
            cert.bound
        );
    }
}
