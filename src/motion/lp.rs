//! A small linear program whose every constraint touches at most four consecutive variables:
//! `min c·x` subject to `A x ≤ b`, solved by Mehrotra's primal-dual interior-point method on the
//! normal equations.
//!
//! Why not a general solver: the time law's linear programs ([`super::retime`]) have 100
//! variables (a dilation's control values) and thousands of rows (limits on a fine grid), each
//! row a cubic B-spline's four local weights. A general conic solver factorises the KKT system
//! of all rows (about 10 ms per thousand rows measured with Clarabel); here the normal matrix
//! `AᵀDA` is a band of half-width 3, formed with 10 updates per row and factorised in
//! microseconds, so one program costs a few passes over the rows. The tests compare optima with
//! Clarabel's.

/// One constraint `coef · x[first..first + 4] ≤ bound`.
#[derive(Clone, Copy, Debug)]
pub struct Row {
    pub first: usize,
    pub coef: [f64; 4],
    pub bound: f64,
}

/// Interior-point iterations at most (a fixed budget: the same answer on any machine).
const MAX_ITERATIONS: usize = 80;
/// Relative residuals and duality gap at which a program counts as solved (the time law judges
/// each result on its own grid, so more digits buy nothing).
const TOLERANCE: f64 = 1e-7;
/// Fraction of the way to the boundary a step may go.
const STEP_FRACTION: f64 = 0.995;

/// Buffers of [`solve`], kept between programs.
#[derive(Default)]
pub struct Workspace {
    rows: Vec<Row>,
    s: Vec<f64>,
    z: Vec<f64>,
    ds: Vec<f64>,
    dz: Vec<f64>,
    ds_aff: Vec<f64>,
    dz_aff: Vec<f64>,
    rp: Vec<f64>,
    rc: Vec<f64>,
    /// `AᵀDA`, a band: `band[4k + d]` is entry `(k, k − d)`; factorised in place.
    band: Vec<f64>,
    rhs: Vec<f64>,
    dx: Vec<f64>,
    rd: Vec<f64>,
}

/// `row · x`.
#[inline]
fn dot(r: &Row, x: &[f64]) -> f64 {
    r.coef[0] * x[r.first]
        + r.coef[1] * x[r.first + 1]
        + r.coef[2] * x[r.first + 2]
        + r.coef[3] * x[r.first + 3]
}

/// `min c·x` subject to `rows`, from `x` (which need not be feasible). The optimum in `x`, or
/// `false` (and `x` unspecified) if the iterations did not reach it.
pub fn solve(c: &[f64], rows: &[Row], x: &mut [f64], ws: &mut Workspace) -> bool {
    let n = c.len();
    assert!(n >= 4 && x.len() == n);
    // rows scaled to a largest coefficient of 1: the same program, better conditioned
    let mut scaled = std::mem::take(&mut ws.rows);
    scaled.clear();
    scaled.extend(rows.iter().map(|r| {
        debug_assert!(r.first + 4 <= n);
        let largest = r.coef.iter().fold(0.0f64, |a, c| a.max(c.abs()));
        let scale = if largest > 0.0 { 1.0 / largest } else { 1.0 };
        Row {
            first: r.first,
            coef: r.coef.map(|c| c * scale),
            bound: r.bound * scale,
        }
    }));
    let solved = solve_scaled(c, &scaled, x, ws);
    ws.rows = scaled;
    solved
}

/// [`solve`] on rows already scaled.
fn solve_scaled(c: &[f64], rows: &[Row], x: &mut [f64], ws: &mut Workspace) -> bool {
    let (n, m) = (c.len(), rows.len());
    for v in [
        &mut ws.s,
        &mut ws.z,
        &mut ws.ds,
        &mut ws.dz,
        &mut ws.ds_aff,
        &mut ws.dz_aff,
        &mut ws.rp,
        &mut ws.rc,
    ] {
        v.clear();
        v.resize(m, 0.0);
    }
    for v in [&mut ws.rhs, &mut ws.dx, &mut ws.rd] {
        v.clear();
        v.resize(n, 0.0);
    }
    ws.band.clear();
    ws.band.resize(4 * n, 0.0);
    // start: slacks at least a small positive value, unit duals
    let b_norm = rows.iter().fold(0.0f64, |a, r| a.max(r.bound.abs()));
    let c_norm = c.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    for (i, r) in rows.iter().enumerate() {
        ws.s[i] = (r.bound - dot(r, x)).max(1e-2 * (1.0 + b_norm));
        ws.z[i] = (1.0 + c_norm) / (1.0 + b_norm).sqrt();
    }
    for _ in 0..MAX_ITERATIONS {
        // residuals: dual c + Aᵀz, primal Ax + s − b
        ws.rd.copy_from_slice(c);
        for (i, r) in rows.iter().enumerate() {
            for k in 0..4 {
                ws.rd[r.first + k] += r.coef[k] * ws.z[i];
            }
            ws.rp[i] = dot(r, x) + ws.s[i] - r.bound;
        }
        let mu = ws.s.iter().zip(&ws.z).map(|(s, z)| s * z).sum::<f64>() / m as f64;
        let rp_norm = ws.rp.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let rd_norm = ws.rd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let objective = c.iter().zip(x.iter()).map(|(c, x)| c * x).sum::<f64>();
        if rp_norm <= TOLERANCE * (1.0 + b_norm)
            && rd_norm <= TOLERANCE * (1.0 + c_norm)
            && mu * m as f64 <= TOLERANCE * (1.0 + objective.abs())
        {
            return true;
        }
        // normal matrix AᵀDA, D = z/s: a band (each row adds a 4 × 4 block on the diagonal)
        ws.band.iter_mut().for_each(|v| *v = 0.0);
        for (i, r) in rows.iter().enumerate() {
            let d = ws.z[i] / ws.s[i];
            for a in 0..4 {
                for b in 0..=a {
                    ws.band[(r.first + a) * 4 + (a - b)] += d * r.coef[a] * r.coef[b];
                }
            }
        }
        let trace = (0..n).map(|j| ws.band[4 * j]).fold(0.0, f64::max);
        for j in 0..n {
            ws.band[4 * j] += 1e-14 * (1.0 + trace);
        }
        if !band_cholesky(&mut ws.band, n) {
            return false;
        }
        // predictor (affine scaling: r_c = s∘z), then Mehrotra's corrector
        ws.rc
            .iter_mut()
            .zip(ws.s.iter().zip(&ws.z))
            .for_each(|(rc, (s, z))| *rc = s * z);
        direction(rows, ws, n);
        let (ap, ad) = step_lengths(&ws.s, &ws.ds, &ws.z, &ws.dz, 1.0);
        let mu_aff =
            ws.s.iter()
                .zip(&ws.ds)
                .zip(ws.z.iter().zip(&ws.dz))
                .map(|((s, ds), (z, dz))| (s + ap * ds) * (z + ad * dz))
                .sum::<f64>()
                / m as f64;
        let sigma = (mu_aff / mu).powi(3).min(1.0);
        ws.ds_aff.copy_from_slice(&ws.ds);
        ws.dz_aff.copy_from_slice(&ws.dz);
        for i in 0..m {
            ws.rc[i] = ws.s[i] * ws.z[i] + ws.ds_aff[i] * ws.dz_aff[i] - sigma * mu;
        }
        direction(rows, ws, n);
        let (ap, ad) = step_lengths(&ws.s, &ws.ds, &ws.z, &ws.dz, STEP_FRACTION);
        for k in 0..n {
            x[k] += ap * ws.dx[k];
        }
        for i in 0..m {
            ws.s[i] += ap * ws.ds[i];
            ws.z[i] += ad * ws.dz[i];
        }
    }
    false
}

/// The Newton direction for the residuals in `ws` (`rd`, `rp`) and complementarity target
/// `rc`, with the normal matrix factorised in `ws.normal`:
/// `AᵀDA Δx = −r_d − Aᵀ(D r_p − r_c/s)`, `Δz = D(AΔx + r_p) − r_c/s`, `Δs = −(AΔx + r_p)`.
fn direction(rows: &[Row], ws: &mut Workspace, n: usize) {
    for k in 0..n {
        ws.rhs[k] = -ws.rd[k];
    }
    for (i, r) in rows.iter().enumerate() {
        let v = (ws.z[i] * ws.rp[i] - ws.rc[i]) / ws.s[i];
        for k in 0..4 {
            ws.rhs[r.first + k] -= r.coef[k] * v;
        }
    }
    ws.dx.copy_from_slice(&ws.rhs);
    band_solve(&ws.band, n, &mut ws.dx);
    for (i, r) in rows.iter().enumerate() {
        let adx = dot(r, &ws.dx);
        ws.ds[i] = -(adx + ws.rp[i]);
        ws.dz[i] = (ws.z[i] * (adx + ws.rp[i]) - ws.rc[i]) / ws.s[i];
    }
}

/// The largest steps, up to 1 and times `fraction`, that keep `s` and `z` positive.
fn step_lengths(s: &[f64], ds: &[f64], z: &[f64], dz: &[f64], fraction: f64) -> (f64, f64) {
    let limit = |v: &[f64], dv: &[f64]| {
        v.iter().zip(dv).fold(1.0f64, |a, (v, dv)| {
            if *dv < 0.0 {
                a.min(-v / dv * fraction)
            } else {
                a
            }
        })
    };
    (limit(s, ds), limit(z, dz))
}

/// In-place Cholesky factor of a symmetric band of half-width 3 (`band[4k + d]` = entry
/// `(k, k − d)`); `false` if it is not positive definite.
fn band_cholesky(band: &mut [f64], n: usize) -> bool {
    for j in 0..n {
        // L[j][j−d] for d = 3, 2, 1, then the diagonal
        for d in (1..=3.min(j)).rev() {
            let i = j - d;
            let mut v = band[4 * j + d];
            for e in 1..=(3 - d).min(i) {
                v -= band[4 * j + d + e] * band[4 * i + e];
            }
            band[4 * j + d] = v / band[4 * i];
        }
        let mut v = band[4 * j];
        for d in 1..=3.min(j) {
            v -= band[4 * j + d] * band[4 * j + d];
        }
        if v <= 0.0 || !v.is_finite() {
            return false;
        }
        band[4 * j] = v.sqrt();
    }
    true
}

/// Solves `L Lᵀ x = b` in place with the factor from [`band_cholesky`].
fn band_solve(band: &[f64], n: usize, b: &mut [f64]) {
    for j in 0..n {
        let mut v = b[j];
        for d in 1..=3.min(j) {
            v -= band[4 * j + d] * b[j - d];
        }
        b[j] = v / band[4 * j];
    }
    for j in (0..n).rev() {
        let mut v = b[j];
        for d in 1..=3.min(n - 1 - j) {
            v -= band[4 * (j + d) + d] * b[j + d];
        }
        b[j] = v / band[4 * j];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The same program by Clarabel (a general interior-point conic solver): the reference.
    fn clarabel_optimum(c: &[f64], rows: &[Row]) -> f64 {
        use clarabel::algebra::CscMatrix;
        use clarabel::solver::{
            DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus,
        };
        let n = c.len();
        let (mut ri, mut ci, mut vi, mut b) = (vec![], vec![], vec![], vec![]);
        for (i, r) in rows.iter().enumerate() {
            for k in 0..4 {
                ri.push(i);
                ci.push(r.first + k);
                vi.push(r.coef[k]);
            }
            b.push(r.bound);
        }
        let m = b.len();
        let a = CscMatrix::new_from_triplets(m, n, ri, ci, vi);
        let settings = DefaultSettingsBuilder::default()
            .verbose(false)
            .build()
            .unwrap();
        let zero = CscMatrix::<f64>::zeros((n, n));
        let mut solver =
            DefaultSolver::new(&zero, c, &a, &b, &[NonnegativeConeT(m)], settings).unwrap();
        solver.solve();
        assert_eq!(solver.solution.status, SolverStatus::Solved);
        solver.solution.obj_val
    }

    /// Random bounded programs of the time law's shape (40 or 100 variables, box rows around a
    /// point and local rows through a point inside, so feasible): the same optimum as
    /// Clarabel's.
    #[test]
    fn local_programs_reach_the_general_solvers_optimum() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut ws = Workspace::default();
        for case in 0..20 {
            let n = if case % 3 == 0 { 100 } else { 40 };
            let centre: Vec<f64> = (0..n).map(|_| rng.random_range(0.5..2.0)).collect();
            let c: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..0.05)).collect();
            let mut rows = Vec::new();
            for k in 0..n {
                let first = k.min(n - 4);
                let mut coef = [0.0; 4];
                coef[k - first] = 1.0;
                rows.push(Row {
                    first,
                    coef,
                    bound: centre[k] * 1.5,
                });
                rows.push(Row {
                    first,
                    coef: coef.map(|v| -v),
                    bound: -centre[k] * 0.5,
                });
            }
            for _ in 0..rng.random_range(100..2000) {
                let first = rng.random_range(0..n - 3);
                let coef: [f64; 4] =
                    std::array::from_fn(|_| rng.random_range(-1.0..1.0) * 10f64.powi(case % 4));
                let at: f64 = (0..4).map(|k| coef[k] * centre[first + k]).sum();
                rows.push(Row {
                    first,
                    coef,
                    bound: at + rng.random_range(0.0..0.3) * 10f64.powi(case % 4),
                });
            }
            let optimum = clarabel_optimum(&c, &rows);
            let mut x = centre.clone();
            assert!(solve(&c, &rows, &mut x, &mut ws), "case {case}");
            let value: f64 = c.iter().zip(&x).map(|(c, x)| c * x).sum();
            assert!(
                (value - optimum).abs() <= 1e-6 * (1.0 + optimum.abs()),
                "case {case}: {value} vs {optimum}"
            );
            for r in &rows {
                let lhs: f64 = (0..4).map(|k| r.coef[k] * x[r.first + k]).sum();
                assert!(lhs <= r.bound + 1e-7 * (1.0 + r.bound.abs()), "case {case}");
            }
        }
    }
}
