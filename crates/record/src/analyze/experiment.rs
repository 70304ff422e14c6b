//! Over the sessions of an experiment ([`experiment`]): the sessions grouped by run and
//! settings, the mean eval-cost curve ± std and mean λ over the updates every session of a
//! group has, and the re-convergence table per segment between task changes
//! ([`reconvergence`]). It takes the runs already joined (`runs`); it reads no file.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::csv::{csv_field, f, Csv};
use super::figures::{draw_curves, perr, Curve, Values};
use super::info::describe_hp;
use super::io;
use super::runs::same_curve;
use crate::{RecordError, Recording, UpdatePoint};

/// Re-convergence of one segment of one session.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// First update of the segment (0, or the update a task change applies from).
    pub start: u64,
    /// One past the last update of the segment.
    pub end: u64,
    /// The highest eval cost within the segment (after the task change, the jump).
    pub peak: f64,
    /// Final level: the lowest eval cost within the segment.
    pub level: f64,
    /// First update from which every eval cost of the segment stays within the tolerance band;
    /// `None` if the segment has not settled: its last eval cost is outside the band, or only
    /// the last one is inside (a curve still falling at the end has its lowest value last).
    pub converged_at: Option<u64>,
}

impl Segment {
    /// Updates from the segment's start until it converged (`converged_at − start`), if it did.
    pub fn updates_to_converge(&self) -> Option<u64> {
        self.converged_at.map(|u| u - self.start)
    }
}

/// Splits the eval-cost curve at the task changes and finds, per segment, where it settles:
/// with L the segment's lowest eval cost and H its highest, the first update from which every
/// eval cost of the segment is ≤ L + tolerance·(H − L), provided that is at least the last two
/// updates; otherwise the segment has not settled.
pub fn reconvergence(rec: &Recording, tolerance: f64) -> Vec<Segment> {
    let points = &rec.digest.points;
    let Some(last) = points.last().map(|s| s.update + 1) else {
        return Vec::new();
    };
    let first = points.first().map(|s| s.update).unwrap_or(0);
    let mut bounds: Vec<u64> = std::iter::once(first)
        .chain(rec.task_changes.iter().map(|c| c.update))
        .filter(|u| *u >= first && *u < last)
        .collect();
    bounds.sort_unstable();
    bounds.dedup();
    bounds.push(last);
    // Each segment's updates in file order, in one pass (a continual run has many segments).
    let mut segments: Vec<Vec<&UpdatePoint>> = vec![Vec::new(); bounds.len() - 1];
    for p in points {
        let i = bounds.partition_point(|b| *b <= p.update);
        if let Some(seg) = i.checked_sub(1).and_then(|i| segments.get_mut(i)) {
            seg.push(p);
        }
    }
    let mut out = Vec::new();
    for (w, seg) in bounds.windows(2).zip(segments) {
        let (s, e) = (w[0], w[1]);
        if seg.is_empty() {
            continue;
        }
        let level = seg
            .iter()
            .map(|c| c.eval_cost)
            .fold(f64::INFINITY, f64::min);
        let peak = seg
            .iter()
            .map(|c| c.eval_cost)
            .fold(f64::NEG_INFINITY, f64::max);
        let threshold = level + tolerance * (peak - level);
        let inside = seg
            .iter()
            .rev()
            .take_while(|c| c.eval_cost <= threshold)
            .count();
        let converged_at = (inside >= 2).then(|| seg[seg.len() - inside].update);
        out.push(Segment {
            start: s,
            end: e,
            peak,
            level,
            converged_at,
        });
    }
    out
}

/// What [`experiment`] computed and wrote.
#[derive(Debug, Clone, Default)]
pub struct ExperimentReport {
    /// Markdown: mean curves summary and the re-convergence table.
    pub table: String,
    /// The files written (CSV, SVG, Markdown), when given an output directory.
    pub files: Vec<PathBuf>,
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n.max(1.0);
    let s = if v.len() > 1 {
        (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (m, s)
}

/// The task a run's config names (`[task.<kind>]`), if its recording has the config.
fn task_of(r: &Recording) -> Option<String> {
    let config: toml::Table = r.run_info()?.config_toml.parse().ok()?;
    let task = config.get("task")?.as_table()?;
    task.keys().next().cloned()
}

/// The eval cost over sessions (mean, sample std) and their mean λ at one update.
struct Common {
    update: u64,
    mean: f64,
    std: f64,
    lambda: f64,
}

/// [`Common`] at each update every one of `sessions` has, ascending, in one walk over their
/// curves (each in update order; a copy is sorted if one is not).
fn common_updates(sessions: &[&Recording]) -> Vec<Common> {
    let sorted: Vec<std::borrow::Cow<'_, [UpdatePoint]>> = sessions
        .iter()
        .map(|r| {
            let p = &r.digest.points;
            if p.is_sorted_by_key(|p| p.update) {
                std::borrow::Cow::Borrowed(p.as_slice())
            } else {
                let mut p = p.clone();
                p.sort_by_key(|p| p.update);
                std::borrow::Cow::Owned(p)
            }
        })
        .collect();
    let Some((lead, others)) = sorted.split_first() else {
        return Vec::new();
    };
    let mut at = vec![0usize; others.len()];
    let mut out = Vec::new();
    let (mut costs, mut lambdas) = (Vec::new(), Vec::new());
    for (i, p) in lead.iter().enumerate() {
        if i > 0 && lead[i - 1].update == p.update {
            continue;
        }
        costs.clear();
        lambdas.clear();
        costs.push(p.eval_cost);
        lambdas.push(p.lambda);
        for (o, a) in others.iter().zip(&mut at) {
            while o.get(*a).is_some_and(|q| q.update < p.update) {
                *a += 1;
            }
            match o.get(*a) {
                Some(q) if q.update == p.update => {
                    costs.push(q.eval_cost);
                    lambdas.push(q.lambda);
                }
                _ => break,
            }
        }
        if costs.len() == sessions.len() {
            let (mean, std) = mean_std(&costs);
            out.push(Common {
                update: p.update,
                mean,
                std,
                lambda: mean_std(&lambdas).0,
            });
        }
    }
    out
}

/// The sessions of an experiment, grouped: by run name, and within a name by what makes runs
/// comparable (hyperparameters, P, N), so that runs of one name with different settings (e.g.
/// `pi2cma experiment --weighting`) are not averaged together. A recording given twice, or a
/// copy of one (same seed and the same eval costs to the bit), counts once, with a note.
fn group_sessions<'a>(
    recs: &'a [Recording],
    notes: &mut Vec<String>,
) -> Vec<(String, Vec<&'a Recording>)> {
    type Key = (String, String, u32, u32);
    let key = |r: &Recording| -> Key {
        let info = r.run_info();
        (
            r.name(),
            info.and_then(|i| i.hyperparameters.as_ref())
                .map(describe_hp)
                .unwrap_or_default(),
            info.map_or(0, |i| i.dim),
            info.map_or(0, |i| i.steps),
        )
    };
    let mut groups: BTreeMap<Key, Vec<&Recording>> = BTreeMap::new();
    for r in recs {
        let Some(info) = r.run_info().filter(|_| !r.digest.points.is_empty()) else {
            notes.push(format!(
                "{} has no recorded update (the run ended before its first): not a session",
                r.path.display()
            ));
            continue;
        };
        // A session's identity for spotting copies: its seed and eval costs, to the bit.
        let members = groups.entry(key(r)).or_default();
        match members
            .iter()
            .find(|m| m.run_info().map(|i| i.seed) == Some(info.seed) && same_curve(m, r))
        {
            Some(m) => notes.push(format!(
                "{} is the same run as {} (same seed, same eval costs): counted once",
                r.path.display(),
                m.path.display()
            )),
            None => members.push(r),
        }
    }
    // A name shared by groups gets what tells them apart.
    let mut per_name: BTreeMap<&str, usize> = BTreeMap::new();
    let mut per_settings: BTreeMap<(&str, &str), usize> = BTreeMap::new();
    for k in groups.keys() {
        *per_name.entry(k.0.as_str()).or_default() += 1;
        *per_settings
            .entry((k.0.as_str(), k.1.as_str()))
            .or_default() += 1;
    }
    let labels: Vec<String> = groups
        .keys()
        .map(|(name, hp, dim, steps)| {
            match (
                per_name[name.as_str()],
                per_settings[&(name.as_str(), hp.as_str())],
            ) {
                (1, _) => name.clone(),
                (_, 1) => format!("{name} ({hp})"),
                _ => format!("{name} ({hp}, P = {dim}, N = {steps})"),
            }
        })
        .collect();
    labels.into_iter().zip(groups.into_values()).collect()
}

/// What begins the re-convergence table's segment at `start`: a task change, or a recording
/// that begins there (a run resumed from a file not given, the later part of a split recording
/// given alone), whose segment is not one the task's change began.
fn segment_label(sessions: &[&Recording], start: u64) -> &'static str {
    if start == 0 {
        // The run's start, also when a schedule changes the task from update 0 on.
        ""
    } else if sessions
        .iter()
        .any(|r| r.task_changes.iter().any(|c| c.update == start))
    {
        " (task change)"
    } else {
        " (first recorded update)"
    }
}

/// Over the sessions of an experiment (grouped as `group_sessions` says): the mean eval-cost
/// curve ± std over sessions and mean λ per update (`mean_curves.svg`, `mean_curves.csv`) over
/// the updates every session of the group has, and the re-convergence table
/// (`reconvergence.md`, `reconvergence.csv`; also returned as Markdown). Into `out` if given:
/// the SVG with `figures`, the two CSV files with `csv`.
pub fn experiment(
    recs: &[Recording],
    out: Option<&Path>,
    tolerance: f64,
    figures: bool,
    csv: bool,
) -> Result<ExperimentReport, RecordError> {
    let mut notes = Vec::new();
    let groups = group_sessions(recs, &mut notes);
    let mut report = ExperimentReport::default();
    let mut curves = Vec::new();
    // Streamed to the file: it has a row per update.
    let mut mean_csv = match out.filter(|_| csv) {
        Some(dir) => {
            std::fs::create_dir_all(dir).map_err(io(dir))?;
            let header = [
                "run",
                "update",
                "sessions",
                "eval_cost_mean",
                "eval_cost_std",
                "lambda_mean",
            ];
            Some(Csv::new(dir, "mean_curves.csv", &header.map(String::from))?)
        }
        None => None,
    };
    let mut reconv_csv = String::from(
        "run,file,segment_start,segment_end,peak,level,converged_at,updates_to_converge\n",
    );
    let mut rows = String::new();
    for (name, sessions) in &groups {
        // Mean curve over the updates every session has: where fewer sessions contribute, the
        // mean would silently become that of fewer runs.
        let common = common_updates(sessions);
        let distinct = |r: &Recording| {
            let mut u: Vec<u64> = r.digest.points.iter().map(|p| p.update).collect();
            u.sort_unstable();
            u.dedup();
            u.len()
        };
        if sessions.iter().any(|r| distinct(r) > common.len()) {
            let lengths: Vec<usize> = sessions.iter().map(|r| r.digest.points.len()).collect();
            notes.push(format!(
                "{name}: its sessions have {}–{} updates; the mean curve and the eval costs at the \
                 segments' ends are over the {} updates every session has",
                lengths.iter().min().unwrap_or(&0),
                lengths.iter().max().unwrap_or(&0),
                common.len()
            ));
        }
        if let Some(csv) = mean_csv.as_mut() {
            for c in &common {
                csv.row(vec![
                    csv_field(name),
                    c.update.to_string(),
                    sessions.len().to_string(),
                    f(c.mean),
                    f(c.std),
                    f(c.lambda),
                ]);
            }
        }
        let column = |v: fn(&Common) -> f64| common.iter().map(v).collect::<Vec<f64>>();
        let task = sessions
            .first()
            .and_then(|r| task_of(r))
            .unwrap_or_default();
        curves.push((
            task,
            Curve::new(
                format!("{name} ({} sessions)", sessions.len()),
                Values {
                    x: &column(|c| c.update as f64),
                    y: &column(|c| c.mean),
                    band: Some(&column(|c| c.std)),
                    lambda: Some(&column(|c| c.lambda)),
                },
            ),
        ));

        // Re-convergence per session and segment.
        let mut per_segment: BTreeMap<u64, Vec<&Segment>> = BTreeMap::new();
        let segs: Vec<(PathBuf, Vec<Segment>)> = sessions
            .iter()
            .map(|r| (r.path.clone(), reconvergence(r, tolerance)))
            .collect();
        let or_empty = |v: Option<u64>| v.map(|v| v.to_string()).unwrap_or_default();
        for (path, ss) in &segs {
            for s in ss {
                let _ = writeln!(
                    reconv_csv,
                    "{},{},{},{},{},{},{},{}",
                    csv_field(name),
                    csv_field(&path.display().to_string()),
                    s.start,
                    s.end,
                    f(s.peak),
                    f(s.level),
                    or_empty(s.converged_at),
                    or_empty(s.updates_to_converge())
                );
                per_segment.entry(s.start).or_default().push(s);
            }
        }
        for (start, ss) in &per_segment {
            // Where the segment ended up: its last update every session has. (The run's final
            // cost on every row said nothing of how a segment before a task change ended.)
            let end = ss.iter().map(|s| s.end).min().unwrap_or(*start);
            let (fm, fs) = common[..common.partition_point(|c| c.update < end)]
                .last()
                .filter(|c| c.update >= *start)
                .map_or((f64::NAN, f64::NAN), |c| (c.mean, c.std));
            let n: Vec<f64> = ss
                .iter()
                .filter_map(|s| s.updates_to_converge())
                .map(|n| n as f64)
                .collect();
            let at: Vec<f64> = ss
                .iter()
                .filter_map(|s| s.converged_at)
                .map(|u| u as f64)
                .collect();
            let (to_converge, converged_at) = if n.is_empty() {
                ("–".to_string(), "–".to_string())
            } else {
                let (m, sd) = mean_std(&n);
                (
                    format!("{m:.1} ± {sd:.1}"),
                    format!("{:.1}", mean_std(&at).0),
                )
            };
            let _ = writeln!(
                rows,
                "| {name} | {start}{} | {} | {} of {} | {to_converge} | {converged_at} | {fm:.4} ± {fs:.4} |",
                segment_label(sessions, *start),
                ss.len(),
                n.len(),
                ss.len()
            );
        }
    }
    // One figure per task: a via-point cost of hundreds and a T-ball cost of a few on one axis
    // flattened the one into the other (and a λ of 2000 beside one of 0.02).
    let mut tasks: Vec<(String, Vec<Curve>)> = Vec::new();
    for (task, c) in curves {
        match tasks.iter_mut().find(|(t, _)| *t == task) {
            Some((_, cs)) => cs.push(c),
            None => tasks.push((task, vec![c])),
        }
    }
    let one_task = tasks.len() <= 1;
    let figure_name = |task: &str| {
        if one_task {
            "mean_curves.svg".to_string()
        } else {
            format!(
                "mean_curves-{}.svg",
                if task.is_empty() { "unknown" } else { task }
            )
        }
    };
    // Mean curves without a point (no session with an update, or sessions without a common
    // update) are empty axes: not drawn.
    let drawable = |cs: &[Curve]| cs.iter().any(|c| !c.pieces.is_empty());
    if figures && out.is_some() {
        if tasks.iter().all(|(_, cs)| !drawable(cs)) {
            notes.push(
                "mean_curves.svg not drawn: no update every session of a run has, nothing to plot"
                    .to_string(),
            );
        }
        if !one_task {
            let names: Vec<String> = tasks.iter().map(|(t, _)| figure_name(t)).collect();
            notes.push(format!(
                "the runs are of {} tasks: their mean curves are drawn per task, in {}",
                tasks.len(),
                names.join(", ")
            ));
        }
    }
    let t = &mut report.table;
    let _ = writeln!(
        t,
        "## Experiment: {} sessions in {} run(s)\n",
        groups.iter().map(|(_, s)| s.len()).sum::<usize>(),
        groups.len()
    );
    for n in &notes {
        let _ = writeln!(t, "note: {n}\n");
    }
    let _ = writeln!(
        t,
        "Re-convergence (tolerance {tolerance}): updates from the segment start until every later \
         eval cost of the segment is within tolerance × (peak − lowest) of the lowest; a segment \
         whose last eval cost is outside that band, or whose band holds for its last update \
         only, has not converged (\"–\"). Means are over the sessions that converged. \
         Converged means levelled off, at whatever cost: whether that is the task's optimum, the \
         last column says (decaying exploration levels off far above it).\n"
    );
    let _ = writeln!(t, "| run | segment from update | sessions | converged | updates to converge (mean ± std) | converged at (mean) | eval cost at the segment's end (mean ± std) |");
    let _ = writeln!(t, "|---|---|---|---|---|---|---|");
    t.push_str(&rows);
    // The task changes of the runs of `task` (of every run given, for one task).
    let changes = |task: &str| {
        let mut c: Vec<u64> = recs
            .iter()
            .filter(|r| one_task || task_of(r).unwrap_or_default() == task)
            .flat_map(|r| r.task_changes.iter().map(|c| c.update))
            .collect();
        c.sort_unstable();
        c.dedup();
        c
    };
    if let Some(dir) = out {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        // `--no-csv` holds for the experiment's CSV files too; its table stays, as Markdown.
        if let Some(mean) = mean_csv {
            report.files.push(mean.write()?);
            let p = dir.join("reconvergence.csv");
            std::fs::write(&p, &reconv_csv).map_err(io(&p))?;
            report.files.push(p);
        }
        let p = dir.join("reconvergence.md");
        std::fs::write(&p, &report.table).map_err(io(&p))?;
        report.files.push(p);
        for (task, cs) in tasks.iter().filter(|(_, cs)| figures && drawable(cs)) {
            let p = dir.join(figure_name(task));
            let title = if one_task {
                "eval cost: mean ± std over sessions".to_string()
            } else {
                format!("{task}: eval cost, mean ± std over sessions")
            };
            {
                let root = SVGBackend::new(&p, (900, 650)).into_drawing_area();
                draw_curves(&root, &title, cs, &changes(task), "eval cost")
                    .map_err(perr(&p, "mean_curves"))?;
            }
            report.files.push(p);
        }
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::test_support::rec_with;
    use crate::proto;

    /// A session whose recording begins at update 25 (resumed from a file not given) has a
    /// segment from 25, which no task change began.
    #[test]
    fn a_segment_is_said_to_begin_at_a_task_change_only_where_one_is() {
        let whole = rec_with(&[5.0, 4.0, 3.0, 3.0, 9.0, 6.0, 4.0, 4.0], Some(4));
        let mut late = rec_with(&[5.0, 4.0, 3.0, 3.0, 9.0, 6.0, 4.0, 4.0], Some(4));
        late.digest.points.retain(|s| s.update >= 6);
        assert_eq!(segment_label(&[&whole], 0), "");
        assert_eq!(segment_label(&[&whole], 4), " (task change)");
        assert_eq!(segment_label(&[&late], 6), " (first recorded update)");
        let from_the_start = rec_with(&[5.0, 4.0], Some(0));
        assert_eq!(segment_label(&[&from_the_start], 0), "");
        let info = |seed| proto::RunInfo {
            name: "A1".into(),
            seed,
            ..Default::default()
        };
        let (mut whole, mut late) = (whole, late);
        whole.run.push(info(1));
        late.run.push(info(2));
        let report = experiment(&[whole, late], None, 0.05, false, false).unwrap();
        assert!(
            report.table.contains("| A1 | 4 (task change) | 1 |"),
            "{}",
            report.table
        );
        assert!(
            report
                .table
                .contains("| A1 | 6 (first recorded update) | 1 |"),
            "{}",
            report.table
        );
    }

    #[test]
    fn reconvergence_hand_checked() {
        // Segment 0..4: peak 100, level 1, band 1 + 0.05·99 = 5.95 → settled from update 2.
        // Segment 4..8: peak 50 at 4, level 2, band 4.4 → 3.0 at 6 is within, 10 at 5 is not.
        let r = rec_with(&[100.0, 30.0, 5.0, 1.0, 50.0, 10.0, 3.0, 2.0], Some(4));
        let s = reconvergence(&r, 0.05);
        assert_eq!(s.len(), 2);
        assert_eq!((s[0].start, s[0].end, s[0].converged_at), (0, 4, Some(2)));
        assert_eq!(
            (s[1].start, s[1].converged_at, s[1].updates_to_converge()),
            (4, Some(6), Some(2))
        );
        assert_eq!(s[1].peak, 50.0);
        assert_eq!(s[1].level, 2.0);
    }

    fn session(name: &str, seed: u64, eliteness: f64, costs: &[f64]) -> Recording {
        let mut r = rec_with(costs, None);
        r.path = PathBuf::from(format!("{name}-{seed}-{eliteness}.mcap"));
        r.run.push(proto::RunInfo {
            name: name.into(),
            seed,
            hyperparameters: Some(proto::Hyperparameters {
                eliteness,
                mapping: proto::CostMapping::Exponential as i32,
                ..Default::default()
            }),
            ..Default::default()
        });
        r
    }

    #[test]
    fn sessions_are_grouped_by_settings_and_counted_once() {
        let recs = [
            session("A1", 1, 10.0, &[4.0, 2.0, 1.0]),
            session("A1", 2, 10.0, &[6.0, 4.0, 3.0, 0.0]),
            session("A1", 1, 10.0, &[4.0, 2.0, 1.0]), // a copy of the first
            session("A1", 1, 20.0, &[8.0, 8.0, 8.0]), // other settings, same name
        ];
        let r = experiment(&recs, None, 0.05, false, false).unwrap();
        let t = &r.table;
        assert!(t.contains("3 sessions in 2 run(s)"), "{t}");
        assert!(t.contains("counted once"), "{t}");
        // The two h = 10 sessions: their mean over the 3 updates both have, final cost
        // (1 + 3)/2 = 2 (not update 3 of one session alone).
        assert!(t.contains("its sessions have 3–4 updates"), "{t}");
        assert!(
            t.contains("| A1 (h = 10,") && t.contains("| 2.0000 ± 1.4142 |"),
            "{t}"
        );
        assert!(
            t.contains("| A1 (h = 20,") && t.contains("| 8.0000 ± 0.0000 |"),
            "{t}"
        );
    }

    /// Via-point and T-ball sessions in one experiment: a figure per task, not both on one
    /// axis (costs of hundreds beside costs of a few).
    #[test]
    fn mean_curves_of_different_tasks_are_drawn_apart() {
        let dir = std::env::temp_dir().join(format!("pi2cma-tasks-{}", std::process::id()));
        let of_task = |name: &str, seed, task: &str, costs: &[f64]| {
            let mut r = session(name, seed, 10.0, costs);
            r.run[0].config_toml = format!("[task.{task}]\nduration = 1.0\n");
            r
        };
        let recs = [
            of_task("A1", 1, "via-point", &[400.0, 300.0, 200.0]),
            of_task("A1", 2, "via-point", &[500.0, 350.0, 250.0]),
            of_task("tball", 1, "tball", &[4.0, 2.0, 1.0]),
        ];
        let report = experiment(&recs, Some(&dir), 0.05, true, false).unwrap();
        assert!(!dir.join("mean_curves.svg").exists(), "{}", report.table);
        let via = std::fs::read_to_string(dir.join("mean_curves-via-point.svg")).unwrap();
        let tball = std::fs::read_to_string(dir.join("mean_curves-tball.svg")).unwrap();
        assert!(via.contains("A1 (2 sessions)") && !via.contains("tball (1 sessions)"));
        assert!(tball.contains("tball (1 sessions)") && !tball.contains("A1 (2 sessions)"));
        assert!(report.table.contains("drawn per task"), "{}", report.table);
        // One task: one mean_curves.svg, as before.
        std::fs::remove_dir_all(&dir).unwrap();
        experiment(&recs[..2], Some(&dir), 0.05, true, false).unwrap();
        assert!(dir.join("mean_curves.svg").is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn each_segment_row_gives_the_eval_cost_where_that_segment_ended() {
        let with_change = |seed, costs: &[f64]| {
            let mut r = session("T", seed, 10.0, costs);
            r.task_changes.push(proto::TaskChange {
                update: 4,
                ..Default::default()
            });
            r
        };
        let recs = [
            with_change(1, &[100.0, 30.0, 5.0, 1.0, 50.0, 10.0, 3.0, 2.0]),
            with_change(2, &[90.0, 20.0, 4.0, 3.0, 60.0, 12.0, 5.0, 4.0]),
        ];
        let t = experiment(&recs, None, 0.05, false, false).unwrap().table;
        let row = |start: &str| {
            t.lines()
                .find(|l| l.contains(&format!("| {start}")))
                .unwrap_or_else(|| panic!("no segment {start}: {t}"))
                .to_string()
        };
        // Before the change, at update 3: (1 + 3)/2; after it, at update 7: (2 + 4)/2.
        assert!(row("0 ").ends_with("| 2.0000 ± 1.4142 |"), "{t}");
        assert!(
            row("4 (task change)").ends_with("| 3.0000 ± 1.4142 |"),
            "{t}"
        );
    }

    #[test]
    fn a_segment_that_has_not_settled_is_not_converged() {
        // After the change the cost rises from its lowest value, 10 at update 3, to 40: the
        // last cost is outside the band 10 + 0.05·30.
        let rising = rec_with(&[5.0, 4.0, 4.0, 10.0, 20.0, 30.0, 40.0], Some(3));
        let s = reconvergence(&rising, 0.05);
        assert_eq!(s[0].converged_at, Some(1));
        assert_eq!(
            (s[1].converged_at, s[1].updates_to_converge()),
            (None, None)
        );
        // Still falling steeply: only the last (and lowest) cost is inside the band.
        let falling = rec_with(&[100.0, 80.0, 60.0, 40.0, 20.0], None);
        assert_eq!(reconvergence(&falling, 0.05)[0].converged_at, None);
    }
}
