//! The shape of a task whose rollouts run outside this code base: in a user's own simulator or
//! on a robot, behind a rollout worker of their own (see `pipeline::worker::serve`). The update
//! side of a run — updater, sampler, recorder, supervisor — needs only the task's shape (P, N,
//! the initial mean) and its setting names; this type carries exactly that.
//!
//! It is not runnable: `rollout` reports NaN, which every executor rejects as a cost, and
//! `session::build_task` refuses to hand it to an executor in the first place.

use std::sync::Mutex;

use crate::{Task, TaskError};

/// P, N, initial mean and named settings of an external task.
#[derive(Debug, Clone, PartialEq)]
pub struct External {
    parameters: usize,
    steps: usize,
    initial_mean: Vec<f64>,
    settings: Vec<(&'static str, f64)>,
    /// Row-major N × P, for per-time-step weighting with basis-activation averaging.
    basis_activations: Option<Vec<f64>>,
}

impl External {
    /// `settings` in the order the wire carries them (their values travel with every work item).
    pub fn new(
        parameters: usize,
        steps: usize,
        initial_mean: Vec<f64>,
        settings: &[(String, f64)],
    ) -> Result<Self, TaskError> {
        let invalid = |reason: String| TaskError::Invalid {
            task: "external",
            reason,
        };
        if parameters == 0 || steps == 0 {
            return Err(invalid(format!(
                "parameters = {parameters}, steps = {steps}: both must be at least 1"
            )));
        }
        if initial_mean.len() != parameters {
            return Err(invalid(format!(
                "initial_mean has {} values, parameters = {parameters}",
                initial_mean.len()
            )));
        }
        if let Some(i) = initial_mean.iter().position(|v| !v.is_finite()) {
            return Err(invalid(format!(
                "initial_mean[{i}] = {} is not finite",
                initial_mean[i]
            )));
        }
        let mut named = Vec::with_capacity(settings.len());
        for (name, value) in settings {
            if !value.is_finite() {
                return Err(TaskError::InvalidSetting {
                    task: "external",
                    name: name.clone(),
                    value: *value,
                    reason: "must be finite",
                });
            }
            named.push((intern(name), *value));
        }
        Ok(Self {
            parameters,
            steps,
            initial_mean,
            settings: named,
            basis_activations: None,
        })
    }

    /// With the policy's basis activations (row-major N × P, finite, non-negative): what
    /// per-time-step weighting with `temporal_averaging = "basis-activation"` needs, and what
    /// the update side cannot compute for a policy that runs elsewhere.
    pub fn with_basis_activations(mut self, activations: Vec<f64>) -> Result<Self, TaskError> {
        let (n, p) = (self.steps, self.parameters);
        if activations.len() != n * p {
            return Err(TaskError::Invalid {
                task: "external",
                reason: format!(
                    "basis activations: {} values, expected steps × parameters = {n} × {p}",
                    activations.len()
                ),
            });
        }
        if let Some(i) = activations
            .iter()
            .position(|v| !(v.is_finite() && *v >= 0.0))
        {
            return Err(TaskError::Invalid {
                task: "external",
                reason: format!(
                    "basis activation of step {} and parameter {} is {}: must be finite and \
                     not negative",
                    i / p,
                    i % p,
                    activations[i]
                ),
            });
        }
        self.basis_activations = Some(activations);
        Ok(self)
    }
}

/// Setting names are `&'static str` in [`Task`]; an external task's come from its config, which
/// several processes parse repeatedly (the supervisor on every `status`). Each distinct name is
/// leaked once.
fn intern(name: &str) -> &'static str {
    static NAMES: Mutex<Vec<&'static str>> = Mutex::new(Vec::new());
    let mut names = NAMES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(n) = names.iter().find(|n| **n == name) {
        return n;
    }
    let n: &'static str = Box::leak(name.to_owned().into_boxed_str());
    names.push(n);
    n
}

impl Task for External {
    fn name(&self) -> &'static str {
        "external"
    }
    fn parameters(&self) -> usize {
        self.parameters
    }
    fn steps(&self) -> usize {
        self.steps
    }
    fn initial_mean(&self) -> Vec<f64> {
        self.initial_mean.clone()
    }
    fn basis_activations(&self) -> Option<Vec<f64>> {
        self.basis_activations.clone()
    }
    /// Not runnable (see the module documentation): NaN everywhere, which executors reject.
    fn rollout(&mut self, _theta: &[f64], per_step: &mut [f64]) -> f64 {
        per_step.fill(f64::NAN);
        f64::NAN
    }
    fn settings(&self) -> Vec<(&'static str, f64)> {
        self.settings.clone()
    }
    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        let Some(i) = self.settings.iter().position(|(n, _)| *n == name) else {
            let known: Vec<&str> = self.settings.iter().map(|(n, _)| *n).collect();
            return Err(TaskError::UnknownSetting {
                task: "external",
                name: name.to_string(),
                known: if known.is_empty() {
                    "none".into()
                } else {
                    known.join(", ")
                },
            });
        };
        if !value.is_finite() {
            return Err(TaskError::InvalidSetting {
                task: "external",
                name: name.to_string(),
                value,
                reason: "must be finite",
            });
        }
        self.settings[i].1 = value;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_and_settings_are_what_the_config_says() {
        let s = [("target_y".to_string(), 0.4), ("mass".to_string(), 1.0)];
        let mut t = External::new(3, 50, vec![0.0, 1.0, 2.0], &s).unwrap();
        assert_eq!((t.parameters(), t.steps()), (3, 50));
        assert_eq!(t.initial_mean(), vec![0.0, 1.0, 2.0]);
        assert_eq!(t.settings(), vec![("target_y", 0.4), ("mass", 1.0)]);
        t.set("mass", 2.0).unwrap();
        assert_eq!(t.settings()[1], ("mass", 2.0));
        let e = t.set("masss", 1.0).unwrap_err().to_string();
        assert!(e.contains("masss") && e.contains("target_y, mass"), "{e}");
        assert!(t.set("mass", f64::NAN).is_err());
    }

    #[test]
    fn basis_activations_have_the_task_shape() {
        let t = External::new(2, 3, vec![0.0; 2], &[]).unwrap();
        assert_eq!(t.basis_activations(), None);
        let psi = vec![1.0, 0.0, 0.5, 0.5, 0.0, 1.0];
        let t = t.with_basis_activations(psi.clone()).unwrap();
        assert_eq!(t.basis_activations(), Some(psi));
        let t = External::new(2, 3, vec![0.0; 2], &[]).unwrap();
        let e = t.clone().with_basis_activations(vec![1.0; 5]).unwrap_err();
        assert!(
            e.to_string()
                .contains("5 values, expected steps × parameters = 3 × 2"),
            "{e}"
        );
        let e = t.with_basis_activations(vec![1.0, 1.0, 1.0, -0.5, 1.0, 1.0]);
        let e = e.unwrap_err().to_string();
        assert!(e.contains("step 1 and parameter 1 is -0.5"), "{e}");
    }

    #[test]
    fn a_mean_of_the_wrong_length_or_not_finite_is_refused() {
        let e = External::new(3, 50, vec![0.0; 2], &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("initial_mean has 2 values, parameters = 3"),
            "{e}"
        );
        let e = External::new(2, 50, vec![0.0, f64::INFINITY], &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("initial_mean[1]"), "{e}");
        assert!(External::new(0, 5, vec![], &[]).is_err());
    }

    #[test]
    fn rollouts_report_nan_so_that_no_executor_takes_them_for_costs() {
        let mut t = External::new(1, 4, vec![0.0], &[]).unwrap();
        let mut c = [0.0; 4];
        assert!(t.rollout(&[0.0], &mut c).is_nan());
        assert!(c.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn names_are_interned_once() {
        assert!(std::ptr::eq(intern("ball_z"), intern("ball_z")));
    }
}
