//! `pi2cma`: run a learning session in-process, run the paper's experiments over several
//! configs and seeds, and benchmark the update. The multiprocess pipeline has its own
//! `supervisor` binary; this command never starts processes.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// `println!` that ignores a closed stdout: `pi2cma run | head` must not abandon the run (and
/// leave its recording unfinished) when `head` exits.
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout().lock(), $($t)*);
    }};
}

/// Set by SIGINT/SIGTERM during `run`: the session stops after the current update, the
/// recording is finished, and the process exits with 130 (a second signal: at once).
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use pi2cma_cli::{bench, experiment, figures};
use session::{Observer, RunConfig, UpdateRecord, WeightingName};

#[derive(Parser)]
#[command(name = "pi2cma", version, about = "PI²-CMA policy search on DMPs")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum WeightingArg {
    Episodic,
    PerTimeStep,
    PerTimeStepBasisActivation,
}

#[derive(Subcommand)]
enum Command {
    /// Run one learning session in-process (built-in default: PI²-CMA on the via-point, A1).
    Run {
        /// Run config (TOML); the built-in default if omitted.
        config: Option<PathBuf>,
        /// Override run.seed.
        #[arg(long, allow_negative_numbers = true)]
        seed: Option<u64>,
        /// Override run.updates (e.g. to go on with `--resume`); the recording's config shows it.
        #[arg(long, allow_negative_numbers = true)]
        updates: Option<u64>,
        /// Directory for run.mcap, updates.csv, mean_curves.csv and fig2.svg; one that holds a
        /// recording is refused. Default: runs/latest, whose results (and analysis/) each run
        /// without --out replaces.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print nothing per update (a rollout run again for non-finite costs is still printed).
        #[arg(long)]
        quiet: bool,
        /// Do not write the MCAP recording (OUT/run.mcap).
        #[arg(long)]
        no_record: bool,
        /// Go on from the last update recorded in this MCAP file (a stopped, crashed or
        /// finished run whose run.updates was raised); without CONFIG, with the config it
        /// recorded. The result is bit for bit what the run would have given uninterrupted.
        #[arg(long, value_name = "FILE")]
        resume: Option<PathBuf>,
    },
    /// Run S sessions (seeds seed, seed+1, …) of each config; write CSVs, figures and the
    /// re-convergence table.
    Experiment {
        /// Run configs (TOML).
        #[arg(required = true)]
        configs: Vec<PathBuf>,
        #[arg(long, default_value_t = 10, allow_negative_numbers = true)]
        sessions: usize,
        /// Override the weighting mode of every config.
        #[arg(long, value_enum)]
        weighting: Option<WeightingArg>,
        /// Default: runs/experiment, which each experiment without --out replaces; with --out,
        /// recordings there are refused.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Also record every session to `OUT/mcap/<run>-seed<seed>.mcap`.
        #[arg(long)]
        record: bool,
    },
    /// Summarise, export (CSV) and plot MCAP recordings; several files: the experiment's mean
    /// curves and re-convergence table.
    Analyze(record::analyze::AnalyzeArgs),
    /// Rewrite a recording whose writer was killed into a complete, indexed file.
    Recover(record::recover::RecoverArgs),
    /// Check configs without running them.
    Check {
        #[arg(required = true)]
        configs: Vec<PathBuf>,
    },
    /// Print the median time of one update (via-point and a large policy, both modes).
    Bench {
        /// Fewer repetitions of the slow large-policy case.
        #[arg(long)]
        quick: bool,
        /// Only the cases whose name contains this (via-point/per-time-step, via-point/episodic,
        /// large/per-time-step, large/per-time-step/2-threads, large/per-time-step/late,
        /// large/episodic).
        #[arg(long, default_value = "")]
        only: String,
    },
    /// Print the built-in default config.
    DefaultConfig,
}

struct Progress {
    total: Option<u64>,
    /// `--quiet`: no task change and no line per update; a rerun, a warning, is printed still.
    quiet: bool,
}

impl Observer for Progress {
    fn on_task_change(&mut self, update: u64, change: &tasks::TaskChange) {
        if self.quiet {
            return;
        }
        // The progress lines count updates from 1; tables and configs index them from 0.
        say!(
            "task change {} = {} from update {}/{} on (index {update})",
            change.name,
            tasks::value_text(change.value),
            update + 1,
            self.total.map_or("∞".to_string(), |t| t.to_string())
        );
    }
    fn on_rerun(&mut self, rerun: &session::Rerun<'_>) {
        say!("{}", rerun.message());
    }
    fn on_update(&mut self, r: &UpdateRecord<'_>) {
        if self.quiet {
            return;
        }
        let s = r.summary;
        let total = self.total.map_or("∞".to_string(), |t| t.to_string());
        say!(
            "update {:>3}/{total}: eval cost {:>10.4}  exploration {:>10.4} ± {:<10.4} λ sampled {:>10.4}",
            s.update + 1,
            s.eval_cost,
            s.exploration_cost_mean,
            s.exploration_cost_std,
            s.lambda
        );
    }
}

fn load(path: &Path) -> Result<RunConfig> {
    Ok(RunConfig::load(path)?)
}

fn apply_weighting(cfg: &mut RunConfig, w: Option<WeightingArg>) -> Result<()> {
    let Some(w) = w else { return Ok(()) };
    use session::WeightingName as W;
    let (weighting, temporal) = match w {
        WeightingArg::Episodic => (W::Episodic, None),
        WeightingArg::PerTimeStep => (W::PerTimeStep, None),
        WeightingArg::PerTimeStepBasisActivation => {
            (W::PerTimeStep, Some(session::TemporalName::BasisActivation))
        }
    };
    cfg.optimizer.weighting = weighting;
    cfg.optimizer.temporal_averaging = temporal;
    // What is wrong was set by the option, not by the file the error names.
    cfg.validate().with_context(|| {
        let name = w.to_possible_value().map(|v| v.get_name().to_string());
        format!("--weighting {}", name.unwrap_or_default())
    })?;
    Ok(())
}

fn write_outputs(out: &Path, results: &[experiment::ConfigResult]) -> Result<String> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    experiment::write_updates_csv(&out.join("updates.csv"), results)
        .with_context(|| format!("writing {}", out.join("updates.csv").display()))?;
    experiment::write_mean_csv(&out.join("mean_curves.csv"), results)
        .with_context(|| format!("writing {}", out.join("mean_curves.csv").display()))?;
    figures::fig2(&out.join("fig2.svg"), results)?;
    let table = experiment::summary_table(results) + &experiment::summary_notes(results);
    std::fs::write(out.join("summary.md"), &table)
        .with_context(|| format!("writing {}", out.join("summary.md").display()))?;
    Ok(table)
}

fn main() -> std::process::ExitCode {
    record::fail_writes_past_file_size_limit();
    // Errors are for users: the chain of causes, without a backtrace.
    match run(Cli::parse()) {
        Ok(()) if INTERRUPTED.load(Ordering::SeqCst) => std::process::ExitCode::from(130),
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// `run --resume`: goes on from where a recording ended, in-process. Its learning curve starts
/// mid-run, so it writes the recording and final state, not the from-update-0 tables and figures;
/// analysing both recordings together (as it prints) gives those for the whole run.
fn run_resumed(
    cfg: &RunConfig,
    text: String,
    point: record::resume::ResumePoint,
    out: &Path,
    quiet: bool,
    no_record: bool,
) -> Result<()> {
    let mcap = out.join("run.mcap");
    let start = point.start;
    say!(
        "pi2cma: run {} ({}), seed {}, resumed at update {} of {} from {}, in-process",
        cfg.run.name,
        cfg.origin.display(),
        cfg.run.seed,
        start.update,
        cfg.run.updates.unwrap_or(0),
        start.origin
    );
    if let Some(why) = &point.truncated {
        say!("(the recording was cut off: {why}; resuming after its last complete update)");
    }
    let recorder = (!no_record)
        .then(|| recorder(&mcap, text).map(|r| r.resuming(&start)))
        .transpose()?;
    let origin = start.origin.clone();
    let origin_update = start.update;
    let mut exec = session::InProcess::resume(cfg, cfg.run.seed, start)?;
    run_observed(cfg, recorder, quiet, |observer, stop| {
        exec.run(observer, stop)
    })?;
    say_if_interrupted(
        exec.optimizer().update_index() - origin_update,
        (!no_record).then_some(mcap.as_path()),
    );
    let d = exec.optimizer().distribution();
    say!("final mean θ = {}", session::mean_text(d.mean.as_slice()));
    say!("final λ = {:.4}", exec.optimizer().lambda());
    if !no_record {
        print_recording(&mcap, out, Some(&origin));
    }
    Ok(())
}

/// Stops `run` after the current update on SIGINT, SIGTERM or SIGHUP (unless started with it
/// ignored: `nohup pi2cma experiment …` survives the terminal), as `mcap-tool record`
/// and the supervisor do: the recording is finished and the results so far are written. A
/// second signal stops at once, as the supervisor's does: an update of slow rollouts (a robot)
/// can take minutes, and a user pressing Ctrl-C again means it.
fn stop_on_signal() -> Result<()> {
    signals::deliver(&signals::Signal::STOP, |signal| {
        use std::io::Write as _;
        // stderr may be closed.
        let mut err = std::io::stderr();
        if INTERRUPTED.swap(true, Ordering::SeqCst) {
            let _ = writeln!(
                err,
                "{signal} (a second signal): stopping at once, within an update (exit code \
                 130); results not yet written stay unwritten or partly written, and a \
                 recording being written keeps the updates flushed before it (`pi2cma recover \
                 FILE` completes it)"
            );
            std::process::exit(130);
        }
        let _ = writeln!(
            err,
            "{signal} received: stopping after the current update (again to stop at once)"
        );
    })
    .context("cannot install the SIGINT/SIGTERM/SIGHUP handlers")?;
    Ok(())
}

fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

/// After Ctrl-C: how many updates ran, and with a recording, the command that goes on from it
/// (the README's "a stopped run goes on with --resume" was said nowhere the user looks then).
/// Into another directory: recording over the file resumed from is refused.
fn say_if_interrupted(updates: u64, recording: Option<&Path>) {
    if interrupted() {
        let recording = recording.map_or(String::new(), |mcap| {
            format!(
                "; the recording is complete; go on with: {} run --resume {} --out OTHER_DIR",
                this_program(),
                mcap.display()
            )
        });
        say!("interrupted after {updates} updates (exit code 130){recording}");
    }
}

/// Where `run` or `experiment` writes, and whether recordings there may be replaced: not those
/// in a directory given by `--out`; those in the default directory, whose results the next run
/// without `--out` replaces.
fn output_dir(out: Option<PathBuf>, default: &str) -> (PathBuf, bool) {
    match out {
        Some(dir) => (dir, false),
        None => (PathBuf::from(default), true),
    }
}

/// Refuses `out`, a directory given by `--out`, when it holds recordings: `run`'s `run.mcap` (or
/// parts of it) or an experiment's `mcap/*.mcap`. The tables and figures `command` writes at the
/// top of the directory (summary.md, mean_curves.csv, fig2.svg, updates.csv), recorded or not,
/// would replace those beside the recordings, which they would no longer describe: an
/// experiment into an earlier experiment's directory, a `--no-record` run into a run's, and
/// each into the other's did so.
fn refuse_results_beside_recordings(out: &Path, command: &str) -> Result<()> {
    record::refuse_overwrite(&out.join("run.mcap"), "--out").with_context(|| {
        format!(
            "{}: holds another run's recording, whose results (updates.csv, mean_curves.csv, \
             fig2.svg, summary.md) this {command} would replace, recorded or not: give another \
             --out",
            out.display()
        )
    })?;
    let dir = out.join("mcap");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Ok(());
    };
    let mut found: Vec<String> = entries
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".mcap"))
        .collect();
    found.sort();
    if let Some(first) = found.first() {
        bail!(
            "{}: holds an earlier experiment's recordings ({}{}), which this {command}'s \
             results (summary.md, mean_curves.csv, fig2.svg) would no longer describe: give \
             another --out",
            out.display(),
            dir.join(first).display(),
            match found.len() {
                1 => String::new(),
                n => format!(" and {} more", n - 1),
            }
        );
    }
    Ok(())
}

/// Creates `out`, the directory a run or experiment writes its results to, before anything runs:
/// an experiment given `--out` naming a file ran every session and only then failed, with
/// `creating afile: File exists (os error 17)`, its results lost.
fn create_out_dir(out: &Path, given: bool) -> Result<()> {
    let what = if given {
        "--out"
    } else {
        "the default results directory"
    };
    if std::fs::symlink_metadata(out).is_ok() && !out.is_dir() {
        bail!(
            "{}: is a file, not a directory ({what}): give a directory (one that does not exist \
             is created)",
            out.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {} ({what})", out.display()))
}

/// The subdirectories of a default output directory that the previous run's commands wrote:
/// the printed `analyze` command's `analysis/`, an experiment's recordings in `mcap/`. A run
/// writes its own files over the previous ones, but these it does not: a new run's results sat
/// beside the previous run's analysis (CSV files and figures of another seed).
const REPLACED_SUBDIRS: [&str; 2] = ["analysis", "mcap"];

/// The files a run or experiment writes at the top of its output directory, besides `run`'s
/// `run.mcap` (and its parts). In the default
/// directory the next run removes the previous run's before it starts: a resumed run (which
/// writes its recording only), a `--no-record` run, a run that failed and an experiment stopped
/// in its first session each left the previous run's tables, figures or recording beside their
/// own, as if they were theirs.
const REPLACED_FILES: [&str; 4] = ["updates.csv", "mean_curves.csv", "fig2.svg", "summary.md"];

/// What those subdirectories hold when only pi2cma wrote them.
const OUTPUT_EXTENSIONS: [&str; 5] = ["csv", "svg", "md", "mcap", "png"];

/// Removes the previous run's [`REPLACED_SUBDIRS`], [`REPLACED_FILES`] and `recording` (with its
/// parts) from `out`, the default directory, so that the run about to write there replaces its
/// results as a whole. Never called for a directory
/// given by `--out`. Nothing else in `out` is removed; a subdirectory that holds a file no
/// pi2cma command writes (a link, another extension) is refused, naming the file, and so is
/// one with a file being recorded (another run writing there). Left as it is when the
/// recording a run resumes lies in `out` (it is still read, and its analysis joins it).
fn replace_default_dir(out: &Path, resumed: Option<&Path>, recording: Option<&str>) -> Result<()> {
    if !std::fs::symlink_metadata(out).is_ok_and(|m| m.is_dir()) {
        return Ok(());
    }
    if let Some(live) = file_being_written(out) {
        bail!(
            "{}: is being written by another process (a run in progress); wait for it, or give \
             --out",
            live.display()
        );
    }
    let inside = |p: &Path| {
        let (p, out) = (p.canonicalize(), out.canonicalize());
        p.is_ok_and(|p| out.is_ok_and(|out| p.starts_with(out)))
    };
    if resumed.is_some_and(inside) {
        return Ok(());
    }
    for sub in REPLACED_SUBDIRS {
        let dir = out.join(sub);
        if !std::fs::symlink_metadata(&dir).is_ok_and(|m| m.is_dir()) {
            continue;
        }
        if let Some(foreign) = foreign_file(&dir) {
            bail!(
                "{}: this run replaces {} (the previous run's), but no pi2cma command writes \
                 this file: move it, or give --out",
                foreign.display(),
                dir.display()
            );
        }
        std::fs::remove_dir_all(&dir).with_context(|| {
            format!(
                "replacing {} (the previous run's) for this run's",
                dir.display()
            )
        })?;
    }
    // `run`'s recording, and a split recording's later parts with it.
    let recording = recording
        .map(|r| record::recording_parts(&out.join(r)))
        .unwrap_or_default();
    let files = REPLACED_FILES.iter().map(|f| out.join(f)).chain(recording);
    for file in files {
        if std::fs::symlink_metadata(&file).is_ok_and(|m| !m.is_dir()) {
            std::fs::remove_file(&file).with_context(|| {
                format!(
                    "replacing {} (the previous run's) for this run's",
                    file.display()
                )
            })?;
        }
    }
    Ok(())
}

/// Refuses to record to `mcap` when it is an earlier recording of the run resumed from
/// `origin` (day1 of day1 → day2 → this run, when day1 is runs/latest/run.mcap and this run
/// records there by default): it would be overwritten, and with it the run's first updates.
fn refuse_overwriting_the_chain(origin: &str, mcap: &Path) -> Result<()> {
    let Ok(target) = mcap.canonicalize() else {
        return Ok(());
    };
    let (chain, _) = record::resumed_chain(Path::new(origin));
    if let Some(earlier) = chain
        .iter()
        .find(|p| p.canonicalize().is_ok_and(|p| p == target))
    {
        bail!(
            "{}: holds {}, an earlier recording of the run being resumed; this run would \
             record over it, and with it the run's first updates: give --out DIR",
            mcap.display(),
            earlier.display()
        );
    }
    Ok(())
}

/// A file or link below `dir` that is not one of pi2cma's outputs ([`OUTPUT_EXTENSIONS`]).
fn foreign_file(dir: &Path) -> Option<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Some(dir.to_path_buf());
    };
    for entry in entries.flatten() {
        let path = entry.path();
        match entry.file_type() {
            Ok(kind) if kind.is_dir() => {
                if let Some(f) = foreign_file(&path) {
                    return Some(f);
                }
            }
            Ok(kind)
                if kind.is_file()
                    && path
                        .extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| OUTPUT_EXTENSIONS.contains(&e)) => {}
            _ => return Some(path),
        }
    }
    None
}

/// A file below `dir` that a recorder holds ([`record::being_written`]), if any.
fn file_being_written(dir: &Path) -> Option<PathBuf> {
    for entry in std::fs::read_dir(dir).ok()?.flatten() {
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        let path = entry.path();
        if kind.is_dir() {
            if let Some(live) = file_being_written(&path) {
                return Some(live);
            }
        } else if kind.is_file() && record::being_written(&path) {
            return Some(path);
        }
    }
    None
}

/// The MCAP recorder of a `run` at `mcap`, recording the config as `text`.
fn recorder(mcap: &Path, text: String) -> Result<record::McapRecorder> {
    Ok(record::McapRecorder::create(mcap)
        .with_context(|| format!("creating {}", mcap.display()))?
        .with_config_text(text))
}

/// Runs `run` with the progress printer (with `quiet`, only its warnings) and `recorder` as
/// observers, then finishes the recording. `run` is to stop after its current update when the
/// stop function it gets says so: on a signal, or once the recording has failed (a full disk),
/// so that a run does not go on unrecorded to its end, which is when the failure is reported.
fn run_observed<T>(
    cfg: &RunConfig,
    mut recorder: Option<record::McapRecorder>,
    quiet: bool,
    run: impl FnOnce(&mut dyn Observer, &dyn Fn() -> bool) -> Result<T, session::SessionError>,
) -> Result<T> {
    let mut progress = Progress {
        total: cfg.run.updates,
        quiet,
    };
    let failed = recorder.as_ref().map(|r| r.failure_flag());
    let stop = || interrupted() || failed.as_ref().is_some_and(|f| f.load(Ordering::SeqCst));
    let value = {
        let mut observers: Vec<&mut dyn Observer> = vec![&mut progress];
        if let Some(r) = recorder.as_mut() {
            observers.push(r);
        }
        run(&mut session::Observers(observers), &stop)?
    };
    if let Some(r) = recorder {
        // The error names the file, what it holds and how to complete it.
        r.finish()
            .context("the run stopped: its recording failed")?;
    }
    Ok(value)
}

/// This binary, as a command it prints must be typed (`cargo run` does not put it on PATH).
fn this_program() -> String {
    std::env::current_exe()
        .map(|exe| record::program_name(&exe))
        .unwrap_or_else(|_| "pi2cma".into())
}

/// Where the recording is and how to analyse it; a resumed run's analysis joins the file it
/// resumed (`resumed_from`), for the whole learning curve.
fn print_recording(mcap: &Path, out: &Path, resumed_from: Option<&str>) {
    let (earlier, left_out) = resumed_from
        .map(|r| record::resumed_chain(Path::new(r)))
        .unwrap_or_default();
    say!(
        "recording: {}\nanalyse it with: {} --out {}",
        record::describe_parts(mcap),
        record::analyze_command(&this_program(), mcap, &earlier),
        out.join("analysis").display()
    );
    if let Some(note) = left_out {
        say!("NOTE: {note}");
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run {
            config,
            seed,
            updates,
            out,
            quiet,
            no_record,
            resume,
        } => {
            let point = resume
                .as_deref()
                .map(record::resume::resume_point)
                .transpose()?;
            let (cfg, text) = record::resume::run_config(
                config.as_deref(),
                point.as_ref(),
                &[("updates", updates), ("seed", seed)],
            )?;
            if cfg.run.updates.is_none() {
                bail!(
                    "{}: run.updates is not set (an unbounded run): give --updates N to run N \
                     updates in-process, or run it with `supervisor run`, which goes on until it \
                     is stopped",
                    cfg.origin.display()
                );
            }
            // Before anything in OUT is written: a config that cannot run in-process (an
            // external task) must not cost the results and recording OUT may hold.
            session::build_task(&cfg)?;
            let (out, replaceable) = output_dir(out, "runs/latest");
            let mcap = out.join("run.mcap");
            if let Some(point) = &point {
                point.check(&cfg)?;
                if !no_record {
                    point.check_output(&mcap, "--out")?;
                    refuse_overwriting_the_chain(&point.start.origin, &mcap)?;
                }
            }
            if !replaceable && !no_record {
                record::refuse_overwrite(&mcap, "--out")?;
            }
            if !replaceable && point.is_none() {
                // Unrecorded, the run still writes its results (a resumed one writes only its
                // recording, checked above).
                refuse_results_beside_recordings(&out, "run")?;
            }
            if replaceable {
                let resumed = point.as_ref().map(|p| Path::new(&p.start.origin));
                replace_default_dir(&out, resumed, Some("run.mcap"))?;
            }
            for note in cfg.notes() {
                eprintln!("note: {note}");
            }
            create_out_dir(&out, !replaceable)?;
            stop_on_signal()?;
            if let Some(point) = point {
                return run_resumed(&cfg, text, point, &out, quiet, no_record);
            }
            say!(
                "pi2cma: run {} ({}), seed {}, {} updates, in-process",
                cfg.run.name,
                cfg.origin.display(),
                cfg.run.seed,
                cfg.run.updates.unwrap_or(0)
            );
            let recorder = (!no_record).then(|| recorder(&mcap, text)).transpose()?;
            let session = run_observed(&cfg, recorder, quiet, |observer, stop| {
                experiment::run_one(&cfg, cfg.run.seed, observer, stop)
            })?;
            say_if_interrupted(
                session.summaries.len() as u64,
                (!no_record).then_some(mcap.as_path()),
            );
            let result = experiment::summarize(&cfg, vec![session])?;
            let table = write_outputs(&out, std::slice::from_ref(&result))?;
            say!("\n{table}");
            if let Some((mean, _)) = result.sessions[0].distributions.last() {
                say!("final mean θ = {}", session::mean_text(mean.as_slice()));
            }
            if let Some(s) = result.sessions[0].summaries.last() {
                say!("final λ = {:.4}", s.lambda_next);
            }
            say!(
                "results in {}/ (updates.csv, mean_curves.csv, fig2.svg, summary.md)",
                out.display()
            );
            if !no_record {
                print_recording(&mcap, &out, None);
            }
        }
        Command::Experiment {
            configs,
            sessions,
            weighting,
            out,
            record,
        } => {
            if sessions == 0 {
                bail!("--sessions must be at least 1");
            }
            let (out, replaceable) = output_dir(out, "runs/experiment");
            // Everything that can refuse the experiment is checked before its first session, not
            // hours later: every config, and every recording it will write.
            let mut planned = Vec::new();
            for path in &configs {
                let mut cfg = load(path)?;
                apply_weighting(&mut cfg, weighting)?;
                if cfg.run.updates.is_none() {
                    bail!(
                        "{}: run.updates must be set for an experiment",
                        path.display()
                    );
                }
                planned.push((path, cfg));
            }
            let recording = |cfg: &RunConfig, seed: u64| {
                let name = record::file_name_part(&cfg.run.name);
                out.join("mcap").join(format!("{name}-seed{seed}.mcap"))
            };
            if record {
                let mut files = std::collections::BTreeMap::new();
                for (path, cfg) in &planned {
                    for s in 0..sessions as u64 {
                        let file = recording(cfg, cfg.run.seed + s);
                        let name = cfg.run.name.as_str();
                        if let Some((other, other_name)) = files.insert(file.clone(), (path, name))
                        {
                            // Names that differ only in characters a file name cannot take
                            // (`day 1`, `day_1`) give the same file.
                            let same = if other_name == name {
                                "the same run.name and seed".to_string()
                            } else {
                                format!(
                                    "run.name {other_name:?} and {name:?} make the same file \
                                     name, every character other than an ASCII letter, digit, \
                                     `-`, `_` or `.` written as `_`; and the same seed"
                                )
                            };
                            bail!(
                                "{} and {} would both record to {} ({same}): give them different run.name",
                                other.display(),
                                path.display(),
                                file.display()
                            );
                        }
                        if !replaceable {
                            record::refuse_overwrite(&file, "--out")?;
                        }
                    }
                }
            }
            if !replaceable {
                refuse_results_beside_recordings(&out, "experiment")?;
            }
            if replaceable {
                replace_default_dir(&out, None, None)?;
            }
            create_out_dir(&out, !replaceable)?;
            // Ctrl-C (or SIGTERM) stops the session under way after its current update, with
            // a finished recording; the outputs hold the sessions completed before it.
            if record {
                let dir = out.join("mcap");
                std::fs::create_dir_all(&dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
            }
            stop_on_signal()?;
            let mut results = Vec::new();
            let mut stopped_in = None;
            for (path, cfg) in &planned {
                eprintln!("running {} × {sessions} sessions", cfg.run.name);
                let mut done = Vec::new();
                for s in 0..sessions as u64 {
                    let seed = cfg.run.seed + s;
                    let result = if record {
                        let file = recording(cfg, seed);
                        let mut rec = record::McapRecorder::create(&file)
                            .with_context(|| format!("creating {}", file.display()))?;
                        let failed = rec.failure_flag();
                        let stop = || interrupted() || failed.load(Ordering::SeqCst);
                        let r = experiment::run_one(cfg, seed, &mut rec, &stop);
                        rec.finish()
                            .context("the experiment stopped: a recording failed")?;
                        r
                    } else {
                        experiment::run_one(cfg, seed, &mut session::NoObserver, &interrupted)
                    };
                    let result = result.with_context(|| format!("running {}", path.display()))?;
                    if interrupted() {
                        // Cut short: not a session of the experiment's curves.
                        stopped_in = Some((cfg.run.name.clone(), seed, result.summaries.len()));
                        break;
                    }
                    done.push(result);
                }
                if !done.is_empty() {
                    results.push(experiment::summarize(cfg, done)?);
                }
                if stopped_in.is_some() {
                    break;
                }
            }
            if let Some((name, seed, updates)) = &stopped_in {
                let complete: usize = results.iter().map(|r| r.sessions.len()).sum();
                say!(
                    "interrupted in session {name} seed {seed} after {updates} updates (exit code 130){}; the results below are the {complete} sessions completed before it",
                    if record { ", its recording finished" } else { "" }
                );
                if results.is_empty() {
                    return Ok(());
                }
            }
            let table = write_outputs(&out, &results)?;
            say!("{table}");
            say!("results in {}/", out.display());
        }
        Command::Analyze(args) => say!(
            "{}",
            record::analyze::run(&args, &this_program())?.trim_end_matches('\n')
        ),
        Command::Recover(args) => say!("{}", record::recover::run(&args)?.describe()),
        Command::Check { configs } => {
            // Every file is checked, not only those before the first bad one.
            let mut bad = 0;
            for path in &configs {
                // An external task's worker program too: `supervisor run` would refuse it.
                match load(path).and_then(|c| {
                    c.external_worker_program()?;
                    Ok(c)
                }) {
                    Ok(cfg) => {
                        say!("{}: ok", path.display());
                        for note in cfg.notes() {
                            say!("note: {note}");
                        }
                    }
                    Err(e) => {
                        eprintln!("error: {e:#}");
                        bad += 1;
                    }
                }
            }
            if bad > 0 {
                bail!("{bad} of {} configs refused", configs.len());
            }
        }
        Command::Bench { quick, only } => {
            for m in bench::run_all(quick, &only) {
                say!(
                    "{:<90} median {:>12.3?}  min {:>12.3?}  ({} samples)",
                    m.label,
                    m.median,
                    m.min,
                    m.samples
                );
            }
        }
        Command::DefaultConfig => say!("{}", session::DEFAULT_CONFIG.trim_end_matches('\n')),
    }
    Ok(())
}

// Keep the weighting names in one place: the CLI's enum maps onto the config's.
const _: fn(WeightingName) = |_| {};
