//! The pipeline's recorder process (the `recorder` binary; the `supervisor` binary hosts the same
//! role): subscribes to the run's iceoryx2 services (see the `wire` crate) and writes the run's
//! MCAP with the same schemas as the in-process recorder.
//!
//! It owns no doorbell of its own (the wire contract has none for it): it is the second listener
//! on `wake/updater` (rung for every cost trajectory and control message), `wake/sampler` (rung
//! for every distribution) and `wake/supervisor` (lifecycle), and the spare subscriber of
//! `distribution`, `costs`, `control` and `lifecycle`. Because those services keep no history,
//! it must be subscribed before the updater publishes the distribution of update 0: start it
//! first and wait for its `lifecycle` message (role [`ROLE_RECORDER`]) before sending START.
//!
//! Two threads: the main thread only drains the subscribers into memory (a copy per message,
//! microseconds), so the services' small buffers never overflow because of the recorder; the
//! writer thread assembles the updates, recomputes each with the core from the recorded inputs
//! (the samples are re-drawn from (seed, update, k)), logs a mismatch with the distribution the
//! updater published as an `error` event on `/log`, writes it, and flushes the file. A SIGKILL
//! loses the update being written and any the writer had not reached yet (none while it keeps
//! up); `mcap-tool recover` completes the file. SIGINT/SIGTERM finish the file (summary and
//! indexes) after writing everything received, and exit 0.

use std::path::PathBuf;

use crate::assemble::{Assembler, CostOutcome};
use crate::{now_ns, Event, RolloutTiming, RunStart, RunWriter, UpdateData};
use anyhow::Context as _;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use pipeline::{announce_ready, iox, Context};
use wire::{Control, CostHeader, DistributionHeader, Lifecycle};

/// The `lifecycle` role this process announces.
pub const ROLE_RECORDER: u32 = wire::role::RECORDER;

/// The recorder's arguments: the usual process arguments and where to write.
#[derive(Debug, Clone, clap::Args)]
pub struct RecorderArgs {
    #[command(flatten)]
    pub process: pipeline::ProcessArgs,
    /// Where to write the recording; default `<run dir>/run.mcap`.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// What the receiving thread hands to the writing thread, in arrival order.
enum Msg {
    Distribution(DistributionHeader, Vec<f64>),
    Cost(CostHeader, Vec<f64>, u64),
    Control(Control),
    Lifecycle(Lifecycle),
    /// The receiving thread has drained every subscriber once: everything published before
    /// the newest distribution it passed on has been passed on too.
    Drained,
    /// No more messages; `true` if a signal ended the run.
    End(bool),
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
    let ctx = Context::new(&cli.process, "recorder")?;
    let text = std::fs::read_to_string(&cli.process.config)
        .with_context(|| format!("{}: cannot read", cli.process.config.display()))?;
    let out = cli
        .out
        .clone()
        .unwrap_or_else(|| ctx.run_dir.join("run.mcap"));

    let dist_sub = iox(
        wire::distribution(&ctx.node, ctx.run_id, &ctx.limits)?
            .subscriber_builder()
            .create(),
        "distribution subscriber",
    )?;
    let costs_sub = iox(
        wire::costs(&ctx.node, ctx.run_id, &ctx.limits)?
            .subscriber_builder()
            .create(),
        "costs subscriber",
    )?;
    let control_sub = iox(
        wire::control(&ctx.node, ctx.run_id, &ctx.limits)?
            .subscriber_builder()
            .create(),
        "control subscriber",
    )?;
    let lifecycle_sub = iox(
        wire::lifecycle(&ctx.node, ctx.run_id, &ctx.limits)?
            .subscriber_builder()
            .create(),
        "lifecycle subscriber",
    )?;
    let mut bells = Vec::new();
    for owner in ["updater", "sampler", "supervisor"] {
        bells.push(ctx.listener(owner)?);
    }
    let waitset = iox(
        WaitSetBuilder::new().create::<wire::Service>(),
        "cannot create waitset",
    )?;
    let mut guards = Vec::new();
    for b in &bells {
        guards.push(iox(
            waitset.attach_notification(b),
            "cannot attach doorbell",
        )?);
    }

    let writer = RunWriter::create(&out)?;
    let (tx, rx) = std::sync::mpsc::channel::<Msg>();
    let state = WriterState::new(&ctx, text, writer)?;
    let writing = std::thread::Builder::new()
        .name("writer".into())
        .spawn(move || state.run(rx))
        .context("cannot start the writer thread")?;
    let _announced = announce_ready(&ctx, ROLE_RECORDER, 0, 0)?;
    eprintln!("recording to {}", out.display());

    let p = ctx.limits.dim;
    let send = |m: Msg| {
        tx.send(m)
            .map_err(|_| anyhow::anyhow!("the writer thread has stopped"))
    };
    let mut result = Ok(());
    let signal = loop {
        for b in &bells {
            iox(b.try_wait(|_| {}), "doorbell")?;
        }
        // Distributions before costs: every cost of update u was published before the
        // distribution of u + 1, so after this order of draining, a seen distribution's
        // predecessor costs are all in hand.
        let mut last = false;
        while let Some(s) = iox(dist_sub.receive(), "receive distribution")? {
            let h: DistributionHeader = *s.user_header();
            if h.run_id != ctx.run_id {
                continue;
            }
            let payload = s.payload();
            if payload.len() < p + p * p {
                result = Err(anyhow::anyhow!(
                    "distribution of update {}: {} values, expected {}",
                    h.update,
                    payload.len(),
                    p + p * p
                ));
                break;
            }
            last |= h.flags & DistributionHeader::FINAL != 0;
            send(Msg::Distribution(h, payload[..p + p * p].to_vec()))?;
        }
        while let Some(s) = iox(costs_sub.receive(), "receive costs")? {
            let h = *s.user_header();
            if h.run_id == ctx.run_id {
                send(Msg::Cost(h, s.payload().to_vec(), now_ns()))?;
            }
        }
        while let Some(s) = iox(control_sub.receive(), "receive control")? {
            if s.payload().run_id == ctx.run_id {
                send(Msg::Control(*s.payload()))?;
            }
        }
        while let Some(s) = iox(lifecycle_sub.receive(), "receive lifecycle")? {
            if s.payload().run_id == ctx.run_id {
                send(Msg::Lifecycle(*s.payload()))?;
            }
        }
        // The writer thread stops by itself after the final update; a marker it no longer
        // needs is not an error.
        let _ = tx.send(Msg::Drained);
        if last || result.is_err() {
            break false;
        }
        match iox(
            // A bounded wait: iceoryx2 0.10's WaitSet can miss a wake-up when several processes
            // notify at once; the pipeline's processes use the same 100 ms safety tick.
            waitset.wait_and_process_once_with_timeout(
                |_| CallbackProgression::Continue,
                std::time::Duration::from_millis(100),
            ),
            "waitset",
        )? {
            WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt => break true,
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
        }
    };
    let _ = tx.send(Msg::End(signal));
    let written = writing
        .join()
        .map_err(|_| anyhow::anyhow!("the writer thread panicked"))??;
    eprintln!("recorded {written} updates to {}", out.display());
    result
}

/// The writing thread: assembles updates, recomputes and writes them.
struct WriterState {
    writer: RunWriter<std::io::BufWriter<std::fs::File>>,
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
    current_update: u64,
    written: u64,
    mismatches: u64,
}

impl WriterState {
    fn new(
        ctx: &Context,
        text: String,
        writer: RunWriter<std::io::BufWriter<std::fs::File>>,
    ) -> anyhow::Result<Self> {
        let cfg = ctx.config.clone();
        let task = session::build_task(&cfg)?;
        let names: Vec<String> = task.settings().iter().map(|(n, _)| n.to_string()).collect();
        let basis = task.basis_activations();
        let (dim, steps) = (ctx.limits.dim, ctx.limits.steps);
        let assembler = Assembler::new(
            cfg.hyperparameters(),
            dim,
            steps,
            basis.clone(),
            names.clone(),
        );
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
            current_update: 0,
            written: 0,
            mismatches: 0,
        })
    }

    fn run(mut self, rx: std::sync::mpsc::Receiver<Msg>) -> anyhow::Result<u64> {
        let mut signal = true;
        while let Ok(m) = rx.recv() {
            match m {
                Msg::End(s) => {
                    signal = s;
                    break;
                }
                // Only at a drain boundary may a missing input count as lost: within one drain
                // the distributions are passed on before the costs that precede them.
                Msg::Drained => self.write_complete(true)?,
                m => {
                    self.handle(m)?;
                    self.write_complete(false)?;
                }
            }
            if self
                .final_update
                .is_some_and(|f| self.assembler.first_update().is_none_or(|n| n >= f))
            {
                signal = false;
                break;
            }
        }
        let pid = self.pid;
        let (written, mismatches) = (self.written, self.mismatches);
        self.writer.write_event(
            self.current_update,
            Event::Exit,
            "recorder",
            pid,
            &format!(
                "recorder exits ({}): {written} updates written, {mismatches} recomputation \
                 mismatches",
                if signal { "signal" } else { "run complete" }
            ),
        )?;
        self.writer.finish()?;
        Ok(written)
    }

    fn handle(&mut self, m: Msg) -> anyhow::Result<()> {
        let pid = self.pid;
        match m {
            Msg::Distribution(h, payload) => {
                let p = self.dim;
                let (mean, cov) = (&payload[..p], &payload[p..p + p * p]);
                let settings = &h.settings[..(h.settings_len as usize).min(h.settings.len())];
                if !self.started {
                    self.started = true;
                    let initial = pi2cma::Distribution {
                        mean: nalgebra::DVector::from_column_slice(mean),
                        covariance: nalgebra::DMatrix::from_column_slice(p, p, cov),
                    };
                    let task_settings: Vec<(&str, f64)> = self
                        .names
                        .iter()
                        .map(String::as_str)
                        .zip(settings.iter().copied())
                        .collect();
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
                    })?;
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
                self.assembler
                    .distribution(h.update, h.seed, mean, cov, settings)
                    .map_err(anyhow::Error::msg)?;
                if h.flags & DistributionHeader::FINAL != 0 {
                    self.final_update = Some(h.update);
                }
            }
            Msg::Cost(h, costs, end_ns) => {
                let timing = RolloutTiming {
                    worker: format!("worker-{}", h.worker),
                    start_ns: end_ns.saturating_sub(h.duration_ns),
                    end_ns,
                };
                match self
                    .assembler
                    .cost(h.update, h.rollout as usize, &costs, h.terminal, timing)
                {
                    Ok(CostOutcome::Stored | CostOutcome::Stale | CostOutcome::Duplicate) => {}
                    Err(e) => self.writer.write_event(
                        h.update,
                        Event::Error,
                        &format!("worker-{}", h.worker),
                        0,
                        &format!("cost of update {} rejected: {e}", h.update),
                    )?,
                }
            }
            Msg::Control(c) => match c.kind {
                Control::WORKER_LOST => self.writer.write_event(
                    self.current_update,
                    Event::Crash,
                    &format!("worker-{}", c.worker),
                    0,
                    &format!(
                        "worker {} (incarnation {}) lost: exited, crashed or scaled away; its \
                         rollouts go to the other workers",
                        c.worker, c.incarnation
                    ),
                )?,
                Control::SET_TASK => self.writer.write_event(
                    self.current_update,
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
                Control::START => self.writer.write_event(
                    self.current_update,
                    Event::Info,
                    "supervisor",
                    0,
                    "start",
                )?,
                _ => {}
            },
            Msg::Lifecycle(l) => {
                if l.pid == pid {
                    return Ok(());
                }
                let (event, what) = if l.incarnation > 0 {
                    (Event::Restart, "restarted")
                } else if l.role == wire::role::WORKER && self.written > 0 {
                    (Event::Scale, "joined the running run")
                } else {
                    (Event::Start, "ready")
                };
                self.writer.write_event(
                    self.current_update,
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
            Msg::End(_) | Msg::Drained => {}
        }
        Ok(())
    }

    /// Writes every complete update; with `skip_lost`, also gives up (with an `error` event) on
    /// updates whose inputs can no longer arrive, and writes what that unblocks.
    fn write_complete(&mut self, skip_lost: bool) -> anyhow::Result<()> {
        let pid = self.pid;
        loop {
            while let Some(a) = self.assembler.next_complete() {
                let a = a.map_err(anyhow::Error::msg)?;
                for (name, value) in &a.changed {
                    self.writer.write_task_change(a.update, name, *value)?;
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
                self.writer.write_update(&UpdateData {
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
                    "update {u} not recorded: {what} never reached the recorder (the services' \
                 safe overflow dropped them)"
                ),
            )?;
            self.writer.flush()?;
        }
    }
}
