//! Survey of the bundled systems' self-intersections (an ignored test: it prints a table).
//!
//! `cargo test --release --lib geometry::survey -- --ignored --nocapture`
//!
//! For each `robots/systems/*.toml`: postures sampled within the joint limits (seeded; each
//! coordinate uniform, or at one of its limits one time in five),
//! and for every non-adjacent pair of collision shapes the share of postures in which the pair
//! intersects (exact signed distance < 0) and the deepest overlap. Pairs are grouped into arm-arm,
//! arm-hand and hand-hand (hand = the wrist frame and everything below it).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{CollisionChecker, RobotGeometry, Scene, Target};
use crate::kinematics::{FrameId, Model, System};

/// Samples per system.
const SAMPLES: usize = 4000;

fn in_hand(model: &Model, wrist: FrameId, frame: FrameId) -> bool {
    let mut f = Some(frame);
    while let Some(fr) = f {
        if fr == wrist {
            return true;
        }
        f = model.frame_parent(fr);
    }
    false
}

/// One system's intersecting pairs: `(group, link a, link b) -> (postures hit, deepest)`.
pub(crate) fn survey_system(
    sys: &System,
    samples: usize,
    seed: u64,
) -> BTreeMap<(&'static str, String, String), (usize, f64)> {
    let robot = Arc::new(RobotGeometry::from_system(sys));
    let checker = CollisionChecker::new(robot.clone(), Scene::new());
    let mut data = checker.data();
    let model = &sys.model;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut q = model.neutral();
    let mut out: BTreeMap<(&'static str, String, String), (usize, f64)> = BTreeMap::new();
    for _ in 0..samples {
        for (k, v) in q.iter_mut().enumerate() {
            let (lo, hi) = (model.lower_limits()[k], model.upper_limits()[k]);
            let (lo, hi) = if lo.is_finite() && hi.is_finite() {
                (lo, hi)
            } else {
                (-std::f64::consts::PI, std::f64::consts::PI)
            };
            // A fifth of the coordinates at a limit: folded extremes are where links meet.
            let u: f64 = rng.random_range(0.0..1.0);
            *v = if u < 0.1 {
                lo
            } else if u < 0.2 {
                hi
            } else {
                rng.random_range(lo..=hi)
            };
        }
        checker.for_each_within(&mut data, &q, 0.0, |pair, d| {
            let p = &checker.pairs()[pair];
            let Target::Shape(j) = p.other else { return };
            let (a, b) = (&robot.shapes()[p.shape], &robot.shapes()[j]);
            let (ha, hb) = (
                in_hand(model, sys.wrist_frame, a.frame),
                in_hand(model, sys.wrist_frame, b.frame),
            );
            let group = match (ha, hb) {
                (false, false) => "arm-arm",
                (true, true) => "hand-hand",
                _ => "arm-hand",
            };
            let (la, lb) = if a.link <= b.link {
                (a.link.clone(), b.link.clone())
            } else {
                (b.link.clone(), a.link.clone())
            };
            let e = out.entry((group, la, lb)).or_insert((0, 0.0));
            e.0 += 1;
            e.1 = f64::max(e.1, -d.distance);
        });
    }
    out
}

#[test]
#[ignore = "survey: prints a table, run with --ignored --nocapture"]
fn survey_self_intersections_of_the_bundled_systems() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    names.sort();
    println!(
        "| system | group | link pair | postures intersecting (of {SAMPLES}) | deepest (mm) |"
    );
    println!("|---|---|---|---|---|");
    for path in names {
        let sys = System::from_file(&path).unwrap();
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let hits = survey_system(&sys, SAMPLES, 7);
        if hits.is_empty() {
            println!("| {name} | - | none | 0 | - |");
        }
        for ((group, a, b), (n, deepest)) in hits {
            println!(
                "| {name} | {group} | {a} - {b} | {n} ({:.1} %) | {:.1} |",
                100.0 * n as f64 / SAMPLES as f64,
                1e3 * deepest
            );
        }
    }
}

/// Every non-adjacent pair of arm links whose relative pose depends on at most three joints
/// (link i against link i+2 or i+3: the pairs that meet at a folded joint) is clear over the
/// whole joint box, not just at samples: branch and bound over the box of those joints, a box
/// being clear when the pair's exact distance at its centre exceeds the half-widths times the
/// pair's speed gains (the most any point can move within the box).
#[test]
fn arm_links_two_or_three_joints_apart_never_intersect_within_the_limits() {
    for name in ["wam_t42", "pa10_t42"] {
        let sys = System::from_file(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("robots/systems/{name}.toml")),
        )
        .unwrap();
        let model = &sys.model;
        let robot = Arc::new(RobotGeometry::from_system(&sys));
        let checker = CollisionChecker::new(robot.clone(), Scene::new());
        let mut data = checker.data();
        let shapes = robot.shapes();
        let (lo, hi) = (model.lower_limits(), model.upper_limits());
        let mut checked = 0;
        for (pi, p) in checker.pairs().iter().enumerate() {
            let Target::Shape(j) = p.other else { continue };
            let (a, b) = (&shapes[p.shape], &shapes[j]);
            if in_hand(model, sys.wrist_frame, a.frame) || in_hand(model, sys.wrist_frame, b.frame)
            {
                continue;
            }
            let mut joints: Vec<usize> = a.chain[p.a_from..]
                .iter()
                .chain(&b.chain[p.b_from..])
                .map(|c| c.q)
                .collect();
            // A fixed base cylinder on the axis of the first joint is unchanged by that joint's
            // rotation: the pair's distance does not depend on it (checked, then left out).
            if a.is_static() && a.solid().shape().as_cylinder().is_some() {
                checker.update(&mut data, &model.neutral());
                let pose = data.shape_poses()[p.shape];
                let axis = pose * nalgebra::Vector3::y();
                let j1 = &b.chain[0];
                let jf = FrameId(j1.frame);
                let joint = model.joint_of_frame(jf).unwrap();
                let world = data.kinematics().frame(jf);
                let j_axis = world * joint.kind.axis().unwrap().into_inner();
                let off = pose.translation.vector - world.translation.vector;
                if axis.cross(&j_axis).norm() < 1e-12 && off.cross(&j_axis).norm() < 1e-12 {
                    joints.retain(|&k| k != j1.q);
                }
            }
            if joints.len() > 3 {
                continue;
            }
            checked += 1;
            let gains: Vec<f64> = joints
                .iter()
                .map(|&k| {
                    let mut rates = vec![0.0; model.nq()];
                    rates[k] = 1.0;
                    robot.speed_bound(p.shape, &rates) + robot.speed_bound(j, &rates)
                })
                .collect();
            let mut boxes = vec![joints.iter().map(|&k| (lo[k], hi[k])).collect::<Vec<_>>()];
            let (mut evaluations, mut margin) = (0usize, f64::INFINITY);
            let mut q = model.neutral();
            while let Some(bx) = boxes.pop() {
                evaluations += 1;
                assert!(
                    evaluations < 400_000,
                    "{name}: {} - {} not certified",
                    a.link,
                    b.link
                );
                for (&k, &(l, h)) in joints.iter().zip(&bx) {
                    q[k] = 0.5 * (l + h);
                }
                checker.update(&mut data, &q);
                let d = checker.pair_distance(&mut data, pi).distance;
                assert!(
                    d > 0.0,
                    "{name}: {} - {} intersect ({:.1} mm) at {q:?}",
                    a.link,
                    b.link,
                    -1e3 * d
                );
                let slack: f64 = gains
                    .iter()
                    .zip(&bx)
                    .map(|(g, (l, h))| g * 0.5 * (h - l))
                    .sum();
                if d > slack {
                    margin = margin.min(d - slack);
                    continue;
                }
                let widest = (0..bx.len())
                    .max_by(|&x, &y| {
                        (gains[x] * (bx[x].1 - bx[x].0))
                            .total_cmp(&(gains[y] * (bx[y].1 - bx[y].0)))
                    })
                    .unwrap();
                let (l, h) = bx[widest];
                let mut left = bx.clone();
                left[widest].1 = 0.5 * (l + h);
                let mut right = bx;
                right[widest].0 = 0.5 * (l + h);
                boxes.push(left);
                boxes.push(right);
            }
            println!(
                "{name}: {} - {} clear over the joint box ({} joints, {evaluations} boxes, margin >= {:.2} mm)",
                a.link,
                b.link,
                joints.len(),
                1e3 * margin
            );
        }
        assert!(checked >= 4, "{name}: only {checked} pairs checked");
    }
}
