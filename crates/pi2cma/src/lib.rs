//! PI²-CMA, PI² (constant and decaying exploration) and CEM as a sans-IO library.
//!
//! This crate is the algorithm only: a Gaussian search [`Distribution`], cost-to-probability
//! mappings, the update rules with `boundcovar`, and an ask/tell [`Optimizer`]. It knows nothing
//! of processes, shared memory, files, clocks or global random state: the caller asks for a
//! [`ParameterBatch`], executes the rollouts wherever it likes, and tells the [`CostBatch`].
//! Each rollout's noise is a pure function of (seed, update, rollout), so the result never
//! depends on who executed a rollout or in which order the costs arrived.
//!
//! It is not a policy representation (see the `dmp` crate), not a task (see `tasks`), and not an
//! executor (the CLI's in-process runner and the iceoryx2 pipeline drive it).

pub mod boundcovar;
mod cost;
mod distribution;
mod error;
mod optimizer;
mod symeig;
mod update;
mod weighting;

pub use boundcovar::{boundcovar, EigenvalueBounds};
pub use cost::{check_finite, CostBatch, CostTrajectory};
pub use distribution::{Distribution, NoiseKey, Sampler};
pub use error::{CostError, ParameterError};
pub use optimizer::{Optimizer, ParameterBatch, UpdateSummary};
pub use update::{
    CovarianceStructure, Exploration, Hyperparameters, LowRankStats, TemporalAveraging, UpdateRule,
    UpdateWeights, Weighting,
};
pub use weighting::CostMapping;

#[cfg(test)]
mod tests;
