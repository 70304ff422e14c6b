//! `recover`: rewrite a recording whose writer was killed (no summary, possibly a torn chunk at
//! the end), or whose bytes were damaged, into a complete, indexed MCAP holding every readable
//! record.
//!
//! Damage inside the file does not end the recovery: chunks are independent, so reading goes on
//! at the next chunk whose CRC holds (found by scanning for one when the damage hit a record's
//! framing), and only the damaged chunks' updates are lost. The report lists each unreadable
//! region.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Compression, WriteOptions};

use crate::RecordError;

/// A region of the input that could not be read.
#[derive(Debug, Clone, PartialEq)]
pub struct Damage {
    /// Byte offset where the region starts: the first record that did not read whole.
    pub offset: u64,
    /// Its length: up to the next readable chunk, or to the end of the file.
    pub len: u64,
    /// What was wrong with its first record.
    pub why: String,
}

/// What `recover` kept and dropped.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecoverReport {
    /// The damaged file read.
    pub input: PathBuf,
    /// The complete file written.
    pub output: PathBuf,
    /// The input's length.
    pub input_bytes: u64,
    /// Messages copied to the output.
    pub messages: u64,
    /// Metadata records copied.
    pub metadata: u64,
    /// Attachments copied.
    pub attachments: u64,
    /// Bytes of the input that could not be read: the total of [`Self::damage`].
    pub dropped_bytes: u64,
    /// The unreadable regions in file order. A killed writer leaves one, at the end (the chunk
    /// in flight); damage inside the file leaves one per damaged stretch, after which reading
    /// went on.
    pub damage: Vec<Damage>,
    /// Messages whose channel was declared only in damaged bytes: not copied (with no channel,
    /// nothing says how to decode them).
    pub orphaned_messages: u64,
    /// Where the input went when it was rewritten in place with damage inside it (not only a
    /// torn tail): `FILE.damaged`.
    pub kept_original: Option<PathBuf>,
    /// The last part of the split recording the input belongs to, if that is another file:
    /// the only part a killed writer leaves unfinished.
    pub last_part: Option<PathBuf>,
}

/// Copies every readable schema, channel, message, metadata and attachment record of `input`
/// into a new, finished MCAP at `output` (zstd chunks, full indexes). `output` may be `input`:
/// the result is written next to it and renamed over it. The input is read as a stream, a
/// chunk at a time, so a continual run's recording recovers in little memory. Channels and
/// schemas also come from the input's summary when it has one, so a finished file whose first
/// chunk (where they are declared) is damaged keeps its later messages.
pub fn recover(input: &Path, output: &Path) -> Result<RecoverReport, RecordError> {
    let mut file = File::open(input).map_err(|e| RecordError::io(input, e))?;
    // Rewritten while its recorder still writes, the file would lose every later update to
    // the replaced inode the recorder goes on writing to.
    if crate::being_written(input) {
        return Err(RecordError::invalid(
            input,
            "is still being written by a running recorder: recover it once the run has ended \
             (a finished run needs no recovery; `mcap-tool info` reads a live recording as it is)",
        ));
    }
    let input_len = file
        .metadata()
        .map_err(|e| RecordError::io(input, e))?
        .len();
    let summary =
        crate::reader::summary_of(&mut file, input_len).map_err(|e| RecordError::io(input, e))?;
    let tmp = tmp_path(output);
    // A failed rewrite (a full disk) leaves no half-written copy behind.
    let mut report = match rewrite(&mut file, input, input_len, summary.as_ref(), &tmp, output) {
        Ok(r) => r,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(disk_full_hint(e, input, output));
        }
    };
    // Nothing readable: not a recording at all (a config given by mistake, an empty file), or
    // damaged beyond reading. Writing an empty MCAP over it would destroy it for nothing.
    if report.messages + report.metadata + report.attachments == 0 {
        let _ = std::fs::remove_file(&tmp);
        let mut why = report
            .damage
            .first()
            .map(|d| format!(" ({})", d.why))
            .unwrap_or_default();
        if report.orphaned_messages > 0 {
            why.push_str(&format!(
                "; {} messages, whose channels were declared only in damaged bytes",
                report.orphaned_messages
            ));
        }
        return Err(RecordError::invalid(
            input,
            format!(
                "no readable record: not an MCAP recording, or damaged beyond recovery{why}; \
                 left as it is"
            ),
        ));
    }
    // Damage inside the file is more than a killed writer's torn tail: rewritten in place,
    // the original stays next to it, for whatever else might read the damaged bytes.
    let inside = report.damage.iter().any(|d| d.offset + d.len < input_len);
    if inside && same_file(input, output) {
        let kept = with_suffix(input, ".damaged");
        std::fs::rename(input, &kept).map_err(|e| RecordError::io(&kept, e))?;
        report.kept_original = Some(kept);
    }
    std::fs::rename(&tmp, output).map_err(|e| RecordError::io(output, e))?;
    Ok(report)
}

/// Whether the file at `path` holds nothing a recorder wrote for its run: no bytes, or the MCAP
/// magic and at most the (possibly torn) header record. That is what a recorder leaves that died
/// between creating its part and writing its first record (the writer keeps even the header in
/// memory until its first flush): there is nothing to recover, and [`recover`] refuses such a
/// file as it refuses any file without a readable record.
pub fn holds_nothing(path: &Path) -> std::io::Result<bool> {
    const MAGIC: &[u8] = mcap::MAGIC;
    const HEADER_OPCODE: u8 = 0x01;
    let file = File::open(path)?;
    let len = file.metadata()?.len();
    let mut head = Vec::with_capacity(MAGIC.len() + 9);
    file.take((MAGIC.len() + 9) as u64).read_to_end(&mut head)?;
    if !crate::reader::could_be_mcap(&head) {
        return Ok(false);
    }
    let Some(record) = head.get(MAGIC.len()..) else {
        return Ok(true);
    };
    match record {
        [] => Ok(true),
        [op, ..] if *op != HEADER_OPCODE => Ok(false),
        [_, l @ ..] if l.len() == 8 => {
            let mut body = [0; 8];
            body.copy_from_slice(l);
            let body = u64::from_le_bytes(body);
            Ok(len <= (MAGIC.len() as u64 + 9).saturating_add(body))
        }
        // A header torn within its length field.
        _ => Ok(true),
    }
}

/// Writes every readable record of `input` into `tmp`, a complete, indexed MCAP.
fn rewrite(
    file: &mut File,
    input: &Path,
    input_len: u64,
    summary: Option<&mcap::Summary>,
    tmp: &Path,
    output: &Path,
) -> Result<RecoverReport, RecordError> {
    let f = File::create(tmp).map_err(|e| RecordError::io(tmp, e))?;
    let mut w = WriteOptions::new()
        .compression(Some(Compression::Zstd))
        .compression_threads(0)
        .library(concat!(
            "pi2cma-record/",
            env!("CARGO_PKG_VERSION"),
            " recover"
        ))
        .create(BufWriter::new(f))
        .map_err(|e| RecordError::mcap(tmp, e))?;
    let mut report = RecoverReport {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        input_bytes: input_len,
        ..Default::default()
    };
    let mut copier = Copier {
        schemas: HashMap::new(),
        channels: HashMap::new(),
        tmp,
    };
    if let Some(summary) = &summary {
        copier.declare(&mut w, summary)?;
    }
    let mut from = 0;
    loop {
        let stop = copy_from(
            file,
            input,
            from,
            input_len,
            &mut copier,
            &mut w,
            &mut report,
        )?;
        let Some((at, why)) = stop else { break };
        let next = next_chunk(file, at + 1, input_len).map_err(|e| RecordError::io(input, e))?;
        let end = next.unwrap_or(input_len);
        report.damage.push(Damage {
            offset: at,
            len: end - at,
            why,
        });
        report.dropped_bytes += end - at;
        match next {
            Some(n) => from = n,
            None => break,
        }
    }
    w.finish().map_err(|e| RecordError::mcap(tmp, e))?;
    let mut inner = w.into_inner();
    std::io::Write::flush(&mut inner).map_err(|e| RecordError::io(tmp, e))?;
    drop(inner);
    Ok(report)
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(suffix);
    path.with_file_name(name)
}

/// Copies the records of `input` from byte `from` (0: the start, with its magic; otherwise a
/// record's first byte) until the data section ends, the file ends, or a record does not read
/// whole: then returns where that record starts and why.
fn copy_from(
    file: &mut File,
    input: &Path,
    from: u64,
    input_len: u64,
    copier: &mut Copier<'_>,
    w: &mut mcap::Writer<BufWriter<File>>,
    report: &mut RecoverReport,
) -> Result<Option<(u64, String)>, RecordError> {
    file.seek(SeekFrom::Start(from))
        .map_err(|e| RecordError::io(input, e))?;
    // Top-level records as they are (chunks still compressed): a chunk is decoded, and its CRC
    // checked, by `chunk_records`, and kept only if all of it decodes. No record is longer than
    // the file: a damaged length fails here instead of asking for that much memory.
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(from != 0)
            .with_skip_end_magic(true)
            .with_emit_chunks(true)
            .with_record_length_limit(usize::try_from(input_len).unwrap_or(usize::MAX)),
    );
    // Byte offset just past the last record that was copied whole.
    let mut good_end: u64 = if from == 0 { 8 } else { from };
    let mut first = true;
    while let Some(event) = reader.next_event() {
        let (opcode, body) = match event {
            Ok(LinearReadEvent::ReadRequest(wanted)) => {
                let buf = reader.insert(wanted.max(1 << 16));
                let read = file.read(buf).map_err(|e| RecordError::io(input, e))?;
                reader.notify_read(read);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => (opcode, data),
            // Damaged leading magic: nothing was read yet.
            Err(e) if first && from == 0 => return Ok(Some((0, e.to_string()))),
            Err(e) => return Ok(Some((good_end, e.to_string()))),
        };
        first = false;
        // Opcode 0 is reserved: never written, but zeroed bytes read as a run of such empty
        // records, which a reader skips like records of a newer version of the format.
        if opcode == OP_RESERVED {
            return Ok(Some((good_end, "opcode 0x00 (zeroed bytes)".into())));
        }
        // opcode, length, body.
        let record_len = 1 + 8 + body.len() as u64;
        let record = match mcap::parse_record(opcode, body) {
            Ok(r) => r,
            Err(e) => return Ok(Some((good_end, e.to_string()))),
        };
        match record {
            Record::Chunk { .. } => match chunk_records(body) {
                Ok(records) => {
                    for r in records {
                        copier.copy(w, r, report)?;
                    }
                }
                Err(e) => return Ok(Some((good_end, format!("damaged chunk: {e}")))),
            },
            Record::DataEnd(_) | Record::Footer(_) => return Ok(None),
            other => copier.copy(w, other, report)?,
        }
        good_end += record_len;
    }
    Ok(None)
}

/// The offset of the first chunk at or after `from` that reads whole: its header is consistent
/// with its length, it decompresses, and its records match the CRC its writer computed. Chunks
/// are what resumes reading after damage because the CRC makes a false find (a stray 0x06 in
/// damaged bytes) all but impossible; top-level records in between (metadata, message indexes)
/// are lost with the damage.
fn next_chunk(file: &File, from: u64, len: u64) -> std::io::Result<Option<u64>> {
    const WINDOW: usize = 1 << 20;
    let mut buf = vec![0; WINDOW];
    let mut base = from;
    while base < len {
        let n = WINDOW.min((len - base) as usize);
        file.read_exact_at(&mut buf[..n], base)?;
        for (i, _) in buf[..n].iter().enumerate().filter(|(_, b)| **b == OP_CHUNK) {
            let at = base + i as u64;
            if chunk_reads_whole(file, at, len)? {
                return Ok(Some(at));
            }
        }
        base += n as u64;
    }
    Ok(None)
}

/// The most a chunk's records can take decompressed, per byte of the chunk: zstd's densest
/// block is RLE, 4 bytes for 128 KiB; lz4 expands less.
pub(crate) const MAX_EXPANSION: usize = (128 << 10) / 4;

const OP_CHUNK: u8 = 0x06;
pub(crate) const OP_RESERVED: u8 = 0x00;

/// Whether a whole, CRC-checked chunk record starts at `at`.
fn chunk_reads_whole(file: &File, at: u64, len: u64) -> std::io::Result<bool> {
    // opcode, record length, then the chunk header: start and end time, uncompressed size,
    // uncompressed CRC, compression (u32 length + name), compressed size.
    let mut head = [0; 9 + 8 + 8 + 8 + 4 + 4];
    if at + head.len() as u64 > len {
        return Ok(false);
    }
    file.read_exact_at(&mut head, at)?;
    let u64_at = |i: usize| u64::from_le_bytes(head[i..i + 8].try_into().unwrap_or([0; 8]));
    let record_len = u64_at(1);
    let crc = u32::from_le_bytes(head[33..37].try_into().unwrap_or([0; 4]));
    let name_len = u64::from(u32::from_le_bytes(
        head[37..41].try_into().unwrap_or([0; 4]),
    ));
    // Our writer and every mcap writer by default compute the CRC; without one, nothing would
    // tell a chunk from noise.
    if crc == 0 || name_len > 8 || record_len > len - at - 9 || u64_at(9) > u64_at(17) {
        return Ok(false);
    }
    let header_len = 8 + 8 + 8 + 4 + 4 + name_len + 8;
    if record_len < header_len {
        return Ok(false);
    }
    let mut tail = vec![0; (name_len + 8) as usize];
    file.read_exact_at(&mut tail, at + 41)?;
    let compressed = u64::from_le_bytes(tail[name_len as usize..].try_into().unwrap_or([0xff; 8]));
    if compressed != record_len - header_len {
        return Ok(false);
    }
    let mut body = vec![0; record_len as usize];
    file.read_exact_at(&mut body, at + 9)?;
    Ok(chunk_records(&body).is_ok())
}

/// The records of the chunk whose record body is `body`, read only if all of it is sound: its
/// CRC is checked before any record is parsed, and neither it nor a record in it may be longer
/// than zstd or lz4 can expand `body` to. `mcap::read::ChunkReader` took the lengths in damaged
/// bytes at their word and reserved that much memory: `recover`, the command for damaged
/// files, aborted ("memory allocation of 4611686018427387913 bytes failed") or panicked
/// ("capacity overflow").
fn chunk_records(body: &[u8]) -> Result<Vec<Record<'static>>, mcap::McapError> {
    let mut input = Vec::with_capacity(9 + body.len());
    input.push(OP_CHUNK);
    input.extend_from_slice(&(body.len() as u64).to_le_bytes());
    input.extend_from_slice(body);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(body.len().saturating_mul(MAX_EXPANSION)),
    );
    let mut rest = &input[..];
    let mut records = Vec::new();
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(wanted) => {
                let n = wanted.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { opcode, data } => {
                records.push(mcap::parse_record(opcode, data)?.into_owned());
            }
        }
    }
    Ok(records)
}

/// A full disk names the way out: the input is untouched, and recovered onto another disk it
/// needs no room on its own (in place, the copy is written next to it first).
fn disk_full_hint(e: RecordError, input: &Path, output: &Path) -> RecordError {
    if !e.is_disk_full() {
        return e;
    }
    let how = if same_file(input, output) {
        format!(
            "recovering in place writes the copy next to it first; recover it onto a disk with \
             room: recover {} --out OTHER_DISK/FILE",
            input.display()
        )
    } else {
        "choose an --out on a disk with room".to_string()
    };
    RecordError::invalid(input, format!("not recovered, left as it is ({e}): {how}"))
}

fn tmp_path(output: &Path) -> PathBuf {
    with_suffix(output, ".recover-tmp")
}

struct Copier<'p> {
    /// Input schema id → output schema id.
    schemas: HashMap<u16, u16>,
    channels: HashMap<u16, u16>,
    tmp: &'p Path,
}

impl Copier<'_> {
    /// Declares the summary's schemas and channels under their input ids. Declared again by
    /// the data section, they keep the ids given here (the writer returns the id of an equal
    /// schema or channel).
    fn declare(
        &mut self,
        w: &mut mcap::Writer<BufWriter<File>>,
        summary: &mcap::Summary,
    ) -> Result<(), RecordError> {
        let mut schemas: Vec<_> = summary.schemas.values().collect();
        schemas.sort_by_key(|s| s.id);
        for s in schemas {
            let header = mcap::records::SchemaHeader {
                id: s.id,
                name: s.name.clone(),
                encoding: s.encoding.clone(),
            };
            let data = std::borrow::Cow::Borrowed(&s.data[..]);
            self.copy_schema_or_channel(w, Record::Schema { header, data })?;
        }
        let mut channels: Vec<_> = summary.channels.values().collect();
        channels.sort_by_key(|c| c.id);
        for c in channels {
            self.copy_schema_or_channel(
                w,
                Record::Channel(mcap::records::Channel {
                    id: c.id,
                    schema_id: c.schema.as_ref().map_or(0, |s| s.id),
                    topic: c.topic.clone(),
                    message_encoding: c.message_encoding.clone(),
                    metadata: c.metadata.clone(),
                }),
            )?;
        }
        Ok(())
    }

    fn copy_schema_or_channel(
        &mut self,
        w: &mut mcap::Writer<BufWriter<File>>,
        record: Record<'_>,
    ) -> Result<(), RecordError> {
        self.copy(w, record, &mut RecoverReport::default())
    }

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
                    report.orphaned_messages += 1;
                    return Ok(());
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
    if let Some(out) = &args.out {
        refuse_replacing_another_file(&args.file, out)?;
    }
    let mut report = recover(&args.file, args.out.as_deref().unwrap_or(&args.file))?;
    let last = crate::last_part(&args.file);
    report.last_part = (last != args.file).then_some(last);
    Ok(report)
}

/// Refuses an `--out` that is a file other than `input`: it may be another recording (a part
/// of the same run, a typo), which recovering would replace for good.
fn refuse_replacing_another_file(input: &Path, out: &Path) -> Result<(), RecordError> {
    let Ok(meta) = std::fs::metadata(out) else {
        return Ok(());
    };
    let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if meta.is_dir() {
        // Was "outdir: Is a directory (os error 21)" once the recovery had been read.
        let name = input.file_name().map(Path::new).unwrap_or(input);
        return Err(RecordError::invalid(
            out,
            format!(
                "is a directory; --out names the recovered file (e.g. {})",
                out.join(name).display()
            ),
        ));
    }
    if meta.len() == 0 || same(input, out) {
        return Ok(());
    }
    Err(RecordError::invalid(
        out,
        format!(
            "a file of {} bytes is there already (--out); recover does not overwrite it: remove \
             it or give another --out (without --out, {} is recovered in place)",
            meta.len(),
            input.display()
        ),
    ))
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
        for (i, d) in self.damage.iter().enumerate() {
            let at_end = i + 1 == self.damage.len() && d.offset + d.len >= self.input_bytes;
            if at_end {
                s.push_str(&format!(
                    "; dropped the unreadable last {} bytes, from byte {} ({})",
                    d.len, d.offset, d.why
                ));
            } else {
                s.push_str(&format!(
                    "; skipped {} damaged bytes at {}..{} ({}) and read on from the next whole \
                     chunk",
                    d.len,
                    d.offset,
                    d.offset + d.len,
                    d.why
                ));
            }
        }
        if let Some(kept) = &self.kept_original {
            s.push_str(&format!(
                "; the damaged original is kept as {}",
                kept.display()
            ));
        }
        if self.orphaned_messages > 0 {
            s.push_str(&format!(
                "; dropped {} messages whose channel was declared only in damaged bytes",
                self.orphaned_messages
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_disk_says_the_recording_is_untouched_and_where_to_recover_it() {
        let full = || std::io::Error::from_raw_os_error(28);
        let input = Path::new("runs/a.mcap");
        let e = disk_full_hint(
            RecordError::mcap("runs/a.mcap.recover-tmp", mcap::McapError::Io(full())),
            input,
            input,
        )
        .to_string();
        assert!(
            e.starts_with("runs/a.mcap: not recovered, left as it is (runs/a.mcap.recover-tmp: MCAP: I/O error: No space left on device")
                && e.ends_with("recover it onto a disk with room: recover runs/a.mcap --out OTHER_DISK/FILE"),
            "{e}"
        );
        let e = disk_full_hint(
            RecordError::io("/x/b.mcap.recover-tmp", full()),
            input,
            Path::new("/x/b.mcap"),
        )
        .to_string();
        assert!(e.ends_with("choose an --out on a disk with room"), "{e}");
        // Other errors pass as they are.
        let other = RecordError::io("runs/a.mcap", std::io::Error::from_raw_os_error(13));
        let text = other.to_string();
        assert_eq!(disk_full_hint(other, input, input).to_string(), text);
    }

    /// `recover A --out B` replaced B, whatever it held (another recording), without a word.
    #[test]
    fn an_out_that_is_another_file_is_refused_and_left_as_it_is() {
        let dir = std::env::temp_dir().join(format!("recover-out-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (input, other) = (dir.join("a.mcap"), dir.join("b.mcap"));
        let mut cfg = session::RunConfig::default_config();
        cfg.run.updates = Some(3);
        crate::testing::record_session(&cfg, 1, &input);
        std::fs::write(&other, b"another recording").unwrap();
        let args = |out: &Path| RecoverArgs {
            file: input.clone(),
            out: Some(out.to_path_buf()),
        };
        let e = run(&args(&other)).unwrap_err().to_string();
        assert!(
            e.starts_with(&format!(
                "{}: a file of 17 bytes is there already (--out)",
                other.display()
            )),
            "{e}"
        );
        assert_eq!(std::fs::read(&other).unwrap(), b"another recording");
        // A directory is named as such, with the file name to give instead.
        let e = run(&args(&dir)).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "{}: is a directory; --out names the recovered file (e.g. {})",
                dir.display(),
                dir.join("a.mcap").display()
            )
        );
        // In place, named as --out (also by another spelling), is no other file.
        let again = dir.join(".").join("a.mcap");
        for out in [&input, &again] {
            run(&args(out)).unwrap();
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// What a writer killed after its first record leaves at `path` (forgotten, it holds the
    /// file's lock as a live writer would).
    fn killed_after_its_first_record(path: &Path) {
        let mut w = crate::RunWriter::create(path).unwrap();
        w.write_event(0, crate::Event::Start, "recorder", 1, "started")
            .unwrap();
        w.flush().unwrap();
        std::mem::forget(w);
    }

    /// CRC-32 (IEEE), as MCAP's chunk CRC.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = (crc >> 1) ^ (0xedb8_8320 & (crc & 1).wrapping_neg());
            }
        }
        !crc
    }

    /// A zstd chunk record whose compressed bytes decode without error (one raw block, as
    /// damaged bytes may) to a record that claims 2⁶² bytes.
    fn chunk_claiming_a_huge_record() -> Vec<u8> {
        let mut content = vec![0x05]; // a message record…
        content.extend_from_slice(&(1u64 << 62).to_le_bytes()); // …of 2⁶² bytes
        let n = content.len() as u8;
        // Frame: magic, descriptor (single segment, 1-byte content size), content size, then
        // one block: last, raw, `n` bytes.
        let mut frame = vec![0x28, 0xb5, 0x2f, 0xfd, 0x20, n];
        frame.extend_from_slice(&((u32::from(n) << 3) | 1).to_le_bytes()[..3]);
        frame.extend_from_slice(&content);
        let mut body = Vec::new();
        for v in [0u64, 0, content.len() as u64] {
            body.extend_from_slice(&v.to_le_bytes()); // start, end time; uncompressed size
        }
        body.extend_from_slice(&crc32(&content).to_le_bytes());
        body.extend_from_slice(&4u32.to_le_bytes());
        body.extend_from_slice(b"zstd");
        body.extend_from_slice(&(frame.len() as u64).to_le_bytes());
        body.extend_from_slice(&frame);
        let mut record = vec![OP_CHUNK];
        record.extend_from_slice(&(body.len() as u64).to_le_bytes());
        record.extend_from_slice(&body);
        record
    }

    #[test]
    fn a_chunk_whose_bytes_claim_a_huge_record_is_damage_not_a_crash() {
        let dir = std::env::temp_dir().join(format!("huge-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let written = dir.join("written.mcap");
        killed_after_its_first_record(&written);
        let input = dir.join("damaged.mcap");
        let mut bytes = std::fs::read(&written).unwrap();
        let at = bytes.len() as u64;
        bytes.extend_from_slice(&chunk_claiming_a_huge_record());
        std::fs::write(&input, &bytes).unwrap();
        let report = recover(&input, &dir.join("recovered.mcap")).unwrap();
        assert_eq!(report.messages, 1, "{report:?}");
        assert_eq!(report.damage.len(), 1, "{report:?}");
        assert_eq!(report.damage[0].offset, at, "{report:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_part_whose_recorder_died_before_its_first_record_holds_nothing() {
        let dir = std::env::temp_dir().join(format!("holds-nothing-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = |name: &str, bytes: &[u8]| {
            let path = dir.join(name);
            std::fs::write(&path, bytes).unwrap();
            path
        };
        // A recorder SIGKILLed right after creating its part: the writer had flushed nothing.
        let created = dir.join("created.mcap");
        std::mem::forget(crate::RunWriter::create(&created).unwrap());
        assert!(holds_nothing(&created).unwrap());
        let magic = b"\x89MCAP0\r\n";
        assert!(holds_nothing(&file("empty.mcap", b"")).unwrap());
        assert!(holds_nothing(&file("torn-magic.mcap", &magic[..5])).unwrap());
        assert!(holds_nothing(&file("magic.mcap", magic)).unwrap());
        let mut header = magic.to_vec();
        header.push(0x01);
        header.extend_from_slice(&4u64.to_le_bytes()[..3]);
        assert!(holds_nothing(&file("torn-length.mcap", &header)).unwrap());
        header.truncate(magic.len() + 1);
        header.extend_from_slice(&4u64.to_le_bytes());
        header.extend_from_slice(&[0, 0, 0, 0]);
        assert!(holds_nothing(&file("header.mcap", &header)).unwrap());
        // Anything after the header is a record someone may want back.
        header.push(0x03);
        assert!(!holds_nothing(&file("more.mcap", &header)).unwrap());
        assert!(!holds_nothing(&file("config.toml", b"[run]\nname = 'A1'\n")).unwrap());
        // A part with its first record written is recovered, not taken for empty.
        let started = dir.join("started.mcap");
        killed_after_its_first_record(&started);
        assert!(!holds_nothing(&started).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
