//! The result file the updater writes when a run ends (`<run dir>/result.toml`): the final
//! distribution (with its exact bits), the last costs, and every task change with the update it
//! took effect at.

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

/// The contents of `result.toml`, written once by the updater as the run ends (stopped or
/// complete); the supervisor reads it for its summary and `--copy-result`. Present only for a
/// run whose updater ended in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunResult {
    /// The config's `run.name`.
    pub name: String,
    /// The config's `run.seed`: with it the run can be recomputed bit for bit.
    pub seed: u64,
    /// Updates completed.
    pub updates: u64,
    /// Whether the configured number of updates was reached (false: stopped early).
    pub complete: bool,
    /// From the start to the end of the last update.
    pub elapsed_s: f64,
    /// Of which the first update (includes connecting every port: a one-time cost).
    #[serde(default)]
    pub first_update_s: f64,
    /// Total cost of the evaluation rollout of the first and of the last update.
    pub first_eval_cost: f64,
    /// See `first_eval_cost`.
    pub last_eval_cost: f64,
    /// λ of the final distribution.
    pub lambda: f64,
    /// The final distribution's mean (P values), as TOML decimals: use [`RunResult::exact`]
    /// for the exact values.
    pub mean: Vec<f64>,
    /// Σ, column-major.
    pub covariance: Vec<f64>,
    /// `f64::to_bits` of `mean` and `covariance` as hex, for bit-exact comparisons.
    pub mean_bits: Vec<String>,
    /// See `mean_bits`.
    pub covariance_bits: Vec<String>,
    /// Every task change that took effect, in order: from the config's schedule, `supervisor
    /// set`, a resume, or the workers (see [`RecordedChange::source`]).
    #[serde(default)]
    pub task_changes: Vec<RecordedChange>,
    /// Changes the workers' task refused (`Task::set` failed): the run went on with the value in
    /// force before. Not in `task_changes`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub refused_changes: Vec<RecordedChange>,
    /// Executions of rollouts whose costs were not finite and that were run again
    /// (`run.nonfinite_reruns`); their costs are in no update.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub nonfinite_reruns: u64,
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// A task change and the update index it took effect at.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordedChange {
    /// The first update that ran with the new value.
    pub from_update: u64,
    /// The task setting's name.
    pub name: String,
    /// Its new value.
    pub value: f64,
    /// "schedule" (from the config), "runtime" (`supervisor set`), "resume" (in force where a
    /// resumed run began) or "workers" (what the workers ran with instead of a value they no
    /// longer took).
    pub source: String,
}

/// Each value's `f64::to_bits` as 16 lower-case hex digits, as in `mean_bits`: for comparing
/// runs bit for bit.
pub fn bits(values: &[f64]) -> Vec<String> {
    values
        .iter()
        .map(|v| format!("{:016x}", v.to_bits()))
        .collect()
}

/// The inverse of [`bits`]; an error names the entry that is not hex.
fn from_bits(bits: &[String]) -> anyhow::Result<Vec<f64>> {
    bits.iter()
        .map(|b| {
            u64::from_str_radix(b, 16)
                .map(f64::from_bits)
                .with_context(|| format!("bad bits `{b}`"))
        })
        .collect()
}

impl RunResult {
    /// Seconds per update after the first (steady state); `None` for fewer than 2 updates.
    pub fn steady_s_per_update(&self) -> Option<f64> {
        (self.updates >= 2)
            .then(|| (self.elapsed_s - self.first_update_s) / (self.updates - 1) as f64)
    }

    /// Writes the file atomically (a temporary file, then a rename), so a reader never sees
    /// half of it.
    pub(crate) fn write(&self, path: &Path) -> anyhow::Result<()> {
        let text = toml::to_string(self).context("cannot encode result")?;
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, text).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Reads a result file; an error names the file (missing, unreadable, or not a result).
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("{}: bad result file", path.display()))
    }

    /// The exact final mean and covariance (from the bits).
    pub fn exact(&self) -> anyhow::Result<(Vec<f64>, Vec<f64>)> {
        Ok((
            from_bits(&self.mean_bits)?,
            from_bits(&self.covariance_bits)?,
        ))
    }
}
