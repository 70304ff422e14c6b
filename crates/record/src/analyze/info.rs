//! The `info` summary of one recording (or of a run's joined files): whether it is complete,
//! the run and its settings, its updates and those it lacks, eval cost and λ, time per update,
//! task changes, health events, messages and metadata. It works from the [`Recording`] it is
//! given (opening its file only to see whether a writer holds it) and, for a part a restarted
//! recorder began, reads the ends of the part before; it writes no file.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use crate::{proto, Recording};

/// The update numbers missing between the first and the last of ascending `updates`, as
/// "3, 7–9" (a recovered file without its damaged chunks' updates); empty if none are.
fn gaps(updates: impl IntoIterator<Item = u64>) -> String {
    gaps_within(updates, None, None)
}

/// [`gaps`] from update `from` on (when given) and up to before `until` (when it lies beyond
/// the last update: the update a later file begins at, which the run had reached).
fn gaps_within(
    updates: impl IntoIterator<Item = u64>,
    from: Option<u64>,
    until: Option<u64>,
) -> String {
    let mut out = Vec::new();
    let mut push = |a: u64, b: u64| {
        out.push(if a == b {
            format!("{a}")
        } else {
            format!("{a}–{b}")
        })
    };
    let mut next = from;
    for u in updates {
        match next {
            Some(n) if u > n => push(n, u - 1),
            _ => {}
        }
        next = Some(next.map_or(u + 1, |n| n.max(u + 1)));
    }
    if let (Some(n), Some(until)) = (next, until) {
        if until > n {
            push(n, until - 1);
        }
    }
    out.join(", ")
}

/// The updates a run's files lack: between its first file's start and its last update, and
/// after that up to where a later file begins without an update (a part a restarted recorder
/// began just before the run stopped, when the run had got there).
pub(super) fn missing_updates(rec: &Recording) -> String {
    let from = rec.run.first().map(|r| r.update);
    let until = rec.run.iter().map(|r| r.update).max();
    gaps_within(rec.digest.points.iter().map(|u| u.update), from, until)
}

/// Why a run's files lack updates: a restarted recorder's predecessor had not written them, or
/// (with no restart logged) they were lost with the damaged part of a recovered file.
pub(super) fn why_missing(rec: &Recording) -> &'static str {
    if rec.digest.recorder_restarts > 0 {
        "not recorded: the recorder was restarted"
    } else {
        "not in the files"
    }
}

/// For the part at `path` if a restarted recorder began it: the updates between it and the
/// part before (read beside it, as `previous_part` names it), which neither holds.
pub fn missing_before_restart(path: &Path) -> Option<String> {
    let ends = crate::read_ends(path).ok()?;
    missing_before(path, &ends.metadata, ends.run?.update)
}

/// [`missing_before_restart`] of the part at `path` with metadata `meta`, beginning at update
/// `begins`.
fn missing_before(path: &Path, meta: &BTreeMap<String, String>, begins: u64) -> Option<String> {
    let restart = meta.get("recorder_restart")?;
    let name = meta.get("previous_part")?;
    let before = path.with_file_name(Path::new(name).file_name()?);
    let ends = match crate::read_ends(&before) {
        Ok(e) => e,
        Err(_) => {
            return Some(format!(
                "begins at update {begins} after a recorder restart (restart {restart}); the \
                 part before, {}, is not there to tell which updates are missing",
                before.display()
            ))
        }
    };
    // Where the part before ends: after its last update, or where it began without one.
    let end = match (&ends.last_update, &ends.run) {
        (Some(u), _) => u.update + 1,
        (None, Some(r)) => r.update,
        (None, None) => return None,
    };
    let missing = gaps_within(std::iter::empty(), Some(end), Some(begins));
    Some(format!(
        "begins at update {begins} after a recorder restart (restart {restart}); {}, after {} \
         (which ends {})",
        if missing.is_empty() {
            "no update is missing".to_string()
        } else {
            format!("missing {missing} (not recorded)")
        },
        before.display(),
        match &ends.last_update {
            Some(u) => format!("with update {}", u.update),
            None => format!("at update {end}, without one"),
        }
    ))
}

/// The task settings the recording's first update ran with, and that update: from `/run`
/// (a resumed run's or a later part's: those in force at its first update), else (a `/run`
/// without them) from the first `/update` held. The task changes listed after them say how
/// they changed; without these a reader saw the changes but not what they changed from.
fn start_settings(rec: &Recording) -> Option<(u64, &[proto::Setting])> {
    let from_run = rec
        .run_info()
        .filter(|r| !r.task_settings.is_empty())
        .map(|r| (r.update, r.task_settings.as_slice()));
    from_run.or_else(|| {
        rec.updates
            .first()
            .filter(|u| !u.task_settings.is_empty())
            .map(|u| (u.update, u.task_settings.as_slice()))
    })
}

/// [`info_for`] as `mcap-tool` prints it.
pub fn info(rec: &Recording) -> String {
    info_for(rec, "mcap-tool")
}

/// A human-readable summary of one recording. `program` is how the user calls the binary that
/// prints it (`mcap-tool`, or `pi2cma` as [`crate::program_name`] gives it): the command it
/// suggests for an unfinished file must be one the user has at hand.
pub fn info_for(rec: &Recording, program: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{} ({} bytes)", rec.path.display(), rec.file_bytes);
    match (&rec.truncated, rec.indexed) {
        (None, true) => {
            let _ = writeln!(s, "  complete, indexed");
        }
        (_, _) if crate::being_written(&rec.path) => {
            let _ = writeln!(
                s,
                "  being written (a running recorder holds it): read as far as it is written"
            );
        }
        (t, _) => {
            let _ = writeln!(
                s,
                "  NOT indexed (writer did not finish){}; `{program} recover {}` rewrites it",
                t.as_ref().map(|t| format!(": {t}")).unwrap_or_default(),
                rec.path.display()
            );
        }
    }
    if let Some(r) = rec.run_info() {
        let hp = r.hyperparameters.unwrap_or_default();
        let _ = writeln!(
            s,
            "  run {}: seed {}, executor {}, P = {}, N = {}, K = {}, {}",
            r.name,
            r.seed,
            r.executor,
            r.dim,
            r.steps,
            hp.rollouts,
            describe_hp(&hp)
        );
    }
    if let Some((update, settings)) = start_settings(rec) {
        let _ = writeln!(
            s,
            "  task settings at the start (update {update}): {}",
            tasks::settings_text(settings.iter().map(|x| (&x.name, x.value)))
        );
    }
    let points = &rec.digest.points;
    let n = points.len();
    if let (Some(first), Some(last)) = (points.first(), points.last()) {
        let best = points
            .iter()
            .min_by(|a, b| a.eval_cost.total_cmp(&b.eval_cost))
            .map(|u| (u.eval_cost, u.update))
            .unwrap_or((f64::NAN, 0));
        let missing = gaps(points.iter().map(|u| u.update));
        // λ of the distribution the last update produced: only the last update has it.
        let lambda_next = rec.updates.last().map_or(f64::NAN, |u| u.lambda_next);
        let _ = writeln!(
            s,
            "  updates: {n} ({}..={}{}), {} bytes per update",
            first.update,
            last.update,
            if missing.is_empty() {
                String::new()
            } else {
                format!("; missing {missing}")
            },
            rec.file_bytes / n as u64
        );
        let _ = writeln!(
            s,
            "  eval cost: {:.6} → {:.6} (best {:.6} at update {}); λ: {:.6} → {:.6}",
            first.eval_cost, last.eval_cost, best.0, best.1, first.lambda, lambda_next
        );
    } else {
        let begins = rec.run_info().map(|r| r.update).filter(|u| *u > 0);
        let _ = writeln!(
            s,
            "  updates: 0{}",
            begins.map_or(String::new(), |u| format!(
                " (the file begins at update {u} and holds none)"
            ))
        );
    }
    // How the run stopped, when it stopped with an update published but not recorded.
    if let Some(u) = &rec.unfinished {
        let _ = writeln!(
            s,
            "  {}",
            if u.not_begun {
                format!(
                    "stopped on request before update {} began (`supervisor stop \
                     --after-update`): no rollout lost; `--resume` goes on with it",
                    u.update
                )
            } else {
                format!(
                    "stopped in update {}: the rollouts it had run are not recorded (`--resume` \
                     runs them again)",
                    u.update
                )
            }
        );
    }
    let restart = rec
        .metadata
        .get(crate::topics::METADATA)
        .zip(rec.run_info())
        .and_then(|(meta, run)| missing_before(&rec.path, meta, run.update));
    if let Some(restart) = restart {
        let _ = writeln!(s, "  {restart}");
    }
    if let Some((a, b)) = rec.time_range {
        let _ = writeln!(s, "  time span: {:.3} s", (b - a) as f64 / 1e9);
    }
    if let Some(t) = update_times(rec) {
        let _ = writeln!(
            s,
            "  time per update (between the starts of consecutive updates' first rollouts): \
             median {:.3} ms, 90 % within {:.3} ms, slowest {:.3} ms (update {} to {})",
            t.median_ns as f64 / 1e6,
            t.p90_ns as f64 / 1e6,
            t.slowest_ns as f64 / 1e6,
            t.slowest_update,
            t.slowest_update + 1
        );
    }
    if let Some(line) = rollout_times_text(&rec.digest.worker_times.summaries()) {
        let _ = writeln!(s, "  {line}");
    }
    for c in &rec.task_changes {
        let _ = writeln!(
            s,
            "  task change before update {}: {} = {}",
            c.update,
            c.name,
            tasks::value_text(c.value)
        );
    }
    let digest = &rec.digest;
    if !digest.events.is_empty() {
        let list: Vec<String> = digest
            .events
            .iter()
            .map(|(k, v)| format!("{k} ×{v}"))
            .collect();
        let _ = writeln!(s, "  health events: {}", list.join(", "));
    }
    // Warnings and errors are what a reader of the summary must not miss (a refused task
    // change, a recomputation mismatch, a lost update); the rest are counted above.
    for l in &digest.serious {
        let _ = writeln!(
            s,
            "    {} at update {} ({}): {}",
            l.event, l.update, l.name, l.message
        );
    }
    if digest.serious_count > digest.serious.len() {
        let _ = writeln!(
            s,
            "    … and {} more (every event: the /log topic, or `--out` for log.csv)",
            digest.serious_count - digest.serious.len()
        );
    }
    if rec.run.is_empty() {
        // A run that ended before its first update: what happened is all there is.
        let _ = writeln!(
            s,
            "  no update recorded: the run ended before its first; its last events:"
        );
        for l in &digest.last_events {
            let _ = writeln!(s, "    {} {}: {}", l.event, l.name, l.message);
        }
    }
    let topics: Vec<String> = rec
        .topic_counts
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    let _ = writeln!(s, "  messages: {}", topics.join(", "));
    for (name, m) in &rec.metadata {
        let keys: Vec<String> = m
            .iter()
            .map(|(k, v)| {
                if v.contains('\n') || v.len() > 40 {
                    format!("{k} ({} lines)", v.lines().count())
                } else {
                    format!("{k}={v}")
                }
            })
            .collect();
        let _ = writeln!(s, "  metadata {name}: {}", keys.join(", "));
    }
    s
}

/// How long updates took, from the recorded rollout start times (the workers' own clocks in
/// the pipeline, the runner's in-process): the interval from the first rollout start of update u
/// to that of u + 1, for each pair of consecutive recorded updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UpdateTimes {
    pub median_ns: u64,
    /// The 90th percentile (nearest rank).
    pub p90_ns: u64,
    pub slowest_ns: u64,
    /// The update the slowest interval began at.
    pub slowest_update: u64,
}

/// [`UpdateTimes`] of a recording; `None` without two consecutive timed updates.
pub fn update_times(rec: &Recording) -> Option<UpdateTimes> {
    let mut first: Vec<(u64, u64)> = rec
        .digest
        .points
        .iter()
        .filter(|p| p.first_start_ns > 0)
        .map(|p| (p.update, p.first_start_ns))
        .collect();
    first.sort_unstable();
    first.dedup_by_key(|p| p.0);
    let mut times: Vec<(u64, u64)> = first
        .windows(2)
        .filter(|w| w[1].0 == w[0].0 + 1)
        .map(|w| (w[1].1.saturating_sub(w[0].1), w[0].0))
        .collect();
    if times.is_empty() {
        return None;
    }
    let (slowest_ns, slowest_update) = *times.iter().max()?;
    times.sort_unstable();
    let rank =
        |q: f64| times[((q * times.len() as f64).ceil() as usize).clamp(1, times.len()) - 1].0;
    Some(UpdateTimes {
        median_ns: rank(0.5),
        p90_ns: rank(0.9),
        slowest_ns,
        slowest_update,
    })
}

/// Workers listed one by one in [`rollout_times_text`]; with more, the fastest and slowest.
const ROLLOUT_TIME_WORKERS_LISTED: usize = 4;

/// The info line of how long rollouts took, per worker, from the recorded start and end times
/// (each worker's own clock). The time per update alone did not tell a robot's 0.5 s rollouts
/// on 2 workers from 1 s rollouts on 4, nor a worker whose rollouts grew slower (a robot whose
/// arm wears, a simulator on a loaded machine) from one that waited for work.
fn rollout_times_text(workers: &[crate::digest::WorkerSummary]) -> Option<String> {
    let one = |w: &crate::digest::WorkerSummary| {
        format!(
            "{} median {:.3} ms (mean {:.3} ms, {} rollout{})",
            w.worker,
            w.median,
            w.mean,
            w.count,
            if w.count == 1 { "" } else { "s" }
        )
    };
    let listed = if workers.len() <= ROLLOUT_TIME_WORKERS_LISTED {
        workers.iter().map(one).collect::<Vec<_>>().join(", ")
    } else {
        let by_median = |a: &&crate::digest::WorkerSummary, b: &&crate::digest::WorkerSummary| {
            a.median.total_cmp(&b.median)
        };
        let fastest = workers.iter().min_by(by_median)?;
        let slowest = workers.iter().max_by(by_median)?;
        format!(
            "{} workers, the fastest {}, the slowest {}",
            workers.len(),
            one(fastest),
            one(slowest)
        )
    };
    (!workers.is_empty()).then(|| {
        format!("time per rollout (its start to its end, as its worker timed it): {listed}")
    })
}

pub(super) fn describe_hp(hp: &proto::Hyperparameters) -> String {
    let mapping = match proto::CostMapping::try_from(hp.mapping) {
        Ok(proto::CostMapping::Exponential) => format!("h = {}", hp.eliteness),
        Ok(proto::CostMapping::Elites) => format!("elites = {}", hp.elites),
        _ => "mapping ?".into(),
    };
    let exploration = match proto::Exploration::try_from(hp.exploration) {
        Ok(proto::Exploration::Constant) => "constant Σ".to_string(),
        Ok(proto::Exploration::Decay) => format!("Σ decay {}", hp.decay),
        Ok(proto::Exploration::Adaptive) => {
            format!("adaptive Σ, λ ∈ [{}, {}]", hp.lambda_min, hp.lambda_max)
        }
        _ => "exploration ?".into(),
    };
    let weighting = match proto::Weighting::try_from(hp.weighting) {
        Ok(w) => w
            .as_str_name()
            .trim_start_matches("WEIGHTING_")
            .to_lowercase(),
        Err(_) => "?".into(),
    };
    let covariance = match hp.covariance_block {
        0 => String::new(),
        b => format!(", Σ per dimension ({b}×{b} blocks)"),
    };
    format!("{mapping}, {exploration}{covariance}, {weighting}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_times_come_from_the_first_rollout_starts() {
        let timed = |updates: &[(u64, u64)]| {
            let mut r = Recording::default();
            for &(u, t) in updates {
                r.digest.add_update(&proto::Update {
                    update: u,
                    ..Default::default()
                });
                for k in 0..3 {
                    r.digest.add_rollout(&proto::Rollout {
                        update: u,
                        rollout: k,
                        start_ns: 1_000_000 + t * 1000 + u64::from(2 - k),
                        ..Default::default()
                    });
                }
            }
            r
        };
        // Updates 0..=4 start at 0, 10, 30, 31, 41 µs (their first rollout; the others later);
        // update 6 follows a gap in the recording and has no interval; update 7 is untimed.
        let mut r = timed(&[(0, 0), (1, 10), (2, 30), (3, 31), (4, 41), (6, 100)]);
        r.digest.add_update(&proto::Update {
            update: 7,
            ..Default::default()
        });
        r.digest.add_rollout(&proto::Rollout {
            update: 7,
            ..Default::default()
        });
        // Intervals 10, 20, 1, 10 µs: median 10 (nearest rank 2 of 4), 90th 20, slowest 20 at 1.
        let t = update_times(&r).unwrap();
        assert_eq!(
            t,
            UpdateTimes {
                median_ns: 10_000,
                p90_ns: 20_000,
                slowest_ns: 20_000,
                slowest_update: 1
            }
        );
        assert!(info(&r)
            .contains("median 0.010 ms, 90 % within 0.020 ms, slowest 0.020 ms (update 1 to 2)"));
        assert_eq!(update_times(&timed(&[(0, 0)])), None);
    }

    #[test]
    fn info_gives_each_workers_time_per_rollout() {
        let mut r = Recording::default();
        r.digest.add_update(&proto::Update::default());
        // worker-0: 500, 502, 510 ms; worker-1: 1000 ms once.
        for (k, (worker, ms)) in [("worker-0", 500), ("worker-1", 1000), ("worker-0", 502)]
            .into_iter()
            .chain([("worker-0", 510)])
            .enumerate()
        {
            let start_ns = 1_000_000_000 * (k as u64 + 1);
            r.digest.add_rollout(&proto::Rollout {
                rollout: k as u32,
                worker: worker.into(),
                start_ns,
                end_ns: start_ns + ms * 1_000_000,
                ..Default::default()
            });
        }
        let s = info(&r);
        assert!(
            s.contains(
                "  time per rollout (its start to its end, as its worker timed it): worker-0 \
                 median 502.000 ms (mean 504.000 ms, 3 rollouts), worker-1 median 1000.000 ms \
                 (mean 1000.000 ms, 1 rollout)\n"
            ),
            "{s}"
        );
        // Past 4 workers, the fastest and the slowest.
        for (w, ms) in [(2, 200), (3, 300), (4, 400)] {
            r.digest.add_rollout(&proto::Rollout {
                worker: format!("worker-{w}"),
                start_ns: 1,
                end_ns: 1 + ms * 1_000_000,
                ..Default::default()
            });
        }
        let s = info(&r);
        assert!(
            s.contains(
                "timed it): 5 workers, the fastest worker-2 median 200.000 ms (mean 200.000 ms, \
                 1 rollout), the slowest worker-1 median 1000.000 ms"
            ),
            "{s}"
        );
        assert!(!info(&Recording::default()).contains("time per rollout"));
    }

    #[test]
    fn info_lists_warnings_and_errors_and_counts_the_rest() {
        let mut r = Recording::default();
        r.run.push(proto::RunInfo::default());
        let log = |event: &str, update: u64| proto::Log {
            event: event.into(),
            update,
            name: "workers".into(),
            message: format!("{event} {update}"),
            ..Default::default()
        };
        r.digest.add_log(&log("start", 0));
        r.digest.add_log(&log("warning", 40));
        let s = info(&r);
        assert!(s.contains("health events: start ×1, warning ×1"), "{s}");
        assert!(
            s.contains("    warning at update 40 (workers): warning 40\n"),
            "{s}"
        );
        assert!(!s.contains("start 0"), "{s}");
        for u in 0..12 {
            r.digest.add_log(&log("error", u));
        }
        let s = info(&r);
        assert!(s.contains("error at update 8 (workers)"), "{s}");
        assert!(!s.contains("error at update 9 "), "{s}");
        assert!(s.contains("    … and 3 more"), "{s}");
    }

    #[test]
    fn gaps_name_the_missing_updates() {
        assert_eq!(gaps([0, 1, 2]), "");
        assert_eq!(gaps([0, 1, 3, 4, 8, 9]), "2, 5–7");
        assert_eq!(gaps([5]), "");
        assert_eq!(gaps([]), "");
        // From the first file's start, and up to a last file that begins without an update.
        assert_eq!(gaps_within([3, 4, 5], Some(0), Some(9)), "0–2, 6–8");
        assert_eq!(gaps_within([3, 4, 5], Some(3), Some(6)), "");
        assert_eq!(gaps_within([3, 4, 5], Some(3), Some(4)), "");
        assert_eq!(gaps_within([], Some(7), Some(8)), "7");
    }

    /// A run that stopped with an update published but not recorded says how: before it began,
    /// on request, or in it (its rollouts then run again when resumed).
    #[test]
    fn the_summary_says_how_a_run_stopped_in_an_update() {
        let dir = std::env::temp_dir().join(format!("analyze-stopped-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (not_begun, expected) in [
            (
                true,
                "  stopped on request before update 7 began (`supervisor stop --after-update`): \
                 no rollout lost; `--resume` goes on with it",
            ),
            (
                false,
                "  stopped in update 7: the rollouts it had run are not recorded (`--resume` \
                 runs them again)",
            ),
        ] {
            let path = dir.join(format!("{not_begun}.mcap"));
            let mut w = crate::RunWriter::create(&path).unwrap();
            w.write_event(6, crate::Event::Start, "updater", 1, "ready")
                .unwrap();
            w.write_unfinished_update(7, &[("viapoint", 0.1)], not_begun)
                .unwrap();
            w.finish().unwrap();
            let said = info(&crate::read_recording(&path).unwrap());
            assert!(said.contains(expected), "no {expected:?} in\n{said}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The summary gives the task settings the run started with, not only the changes after
    /// (a run's first file, and a later part from what its `/run` says).
    #[test]
    fn the_summary_gives_the_task_settings_at_the_start() {
        let dir =
            std::env::temp_dir().join(format!("analyze-start-settings-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(22);
        crate::testing::record_session(&cfg, 1, &path);
        let said = info(&crate::read_recording(&path).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
        for line in [
            "  task settings at the start (update 0): viapoint = 0.3",
            "  task change before update 20: viapoint = 0.1",
        ] {
            assert!(said.contains(line), "no {line:?} in\n{said}");
        }
    }

    /// A recorder restarted just before the run stopped leaves a part without updates: the
    /// joined run's updates end where the part before ends, and those up to where the last part
    /// begins were not named as missing (nothing came after them). `info` of the part names
    /// them too, from the part before beside it.
    #[test]
    fn the_updates_before_a_part_without_updates_are_named_missing() {
        let dir = std::env::temp_dir().join(format!("analyze-gap-end-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("a.mcap");
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(10);
        crate::testing::record_session(&cfg, 1, &first);
        let part = dir.join("a.part-2.mcap");
        let hp = cfg.hyperparameters();
        let initial = pi2cma::Distribution {
            mean: nalgebra::DVector::from_vec(vec![0.5, -2.0]),
            covariance: nalgebra::DMatrix::identity(2, 2),
        };
        let mut w = crate::RunWriter::create(&part).unwrap();
        let previous = first.display().to_string();
        w.write_start(&crate::RunStart {
            name: "A1",
            seed: 1,
            update: 13,
            steps: 101,
            hyperparameters: &hp,
            initial: &initial,
            basis_activations: None,
            config_toml: "",
            executor: "pipeline",
            task_settings: &[("viapoint", 0.3)],
            previous_task_settings: &[],
            resumed_from: None,
            part: Some((2, &previous)),
            run_id: None,
            recorder_restart: Some(1),
        })
        .unwrap();
        w.finish().unwrap();

        let read = |p: &Path| crate::read_recording(p).unwrap();
        let (a, b) = (read(&first), read(&part));
        let joined = a.clone().join(b.clone());
        assert_eq!(missing_updates(&joined), "10–12");
        assert_eq!(missing_updates(&a), "");
        let said = info(&b);
        assert!(
            said.contains("updates: 0 (the file begins at update 13 and holds none)"),
            "{said}"
        );
        let expected = format!(
            "begins at update 13 after a recorder restart (restart 1); missing 10–12 (not \
             recorded), after {} (which ends with update 9)",
            first.display()
        );
        assert!(said.contains(&expected), "{said}");
        assert!(
            said.contains("  task settings at the start (update 13): viapoint = 0.3\n"),
            "{said}"
        );
        std::fs::remove_file(&first).unwrap();
        let said = info(&b);
        assert!(
            said.contains("is not there to tell which updates are missing"),
            "{said}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
