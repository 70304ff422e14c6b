//! Post-hoc analysis of one or many recordings: an info summary, CSV per topic, SVG figures
//! (learning curve with ±std band and λ on a log axis, distribution ellipses for 2-D policies,
//! per-worker rollout time), and over the sessions of an experiment: mean curves and a
//! re-convergence table.
//!
//! Entry point for command lines: [`AnalyzeArgs`] + [`run`].
//!
//! The command is here; what it does is in the submodules: `info` (the summary), `csv` (a CSV
//! file per topic), `figures` (the SVG figures of one run), `runs` (which of the files given
//! are copies, and which are one run's) and `experiment` (mean curves and the re-convergence
//! table over sessions).

mod csv;
mod experiment;
mod figures;
mod info;
mod runs;
#[cfg(test)]
mod test_support;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::recompute::read_and_verify;
use crate::{join_resumed, read_recording_slim, RecordError, Recording};
pub use csv::export_csv;
pub use experiment::{experiment, reconvergence, ExperimentReport, Segment};
pub use figures::{plot, NOTHING_TO_PLOT};
pub use info::{info, info_for, missing_before_restart};
use info::{missing_updates, why_missing};
use runs::drop_copies;
pub use runs::join_runs;

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
    #[arg(long, default_value_t = 0.05, value_parser = parse_tolerance, allow_negative_numbers = true)]
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

#[cfg(test)]
mod tests {
    use super::*;

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
            crate::testing::record_session(&cfg, seed, &f);
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
        // Without --no-csv, every directory searched above holds CSVs: the check above would
        // pass vacuously if the runs' files went elsewhere.
        let written = csv_files();
        for d in [out.clone(), out.join("s1"), out.join("s2")] {
            assert!(
                written.iter().any(|f| f.parent() == Some(d.as_path())),
                "no CSV in {d:?}: {written:?}"
            );
        }
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
        crate::testing::record_session(&cfg, 1, &file);
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
}
