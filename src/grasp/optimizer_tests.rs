use super::*;
use crate::grasp::indexes::{Goal, Transmission};
use crate::grasp::objects::{ObjectSpec, ShapeSpec, SupportPlane};
use crate::grasp::system::{Finger, HandArm, LinkPair};
use crate::kinematics::{JointKind, JointLimits, Mimic, ModelBuilder};
use nalgebra::{Translation3, Unit};
use parry3d_f64::shape::SharedShape;

fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}

/// A 7-DoF anthropomorphic test arm (shoulder 3, elbow 1, wrist 3) with a two-finger
/// underactuated hand (distal joints coupled to proximal by 0.5, eq. 26), collision capsules.
pub(crate) fn test_system() -> HandArm {
    let mut b = ModelBuilder::new("base");
    let z = Unit::new_normalize(Vector3::z());
    let y = Unit::new_normalize(Vector3::y());
    let x = Unit::new_normalize(Vector3::x());
    let lim = |l: f64, u: f64| JointLimits::new(l, u, 2.0, 50.0);
    let mut parent = b.root();
    let arm = [
        ("j1", z, at(0.0, 0.0, 0.3), lim(-2.6, 2.6)),
        ("j2", y, at(0.0, 0.0, 0.0), lim(-2.0, 2.0)),
        ("j3", z, at(0.0, 0.0, 0.0), lim(-2.8, 2.8)),
        ("j4", y, at(0.0, 0.0, 0.35), lim(-2.5, 2.5)),
        ("j5", z, at(0.0, 0.0, 0.3), lim(-2.8, 2.8)),
        ("j6", y, at(0.0, 0.0, 0.0), lim(-1.6, 1.6)),
        ("j7", z, at(0.0, 0.0, 0.0), lim(-2.8, 2.8)),
    ];
    let mut frames = Vec::new();
    for (name, axis, origin, l) in arm {
        parent = b
            .add_joint(
                name,
                parent,
                &format!("{name}_link"),
                JointKind::Revolute { axis },
                origin,
                l,
                None,
            )
            .unwrap();
        frames.push(parent);
    }
    // Forearm capsule on the wrist-roll link, from the elbow-side end to the wrist.
    b.add_collision(
        frames[3],
        at(0.0, 0.0, 0.0),
        SharedShape::capsule(
            Point3::new(0.0, 0.0, 0.05),
            Point3::new(0.0, 0.0, 0.22),
            0.035,
        ),
    )
    .unwrap();
    let palm = b
        .add_fixed_frame("palm", parent, at(0.0, 0.0, 0.06))
        .unwrap();
    b.add_collision(
        palm,
        at(0.0, 0.0, -0.02),
        SharedShape::cuboid(0.025, 0.05, 0.02),
    )
    .unwrap();
    let mut fingers = Vec::new();
    for (k, (side, axis)) in [(1.0, x), (-1.0, Unit::new_normalize(-Vector3::x()))]
        .into_iter()
        .enumerate()
    {
        let pj = format!("f{k}_proximal");
        let dj = format!("f{k}_distal");
        let prox = b
            .add_joint(
                &pj,
                palm,
                &format!("f{k}_prox_link"),
                JointKind::Revolute { axis },
                at(0.0, side * 0.045, 0.0),
                lim(-0.6, 1.4),
                None,
            )
            .unwrap();
        b.add_collision(
            prox,
            at(0.0, 0.0, 0.0),
            SharedShape::capsule(
                Point3::new(0.0, 0.0, 0.012),
                Point3::new(0.0, 0.0, 0.05),
                0.008,
            ),
        )
        .unwrap();
        let dist = b
            .add_joint(
                &dj,
                prox,
                &format!("f{k}_dist_link"),
                JointKind::Revolute { axis },
                at(0.0, 0.0, 0.06),
                lim(-0.3, 0.7),
                Some(Mimic {
                    joint: pj.clone(),
                    multiplier: 0.5,
                    offset: 0.0,
                }),
            )
            .unwrap();
        b.add_collision(
            dist,
            at(0.0, 0.0, 0.0),
            SharedShape::capsule(
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(0.0, 0.0, 0.036),
                0.008,
            ),
        )
        .unwrap();
        fingers.push(Finger {
            name: format!("finger{k}"),
            tip: dist,
            tip_offset: Vector3::new(0.0, 0.0, 0.036),
            radius: 0.009,
            // Flexion about ±x turns the finger towards the other one, across y.
            pad_normal: Vector3::new(0.0, -side, 0.0),
        });
    }
    let model = Arc::new(b.build().unwrap());
    let arm_joints = (0..7)
        .map(|i| model.q_index(&format!("j{}", i + 1)).unwrap())
        .collect();
    let hand_joints = (0..2)
        .map(|k| model.q_index(&format!("f{k}_proximal")).unwrap())
        .collect();
    let elbow = model.frame_id("j4_link");
    let mut sys = HandArm {
        name: "test_arm_2f".into(),
        model: model.clone(),
        arm_joints,
        hand_joints,
        palm,
        fingers,
        idle_fingers: vec![],
        thumb: Some(0),
        spread_pairs: vec![],
        elbow,
        link_spheres: vec![],
        link_pairs: vec![],
        crossing_pairs: vec![],
        support_cover: vec![],
        wrist_joints: 0,
        geometry: Arc::new(crate::geometry::RobotGeometry::new(model.clone())),
    };
    sys.collect_link_spheres(4);
    sys.validate().unwrap();
    sys
}

fn ball(pos: [f64; 3], radius: f64) -> Object {
    Object::new(ObjectSpec {
        name: "ball".into(),
        shape: ShapeSpec::Sphere { radius },
        position: pos,
        orientation: [1.0, 0.0, 0.0, 0.0],
        support: Some(SupportPlane::horizontal(pos[2] - radius)),
        mass: None,
        friction: None,
    })
    .unwrap()
}

fn dir(d: Vector3<f64>, kind: Transmission) -> TaskDirection {
    TaskDirection {
        direction: d.normalize(),
        kind,
        goal: Goal::Maximize,
    }
}

#[test]
fn cost_gradient_and_constraint_jacobian_match_central_differences() {
    let mut sys = test_system();
    // A spread-order row (eq. 28) with a coupled joint value, to cover its Jacobian too.
    sys.spread_pairs = vec![crate::grasp::SpreadOrder {
        lower: crate::grasp::JointValue {
            q_index: sys.hand_joints[0],
            multiplier: 0.5,
            offset: 0.1,
        },
        upper: crate::grasp::JointValue::independent(sys.hand_joints[1]),
    }];
    assert!(sys.link_spheres.len() >= 6, "{}", sys.link_spheres.len());
    let mut req = GraspRequest::new(
        ball([0.5, 0.1, 0.2], 0.035),
        vec![
            dir(Vector3::new(0.3, 1.0, 0.2), Transmission::Velocity),
            dir(Vector3::z(), Transmission::Force),
        ],
        QualityMeasure::CentroidDistance,
    );
    req.weights = Weights {
        tc: 1.0,
        gc: 0.5,
        q: 1.0,
        d: 2.0,
    };
    req.elbow_reference = Some(Point3::new(0.1, -0.3, 0.4));
    // A goal-region row (a plan's motion model) over the arm, two PCA components.
    let arm = sys.arm_joints.clone();
    req.goal_regions = vec![GoalRegion {
        name: "arm".into(),
        joints: arm.clone(),
        mean: arm.iter().map(|&j| 0.1 * j as f64).collect(),
        components: (0..arm.len() * 2)
            .map(|k| (k as f64 * 0.7).sin() * 0.5)
            .collect(),
        center: vec![0.2, -0.1],
        radius: 0.3,
    }];
    for quality in [
        QualityMeasure::CentroidDistance,
        QualityMeasure::PolygonArea,
    ] {
        req.quality = quality;
        if quality == QualityMeasure::PolygonArea {
            // Two fingers give no area; check the formula path with the quality term alone.
            req.weights.q = 1.0;
        }
        let mut e = Eval::new(&sys, &req);
        let n = e.n();
        let u: Vec<f64> = [0.2, 0.6, -0.3, 1.1, 0.4, 0.5, -0.2, 0.3, 0.25][..n].to_vec();
        let mut g = vec![0.0; n];
        e.gradient(&u, &mut g);
        let h = 1e-6;
        for k in 0..n {
            let mut up = u.clone();
            let mut um = u.clone();
            up[k] += h;
            um[k] -= h;
            let fd = (e.cost(&up) - e.cost(&um)) / (2.0 * h);
            assert!(
                (g[k] - fd).abs() < 1e-5 * (1.0 + fd.abs()),
                "{quality:?} u[{k}]: {} vs {fd}",
                g[k]
            );
        }
        let nr = e.n_eq() + e.n_ineq();
        // J^T e_r for every residual r, against differences of that residual.
        for row in 0..nr {
            assert_row_matches_central_differences(&mut e, &u, row, h, 1e-5, "residual");
        }
    }
}

/// `Jᵀ e_row` of residual `row` at `u` against central differences of that residual (step `h`,
/// absolute tolerance `tol`); returns the analytic column for further checks.
fn assert_row_matches_central_differences(
    e: &mut Eval<'_>,
    u: &[f64],
    row: usize,
    h: f64,
    tol: f64,
    what: &str,
) -> Vec<f64> {
    let (n, nr) = (e.n(), e.n_eq() + e.n_ineq());
    let (mut rp, mut rm) = (vec![0.0; nr], vec![0.0; nr]);
    let mut d = vec![0.0; nr];
    d[row] = 1.0;
    let mut jt = vec![0.0; n];
    e.jacobian_t(u, &d, &mut jt);
    for k in 0..n {
        let (mut up, mut um) = (u.to_vec(), u.to_vec());
        up[k] += h;
        um[k] -= h;
        e.residuals(&up, &mut rp);
        e.residuals(&um, &mut rm);
        let fd = (rp[row] - rm[row]) / (2.0 * h);
        assert!(
            (jt[k] - fd).abs() < tol,
            "{what} {row} u[{k}]: {} vs {fd}",
            jt[k]
        );
    }
    jt
}

/// A test posture: the arm at 0.4 of its (±2 rad clipped) range, the hand at fraction `t` of
/// its range (0 open, 1 closed).
fn hand_posture(sys: &HandArm, lo: &[f64], hi: &[f64], t: f64) -> Vec<f64> {
    (0..lo.len())
        .map(|k| {
            let (l, u) = (lo[k].max(-2.0), hi[k].min(2.0));
            l + (u - l) * if k < sys.arm_joints.len() { 0.4 } else { t }
        })
        .collect()
}

/// Link spheres carry their finger, and the link-pair rows (a link sphere of one finger and a
/// link or contact sphere of another) have the analytic gradient their residual has by central
/// differences, on every bundled system, at postures from open to closed hands.
#[test]
fn link_pairs_of_different_fingers_have_exact_gradients_on_every_system() {
    for sys in real_systems() {
        let name = &sys.name;
        let tagged = |f: usize| {
            sys.link_spheres
                .iter()
                .filter(|l| l.finger == Some(f))
                .count()
        };
        let per_finger: Vec<usize> = (0..sys.fingers.len()).map(tagged).collect();
        println!(
            "{name}: {} link spheres, per finger {per_finger:?}, {} link pairs",
            sys.link_spheres.len(),
            sys.link_pairs.len()
        );
        // every pair joins two different fingers
        for p in &sys.link_pairs {
            let (a, other) = match *p {
                LinkPair::Links(a, b) => (a, sys.link_spheres[b].finger.unwrap()),
                LinkPair::Tip(a, f) => (a, f),
            };
            assert_ne!(sys.link_spheres[a].finger.unwrap(), other, "{name}: {p:?}");
        }
        let obj = Object::new(crate::grasp::objects::seeded_object("ball", 0.5, 0.0, 0.0).unwrap())
            .unwrap();
        let req = GraspRequest::new(obj, vec![], QualityMeasure::CentroidDistance);
        let mut e = Eval::new(&sys, &req);
        let nr = e.n_eq() + e.n_ineq();
        let k0 = e.link_pair_row();
        assert_eq!(nr - k0, sys.link_pairs.len());
        let (lo, hi) = bounds(&sys);
        let mut closest = f64::INFINITY;
        for t in [0.1, 0.5, 0.9] {
            let u = hand_posture(&sys, &lo, &hi, t);
            let mut r0 = vec![0.0; nr];
            e.residuals(&u, &mut r0);
            // every 7th row keeps the test short on hands with hundreds of pairs
            for row in (k0..nr).step_by(7) {
                closest = closest.min(FINGER_CLEARANCE - r0[row]);
                let what = format!("{name} t {t} link-pair row");
                assert_row_matches_central_differences(&mut e, &u, row, 1e-6, 1e-6, &what);
            }
        }
        println!(
            "  closest link-pair gap over the postures: {:.1} mm",
            closest * 1e3
        );
    }
}

/// The finger-finger rows on a three-finger hand (WAM + iHY: three pairs), at hand
/// configurations from open to closed, where some pairs come close: analytic `Jᵀ e_r` against
/// central differences of each row.
#[test]
fn finger_separation_rows_match_central_differences() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let s = crate::kinematics::System::from_file(&dir.join("wam_ihy.toml")).unwrap();
    let sys = HandArm::from_system(&s).unwrap();
    assert_eq!(sys.fingers.len(), 3);
    let obj =
        Object::new(crate::grasp::objects::seeded_object("ball", 0.5, 0.0, 0.0).unwrap()).unwrap();
    let req = GraspRequest::new(obj, vec![], QualityMeasure::CentroidDistance);
    let mut e = Eval::new(&sys, &req);
    let nr = e.n_eq() + e.n_ineq();
    let k0 = e.pair_row();
    assert_eq!(e.link_pair_row() - k0, 3);
    let (lo, hi) = bounds(&sys);
    let h = 1e-6;
    let mut closest = f64::INFINITY;
    for t in [0.2, 0.5, 0.8, 0.95] {
        let u = hand_posture(&sys, &lo, &hi, t);
        let mut r0 = vec![0.0; nr];
        e.residuals(&u, &mut r0);
        for (row, r) in r0.iter().enumerate().take(e.link_pair_row()).skip(k0) {
            closest = closest.min(FINGER_CLEARANCE - r);
            let what = format!("t {t} pair row");
            let jt = assert_row_matches_central_differences(&mut e, &u, row, h, 1e-6, &what);
            assert!(
                jt.iter().any(|v| v.abs() > 1e-3),
                "row {row} has no gradient"
            );
        }
    }
    println!(
        "closest contact-sphere gap over the configurations: {:.1} mm",
        closest * 1e3
    );
}

#[test]
fn allocation_free_hand_object_jacobian_equals_the_pseudo_inverse_form() {
    let sys = test_system();
    let req = GraspRequest::new(
        ball([0.5, 0.1, 0.2], 0.035),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    let mut e = Eval::new(&sys, &req);
    let u = [0.2, 0.6, -0.3, 1.1, 0.4, 0.5, -0.2, 0.3, 0.25];
    e.update(&u);
    let nh = sys.hand_joints.len();
    let (_, m_fast) = hand_gc(
        &sys,
        &req,
        &e.kin.data,
        &mut e.scratch.tmp_j,
        &mut Matrix6xX::zeros(nh),
    );
    let cps = contact_points(&sys, &req.object, &e.kin.data);
    let pts: Vec<Point3<f64>> = cps.iter().map(|c| c.0).collect();
    let mut g = nalgebra::DMatrix::zeros(6, 3 * pts.len());
    indexes::grasp_matrix(&pts, &req.object.centroid(), &mut g);
    let mut jh = nalgebra::DMatrix::zeros(3 * pts.len(), nh);
    let mut j = Matrix6xX::zeros(sys.model.nq());
    for (i, f) in sys.fingers.iter().enumerate() {
        let local = e.kin.data.frame(f.tip).inverse_transform_point(&pts[i]);
        frame_jacobian(&sys.model, &e.kin.data, f.tip, &local.coords, &mut j);
        for (h, &qh) in sys.hand_joints.iter().enumerate() {
            for r in 0..3 {
                jh[(3 * i + r, h)] = j[(r, qh)];
            }
        }
    }
    let h = indexes::hand_object_jacobian(&g, &jh);
    let hv = indexes::translational_block(&h);
    let m_ref = indexes::transmission_matrix(&hv);
    assert!(
        (m_fast - m_ref).norm() < 1e-8 * (1.0 + m_ref.norm()),
        "{m_fast} vs {m_ref}"
    );
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a.dot(b).abs() / (a.norm() * b.norm()))
        .min(1.0)
        .acos()
        .to_degrees()
}

#[test]
fn grasps_of_a_ball_are_feasible_with_every_residual_in_tolerance() {
    let sys = test_system();
    for pos in [[0.5, 0.1, 0.2], [0.45, -0.2, 0.15], [0.4, 0.3, 0.3]] {
        let req = GraspRequest::new(ball(pos, 0.033), vec![], QualityMeasure::CentroidDistance);
        let r = plan_grasp(&sys, &req).unwrap();
        assert!(r.feasible, "{pos:?}: {:?} {:?}", r.reason, r.exact);
        // The exact verdict, rechecked from the joint values (the sphere-model residuals are
        // no longer the verdict: the contact repair moves the fingers off the sphere model).
        let obj = ball(pos, 0.033);
        recheck_exact(&sys, &obj, &r).unwrap_or_else(|e| panic!("{pos:?}: {e}"));
        for c in &r.contacts {
            assert!(c.surface_distance.abs() <= 1e-3, "{c:?}");
            assert!(c.pad_angle_deg <= PAD_CONE_DEG, "{c:?}");
        }
        assert!(r.residuals.min_limit_margin >= 0.0);
        assert!(r.residuals.max_coupling_error < 1e-12);
        assert_eq!(r.contacts.len(), 2);
        assert_eq!(r.q_arm.len(), 7);
        assert_eq!(r.q_hand[0].name, "f0_proximal");
    }
}

/// A plan's grasp stays in its motion model's goal region: a region (identity components over
/// the arm joints) 0.35 rad off the unconstrained grasp's arm configuration moves the grasp into
/// it, measured here from the returned joint values alone; a region no grasp reaches makes the
/// answer infeasible with a reason naming the region and the joints furthest out.
#[test]
fn a_goal_region_keeps_the_grasp_inside_it_or_says_which_joints_are_out() {
    let sys = test_system();
    let req = GraspRequest::new(
        ball([0.5, 0.1, 0.2], 0.033),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    let free = plan_grasp(&sys, &req).unwrap();
    assert!(free.feasible);
    let arm: Vec<f64> = free.q_arm.iter().map(|j| j.value).collect();
    let n = arm.len();
    let identity: Vec<f64> = (0..n * n)
        .map(|k| if k / n == k % n { 1.0 } else { 0.0 })
        .collect();
    let region = |center: Vec<f64>, radius: f64| GoalRegion {
        name: "arm".into(),
        joints: sys.arm_joints.clone(),
        mean: vec![0.0; n],
        components: identity.clone(),
        center,
        radius,
    };
    let distance = |r: &GraspResult, c: &[f64]| {
        r.q_arm
            .iter()
            .zip(c)
            .map(|(j, c)| (j.value - c).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    // The region is centred on another feasible grasp of the same ball, on a different IK
    // branch from the free answer, so a grasp inside it exists; the free answer lies outside.
    let radius = 0.25;
    let centre: Vec<f64> = (0..req.starts)
        .map(|k| run_start(&sys, &req, k))
        .filter(|o| o.feasible)
        .map(|o| o.u[..n].to_vec())
        .find(|u| distance(&free, u) > 2.0 * radius)
        .expect("a feasible grasp on another branch");
    let mut inside = req.clone();
    inside.goal_regions = vec![region(centre.clone(), radius)];
    let r = plan_grasp(&sys, &inside).unwrap();
    assert!(r.feasible, "{:?}", r.reason);
    let d = distance(&r, &centre);
    assert!(d <= radius, "{d} from the centre, radius {radius}");
    assert!(r.residuals.max_surface_distance <= 1e-3);
    let mut far = req.clone();
    far.goal_regions = vec![region(arm.iter().map(|v| v + 2.5).collect(), 0.1)];
    let r = plan_grasp(&sys, &far).unwrap();
    assert!(!r.feasible);
    let why = r.reason.unwrap();
    assert!(why.contains("goal region of the arm joints"), "{why}");
    let mut bad = req.clone();
    bad.goal_regions = vec![region(vec![0.0; n], -1.0)];
    assert!(matches!(
        plan_grasp(&sys, &bad),
        Err(GraspError::InvalidParameter {
            field: "goal_regions",
            ..
        })
    ));
}

/// Fig. 3: maximising the velocity ratio along d aligns the velocity ellipsoid's major axis
/// with d (within 10°) and raises β along d compared with the same grasp without TC.
#[test]
fn claim_a_velocity_ratio_maximisation_aligns_the_velocity_ellipsoid() {
    let sys = test_system();
    let d = Vector3::new(0.0, 1.0, 0.0);
    let mut req = GraspRequest::new(
        ball([0.5, 0.0, 0.25], 0.033),
        vec![dir(d, Transmission::Velocity)],
        QualityMeasure::CentroidDistance,
    );
    req.weights.tc = 0.0;
    let without = plan_grasp(&sys, &req).unwrap();
    req.weights.tc = 1.0;
    req.weights.q = 0.1;
    let with = plan_grasp(&sys, &req).unwrap();
    assert!(
        with.feasible && without.feasible,
        "{:?} {:?}",
        with.reason,
        without.reason
    );
    let axis = with.arm_ellipsoids.velocity_major();
    assert!(
        angle_deg(&axis, &d) < 10.0,
        "major axis {axis} vs d: {}°",
        angle_deg(&axis, &d)
    );
    assert!(
        with.terms.arm_ratios[0] > without.terms.arm_ratios[0],
        "{} vs {}",
        with.terms.arm_ratios[0],
        without.terms.arm_ratios[0]
    );
}

/// Fig. 4/6: force- and velocity-optimal results along the same d differ as theory says: the
/// force-optimal grasp has the larger α along d and its force ellipsoid's major axis along d
/// (within 10°); the velocity-optimal one has the larger β along d and its velocity ellipsoid
/// closer to d than the force-optimal one. (This test arm cannot put both major axes on the same
/// d at one placement — its lateral velocity is dominated by the shoulder yaw — so the second
/// alignment is checked along z, where it can.)
#[test]
fn claim_b_force_and_velocity_optima_put_different_ellipsoids_along_d() {
    let sys = test_system();
    let solve = |d: Vector3<f64>, kind| {
        let mut req = GraspRequest::new(
            ball([0.5, 0.0, 0.25], 0.033),
            vec![dir(d, kind)],
            QualityMeasure::CentroidDistance,
        );
        req.weights.q = 0.1;
        req.starts = 12;
        let r = plan_grasp(&sys, &req).unwrap();
        assert!(r.feasible, "{kind:?}: {:?}", r.reason);
        r
    };
    let d = Vector3::x();
    let force = solve(d, Transmission::Force);
    let vel = solve(d, Transmission::Velocity);
    let alpha = |r: &GraspResult| r.arm_ellipsoids.clone();
    let (ef, ev) = (alpha(&force), alpha(&vel));
    assert!(angle_deg(&ef.force_major(), &d) < 10.0, "{ef:?}");
    assert!(angle_deg(&ef.force_major(), &d) < angle_deg(&ev.force_major(), &d));
    // α along d from the force optimum, β along d from the velocity optimum, each against the
    // other result's value of the same ratio.
    let m = |e: &Ellipsoids| {
        let mut m = Matrix3::zeros();
        for k in 0..3 {
            let a = Vector3::from(e.axes[k]);
            m += a * a.transpose() * e.velocity_semi_axes[k].powi(2);
        }
        m
    };
    let ratio = |e: &Ellipsoids, kind| indexes::transmission_ratio(&m(e), &d, kind);
    assert!(ratio(&ef, Transmission::Force) > ratio(&ev, Transmission::Force));
    assert!(ratio(&ev, Transmission::Velocity) > ratio(&ef, Transmission::Velocity));
    assert!((force.terms.arm_ratios[0] - ratio(&ef, Transmission::Force)).abs() < 1e-9);
    let z = Vector3::z();
    let vel_z = solve(z, Transmission::Velocity);
    let az = angle_deg(&vel_z.arm_ellipsoids.velocity_major(), &z);
    let e = &vel_z.arm_ellipsoids;
    let sa = &e.velocity_semi_axes;
    let off_minor = angle_deg(&Vector3::from(e.axes[2]), &z);
    // Where the two largest semi-axes are within 5 % the major axis is ill-defined (the rule of
    // `claim_b_holds_on_the_wam_and_the_pa10`); there z must lie in their plane. Measured since
    // the exact verdict: 89.1° with semi-axes 0.617 / 0.607 / 0.170 (z off the minor axis).
    assert!(
        az < 10.0 || (sa[1] > 0.95 * sa[0] && off_minor > 80.0),
        "velocity axis {az}° off z, semi-axes {sa:?}, {off_minor}° off the minor"
    );
}

/// Claim (b) on the shipped arms (Fig. 4: WAM + iHY grasping the seeded ball; also WAM + T42,
/// PA10 + T42, PA10 + iHY), for d = x, y and z, with the ball on the z = 0 table at (0.5, 0)
/// (the seeded placement) and on a 0.2 m table at (0.55, 0).
///
/// What holds, and is asserted:
/// - for every d and both placements, the force optimum has the larger force ratio α along d and
///   the velocity optimum the larger velocity ratio β ("the corresponding transmission ratio is
///   maximized");
/// - velocity along y (tangential to the base axis, where the first joint moves the hand): the
///   velocity optimum's velocity-ellipsoid major axis is within 10° of d on every system at both
///   placements (measured 0.0°-7.1°), except where its two largest semi-axes are within 5 % and
///   the major axis is ill-defined; there d lies in their plane (> 80° off the minor axis).
///   Since the link-pair rows (fingers no longer cross), that is PA10 + T42 on the z = 0 table
///   (10.2°; before them also WAM + T42 there, 13.3°);
/// - the comparative reading, along x and y on every system and placement: the force optimum's
///   force axis is closer to d than the velocity optimum's force axis, and the velocity
///   optimum's velocity axis closer to d than the force optimum's velocity axis. Along z it also
///   holds for the force axes (all eight), and fails for the velocity axes six times out of
///   eight (WAM + iHY 52.4° vs 49.5° and 89.3° vs 46.5°, WAM + T42 53.8° vs 48.8° and 89.9° vs
///   68.0°, PA10 + T42 raised 89.9° vs 80.5°, PA10 + iHY raised 89.4° vs 84.8°): no optimum gets
///   its velocity axis near z (52°-90°), so the smaller angle is noise between two misaligned
///   axes;
/// - force along x (radial, where the arm can approach its stretched singularity): the force
///   optimum's force-ellipsoid major axis is within 10° of d on every system on the raised table
///   (measured 4.0°-7.4°; 9.5°-23.2° on the seeded z = 0 table, where the ball sits 0.35 m
///   below the shoulder).
///
/// Since `feasible` is the exact verdict (issue 23) and the T42/iHY were rebuilt (wider finger
/// spacing, closure limits), re-measured with 12 starts: 17 of the 24 system x placement x d
/// cases have an exact-feasible grasp for both kinds (none for PA10 + T42 and PA10 + iHY on the
/// raised table, nor PA10 + iHY along z on the seeded table: every start ends with a link in the
/// object or the table, or a contact off its pad). On those 17 the ratio ordering holds and is
/// asserted, with at most 7 cases infeasible. The axis readings above are printed but no longer
/// asserted: on WAM + T42 (raised table) the force optimum's force axis is 13.8° off x (the
/// velocity optimum's 6.5°), and along y its velocity axis 19.3° off (semi-axes 0.70 / 0.59, not
/// within 5 %); the other cases keep them.
///
/// What the issue states — both kinds within 10° along the *same* d — holds for no
/// d ∈ {x, y, z} on these arms at these placements, and is not asserted. Over 48 other ball
/// placements (x 0.35-0.65 m, y 0-0.45 m, table 0-0.6 m; 12 starts; surveyed before the link-pair
/// rows) it held for one d at one
/// placement on WAM + T42, at none on WAM + iHY and at two on PA10 + T42, always along y with the
/// ball close to the base. The optima are not time-capped: every start converges
/// in ~10 ms, far inside its 150 ms cap, and 48 starts, a 1 s cap or w_Q = 0 change the optimal
/// ratios by under 4 % and bring no same-d pair within 10° (`survey_claim_b_alignment`).
/// Maximising a ratio along d need not turn the ellipsoid's axis onto d. The first joint alone
/// moves the flange along y by its distance from the base axis (≈ 0.5 m/rad here), which bounds
/// the force ratio along y and keeps the force ellipsoid's major axis where the arm can approach
/// a singularity (the shoulder-wrist line, 34°-84° off y); the radial velocity ratio along x
/// (β ≤ 0.39 on the WAM) stays below that tangential mobility, so the WAM's velocity major axis
/// stays 69°-81° off x. Along z no optimum comes within 25° (28°-90°). Where the top two
/// semi-axes are close the major axis is ill-defined and moves with the start set (PA10 + T42,
/// velocity along y: 2.8° with these 12 starts, 12.8° with 48 at a 0.1 % larger β, before the
/// clearance rows; 11.2° with 12 after them, 10.2° after the link-pair rows). The printout gives
/// every angle and ratio.
#[test]
fn claim_b_holds_on_the_wam_and_the_pa10() {
    use crate::grasp::objects::seeded_object;
    let dir_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let ellipsoid_matrix = |e: &Ellipsoids| {
        let mut m = Matrix3::zeros();
        for k in 0..3 {
            let a = Vector3::from(e.axes[k]);
            m += a * a.transpose() * e.velocity_semi_axes[k].powi(2);
        }
        m
    };
    let mut fails = Vec::new();
    let mut infeasible: Vec<String> = Vec::new();
    for name in ["wam_ihy", "wam_t42", "pa10_t42", "pa10_ihy"] {
        let s =
            crate::kinematics::System::from_file(&dir_path.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        for (x, table, raised) in [(0.5, 0.0, false), (0.55, 0.2, true)] {
            for (dn, d) in [
                ("x", Vector3::x()),
                ("y", Vector3::y()),
                ("z", Vector3::z()),
            ] {
                let solve = |kind| {
                    let obj = Object::new(seeded_object("ball", x, 0.0, table).unwrap()).unwrap();
                    let mut req = GraspRequest::new(
                        obj,
                        vec![dir(d, kind)],
                        QualityMeasure::CentroidDistance,
                    );
                    req.weights.q = 0.1;
                    req.starts = 12;
                    let r = plan_grasp(&sys, &req).unwrap();
                    r.feasible.then_some(r).ok_or_else(|| {
                        format!(
                            "{name} {kind:?} along {dn} (table {table} m): no exact-feasible grasp"
                        )
                    })
                };
                let (force, vel) = match (solve(Transmission::Force), solve(Transmission::Velocity))
                {
                    (Ok(f), Ok(v)) => (f, v),
                    (f, v) => {
                        let why: Vec<String> = f.err().into_iter().chain(v.err()).collect();
                        infeasible.push(why.join("; "));
                        continue;
                    }
                };
                let (mf, mv) = (
                    ellipsoid_matrix(&force.arm_ellipsoids),
                    ellipsoid_matrix(&vel.arm_ellipsoids),
                );
                let ratio = |m: &Matrix3<f64>, kind| indexes::transmission_ratio(m, &d, kind);
                let (ff, vf) = (
                    ratio(&mf, Transmission::Force),
                    ratio(&mv, Transmission::Force),
                );
                let (vv, fv) = (
                    ratio(&mv, Transmission::Velocity),
                    ratio(&mf, Transmission::Velocity),
                );
                // The reported ellipsoids are the ones behind the reported ratios.
                assert!((force.terms.arm_ratios[0] - ff).abs() < 1e-9 * ff);
                assert!((vel.terms.arm_ratios[0] - vv).abs() < 1e-9 * vv);
                let af = angle_deg(&force.arm_ellipsoids.force_major(), &d);
                let av = angle_deg(&vel.arm_ellipsoids.velocity_major(), &d);
                // The same axes of the other optimum: the comparative reading of claim (b).
                let af_of_v = angle_deg(&vel.arm_ellipsoids.force_major(), &d);
                let av_of_f = angle_deg(&force.arm_ellipsoids.velocity_major(), &d);
                let at = format!("{name} ball at ({x}, 0) on a {table} m table, d = {dn}");
                println!(
                    "{at}: force optimum α {ff:.3} (velocity optimum {vf:.3}), force axis {af:.1}° \
                     (velocity optimum's {af_of_v:.1}°); velocity optimum β {vv:.3} (force optimum \
                     {fv:.3}), velocity axis {av:.1}° (force optimum's {av_of_f:.1}°)"
                );
                assert!(ff > vf, "{at}: α {ff} vs {vf}");
                assert!(vv > fv, "{at}: β {vv} vs {fv}");
                if dn == "y" {
                    // Where the two largest velocity semi-axes are within 5 %, the major axis
                    // is ill-defined (it swings within their plane with the start set); there
                    // the claim is that d lies in that plane, i.e. off the minor axis.
                    let e = &vel.arm_ellipsoids;
                    let s = &e.velocity_semi_axes;
                    let off_minor = angle_deg(&Vector3::from(e.axes[2]), &d);
                    if !(av < 10.0 || (s[1] > 0.95 * s[0] && off_minor > 80.0)) {
                        fails.push(format!(
                            "{at}: velocity axis {av}°, semi-axes {s:?}, {off_minor}° off the minor"
                        ));
                    }
                }
                if dn != "z" {
                    if af >= af_of_v {
                        fails.push(format!("{at}: force axes {af}° vs {af_of_v}°"));
                    }
                    if av >= av_of_f {
                        fails.push(format!("{at}: velocity axes {av}° vs {av_of_f}°"));
                    }
                }
                if dn == "x" && raised && af >= 10.0 {
                    fails.push(format!("{at}: force axis {af}°"));
                }
            }
        }
    }
    // The primary claim (the optimum of a kind has the larger ratio of that kind) is asserted on
    // every case above; the axis readings are printed, not asserted, since the exact verdict
    // (see the doc comment).
    println!("axis readings that do not hold: {fails:#?}");
    println!("no exact-feasible grasp: {infeasible:#?}");
    assert!(
        infeasible.len() <= 7,
        "{} of 24 cases without an exact-feasible grasp (7 measured): {infeasible:#?}",
        infeasible.len()
    );
}

/// Fig. 6: the iHY hand on the WAM grasps the seeded ball optimising the grasp compatibility
/// index (GC, hand-object Jacobian `H = (Gᵀ)⁺ J_h`, eq. 17-19; TC off, w_Q = 0.1, 12 starts)
/// for force and for velocity transmission along y and along z.
///
/// Measured after the finger-finger and link-pair rows (before the first, the velocity optima
/// put two fingertips 0.0-0.2 mm apart, polygon area ~1e-7 m², and reached 17-135 m/s per
/// rad/s; before the second, the iHY's fingers could pass through each other):
///
/// | d | optimum  | α along d | β along d | force axis | velocity axis | sphere gap | velocity semi-axes (m/s per rad/s) |
/// |---|----------|-----------|-----------|------------|---------------|------------|-------------------|
/// | y | force    | 163.66    | 0.006     | 6.0°       | 89.9°         | 40.0 mm    | 0.072 0.014 0.006 |
/// | y | velocity | 0.88      | 1.130     | 90.0°      | 0.2°          | 1.02 mm    | 1.133 0.072 0.014 |
/// | z | force    | 115.27    | 0.008     | 5.1°       | 88.8°         | 40.0 mm    | 0.054 0.046 0.008 |
/// | z | velocity | 0.87      | 1.151     | 90.0°      | 0.2°          | 0.97 mm    | 1.152 0.122 0.043 |
///
/// Asserted: the ratio ordering for both d; for both d each optimum's own axis within 10° of d
/// (Fig. 6 as the paper draws it; before the link-pair rows the force optimum along y was 74.4°
/// off, its best-aligned start bunching the fingers) and closer to d than the other optimum's;
/// contact spheres ≥ 0.5 mm apart; velocity semi-axes below 2 m/s per rad/s (an order of
/// magnitude under the artefact).
///
/// Not a grasp property to celebrate: every velocity optimum drove two fingertips together
/// until the clearance row was active (gap ~1 mm, the bound) — GC's velocity ratio grows as the
/// contacts cluster, so the row, not the index, set where it stopped.
///
/// Since `feasible` is the exact verdict (issue 23: pads on the object within 1 mm and 60°, no
/// two links of the system intersecting, exact parry distances), those optima are gone: two iHY
/// fingertips 1 mm apart put their 22 mm wide distal phalanges through each other, which the
/// sphere model did not see. Re-measured on exact-feasible grasps (with the rebuilt iHY spacing
/// and limits): α along y 89.31 (force optimum) vs 13.52, β 0.064 vs 0.009, force axis 27.4°
/// (other optimum's 88.2°), velocity axis 77.6° (89.6°); along z force axis 49.4° (85.3°),
/// velocity axis 17.8° (89.4°), contact-sphere gaps 11-40 mm. The ratio ordering and the
/// comparative axis reading still hold and are asserted; "each optimum's own axis within 10° of
/// d" does not hold on physically possible grasps here and is no longer asserted.
#[test]
fn fig6_hand_force_and_velocity_optima_along_y_and_z() {
    use crate::grasp::objects::seeded_object;
    let dir_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let s = crate::kinematics::System::from_file(&dir_path.join("wam_ihy.toml")).unwrap();
    let sys = HandArm::from_system(&s).unwrap();
    let m = |e: &Ellipsoids| {
        let mut m = Matrix3::zeros();
        for k in 0..3 {
            let a = Vector3::from(e.axes[k]);
            m += a * a.transpose() * e.velocity_semi_axes[k].powi(2);
        }
        m
    };
    let mut fails = Vec::new();
    for (dn, d) in [("y", Vector3::y()), ("z", Vector3::z())] {
        let solve = |kind| {
            let obj = Object::new(seeded_object("ball", 0.5, 0.0, 0.0).unwrap()).unwrap();
            let mut req =
                GraspRequest::new(obj, vec![dir(d, kind)], QualityMeasure::CentroidDistance);
            req.weights = Weights {
                tc: 0.0,
                gc: 1.0,
                q: 0.1,
                d: 0.0,
            };
            // plan_grasp's selection (lowest-cost feasible of starts 0..12) without its
            // per-start wall cap: GC's gradient costs 2n FK passes, so under load capped starts
            // end at different iterates and the force axes moved by 5°-50° between runs.
            let mut settings = solver_settings();
            settings.max_duration = None;
            let best = (0..12)
                .map(|k| run_start_with(&sys, &req, k, settings.clone()))
                .filter(|o| o.feasible)
                .min_by(|a, b| a.score.total_cmp(&b.score))
                .unwrap_or_else(|| panic!("{kind:?} along {dn}: no feasible start"));
            describe(&sys, &req, &best.u, Some(best.report))
        };
        let force = solve(Transmission::Force);
        let vel = solve(Transmission::Velocity);
        let (ef, ev) = (&force.hand_ellipsoids, &vel.hand_ellipsoids);
        let ratio = |e: &Ellipsoids, kind| indexes::transmission_ratio(&m(e), &d, kind);
        let (ff, vf) = (
            ratio(ef, Transmission::Force),
            ratio(ev, Transmission::Force),
        );
        let (vv, fv) = (
            ratio(ev, Transmission::Velocity),
            ratio(ef, Transmission::Velocity),
        );
        assert!((force.terms.hand_ratios[0] - ff).abs() < 1e-9 * ff);
        assert!((vel.terms.hand_ratios[0] - vv).abs() < 1e-9 * vv);
        let af = angle_deg(&ef.force_major(), &d);
        let af_of_v = angle_deg(&ev.force_major(), &d);
        let av = angle_deg(&ev.velocity_major(), &d);
        let av_of_f = angle_deg(&ef.velocity_major(), &d);
        let (sf, sv) = (
            force.residuals.min_finger_separation,
            vel.residuals.min_finger_separation,
        );
        println!(
            "d = {dn}: force optimum α {ff:.2} (velocity optimum {vf:.2}), force axis {af:.1}° \
             (velocity optimum's {af_of_v:.1}°), sphere gap {:.2} mm, semi-axes {:.3?}; \
             velocity optimum β {vv:.3} (force optimum {fv:.3}), velocity axis {av:.1}° \
             (force optimum's {av_of_f:.1}°), sphere gap {:.2} mm, semi-axes {:.3?}",
            sf * 1e3,
            ef.velocity_semi_axes,
            sv * 1e3,
            ev.velocity_semi_axes
        );
        let mut check = |ok: bool, what: String| {
            if !ok {
                fails.push(format!("d = {dn}: {what}"));
            }
        };
        check(ff > vf, format!("α {ff} vs {vf}"));
        check(vv > fv, format!("β {vv} vs {fv}"));
        // Not asserted since the exact verdict: each optimum's own axis within 10° of d (see
        // the doc comment; measured 17.8°-77.6°).
        check(af < af_of_v, format!("force axes {af}° vs {af_of_v}°"));
        check(av < av_of_f, format!("velocity axes {av}° vs {av_of_f}°"));
        for (r, k) in [(&force, "force"), (&vel, "velocity")] {
            let gap = r.residuals.min_finger_separation;
            check(
                gap >= FINGER_CLEARANCE - PENETRATION_TOLERANCE,
                format!("{k} gap {gap}"),
            );
            let top = r.hand_ellipsoids.velocity_semi_axes[0];
            check(top < 2.0, format!("{k} velocity semi-axis {top}"));
        }
    }
    assert!(fails.is_empty(), "{fails:#?}");
}

/// Fig. 5: the Q_DC-optimal grasp of a cylinder has a smaller centroid distance than feasible
/// grasps found without the quality term, start by start (each pair from the same seed, so the
/// comparison is not a matter of which start landed where).
#[test]
fn claim_c_centroid_optimal_grasp_beats_random_feasible_grasps() {
    let sys = test_system();
    let cyl = Object::new(ObjectSpec {
        name: "cylinder".into(),
        shape: ShapeSpec::Cylinder {
            radius: 0.03,
            height: 0.12,
        },
        position: [0.5, 0.05, 0.16],
        orientation: [1.0, 0.0, 0.0, 0.0],
        support: Some(SupportPlane::horizontal(0.1)),
        mass: None,
        friction: None,
    })
    .unwrap();
    let mut req = GraspRequest::new(cyl, vec![], QualityMeasure::CentroidDistance);
    req.starts = 1;
    let mut pairs = 0;
    for seed in 0..6 {
        req.seed = seed;
        req.weights = Weights {
            tc: 0.0,
            gc: 0.0,
            q: 1.0,
            d: 0.0,
        };
        let best = plan_grasp(&sys, &req).unwrap();
        req.weights.q = 0.0;
        let random = plan_grasp(&sys, &req).unwrap();
        if !(best.feasible && random.feasible) {
            continue;
        }
        pairs += 1;
        assert!(
            best.terms.q_dc <= random.terms.q_dc + 1e-6,
            "seed {seed}: {} vs random {}",
            best.terms.q_dc,
            random.terms.q_dc
        );
    }
    assert!(pairs >= 3, "{pairs} seeds feasible both ways");
}

#[test]
fn an_object_out_of_reach_is_infeasible_with_a_reason() {
    let sys = test_system();
    let req = GraspRequest::new(
        ball([2.0, 0.0, 0.3], 0.033),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    let r = plan_grasp(&sys, &req).unwrap();
    assert!(!r.feasible);
    let reason = r.reason.unwrap();
    assert!(reason.contains("out of reach"), "{reason}");
    assert!(r.residuals.max_surface_distance > 0.5);
    // Beyond the reach ball: no further rounds of starts.
    assert_eq!(r.starts_used, req.starts);
}

/// The reach ball contains every fingertip contact sphere at 2,000 random configurations of
/// each bundled system (forward kinematics, not the bound's own sum), and is not loose: the
/// farthest sampled sphere reaches beyond 80 % of its radius.
#[test]
fn the_reach_ball_contains_every_sampled_fingertip() {
    use rand::{RngExt, SeedableRng};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    for name in [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ] {
        let s = crate::kinematics::System::from_file(&dir.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        let (c, r) = sys.reach_ball().expect("revolute chains");
        let model = &*sys.model;
        let mut data = Data::new(model);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut farthest: f64 = 0.0;
        for _ in 0..2000 {
            let q: Vec<f64> = (0..model.nq())
                .map(|k| {
                    let (lo, hi) = (model.lower_limits()[k], model.upper_limits()[k]);
                    rng.random_range(lo.max(-3.2)..=hi.min(3.2))
                })
                .collect();
            forward_kinematics(model, &mut data, &q);
            for f in &sys.fingers {
                let p = f.contact_point(&data);
                let d = (p - c).norm() + f.radius;
                assert!(d <= r + 1e-9, "{name}: {d} > {r}");
                farthest = farthest.max(d);
            }
        }
        assert!(farthest > 0.8 * r, "{name}: farthest {farthest}, bound {r}");
    }
}

#[test]
fn bad_requests_are_rejected_naming_the_field() {
    let sys = test_system();
    let mut req = GraspRequest::new(
        ball([0.5, 0.0, 0.2], 0.03),
        vec![dir(Vector3::x(), Transmission::Force)],
        QualityMeasure::PolygonArea,
    );
    assert_eq!(
        plan_grasp(&sys, &req).unwrap_err(),
        GraspError::UnusableQuality {
            measure: "polygon_area",
            needed: 3,
            fingers: 2
        }
    );
    req.quality = QualityMeasure::CentroidDistance;
    req.task[0].direction = Vector3::zeros();
    assert_eq!(
        plan_grasp(&sys, &req).unwrap_err(),
        GraspError::InvalidDirection { index: 0 }
    );
    req.task[0].direction = Vector3::new(f64::NAN, 0.0, 1.0);
    assert_eq!(
        plan_grasp(&sys, &req).unwrap_err(),
        GraspError::InvalidDirection { index: 0 }
    );
    req.task.clear();
    req.weights.gc = -1.0;
    assert_eq!(
        plan_grasp(&sys, &req).unwrap_err(),
        GraspError::InvalidWeight {
            field: "gc",
            value: -1.0
        }
    );
    req.weights.gc = 0.0;
    req.weights.d = f64::NAN;
    assert!(matches!(
        plan_grasp(&sys, &req).unwrap_err(),
        GraspError::InvalidWeight { field: "d", .. }
    ));
}

/// Not a claim: prints feasible rate and timing over the seeded objects on the test system
/// (the real figures come from `benches/grasp.rs`).
#[test]
#[ignore]
fn survey_seeded_objects_on_the_test_system() {
    let sys = test_system();
    let mut times = Vec::new();
    let mut feasible = 0;
    let mut total = 0;
    for (name, _, _) in crate::grasp::objects::seeded_shapes() {
        for (x, y) in [(0.45, 0.0), (0.5, 0.15), (0.4, -0.2), (0.55, -0.05)] {
            let obj = Object::new(crate::grasp::objects::seeded_object(name, x, y, 0.1).unwrap())
                .unwrap();
            let req = GraspRequest::new(obj, vec![], QualityMeasure::CentroidDistance);
            let r = plan_grasp(&sys, &req).unwrap();
            total += 1;
            if r.feasible {
                feasible += 1;
            } else {
                println!("{name} at ({x}, {y}): {:?} {:?}", r.reason, r.residuals);
            }
            times.push(r.time_s * 1e3);
        }
    }
    times.sort_by(f64::total_cmp);
    println!(
        "feasible {feasible}/{total}, median {:.1} ms, max {:.1} ms",
        times[times.len() / 2],
        times[times.len() - 1]
    );
}

pub(crate) fn real_systems() -> Vec<HandArm> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    [
        "wam_t42",
        "wam_ihy",
        "wam_ob4f",
        "pa10_t42",
        "pa10_ihy",
        "pa10_ob4f",
    ]
    .iter()
    .map(|n| {
        let s = crate::kinematics::System::from_file(&dir.join(format!("{n}.toml"))).unwrap();
        HandArm::from_system(&s).unwrap()
    })
    .collect()
}

/// Recheck a grasp against the real geometry from its joint values alone (not from the result's
/// own verdict fields): a fresh exact checker over the object and its support, every pair; each
/// finger's pad (the shapes on its tip's rigid body) within 1 mm of the object and its pad
/// normal within 60° of the contact normal; joint limits and couplings exact. `Err` names what
/// fails.
fn recheck_exact(sys: &HandArm, obj: &Object, r: &GraspResult) -> Result<(), String> {
    use crate::geometry::{Category, CollisionChecker, Plane, Scene, SceneShape, Target};
    let model = &*sys.model;
    let mut q = model.neutral();
    for j in r.q_arm.iter().chain(&r.q_hand) {
        let k = model
            .q_index(&j.name)
            .ok_or(format!("unknown joint {}", j.name))?;
        if j.value < model.lower_limits()[k] || j.value > model.upper_limits()[k] {
            return Err(format!("{} = {} outside its limits", j.name, j.value));
        }
        q[k] = j.value;
    }
    let (shape, pose) = obj.shape();
    let mut scene = Scene::new().with_object(SceneShape::new("object", shape.clone(), *pose));
    if let Some(p) = obj.support().and_then(|sp| Plane::try_from(sp).ok()) {
        scene = scene.with_support(p);
    }
    let checker = CollisionChecker::new(sys.geometry.clone(), scene);
    let mut cd = checker.data();
    let c = checker.clearance(&mut cd, &q);
    for (cat, need) in [
        (Category::Object, -1e-3),
        (Category::Support, -1e-3),
        (Category::SelfCollision, 0.0),
    ] {
        let d = c.category_distance(cat);
        if d < need {
            let l = checker.label(c.category(cat).unwrap().pair);
            return Err(format!("{} / {}: {:.2} mm", l.link, l.other, d * 1e3));
        }
    }
    let geo = &sys.geometry;
    // Every finger is on the object or idle (then only clear of it, above), at least two on it.
    let on: Vec<&str> = r.contacts.iter().map(|c| c.finger.as_str()).collect();
    if on.len() < 2 || on.len() + r.idle_fingers.len() != sys.fingers.len() {
        return Err(format!("contacts {on:?}, idle {:?}", r.idle_fingers));
    }
    for f in sys.fingers.iter().filter(|f| on.contains(&f.name.as_str())) {
        let tip_body = geo.body(f.tip);
        let mut best: Option<crate::geometry::SignedDistance> = None;
        for (p, pair) in checker.pairs().iter().enumerate() {
            if pair.other == Target::Object && geo.body(geo.shapes()[pair.shape].frame) == tip_body
            {
                let d = checker.pair_distance(&mut cd, p);
                if best.is_none_or(|b| d.distance < b.distance) {
                    best = Some(d);
                }
            }
        }
        let d = best.ok_or(format!("finger {} has no pad shape", f.name))?;
        if d.distance.abs() > 1e-3 {
            return Err(format!(
                "pad of {} {:.2} mm from the object",
                f.name,
                d.distance * 1e3
            ));
        }
        let n_pad = cd.kinematics().frame(f.tip).rotation * f.pad_normal;
        let angle = n_pad.dot(&d.normal).clamp(-1.0, 1.0).acos().to_degrees();
        if angle > 60.0 {
            return Err(format!("contact of {} {angle:.0}° off its pad", f.name));
        }
    }
    if r.residuals.max_coupling_error > 1e-12 || r.residuals.max_spread_violation > 1e-9 {
        return Err(format!("couplings or spread: {:?}", r.residuals));
    }
    Ok(())
}

/// Claim (d), under the exact verdict: for every shipped system and every seeded object at the
/// documented reachable placements (90 default requests, 4 starts), every grasp reported
/// feasible holds against the real geometry when rechecked from its joint values
/// ([`recheck_exact`]: penetration ≤ 1 mm into the object and the table, no two links
/// intersecting, every pad of a finger on the object within 1 mm of the surface and 60° of the
/// contact normal, idle fingers clear of it), and at least 95 % of the 90 are feasible
/// (issue 23's bar; measured: 90, 39 before grasps could leave fingers idle).
///
/// Changed with the exact verdict (issue 23): the claim used to be "all 90 feasible" on the
/// optimiser's sphere model, under which 0 of the 90 were clean against the URDF collision
/// shapes (links 7-17 mm deep, median).
#[test]
fn claim_d_every_feasible_grasp_of_a_seeded_object_holds_on_the_real_geometry() {
    use crate::grasp::objects::{REACHABLE_PLACEMENTS, seeded_object, seeded_shapes};
    let (mut feasible, mut total) = (0, 0);
    let mut bad = Vec::new();
    for sys in real_systems() {
        for (name, _, _) in seeded_shapes() {
            for (x, y) in REACHABLE_PLACEMENTS {
                let obj = Object::new(seeded_object(name, x, y, 0.0).unwrap()).unwrap();
                let req = GraspRequest::new(obj.clone(), vec![], QualityMeasure::CentroidDistance);
                let r = plan_grasp(&sys, &req).unwrap();
                total += 1;
                let at = format!("{} {name} at ({x}, {y})", sys.name);
                if !r.feasible {
                    println!("{at}: {:?}", r.reason);
                    continue;
                }
                feasible += 1;
                if let Err(e) = recheck_exact(&sys, &obj, &r) {
                    bad.push(format!("{at}: {e}"));
                }
                if !r.exact.passed || r.reason.is_some() {
                    bad.push(format!("{at}: feasible but {:?} {:?}", r.exact, r.reason));
                }
            }
        }
    }
    println!("feasible {feasible}/{total}");
    assert!(bad.is_empty(), "{bad:#?}");
    // Measured 90 of 90 (deterministic: iteration budgets).
    assert!(feasible * 100 >= 95 * total, "feasible {feasible}/{total}");
}

#[test]
#[ignore]
fn survey_real_systems() {
    for sys in real_systems() {
        let mut times = Vec::new();
        let mut feasible = 0;
        let mut exact = 0;
        let mut pens = Vec::new();
        let mut total = 0;
        for (name, _, _) in crate::grasp::objects::seeded_shapes() {
            for (x, y) in [(0.5, 0.0), (0.55, 0.15), (0.45, -0.2)] {
                let obj =
                    Object::new(crate::grasp::objects::seeded_object(name, x, y, 0.0).unwrap())
                        .unwrap();
                let req = GraspRequest::new(obj, vec![], QualityMeasure::CentroidDistance);
                let r = plan_grasp(&sys, &req).unwrap();
                total += 1;
                exact += r.exact.passed as usize;
                pens.push(
                    r.exact
                        .max_object_penetration
                        .max(r.exact.max_support_penetration)
                        .max(-r.exact.min_link_separation),
                );
                if r.feasible {
                    feasible += 1;
                } else {
                    println!("  {} {name} at ({x}, {y}): {:?}", sys.name, r.reason);
                }
                times.push(r.time_s * 1e3);
            }
        }
        times.sort_by(f64::total_cmp);
        pens.sort_by(f64::total_cmp);
        println!(
            "{}: spheres {}, feasible {feasible}/{total}, exact check passed {exact}/{total} \
             (worst exact penetration per grasp: median {:.1} mm, max {:.1} mm), median {:.1} ms, \
             max {:.1} ms",
            sys.name,
            sys.link_spheres.len(),
            pens[pens.len() / 2] * 1e3,
            pens[pens.len() - 1] * 1e3,
            times[times.len() / 2],
            times[times.len() - 1]
        );
    }
}

/// Not a claim: the survey behind `claim_b_holds_on_the_wam_and_the_pa10`. For each system,
/// ball placement, direction and kind it runs every start on its own and prints the lowest-cost
/// feasible start's angle between d and its own ellipsoid's major axis, its ratio, the smallest
/// angle over the feasible starts, and the other ellipsoid's angle and ratio. Knobs (environment):
/// `CB_SYSTEMS=wam_t42,wam_ihy,pa10_t42`, `CB_PLACES=x:y:table,...` (default `0.5:0:0`),
/// `CB_DIRS=x,y,z` (or `a/b/c`), `CB_KINDS=force,velocity`, `CB_STARTS=12`, `CB_CAP_MS=150`
/// (per-start wall cap), `CB_Q=0.1` (w_Q), `CB_GC=1` (GC instead of TC, hand ellipsoids: Fig. 6),
/// `CB_VERBOSE=1` (every start). E.g. `CB_STARTS=48 cargo test --lib survey_claim_b -- --ignored
/// --nocapture`.
#[test]
#[ignore]
fn survey_claim_b_alignment() {
    use crate::grasp::objects::seeded_object;
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let systems = env("CB_SYSTEMS", "wam_t42,wam_ihy,pa10_t42");
    let starts: usize = env("CB_STARTS", "12").parse().unwrap();
    let cap_ms: u64 = env("CB_CAP_MS", "150").parse().unwrap();
    let wq: f64 = env("CB_Q", "0.1").parse().unwrap();
    let places = env("CB_PLACES", "0.5:0.0:0.0");
    let dirs_s = env("CB_DIRS", "x,y,z");
    let kinds_s = env("CB_KINDS", "force,velocity");
    let verbose = std::env::var_os("CB_VERBOSE").is_some();
    let dir_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    for name in systems.split(',') {
        let s =
            crate::kinematics::System::from_file(&dir_path.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        for place in places.split(',') {
            let p: Vec<f64> = place.split(':').map(|v| v.parse().unwrap()).collect();
            let mut line = format!("{name} ball at ({}, {}) table {}:", p[0], p[1], p[2]);
            for dn in dirs_s.split(',') {
                let d = match dn {
                    "x" => Vector3::x(),
                    "y" => Vector3::y(),
                    "z" => Vector3::z(),
                    _ => {
                        let v: Vec<f64> = dn.split('/').map(|v| v.parse().unwrap()).collect();
                        Vector3::new(v[0], v[1], v[2]).normalize()
                    }
                };
                for kn in kinds_s.split(',') {
                    let kind = if kn == "force" {
                        Transmission::Force
                    } else {
                        Transmission::Velocity
                    };
                    let obj =
                        Object::new(seeded_object("ball", p[0], p[1], p[2]).unwrap()).unwrap();
                    let mut req = GraspRequest::new(
                        obj,
                        vec![dir(d, kind)],
                        QualityMeasure::CentroidDistance,
                    );
                    req.weights.q = wq;
                    let hand = std::env::var_os("CB_GC").is_some();
                    if hand {
                        req.weights.tc = 0.0;
                        req.weights.gc = 1.0;
                    }
                    let mut settings = solver_settings();
                    settings.max_duration = Some(Duration::from_millis(cap_ms));
                    let mut rows = Vec::new();
                    for k in 0..starts {
                        let o = run_start_with(&sys, &req, k, settings.clone());
                        let r = describe(&sys, &req, &o.u, None);
                        let e = if hand {
                            &r.hand_ellipsoids
                        } else {
                            &r.arm_ellipsoids
                        };
                        let own_ratio = if hand {
                            r.terms.hand_ratios[0]
                        } else {
                            r.terms.arm_ratios[0]
                        };
                        let axis = match kind {
                            Transmission::Force => e.force_major(),
                            Transmission::Velocity => e.velocity_major(),
                        };
                        let ang = angle_deg(&axis, &d);
                        let comps: Vec<f64> = (0..3)
                            .map(|k| Vector3::from(e.axes[k]).dot(&d).abs())
                            .collect();
                        if verbose && hand {
                            let pts: Vec<Vector3<f64>> =
                                r.contacts.iter().map(|c| Vector3::from(c.point)).collect();
                            let mut closest = f64::INFINITY;
                            for i in 0..pts.len() {
                                for j in i + 1..pts.len() {
                                    closest = closest.min((pts[i] - pts[j]).norm());
                                }
                            }
                            println!(
                                "  {name} {dn} {kn} start {k}: hand ratio {own_ratio:.3}, contact polygon area {:.2e} m², closest contact pair {:.1} mm, hand semi-axes {:.3?}",
                                r.terms.q_agp,
                                closest * 1e3,
                                e.velocity_semi_axes
                            );
                        }
                        if verbose {
                            println!(
                                "  {name} {dn} {kn} start {k}: feas {} {:?} it {} {:.0} ms cost {:.4} ratio {:.3} angle {ang:.1} vel semi-axes {:.3?} |d.axis| {comps:.2?} q_arm {:?}",
                                o.feasible,
                                o.report.status,
                                o.report.iterations,
                                o.report.time.as_secs_f64() * 1e3,
                                o.report.cost,
                                r.terms.arm_ratios[0],
                                e.velocity_semi_axes,
                                r.q_arm
                                    .iter()
                                    .map(|j| (j.value * 100.0).round() / 100.0)
                                    .collect::<Vec<_>>()
                            );
                        }
                        let (other_axis, other_kind) = match kind {
                            Transmission::Force => (e.velocity_major(), Transmission::Velocity),
                            Transmission::Velocity => (e.force_major(), Transmission::Force),
                        };
                        let mut m = Matrix3::zeros();
                        for k in 0..3 {
                            let a = Vector3::from(e.axes[k]);
                            m += a * a.transpose() * e.velocity_semi_axes[k].powi(2);
                        }
                        let other_ratio = indexes::transmission_ratio(&m, &d, other_kind);
                        rows.push((
                            o.feasible,
                            o.report.cost,
                            ang,
                            own_ratio,
                            angle_deg(&other_axis, &d),
                            other_ratio,
                        ));
                    }
                    let feas: Vec<_> = rows.iter().filter(|r| r.0).collect();
                    let best = feas.iter().min_by(|a, b| a.1.total_cmp(&b.1));
                    let min_ang = feas.iter().map(|r| r.2).fold(f64::INFINITY, f64::min);
                    match best {
                        Some(b) => {
                            line += &format!(
                                " {dn}/{kn} {:.1}° (r {:.3}, min {min_ang:.1}°, {}/{starts}; other axis {:.1}°, other ratio {:.3})",
                                b.2,
                                b.3,
                                feas.len(),
                                b.4,
                                b.5
                            )
                        }
                        None => line += &format!(" {dn}/{kn} infeasible"),
                    }
                }
            }
            println!("{line}");
        }
    }
}

/// The wam_t42 system and a request for one task direction on a seeded object at (0.5, 0).
fn wam_t42_request(
    object: &str,
    direction: Vector3<f64>,
    kind: Transmission,
) -> (HandArm, GraspRequest) {
    let systems = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let s = crate::kinematics::System::from_file(&systems.join("wam_t42.toml")).unwrap();
    let sys = HandArm::from_system(&s).unwrap();
    let obj =
        Object::new(crate::grasp::objects::seeded_object(object, 0.5, 0.0, 0.0).unwrap()).unwrap();
    let req = GraspRequest::new(
        obj,
        vec![dir(direction, kind)],
        QualityMeasure::CentroidDistance,
    );
    (sys, req)
}

/// The wam_t42 system and a request to lift the seeded bottle at (0.5, 0) along z.
fn wam_t42_bottle_lift() -> (HandArm, GraspRequest) {
    wam_t42_request("bottle", Vector3::z(), Transmission::Force)
}

/// While no start is exactly feasible the search runs further rounds (4, then 8 more, ...) up to
/// `max_starts`, and stops at the first round with a feasible start. The wam_t42 pencil with a
/// force task along x has no feasible start among the first 4 (the exact-verdict survey) but has
/// one within 32. The rounds are one prefix of a fixed start sequence: the escalated answer is the
/// answer of a single round of that many starts.
#[test]
fn an_infeasible_first_round_escalates_until_a_start_is_feasible() {
    let (sys, mut req) = wam_t42_request("pencil", Vector3::x(), Transmission::Force);
    let answer = |req: &GraspRequest| {
        let mut r = plan_grasp(&sys, req).unwrap();
        r.time_s = 0.0;
        if let Some(s) = r.solver.as_mut() {
            s.time_s = 0.0;
        }
        r
    };
    req.starts = 4;
    req.max_starts = 4;
    let first = answer(&req);
    assert!(!first.feasible);
    assert_eq!((first.starts_used, first.starts_feasible), (4, 0));

    req.max_starts = 32;
    let escalated = answer(&req);
    assert!(escalated.feasible, "{:?}", escalated.reason);
    let used = escalated.starts_used;
    assert!([8, 16, 32].contains(&used), "{used}");
    assert!(escalated.starts_feasible >= 1);
    // The round before the last had no feasible start.
    req.max_starts = used / 2;
    assert_eq!(answer(&req).starts_feasible, 0);
    // One round of `used` starts gives the same answer.
    req.starts = used;
    req.max_starts = used;
    assert_eq!(
        serde_json::to_string(&answer(&req)).unwrap(),
        serde_json::to_string(&escalated).unwrap()
    );
}

/// A request whose first round has feasible starts, none with contacts that can balance (the
/// opposition `d` of the contact normals above [`FIRM_BALANCE`]), runs further rounds and answers
/// with a firm one. The reported opposition is checked against the closed form for two
/// contacts, `d = ‖n₁ + n₂‖/2 = cos(θ/2)` with θ the angle between their normals.
#[test]
fn a_feasible_start_whose_contacts_cannot_balance_escalates_until_a_firm_one() {
    let (sys, mut req) = wam_t42_request("sunglasses", Vector3::y(), Transmission::Force);
    let two_contact = |r: &GraspResult| {
        let n: Vec<Vector3<f64>> = r.contacts.iter().map(|c| Vector3::from(c.normal)).collect();
        assert_eq!(n.len(), 2);
        let d = (n[0].normalize() + n[1].normalize()).norm() / 2.0;
        assert!(
            (d - r.exact.normal_balance).abs() < 1e-9,
            "{d} vs {}",
            r.exact.normal_balance
        );
        d
    };
    req.starts = 4;
    req.max_starts = 4;
    let first = plan_grasp(&sys, &req).unwrap();
    req.max_starts = 32;
    let escalated = plan_grasp(&sys, &req).unwrap();
    assert!(
        first.feasible && first.starts_feasible >= 1,
        "{:?}",
        first.reason
    );
    assert!(two_contact(&first) > FIRM_BALANCE);
    // the answer says so: feasible, not firm
    assert!(first.exact.passed && !first.exact.firm);
    assert!(escalated.feasible && escalated.starts_used > 4);
    assert!(two_contact(&escalated) <= FIRM_BALANCE);
    assert!(escalated.exact.firm);
    // a grasp stored before `firm` existed gets it from its verdict and balance when read
    for r in [&first, &escalated] {
        let mut stored = serde_json::to_value(r).unwrap();
        stored["exact"].as_object_mut().unwrap().remove("firm");
        let read = GraspResult::from_stored(&stored.to_string()).unwrap();
        assert_eq!(read.exact.firm, two_contact(r) <= FIRM_BALANCE);
    }
}

/// Determinism: the same request twice, the second time while busy threads load every core,
/// gives a bit-identical answer (timings aside). With the former 150 ms per-start wall cap the
/// second answer ended at other iterates whenever the load slowed a start down.
#[test]
fn the_same_request_under_load_gives_the_identical_answer() {
    use std::sync::atomic::{AtomicBool, Ordering};
    let (sys, mut req) = wam_t42_bottle_lift();
    req.starts = 4;
    req.threads = 2;
    let answer = || {
        let mut r = plan_grasp(&sys, &req).unwrap();
        assert!(!r.timed_out);
        r.time_s = 0.0;
        if let Some(s) = r.solver.as_mut() {
            s.time_s = 0.0;
        }
        serde_json::to_string(&r).unwrap()
    };
    let idle = answer();
    let stop = AtomicBool::new(false);
    let loaded = std::thread::scope(|scope| {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        for _ in 0..2 * cores {
            scope.spawn(|| {
                let mut x = 0u64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            });
        }
        let a = answer();
        stop.store(true, Ordering::Relaxed);
        a
    });
    assert_eq!(idle, loaded);
}

/// Every bundled hand's descriptor puts the pad on the flexion side: closing a finger (raising
/// its joints towards their upper limits, where the bundled hands are closed) moves the contact
/// point along the pad normal, at the open, half-closed and nearly closed hand.
#[test]
fn pad_normals_face_the_flexion_side_on_every_bundled_hand() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    for name in ["wam_t42", "wam_ihy", "wam_ob4f"] {
        let s = crate::kinematics::System::from_file(&dir.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        let model = &*sys.model;
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let mut data = Data::new(model);
        for t in [0.05, 0.5, 0.9] {
            let mut q = model.neutral();
            for &h in &sys.hand_joints {
                q[h] = lo[h] + t * (hi[h] - lo[h]);
            }
            for (fi, f) in sys.fingers.iter().enumerate() {
                let tip_of = |q: &[f64], data: &mut Data| {
                    forward_kinematics(model, data, q);
                    let x = data.frame(f.tip);
                    (x * Point3::from(f.tip_offset), x.rotation * f.pad_normal)
                };
                let (p0, n0) = tip_of(&q, &mut data);
                // The joint that flexes the distal phalanx (the moving joint nearest the tip;
                // its driver for a coupled joint).
                let mut fr = f.tip;
                let qi = loop {
                    let j = model.joint_of_frame(fr).unwrap();
                    if !j.kind.is_fixed() {
                        break j.actuation.unwrap().q_index;
                    }
                    fr = model.frame_parent(fr).unwrap();
                };
                let mut qc = q.clone();
                qc[qi] = (q[qi] + 0.02).min(hi[qi]);
                let (p1, _) = tip_of(&qc, &mut data);
                let step = p1 - p0;
                assert!(step.norm() > 1e-4, "{name} finger {fi}: no flexion joint");
                let cos = step.normalize().dot(&n0);
                assert!(
                    cos > 0.5,
                    "{name} finger {fi} at {t}: closing moves the tip {:.0} deg off the pad normal",
                    cos.acos().to_degrees()
                );
            }
        }
    }
}

/// No bundled hand is physically impossible within its joint limits (exact parry distances):
/// - at the open hand (every hand coordinate at its lower limit) no two non-adjacent links of the
///   system touching the hand intersect, and links of different fingers are at least 5 mm apart
///   (the old OB4F thumb stood 3.5 mm in front of the middle finger);
/// - at 300 seeded postures per hand, every hand coordinate uniform within its limits, no finger
///   link intersects the palm, the wrist or the arm, nor a non-adjacent link of its own finger
///   (the old T42 distal phalanges passed through the base from 80 % closure, the old OB4F thumb
///   distal through the palm). Two different fingers may meet at such postures, as a real
///   hand's fingers do when closed on nothing; the grasp verdict rejects any grasp where they
///   intersect.
#[test]
fn no_bundled_hand_intersects_itself_within_its_joint_limits() {
    use crate::geometry::{CollisionChecker, Scene, Target};
    use crate::kinematics::FrameId;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let mut fails = Vec::new();
    for name in ["wam_t42", "wam_ihy", "wam_ob4f"] {
        let before = fails.len();
        let s = crate::kinematics::System::from_file(&dir.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        let model = &*sys.model;
        let checker = CollisionChecker::new(sys.geometry.clone(), Scene::new());
        let shapes = sys.geometry.shapes();
        // Finger of a frame: the only finger whose tip chain contains it, when a hand joint
        // moves it (independent reference: the chains walked here, not the geometry's tags).
        let chain = |tip: FrameId| {
            let mut c = vec![tip];
            while let Some(p) = model.frame_parent(*c.last().unwrap()) {
                c.push(p);
            }
            c
        };
        let chains: Vec<Vec<FrameId>> = sys.fingers.iter().map(|f| chain(f.tip)).collect();
        let finger_of = |f: FrameId| {
            let moved = model
                .supporting_q(f)
                .iter()
                .any(|q| sys.hand_joints.contains(q));
            let on: Vec<usize> = (0..chains.len())
                .filter(|&k| chains[k].contains(&f))
                .collect();
            (moved && on.len() == 1).then(|| on[0])
        };
        let on_hand = |i: usize| {
            model
                .supporting_q(shapes[i].frame)
                .iter()
                .any(|q| sys.hand_joints.contains(q))
        };
        let pairs: Vec<(usize, Option<usize>, Option<usize>)> = (0..checker.pairs().len())
            .filter_map(|p| match checker.pairs()[p].other {
                Target::Shape(j) if on_hand(checker.pairs()[p].shape) || on_hand(j) => Some((
                    p,
                    finger_of(shapes[checker.pairs()[p].shape].frame),
                    finger_of(shapes[j].frame),
                )),
                _ => None,
            })
            .collect();
        assert!(pairs.len() >= 10, "{name}: {} pairs", pairs.len());
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let mut q = model.neutral();
        for &h in &sys.hand_joints {
            q[h] = lo[h];
        }
        let mut cd = checker.data();
        checker.update(&mut cd, &q);
        for &(p, fa, fb) in &pairs {
            let d = checker.pair_distance(&mut cd, p).distance;
            let need = if fa.is_some() && fb.is_some() && fa != fb {
                5e-3
            } else {
                0.0
            };
            if d < need {
                let l = checker.label(p);
                fails.push(format!(
                    "{name} open hand: {} / {} {:.1} mm apart (at least {:.0} mm)",
                    l.link,
                    l.other,
                    d * 1e3,
                    need * 1e3
                ));
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(23);
        for k in 0..300 {
            for &h in &sys.hand_joints {
                q[h] = rng.random_range(lo[h]..=hi[h]);
            }
            checker.update(&mut cd, &q);
            for &(p, fa, fb) in &pairs {
                if fa.is_some() && fb.is_some() && fa != fb {
                    continue;
                }
                let d = checker.pair_distance(&mut cd, p).distance;
                if d < 0.0 {
                    let l = checker.label(p);
                    let hq: Vec<String> = sys
                        .hand_joints
                        .iter()
                        .map(|&h| format!("{:.2}", q[h]))
                        .collect();
                    fails.push(format!(
                        "{name} posture {k} [{}]: {} / {} intersect by {:.1} mm",
                        hq.join(", "),
                        l.link,
                        l.other,
                        -d * 1e3
                    ));
                }
            }
        }
        fails.truncate(before + 12);
    }
    assert!(fails.is_empty(), "{fails:#?}");
}

/// Not a claim: per start of one request, the solver's iterations, status, time and the exact
/// distance queries it ran (`G_SYS=wam_t42 G_OBJ=bottle cargo test --lib profile_one_request --
/// --ignored --nocapture`).
#[test]
#[ignore]
fn profile_one_request() {
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let systems = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let s = crate::kinematics::System::from_file(
        &systems.join(format!("{}.toml", env("G_SYS", "wam_t42"))),
    )
    .unwrap();
    let sys = HandArm::from_system(&s).unwrap();
    let obj = Object::new(
        crate::grasp::objects::seeded_object(&env("G_OBJ", "bottle"), 0.5, 0.0, 0.0).unwrap(),
    )
    .unwrap();
    let req = GraspRequest::new(
        obj,
        vec![dir(Vector3::z(), Transmission::Force)],
        QualityMeasure::CentroidDistance,
    );
    for k in 0..req.starts {
        println!("start {k}:");
        let o = run_start(&sys, &req, k);
        let r = describe(&sys, &req, &o.u, None);
        println!(
            "  {:?} it {} outer {} {:.0} ms feasible {} violation {:.2e} res {:?}",
            o.report.status,
            o.report.iterations,
            o.report.outer_iterations,
            o.report.time.as_secs_f64() * 1e3,
            o.feasible,
            o.report.max_constraint_violation,
            r.residuals
        );
    }
}

/// Not a claim: the exact-verdict survey of the closing note. Over the seeded objects at
/// (0.5, 0) x the six systems x {force, velocity} x {x, y, z} (TC weight 1, default request),
/// per system: feasible count under the exact verdict, the worst exact penetration per grasp
/// (object, support or self, max over links; median and max) and the grasp time per request,
/// plus every infeasible reason (`SV_SYSTEMS=wam_t42,... SV_OBJECTS=pencil,... SV_STARTS=4
/// SV_MAX_STARTS=4 SV_VERBOSE=1 cargo test --lib survey_exact_verdict -- --ignored --nocapture`;
/// without `SV_MAX_STARTS` the starts escalate as the service's do).
#[test]
#[ignore]
fn survey_exact_verdict() {
    use crate::grasp::objects::{seeded_object, seeded_shapes};
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let systems = env(
        "SV_SYSTEMS",
        "wam_t42,wam_ihy,wam_ob4f,pa10_t42,pa10_ihy,pa10_ob4f",
    );
    let verbose = std::env::var_os("SV_VERBOSE").is_some();
    let starts: usize = env("SV_STARTS", "4").parse().unwrap();
    // Without `SV_MAX_STARTS` the request's default cap: the service's escalation.
    let max_starts: Option<usize> = std::env::var("SV_MAX_STARTS")
        .ok()
        .map(|v| v.parse().unwrap());
    let objects = env("SV_OBJECTS", "ball,bottle,kitchen_timer,pencil,sunglasses");
    let dir_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let (mut all_feasible, mut all_total) = (0, 0);
    let mut all_pens = Vec::new();
    for name in systems.split(',') {
        let s =
            crate::kinematics::System::from_file(&dir_path.join(format!("{name}.toml"))).unwrap();
        let sys = HandArm::from_system(&s).unwrap();
        let (mut feasible, mut total, mut firm, mut fewer) = (0, 0, 0, 0);
        let mut pens = Vec::new();
        let mut times = Vec::new();
        for (obj_name, _, _) in seeded_shapes() {
            if !objects.split(',').any(|o| o == obj_name) {
                continue;
            }
            for kind in [Transmission::Force, Transmission::Velocity] {
                for (dn, d) in [
                    ("x", Vector3::x()),
                    ("y", Vector3::y()),
                    ("z", Vector3::z()),
                ] {
                    let obj = Object::new(seeded_object(obj_name, 0.5, 0.0, 0.0).unwrap()).unwrap();
                    let mut req = GraspRequest::new(
                        obj,
                        vec![dir(d, kind)],
                        QualityMeasure::CentroidDistance,
                    );
                    req.starts = starts;
                    if let Some(m) = max_starts {
                        req.max_starts = m;
                    }
                    let r = plan_grasp(&sys, &req).unwrap();
                    total += 1;
                    let pen = r
                        .exact
                        .max_object_penetration
                        .max(r.exact.max_support_penetration)
                        .max(-r.exact.min_link_separation);
                    pens.push(pen);
                    times.push(r.time_s * 1e3);
                    if r.feasible {
                        feasible += 1;
                        firm += usize::from(r.exact.normal_balance <= FIRM_BALANCE);
                        fewer += usize::from(!r.idle_fingers.is_empty());
                        if verbose {
                            println!(
                                "  {name} {obj_name} {kind:?} {dn}: balance {:.3}, idle {:?}, \
                                 {:.0} ms",
                                r.exact.normal_balance,
                                r.idle_fingers,
                                r.time_s * 1e3
                            );
                        }
                    } else if verbose {
                        println!("  {name} {obj_name} {kind:?} {dn}: {:?}", r.reason);
                    }
                }
            }
        }
        times.sort_by(f64::total_cmp);
        pens.sort_by(f64::total_cmp);
        println!(
            "{name}: feasible (exact) {feasible}/{total} ({firm} firm, {fewer} with fewer \
             fingers); worst exact penetration per grasp median {:.2} mm, max {:.2} mm; time \
             median {:.0} ms, max {:.0} ms",
            pens[pens.len() / 2] * 1e3,
            pens[pens.len() - 1] * 1e3,
            times[times.len() / 2],
            times[times.len() - 1]
        );
        all_feasible += feasible;
        all_total += total;
        all_pens.extend(pens);
    }
    all_pens.sort_by(f64::total_cmp);
    println!(
        "all: feasible (exact) {all_feasible}/{all_total}; worst exact penetration per grasp \
         median {:.2} mm, 90th percentile {:.2} mm, max {:.2} mm",
        all_pens[all_pens.len() / 2] * 1e3,
        all_pens[all_pens.len() * 9 / 10] * 1e3,
        all_pens[all_pens.len() - 1] * 1e3
    );
}

/// Distance between a segment `[a, b]` and a point (closed form), for the independent check below.
fn segment_point_distance(a: &Point3<f64>, b: &Point3<f64>, p: &Point3<f64>) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (a + ab * t - p).norm()
}

/// The contact repair puts a finger that was pressed into the ball, or opened off it, back onto
/// its surface: afterwards the deepest of that finger's links is within [-0.5, +0.25] mm of the
/// ball. Checked against closed-form capsule-sphere distances of the test system's finger
/// capsules (not the exact checker the repair uses).
#[test]
fn contact_repair_puts_a_displaced_finger_back_onto_the_object() {
    let sys = test_system();
    let (center, radius) = ([0.5, 0.1, 0.2], 0.033);
    let req = GraspRequest::new(
        ball(center, radius),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    let r = plan_grasp(&sys, &req).unwrap();
    assert!(r.feasible, "{:?}", r.reason);
    let u0: Vec<f64> = r.q_arm.iter().chain(&r.q_hand).map(|j| j.value).collect();
    let na = r.q_arm.len();
    let model = &*sys.model;
    let c = Point3::from(center);
    for k in 0..2 {
        for delta in [0.15, -0.3] {
            let mut u = u0.clone();
            u[na + k] += delta;
            let mut e = Eval::new(&sys, &req);
            let note = e.repair(&mut u);
            assert!(note.is_none(), "finger {k} {delta}: {note:?}");
            let mut q = model.neutral();
            for (j, &v) in r.q_arm.iter().chain(&r.q_hand).zip(&u) {
                q[model.q_index(&j.name).unwrap()] = v;
            }
            let mut data = Data::new(model);
            forward_kinematics(model, &mut data, &q);
            // The test system's finger capsules: proximal z 0.012..0.05, distal z 0..0.036,
            // radius 8 mm, in their link frames.
            let gap = [
                (format!("f{k}_prox_link"), 0.012, 0.05),
                (format!("f{k}_dist_link"), 0.0, 0.036),
            ]
            .iter()
            .map(|(link, z0, z1)| {
                let f = data.frame(model.frame_id(link).unwrap());
                let (a, b) = (
                    f * Point3::new(0.0, 0.0, *z0),
                    f * Point3::new(0.0, 0.0, *z1),
                );
                segment_point_distance(&a, &b, &c) - 0.008 - radius
            })
            .fold(f64::INFINITY, f64::min);
            assert!(
                (-5e-4 - 1e-9..=2.5e-4 + 1e-9).contains(&gap),
                "finger {k} displaced by {delta} rad: {:.3} mm from the ball after repair",
                gap * 1e3
            );
        }
    }
}

/// Distance from a point to an axis-aligned box of half extents `he` centred at the origin
/// (closed form) and the box's closest point.
fn point_box(p: &Vector3<f64>, he: &Vector3<f64>) -> (f64, Vector3<f64>) {
    let c = Vector3::new(
        p.x.clamp(-he.x, he.x),
        p.y.clamp(-he.y, he.y),
        p.z.clamp(-he.z, he.z),
    );
    ((p - c).norm(), c)
}

/// A box collision shape of a finger link, restated from the hand's URDF: (link, box centre
/// along the link's x, half extents, the finger whose pad is its +z face if it is a distal).
type FingerBox = (String, f64, Vector3<f64>, Option<String>);

/// The pencil lying on the table (issue 23: its grasps touched it with the fingertips' ends,
/// 60-90 deg off the pads) grasped by `system` along `direction`: every finger on the object
/// touches it with its pad, every finger box (idle fingers included) stays out of the pencil and
/// above the table. Checked without the verdict's own geometry: FK gives each finger's box
/// collision shapes (`boxes`, the URDF's sizes restated); the pencil is a capsule of radius 4 mm
/// on the segment y ∈ [−85, 85] mm at (0.5, ·, 0.004). The distance from the segment to a box
/// is convex along the segment, so a ternary search over it finds the closest pair exactly; the
/// capsule's closed-form outward normal there gives each pad's angle. Every box is within the
/// verdict's bars: pads within 1 mm of the surface and 60 deg of the normal, no box more than
/// 1 mm into the pencil or under the table (its corners). Returns the result.
fn assert_pencil_grasp(
    system: &str,
    direction: Vector3<f64>,
    kind: Transmission,
    boxes: &[FingerBox],
) -> GraspResult {
    let systems = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let s = crate::kinematics::System::from_file(&systems.join(format!("{system}.toml"))).unwrap();
    let sys = HandArm::from_system(&s).unwrap();
    let obj = Object::new(crate::grasp::objects::seeded_object("pencil", 0.5, 0.0, 0.0).unwrap())
        .unwrap();
    let req = GraspRequest::new(
        obj,
        vec![dir(direction, kind)],
        QualityMeasure::CentroidDistance,
    );
    let r = plan_grasp(&sys, &req).unwrap();
    assert!(r.feasible, "{system}: {:?}", r.reason);
    let model = &*sys.model;
    let mut q = model.neutral();
    for j in r.q_arm.iter().chain(&r.q_hand) {
        q[model.q_index(&j.name).unwrap()] = j.value;
    }
    let mut data = Data::new(model);
    forward_kinematics(model, &mut data, &q);
    let (radius, half_len, z_axis) = (0.004, 0.085, 0.004);
    let axis_at = |t: f64| Vector3::new(0.5, t, z_axis);
    let mut pads = 0;
    for (link, cx, he, pad_of) in boxes {
        let pad = pad_of
            .as_ref()
            .is_some_and(|p| r.contacts.iter().any(|c| &c.finger == p));
        let f = data.frame(model.frame_id(link).unwrap());
        let local = |t: f64| {
            f.inverse_transform_point(&Point3::from(axis_at(t))).coords
                - Vector3::new(*cx, 0.0, 0.0)
        };
        let dist = |t: f64| point_box(&local(t), he).0;
        let (mut a, mut b) = (-half_len, half_len);
        for _ in 0..200 {
            let (m1, m2) = (a + (b - a) / 3.0, b - (b - a) / 3.0);
            if dist(m1) <= dist(m2) { b = m2 } else { a = m1 }
        }
        let t = 0.5 * (a + b);
        let gap = dist(t) - radius;
        assert!(
            gap >= -1e-3,
            "{system}: {link} is {:.2} mm inside the pencil",
            -gap * 1e3
        );
        for cx_s in [-1.0, 1.0] {
            for cy in [-1.0, 1.0] {
                for cz in [-1.0, 1.0] {
                    let corner = f * Point3::new(cx + cx_s * he.x, cy * he.y, cz * he.z);
                    assert!(
                        corner.z >= -1e-3,
                        "{system}: {link} corner {:.2} mm under the table",
                        -corner.z * 1e3
                    );
                }
            }
        }
        if pad {
            pads += 1;
            // The pad: the distal box's +z face (the tip frame's z, rpy 0 in the URDF).
            assert!(
                gap <= 1e-3,
                "{system}: {link} pad {:.2} mm off the pencil",
                gap * 1e3
            );
            let (_, closest) = point_box(&local(t), he);
            let axis_point = f * Point3::from(local(t) + Vector3::new(*cx, 0.0, 0.0));
            let box_point = f * Point3::from(closest + Vector3::new(*cx, 0.0, 0.0));
            // The capsule's outward normal at its point nearest the box: from the axis point
            // nearest the box, perpendicular to the axis on the cylinder part, radial from
            // the segment's end on an end cap.
            let outward = (box_point - axis_point).normalize();
            if t.abs() < half_len - 1e-6 {
                assert!(outward.y.abs() < 1e-6);
            }
            let pad_normal = f.rotation * Vector3::z();
            let angle = (-outward)
                .dot(&pad_normal)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            assert!(
                angle <= PAD_CONE_DEG,
                "{system}: {link} pad {angle:.1} deg off the pencil's normal"
            );
        }
    }
    assert_eq!(pads, r.contacts.len(), "{system}: a pad box per contact");
    r
}

/// The finger boxes of `fingers` (proximal and distal, each `(box centre, half extents)`), the
/// distal carrying the finger's pad.
fn finger_boxes(
    fingers: &[&str],
    link: impl Fn(&str, &str) -> String,
    proximal: (f64, Vector3<f64>),
    distal: (f64, Vector3<f64>),
) -> Vec<FingerBox> {
    fingers
        .iter()
        .flat_map(|f| {
            [
                (link(f, "proximal"), proximal.0, proximal.1, None),
                (link(f, "distal"), distal.0, distal.1, Some(f.to_string())),
            ]
        })
        .collect()
}

#[test]
fn pencil_grasp_touches_with_both_pads() {
    // From robots/hands/t42.urdf.
    let boxes = finger_boxes(
        &["left", "right"],
        |f, l| format!("t42_{f}_{l}"),
        (0.03125, Vector3::new(0.03125, 0.01, 0.009)),
        (0.024, Vector3::new(0.024, 0.01, 0.009)),
    );
    let r = assert_pencil_grasp("wam_t42", Vector3::x(), Transmission::Velocity, &boxes);
    assert_eq!(r.contacts.len(), 2);
    assert!(r.idle_fingers.is_empty(), "{:?}", r.idle_fingers);
}

/// The iHY cannot put all three fingertips on the pencil on its pads (a fingertip met it 90 deg
/// off the pad in every start): it picks it with two (`fewer_fingers`), the third kept clear of
/// the pencil and the table. The boxes of all three fingers are checked, the idle one's for
/// clearance only.
#[test]
fn pencil_grasp_with_fewer_fingers_keeps_the_idle_one_clear() {
    // From robots/hands/ihy.urdf.
    let boxes = finger_boxes(
        &["thumb", "finger1", "finger2"],
        |f, l| format!("ihy_{f}_{l}"),
        (0.0285, Vector3::new(0.0285, 0.011, 0.01)),
        (0.025, Vector3::new(0.025, 0.011, 0.01)),
    );
    let r = assert_pencil_grasp("wam_ihy", Vector3::z(), Transmission::Force, &boxes);
    assert_eq!(r.contacts.len(), 2, "{:?}", r.contacts);
    assert_eq!(r.idle_fingers.len(), 1, "{:?}", r.idle_fingers);
    assert!(r.contacts.iter().all(|c| c.finger != r.idle_fingers[0]));
}

/// `subsets(m, k)` lists every k-subset of `0..m` once, ascending, in lexicographic order:
/// against the bit masks of `0..2^m` with k bits set.
#[test]
fn finger_subsets_are_every_combination_once_in_order() {
    for m in 2..=5 {
        for k in 1..=m {
            let mut want: Vec<Vec<usize>> = (0u32..1 << m)
                .filter(|b| b.count_ones() as usize == k)
                .map(|b| (0..m).filter(|i| b & (1 << i) != 0).collect())
                .collect();
            want.sort();
            assert_eq!(super::subsets(m, k), want, "m = {m}, k = {k}");
        }
    }
}
