//! The sampler: turns each published distribution into the update's K parameter vectors (the
//! core's pure `ParameterBatch::sample`) and hands them out by load. Each worker that announces
//! [`wire::Ready`] gets ⌈pending / workers⌉ rollouts, pending as at the start of the hand-out:
//! equal shares at the start of an update, smaller ones while some workers are still busy
//! (guided self-scheduling), so a fast worker takes more rollouts than a slow one. When rollouts
//! are slow, a chunk holds at most 50 ms of them (`CHUNK_TIME`; as measured on the chunks
//! before; one until the first chunk is back), so that work stays queued through the update:
//! a worker that joins mid-update (a scale-up), or finishes early, takes rollouts of this
//! update instead of waiting for the next. Rollouts of a
//! lost worker go back to the pending queue. A worker that holds a chunk and shows no progress
//! (a cost sent, reported with [`Ready::ROLLOUT_DONE`]) for longer than
//! `pipeline.rollout_timeout_ms` is reported to the supervisor (`overdue`), which kills and
//! restarts it. A rollout the updater asks for again (on `reruns`: its costs were not finite)
//! goes back to the front of the queue. A new worker incarnation gets work only once the
//! recorder, if there is one, has connected to it (`Joins`).

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use nalgebra::{DMatrix, DVector};
use pi2cma::{Distribution, ParameterBatch};
use wire::{Control, DistributionHeader, Ready, Service, WorkHeader, MAX_SETTINGS};

use crate::{
    announce_ready, iox, wait_loop, Context, Flow, OncePerWorker, Ports as _, ProcessArgs, Say,
};

/// The distribution of a `distribution` sample; one too short for the run's P is an error, as
/// in the recorder (it came from another process).
fn received_distribution(
    h: &DistributionHeader,
    p: &[f64],
    dim: usize,
) -> anyhow::Result<Distribution> {
    let Some((mean, cov)) = wire::distribution_parts(p, dim) else {
        anyhow::bail!(
            "distribution of update {}: {} values, expected {}",
            h.update,
            p.len(),
            dim + dim * dim
        );
    };
    Ok(Distribution {
        mean: DVector::from_column_slice(mean),
        covariance: DMatrix::from_column_slice(dim, dim, cov),
    })
}

/// The rollouts whose count in `counts` (a `reruns` sample) is above the one in `seen`, which
/// is raised to match: each has had an execution rejected since the last sample read. Counts
/// only grow within an update, so reading only the newest of several samples finds the same
/// rollouts.
fn raised(seen: &mut [u32], counts: &[u32]) -> Vec<u32> {
    let mut out = Vec::new();
    for (k, (s, &c)) in seen.iter_mut().zip(counts).enumerate() {
        if c > *s {
            *s = c;
            out.push(k as u32);
        }
    }
    out
}

/// The most work a chunk holds once the rollouts' duration is known: the sampler's round trip
/// per chunk (tens of µs, up to a few hundred on a busy machine) stays well below 1% of it, and
/// work handed out ahead of the workers is never more than this per worker. Only rollouts slower
/// than CHUNK_TIME / ⌈K / workers⌉ (3.3 ms for K = 15 and one worker) get smaller chunks.
const CHUNK_TIME: Duration = Duration::from_millis(50);

/// Rollouts in each chunk of a hand-out round: ⌈pending / available⌉, at most [`CHUNK_TIME`]
/// of rollouts that take `per_rollout` each, at least 1. Before any chunk came back
/// (`per_rollout` unknown) one: a rollout may take seconds on a robot, and a whole first update
/// handed out blind would leave a worker that joins during it idle to its end; fast rollouts
/// pay one round trip per worker for it, once.
fn chunk_len(pending: usize, available: usize, per_rollout: Option<Duration>) -> usize {
    let share = pending.div_ceil(available.max(1)).max(1);
    match per_rollout {
        None => 1,
        Some(t) if t.is_zero() => share,
        Some(t) => {
            let fit = (CHUNK_TIME.as_nanos() / t.as_nanos()).max(1);
            share.min(usize::try_from(fit).unwrap_or(usize::MAX))
        }
    }
}

/// How often the sampler looks for dead worker nodes.
const DEAD_SCAN: Duration = Duration::from_secs(1);

/// How long the update must have waited for nothing but held-back rollouts (queue empty, no
/// chunk of it out) before they are handed out again: their costs then died with their worker.
/// The updater publishes the next distribution within micro- to milliseconds of its last cost,
/// so this is waited out only when a cost was really lost, or when the updater itself waits (for
/// a recorder behind by its lag bound): then they run again, which the result does not see
/// (the updater keeps a rollout's first cost).
const HELD_BACK_RELEASE: Duration = Duration::from_millis(100);

/// A longer time between two overdue checks (which come at least every `wait_loop` tick, 0.1
/// s) means the sampler was not running: see the check.
const OVERDUE_CHECK_GAP: Duration = Duration::from_secs(1);

type Inbox = (Publisher<Service, [f64], WorkHeader>, Notifier<Service>);

struct Assignment {
    chunk: u64,
    update: u64,
    rollouts: Vec<u32>,
    /// When it was handed out.
    since: Instant,
    /// When the sampler last learnt of progress on it: the hand-out, or the latest
    /// [`Ready::ROLLOUT_DONE`] of its worker. `pipeline.rollout_timeout_ms` counts from here,
    /// so it bounds one rollout, not the chunk: a worker that hangs in its chunk's second
    /// rollout is found about one timeout after its first was done, not chunk-length timeouts
    /// after the hand-out.
    progress: Instant,
    /// How many of `rollouts` (from the first) the worker reported sent
    /// ([`Ready::rollout_done`]): if it is lost, those are held back ([`HeldBack`]).
    sent: usize,
}

struct WorkerPort {
    incarnation: u32,
    inbox: Publisher<Service, [f64], WorkHeader>,
    bell: Notifier<Service>,
    assignment: Option<Assignment>,
    /// The chunk it held too long (reported on `overdue`, its rollouts handed to the others):
    /// the worker is idle again if it ever finishes it.
    overdue_chunk: Option<u64>,
}

struct Current {
    update: u64,
    batch: ParameterBatch,
    settings: [f64; MAX_SETTINGS],
    previous_settings: [f64; MAX_SETTINGS],
    settings_len: u32,
}

/// The `sampler` process: opens the run's services, announces itself, and serves until the
/// run's final distribution, SIGINT or SIGTERM. Fails on a config or service error, or on a
/// distribution not of the run's shape.
pub fn main(args: &ProcessArgs) -> anyhow::Result<()> {
    let ctx = Context::new(args, wire::process::SAMPLER)?;
    let (dim, k_total, steps) = (ctx.limits.dim, ctx.limits.rollouts, ctx.limits.steps);
    let dist =
        wire::distribution(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("distribution")?;
    let ready = wire::ready(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("ready")?;
    let control = wire::control(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("control")?;
    let joined_service = wire::joined(&ctx.node, ctx.run_id, &ctx.limits)?;
    let joined = joined_service.subscriber("joined")?;
    let mut joins = Joins::default();
    let rerun_requests = match ctx.config.run.nonfinite_reruns {
        0 => None,
        _ => Some(wire::reruns(&ctx.node, ctx.run_id, &ctx.limits)?.subscriber("reruns")?),
    };
    let overdue = wire::overdue(&ctx.node, ctx.run_id, &ctx.limits)?.publisher("overdue")?;
    let supervisor_bell = ctx.notifier(wire::process::SUPERVISOR)?;
    let rollout_timeout = ctx
        .config
        .pipeline()
        .rollout_timeout_ms
        .map(Duration::from_millis);
    let doorbell = ctx.listener(wire::process::SAMPLER)?;
    let _announced = announce_ready(&ctx, wire::role::SAMPLER, 0, 0)?;

    let mut workers: BTreeMap<u32, WorkerPort> = BTreeMap::new();
    let mut idle: VecDeque<u32> = VecDeque::new();
    let mut pending: VecDeque<u32> = VecDeque::new();
    let mut held_back = HeldBack::default();
    // The updater's rejected executions per rollout of the current update, as of the newest
    // `reruns` sample read: a rollout with a count is a rerun, and its work items say so
    // (WorkHeader::RERUN).
    let mut rerun_counts: Vec<u32> = vec![0; k_total];
    let mut current: Option<Current> = None;
    let mut next_chunk: u64 = 0;
    // The time a rollout takes, from hand-out to Ready of the chunks done (a moving average,
    // latencies included): sizes the chunks (chunk_len).
    let mut per_rollout: Option<Duration> = None;
    let mut finished = false;
    let mut beyond = OncePerWorker::default();
    let mut last_scan = Instant::now();
    let mut last_overdue_check = Instant::now();
    // PI2CMA_TRACE=1: one line per distribution, request and chunk (µs since start).
    let trace = std::env::var_os("PI2CMA_TRACE").is_some();
    let t0 = std::time::Instant::now();
    let us = || t0.elapsed().as_micros();

    wait_loop(&doorbell, || {
        // Lost workers: their unfinished rollouts go back to the queue. The supervisor reports
        // the ones it manages; dead worker nodes (e.g. a crashed worker of another language
        // that nobody restarts) are found by scanning the run's nodes once a second.
        let mut lost: Vec<(u32, u32)> = Vec::new();
        while let Some(msg) = iox(control.receive(), "receive control")? {
            let m = *msg.payload();
            if m.run_id != ctx.run_id {
                continue;
            }
            match m.kind {
                Control::WORKER_LOST => lost.push((m.worker, m.incarnation)),
                Control::RECORDER_LOST => joins.recorder_lost = true,
                Control::RECORDER_BACK => joins.recorder_lost = false,
                _ => {}
            }
        }
        if last_scan.elapsed() >= DEAD_SCAN {
            last_scan = Instant::now();
            let nodes = ctx.scan_nodes();
            lost.extend(
                nodes
                    .dead
                    .iter()
                    .filter_map(|n| wire::parse_worker_node_name(n)),
            );
            // A worker that ended in order in the middle of its chunk (one started by hand and
            // stopped with Ctrl-C or SIGTERM) has removed its node: it is not dead, and nobody
            // reports a worker the supervisor did not start, so its chunk was waited for
            // forever. Its node was alive when its Ready arrived.
            if let Some(alive) = nodes.alive {
                lost.extend(
                    workers
                        .iter()
                        .map(|(&w, port)| (w, port.incarnation))
                        .filter(|&(w, i)| !alive.contains(&wire::worker_node_name(w, i))),
                );
            }
        }
        for (worker, incarnation) in lost {
            if workers
                .get(&worker)
                .is_some_and(|w| w.incarnation == incarnation)
            {
                let w = workers.remove(&worker).expect("checked above");
                if trace {
                    let n = w.assignment.as_ref().map_or(0, |a| a.rollouts.len());
                    eprintln!("{} lost w{worker}.{incarnation}, holding {n}", us());
                }
                requeue(w.assignment, &current, &mut pending, &mut held_back);
                idle.retain(|i| *i != worker);
                joins.waiting.remove(&worker);
            }
        }
        // The newest distribution starts a new update.
        let mut newest = None;
        while let Some(sample) = iox(dist.receive(), "receive distribution")? {
            let h = *sample.user_header();
            if h.run_id != ctx.run_id || current.as_ref().is_some_and(|c| c.update >= h.update) {
                continue;
            }
            if h.flags & DistributionHeader::FINAL != 0 {
                finished = true;
                newest = None;
                continue;
            }
            newest = Some((h, received_distribution(&h, sample.payload(), dim)?));
        }
        if let Some((h, d)) = newest {
            current = Some(Current {
                update: h.update,
                batch: ParameterBatch::sample(&d, h.seed, h.update, k_total),
                settings: h.settings,
                previous_settings: h.previous_settings,
                settings_len: h.settings_len,
            });
            pending = (0..k_total as u32).collect();
            held_back.clear();
            rerun_counts.fill(0);
            if trace {
                eprintln!("{} dist {} idle {:?}", us(), h.update, idle);
            }
        }
        // Rollouts whose costs were not finite: the update waits for them, so a sample of
        // another update is stale.
        while let Some(sample) = match &rerun_requests {
            Some(requests) => iox(requests.receive(), "receive reruns")?,
            None => None,
        } {
            let h = *sample.user_header();
            if h.run_id != ctx.run_id || current.as_ref().is_none_or(|c| c.update != h.update) {
                continue;
            }
            for k in raised(&mut rerun_counts, sample.payload()) {
                held_back.forget(k);
                if !pending.contains(&k) {
                    pending.push_front(k);
                }
                if trace {
                    eprintln!("{} rerun {}/{k}", us(), h.update);
                }
            }
        }
        if finished {
            pending.clear();
            held_back.clear();
        }
        // Workers asking for work.
        while let Some(msg) = iox(ready.receive(), "receive ready")? {
            let r = *msg.payload();
            if r.run_id != ctx.run_id {
                continue;
            }
            if trace {
                eprintln!("{} ready w{} chunk {}", us(), r.worker, r.chunk as i64);
            }
            // A worker of another config (or revision) may ask from a slot the run's services
            // and shared memory are not sized for (the built-in worker refuses such a slot at
            // start): it gets no work, and opening its inbox, which may fail, would fail the run.
            if r.worker as usize >= ctx.limits.max_workers {
                beyond_slots(&mut beyond, &r, ctx.limits.max_workers);
                continue;
            }
            if r.flags & Ready::ROLLOUT_DONE != 0 {
                let on_its_chunk = workers
                    .get_mut(&r.worker)
                    .filter(|w| w.incarnation == r.incarnation)
                    .and_then(|w| w.assignment.as_mut())
                    .filter(|a| a.chunk == r.chunk);
                if let Some(a) = on_its_chunk {
                    // When read, not when sent: a sampler that was not scheduled for a while
                    // takes the progress as later than it was, never a rollout as longer.
                    a.progress = Instant::now();
                    a.sent = a.sent.max(r.sent().min(a.rollouts.len()));
                }
                continue;
            }
            match workers.get_mut(&r.worker) {
                Some(w) if r.incarnation < w.incarnation => {} // from a lost predecessor
                Some(w) if r.incarnation == w.incarnation => {
                    let done = r.chunk != Ready::NO_CHUNK;
                    let assigned =
                        done && w.assignment.as_ref().is_some_and(|a| a.chunk == r.chunk);
                    let late = done && w.overdue_chunk == Some(r.chunk);
                    if let Some(a) = w.assignment.take_if(|_| assigned) {
                        let took = a.since.elapsed() / a.rollouts.len().max(1) as u32;
                        per_rollout = Some(per_rollout.map_or(took, |t| (t * 3 + took) / 4));
                    }
                    if late {
                        w.overdue_chunk = None;
                    }
                    if (assigned || late) && !idle.contains(&r.worker) {
                        idle.push_back(r.worker);
                    }
                }
                _ => {
                    // A new worker, or a restarted one: what its predecessor held is requeued.
                    let old = workers.remove(&r.worker);
                    let (inbox, bell) = match old {
                        Some(w) => {
                            requeue(w.assignment, &current, &mut pending, &mut held_back);
                            (w.inbox, w.bell)
                        }
                        None => open_inbox(&ctx, r.worker)?,
                    };
                    workers.insert(
                        r.worker,
                        WorkerPort {
                            incarnation: r.incarnation,
                            inbox,
                            bell,
                            assignment: None,
                            overdue_chunk: None,
                        },
                    );
                    idle.retain(|i| *i != r.worker);
                    let recorder = joined_service.dynamic_config().number_of_publishers() > 0;
                    if joins.must_wait(r.worker, r.incarnation, recorder) {
                        joins.wait(&r);
                    } else {
                        joins.waiting.remove(&r.worker);
                        idle.push_back(r.worker);
                    }
                }
            }
        }
        // Incarnations the recorder has connected to (echoed on `joined`) may have work now.
        while let Some(sample) = iox(joined.receive(), "receive joined")? {
            let j = *sample.payload();
            if j.run_id == ctx.run_id && j.role == wire::role::WORKER {
                joins.joined(j.worker, j.incarnation);
            }
        }
        // Asked only while a worker waits: the round is the sampler's hot path.
        if !joins.waiting.is_empty() {
            let recorder = joined_service.dynamic_config().number_of_publishers() > 0;
            for worker in joins.released(recorder, Instant::now()) {
                if workers.contains_key(&worker) && !idle.contains(&worker) {
                    idle.push_back(worker);
                }
            }
        }
        // Workers that hold their chunk too long (checked at least every wait_loop TICK). Only
        // after their Ready messages are read: a sampler that was not scheduled for a while (or
        // stopped) would otherwise find the chunks its workers finished meanwhile overdue.
        if let Some(per_rollout) = rollout_timeout {
            // Time the sampler did not run for is not the workers' to account for: a run
            // suspended with Ctrl-Z (the supervisor stops every process) or a machine that
            // slept had them stopped as well, and each worker holding a chunk was found
            // overdue, killed and restarted, at once when the run was continued. After such a
            // gap each held chunk's timeout counts afresh.
            let now = Instant::now();
            if now.duration_since(last_overdue_check) > OVERDUE_CHECK_GAP {
                for a in workers.values_mut().filter_map(|w| w.assignment.as_mut()) {
                    a.progress = now;
                }
            }
            last_overdue_check = now;
            for (&worker, w) in workers.iter_mut() {
                let Some(a) = &w.assignment else { continue };
                let stalled = a.progress.elapsed();
                if stalled <= per_rollout {
                    continue;
                }
                let report = wire::Overdue {
                    run_id: ctx.run_id,
                    update: a.update,
                    chunk: a.chunk,
                    held_ms: a.since.elapsed().as_millis() as u64,
                    stalled_ms: stalled.as_millis() as u64,
                    worker,
                    incarnation: w.incarnation,
                    rollouts: a.rollouts.len() as u32,
                    _reserved: 0,
                };
                iox(overdue.send_copy(report), "send overdue")?;
                // The supervisor gone too is no reason to fail; it sees the report when it can.
                let _ = supervisor_bell.notify_with_custom_event_id(wire::WAKE);
                if trace {
                    eprintln!(
                        "{} overdue w{worker}.{} chunk {}",
                        us(),
                        w.incarnation,
                        a.chunk
                    );
                }
                // Its rollouts go to the others now, whether or not the supervisor can kill it
                // (a worker it did not start): should it answer after all, the updater keeps
                // whichever result of a rollout comes first, and they are the same.
                w.overdue_chunk = Some(a.chunk);
                requeue(w.assignment.take(), &current, &mut pending, &mut held_back);
            }
        }
        // Hand out work.
        let Some(cur) = current.as_ref() else {
            return Ok(Flow::Continue);
        };
        let busy = || {
            !pending.is_empty()
                || workers.values().any(|w| {
                    w.assignment
                        .as_ref()
                        .is_some_and(|a| a.update == cur.update)
                })
        };
        let released = held_back.release(busy, Instant::now());
        if trace && !released.is_empty() {
            eprintln!("{} released {released:?}", us());
        }
        pending.extend(released);
        // The share is fixed for this round: at the start of an update every worker gets
        // ⌈K / workers⌉ (5 and 5 for K = 10 and 2 workers, where shrinking per hand-out gave
        // 5, 3, 1, 1: two more round trips through the sampler on the update's critical path).
        // Rounds that find some workers still busy shrink the share as guided self-scheduling
        // does. A worker that holds an overdue chunk (one that joined by itself and hung: not
        // the supervisor's to kill) does not count: it takes no share.
        let available = workers
            .iter()
            .filter(|(id, w)| w.overdue_chunk.is_none() && !joins.waiting.contains_key(id))
            .count();
        let share = chunk_len(pending.len(), available, per_rollout);
        // Plan the round first: whether it empties the queue goes into every chunk's header
        // (WorkHeader::QUEUE_EMPTY: its worker then reports Ready without ringing the sampler).
        let mut round: Vec<(u32, Vec<u32>)> = Vec::new();
        while !pending.is_empty() {
            let Some(id) = idle.pop_front() else { break };
            if workers.contains_key(&id) {
                round.push((id, pending.drain(..share.min(pending.len())).collect()));
            }
        }
        let flags = if pending.is_empty() {
            WorkHeader::QUEUE_EMPTY
        } else {
            0
        };
        // Every chunk is published before any worker is rung: a rung worker may take this CPU
        // before the sampler has rung the next one.
        let mut to_ring: Vec<u32> = Vec::new();
        for (id, rollouts) in round {
            let Some(w) = workers.get_mut(&id) else {
                continue;
            };
            let chunk = next_chunk;
            next_chunk += 1;
            let mut delivered = true;
            for &k in &rollouts {
                let sample = iox(w.inbox.loan_slice_uninit(dim), "loan work item")?;
                let mut sample = sample.write_from_slice(cur.batch.row(k as usize));
                *sample.user_header_mut() = WorkHeader {
                    run_id: ctx.run_id,
                    update: cur.update,
                    chunk,
                    rollout: k,
                    chunk_len: rollouts.len() as u32,
                    worker: id,
                    steps: steps as u32,
                    settings_len: cur.settings_len,
                    flags: if rerun_counts[k as usize] > 0 {
                        flags | WorkHeader::RERUN
                    } else {
                        flags
                    },
                    settings: cur.settings,
                    previous_settings: cur.previous_settings,
                };
                if iox(sample.send(), "send work item")? == 0 {
                    delivered = false;
                }
            }
            if !delivered {
                // Its inbox has no subscriber: the worker is gone. Its rollouts go to the next
                // worker that reports Ready; if the round's other chunks said QUEUE_EMPTY, that
                // is at the latest the next tick (wait_loop's TICK).
                workers.remove(&id);
                for k in rollouts.into_iter().rev() {
                    pending.push_front(k);
                }
                continue;
            }
            if trace {
                eprintln!("{} chunk {chunk} -> w{id}: {:?}", us(), rollouts);
            }
            let now = Instant::now();
            w.assignment = Some(Assignment {
                chunk,
                update: cur.update,
                rollouts,
                since: now,
                progress: now,
                sent: 0,
            });
            to_ring.push(id);
        }
        for id in to_ring {
            if let Some(w) = workers.get(&id) {
                iox(
                    w.bell.notify_with_custom_event_id(wire::WAKE),
                    "notify worker",
                )?;
            }
        }
        Ok(Flow::Continue)
    })?;
    Ok(())
}

/// How long a worker incarnation may wait for the recorder to connect to it before the sampler
/// says so: a running recorder does within one of its rounds (a millisecond; at most
/// `wait_loop`'s tick when idle).
const JOIN_WAIT_SAID: Duration = Duration::from_secs(2);

/// The worker incarnations the recorder has connected to, and those waiting for it to. iceoryx2
/// keeps what a departed publisher sent only for the subscribers that had connected to it, and
/// a subscriber connects when it next looks: a worker that joined while the recorder was
/// stalled (stopped, a write held by a slow disk, starved of CPU), worked and crashed took its
/// costs with it, and their updates were not recorded. So a new incarnation gets work only once
/// the recorder has echoed its announcement on `joined` (or a later incarnation's of its slot)
/// — unless there is no recorder to wait for: `joined` has no publisher (`--no-record`, one
/// not yet started, a dead one cleaned up), or the supervisor reported it lost.
#[derive(Debug, Default)]
struct Joins {
    /// Per slot, the newest incarnation echoed.
    echoed: BTreeMap<u32, u32>,
    /// Per slot, the incarnation waiting: (incarnation, pid, since, said).
    waiting: BTreeMap<u32, (u32, u32, Instant, bool)>,
    /// The supervisor reported the recorder gone and not restarted (until RECORDER_BACK).
    recorder_lost: bool,
}

impl Joins {
    fn joined(&mut self, worker: u32, incarnation: u32) {
        let e = self.echoed.entry(worker).or_insert(incarnation);
        *e = (*e).max(incarnation);
    }

    fn connected(echoed: &BTreeMap<u32, u32>, worker: u32, incarnation: u32) -> bool {
        echoed.get(&worker).is_some_and(|&e| e >= incarnation)
    }

    /// Whether incarnation `incarnation` of slot `worker`, asking for work for the first
    /// time, must wait; `recorder`: `joined` has a publisher.
    fn must_wait(&self, worker: u32, incarnation: u32, recorder: bool) -> bool {
        recorder && !self.recorder_lost && !Self::connected(&self.echoed, worker, incarnation)
    }

    fn wait(&mut self, r: &Ready) {
        self.waiting
            .insert(r.worker, (r.incarnation, r.pid, Instant::now(), false));
    }

    /// The slots whose incarnation may have work now; says on stderr which have waited
    /// longer than [`JOIN_WAIT_SAID`], and when they no longer do.
    fn released(&mut self, recorder: bool, now: Instant) -> Vec<u32> {
        let mut out = Vec::new();
        let no_recorder = !recorder || self.recorder_lost;
        for (&worker, (incarnation, pid, since, said)) in &mut self.waiting {
            let waited = now.duration_since(*since);
            let connected = Self::connected(&self.echoed, worker, *incarnation);
            if connected || no_recorder {
                if *said {
                    let why = if connected {
                        "the recorder has connected to it"
                    } else {
                        "there is no recorder to wait for"
                    };
                    eprintln!(
                        "worker-{worker} (pid {pid}) gets work after {:.1} s: {why}",
                        waited.as_secs_f64()
                    );
                }
                out.push(worker);
            } else if !*said && waited >= JOIN_WAIT_SAID {
                *said = true;
                eprintln!(
                    "worker-{worker} (pid {pid}) has waited {:.1} s for the recorder to connect \
                     to it and gets no work until it has (so that its costs are recorded even \
                     if it crashes): is the recorder stalled?",
                    waited.as_secs_f64()
                );
            }
        }
        for w in &out {
            self.waiting.remove(w);
        }
        out
    }
}

/// Rollouts of the current update that a lost worker reported sent. Their costs almost always
/// reached the updater, which then finishes the update without them; so they are handed out
/// again only once the update has waited for nothing else for [`HELD_BACK_RELEASE`] (their
/// costs died with the worker). Handing them out at once ran finished rollouts again (on a
/// robot, for real), and a worker that hung every few rollouts, fewer than a chunk holds, kept
/// an update from ever finishing.
#[derive(Debug, Default)]
struct HeldBack {
    rollouts: Vec<u32>,
    /// Since when the update has waited for nothing but these.
    idle_since: Option<Instant>,
}

impl HeldBack {
    fn hold(&mut self, k: u32) {
        if !self.rollouts.contains(&k) {
            self.rollouts.push(k);
        }
    }

    /// Rollout `k` is being handed out again anyway (a rerun of a non-finite cost).
    fn forget(&mut self, k: u32) {
        self.rollouts.retain(|&h| h != k);
    }

    fn clear(&mut self) {
        self.rollouts.clear();
        self.idle_since = None;
    }

    /// Called every round, `busy` telling whether the queue holds rollouts or a chunk of the
    /// update is out (asked only while something is held back: the round is the sampler's hot
    /// path): the rollouts to hand out again now (none until the update has waited for nothing
    /// else for [`HELD_BACK_RELEASE`]).
    fn release(&mut self, busy: impl FnOnce() -> bool, now: Instant) -> Vec<u32> {
        if self.rollouts.is_empty() || busy() {
            self.idle_since = None;
            return Vec::new();
        }
        let since = *self.idle_since.get_or_insert(now);
        if now.duration_since(since) < HELD_BACK_RELEASE {
            return Vec::new();
        }
        self.idle_since = None;
        std::mem::take(&mut self.rollouts)
    }
}

/// A lost worker's chunk of the current update: the rollouts it did not report sent go to the
/// front of the queue, those it did are held back ([`HeldBack`]).
fn requeue(
    assignment: Option<Assignment>,
    current: &Option<Current>,
    pending: &mut VecDeque<u32>,
    held_back: &mut HeldBack,
) {
    if let (Some(a), Some(c)) = (assignment, current) {
        if a.update == c.update {
            let (sent, unsent) = a.rollouts.split_at(a.sent);
            for &k in unsent.iter().rev() {
                if !pending.contains(&k) {
                    pending.push_front(k);
                }
            }
            for &k in sent.iter().filter(|k| !pending.contains(k)) {
                held_back.hold(k);
            }
        }
    }
}

/// The warning for a `Ready` of worker `r.worker`, at or above `max_workers`, if one is due.
fn beyond_slots(once: &mut OncePerWorker, r: &Ready, max_workers: usize) {
    match once.say(r.worker) {
        Say::First => eprintln!(
            "warning: worker {} (pid {}, incarnation {}) asked for work, but worker ids must be \
             below pipeline.max_workers = {max_workers} (the slots this run is sized for): it \
             gets none, and its further requests are ignored without a word. Was it started \
             with another config?",
            r.worker, r.pid, r.incarnation
        ),
        Say::Last => eprintln!(
            "warning: worker {} (pid {}) asked for work too: more than {} worker ids at or \
             above pipeline.max_workers = {max_workers} asked; any more are ignored without a \
             word",
            r.worker,
            r.pid,
            OncePerWorker::NAMED
        ),
        Say::Nothing => {}
    }
}

fn open_inbox(ctx: &Context, worker: u32) -> anyhow::Result<Inbox> {
    let inbox = iox(
        wire::work(&ctx.node, ctx.run_id, worker, &ctx.limits)?
            .publisher_builder()
            .initial_max_slice_len(ctx.limits.dim)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(2)
            .create(),
        "work publisher",
    )?;
    let bell = ctx.notifier(&wire::worker_doorbell(worker))?;
    Ok((inbox, bell))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ready(worker: u32, incarnation: u32) -> Ready {
        Ready {
            worker,
            incarnation,
            pid: 7,
            ..Ready::default()
        }
    }

    /// A new incarnation waits for the recorder's echo of it or of a later incarnation of its
    /// slot, and not at all without a recorder or once the supervisor reported it lost.
    #[test]
    fn a_worker_waits_for_the_recorders_echo_only_while_there_is_a_recorder() {
        let mut joins = Joins::default();
        assert!(!joins.must_wait(0, 1, false), "no recorder");
        assert!(joins.must_wait(0, 1, true));
        joins.wait(&ready(0, 1));
        joins.wait(&ready(1, 0));
        let now = Instant::now();
        assert!(joins.released(true, now).is_empty());
        joins.joined(0, 2);
        joins.joined(1, 0);
        assert_eq!(joins.released(true, now), [0, 1]);
        assert!(!joins.must_wait(0, 2, true));
        assert!(joins.must_wait(0, 3, true));
        joins.wait(&ready(0, 3));
        assert_eq!(
            joins.released(false, now),
            [0],
            "the recorder's publisher is gone"
        );
        joins.recorder_lost = true;
        assert!(!joins.must_wait(2, 0, true));
        joins.recorder_lost = false;
        assert!(joins.must_wait(2, 0, true));
    }

    #[test]
    fn a_distribution_of_another_length_than_the_runs_is_an_error() {
        let h = DistributionHeader {
            update: 7,
            ..DistributionHeader::default()
        };
        let d = received_distribution(&h, &[1.0, 2.0, 3.0, 0.0, 0.0, 4.0], 2).unwrap();
        assert_eq!(d.mean.as_slice(), [1.0, 2.0]);
        assert_eq!(d.covariance.as_slice(), [3.0, 0.0, 0.0, 4.0]);
        let e = received_distribution(&h, &[1.0, 2.0, 3.0], 2)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("update 7") && e.contains("3 values") && e.contains("expected 6"),
            "{e}"
        );
    }

    #[test]
    fn held_back_rollouts_are_released_only_after_the_update_waited_for_nothing_else() {
        let t0 = Instant::now();
        let ms = |n| t0 + Duration::from_millis(n);
        let mut h = HeldBack::default();
        assert!(h.release(|| false, t0).is_empty());
        h.hold(3);
        h.hold(4);
        h.hold(3);
        // Other rollouts out or queued: the update may still finish without 3 and 4.
        assert!(h.release(|| true, ms(0)).is_empty());
        assert!(h.release(|| false, ms(10)).is_empty());
        assert!(h.release(|| false, ms(60)).is_empty());
        // Busy again: the wait starts over.
        assert!(h.release(|| true, ms(100)).is_empty());
        assert!(h.release(|| false, ms(120)).is_empty());
        assert!(h.release(|| false, ms(219)).is_empty());
        assert_eq!(h.release(|| false, ms(220)), vec![3, 4]);
        assert!(h.release(|| false, ms(400)).is_empty());
        // A rerun hands a rollout out anyway; a new update forgets them all.
        h.hold(1);
        h.hold(2);
        h.forget(1);
        assert!(h.release(|| false, ms(500)).is_empty());
        assert_eq!(h.release(|| false, ms(600)), vec![2]);
        h.hold(5);
        h.clear();
        assert!(h.release(|| false, ms(700)).is_empty());
        assert!(h.release(|| false, ms(900)).is_empty());
    }

    #[test]
    fn chunks_are_equal_shares_unless_rollouts_are_slow() {
        // Fast: ⌈pending / workers⌉, as guided self-scheduling gives.
        assert_eq!(chunk_len(15, 2, Some(Duration::from_micros(50))), 8);
        assert_eq!(chunk_len(1, 4, Some(Duration::from_micros(50))), 1);
        assert_eq!(chunk_len(3, 0, Some(Duration::from_micros(50))), 3);
        // Not yet timed: one each, until the first chunk comes back.
        assert_eq!(chunk_len(15, 2, None), 1);
        // Slow: CHUNK_TIME of them, and never none.
        assert_eq!(chunk_len(15, 1, Some(Duration::from_millis(2))), 15);
        assert_eq!(chunk_len(15, 1, Some(Duration::from_millis(5))), 10);
        assert_eq!(chunk_len(15, 3, Some(Duration::from_millis(20))), 2);
        assert_eq!(chunk_len(15, 1, Some(Duration::from_millis(60))), 1);
        assert_eq!(chunk_len(15, 1, Some(Duration::ZERO)), 15);
    }

    #[test]
    fn a_rollout_is_handed_out_again_once_per_rise_of_its_count() {
        let mut seen = vec![0; 4];
        assert_eq!(raised(&mut seen, &[0, 1, 0, 1]), [1, 3]);
        // The same sample again, or an older one read after it: nothing new.
        assert_eq!(raised(&mut seen, &[0, 1, 0, 1]), [] as [u32; 0]);
        assert_eq!(raised(&mut seen, &[0, 1, 0, 0]), [] as [u32; 0]);
        // Samples lost in between: the newest still names every rollout that rose.
        assert_eq!(raised(&mut seen, &[2, 1, 1, 2]), [0, 2, 3]);
        assert_eq!(seen, [2, 1, 1, 2]);
    }
}
