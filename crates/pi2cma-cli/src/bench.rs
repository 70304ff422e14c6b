//! Micro-benchmarks of the update kernel. They print figures; nothing here asserts speed.

use std::time::{Duration, Instant};

use nalgebra::DVector;
use pi2cma::{
    CostBatch, CostMapping, CovarianceStructure, Distribution, EigenvalueBounds, Exploration,
    Hyperparameters, ParameterBatch, TemporalAveraging, UpdateRule, Weighting,
};
use session::{build_optimizer, build_task, RunConfig, WeightingName};

/// One benchmark's result: the time per call of the measured work.
pub struct Measurement {
    /// What was measured and with which settings, as `pi2cma bench` prints it.
    pub label: String,
    /// Median over the timed groups of the time per call.
    pub median: Duration,
    /// The fastest group: less disturbed by other load on the machine than the median.
    pub min: Duration,
    /// Calls timed in all (groups × calls per group); the warm-up calls before them are not
    /// counted.
    pub samples: usize,
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// Median time of `f`, timed in groups of `inner` calls so the clock's resolution does not
/// dominate sub-microsecond work.
fn measure(label: &str, groups: usize, inner: usize, mut f: impl FnMut()) -> Measurement {
    for _ in 0..inner.min(100) {
        f();
    }
    let times: Vec<Duration> = (0..groups)
        .map(|_| {
            let t = Instant::now();
            for _ in 0..inner {
                f();
            }
            t.elapsed() / inner as u32
        })
        .collect();
    Measurement {
        label: label.to_string(),
        min: times.iter().copied().min().unwrap_or_default(),
        median: median(times),
        samples: groups * inner,
    }
}

/// One full via-point update: ask (sampling), 16 rollouts (the evaluation rollout and 15
/// exploration rollouts, N = 101, P = 2) and tell, with the A1 settings.
pub fn viapoint_update(weighting: WeightingName, groups: usize) -> Measurement {
    let mut cfg = RunConfig::default_config();
    cfg.optimizer.rollouts = 16;
    cfg.optimizer.weighting = weighting;
    cfg.run.updates = None;
    let mut task = build_task(&cfg).expect("default task builds");
    let mut opt = build_optimizer(&cfg, task.as_ref(), 1).expect("default optimizer builds");
    let mut costs = opt.cost_batch();
    let label =
        format!("via-point full update (16 rollouts + update, N = 101, P = 2), {weighting:?}");
    measure(&label, groups, 500, || {
        let batch = opt.ask();
        costs.clear();
        for k in 0..batch.rollouts {
            let (q, phi) = costs.slot_mut(k);
            *phi = task.rollout(batch.row(k), q);
        }
        opt.tell(&costs).expect("finite costs");
    })
}

/// Update only, for a large policy: P = 350 (7 × 50), K = 50, N = 1000, PI²-CMA bounds
/// (λ_min = 0.02), samples drawn from Σ = `lambda`·I. With λ = 1 (early in learning, 50·λ_min)
/// about 2.5 of each step's 49 non-zero eigenvalues fall below λ_min; with λ = 0.05 (late,
/// near λ_min) about 35 do.
pub fn large_update(
    weighting: Weighting,
    groups: usize,
    threads: usize,
    lambda: f64,
) -> Measurement {
    let (p, k, n) = (350usize, 50usize, 1000usize);
    let hp = Hyperparameters {
        rollouts: k,
        mapping: CostMapping::Exponential { eliteness: 10.0 },
        exploration: Exploration::Adaptive {
            bounds: EigenvalueBounds {
                min: 0.02,
                max: f64::INFINITY,
            },
        },
        weighting,
        evaluation_in_update: true,
        covariance: CovarianceStructure::Full,
    };
    let mut rule = UpdateRule::new(hp, p, n, None)
        .expect("valid hyperparameters")
        .with_threads(threads);
    let old = Distribution::isotropic(DVector::zeros(p), lambda).expect("valid distribution");
    let batch = ParameterBatch::sample(&old, 7, 0, k);
    let mut costs = CostBatch::new(k, n);
    for kk in 0..k {
        // Smooth, sample-dependent costs so that every step's weights differ.
        let row = batch.row(kk);
        let q: Vec<f64> = (0..n)
            .map(|i| {
                let j = (i * p) / n;
                row[j] * row[j] * (1.0 + (i as f64 * 0.01).sin())
            })
            .collect();
        costs
            .insert(kk, &q, row.iter().sum::<f64>().abs())
            .expect("finite");
    }
    let label = format!(
        "large update only (P = 350, K = 50, N = 1000, Σ = {lambda}·I), {weighting:?}, \
         {threads} thread(s)"
    );
    let mut m = measure(&label, groups, 1, || {
        rule.update(&old, &batch.values, &costs)
            .expect("valid costs");
    });
    let s = rule.lowrank_stats();
    if s.steps > 0 {
        let per_step = |v: usize| v as f64 / s.steps as f64;
        m.label += &format!(
            " [per step: {:.1} eigenvalues clipped, {:.1} eigenvectors; {:.0}% of steps \
             unclipped, {:.0}% fully decomposed]",
            per_step(s.clipped_values),
            per_step(s.vectors),
            100.0 * per_step(s.unclipped),
            100.0 * per_step(s.full)
        );
    }
    m
}

/// Runs the benchmarks whose name (via-point/per-time-step, via-point/episodic,
/// large/per-time-step, large/per-time-step/2-threads, large/per-time-step/late,
/// large/episodic) contains `filter` ("" for all).
pub fn run_all(quick: bool, filter: &str) -> Vec<Measurement> {
    let per_step = Weighting::PerTimeStep {
        temporal: TemporalAveraging::RemainingSteps,
    };
    let groups = if quick { 4 } else { 200 };
    type Case<'a> = (&'a str, Box<dyn Fn() -> Measurement>);
    let large = if quick { 3 } else { 11 };
    let cases: [Case; 6] = [
        (
            "via-point/per-time-step",
            Box::new(move || viapoint_update(WeightingName::PerTimeStep, groups)),
        ),
        (
            "via-point/episodic",
            Box::new(move || viapoint_update(WeightingName::Episodic, groups)),
        ),
        (
            "large/per-time-step",
            Box::new(move || large_update(per_step, large, 1, 1.0)),
        ),
        (
            "large/per-time-step/2-threads",
            Box::new(move || large_update(per_step, large, 2, 1.0)),
        ),
        (
            "large/per-time-step/late",
            Box::new(move || large_update(per_step, large, 1, 0.05)),
        ),
        (
            "large/episodic",
            Box::new(move || {
                large_update(Weighting::Episodic, if quick { 11 } else { 101 }, 1, 1.0)
            }),
        ),
    ];
    cases
        .iter()
        .filter(|(name, _)| name.contains(filter))
        .map(|(_, run)| run())
        .collect()
}
