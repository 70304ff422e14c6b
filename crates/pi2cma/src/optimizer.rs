//! Ask/tell: the state machine every executor drives (the in-process runner, the multiprocess
//! pipeline, a user's own loop). Call [`Optimizer::ask`] for the batch of update u, run its
//! rollouts anywhere and in any order, then [`Optimizer::tell`] the costs to get update u + 1.

use crate::cost::CostBatch;
use crate::distribution::{Distribution, NoiseKey};
use crate::error::{CostError, ParameterError};
use crate::update::{Hyperparameters, UpdateRule, UpdateWeights, Weighting};

/// The K parameter vectors of one update, row-major K × P. Row 0 is the noise-free evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterBatch {
    /// The run's seed the noise was drawn with.
    pub seed: u64,
    /// Index u of the update this batch is for.
    pub update: u64,
    /// K: parameter vectors in the batch.
    pub rollouts: usize,
    /// P: parameters per vector.
    pub dim: usize,
    /// K × P values, rollout-major: [`ParameterBatch::row`] k is θ_k.
    pub values: Vec<f64>,
}

impl ParameterBatch {
    /// Draws the batch of `update` from `distribution`. A pure function of its arguments: any
    /// process computing it gets the same bits.
    pub fn sample(distribution: &Distribution, seed: u64, update: u64, rollouts: usize) -> Self {
        let dim = distribution.dim();
        let mut values = vec![0.0; rollouts * dim];
        let mut sampler = distribution.sampler();
        for (k, row) in values.chunks_exact_mut(dim.max(1)).enumerate() {
            sampler.sample_into(
                NoiseKey {
                    seed,
                    update,
                    rollout: k as u64,
                },
                row,
            );
        }
        Self {
            seed,
            update,
            rollouts,
            dim,
            values,
        }
    }

    /// θ_k, the parameters of rollout `k` (P values).
    pub fn row(&self, k: usize) -> &[f64] {
        &self.values[k * self.dim..(k + 1) * self.dim]
    }
}

/// What one update did, for learning curves and recordings.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateSummary {
    /// Index u of the update whose rollouts were told (0-based).
    pub update: u64,
    /// Total cost of the evaluation rollout 0 (θ_0 = θ).
    pub eval_cost: f64,
    /// Mean of the total costs of rollouts 1..K.
    pub exploration_cost_mean: f64,
    /// Sample standard deviation of the total costs of rollouts 1..K (0 for one such rollout).
    pub exploration_cost_std: f64,
    /// λ_u: largest eigenvalue of the Σ the batch was sampled from.
    pub lambda: f64,
    /// Largest eigenvalue of the new Σ.
    pub lambda_next: f64,
    /// Per-rollout probability used for the mean update (time-averaged in per-time-step mode).
    pub weights: Vec<f64>,
    /// The weighting the update used.
    pub weighting: Weighting,
}

impl UpdateSummary {
    /// The summary of update `update` from what its rule returned: `lambda` is λ of the
    /// distribution its batch was sampled from, `lambda_next` that of the new one (with
    /// constant exploration, `lambda` again). For [`Optimizer::tell`], and for a process that
    /// runs the [`UpdateRule`] itself and knows the λs (the pipeline's recorder: the updater
    /// publishes them).
    pub fn new(
        update: u64,
        weights: UpdateWeights,
        lambda: f64,
        lambda_next: f64,
        weighting: Weighting,
    ) -> Self {
        let totals = &weights.totals;
        let explore = totals.get(1..).unwrap_or(&[]);
        let mean = explore.iter().sum::<f64>() / explore.len().max(1) as f64;
        let sq: f64 = explore.iter().map(|c| (c - mean) * (c - mean)).sum();
        let std = if explore.len() > 1 {
            (sq / (explore.len() - 1) as f64).sqrt()
        } else {
            0.0
        };
        Self {
            update,
            eval_cost: totals.first().copied().unwrap_or(f64::NAN),
            exploration_cost_mean: mean,
            exploration_cost_std: std,
            lambda,
            lambda_next,
            weights: weights.per_rollout,
            weighting,
        }
    }
}

/// The sans-IO optimizer: distribution, update counter and seed, nothing else.
#[derive(Debug, Clone)]
pub struct Optimizer {
    rule: UpdateRule,
    distribution: Distribution,
    seed: u64,
    update: u64,
    lambda: f64,
    batch: Option<ParameterBatch>,
}

impl Optimizer {
    /// An optimizer at update 0. `steps` is N, the length of every cost trajectory (1 for a task
    /// with only a total cost, told as its terminal cost); `seed` fixes every rollout's noise;
    /// `basis_activations` (row-major N × P) only for [`crate::TemporalAveraging::BasisActivation`].
    /// Refuses hyperparameters that cannot run, naming the field and value.
    pub fn new(
        hp: Hyperparameters,
        initial: Distribution,
        steps: usize,
        seed: u64,
        basis_activations: Option<&[f64]>,
    ) -> Result<Self, ParameterError> {
        let rule = UpdateRule::new(hp, initial.dim(), steps, basis_activations)?;
        Ok(Self::resume(rule, initial, seed, 0))
    }

    /// Continues a run from a known state (e.g. a recording, or another process's copy).
    pub fn resume(rule: UpdateRule, distribution: Distribution, seed: u64, update: u64) -> Self {
        let lambda = rule.lambda_of(&distribution);
        Self {
            rule,
            distribution,
            seed,
            update,
            lambda,
            batch: None,
        }
    }

    /// The current search distribution N(θ, Σ): after [`Optimizer::tell`], the updated one.
    pub fn distribution(&self) -> &Distribution {
        &self.distribution
    }

    /// The update rule, for a caller that resumes one update after another from distributions
    /// it is given (the pipeline's recorder): building a rule allocates and fills all its
    /// buffers, reusing one does not.
    pub fn into_rule(self) -> UpdateRule {
        self.rule
    }

    /// The hyperparameters the optimizer runs with.
    pub fn hyperparameters(&self) -> &Hyperparameters {
        self.rule.hyperparameters()
    }

    /// Index u of the current update (0-based): the number of updates told so far, plus the
    /// update the optimizer was resumed at.
    pub fn update_index(&self) -> u64 {
        self.update
    }

    /// The run's seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// N: the length of every cost trajectory.
    pub fn steps(&self) -> usize {
        self.rule.steps()
    }

    /// λ of the current distribution.
    pub fn lambda(&self) -> f64 {
        self.lambda
    }

    /// An empty cost batch of the right shape for the current update.
    pub fn cost_batch(&self) -> CostBatch {
        CostBatch::new(self.rule.hyperparameters().rollouts, self.rule.steps())
    }

    /// The batch for the current update; asking twice returns the same batch.
    pub fn ask(&mut self) -> &ParameterBatch {
        let stale = self.batch.as_ref().is_none_or(|b| b.update != self.update);
        if stale {
            self.batch = Some(ParameterBatch::sample(
                &self.distribution,
                self.seed,
                self.update,
                self.rule.hyperparameters().rollouts,
            ));
        }
        self.batch.as_ref().expect("batch was just sampled")
    }

    /// Tells the costs of the current update's batch; advances to the next update.
    pub fn tell(&mut self, costs: &CostBatch) -> Result<UpdateSummary, CostError> {
        self.ask();
        let batch = self.batch.as_ref().expect("ask() fills the batch");
        let (new, weights) = self.rule.update(&self.distribution, &batch.values, costs)?;
        let lambda_next = self.rule.lambda_next(self.lambda, &new);
        let summary = UpdateSummary::new(
            self.update,
            weights,
            self.lambda,
            lambda_next,
            self.rule.hyperparameters().weighting,
        );
        self.distribution = new;
        self.lambda = lambda_next;
        self.update += 1;
        Ok(summary)
    }
}
