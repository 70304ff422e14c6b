//! The pipeline's sampler process (see `pipeline::sampler`); started by the supervisor.
use clap::Parser;

/// Draws each update's parameter vectors and hands them out to rollout workers.
#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    process: pipeline::ProcessArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    pipeline::run_main("sampler", || pipeline::sampler::main(&cli.process))
}
