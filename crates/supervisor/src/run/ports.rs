//! The supervisor's iceoryx2 side: reading announcements, progress reports and overdue workers
//! off its ports, sending control messages and run notes, and the doorbell thread that wakes the
//! event loop. It is not where the ports are opened ([`Supervisor::run`]) nor what a message
//! leads to beyond passing it on (joined and hung workers, task changes: their own modules).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::bail;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use pipeline::iox;
use wire::{Control, Lifecycle, Limits, Overdue, Progress, RecorderAck, RunNote, Service};

use super::event_loop::Phase;
use super::process::{process_group, process_started, signal_process, Role};
use super::{say, Event, Supervisor};

pub(super) struct Ports {
    pub(super) lifecycle: Subscriber<Service, Lifecycle, ()>,
    pub(super) overdue: Subscriber<Service, Overdue, ()>,
    pub(super) progress: Subscriber<Service, Progress, ()>,
    pub(super) recorded: Subscriber<Service, RecorderAck, ()>,
    pub(super) control: Publisher<Service, Control, ()>,
    pub(super) notes: Publisher<Service, RunNote, ()>,
    pub(super) sampler_bell: Notifier<Service>,
    pub(super) updater_bell: Notifier<Service>,
    /// Rung after every control message, so the recorder logs it when it happens.
    pub(super) recorder_bell: Notifier<Service>,
    /// Control messages sent ([`Control::sent`] of the last).
    pub(super) control_sent: std::cell::Cell<u64>,
    // Dropped last: ports above belong to it.
    pub(super) _node: Node<Service>,
}

impl Supervisor {
    /// Puts `text` into the recording (the recorder logs it as the supervisor's), if there are
    /// ports and a recorder to take it; never a reason to fail.
    pub(super) fn note(&self, level: u32, text: &str) {
        if let Some(ports) = &self.ports {
            let _ = ports
                .notes
                .send_copy(RunNote::new(self.run_id, level, text));
            let _ = ports.recorder_bell.notify_with_custom_event_id(wire::WAKE);
        }
    }

    pub(super) fn send_control(&self, msg: Control, to_updater: bool) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let sent = ports.control_sent.get() + 1;
        ports.control_sent.set(sent);
        iox(
            ports.control.send_copy(Control { sent, ..msg }),
            "send control",
        )?;
        let bell = if to_updater {
            &ports.updater_bell
        } else {
            &ports.sampler_bell
        };
        iox(bell.notify_with_custom_event_id(wire::WAKE), "notify")?;
        // Only so that the recorder logs the message at once (it drains its subscribers every
        // tick anyway); a recorder that has gone is no reason to fail.
        let _ = ports.recorder_bell.notify_with_custom_event_id(wire::WAKE);
        Ok(())
    }

    pub(super) fn poll_ports(&mut self) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let mut ready = Vec::new();
        while let Some(s) = iox(ports.lifecycle.receive(), "receive lifecycle")? {
            ready.push(*s.payload());
        }
        let mut progress = Vec::new();
        while let Some(s) = iox(ports.progress.receive(), "receive progress")? {
            progress.push(*s.payload());
        }
        let mut overdue = Vec::new();
        while let Some(s) = iox(ports.overdue.receive(), "receive overdue")? {
            overdue.push(*s.payload());
        }
        let run_id = self.run_id;
        for o in overdue.into_iter().filter(|o| o.run_id == run_id) {
            self.kill_hung(o);
        }
        for l in ready {
            if l.run_id != self.run_id {
                continue;
            }
            // A worker program that is a wrapper (a shell script that sets up an environment
            // and starts the worker without `exec`) announces its child's pid, not the one the
            // supervisor started; that child is in the process group of the program started
            // for the slot. It was taken for a worker joining from outside into an occupied
            // slot, stopped, and restarted until the restart limit ended the run.
            let group = (l.role == wire::role::WORKER)
                .then(|| process_group(l.pid))
                .flatten()
                .filter(|g| {
                    self.procs
                        .get(g)
                        .is_some_and(|p| p.role == Role::Worker(l.worker))
                });
            let pid = group.unwrap_or(l.pid);
            if let Some(p) = self.procs.get_mut(&pid) {
                // A restarted or added worker's pid was said nowhere but in `status`: the
                // line of its death named only the pid of the one before.
                if !p.ready && self.phase == Phase::Running && matches!(p.role, Role::Worker(_)) {
                    say(&format!(
                        "{} (pid {pid}, incarnation {}) is ready",
                        p.role.name(),
                        p.incarnation
                    ));
                }
                p.ready = true;
                p.ready_at.get_or_insert_with(Instant::now);
                if p.role == Role::Recorder {
                    self.recorder_back()?;
                }
            } else if l.role == wire::role::WORKER
                && !self.spawned.ours(l.pid, Instant::now())
                && !process_group(l.pid).is_some_and(|g| self.spawned.ours(g, Instant::now()))
            {
                if let Some(holder) = self.slot_holder(l.worker) {
                    // Both would take slot w's work: every rollout of it would run twice (on a
                    // robot, twice for real). The newcomer is the mistake.
                    let msg = format!(
                        "worker-{w} (pid {pid}) joined slot {w}, which {holder} holds: both \
                         would run its rollouts; stopping pid {pid} (SIGTERM). Start a worker \
                         of your own in a free slot (see `supervisor status`)",
                        w = l.worker,
                        pid = l.pid
                    );
                    say(&format!("WARNING: {msg}"));
                    self.note(RunNote::WARNING, &msg);
                    signal_process(l.pid, libc::SIGTERM);
                    continue;
                }
                // A worker the user started (a robot's driver, a debugger session): not ours
                // to stop or restart, but part of the run.
                let Some(started) = process_started(l.pid) else {
                    continue; // gone already: the sampler hands its rollouts on
                };
                say(&format!(
                    "worker-{} (pid {}) joined the run (started outside the supervisor)",
                    l.worker, l.pid
                ));
                self.joined.insert(l.pid, (l.worker, started));
            }
        }
        for p in progress {
            if p.run_id != self.run_id {
                continue;
            }
            if p.flags & Progress::TASK_CHANGE != 0 {
                // The updater takes changes in order, so those before it are due no later.
                for (seq, _, _, from) in &mut self.unreflected_sets {
                    if *seq <= p.last_change_seq && from.is_none() {
                        *from = Some(p.last_change_from);
                    }
                }
                self.answer_sets(p.last_change_seq, Some(p.last_change_from), false);
                continue;
            }
            // A report's settings are those of its next update, `updates`.
            self.unreflected_sets
                .retain(|(_, _, _, from)| from.is_none_or(|f| f > p.updates));
            let before = self
                .progress
                .filter(|prev| prev.updates == p.updates)
                .map_or(0, |prev| prev.rollouts_done);
            let rollout_done = p.rollouts_done > before;
            if rollout_done && p.flags & Progress::FINAL == 0 {
                if self.stall_reported {
                    say(&format!(
                        "the run goes on: {} of {} rollouts of update {} done, after {:.1} s \
                         without progress",
                        p.rollouts_done,
                        p.rollouts,
                        p.updates,
                        self.quiet_since()
                            .map_or(0.0, |t| t.elapsed().as_secs_f64())
                    ));
                    self.stall_reported = false;
                }
                self.last_rollout_at = Some(Instant::now());
            }
            // Reports also come while an update runs (its rollouts done): a first one is no
            // update, and taken for one it reset the time the first update had been under way.
            let first = self.first_update();
            let new_update = self
                .progress
                .map_or(p.updates > first, |prev| p.updates > prev.updates);
            if new_update {
                // A stopping updater's last report is no news of updates going on.
                if self.stall_reported && p.flags & Progress::FINAL == 0 {
                    say(&format!(
                        "the run goes on: update {} after {:.1} s without one",
                        p.updates,
                        self.last_update_at
                            .map_or(0.0, |t| t.elapsed().as_secs_f64())
                    ));
                }
                self.last_update_at = Some(Instant::now());
                self.stall_reported = false;
            }
            // No new update, no update line.
            let news = p.flags & Progress::FINAL != 0 || new_update;
            if self.rates.is_empty() {
                // A resumed run counts its updates from where it resumed.
                self.rates.add(self.first_update(), 0);
            }
            self.rates.add(p.updates, p.elapsed_ns);
            if let Some(rate) = self.rates.rate() {
                self.rate = rate;
            }
            self.progress = Some(p);
            // At most one line a second, plus one at every tenth of a bounded run.
            let tenth = self
                .cfg
                .run
                .updates
                .is_some_and(|n| p.updates % (n / 10).max(1) == 0);
            let due = tenth
                || self
                    .last_shown
                    .is_none_or(|(t, _)| t.elapsed() >= Duration::from_secs(1));
            // A report without a new update (the stopping updater's last) repeated the line
            // before it, as if an update had been made twice.
            let shown = self.last_shown.is_some_and(|(_, u)| u == p.updates);
            if !self.quiet && due && !shown && news {
                self.last_shown = Some((Instant::now(), p.updates));
                say(&self.progress_line());
            } else if !self.quiet && self.under_way_due(&p) {
                if let Some(line) = self.under_way() {
                    self.last_shown = Some((Instant::now(), p.updates));
                    self.under_way_shown = (p.updates, p.rollouts_done);
                    say(&line);
                }
            }
        }
        Ok(())
    }
}

impl Supervisor {
    /// Whether the update under way gets a line of its own: it has taken longer than
    /// [`UNDER_WAY_LINE`], its rollouts done changed since its last line, and no line was
    /// shown for that long. Updates that take seconds say nothing for minutes otherwise.
    fn under_way_due(&self, p: &Progress) -> bool {
        let long = |t: Instant| t.elapsed() >= UNDER_WAY_LINE;
        p.rollouts_done > 0
            && self.under_way_shown != (p.updates, p.rollouts_done)
            && self.last_update_at.is_some_and(long)
            && self.last_shown.is_none_or(|(t, _)| long(t))
    }
}

/// How long an update runs before its rollouts done so far are shown, and how often.
const UNDER_WAY_LINE: Duration = Duration::from_secs(10);

/// A thread that waits on the supervisor's doorbell and turns each ring into [`Event::Bell`].
pub(super) fn spawn_bell(
    run_id: u64,
    limits: Limits,
    tx: Sender<Event>,
    stop: Arc<AtomicBool>,
) -> anyhow::Result<std::thread::JoinHandle<()>> {
    let (ok_tx, ok_rx) = mpsc::channel::<Result<(), String>>();
    let handle = std::thread::Builder::new()
        .name("doorbell".into())
        .spawn(move || {
            let setup = || -> anyhow::Result<_> {
                let node = wire::node(run_id, "supervisor-bell")?;
                let listener = iox(
                    wire::doorbell(&node, run_id, wire::process::SUPERVISOR, &limits)?
                        .listener_builder()
                        .create(),
                    "supervisor doorbell",
                )?;
                Ok((node, listener))
            };
            let (_node, listener) = match setup() {
                Ok(v) => {
                    let _ = ok_tx.send(Ok(()));
                    v
                }
                Err(e) => {
                    let _ = ok_tx.send(Err(format!("{e:#}")));
                    return;
                }
            };
            // The timeout only bounds how long the thread takes to notice `stop`.
            while !stop.load(Ordering::Relaxed) {
                match listener.timed_wait(|_| {}, Duration::from_millis(250)) {
                    Ok(0) => {}
                    Ok(_) => {
                        if tx.send(Event::Bell).is_err() {
                            break;
                        }
                    }
                    // A signal (the supervisor stopped by Ctrl-Z or SIGSTOP and continued, a
                    // handler run on this thread) interrupts the wait: it ended this thread,
                    // and the supervisor, woken by its deadlines only, took seconds to see the
                    // recorder's acknowledgements and to stop its workers.
                    Err(iceoryx2::port::listener::ListenerWaitError::InterruptSignal) => {}
                    Err(_) => break,
                }
            }
        })?;
    match ok_rx.recv() {
        Ok(Ok(())) => Ok(handle),
        Ok(Err(e)) => bail!("{e}"),
        Err(_) => bail!("the doorbell thread died"),
    }
}
