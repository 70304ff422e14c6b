//! The supervisor of a pipeline run: starts the MCAP recorder (crate `record`), the updater, the
//! sampler and N rollout workers in order with readiness handshakes, restarts failed workers
//! and a recorder that died (with backoff and a limit per time window; a restarted recorder
//! continues the recording in a new part), kills workers the sampler reports hung, scales
//! workers at runtime, forwards task changes, shuts everything down in reverse order on a
//! signal or `stop` (the recorder last), and leaves nothing of the run behind.
//!
//! Control commands (`status`, `scale`, `set`, `record`, `stop`) reach a running supervisor
//! through a Unix socket in its run directory `<runs>/<run id>/control.sock`, where `<runs>` is
//! `$PI2CMA_RUN_DIR` or `/tmp/pi2cma-<uid>`.
//!
//! It is not a process of the data paths: the updater, sampler and worker are the `pipeline`
//! crate's, the recorder is `record`'s; this crate's binaries only host them.
//!
//! **Architecture Invariant:** the supervisor never touches rollouts or costs; it only sees
//! lifecycle, progress, overdue and recorder acknowledgement messages, and sends control
//! messages and run notes (see the `wire` crate).

#![warn(missing_docs)]

mod control;
mod run;
mod shm;

pub use control::{client, runs_dir};
pub use run::{
    default_recording, file_size_limit_note, group_members, process_alive, run, RunOptions,
    EMPTY_PART_REMOVED,
};

/// Exit code of a run stopped by SIGINT/SIGTERM.
pub const EXIT_INTERRUPTED: u8 = 130;
/// The run completed or stopped as asked, but its recorder died: the recording is not finished
/// (`recover` completes it). Not 0, so that scripts notice; not 1, the run itself did not fail.
pub const EXIT_RECORDING_UNFINISHED: u8 = 3;
