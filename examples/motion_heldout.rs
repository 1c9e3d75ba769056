//! Held-out humanlikeness of the motion models on real mapped data, for the six bundled systems
//! (issue 6): a synthetic human study (the paper's design: subjects × 5 object positions ×
//! trials) is ingested, mapped onto each robot (eq. 1-7), and for every object position a model
//! is trained on the other four and tested on it. Reported per system: the mean
//! arc-length-resampled joint-space deviation (rad) from the held-out mapped trajectories of
//! (a) the NF model, (b) the straight joint line, (c) a DMP and (d) a ProMP conditioned on start
//! and goal (both trained on the same folds), and `a / b`.
//!
//! The NF model is trained with its goal-conditioned residual profile
//! ([`reachgrasp::motion::ResidualProfile`]); `NO_PROFILE=1` trains the plain NF path.
//!
//! Then, per system and joint group, the variance the first three principal components explain
//! in a model trained on every demonstration (the paper's footnote 2: more than 88 %).
//!
//! `cargo run --release --example motion_heldout -- [subjects] [trials]` (defaults 2 and 5).

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use reachgrasp::human::{StudyConfig, generate_study, ingest};
use reachgrasp::kinematics::System;
use reachgrasp::mapping::{
    BatchItem, MappingModel, RegistrationSpec, SolverOptions, Weights, map_batch,
};
use reachgrasp::motion::mapped::{
    DEFAULT_ACCELERATION_LIMIT, DEFAULT_JERK_LIMIT, system_groups, system_limits,
};
use reachgrasp::motion::{
    CertificateKind, DEFAULT_PROFILE_RIDGE, JointTrajectory, ProfileInputs, TrainOptions, train,
};
use reachgrasp::service::models::held_out_folds;

const SYSTEMS: [&str; 6] = [
    "wam_t42",
    "wam_ihy",
    "wam_ob4f",
    "pa10_t42",
    "pa10_ihy",
    "pa10_ob4f",
];

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("subjects and trials are counts"))
        .collect();
    // `NO_PROFILE=1`: the plain NF path (no residual profile), the previous table.
    let profile = if std::env::var_os("NO_PROFILE").is_some() {
        None
    } else {
        Some(env_or("PROFILE_RIDGE", DEFAULT_PROFILE_RIDGE))
    };
    let profile_inputs: ProfileInputs = std::env::var("PROFILE_INPUTS")
        .map(|v| serde_json::from_value(serde_json::Value::String(v)).expect("profile inputs"))
        .unwrap_or_default();
    // `CERTIFICATE=no_critical_point`: the navigation-function certificate chooses the shrink.
    let certificate: CertificateKind = std::env::var("CERTIFICATE")
        .map(|v| serde_json::from_value(serde_json::Value::String(v)).expect("certificate kind"))
        .unwrap_or_default();
    let defaults = TrainOptions::default();
    let goal_margin = env_or("GOAL_MARGIN", defaults.goal_margin);
    let workspace_margin = env_or("WORKSPACE_MARGIN", defaults.workspace_margin);
    let cfg = StudyConfig {
        subjects: args.first().copied().unwrap_or(2),
        trials: args.get(1).copied().unwrap_or(5),
        seed: env_or("SEED", 1.0) as u64,
        ..StudyConfig::default()
    };
    let t0 = Instant::now();
    let demos: Vec<_> = generate_study(&cfg)
        .expect("study")
        .iter()
        .map(|d| ingest(d).expect("ingest"))
        .collect();
    let positions: Vec<u32> = demos.iter().map(|d| d.labels.position_index).collect();
    eprintln!(
        "{} demonstrations ingested in {:.1} s",
        demos.len(),
        t0.elapsed().as_secs_f64()
    );
    let spec = RegistrationSpec::default();
    let items: Vec<BatchItem<'_>> = demos
        .iter()
        .map(|d| BatchItem {
            frames: &d.frames,
            registration: &spec,
        })
        .collect();
    println!(
        "| system | folds | held-out demos (refused) | (a) NF | (b) joint line | (c) DMP | (d) ProMP | a / b |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut variance = Vec::new();
    for name in SYSTEMS {
        let sys = System::from_file(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("robots/systems/{name}.toml")),
        )
        .expect("bundled system");
        let mm = MappingModel::from_system(&sys).expect("mapping model");
        let anchor = mm.anchor();
        let t = Instant::now();
        let mapped = map_batch(
            &mm,
            &anchor,
            &items,
            Weights::default(),
            SolverOptions::default(),
            2,
            &|_, _| {},
            &AtomicBool::new(false),
        )
        .expect("not cancelled");
        let trajs: Vec<JointTrajectory> = mapped
            .iter()
            .map(|m| JointTrajectory::from(m.as_ref().expect("mapped")))
            .collect();
        let map_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let limits = system_limits(&sys, DEFAULT_ACCELERATION_LIMIT, DEFAULT_JERK_LIMIT);
        let opts = TrainOptions {
            groups: system_groups(&sys),
            cap_spline_intervals: true,
            profile_ridge: profile,
            profile_inputs,
            goal_margin,
            workspace_margin,
            certificate,
            ..TrainOptions::default()
        };
        let (all, _) = train(&trajs, &limits, &opts).expect("a model of every demonstration");
        for m in &all.manifolds {
            let c = &m.certificate;
            let cp = c.critical_points.as_ref();
            eprintln!(
                "{name}: k {} shrink {:.3} γ decreasing {} no critical point {:?} ({} boxes, depth {})",
                c.k,
                c.shrink,
                c.gamma_decreasing,
                cp.map(|p| p.holds),
                cp.map_or(0, |p| p.boxes),
                cp.map_or(0, |p| p.depth),
            );
        }
        variance.push((
            name,
            all.manifolds
                .iter()
                .map(|m| {
                    let v = &m.pca.all_explained_variance;
                    (v.iter().take(3).sum::<f64>(), m.pca.d(), v.len())
                })
                .collect::<Vec<_>>(),
        ));
        let summary =
            held_out_folds(&trajs, &positions, &limits, &opts, |_, _| {}).expect("5 positions");
        for f in &summary.folds {
            match (&f.result, &f.error) {
                (Some(r), _) => eprintln!(
                    "  {name} position {}: NF {:.4}, joint line {:.4}, DMP {:.4}, ProMP {:.4}, ratio {:.3}, refused {}/{}",
                    f.position_index,
                    r.nf,
                    r.joint_line,
                    r.dmp.unwrap_or(f64::NAN),
                    r.promp.unwrap_or(f64::NAN),
                    r.ratio_to_joint_line,
                    r.refused,
                    r.demonstrations
                ),
                (None, e) => eprintln!("  {name} position {}: {e:?}", f.position_index),
            }
        }
        eprintln!(
            "  {name}: mapped in {map_s:.1} s, folds trained in {:.1} s",
            t.elapsed().as_secs_f64()
        );
        let ok = summary.folds.iter().filter(|f| f.result.is_some()).count();
        match summary.overall {
            Some(o) => println!(
                "| {name} | {ok}/{} | {} ({}) | {:.4} | {:.4} | {:.4} | {:.4} | {:.3} |",
                summary.folds.len(),
                o.demonstrations,
                o.refused,
                o.nf,
                o.joint_line,
                o.dmp.unwrap_or(f64::NAN),
                o.promp.unwrap_or(f64::NAN),
                o.ratio_to_joint_line
            ),
            None => println!(
                "| {name} | {ok}/{} | - | - | - | - | - | - |",
                summary.folds.len()
            ),
        }
    }
    println!();
    println!("| system | group | first 3 components | components kept / joints |");
    println!("|---|---|---|---|");
    for (name, groups) in variance {
        for (g, (first3, kept, joints)) in groups.iter().enumerate() {
            let group = if g == 0 { "arm" } else { "hand" };
            println!(
                "| {name} | {group} | {:.1} % | {kept} / {joints} |",
                100.0 * first3
            );
        }
    }
}

/// A number from the environment, or `default`.
fn env_or(name: &str, default: f64) -> f64 {
    std::env::var(name).map_or(default, |v| v.parse().expect("a number"))
}
