//! Motion model benchmarks: training on the default-size synthetic study (250 demonstrations of
//! 100 frames, arm 7 + hand 4 joints; target ≤ 2 s), one trajectory (≤ 2 ms) and one
//! evaluation of the closed-loop law (≤ 5 µs). Trained as `POST /v1/models` trains by default,
//! with the residual profile; `train_250_demos_plain_nf` is the same without it,
//! `train_250_demos_no_critical_point` with the navigation-function certificate choosing the
//! shrink, `trajectory_no_critical_point` a trajectory of that model, `trajectory_within_limits`
//! the first trajectory given a duration the joint limits allow, and
//! `control_path_follower` one period of the closed-loop law along a plan's path (≤ 5 µs).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use reachgrasp::motion::synthetic::{SyntheticStudy, curved_study};
use reachgrasp::motion::{
    CLOCK_TOLERANCE, CertificateKind, Components, DEFAULT_PROFILE_RIDGE, PathFollower,
    TrainOptions, TrajectoryOptions, train,
};

fn bench(c: &mut Criterion) {
    let data = curved_study(&SyntheticStudy {
        trials_per_position: 50,
        frames: 100,
        ..SyntheticStudy::default()
    });
    assert_eq!(data.demos.len(), 250);
    let opts = TrainOptions {
        groups: data.groups.clone(),
        components: Components::VarianceThreshold(0.97),
        profile_ridge: Some(DEFAULT_PROFILE_RIDGE),
        ..TrainOptions::default()
    };
    let plain = TrainOptions {
        profile_ridge: None,
        ..opts.clone()
    };
    let critical = TrainOptions {
        certificate: CertificateKind::NoCriticalPoint,
        ..opts.clone()
    };
    let mut group = c.benchmark_group("motion");
    group.sample_size(10);
    group.bench_function("train_250_demos", |b| {
        b.iter(|| train(black_box(&data.demos), &data.limits, &opts).unwrap())
    });
    group.bench_function("train_250_demos_plain_nf", |b| {
        b.iter(|| train(black_box(&data.demos), &data.limits, &plain).unwrap())
    });
    group.bench_function("train_250_demos_no_critical_point", |b| {
        b.iter(|| train(black_box(&data.demos), &data.limits, &critical).unwrap())
    });
    group.finish();

    let (model, _) = train(&data.demos, &data.limits, &opts).unwrap();
    let n = model.n_joints;
    let start = data.demos[0].frame(0, n).to_vec();
    let goal = data.demos[137].frame(99, n).to_vec();
    let topts = TrajectoryOptions::default();
    c.bench_function("trajectory", |b| {
        b.iter(|| {
            model
                .trajectory(black_box(&start), black_box(&goal), &topts)
                .unwrap()
        })
    });

    // The same reach given 3 s, which the limits allow: the humanlike clock is kept, so one fit
    // of the dilation (the learned 1.23 s is refused: then three fits compete, see `retime`).
    let relaxed = TrajectoryOptions {
        duration: Some(3.0),
        ..TrajectoryOptions::default()
    };
    c.bench_function("trajectory_within_limits", |b| {
        b.iter(|| {
            model
                .trajectory(black_box(&start), black_box(&goal), &relaxed)
                .unwrap()
        })
    });

    let (certified, _) = train(&data.demos, &data.limits, &critical).unwrap();
    c.bench_function("trajectory_no_critical_point", |b| {
        b.iter(|| {
            certified
                .trajectory(black_box(&start), black_box(&goal), &topts)
                .unwrap()
        })
    });

    let params = model.control_params((0..n).map(|j| format!("j{j}")).collect(), 2.0, 2.0);
    let q = data.demos[3].frame(40, n).to_vec();
    let mut u = vec![0.0; n];
    c.bench_function("control_law", |b| {
        b.iter(|| params.control(black_box(&q), black_box(&goal), &mut u))
    });

    // One period of the closed-loop law along a path (issue 19): the robot a little off the
    // path at its middle, the clock reset each time so that it stays there.
    let path = model.trajectory(&start, &goal, &topts).unwrap().points;
    let mid = path[path.len() / 2].clone();
    let off: Vec<f64> = mid.positions.iter().map(|x| x + 0.005).collect();
    let mut reference = vec![0.0; n];
    let mut follower = PathFollower::new(8.0, CLOCK_TOLERANCE, vec![5.0; n]);
    follower.step(&path, &off, mid.t, &mut reference, &mut u);
    let at = follower.clone();
    c.bench_function("control_path_follower", |b| {
        b.iter(|| {
            follower.clone_from(&at);
            follower.step(&path, black_box(&off), 0.01, &mut reference, &mut u)
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
