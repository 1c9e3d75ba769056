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
