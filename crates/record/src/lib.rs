//! MCAP recordings of pi2cma runs: the protobuf message schemas, a writer, the
//! [`McapRecorder`] observer for the in-process runner, the pipeline's recorder process
//! ([`pipeline_recorder`]), readers (of recordings in several parts, and of resumed runs),
//! recomputation of every update from its recorded inputs, `recover` for files whose writer was
//! killed, and post-hoc analysis (info, CSV, SVG figures, experiment tables).
//!
//! A recording holds every input of every update (distribution before, hyperparameters, the K
//! samples, the K cost trajectories) and its outputs, so any update can be recomputed with the
//! core and compared bit for bit. The writer flushes a complete zstd chunk after every update, so
//! a writer killed with SIGKILL loses at most the update in flight.
//!
//! It is not an executor and does not know how rollouts are run: the in-process runner calls it
//! through [`session::Observer`]; the pipeline's recorder process subscribes to the run's
//! iceoryx2 services and writes through [`RunWriter`]. Only [`pipeline_recorder`] knows of
//! processes and shared memory; the rest reads and writes files. Topic names and schemas are documented in the repository README, section
//! "Recording (MCAP) and analysis".
//!
//! Reading a recording with code of your own: [`read_recording`] gives a [`Recording`] with
//! every message decoded ([`proto`] types): [`Recording::run_info`] (P, N, hyperparameters),
//! `updates` (samples K×P and `cost_per_step` K×N row-major, `weights`, `before`/`after`),
//! `summaries`, `rollouts`, `task_changes`, `unfinished`, `logs`, and the MCAP `metadata`.
//! [`distribution_from_proto`] turns a `Distribution` into the core's; a rollout's total is
//! `pi2cma::total_cost` (the recorded totals to the bit); [`recompute::recompute_update`]
//! recomputes an update with the core. A run in several files (parts, resumes):
//! [`join_resumed`].
#![warn(missing_docs)]

pub mod analyze;
mod assemble;
mod convert;
mod digest;
mod error;
pub mod pipeline_recorder;
mod reader;
pub mod recompute;
mod recorder;
pub mod recover;
mod reserve;
pub mod resume;
mod seek_buffer;
mod split;
#[cfg(test)]
mod testing;
pub mod ticks;
mod writer;

/// The messages a recording holds, as prost generates them from `crates/record/proto/`
/// (`pi2cma/record.proto`, `foxglove/Log.proto`): one type per message, one field per protobuf
/// field, with the comments of the `.proto` files.
// The generated code carries the .proto comments where there are some; the .proto files and
// the README's "File format" section (under "Recording (MCAP) and analysis") document every
// message and field, so the generated items are not documented again here.
#[allow(missing_docs)]
pub mod proto {
    /// Package `pi2cma`.
    pub mod pi2cma {
        /// Package `pi2cma.record`: the run's own messages.
        pub mod record {
            include!(concat!(env!("OUT_DIR"), "/pi2cma.record.rs"));
        }
    }
    /// Package `foxglove`: `Log`, the health events on `/log`.
    pub mod foxglove {
        include!(concat!(env!("OUT_DIR"), "/foxglove.rs"));
    }
    pub use self::foxglove::Log;
    pub use self::pi2cma::record::*;
}

pub(crate) use convert::hyperparameters_from_proto;
pub use convert::{config_to_toml, distribution_from_proto, ConvertError};

pub(crate) use digest::{Digest, UpdatePoint};
pub use error::RecordError;
pub use reader::{
    join_resumed, read_ends, read_recording, read_recording_slim, read_run_metadata, Ends,
    Recording,
};
pub(crate) use reader::{read_recording_slim_with, Decoded};
pub use recorder::McapRecorder;
pub use split::{
    analyze_command, describe_parts, file_name_part, first_part, last_part, part_number, part_path,
    program_name, recording_parts, refuse_overwrite, resumed_chain, unfinished_part,
};
pub(crate) use split::{part_path_or_first, RunFiles};
pub use writer::{now_ns, Event, RolloutTiming, RunStart, RunWriter, UpdateData};

/// Whether a writer ([`RunWriter::create`]: a running recorder, `pi2cma run`) holds `path`
/// open: it keeps an exclusive advisory lock on the file while it writes, released when it
/// finishes or its process dies. A file that cannot be opened is not being written.
pub fn being_written(path: &std::path::Path) -> bool {
    std::fs::File::open(path)
        .is_ok_and(|f| matches!(f.try_lock_shared(), Err(std::fs::TryLockError::WouldBlock)))
}

/// Makes a write past the process's file size limit (`ulimit -f`, RLIMIT_FSIZE, which batch
/// systems set) fail with `EFBIG`, which the writers report like a full disk: naming the file,
/// what it holds and how to complete it. By default the kernel kills the writer with SIGXFSZ
/// instead: `pi2cma run` vanished with the shell's "File size limit exceeded" and an unfinished
/// file, and the pipeline's recorder died, was restarted into a new part that died the same
/// way, five times, losing updates at each. Every process that writes recordings calls it at
/// its start; the disposition is inherited across exec, so a process that starts programs of
/// the user's (the supervisor) restores the default in them.
pub fn fail_writes_past_file_size_limit() {
    // SAFETY: sets one signal's disposition to SIG_IGN; no handler runs, nothing is shared.
    #[allow(unsafe_code)]
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

/// The FileDescriptorSet of every schema (with `google/protobuf/timestamp.proto`), stored as the
/// schema data of each channel.
pub(crate) const DESCRIPTORS: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/descriptors.bin"));

/// Topic names and the fully qualified protobuf message name of each (the names are
/// crate-private; the README's "File format" section lists them).
pub mod topics {
    pub(crate) const RUN: &str = "/run";
    pub(crate) const UPDATE: &str = "/update";
    pub(crate) const SUMMARY: &str = "/summary";
    pub(crate) const ROLLOUT: &str = "/rollout";
    pub(crate) const TASK_CHANGE: &str = "/task_change";
    pub(crate) const LOG: &str = "/log";
    pub(crate) const UNFINISHED_UPDATE: &str = "/unfinished_update";

    /// (topic, schema name) of every channel a recording has, in the order they are created.
    pub(crate) const ALL: [(&str, &str); 7] = [
        (RUN, "pi2cma.record.RunInfo"),
        (UPDATE, "pi2cma.record.Update"),
        (SUMMARY, "pi2cma.record.UpdateSummary"),
        (ROLLOUT, "pi2cma.record.Rollout"),
        (TASK_CHANGE, "pi2cma.record.TaskChange"),
        (LOG, "foxglove.Log"),
        (UNFINISHED_UPDATE, "pi2cma.record.UnfinishedUpdate"),
    ];

    /// Name of the MCAP metadata record with the run's config, seed and versions.
    pub const METADATA: &str = "pi2cma.run";
}
