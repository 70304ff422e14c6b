//! What the T-ball examples share (each has `mod common;`).

use std::error::Error;
use std::path::Path;
use std::process::ExitCode;

use session::{RunConfig, TaskSection};
use tball::TballConfig;

/// An example's `main`: runs `run`, and reports an error as the user's message (`Display`), not
/// a `Debug` dump of the error value.
pub fn main(run: fn() -> Result<(), Box<dyn Error>>) -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The `[task.tball]` section of `cfg`, read from `path`; other tasks are refused.
pub fn tball_task<'a>(cfg: &'a RunConfig, path: &Path) -> Result<&'a TballConfig, Box<dyn Error>> {
    match &cfg.task {
        TaskSection::Tball(task) => Ok(task),
        _ => Err(format!("{}: not a [task.tball] config", path.display()).into()),
    }
}
