//! One error type for the library; every variant names the file (and, where it applies, the
//! topic, update or field) it is about.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{file}: {source}")]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: MCAP: {source}")]
    Mcap {
        file: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    #[error("{file}: topic {topic}, message {index}: cannot decode as {schema}: {source}")]
    Decode {
        file: PathBuf,
        topic: String,
        index: u64,
        schema: &'static str,
        #[source]
        source: prost::DecodeError,
    },
    #[error("{file}: {what}")]
    Invalid { file: PathBuf, what: String },
    #[error("{file}: update {update}: {what}")]
    Update {
        file: PathBuf,
        update: u64,
        what: String,
    },
    #[error("{file}: figure {figure}: {what}")]
    Plot {
        file: PathBuf,
        figure: String,
        what: String,
    },
}

impl RecordError {
    pub(crate) fn io(file: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            file: file.into(),
            source,
        }
    }
    pub(crate) fn mcap(file: impl Into<PathBuf>, source: mcap::McapError) -> Self {
        Self::Mcap {
            file: file.into(),
            source,
        }
    }
    pub(crate) fn invalid(file: impl Into<PathBuf>, what: impl Into<String>) -> Self {
        Self::Invalid {
            file: file.into(),
            what: what.into(),
        }
    }
}
