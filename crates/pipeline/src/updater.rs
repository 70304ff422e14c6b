//! The updater: owns the optimizer. Collects the K cost trajectories of an update in place from
//! shared memory, tells the core, and publishes the next distribution with the task settings in
//! force for it. Scheduled task changes and runtime ones (`supervisor set`) take effect at the
//! update they are published with, which is recorded in the result file.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use pi2cma::CostError;
use session::reruns::{after_reruns, rerun_message, NonfiniteReruns, Verdict};
use tasks::TaskChange;
use wire::{Control, DistributionHeader, Progress, RecorderAck, RerunHeader, Service};

use crate::result::{bits, RecordedChange, RunResult};
use crate::{announce_ready, iox, wait_loop, Context, Exit, Flow, Ports as _, ProcessArgs};

const PROGRESS_INTERVAL: Duration = Duration::from_millis(200);

/// The updater's arguments: the usual process arguments and, for a resumed run, its state.
#[derive(Debug, Clone, clap::Args)]
pub struct UpdaterArgs {
    /// The run's config, directory and id.
    #[command(flatten)]
    pub process: ProcessArgs,
    /// Resume from this state (the start file `supervisor run --resume` writes: TOML, values as
    /// bits) instead of update 0.
    #[arg(long, value_name = "FILE")]
    pub start: Option<std::path::PathBuf>,
}

/// The `updater` process: owns the optimizer, publishes each update's distribution once the
/// supervisor sends START, takes in the costs, and writes `result.toml` ([`crate::result`])
/// when the run completes or is stopped. Fails on a config or service error, a cost that is
/// not finite (beyond `run.nonfinite_reruns`), or a task change the updater's own task refuses.
pub fn main(args: &UpdaterArgs) -> anyhow::Result<()> {
    let ctx = Context::new(&args.process, wire::process::UPDATER)?;
    let cfg = &ctx.config;
    let seed = cfg.run.seed;
    let start = args
        .start
        .as_deref()
        .map(session::Start::read)
        .transpose()?;
    let mut task = cfg.build_task()?;
    let mut optimizer = session::build_optimizer_at(cfg, task.as_ref(), seed, start.as_ref())?;
    let first_update = optimizer.update_index();
    let initial_settings = task.settings();
    let schedule = cfg.schedule();
    match &start {
        Some(s) => s.configure(&schedule, task.as_mut(), &initial_settings)?,
        None => schedule.configure(task.as_mut(), &initial_settings, 0)?,
    }
    let (k_total, steps, dim) = (ctx.limits.rollouts, ctx.limits.steps, ctx.limits.dim);

    let dist_service = wire::distribution(&ctx.node, ctx.run_id, &ctx.limits)?;
    let dist_pub = iox(
        dist_service
            .publisher_builder()
            .initial_max_slice_len(wire::distribution_len(&ctx.limits))
            .allocation_strategy(AllocationStrategy::Static)
            .create(),
        "distribution publisher",
    )?;
    let costs = wire::costs(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("costs")?;
    let control = wire::control(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("control")?;
    let progress_pub = wire::progress(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("progress")?;
    let doorbell = ctx.listener(wire::process::UPDATER)?;
    let sampler_bell = ctx.notifier(wire::process::SAMPLER)?;
    let supervisor_bell = ctx.notifier(wire::process::SUPERVISOR)?;
    let mut recorder = RecorderLink::new(&ctx)?;
    // Tells the sampler which rollouts to hand out again (`reruns`); only a run that allows
    // reruns opens it, so one that does not takes no more shared memory than before.
    let rerun_requests = match cfg.run.nonfinite_reruns {
        0 => None,
        _ => Some(iox(
            wire::reruns(&ctx.node, ctx.run_id, &ctx.limits)?
                .publisher_builder()
                .initial_max_slice_len(k_total)
                .allocation_strategy(AllocationStrategy::Static)
                .create(),
            "reruns publisher",
        )?),
    };
    let mut reruns = NonfiniteReruns::new(cfg.run.nonfinite_reruns, k_total);
    let mut reruns_done: u64 = 0;
    // Rejections not yet published on `reruns`: held back while the recorder could not take
    // in their costs (see `RecorderLink::may_rerun`).
    let mut reruns_unissued: u32 = 0;
    let _announced = announce_ready(&ctx, wire::role::UPDATER, 0, 0)?;

    let mut batch = optimizer.cost_batch();
    let mut started: Option<Instant> = None;
    let mut last_progress = Instant::now();
    // Updates completed since the last report: reported within a tick once PROGRESS_INTERVAL
    // has passed, so the supervisor's view (status, its no-update warning) is never more than
    // that behind when updates stop coming.
    let mut unreported = false;
    // When the last update was completed, since the start: what a report carries, so that the
    // supervisor's rate is updates over the time they took. A report sent later (the periodic
    // one above, or a tenth right after it) carried its own send time, and the rate between
    // two reports a millisecond apart read 10090 updates/s in a run of 6.
    let mut done_at = Duration::ZERO;
    let mut first_eval = f64::NAN;
    let mut first_done: Option<Instant> = None;
    // PI2CMA_TRACE=1: report updates slower than 20 ms (stalls) at the end.
    let trace = std::env::var_os("PI2CMA_TRACE").is_some();
    let mut update_start = Instant::now();
    let mut slow: Vec<(u64, Duration)> = Vec::new();
    let mut last_eval = f64::NAN;
    let mut recorded: Vec<RecordedChange> = Vec::new();
    // The task's settings, in the order of its `settings()` values.
    let setting_names: Vec<&'static str> = task.settings().iter().map(|(n, _)| *n).collect();
    let mut refused_changes: Vec<RecordedChange> = Vec::new();
    // The settings published for the current update, and those its rollouts ran with (the
    // first rollout's, with its worker and number): they differ where the workers' task refused
    // a change.
    let mut published: Vec<f64> = Vec::new();
    let mut ran_with: Option<RanWith> = None;
    // What the last update ran with: a worker whose task refuses a change runs with it. For a
    // resumed run, what the recording's last update ran with.
    let mut previous: Option<Vec<f64>> = start.as_ref().map(|s| {
        let settings = task.settings();
        let names: Vec<&str> = settings.iter().map(|(n, _)| *n).collect();
        let in_force: Vec<f64> = settings.iter().map(|(_, v)| *v).collect();
        s.ran_with_values(&names, &in_force)
    });
    let mut runtime: Vec<TaskChange> = Vec::new();
    let mut complete = false;
    // The flags of the distribution waiting to be published (the optimizer's current one); it
    // waits while the recorder's back-pressure holds it back.
    let mut to_publish: Option<u32> = None;
    // `supervisor stop --after-update`: the next distribution is the last, published with
    // `FINAL | STOPPED`, once the update under way is done.
    let mut stop_after = false;
    const STOP: u32 = DistributionHeader::FINAL | DistributionHeader::STOPPED;
    // (the supervisor's number of the last task change taken, the update it takes effect
    // from), echoed in `Progress`; a `Cell` because `report` reads it while the control loop
    // sets it.
    let changes = std::cell::Cell::new((0u64, 0u64));
    // (refused changes so far, the last one's setting index, value and update), in `Progress`.
    let refusals = std::cell::Cell::new((0u32, 0u32, 0.0f64, 0u64));
    // (rollouts of the update under way whose costs are in, those reported), for `Progress`:
    // with rollouts of seconds, `status` shows how far an update has got.
    let rollouts_done = std::cell::Cell::new((0u32, 0u32));
    // What is in force from the start: a resumed run's settings, and the scheduled changes of
    // its first update.
    if let Some(start) = &start {
        println!(
            "resuming at update {first_update} from {} (task settings {})",
            start.origin,
            tasks::settings_text(start.settings.iter().map(|(n, v)| (n, *v)))
        );
        for (name, value) in &start.settings {
            recorded.push(RecordedChange {
                from_update: first_update,
                name: name.clone(),
                value: *value,
                source: "resume".into(),
            });
        }
    }
    // Those of a resumed run's first update that a `supervisor set` overrode (see
    // `Start::scheduled_at_start`) were not taken.
    for c in session::scheduled_at(&schedule, start.as_ref(), first_update) {
        recorded.push(RecordedChange {
            from_update: first_update,
            name: c.name.clone(),
            value: c.value,
            source: "schedule".into(),
        });
    }

    let publish = |optimizer: &pi2cma::Optimizer,
                   values: &[f64],
                   previous: &[f64],
                   flags: u32|
     -> anyhow::Result<()> {
        let d = optimizer.distribution();
        let (packed, len) = wire::pack_settings(values);
        let (previous, _) = wire::pack_settings(previous);
        let sample = iox(
            dist_pub.loan_slice_uninit(dim + dim * dim),
            "loan distribution",
        )?;
        let mut sample = sample.write_from_fn(|i| {
            if i < dim {
                d.mean[i]
            } else {
                d.covariance.as_slice()[i - dim]
            }
        });
        *sample.user_header_mut() = DistributionHeader {
            run_id: ctx.run_id,
            update: optimizer.update_index(),
            seed,
            dim: dim as u32,
            rollouts: k_total as u32,
            steps: steps as u32,
            flags,
            settings_len: len,
            _reserved: 0,
            lambda: optimizer.lambda(),
            settings: packed,
            previous_settings: previous,
        };
        iox(sample.send(), "send distribution")?;
        iox(
            sampler_bell.notify_with_custom_event_id(wire::WAKE),
            "notify sampler",
        )?;
        Ok(())
    };
    let report = |optimizer: &pi2cma::Optimizer,
                  settings: &[(&'static str, f64)],
                  eval: f64,
                  elapsed: Duration,
                  flags: u32|
     -> anyhow::Result<()> {
        let values: Vec<f64> = settings.iter().map(|(_, v)| *v).collect();
        let (packed, len) = wire::pack_settings(&values);
        let (done, _) = rollouts_done.get();
        rollouts_done.set((done, done));
        iox(
            progress_pub.send_copy(Progress {
                run_id: ctx.run_id,
                updates: optimizer.update_index(),
                elapsed_ns: elapsed.as_nanos() as u64,
                eval_cost: eval,
                lambda: optimizer.lambda(),
                flags,
                settings_len: len,
                settings: packed,
                last_change_seq: changes.get().0,
                last_change_from: changes.get().1,
                refused: refusals.get().0,
                last_refused_setting: refusals.get().1,
                last_refused_value: refusals.get().2,
                last_refused_update: refusals.get().3,
                rollouts_done: rollouts_done.get().0,
                rollouts: k_total as u32,
            }),
            "send progress",
        )?;
        iox(
            supervisor_bell.notify_with_custom_event_id(wire::WAKE),
            "notify supervisor",
        )?;
        Ok(())
    };

    let exit = wait_loop(&doorbell, || {
        while let Some(msg) = iox(control.receive(), "receive control")? {
            let m = *msg.payload();
            if m.run_id != ctx.run_id {
                continue;
            }
            match m.kind {
                Control::START if started.is_none() => {
                    started = Some(Instant::now());
                    last_progress = Instant::now();
                    let first = optimizer.update_index();
                    recorder.attach_if_running(first, first);
                    to_publish = Some(0);
                }
                Control::RECORDER_LOST => recorder.detach("the supervisor reports it gone"),
                // The dead recorder's unwritten updates are lost with it: the lag is counted
                // from here, where the new one begins.
                Control::RECORDER_BACK if started.is_some() => {
                    let u = optimizer.update_index();
                    recorder.attach_if_running(u, u + u64::from(to_publish.is_none()))
                }
                Control::STOP_AFTER_UPDATE if started.is_some() && !stop_after => {
                    stop_after = true;
                    let u = optimizer.update_index();
                    match to_publish {
                        // Held back by the recorder: no rollout of it has begun, and its
                        // distribution, with the changes due at it, is where a resumed run
                        // goes on.
                        Some(0) => {
                            to_publish = Some(STOP);
                            println!(
                                "stop requested: the run stops before update {u}, which has not \
                                 begun"
                            );
                            let settings = task.settings();
                            report(&optimizer, &settings, last_eval, done_at, Progress::FINAL)?;
                        }
                        // The run's last update is done already: it ends as it would have.
                        Some(_) => {}
                        None => println!(
                            "stop requested: the run stops after update {u}, the one under way, once \
                             its rollouts are done"
                        ),
                    }
                }
                Control::SET_TASK => {
                    let change = TaskChange {
                        // Update u's rollouts may be under way (or its distribution held back by
                        // the recorder): the change is applied after u's `tell`, so u + 1 is the
                        // first update that sees it. Before the start, update 0 does.
                        from_update: optimizer.update_index() + u64::from(started.is_some()),
                        name: m.name().to_string(),
                        value: m.value,
                    };
                    println!(
                        "task change: {} = {} from update {} (runtime)",
                        change.name,
                        tasks::value_text(change.value),
                        change.from_update
                    );
                    changes.set((m.seq, change.from_update));
                    if started.is_none() {
                        apply(&mut *task, &change, "runtime", &mut recorded)?;
                    } else {
                        runtime.push(change);
                    }
                    report(
                        &optimizer,
                        &task.settings(),
                        last_eval,
                        done_at,
                        Progress::TASK_CHANGE,
                    )?;
                }
                _ => {}
            }
        }
        let Some(t0) = started else {
            return Ok(Flow::Continue);
        };
        let (done, reported) = rollouts_done.get();
        if (unreported || done != reported) && last_progress.elapsed() >= PROGRESS_INTERVAL {
            last_progress = Instant::now();
            unreported = false;
            report(&optimizer, &task.settings(), last_eval, done_at, 0)?;
        }
        // Publishes what waits (if the recorder's back-pressure allows), takes in costs, and
        // after a complete batch updates and publishes again.
        loop {
            if let Some(flags) = to_publish {
                let u = optimizer.update_index();
                if !recorder.may_publish(u, &ctx)? {
                    return Ok(Flow::Continue);
                }
                to_publish = None;
                published = task.settings().iter().map(|(_, v)| *v).collect();
                publish(
                    &optimizer,
                    &published,
                    previous.as_deref().unwrap_or(&published),
                    flags,
                )?;
                recorder.published(u, flags & DistributionHeader::FINAL != 0)?;
                if flags & DistributionHeader::FINAL != 0 {
                    return Ok(Flow::Stop);
                }
                // Draw this update's parameters now, while the workers run: `tell` needs them,
                // and the time until the last cost arrives is idle.
                optimizer.ask();
            }
            let u = optimizer.update_index();
            while let Some(sample) = iox(costs.receive(), "receive costs")? {
                let h = *sample.user_header();
                if h.run_id == ctx.run_id {
                    recorder.cost_received(h.update);
                }
                if h.run_id != ctx.run_id || h.update != u {
                    continue; // a re-executed rollout of an earlier update
                }
                let e = match batch.insert(h.rollout as usize, sample.payload(), h.terminal) {
                    Ok(()) => {
                        RanWith::check(&mut ran_with, &h, &published, &*task)?;
                        continue;
                    }
                    // Re-executed after a worker was lost, or a rerun's late twin.
                    Err(CostError::Duplicate { .. }) => continue,
                    Err(e) => e,
                };
                let tried = match (&e, &rerun_requests) {
                    (CostError::NonFinite { .. }, Some(_)) => {
                        match reruns.reject(h.rollout as usize) {
                            Verdict::Rerun { attempt } => {
                                let by = format!("worker-{}", h.worker);
                                let limit = reruns.limit();
                                println!("{}", rerun_message(u, &e, attempt, limit, &by));
                                reruns_done += 1;
                                reruns_unissued += 1;
                                continue;
                            }
                            Verdict::Fail { reruns } => reruns,
                        }
                    }
                    _ => 0,
                };
                bail!(
                    "update {u}: {e} (reported by worker-{} for rollout {}{}){}",
                    h.worker,
                    h.rollout,
                    ran_with_text(&h, &published, &*task),
                    after_reruns(&e, tried)
                );
            }
            rollouts_done.set((batch.filled() as u32, rollouts_done.get().1));
            let issue =
                reruns_unissued > 0 && recorder.may_rerun(u, u64::from(reruns_unissued), &ctx)?;
            if let (true, Some(requests)) = (issue, &rerun_requests) {
                reruns_unissued = 0;
                // One sample for all the rejections this round: it holds every count.
                let sample = iox(requests.loan_slice_uninit(k_total), "loan reruns")?;
                let mut sample = sample.write_from_slice(reruns.rejected());
                *sample.user_header_mut() = RerunHeader {
                    run_id: ctx.run_id,
                    update: u,
                };
                iox(sample.send(), "send reruns")?;
                iox(
                    sampler_bell.notify_with_custom_event_id(wire::WAKE),
                    "notify sampler",
                )?;
            }
            if !batch.is_complete() {
                return Ok(Flow::Continue);
            }
            if trace && update_start.elapsed() > Duration::from_millis(20) {
                slow.push((u, update_start.elapsed()));
            }
            update_start = Instant::now();
            let summary = optimizer
                .tell(&batch)
                .map_err(|e| anyhow!("update {u}: {e}"))?;
            batch.clear();
            rollouts_done.set((0, rollouts_done.get().1));
            reruns.clear();
            // A rerun held back while a twin completed the rollout is not wanted any more.
            reruns_unissued = 0;
            // A refusal is reported at once: `supervisor status` shows it.
            let news = RanWith::settle(
                &mut ran_with,
                u,
                &published,
                &mut *task,
                (&mut recorded, &mut refused_changes),
                &refusals,
            )?;
            // Before the next update's changes: what this one ran with.
            previous = Some(task.settings().iter().map(|(_, v)| *v).collect());
            if u == first_update {
                first_eval = summary.eval_cost;
                first_done = Some(Instant::now());
            }
            last_eval = summary.eval_cost;
            done_at = t0.elapsed();
            let next = optimizer.update_index();
            let done = cfg.run.updates.is_some_and(|n| next >= n);
            // The last update of a bounded run publishes no changes: none runs after it. A
            // run stopped on request goes on from `next` when resumed, with them.
            if !done {
                for c in schedule.at(next) {
                    apply(&mut *task, c, "schedule", &mut recorded)?;
                }
                for c in runtime.drain(..) {
                    apply(
                        &mut *task,
                        &TaskChange {
                            from_update: next,
                            ..c
                        },
                        "runtime",
                        &mut recorded,
                    )?;
                }
                if let Some(before) = &previous {
                    drop_unchanged(&mut recorded, next, &setting_names, before);
                }
            }
            if done || stop_after {
                complete = done;
                if !done {
                    println!(
                        "stopping as requested: update {u} was the last; the run goes on from \
                         update {next} when resumed"
                    );
                }
                report(
                    &optimizer,
                    &task.settings(),
                    last_eval,
                    done_at,
                    Progress::FINAL,
                )?;
                to_publish = Some(if done {
                    DistributionHeader::FINAL
                } else {
                    STOP
                });
                continue;
            }
            to_publish = Some(0);
            // Every PROGRESS_INTERVAL, and at every tenth of a bounded run (so short runs show
            // their progress too).
            let tenth = cfg.run.updates.is_some_and(|n| next % (n / 10).max(1) == 0);
            unreported = !(news || tenth || last_progress.elapsed() >= PROGRESS_INTERVAL);
            if !unreported {
                last_progress = Instant::now();
                report(&optimizer, &task.settings(), last_eval, done_at, 0)?;
            }
        }
    })?;

    // A change taken while an update ran waits for that update's end; a run stopped before
    // then never applies it, though the reply to `supervisor set` named the update it was due
    // at. It is in neither the result file nor the recording, so say so rather than drop it.
    // A change overridden by a later one of its setting would not have applied either.
    for c in tasks::not_replaced(&runtime) {
        println!(
            "task change {} = {} due from update {} not applied: the run stopped before that \
             update (after --resume, give it again with `supervisor set`)",
            c.name,
            tasks::value_text(c.value),
            c.from_update
        );
    }
    // Stopped in the middle of an update whose rollouts in so far ran with other settings than
    // published: the change was refused all the same, and the value run with stays in force
    // (the recorder does not record the change either, so that `--resume` goes on without it).
    RanWith::settle(
        &mut ran_with,
        optimizer.update_index(),
        &published,
        &mut *task,
        (&mut recorded, &mut refused_changes),
        &refusals,
    )?;
    if trace {
        eprintln!("{} updates slower than 20 ms: {slow:?}", slow.len());
    }
    let elapsed = started.map(|t| t.elapsed()).unwrap_or_default();
    if exit == Exit::Signal {
        report(
            &optimizer,
            &task.settings(),
            last_eval,
            done_at,
            Progress::FINAL,
        )?;
    }
    let d = optimizer.distribution();
    let result = RunResult {
        name: cfg.run.name.clone(),
        seed,
        updates: optimizer.update_index(),
        complete,
        elapsed_s: elapsed.as_secs_f64(),
        first_update_s: first_done
            .zip(started)
            .map_or(0.0, |(f, s)| (f - s).as_secs_f64()),
        first_eval_cost: first_eval,
        last_eval_cost: last_eval,
        lambda: optimizer.lambda(),
        mean: d.mean.as_slice().to_vec(),
        covariance: d.covariance.as_slice().to_vec(),
        mean_bits: bits(d.mean.as_slice()),
        covariance_bits: bits(d.covariance.as_slice()),
        task_changes: recorded,
        refused_changes,
        nonfinite_reruns: reruns_done,
    };
    result.write(&ctx.result_path())?;
    Ok(())
}

fn apply(
    task: &mut dyn tasks::Task,
    change: &TaskChange,
    source: &str,
    recorded: &mut Vec<RecordedChange>,
) -> anyhow::Result<()> {
    task.set(&change.name, change.value)?;
    if source == "schedule" {
        println!(
            "task change: {} = {} from update {} (schedule)",
            change.name,
            tasks::value_text(change.value),
            change.from_update
        );
    }
    // A second change of one setting at one update (a runtime `set` over the schedule's, or
    // two `set`s within an update) overrides the first, which no rollout runs with: listed as
    // taken, it would be a change the run never made.
    if let Some(i) = recorded
        .iter()
        .position(|c| c.from_update == change.from_update && c.name == change.name)
    {
        let overridden = recorded.remove(i);
        println!(
            "task change: {} = {} ({}) overrides {} = {} ({}) from update {}",
            change.name,
            tasks::value_text(change.value),
            source,
            overridden.name,
            tasks::value_text(overridden.value),
            overridden.source,
            change.from_update
        );
    }
    recorded.push(RecordedChange {
        from_update: change.from_update,
        name: change.name.clone(),
        value: change.value,
        source: source.into(),
    });
    Ok(())
}

/// Drops the changes listed for update `u` that leave their setting at the value update
/// `u` − 1 ran with (`before`, in the order of `names`): a `set` to the value in force, or one
/// that overrode a change at `u` back to it. Update `u` runs as `u` − 1 did, so the run makes
/// no change there, and the recording, which sees what the rollouts ran with, shows none.
fn drop_unchanged(recorded: &mut Vec<RecordedChange>, u: u64, names: &[&str], before: &[f64]) {
    recorded.retain(|c| {
        let unchanged = c.from_update == u
            && names
                .iter()
                .position(|n| *n == c.name)
                .and_then(|i| before.get(i))
                .is_some_and(|b| b.to_bits() == c.value.to_bits());
        if unchanged {
            println!(
                "task change: {} = {} ({}) from update {} leaves it as update {} ran with it: \
                 no change",
                c.name,
                tasks::value_text(c.value),
                c.source,
                u,
                u.saturating_sub(1)
            );
        }
        !unchanged
    });
}

/// The settings the rollouts of an update ran with ([`wire::CostHeader::ran_with`]), as its
/// first rollout gave them.
struct RanWith {
    values: Vec<f64>,
    worker: u32,
    rollout: u32,
}

/// The task settings rollout `h` ran with, for an error about its costs: a change that made a
/// task's costs overflow (`supervisor set` of a target 1e308 away, which the update side cannot
/// try on a task of your own) failed the run naming only the worker and the rollout.
fn ran_with_text(h: &wire::CostHeader, published: &[f64], task: &dyn tasks::Task) -> String {
    let names = task.settings();
    if names.is_empty() {
        return String::new();
    }
    let list = tasks::settings_text(
        names
            .iter()
            .zip(h.ran_with(published))
            .map(|((name, _), v)| (name, *v)),
    );
    format!(", which ran with {list}")
}

impl RanWith {
    /// Takes in rollout `h`'s settings: every rollout of an update must have run with the same
    /// ones, or its costs are not comparable.
    fn check(
        first: &mut Option<RanWith>,
        h: &wire::CostHeader,
        published: &[f64],
        task: &dyn tasks::Task,
    ) -> anyhow::Result<()> {
        let values = h.ran_with(published);
        if values.len() != published.len() {
            bail!(
                "update {}: worker-{} ran rollout {} with {} task settings, the run has {}",
                h.update,
                h.worker,
                h.rollout,
                values.len(),
                published.len()
            );
        }
        let Some(first) = first else {
            *first = Some(RanWith {
                values: values.to_vec(),
                worker: h.worker,
                rollout: h.rollout,
            });
            return Ok(());
        };
        let differ = values
            .iter()
            .zip(&first.values)
            .position(|(a, b)| a.to_bits() != b.to_bits());
        if let Some(i) = differ {
            let name = task.settings().get(i).map_or("?", |(n, _)| *n);
            let (theirs, ours) = (values[i], first.values[i]);
            let why = if h.worker == first.worker {
                "its task took a value for one rollout that it refused for another (a worker \
                 must run every rollout of an update with the same settings)"
            } else {
                "one worker's task refused a change another's took (every worker of a run must \
                 accept the same settings)"
            };
            bail!(
                "update {}: worker-{} ran rollout {} with {name} = {}, worker-{} ran rollout {} \
                 with {name} = {}: {why}, and costs of different tasks cannot be weighed against \
                 each other",
                h.update,
                h.worker,
                h.rollout,
                tasks::value_text(theirs),
                first.worker,
                first.rollout,
                tasks::value_text(ours)
            );
        }
        Ok(())
    }

    /// After update `u` (or a stop in its middle): takes the settings its rollouts in so far ran
    /// with ([`RanWith::take_refusals`]) and adds the refusals to `count` (changes refused so
    /// far, the last one's setting index, value and update, as `Progress` reports them).
    /// Whether there were any.
    fn settle(
        slot: &mut Option<RanWith>,
        u: u64,
        published: &[f64],
        task: &mut dyn tasks::Task,
        (recorded, refused): (&mut Vec<RecordedChange>, &mut Vec<RecordedChange>),
        count: &std::cell::Cell<(u32, u32, f64, u64)>,
    ) -> anyhow::Result<bool> {
        let Some(ran) = slot.take() else {
            return Ok(false);
        };
        let taken = ran.take_refusals(u, published, task, recorded, refused)?;
        let Some(&(i, value)) = taken.last() else {
            return Ok(false);
        };
        count.set((count.get().0 + taken.len() as u32, i as u32, value, u));
        Ok(true)
    }

    /// The settings update `u` ran with that differ from those `published` for it: changes the
    /// workers' task refused. They did not take effect: the run goes on with the values the
    /// rollouts ran with, and the changes move from `recorded` to `refused`. Returns them:
    /// (setting index, the value refused).
    fn take_refusals(
        self,
        u: u64,
        published: &[f64],
        task: &mut dyn tasks::Task,
        recorded: &mut Vec<RecordedChange>,
        refused: &mut Vec<RecordedChange>,
    ) -> anyhow::Result<Vec<(usize, f64)>> {
        let names: Vec<&'static str> = task.settings().iter().map(|(n, _)| *n).collect();
        let mut taken = Vec::new();
        for (i, ((name, &ran), &asked)) in names.iter().zip(&self.values).zip(published).enumerate()
        {
            if ran.to_bits() == asked.to_bits() {
                continue;
            }
            taken.push((i, asked));
            println!(
                "task change {name} = {} at update {u} refused by the workers' task (see their \
                 output): update {u} ran with {name} = {}, which stays in force",
                tasks::value_text(asked),
                tasks::value_text(ran)
            );
            task.set(name, ran).map_err(|e| {
                anyhow!("update {u}: the workers ran with {name} = {ran}, which the updater's task refuses: {e}")
            })?;
            let before = recorded.len();
            recorded.retain(|c| {
                // The refused value only: a resumed run's "resume" entry holds the value in force.
                let hit =
                    c.from_update == u && c.name == *name && c.value.to_bits() == asked.to_bits();
                if hit {
                    refused.push(c.clone());
                }
                !hit
            });
            if recorded.len() == before {
                // A value in force before this update that the workers no longer take (a worker
                // of another build joined): what they ran with is what is in force now.
                recorded.push(RecordedChange {
                    from_update: u,
                    name: name.to_string(),
                    value: ran,
                    source: "workers".into(),
                });
            }
        }
        Ok(taken)
    }
}

/// How long the updater waits for a recorder that holds it back before it looks for a dead one
/// itself (the supervisor reports its own recorder's death at once; a recorder started by hand
/// has no one to report it).
const RECORDER_SCAN_AFTER: Duration = Duration::from_secs(1);

/// The updater's side of the recorder's back-pressure (see the `wire` crate, "The recorder").
struct RecorderLink {
    service: wire::FixedService<RecorderAck>,
    acks: Subscriber<Service, RecorderAck, ()>,
    bell: Notifier<Service>,
    run_id: u64,
    lag: u64,
    attached: bool,
    /// The recorder's newest acknowledgement: every update before it is written.
    next_update: u64,
    costs: UnrecordedCosts,
    held_since: Option<Instant>,
    last_scan: Instant,
    last_ring: Option<Instant>,
    /// The acknowledgement at which the recorder was last rung for being half the lag bound
    /// behind: rung once per acknowledgement.
    rung_half_at: Option<u64>,
}

impl RecorderLink {
    fn new(ctx: &Context) -> anyhow::Result<Self> {
        let service = wire::recorded(&ctx.node, ctx.run_id, &ctx.limits)?;
        let acks = service.subscriber("recorded")?;
        Ok(Self {
            service,
            acks,
            bell: ctx.notifier(wire::process::RECORDER)?,
            run_id: ctx.run_id,
            lag: ctx.limits.recorder_max_lag(),
            attached: false,
            next_update: 0,
            costs: UnrecordedCosts::new(
                ctx.limits.recorder_cost_room(),
                ctx.limits.rollouts as u64,
            ),
            held_since: None,
            last_scan: Instant::now(),
            last_ring: None,
            rung_half_at: None,
        })
    }

    /// At START, or at RECORDER_BACK: a recorder that is running then has its publisher on
    /// `recorded` (the supervisor starts it first and waits for it). Its cost messages are
    /// counted from update `count_from`: a restarted recorder begins at the first distribution
    /// published after it announced itself, so the update whose distribution is out already is
    /// not counted. (If that distribution went out between the announcement and RECORDER_BACK,
    /// the recorder takes in that update's costs uncounted, beside up to the room's worth of
    /// counted ones; only their excess over the margin of `max_workers` + 4 can overflow its
    /// buffer — within the update in flight, the most a recorder's restart may lose.)
    fn attach_if_running(&mut self, first_update: u64, count_from: u64) {
        self.attached = self.service.dynamic_config().number_of_publishers() > 0;
        self.next_update = first_update;
        self.costs.attach(first_update, count_from);
        self.held_since = None;
        self.last_ring = None;
        self.rung_half_at = None;
        if self.attached {
            println!(
                "recorder attached: the updater stays at most {} updates ahead of it",
                self.lag
            );
        }
    }

    fn detach(&mut self, why: &str) {
        if self.attached {
            self.attached = false;
            println!("recorder detached ({why}): no more back-pressure");
        }
    }

    fn drain_acks(&mut self) -> anyhow::Result<()> {
        while let Some(a) = iox(self.acks.receive(), "receive recorder ack")? {
            let a = *a.payload();
            if a.run_id == self.run_id && a.next_update >= self.next_update {
                self.next_update = a.next_update;
                self.costs.acknowledged(a.next_update, a.taken);
            }
        }
        Ok(())
    }

    /// A cost message of update `update` received (any: accepted, rejected, a twin).
    fn cost_received(&mut self, update: u64) {
        if self.attached {
            self.costs.received(update);
        }
    }

    /// Whether the distribution of update `u` may be published now; if not, asks the
    /// recorder (HOLD) to ring back after its next acknowledgement.
    fn may_publish(&mut self, u: u64, ctx: &Context) -> anyhow::Result<bool> {
        if !self.attached {
            return Ok(true);
        }
        self.drain_acks()?;
        if u < self.next_update + self.lag && self.costs.fit(self.costs.rollouts) {
            self.held_since = None;
            return Ok(true);
        }
        self.held(ctx)
    }

    /// Whether `n` more executions of update `u` (reruns) may be issued now; if so, they are
    /// counted. If not, asks the recorder (HOLD) to ring back after it has taken more in.
    fn may_rerun(&mut self, u: u64, n: u64, ctx: &Context) -> anyhow::Result<bool> {
        if !self.attached {
            return Ok(true);
        }
        self.drain_acks()?;
        if self.costs.fit(n) {
            self.held_since = None;
            self.costs.issued(u, n);
            return Ok(true);
        }
        self.held(ctx)
    }

    /// Held back: true (go on) if the recorder turns out to be gone, else rings it.
    fn held(&mut self, ctx: &Context) -> anyhow::Result<bool> {
        let since = *self.held_since.get_or_insert_with(Instant::now);
        if since.elapsed() >= RECORDER_SCAN_AFTER && self.last_scan.elapsed() >= RECORDER_SCAN_AFTER
        {
            self.last_scan = Instant::now();
            if self.service.dynamic_config().number_of_publishers() == 0 {
                self.detach("it has exited");
                return Ok(true);
            }
            if ctx
                .dead_nodes()
                .iter()
                .any(|n| n == wire::process::RECORDER)
            {
                self.detach("its node is dead");
                return Ok(true);
            }
        }
        // A failed ring is not fatal: the recorder may just have died, which the checks above
        // find out.
        let _ = self.bell.notify_with_custom_event_id(wire::HOLD);
        Ok(false)
    }

    /// After publishing update `u`: rings the recorder when [`recorder_ring`] says so.
    fn published(&mut self, u: u64, last: bool) -> anyhow::Result<()> {
        if !self.attached {
            return Ok(());
        }
        self.costs.issued(u, self.costs.rollouts);
        self.drain_acks()?;
        let ring = recorder_ring(
            u,
            self.next_update,
            self.lag,
            last || self
                .last_ring
                .is_none_or(|t| t.elapsed() >= wire::RECORDER_RING_INTERVAL),
            self.rung_half_at,
        );
        if ring != Ring::No {
            if ring == Ring::HalfBehind {
                self.rung_half_at = Some(self.next_update);
            }
            self.last_ring = Some(Instant::now());
            // A recorder that has died is reported by the supervisor; no reason to fail here.
            let _ = self.bell.notify_with_custom_event_id(wire::WAKE);
        }
        Ok(())
    }
}

/// Why the updater rings the recorder after publishing an update, if it does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ring {
    No,
    /// It had written everything before the update before: it may be asleep.
    Idle,
    /// It is half the lag bound behind.
    HalfBehind,
}

/// Whether to ring the recorder after publishing update `u`, its newest acknowledgement being
/// `acked` (every update before it written) and the lag bound `lag`.
///
/// An idle recorder (it had written everything before u − 1; a busy one looks again before
/// it sleeps) is rung if `due` (the last ring is [`wire::RECORDER_RING_INTERVAL`] ago, or this
/// is the run's last update): at thousands of updates per second it so works in rounds of
/// several updates, and the ring, a system call and a wake-up, stays off most updates'
/// critical path. One that is half the bound behind is rung too, once per acknowledgement
/// (`rung_half_at`): without this ring, a recorder that had taken in one update slept for
/// the ring interval while the updater published a bound's worth (16 updates are 0.8 ms at
/// 20 000 updates/s) and then waited, held, for a round trip of wake-ups. Measured (5–6
/// alternating runs each): T-ball with 2 workers went from 1 762–1 818 to 2 108–2 228 updates/s
/// recorded (16–27 of ~300 rounds had been asked for by a held updater, now none); A1 at full
/// speed, where half the rounds had been, from 14 300 to 13 300: there the holds had put the
/// recorder's work into pauses of the pipeline instead of beside it.
fn recorder_ring(u: u64, acked: u64, lag: u64, due: bool, rung_half_at: Option<u64>) -> Ring {
    if acked + 1 >= u && due {
        Ring::Idle
    } else if u.saturating_sub(acked) >= (lag / 2).max(1) && rung_half_at != Some(acked) {
        Ring::HalfBehind
    } else {
        Ring::No
    }
}

/// The count behind [`RecorderLink::may_rerun`]: how many cost messages may be waiting in the
/// recorder's subscriber buffer, which holds [`wire::Limits::recorder_cost_room`] (see
/// [`RecorderAck`]). The updater receives every cost message the recorder does.
#[derive(Debug, Clone, PartialEq)]
struct UnrecordedCosts {
    room: u64,
    /// K: the executions a distribution issues.
    rollouts: u64,
    /// Of the newest acknowledgement: cost messages taken in of the updates it has not written
    /// (0 if it counts from an update before `counted_from`, which this side did not count).
    taken: u64,
    /// The cost messages received of each update from `counted_from` on.
    counted_from: u64,
    received: VecDeque<u64>,
    /// The newest update issued and its executions: K, and each rerun.
    issued: (u64, u64),
}

impl UnrecordedCosts {
    fn new(room: u64, rollouts: u64) -> Self {
        Self {
            room,
            rollouts,
            taken: 0,
            counted_from: 0,
            received: VecDeque::new(),
            issued: (0, 0),
        }
    }

    /// A recorder attached whose first update is `first_update`, counted from `count_from`.
    fn attach(&mut self, first_update: u64, count_from: u64) {
        *self = Self {
            counted_from: count_from,
            issued: (first_update, 0),
            ..Self::new(self.room, self.rollouts)
        };
    }

    /// An acknowledgement: every update before `next_update` written, `taken` cost messages of
    /// the later ones taken in. Acknowledgements come in order.
    fn acknowledged(&mut self, next_update: u64, taken: u64) {
        self.taken = if next_update >= self.counted_from {
            taken
        } else {
            0
        };
        let written = next_update.saturating_sub(self.counted_from);
        let written = usize::try_from(written)
            .unwrap_or(usize::MAX)
            .min(self.received.len());
        self.received.drain(..written);
        self.counted_from = self.counted_from.max(next_update);
    }

    fn received(&mut self, update: u64) {
        // Only issued updates have costs: a bogus update index allocates nothing.
        if update < self.counted_from || update > self.issued.0 {
            return;
        }
        let i = (update - self.counted_from) as usize;
        if i >= self.received.len() {
            self.received.resize(i + 1, 0);
        }
        self.received[i] += 1;
    }

    /// `n` executions of update `u` issued (a distribution, K; or reruns).
    fn issued(&mut self, u: u64, n: u64) {
        if self.issued.0 == u {
            self.issued.1 += n;
        } else {
            self.issued = (u, n);
        }
    }

    /// The most cost messages that can be waiting in the recorder's buffer: those received of
    /// the updates it has not written, less those it has taken in, plus the executions of the
    /// update in progress that have not reported yet. None of an update before `counted_from`
    /// (written, or not counted after a restart): its executions are not waited for.
    fn waiting(&self) -> u64 {
        let received: u64 = self.received.iter().sum();
        let (u, issued) = self.issued;
        let out = match u.checked_sub(self.counted_from) {
            Some(i) => {
                let of_u = usize::try_from(i)
                    .ok()
                    .and_then(|i| self.received.get(i))
                    .copied()
                    .unwrap_or(0);
                issued.saturating_sub(of_u)
            }
            None => 0,
        };
        (received + out).saturating_sub(self.taken)
    }

    /// Whether `n` more executions fit.
    fn fit(&self, n: u64) -> bool {
        self.waiting() + n <= self.room
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tasks::Task as _;

    #[test]
    fn the_recorder_is_rung_when_idle_and_due_or_once_when_half_the_bound_behind() {
        let lag = 16;
        // Idle (everything before u − 1 written): rung only when due.
        assert_eq!(recorder_ring(10, 9, lag, true, None), Ring::Idle);
        assert_eq!(recorder_ring(10, 10, lag, true, None), Ring::Idle);
        assert_eq!(recorder_ring(10, 9, lag, false, None), Ring::No);
        // Busy but less than half the bound behind: it looks again before it sleeps.
        assert_eq!(recorder_ring(17, 10, lag, true, None), Ring::No);
        // Half the bound behind: rung once for this acknowledgement, due or not.
        assert_eq!(recorder_ring(18, 10, lag, false, None), Ring::HalfBehind);
        assert_eq!(recorder_ring(19, 10, lag, false, Some(10)), Ring::No);
        assert_eq!(recorder_ring(25, 10, lag, true, Some(10)), Ring::No);
        // A newer acknowledgement, still half behind: rung again.
        assert_eq!(
            recorder_ring(27, 11, lag, false, Some(10)),
            Ring::HalfBehind
        );
        // The smallest bound (huge distributions): once per acknowledgement when behind.
        assert_eq!(recorder_ring(12, 10, 2, false, None), Ring::HalfBehind);
        assert_eq!(recorder_ring(12, 10, 2, false, Some(10)), Ring::No);
    }

    /// Room for 30 cost messages, K = 10: the recorder's buffer as the updater counts it.
    #[test]
    fn unrecorded_costs_count_what_the_recorder_has_not_taken() {
        let mut c = UnrecordedCosts::new(30, 10);
        c.attach(0, 0);
        c.issued(0, 10);
        (0..10).for_each(|_| c.received(0));
        assert_eq!(c.waiting(), 10);
        assert!(c.fit(10));
        c.issued(1, 10);
        (0..10).for_each(|_| c.received(1));
        c.issued(2, 10);
        (0..5).for_each(|_| c.received(2));
        // 25 received, 5 executions of update 2 still out.
        assert_eq!(c.waiting(), 30);
        assert!(!c.fit(1), "a rerun beyond the room");
        // Update 0 written, 3 messages of the later ones taken in.
        c.acknowledged(1, 3);
        assert_eq!(c.waiting(), 10 + 5 + 5 - 3);
        assert!(c.fit(1));
        c.issued(2, 1);
        assert_eq!(c.waiting(), 10 + 5 + 6 - 3);
        // The recorder has taken in everything received; what is out remains.
        c.acknowledged(2, 5);
        assert_eq!(c.waiting(), 6);
        // A cost of an update not issued (a bogus header) or already written counts nothing.
        c.received(u64::MAX);
        c.received(0);
        assert_eq!(c.waiting(), 6);
        // A twin of update 2 waits like any message; the executions out are not fewer than 0.
        (0..12).for_each(|_| c.received(2));
        assert_eq!(c.waiting(), 17 - 5);
    }

    #[test]
    fn unrecorded_costs_ignore_what_an_acknowledgement_counts_from_before_the_count() {
        // A recorder restarted after update 7's distribution went out: counted from 8.
        let mut c = UnrecordedCosts::new(30, 10);
        c.attach(7, 8);
        (0..10).for_each(|_| c.received(7));
        assert_eq!(c.waiting(), 0);
        c.issued(8, 10);
        (0..4).for_each(|_| c.received(8));
        assert_eq!(c.waiting(), 10);
        // It began with update 7 after all; its `taken` includes 7's costs: not subtracted.
        c.acknowledged(7, 14);
        assert_eq!(c.waiting(), 10);
        c.acknowledged(8, 4);
        assert_eq!(c.waiting(), 6);
    }

    /// Reruns of the update that was under way when a restarted recorder attached are not
    /// counted, like its costs: counted as executions still out, they held the next
    /// distribution for good once they were more than the room less K.
    #[test]
    fn unrecorded_costs_do_not_wait_for_an_update_they_do_not_count() {
        let mut c = UnrecordedCosts::new(30, 10);
        c.attach(7, 8);
        c.issued(7, 25);
        (0..35).for_each(|_| c.received(7));
        assert_eq!(c.waiting(), 0);
        assert!(c.fit(10));
    }

    fn reach() -> tasks::External {
        let settings = [("target_x".to_string(), 0.3), ("target_y".to_string(), 0.7)];
        tasks::External::new(1, 1, vec![0.0], &settings).unwrap()
    }

    fn cost(worker: u32, rollout: u32, ran_with: &[f64]) -> wire::CostHeader {
        let (settings, settings_len) = wire::pack_settings(ran_with);
        wire::CostHeader {
            update: 40,
            worker,
            rollout,
            settings,
            settings_len,
            ..Default::default()
        }
    }

    fn change(name: &str, value: f64, source: &str) -> RecordedChange {
        RecordedChange {
            from_update: 40,
            name: name.into(),
            value,
            source: source.into(),
        }
    }

    #[test]
    fn a_second_change_of_a_setting_at_one_update_overrides_the_first() {
        let mut task = reach();
        let mut recorded = Vec::new();
        let at = |name: &str, value: f64, from_update: u64| TaskChange {
            from_update,
            name: name.into(),
            value,
        };
        apply(
            &mut task,
            &at("target_y", 0.5, 40),
            "schedule",
            &mut recorded,
        )
        .unwrap();
        apply(
            &mut task,
            &at("target_x", 0.2, 40),
            "schedule",
            &mut recorded,
        )
        .unwrap();
        apply(
            &mut task,
            &at("target_y", 0.6, 40),
            "runtime",
            &mut recorded,
        )
        .unwrap();
        apply(
            &mut task,
            &at("target_y", 0.7, 41),
            "runtime",
            &mut recorded,
        )
        .unwrap();
        let listed: Vec<(u64, &str, f64, &str)> = recorded
            .iter()
            .map(|c| (c.from_update, c.name.as_str(), c.value, c.source.as_str()))
            .collect();
        assert_eq!(
            listed,
            [
                (40, "target_x", 0.2, "schedule"),
                (40, "target_y", 0.6, "runtime"),
                (41, "target_y", 0.7, "runtime")
            ]
        );
    }

    #[test]
    fn a_cost_error_names_the_settings_its_rollout_ran_with() {
        let task = reach();
        let published = [0.3, 1e308];
        assert_eq!(
            ran_with_text(&cost(0, 3, &[]), &published, &task),
            ", which ran with target_x = 0.3, target_y = 1e308"
        );
        assert_eq!(
            ran_with_text(&cost(0, 3, &[0.3, 0.7]), &published, &task),
            ", which ran with target_x = 0.3, target_y = 0.7"
        );
        let none = tasks::External::new(1, 1, vec![0.0], &[]).unwrap();
        assert_eq!(ran_with_text(&cost(0, 3, &[]), &[], &none), "");
    }

    #[test]
    fn rollouts_that_ran_with_other_settings_than_each_other_stop_the_run() {
        let task = reach();
        let published = [0.3, 5.0];
        let mut first = None;
        // A worker that does not say ran with the published settings.
        RanWith::check(&mut first, &cost(0, 0, &[]), &published, &task).unwrap();
        RanWith::check(&mut first, &cost(1, 3, &[0.3, 5.0]), &published, &task).unwrap();
        let e = RanWith::check(&mut first, &cost(1, 4, &[0.3, 0.7]), &published, &task)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(
                "update 40: worker-1 ran rollout 4 with target_y = 0.7, worker-0 ran rollout 0 \
                 with target_y = 5: one worker's task refused a change another's took"
            ),
            "{e}"
        );
        let e = RanWith::check(&mut first, &cost(0, 6, &[0.3, 0.7]), &published, &task)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("with target_y = 5: its task took a value for one rollout that it refused"),
            "{e}"
        );
        let e = RanWith::check(&mut first, &cost(1, 5, &[0.3]), &published, &task)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("ran rollout 5 with 1 task settings, the run has 2"),
            "{e}"
        );
    }

    #[test]
    fn a_refused_change_moves_to_the_refused_and_the_value_run_with_stays() {
        let mut task = reach();
        task.set("target_y", 5.0).unwrap();
        let published = [0.3, 5.0];
        let mut first = None;
        RanWith::check(&mut first, &cost(0, 0, &[0.3, 0.7]), &published, &task).unwrap();
        let mut recorded = vec![
            change("target_x", 0.3, "runtime"),
            // In force where a resumed run began, then changed by its schedule.
            change("target_y", 0.7, "resume"),
            change("target_y", 5.0, "schedule"),
        ];
        recorded[0].from_update = 12;
        let mut refused = Vec::new();
        let ran = first.unwrap();
        let taken = ran
            .take_refusals(40, &published, &mut task, &mut recorded, &mut refused)
            .unwrap();
        assert_eq!(taken, [(1, 5.0)]);
        assert_eq!(task.settings(), [("target_x", 0.3), ("target_y", 0.7)]);
        assert_eq!(refused, [change("target_y", 5.0, "schedule")]);
        assert_eq!(recorded.len(), 2);
        assert_eq!(recorded[0].from_update, 12);
        assert_eq!(recorded[1], change("target_y", 0.7, "resume"));

        // Not a change of this update (a worker of another build joined): what the rollouts ran
        // with is recorded as in force from here.
        let mut first = None;
        RanWith::check(&mut first, &cost(0, 0, &[0.25, 0.7]), &[0.3, 0.7], &task).unwrap();
        let (mut recorded, mut refused) = (Vec::new(), Vec::new());
        // One refusal counted before: settling adds this one and names it the last.
        let count = std::cell::Cell::new((1, 1, 5.0, 12));
        let lists = (&mut recorded, &mut refused);
        assert!(RanWith::settle(&mut first, 40, &[0.3, 0.7], &mut task, lists, &count).unwrap());
        assert!(first.is_none());
        assert!(refused.is_empty());
        assert_eq!(recorded, [change("target_x", 0.25, "workers")]);
        assert_eq!(task.settings()[0], ("target_x", 0.25));
        assert_eq!(count.get(), (2, 0, 0.3, 40));
        // Nothing in (a run stopped before any rollout of its update reported): nothing to count.
        let lists = (&mut recorded, &mut refused);
        assert!(!RanWith::settle(&mut None, 40, &[0.3, 0.7], &mut task, lists, &count).unwrap());
        assert_eq!(count.get(), (2, 0, 0.3, 40));
    }
}
