//! The update rules: one probability-weighted-averaging kernel serving CEM, PI² with constant or
//! decaying exploration, and PI²-CMA, in per-time-step (Algorithm 1) or episodic mode.
//!
//! The kernel allocates nothing per update after construction; everything that does not depend
//! on the samples (temporal weights, basis-activation weights) is computed once.

use nalgebra::DMatrix;

use crate::boundcovar::{boundcovar, boundcovar2, boundcovar2_interpolated, EigenvalueBounds};
use crate::cost::CostBatch;
use crate::distribution::Distribution;
use crate::error::{CostError, ParameterError};
use crate::symeig::{symmetric_eigen, VECTOR_LANES};
use crate::weighting::{exp_nonpositive, CostMapping};

/// How Σ changes from one update to the next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exploration {
    /// PI²: Σ stays λ·I.
    Constant,
    /// PI² with decay: Σ ← D·Σ per update, so λ_u = λ_init·D^u.
    Decay {
        /// D in (0, 1].
        factor: f64,
    },
    /// PI²-CMA / CEM: Σ ← probability-weighted covariance of the samples around the OLD mean,
    /// with its eigenvalues bounded to [λ_min, λ_max] (`boundcovar`).
    Adaptive {
        /// [λ_min, λ_max] for Σ's eigenvalues.
        bounds: EigenvalueBounds,
    },
}

/// Which costs the probabilities are computed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weighting {
    /// Only the total cost S_0 of each rollout (PI^BB, "black-box").
    Episodic,
    /// Algorithm 1: probabilities per time step from the cost-to-go, then temporal averaging.
    PerTimeStep {
        /// How the per-step updates are averaged over time.
        temporal: TemporalAveraging,
    },
}

/// Temporal averaging of the per-time-step updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TemporalAveraging {
    /// Algorithm 1 as printed: weight N − i for θ and Σ.
    RemainingSteps,
    /// The original PI² (Theodorou et al. 2010): parameter j at step i weighted by
    /// (N − i)·ψ_j(t_i), with ψ_j the policy's basis activation. Σ keeps the (N − i) weights, as
    /// a per-element weighting would not keep it positive semi-definite.
    BasisActivation,
}

/// The shape of Σ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CovarianceStructure {
    /// One P×P covariance over all parameters: correlations across DMP dimensions are learned.
    #[default]
    Full,
    /// The paper's shape (Σ_init = λ_init·I_B per DMP dimension, Algorithm 1 written for one
    /// dimension): Σ is block-diagonal with one `block`×`block` covariance per DMP dimension
    /// (`block` = B, basis functions per dimension; P = dimensions × B). Each block gets line 23
    /// from its own parameters and boundcovar on its own; entries across blocks stay 0.
    PerDimension {
        /// B: parameters (basis functions) per DMP dimension.
        block: usize,
    },
}

/// Validated-on-use hyperparameters of one update rule.
#[derive(Debug, Clone, PartialEq)]
pub struct Hyperparameters {
    /// K: rollouts per update, including the noise-free evaluation rollout 0.
    pub rollouts: usize,
    /// How costs become probabilities: PI²'s exponential or CEM's elites.
    pub mapping: CostMapping,
    /// How Σ changes: constant, decaying or adapted (PI²-CMA, CEM).
    pub exploration: Exploration,
    /// Per-time-step (Algorithm 1) or episodic probabilities.
    pub weighting: Weighting,
    /// Whether rollout 0 (θ_0 = θ) enters the update (the authors' 2012 code) or only serves as
    /// the evaluation (their later code).
    pub evaluation_in_update: bool,
    /// One P×P Σ or one block per DMP dimension.
    pub covariance: CovarianceStructure,
}

impl Hyperparameters {
    /// The first rollout that enters the update: 0 if the evaluation rollout does, 1 if not.
    pub fn first_updating_rollout(&self) -> usize {
        usize::from(!self.evaluation_in_update)
    }

    /// Refuses values that cannot run (K < 2, an eliteness ≤ 0, more elites than rollouts, a
    /// decay outside (0, 1], inverted bounds), naming the field and value.
    pub fn check(&self) -> Result<(), ParameterError> {
        // Rollout 0 is θ itself (ε_0 = 0): entering the update or not, it cannot move the
        // distribution, so one exploration rollout is the least either way.
        if self.rollouts < 2 {
            return Err(ParameterError::OutOfRange {
                field: "rollouts",
                value: self.rollouts.to_string(),
                reason: "too few rollouts: at least one must enter the update besides the \
                         evaluation rollout (rollout 0 is θ itself and cannot move the \
                         distribution, even when it enters the update), so at least 2",
            });
        }
        self.mapping
            .check(self.rollouts - self.first_updating_rollout())?;
        if let Exploration::Decay { factor } = self.exploration {
            if !(factor > 0.0 && factor <= 1.0) {
                return Err(ParameterError::OutOfRange {
                    field: "decay",
                    value: factor.to_string(),
                    reason: "must be in (0, 1]",
                });
            }
        }
        if let Exploration::Adaptive { bounds } = self.exploration {
            EigenvalueBounds::new(bounds.min, bounds.max)?;
        }
        if self.covariance == (CovarianceStructure::PerDimension { block: 0 }) {
            return Err(ParameterError::OutOfRange {
                field: "covariance",
                value: "per-dimension with 0 basis functions per dimension".into(),
                reason: "a DMP dimension has at least one basis function",
            });
        }
        Ok(())
    }
}

/// Which algebra computes the per-step covariance: chosen once from P and the number of rollouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CovarianceKernel {
    /// P = 2: closed-form 2×2 eigen-decomposition.
    Closed2,
    /// P ≤ rollouts: dense P×P eigen-decomposition per step.
    Dense,
    /// P > rollouts: Σ_i = Eᵀ·diag(p_i)·E has rank ≤ K, so boundcovar works on a K×K problem
    /// and Σ_new = λ_min·I + Eᵀ·M·E (episodic), or λ_min·I + Q·M·Qᵀ with Eᵀ = Q·R
    /// (per-time-step, see `lowrank_per_step`).
    LowRank,
}

/// The update kernel with its precomputed weights and scratch buffers.
#[derive(Debug, Clone)]
pub struct UpdateRule {
    hp: Hyperparameters,
    dim: usize,
    steps: usize,
    /// w_i = (N − i)/Σ(N − i).
    temporal: Vec<f64>,
    /// Row-major N × P, each column normalised: (N − i)·ψ_j(t_i)/Σ_i(…). Only for BasisActivation.
    basis_temporal: Option<Vec<f64>>,
    kernel: CovarianceKernel,
    /// Threads for the per-time-step low-rank kernel (1: none are started).
    threads: usize,
    // Scratch, sized once.
    eps: Vec<f64>,
    cost_to_go: Vec<f64>,
    totals: Vec<f64>,
    /// Rollout-major K × N cost-to-go and probabilities, for the per-time-step mode.
    step_costs: Vec<f64>,
    step_probs: Vec<f64>,
    /// 3·N scratch values for per-step reductions.
    step_scratch: Vec<f64>,
    sqrt_probs: Vec<f64>,
    /// Rows: the scaled eigenvectors √(w·c_j)·D^½·v_j of one step (low-rank kernel).
    factor: DMatrix<f64>,
    probs: Vec<f64>,
    order: Vec<usize>,
    mean_weights: Vec<f64>,
    basis_weights: Vec<f64>,
    cov_acc: DMatrix<f64>,
    gram: DMatrix<f64>,
    lowrank_acc: DMatrix<f64>,
    small: DMatrix<f64>,
    /// Per-time-step low-rank kernel: Q (P × K') of X = Q·R over the K' non-zero ε_k, and the
    /// K'×K' temporal average of clip(T_i) − λ_min·I, T_i = R·D_i·Rᵀ; Σ = λ_min·I + Q·core·Qᵀ.
    per_step_basis: Option<(DMatrix<f64>, DMatrix<f64>)>,
    /// How the per-step low-rank problems were solved in the last update.
    lowrank_stats: LowRankStats,
    /// Which per-step solver the low-rank kernel may use (tests force one).
    pub(crate) lowrank_mode: LowRankMode,
    /// Per-dimension covariance with adaptive exploration: one full-covariance rule of B
    /// parameters per DMP dimension, which computes that dimension's block from its own ε and
    /// the shared costs. Empty otherwise.
    blocks: Vec<UpdateRule>,
}

/// What one call of [`UpdateRule::update`] returns besides the new distribution.
#[derive(Debug, Clone, PartialEq)]
pub struct UpdateWeights {
    /// Per rollout (K entries): the total cost S_0.
    pub totals: Vec<f64>,
    /// Per rollout (K entries): the probability with which it entered the mean update, averaged
    /// over time steps in per-time-step mode; 0 for an evaluation rollout left out of the update.
    pub per_rollout: Vec<f64>,
}

impl UpdateRule {
    /// `basis_activations` (row-major N × P, non-negative) is required for
    /// [`TemporalAveraging::BasisActivation`] and ignored otherwise.
    pub fn new(
        hp: Hyperparameters,
        dim: usize,
        steps: usize,
        basis_activations: Option<&[f64]>,
    ) -> Result<Self, ParameterError> {
        hp.check()?;
        if dim == 0 {
            return Err(ParameterError::OutOfRange {
                field: "parameters",
                value: "0".into(),
                reason: "the policy must have at least one parameter",
            });
        }
        if steps == 0 {
            return Err(ParameterError::OutOfRange {
                field: "steps",
                value: "0".into(),
                reason: "cost trajectories must have at least one step",
            });
        }
        let total: f64 = (1..=steps).map(|v| v as f64).sum();
        let temporal = (0..steps).map(|i| (steps - i) as f64 / total).collect();
        let basis_temporal = match hp.weighting {
            Weighting::PerTimeStep {
                temporal: TemporalAveraging::BasisActivation,
            } => {
                let psi = basis_activations.ok_or(ParameterError::OutOfRange {
                    field: "temporal_averaging",
                    value: "basis-activation".into(),
                    reason:
                        "needs the policy's basis activations, which this policy does not provide",
                })?;
                if psi.len() != steps * dim || psi.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                    return Err(ParameterError::OutOfRange {
                        field: "basis_activations",
                        value: format!("{} values", psi.len()),
                        reason: "must be N × P finite non-negative values",
                    });
                }
                let mut w = vec![0.0; steps * dim];
                for j in 0..dim {
                    let norm: f64 = (0..steps)
                        .map(|i| (steps - i) as f64 * psi[i * dim + j])
                        .sum();
                    if !(norm > 0.0) {
                        return Err(ParameterError::OutOfRange {
                            field: "basis_activations",
                            value: format!("column {j}"),
                            reason: "a basis function is never active",
                        });
                    }
                    for i in 0..steps {
                        w[i * dim + j] = (steps - i) as f64 * psi[i * dim + j] / norm;
                    }
                }
                Some(w)
            }
            _ => None,
        };
        let k = hp.rollouts;
        let m = k - hp.first_updating_rollout();
        let per_step_len = match hp.weighting {
            Weighting::PerTimeStep { .. } => steps,
            Weighting::Episodic => 0,
        };
        let blocks = match (hp.covariance, hp.exploration) {
            (CovarianceStructure::PerDimension { block }, _) if !dim.is_multiple_of(block) => {
                return Err(ParameterError::OutOfRange {
                    field: "covariance",
                    value: format!(
                        "per-dimension with {block} basis functions per dimension, P = {dim}"
                    ),
                    reason: "P must be a multiple of the basis functions per dimension",
                });
            }
            (CovarianceStructure::PerDimension { block }, Exploration::Adaptive { .. }) => {
                let sub = Hyperparameters {
                    covariance: CovarianceStructure::Full,
                    ..hp.clone()
                };
                (0..dim / block)
                    .map(|d| {
                        let psi = basis_activations.map(|psi| {
                            psi.chunks_exact(dim)
                                .flat_map(|row| &row[d * block..(d + 1) * block])
                                .copied()
                                .collect::<Vec<f64>>()
                        });
                        UpdateRule::new(sub.clone(), block, steps, psi.as_deref())
                    })
                    .collect::<Result<Vec<_>, _>>()?
            }
            // Constant and decaying exploration keep Σ's shape: nothing to compute per block.
            _ => Vec::new(),
        };
        let kernel = if dim == 2 {
            CovarianceKernel::Closed2
        } else if dim <= m {
            CovarianceKernel::Dense
        } else {
            CovarianceKernel::LowRank
        };
        Ok(Self {
            hp,
            dim,
            steps,
            temporal,
            basis_temporal,
            kernel,
            threads: 1,
            eps: vec![0.0; m * dim],
            cost_to_go: vec![0.0; m],
            totals: vec![0.0; k],
            step_costs: vec![0.0; per_step_len * m],
            step_probs: vec![0.0; per_step_len * m],
            step_scratch: vec![0.0; 3 * per_step_len],
            sqrt_probs: vec![0.0; m],
            factor: DMatrix::zeros(m, m),
            probs: vec![0.0; m],
            order: vec![0; m],
            mean_weights: vec![0.0; m],
            basis_weights: vec![0.0; m * dim],
            cov_acc: DMatrix::zeros(dim, dim),
            gram: DMatrix::zeros(m, m),
            lowrank_acc: DMatrix::zeros(m, m),
            small: DMatrix::zeros(m, m),
            per_step_basis: None,
            lowrank_stats: LowRankStats::default(),
            lowrank_mode: LowRankMode::Auto,
            blocks,
        })
    }

    /// The hyperparameters the rule runs with.
    pub fn hyperparameters(&self) -> &Hyperparameters {
        &self.hp
    }

    /// Lets the per-time-step update of a large policy (P > K) compute its per-step
    /// eigen-decompositions on `threads` threads. The result is bit-identical for any count: the
    /// steps are summed in fixed blocks, in block order. The default, 1, starts no thread.
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self.blocks = std::mem::take(&mut self.blocks)
            .into_iter()
            .map(|b| b.with_threads(threads))
            .collect();
        self
    }

    /// λ of `d`: the largest eigenvalue of Σ. With a per-dimension covariance, the largest of
    /// the blocks' largest eigenvalues, each from its own B×B block (the entries across blocks
    /// are 0 by construction).
    pub fn lambda_of(&self, d: &Distribution) -> f64 {
        match self.hp.covariance {
            CovarianceStructure::PerDimension { block }
                if block > 0 && d.dim().is_multiple_of(block) =>
            {
                (0..d.dim() / block)
                    .map(|i| {
                        let c = d.covariance.view((i * block, i * block), (block, block));
                        crate::boundcovar::largest_eigenvalue(&c.clone_owned())
                    })
                    .fold(f64::NEG_INFINITY, f64::max)
            }
            _ => d.largest_eigenvalue(),
        }
    }

    /// λ of `new`, the distribution an update made from one of λ `lambda`: with constant
    /// exploration Σ does not change, and λ stays the one the run began with.
    pub fn lambda_next(&self, lambda: f64, new: &Distribution) -> f64 {
        match self.hp.exploration {
            Exploration::Constant => lambda,
            _ => self.lambda_of(new),
        }
    }

    /// P: the number of parameters.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// How the per-time-step low-rank kernel (P > K) solved its per-step problems in the last
    /// update: how many steps needed no eigenvalue clipped, and how many eigenvectors it
    /// computed. All zero for other kernels and modes.
    pub fn lowrank_stats(&self) -> LowRankStats {
        self.lowrank_stats
    }

    /// N: the length of every cost trajectory.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// One update: the new distribution from the old one, the K samples (row-major K × P, as
    /// drawn from `old`) and their costs.
    pub fn update(
        &mut self,
        old: &Distribution,
        samples: &[f64],
        costs: &CostBatch,
    ) -> Result<(Distribution, UpdateWeights), CostError> {
        let (k_all, p, n) = (self.hp.rollouts, self.dim, self.steps);
        if costs.rollouts() != k_all || costs.steps() != n {
            return Err(CostError::WrongShape {
                expected: k_all,
                expected_steps: n,
                got: costs.rollouts(),
                got_steps: costs.steps(),
            });
        }
        if let Some(k) = costs.missing().next() {
            return Err(CostError::Missing { rollout: k });
        }
        // One pass over the costs: NaN and ±∞ survive summation, so finite totals prove every
        // value finite; only otherwise look for the culprit to name it.
        costs.totals_into(&mut self.totals);
        if !self.totals.iter().all(|t| t.is_finite()) {
            costs.validate_filled()?;
        }
        let (rows, cols) = old.covariance.shape();
        if old.dim() != p || rows != p || cols != p {
            return Err(CostError::WrongDistribution {
                dim: p,
                mean: old.dim(),
                rows,
                cols,
            });
        }
        if samples.len() != k_all * p {
            return Err(CostError::WrongSamples {
                expected: k_all * p,
                got: samples.len(),
            });
        }
        let first = self.hp.first_updating_rollout();
        let m = k_all - first;
        let theta = old.mean.as_slice();
        for (r, k) in (first..k_all).enumerate() {
            for j in 0..p {
                self.eps[r * p + j] = samples[k * p + j] - theta[j];
            }
        }
        // With per-dimension blocks, the blocks' own rules compute Σ: this rule computes only
        // the mean.
        let adaptive = match self.hp.exploration {
            Exploration::Adaptive { bounds } if self.blocks.is_empty() => Some(bounds),
            _ => None,
        };
        let unbounded = adaptive.is_some_and(|b| b.min == 0.0 && b.max == f64::INFINITY);
        self.mean_weights.fill(0.0);
        if self.basis_temporal.is_some() {
            self.basis_weights.fill(0.0);
        }
        self.cov_acc.fill(0.0);
        if self.kernel == CovarianceKernel::LowRank {
            self.lowrank_acc.fill(0.0);
        }
        self.lowrank_stats = LowRankStats::default();
        self.per_step_basis = None;
        let per_step = matches!(self.hp.weighting, Weighting::PerTimeStep { .. });
        if self.kernel == CovarianceKernel::LowRank && adaptive.is_some() && !per_step {
            self.compute_gram(m);
        }

        match self.hp.weighting {
            Weighting::Episodic => {
                self.cost_to_go.copy_from_slice(&self.totals[first..]);
                self.hp
                    .mapping
                    .probabilities(&self.cost_to_go, &mut self.probs, &mut self.order);
                self.mean_weights.copy_from_slice(&self.probs);
                if let Some(bounds) = adaptive {
                    self.accumulate_covariance(1.0, bounds, unbounded);
                }
            }
            Weighting::PerTimeStep { .. } => {
                self.step_probabilities(costs, first);
                // Everything below works on whole rows of N steps at a time: the loops run over
                // time steps, which vectorise, instead of over K rollouts per step.
                let (probs, temporal) = (&self.step_probs, &self.temporal);
                for r in 0..m {
                    self.mean_weights[r] = dot(temporal, &probs[r * n..(r + 1) * n]);
                }
                if let Some(bt) = &self.basis_temporal {
                    for r in 0..m {
                        let pr = &probs[r * n..(r + 1) * n];
                        for (i, &pri) in pr.iter().enumerate() {
                            let row = &bt[i * p..(i + 1) * p];
                            for j in 0..p {
                                self.basis_weights[r * p + j] += row[j] * pri;
                            }
                        }
                    }
                }
                if let Some(bounds) = adaptive.filter(|_| !unbounded) {
                    if self.kernel == CovarianceKernel::Closed2 {
                        self.closed2_per_step(bounds);
                    } else if self.kernel == CovarianceKernel::LowRank {
                        self.lowrank_per_step(bounds);
                    } else {
                        for i in 0..n {
                            for r in 0..m {
                                self.probs[r] = self.step_probs[r * n + i];
                            }
                            self.accumulate_covariance(self.temporal[i], bounds, false);
                        }
                    }
                }
                if unbounded {
                    // boundcovar is the identity: the temporal average of Σ_k p_ik ε_k ε_kᵀ
                    // is Σ_k (Σ_i w_i p_ik) ε_k ε_kᵀ.
                    self.probs.copy_from_slice(&self.mean_weights);
                    self.accumulate_covariance(1.0, EigenvalueBounds::unbounded(), true);
                }
            }
        }

        // Mean: θ_new = θ + Σ_k a_k ε_k (per parameter for basis-activation averaging).
        let mut mean = old.mean.clone();
        if self.basis_temporal.is_some() {
            for r in 0..m {
                for j in 0..p {
                    mean[j] += self.basis_weights[r * p + j] * self.eps[r * p + j];
                }
            }
        } else {
            for r in 0..m {
                let a = self.mean_weights[r];
                for j in 0..p {
                    mean[j] += a * self.eps[r * p + j];
                }
            }
        }

        let covariance = match self.hp.exploration {
            Exploration::Constant => old.covariance.clone(),
            Exploration::Decay { factor } => &old.covariance * factor,
            Exploration::Adaptive { .. } if !self.blocks.is_empty() => {
                self.block_covariance(old, samples, costs)?
            }
            Exploration::Adaptive { bounds } => self.finish_covariance(bounds, unbounded),
        };
        // Finite costs can still overflow what follows from them (a covariance whose entries
        // square past f64::MAX): refuse here, at the update that went wrong, rather than hand on
        // a distribution whose samples fail the next update as NaN costs.
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        for (what, ok) in [
            ("mean", finite(mean.as_slice())),
            ("covariance", finite(covariance.as_slice())),
        ] {
            if !ok {
                return Err(CostError::NonFiniteUpdate {
                    what,
                    largest_variance: old.covariance.diagonal().max(),
                });
            }
        }
        let mut per_rollout = vec![0.0; k_all];
        per_rollout[first..].copy_from_slice(&self.mean_weights);
        Ok((
            Distribution { mean, covariance },
            UpdateWeights {
                per_rollout,
                totals: self.totals.clone(),
            },
        ))
    }

    /// The block-diagonal Σ of a per-dimension covariance: block d is the full-covariance
    /// update of dimension d's parameters alone (same costs, so the same probabilities).
    /// Unlike the full path it allocates per update (each block's copies of θ, Σ and the
    /// samples, and the probabilities recomputed per block): small next to the rollouts of a
    /// DMP task, and it keeps each block exactly the full rule's result for B parameters.
    fn block_covariance(
        &mut self,
        old: &Distribution,
        samples: &[f64],
        costs: &CostBatch,
    ) -> Result<DMatrix<f64>, CostError> {
        let (p, k) = (self.dim, self.hp.rollouts);
        let mut covariance = DMatrix::zeros(p, p);
        let mut sub_samples = Vec::new();
        for (d, rule) in self.blocks.iter_mut().enumerate() {
            let (lo, b) = (d * rule.dim, rule.dim);
            let sub_old = Distribution {
                mean: old.mean.rows(lo, b).clone_owned(),
                covariance: old.covariance.view((lo, lo), (b, b)).clone_owned(),
            };
            sub_samples.clear();
            for r in 0..k {
                sub_samples.extend_from_slice(&samples[r * p + lo..r * p + lo + b]);
            }
            let (sub_new, _) = rule.update(&sub_old, &sub_samples, costs)?;
            covariance
                .view_mut((lo, lo), (b, b))
                .copy_from(&sub_new.covariance);
        }
        Ok(covariance)
    }

    /// P_{i,k} for every step, rollout-major (row r holds the N probabilities of rollout r).
    fn step_probabilities(&mut self, costs: &CostBatch, first: usize) {
        let n = self.steps;
        let m = self.probs.len();
        // S_{i,k} = φ_k + Σ_{j≥i} q_{j,k}: a suffix sum along each rollout. Four rollouts at a
        // time, so that four independent addition chains share the pipeline.
        let rows: Vec<usize> = (first..self.hp.rollouts).collect();
        for (block, ks) in rows.chunks(4).enumerate() {
            let r0 = block * 4;
            if let [k0, k1, k2, k3] = *ks {
                let q = [
                    costs.per_step(k0),
                    costs.per_step(k1),
                    costs.per_step(k2),
                    costs.per_step(k3),
                ];
                let mut acc = [
                    costs.terminal(k0),
                    costs.terminal(k1),
                    costs.terminal(k2),
                    costs.terminal(k3),
                ];
                let (s0, rest) = self.step_costs[r0 * n..(r0 + 4) * n].split_at_mut(n);
                let (s1, rest) = rest.split_at_mut(n);
                let (s2, s3) = rest.split_at_mut(n);
                for i in (0..n).rev() {
                    for l in 0..4 {
                        acc[l] += q[l][i];
                    }
                    s0[i] = acc[0];
                    s1[i] = acc[1];
                    s2[i] = acc[2];
                    s3[i] = acc[3];
                }
            } else {
                for (l, &k) in ks.iter().enumerate() {
                    let q = costs.per_step(k);
                    let row = &mut self.step_costs[(r0 + l) * n..(r0 + l + 1) * n];
                    let mut acc = costs.terminal(k);
                    for i in (0..n).rev() {
                        acc += q[i];
                        row[i] = acc;
                    }
                }
            }
        }
        match self.hp.mapping {
            CostMapping::Exponential { eliteness } => {
                let unscaled = exponential_rows(
                    &self.step_costs[..m * n],
                    n,
                    eliteness,
                    &mut self.step_probs[..m * n],
                    &mut self.step_scratch[..2 * n],
                );
                if unscaled {
                    self.rescale_extreme_steps();
                }
            }
            CostMapping::Elites { .. } => {
                for i in 0..n {
                    for r in 0..m {
                        self.cost_to_go[r] = self.step_costs[r * n + i];
                    }
                    self.hp.mapping.probabilities(
                        &self.cost_to_go,
                        &mut self.probs,
                        &mut self.order,
                    );
                    for r in 0..m {
                        self.step_probs[r * n + i] = self.probs[r];
                    }
                }
            }
        }
    }

    /// The steps `exponential_rows` left uniform because h/(max − min) or max − min is not
    /// finite get line 18's probabilities from the scalar mapping, which normalises first. Rare
    /// (costs a subnormal apart, or near ±f64::MAX), so it need not be fast.
    fn rescale_extreme_steps(&mut self) {
        let n = self.steps;
        let m = self.probs.len();
        for i in 0..n {
            let column = (0..m).map(|r| self.step_costs[r * n + i]);
            let lo = column.clone().fold(f64::INFINITY, f64::min);
            let hi = column.fold(f64::NEG_INFINITY, f64::max);
            if !extreme_range(self.hp.mapping, hi - lo) {
                continue;
            }
            for r in 0..m {
                self.cost_to_go[r] = self.step_costs[r * n + i];
            }
            self.hp
                .mapping
                .probabilities(&self.cost_to_go, &mut self.probs, &mut self.order);
            for r in 0..m {
                self.step_probs[r * n + i] = self.probs[r];
            }
        }
    }

    /// Per-time-step PI²-CMA covariance for P = 2, vectorised over the N steps: Σ_i per step,
    /// boundcovar in closed form, then the temporal average.
    fn closed2_per_step(&mut self, bounds: EigenvalueBounds) {
        let n = self.steps;
        let m = self.probs.len();
        let (a, rest) = self.step_scratch.split_at_mut(n);
        let (b, c) = rest.split_at_mut(n);
        let c = &mut c[..n];
        a.fill(0.0);
        b.fill(0.0);
        c.fill(0.0);
        closed2_rows(&self.eps, &self.step_probs[..m * n], bounds, a, b, c);
        let w = &self.temporal;
        self.cov_acc[(0, 0)] = dot(w, a);
        self.cov_acc[(0, 1)] = dot(w, b);
        self.cov_acc[(1, 1)] = dot(w, c);
    }

    fn compute_gram(&mut self, m: usize) {
        let x = DMatrix::from_column_slice(self.dim, m, &self.eps);
        self.gram.gemm_tr(1.0, &x, &x, 0.0);
        // Gram entries feed an eigen-solver that expects exact symmetry.
        for a in 0..m {
            for b in 0..a {
                self.gram[(b, a)] = self.gram[(a, b)];
            }
        }
    }

    /// Adds w·boundcovar(Σ_k probs_k ε_k ε_kᵀ) to the accumulator of the chosen kernel.
    fn accumulate_covariance(&mut self, w: f64, bounds: EigenvalueBounds, unbounded: bool) {
        let p = self.dim;
        let m = self.probs.len();
        match self.kernel {
            CovarianceKernel::Closed2 => {
                let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
                for r in 0..m {
                    let (e0, e1) = (self.eps[2 * r], self.eps[2 * r + 1]);
                    let pr = self.probs[r];
                    a += pr * e0 * e0;
                    b += pr * e0 * e1;
                    c += pr * e1 * e1;
                }
                let (a, b, c) = if unbounded {
                    (a, b, c)
                } else {
                    boundcovar2(a, b, c, bounds)
                };
                self.cov_acc[(0, 0)] += w * a;
                self.cov_acc[(0, 1)] += w * b;
                self.cov_acc[(1, 1)] += w * c;
            }
            CovarianceKernel::Dense => {
                let mut s = DMatrix::<f64>::zeros(p, p);
                for r in 0..m {
                    let pr = self.probs[r];
                    let e = &self.eps[r * p..(r + 1) * p];
                    for a in 0..p {
                        for b in 0..=a {
                            s[(a, b)] += pr * e[a] * e[b];
                        }
                    }
                }
                for a in 0..p {
                    for b in 0..a {
                        s[(b, a)] = s[(a, b)];
                    }
                }
                if !unbounded {
                    s = boundcovar(&s, bounds);
                }
                self.cov_acc += s * w;
            }
            CovarianceKernel::LowRank => {
                // G = D^½·(E Eᵀ)·D^½ with D = diag(p); its eigenpairs (μ_j, v_j) give those of
                // Σ_i, and boundcovar(Σ_i) = λ_min·I + Eᵀ·D^½·V·diag(c)·Vᵀ·D^½·E with
                // c_j = (clip(μ_j) − λ_min)/μ_j.
                if unbounded {
                    for r in 0..m {
                        self.lowrank_acc[(r, r)] += w * self.probs[r];
                    }
                    return;
                }
                for (s, pr) in self.sqrt_probs.iter_mut().zip(&self.probs) {
                    *s = pr.sqrt();
                }
                lowrank_step(
                    &self.sqrt_probs,
                    w,
                    &self.gram,
                    bounds,
                    &mut self.small,
                    &mut self.factor,
                    &mut self.lowrank_acc,
                );
            }
        }
    }

    /// The per-time-step low-rank accumulation. With X = Q·R (P × K' and K'×K', over the K'
    /// non-zero ε_k), Σ_i = Q·T_i·Qᵀ with T_i = R·D_i·Rᵀ, so boundcovar(Σ_i) =
    /// λ_min·I + Q·(clip(T_i) − λ_min·I)·Qᵀ, and clip(T_i) − λ_min·I = T_i − λ_min·I − C_i with
    /// C_i = Σ_j (μ_j − clip(μ_j))·v_j·v_jᵀ over the eigenpairs of T_i that are clipped. Σ_i w_i·T_i
    /// = R·diag(Σ_i w_i·p_i)·Rᵀ is summed once; per step only the eigenvalues and the
    /// eigenvectors of the clipped ones are needed (see [`lowrank_qr_step`]). In fixed blocks of
    /// steps whose partial sums are added in block order: the bits do not depend on how many
    /// threads computed the blocks.
    fn lowrank_per_step(&mut self, bounds: EigenvalueBounds) {
        let (n, m, p) = (self.steps, self.probs.len(), self.dim);
        let kept: Vec<usize> = (0..m)
            .filter(|&r| self.eps[r * p..(r + 1) * p].iter().any(|&x| x != 0.0))
            .collect();
        let mk = kept.len();
        let mut x = DMatrix::zeros(p, mk);
        for (c, &r) in kept.iter().enumerate() {
            x.column_mut(c)
                .copy_from_slice(&self.eps[r * p..(r + 1) * p]);
        }
        let qr = x.qr();
        let (q, r) = (qr.q(), qr.r());
        let blocks: Vec<std::ops::Range<usize>> = (0..n)
            .step_by(STEP_BLOCK)
            .map(|s| s..(s + STEP_BLOCK).min(n))
            .collect();
        let (probs, temporal, mode) = (&self.step_probs, &self.temporal, self.lowrank_mode);
        let (kept, r) = (&kept, &r);
        let block = |b: &std::ops::Range<usize>| {
            qr_block(b.clone(), n, kept, probs, temporal, r, bounds, mode)
        };
        let partials: Vec<QrPartial> = if self.threads > 1 && blocks.len() > 1 {
            let per_thread = blocks.len().div_ceil(self.threads);
            std::thread::scope(|scope| {
                let handles: Vec<_> = blocks
                    .chunks(per_thread)
                    .map(|group| scope.spawn(move || group.iter().map(block).collect::<Vec<_>>()))
                    .collect();
                handles
                    .into_iter()
                    .flat_map(|h| h.join().expect("update worker thread panicked"))
                    .collect()
            })
        } else {
            blocks.iter().map(block).collect()
        };
        let mut core = DMatrix::zeros(mk, mk);
        let mut weights = vec![0.0; mk];
        let mut linear = 0.0;
        for part in partials {
            core += part.core;
            for (a, b) in weights.iter_mut().zip(&part.weights) {
                *a += b;
            }
            linear += part.linear;
            self.lowrank_stats.add(&part.stats);
        }
        // + Σ_i w_i·(T_i − λ_min·I) over the steps that did not compute clip(T_i) whole.
        let mut rd = r.clone();
        for (c, w) in weights.iter().enumerate() {
            rd.column_mut(c).scale_mut(*w);
        }
        core.gemm(1.0, &rd, &r.transpose(), 1.0);
        for a in 0..mk {
            core[(a, a)] -= bounds.min * linear;
        }
        self.per_step_basis = Some((q, core));
    }

    fn finish_covariance(&mut self, bounds: EigenvalueBounds, unbounded: bool) -> DMatrix<f64> {
        let p = self.dim;
        match self.kernel {
            CovarianceKernel::Closed2 => {
                let mut s = self.cov_acc.clone();
                s[(1, 0)] = s[(0, 1)];
                s
            }
            CovarianceKernel::Dense => {
                let s = &self.cov_acc;
                (s + s.transpose()) * 0.5
            }
            CovarianceKernel::LowRank if self.per_step_basis.is_some() => {
                let (q, mut core) = self.per_step_basis.take().expect("checked");
                let mk = core.nrows();
                for a in 0..mk {
                    for b in 0..a {
                        let v = 0.5 * (core[(a, b)] + core[(b, a)]);
                        core[(a, b)] = v;
                        core[(b, a)] = v;
                    }
                }
                let qc = &q * &core;
                let mut s = qc * q.transpose();
                for a in 0..p {
                    for b in 0..a {
                        let v = 0.5 * (s[(a, b)] + s[(b, a)]);
                        s[(a, b)] = v;
                        s[(b, a)] = v;
                    }
                    s[(a, a)] += bounds.min;
                }
                s
            }
            CovarianceKernel::LowRank => {
                let m = self.probs.len();
                // M is symmetric up to rounding in the accumulation; make it exactly so.
                for a in 0..m {
                    for b in 0..a {
                        let v = 0.5 * (self.lowrank_acc[(a, b)] + self.lowrank_acc[(b, a)]);
                        self.lowrank_acc[(a, b)] = v;
                        self.lowrank_acc[(b, a)] = v;
                    }
                }
                // X (P × K, columns ε_k) shares the memory layout of the row-major K × P eps.
                let x = DMatrix::from_column_slice(p, m, &self.eps);
                let xm = &x * &self.lowrank_acc;
                let mut s = xm * x.transpose();
                let lower = if unbounded { 0.0 } else { bounds.min };
                for a in 0..p {
                    for b in 0..a {
                        let v = 0.5 * (s[(a, b)] + s[(b, a)]);
                        s[(a, b)] = v;
                        s[(b, a)] = v;
                    }
                    s[(a, a)] += lower;
                }
                s
            }
        }
    }
}

/// Whether a step whose costs span `range` needs the scalar mapping's care: h/range or range
/// itself is not finite, so (S − min)·(−h/range) would be 0·∞ = NaN for the best rollout.
fn extreme_range(mapping: CostMapping, range: f64) -> bool {
    match mapping {
        CostMapping::Exponential { eliteness } => {
            range > 0.0 && !(range.is_finite() && (eliteness / range).is_finite())
        }
        CostMapping::Elites { .. } => false,
    }
}

/// The per-time-step PI² probabilities of K rollouts (rows of N cost-to-go values in `costs`)
/// into `probs`, same layout. Compiled for several instruction sets and chosen at run time: the
/// exponentials dominate a per-time-step update. Only element-wise IEEE operations in a fixed
/// order, so every variant gives the same bits. Returns whether some step's range was too small
/// or too large to scale by (see [`extreme_range`]); such a step is left uniform here, and
/// the caller must replace it.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn exponential_rows(
    costs: &[f64],
    n: usize,
    eliteness: f64,
    probs: &mut [f64],
    scratch: &mut [f64],
) -> bool {
    let m = costs.len() / n;
    let (lo, hi) = scratch.split_at_mut(n);
    lo.copy_from_slice(&costs[..n]);
    hi.copy_from_slice(&costs[..n]);
    for r in 1..m {
        let row = &costs[r * n..(r + 1) * n];
        for i in 0..n {
            lo[i] = lo[i].min(row[i]);
            hi[i] = hi[i].max(row[i]);
        }
    }
    // hi becomes the scale −h/(max − min); 0 when all costs of a step are equal, which makes
    // every exponent 0 and the weights uniform.
    let mut extreme = false;
    for i in 0..n {
        let range = hi[i] - lo[i];
        let scale = -eliteness / range;
        let usable = range > 0.0 && range.is_finite() && scale.is_finite();
        extreme |= range > 0.0 && !usable;
        hi[i] = if usable { scale } else { 0.0 };
    }
    for r in 0..m {
        let (s, pr) = (&costs[r * n..(r + 1) * n], &mut probs[r * n..(r + 1) * n]);
        for i in 0..n {
            pr[i] = exp_nonpositive((s[i] - lo[i]) * hi[i]);
        }
    }
    // lo is free again: it becomes 1/Σ_k E_ik.
    lo.copy_from_slice(&probs[..n]);
    for r in 1..m {
        for (z, e) in lo.iter_mut().zip(&probs[r * n..(r + 1) * n]) {
            *z += e;
        }
    }
    for z in lo.iter_mut() {
        *z = 1.0 / *z;
    }
    for r in 0..m {
        for (pr, inv) in probs[r * n..(r + 1) * n].iter_mut().zip(&*lo) {
            *pr *= inv;
        }
    }
    extreme
}

/// Per-step 2×2 covariances Σ_i = Σ_k P_ik ε_k ε_kᵀ, bounded, as rows (a, b, c) over the steps.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn closed2_rows(
    eps: &[f64],
    probs: &[f64],
    bounds: EigenvalueBounds,
    a: &mut [f64],
    b: &mut [f64],
    c: &mut [f64],
) {
    let n = a.len();
    let m = probs.len() / n;
    for r in 0..m {
        let (x, y) = (eps[2 * r], eps[2 * r + 1]);
        let (xx, xy, yy) = (x * x, x * y, y * y);
        let pr = &probs[r * n..(r + 1) * n];
        for i in 0..n {
            a[i] += pr[i] * xx;
            b[i] += pr[i] * xy;
            c[i] += pr[i] * yy;
        }
    }
    for i in 0..n {
        (a[i], b[i], c[i]) = boundcovar2_interpolated(a[i], b[i], c[i], bounds);
    }
}

/// Groups of [`BISECT_LANES`] eigenvalues up to which bisection is used rather than QL: at
/// K = 50 one group took ~16 µs and QL of all eigenvalues ~45 µs (perf time over the calls
/// counted in the late large update).
const BISECT_GROUPS: usize = 2;

/// Steps per block of the per-time-step low-rank accumulation.
const STEP_BLOCK: usize = 50;

/// How the per-time-step low-rank kernel solves a step's K'×K' problem T_i.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LowRankMode {
    /// Eigenvalues first; no eigenvector when none is clipped, the eigenvectors of the clipped
    /// ones (or of the unclipped ones, if fewer) by inverse iteration, and the full
    /// decomposition only when both sets are large.
    Auto,
    /// The full decomposition at every step (the reference the others are tested against).
    #[cfg(test)]
    Full,
    /// The partial path at every step, however many eigenvalues are clipped.
    #[cfg(test)]
    Partial,
    /// Wrong on purpose, for the tests: treats every step as if nothing were clipped.
    #[cfg(test)]
    IgnoreClipping,
}

/// Counts over the steps of one update of the per-time-step low-rank kernel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LowRankStats {
    /// Steps (per-step problems) solved.
    pub steps: usize,
    /// Steps none of whose eigenvalues needed clipping: no eigenvector computed.
    pub unclipped: usize,
    /// Steps solved with the full eigen-decomposition.
    pub full: usize,
    /// Eigenvectors computed by inverse iteration, over all steps.
    pub vectors: usize,
    /// Eigenvalues clipped, over all steps (below λ_min or above λ_max).
    pub clipped_values: usize,
    /// The most eigenvalues one step found by bisection.
    pub most_bisected: usize,
}

impl LowRankStats {
    fn add(&mut self, o: &LowRankStats) {
        self.steps += o.steps;
        self.unclipped += o.unclipped;
        self.full += o.full;
        self.vectors += o.vectors;
        self.clipped_values += o.clipped_values;
        self.most_bisected = self.most_bisected.max(o.most_bisected);
    }
}

/// One block's share of the per-time-step low-rank sum: `core` holds Σ w_i·(clip(T_i) − λ_min·I)
/// for the steps decomposed whole and −Σ w_i·C_i for the others, whose linear part
/// Σ w_i·(T_i − λ_min·I) = R·diag(`weights`)·Rᵀ − λ_min·`linear`·I is added once at the end.
struct QrPartial {
    core: DMatrix<f64>,
    weights: Vec<f64>,
    linear: f64,
    stats: LowRankStats,
}

/// Scratch of [`lowrank_qr_step`], sized for K' once per block.
struct QrScratch {
    sqrt_p: Vec<f64>,
    rs: Vec<f64>,
    t: Vec<f64>,
    t_copy: Vec<f64>,
    h: Vec<f64>,
    diag: Vec<f64>,
    off: Vec<f64>,
    values: Vec<f64>,
    scratch: Vec<f64>,
    work: Vec<f64>,
    previous: Vec<f64>,
    z: Vec<f64>,
    factor: DMatrix<f64>,
}

#[allow(clippy::too_many_arguments)]
fn qr_block(
    steps: std::ops::Range<usize>,
    n: usize,
    kept: &[usize],
    step_probs: &[f64],
    temporal: &[f64],
    r: &DMatrix<f64>,
    bounds: EigenvalueBounds,
    mode: LowRankMode,
) -> QrPartial {
    let mk = kept.len();
    let mut part = QrPartial {
        core: DMatrix::zeros(mk, mk),
        weights: vec![0.0; mk],
        linear: 0.0,
        stats: LowRankStats::default(),
    };
    let mut sc = QrScratch {
        sqrt_p: vec![0.0; mk],
        rs: vec![0.0; mk * mk],
        t: vec![0.0; mk * mk],
        t_copy: vec![0.0; mk * mk],
        h: vec![0.0; mk],
        diag: vec![0.0; mk],
        off: vec![0.0; mk],
        values: vec![0.0; mk],
        scratch: vec![0.0; mk],
        work: vec![0.0; 6 * VECTOR_LANES * mk],
        previous: Vec::with_capacity(mk * mk),
        z: vec![0.0; VECTOR_LANES * mk],
        factor: DMatrix::zeros(mk, mk),
    };
    for i in steps {
        for (c, &k) in kept.iter().enumerate() {
            sc.sqrt_p[c] = step_probs[k * n + i].sqrt();
        }
        lowrank_qr_step(temporal[i], r.as_slice(), bounds, mode, &mut sc, &mut part);
    }
    part
}

/// T = B·Bᵀ with B = R·diag(√p) (R upper triangular, column-major K'×K'), both triangles, each
/// entry the same sum of the same products as its mirror, so T is exactly symmetric.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn gram_of_scaled(mk: usize, r: &[f64], sqrt_p: &[f64], b: &mut [f64], t: &mut [f64]) {
    for k in 0..mk {
        let s = sqrt_p[k];
        for a in 0..=k {
            b[k * mk + a] = r[k * mk + a] * s;
        }
    }
    t.fill(0.0);
    for k in 0..mk {
        let bk = &b[k * mk..k * mk + k + 1];
        for c in 0..=k {
            let f = bk[c];
            let col = &mut t[c * mk..c * mk + k + 1];
            for (tc, bv) in col.iter_mut().zip(bk) {
                *tc += bv * f;
            }
        }
    }
}

/// One step of the per-time-step low-rank kernel (see [`UpdateRule::lowrank_per_step`]):
/// T = R·D·Rᵀ, reduced to tridiagonal form; Sturm counts at λ_min and λ_max tell how many
/// eigenvalues are clipped. None: T − λ_min·I is the step's share, no eigenvector needed.
/// Otherwise either the clipped eigenpairs (C = Σ (μ_j − clip(μ_j))·v_j·v_jᵀ) or, if fewer,
/// those above λ_min (clip(T) − λ_min·I = Σ (clip(μ_j) − λ_min)·v_j·v_jᵀ) are computed: their
/// eigenvalues by bisection (a few) or QL (more), their vectors by inverse iteration. When
/// both sets are large, the full decomposition.
fn lowrank_qr_step(
    w: f64,
    r: &[f64],
    bounds: EigenvalueBounds,
    mode: LowRankMode,
    sc: &mut QrScratch,
    part: &mut QrPartial,
) {
    use crate::symeig::{bisect, count_below, gershgorin, BISECT_LANES};
    let mk = sc.sqrt_p.len();
    if mk == 0 {
        return;
    }
    gram_of_scaled(mk, r, &sc.sqrt_p, &mut sc.rs, &mut sc.t);
    sc.t_copy.copy_from_slice(&sc.t);
    crate::symeig::reduce_tridiagonal(mk, &mut sc.t, &mut sc.h, &mut sc.diag, &mut sc.off);
    part.stats.steps += 1;
    let (gl, gu, pivmin) = gershgorin(&sc.diag, &sc.off);
    let scale = gl.abs().max(gu.abs());
    let finite = scale.is_finite();
    let (n_low, n_high) = if finite {
        let low = count_below(&sc.diag, &sc.off, bounds.min, pivmin);
        let high = if bounds.max.is_finite() {
            mk - count_below(&sc.diag, &sc.off, bounds.max, pivmin)
        } else {
            0
        };
        (low, high)
    } else {
        (0, 0)
    };
    part.stats.clipped_values += n_low + n_high;
    #[cfg(test)]
    let (n_low, n_high) = if mode == LowRankMode::IgnoreClipping {
        (0, 0)
    } else {
        (n_low, n_high)
    };
    let clipped = n_low + n_high;
    let above = mk - n_low;
    // The eigenvalues whose vectors are needed: the clipped ones, or those above λ_min.
    let direct = clipped > above;
    let needed = clipped.min(above);
    let partial = finite
        && match mode {
            LowRankMode::Auto => needed * 2 <= mk,
            #[cfg(test)]
            LowRankMode::Full => false,
            #[cfg(test)]
            LowRankMode::Partial | LowRankMode::IgnoreClipping => true,
        };
    if !partial {
        // The full decomposition: clip(T) − λ_min·I = V·diag(clip(μ) − λ_min)·Vᵀ.
        part.stats.full += 1;
        sc.t.copy_from_slice(&sc.t_copy);
        crate::symeig::symmetric_eigen(mk, &mut sc.t, &mut sc.values, &mut sc.scratch);
        let mut rank = 0;
        for j in 0..mk {
            let g = bounds.clip(sc.values[j]) - bounds.min;
            if !(g > 0.0) && !g.is_nan() {
                continue;
            }
            let scale = (w * g).sqrt();
            for a in 0..mk {
                sc.factor[(rank, a)] = sc.t[j * mk + a] * scale;
            }
            rank += 1;
        }
        if rank > 0 {
            sc.factor.rows_mut(rank, mk - rank).fill(0.0);
            let ft = sc.factor.transpose();
            part.core.gemm(1.0, &ft, &sc.factor, 1.0);
        }
        return;
    }
    // The needed eigenvalues, ascending indices, into sc.values[..needed].
    let wanted = |j: usize| {
        if direct {
            j >= n_low
        } else {
            j < n_low || j >= mk - n_high
        }
    };
    if needed <= BISECT_GROUPS * BISECT_LANES {
        let margin = 4.0 * f64::EPSILON * scale + pivmin;
        let mut group = (0..mk).filter(|&j| wanted(j)).peekable();
        let mut done = 0;
        while group.peek().is_some() {
            let mut filled = 0;
            let (mut index, mut lo, mut hi) =
                ([0; BISECT_LANES], [0.0; BISECT_LANES], [0.0; BISECT_LANES]);
            for j in group.by_ref().take(BISECT_LANES) {
                index[filled] = j;
                // Sturm counts put eigenvalue j below λ_min if j < n_low, at or above λ_max if
                // j ≥ mk − n_high, and between them otherwise.
                lo[filled] = if j < n_low {
                    gl - margin
                } else if j >= mk - n_high {
                    bounds.max
                } else {
                    bounds.min
                };
                hi[filled] = if j < n_low {
                    bounds.min
                } else if j >= mk - n_high || !bounds.max.is_finite() {
                    gu + margin
                } else {
                    bounds.max
                };
                filled += 1;
            }
            for l in filled..BISECT_LANES {
                (index[l], lo[l], hi[l]) = (index[0], lo[0], hi[0]);
            }
            bisect(&sc.diag, &sc.off, pivmin, scale, index, &mut lo, &mut hi);
            for l in 0..filled {
                sc.values[done + l] = 0.5 * (lo[l] + hi[l]);
            }
            done += filled;
        }
        part.stats.most_bisected = part.stats.most_bisected.max(done);
    } else {
        crate::symeig::tridiagonal_eigenvalues(&sc.diag, &sc.off, &mut sc.values, &mut sc.scratch);
        sc.values.sort_by(f64::total_cmp);
        let mut filled = 0;
        for j in 0..mk {
            if wanted(j) {
                sc.values[filled] = sc.values[j];
                filled += 1;
            }
        }
    }
    sc.previous.clear();
    for start in (0..needed).step_by(VECTOR_LANES) {
        let end = (start + VECTOR_LANES).min(needed);
        let coef: [f64; VECTOR_LANES] = std::array::from_fn(|l| {
            let mu = sc.values[(start + l).min(end - 1)];
            if direct {
                w * (bounds.clip(mu) - bounds.min)
            } else {
                -w * (mu - bounds.clip(mu))
            }
        });
        add_eigen_terms(mk, start..end, &coef[..end - start], sc, part);
    }
    if direct {
        return;
    }
    if clipped == 0 {
        part.stats.unclipped += 1;
    }
    for (a, s) in part.weights.iter_mut().zip(&sc.sqrt_p) {
        *a += w * (s * s);
    }
    part.linear += w;
}

/// core += Σ_l coef_l·z_l·z_lᵀ for the unit eigenvectors z_l of the reduced T for its
/// eigenvalues `sc.values[range]`.
fn add_eigen_terms(
    mk: usize,
    range: std::ops::Range<usize>,
    coef: &[f64],
    sc: &mut QrScratch,
    part: &mut QrPartial,
) {
    let z = &mut sc.z[..mk * range.len()];
    crate::symeig::reduced_eigenvectors(
        mk,
        &sc.t,
        &sc.h,
        &sc.diag,
        &sc.off,
        &sc.values[range],
        &mut sc.previous,
        z,
        &mut sc.work,
    );
    part.stats.vectors += coef.len();
    // All terms of the group in one pass over `core`, rather than one pass per vector: the
    // passes are bound by loading and storing `core`. Unused lanes add 0·z.
    let zs: [&[f64]; VECTOR_LANES] =
        std::array::from_fn(|l| &z[l.min(coef.len() - 1) * mk..][..mk]);
    let cs: [f64; VECTOR_LANES] = std::array::from_fn(|l| coef.get(l).copied().unwrap_or(0.0));
    for b in 0..mk {
        let f: [f64; VECTOR_LANES] = std::array::from_fn(|l| cs[l] * zs[l][b]);
        let col = &mut part.core.as_mut_slice()[b * mk..(b + 1) * mk];
        for (a, cv) in col.iter_mut().enumerate() {
            *cv += f
                .iter()
                .zip(&zs)
                .fold(0.0, |acc, (fl, zl)| acc + fl * zl[a]);
        }
    }
}

/// Adds w·M to `acc`, where boundcovar(Σ_k p_k ε_k ε_kᵀ) = λ_min·I + X·M·Xᵀ. With D = diag(p),
/// G = D^½·(XᵀX)·D^½ has the eigenpairs (μ_j, v_j) of the non-zero part of Σ, and
/// M = D^½·V·diag(c)·Vᵀ·D^½ with c_j = (clip(μ_j) − λ_min)/μ_j.
fn lowrank_step(
    sqrt_p: &[f64],
    w: f64,
    gram: &DMatrix<f64>,
    bounds: EigenvalueBounds,
    small: &mut DMatrix<f64>,
    factor: &mut DMatrix<f64>,
    acc: &mut DMatrix<f64>,
) {
    let m = sqrt_p.len();
    for a in 0..m {
        let da = sqrt_p[a];
        for b in 0..=a {
            let v = da * sqrt_p[b] * gram[(a, b)];
            small[(a, b)] = v;
            small[(b, a)] = v;
        }
    }
    let (mut mu, mut scratch) = (vec![0.0; m], vec![0.0; m]);
    symmetric_eigen(m, small.as_mut_slice(), &mut mu, &mut scratch);
    let mut rank = 0;
    for (j, &mu) in mu.iter().enumerate() {
        if !(mu > 0.0) {
            continue;
        }
        let c = (bounds.clip(mu) - bounds.min) / mu;
        if c == 0.0 {
            continue;
        }
        let scale = (w * c).sqrt();
        let v = small.column(j);
        for a in 0..m {
            factor[(rank, a)] = sqrt_p[a] * v[a] * scale;
        }
        rank += 1;
    }
    if rank > 0 {
        // Rows past `rank` are zero; multiplying them is cheaper than a view, and `gemm`
        // (unlike `gemm_tr`) reaches nalgebra's blocked matrix product.
        factor.rows_mut(rank, m - rank).fill(0.0);
        let ft = factor.transpose();
        acc.gemm(1.0, &ft, &*factor, 1.0);
    }
}

/// Σ a_i·b_i with four accumulators, so the reduction pipelines.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    let mut tail = 0.0;
    for (x, y) in ra.iter().zip(rb) {
        tail += x * y;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

#[cfg(test)]
mod lowrank_tests {
    use super::*;
    use nalgebra::DVector;
    use rand::{Rng, SeedableRng};

    /// A per-time-step PI²-CMA problem with P > K (the low-rank kernel): samples from
    /// N(0, λ·I), `duplicate` makes rollout 2 a copy of rollout 1 (a rank-deficient X besides
    /// the zero ε of the evaluation rollout 0, which enters the update).
    struct Problem {
        p: usize,
        k: usize,
        n: usize,
        h: f64,
        bounds: EigenvalueBounds,
        samples: Vec<f64>,
        costs: CostBatch,
    }

    fn problem(
        rng: &mut impl Rng,
        (p, k, n): (usize, usize, usize),
        lambda: f64,
        h: f64,
        bounds: EigenvalueBounds,
        duplicate: bool,
    ) -> Problem {
        let mut samples = vec![0.0; k * p];
        for v in samples[p..].iter_mut() {
            // Uniform with variance λ.
            *v = rng.random_range(-1.0..1.0) * (3.0 * lambda).sqrt();
        }
        if duplicate {
            let row: Vec<f64> = samples[p..2 * p].to_vec();
            samples[2 * p..3 * p].copy_from_slice(&row);
        }
        let mut costs = CostBatch::new(k, n);
        for r in 0..k {
            let q: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
            costs.insert(r, &q, rng.random_range(0.0..2.0)).unwrap();
        }
        Problem {
            p,
            k,
            n,
            h,
            bounds,
            samples,
            costs,
        }
    }

    fn rule(pb: &Problem, mode: LowRankMode) -> UpdateRule {
        let hp = Hyperparameters {
            rollouts: pb.k,
            mapping: CostMapping::Exponential { eliteness: pb.h },
            exploration: Exploration::Adaptive { bounds: pb.bounds },
            weighting: Weighting::PerTimeStep {
                temporal: TemporalAveraging::RemainingSteps,
            },
            evaluation_in_update: true,
            covariance: CovarianceStructure::Full,
        };
        let mut r = UpdateRule::new(hp, pb.p, pb.n, None).unwrap();
        assert_eq!(r.kernel, CovarianceKernel::LowRank);
        r.lowrank_mode = mode;
        r
    }

    fn run(pb: &Problem, mode: LowRankMode) -> (DMatrix<f64>, LowRankStats) {
        let mut r = rule(pb, mode);
        let old = Distribution::isotropic(DVector::zeros(pb.p), 1.0).unwrap();
        let (new, _) = r.update(&old, &pb.samples, &pb.costs).unwrap();
        (new.covariance, r.lowrank_stats())
    }

    /// Algorithm 1 written out with dense P×P matrices: per step Σ_i = Σ_k p_ik ε_k ε_kᵀ,
    /// boundcovar(Σ_i) by the P×P decomposition, averaged with weights N − i.
    fn dense_reference(pb: &Problem) -> DMatrix<f64> {
        let (p, k, n) = (pb.p, pb.k, pb.n);
        let eps: Vec<DVector<f64>> = (0..k)
            .map(|r| DVector::from_column_slice(&pb.samples[r * p..(r + 1) * p]))
            .collect();
        let total: f64 = (1..=n).map(|v| v as f64).sum();
        let mut acc = DMatrix::zeros(p, p);
        for i in 0..n {
            let s: Vec<f64> = (0..k)
                .map(|r| pb.costs.terminal(r) + pb.costs.per_step(r)[i..].iter().sum::<f64>())
                .collect();
            let lo = s.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let e: Vec<f64> = s
                .iter()
                .map(|v| (-pb.h * (v - lo) / (hi - lo)).exp())
                .collect();
            let z: f64 = e.iter().sum();
            let mut sigma = DMatrix::zeros(p, p);
            for r in 0..k {
                sigma += &eps[r] * eps[r].transpose() * (e[r] / z);
            }
            acc += boundcovar(&sigma, pb.bounds) * ((n - i) as f64 / total);
        }
        acc
    }

    fn max_diff(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
        (a - b).amax() / (1.0 + b.amax())
    }

    /// Every solver the kernel may use, forced on for every step, gives the dense reference's
    /// Σ to rounding: in the regime with nothing clipped, with a few eigenvalues clipped, with
    /// most clipped, with λ_max clipping, and with a rank-deficient X (a duplicated sample). The
    /// deliberately wrong solver (the no-clipping shortcut applied everywhere) agrees only where
    /// nothing is clipped, so the comparison would catch a shortcut applied wrongly.
    #[test]
    fn per_step_solvers_match_the_dense_reference() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2024);
        let inf = f64::INFINITY;
        // (λ of the samples, eliteness, λ_min, λ_max, duplicate, regime)
        let cases = [
            (1.0, 0.3, 0.02, inf, false, "none clipped"),
            (
                1.0,
                0.3,
                0.02,
                inf,
                true,
                "none clipped but the duplicate's null direction",
            ),
            (1.0, 10.0, 0.02, inf, false, "a few clipped"),
            (0.05, 10.0, 0.02, inf, false, "most clipped"),
            (0.05, 10.0, 0.02, inf, true, "most clipped, rank-deficient"),
            (1.0, 3.0, 0.05, 2.0, false, "clipped at both ends"),
            (
                1.0,
                3.0,
                0.0,
                1.0,
                true,
                "λ_min = 0, λ_max clipping, rank-deficient",
            ),
        ];
        let (mut seen_unclipped, mut most_bisected) = (false, 0);
        for (lambda, h, lo, hi, duplicate, regime) in cases {
            for shape in [(30, 8, 12), (60, 20, 9)] {
                let bounds = EigenvalueBounds::new(lo, hi).unwrap();
                let pb = problem(&mut rng, shape, lambda, h, bounds, duplicate);
                let reference = dense_reference(&pb);
                let tol = 1e-13;
                let (auto, stats) = run(&pb, LowRankMode::Auto);
                assert_eq!(stats.steps, pb.n, "{regime}");
                let (full, fs) = run(&pb, LowRankMode::Full);
                let (partial, ps) = run(&pb, LowRankMode::Partial);
                assert_eq!((fs.full, ps.full), (pb.n, 0), "{regime}");
                most_bisected = most_bisected.max(ps.most_bisected);
                for (what, got) in [("auto", &auto), ("full", &full), ("partial", &partial)] {
                    let d = max_diff(got, &reference);
                    assert!(
                        d < tol,
                        "{regime} {shape:?}, {what}: off by {d:e} ({stats:?})"
                    );
                }
                let (wrong, _) = run(&pb, LowRankMode::IgnoreClipping);
                let d = max_diff(&wrong, &reference);
                if stats.clipped_values == 0 {
                    seen_unclipped = true;
                    assert_eq!(stats.unclipped, pb.n, "{regime}");
                    assert_eq!(stats.vectors, 0, "{regime}");
                    assert!(d < tol, "{regime}: {d:e}");
                } else {
                    assert!(
                        d > 1e-6,
                        "{regime}: the wrong shortcut went unnoticed ({d:e})"
                    );
                }
            }
        }
        assert!(seen_unclipped, "no case had every step unclipped");
        assert!(
            most_bisected > crate::symeig::BISECT_LANES,
            "no step needed more than one group of bisection lanes"
        );
    }

    /// The same bits for any thread count, and from one run to the next.
    #[test]
    fn low_rank_kernel_is_deterministic_across_threads() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let bounds = EigenvalueBounds::new(0.02, 5.0).unwrap();
        let pb = problem(&mut rng, (40, 10, 230), 0.1, 10.0, bounds, false);
        let old = Distribution::isotropic(DVector::zeros(pb.p), 1.0).unwrap();
        let bits = |threads: usize| {
            let mut r = rule(&pb, LowRankMode::Auto).with_threads(threads);
            let (new, _) = r.update(&old, &pb.samples, &pb.costs).unwrap();
            new.covariance
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<u64>>()
        };
        let one = bits(1);
        assert_eq!(one, bits(1));
        assert_eq!(one, bits(2));
        assert_eq!(one, bits(3));
    }
}
