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
    let rollouts = 20_000;
    for k in 0..batch.rollouts {
        task.rollout(batch.row(k), &mut per_step);
    }
    let start = Instant::now();
    for r in 0..rollouts {
        black_box(task.rollout(black_box(batch.row(r % batch.rollouts)), &mut per_step));
    }
    let rollout = start.elapsed().as_secs_f64() / rollouts as f64;

    let traces = 2_000;
    let start = Instant::now();
    for r in 0..traces {
        black_box(task.trace(black_box(batch.row(r % batch.rollouts))));
    }
    let trace = start.elapsed().as_secs_f64() / traces as f64;

    let sessions = 10;
    let updates = cfg.run.updates.unwrap_or(40);
    let start = Instant::now();
    for s in 0..sessions {
        let mut exec = InProcess::new(&cfg, cfg.run.seed + s)?;
        for _ in 0..updates {
            exec.step(&mut NoObserver)?;
        }
    }
    let update = start.elapsed().as_secs_f64() / (sessions * updates) as f64;

    println!(
        "T-ball ({} steps of {} s, P = {}, K = {})",
        task.steps(),
        task_cfg.dt,
        task.parameters(),
        cfg.optimizer.rollouts
    );
    println!("{:<44} {:>12}", "what", "time");
    println!("{:<44} {:>9.1} µs", "rollout (cost only)", rollout * 1e6);
    println!(
        "{:<44} {:>9.1} µs",
        "rollout with trace (figures)",
        trace * 1e6
    );
    println!(
        "{:<44} {:>9.1} µs",
        "in-process update (K rollouts + PI²-CMA)",
        update * 1e6
    );
    println!(
        "{:<44} {:>9.1} %",
        "  of which rollouts",
        100.0 * rollout * cfg.optimizer.rollouts as f64 / update
    );
    Ok(())
}
