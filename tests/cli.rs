//! End-to-end tests of the `pi2cma` binary: the quick-start run, the paper configs, and the
//! errors a user sees for bad input. (Wired in as an integration test of crates/pi2cma-cli.)

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn pi2cma(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("pi2cma starts")
}

/// Asserts that a pi2cma command succeeded, showing its errors if not.
fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[path = "scratch.rs"]
mod common;
#[path = "config_edit.rs"]
mod config_edit;

fn scratch(name: &str) -> PathBuf {
    common::scratch(&format!("cli-{name}"))
}

#[test]
fn default_run_prints_progress_and_saves_results() {
    let d = scratch("run");
    let out = pi2cma(&["run", "--out", "res"], &d);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("update  40/40"), "{stdout}");
    assert!(stdout.contains("task change viapoint = 0.1"), "{stdout}");
    for f in ["updates.csv", "mean_curves.csv", "fig2.svg", "summary.md"] {
        let p = d.join("res").join(f);
        assert!(
            p.metadata().map(|m| m.len() > 100).unwrap_or(false),
            "{} missing",
            p.display()
        );
    }
    let csv = std::fs::read_to_string(d.join("res/updates.csv")).expect("csv");
    assert_eq!(csv.lines().count(), 41, "header + 40 updates");
    assert!(csv
        .lines()
        .nth(1)
        .is_some_and(|l| l.starts_with("A1,episodic,0,1,0,")));
}

/// Sends SIGINT, as Ctrl-C does, and waits for the exit.
fn interrupt(child: std::process::Child) -> Output {
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(sent.success());
    child.wait_with_output().expect("exit")
}

/// A closed stdout (`pi2cma run | head`) does not end the run, and SIGINT stops it after the
/// current update with a finished recording, the results so far and exit code 130. Before, the
/// first progress line after `head` exited panicked ("failed printing to stdout"), and SIGINT
/// killed the run, leaving an unindexed recording and no results.
#[test]
fn a_run_survives_a_closed_stdout_and_stops_cleanly_on_sigint() {
    use std::io::{BufRead, BufReader};
    let d = scratch("sigint");
    let mut child = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args(["run", "--out", "res", "--updates", "100000000"])
        .current_dir(&d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("pi2cma starts");
    let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
    for _ in 0..3 {
        lines.next().expect("a line").expect("utf-8");
    }
    drop(lines); // as `head -3` does
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(
        child.try_wait().expect("wait").is_none(),
        "the run ended with its stdout"
    );
    let out = interrupt(child);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    let mcap = std::fs::read(d.join("res/run.mcap")).expect("recording");
    // A finished MCAP ends with its footer and the magic; an abandoned one does not.
    assert!(mcap.ends_with(b"\x89MCAP0\r\n"), "recording not finished");
    let csv = std::fs::read_to_string(d.join("res/updates.csv")).expect("updates.csv");
    assert!(csv.lines().count() > 2, "{csv}");
}

/// SIGINT stops an experiment after the current update of its current session, with that
/// session's recording finished and exit code 130. Before, it killed the process and left an
/// unindexed recording.
#[test]
fn an_experiment_stops_cleanly_on_sigint() {
    let d = scratch("experiment-sigint");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[("updates = 40", "updates = 100000000")],
    );
    std::fs::write(d.join("long.toml"), text).expect("config");
    let child = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args([
            "experiment",
            "--sessions",
            "2",
            "--record",
            "--out",
            "res",
            "long.toml",
        ])
        .current_dir(&d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("pi2cma starts");
    let mcap = d.join("res/mcap/A1-seed1.mcap");
    let end = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while mcap.metadata().map_or(true, |m| m.len() < 100_000) {
        assert!(std::time::Instant::now() < end, "no recording");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = interrupt(child);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(130), "{stdout}");
    assert!(
        stdout.contains("interrupted in session A1 seed 1 after")
            && stdout.contains("its recording finished"),
        "{stdout}"
    );
    let bytes = std::fs::read(&mcap).expect("recording");
    assert!(bytes.ends_with(b"\x89MCAP0\r\n"), "recording not finished");
    assert!(
        !d.join("res/mcap/A1-seed2.mcap").exists(),
        "went on after SIGINT"
    );
}

/// A recording in a directory given by `--out` is never replaced; the default directory,
/// runs/latest, is the latest run's and is.
#[test]
fn a_recording_given_by_out_is_not_overwritten() {
    let d = scratch("no-overwrite");
    let first = pi2cma(&["run", "--out", "mine", "--updates", "3"], &d);
    assert!(first.status.success());
    let kept = std::fs::read(d.join("mine/run.mcap")).expect("recording");
    let again = pi2cma(
        &["run", "--out", "mine", "--updates", "3", "--seed", "2"],
        &d,
    );
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success()
            && err.contains("mine/run.mcap")
            && err.contains("is there already"),
        "{err}"
    );
    assert_eq!(std::fs::read(d.join("mine/run.mcap")).expect("kept"), kept);
    for seed in ["1", "2"] {
        let latest = pi2cma(&["run", "--updates", "3", "--seed", seed], &d);
        assert!(
            latest.status.success(),
            "{}",
            String::from_utf8_lossy(&latest.stderr)
        );
    }
}

/// `experiment --out D --record` checks every config and every recording it will write before
/// its first session: a clash found at the second config used to end the experiment after the
/// first config's sessions had run (hours, with the paper's session counts).
#[test]
fn an_experiment_refuses_before_its_first_session() {
    let d = scratch("experiment-refuses");
    let cfg = |name: &str| {
        let name_line = format!("name = \"{name}\"");
        let text = config_edit::edited(
            session::DEFAULT_CONFIG,
            &[
                ("name = \"A1\"", &name_line),
                ("updates = 40", "updates = 2"),
            ],
        );
        let path = d.join(format!("{name}.toml"));
        std::fs::write(&path, text).expect("config");
        path.to_string_lossy().into_owned()
    };
    let (one, two) = (cfg("one"), cfg("two"));
    std::fs::create_dir_all(d.join("res/mcap")).expect("dir");
    std::fs::write(d.join("res/mcap/two-seed1.mcap"), b"day 1").expect("clash");
    let experiment = |configs: &[&str]| {
        let mut args = vec!["experiment", "--sessions", "2", "--out", "res", "--record"];
        args.extend_from_slice(configs);
        pi2cma(&args, &d)
    };
    let refused = experiment(&[&one, &two]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("two-seed1.mcap") && !err.contains("running"),
        "{err}"
    );
    assert!(!d.join("res/mcap/one-seed1.mcap").exists(), "a session ran");
    assert_eq!(
        std::fs::read(d.join("res/mcap/two-seed1.mcap")).expect("kept"),
        b"day 1"
    );
    // The same config twice would record each session twice to one file.
    let refused = experiment(&[&one, &one]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("would both record to"),
        "{err}"
    );
    // Names that differ only where a file name takes `_` record to one file too, and the
    // error says so (it said "the same run.name" of two different ones).
    let refused = experiment(&[&cfg("day 1"), &cfg("day_1")]);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success()
            && err.contains("would both record to res/mcap/day_1-seed1.mcap (run.name \"day 1\" and \"day_1\" make the same file name"),
        "{err}"
    );
    // A bad config given last is found first too.
    let bad = d.join("bad.toml");
    std::fs::write(&bad, "[run\n").expect("bad config");
    let refused = experiment(&[&one, bad.to_str().expect("utf-8")]);
    assert!(!refused.status.success());
    assert!(!d.join("res/mcap/one-seed1.mcap").exists(), "a session ran");
}

#[test]
fn every_paper_config_is_valid() {
    let configs: Vec<String> = ["C1", "C2", "C3", "D", "A1", "A2", "A3", "A4"]
        .iter()
        .map(|c| {
            repo()
                .join(format!("config/{c}.toml"))
                .display()
                .to_string()
        })
        .collect();
    let mut args = vec!["check"];
    args.extend(configs.iter().map(String::as_str));
    let out = pi2cma(&args, &repo());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).matches(": ok").count(),
        8
    );
}

#[test]
fn bad_config_names_file_field_and_value() {
    let d = scratch("bad");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[("lambda_min = 2.0", "lambda_min = -3.0")],
    );
    std::fs::write(d.join("bad.toml"), text).expect("write");
    let out = pi2cma(&["run", "bad.toml"], &d);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("lambda_min") && err.contains("-3"),
        "{err}"
    );

    let text = config_edit::edited(session::DEFAULT_CONFIG, &[("[run]", "[run]\nsedd = 4")]);
    std::fs::write(d.join("typo.toml"), text).expect("write");
    let out = pi2cma(&["run", "typo.toml"], &d);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("typo.toml") && err.contains("unknown field `sedd`"),
        "{err}"
    );

    let out = pi2cma(&["run", "missing.toml"], &d);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.toml"));

    // `check` reports every bad file, not only the first, and still checks the good ones.
    std::fs::write(d.join("good.toml"), session::DEFAULT_CONFIG).expect("write");
    let out = pi2cma(&["check", "bad.toml", "typo.toml", "good.toml"], &d);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("bad.toml") && err.contains("typo.toml") && err.contains("2 of 3"),
        "{err}"
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("good.toml: ok"));
}

/// A config that cannot run in-process (an external task) is refused before anything in the
/// output directory is written: the previous run's recording and results stay.
#[test]
fn a_config_that_cannot_run_in_process_leaves_the_results_directory() {
    let d = scratch("keep");
    let out = pi2cma(&["run", "--updates", "3", "--out", "res"], &d);
    assert!(out.status.success());
    let before = std::fs::read(d.join("res/run.mcap")).expect("recording");
    let csv = std::fs::read(d.join("res/updates.csv")).expect("csv");
    let external = repo().join("config/external-reach.toml");
    let out = pi2cma(
        &["run", external.to_str().expect("utf-8"), "--out", "res"],
        &d,
    );
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("supervisor run"), "{stderr}");
    assert_eq!(
        std::fs::read(d.join("res/run.mcap")).expect("recording"),
        before
    );
    assert_eq!(std::fs::read(d.join("res/updates.csv")).expect("csv"), csv);
}

/// A bad value typed as an option is reported as that option, not as a field of the config
/// (`--updates 0` was `<built-in default>: run.updates = 0`).
#[test]
fn a_bad_option_value_is_reported_as_the_option() {
    let d = scratch("h2-options");
    let out = pi2cma(&["run", "--updates", "0", "--out", "res"], &d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("--updates 0: must be at least 1") && !stderr.contains("built-in"),
        "{stderr}"
    );
    let out = pi2cma(
        &["run", "--seed", "18446744073709551615", "--out", "res"],
        &d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("--seed 18446744073709551615: "),
        "{stderr}"
    );
    // Set by --weighting, the averaging an external task cannot have.
    let external = repo().join("config/external-reach.toml");
    let out = pi2cma(
        &[
            "experiment",
            external.to_str().expect("utf-8"),
            "--weighting",
            "per-time-step-basis-activation",
            "--out",
            "res",
        ],
        &d,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("--weighting per-time-step-basis-activation: "),
        "{stderr}"
    );
}

/// A negative number is a bad value of its option. Clap took `-1` for an unknown option and
/// advised `-- -1`, which would have made it the CONFIG (or the recording to analyse).
#[test]
fn a_negative_number_is_a_bad_value_of_its_option() {
    let d = scratch("negative-options");
    for (args, expected) in [
        (
            &["run", "--updates", "-1"][..],
            "invalid value '-1' for '--updates <UPDATES>'",
        ),
        (
            &["run", "--seed", "-1"],
            "invalid value '-1' for '--seed <SEED>'",
        ),
        (
            &["experiment", "a.toml", "--sessions", "-1"],
            "invalid value '-1' for '--sessions <SESSIONS>'",
        ),
        (
            &["analyze", "a.mcap", "--tolerance", "-0.1"],
            "invalid value '-0.1' for '--tolerance <TOLERANCE>': -0.1: must be at least 0",
        ),
    ] {
        let out = pi2cma(args, &d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(expected), "{args:?}: {stderr}");
    }
}

#[test]
fn unknown_option_is_rejected() {
    let out = pi2cma(&["run", "--lambda-min", "3"], &repo());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--lambda-min"));
}

/// The lines a successful `pi2cma run` ends with (final θ and λ).
fn final_lines(out: &Output) -> Vec<String> {
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
        .lines()
        .filter(|l| l.starts_with("final "))
        .map(str::to_string)
        .collect()
}

/// Stopped after 20 updates and resumed from its recording, a run ends with the bits of the
/// uninterrupted 40-update run; the resumed recording verifies and names its origin.
#[test]
fn a_run_resumed_from_its_recording_ends_as_the_uninterrupted_one() {
    let d = scratch("resume");
    let short = config_edit::edited(session::DEFAULT_CONFIG, &[("updates = 40", "updates = 20")]);
    std::fs::write(d.join("a20.toml"), short).expect("config");
    let whole = final_lines(&pi2cma(&["run", "--quiet", "--out", "whole"], &d));
    final_lines(&pi2cma(
        &["run", "a20.toml", "--quiet", "--out", "first"],
        &d,
    ));
    let refused = pi2cma(
        &["run", "--resume", "first/run.mcap", "--out", "second"],
        &d,
    );
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("nothing left to run (give more updates)"),
        "{err}"
    );
    let resume_to_40 = |out: &str| {
        let args = [
            "run",
            "--resume",
            "first/run.mcap",
            "--updates",
            "40",
            "--out",
            out,
        ];
        pi2cma(&args, &d)
    };
    let over = resume_to_40("first");
    let err = String::from_utf8_lossy(&over.stderr);
    assert!(err.contains("would record over it"), "{err}");
    let resumed = resume_to_40("second");
    let stdout = String::from_utf8_lossy(&resumed.stdout).to_string();
    assert!(stdout.contains("resumed at update 20 of 40"), "{stdout}");
    assert!(
        stdout.contains(&format!(
            "analyse it with: {} analyze first/run.mcap second/run.mcap",
            env!("CARGO_BIN_EXE_pi2cma")
        )),
        "{stdout}"
    );
    assert_eq!(final_lines(&resumed), whole);
    assert_eq!(whole.len(), 2, "{whole:?}");

    let verify = pi2cma(
        &[
            "analyze",
            "second/run.mcap",
            "--verify",
            "--no-plots",
            "--no-csv",
        ],
        &d,
    );
    let text = String::from_utf8_lossy(&verify.stdout);
    assert!(verify.status.success(), "{text}");
    assert!(
        text.contains("recompute: 20 updates, 0 mismatches"),
        "{text}"
    );
    // Absolute, as typed from here: read from another directory, `first/run.mcap` would name
    // another file.
    let meta = record::read_run_metadata(&d.join("second/run.mcap")).expect("metadata");
    let from = Path::new(&meta["resumed_from"]);
    assert!(
        from.is_absolute()
            && from.canonicalize().ok() == d.join("first/run.mcap").canonicalize().ok(),
        "{from:?}"
    );

    // Analysed together, in any order, the two files are one run: its per-rollout table is the
    // uninterrupted run's, byte for byte.
    let analyze = |files: &[&str], out: &str| {
        let args = [&["analyze"], files, &["--no-plots", "--out", out]].concat();
        let o = pi2cma(&args, &d);
        let text = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(
            o.status.success(),
            "{text}{}",
            String::from_utf8_lossy(&o.stderr)
        );
        text
    };
    let text = analyze(&["second/run.mcap", "first/run.mcap"], "joined");
    assert!(
        text.contains(
            "first/run.mcap + second/run.mcap: one run of 40 updates (0..=39), its files beginning at updates 0, 20"
        ),
        "{text}"
    );
    assert!(!text.contains("Experiment"), "{text}");
    // A copy of the first file beside both is read once, not joined in its place (which left
    // the original as a second session of an "experiment").
    std::fs::copy(d.join("first/run.mcap"), d.join("copy.mcap")).expect("copy");
    let text = analyze(
        &["first/run.mcap", "copy.mcap", "second/run.mcap"],
        "with-copy",
    );
    assert!(
        text.contains("copy.mcap is a copy of first/run.mcap")
            && text.contains("first/run.mcap + second/run.mcap: one run of 40 updates")
            && !text.contains("Experiment"),
        "{text}"
    );
    analyze(&["whole/run.mcap"], "whole-analysis");
    let table = |dir: &str| {
        std::fs::read_to_string(d.join(dir).join("run/update_rollouts.csv")).expect("csv")
    };
    let joined = table("joined");
    assert_eq!(joined.lines().count(), 1 + 40 * 15);
    assert!(
        joined == table("whole-analysis"),
        "the joined table differs"
    );
}

/// `--seed` and `--updates` go into the config the recording keeps, so the recorded config is
/// the run that was made: resumed with it, a run started with `--seed 5` goes on as seed 5.
#[test]
fn command_line_overrides_are_part_of_the_recorded_config() {
    let d = scratch("overrides");
    let run = |args: &[&str]| final_lines(&pi2cma(&[&["run", "--quiet"], args].concat(), &d));
    run(&["--seed", "5", "--updates", "12", "--out", "first"]);
    let resumed = run(&[
        "--resume",
        "first/run.mcap",
        "--updates",
        "25",
        "--out",
        "second",
    ]);
    let whole = run(&["--seed", "5", "--updates", "25", "--out", "whole"]);
    assert_eq!(resumed, whole);
    let default_seed = run(&["--updates", "25", "--out", "seed1"]);
    assert_ne!(default_seed, whole, "the seed changes the run");
}

/// `--quiet` leaves out the per-update lines, not the warnings: a rollout whose costs were not
/// finite and that is run again is printed (README, "Non-finite costs"), as `supervisor run
/// --quiet` prints it. It was printed only without `--quiet`.
#[test]
fn a_rerun_of_a_non_finite_rollout_is_printed_also_with_quiet() {
    let d = scratch("rerun-quiet");
    let text = std::fs::read_to_string(repo().join("config/A1.toml")).expect("A1");
    let text = text.replacen(
        "updates = 40",
        "updates = 10\nnonfinite_reruns = 2\nfault_nan_first_attempt = { update = 3, rollout = 7 }",
        1,
    );
    std::fs::write(d.join("rerun.toml"), text).expect("write config");
    let out = pi2cma(&["run", "rerun.toml", "--quiet", "--out", "res"], &d);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(
        stdout.contains(
            "update 3: cost of rollout 7 (terminal) is NaN; costs must be finite (attempt 1 of \
             at most 3, by in-process): rerunning it with the same parameters \
             (run.nonfinite_reruns = 2)"
        ),
        "{stdout}"
    );
    assert!(!stdout.contains("update   1/10"), "{stdout}");
}

/// An unbounded config (no `run.updates`) does not run in-process as it is; the refusal names
/// `--updates N`, which runs it here, and not only the supervisor (it named `--updates` only
/// when resuming).
#[test]
fn an_unbounded_config_is_refused_naming_updates() {
    let d = scratch("unbounded");
    let text = std::fs::read_to_string(repo().join("config/A1.toml")).expect("A1");
    std::fs::write(
        d.join("unbounded.toml"),
        text.replacen("updates = 40\n", "", 1),
    )
    .expect("write config");
    let out = pi2cma(&["run", "unbounded.toml", "--quiet", "--out", "res"], &d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("unbounded.toml: run.updates is not set")
            && stderr.contains("give --updates N"),
        "{stderr}"
    );
    let out = pi2cma(
        &[
            "run",
            "unbounded.toml",
            "--updates",
            "3",
            "--quiet",
            "--out",
            "res",
        ],
        &d,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `pi2cma run` ends with the final mean as the supervisor's summary shows it: a long one as
/// its first 3 values and the count (it printed all 400 values for P = 400); a short one whole,
/// as `a_run_resumed_from_its_recording_ends_as_the_uninterrupted_one` compares. A resumed run
/// too. The recording keeps the whole mean. P = 10: the run's summary searches the optimum
/// from the final mean, which takes minutes for P = 400.
#[test]
fn a_run_abbreviates_a_long_final_mean() {
    let d = scratch("long-mean");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[("basis_functions = 2", "basis_functions = 10")],
    );
    std::fs::write(d.join("long.toml"), text).expect("write config");
    let check = |args: &[&str], out: &str| {
        let lines = final_lines(&pi2cma(&[args, &["--quiet", "--out", out]].concat(), &d));
        let line = lines
            .iter()
            .find_map(|l| l.strip_prefix("final mean θ = "))
            .unwrap_or_else(|| panic!("no final mean: {lines:?}"));
        let rec = record::read_recording(&d.join(out).join("run.mcap")).expect("recording");
        let last = rec.updates.last().expect("an update");
        let mean = record::distribution_from_proto(last.after.as_ref().expect("after"))
            .expect("distribution")
            .mean;
        assert_eq!(mean.len(), 10);
        let first: Vec<String> = mean.iter().take(3).map(|v| format!("{v:?}")).collect();
        assert_eq!(
            line,
            format!("[{}, …] (10 values)", first.join(", ")),
            "{}",
            &line[..line.len().min(300)]
        );
    };
    check(&["run", "long.toml", "--updates", "2"], "first");
    check(
        &["run", "--resume", "first/run.mcap", "--updates", "3"],
        "second",
    );
}

/// A run's length or seed typed as `--updates` / `--seed` is named as that option, not as
/// `run.updates` / `run.seed` of a config that says otherwise: the note on a change scheduled
/// past the end said "(run.updates = 2)" of the default config's 40 updates, and the resumes
/// refused "… has run.updates = 20" and "the config run.seed = 5".
#[test]
fn a_length_or_seed_given_as_an_option_is_named_as_the_option() {
    let d = scratch("h3-option-names");
    let out = pi2cma(&["run", "--updates", "20", "--quiet", "--out", "first"], &d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let note = "schedule[0].from_update = 20 is not before the run's end (--updates 20)";
    assert!(stderr.contains(note), "{stderr}");
    let resume = |more: &[&str]| {
        let args = [
            &["run", "--resume", "first/run.mcap", "--out", "second"],
            more,
        ]
        .concat();
        let out = pi2cma(&args, &d);
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let err = resume(&["--updates", "20"]);
    assert!(
        err.contains("ends with update 19, and --updates 20 was given: nothing left to run"),
        "{err}"
    );
    let err = resume(&["--updates", "40", "--seed", "5"]);
    assert!(
        err.contains("the recording has seed 1; --seed 5 was given"),
        "{err}"
    );
}

/// A run with a task change ends with the re-convergence table, whose reference optimum is a
/// compass search from the final mean. For a policy of many parameters that search took O(P²)
/// rollouts: `pi2cma run` with P = 400 was still summarising 20 minutes after its last update.
/// It now stops at its budget and the table says so; the paper's tasks (P = 2) are unaffected.
#[test]
fn a_large_policy_run_ends_and_says_its_reference_search_stopped_at_its_budget() {
    let d = scratch("large-policy-summary");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[("basis_functions = 2", "basis_functions = 400")],
    );
    std::fs::write(d.join("large.toml"), text).expect("write config");
    let args = [
        "run",
        "large.toml",
        "--updates",
        "21",
        "--quiet",
        "--no-record",
    ];
    let out = pi2cma(&[&args[..], &["--out", "large"]].concat(), &d);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let row = stdout
        .lines()
        .find(|l| l.starts_with("| A1 |"))
        .unwrap_or_else(|| panic!("no table row:\n{stdout}"));
    assert!(
        row.ends_with("(reference search stopped at its budget) |"),
        "{row}"
    );
    // The paper's via-point task: an exact reference, no remark.
    let out = pi2cma(
        &[
            "run",
            "--updates",
            "21",
            "--quiet",
            "--no-record",
            "--out",
            "small",
        ],
        &d,
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!stdout.contains("budget"), "{stdout}");
}

/// `rollout_delay_ms` stands in for a slow robot. The reference search after the last update
/// ran the task with that delay too: hundreds of rollouts per start, so `pi2cma run` printed its
/// last update and then nothing for minutes (here ≥ 2 × 240 × 0.2 s). The search needs only the
/// cost, so it runs without the delay; the run takes 2 × 4 × 0.2 s of rollouts and its summary.
#[test]
fn a_run_with_slow_rollouts_summarises_without_waiting_for_them_again() {
    let d = scratch("slow-rollouts-summary");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[
            ("rollouts = 15", "rollouts = 4"),
            ("from_update = 20", "from_update = 1"),
            (
                "viapoint_weight = 1000.0",
                "viapoint_weight = 1000.0\nrollout_delay_ms = 200",
            ),
        ],
    );
    std::fs::write(d.join("slow.toml"), text).expect("write config");
    let mut child = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args([
            "run",
            "slow.toml",
            "--updates",
            "2",
            "--quiet",
            "--no-record",
        ])
        .args(["--out", "slow"])
        .current_dir(&d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("pi2cma starts");
    let t = std::time::Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t.elapsed() > std::time::Duration::from_secs(40) {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!(
                "pi2cma run still running after 40 s; it printed:\n{}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let out = child.wait_with_output().expect("output");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.lines().any(|l| l.starts_with("| A1 |")), "{stdout}");
}

/// The first SIGINT stops after the current update; a second one stops at once, as the
/// supervisor's does. Before, it was ignored: with rollouts of 1 s (K = 15) the user waited for
/// the rest of the 15 s update whatever they pressed. A SIGHUP the run was started with ignored
/// (`nohup`) stays ignored, and the messages name the signal.
#[test]
fn a_second_sigint_stops_a_run_at_once_and_a_nohup_run_ignores_sighup() {
    let d = scratch("second-sigint");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[(
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 1000",
        )],
    );
    std::fs::write(d.join("slow.toml"), text).expect("write config");
    // Started as `nohup` starts it: SIGHUP ignored (kept across `exec`).
    let mut child = Command::new("sh")
        .args(["-c", "trap '' HUP; exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_pi2cma"))
        .args(["run", "slow.toml", "--out", "slow"])
        .current_dir(&d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("pi2cma starts");
    // Within the first update, which takes 15 s.
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let pid = child.id().to_string();
    let signal = |name: &str| {
        let sent = Command::new("kill")
            .args([name, &pid])
            .status()
            .expect("kill");
        assert!(sent.success());
    };
    // The terminal's hangup does not reach a nohup'd run (the `ctrlc` crate, used before,
    // installed a handler over the ignored SIGHUP).
    signal("-HUP");
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert!(
        child.try_wait().expect("wait").is_none(),
        "SIGHUP stopped it"
    );
    let sigint = || signal("-INT");
    sigint();
    std::thread::sleep(std::time::Duration::from_millis(300));
    let second = std::time::Instant::now();
    sigint();
    let out = child.wait_with_output().expect("exit");
    let waited = second.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{stderr}");
    assert!(
        stderr.contains("SIGINT received: stopping after the current update")
            && stderr.contains("SIGINT (a second signal): stopping at once")
            && !stderr.contains("SIGHUP"),
        "{stderr}"
    );
    // The update had more than 12 s to go.
    assert!(waited < std::time::Duration::from_secs(8), "{waited:?}");
}

/// `pi2cma analyze` of a recording whose writer was killed suggested `mcap-tool recover`, a
/// command of another binary (found by a user test of the README): it names its own.
#[test]
fn analyze_of_an_unfinished_recording_names_pi2cma_recover() {
    let d = scratch("analyze-unfinished");
    let run = pi2cma(&["run", "--out", "r", "--updates", "4", "--quiet"], &d);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    // What a SIGKILL leaves: the updates flushed so far, no summary section.
    let bytes = std::fs::read(d.join("r/run.mcap")).expect("recording");
    std::fs::write(d.join("cut.mcap"), &bytes[..bytes.len() * 2 / 3]).expect("write");
    let out = pi2cma(&["analyze", "cut.mcap"], &d);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("NOT indexed"), "{stdout}");
    assert!(
        stdout.contains("pi2cma recover cut.mcap`") && !stdout.contains("mcap-tool"),
        "{stdout}"
    );
}

/// The default directory is the latest run's as a whole: `runs/latest/analysis/`, which the
/// printed `analyze` command writes, held the previous run's CSV files and figures after the
/// next run (found by a user test of the README). A directory given by `--out` keeps what
/// else it holds.
#[test]
fn the_next_run_replaces_the_previous_analysis_in_runs_latest_and_leaves_a_given_out_as_it_is() {
    let d = scratch("replaces-latest");
    let first = pi2cma(&["run", "--updates", "3", "--quiet"], &d);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let analyse = pi2cma(
        &[
            "analyze",
            "runs/latest/run.mcap",
            "--out",
            "runs/latest/analysis",
        ],
        &d,
    );
    assert!(
        analyse.status.success(),
        "{}",
        String::from_utf8_lossy(&analyse.stderr)
    );
    assert!(d.join("runs/latest/analysis/run/update.csv").is_file());
    let second = pi2cma(&["run", "--updates", "3", "--quiet", "--seed", "2"], &d);
    assert!(
        second.status.success(),
        "{}",
        String::from_utf8_lossy(&second.stderr)
    );
    assert!(
        !d.join("runs/latest/analysis").exists(),
        "the previous run's analysis is still in runs/latest"
    );
    assert!(d.join("runs/latest/run.mcap").is_file() && d.join("runs/latest/fig2.svg").is_file());
    // A file of the user's own in runs/latest stays; one in a replaced subdirectory is refused.
    std::fs::create_dir_all(d.join("runs/latest/my-own")).expect("mkdir");
    std::fs::write(d.join("runs/latest/my-own/thesis.tex"), "mine").expect("write");
    std::fs::create_dir_all(d.join("runs/latest/analysis")).expect("mkdir");
    std::fs::write(d.join("runs/latest/analysis/notes.txt"), "mine").expect("write");
    let refused = pi2cma(&["run", "--updates", "3", "--quiet"], &d);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success()
            && stderr.contains("analysis/notes.txt: this run replaces")
            && stderr.contains("give --out"),
        "{stderr}"
    );
    std::fs::remove_file(d.join("runs/latest/analysis/notes.txt")).expect("rm");
    let third = pi2cma(&["run", "--updates", "3", "--quiet"], &d);
    assert!(
        third.status.success(),
        "{}",
        String::from_utf8_lossy(&third.stderr)
    );
    assert!(d.join("runs/latest/my-own/thesis.tex").is_file());
    assert!(!d.join("runs/latest/analysis").exists());

    std::fs::create_dir_all(d.join("mine/analysis")).expect("mkdir");
    std::fs::write(d.join("mine/analysis/notes.txt"), "mine").expect("write");
    let given = pi2cma(&["run", "--updates", "3", "--quiet", "--out", "mine"], &d);
    assert!(
        given.status.success(),
        "{}",
        String::from_utf8_lossy(&given.stderr)
    );
    assert!(d.join("mine/analysis/notes.txt").is_file());

    // `experiment`'s default directory, runs/experiment, likewise.
    std::fs::create_dir_all(d.join("runs/experiment/analysis")).expect("mkdir");
    std::fs::write(d.join("runs/experiment/analysis/old.csv"), "old").expect("write");
    let cfg = repo().join("config/A1.toml");
    let cfg = cfg.to_str().expect("utf-8 path");
    let exp = pi2cma(&["experiment", cfg, "--sessions", "1"], &d);
    assert!(
        exp.status.success(),
        "{}",
        String::from_utf8_lossy(&exp.stderr)
    );
    assert!(!d.join("runs/experiment/analysis").exists());
    assert!(d.join("runs/experiment/summary.md").is_file());
}

/// A run resumed from a resumed run (day1 → day2 → day3; found by a review): day2 named day1
/// as typed, `runs/latest/run.mcap`, so day3 started elsewhere followed it to that directory's
/// runs/latest, another run, and printed an analyze command mixing the two; and day3 recording
/// to its default runs/latest/run.mcap, where day1 was, overwrote the run's first updates.
#[test]
fn a_twice_resumed_run_names_its_first_recording_and_never_records_over_it() {
    let w = scratch("chain-w");
    let y = scratch("chain-y");
    let ok = |out: &Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    ok(&pi2cma(&["run", "--updates", "3", "--quiet"], &w));
    let day2 = ["run", "--resume", "runs/latest/run.mcap", "--updates", "6"];
    ok(&pi2cma(
        &[&day2[..], &["--quiet", "--out", "day2"]].concat(),
        &w,
    ));
    // Another run in the other directory's runs/latest.
    let a2 = repo().join("config/A2.toml");
    ok(&pi2cma(
        &[
            "run",
            a2.to_str().expect("utf-8"),
            "--updates",
            "3",
            "--quiet",
        ],
        &y,
    ));
    let day2_file = w.join("day2/run.mcap");
    let day3 = [
        "run",
        "--resume",
        day2_file.to_str().expect("utf-8"),
        "--updates",
        "9",
    ];
    let text = ok(&pi2cma(
        &[&day3[..], &["--quiet", "--out", "d"]].concat(),
        &y,
    ));
    let command = text
        .lines()
        .find(|l| l.contains(" analyze "))
        .unwrap_or_else(|| panic!("no analyze command:\n{text}"));
    let day1 = w.join("runs/latest/run.mcap");
    assert!(
        command.contains(day1.to_str().expect("utf-8"))
            && !command.contains(" runs/latest/run.mcap"),
        "{command}"
    );
    // Day 3 in day 1's directory, to the default place, where day 1's recording is.
    let refused = pi2cma(&[&day3[..], &["--quiet"]].concat(), &w);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success()
            && stderr.contains("an earlier recording of the run being resumed"),
        "{stderr}"
    );
    assert_eq!(
        record::read_run_metadata(&day1).expect("day 1")["first_update"],
        "0"
    );
}

/// A recording that fails mid-run (here a file size limit, as a full disk does) stops the run
/// after the update in flight, and the error names the file, what it holds and how to complete
/// it. Before, the run went on unrecorded to its end (hours of robot time) and only then said
/// `error: recording r/run.mcap: r/run.mcap: MCAP: I/O error: File too large`, with no results
/// written: every update after the failure was lost.
#[test]
fn a_run_whose_recording_fails_stops_and_says_what_the_file_holds() {
    let d = scratch("recording-fails");
    // With SIGXFSZ at its default, as a user's shell leaves it: pi2cma ignores it itself (it
    // was killed by it, exit 153, with the shell's "File size limit exceeded" and nothing more).
    let out = Command::new("sh")
        .args([
            "-c",
            "ulimit -f 1000; exec \"$0\" run --out r --updates 3000",
            env!("CARGO_BIN_EXE_pi2cma"),
        ])
        .current_dir(&d)
        .output()
        .expect("sh starts");
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    let last = stdout
        .lines()
        .filter_map(|l| {
            l.strip_prefix("update ")?
                .split('/')
                .next()?
                .trim()
                .parse::<u64>()
                .ok()
        })
        .max()
        .expect("progress lines");
    // "… r/run.mcap holds 14 updates (0..=13) but is not finished: `pi2cma recover …"
    let held: u64 = stderr
        .split(" holds ")
        .nth(1)
        .and_then(|s| s.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no `holds N updates` in: {stderr}"));
    assert!(
        stderr.contains("the run stopped: its recording failed")
            && stderr.contains("r/run.mcap: MCAP: I/O error: File too large")
            && stderr.contains("pi2cma recover r/run.mcap --out"),
        "{stderr}"
    );
    assert!(
        held > 0 && last <= held + 2,
        "ran {last} updates, recorded {held}: {stderr}"
    );
    // What it says the file holds is what a recovery gets back.
    let rec = pi2cma(&["recover", "r/run.mcap", "--out", "rec.mcap"], &d);
    assert!(
        rec.status.success(),
        "{}",
        String::from_utf8_lossy(&rec.stderr)
    );
    let info = pi2cma(&["analyze", "rec.mcap", "--no-csv", "--no-plots"], &d);
    let info = String::from_utf8_lossy(&info.stdout);
    assert!(
        info.contains(&format!("updates: {held} (0..={})", held - 1)),
        "{info}"
    );
}

/// A run name is a label, not a path: an experiment recorded `name = "day 1/A1"` to
/// `OUT/mcap/day 1/A1-seed1.mcap` and failed with `error: creating …: No such file or
/// directory` (`../x` would have written outside OUT). Its files are named as the supervisor's.
#[test]
fn an_experiment_records_a_run_name_with_a_slash_into_its_mcap_directory() {
    let d = scratch("experiment-name-slash");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[
            ("name = \"A1\"", "name = \"day 1/A1\""),
            ("updates = 40", "updates = 2"),
        ],
    );
    std::fs::write(d.join("c.toml"), text).expect("config");
    let out = pi2cma(
        &[
            "experiment",
            "--sessions",
            "1",
            "--out",
            "res",
            "--record",
            "c.toml",
        ],
        &d,
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(d.join("res/mcap/day_1_A1-seed1.mcap").is_file());
}

/// An `--out` that names a file is refused before anything runs. An experiment ran every
/// session and only then failed, `error: creating afile: File exists (os error 17)`, with its
/// results lost (hours, with the paper's session counts; found by a user test of the README).
#[test]
fn an_out_that_is_a_file_is_refused_before_anything_runs() {
    let d = scratch("out-is-a-file");
    std::fs::write(d.join("afile"), b"mine").expect("file");
    let a1 = repo().join("config/A1.toml");
    let a1 = a1.to_str().expect("utf-8");
    for args in [
        &["experiment", a1, "--sessions", "2", "--out", "afile"][..],
        &["run", "--updates", "3", "--out", "afile"][..],
    ] {
        let refused = pi2cma(args, &d);
        let err = String::from_utf8_lossy(&refused.stderr);
        assert!(
            !refused.status.success()
                && err.contains("afile: is a file, not a directory (--out)")
                && !err.contains("running"),
            "{args:?}: {err}"
        );
    }
    assert_eq!(std::fs::read(d.join("afile")).expect("kept"), b"mine");
}

/// `run --no-record --out DIR` where DIR holds a run's recording replaced that run's tables and
/// figures with its own, beside the other run's recording (found by a user test of the README,
/// which says such a directory is refused).
#[test]
fn an_unrecorded_run_does_not_replace_the_results_beside_a_recording() {
    let d = scratch("no-record-beside");
    let first = pi2cma(&["run", "--out", "mine", "--updates", "3", "--quiet"], &d);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let summary = std::fs::read(d.join("mine/summary.md")).expect("summary");
    let c2 = repo().join("config/C2.toml");
    let again = pi2cma(
        &[
            "run",
            c2.to_str().expect("utf-8"),
            "--out",
            "mine",
            "--updates",
            "3",
            "--no-record",
        ],
        &d,
    );
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success()
            && err.contains("mine: holds another run's recording")
            && err.contains("mine/run.mcap"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(d.join("mine/summary.md")).expect("kept"),
        summary
    );
}

/// An experiment into an --out that holds an earlier experiment's recordings (mcap/) is refused:
/// without --record it replaced that one's summary.md, mean_curves.csv and fig2.svg beside
/// recordings they no longer described.
#[test]
fn an_experiment_does_not_replace_the_results_beside_an_earlier_ones_recordings() {
    let d = scratch("experiment-beside");
    let a1 = repo().join("config/A1.toml");
    let c2 = repo().join("config/C2.toml");
    let experiment = |config: &Path, record: bool| {
        let mut args = vec![
            "experiment",
            config.to_str().expect("utf-8"),
            "--sessions",
            "1",
            "--out",
            "e",
        ];
        if record {
            args.push("--record");
        }
        pi2cma(&args, &d)
    };
    let first = experiment(&a1, true);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let summary = std::fs::read(d.join("e/summary.md")).expect("summary");
    for record in [false, true] {
        let again = experiment(&c2, record);
        let err = String::from_utf8_lossy(&again.stderr);
        assert!(
            !again.status.success()
                && err.contains("e: holds an earlier experiment's recordings (e/mcap/A1-seed"),
            "--record {record}: {err}"
        );
    }
    assert_eq!(
        std::fs::read(d.join("e/summary.md")).expect("kept"),
        summary
    );
}

/// runs/latest is the latest run's as a whole. A resumed run writes its recording only, and the
/// previous run's updates.csv, summary.md and fig2.svg (another config's) stayed beside it; a
/// `--no-record` run left the previous run's run.mcap beside its own results.
#[test]
fn runs_latest_holds_nothing_of_the_previous_run_after_a_resumed_or_unrecorded_run() {
    let d = scratch("latest-whole");
    ok(&pi2cma(
        &["run", "--out", "day1", "--updates", "3", "--quiet"],
        &d,
    ));
    ok(&pi2cma(
        &["run", "--updates", "3", "--quiet", "--seed", "7"],
        &d,
    ));
    let latest = d.join("runs/latest");
    assert!(latest.join("summary.md").is_file() && latest.join("run.mcap").is_file());
    ok(&pi2cma(
        &[
            "run",
            "--resume",
            "day1/run.mcap",
            "--updates",
            "5",
            "--quiet",
        ],
        &d,
    ));
    for f in ["updates.csv", "mean_curves.csv", "fig2.svg", "summary.md"] {
        assert!(
            !latest.join(f).exists(),
            "the previous run's {f} is still there"
        );
    }
    let meta = record::read_run_metadata(&latest.join("run.mcap")).expect("resumed recording");
    assert_eq!(meta["first_update"], "3");

    ok(&pi2cma(
        &["run", "--updates", "3", "--quiet", "--no-record"],
        &d,
    ));
    assert!(
        !latest.join("run.mcap").exists(),
        "the previous run's recording is beside this run's results"
    );
    assert!(latest.join("summary.md").is_file());
}

/// A run stopped with Ctrl-C says how to go on from its recording, and that command goes on
/// (it said only "the recording is complete"; found by a user test of the README).
#[test]
fn an_interrupted_run_prints_the_command_that_resumes_it() {
    use std::io::BufRead as _;
    let d = scratch("interrupted-resume");
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[(
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 2",
        )],
    );
    std::fs::write(d.join("slow.toml"), text).expect("write config");
    let mut child = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args(["run", "slow.toml", "--out", "res"])
        .current_dir(&d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("pi2cma starts");
    // Updates of 30 ms: stopped within the 40, after its first, not after a fixed time (a
    // signal that comes before pi2cma has installed its handler, as on a loaded machine,
    // kills it).
    let mut lines = std::io::BufReader::new(child.stdout.take().expect("stdout")).lines();
    let mut stdout = String::new();
    for line in lines.by_ref() {
        let line = line.expect("utf-8");
        stdout += &line;
        stdout.push('\n');
        if line.starts_with("update ") {
            break;
        }
    }
    // The rest of its output, 40 lines at most, waits in the pipe.
    let out = interrupt(child);
    for line in lines {
        stdout += &line.expect("utf-8");
        stdout.push('\n');
    }
    assert_eq!(out.status.code(), Some(130), "{stdout}");
    let command = stdout
        .lines()
        .find_map(|l| l.split_once("go on with: ").map(|(_, c)| c.to_string()))
        .unwrap_or_else(|| panic!("no resume command:\n{stdout}"));
    let args: Vec<&str> = command.split_whitespace().skip(1).collect();
    assert_eq!(
        args,
        ["run", "--resume", "res/run.mcap", "--out", "OTHER_DIR"],
        "{command}"
    );
    let resumed = pi2cma(&[&args[..4], &["res2", "--quiet"]].concat(), &d);
    let text = String::from_utf8_lossy(&resumed.stdout);
    assert!(
        resumed.status.success() && text.contains("resumed at update"),
        "{text}{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
}

/// `run --out` into an experiment's directory and `experiment --out` into a run's are refused as
/// each is into its own kind: the tables and figures both write at the top of the directory
/// (summary.md, mean_curves.csv, fig2.svg) replaced the other's beside its recordings, which
/// they no longer described.
#[test]
fn a_run_and_an_experiment_do_not_replace_the_results_beside_each_others_recordings() {
    let d = scratch("run-experiment-beside");
    let a1 = repo().join("config/A1.toml");
    let a1 = a1.to_str().expect("utf-8");
    ok(&pi2cma(
        &["run", "--out", "r", "--updates", "3", "--quiet"],
        &d,
    ));
    ok(&pi2cma(
        &[
            "experiment",
            a1,
            "--sessions",
            "1",
            "--out",
            "e",
            "--record",
        ],
        &d,
    ));
    let summaries =
        || ["r", "e"].map(|dir| std::fs::read(d.join(dir).join("summary.md")).expect("summary"));
    let before = summaries();
    let into_run = pi2cma(&["experiment", a1, "--sessions", "1", "--out", "r"], &d);
    let err = String::from_utf8_lossy(&into_run.stderr);
    assert!(
        !into_run.status.success()
            && err.contains("r: holds another run's recording")
            && err.contains("r/run.mcap"),
        "{err}"
    );
    for no_record in [false, true] {
        let mut args = vec!["run", "--out", "e", "--updates", "3", "--quiet"];
        if no_record {
            args.push("--no-record");
        }
        let into_experiment = pi2cma(&args, &d);
        let err = String::from_utf8_lossy(&into_experiment.stderr);
        assert!(
            !into_experiment.status.success()
                && err.contains("e: holds an earlier experiment's recordings (e/mcap/A1-seed"),
            "--no-record {no_record}: {err}"
        );
    }
    assert!(!d.join("e/run.mcap").exists());
    assert_eq!(summaries(), before);
}
