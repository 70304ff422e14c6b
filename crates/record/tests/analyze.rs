//! `analyze` end to end: three sessions of one run recorded, then summary, CSV, figures, mean
//! curves and re-convergence table.

#![allow(clippy::unwrap_used)] // test helpers; a failed unwrap is a failed test

#[path = "../../../tests/config_edit.rs"]
mod config_edit;
#[path = "../../../tests/scratch.rs"]
mod scratch;

use std::path::PathBuf;

use record::analyze::{run, AnalyzeArgs};
use record::McapRecorder;
use session::{run_session, RunConfig};

#[test]
fn analyze_writes_csv_figures_and_the_experiment_table() {
    let dir = scratch::scratch("analyze");
    let mut cfg = RunConfig::default_config();
    cfg.run.updates = Some(30);
    let mut files = Vec::new();
    for seed in 1..=3 {
        let f = dir.join(format!("A1-s{seed}.mcap"));
        let mut rec = McapRecorder::create(&f).unwrap();
        run_session(&cfg, seed, &mut rec).unwrap();
        rec.finish().unwrap();
        files.push(f);
    }
    let out = dir.join("analysis");
    let text = run(
        &AnalyzeArgs {
            files: files.clone(),
            out: Some(out.clone()),
            no_csv: false,
            no_plots: false,
            verify: true,
            tolerance: 0.05,
        },
        "mcap-tool",
    )
    .unwrap();
    assert_eq!(
        text.matches("0 mismatches (bit-identical)").count(),
        3,
        "{text}"
    );
    assert!(text.contains("| A1 | 0 | 3 |"), "{text}");
    assert!(text.contains("| A1 | 20 (task change) | 3 |"), "{text}");
    for s in 1..=3 {
        let sub = out.join(format!("A1-s{s}"));
        let summary = std::fs::read_to_string(sub.join("summary.csv")).unwrap();
        assert_eq!(summary.lines().count(), 31);
        let rollouts = std::fs::read_to_string(sub.join("update_rollouts.csv")).unwrap();
        assert_eq!(rollouts.lines().count(), 1 + 30 * 15);
        // P = 2 means, N = 101 step costs per row.
        let header = rollouts.lines().next().unwrap();
        assert!(header.ends_with("cost_step_100") && header.contains("theta_1,"));
        for fig in ["learning_curve.svg", "distribution.svg", "worker_time.svg"] {
            let svg = std::fs::read_to_string(sub.join(fig)).unwrap();
            assert!(
                svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
                "{fig}"
            );
        }
    }
    let mean = std::fs::read_to_string(out.join("mean_curves.csv")).unwrap();
    assert_eq!(mean.lines().count(), 31);
    assert!(mean.lines().nth(1).unwrap().starts_with("A1,0,3,"));
    let reconv = std::fs::read_to_string(out.join("reconvergence.csv")).unwrap();
    assert_eq!(reconv.lines().count(), 1 + 3 * 2);
    assert!(out.join("mean_curves.svg").is_file());
}

/// `mcap-tool record --seed --updates` records the config it ran: its text has both.
#[test]
fn the_recorded_config_has_the_command_line_seed_and_updates() {
    let dir = scratch::scratch("seed");
    let out = dir.join("s3.mcap");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(["record", "--seed", "3", "--updates", "5", "--out"])
        .arg(&out)
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
    let rec = record::read_recording(&out).unwrap();
    let run = rec.run_info().unwrap();
    assert_eq!(run.seed, 3);
    let recorded = RunConfig::parse(&run.config_toml, &out).unwrap();
    assert_eq!((recorded.run.seed, recorded.run.updates), (3, Some(5)));

    // A config that cannot run in-process leaves the file at --out as it was.
    let before = std::fs::read(&out).unwrap();
    let external =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/external-reach.toml");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .arg("record")
        .arg("--config")
        .arg(&external)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!run.status.success());
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(stderr.contains("supervisor run"), "{stderr}");
    assert_eq!(
        std::fs::read(&out).unwrap(),
        before,
        "the recording was overwritten"
    );
    // Nor does one that can: a recording at --out is refused, and left as it was.
    let again = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(["record", "--updates", "5", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(
        !again.status.success() && stderr.contains("is there already"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(&out).unwrap(), before, "overwritten");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A bad value typed as an option is reported as that option, not as a field of the config
/// (`--updates 0` was `<built-in default>: run.updates = 0`).
#[test]
fn record_reports_a_bad_option_value_as_the_option() {
    let dir = scratch::scratch("h2-options");
    let out = dir.join("x.mcap");
    for (args, expected) in [
        (&["--updates", "0"][..], "--updates 0: must be at least 1"),
        (
            &["--rollout-delay-ms=-1"][..],
            "--rollout-delay-ms -1: must be between 0 and 3600000",
        ),
        // A negative number written apart is the option's value too, not an unknown option
        // (clap's tip for that, `-- -1`, was no way to give it).
        (
            &["--rollout-delay-ms", "-1"][..],
            "--rollout-delay-ms -1: must be between 0 and 3600000",
        ),
        (
            &["--updates", "-3"][..],
            "invalid value '-3' for '--updates <UPDATES>'",
        ),
        (
            &["--seed", "-1"][..],
            "invalid value '-1' for '--seed <SEED>'",
        ),
    ] {
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
            .arg("record")
            .args(args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && stderr.contains(expected) && !stderr.contains("built-in"),
            "{stderr}"
        );
        assert!(!out.exists());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A split recording: `mcap-tool record` names every part, and the `analyze` command it prints
/// reads the whole run (given the first part alone, it read only that part's updates).
#[test]
fn record_names_every_part_of_a_split_recording_and_its_analyze_command_reads_them_all() {
    let dir = scratch::scratch("record-split");
    let config = dir.join("split.toml");
    let a1 = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../config/A1.toml"),
    )
    .unwrap();
    // About 1 MB takes 76 via-point updates: 150 make two parts.
    std::fs::write(
        &config,
        config_edit::edited(&a1, &[("updates = 40", "updates = 150")])
            + "\n[recording]\nsplit_mb = 1\n",
    )
    .unwrap();
    let out = dir.join("split.mcap");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .arg("record")
        .arg("--config")
        .arg(&config)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    let parts = record::recording_parts(&out);
    assert!(parts.len() >= 2, "not split: {parts:?}");
    let names: Vec<String> = parts.iter().map(|p| p.display().to_string()).collect();
    assert!(
        stderr.contains(&format!("split into {} parts", parts.len())),
        "{stderr}"
    );
    // The printed command, run as printed (its program is this mcap-tool).
    let command = stderr
        .lines()
        .find_map(|l| l.strip_prefix("analyse with: mcap-tool "))
        .unwrap_or_else(|| panic!("no analyse command: {stderr}"));
    assert!(command.contains(&names.join(" ")), "{command}");
    let args: Vec<&str> = command.split_whitespace().collect();
    let analysis = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(&args)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&analysis.stdout);
    assert!(analysis.status.success(), "{text}");
    assert!(text.contains("one run of 150 updates (0..=149)"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `mcap-tool experiment` takes the files of one run as one session, as `analyze` does: the
/// parts of a split recording are joined, not averaged as sessions over 0 common updates.
#[test]
fn experiment_joins_the_parts_of_a_split_recording_into_one_session() {
    let dir = scratch::scratch("experiment-split");
    let mut cfg = RunConfig::default_config();
    cfg.run.updates = Some(150);
    cfg.recording = Some(session::RecordingSection {
        split_mb: Some(1),
        ..Default::default()
    });
    let first = dir.join("split.mcap");
    let mut rec = McapRecorder::create(&first).unwrap();
    run_session(&cfg, 1, &mut rec).unwrap();
    rec.finish().unwrap();
    let parts = record::recording_parts(&first);
    assert!(parts.len() >= 2, "not split: {parts:?}");
    let out = dir.join("experiment");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .arg("experiment")
        .args(&parts)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{text}");
    assert!(
        text.contains("## Experiment: 1 sessions in 1 run(s)"),
        "{text}"
    );
    assert!(!text.contains("NaN"), "{text}");
    let mean = std::fs::read_to_string(out.join("mean_curves.csv")).unwrap();
    assert_eq!(mean.lines().count(), 1 + 150, "{mean}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `mcap-tool analyze` and `info` of a recording whose writer was killed suggest its own
/// `recover` command, with the file to give it (as `pi2cma analyze` names `pi2cma recover`).
#[test]
fn analyze_of_an_unfinished_recording_names_mcap_tool_recover() {
    let dir = scratch::scratch("analyze-unfinished");
    let full = dir.join("full.mcap");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args(["record", "--updates", "4", "--out"])
        .arg(&full)
        .stdout(std::process::Stdio::null())
        .status()
        .unwrap();
    assert!(status.success());
    // What a SIGKILL leaves: the updates flushed so far, no summary section.
    let bytes = std::fs::read(&full).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    for command in ["analyze", "info"] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
            .arg(command)
            .arg(&cut)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success() && stdout.contains("NOT indexed"),
            "{stdout}"
        );
        assert!(
            stdout.contains(&format!("`mcap-tool recover {}`", cut.display())),
            "{stdout}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
