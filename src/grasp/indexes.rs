//! Transmission ratios, compatibility indexes and grasp quality measures (paper eq. 10-21).
//! Pure functions on matrices; callers own the buffers. Manipulability, ellipsoids and the
//! ratios themselves are `kinematics::manipulability`'s; this module adds their regularised use
//! (finite at singular configurations), TC/GC and their gradients, the grasp matrix and the
//! quality measures.

use nalgebra::{DMatrix, Matrix3, Matrix3xX, Point3, SymmetricEigen, Vector3};

use crate::kinematics::manipulability::{
    ellipsoid_of_jjt, force_ratio_of_jjt, jjt, velocity_ratio_of_jjt,
};
use serde::{Deserialize, Serialize};

/// What a task direction must transmit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Transmission {
    /// Force transmission ratio α (eq. 14 / 17).
    Force,
    /// Velocity transmission ratio β (eq. 15 / 18).
    Velocity,
}

/// Whether the ratio along the direction is to be made large (fast motion / large force) or
/// small (fine control); the paper notes both are meaningful (§IV, Fig. 6 discussion).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Goal {
    /// Make the ratio large.
    Maximize,
    /// Make the ratio small.
    Minimize,
}

/// A unit task direction (world frame) with its transmission kind and goal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TaskDirection {
    /// Unit vector `d`.
    pub direction: Vector3<f64>,
    /// Force or velocity.
    pub kind: Transmission,
    /// Maximise or minimise.
    pub goal: Goal,
}

impl TaskDirection {
    fn sign(&self) -> f64 {
        match self.goal {
            Goal::Maximize => 1.0,
            Goal::Minimize => -1.0,
        }
    }
}

/// Floor on eigenvalues of `J Jᵀ` when it is inverted: a rank-deficient Jacobian (a hand with
/// fewer independent joints than task coordinates) has zero velocity ratio along unreachable
/// directions; the floor keeps β finite (≈ √floor there) instead of NaN.
pub const EIGEN_FLOOR: f64 = 1e-12;

/// `M = J_v J_vᵀ` for the 3 × n translational block (the kinematics' [`jjt`]).
pub fn transmission_matrix(jv: &Matrix3xX<f64>) -> Matrix3<f64> {
    jjt(jv)
}

/// `M⁻¹` with eigenvalues raised to [`EIGEN_FLOOR`]: the inverse behind the floored velocity
/// ratio, which the TC gradient needs explicitly.
fn inverse_floored(m: &Matrix3<f64>) -> Matrix3<f64> {
    let e = SymmetricEigen::new(*m);
    let mut inv = Matrix3::zeros();
    for k in 0..3 {
        let v = e.eigenvectors.column(k);
        inv += v * v.transpose() / e.eigenvalues[k].max(EIGEN_FLOOR);
    }
    inv
}

/// Force ratio `α = (dᵀ M d)^{-1/2}` (eq. 14, 17) or velocity ratio `β = (dᵀ M⁻¹ d)^{-1/2}`
/// (eq. 15, 18) along unit `d`, with `M = J Jᵀ`: the kinematics' ratios in their regularised
/// form (floored at [`EIGEN_FLOOR`]), so that the indexes stay finite and smooth for the
/// optimiser.
pub fn transmission_ratio(m: &Matrix3<f64>, d: &Vector3<f64>, kind: Transmission) -> f64 {
    match kind {
        Transmission::Force => force_ratio_of_jjt(m, d, EIGEN_FLOOR),
        Transmission::Velocity => velocity_ratio_of_jjt(m, d, EIGEN_FLOOR),
    }
}

/// Compatibility index `Π r_k^{-s_k}` (eq. 16 for the arm, eq. 19 for the hand), `s_k = +1` for
/// a maximised ratio (the paper's definition) and `−1` for a minimised one, so that minimising
/// the index serves every direction's goal. 1 for no directions.
pub fn compatibility_index(m: &Matrix3<f64>, dirs: &[TaskDirection]) -> f64 {
    dirs.iter()
        .map(|t| transmission_ratio(m, &t.direction, t.kind).powf(-t.sign()))
        .product()
}

/// Gradient of [`compatibility_index`] with respect to q, given `J_v` (3 × n) and its partial
/// derivatives `dj[i] = ∂J_v/∂q_i` (3 × n each). Uses `∂(dᵀMd) = 2 (J_vᵀd)·(∂J_vᵀd)` and
/// `∂(dᵀM⁻¹d) = −2 (J_vᵀw)·(∂J_vᵀw)`, `w = M⁻¹d`. Writes into `grad` (length n).
pub fn compatibility_index_gradient(
    jv: &Matrix3xX<f64>,
    dj: &[Matrix3xX<f64>],
    dirs: &[TaskDirection],
    grad: &mut [f64],
) -> f64 {
    let m = transmission_matrix(jv);
    let minv = inverse_floored(&m);
    let tc = compatibility_index(&m, dirs);
    grad.iter_mut().for_each(|g| *g = 0.0);
    for t in dirs {
        let d = &t.direction;
        // ∂ ln r / ∂q_i, r = α or β, then ∂TC = TC · Σ (−s) ∂ln r.
        let (w, denom, factor) = match t.kind {
            Transmission::Force => (*d, d.dot(&(m * d)).max(EIGEN_FLOOR), -1.0),
            Transmission::Velocity => {
                let w = minv * d;
                (w, d.dot(&w), 1.0)
            }
        };
        let jtw = jv.transpose() * w;
        for (i, g) in grad.iter_mut().enumerate() {
            let djtw = dj[i].transpose() * w;
            let dln = factor * jtw.dot(&djtw) / denom;
            *g += tc * (-t.sign()) * dln;
        }
    }
    tc
}

/// Principal axes of the velocity ellipsoid `ẋᵀ M⁻¹ ẋ ≤ 1` (eq. 10) and of the force ellipsoid
/// `fᵀ M f ≤ 1` (eq. 11) for `M = J Jᵀ`. The two share directions with reciprocal lengths.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Ellipsoids {
    /// Unit axis directions (world), sorted by decreasing velocity semi-axis.
    pub axes: [[f64; 3]; 3],
    /// Velocity-ellipsoid semi-axis lengths `√λ_k`.
    pub velocity_semi_axes: [f64; 3],
    /// Force-ellipsoid semi-axis lengths `1/√λ_k`.
    pub force_semi_axes: [f64; 3],
}

impl Ellipsoids {
    /// Axes of `M = J Jᵀ` (the kinematics' [`ellipsoid_of_jjt`], with both sets of lengths).
    pub fn of(m: &Matrix3<f64>) -> Self {
        let e = ellipsoid_of_jjt(m);
        let mut axes = [[0.0; 3]; 3];
        let mut force = [0.0; 3];
        for k in 0..3 {
            let v = e.directions.column(k);
            axes[k] = [v[0], v[1], v[2]];
            force[k] = (e.semi_axes[k] * e.semi_axes[k])
                .max(EIGEN_FLOOR)
                .powf(-0.5);
        }
        Ellipsoids {
            axes,
            velocity_semi_axes: [e.semi_axes[0], e.semi_axes[1], e.semi_axes[2]],
            force_semi_axes: force,
        }
    }

    /// Major axis of the velocity ellipsoid.
    pub fn velocity_major(&self) -> Vector3<f64> {
        Vector3::from(self.axes[0])
    }

    /// Major axis of the force ellipsoid (the velocity ellipsoid's minor axis).
    pub fn force_major(&self) -> Vector3<f64> {
        Vector3::from(self.axes[2])
    }
}

/// Grasp matrix of hard-finger point contacts (6 × 3k): contact `i` maps its contact force
/// `f_i` to the object wrench `[f_i; (c_i − C_G) × f_i]` about the centroid.
pub fn grasp_matrix(contacts: &[Point3<f64>], centroid: &Point3<f64>, out: &mut DMatrix<f64>) {
    let k = contacts.len();
    assert_eq!(
        out.shape(),
        (6, 3 * k),
        "grasp matrix buffer must be 6 x 3k"
    );
    out.fill(0.0);
    for (i, c) in contacts.iter().enumerate() {
        let r = c - centroid;
        for a in 0..3 {
            out[(a, 3 * i + a)] = 1.0;
        }
        let skew = r.cross_matrix();
        out.view_mut((3, 3 * i), (3, 3)).copy_from(&skew);
    }
}

/// Hand-object Jacobian `H = (Gᵀ)⁺ J_h` (6 × n_h): object twist produced by hand joint rates
/// with the contacts sticking. `jh` is 3k × n_h (contact point linear Jacobians, stacked).
pub fn hand_object_jacobian(g: &DMatrix<f64>, jh: &DMatrix<f64>) -> DMatrix<f64> {
    let gt = g.transpose();
    let pinv = gt
        .pseudo_inverse(1e-10)
        .unwrap_or_else(|_| DMatrix::zeros(g.nrows(), g.ncols()));
    pinv * jh
}

/// The translational 3 × n block of `H`, for the hand ratios (eq. 17-18) along 3-D directions.
pub fn translational_block(h: &DMatrix<f64>) -> Matrix3xX<f64> {
    let mut out = Matrix3xX::zeros(h.ncols());
    out.copy_from(&h.rows(0, 3));
    out
}

/// `Q_DC = ‖C_G − C_C‖` (eq. 20), `C_C` the centroid of the contact points.
pub fn q_dc(contacts: &[Point3<f64>], centroid: &Point3<f64>) -> f64 {
    if contacts.is_empty() {
        return 0.0;
    }
    let cc = contacts.iter().fold(Vector3::zeros(), |a, c| a + c.coords) / contacts.len() as f64;
    (centroid.coords - cc).norm()
}

/// Gradient of [`q_dc`] with respect to each contact point (written into `out`, one per
/// contact). Zero where `Q_DC = 0` (a subgradient).
pub fn q_dc_point_gradient(
    contacts: &[Point3<f64>],
    centroid: &Point3<f64>,
    out: &mut [Vector3<f64>],
) -> f64 {
    let k = contacts.len() as f64;
    let cc = contacts.iter().fold(Vector3::zeros(), |a, c| a + c.coords) / k;
    let diff = cc - centroid.coords;
    let q = diff.norm();
    let g = if q > 1e-15 {
        diff / (q * k)
    } else {
        Vector3::zeros()
    };
    out.iter_mut().for_each(|o| *o = g);
    q
}

/// Area of the contact polygon (eq. 21): the triangle for three contacts; for more, the
/// polygon through the contacts in finger order, measured as the norm of its vector area
/// `½‖Σ c_i × c_{i+1}‖` (exact for a planar simple polygon, smooth otherwise). 0 below three.
pub fn q_agp(contacts: &[Point3<f64>]) -> f64 {
    vector_area(contacts).norm()
}

fn vector_area(c: &[Point3<f64>]) -> Vector3<f64> {
    let k = c.len();
    if k < 3 {
        return Vector3::zeros();
    }
    // About the first contact, so that the result does not depend on the world origin.
    let o = c[0].coords;
    let mut v = Vector3::zeros();
    for i in 0..k {
        v += (c[i].coords - o).cross(&(c[(i + 1) % k].coords - o));
    }
    0.5 * v
}

/// Gradient of [`q_agp`] with respect to each contact: `½ û × (c_{i−1} − c_{i+1})`.
pub fn q_agp_point_gradient(contacts: &[Point3<f64>], out: &mut [Vector3<f64>]) -> f64 {
    let k = contacts.len();
    let v = vector_area(contacts);
    let a = v.norm();
    if k < 3 || a < 1e-15 {
        out.iter_mut().for_each(|o| *o = Vector3::zeros());
        return a;
    }
    let u = v / a;
    for i in 0..k {
        let prev = contacts[(i + k - 1) % k].coords;
        let next = contacts[(i + 1) % k].coords;
        out[i] = 0.5 * u.cross(&(prev - next));
    }
    a
}

/// Opposition of the contact normals: the distance from the origin to the convex hull of the
/// unit normals `n_i`, `d = min_{w ≥ 0, Σw = 1} ‖Σ w_i n_i‖`, with the minimising weights
/// written into `w` (one per normal). `d = 0`: positive normal forces can balance each other
/// (an antipodal pair, three fingers around an object); `d = 1`: all normals equal. A frictional
/// grasp cannot balance its contact forces when `d > sin(atan μ)`: the closest point's
/// direction then makes an angle below `90° − atan μ` with every normal, so a plane separates
/// all friction cones from their negatives and closing the hand squeezes the object out.
///
/// The weights say which contacts the imbalance comes from and give the gradient
/// (`∂d/∂n_i = w_i v/‖v‖`, envelope theorem). Hand-rolled rather than parry's GJK, which keeps
/// its simplex to itself, because the sets are a hand's few fingers: in 3-D the closest point
/// of a hull the origin is outside of lies on a vertex, edge or triangle, so every subset of at
/// most three normals is tried and the one whose affine closest point has nonnegative weights
/// and satisfies the optimality condition `v·(n_j − v) ≥ 0` for every `j` is kept. When none
/// does, the origin lies inside the hull: `d = 0` and `w = 0`. Allocates nothing; more than 16
/// normals are refused by a panic (no hand has them).
pub fn normal_balance(normals: &[Vector3<f64>], w: &mut [f64]) -> f64 {
    let m = normals.len();
    assert!(m <= 16 && w.len() == m, "normal_balance: {m} normals");
    w.iter_mut().for_each(|x| *x = 0.0);
    if m == 0 {
        return 0.0;
    }
    const EPS: f64 = 1e-12;
    let optimal = |v: &Vector3<f64>| {
        let vv = v.norm_squared();
        normals.iter().all(|n| v.dot(n) >= vv - 1e-10)
    };
    let mut best: Option<(f64, [usize; 3], [f64; 3], usize)> = None;
    let mut consider = |idx: [usize; 3], wt: [f64; 3], k: usize| {
        let v: Vector3<f64> = (0..k).map(|i| normals[idx[i]] * wt[i]).sum();
        if optimal(&v) {
            let d = v.norm();
            if best.is_none_or(|b| d < b.0 - EPS) {
                best = Some((d, idx, wt, k));
            }
        }
    };
    for a in 0..m {
        consider([a, 0, 0], [1.0, 0.0, 0.0], 1);
        for b in a + 1..m {
            let e = normals[b] - normals[a];
            let ee = e.norm_squared();
            if ee > EPS {
                let t = -normals[a].dot(&e) / ee;
                if t > 0.0 && t < 1.0 {
                    consider([a, b, 0], [1.0 - t, t, 0.0], 2);
                }
            }
            for c in b + 1..m {
                let e2 = normals[c] - normals[a];
                let (g11, g12, g22) = (ee, e.dot(&e2), e2.norm_squared());
                let det = g11 * g22 - g12 * g12;
                if det <= EPS * g11.max(g22).max(1.0) {
                    continue;
                }
                let (r1, r2) = (-normals[a].dot(&e), -normals[a].dot(&e2));
                let s = (r1 * g22 - r2 * g12) / det;
                let t = (r2 * g11 - r1 * g12) / det;
                if s > 0.0 && t > 0.0 && s + t < 1.0 {
                    consider([a, b, c], [1.0 - s - t, s, t], 3);
                }
            }
        }
    }
    match best {
        Some((d, idx, wt, k)) => {
            for i in 0..k {
                w[idx[i]] = wt[i];
            }
            d
        }
        None => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3xX;

    fn dirs(d: Vector3<f64>, kind: Transmission, goal: Goal) -> Vec<TaskDirection> {
        vec![TaskDirection {
            direction: d.normalize(),
            kind,
            goal,
        }]
    }

    #[test]
    fn ratios_of_a_diagonal_jacobian_are_the_closed_forms() {
        // J = diag(a, b, c) (3 × 3): M = diag(a², b², c²); α along x = 1/a, β along x = a.
        let jv = Matrix3xX::from_column_slice(&[2.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]);
        let m = transmission_matrix(&jv);
        let x = Vector3::x();
        assert!((transmission_ratio(&m, &x, Transmission::Force) - 0.5).abs() < 1e-12);
        assert!((transmission_ratio(&m, &x, Transmission::Velocity) - 2.0).abs() < 1e-12);
        // The product α β along any direction of a diagonal M... along an eigenvector it is 1.
        let y = Vector3::y();
        let a = transmission_ratio(&m, &y, Transmission::Force);
        let b = transmission_ratio(&m, &y, Transmission::Velocity);
        assert!((a * b - 1.0).abs() < 1e-12);
        // TC (eq. 16) with one force and one velocity direction: 1/(α_x β_y).
        let tc = compatibility_index(
            &m,
            &[
                TaskDirection {
                    direction: x,
                    kind: Transmission::Force,
                    goal: Goal::Maximize,
                },
                TaskDirection {
                    direction: y,
                    kind: Transmission::Velocity,
                    goal: Goal::Maximize,
                },
            ],
        );
        assert!((tc - 1.0 / (0.5 * 0.5)).abs() < 1e-12);
        let ell = Ellipsoids::of(&m);
        assert!((ell.velocity_major().x.abs() - 1.0).abs() < 1e-12);
        assert!((ell.force_major().y.abs() - 1.0).abs() < 1e-12);
        assert!((ell.velocity_semi_axes[0] - 2.0).abs() < 1e-12);
        assert!((ell.force_semi_axes[2] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn minimised_direction_inverts_its_factor() {
        let jv = Matrix3xX::from_column_slice(&[2.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0]);
        let m = transmission_matrix(&jv);
        let max = compatibility_index(
            &m,
            &dirs(Vector3::x(), Transmission::Velocity, Goal::Maximize),
        );
        let min = compatibility_index(
            &m,
            &dirs(Vector3::x(), Transmission::Velocity, Goal::Minimize),
        );
        assert!((max * min - 1.0).abs() < 1e-12);
    }

    #[test]
    fn compatibility_gradient_matches_finite_differences_on_a_planar_3r_arm() {
        // Planar 3R arm in the x-y plane with unit-ish links; J_v(q) in closed form, ∂J_v/∂q_i
        // by its own closed form, TC gradient against central differences of TC(q).
        let l = [0.4, 0.3, 0.2];
        let jac = |q: &[f64]| {
            let mut j = Matrix3xX::zeros(3);
            for c in 0..3 {
                let (mut sx, mut sy) = (0.0, 0.0);
                let mut ang: f64 = q[..c].iter().sum();
                for k in c..3 {
                    ang += q[k];
                    sx += -l[k] * ang.sin();
                    sy += l[k] * ang.cos();
                }
                j[(0, c)] = sx;
                j[(1, c)] = sy;
                // out-of-plane rows get a small constant so that M is invertible
                j[(2, c)] = 0.1 * (c as f64 + 1.0);
            }
            j
        };
        let q = [0.3, 0.7, -0.4];
        let h = 1e-6;
        let dj: Vec<Matrix3xX<f64>> = (0..3)
            .map(|i| {
                let mut qp = q;
                let mut qm = q;
                qp[i] += h;
                qm[i] -= h;
                (jac(&qp) - jac(&qm)) / (2.0 * h)
            })
            .collect();
        for kind in [Transmission::Force, Transmission::Velocity] {
            for goal in [Goal::Maximize, Goal::Minimize] {
                let d = dirs(Vector3::new(1.0, 0.5, 0.2), kind, goal);
                let mut g = [0.0; 3];
                let tc = compatibility_index_gradient(&jac(&q), &dj, &d, &mut g);
                assert!(
                    (tc - compatibility_index(&transmission_matrix(&jac(&q)), &d)).abs() < 1e-12
                );
                for i in 0..3 {
                    let mut qp = q;
                    let mut qm = q;
                    qp[i] += h;
                    qm[i] -= h;
                    let fd = (compatibility_index(&transmission_matrix(&jac(&qp)), &d)
                        - compatibility_index(&transmission_matrix(&jac(&qm)), &d))
                        / (2.0 * h);
                    assert!(
                        (g[i] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                        "{kind:?} {goal:?} {i}: {} vs {fd}",
                        g[i]
                    );
                }
            }
        }
    }

    #[test]
    fn grasp_matrix_maps_opposing_forces_to_zero_wrench() {
        let c = [Point3::new(0.05, 0.0, 0.0), Point3::new(-0.05, 0.0, 0.0)];
        let mut g = DMatrix::zeros(6, 6);
        grasp_matrix(&c, &Point3::origin(), &mut g);
        // Squeezing forces along the contact line produce no wrench (internal forces).
        let f = nalgebra::DVector::from_vec(vec![-1.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
        assert!((&g * f).norm() < 1e-15);
        // A tangential pair produces a pure torque about z of 2·0.05.
        let f = nalgebra::DVector::from_vec(vec![0.0, 1.0, 0.0, 0.0, -1.0, 0.0]);
        let w = &g * f;
        assert!((w[5] - 0.1).abs() < 1e-15 && w.rows(0, 5).norm() < 1e-15);
    }

    #[test]
    fn hand_object_jacobian_recovers_a_rigid_translation() {
        // Two contacts each driven by one joint along +y with unit gain: moving both joints
        // together translates the object along y; H maps (1, 1) to the twist (0,1,0, 0,0,0).
        let c = [Point3::new(0.05, 0.0, 0.0), Point3::new(-0.05, 0.0, 0.0)];
        let mut g = DMatrix::zeros(6, 6);
        grasp_matrix(&c, &Point3::origin(), &mut g);
        let mut jh = DMatrix::zeros(6, 2);
        jh[(1, 0)] = 1.0;
        jh[(4, 1)] = 1.0;
        let h = hand_object_jacobian(&g, &jh);
        let twist = &h * nalgebra::DVector::from_vec(vec![1.0, 1.0]);
        assert!((twist[1] - 1.0).abs() < 1e-12, "{twist}");
        assert!(twist[0].abs() < 1e-12 && twist[2].abs() < 1e-12);
        assert!(twist.rows(3, 3).norm() < 1e-12);
    }

    #[test]
    fn quality_measures_match_closed_forms_and_their_gradients() {
        let c = [
            Point3::new(0.1, 0.0, 0.0),
            Point3::new(0.0, 0.2, 0.0),
            Point3::new(0.0, 0.0, 0.0),
        ];
        assert!((q_agp(&c) - 0.01).abs() < 1e-15);
        // A unit square as four contacts: area 1 regardless of the origin.
        let sq = [
            Point3::new(1.0, 1.0, 3.0),
            Point3::new(2.0, 1.0, 3.0),
            Point3::new(2.0, 2.0, 3.0),
            Point3::new(1.0, 2.0, 3.0),
        ];
        assert!((q_agp(&sq) - 1.0).abs() < 1e-12);
        let cg = Point3::new(0.0, 0.0, 0.0);
        assert!((q_dc(&c, &cg) - (Vector3::new(0.1, 0.2, 0.0_f64) / 3.0).norm()).abs() < 1e-15);
        let pts = [
            Point3::new(0.1, 0.02, -0.01),
            Point3::new(-0.03, 0.2, 0.05),
            Point3::new(0.01, -0.04, 0.1),
            Point3::new(-0.07, 0.05, 0.02),
        ];
        let mut g_dc = [Vector3::zeros(); 4];
        let mut g_agp = [Vector3::zeros(); 4];
        q_dc_point_gradient(&pts, &cg, &mut g_dc);
        q_agp_point_gradient(&pts, &mut g_agp);
        let h = 1e-7;
        for i in 0..4 {
            for a in 0..3 {
                let mut p = pts;
                let mut m = pts;
                p[i][a] += h;
                m[i][a] -= h;
                let fd_dc = (q_dc(&p, &cg) - q_dc(&m, &cg)) / (2.0 * h);
                let fd_agp = (q_agp(&p) - q_agp(&m)) / (2.0 * h);
                assert!((g_dc[i][a] - fd_dc).abs() < 1e-7);
                assert!((g_agp[i][a] - fd_agp).abs() < 1e-7);
            }
        }
    }

    fn unit(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z).normalize()
    }

    /// A second method: projected gradient on the simplex (sort-based Euclidean projection),
    /// run to convergence.
    fn hull_distance_by_projected_gradient(n: &[Vector3<f64>]) -> f64 {
        let m = n.len();
        let mut w = vec![1.0 / m as f64; m];
        let step = 1.0 / (2.0 * m as f64);
        for _ in 0..200_000 {
            let v: Vector3<f64> = n.iter().zip(&w).map(|(ni, wi)| ni * *wi).sum();
            let mut y: Vec<f64> = w
                .iter()
                .zip(n)
                .map(|(wi, ni)| wi - step * 2.0 * ni.dot(&v))
                .collect();
            let mut s = y.clone();
            s.sort_by(|a, b| b.total_cmp(a));
            let (mut acc, mut theta) = (0.0, 0.0);
            for (k, sk) in s.iter().enumerate() {
                acc += sk;
                let t = (acc - 1.0) / (k + 1) as f64;
                if sk - t > 0.0 {
                    theta = t;
                }
            }
            y.iter_mut().for_each(|x| *x = (*x - theta).max(0.0));
            w = y;
        }
        n.iter()
            .zip(&w)
            .map(|(ni, wi)| ni * *wi)
            .sum::<Vector3<f64>>()
            .norm()
    }

    #[test]
    fn normal_balance_matches_closed_forms() {
        let mut w = [0.0; 4];
        // Two unit normals at angle θ: the hull is their chord, closest at its midpoint, cos(θ/2).
        for deg in [0.0_f64, 30.0, 90.0, 150.0, 179.0, 180.0] {
            let t = deg.to_radians();
            let n = [Vector3::x(), Vector3::new(t.cos(), t.sin(), 0.0)];
            let d = normal_balance(&n, &mut w[..2]);
            assert!((d - (t / 2.0).cos().abs()).abs() < 1e-12, "{deg}: {d}");
            if deg > 0.0 {
                assert!(
                    (w[0] - 0.5).abs() < 1e-9 && (w[1] - 0.5).abs() < 1e-9,
                    "{w:?}"
                );
            }
        }
        // Three normals 120° apart in a plane: their triangle holds the origin.
        let n: Vec<_> = (0..3)
            .map(|k| {
                let a = k as f64 * 2.0 * std::f64::consts::PI / 3.0;
                Vector3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        assert!(normal_balance(&n, &mut w[..3]) < 1e-12);
        // The same three tilted by φ out of the plane: closest point on the axis, at sin φ.
        let phi = 0.4_f64;
        let tilted: Vec<_> = n
            .iter()
            .map(|v| v * phi.cos() + Vector3::z() * phi.sin())
            .collect();
        let d = normal_balance(&tilted, &mut w[..3]);
        assert!((d - phi.sin()).abs() < 1e-12, "{d}");
        // A tetrahedron's vertex directions: the origin is inside the hull.
        let tet = [
            unit(1.0, 1.0, 1.0),
            unit(1.0, -1.0, -1.0),
            unit(-1.0, 1.0, -1.0),
            unit(-1.0, -1.0, 1.0),
        ];
        assert_eq!(normal_balance(&tet, &mut w), 0.0);
        // Three fingers on one side, a thumb not quite opposite (the OB4F's shape of grasp).
        let hand = [
            unit(1.0, 0.0, 0.1),
            unit(1.0, 0.1, 0.0),
            unit(1.0, -0.1, 0.0),
            unit(-1.0, 0.0, 0.0),
        ];
        assert!(normal_balance(&hand, &mut w) < 0.1);
    }

    #[test]
    fn normal_balance_agrees_with_projected_gradient_and_its_gradient_with_differences() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut w = [0.0; 5];
        let mut w2 = [0.0; 5];
        for case in 0..40 {
            let m = 2 + case % 4;
            // Normals in a cap of random width about a random axis, from balanced to one-sided.
            let axis = unit(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let spread = rng.random_range(0.2..2.5);
            let n: Vec<Vector3<f64>> = (0..m)
                .map(|_| {
                    let r = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    );
                    (axis + r * spread).normalize()
                })
                .collect();
            let d = normal_balance(&n, &mut w[..m]);
            let reference = hull_distance_by_projected_gradient(&n);
            assert!(
                (d - reference).abs() < 1e-6,
                "case {case}: {d} vs {reference}"
            );
            assert!((w[..m].iter().sum::<f64>() - 1.0).abs() < 1e-9 || d == 0.0);
            if d < 1e-6 {
                continue;
            }
            // ∂d/∂n_i = w_i v/‖v‖ against central differences of d in each coordinate.
            let v: Vector3<f64> = n.iter().zip(&w[..m]).map(|(ni, wi)| ni * *wi).sum();
            let h = 1e-7;
            for i in 0..m {
                for a in 0..3 {
                    let (mut np, mut nm) = (n.clone(), n.clone());
                    np[i][a] += h;
                    nm[i][a] -= h;
                    let fd = (normal_balance(&np, &mut w2[..m])
                        - normal_balance(&nm, &mut w2[..m]))
                        / (2.0 * h);
                    let g = w[i] * v[a] / d;
                    assert!(
                        (g - fd).abs() < 1e-5,
                        "case {case} n[{i}][{a}]: {g} vs {fd}"
                    );
                }
            }
        }
    }
}
