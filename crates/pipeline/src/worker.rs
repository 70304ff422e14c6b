//! A rollout worker: executes the θ of each work item in its inbox (read in place from shared
//! memory) and writes the cost trajectory straight into a loaned `costs` sample. The task settings
//! of the item's update come with the item, so a worker that joins or restarts mid-run needs no
//! history.

use std::time::{Duration, Instant};

use anyhow::bail;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use session::RunConfig;
use tasks::Task;
use wire::{CostHeader, Ready, WorkHeader};

use crate::{
    announce_ready, iox, wait_loop_spinning, Context, Flow, Ports as _, ProcessArgs, Spin,
};

#[derive(Debug, Clone, clap::Args)]
pub struct WorkerArgs {
    #[command(flatten)]
    pub process: ProcessArgs,
    /// This worker's slot (its inbox is `work/<worker>`).
    #[arg(long)]
    pub worker: u32,
    /// Increases with every restart of the slot.
    #[arg(long, default_value_t = 0)]
    pub incarnation: u32,
}

/// Costs are announced to the updater at least this often while a chunk is being worked on.
const NOTIFY_INTERVAL: Duration = Duration::from_millis(1);

/// The built-in `rollout-worker`: runs the config's own task (via-point, T-ball). That task is
/// the one the run was sized from, so there is no shape to check.
pub fn main(args: &WorkerArgs) -> anyhow::Result<()> {
    slot(args, |ctx| Ok(session::build_task(&ctx.config)?))
}

/// Runs one worker slot of a run with a task of your own — your simulator, your robot — until
/// the run ends; it is the loop of the built-in `rollout-worker`. `make_task` gets the run's
/// config once at start. Use it with `[task.external]`, whose `worker` command is a program
/// that calls this ([`serve_main`] parses the arguments the supervisor passes and reports
/// errors), e.g. `crates/supervisor/examples/reach-worker.rs`.
///
/// The task must have the shape the config declares — P parameters, N steps, the same setting
/// names in the same order — or this fails at start, naming both.
pub fn serve<T: Task>(
    args: &WorkerArgs,
    make_task: impl FnOnce(&RunConfig) -> anyhow::Result<T>,
) -> anyhow::Result<()> {
    slot(args, |ctx| {
        let task = make_task(&ctx.config)?;
        check_shape(&task, &ctx.config).map_err(|e| anyhow::Error::new(ConfigRefused(e)))?;
        Ok(task)
    })
}

/// The worker loop of slot `args.worker`, with the task `make_task` builds once the run's
/// context is open.
fn slot<T: Task>(
    args: &WorkerArgs,
    make_task: impl FnOnce(&Context) -> anyhow::Result<T>,
) -> anyhow::Result<()> {
    let (w, incarnation) = (args.worker, args.incarnation);
    let ctx = Context::new(&args.process, &wire::worker_node_name(w, incarnation))?;
    if w as usize >= ctx.limits.max_workers {
        bail!(
            "worker slot {w} is beyond pipeline.max_workers = {}",
            ctx.limits.max_workers
        );
    }
    let mut task = make_task(&ctx)?;
    let names: Vec<&'static str> = task.settings().iter().map(|(n, _)| *n).collect();
    let mut applied: Vec<f64> = task.settings().iter().map(|(_, v)| *v).collect();
    let nan_from = ctx.config.pipeline().fault_nan_from_update;
    let hang_at = ctx
        .config
        .pipeline()
        .fault_hang_at_update
        .filter(|_| incarnation == 0);
    let (dim, steps) = (ctx.limits.dim, ctx.limits.steps);

    let inbox = wire::work(&ctx.node, ctx.run_id, w, &ctx.limits)?.subscriber("work")?;
    let doorbell = ctx.listener(&format!("worker/{w}"))?;
    let costs = iox(
        wire::costs(&ctx.node, ctx.run_id, &ctx.limits)?
            .publisher_builder()
            .initial_max_slice_len(steps)
            .allocation_strategy(AllocationStrategy::Static)
            .create(),
        "costs publisher",
    )?;
    let ready = wire::ready(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("ready")?;
    let updater_bell = ctx.notifier("updater")?;
    let sampler_bell = ctx.notifier("sampler")?;
    let publish_ready = |completed_chunk: u64| -> anyhow::Result<()> {
        iox(
            ready.send_copy(Ready {
                run_id: ctx.run_id,
                completed_chunk,
                worker: w,
                incarnation,
                pid: std::process::id(),
                _reserved: 0,
            }),
            "send ready",
        )?;
        Ok(())
    };
    let ring = |bell: &Notifier<wire::Service>, what: &str| {
        iox(bell.notify_with_custom_event_id(wire::WAKE), what).map(|_| ())
    };
    let _announced = announce_ready(&ctx, wire::role::WORKER, w, incarnation)?;
    publish_ready(Ready::NO_CHUNK)?;
    ring(&sampler_bell, "notify sampler")?;

    let mut chunk = (u64::MAX, 0u32);
    // The last refused change reported: (update, setting, value bits).
    let mut refused: Option<(u64, usize, u64)> = None;
    let mut last_notify = Instant::now();
    let mut unannounced = false;
    let mut last_run_dir_check = Instant::now();
    let mut spin = Spin::new(Duration::from_micros(ctx.config.pipeline().worker_spin_us));
    wait_loop_spinning(&doorbell, &mut spin, || {
        // The sampler rings the workers one after another, and the kernel tends to run a woken
        // process on the CPU of the process that woke it (Unix-socket wake-ups are "sync"),
        // preempting it: the sampler then rings the next worker only after this one has
        // finished its chunk, while the other CPU idles (seen with `perf sched`: 2 workers
        // took turns on one CPU). One yield hands the CPU back to the sampler, if it is
        // waiting for it, to finish ringing; it costs a syscall per chunk otherwise.
        if iox(inbox.has_samples(), "inbox")? {
            std::thread::yield_now();
        }
        while let Some(item) = iox(inbox.receive(), "receive work")? {
            // A worker with a steady stream of work (the last one left while the others stop)
            // may never find its inbox empty: without this it would not see SIGTERM.
            if crate::termination_requested() {
                return Ok(Flow::Continue);
            }
            let h = *item.user_header();
            if h.run_id != ctx.run_id {
                continue;
            }
            if item.payload().len() != dim || h.steps as usize != steps {
                bail!(
                    "work item of update {} has θ of length {} and {} steps, expected {dim} and {steps}",
                    h.update,
                    item.payload().len(),
                    h.steps
                );
            }
            let len = (h.settings_len as usize).min(names.len());
            let refusals = apply_settings(
                &mut task,
                &names,
                &mut applied,
                &h.settings[..len],
                &h.previous_settings[..len],
                h.update,
            )?;
            for (i, value, e) in refusals {
                // Once per update and setting, not once per rollout.
                if refused != Some((h.update, i, value.to_bits())) {
                    refused = Some((h.update, i, value.to_bits()));
                    eprintln!(
                        "update {}: the task refused {} = {} ({e}); its rollouts run with {} = {}, \
                         as the update before",
                        h.update,
                        names[i],
                        tasks::value_text(value),
                        names[i],
                        tasks::value_text(applied[i])
                    );
                }
            }
            let (ran_with, ran_with_len) = wire::pack_settings(&applied);
            if hang_at.is_some_and(|n| h.update >= n) {
                // Fault injection (pipeline.fault_hang_at_update): a simulator or robot that
                // stops answering. Only a signal ends it.
                while !crate::termination_requested() {
                    std::thread::sleep(Duration::from_millis(10));
                }
                return Ok(Flow::Stop);
            }
            // The wall clock first: preempted between the two reads, the recorded interval
            // (start_ns, start_ns + duration) comes out early, never overlapping the next.
            let start_ns = wire::wall_clock_ns();
            let start = Instant::now();
            let sample = iox(costs.loan_slice_uninit(steps), "loan cost sample")?;
            let mut sample = sample.write_from_fn(|_| 0.0);
            let mut terminal = task.rollout(item.payload(), sample.payload_mut());
            if nan_from.is_some_and(|n| h.update >= n) {
                // Fault injection (pipeline.fault_nan_from_update): a task returning NaN.
                terminal = f64::NAN;
            }
            *sample.user_header_mut() = CostHeader {
                run_id: ctx.run_id,
                update: h.update,
                rollout: h.rollout,
                worker: w,
                duration_ns: start.elapsed().as_nanos() as u64,
                terminal,
                start_ns,
                settings_len: ran_with_len,
                _reserved: 0,
                settings: ran_with,
            };
            drop(item);
            iox(sample.send(), "send costs")?;
            unannounced = true;
            if chunk.0 != h.chunk {
                chunk = (h.chunk, 0);
            }
            chunk.1 += 1;
            let chunk_done = chunk.1 >= h.chunk_len;
            // Ready before the updater's bell: the distribution the updater then publishes
            // wakes the sampler, which must find this worker idle (see the wire protocol). Not
            // before the costs: the sampler forgets a chunk once it is reported done, so a
            // worker killed in between would leave a rollout that nobody redoes.
            if chunk_done {
                publish_ready(h.chunk)?;
            }
            let more = iox(inbox.has_samples(), "inbox")?;
            if chunk_done || !more || last_notify.elapsed() >= NOTIFY_INTERVAL {
                ring(&updater_bell, "notify updater")?;
                last_notify = Instant::now();
                unannounced = false;
            }
            if chunk_done && h.flags & WorkHeader::QUEUE_EMPTY == 0 {
                ring(&sampler_bell, "notify sampler")?;
            }
        }
        if unannounced {
            ring(&updater_bell, "notify updater")?;
            unannounced = false;
        }
        // A worker the supervisor did not start is not stopped by it: it learns that the run
        // has ended from the run directory, which the supervisor removes last. Without this it
        // waited for work forever.
        if last_run_dir_check.elapsed() >= Duration::from_secs(1) {
            last_run_dir_check = Instant::now();
            if !ctx.run_dir.exists() {
                println!(
                    "the run has ended (its run directory {} is gone): exiting",
                    ctx.run_dir.display()
                );
                return Ok(Flow::Stop);
            }
        }
        Ok(Flow::Continue)
    })?;
    Ok(())
}

/// Applies a work item's `settings` to `task`, whose values are `applied`. A value the task
/// refuses is replaced by the one the update before ran with (`previous`), so that every
/// rollout of an update runs with the same settings whichever worker runs it, a fresh one
/// included, and the updater sees the change refused. Returns the refusals: (setting, refused
/// value, why). Fails if there is nothing to fall back to (the value is the one in force before,
/// as at a run's first update) or the task refuses that too.
fn apply_settings<T: Task>(
    task: &mut T,
    names: &[&'static str],
    applied: &mut [f64],
    settings: &[f64],
    previous: &[f64],
    update: u64,
) -> anyhow::Result<Vec<(usize, f64, tasks::TaskError)>> {
    let mut refusals = Vec::new();
    for (i, (&value, &fallback)) in settings.iter().zip(previous).enumerate() {
        if applied[i].to_bits() == value.to_bits() {
            continue;
        }
        let name = names[i];
        let Err(e) = task.set(name, value) else {
            applied[i] = value;
            continue;
        };
        if fallback.to_bits() == value.to_bits() {
            bail!(
                "update {update}: the task refused {name} = {} ({e}), a value in force before this \
                 update (the config's, or an earlier change the other workers took): nothing to \
                 fall back to",
                tasks::value_text(value)
            );
        }
        if applied[i].to_bits() != fallback.to_bits() {
            task.set(name, fallback).map_err(|e2| {
                anyhow::anyhow!(
                    "update {update}: the task refused {name} = {} ({e}) and {name} = {}, the \
                     value the update before ran with ({e2})",
                    tasks::value_text(value),
                    tasks::value_text(fallback)
                )
            })?;
            applied[i] = fallback;
        }
        refusals.push((i, value, e));
    }
    Ok(refusals)
}

/// Parses the arguments the supervisor passes a worker and runs [`serve`]; returns the exit
/// code (1, after printing the error chain, on failure). The whole `main` of a worker of your own:
///
/// ```no_run
/// # struct MySim;
/// # impl MySim { fn new(_: &session::RunConfig) -> anyhow::Result<Self> { Ok(MySim) } }
/// # impl tasks::Task for MySim {
/// #     fn name(&self) -> &'static str { "my-sim" }
/// #     fn parameters(&self) -> usize { 1 }
/// #     fn steps(&self) -> usize { 1 }
/// #     fn initial_mean(&self) -> Vec<f64> { vec![0.0] }
/// #     fn rollout(&mut self, _: &[f64], c: &mut [f64]) -> f64 { c.fill(0.0); 0.0 }
/// #     fn settings(&self) -> Vec<(&'static str, f64)> { vec![] }
/// #     fn set(&mut self, n: &str, _: f64) -> Result<(), tasks::TaskError> {
/// #         Err(tasks::TaskError::Invalid { task: "my-sim", reason: n.into() })
/// #     }
/// # }
/// fn main() -> std::process::ExitCode {
///     pipeline::worker::serve_main("my-sim-worker", MySim::new)
/// }
/// ```
pub fn serve_main<T: Task>(
    name: &str,
    make_task: impl FnOnce(&RunConfig) -> anyhow::Result<T>,
) -> std::process::ExitCode {
    use clap::Parser as _;
    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        worker: WorkerArgs,
    }
    let cli = Cli::parse();
    crate::run_main(name, || serve(&cli.worker, make_task))
}

/// Why a worker refuses the run's config; [`crate::run_main`] exits with
/// [`wire::EXIT_CONFIG_REFUSED`] for it.
#[derive(Debug)]
pub struct ConfigRefused(pub anyhow::Error);

impl std::fmt::Display for ConfigRefused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for ConfigRefused {}

/// A worker's task must match what the update side was configured with: it sizes θ and the
/// cost trajectories, and settings travel by position.
fn check_shape(task: &dyn Task, config: &RunConfig) -> anyhow::Result<()> {
    let declared = config.build_task()?;
    let field = |f: &str| match config.external_worker() {
        Some(_) => format!("task.external.{f}"),
        None => format!("the `{}` task's {f}", declared.name()),
    };
    if task.parameters() != declared.parameters() {
        bail!(
            "task `{}` has {} parameters, but {} = {} in {}",
            task.name(),
            task.parameters(),
            field("parameters"),
            declared.parameters(),
            config.origin.display()
        );
    }
    if task.steps() != declared.steps() {
        bail!(
            "task `{}` has {} steps, but {} = {} in {}",
            task.name(),
            task.steps(),
            field("steps"),
            declared.steps(),
            config.origin.display()
        );
    }
    // The update weighs by the config's activations; a worker whose policy has others would
    // be learning with a projection that is not its own.
    if let (Some(own), Some(declared_psi)) =
        (task.basis_activations(), declared.basis_activations())
    {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        if bits(&own) != bits(&declared_psi) {
            bail!(
                "task `{}` has other basis activations than {} in {}: the update weighs the \
                 rollouts by the config's, so put the task's own there",
                task.name(),
                field("basis_activations"),
                config.origin.display()
            );
        }
    }
    let names = |t: &dyn Task| t.settings().iter().map(|(n, _)| *n).collect::<Vec<_>>();
    if names(task) != names(declared.as_ref()) {
        bail!(
            "task `{}` has the settings {:?}, but {} declares {:?} (same names, same order) in {}",
            task.name(),
            names(task),
            field("settings"),
            names(declared.as_ref()),
            config.origin.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tasks::TaskError;

    /// A task with one setting, `reach`, that refuses values above 1 and starts unset (NaN), as
    /// a worker's own task does before the run's settings arrive.
    struct Arm {
        reach: f64,
        sets: usize,
    }

    impl Task for Arm {
        fn name(&self) -> &'static str {
            "arm"
        }
        fn parameters(&self) -> usize {
            1
        }
        fn steps(&self) -> usize {
            1
        }
        fn initial_mean(&self) -> Vec<f64> {
            vec![0.0]
        }
        fn rollout(&mut self, _: &[f64], c: &mut [f64]) -> f64 {
            c.fill(self.reach);
            0.0
        }
        fn settings(&self) -> Vec<(&'static str, f64)> {
            vec![("reach", self.reach)]
        }
        fn set(&mut self, _: &str, value: f64) -> Result<(), TaskError> {
            self.sets += 1;
            if value > 1.0 {
                return Err(TaskError::Invalid {
                    task: "arm",
                    reason: "out of reach".into(),
                });
            }
            self.reach = value;
            Ok(())
        }
    }

    fn arm() -> (Arm, Vec<f64>) {
        (
            Arm {
                reach: f64::NAN,
                sets: 0,
            },
            vec![f64::NAN],
        )
    }

    #[test]
    fn a_refused_value_is_replaced_by_the_one_the_update_before_ran_with() {
        // A worker that ran the update before with 0.5.
        let (mut task, mut applied) = arm();
        apply_settings(&mut task, &["reach"], &mut applied, &[0.5], &[0.5], 0).unwrap();
        let r = apply_settings(&mut task, &["reach"], &mut applied, &[5.0], &[0.5], 7).unwrap();
        assert_eq!((r.len(), r[0].0, r[0].1), (1, 0, 5.0));
        assert_eq!((task.reach, applied[0]), (0.5, 0.5));
        // A fresh worker (restarted mid-update) ends up with the same value.
        let (mut fresh, mut applied) = arm();
        let r = apply_settings(&mut fresh, &["reach"], &mut applied, &[5.0], &[0.5], 7).unwrap();
        assert_eq!((r.len(), fresh.reach, applied[0]), (1, 0.5, 0.5));
        // The next update, published with the value in force again, changes nothing.
        let sets = fresh.sets;
        let r = apply_settings(&mut fresh, &["reach"], &mut applied, &[0.5], &[0.5], 8).unwrap();
        assert!(r.is_empty());
        assert_eq!(fresh.sets, sets);
    }

    #[test]
    fn a_refused_value_with_nothing_to_fall_back_to_stops_the_worker() {
        // The config's own value at the first update: previous = settings.
        let (mut task, mut applied) = arm();
        let e = apply_settings(&mut task, &["reach"], &mut applied, &[5.0], &[5.0], 0)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("update 0: the task refused reach = 5 (task `arm`: out of reach), a value in force before this update"),
            "{e}"
        );
        // The value before refused too.
        let (mut task, mut applied) = arm();
        let e = apply_settings(&mut task, &["reach"], &mut applied, &[5.0], &[3.0], 4)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("and reach = 3, the value the update before ran with"),
            "{e}"
        );
    }
}
