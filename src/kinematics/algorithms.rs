//! Free-function algorithms over `(model, data, inputs…, out)` (Pinocchio's argument order):
//! compute every frame placement once with [`forward_kinematics`], then extract Jacobians cheaply.
//! Nothing here allocates.

use nalgebra::{Isometry3, Matrix6xX, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};

use super::model::{FrameId, Model, Step};
use super::sincos::sin_cos;

/// Per-worker scratch: one per thread, reused across calls. Holds the world placement of every
/// frame after [`forward_kinematics`].
#[derive(Clone, Debug)]
pub struct Data {
    placements: Vec<Isometry3<f64>>,
}

impl Data {
    pub fn new(model: &Model) -> Self {
        Self {
            placements: vec![Isometry3::identity(); model.n_frames()],
        }
    }
    /// World placement of `id` as of the last [`forward_kinematics`] call.
    pub fn frame(&self, id: FrameId) -> &Isometry3<f64> {
        &self.placements[id.0]
    }
    /// All world placements, indexed by `FrameId.0`.
    pub fn frames(&self) -> &[Isometry3<f64>] {
        &self.placements
    }
    /// The placements of `other` (built for the same model), without allocating.
    pub fn copy_from(&mut self, other: &Data) {
        self.placements.copy_from_slice(&other.placements);
    }
}

/// Places every frame in the world (the root frame is the world origin).
///
/// `q` holds the independent coordinates in [`Model::joint_names`] order; mimic joints take
/// `multiplier * q[driver] + offset`. Panics if `q.len() != model.nq()` or `data` was built for
/// another model (a programming error; validate input with `JointVector` at the edge).
pub fn forward_kinematics(model: &Model, data: &mut Data, q: &[f64]) {
    assert_eq!(q.len(), model.nq(), "q has the wrong length for this model");
    let n = model.n_frames();
    assert_eq!(data.placements.len(), n, "Data built for another model");
    let (parents, origins, steps) = (&model.parents[..n], &model.origins[..n], &model.steps[..n]);
    let x = &mut data.placements[..n];
    x[0] = Isometry3::identity();
    for i in 1..n {
        let o = &origins[i];
        // X_i = X_parent · origin · motion(q), with origin · motion formed directly: a rotation
        // about z is a quaternion (cos θ/2, 0, 0, sin θ/2), whose product costs 8 multiplies.
        let (rot, t_local) = match steps[i] {
            Step::Fixed => (o.rotation, o.translation.vector),
            Step::RevoluteZ {
                q_index,
                multiplier,
                offset,
            } => {
                let (s, c) = sin_cos(0.5 * (multiplier * q[q_index] + offset));
                let r = o.rotation.quaternion();
                let (w, v) = (r.w, &r.coords);
                let local = Quaternion::new(
                    w * c - v.z * s,
                    v.x * c + v.y * s,
                    v.y * c - v.x * s,
                    v.z * c + w * s,
                );
                (UnitQuaternion::new_unchecked(local), o.translation.vector)
            }
            Step::Revolute {
                axis,
                q_index,
                multiplier,
                offset,
            } => {
                let (s, c) = sin_cos(0.5 * (multiplier * q[q_index] + offset));
                let m = UnitQuaternion::new_unchecked(Quaternion::new(
                    c,
                    s * axis.x,
                    s * axis.y,
                    s * axis.z,
                ));
                (o.rotation * m, o.translation.vector)
            }
            Step::Prismatic {
                axis_in_parent,
                q_index,
                multiplier,
                offset,
            } => {
                let d = multiplier * q[q_index] + offset;
                (o.rotation, o.translation.vector + axis_in_parent * d)
            }
        };
        let p = x[parents[i]];
        x[i] = Isometry3::from_parts(
            Translation3::from(p.translation.vector + p.rotation * t_local),
            p.rotation * rot,
        );
    }
}

/// The z axis of a unit quaternion's rotation (third column of its matrix).
#[inline]
fn z_axis(r: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = (r.w, &r.coords);
    Vector3::new(
        2.0 * (v.x * v.z + w * v.y),
        2.0 * (v.y * v.z - w * v.x),
        1.0 - 2.0 * (v.x * v.x + v.y * v.y),
    )
}

/// Geometric Jacobian of the point `point_in_frame` (coordinates in `frame`) rigidly attached to
/// `frame`, expressed in the WORLD frame: `[v; ω] = J q̇`, rows 0..3 the linear velocity of the
/// point, rows 3..6 the angular velocity of the frame. Columns follow `q`; a mimic joint's column
/// is added into its driver's column scaled by the multiplier (∂value/∂q_driver).
///
/// Requires a prior [`forward_kinematics`] at the same `q`. `out` must be 6 × `model.nq()`.
pub fn frame_jacobian(
    model: &Model,
    data: &Data,
    frame: FrameId,
    point_in_frame: &Vector3<f64>,
    out: &mut Matrix6xX<f64>,
) {
    assert_eq!(out.ncols(), model.nq(), "Jacobian buffer must be 6 x nq");
    let x = &data.placements[..];
    let o = out.as_mut_slice();
    o.fill(0.0);
    let p = (x[frame.0] * Point3::from(*point_in_frame)).coords;
    let mut i = frame.0;
    // Columns are contiguous (column-major 6 × nq): column k is o[6k..6k + 6].
    let mut add = |k: usize, m: f64, v: &Vector3<f64>, a: &Vector3<f64>| {
        let col = &mut o[6 * k..6 * k + 6];
        col[0] += m * v.x;
        col[1] += m * v.y;
        col[2] += m * v.z;
        col[3] += m * a.x;
        col[4] += m * a.y;
        col[5] += m * a.z;
    };
    while i != usize::MAX {
        match model.steps[i] {
            Step::Fixed => {}
            // The joint axis is invariant under its own rotation, so the child frame's rotation
            // maps it to the world; the child origin lies on the axis.
            Step::RevoluteZ {
                q_index,
                multiplier,
                ..
            } => {
                let a = z_axis(&x[i].rotation);
                let v = a.cross(&(p - x[i].translation.vector));
                add(q_index, multiplier, &v, &a);
            }
            Step::Revolute {
                axis,
                q_index,
                multiplier,
                ..
            } => {
                let a = x[i].rotation * axis;
                let v = a.cross(&(p - x[i].translation.vector));
                add(q_index, multiplier, &v, &a);
            }
            Step::Prismatic {
                axis_in_parent,
                q_index,
                multiplier,
                ..
            } => {
                // The parent's rotation times the axis in the parent frame.
                let a = x[model.parents[i]].rotation * axis_in_parent;
                add(q_index, multiplier, &a, &Vector3::zeros());
            }
        }
        i = model.parents[i];
    }
}

/// `grad += J_v(frame, point)ᵀ · v`: the linear rows of [`frame_jacobian`] transposed and applied
/// to a world vector, accumulated into `grad` (length `model.nq()`) without forming the 6 × nq
/// matrix. This is what a gradient of a function of one world point needs (constraint and cost
/// gradients of many points), at the cost of one pass up the chain. For a revolute column,
/// `(a × (p − o)) · v = a · ((p − o) × v)`.
///
/// Requires a prior [`forward_kinematics`]. Panics if `grad.len() != model.nq()`.
pub fn add_point_jacobian_transpose(
    model: &Model,
    data: &Data,
    frame: FrameId,
    point_in_frame: &Vector3<f64>,
    v: &Vector3<f64>,
    grad: &mut [f64],
) {
    assert_eq!(
        grad.len(),
        model.nq(),
        "gradient buffer must have length nq"
    );
    let x = &data.placements[..];
    let p = (x[frame.0] * Point3::from(*point_in_frame)).coords;
    let mut i = frame.0;
    while i != usize::MAX {
        match model.steps[i] {
            Step::Fixed => {}
            Step::RevoluteZ {
                q_index,
                multiplier,
                ..
            } => {
                let a = z_axis(&x[i].rotation);
                grad[q_index] += multiplier * a.dot(&(p - x[i].translation.vector).cross(v));
            }
            Step::Revolute {
                axis,
                q_index,
                multiplier,
                ..
            } => {
                let a = x[i].rotation * axis;
                grad[q_index] += multiplier * a.dot(&(p - x[i].translation.vector).cross(v));
            }
            Step::Prismatic {
                axis_in_parent,
                q_index,
                multiplier,
                ..
            } => {
                let a = x[model.parents[i]].rotation * axis_in_parent;
                grad[q_index] += multiplier * a.dot(v);
            }
        }
        i = model.parents[i];
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::kinematics::model::{JointKind, JointLimits, Mimic, ModelBuilder};
    use nalgebra::{Unit, Vector6};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_unit(rng: &mut ChaCha8Rng) -> Unit<Vector3<f64>> {
        loop {
            let v = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            if v.norm() > 0.2 {
                return Unit::new_normalize(v);
            }
        }
    }

    fn random_iso(rng: &mut ChaCha8Rng) -> Isometry3<f64> {
        let t = Vector3::new(
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
            rng.random_range(-0.5..0.5),
        );
        let axis = random_unit(rng);
        Isometry3::from_parts(
            Translation3::from(t),
            UnitQuaternion::from_axis_angle(&axis, rng.random_range(-3.0..3.0)),
        )
    }

    /// A random tree mixing revolute, continuous, prismatic, fixed and mimic joints (mimics
    /// point at earlier or later joints, chained, with offsets).
    pub(crate) fn random_tree(seed: u64, n: usize) -> Model {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut b = ModelBuilder::new("base");
        let mut movers: Vec<String> = Vec::new();
        for k in 0..n {
            let parent = FrameId(rng.random_range(0..=k));
            let axis = random_unit(&mut rng);
            let kind = match rng.random_range(0..5) {
                0 => JointKind::Fixed,
                1 => JointKind::Prismatic { axis },
                2 => JointKind::Continuous { axis },
                _ => JointKind::Revolute { axis },
            };
            let mimic = if !kind.is_fixed() && !movers.is_empty() && rng.random_range(0..4) == 0 {
                let who = movers[rng.random_range(0..movers.len())].clone();
                Some(Mimic {
                    joint: who,
                    multiplier: rng.random_range(-1.5..1.5),
                    offset: rng.random_range(-0.3..0.3),
                })
            } else {
                None
            };
            let name = format!("j{k}");
            if !kind.is_fixed() {
                movers.push(name.clone());
            }
            b.add_joint(
                &name,
                parent,
                &format!("l{k}"),
                kind,
                random_iso(&mut rng),
                JointLimits::new(-2.0, 2.0, 1.0, 1.0),
                mimic,
            )
            .unwrap();
        }
        b.build().unwrap()
    }

    fn random_q(model: &Model, rng: &mut ChaCha8Rng) -> Vec<f64> {
        (0..model.nq())
            .map(|_| rng.random_range(-2.0..2.0))
            .collect()
    }

    /// Central differences of the world point and of the frame orientation (as the rotation
    /// vector of R(q+h) R(q-h)ᵀ / 2h) against the analytic Jacobian.
    pub(crate) fn check_jacobian_fd(
        model: &Model,
        q: &[f64],
        frame: FrameId,
        point: &Vector3<f64>,
        tol: f64,
    ) {
        let mut data = Data::new(model);
        forward_kinematics(model, &mut data, q);
        let mut j = Matrix6xX::zeros(model.nq());
        frame_jacobian(model, &data, frame, point, &mut j);
        let h = 1e-6;
        let mut qp = q.to_vec();
        for k in 0..model.nq() {
            qp.copy_from_slice(q);
            qp[k] = q[k] + h;
            forward_kinematics(model, &mut data, &qp);
            let xp = *data.frame(frame);
            qp[k] = q[k] - h;
            forward_kinematics(model, &mut data, &qp);
            let xm = *data.frame(frame);
            let lin = (xp * Point3::from(*point) - xm * Point3::from(*point)) / (2.0 * h);
            let ang = (xp.rotation * xm.rotation.inverse()).scaled_axis() / (2.0 * h);
            let fd = Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z);
            let an: Vector6<f64> = j.column(k).into();
            assert!(
                (fd - an).norm() <= tol * (1.0 + an.norm()),
                "column {k} ({}) of frame '{}': analytic {an:?} vs FD {fd:?}",
                model.joint_names()[k],
                model.frame_name(frame)
            );
        }
    }

    #[test]
    fn jacobian_matches_central_differences_on_random_trees_with_mimic_and_prismatic() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for seed in 0..40 {
            let model = random_tree(seed, 12);
            for _ in 0..3 {
                let q = random_q(&model, &mut rng);
                for f in 0..model.n_frames() {
                    let p = Vector3::new(
                        rng.random_range(-0.3..0.3),
                        0.1,
                        rng.random_range(-0.3..0.3),
                    );
                    check_jacobian_fd(&model, &q, FrameId(f), &p, 1e-6);
                }
            }
        }
    }

    #[test]
    fn point_jacobian_transpose_product_equals_the_jacobian_rows() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for seed in 0..20 {
            let model = random_tree(seed, 12);
            let q = random_q(&model, &mut rng);
            let mut data = Data::new(&model);
            forward_kinematics(&model, &mut data, &q);
            let mut j = Matrix6xX::zeros(model.nq());
            for f in 0..model.n_frames() {
                let p = Vector3::new(rng.random_range(-0.3..0.3), 0.2, -0.1);
                let v = Vector3::new(0.3, -1.2, rng.random_range(-1.0..1.0));
                frame_jacobian(&model, &data, FrameId(f), &p, &mut j);
                let expected = j.fixed_rows::<3>(0).transpose() * v;
                let mut g = vec![0.5; model.nq()];
                add_point_jacobian_transpose(&model, &data, FrameId(f), &p, &v, &mut g);
                for k in 0..model.nq() {
                    assert!(
                        (g[k] - 0.5 - expected[k]).abs() < 1e-12,
                        "frame {f} column {k}"
                    );
                }
            }
        }
    }

    #[test]
    fn random_trees_contain_mimic_prismatic_and_fixed_joints() {
        // Guards the test above against silently testing only revolute chains.
        let (mut mimic, mut prismatic, mut fixed) = (0, 0, 0);
        for seed in 0..40 {
            for j in random_tree(seed, 12).joints() {
                mimic += j.mimic.is_some() as usize;
                prismatic += matches!(j.kind, JointKind::Prismatic { .. }) as usize;
                fixed += j.kind.is_fixed() as usize;
            }
        }
        assert!(
            mimic > 20 && prismatic > 20 && fixed > 20,
            "{mimic} {prismatic} {fixed}"
        );
    }

    /// Planar 2R arm in the x-y plane: links l1, l2 along x, axes along z.
    pub(crate) fn planar_2r(l1: f64, l2: f64) -> Model {
        let z = Vector3::z_axis();
        let mut b = ModelBuilder::new("base");
        let lim = JointLimits::new(-3.0, 3.0, 1.0, 1.0);
        let f1 = b
            .add_joint(
                "q1",
                b.root(),
                "link1",
                JointKind::Revolute { axis: z },
                Isometry3::identity(),
                lim,
                None,
            )
            .unwrap();
        let f2 = b
            .add_joint(
                "q2",
                f1,
                "link2",
                JointKind::Revolute { axis: z },
                Isometry3::translation(l1, 0.0, 0.0),
                lim,
                None,
            )
            .unwrap();
        b.add_fixed_frame("tip", f2, Isometry3::translation(l2, 0.0, 0.0))
            .unwrap();
        b.build().unwrap()
    }

    #[test]
    fn planar_2r_fk_and_jacobian_match_the_closed_form() {
        let (l1, l2) = (0.7, 0.4);
        let model = planar_2r(l1, l2);
        let tip = model.frame_id("tip").unwrap();
        let mut data = Data::new(&model);
        let mut j = Matrix6xX::zeros(2);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..50 {
            let (q1, q2): (f64, f64) = (rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
            forward_kinematics(&model, &mut data, &[q1, q2]);
            let p = data.frame(tip).translation.vector;
            let x = l1 * q1.cos() + l2 * (q1 + q2).cos();
            let y = l1 * q1.sin() + l2 * (q1 + q2).sin();
            assert!((p - Vector3::new(x, y, 0.0)).norm() < 1e-12);
            frame_jacobian(&model, &data, tip, &Vector3::zeros(), &mut j);
            let s1 = q1.sin();
            let c1 = q1.cos();
            let s12 = (q1 + q2).sin();
            let c12 = (q1 + q2).cos();
            let expected = Matrix6xX::from_column_slice(&[
                -l1 * s1 - l2 * s12,
                l1 * c1 + l2 * c12,
                0.0,
                0.0,
                0.0,
                1.0,
                -l2 * s12,
                l2 * c12,
                0.0,
                0.0,
                0.0,
                1.0,
            ]);
            assert!((&j - &expected).norm() < 1e-12, "{j} vs {expected}");
        }
    }

    #[test]
    fn mimic_joint_follows_its_driver_with_multiplier_and_offset() {
        let z = Vector3::z_axis();
        let lim = JointLimits::new(-3.0, 3.0, 1.0, 1.0);
        let mut b = ModelBuilder::new("base");
        // j2 mimics j3 (declared later), which mimics j1: value(j2) = 0.5 * (2 * q1 + 0.1) - 0.2
        let f1 = b
            .add_joint(
                "j1",
                b.root(),
                "a",
                JointKind::Revolute { axis: z },
                Isometry3::identity(),
                lim,
                None,
            )
            .unwrap();
        let m2 = Mimic {
            joint: "j3".into(),
            multiplier: 0.5,
            offset: -0.2,
        };
        let f2 = b
            .add_joint(
                "j2",
                f1,
                "b",
                JointKind::Revolute { axis: z },
                Isometry3::translation(1.0, 0.0, 0.0),
                lim,
                Some(m2),
            )
            .unwrap();
        let m3 = Mimic {
            joint: "j1".into(),
            multiplier: 2.0,
            offset: 0.1,
        };
        b.add_joint(
            "j3",
            f2,
            "c",
            JointKind::Revolute { axis: z },
            Isometry3::translation(1.0, 0.0, 0.0),
            lim,
            Some(m3),
        )
        .unwrap();
        let model = b.build().unwrap();
        assert_eq!(model.nq(), 1);
        assert_eq!(model.joint_names(), &["j1".to_string()]);
        let a2 = model.joint("j2").unwrap().actuation.unwrap();
        assert_eq!(a2.q_index, 0);
        assert!(
            (a2.multiplier - 1.0).abs() < 1e-15 && (a2.offset - (0.5 * 0.1 - 0.2)).abs() < 1e-15
        );
        let mut data = Data::new(&model);
        let q1: f64 = 0.3;
        forward_kinematics(&model, &mut data, &[q1]);
        let b_frame = model.frame_id("b").unwrap();
        let expected_angle = q1 + (0.5 * (2.0 * q1 + 0.1) - 0.2);
        assert!((data.frame(b_frame).rotation.angle() - expected_angle.abs()).abs() < 1e-12);
        // Folded column: d(tip)/dq1 includes the mimic contributions.
        check_jacobian_fd(
            &model,
            &[q1],
            model.frame_id("c").unwrap(),
            &Vector3::new(0.5, 0.0, 0.0),
            1e-7,
        );
    }

    #[test]
    fn builder_rejects_bad_joints_naming_them() {
        use crate::kinematics::KinematicsError as E;
        let z = Vector3::z_axis();
        let lim = JointLimits::new(-1.0, 1.0, 1.0, 1.0);
        let mut b = ModelBuilder::new("base");
        let r = b.root();
        b.add_joint(
            "a",
            r,
            "la",
            JointKind::Revolute { axis: z },
            Isometry3::identity(),
            lim,
            None,
        )
        .unwrap();
        assert!(matches!(
            b.add_joint("a", r, "lx", JointKind::Revolute { axis: z }, Isometry3::identity(), lim, None),
            Err(E::DuplicateJoint { name }) if name == "a"
        ));
        assert!(matches!(
            b.add_joint("b", r, "la", JointKind::Revolute { axis: z }, Isometry3::identity(), lim, None),
            Err(E::DuplicateFrame { name }) if name == "la"
        ));
        assert!(matches!(
            b.add_joint("c", r, "lc", JointKind::Revolute { axis: z }, Isometry3::identity(), JointLimits::new(1.0, -1.0, 1.0, 1.0), None),
            Err(E::LimitsInverted { joint, .. }) if joint == "c"
        ));
        assert!(matches!(
            b.add_joint("d", r, "ld", JointKind::Revolute { axis: z }, Isometry3::translation(f64::NAN, 0.0, 0.0), lim, None),
            Err(E::NonFinite { path, .. }) if path.contains("'d'")
        ));
        assert!(matches!(
            b.add_joint("e", FrameId(99), "le", JointKind::Fixed, Isometry3::identity(), lim, None),
            Err(E::UnknownParentFrame { joint, .. }) if joint == "e"
        ));
        let mut b2 = b.clone();
        b2.add_joint(
            "m",
            r,
            "lm",
            JointKind::Revolute { axis: z },
            Isometry3::identity(),
            lim,
            Some(Mimic {
                joint: "ghost".into(),
                multiplier: 1.0,
                offset: 0.0,
            }),
        )
        .unwrap();
        assert!(
            matches!(b2.build(), Err(E::MimicUnknownJoint { joint, mimicked }) if joint == "m" && mimicked == "ghost")
        );
        let mut b3 = b.clone();
        b3.add_joint(
            "p",
            r,
            "lp",
            JointKind::Revolute { axis: z },
            Isometry3::identity(),
            lim,
            Some(Mimic {
                joint: "q".into(),
                multiplier: 1.0,
                offset: 0.0,
            }),
        )
        .unwrap();
        b3.add_joint(
            "q",
            r,
            "lq",
            JointKind::Revolute { axis: z },
            Isometry3::identity(),
            lim,
            Some(Mimic {
                joint: "p".into(),
                multiplier: 1.0,
                offset: 0.0,
            }),
        )
        .unwrap();
        assert!(matches!(b3.build(), Err(E::MimicCycle { .. })));
    }
}
