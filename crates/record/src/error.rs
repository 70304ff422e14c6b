//! The library's error type; every variant names the file (and, where it applies, the topic,
//! update or field) it is about. (A recorded message converted back to the core's types knows
//! no file: [`crate::ConvertError`], which the readers wrap in [`RecordError::Update`].) The
//! underlying error is part of the message, not a `source()`: reported through `anyhow`, it
//! would otherwise be printed twice ("X: No such file… Caused by: No such file…").

use std::path::PathBuf;

/// Why reading, writing, recovering or analysing a recording failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// Opening, reading, writing or creating a file failed.
    #[error("{file}: {error}")]
    Io {
        /// The file (or directory) concerned.
        file: PathBuf,
        /// What the operating system said.
        error: std::io::Error,
    },
    /// The file is not valid MCAP, or the MCAP library failed to write it.
    #[error("{file}: MCAP: {}", mcap_message(error))]
    Mcap {
        /// The recording.
        file: PathBuf,
        /// What the MCAP library said.
        error: mcap::McapError,
    },
    /// A message's bytes are not the protobuf message its topic's schema names.
    #[error("{file}: topic {topic}, message {index}: cannot decode as {schema}: {error}")]
    Decode {
        /// The recording.
        file: PathBuf,
        /// The message's topic (e.g. `/update`).
        topic: String,
        /// The message's position among its topic's messages, from 0.
        index: u64,
        /// The protobuf message it should be (e.g. `pi2cma.record.Update`).
        schema: &'static str,
        /// What prost said.
        error: prost::DecodeError,
    },
    /// A run config that cannot be read or is not valid (its message names file and field).
    #[error("{0}")]
    Config(session::ConfigError),
    /// The file is not what the operation needs: not a pi2cma recording, one that cannot be
    /// resumed or joined as asked, a file another writer holds (`what` says which).
    #[error("{file}: {what}")]
    Invalid {
        /// The file concerned.
        file: PathBuf,
        /// What is wrong with it.
        what: String,
    },
    /// One recorded update is inconsistent (a distribution of the wrong shape, an unknown
    /// hyperparameter value, inputs the core refuses when recomputing it).
    #[error("{file}: update {update}: {what}")]
    Update {
        /// The recording.
        file: PathBuf,
        /// The update's number.
        update: u64,
        /// What is wrong with it.
        what: String,
    },
    /// A recording whose writer failed mid-run (a full disk): `cause` names the file and the
    /// error; the recording `file` (with its later parts, `parts` files in all, when split)
    /// holds `updates` updates from `first` on, and `unfinished` is its part that is not
    /// finished, if one is not (the last).
    #[error("{cause}; the recording stopped there: {}", stopped_note(self))]
    Stopped {
        /// The recording (its first part, when split).
        file: PathBuf,
        /// The write error that stopped it, with the file it was writing.
        cause: String,
        /// The first update the recording holds.
        first: u64,
        /// How many updates it holds.
        updates: u64,
        /// How many files it has (1 unless split).
        parts: usize,
        /// The part left unfinished (to `recover`), if any.
        unfinished: Option<PathBuf>,
    },
    /// Drawing a figure failed.
    #[error("{file}: figure {figure}: {what}")]
    Plot {
        /// The SVG file being drawn.
        file: PathBuf,
        /// Which figure (e.g. `worker_timeline`).
        figure: String,
        /// What the plotting library said.
        what: String,
    },
}

/// What a recording whose writer failed ([`RecordError::Stopped`]) holds, and how to complete
/// it: a split recording's parts before the last were finished when the next began, so the
/// part to recover is the last, not the file the run was given.
fn stopped_note(e: &RecordError) -> String {
    let RecordError::Stopped {
        file,
        first,
        updates,
        parts,
        unfinished,
        ..
    } = e
    else {
        return String::new();
    };
    let (first, updates) = (*first, *updates);
    let (what, holds) = match parts {
        0 | 1 => (file.display().to_string(), "holds"),
        n => (
            format!("{} and its {} later part(s)", file.display(), n - 1),
            "hold",
        ),
    };
    let held = match updates {
        0 => return format!("{what} {holds} no update"),
        1 => format!("1 update ({first})"),
        n => format!("{n} updates ({first}..={})", first + n - 1),
    };
    let Some(part) = unfinished else {
        return format!("{what} {holds} {held}, finished");
    };
    let part = part.display();
    let state = if *parts > 1 {
        format!("; its last part, {part}, is not finished")
    } else {
        " but is not finished".to_string()
    };
    format!(
        "{what} {holds} {held}{state}: `pi2cma recover {part} --out OTHER_DISK/FILE` (or \
         `mcap-tool recover …`) completes it, or, once there is room, `pi2cma recover {part}` \
         in place"
    )
}

impl RecordError {
    pub(crate) fn io(file: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            file: file.into(),
            error: source,
        }
    }
    pub(crate) fn mcap(file: impl Into<PathBuf>, source: mcap::McapError) -> Self {
        Self::Mcap {
            file: file.into(),
            error: source,
        }
    }
    pub(crate) fn invalid(file: impl Into<PathBuf>, what: impl Into<String>) -> Self {
        Self::Invalid {
            file: file.into(),
            what: what.into(),
        }
    }
    /// A writer refused: another process writes `file` ([`crate::being_written`]).
    pub(crate) fn written_elsewhere(file: impl Into<PathBuf>) -> Self {
        Self::invalid(
            file,
            "is being written by another process (a running recorder); choose another file",
        )
    }
}

impl From<session::ConfigError> for RecordError {
    fn from(e: session::ConfigError) -> Self {
        Self::Config(e)
    }
}

impl RecordError {
    /// Whether this is a full disk (ENOSPC), whichever writer met it.
    pub(crate) fn is_disk_full(&self) -> bool {
        let io = match self {
            Self::Io { error, .. } => Some(error),
            Self::Mcap {
                error: mcap::McapError::Io(error),
                ..
            } => Some(error),
            _ => None,
        };
        io.is_some_and(|e| e.kind() == std::io::ErrorKind::StorageFull)
    }
}

/// mcap's I/O error says "I/O error from writing, or reading a compression stream" and keeps
/// the cause (a full disk, a vanished directory) as its source: the cause is what to say.
fn mcap_message(error: &mcap::McapError) -> String {
    match error {
        mcap::McapError::Io(e) => format!("I/O error: {e}"),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_mcap_io_error_names_its_cause() {
        let full = std::io::Error::from_raw_os_error(28);
        let e = super::RecordError::mcap("r.mcap", mcap::McapError::Io(full)).to_string();
        assert!(
            e.starts_with("r.mcap: MCAP: I/O error: No space left on device"),
            "{e}"
        );
    }
}
