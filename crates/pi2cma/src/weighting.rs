//! Cost-to-probability mappings (Algorithm 1, lines 18–19, and CEM's elites).

use crate::error::ParameterError;

/// How the costs of one time step (or of whole rollouts, in episodic mode) become probabilities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CostMapping {
    /// PI²: P_k ∝ exp(−h·(S_k − min S)/(max S − min S)), with eliteness h.
    Exponential {
        /// h > 0: how strongly low costs are preferred (the paper uses 10 and 15).
        eliteness: f64,
    },
    /// CEM: the `count` lowest-cost rollouts get 1/count each, the rest 0.
    Elites {
        /// Rollouts that share the probability, 1 ≤ count ≤ rollouts in the update.
        count: usize,
    },
}

impl CostMapping {
    /// Refuses an eliteness that is not finite and > 0, and an elite count outside
    /// 1..=`rollouts_in_update`.
    pub fn check(&self, rollouts_in_update: usize) -> Result<(), ParameterError> {
        match *self {
            CostMapping::Exponential { eliteness } => {
                if !(eliteness.is_finite() && eliteness > 0.0) {
                    return Err(ParameterError::OutOfRange {
                        field: "eliteness",
                        value: eliteness.to_string(),
                        reason: "must be finite and > 0",
                    });
                }
            }
            CostMapping::Elites { count } => {
                if count == 0 || count > rollouts_in_update {
                    return Err(ParameterError::OutOfRange {
                        field: "elites",
                        value: count.to_string(),
                        reason:
                            "must be between 1 and the number of rollouts that enter the update",
                    });
                }
            }
        }
        Ok(())
    }

    /// Writes the probabilities for `costs` into `out` (same length). `order` is scratch space of
    /// the same length for the elites mapping. Equal costs give uniform probabilities, never NaN.
    pub fn probabilities(&self, costs: &[f64], out: &mut [f64], order: &mut [usize]) {
        debug_assert_eq!(costs.len(), out.len());
        let n = costs.len();
        match *self {
            CostMapping::Exponential { eliteness } => {
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for &c in costs {
                    lo = lo.min(c);
                    hi = hi.max(c);
                }
                let range = hi - lo;
                if !(range > 0.0) {
                    out.fill(1.0 / n as f64);
                    return;
                }
                let scale = -eliteness / range;
                if scale.is_finite() && range.is_finite() {
                    for (o, &c) in out.iter_mut().zip(costs) {
                        *o = exp_nonpositive((c - lo) * scale);
                    }
                } else {
                    // A range so small that h/range overflows (subnormal differences), or so
                    // large that hi − lo does (costs near ±f64::MAX): (c − lo)·scale would be
                    // 0·∞ = NaN for the best rollout. Normalising first keeps (c − lo)/range in
                    // [0, 1]; an infinite range is normalised on halves, which cannot overflow.
                    // Every other range takes the branch above, whose rounding the recorded
                    // runs were made with.
                    let normalised = |c: f64| {
                        if range.is_finite() {
                            (c - lo) / range
                        } else {
                            (c / 2.0 - lo / 2.0) / (hi / 2.0 - lo / 2.0)
                        }
                    };
                    for (o, &c) in out.iter_mut().zip(costs) {
                        *o = exp_nonpositive(-eliteness * normalised(c).min(1.0));
                    }
                }
                let sum: f64 = out.iter().sum();
                let inv = 1.0 / sum;
                out.iter_mut().for_each(|o| *o *= inv);
            }
            CostMapping::Elites { count } => {
                for (i, o) in order.iter_mut().enumerate() {
                    *o = i;
                }
                // Ties are broken by rollout index, so the result never depends on arrival order.
                order.sort_unstable_by(|&a, &b| costs[a].total_cmp(&costs[b]).then(a.cmp(&b)));
                out.fill(0.0);
                let w = 1.0 / count as f64;
                for &k in &order[..count] {
                    out[k] = w;
                }
            }
        }
    }
}

/// e^x for x ≤ 0, branch-free so that the loop over a batch vectorises (the exponentials are
/// the largest part of a per-time-step update). Range reduction x = n·ln2 + r, |r| ≤ ln2/2, and a
/// degree-13 Taylor polynomial: within a few ulp of `f64::exp` over [−708, 0]. Below −708 it
/// returns e^−708 ≈ 3·10⁻³⁰⁸ instead of a subnormal or 0; the probabilities it feeds are
/// normalised by a sum ≥ 1, so that difference cannot show.
#[inline(always)]
pub fn exp_nonpositive(x: f64) -> f64 {
    const LOG2E: f64 = std::f64::consts::LOG2_E;
    // ln 2 split as in fdlibm: LN2_HI has trailing zero bits, so n·LN2_HI is exact.
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
    // Adding 1.5·2^52 rounds to the nearest integer and leaves n in the low mantissa bits.
    const SHIFTER: f64 = 6_755_399_441_055_744.0;
    let x = x.clamp(-708.0, 0.0);
    let t = x * LOG2E + SHIFTER;
    let n = t - SHIFTER;
    let r = (x - n * LN2_HI) - n * LN2_LO;
    // Estrin's scheme: a shallow tree instead of a 13-deep Horner chain, so consecutive
    // elements overlap in the pipeline.
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let p01 = 1.0 + r;
    let p23 = 0.5 + r * (1.0 / 6.0);
    let p45 = 1.0 / 24.0 + r * (1.0 / 120.0);
    let p67 = 1.0 / 720.0 + r * (1.0 / 5_040.0);
    let p89 = 1.0 / 40_320.0 + r * (1.0 / 362_880.0);
    let p1011 = 1.0 / 3_628_800.0 + r * (1.0 / 39_916_800.0);
    let p1213 = 1.0 / 479_001_600.0 + r * (1.0 / 6_227_020_800.0);
    let p03 = p01 + r2 * p23;
    let p47 = p45 + r2 * p67;
    let p811 = p89 + r2 * p1011;
    let p813 = p811 + r4 * p1213;
    let p = (p03 + r4 * p47) + r8 * p813;
    // 2^n from n's low bits: n ∈ [−1022, 0], so n + 1023 fits the exponent field.
    let scale = f64::from_bits((t.to_bits().wrapping_add(1023)) << 52);
    p * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    fn probs(m: CostMapping, c: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; c.len()];
        let mut order = vec![0; c.len()];
        m.probabilities(c, &mut out, &mut order);
        out
    }

    #[test]
    fn exponential_hand_checked() {
        // Costs 0, 1, 2 with h = ln 2·2: exponents 0, −ln2, −2ln2 → 1, 1/2, 1/4, sum 7/4.
        let h = 2.0 * std::f64::consts::LN_2;
        let p = probs(
            CostMapping::Exponential { eliteness: h },
            &[10.0, 11.0, 12.0],
        );
        let expect = [4.0 / 7.0, 2.0 / 7.0, 1.0 / 7.0];
        for (a, b) in p.iter().zip(expect) {
            assert!((a - b).abs() < 1e-15, "{p:?}");
        }
    }

    #[test]
    fn extreme_ranges_give_probabilities_not_nan() {
        let m = CostMapping::Exponential { eliteness: 10.0 };
        // h / range overflows: the best rollout would get 0·∞.
        let tiny = probs(m, &[0.0, f64::from_bits(1), 0.0]);
        // hi − lo overflows.
        let huge = probs(m, &[-f64::MAX, f64::MAX, 0.0]);
        for p in [&tiny, &huge] {
            assert!(p.iter().all(|v| v.is_finite()), "{p:?}");
            assert!((p.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{p:?}");
        }
        // The worst rollout gets e^−h relative to the best, as for any other range.
        assert!(
            (tiny[1] / tiny[0] - (-10.0f64).exp()).abs() < 1e-12,
            "{tiny:?}"
        );
        assert!(
            (huge[1] / huge[0] - (-10.0f64).exp()).abs() < 1e-12,
            "{huge:?}"
        );
        assert!(
            (huge[2] / huge[0] - (-5.0f64).exp()).abs() < 1e-12,
            "{huge:?}"
        );
    }

    #[test]
    fn exp_nonpositive_matches_std_exp() {
        let mut worst: f64 = 0.0;
        for i in 0..=200_000 {
            let x = -708.0 * i as f64 / 200_000.0;
            let (a, b) = (exp_nonpositive(x), x.exp());
            worst = worst.max(((a - b) / b).abs());
        }
        assert!(worst < 1e-15, "relative error {worst}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-800.0), exp_nonpositive(-708.0));
        assert!(exp_nonpositive(-1e-300) == 1.0);
    }

    #[test]
    fn equal_costs_give_uniform_weights() {
        for m in [
            CostMapping::Exponential { eliteness: 10.0 },
            CostMapping::Elites { count: 4 },
        ] {
            let p = probs(m, &[3.0; 4]);
            assert_eq!(p, vec![0.25; 4], "{m:?}");
        }
    }

    #[test]
    fn elites_hand_checked_with_ties_by_index() {
        let p = probs(CostMapping::Elites { count: 2 }, &[5.0, 1.0, 3.0, 1.0]);
        assert_eq!(p, vec![0.0, 0.5, 0.0, 0.5]);
        let p = probs(CostMapping::Elites { count: 1 }, &[2.0, 1.0, 1.0]);
        assert_eq!(p, vec![0.0, 1.0, 0.0]);
    }

    #[test]
    fn check_rejects_bad_values() {
        assert!(CostMapping::Exponential { eliteness: 0.0 }
            .check(3)
            .is_err());
        assert!(CostMapping::Exponential {
            eliteness: f64::NAN
        }
        .check(3)
        .is_err());
        assert!(CostMapping::Elites { count: 4 }.check(3).is_err());
        assert!(CostMapping::Elites { count: 0 }.check(3).is_err());
    }
}
