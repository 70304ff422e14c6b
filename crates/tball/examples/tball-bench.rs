//! Benchmark of the T-ball task: time per rollout (cost only, and with a full trace for figures)
//! and time per in-process update (K rollouts + the PI²-CMA update). Prints figures; not a test.
//!
//! ```text
//! cargo run --release -p tball --example tball-bench -- [--config config/tball.toml]
//! ```

use std::error::Error;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Instant;

use pi2cma::ParameterBatch;
use session::{InProcess, NoObserver, RunConfig, TaskSection};
use tasks::Task;
use tball::Tball;

fn main() -> Result<(), Box<dyn Error>> {
    let mut config = PathBuf::from("config/tball.toml");
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        match (flag.as_str(), it.next()) {
            ("--config", Some(v)) => config = v.into(),
            _ => return Err(format!("usage: tball-bench [--config FILE] (got {flag})").into()),
        }
    }
    let cfg = RunConfig::load(&config)?;
    let TaskSection::Tball(task_cfg) = &cfg.task else {
        return Err(format!("{}: not a [task.tball] config", config.display()).into());
    };
    let mut task = Tball::new(task_cfg)?;

    // The rollouts of a real first batch (λ_init around the initial mean), hits and misses alike.
    let optimizer = session::build_optimizer(&cfg, &task, cfg.run.seed)?;
    let batch = ParameterBatch::sample(
        optimizer.distribution(),
        cfg.run.seed,
        0,
        cfg.optimizer.rollouts,
    );
    let mut per_step = vec![0.0; task.steps()];
    let rollouts = 4_000;
    for k in 0..batch.rollouts {
        task.rollout(batch.row(k), &mut per_step);
    }
    // The machine is shared: time several repetitions and report the median and the fastest.
    let rollout = repeat(|| {
        let start = Instant::now();
        for r in 0..rollouts {
            black_box(task.rollout(black_box(batch.row(r % batch.rollouts)), &mut per_step));
        }
        start.elapsed().as_secs_f64() / rollouts as f64
    });
    let traces = 1_000;
    let trace = repeat(|| {
        let start = Instant::now();
        for r in 0..traces {
            black_box(task.trace(black_box(batch.row(r % batch.rollouts))));
        }
        start.elapsed().as_secs_f64() / traces as f64
    });

    let updates = cfg.run.updates.unwrap_or(40);
    let mut sessions = Vec::new();
    for s in 0..5 {
        let start = Instant::now();
        let mut exec = InProcess::new(&cfg, cfg.run.seed + s)?;
        for _ in 0..updates {
            exec.step(&mut NoObserver)?;
        }
        sessions.push(start.elapsed().as_secs_f64() / updates as f64);
    }
    let update = median_and_min(sessions);

    println!(
        "T-ball ({} steps of {} s, P = {}, K = {})",
        task.steps(),
        task_cfg.dt,
        task.parameters(),
        cfg.optimizer.rollouts
    );
    println!("{:<44} {:>12} {:>12}", "what", "median", "fastest");
    for (what, (median, fastest)) in [
        ("rollout (cost only)", rollout),
        ("rollout with trace (figures)", trace),
        ("in-process update (K rollouts + PI²-CMA)", update),
    ] {
        println!(
            "{what:<44} {:>9.1} µs {:>9.1} µs",
            median * 1e6,
            fastest * 1e6
        );
    }
    Ok(())
}

/// (median, fastest) of 5 repetitions.
fn repeat(mut f: impl FnMut() -> f64) -> (f64, f64) {
    median_and_min((0..5).map(|_| f()).collect())
}

fn median_and_min(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[v.len() / 2], v[0])
}
