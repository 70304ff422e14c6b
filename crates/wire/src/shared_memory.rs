//! How much of the shared-memory file system (`/dev/shm`) a run's services take, so that the
//! supervisor can refuse a run that does not fit before any process starts: a full tmpfs
//! shows only as SIGBUS in the first process that writes to a page it has no room for.
//!
//! iceoryx2 0.10 sizes its files with `ftruncate` and writes only what it uses, and tmpfs
//! allocates a page when it is first written: what a run takes is its files' allocated pages
//! (`du`), not their sizes (`ls -l`), which are up to 30 times more (a publisher's segment has
//! room for every sample all subscribers could hold). The estimate follows the files iceoryx2
//! creates, with their sizes as in iceoryx2 0.10's source (checked against the files of real
//! runs), and bounds the pages of each sample segment by how many samples the protocol lets be
//! in use at once. Measured peaks of real runs were 0.36–0.75 times the estimate (README,
//! "Pipeline and supervisor"; the unit tests below hold the measured figures).

use std::mem::{align_of, size_of};

use iceoryx2::service::header::publish_subscribe::Header;

use crate::{
    Control, CostHeader, DistributionHeader, Lifecycle, Limits, Overdue, Progress, PubSub,
    PubSubSettings, Ready, RecorderAck, RerunHeader, RunNote, WorkHeader, BORROWED_SAMPLES,
};

/// What a run's shared memory is for, in bytes of allocated pages at its peak
/// ([`Limits::shared_memory`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SharedMemoryNeed {
    /// The `distribution` segment: P + P² values a sample.
    pub distribution: u64,
    /// The workers' `costs` segments: N values a sample.
    pub costs: u64,
    /// The `work/<w>` segments: P values a sample.
    pub work: u64,
    /// Everything else: the small messages' segments, the connections between ports, every
    /// service's registry of its ports, the doorbells.
    pub other: u64,
}

impl SharedMemoryNeed {
    /// The sum of the parts: what the supervisor compares with the free space of `/dev/shm`.
    pub fn total(&self) -> u64 {
        self.distribution + self.costs + self.work + self.other
    }
}

/// Samples a publisher may loan at once: iceoryx2's default, which every publisher keeps.
const LOANED_SAMPLES: usize = 2;

/// Samples of a small message (ready, lifecycle, control, progress, …) counted as in use at
/// once per publisher: they are rare (one lifecycle announcement per process, a ready per
/// chunk and at most one a millisecond within it, progress at most every 0.1 s) and drained as
/// they come, and the pages they take are a few at most even if a burst (a scale-down's lost
/// workers, the rollout reports of a worker whose sampler sleeps) fills more.
const SMALL_IN_USE: usize = 16;

/// The sum of the peaks of W segments that share a bound on the samples in use at once, as a
/// multiple of that bound divided by W: each segment reaches its peak at its own moment, when
/// its worker had more than an equal share (a faster worker gets more rollouts). Measured: a
/// worker's `costs` segment peaked at up to 1.44 times its equal share of the bound, and the
/// segments' peaks summed to 0.46–1.27 times the bound.
const UNEVEN_SHARES: usize = 2;

/// Bytes before a sample segment's first chunk, and after its chunks (iceoryx2's pool
/// allocator's free list) per chunk; `ls -l` of real segments: 150 + (chunk + 4) · samples.
const SEGMENT_HEAD: usize = 160;
const FREE_LIST_PER_SAMPLE: usize = 4;

impl Limits {
    /// The bytes of `/dev/shm` a run with `workers` worker processes (and the recorder, if
    /// `recorder`; and the `reruns` service, if `reruns`, as with a positive
    /// `run.nonfinite_reruns`) takes at its peak, on a file system that allocates `page` bytes
    /// at a time: an upper estimate. Counted are the files iceoryx2 creates for the run's ports (see the
    /// service functions and the crate documentation's table for who publishes and subscribes
    /// what):
    ///
    /// - per publisher, a sample segment: of its `subscribers · (buffer + 2) + 2` chunks only
    ///   the most ever in use at once are written, because iceoryx2's pool hands out the chunk
    ///   freed last first; that is at most
    ///   - `distribution`: the recorder's lag bound ([`Limits::recorder_max_lag`]) plus the
    ///     one being written and the one the sampler holds (without a recorder, 3);
    ///   - `costs`: those of the updates the recorder may lag behind plus one, K each, plus
    ///     re-executions after crashes (max_workers + 4) and each worker's loans (with reruns,
    ///     the recorder's whole buffer, [`Limits::recorder_cost_room`] + max_workers + 4, plus
    ///     the loans; without a recorder, the updater's own bound of 2K + max_workers + 4 plus
    ///     the loans); shared
    ///     among the workers' segments, each counted with `UNEVEN_SHARES` times its share;
    ///   - `work/<w>`: the K rollouts of an update plus each worker's loans and borrows,
    ///     shared likewise;
    ///   - the small messages, `SMALL_IN_USE` each;
    ///
    ///   plus the pool's free list, 4 bytes per chunk, written in full at creation;
    /// - per publisher–subscriber pair, a connection: two queues of `buffer + 2` indices and a
    ///   flag per chunk of the segment;
    /// - per service, its registry of ports and nodes, sized by the most it admits;
    /// - per doorbell listener one page, and one page for the run.
    ///
    /// Every file takes whole pages. Not counted: the segments of a crashed worker until they
    /// are cleaned up (within a second), and workers beyond `workers` that join or are scaled
    /// to (with `workers` = [`Limits::max_workers`], what the most would take).
    pub fn shared_memory(
        &self,
        workers: usize,
        recorder: bool,
        reruns: bool,
        page: u64,
    ) -> SharedMemoryNeed {
        let page = page.max(1) as usize;
        let w = workers.max(1);
        let rec = usize::from(recorder);
        let (k, p, n) = (self.rollouts.max(1), self.dim, self.steps);
        let pages = |bytes: usize| bytes.div_ceil(page) * page;
        // Every file but the sample segments, and the small messages' segments.
        let mut other = 0;
        let mut service = |s: PubSubSettings, publishers: usize, subscribers: usize| {
            let samples = segment_samples(s);
            other += pages(pubsub_registry(s));
            other += publishers * subscribers * pages(connection(s, samples));
            samples
        };

        let s = self.settings(PubSub::Distribution);
        let chunk = chunk_bytes::<DistributionHeader>(8 * (p + p * p), 8);
        let samples = service(s, 1, 1 + rec);
        let in_use = if recorder {
            self.recorder_max_lag() as usize + 2
        } else {
            3
        };
        let distribution = segment(page, chunk, samples, in_use) as u64;

        let s = self.settings(PubSub::Costs);
        let chunk = chunk_bytes::<CostHeader>(8 * n, 8);
        let samples = service(s, w, 1 + rec);
        let loans = LOANED_SAMPLES * w;
        let bound = if recorder && reruns {
            // Reruns may fill the recorder's buffer up to the room the updater counts.
            self.recorder_cost_room() as usize + self.max_workers + 4 + loans
        } else if recorder {
            (self.recorder_max_lag() as usize + 1) * k + self.max_workers + 4 + loans
        } else {
            2 * k + self.max_workers + 4 + loans
        };
        let costs = (w * segment(page, chunk, samples, share(bound, w))) as u64;

        let s = self.settings(PubSub::Work);
        let chunk = chunk_bytes::<WorkHeader>(8 * p, 8);
        let mut work = 0;
        for _ in 0..w {
            let samples = service(s, 1, 1);
            let bound = k + (LOANED_SAMPLES + BORROWED_SAMPLES) * w;
            work += segment(page, chunk, samples, share(bound, w)) as u64;
        }

        // (service, message size, publishers, subscribers): the crate documentation's table
        // for a run of `w` workers; `recorded` has its updater and supervisor subscribers with or
        // without one.
        let small = [
            (PubSub::Ready, size_of::<Ready>(), w, 1),
            (PubSub::Progress, size_of::<Progress>(), 1, 1),
            (PubSub::Recorded, size_of::<RecorderAck>(), rec, 2),
            (
                PubSub::Lifecycle,
                size_of::<Lifecycle>(),
                2 + w + rec,
                1 + rec,
            ),
            (PubSub::Control, size_of::<Control>(), 1, 2 + rec),
            (PubSub::Overdue, size_of::<Overdue>(), 1, 1),
            (PubSub::Notes, size_of::<RunNote>(), 1, rec),
            (PubSub::Joined, size_of::<Lifecycle>(), rec, 1),
        ];
        let mut small_segments = 0;
        for (kind, size, publishers, subscribers) in small {
            let s = self.settings(kind);
            let chunk = chunk_bytes::<()>(size, 8);
            let samples = service(s, publishers, subscribers);
            small_segments += publishers * segment(page, chunk, samples, SMALL_IN_USE);
        }
        if reruns {
            let s = self.settings(PubSub::Reruns);
            let chunk = chunk_bytes::<RerunHeader>(4 * k, 4);
            let samples = service(s, 1, 1);
            small_segments += segment(page, chunk, samples, samples);
        }

        // Doorbells: updater, sampler, supervisor, recorder (its notifier is opened even
        // without one) and one per worker; a listener each but the recorder's when absent.
        let e = self.doorbell_settings();
        let registry = 352 + 128 * (e.notifiers + e.listeners) + 32 * e.nodes;
        other += (4 + w) * pages(registry) + (3 + rec + w) * page;
        // iceoryx2's node-wide management file.
        other += page;
        SharedMemoryNeed {
            distribution,
            costs,
            work,
            other: (other + small_segments) as u64,
        }
    }
}

/// Chunks of a publisher's segment: iceoryx2 0.10 sizes it for every sample that its
/// subscribers could buffer and borrow and it could loan.
fn segment_samples(s: PubSubSettings) -> usize {
    s.subscribers * (s.buffer + BORROWED_SAMPLES) + LOANED_SAMPLES
}

/// The bytes of one sample: iceoryx2's header, the user header `H` and the payload, each
/// aligned as iceoryx2 lays them out.
fn chunk_bytes<H>(payload: usize, payload_align: usize) -> usize {
    let align = |x: usize, a: usize| x.div_ceil(a) * a;
    let max_align = align_of::<Header>().max(align_of::<H>()).max(payload_align);
    let headers = align(
        align(size_of::<Header>(), align_of::<H>()) + size_of::<H>(),
        payload_align,
    );
    align(headers + payload, max_align)
}

/// The bytes written of a sample segment of `samples` chunks of which at most `in_use` are in
/// use at once: the head and the first `in_use` chunks (the pool hands out the chunk freed
/// last first, so no other chunk is ever written), and the free list after all chunks.
fn segment(page: usize, chunk: usize, samples: usize, in_use: usize) -> usize {
    let written = SEGMENT_HEAD + in_use.min(samples) * chunk;
    let list_start = SEGMENT_HEAD + samples * chunk;
    let end = list_start + FREE_LIST_PER_SAMPLE * samples;
    let head_pages = written.div_ceil(page);
    let list_pages = (end.div_ceil(page)).saturating_sub(head_pages.max(list_start / page));
    (head_pages + list_pages) * page
}

/// Each of `w` segments' peak when they share `bound` samples in use (see [`UNEVEN_SHARES`]):
/// never more than the whole bound.
fn share(bound: usize, w: usize) -> usize {
    (UNEVEN_SHARES * bound).div_ceil(w).min(bound)
}

/// A publisher–subscriber connection: a submission queue of `buffer + 1` and a completion
/// queue of `buffer + borrowed + 1` indices (8 bytes each), a flag per chunk of the
/// publisher's segment, and their headers (236 bytes measured).
fn connection(s: PubSubSettings, samples: usize) -> usize {
    8 * (s.buffer + 1) + 8 * (s.buffer + BORROWED_SAMPLES + 1) + samples + 256
}

/// A publish-subscribe service's registry of its ports and nodes: 152 bytes per publisher, 144
/// per subscriber, 32 per node and 327 more (iceoryx2 0.10, sizes of real files).
fn pubsub_registry(s: PubSubSettings) -> usize {
    352 + 152 * s.publishers + 144 * s.subscribers + 32 * s.nodes
}

#[cfg(test)]
mod tests {
    use super::*;

    const PAGE: u64 = 4096;

    /// The peak of the allocated bytes (`stat`'s blocks, sampled every 0.1 s) of the `/dev/shm`
    /// files of a real run, 20–90 s of `supervisor run --updates 1000000` on the 2-core
    /// development machine; with a recorder, the larger of a run left alone and one whose
    /// recorder was SIGSTOPped for 4–20 s (the updater then waits at the lag bound). A1, tball
    /// and many were measured again when the headers grew (`CostHeader` v3, 72 more bytes per
    /// cost sample; `DistributionHeader` and `WorkHeader` v2, 64 more): 20 s runs, the recorder
    /// stopped for 6 of them, twice, the larger peak kept. The two "large" runs are from before:
    /// their samples hold 8 008 bytes of costs and 2 800 of θ, so the headers add under 3 %.
    struct Measured {
        run: &'static str,
        limits: Limits,
        workers: usize,
        recorder: bool,
        bytes: u64,
    }

    const fn measured(
        run: &'static str,
        (max_workers, rollouts, dim, steps): (usize, usize, usize, usize),
        workers: usize,
        recorder: bool,
        bytes: u64,
    ) -> Measured {
        Measured {
            run,
            limits: Limits {
                max_workers,
                rollouts,
                dim,
                steps,
            },
            workers,
            recorder,
            bytes,
        }
    }

    /// config/A1.toml, config/tball.toml; "large": tball.toml with basis_functions = 50,
    /// rollouts = 50, workers = 8; "many": A1.toml with workers = 24, max_workers = 64.
    const MEASURED: [Measured; 6] = [
        measured("A1", (16, 15, 2, 101), 3, true, 802_816),
        measured("A1 --no-record", (16, 15, 2, 101), 3, false, 397_312),
        measured("tball", (16, 10, 21, 1001), 3, true, 1_855_488),
        measured("large", (16, 50, 350, 1001), 8, true, 6_766_592),
        measured(
            "large --no-record",
            (16, 50, 350, 1001),
            8,
            false,
            2_351_104,
        ),
        measured("many", (64, 15, 2, 101), 24, true, 2_822_144),
    ];

    #[test]
    fn the_estimate_bounds_what_real_runs_took_and_not_by_much_more() {
        for m in MEASURED {
            let estimate = m
                .limits
                .shared_memory(m.workers, m.recorder, false, PAGE)
                .total();
            let ratio = estimate as f64 / m.bytes as f64;
            println!(
                "{}: estimate {estimate}, measured {}, ratio {ratio:.2}",
                m.run, m.bytes
            );
            // Below the peak of a real run is what must never happen; well above it refuses
            // runs that would fit.
            assert!((1.0..3.0).contains(&ratio), "{}: {ratio}", m.run);
        }
    }

    /// The `reruns` service (reruns of non-finite costs): a small segment and its connection,
    /// counted only when the run has it; and with a recorder, the cost messages that reruns may
    /// add to its buffer, up to the room the updater counts.
    #[test]
    fn the_reruns_service_is_counted_when_reruns_are_on() {
        let a1 = MEASURED[0].limits;
        let lag = a1.recorder_max_lag() as usize;
        let more_costs = (a1.recorder_cost_room() as usize - (lag + 1) * a1.rollouts)
            * chunk_bytes::<CostHeader>(8 * a1.steps, 8)
            * UNEVEN_SHARES;
        for (recorder, more) in [(false, 0), (true, more_costs as u64)] {
            let without = a1.shared_memory(3, recorder, false, PAGE).total();
            let with = a1.shared_memory(3, recorder, true, PAGE).total();
            let added = with - without;
            assert!(
                added > more && added <= more + 32 * 1024 + 3 * PAGE,
                "{without} → {with} (expected about {more} more)"
            );
        }
    }

    #[test]
    fn samples_are_laid_out_as_iceoryx2_does() {
        // Sizes of real segments (ls -l) of the quick start's run, less their own 4 014, 702
        // and 294 bytes, divided by their 966, 138 and 36 chunks.
        assert_eq!(chunk_bytes::<CostHeader>(8 * 101, 8), 976);
        assert_eq!(chunk_bytes::<DistributionHeader>(8 * 6, 8), 280);
        assert_eq!(chunk_bytes::<WorkHeader>(8 * 2, 8), 240);
        // Control (88 B since `sent`): its segment of 202 chunks was 28 430 bytes (2026-11-24).
        assert_eq!(chunk_bytes::<()>(size_of::<Control>(), 8), 136);
        let via_point = Limits {
            max_workers: 16,
            rollouts: 15,
            dim: 2,
            steps: 101,
        };
        // The costs segment of the quick start's run is 946 830 bytes: 966 chunks (and 4 014
        // bytes of its own).
        assert_eq!(segment_samples(via_point.settings(PubSub::Costs)), 966);
    }
}
