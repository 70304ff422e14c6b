//! Scratch directories for the end-to-end tests, included by each test file
//! (`#[path = ".../tests/scratch.rs"] mod scratch;`).
//!
//! A test process keeps its files under `<tmp>/pi2cma-test-<pid>/`, and leaves them there: a
//! failed test's recordings and configs stay for inspection. The first test of the next process
//! removes the directories of processes that are no longer running, so repeated runs do not fill
//! the disk (a full run of the tests writes some hundred MB of recordings).

#![allow(dead_code)] // each test file uses what it needs

use std::path::PathBuf;
use std::sync::Once;

const PREFIX: &str = "pi2cma-test-";

/// This process's scratch root, created on first use (after removing dead processes' roots).
fn root() -> PathBuf {
    static SWEEP: Once = Once::new();
    let tmp = std::env::temp_dir();
    SWEEP.call_once(|| {
        let Ok(entries) = std::fs::read_dir(&tmp) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            let Some(pid) = name
                .to_str()
                .and_then(|n| n.strip_prefix(PREFIX))
                .and_then(|p| p.parse::<u32>().ok())
            else {
                continue;
            };
            let alive = std::path::Path::new(&format!("/proc/{pid}")).exists();
            if pid != std::process::id() && !alive {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    });
    let root = tmp.join(format!("{PREFIX}{}", std::process::id()));
    std::fs::create_dir_all(&root).expect("scratch root");
    root
}

/// An empty directory `name` of this process (emptied if a test already used it).
pub fn scratch(name: &str) -> PathBuf {
    let dir = root().join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

/// The directory `name` of this process, shared by the tests that ask for it (not emptied).
pub fn shared(name: &str) -> PathBuf {
    let dir = root().join(name);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}
