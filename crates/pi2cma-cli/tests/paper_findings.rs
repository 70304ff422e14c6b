//! The paper's qualitative findings on the via-point task (Section IV-A), asserted on means over
//! 10 learning sessions of the configs in `config/`, in the episodic weighting mode. The
//! per-time-step mode is reported in the README, not asserted: it does not converge here.

use std::path::PathBuf;

use pi2cma_cli::experiment::{run_config, ConfigResult};
use session::RunConfig;

fn run(name: &str) -> ConfigResult {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../config")
        .join(format!("{name}.toml"));
    let cfg = RunConfig::load(&path).expect("paper config loads");
    assert_eq!(cfg.optimizer.weighting, session::WeightingName::Episodic);
    run_config(&cfg, 10).expect("session runs")
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn larger_constant_exploration_gives_larger_cost_spread() {
    let spread: Vec<f64> = ["C1", "C2", "C3"]
        .iter()
        .map(|c| mean(&run(c).mean_exploration_std()[10..]))
        .collect();
    assert!(spread[0] < spread[1] && spread[1] < spread[2], "{spread:?}");
}

#[test]
fn decay_fails_to_relearn_where_pi2_cma_succeeds() {
    let (d, a2) = (run("D"), run("A2"));
    assert_eq!(d.reconvergence_update(), None, "decay must not re-converge");
    assert!(
        a2.reconvergence_update().is_some(),
        "PI²-CMA must re-converge"
    );
    let (d_last, a_last) = (d.mean_eval_cost()[39], a2.mean_eval_cost()[39]);
    assert!(d_last > 2.0 * a_last, "D {d_last} vs A2 {a_last}");
    // Both learn the first task.
    let (d19, a19) = (d.mean_eval_cost()[19], a2.mean_eval_cost()[19]);
    assert!(d19 < 0.2 * d.mean_eval_cost()[0] && a19 < 0.2 * a2.mean_eval_cost()[0]);
}

#[test]
fn pi2_cma_exploration_falls_when_learned_and_rises_after_the_change() {
    let a1 = run("A1");
    let l = a1.mean_lambda();
    assert!(
        l[19] < l[0] / 20.0,
        "λ must fall while task 1 is learned: {} → {}",
        l[0],
        l[19]
    );
    let peak = l[21..30].iter().cloned().fold(0.0, f64::max);
    assert!(
        peak > 10.0 * l[19],
        "λ must rise after the change: {} → {peak}",
        l[19]
    );
    assert!(
        l[39] < peak / 2.0,
        "λ must fall again once re-learned: {peak} → {}",
        l[39]
    );
}

#[test]
fn reconvergence_is_slowest_for_low_and_fastest_for_high_lambda_min() {
    // Not re-converged within the run counts as later than any update of it: with λ_min = 2 the
    // mean curve reaches the threshold right at the end of the 40 updates (the paper: 38).
    let u: Vec<u64> = ["A1", "A2", "A3"]
        .iter()
        .map(|c| run(c).reconvergence_update().unwrap_or(u64::MAX))
        .collect();
    assert!(u[0] > u[1] && u[1] > u[2], "re-convergence updates {u:?}");
    assert!(
        u[1] < 40 && u[2] < 40,
        "λ_min = 20 and 200 must re-converge: {u:?}"
    );
}

#[test]
fn initial_exploration_does_not_matter_after_a_few_updates() {
    let (a3, a4) = (run("A3").mean_lambda(), run("A4").mean_lambda());
    assert!((a3[0] / a4[0] - 10.0).abs() < 1e-9);
    // The paper sees the curves coincide after about 5 updates; here λ_init = 200 first climbs
    // to several thousand, and the two runs coincide from about update 10 (see the README).
    for u in 10..40 {
        let ratio = a3[u] / a4[u];
        assert!(
            (0.67..1.5).contains(&ratio),
            "update {u}: λ {} vs {}",
            a3[u],
            a4[u]
        );
    }
}
