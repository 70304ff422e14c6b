//! A rollout worker: executes the θ of each work item in its inbox (read in place from shared
//! memory) and writes the cost trajectory straight into a loaned `costs` sample. The task settings
//! of the item's update come with the item, so a worker that joins or restarts mid-run needs no
//! history.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use session::RunConfig;
use tasks::Task;
use wire::{CostHeader, Ready, WorkHeader};

use crate::{
    announce_ready, iox, wait_loop_spinning, Context, Flow, Ports as _, ProcessArgs, ProcessError,
    Spin,
};

/// The arguments the supervisor passes to a worker (`--config`, `--run-dir`, `--run-id`,
/// `--worker`, `--incarnation`): flatten them into your binary's own `clap` parser
/// (`#[command(flatten)]`) and pass them to [`serve`], or let [`serve_main`] parse them.
// clap takes an `Args` struct's doc comment, and that of one it flattens (`ProcessArgs`), as
// the `--help` text of a command that flattens it and has none of its own (a `serve_main`
// worker): these structs' docs are for rustdoc only.
#[derive(Debug, Clone, clap::Args)]
#[command(about = None, long_about = None)]
pub struct WorkerArgs {
    /// The run's config, directory and id.
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

/// This process runs a worker slot: [`stop_requested`] may read iceoryx2's signal flag, whose
/// handlers [`Context::new`] installed. Elsewhere reading it would install them, and Ctrl-C
/// would no longer end an in-process run.
static SERVING: AtomicBool = AtomicBool::new(false);
/// [`stop_requested`] has told the task to stop: the rollout it is in is abandoned.
static STOP_SEEN_BY_TASK: AtomicBool = AtomicBool::new(false);

/// Whether this worker has been asked to stop: SIGTERM or SIGINT, which `supervisor stop`, a
/// scale-down and Ctrl-C send. For a rollout that takes long (a robot's episode, a simulation
/// of many steps): check it, e.g. once per control cycle, and return at once when it is true.
/// A rollout that saw it true is abandoned, whatever it returns: its cost is not sent (the
/// sampler hands the rollout to another worker after a scale-down; after a stop the update
/// stays unfinished), and the worker exits with status 0 at once. A rollout that never checks
/// runs to its end first (its cost is sent), and a worker still in it after
/// `pipeline.shutdown_timeout_ms` is SIGKILLed by the supervisor.
///
/// Two atomic loads once a stop has been seen, an uncontended lock before: cheap enough for
/// every step. Outside a worker (a task run by `session::InProcess`) always false.
pub fn stop_requested() -> bool {
    if !SERVING.load(Ordering::Relaxed) || !crate::termination_requested() {
        return false;
    }
    STOP_SEEN_BY_TASK.store(true, Ordering::Relaxed);
    true
}

/// The built-in `rollout-worker`: runs the config's own task (via-point, T-ball). That task is
/// the one the run was sized from, so there is no shape to check.
pub fn main(args: &WorkerArgs) -> Result<(), ProcessError> {
    slot(args, |ctx| Ok(session::build_task(&ctx.config)?))
}

/// Runs one worker slot of a run with a task of your own — your simulator, your robot — until
/// the run ends; it is the loop of the built-in `rollout-worker`. `make_task` gets the run's
/// config once at start. Use it with `[task.external]`, whose `worker` command is a program
/// that calls this ([`serve_main`] parses the arguments the supervisor passes and reports
/// errors), e.g. `crates/supervisor/examples/reach-worker.rs`.
///
/// The task must have the shape the config declares — P parameters, N steps, the same setting
/// names in the same order ([`session::check_task_shape`]) — or this fails at start, naming
/// both. The same task runs without the pipeline through `session::InProcess::with_task`.
///
/// `make_task` may fail with any error type that converts into a boxed error (`anyhow::Error`
/// does); it comes back as [`ProcessError::MakeTask`], unchanged, and the supervisor restarts
/// the worker (a simulator not up yet may be there next time). A config your task can never
/// run (a robot without the joint it names) is [`ProcessError::ConfigRefused`], also through
/// `?` in an `anyhow::Result`: the worker exits with 78 and is not restarted. The other failures: the
/// run's config, services or ports ([`ProcessError::Config`], [`ProcessError::Service`],
/// [`ProcessError::Port`]), the task's shape ([`ProcessError::TaskShape`]), a work item not of
/// the run's shape ([`ProcessError::WorkItemShape`]), a setting value the task refuses with
/// nothing to fall back to ([`ProcessError::SettingRefused`]). A stop (SIGTERM, SIGINT, the run
/// directory gone) returns `Ok`. A closure that cannot fail names its error type, which is not
/// inferred: `|_| Ok::<_, std::convert::Infallible>(task)`.
pub fn serve<T: Task, E>(
    args: &WorkerArgs,
    make_task: impl FnOnce(&RunConfig) -> Result<T, E>,
) -> Result<(), ProcessError>
where
    E: Into<Box<dyn std::error::Error + Send + Sync>> + 'static,
{
    slot(args, |ctx| {
        let task = make_task(&ctx.config).map_err(ProcessError::from_make_task)?;
        session::check_task_shape(&task, &ctx.config).map_err(ProcessError::TaskShape)?;
        Ok(task)
    })
}

/// The worker loop of slot `args.worker`, with the task `make_task` builds once the run's
/// context is open.
fn slot<T: Task>(
    args: &WorkerArgs,
    make_task: impl FnOnce(&Context) -> Result<T, ProcessError>,
) -> Result<(), ProcessError> {
    let (w, incarnation) = (args.worker, args.incarnation);
    let ctx = Context::new(&args.process, &wire::worker_node_name(w, incarnation))?;
    if w as usize >= ctx.limits.max_workers {
        return Err(ProcessError::SlotBeyondLimit {
            worker: w,
            max_workers: ctx.limits.max_workers,
        });
    }
    SERVING.store(true, Ordering::Relaxed);
    let mut task = make_task(&ctx)?;
    let mut applied = Applied::new(&task);
    let nan_from = ctx.config.pipeline().fault_nan_from_update;
    let hang_at = ctx
        .config
        .pipeline()
        .fault_hang_at_update
        .filter(|_| incarnation == 0);
    let hang_in = ctx
        .config
        .pipeline()
        .fault_hang_at_chunk_rollout
        .unwrap_or(1);
    // Only a run with a rollout timeout needs to hear of a chunk's progress (Ready::ROLLOUT_DONE).
    let report_rollouts = ctx.config.pipeline().rollout_timeout_ms.is_some();
    let (dim, steps) = (ctx.limits.dim, ctx.limits.steps);

    let inbox = wire::work(&ctx.node, ctx.run_id, w, &ctx.limits)?.subscriber("work")?;
    let doorbell = ctx.listener(&wire::worker_doorbell(w))?;
    let costs = iox(
        wire::costs(&ctx.node, ctx.run_id, &ctx.limits)?
            .publisher_builder()
            .initial_max_slice_len(steps)
            .allocation_strategy(AllocationStrategy::Static)
            .set_degradation_handler(crate::failed_connections("costs publisher", "subscriber"))
            .create(),
        "costs publisher",
    )?;
    let ready = wire::ready(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("ready")?;
    let updater_bell = ctx.notifier(wire::process::UPDATER)?;
    let sampler_bell = ctx.notifier(wire::process::SAMPLER)?;
    let publish_ready = |chunk: u64, flags: u32| -> Result<(), ProcessError> {
        iox(
            ready.send_copy(Ready {
                run_id: ctx.run_id,
                chunk,
                worker: w,
                incarnation,
                pid: std::process::id(),
                flags,
            }),
            "send ready",
        )?;
        Ok(())
    };
    let ring = |bell: &Notifier<wire::Service>, what: &str| {
        iox(bell.notify_with_custom_event_id(wire::WAKE), what).map(|_| ())
    };
    // Ready to the sampler before the announcement to the supervisor, which starts the run
    // once every worker has announced: the other way round, a worker descheduled between the
    // two was not yet the sampler's when the first update was handed out, and the others got
    // all its rollouts (with one-minute rollouts it sat idle for the whole update).
    publish_ready(Ready::NO_CHUNK, 0)?;
    ring(&sampler_bell, "notify sampler")?;
    let _announced = announce_ready(&ctx, wire::role::WORKER, w, incarnation)?;

    // (the chunk being worked on, its rollouts sent)
    let mut chunk = (u64::MAX, 0u32);
    let mut reported_at = Instant::now();
    let mut last_notify = Instant::now();
    let mut unannounced = false;
    let mut run_end = crate::RunEnd::new(&ctx.run_dir, ctx.run_id);
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
                return Err(ProcessError::WorkItemShape {
                    update: h.update,
                    len: item.payload().len(),
                    steps: h.steps,
                    expected_len: dim,
                    expected_steps: steps,
                });
            }
            let settings = wire::unpack_settings(&h.settings, h.settings_len);
            let previous = wire::unpack_settings(&h.previous_settings, h.settings_len);
            let len = settings.len().min(applied.names.len());
            let refusals =
                applied.apply(&mut task, h.update, &settings[..len], &previous[..len])?;
            for (i, value, e) in refusals {
                let name = applied.names[i];
                eprintln!(
                    "update {}: the task refused {name} = {} ({e}); its rollouts run with {name} \
                     = {}, as the update before",
                    h.update,
                    tasks::value_text(value),
                    tasks::value_text(applied.values[i])
                );
            }
            let (ran_with, ran_with_len) = wire::pack_settings(&applied.values);
            if chunk.0 != h.chunk {
                chunk = (h.chunk, 0);
                reported_at = Instant::now();
            }
            if hang_at.is_some_and(|n| h.update >= n) && chunk.1 + 1 == hang_in {
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
            if STOP_SEEN_BY_TASK.load(Ordering::Relaxed) {
                // The task returned early on stop_requested(): what it wrote is not this
                // rollout's cost. The sampler hands the rollout on once this worker is gone.
                println!(
                    "update {}, rollout {}: stopped by a signal during the rollout; abandoned, \
                     its cost not sent",
                    h.update, h.rollout
                );
                return Ok(Flow::Stop);
            }
            let rerun = h.flags & WorkHeader::RERUN != 0;
            if nan_from.is_some_and(|n| h.update >= n)
                || ctx
                    .config
                    .run
                    .fault_nan(h.update, h.rollout as usize, rerun)
            {
                // Fault injection (pipeline.fault_nan_from_update, run.fault_nan_first_attempt):
                // a task returning NaN, from an update on or once.
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
            chunk.1 += 1;
            let chunk_done = chunk.1 >= h.chunk_len;
            // Ready before the updater's bell: the distribution the updater then publishes
            // wakes the sampler, which must find this worker idle (see the wire protocol). Not
            // before the costs: the sampler forgets a chunk once it is reported done, so a
            // worker killed in between would leave a rollout that nobody redoes.
            if chunk_done {
                publish_ready(h.chunk, 0)?;
            } else if report_rollouts && reported_at.elapsed() >= wire::ROLLOUT_DONE_INTERVAL {
                publish_ready(h.chunk, Ready::rollout_done(chunk.1 as usize))?;
                reported_at = Instant::now();
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
        if let Some(why) = run_end.ended() {
            println!("the run has ended ({why}): exiting");
            return Ok(Flow::Stop);
        }
        Ok(Flow::Continue)
    })?;
    Ok(())
}

/// The task settings a worker has applied, and the values its task refused in the update it is
/// at.
struct Applied {
    names: Vec<&'static str>,
    values: Vec<f64>,
    /// The update of the work items last applied, and the (setting, value bits) its task
    /// refused in it.
    update: u64,
    refused: Vec<(usize, u64)>,
}

impl Applied {
    fn new<T: Task>(task: &T) -> Self {
        let settings = task.settings();
        Self {
            names: settings.iter().map(|(n, _)| *n).collect(),
            values: settings.iter().map(|(_, v)| *v).collect(),
            update: u64::MAX,
            refused: Vec::new(),
        }
    }

    /// Applies the `settings` of a work item of `update`, on top of those the update before
    /// ran with (`previous`): first the task is brought to `previous` (a fresh worker's is at
    /// the config's values), then the update's changes are tried, together: a change refused
    /// is tried again once the others are in, until a round takes none (the reach task refuses
    /// target_x = 0.8 with target_y = 0.7, out of reach, and takes it once target_y = 0.1 is
    /// in). A change still refused keeps the value of `previous`, so that every rollout of an
    /// update runs with the same settings whichever worker runs it, a fresh one included, and
    /// the updater sees the change refused. The update's other items find it decided.
    ///
    /// Returns the refusals new in this item: (setting, refused value, why). Fails if the task
    /// refuses a value of `previous` (there is nothing to fall back to: the config's own value
    /// at a run's first update, or one the other workers' tasks took).
    fn apply<T: Task>(
        &mut self,
        task: &mut T,
        update: u64,
        settings: &[f64],
        previous: &[f64],
    ) -> Result<Vec<(usize, f64, tasks::TaskError)>, ProcessError> {
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits();
        if update != self.update {
            self.update = update;
            self.refused.clear();
        }
        let decided = settings
            .iter()
            .enumerate()
            .all(|(i, &v)| same(self.values[i], v) || self.refused.contains(&(i, v.to_bits())));
        if decided {
            return Ok(Vec::new());
        }
        let off: Vec<usize> = (0..settings.len())
            .filter(|&i| !same(self.values[i], previous[i]))
            .collect();
        if let Some((i, reason)) = self.take(task, previous, off).into_iter().next() {
            // Not a crash to restart: a restarted worker's task meets the same value, and so
            // does every other worker the sampler hands the rollouts to.
            return Err(ProcessError::SettingRefused {
                update,
                setting: self.names[i],
                value: previous[i],
                reason,
                changed_by_update: !same(settings[i], previous[i]),
            });
        }
        let changes: Vec<usize> = (0..settings.len())
            .filter(|&i| !same(settings[i], previous[i]))
            .collect();
        let refusals: Vec<(usize, f64, tasks::TaskError)> = self
            .take(task, settings, changes)
            .into_iter()
            .map(|(i, e)| (i, settings[i], e))
            .collect();
        self.refused
            .extend(refusals.iter().map(|(i, v, _)| (*i, v.to_bits())));
        Ok(refusals)
    }

    /// Sets the settings `which` to their values in `target` ([`tasks::set_in_rounds`]) and
    /// keeps the values taken. Returns those refused in the last round (a refused value leaves
    /// the task as it was), with why.
    fn take<T: Task>(
        &mut self,
        task: &mut T,
        target: &[f64],
        which: Vec<usize>,
    ) -> Vec<(usize, tasks::TaskError)> {
        let settings: Vec<(&str, f64)> =
            which.iter().map(|&i| (self.names[i], target[i])).collect();
        let refused: Vec<(usize, tasks::TaskError)> = tasks::set_in_rounds(task, &settings)
            .into_iter()
            .map(|(j, e)| (which[j], e))
            .collect();
        for &i in &which {
            if !refused.iter().any(|(r, _)| *r == i) {
                self.values[i] = target[i];
            }
        }
        refused
    }
}

/// Parses the arguments the supervisor passes a worker and runs [`serve`]; returns the exit
/// code (1, after printing the error chain, on failure; [`wire::EXIT_CONFIG_REFUSED`] when
/// [`ProcessError::refuses_config`]). The whole `main` of a worker of your own:
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
pub fn serve_main<T: Task, E>(
    name: &str,
    make_task: impl FnOnce(&RunConfig) -> Result<T, E>,
) -> std::process::ExitCode
where
    E: Into<Box<dyn std::error::Error + Send + Sync>> + 'static,
{
    use clap::Parser as _;
    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        worker: WorkerArgs,
    }
    let cli = Cli::parse();
    crate::run_main(name, || Ok(serve(&cli.worker, make_task)?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tasks::TaskError;

    #[test]
    fn a_worker_command_has_no_help_text_from_the_argument_structs_docs() {
        use clap::CommandFactory as _;
        // As `serve_main`'s parser: a command of its own without docs.
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            worker: WorkerArgs,
        }
        let mut command = Cli::command();
        assert_eq!(command.get_about().map(ToString::to_string), None);
        let help = command.render_long_help().to_string();
        assert!(help.starts_with("Usage:"), "{help}");
    }

    /// A target (x, y) that must stay within 1 of the origin, as the reach task's must stay
    /// within the arm's reach; unset (NaN) until the run's settings arrive, as a worker's own
    /// task is.
    struct Target {
        xy: [f64; 2],
        sets: usize,
    }

    impl Task for Target {
        fn name(&self) -> &'static str {
            "target"
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
            c.fill(0.0);
            0.0
        }
        fn settings(&self) -> Vec<(&'static str, f64)> {
            vec![("x", self.xy[0]), ("y", self.xy[1])]
        }
        fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
            self.sets += 1;
            let mut xy = self.xy;
            xy[usize::from(name == "y")] = value;
            if xy[0].hypot(xy[1]) > 1.0 {
                return Err(TaskError::Invalid {
                    task: "target",
                    reason: "out of reach".into(),
                });
            }
            self.xy = xy;
            Ok(())
        }
    }

    /// A robot driver's handle that must stay on the thread that opened it.
    struct Driver {
        link: std::rc::Rc<std::cell::Cell<u64>>,
    }

    impl Task for Driver {
        fn name(&self) -> &'static str {
            "driver"
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
        fn rollout(&mut self, theta: &[f64], c: &mut [f64]) -> f64 {
            self.link.set(self.link.get() + 1);
            c[0] = theta[0] * theta[0];
            0.0
        }
        fn settings(&self) -> Vec<(&'static str, f64)> {
            vec![]
        }
        fn set(&mut self, name: &str, _: f64) -> Result<(), TaskError> {
            Err(TaskError::Invalid {
                task: "driver",
                reason: name.into(),
            })
        }
    }

    /// Compiles only while `serve`, `serve_main` and the in-process runner take a task that is
    /// not `Send` (they required it, though each keeps its task on one thread).
    fn serve_a_driver(args: &WorkerArgs) -> Result<(), ProcessError> {
        serve(args, |_| {
            Ok::<_, std::convert::Infallible>(Driver {
                link: Default::default(),
            })
        })
    }

    fn serve_main_a_driver() -> std::process::ExitCode {
        serve_main("driver-worker", |_| {
            Ok::<_, std::convert::Infallible>(Driver {
                link: Default::default(),
            })
        })
    }

    fn run_a_driver_in_process(config: &RunConfig) -> anyhow::Result<session::InProcess> {
        let task = Driver {
            link: Default::default(),
        };
        Ok(session::InProcess::with_task(config, 1, Box::new(task))?)
    }

    #[test]
    fn a_task_that_is_not_send_is_served_as_any_other() {
        let served: fn(&WorkerArgs) -> Result<(), ProcessError> = serve_a_driver;
        let main: fn() -> std::process::ExitCode = serve_main_a_driver;
        let in_process: fn(&RunConfig) -> anyhow::Result<session::InProcess> =
            run_a_driver_in_process;
        let _ = (served, main, in_process);
        // And its settings are applied through the same path as a Send task's.
        let link = std::rc::Rc::new(std::cell::Cell::new(0));
        let mut task = Driver { link: link.clone() };
        let mut applied = Applied::new(&task);
        assert!(applied.apply(&mut task, 0, &[], &[]).unwrap().is_empty());
        let mut c = [0.0];
        task.rollout(&[3.0], &mut c);
        assert_eq!((c[0], link.get()), (9.0, 1));
    }

    fn fresh() -> (Target, Applied) {
        let task = Target {
            xy: [f64::NAN; 2],
            sets: 0,
        };
        let applied = Applied::new(&task);
        (task, applied)
    }

    #[test]
    fn a_refused_value_is_replaced_by_the_one_the_update_before_ran_with() {
        // A worker that ran the update before with (0.3, 0.5).
        let (mut task, mut applied) = fresh();
        let before = [0.3, 0.5];
        applied.apply(&mut task, 6, &before, &before).unwrap();
        let r = applied.apply(&mut task, 7, &[0.3, 5.0], &before).unwrap();
        assert_eq!(r.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(), [(1, 5.0)]);
        assert_eq!((task.xy, &applied.values[..]), ([0.3, 0.5], &before[..]));
        // Its next item of the same update: not tried again, nothing new to report.
        let sets = task.sets;
        assert!(applied
            .apply(&mut task, 7, &[0.3, 5.0], &before)
            .unwrap()
            .is_empty());
        assert_eq!(task.sets, sets);
        // A fresh worker (restarted mid-update) ends up with the same values.
        let (mut other, mut applied) = fresh();
        let r = applied.apply(&mut other, 7, &[0.3, 5.0], &before).unwrap();
        assert_eq!(
            (r.len(), other.xy, &applied.values[..]),
            (1, before, &before[..])
        );
        // The next update, published with the values in force again, changes nothing.
        let sets = other.sets;
        assert!(applied
            .apply(&mut other, 8, &before, &before)
            .unwrap()
            .is_empty());
        assert_eq!(other.sets, sets);
    }

    #[test]
    fn an_updates_changes_are_taken_together_and_a_value_refused_stays_refused_for_it() {
        // (0.8, 0.7) is out of reach, (0.8, 0.1) is not: x = 0.8, refused with y as it was, is
        // taken once y = 0.1 is in, whichever order the changes come in.
        let before = [0.3, 0.7];
        let (mut task, mut applied) = fresh();
        applied.apply(&mut task, 4, &before, &before).unwrap();
        assert!(applied
            .apply(&mut task, 5, &[0.8, 0.1], &before)
            .unwrap()
            .is_empty());
        assert_eq!(
            (task.xy, &applied.values[..]),
            ([0.8, 0.1], &[0.8, 0.1][..])
        );
        // (0.8, 0.65) is out of reach too: x stays refused for every item of the update, and a
        // fresh worker (restarted mid-update, its task at the config's values) ends the same.
        let (mut task, mut applied) = fresh();
        applied.apply(&mut task, 4, &before, &before).unwrap();
        let change = [0.8, 0.65];
        let r = applied.apply(&mut task, 5, &change, &before).unwrap();
        assert_eq!(r.iter().map(|r| (r.0, r.1)).collect::<Vec<_>>(), [(0, 0.8)]);
        for _ in 0..3 {
            let sets = task.sets;
            assert!(applied
                .apply(&mut task, 5, &change, &before)
                .unwrap()
                .is_empty());
            assert_eq!(
                (task.sets, applied.values.as_slice()),
                (sets, &[0.3, 0.65][..])
            );
        }
        let mut other = Target {
            xy: [0.9, 0.0],
            sets: 0,
        };
        let mut fresh_applied = Applied::new(&other);
        let r = fresh_applied
            .apply(&mut other, 5, &change, &before)
            .unwrap();
        assert_eq!((r.len(), other.xy), (1, [0.3, 0.65]));
        // In a later update, from where this one ended, it is tried again.
        let r = applied
            .apply(&mut task, 6, &[0.8, 0.1], &[0.3, 0.65])
            .unwrap();
        assert!(r.is_empty());
        assert_eq!(applied.values, [0.8, 0.1]);
    }

    #[test]
    fn a_refused_value_with_nothing_to_fall_back_to_stops_the_worker() {
        let refusal = |update, settings: &[f64], previous: &[f64]| {
            let (mut task, mut applied) = fresh();
            applied
                .apply(&mut task, update, settings, previous)
                .unwrap_err()
        };
        // The config's own value at the first update: previous = settings. Refused as the
        // config is (run_main exits with wire::EXIT_CONFIG_REFUSED): a restart meets the same.
        let e = refusal(0, &[0.3, 5.0], &[0.3, 5.0]);
        assert!(e.refuses_config(), "{e}");
        let expected = [
            (
                e.to_string(),
                "update 0: the task refused y = 5 (task `target`: out of reach), the config's \
                 value, which the run starts from: nothing to fall back to",
            ),
            // Later, in a worker that joins or restarts: in force, from the config or a change.
            (
                refusal(4, &[0.3, 5.0], &[0.3, 5.0]).to_string(),
                "update 4: the task refused y = 5 (task `target`: out of reach), a value in force \
                 before this update (the config's, or an earlier change the other workers \
                 took): nothing to fall back to",
            ),
            // The value before refused too.
            (
                refusal(4, &[0.3, 5.0], &[0.3, 3.0]).to_string(),
                "update 4: the task refused y = 3 (task `target`: out of reach), the value the \
                 update before ran with: nothing to fall back to",
            ),
        ];
        for (e, text) in expected {
            assert_eq!(e, text);
        }
    }
}
