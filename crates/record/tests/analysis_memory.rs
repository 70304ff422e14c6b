//! Peak memory of `mcap-tool analyze`, measured on the child process with wait4. Its own test
//! binary: a child's peak RSS includes its parent's at the moment it was spawned (the child
//! shares the parent's memory until it execs), so the tests here keep the parent small — they
//! record through `mcap-tool record` in child processes — and no other test runs beside them
//! (an in-process analysis in the same binary put 7 MB on top of a measurement).

#![allow(clippy::unwrap_used)] // test helpers; a failed unwrap is a failed test

#[path = "../../../tests/scratch.rs"]
mod scratch;

use std::path::Path;

/// Records `updates` updates of the default via-point run into `file` with `mcap-tool record`.
fn record(file: &Path, updates: u64) {
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(["record", "--updates", &updates.to_string(), "--out"])
        .arg(file)
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(status.success(), "mcap-tool record --updates {updates}");
}

/// Peak RSS (KiB) of `mcap-tool` run with `args` to its end.
// The child is reaped by wait4, which also gives its peak RSS; std's wait cannot.
#[allow(clippy::zombie_processes)]
fn peak_rss_kib(args: &[&std::ffi::OsStr]) -> (bool, i64) {
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut status = 0;
    // SAFETY: wait4 reaps the child this test started and writes only into the two locals it
    // is given; `child` is not waited on again.
    #[allow(unsafe_code)]
    let usage = unsafe {
        let mut u: libc::rusage = std::mem::zeroed();
        let pid = libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut u);
        assert_eq!(pid, child.id() as libc::pid_t, "wait4");
        u
    };
    (
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        usage.ru_maxrss,
    )
}

/// Analysis takes memory for the curves, not for the size of the files, also when a file is a
/// copy of another: the copy check compared the two files read whole.
#[test]
fn a_copy_is_found_without_reading_the_files_whole() {
    let dir = scratch::scratch("copy-memory");
    let a = dir.join("a.mcap");
    record(&a, 2000);
    let copy = dir.join("copy.mcap");
    std::fs::copy(&a, &copy).unwrap();
    let bytes = std::fs::metadata(&a).unwrap().len() as i64;
    let (ok, kib) = peak_rss_kib(&["analyze".as_ref(), a.as_os_str(), copy.as_os_str()]);
    assert!(ok, "analyze failed");
    // About 18 MB against a recording of 27 MB; reading both whole took 2 × 27 MB more.
    assert!(
        kib * 1024 < bytes,
        "analyze of a {bytes}-byte recording and its copy peaked at {kib} KiB of RSS"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// What `analyze --out` keeps does not grow with the number of updates (beyond 48 bytes of
/// scalars each): it kept every update's distributions and every rollout's timing, about 5 kB
/// per via-point update, so that a long continual run's analysis needed tens of GB. Its figures
/// stay as small: they drew every update and rollout.
#[test]
fn analysis_memory_and_figures_do_not_grow_with_the_number_of_updates() {
    let dir = scratch::scratch("long-run-memory");
    let measure = |updates: u64| {
        let f = dir.join(format!("run-{updates}.mcap"));
        record(&f, updates);
        let out = dir.join(format!("analysis-{updates}"));
        let (ok, kib) = peak_rss_kib(&[
            "analyze".as_ref(),
            f.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
            "--no-csv".as_ref(),
        ]);
        assert!(ok, "analyze failed");
        let largest_svg = std::fs::read_dir(out.join(format!("run-{updates}")))
            .unwrap()
            .flatten()
            .map(|e| e.metadata().unwrap().len())
            .max()
            .unwrap();
        (kib, largest_svg)
    };
    let (short_kib, short_svg) = measure(500);
    let (long_kib, long_svg) = measure(5000);
    // 4500 more updates took 4500 × 5 kB = 22 MB more; now 4500 × 48 bytes of scalars and
    // allocator noise. At most 1 kB per update more.
    assert!(
        long_kib - short_kib < 4500,
        "peak RSS {short_kib} KiB for 500 updates, {long_kib} KiB for 5000"
    );
    // An SVG drew every update's ellipse and every rollout's time: 7 MB for 5000 updates.
    assert!(
        long_svg < 3 * short_svg.max(1 << 18),
        "largest SVG {short_svg} bytes for 500 updates, {long_svg} for 5000"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
