//! The pipeline's recorder process; the code is [`record::pipeline_recorder`] (the `supervisor`
//! binary hosts the same role). It is built with the supervisor's other process binaries, so
//! that the supervisor never starts a stale one beside fresh ones.
use clap::Parser;

/// Records the run's updates, rollouts, task changes and health events to MCAP.
#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: record::pipeline_recorder::RecorderArgs,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    record::fail_writes_past_file_size_limit();
    pipeline::run_main("recorder", || {
        record::pipeline_recorder::run_recorder(&cli.args)
    })
}
