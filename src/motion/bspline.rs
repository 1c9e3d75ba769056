//! Tensor-product uniform cubic B-splines: the learned fictitious-obstacle field `s(y)` of
//! DESIGN §5. Hand-rolled (no maintained crate offers allocation-free N-D tensor B-splines with
//! gradients and access to the coefficient differences the convergence bound needs).

use serde::{Deserialize, Serialize};

/// Largest manifold dimension supported by the spline (4^d terms per evaluation).
pub const MAX_DIM: usize = 5;

/// `s(y) = Σ c_j Π_i N_{j_i}(y_i)` over a uniform grid on a box; cubic B-splines per axis,
/// `intervals + 3` coefficients per axis, axis 0 varying fastest in `coefficients`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TensorBSpline {
    /// Axes (the manifold's dimension).
    dim: usize,
    /// Knot intervals per axis.
    intervals: usize,
    /// The grid's lower corner, one per axis.
    lower: Vec<f64>,
    /// Knot spacing, one per axis.
    spacing: Vec<f64>,
    /// `(intervals + 3)^dim` coefficients, axis 0 varying fastest.
    coefficients: Vec<f64>,
}

/// Uniform cubic B-spline basis values and derivatives (w.r.t. the local coordinate) at `u ∈ [0,1]`.
#[inline]
fn basis(u: f64) -> ([f64; 4], [f64; 4]) {
    let v = 1.0 - u;
    let u2 = u * u;
    let u3 = u2 * u;
    (
        [
            v * v * v / 6.0,
            (3.0 * u3 - 6.0 * u2 + 4.0) / 6.0,
            (-3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0) / 6.0,
            u3 / 6.0,
        ],
        [
            -0.5 * v * v,
            0.5 * (3.0 * u2 - 4.0 * u),
            0.5 * (-3.0 * u2 + 2.0 * u + 1.0),
            0.5 * u2,
        ],
    )
}

/// Per-point local support: flat coefficient indices with their basis weights and gradients.
pub(crate) struct Local {
    pub n: usize,
    pub index: [usize; 1024],
    pub weight: [f64; 1024],
    pub grad: [[f64; MAX_DIM]; 1024],
}

impl Local {
    pub fn new() -> Box<Self> {
        Box::new(Local {
            n: 0,
            index: [0; 1024],
            weight: [0.0; 1024],
            grad: [[0.0; MAX_DIM]; 1024],
        })
    }
}

impl TensorBSpline {
    /// A zero spline on the box `[lower, upper]` with `intervals` knot intervals per axis.
    pub fn zeros(lower: &[f64], upper: &[f64], intervals: usize) -> Self {
        let dim = lower.len();
        assert!((1..=MAX_DIM).contains(&dim) && upper.len() == dim && intervals >= 1);
        let spacing = lower
            .iter()
            .zip(upper)
            .map(|(l, u)| ((u - l) / intervals as f64).max(f64::MIN_POSITIVE))
            .collect();
        let n = (intervals + 3).pow(dim as u32);
        TensorBSpline {
            dim,
            intervals,
            lower: lower.to_vec(),
            spacing,
            coefficients: vec![0.0; n],
        }
    }

    pub fn dim(&self) -> usize {
        self.dim
    }
    pub fn intervals(&self) -> usize {
        self.intervals
    }
    pub fn spacing(&self) -> &[f64] {
        &self.spacing
    }
    pub fn lower(&self) -> &[f64] {
        &self.lower
    }
    pub fn coefficients(&self) -> &[f64] {
        &self.coefficients
    }
    pub fn coefficients_mut(&mut self) -> &mut [f64] {
        &mut self.coefficients
    }
    /// Number of coefficients of a spline with these dimensions.
    pub fn coefficient_count(dim: usize, intervals: usize) -> usize {
        (intervals + 3).saturating_pow(dim as u32)
    }

    #[inline]
    fn stride(&self, axis: usize) -> usize {
        (self.intervals + 3).pow(axis as u32)
    }

    /// Cell base index and per-axis basis values/derivatives (derivatives in `y` units).
    /// Points outside the box are clamped onto it (the model only evaluates inside its
    /// workspace ball, which the box contains).
    #[inline]
    fn locate(
        &self,
        y: &[f64],
        b: &mut [[f64; 4]; MAX_DIM],
        db: &mut [[f64; 4]; MAX_DIM],
    ) -> usize {
        let mut base = 0;
        let mut stride = 1;
        let last = (self.intervals - 1) as f64;
        for i in 0..self.dim {
            let x = (y[i] - self.lower[i]) / self.spacing[i];
            let cell = x.floor().clamp(0.0, last);
            let u = (x - cell).clamp(0.0, 1.0);
            let (bv, dv) = basis(u);
            b[i] = bv;
            for a in 0..4 {
                db[i][a] = dv[a] / self.spacing[i];
            }
            base += cell as usize * stride;
            stride *= self.intervals + 3;
        }
        base
    }

    /// `s(y)` and `∇s(y)` (into `grad[..dim]`); allocation-free. Contracts the 4^d local
    /// coefficients one axis at a time (axis 0 first: its four coefficients are contiguous),
    /// carrying the value and the partial derivatives of the axes already contracted.
    pub fn value_gradient(&self, y: &[f64], grad: &mut [f64]) -> f64 {
        let mut b = [[0.0; 4]; MAX_DIM];
        let mut db = [[0.0; 4]; MAX_DIM];
        let base = self.locate(y, &mut b, &mut db);
        let d = self.dim;
        let per_axis = self.intervals + 3;
        // level 1: contract axis 0 straight from the coefficient array
        let mut lvl = [[0.0f64; MAX_DIM + 1]; 256];
        let groups = 1usize << (2 * (d - 1));
        let mut digit = [0usize; MAX_DIM];
        for entry in lvl.iter_mut().take(groups) {
            let mut off = base;
            let mut stride = per_axis;
            for i in 1..d {
                off += digit[i] * stride;
                stride *= per_axis;
            }
            let c = &self.coefficients[off..off + 4];
            entry[0] = c[0] * b[0][0] + c[1] * b[0][1] + c[2] * b[0][2] + c[3] * b[0][3];
            entry[1] = c[0] * db[0][0] + c[1] * db[0][1] + c[2] * db[0][2] + c[3] * db[0][3];
            for dg in digit.iter_mut().take(d).skip(1) {
                *dg += 1;
                if *dg < 4 {
                    break;
                }
                *dg = 0;
            }
        }
        // levels 2..d: contract groups of four consecutive entries along the next axis
        let mut len = groups;
        for axis in 1..d {
            len /= 4;
            for m in 0..len {
                let mut out = [0.0f64; MAX_DIM + 1];
                for a in 0..4 {
                    let e = &lvl[4 * m + a];
                    let w = b[axis][a];
                    // channel 0 value, channel 1 + i the derivative along axis i (< axis)
                    out[0] += e[0] * w;
                    for ch in 1..=axis {
                        out[ch] += e[ch] * w;
                    }
                    out[axis + 1] += e[0] * db[axis][a];
                }
                lvl[m] = out;
            }
        }
        grad[..d].copy_from_slice(&lvl[0][1..=d]);
        lvl[0][0]
    }

    /// `s(y)` only.
    pub fn value(&self, y: &[f64]) -> f64 {
        let mut g = [0.0; MAX_DIM];
        self.value_gradient(y, &mut g)
    }

    /// The 4^d basis functions supported at `y`: indices, values and gradients (for fitting).
    pub(crate) fn local(&self, y: &[f64], out: &mut Local) {
        let mut b = [[0.0; 4]; MAX_DIM];
        let mut db = [[0.0; 4]; MAX_DIM];
        let base = self.locate(y, &mut b, &mut db);
        let d = self.dim;
        let mut digit = [0usize; MAX_DIM];
        let total = 1usize << (2 * d);
        out.n = total;
        for m in 0..total {
            let mut offset = base;
            let mut w = 1.0;
            for i in 0..d {
                offset += digit[i] * self.stride(i);
                w *= b[i][digit[i]];
            }
            out.index[m] = offset;
            out.weight[m] = w;
            for k in 0..d {
                let mut p = db[k][digit[k]];
                for i in 0..d {
                    if i != k {
                        p *= b[i][digit[i]];
                    }
                }
                out.grad[m][k] = p;
            }
            for dg in digit.iter_mut().take(d) {
                *dg += 1;
                if *dg < 4 {
                    break;
                }
                *dg = 0;
            }
        }
    }

    /// Per-axis bound `D_i = max_j |c_{j+e_i} − c_j| / h_i` on `|∂s/∂y_i|` anywhere: the
    /// derivative of a cubic B-spline is a quadratic B-spline whose coefficients are the
    /// coefficient differences over the spacing, and B-spline bases are non-negative and sum
    /// to one, so the derivative lies within those differences.
    pub fn derivative_bounds(&self, out: &mut [f64]) {
        let n = self.intervals + 3;
        for (axis, o) in out.iter_mut().enumerate().take(self.dim) {
            let stride = self.stride(axis);
            let mut m: f64 = 0.0;
            for j in 0..self.coefficients.len() {
                if (j / stride) % n + 1 < n {
                    m = m.max((self.coefficients[j + stride] - self.coefficients[j]).abs());
                }
            }
            *o = m / self.spacing[axis];
        }
    }

    /// `sqrt(Σ_i D_i²)`: a bound on `‖∇s‖` over the whole box.
    pub fn gradient_norm_bound(&self) -> f64 {
        let mut d = [0.0; MAX_DIM];
        self.derivative_bounds(&mut d);
        d[..self.dim].iter().map(|x| x * x).sum::<f64>().sqrt()
    }

    /// The same function on a grid with half the spacing (knot insertion by uniform cubic
    /// subdivision, per axis: vertex points `(c_{j-1} + 6c_j + c_{j+1})/8`, edge points
    /// `(c_j + c_{j+1})/2`). Refined coefficient differences hug the derivative more closely,
    /// which tightens [`Self::radial_bound`] without changing `s`.
    pub fn refined(&self) -> TensorBSpline {
        let d = self.dim;
        let n_old = self.intervals + 3;
        let n_new = 2 * self.intervals + 3;
        let mut coeffs = self.coefficients.clone();
        // refine one axis at a time; `sizes` tracks the current per-axis coefficient counts
        let mut sizes = [n_old; MAX_DIM];
        for axis in 0..d {
            let mut new_sizes = sizes;
            new_sizes[axis] = n_new;
            let total: usize = new_sizes[..d].iter().product();
            let mut out = vec![0.0; total];
            let stride_old: usize = sizes[..axis].iter().product();
            let stride_new = stride_old; // axes below `axis` keep their sizes
            let outer: usize = sizes[axis + 1..d].iter().product();
            for o in 0..outer {
                for inner in 0..stride_old {
                    let base_old = o * stride_old * n_old + inner;
                    let base_new = o * stride_new * n_new + inner;
                    let c = |j: usize| coeffs[base_old + j * stride_old];
                    for m in 0..n_new {
                        let v = if m % 2 == 0 {
                            let j = m / 2;
                            0.5 * (c(j) + c(j + 1))
                        } else {
                            let j = m.div_ceil(2);
                            (c(j - 1) + 6.0 * c(j) + c(j + 1)) / 8.0
                        };
                        out[base_new + m * stride_new] = v;
                    }
                }
            }
            coeffs = out;
            sizes = new_sizes;
        }
        TensorBSpline {
            dim: d,
            intervals: 2 * self.intervals,
            lower: self.lower.clone(),
            spacing: self.spacing.iter().map(|h| h / 2.0).collect(),
            coefficients: coeffs,
        }
    }

    /// Closed-form bound on `sup (y − y_d)·∇s(y)` over `y` in the workspace ball
    /// `(center, radius)` and `y_d` in the goal ball `(goal_center, goal_radius)`. For fixed `y`
    /// the sup over `y_d` is `(y − g)·∇s + r_g‖∇s‖`, `g` the goal centre. Per knot cell, `∂_i s` lies between the smallest and largest
    /// coefficient difference along axis `i` among the cell's 4^d coefficients (over `h_i`; the
    /// derivative is a convex combination of them), and `y_i − c_i` within the cell's extent, so
    /// each term is bounded by the extreme corner products. Cells outside the ball are skipped.
    pub fn radial_bound(
        &self,
        center: &[f64],
        radius: f64,
        goal_center: &[f64],
        goal_radius: f64,
    ) -> f64 {
        let d = self.dim;
        let n = self.intervals;
        let mut cell = [0usize; MAX_DIM];
        let cells = n.pow(d as u32);
        let mut strides = [0usize; MAX_DIM];
        for (i, s) in strides.iter_mut().enumerate().take(d) {
            *s = self.stride(i);
        }
        let mut best = f64::NEG_INFINITY;
        for _ in 0..cells {
            let mut base = 0;
            let mut min_dist2 = 0.0;
            let mut a = [0.0; MAX_DIM];
            let mut b = [0.0; MAX_DIM];
            for i in 0..d {
                base += cell[i] * strides[i];
                let lo_c = self.lower[i] + cell[i] as f64 * self.spacing[i] - center[i];
                let hi_c = lo_c + self.spacing[i];
                if lo_c > 0.0 {
                    min_dist2 += lo_c * lo_c;
                } else if hi_c < 0.0 {
                    min_dist2 += hi_c * hi_c;
                }
                a[i] = self.lower[i] + cell[i] as f64 * self.spacing[i] - goal_center[i];
                b[i] = a[i] + self.spacing[i];
            }
            if min_dist2 < radius * radius {
                let mut lo = [f64::INFINITY; MAX_DIM];
                let mut hi = [f64::NEG_INFINITY; MAX_DIM];
                let mut digit = [0usize; MAX_DIM];
                for _ in 0..(1usize << (2 * d)) {
                    let mut off = base;
                    for i in 0..d {
                        off += digit[i] * strides[i];
                    }
                    for i in 0..d {
                        if digit[i] < 3 {
                            let diff = (self.coefficients[off + strides[i]]
                                - self.coefficients[off])
                                / self.spacing[i];
                            lo[i] = lo[i].min(diff);
                            hi[i] = hi[i].max(diff);
                        }
                    }
                    for dg in digit.iter_mut().take(d) {
                        *dg += 1;
                        if *dg < 4 {
                            break;
                        }
                        *dg = 0;
                    }
                }
                let mut radial = 0.0;
                let mut g2 = 0.0;
                for i in 0..d {
                    radial += (a[i] * lo[i])
                        .max(a[i] * hi[i])
                        .max(b[i] * lo[i])
                        .max(b[i] * hi[i]);
                    g2 += lo[i].abs().max(hi[i].abs()).powi(2);
                }
                best = best.max(radial + goal_radius * g2.sqrt());
            }
            for c in cell.iter_mut().take(d) {
                *c += 1;
                if *c < n {
                    break;
                }
                *c = 0;
            }
        }
        best
    }

    /// Bounds of the derivatives over one knot cell (`cell[i]` in `0..intervals`): the gradient's
    /// components lie in `[grad_lo[i], grad_hi[i]]` and `|∂²s/∂y_i∂y_j| ≤ hess[i][j]` anywhere in
    /// the cell. Same argument as [`Self::derivative_bounds`], restricted to the `4^d`
    /// coefficients that support the cell: the first derivatives are quadratic and the second
    /// (mixed) derivatives linear (bilinear) B-splines in the differenced axes, with the first
    /// (mixed second) coefficient differences over the spacing as coefficients, and non-negative
    /// bases that sum to one keep a spline within its coefficients.
    pub fn cell_bounds(
        &self,
        cell: &[usize],
        grad_lo: &mut [f64],
        grad_hi: &mut [f64],
        hess: &mut [[f64; MAX_DIM]; MAX_DIM],
    ) {
        let d = self.dim;
        let mut strides = [0usize; MAX_DIM];
        let mut base = 0;
        for i in 0..d {
            strides[i] = self.stride(i);
            base += cell[i] * strides[i];
        }
        for i in 0..d {
            grad_lo[i] = f64::INFINITY;
            grad_hi[i] = f64::NEG_INFINITY;
            hess[i][..d].fill(0.0);
        }
        let c = &self.coefficients;
        let mut digit = [0usize; MAX_DIM];
        for _ in 0..(1usize << (2 * d)) {
            let mut off = base;
            for i in 0..d {
                off += digit[i] * strides[i];
            }
            for i in 0..d {
                if digit[i] >= 3 {
                    continue;
                }
                let hi_ = self.spacing[i];
                let diff = (c[off + strides[i]] - c[off]) / hi_;
                grad_lo[i] = grad_lo[i].min(diff);
                grad_hi[i] = grad_hi[i].max(diff);
                if digit[i] < 2 {
                    let s = strides[i];
                    let second = (c[off + 2 * s] - 2.0 * c[off + s] + c[off]) / (hi_ * hi_);
                    hess[i][i] = hess[i][i].max(second.abs());
                }
                for j in i + 1..d {
                    if digit[j] >= 3 {
                        continue;
                    }
                    let (si, sj) = (strides[i], strides[j]);
                    let mixed = (c[off + si + sj] - c[off + si] - c[off + sj] + c[off])
                        / (hi_ * self.spacing[j]);
                    hess[i][j] = hess[i][j].max(mixed.abs());
                    hess[j][i] = hess[i][j];
                }
            }
            for dg in digit.iter_mut().take(d) {
                *dg += 1;
                if *dg < 4 {
                    break;
                }
                *dg = 0;
            }
        }
    }

    /// Multiply every coefficient (shrinks the field).
    pub fn scale(&mut self, factor: f64) {
        self.coefficients.iter_mut().for_each(|c| *c *= factor);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The per-cell bounds contain the gradient and the central-difference Hessian at random
    /// points of random cells.
    #[test]
    fn cell_bounds_contain_the_sampled_derivatives() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for dim in 1..=3 {
            let s = random_spline(dim, &mut rng);
            for _ in 0..10 {
                let cell: Vec<usize> = (0..dim).map(|_| rng.random_range(0..5)).collect();
                let (mut lo, mut hi) = ([0.0; MAX_DIM], [0.0; MAX_DIM]);
                let mut hess = [[0.0; MAX_DIM]; MAX_DIM];
                s.cell_bounds(&cell, &mut lo, &mut hi, &mut hess);
                for _ in 0..200 {
                    let y: Vec<f64> = (0..dim)
                        .map(|i| {
                            let a = s.lower()[i] + cell[i] as f64 * s.spacing()[i];
                            a + rng.random_range(0.001..0.999) * s.spacing()[i]
                        })
                        .collect();
                    let mut g = [0.0; MAX_DIM];
                    s.value_gradient(&y, &mut g);
                    for i in 0..dim {
                        assert!(g[i] >= lo[i] - 1e-12 && g[i] <= hi[i] + 1e-12);
                        for j in 0..dim {
                            let h = 1e-5;
                            let (mut yp, mut ym) = (y.clone(), y.clone());
                            yp[j] += h;
                            ym[j] -= h;
                            let (mut gp, mut gm) = ([0.0; MAX_DIM], [0.0; MAX_DIM]);
                            s.value_gradient(&yp, &mut gp);
                            s.value_gradient(&ym, &mut gm);
                            let second = (gp[i] - gm[i]) / (2.0 * h);
                            assert!(
                                second.abs() <= hess[i][j] + 1e-6,
                                "∂²s/∂{i}∂{j} = {second} > {}",
                                hess[i][j]
                            );
                        }
                    }
                }
            }
        }
    }

    fn random_spline(dim: usize, rng: &mut ChaCha8Rng) -> TensorBSpline {
        let lower: Vec<f64> = (0..dim).map(|i| -1.0 - 0.3 * i as f64).collect();
        let upper: Vec<f64> = (0..dim).map(|i| 1.5 + 0.2 * i as f64).collect();
        let mut s = TensorBSpline::zeros(&lower, &upper, 5);
        for c in s.coefficients_mut() {
            *c = rng.random_range(-1.0..1.0);
        }
        s
    }

    #[test]
    fn refinement_keeps_the_function_and_tightens_the_bound() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for dim in 1..=3 {
            let s = random_spline(dim, &mut rng);
            let r = s.refined();
            for _ in 0..50 {
                let y: Vec<f64> = (0..dim).map(|_| rng.random_range(-0.9..1.4)).collect();
                let (mut g1, mut g2) = ([0.0; MAX_DIM], [0.0; MAX_DIM]);
                assert!(
                    (s.value_gradient(&y, &mut g1) - r.value_gradient(&y, &mut g2)).abs() < 1e-12
                );
                for k in 0..dim {
                    assert!((g1[k] - g2[k]).abs() < 1e-10);
                }
            }
            let c = vec![0.2; dim];
            let g = vec![0.1; dim];
            assert!(r.radial_bound(&c, 1.0, &g, 0.3) <= s.radial_bound(&c, 1.0, &g, 0.3) + 1e-12);
        }
    }

    #[test]
    fn basis_is_a_partition_of_unity() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for dim in 1..=4 {
            let mut s = random_spline(dim, &mut rng);
            s.coefficients_mut().iter_mut().for_each(|c| *c = 1.0);
            let mut local = Local::new();
            for _ in 0..50 {
                let y: Vec<f64> = (0..dim).map(|_| rng.random_range(-1.0..1.5)).collect();
                let mut g = [0.0; MAX_DIM];
                assert!((s.value_gradient(&y, &mut g) - 1.0).abs() < 1e-12);
                assert!(g[..dim].iter().all(|x| x.abs() < 1e-10));
                s.local(&y, &mut local);
                let sum: f64 = local.weight[..local.n].iter().sum();
                assert!((sum - 1.0).abs() < 1e-12);
                assert!(local.weight[..local.n].iter().all(|w| *w >= 0.0));
            }
        }
    }

    #[test]
    fn gradient_matches_central_differences_and_local_support() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for dim in 1..=4 {
            let s = random_spline(dim, &mut rng);
            let mut local = Local::new();
            for _ in 0..30 {
                let y: Vec<f64> = (0..dim).map(|_| rng.random_range(-0.9..1.4)).collect();
                let mut g = [0.0; MAX_DIM];
                let v = s.value_gradient(&y, &mut g);
                let h = 1e-6;
                for k in 0..dim {
                    let mut yp = y.clone();
                    let mut ym = y.clone();
                    yp[k] += h;
                    ym[k] -= h;
                    let fd = (s.value(&yp) - s.value(&ym)) / (2.0 * h);
                    assert!(
                        (fd - g[k]).abs() < 1e-6 * (1.0 + fd.abs()),
                        "{fd} vs {}",
                        g[k]
                    );
                }
                // the sparse design rows reproduce value and gradient
                s.local(&y, &mut local);
                let mut v2 = 0.0;
                let mut g2 = [0.0; MAX_DIM];
                for m in 0..local.n {
                    let c = s.coefficients()[local.index[m]];
                    v2 += c * local.weight[m];
                    for k in 0..dim {
                        g2[k] += c * local.grad[m][k];
                    }
                }
                assert!((v - v2).abs() < 1e-12);
                for k in 0..dim {
                    assert!((g[k] - g2[k]).abs() < 1e-10);
                }
                // the coefficient-difference bound holds
                let mut d = [0.0; MAX_DIM];
                s.derivative_bounds(&mut d);
                for k in 0..dim {
                    assert!(g[k].abs() <= d[k] + 1e-12);
                }
            }
        }
    }
}
