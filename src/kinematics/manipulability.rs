//! Velocity/force ellipsoids of a Jacobian (paper eq. 10-15).
//!
//! All functions take any Jacobian (or a row block of one, e.g. `j.fixed_rows::<3>(0)` for the
//! translational part) with a compile-time row count, so `J Jᵀ` lives on the stack: nothing here
//! allocates.

use nalgebra::allocator::Allocator;
use nalgebra::{
    DefaultAllocator, Dim, DimMin, DimName, DimSub, Matrix, OMatrix, OVector, RawStorage, U1,
};

/// `J Jᵀ`, accumulated column by column (rank-1 updates), so no transposed copy is allocated.
pub fn jjt<R, C, S>(j: &Matrix<f64, R, C, S>) -> OMatrix<f64, R, R>
where
    R: DimName,
    C: Dim,
    S: RawStorage<f64, R, C>,
    DefaultAllocator: Allocator<R, R>,
{
    let mut m = OMatrix::<f64, R, R>::zeros();
    for c in 0..j.ncols() {
        let col = j.column(c);
        m.ger(1.0, &col, &col, 1.0);
    }
    m
}

/// Yoshikawa's manipulability measure, eq. 12: `sqrt(det(J Jᵀ))` (0 at singularities and when
/// the Jacobian has fewer columns than rows).
pub fn manipulability<R, C, S>(j: &Matrix<f64, R, C, S>) -> f64
where
    R: DimName + DimMin<R, Output = R>,
    C: Dim,
    S: RawStorage<f64, R, C>,
    DefaultAllocator: Allocator<R, R> + Allocator<R>,
{
    jjt(j).determinant().max(0.0).sqrt()
}

/// Principal axes of the velocity ellipsoid `ẋᵀ (J Jᵀ)⁻¹ ẋ ≤ 1` (eq. 10), longest first. The force
/// ellipsoid (eq. 11) has the same directions with reciprocal semi-axes.
#[derive(Clone, Debug)]
pub struct Ellipsoid<R: DimName>
where
    DefaultAllocator: Allocator<R, R> + Allocator<R>,
{
    /// Velocity semi-axes `σ_i` (singular values of J), descending.
    pub semi_axes: OVector<f64, R>,
    /// Unit axis directions as columns, matching `semi_axes`.
    pub directions: OMatrix<f64, R, R>,
}

pub fn velocity_ellipsoid<R, C, S>(j: &Matrix<f64, R, C, S>) -> Ellipsoid<R>
where
    R: DimName + DimSub<U1>,
    C: Dim,
    S: RawStorage<f64, R, C>,
    DefaultAllocator: Allocator<R, R> + Allocator<R> + Allocator<<R as DimSub<U1>>::Output>,
{
    ellipsoid_of_jjt(&jjt(j))
}

/// [`velocity_ellipsoid`] from `M = J Jᵀ` already formed (a hand-object Jacobian's `M`, say).
pub fn ellipsoid_of_jjt<R>(m: &OMatrix<f64, R, R>) -> Ellipsoid<R>
where
    R: DimName + DimSub<U1>,
    DefaultAllocator: Allocator<R, R> + Allocator<R> + Allocator<<R as DimSub<U1>>::Output>,
{
    let eig = m.clone().symmetric_eigen();
    let n = R::dim();
    // Sort descending with a fixed-size selection sort (n ≤ 6): no allocation.
    let mut semi_axes = OVector::<f64, R>::zeros();
    let mut directions = OMatrix::<f64, R, R>::zeros();
    let mut used = [false; 16];
    for slot in 0..n {
        let mut best = usize::MAX;
        for (k, &u) in used.iter().enumerate().take(n) {
            if !u && (best == usize::MAX || eig.eigenvalues[k] > eig.eigenvalues[best]) {
                best = k;
            }
        }
        used[best] = true;
        semi_axes[slot] = eig.eigenvalues[best].max(0.0).sqrt();
        directions.set_column(slot, &eig.eigenvectors.column(best));
    }
    Ellipsoid {
        semi_axes,
        directions,
    }
}

/// Force transmission ratio along unit direction `d`, eq. 14: `α = [dᵀ (J Jᵀ) d]^{-1/2}`
/// (infinite when `J` cannot transmit motion along `d` at all).
pub fn force_transmission_ratio<R, C, S>(j: &Matrix<f64, R, C, S>, d: &OVector<f64, R>) -> f64
where
    R: DimName,
    C: Dim,
    S: RawStorage<f64, R, C>,
    DefaultAllocator: Allocator<R, R> + Allocator<R>,
{
    force_ratio_of_jjt(&jjt(j), d, 0.0)
}

/// Eq. 14 from `M = J Jᵀ`. With `floor > 0`, `dᵀ M d` is raised to `floor` first, which keeps
/// the ratio finite (≤ floor^{-1/2}) where `J` cannot move along `d`: the regularised form an
/// optimiser needs (the grasp indexes use it); `floor = 0` is the exact ratio.
pub fn force_ratio_of_jjt<R>(m: &OMatrix<f64, R, R>, d: &OVector<f64, R>, floor: f64) -> f64
where
    R: DimName,
    DefaultAllocator: Allocator<R, R> + Allocator<R>,
{
    let d = d.normalize();
    let q = (m * &d).dot(&d).max(floor);
    if q > 0.0 {
        1.0 / q.sqrt()
    } else {
        f64::INFINITY
    }
}

/// Velocity transmission ratio along unit direction `d`, eq. 15: `β = [dᵀ (J Jᵀ)⁻¹ d]^{-1/2}`,
/// through the eigen-decomposition so a singular `J Jᵀ` gives 0 along directions it cannot move
/// in instead of a failed inverse.
pub fn velocity_transmission_ratio<R, C, S>(j: &Matrix<f64, R, C, S>, d: &OVector<f64, R>) -> f64
where
    R: DimName + DimSub<U1>,
    C: Dim,
    S: RawStorage<f64, R, C>,
    DefaultAllocator: Allocator<R, R> + Allocator<R> + Allocator<<R as DimSub<U1>>::Output>,
{
    velocity_ratio_of_jjt(&jjt(j), d, 0.0)
}

/// Eq. 15 from `M = J Jᵀ`. With `floor > 0`, eigenvalues of `M` are raised to `floor` before
/// inverting (`M⁻¹ ≈ Σ v vᵀ / max(λ, floor)`), so the ratio is smooth and about `√floor` along
/// directions `J` cannot move in (the regularised form of the grasp indexes); with `floor = 0`
/// it is exact and 0 along such directions.
pub fn velocity_ratio_of_jjt<R>(m: &OMatrix<f64, R, R>, d: &OVector<f64, R>, floor: f64) -> f64
where
    R: DimName + DimSub<U1>,
    DefaultAllocator: Allocator<R, R> + Allocator<R> + Allocator<<R as DimSub<U1>>::Output>,
{
    let d = d.normalize();
    let eig = m.clone().symmetric_eigen();
    let scale = eig.eigenvalues.amax().max(f64::MIN_POSITIVE);
    let mut q = 0.0;
    for k in 0..R::dim() {
        let c = eig.eigenvectors.column(k).dot(&d);
        let lambda = eig.eigenvalues[k];
        if floor > 0.0 {
            q += c * c / lambda.max(floor);
        } else if lambda <= 1e-14 * scale {
            if c.abs() > 1e-9 {
                return 0.0;
            }
        } else {
            q += c * c / lambda;
        }
    }
    if q > 0.0 {
        1.0 / q.sqrt()
    } else {
        f64::INFINITY
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::algorithms::tests::planar_2r;
    use crate::kinematics::{Data, forward_kinematics, frame_jacobian};
    use nalgebra::{Matrix6xX, Vector2, Vector3, Vector6};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn planar_2r_manipulability_is_l1_l2_abs_sin_q2() {
        let (l1, l2) = (0.8, 0.5);
        let model = planar_2r(l1, l2);
        let tip = model.frame_id("tip").unwrap();
        let mut data = Data::new(&model);
        let mut j = Matrix6xX::zeros(2);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..100 {
            let q: [f64; 2] = [rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0)];
            forward_kinematics(&model, &mut data, &q);
            frame_jacobian(&model, &data, tip, &Vector3::zeros(), &mut j);
            let planar = j.fixed_rows::<2>(0);
            let w = manipulability(&planar);
            assert!((w - l1 * l2 * q[1].sin().abs()).abs() < 1e-12, "{w}");
            // Product of the ellipsoid semi-axes is the same volume measure.
            let e = velocity_ellipsoid(&planar);
            assert!((e.semi_axes[0] * e.semi_axes[1] - w).abs() < 1e-10);
            assert!(e.semi_axes[0] >= e.semi_axes[1]);
        }
        // Fully stretched: singular.
        forward_kinematics(&model, &mut data, &[0.4, 0.0]);
        frame_jacobian(&model, &data, tip, &Vector3::zeros(), &mut j);
        assert!(manipulability(&j.fixed_rows::<2>(0)) < 1e-15);
        // Along the arm the tip cannot move: zero velocity ratio, unbounded force ratio.
        let along = Vector2::new(0.4f64.cos(), 0.4f64.sin());
        assert_eq!(
            velocity_transmission_ratio(&j.fixed_rows::<2>(0), &along),
            0.0
        );
        assert!(force_transmission_ratio(&j.fixed_rows::<2>(0), &along) > 1e6);
    }

    #[test]
    fn transmission_ratios_match_the_ellipsoid_and_the_explicit_inverse() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for _ in 0..50 {
            let j = Matrix6xX::from_fn(7, |_, _| rng.random_range(-1.0..1.0));
            let m = jjt(&j);
            let minv = m.try_inverse().unwrap();
            let d = Vector6::from_fn(|_, _| rng.random_range(-1.0..1.0)).normalize();
            let alpha = force_transmission_ratio(&j, &d);
            let beta = velocity_transmission_ratio(&j, &d);
            assert!((alpha - 1.0 / (d.dot(&(m * d))).sqrt()).abs() < 1e-9 * alpha);
            assert!((beta - 1.0 / (d.dot(&(minv * d))).sqrt()).abs() < 1e-9 * beta);
            // Along a principal axis: β = σ_i and α = 1/σ_i (eq. 14-15 on the ellipsoid, eq. 10-11).
            let e = velocity_ellipsoid(&j);
            for k in 0..6 {
                let u: Vector6<f64> = e.directions.column(k).into();
                assert!((velocity_transmission_ratio(&j, &u) - e.semi_axes[k]).abs() < 1e-9);
                assert!((force_transmission_ratio(&j, &u) * e.semi_axes[k] - 1.0).abs() < 1e-9);
            }
            // Manipulability equals the ellipsoid volume measure Π σ_i (eq. 12).
            assert!((manipulability(&j) - e.semi_axes.iter().product::<f64>()).abs() < 1e-9);
        }
    }
}
