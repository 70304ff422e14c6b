//! The rerun policy for non-finite costs (`run.nonfinite_reruns`), shared by the in-process
//! runner, the pipeline's updater (which decides) and its recorder (which logs what was
//! decided), so that all three count attempts the same way and say it in the same words.

use pi2cma::CostError;

/// What to do with a rollout whose costs are not finite.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Run it again with the same parameters; `attempt` is the execution that was rejected
    /// (1: the first).
    Rerun {
        /// The execution rejected: 1 for the first.
        attempt: u32,
    },
    /// Fail the run: `reruns` reruns were tried (0 when reruns are off).
    Fail {
        /// Reruns tried, all with non-finite costs.
        reruns: u32,
    },
}

/// The rejected executions of each rollout of the update at hand.
#[derive(Debug, Clone)]
pub struct NonfiniteReruns {
    limit: u32,
    rejected: Vec<u32>,
}

impl NonfiniteReruns {
    /// At most `limit` reruns for each of an update's `rollouts` rollouts.
    pub fn new(limit: u32, rollouts: usize) -> Self {
        Self {
            limit,
            rejected: vec![0; rollouts],
        }
    }

    /// The most reruns of one rollout (`run.nonfinite_reruns`).
    pub fn limit(&self) -> u32 {
        self.limit
    }

    /// Rollout `rollout` reported costs that are not finite: rerun it while it has been rerun
    /// fewer than `limit` times.
    pub fn reject(&mut self, rollout: usize) -> Verdict {
        let Some(rejected) = self.rejected.get_mut(rollout) else {
            // Not a rollout of the update: nothing to rerun (the core names the bad index).
            return Verdict::Fail { reruns: 0 };
        };
        if *rejected >= self.limit {
            return Verdict::Fail { reruns: *rejected };
        }
        *rejected += 1;
        Verdict::Rerun { attempt: *rejected }
    }

    /// The rejected executions of each rollout so far.
    pub fn rejected(&self) -> &[u32] {
        &self.rejected
    }

    /// For the next update.
    pub fn clear(&mut self) {
        self.rejected.fill(0);
    }
}

/// The message of a rejected execution that is rerun (the warning a recording logs):
/// `update 3: cost of rollout 2 (terminal) is NaN; costs must be finite (attempt 1 of at most 3,
/// by worker-1): rerunning it with the same parameters (run.nonfinite_reruns = 2)`.
pub fn rerun_message(update: u64, error: &CostError, attempt: u32, limit: u32, by: &str) -> String {
    format!(
        "update {update}: {error} (attempt {attempt} of at most {}, by {by}): rerunning it with \
         the same parameters (run.nonfinite_reruns = {limit})",
        u64::from(limit) + 1
    )
}

/// What a run that fails on a non-finite cost adds to its message when it tried reruns: `, still
/// after 2 reruns with the same parameters (run.nonfinite_reruns = 2)`; after none (reruns
/// off), [`without_reruns`] for a non-finite cost.
pub fn after_reruns(error: &CostError, reruns: u32) -> String {
    match reruns {
        0 => without_reruns(error).to_string(),
        n => format!(
            ", still after {n} rerun{} with the same parameters (run.nonfinite_reruns = {n})",
            if n == 1 { "" } else { "s" }
        ),
    }
}

/// What a run without reruns adds when it fails on a non-finite cost: the setting that would
/// have run the rollout again. A simulator that gives NaN now and then (a contact solver that
/// diverges) is common, and without this the option is found only in the README.
pub fn without_reruns(error: &CostError) -> &'static str {
    match error {
        CostError::NonFinite { .. } => {
            " (if the task gives such costs now and then, `run.nonfinite_reruns = N` runs such a \
             rollout again, up to N times, with the same parameters)"
        }
        _ => "",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_rollout_is_rerun_up_to_the_limit_and_then_fails_saying_how_often() {
        let mut r = NonfiniteReruns::new(2, 3);
        assert_eq!(r.reject(1), Verdict::Rerun { attempt: 1 });
        // Counted per rollout.
        assert_eq!(r.reject(0), Verdict::Rerun { attempt: 1 });
        assert_eq!(r.reject(1), Verdict::Rerun { attempt: 2 });
        assert_eq!(r.reject(1), Verdict::Fail { reruns: 2 });
        assert_eq!(r.reject(1), Verdict::Fail { reruns: 2 });
        // Per update.
        r.clear();
        assert_eq!(r.reject(1), Verdict::Rerun { attempt: 1 });
        assert_eq!(r.reject(7), Verdict::Fail { reruns: 0 });
    }

    #[test]
    fn without_reruns_the_first_non_finite_cost_fails_and_the_message_names_the_setting() {
        let mut r = NonfiniteReruns::new(0, 3);
        assert_eq!(r.reject(0), Verdict::Fail { reruns: 0 });
        let nan = CostError::NonFinite {
            rollout: 0,
            step: None,
            value: f64::NAN,
        };
        assert_eq!(
            after_reruns(&nan, 0),
            " (if the task gives such costs now and then, `run.nonfinite_reruns = N` runs such a \
             rollout again, up to N times, with the same parameters)"
        );
        // Another cost error has nothing to do with reruns.
        let short = CostError::WrongLength {
            rollout: 0,
            expected: 3,
            got: 2,
        };
        assert_eq!(after_reruns(&short, 0), "");
        assert_eq!(
            after_reruns(&nan, 1),
            ", still after 1 rerun with the same parameters (run.nonfinite_reruns = 1)"
        );
    }

    #[test]
    fn a_rerun_names_the_update_the_rollout_the_first_bad_cost_the_attempt_and_who_ran_it() {
        let error = CostError::NonFinite {
            rollout: 2,
            step: Some(17),
            value: f64::NAN,
        };
        assert_eq!(
            rerun_message(3, &error, 1, 2, "worker-1"),
            "update 3: cost of rollout 2 at step 17 is NaN; costs must be finite (attempt 1 of \
             at most 3, by worker-1): rerunning it with the same parameters \
             (run.nonfinite_reruns = 2)"
        );
    }
}
