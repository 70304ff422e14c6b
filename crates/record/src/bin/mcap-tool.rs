//! `mcap-tool`: record an in-process run to MCAP, inspect, verify, export, plot and recover
//! recordings. The `pi2cma` CLI exposes the same library functions as `pi2cma analyze` and
//! `pi2cma recover`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use record::analyze::{self, AnalyzeArgs};
use record::recover::{self, RecoverArgs};
use record::{read_recording_slim, McapRecorder};
use session::InProcess;

#[derive(Parser)]
#[command(
    name = "mcap-tool",
    about = "pi2cma MCAP recordings: record, analyze, recover"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a config in-process and record it (Ctrl-C stops after the current update and still
    /// leaves a complete file).
    Record {
        /// Run config (TOML); the built-in default (A1) without it.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Session seed; the config's `run.seed` without it.
        #[arg(long, allow_negative_numbers = true)]
        seed: Option<u64>,
        /// Override `run.updates`.
        #[arg(long, allow_negative_numbers = true)]
        updates: Option<u64>,
        /// Override the task's `rollout_delay_ms` (via-point task only).
        #[arg(long, allow_negative_numbers = true)]
        rollout_delay_ms: Option<f64>,
        /// Where to write the MCAP.
        #[arg(long, short)]
        out: PathBuf,
        /// Print `recorded update U` on stdout once update U is flushed to the file.
        #[arg(long)]
        progress: bool,
    },
    /// Summary, CSV, figures and (with several files) experiment tables.
    Analyze(AnalyzeArgs),
    /// Info summary of each file.
    Info {
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Recompute every update from its recorded inputs; exits 1 on any mismatch.
    Verify {
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// CSV per topic into DIR.
    Csv {
        file: PathBuf,
        #[arg(long, short)]
        out: PathBuf,
    },
    /// SVG figures into DIR.
    Plot {
        file: PathBuf,
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Mean curves and re-convergence table over the sessions of an experiment (the files of
    /// one run, resumed or split into parts, are joined into one session, as by `analyze`).
    Experiment {
        #[arg(required = true)]
        files: Vec<PathBuf>,
        #[arg(long, short)]
        out: PathBuf,
        #[arg(long, default_value_t = 0.05, value_parser = analyze::parse_tolerance, allow_negative_numbers = true)]
        tolerance: f64,
    },
    /// Rewrite a recording whose writer was killed into a complete, indexed file.
    Recover(RecoverArgs),
}

fn main() -> std::process::ExitCode {
    record::fail_writes_past_file_size_limit();
    // Errors are for users: the chain of causes, without a backtrace (as `pi2cma` prints them).
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Record {
            config,
            seed,
            updates,
            rollout_delay_ms,
            out,
            progress,
        } => record_run(
            config.as_deref(),
            seed,
            updates,
            rollout_delay_ms,
            &out,
            progress,
        ),
        Command::Analyze(args) => {
            print!("{}", analyze::run(&args, "mcap-tool")?);
            Ok(())
        }
        Command::Info { files } => {
            for f in &files {
                print!(
                    "{}",
                    analyze::info_for(&read_recording_slim(f)?, "mcap-tool")
                );
            }
            Ok(())
        }
        Command::Verify { files } => {
            let mut bad = 0;
            for f in &files {
                let (_, r) = record::recompute::read_and_verify(f)?;
                println!(
                    "{}: {} updates recomputed, {} mismatches {:?}",
                    f.display(),
                    r.updates,
                    r.mismatches.len(),
                    r.mismatches
                );
                bad += r.mismatches.len();
            }
            if bad > 0 {
                bail!("{bad} updates differ from their recomputation");
            }
            Ok(())
        }
        Command::Csv { file, out } => {
            for p in analyze::export_csv(&read_recording_slim(&file)?, &out)? {
                println!("wrote {}", p.display());
            }
            Ok(())
        }
        Command::Plot { file, out } => {
            let figures = analyze::plot(&read_recording_slim(&file)?, &out)?;
            if figures.is_empty() {
                println!("{}: {}", file.display(), analyze::NOTHING_TO_PLOT);
            }
            for p in figures {
                println!("wrote {}", p.display());
            }
            Ok(())
        }
        Command::Experiment {
            files,
            out,
            tolerance,
        } => {
            let recs = files
                .iter()
                .map(|f| read_recording_slim(f))
                .collect::<Result<Vec<_>, _>>()?;
            // The parts of a split recording or a resumed run's files, taken as sessions of
            // their own, gave a mean curve over 0 common updates (NaN) and segments at each
            // part's first update.
            let mut notes = String::new();
            let recs = analyze::join_runs(recs, &mut notes);
            print!("{notes}");
            let r = analyze::experiment(&recs, Some(&out), tolerance, true, true)?;
            print!("{}", r.table);
            for p in &r.files {
                println!("wrote {}", p.display());
            }
            Ok(())
        }
        Command::Recover(args) => {
            let r = recover::run(&args)?;
            println!("{}", r.describe());
            Ok(())
        }
    }
}

fn record_run(
    config: Option<&Path>,
    seed: Option<u64>,
    updates: Option<u64>,
    delay: Option<f64>,
    out: &Path,
    progress: bool,
) -> Result<()> {
    let (mut cfg, text) =
        record::resume::run_config(config, None, &[("updates", updates), ("seed", seed)])?;
    // An override the text cannot take: record the rendered config then.
    let mut text = Some(text);
    if let Some(d) = delay {
        match &mut cfg.task {
            session::TaskSection::ViaPoint(v) => v.rollout_delay_ms = d,
            _ => bail!("--rollout-delay-ms: only for the via-point task"),
        }
        text = None;
    }
    cfg.validate()
        .map_err(|e| e.of_option("task.via-point.rollout_delay_ms", "--rollout-delay-ms"))?;
    let seed = cfg.run.seed;
    // Before the file is created: a config that cannot run here (an external task) must not
    // cost the recording that `out` may hold.
    let mut exec = InProcess::new(&cfg, seed)?;
    record::refuse_overwrite(out, "--out")?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    // With progress, the writer prints `recorded update U` once U is flushed to the file.
    let mut recorder = McapRecorder::create_with_progress(out, progress)?;
    if let Some(t) = text {
        recorder = recorder.with_config_text(t);
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        signals::deliver(&signals::Signal::STOP, move |_| {
            stop.store(true, Ordering::SeqCst)
        })
        .context("installing the SIGINT/SIGTERM/SIGHUP handlers")?;
    }
    // A failed recording stops the run too: it would go on unrecorded to its end.
    let failed = recorder.failure_flag();
    let result = exec.run(&mut recorder, &|| {
        stop.load(Ordering::SeqCst) || failed.load(Ordering::SeqCst)
    });
    if let Err(e) = &result {
        recorder.log_event(record::Event::Crash, &format!("run failed: {e}"));
    }
    let n = recorder
        .finish()
        .context("the run stopped: its recording failed")?;
    result?;
    // A split recording's command names every part: given the first alone, `analyze` reads
    // only the updates of that part.
    eprintln!(
        "recorded {n} updates{} to {}\nanalyse with: {} --out {}",
        if stop.load(Ordering::SeqCst) {
            " (interrupted)"
        } else {
            ""
        },
        record::describe_parts(out),
        record::analyze_command("mcap-tool", out, &[]),
        out.with_extension("analysis").display()
    );
    if stop.load(Ordering::SeqCst) {
        std::process::exit(130);
    }
    Ok(())
}
