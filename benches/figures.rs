//! Figure rendering (issue 9 target: every figure ≤ 50 ms). Each benchmark builds and renders
//! one figure from already-loaded data, as the `plot.svg` handlers do: robot posture (FK),
//! demonstration (a synthetic trial's frames), grasp (a planned grasp), mapping (Fig. 2, a
//! demonstration-length joint trajectory with three postures), trajectory and execution
//! (7 joints × 300 points), the largest execution figure (every wam_ihy joint, a 200 s plan at
//! 100 Hz and a feedback history at its bound of 4000 samples), model (variance bars and
//! 10 + 10 PCA paths).

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use reachgrasp::figures::{
    ExecutionSample, GraspInput, MappingInput, PcaPath, View, demonstration_figure,
    execution_figure, grasp_scene, mapping_scene, model_figure, posture_scene, render_scene,
    trajectory_figure,
};
use reachgrasp::grasp::objects::seeded_object;
use reachgrasp::grasp::{GraspRequest, HandArm, Object, QualityMeasure, Transmission, plan_grasp};
use reachgrasp::human::{self, StudyConfig};
use reachgrasp::kinematics::System;
use reachgrasp::mapping::{FrameMetrics, MAX_FINGERS, MappedTrajectory, Registration};
use reachgrasp::motion::TrajectoryPoint;

fn mapped(sys: &System, frames: usize) -> MappedTrajectory {
    let m = &sys.model;
    let nq = m.nq();
    let (lo, hi) = (m.lower_limits(), m.upper_limits());
    let mut positions = Vec::with_capacity(frames * nq);
    for k in 0..frames {
        let s = k as f64 / (frames - 1) as f64;
        for j in 0..nq {
            let mid = if lo[j].is_finite() && hi[j].is_finite() {
                0.5 * (lo[j] + hi[j])
            } else {
                0.0
            };
            positions.push(mid + 0.3 * s * (j as f64 * 0.7).sin());
        }
    }
    let metric = FrameMetrics {
        t: 0.0,
        fingers: sys.fingers.len(),
        position_error: [0.0; MAX_FINGERS],
        orientation_error: [0.0; MAX_FINGERS],
        elbow_distance: 0.0,
        elbow_distance_mean: 0.0,
        objective: 0.0,
        iterations: 1,
        converged: true,
        swivel_human: f64::NAN,
        swivel_robot: f64::NAN,
        swivel_difference: f64::NAN,
        elbow_bound: f64::NAN,
        support_clearance: f64::NAN,
        object_clearance: f64::NAN,
    };
    MappedTrajectory {
        joint_names: m.joint_names().to_vec(),
        times: (0..frames).map(|k| k as f64 / 120.0).collect(),
        positions,
        metrics: vec![metric; frames],
        registration: Registration::identity(),
    }
}

fn points(n: usize, joints: usize) -> Vec<TrajectoryPoint> {
    (0..n)
        .map(|k| {
            let t = k as f64 * 0.01;
            TrajectoryPoint {
                t,
                positions: (0..joints).map(|j| (t + j as f64).sin()).collect(),
                velocities: vec![0.0; joints],
                accelerations: vec![0.0; joints],
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml");
    let sys = System::from_file(&path).expect("bundled system");
    let view = View::default();
    let cfg = StudyConfig {
        subjects: 1,
        positions: 1,
        trials: 1,
        ..StudyConfig::default()
    };
    let input = human::synth::generate_trial(&cfg.trials()[0], cfg.seed).expect("trial");
    let frames = human::ingest(&input).expect("ingest").frames;

    let mut g = c.benchmark_group("figures");
    g.bench_function("posture", |b| {
        let q = sys.model.neutral();
        b.iter(|| render_scene(&posture_scene(&sys, &q).unwrap(), view).unwrap())
    });
    g.bench_function("demonstration", |b| {
        b.iter(|| demonstration_figure("demo", &frames).unwrap())
    });

    let hand_arm = HandArm::from_system(&sys).expect("grasp view");
    let spec = seeded_object("ball", 0.5, 0.0, 0.0).expect("seeded");
    let req = GraspRequest::new(
        Object::new(spec.clone()).unwrap(),
        vec![],
        QualityMeasure::CentroidDistance,
    );
    let result = plan_grasp(&hand_arm, &req).expect("grasp");
    let dirs = [([0.0, 0.0, 1.0], Transmission::Force)];
    g.bench_function("grasp", |b| {
        b.iter(|| {
            let scene = grasp_scene(&GraspInput {
                system: &hand_arm,
                result: &result,
                object: &spec,
                task_directions: &dirs,
                ellipsoid: None,
            })
            .unwrap();
            render_scene(&scene, view).unwrap()
        })
    });

    let traj = mapped(&sys, frames.len());
    println!("mapping figure: {} frames", frames.len());
    g.bench_function("mapping", |b| {
        b.iter(|| {
            let scene = mapping_scene(&MappingInput {
                system: &sys,
                human: &frames,
                trajectory: &traj,
                postures: 3,
            })
            .unwrap();
            render_scene(&scene, view).unwrap()
        })
    });

    let names: Vec<String> = (1..=7).map(|j| format!("j{j}")).collect();
    let planned = points(300, 7);
    let measured: Vec<ExecutionSample> = planned
        .iter()
        .map(|p| ExecutionSample {
            t: p.t,
            positions: p.positions.iter().map(|x| x + 0.01).collect(),
        })
        .collect();
    g.bench_function("trajectory", |b| {
        b.iter(|| trajectory_figure("t", &names, &planned).unwrap())
    });
    g.bench_function("execution", |b| {
        b.iter(|| execution_figure("e", &names, &planned, &measured).unwrap())
    });
    // The largest execution figure: every wam_ihy joint, a 200 s trajectory at 100 Hz and a
    // feedback history at its bound (store::feedback::MAX_SAMPLES).
    let all: Vec<String> = sys.model.joint_names().to_vec();
    let long_plan = points(20_000, all.len());
    let long_measured: Vec<ExecutionSample> = long_plan
        .iter()
        .step_by(5)
        .take(reachgrasp::store::feedback::MAX_SAMPLES)
        .map(|p| ExecutionSample {
            t: p.t + 0.005,
            positions: p.positions.iter().map(|x| x + 0.01).collect(),
        })
        .collect();
    println!(
        "execution_full_history figure: {} joints, {} planned points, {} measured samples",
        all.len(),
        long_plan.len(),
        long_measured.len()
    );
    g.bench_function("execution_full_history", |b| {
        b.iter(|| execution_figure("e", &all, &long_plan, &long_measured).unwrap())
    });
    let paths: Vec<PcaPath> = (0..20)
        .map(|i| PcaPath {
            generated: i % 2 == 1,
            points: (0..200)
                .map(|k| {
                    let s = k as f64 / 199.0;
                    (s + i as f64 * 0.1, s * s - i as f64 * 0.05)
                })
                .collect(),
        })
        .collect();
    g.bench_function("model", |b| {
        b.iter(|| model_figure("m", &[0.6, 0.2, 0.08, 0.04], &paths).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
