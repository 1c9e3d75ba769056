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
/// Relative residuals at which a program counts as solved (the time law judges each result on
/// its own grid, so more digits buy nothing).
const TOLERANCE: f64 = 1e-5;
/// Fraction of the way to the boundary a step may go.
const STEP_FRACTION: f64 = 0.995;

/// Buffers of [`solve`], kept between programs.
#[derive(Default)]
pub struct Workspace {
    rows: Vec<Row>,
    /// Per row: slack, dual, primal residual `Ax + s − b`, `D = z/s`, `1/s`, the predictor's
    /// `Δs∘Δz/s` (the corrector's second-order term) and the step.
    s: Vec<f64>,
    z: Vec<f64>,
    rp: Vec<f64>,
    d: Vec<f64>,
    inv_s: Vec<f64>,
    second: Vec<f64>,
    ds: Vec<f64>,
    dz: Vec<f64>,
    /// `AᵀDA`, a band: `band[4k + d]` is entry `(k, k − d)`; factorised in place.
    band: Vec<f64>,
    /// Per variable: the dual residual `c + Aᵀz`, the parts of the right-hand sides (see
    /// [`solve_scaled`]) and the step.
    rd: Vec<f64>,
    rhs_pred: Vec<f64>,
    rhs_corr: Vec<f64>,
    rhs_centre: Vec<f64>,
    dx: Vec<f64>,
}

/// The four variables a row touches.
#[inline]
fn local(r: &Row, x: &[f64]) -> [f64; 4] {
    let v = &x[r.first..r.first + 4];
    [v[0], v[1], v[2], v[3]]
}

/// `row · x`.
#[inline]
fn dot(r: &Row, x: &[f64]) -> f64 {
    let v = local(r, x);
    r.coef[0] * v[0] + r.coef[1] * v[1] + r.coef[2] * v[2] + r.coef[3] * v[3]
}

/// `x[first..first + 4] += scale · coef`.
#[inline]
fn add_scaled(r: &Row, scale: f64, x: &mut [f64]) {
    let v = &mut x[r.first..r.first + 4];
    for k in 0..4 {
        v[k] += r.coef[k] * scale;
    }
}

/// `min c·x` subject to `rows`, from `x` (which need not be feasible), to a duality gap of `gap`
/// relative to the objective. The optimum in `x`, or `false` (and `x` unspecified) if the
/// iterations did not reach it.
pub fn solve(c: &[f64], rows: &[Row], x: &mut [f64], gap: f64, ws: &mut Workspace) -> bool {
    let n = c.len();
    assert!(n >= 4 && x.len() == n);
    // rows scaled to a largest coefficient of 1: the same program, better conditioned
    let mut scaled = std::mem::take(&mut ws.rows);
    scaled.clear();
    scaled.extend(rows.iter().map(|r| {
        assert!(r.first + 4 <= n);
        let largest = r.coef.iter().fold(0.0f64, |a, c| a.max(c.abs()));
        let scale = if largest > 0.0 { 1.0 / largest } else { 1.0 };
        Row {
            first: r.first,
            coef: r.coef.map(|c| c * scale),
            bound: r.bound * scale,
        }
    }));
    let solved = solve_scaled(c, &scaled, x, gap, ws);
    ws.rows = scaled;
    solved
}

/// [`solve`] on rows already scaled.
///
/// Each iteration is three passes over the rows. With `D = z/s`, the Newton direction for a
/// complementarity target `r_c` is `AᵀDA Δx = −r_d − Aᵀ(D r_p − r_c/s)`,
/// `Δs = −(AΔx + r_p)`, `Δz = −DΔs − r_c/s`. The predictor's target is `s∘z` (so `r_c/s = z`);
/// Mehrotra's corrector's is `s∘z + Δs_a∘Δz_a − σμ`, whose right-hand side is linear in `σ`:
/// its two parts are summed while the predictor's step is taken, and `σ` (from the predictor's
/// complementarity, itself a polynomial in the step lengths whose four sums are taken there
/// too) combines them.
fn solve_scaled(
    c: &[f64],
    rows: &[Row],
    x: &mut [f64],
    gap_tolerance: f64,
    ws: &mut Workspace,
) -> bool {
    let (n, m) = (c.len(), rows.len());
    for v in [
        &mut ws.s,
        &mut ws.z,
        &mut ws.rp,
        &mut ws.d,
        &mut ws.inv_s,
        &mut ws.second,
        &mut ws.ds,
        &mut ws.dz,
    ] {
        v.clear();
        v.resize(m, 0.0);
    }
    for v in [
        &mut ws.rd,
        &mut ws.rhs_pred,
        &mut ws.rhs_corr,
        &mut ws.rhs_centre,
        &mut ws.dx,
    ] {
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
        // pass 1: residuals, D, the normal matrix, the predictor's right-hand side and the
        // corrector's centring part
        ws.rd.copy_from_slice(c);
        ws.band.iter_mut().for_each(|v| *v = 0.0);
        ws.rhs_pred.iter_mut().for_each(|v| *v = 0.0);
        ws.rhs_centre.iter_mut().for_each(|v| *v = 0.0);
        let (mut gap, mut rp_norm) = (0.0, 0.0f64);
        for (i, r) in rows.iter().enumerate() {
            let (s, z) = (ws.s[i], ws.z[i]);
            let rp = dot(r, x) + s - r.bound;
            let inv_s = 1.0 / s;
            let d = z * inv_s;
            (ws.rp[i], ws.d[i], ws.inv_s[i]) = (rp, d, inv_s);
            rp_norm = rp_norm.max(rp.abs());
            gap += s * z;
            add_scaled(r, z, &mut ws.rd);
            add_scaled(r, z - d * rp, &mut ws.rhs_pred);
            add_scaled(r, inv_s, &mut ws.rhs_centre);
            let block = &mut ws.band[4 * r.first..4 * r.first + 16];
            for a in 0..4 {
                let da = d * r.coef[a];
                for b in 0..=a {
                    block[4 * a + (a - b)] += da * r.coef[b];
                }
            }
        }
        let mu = gap / m as f64;
        let rd_norm = ws.rd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let objective = c.iter().zip(x.iter()).map(|(c, x)| c * x).sum::<f64>();
        if rp_norm <= TOLERANCE * (1.0 + b_norm)
            && rd_norm <= TOLERANCE * (1.0 + c_norm)
            && gap <= gap_tolerance * (1.0 + objective.abs())
        {
            return true;
        }
        let trace = (0..n).map(|j| ws.band[4 * j]).fold(0.0, f64::max);
        for j in 0..n {
            ws.band[4 * j] += 1e-14 * (1.0 + trace);
        }
        if !band_cholesky(&mut ws.band, n) {
            return false;
        }
        // pass 2: the predictor's step, its step lengths, the sums its complementarity after
        // the step is made of, and the corrector's second-order part
        for k in 0..n {
            ws.dx[k] = ws.rhs_pred[k] - ws.rd[k];
        }
        band_solve(&ws.band, n, &mut ws.dx);
        ws.rhs_corr.copy_from_slice(&ws.rhs_pred);
        let (mut sp, mut dp) = (f64::INFINITY, f64::INFINITY);
        let (mut ds_z, mut s_dz, mut ds_dz) = (0.0, 0.0, 0.0);
        for (i, r) in rows.iter().enumerate() {
            let (s, z) = (ws.s[i], ws.z[i]);
            let ds = -(dot(r, &ws.dx) + ws.rp[i]);
            let dz = -ws.d[i] * ds - z;
            // (a division only where the ratio is a new smallest: s/(−Δs) < sp ⇔ s < sp·(−Δs))
            if ds < 0.0 && s < -sp * ds {
                sp = -s / ds;
            }
            if dz < 0.0 && z < -dp * dz {
                dp = -z / dz;
            }
            ds_z += ds * z;
            s_dz += s * dz;
            ds_dz += ds * dz;
            let second = ds * dz * ws.inv_s[i];
            ws.second[i] = second;
            add_scaled(r, second, &mut ws.rhs_corr);
        }
        let (ap, ad) = (sp.min(1.0), dp.min(1.0));
        let mu_aff = (gap + ap * ds_z + ad * s_dz + ap * ad * ds_dz) / m as f64;
        let sigma = (mu_aff.max(0.0) / mu).powi(3).min(1.0);
        // pass 3: the corrector's step and its step lengths
        let centre = sigma * mu;
        for k in 0..n {
            ws.dx[k] = ws.rhs_corr[k] - centre * ws.rhs_centre[k] - ws.rd[k];
        }
        band_solve(&ws.band, n, &mut ws.dx);
        let (mut sp, mut dp) = (f64::INFINITY, f64::INFINITY);
        for (i, r) in rows.iter().enumerate() {
            let (s, z) = (ws.s[i], ws.z[i]);
            let ds = -(dot(r, &ws.dx) + ws.rp[i]);
            let dz = -ws.d[i] * ds - z - ws.second[i] + centre * ws.inv_s[i];
            if ds < 0.0 && s < -sp * ds {
                sp = -s / ds;
            }
            if dz < 0.0 && z < -dp * dz {
                dp = -z / dz;
            }
            (ws.ds[i], ws.dz[i]) = (ds, dz);
        }
        let (ap, ad) = ((STEP_FRACTION * sp).min(1.0), (STEP_FRACTION * dp).min(1.0));
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
            assert!(solve(&c, &rows, &mut x, 1e-7, &mut ws), "case {case}");
            let value: f64 = c.iter().zip(&x).map(|(c, x)| c * x).sum();
            assert!(
                (value - optimum).abs() <= 1e-5 * (1.0 + optimum.abs()),
                "case {case}: {value} vs {optimum}"
            );
            for r in &rows {
                let lhs: f64 = (0..4).map(|k| r.coef[k] * x[r.first + k]).sum();
                assert!(lhs <= r.bound + 1e-7 * (1.0 + r.bound.abs()), "case {case}");
            }
        }
    }
}
