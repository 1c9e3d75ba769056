//! The `reachgrasp` binary: `serve` (the default) runs the HTTP service; `openapi` prints the
//! OpenAPI document.

use clap::{Parser, Subcommand};
use reachgrasp::app::{App, init_tracing, shutdown_signal};
use reachgrasp::config::Config;

#[derive(Debug, Parser)]
#[command(
    name = "reachgrasp",
    version,
    about = "Humanlike reach-and-grasp planning service"
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
    Serve,
    /// Print the OpenAPI 3.1 document as JSON on stdout.
    Openapi,
    /// Compute a task-specific grasp offline (same body and result as `POST /v1/grasps`; a
    /// seeded object is named by `object_id`, e.g. `ball`). Prints the result as JSON.
    Grasp {
        /// JSON request file (the `POST /v1/grasps` body); the flags below build one instead.
        #[arg(long)]
        request: Option<std::path::PathBuf>,
        /// Arm-hand system, e.g. `wam_ihy`.
        #[arg(long)]
        robot: Option<String>,
        /// Seeded object name (`ball`, `bottle`, `kitchen_timer`, `pencil`, `sunglasses`).
        #[arg(long)]
        object: Option<String>,
        /// Task direction `x,y,z` (world frame).
        #[arg(
            long,
            value_delimiter = ',',
            num_args = 3,
            allow_negative_numbers = true
        )]
        direction: Option<Vec<f64>>,
        /// `force` or `velocity` for --direction.
        #[arg(long, default_value = "velocity")]
        kind: String,
        /// `maximize` or `minimize` for --direction.
        #[arg(long, default_value = "maximize")]
        goal: String,
        /// Starts of the multi-start search.
        #[arg(long)]
        starts: Option<usize>,
        /// Seed.
        #[arg(long)]
        seed: Option<u64>,
    },
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command.unwrap_or(Command::Serve) {
        Command::Serve => serve(cli.config),
        Command::Openapi => {
            println!("{}", reachgrasp::api::openapi().to_pretty_json()?);
            Ok(())
        }
        Command::Grasp {
            request,
            robot,
            object,
            direction,
            kind,
            goal,
            starts,
            seed,
        } => {
            let body: serde_json::Value = match request {
                Some(path) => serde_json::from_str(&std::fs::read_to_string(&path)?)?,
                None => {
                    let dirs = match direction {
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
                        "seed": seed,
                    })
                }
            };
            let body: reachgrasp::api::grasps::GraspIn = serde_json::from_value(body)?;
            match reachgrasp::api::grasps::grasp_offline(&cli.config.robots, &body) {
                Ok(r) => {
                    println!("{}", serde_json::to_string_pretty(&r)?);
                    Ok(())
                }
                Err(e) => {
                    let fields: Vec<String> = e
                        .errors()
                        .iter()
                        .map(|f| format!("{}: {}", f.path, f.message))
                        .collect();
                    anyhow::bail!("{} {}", e.detail(), fields.join("; "))
                }
            }
        }
    }
}

fn serve(config: Config) -> anyhow::Result<()> {
    init_tracing(&config)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let app = App::build(config).await?;
        app.run_until(shutdown_signal()).await
    })
}
