//! The proof that recordings are readable by tools other than ours: `tools/plot_learning_curve.py`
//! (PyPI `mcap` + `mcap-protobuf-support` only, no pi2cma code) decodes every topic of a run the
//! `pi2cma` binary recorded, checks its invariants and draws the learning curve.
//! Needs `python3 -m pip install -r tools/requirements.txt` (the README's test command does it).

use std::path::PathBuf;
use std::process::Command;

#[test]
fn python_reader_decodes_every_topic_of_a_run() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let dir = std::env::temp_dir().join(format!("pi2cma-python-reader-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let run = Command::new(env!("CARGO_BIN_EXE_pi2cma"))
        .args(["run", "--quiet", "--out"])
        .arg(&dir)
        .output()
        .expect("pi2cma starts");
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
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
