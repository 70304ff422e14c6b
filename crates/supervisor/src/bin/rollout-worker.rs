//! A pipeline rollout worker (see `pipeline::worker`); started by the supervisor.
use clap::Parser;

/// Executes rollouts from its inbox and writes costs straight into shared memory.
#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    worker: pipeline::worker::WorkerArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    pipeline::run_main("rollout-worker", || {
        Ok(pipeline::worker::main(&cli.worker)?)
    })
}
