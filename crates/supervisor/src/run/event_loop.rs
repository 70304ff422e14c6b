//! The [`Supervisor`]'s event loop: the phases of a run (the recorder, updater, sampler and
//! workers started in order, then running, then stopped in reverse order), their timeouts, and
//! what each event (a child's exit, a control command, a signal, the doorbell) does to the run.
//! It is not where processes are started or their exits judged (`children`), nor where the
//! ports' messages are read (`ports`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use pipeline::iox;
use wire::{Control, Limits, RunNote};

use crate::control::{self, Command as Cmd};
use crate::shm;
use crate::{EXIT_INTERRUPTED, EXIT_RECORDING_UNFINISHED};

use super::children::Proc;
use super::ports::{spawn_bell, Ports};
use super::process::{signal_group, Role};
use super::status::plural;
use super::task_changes::{PendingSet, SET_REPLY_WAIT};
use super::{say, Event, Supervisor};

/// How long the stop waits for a process before it says so.
const STOP_WAIT_SAID: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, PartialEq)]
pub(super) enum Outcome {
    Complete,
    Stopped,
    /// By this signal.
    Interrupted(signals::Signal),
    Failed(String),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Phase {
    StartRecorder,
    StartUpdater,
    StartSampler,
    StartWorkers,
    Running,
    Stopping,
}

impl Supervisor {
    pub(super) fn run(&mut self, text: &str, rx: Receiver<Event>) -> anyhow::Result<u8> {
        // A copy: `self` is borrowed mutably below.
        let limits: &Limits = &{ self.limits };
        std::fs::write(&self.config_file, text)
            .with_context(|| format!("cannot write {}", self.config_file.display()))?;
        if let Some(start) = &self.start {
            start.write(&self.start_file())?;
        }
        let bell_stop = Arc::new(AtomicBool::new(false));
        let bell = spawn_bell(self.run_id, *limits, self.tx.clone(), bell_stop.clone())?;
        let node = wire::node(self.run_id, wire::process::SUPERVISOR)?;
        self.ports = Some(Ports {
            lifecycle: iox(
                wire::lifecycle(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "lifecycle subscriber",
            )?,
            progress: iox(
                wire::progress(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "progress subscriber",
            )?,
            overdue: iox(
                wire::overdue(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "overdue subscriber",
            )?,
            recorded: iox(
                wire::recorded(&node, self.run_id, limits)?
                    .subscriber_builder()
                    .create(),
                "recorded subscriber",
            )?,
            control: iox(
                wire::control(&node, self.run_id, limits)?
                    .publisher_builder()
                    .create(),
                "control publisher",
            )?,
            notes: iox(
                wire::notes(&node, self.run_id, limits)?
                    .publisher_builder()
                    .create(),
                "notes publisher",
            )?,
            sampler_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::SAMPLER, limits)?
                    .notifier_builder()
                    .create(),
                "sampler notifier",
            )?,
            updater_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::UPDATER, limits)?
                    .notifier_builder()
                    .create(),
                "updater notifier",
            )?,
            recorder_bell: iox(
                wire::doorbell(&node, self.run_id, wire::process::RECORDER, limits)?
                    .notifier_builder()
                    .create(),
                "recorder notifier",
            )?,
            control_sent: std::cell::Cell::new(0),
            _node: node,
        });
        let tx = self.tx.clone();
        // Ctrl-Z suspends the run ([`super::suspend`]); the others stop it.
        let mut watched = signals::Signal::STOP.to_vec();
        watched.push(signals::Signal::TSTP);
        let ignored = signals::deliver(&watched, move |s| {
            let _ = tx.send(if s == signals::Signal::TSTP {
                Event::Suspend
            } else {
                Event::Signal(s)
            });
        })
        .context("cannot install the SIGINT/SIGTERM/SIGHUP/SIGTSTP handlers")?;
        if ignored.contains(&signals::Signal::HUP) {
            say("SIGHUP is ignored (nohup): closing the terminal does not stop this run");
        }
        control::serve(&self.run_dir, self.tx.clone())?;
        say(&format!(
            "run {} ({}): starting {}updater, sampler and {} worker{}",
            wire::run_id_hex(self.run_id),
            self.cfg.run.name,
            match &self.recording {
                Some(r) => format!("recorder (to {}), ", r.path.display()),
                None => String::new(),
            },
            self.target_workers,
            plural(self.target_workers as u64)
        ));
        let loop_result = self.event_loop(&rx);
        bell_stop.store(true, Ordering::Relaxed);
        let _ = bell.join();
        if let Err(e) = loop_result {
            // Bring the group down before reporting.
            if self.role_pid(Role::Recorder).is_some() {
                if let Some(rec) = self.recording.as_mut() {
                    rec.lost
                        .get_or_insert_with(|| "killed after a supervisor error".into());
                }
            }
            self.kill_all();
            self.reap(&rx, Duration::from_secs(2));
            return Err(e);
        }
        let recording_lost = self.recording.as_ref().is_some_and(|r| r.lost.is_some());
        Ok(match &self.outcome {
            Some(Outcome::Complete) | Some(Outcome::Stopped) if recording_lost => {
                EXIT_RECORDING_UNFINISHED
            }
            Some(Outcome::Complete) | Some(Outcome::Stopped) => 0,
            Some(Outcome::Interrupted(_)) => EXIT_INTERRUPTED,
            Some(Outcome::Failed(_)) | None => 1,
        })
    }

    fn event_loop(&mut self, rx: &Receiver<Event>) -> anyhow::Result<()> {
        self.advance()?;
        loop {
            let now = Instant::now();
            let next = self
                .deadlines()
                .into_iter()
                .min()
                .map(|d| d.saturating_duration_since(now))
                .unwrap_or(Duration::from_secs(3600));
            match rx.recv_timeout(next) {
                Ok(ev) => self.handle(ev)?,
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => bail!("event channel closed"),
            }
            while let Ok(ev) = rx.try_recv() {
                self.handle(ev)?;
            }
            self.poll_ports()?;
            self.groups_emptied();
            self.release_stops()?;
            self.answer_sets(0, None, self.phase == Phase::Stopping);
            self.check_deadlines();
            self.say_stop_waits();
            self.check_stall();
            self.check_joined();
            self.advance()?;
            if self.phase == Phase::Stopping && self.procs.is_empty() {
                return Ok(());
            }
        }
    }

    fn deadlines(&self) -> Vec<Instant> {
        let mut d: Vec<Instant> = self.slots.values().filter_map(|s| s.restart_at).collect();
        d.extend(self.phase_deadline);
        if self.phase == Phase::Running && !self.stall_reported {
            d.extend(self.quiet_since().map(|t| t + self.stall_after()));
        }
        if self.phase == Phase::Stopping {
            d.extend(self.recording.as_ref().and_then(|r| r.term_at));
        }
        d.extend(self.pending_sets.iter().map(|p| p.until));
        d.extend(self.procs.values().filter_map(|p| self.stop_wait_due(p)));
        // Nothing reports that a process group has emptied: look every 20 ms.
        if self.procs.values().any(|p| p.exited_first.is_some()) {
            d.push(Instant::now() + Duration::from_millis(20));
        }
        d.extend(
            self.procs
                .values()
                .filter_map(|p| p.term_wait.map(|(_, t)| t)),
        );
        d.extend(
            self.procs
                .values()
                .filter(|p| !p.sigkilled)
                .filter_map(|p| p.stop_by),
        );
        d
    }

    pub(super) fn fail(&mut self, reason: String) {
        // The run does not end as asked: the recorder is not waited for as after a stop at an
        // update's end.
        self.stop_after_update = false;
        // A failure also outranks a stop that was asked for: the process may have failed
        // before it saw the request, and then the run did not end as asked.
        if matches!(
            self.outcome,
            None | Some(Outcome::Complete) | Some(Outcome::Stopped)
        ) {
            say(&format!("error: {reason}"));
            self.note(RunNote::ERROR, &format!("the run failed: {reason}"));
            self.outcome = Some(Outcome::Failed(reason));
        }
        self.begin_stop();
    }

    pub(super) fn begin_stop(&mut self) {
        if self.phase == Phase::Stopping {
            return;
        }
        self.phase = Phase::Stopping;
        self.phase_deadline =
            Some(Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms));
        for s in self.slots.values_mut() {
            s.restart_at = None;
        }
    }

    fn check_deadlines(&mut self) {
        let now = Instant::now();
        self.kill_scaled_down_overdue(now);
        let Some(deadline) = self.phase_deadline else {
            return;
        };
        if now < deadline {
            return;
        }
        match self.phase {
            Phase::StartRecorder
            | Phase::StartUpdater
            | Phase::StartSampler
            | Phase::StartWorkers => {
                // Workers between a crash and their restart have no process to wait for.
                // A worker whose earlier processes died is named with how the last one did:
                // the cause, which the timeout alone hid in earlier lines.
                let died = |w: &u32| {
                    self.slots
                        .get(w)
                        .and_then(|s| s.last_death.as_deref())
                        .map(|d| format!("; its last attempt died: {d}"))
                        .unwrap_or_default()
                };
                let waiting: Vec<String> = self
                    .procs
                    .values()
                    .filter(|p| !p.ready)
                    .map(|p| match p.role {
                        Role::Worker(w) if !died(&w).is_empty() => {
                            format!("{} (restarted{})", p.role.name(), died(&w))
                        }
                        _ => p.role.name(),
                    })
                    .chain(
                        self.slots
                            .iter()
                            .filter(|(_, s)| s.pid.is_none())
                            .map(|(w, _)| {
                                format!("worker-{w} (waiting to be restarted{})", died(w))
                            }),
                    )
                    .collect();
                // A worker of the user's own that runs but never announces itself timed out
                // with nothing to say what "ready" is: neither the wire docs nor the README's
                // steps for a worker in another language named the announcement.
                let own_worker_waits = self.cfg.external_worker().is_some()
                    && self
                        .procs
                        .values()
                        .any(|p| !p.ready && matches!(p.role, Role::Worker(_)));
                let hint = if own_worker_waits {
                    "; a worker of your own is ready once it has built its task (a simulator \
                     that takes longer to start needs a larger pipeline.startup_timeout_ms), \
                     opened its ports, announced itself on `lifecycle` (role 3, its slot and \
                     incarnation) and rung `wake/supervisor`, as pipeline::worker::serve and \
                     tools/pi2cma_worker.py do (README, \"Wire layout\")"
                } else {
                    ""
                };
                self.fail(format!(
                    "{} did not become ready within {} ms (pipeline.startup_timeout_ms){hint}",
                    waiting.join(", "),
                    self.pipe.startup_timeout_ms
                ));
            }
            Phase::Stopping if !self.killed => {
                // The stage that was asked to stop and has not (a worker in a robot's long
                // episode, a hung one, a stuck sampler): only it is killed. The stages after it
                // are then asked in order, each with a timeout of its own, so the recorder
                // still finishes the file unless it is the one that hangs.
                let stuck: Vec<(u32, String)> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| p.stopping && !p.sigkilled)
                    .map(|(pid, p)| (*pid, format!("{} (pid {pid})", p.role.name())))
                    .collect();
                if !stuck.is_empty() {
                    let others = self.procs.values().any(|p| !p.stopping);
                    say(&format!(
                        "{} did not stop within {} ms (pipeline.shutdown_timeout_ms); killing {}{}",
                        stuck
                            .iter()
                            .map(|(_, n)| n.as_str())
                            .collect::<Vec<_>>()
                            .join(", "),
                        self.pipe.shutdown_timeout_ms,
                        if stuck.len() == 1 { "it" } else { "them" },
                        if others {
                            ", then stopping the others in order"
                        } else {
                            ""
                        }
                    ));
                    for (pid, _) in &stuck {
                        signal_group(*pid, libc::SIGKILL);
                        if let Some(p) = self.procs.get_mut(pid) {
                            p.sigkilled = true;
                        }
                    }
                    self.phase_deadline = Some(now + Duration::from_secs(5));
                    return;
                }
                let unreaped: Vec<u32> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| p.sigkilled)
                    .map(|(pid, _)| *pid)
                    .collect();
                if !unreaped.is_empty() {
                    let names: Vec<String> = unreaped
                        .iter()
                        .map(|pid| self.procs[pid].role.name())
                        .collect();
                    say(&format!(
                        "giving up waiting for {} after SIGKILL",
                        names.join(", ")
                    ));
                    for pid in unreaped {
                        self.procs.remove(&pid);
                    }
                }
                // The next stage sets its own deadline when it is asked (or the recorder's
                // `term_at` wakes the loop).
                self.phase_deadline = None;
            }
            Phase::Stopping => {
                // Killed processes that still have not been reaped: nothing more to do.
                let names: Vec<String> = self.procs.values().map(|p| p.role.name()).collect();
                say(&format!(
                    "giving up waiting for {} after SIGKILL",
                    names.join(", ")
                ));
                self.procs.clear();
            }
            Phase::Running => self.phase_deadline = None,
        }
    }

    /// When the stop's wait for `p` is to be said ([`Self::say_stop_waits`]), if it is to be:
    /// one rule for the saying and for the event loop's wake-ups, which woke at once, over and
    /// over, for a process SIGKILLed and not yet reaped.
    fn stop_wait_due(&self, p: &Proc) -> Option<Instant> {
        let says = self.phase == Phase::Stopping && !self.killed && !p.sigkilled && !p.wait_said;
        says.then_some(p.asked_at?).map(|t| t + STOP_WAIT_SAID)
    }

    /// Names the processes the stop has waited for longer than [`STOP_WAIT_SAID`], once each:
    /// with a long `shutdown_timeout_ms` (a robot's episode) the stop said nothing until the
    /// timeout, and a second Ctrl-C, pressed at a supervisor that looked hung, killed the
    /// recorder too.
    fn say_stop_waits(&mut self) {
        let now = Instant::now();
        let due: Vec<u32> = self
            .procs
            .iter()
            .filter(|(_, p)| self.stop_wait_due(p).is_some_and(|t| t <= now))
            .map(|(pid, _)| *pid)
            .collect();
        let mut waited = Vec::new();
        for pid in due {
            if let Some(p) = self.procs.get_mut(&pid) {
                p.wait_said = true;
                waited.push(format!("{} (pid {pid})", p.role.name()));
            }
        }
        if waited.is_empty() {
            return;
        }
        let left = self
            .phase_deadline
            .map(|d| d.saturating_duration_since(now).as_secs_f64())
            .unwrap_or(0.0);
        let recorder = if self.role_pid(Role::Recorder).is_some() {
            ", the recorder too, which leaves the recording unfinished"
        } else {
            ""
        };
        // Any signal during the stop kills: "a second Ctrl-C" only to a user who has pressed
        // one. After `supervisor stop` (or a failure, or the run's end) a user pressed Ctrl-C
        // as a first one, to stop in order, and lost the recording's finish.
        let ctrl_c = if matches!(self.outcome, Some(Outcome::Interrupted(_))) {
            "a second Ctrl-C kills"
        } else {
            "Ctrl-C now kills"
        };
        say(&format!(
            "still waiting for {} to stop; killed in {left:.1} s (pipeline.shutdown_timeout_ms = \
             {}); {ctrl_c} every process at once{recorder}",
            waited.join(", "),
            self.pipe.shutdown_timeout_ms
        ));
    }

    fn kill_all(&mut self) {
        self.killed = true;
        for pid in self.procs.keys() {
            signal_group(*pid, libc::SIGKILL);
        }
    }

    /// Waits (bounded) for the exits of killed processes.
    fn reap(&mut self, rx: &Receiver<Event>, bound: Duration) {
        let end = Instant::now() + bound;
        while !self.procs.is_empty() {
            match rx.recv_timeout(end.saturating_duration_since(Instant::now())) {
                Ok(Event::Exited { pid, .. }) => {
                    self.procs.remove(&pid);
                    self.spawned.reaped(pid, Instant::now());
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
    }

    fn advance(&mut self) -> anyhow::Result<()> {
        let startup = Duration::from_millis(self.pipe.startup_timeout_ms);
        match self.phase {
            Phase::StartRecorder => {
                if self.role_pid(Role::Recorder).is_none() {
                    self.spawn(Role::Recorder, 0)?;
                    self.phase_deadline = Some(Instant::now() + startup);
                } else if self.role_ready(Role::Recorder) {
                    // Subscribed to every service: nothing the updater publishes is missed.
                    self.phase = Phase::StartUpdater;
                    return self.advance();
                }
            }
            Phase::StartUpdater => {
                if self.role_pid(Role::Updater).is_none() {
                    self.spawn(Role::Updater, 0)?;
                    self.phase_deadline = Some(Instant::now() + startup);
                } else if self.role_ready(Role::Updater) {
                    self.spawn(Role::Sampler, 0)?;
                    self.phase = Phase::StartSampler;
                    self.phase_deadline = Some(Instant::now() + startup);
                }
            }
            Phase::StartSampler => {
                if self.role_ready(Role::Sampler) {
                    self.phase = Phase::StartWorkers;
                    self.phase_deadline = Some(Instant::now() + startup);
                    self.apply_scale()?;
                }
            }
            Phase::StartWorkers | Phase::Running => {
                self.restart_due();
                if self.phase == Phase::StartWorkers {
                    let workers: Vec<&Proc> = self
                        .procs
                        .values()
                        .filter(|p| matches!(p.role, Role::Worker(_)))
                        .collect();
                    // Slots joined workers hold were skipped: ours are the slots we filled.
                    if workers.len() >= self.slots.len().min(self.target_workers)
                        && workers.iter().all(|p| p.ready)
                    {
                        self.send_control(Control::plain(self.run_id, Control::START), true)?;
                        self.phase = Phase::Running;
                        self.last_update_at = Some(Instant::now());
                        self.phase_deadline = None;
                        say(&format!(
                            "all {} processes ready after {} ms; run started",
                            self.procs.len(),
                            self.started.elapsed().as_millis()
                        ));
                    }
                }
            }
            Phase::Stopping => {
                // Reverse start order: workers, then the sampler, then the updater, then the
                // recorder.
                let workers: Vec<u32> = self
                    .procs
                    .iter()
                    .filter(|(_, p)| matches!(p.role, Role::Worker(_)))
                    .map(|(pid, _)| *pid)
                    .collect();
                let stage = if !workers.is_empty() {
                    workers
                } else if let Some(pid) = self.role_pid(Role::Sampler) {
                    vec![pid]
                } else if let Some(pid) = self.role_pid(Role::Updater) {
                    vec![pid]
                } else if let Some(pid) = self.role_pid(Role::Recorder) {
                    // After a complete run it exits by itself once it has written the final
                    // update; SIGTERM (which finishes the file with everything received)
                    // only if it has not done so within half the shutdown timeout.
                    let complete =
                        self.outcome == Some(Outcome::Complete) || self.stop_after_update;
                    let half = Duration::from_millis(self.pipe.shutdown_timeout_ms / 2);
                    let rec = self.recording.as_mut().expect("a recorder has a recording");
                    let due = *rec.term_at.get_or_insert_with(|| {
                        Instant::now() + if complete { half } else { Duration::ZERO }
                    });
                    if Instant::now() >= due {
                        vec![pid]
                    } else {
                        vec![]
                    }
                } else {
                    vec![]
                };
                let mut asked = false;
                for pid in stage {
                    let p = self.procs.get_mut(&pid).expect("pid from procs");
                    if !p.stopping {
                        p.stopping = true;
                        p.asked_at = Some(Instant::now());
                        asked = true;
                        if matches!(p.role, Role::Worker(_)) {
                            self.stop_worker(pid);
                        } else {
                            signal_group(pid, libc::SIGTERM);
                        }
                    }
                }
                // Each stage has `shutdown_timeout_ms` of its own, from when it is asked.
                if asked {
                    self.phase_deadline =
                        Some(Instant::now() + Duration::from_millis(self.pipe.shutdown_timeout_ms));
                }
            }
        }
        Ok(())
    }

    /// Ctrl-Z: stops every child's process group, then the supervisor; once the supervisor is
    /// continued (`fg`), continues them. The time it was suspended counts towards no stall.
    fn suspend(&mut self) {
        let groups: Vec<u32> = self.procs.keys().copied().collect();
        for &pid in &groups {
            signal_group(pid, libc::SIGSTOP);
        }
        say(&format!(
            "Ctrl-Z: the run is suspended, its {} processes with the supervisor; `fg` (or `kill \
             -CONT {}`) continues them",
            groups.len(),
            std::process::id()
        ));
        let suspended = Instant::now();
        super::suspend::stop_self();
        for &pid in &groups {
            signal_group(pid, libc::SIGCONT);
        }
        let paused = suspended.elapsed();
        for t in [&mut self.last_update_at, &mut self.last_rollout_at]
            .into_iter()
            .flatten()
        {
            *t += paused;
        }
        say(&format!(
            "continued after {:.1} s: the run goes on",
            paused.as_secs_f64()
        ));
    }

    fn handle(&mut self, ev: Event) -> anyhow::Result<()> {
        match ev {
            Event::Bell => Ok(()),
            Event::Signal(signal) => {
                if self.phase == Phase::Stopping {
                    say(&format!(
                        "{signal} (a second signal): killing the group now"
                    ));
                    self.kill_all();
                } else {
                    say(&format!(
                        "{signal} received: stopping (again to kill at once)"
                    ));
                    // Before the update under way is done, a signal ends `stop --after-update`
                    // as it ends any run: that update's rollouts are thrown away, and the
                    // summary must not say that none was (nor the recorder be waited for as if
                    // the updater had ended the run).
                    if std::mem::take(&mut self.stop_after_update) || self.outcome.is_none() {
                        self.outcome = Some(Outcome::Interrupted(signal));
                    }
                    self.begin_stop();
                }
                Ok(())
            }
            Event::Suspend => {
                self.suspend();
                Ok(())
            }
            Event::Command((Cmd::Set(name, value), reply)) => {
                match self.set_task(&name, value) {
                    Ok(seq) => self.pending_sets.push(PendingSet {
                        seq,
                        name: name.clone(),
                        what: format!("{name} = {}", tasks::value_text(value)),
                        reply,
                        until: Instant::now() + SET_REPLY_WAIT,
                    }),
                    Err(e) => {
                        let _ = reply.send(Err(e));
                    }
                }
                Ok(())
            }
            Event::Command((cmd, reply)) => {
                let r = self.command(cmd);
                let _ = reply.send(r);
                Ok(())
            }
            Event::Exited { pid, status } => {
                self.child_exited(pid, status);
                Ok(())
            }
        }
    }

    /// `supervisor stop --after-update`: the updater finishes the update under way and ends the
    /// run with a `FINAL | STOPPED` distribution, whose update a resumed run begins with; the
    /// updater's exit then stops the rest in order. Before the run has started there is no
    /// rollout to keep: a plain stop.
    fn stop_after_update(&mut self) -> Result<String, String> {
        if self.phase == Phase::Stopping {
            return Err("the run is stopping already".into());
        }
        if self.stop_after_update {
            return Ok(
                "stopping after the update under way already (`supervisor stop` stops at \
                       once)"
                    .into(),
            );
        }
        if self.phase != Phase::Running {
            self.command(Cmd::Stop)?;
            return Ok("stopping (the run had not started: no update under way)".into());
        }
        let msg = Control::plain(self.run_id, Control::STOP_AFTER_UPDATE);
        self.send_control(msg, true).map_err(|e| format!("{e:#}"))?;
        self.stop_after_update = true;
        if self.outcome.is_none() {
            self.outcome = Some(Outcome::Stopped);
        }
        let what = format!(
            "stopping after the update under way{} once all its rollouts are done; `supervisor \
             stop` stops at once",
            self.under_way()
                .map_or(String::new(), |line| format!(" ({line})"))
        );
        say(&what);
        Ok(what)
    }

    fn command(&mut self, cmd: Cmd) -> Result<String, String> {
        match cmd {
            Cmd::Status => {
                // The recorder's progress as of now, not of the last loop round.
                self.drain_recorder_acks().map_err(|e| format!("{e:#}"))?;
                Ok(self.status())
            }
            Cmd::Stop => {
                if self.outcome.is_none() {
                    self.outcome = Some(Outcome::Stopped);
                }
                self.stop_after_update = false;
                self.begin_stop();
                Ok("stopping".into())
            }
            Cmd::StopAfterUpdate => self.stop_after_update(),
            Cmd::Scale(n) => {
                if self.phase == Phase::Stopping {
                    return Err("the run is stopping".into());
                }
                if n == 0 {
                    // What a user who asks for 0 wants is a pause: that is a stop and a resume.
                    return Err(
                        "cannot scale to 0 workers: a run needs at least 1 (to pause it, \
                                `supervisor stop --after-update`, which lets the update under \
                                way finish; `supervisor run --resume RECORDING` later goes on \
                                where it stopped, bit for bit)"
                            .into(),
                    );
                }
                if !(1..=self.pipe.max_workers).contains(&n) {
                    return Err(format!(
                        "cannot scale to {n} workers: must be between 1 and pipeline.max_workers = {}",
                        self.pipe.max_workers
                    ));
                }
                let was = self.target_workers;
                if n > was && !self.no_shm_check {
                    let reruns = self.cfg.run.nonfinite_reruns > 0;
                    let ports = (self.recording.is_some(), reruns);
                    shm::check_scale(&self.limits, ports, was, n)?;
                }
                self.target_workers = n;
                if matches!(self.phase, Phase::StartWorkers | Phase::Running) {
                    self.apply_scale().map_err(|e| format!("{e:#}"))?;
                }
                say(&format!("scaling from {was} to {n} workers"));
                Ok(format!("scaling from {was} to {n} workers"))
            }
            Cmd::Set(..) => Err("internal: `set` is answered by `set_task`".into()),
            Cmd::Record => self.record_again(),
        }
    }
}
