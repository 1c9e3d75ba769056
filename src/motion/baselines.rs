//! Two learned baselines for the held-out humanlikeness report (issue 19): a probabilistic
//! movement primitive (ProMP, Paraschos et al. 2013) conditioned on the start and the goal, and
//! a dynamic movement primitive (DMP, Ijspeert et al. 2013, in the goal-change form of Pastor et
//! al. 2009), both in joint space over all of the model's joints, trained on the same
//! demonstrations as the navigation-function model and judged by the same arc-length deviation.
//!
//! Hand-rolled: no maintained Rust crate implements either; each is a few dozen lines of
//! `nalgebra` here, and the tests check them against closed forms rather than against a port.
//!
//! Phase: each demonstration's time is normalised to `z ∈ [0, 1]` (both baselines then give a
//! path; the report compares paths, not timing).

use nalgebra::{DMatrix, DVector};

use super::JointTrajectory;

/// Radial basis functions per joint (ProMP) and per forcing term (DMP).
pub const BASIS: usize = 12;
/// Samples of a generated path.
pub const PATH_SAMPLES: usize = 101;

/// Diagonal loading of the ProMP weight covariance, relative to its mean variance. The weights
/// of a model's demonstrations come from a few object positions (about 40 demonstrations, 4
/// positions, 120 weights on a 10-joint system), so the sample covariance over-fits them: with
/// 1e-6 the conditioned mean reproduces training demonstrations at about 0.35 of the joint line
/// but held-out positions at 0.67-1.37 of it. Over the six bundled systems' held-out folds
/// (`examples/motion_heldout.rs`) 1e-2 gives 0.50-1.14 and 1e-1 0.56-1.13 (mean deviation 0.283
/// and 0.284 rad); the baseline gets the better of the two, so the comparison is against its
/// strongest form we measured.
const PROMP_LOADING: f64 = 1e-2;

/// DMP transformation system: stiffness `K`, critical damping `D = 2√K`.
const DMP_K: f64 = 100.0;
const DMP_D: f64 = 20.0;
/// Canonical system `s = exp(−α z)`: `s(1) = 0.01`.
const DMP_ALPHA: f64 = 4.605_170_185_988_091;
/// Euler steps of a generated DMP over `z ∈ [0, 1]`.
const DMP_STEPS: usize = 1000;

/// Normalised phase of every frame of `dm`: `(t − t_0)/(t_end − t_0)`.
fn phases(dm: &JointTrajectory) -> Vec<f64> {
    let t0 = dm.times[0];
    let span = (dm.times[dm.frames() - 1] - t0).max(f64::MIN_POSITIVE);
    dm.times.iter().map(|t| (t - t0) / span).collect()
}

/// Normalised Gaussian bumps centred evenly on `[0, 1]` (width one spacing), into `out[..BASIS]`.
fn promp_basis(z: f64, out: &mut [f64; BASIS]) {
    let step = 1.0 / (BASIS - 1) as f64;
    let mut sum = 0.0;
    for (b, o) in out.iter_mut().enumerate() {
        let e = (z - b as f64 * step) / step;
        *o = (-0.5 * e * e).exp();
        sum += *o;
    }
    for o in out.iter_mut() {
        *o /= sum;
    }
}

/// A ProMP over `n` joints: the Gaussian of the demonstrations' basis weights (`n·BASIS`,
/// joint-major).
#[derive(Clone, Debug)]
pub struct ProMp {
    n: usize,
    mean: DVector<f64>,
    cov: DMatrix<f64>,
}

impl ProMp {
    /// Fits each demonstration's weights by ridge regression on the basis, then their mean and
    /// covariance, loaded by [`PROMP_LOADING`] (which also keeps conditioning on `2n` values well
    /// posed with fewer demonstrations than weights). `None` with fewer than two demonstrations.
    pub fn fit(demos: &[&JointTrajectory], n: usize) -> Option<Self> {
        if demos.len() < 2 || n == 0 {
            return None;
        }
        let dim = n * BASIS;
        let mut weights: Vec<DVector<f64>> = Vec::with_capacity(demos.len());
        let mut psi = [0.0; BASIS];
        for dm in demos {
            let z = phases(dm);
            let mut gram = DMatrix::<f64>::zeros(BASIS, BASIS);
            let mut rhs = DMatrix::<f64>::zeros(BASIS, n);
            for (f, &zf) in z.iter().enumerate() {
                promp_basis(zf, &mut psi);
                let q = dm.frame(f, n);
                for a in 0..BASIS {
                    for b in 0..BASIS {
                        gram[(a, b)] += psi[a] * psi[b];
                    }
                    for j in 0..n {
                        rhs[(a, j)] += psi[a] * q[j];
                    }
                }
            }
            for a in 0..BASIS {
                gram[(a, a)] += 1e-8;
            }
            let w = gram.cholesky()?.solve(&rhs);
            weights.push(DVector::from_fn(dim, |i, _| w[(i % BASIS, i / BASIS)]));
        }
        let m = weights.len() as f64;
        let mean = weights.iter().fold(DVector::zeros(dim), |acc, w| acc + w) / m;
        let mut cov = DMatrix::<f64>::zeros(dim, dim);
        for w in &weights {
            let e = w - &mean;
            cov += &e * e.transpose();
        }
        cov /= m - 1.0;
        let scale = cov.diagonal().mean().max(1e-12);
        for i in 0..dim {
            cov[(i, i)] += PROMP_LOADING * scale;
        }
        Some(Self { n, mean, cov })
    }

    /// The mean path conditioned on passing through `start` at `z = 0` and `goal` at `z = 1`
    /// (Gaussian conditioning on those `2n` linear observations), `PATH_SAMPLES × n`, its ends
    /// exactly `start` and `goal`.
    pub fn path(&self, start: &[f64], goal: &[f64]) -> Option<Vec<f64>> {
        let n = self.n;
        let dim = n * BASIS;
        let mut h = DMatrix::<f64>::zeros(2 * n, dim);
        let mut psi = [0.0; BASIS];
        for (row0, z) in [(0, 0.0), (n, 1.0)] {
            promp_basis(z, &mut psi);
            for j in 0..n {
                for b in 0..BASIS {
                    h[(row0 + j, j * BASIS + b)] = psi[b];
                }
            }
        }
        let y = DVector::from_fn(2 * n, |i, _| if i < n { start[i] } else { goal[i - n] });
        let sht = &self.cov * h.transpose();
        let mut s = &h * &sht;
        let scale = s.diagonal().mean().max(1e-12);
        for i in 0..2 * n {
            s[(i, i)] += 1e-10 * scale;
        }
        let innovation = y - &h * &self.mean;
        let mean = &self.mean + sht * s.cholesky()?.solve(&innovation);
        let mut out = vec![0.0; PATH_SAMPLES * n];
        for m in 0..PATH_SAMPLES {
            promp_basis(m as f64 / (PATH_SAMPLES - 1) as f64, &mut psi);
            for j in 0..n {
                out[m * n + j] = (0..BASIS).map(|b| psi[b] * mean[j * BASIS + b]).sum();
            }
        }
        out[..n].copy_from_slice(start);
        out[(PATH_SAMPLES - 1) * n..].copy_from_slice(goal);
        Some(out)
    }
}

/// DMP forcing-term features at phase variable `s`: normalised bumps in `s` (centres spaced
/// evenly in `z`), times `s`, into `out[..BASIS]`.
fn dmp_features(s: f64, out: &mut [f64; BASIS]) {
    let mut sum = 0.0;
    for (b, o) in out.iter_mut().enumerate() {
        let c = (-DMP_ALPHA * b as f64 / (BASIS - 1) as f64).exp();
        let next = (-DMP_ALPHA * (b + 1) as f64 / (BASIS - 1) as f64).exp();
        let h = 1.0 / (c - next).powi(2);
        *o = (-h * (s - c).powi(2)).exp();
        sum += *o;
    }
    let k = s / sum.max(f64::MIN_POSITIVE);
    for o in out.iter_mut() {
        *o *= k;
    }
}

/// A DMP per joint, `z`-normalised (`τ = 1`):
/// `ẍ = K(g − x) − D ẋ − K(g − x_0)s + K f(s)`, `f(s) = Σ ψ_b(s) w_b s / Σ ψ_b(s)`,
/// `s = exp(−α z)`. Pastor's form: the forcing term is not scaled by `g − x_0`, so a goal on the
/// other side of the start (or at it) does not mirror or erase the learned shape. One forcing
/// term per joint, fitted by least squares over all training demonstrations together.
#[derive(Clone, Debug)]
pub struct Dmp {
    n: usize,
    /// `n × BASIS`, joint-major.
    weights: Vec<f64>,
}

impl Dmp {
    /// `None` without a demonstration of at least three frames.
    pub fn fit(demos: &[&JointTrajectory], n: usize) -> Option<Self> {
        let mut grams = vec![DMatrix::<f64>::zeros(BASIS, BASIS); n];
        let mut rhs = vec![DVector::<f64>::zeros(BASIS); n];
        let mut phi = [0.0; BASIS];
        let mut used = false;
        for dm in demos {
            let frames = dm.frames();
            if frames < 3 {
                continue;
            }
            used = true;
            let z = phases(dm);
            let x0 = dm.frame(0, n);
            let g = dm.frame(frames - 1, n);
            for f in 1..frames - 1 {
                let (h0, h1) = (z[f] - z[f - 1], z[f + 1] - z[f]);
                if h0 <= 0.0 || h1 <= 0.0 {
                    continue;
                }
                let s = (-DMP_ALPHA * z[f]).exp();
                dmp_features(s, &mut phi);
                let (qa, q, qb) = (dm.frame(f - 1, n), dm.frame(f, n), dm.frame(f + 1, n));
                for j in 0..n {
                    // second-order differences on a non-uniform grid
                    let v = (qb[j] - qa[j]) / (h0 + h1);
                    let a = 2.0 * ((qb[j] - q[j]) / h1 - (q[j] - qa[j]) / h0) / (h0 + h1);
                    let target = (a + DMP_D * v) / DMP_K - (g[j] - q[j]) + (g[j] - x0[j]) * s;
                    for a in 0..BASIS {
                        for b in 0..BASIS {
                            grams[j][(a, b)] += phi[a] * phi[b];
                        }
                        rhs[j][a] += phi[a] * target;
                    }
                }
            }
        }
        if !used {
            return None;
        }
        let mut weights = vec![0.0; n * BASIS];
        for j in 0..n {
            let scale = grams[j].diagonal().mean().max(1e-12);
            for a in 0..BASIS {
                grams[j][(a, a)] += 1e-8 * scale;
            }
            let w = grams[j].clone().cholesky()?.solve(&rhs[j]);
            weights[j * BASIS..(j + 1) * BASIS].copy_from_slice(w.as_slice());
        }
        Some(Self { n, weights })
    }

    /// The DMP rolled out from `start` towards `goal` (semi-implicit Euler, `DMP_STEPS` steps
    /// over `z ∈ [0, 1]`), `PATH_SAMPLES × n`, the last sample exactly `goal`.
    pub fn path(&self, start: &[f64], goal: &[f64]) -> Vec<f64> {
        let n = self.n;
        let mut out = vec![0.0; PATH_SAMPLES * n];
        let mut x = start.to_vec();
        let mut v = vec![0.0; n];
        let mut phi = [0.0; BASIS];
        let dz = 1.0 / DMP_STEPS as f64;
        let every = DMP_STEPS / (PATH_SAMPLES - 1);
        out[..n].copy_from_slice(start);
        for step in 0..DMP_STEPS {
            let s = (-DMP_ALPHA * step as f64 * dz).exp();
            dmp_features(s, &mut phi);
            for j in 0..n {
                let f: f64 = (0..BASIS)
                    .map(|b| phi[b] * self.weights[j * BASIS + b])
                    .sum();
                let acc =
                    DMP_K * (goal[j] - x[j]) - DMP_D * v[j] - DMP_K * (goal[j] - start[j]) * s
                        + DMP_K * f;
                v[j] += acc * dz;
                x[j] += v[j] * dz;
            }
            if (step + 1) % every == 0 {
                let m = (step + 1) / every;
                out[m * n..(m + 1) * n].copy_from_slice(&x);
            }
        }
        out[(PATH_SAMPLES - 1) * n..].copy_from_slice(goal);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Minimum-jerk progress plus a bump of amplitude `c` (`sin² πz`: at rest at both ends, as a
    /// reach is): the demonstration family below.
    fn family(start: &[f64], goal: &[f64], c: &[f64], frames: usize) -> JointTrajectory {
        let n = start.len();
        let mut positions = Vec::with_capacity(frames * n);
        let mut times = Vec::with_capacity(frames);
        for f in 0..frames {
            let z = f as f64 / (frames - 1) as f64;
            let mj = z * z * z * (10.0 - 15.0 * z + 6.0 * z * z);
            for j in 0..n {
                positions.push(
                    start[j]
                        + (goal[j] - start[j]) * mj
                        + c[j] * (std::f64::consts::PI * z).sin().powi(2),
                );
            }
            times.push(1.7 * z);
        }
        JointTrajectory { times, positions }
    }

    fn max_abs(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    /// Demonstrations whose bump depends linearly on start and goal (`c = A (start; goal)`):
    /// the weights are then jointly Gaussian (degenerate) and conditioning on start and goal
    /// recovers the bump, so a held-out path is reproduced up to the basis' approximation. A
    /// mean path without conditioning, or conditioning with a wrong gain, misses it by the bump.
    #[test]
    fn promp_conditioned_on_start_and_goal_recovers_a_linear_gaussian_family() {
        let n = 3;
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let a: Vec<f64> = (0..n * 2 * n)
            .map(|_| rng.random_range(-0.4..0.4))
            .collect();
        let sample = |rng: &mut ChaCha8Rng| {
            let s: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let g: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            let c: Vec<f64> = (0..n)
                .map(|j| {
                    (0..n)
                        .map(|i| a[j * 2 * n + i] * s[i] + a[j * 2 * n + n + i] * g[i])
                        .sum()
                })
                .collect();
            (s, g, c)
        };
        let demos: Vec<JointTrajectory> = (0..30)
            .map(|_| {
                let (s, g, c) = sample(&mut rng);
                family(&s, &g, &c, 120)
            })
            .collect();
        let refs: Vec<&JointTrajectory> = demos.iter().collect();
        let promp = ProMp::fit(&refs, n).unwrap();
        for _ in 0..10 {
            let (s, g, c) = sample(&mut rng);
            let truth = family(&s, &g, &c, PATH_SAMPLES);
            let path = promp.path(&s, &g).unwrap();
            let bump = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let err = max_abs(&path, &truth.positions);
            // measured 2-6 mrad for bumps of 0.27-1.0 rad
            assert!(
                err < 0.015,
                "ProMP misses the held-out path by {err} (bump {bump})"
            );
        }
    }

    /// One demonstration replayed with its own start and goal: the DMP reproduces it up to the
    /// forcing term's basis and the Euler steps.
    #[test]
    fn dmp_reproduces_its_demonstration() {
        let s = [0.2, -0.5];
        let g = [1.1, 0.4];
        let c = [0.3, -0.25];
        let demo = family(&s, &g, &c, 200);
        let dmp = Dmp::fit(&[&demo], 2).unwrap();
        let path = dmp.path(&s, &g);
        let truth = family(&s, &g, &c, PATH_SAMPLES);
        let err = max_abs(&path, &truth.positions);
        assert!(err < 0.005, "DMP reproduction error {err}");
        // without the learned forcing term the roll-out misses the bump (the test can fail)
        let plain = Dmp {
            n: 2,
            weights: vec![0.0; 2 * BASIS],
        };
        assert!(max_abs(&plain.path(&s, &g), &truth.positions) > 0.2);
    }

    /// Pastor's form depends on `g − x`, `g − x_0` and `ẋ` only: moving start and goal by the
    /// same offset moves the whole roll-out by it (closed form of the equations' invariance).
    #[test]
    fn dmp_is_translation_invariant() {
        let demo = family(&[0.0, 0.3], &[0.8, -0.2], &[0.2, 0.1], 150);
        let dmp = Dmp::fit(&[&demo], 2).unwrap();
        let (s, g) = ([0.1, 0.1], [-0.6, 0.9]);
        let a = dmp.path(&s, &g);
        let d = [0.37, -1.2];
        let b = dmp.path(&[s[0] + d[0], s[1] + d[1]], &[g[0] + d[0], g[1] + d[1]]);
        for m in 0..PATH_SAMPLES {
            for j in 0..2 {
                assert!((b[m * 2 + j] - a[m * 2 + j] - d[j]).abs() < 1e-9);
            }
        }
    }
}
