//! Human demonstrations: ingest + derive one minute of tracker (240 Hz) and glove (90 Hz) data
//! (target ≤ 50 ms), and generate the default 250-demonstration synthetic study (target ≤ 2 s).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{UnitQuaternion, Vector3};
use reachgrasp::human::{
    DemonstrationInput, GloveStream, Labels, ObjectShape, ObjectSpec, Pose, StudyConfig, Subject,
    SyncOptions, TrackerStream, generate_study, ingest,
};

/// One minute of smooth, plausible signals (a slow reaching oscillation).
fn one_minute(rate_hz: f64) -> DemonstrationInput {
    let nt = 60 * 240 + 1;
    let ng = 60 * 90 + 1;
    let tt: Vec<f64> = (0..nt).map(|k| k as f64 / 240.0).collect();
    let gt: Vec<f64> = (0..ng).map(|k| k as f64 / 90.0).collect();
    let s = |t: f64| (0.5 * t).sin();
    DemonstrationInput {
        subject: Subject::average("bench"),
        object: ObjectSpec {
            name: "ball".into(),
            shape: ObjectShape::Sphere { radius: 0.04 },
            pose: Pose::default(),
        },
        labels: Labels {
            task: "grasp".into(),
            position_index: 0,
            trial: 0,
            synthetic: false,
            external_id: None,
        },
        tracker: TrackerStream {
            shoulder: tt
                .iter()
                .map(|&t| vec![-0.15, 0.0, 0.33 + 0.01 * s(t)])
                .collect(),
            elbow: tt
                .iter()
                .map(|&t| vec![-0.1 + 0.05 * s(t), -0.15, 0.1])
                .collect(),
            wrist: tt
                .iter()
                .map(|&t| vec![0.1 + 0.2 * s(t), -0.05, 0.08])
                .collect(),
            wrist_orientation: tt
                .iter()
                .map(|&t| {
                    let q = UnitQuaternion::from_scaled_axis(Vector3::new(3.0, 0.2 * s(t), 0.1));
                    vec![q.w, q.i, q.j, q.k]
                })
                .collect(),
            t: tt,
        },
        glove: GloveStream {
            angles: Some(
                gt.iter()
                    .map(|&t| (0..22).map(|k| 0.3 * s(t + k as f64)).collect())
                    .collect(),
            ),
            t: gt,
            raw: None,
            calibration: None,
        },
        keypoints: None,
        sync: SyncOptions {
            rate_hz,
            ..SyncOptions::default()
        },
    }
}

fn bench(c: &mut Criterion) {
    let input = one_minute(120.0);
    c.bench_function("ingest_derive_1min_to_120hz", |b| {
        b.iter(|| ingest(black_box(&input)))
    });
    let input = one_minute(240.0);
    c.bench_function("ingest_derive_1min_to_240hz", |b| {
        b.iter(|| ingest(black_box(&input)))
    });

    let mut g = c.benchmark_group("study");
    g.sample_size(10);
    let cfg = StudyConfig::default();
    g.bench_function("generate_default_250", |b| {
        b.iter(|| generate_study(black_box(&cfg)))
    });
    g.bench_function("generate_and_ingest_default_250", |b| {
        b.iter(|| {
            generate_study(&cfg)
                .unwrap()
                .iter()
                .map(|d| ingest(d).unwrap().frames.len())
                .sum::<usize>()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
