//! Cost trajectories: what a rollout returns, and the batch of K of them an update consumes.

use crate::error::CostError;

/// The cost of one rollout: an immediate cost q_i per time step and a terminal cost φ_N.
///
/// Episodic tasks that only know a total cost report it as `terminal` with zero step costs.
#[derive(Debug, Clone, PartialEq)]
pub struct CostTrajectory {
    /// q_i for the N time steps i = 0…N−1.
    pub per_step: Vec<f64>,
    /// φ_N, added after the last step.
    pub terminal: f64,
}

impl CostTrajectory {
    /// N zero step costs and a zero terminal cost.
    pub fn zeros(steps: usize) -> Self {
        Self {
            per_step: vec![0.0; steps],
            terminal: 0.0,
        }
    }

    /// S_{0}: the total cost of the rollout ([`total_cost`]).
    pub fn total(&self) -> f64 {
        total_cost(&self.per_step, self.terminal)
    }

    /// Checks that every value is finite; a NaN or infinite cost would silently poison the weights.
    pub fn validate(&self, rollout: usize) -> Result<(), CostError> {
        check_finite(rollout, &self.per_step, self.terminal)
    }
}

/// The K cost trajectories of one update, indexed by rollout, so the order in which they arrive
/// (from workers that finish in any order) cannot change the result.
#[derive(Debug, Clone)]
pub struct CostBatch {
    steps: usize,
    /// Row-major K × N immediate costs.
    per_step: Vec<f64>,
    terminal: Vec<f64>,
    filled: Vec<bool>,
}

impl CostBatch {
    /// An empty batch (no rollout filled yet) of K = `rollouts` trajectories of N = `steps` steps;
    /// [`crate::Optimizer::cost_batch`] gives one of the optimizer's shape.
    pub fn new(rollouts: usize, steps: usize) -> Self {
        Self {
            steps,
            per_step: vec![0.0; rollouts * steps],
            terminal: vec![0.0; rollouts],
            filled: vec![false; rollouts],
        }
    }

    /// K.
    pub fn rollouts(&self) -> usize {
        self.terminal.len()
    }

    /// N.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Stores rollout `k`'s costs. Rejects non-finite values, a wrong length, an index out of range
    /// and a rollout told twice.
    pub fn insert(&mut self, k: usize, per_step: &[f64], terminal: f64) -> Result<(), CostError> {
        let rollouts = self.rollouts();
        if k >= rollouts {
            return Err(CostError::RolloutOutOfRange {
                rollout: k,
                rollouts,
            });
        }
        if per_step.len() != self.steps {
            return Err(CostError::WrongLength {
                rollout: k,
                expected: self.steps,
                got: per_step.len(),
            });
        }
        if self.filled[k] {
            return Err(CostError::Duplicate { rollout: k });
        }
        // One pass over the source (often cold: another process wrote it) copies and checks;
        // only a batch with a non-finite value is searched for which. Twice as fast as a check
        // and a copy (0.28 against 0.51 µs for 1001 steps), in the updater and the recorder.
        let mut finite = terminal.is_finite();
        for (to, from) in self.per_step[k * self.steps..(k + 1) * self.steps]
            .iter_mut()
            .zip(per_step)
        {
            *to = *from;
            finite &= from.is_finite();
        }
        if !finite {
            // The slot is not marked filled, so what was copied is never read.
            check_finite(k, per_step, terminal)?;
        }
        self.terminal[k] = terminal;
        self.filled[k] = true;
        Ok(())
    }

    /// [`CostBatch::insert`] of a [`CostTrajectory`].
    pub fn insert_trajectory(&mut self, k: usize, cost: &CostTrajectory) -> Result<(), CostError> {
        self.insert(k, &cost.per_step, cost.terminal)
    }

    /// Mutable access for callers that compute costs in place (the in-process runner); the
    /// rollout is marked as filled and must then pass [`CostBatch::validate_filled`].
    pub fn slot_mut(&mut self, k: usize) -> (&mut [f64], &mut f64) {
        self.filled[k] = true;
        (
            &mut self.per_step[k * self.steps..(k + 1) * self.steps],
            &mut self.terminal[k],
        )
    }

    /// Whether every rollout has been filled.
    pub fn is_complete(&self) -> bool {
        self.filled.iter().all(|f| *f)
    }

    /// How many rollouts have been filled.
    pub fn filled(&self) -> usize {
        self.filled.iter().filter(|f| **f).count()
    }

    /// The rollouts not filled yet, ascending.
    pub fn missing(&self) -> impl Iterator<Item = usize> + '_ {
        self.filled
            .iter()
            .enumerate()
            .filter(|(_, f)| !**f)
            .map(|(k, _)| k)
    }

    /// Rollout `k`'s N immediate costs.
    pub fn per_step(&self, k: usize) -> &[f64] {
        &self.per_step[k * self.steps..(k + 1) * self.steps]
    }

    /// Rollout `k`'s terminal cost.
    pub fn terminal(&self, k: usize) -> f64 {
        self.terminal[k]
    }

    /// Rollout `k`'s total cost S_0 (terminal plus every step, [`total_cost`]).
    pub fn total(&self, k: usize) -> f64 {
        total_cost(self.per_step(k), self.terminal[k])
    }

    /// Rollout `k`'s costs as an owned [`CostTrajectory`].
    pub fn trajectory(&self, k: usize) -> CostTrajectory {
        CostTrajectory {
            per_step: self.per_step(k).to_vec(),
            terminal: self.terminal[k],
        }
    }

    /// Writes every rollout's total cost S_0 into `out` (K values).
    pub fn totals_into(&self, out: &mut [f64]) {
        for (k, o) in out.iter_mut().enumerate() {
            *o = total_cost(self.per_step(k), self.terminal[k]);
        }
    }

    /// The first non-finite cost of rollout `k` (terminal first) as an error naming it: a
    /// runner that reruns such a rollout checks each one as it comes in, before the update.
    pub fn check_rollout(&self, k: usize) -> Result<(), CostError> {
        check_finite(k, self.per_step(k), self.terminal[k])
    }

    /// Re-checks every value; used after in-place writes through [`CostBatch::slot_mut`].
    pub fn validate_filled(&self) -> Result<(), CostError> {
        if let Some(k) = self.missing().next() {
            return Err(CostError::Missing { rollout: k });
        }
        // NaN and ±∞ survive summation, so a finite sum proves every value finite; only
        // otherwise (or on overflow of finite values) look for the culprit.
        if (sum(&self.per_step) + sum(&self.terminal)).is_finite() {
            return Ok(());
        }
        for k in 0..self.rollouts() {
            check_finite(k, self.per_step(k), self.terminal[k])?;
        }
        Ok(())
    }

    /// Marks every rollout unfilled, to fill the batch again (the values stay until overwritten).
    pub fn clear(&mut self) {
        self.filled.iter_mut().for_each(|f| *f = false);
    }
}

/// The first non-finite cost of rollout `rollout`, terminal cost first, as an error naming it.
/// [`CostBatch::insert`] checks it after refusing a rollout told twice; a reader that must tell
/// a rejected execution from a twin (the recorder) asks it of the second as well.
pub fn check_finite(rollout: usize, per_step: &[f64], terminal: f64) -> Result<(), CostError> {
    if !terminal.is_finite() {
        return Err(CostError::NonFinite {
            rollout,
            step: None,
            value: terminal,
        });
    }
    match per_step.iter().position(|c| !c.is_finite()) {
        Some(step) => Err(CostError::NonFinite {
            rollout,
            step: Some(step),
            value: per_step[step],
        }),
        None => Ok(()),
    }
}

/// S_0 of a rollout: `terminal` plus the step costs summed in the update's order. Every total
/// (the weights', the eval cost, what a recording and its CSV export show) is this one, to the
/// bit; a plain left-to-right sum differs in the last digits.
pub fn total_cost(per_step: &[f64], terminal: f64) -> f64 {
    terminal + sum(per_step)
}

/// Σ v with four accumulators, so the additions pipeline instead of forming one long chain
/// (compiled for AVX2 too and chosen at run time; the summation order is fixed, so every
/// variant gives the same bits).
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
pub(crate) fn sum(v: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let chunks = v.chunks_exact(4);
    let tail: f64 = chunks.remainder().iter().sum();
    for c in chunks {
        for l in 0..4 {
            acc[l] += c[l];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_nan_and_inf_with_location() {
        let mut b = CostBatch::new(2, 3);
        let e = b.insert(1, &[0.0, f64::NAN, 1.0], 0.0).unwrap_err();
        assert_eq!(
            e.to_string(),
            "cost of rollout 1 at step 1 is NaN; costs must be finite"
        );
        let e = b.insert(0, &[0.0, 0.0, 1.0], f64::INFINITY).unwrap_err();
        assert!(e.to_string().contains("terminal"), "{e}");
        assert!(!b.is_complete());
        assert_eq!(b.filled(), 0);
        // A rejected rollout's slot (into which its values were copied) takes the next one.
        b.insert(1, &[1.0, 2.0, 3.0], 0.5).unwrap();
        assert_eq!((b.per_step(1), b.terminal(1)), (&[1.0, 2.0, 3.0][..], 0.5));
        assert_eq!(b.filled(), 1);
    }

    #[test]
    fn one_rollout_is_checked_in_place_naming_its_first_non_finite_cost() {
        let mut b = CostBatch::new(2, 3);
        let (per_step, terminal) = b.slot_mut(1);
        per_step.copy_from_slice(&[0.0, f64::INFINITY, f64::NAN]);
        *terminal = 1.0;
        assert_eq!(
            b.check_rollout(1),
            Err(CostError::NonFinite {
                rollout: 1,
                step: Some(1),
                value: f64::INFINITY
            })
        );
        b.slot_mut(1).0.fill(2.0);
        assert_eq!(b.check_rollout(1), Ok(()));
        *b.slot_mut(0).1 = f64::NEG_INFINITY;
        let e = b.check_rollout(0).unwrap_err();
        assert!(e.to_string().contains("(terminal) is -inf"), "{e}");
    }

    #[test]
    fn rejects_duplicates_and_wrong_lengths() {
        let mut b = CostBatch::new(2, 2);
        b.insert(0, &[1.0, 2.0], 3.0).unwrap();
        assert!(matches!(
            b.insert(0, &[1.0, 2.0], 3.0),
            Err(CostError::Duplicate { rollout: 0 })
        ));
        assert!(matches!(
            b.insert(1, &[1.0], 3.0),
            Err(CostError::WrongLength { .. })
        ));
        assert_eq!(b.missing().collect::<Vec<_>>(), vec![1]);
        assert_eq!(b.total(0), 6.0);
    }

    /// S_0 has one value, whoever computes it: the update's (the batch's totals, the eval cost
    /// recorded), a trajectory's and the CSV export's. Costs whose sum depends on the order of
    /// the additions tell a second summation apart.
    #[test]
    fn a_trajectorys_total_is_the_batchs() {
        let t = CostTrajectory {
            per_step: vec![1.0, 1e16, -1e16, 1.0, 0.5],
            terminal: 0.25,
        };
        let mut b = CostBatch::new(1, 5);
        b.insert_trajectory(0, &t).unwrap();
        let mut totals = [0.0];
        b.totals_into(&mut totals);
        assert_eq!(
            t.total().to_bits(),
            b.total(0).to_bits(),
            "{} {}",
            t.total(),
            b.total(0)
        );
        assert_eq!(totals[0].to_bits(), b.total(0).to_bits());
        assert_eq!(
            total_cost(&t.per_step, t.terminal).to_bits(),
            b.total(0).to_bits()
        );
    }
}
