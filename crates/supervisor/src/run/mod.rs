//! `supervisor run`: the event loop that owns the run's processes.
//!
//! Everything happens on the main thread (children must be forked by a thread that lives as
//! long as the supervisor, for PR_SET_PDEATHSIG). Helper threads only forward events into one
//! channel: a child exited, a control command arrived, a signal arrived, the supervisor's
//! doorbell rang (lifecycle or progress messages waiting).
//!
//! This file holds the command's options, the launch of a run ([`run`]: config, checks, run
//! directory) and the [`Supervisor`]'s state. The state machine's concerns live in submodules,
//! each with `impl Supervisor` blocks of its own: `event_loop` (phases, deadlines, events,
//! control commands), `children` (starting the processes and what their exits mean),
//! `process` (programs, signals, liveness), `workers` (slots, scaling, restarts, joined and hung
//! workers), `recorder` (the recording, its recorder's restarts and the recoveries), `ports`
//! (the iceoryx2 messages), `task_changes` (`supervisor set`), `status` (progress lines and
//! `supervisor status`), `summary` (the end of a run) and `cleanup` (removing runs' files). It
//! is not the control socket (`crate::control`) nor the shared-memory check (`crate::shm`).

mod children;
mod cleanup;
mod event_loop;
mod ports;
mod process;
mod recorder;
mod status;
mod summary;
mod suspend;
mod task_changes;
mod workers;

pub(crate) use process::process_stopped;
pub use process::{file_size_limit_note, group_members, process_alive};
pub use recorder::EMPTY_PART_REMOVED;

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::sync::mpsc::{self, Sender};
use std::time::Instant;

use anyhow::{bail, Context};
use session::{PipelineSection, RunConfig};
use wire::{Limits, Progress};

use crate::control::{self, Request};
use crate::shm;
use crate::EXIT_RECORDING_UNFINISHED;

use children::{Proc, Spawned};
pub(crate) use cleanup::supervisor_pid;
use cleanup::{note_recording, sweep_abandoned_runs, sweep_orphaned_ipc, PID_FILE};
pub(crate) use cleanup::{unfinished_recording, unfinished_text};
use event_loop::{Outcome, Phase};
use ports::Ports;
use process::Launcher;
use recorder::{fix_malloc_thresholds, RecorderSync, Recording};
use status::UpdateRate;
use task_changes::PendingSet;
use workers::Slot;

/// What `supervisor run` was asked to do (its command-line arguments).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunOptions {
    /// A run config (TOML); its `[pipeline]` section sets workers, limits and timeouts.
    pub config: Option<PathBuf>,
    /// Rollout workers to start with (overrides `pipeline.workers`).
    // `-2` is a bad value, not an unknown option (clap's tip for that, `-- -2`, would have
    // made it the config file).
    #[arg(long, allow_negative_numbers = true)]
    pub workers: Option<usize>,
    /// Fix the run id (16 hex digits) instead of drawing one.
    #[arg(long, value_parser = pipeline::parse_run_id)]
    pub run_id: Option<u64>,
    /// Directory holding the `updater`, `sampler` and `rollout-worker` binaries, and
    /// optionally `recorder` (else the supervisor's own executable runs it); each of the
    /// three must be there. Without it: the supervisor's own directory if all three are there,
    /// else the supervisor's own executable runs every role.
    #[arg(long)]
    pub bin_dir: Option<PathBuf>,
    /// Also write the result (final distribution with exact bits) to this file.
    #[arg(long)]
    pub result: Option<PathBuf>,
    /// Print no progress lines.
    #[arg(long)]
    pub quiet: bool,
    /// Write the run's MCAP recording here (default: `runs/<run name>-<run id>.mcap` in the
    /// current directory).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    /// Run without the recorder (no MCAP file).
    #[arg(long, conflicts_with = "record")]
    pub no_record: bool,
    /// Go on from the last update recorded in this MCAP file (a stopped, crashed or
    /// finished run whose run.updates is raised); without CONFIG, with the config it
    /// recorded. The result is bit for bit what the run would have given uninterrupted.
    #[arg(long, value_name = "FILE")]
    pub resume: Option<PathBuf>,
    /// Override run.updates (e.g. to go on with `--resume`); the recording's config shows it.
    #[arg(long, allow_negative_numbers = true)]
    pub updates: Option<u64>,
    /// Start (and later scale up) without checking that /dev/shm has room for the run. The
    /// check's estimate can be up to ~3 times what a run takes, so it may refuse a run that
    /// fits; without it, a run that outgrows /dev/shm dies of SIGBUS.
    #[arg(long)]
    pub no_shm_check: bool,
}

/// Where a run's recording goes without `--record`: `runs/<run name>-<run id>.mcap` in the
/// current directory — outside the run directory, which is removed when the run ends.
pub fn default_recording(run_name: &str, run_id: u64) -> PathBuf {
    let name = record::file_name_part(run_name);
    PathBuf::from("runs").join(format!("{name}-{}.mcap", wire::run_id_hex(run_id)))
}

/// Messages into the supervisor's event loop.
pub enum Event {
    Exited {
        pid: u32,
        status: ExitStatus,
    },
    Command(Request),
    /// SIGINT, SIGTERM, or SIGHUP unless the supervisor was started with it ignored (nohup).
    Signal(signals::Signal),
    /// Ctrl-Z (SIGTSTP): suspend the run ([`suspend`]).
    Suspend,
    Bell,
}

struct Supervisor {
    cfg: RunConfig,
    /// A resumed run's state, handed to the updater.
    start: Option<session::Start>,
    recording: Option<Recording>,
    pipe: PipelineSection,
    run_id: u64,
    run_dir: PathBuf,
    launcher: Launcher,
    config_file: PathBuf,
    quiet: bool,
    tx: Sender<Event>,
    procs: BTreeMap<u32, Proc>,
    slots: BTreeMap<u32, Slot>,
    target_workers: usize,
    phase: Phase,
    phase_deadline: Option<Instant>,
    outcome: Option<Outcome>,
    /// `supervisor stop --after-update` was asked (and no plain `stop` since): the updater
    /// ends the run after the update under way with a `FINAL | STOPPED` distribution.
    stop_after_update: bool,
    killed: bool,
    started: Instant,
    progress: Option<Progress>,
    /// The update rate of the progress lines, `status` and the stall warning
    /// ([`UpdateRate`]), and the reports it is taken from.
    rate: f64,
    rates: UpdateRate,
    /// When the last progress line was shown, and the update it showed.
    last_shown: Option<(Instant, u64)>,
    /// When the newest update arrived (when the run started, before the first: a first
    /// update that never comes is a stall too), and whether the silence since was reported.
    last_update_at: Option<Instant>,
    /// When the updater last reported a rollout of the update under way done: with rollouts of
    /// seconds, what shows a run going on between updates (`check_stall`).
    last_rollout_at: Option<Instant>,
    /// (update, rollouts done) of the last line on the update under way (`under_way_due`).
    under_way_shown: (u64, u32),
    stall_reported: bool,
    /// Workers that announced themselves without being started here: pid → (slot, start time;
    /// see [`process_started`](process::process_started)).
    joined: BTreeMap<u32, (u32, u64)>,
    /// When [`Self::check_joined`] last looked.
    joined_checked: Instant,
    total_restarts: u32,
    ports: Option<Ports>,
    /// The number of the last `supervisor set` request (`Control::seq`), and those still
    /// waiting for the updater to say which update they take effect from.
    task_change_seq: u64,
    pending_sets: Vec<PendingSet>,
    /// The last answered changes: (setting, update it takes effect from, `name = value`), so
    /// that a reply can say when it replaces an earlier change due from the same update.
    answered_sets: VecDeque<(String, u64, String)>,
    /// Changes sent that the last [`Progress`] does not show yet: (seq, setting, value, the
    /// update it takes effect from once the updater has said). A new change is checked with the
    /// settings they and that report give ([`Self::settings_in_force`]).
    unreflected_sets: Vec<(u64, String, f64, Option<u64>)>,
    recorder_sync: RecorderSync,
    /// The sizes of the run's services (`pipeline::limits` of the config).
    limits: Limits,
    /// `run --no-shm-check`: scale-ups are not checked against /dev/shm either.
    no_shm_check: bool,
    /// Every pid this supervisor started, reaped ones for
    /// [`LATE_ANNOUNCEMENT`](children::LATE_ANNOUNCEMENT) after: a worker's late announcement,
    /// read after it was reaped, is not a worker joining from outside.
    spawned: Spawned,
}

fn say(msg: &str) {
    print_line("supervisor", msg);
}

/// Prints `[who] line`. A closed stdout (e.g. `supervisor run | head`) is not a reason to die
/// before cleaning up, so write errors are ignored (`println!` would panic).
fn print_line(who: &str, line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stdout().lock(), "[{who}] {line}");
}

fn draw_run_id() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0);
    // splitmix64 of time and pid: distinct for runs started at once.
    let mut z = nanos ^ (u64::from(std::process::id()) << 40);
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Runs a pipeline to the end and returns the process exit code (0, 1 or 130).
pub fn run(opts: &RunOptions) -> anyhow::Result<u8> {
    fix_malloc_thresholds();
    let point = opts
        .resume
        .as_deref()
        .map(record::resume::resume_point)
        .transpose()?;
    let (cfg, text) = record::resume::run_config(
        opts.config.as_deref(),
        point.as_ref(),
        &[("updates", opts.updates)],
    )?;
    let origin = cfg.origin.clone();
    if let Some(point) = &point {
        point.check(&cfg)?;
    }
    for note in cfg.notes() {
        say(&format!("note: {note}"));
    }
    let pipe = cfg.pipeline();
    let target_workers = opts.workers.unwrap_or(pipe.workers);
    if !(1..=pipe.max_workers).contains(&target_workers) {
        // The value came from the command line (the config's own is checked at load).
        bail!(
            "--workers {target_workers}: must be between 1 and pipeline.max_workers = {} of {}",
            pipe.max_workers,
            origin.display()
        );
    }
    let launcher = Launcher::find(opts.bin_dir.as_deref(), &cfg).map_err(|e| {
        // A recorded config has no file of its own: a worker path relative to the run's config
        // file was looked for beside the recording, and the error told the user nothing to do.
        let relative = matches!(&cfg.task, session::TaskSection::External(x)
            if x.worker.first().is_some_and(|p| p.contains('/') && Path::new(p).is_relative()));
        match (&opts.resume, opts.config.is_none() && relative) {
            (Some(file), true) => e.context(format!(
                "resuming {} with its recorded config, whose worker path is relative to a \
                 config file it no longer has (it is looked for beside the recording): give the \
                 config, `supervisor run CONFIG --resume {}` (its worker command may differ from \
                 the recorded one)",
                file.display(),
                file.display()
            )),
            _ => e,
        }
    })?;
    if let Some(dest) = &opts.result {
        check_writable(dest).with_context(|| {
            format!("--result {}: cannot write the result there", dest.display())
        })?;
    }
    let limits = pipeline::limits(&cfg)?;
    let run_id = opts.run_id.unwrap_or_else(draw_run_id);
    let run_dir = control::runs_dir().join(wire::run_id_hex(run_id));
    let recording = if opts.no_record {
        None
    } else {
        let path = opts
            .record
            .clone()
            .unwrap_or_else(|| default_recording(&cfg.run.name, run_id));
        if let Some(point) = &point {
            point.check_output(&path, "--record")?;
        }
        // The recorder creates its file before the workers start, so a run that then fails
        // (a worker refusing the config) would leave an empty recording in place of this one.
        // The parts of an earlier split recording too: the new one would remove them.
        // Without --record the file is the id's default one, there from an earlier run of this
        // id (a script's fixed --run-id, a run whose supervisor was killed): naming `--record`
        // there sent the user looking for an option they had not given.
        let option = if opts.record.is_some() {
            "--record"
        } else {
            "the default place of a run of this name and id, left by an earlier run of the id: \
             give another --run-id, or --record FILE"
        };
        record::refuse_overwrite(&path, option)?;
        Some(Recording {
            path,
            defaulted: opts.record.is_none(),
            lost: None,
            term_at: None,
            restarts: VecDeque::new(),
            restarted: 0,
            continue_in: None,
            back_pending: None,
            recovering: Vec::new(),
        })
    };
    for (id, files, unfinished) in sweep_abandoned_runs(&control::runs_dir()) {
        say(&format!(
            "removed what run {id} left behind (its supervisor was killed): its run directory, \
             iceoryx2 directory and {files} shared-memory files{}",
            unfinished.map_or(String::new(), |part| format!(
                "; {}",
                unfinished_text(&part)
            ))
        ));
    }
    for (id, files) in sweep_orphaned_ipc(run_id) {
        say(&format!(
            "removed the shared memory and iceoryx2 files run {id} left behind ({files} \
             shared-memory files; all its processes are gone)"
        ));
    }
    let (p_field, n_field) = cfg.size_fields()?;
    let shm_sizes = shm::RunSizes {
        config: &origin,
        limits,
        workers: target_workers,
        workers_field: if opts.workers.is_some() {
            "--workers"
        } else {
            "pipeline.workers"
        },
        recorder: recording.is_some(),
        reruns: cfg.run.nonfinite_reruns > 0,
        p_field,
        n_field,
    };
    if opts.no_shm_check {
        if let Some(judged) = shm::describe(&shm_sizes) {
            say(&format!("--no-shm-check: {judged}"));
        }
    } else {
        for warning in shm::check(&shm_sizes)? {
            say(&format!("warning: {warning}"));
        }
    }
    if run_dir.exists() {
        let id = wire::run_id_hex(run_id);
        // What killed runs left behind is gone by now (`sweep_abandoned_runs`): a directory
        // whose supervisor answers is a live run, which removing it would break.
        if control::serving(&run_dir) {
            bail!("run {id} is active (`supervisor status --run {id}`): choose another --run-id");
        }
        bail!(
            "run directory {} exists, but no supervisor answers on it: if no run {id} is going \
             on, remove the directory",
            run_dir.display()
        );
    }
    // The iceoryx2 directory and the shared memory are named by the run id alone: a run of
    // this id under another runs directory (another `PI2CMA_RUN_DIR`, another user) has no run
    // directory here, and starting beside it failed in iceoryx2 and then removed its files.
    // Processes of the run started by hand before it (a recorder for `--no-record`) are not
    // such a run.
    let root = wire::iceoryx_root(run_id);
    if root.exists() && wire::supervisor_alive(run_id) {
        let id = wire::run_id_hex(run_id);
        bail!(
            "run {id} is active outside {}: its supervisor is alive in its iceoryx2 directory \
             {} (a run under another PI2CMA_RUN_DIR, or another user's); a second run with its \
             id would break it: choose another --run-id",
            control::runs_dir().display(),
            root.display()
        );
    }
    // Only now, so that a run refused above leaves no directory behind.
    if let Some(parent) = recording
        .as_ref()
        .and_then(|r| r.path.parent())
        .filter(|p| !p.as_os_str().is_empty())
    {
        std::fs::create_dir_all(parent).with_context(|| {
            format!(
                "cannot create {} for the recording (or run with --no-record)",
                parent.display()
            )
        })?;
    }
    // A second attempt covers another run removing the (then empty) runs directory between
    // our creating it and creating our run directory in it.
    std::fs::create_dir_all(&run_dir)
        .or_else(|_| std::fs::create_dir_all(&run_dir))
        .with_context(|| format!("cannot create {}", run_dir.display()))?;
    let pid_file = run_dir.join(PID_FILE);
    std::fs::write(&pid_file, std::process::id().to_string())
        .with_context(|| format!("cannot write {}", pid_file.display()))?;
    if let Some(r) = &recording {
        note_recording(&run_dir, &r.path)
            .with_context(|| format!("cannot note the recording in {}", run_dir.display()))?;
    }
    let (tx, rx) = mpsc::channel();
    let mut sup = Supervisor {
        pipe: pipe.clone(),
        run_id,
        config_file: run_dir.join("config.toml"),
        run_dir,
        launcher,
        quiet: opts.quiet,
        tx,
        procs: BTreeMap::new(),
        slots: BTreeMap::new(),
        target_workers,
        phase: if recording.is_some() {
            Phase::StartRecorder
        } else {
            Phase::StartUpdater
        },
        recording,
        phase_deadline: None,
        outcome: None,
        stop_after_update: false,
        killed: false,
        started: Instant::now(),
        progress: None,
        rate: 0.0,
        rates: UpdateRate::default(),
        last_shown: None,
        last_update_at: None,
        under_way_shown: (0, 0),
        last_rollout_at: None,
        stall_reported: false,
        joined: BTreeMap::new(),
        joined_checked: Instant::now(),
        total_restarts: 0,
        ports: None,
        task_change_seq: 0,
        answered_sets: VecDeque::new(),
        pending_sets: Vec::new(),
        unreflected_sets: Vec::new(),
        recorder_sync: RecorderSync::default(),
        limits,
        no_shm_check: opts.no_shm_check,
        spawned: Default::default(),
        cfg,
        start: point.map(|p| p.start),
    };
    let result = sup.run(&text, rx);
    // Whatever happened, nothing of the run stays behind.
    sup.ports = None;
    let summary = sup.finish(opts.result.as_deref());
    let code = result?;
    // A part a dead recorder left that its recovery could not complete.
    let unfinished = summary?;
    Ok(if unfinished && code == 0 {
        EXIT_RECORDING_UNFINISHED
    } else {
        code
    })
}

/// Fails unless a file can be written at `path`: checked before a run starts, since the
/// result is written only when the run ends, maybe days later. Creates nothing that stays.
fn check_writable(path: &Path) -> anyhow::Result<()> {
    if path.is_dir() {
        bail!("it is a directory");
    }
    let existed = path.exists();
    std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(path)?;
    if !existed {
        let _ = std::fs::remove_file(path);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_recording_is_under_runs_named_after_the_run_and_its_id() {
        assert_eq!(
            default_recording("A1", 0x00ab_cdef_0123_4567),
            PathBuf::from("runs/A1-00abcdef01234567.mcap")
        );
        // A run name is not a path.
        assert_eq!(
            default_recording("a/b c", 1),
            PathBuf::from("runs/a_b_c-0000000000000001.mcap")
        );
    }
}
