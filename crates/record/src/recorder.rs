//! [`McapRecorder`]: the in-process runner's observer that writes the run's MCAP.
//!
//! The file is written by a thread of its own, so writing update u overlaps with computing
//! update u + 1 (on a machine with a spare core, recording then costs the runner almost nothing
//! while an update takes longer to compute than to write). `on_update(u)` first waits until
//! update u − 1 is flushed, so at any time at most one update — the one in flight — is not yet
//! in the file.
//!
//! Both threads wait for each other once per update. While updates come quickly, each first
//! polls for a while ([`Patience`]): on these machines a sleep and a wake-up cost more than a
//! µs-rollout update takes to compute or write.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, RecvError, Sender, TryRecvError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use pi2cma::{CostBatch, Distribution, Hyperparameters, Optimizer, ParameterBatch, UpdateSummary};
use session::{Observer, Rerun, RunConfig, UpdateRecord};
use tasks::TaskChange;

use crate::writer::{now_ns, Event, RolloutTiming, RunStart, UpdateData};
use crate::RunFiles;
use crate::{config_to_toml, RecordError};

/// Worker name of every rollout of the in-process runner.
pub(crate) const IN_PROCESS: &str = session::IN_PROCESS;

struct StartJob {
    name: String,
    seed: u64,
    update: u64,
    steps: usize,
    hp: Hyperparameters,
    initial: Distribution,
    basis: Option<Vec<f64>>,
    config_toml: String,
    settings: Vec<(String, f64)>,
    /// What the update before `update` ran with (a resumed run's); empty at update 0.
    previous_settings: Vec<(String, f64)>,
    resumed_from: Option<String>,
    /// `recording.split_mb`.
    split_mb: Option<u64>,
    /// `recording.step_costs`.
    step_costs: bool,
}

struct UpdateJob {
    hp: Hyperparameters,
    before: Distribution,
    after: Distribution,
    samples: ParameterBatch,
    costs: CostBatch,
    summary: UpdateSummary,
    settings: Vec<(String, f64)>,
    batch_start_ns: u64,
    batch_end_ns: u64,
    rollouts: Vec<RolloutTiming>,
}

enum Job {
    Start(Box<StartJob>),
    TaskChange(u64, String, f64),
    Update(Box<UpdateJob>),
    Event(u64, Event, String),
}

/// Records a run through [`session::Observer`]. Observer hooks cannot fail: the first error
/// stops the recording and is returned by [`McapRecorder::finish`].
///
/// Each `/rollout` gets worker `"in-process"` and the wall-clock interval the executor measured
/// for it (the recorder asks for them, [`Observer::wants_rollout_times`]); `/update` carries the
/// update's wall-clock interval (from the end of the previous hook to this one).
pub struct McapRecorder {
    jobs: Option<Sender<Job>>,
    acks: Receiver<Ack>,
    thread: Option<JoinHandle<Result<(), RecordError>>>,
    path: PathBuf,
    config_text: Option<String>,
    resumed_from: Option<String>,
    /// A resumed run's settings of the update before its first ([`McapRecorder::resuming`]).
    previous_settings: Vec<(String, f64)>,
    hp: Option<Hyperparameters>,
    error: Option<RecordError>,
    /// An update handed to the writer whose flush has not been confirmed.
    in_flight: bool,
    last_ns: u64,
    updates: u64,
    update_index: u64,
    /// The update the run's recording begins at (a resumed run's first), once started.
    first_update: Option<u64>,
    /// Set by the writer at its first error, as it happens ([`McapRecorder::failure_flag`]).
    failed: Arc<AtomicBool>,
    patience: Patience,
}

/// What the writer reports: every update job is answered by exactly one `Flushed` or
/// `Skipped`; an error (of any job) is reported once, as `Failed`, before that answer.
enum Ack {
    Flushed,
    /// Not written: the recording has failed.
    Skipped,
    Failed(RecordError),
}

fn write_job(w: &mut RunFiles, job: Job, progress: bool) -> Result<(), RecordError> {
    match job {
        Job::Start(s) => {
            w.split_at_mb(s.split_mb);
            w.record_step_costs(s.step_costs);
            fn named(list: &[(String, f64)]) -> Vec<(&str, f64)> {
                list.iter().map(|(n, v)| (n.as_str(), *v)).collect()
            }
            let (settings, previous) = (named(&s.settings), named(&s.previous_settings));
            w.write_start(&RunStart {
                name: &s.name,
                seed: s.seed,
                update: s.update,
                steps: s.steps,
                hyperparameters: &s.hp,
                initial: &s.initial,
                basis_activations: s.basis.as_deref(),
                config_toml: &s.config_toml,
                executor: IN_PROCESS,
                task_settings: &settings,
                previous_task_settings: &previous,
                resumed_from: s.resumed_from.as_deref(),
                part: None,
                run_id: None,
                recorder_restart: None,
            })?;
            w.write_event(
                s.update,
                Event::Start,
                IN_PROCESS,
                std::process::id(),
                &format!("run {} started (seed {})", s.name, s.seed),
            )
        }
        Job::TaskChange(u, name, value) => w.write_task_change(u, &name, value),
        Job::Event(u, event, message) => {
            w.write_event(u, event, IN_PROCESS, std::process::id(), &message)
        }
        Job::Update(j) => {
            let settings: Vec<(&str, f64)> =
                j.settings.iter().map(|(n, v)| (n.as_str(), *v)).collect();
            w.write_update(&UpdateData {
                hyperparameters: &j.hp,
                before: &j.before,
                after: &j.after,
                samples: &j.samples,
                costs: &j.costs,
                summary: &j.summary,
                task_settings: &settings,
                batch_start_ns: j.batch_start_ns,
                batch_end_ns: j.batch_end_ns,
                rollouts: &j.rollouts,
                default_worker: IN_PROCESS,
            })?;
            if progress {
                use std::io::Write;
                let mut out = std::io::stdout().lock();
                let _ = writeln!(out, "recorded update {}", j.summary.update);
                let _ = out.flush();
            }
            Ok(())
        }
    }
}

/// How long a thread polls for what it waits for before it sleeps: longer than the writer takes
/// for an update of most runs (16 µs for A1's, 43 µs for T-ball's, to a file).
const POLL: Duration = Duration::from_micros(100);

/// Receives by polling for up to [`POLL`] while the last waits were that short, by sleeping
/// otherwise: a run of slow rollouts, whose waits are long, does not burn a core polling
/// (one missed poll, and it sleeps until a wait is short again).
#[derive(Debug, Default)]
struct Patience {
    poll: bool,
}

impl Patience {
    fn recv<T>(&mut self, rx: &Receiver<T>) -> Result<T, RecvError> {
        let start = Instant::now();
        if self.poll {
            loop {
                match rx.try_recv() {
                    Ok(v) => return Ok(v),
                    Err(TryRecvError::Disconnected) => return Err(RecvError),
                    Err(TryRecvError::Empty) if start.elapsed() >= POLL => break,
                    Err(TryRecvError::Empty) => std::hint::spin_loop(),
                }
            }
        }
        let got = rx.recv();
        self.poll = start.elapsed() < POLL;
        got
    }
}

/// Writes jobs until the recorder drops its sender, then finishes the file. After the first
/// error nothing more is written (update jobs are answered `Skipped`) and the error is returned.
fn writer_thread(
    mut w: RunFiles,
    jobs: Receiver<Job>,
    acks: Sender<Ack>,
    progress: bool,
    failed_flag: Arc<AtomicBool>,
) -> Result<(), RecordError> {
    let mut failed = false;
    let mut patience = Patience::default();
    while let Ok(job) = patience.recv(&jobs) {
        let is_update = matches!(job, Job::Update(_));
        if failed {
            if is_update {
                let _ = acks.send(Ack::Skipped);
            }
            continue;
        }
        match write_job(&mut w, job, progress) {
            Ok(()) if is_update => {
                let _ = acks.send(Ack::Flushed);
            }
            Ok(()) => {}
            Err(e) => {
                failed = true;
                failed_flag.store(true, Ordering::SeqCst);
                let _ = acks.send(Ack::Failed(e));
                if is_update {
                    let _ = acks.send(Ack::Skipped);
                }
            }
        }
    }
    if failed {
        return Ok(());
    }
    w.finish().map(|_| ())
}

impl McapRecorder {
    /// Creates (truncates) the recording at `path` and starts its writer thread.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        Self::create_with_progress(path, false)
    }

    /// As [`McapRecorder::create`]; with `progress`, the writer prints `recorded update U` on
    /// stdout once update U is flushed to the file.
    pub fn create_with_progress(path: &Path, progress: bool) -> Result<Self, RecordError> {
        let w = RunFiles::create(path)?;
        let (jobs_tx, jobs_rx) = channel();
        let (acks_tx, acks_rx) = channel();
        let failed = Arc::new(AtomicBool::new(false));
        let flag = failed.clone();
        let thread = std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || writer_thread(w, jobs_rx, acks_tx, progress, flag))
            .map_err(|e| RecordError::io(path, e))?;
        Ok(Self {
            jobs: Some(jobs_tx),
            acks: acks_rx,
            thread: Some(thread),
            path: path.to_path_buf(),
            config_text: None,
            resumed_from: None,
            previous_settings: Vec::new(),
            hp: None,
            error: None,
            in_flight: false,
            last_ns: now_ns(),
            updates: 0,
            update_index: 0,
            first_update: None,
            failed,
            patience: Patience::default(),
        })
    }

    /// Records this text as the run's config instead of one rendered from the parsed config
    /// (keeps the user's comments and formatting).
    pub fn with_config_text(mut self, text: impl Into<String>) -> Self {
        self.config_text = Some(text.into());
        self
    }

    /// Records a run resumed at `start`: names the recording it resumes (metadata
    /// `resumed_from`) and, in `/run`, what the update before its first ran with, so that a
    /// resume from this recording before it holds an update goes on as this run would.
    pub fn resuming(mut self, start: &session::Start) -> Self {
        self.resumed_from = Some(start.origin.clone());
        let names: Vec<&str> = start.settings.iter().map(|(n, _)| n.as_str()).collect();
        let in_force: Vec<f64> = start.settings.iter().map(|(_, v)| *v).collect();
        self.previous_settings = names
            .iter()
            .map(|n| n.to_string())
            .zip(start.ran_with_values(&names, &in_force))
            .collect();
        self
    }

    /// Updates confirmed flushed so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The first error reported by the writer so far, if recording has failed.
    pub fn error(&self) -> Option<&RecordError> {
        self.error.as_ref()
    }

    /// True from the moment the writer fails (a full disk, an I/O error), before any hook
    /// notices it: an executor that stops on it does not run on unrecorded (on a robot, for
    /// real) until its end, which is when [`McapRecorder::finish`] reports the error.
    pub fn failure_flag(&self) -> Arc<AtomicBool> {
        self.failed.clone()
    }

    /// Records a health event (e.g. the executor failed) on `/log`.
    pub fn log_event(&mut self, event: Event, message: &str) {
        let u = self.update_index;
        self.send(Job::Event(u, event, message.to_string()));
    }

    /// Hands a job to the writer; false if it was not (the recording has failed).
    fn send(&mut self, job: Job) -> bool {
        if self.error.is_some() {
            return false;
        }
        let Some(tx) = &self.jobs else {
            return false;
        };
        if tx.send(job).is_err() {
            // The writer has stopped; finish() returns why.
            self.jobs = None;
            return false;
        }
        true
    }

    /// Waits for the writer's answer to the update in flight, and collects its errors so far.
    fn wait_flushed(&mut self) {
        while self.in_flight {
            match self.patience.recv(&self.acks) {
                Ok(ack) => self.take(ack),
                // The writer has stopped; close() reports why.
                Err(_) => self.in_flight = false,
            }
        }
        while let Ok(ack) = self.acks.try_recv() {
            self.take(ack);
        }
    }

    fn take(&mut self, ack: Ack) {
        match ack {
            Ack::Flushed => {
                self.updates += 1;
                self.in_flight = false;
            }
            Ack::Skipped => self.in_flight = false,
            Ack::Failed(e) => {
                self.error.get_or_insert(e);
            }
        }
    }

    fn close(&mut self) -> Result<(), RecordError> {
        self.wait_flushed();
        self.jobs = None; // ends the writer's job loop
        if let Some(t) = self.thread.take() {
            let joined = t.join();
            while let Ok(ack) = self.acks.try_recv() {
                self.take(ack);
            }
            match joined {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    self.error.get_or_insert(e);
                }
                Err(_) => {
                    self.error.get_or_insert(RecordError::invalid(
                        self.path.clone(),
                        "the writer thread panicked",
                    ));
                }
            }
        }
        Ok(())
    }

    /// Finishes the file (if `on_finish` has not) and returns the number of updates recorded,
    /// or the first error of the recording.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.close()?;
        match self.error.take() {
            Some(e) => {
                // A split recording's earlier parts were finished as the next began: the one
                // to recover is the last there is (one that holds nothing, created as the disk
                // filled up, holds none of the updates).
                let parts: Vec<PathBuf> = crate::recording_parts(&self.path)
                    .into_iter()
                    .filter(|p| p.is_file() && !crate::recover::holds_nothing(p).unwrap_or(false))
                    .collect();
                let last = parts.last().unwrap_or(&self.path);
                let finished = crate::reader::has_summary(last).unwrap_or(false);
                Err(RecordError::Stopped {
                    file: self.path.clone(),
                    cause: e.to_string(),
                    first: self.first_update.unwrap_or(0),
                    updates: self.updates,
                    parts: parts.len(),
                    unfinished: (!finished).then(|| last.clone()),
                })
            }
            None => Ok(self.updates),
        }
    }
}

impl Drop for McapRecorder {
    fn drop(&mut self) {
        let _ = self.close();
    }
}

impl Observer for McapRecorder {
    fn wants_rollout_times(&self) -> bool {
        true
    }

    fn on_start(
        &mut self,
        config: &RunConfig,
        optimizer: &Optimizer,
        settings: &[(&'static str, f64)],
    ) {
        let text = self
            .config_text
            .clone()
            .unwrap_or_else(|| config_to_toml(config));
        let hp = optimizer.hyperparameters().clone();
        // Basis activations are a property of the policy; rebuilding the task is cheap and keeps
        // the recording self-contained for recomputing basis-activation averaging.
        let basis = config.build_task().ok().and_then(|t| t.basis_activations());
        self.update_index = optimizer.update_index();
        self.first_update = Some(optimizer.update_index());
        self.send(Job::Start(Box::new(StartJob {
            name: config.run.name.clone(),
            seed: optimizer.seed(),
            update: optimizer.update_index(),
            steps: optimizer.steps(),
            hp: hp.clone(),
            initial: optimizer.distribution().clone(),
            basis,
            config_toml: text,
            settings: settings.iter().map(|(n, v)| (n.to_string(), *v)).collect(),
            previous_settings: self.previous_settings.clone(),
            resumed_from: self.resumed_from.clone(),
            split_mb: config.recording_split_mb(),
            step_costs: config.recording_step_costs(),
        })));
        self.hp = Some(hp);
        self.last_ns = now_ns();
    }

    fn on_task_change(&mut self, update: u64, change: &TaskChange) {
        self.send(Job::TaskChange(update, change.name.clone(), change.value));
    }

    fn on_rerun(&mut self, rerun: &Rerun<'_>) {
        self.send(Job::Event(rerun.update, Event::Warning, rerun.message()));
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
        // Update u − 1 must be in the file before u is handed over: at most one in flight.
        self.wait_flushed();
        self.in_flight = self.send(Job::Update(Box::new(UpdateJob {
            hp,
            before: r.before.clone(),
            after: r.after.clone(),
            samples: r.samples.clone(),
            costs: r.costs.clone(),
            summary: r.summary.clone(),
            settings: r
                .task_settings
                .iter()
                .map(|(n, v)| (n.to_string(), *v))
                .collect(),
            batch_start_ns: start,
            batch_end_ns: end,
            rollouts: r
                .rollout_times
                .iter()
                .map(|&(start_ns, end_ns)| RolloutTiming {
                    worker: IN_PROCESS.to_string(),
                    start_ns,
                    end_ns,
                })
                .collect(),
        })));
        self.update_index = r.summary.update + 1;
        self.last_ns = now_ns();
    }

    fn on_finish(&mut self, optimizer: &Optimizer) {
        self.wait_flushed();
        let n = self.updates;
        self.send(Job::Event(
            optimizer.update_index(),
            Event::Exit,
            format!("run finished after {n} recorded updates"),
        ));
        let _ = self.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patience_polls_only_while_waits_are_short_and_sees_a_closed_channel() {
        let (tx, rx) = channel();
        let mut patience = Patience::default();
        tx.send(1).unwrap();
        assert_eq!(patience.recv(&rx), Ok(1));
        assert!(patience.poll, "a wait that ended at once polls next time");
        let late = std::thread::spawn({
            let tx = tx.clone();
            move || {
                std::thread::sleep(POLL * 50);
                tx.send(2).unwrap();
            }
        });
        assert_eq!(patience.recv(&rx), Ok(2));
        assert!(!patience.poll, "a wait longer than POLL sleeps next time");
        late.join().unwrap();
        // A wait that ends at once polls again (a few tries: a loaded machine may preempt the
        // thread between the two clock readings for longer than POLL).
        let polls_again = (3..8).any(|i| {
            tx.send(i).unwrap();
            patience.recv(&rx) == Ok(i) && patience.poll
        });
        assert!(polls_again);
        drop(tx);
        assert_eq!(
            patience.recv(&rx),
            Err(RecvError),
            "polling ends at a closed channel"
        );
    }
}
