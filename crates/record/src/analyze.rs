//! Post-hoc analysis of one or many recordings: an info summary, CSV per topic, SVG figures
//! (learning curve with ±std band and λ on a log axis, distribution ellipses for 2-D policies,
//! per-worker rollout time), and over the sessions of an experiment: mean curves and a
//! re-convergence table.
//!
//! Entry point for command lines: [`AnalyzeArgs`] + [`run`].

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::ticks::{self, Along, Ticks};

use crate::digest::{TimeBucket, WorkerTimes};
pub use crate::digest::{TimelineBar, TIMELINE_UPDATES};
use crate::recompute::read_and_verify;
use crate::{
    distribution_from_proto, join_resumed, proto, read_recording_slim, Decoded, RecordError,
    Recording, UpdatePoint,
};

/// `analyze FILES… [--out DIR]`: prints the info summary of every file; with `--out`, writes CSV
/// and figures per file into `DIR/<file stem>/`, and with several files the experiment's mean
/// curves and re-convergence table into `DIR/`.
#[derive(Debug, Clone, clap::Args)]
pub struct AnalyzeArgs {
    /// MCAP recordings: one run, or the sessions of an experiment (grouped by run name). The
    /// files of a run that was stopped and resumed are joined into one run.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Directory for CSV files and SVG figures; without it only the summary is printed.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Do not write CSV files.
    #[arg(long)]
    pub no_csv: bool,
    /// Do not draw figures.
    #[arg(long)]
    pub no_plots: bool,
    /// Recompute every update from its recorded inputs and report mismatches.
    #[arg(long)]
    pub verify: bool,
    /// Re-convergence tolerance: a segment has converged once every later eval cost is within
    /// `tolerance` × (peak − lowest level) of its lowest level.
    #[arg(long, default_value_t = 0.05, value_parser = parse_tolerance)]
    pub tolerance: f64,
}

/// A tolerance is a fraction of the jump: in [0, 1) (at 1 every update would count as
/// converged).
pub fn parse_tolerance(s: &str) -> Result<f64, String> {
    let t: f64 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if (0.0..1.0).contains(&t) {
        Ok(t)
    } else {
        Err(format!("{s}: must be at least 0 and less than 1"))
    }
}

/// Runs `analyze`; returns the text to print (summaries and the files written). `program` is
/// how the user calls the binary that runs it, for the commands the text suggests
/// ([`info_for`]).
pub fn run(args: &AnalyzeArgs, program: &str) -> Result<String, RecordError> {
    let mut out = String::new();
    let mut recs = Vec::with_capacity(args.files.len());
    let mut read: Vec<(PathBuf, &Path)> = Vec::new();
    for f in &args.files {
        // The same file twice (a shell glob and a name, or two spellings of a path) is one run.
        let canonical = std::fs::canonicalize(f).map_err(io(f))?;
        if let Some((_, first)) = read.iter().find(|(c, _)| *c == canonical) {
            let _ = writeln!(
                out,
                "note: {} is {} again: read once\n",
                f.display(),
                first.display()
            );
            continue;
        }
        read.push((canonical, f));
        // Recomputed as the file is read: a large file is streamed once less.
        let (rec, verified) = if args.verify {
            let (rec, r) = read_and_verify(f)?;
            (rec, Some(r))
        } else {
            (read_recording_slim(f)?, None)
        };
        out.push_str(&info_for(&rec, program));
        if let Some(r) = verified {
            let _ = writeln!(
                out,
                "  recompute: {} updates, {} mismatches{}",
                r.updates,
                r.mismatches.len(),
                if r.mismatches.is_empty() {
                    " (bit-identical)".to_string()
                } else {
                    format!(" at updates {:?}", r.mismatches)
                }
            );
        }
        out.push('\n');
        recs.push(rec);
    }
    // Parts of a split recording left out would cut the run short; say which.
    let mut firsts: Vec<PathBuf> = Vec::new();
    for f in args.files.iter().map(|f| crate::first_part(f)) {
        if !firsts.contains(&f) {
            firsts.push(f);
        }
    }
    for f in &firsts {
        let parts = crate::recording_parts(f);
        // Compared canonically, as the files were read: `./a.part-2.mcap` is `a.part-2.mcap`.
        let is_given: Vec<bool> = parts
            .iter()
            .map(|p| std::fs::canonicalize(p).is_ok_and(|c| read.iter().any(|(r, _)| *r == c)))
            .collect();
        // A first part that was moved away is not there to be given.
        let missing: Vec<String> = parts
            .iter()
            .zip(&is_given)
            .filter(|(p, given)| !**given && p.exists())
            .map(|(p, _)| p.display().to_string())
            .collect();
        // By part number, not place in `parts`: parts deleted from the disk in between (a long
        // run's archived ones) leave a gap that the list of those there does not show.
        let given: Vec<u32> = parts
            .iter()
            .zip(&is_given)
            .filter(|(_, given)| **given)
            .map(|(p, _)| crate::part_number(p))
            .collect();
        let gap = given.windows(2).any(|w| w[1] != w[0] + 1);
        if gap {
            // Parts with a gap between them are neither one run nor separate sessions: their
            // curves would be averaged as an experiment's (0 common updates, NaN statistics).
            let (low, high) = (given[0], given[given.len() - 1]);
            let (there, gone): (Vec<PathBuf>, Vec<PathBuf>) = (low + 1..high)
                .filter(|n| !given.contains(n))
                .map(|n| crate::part_path_or_first(f, n))
                .partition(|p| p.exists());
            let names = |ps: &[PathBuf]| {
                ps.iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let mut what = Vec::new();
            if !there.is_empty() {
                what.push(format!("not {}", names(&there)));
            }
            if !gone.is_empty() {
                what.push(format!("{} no longer there", names(&gone)));
            }
            return Err(RecordError::invalid(
                f,
                format!(
                    "{} of the {} parts of this split recording are given, with a gap: {}; \
                     give the parts in between (or every part) to analyse the run, or the parts \
                     on one side of the gap",
                    given.len(),
                    parts.len(),
                    what.join("; ")
                ),
            ));
        }
        if !missing.is_empty() && parts.len() > 1 {
            let _ = writeln!(
                out,
                "note: the split recording {} has {} parts; not given: {} ({} of them; give \
                 every part to analyse the whole run)\n",
                f.display(),
                parts.len(),
                crate::split::name_list(missing.clone()),
                missing.len()
            );
        }
    }
    // A copy of a file would otherwise be joined to the resumed run's next file in place of
    // the original, and the original become a session of its own.
    let recs = drop_copies(recs, &mut out);
    // A run stopped and resumed is one run in two (or more) files: one curve, one session.
    let runs = join_resumed(recs);
    let subdirs = output_dirs(&runs.iter().map(|(_, p)| p[0].as_path()).collect::<Vec<_>>());
    for ((rec, parts), subdir) in runs.iter().zip(&subdirs) {
        if parts.len() > 1 {
            let names: Vec<String> = parts.iter().map(|p| p.display().to_string()).collect();
            // A resumed run's files, or the parts of a split recording (or both).
            let begins: Vec<String> = rec.run.iter().map(|r| r.update.to_string()).collect();
            // Updates a restarted recorder's predecessor had not written, also those before a
            // last part that holds none.
            let points = &rec.digest.points;
            let missing = missing_updates(rec);
            let _ = writeln!(
                out,
                "{}: one run of {} updates{}, its files beginning at updates {}{}",
                names.join(" + "),
                points.len(),
                match (points.first(), points.last()) {
                    (Some(a), Some(b)) => format!(" ({}..={})", a.update, b.update),
                    _ => String::new(),
                },
                begins.join(", "),
                if missing.is_empty() {
                    String::new()
                } else {
                    format!("; missing {missing} ({})", why_missing(rec))
                }
            );
        }
        if let Some(dir) = &args.out {
            let sub = dir.join(subdir);
            if !args.no_csv {
                for p in export_csv(rec, &sub)? {
                    let _ = writeln!(out, "  wrote {}", p.display());
                }
            }
            if !args.no_plots {
                let figures = plot(rec, &sub)?;
                if figures.is_empty() {
                    let _ = writeln!(out, "  {NOTHING_TO_PLOT}");
                }
                for p in figures {
                    let _ = writeln!(out, "  wrote {}", p.display());
                }
            }
        }
    }
    if runs.len() > 1 {
        let recs: Vec<Recording> = runs.into_iter().map(|(r, _)| r).collect();
        let exp = experiment(
            &recs,
            args.out.as_deref(),
            args.tolerance,
            !args.no_plots,
            !args.no_csv,
        )?;
        out.push_str(&exp.table);
        for p in &exp.files {
            let _ = writeln!(out, "wrote {}", p.display());
        }
    }
    Ok(out)
}

/// One output directory name per run: its file's stem, or, where stems repeat (every
/// `pi2cma run` records `run.mcap` in its own directory), the parent directory's name and the
/// stem, numbered if even that repeats, so that no run's files overwrite another's.
fn output_dirs(files: &[&Path]) -> Vec<String> {
    let count = |names: &[String], n: &String| names.iter().filter(|m| *m == n).count();
    let stems: Vec<String> = files.iter().map(|p| stem(p)).collect();
    let named: Vec<String> = files
        .iter()
        .zip(&stems)
        .map(|(p, s)| {
            let parent = std::path::absolute(p).ok().and_then(|a| {
                a.parent()?
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
            });
            match parent {
                Some(dir) if count(&stems, s) > 1 => format!("{dir}-{s}"),
                _ => s.clone(),
            }
        })
        .collect();
    // Names that repeat are numbered from 1; a name that numbering made already (`a-run-1`
    // beside two `a-run`s) is numbered on from 2 until it is free.
    let mut out: Vec<String> = Vec::with_capacity(named.len());
    for n in &named {
        let repeats = count(&named, n) > 1;
        let mut k = usize::from(!repeats);
        let mut name = n.clone();
        while (repeats && k == 0) || out.contains(&name) {
            k += 1;
            name = format!("{n}-{k}");
        }
        out.push(name);
    }
    out
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into())
}

fn io(file: &Path) -> impl FnOnce(std::io::Error) -> RecordError + '_ {
    move |e| RecordError::io(file, e)
}

// ---------------------------------------------------------------------------------------------
// Info

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
fn missing_updates(rec: &Recording) -> String {
    let from = rec.run.first().map(|r| r.update);
    let until = rec.run.iter().map(|r| r.update).max();
    gaps_within(rec.digest.points.iter().map(|u| u.update), from, until)
}

/// Why a run's files lack updates: a restarted recorder's predecessor had not written them, or
/// (with no restart logged) they were lost with the damaged part of a recovered file.
fn why_missing(rec: &Recording) -> &'static str {
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

fn describe_hp(hp: &proto::Hyperparameters) -> String {
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

// ---------------------------------------------------------------------------------------------
// CSV

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn f(v: f64) -> String {
    // Shortest representation that round-trips exactly.
    format!("{v:?}")
}

fn ts(t: &Option<prost_types::Timestamp>) -> String {
    t.map(|t| (t.seconds as i128 * 1_000_000_000 + t.nanos as i128).to_string())
        .unwrap_or_default()
}

/// A CSV file written as its rows come (an `update_rollouts.csv` can outgrow the RAM). The
/// first write error is kept and returned by [`Csv::write`].
struct Csv {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    error: Option<std::io::Error>,
}

impl Csv {
    fn new(dir: &Path, name: &str, header: &[String]) -> Result<Self, RecordError> {
        let path = dir.join(name);
        let file = std::fs::File::create(&path).map_err(io(&path))?;
        let mut csv = Self {
            out: std::io::BufWriter::with_capacity(1 << 20, file),
            path,
            error: None,
        };
        csv.row(header.to_vec());
        Ok(csv)
    }
    fn row(&mut self, cells: Vec<String>) {
        use std::io::Write as _;
        if self.error.is_none() {
            if let Err(e) = writeln!(self.out, "{}", cells.join(",")) {
                self.error = Some(e);
            }
        }
    }
    fn write(mut self) -> Result<PathBuf, RecordError> {
        use std::io::Write as _;
        match self.error.take() {
            Some(e) => Err(e),
            None => self.out.flush(),
        }
        .map_err(io(&self.path))?;
        Ok(self.path)
    }
}

/// The columns `update.csv` and `summary.csv` begin with: an update's costs and λ.
const SUMMARY_COLUMNS: [&str; 7] = [
    "timestamp_ns",
    "update",
    "eval_cost",
    "exploration_cost_mean",
    "exploration_cost_std",
    "lambda",
    "lambda_next",
];

/// The [`SUMMARY_COLUMNS`] of an update's summary.
fn summary_cells(s: &proto::UpdateSummary) -> Vec<String> {
    vec![
        ts(&s.timestamp),
        s.update.to_string(),
        f(s.eval_cost),
        f(s.exploration_cost_mean),
        f(s.exploration_cost_std),
        f(s.lambda),
        f(s.lambda_next),
    ]
}

fn names(prefix: &str, n: usize) -> Vec<String> {
    (0..n).map(|i| format!("{prefix}{i}")).collect()
}

/// Writes one CSV per topic into `dir` (created if needed): `run.csv`, `update.csv` (scalars,
/// means and covariances before/after), `update_rollouts.csv` (one row per update and rollout:
/// weight, costs, θ), `summary.csv`, `rollout.csv`, `task_change.csv`, `log.csv`. Floats are
/// written in their shortest exact form.
pub fn export_csv(rec: &Recording, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let p = rec
        .run_info()
        .map(|r| r.dim as usize)
        .unwrap_or_else(|| rec.updates.first().map(|u| u.dim as usize).unwrap_or(0));
    let steps = rec.updates.first().map(|u| u.steps as usize).unwrap_or(0);

    let mut run = Csv::new(
        dir,
        "run.csv",
        &[
            "timestamp_ns",
            "update",
            "name",
            "seed",
            "dim",
            "steps",
            "rollouts",
            "executor",
            "hyperparameters",
        ]
        .map(String::from),
    )?;
    for r in &rec.run {
        let hp = r.hyperparameters.unwrap_or_default();
        run.row(vec![
            ts(&r.timestamp),
            r.update.to_string(),
            csv_field(&r.name),
            r.seed.to_string(),
            r.dim.to_string(),
            r.steps.to_string(),
            hp.rollouts.to_string(),
            csv_field(&r.executor),
            csv_field(&describe_hp(&hp)),
        ]);
    }
    files.push(run.write()?);

    let mut header: Vec<String> = SUMMARY_COLUMNS.map(String::from).to_vec();
    header.extend(["batch_start_ns", "batch_end_ns"].map(String::from));
    header.extend(names("before_mean_", p));
    header.extend(names("after_mean_", p));
    header.extend(names("before_cov_", p * p));
    header.extend(names("after_cov_", p * p));
    let mut upd = Csv::new(dir, "update.csv", &header)?;
    let mut header: Vec<String> = ["update", "rollout", "weight", "total_cost", "terminal_cost"]
        .map(String::from)
        .to_vec();
    header.extend(names("theta_", p));
    header.extend(names("cost_step_", steps));
    let mut rol = Csv::new(dir, "update_rollouts.csv", &header)?;
    let mut header: Vec<String> = SUMMARY_COLUMNS.map(String::from).to_vec();
    header.extend(names("mean_next_", p));
    let mut sum = Csv::new(dir, "summary.csv", &header)?;
    let mut ro = Csv::new(
        dir,
        "rollout.csv",
        &[
            "timestamp_ns",
            "update",
            "rollout",
            "worker",
            "start_ns",
            "end_ns",
            "total_cost",
        ]
        .map(String::from),
    )?;
    let mut lg = Csv::new(
        dir,
        "log.csv",
        &[
            "timestamp_ns",
            "update",
            "level",
            "event",
            "name",
            "pid",
            "message",
        ]
        .map(String::from),
    )?;
    // One pass over the files for a recording read slim: its messages are not in memory.
    rec.for_each_message(|m| {
        match m {
            Decoded::Update(u) => update_rows(u, &mut upd, &mut rol),
            Decoded::Summary(s) => {
                let mut row = summary_cells(s);
                row.extend(s.mean.iter().map(|x| f(*x)));
                sum.row(row);
            }
            Decoded::Rollout(r) => ro.row(vec![
                ts(&r.timestamp),
                r.update.to_string(),
                r.rollout.to_string(),
                csv_field(&r.worker),
                r.start_ns.to_string(),
                r.end_ns.to_string(),
                f(r.total_cost),
            ]),
            Decoded::Log(l) => {
                let level = proto::foxglove::log::Level::try_from(l.level)
                    .map(|v| v.as_str_name().to_string())
                    .unwrap_or_else(|_| l.level.to_string());
                lg.row(vec![
                    ts(&l.timestamp),
                    l.update.to_string(),
                    level,
                    csv_field(&l.event),
                    csv_field(&l.name),
                    l.pid.to_string(),
                    csv_field(&l.message),
                ]);
            }
        }
        Ok(())
    })?;
    files.push(upd.write()?);
    files.push(rol.write()?);
    files.push(sum.write()?);
    files.push(ro.write()?);

    let mut tc = Csv::new(
        dir,
        "task_change.csv",
        &["timestamp_ns", "update", "name", "value"].map(String::from),
    )?;
    for c in &rec.task_changes {
        tc.row(vec![
            ts(&c.timestamp),
            c.update.to_string(),
            csv_field(&c.name),
            f(c.value),
        ]);
    }
    files.push(tc.write()?);
    files.push(lg.write()?);
    Ok(files)
}

/// The `update.csv` row and the `update_rollouts.csv` rows of one update.
fn update_rows(u: &proto::Update, upd: &mut Csv, rol: &mut Csv) {
    let mut row = summary_cells(&crate::reader::curve_row(u));
    row.extend([u.batch_start_ns.to_string(), u.batch_end_ns.to_string()]);
    let (b, a) = (
        u.before.clone().unwrap_or_default(),
        u.after.clone().unwrap_or_default(),
    );
    for v in [&b.mean, &a.mean, &b.covariance, &a.covariance] {
        row.extend(v.iter().map(|x| f(*x)));
    }
    upd.row(row);
    let (k, pd, n) = (u.rollouts as usize, u.dim as usize, u.steps as usize);
    for r in 0..k {
        let step = u.cost_per_step.get(r * n..(r + 1) * n).unwrap_or(&[]);
        let terminal = u.cost_terminal.get(r).copied().unwrap_or(f64::NAN);
        let mut row = vec![
            u.update.to_string(),
            r.to_string(),
            f(u.weights.get(r).copied().unwrap_or(f64::NAN)),
            f(terminal + step.iter().sum::<f64>()),
            f(terminal),
        ];
        row.extend(
            u.samples
                .get(r * pd..(r + 1) * pd)
                .unwrap_or(&[])
                .iter()
                .map(|x| f(*x)),
        );
        row.extend(step.iter().map(|x| f(*x)));
        rol.row(row);
    }
}

// ---------------------------------------------------------------------------------------------
// Figures

/// matplotlib's tab10.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn perr<E: std::fmt::Debug>(file: &Path, figure: &str) -> impl FnOnce(E) -> RecordError {
    let file = file.to_path_buf();
    let figure = figure.to_string();
    move |e| RecordError::Plot {
        file,
        figure,
        what: format!("{e:?}"),
    }
}

/// The framed legend of a chart's labelled series, at `position`.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|x| format!("{x:?}"))
}

/// Range with a margin; never empty.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let span = (hi - lo).abs().max(1e-12 * hi.abs().max(1.0));
    (lo - 0.05 * span, hi + 0.05 * span)
}

fn log_range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in vals.filter(|v| *v > 0.0 && v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi > 0.0) {
        return (0.1, 10.0);
    }
    (lo / 1.5, hi * 1.5)
}

/// Up to this many updates, a learning curve is drawn through every update; beyond, through
/// each of [`CURVE_BUCKETS`] runs of consecutive updates' lowest and highest value.
pub const CURVE_POINTS: usize = 4000;

/// For a longer curve: into how many runs of consecutive updates (buckets) it is split. Each
/// line goes through every bucket's lowest and highest value, in the order they occur, and the
/// band spans each bucket's extremes, so that a spike (the cost after a task change) shows as
/// it would undecimated, in an SVG that does not grow with the run.
pub const CURVE_BUCKETS: usize = 1000;

/// One line of a learning-curve figure: per update x, a centre value and a ±band, and λ.
struct Curve {
    label: String,
    /// The last update (a decimated line need not reach it).
    x_max: f64,
    /// Each stretch of consecutive updates (a missing update breaks the line).
    pieces: Vec<Piece>,
}

/// What a [`Curve`] draws over a stretch of consecutive updates.
#[derive(Debug, Default, PartialEq)]
struct Piece {
    line: Vec<(f64, f64)>,
    /// The band's outline: its upper edge forward, its lower edge back.
    band: Option<Vec<(f64, f64)>>,
    lambda: Vec<(f64, f64)>,
}

/// A curve's values per update, as [`Curve::new`] takes them.
struct Values<'a> {
    x: &'a [f64],
    y: &'a [f64],
    band: Option<&'a [f64]>,
    lambda: Option<&'a [f64]>,
}

impl Curve {
    fn new(label: String, v: Values<'_>) -> Self {
        // Buckets of `width` updates; 1 draws every update.
        let width = if v.x.len() > CURVE_POINTS {
            v.x.len().div_ceil(CURVE_BUCKETS)
        } else {
            1
        };
        let pieces = contiguous(v.x)
            .into_iter()
            .map(|r| {
                let x = &v.x[r.clone()];
                let y = &v.y[r.clone()];
                Piece {
                    line: extremes(x, y, width),
                    band: v.band.map(|b| band(x, y, &b[r.clone()], width)),
                    lambda: v
                        .lambda
                        .map(|l| extremes(x, &l[r.clone()], width))
                        .unwrap_or_default(),
                }
            })
            .collect();
        Self {
            label,
            x_max: v.x.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            pieces,
        }
    }
}

/// The points of `y` over `x` a line goes through: every one, or with `width` > 1 per bucket of
/// `width` its lowest and highest, in the order they occur.
fn extremes(x: &[f64], y: &[f64], width: usize) -> Vec<(f64, f64)> {
    if width <= 1 {
        return x.iter().copied().zip(y.iter().copied()).collect();
    }
    let mut out = Vec::new();
    for (xs, ys) in x.chunks(width).zip(y.chunks(width)) {
        let lowest = (0..ys.len()).min_by(|a, b| ys[*a].total_cmp(&ys[*b]));
        let highest = (0..ys.len()).max_by(|a, b| ys[*a].total_cmp(&ys[*b]));
        if let (Some(lo), Some(hi)) = (lowest, highest) {
            let (a, b) = (lo.min(hi), lo.max(hi));
            out.push((xs[a], ys[a]));
            if b != a {
                out.push((xs[b], ys[b]));
            }
        }
    }
    out
}

/// The outline of the band y ± b: per update, or with `width` > 1 per bucket its highest
/// y + b and lowest y − b over the bucket's updates.
fn band(x: &[f64], y: &[f64], b: &[f64], width: usize) -> Vec<(f64, f64)> {
    let upper: Vec<f64> = y.iter().zip(b).map(|(y, b)| y + b).collect();
    let lower: Vec<f64> = y.iter().zip(b).map(|(y, b)| y - b).collect();
    if width <= 1 {
        let mut pts: Vec<(f64, f64)> = x.iter().copied().zip(upper).collect();
        pts.extend(x.iter().copied().zip(lower).rev());
        return pts;
    }
    let (mut top, mut bottom) = (Vec::new(), Vec::new());
    for ((xs, us), ls) in x
        .chunks(width)
        .zip(upper.chunks(width))
        .zip(lower.chunks(width))
    {
        let (first, last) = (xs[0], xs[xs.len() - 1]);
        let u = us.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let l = ls.iter().copied().fold(f64::INFINITY, f64::min);
        top.extend([(first, u), (last, u)]);
        bottom.extend([(first, l), (last, l)]);
    }
    top.extend(bottom.into_iter().rev());
    top
}

/// The index ranges of `x` (update numbers, ascending) without a missing update inside.
fn contiguous(x: &[f64]) -> Vec<std::ops::Range<usize>> {
    let mut ranges = Vec::new();
    let mut start = 0;
    for i in 1..=x.len() {
        if i == x.len() || x[i] - x[i - 1] > 1.0 {
            if start < i {
                ranges.push(start..i);
            }
            start = i;
        }
    }
    ranges
}

/// Cost panel (lines + bands) above a λ panel on a log axis; dashed lines at task changes.
fn draw_curves(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    curves: &[Curve],
    changes: &[u64],
    cost_label: &str,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    area.fill(&WHITE).map_err(|x| e(&x))?;
    let (top, bottom) = area.split_vertically((area.dim_in_pixel().1 as f64 * 0.62) as u32);
    let xmax = curves.iter().map(|c| c.x_max).fold(1.0f64, f64::max);
    // A single update would sit on the axis at update 0: centred instead.
    let lone = curves
        .iter()
        .all(|c| c.pieces.iter().map(|p| p.line.len()).sum::<usize>() <= 1);
    let last = curves.iter().map(|c| c.x_max).fold(0.0f64, f64::max);
    let (xmin, xmax) = if lone {
        (last - 1.0, last + 1.0)
    } else {
        (0.0, xmax)
    };
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in curves.iter().flat_map(|c| &c.pieces) {
        for (_, y) in p.line.iter().chain(p.band.iter().flatten()) {
            lo = lo.min(*y);
            hi = hi.max(*y);
        }
    }
    // Costs that fall over more than two decades (80 to 0.05) were a flat line after the
    // first updates on a linear axis: a log axis then, over the lines' values; a band's
    // lower edge at or below zero runs along its bottom.
    let log = ticks::wants_log(
        curves
            .iter()
            .flat_map(|c| &c.pieces)
            .flat_map(|p| p.line.iter().map(|pt| pt.1)),
    );
    let (lo, hi) = if log {
        log_range(
            curves
                .iter()
                .flat_map(|c| &c.pieces)
                .flat_map(|p| p.line.iter().map(|pt| pt.1)),
        )
    } else {
        padded(lo.min(0.0), hi)
    };
    let (margin, x_area, y_area, caption) = (10, 30, 70, 20);
    let (w, h) = ticks::plot_size(top.dim_in_pixel(), margin, y_area, 0, x_area, caption);
    let xt = Ticks::linear(xmin, xmax, w, Along::Horizontal);
    let (yt, y_desc) = if log {
        (
            Ticks::log(lo, hi, h, Along::Vertical),
            format!("{cost_label} (log)"),
        )
    } else {
        (
            Ticks::linear(lo, hi, h, Along::Vertical),
            cost_label.to_string(),
        )
    };
    // On a log axis the chart draws log10 of each cost (a band edge at or below zero at the
    // axis' bottom): one coordinate type for both scales.
    let fy = |y: f64| if log { y.max(lo).log10() } else { y };
    let yt = Ticks {
        values: yt.values.iter().map(|v| fy(*v)).collect(),
        labels: yt.labels,
    };
    let (lo, hi) = (fy(lo), fy(hi));
    let mut chart = ChartBuilder::on(&top)
        .caption(title, ("sans-serif", caption))
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(xt.on(xmin, xmax), yt.on(lo, hi))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc(y_desc)
        .draw()
        .map_err(|x| e(&x))?;
    let map =
        |pts: &[(f64, f64)]| -> Vec<(f64, f64)> { pts.iter().map(|&(x, y)| (x, fy(y))).collect() };
    for (i, c) in curves.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        // Updates a recording lacks (a restarted recorder's gap) break the line, rather than
        // being drawn over as if they had been there.
        for (n, p) in c.pieces.iter().enumerate() {
            // A line and a band through one update (a run of one update, or one between two
            // missing ones) are invisible: that update is a dot with a bar instead.
            let single = p.line.len() == 1;
            if let Some(b) = &p.band {
                if single {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            map(b),
                            color.mix(0.5).stroke_width(3),
                        )))
                        .map_err(|x| e(&x))?;
                } else {
                    chart
                        .draw_series(std::iter::once(Polygon::new(
                            map(b),
                            color.mix(0.2).filled(),
                        )))
                        .map_err(|x| e(&x))?;
                }
            }
            let line = if single {
                chart.draw_series(
                    map(&p.line)
                        .into_iter()
                        .map(|pt| Circle::new(pt, 3, color.filled())),
                )
            } else {
                chart.draw_series(LineSeries::new(map(&p.line), color.stroke_width(2)))
            }
            .map_err(|x| e(&x))?;
            if n == 0 {
                line.label(c.label.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
            }
        }
    }
    mark_changes(&mut chart, changes, (lo, hi))?;
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;

    let (llo, lhi) = log_range(
        curves
            .iter()
            .flat_map(|c| &c.pieces)
            .flat_map(|p| p.lambda.iter().map(|l| l.1)),
    );
    let (_, h) = ticks::plot_size(bottom.dim_in_pixel(), margin, y_area, 0, x_area, 0);
    let lt = Ticks::log(llo, lhi, h, Along::Vertical);
    let mut chart = ChartBuilder::on(&bottom)
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(xt.on(xmin, xmax), lt.on_log(llo, lhi))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc("λ (log)")
        .draw()
        .map_err(|x| e(&x))?;
    // λ rising again after a change is the point of the method: the change is marked here too.
    mark_changes(&mut chart, changes, (llo, lhi))?;
    for (i, c) in curves.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        for p in c.pieces.iter().filter(|p| !p.lambda.is_empty()) {
            let positive = p.lambda.iter().copied().filter(|(_, l)| *l > 0.0);
            if p.lambda.len() == 1 {
                chart
                    .draw_series(positive.map(|pt| Circle::new(pt, 3, color.filled())))
                    .map_err(|x| e(&x))?;
            } else {
                chart
                    .draw_series(LineSeries::new(positive, color.stroke_width(2)))
                    .map_err(|x| e(&x))?;
            }
        }
    }
    area.present().map_err(|x| e(&x))?;
    Ok(())
}

/// A dashed vertical line from `y.0` to `y.1` at each task change's update.
fn mark_changes<DB, CT>(
    chart: &mut ChartContext<'_, DB, CT>,
    changes: &[u64],
    y: (f64, f64),
) -> Result<(), String>
where
    DB: DrawingBackend,
    CT: CoordTranslate<From = (f64, f64)>,
{
    for &u in changes {
        let x = u as f64;
        chart
            .draw_series(DashedLineSeries::new(
                vec![(x, y.0), (x, y.1)],
                5,
                5,
                BLACK.mix(0.6).stroke_width(1),
            ))
            .map_err(|x| format!("{x:?}"))?;
    }
    Ok(())
}

/// What `analyze` says for a recording without updates instead of drawing figures.
pub const NOTHING_TO_PLOT: &str = "no figures: no update recorded, nothing to plot";

/// Draws the figures of one recording into `dir`: `learning_curve.svg`, `worker_time.svg`, and
/// for 2-D policies `distribution.svg`; none (an empty list) for a recording without updates
/// ([`NOTHING_TO_PLOT`]).
pub fn plot(rec: &Recording, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
    let points = &rec.digest.points;
    if points.is_empty() {
        // Empty axes presented as figures; the callers say there is nothing to plot.
        return Ok(Vec::new());
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let changes: Vec<u64> = rec.task_changes.iter().map(|c| c.update).collect();

    let path = dir.join("learning_curve.svg");
    {
        let root = SVGBackend::new(&path, (900, 650)).into_drawing_area();
        let column = |v: fn(&UpdatePoint) -> f64| points.iter().map(v).collect::<Vec<f64>>();
        let x = column(|p| p.update as f64);
        let curves = [
            Curve::new(
                "exploration mean ± std".into(),
                Values {
                    x: &x,
                    y: &column(|p| p.exploration_cost_mean),
                    band: Some(&column(|p| p.exploration_cost_std)),
                    lambda: None,
                },
            ),
            Curve::new(
                "evaluation (rollout 0)".into(),
                Values {
                    x: &x,
                    y: &column(|p| p.eval_cost),
                    band: None,
                    lambda: Some(&column(|p| p.lambda)),
                },
            ),
        ];
        draw_curves(
            &root,
            &format!("{}: learning curve", rec.name()),
            &curves,
            &changes,
            "cost",
        )
        .map_err(perr(&path, "learning_curve"))?;
    }
    files.push(path);

    let dim = rec.run_info().map(|r| r.dim).unwrap_or(0);
    if dim == 2 && !points.is_empty() {
        let path = dir.join("distribution.svg");
        plot_ellipses(rec, &path).map_err(perr(&path, "distribution"))?;
        files.push(path);
    }

    let path = dir.join("worker_time.svg");
    plot_worker_time(rec, &path).map_err(perr(&path, "worker_time"))?;
    files.push(path);

    let bars = timeline(rec, TIMELINE_UPDATES);
    if !bars.is_empty() {
        let path = dir.join("worker_timeline.svg");
        plot_worker_timeline(rec, &bars, &path).map_err(perr(&path, "worker_timeline"))?;
        files.push(path);
    }
    Ok(files)
}

/// The narrowest bar of `worker_timeline.svg`, in pixels: 1.5 covers at least one whole pixel
/// wherever the bar begins.
const MIN_BAR_PIXELS: f64 = 1.5;

// No two updates of a timeline share a colour.
const _: () = assert!(PALETTE.len() >= TIMELINE_UPDATES);

/// The timed rollouts of the last `updates` updates that have any (at most
/// [`TIMELINE_UPDATES`]: what the digest keeps), in start order: when each worker ran what (the
/// workers' own clocks in the pipeline), so idle workers, stragglers and the gaps between
/// updates show.
pub fn timeline(rec: &Recording, updates: usize) -> Vec<TimelineBar> {
    let timed = &rec.digest.timeline;
    let mut last: Vec<u64> = timed.iter().map(|r| r.update).collect();
    last.sort_unstable();
    last.dedup();
    let from = last.len().checked_sub(updates).map_or(0, |i| last[i]);
    let mut bars: Vec<TimelineBar> = timed.iter().filter(|r| r.update >= from).cloned().collect();
    bars.sort_by_key(|b| (b.start_ns, b.update, b.rollout));
    bars
}

fn plot_worker_timeline(rec: &Recording, bars: &[TimelineBar], path: &Path) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    let t0 = bars.iter().map(|b| b.start_ns).min().unwrap_or(0);
    let ms = |t: u64| (t - t0) as f64 / 1e6;
    let xmax = bars.iter().map(|b| ms(b.end_ns)).fold(0.0f64, f64::max);
    let mut workers: Vec<&str> = bars.iter().map(|b| b.worker.as_str()).collect();
    workers.sort_unstable();
    workers.dedup();
    let row = |w: &str| workers.iter().position(|x| *x == w).unwrap_or(0) as f64;
    let (first, last) = (
        bars.iter().map(|b| b.update).min().unwrap_or(0),
        bars.iter().map(|b| b.update).max().unwrap_or(0),
    );
    // Tall enough for the legend of TIMELINE_UPDATES entries, which sits in room kept free at
    // the right (the x range runs 18 % past the last bar).
    let height = (120 + 40 * workers.len() as u32).max(330);
    let root = SVGBackend::new(path, (1000, height)).into_drawing_area();
    let xright = (xmax * 1.18).max(1e-3);
    let (w, _) = ticks::plot_size(root.dim_in_pixel(), 10, 90, 0, 30, 18);
    let xt = Ticks::linear(0.0, xright, w, Along::Horizontal);
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "{}: what each worker ran, updates {first} to {last}",
                rec.name()
            ),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(90)
        .build_cartesian_2d(xt.on(0f64, xright), -0.5f64..(workers.len() as f64 - 0.5))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("time [ms]")
        .y_labels(workers.len())
        .y_label_formatter(&|y| {
            let i = y.round();
            if (y - i).abs() < 1e-6 && i >= 0.0 {
                workers
                    .get(i as usize)
                    .map(|w| w.to_string())
                    .unwrap_or_default()
            } else {
                String::new()
            }
        })
        .disable_y_mesh()
        .draw()
        .map_err(|x| e(&x))?;
    // The SVG backend draws on whole pixels: a rollout shorter than one (a via-point rollout
    // takes a microsecond, the timeline spans milliseconds) became a rectangle 0 wide, and an
    // update whose rollouts were all that short was missing from the figure. Every bar is at
    // least MIN_BAR_PIXELS wide.
    let (x_range, plot_pixels) = (
        chart.x_range(),
        chart.plotting_area().dim_in_pixel().0.max(1),
    );
    let min_width = MIN_BAR_PIXELS * (x_range.end - x_range.start) / f64::from(plot_pixels);
    // One colour per update shown (TIMELINE_UPDATES of them), named in the legend.
    let mut updates: Vec<u64> = bars.iter().map(|b| b.update).collect();
    updates.sort_unstable();
    updates.dedup();
    for (i, u) in updates.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(bars.iter().filter(|b| b.update == *u).map(|b| {
                let y = row(&b.worker);
                Rectangle::new(
                    [
                        (ms(b.start_ns), y - 0.35),
                        (ms(b.end_ns).max(ms(b.start_ns) + min_width), y + 0.35),
                    ],
                    color.filled(),
                )
            }))
            .map_err(|x| e(&x))?
            .label(format!("update {u}"))
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 12, y + 4)], color.filled()));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// Points of the 2σ ellipse of a 2×2 covariance around `m`.
fn ellipse(m: [f64; 2], c: [[f64; 2]; 2]) -> Vec<(f64, f64)> {
    let (a, b, d) = (c[0][0], c[0][1], c[1][1]);
    let tr = 0.5 * (a + d);
    let disc = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = ((tr + disc).max(0.0), (tr - disc).max(0.0));
    let angle = if b == 0.0 && a >= d {
        0.0
    } else if b == 0.0 {
        std::f64::consts::FRAC_PI_2
    } else {
        (l1 - a).atan2(b)
    };
    let (ca, sa) = (angle.cos(), angle.sin());
    (0..=64)
        .map(|i| {
            let t = i as f64 / 64.0 * std::f64::consts::TAU;
            let (x, y) = (2.0 * l1.sqrt() * t.cos(), 2.0 * l2.sqrt() * t.sin());
            (m[0] + ca * x - sa * y, m[1] + sa * x + ca * y)
        })
        .collect()
}

/// The smallest half-axis, in pixels, the ellipse of the first update after a task change is
/// drawn with: with λ small at the change (the run had converged), its 2σ ellipse was under a
/// pixel, and the red mark of the change was invisible.
pub const MIN_CHANGE_ELLIPSE_PIXELS: f64 = 6.0;

/// The ellipse `pts` around `centre`, scaled up about it to a largest half-axis of `least` if
/// smaller (a circle of that radius if it has none).
fn at_least(pts: &[(f64, f64)], centre: (f64, f64), least: f64) -> Vec<(f64, f64)> {
    let radius = pts
        .iter()
        .map(|p| (p.0 - centre.0).hypot(p.1 - centre.1))
        .fold(0.0f64, f64::max);
    if radius >= least {
        return pts.to_vec();
    }
    if radius > 0.0 {
        let k = least / radius;
        return pts
            .iter()
            .map(|p| {
                (
                    centre.0 + k * (p.0 - centre.0),
                    centre.1 + k * (p.1 - centre.1),
                )
            })
            .collect();
    }
    (0..=64)
        .map(|i| {
            let a = f64::from(i) / 64.0 * std::f64::consts::TAU;
            (centre.0 + least * a.cos(), centre.1 + least * a.sin())
        })
        .collect()
}

fn plot_ellipses(rec: &Recording, path: &Path) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    // Every update's, or for a long run those the digest kept (DISTRIBUTIONS_SHOWN).
    let kept = &rec.digest.distributions;
    let from = |d| distribution_from_proto(d).map_err(|w| w.to_string());
    let mut dists = Vec::new();
    for s in &kept.shown {
        dists.push((s.update, from(&s.distribution)?));
    }
    if let Some((u, last)) = &kept.last {
        dists.push((*u, from(last)?));
    }
    let thinned = kept.shown.len() < rec.digest.points.len();
    let n = dists.len().max(1);
    let ellipses: Vec<(u64, Vec<(f64, f64)>)> = dists
        .iter()
        .map(|(u, d)| {
            let m = [d.mean[0], d.mean[1]];
            let c = [
                [d.covariance[(0, 0)], d.covariance[(0, 1)]],
                [d.covariance[(1, 0)], d.covariance[(1, 1)]],
            ];
            (*u, ellipse(m, c))
        })
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (_, pts) in &ellipses {
        for (x, y) in pts {
            x0 = x0.min(*x);
            x1 = x1.max(*x);
            y0 = y0.min(*y);
            y1 = y1.max(*y);
        }
    }
    let (x0, x1) = padded(x0, x1);
    let (y0, y1) = padded(y0, y1);
    let (width, height) = (750u32, 700u32);
    let (margin, x_labels, y_labels, caption) = (10u32, 35u32, 70u32, 18u32);
    // Both axes to one scale: an ellipse's shape and tilt are what the figure is for (with
    // the data's ranges, Σ = λ·I was drawn 3× wider than tall).
    let plot_w = f64::from(width - 2 * margin - y_labels);
    let plot_h = f64::from(height - 2 * margin - x_labels - caption - margin);
    let ((x0, x1), (y0, y1)) = ticks::equal_scale((x0, x1), (y0, y1), plot_w, plot_h);
    let per_pixel = (x1 - x0) / plot_w;
    let (xt, yt) = (
        Ticks::linear(x0, x1, plot_w, Along::Horizontal),
        Ticks::linear(y0, y1, plot_h, Along::Vertical),
    );
    let root = SVGBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart =
        ChartBuilder::on(&root)
            .caption(
                format!(
                "{}: 2σ ellipses of the search distribution{} (dark = late; red = first update \
                 after a task change)",
                rec.name(),
                if thinned {
                    format!(", {} of {} updates", dists.len(), rec.digest.points.len() + 1)
                } else {
                    String::new()
                }
            ),
                ("sans-serif", caption),
            )
            .margin(margin)
            .x_label_area_size(x_labels)
            .y_label_area_size(y_labels)
            .build_cartesian_2d(xt.on(x0, x1), yt.on(y0, y1))
            .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("θ₁")
        .y_desc("θ₂")
        .draw()
        .map_err(|x| e(&x))?;
    let changes: Vec<u64> = rec.task_changes.iter().map(|c| c.update).collect();
    for (i, ((u, pts), (_, d))) in ellipses.iter().zip(&dists).enumerate() {
        let t = i as f64 / n as f64;
        let (color, pts) = if changes.contains(u) {
            let centre = (d.mean[0], d.mean[1]);
            (
                RGBColor(214, 39, 40).stroke_width(2),
                at_least(pts, centre, MIN_CHANGE_ELLIPSE_PIXELS * per_pixel),
            )
        } else {
            let g = (200.0 * (1.0 - t)) as u8;
            (
                RGBColor(g, g, 255u8.saturating_sub((100.0 * t) as u8)).stroke_width(1),
                pts.clone(),
            )
        };
        chart
            .draw_series(LineSeries::new(pts, color))
            .map_err(|x| e(&x))?;
    }
    chart
        .draw_series(LineSeries::new(
            dists.iter().map(|(_, d)| (d.mean[0], d.mean[1])),
            BLACK.stroke_width(1),
        ))
        .map_err(|x| e(&x))?
        .label(if thinned {
            "mean θ of the updates drawn"
        } else {
            "mean θ per update"
        })
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
    chart
        .draw_series(
            dists
                .iter()
                .map(|(_, d)| Circle::new((d.mean[0], d.mean[1]), 2, BLACK.filled())),
        )
        .map_err(|x| e(&x))?;
    draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

fn plot_worker_time(rec: &Recording, path: &Path) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    // Rollouts without their own timing (the in-process runner) have the update's wall time
    // divided by K, under "`<worker>` (update time / K)" (see `Digest::add_rollout`).
    let times = &rec.digest.worker_times;
    let xmax = rec
        .digest
        .points
        .last()
        .map(|u| u.update as f64 + 1.0)
        .unwrap_or(1.0);
    let ymax = match times {
        WorkerTimes::Each(m) => m
            .values()
            .flat_map(|v| v.iter().map(|p| p.1))
            .fold(0.0f64, f64::max),
        WorkerTimes::Buckets { per_worker, .. } => per_worker
            .values()
            .flat_map(|b| b.values().map(|t| t.max))
            .fold(0.0f64, f64::max),
    };
    // In-process via-point rollouts take well under a millisecond: µs then, not "0.000 ms".
    let (scale, unit) = if ymax < 1.0 {
        (1e3, "µs")
    } else {
        (1.0, "ms")
    };
    let ymax = ymax * scale;
    let root = SVGBackend::new(path, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let caption = match times {
        WorkerTimes::Each(_) => format!("{}: rollout time per worker", rec.name()),
        WorkerTimes::Buckets { width, .. } => format!(
            "{}: rollout time per worker, per {width} updates: mean (dot), range (line)",
            rec.name()
        ),
    };
    let ytop = (ymax * 1.1).max(1e-3);
    let (w, h) = ticks::plot_size(root.dim_in_pixel(), 10, 70, 0, 30, 20);
    let (xt, yt) = (
        Ticks::linear(0.0, xmax, w, Along::Horizontal),
        Ticks::linear(0.0, ytop, h, Along::Vertical),
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(70)
        .build_cartesian_2d(xt.on(0f64, xmax), yt.on(0f64, ytop))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc(format!("rollout time [{unit}]"))
        .draw()
        .map_err(|x| e(&x))?;
    match times {
        WorkerTimes::Each(m) => {
            for (i, (worker, pts)) in m.iter().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let mean = scale * pts.iter().map(|p| p.1).sum::<f64>() / pts.len().max(1) as f64;
                chart
                    .draw_series(
                        pts.iter().map(|(u, ms)| {
                            Circle::new((*u as f64, *ms * scale), 2, color.filled())
                        }),
                    )
                    .map_err(|x| e(&x))?
                    .label(format!(
                        "{worker}: {} rollouts, mean {mean:.3} {unit}",
                        pts.len()
                    ))
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
            }
        }
        WorkerTimes::Buckets { width, per_worker } => {
            let w = *width as f64;
            for (i, (worker, buckets)) in per_worker.iter().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let (count, sum) = buckets
                    .values()
                    .fold((0, 0.0), |(n, s), b| (n + b.count, s + b.sum));
                let mean = scale * sum / count.max(1) as f64;
                let middle = |i: u64| (i as f64 + 0.5) * w;
                chart
                    .draw_series(buckets.iter().map(|(i, b)| {
                        PathElement::new(
                            vec![(middle(*i), b.min * scale), (middle(*i), b.max * scale)],
                            color.mix(0.5).stroke_width(1),
                        )
                    }))
                    .map_err(|x| e(&x))?;
                chart
                    .draw_series(buckets.iter().map(|(i, b): (&u64, &TimeBucket)| {
                        Circle::new(
                            (middle(*i), scale * b.sum / b.count.max(1) as f64),
                            2,
                            color.filled(),
                        )
                    }))
                    .map_err(|x| e(&x))?
                    .label(format!("{worker}: {count} rollouts, mean {mean:.3} {unit}"))
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
            }
        }
    }
    draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Experiments: several sessions (files) of one or more runs

/// Re-convergence of one segment of one session.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// First update of the segment (0, or the update a task change applies from).
    pub start: u64,
    /// One past the last update of the segment.
    pub end: u64,
    pub peak: f64,
    /// Final level: the lowest eval cost within the segment.
    pub level: f64,
    /// First update from which every eval cost of the segment stays within the tolerance band;
    /// `None` if the segment has not settled: its last eval cost is outside the band, or only
    /// the last one is inside (a curve still falling at the end has its lowest value last).
    pub converged_at: Option<u64>,
}

impl Segment {
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

/// The runs among `recs`, as `analyze` takes them: copies of a file dropped (with a note in
/// `out`), and the files of one run (a run and the runs resumed from it, the parts of a split
/// recording) joined into one recording.
pub fn join_runs(recs: Vec<Recording>, out: &mut String) -> Vec<Recording> {
    join_resumed(drop_copies(recs, out))
        .into_iter()
        .map(|(r, _)| r)
        .collect()
}

/// Drops recordings that are copies of one given earlier (the same bytes; compared only when
/// the run name, seed and eval costs match), with a note.
fn drop_copies(recs: Vec<Recording>, out: &mut String) -> Vec<Recording> {
    // The same numbers are not enough: runs are bit-identical by design (pipeline and
    // in-process, any worker count). A copy has the same bytes; they are read only for files
    // whose numbers match, and piecewise (see `same_bytes`).
    let mut kept: Vec<Recording> = Vec::new();
    for r in recs {
        let same_numbers = |k: &Recording| {
            k.name() == r.name()
                && k.run_info().map(|i| i.seed) == r.run_info().map(|i| i.seed)
                && !r.digest.points.is_empty()
                && same_curve(k, &r)
        };
        match kept
            .iter()
            .find(|k| same_numbers(k) && same_bytes(&k.path, &r.path))
        {
            Some(first) => {
                let _ = writeln!(
                    out,
                    "note: {} is a copy of {} (the same bytes): read once\n",
                    r.path.display(),
                    first.path.display()
                );
            }
            None => kept.push(r),
        }
    }
    kept
}

/// Whether two recordings have the same eval costs at the same updates, to the bit.
fn same_curve(a: &Recording, b: &Recording) -> bool {
    let (a, b) = (&a.digest.points, &b.digest.points);
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| (x.update, x.eval_cost.to_bits()) == (y.update, y.eval_cost.to_bits()))
}

/// Whether the files at `a` and `b` hold the same bytes; false if either cannot be read. They
/// are compared a block at a time: reading both whole took memory for twice a recording's size
/// (390 MB of RSS for a 176 MB T-ball recording and its copy, against 31 MB for analysing one).
fn same_bytes(a: &Path, b: &Path) -> bool {
    use std::io::Read as _;
    const BLOCK: u64 = 1 << 20;
    let (Ok(mut fa), Ok(mut fb)) = (std::fs::File::open(a), std::fs::File::open(b)) else {
        return false;
    };
    match (fa.metadata(), fb.metadata()) {
        (Ok(ma), Ok(mb)) if ma.len() == mb.len() => {}
        _ => return false,
    }
    let (mut xa, mut xb) = (Vec::new(), Vec::new());
    loop {
        xa.clear();
        xb.clear();
        match (
            (&mut fa).take(BLOCK).read_to_end(&mut xa),
            (&mut fb).take(BLOCK).read_to_end(&mut xb),
        ) {
            (Ok(0), Ok(0)) => return true,
            (Ok(_), Ok(_)) if xa == xb => {}
            _ => return false,
        }
    }
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
         only, has not converged (\"–\"). Means are over the sessions that converged.\n"
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

    fn rec_with(costs: &[f64], change: Option<u64>) -> Recording {
        let mut r = Recording::default();
        if let Some(u) = change {
            let c = proto::TaskChange {
                update: u,
                ..Default::default()
            };
            r.digest.add_task_change(&c);
            r.task_changes.push(c);
        }
        for (u, c) in costs.iter().enumerate() {
            r.digest.add_update(&proto::Update {
                update: u as u64,
                eval_cost: *c,
                lambda: 1.0,
                ..Default::default()
            });
        }
        r
    }

    /// The tick labels of an SVG plotters wrote (the text of its <text> elements).
    fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| {
                Some(
                    t.split_once('>')?
                        .1
                        .split_once("</text>")?
                        .0
                        .trim()
                        .to_string(),
                )
            })
            .collect()
    }

    /// A run whose cost falls from 80 to 0.05 was a flat line after update 2 on the linear cost
    /// axis, and the update axis was labelled `0.0, 5.0` (found by a user test of the README):
    /// the cost axis is logarithmic, says so, and integer ticks have no decimals.
    #[test]
    fn learning_curve_of_costs_over_three_decades_has_a_log_axis_and_plain_ticks() {
        let costs: Vec<f64> = (0..30).map(|u| 80.0 * 0.78f64.powi(u)).collect();
        let mut r = Recording::default();
        for (u, c) in costs.iter().enumerate() {
            r.digest.add_update(&proto::Update {
                update: u as u64,
                eval_cost: *c,
                exploration_cost_mean: 1.05 * c,
                exploration_cost_std: 0.5 * c,
                lambda: 10f64.powi(u as i32 % 5),
                ..Default::default()
            });
        }
        let dir = std::env::temp_dir().join(format!("lc-log-{}", std::process::id()));
        let files = plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(&files[0]).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let texts = svg_texts(&svg);
        assert!(texts.iter().any(|t| t == "cost (log)"), "{texts:?}");
        for t in &texts {
            assert!(!t.ends_with(".0") && t != "-0", "tick label {t}: {texts:?}");
        }
        assert!(texts.iter().any(|t| t == "10000"), "{texts:?}");
        // Costs within two decades keep a linear axis.
        let r = rec_with(&[5.0, 4.0, 3.0], None);
        let files = plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(&files[0]).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(!svg_texts(&svg).iter().any(|t| t == "cost (log)"));
    }

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
    fn the_timeline_holds_the_last_timed_updates_in_start_order() {
        let mut r = Recording::default();
        for u in 0..5u64 {
            for k in 0..2u32 {
                r.digest.add_rollout(&proto::Rollout {
                    update: u,
                    rollout: k,
                    worker: format!("worker-{k}"),
                    start_ns: 1_000 * u + 10 * u64::from(1 - k) + 1,
                    end_ns: 1_000 * u + 500,
                    ..Default::default()
                });
            }
        }
        // An untimed rollout (a worker that does not stamp, before any arrival) is left out.
        r.digest.add_rollout(&proto::Rollout {
            update: 5,
            ..Default::default()
        });
        let bars = timeline(&r, 2);
        let got: Vec<(u64, u32, &str)> = bars
            .iter()
            .map(|b| (b.update, b.rollout, b.worker.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (3, 1, "worker-1"),
                (3, 0, "worker-0"),
                (4, 1, "worker-1"),
                (4, 0, "worker-0")
            ]
        );
        assert_eq!(timeline(&r, 100).len(), 10);
        assert!(timeline(&Recording::default(), 10).is_empty());
    }

    /// A recording without updates gets no figures (they were empty axes) and says so; one
    /// of a single update gets that update drawn (a line through one point was invisible).
    #[test]
    fn a_recording_of_0_or_1_update_has_no_empty_figures() {
        let dir = std::env::temp_dir().join(format!("pi2cma-0-1-updates-{}", std::process::id()));
        let mut none = rec_with(&[], None);
        none.run.push(proto::RunInfo::default());
        assert!(plot(&none, &dir.join("none")).unwrap().is_empty());
        assert!(!dir.join("none").exists());
        let report = experiment(&[none], Some(&dir), 0.05, true, false).unwrap();
        assert!(
            report.table.contains("mean_curves.svg not drawn"),
            "{}",
            report.table
        );
        assert!(!dir.join("mean_curves.svg").exists());

        let mut one = rec_with(&[3.0], None);
        one.run.push(proto::RunInfo::default());
        let files = plot(&one, &dir.join("one")).unwrap();
        assert!(files.iter().any(|f| f.ends_with("learning_curve.svg")));
        let svg = std::fs::read_to_string(dir.join("one/learning_curve.svg")).unwrap();
        // The eval cost and λ as dots, the exploration band as a bar with its dot.
        assert_eq!(svg.matches("<circle").count(), 3, "{svg}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// λ rising again after a task change is what the figure is for: the change is marked on
    /// the λ panel as well as on the cost panel.
    #[test]
    fn a_task_change_is_marked_on_both_panels_of_the_learning_curve() {
        let mut r = rec_with(&[5.0, 4.0, 3.0, 2.0, 6.0, 5.0], Some(4));
        r.run.push(proto::RunInfo::default());
        let dir = std::env::temp_dir().join(format!("pi2cma-marks-{}", std::process::id()));
        plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(dir.join("learning_curve.svg")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // Dashes are short vertical polylines at one x; the panels split at 62 % of the height.
        let height: f64 = svg
            .split_once("height=\"")
            .and_then(|(_, t)| t.split('"').next()?.parse().ok())
            .expect("an svg height");
        let mut dash_ys = Vec::new();
        for p in svg.split("<polyline").skip(1) {
            let Some((_, pts)) = p.split_once("points=\"") else {
                continue;
            };
            let pts: Vec<(f64, f64)> = pts
                .split('"')
                .next()
                .unwrap_or("")
                .split_whitespace()
                .filter_map(|xy| {
                    let (x, y) = xy.split_once(',')?;
                    Some((x.parse().ok()?, y.parse().ok()?))
                })
                .collect();
            if pts.len() == 2
                && pts[0].0 == pts[1].0
                && pts[0].1 != pts[1].1
                && p.contains("opacity=\"0.6")
            {
                dash_ys.push(pts[0].1);
            }
        }
        let split = height * 0.62;
        assert!(
            dash_ys.iter().any(|y| *y < split),
            "no dash on the cost panel: {dash_ys:?}"
        );
        assert!(
            dash_ys.iter().any(|y| *y > split),
            "no dash on the λ panel: {dash_ys:?}"
        );
    }

    /// The first update after a task change is marked by a red ellipse; with λ small there it
    /// was under a pixel. It is drawn at least MIN_CHANGE_ELLIPSE_PIXELS in half-axis.
    #[test]
    fn the_ellipse_after_a_task_change_stays_visible_when_lambda_is_small() {
        let mut r = Recording::default();
        r.run.push(proto::RunInfo {
            dim: 2,
            ..Default::default()
        });
        let change = proto::TaskChange {
            update: 3,
            ..Default::default()
        };
        r.digest.add_task_change(&change);
        r.task_changes.push(change);
        let d = |m: f64, var: f64| proto::Distribution {
            dim: 2,
            mean: vec![m, -m],
            covariance: vec![var, 0.0, 0.0, var],
        };
        for u in 0..6u64 {
            // Converged before the change: a variance of 1e-12 against 1 at the start.
            let var = if u < 2 { 1.0 } else { 1e-12 };
            r.digest.add_update(&proto::Update {
                update: u,
                dim: 2,
                before: Some(d(u as f64, var)),
                after: Some(d(u as f64 + 1.0, var)),
                ..Default::default()
            });
        }
        let dir = std::env::temp_dir().join(format!("pi2cma-red-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("distribution.svg");
        plot_ellipses(&r, &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let red = svg
            .split("<polyline")
            .find(|p| p.contains("stroke=\"#D62728\""))
            .expect("a red ellipse");
        let pts: Vec<(f64, f64)> = red
            .split("points=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .split_whitespace()
            .filter_map(|p| {
                let (x, y) = p.split_once(',')?;
                Some((x.parse().ok()?, y.parse().ok()?))
            })
            .collect();
        let span = |f: fn(&(f64, f64)) -> f64| {
            let v: Vec<f64> = pts.iter().map(f).collect();
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        // Whole pixels: 2 × 6 px across, give or take the rounding of each end.
        assert!(span(|p| p.0) >= 10.0 && span(|p| p.1) >= 10.0, "{red}");
    }

    /// Rollouts of a microsecond on a timeline of milliseconds (pipelined via-point runs): every
    /// update still has its bars, at least a pixel wide.
    #[test]
    fn the_timeline_draws_every_rollout_however_short() {
        let mut r = Recording::default();
        for u in 0..10u64 {
            for k in 0..15u32 {
                let start = 1_000_000 + 100_000 * u + 600 * u64::from(k);
                r.digest.add_rollout(&proto::Rollout {
                    update: u,
                    rollout: k,
                    worker: format!("worker-{}", k % 3),
                    start_ns: start,
                    end_ns: start + 250,
                    ..Default::default()
                });
            }
        }
        let dir = std::env::temp_dir().join(format!("pi2cma-timeline-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("worker_timeline.svg");
        plot_worker_timeline(&r, &timeline(&r, 10), &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // The bars are the filled rectangles other than the background, the legend's box and
        // its 12 × 8 swatches.
        let widths: Vec<u32> = svg
            .split("<rect ")
            .skip(1)
            .filter(|r| {
                ![
                    "fill=\"#FFFFFF\"",
                    "fill=\"none\"",
                    "width=\"12\" height=\"8\"",
                ]
                .iter()
                .any(|not_a_bar| r.contains(not_a_bar))
            })
            .filter_map(|r| {
                let w = r.split("width=\"").nth(1)?.split('"').next()?;
                w.parse().ok()
            })
            .collect();
        assert_eq!(widths.len(), 150, "{svg}");
        assert!(widths.iter().all(|w| *w >= 1), "bars 0 px wide: {widths:?}");
    }

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
    fn files_are_the_same_bytes_only_to_the_last_byte() {
        let dir = std::env::temp_dir().join(format!("pi2cma-same-bytes-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let data: Vec<u8> = (0..(3 << 20) + 17).map(|i| (i % 251) as u8).collect();
        let write = |name: &str, bytes: &[u8]| {
            let p = dir.join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        let a = write("a", &data);
        let copy = write("copy", &data);
        let mut changed = data.clone();
        *changed.last_mut().unwrap() ^= 1;
        let last_byte = write("last-byte", &changed);
        let shorter = write("shorter", &data[..data.len() - 1]);
        let empty = write("empty", &[]);
        assert!(same_bytes(&a, &copy));
        assert!(!same_bytes(&a, &last_byte));
        assert!(!same_bytes(&a, &shorter));
        assert!(same_bytes(&empty, &write("empty-too", &[])));
        assert!(!same_bytes(&a, &dir.join("absent")));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `analyze --no-csv` writes no CSV file, the experiment's included.
    #[test]
    fn no_csv_holds_for_the_experiments_files_too() {
        let dir = std::env::temp_dir().join(format!("pi2cma-no-csv-{}", std::process::id()));
        let mut files = Vec::new();
        std::fs::create_dir_all(&dir).unwrap();
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(3);
        for seed in 1..=2 {
            let f = dir.join(format!("s{seed}.mcap"));
            let mut rec = crate::McapRecorder::create(&f).unwrap();
            session::run_session(&cfg, seed, &mut rec).unwrap();
            rec.finish().unwrap();
            files.push(f);
        }
        let out = dir.join("analysis");
        let args = |no_csv| AnalyzeArgs {
            files: files.clone(),
            out: Some(out.clone()),
            no_csv,
            no_plots: true,
            verify: false,
            tolerance: 0.05,
        };
        let csv_files = || {
            let mut found = Vec::new();
            for d in [out.clone(), out.join("s1"), out.join("s2")] {
                for e in std::fs::read_dir(d).into_iter().flatten().flatten() {
                    if e.path().extension().is_some_and(|x| x == "csv") {
                        found.push(e.path());
                    }
                }
            }
            found
        };
        run(&args(true), "mcap-tool").unwrap();
        assert_eq!(csv_files(), Vec::<PathBuf>::new());
        assert!(out.join("reconvergence.md").is_file());
        run(&args(false), "mcap-tool").unwrap();
        assert!(out.join("mean_curves.csv").is_file() && out.join("reconvergence.csv").is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `analyze --verify --out` streams the file twice: once read and recomputed, once for the
    /// CSV files (a 175 MB T-ball recording takes about 0.1 s of CPU per pass). It streamed it a
    /// third time, for `--verify` alone.
    #[test]
    fn verify_and_the_csv_files_stream_the_file_twice() {
        let dir = std::env::temp_dir().join(format!("h3-one-pass-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(3);
        let file = dir.join("run.mcap");
        let mut rec = crate::McapRecorder::create(&file).unwrap();
        session::run_session(&cfg, 1, &mut rec).unwrap();
        rec.finish().unwrap();
        let args = AnalyzeArgs {
            files: vec![file],
            out: Some(dir.join("analysis")),
            no_csv: false,
            no_plots: true,
            verify: true,
            tolerance: 0.05,
        };
        let streams = || crate::reader::STREAMS.with(std::cell::Cell::get);
        let before = streams();
        let text = run(&args, "mcap-tool").unwrap();
        assert_eq!(streams() - before, 2, "{text}");
        assert!(
            text.contains("  recompute: 3 updates, 0 mismatches (bit-identical)\n"),
            "{text}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn tolerances_outside_0_to_1_are_refused() {
        assert_eq!(parse_tolerance("0.05"), Ok(0.05));
        assert_eq!(parse_tolerance("0"), Ok(0.0));
        for bad in ["nan", "-1", "inf", "1", "x"] {
            assert!(parse_tolerance(bad).unwrap_err().starts_with(bad), "{bad}");
        }
    }

    #[test]
    fn curves_break_where_updates_are_missing() {
        assert_eq!(contiguous(&[]), Vec::<std::ops::Range<usize>>::new());
        let whole = contiguous(&[0.0, 1.0, 2.0]);
        assert_eq!((whole.len(), whole[0].clone()), (1, 0..3));
        assert_eq!(contiguous(&[0.0, 1.0, 4.0, 5.0, 9.0]), [0..2, 2..4, 4..5]);
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
        let mut rec = crate::McapRecorder::create(&first).unwrap();
        session::run_session(&cfg, 1, &mut rec).unwrap();
        rec.finish().unwrap();
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
        std::fs::remove_file(&first).unwrap();
        let said = info(&b);
        assert!(
            said.contains("is not there to tell which updates are missing"),
            "{said}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
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
    fn output_directories_never_collide() {
        let files = [
            Path::new("a/run.mcap"),
            Path::new("b/run.mcap"),
            Path::new("x/c/run.mcap"),
            Path::new("y/c/run.mcap"),
            Path::new("t.mcap"),
        ];
        assert_eq!(
            output_dirs(&files),
            ["a-run", "b-run", "c-run-1", "c-run-2", "t"]
        );
        // A stem that numbering produces too.
        let files = [
            Path::new("x/a/run.mcap"),
            Path::new("y/a/run.mcap"),
            Path::new("a-run-1.mcap"),
        ];
        let dirs = output_dirs(&files);
        assert_eq!(dirs, ["a-run-1", "a-run-2", "a-run-1-2"]);
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

    #[test]
    fn ellipse_axes_follow_the_eigenvectors() {
        // Σ = diag(4, 1): 2σ half-axes 4 along x and 2 along y.
        let pts = ellipse([1.0, 2.0], [[4.0, 0.0], [0.0, 1.0]]);
        let maxx = pts.iter().map(|p| p.0).fold(f64::MIN, f64::max);
        let maxy = pts.iter().map(|p| p.1).fold(f64::MIN, f64::max);
        assert!(
            (maxx - 5.0).abs() < 1e-9 && (maxy - 4.0).abs() < 1e-2,
            "{maxx} {maxy}"
        );
        // A rotated one: Σ with eigenvalues 3 and 1 along (1,1)/√2 and (1,−1)/√2.
        let pts = ellipse([0.0, 0.0], [[2.0, 1.0], [1.0, 2.0]]);
        let far = pts
            .iter()
            .max_by(|a, b| (a.0 * a.0 + a.1 * a.1).total_cmp(&(b.0 * b.0 + b.1 * b.1)))
            .copied()
            .unwrap();
        assert!((far.0.abs() - far.1.abs()).abs() < 1e-9, "{far:?}");
        assert!(((far.0 * far.0 + far.1 * far.1).sqrt() - 2.0 * 3f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn csv_fields_are_quoted_and_floats_exact() {
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
        let v = 0.1 + 0.2;
        assert_eq!(f(v).parse::<f64>().unwrap().to_bits(), v.to_bits());
    }
}
