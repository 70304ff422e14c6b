//! `supervisor`: runs a pi2cma pipeline (updater, sampler, rollout workers over iceoryx2) and
//! talks to a running one.
use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(about = "Runs PI²-CMA as a multiprocess pipeline over iceoryx2 shared memory")]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Starts a run and supervises it until it ends (without CONFIG: the built-in default,
    /// PI²-CMA on the via-point task with 3 workers).
    Run(#[command(flatten)] supervisor::RunOptions),
    /// Shows workers, update rate, current cost and λ of a running run.
    Status {
        /// The run id (needed only when several runs are active).
        #[arg(long)]
        run: Option<String>,
    },
    /// Changes the number of rollout workers of a running run, without a restart.
    Scale {
        // `-2` is a bad value, as for `run --workers`.
        #[arg(long, allow_negative_numbers = true)]
        workers: usize,
        #[arg(long)]
        run: Option<String>,
    },
    /// Sets a task setting of a running run from its next update on (e.g. `set viapoint 0.1`).
    Set {
        #[arg(value_parser = setting_name)]
        name: String,
        // Negative values are common (T-ball's tee_y = -0.53); without this clap took `-0.5`
        // for an option and told the user to write `-- -0.5`.
        #[arg(allow_negative_numbers = true, value_parser = setting_value)]
        value: f64,
        #[arg(long)]
        run: Option<String>,
    },
    /// Starts a running run's recorder again after it died and was not restarted (once a full
    /// disk has room again): the recording goes on in a new part.
    Record {
        #[arg(long)]
        run: Option<String>,
    },
    /// Stops a running run (exit code 0, with its summary).
    Stop {
        /// Let the update under way finish first (every one of its rollouts; none is thrown
        /// away), then stop: `supervisor run --resume RECORDING` goes on with the next. Without
        /// it, the rollouts of the unfinished update are run again when resumed. A plain `stop`
        /// afterwards stops at once.
        #[arg(long)]
        after_update: bool,
        #[arg(long)]
        run: Option<String>,
    },
    /// The updater process (what the `updater` binary runs).
    #[command(hide = true)]
    Updater {
        #[command(flatten)]
        args: pipeline::updater::UpdaterArgs,
    },
    /// The sampler process (what the `sampler` binary runs).
    #[command(hide = true)]
    Sampler {
        #[command(flatten)]
        process: pipeline::ProcessArgs,
    },
    /// The MCAP recorder (what the `recorder` binary runs).
    #[command(hide = true)]
    Recorder {
        #[command(flatten)]
        args: record::pipeline_recorder::RecorderArgs,
    },
    /// A rollout worker (what the `rollout-worker` binary runs).
    #[command(hide = true, name = "rollout-worker")]
    RolloutWorker {
        #[command(flatten)]
        worker: pipeline::worker::WorkerArgs,
    },
}

/// A setting's name as `set` sends it: one word of the control line.
fn setting_name(s: &str) -> Result<String, String> {
    if s.is_empty() || s.chars().any(char::is_whitespace) {
        return Err(format!(
            "`{s}` is no setting's name: names are single words (`supervisor status` lists the \
             run's settings)"
        ));
    }
    Ok(s.to_string())
}

/// A setting's value as typed, refused here if it is not a finite number: `1e400` was sent as
/// `inf` and refused as `viapoint = inf: must be finite`, a value the user never typed.
fn setting_value(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!(
            "`{s}` is not a finite number (it reads as {v}); a setting's value must be finite"
        ))
    }
}

fn main() -> ExitCode {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let cli = Cli::parse();
    // The supervisor recovers a dead recorder's parts; the recorder writes the recording.
    if matches!(cli.command, Cmd::Run(_) | Cmd::Recorder { .. }) {
        record::fail_writes_past_file_size_limit();
    }
    let remote = |run: Option<String>, line: String| match supervisor::client(run.as_deref(), &line)
    {
        Ok(text) => {
            // Replies end with a newline or not (`set`, `stop`); a shell prompt must not follow
            // on the same line.
            if text.is_empty() || text.ends_with('\n') {
                print!("{text}");
            } else {
                println!("{text}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    };
    match cli.command {
        Cmd::Run(opts) => match supervisor::run(&opts) {
            Ok(code) => ExitCode::from(code),
            Err(e) => {
                eprintln!("[supervisor] error: {e:#}");
                if let Some(note) = supervisor::file_size_limit_note(&e) {
                    eprintln!("[supervisor] note: {note}");
                }
                ExitCode::FAILURE
            }
        },
        Cmd::Status { run } => remote(run, "status".into()),
        Cmd::Scale { workers, run } => remote(run, format!("scale {workers}")),
        Cmd::Set { name, value, run } => remote(run, format!("set {name} {value:?}")),
        Cmd::Stop { run, after_update } => remote(
            run,
            if after_update {
                "stop after-update"
            } else {
                "stop"
            }
            .into(),
        ),
        Cmd::Record { run } => remote(run, "record".into()),
        Cmd::Updater { args } => pipeline::run_main("updater", || pipeline::updater::main(&args)),
        Cmd::Sampler { process } => {
            pipeline::run_main("sampler", || pipeline::sampler::main(&process))
        }
        Cmd::Recorder { args } => pipeline::run_main("recorder", || {
            record::pipeline_recorder::run_recorder(&args)
        }),
        Cmd::RolloutWorker { worker } => {
            pipeline::run_main("rollout-worker", || Ok(pipeline::worker::main(&worker)?))
        }
    }
}
