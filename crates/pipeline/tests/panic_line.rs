//! A process run by `pipeline::run_main` that panics ends its output with one error line naming
//! the panic's message and where it was raised: the supervisor reports a process's last error
//! line as why it died, and after the standard panic message come the backtrace or the hint to
//! set `RUST_BACKTRACE`.
//!
//! `harness = false`: the test runs itself as that process (`PANIC_LINE_CHILD` set), whose main
//! must be its own, not the test harness's, for its last line to be its own.

use std::process::{Command, ExitCode};

const MESSAGE: &str = "the simulator exploded at step 7";

fn main() -> ExitCode {
    if std::env::var_os("PANIC_LINE_CHILD").is_some() {
        return pipeline::run_main("my-worker", || panic!("{MESSAGE}"));
    }
    for backtrace in ["0", "1"] {
        let out = Command::new(std::env::current_exe().expect("the test's own path"))
            .env("PANIC_LINE_CHILD", "1")
            .env("RUST_BACKTRACE", backtrace)
            .output()
            .expect("the test runs itself");
        let stderr = String::from_utf8_lossy(&out.stderr);
        let last = stderr.lines().last().unwrap_or_default();
        assert_eq!(out.status.code(), Some(101), "{stderr}");
        let expected = format!("error: my-worker panicked at {}", file!());
        assert!(
            last.starts_with(&expected) && last.ends_with(&format!(": {MESSAGE}")),
            "RUST_BACKTRACE={backtrace}: the last line is {last:?}, not {expected}…: {MESSAGE}\n{stderr}"
        );
    }
    println!("test a_panic_is_the_last_line ... ok");
    ExitCode::SUCCESS
}
