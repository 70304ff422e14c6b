//! Nothing lost: a recorder killed with SIGKILL keeps every update it had flushed, and
//! `recover` turns the file into a complete, indexed one; SIGINT gives a complete file.

#![allow(clippy::unwrap_used)] // test helpers; a failed unwrap is a failed test

#[path = "../../../tests/config_edit.rs"]
mod config_edit;
#[path = "../../../tests/scratch.rs"]
mod scratch;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use record::read_recording;
use record::recompute::verify;
use record::recover::recover;

fn tmp(name: &str) -> PathBuf {
    scratch::shared("crash").join(name)
}

/// Starts a long recording (2 ms per rollout) and returns it with the updates it reported as
/// flushed once it has reported `until`.
fn start(out: &Path, until: u64) -> (Child, Vec<u64>, impl BufRead) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_mcap-tool"))
        .args([
            "record",
            "--progress",
            "--updates",
            "100000",
            "--rollout-delay-ms",
            "2",
        ])
        .arg("--out")
        .arg(out)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap());
    let mut seen = Vec::new();
    let mut line = String::new();
    while seen.last() != Some(&until) {
        line.clear();
        assert!(
            lines.read_line(&mut line).unwrap() > 0,
            "recorder ended early"
        );
        let u = line.trim().strip_prefix("recorded update ").unwrap();
        seen.push(u.parse().unwrap());
    }
    (child, seen, lines)
}

#[test]
fn sigkill_then_recover_keeps_every_flushed_update() {
    let out = tmp("killed.mcap");
    let (mut child, mut seen, mut lines) = start(&out, 5);
    // While its writer runs, the file is left alone: rewritten, the updates the writer goes on
    // appending would go to the replaced file.
    assert!(record::being_written(&out));
    let e = recover(&out, &out).unwrap_err().to_string();
    assert!(e.contains("still being written"), "{e}");
    let e = record::resume::resume_point(&out).unwrap_err().to_string();
    assert!(e.contains("still being written"), "{e}");
    let e = record::RunWriter::create(&out).err().unwrap().to_string();
    assert!(e.contains("being written by another process"), "{e}");
    assert!(std::fs::metadata(&out).unwrap().len() > 0);
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    // The lock dies with its process.
    assert!(!record::being_written(&out));
    // Updates reported between our last read and the kill were flushed too.
    let mut rest = String::new();
    while lines.read_line(&mut rest).unwrap_or(0) > 0 {}
    for l in rest.lines() {
        if let Some(u) = l.strip_prefix("recorded update ") {
            seen.push(u.parse().unwrap());
        }
    }
    let flushed = *seen.last().unwrap();

    let damaged = read_recording(&out).unwrap();
    assert!(!damaged.indexed, "a killed writer leaves no summary");
    assert!(damaged.updates.len() as u64 > flushed);

    let fixed = tmp("recovered.mcap");
    let report = recover(&out, &fixed).unwrap();
    let rec = read_recording(&fixed).unwrap();
    assert!(rec.indexed && rec.truncated.is_none(), "{report:?}");
    assert!(mcap::Summary::read(&std::fs::read(&fixed).unwrap())
        .unwrap()
        .is_some());
    let indices: Vec<u64> = rec.updates.iter().map(|u| u.update).collect();
    assert!(
        indices.len() as u64 > flushed,
        "{indices:?} lacks update {flushed}"
    );
    assert_eq!(indices, (0..indices.len() as u64).collect::<Vec<_>>());
    assert_eq!(rec.summaries.len(), rec.updates.len());
    assert_eq!(rec.rollouts.len(), rec.updates.len() * 15);
    let v = verify(&rec).unwrap();
    assert!(v.mismatches.is_empty(), "{v:?}");
    assert!(rec.metadata.contains_key("pi2cma.run"));
    assert_eq!(rec.run.len(), 1);

    // In place, too.
    let r = recover(&out, &out).unwrap();
    assert_eq!(r.messages, report.messages);
    assert!(read_recording(&out).unwrap().indexed);
}

#[test]
fn sigint_gives_a_complete_file() {
    let out = tmp("interrupted.mcap");
    let (mut child, seen, _lines) = start(&out, 3);
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "exit code of an interrupted run");
    let rec = read_recording(&out).unwrap();
    assert!(rec.indexed && rec.truncated.is_none());
    assert!(rec.updates.len() >= seen.len());
    let events: Vec<&str> = rec.logs.iter().map(|l| l.event.as_str()).collect();
    assert_eq!(events, ["start", "exit"]);
    assert!(verify(&rec).unwrap().mismatches.is_empty());
}

/// Offsets just past each chunk and its message indexes: the file's flush boundaries.
fn flush_boundaries(file: &[u8]) -> Vec<u64> {
    let (mut pos, mut out) = (8usize, Vec::new());
    let mut in_chunk = false;
    while pos + 9 <= file.len() {
        let op = file[pos];
        let len = u64::from_le_bytes(file[pos + 1..pos + 9].try_into().unwrap()) as usize;
        // 0x06 chunk, 0x07 message index; anything else ends a chunk's group.
        if in_chunk && op != 0x07 {
            out.push(pos as u64);
            in_chunk = false;
        }
        if op == 0x06 {
            in_chunk = true;
        }
        pos += 9 + len;
    }
    out
}

/// Cuts a recording at every flush boundary and in the middle of every following chunk: each cut
/// file recovers to exactly the updates flushed before the cut.
#[test]
fn torn_chunks_lose_only_the_update_in_flight() {
    let path = tmp("whole.mcap");
    let mut cfg = session::RunConfig::default_config();
    cfg.run.updates = Some(8);
    let mut rec = record::McapRecorder::create(&path).unwrap();
    session::run_session(&cfg, 2, &mut rec).unwrap();
    rec.finish().unwrap();
    let whole = std::fs::read(&path).unwrap();
    // Chunks: schemas and channels (closed by the metadata record), /run, then one per update
    // (with the events written before it).
    let sizes: Vec<u64> = flush_boundaries(&whole)[2..].to_vec();
    assert!(sizes.len() >= 8, "{sizes:?}");
    for u in 0..7 {
        let (at, next) = (sizes[u] as usize, sizes[u + 1] as usize);
        for cut in [at, at + 1, (at + next) / 2, next - 1] {
            let damaged = tmp(&format!("cut-{cut}.mcap"));
            std::fs::write(&damaged, &whole[..cut]).unwrap();
            let fixed = tmp(&format!("cut-{cut}-fixed.mcap"));
            let report = recover(&damaged, &fixed).unwrap();
            let r = read_recording(&fixed).unwrap();
            let got: Vec<u64> = r.updates.iter().map(|x| x.update).collect();
            // Cut in the last bytes of the next update's records, its chunk may be whole (only its
            // message index is torn): then that update is recovered as well.
            let keep = if cut == next - 1 {
                got.len().max(u + 1)
            } else {
                u + 1
            };
            assert_eq!(
                got,
                (0..keep as u64).collect::<Vec<_>>(),
                "cut at {cut}: {report:?}"
            );
            assert!(keep <= u + 2);
            assert_eq!(
                report.damage.is_empty(),
                cut == at,
                "cut at {cut}: {report:?}"
            );
            // One unreadable region, at the end: no chunk in the torn tail reads whole.
            assert!(report.damage.len() <= 1, "cut at {cut}: {report:?}");
            assert!(report.damage.iter().all(|d| d.offset + d.len == cut as u64));
            // The torn tail is what was dropped: from the end of the last whole record.
            if cut != at && keep == u + 1 {
                assert_eq!(report.dropped_bytes, (cut - at) as u64, "cut at {cut}");
            }
            assert!(verify(&r).unwrap().mismatches.is_empty());
        }
    }
}

/// A finished 12-update recording, its bytes and the offsets where each update's chunk starts.
fn finished_recording(name: &str) -> (PathBuf, Vec<u8>, Vec<u64>) {
    let path = tmp(name);
    let mut cfg = session::RunConfig::default_config();
    cfg.run.updates = Some(12);
    let mut rec = record::McapRecorder::create(&path).unwrap();
    session::run_session(&cfg, 2, &mut rec).unwrap();
    rec.finish().unwrap();
    let whole = std::fs::read(&path).unwrap();
    // The chunk of update u starts where /run's chunk (u = 0) or update u − 1's ends.
    let starts = flush_boundaries(&whole)[1..].to_vec();
    (path, whole, starts)
}

fn recovered_updates(damaged: &[u8], name: &str) -> (Vec<u64>, record::recover::RecoverReport) {
    let input = tmp(&format!("{name}.mcap"));
    std::fs::write(&input, damaged).unwrap();
    let fixed = tmp(&format!("{name}-fixed.mcap"));
    let report = recover(&input, &fixed).unwrap();
    let r = read_recording(&fixed).unwrap();
    assert!(r.indexed && r.truncated.is_none(), "{report:?}");
    let v = verify(&r).unwrap();
    assert!(v.mismatches.is_empty(), "{v:?}");
    (r.updates.iter().map(|x| x.update).collect(), report)
}

/// Damage inside a file loses the damaged chunk's update only: reading goes on at the next whole
/// chunk, whether the damage left the chunk's framing intact or hit its length.
#[test]
fn damage_inside_a_file_loses_only_the_damaged_chunks() {
    let (path, whole, starts) = finished_recording("inside.mcap");
    let all_but = |lost: &[u64]| (0..12).filter(|u| !lost.contains(u)).collect::<Vec<u64>>();
    // A finished file damaged inside is an error for the readers; recover is the way out.
    let (c3, c4) = (starts[3] as usize, starts[4] as usize);

    // Bytes in the middle of update 3's compressed records.
    let mut bytes = whole.clone();
    bytes[(c3 + c4) / 2..(c3 + c4) / 2 + 8].fill(0xa5);
    let (got, report) = recovered_updates(&bytes, "payload");
    assert_eq!(got, all_but(&[3]), "{report:?}");
    assert_eq!(report.damage.len(), 1, "{report:?}");
    assert_eq!(report.damage[0].offset, c3 as u64);
    assert!(report.damage[0].why.contains("damaged chunk"), "{report:?}");
    assert!(report
        .describe()
        .contains("read on from the next whole chunk"));

    // Update 3's record length: garbage that points past the end of the file.
    let mut bytes = whole.clone();
    bytes[c3 + 1..c3 + 9].copy_from_slice(&0x00ff_ffff_ffff_fff0u64.to_le_bytes());
    let (got, report) = recovered_updates(&bytes, "length");
    assert_eq!(got, all_but(&[3]), "{report:?}");
    assert_eq!(report.damage.len(), 1, "{report:?}");
    // Also a smaller length, which makes the next "record" start inside update 3's data.
    let mut bytes = whole.clone();
    bytes[c3 + 1..c3 + 9].copy_from_slice(&100u64.to_le_bytes());
    let (got, report) = recovered_updates(&bytes, "short");
    assert_eq!(got, all_but(&[3]), "{report:?}");
    // Two damaged stretches: updates 3 and 7. Zeroed bytes read as empty records of the
    // reserved opcode 0, which must count as damage (so the length of the zeroed stretch
    // does not decide whether it is noticed).
    let (c7, c8) = (starts[7] as usize, starts[8] as usize);
    // Update 3's chunk replaced by zeros that end exactly where the next chunk begins.
    let zeros = vec![0; (c4 - c3) / 9 * 9];
    let bytes = [&whole[..c3], &zeros, &whole[c4..]].concat();
    let (got, report) = recovered_updates(&bytes, "zeros");
    assert_eq!(got, all_but(&[3]), "{report:?}");
    assert!(report.damage[0].why.contains("opcode 0x00"), "{report:?}");
    // The readers stop there instead of reading on without update 3: as at a killed writer's
    // end when the summary no longer reads (the zeros are shorter than the chunk and shift it),
    // as damage in a finished file when they are not (a chunk of a multiple of 9 bytes).
    std::fs::write(&path, &bytes).unwrap();
    match read_recording(&path) {
        Ok(r) => {
            assert!(r.truncated.as_deref().unwrap_or("").contains("opcode 0x00"));
            assert_eq!(r.updates.len(), 3);
        }
        Err(e) => assert!(e.to_string().contains("opcode 0x00"), "{e}"),
    }
    let mut bytes = whole.clone();
    bytes[c3..c4].fill(0);
    bytes[(c7 + c8) / 2] ^= 1;
    let (got, report) = recovered_updates(&bytes, "two");
    assert_eq!(got, all_but(&[3, 7]), "{report:?}");
    assert_eq!(report.damage.len(), 2, "{report:?}");
    assert_eq!(
        report.dropped_bytes,
        report.damage.iter().map(|d| d.len).sum::<u64>()
    );
    // In place, the damaged original is kept beside the rewritten file.
    let in_place = tmp("in-place.mcap");
    std::fs::write(&in_place, &bytes).unwrap();
    let report = recover(&in_place, &in_place).unwrap();
    let kept = report.kept_original.clone().unwrap();
    assert_eq!(std::fs::read(&kept).unwrap(), bytes);
    assert!(read_recording(&in_place).unwrap().indexed);
    assert!(report.describe().contains("in-place.mcap.damaged"));
    // The readers refuse such a file with an error naming it, and do not try to allocate the
    // damaged length.
    let mut bytes = whole.clone();
    bytes[c3 + 1..c3 + 9].copy_from_slice(&0x00ff_ffff_ffff_fff0u64.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let e = read_recording(&path).unwrap_err().to_string();
    assert!(e.contains("inside.mcap"), "{e}");
}

/// The channels are declared in the first chunk. A finished file keeps them in its summary too,
/// so damage there loses no later message; a killed writer's file has no summary, and its
/// messages are reported as orphaned instead of failing the recovery.
#[test]
fn damaged_channel_declarations_come_from_the_summary() {
    let (_, whole, starts) = finished_recording("declarations.mcap");
    let first = flush_boundaries(&whole)[0] as usize; // end of the schemas' chunk
    let mut bytes = whole.clone();
    bytes[first - 40..first - 32].fill(0xa5);
    let (got, report) = recovered_updates(&bytes, "declarations");
    assert_eq!(got, (0..12).collect::<Vec<u64>>(), "{report:?}");
    assert_eq!(report.orphaned_messages, 0);
    assert_eq!(report.damage.len(), 1, "{report:?}");

    // Without the summary: cut the file after update 5, as a killed writer would.
    let cut = &bytes[..starts[6] as usize];
    let input = tmp("declarations-killed.mcap");
    std::fs::write(&input, cut).unwrap();
    let fixed = tmp("declarations-killed-fixed.mcap");
    // All of its messages are orphaned, and the /run metadata after the damaged chunk is
    // skipped with it: nothing readable is left.
    let e = recover(&input, &fixed).unwrap_err().to_string();
    assert!(e.contains("declared only in damaged bytes"), "{e}");
}

/// A file with nothing readable (a config given by mistake, an empty file, a cut before any
/// record) is refused and left as it is, in place or not.
#[test]
fn recover_refuses_a_file_without_readable_records_and_leaves_it() {
    let (_, whole, _) = finished_recording("nothing.mcap");
    for (name, bytes) in [
        ("config.toml", b"[run]\nupdates = 5\n".to_vec()),
        ("empty.mcap", Vec::new()),
        ("magic-only.mcap", whole[..20].to_vec()),
    ] {
        let path = tmp(name);
        std::fs::write(&path, &bytes).unwrap();
        let e = recover(&path, &path).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains("no readable record"), "{e}");
        assert_eq!(std::fs::read(&path).unwrap(), bytes, "{name} was changed");
        assert!(!tmp(&format!("{name}.recover-tmp")).exists());
    }
}

/// `mcap-tool record` whose file cannot grow (a file size limit, as a full disk) stops the run
/// and says what the file holds; recovered, it holds that. Before, the run went on unrecorded to
/// its end and said only `error: FILE: MCAP: I/O error: File too large (os error 27)`.
#[test]
fn a_recording_that_fails_stops_the_run_and_says_what_it_holds() {
    let out = tmp("fails.mcap");
    let _ = std::fs::remove_file(&out);
    // SIGXFSZ at its default: mcap-tool ignores it itself (it was killed by it).
    let run = Command::new("sh")
        .args([
            "-c",
            "ulimit -f 1000; exec \"$0\" record --updates 3000 --out \"$1\"",
            env!("CARGO_BIN_EXE_mcap-tool"),
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("the run stopped: its recording failed")
            && stderr.contains("File too large"),
        "{stderr}"
    );
    let held: u64 = stderr
        .split(" holds ")
        .nth(1)
        .and_then(|s| s.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no `holds N updates` in: {stderr}"));
    let recovered = tmp("fails-recovered.mcap");
    recover(&out, &recovered).unwrap();
    let (_, report) = record::recompute::read_and_verify(&recovered).unwrap();
    assert_eq!(
        (report.updates, report.mismatches.len()),
        (held as usize, 0)
    );
}

/// A split recording whose next part cannot be created (here a directory is in its way; a full
/// disk does the same) names its parts as they are: the first part, which the run was given, is
/// finished, as is every part before the last. It said `FILE holds 152 updates (0..=151) but is
/// not finished: pi2cma recover FILE …` of the first part, which held 76 of them and was finished.
#[test]
fn a_split_recording_that_fails_names_its_parts_as_they_are() {
    let out = tmp("split-fails.mcap");
    for p in record::recording_parts(&out) {
        let _ = std::fs::remove_file(&p);
    }
    let text = config_edit::edited(
        session::DEFAULT_CONFIG,
        &[("updates = 40", "updates = 200")],
    ) + "\n[recording]\nsplit_mb = 1\n";
    let cfg = session::RunConfig::parse(&text, Path::new("split-fails.toml")).unwrap();
    let mut rec = record::McapRecorder::create(&out).unwrap();
    // After the recorder removed the stale parts: part 3 cannot be created.
    let blocked = record::part_path(&out, 3);
    let _ = std::fs::remove_dir(&blocked);
    std::fs::create_dir(&blocked).unwrap();
    session::run_session(&cfg, 1, &mut rec).unwrap();
    let e = rec.finish().unwrap_err().to_string();
    std::fs::remove_dir(&blocked).unwrap();
    let part2 = record::part_path(&out, 2);
    let held: Vec<usize> = [&out, &part2]
        .map(|p| read_recording(p).unwrap())
        .iter()
        .map(|r| {
            assert!(r.indexed, "{}", r.path.display());
            r.updates.len()
        })
        .collect();
    let n = held[0] + held[1];
    assert!(
        e.ends_with(&format!(
            "the recording stopped there: {} and its 1 later part(s) hold {n} updates \
             (0..={}), finished",
            out.display(),
            n - 1
        )),
        "{e}"
    );
}
