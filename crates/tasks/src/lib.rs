//! Tasks: a policy plus a cost function, behind the [`Task`] trait, and the paper's via-point task.
//!
//! A task turns a parameter vector θ into a cost trajectory (N immediate costs and a terminal
//! cost). Tasks have named settings (the via-point's `viapoint`, the T-ball's ball height) that a
//! [`TaskSchedule`] or a user changes while learning runs. This crate knows nothing of the update
//! rule or of how rollouts are distributed; the T-ball task and users' own tasks implement the
//! same trait.
//!
//! # Your own simulator or robot as a [`Task`]
//!
//! Implement the eight methods of [`Task`] (one, [`Task::basis_activations`], has a default):
//!
//! - the shape: [`Task::parameters`] P (the length of θ), [`Task::steps`] N (the length of a cost
//!   trajectory; 1 for a task that only knows a total cost), and [`Task::initial_mean`];
//! - [`Task::rollout`]: execute θ, write the N immediate costs into `per_step` (zeroed when it
//!   comes) and return the terminal cost. Put a cost at the step where it arises (effort at
//!   every step, a via-point miss at the via-point's step): with per-time-step weighting, the
//!   paper's Algorithm 1, the update at step i weighs the rollouts by their cost-to-go from i,
//!   the terminal cost plus the immediate costs of steps i…N−1. What only the end state tells
//!   (a distance to the goal, a ball's landing point) is the terminal cost. Only costs
//!   relative to each other matter (PI² normalises each step's costs by their range), but they
//!   must be finite: a NaN or ±∞ fails the update (or reruns the rollout, with
//!   `run.nonfinite_reruns`);
//! - the settings, the task's parameters a run may change while it learns (a target, a mass):
//!   [`Task::settings`] lists their current values by name, and [`Task::set`] changes one, or
//!   refuses the value with a [`TaskError`] and leaves the task as it was. An executor calls
//!   `set` between rollouts, never during one: with the config's values before the first, then
//!   with a [`TaskSchedule`]'s or an operator's changes from the update they are due at.
//!
//! Then run it in a process of your own with `pipeline::worker::serve` (README, "Your own
//! simulator or robot"; `crates/supervisor/examples/reach-worker.rs` is a complete worker), or
//! in this thread with `session::InProcess::with_task`. In both the config declares the
//! task's shape (`[task.external]`), and the run starts from the config's `initial_mean` and
//! setting values, not from those your task starts with.
//!
//! A slider that a DMP moves from 0 to 1 m in 1 s and that should stop at `target`:
//!
//! ```
//! use dmp::{AffineDmp, Dmp, Gains, Trajectory};
//! use tasks::{check_initial_rollout, Task, TaskChange, TaskError, TaskSchedule};
//!
//! struct Slider {
//!     dmp: AffineDmp,
//!     mean: Vec<f64>,
//!     motion: Trajectory,
//!     target: f64,
//! }
//!
//! impl Slider {
//!     fn new() -> Result<Self, dmp::DmpError> {
//!         let dmp = Dmp::new(vec![0.0], vec![1.0], 4, 1.0, 0.01, Gains::default())?;
//!         Ok(Self {
//!             mean: dmp.fit_min_jerk(1.0),
//!             motion: Trajectory::zeros(dmp.steps(), 1, dmp.dt()),
//!             dmp: dmp.affine(),
//!             target: 1.0,
//!         })
//!     }
//! }
//!
//! impl Task for Slider {
//!     fn name(&self) -> &'static str {
//!         "slider"
//!     }
//!     fn parameters(&self) -> usize {
//!         self.dmp.parameters() // P = 4
//!     }
//!     fn steps(&self) -> usize {
//!         self.dmp.steps() // N = 101
//!     }
//!     fn initial_mean(&self) -> Vec<f64> {
//!         self.mean.clone()
//!     }
//!     fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
//!         // Your simulator or robot goes here; this slider follows the DMP exactly.
//!         self.dmp.rollout_into(theta, &mut self.motion);
//!         let n = per_step.len();
//!         for (cost, acc) in per_step.iter_mut().zip(&self.motion.acc) {
//!             *cost = acc * acc / n as f64; // effort, at the step it is spent
//!         }
//!         1e3 * (self.motion.pos[n - 1] - self.target).powi(2) // where it stopped
//!     }
//!     fn settings(&self) -> Vec<(&'static str, f64)> {
//!         vec![("target", self.target)]
//!     }
//!     fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
//!         match name {
//!             "target" if (0.0..=2.0).contains(&value) => {
//!                 self.target = value;
//!                 Ok(())
//!             }
//!             "target" => Err(TaskError::InvalidSetting {
//!                 task: "slider",
//!                 name: name.into(),
//!                 value,
//!                 reason: "the rail is 2 m long",
//!             }),
//!             _ => Err(TaskError::UnknownSetting {
//!                 task: "slider",
//!                 name: name.into(),
//!                 known: "target".into(),
//!             }),
//!         }
//!     }
//! }
//!
//! let mut slider = Slider::new()?;
//! // What a config's checks ask of a built-in task, worth a test of your own: the initial
//! // mean's costs are finite, and every scheduled change is one the task takes.
//! check_initial_rollout(&mut slider)?;
//! let change = |name: &str| TaskChange { from_update: 20, name: name.into(), value: 1.2 };
//! let schedule = TaskSchedule::new(vec![change("target")]);
//! schedule.validate(&mut slider)?;
//! let typo = TaskSchedule::new(vec![change("traget")]).validate(&mut slider);
//! assert_eq!(
//!     typo.unwrap_err().to_string(),
//!     "task `slider` has no setting `traget` (it has: target)"
//! );
//! // A refused value leaves the task as it was.
//! assert!(slider.set("target", 3.0).is_err());
//! assert_eq!(slider.settings(), [("target", 1.0)]);
//!
//! // The state of any update, as an executor brings a task to it: the target moves at 20.
//! let (initial, theta) = (slider.settings(), slider.initial_mean());
//! let mut per_step = vec![0.0; slider.steps()];
//! schedule.configure(&mut slider, &initial, 19)?;
//! let terminal_19 = slider.rollout(&theta, &mut per_step);
//! per_step.fill(0.0);
//! schedule.configure(&mut slider, &initial, 20)?;
//! let terminal_20 = slider.rollout(&theta, &mut per_step);
//! // The minimum-jerk mean stops 5 mm past 1 m: a miss that costs 0.024 up to update 19,
//! // and 38 from update 20 on, when it is 0.195 m.
//! assert!(terminal_19 < 0.1 && terminal_20 > 30.0, "{terminal_19} {terminal_20}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

use std::time::Duration;

mod external;
pub use external::External;

use dmp::{AffineDmp, Dmp, Gains};
use thiserror::Error;

/// A setting's value as messages show it: as written for everyday numbers, in exponent form
/// outside 1e-4..1e16, where `f64`'s `Display` writes up to 300 digits (`1e300`).
pub fn value_text(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e16).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}

/// Sets every one of `settings`, whose values together are a state the task was in (the
/// settings a run is at, a recording's), in rounds: those refused are tried again after a round
/// that took any. A task may judge one setting with another as it is (T-ball's tee must be in
/// the bat's reach with both of its coordinates), so a state reached one change at a time may be
/// refused half-way when set in another order. Fails with the first refusal of a round that took
/// none.
pub fn set_all<N: AsRef<str>>(task: &mut dyn Task, settings: &[(N, f64)]) -> Result<(), TaskError> {
    match set_in_rounds(task, settings).into_iter().next() {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}

/// Those of `changes` (in the order they were given) that no later change of the same setting
/// replaces: of two changes of a setting due at one update, the later is the one in force.
pub fn not_replaced<C: std::borrow::Borrow<TaskChange>>(changes: &[C]) -> impl Iterator<Item = &C> {
    changes.iter().enumerate().filter_map(move |(i, c)| {
        let name = &c.borrow().name;
        let replaced = changes[i + 1..].iter().any(|d| &d.borrow().name == name);
        (!replaced).then_some(c)
    })
}

/// [`set_all`]'s rounds, returning what is still refused after a round that took none: the
/// index of each such setting in `settings`, with its refusal (empty when all were taken). A
/// pipeline worker takes an update's changes so and keeps the refused ones' earlier values.
pub fn set_in_rounds<N: AsRef<str>>(
    task: &mut dyn Task,
    settings: &[(N, f64)],
) -> Vec<(usize, TaskError)> {
    let mut which: Vec<usize> = (0..settings.len()).collect();
    loop {
        let tried = which.len();
        let mut refused = Vec::new();
        for i in which {
            let (name, value) = &settings[i];
            if let Err(e) = task.set(name.as_ref(), *value) {
                refused.push((i, e));
            }
        }
        if refused.is_empty() || refused.len() == tried {
            return refused;
        }
        which = refused.into_iter().map(|(i, _)| i).collect();
    }
}

/// Settings as messages list them: `viapoint = 0.3, goal = 1` ([`value_text`] values).
pub fn settings_text<N: std::fmt::Display>(settings: impl IntoIterator<Item = (N, f64)>) -> String {
    let list: Vec<String> = settings
        .into_iter()
        .map(|(name, v)| format!("{name} = {}", value_text(v)))
        .collect();
    list.join(", ")
}

/// Why a task refused a setting or could not be built. `task` is always [`Task::name`]; a task
/// of your own returns these from [`Task::set`] (and may from its constructor).
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum TaskError {
    /// [`Task::set`] was given a name the task does not have.
    #[error("task `{task}` has no setting `{name}` (it has: {known})")]
    UnknownSetting {
        /// The task's name.
        task: &'static str,
        /// The name asked for.
        name: String,
        /// The task's setting names, comma-separated (`none` for a task without settings).
        known: String,
    },
    /// A value of a known setting that the task cannot run with; the task is unchanged.
    #[error("task `{task}`: {name} = {}: {reason}", value_text(*.value))]
    InvalidSetting {
        /// The task's name.
        task: &'static str,
        /// The setting.
        name: String,
        /// The value refused.
        value: f64,
        /// What the value must be.
        reason: &'static str,
    },
    /// A specification or state the task cannot run with, explained whole in `reason`: a DMP
    /// that cannot be built, an external task's declared shape, settings under which the
    /// initial mean's costs are not finite ([`check_initial_rollout`]).
    #[error("task `{task}`: {reason}")]
    Invalid {
        /// The task's name.
        task: &'static str,
        /// What is wrong, naming the values.
        reason: String,
    },
}

/// A policy with its cost function.
///
/// Not `Send`: a pipeline worker (`pipeline::worker::serve`) and the in-process runner
/// (`session::InProcess`) keep their task on the thread that built it, so a task may hold
/// what must stay there (an `Rc`, a robot driver's handle). Code that moves a task to another
/// thread asks for `Task + Send` itself.
///
/// How to implement it for a simulator or robot of your own, with an example: the
/// [crate documentation](crate).
pub trait Task {
    /// The task's name in messages and errors (``task `via-point`: …``), e.g. `"reach"`.
    fn name(&self) -> &'static str;
    /// P: the length of θ. Constant for the task's life; a run of a task of your own checks it
    /// against its config's `parameters`.
    fn parameters(&self) -> usize;
    /// N: the length of a cost trajectory, i.e. of `per_step` in [`Task::rollout`]; 1 for a
    /// task that only knows a total cost (returned as the terminal cost). Constant, and checked
    /// like P.
    fn steps(&self) -> usize;
    /// The initial mean of the search distribution (e.g. a DMP fitted to a minimum-jerk movement),
    /// P finite values. A `[task.external]` run starts from the config's `initial_mean` instead:
    /// copy these values there.
    fn initial_mean(&self) -> Vec<f64>;
    /// Row-major N × P basis activations, for the original PI²'s per-parameter temporal weights.
    /// Only `optimizer.temporal_averaging = "basis-activation"` uses them; `None` (the default)
    /// otherwise. A `[task.external]` run takes them from the config's `basis_activations`,
    /// and refuses a task whose own differ.
    fn basis_activations(&self) -> Option<Vec<f64>> {
        None
    }
    /// Executes θ: writes the N immediate costs into `per_step`, which comes zeroed (in every
    /// executor), and returns the terminal cost.
    ///
    /// Every cost must be finite. A cost of a step belongs at that step (the per-time-step
    /// update weighs step i by the cost-to-go from i); what only the end state tells is the
    /// terminal cost. With the same θ and settings, a deterministic task (a simulator) gives the
    /// same costs in any worker, which is what makes a run's result the same bits however
    /// many workers ran it.
    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64;
    /// Current values of the settings a task change may set, by name, in a fixed order: a run
    /// checks the names against its config, and a `[task.external]` config lists them in
    /// alphabetical order. Empty for a task without settings.
    fn settings(&self) -> Vec<(&'static str, f64)>;
    /// Sets one setting. A value refused (an error) must leave the task as it was: a pipeline
    /// worker tries an update's changes together, and tries a refused one again once the others
    /// are in (see `pipeline::worker`).
    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError>;
}

impl<T: Task + ?Sized> Task for Box<T> {
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn parameters(&self) -> usize {
        (**self).parameters()
    }
    fn steps(&self) -> usize {
        (**self).steps()
    }
    fn initial_mean(&self) -> Vec<f64> {
        (**self).initial_mean()
    }
    fn basis_activations(&self) -> Option<Vec<f64>> {
        (**self).basis_activations()
    }
    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
        (**self).rollout(theta, per_step)
    }
    fn settings(&self) -> Vec<(&'static str, f64)> {
        (**self).settings()
    }
    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        (**self).set(name, value)
    }
}

/// Runs the initial mean once and fails if a cost is not finite: settings under which even it
/// costs NaN or ±inf (a T-ball miss weighted 10³⁰⁸ per m of gap, a via-point whose distance
/// times its weight overflows) would fail every update, so they are refused where they are given
/// (a config, a schedule entry, a runtime change) rather than by the update that first meets
/// them. Not for a task whose rollouts run elsewhere ([`External`]).
pub fn check_initial_rollout(task: &mut dyn Task) -> Result<(), TaskError> {
    let mut per_step = vec![0.0; task.steps()];
    let terminal = task.rollout(&task.initial_mean(), &mut per_step);
    let bad = match per_step.iter().position(|c| !c.is_finite()) {
        _ if !terminal.is_finite() => Some(("the terminal cost".to_string(), terminal)),
        Some(i) => Some((format!("the cost of step {i}"), per_step[i])),
        None => None,
    };
    match bad {
        None => Ok(()),
        Some((what, value)) => Err(TaskError::Invalid {
            task: task.name(),
            reason: format!(
                "with these settings a rollout of the initial mean gives {what} = {value}: \
                 costs must be finite, so every update would fail"
            ),
        }),
    }
}

/// Sets a task's setting `name` from `update` on (0-based: `from_update = 20` leaves updates
/// 0–19 unchanged, "after 20 updates").
#[derive(Debug, Clone, PartialEq)]
pub struct TaskChange {
    /// The first update (0-based) that runs with `value`.
    pub from_update: u64,
    /// The setting, as [`Task::settings`] names it.
    pub name: String,
    /// The new value, in the setting's own units.
    pub value: f64,
}

/// The task changes of a run, kept sorted by update so any executor — or a worker that joins
/// mid-run — can bring a task to the state of any update.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TaskSchedule {
    changes: Vec<TaskChange>,
}

impl TaskSchedule {
    /// The changes sorted by update, those of one update in the order given (which is the order
    /// they are set in). Nothing is checked against a task here: see [`TaskSchedule::validate`].
    pub fn new(mut changes: Vec<TaskChange>) -> Self {
        // Stable: two changes of one setting at the same update apply in the order given.
        changes.sort_by_key(|c| c.from_update);
        Self { changes }
    }

    /// Adds a change after those already at its update (a change made while the run goes on).
    pub fn push(&mut self, change: TaskChange) {
        let at = self
            .changes
            .partition_point(|c| c.from_update <= change.from_update);
        self.changes.insert(at, change);
    }

    /// Every change, sorted by `from_update`.
    pub fn changes(&self) -> &[TaskChange] {
        &self.changes
    }

    /// The changes that take effect exactly at `update`.
    pub fn at(&self, update: u64) -> impl Iterator<Item = &TaskChange> {
        self.changes.iter().filter(move |c| c.from_update == update)
    }

    /// Brings `task` from its initial settings `initial` to the state of `update`: sets every
    /// initial value, then every change up to and including `update`. Fails with the first
    /// value the task refuses (the task then has the values set before it).
    pub fn configure(
        &self,
        task: &mut dyn Task,
        initial: &[(&'static str, f64)],
        update: u64,
    ) -> Result<(), TaskError> {
        for (name, value) in initial {
            task.set(name, *value)?;
        }
        for c in self.changes.iter().take_while(|c| c.from_update <= update) {
            task.set(&c.name, c.value)?;
        }
        Ok(())
    }

    /// Checks every change against the task's settings before a run starts: sets each in turn
    /// and fails with the first one refused (an unknown name, a value out of range), then
    /// restores the task's settings. Changes are tried in schedule order, so a value the task
    /// only takes after an earlier change is accepted.
    pub fn validate(&self, task: &mut dyn Task) -> Result<(), TaskError> {
        let initial = task.settings();
        for c in &self.changes {
            task.set(&c.name, c.value)?;
        }
        for (name, value) in initial {
            task.set(name, value)?;
        }
        Ok(())
    }
}

/// Makes every rollout block for a fixed time before returning, standing in for a robot or an
/// external simulator (so that scaling over workers can be shown on a small machine).
pub struct Delayed<T> {
    /// The task that computes the costs, unchanged.
    pub inner: T,
    /// The least wall-clock time of a rollout; one that takes longer is not delayed further.
    pub delay: Duration,
}

impl<T: Task> Task for Delayed<T> {
    fn name(&self) -> &'static str {
        self.inner.name()
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
    fn basis_activations(&self) -> Option<Vec<f64>> {
        self.inner.basis_activations()
    }
    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
        let start = std::time::Instant::now();
        let terminal = self.inner.rollout(theta, per_step);
        if let Some(rest) = self.delay.checked_sub(start.elapsed()) {
            std::thread::sleep(rest);
        }
        terminal
    }
    fn settings(&self) -> Vec<(&'static str, f64)> {
        self.inner.settings()
    }
    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        self.inner.set(name, value)
    }
}

/// The via-point task of Section IV-A: a 1-D DMP that should pass through `viapoint` at
/// `viapoint_time`, with the cost of Eq. 3:
/// J_i = viapoint_weight·δ(t_i − viapoint_time)·|x_i − v| + ẍ_i²/N.
/// The via-point term is an immediate cost of the step at `viapoint_time`; the terminal cost is 0.
#[derive(Debug, Clone)]
pub struct ViaPoint {
    dmp: Dmp,
    affine: AffineDmp,
    initial_mean: Vec<f64>,
    viapoint: f64,
    viapoint_step: usize,
    viapoint_weight: f64,
}

/// Parameters of the via-point task; the defaults are the paper's.
#[derive(Debug, Clone, PartialEq)]
pub struct ViaPointSpec {
    /// B: basis functions of the 1-D DMP, so P = B (2).
    pub basis_functions: usize,
    /// The movement's duration τ, in seconds (1).
    pub duration: f64,
    /// The time step, in seconds; must divide `duration`, N = duration/dt + 1 (0.01).
    pub dt: f64,
    /// The DMP's start position (0).
    pub start: f64,
    /// The DMP's goal position (1).
    pub goal: f64,
    /// v: the position to pass through at `viapoint_time` (0.3); the task's one setting
    /// (`viapoint`), which a schedule may change while learning.
    pub viapoint: f64,
    /// When to pass through v, in seconds: a grid point in [0, duration] (0.5).
    pub viapoint_time: f64,
    /// The weight of the miss |x − v| against the acceleration cost ẍ²/N (1000), finite, ≥ 0.
    pub viapoint_weight: f64,
}

impl Default for ViaPointSpec {
    fn default() -> Self {
        Self {
            basis_functions: 2,
            duration: 1.0,
            dt: 0.01,
            start: 0.0,
            goal: 1.0,
            viapoint: 0.3,
            viapoint_time: 0.5,
            viapoint_weight: 1e3,
        }
    }
}

impl ViaPoint {
    /// The task with the minimum-jerk DMP from `start` to `goal` as initial mean. Fails with
    /// [`TaskError::Invalid`] for a DMP [`Dmp::new`] refuses, and [`TaskError::InvalidSetting`]
    /// for a `viapoint_time` off the grid or outside [0, duration], a negative or non-finite
    /// `viapoint_weight`, or a non-finite `viapoint`.
    pub fn new(spec: &ViaPointSpec) -> Result<Self, TaskError> {
        let dmp = Dmp::new(
            vec![spec.start],
            vec![spec.goal],
            spec.basis_functions,
            spec.duration,
            spec.dt,
            Gains::default(),
        )
        .map_err(|e| TaskError::Invalid {
            task: "via-point",
            reason: e.to_string(),
        })?;
        let step = spec.viapoint_time / spec.dt;
        if !(spec.viapoint_time >= 0.0
            && spec.viapoint_time <= spec.duration
            && (step - step.round()).abs() < 1e-9)
        {
            return Err(TaskError::InvalidSetting {
                task: "via-point",
                name: "viapoint_time".into(),
                value: spec.viapoint_time,
                reason: "must be a grid point within [0, duration]",
            });
        }
        if !(spec.viapoint_weight.is_finite() && spec.viapoint_weight >= 0.0) {
            return Err(TaskError::InvalidSetting {
                task: "via-point",
                name: "viapoint_weight".into(),
                value: spec.viapoint_weight,
                reason: "must be finite and >= 0",
            });
        }
        let initial_mean = dmp.fit_min_jerk(spec.duration);
        let mut task = Self {
            affine: dmp.affine(),
            dmp,
            initial_mean,
            viapoint: 0.0,
            viapoint_step: step.round() as usize,
            viapoint_weight: spec.viapoint_weight,
        };
        task.set("viapoint", spec.viapoint)?;
        Ok(task)
    }

    /// The task's DMP: its grid, and [`Dmp::integrate`] for the whole trajectory of a θ.
    pub fn dmp(&self) -> &Dmp {
        &self.dmp
    }

    /// x(t) for θ, for plots.
    pub fn positions(&self, theta: &[f64]) -> Vec<f64> {
        self.affine.rollout(theta).pos
    }
}

impl Task for ViaPoint {
    fn name(&self) -> &'static str {
        "via-point"
    }

    fn parameters(&self) -> usize {
        self.dmp.parameters()
    }

    fn steps(&self) -> usize {
        self.dmp.steps()
    }

    fn initial_mean(&self) -> Vec<f64> {
        self.initial_mean.clone()
    }

    fn basis_activations(&self) -> Option<Vec<f64>> {
        Some(self.dmp.parameter_activations())
    }

    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
        let inv_n = 1.0 / self.affine.steps() as f64;
        self.affine.accelerations_into(0, theta, per_step);
        square_scaled(per_step, inv_n);
        let x = self.affine.position(self.viapoint_step, 0, theta);
        per_step[self.viapoint_step] += self.viapoint_weight * (x - self.viapoint).abs();
        0.0
    }

    fn settings(&self) -> Vec<(&'static str, f64)> {
        vec![("viapoint", self.viapoint)]
    }

    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        match name {
            "viapoint" if value.is_finite() => {
                self.viapoint = value;
                Ok(())
            }
            "viapoint" => Err(TaskError::InvalidSetting {
                task: "via-point",
                name: name.into(),
                value,
                reason: "must be finite",
            }),
            _ => Err(TaskError::UnknownSetting {
                task: "via-point",
                name: name.into(),
                known: "viapoint".into(),
            }),
        }
    }
}

/// v_i ← v_i²·scale, vectorised for the CPU at hand (element-wise, so every variant gives the
/// same bits).
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn square_scaled(v: &mut [f64], scale: f64) {
    for x in v.iter_mut() {
        *x = *x * *x * scale;
    }
}

#[cfg(test)]
mod tests {
    use super::value_text;

    #[test]
    fn huge_and_tiny_values_are_shown_in_exponent_form() {
        assert_eq!(value_text(0.1), "0.1");
        assert_eq!(value_text(0.0), "0");
        assert_eq!(value_text(-1e300), "-1e300");
        assert_eq!(value_text(2.5e-7), "2.5e-7");
        assert_eq!(value_text(f64::INFINITY), "inf");
        let e = super::TaskError::InvalidSetting {
            task: "via-point",
            name: "viapoint".into(),
            value: 1e300,
            reason: "too far",
        };
        assert_eq!(e.to_string(), "task `via-point`: viapoint = 1e300: too far");
    }

    use super::*;

    #[test]
    fn a_via_point_whose_cost_overflows_fails_the_initial_rollout_check() {
        let mut t = ViaPoint::new(&ViaPointSpec::default()).unwrap();
        assert_eq!(check_initial_rollout(&mut t), Ok(()));
        t.set("viapoint", 1e308).unwrap();
        let e = check_initial_rollout(&mut t).unwrap_err().to_string();
        assert!(e.contains("the cost of step 50 = inf"), "{e}");
    }

    #[test]
    fn via_point_cost_matches_equation_3() {
        let mut t = ViaPoint::new(&ViaPointSpec::default()).unwrap();
        let theta = t.initial_mean();
        let mut q = vec![0.0; t.steps()];
        let phi = t.rollout(&theta, &mut q);
        assert_eq!(phi, 0.0);
        let traj = t.dmp().integrate(&theta);
        let n = t.steps() as f64;
        for i in [0, 10, 99] {
            assert!((q[i] - traj.acc[i].powi(2) / n).abs() < 1e-6 * (1.0 + q[i]));
        }
        let expected_via = traj.acc[50].powi(2) / n + 1e3 * (traj.pos[50] - 0.3).abs();
        assert!((q[50] - expected_via).abs() < 1e-6 * expected_via);
    }

    #[test]
    fn schedule_configures_any_update() {
        let mut t = ViaPoint::new(&ViaPointSpec::default()).unwrap();
        let initial = t.settings();
        let s = TaskSchedule::new(vec![TaskChange {
            from_update: 20,
            name: "viapoint".into(),
            value: 0.1,
        }]);
        s.configure(&mut t, &initial, 19).unwrap();
        assert_eq!(t.settings(), vec![("viapoint", 0.3)]);
        s.configure(&mut t, &initial, 20).unwrap();
        assert_eq!(t.settings(), vec![("viapoint", 0.1)]);
        s.configure(&mut t, &initial, 5).unwrap();
        assert_eq!(t.settings(), vec![("viapoint", 0.3)]);
        assert_eq!(s.at(20).count(), 1);
        let bad = TaskSchedule::new(vec![TaskChange {
            from_update: 3,
            name: "via".into(),
            value: 0.1,
        }]);
        let e = bad.validate(&mut t).unwrap_err();
        assert!(e.to_string().contains("no setting `via`"), "{e}");
    }

    #[test]
    fn delayed_task_blocks() {
        let mut t = Delayed {
            inner: ViaPoint::new(&ViaPointSpec::default()).unwrap(),
            delay: Duration::from_millis(20),
        };
        let theta = t.initial_mean();
        let mut q = vec![0.0; t.steps()];
        let start = std::time::Instant::now();
        t.rollout(&theta, &mut q);
        assert!(start.elapsed() >= Duration::from_millis(20));
    }
}
