//! The `reachgrasp` binary: `serve` (the default) runs the HTTP service; `openapi` prints the
//! OpenAPI document; `synth` prints a synthetic demonstration study; `map` maps demonstrations
//! onto a robot offline; `bridge --sim` runs the reference (simulated) bridge worker.

use clap::{Parser, Subcommand};
use reachgrasp::app::{App, init_tracing, shutdown_signal};
use reachgrasp::config::{Config, DEFAULT_ROBOTS, Logging, ROBOTS_HELP, Sources};

#[derive(Debug, Parser)]
#[command(
    name = "reachgrasp",
    version,
    about = "Humanlike reach-and-grasp planning service",
    // The service's flags belong to the service: `reachgrasp --bind ...` (serve by default) or
    // `reachgrasp serve --bind ...`; each other sub-command lists only what it reads.
    args_conflicts_with_subcommands = true
)]
struct Cli {
    #[command(flatten)]
    config: Config,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the HTTP service (the default when no sub-command is given).
    #[command(
        after_help = "Example:\n  REACHGRASP_BIND=0.0.0.0:8080 REACHGRASP_BRIDGE_TOKEN=lab-token reachgrasp serve"
    )]
    Serve(Box<Config>),
    /// Print the OpenAPI 3.1 document as JSON on stdout.
    #[command(after_help = "Example:\n  reachgrasp openapi > openapi/openapi.json")]
    Openapi,
    /// Solve a batch of pose IK targets and print solutions and statistics as JSON.
    #[command(
        after_help = "Example:\n  reachgrasp ik --robot wam_ihy --targets examples/ik-targets.json"
    )]
    Ik {
        #[command(flatten)]
        sources: Sources,
        /// A robot id (bundled or registered) or a system descriptor file.
        #[arg(long)]
        robot: String,
        /// JSON file: a list of IK requests (the body of POST /v1/robots/{id}/ik), or
        /// `{"targets": [...]}`.
        #[arg(long)]
        targets: std::path::PathBuf,
    },
    /// Run a bridge worker: connect to the service's `/v1/bridges/connect` and execute what it
    /// forwards. `--sim` drives a simulated robot (the only built-in robot driver).
    #[command(
        after_help = "Example:\n  reachgrasp bridge --sim --robot wam_ihy --url ws://127.0.0.1:8080/v1/bridges/connect --token lab-token --perturb"
    )]
    Bridge(BridgeArgs),
    /// Generate a seeded synthetic demonstration study and print it as JSON on stdout: an array
    /// of upload documents (each one a valid `POST /v1/demonstrations` body), or with
    /// `--summary` the ingest summary of each. Progress bar on stderr.
    #[command(
        after_help = "Example:\n  reachgrasp synth --seed 7 --subjects 2 --objects ball,bottle > study.json"
    )]
    Synth(SynthArgs),
    /// Compute a task-specific grasp offline (same body and result as `POST /v1/grasps`; a
    /// seeded object is named by `object_id`, e.g. `ball`). Prints the result as JSON. A request
    /// file holding an array is a batch: a progress bar on stderr, an array of results.
    #[command(
        after_help = "Examples:\n  reachgrasp grasp --robot wam_ihy --object ball --direction 0,0,1 --kind force\n  \
        reachgrasp grasp --request examples/grasp-ball.json > results.json"
    )]
    Grasp {
        #[arg(long, env = "REACHGRASP_ROBOTS", default_value = DEFAULT_ROBOTS, help = ROBOTS_HELP)]
        robots: std::path::PathBuf,
        /// JSON request file: the `POST /v1/grasps` body, or an array of them (a batch); the
        /// flags below build one instead.
        #[arg(long)]
        request: Option<std::path::PathBuf>,
        /// Arm-hand system, e.g. `wam_ihy`.
        #[arg(long)]
        robot: Option<String>,
        /// Seeded object name (`ball`, `bottle`, `kitchen_timer`, `pencil`, `sunglasses`).
        #[arg(long)]
        object: Option<String>,
        /// Task direction `x,y,z` or `x y z` (world frame); write `--direction=-1,0,0` when the
        /// first is negative.
        #[arg(
            long,
            value_delimiter = ',',
            num_args = 1..=3,
            allow_negative_numbers = true
        )]
        direction: Option<Vec<f64>>,
        /// `force` or `velocity` for --direction.
        #[arg(long, default_value = "velocity")]
        kind: String,
        /// `maximize` or `minimize` for --direction.
        #[arg(long, default_value = "maximize")]
        goal: String,
        /// Starts of the multi-start search (its first round).
        #[arg(long)]
        starts: Option<usize>,
        /// Most starts in all while none is feasible and firm (default 64).
        #[arg(long)]
        max_starts: Option<usize>,
        /// Seed of the multi-start search: the same seed, the same grasp.
        #[arg(long)]
        seed: Option<u64>,
    },
    /// Map human demonstrations onto a robot offline (the computation of `POST /v1/mappings`):
    /// progress bar on stderr, JSON on stdout (summary, and per demonstration the joint
    /// trajectory and per-frame metrics).
    #[command(
        after_help = "Example:\n  reachgrasp synth --subjects 1 --positions 1 --trials 2 > demos.json\n  \
        reachgrasp map --robot wam_ihy --demo demos.json --rate 30 --weights 1,1e-4,0.01 > mapped.json\n  \
        reachgrasp map --robot wam_ihy --demo examples/demonstration.json > mapped.json"
    )]
    Map(MapArgs),
    /// Retarget a recorded hand keypoint stream onto a robot frame by frame on one thread, as
    /// the WebSocket `GET /v1/robots/{id}/retarget` does, and report frames/s, per-frame latency
    /// and fingertip error (from the goals, and from the file's `targets` when it has them) on
    /// stderr; the report with every frame's joint values as JSON on stdout.
    #[command(
        after_help = "The file: an array of frames ({t, points: 21 x [x,y,z], wrist_orientation?, elbow?, shoulder?}),\n\
        or {frames, targets?} as `RETARGET_DUMP=stream.json cargo bench --bench retarget` writes.\n\
        Example:\n  reachgrasp retarget --robot robots/examples/ff16_hand.toml --stream examples/keypoints-ff16.json > out.json"
    )]
    Retarget(RetargetArgs),
    /// Plan a humanlike motion to a task-specific grasp offline (the computation of
    /// `POST /v1/plans`) against the service's database (`--db`, default
    /// `./data/reachgrasp.db`), which holds the trained models; the plan, its grasp and its
    /// trajectory are stored there as the service would store them. Prints the plan as JSON.
    #[command(
        after_help = "Example:\n  reachgrasp plan --request examples/plan-bottle.json > plan.json"
    )]
    Plan {
        #[command(flatten)]
        sources: Sources,
        /// JSON request file (the `POST /v1/plans` body; `execute` queues the execution in the
        /// database, run by the service once a worker connects).
        #[arg(long)]
        request: std::path::PathBuf,
    },
}

#[derive(Debug, clap::Args)]
struct RetargetArgs {
    #[command(flatten)]
    sources: Sources,
    /// A robot id (bundled or registered) or a system descriptor file.
    #[arg(long)]
    robot: String,
    /// The recorded stream (JSON).
    #[arg(long)]
    stream: std::path::PathBuf,
    /// Low-pass cutoff on the output joints, Hz (default: off).
    #[arg(long)]
    cutoff_hz: Option<f64>,
    /// Output joint speed bound, × the URDF velocity limits (default: off).
    #[arg(long)]
    speed_scale: Option<f64>,
    /// Weight of the fingertip orientation term, 0 to 1 (default 1e-4; 0: positions only).
    #[arg(long)]
    orientation_weight: Option<f64>,
    /// The keypoints are of a left hand (default: a right hand).
    #[arg(long)]
    left: bool,
}

#[derive(Debug, clap::Args)]
struct MapArgs {
    #[command(flatten)]
    sources: Sources,
    /// A robot id (bundled or registered) or a system descriptor file.
    #[arg(long)]
    robot: String,
    /// JSON file: one demonstration upload document (the `POST /v1/demonstrations` body) or an
    /// array of them (what `reachgrasp synth` prints).
    #[arg(long)]
    demo: std::path::PathBuf,
    /// Weights `position,orientation,elbow` of eq. 5 (default 1,1e-4,1e-2).
    #[arg(long, value_delimiter = ',', num_args = 3)]
    weights: Option<Vec<f64>>,
    /// Output rate, Hz, in (0, 500] (default: each demonstration's own rate).
    #[arg(long)]
    rate: Option<f64>,
    /// Uniform scale of the human data: `auto` (robot reach / human reach, the default), or a
    /// positive number.
    #[arg(long)]
    scale: Option<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Debug, clap::Args)]
struct BridgeArgs {
    #[command(flatten)]
    sources: Sources,
    #[command(flatten)]
    logging: Logging,
    /// Drive a simulated robot (integrates commands under the joint velocity and acceleration
    /// limits at the control rate).
    #[arg(long)]
    sim: bool,
    /// Robot system id (bundled in the robots folder, a descriptor file, registered in the local
    /// database, or else loaded from the service at `--url`).
    #[arg(long)]
    robot: String,
    /// The service's bridge WebSocket.
    #[arg(
        long,
        env = "REACHGRASP_BRIDGE_URL",
        default_value = "ws://127.0.0.1:8080/v1/bridges/connect"
    )]
    url: String,
    /// The service's bridge token.
    #[arg(long, env = "REACHGRASP_BRIDGE_TOKEN", hide_env_values = true)]
    token: String,
    /// Worker name (unique among connected workers; default `sim-<robot>`).
    #[arg(long)]
    name: Option<String>,
    /// Control rate (Hz).
    #[arg(long, default_value_t = 100.0)]
    rate_hz: f64,
    /// Feedback rate (Hz).
    #[arg(long, default_value_t = 50.0)]
    feedback_hz: f64,
    /// Joint acceleration limit (rad/s²; the system descriptor has none).
    #[arg(long, default_value_t = reachgrasp::bridge::sim::DEFAULT_ACCELERATION_LIMIT)]
    max_acceleration: f64,
    /// Push the simulated arm at random during motion (velocity impulses).
    #[arg(long)]
    perturb: bool,
    /// Largest displacement of a push per joint (rad).
    #[arg(long, default_value_t = 0.08)]
    perturb_magnitude: f64,
    /// Largest distance (m) a push may carry any link frame once braked; a larger push is
    /// scaled down. Applies to laws run with a scene (this worker then has the kinematics).
    #[arg(long)]
    perturb_max_displacement: Option<f64>,
    /// Seed of the kicks.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// Largest distance (rad) of the robot from a trajectory's first point it accepts.
    #[arg(long, default_value_t = 0.25)]
    start_tolerance: f64,
    /// Final error (rad) that counts as arrived.
    #[arg(long, default_value_t = 0.01)]
    goal_tolerance: f64,
    /// Initial joint positions, comma-separated in model order (default: 0, or mid-range).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    initial: Option<Vec<f64>>,
}

#[derive(Debug, clap::Args)]
struct SynthArgs {
    /// Seed of the study (anthropometry, trials, sensor noise): the same seed, the same study.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Subjects.
    #[arg(long, default_value_t = 5)]
    subjects: usize,
    /// Object positions (1 to 5).
    #[arg(long, default_value_t = 5)]
    positions: usize,
    /// Trials per subject and position.
    #[arg(long, default_value_t = 10)]
    trials: usize,
    /// Comma-separated objects: ball, bottle, kitchen_timer, pencil, sunglasses (default all).
    #[arg(long, value_delimiter = ',')]
    objects: Vec<String>,
    /// Every object at every position (default: objects counterbalanced over positions).
    #[arg(long)]
    full_factorial: bool,
    /// Leave out the sensor noise.
    #[arg(long)]
    no_noise: bool,
    /// Common resampling rate written into each document's `sync`, Hz.
    #[arg(long, default_value_t = 120.0)]
    rate_hz: f64,
    /// Print `{external_id, subject, object, summary}` per demonstration instead of the streams.
    #[arg(long)]
    summary: bool,
    /// Write each demonstration as a hand keypoint recording (`keypoints` instead of `tracker`
    /// and `glove`: the 21 MANO / MediaPipe points of the subject's hand model, with the elbow
    /// and shoulder), as a camera or headset would deliver it.
    #[arg(long, conflicts_with = "summary")]
    keypoints: bool,
}

/// A failure is one line on stderr (its causes joined by `: `), not a debug dump: the user's
/// mistakes (a bad flag, a missing file, an invalid request) read as messages and exit with
/// status 2, as clap's usage errors do; 1 is left for a failure of the program itself.
fn main() -> std::process::ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => {
            // --help and --version: clap prints them (with colour at a terminal only).
            let _ = e.print();
            return std::process::ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("reachgrasp: error: {}", usage_line(&e));
            return std::process::ExitCode::from(2);
        }
    };
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // `reachgrasp synth | head`: the reader has what it wanted; nothing went wrong.
        Err(e)
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) =>
        {
            std::process::ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("reachgrasp: error: {e:#}");
            let internal = e.chain().any(|c| {
                matches!(
                    c.downcast_ref::<reachgrasp::service::Error>(),
                    Some(reachgrasp::service::Error::Internal(_))
                )
            });
            std::process::ExitCode::from(if internal { 1 } else { 2 })
        }
    }
}

/// Clap's usage error as one line: its message, then where to read more.
fn usage_line(e: &clap::Error) -> String {
    let text = e.to_string();
    let message = text
        .lines()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("invalid arguments")
        .trim_start_matches("error: ");
    let help = if let Some(sub) = std::env::args().nth(1).filter(|a| !a.starts_with('-')) {
        format!("reachgrasp {sub} --help")
    } else {
        "reachgrasp --help".to_owned()
    };
    format!("{message} (see `{help}`)")
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        None => serve(cli.config),
        Some(command) => run_command(command),
    }
}

fn run_command(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Serve(config) => serve(*config),
        Command::Openapi => {
            println!(
                "{}",
                serde_json::to_string_pretty(&reachgrasp::api::openapi())?
            );
            Ok(())
        }
        Command::Ik {
            sources,
            robot,
            targets,
        } => ik(&sources, &robot, &targets),
        Command::Synth(args) => synth(args),
        Command::Map(args) => map(args),
        Command::Retarget(args) => retarget(args),
        Command::Plan { sources, request } => plan(sources, &request),
        Command::Bridge(args) => bridge(args),
        Command::Grasp {
            robots,
            request,
            robot,
            object,
            direction,
            kind,
            goal,
            starts,
            max_starts,
            seed,
        } => {
            let body: serde_json::Value = match request {
                Some(path) => serde_json::from_str(&std::fs::read_to_string(&path)?)?,
                None => {
                    let dirs = match direction {
                        Some(d) if d.len() != 3 => anyhow::bail!(
                            "--direction needs three numbers `x,y,z` (or `x y z`), got {}",
                            d.len()
                        ),
                        Some(d) => {
                            serde_json::json!([{ "direction": d, "kind": kind, "goal": goal }])
                        }
                        None => serde_json::json!([]),
                    };
                    serde_json::json!({
                        "robot": robot.ok_or_else(|| anyhow::anyhow!("--robot is required without --request"))?,
                        "object_id": object.ok_or_else(|| anyhow::anyhow!("--object is required without --request"))?,
                        "task_directions": dirs,
                        "starts": starts,
                        "max_starts": max_starts,
                        "seed": seed,
                    })
                }
            };
            grasp(&robots, body)
        }
    }
}

/// A use case's error as a CLI error: every offending field, else the summary.
fn failure(e: reachgrasp::service::Error) -> anyhow::Error {
    use reachgrasp::service::Error as E;
    match e {
        E::Invalid(fields) => anyhow::anyhow!(
            "{}",
            fields
                .iter()
                .map(|f| format!("{}: {}", f.field, f.message))
                .collect::<Vec<_>>()
                .join("; ")
        ),
        E::Payload(issues) => anyhow::anyhow!(
            "{}",
            issues
                .iter()
                .map(|i| format!("{:?}{}: {}", i.part, i.at, i.message))
                .collect::<Vec<_>>()
                .join("; ")
        ),
        other => anyhow::Error::new(other),
    }
}

/// A progress bar on stderr for `len` items of `what`.
fn progress_bar(len: usize, what: &str) -> anyhow::Result<indicatif::ProgressBar> {
    let bar = indicatif::ProgressBar::new(len as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{{spinner}} {what} [{{bar:40}}] {{pos}}/{{len}} ({{elapsed}}, eta {{eta}})"
        ))?
        .progress_chars("=> "),
    );
    bar.tick();
    Ok(bar)
}

fn grasp(robots: &std::path::Path, body: serde_json::Value) -> anyhow::Result<()> {
    use reachgrasp::service::grasps::{GraspIn, offline as grasp_offline};
    let out = match body {
        serde_json::Value::Array(items) => {
            let bar = progress_bar(items.len(), "grasps")?;
            let mut results = Vec::with_capacity(items.len());
            for (i, item) in items.into_iter().enumerate() {
                let body: GraspIn = reachgrasp::wire::from_value(item)
                    .map_err(|e| anyhow::anyhow!("request {i}: {e}"))?;
                let r = grasp_offline(robots, &body)
                    .map_err(|e| failure(e).context(format!("request {i}")))?;
                results.push(r);
                bar.inc(1);
            }
            bar.finish_and_clear();
            serde_json::to_string_pretty(&results)?
        }
        one => {
            let body: GraspIn = reachgrasp::wire::from_value(one).map_err(anyhow::Error::msg)?;
            serde_json::to_string_pretty(&grasp_offline(robots, &body).map_err(failure)?)?
        }
    };
    println!("{out}");
    Ok(())
}

fn plan(sources: Sources, request: &std::path::Path) -> anyhow::Result<()> {
    use anyhow::Context;
    let text = std::fs::read_to_string(request)
        .with_context(|| format!("cannot read {}", request.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not JSON", request.display()))?;
    let body: reachgrasp::service::plans::PlanIn = reachgrasp::wire::from_value(value)
        .map_err(|e| anyhow::anyhow!("{} is not a plan request: {e}", request.display()))?;
    anyhow::ensure!(
        sources.db.is_file(),
        "no database at {} (--db): start the service once so it trains the default models",
        sources.db.display()
    );
    // Offline: no listener is served and no seeding starts; the service's own code plans.
    let config = Config {
        bind: "127.0.0.1:0".parse()?,
        no_seed: true,
        db: sources.db,
        robots: sources.robots,
        ..Config::default()
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let dto = runtime.block_on(async {
        let app = App::build(config).await?;
        let planned = reachgrasp::service::plans::plan(app.state(), &body)
            .await
            .map_err(failure)?;
        reachgrasp::api::plans::plan_dto(planned).map_err(|e| anyhow::anyhow!("{e}"))
    })?;
    println!("{}", serde_json::to_string_pretty(&dto)?);
    Ok(())
}

fn synth(args: SynthArgs) -> anyhow::Result<()> {
    use reachgrasp::human::{ObjectKind, StudyConfig, generate_study_with_progress, ingest};
    use std::io::Write;
    let objects = if args.objects.is_empty() {
        ObjectKind::ALL.to_vec()
    } else {
        args.objects
            .iter()
            .map(|o| {
                serde_json::from_value(serde_json::Value::String(o.trim().to_owned()))
                    .map_err(|_| anyhow::anyhow!("unknown object `{o}`"))
            })
            .collect::<anyhow::Result<_>>()?
    };
    let cfg = StudyConfig {
        seed: args.seed,
        subjects: args.subjects,
        positions: args.positions,
        trials: args.trials,
        objects,
        full_factorial: args.full_factorial,
        noise: !args.no_noise,
        rate_hz: args.rate_hz,
    };
    let bar = progress_bar(cfg.trials().len(), "trials")?;
    let study = generate_study_with_progress(&cfg, &mut |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    if args.summary {
        let bar = progress_bar(study.len(), "ingest")?;
        let rows = study
            .iter()
            .map(|input| {
                let demo = ingest(input)?;
                bar.inc(1);
                Ok(serde_json::json!({
                    "external_id": demo.labels.external_id,
                    "subject": demo.subject.id,
                    "object": demo.object.name,
                    "position_index": demo.labels.position_index,
                    "trial": demo.labels.trial,
                    "summary": demo.summary,
                }))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        bar.finish_and_clear();
        serde_json::to_writer(&mut out, &rows)?;
    } else if args.keypoints {
        let bar = progress_bar(study.len(), "keypoints")?;
        let docs = study
            .iter()
            .map(|input| {
                let demo = ingest(input)?;
                let recording = reachgrasp::human::keypoints::recording_of(&demo)
                    .ok_or_else(|| anyhow::anyhow!("no glove angles to take keypoints from"))?;
                bar.inc(1);
                Ok(serde_json::json!({
                    "subject": input.subject,
                    "object": input.object,
                    "labels": input.labels,
                    "sync": {"rate_hz": input.sync.rate_hz, "max_gap_s": input.sync.max_gap_s},
                    "keypoints": recording,
                }))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        bar.finish_and_clear();
        serde_json::to_writer(&mut out, &docs)?;
    } else {
        serde_json::to_writer(&mut out, &study)?;
    }
    writeln!(out)?;
    out.flush()?;
    Ok(())
}

fn retarget(args: RetargetArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use reachgrasp::service::retarget::{RecordedStream, RetargetQuery, replay};
    let system = reachgrasp::store::library::resolve_for_cli(
        &args.sources.robots,
        &args.sources.db,
        &args.robot,
    )?;
    let query = RetargetQuery {
        handedness: if args.left {
            reachgrasp::human::Handedness::Left
        } else {
            reachgrasp::human::Handedness::Right
        },
        cutoff_hz: args.cutoff_hz,
        speed_scale: args.speed_scale,
        orientation_weight: args.orientation_weight,
        ..RetargetQuery::default()
    };
    let options = query.options().map_err(failure)?;
    let text = std::fs::read_to_string(&args.stream)
        .with_context(|| format!("cannot read {}", args.stream.display()))?;
    let stream: RecordedStream = serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is neither an array of frames nor {{frames, targets}}",
            args.stream.display()
        )
    })?;
    let report = replay(&args.robot, &system, &stream, options).map_err(failure)?;
    eprintln!(
        "{}: {} frames, {:.0} frames/s warm-started on one thread (first frame {:.0} us); \
         per frame p50 {:.1} us, p95 {:.1} us, p99 {:.1} us, max {:.1} us",
        report.robot,
        report.frames,
        report.frames_per_s,
        report.first_frame_us,
        report.latency_us[0],
        report.latency_us[1],
        report.latency_us[2],
        report.latency_us[3]
    );
    let [m, p, x] = report.goal_error_m;
    eprintln!(
        "fingertip error from the goals: median {:.3} mm, p95 {:.3} mm, max {:.3} mm",
        m * 1e3,
        p * 1e3,
        x * 1e3
    );
    if let Some([m, p, x]) = report.target_error_m {
        eprintln!(
            "fingertip error from the targets: median {:.3} mm, p95 {:.3} mm, max {:.3} mm",
            m * 1e3,
            p * 1e3,
            x * 1e3
        );
    }
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

fn map(args: MapArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use reachgrasp::human::{DemonstrationInput, ingest};
    use reachgrasp::service::mappings::{
        RegistrationIn, ScaleIn, WeightsIn, map_offline, parse_params,
    };
    use reachgrasp::store::mappings::DemoLabels;
    use std::io::Write;

    let weights = match args.weights.as_deref() {
        None => WeightsIn::default(),
        Some(&[p, o, e]) => WeightsIn {
            position: Some(p),
            orientation: Some(o),
            elbow: Some(e),
            ..WeightsIn::default()
        },
        Some(_) => anyhow::bail!("--weights takes three numbers: position,orientation,elbow"),
    };
    let scale = args.scale.map(|s| match s.parse::<f64>() {
        Ok(x) => ScaleIn::Factor(x),
        Err(_) => ScaleIn::Named(s),
    });
    let registration = RegistrationIn {
        scale,
        ..RegistrationIn::default()
    };
    let params = parse_params(&weights, &registration, args.rate).map_err(failure)?;
    let system = reachgrasp::store::library::resolve_for_cli(
        &args.sources.robots,
        &args.sources.db,
        &args.robot,
    )?;
    let text = std::fs::read_to_string(&args.demo)
        .with_context(|| format!("cannot read {}", args.demo.display()))?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not JSON", args.demo.display()))?;
    let docs = match value {
        serde_json::Value::Array(items) => items,
        one => vec![one],
    };
    anyhow::ensure!(
        !docs.is_empty(),
        "{} holds no demonstration",
        args.demo.display()
    );
    let mut demos = Vec::with_capacity(docs.len());
    for (i, doc) in docs.into_iter().enumerate() {
        // The upload document of `POST /v1/demonstrations` is the ingest input itself.
        let input: DemonstrationInput = reachgrasp::wire::from_value(doc)
            .map_err(|e| anyhow::anyhow!("demonstration {i} is not an upload document: {e}"))?;
        let demo = ingest(&input).with_context(|| format!("demonstration {i}"))?;
        let labels = DemoLabels {
            demonstration_id: demo
                .labels
                .external_id
                .clone()
                .unwrap_or_else(|| i.to_string()),
            subject_id: demo.subject.id.clone(),
            object_name: demo.object.name.clone(),
            task: demo.labels.task.clone(),
            position_index: demo.labels.position_index,
            trial: demo.labels.trial,
        };
        let object = reachgrasp::mapping::human_object(&demo.object);
        demos.push((labels, demo.frames, Some(object)));
    }
    let bar = progress_bar(demos.len(), "mapping demonstrations")?;
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let result = map_offline(&args.robot, &system, demos, &params, threads, &|done, _| {
        bar.set_position(done as u64)
    });
    bar.finish_and_clear();
    let result = result.map_err(failure)?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    serde_json::to_writer(&mut out, &result)?;
    writeln!(out)?;
    out.flush()?;
    Ok(())
}

fn bridge(args: BridgeArgs) -> anyhow::Result<()> {
    use reachgrasp::bridge::sim::{Perturbation, RunOptions};
    use reachgrasp::bridge::worker::{WorkerOptions, run_worker};
    init_tracing(&args.logging.log, args.logging.log_json)?;
    anyhow::ensure!(
        args.sim,
        "only the simulated robot driver is built in: pass --sim"
    );
    anyhow::ensure!(
        args.rate_hz > 0.0 && args.rate_hz <= 2000.0 && args.feedback_hz > 0.0,
        "--rate-hz must be in (0, 2000] and --feedback-hz positive"
    );
    anyhow::ensure!(
        args.max_acceleration > 0.0 && args.max_acceleration.is_finite(),
        "--max-acceleration must be positive"
    );
    anyhow::ensure!(
        args.perturb_max_displacement
            .is_none_or(|x| x > 0.0 && x.is_finite()),
        "--perturb-max-displacement must be positive"
    );
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    // A worker on another machine has neither the descriptor file nor the service's database:
    // a robot that is not found locally is loaded from the service it connects to.
    let system = match reachgrasp::store::library::resolve_for_cli(
        &args.sources.robots,
        &args.sources.db,
        &args.robot,
    ) {
        Ok(s) => s,
        Err(local) => runtime
            .block_on(reachgrasp::bridge::worker::fetch_system(
                &args.url,
                &args.robot,
            ))
            .map_err(|e| anyhow::anyhow!("{local}; nor from the service: {e:#}"))?,
    };
    let name = args.name.unwrap_or_else(|| format!("sim-{}", args.robot));
    let mut opts = WorkerOptions::for_system(
        args.url,
        args.token,
        name,
        args.robot,
        &system,
        args.max_acceleration,
    );
    if let Some(q) = args.initial {
        anyhow::ensure!(
            q.len() == opts.joint_names.len(),
            "--initial needs {} values ({:?})",
            opts.joint_names.len(),
            opts.joint_names
        );
        opts.initial = Some(q);
    }
    opts.rate_hz = args.rate_hz;
    opts.feedback_hz = args.feedback_hz.min(args.rate_hz);
    opts.run = RunOptions {
        start_tolerance: args.start_tolerance,
        goal_tolerance: args.goal_tolerance,
        ..RunOptions::default()
    };
    opts.perturb = args.perturb.then_some(Perturbation {
        magnitude: args.perturb_magnitude,
        seed: args.seed,
        max_displacement: args.perturb_max_displacement,
        ..Perturbation::default()
    });
    runtime.block_on(async { run_worker(opts, None, shutdown_signal()).await })?;
    Ok(())
}

fn serve(config: Config) -> anyhow::Result<()> {
    init_tracing(&config.log, config.log_json)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let app = App::build(config).await?;
        app.run_until(shutdown_signal()).await
    })
}

fn ik(sources: &Sources, robot: &str, targets: &std::path::Path) -> anyhow::Result<()> {
    use anyhow::Context;
    use reachgrasp::service::robots;
    let system = reachgrasp::store::library::resolve_for_cli(&sources.robots, &sources.db, robot)?;
    let text = std::fs::read_to_string(targets)
        .with_context(|| format!("cannot read {}", targets.display()))?;
    let file: robots::IkBatchFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a list of IK targets", targets.display()))?;
    let report = robots::ik_batch(robot, &system, file)
        .map_err(|e| anyhow::anyhow!("invalid target: {}", failure(e)))?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
