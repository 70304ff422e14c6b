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
//!
//! # Driving it from your own loop
//!
//! 1. Choose the method with [`Hyperparameters`] (table below) and the initial
//!    [`Distribution`] N(θ_init, Σ_init), e.g. [`Distribution::isotropic`] for λ_init·I; the
//!    vectors and matrices are [`nalgebra`]'s, re-exported as [`pi2cma::nalgebra`](nalgebra).
//! 2. [`Optimizer::new`] with N, the number of time steps of a cost trajectory (1 for a task
//!    that only has a total cost), and a seed.
//! 3. Per update: [`Optimizer::ask`] gives the [`ParameterBatch`] of K parameter vectors (row 0
//!    is the mean θ itself, the noise-free evaluation); run each rollout and put its N immediate
//!    costs and terminal cost into the [`CostBatch`] of [`Optimizer::cost_batch`], in any order;
//!    [`Optimizer::tell`] it. The new mean and Σ are [`Optimizer::distribution`], λ (the
//!    largest eigenvalue of Σ) is [`Optimizer::lambda`], and the returned [`UpdateSummary`] has
//!    the evaluation cost and the probabilities of the rollouts.
//!
//! A rejected [`Optimizer::tell`] (a NaN cost, a rollout missing, an update that overflows)
//! leaves the optimizer at the same update with the same batch: fix the costs and tell again.
//!
//! | method | [`CostMapping`] | [`Exploration`] |
//! |---|---|---|
//! | PI²-CMA | `Exponential { eliteness }` | `Adaptive { bounds }` ([`EigenvalueBounds`]) |
//! | PI² | `Exponential { eliteness }` | `Constant` (Σ stays Σ_init) |
//! | PI² with decay | `Exponential { eliteness }` | `Decay { factor }` |
//! | CEM | `Elites { count }` | `Adaptive { bounds }`, usually unbounded |
//!
//! [`Weighting::PerTimeStep`] is Algorithm 1 of the paper (probabilities per time step from the
//! cost-to-go); [`Weighting::Episodic`] uses only the total cost of each rollout.
//!
//! A 3-parameter task whose cost is the squared distance to a target at every step and, with a
//! larger weight, at the end. Each method must lower the cost of the mean tenfold in 30 updates,
//! and PI²-CMA the most:
//!
//! ```
//! use pi2cma::nalgebra::DVector;
//! use pi2cma::{
//!     CostMapping, CostTrajectory, CovarianceStructure, Distribution, EigenvalueBounds,
//!     Exploration, Hyperparameters, Optimizer, TemporalAveraging, Weighting,
//! };
//!
//! const STEPS: usize = 20;
//! const TARGET: [f64; 3] = [1.0, -2.0, 0.5];
//!
//! /// The user's simulator: one rollout of θ.
//! fn rollout(theta: &[f64]) -> CostTrajectory {
//!     let distance: f64 = theta.iter().zip(TARGET).map(|(t, g)| (t - g).powi(2)).sum();
//!     CostTrajectory {
//!         per_step: vec![distance / STEPS as f64; STEPS],
//!         terminal: 10.0 * distance,
//!     }
//! }
//!
//! let methods = [
//!     ("PI²-CMA", CostMapping::Exponential { eliteness: 10.0 },
//!      Exploration::Adaptive { bounds: EigenvalueBounds::new(1e-4, 10.0)? }),
//!     ("PI²", CostMapping::Exponential { eliteness: 10.0 }, Exploration::Constant),
//!     ("PI² decay", CostMapping::Exponential { eliteness: 10.0 },
//!      Exploration::Decay { factor: 0.9 }),
//!     ("CEM", CostMapping::Elites { count: 5 },
//!      Exploration::Adaptive { bounds: EigenvalueBounds::unbounded() }),
//! ];
//! let mut finals = Vec::new();
//! for (name, mapping, exploration) in methods {
//!     let hp = Hyperparameters {
//!         rollouts: 15,
//!         mapping,
//!         exploration,
//!         weighting: Weighting::PerTimeStep { temporal: TemporalAveraging::RemainingSteps },
//!         evaluation_in_update: false,
//!         covariance: CovarianceStructure::Full,
//!     };
//!     let initial = Distribution::isotropic(DVector::zeros(3), 1.0)?;
//!     let mut optimizer = Optimizer::new(hp, initial, STEPS, 42, None)?;
//!     let first = rollout(optimizer.distribution().mean.as_slice()).total();
//!     for _ in 0..30 {
//!         // The batch borrows the optimizer; a copy lets the loop ask it for the cost batch.
//!         let batch = optimizer.ask().clone();
//!         let mut costs = optimizer.cost_batch();
//!         for k in 0..batch.rollouts {
//!             costs.insert_trajectory(k, &rollout(batch.row(k)))?;
//!         }
//!         let summary = optimizer.tell(&costs)?;
//!         assert!(summary.lambda_next == optimizer.lambda());
//!     }
//!     let last = rollout(optimizer.distribution().mean.as_slice()).total();
//!     println!("{name}: cost of the mean {first:.3} → {last:.5}, λ {:.2e}", optimizer.lambda());
//!     assert!(last < first / 10.0, "{name}: {first} → {last}");
//!     finals.push((name, last));
//! }
//! // Adapting Σ lets PI²-CMA go on where constant exploration stalls at its noise floor, decay
//! // runs out of exploration and CEM's Σ collapses.
//! let best = finals.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
//! assert_eq!(best.0, "PI²-CMA", "{finals:?}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs)]

pub use nalgebra;

pub mod boundcovar;
mod cost;
mod distribution;
mod error;
mod optimizer;
mod symeig;
mod update;
mod weighting;

pub use boundcovar::{boundcovar, EigenvalueBounds};
pub use cost::{check_finite, total_cost, CostBatch, CostTrajectory};
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
