//! `supervisor run`: the event loop that owns the run's processes.
//!
//! Everything happens on the main thread (children must be forked by a thread that lives as
//! long as the supervisor, for PR_SET_PDEATHSIG). Helper threads only forward events into one
//! channel: a child exited, a control command arrived, a signal arrived, the supervisor's
//! doorbell rang (lifecycle or progress messages waiting).

use std::collections::{BTreeMap, VecDeque};
use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use pipeline::iox;
use pipeline::result::RunResult;
use session::{executable_file, PipelineSection, RunConfig};
use wire::{Control, Lifecycle, Limits, Overdue, Progress, RecorderAck, RunNote, Service};

use crate::control::{self, Command as Cmd, Request};
use crate::shm::{self, size, SHM_DIR};
use crate::{EXIT_INTERRUPTED, EXIT_RECORDING_UNFINISHED};

/// What `supervisor run` was asked to do (its command-line arguments).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RunOptions {
    /// A run config (TOML); its `[pipeline]` section sets workers, limits and timeouts.
    pub config: Option<PathBuf>,
    /// Rollout workers to start with (overrides `pipeline.workers`).
    #[arg(long)]
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
    #[arg(long)]
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
    Exited { pid: u32, status: ExitStatus },
    Command(Request),
    Signal,
    Bell,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Recorder,
    Updater,
    Sampler,
    Worker(u32),
}

impl Role {
    fn name(self) -> String {
        match self {
            Role::Recorder => "recorder".into(),
            Role::Updater => "updater".into(),
            Role::Sampler => "sampler".into(),
            Role::Worker(w) => format!("worker-{w}"),
        }
    }
    fn binary(self) -> &'static str {
        match self {
            Role::Recorder => "recorder",
            Role::Updater => "updater",
            Role::Sampler => "sampler",
            Role::Worker(_) => "rollout-worker",
        }
    }
}

const BINARIES: [&str; 3] = ["updater", "sampler", "rollout-worker"];

/// How children are started: the `updater`, `sampler` and `rollout-worker` binaries of a
/// directory, or — when they are not next to the supervisor, as after `cargo run`, which builds
/// only the binary it runs — the supervisor's own executable, which hosts all four roles. The
/// recorder (the `recorder` binary) is taken from the directory when it is there,
/// else hosted by the supervisor's executable too. An external task's workers are the user's
/// program (`task.external.worker`).
#[derive(Debug, Clone)]
struct Launcher {
    binaries: Binaries,
    /// The program and leading arguments of an external task's workers (`task.external.worker`),
    /// which replace `rollout-worker`.
    external_worker: Option<(PathBuf, Vec<String>)>,
}

#[derive(Debug, Clone)]
enum Binaries {
    InDir { dir: PathBuf, exe: PathBuf },
    SelfHosted(PathBuf),
}

impl Launcher {
    fn find(bin_dir: Option<&Path>, cfg: &RunConfig) -> anyhow::Result<Self> {
        let external_worker = cfg.external_worker_program()?;
        let binaries = Binaries::find(bin_dir)?;
        Ok(Self {
            binaries,
            external_worker,
        })
    }

    /// The program and its leading arguments for `role`.
    fn program(&self, role: Role) -> (PathBuf, Vec<String>) {
        if let (Role::Worker(_), Some((program, args))) = (role, &self.external_worker) {
            return (program.clone(), args.clone());
        }
        let hosted = |exe: &PathBuf| (exe.clone(), vec![role.binary().to_string()]);
        match &self.binaries {
            Binaries::InDir { dir, exe } => {
                let bin = dir.join(role.binary());
                if role == Role::Recorder && !bin.is_file() {
                    hosted(exe)
                } else {
                    (bin, Vec::new())
                }
            }
            Binaries::SelfHosted(exe) => hosted(exe),
        }
    }
}

impl Binaries {
    fn find(bin_dir: Option<&Path>) -> anyhow::Result<Self> {
        if let Some(dir) = bin_dir {
            for b in BINARIES {
                let p = dir.join(b);
                if !p.exists() {
                    bail!(
                        "missing binary `{b}`: {} does not exist (--bin-dir {} must hold {}; \
                         without --bin-dir the supervisor runs them from its own directory, \
                         or its own executable runs them)",
                        p.display(),
                        dir.display(),
                        BINARIES.join(", ")
                    );
                }
                // Found now rather than when it is started, after the processes before it.
                if !executable_file(&p) {
                    bail!("binary `{b}`: {} is not an executable file", p.display());
                }
            }
            return Ok(Self::InDir {
                dir: dir.to_path_buf(),
                exe: std::env::current_exe()?,
            });
        }
        let exe = std::env::current_exe()?;
        let dir = exe
            .parent()
            .context("the supervisor executable has no directory")?;
        Ok(if BINARIES.iter().all(|b| executable_file(&dir.join(b))) {
            Self::InDir {
                dir: dir.to_path_buf(),
                exe: exe.clone(),
            }
        } else {
            Self::SelfHosted(exe)
        })
    }
}

struct Proc {
    role: Role,
    incarnation: u32,
    ready: bool,
    stopping: bool,
    /// SIGKILLed after it was asked to stop and did not within `shutdown_timeout_ms`.
    sigkilled: bool,
    /// A worker a scale-down asked to stop: killed if it has not by then.
    stop_by: Option<Instant>,
    /// Killed because it held its chunk too long (`pipeline.rollout_timeout_ms`): why.
    hung: Option<String>,
    /// When it was started, and when it announced itself (its ports exist from then on).
    spawned_at: Instant,
    ready_at: Option<Instant>,
    /// A worker asked to stop whose SIGTERM waits for the recorder to connect to its ports:
    /// the RECORDER_SYNC it waits for, and until when (see [`Supervisor::stop_worker`]).
    term_wait: Option<(u64, Instant)>,
    last_line: Arc<Mutex<String>>,
}

/// The supervisor's [`Control::RECORDER_SYNC`]s: the last number given, the one sent and not
/// yet carried out (with when it was sent), and the newest the recorder has carried out.
#[derive(Debug, Default)]
struct RecorderSync {
    seq: u64,
    outstanding: Option<(u64, Instant)>,
    done: u64,
    /// The newest acknowledgement's `next_update`: every update before it is written.
    written: Option<u64>,
}

#[derive(Default)]
struct Slot {
    incarnation: u32,
    pid: Option<u32>,
    restarts: VecDeque<Instant>,
    restart_at: Option<Instant>,
    /// How its last process died (exit status and last output), once one did: what a startup
    /// that times out while it is restarted names as the cause.
    last_death: Option<String>,
}

#[derive(Debug, Clone, PartialEq)]
enum Outcome {
    Complete,
    Stopped,
    Interrupted,
    Failed(String),
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    StartRecorder,
    StartUpdater,
    StartSampler,
    StartWorkers,
    Running,
    Stopping,
}

struct Ports {
    lifecycle: Subscriber<Service, Lifecycle, ()>,
    overdue: Subscriber<Service, Overdue, ()>,
    progress: Subscriber<Service, Progress, ()>,
    recorded: Subscriber<Service, RecorderAck, ()>,
    control: Publisher<Service, Control, ()>,
    notes: Publisher<Service, RunNote, ()>,
    sampler_bell: Notifier<Service>,
    updater_bell: Notifier<Service>,
    /// Rung after every control message, so the recorder logs it when it happens.
    recorder_bell: Notifier<Service>,
    /// Control messages sent ([`Control::sent`] of the last).
    control_sent: std::cell::Cell<u64>,
    // Dropped last: ports above belong to it.
    _node: Node<Service>,
}

/// The run's recording and what became of its recorder.
struct Recording {
    /// As given or defaulted (printed as is).
    path: PathBuf,
    /// The path is [`default_recording`] (no `--record`).
    defaulted: bool,
    /// `None` while the recorder runs or exited cleanly; else why the file is incomplete.
    lost: Option<String>,
    /// When the recorder gets SIGTERM at the end of a complete run if it has not exited by
    /// itself after the final distribution.
    term_at: Option<Instant>,
    /// When the recorder was restarted, within `pipeline.restart_window_s` (as a worker slot's).
    restarts: VecDeque<Instant>,
    /// Restarts over the whole run.
    restarted: u32,
    /// The part the recorder started last after a death goes on in (its restart count is
    /// `restarted`).
    continue_in: Option<u32>,
    /// A restarted recorder the updater has not been told of yet (Control::RECORDER_BACK
    /// once it has announced itself), and how its predecessor died (put into the recording).
    back_pending: Option<String>,
    /// The parts dead recorders left unfinished, being recovered in the background, or their
    /// recovery's outcome once it ended ([`Recording::reap_recoveries`]).
    recovering: Vec<(PathBuf, Recovery)>,
}

/// What the summary says of a part whose recorder died before it wrote anything to it.
pub const EMPTY_PART_REMOVED: &str =
    "held nothing (its recorder died before writing its first record): removed";

/// The recovery of a part a dead recorder left.
enum Recovery {
    Running(std::thread::JoinHandle<Result<String, String>>),
    Done(Result<String, String>),
}

impl Recovery {
    /// Its outcome, waiting for it if it still runs.
    fn outcome(self) -> Result<String, String> {
        match self {
            Recovery::Running(h) => h
                .join()
                .unwrap_or_else(|_| Err("the recovery panicked".to_string())),
            Recovery::Done(done) => done,
        }
    }
}

impl Recording {
    /// Joins the recoveries that have ended, keeping only their outcome for the summary. A
    /// thread not joined keeps its stack mapped (2 MB and two mappings) until the run ends, so
    /// a recorder that kept dying grew the supervisor's address space without bound: +120 MB
    /// and +121 mappings after 60 restarts (+2 MB and 3 with them joined); at the kernel's
    /// 65 530 mappings no thread could be started any more.
    fn reap_recoveries(&mut self) {
        for (_, recovery) in &mut self.recovering {
            if matches!(recovery, Recovery::Running(h) if h.is_finished()) {
                let ended = std::mem::replace(recovery, Recovery::Done(Ok(String::new())));
                *recovery = Recovery::Done(ended.outcome());
            }
        }
    }

    /// The part the recorder started last after a death goes on in.
    fn continued_part(&self) -> Option<PathBuf> {
        self.continue_in
            .map(|n| record::part_path(&record::first_part(&self.path), n))
    }
}

/// The update rate over the updater's last reports: updates over the time they took, the
/// reports of about the last [`UpdateRate::WINDOW_NS`] (at least two). Each report carries
/// when its last update was completed (`Progress::elapsed_ns`). Taken between the last two
/// reports only, sent at most every 200 ms, the rate of a run making 6 updates a second read
/// 5 and 10 by turns, and 1574 to 10090 where a report came a millisecond after the one
/// before (the one at each tenth of a bounded run).
#[derive(Debug, Default)]
struct UpdateRate {
    /// (updates completed, when the last of them was, in ns since the start), oldest first.
    seen: std::collections::VecDeque<(u64, u64)>,
}

impl UpdateRate {
    const WINDOW_NS: u64 = 2_000_000_000;

    fn is_empty(&self) -> bool {
        self.seen.is_empty()
    }

    /// A report of `updates` completed, the last at `elapsed_ns`; one with no new update
    /// says nothing of the rate.
    fn add(&mut self, updates: u64, elapsed_ns: u64) {
        if self.seen.back().is_some_and(|&(u, _)| updates <= u) {
            return;
        }
        self.seen.push_back((updates, elapsed_ns));
        while self.seen.len() > 2 && self.seen[1].1 + Self::WINDOW_NS <= elapsed_ns {
            self.seen.pop_front();
        }
    }

    fn rate(&self) -> Option<f64> {
        let (&(u0, t0), &(u1, t1)) = (self.seen.front()?, self.seen.back()?);
        (t1 > t0).then(|| (u1 - u0) as f64 / ((t1 - t0) as f64 * 1e-9))
    }
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
    killed: bool,
    started: Instant,
    progress: Option<Progress>,
    /// The update rate of the progress lines, `status` and the stall warning
    /// ([`UpdateRate`]), and the reports it is taken from.
    rate: f64,
    rates: UpdateRate,
    last_shown: Option<Instant>,
    /// When the newest update arrived (when the run started, before the first: a first
    /// update that never comes is a stall too), and whether the silence since was reported.
    last_update_at: Option<Instant>,
    stall_reported: bool,
    /// Workers that announced themselves without being started here: pid → (slot, start time;
    /// see [`process_started`]).
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
    /// Every pid this supervisor started, reaped ones for [`LATE_ANNOUNCEMENT`] after: a
    /// worker's late announcement, read after it was reaped, is not a worker joining from
    /// outside.
    spawned: Spawned,
}

/// How long a reaped child's pid is still taken as the supervisor's own when an announcement
/// from it is read ([`Spawned`]); the supervisor reads announcements within a tick of their
/// sending, so this only has to outlast a loaded machine.
const LATE_ANNOUNCEMENT: Duration = Duration::from_secs(60);

/// The pids the supervisor started: running, or reaped within [`LATE_ANNOUNCEMENT`]. They used
/// to be kept for the whole run, one per worker incarnation, so a continual run whose workers
/// were restarted and scaled for days kept a set that only grew, and once the kernel handed one
/// of those pids (`kernel.pid_max` is 32768 on many systems) to a worker the user started, that
/// worker was taken for a late announcement of the supervisor's own: not listed as joined, and
/// not stopped when it took a slot a worker of the supervisor's held.
#[derive(Default)]
struct Spawned {
    /// pid → when it was reaped (`None`: running).
    pids: BTreeMap<u32, Option<Instant>>,
}

impl Spawned {
    fn started(&mut self, pid: u32) {
        self.pids.insert(pid, None);
    }

    /// `pid` has exited and was reaped at `now`; pids reaped too long ago are forgotten.
    fn reaped(&mut self, pid: u32, now: Instant) {
        if let Some(at) = self.pids.get_mut(&pid) {
            *at = Some(now);
        }
        self.pids.retain(|_, at| Self::recent(*at, now));
    }

    /// Whether an announcement read at `now` from `pid` is from a process this supervisor
    /// started.
    fn ours(&self, pid: u32, now: Instant) -> bool {
        self.pids.get(&pid).is_some_and(|at| Self::recent(*at, now))
    }

    fn recent(reaped: Option<Instant>, now: Instant) -> bool {
        reaped.is_none_or(|t| now.saturating_duration_since(t) < LATE_ANNOUNCEMENT)
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.pids.len()
    }
}

/// A `supervisor set` whose reply waits for the updater's [`Progress::TASK_CHANGE`].
struct PendingSet {
    /// Its `Control::seq`, which the updater echoes.
    seq: u64,
    /// The setting, and `name = value`.
    name: String,
    what: String,
    reply: std::sync::mpsc::Sender<Result<String, String>>,
    /// After this, the reply goes without the update index (an updater busy in a long update,
    /// or stopped, answers late or never).
    until: Instant,
}

/// How long `supervisor set` waits for the updater to name the update of a change.
const SET_REPLY_WAIT: Duration = Duration::from_secs(2);

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
        record::refuse_overwrite(&path, "--record")?;
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
    for (id, files) in sweep_abandoned_runs(&control::runs_dir()) {
        say(&format!(
            "removed what run {id} left behind (its supervisor was killed): its run directory, \
             iceoryx2 directory and {files} shared-memory files"
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
        killed: false,
        started: Instant::now(),
        progress: None,
        rate: 0.0,
        rates: UpdateRate::default(),
        last_shown: None,
        last_update_at: None,
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

impl Supervisor {
    fn run(&mut self, text: &str, rx: Receiver<Event>) -> anyhow::Result<u8> {
        // A copy: `self` is borrowed mutably below.
        let limits: &Limits = &{ self.limits };
        std::fs::write(&self.config_file, text)
            .with_context(|| format!("cannot write {}", self.config_file.display()))?;
        if let Some(start) = &self.start {
            start.write(&self.start_file())?;
        }
        let bell_stop = Arc::new(AtomicBool::new(false));
        let bell = spawn_bell(self.run_id, *limits, self.tx.clone(), bell_stop.clone())?;
        let node = wire::node(self.run_id, wire::process::SUPERVISOR)?;
        self.ports = Some(Ports {
            lifecycle: iox(
                wire::lifecycle(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "lifecycle subscriber",
            )?,
            progress: iox(
                wire::progress(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "progress subscriber",
            )?,
            overdue: iox(
                wire::overdue(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "overdue subscriber",
            )?,
            recorded: iox(
                wire::recorded(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "recorded subscriber",
            )?,
            control: iox(
                wire::control(&node, self.run_id, limits)?
                    .publisher_builder()
                    .create(),
                "control publisher",
            )?,
            notes: iox(
                wire::notes(&node, self.run_id, limits)?
                    .publisher_builder()
                    .create(),
                "notes publisher",
            )?,
            sampler_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::SAMPLER, limits)?
                    .notifier_builder()
                    .create(),
                "sampler notifier",
            )?,
            updater_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::UPDATER, limits)?
                    .notifier_builder()
                    .create(),
                "updater notifier",
            )?,
            recorder_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::RECORDER, limits)?
                    .notifier_builder()
                    .create(),
                "recorder notifier",
            )?,
            control_sent: std::cell::Cell::new(0),
            _node: node,
        });
        let tx = self.tx.clone();
        ctrlc::set_handler(move || {
            let _ = tx.send(Event::Signal);
        })
        .context("cannot install the SIGINT/SIGTERM handler")?;
        control::serve(&self.run_dir, self.tx.clone())?;
        say(&format!(
            "run {} ({}): starting {}updater, sampler and {} workers",
            wire::run_id_hex(self.run_id),
            self.cfg.run.name,
            match &self.recording {
                Some(r) => format!("recorder (to {}), ", r.path.display()),
                None => String::new(),
            },
            self.target_workers
        ));
        let loop_result = self.event_loop(&rx);
        bell_stop.store(true, Ordering::Relaxed);
        let _ = bell.join();
        if let Err(e) = loop_result {
            // Bring the group down before reporting.
            if self.role_pid(Role::Recorder).is_some() {
                if let Some(rec) = self.recording.as_mut() {
                    rec.lost
                        .get_or_insert_with(|| "killed after a supervisor error".into());
                }
            }
            self.kill_all();
            self.reap(&rx, Duration::from_secs(2));
            return Err(e);
        }
        let recording_lost = self.recording.as_ref().is_some_and(|r| r.lost.is_some());
        Ok(match &self.outcome {
            Some(Outcome::Complete) | Some(Outcome::Stopped) if recording_lost => {
                EXIT_RECORDING_UNFINISHED
            }
            Some(Outcome::Complete) | Some(Outcome::Stopped) => 0,
            Some(Outcome::Interrupted) => EXIT_INTERRUPTED,
            Some(Outcome::Failed(_)) | None => 1,
        })
    }

    fn event_loop(&mut self, rx: &Receiver<Event>) -> anyhow::Result<()> {
        self.advance()?;
        loop {
            let now = Instant::now();
            let next = self
                .deadlines()
                .into_iter()
                .min()
                .map(|d| d.saturating_duration_since(now))
                .unwrap_or(Duration::from_secs(3600));
            match rx.recv_timeout(next) {
                Ok(ev) => self.handle(ev)?,
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => bail!("event channel closed"),
            }
            while let Ok(ev) = rx.try_recv() {
                self.handle(ev)?;
            }
            self.poll_ports()?;
            self.release_stops()?;
            self.answer_sets(0, None, self.phase == Phase::Stopping);
            self.check_deadlines();
            self.check_stall();
            self.check_joined();
            self.advance()?;
            if self.phase == Phase::Stopping && self.procs.is_empty() {
                return Ok(());
            }
        }
    }

    /// How long a running run may go without an update before the supervisor says so: 20
    /// times the usual time per update, at least 10 s.
    fn stall_after(&self) -> Duration {
        let usual = if self.rate > 0.0 {
            1.0 / self.rate
        } else {
            0.0
        };
        Duration::from_secs_f64((20.0 * usual).clamp(10.0, 86_400.0))
    }

    /// A run without updates for [`Self::stall_after`] is reported once (until updates go on):
    /// a hung worker without `rollout_timeout_ms`, a stopped recorder that holds the updater
    /// (named as such when its acknowledgements lag the updates), a robot waiting for its
    /// operator. Nothing is killed; `status` shows the age as well.
    fn check_stall(&mut self) {
        let Some(at) = self.last_update_at else {
            return;
        };
        if self.phase != Phase::Running || self.stall_reported || at.elapsed() < self.stall_after()
        {
            return;
        }
        self.stall_reported = true;
        let timeout = match self.pipe.rollout_timeout_ms {
            Some(ms) => format!("a worker in a rollout for over {ms} ms is restarted as hung"),
            None => "pipeline.rollout_timeout_ms is not set, so a hung worker is never \
                     restarted"
                .to_string(),
        };
        let since = match self.progress {
            Some(p) if self.rate > 0.0 => format!(
                "since update {} (they came every {} before)",
                p.updates,
                interval_text(1.0 / self.rate)
            ),
            Some(p) => format!("since update {}", p.updates),
            None => "since the start".to_string(),
        };
        // The recorder's acknowledgements tell whether it is what holds the updater back.
        let _ = self.drain_recorder_acks();
        let who = match self.recorder_written() {
            Some((last, Some(n))) if n > 0 && self.recorder_listening() => format!(
                "the recorder has written only through update {last} ({n} behind the updater, \
                 which it holds back): is it stopped, or is its disk slow?"
            ),
            _ => format!("a worker may hang ({timeout})"),
        };
        let text = format!(
            "no update for {:.0} s {since}: {who}; `supervisor status` shows the processes",
            at.elapsed().as_secs_f64(),
        );
        say(&format!("warning: {text}"));
        self.note(RunNote::WARNING, &text);
    }

    fn deadlines(&self) -> Vec<Instant> {
        let mut d: Vec<Instant> = self.slots.values().filter_map(|s| s.restart_at).collect();
        d.extend(self.phase_deadline);
        if self.phase == Phase::Running && !self.stall_reported {
            d.extend(self.last_update_at.map(|t| t + self.stall_after()));
        }
        if self.phase == Phase::Stopping {
            d.extend(self.recording.as_ref().and_then(|r| r.term_at));
        }
        d.extend(self.pending_sets.iter().map(|p| p.until));
        d.extend(
            self.procs
                .values()
                .filter_map(|p| p.term_wait.map(|(_, t)| t)),
        );
        d.extend(
            self.procs
                .values()
                .filter(|p| !p.sigkilled)
                .filter_map(|p| p.stop_by),
        );
        d
    }

    fn fail(&mut self, reason: String) {
        // A failure also outranks a stop that was asked for: the process may have failed
        // before it saw the request, and then the run did not end as asked.
        if matches!(
            self.outcome,
            None | Some(Outcome::Complete) | Some(Outcome::Stopped)
        ) {
            say(&format!("error: {reason}"));
            self.note(RunNote::ERROR, &format!("the run failed: {reason}"));
            self.outcome = Some(Outcome::Failed(reason));
        }
        self.begin_stop();
    }

    /// A worker that a scale-down asked to stop and that has not within `shutdown_timeout_ms`
    /// (stuck, or in a rollout longer than that) is killed, as at the run's stop: it held its
    /// slot's rollouts, and the update waited for it while the others idled. The sampler hands
    /// its rollouts to the others once it is gone.
    fn kill_scaled_down_overdue(&mut self, now: Instant) {
        for (pid, p) in &mut self.procs {
            if p.sigkilled || p.stop_by.is_none_or(|t| now < t) {
                continue;
            }
            say(&format!(
                "{} (pid {pid}), scaled down, did not stop within {} ms \
                 (pipeline.shutdown_timeout_ms); killing it: its rollouts go to the other workers",
                p.role.name(),
                self.pipe.shutdown_timeout_ms
            ));
            signal_group(*pid, libc::SIGKILL);
            p.sigkilled = true;
        }
    }

    /// Sends worker `pid` SIGTERM, once the recorder has connected to its ports if it may
    /// not have: iceoryx2 keeps what a departed publisher sent only for subscribers that had
    /// connected to it, and a recorder connects to a new publisher when it next looks, so a
    /// worker that joined while the recorder was stalled (stopped, or held in a write) would
    /// take its last costs and its announcement with it. It asks the recorder to connect
    /// (RECORDER_SYNC, answered within a millisecond by a running one) and waits at most half
    /// of `pipeline.shutdown_timeout_ms` ([`Self::release_stops`]).
    fn stop_worker(&mut self, pid: u32) {
        // A worker not yet seen to be ready may have announced itself just now: a sync sent
        // after it was started covers the ports it had by then (one sync for all of a batch).
        let Some(since) = self
            .procs
            .get(&pid)
            .map(|p| p.ready_at.unwrap_or(p.spawned_at))
        else {
            signal_group(pid, libc::SIGTERM);
            return;
        };
        let wait = Duration::from_millis(self.pipe.shutdown_timeout_ms / 2);
        // A shutdown timeout of 1 ms leaves no time to wait in.
        let sync = if !wait.is_zero() && self.recorder_listening() {
            self.recorder_sync_after(since)
        } else {
            None
        };
        match (sync, self.procs.get_mut(&pid)) {
            (Some(seq), Some(p)) => p.term_wait = Some((seq, Instant::now() + wait)),
            _ => signal_group(pid, libc::SIGTERM),
        }
    }

    fn recorder(&self) -> Option<&Proc> {
        self.role_pid(Role::Recorder)
            .and_then(|pid| self.procs.get(&pid))
    }

    /// Whether a recorder is running and will answer a RECORDER_SYNC.
    fn recorder_listening(&self) -> bool {
        self.recorder().is_some_and(|p| p.ready && !p.stopping)
    }

    /// The last update the recorder has written, and how many updates the updater's last
    /// report is ahead of it (none if there was no report; 0 if the recorder is ahead of the
    /// report, which comes every 200 ms).
    fn recorder_written(&self) -> Option<(u64, Option<u64>)> {
        // `written` is never 0 (see `drain_recorder_acks`).
        let n = self.recorder_sync.written?;
        let behind = self.progress.map(|p| p.updates.saturating_sub(n));
        Some((n - 1, behind))
    }

    /// The number of a RECORDER_SYNC sent after `t`: the one not yet carried out if it was,
    /// else a new one. `None` if it could not be sent.
    fn recorder_sync_after(&mut self, t: Instant) -> Option<u64> {
        // One sent to a recorder that has died since is never answered.
        let recorder_ready = self.recorder().and_then(|p| p.ready_at);
        if let Some((seq, at)) = self.recorder_sync.outstanding {
            if at >= t && recorder_ready.is_some_and(|r| at >= r) {
                return Some(seq);
            }
        }
        let seq = self.recorder_sync.seq + 1;
        self.send_control(Control::recorder_sync(self.run_id, seq), false)
            .ok()?;
        self.recorder_sync.seq = seq;
        self.recorder_sync.outstanding = Some((seq, Instant::now()));
        Some(seq)
    }

    /// Sends SIGTERM to the workers [`Self::stop_worker`] held back whose RECORDER_SYNC the
    /// recorder has carried out, or that waited long enough, or whose recorder is gone.
    fn release_stops(&mut self) -> anyhow::Result<()> {
        self.drain_recorder_acks()?;
        let done = self.recorder_sync.done;
        if self
            .recorder_sync
            .outstanding
            .is_some_and(|(seq, _)| seq <= done)
        {
            self.recorder_sync.outstanding = None;
        }
        let listening = self.recorder_listening();
        let now = Instant::now();
        let mut late = Vec::new();
        for (pid, p) in &mut self.procs {
            let Some((seq, until)) = p.term_wait else {
                continue;
            };
            if seq > done && listening {
                if now < until {
                    continue;
                }
                late.push(format!("{} (pid {pid})", p.role.name()));
            }
            p.term_wait = None;
            signal_group(*pid, libc::SIGTERM);
            // The whole shutdown timeout from the SIGTERM, as without the wait.
            let grace = now + Duration::from_millis(self.pipe.shutdown_timeout_ms);
            if p.stop_by.is_some() {
                p.stop_by = Some(grace);
            }
            if self.phase == Phase::Stopping {
                self.phase_deadline = self.phase_deadline.max(Some(grace));
            }
        }
        if !late.is_empty() {
            let text = format!(
                "the recorder did not say within {} ms (half pipeline.shutdown_timeout_ms) that \
                 it is connected to {}, which are stopping now: is it stalled? What they sent \
                 since they started may be missing from the recording",
                self.pipe.shutdown_timeout_ms / 2,
                late.join(", ")
            );
            say(&format!("warning: {text}"));
            self.note(RunNote::WARNING, &text);
        }
        Ok(())
    }

    /// Takes in the recorder's acknowledgements (only the newest few are kept: each carries
    /// everything this process reads of them).
    fn drain_recorder_acks(&mut self) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let sync = &mut self.recorder_sync;
        while let Some(a) = iox(ports.recorded.receive(), "receive recorder ack")? {
            let a = a.payload();
            if a.run_id == self.run_id {
                sync.done = sync.done.max(a.synced);
                // 0 comes from a recorder that has taken in no distribution yet.
                if a.next_update > 0 {
                    sync.written = sync.written.max(Some(a.next_update));
                }
            }
        }
        Ok(())
    }

    fn begin_stop(&mut self) {
        if self.phase == Phase::Stopping {
            return;
        }
        self.phase = Phase::Stopping;
        self.phase_deadline =
            Some(Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms));
        for s in self.slots.values_mut() {
            s.restart_at = None;
        }
    }

    fn check_deadlines(&mut self) {
        let now = Instant::now();
        self.kill_scaled_down_overdue(now);
        let Some(deadline) = self.phase_deadline else {
            return;
        };
        if now < deadline {
            return;
        }
        match self.phase {
            Phase::StartRecorder
            | Phase::StartUpdater
            | Phase::StartSampler
            | Phase::StartWorkers => {
                // Workers between a crash and their restart have no process to wait for.
                // A worker whose earlier processes died is named with how the last one did:
                // the cause, which the timeout alone hid in earlier lines.
                let died = |w: &u32| {
                    self.slots
                        .get(w)
                        .and_then(|s| s.last_death.as_deref())
                        .map(|d| format!("; its last attempt died: {d}"))
                        .unwrap_or_default()
                };
                let waiting: Vec<String> = self
                    .procs
                    .values()
                    .filter(|p| !p.ready)
                    .map(|p| match p.role {
                        Role::Worker(w) if !died(&w).is_empty() => {
                            format!("{} (restarted{})", p.role.name(), died(&w))
                        }
                        _ => p.role.name(),
                    })
                    .chain(
                        self.slots
                            .iter()
                            .filter(|(_, s)| s.pid.is_none())
                            .map(|(w, _)| {
                                format!("worker-{w} (waiting to be restarted{})", died(w))
                            }),
                    )
                    .collect();
                // A worker of the user's own that runs but never announces itself timed out
                // with nothing to say what "ready" is: neither the wire docs nor the README's
                // steps for a worker in another language named the announcement.
                let own_worker_waits = self.cfg.external_worker().is_some()
                    && self
                        .procs
                        .values()
                        .any(|p| !p.ready && matches!(p.role, Role::Worker(_)));
                let hint = if own_worker_waits {
                    "; a worker of your own is ready once it has built its task (a simulator \
                     that takes longer to start needs a larger pipeline.startup_timeout_ms), \
                     opened its ports, announced itself on `lifecycle` (role 3, its slot and \
                     incarnation) and rung `wake/supervisor`, as pipeline::worker::serve and \
                     tools/pi2cma_worker.py do (README, \"Wire layout\")"
                } else {
                    ""
                };
                self.fail(format!(
                    "{} did not become ready within {} ms (pipeline.startup_timeout_ms){hint}",
                    waiting.join(", "),
                    self.pipe.startup_timeout_ms
                ));
            }
            Phase::Stopping if !self.killed => {
                // The stage that was asked to stop and has not (a worker in a robot's long
                // episode, a hung one, a stuck sampler): only it is killed. The stages after it
                // are then asked in order, each with a timeout of its own, so the recorder
                // still finishes the file unless it is the one that hangs.
                let stuck: Vec<(u32, String)> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| p.stopping && !p.sigkilled)
                    .map(|(pid, p)| (*pid, format!("{} (pid {pid})", p.role.name())))
                    .collect();
                if !stuck.is_empty() {
                    let others = self.procs.values().any(|p| !p.stopping);
                    say(&format!(
                        "{} did not stop within {} ms (pipeline.shutdown_timeout_ms); killing {}{}",
                        stuck
                            .iter()
                            .map(|(_, n)| n.as_str())
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.pipe.shutdown_timeout_ms,
                        if stuck.len() == 1 { "it" } else { "them" },
                        if others {
                            ", then stopping the others in order"
                        } else {
                            ""
                        }
                    ));
                    for (pid, _) in &stuck {
                        signal_group(*pid, libc::SIGKILL);
                        if let Some(p) = self.procs.get_mut(pid) {
                            p.sigkilled = true;
                        }
                    }
                    self.phase_deadline = Some(now + Duration::from_secs(5));
                    return;
                }
                let unreaped: Vec<u32> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| p.sigkilled)
                    .map(|(pid, _)| *pid)
                    .collect();
                if !unreaped.is_empty() {
                    let names: Vec<String> = unreaped
                        .iter()
                        .map(|pid| self.procs[pid].role.name())
                        .collect();
                    say(&format!(
                        "giving up waiting for {} after SIGKILL",
                        names.join(", ")
                    ));
                    for pid in unreaped {
                        self.procs.remove(&pid);
                    }
                }
                // The next stage sets its own deadline when it is asked (or the recorder's
                // `term_at` wakes the loop).
                self.phase_deadline = None;
            }
            Phase::Stopping => {
                // Killed processes that still have not been reaped: nothing more to do.
                let names: Vec<String> = self.procs.values().map(|p| p.role.name()).collect();
                say(&format!(
                    "giving up waiting for {} after SIGKILL",
                    names.join(", ")
                ));
                self.procs.clear();
            }
            Phase::Running => self.phase_deadline = None,
        }
    }

    fn kill_all(&mut self) {
        self.killed = true;
        for pid in self.procs.keys() {
            signal_group(*pid, libc::SIGKILL);
        }
    }

    /// Waits (bounded) for the exits of killed processes.
    fn reap(&mut self, rx: &Receiver<Event>, bound: Duration) {
        let end = Instant::now() + bound;
        while !self.procs.is_empty() {
            match rx.recv_timeout(end.saturating_duration_since(Instant::now())) {
                Ok(Event::Exited { pid, .. }) => {
                    self.procs.remove(&pid);
                    self.spawned.reaped(pid, Instant::now());
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
    }

    fn role_pid(&self, role: Role) -> Option<u32> {
        self.procs
            .iter()
            .find(|(_, p)| p.role == role)
            .map(|(pid, _)| *pid)
    }

    fn role_ready(&self, role: Role) -> bool {
        self.procs.values().any(|p| p.role == role && p.ready)
    }

    fn advance(&mut self) -> anyhow::Result<()> {
        let startup = Duration::from_millis(self.pipe.startup_timeout_ms);
        match self.phase {
            Phase::StartRecorder => {
                if self.role_pid(Role::Recorder).is_none() {
                    self.spawn(Role::Recorder, 0)?;
                    self.phase_deadline = Some(Instant::now() + startup);
                } else if self.role_ready(Role::Recorder) {
                    // Subscribed to every service: nothing the updater publishes is missed.
                    self.phase = Phase::StartUpdater;
                    return self.advance();
                }
            }
            Phase::StartUpdater => {
                if self.role_pid(Role::Updater).is_none() {
                    self.spawn(Role::Updater, 0)?;
                    self.phase_deadline = Some(Instant::now() + startup);
                } else if self.role_ready(Role::Updater) {
                    self.spawn(Role::Sampler, 0)?;
                    self.phase = Phase::StartSampler;
                    self.phase_deadline = Some(Instant::now() + startup);
                }
            }
            Phase::StartSampler => {
                if self.role_ready(Role::Sampler) {
                    self.phase = Phase::StartWorkers;
                    self.phase_deadline = Some(Instant::now() + startup);
                    self.apply_scale()?;
                }
            }
            Phase::StartWorkers | Phase::Running => {
                self.restart_due();
                if self.phase == Phase::StartWorkers {
                    let workers: Vec<&Proc> = self
                        .procs
                        .values()
                        .filter(|p| matches!(p.role, Role::Worker(_)))
                        .collect();
                    // Slots joined workers hold were skipped: ours are the slots we filled.
                    if workers.len() >= self.slots.len().min(self.target_workers)
                        && workers.iter().all(|p| p.ready)
                    {
                        self.send_control(Control::plain(self.run_id, Control::START), true)?;
                        self.phase = Phase::Running;
                        self.last_update_at = Some(Instant::now());
                        self.phase_deadline = None;
                        say(&format!(
                            "all {} processes ready after {} ms; run started",
                            self.procs.len(),
                            self.started.elapsed().as_millis()
                        ));
                    }
                }
            }
            Phase::Stopping => {
                // Reverse start order: workers, then the sampler, then the updater, then the
                // recorder.
                let workers: Vec<u32> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| matches!(p.role, Role::Worker(_)))
                    .map(|(pid, _)| *pid)
                    .collect();
                let stage = if !workers.is_empty() {
                    workers
                } else if let Some(pid) = self.role_pid(Role::Sampler) {
                    vec![pid]
                } else if let Some(pid) = self.role_pid(Role::Updater) {
                    vec![pid]
                } else if let Some(pid) = self.role_pid(Role::Recorder) {
                    // After a complete run it exits by itself once it has written the final
                    // update; SIGTERM (which finishes the file with everything received)
                    // only if it has not done so within half the shutdown timeout.
                    let complete = self.outcome == Some(Outcome::Complete);
                    let half = Duration::from_millis(self.pipe.shutdown_timeout_ms / 2);
                    let rec = self.recording.as_mut().expect("a recorder has a recording");
                    let due = *rec.term_at.get_or_insert_with(|| {
                        Instant::now() + if complete { half } else { Duration::ZERO }
                    });
                    if Instant::now() >= due {
                        vec![pid]
                    } else {
                        vec![]
                    }
                } else {
                    vec![]
                };
                let mut asked = false;
                for pid in stage {
                    let p = self.procs.get_mut(&pid).expect("pid from procs");
                    if !p.stopping {
                        p.stopping = true;
                        asked = true;
                        if matches!(p.role, Role::Worker(_)) {
                            self.stop_worker(pid);
                        } else {
                            signal_group(pid, libc::SIGTERM);
                        }
                    }
                }
                // Each stage has `shutdown_timeout_ms` of its own, from when it is asked.
                if asked {
                    self.phase_deadline =
                        Some(Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms));
                }
            }
        }
        Ok(())
    }

    /// Restarts the workers whose backoff has passed.
    fn restart_due(&mut self) {
        let now = Instant::now();
        let due: Vec<u32> = self
            .slots
            .iter()
            .filter(|(_, s)| s.restart_at.is_some_and(|t| t <= now))
            .map(|(w, _)| *w)
            .collect();
        for w in due {
            let inc = {
                let s = self.slots.get_mut(&w).expect("due slot exists");
                s.restart_at = None;
                s.incarnation += 1;
                s.incarnation
            };
            if let Err(e) = self.spawn(Role::Worker(w), inc) {
                self.fail(format!("cannot restart worker-{w}: {e:#}"));
            }
        }
    }

    /// Who holds worker slot `w`: a worker this supervisor runs there, or a live one that
    /// joined the run from outside.
    fn slot_holder(&self, w: u32) -> Option<String> {
        if let Some(slot) = self.slots.get(&w) {
            return Some(match slot.pid {
                Some(pid) => format!("worker-{w} (pid {pid}, started by the supervisor)"),
                None => format!("worker-{w} (started by the supervisor, being restarted)"),
            });
        }
        self.joined_in(w)
            .map(|pid| format!("worker-{w} (pid {pid}, joined from outside)"))
    }

    /// The pid of a live worker that joined the run from outside in slot `w`.
    fn joined_in(&self, w: u32) -> Option<u32> {
        self.live_joined()
            .find(|(_, slot)| *slot == w)
            .map(|(pid, _)| pid)
    }

    /// Says when a worker that joined from outside is gone, on the console and in the
    /// recording: its start is there (its announcement), and nobody else reports its end (the
    /// sampler hands its rollouts on by itself). Also keeps the map from growing over a long
    /// run with workers coming and going. At most once a second: it reads `/proc`.
    fn check_joined(&mut self) {
        if self.joined.is_empty()
            || self.phase == Phase::Stopping
            || self.joined_checked.elapsed() < Duration::from_secs(1)
        {
            return;
        }
        self.joined_checked = Instant::now();
        let gone: Vec<(u32, u32)> = self
            .joined
            .iter()
            .filter(|(pid, (_, started))| !still_runs(**pid, *started))
            .map(|(pid, (w, _))| (*pid, *w))
            .collect();
        for (pid, w) in gone {
            self.joined.remove(&pid);
            let msg = format!(
                "worker-{w} (pid {pid}), which joined from outside, is gone; the sampler hands \
                 its rollouts to the other workers"
            );
            say(&msg);
            self.note(RunNote::WARNING, &msg);
        }
    }

    /// (pid, slot) of the workers that joined from outside and still run. A pid alone is not
    /// enough: in a run of days an unrelated process can get a gone worker's pid and would hold
    /// its slot.
    fn live_joined(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.joined
            .iter()
            .filter(|(pid, (_, started))| still_runs(**pid, *started))
            .map(|(pid, (slot, _))| (*pid, *slot))
    }

    /// Starts or stops workers until `target_workers` run (lowest free slots first; the highest
    /// slots are stopped first).
    fn apply_scale(&mut self) -> anyhow::Result<()> {
        let live: Vec<u32> = self.slots.keys().copied().collect();
        if live.len() < self.target_workers {
            let mut w = 0;
            // Slots that joined workers hold are skipped: a second worker there would run the
            // same rollouts.
            while self.slots.len() < self.target_workers && (w as usize) < self.pipe.max_workers {
                if self.joined_in(w).is_none() && !self.slots.contains_key(&w) {
                    // A worker a scale-down stopped may still be finishing its rollout in this
                    // slot: the new one comes after it, or the sampler would take the new one's
                    // announcement for the old one's and its loss for the new one's.
                    let incarnation = self
                        .procs
                        .values()
                        .filter(|p| p.role == Role::Worker(w))
                        .map(|p| p.incarnation + 1)
                        .max()
                        .unwrap_or(0);
                    self.slots.insert(
                        w,
                        Slot {
                            incarnation,
                            ..Slot::default()
                        },
                    );
                    self.spawn(Role::Worker(w), incarnation)?;
                }
                w += 1;
            }
            if self.slots.len() < self.target_workers {
                say(&format!(
                    "{} of {} workers started: the other slots below pipeline.max_workers = {} \
                     are held by workers that joined from outside",
                    self.slots.len(),
                    self.target_workers,
                    self.pipe.max_workers
                ));
            }
        } else {
            for w in live
                .into_iter()
                .rev()
                .take(self.slots.len() - self.target_workers)
            {
                let slot = self.slots.remove(&w).expect("live slot");
                if let Some(pid) = slot.pid {
                    if let Some(p) = self.procs.get_mut(&pid) {
                        p.stopping = true;
                        p.stop_by = Some(
                            Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms),
                        );
                        self.stop_worker(pid);
                    }
                }
            }
        }
        Ok(())
    }

    /// Where a resumed run's state is handed to the updater.
    fn start_file(&self) -> PathBuf {
        self.run_dir.join("start.toml")
    }

    fn spawn(&mut self, role: Role, incarnation: u32) -> anyhow::Result<()> {
        let (exe, leading) = self.launcher.program(role);
        let mut cmd = Command::new(&exe);
        cmd.args(leading)
            .arg("--config")
            .arg(&self.config_file)
            .arg("--run-dir")
            .arg(&self.run_dir)
            .arg("--run-id")
            .arg(wire::run_id_hex(self.run_id));
        if let (Role::Recorder, Some(rec)) = (role, &self.recording) {
            cmd.arg("--out").arg(std::path::absolute(&rec.path)?);
            if let Some(start) = &self.start {
                cmd.arg("--resumed-from")
                    .arg(&start.origin)
                    .arg("--start")
                    .arg(self.start_file());
            }
            if let Some(part) = rec.continue_in {
                cmd.arg("--part")
                    .arg(part.to_string())
                    .arg("--restart")
                    .arg(rec.restarted.to_string());
            }
        }
        if let (Role::Updater, Some(_)) = (role, &self.start) {
            cmd.arg("--start").arg(self.start_file());
        }
        if let Role::Worker(w) = role {
            cmd.arg("--worker")
                .arg(w.to_string())
                .arg("--incarnation")
                .arg(incarnation.to_string());
        }
        let (reader, writer) = std::io::pipe()?;
        cmd.stdin(Stdio::null())
            .stdout(writer.try_clone()?)
            .stderr(writer)
            .process_group(0);
        die_with_parent(&mut cmd);
        let mut child = cmd
            .spawn()
            .with_context(|| format!("cannot start {} ({})", role.name(), exe.display()))?;
        drop(cmd); // closes our copies of the pipe's write end
        let pid = child.id();
        let last_line = Arc::new(Mutex::new(String::new()));
        let name = role.name();
        let last = last_line.clone();
        let printer = std::thread::Builder::new()
            .name(format!("out-{name}"))
            .spawn(move || {
                // The reason a process died: its last error line, else its last line (after
                // `error: …`, clap adds "For more information, try '--help'.").
                let mut seen_error = false;
                for line in BufReader::new(reader).lines() {
                    let Ok(line) = line else { break };
                    print_line(&name, &line);
                    let error = line.trim_start().to_ascii_lowercase().starts_with("error");
                    if error || !seen_error {
                        if let Ok(mut l) = last.lock() {
                            *l = line;
                        }
                    }
                    seen_error |= error;
                }
            })?;
        let tx = self.tx.clone();
        std::thread::Builder::new()
            .name(format!("wait-{pid}"))
            .spawn(move || {
                let status = child.wait();
                let _ = printer.join(); // the child's last words are printed before its exit
                if let Ok(status) = status {
                    let _ = tx.send(Event::Exited { pid, status });
                }
            })?;
        self.spawned.started(pid);
        self.procs.insert(
            pid,
            Proc {
                role,
                incarnation,
                ready: false,
                stopping: false,
                sigkilled: false,
                stop_by: None,
                hung: None,
                spawned_at: Instant::now(),
                ready_at: None,
                term_wait: None,
                last_line,
            },
        );
        if let Role::Worker(w) = role {
            self.slots.entry(w).or_default().pid = Some(pid);
        }
        Ok(())
    }

    /// Puts `text` into the recording (the recorder logs it as the supervisor's), if there are
    /// ports and a recorder to take it; never a reason to fail.
    fn note(&self, level: u32, text: &str) {
        if let Some(ports) = &self.ports {
            let _ = ports
                .notes
                .send_copy(RunNote::new(self.run_id, level, text));
            let _ = ports.recorder_bell.notify_with_custom_event_id(wire::WAKE);
        }
    }

    /// A restarted recorder has announced itself: the updater holds back for it again.
    fn recorder_back(&mut self) -> anyhow::Result<()> {
        let Some(rec) = self.recording.as_mut() else {
            return Ok(());
        };
        let Some(death) = rec.back_pending.take() else {
            return Ok(());
        };
        // Not the last part there is: the new one is created with its first update.
        let part = rec
            .continued_part()
            .unwrap_or_else(|| record::last_part(&rec.path));
        self.note(RunNote::WARNING, &death);
        self.send_control(Control::plain(self.run_id, Control::RECORDER_BACK), true)?;
        say(&format!(
            "recorder restarted: recording to {}",
            part.display()
        ));
        Ok(())
    }

    fn send_control(&self, msg: Control, to_updater: bool) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let sent = ports.control_sent.get() + 1;
        ports.control_sent.set(sent);
        iox(
            ports.control.send_copy(Control { sent, ..msg }),
            "send control",
        )?;
        let bell = if to_updater {
            &ports.updater_bell
        } else {
            &ports.sampler_bell
        };
        iox(bell.notify_with_custom_event_id(wire::WAKE), "notify")?;
        // Only so that the recorder logs the message at once (it drains its subscribers every
        // tick anyway); a recorder that has gone is no reason to fail.
        let _ = ports.recorder_bell.notify_with_custom_event_id(wire::WAKE);
        Ok(())
    }

    fn poll_ports(&mut self) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let mut ready = Vec::new();
        while let Some(s) = iox(ports.lifecycle.receive(), "receive lifecycle")? {
            ready.push(*s.payload());
        }
        let mut progress = Vec::new();
        while let Some(s) = iox(ports.progress.receive(), "receive progress")? {
            progress.push(*s.payload());
        }
        let mut overdue = Vec::new();
        while let Some(s) = iox(ports.overdue.receive(), "receive overdue")? {
            overdue.push(*s.payload());
        }
        let run_id = self.run_id;
        for o in overdue.into_iter().filter(|o| o.run_id == run_id) {
            self.kill_hung(o);
        }
        for l in ready {
            if l.run_id != self.run_id {
                continue;
            }
            if let Some(p) = self.procs.get_mut(&l.pid) {
                p.ready = true;
                p.ready_at.get_or_insert_with(Instant::now);
                if p.role == Role::Recorder {
                    self.recorder_back()?;
                }
            } else if l.role == wire::role::WORKER && !self.spawned.ours(l.pid, Instant::now()) {
                if let Some(holder) = self.slot_holder(l.worker) {
                    // Both would take slot w's work: every rollout of it would run twice (on a
                    // robot, twice for real). The newcomer is the mistake.
                    let msg = format!(
                        "worker-{w} (pid {pid}) joined slot {w}, which {holder} holds: both \
                         would run its rollouts; stopping pid {pid} (SIGTERM). Start a worker \
                         of your own in a free slot (see `supervisor status`)",
                        w = l.worker,
                        pid = l.pid
                    );
                    say(&format!("WARNING: {msg}"));
                    self.note(RunNote::WARNING, &msg);
                    signal_process(l.pid, libc::SIGTERM);
                    continue;
                }
                // A worker the user started (a robot's driver, a debugger session): not ours
                // to stop or restart, but part of the run.
                let Some(started) = process_started(l.pid) else {
                    continue; // gone already: the sampler hands its rollouts on
                };
                say(&format!(
                    "worker-{} (pid {}) joined the run (started outside the supervisor)",
                    l.worker, l.pid
                ));
                self.joined.insert(l.pid, (l.worker, started));
            }
        }
        for p in progress {
            if p.run_id != self.run_id {
                continue;
            }
            if p.flags & Progress::TASK_CHANGE != 0 {
                // The updater takes changes in order, so those before it are due no later.
                for (seq, _, _, from) in &mut self.unreflected_sets {
                    if *seq <= p.last_change_seq && from.is_none() {
                        *from = Some(p.last_change_from);
                    }
                }
                self.answer_sets(p.last_change_seq, Some(p.last_change_from), false);
                continue;
            }
            // A report's settings are those of its next update, `updates`.
            self.unreflected_sets
                .retain(|(_, _, _, from)| from.is_none_or(|f| f > p.updates));
            if self.progress.is_none_or(|prev| p.updates > prev.updates) {
                // A stopping updater's last report is no news of updates going on.
                if self.stall_reported && p.flags & Progress::FINAL == 0 {
                    say(&format!(
                        "updates go on: update {} after {:.1} s without one",
                        p.updates,
                        self.last_update_at
                            .map_or(0.0, |t| t.elapsed().as_secs_f64())
                    ));
                }
                self.last_update_at = Some(Instant::now());
                self.stall_reported = false;
            }
            if self.rates.is_empty() {
                // A resumed run counts its updates from where it resumed.
                self.rates
                    .add(self.start.as_ref().map_or(0, |s| s.update), 0);
            }
            self.rates.add(p.updates, p.elapsed_ns);
            if let Some(rate) = self.rates.rate() {
                self.rate = rate;
            }
            self.progress = Some(p);
            // At most one line a second, plus one at every tenth of a bounded run.
            let tenth = self
                .cfg
                .run
                .updates
                .is_some_and(|n| p.updates % (n / 10).max(1) == 0);
            let due = tenth
                || self
                    .last_shown
                    .is_none_or(|t| t.elapsed() >= Duration::from_secs(1));
            if !self.quiet && due {
                self.last_shown = Some(Instant::now());
                say(&self.progress_line());
            }
        }
        Ok(())
    }

    /// Kills the worker incarnation the sampler reports as hung; [`Self::exited`] then reports it
    /// lost (reason HUNG) and restarts it like a crashed one.
    fn kill_hung(&mut self, o: Overdue) {
        let per_rollout = self.pipe.rollout_timeout_ms.unwrap_or(0);
        let why = format!(
            "hung: no rollout done for {} ms, over pipeline.rollout_timeout_ms = {per_rollout} (held {} rollout(s) of update {} for {} ms)",
            o.stalled_ms, o.rollouts, o.update, o.held_ms
        );
        // Ours also when a scale-down has taken its slot away: asked to stop, a hung worker
        // does not, and would stay, holding its rollouts, until the run ends.
        let ours = self
            .procs
            .iter_mut()
            .find(|(_, p)| p.role == Role::Worker(o.worker) && p.incarnation == o.incarnation);
        let Some((&pid, p)) = ours else {
            if self.joined_in(o.worker).is_some() && !self.slots.contains_key(&o.worker) {
                // A worker that joined the run by itself: the sampler has handed its rollouts on.
                say(&format!(
                    "worker-{} (incarnation {}, not started by this supervisor) {why}; its rollouts went to the other workers",
                    o.worker, o.incarnation
                ));
            }
            return; // already gone
        };
        if (p.stopping && self.phase == Phase::Stopping) || p.hung.is_some() {
            return; // going (the shutdown's timeout bounds it), or being killed
        }
        say(&format!(
            "worker-{} (pid {pid}) {why}; killing it",
            o.worker
        ));
        p.hung = Some(why);
        signal_group(pid, libc::SIGKILL);
    }

    fn progress_line(&self) -> String {
        // A resumed run counts from where it resumed; before its first update there is no
        // eval cost to show (the updater reports NaN).
        let first = self.start.as_ref().map_or(0, |s| s.update);
        let Some(p) = self.progress.filter(|p| p.updates > first) else {
            return "no update finished yet".into();
        };
        let of = self
            .cfg
            .run
            .updates
            .map_or("∞".to_string(), |n| n.to_string());
        // While stopping, the workers are going: their count says nothing about the run.
        let workers = if self.phase == Phase::Stopping {
            String::new()
        } else {
            format!("  {} workers", self.worker_count())
        };
        format!(
            "update {}/{of}  eval cost {}  λ now {}  {:.0} updates/s{workers}",
            p.updates,
            reading(p.eval_cost),
            reading(p.lambda),
            self.rate,
        )
    }

    fn worker_count(&self) -> usize {
        self.procs
            .values()
            .filter(|p| matches!(p.role, Role::Worker(_)) && !p.stopping)
            .count()
    }

    fn handle(&mut self, ev: Event) -> anyhow::Result<()> {
        match ev {
            Event::Bell => Ok(()),
            Event::Signal => {
                if self.phase == Phase::Stopping {
                    say("second signal: killing the group now");
                    self.kill_all();
                } else {
                    say("signal received: stopping (again to kill at once)");
                    if self.outcome.is_none() {
                        self.outcome = Some(Outcome::Interrupted);
                    }
                    self.begin_stop();
                }
                Ok(())
            }
            Event::Command((Cmd::Set(name, value), reply)) => {
                match self.set_task(&name, value) {
                    Ok(seq) => self.pending_sets.push(PendingSet {
                        seq,
                        name: name.clone(),
                        what: format!("{name} = {}", tasks::value_text(value)),
                        reply,
                        until: Instant::now() + SET_REPLY_WAIT,
                    }),
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Event::Command((cmd, reply)) => {
                let r = self.command(cmd);
                let _ = reply.send(r);
                Ok(())
            }
            Event::Exited { pid, status } => {
                self.exited(pid, status);
                Ok(())
            }
        }
    }

    fn command(&mut self, cmd: Cmd) -> Result<String, String> {
        match cmd {
            Cmd::Status => {
                // The recorder's progress as of now, not of the last loop round.
                self.drain_recorder_acks().map_err(|e| format!("{e:#}"))?;
                Ok(self.status())
            }
            Cmd::Stop => {
                if self.outcome.is_none() {
                    self.outcome = Some(Outcome::Stopped);
                }
                self.begin_stop();
                Ok("stopping".into())
            }
            Cmd::Scale(n) => {
                if self.phase == Phase::Stopping {
                    return Err("the run is stopping".into());
                }
                if !(1..=self.pipe.max_workers).contains(&n) {
                    return Err(format!(
                        "cannot scale to {n} workers: must be between 1 and pipeline.max_workers = {}",
                        self.pipe.max_workers
                    ));
                }
                let was = self.target_workers;
                if n > was && !self.no_shm_check {
                    let reruns = self.cfg.run.nonfinite_reruns > 0;
                    let ports = (self.recording.is_some(), reruns);
                    shm::check_scale(&self.limits, ports, was, n)?;
                }
                self.target_workers = n;
                if matches!(self.phase, Phase::StartWorkers | Phase::Running) {
                    self.apply_scale().map_err(|e| format!("{e:#}"))?;
                }
                say(&format!("scaling from {was} to {n} workers"));
                Ok(format!("scaling from {was} to {n} workers"))
            }
            Cmd::Set(..) => Err("internal: `set` is answered by `set_task`".into()),
            Cmd::Record => self.record_again(),
        }
    }

    /// `supervisor record`: a recorder again, after the run's died and was not restarted (it
    /// stopped at an error of its own, such as a full disk, or the restart limit was used up).
    fn record_again(&mut self) -> Result<String, String> {
        if self.phase != Phase::Running {
            return Err("the run is not running (starting or stopping)".into());
        }
        let Some(rec) = self.recording.as_ref() else {
            return Err("this run has no recording (--no-record)".into());
        };
        if let Some(pid) = self.role_pid(Role::Recorder) {
            return Err(format!("the recorder is running (pid {pid})"));
        }
        let cause = rec.lost.clone().unwrap_or_else(|| "it exited".into());
        let (next, restart, recovery) = self
            .continue_recording(|dead| {
                format!(
                    "the recording started again (`supervisor record`) after the recorder died \
                     ({cause}); {} holds it up to where it died (recovered by the supervisor)",
                    dead.display()
                )
            })
            .map_err(|e| format!("cannot start the recorder: {e:#}"))?;
        if let Some(rec) = self.recording.as_mut() {
            rec.lost = None;
        }
        let text = format!(
            "recorder started again (restart {restart}): the recording goes on in {}, and \
             {recovery}; the updates since the recorder died are not recorded",
            next.display()
        );
        say(&text);
        Ok(text)
    }

    /// The task settings a change sent now joins: the updater's last report (before the first,
    /// the settings the run started with), then the changes sent since that it does not show.
    /// Scheduled changes still ahead are not included: one is checked when the config is.
    fn settings_in_force(&self) -> Vec<(String, f64)> {
        let mut settings: Vec<(String, f64)> = match (&self.progress, &self.start) {
            (Some(p), _) => self.reported_settings(p),
            (None, Some(start)) => start.settings.clone(),
            (None, None) => Vec::new(),
        };
        settings.extend(
            self.unreflected_sets
                .iter()
                .map(|(_, n, v, _)| (n.clone(), *v)),
        );
        settings
    }

    /// A progress report's settings, by name.
    fn reported_settings(&self, p: &Progress) -> Vec<(String, f64)> {
        let names = self
            .cfg
            .build_task()
            .map(|t| t.settings())
            .unwrap_or_default();
        named_settings(&names, p)
    }

    /// Sends a task change to the updater; returns its number, which the updater's
    /// [`Progress::TASK_CHANGE`] answer carries.
    fn set_task(&mut self, name: &str, value: f64) -> Result<u64, String> {
        if self.phase == Phase::Stopping {
            return Err("the run is stopping".into());
        }
        self.cfg
            .check_task_change(&self.settings_in_force(), name, value)
            .map_err(|e| e.to_string())?;
        // The control service keeps no history: a change sent before the updater subscribed
        // would be lost.
        if !self.role_ready(Role::Updater) {
            return Err("the updater is not running yet: try again in a moment".into());
        }
        // A number is never reused, even when the send fails after the message went out (the
        // bell), so the updater's echo names exactly one request.
        self.task_change_seq += 1;
        let seq = self.task_change_seq;
        let msg = Control::set_task(self.run_id, seq, name, value)
            .ok_or_else(|| format!("setting name `{name}` is too long"))?;
        self.send_control(msg, true).map_err(|e| format!("{e:#}"))?;
        self.unreflected_sets
            .push((seq, name.to_string(), value, None));
        say(&format!(
            "task change {name} = {} sent to the updater",
            tasks::value_text(value)
        ));
        Ok(seq)
    }

    /// Answers the `supervisor set` requests the updater has taken (those numbered up to `taken`,
    /// the last from update `from`), and, with `flush`, all others: those it has not answered in
    /// [`SET_REPLY_WAIT`] or at all.
    fn answer_sets(&mut self, taken: u64, from: Option<u64>, flush: bool) {
        let now = Instant::now();
        let ends_before = self.cfg.run.updates;
        // Only the workers know their own task's limits: say where a refusal would show.
        let may_refuse = if matches!(self.cfg.task, session::TaskSection::External(_)) {
            "; the workers' task may still refuse it (`supervisor status` then says so)"
        } else {
            ""
        };
        let schedule = self.cfg.schedule();
        let answered = &mut self.answered_sets;
        self.pending_sets.retain(|p| {
            let reply = match from {
                Some(u) if p.seq == taken && ends_before.is_some_and(|n| u >= n) => format!(
                    "{}: would take effect from update {u}, but the run ends after update {} \
                     (0-based): it will not take effect",
                    p.what,
                    ends_before.unwrap_or(u).saturating_sub(1)
                ),
                Some(u) if p.seq == taken => {
                    // Changes of one setting due from one update are applied in order, the
                    // schedule's first: only the last is in force for that update, and listed
                    // (the updater prints the override).
                    let replaced = answered
                        .iter()
                        .rev()
                        .find(|(name, from, _)| *name == p.name && *from == u)
                        .map(|(_, _, what)| what.clone())
                        .or_else(|| {
                            schedule.at(u).filter(|c| c.name == p.name).last().map(|c| {
                                format!(
                                    "{} = {} (schedule)",
                                    c.name,
                                    tasks::value_text(c.value)
                                )
                            })
                        })
                        .map(|what| {
                            format!(", replacing {what}, which was due from the same update")
                        })
                        .unwrap_or_default();
                    answered.push_back((p.name.clone(), u, p.what.clone()));
                    if answered.len() > 16 {
                        answered.pop_front();
                    }
                    format!(
                        "{}: takes effect from update {u} (0-based){replaced}{may_refuse}",
                        p.what
                    )
                }
                // Taken, but its answer was overtaken by a later change's.
                _ if p.seq <= taken => format!(
                    "{}: takes effect at the next update the updater starts (it prints and records the index)",
                    p.what
                ),
                _ if flush || now >= p.until => format!(
                    "{}: sent to the updater, which has not answered{}; if it takes the change, it prints and records the update it takes effect from",
                    p.what,
                    if flush {
                        " before the run stopped".to_string()
                    } else {
                        format!(" in {} s", SET_REPLY_WAIT.as_secs())
                    }
                ),
                _ => return true,
            };
            let _ = p.reply.send(Ok(reply));
            false
        });
    }

    fn status(&self) -> String {
        let mut s = format!(
            "run {} ({}), {:?} for {:.1} s\n",
            wire::run_id_hex(self.run_id),
            self.cfg.run.name,
            self.phase,
            self.started.elapsed().as_secs_f64()
        );
        let joined: Vec<(u32, u32)> = self.live_joined().collect();
        s += &format!(
            "workers: {} running (target {}, max {}){}, restarts {}\n",
            self.worker_count(),
            self.target_workers,
            self.pipe.max_workers,
            if !joined.is_empty() {
                format!(", and {} joined from outside", joined.len())
            } else {
                String::new()
            },
            self.total_restarts
        );
        s += &match &self.recording {
            Some(r) if r.lost.is_some() => format!(
                "recording: {} (recorder died; `supervisor record` starts it again in a new part, \
                 or recover the file after the run)\n",
                record::last_part(&r.path).display()
            ),
            // A split recording: the part being written is the last that exists.
            Some(r) => {
                let restarted = match (r.restarted, r.continue_in) {
                    (0, _) => String::new(),
                    // Its part is created with the first update it records.
                    (n, Some(part)) if r.continued_part().is_some_and(|p| !p.exists()) => {
                        format!(
                            " (the recorder was restarted {n} time(s); it goes on in part {part} \
                             from the next update)"
                        )
                    }
                    (n, _) => format!(" (the recorder was restarted {n} time(s))"),
                };
                // A stalled recorder holds the updater back: this says which of the two lags.
                let written = match self.recorder_written() {
                    None => String::new(),
                    Some((last, behind)) => format!(
                        "; written through update {last}{}",
                        match behind {
                            None => String::new(),
                            Some(0) => ", up to date".to_string(),
                            Some(n) => format!(", {n} behind the updater"),
                        }
                    ),
                };
                // By its number: earlier parts may have been archived meanwhile.
                let last = record::last_part(&r.path);
                match record::part_number(&last) {
                    1 => format!("recording: {}{restarted}{written}\n", last.display()),
                    n => format!(
                        "recording: {}, part {n} of the recording begun in {}{restarted}{written}\n",
                        last.display(),
                        r.path.display()
                    ),
                }
            }
            None => "recording: off (--no-record)\n".to_string(),
        };
        for (pid, w) in &joined {
            s += &format!("  worker-{w} pid {pid} (joined; not started by the supervisor)\n");
        }
        for (pid, p) in &self.procs {
            s += &format!(
                "  {} pid {pid} incarnation {}{}{}\n",
                p.role.name(),
                p.incarnation,
                if p.ready { "" } else { " (starting)" },
                if p.stopping { " (stopping)" } else { "" }
            );
        }
        match &self.progress {
            Some(p) => {
                // Named once: it builds the task for its setting names.
                let named = self.reported_settings(p);
                let settings = tasks::settings_text(named.iter().map(|(n, v)| (n, *v)));
                let refused = match p.refused {
                    0 => String::new(),
                    n => format!(
                        "refused by the workers' task: {n} change{} (the last: {} = {} at \
                         update {})\n",
                        plural(u64::from(n)),
                        named
                            .get(p.last_refused_setting as usize)
                            .map_or("?", |(name, _)| name.as_str()),
                        tasks::value_text(p.last_refused_value),
                        p.last_refused_update
                    ),
                };
                // The updater reports every 200 ms; the recorder acknowledges each update it
                // writes, so it can be ahead of the report, and "written through update 16" above
                // "updates: 15" read as a contradiction.
                let updates = p.updates.max(self.recorder_sync.written.unwrap_or(0));
                s += &format!(
                    "updates: {} of {}, {:.1} updates/s, the last {:.1} s ago\ncurrent cost: {}\nlambda: {}\ntask: {}\n{refused}",
                    updates,
                    self.cfg
                        .run
                        .updates
                        .map_or("unbounded".to_string(), |n| n.to_string()),
                    self.rate,
                    self.last_update_at
                        .map_or(0.0, |t| t.elapsed().as_secs_f64()),
                    reading(p.eval_cost),
                    reading(p.lambda),
                    settings
                );
            }
            None => s += "updates: 0\n",
        }
        s
    }

    fn exited(&mut self, pid: u32, status: ExitStatus) {
        self.spawned.reaped(pid, Instant::now());
        let Some(p) = self.procs.remove(&pid) else {
            return;
        };
        // Processes read the copy of the config in the run directory; the user knows theirs.
        let last = p
            .last_line
            .lock()
            .map(|l| {
                l.replace(
                    &self.config_file.display().to_string(),
                    &self.cfg.origin.display().to_string(),
                )
            })
            .unwrap_or_default();
        let cause = match (&p.hung, last.is_empty()) {
            (Some(_), _) => format!("{status}, killed after it hung"),
            (None, true) => status.to_string(),
            // The last line may be an error or only news ("recording continues in …"): label it,
            // so it does not read as the cause.
            (None, false) => format!("{status}; its last output: {last}"),
        };
        let cause = match sigbus_hint(
            status,
            shm::space(Path::new(SHM_DIR)).map(|s| (s.free, s.total)),
        ) {
            Some(hint) => format!("{cause}; {hint}"),
            None => cause,
        };
        match p.role {
            Role::Worker(w) => {
                // Its slot may have been given to a new worker after a scale-down stopped it.
                let own_slot = self.slots.get(&w).is_some_and(|s| s.pid == Some(pid));
                let reason = if p.hung.is_some() {
                    wire::lost::HUNG
                } else if !own_slot {
                    wire::lost::SCALED_DOWN
                } else if p.stopping || self.phase == Phase::Stopping {
                    wire::lost::STOPPED
                } else if status.success() {
                    wire::lost::EXITED
                } else {
                    wire::lost::CRASHED
                };
                let how = status.to_string();
                let lost = Control::worker_lost(self.run_id, w, p.incarnation, pid, reason, &how);
                let _ = self.send_control(lost, false);
                let Some(slot) = self.slots.get_mut(&w).filter(|_| own_slot) else {
                    return; // scaled away
                };
                slot.pid = None;
                slot.last_death = Some(cause.clone());
                if p.stopping || self.phase == Phase::Stopping {
                    return;
                }
                if status.code() == Some(i32::from(wire::EXIT_CONFIG_REFUSED)) {
                    self.fail(format!(
                        "worker-{w} refused the config, not restarted ({cause})"
                    ));
                    return;
                }
                // One that exits before it has announced itself ran nothing: a start that
                // failed, restarted as such (taken for a stop, it ended the run with exit 0).
                if status.success() && p.ready {
                    self.exited_on_purpose(w, pid, &cause);
                    return;
                }
                let now = Instant::now();
                if !may_restart(&mut slot.restarts, &self.pipe, now) {
                    let n = slot.restarts.len();
                    self.fail(format!(
                        "worker-{w} died ({cause}) after {n} restarts within {} s: restart limit (pipeline.restart_limit = {}) exhausted",
                        self.pipe.restart_window_s, self.pipe.restart_limit
                    ));
                    return;
                }
                slot.restarts.push_back(now);
                let backoff = restart_backoff(slot.restarts.len());
                slot.restart_at = Some(now + backoff);
                self.total_restarts += 1;
                say(&format!(
                    "worker-{w} (pid {pid}) died ({cause}); its rollouts go to the others; restart {} of {} in {} ms",
                    slot.restarts.len(),
                    self.pipe.restart_limit,
                    backoff.as_millis()
                ));
            }
            Role::Updater => {
                if self.phase == Phase::Stopping && (p.stopping || self.killed) {
                    // Told to stop, it exits 0 (or is killed at the shutdown timeout); exit
                    // code 1 is an error of its own, such as a cost it refused just before.
                    if status.code() == Some(1) {
                        self.fail(format!("updater exited ({cause})"));
                    }
                    return;
                }
                if status.success() && self.phase == Phase::Running {
                    if self.outcome.is_none() {
                        self.outcome = Some(Outcome::Complete);
                    }
                    self.begin_stop();
                } else {
                    self.fail(format!("updater exited ({cause})"));
                }
            }
            Role::Sampler => {
                if self.phase == Phase::Stopping && (p.stopping || self.killed) {
                    if status.code() == Some(1) {
                        self.fail(format!("sampler exited ({cause})"));
                    }
                    return;
                }
                self.fail(format!("sampler exited ({cause})"));
            }
            Role::Recorder => {
                let starting = self.phase == Phase::StartRecorder;
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                // The part being written (the only one a split recording leaves unfinished).
                let path = record::last_part(&rec.path).display().to_string();
                if !starting && !status.success() && self.phase == Phase::Running {
                    if !recorder_restartable(status, p.ready) {
                        say(&format!(
                            "recorder not restarted: it stopped at an error of its own ({cause}), \
                             which a new one would meet as well (a full disk, an unwritable \
                             file); once that is mended, `supervisor record` starts it again"
                        ));
                    } else {
                        match self.restart_recorder(pid, &cause) {
                            Ok(true) => return,
                            Ok(false) => {}
                            Err(e) => say(&format!("WARNING: cannot restart the recorder: {e:#}")),
                        }
                    }
                }
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                rec.back_pending = None;
                if !starting {
                    // Whatever its exit status, the updater must stop waiting for its
                    // acknowledgements.
                    let _ = self
                        .send_control(Control::plain(self.run_id, Control::RECORDER_LOST), true);
                }
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                if starting {
                    // It recorded nothing: the path may even be another run's live file (which
                    // it refused), so the summary must not point to it.
                    self.recording = None;
                    self.fail(format!(
                        "recorder exited before it was ready ({cause}); run with --no-record to \
                         run without a recording"
                    ));
                } else if !status.success() {
                    // Not restarted: while stopping, or pipeline.restart_limit is exhausted.
                    rec.lost = Some(cause.clone());
                    let go_on = if self.phase == Phase::Stopping {
                        ""
                    } else {
                        "; the run continues without recording (`supervisor record` starts it \
                         again, into a new part)"
                    };
                    let (pi2cma, how_to_build) = pi2cma_program();
                    if Path::new(&path).exists() {
                        say(&format!(
                            "WARNING: recorder (pid {pid}) died ({cause}){go_on}. {path} holds \
                             every update flushed so far but is not finished: `{pi2cma} recover \
                             {path}` (or `mcap-tool recover {path}`) completes it{how_to_build}"
                        ));
                    } else {
                        // Stopped as the run failed to start, before it created its file.
                        say(&format!(
                            "WARNING: recorder (pid {pid}) died ({cause}){go_on}, before it \
                             created {path}: nothing was recorded"
                        ));
                    }
                }
            }
        }
    }

    /// Worker `w` (pid `pid`) exited with status 0 unasked, after it had announced itself: a
    /// task that ended its worker on
    /// purpose (`sys.exit(0)` in a Python rollout, `std::process::exit(0)`, an operator's
    /// `kill` of the worker, which ends it in order). Restarting it would undo that and spend
    /// the restart limit on it, so it is taken as a scale-down by one: its slot is freed, its
    /// rollouts go to the others, and `supervisor scale` brings a worker back. With no worker
    /// left to run rollouts the run is stopped, as by `supervisor stop`.
    fn exited_on_purpose(&mut self, w: u32, pid: u32, cause: &str) {
        self.slots.remove(&w);
        self.target_workers = self.target_workers.saturating_sub(1);
        let left = self.slots.len() + self.live_joined().count();
        if left > 0 {
            say(&format!(
                "worker-{w} (pid {pid}) exited on its own ({cause}): taken as stopped on \
                 purpose, not restarted; its rollouts go to the others, {left} worker(s) go on \
                 (`supervisor scale` adds workers again)"
            ));
            return;
        }
        say(&format!(
            "worker-{w} (pid {pid}) exited on its own ({cause}): taken as stopped on purpose, \
             not restarted; no worker is left to run rollouts, so the run stops"
        ));
        if self.outcome.is_none() {
            self.outcome = Some(Outcome::Stopped);
        }
        self.begin_stop();
    }

    /// After the recorder died mid-run: unless `pipeline.restart_limit` restarts within
    /// `restart_window_s` are used up, removes the dead node's ports (the services have room for
    /// one recorder), recovers the part it left unfinished in the background, and starts a
    /// recorder that goes on in the next part. The updater, held by the lag bound meanwhile, is
    /// told once the new one has announced itself ([`Control::RECORDER_BACK`]). Returns whether
    /// it restarted.
    fn restart_recorder(&mut self, pid: u32, cause: &str) -> anyhow::Result<bool> {
        let Some(rec) = self.recording.as_mut() else {
            return Ok(false);
        };
        let now = Instant::now();
        if !may_restart(&mut rec.restarts, &self.pipe, now) {
            say(&format!(
                "recorder not restarted: {} restarts within {} s (pipeline.restart_limit = {})",
                rec.restarts.len(),
                self.pipe.restart_window_s,
                self.pipe.restart_limit
            ));
            return Ok(false);
        }
        rec.restarts.push_back(now);
        let limit = self.pipe.restart_limit;
        let restart = rec.restarted + 1;
        let (next, restart, recovery) = self.continue_recording(|dead| {
            format!(
                "the recorder (pid {pid}) died ({cause}) and was restarted (restart {restart} \
                 of {limit}); {} holds the recording up to where it died (recovered by the \
                 supervisor)",
                dead.display()
            )
        })?;
        say(&format!(
            "WARNING: recorder (pid {pid}) died ({cause}); restart {restart} of {limit}: the \
             recording goes on in {}, and {recovery}; the updates the dead recorder had not \
             written are not recorded",
            next.display(),
        ));
        Ok(true)
    }

    /// Starts a recorder that goes on with the recording in its next part, after the one that
    /// wrote the last part died: removes the dead node's ports (the services have room for one
    /// recorder) and recovers that part in the background. `note(dead part)` is put into the new
    /// part once the recorder has announced itself ([`Self::recorder_back`]). Returns the new
    /// part, the restart count and what becomes of the dead part.
    fn continue_recording(
        &mut self,
        note: impl FnOnce(&Path) -> String,
    ) -> anyhow::Result<(PathBuf, u32, String)> {
        let Some(rec) = self.recording.as_mut() else {
            bail!("this run has no recording");
        };
        let dead = record::last_part(&rec.path);
        let part = record::part_number(&dead) + 1;
        rec.restarted += 1;
        rec.continue_in = Some(part);
        let restart = rec.restarted;
        let next = rec.continued_part().expect("continue_in is set");
        rec.back_pending = Some(note(&dead));
        rec.reap_recoveries();
        if let Some(ports) = &self.ports {
            pipeline::remove_dead_nodes(&ports._node);
        }
        // A restarted recorder that died before it created its part leaves the part its
        // predecessor left as the last one, whose recovery is under way or done: a second
        // recovery at the same time would write the same temporary file (and rename it away
        // under the first), leaving the part damaged.
        let recovering = self
            .recording
            .as_ref()
            .is_some_and(|r| r.recovering.iter().any(|(p, _)| *p == dead));
        if !recovering {
            let input = dead.clone();
            let recovery = std::thread::Builder::new()
                .name("recover".into())
                .spawn(move || {
                    // Killed between creating its part and writing its first record (a window
                    // a loaded machine widens), a recorder leaves a part that holds nothing to
                    // recover; kept, it would fail the recovery and the run (exit 3) and stop
                    // the analysis of the parts, for no update lost.
                    let outcome = if record::recover::holds_nothing(&input).unwrap_or(false) {
                        std::fs::remove_file(&input)
                            .map(|()| format!("{}: {EMPTY_PART_REMOVED}", input.display()))
                            .map_err(|e| format!("{}: cannot remove: {e}", input.display()))
                    } else {
                        record::recover::recover(&input, &input)
                            .map(|r| r.describe())
                            .map_err(|e| e.to_string())
                    };
                    release_freed_memory();
                    outcome
                })?;
            if let Some(rec) = self.recording.as_mut() {
                rec.recovering
                    .push((dead.clone(), Recovery::Running(recovery)));
            }
        }
        let recovery = if recovering {
            format!("{} is being recovered already", dead.display())
        } else {
            format!("{} is recovered in the background", dead.display())
        };
        self.spawn(Role::Recorder, restart)?;
        Ok((next, restart, recovery))
    }

    /// Removes everything of the run and prints the summary. Returns whether a part that a
    /// restarted recorder's predecessor left is still unfinished (its recovery failed).
    fn finish(&mut self, copy_result: Option<&Path>) -> anyhow::Result<bool> {
        let result_path = pipeline::result_path(&self.run_dir);
        let result = RunResult::read(&result_path).ok();
        // A failed copy must not skip the clean-up and the summary: the run is over either
        // way, and the summary (and the recording) still say what it gave.
        let copied = match (copy_result, result_path.exists()) {
            (Some(dest), true) => std::fs::copy(&result_path, dest)
                .map(drop)
                .with_context(|| format!("cannot copy the result to {}", dest.display())),
            _ => Ok(()),
        };
        remove_run(&self.run_dir, self.run_id);
        if let Some(r) = result {
            let of = self
                .cfg
                .run
                .updates
                .map_or("unbounded".to_string(), |n| n.to_string());
            // A resumed run ran updates first..r.updates; the others are in the file it resumed.
            let first = self.start.as_ref().map_or(0, |s| s.update);
            let ran = r.updates.saturating_sub(first);
            let resumed = self.start.as_ref().map_or(String::new(), |s| {
                format!(" (resumed at update {first} from {})", s.origin)
            });
            say(&format!(
                "summary: run {} ({}): {} updates of {of}{resumed} in {} ({:.0} updates/s), {} worker{} targeted at the end, {} restart{}",
                wire::run_id_hex(self.run_id),
                r.name,
                r.updates,
                // The quick start's 40 updates take ~5 ms: "0.00 s" said nothing.
                interval_text(r.elapsed_s),
                ran as f64 / r.elapsed_s.max(1e-9),
                self.target_workers,
                plural(self.target_workers as u64),
                self.total_restarts,
                plural(u64::from(self.total_restarts))
            ));
            // A run stopped before its first update has no costs to show.
            if r.updates > 0 {
                say(&format!(
                    "  evaluation cost {} → {}, final λ {}",
                    reading(r.first_eval_cost),
                    reading(r.last_eval_cost),
                    reading(r.lambda)
                ));
            }
            say(&format!("  final mean θ = {}", session::mean_text(&r.mean)));
            for c in &r.task_changes {
                // A resumed run's settings were in force where it resumed; when they were set
                // is in the recording it resumed from.
                say(&if c.source == "resume" {
                    format!(
                        "  task setting {} = {} in force where the run resumed (update {})",
                        c.name,
                        tasks::value_text(c.value),
                        c.from_update
                    )
                } else {
                    format!(
                        "  task change {} = {} from update {} ({})",
                        c.name,
                        tasks::value_text(c.value),
                        c.from_update,
                        c.source
                    )
                });
            }
            for c in &r.refused_changes {
                say(&format!(
                    "  task change {} = {} at update {} ({}) refused by the workers' task: not \
                     taken",
                    c.name,
                    tasks::value_text(c.value),
                    c.from_update,
                    c.source
                ));
            }
            if r.nonfinite_reruns > 0 {
                say(&format!(
                    "  {} rollout execution(s) with non-finite costs run again \
                     (run.nonfinite_reruns = {})",
                    r.nonfinite_reruns, self.cfg.run.nonfinite_reruns
                ));
            }
        }
        match &self.outcome {
            Some(Outcome::Complete) => say("finished"),
            Some(Outcome::Stopped) => say("stopped on request"),
            Some(Outcome::Interrupted) => say("interrupted"),
            Some(Outcome::Failed(reason)) => say(&format!("failed: {reason}")),
            None => {}
        }
        let recoveries: Vec<(PathBuf, Result<String, String>)> = self
            .recording
            .as_mut()
            .map(|r| std::mem::take(&mut r.recovering))
            .unwrap_or_default()
            .into_iter()
            .map(|(part, recovery)| (part, recovery.outcome()))
            .collect();
        let mut unfinished = false;
        // Any part, not the first: a long run's first parts may have been archived meanwhile,
        // and then what became of the recording (a part left unfinished above all) went
        // unsaid.
        if let Some(rec) = self
            .recording
            .as_ref()
            .filter(|r| record::last_part(&r.path).exists())
        {
            let path = record::describe_parts(&rec.path);
            // A resumed run's analysis joins the recordings it continues (the one it resumed,
            // the one that one resumed, …), for the whole curve.
            let (earlier, left_out) = self
                .start
                .as_ref()
                .map(|s| record::resumed_chain(Path::new(&s.origin)))
                .unwrap_or_default();
            let (pi2cma, how_to_build) = pi2cma_program();
            let analyse = format!(
                "{} --out {}{how_to_build}",
                record::analyze_command(&pi2cma, &rec.path, &earlier),
                analysis_out(&rec.path).display()
            );
            let place = if rec.defaulted {
                " (the default place: runs/<run name>-<run id>.mcap in the current directory; \
                 --record FILE to choose)"
            } else {
                ""
            };
            match &rec.lost {
                None => {
                    say(&format!("recording: {path}{place}"));
                    say(&format!("  analyse it with: {analyse}"));
                }
                Some(cause) => {
                    // Only the last part can be unfinished; the others were finished as they
                    // filled.
                    let last = record::last_part(&rec.path);
                    let last = last.display();
                    say(&format!(
                        "recording: {path}{place}: {last} is NOT finished (the recorder died: {cause})"
                    ));
                    say(&format!(
                        "  complete it with: {pi2cma} recover {last}   (or: mcap-tool recover {last})"
                    ));
                    say(&format!("  then analyse it with: {analyse}"));
                }
            }
            if let Some(note) = left_out {
                say(&format!("  NOTE: {note}"));
            }
            if rec.restarted > 0 {
                // Read after the recoveries ended: a part before a restart is complete then.
                let gaps: Vec<(PathBuf, String)> = record::recording_parts(&rec.path)
                    .into_iter()
                    .filter_map(|part| {
                        record::analyze::missing_before_restart(&part).map(|gap| (part, gap))
                    })
                    .collect();
                for line in restart_lines(rec.restarted, &gaps) {
                    say(&line);
                }
            }
            for (part, done) in &recoveries {
                match done {
                    Ok(report) => say(&format!("  {report}")),
                    Err(e) => {
                        unfinished = true;
                        let part = part.display();
                        say(&format!(
                            "  {part} is NOT finished (its recorder died, and recovering it \
                             failed: {e}); complete it with: {pi2cma} recover {part}"
                        ));
                    }
                }
            }
        }
        copied.map(|()| unfinished)
    }
}

/// The summary's lines on a recording whose recorder was restarted `restarted` times: the
/// updates missing before each part a restart began (`gaps`: the part and what it says).
/// The settings of progress report `p` named by the task's `settings` (the wire carries their
/// values in the task's order).
fn named_settings(settings: &[(&str, f64)], p: &Progress) -> Vec<(String, f64)> {
    settings
        .iter()
        .zip(wire::unpack_settings(&p.settings, p.settings_len))
        .map(|((n, _), v)| (n.to_string(), *v))
        .collect()
}

fn restart_lines(restarted: u32, gaps: &[(PathBuf, String)]) -> Vec<String> {
    let heading = format!(
        "  the recorder died and was restarted {restarted} time(s); each restart began a new \
         part, and the updates a dead recorder had not written are missing"
    );
    // Parts may be archived while the run goes on, those a restart began too: a heading
    // followed by nothing read as if the list had been lost. A restarted recorder that got no
    // update before the run ended began no part.
    let why = "moved away or deleted during the run, or never begun: the run ended before the \
               restarted recorder's first update";
    if gaps.is_empty() {
        return vec![format!(
            "{heading}; the parts that said which are not there ({why})"
        )];
    }
    let mut lines = vec![format!("{heading}:")];
    for (part, gap) in gaps {
        lines.push(format!("    {}: {gap}", part.display()));
    }
    let gone = (restarted as usize).saturating_sub(gaps.len());
    if gone > 0 {
        lines.push(format!(
            "    ({gone} of the {restarted} parts the restarts began are not there: {why})"
        ));
    }
    lines
}

/// Whether a recorder that died mid-run is worth restarting: unless, having announced itself,
/// it exited at an error of its own (exit status 1, after printing it), such as a full disk or an
/// I/O error, which its successor would meet too. Killed (SIGKILL, the OOM killer), crashed or
/// panicked, it is; and so is one that failed before it announced itself (a restarted one that
/// met its predecessor's ports not yet removed).
fn recorder_restartable(status: ExitStatus, announced: bool) -> bool {
    !(announced && status.code() == Some(1))
}

/// How long a worker waits for its `n`th restart within the window (n ≥ 1): 100 ms, 200 ms,
/// 400 ms … at most 5 s.
fn restart_backoff(n: usize) -> Duration {
    let doublings = (n.max(1) - 1).min(6) as u32;
    (Duration::from_millis(100) * 2u32.pow(doublings)).min(Duration::from_secs(5))
}

/// Whether a process restarted at `restarts` may be restarted once more at `now`
/// (`pipeline.restart_limit` within `restart_window_s`); forgets the restarts outside the
/// window.
fn may_restart(restarts: &mut VecDeque<Instant>, pipe: &PipelineSection, now: Instant) -> bool {
    // Any window past what a Duration holds is "forever".
    let window = Duration::try_from_secs_f64(pipe.restart_window_s).unwrap_or(Duration::MAX);
    while restarts
        .front()
        .is_some_and(|t| now.duration_since(*t) > window)
    {
        restarts.pop_front();
    }
    restarts.len() < pipe.restart_limit as usize
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

/// The supervisor's pid, in its run directory: tells a killed run from a live one.
const PID_FILE: &str = "supervisor.pid";

/// Removes everything of run `run_id`: its run directory (and the runs directory if it was the
/// last run in it), its iceoryx2 directory and its shared memory. Returns how many
/// shared-memory files were removed.
fn remove_run(run_dir: &Path, run_id: u64) -> usize {
    let _ = std::fs::remove_dir_all(run_dir);
    // remove_dir keeps a non-empty runs directory.
    if let Some(base) = run_dir.parent() {
        let _ = std::fs::remove_dir(base);
    }
    remove_ipc(run_id)
}

/// Removes a run's iceoryx2 directory and its files with the run's prefix; returns how many of
/// those files there were.
fn remove_ipc(run_id: u64) -> usize {
    let _ = std::fs::remove_dir_all(wire::iceoryx_root(run_id));
    remove_prefixed(&wire::file_prefix(run_id))
}

/// Removes the run's shared-memory segments and iceoryx2's files in the temp directory (a
/// SIGKILLed process leaves its own behind); returns how many.
fn remove_prefixed(prefix: &str) -> usize {
    let mut removed = 0;
    for dir in ["/dev/shm", "/tmp"] {
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(prefix)
                    && std::fs::remove_file(e.path()).is_ok()
                {
                    removed += 1;
                }
            }
        }
    }
    removed
}

/// Removes the runs under `base` whose supervisor is gone (killed with SIGKILL, or its machine
/// lost power): a killed supervisor's processes die with it (PR_SET_PDEATHSIG), but nobody
/// removes their shared memory, which holds RAM until reboot, nor their run directory, whose
/// stale control socket `supervisor ctl` would otherwise offer as an active run. Returns the
/// removed runs and how many shared-memory files each had.
///
/// A run is gone when its control socket refuses connections and the pid in its run directory
/// is not alive; a run directory without a pid file (one being created right now) is left
/// alone unless it is older than a minute.
fn sweep_abandoned_runs(base: &Path) -> Vec<(String, usize)> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(base) else {
        return removed;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let Ok(run_id) = u64::from_str_radix(&name, 16) else {
            continue;
        };
        if name.len() != 16 || !run_abandoned(&e.path()) {
            continue;
        }
        removed.push((name, remove_run(&e.path(), run_id)));
    }
    removed
}

/// Removes the inter-process files of runs whose run directory is gone, which
/// [`sweep_abandoned_runs`] cannot find: a killed run whose directory was deleted by hand, or
/// that lived under another `PI2CMA_RUN_DIR` (a test's). Left alone, its shared memory holds RAM
/// until reboot. Removed: an iceoryx2 directory `/tmp/p2c-<run>/` none of whose processes is alive
/// ([`wire::run_alive`]) with the run's shared memory, and shared memory whose iceoryx2 directory
/// is gone. Only what is older than a minute, so a run that is starting is never touched; never
/// the run `own`. Returns the runs and how many shared-memory files each had.
fn sweep_orphaned_ipc(own: u64) -> Vec<(String, usize)> {
    const MIN_AGE: Duration = Duration::from_secs(60);
    let old = |p: &Path| {
        std::fs::symlink_metadata(p)
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > MIN_AGE))
    };
    let run_id = |hex: &str| {
        (hex.len() == 16 && hex.bytes().all(|b| b.is_ascii_hexdigit()))
            .then(|| u64::from_str_radix(hex, 16).ok())
            .flatten()
    };
    let mut runs = std::collections::BTreeSet::new();
    for entry in std::fs::read_dir("/tmp").into_iter().flatten().flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        // `/tmp/p2c-<run>/`
        if let Some(id) = name.strip_prefix("p2c-").and_then(run_id) {
            if id != own && old(&entry.path()) && !wire::run_alive(id) {
                runs.insert(id);
            }
        }
    }
    for entry in std::fs::read_dir("/dev/shm")
        .into_iter()
        .flatten()
        .flatten()
    {
        let name = entry.file_name().to_string_lossy().to_string();
        // `/dev/shm/p2c<run>_…`
        let id = name
            .strip_prefix("p2c")
            .and_then(|rest| rest.split_once('_'))
            .and_then(|(hex, _)| run_id(hex));
        if let Some(id) = id {
            if id != own && !wire::iceoryx_root(id).exists() && old(&entry.path()) {
                runs.insert(id);
            }
        }
    }
    runs.into_iter()
        .map(|id| (wire::run_id_hex(id), remove_ipc(id)))
        .collect()
}

fn run_abandoned(run_dir: &Path) -> bool {
    if control::serving(run_dir) {
        return false;
    }
    match std::fs::read_to_string(run_dir.join(PID_FILE)) {
        Ok(pid) => match pid.trim().parse::<u32>() {
            Ok(pid) => !process_alive(pid),
            Err(_) => false,
        },
        Err(_) => std::fs::metadata(run_dir)
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > Duration::from_secs(60))),
    }
}

/// How a printed command calls `pi2cma`: the binary beside this one (cargo builds both into one
/// directory), relative to the working directory when under it, so that the command works as
/// printed; else by name, with how to build it (the quick start builds only the supervisor).
fn pi2cma_program() -> (String, &'static str) {
    let beside = std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.join("pi2cma")))
        .filter(|p| executable_file(p));
    match beside {
        Some(path) => (record::program_name(&path), ""),
        None => (
            "pi2cma".into(),
            "   (pi2cma: `cargo build --release -p pi2cma-cli` in the pi2cma repository)",
        ),
    }
}

/// The plural ending of a noun counted `n`: `1 worker`, `2 workers`.
fn plural(n: u64) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// The `--out` of the printed analysis command: the recording's directory, since `analyze`
/// writes a run's CSV files and figures into `OUT/<file stem>/` (`runs/A1-<id>.mcap` →
/// `runs/A1-<id>/`, beside the recording).
fn analysis_out(recording: &Path) -> &Path {
    match recording.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    }
}

/// Whether process `pid` runs: it exists and is not a zombie (one that has exited and waits to
/// be reaped still has `/proc/<pid>`).
pub fn process_alive(pid: u32) -> bool {
    process_started(pid).is_some()
}

/// Whether the process that had pid `pid` and start time `started` still runs, not another that
/// got its pid.
fn still_runs(pid: u32, started: u64) -> bool {
    process_started(pid) == Some(started)
}

/// When process `pid` started (clock ticks after boot, field 22 of `/proc/<pid>/stat`) if it
/// runs: with the pid, an identity that pid reuse does not fool. `None` for a zombie.
pub fn process_started(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The fields follow the parenthesised command name, which may contain spaces and `)`.
    let (_, rest) = stat.rsplit_once(')')?;
    let mut fields = rest.split_whitespace();
    // Field 3, the state; field 22 is 18 further on.
    if fields.next()? == "Z" {
        return None;
    }
    fields.nth(18)?.parse().ok()
}

/// A thread that waits on the supervisor's doorbell and turns each ring into [`Event::Bell`].
fn spawn_bell(
    run_id: u64,
    limits: Limits,
    tx: Sender<Event>,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let (ok_tx, ok_rx) = mpsc::channel::<Result<(), String>>();
    let handle = std::thread::Builder::new()
        .name("doorbell".into())
        .spawn(move || {
            let setup = || -> anyhow::Result<_> {
                let node = wire::node(run_id, "supervisor-bell")?;
                let listener = iox(
                    wire::doorbell(&node, run_id, wire::process::SUPERVISOR, &limits)?
                        .listener_builder()
                        .create(),
                    "supervisor doorbell",
                )?;
                Ok((node, listener))
            };
            let (_node, listener) = match setup() {
                Ok(v) => {
                    let _ = ok_tx.send(Ok(()));
                    v
                }
                Err(e) => {
                    let _ = ok_tx.send(Err(format!("{e:#}")));
                    return;
                }
            };
            // The timeout only bounds how long the thread takes to notice `stop`.
            while !stop.load(Ordering::Relaxed) {
                match listener.timed_wait(|_| {}, Duration::from_millis(250)) {
                    Ok(0) => {}
                    Ok(_) => {
                        if tx.send(Event::Bell).is_err() {
                            break;
                        }
                    }
                    Err(_) => break,
                }
            }
        })?;
    match ok_rx.recv() {
        Ok(Ok(())) => Ok(handle),
        Ok(Err(e)) => bail!("{e}"),
        Err(_) => bail!("the doorbell thread died"),
    }
}

/// Signals one process that is not ours to group-kill (a worker that joined from outside).
/// The pid comes from a shared-memory message: 0 or one beyond `pid_t` would signal a process
/// group or everything the user owns, so only a plain other process's pid is signalled.
fn signal_process(pid: u32, sig: libc::c_int) {
    if pid == 0 || pid > i32::MAX as u32 || pid == std::process::id() {
        return;
    }
    // SAFETY: kill has no memory-safety preconditions; a stale pid only yields ESRCH.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// Sends `sig` to the process group of child `pid` (each child leads its own group).
fn signal_group(pid: u32, sig: libc::c_int) {
    // SAFETY: killpg has no memory-safety preconditions; a stale group id only yields ESRCH.
    #[allow(unsafe_code)]
    unsafe {
        libc::killpg(pid as libc::pid_t, sig);
    }
}

/// What a child killed by SIGBUS most likely ran into: iceoryx2 sizes its segments without
/// reserving their pages, so a full /dev/shm shows only as SIGBUS at the first write to a page
/// it has no room for, and `signal: 7 (SIGBUS)` alone does not say so.
fn sigbus_hint(status: ExitStatus, shm: Option<(u64, u64)>) -> Option<String> {
    use std::os::unix::process::ExitStatusExt as _;
    if status.signal() != Some(libc::SIGBUS) {
        return None;
    }
    let space = match shm {
        Some((free, total)) => format!("{SHM_DIR} has {} free of {}", size(free), size(total)),
        None => format!("{SHM_DIR} could not be inspected"),
    };
    Some(format!(
        "SIGBUS here most likely means the shared memory is full: {space}; free space there \
         (or enlarge it), or make the run's messages smaller (K, P, N, pipeline.max_workers)"
    ))
}

/// Returns the memory a part's recovery freed to the system. glibc keeps what a thread freed
/// in that thread's malloc arena, and each recovery ran in a thread of its own: the
/// supervisor's RSS stepped up 2–3 MiB with each of the first recorder restarts and stayed
/// there (malloc_stats: 15.6 MB from the system, 1.9 MB in use).
fn release_freed_memory() {
    // SAFETY: malloc_trim only gives free pages of the arenas back (it takes each arena's
    // lock); it touches no memory in use.
    #[cfg(target_env = "gnu")]
    #[allow(unsafe_code)]
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Keeps glibc's mmap threshold at its initial 128 KiB. Freeing a block it had mapped raises
/// it (and the trim threshold, to twice that) up to 32 MiB; a recovery frees blocks of
/// megabytes, after which blocks that size came from the arenas and their freed tops were
/// kept (malloc_trim gives back the top of the main arena only). Measured over 6 recorder
/// kills: +7.5 MiB RSS with the threshold free to rise, +2.2 MiB with it fixed.
fn fix_malloc_thresholds() {
    // SAFETY: mallopt sets a parameter of the allocator; no memory is touched.
    #[cfg(target_env = "gnu")]
    #[allow(unsafe_code)]
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
    }
}

/// The child gets SIGKILL when the supervisor dies, however it dies.
fn die_with_parent(cmd: &mut Command) {
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs in the forked child before exec and only calls the
    // async-signal-safe functions prctl, getppid and _exit; it allocates nothing.
    #[allow(unsafe_code)]
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The supervisor died between fork and prctl: the signal would never come.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

/// A cost or λ as people read it in the progress lines, `status` and the summary: 4 decimals,
/// in exponent form where those would say little (below 1e-3, `0.0000` for λ = 1e-60) or
/// show digits no one reads (from 1e12 on).
fn reading(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-3..1e12).contains(&v.abs()) {
        format!("{v:.4e}")
    } else {
        format!("{v:.4}")
    }
}

/// A time between updates as the stall warning shows it: in seconds, in milliseconds below
/// 10 ms (a run at thousands of updates per second came "every 0.000 s").
fn interval_text(secs: f64) -> String {
    if secs >= 0.01 {
        format!("{secs:.3} s")
    } else {
        format!("{:.3} ms", secs * 1e3)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_update_rate_is_updates_over_the_time_they_took_in_the_last_seconds() {
        let ms = 1_000_000u64;
        let mut r = UpdateRate::default();
        assert_eq!(r.rate(), None);
        // A resumed run's origin, then updates every 160 ms, reported every other one.
        r.add(384, 0);
        assert_eq!(r.rate(), None);
        for n in 1..=20u64 {
            if n % 2 == 0 {
                r.add(384 + n, n * 160 * ms);
            }
        }
        assert!((r.rate().unwrap() - 6.25).abs() < 1e-9, "{:?}", r.rate());
        // The window keeps about the last 2 s: 4 workers more make updates every 80 ms.
        for n in 1..=40u64 {
            r.add(404 + n, 3200 * ms + n * 80 * ms);
        }
        assert!((r.rate().unwrap() - 12.5).abs() < 1e-9, "{:?}", r.rate());
        // A report with no new update (a task change, a stop) changes nothing.
        r.add(444, 9000 * ms);
        assert!((r.rate().unwrap() - 12.5).abs() < 1e-9, "{:?}", r.rate());
        // After a long stall, the window spans it: one update in 3 s.
        r.add(445, 3200 * ms + 40 * 80 * ms + 3000 * ms);
        assert!(r.rate().unwrap() < 1.0, "{:?}", r.rate());
    }

    #[test]
    fn a_progress_report_with_more_settings_than_it_can_hold_shows_those_it_holds() {
        use super::{named_settings, Progress};
        let names = [("viapoint", 0.0), ("t", 0.0)];
        let mut p = Progress {
            settings_len: 1,
            ..Progress::default()
        };
        p.settings[..2].copy_from_slice(&[0.25, 9.0]);
        assert_eq!(named_settings(&names, &p), [("viapoint".into(), 0.25)]);
        // A count beyond the header's array (a process of another revision, or not ours).
        p.settings_len = 9;
        assert_eq!(
            named_settings(&names, &p),
            [("viapoint".into(), 0.25), ("t".into(), 9.0)]
        );
    }

    #[test]
    fn spawned_pids_are_forgotten_a_while_after_they_were_reaped() {
        use super::{Spawned, LATE_ANNOUNCEMENT};
        use std::time::{Duration, Instant};
        let t0 = Instant::now();
        let mut spawned = Spawned::default();
        spawned.started(1);
        // A day of worker incarnations, restarted and scaled.
        for pid in 100..10_100 {
            spawned.started(pid);
            spawned.reaped(pid, t0);
        }
        // Its announcement, read just after it was reaped, is not a worker joining.
        assert!(spawned.ours(5000, t0 + Duration::from_secs(1)));
        let later = t0 + LATE_ANNOUNCEMENT + Duration::from_secs(1);
        spawned.started(20_000);
        spawned.reaped(20_000, later);
        // The pid, handed by the kernel to a worker started by hand, is that worker's.
        assert!(!spawned.ours(5000, later));
        assert!(spawned.ours(1, later), "a running child stays ours");
        assert!(spawned.ours(20_000, later));
        assert_eq!(
            spawned.len(),
            2,
            "only the running and the recently reaped are kept"
        );
    }

    use super::*;

    #[test]
    fn costs_and_lambda_are_shown_with_4_decimals_or_in_exponent_form() {
        assert_eq!(reading(1.9999999999999998), "2.0000");
        assert_eq!(reading(22.428912381184755), "22.4289");
        assert_eq!(reading(0.0), "0.0000");
        assert_eq!(reading(1e-60), "1.0000e-60");
        assert_eq!(reading(-3.5e15), "-3.5000e15");
        assert_eq!(reading(f64::NAN), "NaN");
        assert_eq!(reading(f64::INFINITY), "inf");
    }

    /// The parts restarts began say which updates are missing; with none of them left (moved
    /// away or deleted during the run), the heading was followed by nothing.
    #[test]
    fn the_restarts_missing_updates_are_listed_or_said_to_be_unknown() {
        let gap = (
            PathBuf::from("day.part-4.mcap"),
            "begins at update 40 after a recorder restart (restart 1); missing 38..=39".into(),
        );
        let lines = restart_lines(1, std::slice::from_ref(&gap));
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[0].ends_with("are missing:"), "{lines:?}");
        assert!(
            lines[1].starts_with("    day.part-4.mcap: begins at update 40"),
            "{lines:?}"
        );

        let lines = restart_lines(2, &[]);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(!lines[0].ends_with(':'), "{lines:?}");
        assert!(lines[0].contains("are not there (moved away"), "{lines:?}");

        // One of two restarts' parts gone: what is there is listed, and the other said.
        let lines = restart_lines(2, &[gap]);
        assert!(lines[0].ends_with("are missing:"), "{lines:?}");
        assert!(lines[2].contains("1 of the 2 parts"), "{lines:?}");
    }

    #[test]
    fn a_stall_warning_shows_a_short_interval_in_ms() {
        assert_eq!(interval_text(0.161), "0.161 s");
        assert_eq!(interval_text(0.000118), "0.118 ms");
    }

    #[test]
    fn a_child_killed_by_sigbus_is_said_to_have_found_the_shared_memory_full() {
        use std::os::unix::process::ExitStatusExt as _;
        let bus = ExitStatus::from_raw(libc::SIGBUS);
        let hint = sigbus_hint(bus, Some((12 << 10, 64 << 20))).unwrap();
        assert!(
            hint.contains("shared memory is full: /dev/shm has 12 KiB free of 64.0 MiB"),
            "{hint}"
        );
        assert!(sigbus_hint(bus, None)
            .unwrap()
            .contains("/dev/shm could not be inspected"));
        for other in [
            ExitStatus::from_raw(libc::SIGSEGV),
            ExitStatus::from_raw(1 << 8),
        ] {
            assert_eq!(sigbus_hint(other, Some((0, 1))), None);
        }
    }

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

    #[test]
    fn a_workers_restart_backoff_doubles_up_to_5_s() {
        let ms: Vec<u128> = (1..=9).map(|n| restart_backoff(n).as_millis()).collect();
        assert_eq!(ms, [100, 200, 400, 800, 1600, 3200, 5000, 5000, 5000]);
    }

    #[test]
    fn a_recorder_is_restarted_unless_it_stopped_at_an_error_of_its_own() {
        use std::os::unix::process::ExitStatusExt as _;
        let killed = ExitStatus::from_raw(libc::SIGKILL);
        let exited = |code: i32| ExitStatus::from_raw(code << 8);
        assert!(recorder_restartable(killed, true));
        assert!(recorder_restartable(exited(101), true)); // a panic
        assert!(!recorder_restartable(exited(1), true));
        assert!(recorder_restartable(exited(1), false));
    }

    #[test]
    fn the_analysis_goes_beside_the_recording() {
        assert_eq!(
            analysis_out(Path::new("runs/A1-00ab.mcap")),
            Path::new("runs")
        );
        assert_eq!(analysis_out(Path::new("day1.mcap")), Path::new("."));
        assert_eq!(analysis_out(Path::new("/d/x.mcap")), Path::new("/d"));
    }

    /// A process's start time identifies it across pid reuse; a zombie or a reaped process has
    /// none; a command name with spaces and `)` does not shift the fields.
    #[test]
    fn process_started_reads_the_start_time_of_live_processes_only() {
        let own = process_started(std::process::id()).expect("this process runs");
        assert_eq!(process_started(std::process::id()), Some(own));
        let dir = std::env::temp_dir().join(format!("started-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let odd = dir.join("a) b 7 Z");
        std::fs::copy("/bin/sleep", &odd).expect("copy sleep");
        let mut child = std::process::Command::new(&odd)
            .arg("30")
            .spawn()
            .expect("spawn");
        let pid = child.id();
        let started = process_started(pid).expect("child runs");
        assert!(started >= own, "{started} < {own}");
        child.kill().expect("kill");
        // Killed but not reaped: a zombie, not running.
        let deadline = Instant::now() + Duration::from_secs(5);
        while process_started(pid).is_some() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(process_started(pid), None);
        assert!(
            std::fs::metadata(format!("/proc/{pid}")).is_ok(),
            "reaped early"
        );
        child.wait().expect("reap");
        assert_eq!(process_started(pid), None);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
