//! Held-out humanlikeness of the motion models on real mapped data, for the six bundled systems
//! (issues 6 and 19): a synthetic human study (the paper's design: subjects × 5 object
//! positions × trials) is ingested, mapped onto each robot (eq. 1-7), and for every object
//! position a model is trained on the other four and tested on it.
//!
//! Per system, one table row with the mean arc-length-resampled joint-space deviation (rad) from
//! the held-out mapped trajectories, all on the same demonstrations: (a) the NF path alone (no
//! residual profile), (b) the straight joint line, (c) the straight line in PCA coordinates
//! (with the learned off-manifold curvature), (d) a goal-conditioned DMP per joint, (e) a ProMP
//! conditioned on start and goal, (f) the NF path with the residual profile (the option), and
//! `a / b`, `f / b`. Then per system and group: the explained variance of the first three
//! components (the paper's footnote 2: > 88 %), the default model's certificate (k, shrink,
//! boxes) and 10,000 random (start, goal) pairs of its flow: converged (error ≤ 1e-6 rad in
//! joint space) and how many of them let `γ` rise on the way.
//!
//! `cargo run --release --example motion_heldout -- [subjects] [trials]` (defaults 2 and 5).
//! Environment: `SEED` (study seed, 1), `PAIRS` (certificate pairs, 10000), `NO_PROFILE=1`
//! skips the residual-profile column.

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use reachgrasp::human::{StudyConfig, generate_study, ingest};
use reachgrasp::kinematics::System;
use reachgrasp::mapping::{
    BatchItem, MappingModel, RegistrationSpec, SolverOptions, Weights, map_batch,
};
use reachgrasp::motion::mapped::{DEFAULT_ACCELERATION_LIMIT, system_groups, system_limits};
use reachgrasp::motion::{
    DEFAULT_PROFILE_RIDGE, FlowOptions, FlowPath, HeldOutReport, JointTrajectory, MotionModel,
    TrainOptions, integrate_flow, train,
};

const SYSTEMS: [&str; 6] = [
    "wam_t42",
    "wam_ihy",
    "wam_ob4f",
    "pa10_t42",
    "pa10_ihy",
    "pa10_ob4f",
];

#[derive(Default)]
struct Sums {
    demos: usize,
    refused: usize,
    plain: f64,
    joint: f64,
    pca: f64,
    dmp: f64,
    promp: f64,
    profile: f64,
}

impl Sums {
    fn add(&mut self, h: &HeldOutReport, profile: Option<&HeldOutReport>) {
        let u = (h.demonstrations - h.refused) as f64;
        self.demos += h.demonstrations;
        self.refused += h.refused;
        self.plain += u * h.nf_plain;
        self.joint += u * h.joint_line;
        self.pca += u * h.pca_line;
        self.dmp += u * h.dmp;
        self.promp += u * h.promp;
        if let Some(p) = profile {
            self.profile += (p.demonstrations - p.refused) as f64 * p.nf;
        }
    }
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("subjects and trials are counts"))
        .collect();
    let with_profile = std::env::var_os("NO_PROFILE").is_none();
    let pairs = env_or("PAIRS", 10_000.0) as usize;
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
    let mut distinct = positions.clone();
    distinct.sort_unstable();
    distinct.dedup();
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
    let mut table = vec![
        "| system | held-out demos (refused) | (a) NF alone | (b) joint line | (c) PCA line | (d) DMP | (e) ProMP | (f) NF + profile | a / b | f / b |".to_string(),
        "|---|---|---|---|---|---|---|---|---|---|".to_string(),
    ];
    let mut extra = vec![
        "| system | group | PCs kept | first 3 PCs | k | shrink | boxes | pairs converged | γ rose |".to_string(),
        "|---|---|---|---|---|---|---|---|---|".to_string(),
    ];
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
        let limits = system_limits(&sys, DEFAULT_ACCELERATION_LIMIT);
        let opts = TrainOptions {
            groups: system_groups(&sys),
            cap_spline_intervals: true,
            ..TrainOptions::default()
        };
        let mut sums = Sums::default();
        for &p in &distinct {
            let held: Vec<usize> = (0..trajs.len()).filter(|&i| positions[i] == p).collect();
            let fold = TrainOptions {
                held_out: held,
                ..opts.clone()
            };
            let plain = match train(&trajs, &limits, &fold) {
                Ok((_, r)) => r.held_out.expect("held out"),
                Err(e) => {
                    eprintln!("  {name} position {p}: {e}");
                    continue;
                }
            };
            let profiled = with_profile.then(|| {
                let o = TrainOptions {
                    profile_ridge: Some(DEFAULT_PROFILE_RIDGE),
                    ..fold.clone()
                };
                train(&trajs, &limits, &o)
                    .expect("trains with the profile as without")
                    .1
                    .held_out
                    .expect("held out")
            });
            eprintln!(
                "  {name} position {p}: NF {:.4}, joint line {:.4}, PCA line {:.4}, DMP {:.4}, ProMP {:.4}, a/b {:.3}, refused {}/{}",
                plain.nf_plain,
                plain.joint_line,
                plain.pca_line,
                plain.dmp,
                plain.promp,
                plain.plain_ratio_to_joint_line,
                plain.refused,
                plain.demonstrations
            );
            sums.add(&plain, profiled.as_ref());
        }
        let used = (sums.demos - sums.refused) as f64;
        if used > 0.0 {
            let f = |v: f64| v / used;
            let profile = if with_profile {
                format!("{:.4}", f(sums.profile))
            } else {
                "-".into()
            };
            let profile_ratio = if with_profile {
                format!("{:.3}", sums.profile / sums.joint)
            } else {
                "-".into()
            };
            table.push(format!(
                "| {name} | {} ({}) | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {profile} | {:.3} | {profile_ratio} |",
                sums.demos,
                sums.refused,
                f(sums.plain),
                f(sums.joint),
                f(sums.pca),
                f(sums.dmp),
                f(sums.promp),
                sums.plain / sums.joint,
            ));
        } else {
            table.push(format!("| {name} | - | - | - | - | - | - | - | - | - |"));
        }
        eprintln!(
            "  {name}: mapped in {map_s:.1} s, folds trained in {:.1} s",
            t.elapsed().as_secs_f64()
        );
        // the default model (all demonstrations) and its certificate, checked on random pairs
        let (model, report) = train(&trajs, &limits, &opts).expect("default model");
        for (g, (m, fit)) in model.manifolds.iter().zip(&report.manifolds).enumerate() {
            let first3: f64 = m.pca.all_explained_variance.iter().take(3).sum();
            let (ok, rose) = certificate_pairs(&model, g, pairs, 7 + g as u64);
            let c = &m.certificate;
            extra.push(format!(
                "| {name} | {} | {} | {:.1} % | {} | {:.3} | {} | {ok}/{pairs} | {rose} |",
                if g == 0 { "arm" } else { "hand" },
                fit.components,
                100.0 * first3,
                c.k,
                c.shrink,
                c.boxes,
            ));
        }
    }
    for l in table {
        println!("{l}");
    }
    println!();
    for l in extra {
        println!("{l}");
    }
}

/// Random (start in the workspace ball, goal in the goal region) pairs of group `g`'s flow:
/// how many converge to within 1e-6 rad (joint space), and in how many `γ` rose on the way.
fn certificate_pairs(model: &MotionModel, g: usize, pairs: usize, seed: u64) -> (usize, usize) {
    let m = &model.manifolds[g];
    let c = &m.certificate;
    let d = m.pca.d();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ball = |rng: &mut ChaCha8Rng, center: &[f64], radius: f64| -> Vec<f64> {
        loop {
            let v: Vec<f64> = (0..d).map(|_| rng.random_range(-1.0..1.0)).collect();
            if v.iter().map(|x| x * x).sum::<f64>() < 1.0 {
                return v.iter().zip(center).map(|(a, c)| c + a * radius).collect();
            }
        }
    };
    let opts = FlowOptions::default();
    let mut path = FlowPath::default();
    let (mut ok, mut rose) = (0, 0);
    for _ in 0..pairs {
        let y0 = ball(&mut rng, &m.nf.center, 0.98 * m.nf.radius);
        let yd = ball(&mut rng, &c.goal_center, c.goal_radius);
        integrate_flow(&m.nf, &y0, &yd, &opts, &mut path);
        // ‖W e‖ = ‖e‖ (orthonormal columns)
        if path.converged && path.final_error <= 1e-6 {
            ok += 1;
        }
        if path.gamma.windows(2).any(|w| w[1] > w[0]) {
            rose += 1;
        }
    }
    (ok, rose)
}

/// A number from the environment, or `default`.
fn env_or(name: &str, default: f64) -> f64 {
    std::env::var(name).map_or(default, |v| v.parse().expect("a number"))
}
