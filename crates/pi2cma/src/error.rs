//! One error enum per kind of operation, each naming the offending value.

use thiserror::Error;

/// A cost trajectory that cannot enter an update, or an update that cannot be computed from
/// what it was told.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CostError {
    #[error("cost of rollout {rollout} {} is {value}; costs must be finite", match step { Some(s) => format!("at step {s}"), None => "(terminal)".to_string() })]
    NonFinite {
        rollout: usize,
        step: Option<usize>,
        value: f64,
    },
    #[error(
        "the update gives a non-finite {what} from finite costs: the costs' range or the \
         covariance ({largest_variance:e} at most) overflows its arithmetic; the distribution \
         stays as it was"
    )]
    NonFiniteUpdate {
        what: &'static str,
        largest_variance: f64,
    },
    #[error("rollout index {rollout} out of range: the update has {rollouts} rollouts")]
    RolloutOutOfRange { rollout: usize, rollouts: usize },
    #[error("cost trajectory of rollout {rollout} has {got} steps, expected {expected}")]
    WrongLength {
        rollout: usize,
        expected: usize,
        got: usize,
    },
    #[error("rollout {rollout} was told twice in the same update")]
    Duplicate { rollout: usize },
    #[error("rollout {rollout} has not been told yet")]
    Missing { rollout: usize },
    #[error("cost batch is for update {got}, the optimizer is at update {expected}")]
    WrongUpdate { expected: u64, got: u64 },
    #[error("cost batch has {got} rollouts of {got_steps} steps, expected {expected} of {expected_steps}")]
    WrongShape {
        expected: usize,
        expected_steps: usize,
        got: usize,
        got_steps: usize,
    },
    /// The distribution or samples an update is told do not have the rule's P (K × P samples):
    /// the caller resumed from, or sampled with, a distribution of another task.
    #[error(
        "the update rule is for P = {dim}, but the distribution has {mean} mean entries and a \
         {rows}×{cols} covariance"
    )]
    WrongDistribution {
        dim: usize,
        mean: usize,
        rows: usize,
        cols: usize,
    },
    #[error("sample batch has {got} values, expected K × P = {expected}")]
    WrongSamples { expected: usize, got: usize },
}

/// Hyperparameters or an initial distribution that cannot run.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ParameterError {
    #[error("{field} = {value}: {reason}")]
    OutOfRange {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    #[error("covariance is {rows}×{cols} but the mean has {dim} entries")]
    ShapeMismatch {
        dim: usize,
        rows: usize,
        cols: usize,
    },
    #[error(
        "covariance is not symmetric positive semi-definite (smallest eigenvalue {min_eigenvalue})"
    )]
    NotPositiveSemiDefinite { min_eigenvalue: f64 },
    #[error("distribution contains a non-finite value")]
    NonFinite,
}
