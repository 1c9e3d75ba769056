//! Exact-geometry benchmarks (`cargo bench --bench geometry`): on every bundled system with a
//! ball on the table and two obstacle boxes,
//! - a posture check (FK, every shape posed, broad phase, exact minimum overall and per category;
//!   target: microseconds to tens of microseconds);
//! - a continuous check of a 1.5 s reach sampled at 100 Hz (151 configurations) by conservative
//!   advancement at the default 0.5 mm tolerance.
//!
//! Before criterion runs, a report prints per system the shape and pair counts, the median
//! posture-check time over 2,000 random postures and the exact queries per check, and for the
//! path check its steps, exact queries and time. A second report times the closed-loop safety
//! filter (`geometry::barrier`) per control period along that reach driven by a proportional
//! law, at the default influence and at the former 0.3 m.

use std::hint::black_box;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use criterion::{Criterion, criterion_group};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use reachgrasp::geometry::barrier::{BarrierOptions, SafetyFilter};
use reachgrasp::geometry::{
    CollisionChecker, ObstacleSpec, PathOptions, Plane, Polyline, RobotGeometry, Scene, SceneShape,
    ShapeSpec,
};
use reachgrasp::kinematics::System;

const SYSTEMS: [&str; 6] = [
    "wam_t42",
    "wam_ihy",
    "wam_ob4f",
    "pa10_t42",
    "pa10_ihy",
    "pa10_ob4f",
];

fn system(name: &str) -> System {
    System::from_file(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("robots/systems/{name}.toml")),
    )
    .unwrap()
}

fn scene() -> Scene {
    let obstacle = |name: &str, position: [f64; 3], size: [f64; 3]| {
        SceneShape::from_spec(
            &ObstacleSpec {
                name: name.into(),
                shape: ShapeSpec::Box { size },
                position,
                orientation: [1.0, 0.0, 0.0, 0.0],
            },
            "",
        )
        .unwrap()
    };
    Scene::new()
        .with_object(
            SceneShape::from_spec(
                &ObstacleSpec {
                    name: "ball".into(),
                    shape: ShapeSpec::Sphere { radius: 0.033 },
                    position: [0.5, 0.0, 0.033],
                    orientation: [1.0, 0.0, 0.0, 0.0],
                },
                "",
            )
            .unwrap(),
        )
        .with_support(Plane::horizontal(0.0))
        .with_obstacle(obstacle("box", [0.35, 0.25, 0.15], [0.1, 0.1, 0.3]))
        .with_obstacle(obstacle("shelf", [0.0, -0.6, 0.5], [0.8, 0.3, 0.02]))
}

fn random_q(sys: &System, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let m = &sys.model;
    (0..m.nq())
        .map(|k| rng.random_range(m.lower_limits()[k]..=m.upper_limits()[k]))
        .collect()
}

/// A reach from a bent-elbow ready pose towards the ball, 151 configurations (min-jerk timing).
fn reach(sys: &System) -> Vec<f64> {
    let m = &sys.model;
    let n = m.nq();
    let mut start = m.neutral();
    let mut goal = m.neutral();
    let ready = [0.0, -0.3, 0.0, 1.8, 0.0, 0.3, 0.0];
    let near = [0.0, 0.9, 0.0, 1.2, 0.0, 0.9, 0.0];
    for (i, &k) in sys.arm_joints.iter().enumerate().take(7) {
        let clamp = |v: f64| v.clamp(m.lower_limits()[k], m.upper_limits()[k]);
        start[k] = clamp(ready[i]);
        goal[k] = clamp(near[i]);
    }
    let mut points = Vec::with_capacity(151 * n);
    for i in 0..=150 {
        let t = i as f64 / 150.0;
        let s = t * t * t * (10.0 - 15.0 * t + 6.0 * t * t);
        points.extend(start.iter().zip(&goal).map(|(a, b)| a + s * (b - a)));
    }
    points
}

fn report() {
    println!(
        "| system | shapes | pairs | posture check median (µs) | exact queries / check | path: steps | exact queries | time (ms) | min clearance (mm) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for name in SYSTEMS {
        let sys = system(name);
        let robot = Arc::new(RobotGeometry::from_system(&sys));
        let checker = CollisionChecker::new(robot.clone(), scene());
        let mut data = checker.data();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let qs: Vec<Vec<f64>> = (0..2000).map(|_| random_q(&sys, &mut rng)).collect();
        let mut times = Vec::with_capacity(qs.len());
        let q0 = data.exact_queries();
        for q in &qs {
            let t = Instant::now();
            black_box(checker.clearance(&mut data, black_box(q)));
            times.push(t.elapsed().as_secs_f64());
        }
        let per_check = (data.exact_queries() - q0) as f64 / qs.len() as f64;
        times.sort_by(f64::total_cmp);
        let points = reach(&sys);
        let t = Instant::now();
        let rep = checker.check_path(
            &mut data,
            &Polyline::new(&points, sys.model.nq()),
            &PathOptions::default(),
        );
        let path_ms = 1e3 * t.elapsed().as_secs_f64();
        println!(
            "| {name} | {} | {} | {:.1} | {per_check:.1} | {} | {} | {path_ms:.2} | {:.1} |",
            robot.shapes().len(),
            checker.pairs().len(),
            1e6 * times[times.len() / 2],
            rep.steps,
            rep.exact_queries,
            1e3 * rep.distance()
        );
    }
}

/// The safety filter's cost per control period (100 Hz) on the reach of [`reach`] run by the
/// law `u = 1.5 (q_d − q)` for 3 s: median, p99 and largest time of one `filter` call, and the
/// constraints it set up per period.
fn filter_report() {
    println!();
    println!(
        "| system | influence (m) | filter median (µs) | p99 (µs) | max (µs) | constraints / period | periods filtered |"
    );
    println!("|---|---|---|---|---|---|---|");
    for name in SYSTEMS {
        let sys = system(name);
        let m = &sys.model;
        let n = m.nq();
        let points = reach(&sys);
        let (start, goal) = (&points[..n], &points[points.len() - n..]);
        for influence in [BarrierOptions::default().influence, 0.3] {
            let checker =
                CollisionChecker::new(Arc::new(RobotGeometry::from_system(&sys)), scene());
            let opts = BarrierOptions {
                influence,
                ..BarrierOptions::default()
            };
            let mut f = SafetyFilter::new(checker, goal, m.velocity_limits(), opts);
            let mut q = start.to_vec();
            let mut u = vec![0.0; n];
            let (mut times, mut constraints, mut filtered) = (Vec::with_capacity(300), 0, 0);
            for _ in 0..300 {
                for j in 0..n {
                    u[j] = 1.5 * (goal[j] - q[j]);
                }
                let t = Instant::now();
                let step = black_box(f.filter(&q, &mut u));
                times.push(t.elapsed().as_secs_f64());
                constraints += step.constraints;
                filtered += usize::from(step.active > 0);
                for j in 0..n {
                    q[j] = (q[j] + 0.01 * u[j]).clamp(m.lower_limits()[j], m.upper_limits()[j]);
                }
            }
            times.sort_by(f64::total_cmp);
            println!(
                "| {name} | {influence} | {:.0} | {:.0} | {:.0} | {:.1} | {filtered} / 300 |",
                1e6 * times[times.len() / 2],
                1e6 * times[times.len() * 99 / 100],
                1e6 * times[times.len() - 1],
                constraints as f64 / 300.0,
            );
        }
    }
}

fn posture(c: &mut Criterion) {
    let mut g = c.benchmark_group("geometry posture check");
    for name in ["wam_t42", "pa10_ob4f"] {
        let sys = system(name);
        let checker = CollisionChecker::new(Arc::new(RobotGeometry::from_system(&sys)), scene());
        let mut data = checker.data();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let qs: Vec<Vec<f64>> = (0..64).map(|_| random_q(&sys, &mut rng)).collect();
        let mut i = 0;
        g.bench_function(name, |b| {
            b.iter(|| {
                i = (i + 1) & 63;
                black_box(checker.clearance(&mut data, black_box(&qs[i])))
            })
        });
    }
    g.finish();
}

fn path(c: &mut Criterion) {
    let mut g = c.benchmark_group("geometry path check (151 configurations)");
    g.sample_size(20);
    for name in ["wam_t42", "pa10_ob4f"] {
        let sys = system(name);
        let checker = CollisionChecker::new(Arc::new(RobotGeometry::from_system(&sys)), scene());
        let mut data = checker.data();
        let points = reach(&sys);
        let nq = sys.model.nq();
        g.bench_function(name, |b| {
            b.iter(|| {
                black_box(checker.check_path(
                    &mut data,
                    &Polyline::new(black_box(&points), nq),
                    &PathOptions::default(),
                ))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, posture, path);

fn main() {
    report();
    filter_report();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
