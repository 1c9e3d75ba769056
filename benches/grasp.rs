//! Grasp planning over the seeded objects at the documented reachable placements, for every
//! shipped arm-hand system. Targets (issue 7): a feasible grasp in ≥ 95 % of requests and a
//! median time per request ≤ 100 ms on 2 cores. A first pass prints the feasible rate and the
//! median/max request time per system; criterion then times the request loop.

use std::path::Path;

use criterion::{Criterion, criterion_group, criterion_main};
use reachgrasp::grasp::objects::{REACHABLE_PLACEMENTS, seeded_object, seeded_shapes};
use reachgrasp::grasp::{GraspRequest, HandArm, Object, QualityMeasure, plan_grasp};
use reachgrasp::kinematics::System;

const SYSTEMS: [&str; 6] = [
    "wam_t42",
    "wam_ihy",
    "wam_ob4f",
    "pa10_t42",
    "pa10_ihy",
    "pa10_ob4f",
];

fn requests() -> Vec<GraspRequest> {
    let mut out = Vec::new();
    for (name, _, _) in seeded_shapes() {
        for (x, y) in REACHABLE_PLACEMENTS {
            let obj = Object::new(seeded_object(name, x, y, 0.0).expect("seeded")).expect("valid");
            out.push(GraspRequest::new(
                obj,
                vec![],
                QualityMeasure::CentroidDistance,
            ));
        }
    }
    out
}

fn bench(c: &mut Criterion) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("robots/systems");
    let reqs = requests();
    let mut group = c.benchmark_group("grasp");
    group.sample_size(10);
    // `GRASP_SYSTEMS=pa10_ob4f,wam_t42` restricts the run (profiling one system under callgrind).
    let only = std::env::var("GRASP_SYSTEMS").ok();
    for name in SYSTEMS {
        if only
            .as_deref()
            .is_some_and(|o| !o.split(',').any(|x| x == name))
        {
            continue;
        }
        let sys = System::from_file(&dir.join(format!("{name}.toml"))).expect("system loads");
        let sys = HandArm::from_system(&sys).expect("grasp view");
        let mut times = Vec::new();
        let mut feasible = 0;
        for r in &reqs {
            let res = plan_grasp(&sys, r).expect("valid request");
            feasible += usize::from(res.feasible);
            times.push(res.time_s * 1e3);
            if std::env::var_os("GRASP_VERBOSE").is_some() {
                println!(
                    "  {} at {:?}: {:.1} ms, feasible {} ({}/{} starts), best start {:?}",
                    r.object.spec().name,
                    r.object.spec().position,
                    res.time_s * 1e3,
                    res.feasible,
                    res.starts_feasible,
                    res.starts_used,
                    res.solver
                );
            }
        }
        times.sort_by(f64::total_cmp);
        println!(
            "grasp/{name}: feasible {feasible}/{} ({:.1} %), median {:.1} ms, max {:.1} ms per request",
            reqs.len(),
            100.0 * feasible as f64 / reqs.len() as f64,
            times[times.len() / 2],
            times[times.len() - 1]
        );
        let mut k = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                k = (k + 1) % reqs.len();
                plan_grasp(&sys, &reqs[k]).expect("valid request")
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
