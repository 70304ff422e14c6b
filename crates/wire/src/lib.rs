//! The wire contract of the pi2cma pipeline: every message type, every service name and every
//! service's builder settings, in one place, so that every process — including a rollout worker
//! written in another language with iceoryx2's C, C++ or Python bindings — opens each service with
//! the same settings. README.md's "Wire layout" section restates it for those workers (names,
//! type names, sizes, C declarations); tests/readme.rs fails when the two differ.
//!
//! **Architecture Invariant:** this crate knows nothing of the update rule, tasks or configs. It
//! takes plain numbers ([`Limits`]) and returns iceoryx2 port factories. Nothing on the data paths
//! is serialised: payloads are `#[repr(C)]` structs and `f64` slices read and written in place in
//! shared memory.
//!
//! # Topology (publish-subscribe and event services only)
//!
//! All names start with `pi2cma/<run>/`, where `<run>` is the run id as 16 lower-case hex
//! digits, and all processes of a run use the per-run iceoryx2 config of [`iceoryx_config`]
//! (own `global.prefix` and root path), so two runs never see each other.
//!
//! | service | payload | user header | publishers → subscribers |
//! |---|---|---|---|
//! | `distribution` | `[f64]`: mean (P), then Σ (P×P, column-major) | [`DistributionHeader`] | updater → sampler, recorder |
//! | `work/<w>` | `[f64]`: θ (P) | [`WorkHeader`] | sampler → worker `w` (its inbox) |
//! | `costs` | `[f64]`: immediate costs (N) | [`CostHeader`] | workers → updater, recorder |
//! | `ready` | [`Ready`] | – | workers → sampler |
//! | `progress` | [`Progress`] | – | updater → supervisor |
//! | `recorded` | [`RecorderAck`] | – | recorder → updater, supervisor |
//! | `lifecycle` | [`Lifecycle`] | – | every process → supervisor, recorder |
//! | `joined` | [`Lifecycle`] | – | recorder → sampler |
//! | `control` | [`Control`] | – | supervisor → sampler, updater, recorder |
//! | `reruns` | `[u32]`: rejected executions per rollout (K) | [`RerunHeader`] | updater → sampler (only with `run.nonfinite_reruns` > 0) |
//! | `overdue` | [`Overdue`] | – | sampler → supervisor |
//! | `notes` | [`RunNote`] | – | supervisor → recorder |
//!
//! Every receiving process owns one event service, its doorbell: `wake/updater`,
//! `wake/sampler`, `wake/supervisor`, `wake/recorder`, `wake/worker/<w>`. A sender publishes its samples, then
//! notifies the receiver's doorbell once (event id [`WAKE`]); the receiver waits on its doorbell
//! (never spins), consumes all notifications, then drains its subscribers. Wait with the
//! listener's own `timed_wait`/`blocking_wait`, not by attaching it to a `WaitSet`: with
//! iceoryx2 0.10 a WaitSet-attached listener can miss a wake-up under concurrent notifiers (see
//! `pipeline::wait_loop`); a short timeout as a safety net costs nothing measurable.
//!
//! # Protocol of one update u
//!
//! 1. The updater publishes the distribution of update u ([`DistributionHeader::update`] = u) with
//!    the task settings in force for u, and rings `wake/sampler`.
//! 2. The sampler draws the K parameter vectors (a pure function of seed, u and k), and hands
//!    them out in chunks: each worker that announced [`Ready`] gets ⌈pending / workers⌉
//!    rollouts (pending as at the start of the hand-out; with slow rollouts, or none timed
//!    yet, no more than the sampler's `CHUNK_TIME` of them, so work stays queued for workers
//!    that join), one `work/<w>` sample per rollout, all with the same [`WorkHeader::chunk`];
//!    it rings the workers after publishing every chunk.
//! 3. The worker executes each θ and writes the N immediate costs straight into a loaned `costs`
//!    sample ([`CostHeader::terminal`] holds the terminal cost, [`CostHeader::settings`] the
//!    task settings it ran with: the work item's unless its task refused a change). After the
//!    last rollout of its chunk it publishes [`Ready`] with `chunk` = that chunk,
//!    then rings `wake/updater`, then rings `wake/sampler` unless the chunk carried
//!    [`WorkHeader::QUEUE_EMPTY`]. Ready goes out before the updater's bell: the updater may
//!    publish the next distribution as soon as it has the costs, and the sampler, woken by that,
//!    must find every finished worker's Ready. Within a long chunk the worker also rings
//!    `wake/updater` at least every millisecond, and, in a run with a rollout timeout, publishes
//!    [`Ready`] with [`Ready::ROLLOUT_DONE`] after a rollout that is not the chunk's last (at
//!    most every [`ROLLOUT_DONE_INTERVAL`], ringing nobody). A worker that has just started
//!    sends [`Ready`] with [`Ready::NO_CHUNK`] and rings `wake/sampler`.
//! 4. The updater stores cost (u, k) (duplicates and other updates are ignored, so a rollout may
//!    be executed twice after a worker crash), and when all K are in, tells the core and goes to 1.
//!    A cost that is not finite fails the run, unless `run.nonfinite_reruns` allows another
//!    execution of rollout k: then the updater publishes on `reruns` how many executions of
//!    each rollout of u it has rejected so far and rings `wake/sampler`, which hands out again
//!    every rollout whose count rose since the sample it read last (same θ,
//!    [`WorkHeader::RERUN`] set), and the update waits for them. A `reruns` sample is the whole
//!    state, not a request: a burst of rejections that overflows the sampler's buffer loses
//!    only samples that the newest one includes.
//!
//! # The recorder
//!
//! The MCAP recorder (crate `record`) is a spare subscriber of `distribution`, `costs`,
//! `control` and `lifecycle`, and the one subscriber of `notes`; it is woken on its own doorbell, `wake/recorder`, so no sender on
//! the data paths pays for it. It acknowledges on `recorded` ([`RecorderAck`]). The updater
//! applies back-pressure when a recorder was running at START (`recorded` has a publisher): it
//! publishes distribution u only while u − `next_update` < [`Limits::recorder_max_lag`],
//! and while the cost messages the recorder has not taken fit its buffer (reruns make more
//! than K per update; see [`RecorderAck`]), otherwise it rings `wake/recorder` with [`HOLD`]
//! and waits; the recorder acknowledges each update as soon as it is written and rings
//! `wake/updater` once half the lag bound is free (or at the end of its round, after an
//! acknowledgement of the cost messages it has taken). After publishing u, the updater rings `wake/recorder` if the
//! recorder has written everything before u − 1 (it may be asleep) and its last ring is a
//! millisecond ago, and once per acknowledgement when the recorder is half the lag bound
//! behind (so that it is not held at full speed); a busy recorder looks for new samples before
//! it sleeps. The
//! supervisor sends [`Control::RECORDER_LOST`] when the recorder exits and is not restarted, and
//! an updater held for a second also looks for a dead `recorder` node, so a dead recorder never
//! stalls the run. A recorder that dies mid-run is restarted (within `pipeline.restart_limit`):
//! the supervisor removes the dead node's ports, starts a recorder that continues the recording
//! in a new part, and once it has announced itself sends [`Control::RECORDER_BACK`]; the updater,
//! held meanwhile by the lag bound, counts the lag from the update at hand again. The new
//! recorder drops what its subscribers held when it announced itself and begins at the first
//! distribution after, whose costs all follow it. Before it stops a worker, the supervisor
//! sends [`Control::RECORDER_SYNC`] and waits (at most half of `pipeline.shutdown_timeout_ms`)
//! for an acknowledgement whose `synced` has reached it: the recorder has then connected to
//! the worker's ports, and iceoryx2 keeps what the worker sent for it after the worker exits.
//! A worker that crashes cannot be held so; instead the recorder, whenever it takes in a
//! worker's announcement on `lifecycle`, connects to every publisher there is and echoes the
//! announcement on `joined` (ringing `wake/sampler`), and so it does at its start for every
//! live worker that has a `costs` publisher then. The sampler hands a worker incarnation no
//! work until `joined` has echoed it (or a later incarnation of its slot), unless `joined` has
//! no publisher (no recorder, or a dead one cleaned up) or the supervisor reported
//! [`Control::RECORDER_LOST`]: whatever the worker then sends is kept for the recorder even if
//! the worker crashes.
//!
//! A worker that holds a chunk and sends no cost for longer than `pipeline.rollout_timeout_ms`
//! (it reports the rollouts it finishes within a chunk with [`Ready::ROLLOUT_DONE`]) is
//! reported by the sampler on `overdue` ([`Overdue`], once per incarnation, ringing
//! `wake/supervisor`); the supervisor kills it and reports it lost with [`lost::HUNG`].
//!
//! A worker that dies (or is scaled away) is reported by the supervisor on `control`
//! ([`Control::WORKER_LOST`]), announces a higher incarnation when restarted, or is found by the
//! sampler among the run's dead nodes (node name [`worker_node_name`]); the sampler hands the
//! rollouts of its chunk it did not report sent ([`Ready::rollout_done`]) to the others, and
//! those it did only if the update still waits for them once everything else is back (their
//! costs died with the worker). Because a
//! rollout's parameters depend only on (seed, u, k), the result is bit-identical whatever the
//! worker count, completion order or crashes.
//!
//! A foreign worker joins as worker `w` by: creating a node named [`worker_node_name`] with the
//! run's config, subscribing to `work/<w>`, listening on `wake/worker/<w>`, publishing on
//! `costs` and `ready` and notifying `wake/updater` and `wake/sampler`, then announcing itself
//! on `lifecycle` ([`Lifecycle`] with [`role::WORKER`], its slot and incarnation) and ringing
//! `wake/supervisor` (the supervisor waits for this before it starts a run or counts a worker
//! in), then sending [`Ready`] with [`Ready::NO_CHUNK`]. Every service must be opened with the settings of the functions
//! below (see [`Limits`]). What the services of a run take of `/dev/shm` is
//! [`Limits::shared_memory`].

#![warn(missing_docs)]

use iceoryx2::port::event_id::EventId;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{EventCreateError, EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    self as publish_subscribe_builder, PublishSubscribeCreateError, PublishSubscribeOpenError,
    PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event, publish_subscribe};

mod shared_memory;

pub use shared_memory::SharedMemoryNeed;

/// Number of task settings a header can carry.
pub const MAX_SETTINGS: usize = 8;

/// Length of a setting name in a [`Control`] message.
pub const MAX_NAME: usize = 32;

/// "Something for you was published."
pub const WAKE: EventId = EventId::new(1);

/// The exit code of a process that refuses the run's config: a worker whose task has another
/// shape than the config declares (parameters, steps, settings, basis activations). Its
/// restart would refuse it again, so the supervisor fails the run at once, naming the config
/// (sysexits' `EX_CONFIG`).
pub const EXIT_CONFIG_REFUSED: u8 = 78;

/// On `wake/recorder` only, from the updater: "I am holding back a distribution or a rerun
/// until you acknowledge more updates or cost messages (see [`RecorderAck`]); acknowledge
/// what you have taken at the end of your round and ring `wake/updater`."
pub const HOLD: EventId = EventId::new(2);

/// The iceoryx2 service flavour of every port in the pipeline.
pub type Service = ipc::Service;

/// Header of a `distribution` sample. Payload: P + P·P `f64`s, the mean and then the covariance
/// in column-major order.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.DistributionHeader.v2")]
pub struct DistributionHeader {
    /// The run this sample belongs to (every message starts with it).
    pub run_id: u64,
    /// The update whose rollouts are drawn from this distribution (0-based).
    pub update: u64,
    /// Session seed: the noise of rollout k is a pure function of (seed, update, k).
    pub seed: u64,
    /// P.
    pub dim: u32,
    /// K.
    pub rollouts: u32,
    /// N.
    pub steps: u32,
    /// [`DistributionHeader::FINAL`]: no update follows; the sampler hands out no more work.
    /// With it, [`DistributionHeader::STOPPED`]: the run stops here on request.
    pub flags: u32,
    /// Valid entries of `settings`.
    pub settings_len: u32,
    /// Padding made explicit (the layout has none hidden); 0.
    pub _reserved: u32,
    /// λ of this distribution.
    pub lambda: f64,
    /// Task settings in force for `update`, in the order of the task's `settings()`.
    pub settings: [f64; MAX_SETTINGS],
    /// The settings the previous update ran with (`settings_len` of them); those of `update`
    /// itself at the first update of a run. A worker whose task refuses a change runs with
    /// these instead ([`WorkHeader::previous_settings`]).
    pub previous_settings: [f64; MAX_SETTINGS],
}

impl DistributionHeader {
    /// In `flags`: a bounded run's last update is done. This is the final distribution, which
    /// the recorder keeps as the run's result; no rollouts are drawn from it.
    pub const FINAL: u32 = 1;
    /// In `flags`, with [`Self::FINAL`]: the run stops here on request (`supervisor stop
    /// --after-update`, [`Control::STOP_AFTER_UPDATE`]) before its last update: this update
    /// does not run, and its settings are the ones it was to run with (the changes due at it
    /// applied), which a resumed run goes on with.
    pub const STOPPED: u32 = 2;
}

/// Header of a `work/<w>` sample. Payload: θ, P `f64`s.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.WorkHeader.v2")]
pub struct WorkHeader {
    /// The run this work item belongs to.
    pub run_id: u64,
    /// The update u the rollout belongs to; echo it in [`CostHeader::update`].
    pub update: u64,
    /// Sequence number of the assignment this rollout belongs to (unique per run).
    pub chunk: u64,
    /// k.
    pub rollout: u32,
    /// Number of rollouts in this chunk; the worker announces [`Ready`] after that many.
    pub chunk_len: u32,
    /// The worker slot w the item was published to (that of `work/<w>`).
    pub worker: u32,
    /// N: the length of the cost trajectory to return.
    pub steps: u32,
    /// Valid entries of `settings`.
    pub settings_len: u32,
    /// [`WorkHeader::QUEUE_EMPTY`], [`WorkHeader::RERUN`], or 0.
    pub flags: u32,
    /// Task settings for `update` (see [`DistributionHeader::settings`]).
    pub settings: [f64; MAX_SETTINGS],
    /// What the previous update ran with ([`DistributionHeader::previous_settings`]): where the
    /// task refuses a value of `settings`, the worker runs with this one instead and says so in
    /// [`CostHeader::settings`]. Equal to `settings` where there is nothing to fall back to.
    pub previous_settings: [f64; MAX_SETTINGS],
}

impl WorkHeader {
    /// No rollout of this update was left pending when this chunk was handed out: the worker
    /// publishes its [`Ready`] for it without ringing `wake/sampler`, which reads it when the
    /// next distribution or a lost worker wakes it anyway. A worker that ignores the flag and
    /// always rings is still correct, only slower.
    pub const QUEUE_EMPTY: u32 = 1;
    /// An execution of this rollout reported costs that were not finite, and the updater asked
    /// for it again (on `reruns`, [`RerunHeader`]). Information for the worker (a robot may
    /// want to reset before it tries again); the parameters are the same.
    pub const RERUN: u32 = 2;
}

/// Header of a `costs` sample. Payload: the N immediate costs q_i.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.CostHeader.v3")]
pub struct CostHeader {
    /// The run, as in the work item.
    pub run_id: u64,
    /// [`WorkHeader::update`] of the work item: the updater keys costs by (update, rollout).
    pub update: u64,
    /// [`WorkHeader::rollout`] of the work item, k.
    pub rollout: u32,
    /// The sending worker's slot w.
    pub worker: u32,
    /// How long the rollout ran (a monotonic clock), for statistics.
    pub duration_ns: u64,
    /// φ_N.
    pub terminal: f64,
    /// When the rollout started: wall-clock ns since the Unix epoch, the clock of every
    /// recording's `log_time`; 0 if the worker does not say. The recorder takes the costs in
    /// rounds, up to a millisecond after they were sent, so only the worker knows when its
    /// rollout ran.
    pub start_ns: u64,
    /// Valid entries of `settings`; 0: the rollout ran with its work item's settings.
    pub settings_len: u32,
    /// Padding made explicit; 0.
    pub _reserved: u32,
    /// The task settings the rollout ran with, in the order of the work item's. They differ
    /// from the work item's when the task refused a change (`Task::set` failed): the worker
    /// runs with [`WorkHeader::previous_settings`] there and says so here, and the updater takes
    /// the change as refused ([`CostHeader::ran_with`]).
    pub settings: [f64; MAX_SETTINGS],
}

impl CostHeader {
    /// The settings the rollout ran with: its own when it gives them, else `published` (the
    /// settings of the update's distribution).
    pub fn ran_with<'a>(&'a self, published: &'a [f64]) -> &'a [f64] {
        match self.settings_len {
            0 => published,
            n => unpack_settings(&self.settings, n),
        }
    }
}

/// A worker asks for work (`flags` 0), or reports that it is still getting through its chunk
/// ([`Ready::ROLLOUT_DONE`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.Ready.v2")]
pub struct Ready {
    /// The run.
    pub run_id: u64,
    /// The chunk just finished, or [`Ready::NO_CHUNK`] from a worker that has just started;
    /// with [`Ready::ROLLOUT_DONE`], the chunk the worker is working on.
    pub chunk: u64,
    /// The worker's slot w: the sampler publishes its work on `work/<w>`.
    pub worker: u32,
    /// Increases with every restart of worker `worker`.
    pub incarnation: u32,
    /// The worker's process id, for the sampler's messages.
    pub pid: u32,
    /// 0 or [`Ready::ROLLOUT_DONE`], with [`Ready::rollout_done`]'s count in bits 16–31.
    pub flags: u32,
}

impl Ready {
    /// In `chunk`: the worker has finished no chunk yet (its first request for work after it
    /// started; `UINT64_MAX` in C).
    pub const NO_CHUNK: u64 = u64::MAX;
    /// A rollout of `chunk` other than its last has just been sent: not a request for work,
    /// but what lets `pipeline.rollout_timeout_ms` bound one rollout rather than a whole chunk
    /// (the sampler counts the timeout from the latest of these). Sent only when the run has a
    /// rollout timeout, without ringing `wake/sampler` (it is read when the sampler next wakes,
    /// at least every 0.1 s), and at most every [`ROLLOUT_DONE_INTERVAL`]: fast rollouts send
    /// none at all. A worker's own messages reach the sampler in order, and it sends nothing
    /// after a chunk's last Ready until it gets the next chunk, so a full subscriber buffer
    /// drops only older reports of the same worker, never a request for work.
    pub const ROLLOUT_DONE: u32 = 1;
    /// Where in `flags` a ROLLOUT_DONE report counts the rollouts of the chunk whose costs
    /// have been sent (in the chunk's order). A worker that leaves these bits 0 (one written
    /// before they existed) says nothing, and a lost worker's whole chunk is handed out again.
    const SENT_SHIFT: u32 = 16;

    /// The `flags` of a [`Ready::ROLLOUT_DONE`] report after the costs of the chunk's first
    /// `sent` rollouts were sent. Those a lost worker reported are held back from the others
    /// until the update waits for nothing else: their costs almost always reached the updater,
    /// and on a robot a rollout run again is run for real.
    pub fn rollout_done(sent: usize) -> u32 {
        let sent = u32::try_from(sent)
            .unwrap_or(u32::MAX)
            .min(u32::MAX >> Self::SENT_SHIFT);
        Self::ROLLOUT_DONE | sent << Self::SENT_SHIFT
    }

    /// The count [`Ready::rollout_done`] put into `flags` (0 if none).
    pub fn sent(&self) -> usize {
        if self.flags & Self::ROLLOUT_DONE == 0 {
            return 0;
        }
        (self.flags >> Self::SENT_SHIFT) as usize
    }
}

/// A worker sends [`Ready::ROLLOUT_DONE`] at most this often. A rollout therefore begins at
/// most this long after the sampler's last sign of life from its worker, and is taken to hang
/// only when it runs longer than `pipeline.rollout_timeout_ms` minus this.
pub const ROLLOUT_DONE_INTERVAL: std::time::Duration = std::time::Duration::from_millis(1);

/// What the updater reports to the supervisor (rate-limited, and always for the last update),
/// and its answer to each runtime task change ([`Progress::TASK_CHANGE`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.Progress.v5")]
pub struct Progress {
    /// The run.
    pub run_id: u64,
    /// Updates completed.
    pub updates: u64,
    /// When the last of `updates` was completed, since the first distribution was published
    /// (not when the report was sent, which may be later: rates are taken between reports).
    pub elapsed_ns: u64,
    /// Total cost of the evaluation rollout of the last update.
    pub eval_cost: f64,
    /// λ of the current distribution.
    pub lambda: f64,
    /// [`Progress::FINAL`], [`Progress::TASK_CHANGE`], or 0 (a periodic report).
    pub flags: u32,
    /// Valid entries of `settings`.
    pub settings_len: u32,
    /// The task settings the updater holds when it sends the report (runtime changes
    /// included), in the order of the task's `settings()`.
    pub settings: [f64; MAX_SETTINGS],
    /// [`Control::seq`] of the last [`Control::SET_TASK`] the updater took (0: none yet). An
    /// echo, not a count, so that the supervisor pairs each answer with its request even if a
    /// message it sent was not counted on its side or an answer was overwritten.
    pub last_change_seq: u64,
    /// The update that change takes effect from.
    pub last_change_from: u64,
    /// Task changes the workers' task refused so far (see [`CostHeader::settings`]); the
    /// `last_refused_*` fields describe the last of them and are meaningful only when this is
    /// above 0.
    pub refused: u32,
    /// The refused setting: an index into `settings`.
    pub last_refused_setting: u32,
    /// The value the task refused.
    pub last_refused_value: f64,
    /// The update whose rollout refused it.
    pub last_refused_update: u64,
    /// Rollouts of the update under way (update `updates`) whose costs the updater has, of
    /// `rollouts`: with rollouts that take seconds, how far an update has got.
    pub rollouts_done: u32,
    /// The rollouts of an update (K, and the evaluation rollout if it is one of them).
    pub rollouts: u32,
}

impl Progress {
    /// The run is complete (bounded run) or the updater is stopping.
    pub const FINAL: u32 = 1;
    /// Sent at once when a task change arrives, so that `supervisor set` can say which update it
    /// takes effect from; the other fields are as of the last report, not a new update.
    pub const TASK_CHANGE: u32 = 2;
}

/// The recorder's acknowledgement on `recorded`, sent after each update it has written and
/// flushed, and at the end of a round in which a held updater rang it: every update before
/// `next_update` is in the file, and `taken` cost messages of updates from `next_update` on
/// are out of its subscriber's buffer. The updater publishes the distribution of update u only
/// while u − `next_update` < [`Limits::recorder_max_lag`]: then at most that many
/// distributions can be waiting in the recorder's buffers, and a recorder killed with SIGKILL
/// loses at most that many updates. Reruns make an update's cost messages more than K, so
/// the updater also counts them: it receives every cost message the recorder does, and issues
/// a distribution or a rerun only while those of updates from `next_update` on, less
/// `taken`, plus the executions still out, fit in [`Limits::recorder_cost_room`]. So nothing
/// is dropped by safe overflow, however many reruns there are. `synced` is the newest
/// [`Control::RECORDER_SYNC`] the recorder has carried out (for the supervisor).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.RecorderAck.v2")]
pub struct RecorderAck {
    /// The run.
    pub run_id: u64,
    /// The first update not yet written and flushed: every update before it is in the file.
    pub next_update: u64,
    /// Cost messages of updates from `next_update` on that the recorder has taken out of its
    /// subscriber's buffer.
    pub taken: u64,
    /// [`Control::seq`] of the newest [`Control::RECORDER_SYNC`] carried out (0: none).
    pub synced: u64,
}

/// Process roles in [`Lifecycle`].
pub mod role {
    /// The updater (crate `pipeline`, binary `updater`): owns the optimizer.
    pub const UPDATER: u32 = 1;
    /// The sampler (binary `sampler`): draws the rollouts and hands them out.
    pub const SAMPLER: u32 = 2;
    /// A rollout worker, of this workspace or of your own, in any language.
    pub const WORKER: u32 = 3;
    /// The MCAP recorder (crate `record`): the spare subscriber of the run's services, started
    /// first and stopped last by the supervisor.
    pub const RECORDER: u32 = 4;
}

/// A process announces it is ready (all its ports are open and connected).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.Lifecycle.v1")]
pub struct Lifecycle {
    /// The run.
    pub run_id: u64,
    /// The announcing process's id: the supervisor tells the processes it started from others.
    pub pid: u32,
    /// One of [`role`].
    pub role: u32,
    /// For [`role::WORKER`], its slot w; 0 otherwise.
    pub worker: u32,
    /// For [`role::WORKER`], its incarnation (as in [`Ready::incarnation`]); 0 otherwise.
    pub incarnation: u32,
}

/// What the supervisor has to say about the run that belongs in its recording: why it failed,
/// or that it stalled. The recorder logs it on `/log` as an event of the supervisor.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.RunNote.v1")]
pub struct RunNote {
    /// The run.
    pub run_id: u64,
    /// One of the `RunNote::` levels.
    pub level: u32,
    /// Length of `text` in bytes (UTF-8).
    pub text_len: u32,
    /// The message, UTF-8, its first `text_len` bytes valid; read it with [`RunNote::text`].
    pub text: [u8; MAX_NOTE],
}

/// The longest start of `text` of at most `max` bytes that ends at a character boundary.
fn char_prefix(text: &str, max: usize) -> &str {
    let mut cut = text.len().min(max);
    while !text.is_char_boundary(cut) {
        cut -= 1;
    }
    &text[..cut]
}

/// Length of a [`RunNote`]'s text: room for a failure reason with the process's last line.
pub const MAX_NOTE: usize = 1024;

impl Default for RunNote {
    fn default() -> Self {
        Self {
            run_id: 0,
            level: 0,
            text_len: 0,
            text: [0; MAX_NOTE],
        }
    }
}

impl RunNote {
    /// For the record only; logged as the supervisor's `info`.
    pub const INFO: u32 = 0;
    /// Something went wrong that did not fail the run; logged as the supervisor's `warning`.
    pub const WARNING: u32 = 1;
    /// The run failed; `text` says why.
    pub const ERROR: u32 = 2;

    /// `text` cut to [`MAX_NOTE`] bytes at a character boundary.
    pub fn new(run_id: u64, level: u32, text: &str) -> Self {
        let text = char_prefix(text, MAX_NOTE);
        let mut note = Self {
            run_id,
            level,
            text_len: text.len() as u32,
            ..Self::default()
        };
        note.text[..text.len()].copy_from_slice(text.as_bytes());
        note
    }

    /// The first `text_len` bytes of `text` (at most [`MAX_NOTE`]); empty if they are not
    /// UTF-8.
    pub fn text(&self) -> &str {
        let len = (self.text_len as usize).min(MAX_NOTE);
        // Written by `new`, whole characters; anything else reads as empty.
        std::str::from_utf8(&self.text[..len]).unwrap_or("")
    }
}

/// The sampler's report of a worker that has sent no cost for longer than
/// `pipeline.rollout_timeout_ms` while it holds a chunk: it has held `rollouts` rollouts of
/// update `update` for `held_ms`, and `stalled_ms` of that passed since its last sign of
/// progress (the hand-out, or its last [`Ready::ROLLOUT_DONE`]). The supervisor kills that
/// incarnation and restarts it; its rollouts go to the other workers as any lost worker's do.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.Overdue.v2")]
pub struct Overdue {
    /// The run.
    pub run_id: u64,
    /// The update of the chunk held.
    pub update: u64,
    /// [`WorkHeader::chunk`] of the chunk held.
    pub chunk: u64,
    /// Milliseconds since the chunk was handed out.
    pub held_ms: u64,
    /// Milliseconds since the last sign of progress (hand-out or [`Ready::ROLLOUT_DONE`]).
    pub stalled_ms: u64,
    /// The worker's slot w.
    pub worker: u32,
    /// The incarnation that holds the chunk: the supervisor kills only that one.
    pub incarnation: u32,
    /// Rollouts in the chunk ([`WorkHeader::chunk_len`]).
    pub rollouts: u32,
    /// Padding made explicit; 0.
    pub _reserved: u32,
}

/// A command from the supervisor.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.Control.v4")]
pub struct Control {
    /// The run.
    pub run_id: u64,
    /// What the message says: one of the `Control::` kinds ([`Control::WORKER_LOST`], …).
    pub kind: u32,
    /// For [`Control::WORKER_LOST`].
    pub worker: u32,
    /// For [`Control::WORKER_LOST`].
    pub incarnation: u32,
    /// For [`Control::WORKER_LOST`]: one of [`lost`].
    pub reason: u32,
    /// Length of `name` in bytes (UTF-8).
    pub name_len: u32,
    /// For [`Control::WORKER_LOST`]: the process id the worker had (0 if unknown).
    pub pid: u32,
    /// The task setting of [`Control::SET_TASK`]; for [`Control::WORKER_LOST`], how the process
    /// ended (e.g. `signal: 9 (SIGKILL)`), cut to [`MAX_NAME`] bytes.
    pub name: [u8; MAX_NAME],
    /// For [`Control::SET_TASK`]: the setting's new value.
    pub value: f64,
    /// For [`Control::SET_TASK`]: the sender's number for the change (from 1), echoed in
    /// [`Progress::last_change_seq`]; for [`Control::RECORDER_SYNC`], the sync's number.
    pub seq: u64,
    /// The supervisor numbers every message it sends, from 1: a subscriber that sees a gap
    /// lost messages to the safe overflow of its buffer (a recorder stalled for long); 0 from
    /// a sender that does not number them.
    pub sent: u64,
}

/// Header of a `reruns` sample, from the updater. Payload: for each of the K rollouts of
/// update `update`, how many of its executions the updater has rejected so far because their
/// costs were not finite. The sampler hands out again each rollout whose count is higher than
/// in the last sample it read, so that it needs only the newest sample of an update.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("pi2cma.RerunHeader.v1")]
pub struct RerunHeader {
    /// The run.
    pub run_id: u64,
    /// The update u whose rollouts the payload counts.
    pub update: u64,
}

/// Why a worker is gone ([`Control::reason`] of [`Control::WORKER_LOST`]): the recording's health
/// log tells a crash from a scale-down.
pub mod lost {
    /// Killed by a signal or exited with a failure status, unasked.
    pub const CRASHED: u32 = 0;
    /// Exited with status 0, unasked.
    pub const EXITED: u32 = 1;
    /// Stopped by the supervisor because the number of workers was scaled down.
    pub const SCALED_DOWN: u32 = 2;
    /// Stopped by the supervisor because the run is stopping.
    pub const STOPPED: u32 = 3;
    /// Killed by the supervisor because it held its chunk too long ([`super::Overdue`]).
    pub const HUNG: u32 = 4;
}

impl Control {
    /// Worker `worker` (incarnation `incarnation`) is gone: hand its rollouts to others (sampler).
    pub const WORKER_LOST: u32 = 1;
    /// Set task setting `name` to `value` from the next update on (updater).
    pub const SET_TASK: u32 = 2;
    /// Start: the sampler is ready, publish the first distribution (updater).
    pub const START: u32 = 3;
    /// The recorder is gone: stop waiting for its acknowledgements (updater).
    pub const RECORDER_LOST: u32 = 4;
    /// A restarted recorder is subscribed: hold back for its acknowledgements again, counted
    /// from the update at hand (updater).
    pub const RECORDER_BACK: u32 = 5;
    // Kind 6 was a rerun request from the updater, one message per rejected execution: a
    // burst of them overflowed the sampler's buffer, losing requests and hanging the update.
    // Reruns now travel on their own service as a state ([`RerunHeader`]); 6 stays unused.
    /// Connect to every publisher there is now and say so with [`RecorderAck::synced`] =
    /// `seq` (recorder), ringing `wake/supervisor`. The supervisor asks it before it stops a
    /// worker: iceoryx2 keeps what a departed publisher sent only for subscribers that had
    /// connected to it, so a worker that joined while the recorder was stalled would take its
    /// last costs and its announcement with it.
    pub const RECORDER_SYNC: u32 = 7;
    /// Finish the update under way (every one of its rollouts), then publish the next
    /// distribution with [`DistributionHeader::FINAL`] | [`DistributionHeader::STOPPED`] and
    /// exit (updater): a stop that throws away no rollout, for rollouts that take a robot
    /// seconds each. A distribution held back (its rollouts not begun) is published so at once.
    pub const STOP_AFTER_UPDATE: u32 = 8;

    /// [`Self::RECORDER_SYNC`] number `seq`.
    pub fn recorder_sync(run_id: u64, seq: u64) -> Self {
        Self {
            seq,
            ..Self::plain(run_id, Self::RECORDER_SYNC)
        }
    }

    /// A message of `kind` without arguments.
    pub fn plain(run_id: u64, kind: u32) -> Self {
        Self {
            run_id,
            kind,
            ..Self::default()
        }
    }

    /// `reason` is one of [`lost`]; `how` (e.g. the exit status) is cut to [`MAX_NAME`] bytes at
    /// a character boundary.
    pub fn worker_lost(
        run_id: u64,
        worker: u32,
        incarnation: u32,
        pid: u32,
        reason: u32,
        how: &str,
    ) -> Self {
        Self {
            worker,
            incarnation,
            pid,
            reason,
            ..Self::plain(run_id, Self::WORKER_LOST).with_name(how)
        }
    }

    /// Change number `seq`; `None` if the name is longer than [`MAX_NAME`] bytes.
    pub fn set_task(run_id: u64, seq: u64, name: &str, value: f64) -> Option<Self> {
        (name.len() <= MAX_NAME).then(|| Self {
            value,
            seq,
            ..Self::plain(run_id, Self::SET_TASK).with_name(name)
        })
    }

    /// Sets `name`, cut to [`MAX_NAME`] bytes at a character boundary.
    fn with_name(mut self, text: &str) -> Self {
        let text = char_prefix(text, MAX_NAME);
        self.name = [0; MAX_NAME];
        self.name[..text.len()].copy_from_slice(text.as_bytes());
        self.name_len = text.len() as u32;
        self
    }

    /// The first `name_len` bytes of `name` (at most [`MAX_NAME`]); empty if they are not
    /// UTF-8.
    pub fn name(&self) -> &str {
        let len = (self.name_len as usize).min(MAX_NAME);
        std::str::from_utf8(&self.name[..len]).unwrap_or("")
    }
}

/// Copies up to [`MAX_SETTINGS`] values into a header array; returns the count.
pub fn pack_settings(values: &[f64]) -> ([f64; MAX_SETTINGS], u32) {
    let mut out = [0.0; MAX_SETTINGS];
    let n = values.len().min(MAX_SETTINGS);
    out[..n].copy_from_slice(&values[..n]);
    (out, n as u32)
}

/// The first `len` values of a header's settings array (its `settings_len`), no more than it
/// holds: the inverse of [`pack_settings`].
pub fn unpack_settings(values: &[f64; MAX_SETTINGS], len: u32) -> &[f64] {
    &values[..usize::try_from(len).map_or(MAX_SETTINGS, |n| n.min(MAX_SETTINGS))]
}

/// The publish-subscribe services of a run ([`Limits::settings`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PubSub {
    Distribution,
    Work,
    Costs,
    Ready,
    Recorded,
    Progress,
    Lifecycle,
    Overdue,
    Notes,
    Control,
    Reruns,
    Joined,
}

/// What a publish-subscribe service is opened with, besides its types: the most publishers,
/// subscribers and nodes, and each subscriber's buffer (samples per publisher).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct PubSubSettings {
    pub publishers: usize,
    pub subscribers: usize,
    pub buffer: usize,
    pub nodes: usize,
}

/// What an event service (a doorbell) is opened with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct EventSettings {
    pub notifiers: usize,
    pub listeners: usize,
    pub nodes: usize,
}

/// Samples a subscriber may hold at once, of every service.
pub(crate) const BORROWED_SAMPLES: usize = 2;

/// The numbers every service size is derived from. Every process of a run must use the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// `pipeline.max_workers`.
    pub max_workers: usize,
    /// K.
    pub rollouts: usize,
    /// P.
    pub dim: usize,
    /// N.
    pub steps: usize,
}

impl Limits {
    /// Ports of crashed processes stay registered until a new node cleans them up; leave room.
    fn worker_ports(&self) -> usize {
        2 * self.max_workers + 2
    }
    fn nodes(&self) -> usize {
        2 * self.max_workers + 8
    }

    /// The builder settings of each publish-subscribe service, in one place so that the service
    /// functions ([`distribution`], [`costs`], …) and the shared-memory estimate
    /// ([`Limits::shared_memory`]) cannot disagree.
    pub(crate) fn settings(&self, service: PubSub) -> PubSubSettings {
        let w = self.max_workers;
        let (publishers, subscribers, buffer, nodes) = match service {
            PubSub::Distribution => (2, 4, self.distribution_buffer(), self.nodes()),
            PubSub::Work => (2, 2, self.rollouts.max(1), 8),
            PubSub::Costs => (self.worker_ports(), 2, self.cost_buffer(), self.nodes()),
            PubSub::Ready => (self.worker_ports(), 2, 2 * w + 4, self.nodes()),
            PubSub::Recorded => (2, 2, 4, self.nodes()),
            PubSub::Progress => (2, 4, 8, self.nodes()),
            PubSub::Lifecycle => (self.worker_ports() + 4, 2, 2 * w + 8, self.nodes()),
            PubSub::Overdue => (2, 2, 2 * w + 4, self.nodes()),
            PubSub::Notes => (2, 2, 16, self.nodes()),
            PubSub::Control => (2, 4, 2 * w + 16, self.nodes()),
            // A sample is the whole state of the update's reruns: the newest is all it takes.
            PubSub::Reruns => (2, 2, 4, self.nodes()),
            // One echo per worker incarnation; a later one of a slot stands for the earlier.
            PubSub::Joined => (2, 2, 2 * w + 8, self.nodes()),
        };
        PubSubSettings {
            publishers,
            subscribers,
            buffer,
            nodes,
        }
    }

    /// The builder settings of every doorbell ([`doorbell`]).
    pub(crate) fn doorbell_settings(&self) -> EventSettings {
        EventSettings {
            notifiers: self.worker_ports() + 4,
            listeners: 2,
            nodes: self.nodes(),
        }
    }

    /// Cost samples a subscriber can hold: one per rollout plus re-executions after a crash, and
    /// room for the recorder's lag: [`RECORDER_SLACK_UPDATES`] updates' worth, as far as
    /// [`SEGMENT_BUDGET_BYTES`] allows (the lag bound shrinks to what fits), and never less
    /// than the least lag bound, [`MIN_RECORDER_LAG`] updates, needs.
    fn cost_buffer(&self) -> usize {
        let needed = (MIN_RECORDER_LAG as usize + 1) * self.rollouts + self.max_workers + 4;
        let slack = RECORDER_SLACK_UPDATES * self.rollouts;
        let affordable = SEGMENT_BUDGET_BYTES / (2 * 8 * self.steps.max(1));
        needed.max(slack.min(affordable))
    }

    /// Distributions a subscriber can hold: 4, or up to [`RECORDER_SLACK_UPDATES`] for the
    /// recorder as far as [`SEGMENT_BUDGET_BYTES`] allows.
    fn distribution_buffer(&self) -> usize {
        let affordable = SEGMENT_BUDGET_BYTES / (4 * 8 * (self.dim + self.dim * self.dim).max(1));
        4usize.max(RECORDER_SLACK_UPDATES.min(affordable))
    }

    /// The cost messages the recorder's subscriber can hold, less room for re-executions after
    /// crashes and late twins (`max_workers` + 4), which nobody issues: the most the updater
    /// lets wait for the recorder (see [`RecorderAck`]). Each worker's publisher has a buffer
    /// of its own in the subscriber; one is counted, as if one worker sent them all.
    pub fn recorder_cost_room(&self) -> u64 {
        (self.cost_buffer() - self.max_workers - 4) as u64
    }

    /// How far the updater may run ahead of the recorder's acknowledgement ([`RecorderAck`]):
    /// at most [`RECORDER_MAX_LAG`] updates, and only as many as the recorder's buffers hold
    /// (L distributions, and the costs of L + 1 updates plus re-executions, which leaves a
    /// margin), so nothing is dropped by safe overflow. At least [`MIN_RECORDER_LAG`].
    pub fn recorder_max_lag(&self) -> u64 {
        let by_costs =
            (self.recorder_cost_room() as usize / self.rollouts.max(1)).saturating_sub(1);
        RECORDER_MAX_LAG
            .min(self.distribution_buffer() as u64)
            .min(by_costs as u64)
            .max(MIN_RECORDER_LAG)
    }
}

/// The least lag bound that lets a run go on: the recorder writes update u once it has the
/// distribution of u + 1 (the update's "after"), so the updater must be allowed to publish
/// u + 1 while u is not yet acknowledged. A bound of 1 (what the buffers allowed from about
/// N = 20 000 steps at K = 15) held the run after its first update for good.
pub const MIN_RECORDER_LAG: u64 = 2;

/// The updater rings an idle recorder at most this often; in return, a recorder that took in
/// anything in its last round waits at most this long before it looks again, so an update
/// whose ring was skipped is taken in within about this interval even if the run then pauses.
pub const RECORDER_RING_INTERVAL: std::time::Duration = std::time::Duration::from_millis(1);

/// The most updates the recorder may fall behind the updater (see [`RecorderAck`]). Enough
/// for the recorder to batch its work at thousands of updates per second; small enough that a
/// recorder killed with SIGKILL loses little.
pub const RECORDER_MAX_LAG: u64 = 16;

/// Wall-clock time in ns since the Unix epoch: [`CostHeader::start_ns`], and the `log_time` of
/// every message a recording holds, in every process (one clock, so that intervals taken in
/// different processes can be compared).
pub fn wall_clock_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// The names of the run's processes other than workers: each is the name of the process's
/// iceoryx2 node and the owner of its doorbell, `wake/<name>` ([`doorbell`]). Every process
/// must use these: the updater finds a dead recorder by its node name, and a process rings
/// another by its doorbell's name. Workers are [`worker_node_name`] and
/// [`worker_doorbell`].
pub mod process {
    /// The updater: doorbell `wake/updater`, rung by the workers (after their costs), the
    /// recorder and the supervisor.
    pub const UPDATER: &str = "updater";
    /// The sampler: doorbell `wake/sampler`, rung by the updater (a new distribution or
    /// reruns), the workers (asking for work) and the supervisor.
    pub const SAMPLER: &str = "sampler";
    /// The recorder: doorbell `wake/recorder`, rung by the updater (with [`crate::HOLD`] when
    /// it is held back) and the supervisor.
    pub const RECORDER: &str = "recorder";
    /// The supervisor: doorbell `wake/supervisor`, rung after `lifecycle`, `progress`,
    /// `recorded` and `overdue` messages.
    pub const SUPERVISOR: &str = "supervisor";
}

/// The owner of worker `w`'s doorbell ([`doorbell`]): `worker/<w>`, the service
/// `wake/worker/<w>`.
pub fn worker_doorbell(worker: u32) -> String {
    format!("worker/{worker}")
}

/// The node name of worker `w`, incarnation `incarnation`: `worker-<w>.<incarnation>`. The
/// sampler finds crashed workers by these names among the run's dead nodes.
pub fn worker_node_name(worker: u32, incarnation: u32) -> String {
    format!("worker-{worker}.{incarnation}")
}

/// The inverse of [`worker_node_name`].
pub fn parse_worker_node_name(name: &str) -> Option<(u32, u32)> {
    let (w, i) = name.strip_prefix("worker-")?.split_once('.')?;
    Some((w.parse().ok()?, i.parse().ok()?))
}

/// A run id: shown as 16 hex digits.
pub fn run_id_hex(run_id: u64) -> String {
    format!("{run_id:016x}")
}

fn service_name(run_id: u64, tail: &str) -> Result<ServiceName, WireError> {
    let name = format!("pi2cma/{}/{tail}", run_id_hex(run_id));
    ServiceName::new(&name).map_err(|e| WireError::new(&name, format!("{e:?}")))
}

/// An iceoryx2 port or service that could not be opened or created.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2 service `{service}`: {reason}")]
pub struct WireError {
    /// The full service name (`pi2cma/<run>/costs`), the node name, or `config`.
    pub service: String,
    /// iceoryx2's error, and what to do about it where this crate knows
    /// ([`VERSION_MISMATCH_HINT`], [`CONTRACT_MISMATCH_HINT`]).
    pub reason: String,
}

impl WireError {
    pub(crate) fn new(service: &str, reason: impl Into<String>) -> Self {
        Self {
            service: service.to_string(),
            reason: reason.into(),
        }
    }
}

/// The iceoryx2 file prefix of a run: shared memory is `/dev/shm/<prefix>…`.
pub fn file_prefix(run_id: u64) -> String {
    format!("p2c{}_", run_id_hex(run_id))
}

/// The per-run iceoryx2 root directory, `/tmp/p2c-<run>/`. Kept short on purpose: iceoryx2's
/// event services are Unix sockets under it, and socket paths are limited to 108 bytes.
pub fn iceoryx_root(run_id: u64) -> std::path::PathBuf {
    std::path::PathBuf::from(format!("/tmp/p2c-{}/", run_id_hex(run_id)))
}

/// The per-run iceoryx2 config: `global.prefix` = [`file_prefix`], `global.root-path` =
/// [`iceoryx_root`]. Everything else is iceoryx2's default. A foreign process joins the run by
/// using the same two values.
pub fn iceoryx_config(run_id: u64) -> Result<Config, WireError> {
    let mut config = Config::default();
    let prefix = file_prefix(run_id);
    config.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|e| WireError::new("config", format!("prefix {prefix}: {e:?}")))?;
    let root = iceoryx_root(run_id);
    let root = root.to_string_lossy();
    let path = iceoryx2::prelude::Path::new(root.as_bytes())
        .map_err(|e| WireError::new("config", format!("root path {root}: {e:?}")))?;
    config.global.set_root_path(&path);
    Ok(config)
}

/// Whether a process of run `run_id` is alive, by iceoryx2's node registry under the run's root
/// ([`iceoryx_root`]): its nodes' owners hold a lock that dies with them. A node whose state
/// cannot be read counts as alive, and so does a registry that cannot be listed: only a run
/// known to be dead may be cleaned up.
pub fn run_alive(run_id: u64) -> bool {
    let Ok(config) = iceoryx_config(run_id) else {
        return true;
    };
    let mut alive = false;
    let listed = Node::<Service>::list(&config, |state| {
        if matches!(state, NodeState::Dead(_)) {
            CallbackProgression::Continue
        } else {
            alive = true;
            CallbackProgression::Stop
        }
    });
    alive || listed.is_err()
}

/// Whether run `run_id` has a live supervisor ([`process::SUPERVISOR`]'s node under the run's
/// root), whatever other processes of it run (a recorder or a worker started by hand before
/// the supervisor). A node whose state or name cannot be read (another user's) counts as one,
/// and so does a registry that cannot be listed: a second supervisor is started only beside a
/// run known to have none.
pub fn supervisor_alive(run_id: u64) -> bool {
    supervisor_known_alive(run_id).unwrap_or(true)
}

/// Whether run `run_id` has a live supervisor, as far as its node registry tells: `Some(true)`
/// for a live node named [`process::SUPERVISOR`], `Some(false)` when every node could be read
/// and none is one, `None` when that cannot be told (the registry cannot be listed, or a node's
/// state or name cannot be read: another user's, or one being created).
pub fn supervisor_known_alive(run_id: u64) -> Option<bool> {
    use iceoryx2::node::NodeView as _;
    let config = iceoryx_config(run_id).ok()?;
    let mut found = Some(false);
    let listed = Node::<Service>::list(&config, |state| {
        let this = match state {
            NodeState::Dead(_) => Some(false),
            NodeState::Alive(view) => view
                .details()
                .as_ref()
                .map(|d| d.name().as_str() == process::SUPERVISOR),
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => None,
        };
        match this {
            Some(true) => {
                found = Some(true);
                CallbackProgression::Stop
            }
            Some(false) => CallbackProgression::Continue,
            None => {
                found = None;
                CallbackProgression::Continue
            }
        }
    });
    listed.ok().and(found)
}

/// Creates a named node with the run's config.
pub fn node(run_id: u64, name: &str) -> Result<Node<Service>, WireError> {
    let config = iceoryx_config(run_id)?;
    let node_name =
        NodeName::new(name).map_err(|e| WireError::new(name, format!("node name: {e:?}")))?;
    NodeBuilder::new()
        .name(&node_name)
        .config(&config)
        .create::<Service>()
        .map_err(|e| WireError::new(name, format!("cannot create node: {e:?}")))
}

/// A service whose payload is an `f64` slice with user header `H` (`distribution`, `work/<w>`,
/// `costs`): make publishers and subscribers from it.
pub type SliceService<H> = publish_subscribe::PortFactory<Service, [f64], H>;
/// A service whose payload is one fixed-size message `T` without user header.
pub type FixedService<T> = publish_subscribe::PortFactory<Service, T, ()>;
/// A service whose payload is a `u32` slice with user header `H` (`reruns`).
pub type CountService<H> = publish_subscribe::PortFactory<Service, [u32], H>;
/// A doorbell: make the owner's listener or another process's notifier from it.
pub type EventService = event::PortFactory<Service>;

/// How opening or creating a service failed, as far as [`open_or_create`] treats failures
/// differently.
trait OpenFailure: std::fmt::Debug {
    /// Only because a system call was interrupted (EINTR) or the service was in flux: such an
    /// open is retried, as POSIX code retries EINTR. The sampler opening a new worker's
    /// `work/<w>` and `wake/worker/<w>` saw it during a scale-up next to a joined worker, and
    /// failed the run.
    fn interrupted(&self) -> bool;
    /// The service was created by a process built with another iceoryx2 version, which
    /// iceoryx2 refuses down to the patch version.
    fn version_mismatch(&self) -> bool;
    /// The service carries other message types than this process's: one side was built from
    /// another revision of this crate (the type names are versioned, `pi2cma.Ready.v2`).
    fn other_contract(&self) -> bool {
        false
    }
}

impl OpenFailure for PublishSubscribeOpenOrCreateError {
    fn interrupted(&self) -> bool {
        matches!(
            self,
            Self::PublishSubscribeOpenError(PublishSubscribeOpenError::Interrupt)
                | Self::PublishSubscribeCreateError(PublishSubscribeCreateError::Interrupt)
                | Self::SystemInFlux
        )
    }
    fn version_mismatch(&self) -> bool {
        matches!(
            self,
            Self::PublishSubscribeOpenError(PublishSubscribeOpenError::VersionMismatch)
        )
    }
    fn other_contract(&self) -> bool {
        matches!(
            self,
            Self::PublishSubscribeOpenError(PublishSubscribeOpenError::IncompatibleTypes)
        )
    }
}

impl OpenFailure for EventOpenOrCreateError {
    fn interrupted(&self) -> bool {
        matches!(
            self,
            Self::EventOpenError(EventOpenError::Interrupt)
                | Self::EventCreateError(EventCreateError::Interrupt)
                | Self::SystemInFlux
        )
    }
    fn version_mismatch(&self) -> bool {
        matches!(self, Self::EventOpenError(EventOpenError::VersionMismatch))
    }
}

/// What a process that meets services of another iceoryx2 version is told: a worker crate
/// outside the workspace that resolved its own dependency versions.
pub const VERSION_MISMATCH_HINT: &str = "the run's services were created by a process built \
    with another iceoryx2 version than this one (iceoryx2 connects only the same version, \
    patch included): build your worker with the pi2cma workspace's Cargo.lock (copy it into \
    your worker crate) or as a member of the workspace";

/// What a process that meets the run's messages under other type names is told: a worker built
/// against an older or newer revision of the wire contract.
pub const CONTRACT_MISMATCH_HINT: &str = "the run's messages are of other types than this \
    process's (their names are versioned, e.g. pi2cma.Ready.v2): this process was built from \
    another revision of pi2cma's wire crate than the run's processes; rebuild your worker against \
    the pi2cma workspace the supervisor was built from (a Python worker: take that workspace's \
    tools/pi2cma_worker.py and its wire layout in the README)";

/// Opens or creates the run's service `pi2cma/<run>/<tail>` with `open`, again a few times while
/// it fails only for a moment ([`OpenFailure::interrupted`]); an error names the service, and
/// one of another iceoryx2 version says what to do about it.
fn open_or_create<T, E: OpenFailure>(
    run_id: u64,
    tail: &str,
    mut open: impl FnMut(&ServiceName) -> Result<T, E>,
) -> Result<T, WireError> {
    let name = service_name(run_id, tail)?;
    let mut tries = 0;
    loop {
        match open(&name) {
            Err(e) if e.interrupted() && tries < 20 => {
                // Backing off: a service in flux needs its creator to finish, not a hot loop.
                tries += 1;
                std::thread::sleep(std::time::Duration::from_micros(100 << tries.min(7)));
            }
            Err(e) if e.version_mismatch() => {
                return Err(WireError::new(
                    name.as_str(),
                    format!("{e:?}: {VERSION_MISMATCH_HINT}"),
                ))
            }
            Err(e) if e.other_contract() => {
                return Err(WireError::new(
                    name.as_str(),
                    format!("{e:?}: {CONTRACT_MISMATCH_HINT}"),
                ))
            }
            r => return r.map_err(|e| WireError::new(name.as_str(), format!("{e:?}"))),
        }
    }
}

/// The settings every publish-subscribe service of the run shares; only the message type and
/// these counts differ between them.
fn pubsub_settings<P: std::fmt::Debug + IceoryxSend + ?Sized, H: std::fmt::Debug + ZeroCopySend>(
    builder: publish_subscribe_builder::Builder<P, H, Service>,
    s: PubSubSettings,
) -> publish_subscribe_builder::Builder<P, H, Service> {
    builder
        .max_publishers(s.publishers)
        .max_subscribers(s.subscribers)
        .subscriber_max_buffer_size(s.buffer)
        .subscriber_max_borrowed_samples(BORROWED_SAMPLES)
        .history_size(0)
        .enable_safe_overflow(true)
        .max_nodes(s.nodes)
}

fn slice_service<T: std::fmt::Debug + ZeroCopySend, H: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Service>,
    run_id: u64,
    tail: &str,
    settings: PubSubSettings,
) -> Result<publish_subscribe::PortFactory<Service, [T], H>, WireError> {
    open_or_create(run_id, tail, |name| {
        let builder = node
            .service_builder(name)
            .publish_subscribe::<[T]>()
            .user_header::<H>();
        pubsub_settings(builder, settings).open_or_create()
    })
}

fn fixed_service<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<Service>,
    run_id: u64,
    tail: &str,
    settings: PubSubSettings,
) -> Result<FixedService<T>, WireError> {
    open_or_create(run_id, tail, |name| {
        let builder = node.service_builder(name).publish_subscribe::<T>();
        pubsub_settings(builder, settings).open_or_create()
    })
}

/// Updates' worth of samples a subscriber's buffer holds: the recorder's lag bound
/// ([`RECORDER_MAX_LAG`]) twice over. Back-pressure, not buffer size, keeps the recorder from
/// losing samples (until back-pressure, these buffers held 256 updates, 8× the shared memory).
pub const RECORDER_SLACK_UPDATES: usize = 2 * RECORDER_MAX_LAG as usize;

/// The most shared memory the subscriber buffers of one publisher may take (16 MiB).
pub const SEGMENT_BUDGET_BYTES: usize = 16 << 20;

/// `distribution`: 1 publisher (updater), up to 4 subscribers (the sampler and the
/// recorder, and room for two more, e.g. a monitor of your own), a buffer of 4 to 32 (see `Limits::distribution_buffer`). Publishers use
/// `initial_max_slice_len(P + P·P)`.
pub fn distribution(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<SliceService<DistributionHeader>, WireError> {
    slice_service(
        node,
        run_id,
        "distribution",
        l.settings(PubSub::Distribution),
    )
}

/// Length of a distribution payload.
pub fn distribution_len(l: &Limits) -> usize {
    l.dim + l.dim * l.dim
}

/// A `distribution` payload split into the mean (P values) and Σ (P×P, column-major); `None`
/// if it holds fewer values than that.
pub fn distribution_parts(payload: &[f64], dim: usize) -> Option<(&[f64], &[f64])> {
    let (mean, rest) = payload.split_at_checked(dim)?;
    Some((mean, rest.get(..dim * dim)?))
}

/// `work/<w>`: 1 publisher (sampler), 2 subscribers (worker w; a crashed predecessor until
/// cleaned), a buffer of K. Publishers use `initial_max_slice_len(P)`.
pub fn work(
    node: &Node<Service>,
    run_id: u64,
    worker: u32,
    l: &Limits,
) -> Result<SliceService<WorkHeader>, WireError> {
    slice_service(
        node,
        run_id,
        &format!("work/{worker}"),
        l.settings(PubSub::Work),
    )
}

/// `costs`: 2·max_workers + 2 publishers, 2 subscribers (updater, recorder), a buffer of
/// 3K + max_workers + 4, raised towards 32·K for the recorder (see `Limits::cost_buffer`).
/// Publishers use `initial_max_slice_len(N)`.
pub fn costs(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<SliceService<CostHeader>, WireError> {
    slice_service(node, run_id, "costs", l.settings(PubSub::Costs))
}

/// `ready`: 2·max_workers + 2 publishers, 2 subscribers, a buffer of 2·max_workers + 4.
pub fn ready(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Ready>, WireError> {
    fixed_service(node, run_id, "ready", l.settings(PubSub::Ready))
}

/// `recorded`: 1 publisher (the recorder), 2 subscribers (updater, spare), a buffer of 4 (only
/// the newest acknowledgement matters).
pub fn recorded(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<RecorderAck>, WireError> {
    fixed_service(node, run_id, "recorded", l.settings(PubSub::Recorded))
}

/// `progress`: 2 publishers, 4 subscribers, a buffer of 8.
pub fn progress(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Progress>, WireError> {
    fixed_service(node, run_id, "progress", l.settings(PubSub::Progress))
}

/// `lifecycle`: 2·max_workers + 6 publishers, 2 subscribers, a buffer of 2·max_workers + 8.
pub fn lifecycle(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Lifecycle>, WireError> {
    fixed_service(node, run_id, "lifecycle", l.settings(PubSub::Lifecycle))
}

/// `joined`: 2 publishers (the recorder; a dead predecessor until cleaned), 2 subscribers (the
/// sampler), a buffer of 2·max_workers + 8. The recorder echoes a worker's [`Lifecycle`]
/// announcement here once it has connected to that worker's publishers (see "The recorder").
pub fn joined(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Lifecycle>, WireError> {
    fixed_service(node, run_id, "joined", l.settings(PubSub::Joined))
}

/// `overdue`: 2 publishers (the sampler), 2 subscribers (the supervisor), a buffer of
/// 2·max_workers + 4: each worker incarnation is reported once.
pub fn overdue(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Overdue>, WireError> {
    fixed_service(node, run_id, "overdue", l.settings(PubSub::Overdue))
}

/// `notes`: 2 publishers (the supervisor), 2 subscribers (the recorder), a buffer of 16.
pub fn notes(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<RunNote>, WireError> {
    fixed_service(node, run_id, "notes", l.settings(PubSub::Notes))
}

/// `reruns`: 2 publishers (the updater; a crashed predecessor until cleaned), 2 subscribers, a
/// buffer of 4: each sample holds all an update's reruns, so an overflow loses nothing.
/// Publishers use `initial_max_slice_len(K)`; only a run with `run.nonfinite_reruns` > 0 opens
/// it.
pub fn reruns(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<CountService<RerunHeader>, WireError> {
    slice_service(node, run_id, "reruns", l.settings(PubSub::Reruns))
}

/// `control`: 2 publishers (the supervisor), 4 subscribers, a buffer of 2·max_workers + 16.
pub fn control(
    node: &Node<Service>,
    run_id: u64,
    l: &Limits,
) -> Result<FixedService<Control>, WireError> {
    fixed_service(node, run_id, "control", l.settings(PubSub::Control))
}

/// The doorbell of a receiving process: `wake/updater`, `wake/sampler`, `wake/supervisor`,
/// `wake/recorder` or `wake/worker/<w>`. Up to 2·max_workers + 6 notifiers, 2 listeners, event
/// ids up to 2 ([`WAKE`], [`HOLD`]).
pub fn doorbell(
    node: &Node<Service>,
    run_id: u64,
    owner: &str,
    l: &Limits,
) -> Result<EventService, WireError> {
    let tail = format!("wake/{owner}");
    let s = l.doorbell_settings();
    open_or_create(run_id, &tail, |name| {
        node.service_builder(name)
            .event()
            .max_notifiers(s.notifiers)
            .max_listeners(s.listeners)
            .max_nodes(s.nodes)
            .event_id_max_value(HOLD.as_value())
            .open_or_create()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rollout_done_report_carries_the_count_of_rollouts_sent() {
        let report = |flags| Ready {
            flags,
            ..Ready::default()
        };
        for sent in [0, 1, 7, 10_000, 65_535] {
            let r = report(Ready::rollout_done(sent));
            assert_ne!(r.flags & Ready::ROLLOUT_DONE, 0);
            assert_eq!(r.sent(), sent);
        }
        // Beyond the 16 bits: as many as fit, never a wrapped smaller count.
        assert_eq!(report(Ready::rollout_done(70_000)).sent(), 65_535);
        // A worker that does not count (flags 1), and a request for work, say nothing.
        assert_eq!(report(Ready::ROLLOUT_DONE).sent(), 0);
        assert_eq!(report(0).sent(), 0);
    }

    #[test]
    fn a_service_of_another_iceoryx2_version_is_named_with_what_to_do() {
        let e = open_or_create::<(), _>(0x2a, "costs", |_| {
            Err(
                PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                    PublishSubscribeOpenError::VersionMismatch,
                ),
            )
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("iceoryx2 service `pi2cma/000000000000002a/costs`: ")
                && e.ends_with(VERSION_MISMATCH_HINT),
            "{e}"
        );
        let e = open_or_create::<(), _>(0x2a, "wake/sampler", |_| {
            Err(EventOpenOrCreateError::EventOpenError(
                EventOpenError::VersionMismatch,
            ))
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("Cargo.lock"), "{e}");
        // Other failures are not taken for it.
        let e = open_or_create::<(), _>(0x2a, "costs", |_| {
            Err(
                PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                    PublishSubscribeOpenError::DoesNotExist,
                ),
            )
        })
        .unwrap_err()
        .to_string();
        assert!(!e.contains("Cargo.lock"), "{e}");
    }

    #[test]
    fn a_service_of_other_message_types_says_the_worker_is_of_another_revision() {
        let e = open_or_create::<(), _>(0x2a, "ready", |_| {
            Err(
                PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                    PublishSubscribeOpenError::IncompatibleTypes,
                ),
            )
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("iceoryx2 service `pi2cma/000000000000002a/ready`: ")
                && e.ends_with(CONTRACT_MISMATCH_HINT),
            "{e}"
        );
    }

    #[test]
    fn layouts_are_stable() {
        // A foreign worker relies on these sizes; changing them needs a new type name version.
        assert_eq!(
            std::mem::size_of::<DistributionHeader>(),
            56 + 16 * MAX_SETTINGS
        );
        assert_eq!(std::mem::size_of::<WorkHeader>(), 48 + 16 * MAX_SETTINGS);
        assert_eq!(std::mem::size_of::<CostHeader>(), 56 + 8 * MAX_SETTINGS);
        assert_eq!(std::mem::size_of::<Ready>(), 32);
        assert_eq!(std::mem::size_of::<Lifecycle>(), 24);
        assert_eq!(std::mem::size_of::<Control>(), 32 + MAX_NAME + 24);
        assert_eq!(std::mem::size_of::<Progress>(), 96 + 8 * MAX_SETTINGS);
        assert_eq!(std::mem::size_of::<RecorderAck>(), 32);
        assert_eq!(std::mem::size_of::<Overdue>(), 56);
        assert_eq!(std::mem::size_of::<RunNote>(), 16 + MAX_NOTE);
    }

    #[test]
    fn recorder_lag_fits_the_buffers() {
        let via_point = Limits {
            max_workers: 16,
            rollouts: 15,
            dim: 2,
            steps: 101,
        };
        assert_eq!(via_point.recorder_max_lag(), RECORDER_MAX_LAG);
        // A large policy: a distribution is ~1 MB, so only 4 fit in the 16 MiB budget.
        let large = Limits {
            max_workers: 16,
            rollouts: 50,
            dim: 350,
            steps: 1000,
        };
        assert_eq!(large.distribution_buffer(), 4);
        assert_eq!(large.recorder_max_lag(), 4);
        // Long rollouts: the 16 MiB budget holds 52 cost messages of N = 20 001 steps, less
        // than 3 updates' worth; the buffer is made large enough for the least lag anyway.
        let long = Limits {
            max_workers: 16,
            rollouts: 15,
            dim: 2,
            steps: 20_001,
        };
        assert_eq!(long.recorder_max_lag(), MIN_RECORDER_LAG);
        for l in [via_point, large, long] {
            let lag = l.recorder_max_lag() as usize;
            assert!(lag <= l.distribution_buffer());
            assert!((lag + 1) * l.rollouts + l.max_workers + 4 <= l.cost_buffer());
            // Without reruns the count of cost messages never holds the updater (L updates of
            // K, the next one's K), and a held rerun always goes once the recorder has taken
            // everything: K rollouts rerun at once fit.
            assert!(((lag + 1) * l.rollouts) as u64 <= l.recorder_cost_room());
            assert!(2 * l.rollouts as u64 <= l.recorder_cost_room());
        }
    }

    #[test]
    fn a_distribution_payload_splits_into_mean_and_covariance() {
        let payload = [1.0, 2.0, 3.0, 0.0, 0.0, 4.0, 9.0];
        let (mean, cov) = distribution_parts(&payload, 2).unwrap();
        assert_eq!((mean, cov), (&[1.0, 2.0][..], &[3.0, 0.0, 0.0, 4.0][..]));
        assert_eq!(distribution_parts(&payload[..5], 2), None);
        assert_eq!(distribution_parts(&payload[..1], 2), None);
    }

    #[test]
    fn settings_unpack_as_packed_and_never_beyond_the_array() {
        let (values, len) = pack_settings(&[0.5, -1.0]);
        assert_eq!(unpack_settings(&values, len), [0.5, -1.0]);
        assert_eq!(unpack_settings(&values, 0), [0.0; 0]);
        assert_eq!(unpack_settings(&values, u32::MAX).len(), MAX_SETTINGS);
    }

    #[test]
    fn worker_node_names_round_trip() {
        assert_eq!(
            parse_worker_node_name(&worker_node_name(3, 7)),
            Some((3, 7))
        );
        assert_eq!(parse_worker_node_name("sampler"), None);
        assert_eq!(parse_worker_node_name("worker-3"), None);
    }

    #[test]
    fn doorbells_have_the_names_foreign_workers_use() {
        // README's wire section and tools/pi2cma_worker.py name them so.
        let name = |owner: &str| service_name(0x2a, &format!("wake/{owner}")).unwrap();
        assert_eq!(
            name(&worker_doorbell(3)).as_str(),
            "pi2cma/000000000000002a/wake/worker/3"
        );
        for (owner, tail) in [
            (process::UPDATER, "updater"),
            (process::SAMPLER, "sampler"),
            (process::SUPERVISOR, "supervisor"),
            (process::RECORDER, "recorder"),
        ] {
            assert_eq!(
                name(owner).as_str(),
                format!("pi2cma/000000000000002a/wake/{tail}")
            );
        }
    }

    #[test]
    fn run_notes_round_trip_and_are_cut_at_a_character() {
        let n = RunNote::new(7, RunNote::ERROR, "worker-1 died: restart limit exhausted");
        assert_eq!(
            (n.level, n.text()),
            (RunNote::ERROR, "worker-1 died: restart limit exhausted")
        );
        let long = format!("{}é", "x".repeat(MAX_NOTE - 1));
        assert_eq!(
            RunNote::new(7, RunNote::INFO, &long).text(),
            "x".repeat(MAX_NOTE - 1)
        );
    }

    #[test]
    fn control_names_round_trip_and_are_bounded() {
        let c = Control::set_task(7, 3, "viapoint", 0.1).unwrap();
        assert_eq!((c.name(), c.seq, c.value), ("viapoint", 3, 0.1));
        assert!(Control::set_task(7, 4, &"x".repeat(MAX_NAME + 1), 0.0).is_none());
        let c = Control::worker_lost(7, 2, 1, 42, lost::CRASHED, "signal: 9 (SIGKILL)");
        assert_eq!(
            (c.kind, c.worker, c.incarnation),
            (Control::WORKER_LOST, 2, 1)
        );
        assert_eq!((c.reason, c.name()), (lost::CRASHED, "signal: 9 (SIGKILL)"));
        // Cut to MAX_NAME bytes, never inside a character.
        let long = format!("{}é", "x".repeat(MAX_NAME - 1));
        let c = Control::worker_lost(7, 0, 0, 42, lost::EXITED, &long);
        assert_eq!(c.name(), "x".repeat(MAX_NAME - 1));
    }
}
