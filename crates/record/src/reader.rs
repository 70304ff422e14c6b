//! Reading a recording back: every message of every topic, decoded, in file order. Works on
//! complete files and on files whose writer was killed (the readable prefix is returned and
//! the damage is reported in [`Recording::truncated`]).
//!
//! Every reader streams the file through mcap's sans-io reader ([`stream`]), so none holds the
//! file in memory. [`read_recording_slim`] keeps of the updates, rollouts, summaries and events
//! only their [`Digest`] (per update 48 bytes of scalars, the rest bounded), which
//! [`Recording::for_each_update`] and its siblings complete by streaming the files again for the
//! few uses that need every message, so analysing a continual run's recording takes memory for
//! its learning curve, not for its size or its messages.

use std::collections::BTreeMap;
use std::io::{Read, Seek};
use std::path::{Path, PathBuf};

use prost::Message;

use crate::{proto, topics, Digest, RecordError};

/// A decoded recording.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// The file read (the first, for a joined run).
    pub path: PathBuf,
    /// Its size in bytes (the sum of the files, for a joined run).
    pub file_bytes: u64,
    /// Whether the file has a summary section (i.e. was finished or recovered).
    pub indexed: bool,
    /// Why reading stopped early, if it did (a file whose writer was killed).
    pub truncated: Option<String>,
    /// MCAP metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// The `/run` messages: one per start or resume of the run in this file.
    pub run: Vec<proto::RunInfo>,
    /// Every update, read whole; read slim, only the first and the last of each file, without
    /// their bulk (what joining files into runs compares): `digest` has every update's scalars.
    pub updates: Vec<proto::Update>,
    /// Empty when read slim.
    pub summaries: Vec<proto::UpdateSummary>,
    /// Empty when read slim.
    pub rollouts: Vec<proto::Rollout>,
    /// The `/task_change` messages, in file order.
    pub task_changes: Vec<proto::TaskChange>,
    /// The `/unfinished_update` after the last `/update`, if the run stopped in the update after
    /// its last recorded one (pipeline recordings): the settings that update was to run with.
    pub unfinished: Option<proto::UnfinishedUpdate>,
    /// Empty when read slim.
    pub logs: Vec<proto::Log>,
    /// What analysis keeps of the messages, either way read.
    pub(crate) digest: Digest,
    /// Message counts per topic, including topics this reader does not know.
    pub topic_counts: BTreeMap<String, u64>,
    /// log_time (wall-clock ns since the Unix epoch) of the first and last message.
    pub time_range: Option<(u64, u64)>,
    /// The files read, in order (more than one for a joined run, [`Recording::join`]).
    pub files: Vec<PathBuf>,
    /// Whether the recording was read slim ([`read_recording_slim`]).
    pub slim: bool,
}

impl Recording {
    /// The `/run` message of the run (the first one, if the run was resumed into the same file).
    pub fn run_info(&self) -> Option<&proto::RunInfo> {
        self.run.first()
    }

    /// A value of the MCAP metadata record `pi2cma.run`.
    pub(crate) fn run_metadata(&self, key: &str) -> Option<&str> {
        self.metadata
            .get(topics::METADATA)
            .and_then(|m| m.get(key))
            .map(String::as_str)
    }

    /// The run name: from `/run`, else from the metadata, else the file name.
    pub fn name(&self) -> String {
        if let Some(r) = self.run_info() {
            return r.name.clone();
        }
        if let Some(n) = self.run_metadata("name") {
            return n.to_string();
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
        self.updates.iter().map(curve_row).collect()
    }

    /// Calls `f` with every update, bulk included, in order: from memory, or for a recording
    /// read slim, streamed from its files one update at a time.
    pub(crate) fn for_each_update(
        &self,
        f: impl FnMut(&proto::Update) -> Result<(), RecordError>,
    ) -> Result<(), RecordError> {
        self.for_each(topics::UPDATE, "Update", &self.updates, f)
    }

    /// Calls `f` with every `/update`, `/summary`, `/rollout` and `/log` message: from memory
    /// (topic by topic), or for a recording read slim, streamed from its files in one pass (in
    /// file order). Each topic's messages come in their order either way.
    pub(crate) fn for_each_message(
        &self,
        mut f: impl FnMut(Decoded<'_>) -> Result<(), RecordError>,
    ) -> Result<(), RecordError> {
        if !self.slim {
            self.updates
                .iter()
                .try_for_each(|m| f(Decoded::Update(m)))?;
            self.summaries
                .iter()
                .try_for_each(|m| f(Decoded::Summary(m)))?;
            self.rollouts
                .iter()
                .try_for_each(|m| f(Decoded::Rollout(m)))?;
            return self.logs.iter().try_for_each(|m| f(Decoded::Log(m)));
        }
        for file in &self.files {
            // Per topic, for the error naming a message that does not decode.
            let (mut updates, mut summaries, mut rollouts, mut logs) = (0, 0, 0, 0);
            let next = |count: &mut u64| {
                *count += 1;
                *count - 1
            };
            stream(file, |item| {
                let Item::Message { topic, data, .. } = item else {
                    return Ok(());
                };
                match topic {
                    topics::UPDATE => {
                        let i = next(&mut updates);
                        f(Decoded::Update(&decode(file, topic, i, "Update", data)?))
                    }
                    topics::SUMMARY => {
                        let i = next(&mut summaries);
                        f(Decoded::Summary(&decode(
                            file,
                            topic,
                            i,
                            "UpdateSummary",
                            data,
                        )?))
                    }
                    topics::ROLLOUT => {
                        let i = next(&mut rollouts);
                        f(Decoded::Rollout(&decode(file, topic, i, "Rollout", data)?))
                    }
                    topics::LOG => {
                        let i = next(&mut logs);
                        f(Decoded::Log(&decode(file, topic, i, "Log", data)?))
                    }
                    _ => Ok(()),
                }
            })?;
        }
        Ok(())
    }

    fn for_each<M: Message + Default>(
        &self,
        topic: &'static str,
        schema: &'static str,
        held: &[M],
        mut f: impl FnMut(&M) -> Result<(), RecordError>,
    ) -> Result<(), RecordError> {
        if !self.slim {
            return held.iter().try_for_each(f);
        }
        for file in &self.files {
            let mut index = 0;
            stream(file, |item| match item {
                Item::Message { topic: t, data, .. } if t == topic => {
                    index += 1;
                    f(&decode(file, topic, index - 1, schema, data)?)
                }
                _ => Ok(()),
            })?;
        }
        Ok(())
    }
}

/// A message [`Recording::for_each_message`] hands over.
pub enum Decoded<'a> {
    Update(&'a proto::Update),
    Summary(&'a proto::UpdateSummary),
    Rollout(&'a proto::Rollout),
    Log(&'a proto::Log),
}

/// The learning-curve row of an update: what its `/summary` message holds.
pub(crate) fn curve_row(u: &proto::Update) -> proto::UpdateSummary {
    proto::UpdateSummary {
        timestamp: u.timestamp,
        update: u.update,
        eval_cost: u.eval_cost,
        exploration_cost_mean: u.exploration_cost_mean,
        exploration_cost_std: u.exploration_cost_std,
        lambda: u.lambda,
        lambda_next: u.lambda_next,
        mean: u.after.as_ref().map(|d| d.mean.clone()).unwrap_or_default(),
    }
}

/// One record of a recording, as [`stream`] hands it over.
pub(crate) enum Item<'a> {
    Metadata(mcap::records::Metadata),
    Message {
        topic: &'a str,
        log_time: u64,
        data: &'a [u8],
    },
}

#[cfg(test)]
thread_local! {
    /// How many times this thread streamed a file: what tests of the number of passes count.
    pub(crate) static STREAMS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Streams the records of the recording at `path` (chunks decompressed, each checked against
/// its CRC) through mcap's sans-io reader, so memory stays at about one chunk whatever the size
/// of the file. Returns why reading stopped early (a file whose writer was killed: the records
/// before are all handed over), if it did.
pub(crate) fn stream(
    path: &Path,
    mut on: impl FnMut(Item<'_>) -> Result<(), RecordError>,
) -> Result<Option<String>, RecordError> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    #[cfg(test)]
    STREAMS.with(|n| n.set(n.get() + 1));
    let mut file = std::fs::File::open(path).map_err(|e| RecordError::io(path, e))?;
    // A file given by mistake (a config, a text) would otherwise read as a recording cut short
    // before its /run: its first bytes tell the user what it is. Fewer bytes than the magic that
    // begin it are a writer killed at once, which is a recording cut short.
    let mut head = Vec::with_capacity(mcap::MAGIC.len());
    (&mut file)
        .take(mcap::MAGIC.len() as u64)
        .read_to_end(&mut head)
        .map_err(|e| RecordError::io(path, e))?;
    if !could_be_mcap(&head) {
        return Err(RecordError::invalid(
            path,
            "not an MCAP file (it does not begin with the MCAP magic bytes), so not a pi2cma \
             recording",
        ));
    }
    file.rewind().map_err(|e| RecordError::io(path, e))?;
    // A chunk is checked against the CRC its writer computed before any of its messages is
    // handed over: damage is reported, never read as other numbers.
    // A damaged record length must fail as damage, not ask for that much memory.
    let len = file.metadata().map_err(|e| RecordError::io(path, e))?.len();
    let limit = record_length_limit(len);
    // Bytes of the file not yet read. A record outside a chunk is read into memory whole, so a
    // damaged length within `limit` would still have its buffer filled: reads ask for no more
    // than the file has left (past that, 64 KiB at a time: a file still being written grows).
    let mut left = len;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(limit),
    );
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            Err(
                e @ (mcap::McapError::ChunkTooLarge(_) | mcap::McapError::RecordTooLarge { .. }),
            ) => {
                return Ok(Some(format!(
                    "records end early: {e} (the limit, {limit} bytes, is the most this file's \
                     chunks can decompress to, or all of a chunk a reader here holds in memory)"
                )))
            }
            Err(e) => return Ok(Some(format!("records end early: {e}"))),
        };
        match event {
            LinearReadEvent::ReadRequest(wanted) => {
                let n = wanted.max(1 << 16);
                let n = usize::try_from(left).map_or(n, |left| n.min(left.max(1 << 16)));
                let read = file
                    .read(reader.insert(n))
                    .map_err(|e| RecordError::io(path, e))?;
                left = left.saturating_sub(read as u64);
                reader.notify_read(read);
            }
            LinearReadEvent::Record { opcode, .. } if opcode == crate::recover::OP_RESERVED => {
                return Ok(Some("records end early: opcode 0x00 (zeroed bytes)".into()))
            }
            LinearReadEvent::Record { opcode, data } => match mcap::parse_record(opcode, data) {
                Ok(mcap::records::Record::Channel(c)) => {
                    topics.insert(c.id, c.topic);
                }
                Ok(mcap::records::Record::Metadata(m)) => on(Item::Metadata(m))?,
                Ok(mcap::records::Record::Message { header, data }) => {
                    if let Some(topic) = topics.get(&header.channel_id) {
                        on(Item::Message {
                            topic,
                            log_time: header.log_time,
                            data: &data,
                        })?;
                    }
                }
                Ok(_) => {}
                Err(e) => return Ok(Some(format!("records end early: {e}"))),
            },
        }
    }
    Ok(None)
}

/// The longest record, or chunk decompressed, that [`stream`] takes from a file of `len` bytes:
/// a longer length is damage. No chunk decompresses to more than zstd's densest expansion of
/// the whole file ([`crate::recover::MAX_EXPANSION`]; lz4 and uncompressed chunks expand less).
/// A bound below that, 64 times the file, refused other programs' chunks that compress better
/// (zeroed buffers, one-colour images) as damage. mcap's reader fills as much memory as a
/// chunk's header says it decompresses to before it checks the chunk's CRC, so a damaged size
/// takes up to this limit: hence also [`MAX_CHUNK`], whatever the size of the file.
pub(crate) fn record_length_limit(len: u64) -> usize {
    usize::try_from(len)
        .unwrap_or(usize::MAX)
        .saturating_mul(crate::recover::MAX_EXPANSION)
        .min(MAX_CHUNK)
}

/// The most of a chunk, decompressed, that [`stream`] holds in memory: 1 GiB, against our
/// writer's chunks of about 8 MiB and other writers' default of 1 MiB.
pub(crate) const MAX_CHUNK: usize = 1 << 30;

/// Whether `head`, the first bytes of a file (up to the MCAP magic's length), is how an MCAP
/// file begins, or as much of it as a writer killed right after creating the file leaves.
pub(crate) fn could_be_mcap(head: &[u8]) -> bool {
    mcap::MAGIC.starts_with(&head[..head.len().min(mcap::MAGIC.len())])
}

/// Whether the file has a readable summary section (it was finished or recovered), read from
/// its end.
pub(crate) fn has_summary(path: &Path) -> Result<bool, RecordError> {
    let mut file = std::fs::File::open(path).map_err(|e| RecordError::io(path, e))?;
    let len = file.metadata().map_err(|e| RecordError::io(path, e))?.len();
    Ok(summary_of(&mut file, len)
        .map_err(|e| RecordError::io(path, e))?
        .is_some())
}

/// The summary section of an MCAP file of `len` bytes, read from its end; `None` if it has no
/// readable one (its writer was killed, or its end is damaged).
pub(crate) fn summary_of(
    file: &mut std::fs::File,
    len: u64,
) -> std::io::Result<Option<mcap::Summary>> {
    use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(len)
            .with_record_length_limit(usize::try_from(len).unwrap_or(usize::MAX)),
    );
    while let Some(event) = reader.next_event() {
        match event {
            Err(_) => return Ok(None),
            Ok(SummaryReadEvent::ReadRequest(n)) => {
                let read = file.read(reader.insert(n))?;
                reader.notify_read(read);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let pos = file.seek(to)?;
                reader.notify_seeked(pos);
            }
        }
    }
    Ok(reader.finish())
}

/// The error for a file without a `/run` message, which every recording writes and flushes
/// before its first update: another file given by mistake (a config, an empty file, another
/// program's MCAP), or one cut before anything was recorded.
fn no_run(path: &Path, why: Option<&str>) -> RecordError {
    RecordError::invalid(
        path,
        format!(
            "not a pi2cma recording: no /run message{}",
            why.map(|w| format!(" ({w})")).unwrap_or_default()
        ),
    )
}

/// The error for a finished file that does not read to its end: damaged bytes, which
/// `recover` reads past.
fn damaged(path: &Path, why: &str) -> RecordError {
    RecordError::invalid(
        path,
        format!(
            "{why} (the file is damaged; `pi2cma recover {0}` or `mcap-tool recover {0}` keeps \
             every undamaged chunk)",
            path.display()
        ),
    )
}

/// The first `/run` message and the last complete `/update` of a recording.
#[derive(Debug, Clone, Default)]
pub struct Ends {
    /// The first `/run` message, if the file has one.
    pub run: Option<proto::RunInfo>,
    /// The last complete `/update` message, if any.
    pub last_update: Option<proto::Update>,
    /// How many `/update` messages the file holds.
    pub updates: u64,
    /// The `/task_change` messages after the last `/update`: changes that take effect at the
    /// update after it (a run stopped right after a task change).
    pub changes_after: Vec<proto::TaskChange>,
    /// The `/unfinished_update` after the last `/update`: all the settings the update after
    /// it was to run with, if the run stopped in that update.
    pub unfinished: Option<proto::UnfinishedUpdate>,
    /// The file's metadata record `pi2cma.run` (`resumed_from`, `previous_part`, …).
    pub metadata: BTreeMap<String, String>,
    /// Why reading stopped early (a file whose writer was killed), if it did.
    pub truncated: Option<String>,
}

/// The metadata record `pi2cma.run` of the recording at `path` (any part of one), read from the
/// file's start, where its writer puts it: what a recording resumed (`resumed_from`), without
/// streaming a part of gigabytes through.
pub fn read_run_metadata(path: &Path) -> Result<BTreeMap<String, String>, RecordError> {
    let mut found = None;
    let read = stream(path, |item| match item {
        Item::Metadata(m) if m.name == topics::METADATA => {
            found = Some(m.metadata);
            // Ends the reading: nothing after it is needed (the error is not reported).
            Err(RecordError::invalid(path, "read up to its metadata"))
        }
        _ => Ok(()),
    });
    match (found, read) {
        (Some(meta), _) => Ok(meta),
        (None, Err(e)) => Err(e),
        (None, Ok(_)) => Err(RecordError::invalid(
            path,
            format!("no metadata record {}", topics::METADATA),
        )),
    }
}

/// [`Ends`] of the recording at `path`, read as a stream: memory stays at about one chunk,
/// whatever the size of the file (a continual run's recording can outgrow the RAM that
/// [`read_recording`] needs). A file whose writer was killed gives its readable prefix.
pub fn read_ends(path: &Path) -> Result<Ends, RecordError> {
    let mut ends = Ends::default();
    // Only the last one is decoded.
    let mut last_update: Vec<u8> = Vec::new();
    ends.truncated = stream(path, |item| {
        match item {
            Item::Message {
                topic: topics::RUN,
                data,
                ..
            } if ends.run.is_none() => {
                ends.run = Some(decode(path, topics::RUN, 0, "RunInfo", data)?);
            }
            Item::Message {
                topic: topics::UPDATE,
                data,
                ..
            } => {
                ends.updates += 1;
                last_update.clear();
                last_update.extend_from_slice(data);
                ends.changes_after.clear();
                ends.unfinished = None;
            }
            Item::Message {
                topic: topics::UNFINISHED_UPDATE,
                data,
                ..
            } => {
                ends.unfinished = Some(decode(
                    path,
                    topics::UNFINISHED_UPDATE,
                    0,
                    "UnfinishedUpdate",
                    data,
                )?);
            }
            Item::Metadata(m) if m.name == topics::METADATA => ends.metadata = m.metadata,
            Item::Message {
                topic: topics::TASK_CHANGE,
                data,
                ..
            } => {
                let index = ends.changes_after.len() as u64;
                ends.changes_after.push(decode(
                    path,
                    topics::TASK_CHANGE,
                    index,
                    "TaskChange",
                    data,
                )?);
            }
            _ => {}
        }
        Ok(())
    })?;
    if ends.run.is_none() {
        return Err(no_run(path, ends.truncated.as_deref()));
    }
    // A finished file is whole: its end is not where the damage is (resuming there would
    // redo, and record twice, the updates after it).
    if let Some(why) = &ends.truncated {
        if has_summary(path)? {
            return Err(damaged(path, why));
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
    /// bit. Judged by content, not by file name, so renamed or moved files still join. A
    /// recording without updates (a run stopped in its first update, or in the first of a
    /// restarted recorder's part) ends where its `/run` begins, with the distribution it gives.
    pub(crate) fn is_continued_by(&self, next: &Recording) -> bool {
        let Some(first) = next.updates.first() else {
            return false;
        };
        let Some(last) = self.updates.last() else {
            return self.run.last().is_some_and(|began| {
                first.update == began.update
                    && first.seed == began.seed
                    && (first.dim, first.steps) == (began.dim, began.steps)
                    && first.hyperparameters == began.hyperparameters
                    && first.before.is_some()
                    && first.before == began.initial
            });
        };
        first.update == last.update + 1
            && first.seed == last.seed
            && (first.dim, first.steps, first.rollouts) == (last.dim, last.steps, last.rollouts)
            && first.hyperparameters == last.hyperparameters
            && first.before.is_some()
            && first.before == last.after
    }

    /// Whether `next` is the part a restarted pipeline recorder began after this one's recorder
    /// died: metadata `recorder_restart`, the same `run_id` (a random 64-bit id per run), this
    /// recording's last file as its `previous_part` (by file name, so that moved files still
    /// join), the same seed, task shape and hyperparameters, and a later first update. The
    /// updates between them, which the dead recorder had not written, are missing from the
    /// joined run (the info summary lists them).
    pub(crate) fn is_continued_after_restart_by(&self, next: &Recording) -> bool {
        let meta = Recording::run_metadata;
        let previous_is_mine = meta(next, "previous_part")
            .and_then(|p| Path::new(p).file_name())
            .is_some_and(|p| self.files.last().and_then(|f| f.file_name()) == Some(p));
        let same_run = meta(next, "recorder_restart").is_some()
            && meta(next, "run_id").is_some()
            && meta(next, "run_id") == meta(self, "run_id")
            && previous_is_mine;
        let (Some(mine), Some(theirs)) = (self.run_info(), next.run_info()) else {
            return false;
        };
        // Where this recording ends: after its last update, or where it began if the recorder
        // died before writing one.
        let end = self.updates.last().map_or(mine.update, |u| u.update + 1);
        same_run
            && theirs.update >= end
            && (theirs.seed, theirs.dim, theirs.steps) == (mine.seed, mine.dim, mine.steps)
            && theirs.hyperparameters == mine.hyperparameters
    }

    /// This recording followed by `next`, which resumes it (see [`join_resumed`]), as one run: the
    /// messages of both in order, each `/run` kept (the second says where the run resumed),
    /// the metadata of the first, and the damage of the second (the first's end was resumed
    /// from, so nothing of it is missing).
    pub fn join(mut self, next: Recording) -> Recording {
        // A part without /summary still has its curve in /update (read whole: slim, the digest
        // has the curve and the summaries are streamed).
        if !(self.slim || next.slim) {
            self.summaries = self.curve();
            self.summaries.extend(next.curve());
        }
        self.digest.append(next.digest);
        self.file_bytes += next.file_bytes;
        self.files.extend(next.files);
        self.slim |= next.slim;
        self.indexed &= next.indexed;
        self.truncated = next.truncated;
        self.run.extend(next.run);
        self.updates.extend(next.updates);
        self.unfinished = next.unfinished;
        self.rollouts.extend(next.rollouts);
        // A change at the update where `next` begins can be in both: recorded at the end of
        // this one (the run stopped right after it) and at the start of `next` (in-process).
        for c in next.task_changes {
            if !self.task_changes.iter().any(|t| {
                (t.update, &t.name, t.value.to_bits()) == (c.update, &c.name, c.value.to_bits())
            }) {
                self.task_changes.push(c);
            }
        }
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
/// (same seed, task shape and hyperparameters, first update the one after its last, drawn from
/// its last new distribution bit for bit; judged by content, not file name) or that a
/// restarted pipeline recorder went on with (metadata `recorder_restart`, the same `run_id`,
/// `previous_part` naming its last file), in any order given; runs are in the order of their
/// first file. Returns each run with the files it was joined from.
pub fn join_resumed(recs: Vec<Recording>) -> Vec<(Recording, Vec<PathBuf>)> {
    let n = recs.len();
    // The predecessor of each recording, if another one given ends where it starts.
    let mut successor: Vec<Option<usize>> = vec![None; n];
    let mut has_predecessor = vec![false; n];
    for (j, next) in recs.iter().enumerate() {
        if let Some(i) = (0..n).find(|&i| {
            i != j
                && successor[i].is_none()
                && (recs[i].is_continued_by(next) || recs[i].is_continued_after_restart_by(next))
        }) {
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
    read(path, false, &mut |_, _| {})
}

/// Reads and decodes a recording slim ([`Recording::slim`]): of `/update` only the first and the
/// last are kept, without their bulk (`samples`, `cost_per_step`, `cost_terminal`, `cost_total`
/// and `weights` left empty), and `/summary`, `/rollout` and `/log` are not kept; every update's scalars are
/// in the crate's digest (the learning curve, what `analyze` needs). [`read_recording`] reads
/// every message whole.
pub fn read_recording_slim(path: &Path) -> Result<Recording, RecordError> {
    read(path, true, &mut |_, _| {})
}

/// [`read_recording_slim`] that hands every `/update`, bulk included, to `each` as it is read,
/// with the first `/run` read before it: what needs every update whole (`verify`) without
/// streaming the file a second time.
pub fn read_recording_slim_with(
    path: &Path,
    mut each: impl FnMut(Option<&proto::RunInfo>, &proto::Update),
) -> Result<Recording, RecordError> {
    read(path, true, &mut each)
}

fn read(
    path: &Path,
    slim: bool,
    each: &mut dyn FnMut(Option<&proto::RunInfo>, &proto::Update),
) -> Result<Recording, RecordError> {
    let mut rec = Recording {
        path: path.to_path_buf(),
        file_bytes: std::fs::metadata(path)
            .map_err(|e| RecordError::io(path, e))?
            .len(),
        indexed: has_summary(path)?,
        files: vec![path.to_path_buf()],
        slim,
        ..Default::default()
    };
    let truncated = stream(path, |item| {
        let (topic, log_time, data) = match item {
            Item::Metadata(m) => {
                rec.metadata.insert(m.name, m.metadata);
                return Ok(());
            }
            Item::Message {
                topic,
                log_time,
                data,
            } => (topic, log_time, data),
        };
        let count = rec.topic_counts.entry(topic.to_string()).or_insert(0);
        let index = *count;
        *count += 1;
        rec.time_range = Some(match rec.time_range {
            None => (log_time, log_time),
            Some((a, b)) => (a.min(log_time), b.max(log_time)),
        });
        match topic {
            topics::RUN => rec.run.push(decode(path, topic, index, "RunInfo", data)?),
            topics::UPDATE => {
                let mut u: proto::Update = decode(path, topic, index, "Update", data)?;
                each(rec.run.first(), &u);
                rec.digest.add_update(&u);
                if slim {
                    u.samples = Vec::new();
                    u.cost_per_step = Vec::new();
                    u.cost_terminal = Vec::new();
                    u.cost_total = Vec::new();
                    u.weights = Vec::new();
                    // The first and the last: what joining compares.
                    rec.updates.truncate(1);
                }
                rec.updates.push(u);
                rec.unfinished = None;
            }
            topics::UNFINISHED_UPDATE => {
                rec.unfinished = Some(decode(path, topic, index, "UnfinishedUpdate", data)?);
            }
            topics::SUMMARY => {
                let s = decode(path, topic, index, "UpdateSummary", data)?;
                if !slim {
                    rec.summaries.push(s);
                }
            }
            topics::ROLLOUT => {
                let r = decode(path, topic, index, "Rollout", data)?;
                rec.digest.add_rollout(&r);
                if !slim {
                    rec.rollouts.push(r);
                }
            }
            topics::TASK_CHANGE => {
                let c = decode(path, topic, index, "TaskChange", data)?;
                rec.digest.add_task_change(&c);
                rec.task_changes.push(c);
            }
            topics::LOG => {
                let l = decode(path, topic, index, "Log", data)?;
                rec.digest.add_log(&l);
                if !slim {
                    rec.logs.push(l);
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    // A run that ended before its first update (a worker that cannot start) recorded only its
    // health events: still ours (every topic one of ours, events on /log), and what the user
    // wants to read. Anything else without /run is some other file.
    let only_events = !rec.digest.events.is_empty()
        && rec
            .topic_counts
            .keys()
            .all(|t| topics::ALL.iter().any(|(ours, _)| ours == t));
    if rec.run.is_empty() && !only_events {
        return Err(no_run(path, truncated.as_deref()));
    }
    // A finished file is whole: damage inside it is an error, not a killed writer's end.
    if let Some(why) = truncated {
        if rec.indexed {
            return Err(damaged(path, &why));
        }
        rec.truncated = Some(why);
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

    /// A restarted recorder's part joins the part its predecessor left, across the updates
    /// neither wrote, and only when its metadata ties it to that part of the same run.
    #[test]
    fn a_restarted_recorders_part_joins_across_the_gap_only_with_its_own_run() {
        let with_meta = |mut r: Recording, meta: &[(&str, &str)]| {
            r.files = vec![r.path.clone()];
            let meta = meta.iter().map(|(k, v)| (k.to_string(), v.to_string()));
            r.metadata
                .insert(topics::METADATA.to_string(), meta.collect());
            r
        };
        let run_id = ("run_id", "00000000000000aa");
        let first = with_meta(part("dir/a.mcap", 7, 0, 10), &[run_id]);
        // Moved elsewhere since: joined by the previous part's file name.
        let restart = [
            run_id,
            ("recorder_restart", "1"),
            ("previous_part", "/elsewhere/a.mcap"),
        ];
        let second = with_meta(part("dir/a.part-2.mcap", 7, 13, 20), &restart);
        assert!(first.is_continued_after_restart_by(&second));
        assert!(!first.is_continued_by(&second));
        let runs = join_resumed(vec![second.clone(), first.clone()]);
        assert_eq!(runs.len(), 1);
        let joined: Vec<u64> = runs[0].0.updates.iter().map(|u| u.update).collect();
        assert_eq!(joined, (0..10).chain(13..20).collect::<Vec<_>>());
        let untied = [
            vec![("run_id", "00000000000000bb"), restart[1], restart[2]],
            vec![run_id, restart[2]],
            vec![run_id, restart[1], ("previous_part", "b.mcap")],
            vec![restart[1], restart[2]],
        ];
        for meta in untied {
            let other = with_meta(part("dir/a.part-2.mcap", 7, 13, 20), &meta);
            assert!(!first.is_continued_after_restart_by(&other), "{meta:?}");
            assert_eq!(join_resumed(vec![first.clone(), other]).len(), 2);
        }
        // Overlapping the first part: not a continuation.
        let early = with_meta(part("dir/a.part-2.mcap", 7, 5, 20), &restart);
        assert!(!first.is_continued_after_restart_by(&early));
    }

    /// `/unfinished_update` is read into the recording: it was only in [`read_ends`], so a user
    /// reading every topic with [`read_recording`] could not see it.
    #[test]
    fn read_recording_holds_the_unfinished_update() {
        let dir = std::env::temp_dir().join(format!("reader-unfinished-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let mut w = crate::RunWriter::create(&path).unwrap();
        w.write_event(0, crate::Event::Start, "updater", 1, "ready")
            .unwrap();
        w.write_unfinished_update(7, &[("viapoint", 0.1)], false)
            .unwrap();
        w.finish().unwrap();
        let rec = read_recording(&path).unwrap();
        let u = rec
            .unfinished
            .as_ref()
            .expect("the /unfinished_update read");
        assert_eq!(u.update, 7);
        assert_eq!(
            (u.task_settings[0].name.as_str(), u.task_settings[0].value),
            ("viapoint", 0.1)
        );
        // A finished recording has none.
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(2);
        let finished = dir.join("b.mcap");
        crate::testing::record_session(&cfg, 1, &finished);
        assert_eq!(read_recording(&finished).unwrap().unfinished, None);
        std::fs::remove_dir_all(&dir).unwrap();
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
        crate::testing::record_session(&cfg, 1, &path);
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
            // Read slim, the same recording without the bulk, which streams back in full.
            let slim = read_recording_slim(&cut).unwrap();
            assert!(slim.slim && !whole.slim);
            assert_eq!(slim.digest, whole.digest);
            assert_eq!(slim.digest.points.len(), whole.updates.len());
            assert_eq!(
                (
                    slim.indexed,
                    &slim.truncated,
                    &slim.topic_counts,
                    slim.time_range
                ),
                (
                    whole.indexed,
                    &whole.truncated,
                    &whole.topic_counts,
                    whole.time_range
                )
            );
            assert_eq!(
                (&slim.run, &slim.task_changes, &slim.metadata),
                (&whole.run, &whole.task_changes, &whole.metadata)
            );
            // Of the updates only the first and the last, without their bulk.
            let ends: Vec<&proto::Update> = match whole.updates.as_slice() {
                [] => vec![],
                [one] => vec![one],
                [first, .., last] => vec![first, last],
            };
            assert_eq!(slim.updates.len(), ends.len());
            for (s, w) in slim.updates.iter().zip(ends) {
                assert!(s.samples.is_empty() && s.cost_per_step.is_empty());
                assert!(s.cost_terminal.is_empty() && s.weights.is_empty());
                assert!(s.cost_total.is_empty());
                let bulk = proto::Update {
                    samples: w.samples.clone(),
                    cost_per_step: w.cost_per_step.clone(),
                    cost_terminal: w.cost_terminal.clone(),
                    cost_total: w.cost_total.clone(),
                    weights: w.weights.clone(),
                    ..s.clone()
                };
                assert_eq!(&bulk, w);
            }
            assert!(slim.summaries.is_empty() && slim.rollouts.is_empty() && slim.logs.is_empty());
            // Streamed back, every message is there, in order.
            let mut streamed = Vec::new();
            slim.for_each_update(|u| {
                streamed.push(u.clone());
                Ok(())
            })
            .unwrap();
            assert_eq!(streamed, whole.updates);
            let mut again = Recording::default();
            slim.for_each_message(|m| {
                match m {
                    Decoded::Update(u) => again.updates.push(u.clone()),
                    Decoded::Summary(s) => again.summaries.push(s.clone()),
                    Decoded::Rollout(r) => again.rollouts.push(r.clone()),
                    Decoded::Log(l) => again.logs.push(l.clone()),
                }
                Ok(())
            })
            .unwrap();
            assert_eq!(
                (
                    &again.updates,
                    &again.summaries,
                    &again.rollouts,
                    &again.logs
                ),
                (
                    &whole.updates,
                    &whole.summaries,
                    &whole.rollouts,
                    &whole.logs
                )
            );
        }
        assert!(checked > 25, "the prefixes hold updates");

        // A finished file damaged inside is an error naming it, not a killed writer's prefix.
        let mut damaged = bytes.clone();
        let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
        let chunk = &summary.chunk_indexes[summary.chunk_indexes.len() / 2];
        // Inside the chunk's compressed records, which zstd would decode into other numbers.
        let middle = (chunk.chunk_start_offset + chunk.chunk_length / 2) as usize;
        damaged[middle..middle + 16].fill(0xff);
        std::fs::write(&cut, &damaged).unwrap();
        let e = match read_recording_slim(&cut) {
            Ok(r) => panic!("a damaged file read as {} updates", r.updates.len()),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("cut.mcap") && e.contains("recover"), "{e}");
        // Resume's reader too: the end of a finished file is not where its damage is.
        let e = read_ends(&cut).unwrap_err().to_string();
        assert!(e.contains("cut.mcap") && e.contains("recover"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Writes `content` to `path` and returns the error each reader gives for it.
    fn errors_of_every_reader(path: &Path, content: &[u8]) -> [String; 3] {
        std::fs::write(path, content).unwrap();
        [
            read_recording(path).unwrap_err().to_string(),
            read_recording_slim(path).unwrap_err().to_string(),
            read_ends(path).unwrap_err().to_string(),
        ]
    }

    /// A file that is not a recording (another program's MCAP, an empty file, a recording cut
    /// before its /run was flushed, even within the magic) is an error naming it, not a
    /// recording of 0 updates. (Files that are no MCAP at all: the test after this one.)
    #[test]
    fn a_file_without_a_run_message_is_not_a_recording() {
        let dir = std::env::temp_dir().join(format!("reader-no-run-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.mcap");
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(2);
        crate::testing::record_session(&cfg, 1, &path);
        let bytes = std::fs::read(&path).unwrap();
        let mut other = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
        other.finish().unwrap();
        let other = other.into_inner().into_inner();
        for (name, content) in [
            ("other.mcap", other),
            ("empty.mcap", Vec::new()),
            ("magic.mcap", bytes[..5].to_vec()),
            ("head.mcap", bytes[..100].to_vec()),
        ] {
            for e in errors_of_every_reader(&dir.join(name), &content) {
                assert!(
                    e.contains(name) && e.contains("not a pi2cma recording"),
                    "{e}"
                );
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Another program's MCAP whose chunks compress well (images of one colour, zeroed buffers)
    /// read as cut short: the readers refused chunks that decompress to more than 64 times the
    /// file ("records end early: chunk (de)compressed length exceeds limit"), so `info` added
    /// that to "not a pi2cma recording". Such chunks read whole; a damaged length past what the
    /// file can hold (a chunk's decompressed size, a record's length) is still refused.
    #[test]
    fn chunks_that_compress_well_read_whole_and_damaged_lengths_are_refused() {
        let dir = std::env::temp_dir().join(format!("reader-zeros-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("zeros.mcap");
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .create(std::io::BufWriter::new(
                std::fs::File::create(&path).unwrap(),
            ))
            .unwrap();
        let channel = w.add_channel(0, "/blob", "", &BTreeMap::new()).unwrap();
        // 80 MiB of zeros in one chunk: a few kB in the file.
        let message = vec![0u8; 80 << 20];
        for t in 0..2 {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: t,
                log_time: t.into(),
                publish_time: t.into(),
            };
            w.write_to_known_channel(&header, &message).unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.len() < 64 << 10, "{} bytes", bytes.len());
        let mut sizes = Vec::new();
        let stopped = stream(&path, |item| {
            if let Item::Message { topic, data, .. } = item {
                sizes.push((topic.to_string(), data.len()));
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(stopped, None);
        assert_eq!(sizes, vec![("/blob".to_string(), 80 << 20); 2]);
        let e = read_recording_slim(&path).unwrap_err().to_string();
        assert!(
            e.contains("no /run message") && !e.contains("end early"),
            "{e}"
        );

        // Damaged lengths: the first chunk's decompressed size (a 1 in its top byte, then all
        // of it), and the length of the record after it, read as up to 2^64 bytes.
        let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
        let chunk = summary.chunk_indexes[0].chunk_start_offset as usize;
        let next = (chunk + 9)
            + u64::from_le_bytes(bytes[chunk + 1..chunk + 9].try_into().unwrap()) as usize;
        // opcode, record length, start and end time: then the uncompressed size.
        let size = chunk + 9 + 16;
        let damaged = dir.join("damaged.mcap");
        for (at, value) in [
            (size + 7, vec![0x01]),
            (size, vec![0xff; 8]),
            (next + 1, vec![0xff; 8]),
            (next + 1, (1u64 << 30).to_le_bytes().to_vec()),
        ] {
            let mut b = bytes.clone();
            b[at..at + value.len()].copy_from_slice(&value);
            std::fs::write(&damaged, &b).unwrap();
            let stopped = stream(&damaged, |_| Ok(())).unwrap();
            assert!(
                stopped.as_deref().unwrap_or("").contains("end early"),
                "{value:?} at {at}: {stopped:?}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A text file given by mistake used to read as an MCAP file cut short ("no /run message
    /// (records end early: MCAP file ended in the middle of a record)", found by a user test of
    /// the README). Its first bytes tell that it is no MCAP file at all.
    #[test]
    fn a_file_without_the_mcap_magic_is_named_as_no_mcap_file() {
        let dir = std::env::temp_dir().join(format!("reader-no-magic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, content) in [
            ("notmcap.mcap", &b"just some text, not a recording\n"[..]),
            ("config.toml", &b"[run]\nupdates = 5\n"[..]),
            ("short.mcap", &b"txt"[..]),
        ] {
            for e in errors_of_every_reader(&dir.join(name), content) {
                assert!(
                    e.contains(name) && e.contains("not an MCAP file") && !e.contains("/run"),
                    "{e}"
                );
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_run_that_ended_before_its_first_update_reads_as_its_events() {
        let dir = std::env::temp_dir().join(format!("reader-events-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("failed.mcap");
        let mut w = crate::RunWriter::create(&path).unwrap();
        w.write_event(0, crate::Event::Crash, "worker-1", 42, "worker-1 crashed")
            .unwrap();
        w.finish().unwrap();
        let rec = read_recording(&path).unwrap();
        assert!(rec.run.is_empty() && rec.updates.is_empty());
        assert_eq!(rec.logs.len(), 1);
        assert_eq!(rec.logs[0].pid, 42);
        let info = crate::analyze::info(&rec);
        assert!(info.contains("no update recorded"), "{info}");
        assert!(info.contains("crash worker-1: worker-1 crashed"), "{info}");
        // Nothing to resume from.
        assert!(read_ends(&path).is_err());
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

    /// A recording without updates (a run stopped in its first update; a restarted recorder's
    /// part that the run stopped in, as `stop --after-update` in the update the recorder died
    /// in leaves it) is joined by the run resumed from it: `analyze` made that run a session of
    /// its own beside the parts (`2 sessions in 1 run(s)`, statistics NaN).
    #[test]
    fn a_recording_without_updates_joins_the_run_resumed_from_it() {
        let began = |seed: u64, at: u64, mean: f64| {
            let mut r = part("began", seed, at, at);
            r.run[0].seed = seed;
            r.run[0].initial = Some(proto::Distribution {
                dim: 1,
                mean: vec![mean],
                covariance: vec![1.0],
            });
            r
        };
        // `part`'s update u is drawn from mean u.
        assert!(began(1, 4, 4.0).is_continued_by(&part("resumed", 1, 4, 8)));
        let runs = join_resumed(vec![part("resumed", 1, 4, 8), began(1, 4, 4.0)]);
        assert_eq!(runs.len(), 1);
        let files: Vec<String> = runs[0].1.iter().map(|p| p.display().to_string()).collect();
        assert_eq!(files, ["began", "resumed"]);
        let updates: Vec<u64> = runs[0].0.updates.iter().map(|u| u.update).collect();
        assert_eq!(updates, (4..8).collect::<Vec<_>>());
        // Not where it began, not from its distribution, another seed: other runs.
        for other in [began(1, 3, 4.0), began(1, 4, 4.5), began(2, 4, 4.0)] {
            assert!(!other.is_continued_by(&part("resumed", 1, 4, 8)));
        }
        assert!(!began(1, 4, 4.0).is_continued_by(&began(1, 4, 4.0)));
    }
}
