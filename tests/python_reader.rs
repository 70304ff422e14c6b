//! The proof that recordings are readable by tools other than ours: `tools/plot_learning_curve.py`
//! (PyPI `mcap` + `mcap-protobuf-support` only, no pi2cma code) decodes every topic of a run the
//! `pi2cma` binary recorded, checks its invariants and draws the learning curve.
//! Needs `python3 -m pip install -r tools/requirements.txt` (the README's test command does it).

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "scratch.rs"]
mod common;
#[path = "config_edit.rs"]
mod config_edit;

/// An empty scratch directory `name`.
fn scratch(name: &str) -> PathBuf {
    common::scratch(&format!("python-{name}"))
}

/// `pi2cma run ARGS` in `dir`, which must succeed.
fn pi2cma_run(dir: &Path, args: &[&str]) {
    let run = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .arg("run")
        .args(args)
        .current_dir(dir)
        .output()
        .expect("pi2cma starts");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// `python3 tools/TOOL ARGS` in `dir`: whether it succeeded, and its stdout and stderr.
fn python_tool(tool: &str, args: &[&str], dir: &Path) -> (bool, String) {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let out = Command::new("python3")
        .arg(repo.join("tools").join(tool))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("python3 starts (then: python3 -m pip install -r tools/requirements.txt)");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

#[test]
fn python_reader_decodes_every_topic_of_a_run() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = scratch("python-reader");
    pi2cma_run(&dir, &["--quiet", "--out", "."]);
    let mcap = dir.join("run.mcap");
    let svg = dir.join("curve.svg");
    let out = Command::new("python3")
        .arg(repo.join("tools/plot_learning_curve.py"))
        .arg(&mcap)
        .arg("--check")
        .arg("-o")
        .arg(&svg)
        .output()
        .expect(
            "python3 starts (install it, then: python3 -m pip install -r tools/requirements.txt)",
        );
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(
        out.status.success(),
        "the Python reader failed (are tools/requirements.txt installed?)\n{stdout}\n{stderr}"
    );
    // The default run: 40 updates of K = 15 rollouts, one task change, start and exit events.
    for decoded in [
        "/run 1",
        "/update 40",
        "/summary 40",
        "/rollout 600",
        "/task_change 1",
        "/log 2",
    ] {
        assert!(
            stdout.contains(decoded),
            "expected `{decoded}` decoded:\n{stdout}"
        );
    }
    assert!(
        svg.metadata().map(|m| m.len() > 1000).unwrap_or(false),
        "no figure written"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A recording without step costs (`recording.step_costs = false`) reads and checks in Python
/// too: `plot_learning_curve.py --check` takes `cost_total` for the trajectories (and checks
/// `eval_cost` against it), and the independent `check_update.py` recomputes every update from
/// the totals.
#[test]
fn python_tools_read_and_recompute_a_recording_without_step_costs() {
    let dir = scratch("python-no-step-costs");
    let text = format!(
        "{}\n[recording]\nstep_costs = false\n",
        session::DEFAULT_CONFIG
    );
    std::fs::write(dir.join("light.toml"), text).expect("write config");
    pi2cma_run(&dir, &["light.toml", "--quiet", "--out", "."]);
    let steps = record::read_recording(&dir.join("run.mcap"))
        .expect("read")
        .updates[5]
        .cost_per_step
        .len();
    assert_eq!(steps, 0);
    let (ok, out) = python_tool(
        "plot_learning_curve.py",
        &["run.mcap", "--check", "-o", "curve.svg"],
        &dir,
    );
    assert!(
        ok && out.contains("/update 40") && out.contains("1 passed"),
        "{out}"
    );
    let (ok, out) = python_tool("check_update.py", &["run.mcap"], &dir);
    assert!(ok && out.contains("40 updates: agrees"), "{out}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The parts of a split recording (`recording.split_mb`), read by the Python tool as one run
/// (`--join`): every part checks by itself, each goes on where the one before ends, and one
/// curve is drawn; given out of order, the seams fail.
#[test]
fn python_reader_joins_the_parts_of_a_split_recording() {
    let dir = scratch("python-join");
    let config = format!(
        "{}\n[recording]\nsplit_mb = 1\n",
        config_edit::edited(
            session::DEFAULT_CONFIG,
            &[("updates = 40", "updates = 200")]
        )
    );
    std::fs::write(dir.join("split.toml"), config).expect("config");
    pi2cma_run(&dir, &["split.toml", "--quiet", "--out", "out"]);
    let parts = ["out/run.mcap", "out/run.part-2.mcap", "out/run.part-3.mcap"];
    let python = |files: &[&str]| {
        let args = [&["--join", "--check", "-o", "joined.svg"], files].concat();
        python_tool("plot_learning_curve.py", &args, &dir)
    };
    let (ok, text) = python(&parts);
    assert!(ok, "{text}");
    assert!(text.contains("joined 3 files: updates 0..199"), "{text}");
    assert!(text.contains("3 passed, 0 failed, join passed"), "{text}");
    assert!(dir.join("joined.svg").is_file());
    std::fs::remove_file(dir.join("joined.svg")).unwrap();
    // Out of order: the summary says the join failed, and no figure is drawn.
    let (ok, text) = python(&[parts[1], parts[0], parts[2]]);
    assert!(!ok && text.contains("does not go on where"), "{text}");
    assert!(
        text.contains("join failed") && !text.contains("joined 3 files"),
        "{text}"
    );
    assert!(!dir.join("joined.svg").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `pi2cma_worker.serve(make_task)` calls `make_task(shape)` when its first parameter must be
/// given or is named `shape`, else `make_task()`: the README's `serve(MyTask)` with a plain
/// `__init__(self)` failed with a TypeError in every restart of the worker, and one with only
/// options (`gain=1.0`) got the shape as its gain.
#[test]
fn python_worker_builds_tasks_with_or_without_the_shape() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let script = r#"
import sys
sys.path.insert(0, sys.argv[1])
import pi2cma_worker as w
class Plain:
    def __init__(self): pass
class WithShape:
    def __init__(self, shape): pass
class Options:
    def __init__(self, gain=1.0): pass
class OptionalShape:
    def __init__(self, shape=None, gain=1.0): pass
def plain(): pass
def with_shape(shape): pass
def needs_two(shape, other): pass
cases = (Plain, WithShape, Options, OptionalShape, plain, with_shape, needs_two, print)
got = [w._takes_an_argument(f) for f in cases]
assert got == [False, True, False, True, False, True, True, True], got
print("ok")
"#;
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(repo.join("tools"))
        .output()
        .expect("python3 starts");
    assert!(
        out.status.success() && out.stdout.starts_with(b"ok"),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `pi2cma_worker` refuses a task whose `parameters`, `steps` or `settings` is a method (the Rust
/// trait's form), missing, or `settings` not a dict, naming the attribute, as a shape mismatch
/// (exit 78, not restarted): it failed with `TypeError: 'method' object is not iterable` or an
/// AttributeError and was restarted up to the restart limit.
#[test]
fn python_worker_names_a_shape_attribute_of_the_wrong_kind() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let script = r#"
import sys, types
sys.path.insert(0, sys.argv[1])
import pi2cma_worker as w
shape = types.SimpleNamespace(parameters=2, steps=3, settings=["x"], basis_activations=None, origin="c.toml")
class Good:
    parameters, steps, settings = 2, 3, {"x": 0.0}
    def set(self, name, value): pass
w._check_shape(Good(), shape)
class SettingsMethod(Good):
    def settings(self): return {"x": 0.0}
class StepsMethod(Good):
    def steps(self): return 3
class SettingsList(Good):
    settings = [("x", 0.0)]
class NoSettings:
    parameters, steps = 2, 3
for case in (SettingsMethod, StepsMethod, SettingsList, NoSettings):
    try:
        w._check_shape(case(), shape)
        print(case.__name__, "passed")
    except w.ConfigRefused as e:
        print(case.__name__, e)
"#;
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(repo.join("tools"))
        .output()
        .expect("python3 starts");
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    for expected in [
        "SettingsMethod the task's `settings` is a method: it must be a dict",
        "StepsMethod the task's `steps` is a method: it must be N, the number of step costs",
        "SettingsList the task's `settings` is [('x', 0.0)]: it must be a dict",
        "NoSettings the task has no attribute `settings`: it must be a dict",
    ] {
        assert!(text.contains(expected), "{expected:?} not in:\n{text}");
    }
}

/// A run that ended before its first update (stopped at once, or a worker that could not start)
/// leaves its /run and events, or its events alone: `analyze` reads both, and so must `--check`
/// (it failed them: "topic /update is missing", "no /update messages").
#[test]
fn python_check_accepts_a_recording_without_updates_as_analyze_does() {
    let dir = scratch("python-no-updates");
    let cfg = session::RunConfig::default_config();
    let hp = cfg.hyperparameters();
    let initial = pi2cma::Distribution {
        mean: nalgebra::DVector::from_vec(vec![0.5, -2.0]),
        covariance: nalgebra::DMatrix::from_row_slice(2, 2, &[3.0, 0.0, 0.0, 3.0]),
    };
    let text = record::config_to_toml(&cfg);
    let write = |name: &str, with_run: bool| {
        let path = dir.join(name);
        let mut w = record::RunWriter::create(&path).expect("create");
        if with_run {
            w.write_start(&record::RunStart {
                name: "A1",
                seed: 1,
                update: 0,
                steps: 101,
                hyperparameters: &hp,
                initial: &initial,
                basis_activations: None,
                config_toml: &text,
                executor: "pipeline",
                task_settings: &[],
                previous_task_settings: &[],
                resumed_from: None,
                part: None,
                run_id: None,
                recorder_restart: None,
            })
            .expect("run");
        }
        w.write_event(0, record::Event::Crash, "worker-0", 7, "worker-0 crashed")
            .expect("event");
        w.finish().expect("finish");
        path
    };
    for file in [write("stopped.mcap", true), write("events.mcap", false)] {
        let analyze = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
            .arg("analyze")
            .arg(&file)
            .output()
            .expect("pi2cma starts");
        let summary = String::from_utf8_lossy(&analyze.stdout);
        assert!(analyze.status.success(), "{summary}");
        let name = file.file_name().and_then(|n| n.to_str()).expect("a name");
        let (ok, text) = python_tool("plot_learning_curve.py", &["--check", name], &dir);
        assert!(ok, "{}: {text}", file.display());
        assert!(text.contains("1 passed, 0 failed"), "{text}");
        // check_update.py has nothing to recompute there, and says so (it failed with a
        // TypeError traceback on the file without /run, and said "DISAGREES" of the other).
        let (ok, text) = python_tool("check_update.py", &[name], &dir);
        assert!(
            !ok && text.contains("no update recorded")
                && text.contains("without an update to recompute")
                && !text.contains("Traceback")
                && !text.contains("DISAGREES"),
            "{}: {text}",
            file.display()
        );
    }
}

/// Writes `src` to `dst` with the lowest bit of a step cost of update 10 flipped: a damaged
/// chunk, as a bad sector or a bad copy leaves it.
fn damage_a_step_cost(src: &Path, dst: &Path) {
    // Its bytes are stored as they are (zstd literals), once.
    let cost = record::read_recording(src).expect("read").updates[10].cost_per_step[37];
    let mut bytes = std::fs::read(src).expect("read the file");
    let at = bytes
        .windows(8)
        .position(|w| w == cost.to_le_bytes())
        .expect("the step cost's bytes are in the file");
    bytes[at] ^= 1;
    std::fs::write(dst, &bytes).expect("write the damaged file");
}

/// A damaged chunk (a bad sector, a bad copy) is an error naming the file, never other numbers
/// (README, "Nothing lost"): the `mcap` package checks no CRC unless asked, so a step cost with
/// its lowest byte flipped was read as another number, `--check` passed ("1 passed, 0 failed")
/// and `check_update.py` agreed.
#[test]
fn python_tools_refuse_a_damaged_chunk_as_ours_do() {
    let dir = scratch("damaged");
    pi2cma_run(&dir, &["--quiet", "--out", "."]);
    let mcap = dir.join("run.mcap");
    damage_a_step_cost(&mcap, &mcap);
    assert!(
        record::read_recording(&mcap).is_err(),
        "our reader must see the damage"
    );
    for (tool, args) in [
        ("plot_learning_curve.py", &["--check", "run.mcap"][..]),
        ("check_update.py", &["run.mcap"]),
    ] {
        let (ok, text) = python_tool(tool, args, &dir);
        assert!(!ok, "{tool} passed a damaged file:\n{text}");
        assert!(
            text.contains("run.mcap: damaged"),
            "{tool} does not name the damage:\n{text}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Rewrites the recording `src` into `dst` with update 1's terminal cost of rollout 3 raised by
/// 1, through the PyPI `mcap` package: every chunk's CRC is right, the numbers are not.
const TAMPER: &str = r#"
import sys
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory

src, dst = sys.argv[1], sys.argv[2]
with open(src, "rb") as f, open(dst, "wb") as o:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    w = Writer(o)
    w.start(reader.get_header().profile, "tamper")
    schemas, channels = {}, {}
    for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channels:
            channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                      schemas[schema.id], channel.metadata)
        data = message.data
        if channel.topic == "/update" and decoded.update == 1:
            decoded.cost_terminal[3] += 1.0
            data = decoded.SerializeToString()
        w.add_message(channels[channel.id], message.log_time, data, message.publish_time,
                      message.sequence)
    w.finish()
"#;

/// [`TAMPER`] of `src` into `dst`, both in `dir`; its stderr, inherited, is in the test's output.
fn tamper(dir: &Path, src: &str, dst: &str) {
    let status = Command::new("python3")
        .args(["-c", TAMPER, src, dst])
        .current_dir(dir)
        .status()
        .expect("python3 starts");
    assert!(status.success(), "the tampering script failed");
}

/// Given several files, `check_update.py` checks each and names every one that failed: it
/// stopped at the first damaged file (`sys.exit` from its reader), so the files after it were
/// never recomputed, and a missing file ended it with a traceback, as did a file that is not
/// MCAP (`struct.error` from inside the `mcap` package).
#[test]
fn check_update_checks_every_file_and_names_each_that_failed() {
    let dir = common::scratch("h3-check-update-several");
    pi2cma_run(&dir, &["--quiet", "--out", "."]);
    damage_a_step_cost(&dir.join("run.mcap"), &dir.join("damaged.mcap"));
    tamper(&dir, "run.mcap", "disagrees.mcap");
    std::fs::write(dir.join("notes.mcap"), "not a recording\n").expect("write");
    std::fs::write(dir.join("empty.mcap"), "").expect("write");
    let files = [
        "damaged.mcap",
        "notes.mcap",
        "run.mcap",
        "empty.mcap",
        "disagrees.mcap",
        "missing.mcap",
    ];
    let (ok, text) = python_tool("check_update.py", &files, &dir);
    assert!(!ok, "check_update.py passed:\n{text}");
    assert!(!text.contains("Traceback"), "{text}");
    assert!(text.contains("damaged.mcap: damaged"), "{text}");
    // The good file and the one after the damaged file were recomputed.
    assert!(text.contains("6 recording(s), 80 updates"), "{text}");
    assert!(
        text.contains("notes.mcap: not an MCAP file (it does not begin with the MCAP magic")
            && text.contains("empty.mcap: not an MCAP file (it is empty)"),
        "{text}"
    );
    let failed = text
        .lines()
        .find(|l| l.starts_with("check_update: failed:"))
        .unwrap_or_else(|| panic!("no line naming the failed files:\n{text}"));
    for name in [
        "damaged.mcap (damaged",
        "disagrees.mcap (disagrees",
        "missing.mcap (",
        "notes.mcap (not MCAP)",
        "empty.mcap (not MCAP)",
    ] {
        assert!(failed.contains(name), "{name} not in {failed}\n{text}");
    }
    assert!(!failed.contains(" run.mcap"), "{failed}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A file that is not there, or not MCAP, is one line on stderr naming it and what is wrong,
/// with exit status 2 (a bad argument, as argparse exits): it was a Python traceback
/// (`FileNotFoundError`, `struct.error: unpack requires a buffer of 8 bytes`), with status 1.
/// An empty file passed as a recording with nothing decoded.
#[test]
fn plot_learning_curve_names_a_file_it_cannot_read() {
    let dir = common::scratch("h3-plot-unreadable");
    std::fs::write(dir.join("notes.mcap"), "not a recording\n").expect("write");
    std::fs::write(dir.join("empty.mcap"), "").expect("write");
    std::fs::create_dir(dir.join("folder.mcap")).expect("mkdir");
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    for (file, problem) in [
        (
            "missing.mcap",
            "missing.mcap: cannot be read: No such file or directory",
        ),
        ("notes.mcap", "notes.mcap: not an MCAP file"),
        ("empty.mcap", "empty.mcap: not an MCAP file"),
        ("folder.mcap", "folder.mcap: cannot be read: Is a directory"),
    ] {
        let out = Command::new("python3")
            .arg(repo.join("tools/plot_learning_curve.py"))
            .args(["--check", file])
            .current_dir(&dir)
            .output()
            .expect("python3 starts");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{file}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{file}: {stderr}");
        assert!(stderr.contains(problem), "{file}: {stderr}");
    }
}

/// CEM without bounds lets Σ collapse: by update 38 of this run the 14 exploration costs agree
/// to 13 digits (std 6·10⁻¹¹ on costs of 414). Their standard deviation then depends on the last
/// bits of each total, which the script sums in another order than we do, and it reported
/// "DISAGREES" (expl_std = 5.09e-04) of a run whose every update it recomputed to 10⁻¹⁴.
#[test]
fn check_update_agrees_with_a_run_whose_costs_collapse() {
    let dir = scratch("check-update-collapse");
    let config = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[
            ("method = \"pi2-cma\"", "method = \"cem\""),
            ("eliteness = 15.0", "elites = 4"),
            ("lambda_min = 2.0", "lambda_min = 0.0"),
            ("basis_functions = 2", "basis_functions = 20"),
        ],
    );
    std::fs::write(dir.join("cem.toml"), config).expect("config");
    pi2cma_run(&dir, &["cem.toml", "--quiet", "--out", "."]);
    let (ok, text) = python_tool("check_update.py", &["run.mcap"], &dir);
    assert!(ok, "{text}");
    assert!(text.contains("40 updates: agrees within 1e-09"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A resumed run's recording begins with the distribution the run had got to, not with the
/// minimum-jerk fit: `check_task_costs.py` checks its costs and says it does not check its
/// initial mean. It compared that mean with the fit and called every resumed recording wrong
/// (`initial mean=3.95e-01  >>> DISAGREES`).
#[test]
fn task_costs_of_a_resumed_recording_agree_and_its_initial_mean_is_not_the_fits() {
    let dir = scratch("task-costs-resumed");
    pi2cma_run(&dir, &["--quiet", "--updates", "5", "--out", "."]);
    pi2cma_run(
        &dir,
        &[
            "--resume",
            "run.mcap",
            "--updates",
            "8",
            "--quiet",
            "--out",
            "resumed",
        ],
    );
    let (ok, text) = python_tool(
        "check_task_costs.py",
        &["run.mcap", "resumed/run.mcap"],
        &dir,
    );
    assert!(ok, "{text}");
    assert!(
        text.contains("run.mcap: via-point, 5 updates: max rel diff initial mean=")
            && text.contains("resumed/run.mcap: via-point, 3 updates: max rel diff step costs=")
            && text.contains("(initial mean not checked: the recording begins at update 5)")
            && text.contains("2 recording(s): agree within 1e-09"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `tools/check_task_costs.py` rebuilds the DMP and the costs (Eq. 3, Eq. 4) from the paper and
/// the README, which `check_update.py` takes from the recording and so cannot check: the
/// via-point and T-ball costs of our runs agree with it, and a recording whose costs are not
/// the task's (rollout 3's terminal cost raised by 1) is named.
#[test]
fn task_costs_agree_with_an_independent_dmp_and_cost() {
    let dir = scratch("task-costs");
    pi2cma_run(&dir, &["--quiet", "--out", "."]);
    let tball = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/tball.toml"),
    )
    .expect("config/tball.toml");
    let tball = config_edit::edited(&tball, &[("updates = 40", "updates = 3")]);
    std::fs::write(dir.join("tball.toml"), tball).expect("config");
    pi2cma_run(&dir, &["tball.toml", "--quiet", "--out", "tball"]);
    let (ok, text) = python_tool("check_task_costs.py", &["run.mcap", "tball/run.mcap"], &dir);
    assert!(ok, "{text}");
    assert!(
        text.contains("run.mcap: via-point, 40 updates")
            && text.contains("tball/run.mcap: tball, 3 updates")
            && text.contains("2 recording(s): agree within 1e-09"),
        "{text}"
    );
    tamper(&dir, "run.mcap", "tampered.mcap");
    let (ok, text) = python_tool("check_task_costs.py", &["tampered.mcap"], &dir);
    assert!(!ok, "{text}");
    assert!(
        text.contains("terminal=1.00e+00  >>> DISAGREES")
            && text.contains("failed: tampered.mcap (disagrees)"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
