//! [`McapRecorder`]: the in-process runner's observer that writes the run's MCAP.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use pi2cma::{Hyperparameters, Optimizer};
use session::{Observer, RunConfig, UpdateRecord};
use tasks::TaskChange;

use crate::writer::{now_ns, Event, RunStart, RunWriter, UpdateData};
use crate::{config_to_toml, RecordError};

/// Worker name of every rollout of the in-process runner.
pub const IN_PROCESS: &str = "in-process";

/// Records a run through [`session::Observer`]. Observer hooks cannot fail, so the first error
/// is kept, recording stops, and [`McapRecorder::finish`] returns it.
///
/// The in-process executor does not time single rollouts: each `/rollout` gets worker
/// `"in-process"` and no timing, and `/update` carries the update's wall-clock interval (from
/// the end of the previous hook to this one).
pub struct McapRecorder {
    writer: Option<RunWriter<BufWriter<File>>>,
    path: PathBuf,
    config_text: Option<String>,
    hp: Option<Hyperparameters>,
    error: Option<RecordError>,
    last_ns: u64,
    updates: u64,
    update_index: u64,
}

impl McapRecorder {
    /// Creates (truncates) the recording at `path`.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        Ok(Self {
            writer: Some(RunWriter::create(path)?),
            path: path.to_path_buf(),
            config_text: None,
            hp: None,
            error: None,
            last_ns: now_ns(),
            updates: 0,
            update_index: 0,
        })
    }

    /// Records this text as the run's config instead of one rendered from the parsed config
    /// (keeps the user's comments and formatting).
    pub fn with_config_text(mut self, text: impl Into<String>) -> Self {
        self.config_text = Some(text.into());
        self
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Updates recorded so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The first error, if recording has failed.
    pub fn error(&self) -> Option<&RecordError> {
        self.error.as_ref()
    }

    /// Records a health event (e.g. the executor failed) on `/log`.
    pub fn log_event(&mut self, event: Event, message: &str) {
        let update = self.update_index;
        self.with_writer(|w| w.write_event(update, event, IN_PROCESS, std::process::id(), message));
    }

    /// Finishes the file (if `on_finish` has not) and returns the first error of the recording.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        if let Some(w) = self.writer.take() {
            if let Err(e) = w.finish() {
                self.error.get_or_insert(e);
            }
        }
        match self.error.take() {
            Some(e) => Err(e),
            None => Ok(self.updates),
        }
    }

    fn with_writer(
        &mut self,
        f: impl FnOnce(&mut RunWriter<BufWriter<File>>) -> Result<(), RecordError>,
    ) {
        if self.error.is_some() {
            return;
        }
        if let Some(w) = self.writer.as_mut() {
            if let Err(e) = f(w) {
                self.error = Some(e);
            }
        }
    }
}

impl Observer for McapRecorder {
    fn on_start(&mut self, config: &RunConfig, optimizer: &Optimizer) {
        let text = self
            .config_text
            .clone()
            .unwrap_or_else(|| config_to_toml(config));
        let hp = optimizer.hyperparameters().clone();
        // Basis activations are a property of the policy; rebuilding the task is cheap and keeps
        // the recording self-contained for recomputing basis-activation averaging.
        let (basis, settings) = match session::build_task(config) {
            Ok(t) => (t.basis_activations(), t.settings()),
            Err(_) => (None, Vec::new()),
        };
        self.update_index = optimizer.update_index();
        let start = RunStart {
            name: &config.run.name,
            seed: optimizer.seed(),
            update: optimizer.update_index(),
            steps: optimizer.steps(),
            hyperparameters: &hp,
            initial: optimizer.distribution(),
            basis_activations: basis.as_deref(),
            config_toml: &text,
            executor: IN_PROCESS,
            task_settings: &settings,
        };
        self.with_writer(|w| {
            w.write_start(&start)?;
            w.write_event(
                start.update,
                Event::Start,
                IN_PROCESS,
                std::process::id(),
                &format!("run {} started (seed {})", start.name, start.seed),
            )
        });
        self.hp = Some(hp);
        self.last_ns = now_ns();
    }

    fn on_task_change(&mut self, update: u64, change: &TaskChange) {
        self.with_writer(|w| w.write_task_change(update, &change.name, change.value));
    }

    fn on_update(&mut self, r: &UpdateRecord<'_>) {
        let end = now_ns();
        let start = self.last_ns;
        let Some(hp) = self.hp.clone() else {
            self.error.get_or_insert(RecordError::invalid(
                self.path.clone(),
                "on_update before on_start: no hyperparameters to record",
            ));
            return;
        };
        let data = UpdateData {
            hyperparameters: &hp,
            before: r.before,
            after: r.after,
            samples: r.samples,
            costs: r.costs,
            summary: r.summary,
            task_settings: r.task_settings,
            batch_start_ns: start,
            batch_end_ns: end,
            rollouts: &[],
            default_worker: IN_PROCESS,
        };
        self.with_writer(|w| w.write_update(&data));
        if self.error.is_none() {
            self.updates += 1;
        }
        self.update_index = r.summary.update + 1;
        self.last_ns = now_ns();
    }

    fn on_finish(&mut self, optimizer: &Optimizer) {
        let u = optimizer.update_index();
        let n = self.updates;
        self.with_writer(|w| {
            w.write_event(
                u,
                Event::Exit,
                IN_PROCESS,
                std::process::id(),
                &format!("run finished after {n} recorded updates"),
            )
        });
        if let Some(w) = self.writer.take() {
            if let Err(e) = w.finish() {
                self.error.get_or_insert(e);
            }
        }
    }
}
