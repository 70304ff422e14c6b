//! Recomputing every recorded update with the core from its recorded inputs.

use std::path::Path;

use pi2cma::{CostBatch, Distribution, UpdateRule, Weighting};

use crate::{
    distribution_from_proto, hyperparameters_from_proto, proto, read_recording_slim_with,
    RecordError, Recording,
};

/// One update recomputed: the core's new distribution and weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Recomputed {
    /// The update's number.
    pub update: u64,
    /// The distribution the core computes from the recorded inputs (compare with the
    /// recorded `after`).
    pub after: Distribution,
    /// The K rollout weights it computes, in rollout order.
    pub weights: Vec<f64>,
}

/// The outcome of recomputing a whole recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VerifyReport {
    /// How many updates were recomputed.
    pub updates: usize,
    /// Updates whose recomputed distribution or weights differ from the recorded ones (bitwise).
    pub mismatches: Vec<u64>,
}

/// Recomputes update `u` with `UpdateRule::update(before, samples, costs)`.
pub fn recompute_update(rec: &Recording, u: &proto::Update) -> Result<Recomputed, RecordError> {
    recompute(&rec.path, rec.run_info(), u)
}

/// [`recompute_update`] of an update of the file `path` whose `/run` is `run`.
fn recompute(
    path: &Path,
    run: Option<&proto::RunInfo>,
    u: &proto::Update,
) -> Result<Recomputed, RecordError> {
    let e = |what: String| RecordError::Update {
        file: path.to_path_buf(),
        update: u.update,
        what,
    };
    let hp = hyperparameters_from_proto(
        u.hyperparameters
            .as_ref()
            .ok_or_else(|| e("no hyperparameters".into()))?,
    )
    .map_err(|w| e(w.to_string()))?;
    let before = distribution_from_proto(u.before.as_ref().ok_or_else(|| e("no `before`".into()))?)
        .map_err(|w| e(format!("before: {w}")))?;
    let (k, p, n) = (u.rollouts as usize, u.dim as usize, u.steps as usize);
    // Recorded with `recording.step_costs = false`: the totals stand for the trajectories.
    let totals_only = u.cost_per_step.is_empty() && k * n > 0 && u.cost_total.len() == k;
    // A `before` of another P is the core's error (CostError::WrongDistribution), below.
    let steps_ok = totals_only || u.cost_per_step.len() == k * n;
    if u.samples.len() != k * p || !steps_ok || u.cost_terminal.len() != k {
        return Err(e(format!(
            "K = {k}, P = {p}, N = {n} but {} samples, {} step costs, {} terminal costs",
            u.samples.len(),
            u.cost_per_step.len(),
            u.cost_terminal.len()
        )));
    }
    if totals_only && matches!(hp.weighting, Weighting::PerTimeStep { .. }) {
        return Err(e(
            "no step costs recorded (recording.step_costs = false), which a per-time-step \
             update needs"
                .into(),
        ));
    }
    let basis = run
        .map(|r| r.basis_activations.as_slice())
        .filter(|b| !b.is_empty());
    let mut rule = UpdateRule::new(hp, p, n, basis).map_err(|x| e(x.to_string()))?;
    let mut costs = CostBatch::new(k, n);
    let zeros = vec![0.0; if totals_only { n } else { 0 }];
    for r in 0..k {
        // Episodic weighting weighs rollout r by its total alone; zero steps and the total as
        // terminal cost give that total back bit for bit (total_cost adds zeros to 0.0).
        let (steps, terminal) = if totals_only {
            (zeros.as_slice(), u.cost_total[r])
        } else {
            (&u.cost_per_step[r * n..(r + 1) * n], u.cost_terminal[r])
        };
        costs
            .insert(r, steps, terminal)
            .map_err(|x| e(x.to_string()))?;
    }
    let (after, weights) = rule
        .update(&before, &u.samples, &costs)
        .map_err(|x| e(x.to_string()))?;
    Ok(Recomputed {
        update: u.update,
        after,
        weights: weights.per_rollout,
    })
}

pub(crate) fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Whether the recomputed update equals the recorded one bit for bit (distribution after and
/// per-rollout weights).
pub(crate) fn matches_recorded(u: &proto::Update, r: &Recomputed) -> bool {
    let Some(after) = u.after.as_ref() else {
        return false;
    };
    let Ok(recorded) = distribution_from_proto(after) else {
        return false;
    };
    same_bits(recorded.mean.as_slice(), r.after.mean.as_slice())
        && same_bits(
            recorded.covariance.as_slice(),
            r.after.covariance.as_slice(),
        )
        && same_bits(&u.weights, &r.weights)
}

impl VerifyReport {
    fn add(&mut self, u: &proto::Update, r: &Recomputed) {
        self.updates += 1;
        if !matches_recorded(u, r) {
            self.mismatches.push(u.update);
        }
    }
}

/// Recomputes every update of the recording and compares.
pub fn verify(rec: &Recording) -> Result<VerifyReport, RecordError> {
    let mut report = VerifyReport::default();
    rec.for_each_update(|u| {
        report.add(u, &recompute_update(rec, u)?);
        Ok(())
    })?;
    Ok(report)
}

/// [`read_recording_slim`](crate::read_recording_slim) and [`verify`] in one pass over the file:
/// each update is recomputed as it is read, where `verify` of a recording read slim streams the
/// file again.
pub fn read_and_verify(path: &Path) -> Result<(Recording, VerifyReport), RecordError> {
    let mut report = VerifyReport::default();
    // The first update that cannot be recomputed ends the recomputing; its error is returned
    // once the file is read, so that a file that does not read fails as it does read alone.
    let mut failed = None;
    let rec = read_recording_slim_with(path, |run, u| {
        if failed.is_none() {
            match recompute(path, run, u) {
                Ok(r) => report.add(u, &r),
                Err(e) => failed = Some(e),
            }
        }
    })?;
    match failed {
        Some(e) => Err(e),
        None => Ok((rec, report)),
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};
    use pi2cma::{CostMapping, CovarianceStructure, Exploration, Hyperparameters, Weighting};

    use super::*;
    use crate::convert::{distribution_to_proto, hyperparameters_to_proto};

    /// An update of K = 3, P = 2, N = 1 whose `before` has dimension `before_dim`.
    fn update(before_dim: usize) -> proto::Update {
        let hp = Hyperparameters {
            rollouts: 3,
            mapping: CostMapping::Exponential { eliteness: 10.0 },
            exploration: Exploration::Constant,
            weighting: Weighting::Episodic,
            evaluation_in_update: false,
            covariance: CovarianceStructure::Full,
        };
        let before = Distribution {
            mean: DVector::zeros(before_dim),
            covariance: DMatrix::identity(before_dim, before_dim),
        };
        proto::Update {
            update: 4,
            hyperparameters: Some(hyperparameters_to_proto(&hp)),
            before: Some(distribution_to_proto(&before)),
            rollouts: 3,
            dim: 2,
            steps: 1,
            samples: vec![0.0, 0.0, 1.0, -1.0, 0.5, 0.25],
            cost_per_step: vec![1.0, 2.0, 3.0],
            cost_terminal: vec![0.0; 3],
            ..Default::default()
        }
    }

    #[test]
    fn a_recorded_before_of_another_dimension_than_the_update_is_an_error() {
        let path = Path::new("damaged.mcap");
        assert!(recompute(path, None, &update(2)).is_ok());
        let e = recompute(path, None, &update(3)).unwrap_err().to_string();
        assert!(
            e.contains("damaged.mcap") && e.contains("update 4") && e.contains("3 mean entries"),
            "{e}"
        );
    }
}
