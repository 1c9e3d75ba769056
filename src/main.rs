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
    /// Solve a batch of pose IK targets and print solutions and statistics as JSON.
    Ik {
        /// A robot id (bundled or registered) or a system descriptor file.
        #[arg(long)]
        robot: String,
        /// JSON file: a list of IK requests (the body of POST /v1/robots/{id}/ik), or
        /// `{"targets": [...]}`.
        #[arg(long)]
        targets: std::path::PathBuf,
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
        Command::Ik { robot, targets } => ik(&cli.config, &robot, &targets),
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

fn ik(config: &Config, robot: &str, targets: &std::path::Path) -> anyhow::Result<()> {
    use anyhow::Context;
    use reachgrasp::api::robots;
    let system = robots::resolve_robot_for_cli(config, robot)?;
    let text = std::fs::read_to_string(targets)
        .with_context(|| format!("cannot read {}", targets.display()))?;
    let file: robots::IkBatchFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a list of IK targets", targets.display()))?;
    let report = robots::ik_batch(robot, &system, file)
        .map_err(|e| anyhow::anyhow!("invalid target: {}", e.detail()))?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
