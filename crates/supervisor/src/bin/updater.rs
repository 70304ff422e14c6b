//! The pipeline's updater process (see `pipeline::updater`); started by the supervisor.
use clap::Parser;

/// Collects each update's cost trajectories, tells the core, publishes the next distribution.
#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: pipeline::updater::UpdaterArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    pipeline::run_main("updater", || pipeline::updater::main(&cli.args))
}
