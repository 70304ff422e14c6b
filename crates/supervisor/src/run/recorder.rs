//! The recording and its recorder: what became of the recording, the RECORDER_SYNC handshake
//! and the recorder's acknowledgements, restarting a recorder that died (the recording goes on
//! in a new part, the dead one's part is recovered in the background), `supervisor record`,
//! and the malloc tuning those recoveries need. It is not the recorder process (crate `record`)
//! nor what the summary says of the recording (`summary`).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::time::{Duration, Instant};

use anyhow::bail;
use pipeline::iox;
use wire::{Control, RunNote};

use super::children::Proc;
use super::event_loop::Phase;
use super::process::{signal_group, Role};
use super::workers::may_restart;
use super::{say, Supervisor};

/// The supervisor's [`Control::RECORDER_SYNC`]s: the last number given, the one sent and not
/// yet carried out (with when it was sent), and the newest the recorder has carried out.
#[derive(Debug, Default)]
pub(super) struct RecorderSync {
    seq: u64,
    outstanding: Option<(u64, Instant)>,
    done: u64,
    /// The newest acknowledgement's `next_update`: every update before it is written.
    pub(super) written: Option<u64>,
}

/// The run's recording and what became of its recorder.
pub(super) struct Recording {
    /// As given or defaulted (printed as is).
    pub(super) path: PathBuf,
    /// The path is [`default_recording`](super::default_recording) (no `--record`).
    pub(super) defaulted: bool,
    /// `None` while the recorder runs or exited cleanly; else why the file is incomplete.
    pub(super) lost: Option<String>,
    /// When the recorder gets SIGTERM at the end of a complete run if it has not exited by
    /// itself after the final distribution.
    pub(super) term_at: Option<Instant>,
    /// When the recorder was restarted, within `pipeline.restart_window_s` (as a worker slot's).
    pub(super) restarts: VecDeque<Instant>,
    /// Restarts over the whole run.
    pub(super) restarted: u32,
    /// The part the recorder started last after a death goes on in (its restart count is
    /// `restarted`).
    pub(super) continue_in: Option<u32>,
    /// A restarted recorder the updater has not been told of yet (Control::RECORDER_BACK
    /// once it has announced itself), and how its predecessor died (put into the recording).
    pub(super) back_pending: Option<String>,
    /// The parts dead recorders left unfinished, being recovered in the background, or their
    /// recovery's outcome once it ended ([`Recording::reap_recoveries`]).
    pub(super) recovering: Vec<(PathBuf, Recovery)>,
}

/// What the summary says of a part whose recorder died before it wrote anything to it.
pub const EMPTY_PART_REMOVED: &str =
    "held nothing (its recorder died before writing its first record): removed";

/// The recovery of a part a dead recorder left.
pub(super) enum Recovery {
    Running(std::thread::JoinHandle<Result<String, String>>),
    Done(Result<String, String>),
}

impl Recovery {
    /// Its outcome, waiting for it if it still runs.
    pub(super) fn outcome(self) -> Result<String, String> {
        match self {
            Recovery::Running(h) => h
                .join()
                .unwrap_or_else(|_| Err("the recovery panicked".to_string())),
            Recovery::Done(done) => done,
        }
    }
}

impl Recording {
    /// Joins the recoveries that have ended, keeping only their outcome for the summary. A
    /// thread not joined keeps its stack mapped (2 MB and two mappings) until the run ends, so
    /// a recorder that kept dying grew the supervisor's address space without bound: +120 MB
    /// and +121 mappings after 60 restarts (+2 MB and 3 with them joined); at the kernel's
    /// 65 530 mappings no thread could be started any more.
    fn reap_recoveries(&mut self) {
        for (_, recovery) in &mut self.recovering {
            if matches!(recovery, Recovery::Running(h) if h.is_finished()) {
                let ended = std::mem::replace(recovery, Recovery::Done(Ok(String::new())));
                *recovery = Recovery::Done(ended.outcome());
            }
        }
    }

    /// The part the recorder started last after a death goes on in.
    pub(super) fn continued_part(&self) -> Option<PathBuf> {
        self.continue_in
            .map(|n| record::part_path(&record::first_part(&self.path), n))
    }
}

impl Supervisor {
    fn recorder(&self) -> Option<&Proc> {
        self.role_pid(Role::Recorder)
            .and_then(|pid| self.procs.get(&pid))
    }

    /// Whether a recorder is running and will answer a RECORDER_SYNC.
    pub(super) fn recorder_listening(&self) -> bool {
        self.recorder().is_some_and(|p| p.ready && !p.stopping)
    }

    /// The last update the recorder has written, and how many updates the updater's last
    /// report is ahead of it (none if there was no report; 0 if the recorder is ahead of the
    /// report, which comes every 200 ms).
    pub(super) fn recorder_written(&self) -> Option<(u64, Option<u64>)> {
        // `written` is never 0 (see `drain_recorder_acks`).
        let n = self.recorder_sync.written?;
        let behind = self.progress.map(|p| p.updates.saturating_sub(n));
        Some((n - 1, behind))
    }

    /// The number of a RECORDER_SYNC sent after `t`: the one not yet carried out if it was,
    /// else a new one. `None` if it could not be sent.
    pub(super) fn recorder_sync_after(&mut self, t: Instant) -> Option<u64> {
        // One sent to a recorder that has died since is never answered.
        let recorder_ready = self.recorder().and_then(|p| p.ready_at);
        if let Some((seq, at)) = self.recorder_sync.outstanding {
            if at >= t && recorder_ready.is_some_and(|r| at >= r) {
                return Some(seq);
            }
        }
        let seq = self.recorder_sync.seq + 1;
        self.send_control(Control::recorder_sync(self.run_id, seq), false)
            .ok()?;
        self.recorder_sync.seq = seq;
        self.recorder_sync.outstanding = Some((seq, Instant::now()));
        Some(seq)
    }

    /// Sends SIGTERM to the workers [`Self::stop_worker`] held back whose RECORDER_SYNC the
    /// recorder has carried out, or that waited long enough, or whose recorder is gone.
    pub(super) fn release_stops(&mut self) -> anyhow::Result<()> {
        self.drain_recorder_acks()?;
        let done = self.recorder_sync.done;
        if self
            .recorder_sync
            .outstanding
            .is_some_and(|(seq, _)| seq <= done)
        {
            self.recorder_sync.outstanding = None;
        }
        let listening = self.recorder_listening();
        let now = Instant::now();
        let mut late = Vec::new();
        for (pid, p) in &mut self.procs {
            let Some((seq, until)) = p.term_wait else {
                continue;
            };
            if seq > done && listening {
                if now < until {
                    continue;
                }
                late.push(format!("{} (pid {pid})", p.role.name()));
            }
            p.term_wait = None;
            signal_group(*pid, libc::SIGTERM);
            // The whole shutdown timeout from the SIGTERM, as without the wait.
            let grace = now + Duration::from_millis(self.pipe.shutdown_timeout_ms);
            if p.stop_by.is_some() {
                p.stop_by = Some(grace);
            }
            if self.phase == Phase::Stopping {
                self.phase_deadline = self.phase_deadline.max(Some(grace));
            }
        }
        if !late.is_empty() {
            let text = format!(
                "the recorder did not say within {} ms (half pipeline.shutdown_timeout_ms) that \
                 it is connected to {}, which are stopping now: is it stalled? What they sent \
                 since they started may be missing from the recording",
                self.pipe.shutdown_timeout_ms / 2,
                late.join(", ")
            );
            say(&format!("warning: {text}"));
            self.note(RunNote::WARNING, &text);
        }
        Ok(())
    }

    /// Takes in the recorder's acknowledgements (only the newest few are kept: each carries
    /// everything this process reads of them).
    pub(super) fn drain_recorder_acks(&mut self) -> anyhow::Result<()> {
        let Some(ports) = &self.ports else {
            return Ok(());
        };
        let sync = &mut self.recorder_sync;
        while let Some(a) = iox(ports.recorded.receive(), "receive recorder ack")? {
            let a = a.payload();
            if a.run_id == self.run_id {
                sync.done = sync.done.max(a.synced);
                // 0 comes from a recorder that has taken in no distribution yet.
                if a.next_update > 0 {
                    sync.written = sync.written.max(Some(a.next_update));
                }
            }
        }
        Ok(())
    }

    /// A restarted recorder has announced itself: the updater holds back for it again.
    pub(super) fn recorder_back(&mut self) -> anyhow::Result<()> {
        let Some(rec) = self.recording.as_mut() else {
            return Ok(());
        };
        let Some(death) = rec.back_pending.take() else {
            return Ok(());
        };
        // Not the last part there is: the new one is created with its first update.
        let part = rec
            .continued_part()
            .unwrap_or_else(|| record::last_part(&rec.path));
        self.note(RunNote::WARNING, &death);
        self.send_control(Control::plain(self.run_id, Control::RECORDER_BACK), true)?;
        say(&format!(
            "recorder restarted: recording to {}",
            part.display()
        ));
        Ok(())
    }

    /// `supervisor record`: a recorder again, after the run's died and was not restarted (it
    /// stopped at an error of its own, such as a full disk, or the restart limit was used up).
    pub(super) fn record_again(&mut self) -> Result<String, String> {
        if self.phase != Phase::Running {
            return Err("the run is not running (starting or stopping)".into());
        }
        let Some(rec) = self.recording.as_ref() else {
            return Err("this run has no recording (--no-record)".into());
        };
        if let Some(pid) = self.role_pid(Role::Recorder) {
            return Err(format!("the recorder is running (pid {pid})"));
        }
        let cause = rec.lost.clone().unwrap_or_else(|| "it exited".into());
        let (next, restart, recovery) = self
            .continue_recording(|dead| {
                format!(
                    "the recording started again (`supervisor record`) after the recorder died \
                     ({cause}); {} holds it up to where it died (recovered by the supervisor)",
                    dead.display()
                )
            })
            .map_err(|e| format!("cannot start the recorder: {e:#}"))?;
        if let Some(rec) = self.recording.as_mut() {
            rec.lost = None;
        }
        let text = format!(
            "recorder started again (restart {restart}): the recording goes on in {}, and \
             {recovery}; the updates since the recorder died are not recorded",
            next.display()
        );
        say(&text);
        Ok(text)
    }

    /// After the recorder died mid-run: unless `pipeline.restart_limit` restarts within
    /// `restart_window_s` are used up, removes the dead node's ports (the services have room for
    /// one recorder), recovers the part it left unfinished in the background, and starts a
    /// recorder that goes on in the next part. The updater, held by the lag bound meanwhile, is
    /// told once the new one has announced itself ([`Control::RECORDER_BACK`]). Returns whether
    /// it restarted.
    pub(super) fn restart_recorder(&mut self, pid: u32, cause: &str) -> anyhow::Result<bool> {
        let Some(rec) = self.recording.as_mut() else {
            return Ok(false);
        };
        let now = Instant::now();
        if !may_restart(&mut rec.restarts, &self.pipe, now) {
            say(&format!(
                "recorder not restarted: {} restarts within {} s (pipeline.restart_limit = {})",
                rec.restarts.len(),
                self.pipe.restart_window_s,
                self.pipe.restart_limit
            ));
            return Ok(false);
        }
        rec.restarts.push_back(now);
        let limit = self.pipe.restart_limit;
        let restart = rec.restarted + 1;
        let (next, restart, recovery) = self.continue_recording(|dead| {
            format!(
                "the recorder (pid {pid}) died ({cause}) and was restarted (restart {restart} \
                 of {limit}); {} holds the recording up to where it died (recovered by the \
                 supervisor)",
                dead.display()
            )
        })?;
        say(&format!(
            "WARNING: recorder (pid {pid}) died ({cause}); restart {restart} of {limit}: the \
             recording goes on in {}, and {recovery}; the updates the dead recorder had not \
             written are not recorded",
            next.display(),
        ));
        Ok(true)
    }

    /// Starts a recorder that goes on with the recording in its next part, after the one that
    /// wrote the last part died: removes the dead node's ports (the services have room for one
    /// recorder) and recovers that part in the background. `note(dead part)` is put into the new
    /// part once the recorder has announced itself ([`Self::recorder_back`]). Returns the new
    /// part, the restart count and what becomes of the dead part.
    fn continue_recording(
        &mut self,
        note: impl FnOnce(&Path) -> String,
    ) -> anyhow::Result<(PathBuf, u32, String)> {
        let Some(rec) = self.recording.as_mut() else {
            bail!("this run has no recording");
        };
        let dead = record::last_part(&rec.path);
        let part = record::part_number(&dead) + 1;
        rec.restarted += 1;
        rec.continue_in = Some(part);
        let restart = rec.restarted;
        let next = rec.continued_part().expect("continue_in is set");
        rec.back_pending = Some(note(&dead));
        rec.reap_recoveries();
        if let Some(ports) = &self.ports {
            pipeline::remove_dead_nodes(&ports._node);
        }
        // A restarted recorder that died before it created its part leaves the part its
        // predecessor left as the last one, whose recovery is under way or done: a second
        // recovery at the same time would write the same temporary file (and rename it away
        // under the first), leaving the part damaged.
        let recovering = self
            .recording
            .as_ref()
            .is_some_and(|r| r.recovering.iter().any(|(p, _)| *p == dead));
        if !recovering {
            let input = dead.clone();
            let recovery = std::thread::Builder::new()
                .name("recover".into())
                .spawn(move || {
                    // Killed between creating its part and writing its first record (a window
                    // a loaded machine widens), a recorder leaves a part that holds nothing to
                    // recover; kept, it would fail the recovery and the run (exit 3) and stop
                    // the analysis of the parts, for no update lost.
                    let outcome = if record::recover::holds_nothing(&input).unwrap_or(false) {
                        std::fs::remove_file(&input)
                            .map(|()| format!("{}: {EMPTY_PART_REMOVED}", input.display()))
                            .map_err(|e| format!("{}: cannot remove: {e}", input.display()))
                    } else {
                        record::recover::recover(&input, &input)
                            .map(|r| r.describe())
                            .map_err(|e| e.to_string())
                    };
                    release_freed_memory();
                    outcome
                })?;
            if let Some(rec) = self.recording.as_mut() {
                rec.recovering
                    .push((dead.clone(), Recovery::Running(recovery)));
            }
        }
        let recovery = if recovering {
            format!("{} is being recovered already", dead.display())
        } else {
            format!("{} is recovered in the background", dead.display())
        };
        self.spawn(Role::Recorder, restart)?;
        Ok((next, restart, recovery))
    }
}

/// Whether a recorder that died mid-run is worth restarting: unless, having announced itself,
/// it exited at an error of its own (exit status 1, after printing it), such as a full disk or an
/// I/O error, which its successor would meet too. Killed (SIGKILL, the OOM killer), crashed or
/// panicked, it is; and so is one that failed before it announced itself (a restarted one that
/// met its predecessor's ports not yet removed).
pub(super) fn recorder_restartable(status: ExitStatus, announced: bool) -> bool {
    !(announced && status.code() == Some(1))
}

/// Returns the memory a part's recovery freed to the system. glibc keeps what a thread freed
/// in that thread's malloc arena, and each recovery ran in a thread of its own: the
/// supervisor's RSS stepped up 2–3 MiB with each of the first recorder restarts and stayed
/// there (malloc_stats: 15.6 MB from the system, 1.9 MB in use).
fn release_freed_memory() {
    // SAFETY: malloc_trim only gives free pages of the arenas back (it takes each arena's
    // lock); it touches no memory in use.
    #[cfg(target_env = "gnu")]
    #[allow(unsafe_code)]
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Keeps glibc's mmap threshold at its initial 128 KiB. Freeing a block it had mapped raises
/// it (and the trim threshold, to twice that) up to 32 MiB; a recovery frees blocks of
/// megabytes, after which blocks that size came from the arenas and their freed tops were
/// kept (malloc_trim gives back the top of the main arena only). Measured over 6 recorder
/// kills: +7.5 MiB RSS with the threshold free to rise, +2.2 MiB with it fixed.
pub(super) fn fix_malloc_thresholds() {
    // SAFETY: mallopt sets a parameter of the allocator; no memory is touched.
    #[cfg(target_env = "gnu")]
    #[allow(unsafe_code)]
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recorder_is_restarted_unless_it_stopped_at_an_error_of_its_own() {
        use std::os::unix::process::ExitStatusExt as _;
        let killed = ExitStatus::from_raw(libc::SIGKILL);
        let exited = |code: i32| ExitStatus::from_raw(code << 8);
        assert!(recorder_restartable(killed, true));
        assert!(recorder_restartable(exited(101), true)); // a panic
        assert!(!recorder_restartable(exited(1), true));
        assert!(recorder_restartable(exited(1), false));
    }
}
