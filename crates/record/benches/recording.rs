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
            "A1, no step costs",
            RunConfig {
                recording: Some(session::RecordingSection {
                    step_costs: false,
                    ..Default::default()
                }),
                ..config("a", 2, "episodic", 0.0, 2000)
            },
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
    pipeline_cases(&dir, &filter);
    let _ = std::fs::remove_dir_all(&dir);
}

fn without_step_costs(config: String) -> String {
    format!("{config}\n[recording]\nstep_costs = false\n")
}

/// The multiprocess pipeline (`supervisor run`, 3 workers) with and without the recorder
/// process; needs the supervisor's binaries next to `recorder` (`cargo build --release -p
/// supervisor`). Throughput is the updater's own measure (result file `elapsed_s`).
fn pipeline_cases(dir: &Path, filter: &[String]) {
    use std::process::{Command, Stdio};
    // The bench runs from target/<profile>/deps; the binaries are one level up.
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().and_then(Path::parent).unwrap().to_path_buf();
    if !["supervisor", "recorder"]
        .iter()
        .all(|b| bin.join(b).is_file())
    {
        println!(
            "\npipeline: skipped, the supervisor crate's binaries are not in {} (`cargo build \
             --release -p supervisor` first)",
            bin.display()
        );
        return;
    }
    println!("\n| pipeline case | updates | without (updates/s, steady state) | with recorder (updates/s, steady state) | recording cost | recorded | bytes/update | recorder CPU / updates (whole process: start, idle waits included) |");
    println!("|---|---|---|---|---|---|---|---|");
    let via_point = |updates: u64, delay: f64| {
        session::DEFAULT_CONFIG
            .replace("updates = 40", &format!("updates = {updates}"))
            .replace(
                "viapoint_weight = 1000.0",
                &format!("viapoint_weight = 1000.0\nrollout_delay_ms = {delay}"),
            )
    };
    // The T-ball task of the paper (config/tball.toml): K = 10 rollouts of ~0.1 ms, P = 21,
    // N = 1001 (80 kB of step costs per update), 2 workers.
    let tball = |updates: u64, workers: usize| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/tball.toml");
        std::fs::read_to_string(path)
            .unwrap()
            .replace("updates = 40", &format!("updates = {updates}"))
            .replace(
                "[task.tball]",
                &format!("[pipeline]\nworkers = {workers}\n\n[task.tball]"),
            )
    };
    let cases = [
        ("pipeline A1, 3 workers", 2000u64, via_point(2000, 0.0)),
        (
            "pipeline A1, 3 workers, 1 ms rollouts",
            150,
            via_point(150, 1.0),
        ),
        ("pipeline T-ball, 2 workers", 1000, tball(1000, 2)),
        // One core left for the recorder: what recording costs when it does not compete with
        // the rollouts for the CPU.
        ("pipeline T-ball, 1 worker", 1000, tball(1000, 1)),
        // `recording.step_costs = false`: totals only (both are episodic runs).
        (
            "pipeline A1, 3 workers, no step costs",
            2000,
            without_step_costs(via_point(2000, 0.0)),
        ),
        (
            "pipeline T-ball, 2 workers, no step costs",
            1000,
            without_step_costs(tball(1000, 2)),
        ),
    ];
    let mut id = 0u32;
    for (name, updates, text) in cases {
        if !filter.iter().all(|f| name.contains(f.as_str())) {
            continue;
        }
        let cfg = dir.join("pipe.toml");
        std::fs::write(&cfg, text).unwrap();
        let mut best = [f64::INFINITY; 2];
        let mut hung = 0;
        let (mut recorded, mut bytes) = (0, 0);
        // The recorder's own figure (its exit line), fewest of the runs: what recording takes
        // from a machine whose cores the rollouts keep busy.
        let mut recorder_cpu_us = f64::INFINITY;
        for _ in 0..3 {
            for with in [false, true] {
                id += 1;
                let run_id = format!("{:08x}{id:08x}", std::process::id());
                let out = dir.join("pipe.mcap");
                let _ = std::fs::remove_file(&out);
                let mut rec = with.then(|| {
                    let c = Command::new(bin.join("recorder"))
                        .args(["--config"])
                        .arg(&cfg)
                        .arg("--run-dir")
                        .arg(dir)
                        .args(["--run-id", &run_id, "--out"])
                        .arg(&out)
                        .stderr(Stdio::piped())
                        .spawn()
                        .unwrap();
                    while !out.exists() {
                        std::thread::sleep(std::time::Duration::from_millis(10));
                    }
                    std::thread::sleep(std::time::Duration::from_millis(300));
                    c
                });
                let result = dir.join("result.toml");
                let _ = std::fs::remove_file(&result);
                let mut sup = Command::new(bin.join("supervisor"))
                    .arg("run")
                    .arg(&cfg)
                    // The recorder under test is started above (or not at all).
                    .args(["--quiet", "--no-record", "--run-id", &run_id, "--bin-dir"])
                    .arg(&bin)
                    .arg("--result")
                    .arg(&result)
                    .env("PI2CMA_RUN_DIR", dir.join("runs"))
                    .stdout(Stdio::null())
                    .spawn()
                    .unwrap();
                let t = std::time::Instant::now();
                let mut stalled = false;
                while sup.try_wait().unwrap().is_none() {
                    if t.elapsed() > std::time::Duration::from_secs(60) {
                        // Stop it in order (SIGINT) so that it cleans up its run.
                        let _ = Command::new("kill")
                            .args(["-INT", &sup.id().to_string()])
                            .status();
                        let _ = sup.wait();
                        hung += 1;
                        stalled = true;
                        println!("  ({name}: run {run_id} stalled for 60 s and was stopped)");
                        break;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                if let Some(c) = rec.take() {
                    if stalled {
                        let _ = Command::new("kill")
                            .args(["-INT", &c.id().to_string()])
                            .status();
                    }
                    let exit = c.wait_with_output().unwrap();
                    let text = String::from_utf8_lossy(&exit.stderr);
                    // "recorded N updates to FILE (X µs of CPU per update; …)"
                    if let Some(us) = text
                        .split(" µs of CPU per update")
                        .next()
                        .and_then(|head| head.rsplit('(').next())
                        .and_then(|x| x.trim().parse::<f64>().ok())
                    {
                        recorder_cpu_us = recorder_cpu_us.min(us);
                    }
                    recorded = record::read_recording(&out).unwrap().updates.len();
                    bytes = std::fs::metadata(&out).unwrap().len() / updates;
                }
                let Ok(text) = std::fs::read_to_string(&result) else {
                    continue;
                };
                let r: toml::Table = toml::from_str(&text).unwrap();
                if r.get("complete").and_then(|c| c.as_bool()) != Some(true) {
                    continue;
                }
                // Steady state: the first update, which connects every port, left out.
                let per_update = (r["elapsed_s"].as_float().unwrap()
                    - r["first_update_s"].as_float().unwrap())
                    / (updates - 1) as f64;
                let i = usize::from(with);
                best[i] = best[i].min(per_update);
            }
        }
        println!(
            "| {name} | {updates} | {:.0} | {:.0} | {:+.1}% | {recorded} of {updates} | {bytes} | {recorder_cpu_us:.1} µs |{}",
            1.0 / best[0],
            1.0 / best[1],
            100.0 * (best[1] / best[0] - 1.0),
            if hung > 0 {
                format!(" ({hung} of 6 runs stalled)")
            } else {
                String::new()
            }
        );
    }
}
