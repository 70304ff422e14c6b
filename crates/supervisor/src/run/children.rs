//! The supervisor's children: starting a role's process (its output printed, its exit
//! forwarded to the event loop), the table of running processes and of the pids started, and
//! what a child's exit means for the run (a restart, a failure, the run complete or stopped).
//! It is not the operating system's side of processes (`process`) nor worker slots and scaling
//! (`workers`).

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use wire::Control;

use crate::shm::{self, SHM_DIR};

use super::event_loop::{Outcome, Phase};
use super::process::{
    die_with_parent, file_size_limit, group_members, sigbus_hint, signal_group, xfsz_hint, Role,
};
use super::recorder::recorder_restartable;
use super::summary::pi2cma_program;
use super::workers::{may_restart, restart_backoff};
use super::{print_line, say, Event, Supervisor};

pub(super) struct Proc {
    pub(super) role: Role,
    pub(super) incarnation: u32,
    pub(super) ready: bool,
    pub(super) stopping: bool,
    /// SIGKILLed after it was asked to stop and did not within `shutdown_timeout_ms`.
    pub(super) sigkilled: bool,
    /// A worker a scale-down asked to stop: killed if it has not by then.
    pub(super) stop_by: Option<Instant>,
    /// Killed because it held its chunk too long (`pipeline.rollout_timeout_ms`): why.
    pub(super) hung: Option<String>,
    /// When it was started, and when it announced itself (its ports exist from then on).
    pub(super) spawned_at: Instant,
    pub(super) ready_at: Option<Instant>,
    /// A worker asked to stop whose SIGTERM waits for the recorder to connect to its ports:
    /// the RECORDER_SYNC it waits for, and until when (see [`Supervisor::stop_worker`]).
    pub(super) term_wait: Option<(u64, Instant)>,
    /// It has exited while asked to stop, but processes it started in its process group still
    /// run (a worker program that is a wrapper script without `exec`, whose child is the real
    /// worker, still finishing its rollout): its exit counts once they are gone, so the stage
    /// waits for them as for it and kills them at its timeout.
    pub(super) exited_first: Option<ExitStatus>,
    /// When the run's stop asked it to stop, and whether the wait for it has been said
    /// ([`Supervisor::say_stop_waits`]).
    pub(super) asked_at: Option<Instant>,
    pub(super) wait_said: bool,
    /// Its last error line, else its last line, and when it was printed.
    last_line: Arc<Mutex<(String, Option<Instant>)>>,
}

/// How long a reaped child's pid is still taken as the supervisor's own when an announcement
/// from it is read ([`Spawned`]); the supervisor reads announcements within a tick of their
/// sending, so this only has to outlast a loaded machine.
pub(super) const LATE_ANNOUNCEMENT: Duration = Duration::from_secs(60);

/// How long a child's exit waits for the rest of its output to be printed.
const OUTPUT_AFTER_EXIT: Duration = Duration::from_millis(200);

/// The pids the supervisor started: running, or reaped within [`LATE_ANNOUNCEMENT`]. They used
/// to be kept for the whole run, one per worker incarnation, so a continual run whose workers
/// were restarted and scaled for days kept a set that only grew, and once the kernel handed one
/// of those pids (`kernel.pid_max` is 32768 on many systems) to a worker the user started, that
/// worker was taken for a late announcement of the supervisor's own: not listed as joined, and
/// not stopped when it took a slot a worker of the supervisor's held.
#[derive(Default)]
pub(super) struct Spawned {
    /// pid → when it was reaped (`None`: running).
    pids: BTreeMap<u32, Option<Instant>>,
}

impl Spawned {
    fn started(&mut self, pid: u32) {
        self.pids.insert(pid, None);
    }

    /// `pid` has exited and was reaped at `now`; pids reaped too long ago are forgotten.
    pub(super) fn reaped(&mut self, pid: u32, now: Instant) {
        if let Some(at) = self.pids.get_mut(&pid) {
            *at = Some(now);
        }
        self.pids.retain(|_, at| Self::recent(*at, now));
    }

    /// Whether an announcement read at `now` from `pid` is from a process this supervisor
    /// started.
    pub(super) fn ours(&self, pid: u32, now: Instant) -> bool {
        self.pids.get(&pid).is_some_and(|at| Self::recent(*at, now))
    }

    fn recent(reaped: Option<Instant>, now: Instant) -> bool {
        reaped.is_none_or(|t| now.saturating_duration_since(t) < LATE_ANNOUNCEMENT)
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.pids.len()
    }
}

impl Supervisor {
    pub(super) fn role_pid(&self, role: Role) -> Option<u32> {
        self.procs
            .iter()
            .find(|(_, p)| p.role == role)
            .map(|(pid, _)| *pid)
    }

    pub(super) fn role_ready(&self, role: Role) -> bool {
        self.procs.values().any(|p| p.role == role && p.ready)
    }

    /// Where a resumed run's state is handed to the updater.
    pub(super) fn start_file(&self) -> PathBuf {
        self.run_dir.join("start.toml")
    }

    pub(super) fn spawn(&mut self, role: Role, incarnation: u32) -> anyhow::Result<()> {
        let (exe, leading) = self.launcher.program(role);
        let mut cmd = Command::new(&exe);
        cmd.args(leading)
            .arg("--config")
            .arg(&self.config_file)
            .arg("--run-dir")
            .arg(&self.run_dir)
            .arg("--run-id")
            .arg(wire::run_id_hex(self.run_id));
        if let (Role::Recorder, Some(rec)) = (role, &self.recording) {
            cmd.arg("--out").arg(std::path::absolute(&rec.path)?);
            if let Some(start) = &self.start {
                cmd.arg("--resumed-from")
                    .arg(&start.origin)
                    .arg("--start")
                    .arg(self.start_file());
            }
            if let Some(part) = rec.continue_in {
                cmd.arg("--part")
                    .arg(part.to_string())
                    .arg("--restart")
                    .arg(rec.restarted.to_string());
            }
        }
        if let (Role::Updater, Some(_)) = (role, &self.start) {
            cmd.arg("--start").arg(self.start_file());
        }
        if let Role::Worker(w) = role {
            cmd.arg("--worker")
                .arg(w.to_string())
                .arg("--incarnation")
                .arg(incarnation.to_string());
        }
        let (reader, writer) = std::io::pipe()?;
        cmd.stdin(Stdio::null())
            .stdout(writer.try_clone()?)
            .stderr(writer)
            .process_group(0);
        die_with_parent(&mut cmd);
        let mut child = cmd
            .spawn()
            .with_context(|| format!("cannot start {} ({})", role.name(), exe.display()))?;
        drop(cmd); // closes our copies of the pipe's write end
        let pid = child.id();
        let last_line = Arc::new(Mutex::new((String::new(), None)));
        let name = role.name();
        let last = last_line.clone();
        let (printed, printer_done) = std::sync::mpsc::channel::<()>();
        std::thread::Builder::new()
            .name(format!("out-{name}"))
            .spawn(move || {
                // The reason a process died: its last error line, else its last line (after
                // `error: …`, clap adds "For more information, try '--help'.").
                let mut seen_error = false;
                for line in BufReader::new(reader).lines() {
                    let Ok(line) = line else { break };
                    print_line(&name, &line);
                    let error = line.trim_start().to_ascii_lowercase().starts_with("error");
                    if error || !seen_error {
                        if let Ok(mut l) = last.lock() {
                            *l = (line, Some(Instant::now()));
                        }
                    }
                    seen_error |= error;
                }
                drop(printed);
            })?;
        let tx = self.tx.clone();
        std::thread::Builder::new()
            .name(format!("wait-{pid}"))
            .spawn(move || {
                let status = child.wait();
                // The child's last words are printed before its exit, but a process it started
                // (a simulator) holds the pipe open as long as it runs: waiting for the end of
                // the output hid a dead worker, which was not restarted nor reported.
                let _ = printer_done.recv_timeout(OUTPUT_AFTER_EXIT);
                if let Ok(status) = status {
                    let _ = tx.send(Event::Exited { pid, status });
                }
            })?;
        self.spawned.started(pid);
        self.procs.insert(
            pid,
            Proc {
                role,
                incarnation,
                ready: false,
                stopping: false,
                sigkilled: false,
                stop_by: None,
                hung: None,
                spawned_at: Instant::now(),
                ready_at: None,
                term_wait: None,
                exited_first: None,
                asked_at: None,
                wait_said: false,
                last_line,
            },
        );
        if let Role::Worker(w) = role {
            self.slots.entry(w).or_default().pid = Some(pid);
        }
        Ok(())
    }

    /// A child has exited (its waiter says so). What it left running in its process group is
    /// waited for if it was asked to stop, and killed if it died unasked: a simulator a crashed
    /// worker started would otherwise run on beside the one its restart starts, and outlive
    /// the run. Then [`Self::exited`] judges the exit.
    pub(super) fn child_exited(&mut self, pid: u32, status: ExitStatus) {
        let stopping = self.phase == Phase::Stopping;
        if let Some(p) = self.procs.get_mut(&pid) {
            let left = group_members(pid);
            if !left.is_empty() {
                if p.stopping || stopping {
                    p.exited_first = Some(status);
                    return;
                }
                // Killed with its group already (hung, or overdue after a scale-down): what is
                // left is dying of that SIGKILL, not left running.
                if p.hung.is_some() || p.sigkilled {
                    signal_group(pid, libc::SIGKILL);
                    self.exited(pid, status);
                    return;
                }
                let names: Vec<String> = left
                    .iter()
                    .map(|m| {
                        let comm =
                            std::fs::read_to_string(format!("/proc/{m}/comm")).unwrap_or_default();
                        format!("{m} {}", comm.trim())
                    })
                    .collect();
                say(&format!(
                    "{} (pid {pid}) left {} process(es) running in its process group ({}): \
                     killing them",
                    p.role.name(),
                    left.len(),
                    names.join(", ")
                ));
                signal_group(pid, libc::SIGKILL);
            }
        }
        self.exited(pid, status);
    }

    /// Judges the exits of children that exited before the rest of their process group
    /// ([`Proc::exited_first`]) once that group is empty.
    pub(super) fn groups_emptied(&mut self) {
        let emptied: Vec<(u32, ExitStatus)> = self
            .procs
            .iter()
            .filter_map(|(pid, p)| Some((*pid, p.exited_first?)))
            .filter(|(pid, _)| group_members(*pid).is_empty())
            .collect();
        for (pid, status) in emptied {
            self.exited(pid, status);
        }
    }

    pub(super) fn exited(&mut self, pid: u32, status: ExitStatus) {
        self.spawned.reaped(pid, Instant::now());
        let Some(p) = self.procs.remove(&pid) else {
            return;
        };
        // Processes read the copy of the config in the run directory; the user knows theirs.
        let (last, printed) = p
            .last_line
            .lock()
            .map(|l| {
                let text = l.0.replace(
                    &self.config_file.display().to_string(),
                    &self.cfg.origin.display().to_string(),
                );
                (text, l.1)
            })
            .unwrap_or_default();
        let cause = death_cause(
            status,
            p.hung.is_some(),
            &last,
            printed.map(|t| t.elapsed()),
        );
        let hint = sigbus_hint(
            status,
            shm::space(Path::new(SHM_DIR)).map(|s| (s.free, s.total)),
        )
        .or_else(|| xfsz_hint(status, file_size_limit()));
        let cause = match hint {
            Some(hint) => format!("{cause}; {hint}"),
            None => cause,
        };
        match p.role {
            Role::Worker(w) => {
                // Its slot may have been given to a new worker after a scale-down stopped it.
                let own_slot = self.slots.get(&w).is_some_and(|s| s.pid == Some(pid));
                let reason = if p.hung.is_some() {
                    wire::lost::HUNG
                } else if !own_slot {
                    wire::lost::SCALED_DOWN
                } else if p.stopping || self.phase == Phase::Stopping {
                    wire::lost::STOPPED
                } else if status.success() {
                    wire::lost::EXITED
                } else {
                    wire::lost::CRASHED
                };
                let how = status.to_string();
                let lost = Control::worker_lost(self.run_id, w, p.incarnation, pid, reason, &how);
                let _ = self.send_control(lost, false);
                let asked = p.stopping || self.phase == Phase::Stopping;
                if asked && !p.sigkilled && !self.killed {
                    // A worker asked to stop that ended otherwise than as asked (a task whose
                    // shutdown failed: a robot that did not park) went unsaid.
                    if !stopped_as_asked(status) {
                        let msg = format!(
                            "{} (pid {pid}), asked to stop, did not end cleanly ({cause})",
                            p.role.name()
                        );
                        say(&format!("warning: {msg}"));
                        self.note(wire::RunNote::WARNING, &msg);
                    } else if self.phase != Phase::Stopping {
                        say(&format!("{} (pid {pid}) stopped ({status})", p.role.name()));
                    }
                }
                let Some(slot) = self.slots.get_mut(&w).filter(|_| own_slot) else {
                    return; // scaled away
                };
                slot.pid = None;
                slot.last_death = Some(cause.clone());
                if p.stopping || self.phase == Phase::Stopping {
                    return;
                }
                if status.code() == Some(i32::from(wire::EXIT_CONFIG_REFUSED)) {
                    self.fail(format!(
                        "worker-{w} refused the config, not restarted ({cause})"
                    ));
                    return;
                }
                // One that exits before it has announced itself ran nothing: a start that
                // failed, restarted as such (taken for a stop, it ended the run with exit 0).
                if status.success() && p.ready {
                    self.exited_on_purpose(w, pid, &cause);
                    return;
                }
                let now = Instant::now();
                if !may_restart(&mut slot.restarts, &self.pipe, now) {
                    let n = slot.restarts.len();
                    self.fail(format!(
                        "worker-{w} died ({cause}) after {n} restarts within {} s: restart limit (pipeline.restart_limit = {}) exhausted",
                        self.pipe.restart_window_s, self.pipe.restart_limit
                    ));
                    return;
                }
                slot.restarts.push_back(now);
                let backoff = restart_backoff(slot.restarts.len());
                slot.restart_at = Some(now + backoff);
                self.total_restarts += 1;
                say(&format!(
                    "worker-{w} (pid {pid}) died ({cause}); its rollouts go to the others; restart {} of {} in {} ms",
                    slot.restarts.len(),
                    self.pipe.restart_limit,
                    backoff.as_millis()
                ));
            }
            Role::Updater => {
                if self.phase == Phase::Stopping && (p.stopping || self.killed) {
                    // Told to stop, it exits 0 (or is killed at the shutdown timeout); exit
                    // code 1 is an error of its own, such as a cost it refused just before.
                    if status.code() == Some(1) {
                        self.fail(format!("updater exited ({cause})"));
                    }
                    return;
                }
                if status.success() && self.phase == Phase::Running {
                    if self.outcome.is_none() {
                        self.outcome = Some(Outcome::Complete);
                    }
                    self.begin_stop();
                } else {
                    self.fail(format!("updater exited ({cause})"));
                }
            }
            Role::Sampler => {
                if self.phase == Phase::Stopping && (p.stopping || self.killed) {
                    if status.code() == Some(1) {
                        self.fail(format!("sampler exited ({cause})"));
                    }
                    return;
                }
                self.fail(format!("sampler exited ({cause})"));
            }
            Role::Recorder => {
                let starting = self.phase == Phase::StartRecorder;
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                // The part being written (the only one a split recording leaves unfinished).
                let path = record::last_part(&rec.path).display().to_string();
                if !starting && !status.success() && self.phase == Phase::Running {
                    if !recorder_restartable(status, p.ready) {
                        say(&format!(
                            "recorder not restarted: it stopped at an error of its own ({cause}), \
                             which a new one would meet as well (a full disk, an unwritable \
                             file); once that is mended, `supervisor record` starts it again"
                        ));
                    } else {
                        match self.restart_recorder(pid, &cause) {
                            Ok(true) => return,
                            Ok(false) => {}
                            Err(e) => say(&format!("WARNING: cannot restart the recorder: {e:#}")),
                        }
                    }
                }
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                rec.back_pending = None;
                if !starting {
                    // Whatever its exit status, the updater must stop waiting for its
                    // acknowledgements.
                    let _ = self
                        .send_control(Control::plain(self.run_id, Control::RECORDER_LOST), true);
                }
                let Some(rec) = self.recording.as_mut() else {
                    return;
                };
                if starting {
                    // It recorded nothing: the path may even be another run's live file (which
                    // it refused), so the summary must not point to it.
                    self.recording = None;
                    self.fail(format!(
                        "recorder exited before it was ready ({cause}); run with --no-record to \
                         run without a recording"
                    ));
                } else if !status.success() {
                    // Not restarted: while stopping, or pipeline.restart_limit is exhausted.
                    rec.lost = Some(cause.clone());
                    let go_on = if self.phase == Phase::Stopping {
                        ""
                    } else {
                        "; the run continues without recording (`supervisor record` starts it \
                         again, into a new part)"
                    };
                    let (pi2cma, how_to_build) = pi2cma_program();
                    if Path::new(&path).exists() {
                        say(&format!(
                            "WARNING: recorder (pid {pid}) died ({cause}){go_on}. {path} holds \
                             every update flushed so far but is not finished: `{pi2cma} recover \
                             {path}` (or `mcap-tool recover {path}`) completes it{how_to_build}"
                        ));
                    } else {
                        // Stopped as the run failed to start, before it created its file.
                        say(&format!(
                            "WARNING: recorder (pid {pid}) died ({cause}){go_on}, before it \
                             created {path}: nothing was recorded"
                        ));
                    }
                }
            }
        }
    }
}

/// Why a child ended, as the restart and failure messages give it: its exit status and its
/// last output. The last line may be an error or only news ("recording continues in …"), so it
/// is labelled, not given as the cause; one printed long before the death (a refused `set`
/// 50 updates before a worker was SIGKILLed) says how long before, so that it does not read as
/// what killed it.
fn death_cause(status: ExitStatus, hung: bool, last: &str, age: Option<Duration>) -> String {
    if hung {
        return format!("{status}, killed after it hung");
    }
    if last.is_empty() {
        return status.to_string();
    }
    match age {
        Some(age) if age >= Duration::from_secs(2) => format!(
            "{status}; its last output, {:.0} s before: {last}",
            age.as_secs_f64()
        ),
        _ => format!("{status}; its last output: {last}"),
    }
}

/// Whether a process asked to stop (SIGTERM) ended as that asks: exit status 0, or death by
/// SIGTERM or SIGINT, or their shells' exit codes 128 + signal (a wrapper script, a Python
/// worker without a handler), which are no failure.
fn stopped_as_asked(status: ExitStatus) -> bool {
    use std::os::unix::process::ExitStatusExt as _;
    let asked = [libc::SIGTERM, libc::SIGINT];
    status.success()
        || status.signal().is_some_and(|s| asked.contains(&s))
        || status
            .code()
            .is_some_and(|c| asked.iter().any(|s| c == 128 + s))
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_death_names_how_long_before_it_the_last_output_came_when_that_was_long() {
        use super::death_cause;
        use std::os::unix::process::ExitStatusExt as _;
        use std::process::ExitStatus;
        use std::time::Duration;
        let killed = ExitStatus::from_raw(9);
        let refused = "update 38: the task's set('effort', -1.0) raised ValueError";
        assert_eq!(
            death_cause(killed, false, refused, Some(Duration::from_millis(53_400))),
            format!("signal: 9 (SIGKILL); its last output, 53 s before: {refused}")
        );
        // Its dying words: no age.
        let failed = ExitStatus::from_raw(1 << 8);
        let error = "error: my_worker.py failed: RuntimeError: simulator license not found";
        assert_eq!(
            death_cause(failed, false, error, Some(Duration::from_millis(30))),
            format!("exit status: 1; its last output: {error}")
        );
        assert_eq!(death_cause(killed, false, "", None), "signal: 9 (SIGKILL)");
        assert_eq!(
            death_cause(killed, true, refused, Some(Duration::from_secs(60))),
            "signal: 9 (SIGKILL), killed after it hung"
        );
    }

    #[test]
    fn spawned_pids_are_forgotten_a_while_after_they_were_reaped() {
        use super::{Spawned, LATE_ANNOUNCEMENT};
        use std::time::{Duration, Instant};
        let t0 = Instant::now();
        let mut spawned = Spawned::default();
        spawned.started(1);
        // A day of worker incarnations, restarted and scaled.
        for pid in 100..10_100 {
            spawned.started(pid);
            spawned.reaped(pid, t0);
        }
        // Its announcement, read just after it was reaped, is not a worker joining.
        assert!(spawned.ours(5000, t0 + Duration::from_secs(1)));
        let later = t0 + LATE_ANNOUNCEMENT + Duration::from_secs(1);
        spawned.started(20_000);
        spawned.reaped(20_000, later);
        // The pid, handed by the kernel to a worker started by hand, is that worker's.
        assert!(!spawned.ours(5000, later));
        assert!(spawned.ours(1, later), "a running child stays ours");
        assert!(spawned.ours(20_000, later));
        assert_eq!(
            spawned.len(),
            2,
            "only the running and the recently reaped are kept"
        );
    }
}
