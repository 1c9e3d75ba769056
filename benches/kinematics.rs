//! Kinematics benchmarks: FK of every frame plus one 6×7 Jacobian of the WAM (target ≤ 0.3 µs),
//! and pose IK on random reachable poses with random seeds and a 5 ms budget (targets: success
//! ≥ 99.9 %, median ≤ 50 µs). Before criterion runs, a report solves 10,000 poses per arm and
//! prints success rate, median, p95 and max times (criterion itself samples fewer solves).

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use criterion::{Criterion, criterion_group};
use nalgebra::{Matrix6xX, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use reachgrasp::kinematics::{
    Data, IkOptions, IkSolver, IkTarget, Model, forward_kinematics, frame_jacobian,
    model_from_urdf_file,
};

fn arm(file: &str) -> Model {
    model_from_urdf_file(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("robots/arms")
            .join(file),
    )
    .unwrap()
}

fn random_q(model: &Model, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..model.nq())
        .map(|k| rng.random_range(model.lower_limits()[k]..model.upper_limits()[k]))
        .collect()
}

fn targets(model: &Model, flange: &str, n: usize, seed: u64) -> Vec<(IkTarget, Vec<f64>)> {
    let f = model.frame_id(flange).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut data = Data::new(model);
    (0..n)
        .map(|_| {
            let q = random_q(model, &mut rng);
            forward_kinematics(model, &mut data, &q);
            let t = IkTarget {
                frame: f,
                point_in_frame: Vector3::zeros(),
                pose: *data.frame(f),
            };
            (t, random_q(model, &mut rng))
        })
        .collect()
}

fn ik_report() {
    for (file, flange) in [("wam.urdf", "wam_flange"), ("pa10.urdf", "pa10_flange")] {
        let model = arm(file);
        let opts = IkOptions::default();
        let mut solver = IkSolver::new(&model);
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        let mut times = Vec::new();
        let (mut ok, mut iters, mut restarts) = (0usize, 0usize, 0usize);
        let mut failures = Vec::new();
        let cases = targets(&model, flange, 10_000, 7);
        for (t, seed) in &cases {
            let start = Instant::now();
            let r = solver.solve(&model, t, seed, &opts, &mut rng);
            times.push(start.elapsed());
            ok += r.success as usize;
            if !r.success {
                failures.push(format!(
                    "{:.1} ms, {} restarts, {:.1e} m, {:.1e} rad",
                    r.elapsed.as_secs_f64() * 1e3,
                    r.restarts,
                    r.position_error,
                    r.orientation_error
                ));
            }
            iters += r.iterations;
            restarts += r.restarts;
        }
        times.sort();
        let pct = |p: f64| times[((times.len() - 1) as f64 * p) as usize];
        println!(
            "ik report {file}: {} poses, success {:.2} %, median {:?}, p95 {:?}, p99.9 {:?}, max {:?}, mean iterations {:.1}, mean restarts {:.2}",
            cases.len(),
            100.0 * ok as f64 / cases.len() as f64,
            pct(0.5),
            pct(0.95),
            pct(0.999),
            times.last().unwrap(),
            iters as f64 / cases.len() as f64,
            restarts as f64 / cases.len() as f64
        );
        // Why the failures failed (time budget, restart limit, residual left).
        for f in failures.iter().take(10) {
            println!("  failed: {f}");
        }
    }
}

fn fk_jacobian(c: &mut Criterion) {
    let model = arm("wam.urdf");
    let flange = model.frame_id("wam_flange").unwrap();
    let mut data = Data::new(&model);
    let mut j = Matrix6xX::zeros(model.nq());
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let qs: Vec<Vec<f64>> = (0..64).map(|_| random_q(&model, &mut rng)).collect();
    let mut i = 0;
    c.bench_function("wam fk all frames + 6x7 jacobian", |b| {
        b.iter(|| {
            i = (i + 1) & 63;
            forward_kinematics(&model, &mut data, black_box(&qs[i]));
            frame_jacobian(&model, &data, flange, &Vector3::zeros(), &mut j);
            black_box(&j);
        })
    });
}

fn ik(c: &mut Criterion) {
    let mut g = c.benchmark_group("pose ik, random reachable pose, random seed, default budget");
    for (file, flange) in [("wam.urdf", "wam_flange"), ("pa10.urdf", "pa10_flange")] {
        let model = arm(file);
        let cases = targets(&model, flange, 1000, 3);
        let mut solver = IkSolver::new(&model);
        let opts = IkOptions::default();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut i = 0;
        g.bench_function(file, |b| {
            b.iter(|| {
                i = (i + 1) % cases.len();
                let (t, seed) = &cases[i];
                black_box(solver.solve(&model, t, seed, &opts, &mut rng))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, fk_jacobian, ik);

/// `KIN_PROFILE=N`: only N FK + Jacobian evaluations, for instruction counts that do not depend
/// on machine load: `KIN_PROFILE=100000 valgrind --tool=callgrind --toggle-collect='*forward_kinematics*'
/// --toggle-collect='*frame_jacobian*' target/release/deps/kinematics-*` then divide by N.
fn profile_fk(n: usize) {
    let model = arm("wam.urdf");
    let flange = model.frame_id("wam_flange").unwrap();
    let mut data = Data::new(&model);
    let mut j = Matrix6xX::zeros(model.nq());
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let qs: Vec<Vec<f64>> = (0..64).map(|_| random_q(&model, &mut rng)).collect();
    for i in 0..n {
        forward_kinematics(&model, &mut data, black_box(&qs[i & 63]));
        frame_jacobian(&model, &data, flange, &Vector3::zeros(), &mut j);
        black_box(&j);
    }
}

fn main() {
    if let Some(n) = std::env::var("KIN_PROFILE")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        profile_fk(n);
        return;
    }
    ik_report();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
