//! Tests against independent references: closed forms for primitive pairs and planes, dense
//! sampling and closed-form contact times for the continuous check, hand-computed clearances on
//! a bundled system, central differences for the distance gradient.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::shape::{Ball, Capsule, Cuboid, Cylinder, SharedShape};

use super::*;
use crate::kinematics::{JointKind, JointLimits, ModelBuilder, System};

fn iso(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::translation(x, y, z)
}

fn rot(axis: Vector3<f64>, angle: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle)
}

fn sd(a: &SharedShape, pa: Isometry3<f64>, b: &SharedShape, pb: Isometry3<f64>) -> SignedDistance {
    let mut s = QueryScratch::default();
    signed_distance(
        &Solid::new(a.clone()),
        &pa,
        &Solid::new(b.clone()),
        &pb,
        &mut s,
    )
}

/// Witness points lie `|distance|` apart along the normal.
fn check_witness(d: &SignedDistance) {
    let gap = (d.point_b - d.point_a).dot(&d.normal);
    assert!(
        (gap - d.distance).abs() < 1e-9,
        "witness gap {gap} vs distance {}",
        d.distance
    );
    assert!((d.normal.norm() - 1.0).abs() < 1e-12);
}

fn ball(r: f64) -> SharedShape {
    SharedShape::new(Ball::new(r))
}
fn cuboid(x: f64, y: f64, z: f64) -> SharedShape {
    SharedShape::new(Cuboid::new(Vector3::new(x, y, z)))
}

/// Shape a, its pose, shape b, its pose, the closed-form signed distance, the tolerance.
type PairCase = (
    SharedShape,
    Isometry3<f64>,
    SharedShape,
    Isometry3<f64>,
    f64,
    f64,
);

#[test]
fn primitive_pairs_match_closed_forms_on_both_sides_of_contact() {
    // (shape a, pose a, shape b, pose b, expected signed distance)
    let cases: Vec<PairCase> = vec![
        // balls: centre distance minus radii
        (
            ball(0.1),
            iso(0.0, 0.0, 0.0),
            ball(0.2),
            iso(0.5, 0.0, 0.0),
            0.2,
            1e-12,
        ),
        (
            ball(0.1),
            iso(0.0, 0.0, 0.0),
            ball(0.2),
            iso(0.25, 0.0, 0.0),
            -0.05,
            1e-12,
        ),
        // ball beside a box face; ball over a box edge (distance to the edge line)
        (
            cuboid(0.1, 0.2, 0.3),
            iso(0.0, 0.0, 0.0),
            ball(0.05),
            iso(0.3, 0.0, 0.0),
            0.15,
            1e-12,
        ),
        (
            cuboid(0.1, 0.2, 0.3),
            iso(0.0, 0.0, 0.0),
            ball(0.05),
            iso(0.2, 0.3, 0.0),
            (0.1f64.powi(2) + 0.1f64.powi(2)).sqrt() - 0.05,
            1e-12,
        ),
        // ball centre inside the box, 0.02 from the nearest face: depth 0.02 + r
        (
            cuboid(0.1, 0.2, 0.3),
            iso(0.0, 0.0, 0.0),
            ball(0.05),
            iso(0.08, 0.0, 0.0),
            -0.07,
            1e-12,
        ),
        // boxes side by side; overlapping by 0.01 along x (the smallest overlap)
        (
            cuboid(0.1, 0.1, 0.1),
            iso(0.0, 0.0, 0.0),
            cuboid(0.1, 0.1, 0.1),
            iso(0.25, 0.0, 0.0),
            0.05,
            1e-9,
        ),
        (
            cuboid(0.1, 0.1, 0.1),
            iso(0.0, 0.0, 0.0),
            cuboid(0.1, 0.1, 0.1),
            iso(0.19, 0.02, 0.0),
            -0.01,
            1e-9,
        ),
        // capsules (axis y in parry): parallel, and crossed at right angles
        (
            SharedShape::new(Capsule::new_y(0.2, 0.03)),
            iso(0.0, 0.0, 0.0),
            SharedShape::new(Capsule::new_y(0.1, 0.02)),
            iso(0.1, 0.05, 0.0),
            0.1 - 0.05,
            1e-12,
        ),
        (
            SharedShape::new(Capsule::new_y(0.2, 0.03)),
            iso(0.0, 0.0, 0.0),
            SharedShape::new(Capsule::new_y(0.2, 0.02)),
            Isometry3::from_parts(
                Translation3::new(0.0, 0.0, 0.04),
                rot(Vector3::z(), FRAC_PI_2),
            ),
            0.04 - 0.05,
            1e-12,
        ),
        // cylinders standing side by side (axis y): centre distance minus radii, both signs
        (
            SharedShape::new(Cylinder::new(0.1, 0.05)),
            iso(0.0, 0.0, 0.0),
            SharedShape::new(Cylinder::new(0.15, 0.04)),
            iso(0.2, 0.02, 0.0),
            0.2 - 0.09,
            1e-7,
        ),
        (
            SharedShape::new(Cylinder::new(0.1, 0.05)),
            iso(0.0, 0.0, 0.0),
            SharedShape::new(Cylinder::new(0.15, 0.04)),
            iso(0.08, 0.0, 0.0),
            0.08 - 0.09,
            1e-6,
        ),
        // cylinder (axis y) beside a box face, and a cylinder cap above a box
        (
            SharedShape::new(Cylinder::new(0.1, 0.05)),
            iso(0.0, 0.0, 0.0),
            cuboid(0.1, 0.1, 0.1),
            iso(0.25, 0.0, 0.0),
            0.25 - 0.1 - 0.05,
            1e-7,
        ),
        (
            SharedShape::new(Cylinder::new(0.1, 0.05)),
            iso(0.0, 0.215, 0.0),
            cuboid(0.1, 0.1, 0.1),
            iso(0.0, 0.0, 0.0),
            0.215 - 0.1 - 0.1,
            1e-7,
        ),
        // capsule tip sunk 0.01 into a box top
        (
            SharedShape::new(Capsule::new_y(0.1, 0.02)),
            iso(0.0, 0.21, 0.0),
            cuboid(0.2, 0.1, 0.2),
            iso(0.0, 0.0, 0.0),
            -0.01,
            1e-9,
        ),
    ];
    for (k, (a, pa, b, pb, want, tol)) in cases.into_iter().enumerate() {
        let d = sd(&a, pa, &b, pb);
        assert!(
            (d.distance - want).abs() < tol,
            "case {k}: {} vs closed form {want}",
            d.distance
        );
        check_witness(&d);
        // symmetric
        let r = sd(&b, pb, &a, pa);
        assert!(
            (r.distance - want).abs() < tol,
            "case {k} reversed: {}",
            r.distance
        );
    }
}

#[test]
fn shapes_against_the_support_plane_match_closed_forms() {
    let plane = HalfSpace {
        normal: Vector3::z_axis(),
        offset: 0.1,
    };
    let tilt = 0.3;
    let r = rot(Vector3::x(), tilt);
    // (shape, pose, lowest point height)
    let (he, h2, rc) = (Vector3::new(0.1, 0.2, 0.05), 0.15, 0.04);
    let box_pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.2), r);
    let box_low = 0.2
        - (0..3)
            .map(|i| (r.to_rotation_matrix()[(2, i)]).abs() * he[i])
            .sum::<f64>();
    let cases: Vec<(SharedShape, Isometry3<f64>, f64)> = vec![
        (ball(0.05), iso(1.0, 2.0, 0.12), 0.12 - 0.05),
        (ball(0.05), iso(1.0, 2.0, 0.08), 0.08 - 0.05),
        (SharedShape::new(Cuboid::new(he)), box_pose, box_low),
        // parry's axis y, turned by `tilt` about x, rises at sin(tilt): the lowest rim point of
        // the cylinder is h sin(tilt) + r cos(tilt) below the centre; the capsule's h sin + r
        (
            SharedShape::new(Cylinder::new(h2, rc)),
            Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.2), r),
            0.2 - h2 * tilt.sin() - rc * tilt.cos(),
        ),
        (
            SharedShape::new(Capsule::new_y(h2, rc)),
            Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.1), r),
            0.1 - h2 * tilt.sin() - rc,
        ),
    ];
    for (k, (s, pose, low)) in cases.into_iter().enumerate() {
        let d = half_space_distance(&Solid::new(s), &pose, &plane);
        assert!(
            (d.distance - (low - 0.1)).abs() < 1e-12,
            "case {k}: {} vs {}",
            d.distance,
            low - 0.1
        );
        check_witness(&d);
    }
}

const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
    f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

/// An L-shaped prism (non-convex): the unit square minus its upper-right quarter, extruded 1 in z.
fn l_prism() -> ShapeSpec {
    let outline = [
        [0.0, 0.0],
        [1.0, 0.0],
        [1.0, 0.5],
        [0.5, 0.5],
        [0.5, 1.0],
        [0.0, 1.0],
    ];
    let mut vertices = Vec::new();
    for z in [0.0, 1.0] {
        for p in outline {
            vertices.push([p[0], p[1], z]);
        }
    }
    let mut triangles = Vec::new();
    // bottom (seen from below: clockwise in xy) and top, fan-free triangulation of the L
    let tri_2d = [[0, 1, 2], [0, 2, 3], [0, 3, 5], [3, 4, 5]];
    for t in tri_2d {
        triangles.push([t[0], t[2], t[1]]);
        triangles.push([t[0] + 6, t[1] + 6, t[2] + 6]);
    }
    for i in 0..6u32 {
        let j = (i + 1) % 6;
        triangles.push([i, j, j + 6]);
        triangles.push([i, j + 6, i + 6]);
    }
    ShapeSpec::Mesh {
        vertices,
        triangles,
    }
}

#[test]
fn meshes_are_exact_in_sign_and_convex_ones_exact_in_depth() {
    // A convex mesh (unit cube, re-centred) becomes a polyhedron and matches the box.
    let mut cube = parse_obj(CUBE_OBJ).unwrap();
    let built = build_shape(&mut cube, "shape").unwrap();
    let solid = Solid::new(built.shape.clone());
    assert!(solid.is_exact());
    let b = cuboid(0.5, 0.5, 0.5);
    for p in [iso(0.9, 0.1, 0.0), iso(0.6, 0.0, 0.3), iso(0.3, 0.0, 0.0)] {
        let m = sd(&built.shape, Isometry3::identity(), &ball(0.2), p);
        let c = sd(&b, Isometry3::identity(), &ball(0.2), p);
        assert!((m.distance - c.distance).abs() < 1e-9, "{m:?} vs {c:?}");
    }
    // A non-convex L prism: a ball in the notch, beside it, and wholly inside.
    let mut l = l_prism();
    let built = build_shape(&mut l, "shape").unwrap();
    assert!(!Solid::new(built.shape.clone()).is_exact());
    // Re-centring moved the volume centroid to the origin: the L's centroid is (5/12, 5/12, 1/2).
    let c = 5.0 / 12.0;
    let at = |x: f64, y: f64, z: f64| iso(x - c, y - c, z - 0.5);
    // In the notch, 0.1 from both inner faces.
    let d = sd(
        &built.shape,
        Isometry3::identity(),
        &ball(0.05),
        at(0.6, 0.6, 0.5),
    );
    assert!((d.distance - 0.05).abs() < 1e-9, "{d:?}");
    // Beyond the convex corner edge at (1, 0.5): the edge is the closest feature.
    let d = sd(
        &built.shape,
        Isometry3::identity(),
        &ball(0.05),
        at(1.1, 0.6, 0.5),
    );
    assert!((d.distance - (0.02f64.sqrt() - 0.05)).abs() < 1e-9, "{d:?}");
    // Outside beyond x = 1, opposite the lower arm.
    let d = sd(
        &built.shape,
        Isometry3::identity(),
        &ball(0.05),
        at(1.2, 0.2, 0.5),
    );
    assert!((d.distance - 0.15).abs() < 1e-9, "{d:?}");
    // Wholly inside, centre 0.15 from the nearest face (y = 0): negative. The true depth is
    // 0.15 + r; a non-convex mesh reports the gap to its surface, 0.15 - r, a lower bound.
    let d = sd(
        &built.shape,
        Isometry3::identity(),
        &ball(0.05),
        at(0.25, 0.15, 0.5),
    );
    assert!(d.distance < 0.0, "{d:?}");
    assert!((d.distance + 0.10).abs() < 1e-9, "{d:?}");
}

/// A one-joint arm: a revolute joint about `axis` at `joint_at`, carrying a capsule of radius `r`
/// from the joint along local x for `len`.
fn one_link_arm(axis: Vector3<f64>, joint_at: [f64; 3], len: f64, r: f64) -> Arc<RobotGeometry> {
    let mut b = ModelBuilder::new("base");
    let link = b
        .add_joint(
            "j",
            b.root(),
            "link",
            JointKind::Revolute {
                axis: nalgebra::Unit::new_normalize(axis),
            },
            iso(joint_at[0], joint_at[1], joint_at[2]),
            JointLimits::new(-4.0, 4.0, 1.0, 1.0),
            None,
        )
        .unwrap();
    // parry capsules run along y: rotate y onto x and centre on the link's half length
    let placement = Isometry3::from_parts(
        Translation3::new(0.5 * len, 0.0, 0.0),
        rot(Vector3::z(), -FRAC_PI_2),
    );
    b.add_collision(
        link,
        placement,
        SharedShape::new(Capsule::new_y(0.5 * len, r)),
    )
    .unwrap();
    Arc::new(RobotGeometry::new(Arc::new(b.build().unwrap())))
}

#[test]
fn a_link_rotating_into_the_table_is_caught_at_the_closed_form_contact_angle() {
    // Joint about +y at height h: positive angles swing the link (along +x) down. The capsule's
    // lowest point is h - len sin θ - r, so it touches the plane at sin θ* = (h - r) / len.
    let (h, len, r) = (0.3, 0.5, 0.02);
    let robot = one_link_arm(Vector3::y(), [0.0, 0.0, h], len, r);
    let checker = CollisionChecker::new(
        robot.clone(),
        Scene::new().with_support(Plane::horizontal(0.0)),
    );
    let mut data = checker.data();
    let theta_star = ((h - r) / len).asin();
    let theta1 = 1.2; // beyond contact: ends 0.5 sin 1.2 + 0.02 - 0.3 = 0.186 deep
    let points = [0.0, theta1];
    let opts = PathOptions::default();
    let rep = checker.check_path(&mut data, &Polyline::new(&points, 1), &opts);
    assert!(rep.complete);
    let first = rep
        .first_collision
        .expect("the link goes through the table");
    let s_star = theta_star / theta1;
    // Before the first reported collision no pair is more than tol inside: the contact angle is
    // at most tol / (len + r) radians earlier; and the first collision lies past contact.
    let ds_tol = opts.tolerance / (len + r) / theta1;
    assert!(
        first.s >= s_star - 1e-9 && first.s <= s_star + ds_tol + 1e-9,
        "first collision at s = {} vs closed form {s_star}",
        first.s
    );
    let deepest = h - len * theta1.sin() - r;
    assert!((rep.distance() - deepest).abs() < 1e-12, "{rep:?}");
    // The path down and back up in one segment each: the same contact, min at the turn.
    let points = [0.0, theta1, 0.0];
    let rep = checker.check_path(&mut data, &Polyline::new(&points, 1), &opts);
    assert!((rep.distance() - deepest).abs() < 1e-12);
    assert!((rep.min.unwrap().s - 1.0).abs() < 1e-12);
}

#[test]
fn an_approach_that_ends_near_the_table_is_certified_in_few_steps() {
    // The link swings down towards the table and stops 5 mm above it: its distance falls all
    // the way. Held to the tolerance over the running minimum, every step would certify 0.5 mm
    // of the 275 mm it falls (at least 550 steps); with the end's exact minimum as the floor
    // the steps shrink only near it.
    let (h, len, r) = (0.3, 0.5, 0.02);
    let robot = one_link_arm(Vector3::y(), [0.0, 0.0, h], len, r);
    let checker = CollisionChecker::new(robot, Scene::new().with_support(Plane::horizontal(0.0)));
    let mut data = checker.data();
    let theta1 = ((h - r - 0.005) / len).asin();
    let points = [0.0, theta1];
    let opts = PathOptions::default();
    let rep = checker.check_path(&mut data, &Polyline::new(&points, 1), &opts);
    assert!(rep.complete && rep.first_collision.is_none());
    assert!((rep.distance() - 0.005).abs() < 1e-12, "{rep:?}");
    assert!(rep.steps < 60, "{} steps", rep.steps);
    // a second method: the closed form along a dense sweep never goes below the bound
    for k in 0..=1000 {
        let theta = theta1 * k as f64 / 1000.0;
        assert!(h - len * theta.sin() - r >= rep.lower_bound());
    }
}

#[test]
fn a_collision_between_two_clear_samples_is_found_and_agrees_with_dense_sampling() {
    // A horizontal link sweeping 90 degrees about z from +x to +y; a box sits at 45 degrees. Both
    // ends are clear, the middle is not.
    let (len, r) = (0.6, 0.03);
    let robot = one_link_arm(Vector3::z(), [0.0, 0.0, 0.5], len, r);
    let c45 = FRAC_PI_4.cos();
    let obstacle = SceneShape::from_spec(
        &ObstacleSpec {
            name: "box".into(),
            shape: ShapeSpec::Box {
                size: [0.1, 0.1, 0.1],
            },
            position: [0.4 * c45, 0.4 * c45, 0.5],
            orientation: [1.0, 0.0, 0.0, 0.0],
        },
        "",
    )
    .unwrap();
    let checker = CollisionChecker::new(robot, Scene::new().with_obstacle(obstacle));
    let mut data = checker.data();
    let points = [0.0, FRAC_PI_2];
    let path = Polyline::new(&points, 1);
    let opts = PathOptions::default();
    let rep = checker.check_path(&mut data, &path, &opts);
    assert!(rep.complete);
    let ends = [0.0, 1.0].map(|s| {
        let c = checker.clearance(&mut data, &[s * FRAC_PI_2]);
        c.distance()
    });
    assert!(ends.iter().all(|&d| d > 0.05), "ends are clear: {ends:?}");
    let first = rep.first_collision.expect("the sweep hits the box");
    // Closed-form contact: the box's nearest vertical edge is at angle 45° - atan(0.05 / 0.35)
    // seen from the axis, at 0.35 from... use the second method instead: dense sampling.
    let n = 20_000;
    let mut dense_min = f64::INFINITY;
    let mut dense_first = None;
    for k in 0..=n {
        let s = k as f64 / n as f64;
        let d = checker.clearance(&mut data, &[s * FRAC_PI_2]).distance();
        dense_min = dense_min.min(d);
        if d < 0.0 && dense_first.is_none() {
            dense_first = Some(s);
        }
    }
    // Dense sampling never sees less than the certified bound; the report is within the
    // tolerance of the dense minimum (sampling at 1/n misses at most (len + r) π/2 / n).
    let ds = (len + r) * FRAC_PI_2 / n as f64;
    assert!(
        dense_min >= rep.lower_bound() - 1e-12,
        "{dense_min} vs {rep:?}"
    );
    assert!(rep.distance() <= dense_min + ds, "{dense_min} vs {rep:?}");
    let dense_first = dense_first.unwrap();
    let s_tol = opts.tolerance / ((len + r) * FRAC_PI_2);
    assert!(
        (first.s - dense_first).abs() <= s_tol + 1.0 / n as f64,
        "first contact {} vs dense {dense_first}",
        first.s
    );
}

fn system(name: &str) -> System {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("robots/systems/{name}.toml"));
    System::from_file(&p).unwrap()
}

/// Distance from a point to the segment [a, b].
fn point_segment(p: Vector3<f64>, a: Vector3<f64>, b: Vector3<f64>) -> f64 {
    let t = ((p - a).dot(&(b - a)) / (b - a).norm_squared()).clamp(0.0, 1.0);
    (p - (a + (b - a) * t)).norm()
}

#[test]
fn wam_clearances_at_the_zero_posture_match_hand_computation() {
    // At q = 0 the WAM stands straight up and every link frame is world-aligned (the DH twists
    // of joints 2/3, 4/5 and 6/7 cancel pairwise). From the URDF: shoulder at z = 0.346 with
    // link1's 0.09 sphere; the upper-arm cylinder (r 0.045) runs up the shoulder axis from
    // 0.095 to 0.49 above the shoulder.
    let sys = system("wam_t42");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let ball_at = Vector3::new(0.25, 0.0, 0.62);
    let obstacle = SceneShape::new(
        "ball",
        ball(0.04),
        Isometry3::translation(ball_at.x, ball_at.y, ball_at.z),
    );
    let scene = Scene::new()
        .with_support(Plane::horizontal(0.0))
        .with_obstacle(obstacle);
    let checker = CollisionChecker::new(robot, scene);
    let mut data = checker.data();
    let q = vec![0.0; sys.model.nq()];
    let c = checker.clearance(&mut data, &q);
    let support = c.category(Category::Support).unwrap();
    assert!(
        (support.distance.distance - (0.346 - 0.09)).abs() < 1e-9,
        "{support:?}"
    );
    let (a, b) = (Vector3::new(0.0, 0.0, 0.441), Vector3::new(0.0, 0.0, 0.836));
    let want = point_segment(ball_at, a, b) - 0.045 - 0.04;
    let obs = c.category(Category::Obstacle).unwrap();
    assert!(
        (obs.distance.distance - want).abs() < 1e-7,
        "{} vs hand-computed {want}",
        obs.distance.distance
    );
    assert_eq!(checker.label(obs.pair).link, "wam_link3");
    assert_eq!(checker.label(obs.pair).other, "ball");
}

#[test]
fn adjacent_and_allowed_pairs_are_not_checked() {
    let sys = system("wam_t42");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let checker = CollisionChecker::new(robot.clone(), Scene::new());
    let m = robot.model();
    let frame = |n: &str| m.frame_id(n).unwrap();
    // link2-link3 and link1-link2 are joined by one joint; link7 and the hand base by a fixed mount.
    for (a, b) in [("wam_link1", "wam_link2"), ("wam_link2", "wam_link3")] {
        assert!(robot.adjacent(frame(a), frame(b)), "{a} {b}");
    }
    assert!(!robot.adjacent(frame("wam_link1"), frame("wam_link3")));
    for p in checker.pairs() {
        if let Target::Shape(j) = p.other {
            let (a, b) = (&robot.shapes()[p.shape], &robot.shapes()[j]);
            assert!(!robot.adjacent(a.frame, b.frame));
        }
    }
    // Fingers are tagged from the descriptor.
    let left = robot
        .finger_names()
        .iter()
        .position(|f| f == "left")
        .unwrap();
    let tip_link = m.frame_parent(sys.fingers[left].tip).unwrap();
    assert!(robot.shapes().iter().any(|s| s.finger == Some(left)));
    assert!(
        robot
            .shapes()
            .iter()
            .filter(|s| s.frame == tip_link || s.frame == sys.fingers[left].tip)
            .all(|s| s.finger == Some(left))
    );
    // Allowing the left tip link against the object removes exactly its object pairs.
    let obj = SceneShape::new("ball", ball(0.03), iso(0.5, 0.0, 0.1));
    let mut checker = CollisionChecker::new(robot.clone(), Scene::new().with_object(obj));
    let mut acm = AllowedContacts::none();
    let tip_shapes = robot.tip_shapes(&sys, left);
    assert!(!tip_shapes.is_empty());
    for &s in &tip_shapes {
        acm.allow(Member::Shape(s), Member::Object);
    }
    checker.set_allowed(&acm);
    for (i, p) in checker.pairs().iter().enumerate() {
        let want = p.other == Target::Object && tip_shapes.contains(&p.shape);
        assert_eq!(checker.is_allowed(i), want);
    }
}

#[test]
fn distance_gradient_matches_central_differences() {
    let sys = system("wam_t42");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let obstacle = SceneShape::new("ball", ball(0.05), iso(0.45, 0.1, 0.55));
    let checker = CollisionChecker::new(
        robot,
        Scene::new()
            .with_support(Plane::horizontal(0.0))
            .with_obstacle(obstacle),
    );
    let mut data = checker.data();
    let nq = sys.model.nq();
    let mut q = sys.model.neutral();
    for (k, v) in q.iter_mut().enumerate().take(7) {
        *v = [0.3, 0.6, -0.2, 1.4, 0.3, 0.5, 0.2][k];
    }
    checker.update(&mut data, &q);
    for pair in 0..checker.pairs().len() {
        if checker.pairs()[pair].category == Category::SelfCollision && pair % 3 != 0 {
            continue; // a sample of self pairs keeps the test short
        }
        let d = checker.pair_distance(&mut data, pair);
        // GJK (two polyhedral or cylindrical shapes) stops at 1.5e-7 relative accuracy in the
        // distance, which leaves the witness normal good to ~1e-3 rad; the other kernels
        // (projections, closed forms, the plane's support point) are exact.
        let gjk = {
            let p = &checker.pairs()[pair];
            let sa = checker.robot().shapes()[p.shape].solid();
            match p.other {
                Target::Shape(j) => sa.is_gjk() && checker.robot().shapes()[j].solid().is_gjk(),
                Target::Obstacle(_) | Target::Object | Target::Support => false,
            }
        };
        let tol = if gjk { 5e-3 } else { 1e-6 };
        let mut g = vec![0.0; nq];
        checker.add_distance_gradient(&data, pair, &d, &mut g);
        let h = 1e-6;
        for k in 0..nq {
            let mut qp = q.clone();
            let mut qm = q.clone();
            qp[k] += h;
            qm[k] -= h;
            checker.update(&mut data, &qp);
            let dp = checker.pair_distance(&mut data, pair).distance;
            checker.update(&mut data, &qm);
            let dm = checker.pair_distance(&mut data, pair).distance;
            let fd = (dp - dm) / (2.0 * h);
            assert!(
                (fd - g[k]).abs() < tol * (1.0 + fd.abs()),
                "pair {pair} ({:?}) joint {k}: fd {fd} vs analytic {}",
                checker.label(pair),
                g[k]
            );
        }
        checker.update(&mut data, &q);
    }
}

#[test]
fn bundled_trajectory_check_agrees_with_dense_sampling() {
    // A WAM + T42 reach from the zero posture down to a table-top pose, past a box obstacle.
    let sys = system("wam_t42");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let obstacle = SceneShape::from_spec(
        &ObstacleSpec {
            name: "box".into(),
            shape: ShapeSpec::Box {
                size: [0.1, 0.3, 0.2],
            },
            position: [0.55, 0.0, 0.35],
            orientation: [1.0, 0.0, 0.0, 0.0],
        },
        "",
    )
    .unwrap();
    let checker = CollisionChecker::new(
        robot,
        Scene::new()
            .with_support(Plane::horizontal(0.0))
            .with_obstacle(obstacle),
    );
    let mut data = checker.data();
    let nq = sys.model.nq();
    let mut start = sys.model.neutral();
    start[..7].copy_from_slice(&[0.0; 7]);
    let mut goal = start.clone();
    goal[..7].copy_from_slice(&[0.1, 1.3, 0.0, 1.6, 0.0, 0.4, 0.0]);
    let points: Vec<f64> = start.iter().chain(&goal).copied().collect();
    let path = Polyline::new(&points, nq);
    let opts = PathOptions::default();
    let rep = checker.check_path(&mut data, &path, &opts);
    assert!(rep.complete, "{rep:?}");
    let n = 4000;
    let mut q = vec![0.0; nq];
    let mut dense = [f64::INFINITY; 4];
    for k in 0..=n {
        path.eval(k as f64 / n as f64, &mut q);
        let c = checker.clearance(&mut data, &q);
        for cat in Category::ALL {
            dense[cat as usize] = dense[cat as usize].min(c.category_distance(cat));
        }
    }
    // Sampling at 1/n misses at most L/n with L the whole-path motion bound of the arm (< 4 m).
    let miss = 4.0 / n as f64;
    for cat in Category::ALL {
        let r = rep.category_distance(cat);
        let dn = dense[cat as usize];
        assert!(
            dn >= r - opts.tolerance - 1e-12,
            "{cat:?}: dense {dn} below bound of {r}"
        );
        assert!(r <= dn + miss, "{cat:?}: report {r} vs dense {dn}");
    }
}

#[test]
fn a_path_through_a_box_is_moved_around_it_as_the_continuous_check_confirms() {
    // The reach of `bundled_trajectory_check_agrees_with_dense_sampling`, as 41 configurations
    // on the joint line, past a box it passes through. The refinement holds the configurations
    // to the margin with first-order steps; the continuous check of the polyline through them
    // (conservative advancement, another method) must find the box clear, the ends unmoved. A
    // clear path must come back unchanged.
    let sys = system("wam_t42");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let boxed = |x: f64| {
        let obstacle = SceneShape::from_spec(
            &ObstacleSpec {
                name: "box".into(),
                shape: ShapeSpec::Box {
                    size: [0.1, 0.1, 0.1],
                },
                position: [x, 0.0, 0.75],
                orientation: [1.0, 0.0, 0.0, 0.0],
            },
            "",
        )
        .unwrap();
        CollisionChecker::new(
            robot.clone(),
            Scene::new()
                .with_support(Plane::horizontal(0.0))
                .with_obstacle(obstacle),
        )
    };
    let nq = sys.model.nq();
    let start = sys.model.neutral();
    let mut goal = start.clone();
    goal[..7].copy_from_slice(&[0.1, 1.3, 0.0, 1.6, 0.0, 0.4, 0.0]);
    let count = 41;
    let line = |ctrl: &mut Vec<f64>| {
        ctrl.clear();
        for k in 0..count {
            let u = k as f64 / (count - 1) as f64;
            ctrl.extend(start.iter().zip(&goal).map(|(a, b)| a + u * (b - a)));
        }
    };
    let curve: Vec<avoid::CurveSample> = (0..count)
        .map(|k| avoid::CurveSample {
            x: k as f64 / (count - 1) as f64,
            first: k,
            w: [1.0, 0.0, 0.0, 0.0],
        })
        .collect();
    let opts = avoid::AvoidOptions::default();
    let (lower, upper) = (sys.model.lower_limits(), sys.model.upper_limits());
    let mut scratch = avoid::AvoidScratch::new(nq, count);
    let mut refine = |checker: &CollisionChecker, ctrl: &mut [f64]| {
        let mut data = checker.data();
        avoid::refine(
            checker,
            &mut data,
            ctrl,
            &curve,
            lower,
            upper,
            &opts,
            &mut scratch,
        )
    };
    let obstacle_clearance = |checker: &CollisionChecker, ctrl: &[f64]| {
        let mut data = checker.data();
        let rep = checker.check_path(&mut data, &Polyline::new(ctrl, nq), &PathOptions::default());
        assert!(rep.complete);
        rep.category_distance(Category::Obstacle)
    };

    let checker = boxed(0.45);
    let mut ctrl = Vec::new();
    line(&mut ctrl);
    let before = obstacle_clearance(&checker, &ctrl);
    assert!(
        before < -0.02,
        "the joint line passes through the box: {before}"
    );
    let rep = refine(&checker, &mut ctrl);
    assert!(rep.below_target > 0 && rep.still_below == 0, "{rep:?}");
    let after = obstacle_clearance(&checker, &ctrl);
    assert!(
        after > 0.005,
        "clear of the box after the refinement: {after} ({rep:?})"
    );
    assert_eq!(&ctrl[..nq], &start[..]);
    assert_eq!(&ctrl[(count - 1) * nq..], &goal[..]);
    for (k, row) in ctrl.chunks_exact(nq).enumerate() {
        for j in 0..nq {
            assert!(row[j] >= lower[j] && row[j] <= upper[j], "{k}: joint {j}");
        }
    }

    // Far from the box, nothing to move.
    let checker = boxed(-0.8);
    line(&mut ctrl);
    let given = ctrl.clone();
    let rep = refine(&checker, &mut ctrl);
    assert_eq!((rep.rounds, rep.below_target), (0, 0), "{rep:?}");
    assert_eq!(ctrl, given);
}

/// The broad phase's bounding capsules: every support point of the shape lies inside its
/// capsule, and their gap never exceeds the signed distance parry computes (its own distance
/// and contact queries, not ours) over random poses, separated and interpenetrating; beside
/// the middle of a long link the capsules see the gap the spheres cannot.
#[test]
fn bounding_capsules_contain_their_shapes_and_bound_parry_distances() {
    use parry3d_f64::shape::{Cone, ConvexPolyhedron};
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
    let mut cloud: Vec<nalgebra::Point3<f64>> = Vec::new();
    for _ in 0..40 {
        cloud.push(nalgebra::Point3::new(
            rng.random_range(-0.02..0.03),
            rng.random_range(-0.01..0.012),
            rng.random_range(-0.09..0.07),
        ));
    }
    let shapes = [
        SharedShape::new(Cylinder::new(0.15, 0.02)),
        cuboid(0.01, 0.08, 0.02),
        SharedShape::new(ConvexPolyhedron::from_convex_hull(&cloud).expect("a hull")),
        SharedShape::new(Cone::new(0.05, 0.03)),
        ball(0.04),
        SharedShape::new(Capsule::new_z(0.06, 0.015)),
    ];
    let solids: Vec<Solid> = shapes.iter().map(|s| Solid::new(s.clone())).collect();
    for (shape, solid) in shapes.iter().zip(&solids) {
        let c = solid.capsule;
        let sm = shape.as_support_map().expect("support-mapped");
        for _ in 0..500 {
            let d = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let p = sm.local_support_point(&d);
            let (a, b) = (c.a.coords, c.b.coords);
            let far = if (b - a).norm() > 0.0 {
                point_segment(p.coords, a, b)
            } else {
                (p.coords - a).norm()
            };
            assert!(
                far <= c.radius,
                "{:?}: support point {far} from the axis",
                shape.shape_type()
            );
        }
    }
    let pose = |rng: &mut rand_chacha::ChaCha8Rng| {
        let t = Translation3::new(
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
        );
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(0.1..1.0),
        );
        Isometry3::from_parts(t, rot(axis, rng.random_range(-3.0..3.0)))
    };
    let (mut separated, mut touching) = (0, 0);
    for _ in 0..3000 {
        let (i, j) = (rng.random_range(0..6), rng.random_range(0..6));
        let (pa, pb) = (pose(&mut rng), pose(&mut rng));
        let (a, b) = (&shapes[i], &shapes[j]);
        let dist = parry3d_f64::query::distance(&pa, a.as_ref(), &pb, b.as_ref()).unwrap();
        let signed = if dist > 0.0 {
            separated += 1;
            dist
        } else {
            touching += 1;
            parry3d_f64::query::contact(&pa, a.as_ref(), &pb, b.as_ref(), 0.0)
                .unwrap()
                .map_or(0.0, |c| c.dist)
        };
        let bound = solids[i].capsule.gap(&pa, &solids[j].capsule, &pb);
        assert!(
            bound <= signed + 1e-9,
            "{i} vs {j}: bound {bound} above {signed}"
        );
    }
    assert!(
        separated > 500 && touching > 200,
        "{separated} / {touching}"
    );
    // beside the middle of the long cylinder, 5 cm off its side: the spheres overlap
    let (long, cube) = (&solids[0], Solid::new(cuboid(0.01, 0.01, 0.01)));
    let (pa, pb) = (Isometry3::identity(), iso(0.02 + 0.05 + 0.01, 0.0, 0.0));
    let spheres = (pb.translation.vector - pa.translation.vector).norm() - long.bound - cube.bound;
    let capsules = long.capsule.gap(&pa, &cube.capsule, &pb);
    assert!(spheres < 0.0, "{spheres}");
    assert!(capsules > 0.03 && capsules <= 0.05, "{capsules}");
}

#[test]
fn carried_pair_bounds_find_the_pairs_an_uncached_scan_finds() {
    // The avoidance carries each pair's distance from one check of a path point to the next,
    // less the gain-weighted joint motion since, and skips the pairs that bound keeps at their
    // cutoff. A gain too small or a joint missing from a chain would skip a pair the uncached
    // scan reports: compare both along a random walk of a wam_ihy hand around a bottle.
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    let sys = system("wam_ihy");
    let robot = Arc::new(RobotGeometry::from_system(&sys));
    let nq = sys.model.nq();
    let (lo, hi) = (sys.model.lower_limits(), sys.model.upper_limits());
    let mut q: Vec<f64> = lo.iter().zip(hi).map(|(l, h)| 0.5 * (l + h)).collect();
    q[1] = 0.8;
    q[3] = 1.6;
    // the bottle beside the hand, on a table under it
    let probe = CollisionChecker::new(robot.clone(), Scene::new());
    let mut data = probe.data();
    probe.update(&mut data, &q);
    let hand = data.shape_poses().last().unwrap().translation.vector;
    let at = hand + Vector3::new(0.05, 0.0, 0.0);
    let bottle = SceneShape::new(
        "bottle",
        SharedShape::new(Cylinder::new(0.1, 0.03)),
        Isometry3::new(at, Vector3::x() * FRAC_PI_2),
    );
    let scene = Scene::new()
        .with_object(bottle)
        .with_support(Plane::horizontal(hand.z - 0.12));
    let checker = CollisionChecker::new(robot, scene);
    let mut data = checker.data();
    let np = checker.pairs().len();
    let cutoff = [0.03, 0.03, 0.03, 0.004];
    let mut lower = vec![f64::NEG_INFINITY; np];
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut found, mut bounded_queries, mut plain_queries) = (0, 0, 0);
    let mut prev = q.clone();
    for step in 0..600 {
        // small steps as between avoidance rounds, and now and then a jump
        let size = if step % 100 == 99 { 0.4 } else { 0.005 };
        for j in 0..nq {
            q[j] = (q[j] + rng.random_range(-size..size)).clamp(lo[j], hi[j]);
        }
        checker.carry_bounds(&mut data, &prev, &q, &mut lower);
        prev.copy_from_slice(&q);
        checker.update(&mut data, &q);
        let before = data.exact_queries();
        let mut bounded = Vec::new();
        checker.for_each_within_bounded(&mut data, &cutoff, &mut lower, |p, d| {
            bounded.push((p, d.distance))
        });
        bounded_queries += data.exact_queries() - before;
        let before = data.exact_queries();
        let mut plain = Vec::new();
        for cat in Category::ALL {
            checker.for_each_within_current(&mut data, cutoff[cat as usize], &[cat], |p, d| {
                plain.push((p, d.distance))
            });
        }
        plain_queries += data.exact_queries() - before;
        plain.sort_by_key(|&(p, _)| p);
        assert_eq!(bounded, plain, "step {step}");
        found += plain.len();
    }
    // the walk meets the cutoffs, and the bounds spare a quarter of the queries or more
    assert!(found > 1000, "{found} pairs within the cutoffs");
    assert!(
        bounded_queries * 4 < plain_queries * 3,
        "{bounded_queries} exact queries with carried bounds, {plain_queries} without"
    );
}
