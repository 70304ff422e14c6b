//! End-to-end tests: start the real `supervisor` binary (which starts the real `updater`,
//! `sampler` and `rollout-worker` binaries of this crate), and compare its result bit for bit with
//! the in-process runner. Every wait is bounded, so a hang fails the test instead of blocking CI.
//! Each test uses its own runs directory (`PI2CMA_RUN_DIR`) and run id, so tests run in parallel
//! without seeing each other — which is itself a check of run isolation. Each supervisor runs in
//! its scratch directory, so the recordings (`runs/<run name>-<run id>.mcap` by default) land
//! there.

// Test helpers outside #[test] functions; a failed unwrap is a failed test.
#![allow(clippy::unwrap_used)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, Instant};

use pipeline::result::RunResult;
use session::RunConfig;

#[path = "../../../tests/config_edit.rs"]
mod config_edit;

#[path = "../../../tests/pipeline_checks.rs"]
mod pipeline_checks;
use pipeline_checks::{
    assert_recomputes, assert_recorded, assert_recovered, signal, update_indices, KillOnDrop,
};

const SUPERVISOR: &str = env!("CARGO_BIN_EXE_supervisor");

/// Tests that need the machine to themselves hold it exclusively, the others shared.
static MACHINE: RwLock<()> = RwLock::new(());

#[allow(dead_code)] // held for its Drop
enum Hold {
    Shared(RwLockReadGuard<'static, ()>),
    Exclusive(RwLockWriteGuard<'static, ()>),
}

/// A temporary runs directory, removed on drop; holds [`MACHINE`] while it lives.
struct Scratch(PathBuf, #[allow(dead_code)] Hold);

/// Scratch directories are named per test and emptied when a test begins: two tests of one
/// name, run in parallel, delete each other's runs (their workers then exit on the run
/// directory's disappearance), a failure that shows only when their runs overlap.
#[test]
fn every_test_has_a_scratch_directory_of_its_own() {
    let source = include_str!("e2e.rs");
    let mut seen = std::collections::BTreeSet::new();
    for call in ["Scratch::new(\"", "Scratch::exclusive(\""] {
        for at in source.match_indices(call).map(|(i, _)| i + call.len()) {
            let name = &source[at..at + source[at..].find('"').unwrap()];
            assert!(
                seen.insert(name),
                "two tests use the scratch directory {name:?}"
            );
        }
    }
    assert!(seen.len() > 50, "{seen:?}");
}

/// `--help` is read by users, not by rustdoc: a doc comment's intra-doc link
/// (`[`session::Start::write`]`) showed there as brackets and backticks around a Rust path.
#[test]
fn help_texts_show_no_rustdoc_links() {
    let programs = [
        (
            SUPERVISOR,
            &["", "run", "stop", "scale", "set", "status", "record"][..],
        ),
        (env!("CARGO_BIN_EXE_updater"), &[""][..]),
        (env!("CARGO_BIN_EXE_sampler"), &[""][..]),
        (env!("CARGO_BIN_EXE_rollout-worker"), &[""][..]),
        (env!("CARGO_BIN_EXE_recorder"), &[""][..]),
    ];
    for (program, subcommands) in programs {
        for sub in subcommands {
            let args: Vec<&str> = [*sub, "--help"]
                .into_iter()
                .filter(|a| !a.is_empty())
                .collect();
            let out = Command::new(program).args(&args).output().unwrap();
            let help = String::from_utf8_lossy(&out.stdout);
            assert!(out.status.success(), "{program} {args:?}: {help}");
            assert!(
                !help.contains("[`") && !help.contains("`]"),
                "{program} {args:?} shows a rustdoc link:\n{help}"
            );
        }
    }
}

/// A run id names the run's iceoryx2 root, `/tmp/p2c-<run id>/`, so two tests of one id, run in
/// parallel, share its services and files: one run's clean-up removes the other's, a failure
/// that shows only when their runs overlap. The ids are the literal ones a test passes after
/// its scratch directory (`Run::start*(&scratch, N, …)` and the helpers that take one) or to
/// `run_id(…)`; a test may use its own more than once.
#[test]
fn every_test_has_run_ids_of_its_own() {
    let source = include_str!("e2e.rs");
    let mut owner: std::collections::BTreeMap<u64, &str> = std::collections::BTreeMap::new();
    for function in source.split("\nfn ").skip(1) {
        let name = &function[..function.find('(').unwrap()];
        for call in ["&scratch, ", "run_id("] {
            for at in function.match_indices(call).map(|(i, _)| i + call.len()) {
                let digits: String = function[at..]
                    .chars()
                    .take_while(char::is_ascii_digit)
                    .collect();
                let Ok(id) = digits.parse::<u64>() else {
                    continue;
                };
                let first = *owner.entry(id).or_insert(name);
                assert_eq!(first, name, "two tests use run id {id}");
            }
        }
    }
    assert!(owner.len() > 50, "{owner:?}");
}

impl Scratch {
    fn new(name: &str) -> Self {
        let hold = Hold::Shared(MACHINE.read().unwrap_or_else(|e| e.into_inner()));
        Self::with(name, hold)
    }
    /// For a test whose run goes at full speed and must not be slowed down by the other
    /// tests' runs: the recorder of the pipeline loses messages when it is not scheduled for
    /// about half a millisecond (the services' safe overflow, see crates/record's README).
    fn exclusive(name: &str) -> Self {
        let hold = Hold::Exclusive(MACHINE.write().unwrap_or_else(|e| e.into_inner()));
        Self::with(name, hold)
    }
    fn with(name: &str, hold: Hold) -> Self {
        let dir = std::env::temp_dir().join(format!("p2c-e2e-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir, hold)
    }
    fn path(&self, file: &str) -> PathBuf {
        self.0.join(file)
    }
    /// `PI2CMA_RUN_DIR` (run directories), not the recordings' `runs/`.
    fn runs(&self) -> PathBuf {
        self.0.join("live")
    }
    /// Where a run of `name` and `id` records without `--record` (relative to the scratch
    /// directory, the supervisor's working directory).
    fn recording(&self, name: &str, id: u64) -> PathBuf {
        self.0.join(format!("runs/{name}-{}.mcap", run_id(id)))
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

struct Run {
    child: Child,
    output: Arc<Mutex<Vec<String>>>,
    readers: Vec<std::thread::JoinHandle<()>>,
    run_id: String,
    runs: PathBuf,
}

fn run_id(n: u64) -> String {
    format!("{:016x}", (u64::from(std::process::id()) << 20) ^ n)
}

impl Run {
    /// The prefix of the run's shared memory files (`wire::file_prefix`).
    fn shm_prefix(&self) -> String {
        wire::file_prefix(self.id())
    }

    /// The run's iceoryx2 root directory (`wire::iceoryx_root`).
    fn ipc_root(&self) -> PathBuf {
        wire::iceoryx_root(self.id())
    }

    fn id(&self) -> u64 {
        u64::from_str_radix(&self.run_id, 16).unwrap()
    }

    fn start(scratch: &Scratch, id: u64, args: &[&str]) -> Self {
        Self::start_with_env(scratch, id, args, &[])
    }

    /// `run CONFIG --quiet --result RESULT`: the shape most tests start.
    fn start_quiet(scratch: &Scratch, id: u64, config: &Path, result: &Path) -> Self {
        Self::start_quiet_with_env(scratch, id, config, result, &[])
    }

    fn start_quiet_with_env(
        scratch: &Scratch,
        id: u64,
        config: &Path,
        result: &Path,
        env: &[(&str, &str)],
    ) -> Self {
        let (config, result) = (config.to_str().unwrap(), result.to_str().unwrap());
        Self::start_with_env(scratch, id, &[config, "--quiet", "--result", result], env)
    }

    fn start_with_env(scratch: &Scratch, id: u64, args: &[&str], env: &[(&str, &str)]) -> Self {
        Self::spawn(scratch, id, Command::new(SUPERVISOR), args, env)
    }

    /// As `nohup` starts it: SIGHUP ignored (the shell's `trap '' HUP` is kept across `exec`).
    fn start_ignoring_sighup(scratch: &Scratch, id: u64, args: &[&str]) -> Self {
        let mut cmd = Command::new("sh");
        cmd.args(["-c", "trap '' HUP; exec \"$0\" \"$@\"", SUPERVISOR]);
        Self::spawn(scratch, id, cmd, args, &[])
    }

    /// With SIGHUP's default action whatever the tests were started with (they may run under
    /// nohup themselves). `env --default-signal` is GNU coreutils ≥ 8.31.
    fn start_with_default_sighup(scratch: &Scratch, id: u64, args: &[&str]) -> Self {
        let mut cmd = Command::new("env");
        cmd.args(["--default-signal=HUP", SUPERVISOR]);
        Self::spawn(scratch, id, cmd, args, &[])
    }

    /// `cmd run ARGS --run-id ID` (cmd: the supervisor, or what execs it), in the scratch
    /// directory's run directory unless `env` names another.
    fn spawn(
        scratch: &Scratch,
        id: u64,
        mut cmd: Command,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let run_id = run_id(id);
        let mut child = cmd
            .arg("run")
            .args(args)
            .args(["--run-id", &run_id])
            .current_dir(&scratch.0)
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .envs(env.iter().copied())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let output = Arc::new(Mutex::new(Vec::new()));
        let mut readers = Vec::new();
        for stream in [
            Box::new(child.stdout.take().unwrap()) as Box<dyn std::io::Read + Send>,
            Box::new(child.stderr.take().unwrap()),
        ] {
            let out = output.clone();
            readers.push(std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    out.lock().unwrap().push(line);
                }
            }));
        }
        Self {
            child,
            output,
            readers,
            run_id,
            runs: scratch.runs(),
        }
    }

    fn text(&self) -> String {
        self.output.lock().unwrap().join("\n")
    }

    /// Waits until the output holds `needle`; fails at `end`.
    fn wait_output(&self, needle: &str, end: Instant) {
        while !self.text().contains(needle) {
            assert!(
                Instant::now() < end,
                "no `{needle}` in the output:\n{}",
                self.text()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn wait(&mut self, bound: Duration) -> ExitStatus {
        let end = Instant::now() + bound;
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                // The pipes close with the supervisor (its children have pipes of their own).
                for r in self.readers.drain(..) {
                    r.join().unwrap();
                }
                return s;
            }
            if Instant::now() > end {
                let _ = self.child.kill();
                panic!("supervisor still running after {bound:?}:\n{}", self.text());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits for the supervisor to exit (bounded) and asserts it exited with `code`, showing its
    /// output otherwise.
    fn wait_exit(&mut self, bound: Duration, code: i32) {
        let status = self.wait(bound);
        assert_eq!(status.code(), Some(code), "{}", self.text());
    }

    /// `supervisor <args> --run <id>`; returns (success, stdout + stderr).
    fn ctl(&self, args: &[&str]) -> (bool, String) {
        let out = Command::new(SUPERVISOR)
            .args(args)
            .args(["--run", &self.run_id])
            .env("PI2CMA_RUN_DIR", &self.runs)
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        (out.status.success(), text)
    }

    /// [`Run::ctl`] that must succeed; returns the reply.
    fn ctl_ok(&self, args: &[&str]) -> String {
        let (ok, reply) = self.ctl(args);
        assert!(ok, "{reply}");
        reply
    }

    /// Polls `status` until `pred` holds (bounded); the run's socket may not exist yet.
    fn wait_status(&self, what: &str, pred: impl Fn(&str) -> bool) -> String {
        let end = Instant::now() + Duration::from_secs(30);
        loop {
            let (ok, s) = self.ctl(&["status"]);
            if ok && pred(&s) {
                return s;
            }
            assert!(
                Instant::now() < end,
                "timed out waiting for {what}; last status:\n{s}\noutput:\n{}",
                self.text()
            );
            std::thread::sleep(Duration::from_millis(30));
        }
    }
}

impl Drop for Run {
    /// A failed test must not leave its run behind: interrupt, then kill.
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            let _ = Command::new("kill")
                .args(["-INT", &self.child.id().to_string()])
                .status();
            let end = Instant::now() + Duration::from_secs(10);
            while self.child.try_wait().ok().flatten().is_none() && Instant::now() < end {
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

fn updates_in(status: &str) -> u64 {
    status
        .lines()
        .find_map(|l| l.strip_prefix("updates: "))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// (role name, pid) of every process in a status reply.
fn pids_in(status: &str) -> Vec<(String, u32)> {
    status
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            let name = it.next()?.to_string();
            (it.next()? == "pid").then_some(())?;
            Some((name, it.next()?.parse().ok()?))
        })
        .collect()
}

/// The pid of process `name` (`worker-1`, `recorder`, …) in a status reply.
fn pid_of(status: &str, name: &str) -> u32 {
    pids_in(status)
        .into_iter()
        .find_map(|(n, pid)| (n == name).then_some(pid))
        .unwrap_or_else(|| panic!("no {name} in the status:\n{status}"))
}

/// Nothing of run `run_id` left: no process, no run directory, no shared memory, no iceoryx2
/// files.
fn assert_nothing_left(run: &Run) {
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let cmdline = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        if String::from_utf8_lossy(&cmdline).contains(&run.run_id) && supervisor::process_alive(pid)
        {
            panic!(
                "process {pid} of the run is still running: {}",
                String::from_utf8_lossy(&cmdline).replace('\0', " ")
            );
        }
    }
    let dir = run.runs.join(&run.run_id);
    assert!(!dir.exists(), "{} left behind", dir.display());
    let root = run.ipc_root();
    assert!(!root.exists(), "{} left behind", root.display());
    let prefix = run.shm_prefix();
    for d in ["/dev/shm", "/tmp", "/tmp/iceoryx2"] {
        if let Ok(entries) = std::fs::read_dir(d) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().to_string();
                assert!(!name.starts_with(&prefix), "{d}/{name} left behind");
            }
        }
    }
}

/// The A1 config with changes applied by text replacement (checked to apply).
fn config(edits: &[(&str, &str)]) -> String {
    config_edit::edited(session::DEFAULT_CONFIG, edits)
}

fn write_config(scratch: &Scratch, name: &str, text: &str) -> PathBuf {
    let p = scratch.path(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// The rollout delay never changes a cost; a reference run leaves it out to be fast.
fn without_rollout_delay(cfg: &mut RunConfig) {
    if let session::TaskSection::ViaPoint(v) = &mut cfg.task {
        v.rollout_delay_ms = 0.0;
    }
}

/// The mean and covariance the in-process runner reaches in `updates` updates of config `text`.
fn in_process(text: &str, updates: u64) -> (Vec<f64>, Vec<f64>) {
    let mut cfg = RunConfig::parse(text, Path::new("test.toml")).unwrap();
    cfg.run.updates = Some(updates);
    without_rollout_delay(&mut cfg);
    let (_, d) = session::run_session(&cfg, cfg.run.seed, &mut session::NoObserver).unwrap();
    (d.mean.as_slice().to_vec(), d.covariance.as_slice().to_vec())
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Asserts the result's final distribution equals the in-process run's bit for bit.
fn assert_bit_identical(config_text: &str, result: &Path) {
    let r = RunResult::read(result).unwrap();
    let (mean, cov) = r.exact().unwrap();
    let (in_process_mean, in_process_cov) = in_process(config_text, r.updates);
    assert_eq!(bits(&mean), bits(&in_process_mean), "mean differs");
    assert_eq!(bits(&cov), bits(&in_process_cov), "covariance differs");
}

/// Asserts each rollout's recorded interval is the one its worker ran it in: a worker runs one
/// rollout at a time, so its intervals follow one another. (An interval reconstructed from when
/// the recorder took the costs in is off by up to its round, a millisecond, and overlaps.)
fn assert_rollouts_timed_by_their_workers(rec: &record::Recording) {
    let mut by_worker: std::collections::BTreeMap<&str, Vec<(u64, u64)>> = Default::default();
    for r in &rec.rollouts {
        assert!(r.start_ns > 0 && r.end_ns >= r.start_ns, "{r:?}");
        by_worker
            .entry(r.worker.as_str())
            .or_default()
            .push((r.start_ns, r.end_ns));
    }
    assert!(by_worker.len() > 1, "{:?}", by_worker.keys());
    for (worker, mut intervals) in by_worker {
        intervals.sort_unstable();
        for w in intervals.windows(2) {
            // Exact: NTP slews the monotonic clock as it does the wall clock (only a step of
            // the wall clock, which time daemons avoid, could break this).
            assert!(
                w[1].0 >= w[0].1,
                "{worker}: a rollout ran {:?} and the next began at {} ns",
                w[0],
                w[1].0
            );
        }
    }
}

/// Asserts the recorded distribution after the last update equals the in-process run's of as
/// many updates, bit for bit.
fn assert_recording_matches_in_process(config_text: &str, rec: &record::Recording) {
    let last = rec.updates.last().unwrap();
    let after = record::distribution_from_proto(last.after.as_ref().unwrap()).unwrap();
    let (mean, cov) = in_process(config_text, last.update + 1);
    assert_eq!(bits(after.mean.as_slice()), bits(&mean));
    assert_eq!(bits(after.covariance.as_slice()), bits(&cov));
}

/// Whether the recording logged `event` for process `name`.
fn logged(rec: &record::Recording, event: &str, name: &str) -> bool {
    rec.logs.iter().any(|l| l.event == event && l.name == name)
}

/// Config edit: 2 ms rollouts (the same costs), a run slow enough to act on while it runs.
const DELAYED: (&str, &str) = (
    "viapoint_weight = 1000.0",
    "viapoint_weight = 1000.0\nrollout_delay_ms = 2.0",
);

/// Config edit: no `run.updates`, a run that goes on until it is stopped.
const UNBOUNDED: (&str, &str) = ("updates = 40\n", "");

#[test]
fn a1_is_bit_identical_to_in_process_with_1_3_and_8_workers_running_at_once() {
    let scratch = Scratch::new("a1");
    let mut runs: Vec<(Run, PathBuf)> = [1usize, 3, 8]
        .iter()
        .map(|&w| {
            let result = scratch.path(&format!("result-{w}.toml"));
            let run = Run::start(
                &scratch,
                w as u64,
                &[
                    "--workers",
                    &w.to_string(),
                    "--quiet",
                    "--result",
                    result.to_str().unwrap(),
                ],
            );
            (run, result)
        })
        .collect();
    for (run, result) in &mut runs {
        run.wait_exit(Duration::from_secs(60), 0);
        assert!(run.text().contains("summary: run"), "{}", run.text());
        let r = RunResult::read(result).unwrap();
        assert_eq!(r.updates, 40);
        assert!(r.complete);
        assert_eq!(r.task_changes.len(), 1);
        assert_eq!(r.task_changes[0].from_update, 20);
        assert_bit_identical(session::DEFAULT_CONFIG, result);
        assert_nothing_left(run);
    }
}

/// Every method and weighting: the configs of Fig. 2 besides A1, CEM (which none of them
/// uses) and A1 with per-time-step weighting under either temporal averaging, through the
/// pipeline with two workers: the same bits as in-process. The core is shared, but the pipeline carries each method's own inputs (the
/// evaluation rollout, per-step costs under time-step weighting, the decayed covariance).
#[test]
fn every_method_is_bit_identical_to_in_process() {
    let scratch = Scratch::new("methods");
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config");
    let read = |name: &str| std::fs::read_to_string(dir.join(format!("{name}.toml"))).unwrap();
    let cem = read("A1")
        .replacen("name = \"A1\"", "name = \"cem\"", 1)
        .replacen("method = \"pi2-cma\"", "method = \"cem\"\nelites = 5", 1)
        .replacen("eliteness = 15.0\n", "", 1);
    assert!(cem.contains("method = \"cem\"") && !cem.contains("eliteness"));
    let mut cases: Vec<(String, String)> = ["A2", "A3", "A4", "C1", "C2", "C3", "D"]
        .iter()
        .map(|n| (n.to_string(), read(n)))
        .collect();
    cases.push(("cem".into(), cem));
    for temporal in ["remaining-steps", "basis-activation"] {
        let per_step = read("A1").replacen(
            "weighting = \"episodic\"",
            &format!("weighting = \"per-time-step\"\ntemporal_averaging = \"{temporal}\""),
            1,
        );
        assert!(per_step.contains("per-time-step"));
        cases.push((format!("A1-{temporal}"), per_step));
    }
    // One B×B covariance per joint: 7 blocks of 3, each through the per-time-step kernel.
    let per_dimension = read("tball").replacen(
        "[optimizer]\n",
        "[optimizer]\ncovariance = \"per-dimension\"\n",
        1,
    );
    let per_dimension = per_dimension.replacen(
        "weighting = \"episodic\"",
        "weighting = \"per-time-step\"",
        1,
    );
    assert!(per_dimension.contains("per-dimension") && per_dimension.contains("per-time-step"));
    cases.push(("tball-per-dimension".into(), per_dimension));
    // A few at a time: each run has its updater, sampler and two workers.
    for (batch, chunk) in cases.chunks(4).enumerate() {
        let mut runs: Vec<(Run, PathBuf, String)> = chunk
            .iter()
            .enumerate()
            .map(|(i, (name, text))| {
                assert!(text.contains("updates = 40\n"), "{name}");
                let text = text.replacen("updates = 40\n", "updates = 8\n", 1);
                let cfg = write_config(&scratch, &format!("{name}.toml"), &text);
                let result = scratch.path(&format!("result-{name}.toml"));
                // Ids 920–939 are this test's, one per case.
                let id = 920 + (batch * 4 + i) as u64;
                let run = Run::start(
                    &scratch,
                    id,
                    &[
                        cfg.to_str().unwrap(),
                        "--workers",
                        "2",
                        "--quiet",
                        "--no-record",
                        "--result",
                        result.to_str().unwrap(),
                    ],
                );
                (run, result, text)
            })
            .collect();
        for (run, result, text) in &mut runs {
            run.wait_exit(Duration::from_secs(60), 0);
            let r = RunResult::read(result).unwrap();
            assert_eq!((r.updates, r.complete), (8, true), "{}", run.text());
            assert_bit_identical(text, result);
            assert_nothing_left(run);
        }
    }
}

#[test]
fn supervisor_alone_hosts_all_roles_as_after_cargo_run() {
    // `cargo run -p supervisor` builds only the supervisor binary; it then runs the three
    // roles itself. A copy in a directory of its own has no sibling binaries.
    let scratch = Scratch::new("alone");
    let alone = scratch.path("supervisor");
    std::fs::copy(SUPERVISOR, &alone).unwrap();
    let result = scratch.path("result.toml");
    // A child that another test thread forks while the copy is open for writing holds that
    // file descriptor until it execs: exec fails with ETXTBSY meanwhile (seen once in a full
    // `cargo test --workspace`), so that is retried.
    let end = Instant::now() + Duration::from_secs(10);
    let out = loop {
        let tried = Command::new(&alone)
            .args(["run", "--quiet", "--result", result.to_str().unwrap()])
            .args(["--run-id", &run_id(50)])
            .current_dir(&scratch.0)
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output();
        match tried {
            Err(e)
                if e.kind() == std::io::ErrorKind::ExecutableFileBusy && Instant::now() < end =>
            {
                std::thread::sleep(Duration::from_millis(20));
            }
            other => break other.unwrap(),
        }
    };
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("summary: run"), "{text}");
    // The run's time is given with digits that say something: 40 updates take milliseconds,
    // which "0.01 s" gave to within 50 %. It agrees with the rate printed beside it.
    let (elapsed, rate) = text
        .split_once("updates of 40 in ")
        .and_then(|(_, t)| {
            let (time, rest) = t.split_once(" (")?;
            let (n, unit) = time.split_once(' ')?;
            let scale = match unit {
                "s" => 1.0,
                "ms" => 1e-3,
                _ => return None,
            };
            let rate = rest.split_once(" updates/s")?.0.parse::<f64>().ok()?;
            Some((n.parse::<f64>().ok()? * scale, rate))
        })
        .unwrap_or_else(|| panic!("no time and rate in {text}"));
    assert!(
        ((40.0 / elapsed) / rate - 1.0).abs() < 0.1,
        "40 updates in {elapsed} s, but {rate} updates/s: {text}"
    );
    assert_bit_identical(session::DEFAULT_CONFIG, &result);
    // The recorder role too: the quick start records without crate record's binaries. (At
    // full speed beside the other tests' runs it may lose updates; the recording test checks
    // that every update is recorded, on a machine to itself.)
    let rec = record::read_recording(&scratch.recording("A1", 50)).unwrap();
    assert!(rec.indexed && !rec.updates.is_empty(), "{text}");
    assert_recomputes(&rec);
}

#[test]
fn killed_worker_is_restarted_and_the_result_stays_bit_identical() {
    let scratch = Scratch::new("kill");
    let text = config(&[("updates = 40", "updates = 200"), DELAYED]);
    let cfg = write_config(&scratch, "kill.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 100, &cfg, &result);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    let victim = pid_of(&status, "worker-1");
    signal(victim, "-9");
    let after = run.wait_status("restarted worker-1", |s| {
        s.contains("worker-1 pid")
            && !s.contains(&format!("pid {victim} "))
            && s.contains("restarts 1")
    });
    assert!(after.contains("incarnation 1"), "{after}");
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(
        out.contains(&format!("worker-1 (pid {victim}) died")),
        "{out}"
    );
    assert!(!supervisor::process_alive(victim));
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 200);
    assert_bit_identical(&text, &result);
    // The recording's health log has the loss and the restart.
    let rec = record::read_recording(&scratch.recording("A1", 100)).unwrap();
    let crash = rec.logs.iter().any(|l| {
        l.event == "crash"
            && l.name == "worker-1"
            && l.message.contains("SIGKILL")
            && l.pid == victim
    });
    assert!(crash, "{:#?}", rec.logs);
    assert!(logged(&rec, "restart", "worker-1"), "{:#?}", rec.logs);
    assert_recorded(&rec, 200);
    assert_nothing_left(&run);
}

/// A worker whose simulator or robot stops answering holds its chunk forever. With
/// `pipeline.rollout_timeout_ms` the sampler reports it, the supervisor kills and restarts it,
/// its rollouts go to the others, and the run ends as if nothing had happened.
#[test]
fn a_hung_worker_is_killed_and_restarted_and_the_result_stays_bit_identical() {
    let scratch = Scratch::new("hung");
    let text = config(&[
        ("updates = 40", "updates = 30"),
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 400\nfault_hang_at_update = 4",
        ),
    ]);
    let cfg = write_config(&scratch, "hung.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 730, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    for w in 0..3 {
        let said = format!("worker-{w} (pid ");
        assert!(
            out.lines().any(|l| l.contains(&said)
                && l.contains("hung: no rollout done for")
                && l.contains("of update 4")),
            "{out}"
        );
    }
    // At least the three hung ones; on a loaded machine a restarted worker's first chunk may
    // also run over (the limit counts from the hand-out), which costs a restart, not the result.
    let restarts: u32 = out
        .split(" restarts")
        .next()
        .and_then(|s| s.rsplit(", ").next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0);
    assert!(restarts >= 3, "{out}");
    assert_bit_identical(&text, &result);
    let rec = record::read_recording(&scratch.recording("A1", 730)).unwrap();
    for w in 0..3 {
        let name = format!("worker-{w}");
        let hung = rec
            .logs
            .iter()
            .any(|l| l.event == "crash" && l.name == name && l.message.contains("hung"));
        assert!(hung, "{:#?}", rec.logs);
        assert!(logged(&rec, "restart", &name), "{:#?}", rec.logs);
    }
    assert_recorded(&rec, 30);
    assert_nothing_left(&run);
}

/// A worker an operator freezes (SIGSTOP: Ctrl-Z, an e-stop script) is not hung: `status`
/// lists it as stopped by a signal (it listed it as running), and when it outlasts
/// `rollout_timeout_ms` the kill says that it is stopped rather than "hung", which read as a
/// fault of the task. The run goes on as if nothing had happened.
#[test]
fn a_worker_stopped_by_a_signal_is_shown_as_stopped_and_not_called_hung() {
    let scratch = Scratch::new("sigstopped");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 1500",
        ),
    ]);
    let cfg = write_config(&scratch, "sigstopped.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 27800, &cfg, &result);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let victim = pid_of(&status, "worker-1");
    signal(victim, "-STOP");
    let shown = format!(
        "worker-1 pid {victim} incarnation 0 (stopped by a signal: it runs nothing until `kill -CONT -- -{victim}`)"
    );
    let status = run.wait_status("worker-1 shown stopped", |s| s.contains(&shown));
    assert!(
        status.contains("3 running (target 3, max 16), 1 of them stopped by a signal"),
        "{status}"
    );
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("worker-1 (pid ", end);
    run.wait_output(", incarnation 1) is ready", end);
    let out = run.text();
    assert!(
        out.lines().any(|l| l.contains(&format!(
            "worker-1 (pid {victim}) is stopped by a signal (SIGSTOP, Ctrl-Z), not hung, but \
             holds its rollouts as a hung worker does: no rollout done for"
        )) && l.ends_with("; killing it")),
        "{out}"
    );
    assert!(!out.contains(") hung: "), "{out}");
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// `rollout_timeout_ms` bounds one rollout, not a worker's chunk: a worker that sends the cost
/// of its chunk's first rollout and hangs in the second is killed about one timeout after that
/// cost, not after the timeout times the chunk's length from the hand-out (5 rollouts of 400 ms:
/// 2 s, as before each worker reported its rollouts within a chunk).
#[test]
fn a_worker_hung_in_its_chunks_second_rollout_is_killed_after_about_one_timeout() {
    let scratch = Scratch::new("hung-second");
    let text = config(&[
        ("updates = 40", "updates = 12"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
        ),
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 400\nfault_hang_at_update = 3\n\
             fault_hang_at_chunk_rollout = 2",
        ),
    ]);
    let cfg = write_config(&scratch, "hung-second.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1300, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    // K = 15, 3 workers and 20 ms rollouts: chunks of 2 (50 ms of rollouts at most, the
    // sampler's CHUNK_TIME; 5 in update 0) at the start of update 3, so every first
    // incarnation hangs in its second rollout there.
    let hung: Vec<&str> = out.lines().filter(|l| l.contains(") hung: ")).collect();
    assert_eq!(hung.len(), 3, "{out}");
    for line in hung {
        let held_ms: u64 = line
            .split(" for ")
            .nth(2)
            .and_then(|s| s.split(" ms").next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no held time in {line}"));
        // One rollout of 20 ms, then one timeout, checked every 0.1 s: about 0.5 s; well under
        // the 2 s of five timeouts even on a loaded machine.
        assert!(
            (400..1200).contains(&held_ms),
            "held {held_ms} ms: {line}\n{out}"
        );
        assert!(line.contains("of update 3"), "{line}");
    }
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A sampler that is not scheduled for longer than `rollout_timeout_ms` (stopped here; a
/// paused VM or a debugger does the same) must not take the chunks its workers finished
/// meanwhile for hung ones: it checked the timeout before it read their Ready messages, and
/// the supervisor killed healthy workers (with `restart_limit = 0` that failed the run).
#[test]
fn a_sampler_that_was_stopped_does_not_take_finished_chunks_for_hung_workers() {
    let scratch = Scratch::new("sampler-stop");
    let text = config(&[
        ("updates = 40", "updates = 20"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
        ),
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 600\nrestart_limit = 0",
        ),
    ]);
    let cfg = write_config(&scratch, "sampler-stop.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 951, &cfg, &result);
    let s = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let sampler = pid_of(&s, "sampler");
    // Longer than a whole chunk's limit (5 rollouts of 600 ms): the workers finish theirs
    // meanwhile and wait.
    signal(sampler, "-STOP");
    std::thread::sleep(Duration::from_secs(4));
    signal(sampler, "-CONT");
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(!out.contains("hung"), "{out}");
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A worker that hangs and is then scaled away is still the supervisor's: over
/// `rollout_timeout_ms` it is killed (it was taken for one that joined from outside, "not
/// started by this supervisor", and left holding its process until the run ended).
#[test]
fn a_hung_worker_that_was_scaled_down_is_still_killed() {
    let scratch = Scratch::new("hung-scaled");
    let text = config(&[
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
        ),
        ("workers = 3", "workers = 4"),
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 600",
        ),
    ]);
    let cfg = write_config(&scratch, "hung-scaled.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 952, &cfg, &result);
    let s = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let victim = pid_of(&s, "worker-3");
    signal(victim, "-STOP");
    run.ctl_ok(&["scale", "--workers", "3"]);
    let s = run.wait_status("worker-3 gone", |s| !s.contains("worker-3 pid"));
    assert!(updates_in(&s) < 40, "{s}");
    assert!(!supervisor::process_alive(victim));
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    // Stopped (SIGSTOP) to hang, and killed as a hung worker is; the line says it was stopped.
    assert!(
        out.contains(&format!(
            "worker-3 (pid {victim}) is stopped by a signal (SIGSTOP, Ctrl-Z), not hung, but \
             holds its rollouts as a hung worker does: no rollout done for"
        )),
        "{out}"
    );
    assert!(!out.contains("not started by this supervisor"), "{out}");
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// The backoff a restart is announced with is the one it waits: at most 5 s (the 7th restart
/// said "in 6400 ms" and came after 5 s).
#[test]
fn a_restart_says_the_backoff_it_waits_at_most_5_s() {
    let scratch = Scratch::new("backoff");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        ("max_workers = 16", "max_workers = 16\nrestart_limit = 10"),
    ]);
    let cfg = write_config(&scratch, "backoff.toml", &text);
    let mut run = Run::start(
        &scratch,
        953,
        &[cfg.to_str().unwrap(), "--quiet", "--no-record"],
    );
    let mut s = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    for n in 1..=7 {
        let victim = pid_of(&s, "worker-0");
        signal(victim, "-9");
        let said = format!("restart {n} of 10 in ");
        run.wait_output(&said, Instant::now() + Duration::from_secs(10));
        if n < 7 {
            s = run.wait_status("worker-0 restarted", |s| {
                s.contains("worker-0 pid") && !s.contains(&format!("pid {victim} "))
            });
        }
    }
    assert!(
        run.text().contains("restart 7 of 10 in 5000 ms"),
        "{}",
        run.text()
    );
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    assert_nothing_left(&run);
}

#[test]
fn exhausted_restart_limit_stops_the_run_with_the_reason() {
    let scratch = Scratch::new("limit");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        ("max_workers = 16", "max_workers = 16\nrestart_limit = 0"),
    ]);
    let cfg = write_config(&scratch, "limit.toml", &text);
    let mut run = Run::start(&scratch, 150, &[cfg.to_str().unwrap(), "--quiet"]);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let pids = pids_in(&status);
    signal(pid_of(&status, "worker-2"), "-9");
    run.wait_exit(Duration::from_secs(20), 1);
    let out = run.text();
    assert!(
        out.contains("worker-2 died") && out.contains("restart limit"),
        "{out}"
    );
    for (name, pid) in pids {
        assert!(
            !supervisor::process_alive(pid),
            "{name} (pid {pid}) survived"
        );
    }
    // The recording says why the run ended, not only that worker-2 crashed.
    let rec = record::read_recording(&scratch.recording("A1", 150)).unwrap();
    let failed = rec.logs.iter().any(|l| {
        l.event == "error"
            && l.name == "supervisor"
            && l.message.starts_with("the run failed: worker-2 died")
            && l.message.contains("restart limit")
    });
    assert!(failed, "{:#?}", rec.logs);
    assert_nothing_left(&run);
}

/// `run CONFIG --quiet --result RESULT` with the sampler's trace (PI2CMA_TRACE) in its output.
fn start_traced(scratch: &Scratch, id: u64, config: &Path, result: &Path) -> Run {
    Run::start_quiet_with_env(scratch, id, config, result, &[("PI2CMA_TRACE", "1")])
}

/// A rollout worker the supervisor does not manage (as one written in another language would
/// be), joining `run` as worker 5 with `config`.
fn join_as_worker_5(run: &Run, config: &Path) -> Child {
    join_as_worker(run, config, 5)
}

fn join_as_worker(run: &Run, config: &Path, w: u32) -> Child {
    let run_dir = run.runs.join(&run.run_id);
    Command::new(env!("CARGO_BIN_EXE_rollout-worker"))
        .arg("--config")
        .arg(config)
        .arg("--run-dir")
        .arg(&run_dir)
        .args(["--run-id", &run.run_id, "--worker", &w.to_string()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// Two workers in one slot would both run its rollouts (on a robot, twice for real): a worker
/// that joins a slot the supervisor's worker holds is stopped, and scaling up skips the slots
/// that joined workers hold. Before, both happened silently, and every update ran slot 1's
/// rollouts twice.
#[test]
fn joined_workers_never_share_a_slot() {
    let scratch = Scratch::new("slots");
    let text = config(&[
        ("updates = 40", "updates = 100000"),
        DELAYED,
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "slots.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 850, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let run_config = run.runs.join(&run.run_id).join("config.toml");

    let mut intruder = KillOnDrop(join_as_worker(&run, &run_config, 0));
    let end = Instant::now() + Duration::from_secs(30);
    let stopped = loop {
        if let Some(status) = intruder.0.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < end, "not stopped:\n{}", run.text());
        std::thread::sleep(Duration::from_millis(20));
    };
    let _ = stopped;
    let said = format!("pid {}) joined slot 0, which worker-0", intruder.0.id());
    assert!(run.text().contains(&said), "{}", run.text());

    let guest = KillOnDrop(join_as_worker(&run, &run_config, 1));
    let joined = format!("worker-1 (pid {}) joined the run", guest.0.id());
    run.wait_output(&joined, end);
    run.ctl_ok(&["scale", "--workers", "3"]);
    let status = run.wait_status("3 workers of ours", |s| s.contains("workers: 3 running"));
    assert_eq!(status.matches("worker-1 pid").count(), 1, "{status}");
    for w in [0, 2, 3] {
        assert!(status.contains(&format!("worker-{w} pid")), "{status}");
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    // The joined worker sees its run directory gone and exits by itself.
    let mut guest = guest;
    let end = Instant::now() + Duration::from_secs(10);
    while guest.0.try_wait().unwrap().is_none() {
        assert!(Instant::now() < end, "the joined worker outlived its run");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_nothing_left(&run);
}

/// A process of `run` that the supervisor knows nothing of (as a worker of another config or
/// revision would be), with its node named `name`.
fn foreign_process(run: &Run, name: &str) -> pipeline::Context {
    let run_dir = run.runs.join(&run.run_id);
    let args = pipeline::ProcessArgs {
        config: run_dir.join("config.toml"),
        run_dir,
        run_id: run.id(),
    };
    pipeline::Context::new(&args, name).unwrap()
}

/// Costs of an update the updater cannot reach (it runs at most the lag bound ahead of the
/// recorder, and takes costs of the update it is at only) are dropped by the recorder with one
/// warning naming the update and the worker, however often they come, and the run is recorded
/// whole. Before, the recorder kept a K × N batch for each such update for good, and said
/// nothing.
#[test]
fn costs_of_an_update_out_of_the_updaters_reach_are_dropped_with_one_warning() {
    use iceoryx2::prelude::AllocationStrategy;
    let scratch = Scratch::new("far-costs");
    let text = config(&[("updates = 40", "updates = 150"), DELAYED]);
    let cfg = write_config(&scratch, "far.toml", &text);
    let mcap = scratch.path("far.mcap");
    let args = [
        cfg.to_str().unwrap(),
        "--quiet",
        "--record",
        mcap.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 5151, &args);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let ctx = foreign_process(&run, "far-costs");
    let steps = ctx.limits.steps;
    let costs = wire::costs(&ctx.node, ctx.run_id, &ctx.limits)
        .unwrap()
        .publisher_builder()
        .initial_max_slice_len(steps)
        .allocation_strategy(AllocationStrategy::Static)
        .create()
        .unwrap();
    let recorder = ctx.notifier(wire::process::RECORDER).unwrap();
    let far = 1_000_000_000_000u64;
    for i in 0..40u64 {
        let sample = costs.loan_slice_uninit(steps).unwrap();
        let mut sample = sample.write_from_fn(|_| 1.0);
        *sample.user_header_mut() = wire::CostHeader {
            run_id: ctx.run_id,
            update: far + i,
            rollout: 0,
            worker: 2,
            ..Default::default()
        };
        sample.send().unwrap();
        recorder.notify_with_custom_event_id(wire::WAKE).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    drop((costs, recorder, ctx));
    run.wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(&mcap).unwrap();
    assert_recorded(&rec, 150);
    assert_recording_matches_in_process(&text, &rec);
    let logged = warnings(&rec);
    assert_eq!(logged.len(), 1, "{logged:?}");
    let (_, name, message) = &logged[0];
    assert_eq!(name, "worker-2");
    assert!(
        message.starts_with(&format!(
            "cost of update {far} (rollout 0) from worker-2 dropped: the updater runs at most"
        )),
        "{message}"
    );
    assert_nothing_left(&run);
}

/// A `Ready` from a worker id at or above `pipeline.max_workers` (a worker started with another
/// config, or of another revision) is ignored with one warning that names the id and the bound,
/// however often it comes, and the run goes on. Before, the sampler opened `work/<w>` and the
/// worker's doorbell for it, outside the slots the run is sized for, and handed it rollouts.
#[test]
fn a_ready_from_beyond_max_workers_is_ignored_with_one_warning() {
    let scratch = Scratch::new("beyond-slots");
    let text = config(&[
        ("updates = 40", "updates = 100000"),
        DELAYED,
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "beyond.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = start_traced(&scratch, 5150, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let ctx = foreign_process(&run, "beyond-slots");
    let ready = {
        use pipeline::Ports as _;
        wire::ready(&ctx.node, ctx.run_id, &ctx.limits)
            .unwrap()
            .publisher("ready")
            .unwrap()
    };
    let sampler = ctx.notifier(wire::process::SAMPLER).unwrap();
    let worker = ctx.limits.max_workers as u32 + 7;
    for _ in 0..5 {
        let request = wire::Ready {
            run_id: ctx.run_id,
            chunk: wire::Ready::NO_CHUNK,
            worker,
            incarnation: 0,
            pid: std::process::id(),
            flags: 0,
        };
        ready.send_copy(request).unwrap();
        sampler.notify_with_custom_event_id(wire::WAKE).unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    let end = Instant::now() + Duration::from_secs(30);
    let warning = format!(
        "[sampler] warning: worker {worker} (pid {}, incarnation 0) asked for work, but worker \
         ids must be below pipeline.max_workers = {}",
        std::process::id(),
        ctx.limits.max_workers
    );
    run.wait_output(&warning, end);
    let at = updates_in(&run.ctl_ok(&["status"]));
    run.wait_status("3 more updates", |s| updates_in(s) >= at + 3);
    drop((ready, sampler, ctx));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    let out = run.text();
    assert_eq!(
        out.matches(&format!("warning: worker {worker} ")).count(),
        1,
        "{out}"
    );
    assert!(!out.contains(&format!("-> w{worker}")), "{out}");
    assert_nothing_left(&run);
}

#[test]
fn a_crashed_unsupervised_worker_is_found_by_the_sampler() {
    // A worker the supervisor does not manage (as one written in another language would be):
    // when it is SIGKILLed nobody reports it, the sampler finds its dead node.
    let scratch = Scratch::new("foreign");
    let text = config(&[
        ("updates = 40", "updates = 250"),
        DELAYED,
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "foreign.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = start_traced(&scratch, 250, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let run_config = run.runs.join(&run.run_id).join("config.toml");
    let mut foreign = join_as_worker_5(&run, &run_config);
    // The sampler's trace shows when the foreign worker got a chunk; kill it while it works.
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("-> w5:", end);
    // The supervisor says it joined, and status lists it.
    let pid = foreign.id();
    let joined = format!("worker-5 (pid {pid}) joined the run (started outside");
    run.wait_output(&joined, end);
    let (_, status) = run.ctl(&["status"]);
    assert!(
        status.contains(&format!("worker-5 pid {pid} (joined;"))
            && status.contains(", and 1 joined from outside"),
        "{status}"
    );
    foreign.kill().unwrap();
    foreign.wait().unwrap();
    // Its end is said, as its start was.
    let gone = format!("worker-5 (pid {pid}), which joined from outside, is gone");
    run.wait_output(&gone, end);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(run.text().contains("lost w5.0"), "{}", run.text());
    assert_eq!(RunResult::read(&result).unwrap().updates, 250);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A worker started by hand and stopped by its user (Ctrl-C, SIGTERM) in the middle of its chunk
/// ends in order: it removes its node, so there is no dead node to find, and nobody reports a
/// worker the supervisor did not start. Before, the sampler waited for the rest of its chunk
/// forever and the run hung, while the supervisor said the sampler had handed its rollouts on.
#[test]
fn an_unsupervised_worker_stopped_in_its_chunk_loses_its_rollouts_to_the_others() {
    let scratch = Scratch::new("foreign-term");
    let text = config(&[
        ("updates = 40", "updates = 60"),
        DELAYED,
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "foreign.toml", &text);
    // The joining worker's own config: the run's, with rollouts slow enough that the signal
    // surely finds it in the middle of its chunk (8 rollouts of 0.5 s).
    let slow = write_config(
        &scratch,
        "slow.toml",
        &config_edit::edited(
            &text,
            &[("rollout_delay_ms = 2.0", "rollout_delay_ms = 500.0")],
        ),
    );
    let result = scratch.path("result.toml");
    let mut run = start_traced(&scratch, 270, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let mut foreign = KillOnDrop(join_as_worker_5(&run, &slow));
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("-> w5:", end);
    signal(foreign.0.id(), "-TERM");
    foreign.0.wait().unwrap();
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    let lost = out
        .lines()
        .find(|l| l.contains("lost w5.0, holding "))
        .unwrap_or_else(|| panic!("w5 never lost:\n{out}"));
    assert!(!lost.ends_with("holding 0"), "{lost}");
    assert_eq!(RunResult::read(&result).unwrap().updates, 60);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A worker that joined the run by itself and hangs cannot be killed by the supervisor; its
/// rollouts go to the others once it is overdue, and the run ends with the same bits.
#[test]
fn a_hung_unsupervised_worker_loses_its_rollouts_to_the_others() {
    let scratch = Scratch::new("foreign-hung");
    let text = config(&[
        ("updates = 40", "updates = 100"),
        DELAYED,
        ("workers = 3", "workers = 1"),
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 100",
        ),
    ]);
    let cfg = write_config(&scratch, "foreign.toml", &text);
    // The joining worker's own config: the run's, and it hangs at its first chunk.
    let hanging = write_config(
        &scratch,
        "hanging.toml",
        &config_edit::edited(
            &text,
            &[(
                "rollout_timeout_ms = 100",
                "rollout_timeout_ms = 100\nfault_hang_at_update = 0",
            )],
        ),
    );
    let result = scratch.path("result.toml");
    let mut run = start_traced(&scratch, 260, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let mut foreign = join_as_worker_5(&run, &hanging);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(out.contains("-> w5:"), "w5 never got work:\n{out}");
    assert!(
        out.contains(
            "worker-5 (incarnation 0, not started by this supervisor) hung: no rollout done for"
        ),
        "{out}"
    );
    assert!(
        foreign.try_wait().unwrap().is_none(),
        "the hung worker is not the supervisor's to kill"
    );
    foreign.kill().unwrap();
    foreign.wait().unwrap();
    // Once w5 is overdue, w0 is the only worker that takes work: it gets each update's 15
    // rollouts in one chunk, not a share that counts w5.
    let last = out.lines().rfind(|l| l.contains("-> w0: [")).unwrap();
    assert_eq!(last.matches(',').count() + 1, 15, "{last}");
    assert_eq!(RunResult::read(&result).unwrap().updates, 100);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

#[test]
fn scaling_1_to_4_to_2_workers_mid_run_keeps_the_result_bit_identical() {
    let scratch = Scratch::new("scale");
    let text = config(&[
        ("updates = 40", "updates = 120"),
        DELAYED,
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "scale.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 200, &cfg, &result);
    let s = run.wait_status("5 updates", |s| updates_in(s) >= 5);
    assert!(s.contains("workers: 1 running"), "{s}");
    run.ctl_ok(&["scale", "--workers", "4"]);
    let s = run.wait_status("4 workers", |s| {
        s.contains("workers: 4 running") && !s.contains("(starting)")
    });
    let at4 = updates_in(&s);
    run.wait_status("progress with 4 workers", |s| updates_in(s) >= at4 + 5);
    run.ctl_ok(&["scale", "--workers", "2"]);
    let s = run.wait_status("2 workers", |s| pids_in(s).len() == 5);
    assert!(s.contains("workers: 2 running"), "{s}");
    // Above the limit: refused, run unaffected.
    let (ok, reply) = run.ctl(&["scale", "--workers", "17"]);
    assert!(!ok && reply.contains("max_workers = 16"), "{reply}");
    // To 0: refused, saying how to pause a run instead.
    let (ok, reply) = run.ctl(&["scale", "--workers", "0"]);
    assert!(
        !ok && reply.contains("`supervisor stop --after-update`"),
        "{reply}"
    );
    run.wait_exit(Duration::from_secs(60), 0);
    assert_eq!(RunResult::read(&result).unwrap().updates, 120);
    assert_bit_identical(&text, &result);
    // The recording's health log has the workers that joined the running run.
    let rec = record::read_recording(&scratch.recording("A1", 200)).unwrap();
    for w in ["worker-1", "worker-2", "worker-3"] {
        assert!(logged(&rec, "scale", w), "{w}: {:#?}", rec.logs);
    }
    // The scale-down stopped the two highest slots: logged as such, not as crashes.
    for w in ["worker-2", "worker-3"] {
        let stopped = rec.logs.iter().any(|l| {
            l.event == "scale" && l.name == w && l.message.contains("stopped by a scale-down")
        });
        assert!(stopped, "{w}: {:#?}", rec.logs);
    }
    assert!(
        !rec.logs.iter().any(|l| l.event == "crash"),
        "{:#?}",
        rec.logs
    );
    assert_recorded(&rec, 120);
    assert_nothing_left(&run);
}

/// Workers that join and are scaled away while the recorder is stopped (SIGSTOP): the
/// recorder connects to a new publisher only when it next looks, and iceoryx2 keeps what a
/// departed publisher sent only for subscribers that had connected to it. Before the
/// supervisor asked the recorder to connect (RECORDER_SYNC) before stopping a worker, such a
/// run lost whole updates ("update N not recorded: the costs of rollouts […] never reached the
/// recorder") and every join of the scaled-up workers from the recording.
#[test]
fn workers_scaled_up_and_down_while_the_recorder_is_stopped_are_all_recorded() {
    let scratch = Scratch::new("scale-stopped-recorder");
    let text = config(&[
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
        ),
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "scale.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1910, &cfg, &result);
    let s = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let recorder = pid_of(&s, "recorder");
    signal(recorder, "-STOP");
    run.ctl_ok(&["scale", "--workers", "8"]);
    let s = run.wait_status("8 workers", |s| {
        s.contains("workers: 8 running") && !s.contains("(starting)")
    });
    // Rollouts for the joined workers: the updater runs on until the lag bound holds it.
    let at8 = updates_in(&s);
    run.wait_status("progress with 8 workers", |s| updates_in(s) >= at8 + 2);
    run.ctl_ok(&["scale", "--workers", "1"]);
    std::thread::sleep(Duration::from_millis(800));
    signal(recorder, "-CONT");
    run.wait_exit(Duration::from_secs(120), 0);
    assert_eq!(RunResult::read(&result).unwrap().updates, 40);
    let rec = record::read_recording(&scratch.recording("A1", 1910)).unwrap();
    let errors: Vec<_> = rec.logs.iter().filter(|l| l.event == "error").collect();
    assert!(errors.is_empty(), "{errors:#?}");
    assert_recorded(&rec, 40);
    for w in 1..8 {
        let w = format!("worker-{w}");
        let joined = rec.logs.iter().any(|l| {
            l.event == "scale" && l.name == w && l.message.contains("joined the running run")
        });
        assert!(joined, "{w}: {:#?}", rec.logs);
    }
    assert_nothing_left(&run);
}

/// Issue #4: iceoryx2 keeps what a departed publisher sent only for subscribers that had
/// connected to it, and a subscriber connects when it next looks. A worker that joined while
/// the recorder was stopped, sent costs and was killed took them with it: "update N not
/// recorded: the costs of rollouts […] never reached the recorder". RECORDER_SYNC covers
/// workers the supervisor stops, not crashes. The sampler now hands a worker incarnation no
/// work until the recorder says it has connected to it (`joined`).
#[test]
fn workers_that_crash_while_the_recorder_is_stopped_lose_no_update() {
    let scratch = Scratch::new("crash-stopped-recorder");
    let text = config(&[
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 7.0",
        ),
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "crash.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 27900, &cfg, &result);
    let s = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let recorder = pid_of(&s, "recorder");
    signal(recorder, "-STOP");
    // The first incarnation was connected to before the stop; the second joins during it.
    let mut victim = pid_of(&s, "worker-0");
    for _ in 0..2 {
        // About three updates' rollouts, if it is given work.
        std::thread::sleep(Duration::from_millis(300));
        signal(victim, "-9");
        let s = run.wait_status("worker-0 restarted", |s| {
            s.contains("worker-0 pid") && !s.contains(&format!("pid {victim} "))
        });
        victim = pid_of(&s, "worker-0");
    }
    std::thread::sleep(Duration::from_millis(300));
    signal(recorder, "-CONT");
    run.wait_exit(Duration::from_secs(120), 0);
    assert_eq!(RunResult::read(&result).unwrap().updates, 40);
    let rec = record::read_recording(&scratch.recording("A1", 27900)).unwrap();
    assert_recorded(&rec, 40);
    assert_nothing_left(&run);
}

/// N = 20 001 steps (K = 15): the 16 MiB budget of the cost buffers holds less than three
/// updates' costs, and the recorder's lag bound came out as 1 update. But the recorder writes
/// update u only once it has the distribution of u + 1, which a bound of 1 held back: the run
/// stopped after its first update for good ("no update for 10 s since update 1"). The bound is
/// at least 2 now, the buffers sized for it.
#[test]
fn a_recorded_run_with_very_long_rollouts_goes_on() {
    let scratch = Scratch::new("long-rollouts");
    let text = config(&[
        ("updates = 40", "updates = 10"),
        ("dt = 0.01", "dt = 0.00005"),
    ]);
    let cfg = write_config(&scratch, "long.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1913, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(
        run.text()
            .contains("the updater stays at most 2 updates ahead of it"),
        "{}",
        run.text()
    );
    let rec = record::read_recording(&scratch.recording("A1", 1913)).unwrap();
    assert_recorded(&rec, 10);
    assert_nothing_left(&run);
}

/// The supervisor's `control` messages beyond the recorder's buffer (2 · max_workers + 16 =
/// 48) are dropped while the recorder is stopped: the recording says how many were lost
/// (they are numbered, `Control::sent`), instead of silently missing their events.
#[test]
fn control_messages_a_stopped_recorder_missed_are_counted_in_the_recording() {
    let scratch = Scratch::new("control-overflow");
    let text = config(&[DELAYED]);
    let cfg = write_config(&scratch, "sets.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1911, &cfg, &result);
    let s = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let recorder = pid_of(&s, "recorder");
    signal(recorder, "-STOP");
    for i in 0..60 {
        let value = if i % 2 == 0 { "0.2" } else { "0.25" };
        run.ctl_ok(&["set", "viapoint", value]);
    }
    // `status` shows that the recorder is what holds the run.
    let s = run.wait_status("the recorder behind", |s| {
        s.lines()
            .find(|l| l.starts_with("recording: "))
            .and_then(|l| l.split(", ").last()?.strip_suffix(" behind the updater"))
            .and_then(|n| n.parse::<u64>().ok())
            .is_some_and(|n| n >= 10)
    });
    assert!(s.contains("; written through update "), "{s}");
    signal(recorder, "-CONT");
    run.wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(&scratch.recording("A1", 1911)).unwrap();
    let requested = rec
        .logs
        .iter()
        .filter(|l| l.message.starts_with("task change requested"))
        .count();
    let lost: Vec<u64> = rec
        .logs
        .iter()
        .filter(|l| l.event == "error")
        .filter_map(|l| {
            let (n, rest) = l.message.split_once(' ')?;
            rest.contains("of the supervisor on `control` never reached the recorder")
                .then(|| n.parse().ok())?
        })
        .collect();
    assert!(requested < 60, "none lost: {requested} requests logged");
    assert_eq!(
        lost.iter().sum::<u64>() as usize,
        60 - requested,
        "{:#?}",
        rec.logs
    );
    assert_nothing_left(&run);
}

/// With slow rollouts (60 ms), a worker that joins mid-update takes rollouts of that update:
/// the sampler keeps work queued (chunks of at most 50 ms of rollouts) instead of handing out
/// the whole update at its start, which left a scaled-up worker idle until the next update.
/// Judged for each joiner whose update still had a rollout started 100 ms or more after the
/// join (by its log time, which is later than the join, never earlier). The first joins in
/// update 0, before any rollout was timed.
#[test]
fn a_worker_scaled_up_mid_update_takes_rollouts_of_that_update() {
    let scratch = Scratch::new("join-mid-update");
    let text = config(&[
        ("updates = 40", "updates = 10"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 60.0",
        ),
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "join.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1841, &cfg, &result);
    // The first scale-up lands in update 0 (0.9 s with one worker), before the sampler has
    // timed any rollout: 0.3 s after the worker is up.
    run.wait_status("1 worker", |s| s.contains("workers: 1 running"));
    std::thread::sleep(Duration::from_millis(300));
    for (after, workers) in [(0, "2"), (3, "3"), (6, "4")] {
        run.wait_status("updates", |s| updates_in(s) >= after);
        run.ctl_ok(&["scale", "--workers", workers]);
    }
    run.wait_exit(Duration::from_secs(60), 0);
    assert_bit_identical(&text, &result);
    let rec = record::read_recording(&scratch.recording("A1", 1841)).unwrap();
    let mut judged = 0;
    for w in ["worker-1", "worker-2", "worker-3"] {
        let joined = rec
            .logs
            .iter()
            // Before the first update is recorded a joiner is logged as `ready` (a start).
            .find(|l| l.name == w && (l.message.contains("joined") || l.message.ends_with("ready")))
            .unwrap_or_else(|| panic!("{w} did not join: {:#?}", rec.logs));
        let t = joined.timestamp.as_ref().unwrap();
        let t_join = t.seconds as u64 * 1_000_000_000 + t.nanos as u64;
        let u_join = rec
            .rollouts
            .iter()
            .filter(|r| r.start_ns <= t_join)
            .max_by_key(|r| r.start_ns)
            .map(|r| r.update)
            .unwrap();
        let of_update: Vec<_> = rec.rollouts.iter().filter(|r| r.update == u_join).collect();
        let queued_long_after = of_update
            .iter()
            .any(|r| r.worker != w && r.start_ns >= t_join + 100_000_000);
        if !queued_long_after {
            continue;
        }
        judged += 1;
        let ran: Vec<_> = of_update
            .iter()
            .map(|r| (r.worker.as_str(), r.rollout))
            .collect();
        assert!(
            ran.iter().any(|(name, _)| *name == w),
            "{w} joined in update {u_join} and ran none of it: {ran:?}"
        );
    }
    assert!(judged > 0, "every worker joined at the end of an update");
    assert_nothing_left(&run);
}

/// Scaled down and straight back up while the stopped workers are still in a rollout: the new
/// workers in their slots must get work (the sampler took the new one's announcement for its
/// stopping predecessor's, and the predecessor's loss for the new one's, so the run went on with
/// two workers while `status` showed four).
#[test]
fn scaling_down_and_straight_back_up_gives_the_new_workers_work() {
    let scratch = Scratch::new("rescale");
    let text = config(&[
        ("updates = 40", "updates = 30"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
        ),
        ("workers = 3", "workers = 4"),
    ]);
    let cfg = write_config(&scratch, "rescale.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 950, &cfg, &result);
    let s = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let old = [pid_of(&s, "worker-2"), pid_of(&s, "worker-3")];
    run.ctl_ok(&["scale", "--workers", "2"]);
    run.ctl_ok(&["scale", "--workers", "4"]);
    let s = run.wait_status("4 new workers", |s| {
        s.contains("workers: 4 running") && old.iter().all(|p| !s.contains(&format!("pid {p} ")))
    });
    let rescaled = updates_in(&s);
    run.wait_exit(Duration::from_secs(60), 0);
    assert_bit_identical(&text, &result);
    let rec = record::read_recording(&scratch.recording("A1", 950)).unwrap();
    assert_recorded(&rec, 30);
    // From two updates after the scale-up on, every update's rollouts ran on all four workers.
    for u in rescaled + 2..30 {
        let workers: std::collections::BTreeSet<&str> = rec
            .rollouts
            .iter()
            .filter(|r| r.update == u)
            .map(|r| r.worker.as_str())
            .collect();
        assert_eq!(workers.len(), 4, "update {u} ran on {workers:?}");
    }
    for w in ["worker-2", "worker-3"] {
        let stopped = rec.logs.iter().any(|l| {
            l.event == "scale" && l.name == w && l.message.contains("stopped by a scale-down")
        });
        assert!(stopped, "{w}: {:#?}", rec.logs);
        // Their successors came with the scale-up, not in place of a lost worker: the recording
        // said `restart` (a warning) for them, by their incarnation.
        let joined = rec.logs.iter().any(|l| {
            l.event == "scale" && l.name == w && l.message.contains("joined the running run")
        });
        assert!(joined, "{w}: {:#?}", rec.logs);
    }
    let restarts: Vec<_> = rec.logs.iter().filter(|l| l.event == "restart").collect();
    assert!(restarts.is_empty(), "{restarts:#?}");
    assert_nothing_left(&run);
}

#[test]
fn sigint_stops_every_process_within_the_bound_and_leaves_nothing() {
    let scratch = Scratch::new("sigint");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nshutdown_timeout_ms = 2000",
        ),
    ]);
    let cfg = write_config(&scratch, "sigint.toml", &text);
    let mut run = Run::start(&scratch, 300, &[cfg.to_str().unwrap(), "--quiet"]);
    let status = run.wait_status("5 updates", |s| updates_in(s) >= 5);
    let pids = pids_in(&status);
    // Recorder, updater, sampler, 3 workers.
    assert_eq!(pids.len(), 6, "{status}");
    let t0 = Instant::now();
    signal(run.child.id(), "-INT");
    run.wait_exit(Duration::from_secs(10), 130);
    assert!(
        t0.elapsed() < Duration::from_millis(2000 + 1500),
        "{:?}",
        t0.elapsed()
    );
    for (name, pid) in pids {
        assert!(
            !supervisor::process_alive(pid),
            "{name} (pid {pid}) survived"
        );
    }
    assert!(run.text().contains("interrupted"), "{}", run.text());
    assert_nothing_left(&run);
}

/// `nohup supervisor run … &` went on only until the user logged out: the supervisor's SIGINT
/// handler (the `ctrlc` crate's) was installed over the SIGHUP that nohup had ignored, and the
/// terminal's hangup stopped the run. A SIGHUP the supervisor was started with ignored stays
/// ignored; otherwise it stops the run like SIGTERM, and every stop names its signal.
#[test]
fn sighup_stops_a_run_unless_started_ignored_as_nohup_does_and_the_signal_is_named() {
    let scratch = Scratch::new("sighup");
    let cfg = write_config(&scratch, "sighup.toml", &config(&[UNBOUNDED, DELAYED]));
    let args = [cfg.to_str().unwrap(), "--quiet", "--no-record"];
    let mut nohup = Run::start_ignoring_sighup(&scratch, 28200, &args);
    let mut plain = Run::start_with_default_sighup(&scratch, 28201, &args);
    for run in [&nohup, &plain] {
        run.wait_status("3 updates", |s| updates_in(s) >= 3);
        signal(run.child.id(), "-HUP");
    }
    assert_interrupted_by(&mut plain, "SIGHUP");
    // Alive and learning after the hangup, and said why at the start.
    let before = updates_in(&nohup.ctl_ok(&["status"]));
    nohup.wait_status("more updates after SIGHUP", |s| updates_in(s) > before + 3);
    assert!(
        nohup
            .text()
            .contains("SIGHUP is ignored (nohup): closing the terminal does not stop this run"),
        "{}",
        nohup.text()
    );
    signal(nohup.child.id(), "-TERM");
    assert_interrupted_by(&mut nohup, "SIGTERM");
    assert_nothing_left(&plain);
    assert_nothing_left(&nohup);
}

/// `run` ends interrupted (exit 130) and names `signal` as it stops and in its summary.
fn assert_interrupted_by(run: &mut Run, signal: &str) {
    run.wait_exit(Duration::from_secs(10), 130);
    let text = run.text();
    assert!(
        text.contains(&format!("{signal} received: stopping"))
            && text.contains(&format!("interrupted ({signal})")),
        "{text}"
    );
}

/// iceoryx2 catches SIGABRT and SIGQUIT along with SIGINT and SIGTERM, only to note them:
/// `kill -ABRT` of a hung worker, for its core dump, did nothing. The pipeline's processes give
/// both their default action back: the worker dies of it, is said to, and is restarted.
#[test]
fn sigabrt_and_sigquit_end_a_worker_which_is_restarted() {
    let scratch = Scratch::new("abrt");
    let cfg = write_config(&scratch, "abrt.toml", &config(&[UNBOUNDED, DELAYED]));
    let run = Run::start(
        &scratch,
        28202,
        &[cfg.to_str().unwrap(), "--quiet", "--no-record"],
    );
    for (restarts, (sig, name)) in [("-ABRT", "SIGABRT"), ("-QUIT", "SIGQUIT")]
        .into_iter()
        .enumerate()
    {
        let status = run.wait_status("worker-1 learning", |s| {
            updates_in(s) >= 3
                && s.contains(&format!("restarts {restarts}"))
                && s.contains("worker-1 pid")
        });
        let victim = pid_of(&status, "worker-1");
        signal(victim, sig);
        run.wait_output(
            &format!("worker-1 (pid {victim}) died"),
            Instant::now() + Duration::from_secs(10),
        );
        let died = run
            .text()
            .lines()
            .find(|l| l.contains(&format!("worker-1 (pid {victim}) died")))
            .unwrap_or_default()
            .to_owned();
        assert!(died.contains(name), "{died}");
        run.wait_status("worker-1 restarted", |s| {
            s.contains(&format!("restarts {}", restarts + 1))
                && !s.contains(&format!("pid {victim} "))
        });
    }
}

/// SIGKILLs a run's supervisor after its third update (no clean-up of its own) and waits until
/// its four processes have died with it.
fn sigkill_after_3_updates(run: &mut Run) {
    let s = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let pids = pids_in(&s);
    assert_eq!(pids.len(), 5, "{s}");
    sigkill_supervisor(run, &pids);
}

/// SIGKILLs a run's supervisor (no clean-up of its own) and waits until its processes `pids`
/// have died with it.
fn sigkill_supervisor(run: &mut Run, pids: &[(String, u32)]) {
    run.child.kill().unwrap();
    run.wait(Duration::from_secs(10));
    let end = Instant::now() + Duration::from_secs(10);
    while pids.iter().any(|(_, pid)| supervisor::process_alive(*pid)) {
        assert!(
            Instant::now() < end,
            "children outlived their supervisor: {pids:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The run that comes next (a 5-update run), run to its successful end.
fn next_short_run(scratch: &Scratch, id: u64) -> Run {
    let short = write_config(
        scratch,
        "short.toml",
        &config(&[("updates = 40", "updates = 5")]),
    );
    let mut next = Run::start_quiet(scratch, id, &short, &scratch.path("result.toml"));
    next.wait_exit(Duration::from_secs(60), 0);
    next
}

/// The files of a run's iceoryx2 directory and shared memory, made two minutes old.
fn backdate_ipc(run: &Run) {
    let then = std::time::SystemTime::now() - Duration::from_secs(120);
    let prefix = run.shm_prefix();
    let shm = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.path());
    let root = run.ipc_root();
    for p in shm
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with(&prefix)
        })
        .chain([root])
    {
        std::fs::File::open(&p).unwrap().set_modified(then).unwrap();
    }
}

/// A killed run whose run directory was removed (by hand, or it was under another
/// PI2CMA_RUN_DIR) leaves shared memory nobody's sweep finds by run directory; the next run
/// finds it by iceoryx2's registry of dead processes and removes it, and leaves a live run's,
/// however old, alone.
#[test]
fn shared_memory_of_a_dead_run_without_its_directory_is_removed_and_a_live_runs_kept() {
    let scratch = Scratch::new("orphans");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "unbounded.toml", &text);
    let args = [cfg.to_str().unwrap(), "--quiet", "--no-record"];
    let mut killed = Run::start(&scratch, 720, &args);
    sigkill_after_3_updates(&mut killed);
    std::fs::remove_dir_all(killed.runs.join(&killed.run_id)).unwrap();
    let mut live = Run::start(&scratch, 721, &args);
    live.wait_status("3 updates", |s| updates_in(s) >= 3);
    backdate_ipc(&killed);
    backdate_ipc(&live);

    let next = next_short_run(&scratch, 722);
    let said = |run: &Run| {
        format!(
            "removed the shared memory and iceoryx2 files run {} left behind",
            run.run_id
        )
    };
    assert!(next.text().contains(&said(&killed)), "{}", next.text());
    assert!(!next.text().contains(&said(&live)), "{}", next.text());
    assert_nothing_left(&killed);

    // The live run goes on: its status still grows, and it stops cleanly.
    let before = updates_in(&live.ctl(&["status"]).1);
    live.wait_status("more updates", |s| updates_in(s) > before + 2);
    live.ctl_ok(&["stop"]);
    live.wait_exit(Duration::from_secs(30), 0);
    assert_nothing_left(&live);
    assert_nothing_left(&next);
}

/// ... and the recording its recorder, killed with it, left unfinished is named with what to
/// do with it, by `status` and by the next run (they named no file).
#[test]
fn what_a_killed_supervisor_left_behind_is_removed_by_the_next_run() {
    let scratch = Scratch::new("sweep");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "unbounded.toml", &text);
    let recording = scratch.path("killed.mcap");
    let mut killed = Run::start(
        &scratch,
        700,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--record",
            recording.to_str().unwrap(),
        ],
    );
    let s = killed.wait_status("3 updates", |s| updates_in(s) >= 3);
    let pids = pids_in(&s);
    assert_eq!(pids.len(), 6, "{s}");
    sigkill_supervisor(&mut killed, &pids);
    let unfinished = format!("its recording {} is unfinished: `", recording.display());
    let what_to_do = format!("recover {}`", recording.display());
    let prefix = killed.shm_prefix();
    let shm = || {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .count()
    };
    assert!(shm() > 0, "a SIGKILLed run leaves its shared memory");
    assert!(killed.runs.join(&killed.run_id).exists());
    let (ok, reply) = killed.ctl(&["status"]);
    assert!(!ok && reply.contains("supervisor was killed"), "{reply}");
    assert!(
        reply.contains(&unfinished) && reply.contains(&what_to_do),
        "{reply}"
    );

    let next = next_short_run(&scratch, 701);
    let said = format!("removed what run {} left behind", killed.run_id);
    assert!(next.text().contains(&said), "{}", next.text());
    assert!(
        next.text().contains(&unfinished) && next.text().contains(&what_to_do),
        "{}",
        next.text()
    );
    assert_nothing_left(&killed);
    assert_nothing_left(&next);
}

/// The update a `supervisor set` reply says its change takes effect from.
fn takes_effect_from(reply: &str) -> u64 {
    reply
        .split("takes effect from update ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no update index in the reply: {reply}"))
}

#[test]
fn continual_run_takes_runtime_task_changes_and_stops_on_request() {
    let scratch = Scratch::new("continual");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        (
            "[[schedule]]\nfrom_update = 20\nset = \"viapoint\"\nvalue = 0.1\n",
            "",
        ),
    ]);
    let cfg = write_config(&scratch, "continual.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 400, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let (ok, reply) = run.ctl(&["set", "goal", "2.0"]);
    assert!(!ok && reply.contains("no setting `goal`"), "{reply}");
    // Finite, but every rollout's cost would overflow: it ended the run at the update it took
    // effect from.
    let (ok, reply) = run.ctl(&["set", "viapoint", "1e308"]);
    assert!(
        !ok && reply.contains("gives the cost of step 50 = inf"),
        "{reply}"
    );
    // Two changes in a row: each reply names the update its own change takes effect from, as
    // the updater decided it (the updater echoes each change's number).
    let mut said = Vec::new();
    let mut replies = Vec::new();
    for value in ["0.2", "0.25"] {
        let reply = run.ctl_ok(&["set", "viapoint", value]);
        replies.push(reply.clone());
        said.push(takes_effect_from(&reply));
    }
    // The second replaces the first for that update if both are due from it, and says so.
    let replacing = "replacing viapoint = 0.2, which was due from the same update";
    assert_eq!(
        replies[1].contains(replacing),
        said[0] == said[1],
        "{replies:?}"
    );
    assert!(!replies[0].contains("replacing"), "{replies:?}");
    run.wait_status("task change applied", |s| s.contains("viapoint = 0.25"));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let r = RunResult::read(&result).unwrap();
    assert!(!r.complete);
    let runtime: Vec<_> = r
        .task_changes
        .iter()
        .filter(|c| c.source == "runtime")
        .collect();
    // A change replaced at its update is no change the run made: the result lists the other.
    let mut expected = vec![(0.2, said[0]), (0.25, said[1])];
    if said[0] == said[1] {
        expected.remove(0);
    }
    assert_eq!(runtime.len(), expected.len(), "{:?}", r.task_changes);
    let mut replay = text.clone();
    for (change, (value, from)) in runtime.iter().zip(expected) {
        assert_eq!((change.name.as_str(), change.value), ("viapoint", value));
        assert!(change.from_update >= 3 && change.from_update <= r.updates);
        assert_eq!(change.from_update, from, "{said:?}");
        // The same changes scheduled in the config reproduce the run in-process, bit for bit.
        replay.push_str(&format!(
            "\n[[schedule]]\nfrom_update = {}\nset = \"viapoint\"\nvalue = {value}\n",
            change.from_update
        ));
    }
    assert_bit_identical(&replay, &result);
    assert_nothing_left(&run);
}

#[test]
fn a_runtime_change_is_judged_with_the_settings_earlier_changes_left() {
    let scratch = Scratch::new("in-force");
    let tball = include_str!("../../../config/tball.toml");
    // Without the scheduled lower ball, so that the settings in force differ from the
    // config's only by the changes made here, however far the run has got.
    let schedule = "[[schedule]]\nfrom_update = 20\nset = \"ball_height\"\nvalue = 0.47\n";
    assert!(tball.contains("updates = 40\n") && tball.contains(schedule));
    let text = tball
        .replacen("updates = 40\n", "", 1)
        .replacen(schedule, "", 1)
        .replacen(
            "[task.tball]\n",
            "[task.tball]\nrollout_delay_ms = 2.0\n",
            1,
        );
    let cfg = write_config(&scratch, "tball.toml", &text);
    let mut run = Run::start(
        &scratch,
        420,
        &[cfg.to_str().unwrap(), "--quiet", "--no-record"],
    );
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    // The tee moved to y = 0.6, then to x = 1: each alone is within the bat's reach (1.103 m,
    // 1.053 m from the shoulder; at most 1.185 m), both together are not (1.281 m). The second
    // is judged with the first in force: with the config's tee_y = -0.53 it would pass.
    run.ctl_ok(&["set", "tee_y", "0.6"]);
    let (ok, reply) = run.ctl(&["set", "tee_x", "1"]);
    assert!(
        !ok && reply.contains("out of the bat's reach")
            && reply.contains("settings in force that differ from the config: tee_y = 0.6"),
        "{reply}"
    );
    // Once the updater reports the first change, it is still the one in force.
    run.wait_status("tee_y in force", |s| s.contains("tee_y = 0.6"));
    let (ok, reply) = run.ctl(&["set", "tee_x", "1"]);
    assert!(!ok && reply.contains("tee_y = 0.6"), "{reply}");
    // A negative value (config/tball.toml has tee_y = -0.53) is a value, not an option: clap
    // answered "unexpected argument '-0' found".
    run.ctl_ok(&["set", "tee_y", "-0.5"]);
    run.wait_status("tee_y = -0.5 in force", |s| s.contains("tee_y = -0.5"));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_nothing_left(&run);
}

#[test]
fn bad_input_is_reported_with_its_cause_and_leaves_nothing_running() {
    let scratch = Scratch::new("bad");
    // Malformed config.
    let bad = write_config(&scratch, "bad.toml", "[run\nname=");
    let mut run = Run::start(&scratch, 500, &[bad.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(run.text().contains("bad.toml"), "{}", run.text());
    assert_nothing_left(&run);

    // A run refused at start (here: its run directory is in use) creates no directory for its
    // recording.
    let busy = scratch.runs().join(run_id(508));
    std::fs::create_dir_all(&busy).unwrap();
    std::fs::write(busy.join("supervisor.pid"), std::process::id().to_string()).unwrap();
    let nested = scratch.path("not-yet/run.mcap");
    let mut run = Run::start(&scratch, 508, &["--record", nested.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(
        run.text()
            .contains("exists, but no supervisor answers on it"),
        "{}",
        run.text()
    );
    assert!(!scratch.path("not-yet").exists(), "{}", run.text());
    std::fs::remove_dir_all(&busy).unwrap();

    // A recording in the way: not overwritten (a run that then failed would leave an empty
    // one in its place).
    let keep = scratch.path("keep.mcap");
    std::fs::write(&keep, b"a recording").unwrap();
    let mut run = Run::start(&scratch, 509, &["--record", keep.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(run.text().contains("is there already"), "{}", run.text());
    assert_eq!(std::fs::read(&keep).unwrap(), b"a recording");
    assert_nothing_left(&run);
    // Nor the parts of an earlier split recording whose first file was moved away: the new
    // recording would have removed them.
    let part = scratch.path("moved.part-2.mcap");
    std::fs::write(&part, b"a part").unwrap();
    let moved = scratch.path("moved.mcap");
    let mut run = Run::start(&scratch, 510, &["--record", moved.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(
        run.text()
            .contains("moved.part-2.mcap of an earlier recording"),
        "{}",
        run.text()
    );
    assert_eq!(std::fs::read(&part).unwrap(), b"a part");
    assert!(!moved.exists());
    assert_nothing_left(&run);

    // Worker count above the limit.
    let mut run = Run::start(&scratch, 501, &["--workers", "17"]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(
        run.text().contains("--workers 17") && run.text().contains("max_workers = 16"),
        "{}",
        run.text()
    );
    assert_nothing_left(&run);
    let over = write_config(
        &scratch,
        "over.toml",
        &config(&[("workers = 3", "workers = 300")]),
    );
    let mut run = Run::start(&scratch, 502, &[over.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(
        run.text().contains("pipeline.workers = 300"),
        "{}",
        run.text()
    );

    // A missing binary.
    let bins = scratch.path("bins");
    std::fs::create_dir_all(&bins).unwrap();
    let here = Path::new(SUPERVISOR).parent().unwrap();
    for b in ["updater", "sampler"] {
        std::os::unix::fs::symlink(here.join(b), bins.join(b)).unwrap();
    }
    let mut run = Run::start(&scratch, 503, &["--bin-dir", bins.to_str().unwrap()]);
    assert!(!run.wait(Duration::from_secs(10)).success());
    assert!(
        run.text().contains(&format!(
            "missing binary `rollout-worker`: {} does not exist (--bin-dir {} must hold \
             updater, sampler, rollout-worker;",
            bins.join("rollout-worker").display(),
            bins.display()
        )),
        "{}",
        run.text()
    );
    assert_nothing_left(&run);
    // One that is there but cannot run: refused before the updater and sampler start, not
    // when its turn to start comes.
    for (id, make) in [(511, "file"), (512, "dir")] {
        let worker = bins.join("rollout-worker");
        let _ = std::fs::remove_file(&worker);
        let _ = std::fs::remove_dir(&worker);
        match make {
            "file" => std::fs::write(&worker, "#!/bin/sh\n").unwrap(),
            _ => std::fs::create_dir(&worker).unwrap(),
        }
        let mut run = Run::start(&scratch, id, &["--bin-dir", bins.to_str().unwrap()]);
        run.wait_exit(Duration::from_secs(10), 1);
        let out = run.text();
        assert!(
            out.contains(&format!(
                "binary `rollout-worker`: {} is not an executable file",
                worker.display()
            )) && !out.contains("starting"),
            "{out}"
        );
        assert_nothing_left(&run);
    }
    // A recorder there that cannot run (it is optional, but the one there is used), and a
    // --bin-dir that is no directory: both refused before anything starts.
    std::fs::remove_dir_all(&bins).unwrap();
    std::fs::create_dir(&bins).unwrap();
    for b in ["updater", "sampler", "rollout-worker"] {
        std::os::unix::fs::symlink(here.join(b), bins.join(b)).unwrap();
    }
    std::fs::write(bins.join("recorder"), "#!/bin/sh\n").unwrap();
    let not_a_dir = scratch.path("bins.toml");
    std::fs::write(&not_a_dir, "").unwrap();
    for (id, dir, expected) in [
        (
            27602,
            &bins,
            format!(
                "binary `recorder`: {} is not an executable file (remove it",
                bins.join("recorder").display()
            ),
        ),
        (
            27603,
            &not_a_dir,
            format!(
                "--bin-dir {}: is not a directory; give the directory that holds updater, \
                 sampler, rollout-worker",
                not_a_dir.display()
            ),
        ),
    ] {
        let mut run = Run::start(&scratch, id, &["--bin-dir", dir.to_str().unwrap()]);
        run.wait_exit(Duration::from_secs(10), 1);
        let out = run.text();
        assert!(
            out.contains(&expected) && !out.contains("starting"),
            "{out}"
        );
        assert_nothing_left(&run);
    }

    // A task that returns NaN (fault injection).
    let nan = write_config(
        &scratch,
        "nan.toml",
        &config(&[(
            "max_workers = 16",
            "max_workers = 16\nfault_nan_from_update = 3",
        )]),
    );
    let mut run = Run::start(&scratch, 504, &[nan.to_str().unwrap()]);
    let exit = run.wait(Duration::from_secs(20));
    assert!(!exit.success(), "{}", run.text());
    let out = run.text();
    assert!(out.contains("update 3") && out.contains("NaN"), "{out}");
    // The run had no reruns: the error names the setting that would have rerun the rollout.
    assert!(
        out.contains("(if the task gives such costs now and then, `run.nonfinite_reruns = N`"),
        "{out}"
    );
    assert!(out.contains("updater exited"), "{out}");
    assert_nothing_left(&run);
}

/// A bad value typed as an option is reported as that option: `--updates 0` was reported as
/// `<built-in default>: run.updates = 0`, a field of no file the user had; the same value in a
/// config file still names the file and field.
#[test]
fn a_bad_option_value_is_reported_as_the_option_and_a_bad_field_as_the_field() {
    let scratch = Scratch::new("h2-options");
    let mut run = Run::start(&scratch, 1600, &["--updates", "0"]);
    run.wait_exit(Duration::from_secs(10), 1);
    assert!(
        run.text().contains("--updates 0: must be at least 1")
            && !run.text().contains("built-in default"),
        "{}",
        run.text()
    );
    assert_nothing_left(&run);
    let zero = write_config(
        &scratch,
        "zero.toml",
        &config(&[("updates = 40", "updates = 0")]),
    );
    let mut run = Run::start(&scratch, 1601, &[zero.to_str().unwrap()]);
    run.wait_exit(Duration::from_secs(10), 1);
    assert!(
        run.text()
            .contains("zero.toml: run.updates = 0: must be at least 1"),
        "{}",
        run.text()
    );
    assert_nothing_left(&run);
}

/// `status` shows cost and λ as the progress lines and the summary do (4 decimals), not as raw
/// floats (`lambda: 1.9999999999999998`).
#[test]
fn status_shows_cost_and_lambda_as_the_progress_lines_do() {
    let scratch = Scratch::new("h2-status");
    let cfg = write_config(&scratch, "status.toml", &config(&[UNBOUNDED, DELAYED]));
    let mut run = Run::start_quiet(&scratch, 1602, &cfg, &scratch.path("result.toml"));
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    for field in ["current cost: ", "lambda: "] {
        let value = status
            .lines()
            .find_map(|l| l.strip_prefix(field))
            .unwrap_or_else(|| panic!("no `{field}` line:\n{status}"));
        let decimals = value.split_once('.').map_or(0, |(_, d)| d.len());
        assert!(
            decimals == 4 && value.parse::<f64>().is_ok(),
            "{field}{value}:\n{status}"
        );
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
}

/// The progress lines' update rate is updates over the time they took, so no line shows more
/// than the run's fastest update allows. It was taken between the updater's last two reports,
/// each stamped with when it was sent: a report at a tenth of the run, sent when its update
/// ended, came 70–100 ms after the periodic one sent within the update before, and a run of
/// 150 ms updates printed 10 to 14 updates/s (with 40 ms rollouts, 1574 to 10090).
#[test]
fn the_progress_lines_show_no_faster_rate_than_the_updates_had() {
    let scratch = Scratch::new("progress-rate");
    let slow = (
        "viapoint_weight = 1000.0",
        "viapoint_weight = 1000.0\nrollout_delay_ms = 30.0",
    );
    let cfg = write_config(
        &scratch,
        "rate.toml",
        &config(&[("updates = 40", "updates = 24"), slow]),
    );
    let mcap = scratch.path("rate.mcap");
    let args = [
        cfg.to_str().unwrap(),
        "--workers",
        "3",
        "--record",
        mcap.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 5105, &args);
    run.wait_exit(Duration::from_secs(60), 0);
    // The shortest time from one update to the next: between their first rollouts' starts, as
    // the workers stamped them.
    let rec = record::read_recording(&mcap).unwrap();
    let mut first_start = std::collections::BTreeMap::<u64, u64>::new();
    for r in &rec.rollouts {
        let s = first_start.entry(r.update).or_insert(r.start_ns);
        *s = (*s).min(r.start_ns);
    }
    let starts: Vec<u64> = first_start.into_values().collect();
    let fastest = starts.windows(2).map(|w| w[1] - w[0]).min().unwrap();
    // A margin for the updater's and the workers' clocks reading the same updates a few ms
    // apart.
    let bound = 1.25 / (fastest as f64 * 1e-9);
    let out = run.text();
    let rates: Vec<f64> = out
        .lines()
        .filter_map(|l| l.split("  ").find_map(|f| f.strip_suffix(" updates/s")))
        .map(|r| r.parse().unwrap())
        .collect();
    assert!(rates.len() >= 10, "{out}");
    assert!(
        rates.iter().all(|&r| r <= bound),
        "rates {rates:?}, but the fastest update took {} ms:\n{out}",
        fastest as f64 * 1e-6
    );
}

/// A supervisor stopped by a signal (here SIGSTOP, which leaves its children running) takes a
/// command's connection but cannot answer: the command said so,
/// naming what to do, instead of `Resource temporarily unavailable (os error 11)` after 10 s.
#[test]
fn a_command_to_a_stopped_supervisor_says_it_is_stopped() {
    let scratch = Scratch::new("ctl-stopped");
    let cfg = write_config(&scratch, "ctl.toml", &config(&[UNBOUNDED, DELAYED]));
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 27802, &cfg, &result);
    run.wait_status("an update", |s| updates_in(s) >= 1);
    let pid = run.child.id();
    signal(pid, "-STOP");
    let (ok, reply) = run.ctl(&["status"]);
    signal(pid, "-CONT");
    assert!(
        !ok && reply.contains(&format!(
            "the run's supervisor (pid {pid}) is stopped by a signal (Ctrl-Z in its terminal, \
             which suspends the run's processes with it; SIGSTOP, which leaves them running \
             unsupervised) and answers no command until it is continued (`fg` in its terminal, \
             or `kill -CONT {pid}`)"
        )),
        "{reply}"
    );
    // Continued, it hears its doorbell again: the SIGSTOP/SIGCONT interrupted the doorbell
    // thread's wait, which ended the thread, and the stop then waited for the recorder's
    // acknowledgement until a deadline (`still waiting for worker-0 … to stop`).
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert!(!run.text().contains("still waiting"), "{}", run.text());
    assert_nothing_left(&run);
}

/// The state of process `pid` (field 3 of its stat: `T` when stopped by a signal).
fn process_state(pid: u32) -> String {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| Some(s.rsplit_once(')')?.1.split_whitespace().next()?.to_string()))
        .unwrap_or_default()
}

/// Ctrl-Z in the terminal of `supervisor run` (SIGTSTP) suspends the whole run: the children
/// lead process groups of their own, which the terminal's Ctrl-Z does not reach, so it stopped
/// the supervisor alone and the run went on unsupervised. Continued (`fg`), the run goes on
/// with no worker taken for hung (the sampler's clock ran on while it was stopped, and every
/// worker in a rollout was past `rollout_timeout_ms`) and ends with the same bits.
#[test]
fn ctrl_z_suspends_the_whole_run_and_fg_continues_it_without_restarts() {
    let scratch = Scratch::new("ctrl-z");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 400",
        ),
    ]);
    let cfg = write_config(&scratch, "ctrl-z.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 27803, &cfg, &result);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let supervisor = run.child.id();
    let mut pids: Vec<u32> = pids_in(&status).into_iter().map(|(_, pid)| pid).collect();
    pids.push(supervisor);
    signal(supervisor, "-TSTP");
    let end = Instant::now() + Duration::from_secs(10);
    while pids.iter().any(|&pid| process_state(pid) != "T") {
        assert!(
            Instant::now() < end,
            "not all stopped: {:?}\n{}",
            pids.iter()
                .map(|&p| (p, process_state(p)))
                .collect::<Vec<_>>(),
            run.text()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // Longer than the rollout timeout, and than the gap the sampler takes for its own stop.
    std::thread::sleep(Duration::from_millis(1500));
    signal(supervisor, "-CONT");
    run.wait_output("continued after ", end + Duration::from_secs(2));
    let before = updates_in(&run.ctl_ok(&["status"]));
    let status = run.wait_status("updates going on", |s| updates_in(s) >= before + 3);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let out = run.text();
    assert!(
        status.contains(", restarts 0\n")
            && !out.contains(" hung")
            && !out.contains("still waiting"),
        "{status}\n{out}"
    );
    assert!(
        out.contains(&format!(
            "Ctrl-Z: the run is suspended, its 6 processes with the supervisor; `fg` (or `kill \
             -CONT {supervisor}`) continues them"
        )),
        "{out}"
    );
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A run stopped between slow updates (a robot's) shows each update's progress line once: the
/// stopping updater's last report, of no new update, printed the line before it again (`update
/// 4/12 … 2 workers` then `update 4/12 …`), as if update 4 had been made twice. A run of one
/// worker says `1 worker`, not `1 workers`.
#[test]
fn a_stopped_run_shows_each_updates_progress_line_once() {
    let scratch = Scratch::new("progress-once");
    let slow = (
        "viapoint_weight = 1000.0",
        "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
    );
    let cfg = write_config(&scratch, "once.toml", &config(&[UNBOUNDED, slow]));
    let args = [cfg.to_str().unwrap(), "--workers", "1", "--no-record"];
    let mut run = Run::start(&scratch, 27801, &args);
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("update 2/∞", end);
    // Updates of 1.5 s: the stop's report comes after the second a line waits for, before
    // update 3.
    std::thread::sleep(Duration::from_millis(1100));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let out = run.text();
    let shown: Vec<&str> = out
        .lines()
        .filter_map(|l| l.strip_prefix("[supervisor] update ")?.split('/').next())
        .collect();
    let mut once = shown.clone();
    once.dedup();
    assert_eq!(shown, once, "{out}");
    assert!(
        out.lines()
            .any(|l| l.ends_with("updater, sampler and 1 worker"))
            && out.contains("  1 worker")
            && !out.contains("1 workers"),
        "{out}"
    );
}

/// The recording's /log has the run's start after every process's announcement, as they
/// happened: the supervisor sends START once all have announced themselves. The recorder took
/// in the supervisor's messages before the announcements of the same round, and logged the
/// last worker's `start` after the run's.
#[test]
fn the_runs_start_is_logged_after_every_process_announced_itself() {
    let scratch = Scratch::new("start-order");
    let cfg = write_config(&scratch, "order.toml", &config(&[DELAYED]));
    let mcap = scratch.path("order.mcap");
    let args = [cfg.to_str().unwrap(), "--quiet", "--updates", "4"];
    Run::start(
        &scratch,
        5107,
        &[&args[..], &["--record", mcap.to_str().unwrap()]].concat(),
    )
    .wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(&mcap).unwrap();
    let order: Vec<String> = rec
        .logs
        .iter()
        .filter(|l| l.event == "start" || l.message == "start")
        .map(|l| format!("{} {}", l.event, l.name))
        .collect();
    let start = order.iter().position(|e| e == "info supervisor");
    for name in ["updater", "sampler", "worker-0", "worker-1", "worker-2"] {
        let announced = order.iter().position(|e| *e == format!("start {name}"));
        assert!(
            announced.is_some() && announced < start,
            "{name}: {order:?}"
        );
    }
}

/// The summary abbreviates a long final mean (it printed all 400 values for P = 400); a short
/// one it prints whole, as it was.
#[test]
fn the_summary_abbreviates_a_long_final_mean() {
    let scratch = Scratch::new("h2-long-mean");
    let cfg = write_config(
        &scratch,
        "long.toml",
        &config(&[
            ("updates = 40", "updates = 2"),
            ("basis_functions = 2", "basis_functions = 400"),
        ]),
    );
    let mut run = Run::start_quiet(&scratch, 1603, &cfg, &scratch.path("result.toml"));
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    let line = out
        .lines()
        .find(|l| l.contains("final mean θ = "))
        .unwrap_or_else(|| panic!("no final mean:\n{out}"));
    assert!(
        line.matches(", ").count() < 8 && line.contains("…") && line.contains("(400 values)"),
        "{}",
        &line[..line.len().min(300)]
    );
}

/// Config edit: `run.nonfinite_reruns = 2`, and the lines `more` in `[run]` too.
fn reruns(more: &str) -> (&'static str, String) {
    (
        "seed = 1\n",
        format!("seed = 1\nnonfinite_reruns = 2\n{more}"),
    )
}

/// The warnings a recording logged.
fn warnings(rec: &record::Recording) -> Vec<(u64, String, String)> {
    rec.logs
        .iter()
        .filter(|l| l.event == "warning")
        .map(|l| (l.update, l.name.clone(), l.message.clone()))
        .collect()
}

/// A rollout whose first execution reports NaN (a sensor dropout) is run again, by whichever
/// worker, with the same parameters: the run goes on, ends bit for bit where the in-process
/// run with the same fault does (and the run without it), logs the rejected execution as a
/// warning, and records the accepted costs, from which every update recomputes.
#[test]
fn a_transient_non_finite_cost_is_rerun_and_the_run_stays_bit_identical() {
    let scratch = Scratch::new("rerun");
    let (from, to) = reruns("fault_nan_first_attempt = { update = 3, rollout = 7 }\n");
    let text = config(&[(from, to.as_str()), DELAYED]);
    let cfg = write_config(&scratch, "rerun.toml", &text);
    let (mcap, result) = (
        scratch.path("rerun.mcap"),
        scratch.path("rerun.toml.result"),
    );
    let args = [
        cfg.to_str().unwrap(),
        "--workers",
        "2",
        "--quiet",
        "--record",
        mcap.to_str().unwrap(),
        "--result",
        result.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 1100, &args);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(
        out.contains(
            "update 3: cost of rollout 7 (terminal) is NaN; costs must be finite (attempt 1 of \
             at most 3, by worker-"
        ),
        "{out}"
    );
    assert!(
        out.contains(
            "1 rollout execution(s) with non-finite costs run again (run.nonfinite_reruns = 2)"
        ),
        "{out}"
    );
    let r = RunResult::read(&result).unwrap();
    assert_eq!((r.updates, r.complete, r.nonfinite_reruns), (40, true, 1));
    assert_bit_identical(&text, &result);
    // The fault changes nothing once rerun: the run without it.
    assert_bit_identical(&config(&[DELAYED]), &result);

    let rec = record::read_recording(&mcap).unwrap();
    assert_recorded(&rec, 40);
    assert_recording_matches_in_process(&text, &rec);
    let logged = warnings(&rec);
    assert_eq!(logged.len(), 1, "{logged:?}");
    let (update, name, message) = &logged[0];
    assert_eq!(*update, 3);
    assert!(name == "worker-0" || name == "worker-1", "{name}");
    assert_eq!(
        *message,
        format!(
            "update 3: cost of rollout 7 (terminal) is NaN; costs must be finite (attempt 1 of \
             at most 3, by {name}): rerunning it with the same parameters \
             (run.nonfinite_reruns = 2)"
        )
    );
    // One accepted execution of each rollout.
    let of_update_3 = rec.rollouts.iter().filter(|r| r.update == 3).count();
    assert_eq!(of_update_3, 15);
    assert_nothing_left(&run);
}

/// Every rollout of an update rejected at once — K rerun requests in one burst, more than the
/// `control` service buffers (2·max_workers + 16) — is every one run again: none of the requests
/// may be lost while the sampler is not scheduled, or the update waits forever for a rollout
/// nobody hands out.
#[test]
fn a_burst_of_rejected_rollouts_larger_than_any_buffer_is_run_again_whole() {
    let scratch = Scratch::new("rerun-burst");
    let (from, to) = reruns("fault_nan_first_attempt = { update = 2 }\n");
    let text = config(&[
        (from, to.as_str()),
        ("updates = 40\n", "updates = 6\n"),
        ("rollouts = 15", "rollouts = 60"),
        (
            "workers = 3\nmax_workers = 16",
            "workers = 1\nmax_workers = 1",
        ),
    ]);
    let cfg = write_config(&scratch, "burst.toml", &text);
    let result = scratch.path("burst.toml.result");
    let args = [
        cfg.to_str().unwrap(),
        "--workers",
        "1",
        "--quiet",
        "--no-record",
        "--result",
        result.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 1840, &args);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(
        out.contains(
            "60 rollout execution(s) with non-finite costs run again (run.nonfinite_reruns = 2)"
        ),
        "{out}"
    );
    let r = RunResult::read(&result).unwrap();
    assert_eq!((r.updates, r.complete, r.nonfinite_reruns), (6, true, 60));
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A cost that stays non-finite is no transient fault: after `run.nonfinite_reruns` reruns the
/// run fails as without them, and says how many were tried.
#[test]
fn a_cost_that_stays_non_finite_fails_the_run_after_the_reruns() {
    let scratch = Scratch::new("rerun-fails");
    let (from, to) = reruns("");
    let text = config(&[
        (from, to.as_str()),
        (
            "max_workers = 16",
            "max_workers = 16\nfault_nan_from_update = 3",
        ),
    ]);
    let cfg = write_config(&scratch, "persists.toml", &text);
    let mcap = scratch.path("persists.mcap");
    let args = [
        cfg.to_str().unwrap(),
        "--workers",
        "2",
        "--record",
        mcap.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 1101, &args);
    run.wait_exit(Duration::from_secs(30), 1);
    let out = run.text();
    assert!(
        out.contains("NaN; costs must be finite (reported by worker-")
            && out.contains(
                "), still after 2 reruns with the same parameters (run.nonfinite_reruns = 2)"
            ),
        "{out}"
    );
    assert!(out.contains("update 3: cost of rollout "), "{out}");
    let rec = record::read_recording(&mcap).unwrap();
    assert_eq!(update_indices(&rec), (0..3).collect::<Vec<_>>());
    let logged = warnings(&rec);
    assert!(
        logged
            .iter()
            .any(|(u, _, m)| *u == 3 && m.contains("(attempt 2 of at most 3, by worker-")),
        "{logged:?}"
    );
    assert_nothing_left(&run);
}

/// `--result` is written when the run ends, maybe days later: a place it cannot be written is
/// refused before anything starts, and one that goes away during the run still gets the
/// summary and leaves nothing behind.
#[test]
fn a_result_file_that_cannot_be_written_is_refused_at_start_and_cleaned_up_after_at_the_end() {
    let scratch = Scratch::new("result");
    for (id, dest) in [
        (520, scratch.path("missing/result.toml")),
        (521, scratch.path("")),
    ] {
        let dest = dest.to_str().unwrap();
        let mut run = Run::start(&scratch, id, &["--quiet", "--no-record", "--result", dest]);
        run.wait_exit(Duration::from_secs(10), 1);
        let out = run.text();
        assert!(out.contains(&format!("--result {dest}")), "{out}");
        assert!(!out.contains("starting"), "{out}");
        assert_nothing_left(&run);
    }
    assert!(!scratch.path("missing").exists());

    let cfg = write_config(&scratch, "continual.toml", &config(&[UNBOUNDED, DELAYED]));
    let out_dir = scratch.path("out");
    std::fs::create_dir_all(&out_dir).unwrap();
    let result = out_dir.join("result.toml");
    let mut run = Run::start(
        &scratch,
        522,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--no-record",
            "--result",
            result.to_str().unwrap(),
        ],
    );
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    std::fs::remove_dir_all(&out_dir).unwrap();
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 1);
    let out = run.text();
    assert!(out.contains("cannot copy the result to"), "{out}");
    assert!(
        out.contains("summary: run") && out.contains("final mean"),
        "{out}"
    );
    assert_nothing_left(&run);
}

/// A full /dev/shm kills the process that writes to a page it has no room for with SIGBUS (the
/// segments are sized without their pages): the supervisor says what that most likely means.
#[test]
fn a_worker_killed_by_sigbus_is_reported_with_the_state_of_the_shared_memory() {
    let scratch = Scratch::new("sigbus");
    let cfg = write_config(&scratch, "continual.toml", &config(&[UNBOUNDED, DELAYED]));
    let mut run = Run::start(&scratch, 523, &[cfg.to_str().unwrap(), "--no-record"]);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let pid = pid_of(&status, "worker-1");
    // Rust's stack-overflow handler takes the first SIGBUS, restores the default action and
    // returns (a real fault then recurs, a sent signal does not): so send it until it kills.
    let end = Instant::now() + Duration::from_secs(20);
    while !run.text().contains("SIGBUS here most likely") {
        assert!(Instant::now() < end, "{}", run.text());
        let _ = Command::new("kill")
            .args(["-BUS", &pid.to_string()])
            .status();
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = run.text();
    assert!(
        out.contains(&format!("worker-1 (pid {pid}) died (signal: 7 (SIGBUS)"))
            && out.contains("shared memory is full: /dev/shm has"),
        "{out}"
    );
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_nothing_left(&run);
}

#[test]
fn a_run_is_recorded_by_default_and_every_update_recomputes_bit_identically() {
    let scratch = Scratch::exclusive("record");
    // The quick start: the built-in default at full speed.
    let mut run = Run::start(&scratch, 600, &["--quiet"]);
    run.wait_exit(Duration::from_secs(60), 0);
    // The predictable place, relative to the working directory, and how to analyse it.
    let shown = format!("runs/A1-{}.mcap", run_id(600));
    let out = run.text();
    assert!(
        out.contains(&format!("recording: {shown} (the default place")),
        "{out}"
    );
    // The pi2cma beside the supervisor, as the command must be typed, writing beside the file
    // (`cargo test -p supervisor` alone does not build pi2cma: then how to build it is said).
    let pi2cma = Path::new(env!("CARGO_BIN_EXE_supervisor")).with_file_name("pi2cma");
    if pi2cma.is_file() {
        let analyse = format!(
            "analyse it with: {} analyze {shown} --out runs",
            pi2cma.display()
        );
        assert!(out.contains(&analyse), "{out}");
        // It works as printed, and writes beside the recording.
        let ran = std::process::Command::new(&pi2cma)
            .args(["analyze", &shown, "--out", "runs"])
            .current_dir(&scratch.0)
            .output()
            .unwrap();
        assert!(ran.status.success(), "{ran:?}");
        let figure = scratch.path(&format!("runs/A1-{}/learning_curve.svg", run_id(600)));
        assert!(figure.is_file(), "{}", String::from_utf8_lossy(&ran.stdout));
    } else {
        assert!(
            out.contains(&format!("analyse it with: pi2cma analyze {shown} --out runs   (pi2cma: `cargo build --release -p pi2cma-cli`")),
            "{out}"
        );
    }
    let rec = record::read_recording(&scratch.recording("A1", 600)).unwrap();
    assert!(rec.indexed && rec.truncated.is_none());
    assert_eq!(rec.run_info().unwrap().executor, "pipeline");
    // Every process's announcement is logged. (A recorder that drains late sees a worker's
    // announcement after it wrote an update and logs it as `scale` instead of `start`.)
    for name in ["updater", "sampler", "worker-0", "worker-1", "worker-2"] {
        assert!(
            logged(&rec, "start", name) || logged(&rec, "scale", name),
            "{name}: {:#?}",
            rec.logs
        );
    }
    assert!(logged(&rec, "exit", "recorder"), "{:#?}", rec.logs);
    // Every update recorded and recomputed bit for bit, at full speed: the subscriber buffers
    // hold 256 updates (wire::RECORDER_SLACK_UPDATES), more than this whole run.
    assert_recorded(&rec, 40);
    assert_recording_matches_in_process(session::DEFAULT_CONFIG, &rec);
    assert_rollouts_timed_by_their_workers(&rec);
    assert_nothing_left(&run);

    // The default config with 2 ms rollouts (same costs, same result): every update recorded,
    // recomputed bit for bit, and the last one equal to the in-process run's.
    let text = config(&[DELAYED]);
    let cfg = write_config(&scratch, "delayed.toml", &text);
    let mut run = Run::start(&scratch, 602, &[cfg.to_str().unwrap(), "--quiet"]);
    run.wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(&scratch.recording("A1", 602)).unwrap();
    assert_recorded(&rec, 40);
    assert_recording_matches_in_process(session::DEFAULT_CONFIG, &rec);
    assert_rollouts_timed_by_their_workers(&rec);
    assert_eq!(rec.task_changes.len(), 1);
    // It ended by itself after the final distribution, not by the supervisor's SIGTERM.
    assert!(
        rec.logs
            .iter()
            .any(|l| l.event == "exit" && l.message.contains("(run complete)")),
        "{:#?}",
        rec.logs
    );
    assert_nothing_left(&run);

    // --no-record: no recorder, no file.
    let mut run = Run::start(&scratch, 601, &["--quiet", "--no-record"]);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(!scratch.recording("A1", 601).exists());
    assert!(!run.text().contains("recording:"), "{}", run.text());
    assert_nothing_left(&run);
}

/// `run CONFIG --quiet --record MCAP --result RESULT`.
fn start_recorded(scratch: &Scratch, id: u64, config: &Path, mcap: &Path, result: &Path) -> Run {
    let args = [
        config.to_str().unwrap(),
        "--quiet",
        "--record",
        mcap.to_str().unwrap(),
        "--result",
        result.to_str().unwrap(),
    ];
    Run::start(scratch, id, &args)
}

/// `recording.split_mb`: the pipeline's recording is a series of finished parts, each one a
/// recording that verifies by itself; together they are the run, and the summary names them all.
#[test]
fn a_split_pipeline_recording_is_finished_parts_that_make_the_run() {
    let scratch = Scratch::new("rec-split");
    let text = format!(
        "{}\n[recording]\nsplit_mb = 1\n",
        config(&[("updates = 40", "updates = 200"), DELAYED])
    );
    let cfg = write_config(&scratch, "split.toml", &text);
    let mcap = scratch.path("split.mcap");
    let result = scratch.path("result.toml");
    let mut run = start_recorded(&scratch, 740, &cfg, &mcap, &result);
    // Status names the part being written (part 2 holds updates 76..=151).
    let said = format!("part 2 of the recording begun in {}", mcap.display());
    run.wait_status("part 2", |s| s.contains(&said));
    run.wait_exit(Duration::from_secs(60), 0);
    let parts = record::recording_parts(&mcap);
    assert_eq!(parts.len(), 3, "{parts:?}");
    let names: Vec<String> = parts.iter().map(|p| p.display().to_string()).collect();
    let out = run.text();
    assert!(
        out.contains(&format!("split into 3 parts: {}", names.join(", "))),
        "{out}"
    );
    assert!(
        out.contains(&format!("pi2cma analyze {}", names.join(" "))),
        "{out}"
    );
    let mut recs = Vec::new();
    for p in &parts {
        let rec = record::read_recording(p).unwrap();
        assert!(rec.indexed && rec.truncated.is_none(), "{}", p.display());
        assert_recomputes(&rec);
        recs.push(rec);
    }
    let runs = record::join_resumed(recs);
    assert_eq!(runs.len(), 1);
    assert_eq!(update_indices(&runs[0].0), (0..200).collect::<Vec<_>>());
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A long run's earlier parts archived while it runs (here the first two): `status` still names
/// the part being written, and a recorder that dies then goes on in the part after it, with
/// that part recovered. Before, the parts ended at the first one missing: `status` named the
/// moved first file, the dead recorder's part was left unfinished while the supervisor tried to
/// recover the missing file (exit 3), and the new recorder began again in part 2 and would
/// have truncated part 3 on reaching it.
#[test]
fn a_recorder_that_dies_after_earlier_parts_were_archived_goes_on_after_the_last_part() {
    let scratch = Scratch::new("rec-archived");
    let text = format!(
        "{}\n[recording]\nsplit_mb = 1\n",
        config(&[("updates = 40", "updates = 400"), DELAYED])
    );
    let cfg = write_config(&scratch, "archived.toml", &text);
    let mcap = scratch.path("day.mcap");
    let result = scratch.path("result.toml");
    let mut run = start_recorded(&scratch, 960, &cfg, &mcap, &result);
    let part = |n| record::part_path(&mcap, n);
    run.wait_status("part 3", |s| s.contains("part 3 of the recording begun in"));
    std::fs::remove_file(&mcap).unwrap();
    std::fs::remove_file(part(2)).unwrap();
    // The part being written, as `status` names it: 3, or a later one on a slow machine.
    let writing = |s: &str| -> Option<u32> {
        let line = s.lines().find(|l| l.starts_with("recording: "))?;
        let (file, rest) = line["recording: ".len()..].split_once(", part ")?;
        let n: u32 = rest.split_whitespace().next()?.parse().ok()?;
        (n >= 3 && Path::new(file) == part(n)).then_some(n)
    };
    let status = run.wait_status("the part being written after archiving", |s| {
        writing(s).is_some()
    });
    let victim = sigkill_recorder(&status);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(
        out.contains(&format!("WARNING: recorder (pid {victim}) died")),
        "{out}"
    );
    let restarted = out
        .lines()
        .find_map(|l| {
            l.split_once("recorder restarted: recording to ")
                .map(|(_, file)| PathBuf::from(file.trim()))
        })
        .unwrap_or_else(|| panic!("no restart:\n{out}"));
    let n = record::part_number(&restarted);
    assert!(
        restarted == part(n) && n > writing(&status).unwrap(),
        "{}:\n{out}",
        restarted.display()
    );
    assert!(!out.contains("NOT finished"), "{out}");
    // The summary still says what became of the recording, its first part gone or not.
    let dead = part(n - 1).display().to_string();
    assert!(
        out.contains("the recorder died and was restarted 1 time(s)")
            && out.contains(&format!("into {dead} (complete, indexed)")),
        "{out}"
    );
    let parts = record::recording_parts(&mcap);
    assert_eq!(parts[1], part(3), "{parts:?}");
    let recs: Vec<record::Recording> = parts[1..]
        .iter()
        .map(|p| record::read_recording(p).unwrap())
        .collect();
    for (p, rec) in parts[1..].iter().zip(&recs) {
        assert!(rec.indexed && rec.truncated.is_none(), "{}", p.display());
    }
    // Part 3 kept what it held: from where part 2 ended, not overwritten by a later part.
    assert!(
        recs[0].updates[0].update > 100,
        "{}",
        recs[0].updates[0].update
    );
    let runs = record::join_resumed(recs);
    assert_eq!(runs.len(), 1);
    assert_eq!(runs[0].0.updates.last().unwrap().update, 399);
    assert_nothing_left(&run);
}

#[test]
fn sigint_mid_run_leaves_a_finished_recording_with_every_completed_update() {
    let scratch = Scratch::new("rec-sigint");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "sigint.toml", &text);
    let mcap = scratch.path("chosen/interrupted.mcap");
    let result = scratch.path("result.toml");
    let mut run = start_recorded(&scratch, 705, &cfg, &mcap, &result);
    run.wait_status("5 updates", |s| updates_in(s) >= 5);
    signal(run.child.id(), "-INT");
    run.wait_exit(Duration::from_secs(15), 130);
    let out = run.text();
    assert!(
        out.contains(&format!("recording: {}\n", mcap.display())),
        "{out}"
    );
    assert!(
        out.contains(&format!("pi2cma analyze {}", mcap.display())),
        "{out}"
    );
    // Every update the updater completed, in a finished (indexed) file.
    let r = RunResult::read(&result).unwrap();
    assert!(r.updates >= 5 && !r.complete);
    let rec = record::read_recording(&mcap).unwrap();
    assert_recorded(&rec, r.updates);
    assert_recording_matches_in_process(&text, &rec);
    // Stopped by the supervisor's SIGTERM, after the updater: it finished the file.
    assert!(
        rec.logs
            .iter()
            .any(|l| l.event == "exit" && l.message.contains("(signal)")),
        "{:#?}",
        rec.logs
    );
    // The workers stopped with the run, and their rollouts went nowhere: the log said they
    // went "to the other workers", which were stopping too.
    let stopped: Vec<&str> = rec
        .logs
        .iter()
        .filter(|l| l.message.contains("stopped with the run"))
        .map(|l| l.message.as_str())
        .collect();
    assert!(
        !stopped.is_empty() && stopped.iter().all(|m| !m.contains("other workers")),
        "{stopped:#?}"
    );
    assert_nothing_left(&run);
}

/// A worker that does not stop in time (a robot's long episode; here one stopped with SIGSTOP)
/// is killed alone: the sampler, updater and recorder still stop in order, and the recording is
/// finished with every completed update.
#[test]
fn a_worker_that_outlasts_the_shutdown_timeout_is_killed_alone_and_the_recording_finished() {
    let scratch = Scratch::new("stuck-stop");
    let text = config(&[
        UNBOUNDED,
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nshutdown_timeout_ms = 3000",
        ),
    ]);
    let cfg = write_config(&scratch, "stuck.toml", &text);
    let mcap = scratch.path("stuck.mcap");
    let result = scratch.path("result.toml");
    let mut run = start_recorded(&scratch, 707, &cfg, &mcap, &result);
    let status = run.wait_status("5 updates", |s| updates_in(s) >= 5);
    let worker = pid_of(&status, "worker-1");
    signal(worker, "-STOP");
    signal(run.child.id(), "-INT");
    run.wait_exit(Duration::from_secs(20), 130);
    let out = run.text();
    // Killed alone (another worker slow to take SIGTERM may be named with it).
    let killed = out
        .lines()
        .find(|l| l.contains("did not stop within 3000 ms"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        killed.contains(&format!("worker-1 (pid {worker})")),
        "{out}"
    );
    for role in ["sampler", "updater", "recorder"] {
        assert!(!killed.contains(role), "{out}");
    }
    assert!(!out.contains("failed"), "{out}");
    let r = RunResult::read(&result).unwrap();
    let rec = record::read_recording(&mcap).unwrap();
    assert!(rec.indexed, "{out}");
    assert_recorded(&rec, r.updates);
    assert_nothing_left(&run);
}

/// A run that stops making updates (a worker stopped with SIGSTOP, no rollout timeout) is
/// reported after at least 10 s, `status` shows how long ago the last update was, and the
/// supervisor says so when the run goes on.
#[test]
fn a_run_without_updates_is_reported_and_its_age_shown() {
    let scratch = Scratch::new("stall");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "stall.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 708, &cfg, &result);
    let status = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    assert!(status.contains(" s ago\n"), "{status}");
    let workers: Vec<u32> = pids_in(&status)
        .into_iter()
        .filter(|(n, _)| n.starts_with("worker-"))
        .map(|(_, pid)| pid)
        .collect();
    let signal_all = |sig: &str| {
        for pid in &workers {
            signal(*pid, sig);
        }
    };
    signal_all("-STOP");
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("warning: no update for", end);
    // The recorder has written everything: the warning does not blame it. Nor does it take
    // the stopped workers for hung ones ("a worker may hang"): it names them.
    let text = run.text();
    let warning = text
        .lines()
        .find(|l| l.contains("warning: no update for"))
        .unwrap();
    assert!(
        warning.contains(
            ": stopped by a signal (SIGSTOP, Ctrl-Z), which holds the run until they get SIGCONT"
        ) && workers
            .iter()
            .all(|pid| warning.contains(&format!(" (pid {pid})"))),
        "{warning}"
    );
    let (_, status) = run.ctl(&["status"]);
    assert!(
        status.contains("\nstalled: no update for ")
            && status.contains(" s, where they came every "),
        "{status}"
    );
    assert!(
        status.contains("3 running (target 3, max 16), 3 of them stopped by a signal")
            && workers.iter().all(|pid| status.contains(&format!(
                " pid {pid} incarnation 0 (stopped by a signal: it runs nothing until `kill -CONT -- -{pid}`)"
            ))),
        "{status}"
    );
    let age: f64 = status
        .split(", the last ")
        .nth(1)
        .and_then(|s| s.split(" s ago").next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("{status}"));
    assert!(age >= 10.0, "{status}");
    signal_all("-CONT");
    run.wait_output("the run goes on: ", end);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let rec = record::read_recording(&scratch.recording("A1", 708)).unwrap();
    let warned = rec.logs.iter().any(|l| {
        l.event == "warning" && l.name == "supervisor" && l.message.starts_with("no update for")
    });
    assert!(warned, "{:#?}", rec.logs);
    assert_nothing_left(&run);
}

/// A recorder that stops (SIGSTOP) holds the updater back: the stall warning names it, with
/// how far it has written, instead of "a worker or the recorder may hang".
#[test]
fn a_stopped_recorder_is_named_in_the_stall_warning() {
    let scratch = Scratch::new("stall-recorder");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "stall-recorder.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1912, &cfg, &result);
    let status = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let recorder = pid_of(&status, "recorder");
    signal(recorder, "-STOP");
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("warning: no update for", end);
    let text = run.text();
    let warning = text
        .lines()
        .find(|l| l.contains("warning: no update for"))
        .unwrap();
    assert!(
        warning.contains(": the recorder has written only through update ")
            && warning.contains(
                " behind the updater, which it holds back): is it stopped, or is its disk slow?"
            ),
        "{warning}"
    );
    signal(recorder, "-CONT");
    run.wait_output("the run goes on: ", end);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_nothing_left(&run);
}

/// Updates that came faster than the updater's progress interval, then stopped: the supervisor
/// still learns of every one within a moment (it saw none of the five, and its no-update
/// warning said "since the start"), and a stop is not taken for updates going on.
#[test]
fn the_last_updates_before_a_stall_are_reported() {
    let scratch = Scratch::new("stall-late");
    let text = config(&[
        UNBOUNDED,
        (
            "max_workers = 16",
            "max_workers = 16\nfault_hang_at_update = 5",
        ),
    ]);
    let cfg = write_config(&scratch, "stall5.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 711, &cfg, &result);
    run.wait_status("the 5 updates before the hang", |s| updates_in(s) == 5);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert!(!run.text().contains("the run goes on"), "{}", run.text());
    assert_nothing_left(&run);
}

/// Workers that hang in the first update (no rollout timeout): the run is reported as stalled
/// since its start, and a stop still ends it.
#[test]
fn a_first_update_that_never_comes_is_reported() {
    let scratch = Scratch::new("stall-start");
    let text = config(&[
        UNBOUNDED,
        (
            "max_workers = 16",
            "max_workers = 16\nfault_hang_at_update = 0",
        ),
    ]);
    let cfg = write_config(&scratch, "stall0.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 709, &cfg, &result);
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("no update for", end);
    // Slow rollouts look the same before the first update: the warning says so too.
    assert!(
        run.text().contains(
            "s since the start: a worker may hang, or the first update's 15 rollouts take that \
             long on 3 workers (pipeline.rollout_timeout_ms is not set"
        ),
        "{}",
        run.text()
    );
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_nothing_left(&run);
}

#[test]
fn a_killed_recorder_is_restarted_into_a_new_part_and_only_its_unwritten_updates_are_missing() {
    let scratch = Scratch::new("rec-restart");
    let text = config(&[("updates = 40", "updates = 200"), DELAYED]);
    let cfg = write_config(&scratch, "restart.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 802, &cfg, &result);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    let path = scratch.recording("A1", 802);
    let flushed = record::read_recording(&path).unwrap().updates.len();
    let victim = sigkill_recorder(&status);
    // The second recorder, killed too once it records: a restart of a restart.
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("recorder restarted: recording to", end);
    let part2 = record::part_path(&path, 2);
    let status = run.wait_status("10 updates in part 2", |s| {
        s.contains("(the recorder was restarted 1 time(s))")
            && record::read_recording(&part2).is_ok_and(|r| r.updates.len() >= 10)
    });
    let second_victim = sigkill_recorder(&status);
    // Every part recovered or finished: a complete recording, exit 0.
    run.wait_exit(Duration::from_secs(60), 0);
    assert_eq!(RunResult::read(&result).unwrap().updates, 200);
    let out = run.text();
    for pid in [victim, second_victim] {
        assert!(
            out.contains(&format!("WARNING: recorder (pid {pid}) died")),
            "{out}"
        );
    }
    assert!(
        out.contains("restart 2 of 5: the recording goes on in"),
        "{out}"
    );
    assert_eq!(out.matches("[recorder] recording to").count(), 3, "{out}");
    assert!(out.contains("was restarted 2 time(s)"), "{out}");
    assert!(!out.contains("NOT finished"), "{out}");
    let part3 = record::part_path(&path, 3);
    let parts: Vec<record::Recording> = [&path, &part2, &part3]
        .iter()
        .map(|p| record::read_recording(p).unwrap())
        .collect();
    for (i, p) in parts.iter().enumerate() {
        assert!(p.indexed, "part {} not finished", i + 1);
        assert!(p.truncated.is_none(), "part {}: {:?}", i + 1, p.truncated);
    }
    assert!(parts[0].updates.len() >= flushed.max(1));
    assert_eq!(parts[2].updates.last().unwrap().update, 199);
    // Each gap is at most what the dead recorder may have left unwritten: the lag bound, the
    // update in flight, and the one the updater held when it was told of the new recorder.
    let lag = wire::RECORDER_MAX_LAG;
    for pair in parts.windows(2) {
        let (end, begin) = (
            pair[0].updates.last().unwrap().update + 1,
            pair[1].updates.first().unwrap().update,
        );
        assert!(begin >= end && begin - end <= lag + 2, "{end}..{begin}");
        // The summary names the updates between the parts, as the parts hold them.
        let missing = match begin - end {
            0 => "no update is missing".to_string(),
            1 => format!("missing {end} (not recorded)"),
            _ => format!("missing {end}–{} (not recorded)", begin - 1),
        };
        let said = format!(
            "{}: begins at update {begin} after a recorder restart",
            pair[1].path.file_name().unwrap().to_string_lossy()
        );
        let line = out.lines().find(|l| l.contains(&said));
        assert!(
            line.is_some_and(|l| l.contains(&missing)),
            "{said} … {missing}:\n{out}"
        );
        assert!(
            pair[1]
                .logs
                .iter()
                .any(|l| l.event == "warning" && l.message.contains("the recorder was restarted")),
            "{:?}",
            pair[1].logs
        );
    }
    // One run, joined across the gaps, in any order given, and every update in it recomputes.
    let mut shuffled = parts.clone();
    shuffled.reverse();
    let runs = record::join_resumed(shuffled);
    assert_eq!(runs.len(), 1);
    let (joined, files) = &runs[0];
    assert_eq!(files, &[path.clone(), part2.clone(), part3.clone()]);
    let recorded: usize = parts.iter().map(|p| p.updates.len()).sum();
    assert_eq!(joined.updates.len(), recorded);
    assert_recomputes(joined);
    assert_recording_matches_in_process(&text, joined);
    let info = record::analyze::info(joined);
    assert!(info.contains("missing"), "{info}");
    // The Python reader's `--join` takes the parts as one run as well, with the gaps named
    // (it refused them: "does not go on where … ends"). Needs tools/requirements.txt.
    let text = python_join_check(&[&path, &part2, &part3]);
    assert!(
        text.contains("joined 3 files: updates 0..199; missing ")
            && text.contains("(not recorded: the recorder was restarted)")
            && text.contains("3 passed, 0 failed, join passed"),
        "{text}"
    );
    assert_nothing_left(&run);
}

#[test]
fn a_killed_recorder_past_the_restart_limit_is_not_restarted_and_recover_completes_the_file() {
    let scratch = Scratch::new("rec-kill");
    let text = config(&[
        ("updates = 40", "updates = 200"),
        DELAYED,
        ("max_workers = 16", "max_workers = 16\nrestart_limit = 0"),
    ]);
    let cfg = write_config(&scratch, "kill.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 800, &cfg, &result);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    let path = scratch.recording("A1", 800);
    // What the recorder has flushed so far must survive its SIGKILL.
    let flushed = record::read_recording(&path).unwrap().updates.len();
    let victim = sigkill_recorder(&status);
    // Complete, but the recording is not: scripts must notice.
    run.wait_exit(Duration::from_secs(60), 3);
    assert_eq!(RunResult::read(&result).unwrap().updates, 200);
    let out = run.text();
    let shown = format!("runs/A1-{}.mcap", run_id(800));
    assert!(
        out.contains(&format!("WARNING: recorder (pid {victim}) died"))
            && out.contains("the run continues without recording"),
        "{out}"
    );
    assert!(out.contains(&format!("pi2cma recover {shown}")), "{out}");
    assert!(out.contains("is NOT finished"), "{out}");
    assert!(
        out.contains("recorder not restarted: 0 restarts within 60 s"),
        "{out}"
    );
    // Not restarted: exactly one recorder ran.
    assert_eq!(out.matches("[recorder] recording to").count(), 1, "{out}");
    let damaged = record::read_recording(&path).unwrap();
    assert!(!damaged.indexed);
    let fixed = scratch.path("fixed.mcap");
    let report = record::recover::recover(&path, &fixed).unwrap();
    let rec = record::read_recording(&fixed).unwrap();
    assert!(rec.indexed, "{report:?}");
    let recovered = assert_recovered(&rec, flushed.max(1));
    assert_eq!(recovered, damaged.updates.len());
    assert_recording_matches_in_process(&text, &rec);
    assert_nothing_left(&run);
}

/// A recording that reaches the file size limit (`ulimit -f`, as batch systems set) is a full
/// disk: the recorder says so, naming the file, and is not restarted into parts that meet the
/// same limit; the file holds every update up to it. SIGXFSZ killed it before, silently ("died
/// (signal: 25 (SIGXFSZ))"), five restarts each lost updates, and the run went on unrecorded.
#[test]
fn a_recorder_at_the_file_size_limit_says_so_and_is_not_restarted() {
    let scratch = Scratch::new("fsize");
    let cfg = write_config(
        &scratch,
        "fsize.toml",
        &config(&[("updates = 40", "updates = 3000")]),
    );
    let path = scratch.path("fsize.mcap");
    let id = run_id(27600);
    // 4000 blocks (2 MB in sh's 512-byte blocks): the run's shared memory fits, the recording
    // (about 15 kB per update) does not.
    let out = Command::new("sh")
        .args([
            "-c",
            "ulimit -f 4000; exec \"$0\" \"$@\"",
            SUPERVISOR,
            "run",
        ])
        .arg(&cfg)
        .args(["--quiet", "--run-id", &id, "--record"])
        .arg(&path)
        .current_dir(&scratch.0)
        .env("PI2CMA_RUN_DIR", scratch.runs())
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains(&format!(
            "recorder failed: {}: MCAP: I/O error: File too large",
            path.display()
        )) && text.contains("recorder not restarted: it stopped at an error of its own")
            && !text.contains("SIGXFSZ"),
        "{text}"
    );
    assert_eq!(text.matches("[recorder] recording to").count(), 1, "{text}");
    let fixed = scratch.path("fixed.mcap");
    record::recover::recover(&path, &fixed).unwrap();
    let (_, report) = record::recompute::read_and_verify(&fixed).unwrap();
    assert!(
        report.updates > 0 && report.mismatches.is_empty(),
        "{report:?}"
    );
}

/// Processes killed by SIGXFSZ (a file size limit so low that the workers' shared memory files
/// pass it) are said to have met the limit, with its size: `died (signal: 25 (SIGXFSZ))` alone
/// said neither.
#[test]
fn a_process_killed_by_the_file_size_limit_is_said_to_have_met_it() {
    let scratch = Scratch::new("xfsz");
    let id = run_id(27604);
    // 400 blocks of 512 bytes (sh's unit): 200 KiB, less than a worker's shared memory.
    let out = Command::new("sh")
        .args(["-c", "ulimit -f 400; exec \"$0\" \"$@\"", SUPERVISOR, "run"])
        .args(["--quiet", "--no-record", "--run-id", &id])
        .current_dir(&scratch.0)
        .env("PI2CMA_RUN_DIR", scratch.runs())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    let deaths: Vec<&str> = text.lines().filter(|l| l.contains("(SIGXFSZ)")).collect();
    // So low that the supervisor's own ports fail (it ignores SIGXFSZ): iceoryx2's error
    // (`InternalError`, `UnableToCreateDataSegment`) gets a note on the limit.
    for blocks in ["4", "40"] {
        let out = Command::new("sh")
            .args(["-c", "ulimit -f \"$1\"; shift; exec \"$0\" \"$@\""])
            .args([
                SUPERVISOR,
                blocks,
                "run",
                "--quiet",
                "--no-record",
                "--run-id",
                &id,
            ])
            .current_dir(&scratch.0)
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(&format!(
                "[supervisor] note: a file size limit is set (`ulimit -f`: {} KiB), and \
                 iceoryx2's shared memory files count against it",
                blocks.parse::<u64>().unwrap() / 2
            )),
            "ulimit -f {blocks}: {err}"
        );
    }
    assert!(!deaths.is_empty(), "{text}");
    for l in deaths {
        assert!(
            l.contains(
                "SIGXFSZ means it wrote past the file size limit (`ulimit -f`: 200 KiB); its \
                 shared memory files count against it"
            ),
            "{l}"
        );
    }
}

/// A recorder not restarted (restart_limit = 0 here; a full disk in use) is started again by
/// `supervisor record`: the recording goes on in a new part, the dead one is recovered, and the
/// run ends with a complete recording (exit 0).
#[test]
fn supervisor_record_starts_a_recorder_that_was_not_restarted_again() {
    let scratch = Scratch::new("rec-again");
    let text = config(&[
        ("updates = 40", "updates = 300"),
        DELAYED,
        ("max_workers = 16", "max_workers = 16\nrestart_limit = 0"),
    ]);
    let cfg = write_config(&scratch, "again.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 807, &cfg, &result);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    let (ok, reply) = run.ctl(&["record"]);
    assert!(!ok && reply.contains("the recorder is running"), "{reply}");
    sigkill_recorder(&status);
    run.wait_status("the recorder gone", |s| {
        s.contains("`supervisor record` starts it again")
    });
    let reply = run.ctl_ok(&["record"]);
    assert!(
        reply.contains("recorder started again (restart 1)"),
        "{reply}"
    );
    run.wait_exit(Duration::from_secs(60), 0);
    let path = scratch.recording("A1", 807);
    let parts =
        [path.clone(), record::part_path(&path, 2)].map(|p| record::read_recording(&p).unwrap());
    assert!(parts.iter().all(|p| p.indexed && p.truncated.is_none()));
    assert_eq!(parts[1].updates.last().unwrap().update, 299);
    let runs = record::join_resumed(parts.to_vec());
    assert_eq!(runs.len(), 1);
    assert_recomputes(&runs[0].0);
    assert!(
        parts[1]
            .logs
            .iter()
            .any(|l| l.message.contains("`supervisor record`")),
        "{:?}",
        parts[1].logs
    );
    assert_nothing_left(&run);
}

/// A recorder started again (`supervisor record`) while the run goes at full speed: until the
/// updater hears of it (Control::RECORDER_BACK) it runs free, so the new recorder takes in the
/// distributions and costs of more updates in a round than the lag bound, and after it the
/// updater counts the lag from where it is, not from the recorder's first update. Those costs
/// are the run's own: none may be dropped as out of the updater's reach. They were, each worker
/// named as one "started with another config" (in about half of such restarts: three here).
#[test]
fn a_recorder_started_again_at_full_speed_drops_no_cost_of_the_run() {
    let scratch = Scratch::new("rec-again-fast");
    let text = config(&[
        UNBOUNDED,
        ("max_workers = 16", "max_workers = 16\nrestart_limit = 0"),
    ]);
    let cfg = write_config(&scratch, "again-fast.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 5250, &cfg, &result);
    let path = scratch.recording("A1", 5250);
    let mut status = run.wait_status("100 updates", |s| updates_in(s) >= 100);
    for part in 2..=4 {
        sigkill_recorder(&status);
        run.wait_status("the recorder gone", |s| {
            s.contains("`supervisor record` starts it again")
        });
        run.ctl_ok(&["record"]);
        let file = record::part_path(&path, part);
        status = run.wait_status(&format!("300 updates in part {part}"), |_| {
            record::read_recording(&file).is_ok_and(|r| r.updates.len() >= 300)
        });
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    for part in 2..=4 {
        let rec = record::read_recording(&record::part_path(&path, part)).unwrap();
        let dropped: Vec<&str> = rec
            .logs
            .iter()
            .filter(|l| l.message.contains(" dropped: "))
            .map(|l| l.message.as_str())
            .collect();
        assert!(dropped.is_empty(), "part {part}: {dropped:#?}");
    }
    assert_nothing_left(&run);
}

/// A recorder that dies again and again (a recurring crash, within `restart_limit`): each
/// death starts a recovery thread for the part it left. Before, none was joined until the run
/// ended, and each kept its stack mapped (2 MB, two mappings): the supervisor's address space
/// grew by that per restart for as long as the run went on.
#[test]
fn the_recoveries_of_a_recorder_restarted_again_and_again_do_not_pile_up() {
    let scratch = Scratch::new("rec-piling");
    let text = config(&[
        ("updates = 40", "updates = 100000"),
        DELAYED,
        (
            "max_workers = 16",
            "max_workers = 16\nrestart_limit = 30\nrestart_window_s = 600",
        ),
    ]);
    let cfg = write_config(&scratch, "again.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 961, &cfg, &result);
    let path = scratch.recording("A1", 961);
    let mappings = |pid: u32| {
        std::fs::read_to_string(format!("/proc/{pid}/maps"))
            .unwrap()
            .lines()
            .count()
    };
    let supervisor = run.child.id();
    let end = Instant::now() + Duration::from_secs(120);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    sigkill_recorder(&status);
    let deaths = 14;
    let mut before = 0;
    for k in 2..=deaths {
        // Killed once its part exists, so that each death leaves a part of its own to recover.
        let victim = restarted_recorder(&run, k - 1, end);
        while !record::part_path(&path, k).exists() {
            assert!(Instant::now() < end, "no part {k}:\n{}", run.text());
            std::thread::sleep(Duration::from_millis(10));
        }
        if k == 3 {
            // After the first recoveries, which set up what any thread needs.
            before = mappings(supervisor);
        }
        signal(victim, "-9");
    }
    restarted_recorder(&run, deaths, end);
    let after = mappings(supervisor);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(
        after < before + 8,
        "{before} mappings after 2 restarts, {after} after {deaths}"
    );
    let out = run.text();
    assert!(!out.contains("NOT finished"), "{out}");
    // A recorder killed before its first record (a loaded machine) leaves nothing to recover.
    assert_eq!(
        out.matches("(complete, indexed)").count()
            + out.matches(supervisor::EMPTY_PART_REMOVED).count(),
        deaths as usize,
        "{out}"
    );
    assert_nothing_left(&run);
}

#[test]
fn a_recorder_killed_at_full_speed_releases_the_updater_it_was_holding_back() {
    // µs rollouts: the updater runs into the recorder's lag bound within milliseconds, so after
    // the SIGKILL it waits for acknowledgements that never come: until the supervisor reports
    // the recorder gone (Control::RECORDER_LOST) when it is not restarted, or a restarted one
    // back (Control::RECORDER_BACK).
    for (id, limit, code) in [(801, 0, 3), (803, 5, 0)] {
        let scratch = Scratch::new(&format!("rec-kill-fast-{limit}"));
        let updates = 20_000;
        let text = config(&[
            ("updates = 40", &format!("updates = {updates}")),
            (
                "max_workers = 16",
                &format!("max_workers = 16\nrestart_limit = {limit}"),
            ),
        ]);
        let cfg = write_config(&scratch, "fast.toml", &text);
        let result = scratch.path("result.toml");
        let mut run = Run::start_quiet(&scratch, id, &cfg, &result);
        let status = run.wait_status("100 updates", |s| updates_in(s) >= 100);
        sigkill_recorder(&status);
        run.wait_exit(Duration::from_secs(60), code);
        assert_eq!(RunResult::read(&result).unwrap().updates, updates);
        let out = run.text();
        if limit == 0 {
            assert!(
                out.contains("recorder attached") && out.contains("recorder detached"),
                "{out}"
            );
        } else {
            // Held by the lag bound until the new recorder was there: no update unrecorded
            // beyond the dead one's unwritten ones.
            assert_eq!(out.matches("recorder attached").count(), 2, "{out}");
            let path = scratch.recording("A1", id);
            let parts = [path.clone(), record::part_path(&path, 2)]
                .map(|p| record::read_recording(&p).unwrap());
            let (end, begin) = (
                parts[0].updates.last().unwrap().update + 1,
                parts[1].updates.first().unwrap().update,
            );
            assert!(begin - end <= wire::RECORDER_MAX_LAG + 2, "{end}..{begin}");
            assert_eq!(parts[1].updates.last().unwrap().update, updates - 1);
        }
        assert_nothing_left(&run);
    }
}

#[test]
fn a_restarted_recorder_killed_before_its_part_exists_leaves_the_part_before_recovered_once() {
    // The restarted recorder dies before it has created its part: the part its predecessor
    // left is the last one again, and is being recovered in the background already (at full
    // speed, a part of tens of MB takes a while). Recovered a second time at once, both
    // recoveries wrote the same temporary file: the part came out damaged, and the summary said
    // it was not finished (exit 3).
    let scratch = Scratch::exclusive("rec-kill-early");
    let updates = 20_000;
    let text = config(&[("updates = 40", &format!("updates = {updates}"))]);
    let cfg = write_config(&scratch, "early.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 804, &cfg, &result);
    let status = run.wait_status("4000 updates", |s| updates_in(s) >= 4000);
    sigkill_recorder(&status);
    let second = restarted_recorder(&run, 1, Instant::now() + Duration::from_secs(10));
    signal(second, "-9");
    run.wait_exit(Duration::from_secs(60), 0);
    assert_eq!(RunResult::read(&result).unwrap().updates, updates);
    let out = run.text();
    assert!(!out.contains("NOT finished"), "{out}");
    let path = scratch.recording("A1", 804);
    let parts: Vec<record::Recording> = record::recording_parts(&path)
        .iter()
        .map(|p| record::read_recording(p).unwrap())
        .collect();
    for (i, p) in parts.iter().enumerate() {
        assert!(p.indexed && p.truncated.is_none(), "part {}: {out}", i + 1);
    }
    let runs = record::join_resumed(parts);
    assert_eq!(runs.len(), 1, "{out}");
    assert_eq!(runs[0].0.updates.last().unwrap().update, updates - 1);
    assert_nothing_left(&run);
}

#[test]
fn a_restarted_recorder_that_ends_before_its_first_update_leaves_no_part_behind() {
    // Half a second per update: a restarted recorder killed as soon as it has announced itself,
    // or stopped with the run then, has not seen a distribution yet. It used to leave a part
    // without a `/run`: empty when killed (its recovery failed: "NOT finished", exit 3, and the
    // parts no longer joined), or with only its log when stopped (`--resume` refused the
    // recording: "no /run message").
    let scratch = Scratch::new("rec-kill-unstarted");
    let text = config(&[
        ("updates = 40", "updates = 200"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
        ),
    ]);
    let cfg = write_config(&scratch, "unstarted.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 805, &cfg, &result);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    sigkill_recorder(&status);
    let restarted = |n: usize| {
        let end = Instant::now() + Duration::from_secs(30);
        while run
            .text()
            .matches("recorder restarted: recording to")
            .count()
            < n
        {
            assert!(Instant::now() < end, "no restart {n}:\n{}", run.text());
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    restarted(1);
    signal(
        restarted_recorder(&run, 1, Instant::now() + Duration::from_secs(5)),
        "-9",
    );
    restarted(2);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(!out.contains("NOT finished"), "{out}");
    let shown = format!(
        "recorder restarted: recording to runs/A1-{}.part-2.mcap",
        run_id(805)
    );
    assert_eq!(out.matches(&shown).count(), 2, "{out}");
    let path = scratch.recording("A1", 805);
    let parts: Vec<record::Recording> = record::recording_parts(&path)
        .iter()
        .map(|p| record::read_recording(p).unwrap())
        .collect();
    for (i, p) in parts.iter().enumerate() {
        assert!(p.indexed && p.run_info().is_some(), "part {}: {out}", i + 1);
    }
    assert_eq!(record::join_resumed(parts).len(), 1, "{out}");
    let resume = record::resume::resume_point(&path);
    assert!(resume.is_ok(), "{:?}\n{out}", resume.err());
    assert_nothing_left(&run);
}

/// A restarted recorder killed after it wrote its part's `/run` but before the part's first
/// update leaves a part that holds no update; the next restart's part names it as its
/// `previous_part`. `analyze` joins the three parts as one run; so must the Python reader's
/// `--join` (it compared `previous_part` with the last file that held updates, and refused the
/// seam: "does not go on where … ends").
#[test]
fn parts_joined_across_a_restarted_recorders_part_without_updates() {
    let scratch = Scratch::new("rec-part-without-updates");
    let text = config(&[
        ("updates = 40", "updates = 400"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 60.0",
        ),
    ]);
    let cfg = write_config(&scratch, "no-updates.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 5251, &cfg, &result);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let path = scratch.recording("A1", 5251);
    let part2 = record::part_path(&path, 2);
    sigkill_recorder(&status);
    let second = restarted_recorder(&run, 1, Instant::now() + Duration::from_secs(10));
    // Killed once its part has its `/run` and before its first update is in.
    let end = Instant::now() + Duration::from_secs(20);
    while !record::read_recording(&part2).is_ok_and(|r| r.run_info().is_some()) {
        assert!(Instant::now() < end, "no /run in part 2:\n{}", run.text());
        std::thread::sleep(Duration::from_millis(2));
    }
    signal(second, "-9");
    let part3 = record::part_path(&path, 3);
    run.wait_status("2 updates in part 3", |_| {
        record::read_recording(&part3).is_ok_and(|r| r.updates.len() >= 2)
    });
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    let parts = [&path, &part2, &part3].map(|p| record::read_recording(p).unwrap());
    assert!(
        parts[1].updates.is_empty(),
        "part 2 holds updates: {}",
        run.text()
    );
    assert_eq!(
        record::join_resumed(parts.to_vec()).len(),
        1,
        "{}",
        run.text()
    );
    let text = python_join_check(&[&path, &part2, &part3]);
    assert!(text.contains("join passed"), "{text}");
    assert_nothing_left(&run);
}

/// The pid of the recorder the supervisor of `run` started as restart `restart`, as soon as it
/// exists (polled in /proc); fails at `end`.
fn restarted_recorder(run: &Run, restart: u32, end: Instant) -> u32 {
    let restart = format!("--restart\0{restart}\0");
    loop {
        for e in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            let cmdline = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
            let cmdline = String::from_utf8_lossy(&cmdline);
            if cmdline.contains(&run.run_id) && cmdline.contains(&restart) {
                return pid;
            }
        }
        assert!(
            Instant::now() < end,
            "no restarted recorder:\n{}",
            run.text()
        );
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// Kills the recorder named in a `supervisor status` output with SIGKILL; returns its pid.
fn sigkill_recorder(status: &str) -> u32 {
    let pid = pid_of(status, "recorder");
    signal(pid, "-9");
    pid
}

/// `config/<file>` with its worker program `relative` (as the file names it) replaced by the
/// absolute `worker` (the test's config lives elsewhere), and `edits` applied (checked to apply).
fn external_config_from(
    file: &str,
    relative: &str,
    worker: &Path,
    edits: &[(&str, &str)],
) -> String {
    let worker = std::path::absolute(worker).unwrap();
    let worker = worker.to_str().unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../config")
        .join(file);
    let mut text = std::fs::read_to_string(path).unwrap();
    let quoted = format!("{relative:?}");
    assert!(text.contains(&quoted), "{quoted} not in {file}");
    text = text.replacen(&quoted, &format!("{worker:?}"), 1);
    for (from, to) in edits {
        assert!(text.contains(from), "`{from}` not in {file}");
        text = text.replacen(from, to, 1);
    }
    text
}

/// `config/external-reach.toml`, its worker `examples/reach-worker.rs` built with the tests.
fn external_config(edits: &[(&str, &str)]) -> String {
    let worker = Path::new(SUPERVISOR)
        .parent()
        .unwrap()
        .join("examples/reach-worker");
    assert!(worker.is_file(), "{} not built", worker.display());
    external_config_from(
        "external-reach.toml",
        "../target/release/examples/reach-worker",
        &worker,
        edits,
    )
}

/// Edits of an external-reach config that declare P = 12 for a worker whose task has 10, and
/// stop the run at the first worker that fails.
const DECLARE_12_PARAMETERS: [(&str, &str); 3] = [
    ("parameters = 10", "parameters = 12"),
    ("initial_mean = [", "initial_mean = [0.0, 0.0, "),
    ("workers = 2", "workers = 2\nrestart_limit = 0"),
];

/// Runs config `text` (written as `file`), which must fail (exit 1) with output containing every
/// one of `expected`, and leave nothing behind.
fn assert_run_fails_saying(scratch: &Scratch, id: u64, file: &str, text: &str, expected: &[&str]) {
    assert_run_fails_saying_not(scratch, id, file, text, expected, &[]);
}

fn assert_run_fails_saying_not(
    scratch: &Scratch,
    id: u64,
    file: &str,
    text: &str,
    expected: &[&str],
    unexpected: &[&str],
) {
    let cfg = write_config(scratch, file, text);
    let mut run = Run::start(scratch, id, &[cfg.to_str().unwrap(), "--quiet"]);
    run.wait_exit(Duration::from_secs(60), 1);
    let out = run.text();
    for e in expected {
        assert!(out.contains(e), "`{e}` not in:\n{out}");
    }
    for e in unexpected {
        assert!(!out.contains(e), "`{e}` in:\n{out}");
    }
    assert_nothing_left(&run);
}

#[test]
fn a_task_of_your_own_learns_in_its_own_workers_and_is_recorded() {
    let scratch = Scratch::exclusive("external");
    let text = external_config(&[]);
    let cfg = write_config(&scratch, "reach.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1510, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 80);
    // Learned (the first reach misses the target by 12 cm), and re-learned after the target
    // moved at update 40.
    assert!(r.first_eval_cost > 100.0, "{}", r.first_eval_cost);
    assert!(r.last_eval_cost < 5.0, "{}", r.last_eval_cost);
    assert_eq!(r.task_changes.len(), 1);
    assert_eq!(
        (
            r.task_changes[0].name.as_str(),
            r.task_changes[0].from_update
        ),
        ("target_y", 40)
    );
    let rec = record::read_recording(&scratch.recording("reach", 1510)).unwrap();
    assert_recorded(&rec, 80);
    for name in ["worker-0", "worker-1"] {
        assert!(
            logged(&rec, "start", name) || logged(&rec, "scale", name),
            "{name}: {:#?}",
            rec.logs
        );
    }
    // The built-in rollout-worker cannot run an external task (session::build_task refuses
    // it), so these rollouts ran in the example's program.
    assert_eq!(rec.rollouts.len(), 80 * 10);
    assert_nothing_left(&run);

    // The same task and config without the pipeline (`reach-worker --in-process`, through
    // session::InProcess::with_task): the same final distribution, bit for bit.
    let worker = Path::new(SUPERVISOR)
        .parent()
        .unwrap()
        .join("examples/reach-worker");
    let out = std::process::Command::new(worker)
        .arg("--in-process")
        .arg(&cfg)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        text.lines().collect::<Vec<_>>(),
        [
            format!("mean_bits = {:?}", r.mean_bits),
            format!("covariance_bits = {:?}", r.covariance_bits)
        ]
    );
}

/// A worker of your own that runs but never announces itself on `lifecycle` (the step the
/// README's and the wire crate's instructions for a worker in another language left out): the
/// startup timeout says what being ready takes.
#[test]
fn a_worker_of_your_own_that_never_announces_itself_is_told_what_ready_takes() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("silent-worker");
    let script = scratch.path("silent.sh");
    std::fs::write(&script, "#!/bin/sh\nexec sleep 30\n").unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let text = external_config_from(
        "external-reach.toml",
        "../target/release/examples/reach-worker",
        &script,
        &[("workers = 2", "workers = 1\nstartup_timeout_ms = 2000")],
    );
    assert_run_fails_saying(
        &scratch,
        1000,
        "silent.toml",
        &text,
        &[
            "worker-0 did not become ready within 2000 ms (pipeline.startup_timeout_ms); a \
             worker of your own is ready once it has built its task",
            "announced itself on `lifecycle` (role 3, its slot and incarnation)",
        ],
    );
}

/// Runs config `text` (written as `<id>.toml`) to its end, which must be a success: the run,
/// its output and its result file.
fn run_to_its_end(scratch: &Scratch, id: u64, text: &str) -> (Run, String, RunResult) {
    let cfg = write_config(scratch, &format!("{id}.toml"), text);
    let result = scratch.path(&format!("{id}.result.toml"));
    let mut run = Run::start(
        scratch,
        id,
        &[cfg.to_str().unwrap(), "--result", result.to_str().unwrap()],
    );
    run.wait_exit(Duration::from_secs(120), 0);
    let out = run.text();
    (run, out, RunResult::read(&result).unwrap())
}

/// A change the workers' task refuses (a target out of the arm's reach) is not taken: the update
/// runs with the value in force, the run goes on, and ends as the same run without the change,
/// bit for bit. The result file and the recording say what was refused. A value the task
/// refuses before any rollout (the config's own) still stops the run, since there is nothing to
/// fall back to. Both for the Rust example worker and for the Python one.
#[test]
fn a_change_the_workers_refuse_is_not_taken_and_the_run_goes_on() {
    let scratch = Scratch::exclusive("refused");
    let out_of_reach = ("value = 0.78", "value = 5.0");
    let no_schedule = (
        "[[schedule]]\nfrom_update = 40\nset = \"target_y\"\nvalue = 0.78\n",
        "",
    );
    type ConfigOf = fn(&[(&str, &str)]) -> String;
    let cases: [(&str, ConfigOf, u64); 2] = [
        ("reach", external_config, 850),
        ("reach-python", python_config, 853),
    ];
    for (name, config, id) in cases {
        let (run, out, r) = run_to_its_end(&scratch, id, &config(&[out_of_reach]));
        for expected in [
            "update 40: the task",
            "out of the arm's reach (0.9 m)",
            "task change target_y = 5 at update 40 refused by the workers' task",
            "update 40 ran with target_y = 0.7, which stays in force",
        ] {
            assert!(
                out.contains(expected),
                "{name}: `{expected}` not in:\n{out}"
            );
        }
        assert_eq!((r.updates, r.complete), (80, true), "{name}");
        assert!(r.task_changes.is_empty(), "{name}: {:?}", r.task_changes);
        assert_eq!(r.refused_changes.len(), 1, "{name}");
        let c = &r.refused_changes[0];
        assert_eq!(
            (c.from_update, c.name.as_str(), c.value, c.source.as_str()),
            (40, "target_y", 5.0, "schedule"),
            "{name}"
        );
        let rec = record::read_recording(&scratch.recording(name, id)).unwrap();
        assert_recorded(&rec, 80);
        assert!(
            rec.task_changes.is_empty(),
            "{name}: {:?}",
            rec.task_changes
        );
        for u in &rec.updates {
            let y = u
                .task_settings
                .iter()
                .find(|s| s.name == "target_y")
                .unwrap();
            assert_eq!(y.value, 0.7, "{name}: update {}", u.update);
        }
        assert!(
            rec.logs.iter().any(|l| l.event == "warning"
                && l.update == 40
                && l.message.contains("target_y = 5 refused")),
            "{name}: {:#?}",
            rec.logs
        );
        assert_nothing_left(&run);

        // The same run without the change: the same bits.
        let cfg = write_config(
            &scratch,
            &format!("{id}-none.toml"),
            &config(&[no_schedule]),
        );
        let plain = scratch.path(&format!("{id}-none.result.toml"));
        let mut run = Run::start_quiet(&scratch, id + 1, &cfg, &plain);
        run.wait_exit(Duration::from_secs(120), 0);
        let p = RunResult::read(&plain).unwrap();
        assert_eq!(
            (&r.mean_bits, &r.covariance_bits),
            (&p.mean_bits, &p.covariance_bits),
            "{name}"
        );
        assert_nothing_left(&run);

        // Refused before the first rollout: the config's own target. Refused as the config is
        // (every restart would meet the same), not restarted as a crash.
        let stop_at_first = ("workers = 2", "workers = 2\nrestart_limit = 0");
        assert_run_fails_saying(
            &scratch,
            id + 2,
            &format!("{id}-far.toml"),
            &config(&[("target_y = 0.70", "target_y = 7.0"), stop_at_first]),
            &[
                "update 0: the task",
                "the config's value, which the run starts from",
                "nothing to fall back to",
                "out of the arm's reach",
                "refused the config, not restarted (exit status: 78",
            ],
        );
    }

    // At runtime: `supervisor set` is answered when the updater takes the change; the workers
    // refuse it, status then shows the target in force, and the next change is taken.
    let text = external_config(&[
        no_schedule,
        ("updates = 80\n", ""),
        (
            "/reach-worker\"]",
            "/reach-worker\", \"--rollout-ms\", \"1\"]",
        ),
    ]);
    let cfg = write_config(&scratch, "runtime.toml", &text);
    let result = scratch.path("runtime.result.toml");
    let mut run = Run::start_quiet(&scratch, 856, &cfg, &result);
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let reply = run.ctl_ok(&["set", "target_x", "3.0"]);
    assert!(
        reply.contains("the workers' task may still refuse it (`supervisor status` then says so)"),
        "{reply}"
    );
    let from = takes_effect_from(&reply);
    let status = run.wait_status("the refused update done", |s| updates_in(s) > from + 1);
    assert!(
        status.contains("task: target_x = 0.3, target_y = 0.7")
            && status.contains(&format!(
                "refused by the workers' task: 1 change (the last: target_x = 3 at update {from})"
            )),
        "{status}"
    );
    run.ctl_ok(&["set", "target_x", "0.35"]);
    run.wait_status("the next change in force", |s| {
        s.contains("target_x = 0.35")
    });
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let r = RunResult::read(&result).unwrap();
    let changes = |list: &[pipeline::result::RecordedChange]| -> Vec<(String, f64, String)> {
        list.iter()
            .map(|c| (c.name.clone(), c.value, c.source.clone()))
            .collect()
    };
    let runtime = |v: f64| ("target_x".to_string(), v, "runtime".to_string());
    assert_eq!(changes(&r.refused_changes), [runtime(3.0)]);
    assert_eq!(r.refused_changes[0].from_update, from);
    assert_eq!(changes(&r.task_changes), [runtime(0.35)]);
    assert_nothing_left(&run);
}

/// Two changes at one update are taken together: target (0.8, 0.7) is out of the arm's reach,
/// (0.8, 0.1) is not, so x = 0.8, refused with y as it was, is taken once y = 0.1 is in (before,
/// x was refused for good: not what was asked). With (0.8, 0.65), out of reach, x is refused and
/// stays refused for every rollout of its update (before, the workers tried it again for their
/// next rollout and took it once y was in, the update's rollouts ran with different targets, and
/// the updater stopped the run).
#[test]
fn an_updates_changes_are_taken_together_and_one_refused_stays_refused_for_every_rollout() {
    let scratch = Scratch::new("refused-pair");
    let schedule = |y: f64| {
        (
            "[[schedule]]\nfrom_update = 40\nset = \"target_y\"\nvalue = 0.78\n".to_string(),
            format!(
                "[[schedule]]\nfrom_update = 5\nset = \"target_x\"\nvalue = 0.8\n\n\
                 [[schedule]]\nfrom_update = 5\nset = \"target_y\"\nvalue = {y}\n"
            ),
        )
    };
    type ConfigOf = fn(&[(&str, &str)]) -> String;
    let cases: [(&str, ConfigOf, u64); 2] = [
        ("reach", external_config, 862),
        ("reach-python", python_config, 868),
    ];
    let changes = |list: &[pipeline::result::RecordedChange]| -> Vec<(u64, String, f64)> {
        list.iter()
            .map(|c| (c.from_update, c.name.clone(), c.value))
            .collect()
    };
    for (name, config, id) in cases {
        for (y, taken, refused, ran) in [
            (0.1, vec!["target_x", "target_y"], vec![], [0.8, 0.1]),
            (0.65, vec!["target_y"], vec!["target_x"], [0.3, 0.65]),
        ] {
            let id = id + u64::from(y > 0.5);
            let (from, to) = schedule(y);
            let text = config(&[(&from, &to), ("updates = 80", "updates = 20")]);
            let (run, out, r) = run_to_its_end(&scratch, id, &text);
            let value = |s: &str| if s == "target_x" { 0.8 } else { y };
            let at_5 = |names: Vec<&str>| -> Vec<(u64, String, f64)> {
                names
                    .into_iter()
                    .map(|n| (5, n.to_string(), value(n)))
                    .collect()
            };
            assert_eq!(r.updates, 20, "{name}:\n{out}");
            assert_eq!(changes(&r.refused_changes), at_5(refused), "{name}:\n{out}");
            assert_eq!(changes(&r.task_changes), at_5(taken), "{name}:\n{out}");
            let rec = record::read_recording(&scratch.recording(name, id)).unwrap();
            for u in rec.updates.iter().filter(|u| u.update >= 5) {
                let s: Vec<f64> = u.task_settings.iter().map(|s| s.value).collect();
                assert_eq!(s, ran, "{name}: update {}", u.update);
            }
            assert_nothing_left(&run);
        }
    }
}

/// A resumed run's first update falls back, for a change the workers' task refuses, to what the
/// recording's last update ran with (before the start file carried it, its workers had nothing
/// to fall back to and the resumed run failed), and ends as the same resume without the change.
#[test]
fn a_change_refused_at_the_update_a_run_resumes_from_falls_back_to_the_recorded_settings() {
    let scratch = Scratch::new("refused-resume");
    let first = external_config(&[
        ("updates = 80", "updates = 10"),
        (
            "[[schedule]]\nfrom_update = 40\nset = \"target_y\"\nvalue = 0.78\n",
            "",
        ),
    ]);
    let cfg = write_config(&scratch, "first.toml", &first);
    let recording = scratch.path("first.mcap");
    let mut run = Run::start(
        &scratch,
        864,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--record",
            recording.to_str().unwrap(),
        ],
    );
    run.wait_exit(Duration::from_secs(60), 0);
    let resume = |id: u64, schedule: &str| {
        let text = first.clone() + schedule;
        let cfg = write_config(&scratch, &format!("{id}.toml"), &text);
        let result = scratch.path(&format!("{id}.result.toml"));
        let mut run = Run::start(
            &scratch,
            id,
            &[
                cfg.to_str().unwrap(),
                "--resume",
                recording.to_str().unwrap(),
                "--updates",
                "20",
                "--no-record",
                "--result",
                result.to_str().unwrap(),
            ],
        );
        run.wait_exit(Duration::from_secs(60), 0);
        (run.text(), RunResult::read(&result).unwrap())
    };
    let (out, refused) = resume(
        865,
        "\n[[schedule]]\nfrom_update = 10\nset = \"target_y\"\nvalue = 5.0\n",
    );
    assert!(
        out.contains("update 10: the task refused target_y = 5"),
        "{out}"
    );
    assert_eq!(refused.updates, 20);
    let c = &refused.refused_changes;
    assert_eq!(c.len(), 1, "{c:?}");
    assert_eq!((c[0].from_update, c[0].value), (10, 5.0));
    // The settings in force where it resumed stay recorded as such.
    assert!(refused.task_changes.iter().all(|c| c.source == "resume"));
    let (_, plain) = resume(866, "");
    assert_eq!(
        (&refused.mean_bits, &refused.covariance_bits),
        (&plain.mean_bits, &plain.covariance_bits)
    );
}

/// A worker restarted in the middle of the update whose change its task refuses starts with the
/// config's values, not those the update before ran with: it falls back to the work item's
/// `previous_settings`, as the worker it replaces did, so the update's rollouts all ran with the
/// same settings and the run ends as the same run without the change. (Before the work items
/// carried them, it had nothing to fall back to and stopped at every restart.)
#[test]
fn a_worker_restarted_in_the_update_of_a_refused_change_falls_back_as_the_others_did() {
    let scratch = Scratch::exclusive("refused-restart");
    // One worker, 50 ms rollouts: update 3, with the refused target, takes 0.5 s.
    let edits = |schedule: (&'static str, &'static str)| {
        external_config(&[
            ("updates = 80", "updates = 6"),
            ("workers = 2", "workers = 1"),
            (
                "/reach-worker\"]",
                "/reach-worker\", \"--rollout-ms\", \"50\"]",
            ),
            schedule,
        ])
    };
    let refused = edits((
        "from_update = 40\nset = \"target_y\"\nvalue = 0.78",
        "from_update = 3\nset = \"target_y\"\nvalue = 5.0",
    ));
    let cfg = write_config(&scratch, "refused.toml", &refused);
    let result = scratch.path("refused.result.toml");
    let mut run = Run::start(
        &scratch,
        860,
        &[
            cfg.to_str().unwrap(),
            "--no-record",
            "--result",
            result.to_str().unwrap(),
        ],
    );
    let status = run.wait_status("update 3 under way", |s| updates_in(s) >= 3);
    assert_eq!(updates_in(&status), 3, "{status}");
    signal(pid_of(&status, "worker-0"), "-9");
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    // Both incarnations met the refused value, and ran update 3 with the one before.
    let refusal = "[worker-0] update 3: the task refused target_y = 5";
    assert_eq!(out.matches(refusal).count(), 2, "{out}");
    assert!(out.contains("as the update before"), "{out}");
    let r = RunResult::read(&result).unwrap();
    assert_eq!(
        (r.updates, r.task_changes.len(), r.refused_changes.len()),
        (6, 0, 1)
    );

    let plain = edits((
        "[[schedule]]\nfrom_update = 40\nset = \"target_y\"\nvalue = 0.78\n",
        "",
    ));
    let cfg = write_config(&scratch, "plain.toml", &plain);
    let plain_result = scratch.path("plain.result.toml");
    let mut run = Run::start(
        &scratch,
        861,
        &[
            cfg.to_str().unwrap(),
            "--no-record",
            "--quiet",
            "--result",
            plain_result.to_str().unwrap(),
        ],
    );
    run.wait_exit(Duration::from_secs(60), 0);
    let p = RunResult::read(&plain_result).unwrap();
    assert_eq!(
        (&r.mean_bits, &r.covariance_bits),
        (&p.mean_bits, &p.covariance_bits)
    );
    assert_nothing_left(&run);
}

/// A run stopped in the middle of an update whose workers refused its change: the rollouts in
/// so far ran with the old value, so the change is refused (result file), not recorded as a
/// change ahead, and `--resume` goes on with the value in force (it went on with the refused
/// one, which the resumed run's new workers refused before any rollout: the run failed).
#[test]
fn a_change_refused_in_the_update_a_run_stops_in_is_not_resumed_with() {
    let scratch = Scratch::new("refused-stop");
    let text = external_config(&[
        (
            "[[schedule]]\nfrom_update = 40\nset = \"target_y\"\nvalue = 0.78\n",
            "",
        ),
        ("updates = 80\n", ""),
        (
            "/reach-worker\"]",
            "/reach-worker\", \"--rollout-ms\", \"300\"]",
        ),
    ]);
    let cfg = write_config(&scratch, "slow.toml", &text);
    let result = scratch.path("slow.result.toml");
    let id = 858;
    let mut run = Run::start(
        &scratch,
        id,
        &[cfg.to_str().unwrap(), "--result", result.to_str().unwrap()],
    );
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let from = takes_effect_from(&run.ctl_ok(&["set", "target_y", "5"]));
    run.wait_output(
        &format!("update {from}: the task refused target_y = 5"),
        Instant::now() + Duration::from_secs(30),
    );
    // Until one of the update's rollouts has reported (each takes 300 ms, the update 1.5 s): a
    // stop abandons the rollouts under way (`pipeline::worker::stop_requested()`), and a change
    // is known to be refused only from a cost that ran without it.
    std::thread::sleep(Duration::from_millis(700));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let out = run.text();
    let r = RunResult::read(&result).unwrap();
    assert_eq!(
        r.updates, from,
        "the update refused in was finished:\n{out}"
    );
    assert!(r.task_changes.is_empty(), "{:?}\n{out}", r.task_changes);
    let refused: Vec<_> = r
        .refused_changes
        .iter()
        .map(|c| (c.from_update, c.name.as_str(), c.value, c.source.as_str()))
        .collect();
    assert_eq!(refused, [(from, "target_y", 5.0, "runtime")], "{out}");
    assert!(
        out.contains(&format!(
            "task change target_y = 5 at update {from} refused by the workers' task"
        )),
        "{out}"
    );
    let recording = scratch.recording("reach", id);
    let rec = record::read_recording(&recording).unwrap();
    assert!(rec.task_changes.is_empty(), "{:?}", rec.task_changes);
    assert!(
        rec.logs.iter().any(|l| l.event == "warning"
            && l.update == from
            && l.message.contains("target_y = 5 refused")),
        "{:#?}",
        rec.logs
    );
    let point = record::resume::resume_point(&recording).unwrap();
    assert_eq!(
        point.start.settings,
        [("target_x".to_string(), 0.3), ("target_y".to_string(), 0.7)]
    );
    assert_nothing_left(&run);
}

/// `reach-worker --basis-activations`: the `[task.external] basis_activations` line of its task.
fn reach_basis_activations() -> String {
    let worker = Path::new(SUPERVISOR)
        .parent()
        .unwrap()
        .join("examples/reach-worker");
    let out = std::process::Command::new(worker)
        .arg("--basis-activations")
        .output()
        .unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn a_task_of_your_own_learns_with_per_time_step_weighting_by_its_basis_activations() {
    let scratch = Scratch::new("external-psi");
    let psi = reach_basis_activations();
    let per_time_step = (
        "weighting = \"episodic\"",
        "weighting = \"per-time-step\"\ntemporal_averaging = \"basis-activation\"",
    );
    let declared = format!("{psi}\n[task.external.settings]");
    let text = external_config(&[per_time_step, ("[task.external.settings]", &declared)]);
    let cfg = write_config(&scratch, "reach-psi.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 840, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 80);
    assert!(r.last_eval_cost < r.first_eval_cost / 4.0, "{r:?}");
    // The activations are recorded, and every update recomputes with them bit for bit.
    let rec = record::read_recording(&scratch.recording("reach", 840)).unwrap();
    let recorded = &rec.run_info().unwrap().basis_activations;
    let cfg = RunConfig::parse(&text, Path::new("reach-psi.toml")).unwrap();
    assert_eq!(
        Some(recorded.clone()),
        cfg.external_basis_activations().unwrap()
    );
    assert_eq!(recorded.len(), 101 * 10);
    assert_recorded(&rec, 80);
    assert_nothing_left(&run);

    // Activations that are not the worker's own: it refuses to run for them.
    let first = psi.lines().nth(1).unwrap();
    let other = first.replacen("[0.", "[0.5", 1);
    assert_ne!(first, other);
    let declared = format!(
        "{}\n[task.external.settings]",
        psi.replacen(first, &other, 1)
    );
    let text = external_config(&[
        per_time_step,
        ("[task.external.settings]", &declared),
        ("workers = 2", "workers = 2\nrestart_limit = 0"),
    ]);
    assert_run_fails_saying(
        &scratch,
        841,
        "other-psi.toml",
        &text,
        &["task `reach` has other basis activations than task.external.basis_activations"],
    );
}

#[test]
fn a_worker_whose_task_does_not_match_the_config_or_is_missing_is_named() {
    let scratch = Scratch::new("external-bad");
    // A mismatch is the config's fault: the worker is not restarted, and the reason names the
    // user's file, not the copy in the run directory.
    let p12 = scratch.path("p12.toml").display().to_string();
    assert_run_fails_saying_not(
        &scratch,
        810,
        "p12.toml",
        &external_config(&DECLARE_12_PARAMETERS),
        &[
            "refused the config, not restarted",
            &format!("task `reach` has 10 parameters, but task.external.parameters = 12 in {p12}"),
        ],
        &["restart 1 of"],
    );
    // A worker program that does not exist: refused before anything starts.
    let text = config_edit::edited(
        &external_config(&[]),
        &[("worker = [\"/", "worker = [\"/nonexistent/")],
    );
    assert_run_fails_saying(
        &scratch,
        811,
        "missing.toml",
        &text,
        &[
            &format!(
                "{}: task.external.worker = \"/nonexistent/",
                scratch.path("missing.toml").display()
            ),
            "not an executable file",
        ],
    );
}

#[test]
fn external_workers_are_restarted_and_scaled_like_built_in_ones_and_the_result_stays_the_same() {
    let scratch = Scratch::new("external-heal");
    let base = [
        ("updates = 80", "updates = 120"),
        ("workers = 2", "workers = 2\nmax_workers = 4"),
    ];
    // 1 ms rollouts: a real-time simulator; the run lasts long enough to act on it.
    let slow = external_config(&[
        base[0],
        base[1],
        (
            "/reach-worker\"]",
            "/reach-worker\", \"--rollout-ms\", \"1\"]",
        ),
    ]);
    let cfg = write_config(&scratch, "slow.toml", &slow);
    let result = scratch.path("slow.toml.result");
    let mut run = Run::start_quiet(&scratch, 820, &cfg, &result);
    let status = run.wait_status("10 updates", |s| updates_in(s) >= 10);
    let victim = pid_of(&status, "worker-1");
    let cmdline = std::fs::read(format!("/proc/{victim}/cmdline")).unwrap();
    assert!(
        String::from_utf8_lossy(&cmdline).contains("reach-worker"),
        "{}",
        String::from_utf8_lossy(&cmdline)
    );
    signal(victim, "-9");
    run.wait_status("restarted worker-1", |s| {
        s.contains("restarts 1") && s.contains("incarnation 1")
    });
    run.ctl_ok(&["scale", "--workers", "3"]);
    run.wait_status("3 workers", |s| {
        s.contains("workers: 3 running") && !s.contains("(starting)")
    });
    run.wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(&scratch.recording("reach", 820)).unwrap();
    assert!(logged(&rec, "restart", "worker-1"), "{:#?}", rec.logs);
    assert!(logged(&rec, "scale", "worker-2"), "{:#?}", rec.logs);
    assert_recorded(&rec, 120);
    assert_nothing_left(&run);

    // The same run without delay, loss or scaling ends with the same distribution, bit for bit:
    // the noise of a rollout is a function of (seed, update, rollout), not of who ran it.
    let fast = external_config(&base);
    let cfg = write_config(&scratch, "fast.toml", &fast);
    let reference = scratch.path("fast.toml.result");
    let mut run = Run::start_quiet(&scratch, 821, &cfg, &reference);
    run.wait_exit(Duration::from_secs(60), 0);
    let (a, b) = (
        RunResult::read(&result).unwrap(),
        RunResult::read(&reference).unwrap(),
    );
    assert_eq!(a.updates, 120);
    assert_eq!(a.mean_bits, b.mean_bits);
    assert_eq!(a.covariance_bits, b.covariance_bits);
    assert_nothing_left(&run);
}

/// `config/external-reach-python.toml`, its worker `tools/reach_worker.py`.
fn python_config(edits: &[(&str, &str)]) -> String {
    let worker = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/reach_worker.py");
    external_config_from(
        "external-reach-python.toml",
        "../tools/reach_worker.py",
        &worker,
        edits,
    )
}

/// A Python worker started by hand (or behind a wrapper script without `exec`) ends when its
/// run's supervisor is SIGKILLed, as rollout-worker does: it saw the supervisor, and the
/// supervisor is gone. Before, it waited until a later `supervisor run` swept the run directory
/// away, which may never come.
#[test]
fn a_python_worker_started_by_hand_ends_when_the_supervisor_is_killed() {
    let scratch = Scratch::new("python-orphan");
    let text = python_config(&[("updates = 80\n", "")]);
    let cfg = write_config(&scratch, "orphan.toml", &text);
    let mut run = Run::start(
        &scratch,
        26600,
        &[cfg.to_str().unwrap(), "--quiet", "--no-record"],
    );
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let run_dir = run.runs.join(&run.run_id);
    let worker = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/reach_worker.py");
    let log = scratch.path("joined.log");
    let mut joined = KillOnDrop(
        Command::new(worker)
            .arg("--config")
            .arg(run_dir.join("config.toml"))
            .arg("--run-dir")
            .arg(&run_dir)
            .args(["--run-id", &run.run_id, "--worker", "5"])
            .stdout(std::fs::File::create(&log).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let said = format!("worker-5 (pid {}) joined the run", joined.0.id());
    run.wait_output(&said, Instant::now() + Duration::from_secs(30));
    let pids = pids_in(&run.ctl_ok(&["status"]));
    sigkill_supervisor(&mut run, &pids);
    assert!(run_dir.exists(), "a killed supervisor removes nothing");
    let end = Instant::now() + Duration::from_secs(10);
    let status = loop {
        if let Some(status) = joined.0.try_wait().unwrap() {
            break status;
        }
        assert!(
            Instant::now() < end,
            "the joined Python worker outlived its supervisor"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status}");
    let said = std::fs::read_to_string(&log).unwrap();
    assert!(said.contains("its supervisor was killed"), "{said}");
    let next = next_short_run(&scratch, 26601);
    assert_nothing_left(&run);
    assert_nothing_left(&next);
}

/// `tools/pi2cma_worker.py` checks a task's basis activations (an attribute) against the
/// config's, as `serve` does in Rust.
#[test]
fn a_python_worker_checks_its_basis_activations_against_the_config() {
    let scratch = Scratch::new("python-psi");
    let cfg = write_config(
        &scratch,
        "psi.toml",
        &python_config(&[(
            "[task.external.settings]",
            &format!("{}\n[task.external.settings]", reach_basis_activations()),
        )]),
    );
    let tools = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools");
    // The config's activations pass; with one value changed, the check names the field and
    // the value.
    let script = r#"
import sys, pi2cma_worker as w
shape = w.Shape(sys.argv[1])
class Task:
    parameters, steps, settings = shape.parameters, shape.steps, {"target_x": 0.3, "target_y": 0.7}
    basis_activations = [list(r) for r in shape.basis_activations]
w._check_shape(Task, shape)
Task.basis_activations[3][1] = 0.75
try:
    w._check_shape(Task, shape)
except w.ConfigRefused as e:  # exits 78: the supervisor does not restart it
    print(e)
"#;
    let args = ["-c".as_ref(), script.as_ref(), cfg.as_os_str()];
    let text = python_ok(&args, &[("PYTHONPATH", tools.as_os_str())]);
    assert!(
        text.contains("other basis activations than task.external.basis_activations in"),
        "{text}"
    );
    // And where: the step and parameter, the task's value and the config's.
    assert!(
        text.contains("(at step 3, parameter 1: the task's 0.75, the config's "),
        "{text}"
    );
}

/// `tools/pi2cma_worker.py`'s `_RunEnd`, as `pipeline::RunEnd`: a supervisor that ends in
/// order removes its node, then the run directory a moment later; a worker started by hand
/// that looked in between was told its supervisor "was killed" of a run that had ended as
/// asked. Only a supervisor missing at two looks, the run directory still there, was killed.
#[test]
fn a_python_worker_does_not_take_a_supervisor_that_ended_in_order_for_a_killed_one() {
    let scratch = Scratch::new("python-run-end");
    let tools = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools");
    let run_dir = scratch.path("run");
    let script = r#"
import gc, os, sys, pi2cma_worker as w
iox2, run_id, run_dir = w.iox2, int(sys.argv[1], 16), sys.argv[2]
def supervisor():
    config = iox2.config.default()
    config.global_cfg.prefix = iox2.FileName.new(f"p2c{run_id:016x}_")
    config.global_cfg.root_path = iox2.Path.new(f"/tmp/p2c-{run_id:016x}/")
    node = (iox2.NodeBuilder.new().name(iox2.NodeName.new("supervisor")).config(config)
            .create(iox2.ServiceType.Ipc))
    return node, config
def look(end):
    end.next_look = None
    return end.ended()
for ends_in_order in [True, False]:
    os.mkdir(run_dir)
    node, config = supervisor()
    end = w._RunEnd(run_dir, config)
    assert look(end) is None
    del node
    gc.collect()
    assert look(end) is None, "missed once"
    if ends_in_order:
        os.rmdir(run_dir)
        print(look(end))
    else:
        print(look(end))
        os.rmdir(run_dir)
"#;
    let id = run_id(26962);
    let args = [
        "-c".as_ref(),
        script.as_ref(),
        id.as_ref(),
        run_dir.as_os_str(),
    ];
    let text = python_ok(&args, &[("PYTHONPATH", tools.as_os_str())]);
    let _ = std::fs::remove_dir_all(format!("/tmp/p2c-{id}"));
    assert_eq!(
        text,
        format!(
            "its run directory {} is gone\nits supervisor was killed; the next `supervisor \
             run` removes what it left\n",
            run_dir.display()
        )
    );
}

/// The Python reader's `--join --check` of `files`, which must succeed; returns its output.
/// Needs tools/requirements.txt.
fn python_join_check(files: &[&Path]) -> String {
    let tool = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/plot_learning_curve.py");
    let mut args = vec![tool.as_os_str(), "--join".as_ref(), "--check".as_ref()];
    args.extend(files.iter().map(|p| p.as_os_str()));
    python_ok(&args, &[])
}

/// `python3 ARGS` with `env`, which must succeed; returns its stdout and stderr.
fn python_ok(args: &[&std::ffi::OsStr], env: &[(&str, &std::ffi::OsStr)]) -> String {
    let out = std::process::Command::new("python3")
        .args(args)
        .envs(env.iter().copied())
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    text
}

/// Needs `python3 -m pip install -r tools/requirements.txt` (the README's test command does it).
#[test]
fn a_python_worker_speaks_the_wire_protocol_and_learns_its_task() {
    let scratch = Scratch::new("python");
    let text = python_config(&[]);
    let cfg = write_config(&scratch, "reach.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 830, &cfg, &result);
    let exit = run.wait(Duration::from_secs(120));
    assert!(
        exit.success(),
        "is tools/requirements.txt installed (iceoryx2 for Python)?\n{}",
        run.text()
    );
    // No worker reported an error on the way out.
    assert!(!run.text().contains("error"), "{}", run.text());
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 80);
    assert!(r.first_eval_cost > 100.0, "{}", r.first_eval_cost);
    assert!(r.last_eval_cost < 5.0, "{}", r.last_eval_cost);
    assert_eq!(r.task_changes.len(), 1);
    let rec = record::read_recording(&scratch.recording("reach-python", 830)).unwrap();
    assert_recorded(&rec, 80);
    assert_nothing_left(&run);

    // Its own shape check, named as the Rust worker's is.
    assert_run_fails_saying(
        &scratch,
        831,
        "p12.toml",
        &python_config(&DECLARE_12_PARAMETERS),
        &["the task has parameters 10, but task.external.parameters = 12"],
    );
}

/// A Python task that fails in its own code: the run fails naming the update, the rollout and
/// what was wrong (a None among the step costs failed with only `TypeError: must be real number,
/// not NoneType`; an exception with its type and message but neither where nor its traceback;
/// a refused setting without the update),
/// and the recording keeps every update before it.
#[test]
fn a_python_task_that_fails_is_named_with_its_update_rollout_and_value() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("python-fails");
    let tools = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools");
    let tools = std::path::absolute(tools).unwrap();
    for (id, mode, expected) in [
        (
            832,
            "none",
            [
                "update 3, rollout 0: the task's rollout returned step cost 7 = None, not a number",
                "",
            ],
        ),
        (
            833,
            "raise",
            [
                "update 3, rollout 0: the task's rollout raised RuntimeError: simulator exploded",
                "in rollout\n",
            ],
        ),
        // The config's own target: refused before any rollout, nothing to fall back to.
        (
            834,
            "set",
            [
                "update 0: the task's set('target_y', 0.7) raised ValueError: out of reach",
                "(the config's value, which the run starts from): nothing to fall back to",
            ],
        ),
    ] {
        let script = scratch.path(&format!("{mode}.py"));
        std::fs::write(
            &script,
            format!(
                r#"#!/usr/bin/env python3
import sys
sys.path.insert(0, {tools:?})
import pi2cma_worker, reach_worker
class Broken(reach_worker.Reach):
    def rollout(self, theta):
        self.n = getattr(self, "n", 0) + 1
        costs, terminal = super().rollout(theta)
        if self.n > 3 * 5 and {mode:?} != "set":  # from update 3 on (5 rollouts, one worker)
            if {mode:?} == "raise":
                raise RuntimeError("simulator exploded")
            costs[7] = None
        return costs, terminal
    def set(self, name, value):
        if {mode:?} == "set" and value == 0.7:
            raise ValueError("out of reach")
        super().set(name, value)
pi2cma_worker.serve(Broken)
"#
            ),
        )
        .unwrap();
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
        let text = external_config_from(
            "external-reach-python.toml",
            "../tools/reach_worker.py",
            &script,
            &[
                ("workers = 2", "workers = 1\nrestart_limit = 0"),
                ("rollouts = 10", "rollouts = 5"),
            ],
        );
        let expected: Vec<&str> = expected.into_iter().filter(|e| !e.is_empty()).collect();
        assert_run_fails_saying(&scratch, id, &format!("{mode}.toml"), &text, &expected);
        let rec = record::read_recording(&scratch.recording("reach-python", id)).unwrap();
        assert!(
            rec.indexed && rec.truncated.is_none(),
            "{:?}",
            rec.truncated
        );
        let made = if mode == "set" { 0 } else { 3 };
        assert_eq!(update_indices(&rec), (0..made).collect::<Vec<u64>>());
        assert_recomputes(&rec);
    }
}

/// The config of `tools/reach_worker.py`'s task as changed by `body` (Python: a class `Task`
/// derived from `reach_worker.Reach`), written as an executable script `<name>.py` and
/// edited by `edits`.
fn python_task_config(scratch: &Scratch, name: &str, body: &str, edits: &[(&str, &str)]) -> String {
    use std::os::unix::fs::PermissionsExt;
    let tools =
        std::path::absolute(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools")).unwrap();
    let script = scratch.path(&format!("{name}.py"));
    std::fs::write(
        &script,
        format!(
            "#!/usr/bin/env python3\nimport os, sys, time\nsys.path.insert(0, {tools:?})\n\
             import pi2cma_worker, reach_worker\n{body}\npi2cma_worker.serve(Task)\n"
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    external_config_from(
        "external-reach-python.toml",
        "../tools/reach_worker.py",
        &script,
        edits,
    )
}

/// A Python task whose start raises, with a startup timeout shorter than the restarts take: the
/// failure names how the workers' last attempt died (before, only `worker-0 (waiting to be
/// restarted), … did not become ready within 3000 ms`, the cause in earlier lines only).
#[test]
fn a_startup_timeout_names_how_the_restarted_workers_last_attempt_died() {
    let scratch = Scratch::new("python-init-raises");
    let body = "class Task(reach_worker.Reach):\n    def __init__(self, shape):\n        \
                raise RuntimeError('no simulator license')";
    let edits = [(
        "workers = 2",
        "workers = 2\nstartup_timeout_ms = 3000\nrestart_limit = 100",
    )];
    let cfg = write_config(
        &scratch,
        "raises.toml",
        &python_task_config(&scratch, "raises", body, &edits),
    );
    let mut run = Run::start(&scratch, 6500, &[cfg.to_str().unwrap(), "--quiet"]);
    run.wait_exit(Duration::from_secs(60), 1);
    let out = run.text();
    let failed = out
        .lines()
        .find(|l| l.contains("[supervisor] failed: "))
        .unwrap_or("");
    assert!(
        failed.contains("did not become ready within 3000 ms")
            && failed.contains(
                "its last attempt died: exit status: 1; its last output: error: \
                                raises.py failed: RuntimeError: no simulator license"
            ),
        "{out}"
    );
    assert_nothing_left(&run);
}

/// A Python task's rollout that returns another number of step costs than the config declares
/// is refused as a task of another shape is: exit 78, not restarted (before, each worker was
/// restarted up to the restart limit, every restart meeting the same). Its worker's output has
/// none of iceoryx2's own log lines (`No config file was loaded, …`).
#[test]
fn a_python_task_with_another_number_of_step_costs_is_not_restarted() {
    let scratch = Scratch::new("python-cost-len");
    let body = "class Task(reach_worker.Reach):\n    def rollout(self, theta):\n        \
                costs, terminal = super().rollout(theta)\n        return costs[:-1], terminal";
    let text = python_task_config(&scratch, "short", body, &[]);
    assert_run_fails_saying_not(
        &scratch,
        6501,
        "short.toml",
        &text,
        &[
            "refused the config, not restarted (exit status: 78",
            "the task's rollout returned 100 step costs, expected 101 (task.external.steps)",
        ],
        &["restart 1 of", "No config file was loaded"],
    );
}

/// A Python task that hangs while it is built (a simulator waiting for its license) is stopped
/// there at once by `supervisor stop`: its worker exits 0, not SIGKILLed after
/// `shutdown_timeout_ms` (before, the signal only ended a loop not yet begun).
#[test]
fn a_python_task_hanging_in_its_start_is_stopped_at_once() {
    let scratch = Scratch::new("python-init-hangs");
    let mark = scratch.path("building");
    let body = format!(
        "class Task(reach_worker.Reach):\n    def __init__(self, shape):\n        \
         open({mark:?}, 'w').close()\n        while True:\n            time.sleep(0.01)"
    );
    let edits = [(
        "workers = 2",
        "workers = 1\nstartup_timeout_ms = 60000\nshutdown_timeout_ms = 20000",
    )];
    let cfg = write_config(
        &scratch,
        "hangs.toml",
        &python_task_config(&scratch, "hangs", &body, &edits),
    );
    let mut run = Run::start(&scratch, 6502, &[cfg.to_str().unwrap(), "--no-record"]);
    let end = Instant::now() + Duration::from_secs(30);
    while !mark.exists() {
        assert!(
            Instant::now() < end,
            "the task was never built:\n{}",
            run.text()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let t0 = Instant::now();
    run.ctl_ok(&["stop"]);
    run.wait(Duration::from_secs(30));
    let out = run.text();
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "{:?}:\n{out}",
        t0.elapsed()
    );
    assert!(
        out.contains("stopped by a signal while the task was being built")
            && !out.contains("did not stop within"),
        "{out}"
    );
    assert_nothing_left(&run);
}

/// Files `<what>-<worker>-<pid>` the slow test worker leaves in `dir`: (worker, pid).
fn marks(dir: &Path, what: &str) -> Vec<(String, u32)> {
    let mut found: Vec<(String, u32)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let rest = name.strip_prefix(&format!("{what}-"))?;
            let (w, pid) = rest.split_once('-')?;
            Some((w.to_string(), pid.parse().ok()?))
        })
        .collect();
    found.sort();
    found
}

/// Waits (bounded) until a worker of the slow test worker is in its long rollout; returns
/// (worker, pid).
fn wait_rolling(run: &Run, dir: &Path) -> (String, u32) {
    let end = Instant::now() + Duration::from_secs(30);
    loop {
        if let Some(m) = marks(dir, "rolling").into_iter().next() {
            return m;
        }
        assert!(
            Instant::now() < end,
            "no worker began its slow rollout:\n{}",
            run.text()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A Python worker whose rollout takes a minute (a simulator's step loop, here sleeps of 10 ms)
/// is stopped in it at once by the supervisor's SIGTERM: its `finally` runs, the rollout is
/// abandoned (no cost of it reaches the updater) and it exits 0. Scaled down, it is gone at once
/// and another worker runs its rollouts: the run ends as the same run without the slow rollout,
/// bit for bit. Stopped (`supervisor stop`), the group ends well within
/// `shutdown_timeout_ms`, and the result and the recording hold only complete updates, those of
/// the run without the slow rollout.
#[test]
fn a_python_worker_stopped_in_a_long_rollout_abandons_it_and_exits_at_once() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("python-slow");
    let tools =
        std::path::absolute(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools")).unwrap();
    let (slow, dir) = (scratch.path("slow"), scratch.path("marks"));
    std::fs::create_dir_all(&dir).unwrap();
    // The workers `slow` names run a one-minute rollout from their 11th rollout on (update 2 or
    // so), and say when it begins and when its `finally` ran.
    let script = scratch.path("slow.py");
    std::fs::write(
        &script,
        format!(
            r#"#!/usr/bin/env python3
import os, sys, time
sys.path.insert(0, {tools:?})
import pi2cma_worker, reach_worker
WORKER = sys.argv[sys.argv.index("--worker") + 1]
class Slow(reach_worker.Reach):
    def rollout(self, theta):
        self.n = getattr(self, "n", 0) + 1
        costs, terminal = super().rollout(theta)
        slow = os.path.exists({slow:?}) and WORKER in open({slow:?}).read().split()
        if self.n > 10 and slow:
            mark = os.path.join({dir:?}, "%s-" + WORKER + "-" + str(os.getpid()))
            try:
                open(mark % "rolling", "w").close()
                end = time.monotonic() + 60
                while time.monotonic() < end:
                    time.sleep(0.01)
            finally:
                open(mark % "cleaned", "w").close()
        return costs, terminal
pi2cma_worker.serve(Slow)
"#
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let config = |edits: &[(&str, &str)]| {
        external_config_from(
            "external-reach-python.toml",
            "../tools/reach_worker.py",
            &script,
            edits,
        )
    };
    let bound = Duration::from_secs(5);

    // Scaled down in its slow rollout: worker-1 is gone at once, having cleaned up, and worker-0
    // runs the rollouts it held (the update could not finish without them).
    std::fs::write(&slow, "1").unwrap();
    let text = config(&[]);
    let cfg = write_config(&scratch, "scale.toml", &text);
    let result = scratch.path("scale.result.toml");
    let mut run = Run::start_quiet(&scratch, 835, &cfg, &result);
    let (w, pid) = wait_rolling(&run, &dir);
    assert_eq!(w, "1");
    assert_eq!(pid_of(&run.ctl_ok(&["status"]), "worker-1"), pid);
    // Well in it: the run waits for the rollouts worker-1 holds.
    std::thread::sleep(Duration::from_millis(300));
    let stalled = updates_in(&run.ctl_ok(&["status"]));
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(updates_in(&run.ctl_ok(&["status"])), stalled);
    let t0 = Instant::now();
    run.ctl_ok(&["scale", "--workers", "1"]);
    while supervisor::process_alive(pid) {
        assert!(
            t0.elapsed() < bound,
            "worker-1 (pid {pid}) still in its rollout {:?} after the scale-down:\n{}",
            t0.elapsed(),
            run.text()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(marks(&dir, "cleaned"), vec![(w, pid)]);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    assert!(
        out.contains("stopped by a signal during the rollout; abandoned, its cost not sent"),
        "{out}"
    );
    let r = RunResult::read(&result).unwrap();
    assert!(r.updates == 80 && stalled < 80, "{stalled}");
    let rec = record::read_recording(&scratch.recording("reach-python", 835)).unwrap();
    assert_recorded(&rec, 80);
    let scaled = rec.logs.iter().any(|l| {
        l.event == "scale"
            && l.name == "worker-1"
            && l.message
                .contains("stopped by a scale-down (exit status: 0)")
    });
    assert!(scaled, "{:#?}", rec.logs);
    // Nothing of the abandoned rollout reached the updater: the run without it gives the same
    // bits.
    std::fs::remove_file(&slow).unwrap();
    let (reference, _, plain) = run_to_its_end(&scratch, 836, &text);
    assert_eq!(r.mean_bits, plain.mean_bits);
    assert_eq!(r.covariance_bits, plain.covariance_bits);
    assert_nothing_left(&run);
    assert_nothing_left(&reference);

    // Stopped in the slow rollout: the group ends well within shutdown_timeout_ms, exit 0 as
    // for any stop, every slow rollout cleaned up, none killed.
    for f in std::fs::read_dir(&dir).unwrap().flatten() {
        std::fs::remove_file(f.path()).unwrap();
    }
    std::fs::write(&slow, "0 1").unwrap();
    let text = config(&[("workers = 2", "workers = 2\nshutdown_timeout_ms = 15000")]);
    let cfg = write_config(&scratch, "stop.toml", &text);
    let result = scratch.path("stop.result.toml");
    let mut run = Run::start_quiet(&scratch, 837, &cfg, &result);
    let first = wait_rolling(&run, &dir);
    std::thread::sleep(Duration::from_millis(300));
    let t0 = Instant::now();
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(t0.elapsed() < bound, "{:?}:\n{}", t0.elapsed(), run.text());
    let out = run.text();
    assert!(!out.contains("did not stop within"), "{out}");
    // Every slow rollout begun ran its `finally` (a worker may have begun one as the stop came).
    let (rolling, cleaned) = (marks(&dir, "rolling"), marks(&dir, "cleaned"));
    assert!(
        rolling.contains(&first) && rolling.iter().all(|m| cleaned.contains(m)),
        "{rolling:?} {cleaned:?}"
    );
    let r = RunResult::read(&result).unwrap();
    assert!(!r.complete && r.updates < 80, "{}", r.updates);
    let rec = record::read_recording(&scratch.recording("reach-python", 837)).unwrap();
    assert_recorded(&rec, r.updates);
    assert!(
        rec.rollouts.iter().all(|x| x.update < r.updates),
        "rollouts of the unfinished update {} recorded",
        r.updates
    );
    for (w, _) in rolling {
        let stopped = rec.logs.iter().any(|l| {
            l.event == "exit"
                && l.name == format!("worker-{w}")
                && l.message.contains("stopped with the run (exit status: 0)")
        });
        assert!(stopped, "worker-{w}: {:#?}", rec.logs);
    }
    // The updates made are those of the run without the slow rollout, bit for bit.
    std::fs::remove_file(&slow).unwrap();
    let updates = format!("updates = {}", r.updates);
    let (reference, _, plain) =
        run_to_its_end(&scratch, 838, &config(&[("updates = 80", &updates)]));
    assert_eq!(r.mean_bits, plain.mean_bits);
    assert_eq!(r.covariance_bits, plain.covariance_bits);
    assert_nothing_left(&run);
    assert_nothing_left(&reference);
}

/// A Rust worker whose task looks at `pipeline::worker::stop_requested()` in a long rollout
/// (the reach example's real-time wait, here a minute a rollout) leaves it at once when it is
/// scaled down or the run is stopped: the rollout is abandoned, its cost not sent, and the
/// worker exits 0. Before, SIGTERM was seen only after the rollout, so the supervisor waited
/// `shutdown_timeout_ms` (15 s here) and SIGKILLed the worker.
#[test]
fn a_rust_worker_that_checks_stop_requested_leaves_a_long_rollout_at_once() {
    let scratch = Scratch::new("rust-slow");
    let text = external_config(&[
        (
            "reach-worker\"]",
            "reach-worker\", \"--rollout-ms\", \"60000\"]",
        ),
        ("workers = 2", "workers = 2\nshutdown_timeout_ms = 15000"),
    ]);
    let cfg = write_config(&scratch, "slow.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1301, &cfg, &result);
    let s = run.wait_status("2 workers", |s| s.contains("worker-1 pid"));
    let (first, second) = (pid_of(&s, "worker-0"), pid_of(&s, "worker-1"));
    // Both are in their first rollout (the first update needs a minute). A fixed wait of a
    // second was not always enough on a loaded machine: a worker not yet in a rollout leaves
    // without one to abandon.
    let end = Instant::now() + Duration::from_secs(60);
    for w in ["worker-0", "worker-1"] {
        run.wait_output(&format!("[{w}] a rollout of 60000 ms begins"), end);
    }
    let bound = Duration::from_secs(5);
    let t0 = Instant::now();
    run.ctl_ok(&["scale", "--workers", "1"]);
    while supervisor::process_alive(second) {
        assert!(
            t0.elapsed() < bound,
            "worker-1 still in its rollout {:?} after the scale-down:\n{}",
            t0.elapsed(),
            run.text()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let t0 = Instant::now();
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(t0.elapsed() < bound, "{:?}:\n{}", t0.elapsed(), run.text());
    assert!(!supervisor::process_alive(first));
    let out = run.text();
    assert!(!out.contains("did not stop within"), "{out}");
    let abandoned = out
        .lines()
        .filter(|l| {
            l.contains("stopped by a signal during the rollout; abandoned, its cost not sent")
        })
        .count();
    assert_eq!(abandoned, 2, "{out}");
    let r = RunResult::read(&result).unwrap();
    assert_eq!((r.complete, r.updates), (false, 0));
    assert_nothing_left(&run);
}

/// A worker program as users write them: a shell script that starts a simulator of its own
/// beside the worker (here `sleep`, which inherits the script's output), runs the worker
/// without `exec`, and whose own shutdown fails (exit 3 on SIGTERM). Each of these broke the
/// supervisor:
/// - the worker announced its own pid, not the script's, so it was taken for a worker joining
///   from outside into the slot the script held, stopped (SIGTERM), and restarted until
///   `restart_limit` failed the run;
/// - a dead worker was reported only once its output pipe closed, which the simulator held
///   open: the death went unsaid and the worker was never restarted, and the simulator ran on;
/// - an exit other than as asked at the stop was not said.
#[test]
fn a_worker_program_that_is_a_script_with_a_simulator_of_its_own_is_supervised() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("worker-script");
    let reach = Path::new(SUPERVISOR)
        .parent()
        .unwrap()
        .join("examples/reach-worker");
    let sims = scratch.path("simulators");
    let script = scratch.path("worker.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nsleep 600 &\necho $! >> {sims}\ntrap 'wait $worker; exit 3' TERM\n\
             {reach} --rollout-ms 20 \"$@\" &\nworker=$!\nwait $worker\n",
            sims = sims.display(),
            reach = reach.display()
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let text = external_config_from(
        "external-reach.toml",
        "../target/release/examples/reach-worker",
        &script,
        &[("updates = 80\n", "")],
    );
    let cfg = write_config(&scratch, "script.toml", &text);
    let mut run = Run::start(&scratch, 26449, &[cfg.to_str().unwrap(), "--no-record"]);
    let status = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    assert!(!run.text().contains("joined"), "{}", run.text());
    let script_pid = pid_of(&status, "worker-1");
    let left = supervisor::group_members(script_pid);
    assert_eq!(left.len(), 3, "script, simulator and worker: {left:?}");
    signal(script_pid, "-9");
    let end = Instant::now() + Duration::from_secs(10);
    run.wait_output(
        &format!("worker-1 (pid {script_pid}) left 2 process(es) running in its process group"),
        end,
    );
    run.wait_output(
        &format!("worker-1 (pid {script_pid}) died (signal: 9 (SIGKILL))"),
        end,
    );
    run.wait_output("worker-1 (pid ", end);
    run.wait_output(", incarnation 1) is ready", end);
    while left.iter().any(|&pid| supervisor::process_alive(pid)) {
        assert!(Instant::now() < end, "{left:?} outlived their worker");
        std::thread::sleep(Duration::from_millis(20));
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    let out = run.text();
    for w in [0, 1] {
        assert!(
            out.lines()
                .any(|l| l.contains(&format!("warning: worker-{w} (pid "))
                    && l.contains("asked to stop, did not end cleanly (exit status: 3")),
            "{out}"
        );
    }
    assert!(!out.contains("joined"), "{out}");
    let sims = std::fs::read_to_string(&sims).unwrap();
    assert_eq!(sims.lines().count(), 3, "{sims}");
    for pid in sims.lines() {
        assert!(!supervisor::process_alive(pid.parse().unwrap()), "{pid}");
    }
    assert_nothing_left(&run);
}

/// A worker that exits with status 0 unasked was stopped on purpose (an operator's `kill`,
/// which a Rust worker answers by ending in order; `sys.exit(0)` in a Python task's rollout):
/// it is not restarted (it was, as a death, counting towards `restart_limit`), the run goes on
/// with the others, and with none left it stops as `supervisor stop` stops it.
#[test]
fn a_worker_that_exits_0_on_its_own_is_not_restarted() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("exit-0");
    // A Rust worker (the built-in one) ended by SIGTERM: the other goes on, and the result is
    // the in-process one.
    let text = config(&[
        ("updates = 40", "updates = 20"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
        ),
        ("workers = 3", "workers = 2"),
    ]);
    let cfg = write_config(&scratch, "exit-0.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 1302, &cfg, &result);
    let s = run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let victim = pid_of(&s, "worker-1");
    signal(victim, "-TERM");
    let s = run.wait_status("worker-1 gone", |s| !s.contains("worker-1 pid"));
    assert!(s.contains("workers: 1 running (target 1"), "{s}");
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    let said = out
        .lines()
        .find(|l| {
            l.contains(&format!(
                "worker-1 (pid {victim}) exited on its own (exit status: 0"
            ))
        })
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        said.contains(
            "taken as stopped on purpose, not restarted; its rollouts go to the others, 1 \
             worker(s) go on"
        ),
        "{said}"
    );
    assert!(!out.contains("restart 1 of"), "{out}");
    assert_bit_identical(&text, &result);
    let rec = record::read_recording(&scratch.recording("A1", 1302)).unwrap();
    let logged = rec.logs.iter().any(|l| {
        l.event == "exit"
            && l.name == "worker-1"
            && l.message.contains("taken as stopped on purpose")
    });
    assert!(logged, "{:#?}", rec.logs);
    assert_nothing_left(&run);

    // A Python task that calls sys.exit(0) in its third rollout, in the run's only worker:
    // the run stops, exit 0, at the update it was in.
    let tools =
        std::path::absolute(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools")).unwrap();
    let script = scratch.path("quits.py");
    std::fs::write(
        &script,
        format!(
            r#"#!/usr/bin/env python3
import sys
sys.path.insert(0, {tools:?})
import pi2cma_worker, reach_worker
class Quits(reach_worker.Reach):
    def rollout(self, theta):
        self.n = getattr(self, "n", 0) + 1
        if self.n == 3:
            sys.exit(0)
        return super().rollout(theta)
pi2cma_worker.serve(Quits)
"#
        ),
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let text = external_config_from(
        "external-reach-python.toml",
        "../tools/reach_worker.py",
        &script,
        &[("workers = 2", "workers = 1")],
    );
    let cfg = write_config(&scratch, "quits.toml", &text);
    let result = scratch.path("quits.result.toml");
    let mut run = Run::start_quiet(&scratch, 1303, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    for said in [
        "update 0, rollout 2: the task's rollout called sys.exit(0): the worker exits with \
         status 0, stopped on purpose (the supervisor does not restart it); the rollout is \
         abandoned, its cost not sent",
        "exited on its own (exit status: 0",
        "): taken as stopped on purpose, not restarted; no worker is left to run rollouts, so \
         the run stops",
        "stopped on request",
    ] {
        assert!(out.contains(said), "no `{said}` in:\n{out}");
    }
    assert!(!out.contains("restart 1 of"), "{out}");
    let r = RunResult::read(&result).unwrap();
    assert_eq!((r.complete, r.updates), (false, 0));
    assert_nothing_left(&run);
}

/// The run of a robot that loses power: the whole group is SIGKILLed mid-run, after a runtime
/// task change, leaving an unfinished recording. The pipeline resumes from that file, as it is,
/// and reaches the bits of an uninterrupted run with the same change; so does the in-process
/// runner resumed from the same file.
#[test]
fn a_killed_run_resumes_from_its_recording_to_the_uninterrupted_result() {
    let scratch = Scratch::new("resume");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "unbounded.toml", &text);
    let first = scratch.path("first.mcap");
    let mut killed = Run::start(
        &scratch,
        900,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--record",
            first.to_str().unwrap(),
        ],
    );
    killed.wait_status("22 updates", |s| updates_in(s) >= 22);
    killed.ctl_ok(&["set", "viapoint", "0.2"]);
    // The updater prints the update the change takes effect at; the status lags (an
    // unbounded run reports every 0.2 s), so wait well past it for the recorder to have it.
    let end = Instant::now() + Duration::from_secs(30);
    let from = loop {
        let said = killed.text();
        let from = said.lines().find_map(|l| {
            l.strip_prefix("[updater] task change: viapoint = 0.2 from update ")
                .and_then(|rest| rest.strip_suffix(" (runtime)"))
                .and_then(|n| n.parse::<u64>().ok())
        });
        if let Some(from) = from {
            break from;
        }
        assert!(
            Instant::now() < end,
            "the updater never took the change:\n{said}"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    killed.wait_status("20 more updates", |s| updates_in(s) >= from + 20);
    let pids = pids_in(&killed.ctl(&["status"]).1);
    sigkill_supervisor(&mut killed, &pids);

    let rec = record::read_recording(&first).unwrap();
    assert!(
        !rec.indexed,
        "a killed recorder cannot have finished the file"
    );
    let last = rec.updates.last().unwrap().update;
    let viapoint = |u: &record::proto::Update| u.task_settings[0].value;
    let changed_at = rec
        .updates
        .iter()
        .find(|u| viapoint(u) == 0.2)
        .unwrap_or_else(|| {
            let seen: Vec<_> = rec
                .updates
                .iter()
                .map(|u| (u.update, &u.task_settings))
                .collect();
            panic!(
                "the runtime change is not recorded: {seen:?}\n{}",
                killed.text()
            )
        })
        .update;
    assert_eq!(changed_at, from, "the recording and the updater disagree");
    assert!(
        changed_at > 20 && last < 199,
        "changed at {changed_at}, last {last}"
    );

    // What an uninterrupted run with that change at that update gives.
    let reference = format!(
        "{}\n[[schedule]]\nfrom_update = {changed_at}\nset = \"viapoint\"\nvalue = 0.2\n",
        config(&[("updates = 40", "updates = 200")])
    );
    let resumed_rec = scratch.path("resumed.mcap");
    let result = scratch.path("result.toml");
    let mut resumed = Run::start(
        &scratch,
        901,
        &[
            "--resume",
            first.to_str().unwrap(),
            "--updates",
            "200",
            "--quiet",
            "--record",
            resumed_rec.to_str().unwrap(),
            "--result",
            result.to_str().unwrap(),
        ],
    );
    resumed.wait_exit(Duration::from_secs(60), 0);
    let said = format!("resumed at update {} from {}", last + 1, first.display());
    assert!(resumed.text().contains(&said), "{}", resumed.text());
    assert_bit_identical(&reference, &result);
    let r = record::read_recording(&resumed_rec).unwrap();
    assert!(r.indexed && r.truncated.is_none());
    assert_eq!(update_indices(&r), (last + 1..200).collect::<Vec<_>>());
    assert!(r.updates.iter().all(|u| viapoint(u) == 0.2));
    assert_recomputes(&r);
    let meta = &r.metadata[record::topics::METADATA];
    assert_eq!(meta["resumed_from"], first.display().to_string());
    // The killed file and the resumed one analyse as one run of 200 updates.
    let analyse = format!(
        "pi2cma analyze {} {} --out ",
        first.display(),
        resumed_rec.display()
    );
    assert!(resumed.text().contains(&analyse), "{}", resumed.text());
    let killed = record::read_recording(&first).unwrap();
    let runs = record::join_resumed(vec![r.clone(), killed]);
    assert_eq!(runs.len(), 1);
    assert_eq!(update_indices(&runs[0].0), (0..200).collect::<Vec<_>>());

    // The in-process runner, resumed from the same file, gives the same bits.
    let point = record::resume::resume_point(&first).unwrap();
    let (mut cfg200, _) = point.recorded_config().unwrap();
    cfg200.run.updates = Some(200);
    without_rollout_delay(&mut cfg200);
    point.check(&cfg200).unwrap();
    let mut exec = session::InProcess::resume(&cfg200, 1, point.start).unwrap();
    exec.run(&mut session::NoObserver, &|| false).unwrap();
    let (mean, cov) = RunResult::read(&result).unwrap().exact().unwrap();
    let d = exec.optimizer().distribution();
    assert_eq!(bits(&mean), bits(d.mean.as_slice()));
    assert_eq!(bits(&cov), bits(d.covariance.as_slice()));
    assert_nothing_left(&resumed);
}

/// A run resumed from a run that was itself resumed (day1 → day2 → day3): the printed
/// `analyze` command names every recording back to the run's start (before, it named day2 and
/// day3 only: a curve beginning at day2's first update); one moved away since is said to be
/// left out, not silently dropped.
#[test]
fn a_run_resumed_twice_prints_an_analyze_command_of_every_recording_back_to_its_start() {
    let scratch = Scratch::new("resume-chain");
    let cfg = write_config(&scratch, "a1.toml", &config(&[]));
    let day = |n: u32| scratch.path(&format!("day{n}.mcap"));
    let shown = |n: u32| day(n).display().to_string();
    let mut first = Run::start(
        &scratch,
        6496,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--updates",
            "4",
            "--record",
            &shown(1),
        ],
    );
    first.wait_exit(Duration::from_secs(60), 0);
    let resume = |id: u64, from: u32, to: u32, updates: &str| {
        let args = [
            "--resume",
            &shown(from),
            "--updates",
            updates,
            "--quiet",
            "--record",
            &shown(to),
        ];
        let mut run = Run::start(&scratch, id, &args);
        run.wait_exit(Duration::from_secs(60), 0);
        run.text()
    };
    // The analyze command of the days `days`, in order.
    let analyze = |days: &[u32]| {
        let files: Vec<String> = days.iter().map(|&n| shown(n)).collect();
        format!("pi2cma analyze {} --out", files.join(" "))
    };
    let out = resume(6497, 1, 2, "8");
    assert!(out.contains(&analyze(&[1, 2])), "{out}");
    let out = resume(6498, 2, 3, "12");
    assert!(out.contains(&analyze(&[1, 2, 3])), "{out}");
    // The settings resumed with, as the other messages write values (not Rust's debug form).
    assert!(
        out.contains("(task settings viapoint = ") && !out.contains("(task settings [("),
        "{out}"
    );
    assert!(!out.contains("NOTE:"), "{out}");
    // day1 moved away: the command names what is there and says what it leaves out.
    std::fs::rename(day(1), scratch.path("elsewhere.mcap")).unwrap();
    let out = resume(6499, 3, 4, "16");
    assert!(out.contains(&analyze(&[2, 3, 4])), "{out}");
    assert!(
        out.contains(&format!(
            "NOTE: {} resumed {} (it is not there): the command leaves it",
            shown(2),
            shown(1)
        )),
        "{out}"
    );
}

/// What a resumed run's recorder logs before its first update (the processes' announcements,
/// the supervisor's START) is logged at the update the run resumes at, as everything after it
/// is: it was logged at update 0, which the recording does not hold.
#[test]
fn a_resumed_runs_start_events_are_logged_at_the_update_it_resumes_at() {
    let scratch = Scratch::new("resume-log-update");
    let cfg = write_config(&scratch, "a1.toml", &config(&[]));
    let (day1, day2) = (scratch.path("day1.mcap"), scratch.path("day2.mcap"));
    let (day1, day2) = (day1.to_str().unwrap(), day2.to_str().unwrap());
    let args = [
        cfg.to_str().unwrap(),
        "--quiet",
        "--updates",
        "4",
        "--record",
        day1,
    ];
    Run::start(&scratch, 5103, &args).wait_exit(Duration::from_secs(60), 0);
    let args = [
        "--resume",
        day1,
        "--updates",
        "8",
        "--quiet",
        "--record",
        day2,
    ];
    Run::start(&scratch, 5104, &args).wait_exit(Duration::from_secs(60), 0);
    let rec = record::read_recording(Path::new(day2)).unwrap();
    assert!(logged(&rec, "start", "worker-0"), "{:?}", rec.logs);
    let before: Vec<String> = rec
        .logs
        .iter()
        .filter(|l| l.update < 4)
        .map(|l| format!("{} {} at update {}", l.event, l.name, l.update))
        .collect();
    assert!(before.is_empty(), "{before:?}");
}

/// A run that ends right before a task change: its resumed recording marks the change where
/// it took effect, and the two files analyse as one run with it once, as the uninterrupted
/// run's recording has it (before, the pipeline recorded it in neither file).
#[test]
fn a_task_change_at_the_update_a_run_resumes_from_is_recorded_once() {
    let scratch = Scratch::new("resume-change");
    let cfg = write_config(&scratch, "a1.toml", &config(&[]));
    let (first, second) = (scratch.path("first.mcap"), scratch.path("second.mcap"));
    let (first_s, second_s) = (first.to_str().unwrap(), second.to_str().unwrap());
    // A1's change is at update 20.
    let mut a = Run::start(
        &scratch,
        1000,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--updates",
            "20",
            "--record",
            first_s,
        ],
    );
    a.wait_exit(Duration::from_secs(60), 0);
    let args = [
        "--resume",
        first_s,
        "--updates",
        "40",
        "--quiet",
        "--record",
        second_s,
    ];
    let mut b = Run::start(&scratch, 1001, &args);
    b.wait_exit(Duration::from_secs(60), 0);

    let recs = vec![
        record::read_recording(&second).unwrap(),
        record::read_recording(&first).unwrap(),
    ];
    let runs = record::join_resumed(recs);
    assert_eq!(runs.len(), 1);
    let changes: Vec<(u64, &str, f64)> = runs[0]
        .0
        .task_changes
        .iter()
        .map(|c| (c.update, c.name.as_str(), c.value))
        .collect();
    assert_eq!(changes, [(20, "viapoint", 0.1)]);
    assert_nothing_left(&b);
}

/// A `set` taken while an update runs is due from the next; a run stopped before that update
/// never applies it, and says so instead of dropping it silently (it is in neither the result
/// file nor the recording, so a resume would not have it).
#[test]
fn a_task_change_the_stopped_run_never_reached_is_reported_not_applied() {
    let scratch = Scratch::new("set-then-stop");
    let text = config(&[
        UNBOUNDED,
        (
            "max_workers = 16",
            "max_workers = 16\nfault_hang_at_update = 0\nshutdown_timeout_ms = 1000",
        ),
    ]);
    let cfg = write_config(&scratch, "hang.toml", &text);
    let result = scratch.path("result.toml");
    let args = [
        cfg.to_str().unwrap(),
        "--quiet",
        "--no-record",
        "--result",
        result.to_str().unwrap(),
    ];
    let mut run = Run::start(&scratch, 1010, &args);
    // Update 0 never completes: its workers stop answering. The change follows START on the
    // control service, so the updater takes it as due from update 1.
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("run started", end);
    // The first is overridden by the second, due from the same update: only the second would
    // have applied, and only it is reported.
    for value in ["0.8", "0.9"] {
        let (ok, reply) = run.ctl(&["set", "viapoint", value]);
        assert!(
            ok && reply.contains("takes effect from update 1"),
            "{reply}"
        );
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    assert!(
        run.text().contains(
            "task change viapoint = 0.9 due from update 1 not applied: the run stopped before \
             that update"
        ),
        "{}",
        run.text()
    );
    assert!(
        !run.text()
            .contains("viapoint = 0.8 due from update 1 not applied"),
        "{}",
        run.text()
    );
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 0);
    assert!(
        r.task_changes.iter().all(|c| c.source != "runtime"),
        "{:?}",
        r.task_changes
    );
    assert_nothing_left(&run);
}

/// A resume that would not continue the recorded run is refused before anything starts.
#[test]
fn a_resume_that_is_not_the_recorded_run_is_refused() {
    let scratch = Scratch::new("resume-refused");
    let short = write_config(
        &scratch,
        "short.toml",
        &config(&[("updates = 40", "updates = 5")]),
    );
    let first = scratch.path("first.mcap");
    let mut run = Run::start(
        &scratch,
        910,
        &[
            short.to_str().unwrap(),
            "--quiet",
            "--record",
            first.to_str().unwrap(),
        ],
    );
    run.wait_exit(Duration::from_secs(60), 0);
    let other_seed = write_config(&scratch, "seed2.toml", &config(&[("seed = 1", "seed = 2")]));
    let fewer_rollouts = write_config(
        &scratch,
        "k10.toml",
        &config(&[("rollouts = 15", "rollouts = 10")]),
    );
    let first_s = first.to_str().unwrap();
    for (id, args, expected) in [
        (911, vec!["--resume", first_s], "nothing left to run"),
        (
            912,
            vec![other_seed.to_str().unwrap(), "--resume", first_s],
            "the recording has seed 1; the config run.seed = 2",
        ),
        (
            913,
            vec![fewer_rollouts.to_str().unwrap(), "--resume", first_s],
            "rollouts: 15 vs 10",
        ),
        (
            914,
            vec!["--resume", first_s, "--updates", "9", "--record", first_s],
            "would record over it",
        ),
        (915, vec!["--resume", "missing.mcap"], "missing.mcap"),
    ] {
        let mut run = Run::start(&scratch, id, &args);
        assert!(!run.wait(Duration::from_secs(30)).success(), "{args:?}");
        assert!(run.text().contains(expected), "{args:?}: {}", run.text());
        assert!(!run.runs.join(&run.run_id).exists(), "{args:?}");
    }
    // The refused resumes left the recording as it was.
    assert_eq!(record::read_recording(&first).unwrap().updates.len(), 5);
}

/// Starts a run of the reach task (300 ms rollouts, 6 updates) whose schedule changes target_y
/// to 0.6 at update 3, with `args` after its config, and sets target_y to 0.5 while update 2
/// runs, which overrides the scheduled change; returns once the updater has said so and the
/// recorder has had time to write update 2 (update 3 takes 1.5 s), with the config's path.
fn set_over_a_scheduled_change(scratch: &Scratch, id: u64, args: &[&str]) -> (Run, PathBuf) {
    let text = external_config(&[
        (
            "from_update = 40\nset = \"target_y\"\nvalue = 0.78",
            "from_update = 3\nset = \"target_y\"\nvalue = 0.6",
        ),
        ("updates = 80", "updates = 6"),
        (
            "/reach-worker\"]",
            "/reach-worker\", \"--rollout-ms\", \"300\"]",
        ),
    ]);
    let cfg = write_config(scratch, "override.toml", &text);
    let run = Run::start(scratch, id, &[&[cfg.to_str().unwrap()], args].concat());
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let reply = run.ctl_ok(&["set", "target_y", "0.5"]);
    assert_eq!(takes_effect_from(&reply), 3, "update 2 takes 1.5 s");
    // The reply names the scheduled change it replaces, as the updater's output does.
    assert!(
        reply.contains("replacing target_y = 0.6 (schedule), which was due from the same update"),
        "{reply}"
    );
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output(
        "task change: target_y = 0.5 (runtime) overrides target_y = 0.6 (schedule) from update 3",
        end,
    );
    std::thread::sleep(Duration::from_millis(400));
    (run, cfg)
}

/// A `supervisor set` over the schedule's change of the same setting at the same update
/// overrides it, and the recording of a run stopped in that update records the runtime value as
/// the change ahead. `--resume` must go on with it: it went on with the schedule's, which it
/// applied again on top of the recorded settings.
#[test]
fn a_runtime_change_over_a_scheduled_one_is_resumed_with_not_the_scheduled_one() {
    let scratch = Scratch::new("override-resume");
    let result = scratch.path("override.result.toml");
    let id = 870;
    let args = ["--result", result.to_str().unwrap()];
    let (mut run, cfg) = set_over_a_scheduled_change(&scratch, 870, &args);
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    let out = run.text();
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 3, "{out}");
    let listed: Vec<_> = r
        .task_changes
        .iter()
        .map(|c| (c.from_update, c.name.as_str(), c.value, c.source.as_str()))
        .collect();
    assert_eq!(listed, [(3, "target_y", 0.5, "runtime")], "{out}");
    let recording = scratch.recording("reach", id);
    let point = record::resume::resume_point(&recording).unwrap();
    assert_eq!(
        point.start.settings,
        [("target_x".to_string(), 0.3), ("target_y".to_string(), 0.5)]
    );
    assert_nothing_left(&run);

    let second = scratch.path("resumed.mcap");
    let resumed_result = scratch.path("resumed.result.toml");
    let mut resumed = Run::start(
        &scratch,
        id + 1,
        &[
            cfg.to_str().unwrap(),
            "--resume",
            recording.to_str().unwrap(),
            "--record",
            second.to_str().unwrap(),
            "--result",
            resumed_result.to_str().unwrap(),
        ],
    );
    resumed.wait_exit(Duration::from_secs(60), 0);
    let out = resumed.text();
    let rec = record::read_recording(&second).unwrap();
    for u in &rec.updates {
        let s: Vec<f64> = u.task_settings.iter().map(|s| s.value).collect();
        assert_eq!(s, [0.3, 0.5], "update {}:\n{out}", u.update);
    }
    let r = RunResult::read(&resumed_result).unwrap();
    assert!(
        r.task_changes.iter().all(|c| c.source == "resume"),
        "{:?}\n{out}",
        r.task_changes
    );
    assert_nothing_left(&resumed);
}

/// What a SIGKILL (power loss) costs besides the updates in flight (README, "Nothing lost"):
/// the recorder writes what the update the run was in was to run with (`/task_change`,
/// `/unfinished_update`) only when stopped in order, and the killed file holds nothing of that
/// update for `recover` to rebuild it from. So the `set` of the test above, killed instead of
/// stopped in the update it took effect at, is lost: `--resume` goes on with the settings of
/// the last recorded update, and the schedule's change it had overridden applies again.
#[test]
fn a_set_at_the_update_a_killed_run_was_in_is_lost_with_that_update() {
    let scratch = Scratch::new("h3-killed-set");
    let id = 1650;
    let (mut run, _) = set_over_a_scheduled_change(&scratch, 1650, &[]);
    let pids = pids_in(&run.ctl(&["status"]).1);
    sigkill_supervisor(&mut run, &pids);

    let recording = scratch.recording("reach", id);
    let recovered = scratch.path("recovered.mcap");
    record::recover::recover(&recording, &recovered).unwrap();
    for file in [&recording, &recovered] {
        let rec = record::read_recording(file).unwrap();
        assert_eq!(update_indices(&rec), [0, 1, 2], "{}", file.display());
        for topic in ["/task_change", "/unfinished_update"] {
            assert!(
                !rec.topic_counts.contains_key(topic),
                "{}: {topic} {:?}",
                file.display(),
                rec.topic_counts
            );
        }
        let point = record::resume::resume_point(file).unwrap();
        assert_eq!(point.start.update, 3);
        let ran: Vec<(String, f64)> = rec.updates[2]
            .task_settings
            .iter()
            .map(|s| (s.name.clone(), s.value))
            .collect();
        // Update 2's settings, not the 0.5 update 3 was published with.
        assert_eq!(point.start.settings, ran, "{}", file.display());
        assert!(!ran.iter().any(|(_, v)| *v == 0.5), "{ran:?}");
        assert!(!point.start.published, "{}", file.display());
    }
    // What the killed run left (the next run's sweep would find it; no run follows here).
    let prefix = run.shm_prefix();
    for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
        if e.file_name().to_string_lossy().starts_with(&prefix) {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let _ = std::fs::remove_dir_all(run.ipc_root());
}

/// A `set` to the value in force, and one that overrides a scheduled change back to it, leave
/// the run as it was: the result file lists no change, as the recording shows none.
#[test]
fn a_set_to_the_value_in_force_is_no_task_change() {
    let scratch = Scratch::new("set-in-force");
    let text = external_config(&[
        (
            "from_update = 40\nset = \"target_y\"\nvalue = 0.78",
            "from_update = 3\nset = \"target_y\"\nvalue = 0.6",
        ),
        ("updates = 80", "updates = 5"),
        (
            "/reach-worker\"]",
            "/reach-worker\", \"--rollout-ms\", \"300\"]",
        ),
    ]);
    let cfg = write_config(&scratch, "in-force.toml", &text);
    let result = scratch.path("in-force.result.toml");
    let id = 880;
    let mut run = Run::start(
        &scratch,
        id,
        &[cfg.to_str().unwrap(), "--result", result.to_str().unwrap()],
    );
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    assert_eq!(
        takes_effect_from(&run.ctl_ok(&["set", "target_x", "0.3"])),
        3
    );
    assert_eq!(
        takes_effect_from(&run.ctl_ok(&["set", "target_y", "0.7"])),
        3
    );
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    for needle in [
        "task change: target_x = 0.3 (runtime) from update 3 leaves it as update 2 ran with it",
        "task change: target_y = 0.7 (runtime) from update 3 leaves it as update 2 ran with it",
    ] {
        assert!(out.contains(needle), "{needle}\n{out}");
    }
    let r = RunResult::read(&result).unwrap();
    assert_eq!(r.updates, 5, "{out}");
    assert!(r.task_changes.is_empty(), "{:?}\n{out}", r.task_changes);
    let rec = record::read_recording(&scratch.recording("reach", id)).unwrap();
    assert!(rec.task_changes.is_empty(), "{:?}", rec.task_changes);
    for u in &rec.updates {
        let s: Vec<f64> = u.task_settings.iter().map(|s| s.value).collect();
        assert_eq!(s, [0.3, 0.7], "update {}:\n{out}", u.update);
    }
    assert_nothing_left(&run);
}

/// A1 with its via-point change (0.3 → 0.1) at update `at`, `edits` applied, and rollouts of
/// `delay_ms` (0: none).
fn a1_changing_at(at: u64, delay_ms: f64, edits: &[(&str, &str)]) -> String {
    let at = format!("from_update = {at}");
    let delay = format!("viapoint_weight = 1000.0\nrollout_delay_ms = {delay_ms:?}");
    let mut all = vec![("from_update = 20", at.as_str())];
    if delay_ms > 0.0 {
        all.push(("viapoint_weight = 1000.0", delay.as_str()));
    }
    all.extend_from_slice(edits);
    config(&all)
}

/// Resumes `recording` (of `a1_changing_at(at, …)`, stopped in update `at`) to update 8, and
/// checks that the pipeline and the in-process runner, resumed from it, both end exactly where
/// the uninterrupted run with the schedule's change to `viapoint` does, and that updates `at`
/// and on ran with it.
fn assert_resumes_with_viapoint(
    scratch: &Scratch,
    id: u64,
    recording: &Path,
    at: u64,
    viapoint: f64,
) {
    let reference = a1_changing_at(
        at,
        0.0,
        &[("value = 0.1", &format!("value = {viapoint:?}"))],
    );
    let config = &write_config(scratch, "fast.toml", &a1_changing_at(at, 0.0, &[]));
    let to = &scratch.path("second.mcap");
    let result = scratch.path(&format!("resumed-{id}.result.toml"));
    let mut resumed = Run::start(
        scratch,
        id,
        &[
            config.to_str().unwrap(),
            "--resume",
            recording.to_str().unwrap(),
            "--updates",
            "8",
            "--quiet",
            "--record",
            to.to_str().unwrap(),
            "--result",
            result.to_str().unwrap(),
        ],
    );
    resumed.wait_exit(Duration::from_secs(60), 0);
    assert_bit_identical(&reference, &result);
    let point = record::resume::resume_point(recording).unwrap();
    let mut cfg = RunConfig::load(config).unwrap();
    cfg.run.updates = Some(8);
    let mut exec = session::InProcess::resume(&cfg, 1, point.start).unwrap();
    exec.run(&mut session::NoObserver, &|| false).unwrap();
    let (mean, _) = RunResult::read(&result).unwrap().exact().unwrap();
    assert_eq!(
        bits(&mean),
        bits(exec.optimizer().distribution().mean.as_slice())
    );
    assert_nothing_left(&resumed);
    let rec = record::read_recording(to).unwrap();
    assert_recomputes(&rec);
    assert_eq!(
        viapoints(&rec),
        (at..8).map(|u| (u, viapoint)).collect::<Vec<_>>()
    );
}

/// The via-point values the updates of a recording ran with.
fn viapoints(rec: &record::Recording) -> Vec<(u64, f64)> {
    rec.updates
        .iter()
        .map(|u| (u.update, u.task_settings[0].value))
        .collect()
}

/// A `set` that overrides the schedule's change at update 3 back to the value in force is no
/// task change, so nothing in the recording showed it: a run stopped in update 3 was resumed
/// with the schedule's change applied again, and went on as a run that had never been given
/// the `set`. The recorder now writes the settings the update was to run with
/// (`/unfinished_update`), and the resume goes on with them.
#[test]
fn a_set_back_to_the_value_in_force_over_a_scheduled_change_is_resumed_with() {
    let scratch = Scratch::new("override-back-resume");
    let cfg = write_config(&scratch, "slow.toml", &a1_changing_at(3, 300.0, &[]));
    let first = scratch.path("first.mcap");
    let result = scratch.path("first.result.toml");
    let mut run = Run::start(
        &scratch,
        1400,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--record",
            first.to_str().unwrap(),
            "--result",
            result.to_str().unwrap(),
        ],
    );
    run.wait_status("2 updates", |s| updates_in(s) >= 2);
    let reply = run.ctl_ok(&["set", "viapoint", "0.3"]);
    assert_eq!(
        takes_effect_from(&reply),
        3,
        "an update takes 1.5 s: {reply}"
    );
    run.wait_output(
        "task change: viapoint = 0.3 (runtime) from update 3 leaves it as update 2 ran with it",
        Instant::now() + Duration::from_secs(30),
    );
    std::thread::sleep(Duration::from_millis(300));
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    let out = run.text();
    assert_eq!(RunResult::read(&result).unwrap().updates, 3, "{out}");
    let rec = record::read_recording(&first).unwrap();
    assert!(rec.task_changes.is_empty(), "{:?}", rec.task_changes);
    assert_nothing_left(&run);

    // Uninterrupted, the via-point stays at 0.3: the schedule's change was overridden.
    assert_resumes_with_viapoint(&scratch, 1401, &first, 3, 0.3);
}

/// A part a restarted recorder began at the first update that a `set` over the schedule's
/// change ran with, and the run stopped in that update: the part holds its `/run` only. Its
/// settings are the ones the update was published with, so the schedule's change is not
/// applied again over the `set` (before, the resume did: its `/run` did not say what the update
/// before ran with, and the schedule's change looked due); and `/run` now says what the update
/// before ran with, which a change refused there falls back to.
#[test]
fn a_part_without_updates_resumes_as_the_run_went_on() {
    let scratch = Scratch::new("run-only-part-resume");
    let text = a1_changing_at(
        4,
        300.0,
        &[(
            "max_workers = 16",
            "max_workers = 16\nfault_hang_at_update = 4\nshutdown_timeout_ms = 1000",
        )],
    );
    let cfg = write_config(&scratch, "hang-at-4.toml", &text);
    let first = scratch.path("first.mcap");
    let mut run = Run::start(
        &scratch,
        1402,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--record",
            first.to_str().unwrap(),
        ],
    );
    let status = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    // Update 3 is held while the recorder is replaced, so the new one begins at update 4.
    let workers: Vec<u32> = pids_in(&status)
        .into_iter()
        .filter(|(n, _)| n.starts_with("worker-"))
        .map(|(_, pid)| pid)
        .collect();
    for &w in &workers {
        signal(w, "-STOP");
    }
    let status = run.ctl_ok(&["status"]);
    assert_eq!(updates_in(&status), 3, "update 3 took 1.5 s:\n{status}");
    let reply = run.ctl_ok(&["set", "viapoint", "0.2"]);
    assert_eq!(takes_effect_from(&reply), 4, "{reply}");
    sigkill_recorder(&status);
    run.wait_output(
        "recorder restarted: recording to",
        Instant::now() + Duration::from_secs(30),
    );
    for &w in &workers {
        signal(w, "-CONT");
    }
    // The workers' first incarnations stop answering at update 4: the run stays in it.
    let part = record::part_path(&first, 2);
    let end = Instant::now() + Duration::from_secs(30);
    while !record::read_ends(&part).is_ok_and(|e| e.run.is_some()) {
        assert!(Instant::now() < end, "no part 2:\n{}", run.text());
        std::thread::sleep(Duration::from_millis(20));
    }
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    let out = run.text();
    let rec = record::read_recording(&part).unwrap();
    let info = rec.run_info().unwrap();
    assert!(rec.updates.is_empty() && info.update == 4, "{out}");
    let named = |s: &[record::proto::Setting]| -> Vec<(String, f64)> {
        s.iter().map(|s| (s.name.clone(), s.value)).collect()
    };
    let viapoint = |v: f64| vec![("viapoint".to_string(), v)];
    assert_eq!(named(&info.task_settings), viapoint(0.2), "{out}");
    assert_eq!(named(&info.previous_task_settings), viapoint(0.3), "{out}");
    let point = record::resume::resume_point(&first).unwrap();
    assert_eq!(point.start.update, 4);
    assert_eq!(point.start.ran_with, viapoint(0.3));
    assert_nothing_left(&run);

    // Uninterrupted, update 4 and on run with the `set`'s 0.2, not the schedule's 0.1.
    assert_resumes_with_viapoint(&scratch, 1403, &first, 4, 0.2);
}

/// `--run` takes the id as `supervisor run --run-id` was given it (`2222` for the run
/// 0000000000002222), as well as the start of the whole id.
#[test]
fn a_run_is_found_by_its_id_without_leading_zeros() {
    let scratch = Scratch::new("short-id");
    let text = config(&[(
        "viapoint_weight = 1000.0",
        "viapoint_weight = 1000.0\nrollout_delay_ms = 50.0",
    )]);
    let cfg = write_config(&scratch, "short.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 881, &cfg, &result);
    run.wait_status("1 update", |s| updates_in(s) >= 1);
    let short = run.run_id.trim_start_matches('0').to_string();
    assert!(short.len() < 16, "{}", run.run_id);
    for id in [short.as_str(), &run.run_id[..8]] {
        let out = Command::new(SUPERVISOR)
            .args(["status", "--run", id])
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string()
            + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "--run {id}: {text}");
        assert!(text.contains(&run.run_id), "--run {id}: {text}");
    }
    // An id that names no run: the error lists the active ones.
    let out = Command::new(SUPERVISOR)
        .args(["status", "--run", "fff"])
        .env("PI2CMA_RUN_DIR", scratch.runs())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("no active run `fff` under")
            && text.contains(&format!("(active: {} (A1))", run.run_id)),
        "{text}"
    );
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(30), 0);
    assert_nothing_left(&run);
}

/// A name the control line cannot carry is refused by name before any run is asked (it was
/// sent, and the run replied `unknown command \`set  1.0\``).
#[test]
fn set_refuses_a_setting_name_that_is_not_one_word() {
    let scratch = Scratch::new("set-bad-name");
    for name in ["", "a b", "target_y\n"] {
        let out = Command::new(SUPERVISOR)
            .args(["set", name, "1"])
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name:?}: {text}");
        assert!(
            text.contains(&format!("`{name}` is no setting's name")),
            "{name:?}: {text}"
        );
    }
}

/// A negative number of workers (or updates) is a bad value of the option, named so. Clap took
/// `-2` for an unknown option and advised `-- -2`, which would have made it the config file.
#[test]
fn a_negative_number_of_workers_is_a_bad_value_of_the_option() {
    let scratch = Scratch::new("negative-workers");
    for args in [
        &["run", "--workers", "-2"][..],
        &["scale", "--workers", "-2"],
        &["run", "--updates", "-2"],
    ] {
        let out = Command::new(SUPERVISOR)
            .args(args)
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {text}");
        let option = format!("{} <{}>", args[1], args[1][2..].to_uppercase());
        assert!(
            text.contains(&format!("invalid value '-2' for '{option}'")),
            "{args:?}: {text}"
        );
    }
}

/// A value that is not a finite number is refused as typed before any run is asked: `1e400`
/// was sent as `inf`, and the run's refusal named `inf`.
#[test]
fn set_refuses_a_value_that_is_not_finite_as_typed() {
    let scratch = Scratch::new("set-not-finite");
    for value in ["1e400", "-1e999", "nan", "inf"] {
        let out = Command::new(SUPERVISOR)
            .args(["set", "viapoint", value])
            .env("PI2CMA_RUN_DIR", scratch.runs())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{value}: {text}");
        assert!(
            text.contains(&format!("`{value}` is not a finite number")),
            "{value}: {text}"
        );
    }
}

/// A run that fails to start stops its recorder: the warning tells `recover` only of a file
/// the recorder created (it pointed to a file that did not exist), and not of one it finished
/// (a recorder that got to its stop in time: seen in CI after the recorder got faster).
#[test]
fn a_recorder_stopped_before_it_created_its_file_is_not_said_to_leave_one() {
    let scratch = Scratch::new("rec-no-file");
    let text = config(&[("[pipeline]", "[pipeline]\nstartup_timeout_ms = 1")]);
    let cfg = write_config(&scratch, "no-file.toml", &text);
    let out_file = scratch.path("no-file.mcap");
    let mut run = Run::start(
        &scratch,
        882,
        &[
            cfg.to_str().unwrap(),
            "--record",
            out_file.to_str().unwrap(),
        ],
    );
    run.wait_exit(Duration::from_secs(30), 1);
    let out = run.text();
    assert!(
        out.contains("did not become ready within 1 ms (pipeline.startup_timeout_ms)"),
        "{out}"
    );
    if out_file.exists() {
        // Stopped in time to finish its file (0 updates: a complete, indexed recording), or
        // not: then the summary points to `recover`.
        let finished = record::read_recording(&out_file).is_ok_and(|r| r.indexed);
        let said = if finished {
            "analyse it with"
        } else {
            "recover"
        };
        assert!(out.contains(said), "{out}");
    } else {
        assert!(!out.contains("recover"), "{out}");
        assert!(out.contains("nothing was recorded"), "{out}");
    }
    assert_nothing_left(&run);
}

/// A worker that exits with status 0 before it has announced itself ran nothing: that is a
/// failed start, restarted as a crash (and with `restart_limit = 0` it fails the run), not a
/// stop on purpose, which would end the run with exit 0 as if all were well.
#[test]
fn a_worker_that_exits_0_before_announcing_itself_is_a_failed_start() {
    use std::os::unix::fs::PermissionsExt;
    let scratch = Scratch::new("exit-0-early");
    let script = scratch.path("quits.sh");
    std::fs::write(&script, "#!/bin/sh\nexit 0\n").unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let text = external_config_from(
        "external-reach.toml",
        "../target/release/examples/reach-worker",
        &script,
        &[("workers = 2", "workers = 1\nrestart_limit = 0")],
    );
    assert_run_fails_saying_not(
        &scratch,
        1304,
        "quits.toml",
        &text,
        &["worker-0 died (exit status: 0) after 0 restarts"],
        &["taken as stopped on purpose"],
    );
}

/// A Python worker without iceoryx2 (the tools' requirements not installed) says so and is not
/// restarted: every restart would meet the same (it was restarted up to the limit).
#[test]
fn a_python_worker_without_iceoryx2_is_not_restarted() {
    let scratch = Scratch::new("python-no-iox2");
    // An `iceoryx2` module first on the path that cannot be imported, as a missing one.
    let fake = scratch.path("fake-site");
    std::fs::create_dir_all(&fake).unwrap();
    std::fs::write(
        fake.join("iceoryx2.py"),
        "raise ModuleNotFoundError(\"No module named 'iceoryx2'\")\n",
    )
    .unwrap();
    let cfg = write_config(&scratch, "no-iox2.toml", &python_config(&[]));
    let fake = fake.to_str().unwrap();
    let mut run = Run::start_with_env(
        &scratch,
        883,
        &[cfg.to_str().unwrap(), "--quiet"],
        &[("PYTHONPATH", fake)],
    );
    run.wait_exit(Duration::from_secs(60), 1);
    let out = run.text();
    assert!(
        out.contains("pi2cma_worker: cannot import iceoryx2 (No module named 'iceoryx2'); install"),
        "{out}"
    );
    assert!(out.contains("not restarted"), "{out}");
    assert!(!out.contains("restart 1 of"), "{out}");
    assert_nothing_left(&run);
}

/// A worker a scale-down asks to stop and that does not (stuck here; on a robot, an episode
/// longer than the timeout) is killed after `shutdown_timeout_ms`, without a rollout timeout:
/// it held its rollouts and the run waited for it forever.
#[test]
fn a_scaled_down_worker_that_does_not_stop_is_killed_after_the_shutdown_timeout() {
    let scratch = Scratch::new("scaled-stuck");
    let text = config(&[
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 100.0",
        ),
        ("workers = 3", "workers = 4"),
        (
            "max_workers = 16",
            "max_workers = 16\nshutdown_timeout_ms = 1000",
        ),
    ]);
    let cfg = write_config(&scratch, "scaled-stuck.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start_quiet(&scratch, 954, &cfg, &result);
    let s = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let victim = pid_of(&s, "worker-3");
    signal(victim, "-STOP");
    run.ctl_ok(&["scale", "--workers", "3"]);
    run.wait_output(
        &format!(
            "worker-3 (pid {victim}), scaled down, did not stop within 1000 ms \
             (pipeline.shutdown_timeout_ms); killing it"
        ),
        Instant::now() + Duration::from_secs(20),
    );
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(!supervisor::process_alive(victim));
    // Killed when due, not at the next thing the supervisor woke for (the stall warning, 10 s).
    let out = run.text();
    assert!(!out.contains("no update for"), "{out}");
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A1 with 20 ms rollouts (about 4 s), started quiet with a result file and waited for until
/// it has made an update: (config text, config file, result file, run).
fn a_slow_run_going_on(scratch: &Scratch, id: u64) -> (String, PathBuf, PathBuf, Run) {
    let text = config(&[(
        "viapoint_weight = 1000.0",
        "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
    )]);
    let cfg = write_config(scratch, "slow.toml", &text);
    let result = scratch.path("result.toml");
    let run = Run::start_quiet(scratch, id, &cfg, &result);
    run.wait_status("1 update", |s| updates_in(s) >= 1);
    (text, cfg, result, run)
}

/// A stop that waits for a process says so while it waits, naming it: with a robot's
/// `shutdown_timeout_ms` of a minute, the supervisor said nothing after "signal received"
/// until the timeout, and a user who took it for hung pressed Ctrl-C again, which kills the
/// recorder too and leaves the recording unfinished. A stop not begun by Ctrl-C (`supervisor
/// stop`) is told that Ctrl-C now kills, not that "a second" does: the first one a user then
/// pressed, to stop it in order, killed every process.
#[test]
fn a_stop_that_waits_for_a_worker_names_it_while_it_waits() {
    let scratch = Scratch::new("stop-waits");
    let text = config(&[
        ("updates = 40\n", ""),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
        ),
        (
            "max_workers = 16",
            "max_workers = 16\nshutdown_timeout_ms = 4000",
        ),
    ]);
    let cfg = write_config(&scratch, "stop-waits.toml", &text);
    let signalled = Run::start(&scratch, 26450, &[cfg.to_str().unwrap(), "--quiet"]);
    let commanded = Run::start(&scratch, 26960, &[cfg.to_str().unwrap(), "--quiet"]);
    for (mut run, by_signal) in [(signalled, true), (commanded, false)] {
        let status = run.wait_status("1 update", |s| updates_in(s) >= 1);
        let stuck = pid_of(&status, "worker-1");
        signal(stuck, "-STOP");
        if by_signal {
            signal(run.child.id(), "-INT");
        } else {
            run.ctl_ok(&["stop"]);
        }
        let waiting = format!("still waiting for worker-1 (pid {stuck}) to stop");
        run.wait_output(&waiting, Instant::now() + Duration::from_secs(3));
        run.wait_exit(Duration::from_secs(30), if by_signal { 130 } else { 0 });
        let out = run.text();
        let said = |needle: &str| {
            out.find(needle)
                .unwrap_or_else(|| panic!("{needle}: {out}"))
        };
        assert!(
            said(&waiting) < said("did not stop within 4000 ms"),
            "{out}"
        );
        let kills = if by_signal {
            "a second Ctrl-C kills every process at once, the recorder too"
        } else {
            "Ctrl-C now kills every process at once, the recorder too"
        };
        assert!(out.contains(kills), "{out}");
        assert_nothing_left(&run);
    }
}

/// A run without `--record` whose default recording is there already (an earlier run of the
/// same `--run-id`) is refused naming that default, not `--record`, which was not given.
#[test]
fn a_default_recording_left_by_an_earlier_run_of_the_id_is_named_as_the_default() {
    let scratch = Scratch::new("default-recording-there");
    let earlier = scratch.recording("A1", 26451);
    std::fs::create_dir_all(earlier.parent().unwrap()).unwrap();
    std::fs::write(&earlier, b"an earlier run's recording").unwrap();
    let mut run = Run::start(&scratch, 26451, &["--quiet"]);
    run.wait_exit(Duration::from_secs(20), 1);
    let out = run.text();
    assert!(
        out.contains("is there already (the default place of a run of this name and id")
            && out.contains("give another --run-id, or --record FILE")
            && !out.contains("(--record)"),
        "{out}"
    );
    assert_eq!(
        std::fs::read(&earlier).unwrap(),
        b"an earlier run's recording"
    );
    assert_nothing_left(&run);
}

/// A second run with a live run's id is refused as that: the directory belongs to a run going
/// on (the message said "is active or was killed (remove the directory)", which would break it).
#[test]
fn a_second_run_with_a_live_runs_id_is_refused_without_harming_it() {
    let scratch = Scratch::new("same-id");
    let (text, cfg, result, mut run) = a_slow_run_going_on(&scratch, 884);
    let second = scratch.path("second.toml");
    // Its own recording file would be the live run's: refused first, and not what is tested.
    let mut again = Run::start(
        &scratch,
        884,
        &[
            cfg.to_str().unwrap(),
            "--quiet",
            "--no-record",
            "--result",
            second.to_str().unwrap(),
        ],
    );
    assert!(!again.wait(Duration::from_secs(20)).success());
    let id = run_id(884);
    assert!(
        again.text().contains(&format!(
            "run {id} is active (`supervisor status --run {id}`)"
        )),
        "{}",
        again.text()
    );
    run.wait_exit(Duration::from_secs(60), 0);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// The iceoryx2 directory and shared memory of a run are named by its id alone, not by its runs
/// directory: a second run with a live run's id under another `PI2CMA_RUN_DIR` (another user's,
/// a script's own) found no run directory, started, failed with iceoryx2's
/// `ExceedsMaxSupportedSubscribers`, and its clean-up removed the live run's shared memory,
/// which then made no update again. It is refused before it starts anything.
#[test]
fn a_second_run_with_a_live_runs_id_under_another_runs_directory_is_refused() {
    let scratch = Scratch::new("same-id-other-runs-dir");
    let (text, cfg, result, mut run) = a_slow_run_going_on(&scratch, 26448);
    let elsewhere = scratch.path("elsewhere");
    let mut again = Run::start_with_env(
        &scratch,
        26448,
        &[cfg.to_str().unwrap(), "--quiet", "--no-record"],
        &[("PI2CMA_RUN_DIR", elsewhere.to_str().unwrap())],
    );
    assert!(!again.wait(Duration::from_secs(20)).success());
    let id = run_id(26448);
    assert!(
        again.text().contains(&format!(
            "run {id} is active outside {}: ",
            elsewhere.display()
        )),
        "{}",
        again.text()
    );
    // The live run goes on to its end.
    let before = updates_in(&run.ctl_ok(&["status"]));
    run.wait_status("more updates", |s| updates_in(s) > before + 2);
    run.wait_exit(Duration::from_secs(60), 0);
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// An external task's worker path is relative to its config file (as in
/// config/external-reach.toml). A run resumed without its config goes on with the recorded
/// config, which has no file of its own: the worker was looked for beside the recording, and
/// the run failed saying only "relative to the config file's directory". It now says to give
/// the config, and with it the run resumes.
#[test]
fn an_external_run_resumed_without_its_config_says_to_give_it() {
    let scratch = Scratch::new("resume-relative-worker");
    let worker = Path::new(SUPERVISOR)
        .parent()
        .unwrap()
        .join("examples/reach-worker");
    assert!(worker.is_file(), "{} not built", worker.display());
    for dir in ["bin", "config"] {
        std::fs::create_dir_all(scratch.path(dir)).unwrap();
    }
    std::fs::copy(&worker, scratch.path("bin/reach-worker")).unwrap();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/external-reach.toml"),
    )
    .unwrap()
    .replacen(
        "\"../target/release/examples/reach-worker\"",
        "\"../bin/reach-worker\"",
        1,
    );
    write_config(&scratch, "config/reach.toml", &text);
    let first = ["config/reach.toml", "--quiet", "--record", "day1.mcap"];
    Run::start(&scratch, 1500, &first).wait_exit(Duration::from_secs(60), 0);
    let resume = [
        "--resume",
        "day1.mcap",
        "--updates",
        "90",
        "--record",
        "day2.mcap",
    ];
    let mut run = Run::start(&scratch, 1501, &resume);
    run.wait_exit(Duration::from_secs(60), 1);
    let out = run.text();
    assert!(
        out.contains("give the config, `supervisor run CONFIG --resume day1.mcap`"),
        "{out}"
    );
    let mut run = Run::start(
        &scratch,
        1502,
        &[&["config/reach.toml"][..], &resume].concat(),
    );
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(scratch.path("day2.mcap").is_file());
    assert_nothing_left(&run);
}

/// A run's length typed as `--updates` is named as that option, not as `run.updates` of a file
/// that says otherwise: the resume with nothing left to run said "… has run.updates = 5", and
/// the note on a change scheduled past the run's end "(run.updates = 2)" of a config whose
/// `updates = 40`.
#[test]
fn a_length_given_as_updates_is_named_as_the_option() {
    let scratch = Scratch::new("h3-updates-option");
    let first = scratch.path("first.mcap");
    let text = config(&[("updates = 40", "updates = 5")]);
    let cfg = RunConfig::parse(&text, Path::new("short.toml")).unwrap();
    let mut rec = record::McapRecorder::create(&first)
        .unwrap()
        .with_config_text(text);
    session::run_session(&cfg, 1, &mut rec).unwrap();
    rec.finish().unwrap();
    let first_s = first.to_str().unwrap();
    let mut run = Run::start(&scratch, 1820, &["--resume", first_s, "--updates", "5"]);
    assert!(!run.wait(Duration::from_secs(30)).success());
    assert!(
        run.text()
            .contains("ends with update 4, and --updates 5 was given: nothing left to run"),
        "{}",
        run.text()
    );
    // The default config's change at update 20, past the end of 2 updates.
    let mut run = Run::start(
        &scratch,
        1821,
        &["--updates", "2", "--quiet", "--no-record"],
    );
    run.wait_exit(Duration::from_secs(60), 0);
    assert!(
        run.text()
            .contains("is not before the run's end (--updates 2): viapoint = 0.1"),
        "{}",
        run.text()
    );
}

/// A lost worker's chunk: the rollouts it reported sent (`Ready::rollout_done`) are not handed
/// out again while the update can finish without them. Before, the whole chunk went back to the
/// queue, so finished rollouts ran again (on a robot, for real), and a worker that hung every
/// few rollouts, fewer than a chunk, kept an update from ever finishing (found by a user test).
/// Here every first incarnation hangs in its chunk's second rollout in update 3 (chunks of 2):
/// only those three rollouts may run twice.
#[test]
fn a_lost_workers_finished_rollouts_do_not_run_again() {
    let scratch = Scratch::new("hung-finished");
    let text = config(&[
        ("updates = 40", "updates = 6"),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 20.0",
        ),
        (
            "max_workers = 16",
            "max_workers = 16\nrollout_timeout_ms = 400\nfault_hang_at_update = 3\n\
             fault_hang_at_chunk_rollout = 2",
        ),
    ]);
    let cfg = write_config(&scratch, "hung-finished.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = start_traced(&scratch, 1921, &cfg, &result);
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    // The sampler's trace: "<µs> dist 3 idle …", then "<µs> chunk N -> wW: [k, …]".
    let mut update = None;
    let mut handed = vec![0u32; 15];
    for line in out.lines() {
        let mut words = line
            .split_whitespace()
            .skip_while(|w| !w.starts_with("dist") && !w.starts_with("chunk"));
        match (words.next(), words.next()) {
            (Some("dist"), Some(u)) => update = u.parse::<u64>().ok(),
            (Some("chunk"), _) if update == Some(3) => {
                let list = line
                    .rsplit_once('[')
                    .map_or("", |(_, l)| l.trim_end_matches(']'));
                for k in list
                    .split(',')
                    .filter_map(|k| k.trim().parse::<usize>().ok())
                {
                    handed[k] += 1;
                }
            }
            _ => {}
        }
    }
    let hung: Vec<&str> = out.lines().filter(|l| l.contains(") hung: ")).collect();
    assert_eq!(hung.len(), 3, "{out}");
    let twice = handed.iter().filter(|&&n| n == 2).count();
    assert!(
        handed.iter().all(|&n| (1..=2).contains(&n)) && twice == 3,
        "update 3's rollouts handed out {handed:?} times:\n{out}"
    );
    assert_bit_identical(&text, &result);
    assert_nothing_left(&run);
}

/// A change that takes effect at update 0 (a schedule's `from_update = 0`, or a `supervisor
/// set` before the first update) is recorded as a `/task_change` at 0, as the in-process
/// runner records it: the pipeline's recorder compared the first update with nothing, so the
/// same run analysed without a change marker and its config's value in view (found comparing
/// `analyze` of both recordings).
#[test]
fn a_change_at_update_0_is_recorded_as_in_process() {
    let scratch = Scratch::new("change-at-0");
    let text = config(&[
        ("updates = 40", "updates = 3"),
        ("from_update = 20", "from_update = 0"),
    ]);
    let cfg_path = write_config(&scratch, "at0.toml", &text);
    let in_process = scratch.path("in-process.mcap");
    let cfg = RunConfig::parse(&text, &cfg_path).unwrap();
    let mut rec = record::McapRecorder::create(&in_process).unwrap();
    session::run_session(&cfg, cfg.run.seed, &mut rec).unwrap();
    rec.finish().unwrap();
    let mut run = Run::start(&scratch, 6000, &[cfg_path.to_str().unwrap(), "--quiet"]);
    run.wait_exit(Duration::from_secs(60), 0);
    let changes = |p: &Path| -> Vec<(u64, String, f64)> {
        record::read_recording(p)
            .unwrap()
            .task_changes
            .iter()
            .map(|c| (c.update, c.name.clone(), c.value))
            .collect()
    };
    let expected = vec![(0, "viapoint".to_string(), 0.1)];
    assert_eq!(changes(&in_process), expected);
    assert_eq!(
        changes(&scratch.recording("A1", 6000)),
        expected,
        "{}",
        run.text()
    );
}

/// `supervisor stop --after-update`, for rollouts that take a robot seconds: the update under
/// way finishes, every one of its rollouts, and no rollout of the next begins (the task counts
/// the rollouts it ran); the recording ends with that update and says where a resumed run goes
/// on, a `set` given in it is kept for the next, and `--resume` ends exactly where the run
/// without the stop does. A plain `stop` would have thrown the update's finished rollouts away.
#[test]
fn stop_after_update_finishes_the_update_under_way_and_resumes_to_the_uninterrupted_result() {
    let scratch = Scratch::new("stop-after-update");
    let ran = scratch.path("ran");
    let text = python_task_config(
        &scratch,
        "counted",
        r#"class Task(reach_worker.Reach):
    def rollout(self, theta):
        time.sleep(0.03)
        with open(os.environ.get("RAN_LOG", os.devnull), "a") as f:
            f.write("rollout\n")
        return super().rollout(theta)"#,
        &[("updates = 80", "updates = 14")],
    );
    let cfg = write_config(&scratch, "reach.toml", &text);
    let (first, result) = (scratch.path("first.mcap"), scratch.path("first.toml"));
    let mut run = Run::start_with_env(
        &scratch,
        28000,
        &[
            cfg.to_str().unwrap(),
            "--record",
            first.to_str().unwrap(),
            "--result",
            result.to_str().unwrap(),
        ],
        &[("RAN_LOG", ran.to_str().unwrap())],
    );
    run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let set = run.ctl_ok(&["set", "target_y", "0.74"]);
    let reply = run.ctl_ok(&["stop", "--after-update"]);
    assert!(
        reply.contains("stopping after the update under way"),
        "{reply}"
    );
    let again = run.ctl_ok(&["stop", "--after-update"]);
    assert!(again.contains("already"), "{again}");
    run.wait_exit(Duration::from_secs(60), 0);
    let out = run.text();
    let last: u64 = out
        .lines()
        .find_map(|l| {
            l.strip_prefix("[updater] stopping as requested: update ")?
                .split_once(' ')?
                .0
                .parse()
                .ok()
        })
        .unwrap_or_else(|| panic!("the updater did not say where it stopped:\n{out}"));
    assert!((3..13).contains(&last), "{out}");
    let from = takes_effect_from(&set);
    assert!(
        from <= last + 1,
        "set from {from}, stopped after {last}\n{out}"
    );
    let said = format!(
        "stopped on request after update {last} (`supervisor stop --after-update`): no rollout \
         was thrown away; `supervisor run --resume {}` goes on with update {}",
        first.display(),
        last + 1
    );
    assert!(out.contains(&said), "{out}");
    // Every rollout run is in a recorded update: none of the stopped update's was lost, none
    // of the next one's began.
    let rec = record::read_recording(&first).unwrap();
    assert!(rec.indexed, "{out}");
    assert_eq!(update_indices(&rec), (0..=last).collect::<Vec<_>>());
    assert_recomputes(&rec);
    let unfinished = rec.unfinished.as_ref().unwrap();
    assert_eq!((unfinished.update, unfinished.not_begun), (last + 1, true));
    let executions = std::fs::read_to_string(&ran).unwrap().lines().count() as u64;
    assert_eq!(executions, 10 * (last + 1), "{out}");
    assert_eq!(RunResult::read(&result).unwrap().updates, last + 1);

    // Resumed: it goes on with the next update, with the change, to the end of the run without
    // the stop.
    let (resumed_rec, resumed) = (scratch.path("resumed.mcap"), scratch.path("resumed.toml"));
    let mut again = Run::start(
        &scratch,
        28001,
        &[
            "--resume",
            first.to_str().unwrap(),
            "--quiet",
            "--record",
            resumed_rec.to_str().unwrap(),
            "--result",
            resumed.to_str().unwrap(),
        ],
    );
    again.wait_exit(Duration::from_secs(60), 0);
    let said = format!("resumed at update {} from {}", last + 1, first.display());
    assert!(again.text().contains(&said), "{}", again.text());
    let r = record::read_recording(&resumed_rec).unwrap();
    assert_eq!(update_indices(&r), (last + 1..14).collect::<Vec<_>>());
    let reference =
        format!("{text}\n[[schedule]]\nfrom_update = {from}\nset = \"target_y\"\nvalue = 0.74\n");
    let (_, _, uninterrupted) = run_to_its_end(&scratch, 28002, &reference);
    let (mean, cov) = RunResult::read(&resumed).unwrap().exact().unwrap();
    let (mean0, cov0) = uninterrupted.exact().unwrap();
    assert_eq!(bits(&mean), bits(&mean0));
    assert_eq!(bits(&cov), bits(&cov0));
    assert_nothing_left(&again);
}

/// `supervisor stop --after-update` while a stalled recorder holds the updater back: the
/// distribution held back has not begun (no rollout of it was handed out), so the run stops
/// before it at once, and a resumed run begins with it and ends where the in-process run does.
#[test]
fn stop_after_update_with_the_next_distribution_held_back_stops_before_it() {
    let scratch = Scratch::new("stop-after-update-held");
    let text = config(&[UNBOUNDED, DELAYED]);
    let cfg = write_config(&scratch, "held.toml", &text);
    let (first, result) = (scratch.path("first.mcap"), scratch.path("first.toml"));
    let mut run = start_recorded(&scratch, 28003, &cfg, &first, &result);
    let status = run.wait_status("3 updates", |s| updates_in(s) >= 3);
    let recorder = pid_of(&status, "recorder");
    signal(recorder, "-STOP");
    // Held back: the updates stop coming.
    let end = Instant::now() + Duration::from_secs(30);
    let mut seen = updates_in(&run.ctl_ok(&["status"]));
    loop {
        std::thread::sleep(Duration::from_millis(500));
        let now = updates_in(&run.ctl_ok(&["status"]));
        if now == seen {
            break;
        }
        assert!(Instant::now() < end, "the updater was never held back");
        seen = now;
    }
    run.ctl_ok(&["stop", "--after-update"]);
    let said = "[updater] stop requested: the run stops before update ";
    run.wait_output(said, end);
    signal(recorder, "-CONT");
    run.wait_exit(Duration::from_secs(30), 0);
    let out = run.text();
    let held: u64 = out
        .lines()
        .find_map(|l| l.strip_prefix(said)?.split_once(',')?.0.parse().ok())
        .unwrap();
    assert!(held > 3, "{out}");
    let rec = record::read_recording(&first).unwrap();
    assert_eq!(update_indices(&rec), (0..held).collect::<Vec<_>>(), "{out}");
    assert_recomputes(&rec);
    assert!(out.contains(&format!(
        "stopped on request after update {} (`supervisor stop --after-update`)",
        held - 1
    )));

    let resumed = scratch.path("resumed.toml");
    let updates = (held + 3).to_string();
    let mut again = Run::start(
        &scratch,
        28004,
        &[
            "--resume",
            first.to_str().unwrap(),
            "--updates",
            &updates,
            "--quiet",
            "--no-record",
            "--result",
            resumed.to_str().unwrap(),
        ],
    );
    again.wait_exit(Duration::from_secs(60), 0);
    let (mean, cov) = RunResult::read(&resumed).unwrap().exact().unwrap();
    let (mean0, cov0) = in_process(&text, held + 3);
    assert_eq!(bits(&mean), bits(&mean0));
    assert_eq!(bits(&cov), bits(&cov0));
    assert_nothing_left(&again);
}

/// Ctrl-C after `supervisor stop --after-update`, before the update under way is done, ends the
/// run as Ctrl-C does: that update's finished rollouts are thrown away, and the run is
/// interrupted (exit 130). The summary said `stopped on request after update N (`supervisor
/// stop --after-update`): no rollout was thrown away`, with exit 0, and the recorder was waited
/// for as if the updater had ended the run.
#[test]
fn a_signal_before_the_update_under_way_is_done_interrupts_a_stop_after_update() {
    let scratch = Scratch::new("stop-after-update-sigint");
    let text = config(&[
        UNBOUNDED,
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 300.0",
        ),
    ]);
    let cfg = write_config(&scratch, "slow.toml", &text);
    let (mcap, result) = (scratch.path("run.mcap"), scratch.path("result.toml"));
    let mut run = start_recorded(&scratch, 28100, &cfg, &mcap, &result);
    run.wait_status("1 update", |s| updates_in(s) >= 1);
    // 15 rollouts of 0.3 s on 3 workers: the update just begun has 1.5 s to go.
    let reply = run.ctl_ok(&["stop", "--after-update"]);
    assert!(
        reply.contains("stopping after the update under way"),
        "{reply}"
    );
    signal(run.child.id(), "-INT");
    run.wait_exit(Duration::from_secs(30), 130);
    let out = run.text();
    assert!(out.contains("[supervisor] interrupted"), "{out}");
    assert!(!out.contains("no rollout was thrown away"), "{out}");
    let r = RunResult::read(&result).unwrap();
    assert!(!r.complete, "{out}");
    let rec = record::read_recording(&mcap).unwrap();
    assert_recorded(&rec, r.updates);
    assert_nothing_left(&run);
}

/// With rollouts that take a robot seconds, an update takes minutes: `status` shows how many of
/// its rollouts are done, and an update under way for longer than 10 s gets a line of its own
/// when that number changes (before, nothing was said between two updates' lines, and a first
/// update of 15 one-second rollouts was warned of at 10 s as `a worker may hang`).
#[test]
fn the_rollouts_done_of_a_long_update_are_shown() {
    let scratch = Scratch::new("under-way");
    let text = config(&[
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 1000.0",
        ),
        ("workers = 3", "workers = 1"),
    ]);
    let cfg = write_config(&scratch, "long.toml", &text);
    let result = scratch.path("result.toml");
    let mut run = Run::start(
        &scratch,
        28005,
        &[
            cfg.to_str().unwrap(),
            "--no-record",
            "--result",
            result.to_str().unwrap(),
        ],
    );
    let status = run.wait_status("2 rollouts done", |s| {
        s.contains("update 0 (the 1st of 40) under way: 2 of 15 rollouts done, for ")
    });
    // No update is done yet: no rate, no last update (it read `0 updates/s, the last 1.1 s
    // ago`, the time since the first rollout's report).
    assert!(
        status.contains("updates: 0 of 40, none made yet\ncurrent cost: none yet\n"),
        "{status}"
    );
    // The first update has been under way since the run started, for 2 rollouts of 1 s at
    // least; the first rollout's report reset that time, which then read about 1 s.
    let under_way: f64 = status
        .split("rollouts done, for ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("{status}"));
    assert!(under_way >= 2.0, "{status}");
    let end = Instant::now() + Duration::from_secs(30);
    run.wait_output("[supervisor] update 0 (the 1st of 40) under way: ", end);
    let out = run.text();
    let line = out
        .lines()
        .find(|l| l.starts_with("[supervisor] update 0 (the 1st of 40) under way: "))
        .unwrap();
    let done: u32 = line
        .split(": ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{line}"));
    // About 10 s in, at 1 s a rollout.
    assert!((9..=12).contains(&done), "{line}");
    assert!(!out.contains("no update finished yet"), "{out}");
    // Rollouts coming in are no stall, though the update takes longer than the 10 s after
    // which a first update without rollouts is warned of.
    assert!(!out.contains("warning: no update for"), "{out}");
    run.ctl_ok(&["stop"]);
    run.wait_exit(Duration::from_secs(20), 0);
    assert_nothing_left(&run);
}

/// A Python task that fails the same way at every restart prints its traceback once: each
/// later incarnation says it is the same (it printed the whole traceback at every restart,
/// burying the run's other lines). Failures that differ are each printed in full.
#[test]
fn a_python_task_failing_alike_at_every_restart_prints_its_traceback_once() {
    let scratch = Scratch::new("python-same-traceback");
    for (id, message, full) in [
        (28006, r#""simulator exploded""#, 1),
        // Each incarnation's message is its own: every traceback differs, all are printed.
        (
            28007,
            r#""simulator exploded in incarnation " + sys.argv[sys.argv.index("--incarnation") + 1]"#,
            3,
        ),
    ] {
        let text = python_task_config(
            &scratch,
            &format!("explodes{full}"),
            &format!(
                r#"class Task(reach_worker.Reach):
    def rollout(self, theta):
        self.n = getattr(self, "n", 0) + 1
        if self.n > 3:
            raise RuntimeError({message})
        return super().rollout(theta)"#
            ),
            &[("workers = 2", "workers = 1\nrestart_limit = 2")],
        );
        let cfg = write_config(&scratch, &format!("explodes{full}.toml"), &text);
        let mut run = Run::start(&scratch, id, &[cfg.to_str().unwrap(), "--no-record"]);
        run.wait_exit(Duration::from_secs(60), 1);
        let out = run.text();
        let count = |what: &str| out.matches(what).count();
        // Three incarnations (the first and two restarts), each failing.
        assert_eq!(count("[worker-0] error: explodes"), 3, "{out}");
        assert_eq!(count("Traceback (most recent call last)"), full, "{out}");
        assert_eq!(
            count("(the same traceback as incarnation "),
            3 - full,
            "{out}"
        );
        if full == 1 {
            assert!(
                out.contains("(the same traceback as incarnation 1's, printed before)"),
                "{out}"
            );
        }
        assert_nothing_left(&run);
    }
}
