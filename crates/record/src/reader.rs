//! Reading a recording back: every message of every topic, decoded, in file order. Works on
//! complete files and on files whose writer was killed (the readable prefix is returned and
//! the damage is reported in [`Recording::truncated`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::read::Options;
use prost::Message;

use crate::{proto, topics, RecordError};

/// A decoded recording.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub path: PathBuf,
    pub file_bytes: u64,
    /// Whether the file has a summary section (i.e. was finished or recovered).
    pub indexed: bool,
    /// Why reading stopped early, if it did (a file whose writer was killed).
    pub truncated: Option<String>,
    /// MCAP metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    pub run: Vec<proto::RunInfo>,
    pub updates: Vec<proto::Update>,
    pub summaries: Vec<proto::UpdateSummary>,
    pub rollouts: Vec<proto::Rollout>,
    pub task_changes: Vec<proto::TaskChange>,
    pub logs: Vec<proto::Log>,
    /// Message counts per topic, including topics this reader does not know.
    pub topic_counts: BTreeMap<String, u64>,
    /// log_time of the first and last message.
    pub time_range: Option<(u64, u64)>,
}

impl Recording {
    /// The `/run` message of the run (the first one, if the run was resumed into the same file).
    pub fn run_info(&self) -> Option<&proto::RunInfo> {
        self.run.first()
    }

    /// The run name: from `/run`, else from the metadata, else the file name.
    pub fn name(&self) -> String {
        if let Some(r) = self.run_info() {
            return r.name.clone();
        }
        if let Some(n) = self
            .metadata
            .get(topics::METADATA)
            .and_then(|m| m.get("name"))
        {
            return n.clone();
        }
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    }

    /// Learning-curve rows from `/summary` (or from `/update` if a file has no summaries).
    pub fn curve(&self) -> Vec<proto::UpdateSummary> {
        if !self.summaries.is_empty() {
            return self.summaries.clone();
        }
        self.updates
            .iter()
            .map(|u| proto::UpdateSummary {
                timestamp: u.timestamp,
                update: u.update,
                eval_cost: u.eval_cost,
                exploration_cost_mean: u.exploration_cost_mean,
                exploration_cost_std: u.exploration_cost_std,
                lambda: u.lambda,
                lambda_next: u.lambda_next,
                mean: u.after.as_ref().map(|d| d.mean.clone()).unwrap_or_default(),
            })
            .collect()
    }
}

fn decode<M: Message + Default>(
    file: &Path,
    topic: &str,
    index: u64,
    schema: &'static str,
    data: &[u8],
) -> Result<M, RecordError> {
    M::decode(data).map_err(|error| RecordError::Decode {
        file: file.to_path_buf(),
        topic: topic.to_string(),
        index,
        schema,
        error,
    })
}

/// Reads and decodes a whole recording.
pub fn read_recording(path: &Path) -> Result<Recording, RecordError> {
    let buf = std::fs::read(path).map_err(|e| RecordError::io(path, e))?;
    let mut rec = Recording {
        path: path.to_path_buf(),
        file_bytes: buf.len() as u64,
        indexed: matches!(mcap::read::Summary::read(&buf), Ok(Some(_))),
        ..Default::default()
    };
    // Metadata records (not part of the message stream).
    let records = mcap::read::LinearReader::new_with_options(&buf, Options::IgnoreEndMagic.into())
        .map_err(|e| RecordError::mcap(path, e))?;
    for r in records {
        match r {
            Ok(mcap::records::Record::Metadata(m)) => {
                rec.metadata.insert(m.name, m.metadata);
            }
            Ok(_) => {}
            Err(e) => {
                rec.truncated = Some(format!("records end early: {e}"));
                break;
            }
        }
    }
    let stream = mcap::MessageStream::new_with_options(&buf, Options::IgnoreEndMagic.into())
        .map_err(|e| RecordError::mcap(path, e))?;
    for m in stream {
        let m = match m {
            Ok(m) => m,
            Err(e) => {
                if rec.indexed {
                    return Err(RecordError::mcap(path, e));
                }
                rec.truncated
                    .get_or_insert_with(|| format!("messages end early: {e}"));
                break;
            }
        };
        let topic = m.channel.topic.as_str();
        let count = rec.topic_counts.entry(topic.to_string()).or_insert(0);
        let index = *count;
        *count += 1;
        rec.time_range = Some(match rec.time_range {
            None => (m.log_time, m.log_time),
            Some((a, b)) => (a.min(m.log_time), b.max(m.log_time)),
        });
        let data = &m.data[..];
        match topic {
            topics::RUN => rec.run.push(decode(path, topic, index, "RunInfo", data)?),
            topics::UPDATE => rec
                .updates
                .push(decode(path, topic, index, "Update", data)?),
            topics::SUMMARY => {
                rec.summaries
                    .push(decode(path, topic, index, "UpdateSummary", data)?)
            }
            topics::ROLLOUT => rec
                .rollouts
                .push(decode(path, topic, index, "Rollout", data)?),
            topics::TASK_CHANGE => {
                rec.task_changes
                    .push(decode(path, topic, index, "TaskChange", data)?)
            }
            topics::LOG => rec.logs.push(decode(path, topic, index, "Log", data)?),
            _ => {}
        }
    }
    Ok(rec)
}
