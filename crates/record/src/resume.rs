//! Resuming a run from its recording: the state after the last recorded update (its `after`
//! distribution and the task settings it ran with) as a [`session::Start`], and the check that a
//! config continues that run rather than some other one.
//!
//! A file whose writer was killed works as it is (its readable prefix); `recover` is not needed
//! first. The resumed run records to a file of its own, whose metadata names this one.

use std::path::Path;

use pi2cma::{Hyperparameters, TemporalAveraging, Weighting};
use session::{RunConfig, Start, TaskSection};

use crate::recompute::same_bits;
use crate::{
    distribution_from_proto, first_part, hyperparameters_from_proto, last_part, proto, read_ends,
    RecordError,
};

/// The config a run uses, and its text as the recording keeps it: the file `given`, else the
/// config `point` recorded (a resumed run), else the built-in default; with the command line's
/// `run` overrides written into the text too, so that the recorded config reruns the run
/// ([`RunConfig::with_run_overrides`]).
pub fn run_config(
    given: Option<&Path>,
    point: Option<&ResumePoint>,
    overrides: &[(&str, Option<u64>)],
) -> Result<(RunConfig, String), RecordError> {
    let (cfg, text) = match (given, point) {
        (Some(p), _) => RunConfig::load_with_text(p)?,
        (None, Some(point)) => point.recorded_config()?,
        (None, None) => (
            RunConfig::default_config(),
            session::DEFAULT_CONFIG.to_string(),
        ),
    };
    Ok(RunConfig::with_run_overrides(
        &text,
        &cfg.origin,
        overrides,
    )?)
}

/// Where a recorded run stopped, and what it was.
#[derive(Debug, Clone)]
pub struct ResumePoint {
    /// The state to resume from: the update after the last recorded one.
    pub start: Start,
    /// The run's seed (samples are a function of seed, update and rollout index).
    pub seed: u64,
    /// The hyperparameters of the last recorded update.
    pub hyperparameters: Hyperparameters,
    /// The number of policy parameters P.
    pub dim: usize,
    /// Time steps per rollout.
    pub steps: usize,
    /// The policy's basis activations as recorded in `/run` (row-major N × P; empty if none).
    pub basis_activations: Vec<f64>,
    /// The config the run was started with, as recorded.
    pub config_toml: Option<String>,
    /// Why reading stopped early (a file whose writer was killed), if it did.
    pub truncated: Option<String>,
}

/// Reads the state after the last update recorded in `path`; of a recording split into parts
/// (`recording.split_mb`), in its last part, whichever part `path` names.
pub fn resume_point(path: &Path) -> Result<ResumePoint, RecordError> {
    resume_point_within(path, RESUMED_FROM_DEPTH)
}

/// How many recordings back (`resumed_from`) a recording without updates is followed for what
/// the update before its first ran with: enough for a resumed run stopped before its first
/// update, resumed again and stopped again, and bounded should files name each other.
const RESUMED_FROM_DEPTH: u32 = 8;

fn resume_point_within(path: &Path, depth: u32) -> Result<ResumePoint, RecordError> {
    let last = last_part(path);
    let path = last.as_path();
    if crate::being_written(path) {
        return Err(RecordError::invalid(
            path,
            "is still being written by a running recorder: its run has not ended (stop it \
             first, e.g. `supervisor stop`)",
        ));
    }
    // Streamed: the recording of a long continual run may not fit in memory.
    let rec = read_ends(path)?;
    let from = match &rec.last_update {
        Some(last) => after_update(last, &rec.changes_after, rec.unfinished.as_ref()),
        None => at_start(path, &rec, depth)?,
    };
    let bad = |what: String| RecordError::Update {
        file: path.to_path_buf(),
        update: from.update,
        what: format!("{}{what}", from.place),
    };
    let distribution = distribution_from_proto(
        from.distribution
            .ok_or_else(|| bad(format!("no `{}` distribution", from.distribution_name)))?,
    )
    .map_err(|w| bad(format!("{}: {w}", from.distribution_name)))?;
    let hyperparameters = hyperparameters_from_proto(
        from.hyperparameters
            .ok_or_else(|| bad("no hyperparameters".into()))?,
    )
    .map_err(|w| bad(w.to_string()))?;
    Ok(ResumePoint {
        start: Start {
            update: from.start,
            distribution,
            settings: from.settings,
            ran_with: from.ran_with,
            published: from.published,
            origin: path.display().to_string(),
        },
        seed: from.seed,
        hyperparameters,
        dim: from.dim as usize,
        steps: from.steps as usize,
        basis_activations: rec
            .run
            .as_ref()
            .map(|r| r.basis_activations.clone())
            .unwrap_or_default(),
        config_toml: rec
            .run
            .as_ref()
            .map(|r| r.config_toml.clone())
            .filter(|t| !t.is_empty()),
        truncated: rec.truncated.clone(),
    })
}

/// Where a recording's run goes on from, as its messages hold it (decoded by
/// [`resume_point`]).
struct Recorded<'a> {
    /// The update of the message the state is read from.
    update: u64,
    /// Where in that message, for errors ("" for `/update`).
    place: &'static str,
    distribution_name: &'static str,
    distribution: Option<&'a proto::Distribution>,
    hyperparameters: Option<&'a proto::Hyperparameters>,
    /// The update to run first.
    start: u64,
    seed: u64,
    dim: u32,
    steps: u32,
    settings: Vec<(String, f64)>,
    ran_with: Vec<(String, f64)>,
    /// [`Start::published`].
    published: bool,
}

/// The state after the last recorded update: its `after` distribution.
fn after_update<'a>(
    last: &'a proto::Update,
    changes_after: &[proto::TaskChange],
    unfinished: Option<&proto::UnfinishedUpdate>,
) -> Recorded<'a> {
    let ran_with = by_name(&last.task_settings);
    let mut settings = ran_with.clone();
    let next = last.update + 1;
    let unfinished = unfinished.filter(|u| u.update == next);
    match unfinished {
        // The run stopped in the next update: every setting as it was to run with, also one a
        // `set` kept at its value over the schedule's change, which no change record shows.
        Some(u) => settings = by_name(&u.task_settings),
        // Changes recorded for the update after the last (the run stopped right after them)
        // are what that update runs with: the distribution it samples from carried them.
        None => {
            for c in changes_after.iter().filter(|c| c.update == next) {
                if let Some(s) = settings.iter_mut().find(|(n, _)| *n == c.name) {
                    s.1 = c.value;
                }
            }
        }
    }
    Recorded {
        update: last.update,
        place: "",
        distribution_name: "after",
        distribution: last.after.as_ref(),
        hyperparameters: last.hyperparameters.as_ref(),
        start: last.update + 1,
        seed: last.seed,
        dim: last.dim,
        steps: last.steps,
        settings,
        ran_with,
        published: unfinished.is_some(),
    }
}

/// The state a recording without updates begins with: its `/run`, the distribution of its
/// first update and the settings that distribution was published with. A part begun by a
/// restarted recorder has no update when the run stopped before it wrote one, and is still
/// where the run had got to (the updates between it and the part before were not recorded). A
/// recording of a run's update 0 has nothing to resume: the run starts anew.
fn at_start<'a>(
    path: &Path,
    rec: &'a crate::Ends,
    depth: u32,
) -> Result<Recorded<'a>, RecordError> {
    let run = rec
        .run
        .as_ref()
        .filter(|r| r.update > 0)
        .ok_or_else(|| RecordError::invalid(path, "has no recorded update to resume from"))?;
    // The distribution of a run's last update (`run.updates`) is published without the
    // changes due at it: that update does not run. Any other holds them.
    let ended_there =
        RunConfig::parse(&run.config_toml, path).is_ok_and(|c| c.run.updates == Some(run.update));
    Ok(Recorded {
        update: run.update,
        place: "/run: ",
        distribution_name: "initial",
        distribution: run.initial.as_ref(),
        hyperparameters: run.hyperparameters.as_ref(),
        start: run.update,
        seed: run.seed,
        dim: run.dim,
        steps: run.steps,
        settings: by_name(&run.task_settings),
        ran_with: ran_before(path, rec, run, depth),
        published: !ended_there,
    })
}

/// What update `run.update` − 1 ran with, for a recording that holds no update: its `/run`
/// says so; a recording made before it did is helped by the recording its run resumed
/// (metadata `resumed_from`) when it resumed at the same update, or by the part before it
/// when that part's last update is the one before. Empty when none of them knows: a change
/// refused at the first update then has the settings in force to fall back to.
fn ran_before(
    path: &Path,
    rec: &crate::Ends,
    run: &proto::RunInfo,
    depth: u32,
) -> Vec<(String, f64)> {
    if !run.previous_task_settings.is_empty() {
        return by_name(&run.previous_task_settings);
    }
    let resumed = rec
        .metadata
        .get("resumed_from")
        .filter(|_| depth > 0)
        .and_then(|from| resume_point_within(Path::new(from), depth - 1).ok())
        .filter(|p| p.start.update == run.update)
        .map(|p| p.start);
    if let Some(start) = resumed {
        return start.ran_with;
    }
    let n = crate::part_number(path);
    let before = (n >= 2)
        .then(|| crate::part_path_or_first(&first_part(path), n - 1))
        .and_then(|p| read_ends(&p).ok())
        .and_then(|e| e.last_update)
        .filter(|u| u.update + 1 == run.update);
    before.map_or_else(Vec::new, |u| by_name(&u.task_settings))
}

fn by_name(settings: &[proto::Setting]) -> Vec<(String, f64)> {
    settings.iter().map(|s| (s.name.clone(), s.value)).collect()
}

/// A task section as far as it decides a rollout's cost, in `Debug` form.
fn comparable(task: &TaskSection) -> String {
    let mut t = task.clone();
    match &mut t {
        TaskSection::ViaPoint(v) => v.rollout_delay_ms = 0.0,
        TaskSection::Tball(b) => b.rollout_delay_ms = 0.0,
        TaskSection::External(e) => e.worker.clear(),
    }
    format!("{t:?}")
}

/// The `name: value` fields of two `Debug` forms of one struct that differ, as "name: a → b".
fn differing_fields(was: &str, now: &str) -> String {
    // Top-level fields: split at ", " outside brackets, braces and parentheses (1 deep: inside
    // the variant's own braces).
    fn fields(s: &str) -> Vec<&str> {
        let (mut out, mut depth, mut start) = (Vec::new(), 0i32, None);
        for (i, c) in s.char_indices() {
            match c {
                '{' | '[' | '(' => {
                    depth += 1;
                    if depth == 2 && c == '{' && start.is_none() {
                        start = Some(i + 1);
                    }
                }
                '}' | ']' | ')' => {
                    if depth == 2 && c == '}' {
                        if let Some(b) = start.take() {
                            out.push(s[b..i].trim());
                        }
                    }
                    depth -= 1;
                }
                ',' if depth == 2 => {
                    if let Some(b) = start {
                        out.push(s[b..i].trim());
                        start = Some(i + 1);
                    }
                }
                _ => {}
            }
        }
        out
    }
    let (a, b) = (fields(was), fields(now));
    let changed: Vec<String> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x != y)
        .map(|(x, y)| match (x.split_once(": "), y.split_once(": ")) {
            (Some((name, from)), Some((_, to))) => format!("{name}: {from} → {to}"),
            _ => format!("{x} → {y}"),
        })
        .collect();
    if changed.is_empty() || a.len() != b.len() {
        format!("{was} → {now}")
    } else {
        changed.join("; ")
    }
}

impl ResumePoint {
    /// The task section of the recorded config, if the recording has one that parses.
    fn recorded_task(&self) -> Option<TaskSection> {
        self.recorded_config().ok().map(|(cfg, _)| cfg.task)
    }

    /// The config the recorded run was started with, and its text: what a resume without a
    /// config of its own continues with.
    pub fn recorded_config(&self) -> Result<(RunConfig, String), RecordError> {
        let file = Path::new(&self.start.origin);
        let text = self.config_toml.clone().ok_or_else(|| {
            RecordError::invalid(file, "has no recorded config: give the run's config file")
        })?;
        let origin = format!("{} (its recorded config)", self.start.origin);
        let cfg = RunConfig::parse(&text, Path::new(&origin))
            .map_err(|e| RecordError::invalid(file, e.to_string()))?;
        Ok((cfg, text))
    }

    /// Refuses a resumed run's recording path that is the file being resumed or a part of its
    /// recording (it would be truncated, or the parts after it removed, before anything is
    /// written); `option` names the option that chose it.
    pub fn check_output(&self, recording: &Path, option: &str) -> Result<(), RecordError> {
        let origin = Path::new(&self.start.origin);
        let first = |p: &Path| first_part(p).canonicalize().ok();
        let same = first(recording).is_some_and(|r| first(origin) == Some(r));
        if same {
            return Err(RecordError::invalid(
                origin,
                format!("the resumed run would record over it; give another {option}"),
            ));
        }
        Ok(())
    }

    /// Whether `config` continues this run: the same task shape and setting names, seed and
    /// hyperparameters, and updates left to run. Anything else would not be the recorded run
    /// going on, so it is refused, naming both sides.
    pub fn check(&self, config: &RunConfig) -> Result<(), RecordError> {
        let file = Path::new(&self.start.origin);
        let cfg = config.origin.display();
        let refuse = |what: String| {
            RecordError::invalid(
                file,
                format!("cannot resume with {cfg}: {what} (to start afresh, run without --resume)"),
            )
        };
        let task = config.build_task().map_err(|e| refuse(e.to_string()))?;
        let (dim, steps) = (task.initial_mean().len(), task.steps());
        if (dim, steps) != (self.dim, self.steps) {
            return Err(refuse(format!(
                "the recorded task has P = {}, N = {}; the config's has P = {dim}, N = {steps}",
                self.dim, self.steps
            )));
        }
        let names: Vec<&str> = task.settings().iter().map(|(n, _)| *n).collect();
        let recorded: Vec<&str> = self
            .start
            .settings
            .iter()
            .map(|(n, _)| n.as_str())
            .collect();
        if names != recorded {
            return Err(refuse(format!(
                "the recorded task has the settings {recorded:?}; the config's has {names:?}"
            )));
        }
        if config.run.seed != self.seed {
            let given = config
                .option_setting("seed", config.run.seed)
                .map(|o| format!("{o} was given"))
                .unwrap_or_else(|| format!("the config run.seed = {}", config.run.seed));
            return Err(refuse(format!(
                "the recording has seed {}; {given}",
                self.seed
            )));
        }
        let (r, c) = (&self.hyperparameters, &config.hyperparameters());
        let differs: Vec<String> = [
            // Named by the config keys behind each, so the user knows what to look at.
            differ("optimizer.rollouts", &r.rollouts, &c.rollouts),
            differ(
                "cost mapping (optimizer.method, eliteness, elites)",
                &r.mapping,
                &c.mapping,
            ),
            differ(
                "exploration (optimizer.method, lambda_init, lambda_min, lambda_max, decay)",
                &r.exploration,
                &c.exploration,
            ),
            differ(
                "optimizer.weighting, temporal_averaging",
                &r.weighting,
                &c.weighting,
            ),
            differ(
                "optimizer.evaluation_in_update",
                &r.evaluation_in_update,
                &c.evaluation_in_update,
            ),
            differ("optimizer.covariance", &r.covariance, &c.covariance),
        ]
        .into_iter()
        .flatten()
        .collect();
        if !differs.is_empty() {
            return Err(refuse(format!(
                "its hyperparameters differ (recording vs config): {}",
                differs.join("; ")
            )));
        }
        // With basis-activation averaging the activations are part of the update rule.
        let averaged_by_basis = c.weighting
            == Weighting::PerTimeStep {
                temporal: TemporalAveraging::BasisActivation,
            };
        let own = task.basis_activations().unwrap_or_default();
        if averaged_by_basis && !same_bits(&own, &self.basis_activations) {
            return Err(refuse(
                "the basis activations differ (the recording's /run vs the config's task), and \
                 the update weighs by them (temporal_averaging = \"basis-activation\")"
                    .into(),
            ));
        }
        // The task itself: another cost function would make the files one run only in name.
        // Only what does not change a rollout's cost may differ: the stand-in delay of a
        // simulated rollout and the command that starts an external worker.
        if let Some(recorded) = self.recorded_task() {
            let (was, now) = (comparable(&recorded), comparable(&config.task));
            if was != now {
                return Err(refuse(format!(
                    "its task differs from the recorded run's (recording vs config): {} (a task \
                     change while learning goes through [[schedule]] or `supervisor set`)",
                    differing_fields(&was, &now)
                )));
            }
        }
        if let Some(n) = config.run.updates.filter(|n| *n <= self.start.update) {
            let given = config
                .option_setting("updates", n)
                .map(|o| format!("{o} was given"))
                .unwrap_or_else(|| format!("{cfg} has run.updates = {n}"));
            return Err(RecordError::invalid(
                file,
                format!(
                    "ends with update {}, and {given}: nothing left to run (give more updates)",
                    self.start.update - 1
                ),
            ));
        }
        Ok(())
    }
}

/// `name: recorded vs configured` if they differ.
fn differ<T: PartialEq + std::fmt::Debug>(name: &str, recorded: &T, config: &T) -> Option<String> {
    (recorded != config).then(|| format!("{name}: {recorded:?} vs {config:?}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{read_recording, McapRecorder};

    fn config(edits: &[(&str, &str)]) -> RunConfig {
        let mut text = session::DEFAULT_CONFIG.to_string();
        for (from, to) in edits {
            assert!(text.contains(from), "{from}");
            text = text.replacen(from, to, 1);
        }
        RunConfig::parse(&text, Path::new("c.toml")).unwrap()
    }

    #[test]
    fn other_basis_activations_are_refused_when_the_update_weighs_by_them() {
        let dir = std::env::temp_dir().join(format!("resume-psi-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let by_basis = [
            ("updates = 40", "updates = 3"),
            (
                "weighting = \"episodic\"",
                "weighting = \"per-time-step\"\ntemporal_averaging = \"basis-activation\"",
            ),
        ];
        let cfg = config(&by_basis);
        crate::testing::record_session(&cfg, 1, &path);
        let mut point = resume_point(&path).unwrap();
        assert_eq!(point.basis_activations.len(), 101 * 2);
        let more = config(&[by_basis[1]]);
        point.check(&more).unwrap();
        // A recording whose policy had other activations (an external task's config changed).
        point.basis_activations[3] += 0.25;
        let e = point.check(&more).unwrap_err().to_string();
        assert!(e.contains("the basis activations differ"), "{e}");
        // Episodic weighting does not use them.
        let mut episodic = point.clone();
        episodic.hyperparameters = config(&[]).hyperparameters();
        episodic.check(&config(&[])).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A pipeline run stopped right after `supervisor set`, before any update ran with the
    /// change, has it recorded after its last update (the recorder writes what the published
    /// distribution of the next update carries): the resume goes on with it.
    #[test]
    fn a_change_recorded_for_the_update_after_the_last_is_where_the_run_resumes() {
        use session::{Observer, UpdateRecord};
        struct ChangeAtEnd(McapRecorder);
        impl Observer for ChangeAtEnd {
            fn wants_rollout_times(&self) -> bool {
                self.0.wants_rollout_times()
            }
            fn on_start(
                &mut self,
                c: &RunConfig,
                o: &pi2cma::Optimizer,
                s: &[(&'static str, f64)],
            ) {
                self.0.on_start(c, o, s)
            }
            fn on_task_change(&mut self, u: u64, c: &tasks::TaskChange) {
                self.0.on_task_change(u, c)
            }
            fn on_update(&mut self, r: &UpdateRecord<'_>) {
                self.0.on_update(r)
            }
            fn on_finish(&mut self, o: &pi2cma::Optimizer) {
                let u = o.update_index();
                let change = tasks::TaskChange {
                    from_update: u,
                    name: "viapoint".into(),
                    value: 0.9,
                };
                self.0.on_task_change(u, &change);
                self.0.on_finish(o)
            }
        }
        let dir = std::env::temp_dir().join(format!("resume-ahead-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let cfg = config(&[("updates = 40", "updates = 25")]);
        let mut rec = ChangeAtEnd(McapRecorder::create(&path).unwrap());
        session::run_session(&cfg, 1, &mut rec).unwrap();
        rec.0.finish().unwrap();

        let point = resume_point(&path).unwrap();
        assert_eq!(point.start.update, 25);
        // Not the 0.1 of the schedule's change at 20, which update 24 ran with.
        assert_eq!(point.start.settings, [("viapoint".to_string(), 0.9)]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A part a restarted recorder began just before the run stopped: its `/run` only. The
    /// settings there are those its first update was published with; what the update before
    /// ran with (what a refused change falls back to) comes from `/run` too, or, in a recording
    /// made before `/run` held it, from the recording it resumed or the part before.
    #[test]
    fn a_recording_without_updates_resumes_where_its_run_message_begins() {
        let dir = std::env::temp_dir().join(format!("resume-run-only-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = config(&[]);
        let hp = cfg.hyperparameters();
        let initial = pi2cma::Distribution {
            mean: nalgebra::DVector::from_vec(vec![0.5, -2.0]),
            covariance: nalgebra::DMatrix::from_row_slice(2, 2, &[3.0, 0.25, 0.25, 1.5]),
        };
        let text = crate::config_to_toml(&cfg);
        let write = |name: &str,
                     update: u64,
                     previous: &[(&str, f64)],
                     resumed_from: Option<&str>,
                     text: &str| {
            let path = dir.join(name);
            let mut w = crate::RunWriter::create(&path).unwrap();
            w.write_start(&crate::RunStart {
                name: "A1",
                seed: 1,
                update,
                steps: 101,
                hyperparameters: &hp,
                initial: &initial,
                basis_activations: None,
                config_toml: text,
                executor: "pipeline",
                task_settings: &[("viapoint", 0.1)],
                previous_task_settings: previous,
                resumed_from,
                part: None,
                run_id: Some(7),
                recorder_restart: Some(1),
            })
            .unwrap();
            w.finish().unwrap();
            path
        };
        let viapoint = |v: f64| vec![("viapoint".to_string(), v)];
        let point =
            resume_point(&write("at-12.mcap", 12, &[("viapoint", 0.3)], None, &text)).unwrap();
        assert_eq!(point.start.update, 12);
        assert_eq!(point.start.distribution, initial);
        assert_eq!(point.start.settings, viapoint(0.1));
        assert_eq!(point.start.ran_with, viapoint(0.3));
        assert!(point.start.published);
        assert_eq!((point.seed, point.dim, point.steps), (1, 2, 101));
        assert_eq!(point.hyperparameters, hp);
        point.check(&cfg).unwrap();
        // Recorded before `/run` held the settings of the update before, with nothing else
        // that knows them.
        let older = resume_point(&write("older.mcap", 12, &[], None, &text)).unwrap();
        assert!(older.start.ran_with.is_empty() && older.start.published);
        // The distribution of the run's last update holds no change due at it.
        let ended = config(&[("updates = 40", "updates = 12")]);
        let ended = crate::config_to_toml(&ended);
        let ended = resume_point(&write("ended.mcap", 12, &[], None, &ended)).unwrap();
        assert!(!ended.start.published);

        // Older recordings: a run of updates 0..=11 (viapoint 0.3 until the schedule's 0.1 at
        // 20), then a part, and a resumed run's file, beginning at 12 without the settings.
        let twelve = config(&[("updates = 40", "updates = 12")]);
        crate::testing::record_session(&twelve, 1, &dir.join("run.mcap"));
        std::fs::copy(dir.join("run.mcap"), dir.join("day1.mcap")).unwrap();
        let part = write("run.part-2.mcap", 12, &[], None, &text);
        assert_eq!(resume_point(&part).unwrap().start.ran_with, viapoint(0.3));
        let day1 = dir.join("day1.mcap").display().to_string();
        let day2 = write("day2.mcap", 12, &[], Some(&day1), &text);
        assert_eq!(resume_point(&day2).unwrap().start.ran_with, viapoint(0.3));
        // A part whose part before does not end with the update before its first (a restarted
        // recorder's: updates missing).
        let gap = write("run.part-3.mcap", 14, &[], None, &text);
        assert!(resume_point(&gap).unwrap().start.ran_with.is_empty());

        // Update 0 of a run: nothing to resume.
        let e = resume_point(&write("at-0.mcap", 0, &[], None, &text))
            .unwrap_err()
            .to_string();
        assert!(e.contains("has no recorded update to resume from"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_point_is_the_state_after_the_last_update_and_other_runs_are_refused() {
        let dir = std::env::temp_dir().join(format!("resume-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let cfg = config(&[("updates = 40", "updates = 25")]);
        let after = crate::testing::record_session(&cfg, 1, &path);

        let point = resume_point(&path).unwrap();
        assert_eq!(point.start.update, 25);
        assert_eq!(point.start.distribution, after);
        assert_eq!(point.start.settings, [("viapoint".to_string(), 0.1)]);
        assert_eq!((point.seed, point.dim, point.steps), (1, 2, 101));
        assert!(point.truncated.is_none());
        let (recorded, _) = point.recorded_config().unwrap();
        assert_eq!(recorded.run.updates, Some(25));

        point.check(&config(&[])).unwrap();
        let refused = |c: RunConfig| point.check(&c).unwrap_err().to_string();
        let e = refused(config(&[("updates = 40", "updates = 25")]));
        assert!(e.ends_with("ends with update 24, and c.toml has run.updates = 25: nothing left to run (give more updates)"), "{e}");
        // Values typed as options are named as typed, not as keys of a file that lacks them.
        let option = |field, value| {
            RunConfig::with_run_overrides(
                session::DEFAULT_CONFIG,
                Path::new("c.toml"),
                &[(field, Some(value))],
            )
            .unwrap()
            .0
        };
        let e = refused(option("updates", 20));
        assert!(e.ends_with("ends with update 24, and --updates 20 was given: nothing left to run (give more updates)"), "{e}");
        let e = refused(option("seed", 2));
        assert!(
            e.contains("the recording has seed 1; --seed 2 was given"),
            "{e}"
        );
        let e = refused(config(&[("seed = 1", "seed = 2")]));
        assert!(
            e.contains("the recording has seed 1; the config run.seed = 2"),
            "{e}"
        );
        let e = refused(config(&[("basis_functions = 2", "basis_functions = 3")]));
        assert!(
            e.contains("the recorded task has P = 2, N = 101; the config's has P = 3, N = 101"),
            "{e}"
        );
        let e = refused(config(&[(
            "weighting = \"episodic\"",
            "weighting = \"per-time-step\"",
        )]));
        assert!(
            e.contains(
                "its hyperparameters differ (recording vs config): optimizer.weighting, \
                 temporal_averaging: Episodic vs"
            ),
            "{e}"
        );
        let e = refused(config(&[("eliteness = 15.0", "eliteness = 10.0")]));
        assert!(
            e.contains(
                "cost mapping (optimizer.method, eliteness, elites): Exponential { eliteness: 15.0 } vs Exponential { eliteness: 10.0 }"
            ),
            "{e}"
        );
        assert!(
            e.starts_with(&format!("{}: cannot resume with c.toml:", path.display())),
            "{e}"
        );
        // Another cost function is another run; a stand-in delay is not.
        let e = refused(config(&[(
            "viapoint_weight = 1000.0",
            "viapoint_weight = 500.0",
        )]));
        assert!(
            e.contains("its task differs from the recorded run's (recording vs config): viapoint_weight: 1000.0 → 500.0 ("),
            "{e}"
        );
        point
            .check(&config(&[(
                "viapoint_weight = 1000.0",
                "viapoint_weight = 1000.0\nrollout_delay_ms = 3.0",
            )]))
            .unwrap();

        // Resumed in-process, the new recording's `/run` holds the settings the run resumed
        // with (the via-point moved at update 20), not the config's initial ones (0.3).
        let resumed = dir.join("b.mcap");
        let cfg30 = config(&[("updates = 40", "updates = 30")]);
        let mut exec = session::InProcess::resume(&cfg30, 1, point.start.clone()).unwrap();
        let mut rec = McapRecorder::create(&resumed).unwrap();
        exec.run(&mut rec, &|| false).unwrap();
        rec.finish().unwrap();
        let b = read_recording(&resumed).unwrap();
        let names = |s: &[crate::proto::Setting]| -> Vec<(String, f64)> {
            s.iter().map(|s| (s.name.clone(), s.value)).collect()
        };
        let run = b.run_info().unwrap();
        assert_eq!(names(&run.task_settings), point.start.settings);
        assert_eq!(names(&b.updates[0].task_settings), point.start.settings);

        std::fs::write(dir.join("empty.mcap"), b"").unwrap();
        assert!(resume_point(&dir.join("empty.mcap")).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
