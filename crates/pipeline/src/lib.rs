//! The processes of the pipeline: [`updater`] (owns the sans-IO optimizer: tells costs, publishes
//! distributions), [`sampler`] (draws each update's parameter vectors and hands them out to
//! workers by load) and [`worker`] (executes rollouts, writing costs straight into shared memory;
//! [`worker::serve`] runs the same loop around a user's own task). The wire contract (message
//! layouts, service names and settings) is the `wire` crate's; the binaries live in the
//! `supervisor` crate, which starts and supervises these processes. The library's functions fail
//! with [`ProcessError`]; [`run_main`], the processes' binary edge, reports it with context.
//!
//! **Architecture Invariant:** the processes never serialise on the data paths and do not spin:
//! each waits on its doorbell event (the crate-private `wait_loop`, whose comment says why not
//! in a WaitSet) and then drains its subscribers. The one bounded exception is a worker polling
//! for its next work for at most `pipeline.worker_spin_us` after a chunk (`Spin`).

#![warn(missing_docs)]

mod error;
pub mod result;
pub mod sampler;
pub mod updater;
pub mod worker;

use std::fmt::Debug;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{DegradationAction, DegradationCause, DegradationInfo};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2_bb_posix::signal::SignalHandler;
use session::RunConfig;
use std::sync::atomic::{AtomicBool, Ordering};
use wire::{Limits, Service};

pub use error::ProcessError;

/// Arguments every pipeline process takes (the supervisor passes them).
#[derive(Debug, Clone, clap::Args)]
pub struct ProcessArgs {
    /// The run's config (the supervisor writes it into the run directory).
    #[arg(long)]
    pub config: PathBuf,
    /// The run directory: iceoryx2 files, result file.
    #[arg(long)]
    pub run_dir: PathBuf,
    /// The run id, 16 hex digits.
    #[arg(long, value_parser = parse_run_id)]
    pub run_id: u64,
}

/// The run id of `--run-id`, hex digits (the supervisor passes 16); the error names the text.
pub fn parse_run_id(s: &str) -> Result<u64, String> {
    u64::from_str_radix(s, 16).map_err(|e| format!("run id `{s}` is not hex: {e}"))
}

/// What a process needs from its run: the config, the limits derived from it, and its node.
pub struct Context {
    /// The run's config, as loaded from `--config`.
    pub config: RunConfig,
    /// The run id: every message carries it, every service name contains it.
    pub run_id: u64,
    /// The run directory (`--run-dir`): the result file, and the recording by default.
    pub run_dir: PathBuf,
    /// The sizes every service of the run is opened with ([`limits`] of `config`).
    pub limits: Limits,
    /// This process's iceoryx2 node, with the run's iceoryx2 config ([`wire::node`]).
    pub node: Node<Service>,
}

impl Context {
    /// Loads the config and creates the node named `node_name` (a process name of
    /// [`wire::process`], or [`wire::worker_node_name`]); installs iceoryx2's SIGINT/SIGTERM
    /// handling ([`termination_requested`]). Fails on a config the process cannot use
    /// ([`ProcessError::Config`], [`ProcessError::Task`], [`ProcessError::TooManySettings`]) or
    /// a node that cannot be created ([`ProcessError::Service`]).
    pub fn new(args: &ProcessArgs, node_name: &str) -> Result<Self, ProcessError> {
        let config = RunConfig::load(&args.config)?;
        let limits = limits(&config)?;
        let node = wire::node(args.run_id, node_name)?;
        // Installs iceoryx2's SIGINT/SIGTERM handling now, so a signal before the first wait
        // still ends in an orderly exit that removes this process's resources.
        let _ = node.wait(Duration::ZERO);
        // It also catches SIGABRT and SIGQUIT, only to note them: `kill -ABRT` of a hung
        // process, for its core dump, did nothing. They end the process again (the supervisor
        // reports the death and restarts a worker).
        signals::restore_default(&[signals::Signal::ABRT, signals::Signal::QUIT])?;
        Ok(Self {
            config,
            run_id: args.run_id,
            run_dir: args.run_dir.clone(),
            limits,
            node,
        })
    }

    /// [`result_path`] of this run.
    pub(crate) fn result_path(&self) -> PathBuf {
        result_path(&self.run_dir)
    }

    /// A listener on the doorbell `wake/<owner>` of this run.
    pub fn listener(&self, owner: &str) -> Result<Listener<Service>, ProcessError> {
        let bell = wire::doorbell(&self.node, self.run_id, owner, &self.limits)?;
        iox(
            bell.listener_builder().create(),
            &format!("listener on wake/{owner}"),
        )
    }

    /// The names of this run's dead nodes (processes killed without cleaning up); their stale
    /// iceoryx2 resources are removed on the way.
    pub fn dead_nodes(&self) -> Vec<String> {
        remove_dead_nodes(&self.node)
    }

    /// This run's nodes: the dead ones, as [`Context::dead_nodes`], and the live ones.
    pub fn scan_nodes(&self) -> NodeScan {
        scan_nodes(&self.node)
    }

    /// A notifier ringing the doorbell `wake/<owner>` of this run.
    pub fn notifier(&self, owner: &str) -> Result<Notifier<Service>, ProcessError> {
        let bell = wire::doorbell(&self.node, self.run_id, owner, &self.limits)?;
        iox(
            bell.notifier_builder().create(),
            &format!("notifier of wake/{owner}"),
        )
    }
}

/// How a process the supervisor did not start (a worker or a recorder started by hand) learns
/// that its run has ended, since nobody stops it: the run directory, which the supervisor
/// removes last, is gone; or the supervisor it has seen is gone without removing anything
/// (killed with SIGKILL: until a later `supervisor run` swept the run away, such a process waited
/// forever, a recorder with its file unfinished). A supervisor not yet seen is not missed: such
/// a process may be started before it.
pub struct RunEnd {
    run_dir: PathBuf,
    run_id: u64,
    supervisor_seen: bool,
    /// The supervisor was missing at the last look, with the run directory still there.
    supervisor_missed: bool,
    /// When to look next.
    next_look: Option<Instant>,
}

/// How long after a look at a missing supervisor the next one comes: one that ends in order
/// removes its node first and the run directory a moment later.
const SUPERVISOR_MISSED_LOOK: Duration = Duration::from_millis(100);

impl RunEnd {
    /// Watches run `run_id`, whose run directory is `run_dir`.
    pub fn new(run_dir: &Path, run_id: u64) -> Self {
        Self {
            run_dir: run_dir.to_path_buf(),
            run_id,
            supervisor_seen: false,
            supervisor_missed: false,
            next_look: None,
        }
    }

    /// Why the run has ended, if it has: looked at most once a second (the supervisor is
    /// looked for in the run's iceoryx2 node registry), `None` in between.
    pub fn ended(&mut self) -> Option<String> {
        let now = Instant::now();
        if self.next_look.is_some_and(|t| now < t) {
            return None;
        }
        self.next_look = Some(now + Duration::from_secs(1));
        if !self.run_dir.exists() {
            return Some(format!(
                "its run directory {} is gone",
                self.run_dir.display()
            ));
        }
        // Only a supervisor seen for certain is missed: a node being created reads as unknown.
        match wire::supervisor_known_alive(self.run_id) {
            Some(true) => {
                self.supervisor_seen = true;
                self.supervisor_missed = false;
                None
            }
            // Missed twice with the run directory there: killed. Taken as killed at the first,
            // a supervisor that ended in order was, when the look came between the removal of
            // its node and that of the run directory.
            Some(false) if self.supervisor_missed => Some(
                "its supervisor was killed; the next `supervisor run` removes what it left".into(),
            ),
            Some(false) if self.supervisor_seen => {
                self.supervisor_missed = true;
                self.next_look = Some(now + SUPERVISOR_MISSED_LOOK);
                None
            }
            _ => None,
        }
    }
}

/// Where the updater writes the run's [`result::RunResult`]: `<run dir>/result.toml`.
pub fn result_path(run_dir: &Path) -> PathBuf {
    run_dir.join("result.toml")
}

// The config refuses an external task with more settings than the wire headers carry.
const _: () = assert!(session::MAX_EXTERNAL_SETTINGS == wire::MAX_SETTINGS);

/// K, P, N and the worker limit of a config: the numbers every service is sized from.
pub fn limits(config: &RunConfig) -> Result<Limits, ProcessError> {
    let task = config.build_task()?;
    if task.settings().len() > wire::MAX_SETTINGS {
        return Err(ProcessError::TooManySettings {
            task: task.name(),
            settings: task.settings().len(),
            max: wire::MAX_SETTINGS,
        });
    }
    Ok(Limits {
        max_workers: config.pipeline().max_workers,
        rollouts: config.optimizer.rollouts,
        dim: task.parameters(),
        steps: task.steps(),
    })
}

/// A subscriber or a publisher with iceoryx2's default settings on one of the run's services
/// (as `wire` opens them), named in an error: `wire::control(…)?.subscriber("control")?`.
pub trait Ports<P: Debug + IceoryxSend + ?Sized, H: Debug + ZeroCopySend> {
    /// A subscriber; a failure is [`ProcessError::Port`] naming `"<name> subscriber"`.
    fn subscriber(&self, name: &str) -> Result<Subscriber<Service, P, H>, ProcessError>;
    /// A publisher; a failure is [`ProcessError::Port`] naming `"<name> publisher"`.
    fn publisher(&self, name: &str) -> Result<Publisher<Service, P, H>, ProcessError>;
}

impl<P: Debug + IceoryxSend + ?Sized, H: Debug + ZeroCopySend> Ports<P, H>
    for PortFactory<Service, P, H>
{
    fn subscriber(&self, name: &str) -> Result<Subscriber<Service, P, H>, ProcessError> {
        let port = format!("{name} subscriber");
        iox(
            self.subscriber_builder()
                .set_degradation_handler(failed_connections(&port, "publisher"))
                .create(),
            &port,
        )
    }
    fn publisher(&self, name: &str) -> Result<Publisher<Service, P, H>, ProcessError> {
        let port = format!("{name} publisher");
        iox(
            self.publisher_builder()
                .set_degradation_handler(failed_connections(&port, "subscriber"))
                .create(),
            &port,
        )
    }
}

/// The degradation handler of every port: says on stderr, once per pair of ports, that `port`
/// could not connect to a `peer` (iceoryx2's own warning is below the log level every process
/// sets, so a failed connection, after which nothing the peer sends reaches this port, was
/// silent). It happens when a publisher's data segment is gone before a subscriber first
/// looked, e.g. a worker that died and was cleaned up while the recorder was stalled.
pub(crate) fn failed_connections(
    port: &str,
    peer: &'static str,
) -> impl Fn(DegradationCause, &DegradationInfo) -> DegradationAction + Send + 'static {
    let port = port.to_string();
    let said = std::sync::Mutex::new(std::collections::HashSet::new());
    move |cause, info| {
        let pair = (info.sender_port_id, info.receiver_port_id);
        // A poisoned set only means a report was cut short: say it again rather than never.
        let first = said.lock().map_or(true, |mut s| s.insert(pair));
        if first {
            let line = degradation_line(&port, peer, &cause, info);
            #[cfg(test)]
            tests::REPORTED.with(|r| r.borrow_mut().push(line.clone()));
            eprintln!("{line}");
        }
        DegradationAction::Ignore
    }
}

fn degradation_line(
    port: &str,
    peer: &str,
    cause: &DegradationCause,
    info: &DegradationInfo,
) -> String {
    let (sender, receiver) = (info.sender_port_id, info.receiver_port_id);
    let ports = format!("(sender port {sender:#x}, receiver port {receiver:#x})");
    match cause {
        DegradationCause::FailedToEstablishConnection => format!(
            "warning: the {port} cannot connect to a {peer} {ports}: nothing sent between them \
             reaches the receiver (is the sender's data segment in /dev/shm gone? a process that \
             died and was cleaned up before this one looked leaves it so)"
        ),
        DegradationCause::ConnectionCorrupted => format!(
            "warning: the {port} has a corrupted connection to a {peer} {ports}: what was sent \
             on it may be lost"
        ),
    }
}

/// Turns an iceoryx2 error (which are `Debug`) into an error that says what failed
/// ([`ProcessError::Port`]).
pub fn iox<T, E: Debug>(r: Result<T, E>, what: &str) -> Result<T, ProcessError> {
    r.map_err(|e| ProcessError::Port {
        what: what.to_string(),
        reason: format!("{e:?}"),
    })
}

/// How a [`wait_loop`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Exit {
    /// The handler returned [`Flow::Stop`].
    Done,
    /// SIGINT or SIGTERM.
    Signal,
}

/// What a [`wait_loop`]'s handler asks for: wait for the next wake-up, or end the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Flow {
    Continue,
    Stop,
}

/// Longest a process sleeps without looking at its subscribers and at termination requests.
pub const TICK: Duration = Duration::from_millis(100);

/// Calls `on_wake` once, then every time the doorbell rings (and at least every [`TICK`]),
/// until it returns [`Flow::Stop`] or SIGINT/SIGTERM arrives.
///
/// This blocks in `Listener::timed_wait`, not in a `WaitSet`: iceoryx2 0.10's event listener
/// keeps a "notified" flag beside its socket, and under concurrent notifiers the flag can stay
/// set while the socket is empty; later notifiers then skip the socket write. `timed_wait`
/// checks the flag before blocking, an epoll-based `WaitSet` does not and slept forever
/// (measured: a 1-worker run hung after ~7000 updates). The tick is a second safety net: a
/// lost wake-up costs at most [`TICK`], and an idle process wakes 10 times a second.
pub(crate) fn wait_loop(
    doorbell: &Listener<Service>,
    on_wake: impl FnMut() -> anyhow::Result<Flow>,
) -> anyhow::Result<Exit> {
    wait_loop_spinning(doorbell, &mut Spin::new(Duration::ZERO), on_wake)
}

/// [`wait_loop`], but polling the doorbell for up to `spin`'s budget before blocking: see
/// [`Spin`].
pub(crate) fn wait_loop_spinning<E>(
    doorbell: &Listener<Service>,
    spin: &mut Spin,
    mut on_wake: impl FnMut() -> Result<Flow, E>,
) -> Result<Exit, E> {
    loop {
        if on_wake()? == Flow::Stop {
            return Ok(Exit::Done);
        }
        if termination_requested() {
            return Ok(Exit::Signal);
        }
        if spin.poll(|| doorbell.try_wait(|_| {}).is_ok_and(|n| n > 0)) {
            continue;
        }
        let blocked = Instant::now();
        // An error here is a signal interrupting the wait; the check above sees it next.
        let _ = doorbell.timed_wait(|_| {}, TICK);
        spin.blocked_for(blocked.elapsed());
    }
}

/// Adaptive polling before a blocking wait, for a process whose waits are usually short.
///
/// A process that blocks lets its CPU go idle, and waking an idle CPU is slow on virtual
/// machines (the guest halts the vCPU; the wake-up is an inter-processor interrupt through the
/// hypervisor: ~30 µs per hop measured on our 2-vCPU test machines) and costs power-state exits
/// on bare metal. A rollout worker waits between its chunks for as long as the update takes
/// (tens of µs); polling its doorbell for that long, yielding the CPU between polls, takes the
/// wake-up off every update's critical path. The budget adapts like Linux's guest halt-polling:
/// a wait that the poll caught, or that blocked for less than the maximum, sets it back to the
/// maximum; a wait that blocked for longer halves it, so a worker waiting for slow rollouts of
/// others, or for a paused run, soon stops polling.
#[derive(Debug, Clone)]
pub(crate) struct Spin {
    max: Duration,
    budget: Duration,
}

impl Spin {
    /// Budgets below this are not worth a poll loop.
    const FLOOR: Duration = Duration::from_micros(10);

    /// Polls for up to `max` (0: never).
    pub(crate) fn new(max: Duration) -> Self {
        Self { max, budget: max }
    }

    /// Polls `ready` (yielding between polls) for up to the budget, at least once unless the
    /// budget is zero; whether it became true.
    pub(crate) fn poll(&mut self, mut ready: impl FnMut() -> bool) -> bool {
        if self.budget.is_zero() {
            return false;
        }
        let start = Instant::now();
        loop {
            if ready() {
                self.budget = self.max;
                return true;
            }
            if termination_requested() || start.elapsed() >= self.budget {
                return false;
            }
            std::thread::yield_now();
        }
    }

    /// Adapts the budget to a wait that polling did not catch and that then blocked for `d`.
    pub(crate) fn blocked_for(&mut self, d: Duration) {
        self.budget = if d <= self.max {
            self.max
        } else if self.budget / 2 < Self::FLOOR {
            Duration::ZERO
        } else {
            self.budget / 2
        };
    }
}

/// Whether SIGINT or SIGTERM has arrived (iceoryx2's flag, installed by [`Context::new`]).
/// Not `node.wait(0)`: that is a nanosleep, which sleeps for the timer slack (~50 µs).
///
/// Sticky: iceoryx2's `SignalHandler::termination_requested` reads its flag by swapping it out,
/// so a second caller (the spin loop, then the wait loop) would find nothing and the process
/// would never stop; the first true is kept here for every later call.
pub fn termination_requested() -> bool {
    static SEEN: AtomicBool = AtomicBool::new(false);
    if SEEN.load(Ordering::Relaxed) {
        return true;
    }
    let now = SignalHandler::termination_requested();
    if now {
        SEEN.store(true, Ordering::Relaxed);
    }
    now
}

/// Keeps the lifecycle port alive: a sample of a dropped publisher may never be received.
pub struct Announced {
    _publisher: iceoryx2::port::publisher::Publisher<Service, wire::Lifecycle, ()>,
}

/// Announces on `lifecycle` that this process is ready, and rings the supervisor. Keep the
/// returned value for the life of the process.
pub fn announce_ready(
    ctx: &Context,
    role: u32,
    worker: u32,
    incarnation: u32,
) -> Result<Announced, ProcessError> {
    let publisher = wire::lifecycle(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("lifecycle")?;
    iox(
        publisher.send_copy(wire::Lifecycle {
            run_id: ctx.run_id,
            pid: std::process::id(),
            role,
            worker,
            incarnation,
        }),
        "send lifecycle",
    )?;
    let notifier = ctx.notifier(wire::process::SUPERVISOR)?;
    iox(notifier.notify_with_custom_event_id(wire::WAKE), "notify")?;
    if role == wire::role::WORKER {
        // The sampler gives a worker work once the recorder has connected to it, which it
        // does when it takes in this announcement: ring it rather than wait for its tick. The
        // recorder may not exist.
        let recorder = ctx.notifier(wire::process::RECORDER)?;
        let _ = recorder.notify_with_custom_event_id(wire::WAKE);
    }
    Ok(Announced {
        _publisher: publisher,
    })
}

/// Which of the messages of workers that cannot be of this run (a slot beyond the run's, an
/// update no updater of the run can be at: a worker started with another config or of another
/// revision) to warn about. Such a worker may send them all the time, and one line each would
/// fill the output and the recording: the first message of each worker id is named, for up to
/// [`OncePerWorker::NAMED`] ids, and one last warning says the rest go unsaid.
#[derive(Debug, Default)]
pub struct OncePerWorker {
    named: Vec<u32>,
    silent: bool,
}

/// What [`OncePerWorker::say`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Say {
    /// The first message of this worker id: name it, and that its like goes unsaid from now on.
    First,
    /// A worker id beyond the named ones: say that no more are named.
    Last,
    /// Already named, or past the last warning: say nothing.
    Nothing,
}

impl OncePerWorker {
    /// Worker ids named one by one; more are a flood, not a misconfigured worker or two.
    pub const NAMED: usize = 8;

    /// What to say about a message of `worker` that cannot be of this run.
    pub fn say(&mut self, worker: u32) -> Say {
        if self.silent || self.named.contains(&worker) {
            Say::Nothing
        } else if self.named.len() == Self::NAMED {
            self.silent = true;
            Say::Last
        } else {
            self.named.push(worker);
            Say::First
        }
    }
}

/// Runs a process main: prints the error chain and returns exit code 1 on failure,
/// [`wire::EXIT_CONFIG_REFUSED`] when the process refused the run's config
/// ([`ProcessError::refuses_config`]).
pub fn run_main(name: &str, f: impl FnOnce() -> anyhow::Result<()>) -> std::process::ExitCode {
    iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
    report_panics(name);
    match f().with_context(|| format!("{name} failed")) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.downcast_ref::<ProcessError>()
                .is_some_and(ProcessError::refuses_config)
            {
                std::process::ExitCode::from(wire::EXIT_CONFIG_REFUSED)
            } else {
                std::process::ExitCode::FAILURE
            }
        }
    }
}

/// Ends a panic's output with `error: NAME panicked at FILE:LINE: MESSAGE`. The supervisor
/// reports a process's last error line (else its last line) as why it died, and after the
/// standard hook's message come the backtrace or the hint to set `RUST_BACKTRACE`: a user's task
/// that panicked in a rollout was reported as "its last output: note: run with
/// `RUST_BACKTRACE=1` …", naming neither the task's message nor where.
fn report_panics(name: &str) {
    let name = name.to_string();
    let standard = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        standard(info);
        eprintln!(
            "error: {}",
            panic_line(&name, info.payload(), info.location())
        );
    }));
}

/// One line for a panic: its message (a `&str` or `String` payload; other payloads have none
/// to show) and where it was raised.
fn panic_line(
    name: &str,
    payload: &(dyn std::any::Any + Send),
    location: Option<&std::panic::Location<'_>>,
) -> String {
    let message = payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("(a panic without a message)");
    // The supervisor keeps one line.
    let message = message.replace('\n', " ");
    match location {
        Some(at) => format!("{name} panicked at {at}: {message}"),
        None => format!("{name} panicked: {message}"),
    }
}

/// The names of the dead nodes (processes killed without cleaning up) under `node`'s config,
/// whose stale iceoryx2 resources (ports, which count against the services' limits) are removed
/// on the way: before a dead process is replaced, its ports must go.
pub fn remove_dead_nodes(node: &Node<Service>) -> Vec<String> {
    scan_nodes(node).dead
}

/// The nodes under a config, by name ([`scan_nodes`]).
#[derive(Debug, Clone, Default)]
pub struct NodeScan {
    /// Processes killed without cleaning up; their stale resources have been removed.
    pub dead: Vec<String>,
    /// The live nodes; `None` when that cannot be told (the nodes could not be listed, or one
    /// of them is being created or removed, or belongs to another user).
    pub alive: Option<Vec<String>>,
}

/// The dead nodes under `node`'s config, whose stale iceoryx2 resources are removed on the way
/// (as [`remove_dead_nodes`]), and the live ones. A node that is in neither list has been
/// removed by its process: one that ended in order (SIGINT, SIGTERM).
pub fn scan_nodes(node: &Node<Service>) -> NodeScan {
    let mut dead = Vec::new();
    let mut alive = Some(Vec::new());
    let listed = Node::<Service>::list(node.config(), |state| {
        match state {
            NodeState::Dead(view) => {
                if let Some(d) = view.details().as_ref() {
                    dead.push(d.name().as_str().to_string());
                }
                let _ = view.try_remove_stale_resources();
            }
            NodeState::Alive(view) => match (view.details().as_ref(), alive.as_mut()) {
                (Some(d), Some(names)) => names.push(d.name().as_str().to_string()),
                _ => alive = None,
            },
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => alive = None,
        }
        CallbackProgression::Continue
    });
    if listed.is_err() {
        alive = None;
    }
    NodeScan { dead, alive }
}

/// The worker incarnations `(slot, incarnation)` whose nodes are alive and have a publisher on
/// `service` now (e.g. `costs`): a worker creates its node before its ports, so a live worker
/// node is no sign that its costs can reach a subscriber yet.
pub fn workers_publishing_on<P: Debug + IceoryxSend + ?Sized, H: Debug + ZeroCopySend>(
    node: &Node<Service>,
    service: &PortFactory<Service, P, H>,
) -> Vec<(u32, u32)> {
    let mut publishing = std::collections::HashSet::new();
    iceoryx2::service::port_factory::PortFactory::dynamic_config(service).list_publishers(|p| {
        publishing.insert(p.node_id);
        CallbackProgression::Continue
    });
    let mut found = Vec::new();
    let _ = Node::<Service>::list(node.config(), |state| {
        if let NodeState::Alive(view) = state {
            let named = view
                .details()
                .as_ref()
                .map(|d| d.name().as_str().to_string());
            if let (true, Some(w)) = (
                publishing.contains(view.id()),
                named.as_deref().and_then(wire::parse_worker_node_name),
            ) {
                found.push(w);
            }
        }
        CallbackProgression::Continue
    });
    found.sort_unstable();
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only the live worker nodes with a publisher on the service are named: one whose node
    /// exists but whose `costs` publisher does not yet is not.
    #[test]
    fn workers_are_named_publishing_only_once_their_publisher_exists() {
        let run_id = 0x7101;
        let limits = fresh_run(run_id);
        let early = wire::node(run_id, &wire::worker_node_name(0, 1)).unwrap();
        let late = wire::node(run_id, &wire::worker_node_name(1, 0)).unwrap();
        let recorder = wire::node(run_id, wire::process::RECORDER).unwrap();
        let costs = wire::costs(&recorder, run_id, &limits).unwrap();
        let early_costs = wire::costs(&early, run_id, &limits).unwrap();
        let _publisher = early_costs.publisher("costs").unwrap();
        assert_eq!(workers_publishing_on(&recorder, &costs), [(0, 1)]);
        let late_costs = wire::costs(&late, run_id, &limits).unwrap();
        let _late_publisher = late_costs.publisher("costs").unwrap();
        assert_eq!(workers_publishing_on(&recorder, &costs), [(0, 1), (1, 0)]);
        drop((_publisher, _late_publisher, early_costs, late_costs, costs));
        drop((early, late, recorder));
        remove_run(run_id);
    }

    thread_local! {
        /// The lines [`failed_connections`] printed on this thread.
        pub(crate) static REPORTED: std::cell::RefCell<Vec<String>> =
            const { std::cell::RefCell::new(Vec::new()) };
    }

    fn shm_files(run_id: u64) -> std::collections::BTreeSet<std::path::PathBuf> {
        let prefix = wire::file_prefix(run_id);
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .map(|e| e.path())
            .collect()
    }

    /// Removes what an earlier test run of `run_id` left, and gives small limits for one.
    fn fresh_run(run_id: u64) -> Limits {
        remove_run(run_id);
        Limits {
            max_workers: 2,
            rollouts: 4,
            dim: 2,
            steps: 3,
        }
    }

    fn remove_run(run_id: u64) {
        let _ = std::fs::remove_dir_all(wire::iceoryx_root(run_id));
        for f in shm_files(run_id) {
            let _ = std::fs::remove_file(f);
        }
    }

    /// A publisher whose data segment is gone before a subscriber first looks (what a worker
    /// that died and was cleaned up while the recorder was stalled leaves): the subscriber
    /// cannot connect, and nothing the publisher sent reaches it. iceoryx2 only warns, below
    /// the log level the processes set; the port says so itself, once.
    #[test]
    fn a_subscriber_that_cannot_connect_to_a_publisher_says_so_once() {
        let run_id = 0x7100;
        let limits = fresh_run(run_id);
        let worker = wire::node(run_id, "worker-0.1").unwrap();
        let worker_costs = wire::costs(&worker, run_id, &limits).unwrap();
        let before = shm_files(run_id);
        let publisher = worker_costs.publisher("costs").unwrap();
        let segments: Vec<_> = shm_files(run_id).difference(&before).cloned().collect();
        assert!(
            !segments.is_empty(),
            "the publisher made no file in /dev/shm"
        );
        for f in &segments {
            std::fs::remove_file(f).unwrap();
        }
        let recorder = wire::node(run_id, wire::process::RECORDER).unwrap();
        let subscriber = wire::costs(&recorder, run_id, &limits)
            .unwrap()
            .subscriber("costs")
            .unwrap();
        for _ in 0..3 {
            assert!(!subscriber.has_samples().unwrap());
        }
        let reported = REPORTED.with(|r| r.take());
        assert_eq!(reported.len(), 1, "{reported:#?}");
        assert!(
            reported[0].starts_with(
                "warning: the costs subscriber cannot connect to a publisher (sender port 0x"
            ),
            "{}",
            reported[0]
        );
        drop((subscriber, publisher, recorder, worker_costs, worker));
        remove_run(run_id);
    }

    const MAX: Duration = Duration::from_micros(200);

    /// A supervisor that ends in order removes its node, and then, a moment later, the run
    /// directory: a process started by hand that looked in between was told "its supervisor
    /// was killed; the next `supervisor run` removes what it left", of a run that had ended
    /// as asked and left nothing.
    #[test]
    fn a_supervisor_that_ends_in_order_is_not_taken_for_a_killed_one() {
        let run_id = 0x6960;
        let dir = std::env::temp_dir().join(format!("p2c-run-end-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let supervisor = wire::node(run_id, wire::process::SUPERVISOR).unwrap();
        let mut end = RunEnd::new(&dir, run_id);
        let look = |end: &mut RunEnd| {
            end.next_look = None;
            end.ended()
        };
        assert_eq!(look(&mut end), None);
        drop(supervisor);
        assert_eq!(look(&mut end), None, "the run directory goes next");
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(
            look(&mut end),
            Some(format!("its run directory {} is gone", dir.display()))
        );
        // Gone, and the run directory still there: killed.
        std::fs::create_dir_all(&dir).unwrap();
        let mut end = RunEnd::new(&dir, run_id);
        let supervisor = wire::node(run_id, wire::process::SUPERVISOR).unwrap();
        assert_eq!(look(&mut end), None);
        drop(supervisor);
        assert_eq!(look(&mut end), None);
        assert_eq!(
            look(&mut end).as_deref(),
            Some("its supervisor was killed; the next `supervisor run` removes what it left")
        );
        std::fs::remove_dir_all(&dir).unwrap();
        // What the nodes leave, as a supervisor's clean-up removes it.
        let _ = std::fs::remove_dir_all(wire::iceoryx_root(run_id));
        for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
            if e.file_name()
                .to_string_lossy()
                .starts_with(&wire::file_prefix(run_id))
            {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    #[test]
    fn a_worker_id_is_named_once_and_a_flood_of_ids_once_more() {
        let mut once = OncePerWorker::default();
        assert_eq!(once.say(300), Say::First);
        assert_eq!(once.say(300), Say::Nothing);
        for w in 1..OncePerWorker::NAMED as u32 {
            assert_eq!(once.say(300 + w), Say::First);
            assert_eq!(once.say(300 + w), Say::Nothing);
        }
        assert_eq!(once.say(900), Say::Last);
        assert_eq!(once.say(901), Say::Nothing);
        assert_eq!(once.say(900), Say::Nothing);
        assert_eq!(once.say(300), Say::Nothing);
    }

    #[test]
    fn a_panic_is_one_line_with_its_message_and_place() {
        let payload: Box<dyn std::any::Any + Send> = Box::new(String::from("two\nlines"));
        let at = std::panic::Location::caller();
        assert_eq!(
            panic_line("w", payload.as_ref(), Some(at)),
            format!("w panicked at {at}: two lines")
        );
        let payload: Box<dyn std::any::Any + Send> = Box::new("static");
        assert_eq!(
            panic_line("w", payload.as_ref(), None),
            "w panicked: static"
        );
        let payload: Box<dyn std::any::Any + Send> = Box::new(7_u32);
        assert_eq!(
            panic_line("w", payload.as_ref(), None),
            "w panicked: (a panic without a message)"
        );
    }

    #[test]
    fn a_poll_that_catches_the_wake_up_restores_the_full_budget() {
        let mut spin = Spin::new(MAX);
        spin.blocked_for(Duration::from_millis(5));
        assert_eq!(spin.budget, MAX / 2);
        // Caught at the first poll, which comes before any look at the clock: the outcome does
        // not depend on how loaded the machine is.
        assert!(spin.poll(|| true));
        assert_eq!(spin.budget, MAX);
    }

    #[test]
    fn long_blocks_halve_the_budget_down_to_no_polling_and_a_short_one_restores_it() {
        let mut spin = Spin::new(MAX);
        let start = Instant::now();
        assert!(!spin.poll(|| false));
        assert!(start.elapsed() >= MAX, "polled for the whole budget");
        let mut budgets = Vec::new();
        for _ in 0..6 {
            spin.blocked_for(Duration::from_millis(5));
            budgets.push(spin.budget.as_micros());
        }
        assert_eq!(budgets, [100, 50, 25, 12, 0, 0]);
        // No budget: no polling at all, not even one call.
        assert!(!spin.poll(|| panic!("polled with a zero budget")));
        spin.blocked_for(Duration::from_micros(150));
        assert_eq!(spin.budget, MAX);
    }

    #[test]
    fn a_zero_maximum_never_polls() {
        let mut spin = Spin::new(Duration::ZERO);
        assert!(!spin.poll(|| panic!("polled")));
        spin.blocked_for(Duration::ZERO);
        assert!(!spin.poll(|| panic!("polled")));
    }
}
