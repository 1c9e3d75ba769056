//! Mapping throughput: single thread, `wam_ihy`, warm-started frames, default weights, in the
//! demonstration's registered scene (the exact support/object clearance penalty active).
//!
//! Reports frames/s of `Mapper::solve_next` over a synthetic demonstration (target ≥ 5,000), of
//! a whole `Mapper::map` (first frame by the multi-start, every later frame and the exact
//! clearance metrics), of a whole `Mapper::map_from` (what a batch does for every demonstration
//! but its first: the first frame solved locally from another subject's first posture), and,
//! once, checks the warm-started objective of the median frame against a reference solve (tight
//! tolerance, several starts): printed as a relative gap (target ≤ 1 %).

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use reachgrasp::human::{StudyConfig, generate_study, ingest};
use reachgrasp::kinematics::System;
use reachgrasp::mapping::{
    FrameGoals, Mapper, MappingModel, RegistrationSpec, SolverOptions, Weights, human_object,
    registration_for,
};

fn bench(c: &mut Criterion) {
    let sys = System::from_file(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems/wam_ihy.toml"),
    )
    .unwrap();
    let mm = MappingModel::from_system(&sys).unwrap();
    let anchor = mm.anchor();
    let cfg = StudyConfig {
        subjects: 1,
        positions: 1,
        trials: 1,
        ..StudyConfig::default()
    };
    let demo = ingest(&generate_study(&cfg).unwrap()[0]).unwrap();
    // Another subject's demonstration: the batch reference of the `map_from` figure.
    let two = StudyConfig {
        subjects: 2,
        ..cfg.clone()
    };
    let other = ingest(&generate_study(&two).unwrap()[1]).unwrap();
    let frames = demo.frames;
    let spec = RegistrationSpec::default().for_object(Some(human_object(&demo.object)));
    let reg = registration_for(&frames, &spec, &anchor).unwrap();
    let mut mapper = Mapper::new(mm.clone(), Weights::default(), SolverOptions::default()).unwrap();
    mapper.set_scene(&reg);
    let goals: Vec<FrameGoals> = frames
        .iter()
        .map(|f| {
            let mut g = FrameGoals::default();
            mapper.goals(f, &reg, &mut g);
            g
        })
        .collect();
    let first = mapper.solve_first(&goals[0], frames[0].t);
    let q0 = mapper.solution().to_vec();

    // Quality: warm-started objective on the median frame vs a tight multi-start reference.
    let mut objectives = Vec::with_capacity(frames.len());
    objectives.push(first.objective);
    let mut warm_solutions = vec![q0.clone()];
    for k in 1..frames.len() {
        let m = mapper.solve_next(&goals[k], frames[k].t, frames[k].t - frames[k - 1].t);
        objectives.push(m.objective);
        warm_solutions.push(mapper.solution().to_vec());
    }
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| objectives[a].total_cmp(&objectives[b]));
    let median = order[order.len() / 2];
    let tight = SolverOptions {
        tolerance: 1e-10,
        first_frame_tolerance: 1e-10,
        max_iterations: 5000,
        first_frame_max_iterations: 5000,
        first_frame_starts: 16,
        ..SolverOptions::default()
    };
    let mut reference = Mapper::new(mm.clone(), Weights::default(), tight).unwrap();
    reference.set_scene(&reg);
    let mut best = reference
        .solve_first(&goals[median], frames[median].t)
        .objective;
    // The reference also polishes the warm solution with the tight tolerance, so it is never
    // worse than the warm start it is compared with.
    reference.set_solution(&warm_solutions[median]);
    let polished = reference
        .solve_next(&goals[median], frames[median].t, 1.0)
        .objective;
    best = best.min(polished);
    let warm = objectives[median];
    println!(
        "mapping quality: median frame {median}: warm-started F = {warm:.6e}, reference F = {best:.6e}, \
         gap {:.3} %",
        100.0 * (warm - best) / best.abs().max(1e-300)
    );

    let mut group = c.benchmark_group("mapping");
    let n = frames.len() - 1;
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function("wam_ihy_warm_started_frames", |b| {
        b.iter(|| {
            mapper.set_solution(&q0);
            for k in 1..frames.len() {
                let m = mapper.solve_next(&goals[k], frames[k].t, frames[k].t - frames[k - 1].t);
                std::hint::black_box(m.objective);
            }
        })
    });
    let mut whole = Mapper::new(mm.clone(), Weights::default(), SolverOptions::default()).unwrap();
    group.throughput(Throughput::Elements(frames.len() as u64));
    group.bench_function("wam_ihy_whole_demonstration_with_clearance_metrics", |b| {
        b.iter(|| std::hint::black_box(whole.map(&frames, &spec, &anchor).unwrap().metrics.len()))
    });
    let other_spec = RegistrationSpec::default().for_object(Some(human_object(&other.object)));
    let reference = whole
        .start_reference(&other.frames, &other_spec, &anchor)
        .unwrap();
    group.bench_function("wam_ihy_whole_demonstration_from_a_batch_reference", |b| {
        b.iter(|| {
            std::hint::black_box(
                whole
                    .map_from(&frames, &spec, &anchor, &reference)
                    .unwrap()
                    .metrics
                    .len(),
            )
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
