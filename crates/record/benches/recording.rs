//! Throughput of in-process runs with and without MCAP recording, and bytes per update.
//! Prints figures; asserts nothing. `cargo bench -p record --bench recording`.

#![allow(clippy::unwrap_used)] // a benchmark that cannot set up has nothing to report

use std::path::Path;
use std::time::Instant;

use record::McapRecorder;
use session::{run_session, NoObserver, RunConfig};

fn config(name: &str, basis: usize, weighting: &str, delay_ms: f64, updates: u64) -> RunConfig {
    let text = session::DEFAULT_CONFIG
        .replace("updates = 40", &format!("updates = {updates}"))
        .replace("basis_functions = 2", &format!("basis_functions = {basis}"))
        .replace(
            "weighting = \"episodic\"",
            &format!("weighting = \"{weighting}\""),
        )
        .replace(
            "viapoint_weight = 1000.0",
            &format!("viapoint_weight = 1000.0\nrollout_delay_ms = {delay_ms}"),
        );
    RunConfig::parse(&text, Path::new(name)).unwrap()
}

fn main() {
    let dir = std::env::temp_dir().join(format!("record-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        (
            "A1: P=2, N=101, K=15, episodic",
            config("a", 2, "episodic", 0.0, 2000),
        ),
        (
            "P=10, N=101, K=15, per-time-step",
            config("b", 10, "per-time-step", 0.0, 1000),
        ),
        (
            "A1 with 0.2 ms rollouts (external sim)",
            config("c", 2, "episodic", 0.2, 300),
        ),
    ];
    println!("| case | updates | without (updates/s) | with (updates/s) | recording cost | bytes/update |");
    println!("|---|---|---|---|---|---|");
    // `cargo bench -p record --bench recording -- P=10` runs the cases whose name contains it.
    let filter: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    for (name, cfg) in &cases {
        if !filter.iter().all(|f| name.contains(f.as_str())) {
            continue;
        }
        let updates = cfg.run.updates.unwrap();
        let path = dir.join("bench.mcap");
        let (mut best_plain, mut best_rec) = (f64::INFINITY, f64::INFINITY);
        let mut bytes = 0;
        for _ in 0..5 {
            let t = Instant::now();
            run_session(cfg, 1, &mut NoObserver).unwrap();
            best_plain = best_plain.min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            let mut rec = McapRecorder::create(&path).unwrap();
            run_session(cfg, 1, &mut rec).unwrap();
            rec.finish().unwrap();
            best_rec = best_rec.min(t.elapsed().as_secs_f64());
            bytes = std::fs::metadata(&path).unwrap().len();
        }
        let n = updates as f64;
        println!(
            "| {name} | {updates} | {:.0} | {:.0} | {:+.1}% | {} |",
            n / best_plain,
            n / best_rec,
            100.0 * (best_rec / best_plain - 1.0),
            bytes / updates
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
