//! `recover`: rewrite a recording whose writer was killed (no summary, possibly a torn chunk at
//! the end) into a complete, indexed MCAP holding every readable record.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};

use mcap::read::ChunkReader;
use mcap::records::{MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Compression, WriteOptions};

use crate::RecordError;

/// What `recover` kept and dropped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecoverReport {
    pub input: PathBuf,
    pub output: PathBuf,
    pub messages: u64,
    pub metadata: u64,
    pub attachments: u64,
    /// Bytes at the end of the input that could not be read (the chunk in flight).
    pub dropped_bytes: u64,
    /// Why reading stopped, if the input was damaged.
    pub stopped_by: Option<String>,
    /// The last part of the split recording the input belongs to, if that is another file:
    /// the only part a killed writer leaves unfinished.
    pub last_part: Option<PathBuf>,
}

/// Copies every readable schema, channel, message, metadata and attachment record of `input`
/// into a new, finished MCAP at `output` (zstd chunks, full indexes). `output` may be `input`:
/// the result is written next to it and renamed over it. The input is read as a stream, a
/// chunk at a time, so a continual run's recording recovers in little memory.
pub fn recover(input: &Path, output: &Path) -> Result<RecoverReport, RecordError> {
    let mut file = File::open(input).map_err(|e| RecordError::io(input, e))?;
    let input_len = file
        .metadata()
        .map_err(|e| RecordError::io(input, e))?
        .len();
    let tmp = tmp_path(output);
    let f = File::create(&tmp).map_err(|e| RecordError::io(&tmp, e))?;
    let mut w = WriteOptions::new()
        .compression(Some(Compression::Zstd))
        .compression_threads(0)
        .library(concat!(
            "pi2cma-record/",
            env!("CARGO_PKG_VERSION"),
            " recover"
        ))
        .create(BufWriter::new(f))
        .map_err(|e| RecordError::mcap(&tmp, e))?;
    let mut report = RecoverReport {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        ..Default::default()
    };
    let mut copier = Copier {
        schemas: HashMap::new(),
        channels: HashMap::new(),
        tmp: &tmp,
    };
    // Top-level records as they are (chunks still compressed): a chunk is decoded, and its CRC
    // checked, by `ChunkReader`, and kept only if all of it decodes.
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_emit_chunks(true),
    );
    // Byte offset just past the last record that was copied whole (after the leading magic).
    let mut good_end: u64 = 8;
    while let Some(event) = reader.next_event() {
        let (opcode, body) = match event {
            Ok(LinearReadEvent::ReadRequest(wanted)) => {
                let buf = reader.insert(wanted.max(1 << 16));
                let read = file.read(buf).map_err(|e| RecordError::io(input, e))?;
                reader.notify_read(read);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => (opcode, data),
            Err(e) => {
                report.stopped_by = Some(e.to_string());
                break;
            }
        };
        // opcode, length, body.
        let record_len = 1 + 8 + body.len() as u64;
        let record = match mcap::parse_record(opcode, body) {
            Ok(r) => r,
            Err(e) => {
                report.stopped_by = Some(e.to_string());
                break;
            }
        };
        match record {
            Record::Chunk { header, data } => {
                let inner: Result<Vec<Record<'_>>, _> =
                    ChunkReader::new(header, &data).and_then(|r| r.collect());
                match inner {
                    Ok(records) => {
                        for r in records {
                            copier.copy(&mut w, r, &mut report)?;
                        }
                    }
                    Err(e) => {
                        report.stopped_by = Some(format!("damaged chunk: {e}"));
                        break;
                    }
                }
            }
            Record::DataEnd(_) | Record::Footer(_) => {
                good_end = input_len;
                break;
            }
            other => copier.copy(&mut w, other, &mut report)?,
        }
        good_end += record_len;
    }
    if report.stopped_by.is_some() {
        report.dropped_bytes = input_len.saturating_sub(good_end);
    }
    w.finish().map_err(|e| RecordError::mcap(&tmp, e))?;
    let mut inner = w.into_inner();
    std::io::Write::flush(&mut inner).map_err(|e| RecordError::io(&tmp, e))?;
    drop(inner);
    std::fs::rename(&tmp, output).map_err(|e| RecordError::io(output, e))?;
    Ok(report)
}

fn tmp_path(output: &Path) -> PathBuf {
    let mut name = output
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".recover-tmp");
    output.with_file_name(name)
}

struct Copier<'p> {
    /// Input schema id → output schema id.
    schemas: HashMap<u16, u16>,
    channels: HashMap<u16, u16>,
    tmp: &'p Path,
}

impl Copier<'_> {
    fn copy(
        &mut self,
        w: &mut mcap::Writer<BufWriter<File>>,
        record: Record<'_>,
        report: &mut RecoverReport,
    ) -> Result<(), RecordError> {
        let err = |e| RecordError::mcap(self.tmp, e);
        match record {
            Record::Schema { header, data } => {
                let id = w
                    .add_schema(&header.name, &header.encoding, &data)
                    .map_err(err)?;
                self.schemas.insert(header.id, id);
            }
            Record::Channel(c) => {
                let schema = if c.schema_id == 0 {
                    0
                } else {
                    match self.schemas.get(&c.schema_id) {
                        Some(&s) => s,
                        None => {
                            return Err(RecordError::invalid(
                                self.tmp,
                                format!(
                                    "channel {} ({}) refers to unknown schema {}",
                                    c.id, c.topic, c.schema_id
                                ),
                            ))
                        }
                    }
                };
                let id = w
                    .add_channel(schema, &c.topic, &c.message_encoding, &c.metadata)
                    .map_err(err)?;
                self.channels.insert(c.id, id);
            }
            Record::Message { header, data } => {
                let Some(&channel_id) = self.channels.get(&header.channel_id) else {
                    return Err(RecordError::invalid(
                        self.tmp,
                        format!(
                            "message {} on unknown channel {}",
                            header.sequence, header.channel_id
                        ),
                    ));
                };
                w.write_to_known_channel(
                    &MessageHeader {
                        channel_id,
                        ..header
                    },
                    &data,
                )
                .map_err(err)?;
                report.messages += 1;
            }
            Record::Metadata(m) => {
                w.write_metadata(&m).map_err(err)?;
                report.metadata += 1;
            }
            Record::Attachment { header, data, .. } => {
                w.attach(&mcap::Attachment {
                    log_time: header.log_time,
                    create_time: header.create_time,
                    name: header.name,
                    media_type: header.media_type,
                    data: std::borrow::Cow::Borrowed(&data),
                })
                .map_err(err)?;
                report.attachments += 1;
            }
            // Indexes and statistics are rebuilt by the writer.
            _ => {}
        }
        Ok(())
    }
}

/// `recover FILE [--out OUT]`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecoverArgs {
    /// The damaged recording.
    pub file: PathBuf,
    /// Where to write the recovered file; without it the input is replaced.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
}

/// Runs `recover` as given on a command line.
pub fn run(args: &RecoverArgs) -> Result<RecoverReport, RecordError> {
    let mut report = recover(&args.file, args.out.as_deref().unwrap_or(&args.file))?;
    let last = crate::last_part(&args.file);
    report.last_part = (last != args.file).then_some(last);
    Ok(report)
}

impl RecoverReport {
    /// One paragraph for a terminal.
    pub fn describe(&self) -> String {
        let mut s = format!(
            "recovered {} messages, {} metadata records and {} attachments from {} into {} \
             (complete, indexed)",
            self.messages,
            self.metadata,
            self.attachments,
            self.input.display(),
            self.output.display()
        );
        if let Some(why) = &self.stopped_by {
            s.push_str(&format!(
                "; dropped the unreadable last {} bytes ({why})",
                self.dropped_bytes
            ));
        }
        if let Some(last) = &self.last_part {
            s.push_str(&format!(
                ". {} is a part of a split recording whose last part is {}: that is the one a \
                 killed writer leaves unfinished",
                self.input.display(),
                last.display()
            ));
        }
        s
    }
}
