//! The 3-D viewer's scene (issue 21 target: "viewer scene ready ≤ 1 s for a 20-second
//! trajectory"): the server's part, building the scene of a 20 s wam_ihy trajectory at 100 Hz
//! (every joint moving) with the seeded bottle on its table and two obstacles, FK at 30 frames/s,
//! and serialising it to the JSON the page fetches. The browser's part (fetch, build the
//! three.js scene, first frame) is measured and printed by `tests/viewer.rs`.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use reachgrasp::figures::viewer::{Track, ViewInput, view_scene};
use reachgrasp::geometry::ShapeSpec;
use reachgrasp::grasp::objects::seeded_object;
use reachgrasp::kinematics::System;

fn bench(c: &mut Criterion) {
    let sys = System::from_file(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml"),
    )
    .expect("bundled system");
    let m = &sys.model;
    let names = m.joint_names().to_vec();
    let times: Vec<f64> = (0..=2000).map(|k| k as f64 / 100.0).collect();
    let mut positions = Vec::with_capacity(times.len() * names.len());
    for &t in &times {
        for j in 0..names.len() {
            let (lo, hi) = (m.lower_limits()[j], m.upper_limits()[j]);
            let mid = 0.5 * (lo + hi);
            positions.push(mid + 0.4 * (hi - lo).min(2.0) * (0.3 * t + j as f64).sin());
        }
    }
    let object = seeded_object("bottle", 0.55, 0.1, -0.1).expect("seeded bottle");
    let object_pose = Isometry3::from_parts(
        Translation3::from(nalgebra::Vector3::from(object.position)),
        UnitQuaternion::identity(),
    );
    let obstacles = vec![
        (
            "box".to_owned(),
            ShapeSpec::Box {
                size: [0.1, 0.2, 0.3],
            },
            Isometry3::translation(0.4, -0.3, 0.05),
        ),
        (
            "post".to_owned(),
            ShapeSpec::Cylinder {
                radius: 0.03,
                height: 0.5,
            },
            Isometry3::translation(0.3, 0.4, 0.15),
        ),
    ];
    let input = ViewInput {
        title: "bench",
        robot: "wam_ihy",
        system: &sys,
        track: Some(Track {
            joint_names: &names,
            times: &times,
            positions: &positions,
        }),
        object: Some((&object.shape, &object_pose)),
        support: object.support,
        obstacles: &obstacles,
        grasp: None,
        human: None,
        fps: None,
    };
    let json = serde_json::to_string(&view_scene(&input).unwrap()).unwrap();
    println!(
        "viewer scene of a 20 s trajectory: {} frames, {} bytes of JSON",
        view_scene(&input).unwrap().frames.times.len(),
        json.len()
    );
    c.bench_function("viewer scene ready (20 s trajectory, build + JSON)", |b| {
        b.iter(|| serde_json::to_string(&view_scene(&input).unwrap()).unwrap())
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
