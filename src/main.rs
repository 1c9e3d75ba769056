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
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command.unwrap_or(Command::Serve) {
        Command::Serve => serve(cli.config),
        Command::Openapi => {
            println!("{}", reachgrasp::api::openapi().to_pretty_json()?);
            Ok(())
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
