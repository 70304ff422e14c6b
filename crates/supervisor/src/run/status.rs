//! What the supervisor says while a run goes on: the update rate, the progress lines, the
//! `supervisor status` text, the stall warning, and how numbers read in them. It is not the
//! summary at the end of a run (`summary`).

use std::time::{Duration, Instant};

use wire::{Progress, RunNote};

use super::event_loop::Phase;
use super::process::{stopped_in_group, Role};
use super::{say, Supervisor};

/// The update rate over the updater's last reports: updates over the time they took, the
/// reports of about the last [`UpdateRate::WINDOW_NS`] (at least two). Each report carries
/// when its last update was completed (`Progress::elapsed_ns`). Taken between the last two
/// reports only, sent at most every 200 ms, the rate of a run making 6 updates a second read
/// 5 and 10 by turns, and 1574 to 10090 where a report came a millisecond after the one
/// before (the one at each tenth of a bounded run).
#[derive(Debug, Default)]
pub(super) struct UpdateRate {
    /// (updates completed, when the last of them was, in ns since the start), oldest first.
    seen: std::collections::VecDeque<(u64, u64)>,
}

impl UpdateRate {
    const WINDOW_NS: u64 = 2_000_000_000;

    pub(super) fn is_empty(&self) -> bool {
        self.seen.is_empty()
    }

    /// A report of `updates` completed, the last at `elapsed_ns`; one with no new update
    /// says nothing of the rate.
    pub(super) fn add(&mut self, updates: u64, elapsed_ns: u64) {
        if self.seen.back().is_some_and(|&(u, _)| updates <= u) {
            return;
        }
        self.seen.push_back((updates, elapsed_ns));
        while self.seen.len() > 2 && self.seen[1].1 + Self::WINDOW_NS <= elapsed_ns {
            self.seen.pop_front();
        }
    }

    pub(super) fn rate(&self) -> Option<f64> {
        let (&(u0, t0), &(u1, t1)) = (self.seen.front()?, self.seen.back()?);
        (t1 > t0).then(|| (u1 - u0) as f64 / ((t1 - t0) as f64 * 1e-9))
    }
}

impl Supervisor {
    /// The update the run started at: 0, or where a resumed run went on.
    pub(super) fn first_update(&self) -> u64 {
        self.start.as_ref().map_or(0, |s| s.update)
    }

    /// How long a running run may go without an update before the supervisor says so: 20
    /// times the usual time per update, at least 10 s.
    pub(super) fn stall_after(&self) -> Duration {
        let usual = if self.rate > 0.0 {
            1.0 / self.rate
        } else {
            0.0
        };
        Duration::from_secs_f64((20.0 * usual).clamp(10.0, 86_400.0))
    }

    /// Since when the run has shown no progress: its last update, or a rollout of the update
    /// under way done after it.
    pub(super) fn quiet_since(&self) -> Option<Instant> {
        self.last_update_at.max(self.last_rollout_at)
    }

    /// A run without updates (nor rollouts done) for [`Self::stall_after`] is reported once (until the run goes on):
    /// a hung worker without `rollout_timeout_ms`, a stopped recorder that holds the updater
    /// (named as such when its acknowledgements lag the updates), a robot waiting for its
    /// operator. Nothing is killed; `status` shows the age as well.
    pub(super) fn check_stall(&mut self) {
        let Some(at) = self.quiet_since() else {
            return;
        };
        if self.phase != Phase::Running || self.stall_reported || at.elapsed() < self.stall_after()
        {
            return;
        }
        self.stall_reported = true;
        let timeout = match self.pipe.rollout_timeout_ms {
            Some(ms) => format!("a worker in a rollout for over {ms} ms is restarted as hung"),
            None => "pipeline.rollout_timeout_ms is not set, so a hung worker is never \
                     restarted"
                .to_string(),
        };
        let since = match self.progress {
            Some(p) if self.rate > 0.0 => format!(
                "since update {} (they came every {} before)",
                p.updates,
                interval_text(1.0 / self.rate)
            ),
            Some(p) => format!("since update {}", p.updates),
            None => "since the start".to_string(),
        };
        // The recorder's acknowledgements tell whether it is what holds the updater back.
        let _ = self.drain_recorder_acks();
        let stopped = self.stopped_processes();
        let who = match self.recorder_written() {
            Some((last, Some(n))) if n > 0 && self.recorder_listening() => format!(
                "the recorder has written only through update {last} ({n} behind the updater, \
                 which it holds back): is it stopped, or is its disk slow?"
            ),
            // Before the first update there is no usual time to compare with, and rollouts of
            // seconds (a robot's, a slow simulator's) reach 10 s in the first update alone: a
            // run of 2 s rollouts was warned of a hanging worker at its first update.
            // A process stopped by a signal (an operator's Ctrl-Z or e-stop script, SIGSTOP)
            // was warned of as "a worker may hang", and `status` listed it as running.
            _ if !stopped.is_empty() => format!(
                "stopped by a signal (SIGSTOP, Ctrl-Z), which holds the run until {} get{} \
                 SIGCONT (`kill -CONT -- -PID` resumes a process and what it started): {}",
                if stopped.len() == 1 { "it" } else { "they" },
                if stopped.len() == 1 { "s" } else { "" },
                stopped
                    .iter()
                    .map(|(name, pid)| format!("{name} (pid {pid})"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            _ if self.progress.is_none() => format!(
                "a worker may hang, or the first update's {} rollouts take that long on {} \
                 worker{} ({timeout})",
                self.cfg.optimizer.rollouts,
                self.worker_count(),
                plural(self.worker_count() as u64)
            ),
            _ => format!("a worker may hang ({timeout})"),
        };
        // Rollouts done since the last update: the update under way has stopped going on.
        let text = match (self.last_rollout_at, self.progress) {
            (Some(r), Some(p)) if self.last_update_at.is_none_or(|u| r > u) => format!(
                "no rollout done for {:.0} s (update {}: {} of {} rollouts done): {who}; \
                 `supervisor status` shows the processes",
                r.elapsed().as_secs_f64(),
                p.updates,
                p.rollouts_done,
                p.rollouts
            ),
            _ => format!(
                "no update for {:.0} s {since}: {who}; `supervisor status` shows the processes",
                at.elapsed().as_secs_f64(),
            ),
        };
        say(&format!("warning: {text}"));
        self.note(RunNote::WARNING, &text);
    }

    pub(super) fn progress_line(&self) -> String {
        // A resumed run counts from where it resumed; before its first update there is no
        // eval cost to show (the updater reports NaN).
        let first = self.first_update();
        let Some(p) = self.progress.filter(|p| p.updates > first) else {
            return "no update finished yet".into();
        };
        let of = self
            .cfg
            .run
            .updates
            .map_or("∞".to_string(), |n| n.to_string());
        // While stopping, the workers are going: their count says nothing about the run.
        let workers = if self.phase == Phase::Stopping {
            String::new()
        } else {
            let n = self.worker_count();
            format!("  {n} worker{}", plural(n as u64))
        };
        format!(
            "update {}/{of}  eval cost {}  λ now {}  {}{workers}",
            p.updates,
            reading(p.eval_cost),
            reading(p.lambda),
            rate_text(self.rate),
        )
    }

    /// `update 25 (the 26th of 40) under way: 7 of 15 rollouts done, for 12.3 s`: how far the
    /// update under way has got, which with rollouts of seconds is the only news for minutes.
    /// The update by its index, as the updater, the stop and the recording name it (the
    /// progress lines' `update 25/40` counts the updates done). None while the run is not
    /// running or its last update is done.
    pub(super) fn under_way(&self) -> Option<String> {
        let p = self.progress?;
        if self.phase != Phase::Running || p.flags & Progress::FINAL != 0 || p.rollouts == 0 {
            return None;
        }
        let of = self
            .cfg
            .run
            .updates
            .map_or(String::new(), |n| format!(" of {n}"));
        Some(format!(
            "update {} (the {}{of}) under way: {} of {} rollouts done, for {:.1} s",
            p.updates,
            ordinal(p.updates + 1),
            p.rollouts_done,
            p.rollouts,
            self.last_update_at
                .map_or(0.0, |t| t.elapsed().as_secs_f64())
        ))
    }

    /// The processes of the run (name, pid) in whose process group a signal has stopped a
    /// process (`process::stopped_in_group`).
    pub(super) fn stopped_processes(&self) -> Vec<(String, u32)> {
        self.procs
            .iter()
            .filter(|(&pid, _)| !stopped_in_group(pid).is_empty())
            .map(|(&pid, p)| (p.role.name(), pid))
            .collect()
    }

    fn worker_count(&self) -> usize {
        self.procs
            .values()
            .filter(|p| matches!(p.role, Role::Worker(_)) && !p.stopping)
            .count()
    }

    pub(super) fn status(&self) -> String {
        let mut s = format!(
            "run {} ({}), {:?} for {:.1} s{}\n",
            wire::run_id_hex(self.run_id),
            self.cfg.run.name,
            self.phase,
            self.started.elapsed().as_secs_f64(),
            if self.stop_after_update && self.phase == Phase::Running {
                "; stopping after the update under way (`supervisor stop --after-update`)"
            } else {
                ""
            }
        );
        let joined: Vec<(u32, u32)> = self.live_joined().collect();
        let stopped = self.stopped_processes();
        let stopped_workers = stopped
            .iter()
            .filter(|(_, pid)| {
                self.procs
                    .get(pid)
                    .is_some_and(|p| matches!(p.role, Role::Worker(_)) && !p.stopping)
            })
            .count();
        s += &format!(
            "workers: {} running (target {}, max {}){}{}, restarts {}\n",
            self.worker_count(),
            self.target_workers,
            self.pipe.max_workers,
            if !joined.is_empty() {
                format!(", and {} joined from outside", joined.len())
            } else {
                String::new()
            },
            match stopped_workers {
                0 => String::new(),
                n => format!(", {n} of them stopped by a signal"),
            },
            self.total_restarts
        );
        s += &match &self.recording {
            Some(r) if r.lost.is_some() => format!(
                "recording: {} (recorder died; `supervisor record` starts it again in a new part, \
                 or recover the file after the run)\n",
                record::last_part(&r.path).display()
            ),
            // A split recording: the part being written is the last that exists.
            Some(r) => {
                let restarted = match (r.restarted, r.continue_in) {
                    (0, _) => String::new(),
                    // Its part is created with the first update it records.
                    (n, Some(part)) if r.continued_part().is_some_and(|p| !p.exists()) => {
                        format!(
                            " (the recorder was restarted {n} time(s); it goes on in part {part} \
                             from the next update)"
                        )
                    }
                    (n, _) => format!(" (the recorder was restarted {n} time(s))"),
                };
                // A stalled recorder holds the updater back: this says which of the two lags.
                let written = match self.recorder_written() {
                    None => String::new(),
                    Some((last, behind)) => format!(
                        "; written through update {last}{}",
                        match behind {
                            None => String::new(),
                            Some(0) => ", up to date".to_string(),
                            Some(n) => format!(", {n} behind the updater"),
                        }
                    ),
                };
                // By its number: earlier parts may have been archived meanwhile.
                let last = record::last_part(&r.path);
                match record::part_number(&last) {
                    1 => format!("recording: {}{restarted}{written}\n", last.display()),
                    n => format!(
                        "recording: {}, part {n} of the recording begun in {}{restarted}{written}\n",
                        last.display(),
                        r.path.display()
                    ),
                }
            }
            None => "recording: off (--no-record)\n".to_string(),
        };
        for (pid, w) in &joined {
            s += &format!("  worker-{w} pid {pid} (joined; not started by the supervisor)\n");
        }
        for (pid, p) in &self.procs {
            let frozen = if stopped.iter().any(|(_, s)| s == pid) {
                format!(" (stopped by a signal: it runs nothing until `kill -CONT -- -{pid}`)")
            } else {
                String::new()
            };
            s += &format!(
                "  {} pid {pid} incarnation {}{}{}{frozen}\n",
                p.role.name(),
                p.incarnation,
                if p.ready { "" } else { " (starting)" },
                if p.stopping { " (stopping)" } else { "" }
            );
        }
        match &self.progress {
            Some(p) => {
                // Named once: it builds the task for its setting names.
                let named = self.reported_settings(p);
                let settings = task_text(&named);
                let refused = match p.refused {
                    0 => String::new(),
                    n => format!(
                        "refused by the workers' task: {n} change{} (the last: {} = {} at \
                         update {})\n",
                        plural(u64::from(n)),
                        named
                            .get(p.last_refused_setting as usize)
                            .map_or("?", |(name, _)| name.as_str()),
                        tasks::value_text(p.last_refused_value),
                        p.last_refused_update
                    ),
                };
                // The updater reports every 200 ms; the recorder acknowledges each update it
                // writes, so it can be ahead of the report, and "written through update 16" above
                // "updates: 15" read as a contradiction.
                let updates = p.updates.max(self.recorder_sync.written.unwrap_or(0));
                // The updater reports the rollouts of the run's first update too: before it is
                // done there is no rate and no last update (it read `0 updates/s, the last 2.1
                // s ago`).
                let first = self.first_update();
                let pace = if updates > first {
                    format!(
                        "{}, the last {:.1} s ago",
                        rate_text(self.rate),
                        self.last_update_at
                            .map_or(0.0, |t| t.elapsed().as_secs_f64())
                    )
                } else {
                    "none made yet".to_string()
                };
                s += &format!(
                    "updates: {} of {}, {pace}\ncurrent cost: {}\nlambda: {}\ntask: {}\n{refused}",
                    updates,
                    self.cfg
                        .run
                        .updates
                        .map_or("unbounded".to_string(), |n| n.to_string()),
                    // The evaluation cost comes with an update (NaN before the first).
                    if updates > first {
                        reading(p.eval_cost)
                    } else {
                        "none yet".to_string()
                    },
                    reading(p.lambda),
                    settings
                );
                if let Some(line) = self.under_way() {
                    s += &format!("{line}\n");
                }
            }
            None => s += "updates: 0\n",
        }
        // The rate above is that of the updates before a stall: with slow rollouts it read as
        // a run going on while the output had warned that none had come for minutes.
        if self.stall_reported {
            if let Some(at) = self.last_update_at {
                let rollout = self.last_rollout_at.filter(|&r| r > at);
                s += &format!(
                    "stalled: no update for {:.0} s{}{} (see the warning in the run's output)\n",
                    at.elapsed().as_secs_f64(),
                    if self.rate > 0.0 {
                        format!(", where they came every {}", interval_text(1.0 / self.rate))
                    } else {
                        String::new()
                    },
                    rollout.map_or(String::new(), |r| format!(
                        ", and no rollout done for {:.0} s",
                        r.elapsed().as_secs_f64()
                    ))
                );
            }
        }
        s
    }
}

/// The status's `task:` line: the settings in force, or that the task has none (a task of your
/// own may have none: the line was left blank).
fn task_text(settings: &[(String, f64)]) -> String {
    if settings.is_empty() {
        return "no settings".into();
    }
    tasks::settings_text(settings.iter().map(|(n, v)| (n, *v)))
}

/// The plural ending of a noun counted `n`: `1 worker`, `2 workers`.
pub(super) fn plural(n: u64) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// A cost or λ as people read it in the progress lines, `status` and the summary: 4 decimals,
/// in exponent form where those would say little (below 1e-3, `0.0000` for λ = 1e-60) or
/// show digits no one reads (from 1e12 on).
pub(super) fn reading(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-3..1e12).contains(&v.abs()) {
        format!("{v:.4e}")
    } else {
        format!("{v:.4}")
    }
}

/// An update rate as the progress lines, `status` and the summary show it: whole updates per
/// second from 10 on, two significant digits down to 1, and below one update a second the
/// time per update (`11 s per update`). Rollouts of seconds (a robot's, a slow simulator's)
/// make updates of tens of seconds, which `{:.0}` printed as `0 updates/s` and two digits as
/// `0.091 updates/s`, which the reader had to invert.
pub(super) fn rate_text(per_s: f64) -> String {
    if per_s > 0.0 && per_s < 1.0 {
        format!("{} s per update", two_digits_below_ten(1.0 / per_s))
    } else if per_s > 0.0 && per_s.is_finite() {
        format!("{} updates/s", two_digits_below_ten(per_s))
    } else {
        format!("{per_s:.0} updates/s")
    }
}

/// `x` (≥ 1) with one decimal below 10, two significant digits, and whole from 10 on; judged on
/// the rounded value, so that 9.96 is `10`, not `10.0`.
fn two_digits_below_ten(x: f64) -> String {
    let one_decimal = format!("{x:.1}");
    if one_decimal.parse::<f64>().is_ok_and(|r| r < 10.0) {
        one_decimal
    } else {
        format!("{x:.0}")
    }
}

/// `1st`, `2nd`, `3rd`, `4th`, …, `11th`, `21st`.
fn ordinal(n: u64) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// A time between updates as the stall warning shows it: in seconds, in milliseconds below
/// 10 ms (a run at thousands of updates per second came "every 0.000 s").
pub(super) fn interval_text(secs: f64) -> String {
    if secs >= 0.01 {
        format!("{secs:.3} s")
    } else {
        format!("{:.3} ms", secs * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ordinals_read_as_english() {
        let said: Vec<String> = [1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111, 112]
            .into_iter()
            .map(ordinal)
            .collect();
        assert_eq!(
            said,
            [
                "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st",
                "111th", "112th"
            ]
        );
    }

    #[test]
    fn the_update_rate_is_updates_over_the_time_they_took_in_the_last_seconds() {
        let ms = 1_000_000u64;
        let mut r = UpdateRate::default();
        assert_eq!(r.rate(), None);
        // A resumed run's origin, then updates every 160 ms, reported every other one.
        r.add(384, 0);
        assert_eq!(r.rate(), None);
        for n in 1..=20u64 {
            if n % 2 == 0 {
                r.add(384 + n, n * 160 * ms);
            }
        }
        assert!((r.rate().unwrap() - 6.25).abs() < 1e-9, "{:?}", r.rate());
        // The window keeps about the last 2 s: 4 workers more make updates every 80 ms.
        for n in 1..=40u64 {
            r.add(404 + n, 3200 * ms + n * 80 * ms);
        }
        assert!((r.rate().unwrap() - 12.5).abs() < 1e-9, "{:?}", r.rate());
        // A report with no new update (a task change, a stop) changes nothing.
        r.add(444, 9000 * ms);
        assert!((r.rate().unwrap() - 12.5).abs() < 1e-9, "{:?}", r.rate());
        // After a long stall, the window spans it: one update in 3 s.
        r.add(445, 3200 * ms + 40 * 80 * ms + 3000 * ms);
        assert!(r.rate().unwrap() < 1.0, "{:?}", r.rate());
    }

    #[test]
    fn costs_and_lambda_are_shown_with_4_decimals_or_in_exponent_form() {
        assert_eq!(reading(1.9999999999999998), "2.0000");
        assert_eq!(reading(22.428912381184755), "22.4289");
        assert_eq!(reading(0.0), "0.0000");
        assert_eq!(reading(1e-60), "1.0000e-60");
        assert_eq!(reading(-3.5e15), "-3.5000e15");
        assert_eq!(reading(f64::NAN), "NaN");
        assert_eq!(reading(f64::INFINITY), "inf");
    }

    #[test]
    fn a_slow_runs_update_rate_is_shown_with_two_significant_digits() {
        assert_eq!(rate_text(1191.4), "1191 updates/s");
        assert_eq!(rate_text(12.4), "12 updates/s");
        assert_eq!(rate_text(9.74), "9.7 updates/s");
        assert_eq!(rate_text(9.96), "10 updates/s");
        assert_eq!(rate_text(1.0), "1.0 updates/s");
        // Below one a second, the time per update.
        assert_eq!(rate_text(0.69), "1.4 s per update");
        // 2 s rollouts, 5 per worker: an update every 10 s (9.98 s rounds to 10, whole).
        assert_eq!(rate_text(0.1002), "10 s per update");
        assert_eq!(rate_text(0.2), "5.0 s per update");
        // A robot's episode of minutes.
        assert_eq!(rate_text(0.00123), "813 s per update");
        assert_eq!(rate_text(0.0), "0 updates/s");
    }

    #[test]
    fn the_task_line_names_the_settings_or_says_there_are_none() {
        assert_eq!(task_text(&[]), "no settings");
        let two = [("goal_x".to_string(), 0.5), ("effort".to_string(), 1.0)];
        assert_eq!(task_text(&two), "goal_x = 0.5, effort = 1");
    }

    #[test]
    fn a_stall_warning_shows_a_short_interval_in_ms() {
        assert_eq!(interval_text(0.161), "0.161 s");
        assert_eq!(interval_text(0.000118), "0.118 ms");
    }
}
