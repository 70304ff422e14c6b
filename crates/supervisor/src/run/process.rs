//! A child process as the operating system sees it: which program runs a role ([`Launcher`]),
//! signals, whether a pid still runs (pid reuse included), dying with the supervisor, and what a
//! SIGBUS most likely means. It is not the supervisor's bookkeeping of its children
//! (`children`).

use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus};

use anyhow::{bail, Context};
use session::{executable_file, RunConfig};

use crate::shm::{size, SHM_DIR};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Role {
    Recorder,
    Updater,
    Sampler,
    Worker(u32),
}

impl Role {
    pub(super) fn name(self) -> String {
        match self {
            Role::Recorder => "recorder".into(),
            Role::Updater => "updater".into(),
            Role::Sampler => "sampler".into(),
            Role::Worker(w) => format!("worker-{w}"),
        }
    }
    fn binary(self) -> &'static str {
        match self {
            Role::Recorder => "recorder",
            Role::Updater => "updater",
            Role::Sampler => "sampler",
            Role::Worker(_) => "rollout-worker",
        }
    }
}

const BINARIES: [&str; 3] = ["updater", "sampler", "rollout-worker"];

/// How children are started: the `updater`, `sampler` and `rollout-worker` binaries of a
/// directory, or — when they are not next to the supervisor, as after `cargo run`, which builds
/// only the binary it runs — the supervisor's own executable, which hosts all four roles. The
/// recorder (the `recorder` binary) is taken from the directory when it is there,
/// else hosted by the supervisor's executable too. An external task's workers are the user's
/// program (`task.external.worker`).
#[derive(Debug, Clone)]
pub(super) struct Launcher {
    binaries: Binaries,
    /// The program and leading arguments of an external task's workers (`task.external.worker`),
    /// which replace `rollout-worker`.
    external_worker: Option<(PathBuf, Vec<String>)>,
}

#[derive(Debug, Clone)]
enum Binaries {
    InDir { dir: PathBuf, exe: PathBuf },
    SelfHosted(PathBuf),
}

impl Launcher {
    pub(super) fn find(bin_dir: Option<&Path>, cfg: &RunConfig) -> anyhow::Result<Self> {
        let external_worker = cfg.external_worker_program()?;
        let binaries = Binaries::find(bin_dir)?;
        Ok(Self {
            binaries,
            external_worker,
        })
    }

    /// The program and its leading arguments for `role`.
    pub(super) fn program(&self, role: Role) -> (PathBuf, Vec<String>) {
        if let (Role::Worker(_), Some((program, args))) = (role, &self.external_worker) {
            return (program.clone(), args.clone());
        }
        let hosted = |exe: &PathBuf| (exe.clone(), vec![role.binary().to_string()]);
        match &self.binaries {
            Binaries::InDir { dir, exe } => {
                let bin = dir.join(role.binary());
                if role == Role::Recorder && !bin.is_file() {
                    hosted(exe)
                } else {
                    (bin, Vec::new())
                }
            }
            Binaries::SelfHosted(exe) => hosted(exe),
        }
    }
}

impl Binaries {
    fn find(bin_dir: Option<&Path>) -> anyhow::Result<Self> {
        if let Some(dir) = bin_dir {
            // Else each binary was said to be missing: `--bin-dir a.toml` gave "missing binary
            // `updater`: a.toml/updater does not exist".
            if !dir.is_dir() {
                let what = if dir.exists() {
                    "is not a directory"
                } else {
                    "does not exist"
                };
                bail!(
                    "--bin-dir {}: {what}; give the directory that holds {}",
                    dir.display(),
                    BINARIES.join(", ")
                );
            }
            for b in BINARIES {
                let p = dir.join(b);
                if !p.exists() {
                    bail!(
                        "missing binary `{b}`: {} does not exist (--bin-dir {} must hold {}; \
                         without --bin-dir the supervisor runs them from its own directory, \
                         or its own executable runs them)",
                        p.display(),
                        dir.display(),
                        BINARIES.join(", ")
                    );
                }
                // Found now rather than when it is started, after the processes before it.
                if !executable_file(&p) {
                    bail!("binary `{b}`: {} is not an executable file", p.display());
                }
            }
            // The recorder is optional there, but one that is there is the one that runs: it
            // failed only once started, after the other processes' shared memory was made.
            let recorder = dir.join(Role::Recorder.binary());
            if recorder.exists() && !executable_file(&recorder) {
                bail!(
                    "binary `recorder`: {} is not an executable file (remove it to have the \
                     supervisor's own executable record)",
                    recorder.display()
                );
            }
            return Ok(Self::InDir {
                dir: dir.to_path_buf(),
                exe: std::env::current_exe()?,
            });
        }
        let exe = std::env::current_exe()?;
        let dir = exe
            .parent()
            .context("the supervisor executable has no directory")?;
        Ok(if BINARIES.iter().all(|b| executable_file(&dir.join(b))) {
            Self::InDir {
                dir: dir.to_path_buf(),
                exe: exe.clone(),
            }
        } else {
            Self::SelfHosted(exe)
        })
    }
}

/// Whether process `pid` runs: it exists and is not a zombie (one that has exited and waits to
/// be reaped still has `/proc/<pid>`).
pub fn process_alive(pid: u32) -> bool {
    process_started(pid).is_some()
}

/// Whether the process that had pid `pid` and start time `started` still runs, not another that
/// got its pid.
pub(super) fn still_runs(pid: u32, started: u64) -> bool {
    process_started(pid) == Some(started)
}

/// When process `pid` started (clock ticks after boot, field 22 of `/proc/<pid>/stat`) if it
/// runs: with the pid, an identity that pid reuse does not fool. `None` for a zombie.
pub(super) fn process_started(pid: u32) -> Option<u64> {
    // Field 22 is 19 after the parent (field 4).
    stat_fields(pid, |state, after| {
        if state == "Z" {
            return None;
        }
        after.nth(18)?.parse().ok()
    })
}

/// The process group of process `pid` (field 5 of `/proc/<pid>/stat`), if it exists.
pub(super) fn process_group(pid: u32) -> Option<u32> {
    stat_fields(pid, |_, after| group_field(after))
}

/// The group among the fields after the state: parent, then group.
fn group_field(after_state: &mut std::str::SplitWhitespace<'_>) -> Option<u32> {
    after_state.nth(1)?.parse().ok()
}

/// What `field` takes from `/proc/<pid>/stat`: the state (field 3; `Z` for a zombie, one that
/// has exited and waits to be reaped) and the fields after it. `None` if `pid` does not exist.
fn stat_fields<T>(
    pid: u32,
    field: impl FnOnce(&str, &mut std::str::SplitWhitespace<'_>) -> Option<T>,
) -> Option<T> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The fields follow the parenthesised command name, which may contain spaces and `)`.
    let (_, rest) = stat.rsplit_once(')')?;
    let mut fields = rest.split_whitespace();
    let state = fields.next()?;
    field(state, &mut fields)
}

/// The processes other than zombies in process group `group` (a child of the supervisor leads
/// one of its own, and what it starts is in it unless it moves out). One read of each
/// process's stat: its group and its state.
pub fn group_members(group: u32) -> Vec<u32> {
    group_in_state(group, |state| state != "Z")
}

/// The processes of process group `group` that a signal has stopped: state `T` (SIGSTOP, an
/// operator's Ctrl-Z or e-stop script freezing the program) or `t` (a debugger's). Such a
/// process is not hung and has not died: it holds what it holds until SIGCONT resumes it where
/// it was, so what the supervisor says of a run that waits for it names it as stopped.
pub(super) fn stopped_in_group(group: u32) -> Vec<u32> {
    group_in_state(group, stopped_state)
}

/// Whether process `pid` is stopped by a signal (see [`stopped_in_group`]).
pub(crate) fn process_stopped(pid: u32) -> bool {
    stat_fields(pid, |state, _| Some(stopped_state(state))).unwrap_or(false)
}

/// A process state (field 3 of its stat) of one stopped by a signal, or by a debugger.
fn stopped_state(state: &str) -> bool {
    state == "T" || state == "t"
}

/// The processes of process group `group` whose state (field 3 of their stat) `state` accepts.
fn group_in_state(group: u32, state: impl Fn(&str) -> bool) -> Vec<u32> {
    let member = |pid: u32| {
        stat_fields(pid, |s, after| {
            Some(state(s) && group_field(after)? == group)
        })
        .unwrap_or(false)
    };
    std::fs::read_dir("/proc")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&pid| member(pid))
        .collect()
}

/// Signals one process that is not ours to group-kill (a worker that joined from outside).
/// The pid comes from a shared-memory message: 0 or one beyond `pid_t` would signal a process
/// group or everything the user owns, so only a plain other process's pid is signalled.
pub(super) fn signal_process(pid: u32, sig: libc::c_int) {
    if pid == 0 || pid > i32::MAX as u32 || pid == std::process::id() {
        return;
    }
    // SAFETY: kill has no memory-safety preconditions; a stale pid only yields ESRCH.
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// Sends `sig` to the process group of child `pid` (each child leads its own group).
pub(super) fn signal_group(pid: u32, sig: libc::c_int) {
    // SAFETY: killpg has no memory-safety preconditions; a stale group id only yields ESRCH.
    #[allow(unsafe_code)]
    unsafe {
        libc::killpg(pid as libc::pid_t, sig);
    }
}

/// What a child killed by SIGBUS most likely ran into: iceoryx2 sizes its segments without
/// reserving their pages, so a full /dev/shm shows only as SIGBUS at the first write to a page
/// it has no room for, and `signal: 7 (SIGBUS)` alone does not say so.
pub(super) fn sigbus_hint(status: ExitStatus, shm: Option<(u64, u64)>) -> Option<String> {
    use std::os::unix::process::ExitStatusExt as _;
    if status.signal() != Some(libc::SIGBUS) {
        return None;
    }
    let space = match shm {
        Some((free, total)) => format!("{SHM_DIR} has {} free of {}", size(free), size(total)),
        None => format!("{SHM_DIR} could not be inspected"),
    };
    Some(format!(
        "SIGBUS here most likely means the shared memory is full: {space}; free space there \
         (or enlarge it), or make the run's messages smaller (K, P, N, pipeline.max_workers)"
    ))
}

/// What a child killed by SIGXFSZ ran into: a file size limit (`ulimit -f`, `limit` bytes; `None`
/// when there is none or it cannot be read). `signal: 25 (SIGXFSZ)` alone did not say which file
/// nor that iceoryx2's shared memory files, which a process sizes when it creates its ports,
/// count against it like any file: a limit of a few hundred kB kills the workers at their start.
pub(super) fn xfsz_hint(status: ExitStatus, limit: Option<u64>) -> Option<String> {
    use std::os::unix::process::ExitStatusExt as _;
    if status.signal() != Some(libc::SIGXFSZ) {
        return None;
    }
    let limit = limit.map_or("the file size limit".to_string(), |l| {
        format!("the file size limit (`ulimit -f`: {})", size(l))
    });
    Some(format!(
        "SIGXFSZ means it wrote past {limit}; its shared memory files count against it as well \
         as the recording: raise or remove the limit"
    ))
}

/// A note for a run that failed at iceoryx2 (a node, a service, a port: its shared memory
/// files) while a file size limit is set: with the supervisor ignoring SIGXFSZ the failure is
/// iceoryx2's `InternalError` or `UnableToCreateDataSegment`, which does not say why.
pub fn file_size_limit_note(e: &anyhow::Error) -> Option<String> {
    // The doorbell thread hands its error over as text (`iceoryx2 service …`).
    let ipc = e.chain().any(|c| {
        c.is::<wire::WireError>()
            || matches!(
                c.downcast_ref::<pipeline::ProcessError>(),
                Some(pipeline::ProcessError::Port { .. })
            )
            || c.to_string().starts_with("iceoryx2 service")
    });
    let limit = file_size_limit().filter(|_| ipc)?;
    Some(format!(
        "a file size limit is set (`ulimit -f`: {}), and iceoryx2's shared memory files count \
         against it: raise or remove the limit",
        size(limit)
    ))
}

/// The process's file size limit (RLIMIT_FSIZE) in bytes; `None` when unlimited.
pub(super) fn file_size_limit() -> Option<u64> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the limits into `r`, which lives for the call.
    #[allow(unsafe_code)]
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_FSIZE, &mut r) } == 0;
    (ok && r.rlim_cur != libc::RLIM_INFINITY).then_some(r.rlim_cur)
}

/// The child gets SIGKILL when the supervisor dies, however it dies, and the default handling
/// of SIGXFSZ, SIGINT, SIGTERM and SIGHUP.
pub(super) fn die_with_parent(cmd: &mut Command) {
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs in the forked child before exec and only calls the
    // async-signal-safe functions signal, prctl, getppid and _exit; it allocates nothing.
    #[allow(unsafe_code)]
    unsafe {
        cmd.pre_exec(move || {
            // The supervisor ignores SIGXFSZ (record::fail_writes_past_file_size_limit); a
            // worker is the user's program, which gets the default (the recorder ignores it
            // again itself).
            libc::signal(libc::SIGXFSZ, libc::SIG_DFL);
            // A supervisor started under nohup keeps SIGHUP ignored (the `signals` crate); its
            // children, in process groups of their own that no terminal signals, start as a
            // fresh program would, as they did before.
            for s in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
                libc::signal(s, libc::SIG_DFL);
            }
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The supervisor died between fork and prctl: the signal would never come.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn a_child_killed_by_sigbus_is_said_to_have_found_the_shared_memory_full() {
        use std::os::unix::process::ExitStatusExt as _;
        let bus = ExitStatus::from_raw(libc::SIGBUS);
        let hint = sigbus_hint(bus, Some((12 << 10, 64 << 20))).unwrap();
        assert!(
            hint.contains("shared memory is full: /dev/shm has 12 KiB free of 64.0 MiB"),
            "{hint}"
        );
        assert!(sigbus_hint(bus, None)
            .unwrap()
            .contains("/dev/shm could not be inspected"));
        for other in [
            ExitStatus::from_raw(libc::SIGSEGV),
            ExitStatus::from_raw(1 << 8),
        ] {
            assert_eq!(sigbus_hint(other, Some((0, 1))), None);
        }
    }

    /// A process's start time identifies it across pid reuse; a zombie or a reaped process has
    /// none; a command name with spaces and `)` does not shift the fields.
    #[test]
    fn process_started_reads_the_start_time_of_live_processes_only() {
        let own = process_started(std::process::id()).expect("this process runs");
        assert_eq!(process_started(std::process::id()), Some(own));
        let dir = std::env::temp_dir().join(format!("started-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let odd = dir.join("a) b 7 Z");
        std::fs::copy("/bin/sleep", &odd).expect("copy sleep");
        let mut child = std::process::Command::new(&odd)
            .arg("30")
            .spawn()
            .expect("spawn");
        let pid = child.id();
        let started = process_started(pid).expect("child runs");
        assert!(started >= own, "{started} < {own}");
        child.kill().expect("kill");
        // Killed but not reaped: a zombie, not running.
        let deadline = Instant::now() + Duration::from_secs(5);
        while process_started(pid).is_some() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(process_started(pid), None);
        assert!(
            std::fs::metadata(format!("/proc/{pid}")).is_ok(),
            "reaped early"
        );
        child.wait().expect("reap");
        assert_eq!(process_started(pid), None);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn stopped_in_group_names_a_process_stopped_by_a_signal_until_it_is_continued() {
        use std::os::unix::process::CommandExt;
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .process_group(0)
            .spawn()
            .expect("spawn");
        let pid = child.id();
        let wait_for = |want: Vec<u32>| {
            let deadline = Instant::now() + Duration::from_secs(5);
            while stopped_in_group(pid) != want && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            assert_eq!(stopped_in_group(pid), want);
        };
        wait_for(vec![]);
        assert!(!process_stopped(pid));
        signal_group(pid, libc::SIGSTOP);
        wait_for(vec![pid]);
        assert!(process_stopped(pid));
        signal_group(pid, libc::SIGCONT);
        wait_for(vec![]);
        assert!(!process_stopped(pid));
        child.kill().expect("kill");
        child.wait().expect("reap");
    }
}
