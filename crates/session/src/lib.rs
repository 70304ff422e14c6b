//! A configured learning session: the TOML schema ([`RunConfig`]), building the optimizer and the
//! task from it, and the in-process executor that drives the sans-IO core.
//!
//! The executor owns the loop (ask, run rollouts, tell, apply task changes, stop); recording and
//! printing are [`Observer`]s, not part of the loop. It is not the multiprocess pipeline, which
//! drives the same core with the same builders, so both give the same result for the same seed.
//!
//! # Your own task, learned in this thread
//!
//! A config ([`RunConfig::parse`] or [`RunConfig::load`]) declares a task of your own as
//! `[task.external]`: its shape (P, N), the initial mean the search starts from, and its
//! settings with their initial values (README, "Your own simulator or robot").
//! [`InProcess::with_task`] runs that config with your [`tasks::Task`] doing the rollouts in this
//! thread, and [`InProcess::run`] reports each update to an [`Observer`]. The update side is
//! built from the config alone, so the same config and seed give the pipeline's result
//! (`supervisor run`, with your task in `pipeline::worker::serve`), bit for bit.
//!
//! A point that the policy moves from the origin to θ in N = 10 equal steps, with a target
//! that a `[[schedule]]` moves after 20 updates:
//!
//! ```
//! use session::{InProcess, Observer, RunConfig, UpdateRecord};
//! use tasks::{Task, TaskChange, TaskError};
//!
//! const CONFIG: &str = r#"
//! [run]
//! name = "point"
//! seed = 1
//! updates = 40
//!
//! [optimizer]
//! method = "pi2-cma"
//! rollouts = 10
//! evaluation_in_update = false
//! weighting = "per-time-step"
//! eliteness = 10.0
//! lambda_init = 0.1
//! lambda_min = 1e-4
//! lambda_max = 1.0
//!
//! [task.external]
//! worker = ["./point-worker"]  # what `supervisor run` would start; unused in-process
//! parameters = 2
//! steps = 10
//! initial_mean = [0.0, 0.0]
//! [task.external.settings]     # alphabetical, as Task::settings must list them
//! target_x = 0.5
//! target_y = 0.3
//!
//! [[schedule]]
//! from_update = 20
//! set = "target_x"
//! value = 0.2
//! "#;
//!
//! struct Point {
//!     target: [f64; 2],
//! }
//!
//! impl Task for Point {
//!     fn name(&self) -> &'static str {
//!         "point"
//!     }
//!     fn parameters(&self) -> usize {
//!         2
//!     }
//!     fn steps(&self) -> usize {
//!         10
//!     }
//!     fn initial_mean(&self) -> Vec<f64> {
//!         vec![0.0, 0.0]
//!     }
//!     fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
//!         // Each of the N = 10 steps moves θ/10: its cost is its squared length, weighted.
//!         let step = (theta[0].powi(2) + theta[1].powi(2)) / 100.0;
//!         per_step.fill(0.01 * step);
//!         // The terminal cost: where the point ended, against the target.
//!         let miss = (theta[0] - self.target[0]).powi(2) + (theta[1] - self.target[1]).powi(2);
//!         100.0 * miss
//!     }
//!     fn settings(&self) -> Vec<(&'static str, f64)> {
//!         vec![("target_x", self.target[0]), ("target_y", self.target[1])]
//!     }
//!     fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
//!         let i = match name {
//!             "target_x" => 0,
//!             "target_y" => 1,
//!             _ => {
//!                 return Err(TaskError::UnknownSetting {
//!                     task: "point",
//!                     name: name.into(),
//!                     known: "target_x, target_y".into(),
//!                 })
//!             }
//!         };
//!         self.target[i] = value;
//!         Ok(())
//!     }
//! }
//!
//! /// Keeps each update's evaluation cost (rollout 0: the mean, without noise).
//! #[derive(Default)]
//! struct Costs {
//!     evaluation: Vec<f64>,
//!     changes: Vec<(u64, TaskChange)>,
//! }
//!
//! impl Observer for Costs {
//!     fn on_update(&mut self, record: &UpdateRecord<'_>) {
//!         self.evaluation.push(record.summary.eval_cost);
//!     }
//!     fn on_task_change(&mut self, update: u64, change: &TaskChange) {
//!         self.changes.push((update, change.clone()));
//!     }
//! }
//!
//! let config = RunConfig::parse(CONFIG, "point.toml".as_ref())?;
//! // The task's own target is replaced by the config's before the first rollout.
//! let task = Box::new(Point { target: [f64::NAN; 2] });
//! let mut run = InProcess::with_task(&config, config.run.seed, task)?;
//! let mut costs = Costs::default();
//! run.run(&mut costs, &|| false)?;
//!
//! let e = &costs.evaluation;
//! assert_eq!(e.len(), 40);
//! // Update 0 evaluates the config's initial mean at the config's target: 100·(0.5² + 0.3²).
//! assert_eq!(e[0], 34.0);
//! // Learned in 20 updates; the schedule's change then costs 9.3, learned again by update 39.
//! assert!(e[19] < 0.01 && e[20] > 5.0 && e[39] < 0.01, "{e:?}");
//! assert_eq!(costs.changes.len(), 1);
//! assert_eq!((costs.changes[0].0, costs.changes[0].1.name.as_str()), (20, "target_x"));
//! let mean = &run.optimizer().distribution().mean;
//! assert!((mean[0] - 0.2).abs() < 0.01 && (mean[1] - 0.3).abs() < 0.01, "{mean}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

mod config;
pub mod reruns;
mod start;

pub use config::{
    executable_file, ConfigError, CovarianceName, ExternalConfig, MemoryNeed, MemoryPart, Method,
    OptimizerSection, PipelineSection, RecordingSection, RolloutAt, RunConfig, RunSection,
    ScheduleEntry, TaskSection, TemporalName, ViaPointConfig, WeightingName, DEFAULT_CONFIG,
    LAMBDA_RANGE, MAX_DMP_WORK, MAX_EXTERNAL_SETTINGS, MAX_NONFINITE_RERUNS, MAX_PARAMETERS,
    MAX_ROLLOUTS, MAX_STEPS, MEMORY_LIMIT_BYTES,
};

pub use start::{scheduled_at, Start, StartFileError};

use pi2cma::{
    CostBatch, CostError, Distribution, Optimizer, ParameterBatch, ParameterError, UpdateRule,
    UpdateSummary,
};
use tasks::{Delayed, Task, TaskChange, TaskError};

/// Why a session could not be built or stopped before its last update. A refused update leaves
/// the optimizer at that update ([`InProcess::optimizer`] has the distribution of the updates
/// before), so nothing already learned is lost.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SessionError {
    /// The core refused an update's costs: a NaN or ±∞ cost (naming rollout and step, or
    /// terminal) with `run.nonfinite_reruns = 0`, or finite costs whose update overflows f64.
    // The cost error is part of the message, not a source: chained, it would be printed twice
    // (`update 4: cost … is NaN: cost … is NaN`).
    #[error(
        "update {update}{}: {error}{}",
        ran_with_text(ran_with),
        reruns::without_reruns(error)
    )]
    Cost {
        /// The update (0-based) whose costs were refused.
        update: u64,
        /// What the core found.
        error: CostError,
        /// The task settings its rollouts ran with (none for a task without settings): a
        /// change that made the costs overflow shows in them, as in the pipeline's error.
        ran_with: Vec<(&'static str, f64)>,
    },
    /// A rollout whose costs were still not finite after `reruns` reruns
    /// (`run.nonfinite_reruns`).
    #[error(
        "update {update}{}: {error}{}",
        ran_with_text(ran_with),
        reruns::after_reruns(error, *reruns)
    )]
    CostAfterReruns {
        /// The update (0-based).
        update: u64,
        /// The last rerun's first non-finite cost.
        error: CostError,
        /// Reruns tried: `run.nonfinite_reruns`.
        reruns: u32,
        /// The task settings its rollouts ran with (none for a task without settings).
        ran_with: Vec<(&'static str, f64)>,
    },
    /// The task refused a setting (the config's initial values or a scheduled change), or the
    /// config's task could not be built.
    #[error(transparent)]
    Task(#[from] TaskError),
    /// The core refused the configured hyperparameters or the initial (or resumed)
    /// distribution.
    #[error(transparent)]
    Parameter(#[from] ParameterError),
    /// A resumed run's distribution has another number of parameters than the task.
    #[error("{origin}: its distribution has {dim} parameters, but the task has {task_dim}")]
    StartShape {
        /// Where the state came from ([`Start::origin`]).
        origin: String,
        /// Its distribution's number of parameters.
        dim: usize,
        /// The task's P.
        task_dim: usize,
    },
    /// A task of your own has another shape than its config declares ([`check_task_shape`]).
    #[error("{0}")]
    TaskShape(String),
    /// A task of your own refused a value its config gives it: an initial value of
    /// `[task.external.settings]` or a `[[schedule]]` change ([`InProcess::with_task`]).
    #[error("{origin}: {what} refused by the task: {error}")]
    SettingRefused {
        /// The config file.
        origin: String,
        /// Where in it: `task.external.settings` or `[[schedule]] from_update = U`.
        what: String,
        /// The task's refusal, naming the setting and value.
        error: TaskError,
    },
}

/// ` (ran with viapoint = 0.3)` after a cost error's update: the settings its rollouts ran
/// with, as the pipeline's error gives them; nothing for a task without settings.
fn ran_with_text(settings: &[(&'static str, f64)]) -> String {
    if settings.is_empty() {
        return String::new();
    }
    format!(
        " (ran with {})",
        tasks::settings_text(settings.iter().copied())
    )
}

/// Checks that a task of your own has the shape its config declares: P parameters, N steps, the
/// same setting names in the same order (alphabetical for `[task.external.settings]`, as the
/// wire carries them), and, where both have them, the same basis activations. The update side
/// is built from the config, so a task of another shape would be handed θ and settings it does
/// not read as meant. A pipeline worker of your own (`pipeline::worker::serve`) and
/// [`InProcess::with_task`] check it before their first rollout.
pub fn check_task_shape(task: &dyn Task, config: &RunConfig) -> Result<(), SessionError> {
    check_shape_against(task, config.build_task()?.as_ref(), config)
}

/// [`check_task_shape`] against the config's task `declared`, built once by a caller that
/// needs it too.
fn check_shape_against(
    task: &dyn Task,
    declared: &dyn Task,
    config: &RunConfig,
) -> Result<(), SessionError> {
    let field = |f: &str| match config.external_worker() {
        Some(_) => format!("task.external.{f}"),
        None => format!("the `{}` task's {f}", declared.name()),
    };
    let origin = config.origin.display();
    let refuse = |text: String| Err(SessionError::TaskShape(text));
    if task.parameters() != declared.parameters() {
        return refuse(format!(
            "task `{}` has {} parameters, but {} = {} in {origin}",
            task.name(),
            task.parameters(),
            field("parameters"),
            declared.parameters(),
        ));
    }
    if task.steps() != declared.steps() {
        return refuse(format!(
            "task `{}` has {} steps, but {} = {} in {origin}",
            task.name(),
            task.steps(),
            field("steps"),
            declared.steps(),
        ));
    }
    // The update weighs by the config's activations; a task whose policy has others would be
    // learning with a projection that is not its own.
    if let (Some(own), Some(declared_psi)) =
        (task.basis_activations(), declared.basis_activations())
    {
        if let Some(difference) = first_difference(&own, &declared_psi, declared.parameters()) {
            return refuse(format!(
                "task `{}` has other basis activations than {} in {origin} ({difference}): the \
                 update weighs the rollouts by the config's, so put the task's own there",
                task.name(),
                field("basis_activations"),
            ));
        }
    }
    let names = |t: &dyn Task| t.settings().iter().map(|(n, _)| *n).collect::<Vec<_>>();
    if names(task) != names(declared) {
        // A TOML table has no order a task could follow: the config's names are sorted.
        let order = match config.external_worker() {
            Some(_) => "same names, in alphabetical order",
            None => "same names, same order",
        };
        return refuse(format!(
            "task `{}` has the settings {:?}, but {} declares {:?} ({order}) in {origin}",
            task.name(),
            names(task),
            field("settings"),
            names(declared),
        ));
    }
    Ok(())
}

/// Where a task's own row-major basis activations `own` first differ from the config's
/// `declared` (N rows of P), bit for bit: the values at that step and parameter, or the lengths.
/// A message that only said they differ left a user to compare 400 numbers by eye.
fn first_difference(own: &[f64], declared: &[f64], p: usize) -> Option<String> {
    if own.len() != declared.len() {
        return Some(format!(
            "the task's are {} values, the config's {} rows of {p}",
            own.len(),
            declared.len() / p
        ));
    }
    let i = (0..own.len()).find(|&i| own[i].to_bits() != declared[i].to_bits())?;
    Some(format!(
        "at step {}, parameter {}: the task's {:?}, the config's {:?}",
        i / p,
        i % p,
        own[i],
        declared[i]
    ))
}

/// The task of a config, with its rollout delay if one is set, ready to run rollouts. An
/// external task (`[task.external]`) is refused: its rollouts run in the user's own workers,
/// started by `supervisor run`.
pub fn build_task(config: &RunConfig) -> Result<Box<dyn Task>, TaskError> {
    let task = build_task_without_delay(config)?;
    let delay = config.rollout_delay();
    Ok(if delay.is_zero() {
        task
    } else {
        Box::new(Delayed { inner: task, delay })
    })
}

/// [`build_task`] without the rollout delay: for what needs the task's costs, not its timing
/// (the re-convergence reference's thousands of rollouts).
pub fn build_task_without_delay(config: &RunConfig) -> Result<Box<dyn Task>, TaskError> {
    if let Some((program, _)) = config.external_worker() {
        return Err(TaskError::Invalid {
            task: "external",
            reason: format!(
                "{}: its rollouts run in its own workers (task.external.worker = {}), which only \
                 the pipeline starts: use `supervisor run {}`",
                config.origin.display(),
                program.display(),
                config.origin.display()
            ),
        });
    }
    config.build_task()
}

/// The optimizer of a config for session seed `seed`: Σ_init = λ_init·I around `task`'s initial
/// mean, with its basis activations. For a `[task.external]` config pass the declared task,
/// [`RunConfig::build_task`], as [`InProcess::with_task`] does: your own task's initial mean and
/// activations are not the config's, and would start another run.
///
/// To drive the core from a loop of your own (a robot's control loop) rather than through
/// [`InProcess`]: ask, run your task, tell. Set the config's values and the schedule's changes in
/// your task as an executor does ([`tasks::TaskSchedule::configure`]) and zero the step costs
/// before each rollout, and it is the in-process run (and the pipeline's), to the last bit of
/// the distribution:
///
/// ```
/// use session::{build_optimizer, InProcess, NoObserver, RunConfig};
/// use tasks::{Task, TaskError};
///
/// /// θ should reach `goal` in N = 5 steps; any goal is taken.
/// struct Line(f64);
/// impl Task for Line {
///     fn name(&self) -> &'static str { "line" }
///     fn parameters(&self) -> usize { 1 }
///     fn steps(&self) -> usize { 5 }
///     fn initial_mean(&self) -> Vec<f64> { vec![0.0] }
///     fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
///         per_step[4] = 0.01 * theta[0].powi(2); // effort, at the last step
///         (theta[0] - self.0).powi(2)
///     }
///     fn settings(&self) -> Vec<(&'static str, f64)> { vec![("goal", self.0)] }
///     fn set(&mut self, _: &str, value: f64) -> Result<(), TaskError> {
///         self.0 = value;
///         Ok(())
///     }
/// }
///
/// // The default config's [run] and [optimizer], for 10 updates (in 40 the runs from any
/// // initial mean end in the same bits: λ is at its bound and the mean near the goal).
/// let head = session::DEFAULT_CONFIG.split("[task.via-point]").next().unwrap();
/// let text = head.replace("updates = 40", "updates = 10")
///     + "[task.external]\nworker = [\"./line-worker\"]\nparameters = 1\nsteps = 5\n\
///        initial_mean = [0.5]\nsettings = { goal = 2.0 }\n\
///        [[schedule]]\nfrom_update = 5\nset = \"goal\"\nvalue = 3.0\n";
/// let config = RunConfig::parse(&text, "line.toml".as_ref())?;
///
/// let mut run = InProcess::with_task(&config, 7, Box::new(Line(0.0)))?;
/// run.run(&mut NoObserver, &|| false)?;
///
/// let mut optimizer = build_optimizer(&config, config.build_task()?.as_ref(), 7)?;
/// let (mut line, schedule) = (Line(0.0), config.schedule());
/// let initial = config.build_task()?.settings();
/// let mut per_step = vec![0.0; line.steps()];
/// while optimizer.update_index() < config.run.updates.unwrap() {
///     schedule.configure(&mut line, &initial, optimizer.update_index())?;
///     let batch = optimizer.ask().clone();
///     let mut costs = optimizer.cost_batch();
///     for k in 0..batch.rollouts {
///         per_step.fill(0.0);
///         let terminal = line.rollout(batch.row(k), &mut per_step);
///         costs.insert(k, &per_step, terminal)?;
///     }
///     optimizer.tell(&costs)?;
/// }
/// let (own, in_process) = (optimizer.distribution(), run.optimizer().distribution());
/// let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
/// assert_eq!(bits(own.mean.as_slice()), bits(in_process.mean.as_slice()));
/// assert_eq!(bits(own.covariance.as_slice()), bits(in_process.covariance.as_slice()));
/// assert!((own.mean[0] - 3.0).abs() < 0.2, "{}", own.mean);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn build_optimizer(
    config: &RunConfig,
    task: &dyn Task,
    seed: u64,
) -> Result<Optimizer, ParameterError> {
    let mean = nalgebra::DVector::from_vec(task.initial_mean());
    let initial = Distribution::isotropic(mean, config.optimizer.lambda_init)?;
    let activations = task.basis_activations();
    Optimizer::new(
        config.hyperparameters(),
        initial,
        task.steps(),
        seed,
        activations.as_deref(),
    )
}

/// The optimizer of a config for session seed `seed`, resumed at `start` (see [`Start`]) or, with
/// `None`, fresh as [`build_optimizer`] makes it.
pub fn build_optimizer_at(
    config: &RunConfig,
    task: &dyn Task,
    seed: u64,
    start: Option<&Start>,
) -> Result<Optimizer, SessionError> {
    let Some(start) = start else {
        return Ok(build_optimizer(config, task, seed)?);
    };
    let d = &start.distribution;
    if d.dim() != task.initial_mean().len() {
        return Err(SessionError::StartShape {
            origin: start.origin.clone(),
            dim: d.dim(),
            task_dim: task.initial_mean().len(),
        });
    }
    // Checks what a file could have damaged; keeps every bit.
    let d = Distribution::new(d.mean.clone(), d.covariance.clone())?;
    let activations = task.basis_activations();
    let rule = UpdateRule::new(
        config.hyperparameters(),
        d.dim(),
        task.steps(),
        activations.as_deref(),
    )?;
    Ok(Optimizer::resume(rule, d, seed, start.update))
}

/// Everything about one finished update, for observers.
pub struct UpdateRecord<'a> {
    /// The distribution the rollouts were sampled from.
    pub before: &'a Distribution,
    /// The distribution after the update: the next update samples from it.
    pub after: &'a Distribution,
    /// The K parameter vectors run (row 0: the mean, the noise-free evaluation).
    pub samples: &'a ParameterBatch,
    /// Their costs as the update took them: N per-step costs and a terminal cost per rollout
    /// (of the accepted execution, for a rollout that was rerun).
    pub costs: &'a CostBatch,
    /// What the core reports of the update: evaluation cost, λ before and after, probabilities.
    pub summary: &'a UpdateSummary,
    /// The task's settings during this update.
    pub task_settings: &'a [(&'static str, f64)],
    /// Wall-clock start and end of each rollout, in ns since the Unix epoch, in rollout order;
    /// empty unless an observer asked for them ([`Observer::wants_rollout_times`]).
    pub rollout_times: &'a [(u64, u64)],
}

/// Hooks called by an executor; the default implementations do nothing.
pub trait Observer {
    /// Whether [`UpdateRecord::rollout_times`] should be measured (two clock reads per rollout,
    /// which a fast in-process task notices; so only on request).
    fn wants_rollout_times(&self) -> bool {
        false
    }
    /// `task_settings`: the task's settings for the first update this run makes (for a resumed
    /// run, those in force where it resumed, not the config's initial ones).
    fn on_start(
        &mut self,
        _config: &RunConfig,
        _optimizer: &Optimizer,
        _task_settings: &[(&'static str, f64)],
    ) {
    }
    /// A scheduled change, set in the task just before update `update`'s rollouts (after
    /// [`Observer::on_start`] for a change due at the first update).
    fn on_task_change(&mut self, _update: u64, _change: &TaskChange) {}
    /// An execution of a rollout whose costs were not finite, which is run again
    /// (`run.nonfinite_reruns`); its costs are not in the update.
    fn on_rerun(&mut self, _rerun: &Rerun<'_>) {}
    /// An update was told and accepted: the optimizer is at the next update.
    fn on_update(&mut self, _record: &UpdateRecord<'_>) {}
    /// The run ended without error: its last update was made or `stop` returned true. Not
    /// called when [`InProcess::run`] fails.
    fn on_finish(&mut self, _optimizer: &Optimizer) {}
}

/// A rejected execution of a rollout that is run again ([`Observer::on_rerun`]).
pub struct Rerun<'a> {
    /// The update (0-based) whose rollout is run again.
    pub update: u64,
    /// The first non-finite cost of the execution ([`CostError::NonFinite`]: rollout, step or
    /// terminal, value).
    pub error: &'a CostError,
    /// The execution rejected: 1 for the first.
    pub attempt: u32,
    /// `run.nonfinite_reruns`.
    pub limit: u32,
}

/// Who ran a rollout of the in-process runner, in messages and recordings.
pub const IN_PROCESS: &str = "in-process";

impl Rerun<'_> {
    /// [`reruns::rerun_message`], by [`IN_PROCESS`].
    pub fn message(&self) -> String {
        reruns::rerun_message(
            self.update,
            self.error,
            self.attempt,
            self.limit,
            IN_PROCESS,
        )
    }
}

/// An observer that observes nothing.
pub struct NoObserver;
impl Observer for NoObserver {}

/// Fans every hook out to several observers.
pub struct Observers<'a>(pub Vec<&'a mut dyn Observer>);

impl Observer for Observers<'_> {
    fn wants_rollout_times(&self) -> bool {
        self.0.iter().any(|o| o.wants_rollout_times())
    }
    fn on_start(
        &mut self,
        config: &RunConfig,
        optimizer: &Optimizer,
        task_settings: &[(&'static str, f64)],
    ) {
        self.0
            .iter_mut()
            .for_each(|o| o.on_start(config, optimizer, task_settings));
    }
    fn on_task_change(&mut self, update: u64, change: &TaskChange) {
        self.0
            .iter_mut()
            .for_each(|o| o.on_task_change(update, change));
    }
    fn on_rerun(&mut self, rerun: &Rerun<'_>) {
        self.0.iter_mut().for_each(|o| o.on_rerun(rerun));
    }
    fn on_update(&mut self, record: &UpdateRecord<'_>) {
        self.0.iter_mut().for_each(|o| o.on_update(record));
    }
    fn on_finish(&mut self, optimizer: &Optimizer) {
        self.0.iter_mut().for_each(|o| o.on_finish(optimizer));
    }
}

/// The in-process executor: runs every rollout of an update in this thread, in rollout order.
pub struct InProcess {
    config: RunConfig,
    task: Box<dyn Task>,
    optimizer: Optimizer,
    initial_settings: Vec<(&'static str, f64)>,
    start: Option<Start>,
    costs: CostBatch,
    rollout_times: Vec<(u64, u64)>,
    reruns: reruns::NonfiniteReruns,
}

/// Wall-clock time in ns since the Unix epoch (0 before it).
fn wall_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

impl InProcess {
    /// A run of `config`'s built-in task (via-point, T-ball) from the start, with session seed
    /// `seed` (usually `config.run.seed`: the noise of every rollout is a function of it). An
    /// external task is refused ([`build_task`]): run it with [`InProcess::with_task`].
    pub fn new(config: &RunConfig, seed: u64) -> Result<Self, SessionError> {
        Self::new_at(config, seed, None, None)
    }

    /// A run resumed at `start` (e.g. the state a recording ended in): for the same config and
    /// seed it goes on exactly as the stopped run would have.
    pub fn resume(config: &RunConfig, seed: u64, start: Start) -> Result<Self, SessionError> {
        Self::new_at(config, seed, Some(start), None)
    }

    /// A run of `config` whose rollouts `task`, a task of your own, executes in this thread:
    /// the task a `[task.external]` config declares for the pipeline's workers, run without the
    /// pipeline. The update side is built from the config, as the pipeline's is: its
    /// `initial_mean`, its basis activations, and its setting values, which are set in `task`
    /// before the first update (then the schedule's changes at their updates). So for the same
    /// config and seed the run ends with the pipeline's result, bit for bit. `task` must have
    /// the declared shape ([`check_task_shape`]). Unlike a pipeline worker, a task that
    /// refuses a scheduled change fails the run: here, before the first update, as every
    /// setting value and scheduled change of the config is tried in `task` first
    /// ([`SessionError::SettingRefused`], naming the entry).
    pub fn with_task(
        config: &RunConfig,
        seed: u64,
        task: Box<dyn Task>,
    ) -> Result<Self, SessionError> {
        Self::new_at(config, seed, None, Some(task))
    }

    /// [`InProcess::with_task`] resumed at `start`, as [`InProcess::resume`].
    pub fn resume_with_task(
        config: &RunConfig,
        seed: u64,
        task: Box<dyn Task>,
        start: Start,
    ) -> Result<Self, SessionError> {
        Self::new_at(config, seed, Some(start), Some(task))
    }

    fn new_at(
        config: &RunConfig,
        seed: u64,
        start: Option<Start>,
        own: Option<Box<dyn Task>>,
    ) -> Result<Self, SessionError> {
        let (task, declared) = match own {
            None => (build_task(config)?, None),
            Some(mut task) => {
                let declared = config.build_task()?;
                check_shape_against(task.as_ref(), declared.as_ref(), config)?;
                if start.is_none() {
                    try_settings(task.as_mut(), &declared.settings(), config)?;
                }
                (task, Some(declared))
            }
        };
        // A task of your own may start from other values and another initial mean than the
        // config declares; the pipeline's update side knows only the config's.
        let shape = declared.as_deref().unwrap_or(task.as_ref());
        let optimizer = build_optimizer_at(config, shape, seed, start.as_ref())?;
        let initial_settings = shape.settings();
        let costs = optimizer.cost_batch();
        let reruns = reruns::NonfiniteReruns::new(config.run.nonfinite_reruns, costs.rollouts());
        Ok(Self {
            config: config.clone(),
            task,
            optimizer,
            initial_settings,
            start,
            costs,
            rollout_times: Vec::new(),
            reruns,
        })
    }

    /// The optimizer: its [`Optimizer::distribution`] is the run's current (after [`run`]:
    /// final) search distribution, [`Optimizer::update_index`] the next update.
    ///
    /// [`run`]: InProcess::run
    pub fn optimizer(&self) -> &Optimizer {
        &self.optimizer
    }

    /// Runs until the configured number of updates, or until `stop()` returns true (checked
    /// before every update; needed for unbounded runs).
    pub fn run(
        &mut self,
        observer: &mut dyn Observer,
        stop: &dyn Fn() -> bool,
    ) -> Result<(), SessionError> {
        let schedule = self.config.schedule();
        match &self.start {
            // Only where the resumed run begins; later calls find the task as the run left it.
            Some(start) if start.update == self.optimizer.update_index() => {
                start.configure(&schedule, self.task.as_mut(), &self.initial_settings)?
            }
            Some(_) => {}
            None => schedule.configure(
                self.task.as_mut(),
                &self.initial_settings,
                self.optimizer.update_index(),
            )?,
        }
        // The settings of the first update: the task's, with the changes due at it (applied in
        // the loop, after on_start, so that observers see the start before any change).
        // At a resumed run's first update, those its recording does not override (see
        // `Start::scheduled_at_start`).
        let mut first = self.task.settings();
        let first_update = self.optimizer.update_index();
        for change in scheduled_at(&schedule, self.start.as_ref(), first_update) {
            if let Some(s) = first.iter_mut().find(|(n, _)| *n == change.name) {
                s.1 = change.value;
            }
        }
        observer.on_start(&self.config, &self.optimizer, &first);
        while self
            .config
            .run
            .updates
            .is_none_or(|n| self.optimizer.update_index() < n)
            && !stop()
        {
            let u = self.optimizer.update_index();
            for change in scheduled_at(&schedule, self.start.as_ref(), u) {
                self.task
                    .set(&change.name, change.value)
                    .map_err(refused(&self.config, schedule_entry(change)))?;
                observer.on_task_change(u, change);
            }
            self.step(observer)?;
        }
        observer.on_finish(&self.optimizer);
        Ok(())
    }

    /// One update: ask, run the K rollouts (each one whose costs are not finite again, up to
    /// `run.nonfinite_reruns` times), tell.
    pub fn step(&mut self, observer: &mut dyn Observer) -> Result<UpdateSummary, SessionError> {
        let before = self.optimizer.distribution().clone();
        let samples = self.optimizer.ask().clone();
        let update = self.optimizer.update_index();
        self.costs.clear();
        self.reruns.clear();
        self.rollout_times.clear();
        let timed = observer.wants_rollout_times();
        for k in 0..samples.rollouts {
            let mut rerun = false;
            loop {
                let start = if timed { wall_ns() } else { 0 };
                let (per_step, terminal) = self.costs.slot_mut(k);
                // As a pipeline worker hands them (a fresh cost sample): a task that writes
                // only the steps that cost something, or adds to them, must not find the
                // previous update's (or attempt's) costs there, or it runs another run
                // in-process than in the pipeline.
                per_step.fill(0.0);
                *terminal = self.task.rollout(samples.row(k), per_step);
                if self.config.run.fault_nan(update, k, rerun) {
                    *terminal = f64::NAN;
                }
                // The accepted execution's interval, as the pipeline records it.
                let end = if timed { wall_ns() } else { 0 };
                // Without reruns the core's check in `tell` reports it, as it always has.
                let checked = match self.reruns.limit() {
                    0 => Ok(()),
                    _ => self.costs.check_rollout(k),
                };
                let Err(error) = checked else {
                    if timed {
                        self.rollout_times.push((start, end));
                    }
                    break;
                };
                match self.reruns.reject(k) {
                    reruns::Verdict::Rerun { attempt } => observer.on_rerun(&Rerun {
                        update,
                        error: &error,
                        attempt,
                        limit: self.reruns.limit(),
                    }),
                    reruns::Verdict::Fail { reruns } => {
                        return Err(SessionError::CostAfterReruns {
                            update,
                            error,
                            reruns,
                            ran_with: self.task.settings(),
                        })
                    }
                }
                rerun = true;
            }
        }
        let summary = self
            .optimizer
            .tell(&self.costs)
            .map_err(|error| SessionError::Cost {
                update,
                error,
                ran_with: self.task.settings(),
            })?;
        let settings = self.task.settings();
        observer.on_update(&UpdateRecord {
            before: &before,
            after: self.optimizer.distribution(),
            samples: &samples,
            costs: &self.costs,
            summary: &summary,
            task_settings: &settings,
            rollout_times: &self.rollout_times,
        });
        Ok(summary)
    }
}

/// Sets the config's setting values, then every scheduled change, in a task of your own, in the
/// order a run sets them, and leaves it at the config's values, where a run begins. Only the
/// task knows which values it can take (the config's checks cannot ask it), and a change
/// refused at its update would end an in-process run after all the rollouts before it.
fn try_settings(
    task: &mut dyn Task,
    initial: &[(&'static str, f64)],
    config: &RunConfig,
) -> Result<(), SessionError> {
    let set_initial = |task: &mut dyn Task| {
        initial.iter().try_for_each(|(name, value)| {
            task.set(name, *value)
                .map_err(refused(config, "task.external.settings".into()))
        })
    };
    set_initial(task)?;
    for change in config.schedule().changes() {
        task.set(&change.name, change.value)
            .map_err(refused(config, schedule_entry(change)))?;
    }
    // Not at the schedule's last change: an update stepped without `run` (which sets the
    // values again) ran with it.
    set_initial(task)
}

/// A change's place in its config, for [`SessionError::SettingRefused`].
fn schedule_entry(change: &TaskChange) -> String {
    format!("[[schedule]] from_update = {}", change.from_update)
}

/// [`SessionError::SettingRefused`] of `config`, at `what`.
fn refused(config: &RunConfig, what: String) -> impl FnOnce(TaskError) -> SessionError + '_ {
    move |error| SessionError::SettingRefused {
        origin: config.origin.display().to_string(),
        what,
        error,
    }
}

/// Runs one bounded session in-process and returns the per-update summaries.
pub fn run_session(
    config: &RunConfig,
    seed: u64,
    observer: &mut dyn Observer,
) -> Result<(Vec<UpdateSummary>, Distribution), SessionError> {
    struct Collect<'a> {
        inner: &'a mut dyn Observer,
        out: Vec<UpdateSummary>,
    }
    impl Observer for Collect<'_> {
        fn wants_rollout_times(&self) -> bool {
            self.inner.wants_rollout_times()
        }
        fn on_start(&mut self, c: &RunConfig, o: &Optimizer, s: &[(&'static str, f64)]) {
            self.inner.on_start(c, o, s)
        }
        fn on_task_change(&mut self, u: u64, c: &TaskChange) {
            self.inner.on_task_change(u, c)
        }
        fn on_rerun(&mut self, r: &Rerun<'_>) {
            self.inner.on_rerun(r)
        }
        fn on_update(&mut self, r: &UpdateRecord<'_>) {
            self.out.push(r.summary.clone());
            self.inner.on_update(r)
        }
        fn on_finish(&mut self, o: &Optimizer) {
            self.inner.on_finish(o)
        }
    }
    let mut exec = InProcess::new(config, seed)?;
    let mut collect = Collect {
        inner: observer,
        out: Vec::new(),
    };
    exec.run(&mut collect, &|| false)?;
    Ok((collect.out, exec.optimizer().distribution().clone()))
}

/// A final mean as the binaries print it at the end of a run (`pi2cma run`, the supervisor's
/// summary): whole up to 8 values (the via-point task's 2 as
/// `[-134.33814993070465, -681.537558832857]`), else the first 3 and the count; a mean of
/// P = 400 filled screens, and the recording and the supervisor's `--result` hold it whole.
pub fn mean_text(mean: &[f64]) -> String {
    const WHOLE: usize = 8;
    const SHOWN: usize = 3;
    if mean.len() <= WHOLE {
        return format!("{mean:?}");
    }
    let first: Vec<String> = mean[..SHOWN].iter().map(|v| format!("{v:?}")).collect();
    format!("[{}, …] ({} values)", first.join(", "), mean.len())
}

/// Mean and covariance as bits, for tests that compare distributions exactly.
#[cfg(test)]
pub(crate) fn bits(d: &Distribution) -> Vec<u64> {
    d.mean
        .iter()
        .chain(d.covariance.iter())
        .map(|v| v.to_bits())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_final_mean_is_abbreviated_and_a_short_one_shown_whole() {
        assert_eq!(
            mean_text(&[-134.33814993070465, -681.537558832857]),
            "[-134.33814993070465, -681.537558832857]"
        );
        assert_eq!(mean_text(&[1.0; 8]), format!("{:?}", [1.0; 8]));
        let long: Vec<f64> = (0..400).map(f64::from).collect();
        assert_eq!(mean_text(&long), "[0.0, 1.0, 2.0, …] (400 values)");
    }

    /// Printed with its whole chain, as the binaries print errors, the cost error appears once.
    #[test]
    fn a_cost_error_is_printed_once() {
        let e = SessionError::Cost {
            update: 4,
            error: CostError::NonFinite {
                rollout: 1,
                step: Some(0),
                value: f64::NAN,
            },
            ran_with: vec![("viapoint", 0.3)],
        };
        let mut chain = e.to_string();
        let mut source = std::error::Error::source(&e);
        while let Some(s) = source {
            chain.push_str(&format!(": {s}"));
            source = s.source();
        }
        assert_eq!(
            chain,
            format!(
                "update 4 (ran with viapoint = 0.3): cost of rollout 1 at step 0 is NaN; costs \
                 must be finite{}",
                reruns::without_reruns(&CostError::NonFinite {
                    rollout: 1,
                    step: Some(0),
                    value: f64::NAN,
                })
            )
        );
    }

    /// What an update produced: the distribution after it, and the settings it ran with.
    #[derive(Debug, Clone)]
    struct Step {
        after: Distribution,
        settings: Vec<(String, f64)>,
    }

    impl PartialEq for Step {
        /// Bit for bit.
        fn eq(&self, o: &Self) -> bool {
            bits(&self.after) == bits(&o.after) && self.settings == o.settings
        }
    }

    fn capture(mut exec: InProcess) -> Vec<Step> {
        struct Capture(Vec<Step>);
        impl Observer for Capture {
            fn on_update(&mut self, r: &UpdateRecord<'_>) {
                self.0.push(Step {
                    after: r.after.clone(),
                    settings: r
                        .task_settings
                        .iter()
                        .map(|(n, v)| (n.to_string(), *v))
                        .collect(),
                });
            }
        }
        let mut c = Capture(Vec::new());
        exec.run(&mut c, &|| false).unwrap();
        c.0
    }

    #[test]
    fn a_resumed_session_goes_on_bit_for_bit() {
        let cfg = RunConfig::default_config();
        let full = capture(InProcess::new(&cfg, 1).unwrap());
        assert_eq!(full.len(), 40);
        // 20: the schedule moves the via-point at the very update the run resumes at.
        for at in [20usize, 27] {
            let start = Start {
                update: at as u64,
                distribution: full[at - 1].after.clone(),
                settings: full[at - 1].settings.clone(),
                ran_with: Vec::new(),
                published: false,
                origin: "test".into(),
            };
            let resumed = capture(InProcess::resume(&cfg, 1, start).unwrap());
            assert_eq!(resumed, full[at..], "resumed at {at}");
        }
        // Settings the schedule does not know (a runtime change) are kept, not re-derived.
        let start = Start {
            update: 30,
            distribution: full[29].after.clone(),
            settings: vec![("viapoint".into(), 0.2)],
            ran_with: Vec::new(),
            published: false,
            origin: "test".into(),
        };
        let resumed = capture(InProcess::resume(&cfg, 1, start).unwrap());
        assert!(resumed
            .iter()
            .all(|s| s.settings == [("viapoint".to_string(), 0.2)]));
        assert_ne!(resumed, full[30..]);
        // A state of another shape is refused.
        let wrong = Start {
            update: 5,
            distribution: Distribution::isotropic(nalgebra::DVector::zeros(3), 1.0).unwrap(),
            settings: Vec::new(),
            ran_with: Vec::new(),
            published: false,
            origin: "test".into(),
        };
        let e = InProcess::resume(&cfg, 1, wrong).err().unwrap().to_string();
        assert_eq!(
            e,
            "test: its distribution has 3 parameters, but the task has 2"
        );
    }

    /// The default config's via-point task, declared as `[task.external]` and handed to
    /// `with_task` at another via-point: the config's setting and schedule are brought into it,
    /// and the run is the built-in one, bit for bit. A task of another shape is refused, naming
    /// the field; `InProcess::new` refuses the external config.
    #[test]
    fn a_task_of_your_own_runs_in_process_as_its_config_declares_it() {
        let builtin = RunConfig::default_config();
        let reference = capture(InProcess::new(&builtin, 1).unwrap());
        let own = || {
            let mut t = tasks::ViaPoint::new(&Default::default()).unwrap();
            t.set("viapoint", 0.9).unwrap();
            Box::new(t) as Box<dyn Task>
        };
        let external = |mean: &[f64]| external_via_point(mean, "own.toml");
        let mean = own().initial_mean();
        let cfg = external(&mean);
        assert_eq!(
            capture(InProcess::with_task(&cfg, 1, own()).unwrap()),
            reference
        );
        // Resumed (at the schedule's change and after it), from a task at another via-point.
        for at in [20usize, 27] {
            let start = Start {
                update: at as u64,
                distribution: reference[at - 1].after.clone(),
                settings: reference[at - 1].settings.clone(),
                ran_with: Vec::new(),
                published: false,
                origin: "test".into(),
            };
            let resumed = capture(InProcess::resume_with_task(&cfg, 1, own(), start).unwrap());
            assert_eq!(resumed, reference[at..], "resumed at {at}");
        }
        // The config's initial mean, not the task's: another one is another run.
        let other = capture(InProcess::with_task(&external(&[0.0, 0.0]), 1, own()).unwrap());
        assert_ne!(other[0].after.mean, reference[0].after.mean);

        let e = InProcess::with_task(&cfg, 1, Box::new(Target1D))
            .err()
            .unwrap()
            .to_string();
        assert_eq!(
            e,
            "task `target-1d` has 1 parameters, but task.external.parameters = 2 in own.toml"
        );
        let e = InProcess::new(&cfg, 1).err().unwrap().to_string();
        assert!(e.contains("only the pipeline starts"), "{e}");
    }

    /// A task that writes only the steps that cost something finds zeros in the others, as in
    /// a pipeline worker, not the costs of the update before.
    #[test]
    fn a_rollout_finds_its_step_costs_zeroed() {
        struct Sparse(std::sync::Arc<std::sync::Mutex<f64>>);
        impl Task for Sparse {
            fn name(&self) -> &'static str {
                "sparse"
            }
            fn parameters(&self) -> usize {
                1
            }
            fn steps(&self) -> usize {
                3
            }
            fn initial_mean(&self) -> Vec<f64> {
                vec![0.0]
            }
            fn rollout(&mut self, theta: &[f64], c: &mut [f64]) -> f64 {
                let found = c.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                let mut seen = self.0.lock().unwrap();
                *seen = seen.max(found);
                c[1] = (theta[0] - 1.0).powi(2);
                0.0
            }
            fn settings(&self) -> Vec<(&'static str, f64)> {
                Vec::new()
            }
            fn set(&mut self, _: &str, _: f64) -> Result<(), TaskError> {
                Ok(())
            }
        }
        let text = DEFAULT_CONFIG
            .split("[task.via-point]")
            .next()
            .unwrap()
            .to_string()
            + "[task.external]\nworker = [\"./worker\"]\nparameters = 1\nsteps = 3\n\
               initial_mean = [0.0]\n";
        let cfg = RunConfig::parse(&text, std::path::Path::new("sparse.toml")).unwrap();
        let seen = std::sync::Arc::new(std::sync::Mutex::new(0.0));
        let steps = capture(InProcess::with_task(&cfg, 1, Box::new(Sparse(seen.clone()))).unwrap());
        assert_eq!(steps.len(), 40);
        assert_eq!(*seen.lock().unwrap(), 0.0);
    }

    /// A task of your own that refuses a value of its config fails `with_task`, naming the
    /// entry, before a rollout: a scheduled change it refuses was found only at its update,
    /// after the rollouts of all the updates before (hours of them on a robot).
    #[test]
    fn a_value_your_task_refuses_fails_the_run_before_its_first_rollout() {
        let cfg = external_via_point(&[0.0, 0.0], "own.toml");
        let rollouts = std::rc::Rc::new(std::cell::Cell::new(0));
        let run = |lowest: f64| {
            let count = rollouts.clone();
            let task = Box::new(Hooked {
                inner: Box::new(tasks::ViaPoint::new(&Default::default()).unwrap()),
                name: "guarded",
                rollout: move |_: &[f64], _: &mut [f64], terminal| {
                    count.set(count.get() + 1);
                    terminal
                },
                set: move |name: &str, value| match value < lowest {
                    true => Err(TaskError::InvalidSetting {
                        task: "guarded",
                        name: name.into(),
                        value,
                        reason: "too low",
                    }),
                    false => Ok(()),
                },
            });
            InProcess::with_task(&cfg, 1, task).and_then(|mut r| r.run(&mut NoObserver, &|| false))
        };
        // The schedule moves the via-point from 0.3 to 0.1 at update 20.
        assert_eq!(
            run(0.2).unwrap_err().to_string(),
            "own.toml: [[schedule]] from_update = 20 refused by the task: task `guarded`: \
             viapoint = 0.1: too low"
        );
        assert_eq!(
            run(0.5).unwrap_err().to_string(),
            "own.toml: task.external.settings refused by the task: task `guarded`: \
             viapoint = 0.3: too low"
        );
        assert_eq!(rollouts.get(), 0);
        run(0.0).unwrap();
        assert_eq!(rollouts.get(), 40 * 15);
    }

    /// Trying the config's values leaves a task of your own at them, as a run begins, not at the
    /// schedule's last change: an update stepped without `run` ([`InProcess::step`]) ran with
    /// the via-point at 0.1, the change due from update 20.
    #[test]
    fn trying_the_settings_leaves_your_task_at_the_configs_values() {
        let cfg = external_via_point(&[0.0, 0.0], "own.toml");
        let task = Box::new(tasks::ViaPoint::new(&Default::default()).unwrap());
        let exec = InProcess::with_task(&cfg, 1, task).unwrap();
        assert_eq!(exec.task.settings(), [("viapoint", 0.3)]);
    }

    /// The default config with its via-point task declared as `[task.external]`, starting from
    /// `mean`.
    fn external_via_point(mean: &[f64], origin: &str) -> RunConfig {
        RunConfig::parse(&external_via_point_text(mean), std::path::Path::new(origin)).unwrap()
    }

    /// The text of [`external_via_point`]'s config.
    fn external_via_point_text(mean: &[f64]) -> String {
        let builtin_section = DEFAULT_CONFIG
            .split("[task.via-point]")
            .nth(1)
            .and_then(|rest| rest.split("\n\n").next())
            .unwrap();
        let section = format!(
            "[task.external]\nworker = [\"./worker\"]\nparameters = 2\nsteps = 101\n\
             initial_mean = {mean:?}\n[task.external.settings]\nviapoint = 0.3\n"
        );
        DEFAULT_CONFIG.replace(&format!("[task.via-point]{builtin_section}"), &section)
    }

    /// An external task's settings come in alphabetical order, and the refusal of a task that
    /// declares them in another says so (a user cannot see the order in the TOML table).
    #[test]
    fn a_task_with_its_settings_in_another_order_is_told_they_are_alphabetical() {
        struct Reach;
        impl Task for Reach {
            fn name(&self) -> &'static str {
                "reach"
            }
            fn parameters(&self) -> usize {
                1
            }
            fn steps(&self) -> usize {
                3
            }
            fn initial_mean(&self) -> Vec<f64> {
                vec![0.0]
            }
            fn rollout(&mut self, _: &[f64], _: &mut [f64]) -> f64 {
                0.0
            }
            fn settings(&self) -> Vec<(&'static str, f64)> {
                vec![("goal_y", 0.0), ("goal_x", 1.0)]
            }
            fn set(&mut self, _: &str, _: f64) -> Result<(), TaskError> {
                Ok(())
            }
        }
        let text = DEFAULT_CONFIG
            .split("[task.via-point]")
            .next()
            .unwrap()
            .to_string()
            + "[task.external]\nworker = [\"./worker\"]\nparameters = 1\nsteps = 3\n\
               initial_mean = [0.0]\nsettings = { goal_y = 0.0, goal_x = 1.0 }\n";
        let cfg = RunConfig::parse(&text, std::path::Path::new("reach.toml")).unwrap();
        let e = check_task_shape(&Reach, &cfg).unwrap_err().to_string();
        assert_eq!(
            e,
            "task `reach` has the settings [\"goal_y\", \"goal_x\"], but task.external.settings \
             declares [\"goal_x\", \"goal_y\"] (same names, in alphabetical order) in reach.toml"
        );
    }

    struct Target1D;
    impl Task for Target1D {
        fn name(&self) -> &'static str {
            "target-1d"
        }
        fn parameters(&self) -> usize {
            1
        }
        fn steps(&self) -> usize {
            101
        }
        fn initial_mean(&self) -> Vec<f64> {
            vec![0.0]
        }
        fn rollout(&mut self, _: &[f64], c: &mut [f64]) -> f64 {
            c.fill(0.0);
            0.0
        }
        fn settings(&self) -> Vec<(&'static str, f64)> {
            vec![("viapoint", 0.0)]
        }
        fn set(&mut self, _: &str, _: f64) -> Result<(), TaskError> {
            Ok(())
        }
    }

    /// A task whose own basis activations differ from its config's is told where: the first
    /// step and parameter that differ, with both values, or both shapes.
    #[test]
    fn other_basis_activations_are_refused_naming_the_first_difference() {
        /// The via-point task (P = 2, N = 101) with the activations `psi`.
        struct Psi(tasks::ViaPoint, Vec<f64>);
        impl Task for Psi {
            fn name(&self) -> &'static str {
                "psi"
            }
            fn parameters(&self) -> usize {
                self.0.parameters()
            }
            fn steps(&self) -> usize {
                self.0.steps()
            }
            fn initial_mean(&self) -> Vec<f64> {
                self.0.initial_mean()
            }
            fn basis_activations(&self) -> Option<Vec<f64>> {
                Some(self.1.clone())
            }
            fn rollout(&mut self, theta: &[f64], c: &mut [f64]) -> f64 {
                self.0.rollout(theta, c)
            }
            fn settings(&self) -> Vec<(&'static str, f64)> {
                self.0.settings()
            }
            fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
                self.0.set(name, value)
            }
        }
        let rows: Vec<String> = (0..101).map(|i| format!("[{i}.0, 0.5]")).collect();
        let psi: Vec<f64> = (0..101).flat_map(|i| [i as f64, 0.5]).collect();
        let text = external_via_point_text(&[0.0, 0.0]).replace(
            "[task.external.settings]",
            &format!(
                "basis_activations = [{}]\n[task.external.settings]",
                rows.join(", ")
            ),
        );
        let cfg = RunConfig::parse(&text, std::path::Path::new("psi.toml")).unwrap();
        let task = |psi: Vec<f64>| Psi(tasks::ViaPoint::new(&Default::default()).unwrap(), psi);
        check_task_shape(&task(psi.clone()), &cfg).unwrap();
        let mut other = psi.clone();
        other[2 * 7 + 1] = 0.25;
        assert_eq!(
            check_task_shape(&task(other), &cfg)
                .unwrap_err()
                .to_string(),
            "task `psi` has other basis activations than task.external.basis_activations in \
             psi.toml (at step 7, parameter 1: the task's 0.25, the config's 0.5): the update \
             weighs the rollouts by the config's, so put the task's own there"
        );
        assert!(check_task_shape(&task(psi[..200].to_vec()), &cfg)
            .unwrap_err()
            .to_string()
            .contains("(the task's are 200 values, the config's 101 rows of 2)"));
    }

    /// A task of your own that misbehaves in one way: `inner` with a hook after each rollout
    /// (given θ, the step costs and the terminal cost; returning the terminal cost) and one
    /// before each set (whose refusal is the task's).
    struct Hooked<R, S> {
        inner: Box<dyn Task>,
        name: &'static str,
        rollout: R,
        set: S,
    }
    impl<R, S> Task for Hooked<R, S>
    where
        R: FnMut(&[f64], &mut [f64], f64) -> f64,
        S: FnMut(&str, f64) -> Result<(), TaskError>,
    {
        fn name(&self) -> &'static str {
            self.name
        }
        fn parameters(&self) -> usize {
            self.inner.parameters()
        }
        fn steps(&self) -> usize {
            self.inner.steps()
        }
        fn initial_mean(&self) -> Vec<f64> {
            self.inner.initial_mean()
        }
        fn rollout(&mut self, theta: &[f64], c: &mut [f64]) -> f64 {
            let terminal = self.inner.rollout(theta, c);
            (self.rollout)(theta, c, terminal)
        }
        fn settings(&self) -> Vec<(&'static str, f64)> {
            self.inner.settings()
        }
        fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
            (self.set)(name, value)?;
            self.inner.set(name, value)
        }
    }

    /// The default config with `lines` added to its `[run]` table.
    fn default_with_run(lines: &str) -> RunConfig {
        let text = DEFAULT_CONFIG.replace("seed = 1\n", &format!("seed = 1\n{lines}\n"));
        RunConfig::parse(&text, std::path::Path::new("reruns.toml")).unwrap()
    }

    /// The messages of the reruns an observer was told of.
    #[derive(Default)]
    struct Reruns(Vec<String>);
    impl Observer for Reruns {
        fn on_rerun(&mut self, r: &Rerun<'_>) {
            self.0.push(r.message());
        }
    }

    #[test]
    fn a_transient_non_finite_cost_is_rerun_and_the_run_is_the_one_without_it() {
        let reference = capture(InProcess::new(&RunConfig::default_config(), 1).unwrap());
        let cfg = default_with_run(
            "nonfinite_reruns = 2\nfault_nan_first_attempt = { update = 3, rollout = 7 }",
        );
        let mut told = Reruns::default();
        let mut exec = InProcess::new(&cfg, 1).unwrap();
        exec.run(&mut told, &|| false).unwrap();
        assert_eq!(
            told.0,
            ["update 3: cost of rollout 7 (terminal) is NaN; costs must be finite (attempt 1 of \
              at most 3, by in-process): rerunning it with the same parameters \
              (run.nonfinite_reruns = 2)"]
        );
        assert_eq!(capture(InProcess::new(&cfg, 1).unwrap()), reference);

        // Without reruns the same fault fails the run as a non-finite cost always has.
        let cfg = default_with_run("fault_nan_first_attempt = { update = 3, rollout = 7 }");
        let mut told = Reruns::default();
        let e = InProcess::new(&cfg, 1)
            .unwrap()
            .run(&mut told, &|| false)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "update 3 (ran with viapoint = 0.3): cost of rollout 7 (terminal) is NaN; costs \
             must be finite (if the task gives such costs now and then, `run.nonfinite_reruns = N` runs such a rollout again, \
             up to N times, with the same parameters)"
        );
        assert!(told.0.is_empty());
    }

    /// `fault_nan_first_attempt` without `rollout` faults every rollout of its update, and
    /// without `update` every rollout of every update; reruns leave the run the one without.
    #[test]
    fn a_fault_of_every_rollout_is_rerun_every_time_and_changes_nothing() {
        let reference = capture(InProcess::new(&RunConfig::default_config(), 1).unwrap());
        for (fault, reruns) in [("{ update = 3 }", 15), ("{}", 15 * 40)] {
            let cfg = default_with_run(&format!(
                "nonfinite_reruns = 1\nfault_nan_first_attempt = {fault}"
            ));
            let mut told = Reruns::default();
            InProcess::new(&cfg, 1)
                .unwrap()
                .run(&mut told, &|| false)
                .unwrap();
            assert_eq!(told.0.len(), reruns, "{fault}");
            assert_eq!(
                capture(InProcess::new(&cfg, 1).unwrap()),
                reference,
                "{fault}"
            );
        }
    }

    #[test]
    fn a_cost_that_stays_non_finite_fails_the_run_after_the_reruns_saying_so() {
        let cfg = default_with_run("nonfinite_reruns = 2");
        // The via-point task whose rollouts of a negative first parameter cost +∞ at step 4.
        let task = Box::new(Hooked {
            inner: build_task(&cfg).unwrap(),
            name: "diverges",
            rollout: |theta: &[f64], c: &mut [f64], terminal| {
                if theta[0] < 0.0 {
                    c[4] = f64::INFINITY;
                }
                terminal
            },
            set: |_: &str, _| Ok(()),
        });
        let mut told = Reruns::default();
        let e = InProcess::with_task(&cfg, 1, task)
            .unwrap()
            .run(&mut told, &|| false)
            .unwrap_err();
        let SessionError::CostAfterReruns { update, error, .. } = &e else {
            panic!("{e}");
        };
        let CostError::NonFinite { rollout, .. } = error else {
            panic!("{e}");
        };
        assert_eq!(
            e.to_string(),
            format!(
                "update {update} (ran with viapoint = {}): cost of rollout {rollout} at step 4 is \
                 inf; costs must be finite, still after 2 reruns with the same parameters \
                 (run.nonfinite_reruns = 2)",
                if *update < 20 { "0.3" } else { "0.1" }
            )
        );
        let attempts: Vec<&str> = told
            .0
            .iter()
            .map(|m| {
                m.split(" (attempt ")
                    .nth(1)
                    .unwrap()
                    .split(',')
                    .next()
                    .unwrap()
            })
            .collect();
        assert_eq!(
            attempts,
            ["1 of at most 3", "2 of at most 3"],
            "{:?}",
            told.0
        );
    }

    #[test]
    fn default_session_learns_and_is_reproducible() {
        let cfg = RunConfig::default_config();
        let (a, da) = run_session(&cfg, 1, &mut NoObserver).unwrap();
        let (b, db) = run_session(&cfg, 1, &mut NoObserver).unwrap();
        assert_eq!(a.len(), 40);
        assert_eq!(da, db);
        assert_eq!(a, b);
        assert!(
            a[19].eval_cost < 0.2 * a[0].eval_cost,
            "{} → {}",
            a[0].eval_cost,
            a[19].eval_cost
        );
    }
}
