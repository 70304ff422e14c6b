//! Sans-IO assembly of updates from what the multiprocess pipeline publishes: the distribution of
//! each update and the K cost trajectories, arriving in any order, with duplicates. The
//! pipeline's recorder process feeds it from iceoryx2 services and writes what it returns with
//! [`crate::RunWriter`]; tests feed it directly.
//!
//! Costs of an update further ahead than the updater can be are dropped: held back by this
//! recorder, it publishes update u only while u is less than the recorder's oldest unwritten
//! update plus the lag bound (`wire::Limits::recorder_max_lag`), and takes costs of the update it
//! is at only, so costs beyond that come from no worker of this run's updater (one of another
//! config or revision), and kept, each would hold a K × N batch for good. The bound is counted
//! from the newest distribution taken in, not from the oldest unwritten update: an updater not
//! (yet) held back by this recorder runs further ahead — until it hears of a recorder started
//! again, and after it, when it counts the lag from the update it is at, which the recorder may
//! not have written for a while. Every distribution it published came before its costs, so an
//! update more than the lag bound past the newest one the recorder has seen is none of its.
//!
//! An update u is complete once its distribution, all K costs and the distribution of u + 1 are
//! in. The recorder then recomputes the update with the core (`Optimizer::resume` + `tell`),
//! which yields the samples (a pure function of seed, u, k), the weights and the summary exactly
//! as the updater computed them, and checks that the result equals the published distribution
//! of u + 1 bit for bit.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};
use pi2cma::{
    CostBatch, CostError, Distribution, Hyperparameters, ParameterBatch, UpdateRule, UpdateSummary,
};

use crate::RolloutTiming;

/// Why the assembler cannot take a distribution or hand out an update.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AssembleError {
    #[error(
        "distribution of update {update}: {mean} mean and {covariance} covariance values for \
         P = {dim}"
    )]
    DistributionLength {
        update: u64,
        mean: usize,
        covariance: usize,
        dim: usize,
    },
    #[error("update {update}: cannot build the update rule: {error}")]
    Rule {
        update: u64,
        error: pi2cma::ParameterError,
    },
    #[error("update {update}: {error}")]
    Update { update: u64, error: CostError },
}

/// Costs the assembler held from before its first distribution, dropped then because their
/// update is further ahead of it than the updater can be ([`Assembler::take_dropped`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Dropped {
    pub update: u64,
    /// The first distribution's update.
    pub first: u64,
    /// The workers that sent them, as their timings name them.
    pub workers: Vec<String>,
}

/// [`Assembler::reach`] once the newest distribution taken in is `newest`.
fn reach(newest: u64, lag: u64) -> u64 {
    newest.saturating_add(lag).saturating_add(1)
}

/// A published distribution: the one update `update` samples from.
#[derive(Debug, Clone)]
struct Published {
    distribution: Distribution,
    seed: u64,
    settings: Vec<f64>,
    /// λ of the distribution as its publisher computed it (`wire::DistributionHeader::lambda`),
    /// if known: an eigenvalue computation at P ≥ 3 (8 µs at P = 21) not done again.
    lambda: Option<f64>,
}

#[derive(Debug)]
struct Pending {
    costs: CostBatch,
    timings: Vec<Option<RolloutTiming>>,
    duplicates: u32,
    /// The settings the first stored rollout says it ran with (`None`: as published).
    ran_with: Option<Vec<f64>>,
}

/// One complete update, ready for [`crate::RunWriter::write_update`].
#[derive(Debug, Clone)]
pub struct Assembled {
    pub update: u64,
    pub before: Distribution,
    /// The distribution the pipeline published for update + 1.
    pub after: Distribution,
    pub samples: ParameterBatch,
    pub costs: CostBatch,
    pub summary: UpdateSummary,
    /// Task settings in force for this update: those its rollouts ran with.
    pub settings: Vec<(String, f64)>,
    /// Changes published for this update that its rollouts did not run with (the workers' task
    /// refused them): (setting, the value refused, the value run with, which `settings` holds).
    pub refused: Vec<(String, f64, f64)>,
    /// Settings that differ from the previous update's (task changes taking effect here).
    pub changed: Vec<(String, f64)>,
    pub timings: Vec<RolloutTiming>,
    /// Cost messages for rollouts already received (re-executions after a worker loss).
    pub duplicates: u32,
    /// Whether the core, given the recorded inputs, computes exactly `after`.
    pub recomputed_matches: bool,
}

/// Collects distributions and costs by update and hands out complete updates in order.
pub struct Assembler {
    hp: Hyperparameters,
    dim: usize,
    steps: usize,
    basis: Option<Vec<f64>>,
    /// The rule the last update was recomputed with, for the next one (building one allocates
    /// and fills all its buffers).
    rule: Option<UpdateRule>,
    /// Cost batches of updates already written, for the next ones ([`Assembler::recycle`]).
    spare: Vec<CostBatch>,
    setting_names: Vec<String>,
    distributions: BTreeMap<u64, Published>,
    pending: BTreeMap<u64, Pending>,
    /// Settings of the last update handed out, to detect task changes.
    last_settings: Option<Vec<f64>>,
    /// Updates below this were handed out (or skipped); their messages are stale.
    next: Option<u64>,
    /// The newest distribution taken in.
    newest: Option<u64>,
    /// How far the updater may run ahead of what it knows to be written: costs of
    /// `newest + 1 + lag` and later are dropped ([`Assembler::reach`]).
    lag: u64,
    /// Costs held from before the first distribution and dropped at it.
    dropped: Vec<Dropped>,
}

/// The task changes of the update after the last one handed out ([`Assembler::changes_ahead`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Ahead {
    pub update: u64,
    /// (setting, value) published for `update` and not refused by the rollouts in so far.
    pub changed: Vec<(String, f64)>,
    /// (setting, value published, value the rollouts in so far ran with): changes the
    /// workers' task refused.
    pub refused: Vec<(String, f64, f64)>,
    /// Every setting's value as `update` runs with it, in the order of the setting names: as
    /// published, with the refused changes at the value run with.
    pub settings: Vec<f64>,
}

/// What happened to a cost message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CostOutcome {
    Stored,
    Duplicate,
    /// For an update already written or skipped.
    Stale,
    /// For an update the updater cannot have reached (see the module's documentation): at or
    /// beyond `limit`, the newest distribution taken in plus one plus the lag bound
    /// ([`Assembler::reach`]); `None` before the first
    /// distribution, when costs of more updates came in than the lag bound allows (lag + 1:
    /// the update whose distribution came before the recorder looked, and the lag's). Dropped.
    OutOfReach {
        limit: Option<u64>,
    },
}

impl Assembler {
    /// `setting_names`: the task's settings, in the order the distribution header carries them;
    /// `lag`: how far the updater runs ahead of what is handed out
    /// (`wire::Limits::recorder_max_lag`).
    pub fn new(
        hp: Hyperparameters,
        dim: usize,
        steps: usize,
        basis: Option<Vec<f64>>,
        setting_names: Vec<String>,
        lag: u64,
    ) -> Self {
        Self {
            hp,
            dim,
            steps,
            basis,
            rule: None,
            spare: Vec::new(),
            setting_names,
            distributions: BTreeMap::new(),
            pending: BTreeMap::new(),
            last_settings: None,
            next: None,
            newest: None,
            lag,
            dropped: Vec::new(),
        }
    }

    /// Settings (in the order of `setting_names`) that the update before the first one ran
    /// with, in the recording this one continues: a change at the first update is then handed
    /// out as one.
    pub fn continue_from(&mut self, settings: Vec<f64>) {
        self.last_settings = Some(settings);
    }

    /// The first distribution seen (the recording starts there).
    pub fn first_update(&self) -> Option<u64> {
        self.distributions.keys().next().copied()
    }

    pub fn hyperparameters(&self) -> &Hyperparameters {
        &self.hp
    }

    /// A distribution as published: mean (P) and Σ (P×P) column-major, the task settings, and
    /// λ of it as its publisher computed it if known (the updater's
    /// `wire::DistributionHeader::lambda`), which the assembled updates then carry instead of
    /// computing it again.
    pub fn distribution(
        &mut self,
        update: u64,
        seed: u64,
        mean: &[f64],
        covariance_col_major: &[f64],
        settings: &[f64],
        lambda: Option<f64>,
    ) -> Result<(), AssembleError> {
        let p = self.dim;
        if mean.len() != p || covariance_col_major.len() != p * p {
            return Err(AssembleError::DistributionLength {
                update,
                mean: mean.len(),
                covariance: covariance_col_major.len(),
                dim: p,
            });
        }
        if self.next.is_some_and(|n| update < n) {
            return Ok(());
        }
        if self.next.is_none() {
            // A recorder that joined a run under way may hold costs of an update whose
            // distribution it missed: they can never complete one. Those of updates the lag
            // bound puts out of the updater's reach came from no worker of its.
            self.pending.retain(|&u, _| u >= update);
            let ahead = self.pending.split_off(&reach(update, self.lag));
            for (u, p) in ahead {
                let mut workers: Vec<String> =
                    p.timings.into_iter().flatten().map(|t| t.worker).collect();
                workers.sort();
                workers.dedup();
                self.dropped.push(Dropped {
                    update: u,
                    first: update,
                    workers,
                });
                self.recycle(p.costs);
            }
            self.next = Some(update);
        }
        self.newest = Some(self.newest.map_or(update, |d| d.max(update)));
        self.distributions.insert(
            update,
            Published {
                distribution: Distribution {
                    mean: DVector::from_column_slice(mean),
                    covariance: DMatrix::from_column_slice(p, p, covariance_col_major),
                },
                seed,
                settings: settings.to_vec(),
                lambda,
            },
        );
        Ok(())
    }

    /// A cost trajectory of rollout `rollout` of update `update`, and the task settings it ran
    /// with if its worker says (`wire::CostHeader::settings`).
    pub fn cost(
        &mut self,
        update: u64,
        rollout: usize,
        per_step: &[f64],
        terminal: f64,
        timing: RolloutTiming,
        ran_with: Option<&[f64]>,
    ) -> Result<CostOutcome, CostError> {
        if self.next.is_some_and(|n| update < n) {
            return Ok(CostOutcome::Stale);
        }
        if let Some(out) = self.out_of_reach(update) {
            return Ok(out);
        }
        let (k, n) = (self.hp.rollouts, self.steps);
        let spare = &mut self.spare;
        let p = self.pending.entry(update).or_insert_with(|| Pending {
            costs: spare.pop().unwrap_or_else(|| CostBatch::new(k, n)),
            timings: vec![None; k],
            duplicates: 0,
            ran_with: None,
        });
        match p.costs.insert(rollout, per_step, terminal) {
            Ok(()) => {
                p.timings[rollout] = Some(timing);
                if p.ran_with.is_none() {
                    p.ran_with = ran_with.map(<[f64]>::to_vec);
                }
                Ok(CostOutcome::Stored)
            }
            Err(CostError::Duplicate { .. }) => {
                // A rejected execution taken in after the rerun that replaced it: the
                // subscriber does not keep the order between two workers' messages (the
                // updater, which asked for the rerun, had it first). It is the rejection it
                // was, not a twin after a worker loss.
                pi2cma::check_finite(rollout, per_step, terminal)?;
                p.duplicates += 1;
                Ok(CostOutcome::Duplicate)
            }
            Err(e) => Err(e),
        }
    }

    /// [`CostOutcome::OutOfReach`] if a cost of `update` (not stale) would be dropped now. A
    /// caller that can take in more distributions first (published after it last looked)
    /// should, before it hands such a cost over.
    pub fn out_of_reach(&self, update: u64) -> Option<CostOutcome> {
        match self.reach() {
            Some(limit) if update >= limit => Some(CostOutcome::OutOfReach { limit: Some(limit) }),
            None if !self.pending.contains_key(&update) && self.pending.len() as u64 > self.lag => {
                Some(CostOutcome::OutOfReach { limit: None })
            }
            _ => None,
        }
    }

    /// The first update the updater cannot have published (see the module's documentation):
    /// the lag bound past the newest distribution taken in; `None` before the first.
    pub fn reach(&self) -> Option<u64> {
        self.newest.map(|d| reach(d, self.lag))
    }

    /// The costs dropped at the first distribution ([`Dropped`]), for the caller to report.
    pub fn take_dropped(&mut self) -> Vec<Dropped> {
        std::mem::take(&mut self.dropped)
    }

    /// Takes back the cost batch of an update handed out and written, for a later update: a
    /// new one is K × N zeroed values (12 kB for A1) allocated per update.
    pub fn recycle(&mut self, mut costs: CostBatch) {
        // As many as updates can be in progress at once is plenty; more only hold memory.
        if self.spare.len() < 4
            && costs.rollouts() == self.hp.rollouts
            && costs.steps() == self.steps
        {
            costs.clear();
            self.spare.push(costs);
        }
    }

    /// The next update if it is complete. Call until it returns `None`.
    pub fn next_complete(&mut self) -> Option<Result<Assembled, AssembleError>> {
        let u = self.next?;
        let complete = self.distributions.contains_key(&u)
            && self.distributions.contains_key(&(u + 1))
            && self.pending.get(&u).is_some_and(|p| p.costs.is_complete());
        if !complete {
            return None;
        }
        self.next = Some(u + 1);
        let before = self.distributions.remove(&u)?;
        let pending = self.pending.remove(&u)?;
        let next = self.distributions.get(&(u + 1))?;
        let (after, after_lambda) = (next.distribution.clone(), next.lambda);
        Some(self.assemble(u, before, pending, after, after_lambda))
    }

    /// Updates that can never complete because a later distribution exists but an input is
    /// missing: skips the oldest such update and returns it with what was missing. Call after
    /// draining all inputs; a recorder that sees this has lost messages.
    pub fn skip_incomplete(&mut self) -> Option<(u64, String)> {
        let u = self.next?;
        let later = self.distributions.keys().any(|&d| d > u + 1);
        if !later {
            return None;
        }
        let mut what = Vec::new();
        for d in [u, u + 1] {
            if !self.distributions.contains_key(&d) {
                what.push(format!("the distribution of update {d}"));
            }
        }
        let missing: Vec<usize> = match self.pending.get(&u) {
            Some(p) => p.costs.missing().collect(),
            None => (0..self.hp.rollouts).collect(),
        };
        if !missing.is_empty() {
            what.push(format!("the costs of rollouts {missing:?}"));
        }
        self.distributions.remove(&u);
        self.pending.remove(&u);
        self.next = Some(u + 1);
        Some((u, what.join(" and ")))
    }

    /// The task changes that the distribution of the next update carries (published, but its
    /// update not complete), against the settings of the last update handed out: changes that
    /// take effect at an update the recording does not reach, as when the run stops right
    /// after `supervisor set`. Empty before the first update is handed out. A change that the
    /// rollouts of that update already in say they did not run with (the workers' task refused
    /// it) is not among them: it is in [`Ahead::refused`], with the value run with.
    pub fn changes_ahead(&self) -> Option<Ahead> {
        let u = self.next?;
        let prev = self.last_settings.as_ref()?;
        let next = self.distributions.get(&u)?;
        let ran = self
            .pending
            .get(&u)
            .and_then(|p| p.ran_with.as_ref())
            .filter(|r| r.len() == next.settings.len());
        let mut ahead = Ahead {
            update: u,
            changed: Vec::new(),
            refused: Vec::new(),
            settings: next.settings.clone(),
        };
        for (i, ((name, v), p)) in self
            .setting_names
            .iter()
            .zip(&next.settings)
            .zip(prev)
            .enumerate()
        {
            if v.to_bits() == p.to_bits() {
                continue;
            }
            match ran.map(|r| r[i]) {
                Some(r) if r.to_bits() != v.to_bits() => {
                    ahead.refused.push((name.clone(), *v, r));
                    ahead.settings[i] = r;
                }
                _ => ahead.changed.push((name.clone(), *v)),
            }
        }
        Some(ahead)
    }

    fn assemble(
        &mut self,
        u: u64,
        before: Published,
        pending: Pending,
        after: Distribution,
        after_lambda: Option<f64>,
    ) -> Result<Assembled, AssembleError> {
        let mut rule = match self.rule.take() {
            Some(rule) => rule,
            None => UpdateRule::new(self.hp.clone(), self.dim, self.steps, self.basis.as_deref())
                .map_err(|error| AssembleError::Rule { update: u, error })?,
        };
        // What `Optimizer::ask` and `tell` do, with the λs the updater published when known.
        let samples =
            ParameterBatch::sample(&before.distribution, before.seed, u, self.hp.rollouts);
        let updated = rule.update(&before.distribution, &samples.values, &pending.costs);
        let result = updated.map(|(recomputed, weights)| {
            let lambda = before
                .lambda
                .unwrap_or_else(|| rule.lambda_of(&before.distribution));
            let lambda_next = after_lambda.unwrap_or_else(|| rule.lambda_next(lambda, &recomputed));
            let summary = UpdateSummary::new(u, weights, lambda, lambda_next, self.hp.weighting);
            (recomputed, summary)
        });
        self.rule = Some(rule);
        let (recomputed, summary) =
            result.map_err(|error| AssembleError::Update { update: u, error })?;
        let same = crate::recompute::same_bits;
        let recomputed_matches = same(recomputed.mean.as_slice(), after.mean.as_slice())
            && same(
                recomputed.covariance.as_slice(),
                after.covariance.as_slice(),
            );
        // The updater fails the run when rollouts disagree, so the first one speaks for all.
        let ran = pending
            .ran_with
            .filter(|r| r.len() == before.settings.len())
            .unwrap_or_else(|| before.settings.clone());
        let settings: Vec<(String, f64)> = self
            .setting_names
            .iter()
            .cloned()
            .zip(ran.iter().copied())
            .collect();
        let refused = self
            .setting_names
            .iter()
            .zip(before.settings.iter().zip(&ran))
            .filter(|(_, (asked, ran))| asked.to_bits() != ran.to_bits())
            .map(|(n, (asked, ran))| (n.clone(), *asked, *ran))
            .collect();
        let changed = match &self.last_settings {
            Some(prev) => settings
                .iter()
                .zip(prev)
                .filter(|((_, v), p)| v.to_bits() != p.to_bits())
                .map(|(s, _)| s.clone())
                .collect(),
            None => Vec::new(),
        };
        self.last_settings = Some(ran);
        let timings = pending
            .timings
            .into_iter()
            .map(|t| {
                t.unwrap_or_else(|| RolloutTiming {
                    worker: "unknown".into(),
                    start_ns: 0,
                    end_ns: 0,
                })
            })
            .collect();
        Ok(Assembled {
            update: u,
            before: before.distribution,
            after,
            samples,
            costs: pending.costs,
            summary,
            settings,
            refused,
            changed,
            timings,
            duplicates: pending.duplicates,
            recomputed_matches,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use session::{run_session, Observer, RunConfig, UpdateRecord};

    struct Capture(
        Vec<(
            Distribution,
            Distribution,
            ParameterBatch,
            CostBatch,
            UpdateSummary,
        )>,
    );
    impl Observer for Capture {
        fn on_update(&mut self, r: &UpdateRecord<'_>) {
            self.0.push((
                r.before.clone(),
                r.after.clone(),
                r.samples.clone(),
                r.costs.clone(),
                r.summary.clone(),
            ));
        }
    }

    #[test]
    fn out_of_order_and_duplicate_costs_assemble_to_the_in_process_updates() {
        assemble_like_in_process(RunConfig::default_config());
        // P = 5: λ by the general eigensolver (published or computed, the summaries must be
        // the in-process run's).
        let text = session::DEFAULT_CONFIG.replace("basis_functions = 2", "basis_functions = 5");
        assemble_like_in_process(RunConfig::parse(&text, std::path::Path::new("p5")).unwrap());
    }

    fn assemble_like_in_process(mut cfg: RunConfig) {
        cfg.run.updates = Some(25);
        let mut cap = Capture(Vec::new());
        run_session(&cfg, 4, &mut cap).unwrap();
        let task = session::build_task(&cfg).unwrap();
        let names: Vec<String> = task.settings().iter().map(|(n, _)| n.to_string()).collect();
        let mut a = Assembler::new(
            cfg.hyperparameters(),
            task.parameters(),
            task.steps(),
            task.basis_activations(),
            names,
            wire::RECORDER_MAX_LAG,
        );
        let k = cfg.optimizer.rollouts;
        let mut out = Vec::new();
        for (u, (before, _, _, costs, summary)) in cap.0.iter().enumerate() {
            let u = u as u64;
            let viapoint = if u >= 20 { 0.1 } else { 0.3 };
            // Costs first, in reverse order, rollout 3 twice (a re-execution).
            for r in (0..k).rev().chain([3]) {
                let t = RolloutTiming {
                    worker: format!("worker-{}", r % 3),
                    start_ns: 1,
                    end_ns: 2,
                };
                let o = a
                    .cost(u, r, costs.per_step(r), costs.terminal(r), t, None)
                    .unwrap();
                assert_ne!(o, CostOutcome::Stale);
            }
            // A rejected execution of rollout 5 taken in after the rerun that replaced it: a
            // rejection, not a twin, and the update it belongs to is unchanged.
            let t = RolloutTiming {
                worker: "worker-2".into(),
                start_ns: 1,
                end_ns: 2,
            };
            let late = a.cost(u, 5, costs.per_step(5), f64::NAN, t, None);
            assert!(
                matches!(late, Err(CostError::NonFinite { rollout: 5, .. })),
                "{late:?}"
            );
            // λ as the updater publishes it on every other update; computed on the others.
            a.distribution(
                u,
                4,
                before.mean.as_slice(),
                before.covariance.as_slice(),
                &[viapoint],
                u.is_multiple_of(2).then_some(summary.lambda),
            )
            .unwrap();
            while let Some(x) = a.next_complete() {
                out.push(x.unwrap());
            }
        }
        let last = &cap.0.last().unwrap().1;
        a.distribution(
            25,
            4,
            last.mean.as_slice(),
            last.covariance.as_slice(),
            &[0.1],
            None,
        )
        .unwrap();
        while let Some(x) = a.next_complete() {
            out.push(x.unwrap());
        }
        assert_eq!(out.len(), 25);
        for (x, (before, after, samples, _, summary)) in out.iter().zip(&cap.0) {
            assert!(x.recomputed_matches, "update {}", x.update);
            assert_eq!(&x.before, before);
            assert_eq!(&x.after, after);
            assert_eq!(&x.samples, samples);
            assert_eq!(&x.summary, summary);
            assert_eq!(x.duplicates, 1);
            assert_eq!(x.timings[4].worker, "worker-1");
            assert_eq!(x.changed.is_empty(), x.update != 20, "update {}", x.update);
        }
        // Stale messages for written updates are recognised.
        let c = &cap.0[0].3;
        let t = RolloutTiming {
            worker: "w".into(),
            start_ns: 0,
            end_ns: 0,
        };
        assert_eq!(
            a.cost(0, 0, c.per_step(0), c.terminal(0), t, None).unwrap(),
            CostOutcome::Stale
        );
    }

    /// What the next update's distribution changes, before that update completes (a run
    /// stopped right after `supervisor set`), and a first update compared with the settings of
    /// the recording a resumed run continues.
    #[test]
    fn changes_ahead_and_changes_at_a_resumed_first_update_are_found() {
        let hp = session::RunConfig::default_config().hyperparameters();
        let names = vec!["viapoint".to_string()];
        let (mean, cov) = ([0.0, 0.0], [1.0, 0.0, 0.0, 1.0]);
        let mut a = Assembler::new(hp.clone(), 2, 101, None, names.clone(), 16);
        assert_eq!(a.changes_ahead(), None);
        a.distribution(7, 1, &mean, &cov, &[0.3], None).unwrap();
        let costs = vec![1.0; 101];
        let timing = || RolloutTiming {
            worker: "w".into(),
            start_ns: 0,
            end_ns: 0,
        };
        for k in 0..hp.rollouts {
            a.cost(7, k, &costs, 0.0, timing(), None).unwrap();
        }
        a.distribution(8, 1, &mean, &cov, &[0.9], None).unwrap();
        assert!(a.next_complete().unwrap().unwrap().changed.is_empty());
        assert_eq!(
            a.changes_ahead(),
            Some(Ahead {
                update: 8,
                changed: vec![("viapoint".to_string(), 0.9)],
                refused: Vec::new(),
                settings: vec![0.9],
            })
        );
        // A rollout of update 8 that ran with the old value: the change is refused.
        a.cost(8, 0, &costs, 0.0, timing(), Some(&[0.3])).unwrap();
        assert_eq!(
            a.changes_ahead(),
            Some(Ahead {
                update: 8,
                changed: Vec::new(),
                refused: vec![("viapoint".to_string(), 0.9, 0.3)],
                settings: vec![0.3],
            })
        );

        let mut resumed = Assembler::new(hp.clone(), 2, 101, None, names, 16);
        resumed.continue_from(vec![0.1]);
        resumed
            .distribution(7, 1, &mean, &cov, &[0.3], None)
            .unwrap();
        for k in 0..hp.rollouts {
            resumed.cost(7, k, &costs, 0.0, timing(), None).unwrap();
        }
        resumed
            .distribution(8, 1, &mean, &cov, &[0.3], None)
            .unwrap();
        let first = resumed.next_complete().unwrap().unwrap();
        assert_eq!(first.changed, [("viapoint".to_string(), 0.3)]);
    }

    /// Update 8 publishes viapoint = 0.9, which the workers' task refuses: its rollouts say they
    /// ran with 0.3. The update is recorded with 0.3 and the change as refused, not taken, and
    /// update 9 (published with 0.3 again) changes nothing.
    #[test]
    fn a_change_the_rollouts_did_not_run_with_is_refused_not_taken() {
        let hp = session::RunConfig::default_config().hyperparameters();
        let mut a = Assembler::new(hp.clone(), 2, 3, None, vec!["viapoint".to_string()], 16);
        let (mean, cov) = ([0.0, 0.0], [1.0, 0.0, 0.0, 1.0]);
        let timing = || RolloutTiming {
            worker: "w".into(),
            start_ns: 0,
            end_ns: 0,
        };
        for (u, published, ran) in [(7, 0.3, None), (8, 0.9, Some(0.3)), (9, 0.3, None)] {
            a.distribution(u, 1, &mean, &cov, &[published], None)
                .unwrap();
            for k in 0..hp.rollouts {
                let ran = ran.map(|r| [r]);
                a.cost(u, k, &[1.0; 3], 0.0, timing(), ran.as_ref().map(|r| &r[..]))
                    .unwrap();
            }
        }
        a.distribution(10, 1, &mean, &cov, &[0.3], None).unwrap();
        let updates: Vec<Assembled> = std::iter::from_fn(|| a.next_complete())
            .map(Result::unwrap)
            .collect();
        assert_eq!(updates.len(), 3);
        let viapoint = |v: f64| vec![("viapoint".to_string(), v)];
        assert_eq!(updates[1].settings, viapoint(0.3));
        assert_eq!(updates[1].refused, [("viapoint".to_string(), 0.9, 0.3)]);
        for u in &updates {
            assert!(u.changed.is_empty(), "update {}: {:?}", u.update, u.changed);
        }
        assert!(updates[0].refused.is_empty() && updates[2].refused.is_empty());
    }

    fn timing(w: &str) -> RolloutTiming {
        RolloutTiming {
            worker: w.into(),
            start_ns: 0,
            end_ns: 0,
        }
    }

    /// The updater publishes update u only while u < (oldest update not written) + lag, and a
    /// distribution before its costs, so a cost of an update the lag bound past the newest
    /// distribution comes from no worker of its: dropped, however far ahead (before, each
    /// distinct update held a K × N batch for good).
    #[test]
    fn costs_further_ahead_than_the_updater_can_be_are_dropped() {
        let hp = RunConfig::default_config().hyperparameters();
        let (d, c) = ([0.0, 0.0], [1.0, 0.0, 0.0, 1.0]);
        let mut a = Assembler::new(hp.clone(), 2, 3, None, vec![], 2);
        a.distribution(7, 1, &d, &c, &[], None).unwrap();
        let cost = |a: &mut Assembler, u: u64| a.cost(u, 0, &[1.0; 3], 0.0, timing("w"), None);
        assert_eq!(cost(&mut a, 8).unwrap(), CostOutcome::Stored);
        assert_eq!(cost(&mut a, 9).unwrap(), CostOutcome::Stored);
        assert_eq!(
            cost(&mut a, 10).unwrap(),
            CostOutcome::OutOfReach { limit: Some(10) }
        );
        for u in (1000..2000).chain([u64::MAX]) {
            assert_eq!(
                cost(&mut a, u).unwrap(),
                CostOutcome::OutOfReach { limit: Some(10) }
            );
        }
        assert_eq!(a.pending.len(), 2);
        // Update 7 written, the window moves on.
        for k in 0..hp.rollouts {
            a.cost(7, k, &[1.0; 3], 0.0, timing("w"), None).unwrap();
        }
        a.distribution(8, 1, &d, &c, &[], None).unwrap();
        assert_eq!(a.next_complete().unwrap().unwrap().update, 7);
        assert_eq!(cost(&mut a, 10).unwrap(), CostOutcome::Stored);

        // Before the first distribution: the update whose distribution came before the
        // recorder looked and `lag` more; at the first distribution, those beyond its reach go.
        let mut b = Assembler::new(hp, 2, 3, None, vec![], 2);
        let from = |b: &mut Assembler, u: u64, w: &str| {
            b.cost(u, 0, &[1.0; 3], 0.0, timing(w), None).unwrap()
        };
        assert_eq!(from(&mut b, 500, "worker-300"), CostOutcome::Stored);
        assert_eq!(from(&mut b, 4, "worker-0"), CostOutcome::Stored);
        assert_eq!(from(&mut b, 5, "worker-1"), CostOutcome::Stored);
        assert_eq!(
            from(&mut b, 6, "worker-0"),
            CostOutcome::OutOfReach { limit: None }
        );
        assert_eq!(from(&mut b, 500, "worker-301"), CostOutcome::Duplicate);
        b.distribution(5, 1, &d, &c, &[], None).unwrap();
        assert_eq!(
            b.take_dropped(),
            [Dropped {
                update: 500,
                first: 5,
                workers: vec!["worker-300".into()],
            }]
        );
        assert_eq!(b.pending.keys().copied().collect::<Vec<_>>(), [5]);
        assert!(b.take_dropped().is_empty());
    }

    /// An updater not held back by this recorder runs ahead of it: after a recorder is started
    /// again (restarted, or `supervisor record`), until the updater hears of it, and after it,
    /// when the updater counts the lag from the update it is at. A round of the recorder then
    /// takes in the distributions and costs of more updates than the lag bound: the costs are
    /// the run's, and every update is handed out. (They were dropped as "out of the updater's
    /// reach" from the oldest update not written plus the lag bound on, and those updates
    /// skipped as lost.)
    #[test]
    fn costs_of_every_distribution_taken_in_are_kept_however_far_ahead_of_the_writing() {
        let hp = RunConfig::default_config().hyperparameters();
        let (d, c) = ([0.0, 0.0], [1.0, 0.0, 0.0, 1.0]);
        let mut a = Assembler::new(hp.clone(), 2, 3, None, vec![], 2);
        // One round: the distributions first, then the costs, as the recorder drains them.
        for u in 20..=30 {
            a.distribution(u, 1, &d, &c, &[], None).unwrap();
        }
        for u in 20..30 {
            for k in 0..hp.rollouts {
                let outcome = a.cost(u, k, &[1.0; 3], 0.0, timing("worker-0"), None);
                assert_eq!(outcome.unwrap(), CostOutcome::Stored, "update {u}");
            }
        }
        let handed: Vec<u64> = std::iter::from_fn(|| a.next_complete())
            .map(|r| r.unwrap().update)
            .collect();
        assert_eq!(handed, (20..30).collect::<Vec<_>>());
        assert_eq!(a.reach(), Some(33));
    }

    #[test]
    fn a_distribution_of_another_length_is_an_error_naming_both() {
        let hp = RunConfig::default_config().hyperparameters();
        let mut a = Assembler::new(hp, 2, 3, None, vec![], 2);
        let e = a
            .distribution(3, 1, &[0.0; 3], &[1.0; 4], &[], None)
            .unwrap_err();
        assert_eq!(
            e,
            AssembleError::DistributionLength {
                update: 3,
                mean: 3,
                covariance: 4,
                dim: 2
            }
        );
        assert_eq!(
            e.to_string(),
            "distribution of update 3: 3 mean and 4 covariance values for P = 2"
        );
    }

    #[test]
    fn lost_costs_are_skipped_and_reported() {
        let cfg = RunConfig::default_config();
        let hp = cfg.hyperparameters();
        let mut a = Assembler::new(hp, 2, 3, None, vec![], 16);
        let d = [0.0, 0.0];
        let c = [1.0, 0.0, 0.0, 1.0];
        for u in 0..3 {
            a.distribution(u, 1, &d, &c, &[], None).unwrap();
        }
        a.cost(
            0,
            2,
            &[1.0, 2.0, 3.0],
            0.0,
            RolloutTiming {
                worker: "w".into(),
                start_ns: 0,
                end_ns: 0,
            },
            None,
        )
        .unwrap();
        assert!(a.next_complete().is_none());
        let (u, what) = a.skip_incomplete().unwrap();
        assert_eq!(u, 0);
        assert!(
            what.starts_with("the costs of rollouts [0, 1, 3, 4,"),
            "{what}"
        );
        // Update 1 lacks its costs too, but may still get them: distribution 3 is not in yet.
        assert!(a.skip_incomplete().is_none());
        a.distribution(3, 1, &d, &c, &[], None).unwrap();
        let (u, what) = a.skip_incomplete().unwrap();
        assert_eq!(u, 1);
        assert!(what.contains("rollouts [0, 1, 2,"), "{what}");
    }
}
