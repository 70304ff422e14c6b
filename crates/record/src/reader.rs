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

/// The first `/run` message and the last complete `/update` of a recording.
#[derive(Debug, Clone, Default)]
pub struct Ends {
    pub run: Option<proto::RunInfo>,
    pub last_update: Option<proto::Update>,
    /// How many `/update` messages the file holds.
    pub updates: u64,
    /// Why reading stopped early (a file whose writer was killed), if it did.
    pub truncated: Option<String>,
}

/// [`Ends`] of the recording at `path`, read as a stream: memory stays at about one chunk,
/// whatever the size of the file (a continual run's recording can outgrow the RAM that
/// [`read_recording`] needs). A file whose writer was killed gives its readable prefix.
pub fn read_ends(path: &Path) -> Result<Ends, RecordError> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
    use std::io::Read;
    let mut file = std::fs::File::open(path).map_err(|e| RecordError::io(path, e))?;
    let mut reader = LinearReader::new();
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    let mut ends = Ends::default();
    // Only the last one is decoded.
    let mut last_update: Vec<u8> = Vec::new();
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            Err(e) => {
                ends.truncated = Some(format!("records end early: {e}"));
                break;
            }
        };
        match event {
            LinearReadEvent::ReadRequest(wanted) => {
                let buf = reader.insert(wanted.max(1 << 16));
                let read = file.read(buf).map_err(|e| RecordError::io(path, e))?;
                reader.notify_read(read);
            }
            LinearReadEvent::Record { opcode, data } => match mcap::parse_record(opcode, data) {
                Ok(mcap::records::Record::Channel(c)) => {
                    topics.insert(c.id, c.topic);
                }
                Ok(mcap::records::Record::Message { header, data }) => {
                    match topics.get(&header.channel_id).map(String::as_str) {
                        Some(topics::RUN) if ends.run.is_none() => {
                            ends.run = Some(decode(path, topics::RUN, 0, "RunInfo", &data)?);
                        }
                        Some(topics::UPDATE) => {
                            ends.updates += 1;
                            last_update.clear();
                            last_update.extend_from_slice(&data);
                        }
                        _ => {}
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    ends.truncated = Some(format!("records end early: {e}"));
                    break;
                }
            },
        }
    }
    if ends.updates > 0 {
        let index = ends.updates - 1;
        ends.last_update = Some(decode(path, topics::UPDATE, index, "Update", &last_update)?);
    }
    Ok(ends)
}

impl Recording {
    /// Whether `next` goes on exactly where this recording ends, as a run resumed from it does
    /// (`--resume`): same seed, task shape and hyperparameters, its first update is the one
    /// after this recording's last, drawn from this recording's last new distribution, bit for
    /// bit. Judged by content, not by file name, so renamed or moved files still join.
    pub fn is_continued_by(&self, next: &Recording) -> bool {
        let (Some(last), Some(first)) = (self.updates.last(), next.updates.first()) else {
            return false;
        };
        first.update == last.update + 1
            && first.seed == last.seed
            && (first.dim, first.steps, first.rollouts) == (last.dim, last.steps, last.rollouts)
            && first.hyperparameters == last.hyperparameters
            && first.before.is_some()
            && first.before == last.after
    }

    /// This recording followed by `next` ([`Recording::is_continued_by`]), as one run: the
    /// messages of both in order, each `/run` kept (the second says where the run resumed),
    /// the metadata of the first, and the damage of the second (the first's end was resumed
    /// from, so nothing of it is missing).
    pub fn join(mut self, next: Recording) -> Recording {
        // A part without /summary still has its curve in /update.
        self.summaries = self.curve();
        self.summaries.extend(next.curve());
        self.file_bytes += next.file_bytes;
        self.indexed &= next.indexed;
        self.truncated = next.truncated;
        self.run.extend(next.run);
        self.updates.extend(next.updates);
        self.rollouts.extend(next.rollouts);
        self.task_changes.extend(next.task_changes);
        self.logs.extend(next.logs);
        for (topic, n) in next.topic_counts {
            *self.topic_counts.entry(topic).or_insert(0) += n;
        }
        self.time_range = match (self.time_range, next.time_range) {
            (Some((a, b)), Some((c, d))) => Some((a.min(c), b.max(d))),
            (a, b) => a.or(b),
        };
        self
    }
}

/// Recordings grouped into runs: each run is a recording followed by those that resume it
/// ([`Recording::is_continued_by`]), in any order given; runs are in the order of their first
/// file. Returns each run with the files it was joined from.
pub fn join_resumed(recs: Vec<Recording>) -> Vec<(Recording, Vec<PathBuf>)> {
    let n = recs.len();
    // The predecessor of each recording, if another one given ends where it starts.
    let mut successor: Vec<Option<usize>> = vec![None; n];
    let mut has_predecessor = vec![false; n];
    for (j, next) in recs.iter().enumerate() {
        if let Some(i) =
            (0..n).find(|&i| i != j && successor[i].is_none() && recs[i].is_continued_by(next))
        {
            successor[i] = Some(j);
            has_predecessor[j] = true;
        }
    }
    let mut slots: Vec<Option<Recording>> = recs.into_iter().map(Some).collect();
    let mut runs = Vec::new();
    for head in (0..n).filter(|&i| !has_predecessor[i]) {
        let Some(mut run) = slots[head].take() else {
            continue;
        };
        let mut parts = vec![run.path.clone()];
        let mut at = head;
        while let Some(j) = successor[at] {
            let Some(next) = slots[j].take() else { break };
            parts.push(next.path.clone());
            run = run.join(next);
            at = j;
        }
        runs.push((run, parts));
    }
    runs
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A recording of updates `from..to` of a 1-D run whose mean after update u is u + 1.
    fn part(name: &str, seed: u64, from: u64, to: u64) -> Recording {
        let d = |m: f64| proto::Distribution {
            dim: 1,
            mean: vec![m],
            covariance: vec![1.0],
        };
        Recording {
            path: name.into(),
            run: vec![proto::RunInfo {
                update: from,
                ..Default::default()
            }],
            updates: (from..to)
                .map(|u| proto::Update {
                    update: u,
                    seed,
                    before: Some(d(u as f64)),
                    after: Some(d(u as f64 + 1.0)),
                    ..Default::default()
                })
                .collect(),
            topic_counts: [("/update".to_string(), to - from)].into(),
            ..Default::default()
        }
    }

    /// Streamed, the ends of a recording are those of the whole read, for a finished file and
    /// for every prefix a killed writer can leave.
    #[test]
    fn streamed_ends_are_those_of_the_whole_recording() {
        let dir = std::env::temp_dir().join(format!("reader-ends-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(25);
        let mut rec = crate::McapRecorder::create(&path).unwrap();
        session::run_session(&cfg, 1, &mut rec).unwrap();
        rec.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.join("cut.mcap");
        let mut checked = 0;
        for end in [
            bytes.len(),
            bytes.len() - 9,
            bytes.len() * 9 / 10,
            bytes.len() / 2,
            bytes.len() / 5,
        ] {
            std::fs::write(&cut, &bytes[..end]).unwrap();
            let whole = read_recording(&cut).unwrap();
            let ends = read_ends(&cut).unwrap();
            assert_eq!(ends.run.as_ref(), whole.run_info());
            assert_eq!(ends.last_update.as_ref(), whole.updates.last());
            assert_eq!(ends.updates, whole.updates.len() as u64);
            assert_eq!(
                ends.truncated.is_some(),
                end < bytes.len(),
                "{:?}",
                ends.truncated
            );
            checked += ends.updates;
        }
        assert!(checked > 25, "the prefixes hold updates");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn resumed_parts_join_into_one_run_in_any_order() {
        let runs = join_resumed(vec![
            part("c", 1, 20, 30),
            part("other-seed", 2, 10, 20),
            part("a", 1, 0, 10),
            part("b", 1, 10, 20),
        ]);
        let parts: Vec<Vec<String>> = runs
            .iter()
            .map(|(_, p)| p.iter().map(|p| p.display().to_string()).collect())
            .collect();
        assert_eq!(parts, [vec!["other-seed"], vec!["a", "b", "c"]]);
        let (run, _) = &runs[1];
        let updates: Vec<u64> = run.updates.iter().map(|u| u.update).collect();
        assert_eq!(updates, (0..30).collect::<Vec<_>>());
        assert_eq!(run.curve().len(), 30);
        assert_eq!(run.run.len(), 3);
        assert_eq!(run.topic_counts["/update"], 30);

        // A part that does not start from the last distribution is another run.
        let mut moved = part("b", 1, 10, 20);
        moved.updates[0].before = Some(proto::Distribution {
            dim: 1,
            mean: vec![10.5],
            covariance: vec![1.0],
        });
        assert!(!part("a", 1, 0, 10).is_continued_by(&moved));
        assert_eq!(join_resumed(vec![part("a", 1, 0, 10), moved]).len(), 2);
    }
}
