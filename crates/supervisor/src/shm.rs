//! Whether a run's shared memory fits in /dev/shm, asked before any of its processes starts.
//!
//! iceoryx2 sizes its files without reserving their pages, so a /dev/shm too small for a run
//! shows only as SIGBUS in whichever process first writes to a page there is no room for,
//! possibly long into the run (a recorder that falls behind fills more of the buffers). So the
//! supervisor compares the run's need (`wire::Limits::shared_memory`) with the free space
//! first, and says what drives the need.

use std::path::Path;

use anyhow::bail;
use wire::{Limits, SharedMemoryNeed};

/// Where iceoryx2's shared-memory segments live (POSIX shm_open on Linux).
pub(crate) const SHM_DIR: &str = "/dev/shm";

/// A need above this share of the free space is warned about, one above all of it refused.
/// The need is an estimate from the protocol's bounds (a recorder on a slow disk lets the
/// buffers fill to them), above every peak measured but not a proven maximum (a worker's share
/// of the costs in flight is taken as twice an equal one); a run above the free space may die
/// of SIGBUS at any time, hours in: refused, which costs a moment, though one that would have
/// fit can be refused too (its message says how to make room). Within the last 10 % the run fits even at its bound, but
/// anything else that writes to /dev/shm meanwhile (another run, a browser) can take that
/// room: a warning, not a refusal, since measured peaks were 0.36–0.75 times the bound.
const WARN_SHARE: f64 = 0.9;

/// The free, total and block bytes of a file system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Space {
    pub free: u64,
    pub total: u64,
    /// The unit of allocation: a page on tmpfs.
    pub block: u64,
}

/// The space of the file system at `dir`.
pub(crate) fn space(dir: &Path) -> Option<Space> {
    use std::os::unix::ffi::OsStrExt as _;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: statvfs writes only into the struct it is given; the path is NUL-terminated.
    #[allow(unsafe_code)]
    let st = unsafe {
        let mut st: libc::statvfs = std::mem::zeroed();
        (libc::statvfs(path.as_ptr(), &mut st) == 0).then_some(st)
    }?;
    let frsize = st.f_frsize as u64;
    Some(Space {
        free: st.f_bavail as u64 * frsize,
        total: st.f_blocks as u64 * frsize,
        block: frsize,
    })
}

/// `512 bytes`, `12 KiB`, `64.0 MiB`, `1.5 GiB`.
pub(crate) fn size(bytes: u64) -> String {
    if bytes < 1 << 10 {
        format!("{bytes} bytes")
    } else if bytes < 1 << 20 {
        format!("{} KiB", bytes >> 10)
    } else if bytes < 1 << 30 {
        format!("{:.1} MiB", bytes as f64 / f64::from(1 << 20))
    } else {
        format!("{:.1} GiB", bytes as f64 / f64::from(1 << 30))
    }
}

/// A run as far as its shared memory goes, and how its config names the sizes.
#[derive(Debug, Clone)]
pub(crate) struct RunSizes<'a> {
    pub config: &'a Path,
    pub limits: Limits,
    pub workers: usize,
    /// `pipeline.workers`, or `--workers` when the command line set it.
    pub workers_field: &'static str,
    pub recorder: bool,
    /// Whether the run has the `reruns` service (`run.nonfinite_reruns` > 0).
    pub reruns: bool,
    /// The fields that set P and N (`session::RunConfig::size_fields`).
    pub p_field: String,
    pub n_field: String,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Verdict {
    Fits,
    Warn(Vec<String>),
    Refuse(String),
}

/// The warnings to print before the run starts, or the error that refuses it. Nothing to say
/// if /dev/shm cannot be inspected: iceoryx2 then fails on its own terms.
pub(crate) fn check(run: &RunSizes) -> anyhow::Result<Vec<String>> {
    let Some(space) = space(Path::new(SHM_DIR)) else {
        return Ok(Vec::new());
    };
    match judge(run, &space) {
        Verdict::Fits => Ok(Vec::new()),
        Verdict::Warn(warnings) => Ok(warnings),
        Verdict::Refuse(error) => bail!(error),
    }
}

/// For `--no-shm-check`: what the check would have said, as information (`None` when /dev/shm
/// cannot be inspected or the run fits).
pub(crate) fn describe(run: &RunSizes) -> Option<String> {
    let space = space(Path::new(SHM_DIR))?;
    match judge(run, &space) {
        Verdict::Fits => None,
        Verdict::Warn(_) | Verdict::Refuse(_) => Some(format!(
            "not checking that this run's iceoryx2 services fit in {SHM_DIR}: the estimate is up \
             to {} with {} free",
            size(
                run.limits
                    .shared_memory(run.workers, run.recorder, run.reruns, space.block)
                    .total()
            ),
            size(space.free)
        )),
    }
}

pub(crate) fn judge(run: &RunSizes, space: &Space) -> Verdict {
    let need_of = |workers| {
        run.limits
            .shared_memory(workers, run.recorder, run.reruns, space.block)
    };
    let need = need_of(run.workers);
    if need.total() > space.free {
        return Verdict::Refuse(refusal(run, &need, space));
    }
    let mut warnings = Vec::new();
    if need.total() as f64 > WARN_SHARE * space.free as f64 {
        warnings.push(format!(
            "this run's iceoryx2 services may take up to {} of the {} free in {SHM_DIR}: should \
             anything else take more of it meanwhile, a process of the run dies of SIGBUS (free \
             space there, or enlarge it: `sudo mount -o remount,size={} {SHM_DIR}`)",
            size(need.total()),
            size(space.free),
            suggested_size(need.total(), space)
        ));
    }
    let max = run.limits.max_workers;
    let fits = |workers| need_of(workers).total() <= space.free;
    // The first count that does not fit, not the last that does: the need grows with the
    // workers only by their ports, and their shares of the costs round unevenly.
    if let Some(too_many) = (run.workers + 1..=max).find(|&w| !fits(w)) {
        let most = too_many - 1;
        warnings.push(format!(
            "{SHM_DIR} has room for at most {most} workers of this run ({} free), not \
             pipeline.max_workers = {max} ({} needed): more (`supervisor scale`, or workers \
             that join) would get processes killed by SIGBUS",
            size(space.free),
            size(need_of(max).total())
        ));
    }
    if warnings.is_empty() {
        Verdict::Fits
    } else {
        Verdict::Warn(warnings)
    }
}

/// Whether a running run can grow from `from` to `to` workers: the new workers' share of the
/// estimate must fit in what /dev/shm has free now (the run's own pages are already taken
/// from it). `Err` is the refusal; nothing to say if /dev/shm cannot be inspected.
pub(crate) fn check_scale(
    limits: &Limits,
    (recorder, reruns): (bool, bool),
    from: usize,
    to: usize,
) -> Result<(), String> {
    match space(Path::new(SHM_DIR)) {
        Some(space) => judge_scale(limits, (recorder, reruns), from, to, &space),
        None => Ok(()),
    }
}

fn judge_scale(
    limits: &Limits,
    (recorder, reruns): (bool, bool),
    from: usize,
    to: usize,
    space: &Space,
) -> Result<(), String> {
    let need_of = |workers| {
        limits
            .shared_memory(workers, recorder, reruns, space.block)
            .total()
    };
    let more = need_of(to).saturating_sub(need_of(from));
    if more <= space.free {
        return Ok(());
    }
    Err(format!(
        "cannot scale to {to} workers: they need about {} more shared memory, but {SHM_DIR} has \
         {} free; a worker without room would die of SIGBUS. Free space there, or enlarge it \
         (`sudo mount -o remount,size={} {SHM_DIR}`); a run started with `--no-shm-check` is \
         scaled unchecked",
        size(more),
        size(space.free),
        suggested_size(more, space)
    ))
}

fn refusal(run: &RunSizes, need: &SharedMemoryNeed, space: &Space) -> String {
    let l = &run.limits;
    let total = need.total();
    let mut parts = [
        (need.costs, "the workers' costs", "N × K"),
        (need.distribution, "the distribution", "P²"),
        (need.work, "the work", "P × K"),
        (need.other, "ports and registries", "the workers"),
    ];
    parts.sort_by_key(|(bytes, ..)| std::cmp::Reverse(*bytes));
    let parts = parts
        .iter()
        .filter(|(bytes, ..)| *bytes * 10 >= total)
        .map(|(bytes, what, with)| format!("{what} {}, growing with {with}", size(*bytes)))
        .collect::<Vec<_>>()
        .join("; ");
    format!(
        "{}: this run needs up to {} of shared memory for its iceoryx2 services ({parts}), but \
         {SHM_DIR} has {} free (of {}). The need grows with {} = {}, pipeline.max_workers = {} \
         (the buffers' sizes), optimizer.rollouts = K = {}, the steps N = {} ({}) and the \
         parameters P = {} ({}). Make the run smaller, free space in {SHM_DIR} (`du -sh \
         {SHM_DIR}/*`), or enlarge it: `sudo mount -o remount,size={} {SHM_DIR}` (in Docker: \
         `--shm-size`). The estimate can be up to ~3 times what a run takes: if you know this \
         one fits, `--no-shm-check` starts it unchecked (it dies of SIGBUS if it does not)",
        run.config.display(),
        size(total),
        size(space.free),
        size(space.total),
        run.workers_field,
        run.workers,
        l.max_workers,
        l.rollouts,
        l.steps,
        run.n_field,
        l.dim,
        run.p_field,
        suggested_size(total, space)
    )
}

/// A /dev/shm size (mount's `size=`) that holds what it holds now and the run, with a quarter
/// to spare, in whole 64 MiB.
fn suggested_size(need: u64, space: &Space) -> String {
    let used = space.total.saturating_sub(space.free);
    let step = 64u64 << 20;
    let bytes = (used + need + need / 4).div_ceil(step) * step;
    if bytes.is_multiple_of(1 << 30) {
        format!("{}G", bytes >> 30)
    } else {
        format!("{}M", bytes >> 20)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_read_in_their_unit() {
        // A file size limit of a few blocks was "0 KiB"; the supervisor's note said bytes.
        assert_eq!(size(512), "512 bytes");
        assert_eq!(size(12 << 10), "12 KiB");
        assert_eq!(size(64 << 20), "64.0 MiB");
        assert_eq!(size(3 << 29), "1.5 GiB");
    }

    fn tball_large(free: u64) -> (RunSizes<'static>, Space) {
        let run = RunSizes {
            config: Path::new("large.toml"),
            limits: Limits {
                max_workers: 16,
                rollouts: 50,
                dim: 350,
                steps: 1001,
            },
            workers: 8,
            workers_field: "pipeline.workers",
            recorder: true,
            reruns: false,
            p_field: "task.tball.basis_functions".into(),
            n_field: "task.tball.dt".into(),
        };
        let space = Space {
            free,
            total: 64 << 20,
            block: 4096,
        };
        (run, space)
    }

    #[test]
    fn a_run_that_does_not_fit_is_refused_naming_the_need_the_space_and_the_fields() {
        let (run, space) = tball_large(8 << 20);
        let need = run.limits.shared_memory(8, true, false, 4096).total();
        assert!(need > space.free, "{need}");
        let Verdict::Refuse(e) = judge(&run, &space) else {
            panic!("not refused");
        };
        for part in [
            format!(
                "large.toml: this run needs up to {} of shared memory",
                size(need)
            ),
            "/dev/shm has 8.0 MiB free (of 64.0 MiB)".into(),
            "pipeline.workers = 8, pipeline.max_workers = 16".into(),
            "optimizer.rollouts = K = 50".into(),
            "N = 1001 (task.tball.dt)".into(),
            "P = 350 (task.tball.basis_functions)".into(),
            "the workers' costs 4.6 MiB, growing with N × K".into(),
            "the distribution 5.6 MiB, growing with P²".into(),
            // 56 MiB used, 11.6 needed: 70.5 MiB with a quarter to spare.
            "sudo mount -o remount,size=128M /dev/shm".into(),
            "if you know this one fits, `--no-shm-check` starts it unchecked".into(),
        ] {
            assert!(e.contains(&part), "{part:?} not in {e}");
        }
    }

    #[test]
    fn a_run_close_to_the_free_space_is_warned_about_and_one_with_room_is_not() {
        let (mut run, space) = tball_large(0);
        run.limits.max_workers = run.workers;
        let need = run.limits.shared_memory(8, true, false, 4096).total();
        let close = Space {
            free: need + need / 20,
            ..space
        };
        let Verdict::Warn(w) = judge(&run, &close) else {
            panic!("no warning")
        };
        assert_eq!(w.len(), 1);
        assert!(
            w[0].contains(&format!("may take up to {}", size(need))),
            "{w:?}"
        );
        let exact = Space {
            free: need,
            ..space
        };
        assert!(matches!(judge(&run, &exact), Verdict::Warn(_)));
        let roomy = Space {
            free: 2 * need,
            ..space
        };
        assert_eq!(judge(&run, &roomy), Verdict::Fits);
        let short = Space {
            free: need - 1,
            ..space
        };
        assert!(matches!(judge(&run, &short), Verdict::Refuse(_)));
    }

    #[test]
    fn room_for_fewer_workers_than_max_workers_is_said() {
        let (mut run, space) = tball_large(0);
        run.workers = 2;
        let need = |w| run.limits.shared_memory(w, true, false, 4096).total();
        let free = Space {
            free: (need(12) + need(13)) / 2,
            ..space
        };
        assert!(need(2) as f64 <= 0.9 * free.free as f64);
        let Verdict::Warn(w) = judge(&run, &free) else {
            panic!("no warning")
        };
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("room for at most 12 workers of this run")
                && w[0].contains("not pipeline.max_workers = 16"),
            "{w:?}"
        );
    }

    #[test]
    fn the_space_of_a_file_system_is_read() {
        let s = space(Path::new("/")).unwrap();
        assert!(s.free <= s.total && s.total > 0 && s.block > 0);
        assert_eq!(space(Path::new("/no/such/dir")), None);
    }

    #[test]
    fn scaling_up_is_refused_when_the_new_workers_do_not_fit() {
        let (run, _) = tball_large(0);
        let need = |w| run.limits.shared_memory(w, true, false, 4096).total();
        let more = need(12) - need(8);
        let space = |free| Space {
            free,
            total: 64 << 20,
            block: 4096,
        };
        assert_eq!(
            judge_scale(&run.limits, (true, false), 8, 12, &space(more)),
            Ok(())
        );
        let e = judge_scale(&run.limits, (true, false), 8, 12, &space(more - 1)).unwrap_err();
        assert!(
            e.starts_with("cannot scale to 12 workers: they need about")
                && e.contains("SIGBUS")
                && e.contains("started with `--no-shm-check` is scaled unchecked")
                && !e.contains("  "),
            "{e}"
        );
        // Scaling down never needs room.
        assert_eq!(
            judge_scale(&run.limits, (true, false), 8, 2, &space(0)),
            Ok(())
        );
    }
}
