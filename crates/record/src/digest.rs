//! What analysis keeps of a recording while it streams past: per update only its learning-curve
//! scalars ([`UpdatePoint`], 48 bytes), and for the figures and the summary a bounded amount
//! whatever the number of updates — at most [`DISTRIBUTIONS_SHOWN`] 2-D distributions, per
//! worker either every rollout time (up to [`ROLLOUT_TIMES_KEPT`]) or at most
//! [`TIME_BUCKETS`] buckets of them, the rollouts of the last [`TIMELINE_UPDATES`] updates,
//! and counts and a few examples of the health events. A continual run's recording has
//! millions of updates; the messages themselves (distributions, rollouts, events) would take
//! tens of GB.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use crate::proto;

/// How many of the last updates `worker_timeline.svg` shows.
pub const TIMELINE_UPDATES: usize = 10;

/// The most 2-D distributions `distribution.svg` draws (besides the first after each task
/// change and the final one): every update's up to this many updates, beyond that every k-th,
/// k the smallest power of two that keeps at most this many. More ellipses than pixels along
/// the mean's path show nothing more, and each adds 2 kB to the SVG.
pub const DISTRIBUTIONS_SHOWN: usize = 500;

/// Up to this many rollouts, `worker_time.svg` draws each one's time; beyond, per worker the
/// mean and the range of each bucket of [`TIME_BUCKETS`] (a point per rollout took 10 MB of
/// SVG per 100 000 rollouts).
pub const ROLLOUT_TIMES_KEPT: usize = 20_000;

/// The most buckets per worker `worker_time.svg` draws for a long run: buckets are aligned runs
/// of 2^j consecutive updates, j the smallest that needs no more than this many.
pub const TIME_BUCKETS: u64 = 500;

/// Warnings and errors the info summary lists one by one (the rest are counted).
pub const SERIOUS_LISTED: usize = 10;

/// Health events the summary of a run without any update shows: its last ones.
pub const LAST_EVENTS: usize = 3;
/// How the warning a restarted recorder writes at the start of its part begins (the pipeline
/// recorder writes it with this prefix); analysis counts these to say why updates are missing.
pub const RECORDER_RESTARTED: &str = "the recorder was restarted";

/// The learning-curve scalars of one update, and when its first rollout started.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct UpdatePoint {
    pub update: u64,
    pub eval_cost: f64,
    pub exploration_cost_mean: f64,
    pub exploration_cost_std: f64,
    pub lambda: f64,
    /// The earliest start of the update's timed rollouts (ns); 0 if none was timed.
    pub first_start_ns: u64,
}

/// One rollout on the timeline: its worker's row, update, rollout index and interval (ns).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimelineBar {
    pub worker: String,
    pub update: u64,
    pub rollout: u32,
    pub start_ns: u64,
    pub end_ns: u64,
}

/// Min, max and sum of rollout times (ms) within a bucket of updates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeBucket {
    pub min: f64,
    pub max: f64,
    pub sum: f64,
    pub count: usize,
}

impl TimeBucket {
    fn one(ms: f64) -> Self {
        Self {
            min: ms,
            max: ms,
            sum: ms,
            count: 1,
        }
    }
    fn merge(&mut self, o: &TimeBucket) {
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.sum += o.sum;
        self.count += o.count;
    }
}

/// Rollout times per worker: every one while there are at most [`ROLLOUT_TIMES_KEPT`], then
/// buckets of `width` updates (bucket i holds updates i·width … (i+1)·width − 1).
#[derive(Debug, Clone, PartialEq)]
pub enum WorkerTimes {
    /// Per worker: (update, rollout time in ms), in file order.
    Each(BTreeMap<String, Vec<(u64, f64)>>),
    Buckets {
        width: u64,
        per_worker: BTreeMap<String, BTreeMap<u64, TimeBucket>>,
        /// Per worker, how many rollout times fell in each of [`MEDIAN_BINS_PER_OCTAVE`]
        /// log-spaced bins per octave of ms: the median within 0.034 % once the times
        /// themselves are not kept.
        histograms: BTreeMap<String, BTreeMap<i32, usize>>,
    },
}

/// Bins per doubling of the rollout time in [`WorkerTimes::Buckets`]' histograms: a bin spans
/// a factor 2^(1/1024), so its geometric middle is within 0.034 % of any time in it, well
/// under the 3 significant digits `worker_time.svg` gives. A worker's times over 1 ns … 1 h
/// fill at most 42 octaves, 43 000 bins; real ones a few hundred.
pub const MEDIAN_BINS_PER_OCTAVE: f64 = 1024.0;

fn median_bin(ms: f64) -> i32 {
    (ms.max(f64::MIN_POSITIVE).log2() * MEDIAN_BINS_PER_OCTAVE).floor() as i32
}

fn add_to_histogram(h: &mut BTreeMap<String, BTreeMap<i32, usize>>, worker: &str, ms: f64) {
    let bins = match h.get_mut(worker) {
        Some(b) => b,
        None => h.entry(worker.to_string()).or_default(),
    };
    *bins.entry(median_bin(ms)).or_insert(0) += 1;
}

/// One worker's rollout times as `worker_time.svg`'s legend gives them.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerSummary {
    pub worker: String,
    pub count: usize,
    /// ms; exact while every time is kept, else within 0.034 % ([`MEDIAN_BINS_PER_OCTAVE`]).
    pub median: f64,
    /// ms
    pub mean: f64,
    pub median_exact: bool,
}

/// The median of times (ms) sorted in place: the middle one, or the mean of the two middle.
fn median_of(times: &mut [f64]) -> f64 {
    times.sort_by(f64::total_cmp);
    match times.len() {
        0 => 0.0,
        n if n % 2 == 1 => times[n / 2],
        n => (times[n / 2 - 1] + times[n / 2]) / 2.0,
    }
}

/// The median of a histogram of [`median_bin`]s: the geometric middle of the bin holding the
/// middle time (of the two middle times' bins, for an even count).
fn median_of_histogram(bins: &BTreeMap<i32, usize>) -> f64 {
    let n: usize = bins.values().sum();
    let middle = |bin: i32| ((f64::from(bin) + 0.5) / MEDIAN_BINS_PER_OCTAVE).exp2();
    let at = |rank: usize| {
        let mut seen = 0;
        for (bin, c) in bins {
            seen += c;
            if seen > rank {
                return middle(*bin);
            }
        }
        0.0
    };
    match n {
        0 => 0.0,
        n if n % 2 == 1 => at(n / 2),
        n => (at(n / 2 - 1) + at(n / 2)) / 2.0,
    }
}

impl Default for WorkerTimes {
    fn default() -> Self {
        Self::Each(BTreeMap::new())
    }
}

impl WorkerTimes {
    /// Per worker, in name order: count, median and mean of its rollout times.
    pub fn summaries(&self) -> Vec<WorkerSummary> {
        match self {
            Self::Each(m) => m
                .iter()
                .map(|(w, pts)| {
                    let mut t: Vec<f64> = pts.iter().map(|p| p.1).collect();
                    WorkerSummary {
                        worker: w.clone(),
                        count: t.len(),
                        mean: t.iter().sum::<f64>() / t.len().max(1) as f64,
                        median: median_of(&mut t),
                        median_exact: true,
                    }
                })
                .collect(),
            Self::Buckets {
                per_worker,
                histograms,
                ..
            } => per_worker
                .iter()
                .map(|(w, buckets)| {
                    let (count, sum) = buckets
                        .values()
                        .fold((0, 0.0), |(n, s), b| (n + b.count, s + b.sum));
                    WorkerSummary {
                        worker: w.clone(),
                        count,
                        mean: sum / count.max(1) as f64,
                        median: histograms.get(w).map_or(0.0, median_of_histogram),
                        median_exact: false,
                    }
                })
                .collect(),
        }
    }

    /// How many rollout times there are.
    pub fn rollouts(&self) -> usize {
        match self {
            Self::Each(m) => m.values().map(Vec::len).sum(),
            Self::Buckets { per_worker, .. } => per_worker
                .values()
                .flat_map(|b| b.values())
                .map(|b| b.count)
                .sum(),
        }
    }

    fn add(&mut self, worker: &str, update: u64, ms: f64) {
        match self {
            Self::Each(m) => {
                // One worker name per rollout is the bulk of a small run; allocated once.
                match m.get_mut(worker) {
                    Some(v) => v.push((update, ms)),
                    None => {
                        m.insert(worker.to_string(), vec![(update, ms)]);
                    }
                }
                if self.rollouts() > ROLLOUT_TIMES_KEPT {
                    self.bucket(1);
                }
            }
            Self::Buckets {
                width,
                per_worker,
                histograms,
            } => {
                add_to_histogram(histograms, worker, ms);
                let b = match per_worker.get_mut(worker) {
                    Some(b) => b,
                    None => per_worker.entry(worker.to_string()).or_default(),
                };
                let t = TimeBucket::one(ms);
                b.entry(update / *width)
                    .and_modify(|x| x.merge(&t))
                    .or_insert(t);
                self.narrow();
            }
        }
    }

    /// Turns every time kept into buckets of at least `width` updates.
    fn bucket(&mut self, width: u64) {
        if let Self::Each(m) = self {
            let mut per_worker: BTreeMap<String, BTreeMap<u64, TimeBucket>> = BTreeMap::new();
            let mut histograms = BTreeMap::new();
            for (w, pts) in std::mem::take(m) {
                let b = per_worker.entry(w.clone()).or_default();
                for (u, ms) in pts {
                    add_to_histogram(&mut histograms, &w, ms);
                    let t = TimeBucket::one(ms);
                    b.entry(u / width).and_modify(|x| x.merge(&t)).or_insert(t);
                }
            }
            *self = Self::Buckets {
                width,
                per_worker,
                histograms,
            };
        }
        self.widen_to(width);
        self.narrow();
    }

    /// Buckets `width` wide (a power of two at least the current width).
    fn widen_to(&mut self, to: u64) {
        if let Self::Buckets {
            width, per_worker, ..
        } = self
        {
            while *width < to {
                *width *= 2;
                for b in per_worker.values_mut() {
                    let mut merged: BTreeMap<u64, TimeBucket> = BTreeMap::new();
                    for (i, t) in std::mem::take(b) {
                        merged.entry(i / 2).and_modify(|x| x.merge(&t)).or_insert(t);
                    }
                    *b = merged;
                }
            }
        }
    }

    /// Widens the buckets until each worker's span of updates needs at most [`TIME_BUCKETS`].
    fn narrow(&mut self) {
        loop {
            let Self::Buckets {
                width, per_worker, ..
            } = self
            else {
                return;
            };
            let too_many =
                per_worker
                    .values()
                    .any(|b| match (b.first_key_value(), b.last_key_value()) {
                        (Some((lo, _)), Some((hi, _))) => hi - lo >= TIME_BUCKETS,
                        _ => false,
                    });
            if !too_many {
                return;
            }
            let to = *width * 2;
            self.widen_to(to);
        }
    }

    /// These times followed by `next`'s (a run's next file).
    fn append(&mut self, next: WorkerTimes) {
        match (&mut *self, next) {
            (Self::Each(a), Self::Each(b))
                if a.values().map(Vec::len).sum::<usize>()
                    + b.values().map(Vec::len).sum::<usize>()
                    <= ROLLOUT_TIMES_KEPT =>
            {
                for (w, pts) in b {
                    a.entry(w).or_default().extend(pts);
                }
            }
            (_, mut next) => {
                let width = |t: &WorkerTimes| match t {
                    Self::Each(_) => 1,
                    Self::Buckets { width, .. } => *width,
                };
                let w = width(self).max(width(&next));
                self.bucket(w);
                next.bucket(w);
                if let (
                    Self::Buckets {
                        per_worker: a,
                        histograms: ha,
                        ..
                    },
                    Self::Buckets {
                        per_worker: b,
                        histograms: hb,
                        ..
                    },
                ) = (&mut *self, next)
                {
                    for (worker, buckets) in b {
                        let mine = a.entry(worker).or_default();
                        for (i, t) in buckets {
                            mine.entry(i).and_modify(|x| x.merge(&t)).or_insert(t);
                        }
                    }
                    for (worker, bins) in hb {
                        let mine = ha.entry(worker).or_default();
                        for (bin, c) in bins {
                            *mine.entry(bin).or_insert(0) += c;
                        }
                    }
                }
                self.narrow();
            }
        }
    }
}

/// A 2-D search distribution `distribution.svg` draws: the one update `update` sampled from.
#[derive(Debug, Clone, PartialEq)]
pub struct Shown {
    pub update: u64,
    pub distribution: proto::Distribution,
    /// The first update after a task change: always kept.
    pub after_change: bool,
    /// How many updates came before it.
    index: u64,
}

/// The 2-D distributions kept for `distribution.svg` ([`DISTRIBUTIONS_SHOWN`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Distributions {
    pub shown: Vec<Shown>,
    /// Every `every`-th update's distribution is kept (besides those after a change).
    every: u64,
    seen: u64,
    /// What the last update produced, at the update after it.
    pub last: Option<(u64, proto::Distribution)>,
}

impl Default for Distributions {
    fn default() -> Self {
        Self {
            shown: Vec::new(),
            every: 1,
            seen: 0,
            last: None,
        }
    }
}

impl Distributions {
    fn add(&mut self, s: Shown) {
        if s.after_change || s.index.is_multiple_of(self.every) {
            self.shown.push(s);
        }
        self.seen += 1;
        self.thin();
    }

    /// Doubles the stride of the ellipses kept until at most [`DISTRIBUTIONS_SHOWN`] are.
    fn thin(&mut self) {
        let regular = |shown: &[Shown], every: u64| {
            shown
                .iter()
                .filter(|s| s.index.is_multiple_of(every))
                .count()
        };
        while regular(&self.shown, self.every) > DISTRIBUTIONS_SHOWN {
            self.every *= 2;
            let every = self.every;
            self.shown
                .retain(|s| s.after_change || s.index.is_multiple_of(every));
        }
    }

    fn append(&mut self, next: Distributions) {
        let offset = self.seen;
        self.shown.extend(next.shown.into_iter().map(|s| Shown {
            index: s.index + offset,
            ..s
        }));
        self.seen += next.seen;
        self.every = self.every.max(next.every);
        let every = self.every;
        self.shown
            .retain(|s| s.after_change || s.index.is_multiple_of(every));
        self.last = next.last.or(self.last.take());
        self.thin();
    }
}

/// Everything of a recording that analysis keeps: see the module documentation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Digest {
    /// Every update's scalars, in file order.
    pub points: Vec<UpdatePoint>,
    pub distributions: Distributions,
    pub worker_times: WorkerTimes,
    /// The timed rollouts of the last [`TIMELINE_UPDATES`] updates that have any.
    pub timeline: Vec<TimelineBar>,
    /// Health events per kind.
    pub events: BTreeMap<String, u64>,
    /// The first [`SERIOUS_LISTED`] warnings and errors.
    pub serious: Vec<proto::Log>,
    /// How many warnings and errors there are.
    pub serious_count: usize,
    /// The last [`LAST_EVENTS`] health events.
    pub last_events: VecDeque<proto::Log>,
    /// How many times a restarted recorder began a part (its warning on `/log`).
    pub recorder_restarts: u64,
    /// The updates `timeline` holds rollouts of.
    timeline_updates: BTreeSet<u64>,
    /// Updates task changes apply from, as far as read.
    changes: BTreeSet<u64>,
    /// The last update read: (update, batch start, batch end, K), for its untimed rollouts.
    batch: Option<(u64, u64, u64, u32)>,
}

impl Digest {
    pub fn add_update(&mut self, u: &proto::Update) {
        self.points.push(UpdatePoint {
            update: u.update,
            eval_cost: u.eval_cost,
            exploration_cost_mean: u.exploration_cost_mean,
            exploration_cost_std: u.exploration_cost_std,
            lambda: u.lambda,
            first_start_ns: 0,
        });
        self.batch = Some((u.update, u.batch_start_ns, u.batch_end_ns, u.rollouts));
        if u.dim == 2 {
            if let Some(b) = &u.before {
                self.distributions.add(Shown {
                    update: u.update,
                    index: self.distributions.seen,
                    distribution: b.clone(),
                    // Its change is recorded before it (the writers record a change when it is
                    // applied, before the update's batch).
                    after_change: self.changes.contains(&u.update),
                });
            }
            self.distributions.last = u.after.clone().map(|a| (u.update + 1, a));
        }
    }

    pub fn add_rollout(&mut self, r: &proto::Rollout) {
        if r.start_ns > 0 {
            let at = match self.points.last() {
                Some(p) if p.update == r.update => Some(self.points.len() - 1),
                _ => self.points.iter().rposition(|p| p.update == r.update),
            };
            if let Some(p) = at.map(|i| &mut self.points[i]) {
                p.first_start_ns = match p.first_start_ns {
                    0 => r.start_ns,
                    t => t.min(r.start_ns),
                };
            }
        }
        if r.end_ns > r.start_ns {
            self.worker_times
                .add(&r.worker, r.update, (r.end_ns - r.start_ns) as f64 / 1e6);
        } else if let Some((_, s, e, k)) = self.batch.filter(|b| b.0 == r.update) {
            if e > s && k > 0 {
                self.worker_times.add(
                    &format!("{} (update time / K)", r.worker),
                    r.update,
                    (e - s) as f64 / 1e6 / k as f64,
                );
            }
        }
        if r.start_ns > 0 && r.end_ns >= r.start_ns {
            self.add_bar(TimelineBar {
                worker: r.worker.clone(),
                update: r.update,
                rollout: r.rollout,
                start_ns: r.start_ns,
                end_ns: r.end_ns,
            });
        }
    }

    fn add_bar(&mut self, bar: TimelineBar) {
        if !self.timeline_updates.contains(&bar.update) {
            if self.timeline_updates.len() >= TIMELINE_UPDATES {
                match self.timeline_updates.first() {
                    Some(&lowest) if lowest < bar.update => {
                        self.timeline_updates.remove(&lowest);
                        self.timeline.retain(|b| b.update != lowest);
                    }
                    _ => return,
                }
            }
            self.timeline_updates.insert(bar.update);
        }
        self.timeline.push(bar);
    }

    pub fn add_task_change(&mut self, c: &proto::TaskChange) {
        self.changes.insert(c.update);
    }

    pub fn add_log(&mut self, l: &proto::Log) {
        *self.events.entry(l.event.clone()).or_insert(0) += 1;
        if l.event == "warning" || l.event == "error" {
            if self.serious.len() < SERIOUS_LISTED {
                self.serious.push(l.clone());
            }
            self.serious_count += 1;
        }
        if l.name == "recorder" && l.message.starts_with(RECORDER_RESTARTED) {
            self.recorder_restarts += 1;
        }
        self.last_events.push_back(l.clone());
        if self.last_events.len() > LAST_EVENTS {
            self.last_events.pop_front();
        }
    }

    /// This digest followed by `next`'s (a run's next file, [`crate::Recording::join`]).
    pub fn append(&mut self, next: Digest) {
        self.points.extend(next.points);
        self.distributions.append(next.distributions);
        self.worker_times.append(next.worker_times);
        for bar in next.timeline {
            self.add_bar(bar);
        }
        for (k, n) in next.events {
            *self.events.entry(k).or_insert(0) += n;
        }
        let room = SERIOUS_LISTED.saturating_sub(self.serious.len());
        self.serious.extend(next.serious.into_iter().take(room));
        self.serious_count += next.serious_count;
        self.recorder_restarts += next.recorder_restarts;
        self.last_events.extend(next.last_events);
        while self.last_events.len() > LAST_EVENTS {
            self.last_events.pop_front();
        }
        self.changes.extend(next.changes);
        self.batch = next.batch;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn update(u: u64, mean: f64) -> proto::Update {
        let d = |m: f64| proto::Distribution {
            dim: 2,
            mean: vec![m, m],
            covariance: vec![1.0, 0.0, 0.0, 1.0],
        };
        proto::Update {
            update: u,
            dim: 2,
            rollouts: 2,
            batch_start_ns: 10,
            batch_end_ns: 30,
            before: Some(d(mean)),
            after: Some(d(mean + 1.0)),
            ..Default::default()
        }
    }

    /// A long run keeps at most DISTRIBUTIONS_SHOWN ellipses at a regular stride, every one
    /// after a task change, and the final distribution; a short one every update's.
    #[test]
    fn distributions_are_thinned_to_a_bound_keeping_the_changes() {
        let mut short = Digest::default();
        for u in 0..DISTRIBUTIONS_SHOWN as u64 {
            short.add_update(&update(u, u as f64));
        }
        assert_eq!(short.distributions.shown.len(), DISTRIBUTIONS_SHOWN);
        let mut long = Digest::default();
        for u in 0..10_000u64 {
            if u % 777 == 0 {
                long.add_task_change(&proto::TaskChange {
                    update: u,
                    ..Default::default()
                });
            }
            long.add_update(&update(u, u as f64));
        }
        let shown = &long.distributions.shown;
        let regular: Vec<u64> = shown
            .iter()
            .filter(|s| s.index.is_multiple_of(long.distributions.every))
            .map(|s| s.update)
            .collect();
        assert!(regular.len() <= DISTRIBUTIONS_SHOWN && regular.len() > DISTRIBUTIONS_SHOWN / 2);
        assert_eq!(regular[0], 0);
        let stride = regular[1] - regular[0];
        assert!(
            regular.windows(2).all(|w| w[1] - w[0] == stride),
            "{regular:?}"
        );
        let changes: Vec<u64> = shown
            .iter()
            .filter(|s| s.after_change)
            .map(|s| s.update)
            .collect();
        assert_eq!(changes, (0..10_000).step_by(777).collect::<Vec<u64>>());
        assert_eq!(
            shown.len(),
            regular.len() + changes.len() - 1,
            "update 0 is both"
        );
        assert_eq!(long.distributions.last.as_ref().map(|l| l.0), Some(10_000));
    }

    /// Bucketed, the rollout times keep their count, extremes and sum per worker, in at most
    /// TIME_BUCKETS buckets, also across a run's files.
    #[test]
    fn rollout_times_are_bucketed_without_losing_count_or_extremes() {
        let mut first = Digest::default();
        let mut second = Digest::default();
        let mut n = 0;
        for u in 0..20_000u64 {
            let d = if u < 12_000 { &mut first } else { &mut second };
            d.add_update(&update(u, 0.0));
            for k in 0..2u32 {
                let ms = (u * 7 + u64::from(k) * 3) % 100 + 1;
                d.add_rollout(&proto::Rollout {
                    update: u,
                    rollout: k,
                    worker: format!("worker-{k}"),
                    start_ns: 1_000_000 * u + 1,
                    end_ns: 1_000_000 * u + 1 + ms * 1_000_000,
                    ..Default::default()
                });
                n += 1;
            }
        }
        first.append(second);
        let WorkerTimes::Buckets {
            width, per_worker, ..
        } = &first.worker_times
        else {
            panic!("{n} rollouts are kept one by one");
        };
        assert!(width.is_power_of_two());
        assert_eq!(first.worker_times.rollouts(), n);
        for b in per_worker.values() {
            assert!(b.len() as u64 <= TIME_BUCKETS);
            let lo = b.values().map(|t| t.min).fold(f64::INFINITY, f64::min);
            let hi = b.values().map(|t| t.max).fold(0.0, f64::max);
            assert_eq!((lo, hi), (1.0, 100.0));
        }
        // The median survives bucketing, to within a histogram bin.
        let exact: Vec<f64> = (0..2u64)
            .map(|k| {
                let mut t: Vec<f64> = (0..20_000u64)
                    .map(|u| ((u * 7 + k * 3) % 100 + 1) as f64)
                    .collect();
                median_of(&mut t)
            })
            .collect();
        for (s, exact) in first.worker_times.summaries().iter().zip(exact) {
            assert!(!s.median_exact);
            assert!(
                (s.median / exact - 1.0).abs() < 3.4e-4,
                "{}: median {} against {exact}",
                s.worker,
                s.median
            );
        }
        // Only the last updates' rollouts stay for the timeline.
        let mut kept: Vec<u64> = first.timeline.iter().map(|b| b.update).collect();
        kept.dedup();
        assert_eq!(
            kept,
            (20_000 - TIMELINE_UPDATES as u64..20_000).collect::<Vec<_>>()
        );
    }
}
