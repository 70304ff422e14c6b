//! Rollout worker slots: scaling to the target count, restarts with backoff and a limit per
//! window, stopping a worker once the recorder has connected to its ports, hung workers, and
//! workers that joined the run from outside. It is not the starting of a process (`children`)
//! nor the handing on of a gone worker's rollouts (the sampler does that).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use session::PipelineSection;
use wire::{Overdue, RunNote};

use super::event_loop::{Outcome, Phase};
use super::process::{signal_group, still_runs, stopped_in_group, Role};
use super::{say, Supervisor};

#[derive(Default)]
pub(super) struct Slot {
    incarnation: u32,
    pub(super) pid: Option<u32>,
    pub(super) restarts: VecDeque<Instant>,
    pub(super) restart_at: Option<Instant>,
    /// How its last process died (exit status and last output), once one did: what a startup
    /// that times out while it is restarted names as the cause.
    pub(super) last_death: Option<String>,
}

impl Supervisor {
    /// A worker that a scale-down asked to stop and that has not within `shutdown_timeout_ms`
    /// (stuck, or in a rollout longer than that) is killed, as at the run's stop: it held its
    /// slot's rollouts, and the update waited for it while the others idled. The sampler hands
    /// its rollouts to the others once it is gone.
    pub(super) fn kill_scaled_down_overdue(&mut self, now: Instant) {
        for (pid, p) in &mut self.procs {
            if p.sigkilled || p.stop_by.is_none_or(|t| now < t) {
                continue;
            }
            say(&format!(
                "{} (pid {pid}), scaled down, did not stop within {} ms \
                 (pipeline.shutdown_timeout_ms); killing it: its rollouts go to the other workers",
                p.role.name(),
                self.pipe.shutdown_timeout_ms
            ));
            signal_group(*pid, libc::SIGKILL);
            p.sigkilled = true;
        }
    }

    /// Sends worker `pid` SIGTERM, once the recorder has connected to its ports if it may
    /// not have: iceoryx2 keeps what a departed publisher sent only for subscribers that had
    /// connected to it, and a recorder connects to a new publisher when it next looks, so a
    /// worker that joined while the recorder was stalled (stopped, or held in a write) would
    /// take its last costs and its announcement with it. It asks the recorder to connect
    /// (RECORDER_SYNC, answered within a millisecond by a running one) and waits at most half
    /// of `pipeline.shutdown_timeout_ms` ([`Self::release_stops`]).
    pub(super) fn stop_worker(&mut self, pid: u32) {
        // A worker not yet seen to be ready may have announced itself just now: a sync sent
        // after it was started covers the ports it had by then (one sync for all of a batch).
        let Some(since) = self
            .procs
            .get(&pid)
            .map(|p| p.ready_at.unwrap_or(p.spawned_at))
        else {
            signal_group(pid, libc::SIGTERM);
            return;
        };
        let wait = Duration::from_millis(self.pipe.shutdown_timeout_ms / 2);
        // A shutdown timeout of 1 ms leaves no time to wait in.
        let sync = if !wait.is_zero() && self.recorder_listening() {
            self.recorder_sync_after(since)
        } else {
            None
        };
        match (sync, self.procs.get_mut(&pid)) {
            (Some(seq), Some(p)) => p.term_wait = Some((seq, Instant::now() + wait)),
            _ => signal_group(pid, libc::SIGTERM),
        }
    }

    /// Restarts the workers whose backoff has passed.
    pub(super) fn restart_due(&mut self) {
        let now = Instant::now();
        let due: Vec<u32> = self
            .slots
            .iter()
            .filter(|(_, s)| s.restart_at.is_some_and(|t| t <= now))
            .map(|(w, _)| *w)
            .collect();
        for w in due {
            let inc = {
                let s = self.slots.get_mut(&w).expect("due slot exists");
                s.restart_at = None;
                s.incarnation += 1;
                s.incarnation
            };
            if let Err(e) = self.spawn(Role::Worker(w), inc) {
                self.fail(format!("cannot restart worker-{w}: {e:#}"));
            }
        }
    }

    /// Who holds worker slot `w`: a worker this supervisor runs there, or a live one that
    /// joined the run from outside.
    pub(super) fn slot_holder(&self, w: u32) -> Option<String> {
        if let Some(slot) = self.slots.get(&w) {
            return Some(match slot.pid {
                Some(pid) => format!("worker-{w} (pid {pid}, started by the supervisor)"),
                None => format!("worker-{w} (started by the supervisor, being restarted)"),
            });
        }
        self.joined_in(w)
            .map(|pid| format!("worker-{w} (pid {pid}, joined from outside)"))
    }

    /// The pid of a live worker that joined the run from outside in slot `w`.
    fn joined_in(&self, w: u32) -> Option<u32> {
        self.live_joined()
            .find(|(_, slot)| *slot == w)
            .map(|(pid, _)| pid)
    }

    /// Says when a worker that joined from outside is gone, on the console and in the
    /// recording: its start is there (its announcement), and nobody else reports its end (the
    /// sampler hands its rollouts on by itself). Also keeps the map from growing over a long
    /// run with workers coming and going. At most once a second: it reads `/proc`.
    pub(super) fn check_joined(&mut self) {
        if self.joined.is_empty()
            || self.phase == Phase::Stopping
            || self.joined_checked.elapsed() < Duration::from_secs(1)
        {
            return;
        }
        self.joined_checked = Instant::now();
        let gone: Vec<(u32, u32)> = self
            .joined
            .iter()
            .filter(|(pid, (_, started))| !still_runs(**pid, *started))
            .map(|(pid, (w, _))| (*pid, *w))
            .collect();
        for (pid, w) in gone {
            self.joined.remove(&pid);
            let msg = format!(
                "worker-{w} (pid {pid}), which joined from outside, is gone; the sampler hands \
                 its rollouts to the other workers"
            );
            say(&msg);
            self.note(RunNote::WARNING, &msg);
        }
    }

    /// (pid, slot) of the workers that joined from outside and still run. A pid alone is not
    /// enough: in a run of days an unrelated process can get a gone worker's pid and would hold
    /// its slot.
    pub(super) fn live_joined(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.joined
            .iter()
            .filter(|(pid, (_, started))| still_runs(**pid, *started))
            .map(|(pid, (slot, _))| (*pid, *slot))
    }

    /// Starts or stops workers until `target_workers` run (lowest free slots first; the highest
    /// slots are stopped first).
    pub(super) fn apply_scale(&mut self) -> anyhow::Result<()> {
        let live: Vec<u32> = self.slots.keys().copied().collect();
        if live.len() < self.target_workers {
            let mut w = 0;
            // Slots that joined workers hold are skipped: a second worker there would run the
            // same rollouts.
            while self.slots.len() < self.target_workers && (w as usize) < self.pipe.max_workers {
                if self.joined_in(w).is_none() && !self.slots.contains_key(&w) {
                    // A worker a scale-down stopped may still be finishing its rollout in this
                    // slot: the new one comes after it, or the sampler would take the new one's
                    // announcement for the old one's and its loss for the new one's.
                    let incarnation = self
                        .procs
                        .values()
                        .filter(|p| p.role == Role::Worker(w))
                        .map(|p| p.incarnation + 1)
                        .max()
                        .unwrap_or(0);
                    self.slots.insert(
                        w,
                        Slot {
                            incarnation,
                            ..Slot::default()
                        },
                    );
                    self.spawn(Role::Worker(w), incarnation)?;
                }
                w += 1;
            }
            if self.slots.len() < self.target_workers {
                say(&format!(
                    "{} of {} workers started: the other slots below pipeline.max_workers = {} \
                     are held by workers that joined from outside",
                    self.slots.len(),
                    self.target_workers,
                    self.pipe.max_workers
                ));
            }
        } else {
            for w in live
                .into_iter()
                .rev()
                .take(self.slots.len() - self.target_workers)
            {
                let slot = self.slots.remove(&w).expect("live slot");
                if let Some(pid) = slot.pid {
                    if let Some(p) = self.procs.get_mut(&pid) {
                        p.stopping = true;
                        p.stop_by = Some(
                            Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms),
                        );
                        self.stop_worker(pid);
                    }
                }
            }
        }
        Ok(())
    }

    /// Kills the worker incarnation the sampler reports as hung; [`Self::exited`] then reports it
    /// lost (reason HUNG) and restarts it like a crashed one.
    pub(super) fn kill_hung(&mut self, o: Overdue) {
        let per_rollout = self.pipe.rollout_timeout_ms.unwrap_or(0);
        let overdue = format!(
            "no rollout done for {} ms, over pipeline.rollout_timeout_ms = {per_rollout} (held {} rollout(s) of update {} for {} ms)",
            o.stalled_ms, o.rollouts, o.update, o.held_ms
        );
        let why = format!("hung: {overdue}");
        // Ours also when a scale-down has taken its slot away: asked to stop, a hung worker
        // does not, and would stay, holding its rollouts, until the run ends.
        let ours = self
            .procs
            .iter_mut()
            .find(|(_, p)| p.role == Role::Worker(o.worker) && p.incarnation == o.incarnation);
        let Some((&pid, p)) = ours else {
            if self.joined_in(o.worker).is_some() && !self.slots.contains_key(&o.worker) {
                // A worker that joined the run by itself: the sampler has handed its rollouts on.
                say(&format!(
                    "worker-{} (incarnation {}, not started by this supervisor) {why}; its rollouts went to the other workers",
                    o.worker, o.incarnation
                ));
            }
            return; // already gone
        };
        if (p.stopping && self.phase == Phase::Stopping) || p.hung.is_some() {
            return; // going (the shutdown's timeout bounds it), or being killed
        }
        // A worker an operator froze (SIGSTOP, Ctrl-Z) holds its rollouts as a hung one does,
        // and is killed as one; "hung" alone read as a fault of the task.
        let why = if stopped_in_group(pid).is_empty() {
            why
        } else {
            format!("is stopped by a signal (SIGSTOP, Ctrl-Z), not hung, but holds its rollouts as a hung worker does: {overdue}")
        };
        say(&format!(
            "worker-{} (pid {pid}) {why}; killing it",
            o.worker
        ));
        p.hung = Some(why);
        signal_group(pid, libc::SIGKILL);
    }

    /// Worker `w` (pid `pid`) exited with status 0 unasked, after it had announced itself: a
    /// task that ended its worker on
    /// purpose (`sys.exit(0)` in a Python rollout, `std::process::exit(0)`, an operator's
    /// `kill` of the worker, which ends it in order). Restarting it would undo that and spend
    /// the restart limit on it, so it is taken as a scale-down by one: its slot is freed, its
    /// rollouts go to the others, and `supervisor scale` brings a worker back. With no worker
    /// left to run rollouts the run is stopped, as by `supervisor stop`.
    pub(super) fn exited_on_purpose(&mut self, w: u32, pid: u32, cause: &str) {
        self.slots.remove(&w);
        self.target_workers = self.target_workers.saturating_sub(1);
        let left = self.slots.len() + self.live_joined().count();
        if left > 0 {
            say(&format!(
                "worker-{w} (pid {pid}) exited on its own ({cause}): taken as stopped on \
                 purpose, not restarted; its rollouts go to the others, {left} worker(s) go on \
                 (`supervisor scale` adds workers again)"
            ));
            return;
        }
        say(&format!(
            "worker-{w} (pid {pid}) exited on its own ({cause}): taken as stopped on purpose, \
             not restarted; no worker is left to run rollouts, so the run stops"
        ));
        if self.outcome.is_none() {
            self.outcome = Some(Outcome::Stopped);
        }
        self.begin_stop();
    }
}

/// How long a worker waits for its `n`th restart within the window (n ≥ 1): 100 ms, 200 ms,
/// 400 ms … at most 5 s.
pub(super) fn restart_backoff(n: usize) -> Duration {
    let doublings = (n.max(1) - 1).min(6) as u32;
    (Duration::from_millis(100) * 2u32.pow(doublings)).min(Duration::from_secs(5))
}

/// Whether a process restarted at `restarts` may be restarted once more at `now`
/// (`pipeline.restart_limit` within `restart_window_s`); forgets the restarts outside the
/// window.
pub(super) fn may_restart(
    restarts: &mut VecDeque<Instant>,
    pipe: &PipelineSection,
    now: Instant,
) -> bool {
    // Any window past what a Duration holds is "forever".
    let window = Duration::try_from_secs_f64(pipe.restart_window_s).unwrap_or(Duration::MAX);
    while restarts
        .front()
        .is_some_and(|t| now.duration_since(*t) > window)
    {
        restarts.pop_front();
    }
    restarts.len() < pipe.restart_limit as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_workers_restart_backoff_doubles_up_to_5_s() {
        let ms: Vec<u128> = (1..=9).map(|n| restart_backoff(n).as_millis()).collect();
        assert_eq!(ms, [100, 200, 400, 800, 1600, 3200, 5000, 5000, 5000]);
    }
}
