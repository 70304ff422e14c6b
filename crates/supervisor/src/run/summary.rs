//! The end of a run: removing what it leaves behind and printing the summary (the result, how
//! the run ended, the recording, its restarts and recoveries, and the commands that complete
//! and analyse it). It is not the shutdown of the processes (the event loop's stopping phase).

use std::path::{Path, PathBuf};

use anyhow::Context;
use pipeline::result::RunResult;
use session::executable_file;

use super::cleanup::remove_run;
use super::event_loop::Outcome;
use super::status::{interval_text, plural, rate_text, reading};
use super::{say, Supervisor};

impl Supervisor {
    /// Removes everything of the run and prints the summary. Returns whether a part that a
    /// restarted recorder's predecessor left is still unfinished (its recovery failed).
    pub(super) fn finish(&mut self, copy_result: Option<&Path>) -> anyhow::Result<bool> {
        let result_path = pipeline::result_path(&self.run_dir);
        let result = RunResult::read(&result_path).ok();
        // A failed copy must not skip the clean-up and the summary: the run is over either
        // way, and the summary (and the recording) still say what it gave.
        let copied = match (copy_result, result_path.exists()) {
            (Some(dest), true) => std::fs::copy(&result_path, dest)
                .map(drop)
                .with_context(|| format!("cannot copy the result to {}", dest.display())),
            _ => Ok(()),
        };
        remove_run(&self.run_dir, self.run_id);
        if let Some(r) = &result {
            let of = self
                .cfg
                .run
                .updates
                .map_or("unbounded".to_string(), |n| n.to_string());
            // A resumed run ran updates first..r.updates; the others are in the file it resumed.
            let first = self.first_update();
            let ran = r.updates.saturating_sub(first);
            let resumed = self.start.as_ref().map_or(String::new(), |s| {
                format!(" (resumed at update {first} from {})", s.origin)
            });
            say(&format!(
                "summary: run {} ({}): {} update{} of {of}{resumed} {}, {} worker{} targeted at the end, {} restart{}",
                wire::run_id_hex(self.run_id),
                r.name,
                r.updates,
                plural(r.updates),
                pace_text(ran, r.elapsed_s),
                self.target_workers,
                plural(self.target_workers as u64),
                self.total_restarts,
                plural(u64::from(self.total_restarts))
            ));
            // A run stopped before its first update has no costs to show.
            if r.updates > 0 {
                say(&format!(
                    "  evaluation cost {} → {}, final λ {}",
                    reading(r.first_eval_cost),
                    reading(r.last_eval_cost),
                    reading(r.lambda)
                ));
            }
            say(&if ran > 0 {
                format!("  final mean θ = {}", session::mean_text(&r.mean))
            } else {
                // Not a result: what the run started from.
                format!(
                    "  mean θ = {} (no update ran: {})",
                    session::mean_text(&r.mean),
                    if first > 0 {
                        "the mean it resumed from"
                    } else {
                        "the initial mean"
                    }
                )
            });
            for c in &r.task_changes {
                // A resumed run's settings were in force where it resumed; when they were set
                // is in the recording it resumed from.
                say(&if c.source == "resume" {
                    format!(
                        "  task setting {} = {} in force where the run resumed (update {})",
                        c.name,
                        tasks::value_text(c.value),
                        c.from_update
                    )
                } else {
                    format!(
                        "  task change {} = {} from update {} ({})",
                        c.name,
                        tasks::value_text(c.value),
                        c.from_update,
                        c.source
                    )
                });
            }
            for c in &r.refused_changes {
                say(&format!(
                    "  task change {} = {} at update {} ({}) refused by the workers' task: not \
                     taken",
                    c.name,
                    tasks::value_text(c.value),
                    c.from_update,
                    c.source
                ));
            }
            if r.nonfinite_reruns > 0 {
                say(&format!(
                    "  {} rollout execution(s) with non-finite costs run again \
                     (run.nonfinite_reruns = {})",
                    r.nonfinite_reruns, self.cfg.run.nonfinite_reruns
                ));
            }
        }
        match &self.outcome {
            Some(Outcome::Complete) => say("finished"),
            // The update under way was the run's last: it ended as it would have.
            Some(Outcome::Stopped)
                if self.stop_after_update && result.as_ref().is_some_and(|r| r.complete) =>
            {
                say("finished (the update under way at `supervisor stop --after-update` was the run's last)")
            }
            Some(Outcome::Stopped) if self.stop_after_update => {
                let updates = result.as_ref().map_or(0, |r| r.updates);
                let last = match updates.checked_sub(1) {
                    Some(last) => format!("after update {last}"),
                    None => "before its first update".into(),
                };
                let go_on = match &self.recording {
                    Some(rec) => format!(
                        "`supervisor run --resume {}` goes on with update {updates}",
                        rec.path.display()
                    ),
                    None => "run without a recording, it cannot be resumed".into(),
                };
                say(&format!(
                    "stopped on request {last} (`supervisor stop --after-update`): no rollout \
                     was thrown away; {go_on}"
                ));
            }
            Some(Outcome::Stopped) => say("stopped on request"),
            Some(Outcome::Interrupted(signal)) => say(&format!("interrupted ({signal})")),
            Some(Outcome::Failed(reason)) => say(&format!("failed: {reason}")),
            None => {}
        }
        let recoveries: Vec<(PathBuf, Result<String, String>)> = self
            .recording
            .as_mut()
            .map(|r| std::mem::take(&mut r.recovering))
            .unwrap_or_default()
            .into_iter()
            .map(|(part, recovery)| (part, recovery.outcome()))
            .collect();
        let mut unfinished = false;
        // Any part, not the first: a long run's first parts may have been archived meanwhile,
        // and then what became of the recording (a part left unfinished above all) went
        // unsaid.
        if let Some(rec) = self
            .recording
            .as_ref()
            .filter(|r| record::last_part(&r.path).exists())
        {
            let path = record::describe_parts(&rec.path);
            // A resumed run's analysis joins the recordings it continues (the one it resumed,
            // the one that one resumed, …), for the whole curve.
            let (earlier, left_out) = self
                .start
                .as_ref()
                .map(|s| record::resumed_chain(Path::new(&s.origin)))
                .unwrap_or_default();
            let (pi2cma, how_to_build) = pi2cma_program();
            let analyse = format!(
                "{} --out {}{how_to_build}",
                record::analyze_command(&pi2cma, &rec.path, &earlier),
                analysis_out(&rec.path).display()
            );
            let place = if rec.defaulted {
                " (the default place: runs/<run name>-<run id>.mcap in the current directory; \
                 --record FILE to choose)"
            } else {
                ""
            };
            match &rec.lost {
                None => {
                    say(&format!("recording: {path}{place}"));
                    say(&format!("  analyse it with: {analyse}"));
                }
                Some(cause) => {
                    // Only the last part can be unfinished; the others were finished as they
                    // filled.
                    let last = record::last_part(&rec.path);
                    let last = last.display();
                    say(&format!(
                        "recording: {path}{place}: {last} is NOT finished (the recorder died: {cause})"
                    ));
                    say(&format!(
                        "  complete it with: {pi2cma} recover {last}   (or: mcap-tool recover {last})"
                    ));
                    say(&format!("  then analyse it with: {analyse}"));
                }
            }
            if let Some(note) = left_out {
                say(&format!("  NOTE: {note}"));
            }
            if rec.restarted > 0 {
                // Read after the recoveries ended: a part before a restart is complete then.
                let gaps: Vec<(PathBuf, String)> = record::recording_parts(&rec.path)
                    .into_iter()
                    .filter_map(|part| {
                        record::analyze::missing_before_restart(&part).map(|gap| (part, gap))
                    })
                    .collect();
                for line in restart_lines(rec.restarted, &gaps) {
                    say(&line);
                }
            }
            for (part, done) in &recoveries {
                match done {
                    Ok(report) => say(&format!("  {report}")),
                    Err(e) => {
                        unfinished = true;
                        let part = part.display();
                        say(&format!(
                            "  {part} is NOT finished (its recorder died, and recovering it \
                             failed: {e}); complete it with: {pi2cma} recover {part}"
                        ));
                    }
                }
            }
        }
        copied.map(|()| unfinished)
    }
}

/// The summary's lines on a recording whose recorder was restarted `restarted` times: the
/// updates missing before each part a restart began (`gaps`: the part and what it says).
fn restart_lines(restarted: u32, gaps: &[(PathBuf, String)]) -> Vec<String> {
    let heading = format!(
        "  the recorder died and was restarted {restarted} time(s); each restart began a new \
         part, and the updates a dead recorder had not written are missing"
    );
    // Parts may be archived while the run goes on, those a restart began too: a heading
    // followed by nothing read as if the list had been lost. A restarted recorder that got no
    // update before the run ended began no part.
    let why = "moved away or deleted during the run, or never begun: the run ended before the \
               restarted recorder's first update";
    if gaps.is_empty() {
        return vec![format!(
            "{heading}; the parts that said which are not there ({why})"
        )];
    }
    let mut lines = vec![format!("{heading}:")];
    for (part, gap) in gaps {
        lines.push(format!("    {}: {gap}", part.display()));
    }
    let gone = (restarted as usize).saturating_sub(gaps.len());
    if gone > 0 {
        lines.push(format!(
            "    ({gone} of the {restarted} parts the restarts began are not there: {why})"
        ));
    }
    lines
}

/// How a printed command calls `pi2cma`: the binary beside this one (cargo builds both into one
/// directory), relative to the working directory when under it, so that the command works as
/// printed; else by name, with how to build it (the quick start builds only the supervisor).
pub(super) fn pi2cma_program() -> (String, &'static str) {
    let beside = std::env::current_exe()
        .ok()
        .and_then(|exe| Some(exe.parent()?.join("pi2cma")))
        .filter(|p| executable_file(p));
    match beside {
        Some(path) => (record::program_name(&path), ""),
        None => (
            "pi2cma".into(),
            "   (pi2cma: `cargo build --release -p pi2cma-cli` in the pi2cma repository)",
        ),
    }
}

/// The `--out` of the printed analysis command: the recording's directory, since `analyze`
/// writes a run's CSV files and figures into `OUT/<file stem>/` (`runs/A1-<id>.mcap` →
/// `runs/A1-<id>/`, beside the recording).
fn analysis_out(recording: &Path) -> &Path {
    match recording.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    }
}

/// How long the run's own updates took and at what rate; a run that ran none (stopped, or
/// failed, before its first) says so: "in 0.000 ms (0 updates/s)" read as a measurement.
fn pace_text(ran: u64, elapsed_s: f64) -> String {
    if ran == 0 {
        return "(none ran)".into();
    }
    format!(
        // The quick start's 40 updates take ~5 ms: "0.00 s" said nothing.
        "in {} ({})",
        interval_text(elapsed_s),
        rate_text(ran as f64 / elapsed_s.max(1e-9))
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parts restarts began say which updates are missing; with none of them left (moved
    /// away or deleted during the run), the heading was followed by nothing.
    #[test]
    fn the_restarts_missing_updates_are_listed_or_said_to_be_unknown() {
        let gap = (
            PathBuf::from("day.part-4.mcap"),
            "begins at update 40 after a recorder restart (restart 1); missing 38..=39".into(),
        );
        let lines = restart_lines(1, std::slice::from_ref(&gap));
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(lines[0].ends_with("are missing:"), "{lines:?}");
        assert!(
            lines[1].starts_with("    day.part-4.mcap: begins at update 40"),
            "{lines:?}"
        );

        let lines = restart_lines(2, &[]);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(!lines[0].ends_with(':'), "{lines:?}");
        assert!(lines[0].contains("are not there (moved away"), "{lines:?}");

        // One of two restarts' parts gone: what is there is listed, and the other said.
        let lines = restart_lines(2, &[gap]);
        assert!(lines[0].ends_with("are missing:"), "{lines:?}");
        assert!(lines[2].contains("1 of the 2 parts"), "{lines:?}");
    }

    #[test]
    fn a_run_that_ran_no_update_says_so_instead_of_a_rate() {
        assert_eq!(pace_text(0, 0.0), "(none ran)");
        assert_eq!(pace_text(40, 0.004173), "in 4.173 ms (9585 updates/s)");
        assert_eq!(pace_text(3, 30.0), "in 30.000 s (10 s per update)");
    }

    #[test]
    fn the_analysis_goes_beside_the_recording() {
        assert_eq!(
            analysis_out(Path::new("runs/A1-00ab.mcap")),
            Path::new("runs")
        );
        assert_eq!(analysis_out(Path::new("day1.mcap")), Path::new("."));
        assert_eq!(analysis_out(Path::new("/d/x.mcap")), Path::new("/d"));
    }
}
