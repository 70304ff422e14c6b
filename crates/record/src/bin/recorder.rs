//! The pipeline's recorder process: subscribes to the run's iceoryx2 services (see the `wire`
//! crate) and writes the run's MCAP with the same schemas as the in-process recorder.
//!
//! It owns no doorbell of its own (the wire contract has none for it): it is the second listener
//! on `wake/updater` (rung for every cost trajectory and control message), `wake/sampler` (rung
//! for every distribution) and `wake/supervisor` (lifecycle), and the spare subscriber of
//! `distribution`, `costs`, `control` and `lifecycle`. Because those services keep no history,
//! it must be subscribed before the updater publishes the distribution of update 0: start it
//! first and wait for its `lifecycle` message (role [`ROLE_RECORDER`]) before sending START.
//!
//! Each update is recomputed with the core from the recorded inputs before it is written (the
//! samples are re-drawn from (seed, update, k)); a mismatch with the distribution the updater
//! published is logged as an error event on `/log`. After every update the file is flushed: a
//! SIGKILL loses at most the update in flight, and `mcap-tool recover` completes the file.
//! SIGINT/SIGTERM finish the file (summary and indexes) and exit 0.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use pipeline::{announce_ready, iox, Context};
use record::assemble::{Assembler, CostOutcome};
use record::{now_ns, Event, RolloutTiming, RunStart, RunWriter, UpdateData};
use wire::{Control, DistributionHeader, Lifecycle};

/// The `lifecycle` role this process announces (the wire contract's roles are 1–3).
const ROLE_RECORDER: u32 = 4;

/// Records the run's updates, rollouts, task changes and health events to MCAP.
#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    process: pipeline::ProcessArgs,
    /// Where to write the recording; default `<run dir>/run.mcap`.
    #[arg(long)]
    out: Option<PathBuf>,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    pipeline::run_main("recorder", || run(&cli))
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

fn run(cli: &Cli) -> anyhow::Result<()> {
    let ctx = Context::new(&cli.process, "recorder")?;
    let cfg = &ctx.config;
    let text = std::fs::read_to_string(&cli.process.config)
        .with_context(|| format!("{}: cannot read", cli.process.config.display()))?;
    let task = session::build_task(cfg)?;
    let names: Vec<String> = task.settings().iter().map(|(n, _)| n.to_string()).collect();
    let basis = task.basis_activations();
    let (p, steps) = (ctx.limits.dim, ctx.limits.steps);
    let hp = cfg.hyperparameters();
    let mut assembler = Assembler::new(hp.clone(), p, steps, basis.clone(), names.clone());
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
        bells.push(iox(
            wire::doorbell(&ctx.node, ctx.run_id, owner, &ctx.limits)?
                .listener_builder()
                .create(),
            &format!("second listener on wake/{owner}"),
        )?);
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

    let mut writer = RunWriter::create(&out)?;
    let _announced = announce_ready(&ctx, ROLE_RECORDER, 0, 0)?;
    eprintln!("recording to {}", out.display());

    let pid = std::process::id();
    let mut started = false;
    let mut final_update: Option<u64> = None;
    let mut current_update = 0u64;
    let mut written = 0u64;
    let mut mismatches = 0u64;
    let stopped_by_signal;
    loop {
        for b in &bells {
            iox(b.try_wait(|_| {}), "doorbell")?;
        }
        // Distributions before costs: every cost of update u was published before the
        // distribution of u + 1, so after this order of draining, a seen distribution's
        // predecessor costs are all in hand.
        while let Some(s) = iox(dist_sub.receive(), "receive distribution")? {
            let h: DistributionHeader = *s.user_header();
            if h.run_id != ctx.run_id {
                continue;
            }
            let payload = s.payload();
            if payload.len() < p + p * p {
                anyhow::bail!(
                    "distribution of update {}: {} values, expected {}",
                    h.update,
                    payload.len(),
                    p + p * p
                );
            }
            let (mean, cov) = (&payload[..p], &payload[p..p + p * p]);
            let settings = &h.settings[..(h.settings_len as usize).min(h.settings.len())];
            if !started {
                started = true;
                let initial = pi2cma::Distribution {
                    mean: nalgebra::DVector::from_column_slice(mean),
                    covariance: nalgebra::DMatrix::from_column_slice(p, p, cov),
                };
                let task_settings: Vec<(&str, f64)> = names
                    .iter()
                    .map(String::as_str)
                    .zip(settings.iter().copied())
                    .collect();
                writer.write_start(&RunStart {
                    name: &cfg.run.name,
                    seed: h.seed,
                    update: h.update,
                    steps,
                    hyperparameters: &hp,
                    initial: &initial,
                    basis_activations: basis.as_deref(),
                    config_toml: &text,
                    executor: "pipeline",
                    task_settings: &task_settings,
                })?;
                writer.write_event(
                    h.update,
                    Event::Start,
                    "recorder",
                    pid,
                    &format!("recording run {} from update {}", ctx.run_id, h.update),
                )?;
            }
            current_update = current_update.max(h.update);
            assembler
                .distribution(h.update, h.seed, mean, cov, settings)
                .map_err(anyhow::Error::msg)?;
            if h.flags & DistributionHeader::FINAL != 0 {
                final_update = Some(h.update);
            }
        }
        while let Some(s) = iox(costs_sub.receive(), "receive costs")? {
            let h = *s.user_header();
            if h.run_id != ctx.run_id {
                continue;
            }
            let end_ns = now_ns();
            let timing = RolloutTiming {
                worker: format!("worker-{}", h.worker),
                start_ns: end_ns.saturating_sub(h.duration_ns),
                end_ns,
            };
            match assembler.cost(
                h.update,
                h.rollout as usize,
                s.payload(),
                h.terminal,
                timing,
            ) {
                Ok(CostOutcome::Stored | CostOutcome::Stale | CostOutcome::Duplicate) => {}
                Err(e) => writer.write_event(
                    h.update,
                    Event::Error,
                    &format!("worker-{}", h.worker),
                    0,
                    &format!("cost of update {} rejected: {e}", h.update),
                )?,
            }
        }
        while let Some(s) = iox(control_sub.receive(), "receive control")? {
            let c: Control = *s.payload();
            if c.run_id != ctx.run_id {
                continue;
            }
            match c.kind {
                Control::WORKER_LOST => writer.write_event(
                    current_update,
                    Event::Crash,
                    &format!("worker-{}", c.worker),
                    0,
                    &format!(
                        "worker {} (incarnation {}) lost: exited, crashed or scaled away; its \
                         rollouts go to the other workers",
                        c.worker, c.incarnation
                    ),
                )?,
                Control::SET_TASK => writer.write_event(
                    current_update,
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
                Control::START => {
                    writer.write_event(current_update, Event::Info, "supervisor", 0, "start")?
                }
                _ => {}
            }
        }
        while let Some(s) = iox(lifecycle_sub.receive(), "receive lifecycle")? {
            let l: Lifecycle = *s.payload();
            if l.run_id != ctx.run_id || l.pid == pid {
                continue;
            }
            let (event, what) = if l.incarnation > 0 {
                (Event::Restart, "restarted")
            } else if l.role == wire::role::WORKER && written > 0 {
                (Event::Scale, "joined the running run")
            } else {
                (Event::Start, "ready")
            };
            writer.write_event(
                current_update,
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
        while let Some(a) = assembler.next_complete() {
            let a = a.map_err(anyhow::Error::msg)?;
            for (name, value) in &a.changed {
                writer.write_task_change(a.update, name, *value)?;
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
            writer.write_update(&UpdateData {
                hyperparameters: assembler.hyperparameters(),
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
            written += 1;
            if !a.recomputed_matches {
                mismatches += 1;
                writer.write_event(
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
                writer.write_event(
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
        while let Some((u, what)) = assembler.skip_incomplete() {
            writer.write_event(
                u,
                Event::Error,
                "recorder",
                pid,
                &format!(
                    "update {u} not recorded: {what} never reached the recorder (it fell \
                     behind and the services' safe overflow dropped them)"
                ),
            )?;
            writer.flush()?;
        }
        if final_update.is_some_and(|f| assembler.first_update().is_none_or(|n| n >= f)) {
            stopped_by_signal = false;
            break;
        }
        match iox(
            waitset.wait_and_process_once(|_| CallbackProgression::Continue),
            "waitset",
        )? {
            WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt => {
                stopped_by_signal = true;
                break;
            }
            WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
        }
    }
    writer.write_event(
        current_update,
        Event::Exit,
        "recorder",
        pid,
        &format!(
            "recorder exits ({}): {written} updates written, {mismatches} recomputation \
             mismatches",
            if stopped_by_signal {
                "signal"
            } else {
                "run complete"
            }
        ),
    )?;
    writer.finish()?;
    eprintln!("recorded {written} updates to {}", out.display());
    Ok(())
}
