//! Where a resumed run starts: the update, the distribution and the task settings a stopped run
//! ended with. The optimizer's whole state is its distribution, seed and update index, and the
//! samples of update u are a pure function of (seed, u, k), so a run resumed from the state after
//! update u − 1 continues exactly as if it had never stopped.
//!
//! This crate only holds and applies the state; reading it out of a recording is the `record`
//! crate's job. [`Start::write`] and [`Start::read`] carry it to another process (the pipeline's
//! updater) with every f64 bit for bit.

use std::path::Path;

use nalgebra::{DMatrix, DVector};
use pi2cma::Distribution;
use serde::{Deserialize, Serialize};
use tasks::{Task, TaskChange, TaskError, TaskSchedule};

/// The schedule's changes due at update `u` of a run that resumes from `start`, if any: at the
/// update it resumes at, those its recording does not override ([`Start::scheduled_at_start`]).
/// Of two changes of one setting due at the same update only the later (as written) is one:
/// the earlier never takes effect, and the in-process run recorded both as `/task_change`s,
/// where the pipeline's updater lists the one in force.
pub fn scheduled_at<'a>(
    schedule: &'a TaskSchedule,
    start: Option<&Start>,
    u: u64,
) -> Vec<&'a TaskChange> {
    let due = match start {
        Some(s) if s.update == u => s.scheduled_at_start(schedule),
        _ => schedule.at(u).collect(),
    };
    tasks::not_replaced(&due).copied().collect()
}

/// The state a run resumes from.
#[derive(Debug, Clone, PartialEq)]
pub struct Start {
    /// The first update to run (≥ 1: the state is what update `update − 1` produced).
    pub update: u64,
    /// The distribution update `update` samples from.
    pub distribution: Distribution,
    /// The task settings update `update` starts with, by name: those update `update − 1` ran
    /// with (scheduled and runtime changes included), and changes already recorded for update
    /// `update` (a run stopped right after them).
    pub settings: Vec<(String, f64)>,
    /// The settings update `update − 1` ran with, by name: what a worker whose task refuses a
    /// change of `settings` runs update `update` with. Empty: the same as `settings`.
    pub ran_with: Vec<(String, f64)>,
    /// Whether `settings` are those the distribution of `update` was published with (the run
    /// stopped in that update, or its recording's part begins there): the schedule's changes
    /// at `update`, and `supervisor set`s over them, are in them already, so none is applied
    /// again. A `set` that overrode a scheduled change back to the value in force is in them
    /// only as that value, which the schedule's change would otherwise replace.
    pub published: bool,
    /// Where the state came from (a recording's path), for messages and recordings.
    pub origin: String,
}

/// Why a start file cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {reason}")]
pub struct StartFileError {
    /// The start file.
    pub file: String,
    /// What is wrong with it.
    pub reason: String,
}

/// The file form: f64 values as the hex of their bits, so nothing is lost in decimal.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StartFile {
    origin: String,
    update: u64,
    dim: usize,
    mean_bits: Vec<String>,
    /// Column-major, as nalgebra stores it.
    covariance_bits: Vec<String>,
    settings: Vec<SettingBits>,
    #[serde(default)]
    ran_with: Vec<SettingBits>,
    #[serde(default)]
    published: bool,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SettingBits {
    name: String,
    value_bits: String,
}

fn to_hex(v: f64) -> String {
    format!("{:016x}", v.to_bits())
}

fn from_hex(s: &str) -> Result<f64, String> {
    u64::from_str_radix(s, 16)
        .map(f64::from_bits)
        .map_err(|e| format!("`{s}` is not the hex of an f64's bits: {e}"))
}

impl Start {
    /// Brings `task` to the state of update `self.update`: the config's `initial` settings, the
    /// schedule up to the last run update, the settings that update ran with (which include
    /// runtime changes the schedule does not know), then the schedule's changes at
    /// `self.update`.
    pub fn configure(
        &self,
        schedule: &TaskSchedule,
        task: &mut dyn Task,
        initial: &[(&'static str, f64)],
    ) -> Result<(), TaskError> {
        schedule.configure(task, initial, self.update.saturating_sub(1))?;
        tasks::set_all(task, &self.settings)?;
        for c in self.scheduled_at_start(schedule) {
            task.set(&c.name, c.value)?;
        }
        Ok(())
    }

    /// The schedule's changes at `self.update` that the recording does not override: none when
    /// the settings are the published ones ([`Start::published`]). Otherwise a change
    /// recorded for that update (the run stopped right after publishing its distribution) is
    /// what the update was to run with: the schedule's change, or a `supervisor set` over it at
    /// the same update, which overrode it. Applied again on top, the schedule's would undo the
    /// set, and the resumed run would go on with a value the run it continues had replaced.
    pub fn scheduled_at_start<'a>(&self, schedule: &'a TaskSchedule) -> Vec<&'a TaskChange> {
        if self.published {
            return Vec::new();
        }
        let bits = |list: &[(String, f64)], name: &str| {
            list.iter()
                .find(|(n, _)| n == name)
                .map(|(_, v)| v.to_bits())
        };
        schedule
            .at(self.update)
            .filter(|c| {
                // A setting `ran_with` does not name (an older start file's: empty) ran with
                // its value in `settings`: no change recorded.
                let (recorded, ran) =
                    (bits(&self.settings, &c.name), bits(&self.ran_with, &c.name));
                let overridden = recorded.is_some()
                    && ran.is_some()
                    && recorded != ran
                    && recorded != Some(c.value.to_bits());
                !overridden
            })
            .collect()
    }

    /// Writes the state for [`Start::read`] (TOML, values as bits).
    pub fn write(&self, path: &Path) -> Result<(), StartFileError> {
        let file = StartFile {
            origin: self.origin.clone(),
            update: self.update,
            dim: self.distribution.dim(),
            mean_bits: self.distribution.mean.iter().map(|v| to_hex(*v)).collect(),
            covariance_bits: self
                .distribution
                .covariance
                .iter()
                .map(|v| to_hex(*v))
                .collect(),
            settings: setting_bits(&self.settings),
            ran_with: setting_bits(&self.ran_with),
            published: self.published,
        };
        let err = |reason: String| StartFileError {
            file: path.display().to_string(),
            reason,
        };
        let text = toml::to_string(&file).map_err(|e| err(e.to_string()))?;
        std::fs::write(path, text).map_err(|e| err(format!("cannot write: {e}")))
    }

    /// Reads a state written by [`Start::write`].
    pub fn read(path: &Path) -> Result<Self, StartFileError> {
        let err = |reason: String| StartFileError {
            file: path.display().to_string(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let file: StartFile = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
        let values = |hex: &[String]| {
            hex.iter()
                .map(|h| from_hex(h))
                .collect::<Result<Vec<_>, _>>()
        };
        let mean = values(&file.mean_bits).map_err(err)?;
        let covariance = values(&file.covariance_bits).map_err(err)?;
        let p = file.dim;
        if mean.len() != p || covariance.len() != p * p {
            return Err(err(format!(
                "dim = {p} but {} mean and {} covariance values",
                mean.len(),
                covariance.len()
            )));
        }
        let named = |bits: Vec<SettingBits>| {
            bits.into_iter()
                .map(|s| Ok((s.name, from_hex(&s.value_bits)?)))
                .collect::<Result<Vec<_>, String>>()
                .map_err(err)
        };
        let settings = named(file.settings)?;
        let ran_with = named(file.ran_with)?;
        Ok(Self {
            update: file.update,
            distribution: Distribution {
                mean: DVector::from_vec(mean),
                covariance: DMatrix::from_vec(p, p, covariance),
            },
            settings,
            ran_with,
            published: file.published,
            origin: file.origin,
        })
    }

    /// [`Start::ran_with`] as values in the order of `names` (a task's settings); a setting it
    /// does not name keeps its value in `settings`, then `in_force`.
    pub fn ran_with_values(&self, names: &[&str], in_force: &[f64]) -> Vec<f64> {
        names
            .iter()
            .zip(in_force)
            .map(|(name, v)| {
                self.ran_with
                    .iter()
                    .chain(&self.settings)
                    .find(|(n, _)| n == name)
                    .map_or(*v, |(_, v)| *v)
            })
            .collect()
    }
}

fn setting_bits(settings: &[(String, f64)]) -> Vec<SettingBits> {
    settings
        .iter()
        .map(|(name, v)| SettingBits {
            name: name.clone(),
            value_bits: to_hex(*v),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bits;

    /// Two scheduled changes of one setting at one update: only the later is due (with another
    /// setting's change between them kept).
    #[test]
    fn of_two_changes_of_a_setting_at_one_update_the_later_is_due() {
        let change = |name: &str, value| TaskChange {
            from_update: 20,
            name: name.into(),
            value,
        };
        let schedule = TaskSchedule::new(vec![
            change("viapoint", 0.2),
            change("goal", 2.0),
            change("viapoint", 0.1),
        ]);
        let due: Vec<(&str, f64)> = scheduled_at(&schedule, None, 20)
            .iter()
            .map(|c| (c.name.as_str(), c.value))
            .collect();
        assert_eq!(due, [("goal", 2.0), ("viapoint", 0.1)]);
    }

    #[test]
    fn a_start_file_keeps_every_bit() {
        let awkward = [0.1 + 0.2, -0.0, 5e-324, 1e-300, f64::MAX, -1.0 / 3.0];
        let start = Start {
            update: 21,
            distribution: Distribution {
                mean: DVector::from_column_slice(&awkward[..2]),
                covariance: DMatrix::from_column_slice(2, 2, &awkward[2..]),
            },
            settings: vec![("viapoint_y".into(), 0.1 + 0.7), ("other".into(), -0.0)],
            ran_with: vec![("viapoint_y".into(), 0.3)],
            published: true,
            origin: "runs/a.mcap".into(),
        };
        let dir = std::env::temp_dir().join(format!("start-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("start.toml");
        start.write(&path).unwrap();
        let back = Start::read(&path).unwrap();
        assert_eq!(bits(&back.distribution), bits(&start.distribution));
        assert_eq!(back.settings[1].1.to_bits(), (-0.0f64).to_bits());
        assert_eq!(back.settings[0], start.settings[0]);
        assert_eq!(back.ran_with, start.ran_with);
        assert!(back.published);
        // What the update before ran with, by name; the rest as in force.
        assert_eq!(
            back.ran_with_values(&["other", "viapoint_y", "new"], &[1.0, 2.0, 3.0]),
            [-0.0, 0.3, 3.0]
        );
        assert_eq!((back.update, back.origin.as_str()), (21, "runs/a.mcap"));

        std::fs::write(&path, "origin = \"x\"\nupdate = 1\ndim = 1\nmean_bits = [\"zz\"]\ncovariance_bits = []\nsettings = []\n").unwrap();
        let e = Start::read(&path).unwrap_err().to_string();
        assert!(e.contains("start.toml") && e.contains("`zz`"), "{e}");
        std::fs::write(&path, "origin = \"x\"\nupdate = 1\ndim = 2\nmean_bits = []\ncovariance_bits = []\nsettings = []\nextra = 1\n").unwrap();
        let e = Start::read(&path).unwrap_err().to_string();
        assert!(e.contains("extra"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_recorded_change_that_overrode_the_schedules_at_the_first_update_is_not_undone() {
        let at = |name: &str, value: f64| TaskChange {
            from_update: 40,
            name: name.into(),
            value,
        };
        let schedule = TaskSchedule::new(vec![at("a", 0.6), at("b", 2.0), at("c", 5.0)]);
        // Update 39 ran with a = 0.7, b = 1, c = 4; the distribution of update 40 carried a set
        // over the schedule's a (0.5), the schedule's b, and c as before (the recording has no
        // change of c: the distribution was not published, or a set undid the schedule's).
        let start = Start {
            update: 40,
            distribution: Distribution {
                mean: DVector::zeros(1),
                covariance: DMatrix::identity(1, 1),
            },
            settings: vec![("a".into(), 0.5), ("b".into(), 2.0), ("c".into(), 4.0)],
            ran_with: vec![("a".into(), 0.7), ("b".into(), 1.0), ("c".into(), 4.0)],
            published: false,
            origin: "runs/a.mcap".into(),
        };
        let due: Vec<(&str, f64)> = start
            .scheduled_at_start(&schedule)
            .iter()
            .map(|c| (c.name.as_str(), c.value))
            .collect();
        assert_eq!(due, [("b", 2.0), ("c", 5.0)]);
        // The settings the distribution of update 40 was published with: c stayed at 4 there
        // (a `set` undid the schedule's change), and nothing is applied over them.
        let published = Start {
            published: true,
            ..start
        };
        assert!(published.scheduled_at_start(&schedule).is_empty());
    }

    /// A T-ball run that moved its tee to y = -0.2, then to x = 1.15 (straight ahead of the
    /// shoulder, within the bat's reach), could not be resumed: its settings were set in their
    /// order, x first, with the config's y = -0.53 out of reach.
    #[test]
    fn settings_a_run_reached_one_change_at_a_time_are_resumed_in_any_order() {
        let mut task = tball::Tball::new(&tball::TballConfig::default()).unwrap();
        let initial = task.settings();
        let start = Start {
            update: 3,
            distribution: Distribution {
                mean: DVector::zeros(1),
                covariance: DMatrix::identity(1, 1),
            },
            settings: vec![("tee_x".into(), 1.15), ("tee_y".into(), -0.2)],
            ran_with: Vec::new(),
            published: true,
            origin: "runs/a.mcap".into(),
        };
        start
            .configure(&TaskSchedule::default(), &mut task, &initial)
            .unwrap();
        assert_eq!(task.resting_ball(), [1.15, -0.2, 0.52]);
    }
}
