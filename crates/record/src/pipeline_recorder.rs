//! The pipeline's recorder process (the `recorder` binary; the `supervisor` binary hosts the same
//! role): subscribes to the run's iceoryx2 services (see the `wire` crate) and writes the run's
//! MCAP with the same schemas as the in-process recorder.
//!
//! It is the spare subscriber of `distribution`, `costs`, `control` and `lifecycle` (and the
//! one of `notes`, the supervisor's word on the run), and waits
//! on its own doorbell, `wake/recorder`, which the updater rings after a distribution when the
//! recorder may be asleep. Because those services keep no history, it must be subscribed before
//! the updater publishes the distribution of update 0: start it first and wait for its
//! `lifecycle` message (role [`wire::role::RECORDER`]) before sending START.
//!
//! Delivery is lossless by back-pressure, not by buffer size: it acknowledges each update it
//! has written and flushed on `recorded` ([`wire::RecorderAck`], with the cost messages of
//! later updates it has taken in), and the updater stays at most `Limits::recorder_max_lag`
//! updates ahead of the acknowledgement, a lag the subscriber buffers are sized for, and issues
//! a rerun only while its costs fit. When the updater is held back it rings with
//! [`wire::HOLD`], and the recorder acknowledges at the end of its round and rings
//! `wake/updater`.
//!
//! A worker's announcement on `lifecycle` makes it connect to every `costs` publisher there is
//! and echo the announcement on `joined`: the sampler gives the worker work only then, so that
//! iceoryx2 keeps what the worker sends for this process even if it crashes while this
//! process is stalled (at its start it echoes every live worker that has a `costs` publisher;
//! see [`wire::joined`]).
//!
//! One thread: drain every subscriber (distributions first), recompute each complete update
//! with the core from the recorded inputs (the samples are re-drawn from (seed, update, k); λ,
//! which follows from the distributions, is the one the updater published with each),
//! log a mismatch with the distribution the updater published as an `error` event on `/log`,
//! write the updates complete at once and hand them to the OS together (one `write`),
//! acknowledge, and look for new samples before sleeping. At thousands of
//! updates per second it therefore works in rounds of several updates and is rung rarely. A
//! SIGKILL loses the updates of the round being written (at most the lag bound plus one); `mcap-tool
//! recover` completes the file. SIGINT/SIGTERM finish the file (summary and indexes) after
//! writing everything received, and exit 0.

use std::path::PathBuf;

use crate::assemble::{Assembler, CostOutcome, Dropped};
use crate::{now_ns, Event, RolloutTiming, RunFiles, RunStart, UpdateData};
use anyhow::Context as _;
use iceoryx2::port::subscriber::Subscriber;
use pi2cma::CostError;
use pipeline::{announce_ready, iox, Context, OncePerWorker, Ports as _, Say};
use session::reruns::{after_reruns, rerun_message, NonfiniteReruns, Verdict};
use wire::{Control, CostHeader, DistributionHeader, Lifecycle, RunNote};

/// The `lifecycle` role this process announces.
pub(crate) const ROLE_RECORDER: u32 = wire::role::RECORDER;

/// The recorder's arguments: the usual process arguments and where to write.
#[derive(Debug, Clone, clap::Args)]
pub struct RecorderArgs {
    /// Run directory, run id, process name: what the supervisor passes every process.
    #[command(flatten)]
    pub process: pipeline::ProcessArgs,
    /// Where to write the recording; default `<run dir>/run.mcap`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The recording this run resumes (recorded as metadata `resumed_from`).
    #[arg(long, value_name = "FILE")]
    pub resumed_from: Option<String>,
    /// The resumed run's state (the start file `supervisor run --resume` writes), as the
    /// updater gets it: its first update is compared with these settings. Without it, a
    /// `--resumed-from` recording is read for them.
    #[arg(long, value_name = "FILE")]
    pub start: Option<PathBuf>,
    /// A recorder started after the run's recorder died (the supervisor's restart count). It
    /// goes on with the recording in part `--part` and begins at the first distribution
    /// published after it announced itself: the updates its predecessor had not written are
    /// not recorded.
    #[arg(long, value_name = "N", requires = "part")]
    pub restart: Option<u32>,
    /// The part a restarted recorder writes (2 or more; it must not exist yet).
    #[arg(long, value_name = "N", requires = "restart")]
    pub part: Option<u32>,
}

/// A message taken from one of the subscribers; payloads are borrowed from the sample.
enum Msg<'a> {
    /// The header, the mean and Σ (column-major).
    Distribution(DistributionHeader, &'a [f64], &'a [f64]),
    Control(Control),
    Lifecycle(Lifecycle),
    Note(Box<RunNote>),
}

fn role_name(l: &Lifecycle) -> String {
    match l.role {
        wire::role::UPDATER => "updater".into(),
        wire::role::SAMPLER => "sampler".into(),
        wire::role::WORKER => format!("worker-{}", l.worker),
        ROLE_RECORDER => "recorder".into(),
        r => format!("role-{r}"),
    }
}

/// Records the run's updates, rollouts, task changes and health events to MCAP until the
/// `FINAL` distribution or SIGINT/SIGTERM.
pub fn run_recorder(cli: &RecorderArgs) -> anyhow::Result<()> {
    let ctx = Context::new(&cli.process, wire::process::RECORDER)?;
    let text = std::fs::read_to_string(&cli.process.config)
        .with_context(|| format!("{}: cannot read", cli.process.config.display()))?;
    let out = cli
        .out
        .clone()
        .unwrap_or_else(|| ctx.run_dir.join("run.mcap"));

    let dist_sub =
        wire::distribution(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("distribution")?;
    let costs_service = wire::costs(&ctx.node, ctx.run_id, &ctx.limits)?;
    let costs_sub = costs_service.subscriber("costs")?;
    let control_sub = wire::control(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("control")?;
    let lifecycle_sub =
        wire::lifecycle(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("lifecycle")?;
    let notes_sub = wire::notes(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("notes")?;
    let doorbell = ctx.listener(wire::process::RECORDER)?;
    let updater_bell = ctx.notifier(wire::process::UPDATER)?;
    let supervisor_bell = ctx.notifier(wire::process::SUPERVISOR)?;
    let acks = wire::recorded(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("recorded")?;
    let joined = wire::joined(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("joined")?;
    let sampler_bell = ctx.notifier(wire::process::SAMPLER)?;

    let mut writer = match cli.part {
        Some(part) => RunFiles::continue_in_part(&out, part)?,
        None => RunFiles::create(&out)?,
    };
    writer.split_at_mb(ctx.config.recording_split_mb());
    writer.record_step_costs(ctx.config.recording_step_costs());
    // A round's updates go to the OS in one `write` (see `State::write_complete`).
    writer.hold_output();
    // Where a resumed run starts: the supervisor's start file, read at once, not the origin
    // recording, which is streamed whole (a day's run: gigabytes) before the recorder may
    // announce itself.
    let start = match (&cli.start, &cli.resumed_from) {
        (Some(file), _) => Some(session::Start::read(file)?),
        (None, Some(origin)) => crate::resume::resume_point(std::path::Path::new(origin))
            .ok()
            .map(|p| p.start),
        (None, None) => None,
    };
    let mut state = WriterState::new(&ctx, text, writer, cli.resumed_from.clone(), start)?;
    state.restart = cli.restart;
    if cli.restart.is_some() {
        // Joining a run under way: a distribution already taken in may have had costs
        // published before the costs subscriber existed.
        drop_backlog(
            &mut || Ok(iox(costs_sub.receive(), "receive costs")?.is_some()),
            &mut || Ok(iox(dist_sub.receive(), "receive distribution")?.is_some()),
        )?;
    }
    // Workers that announced themselves before this process's `lifecycle` subscriber existed
    // (a restarted recorder; one started after its workers) are never heard of here, and the
    // sampler holds a new incarnation until it is echoed on `joined`: every live worker with a
    // `costs` publisher now is, once connected to. Listed before connecting, so that each one
    // echoed is one connected to; a worker whose node exists but whose publisher does not yet
    // is echoed when its announcement (sent after its ports exist) comes.
    let publishing = pipeline::workers_publishing_on(&ctx.node, &costs_service);
    iox(costs_sub.has_samples(), "costs subscriber")?;
    iox(lifecycle_sub.has_samples(), "lifecycle subscriber")?;
    let workers: Vec<wire::Lifecycle> = publishing
        .into_iter()
        .map(|(worker, incarnation)| wire::Lifecycle {
            run_id: ctx.run_id,
            pid: 0,
            role: wire::role::WORKER,
            worker,
            incarnation,
        })
        .collect();
    echo_joined(&joined, &sampler_bell, &workers)?;
    let _announced = announce_ready(&ctx, ROLE_RECORDER, 0, cli.restart.unwrap_or(0))?;
    let out = match cli.part {
        Some(part) => crate::part_path(&out, part),
        None => out,
    };
    eprintln!("recording to {}", out.display());

    let lag = ctx.limits.recorder_max_lag();
    // The first distribution not yet taken in.
    let mut next_update: Option<u64> = None;
    // What the acknowledgements say: every update before `acked` written (from the first
    // distribution taken in), and the cost messages taken in of each update since.
    let mut acked: Option<u64> = None;
    let mut taken = TakenCosts::default();
    // The newest RECORDER_SYNC asked for, and carried out.
    let (mut sync_asked, mut synced) = (0u64, 0u64);
    // The number of the last control message (`Control::sent`), to see what was lost.
    let mut control_last: Option<u64> = None;
    let control_buffer = control_sub.buffer_size();
    let mut hold = false;
    // For the exit line: rounds of draining and writing, and requests of a held updater.
    let (mut rounds, mut holds) = (0u64, 0u64);
    let mut run_end = pipeline::RunEnd::new(&ctx.run_dir, ctx.run_id);
    let mut ending = None;
    let why = loop {
        iox(
            doorbell.try_wait(|a| hold |= a.id == wire::HOLD),
            "doorbell",
        )?;
        rounds += 1;
        holds += u64::from(hold);
        // Distributions before costs: every cost of update u was published before the
        // distribution of u + 1, so after this order of draining, a seen distribution's
        // predecessor costs are all in hand.
        let mut took_in =
            take_distributions(&dist_sub, &ctx, &mut state, &mut next_update, &mut acked)?;
        while let Some(s) = iox(costs_sub.receive(), "receive costs")? {
            let h = *s.user_header();
            if h.run_id == ctx.run_id {
                took_in = true;
                // Its update's distribution was published before it, maybe after the drain
                // above: a cost is judged out of the updater's reach only once the
                // distributions there are are in.
                if state.assembler.out_of_reach(h.update).is_some() {
                    take_distributions(&dist_sub, &ctx, &mut state, &mut next_update, &mut acked)?;
                }
                // A clock read per cost message showed in the recorder's profile; a worker
                // that stamps its rollouts does not need it.
                let received_ns = if h.start_ns == 0 { now_ns() } else { 0 };
                // Costs dropped as out of the updater's reach are not counted: the updater
                // does not count them either (it counts only updates it has issued).
                if state.cost(h, s.payload(), received_ns)? {
                    taken.add(h.update);
                }
            }
        }
        // The supervisor sends START after every process has announced itself, but the
        // announcements are drained below: START, and what came after it, waits for them, or
        // the last worker's `start` was logged after the run's.
        let mut after_start: Vec<Control> = Vec::new();
        while let Some(s) = iox(control_sub.receive(), "receive control")? {
            let c = *s.payload();
            if c.run_id != ctx.run_id {
                continue;
            }
            if c.sent > 0 {
                let lost = control_last.map_or(0, |last| c.sent.saturating_sub(last + 1));
                control_last = Some(c.sent);
                if lost > 0 {
                    state.control_lost(lost, control_buffer)?;
                }
            }
            if c.kind == Control::RECORDER_SYNC {
                sync_asked = sync_asked.max(c.seq);
            } else if c.kind == Control::START || !after_start.is_empty() {
                after_start.push(c);
            } else {
                state.handle(Msg::Control(c))?;
            }
        }
        let mut workers: Vec<wire::Lifecycle> = Vec::new();
        while let Some(s) = iox(lifecycle_sub.receive(), "receive lifecycle")? {
            if s.payload().run_id == ctx.run_id {
                if s.payload().role == wire::role::WORKER {
                    workers.push(*s.payload());
                }
                state.handle(Msg::Lifecycle(*s.payload()))?;
            }
        }
        if !workers.is_empty() {
            // A worker opens `costs` before it announces itself: connecting now means that what
            // it sends is kept for this process even if it crashes before the next round. The
            // sampler gives it work only after the echo.
            iox(costs_sub.has_samples(), "costs subscriber")?;
            echo_joined(&joined, &sampler_bell, &workers)?;
        }
        for c in after_start {
            state.handle(Msg::Control(c))?;
        }
        while let Some(s) = iox(notes_sub.receive(), "receive notes")? {
            if s.payload().run_id == ctx.run_id {
                state.handle(Msg::Note(Box::new(*s.payload())))?;
            }
        }
        // Every subscriber has been drained once: what is still missing can no longer arrive.
        // Updates are acknowledged as each `write` of them reaches the OS (at most
        // `WriterState::WRITE_BYTES` apart), so a held updater goes on while the rest of a long
        // round is written; it is rung back when half the lag bound is free.
        let newest = next_update.unwrap_or(0);
        let ring_back = |hold: &mut bool| {
            // Not fatal: after the final update the updater may already have exited.
            if std::mem::take(hold) {
                let _ = updater_bell.notify_with_custom_event_id(wire::WAKE);
            }
        };
        let ack = |next_update: u64, taken: &mut TakenCosts, synced: u64| {
            let ack = wire::RecorderAck {
                run_id: ctx.run_id,
                next_update,
                taken: taken.from(next_update),
                synced,
            };
            iox(acks.send_copy(ack), "send recorder ack").map(drop)
        };
        state.write_complete(true, &mut |u| {
            acked = Some(u + 1);
            ack(u + 1, &mut taken, synced)?;
            if newest.saturating_sub(u + 1) <= lag / 2 {
                ring_back(&mut hold);
            }
            Ok(())
        })?;
        if sync_asked > synced {
            // Connects every subscriber whose service has a publisher it has not seen (what
            // `has_samples` does first): from now on what they send is kept for this process
            // even after they exit.
            iox(costs_sub.has_samples(), "costs subscriber")?;
            iox(lifecycle_sub.has_samples(), "lifecycle subscriber")?;
            synced = sync_asked;
            ack(acked.unwrap_or(0), &mut taken, synced)?;
            // Not fatal: the supervisor may be exiting.
            let _ = supervisor_bell.notify_with_custom_event_id(wire::WAKE);
        } else if let (true, Some(a)) = (hold, acked) {
            // A held updater may wait for cost messages to be taken in, not for an update.
            ack(a, &mut taken, synced)?;
        }
        ring_back(&mut hold);
        if state.done() {
            break "run complete";
        }
        // Samples published after the drain above, whose publisher may not have rung (it saw
        // an acknowledgement that said this process was busy): take them in before sleeping.
        let more = iox(dist_sub.has_samples(), "distribution subscriber")?
            || iox(costs_sub.has_samples(), "costs subscriber")?;
        if more {
            continue;
        }
        if pipeline::termination_requested() {
            break "signal";
        }
        // A recorder started by hand (`supervisor run --no-record`) is not stopped by the
        // supervisor: as a worker started by hand does, it learns that the run has ended
        // ([`pipeline::RunEnd`]). Without this, a run that never came or whose supervisor was
        // killed left it waiting forever with its file unfinished. One more round first: what
        // was published just before the end is taken in.
        if let Some(why) = ending.take() {
            eprintln!("the run has ended ({why}): finishing the recording");
            break "run ended";
        }
        if let Some(why) = run_end.ended() {
            ending = Some(why);
            continue;
        }
        // A bounded wait, as in the pipeline's processes (`pipeline::wait_loop`); shorter while
        // the run is active, because the updater skips rings within RECORDER_RING_INTERVAL of
        // the last. An error is a signal interrupting the wait, seen above next.
        let wait = if took_in {
            wire::RECORDER_RING_INTERVAL
        } else {
            pipeline::TICK
        };
        let _ = doorbell.timed_wait(|a| hold |= a.id == wire::HOLD, wait);
    };
    let not_recorded = std::mem::take(&mut state.not_recorded);
    let written = state.finish(why)?;
    let cpu = process_cpu_seconds();
    // Per update only when there were updates: the CPU of a start and stop is not a rate.
    let cost = match written {
        0 => format!("{:.1} ms of CPU", cpu * 1e3),
        n => format!("{:.1} µs of CPU per update", cpu * 1e6 / n as f64),
    };
    // A split recording: where it began and the part it ended in (every part would make a
    // line of kilobytes in a long run).
    let last = crate::last_part(&out);
    let to = if last == out {
        out.display().to_string()
    } else {
        format!("{} … {}", out.display(), last.display())
    };
    eprintln!(
        "recorded {written} updates to {to} ({cost}; {rounds} rounds, {holds} of them asked for \
         by a held updater)"
    );
    if !not_recorded.is_empty() {
        eprintln!(
            "warning: {} not recorded ({}): their inputs never reached the recorder; the \
             recording's /log says which (`mcap-tool info {}`)",
            plural(not_recorded.len(), "update"),
            update_ranges(&not_recorded),
            out.display()
        );
    }
    Ok(())
}

fn plural(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// `3, 6..=8, 12` for updates 3, 6, 7, 8, 12 (ascending, as they are given up on).
fn update_ranges(updates: &[u64]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < updates.len() {
        let mut j = i;
        while j + 1 < updates.len() && updates[j + 1] == updates[j] + 1 {
            j += 1;
        }
        parts.push(if j == i {
            updates[i].to_string()
        } else {
            format!("{}..={}", updates[i], updates[j])
        });
        i = j + 1;
    }
    parts.join(", ")
}

/// Says on `joined` that this process is connected to the publishers of `workers` (their
/// announcements) and rings the sampler, which holds them until then. Not fatal if the sampler
/// is gone: the run may be ending.
fn echo_joined(
    joined: &iceoryx2::port::publisher::Publisher<wire::Service, wire::Lifecycle, ()>,
    sampler_bell: &iceoryx2::port::notifier::Notifier<wire::Service>,
    workers: &[wire::Lifecycle],
) -> anyhow::Result<()> {
    if workers.is_empty() {
        return Ok(());
    }
    for w in workers {
        iox(joined.send_copy(*w), "send joined")?;
    }
    let _ = sampler_bell.notify_with_custom_event_id(wire::WAKE);
    Ok(())
}

/// Takes in every distribution waiting on `distribution`; `next_update` becomes the one after
/// the newest, `acked` the first taken in (if none was before). Returns whether any was.
fn take_distributions(
    dist_sub: &Subscriber<wire::Service, [f64], DistributionHeader>,
    ctx: &Context,
    state: &mut WriterState,
    next_update: &mut Option<u64>,
    acked: &mut Option<u64>,
) -> anyhow::Result<bool> {
    let p = ctx.limits.dim;
    let mut took = false;
    while let Some(s) = iox(dist_sub.receive(), "receive distribution")? {
        let h: DistributionHeader = *s.user_header();
        if h.run_id != ctx.run_id {
            continue;
        }
        let payload = s.payload();
        let Some((mean, cov)) = wire::distribution_parts(payload, p) else {
            anyhow::bail!(
                "distribution of update {}: {} values, expected {}",
                h.update,
                payload.len(),
                p + p * p
            );
        };
        *next_update = Some(next_update.unwrap_or(0).max(h.update + 1));
        acked.get_or_insert(h.update);
        took = true;
        state.handle(Msg::Distribution(h, mean, cov))?;
    }
    Ok(took)
}

/// The cost messages taken in of each update not yet acknowledged as written: what
/// [`wire::RecorderAck::taken`] counts.
#[derive(Debug, Default)]
struct TakenCosts(std::collections::BTreeMap<u64, u64>);

impl TakenCosts {
    fn add(&mut self, update: u64) {
        *self.0.entry(update).or_default() += 1;
    }

    /// Those of updates from `update` on; the earlier ones are forgotten.
    fn from(&mut self, update: u64) -> u64 {
        self.0 = self.0.split_off(&update);
        self.0.values().sum()
    }
}

/// Drops what a restarted recorder's subscribers hold (each `receive_*` takes one message,
/// false when there is none), costs before distributions: a distribution left then was
/// published after the costs were drained, and so are all its costs. Drained the other way
/// round, a distribution published between the two drains stays while the costs its workers
/// sent at once go: that update never completes, and the recorder holds the run back for good.
/// (Costs left of a distribution that went are dropped at the first distribution,
/// [`crate::assemble::Assembler::distribution`].)
fn drop_backlog(
    receive_cost: &mut dyn FnMut() -> anyhow::Result<bool>,
    receive_distribution: &mut dyn FnMut() -> anyhow::Result<bool>,
) -> anyhow::Result<()> {
    while receive_cost()? {}
    while receive_distribution()? {}
    Ok(())
}

/// Assembles updates, recomputes and writes them.
struct WriterState {
    writer: RunFiles,
    assembler: Assembler,
    config: session::RunConfig,
    text: String,
    names: Vec<String>,
    basis: Option<Vec<f64>>,
    steps: usize,
    dim: usize,
    run_id: u64,
    pid: u32,
    started: bool,
    final_update: Option<u64>,
    /// The `FINAL` distribution is `STOPPED`: its update, which did not run, is where a resumed
    /// run goes on, with its settings.
    stopped: bool,
    current_update: u64,
    written: u64,
    mismatches: u64,
    /// Updates given up on ([`Assembler::skip_incomplete`]): named in the exit lines too, which
    /// the user reads, not only in `/log`.
    not_recorded: Vec<u64>,
    resumed_from: Option<String>,
    /// A restarted recorder's restart count ([`RecorderArgs::restart`]).
    restart: Option<u32>,
    /// Events a restarted recorder took in before its first distribution ([`Self::log`]).
    deferred: Vec<(Event, String, u32, String)>,
    slots: WorkerSlots,
    worker_names: WorkerNames,
    /// The rejected executions of each update's rollouts whose costs were not finite, counted
    /// as the updater counts them (`run.nonfinite_reruns`): a rejected execution it runs again
    /// is a warning, the one that fails the run an error (why not from the updater's
    /// `reruns` samples: [`Self::cost_rejected`]).
    reruns: std::collections::BTreeMap<u64, NonfiniteReruns>,
    /// How far the updater runs ahead of the recorder (`wire::Limits::recorder_max_lag`).
    lag: u64,
    /// Which workers' costs out of the updater's reach were warned about.
    ahead: OncePerWorker,
}

/// Why a worker incarnation was started, as far as the recorder can tell ([`WorkerSlots`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Started {
    /// The first worker seen in its slot.
    First,
    /// In place of one that crashed, exited or hung.
    Restart,
    /// By a scale-up, into a slot a scale-down emptied or is still emptying.
    Scale,
}

/// The worker incarnations announced and lost per slot. An incarnation above 0 is not by itself
/// a restart: a scale-up refills a slot whose worker a scale-down is still stopping (it finishes
/// its rollout first) with the next incarnation, and that is a scale.
#[derive(Debug, Default)]
struct WorkerSlots {
    /// slot → (incarnations announced and not lost, the reason of the slot's last loss).
    slots: std::collections::HashMap<u32, (Vec<u32>, Option<u32>)>,
}

impl WorkerSlots {
    fn announced(&mut self, worker: u32, incarnation: u32) -> Started {
        let (live, last_loss) = self.slots.entry(worker).or_default();
        // A worker that exited on purpose is not restarted either: what fills its slot again
        // comes from a scale-up.
        let started = if live.iter().any(|&i| i < incarnation)
            || matches!(
                *last_loss,
                Some(wire::lost::SCALED_DOWN | wire::lost::EXITED)
            ) {
            Started::Scale
        } else if incarnation > 0 {
            // Also when the loss was never seen (a restarted recorder joins a run under way).
            Started::Restart
        } else {
            Started::First
        };
        live.push(incarnation);
        started
    }

    fn lost(&mut self, worker: u32, incarnation: u32, reason: u32) {
        let (live, last_loss) = self.slots.entry(worker).or_default();
        live.retain(|&i| i != incarnation);
        *last_loss = Some(reason);
    }
}

impl WriterState {
    /// The most a `write` of updates to the OS holds, about (bytes of messages before
    /// compression): 17 A1 updates, 3 of T-ball. It bounds the memory of a long round and
    /// the time before its first acknowledgement.
    const WRITE_BYTES: u64 = 256 << 10;

    fn new(
        ctx: &Context,
        text: String,
        writer: RunFiles,
        resumed_from: Option<String>,
        start: Option<session::Start>,
    ) -> anyhow::Result<Self> {
        let cfg = ctx.config.clone();
        let task = cfg.build_task()?;
        let names: Vec<String> = task.settings().iter().map(|(n, _)| n.to_string()).collect();
        let basis = task.basis_activations();
        let (dim, steps) = (ctx.limits.dim, ctx.limits.steps);
        let lag = ctx.limits.recorder_max_lag();
        let mut assembler = Assembler::new(
            cfg.hyperparameters(),
            dim,
            steps,
            basis.clone(),
            names.clone(),
            lag,
        );
        // A resumed run's first update is compared with the settings the recording it resumes
        // ended with, so that a change taking effect there (a scheduled one the stopped run did
        // not reach) is recorded, as the in-process runner records it. Without them only that
        // marker is lost.
        // A new run's first update is compared with the task's configured settings: a change
        // taking effect at update 0 (a schedule's `from_update = 0`, a `supervisor set` before
        // the first update) is then recorded at 0, as the in-process runner records it; the
        // updater publishes update 0 with itself as the update before.
        let ran_before: Option<Vec<f64>> = match (start.as_ref(), &resumed_from) {
            (Some(start), _) => Some(
                names
                    .iter()
                    .map(|n| {
                        start
                            .settings
                            .iter()
                            .find(|(s, _)| s == n)
                            .map_or(f64::NAN, |(_, v)| *v)
                    })
                    .collect(),
            ),
            (None, None) => Some(task.settings().iter().map(|(_, v)| *v).collect()),
            // A resumed run whose resume point was not found: no settings to compare with.
            (None, Some(_)) => None,
        };
        if let Some(settings) = ran_before {
            assembler.continue_from(settings);
        }
        Ok(Self {
            writer,
            assembler,
            config: cfg,
            text,
            names,
            basis,
            steps,
            dim,
            run_id: ctx.run_id,
            pid: std::process::id(),
            started: false,
            final_update: None,
            stopped: false,
            // What comes before the first distribution (the processes' announcements, the
            // supervisor's START) happens at the update the run starts at: a resumed run's
            // logged it at update 0, which its recording does not hold.
            current_update: start.map_or(0, |s| s.update),
            written: 0,
            mismatches: 0,
            not_recorded: Vec::new(),
            resumed_from,
            restart: None,
            deferred: Vec::new(),
            slots: WorkerSlots::default(),
            worker_names: WorkerNames::default(),
            reruns: Default::default(),
            lag,
            ahead: OncePerWorker::default(),
        })
    }

    /// Whether every update up to the `FINAL` distribution has been written.
    fn done(&self) -> bool {
        self.final_update
            .is_some_and(|f| self.assembler.first_update().is_none_or(|n| n >= f))
    }

    /// Logs the recorder's exit and `why` (`run complete`, `signal`, `run ended`) and
    /// finishes the file (summary, indexes); returns the number of updates written.
    fn finish(mut self, why: &str) -> anyhow::Result<u64> {
        let pid = self.pid;
        let (written, mismatches) = (self.written, self.mismatches);
        // A change that takes effect at the update after the last written one (the run was
        // stopped right after `supervisor set`, or before a scheduled change) reached the
        // published distribution but no update: without it here, `--resume` would go on with
        // the old settings and the joined analysis would lack its marker.
        // A change its rollouts in so far did not run with was refused by the workers' task:
        // not a change, so that `--resume` goes on with the value in force.
        if let Some(ahead) = self.assembler.changes_ahead() {
            let u = ahead.update;
            for (name, value) in &ahead.changed {
                self.writer.write_task_change(u, name, *value)?;
            }
            for (name, asked, ran) in &ahead.refused {
                self.write_refusal(u, ", which the run stopped in,", name, *asked, *ran)?;
            }
            // All the settings the update was to run with: a `set` that overrode a scheduled
            // change back to the value in force is no change above, and `--resume` would
            // apply the schedule's change again without them. The FINAL distribution's update
            // does not run, and its settings hold no change due at it, unless the run stopped
            // there on request: then they are what it goes on with.
            if self.final_update != Some(u) || self.stopped {
                let settings: Vec<(&str, f64)> = self
                    .names
                    .iter()
                    .map(String::as_str)
                    .zip(ahead.settings.iter().copied())
                    .collect();
                self.writer
                    .write_unfinished_update(u, &settings, self.stopped)?;
            }
        }
        // A restarted recorder stopped before its first distribution has no part (it is
        // created with its `/run`): what it took in goes to its output only.
        if !self.writer.has_part() {
            for (event, name, pid, message) in std::mem::take(&mut self.deferred) {
                eprintln!("not recorded ({event:?} {name}, pid {pid}): {message}");
            }
            eprintln!("no part written: the run ended before the first update after the restart");
            self.writer.finish()?;
            return Ok(written);
        }
        self.writer.write_event(
            self.current_update,
            Event::Exit,
            "recorder",
            pid,
            &format!(
                "recorder exits ({why}): {written} updates written, {mismatches} recomputation \
                 mismatches"
            ),
        )?;
        self.writer.finish()?;
        Ok(written)
    }

    fn handle(&mut self, m: Msg<'_>) -> anyhow::Result<()> {
        let pid = self.pid;
        match m {
            Msg::Distribution(h, mean, cov) => {
                let p = self.dim;
                let settings = wire::unpack_settings(&h.settings, h.settings_len);
                let previous = wire::unpack_settings(&h.previous_settings, h.settings_len);
                if !self.started {
                    self.started = true;
                    // What the update before ran with: a change taking effect at the first
                    // update of this part (or of a run joined under way) is recorded as one.
                    // A new run's update 0 is compared with the configured settings instead
                    // (`WriterState::new`), a resumed run's with its recording's.
                    let joined = self.resumed_from.is_none() && h.update > 0;
                    if self.restart.is_some() || joined {
                        self.assembler.continue_from(previous.to_vec());
                    }
                    let initial = pi2cma::Distribution {
                        mean: nalgebra::DVector::from_column_slice(mean),
                        covariance: nalgebra::DMatrix::from_column_slice(p, p, cov),
                    };
                    let named = |values: &[f64]| -> Vec<(&str, f64)> {
                        self.names
                            .iter()
                            .map(String::as_str)
                            .zip(values.iter().copied())
                            .collect()
                    };
                    let task_settings = named(settings);
                    // So that `--resume` from a part that holds no update knows what a worker
                    // refusing a change at its first update falls back to.
                    let previous_task_settings = named(previous);
                    self.writer.write_start(&RunStart {
                        name: &self.config.run.name,
                        seed: h.seed,
                        update: h.update,
                        steps: self.steps,
                        hyperparameters: self.assembler.hyperparameters(),
                        initial: &initial,
                        basis_activations: self.basis.as_deref(),
                        config_toml: &self.text,
                        executor: "pipeline",
                        task_settings: &task_settings,
                        previous_task_settings: &previous_task_settings,
                        resumed_from: self.resumed_from.as_deref(),
                        part: None,
                        run_id: Some(self.run_id),
                        recorder_restart: self.restart,
                    })?;
                    if let Some(n) = self.restart {
                        self.writer.write_event(
                            h.update,
                            Event::Warning,
                            "recorder",
                            pid,
                            &format!(
                                "{} (restart {n}) after the one before it died: this part \
                                 begins at update {}; the updates between the last one of the \
                                 part before and this one were not recorded",
                                crate::digest::RECORDER_RESTARTED,
                                h.update
                            ),
                        )?;
                        for (event, name, pid, message) in std::mem::take(&mut self.deferred) {
                            self.writer
                                .write_event(h.update, event, &name, pid, &message)?;
                        }
                    }
                    self.writer.write_event(
                        h.update,
                        Event::Start,
                        "recorder",
                        pid,
                        &format!(
                            "recording run {} from update {}",
                            wire::run_id_hex(self.run_id),
                            h.update
                        ),
                    )?;
                }
                self.current_update = self.current_update.max(h.update);
                // The updater's λ of it: the recorded λs are the ones it published (the
                // recomputation checks the distributions, which λ follows from).
                self.assembler.distribution(
                    h.update,
                    h.seed,
                    mean,
                    cov,
                    settings,
                    Some(h.lambda),
                )?;
                self.report_dropped()?;
                if h.flags & DistributionHeader::FINAL != 0 {
                    self.final_update = Some(h.update);
                    self.stopped = h.flags & DistributionHeader::STOPPED != 0;
                    if self.stopped {
                        self.log(
                            Event::Info,
                            "updater",
                            0,
                            &format!(
                                "run stopped before update {} as asked (`supervisor stop \
                                 --after-update`): no rollout of it ran; a resumed run goes on \
                                 from it",
                                h.update
                            ),
                        )?;
                    }
                }
            }
            Msg::Control(c) => match c.kind {
                Control::WORKER_LOST => {
                    self.slots.lost(c.worker, c.incarnation, c.reason);
                    let (event, what) = match c.reason {
                        wire::lost::SCALED_DOWN => (Event::Scale, "stopped by a scale-down"),
                        wire::lost::STOPPED => (Event::Exit, "stopped with the run"),
                        wire::lost::EXITED => (
                            Event::Exit,
                            "exited on its own with status 0, taken as stopped on purpose (not \
                             restarted)",
                        ),
                        wire::lost::HUNG => (
                            Event::Crash,
                            "hung (no rollout done for longer than pipeline.rollout_timeout_ms) and was \
                             killed",
                        ),
                        _ => (Event::Crash, "crashed"),
                    };
                    // Stopped with the run, the other workers are stopping too: its
                    // rollouts go nowhere (the update stays unfinished).
                    let rollouts = if c.reason == wire::lost::STOPPED {
                        ""
                    } else {
                        "; the rollouts it held go to the other workers"
                    };
                    self.log(
                        event,
                        &format!("worker-{}", c.worker),
                        c.pid,
                        &format!(
                            "worker-{} (incarnation {}) {what} ({}){rollouts}",
                            c.worker,
                            c.incarnation,
                            c.name()
                        ),
                    )?
                }
                Control::SET_TASK => self.log(
                    Event::Info,
                    "supervisor",
                    0,
                    &format!(
                        "task change requested: {} = {} (takes effect with the next \
                         distribution)",
                        c.name(),
                        c.value
                    ),
                )?,
                Control::START => self.log(Event::Info, "supervisor", 0, "start")?,
                _ => {}
            },
            Msg::Note(n) => {
                let event = match n.level {
                    RunNote::ERROR => Event::Error,
                    RunNote::WARNING => Event::Warning,
                    _ => Event::Info,
                };
                self.log(event, "supervisor", 0, n.text())?;
            }
            Msg::Lifecycle(l) => {
                if l.pid == pid {
                    return Ok(());
                }
                let (event, what) = if l.role == wire::role::WORKER {
                    match self.slots.announced(l.worker, l.incarnation) {
                        Started::Restart => (Event::Restart, "restarted"),
                        Started::Scale => (Event::Scale, "joined the running run"),
                        Started::First if self.written > 0 => {
                            (Event::Scale, "joined the running run")
                        }
                        Started::First => (Event::Start, "ready"),
                    }
                } else if l.incarnation > 0 {
                    (Event::Restart, "restarted")
                } else {
                    (Event::Start, "ready")
                };
                self.log(
                    event,
                    &role_name(&l),
                    l.pid,
                    &format!(
                        "{} (pid {}, incarnation {}) {what}",
                        role_name(&l),
                        l.pid,
                        l.incarnation
                    ),
                )?;
            }
        }
        Ok(())
    }

    /// A cost message, with the time it was taken in, read only for a worker that does not
    /// stamp its rollouts (see [`rollout_timing`]), 0 otherwise: whether it is kept (not
    /// dropped as out of the updater's reach).
    fn cost(&mut self, h: CostHeader, costs: &[f64], received_ns: u64) -> anyhow::Result<bool> {
        let timing = rollout_timing(&h, received_ns, &mut self.worker_names);
        let ran_with = (h.settings_len > 0).then(|| h.ran_with(&[]));
        match self.assembler.cost(
            h.update,
            h.rollout as usize,
            costs,
            h.terminal,
            timing,
            ran_with,
        ) {
            Ok(CostOutcome::Stored | CostOutcome::Stale | CostOutcome::Duplicate) => {}
            Ok(CostOutcome::OutOfReach { limit }) => {
                self.cost_ahead(&h, limit)?;
                return Ok(false);
            }
            // Before a restarted recorder's first distribution, it has no part yet.
            Err(e) => self.cost_rejected(&h, &e)?,
        }
        Ok(true)
    }

    /// The warning for costs of an update the updater cannot be at (the assembler's
    /// [`CostOutcome::OutOfReach`]), once per worker ([`OncePerWorker`]).
    fn cost_ahead(&mut self, h: &CostHeader, limit: Option<u64>) -> anyhow::Result<()> {
        let by = format!("worker-{}", h.worker);
        let lag = self.lag;
        let message = match self.ahead.say(h.worker) {
            Say::Nothing => return Ok(()),
            Say::First => {
                let why = match limit {
                    Some(limit) => format!(
                        "the updater runs at most {lag} updates (the lag bound) ahead of the \
                         recorder and publishes an update's distribution before its costs, so \
                         no update from {limit} on (the lag bound past the newest distribution \
                         the recorder has taken in) can be under way"
                    ),
                    None => format!(
                        "before its first distribution the recorder keeps the costs of at most \
                         {} updates (the lag bound {lag}, and one more)",
                        lag + 1
                    ),
                };
                format!(
                    "cost of update {} (rollout {}) from {by} dropped: {why}. Was the worker \
                     started with another config? Its further costs of such updates are \
                     dropped without a word",
                    h.update, h.rollout
                )
            }
            Say::Last => format!(
                "cost of update {} from {by} dropped as out of the updater's reach too: more \
                 than {} workers sent such costs; any more are dropped without a word",
                h.update,
                OncePerWorker::NAMED
            ),
        };
        self.log(Event::Warning, &by, 0, &message)
    }

    /// The warnings for costs held from before the first distribution and dropped at it.
    fn report_dropped(&mut self) -> anyhow::Result<()> {
        let lag = self.lag;
        for Dropped {
            update,
            first,
            workers,
        } in self.assembler.take_dropped()
        {
            let message = format!(
                "costs of update {update} from {} dropped: the recording begins at update \
                 {first}, and the updater runs at most {lag} updates (the lag bound) ahead of it. \
                 Was a worker started with another config?",
                workers.join(", ")
            );
            self.log(Event::Warning, "recorder", self.pid, &message)?;
        }
        Ok(())
    }

    /// The event for costs the assembler rejected: a warning for an execution with non-finite
    /// costs that the updater runs again, otherwise (the run fails on it) an error.
    ///
    /// Whether the updater reruns it is re-derived here with the updater's own policy
    /// ([`NonfiniteReruns`]) from the same cost messages, rather than read from the updater's
    /// `reruns` service (the sampler's, which this process does not subscribe to):
    /// - The execution that fails the run is in no `reruns` sample (the updater exits), so the
    ///   recorder must judge a non-finite cost itself anyway to log that error and its rerun
    ///   count; `reruns` would be a second source for what this count already gives.
    /// - `reruns` and the costs come on two services with no order between them: pairing them
    ///   needs costs held in both directions, and a non-finite cost not yet counted in a
    ///   `reruns` sample is a rerun not yet announced or the run's failure, which cannot be
    ///   told apart until the run ends.
    /// - The warning quotes the rejected value and step, which only the cost message carries.
    /// - The costs service is the one sized for a lagging recorder (it holds the updater back
    ///   through it).
    ///
    /// The counts agree with the updater's because both count the same messages per rollout,
    /// and a rollout's next execution is handed out only after its rejection; one taken in
    /// after the rerun that replaced it still comes here (the assembler checks a second
    /// execution's costs before it calls it a twin). What re-deriving cannot know (the
    /// updater's counts would give it): a recorder restarted between a rollout's rejected
    /// executions counts from its restart, so it logs lower attempt numbers and rerun count
    /// than the updater's; and with two executions of one rollout waiting in its costs
    /// subscriber at once (a recorder busy writing; receiving does not keep the order between
    /// two workers' messages), the workers named for attempts 1 and 2 may be swapped. Both only
    /// change the wording of the health log.
    fn cost_rejected(&mut self, h: &CostHeader, e: &CostError) -> anyhow::Result<()> {
        let by = format!("worker-{}", h.worker);
        let limit = self.config.run.nonfinite_reruns;
        let tried = match e {
            CostError::NonFinite { .. } if limit > 0 => {
                if let Some(first) = self.assembler.first_update() {
                    self.reruns.retain(|&u, _| u >= first);
                }
                let rollouts = self.config.optimizer.rollouts;
                let verdict = self
                    .reruns
                    .entry(h.update)
                    .or_insert_with(|| NonfiniteReruns::new(limit, rollouts))
                    .reject(h.rollout as usize);
                match verdict {
                    Verdict::Rerun { attempt } => {
                        let message = rerun_message(h.update, e, attempt, limit, &by);
                        return self.log_at(h.update, Event::Warning, &by, 0, &message);
                    }
                    Verdict::Fail { reruns } => reruns,
                }
            }
            _ => 0,
        };
        let message = format!(
            "cost of update {} rejected: {e}{}",
            h.update,
            after_reruns(e, tried)
        );
        self.log_at(h.update, Event::Error, &by, 0, &message)
    }

    /// `lost` messages of the supervisor on `control` overflowed this process's buffer
    /// (`buffer` of them): health events and task-change requests among them are missing.
    fn control_lost(&mut self, lost: u64, buffer: usize) -> anyhow::Result<()> {
        let message = format!(
            "{lost} message{} of the supervisor on `control` never reached the recorder (its \
             buffer of {buffer} overflowed: the recorder was stalled): worker exits, scale-downs, \
             crashes or task-change requests among them are missing from /log",
            if lost == 1 { "" } else { "s" }
        );
        let pid = self.pid;
        self.log(Event::Error, "recorder", pid, &message)
    }

    /// An event on /log at the update at hand. A restarted recorder keeps what comes before
    /// its first distribution for the update it begins at, after its `/run`.
    fn log(&mut self, event: Event, name: &str, pid: u32, message: &str) -> anyhow::Result<()> {
        self.log_at(self.current_update, event, name, pid, message)
    }

    /// An event on /log at `update` (deferred as [`Self::log`] does).
    fn log_at(
        &mut self,
        update: u64,
        event: Event,
        name: &str,
        pid: u32,
        message: &str,
    ) -> anyhow::Result<()> {
        if !self.writer.has_part() {
            self.deferred
                .push((event, name.to_string(), pid, message.to_string()));
            return Ok(());
        }
        self.writer.write_event(update, event, name, pid, message)?;
        Ok(())
    }

    /// The `warning` on /log for a change the workers' task refused at update `u` (`which`
    /// describes the update, after its number).
    fn write_refusal(
        &mut self,
        u: u64,
        which: &str,
        name: &str,
        asked: f64,
        ran: f64,
    ) -> anyhow::Result<()> {
        self.writer.write_event(
            u,
            Event::Warning,
            "workers",
            0,
            &format!(
                "task change {name} = {} refused by the workers' task: update {u}{which} ran with \
                 {name} = {}, which stays in force",
                tasks::value_text(asked),
                tasks::value_text(ran)
            ),
        )?;
        Ok(())
    }

    /// Writes every complete update; with `skip_lost`, also gives up (with an `error` event) on
    /// updates whose inputs can no longer arrive, and writes what that unblocks.
    /// Calls `written(u)` once the updates up to u are written and flushed (or given up), for
    /// the newest u of every `write` to the OS.
    ///
    /// The updates complete at once (a round's, at full speed several) are handed to the OS
    /// together, in one `write` of at most [`WriterState::WRITE_BYTES`] (and acknowledged then): the
    /// page cache takes larger writes for less CPU per byte ([`crate::RunWriter::hold_output`]).
    /// A SIGKILL loses what this call has not flushed, the round's updates, as before.
    fn write_complete(
        &mut self,
        skip_lost: bool,
        written: &mut dyn FnMut(u64) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        let pid = self.pid;
        loop {
            let mut unflushed = None;
            while let Some(a) = self.assembler.next_complete() {
                let a = a?;
                for (name, value) in &a.changed {
                    self.writer.write_task_change(a.update, name, *value)?;
                }
                for (name, asked, ran) in &a.refused {
                    self.write_refusal(a.update, "", name, *asked, *ran)?;
                }
                let settings: Vec<(&str, f64)> =
                    a.settings.iter().map(|(n, v)| (n.as_str(), *v)).collect();
                let start = a
                    .timings
                    .iter()
                    .map(|t| t.start_ns)
                    .filter(|t| *t > 0)
                    .min();
                let end = a.timings.iter().map(|t| t.end_ns).max();
                let begun = self.writer.write_update(&UpdateData {
                    hyperparameters: self.assembler.hyperparameters(),
                    before: &a.before,
                    after: &a.after,
                    samples: &a.samples,
                    costs: &a.costs,
                    summary: &a.summary,
                    task_settings: &settings,
                    batch_start_ns: start.unwrap_or(0),
                    batch_end_ns: end.unwrap_or(0),
                    rollouts: &a.timings,
                    default_worker: "unknown",
                })?;
                self.written += 1;
                if let Some(part) = begun {
                    eprintln!("recording continues in {}", part.display());
                }
                if !a.recomputed_matches {
                    self.mismatches += 1;
                    self.writer.write_event(
                        a.update,
                        Event::Error,
                        "recorder",
                        pid,
                        &format!(
                        "update {}: the core, given the recorded inputs, does not reproduce the \
                         published distribution of update {}",
                        a.update,
                        a.update + 1
                    ),
                    )?;
                }
                if a.duplicates > 0 {
                    self.writer.write_event(
                        a.update,
                        Event::Info,
                        "recorder",
                        pid,
                        &format!(
                        "update {}: {} rollouts executed twice (after a worker loss); the first \
                         result of each was kept",
                        a.update, a.duplicates
                    ),
                    )?;
                }
                self.assembler.recycle(a.costs);
                unflushed = Some(a.update);
                if self.writer.held_bytes() >= Self::WRITE_BYTES {
                    self.writer.flush()?;
                    written(a.update)?;
                    unflushed = None;
                }
            }
            if let Some(u) = unflushed {
                self.writer.flush()?;
                written(u)?;
            }
            if !skip_lost {
                return Ok(());
            }
            let Some((u, what)) = self.assembler.skip_incomplete() else {
                return Ok(());
            };
            self.writer.write_event(
                u,
                Event::Error,
                "recorder",
                pid,
                &format!(
                    "update {u} not recorded: {what} never reached the recorder (dropped by the \
                     services' safe overflow, or sent by a worker that exited before the \
                     recorder connected to it: see \"Nothing lost\" in the README)"
                ),
            )?;
            self.writer.flush()?;
            self.not_recorded.push(u);
            written(u)?;
        }
    }
}

/// `worker-<w>` for the workers seen, each formatted once: every cost message names its worker,
/// and a `format!` per message showed in the recorder's profile.
#[derive(Debug, Default)]
struct WorkerNames(Vec<String>);

impl WorkerNames {
    /// Worker ids are slots below `pipeline.max_workers`; a larger one is formatted, not kept.
    const KEPT: usize = session::PipelineSection::WORKER_LIMIT;

    fn name(&mut self, worker: u32) -> String {
        let w = worker as usize;
        if w >= Self::KEPT {
            return format!("worker-{worker}");
        }
        while self.0.len() <= w {
            let next = self.0.len();
            self.0.push(format!("worker-{next}"));
        }
        self.0[w].clone()
    }
}

/// When rollout `h` ran: as its worker stamped it, or, from a worker that does not
/// (`start_ns` = 0), the interval that ended when the costs were taken in (up to a round late).
fn rollout_timing(h: &CostHeader, received_ns: u64, names: &mut WorkerNames) -> RolloutTiming {
    let start_ns = match h.start_ns {
        0 => received_ns.saturating_sub(h.duration_ns),
        t => t,
    };
    RolloutTiming {
        worker: names.name(h.worker),
        start_ns,
        end_ns: start_ns.saturating_add(h.duration_ns),
    }
}

/// CPU time (user + system) this process has used, in seconds; 0 if unknown.
fn process_cpu_seconds() -> f64 {
    // SAFETY: getrusage writes into the struct it is given and reads nothing else.
    #[allow(unsafe_code)]
    let usage = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        (libc::getrusage(libc::RUSAGE_SELF, &mut u) == 0).then_some(u)
    };
    usage.map_or(0.0, |u| {
        let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
        t(u.ru_utime) + t(u.ru_stime)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::RefCell;
    use std::collections::VecDeque;

    /// Whatever moment between the two drains the updater publishes a distribution and a
    /// worker its first cost at, the first distribution left has all its costs left.
    #[test]
    fn updates_not_recorded_are_named_as_ranges() {
        assert_eq!(super::update_ranges(&[6]), "6");
        assert_eq!(super::update_ranges(&[3, 6, 7, 8, 12]), "3, 6..=8, 12");
        assert_eq!(super::update_ranges(&[6, 7, 8, 9, 10, 11]), "6..=11");
        assert_eq!(super::plural(1, "update"), "1 update");
        assert_eq!(super::plural(12, "update"), "12 updates");
    }

    #[test]
    fn a_restarted_recorder_keeps_no_distribution_without_its_costs() {
        // (distribution update, costs' updates) the subscribers hold; `publish_after` is the
        // number of empty receives after which update 6 and one of its costs arrive.
        for publish_after in 0..3 {
            let dists = RefCell::new(VecDeque::from([5u64]));
            let costs = RefCell::new(VecDeque::from([5u64, 5]));
            let empty = RefCell::new(0);
            let arrive = || {
                let mut n = empty.borrow_mut();
                *n += 1;
                if *n == publish_after + 1 {
                    dists.borrow_mut().push_back(6);
                    costs.borrow_mut().push_back(6);
                }
            };
            drop_backlog(
                &mut || {
                    let got = costs.borrow_mut().pop_front().is_some();
                    if !got {
                        arrive();
                    }
                    Ok(got)
                },
                &mut || {
                    let got = dists.borrow_mut().pop_front().is_some();
                    if !got {
                        arrive();
                    }
                    Ok(got)
                },
            )
            .unwrap();
            // The rest of update 6's costs come later: they are there for a distribution left.
            let left = dists.borrow().front().copied();
            if let Some(u) = left {
                assert!(
                    costs.borrow().contains(&u),
                    "update {u} kept without its first cost ({publish_after})"
                );
            }
        }
    }

    #[test]
    fn a_slot_refilled_by_a_scale_up_is_a_scale_not_a_restart() {
        let mut slots = WorkerSlots::default();
        assert_eq!(slots.announced(2, 0), Started::First);
        // Scaled down and straight back up: incarnation 1 announces while 0 finishes its
        // rollout, and 0's loss comes after.
        assert_eq!(slots.announced(2, 1), Started::Scale);
        slots.lost(2, 0, wire::lost::SCALED_DOWN);
        // Scaled down, stopped, then back up.
        slots.lost(2, 1, wire::lost::SCALED_DOWN);
        assert_eq!(slots.announced(2, 2), Started::Scale);
        // A crash, then its replacement.
        slots.lost(2, 2, wire::lost::CRASHED);
        assert_eq!(slots.announced(2, 3), Started::Restart);
        slots.lost(2, 3, wire::lost::HUNG);
        assert_eq!(slots.announced(2, 4), Started::Restart);
        // Exited on its own with status 0: not restarted, so what comes next is a scale-up.
        slots.lost(2, 4, wire::lost::EXITED);
        assert_eq!(slots.announced(2, 5), Started::Scale);
        // A restarted recorder may see an incarnation above 0 with no history in its slot: it
        // cannot tell, and says restart, as before the slots were tracked.
        assert_eq!(slots.announced(5, 3), Started::Restart);
        assert_eq!(slots.announced(0, 0), Started::First);
    }

    #[test]
    fn a_rollout_is_recorded_when_its_worker_ran_it() {
        let h = CostHeader {
            worker: 2,
            duration_ns: 300,
            start_ns: 1_000,
            ..Default::default()
        };
        // Taken in a round later: the worker's stamp, not the arrival, places it.
        let mut names = WorkerNames::default();
        let t = rollout_timing(&h, 900_000, &mut names);
        assert_eq!(
            (t.worker.as_str(), t.start_ns, t.end_ns),
            ("worker-2", 1_000, 1_300)
        );
        // A worker that does not stamp: the interval ending at the arrival.
        let unstamped = CostHeader { start_ns: 0, ..h };
        let t = rollout_timing(&unstamped, 900_000, &mut names);
        assert_eq!((t.start_ns, t.end_ns), (899_700, 900_000));
        // Names kept or not, each is the worker's own.
        for w in [0, 2, 7, 2, 255, 256, u32::MAX] {
            assert_eq!(names.name(w), format!("worker-{w}"));
        }
    }
}
