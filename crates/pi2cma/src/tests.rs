//! Whole-update tests: hand-computed updates, a literal Algorithm 1 as reference for every
//! covariance kernel, determinism and order independence.

use nalgebra::{DMatrix, DVector};
use rand::{Rng, SeedableRng};

use crate::*;

fn hp(
    k: usize,
    mapping: CostMapping,
    exploration: Exploration,
    weighting: Weighting,
) -> Hyperparameters {
    Hyperparameters {
        rollouts: k,
        mapping,
        exploration,
        weighting,
        evaluation_in_update: true,
        covariance: CovarianceStructure::Full,
    }
}

const PER_STEP: Weighting = Weighting::PerTimeStep {
    temporal: TemporalAveraging::RemainingSteps,
};

/// PI²-CMA as Algorithm 1: exponential mapping with eliteness `h`, adaptive exploration within
/// `bounds`, per-time-step weighting.
fn pi2cma(k: usize, h: f64, bounds: EigenvalueBounds) -> Hyperparameters {
    hp(
        k,
        CostMapping::Exponential { eliteness: h },
        Exploration::Adaptive { bounds },
        PER_STEP,
    )
}

/// The update rule of `hp` for P = `p`, N = `n`, without basis activations.
fn update_rule(hp: Hyperparameters, p: usize, n: usize) -> UpdateRule {
    UpdateRule::new(hp, p, n, None).unwrap()
}

/// The hand-computed example's step costs (K = 3, N = 2; no terminal costs).
fn hand_costs() -> CostBatch {
    let mut costs = CostBatch::new(3, 2);
    costs.insert(0, &[1.0, 1.0], 0.0).unwrap();
    costs.insert(1, &[0.0, 1.0], 0.0).unwrap();
    costs.insert(2, &[2.0, 0.0], 0.0).unwrap();
    costs
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-14 * (1.0 + b.abs())
}

/// K = 3, N = 2, P = 2, h = 2·ln 2 so that every exponential is a power of 2. Worked by hand:
/// step 1: S = (1, 1, 0) → p = (1/6, 1/6, 2/3); step 0: S = (2, 1, 2) → p = (1/6, 2/3, 1/6);
/// temporal weights (2/3, 1/3); θ_new = (1/2, 2/3);
/// Σ_0 = diag(2/3, 2/3), Σ_1 = diag(1/6, 8/3) → bounded to [0.5, 2]: diag(1/2, 2);
/// Σ_new = diag(11/18, 10/9).
#[test]
fn small_update_matches_hand_computation() {
    let bounds = EigenvalueBounds::new(0.5, 2.0).unwrap();
    let h = 2.0 * std::f64::consts::LN_2;
    let mut rule = update_rule(pi2cma(3, h, bounds), 2, 2);
    let old = Distribution::isotropic(DVector::zeros(2), 1.0).unwrap();
    let samples = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0];
    let costs = hand_costs();
    let (new, w) = rule.update(&old, &samples, &costs).unwrap();
    assert!(
        close(new.mean[0], 0.5) && close(new.mean[1], 2.0 / 3.0),
        "{}",
        new.mean
    );
    let c = &new.covariance;
    assert!(close(c[(0, 0)], 11.0 / 18.0), "{c}");
    assert!(close(c[(1, 1)], 10.0 / 9.0), "{c}");
    assert_eq!(c[(0, 1)], 0.0);
    assert_eq!(c[(1, 0)], 0.0);
    // Time-averaged weights: 2/3·(1/6, 2/3, 1/6) + 1/3·(1/6, 1/6, 2/3).
    let expect = [1.0 / 6.0, 1.0 / 2.0, 1.0 / 3.0];
    for (a, b) in w.per_rollout.iter().zip(expect) {
        assert!(close(*a, b), "{:?}", w.per_rollout);
    }

    // Episodic: totals (2, 1, 2) → p = (1/6, 2/3, 1/6), θ = (2/3, 1/3), Σ = diag(2/3, 2/3).
    let mut rule = update_rule(
        hp(
            3,
            CostMapping::Exponential { eliteness: h },
            Exploration::Adaptive { bounds },
            Weighting::Episodic,
        ),
        2,
        2,
    );
    let (new, _) = rule.update(&old, &samples, &costs).unwrap();
    assert!(close(new.mean[0], 2.0 / 3.0) && close(new.mean[1], 1.0 / 3.0));
    assert!(close(new.covariance[(0, 0)], 2.0 / 3.0));
    assert!(close(new.covariance[(1, 1)], 2.0 / 3.0));

    // CEM with one elite (rollout 1): θ = θ_1, Σ = ε_1 ε_1ᵀ = diag(1, 0), bounded to [0.5, 2].
    let mut rule = update_rule(
        hp(
            3,
            CostMapping::Elites { count: 1 },
            Exploration::Adaptive { bounds },
            Weighting::Episodic,
        ),
        2,
        2,
    );
    let (new, _) = rule.update(&old, &samples, &costs).unwrap();
    assert_eq!(new.mean.as_slice(), &[1.0, 0.0]);
    assert_eq!(new.covariance.as_slice(), &[1.0, 0.0, 0.0, 0.5]);
}

#[test]
fn constant_and_decay_exploration() {
    let old = Distribution::isotropic(DVector::zeros(2), 8.0).unwrap();
    let samples = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0];
    let mut costs = CostBatch::new(3, 1);
    for k in 0..3 {
        costs.insert(k, &[k as f64], 0.0).unwrap();
    }
    for (exploration, expect) in [
        (Exploration::Constant, 8.0),
        (Exploration::Decay { factor: 0.8 }, 6.4),
    ] {
        let mut rule = update_rule(
            hp(
                3,
                CostMapping::Exponential { eliteness: 10.0 },
                exploration,
                PER_STEP,
            ),
            2,
            1,
        );
        let (new, _) = rule.update(&old, &samples, &costs).unwrap();
        assert_eq!(new.covariance[(0, 0)], expect);
        assert_eq!(new.covariance[(0, 1)], 0.0);
        assert!(new.mean[0] > 0.0);
    }
}

/// Algorithm 1 exactly as printed, with dense matrices, as a reference for the fast kernels.
fn literal_algorithm_1(
    theta: &DVector<f64>,
    samples: &[DVector<f64>],
    q: &[Vec<f64>],
    phi: &[f64],
    h: f64,
    bounds: EigenvalueBounds,
) -> (DVector<f64>, DMatrix<f64>) {
    let (k, n, p) = (samples.len(), q[0].len(), theta.len());
    let mut num_theta = DVector::zeros(p);
    let mut num_sigma = DMatrix::zeros(p, p);
    let mut den = 0.0;
    for i in 0..n {
        let s: Vec<f64> = (0..k)
            .map(|kk| phi[kk] + q[kk][i..].iter().sum::<f64>())
            .collect();
        let lo = s.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = s
            .iter()
            .map(|v| (-h * (v - lo) / (hi - lo)).exp())
            .collect();
        let sum: f64 = e.iter().sum();
        let mut th = DVector::zeros(p);
        let mut sg = DMatrix::zeros(p, p);
        for kk in 0..k {
            let d = &samples[kk] - theta;
            th += &d * (e[kk] / sum);
            sg += &d * d.transpose() * (e[kk] / sum);
        }
        let sg = boundcovar(&sg, bounds);
        let w = (n - i) as f64;
        num_theta += th * w;
        num_sigma += sg * w;
        den += w;
    }
    (theta + num_theta / den, num_sigma / den)
}

/// The samples of a random problem one after another, as the update takes them.
fn flat(samples: &[DVector<f64>]) -> Vec<f64> {
    samples.iter().flat_map(|s| s.iter().cloned()).collect()
}

/// The cost batch of a random problem's step costs `q` and terminal costs `phi`.
fn cost_batch(q: &[Vec<f64>], phi: &[f64]) -> CostBatch {
    let mut costs = CostBatch::new(q.len(), q[0].len());
    for (k, (q, phi)) in q.iter().zip(phi).enumerate() {
        costs.insert(k, q, *phi).unwrap();
    }
    costs
}

/// A random update problem: θ, K samples (rollout 0 = θ), step costs q (K × N) and terminal φ.
#[allow(clippy::type_complexity)]
fn random_problem(
    rng: &mut impl Rng,
    k: usize,
    n: usize,
    p: usize,
) -> (DVector<f64>, Vec<DVector<f64>>, Vec<Vec<f64>>, Vec<f64>) {
    let theta = DVector::from_fn(p, |_, _| rng.random_range(-1.0..1.0));
    let samples: Vec<DVector<f64>> = (0..k)
        .map(|kk| {
            if kk == 0 {
                theta.clone()
            } else {
                DVector::from_fn(p, |_, _| rng.random_range(-3.0..3.0))
            }
        })
        .collect();
    let q: Vec<Vec<f64>> = (0..k)
        .map(|_| (0..n).map(|_| rng.random_range(0.0..1.0)).collect())
        .collect();
    let phi: Vec<f64> = (0..k).map(|_| rng.random_range(0.0..2.0)).collect();
    (theta, samples, q, phi)
}

#[test]
fn every_covariance_kernel_matches_literal_algorithm_1() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    // P = 2 (closed form), 3 ≤ K (dense), 6 and 12 > K (low rank).
    for &p in &[2usize, 3, 6, 12] {
        for trial in 0..20 {
            let (k, n) = (5, 7);
            let (theta, samples, q, phi) = random_problem(&mut rng, k, n, p);
            let bounds = if trial % 3 == 0 {
                EigenvalueBounds::unbounded()
            } else {
                EigenvalueBounds::new(rng.random_range(0.0..0.5), rng.random_range(1.0..4.0))
                    .unwrap()
            };
            let h = 10.0;
            let (mean, cov) = literal_algorithm_1(&theta, &samples, &q, &phi, h, bounds);
            let mut rule = update_rule(pi2cma(k, h, bounds), p, n);
            let flat = flat(&samples);
            let costs = cost_batch(&q, &phi);
            let old = Distribution::isotropic(theta.clone(), 1.0).unwrap();
            let (new, _) = rule.update(&old, &flat, &costs).unwrap();
            assert!((&new.mean - &mean).amax() < 1e-12, "P={p}: mean");
            assert!(
                (&new.covariance - &cov).amax() < 1e-10 * (1.0 + cov.amax()),
                "P={p} trial {trial}: {} vs {}",
                new.covariance,
                cov
            );
            assert_eq!(new.covariance, new.covariance.transpose());
        }
    }
}

fn optimizer(seed: u64, weighting: Weighting) -> Optimizer {
    Optimizer::new(
        hp(
            6,
            CostMapping::Exponential { eliteness: 10.0 },
            Exploration::Adaptive {
                bounds: EigenvalueBounds::new(0.01, 100.0).unwrap(),
            },
            weighting,
        ),
        Distribution::isotropic(DVector::from_vec(vec![1.0, -1.0, 0.5]), 2.0).unwrap(),
        4,
        seed,
        None,
    )
    .unwrap()
}

fn toy_costs(theta: &[f64]) -> (Vec<f64>, f64) {
    let q: Vec<f64> = (0..4)
        .map(|i| (theta[i % 3] - 0.1 * i as f64).powi(2))
        .collect();
    (q, theta.iter().map(|v| v.abs()).sum())
}

#[test]
fn same_seed_bit_identical_and_told_order_irrelevant() {
    let run = |seed: u64, shuffle: bool| {
        let mut opt = optimizer(seed, PER_STEP);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
        let mut out = vec![];
        for _ in 0..10 {
            let batch = opt.ask().clone();
            let mut order: Vec<usize> = (0..batch.rollouts).collect();
            if shuffle {
                use rand::seq::SliceRandom;
                order.shuffle(&mut rng);
            }
            let mut costs = opt.cost_batch();
            for k in order {
                let (q, phi) = toy_costs(batch.row(k));
                costs.insert(k, &q, phi).unwrap();
            }
            let s = opt.tell(&costs).unwrap();
            out.push(s.eval_cost.to_bits());
        }
        (out, opt.distribution().clone())
    };
    let a = run(5, false);
    let b = run(5, true);
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1, "distribution must be bit-identical");
    let c = run(6, false);
    assert_ne!(a.1, c.1, "another seed must give another run");
}

#[test]
fn nan_cost_is_rejected_by_tell() {
    let mut opt = optimizer(1, Weighting::Episodic);
    opt.ask();
    let mut costs = opt.cost_batch();
    for k in 0..6 {
        let (slot, term) = costs.slot_mut(k);
        slot.fill(1.0);
        *term = if k == 3 { f64::NAN } else { 0.0 };
    }
    let e = opt.tell(&costs).unwrap_err();
    assert_eq!(
        e.to_string(),
        "cost of rollout 3 (terminal) is NaN; costs must be finite"
    );
    assert_eq!(opt.update_index(), 0, "a rejected tell must not advance");
    let mut incomplete = opt.cost_batch();
    incomplete.insert(0, &[0.0; 4], 0.0).unwrap();
    assert!(matches!(
        opt.tell(&incomplete),
        Err(CostError::Missing { rollout: 1 })
    ));
}

#[test]
fn summary_reports_eval_and_exploration_statistics() {
    let mut opt = optimizer(3, Weighting::Episodic);
    let lambda0 = opt.lambda();
    assert_eq!(lambda0, 2.0);
    let n = opt.ask().rollouts;
    let mut costs = opt.cost_batch();
    for k in 0..n {
        costs.insert(k, &[0.0; 4], k as f64).unwrap();
    }
    let s = opt.tell(&costs).unwrap();
    assert_eq!(s.update, 0);
    assert_eq!(s.eval_cost, 0.0);
    assert_eq!(s.exploration_cost_mean, 3.0); // costs 1..5
    assert!((s.exploration_cost_std - 2.5f64.sqrt()).abs() < 1e-15);
    assert_eq!(s.lambda, 2.0);
    assert!((s.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert_eq!(opt.update_index(), 1);
}

/// With the same activation for every parameter, the original PI²'s per-parameter temporal
/// weights reduce to Algorithm 1's (N − i) weights; with an activation that is zero after step 0
/// a parameter only sees the first step's probabilities.
#[test]
fn basis_activation_averaging() {
    let (k, n, p) = (4, 5, 2);
    let mk = |temporal| {
        hp(
            k,
            CostMapping::Exponential { eliteness: 5.0 },
            Exploration::Constant,
            Weighting::PerTimeStep { temporal },
        )
    };
    let samples = [0.0, 0.0, 1.0, -1.0, 0.5, 2.0, -1.0, 0.25];
    let mut costs = CostBatch::new(k, n);
    for kk in 0..k {
        let q: Vec<f64> = (0..n).map(|i| ((kk * 7 + i * 3) % 5) as f64).collect();
        costs.insert(kk, &q, kk as f64).unwrap();
    }
    let old = Distribution::isotropic(DVector::zeros(p), 1.0).unwrap();
    let uniform = vec![0.5; n * p];
    let mut a = update_rule(mk(TemporalAveraging::RemainingSteps), p, n);
    let mut b =
        UpdateRule::new(mk(TemporalAveraging::BasisActivation), p, n, Some(&uniform)).unwrap();
    let (da, _) = a.update(&old, &samples, &costs).unwrap();
    let (db, _) = b.update(&old, &samples, &costs).unwrap();
    assert!((&da.mean - &db.mean).amax() < 1e-14);

    // Parameter 1 active only at step 0: its update uses step 0's probabilities alone.
    let mut first_only = vec![1.0; n * p];
    for i in 1..n {
        first_only[i * p + 1] = 0.0;
    }
    let mut c = UpdateRule::new(
        mk(TemporalAveraging::BasisActivation),
        p,
        n,
        Some(&first_only),
    )
    .unwrap();
    let (dc, _) = c.update(&old, &samples, &costs).unwrap();
    let s0: Vec<f64> = (0..k).map(|kk| costs.total(kk)).collect();
    let mut probs = vec![0.0; k];
    let mut order = vec![0; k];
    CostMapping::Exponential { eliteness: 5.0 }.probabilities(&s0, &mut probs, &mut order);
    let expect: f64 = (0..k).map(|kk| probs[kk] * samples[kk * p + 1]).sum();
    assert!(
        (dc.mean[1] - expect).abs() < 1e-14,
        "{} vs {expect}",
        dc.mean[1]
    );

    // Without activations the option is refused, not silently ignored.
    assert!(UpdateRule::new(mk(TemporalAveraging::BasisActivation), p, n, None).is_err());
}

#[test]
fn threaded_low_rank_update_is_bit_identical_and_matches_algorithm_1() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    let (k, n, p) = (6, 130, 15);
    let (theta, samples, q, phi) = random_problem(&mut rng, k, n, p);
    let bounds = EigenvalueBounds::new(0.3, 3.0).unwrap();
    let flat = flat(&samples);
    let costs = cost_batch(&q, &phi);
    let old = Distribution::isotropic(theta.clone(), 1.0).unwrap();
    let run = |threads| {
        update_rule(pi2cma(k, 10.0, bounds), p, n)
            .with_threads(threads)
            .update(&old, &flat, &costs)
            .unwrap()
            .0
    };
    let (one, two, three) = (run(1), run(2), run(3));
    assert_eq!(one, two);
    assert_eq!(one, three);
    let (mean, cov) = literal_algorithm_1(&theta, &samples, &q, &phi, 10.0, bounds);
    assert!((&one.mean - &mean).amax() < 1e-12);
    assert!((&one.covariance - &cov).amax() < 1e-10 * (1.0 + cov.amax()));
}

/// Finite costs and a finite distribution can still overflow the update's arithmetic (here
/// ε·εᵀ of samples 1e160 from the mean): the update is refused, naming what went non-finite,
/// instead of handing on a NaN distribution that fails one update later as NaN costs. Samples
/// 1e150 away give a Σ of entries up to 9e300, which the 2×2 closed form squared into NaN and
/// refused too; it now scales such a Σ and computes the update: Σ_k P_k ε_k ε_kᵀ (within the
/// bounds, so unchanged by boundcovar).
#[test]
fn an_update_that_overflows_is_refused() {
    let mut rule = update_rule(
        hp(
            3,
            CostMapping::Exponential { eliteness: 10.0 },
            Exploration::Adaptive {
                bounds: EigenvalueBounds::new(1.0, f64::INFINITY).unwrap(),
            },
            Weighting::Episodic,
        ),
        2,
        2,
    );
    let old = Distribution::isotropic(DVector::zeros(2), 1e300).unwrap();
    let costs = hand_costs();
    let samples = [0.0, 0.0, 1e160, 3e160, -2e160, 1e160];
    let r = rule.update(&old, &samples, &costs);
    assert!(
        matches!(r, Err(CostError::NonFiniteUpdate { .. })),
        "{:?}",
        r.map(|(d, _)| d)
    );
    let samples = [0.0, 0.0, 1e150, 3e150, -2e150, 1e150];
    let (new, weights) = rule.update(&old, &samples, &costs).unwrap();
    let p = &weights.per_rollout;
    let eps = |k: usize| DVector::from_column_slice(&samples[2 * k..2 * k + 2]);
    let expected: DMatrix<f64> = (1..3).map(|k| eps(k) * eps(k).transpose() * p[k]).sum();
    let off = (&new.covariance - &expected).amax() / expected.amax();
    assert!(off < 1e-14, "{} vs {expected}", new.covariance);
}

/// A distribution or sample batch of another P is refused with an error naming both shapes
/// (the rule is for P = 2), directly and through an optimizer resumed from such a
/// distribution, instead of a panic; the rule then still computes a right-shaped update.
#[test]
fn a_distribution_or_samples_of_another_dimension_are_refused() {
    let exploration = Exploration::Adaptive {
        bounds: EigenvalueBounds::new(0.0, f64::INFINITY).unwrap(),
    };
    let h = hp(
        3,
        CostMapping::Exponential { eliteness: 2.0 },
        exploration,
        PER_STEP,
    );
    let mut rule = update_rule(h.clone(), 2, 2);
    let costs = hand_costs();
    let wide = Distribution::isotropic(DVector::zeros(3), 1.0).unwrap();
    let samples3 = vec![0.5; 9];
    let r = rule.update(&wide, &samples3, &costs).map(|(d, _)| d);
    assert_eq!(
        r,
        Err(CostError::WrongDistribution {
            dim: 2,
            mean: 3,
            rows: 3,
            cols: 3
        })
    );
    // A mean of the right length with a covariance of another shape.
    let odd = Distribution {
        mean: DVector::zeros(2),
        covariance: DMatrix::identity(3, 3),
    };
    let r = rule.update(&odd, &[0.5; 6], &costs).map(|(d, _)| d);
    assert!(
        matches!(
            r,
            Err(CostError::WrongDistribution {
                rows: 3,
                cols: 3,
                ..
            })
        ),
        "{r:?}"
    );
    let old = Distribution::isotropic(DVector::zeros(2), 1.0).unwrap();
    let r = rule.update(&old, &samples3, &costs).map(|(d, _)| d);
    assert_eq!(
        r,
        Err(CostError::WrongSamples {
            expected: 6,
            got: 9
        })
    );
    let e = r.unwrap_err().to_string();
    assert!(e.contains("K × P = 6") && e.contains("9 values"), "{e}");
    let (new, _) = rule
        .update(&old, &[0.0, 0.0, 1.0, 0.5, -1.0, 0.25], &costs)
        .unwrap();
    assert_eq!(new.dim(), 2);

    let mut opt = Optimizer::resume(update_rule(h, 2, 2), wide, 7, 0);
    let told = opt.tell(&costs).map(|s| s.update);
    assert!(
        matches!(
            told,
            Err(CostError::WrongDistribution {
                dim: 2,
                mean: 3,
                ..
            })
        ),
        "{told:?}"
    );
    assert_eq!(opt.update_index(), 0, "a refused update does not advance");
}

/// One rollout is θ itself: with or without it in the update, nothing would be learned.
#[test]
fn one_rollout_is_refused_with_or_without_the_evaluation_in_the_update() {
    for evaluation_in_update in [true, false] {
        let h = Hyperparameters {
            evaluation_in_update,
            ..hp(
                1,
                CostMapping::Exponential { eliteness: 10.0 },
                Exploration::Constant,
                Weighting::Episodic,
            )
        };
        assert!(
            matches!(
                h.check(),
                Err(ParameterError::OutOfRange {
                    field: "rollouts",
                    ..
                })
            ),
            "{evaluation_in_update}"
        );
        assert!(Hyperparameters { rollouts: 2, ..h }.check().is_ok());
    }
}

/// Algorithm 1, line 18 is defined for any max > min, however close: the best rollout of a step
/// gets e⁰ and the worst e^−h. Step costs that differ only in the subnormals (an external task
/// whose costs vanish at the end of the movement) make h/(max − min) overflow; the per-step
/// probabilities must still be those of line 18, as the episodic mapping's are, not 0·∞ = NaN.
/// Worked by hand with h = 2·ln 2 (e^−h = 1/4): p = (4/9, 1/9, 4/9), θ_new = (1/9, 8/9), and
/// Σ_new = diag(1/9, 16/9) (within the bounds, so unchanged).
#[test]
fn per_step_probabilities_of_costs_a_subnormal_apart_follow_line_18() {
    let h = 2.0 * std::f64::consts::LN_2;
    let tiny = f64::from_bits(1);
    let old = Distribution::isotropic(DVector::zeros(2), 1.0).unwrap();
    let samples = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0];
    let bounds = EigenvalueBounds::new(0.01, 100.0).unwrap();
    for (step_costs, terminal) in [([0.0, tiny, 0.0], 0.0), ([0.0, 0.0, 0.0], tiny)] {
        let mut costs = CostBatch::new(3, 2);
        for k in 0..3 {
            let (q, phi) = if terminal == 0.0 {
                ([0.0, step_costs[k]], 0.0)
            } else {
                ([0.0, 0.0], if k == 1 { terminal } else { 0.0 })
            };
            costs.insert(k, &q, phi).unwrap();
        }
        let mut rule = update_rule(pi2cma(3, h, bounds), 2, 2);
        let (new, w) = rule.update(&old, &samples, &costs).unwrap();
        assert!(
            close(new.mean[0], 1.0 / 9.0) && close(new.mean[1], 8.0 / 9.0),
            "{}",
            new.mean
        );
        let c = &new.covariance;
        assert!(
            close(c[(0, 0)], 1.0 / 9.0) && close(c[(1, 1)], 16.0 / 9.0),
            "{c}"
        );
        assert_eq!(c[(0, 1)], 0.0);
        for (a, b) in w.per_rollout.iter().zip([4.0 / 9.0, 1.0 / 9.0, 4.0 / 9.0]) {
            assert!(close(*a, b), "{:?}", w.per_rollout);
        }
    }
}

/// boundcovar by cyclic Jacobi rotations: an eigen-solver that shares no code with the crate's
/// (tred2/tql2, the 2×2 closed form, the low-rank K×K problem), for the references below.
fn jacobi_boundcovar(m: &DMatrix<f64>, bounds: EigenvalueBounds) -> DMatrix<f64> {
    let n = m.nrows();
    let (mut a, mut v) = (m.clone(), DMatrix::<f64>::identity(n, n));
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .filter(|(i, j)| i != j)
            .map(|(i, j)| a[(i, j)].powi(2))
            .sum();
        if off <= 1e-28 * a.norm_squared() {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[(p, q)] == 0.0 {
                    continue;
                }
                // Golub & Van Loan, Algorithm 8.5.1 (the symmetric Schur decomposition).
                let tau = (a[(q, q)] - a[(p, p)]) / (2.0 * a[(p, q)]);
                let t = tau.signum() / (tau.abs() + (1.0 + tau * tau).sqrt());
                let c = 1.0 / (1.0 + t * t).sqrt();
                let mut r = DMatrix::<f64>::identity(n, n);
                (r[(p, p)], r[(q, q)], r[(p, q)], r[(q, p)]) = (c, c, t * c, -t * c);
                a = r.transpose() * &a * &r;
                v = &v * &r;
            }
        }
    }
    (0..n).fold(DMatrix::zeros(n, n), |acc, j| {
        acc + v.column(j) * v.column(j).transpose() * bounds.clip(a[(j, j)])
    })
}

/// The episodic mode (PI^BB) is Algorithm 1 with one step whose cost is the total S_0: one
/// probability per rollout from lines 18–19, θ_new = θ + Σ_k P_k ε_k, Σ_new =
/// boundcovar(Σ_k P_k ε_k ε_kᵀ). Checked for every covariance kernel (P = 2 closed form, dense,
/// and the low-rank one the T-ball run takes with P = 21 > K = 10) and with the evaluation
/// rollout in and out of the update; the per-time-step mode with rollout 0 left out is checked
/// against `literal_algorithm_1` over the other rollouts.
#[test]
fn episodic_and_evaluation_excluded_updates_match_the_formulas() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(99);
    let (k, n, h) = (5, 7, 10.0);
    for &p in &[2usize, 3, 6, 12] {
        for evaluation_in_update in [true, false] {
            for _ in 0..10 {
                let (theta, samples, q, phi) = random_problem(&mut rng, k, n, p);
                let bounds =
                    EigenvalueBounds::new(rng.random_range(0.0..0.5), rng.random_range(1.0..4.0))
                        .unwrap();
                let first = usize::from(!evaluation_in_update);
                let s: Vec<f64> = (first..k)
                    .map(|r| phi[r] + q[r].iter().sum::<f64>())
                    .collect();
                let lo = s.iter().cloned().fold(f64::INFINITY, f64::min);
                let hi = s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
                let e: Vec<f64> = s
                    .iter()
                    .map(|v| (-h * (v - lo) / (hi - lo)).exp())
                    .collect();
                let total: f64 = e.iter().sum();
                let (mut mean, mut cov) = (theta.clone(), DMatrix::zeros(p, p));
                for (r, sample) in samples[first..].iter().enumerate() {
                    let d = sample - &theta;
                    mean += &d * (e[r] / total);
                    cov += &d * d.transpose() * (e[r] / total);
                }
                let cov = jacobi_boundcovar(&cov, bounds);

                let old = Distribution::isotropic(theta.clone(), 1.0).unwrap();
                let (flat, costs) = (flat(&samples), cost_batch(&q, &phi));
                let mapping = CostMapping::Exponential { eliteness: h };
                let adaptive = Exploration::Adaptive { bounds };
                let episodic = Hyperparameters {
                    evaluation_in_update,
                    ..hp(k, mapping, adaptive, Weighting::Episodic)
                };
                let (new, _) = update_rule(episodic, p, n)
                    .update(&old, &flat, &costs)
                    .unwrap();
                let tol = 1e-10 * (1.0 + cov.amax());
                assert!((&new.mean - &mean).amax() < 1e-12, "P={p}: {}", new.mean);
                assert!(
                    (&new.covariance - &cov).amax() < tol,
                    "P={p}, evaluation in update: {evaluation_in_update}: {} vs {cov}",
                    new.covariance
                );

                let per_step = Hyperparameters {
                    evaluation_in_update,
                    ..pi2cma(k, h, bounds)
                };
                let (new, _) = update_rule(per_step, p, n)
                    .update(&old, &flat, &costs)
                    .unwrap();
                let (mean, cov) = literal_algorithm_1(
                    &theta,
                    &samples[first..],
                    &q[first..],
                    &phi[first..],
                    h,
                    bounds,
                );
                assert!((&new.mean - &mean).amax() < 1e-12, "P={p}: {}", new.mean);
                assert!((&new.covariance - &cov).amax() < 1e-10 * (1.0 + cov.amax()));
            }
        }
    }
}

/// Per-dimension covariance, worked by hand: P = 4 = 2 DMP dimensions × B = 2, K = 3, episodic
/// with the hand example's totals (2, 1, 2) → p = (1/6, 2/3, 1/6), bounds [0.5, 2].
/// ε_1 = (1, 1, 0, 2), ε_2 = (1, −1, 2, 0).
/// Block 0: 2/3·[1 1; 1 1] + 1/6·[1 −1; −1 1] = [5/6 1/2; 1/2 5/6], eigenvalues 4/3 along
/// (1, 1)/√2 and 1/3 along (1, −1)/√2; 1/3 is raised to 1/2: [11/12 5/12; 5/12 11/12].
/// Block 1: 2/3·diag(0, 4) + 1/6·diag(4, 0) = diag(2/3, 8/3), bounded: diag(2/3, 2).
/// The entries across blocks are 0 (a full Σ would have e.g. Σ_02 = 1/6·1·2 = 1/3).
/// θ_new = 2/3·ε_1 + 1/6·ε_2 = (5/6, 1/2, 1/3, 4/3); λ_next = 2.
#[test]
fn per_dimension_update_matches_hand_computation() {
    let bounds = EigenvalueBounds::new(0.5, 2.0).unwrap();
    let h = 2.0 * std::f64::consts::LN_2;
    let per_dimension = Hyperparameters {
        covariance: CovarianceStructure::PerDimension { block: 2 },
        ..hp(
            3,
            CostMapping::Exponential { eliteness: h },
            Exploration::Adaptive { bounds },
            Weighting::Episodic,
        )
    };
    let old = Distribution::isotropic(DVector::zeros(4), 1.0).unwrap();
    let samples = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 2.0, 1.0, -1.0, 2.0, 0.0];
    let mut costs = CostBatch::new(3, 2);
    costs.insert(0, &[1.0, 1.0], 0.0).unwrap();
    costs.insert(1, &[0.0, 1.0], 0.0).unwrap();
    costs.insert(2, &[2.0, 0.0], 0.0).unwrap();
    let mut opt = Optimizer::resume(
        UpdateRule::new(per_dimension.clone(), 4, 2, None).unwrap(),
        old.clone(),
        1,
        0,
    );
    let (new, _) = update_rule(per_dimension, 4, 2)
        .update(&old, &samples, &costs)
        .unwrap();
    for (a, b) in new.mean.iter().zip([5.0 / 6.0, 0.5, 1.0 / 3.0, 4.0 / 3.0]) {
        assert!(close(*a, b), "{}", new.mean);
    }
    #[rustfmt::skip]
    let expect = DMatrix::from_row_slice(4, 4, &[
        11.0 / 12.0, 5.0 / 12.0, 0.0, 0.0,
        5.0 / 12.0, 11.0 / 12.0, 0.0, 0.0,
        0.0, 0.0, 2.0 / 3.0, 0.0,
        0.0, 0.0, 0.0, 2.0,
    ]);
    for (a, b) in new.covariance.iter().zip(expect.iter()) {
        assert!(close(*a, *b), "{}", new.covariance);
    }
    for (i, j) in [(0, 2), (0, 3), (1, 2), (1, 3)] {
        assert_eq!(new.covariance[(i, j)], 0.0);
        assert_eq!(new.covariance[(j, i)], 0.0);
    }

    // The same update through ask/tell, with these samples: λ_next is the blocks' largest.
    let mut rule = update_rule(
        Hyperparameters {
            covariance: CovarianceStructure::PerDimension { block: 2 },
            ..hp(
                3,
                CostMapping::Exponential { eliteness: h },
                Exploration::Adaptive { bounds },
                Weighting::Episodic,
            )
        },
        4,
        2,
    );
    let (again, _) = rule.update(&old, &samples, &costs).unwrap();
    assert_eq!(again, new);
    assert!(close(rule.lambda_of(&new), 2.0));
    assert_eq!(opt.lambda(), 1.0);
    let summary = opt.tell(&random_costs_for(&opt)).unwrap();
    let c = &opt.distribution().covariance;
    assert_eq!(summary.lambda_next, rule.lambda_of(opt.distribution()));
    for (i, j) in [(0, 2), (0, 3), (1, 2), (1, 3)] {
        assert_eq!(c[(i, j)], 0.0, "{c}");
    }
}

/// Costs for the optimizer's current batch (any finite values will do).
fn random_costs_for(opt: &Optimizer) -> CostBatch {
    let mut costs = opt.cost_batch();
    for k in 0..costs.rollouts() {
        let q: Vec<f64> = (0..costs.steps())
            .map(|i| ((k * 7 + i * 3) % 5) as f64)
            .collect();
        costs.insert(k, &q, k as f64).unwrap();
    }
    costs
}

/// Per-time-step PI²-CMA with a per-dimension covariance: each B×B block is Algorithm 1 run on
/// that dimension's parameters alone (`literal_algorithm_1`, same costs), the mean is the full
/// update's, and the entries across blocks are 0. B = 2 (closed form), 3 (dense), 6 (low rank,
/// B > K).
#[test]
fn per_dimension_per_time_step_blocks_are_algorithm_1_per_dimension() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (k, n, h) = (5, 7, 10.0);
    for &(dims, b) in &[(3usize, 2usize), (2, 3), (3, 6)] {
        let p = dims * b;
        for _ in 0..5 {
            let (theta, samples, q, phi) = random_problem(&mut rng, k, n, p);
            let bounds =
                EigenvalueBounds::new(rng.random_range(0.0..0.5), rng.random_range(1.0..4.0))
                    .unwrap();
            let per_dim = Hyperparameters {
                covariance: CovarianceStructure::PerDimension { block: b },
                ..pi2cma(k, h, bounds)
            };
            let old = Distribution::isotropic(theta.clone(), 1.0).unwrap();
            let (new, _) = update_rule(per_dim, p, n)
                .update(&old, &flat(&samples), &cost_batch(&q, &phi))
                .unwrap();
            let (full, _) = update_rule(pi2cma(k, h, bounds), p, n)
                .update(&old, &flat(&samples), &cost_batch(&q, &phi))
                .unwrap();
            assert_eq!(new.mean, full.mean);
            for d in 0..dims {
                let sub = |v: &DVector<f64>| v.rows(d * b, b).clone_owned();
                let sub_samples: Vec<DVector<f64>> = samples.iter().map(sub).collect();
                let (_, cov) = literal_algorithm_1(&sub(&theta), &sub_samples, &q, &phi, h, bounds);
                let got = new.covariance.view((d * b, d * b), (b, b));
                assert!(
                    (got - &cov).amax() < 1e-10 * (1.0 + cov.amax()),
                    "B={b}, block {d}: {got} vs {cov}"
                );
            }
            for i in 0..p {
                for j in 0..p {
                    if i / b != j / b {
                        assert_eq!(new.covariance[(i, j)], 0.0, "B={b}");
                    }
                }
            }
        }
    }
}

/// P must be whole DMP dimensions of B parameters.
#[test]
fn per_dimension_needs_p_to_be_a_multiple_of_the_block() {
    let bounds = EigenvalueBounds::new(0.1, 2.0).unwrap();
    let h = Hyperparameters {
        covariance: CovarianceStructure::PerDimension { block: 3 },
        ..pi2cma(5, 10.0, bounds)
    };
    assert!(matches!(
        UpdateRule::new(h.clone(), 7, 4, None),
        Err(ParameterError::OutOfRange {
            field: "covariance",
            ..
        })
    ));
    assert!(UpdateRule::new(h, 6, 4, None).is_ok());
    let zero = Hyperparameters {
        covariance: CovarianceStructure::PerDimension { block: 0 },
        ..pi2cma(5, 10.0, bounds)
    };
    assert!(zero.check().is_err());
}

/// A user whose task stops giving information (costs unrelated to θ) keeps learning: CEM has no
/// lower bound, so Σ shrinks towards 0 update after update, as does PI²-CMA bounded to
/// [0, 1e-300]. Σ then has entries far below 1 and eigenvalues spanning hundreds of orders of
/// magnitude, and the eigen-decomposition the sampler falls back on (Cholesky fails on a
/// singular Σ) gave eigenvalues ±∞: parameters came out NaN after 253 CEM updates of P = 200
/// ("cost of rollout 1 (terminal) is NaN" from a task that multiplies θ by 0), and at once
/// for the 1e-300 bound. Every batch must stay finite and every update go through.
#[test]
fn a_covariance_shrinking_towards_zero_keeps_drawing_finite_parameters() {
    let episodic = |mapping, bounds| Hyperparameters {
        evaluation_in_update: false,
        ..hp(
            10,
            mapping,
            Exploration::Adaptive { bounds },
            Weighting::Episodic,
        )
    };
    let cem = episodic(
        CostMapping::Elites { count: 3 },
        EigenvalueBounds::unbounded(),
    );
    let tiny = episodic(
        CostMapping::Exponential { eliteness: 10.0 },
        EigenvalueBounds::new(0.0, 1e-300).unwrap(),
    );
    for (name, hp, updates) in [("CEM", cem, 300u64), ("λ_max = 1e-300", tiny, 5)] {
        let p = 200;
        let initial = Distribution::isotropic(DVector::from_element(p, 3.0), 1.0).unwrap();
        let mut opt = Optimizer::new(hp, initial, 3, 7, None).unwrap();
        for u in 0..updates {
            let lambda = opt.lambda();
            let batch = opt.ask();
            if let Some(bad) = batch.values.iter().position(|v| !v.is_finite()) {
                panic!(
                    "{name}, update {u}: parameter {bad} of the batch is {} (λ {:e})",
                    batch.values[bad], lambda
                );
            }
            let mut costs = opt.cost_batch();
            for k in 0..10 {
                let uninformative = ((u * 31 + k * 7) % 13) as f64;
                costs.insert(k as usize, &[0.0; 3], uninformative).unwrap();
            }
            if let Err(e) = opt.tell(&costs) {
                panic!("{name}, update {u}: {e}");
            }
        }
        let d = opt.distribution();
        assert!(opt.lambda().is_finite() && opt.lambda() >= 0.0, "{name}");
        assert!(d.smallest_eigenvalue().is_finite(), "{name}");
    }
}
