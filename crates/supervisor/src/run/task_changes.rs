//! `supervisor set`: a task change checked against the settings in force, sent to the updater,
//! and answered with the update it takes effect from. It is not where changes are applied (the
//! updater) nor the config's schedule of changes.

use std::time::{Duration, Instant};

use wire::{Control, Progress};

use super::event_loop::Phase;
use super::process::Role;
use super::{say, Supervisor};

/// A `supervisor set` whose reply waits for the updater's [`Progress::TASK_CHANGE`].
pub(super) struct PendingSet {
    /// Its `Control::seq`, which the updater echoes.
    pub(super) seq: u64,
    /// The setting, and `name = value`.
    pub(super) name: String,
    pub(super) what: String,
    pub(super) reply: std::sync::mpsc::Sender<Result<String, String>>,
    /// After this, the reply goes without the update index (an updater busy in a long update,
    /// or stopped, answers late or never).
    pub(super) until: Instant,
}

/// How long `supervisor set` waits for the updater to name the update of a change.
pub(super) const SET_REPLY_WAIT: Duration = Duration::from_secs(2);

impl Supervisor {
    /// The task settings a change sent now joins: the updater's last report (before the first,
    /// the settings the run started with), then the changes sent since that it does not show.
    /// Scheduled changes still ahead are not included: one is checked when the config is.
    fn settings_in_force(&self) -> Vec<(String, f64)> {
        let mut settings: Vec<(String, f64)> = match (&self.progress, &self.start) {
            (Some(p), _) => self.reported_settings(p),
            (None, Some(start)) => start.settings.clone(),
            (None, None) => Vec::new(),
        };
        settings.extend(
            self.unreflected_sets
                .iter()
                .map(|(_, n, v, _)| (n.clone(), *v)),
        );
        settings
    }

    /// A progress report's settings, by name.
    pub(super) fn reported_settings(&self, p: &Progress) -> Vec<(String, f64)> {
        let names = self
            .cfg
            .build_task()
            .map(|t| t.settings())
            .unwrap_or_default();
        named_settings(&names, p)
    }

    /// Sends a task change to the updater; returns its number, which the updater's
    /// [`Progress::TASK_CHANGE`] answer carries.
    pub(super) fn set_task(&mut self, name: &str, value: f64) -> Result<u64, String> {
        if self.phase == Phase::Stopping {
            return Err("the run is stopping".into());
        }
        self.cfg
            .check_task_change(&self.settings_in_force(), name, value)
            .map_err(|e| e.to_string())?;
        // The control service keeps no history: a change sent before the updater subscribed
        // would be lost.
        if !self.role_ready(Role::Updater) {
            return Err("the updater is not running yet: try again in a moment".into());
        }
        // A number is never reused, even when the send fails after the message went out (the
        // bell), so the updater's echo names exactly one request.
        self.task_change_seq += 1;
        let seq = self.task_change_seq;
        let msg = Control::set_task(self.run_id, seq, name, value)
            .ok_or_else(|| format!("setting name `{name}` is too long"))?;
        self.send_control(msg, true).map_err(|e| format!("{e:#}"))?;
        self.unreflected_sets
            .push((seq, name.to_string(), value, None));
        say(&format!(
            "task change {name} = {} sent to the updater",
            tasks::value_text(value)
        ));
        Ok(seq)
    }

    /// Answers the `supervisor set` requests the updater has taken (those numbered up to `taken`,
    /// the last from update `from`), and, with `flush`, all others: those it has not answered in
    /// [`SET_REPLY_WAIT`] or at all.
    pub(super) fn answer_sets(&mut self, taken: u64, from: Option<u64>, flush: bool) {
        let now = Instant::now();
        let ends_before = self.cfg.run.updates;
        // Only the workers know their own task's limits: say where a refusal would show.
        let may_refuse = if matches!(self.cfg.task, session::TaskSection::External(_)) {
            "; the workers' task may still refuse it (`supervisor status` then says so)"
        } else {
            ""
        };
        let schedule = self.cfg.schedule();
        let answered = &mut self.answered_sets;
        self.pending_sets.retain(|p| {
            let reply = match from {
                Some(u) if p.seq == taken && ends_before.is_some_and(|n| u >= n) => format!(
                    "{}: would take effect from update {u}, but the run ends after update {} \
                     (0-based): it will not take effect",
                    p.what,
                    ends_before.unwrap_or(u).saturating_sub(1)
                ),
                Some(u) if p.seq == taken => {
                    // Changes of one setting due from one update are applied in order, the
                    // schedule's first: only the last is in force for that update, and listed
                    // (the updater prints the override).
                    let replaced = answered
                        .iter()
                        .rev()
                        .find(|(name, from, _)| *name == p.name && *from == u)
                        .map(|(_, _, what)| what.clone())
                        .or_else(|| {
                            schedule.at(u).filter(|c| c.name == p.name).last().map(|c| {
                                format!(
                                    "{} = {} (schedule)",
                                    c.name,
                                    tasks::value_text(c.value)
                                )
                            })
                        })
                        .map(|what| {
                            format!(", replacing {what}, which was due from the same update")
                        })
                        .unwrap_or_default();
                    answered.push_back((p.name.clone(), u, p.what.clone()));
                    if answered.len() > 16 {
                        answered.pop_front();
                    }
                    format!(
                        "{}: takes effect from update {u} (0-based){replaced}{may_refuse}",
                        p.what
                    )
                }
                // Taken, but its answer was overtaken by a later change's.
                _ if p.seq <= taken => format!(
                    "{}: takes effect at the next update the updater starts (it prints and records the index)",
                    p.what
                ),
                _ if flush || now >= p.until => format!(
                    "{}: sent to the updater, which has not answered{}; if it takes the change, it prints and records the update it takes effect from",
                    p.what,
                    if flush {
                        " before the run stopped".to_string()
                    } else {
                        format!(" in {} s", SET_REPLY_WAIT.as_secs())
                    }
                ),
                _ => return true,
            };
            let _ = p.reply.send(Ok(reply));
            false
        });
    }
}

/// The settings of progress report `p` named by the task's `settings` (the wire carries their
/// values in the task's order).
fn named_settings(settings: &[(&str, f64)], p: &Progress) -> Vec<(String, f64)> {
    settings
        .iter()
        .zip(wire::unpack_settings(&p.settings, p.settings_len))
        .map(|((n, _), v)| (n.to_string(), *v))
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_progress_report_with_more_settings_than_it_can_hold_shows_those_it_holds() {
        use super::{named_settings, Progress};
        let names = [("viapoint", 0.0), ("t", 0.0)];
        let mut p = Progress {
            settings_len: 1,
            ..Progress::default()
        };
        p.settings[..2].copy_from_slice(&[0.25, 9.0]);
        assert_eq!(named_settings(&names, &p), [("viapoint".into(), 0.25)]);
        // A count beyond the header's array (a process of another revision, or not ours).
        p.settings_len = 9;
        assert_eq!(
            named_settings(&names, &p),
            [("viapoint".into(), 0.25), ("t".into(), 9.0)]
        );
    }
}
