//! CPU per update of the MCAP writer alone (what the pipeline's recorder spends after it has
//! assembled an update): A1's updates (P = 2, K = 15, N = 101, ~15 kB each) and T-ball's
//! (P = 21, K = 10, N = 1001, ~91 kB), captured from in-process runs, written and flushed one
//! by one to a file and to nowhere (the same without the `write` system call). Prints figures;
//! asserts nothing. `cargo bench -p record --bench write_update`.

#![allow(clippy::unwrap_used)] // a benchmark that cannot set up has nothing to report

use std::path::Path;
use std::time::Instant;

use pi2cma::{CostBatch, Distribution, Hyperparameters, Optimizer, ParameterBatch, UpdateSummary};
use record::{RolloutTiming, RunWriter, UpdateData};
use session::{run_session, Observer, RunConfig, UpdateRecord};

struct Captured {
    before: Distribution,
    after: Distribution,
    samples: ParameterBatch,
    costs: CostBatch,
    summary: UpdateSummary,
    settings: Vec<(&'static str, f64)>,
}

#[derive(Default)]
struct Capture {
    hp: Option<Hyperparameters>,
    updates: Vec<Captured>,
}

impl Observer for Capture {
    fn on_start(&mut self, _: &RunConfig, o: &Optimizer, _: &[(&'static str, f64)]) {
        self.hp = Some(o.hyperparameters().clone());
    }
    fn on_update(&mut self, r: &UpdateRecord<'_>) {
        self.updates.push(Captured {
            before: r.before.clone(),
            after: r.after.clone(),
            samples: r.samples.clone(),
            costs: r.costs.clone(),
            summary: r.summary.clone(),
            settings: r.task_settings.to_vec(),
        });
    }
}

fn write_all<W: std::io::Write + std::io::Seek>(
    w: &mut RunWriter<W>,
    hp: &Hyperparameters,
    updates: &[Captured],
    timings: &[RolloutTiming],
) {
    for u in updates {
        w.write_update(&UpdateData {
            hyperparameters: hp,
            before: &u.before,
            after: &u.after,
            samples: &u.samples,
            costs: &u.costs,
            summary: &u.summary,
            task_settings: &u.settings,
            batch_start_ns: 1,
            batch_end_ns: 2,
            rollouts: timings,
            default_worker: "unknown",
        })
        .unwrap();
    }
}

/// A destination that keeps nothing: the writer's CPU without the `write` system call or the
/// page faults of a growing buffer.
#[derive(Default)]
struct Discard {
    pos: u64,
    end: u64,
}

impl std::io::Write for Discard {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.pos += b.len() as u64;
        self.end = self.end.max(self.pos);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl std::io::Seek for Discard {
    fn seek(&mut self, to: std::io::SeekFrom) -> std::io::Result<u64> {
        self.pos = match to {
            std::io::SeekFrom::Start(p) => p,
            std::io::SeekFrom::End(d) => self.end.saturating_add_signed(d),
            std::io::SeekFrom::Current(d) => self.pos.saturating_add_signed(d),
        };
        Ok(self.pos)
    }
}

fn main() {
    let a1 = session::DEFAULT_CONFIG.replace("updates = 40", "updates = 5000");
    bench("A1", &a1, 3);
    // The paper's T-ball task: P = 21, K = 10, N = 1001 (80 kB of step costs per update).
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/tball.toml");
    let tball = std::fs::read_to_string(path)
        .unwrap()
        .replace("updates = 40", "updates = 400");
    bench("T-ball", &tball, 2);
}

/// Captures the updates of an in-process run of `config` and writes them, best of 5.
fn bench(name: &str, config: &str, workers: usize) {
    let cfg = RunConfig::parse(config, Path::new(name)).unwrap();
    let mut cap = Capture::default();
    run_session(&cfg, 1, &mut cap).unwrap();
    let hp = cap.hp.unwrap();
    let k = cap.updates[0].costs.rollouts();
    let now = record::now_ns();
    let timings: Vec<RolloutTiming> = (0..k)
        .map(|r| RolloutTiming {
            worker: format!("worker-{}", r % workers),
            start_ns: now + 1000 * r as u64,
            end_ns: now + 1000 * r as u64 + 700,
        })
        .collect();
    let dir = std::env::temp_dir().join(format!("write-update-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let n = cap.updates.len() as f64;
    let (mut file_best, mut mem_best) = (f64::INFINITY, f64::INFINITY);
    let mut bytes = 0;
    for _ in 0..5 {
        let path = dir.join("bench.mcap");
        let t = Instant::now();
        let mut w = RunWriter::create(&path).unwrap();
        write_all(&mut w, &hp, &cap.updates, &timings);
        file_best = file_best.min(t.elapsed().as_secs_f64());
        w.finish().unwrap();
        bytes = std::fs::metadata(&path).unwrap().len();
        std::fs::remove_file(&path).unwrap();
        let t = Instant::now();
        let mut w = RunWriter::new(Discard::default(), "nowhere").unwrap();
        write_all(&mut w, &hp, &cap.updates, &timings);
        mem_best = mem_best.min(t.elapsed().as_secs_f64());
    }
    println!(
        "write_update, {name} ({} updates, {} bytes/update): to a file {:.1} µs/update, discarded (no system call) {:.1} µs/update (best of 5)",
        n,
        bytes / cap.updates.len() as u64,
        file_best * 1e6 / n,
        mem_best * 1e6 / n
    );
    let _ = std::fs::remove_dir_all(&dir);
}
