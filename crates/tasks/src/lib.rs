//! Tasks: a policy plus a cost function, behind the [`Task`] trait, and the paper's via-point task.
//!
//! A task turns a parameter vector θ into a cost trajectory (N immediate costs and a terminal
//! cost). Tasks have named settings (the via-point's `viapoint`, the T-ball's ball height) that a
//! [`TaskSchedule`] or a user changes while learning runs. This crate knows nothing of the update
//! rule or of how rollouts are distributed; the T-ball task and users' own tasks implement the
//! same trait.

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

/// Settings as messages list them: `viapoint = 0.3, goal = 1` ([`value_text`] values).
pub fn settings_text<N: std::fmt::Display>(settings: impl IntoIterator<Item = (N, f64)>) -> String {
    let list: Vec<String> = settings
        .into_iter()
        .map(|(name, v)| format!("{name} = {}", value_text(v)))
        .collect();
    list.join(", ")
}

#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum TaskError {
    #[error("task `{task}` has no setting `{name}` (it has: {known})")]
    UnknownSetting {
        task: &'static str,
        name: String,
        known: String,
    },
    #[error("task `{task}`: {name} = {}: {reason}", value_text(*.value))]
    InvalidSetting {
        task: &'static str,
        name: String,
        value: f64,
        reason: &'static str,
    },
    #[error("task `{task}`: {reason}")]
    Invalid { task: &'static str, reason: String },
}

/// A policy with its cost function.
///
/// Not `Send`: a pipeline worker (`pipeline::worker::serve`) and the in-process runner
/// (`session::InProcess`) keep their task on the thread that built it, so a task may hold
/// what must stay there (an `Rc`, a robot driver's handle). Code that moves a task to another
/// thread asks for `Task + Send` itself.
pub trait Task {
    fn name(&self) -> &'static str;
    /// P: the length of θ.
    fn parameters(&self) -> usize;
    /// N: the length of a cost trajectory.
    fn steps(&self) -> usize;
    /// The initial mean of the search distribution (e.g. a DMP fitted to a minimum-jerk movement).
    fn initial_mean(&self) -> Vec<f64>;
    /// Row-major N × P basis activations, for the original PI²'s per-parameter temporal weights.
    fn basis_activations(&self) -> Option<Vec<f64>> {
        None
    }
    /// Executes θ: writes the N immediate costs into `per_step`, which comes zeroed (in every
    /// executor), and returns the terminal cost.
    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64;
    /// Current values of the settings a task change may set.
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
/// costs NaN or ±inf (a tee 10³⁰⁰ m away, a via-point whose distance times its weight
/// overflows) would fail every update, so they are refused where they are given (a config, a
/// schedule entry, a runtime change) rather than by the update that first meets them. Not for
/// a task whose rollouts run elsewhere ([`External`]).
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
    pub from_update: u64,
    pub name: String,
    pub value: f64,
}

/// The task changes of a run, kept sorted by update so any executor — or a worker that joins
/// mid-run — can bring a task to the state of any update.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TaskSchedule {
    changes: Vec<TaskChange>,
}

impl TaskSchedule {
    pub fn new(mut changes: Vec<TaskChange>) -> Self {
        // Stable: two changes of one setting at the same update apply in the order given.
        changes.sort_by_key(|c| c.from_update);
        Self { changes }
    }

    pub fn push(&mut self, change: TaskChange) {
        let at = self
            .changes
            .partition_point(|c| c.from_update <= change.from_update);
        self.changes.insert(at, change);
    }

    pub fn changes(&self) -> &[TaskChange] {
        &self.changes
    }

    /// The changes that take effect exactly at `update`.
    pub fn at(&self, update: u64) -> impl Iterator<Item = &TaskChange> {
        self.changes.iter().filter(move |c| c.from_update == update)
    }

    /// Brings `task` from its initial settings `initial` to the state of `update`.
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

    /// Checks every change against the task's settings before a run starts.
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
    pub inner: T,
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
    pub basis_functions: usize,
    pub duration: f64,
    pub dt: f64,
    pub start: f64,
    pub goal: f64,
    pub viapoint: f64,
    pub viapoint_time: f64,
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
