//! One error enum per kind of operation, each naming the offending value.

use thiserror::Error;

/// A cost trajectory that cannot enter an update, or an update that cannot be computed from
/// what it was told.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CostError {
    /// A cost is NaN or ±∞.
    #[error("cost of rollout {rollout} {} is {value}; costs must be finite", match step { Some(s) => format!("at step {s}"), None => "(terminal)".to_string() })]
    NonFinite {
        /// The rollout k.
        rollout: usize,
        /// The time step, or `None` for the terminal cost.
        step: Option<usize>,
        /// The offending value.
        value: f64,
    },
    #[error(
        "the update gives a non-finite {what} from finite costs: the costs' range or the \
         covariance ({largest_variance:e} at most) overflows its arithmetic; the distribution \
         stays as it was"
    )]
    /// Finite costs whose update overflows f64 (costs or a covariance near f64::MAX); the
    /// optimizer stays at the same update.
    NonFiniteUpdate {
        /// `"mean"` or `"covariance"`.
        what: &'static str,
        /// The largest diagonal entry of the Σ the batch was drawn from.
        largest_variance: f64,
    },
    #[error("rollout index {rollout} out of range: the update has {rollouts} rollouts")]
    /// A rollout index ≥ K.
    RolloutOutOfRange {
        /// The index given.
        rollout: usize,
        /// K.
        rollouts: usize,
    },
    #[error("cost trajectory of rollout {rollout} has {got} steps, expected {expected}")]
    /// A cost trajectory whose number of step costs is not N.
    WrongLength {
        /// The rollout k.
        rollout: usize,
        /// N.
        expected: usize,
        /// The number of step costs given.
        got: usize,
    },
    #[error("rollout {rollout} was told twice in the same update")]
    /// A rollout's costs given twice for one update.
    Duplicate {
        /// The rollout k.
        rollout: usize,
    },
    #[error("rollout {rollout} has not been told yet")]
    /// A batch told before every rollout was filled.
    Missing {
        /// The first rollout not filled.
        rollout: usize,
    },
    #[error("cost batch is for update {got}, the optimizer is at update {expected}")]
    /// Costs of another update than the current one.
    WrongUpdate {
        /// The optimizer's current update.
        expected: u64,
        /// The update the costs are for.
        got: u64,
    },
    #[error("cost batch has {got} rollouts of {got_steps} steps, expected {expected} of {expected_steps}")]
    /// A cost batch of another K or N than the update rule's.
    WrongShape {
        /// The rule's K.
        expected: usize,
        /// The rule's N.
        expected_steps: usize,
        /// The batch's K.
        got: usize,
        /// The batch's N.
        got_steps: usize,
    },
    /// The distribution or samples an update is told do not have the rule's P (K × P samples):
    /// the caller resumed from, or sampled with, a distribution of another task.
    #[error(
        "the update rule is for P = {dim}, but the distribution has {mean} mean entries and a \
         {rows}×{cols} covariance"
    )]
    WrongDistribution {
        /// The rule's P.
        dim: usize,
        /// Entries of the distribution's mean.
        mean: usize,
        /// Rows of its covariance.
        rows: usize,
        /// Columns of its covariance.
        cols: usize,
    },
    #[error("sample batch has {got} values, expected K × P = {expected}")]
    /// A sample batch of another size than K × P.
    WrongSamples {
        /// K × P.
        expected: usize,
        /// The number of values given.
        got: usize,
    },
}

/// Hyperparameters or an initial distribution that cannot run.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ParameterError {
    /// A hyperparameter or setting outside its range.
    #[error("{field} = {value}: {reason}")]
    OutOfRange {
        /// Its name, as the configuration spells it.
        field: &'static str,
        /// The value given.
        value: String,
        /// What it must be.
        reason: &'static str,
    },
    #[error("covariance is {rows}×{cols} but the mean has {dim} entries")]
    /// A covariance whose size is not the mean's.
    ShapeMismatch {
        /// Entries of the mean.
        dim: usize,
        /// Rows of the covariance.
        rows: usize,
        /// Columns of the covariance.
        cols: usize,
    },
    #[error(
        "covariance is not symmetric positive semi-definite (smallest eigenvalue {min_eigenvalue})"
    )]
    /// A covariance that is not symmetric or has a negative eigenvalue (beyond rounding).
    NotPositiveSemiDefinite {
        /// Its smallest eigenvalue.
        min_eigenvalue: f64,
    },
    #[error("distribution contains a non-finite value")]
    /// A NaN or ±∞ in the mean or the covariance.
    NonFinite,
}
