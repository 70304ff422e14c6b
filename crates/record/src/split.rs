//! A run's recording as one file, or as a series of parts of bounded size (`recording.split_mb`):
//! a continual run that learns for days then leaves finished, indexed files that any tool opens,
//! instead of one file that grows without end and is indexed only when the run stops. The first
//! part is the file asked for; part n ≥ 2 is `<stem>.part-<n>.mcap` beside it. Each part is a
//! recording of its own — its `/run` names the update it begins at and the distribution that
//! update samples from — so every part verifies by itself, and the parts join into one run
//! ([`crate::join_resumed`]) as a resumed run's files do.

use std::path::{Path, PathBuf};

use pi2cma::Hyperparameters;

use crate::writer::{FileSink, RunStart, RunWriter, UpdateData};
use crate::{Event, RecordError};

/// Part `n` (≥ 2) of the split recording whose first part is `first`.
pub fn part_path(first: &Path, n: u32) -> PathBuf {
    let stem = first
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    first.with_file_name(format!("{stem}.part-{n}.mcap"))
}

/// Part `n` of the recording whose first part is `first`: `first` itself for n = 1.
pub fn part_path_or_first(first: &Path, n: u32) -> PathBuf {
    match n {
        0 | 1 => first.to_path_buf(),
        n => part_path(first, n),
    }
}

/// The stem and number of a part after the first: `<stem>.part-<n>.mcap`, n ≥ 2.
fn part_of(path: &Path) -> Option<(String, u32)> {
    let name = path.file_name()?.to_string_lossy().into_owned();
    let (stem, n) = name.strip_suffix(".mcap")?.rsplit_once(".part-")?;
    let n = n.parse::<u32>().ok().filter(|&n| n >= 2)?;
    Some((stem.to_string(), n))
}

/// The number of the part `path` is (1 for a first part).
pub fn part_number(path: &Path) -> u32 {
    part_of(path).map_or(1, |(_, n)| n)
}

/// The first part of the recording `path` belongs to (`path` itself unless it is a part).
pub fn first_part(path: &Path) -> PathBuf {
    match part_of(path) {
        Some((stem, _)) => path.with_file_name(format!("{stem}.mcap")),
        None => path.to_path_buf(),
    }
}

/// Every part of the recording whose first part is `first`, in order: `first` (there or not),
/// then each `<stem>.part-<n>.mcap` beside it, n ≥ 2, by n. Parts may be missing in between:
/// during a run of days, earlier parts are archived or deleted to free the disk while the
/// recorder writes the newest. Stopping at the first missing part made the part being written
/// invisible: a restarted recorder began again at a low part number (truncating an existing
/// part when it got there), `--resume` went on from an early update, and a new recording to the
/// path did not see the parts it would later overwrite.
pub fn recording_parts(first: &Path) -> Vec<PathBuf> {
    let mut parts = vec![first.to_path_buf()];
    let Some(stem) = first.file_stem().map(|s| s.to_string_lossy().into_owned()) else {
        return parts;
    };
    let dir = match first.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return parts;
    };
    let mut found: Vec<u32> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name();
            let (s, n) = part_of(Path::new(&name))?;
            // Only the name `part_path` gives (`part-2`, not `part-02`), so that every part
            // listed is the file `part_path` names for its number.
            (s == stem && part_path(first, n).file_name() == Some(name.as_os_str())).then_some(n)
        })
        .collect();
    found.sort_unstable();
    parts.extend(found.into_iter().map(|n| part_path(first, n)));
    parts
}

/// The parts of [`recording_parts`] that are there: a first part moved away during the run is
/// not named in a command to run on them. `first` if none is.
fn parts_there(first: &Path) -> Vec<PathBuf> {
    let parts: Vec<PathBuf> = recording_parts(first)
        .into_iter()
        .filter(|p| p.exists())
        .collect();
    if parts.is_empty() {
        vec![first.to_path_buf()]
    } else {
        parts
    }
}

/// The parts of [`parts_there`] from the last gap in their numbers on: the ones `analyze` takes
/// together (it refuses parts given across a gap).
fn parts_after_the_last_gap(first: &Path) -> Vec<PathBuf> {
    let mut parts = parts_there(first);
    let numbers: Vec<u32> = parts.iter().map(|p| part_number(p)).collect();
    let from = (1..numbers.len())
        .rev()
        .find(|&i| numbers[i] != numbers[i - 1] + 1)
        .unwrap_or(0);
    parts.split_off(from)
}

/// The last part of the recording `path` (its first part or any other) belongs to: the one a run
/// goes on from, and the only one a killed writer can leave unfinished.
pub fn last_part(path: &Path) -> PathBuf {
    recording_parts(&first_part(path))
        .pop()
        .unwrap_or_else(|| path.to_path_buf())
}

/// The part of the recording `path` (any of its parts) that a killed writer left unfinished:
/// its last part holding anything (one created as the disk filled up holds none of the
/// updates), when that part has no summary section. `recover` completes it; `--resume` goes on
/// from it as it is. `None` for a finished recording, or one that is not there.
pub fn unfinished_part(path: &Path) -> Option<PathBuf> {
    let last = recording_parts(&first_part(path))
        .into_iter()
        .rev()
        .find(|p| p.is_file() && !crate::recover::holds_nothing(p).unwrap_or(false))?;
    (!crate::reader::has_summary(&last).unwrap_or(false)).then_some(last)
}

/// The `analyze` command line for a run's recording `first` (all its parts) that continues the
/// recordings `earlier` (all their parts, whichever one each names; oldest first, as
/// [`resumed_chain`] gives them): one learning curve from the run's very start. `pi2cma` is how
/// to call the `pi2cma` binary ([`program_name`]).
pub fn analyze_command(pi2cma: &str, first: &Path, earlier: &[PathBuf]) -> String {
    let mut files: Vec<String> = earlier
        .iter()
        .flat_map(|r| as_shell_words(&first_part(r)))
        .collect();
    files.extend(as_shell_words(first));
    format!("{pi2cma} analyze {}", files.join(" "))
}

/// More recordings back than this are not followed (files that name each other in a circle
/// are caught before; this bounds the reading).
const RESUMED_CHAIN_LIMIT: usize = 1000;

/// The recordings a run resumed from `resumed_from` continues, oldest first: `resumed_from`
/// and, back to the run's start, each one that the one after it resumed (its metadata
/// `resumed_from`, read from any of its parts there). A recording resumed from a run that was
/// itself resumed (day1 → day2 → day3) needs them all for the whole curve. When one named is
/// not there (moved or deleted) or cannot be read, the chain begins after it and the note says
/// so: the command then gives a curve that does not begin at the run's start.
pub fn resumed_chain(resumed_from: &Path) -> (Vec<PathBuf>, Option<String>) {
    let mut chain: Vec<PathBuf> = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    let mut next = Some(resumed_from.to_path_buf());
    // The run (name, seed) and first update of the recording last added.
    let mut later: Option<ChainLink> = None;
    while let Some(path) = next.take() {
        let named_by = chain.last().map_or_else(
            || "this run resumed".to_string(),
            |p| format!("{} resumed", p.display()),
        );
        let Some(there) = recording_parts(&first_part(&path))
            .into_iter()
            .find(|p| p.exists())
        else {
            chain.reverse();
            return (
                chain,
                Some(not_followed(&named_by, &path, "it is not there")),
            );
        };
        let key = there.canonicalize().unwrap_or_else(|_| there.clone());
        if !seen.insert(key) || chain.len() >= RESUMED_CHAIN_LIMIT {
            break;
        }
        let meta = match crate::read_run_metadata(&there) {
            Ok(meta) => meta,
            Err(e) => {
                chain.reverse();
                return (chain, Some(not_followed(&named_by, &path, &e.to_string())));
            }
        };
        // Recordings made before `resumed_from` was stored absolute name it as typed, which
        // read from another directory can be another run's file (every run's default is
        // runs/latest/run.mcap), or one a later run has overwritten: it must be the same run,
        // and begin before the recording that resumed it.
        let link = ChainLink {
            run: (meta.get("name").cloned(), meta.get("seed").cloned()),
            first: meta.get("first_update").and_then(|f| f.parse().ok()),
        };
        if let Some(l) = &later {
            if link.run != l.run || link.first.zip(l.first).is_some_and(|(f, l)| f >= l) {
                chain.reverse();
                return (
                    chain,
                    Some(not_followed(
                        &named_by,
                        &path,
                        "the file there now is another recording",
                    )),
                );
            }
        }
        next = meta.get("resumed_from").map(PathBuf::from);
        later = Some(link);
        chain.push(path);
    }
    chain.reverse();
    (chain, None)
}

/// What [`resumed_chain`] checks of a recording it follows: its run (name, seed, as its
/// metadata has them) and its first update.
struct ChainLink {
    run: (Option<String>, Option<String>),
    first: Option<u64>,
}

/// The note for an earlier recording of a resumed run's chain that is left out of the
/// `analyze` command.
fn not_followed(named_by: &str, path: &Path, why: &str) -> String {
    format!(
        "{named_by} {} ({why}): the command leaves it and what it resumed out, so its curve \
         begins later than the run; add them before the others, from where they are now, for \
         the whole curve",
        path.display()
    )
}

/// More parts than this are named by a pattern in a printed command (a day's run in 1 GB parts
/// has thousands: a command of kilobytes).
const PARTS_NAMED_ONE_BY_ONE: usize = 4;

/// The parts of `first` that `analyze` takes together ([`parts_after_the_last_gap`]), as a
/// shell names them: one by one, or, when they are many and are every part there (no earlier
/// ones before a gap that a pattern would take in too), the first file and
/// `<stem>.part-*.mcap` (`analyze` puts the parts in order itself).
fn as_shell_words(first: &Path) -> Vec<String> {
    let parts = parts_after_the_last_gap(first);
    let named = |ps: &[PathBuf]| ps.iter().map(|p| p.display().to_string()).collect();
    if parts.len() <= PARTS_NAMED_ONE_BY_ONE || parts != parts_there(first) {
        return named(&parts);
    }
    let pattern =
        part_path(first, 2)
            .display()
            .to_string()
            .replacen(".part-2.mcap", ".part-*.mcap", 1);
    let mut words: Vec<String> = named(&parts[..usize::from(parts[0] == first)]);
    words.push(pattern);
    words
}

/// How a printed command calls the program at `path` so that it works as printed: relative to
/// the working directory when under it, else the full path (`cargo run` leaves the binaries in
/// target/release, which is not on PATH).
pub fn program_name(path: &Path) -> String {
    std::env::current_dir()
        .ok()
        .and_then(|cwd| path.strip_prefix(cwd).ok())
        .unwrap_or(path)
        .display()
        .to_string()
}

/// A run name (`run.name`, free text) as a part of a file name: characters other than ASCII
/// letters, digits, `-`, `_` and `.` become `_`, so that a name is never a path (`a/b`).
pub fn file_name_part(run_name: &str) -> String {
    run_name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// How the binaries name a finished recording: `FILE`, or `FILE (split into n parts: FILE, …)`.
pub fn describe_parts(path: &Path) -> String {
    let parts = parts_there(path);
    if parts == [path] {
        return path.display().to_string();
    }
    let names = name_list(parts.iter().map(|p| p.display().to_string()).collect());
    let all = parts.last().map_or(1, |p| part_number(p)) as usize;
    let there = match parts.len() {
        n if n == all => String::new(),
        n => format!(", {n} of them there"),
    };
    format!(
        "{} (split into {all} parts{there}: {names})",
        path.display(),
    )
}

/// Files named in a message: every one, or when they are many the first two, `…` and the last.
pub(crate) fn name_list(mut names: Vec<String>) -> String {
    if names.len() > PARTS_NAMED_ONE_BY_ONE {
        names.drain(2..names.len() - 1);
        names.insert(2, "…".into());
    }
    names.join(", ")
}

/// Refuses to record at `path` (given by `option`, e.g. `--out`) when a recording is there: a
/// non-empty file, or the parts of an earlier split recording, which count even when its first
/// file has been moved away (a new recording would remove them). One message for every writer.
pub fn refuse_overwrite(path: &Path, option: &str) -> Result<(), RecordError> {
    fn looks_like_mcap(path: &Path) -> bool {
        use std::io::Read as _;
        let mut head = [0u8; 8];
        let n = std::fs::File::open(path)
            .and_then(|mut f| f.read(&mut head))
            .unwrap_or(0);
        crate::reader::could_be_mcap(&head[..n])
    }
    // Its length is the directory's, not a recording's.
    if path.is_dir() {
        return Err(RecordError::invalid(
            path,
            format!("is a directory ({option}); a recording is a file: give a file name"),
        ));
    }
    let first = std::fs::metadata(path)
        .ok()
        .filter(|m| m.len() > 0)
        .map(|m| m.len());
    let parts: Vec<String> = recording_parts(path)
        .iter()
        .skip(1)
        .map(|p| p.display().to_string())
        .collect();
    let (what, is, it) = match (first, parts.as_slice()) {
        (None, []) => return Ok(()),
        // Called a recording, a config given to `--record` by mistake read as a lost run.
        (Some(bytes), []) if !looks_like_mcap(path) => {
            return Err(RecordError::invalid(
                path,
                format!(
                    "is there already ({option}), a file of {bytes} bytes that is not a \
                     recording: a run records to a new file; give another name"
                ),
            ))
        }
        (Some(bytes), []) => (format!("a recording of {bytes} bytes"), "is", "it"),
        (Some(bytes), _) => (
            format!(
                "a recording of {bytes} bytes and its parts {}",
                parts.join(", ")
            ),
            "are",
            "them",
        ),
        (None, [one]) => (
            format!("the part {one} of an earlier recording"),
            "is",
            "it",
        ),
        (None, _) => (
            format!("the parts {} of an earlier recording", parts.join(", ")),
            "are",
            "them",
        ),
    };
    Err(RecordError::invalid(
        path,
        format!(
            "{what} {is} there already ({option}); a run does not overwrite a recording: remove \
             {it} or record elsewhere"
        ),
    ))
}

/// What every part's `/run` repeats.
#[derive(Debug, Clone)]
struct Run {
    name: String,
    seed: u64,
    steps: usize,
    hyperparameters: Hyperparameters,
    basis_activations: Option<Vec<f64>>,
    config_toml: String,
    executor: String,
    resumed_from: Option<String>,
    run_id: Option<u64>,
}

/// Writes a run's recording: [`RunWriter`]'s calls, and a new part once the current one holds
/// `split_mb` (see [`RunFiles::split_at_mb`]). A part is finished (indexed) when the update
/// after its last arrives; the new part begins with that update, and with the task changes
/// written for it.
pub struct RunFiles {
    writer: Option<RunWriter<FileSink>>,
    first: PathBuf,
    part: u32,
    split_bytes: Option<u64>,
    run: Option<Run>,
    /// Whether the part was full after the last update: the next update begins a new part.
    full: bool,
    /// Task changes written while `full`: they come before the next update, so they belong to
    /// the part that begins with it.
    pending_changes: Vec<(u64, String, f64)>,
    /// A restarted recorder's part ([`RunFiles::continue_in_part`]) is created by
    /// [`RunFiles::write_start`], not before.
    create_at_start: bool,
    /// The settings the last update written ran with: the next part's `/run` names them as
    /// what the update before its first ran with.
    last_settings: Vec<(String, f64)>,
    /// [`RunFiles::hold_output`]: for every part's writer.
    held: bool,
    /// [`RunFiles::record_step_costs`]: for every part's writer.
    step_costs: bool,
}

impl RunFiles {
    /// Creates (truncates) `path`, the first part. Parts that an earlier recording to the same
    /// path left are removed: they continued the file just overwritten.
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        // A recording in progress is refused before anything of it is touched: its writer
        // holds only the part it is writing, which need not be the first (whose lock
        // `RunWriter::create` tries below).
        let parts = recording_parts(path);
        if let Some(live) = parts.iter().skip(1).find(|p| crate::being_written(p)) {
            return Err(RecordError::written_elsewhere(live));
        }
        // Taken before the stale parts go, so that no other writer starts in between.
        let writer = RunWriter::create(path)?;
        for stale in parts.into_iter().skip(1) {
            std::fs::remove_file(&stale).map_err(|e| RecordError::io(&stale, e))?;
        }
        Ok(Self {
            writer: Some(writer),
            first: path.to_path_buf(),
            part: 1,
            split_bytes: None,
            run: None,
            full: false,
            pending_changes: Vec::new(),
            create_at_start: false,
            last_settings: Vec::new(),
            held: false,
            step_costs: true,
        })
    }

    /// Goes on with the recording whose first part is `first` in part `part` (≥ 2), which must
    /// not exist yet: the parts before it stay as they are (a restarted recorder's predecessor
    /// left them; the supervisor recovers the unfinished one). The part is created with its
    /// `/run` ([`RunFiles::write_start`]): a recorder that ends or dies before then leaves no
    /// part without one, which neither `--resume` nor the joined analysis could read, and whose
    /// empty file no recovery completes (the next restarted recorder takes the same part).
    pub fn continue_in_part(first: &Path, part: u32) -> Result<Self, RecordError> {
        if part < 2 {
            return Err(RecordError::invalid(
                first.to_path_buf(),
                format!("a recording goes on in part 2 or later, not in part {part}"),
            ));
        }
        let path = part_path(first, part);
        if path.exists() {
            return Err(RecordError::invalid(
                path,
                "is there already: a restarted recorder begins a new part",
            ));
        }
        Ok(Self {
            writer: None,
            first: first.to_path_buf(),
            part,
            split_bytes: None,
            run: None,
            full: false,
            pending_changes: Vec::new(),
            create_at_start: true,
            last_settings: Vec::new(),
            held: false,
            step_costs: true,
        })
    }

    /// Splits into parts of about `mb` MB of messages before compression (`recording.split_mb`);
    /// `None`: one file.
    pub fn split_at_mb(&mut self, mb: Option<u64>) {
        self.split_bytes = mb.map(|mb| mb.saturating_mul(1 << 20));
    }

    /// As [`RunWriter::hold_output`], for this part and the ones after it: updates reach the
    /// OS at [`RunFiles::flush`] (or when their part is finished).
    pub fn hold_output(&mut self) {
        self.held = true;
        if let Some(w) = &mut self.writer {
            w.hold_output();
        }
    }

    /// As [`RunWriter::record_step_costs`], for this part and the ones after it.
    pub fn record_step_costs(&mut self, on: bool) {
        self.step_costs = on;
        if let Some(w) = &mut self.writer {
            w.record_step_costs(on);
        }
    }

    /// A part's writer, holding its output if [`RunFiles::hold_output`] said so.
    fn create_part(&self, path: &Path) -> Result<RunWriter<FileSink>, RecordError> {
        let mut w = RunWriter::create(path)?;
        if self.held {
            w.hold_output();
        }
        w.record_step_costs(self.step_costs);
        Ok(w)
    }

    fn writer(&mut self) -> Result<&mut RunWriter<FileSink>, RecordError> {
        self.writer
            .as_mut()
            .ok_or_else(|| RecordError::invalid(self.first.clone(), "the writer has failed"))
    }

    /// The part being written.
    fn file(&self) -> PathBuf {
        part_path_or_first(&self.first, self.part)
    }

    pub fn write_start(&mut self, start: &RunStart<'_>) -> Result<(), RecordError> {
        self.run = Some(Run {
            name: start.name.to_string(),
            seed: start.seed,
            steps: start.steps,
            hyperparameters: start.hyperparameters.clone(),
            basis_activations: start.basis_activations.map(<[f64]>::to_vec),
            config_toml: start.config_toml.to_string(),
            executor: start.executor.to_string(),
            resumed_from: start.resumed_from.map(str::to_string),
            run_id: start.run_id,
        });
        if std::mem::take(&mut self.create_at_start) {
            let path = self.file();
            if path.exists() {
                return Err(RecordError::invalid(
                    path,
                    "is there already: a restarted recorder begins a new part",
                ));
            }
            self.writer = Some(self.create_part(&path)?);
        }
        match (self.part, start.part) {
            // A restarted recorder's part names the one its predecessor left.
            (n @ 2.., None) => {
                let previous = part_path_or_first(&self.first, n - 1).display().to_string();
                self.writer()?.write_start(&RunStart {
                    part: Some((n, &previous)),
                    ..*start
                })
            }
            _ => self.writer()?.write_start(start),
        }
    }

    /// As [`RunWriter::write_update`], into a new part first if the current one is full;
    /// returns the new part's file if it began one.
    pub fn write_update(&mut self, u: &UpdateData<'_>) -> Result<Option<PathBuf>, RecordError> {
        let begun = if std::mem::take(&mut self.full) {
            self.next_part(u)?
        } else {
            None
        };
        self.writer()?.write_update(u)?;
        self.last_settings = u
            .task_settings
            .iter()
            .map(|(n, v)| (n.to_string(), *v))
            .collect();
        // Decided here, after the update, so that what comes before the next one (its task
        // changes) knows which part it belongs to.
        self.full = self.split_bytes.is_some_and(|max| {
            self.writer
                .as_ref()
                .is_some_and(|w| w.bytes_written() >= max)
        });
        Ok(begun)
    }

    /// Finishes the current part and starts the next with `u`'s update: its `/run` holds the
    /// distribution `u` samples from and the settings it runs with.
    fn next_part(&mut self, u: &UpdateData<'_>) -> Result<Option<PathBuf>, RecordError> {
        let Some(run) = self.run.clone() else {
            return Ok(None);
        };
        let previous = self.file();
        if let Some(w) = self.writer.take() {
            w.finish()?;
        }
        self.part += 1;
        let path = self.file();
        let mut w = self.create_part(&path)?;
        let previous = previous.display().to_string();
        let ran_before: Vec<(&str, f64)> = self
            .last_settings
            .iter()
            .map(|(n, v)| (n.as_str(), *v))
            .collect();
        w.write_start(&RunStart {
            name: &run.name,
            seed: run.seed,
            update: u.summary.update,
            steps: run.steps,
            hyperparameters: &run.hyperparameters,
            initial: u.before,
            basis_activations: run.basis_activations.as_deref(),
            config_toml: &run.config_toml,
            executor: &run.executor,
            task_settings: u.task_settings,
            previous_task_settings: &ran_before,
            resumed_from: run.resumed_from.as_deref(),
            part: Some((self.part, &previous)),
            run_id: run.run_id,
            recorder_restart: None,
        })?;
        w.write_event(
            u.summary.update,
            Event::Info,
            "recorder",
            std::process::id(),
            &format!(
                "part {} of the recording; updates before {} are in {previous} and the parts before it",
                self.part, u.summary.update
            ),
        )?;
        for (update, name, value) in self.pending_changes.drain(..) {
            w.write_task_change(update, &name, value)?;
        }
        self.writer = Some(w);
        Ok(Some(path))
    }

    pub fn write_task_change(
        &mut self,
        update: u64,
        name: &str,
        value: f64,
    ) -> Result<(), RecordError> {
        if self.full && self.run.is_some() {
            self.pending_changes.push((update, name.to_string(), value));
            return Ok(());
        }
        self.writer()?.write_task_change(update, name, value)
    }

    /// As [`RunWriter::write_unfinished_update`], into the part being written: the update it
    /// names comes after that part's last.
    pub fn write_unfinished_update(
        &mut self,
        update: u64,
        task_settings: &[(&str, f64)],
        not_begun: bool,
    ) -> Result<(), RecordError> {
        self.writer()?
            .write_unfinished_update(update, task_settings, not_begun)
    }

    pub fn write_event(
        &mut self,
        update: u64,
        event: Event,
        name: &str,
        pid: u32,
        message: &str,
    ) -> Result<(), RecordError> {
        self.writer()?
            .write_event(update, event, name, pid, message)
    }

    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.writer()?.flush()
    }

    /// Bytes of messages not yet flushed, before compression (see [`RunFiles::hold_output`]).
    pub fn held_bytes(&self) -> u64 {
        self.writer.as_ref().map_or(0, RunWriter::held_bytes)
    }

    /// Whether there is a part being written: not for a restarted recorder's part before its
    /// `/run` ([`RunFiles::continue_in_part`]).
    pub fn has_part(&self) -> bool {
        !self.create_at_start
    }

    /// Finishes the part being written; the earlier ones were finished when they filled.
    pub fn finish(mut self) -> Result<(), RecordError> {
        match self.writer.take() {
            Some(mut w) => {
                // No update came after them: they stay with the last one.
                for (update, name, value) in self.pending_changes.drain(..) {
                    w.write_task_change(update, &name, value)?;
                }
                w.finish().map(|_| ())
            }
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{join_resumed, read_recording, recompute::verify, Recording};

    #[test]
    fn a_recording_goes_on_only_in_a_new_part_after_the_first() {
        let dir = std::env::temp_dir().join(format!("split-continue-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("r.mcap");
        assert_eq!(part_number(&first), 1);
        assert_eq!(part_number(&part_path(&first, 3)), 3);
        assert_eq!(part_path_or_first(&first, 1), first);
        assert!(RunFiles::continue_in_part(&first, 1).is_err());
        // Ended before its `/run`: no part without one is left.
        let files = RunFiles::continue_in_part(&first, 2).unwrap();
        assert!(!files.has_part());
        files.finish().unwrap();
        assert!(!part_path(&first, 2).exists() && !first.exists());
        std::fs::write(part_path(&first, 2), b"").unwrap();
        let again = RunFiles::continue_in_part(&first, 2)
            .err()
            .unwrap()
            .to_string();
        assert!(again.contains("is there already"), "{again}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The refusal's verb and pronoun follow what is there: "the parts a, b of an earlier
    /// recording is there already: remove it" said one thing of two files.
    #[test]
    fn a_refusal_names_what_is_there_in_its_number() {
        let dir = std::env::temp_dir().join(format!("split-refuse-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("r.mcap");
        // Each file is added to those before it.
        for (file, said) in [
            (
                part_path(&first, 2),
                "r.part-2.mcap of an earlier recording is",
            ),
            (
                part_path(&first, 3),
                "r.part-3.mcap of an earlier recording are",
            ),
            (first.clone(), "r.part-3.mcap are"),
        ] {
            std::fs::write(&file, b"x").unwrap();
            let e = refuse_overwrite(&first, "--record")
                .unwrap_err()
                .to_string();
            let it = if said.ends_with("is") { "it" } else { "them" };
            let expected = format!(
                "{said} there already (--record); a run does not overwrite a recording: remove \
                 {it} or record elsewhere"
            );
            assert!(e.contains(&expected), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_there_that_is_no_recording_is_not_called_one() {
        let dir = std::env::temp_dir().join(format!("split-not-mcap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let config = dir.join("A1.toml");
        std::fs::write(&config, session::DEFAULT_CONFIG).unwrap();
        let e = refuse_overwrite(&config, "--record")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "{}: is there already (--record), a file of {} bytes that is not a recording: a \
                 run records to a new file; give another name",
                config.display(),
                session::DEFAULT_CONFIG.len()
            )
        );
        // A recording is called one.
        let recording = dir.join("r.mcap");
        record(&recording, 1, None);
        let e = refuse_overwrite(&recording, "--record")
            .unwrap_err()
            .to_string();
        assert!(e.contains(": a recording of "), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// What `analyze FILES` prints (no output files), or its error.
    fn analyze_summaries(files: &[PathBuf]) -> Result<String, RecordError> {
        crate::analyze::run(
            &crate::analyze::AnalyzeArgs {
                files: files.to_vec(),
                out: None,
                no_csv: true,
                no_plots: true,
                verify: false,
                tolerance: 0.05,
            },
            "mcap-tool",
        )
    }

    #[test]
    fn a_directory_given_for_a_recording_is_named_as_one() {
        let dir = std::env::temp_dir().join(format!("split-dir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let e = refuse_overwrite(&dir, "--out").unwrap_err().to_string();
        assert!(e.contains("is a directory (--out)"), "{e}");
        assert!(!e.contains("a recording of"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_split_recording_being_written_is_left_whole() {
        let dir = std::env::temp_dir().join(format!("split-live-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("x.mcap");
        std::fs::write(&first, b"a finished first part").unwrap();
        // Part 2 is the one its recorder is writing (it holds only that part's lock).
        let live = crate::RunWriter::create(&part_path(&first, 2)).unwrap();
        let e = RunFiles::create(&first).err().unwrap().to_string();
        assert!(
            e.contains("x.part-2.mcap") && e.contains("being written"),
            "{e}"
        );
        assert!(part_path(&first, 2).exists());
        assert_eq!(std::fs::read(&first).unwrap(), b"a finished first part");
        // Once it has finished, a new recording to the path replaces the old parts.
        live.finish().unwrap();
        drop(RunFiles::create(&first).unwrap());
        assert!(!part_path(&first, 2).exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn record(path: &Path, updates: u64, split_mb: Option<u64>) -> pi2cma::Distribution {
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(updates);
        cfg.recording = Some(session::RecordingSection {
            split_mb,
            ..Default::default()
        });
        crate::testing::record_session(&cfg, 1, path)
    }

    /// Of a killed writer's recording, the part to recover is its last, named from any part;
    /// a finished recording, or none, has none.
    #[test]
    fn the_unfinished_part_is_the_last_one_without_a_summary() {
        let dir = std::env::temp_dir().join(format!("split-unfinished-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("run.mcap");
        assert_eq!(unfinished_part(&first), None);
        record(&first, 200, Some(1));
        let parts = recording_parts(&first);
        assert_eq!(parts.len(), 3, "{parts:?}");
        assert_eq!(unfinished_part(&first), None);
        // The last part cut short, as a SIGKILL of its writer leaves it.
        let bytes = std::fs::read(&parts[2]).unwrap();
        std::fs::write(&parts[2], &bytes[..bytes.len() / 2]).unwrap();
        assert_eq!(unfinished_part(&first), Some(parts[2].clone()));
        assert_eq!(unfinished_part(&parts[1]), Some(parts[2].clone()));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// 200 A1 updates of ~14 kB in parts of 1 MB: three finished parts, each a recording that
    /// verifies by itself, which join into the run; a later, shorter recording to the same
    /// path leaves no stale part behind.
    #[test]
    fn a_split_recording_is_finished_parts_that_join_into_the_run() {
        let dir = std::env::temp_dir().join(format!("split-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("run.mcap");
        let last = record(&first, 200, Some(1));
        let parts = recording_parts(&first);
        assert_eq!(parts.len(), 3, "{parts:?}");
        let mut recs = Vec::new();
        for (i, p) in parts.iter().enumerate() {
            let rec = read_recording(p).unwrap();
            assert!(rec.indexed && rec.truncated.is_none(), "{}", p.display());
            assert!(verify(&rec).unwrap().mismatches.is_empty());
            let meta = &rec.metadata[crate::topics::METADATA];
            let first_update = rec.updates[0].update;
            assert_eq!(meta["first_update"], first_update.to_string());
            assert_eq!(rec.run_info().unwrap().update, first_update);
            if i > 0 {
                assert_eq!(meta["part"], (i + 1).to_string());
                assert_eq!(meta["previous_part"], parts[i - 1].display().to_string());
                assert!(rec.logs.iter().any(|l| l.message.starts_with("part ")));
            }
            recs.push(rec);
        }
        let runs = join_resumed(recs);
        assert_eq!(runs.len(), 1);
        let updates: Vec<u64> = runs[0].0.updates.iter().map(|u| u.update).collect();
        assert_eq!(updates, (0..200).collect::<Vec<_>>());
        // `recover` of an earlier part points at the last, the only one a killed writer leaves
        // unfinished.
        let report = crate::recover::run(&crate::recover::RecoverArgs {
            file: first.clone(),
            out: Some(dir.join("recovered.mcap")),
        })
        .unwrap();
        assert_eq!(report.last_part.as_ref(), Some(&parts[2]));
        assert!(report.describe().contains("whose last part is"));
        std::fs::remove_file(dir.join("recovered.mcap")).unwrap();
        // `analyze` of some of the parts says which are missing; of all of them, one run.
        let text = analyze_summaries(&parts[..2]).unwrap();
        assert!(
            text.contains(&format!("not given: {}", parts[2].display())),
            "{text}"
        );
        let text = analyze_summaries(&parts).unwrap();
        assert!(
            !text.contains("not given") && text.contains("one run of 200 updates"),
            "{text}"
        );
        // With a gap, they are no run: refused, naming the missing part.
        let gap = analyze_summaries(&[parts[0].clone(), parts[2].clone()])
            .unwrap_err()
            .to_string();
        assert!(
            gap.contains("with a gap") && gap.contains(&parts[1].display().to_string()),
            "{gap}"
        );
        // Resuming from any part goes on from the last.
        let point = crate::resume::resume_point(&first).unwrap();
        assert_eq!(point.start.update, 200);
        assert_eq!(point.start.distribution, last);
        assert_eq!(point.start.origin, parts[2].display().to_string());

        record(&first, 50, None);
        assert_eq!(recording_parts(&first), std::slice::from_ref(&first));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A long run's earlier parts archived while it runs (part 2 deleted here): the parts after
    /// the gap are still the recording's. Before, the parts stopped at the first missing one,
    /// so `--resume` went on from the end of part 1, a restarted recorder began again in part
    /// 2, and a new recording to the path neither refused nor removed part 3.
    #[test]
    fn parts_after_a_missing_one_are_still_the_recordings() {
        let dir = std::env::temp_dir().join(format!("split-gap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("run.mcap");
        let last = record(&first, 200, Some(1));
        let third = part_path(&first, 3);
        assert!(third.exists() && !part_path(&first, 4).exists());
        std::fs::remove_file(part_path(&first, 2)).unwrap();
        // Not a part: another spelling of its number.
        std::fs::write(dir.join("run.part-03.mcap"), b"").unwrap();

        assert_eq!(recording_parts(&first), [first.clone(), third.clone()]);
        assert_eq!(last_part(&first), third);
        let point = crate::resume::resume_point(&first).unwrap();
        assert_eq!(point.start.update, 200);
        assert_eq!(point.start.distribution, last);
        let described = describe_parts(&first);
        assert!(
            described.contains("split into 3 parts, 2 of them there"),
            "{described}"
        );

        let gap = analyze_summaries(&[first.clone(), third.clone()])
            .unwrap_err()
            .to_string();
        let second = part_path(&first, 2).display().to_string();
        assert!(
            gap.contains("with a gap") && gap.contains(&format!("{second} no longer there")),
            "{gap}"
        );

        // The command printed at the end names what `analyze` takes together.
        assert_eq!(
            analyze_command("pi2cma", &first, &[]),
            format!("pi2cma analyze {}", third.display())
        );
        // The first part moved away too: what is left is still a recording there.
        std::fs::remove_file(&first).unwrap();
        assert_eq!(last_part(&first), third);
        assert_eq!(
            analyze_command("pi2cma", &first, &[]),
            format!("pi2cma analyze {}", third.display())
        );
        let e = refuse_overwrite(&first, "--record")
            .unwrap_err()
            .to_string();
        assert!(e.contains(&third.display().to_string()), "{e}");
        // A new recording to the path (as `pi2cma run`'s `runs/latest/`) removes it, not
        // overwrites it later when its own parts get there.
        drop(RunFiles::create(&first).unwrap());
        assert!(!third.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A resumed run's analyze command names every part of both recordings, whichever part the
    /// run resumed from.
    /// A task change at a part's first update is in that part, before the update, and the
    /// part's `/run` has the new value.
    #[test]
    fn a_task_change_at_the_first_update_of_a_part_is_in_that_part() {
        let dir = std::env::temp_dir().join(format!("split-change-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("run.mcap");
        record(&path, 100, Some(1));
        let second = read_recording(&recording_parts(&path)[1]).unwrap();
        let boundary = second.updates[0].update;
        assert!(boundary > 20, "{boundary}");

        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(100);
        cfg.recording = Some(session::RecordingSection {
            split_mb: Some(1),
            ..Default::default()
        });
        cfg.schedule[0].from_update = boundary;
        crate::testing::record_session(&cfg, 1, &path);
        let parts: Vec<Recording> = recording_parts(&path)
            .iter()
            .map(|p| read_recording(p).unwrap())
            .collect();
        assert_eq!(parts[1].updates[0].update, boundary);
        assert!(
            parts[0].task_changes.is_empty(),
            "{:?}",
            parts[0].task_changes
        );
        let change = &parts[1].task_changes;
        assert_eq!(change.len(), 1);
        assert_eq!((change[0].update, change[0].value), (boundary, 0.1));
        let settings = &parts[1].run_info().unwrap().task_settings;
        assert_eq!(settings[0].value, 0.1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_analyze_command_names_every_part_of_both_recordings() {
        let dir = std::env::temp_dir().join(format!("split-cmd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let names = ["a.mcap", "a.part-2.mcap", "b.mcap", "b.part-2.mcap"];
        for n in names {
            std::fs::write(dir.join(n), b"").unwrap();
        }
        let files: Vec<String> = names
            .iter()
            .map(|n| dir.join(n).display().to_string())
            .collect();
        assert_eq!(
            analyze_command("pi2cma", &dir.join("b.mcap"), &[dir.join("a.part-2.mcap")]),
            format!("pi2cma analyze {}", files.join(" "))
        );
        assert_eq!(
            analyze_command("pi2cma", &dir.join("a.mcap"), &[]),
            format!("pi2cma analyze {} {}", files[0], files[1])
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A recording of many parts is named by a pattern in the printed command, and in its
    /// description by its first, second and last part; a gap before the pattern's parts would
    /// put earlier ones in, so then they are named one by one.
    #[test]
    fn many_parts_are_named_by_a_pattern() {
        let dir = std::env::temp_dir().join(format!("split-many-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("day.mcap");
        std::fs::write(&first, b"").unwrap();
        for n in 2..=12 {
            std::fs::write(part_path(&first, n), b"").unwrap();
        }
        let d = dir.display();
        assert_eq!(
            analyze_command("pi2cma", &first, &[]),
            format!("pi2cma analyze {d}/day.mcap {d}/day.part-*.mcap")
        );
        assert_eq!(
            describe_parts(&first),
            format!(
                "{d}/day.mcap (split into 12 parts: {d}/day.mcap, {d}/day.part-2.mcap, …, \
                 {d}/day.part-12.mcap)"
            )
        );
        // The first part archived: the pattern alone.
        std::fs::remove_file(&first).unwrap();
        assert_eq!(
            analyze_command("pi2cma", &first, &[]),
            format!("pi2cma analyze {d}/day.part-*.mcap")
        );
        // Part 4 archived too: the pattern would take in 2 and 3 across the gap.
        std::fs::remove_file(part_path(&first, 4)).unwrap();
        let words: Vec<String> = (5..=12)
            .map(|n| part_path(&first, n).display().to_string())
            .collect();
        assert_eq!(
            analyze_command("pi2cma", &first, &[]),
            format!("pi2cma analyze {}", words.join(" "))
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn parts_are_named_after_the_first() {
        let first = Path::new("runs/day.mcap");
        assert_eq!(part_path(first, 2), Path::new("runs/day.part-2.mcap"));
        assert_eq!(first_part(Path::new("runs/day.part-12.mcap")), first);
        assert_eq!(first_part(first), first);
        assert_eq!(
            first_part(Path::new("a.part-x.mcap")),
            Path::new("a.part-x.mcap")
        );
        assert_eq!(
            first_part(Path::new("a.part-1.mcap")),
            Path::new("a.part-1.mcap")
        );
    }
}
