//! Removing a run's files: its run directory, iceoryx2 directory and shared memory, at the end
//! of the run and, when another run starts, whatever killed runs left behind. It is not the
//! stopping of processes (`event_loop`, `process`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::control;

use super::process::process_alive;

/// The supervisor's pid, in its run directory: tells a killed run from a live one.
pub(super) const PID_FILE: &str = "supervisor.pid";

/// The recording's first part, as an absolute path, in the run directory of a recorded run: a
/// run whose supervisor was killed left that recording unfinished, and what was said of it
/// (its run directory removed by the next run, `status` refusing it) did not name the file.
pub(super) const RECORDING_FILE: &str = "recording.path";

/// Notes the run's recording `first` in its run directory ([`RECORDING_FILE`]).
pub(super) fn note_recording(run_dir: &Path, first: &Path) -> std::io::Result<()> {
    use std::os::unix::ffi::OsStrExt as _;
    let first = std::path::absolute(first)?;
    std::fs::write(run_dir.join(RECORDING_FILE), first.as_os_str().as_bytes())
}

/// The part of the recording of the run in `run_dir` that is unfinished (its recorder was
/// killed with its supervisor), if it is noted there and is.
pub(crate) fn unfinished_recording(run_dir: &Path) -> Option<PathBuf> {
    use std::os::unix::ffi::OsStrExt as _;
    let noted = std::fs::read(run_dir.join(RECORDING_FILE)).ok()?;
    record::unfinished_part(Path::new(std::ffi::OsStr::from_bytes(&noted)))
}

/// What to do with `part`, the unfinished part of a killed run's recording.
pub(crate) fn unfinished_text(part: &Path) -> String {
    let part = part.display();
    format!(
        "its recording {part} is unfinished: `{pi2cma} recover {part}` completes it, and \
         `supervisor run CONFIG --resume {part}` goes on from it",
        pi2cma = super::summary::pi2cma_program().0
    )
}

/// Removes everything of run `run_id`: its run directory (and the runs directory if it was the
/// last run in it), its iceoryx2 directory and its shared memory. Returns how many
/// shared-memory files were removed.
pub(super) fn remove_run(run_dir: &Path, run_id: u64) -> usize {
    let _ = std::fs::remove_dir_all(run_dir);
    // remove_dir keeps a non-empty runs directory.
    if let Some(base) = run_dir.parent() {
        let _ = std::fs::remove_dir(base);
    }
    remove_ipc(run_id)
}

/// Removes a run's iceoryx2 directory and its files with the run's prefix; returns how many of
/// those files there were.
fn remove_ipc(run_id: u64) -> usize {
    let _ = std::fs::remove_dir_all(wire::iceoryx_root(run_id));
    remove_prefixed(&wire::file_prefix(run_id))
}

/// Removes the run's shared-memory segments and iceoryx2's files in the temp directory (a
/// SIGKILLed process leaves its own behind); returns how many.
fn remove_prefixed(prefix: &str) -> usize {
    let mut removed = 0;
    for dir in ["/dev/shm", "/tmp"] {
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(prefix)
                    && std::fs::remove_file(e.path()).is_ok()
                {
                    removed += 1;
                }
            }
        }
    }
    removed
}

/// Removes the runs under `base` whose supervisor is gone (killed with SIGKILL, or its machine
/// lost power): a killed supervisor's processes die with it (PR_SET_PDEATHSIG), but nobody
/// removes their shared memory, which holds RAM until reboot, nor their run directory, whose
/// stale control socket `supervisor ctl` would otherwise offer as an active run. Returns the
/// removed runs and how many shared-memory files each had.
///
/// A run is gone when its control socket refuses connections and the pid in its run directory
/// is not alive; a run directory without a pid file (one being created right now) is left
/// alone unless it is older than a minute.
pub(super) fn sweep_abandoned_runs(base: &Path) -> Vec<(String, usize, Option<PathBuf>)> {
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(base) else {
        return removed;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        let Ok(run_id) = u64::from_str_radix(&name, 16) else {
            continue;
        };
        if name.len() != 16 || !run_abandoned(&e.path()) {
            continue;
        }
        let unfinished = unfinished_recording(&e.path());
        removed.push((name, remove_run(&e.path(), run_id), unfinished));
    }
    removed
}

/// Removes the inter-process files of runs whose run directory is gone, which
/// [`sweep_abandoned_runs`] cannot find: a killed run whose directory was deleted by hand, or
/// that lived under another `PI2CMA_RUN_DIR` (a test's). Left alone, its shared memory holds RAM
/// until reboot. Removed: an iceoryx2 directory `/tmp/p2c-<run>/` none of whose processes is alive
/// ([`wire::run_alive`]) with the run's shared memory, and shared memory whose iceoryx2 directory
/// is gone. Only what is older than a minute, so a run that is starting is never touched; never
/// the run `own`. Returns the runs and how many shared-memory files each had.
pub(super) fn sweep_orphaned_ipc(own: u64) -> Vec<(String, usize)> {
    const MIN_AGE: Duration = Duration::from_secs(60);
    let old = |p: &Path| {
        std::fs::symlink_metadata(p)
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > MIN_AGE))
    };
    let run_id = |hex: &str| {
        (hex.len() == 16 && hex.bytes().all(|b| b.is_ascii_hexdigit()))
            .then(|| u64::from_str_radix(hex, 16).ok())
            .flatten()
    };
    let mut runs = std::collections::BTreeSet::new();
    for entry in std::fs::read_dir("/tmp").into_iter().flatten().flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        // `/tmp/p2c-<run>/`
        if let Some(id) = name.strip_prefix("p2c-").and_then(run_id) {
            if id != own && old(&entry.path()) && !wire::run_alive(id) {
                runs.insert(id);
            }
        }
    }
    for entry in std::fs::read_dir("/dev/shm")
        .into_iter()
        .flatten()
        .flatten()
    {
        let name = entry.file_name().to_string_lossy().to_string();
        // `/dev/shm/p2c<run>_…`
        let id = name
            .strip_prefix("p2c")
            .and_then(|rest| rest.split_once('_'))
            .and_then(|(hex, _)| run_id(hex));
        if let Some(id) = id {
            if id != own && !wire::iceoryx_root(id).exists() && old(&entry.path()) {
                runs.insert(id);
            }
        }
    }
    runs.into_iter()
        .map(|id| (wire::run_id_hex(id), remove_ipc(id)))
        .collect()
}

/// The pid of the supervisor of the run in `run_dir`, from its pid file: `Ok(None)` if the
/// file holds no pid, `Err` if it cannot be read (not written yet, or removed).
pub(crate) fn supervisor_pid(run_dir: &Path) -> std::io::Result<Option<u32>> {
    std::fs::read_to_string(run_dir.join(PID_FILE)).map(|pid| pid.trim().parse().ok())
}

fn run_abandoned(run_dir: &Path) -> bool {
    if control::serving(run_dir) {
        return false;
    }
    match supervisor_pid(run_dir) {
        Ok(pid) => pid.is_some_and(|pid| !process_alive(pid)),
        Err(_) => std::fs::metadata(run_dir)
            .and_then(|m| m.modified())
            .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > Duration::from_secs(60))),
    }
}
