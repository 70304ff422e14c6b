//! Process helpers and recording checks of the tests that run the pipeline's binaries
//! (`crates/supervisor/tests/e2e.rs`, `crates/supervisor/tests/recorder.rs`), included by each
//! (`#[path = ".../tests/pipeline_checks.rs"] mod pipeline_checks;`).

#![allow(dead_code)] // each test file uses what it needs

use std::process::{Child, Command};

use record::recompute::VerifyReport;
use record::Recording;

/// Sends `sig` (`-INT`, `-9`, …) to process `pid`; fails the test if `kill` fails.
pub fn signal(pid: u32, sig: &str) {
    let sent = Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .unwrap();
    assert!(sent.success(), "kill {sig} {pid}: {sent}");
}

/// A child killed when the test ends, passed or not (one that has exited is left alone).
pub struct KillOnDrop(pub Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The indices of a recording's updates, in the order recorded.
pub fn update_indices(rec: &Recording) -> Vec<u64> {
    rec.updates.iter().map(|u| u.update).collect()
}

/// Asserts that every update of `rec` recomputes bit for bit from its recorded inputs.
pub fn assert_recomputes(rec: &Recording) -> VerifyReport {
    let v = record::recompute::verify(rec).unwrap();
    assert!(v.mismatches.is_empty(), "{v:?}");
    v
}

/// Asserts a finished recording of a pipeline run holds updates 0..n, every one recomputing bit
/// for bit from its recorded inputs, and no error events.
pub fn assert_recorded(rec: &Recording, n: u64) {
    assert!(
        rec.indexed && rec.truncated.is_none(),
        "{:?}",
        rec.truncated
    );
    assert_eq!(rec.run_info().unwrap().executor, "pipeline");
    assert_eq!(update_indices(rec), (0..n).collect::<Vec<_>>());
    assert_eq!(assert_recomputes(rec).updates as u64, n);
    let errors: Vec<&str> = rec
        .logs
        .iter()
        .filter(|l| l.event == "error")
        .map(|l| l.message.as_str())
        .collect();
    assert!(errors.is_empty(), "{errors:?}");
}

/// Asserts a recording recovered from a killed recorder holds updates 0..m, at least
/// `at_least` of them, every one recomputing bit for bit; returns m.
pub fn assert_recovered(rec: &Recording, at_least: usize) -> usize {
    let indices = update_indices(rec);
    assert!(indices.len() >= at_least, "{} < {at_least}", indices.len());
    assert_eq!(indices, (0..indices.len() as u64).collect::<Vec<_>>());
    assert_recomputes(rec);
    indices.len()
}
