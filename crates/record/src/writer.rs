//! The low-level writer: one MCAP file per run, protobuf messages on fixed topics, a zstd chunk
//! closed and flushed to the OS after every update (or, its output held, with the updates
//! after it at the next flush: the pipeline's recorder hands a round over at once). Both the
//! in-process [`crate::McapRecorder`] and the pipeline's recorder process write through it.

use std::collections::BTreeMap;
use std::io::{Seek, SeekFrom, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::reserve::ReservingFile;
use crate::seek_buffer::SeekBuffer;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata};
use mcap::{Compression, WriteOptions};
use pi2cma::{CostBatch, Distribution, Hyperparameters, ParameterBatch, UpdateSummary};
use prost::Message;

use crate::convert::{distribution_to_proto, hyperparameters_to_proto};
use crate::{proto, topics, RecordError, DESCRIPTORS};

/// Wall-clock time in ns since the Unix epoch: the `log_time` of every message of every process.
pub fn now_ns() -> u64 {
    wire::wall_clock_ns()
}

fn timestamp(ns: u64) -> prost_types::Timestamp {
    prost_types::Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

/// Who ran one rollout and when (wall-clock ns; 0 = not timed).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RolloutTiming {
    /// The worker's name (e.g. `worker-0`, or `in-process`).
    pub worker: String,
    /// When the rollout started.
    pub start_ns: u64,
    /// When it ended.
    pub end_ns: u64,
}

/// What a run records once, at its start.
#[derive(Debug, Clone)]
pub struct RunStart<'a> {
    /// The run's name (`[run] name`).
    pub name: &'a str,
    /// The run's seed.
    pub seed: u64,
    /// The update the run starts (or resumes) at.
    pub update: u64,
    /// Time steps per rollout.
    pub steps: usize,
    /// The hyperparameters the run starts with.
    pub hyperparameters: &'a Hyperparameters,
    /// The distribution update `update` samples from.
    pub initial: &'a Distribution,
    /// Row-major N × P, if the task has basis activations.
    pub basis_activations: Option<&'a [f64]>,
    /// The config as TOML text.
    pub config_toml: &'a str,
    /// "in-process" or "pipeline".
    pub executor: &'a str,
    /// What update `update` runs with (its distribution's settings).
    pub task_settings: &'a [(&'a str, f64)],
    /// What update `update` − 1 ran with; empty when there is none or it is not known.
    pub previous_task_settings: &'a [(&'a str, f64)],
    /// The recording a resumed run continues (metadata `resumed_from`).
    pub resumed_from: Option<&'a str>,
    /// For a part after the first of a split recording (`recording.split_mb`): its number (2, 3,
    /// …) and the file of the part before it (metadata `part`, `previous_part`).
    pub part: Option<(u32, &'a str)>,
    /// The pipeline run's id (metadata `run_id`, hex): what ties the parts of a recording whose
    /// recorder was restarted across the updates it did not record.
    pub run_id: Option<u64>,
    /// For the part a restarted pipeline recorder begins: how many restarts (metadata
    /// `recorder_restart`).
    pub recorder_restart: Option<u32>,
}

/// Everything about one finished update.
#[derive(Debug, Clone)]
pub struct UpdateData<'a> {
    /// The hyperparameters the update ran with.
    pub hyperparameters: &'a Hyperparameters,
    /// The distribution the update sampled from.
    pub before: &'a Distribution,
    /// The distribution it computed.
    pub after: &'a Distribution,
    /// The K parameter samples (K × P).
    pub samples: &'a ParameterBatch,
    /// The K cost trajectories (K × steps).
    pub costs: &'a CostBatch,
    /// The core's summary of the update (eval cost, exploration costs, λ).
    pub summary: &'a UpdateSummary,
    /// The task settings the update's rollouts ran with (setting, value).
    pub task_settings: &'a [(&'a str, f64)],
    /// Wall-clock interval of the update as seen by the caller (ns since the Unix epoch):
    /// start.
    pub batch_start_ns: u64,
    /// End of that interval.
    pub batch_end_ns: u64,
    /// One per rollout, in rollout order; if shorter (e.g. empty), the missing rollouts are
    /// recorded with worker `default_worker` and no timing.
    pub rollouts: &'a [RolloutTiming],
    /// The worker named for rollouts `rollouts` does not cover.
    pub default_worker: &'a str,
}

/// A health event, recorded as a `foxglove.Log` message on `/log`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// A process (or the run) started.
    Start,
    /// A process ended as asked (the run finished or stopped).
    Exit,
    /// A process died unexpectedly (a panic, a signal, a failed run).
    Crash,
    /// A process was started again after a crash.
    Restart,
    /// Workers were added or removed (a scale-down stops one).
    Scale,
    /// Anything else worth knowing (e.g. a recorder catching up).
    Info,
    /// Something went wrong that is not a process crash (e.g. lost messages, a failed run).
    Error,
    /// Something that may be going wrong (e.g. a run without updates for a while).
    Warning,
}

impl Event {
    pub(crate) fn as_str(self) -> &'static str {
        match self {
            Event::Start => "start",
            Event::Exit => "exit",
            Event::Crash => "crash",
            Event::Restart => "restart",
            Event::Scale => "scale",
            Event::Info => "info",
            Event::Error => "error",
            Event::Warning => "warning",
        }
    }

    fn level(self) -> proto::foxglove::log::Level {
        use proto::foxglove::log::Level;
        match self {
            Event::Crash | Event::Error => Level::Error,
            Event::Restart | Event::Warning => Level::Warning,
            _ => Level::Info,
        }
    }
}

/// zstd's level −1000: a "fast" level whose match finder, after a miss, skips ~1000 bytes, so a
/// chunk is stored nearly as it is, in an ordinary zstd frame every reader decodes. The messages
/// hardly compress (mostly f64 step costs and samples): level −1 made A1's 13.6 kB updates 8 %
/// smaller than this but took ~6 µs more per update (`cargo bench -p record --bench
/// write_update`: 15.5–21 against 10–13.5 µs per update without the `write`), and the
/// recorder's CPU is what recording costs a busy machine. The `mcap` crate takes the level as
/// `u32` and hands it to zstd as `i32`, so the level is written as its two's complement.
const ZSTD_LEVEL: u32 = (-1000i32).cast_unsigned();

/// What the `mcap` writer writes to: `W`, its flushes passed on only while `passes` (they are
/// held while [`RunWriter::hold_output`] is in force, between [`RunWriter::flush`]es).
struct FlushGate<W> {
    inner: W,
    passes: Arc<AtomicBool>,
}

impl<W: Write> Write for FlushGate<W> {
    fn write(&mut self, data: &[u8]) -> std::io::Result<usize> {
        self.inner.write(data)
    }

    fn write_all(&mut self, data: &[u8]) -> std::io::Result<()> {
        self.inner.write_all(data)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.passes.load(Ordering::Relaxed) {
            self.inner.flush()
        } else {
            Ok(())
        }
    }
}

impl<W: Seek> Seek for FlushGate<W> {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(to)
    }

    fn stream_position(&mut self) -> std::io::Result<u64> {
        self.inner.stream_position()
    }
}

/// Channel ids of the topics, in [`topics::ALL`] order.
struct Channels([u16; topics::ALL.len()]);

/// `/update`'s place in [`topics::ALL`].
const CHANNEL_UPDATE: usize = 1;

/// `Update.cost_per_step`'s field number in `record.proto`.
const COST_PER_STEP_FIELD: u32 = 10;

/// Writes one run's MCAP. Every `write_*` call encodes and appends; [`RunWriter::write_update`]
/// also closes the chunk and flushes it to the OS. Dropping the writer finishes the file (summary
/// and indexes); call [`RunWriter::finish`] to see errors.
pub struct RunWriter<W: Write + Seek> {
    mcap: mcap::Writer<FlushGate<W>>,
    /// Whether the `mcap` writer's flushes reach `W` (see [`RunWriter::hold_output`]).
    passes: Arc<AtomicBool>,
    held: bool,
    /// Bytes of messages written since the last [`RunWriter::flush`], before compression.
    held_bytes: u64,
    file: PathBuf,
    channels: Channels,
    sequence: u32,
    buf: Vec<u8>,
    /// Bytes of messages written, before compression.
    bytes: u64,
    /// Whether `/update` carries the K × N step costs ([`RunWriter::record_step_costs`]).
    step_costs: bool,
}

/// What [`RunWriter::create`] writes to: the file (reserving its blocks ahead) behind a buffer
/// that serves the `mcap` writer's per-chunk seeks from memory (one `write` per flush).
pub type FileSink = SeekBuffer<ReservingFile>;

impl RunWriter<FileSink> {
    /// Creates (truncates) `path`, holding an exclusive advisory lock on it until the writer is
    /// dropped (or its process dies, even by SIGKILL): `recover` and `--resume` see a recording
    /// that is still being written ([`crate::being_written`]) and leave it alone, and a second
    /// writer of the same file is refused before it truncates it.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        let f = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)
            .map_err(|e| RecordError::io(path, e))?;
        // A reader's probe (`being_written`, e.g. a `watch mcap-tool info`) holds a shared lock
        // for a moment: only a lock held for 100 ms is another writer's.
        let mut tries = 0;
        loop {
            match f.try_lock() {
                Ok(()) => break,
                Err(std::fs::TryLockError::WouldBlock) if tries < 10 => {
                    tries += 1;
                    std::thread::sleep(std::time::Duration::from_millis(10));
                }
                Err(std::fs::TryLockError::WouldBlock) => {
                    return Err(RecordError::written_elsewhere(path))
                }
                // A file system without flock (some NFS mounts): recording matters more than
                // the lock, which only keeps recover and --resume off a live file.
                Err(std::fs::TryLockError::Error(e)) => {
                    eprintln!(
                        "warning: {}: cannot lock it ({e}); recording without the lock, so \
                         `recover` and `--resume` cannot tell that it is being written",
                        path.display()
                    );
                    break;
                }
            }
        }
        f.set_len(0).map_err(|e| RecordError::io(path, e))?;
        Self::new(SeekBuffer::new(ReservingFile::new(f)), path)
    }
}

impl<W: Write + Seek> RunWriter<W> {
    /// `file` only names the destination in error messages.
    pub fn new(w: W, file: impl Into<PathBuf>) -> Result<Self, RecordError> {
        let file = file.into();
        let opts = WriteOptions::new()
            .compression(Some(Compression::Zstd))
            .compression_level(ZSTD_LEVEL)
            .compression_threads(0)
            // Chunks are closed by the flush after every update; this bound only matters for
            // very large updates.
            .chunk_size(Some(8 << 20))
            .profile("")
            .library(concat!("pi2cma-record/", env!("CARGO_PKG_VERSION")));
        let passes = Arc::new(AtomicBool::new(true));
        let gate = FlushGate {
            inner: w,
            passes: Arc::clone(&passes),
        };
        let mut mcap = opts
            .create(gate)
            .map_err(|e| RecordError::mcap(file.clone(), e))?;
        let mut ids = [0u16; topics::ALL.len()];
        for (i, (topic, schema)) in topics::ALL.iter().enumerate() {
            let schema_id = mcap
                .add_schema(schema, "protobuf", DESCRIPTORS)
                .map_err(|e| RecordError::mcap(file.clone(), e))?;
            ids[i] = mcap
                .add_channel(schema_id, topic, "protobuf", &BTreeMap::new())
                .map_err(|e| RecordError::mcap(file.clone(), e))?;
        }
        Ok(Self {
            mcap,
            passes,
            held: false,
            held_bytes: 0,
            file,
            channels: Channels(ids),
            sequence: 0,
            buf: Vec::new(),
            bytes: 0,
            step_costs: true,
        })
    }

    /// Bytes of messages written so far, before compression (what `recording.split_mb` bounds).
    pub(crate) fn bytes_written(&self) -> u64 {
        self.bytes
    }

    /// Bytes of messages written since the last [`RunWriter::flush`], before compression: what
    /// a held output ([`RunWriter::hold_output`]) keeps in memory, about.
    pub(crate) fn held_bytes(&self) -> u64 {
        self.held_bytes
    }

    fn mcap_err(&self, e: mcap::McapError) -> RecordError {
        RecordError::mcap(self.file.clone(), e)
    }

    fn put<M: Message>(
        &mut self,
        channel: usize,
        log_time: u64,
        msg: &M,
    ) -> Result<(), RecordError> {
        self.encode(msg)?;
        self.write_buf(channel, log_time)
    }

    fn encode<M: Message>(&mut self, msg: &M) -> Result<(), RecordError> {
        self.buf.clear();
        msg.encode(&mut self.buf)
            .map_err(|e| RecordError::invalid(self.file.clone(), format!("encode: {e}")))
    }

    /// `/update` with its step costs (`cost_per_step`, left empty in `msg`) appended as one
    /// packed field, copied row by row from the batch. Most of a T-ball update's 88 kB are
    /// step costs: a K × N `Vec` handed to prost, which writes a packed double one at a time,
    /// took 34 µs per update, this 5 (the recorder's CPU is what recording costs a busy
    /// machine). Protobuf decoders take fields in any order.
    fn put_with_step_costs(
        &mut self,
        log_time: u64,
        msg: &proto::Update,
        costs: &CostBatch,
    ) -> Result<(), RecordError> {
        debug_assert!(msg.cost_per_step.is_empty());
        self.encode(msg)?;
        let values = costs.rollouts() * costs.steps();
        if values > 0 {
            prost::encoding::encode_key(
                COST_PER_STEP_FIELD,
                prost::encoding::WireType::LengthDelimited,
                &mut self.buf,
            );
            prost::encoding::encode_varint(8 * values as u64, &mut self.buf);
            let start = self.buf.len();
            self.buf.resize(start + 8 * values, 0);
            // Row by row: over one row's slice the loop compiles to vector moves; through a
            // flat_map over all rows it moved one double at a time, its iterator state on the
            // stack (9.7 → 9.1 µs per A1 update for the whole writer, `write_update` bench).
            let rows = self.buf[start..].chunks_exact_mut(8 * costs.steps());
            for (row, r) in rows.zip(0..costs.rollouts()) {
                for (to, v) in row.chunks_exact_mut(8).zip(costs.per_step(r)) {
                    to.copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        self.write_buf(CHANNEL_UPDATE, log_time)
    }

    fn write_buf(&mut self, channel: usize, log_time: u64) -> Result<(), RecordError> {
        self.sequence = self.sequence.wrapping_add(1);
        self.bytes += self.buf.len() as u64;
        self.held_bytes += self.buf.len() as u64;
        let header = MessageHeader {
            channel_id: self.channels.0[channel],
            sequence: self.sequence,
            log_time,
            publish_time: log_time,
        };
        self.mcap
            .write_to_known_channel(&header, &self.buf)
            .map_err(|e| RecordError::mcap(self.file.clone(), e))
    }

    /// The MCAP metadata record `pi2cma.run` (config TOML, seed, versions, …) and the `/run`
    /// message; flushed.
    pub fn write_start(&mut self, start: &RunStart<'_>) -> Result<(), RecordError> {
        let now = now_ns();
        let versions = versions();
        let mut meta = BTreeMap::new();
        meta.insert("name".to_string(), start.name.to_string());
        meta.insert("seed".to_string(), start.seed.to_string());
        meta.insert("first_update".to_string(), start.update.to_string());
        meta.insert("executor".to_string(), start.executor.to_string());
        meta.insert("config_toml".to_string(), start.config_toml.to_string());
        meta.insert("started_ns".to_string(), now.to_string());
        if let Some(from) = start.resumed_from {
            // Absolute: a path as typed, read later from another directory, names another
            // file (every run's default is runs/latest/run.mcap).
            let from = std::path::absolute(from)
                .map_or_else(|_| from.to_string(), |p| p.display().to_string());
            meta.insert("resumed_from".to_string(), from);
        }
        if let Some((part, previous)) = start.part {
            meta.insert("part".to_string(), part.to_string());
            meta.insert("previous_part".to_string(), previous.to_string());
        }
        if let Some(id) = start.run_id {
            meta.insert("run_id".to_string(), format!("{id:016x}"));
        }
        if let Some(n) = start.recorder_restart {
            meta.insert("recorder_restart".to_string(), n.to_string());
        }
        for (k, v) in &versions {
            meta.insert(format!("version.{k}"), v.clone());
        }
        self.mcap
            .write_metadata(&Metadata {
                name: topics::METADATA.to_string(),
                metadata: meta,
            })
            .map_err(|e| self.mcap_err(e))?;
        let info = proto::RunInfo {
            timestamp: Some(timestamp(now)),
            update: start.update,
            name: start.name.to_string(),
            seed: start.seed,
            dim: start.initial.dim() as u32,
            steps: start.steps as u32,
            hyperparameters: Some(hyperparameters_to_proto(start.hyperparameters)),
            initial: Some(distribution_to_proto(start.initial)),
            basis_activations: start
                .basis_activations
                .map(<[f64]>::to_vec)
                .unwrap_or_default(),
            config_toml: start.config_toml.to_string(),
            executor: start.executor.to_string(),
            task_settings: settings(start.task_settings),
            previous_task_settings: settings(start.previous_task_settings),
            versions: versions
                .into_iter()
                .map(|(key, value)| proto::KeyValue { key, value })
                .collect(),
        };
        self.put(0, now, &info)?;
        self.flush()
    }

    /// From now on, [`RunWriter::write_update`] closes the update's chunk but keeps its bytes
    /// in memory until [`RunWriter::flush`]: the pipeline's recorder, which takes updates in
    /// rounds, hands a round to the OS with one `write`. The page cache costs less per byte
    /// in larger writes (on ext4, 300 MB written with `dd`: 0.15 s of system time in writes
    /// of 15 kB, an A1 update; 0.08 s in 75 kB, 0.05 s in 256 kB), and that system time was a
    /// quarter of the recorder's CPU (`perf`, A1 at full speed).
    pub fn hold_output(&mut self) {
        self.held = true;
        self.passes.store(false, Ordering::Relaxed);
    }

    /// With `false` (`recording.step_costs = false`), `/update` leaves `cost_per_step` empty:
    /// a T-ball update's 91.5 kB become ~11 kB, an A1 update's 15 kB ~3 kB. Each rollout's
    /// terminal and total cost are still recorded, and with episodic weighting, which weighs
    /// rollouts by their totals alone, every update is still recomputed exactly from them.
    pub fn record_step_costs(&mut self, on: bool) {
        self.step_costs = on;
    }

    /// `/update`, `/summary` and one `/rollout` per rollout, then a flush: after this returns,
    /// the update survives a SIGKILL of this process (after the next [`RunWriter::flush`] if
    /// the output is held).
    pub fn write_update(&mut self, u: &UpdateData<'_>) -> Result<(), RecordError> {
        let now = now_ns();
        let s = u.summary;
        let k = u.costs.rollouts();
        let n = u.costs.steps();
        if u.samples.rollouts != k || u.samples.update != s.update {
            return Err(RecordError::Update {
                file: self.file.clone(),
                update: s.update,
                what: format!(
                    "samples are of update {} with {} rollouts, costs have {k} rollouts",
                    u.samples.update, u.samples.rollouts
                ),
            });
        }
        let terminal: Vec<f64> = (0..k).map(|r| u.costs.terminal(r)).collect();
        let totals: Vec<f64> = (0..k).map(|r| u.costs.total(r)).collect();
        let after = distribution_to_proto(u.after);
        let msg = proto::Update {
            timestamp: Some(timestamp(now)),
            update: s.update,
            seed: u.samples.seed,
            hyperparameters: Some(hyperparameters_to_proto(u.hyperparameters)),
            before: Some(distribution_to_proto(u.before)),
            rollouts: k as u32,
            dim: u.samples.dim as u32,
            steps: n as u32,
            samples: u.samples.values.clone(),
            // Appended by `put_with_step_costs`, straight from the batch.
            cost_per_step: Vec::new(),
            cost_terminal: terminal,
            weights: s.weights.clone(),
            after: Some(after.clone()),
            eval_cost: s.eval_cost,
            exploration_cost_mean: s.exploration_cost_mean,
            exploration_cost_std: s.exploration_cost_std,
            lambda: s.lambda,
            lambda_next: s.lambda_next,
            task_settings: settings(u.task_settings),
            batch_start_ns: u.batch_start_ns,
            batch_end_ns: u.batch_end_ns,
            cost_total: totals,
        };
        if self.step_costs {
            self.put_with_step_costs(now, &msg, u.costs)?;
        } else {
            self.put(CHANNEL_UPDATE, now, &msg)?;
        }
        let totals = msg.cost_total;
        let summary = proto::UpdateSummary {
            timestamp: Some(timestamp(now)),
            update: s.update,
            eval_cost: s.eval_cost,
            exploration_cost_mean: s.exploration_cost_mean,
            exploration_cost_std: s.exploration_cost_std,
            lambda: s.lambda,
            lambda_next: s.lambda_next,
            mean: after.mean,
        };
        self.put(2, now, &summary)?;
        // One message refilled for every rollout: its worker name keeps its allocation.
        let mut msg = proto::Rollout {
            timestamp: Some(timestamp(now)),
            update: s.update,
            ..Default::default()
        };
        for r in 0..k {
            let (worker, start_ns, end_ns) = match u.rollouts.get(r) {
                Some(t) => (t.worker.as_str(), t.start_ns, t.end_ns),
                None => (u.default_worker, 0, 0),
            };
            msg.rollout = r as u32;
            msg.worker.clear();
            msg.worker.push_str(worker);
            msg.start_ns = start_ns;
            msg.end_ns = end_ns;
            msg.total_cost = totals[r];
            self.put(3, now, &msg)?;
        }
        self.end_chunk()
    }

    /// `/task_change`: setting `name` became `value` before update `update`.
    pub(crate) fn write_task_change(
        &mut self,
        update: u64,
        name: &str,
        value: f64,
    ) -> Result<(), RecordError> {
        let now = now_ns();
        let msg = proto::TaskChange {
            timestamp: Some(timestamp(now)),
            update,
            name: name.to_string(),
            value,
        };
        self.put(4, now, &msg)
    }

    /// `/unfinished_update`: the settings update `update` was to run with, its distribution
    /// published but the update not complete when the run stopped; `not_begun`: the run
    /// stopped before it, on request.
    pub(crate) fn write_unfinished_update(
        &mut self,
        update: u64,
        task_settings: &[(&str, f64)],
        not_begun: bool,
    ) -> Result<(), RecordError> {
        let now = now_ns();
        let msg = proto::UnfinishedUpdate {
            timestamp: Some(timestamp(now)),
            update,
            task_settings: settings(task_settings),
            not_begun,
        };
        self.put(6, now, &msg)
    }

    /// `/log`: a health event about process `name` during update `update`.
    pub fn write_event(
        &mut self,
        update: u64,
        event: Event,
        name: &str,
        pid: u32,
        message: &str,
    ) -> Result<(), RecordError> {
        let now = now_ns();
        let msg = proto::Log {
            timestamp: Some(timestamp(now)),
            level: event.level() as i32,
            message: message.to_string(),
            name: name.to_string(),
            file: String::new(),
            line: 0,
            update,
            event: event.as_str().to_string(),
            pid,
        };
        self.put(5, now, &msg)
    }

    /// Closes the current chunk and hands it, and any held before it, to the OS.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.passes.store(true, Ordering::Relaxed);
        let flushed = self.mcap.flush().map_err(|e| self.mcap_err(e));
        self.passes.store(!self.held, Ordering::Relaxed);
        self.held_bytes = 0;
        flushed
    }

    /// Closes the current chunk; hands it to the OS unless the output is held.
    fn end_chunk(&mut self) -> Result<(), RecordError> {
        self.mcap.flush().map_err(|e| self.mcap_err(e))
    }

    /// Writes the summary section and indexes and flushes the destination (held output too);
    /// the file is then complete.
    pub fn finish(mut self) -> Result<(), RecordError> {
        // The `mcap` writer's last act is a flush of the destination.
        self.passes.store(true, Ordering::Relaxed);
        self.mcap.finish().map_err(|e| self.mcap_err(e))?;
        Ok(())
    }
}

impl<W: Write + Seek> Drop for RunWriter<W> {
    /// The `mcap` writer, dropped next, finishes the file (an error path that did not call
    /// [`RunWriter::finish`]); its closing flush must reach the destination even with the
    /// output held, or the held updates and the summary would be dropped with the buffer.
    fn drop(&mut self) {
        self.passes.store(true, Ordering::Relaxed);
    }
}

fn settings(s: &[(&str, f64)]) -> Vec<proto::Setting> {
    s.iter()
        .map(|(name, value)| proto::Setting {
            name: name.to_string(),
            value: *value,
        })
        .collect()
}

/// Versions recorded with every run.
pub(crate) fn versions() -> Vec<(String, String)> {
    let mut v = vec![
        ("record".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ("mcap-crate".to_string(), "0.26".to_string()),
        ("schema".to_string(), "pi2cma.record/1".to_string()),
    ];
    if let Some(commit) = option_env!("PI2CMA_GIT_COMMIT") {
        v.push(("git".to_string(), commit.to_string()));
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A held output keeps closed chunks from the file until the flush, which hands them all
    /// over, readable; without the hold every chunk reaches the file as it closes.
    #[test]
    fn a_held_output_reaches_the_file_at_the_flush() {
        let dir = std::env::temp_dir().join(format!("writer-held-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let len = |p: &Path| std::fs::metadata(p).unwrap().len();
        let logs = |p: &Path| {
            crate::read_recording(p)
                .unwrap()
                .logs
                .into_iter()
                .map(|l| l.message)
                .collect::<Vec<_>>()
        };
        for held in [false, true] {
            let path = dir.join(format!("held-{held}.mcap"));
            let mut w = RunWriter::create(&path).unwrap();
            if held {
                w.hold_output();
            }
            for m in ["first", "second"] {
                w.write_event(0, Event::Info, "test", 1, m).unwrap();
                w.end_chunk().unwrap();
            }
            if held {
                assert_eq!(len(&path), 0, "nothing written before the flush");
                assert!(w.held_bytes() > 0);
                w.flush().unwrap();
                assert_eq!(w.held_bytes(), 0);
            }
            assert!(len(&path) > 0);
            assert_eq!(logs(&path), ["first", "second"], "held: {held}");
            // Still held after the flush.
            let before = len(&path);
            w.write_event(0, Event::Info, "test", 1, "third").unwrap();
            w.end_chunk().unwrap();
            assert_eq!(len(&path) > before, !held, "held: {held}");
            w.finish().unwrap();
            assert_eq!(logs(&path), ["first", "second", "third"]);
            // Dropped without `finish` (an error path), held output and summary still land.
            let path = dir.join(format!("dropped-{held}.mcap"));
            let mut w = RunWriter::create(&path).unwrap();
            if held {
                w.hold_output();
            }
            w.write_event(0, Event::Info, "test", 1, "held").unwrap();
            w.end_chunk().unwrap();
            drop(w);
            let r = crate::read_recording(&path).unwrap();
            assert!(r.indexed, "held: {held}");
            assert_eq!(r.logs.len(), 1, "held: {held}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `put_with_step_costs` writes the field by its number: it must be the generated code's.
    #[test]
    fn step_costs_are_written_as_prost_writes_cost_per_step() {
        let steps = [0.25, -1.5, 3.0e-300, f64::MIN_POSITIVE];
        let mut costs = CostBatch::new(2, 2);
        costs.insert(0, &steps[..2], 7.0).unwrap();
        costs.insert(1, &steps[2..], 8.0).unwrap();
        let msg = proto::Update {
            update: 3,
            rollouts: 2,
            ..Default::default()
        };
        let mut w = RunWriter::new(std::io::Cursor::new(Vec::new()), "test.mcap").unwrap();
        w.encode(&msg).unwrap();
        let without = w.buf.clone();
        w.put_with_step_costs(1, &msg, &costs).unwrap();
        let mut with = msg.clone();
        with.cost_per_step = steps.to_vec();
        let mut expected = without;
        // prost writes fields in number order; ours come last, which decoders accept.
        let mut field = Vec::new();
        proto::Update {
            cost_per_step: steps.to_vec(),
            ..Default::default()
        }
        .encode(&mut field)
        .unwrap();
        expected.extend_from_slice(&field);
        assert_eq!(w.buf, expected);
        assert_eq!(proto::Update::decode(&w.buf[..]).unwrap(), with);
    }
}
