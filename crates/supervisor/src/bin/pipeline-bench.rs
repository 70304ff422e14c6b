//! Pipeline benchmarks; prints figures (run with `--release`):
//!
//! 1. overhead: the via-point task with 1 worker, updates/s of the pipeline against the
//!    in-process runner in the same process run (and a bit-identity check);
//! 2. scaling: 10 ms blocking rollouts, K = 15, time per update for 1, 2, 4, 8 and 15 workers
//!    against the ideal ⌈15/W⌉·10 ms;
//! 3. an idle group (rollouts blocking for 1 s, as on a robot): CPU used by all processes, and
//!    the peak RSS of each.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Parser;
use pipeline::result::RunResult;
use session::RunConfig;

#[derive(Parser)]
struct Cli {
    /// Updates of the overhead run.
    #[arg(long, default_value_t = 20_000)]
    updates: u64,
    /// Updates per worker count in the scaling run.
    #[arg(long, default_value_t = 30)]
    scaling_updates: u64,
    /// Seconds of the idle-group measurement.
    #[arg(long, default_value_t = 5.0)]
    idle_s: f64,
    /// Only these parts (overhead, scaling, idle).
    #[arg(long, value_delimiter = ',', default_value = "overhead,scaling,idle")]
    parts: Vec<String>,
}

fn config(edits: &[(&str, &str)]) -> String {
    let mut text = session::DEFAULT_CONFIG.to_string();
    for (from, to) in edits {
        text = text.replacen(from, to, 1);
    }
    text
}

fn scratch() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("p2c-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

fn supervisor() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe()?;
    Ok(exe
        .parent()
        .context("no executable directory")?
        .join("supervisor"))
}

/// Runs the supervisor on `text` to the end; returns its result.
fn pipeline_run(dir: &Path, name: &str, text: &str, workers: usize) -> anyhow::Result<RunResult> {
    let cfg = dir.join(format!("{name}.toml"));
    let result = dir.join(format!("{name}-result.toml"));
    std::fs::write(&cfg, text)?;
    let out = Command::new(supervisor()?)
        .arg("run")
        .arg(&cfg)
        // The pipeline alone; crate record's bench measures the recorder's cost.
        .args(["--quiet", "--no-record", "--workers", &workers.to_string()])
        .arg("--result")
        .arg(&result)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()?;
    if !out.status.success() {
        bail!(
            "supervisor failed: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    RunResult::read(&result)
}

fn overhead(dir: &Path, updates: u64) -> anyhow::Result<()> {
    let text = config(&[("updates = 40", &format!("updates = {updates}"))]);
    let cfg = RunConfig::parse(&text, Path::new("overhead.toml"))?;
    let t0 = Instant::now();
    let (_, d) = session::run_session(&cfg, cfg.run.seed, &mut session::NoObserver)?;
    let in_process = t0.elapsed().as_secs_f64();
    let r = pipeline_run(dir, "overhead", &text, 1)?;
    let (mean, cov) = r.exact()?;
    let identical = mean == d.mean.as_slice() && cov == d.covariance.as_slice();
    let ip_rate = updates as f64 / in_process;
    let pl_rate = r.updates as f64 / r.elapsed_s;
    println!("{}", overhead_title(&cfg, updates)?);
    println!(
        "in-process : {ip_rate:>9.0} updates/s ({:>6.1} µs/update)",
        1e6 / ip_rate
    );
    println!(
        "pipeline   : {pl_rate:>9.0} updates/s ({:>6.1} µs/update)",
        1e6 / pl_rate
    );
    println!(
        "pipeline cost per update: {:.1} µs; final distribution bit-identical: {identical}",
        1e6 / pl_rate - 1e6 / ip_rate
    );
    println!();
    Ok(())
}

/// The overhead part's heading, with the run's K, P and N (it said N = 100 of the via-point's
/// 101 steps when they were written out by hand).
fn overhead_title(cfg: &RunConfig, updates: u64) -> anyhow::Result<String> {
    let size = cfg.memory_need()?;
    Ok(format!(
        "## Pipeline overhead: via-point (K = {}, P = {}, N = {}), 1 worker, {updates} updates",
        size.rollouts, size.parameters, size.steps
    ))
}

fn scaling(dir: &Path, updates: u64) -> anyhow::Result<()> {
    let text = config(&[
        ("updates = 40", &format!("updates = {updates}")),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 10.0",
        ),
    ]);
    println!(
        "## Scaling: rollouts blocking 10 ms, K = 15, {updates} updates per worker count \
         (ms/update after the first update, which also connects every port)"
    );
    println!("workers  ms/update  ideal ms  efficiency  first update ms");
    for w in [1usize, 2, 4, 8, 15] {
        let r = pipeline_run(dir, &format!("scaling-{w}"), &text, w)?;
        let per = r.steady_s_per_update().context("too few updates")? * 1e3;
        let ideal = 15usize.div_ceil(w) as f64 * 10.0;
        println!(
            "{w:>7}  {per:>9.2}  {ideal:>8.1}  {:>9.1}%  {:>15.1}",
            100.0 * ideal / per,
            r.first_update_s * 1e3
        );
    }
    println!();
    Ok(())
}

/// CPU time of a process (all threads) in ns, from `/proc/<pid>/schedstat`.
fn cpu_ns(pid: u32) -> Option<u64> {
    let mut total = 0;
    for t in std::fs::read_dir(format!("/proc/{pid}/task"))
        .ok()?
        .flatten()
    {
        let s = std::fs::read_to_string(t.path().join("schedstat")).ok()?;
        total += s.split_whitespace().next()?.parse::<u64>().ok()?;
    }
    Some(total)
}

fn peak_rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
}

fn idle(dir: &Path, seconds: f64) -> anyhow::Result<()> {
    let text = config(&[
        ("updates = 40\n", ""),
        (
            "viapoint_weight = 1000.0",
            "viapoint_weight = 1000.0\nrollout_delay_ms = 1000.0",
        ),
    ]);
    let cfg = dir.join("idle.toml");
    std::fs::write(&cfg, &text)?;
    let run_id = format!(
        "{:016x}",
        0xbe4c_0000_0000_0000u64 | u64::from(std::process::id())
    );
    let runs = dir.join("runs");
    let mut child = Command::new(supervisor()?)
        .arg("run")
        .arg(&cfg)
        .args(["--quiet", "--no-record", "--run-id", &run_id])
        .env("PI2CMA_RUN_DIR", &runs)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    let status = |child: &mut std::process::Child| -> anyhow::Result<String> {
        let end = Instant::now() + Duration::from_secs(30);
        loop {
            let out = Command::new(supervisor()?)
                .args(["status", "--run", &run_id])
                .env("PI2CMA_RUN_DIR", &runs)
                .output()?;
            let s = String::from_utf8_lossy(&out.stdout).to_string();
            if out.status.success() && s.contains("Running") {
                return Ok(s);
            }
            if Instant::now() > end || child.try_wait()?.is_some() {
                bail!("the idle run did not start");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    let s = status(&mut child)?;
    let mut pids: Vec<(String, u32)> = vec![("supervisor".into(), child.id())];
    for l in s.lines() {
        let f: Vec<&str> = l.split_whitespace().collect();
        if f.len() >= 3 && f[1] == "pid" {
            pids.push((f[0].to_string(), f[2].parse()?));
        }
    }
    std::thread::sleep(Duration::from_millis(500));
    let before: Vec<u64> = pids.iter().map(|(_, p)| cpu_ns(*p).unwrap_or(0)).collect();
    let t0 = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let wall = t0.elapsed().as_secs_f64();
    let after: Vec<u64> = pids.iter().map(|(_, p)| cpu_ns(*p).unwrap_or(0)).collect();
    println!("## Idle group: 3 workers whose rollouts block 1 s (a robot), {seconds} s window");
    println!("process       CPU %   peak RSS");
    let mut total = 0.0;
    for (i, (name, pid)) in pids.iter().enumerate() {
        let cpu = after[i].saturating_sub(before[i]) as f64 * 1e-9 / wall * 100.0;
        total += cpu;
        println!(
            "{name:<12} {cpu:>6.3}  {:>6.1} MiB",
            peak_rss_kib(*pid).unwrap_or(0) as f64 / 1024.0
        );
    }
    println!("all          {total:>6.3}  (% of one core)");
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
    let _ = child.wait();
    println!();
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let dir = scratch()?;
    let parts = |p: &str| cli.parts.iter().any(|x| x == p);
    let r = (|| {
        if parts("overhead") {
            overhead(&dir, cli.updates)?;
        }
        if parts("scaling") {
            scaling(&dir, cli.scaling_updates)?;
        }
        if parts("idle") {
            idle(&dir, cli.idle_s)?;
        }
        anyhow::Ok(())
    })();
    let _ = std::fs::remove_dir_all(&dir);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_overhead_heading_gives_the_runs_own_size() -> anyhow::Result<()> {
        let text = config(&[("updates = 40", "updates = 7")]);
        let cfg = RunConfig::parse(&text, Path::new("overhead.toml"))?;
        assert_eq!(
            overhead_title(&cfg, 7)?,
            "## Pipeline overhead: via-point (K = 15, P = 2, N = 101), 1 worker, 7 updates"
        );
        Ok(())
    }
}
