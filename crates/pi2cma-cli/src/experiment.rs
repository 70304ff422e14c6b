//! Experiments: S learning sessions (seeds) per config, run in-process, aggregated into mean
//! curves, CSV files and the re-convergence table.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{DMatrix, DVector};
use pi2cma::{Optimizer, UpdateSummary, Weighting};
use session::{InProcess, Observer, Observers, RunConfig, SessionError, UpdateRecord};
use tasks::Task;

/// One session's trajectory through the updates.
#[derive(Debug, Clone)]
pub struct SessionResult {
    /// The seed the session ran with.
    pub seed: u64,
    /// One summary per finished update, in order (index u); fewer than `run.updates` when the
    /// session was stopped early.
    pub summaries: Vec<UpdateSummary>,
    /// The distribution each update sampled from (index u), plus the final one at the end.
    pub distributions: Vec<(DVector<f64>, DMatrix<f64>)>,
}

/// All sessions of one config.
#[derive(Debug, Clone)]
pub struct ConfigResult {
    /// The config's `run.name`.
    pub name: String,
    /// The cost weighting the config learned with (episodic or per time step).
    pub weighting: Weighting,
    /// `from_update` of the config's last scheduled task change (None without a schedule):
    /// re-convergence is counted from this update.
    pub change_at: Option<u64>,
    /// Every session that ran, in the order they ran.
    pub sessions: Vec<SessionResult>,
    /// Lowest total cost reachable on the task as it is after the last change (found by a
    /// deterministic compass search from the final means); the reference for re-convergence.
    pub optimum_after_change: Option<f64>,
    /// Whether that search converged; false when it stopped at [`COMPASS_BUDGET`] (a policy of
    /// many parameters), so the reference may lie above the optimum.
    pub optimum_converged: bool,
}

/// The most total-cost evaluations of one compass search. The paper's tasks need far fewer
/// (via-point, P = 2: ~240; T-ball, P = 21: ~6 300), so their references are exact; without a
/// bound a policy of P = 400 kept `pi2cma run` busy for more than 20 minutes after its last
/// update (P = 160: 5.4 s), the search taking O(P²) rollouts of O(P) each.
pub const COMPASS_BUDGET: u64 = 20_000;

struct Collector {
    summaries: Vec<UpdateSummary>,
    distributions: Vec<(DVector<f64>, DMatrix<f64>)>,
}

impl Observer for Collector {
    fn on_update(&mut self, r: &UpdateRecord<'_>) {
        self.summaries.push(r.summary.clone());
        self.distributions
            .push((r.before.mean.clone(), r.before.covariance.clone()));
    }
    fn on_finish(&mut self, o: &Optimizer) {
        let d = o.distribution();
        self.distributions
            .push((d.mean.clone(), d.covariance.clone()));
    }
}

/// Runs one session in-process and collects its curve; `observer` sees every hook too (progress
/// printing, MCAP recording), and `stop` is asked after every update (true: end it there).
pub fn run_one(
    config: &RunConfig,
    seed: u64,
    observer: &mut dyn Observer,
    stop: &dyn Fn() -> bool,
) -> Result<SessionResult, SessionError> {
    let mut exec = InProcess::new(config, seed)?;
    let mut c = Collector {
        summaries: Vec::new(),
        distributions: Vec::new(),
    };
    exec.run(&mut Observers(vec![&mut c, observer]), stop)?;
    Ok(SessionResult {
        seed,
        summaries: c.summaries,
        distributions: c.distributions,
    })
}

/// Runs `sessions` sessions with seeds run.seed, run.seed + 1, ….
pub fn run_config(config: &RunConfig, sessions: usize) -> Result<ConfigResult, SessionError> {
    let sessions = (0..sessions as u64)
        .map(|s| {
            run_one(
                config,
                config.run.seed + s,
                &mut session::NoObserver,
                &|| false,
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    summarize(config, sessions)
}

/// Groups finished sessions of one config and finds the reference optimum after the change.
pub fn summarize(
    config: &RunConfig,
    sessions: Vec<SessionResult>,
) -> Result<ConfigResult, SessionError> {
    let change_at = config.schedule().changes().last().map(|c| c.from_update);
    let mut result = ConfigResult {
        name: config.run.name.clone(),
        weighting: config.weighting(),
        change_at,
        sessions,
        optimum_after_change: None,
        optimum_converged: true,
    };
    if change_at.is_some() {
        // Without its rollout delay: the delay stands in for a slow robot, and the search's
        // hundreds to thousands of rollouts kept `pi2cma run` silent for minutes after its
        // last update.
        let mut task = session::build_task_without_delay(config)?;
        let initial = task.settings();
        config
            .schedule()
            .configure(task.as_mut(), &initial, u64::MAX)?;
        let starts: Vec<Vec<f64>> = result
            .sessions
            .iter()
            .filter_map(|s| s.distributions.last().map(|d| d.0.as_slice().to_vec()))
            .chain(std::iter::once(task.initial_mean()))
            .collect();
        let found: Vec<Minimum> = starts
            .iter()
            .map(|s| minimize_total_cost(task.as_mut(), s, &[]))
            .collect();
        result.optimum_converged = found.iter().all(|m| m.converged);
        let Some(best) = found.iter().min_by(|a, b| a.cost.total_cmp(&b.cost)) else {
            return Ok(result);
        };
        if !result.optimum_converged {
            // Out of budget already (a policy of many parameters): not another budget's worth.
            result.optimum_after_change = Some(best.cost);
            return Ok(result);
        }
        // A search along the axes stops anywhere on a valley that runs across them, such as
        // the via-point's |x(0.5) − v| (a kink along a line in θ): from different starts it
        // found 63.25 to 63.44 for the same task, one reference per config. The minima found
        // lie on that valley, so the lines between them run along it: search those too.
        let along: Vec<Vec<f64>> = found
            .iter()
            .filter_map(|m| {
                unit(
                    &m.point
                        .iter()
                        .zip(&best.point)
                        .map(|(a, b)| a - b)
                        .collect::<Vec<_>>(),
                )
            })
            .collect();
        let again = minimize_total_cost(task.as_mut(), &best.point, &along);
        result.optimum_converged &= again.converged;
        result.optimum_after_change = Some(again.cost.min(best.cost));
    }
    Ok(result)
}

/// Total cost of θ on `task`.
pub fn total_cost(task: &mut dyn Task, theta: &[f64]) -> f64 {
    let mut q = vec![0.0; task.steps()];
    let phi = task.rollout(theta, &mut q);
    phi + q.iter().sum::<f64>()
}

/// `v` scaled to length 1; None for a (near) zero vector.
fn unit(v: &[f64]) -> Option<Vec<f64>> {
    let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    (norm > 1e-9).then(|| v.iter().map(|x| x / norm).collect())
}

/// What a compass search found.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Minimum {
    pub(crate) cost: f64,
    /// Where: the parameters of `cost`.
    pub(crate) point: Vec<f64>,
    /// False: it stopped at [`COMPASS_BUDGET`] evaluations before its step shrank to 1e-9.
    pub(crate) converged: bool,
}

/// Deterministic compass search along the axes and the unit vectors `along`: enough to locate
/// the optimum of a low-dimensional task (the via-point has P = 2), used only as a reference
/// level, never inside learning.
pub(crate) fn minimize_total_cost(
    task: &mut dyn Task,
    start: &[f64],
    along: &[Vec<f64>],
) -> Minimum {
    let mut x = start.to_vec();
    let mut best = total_cost(task, &x);
    let mut step = x.iter().map(|v| v.abs()).fold(1.0, f64::max);
    let mut evaluations = 1;
    let axes = (0..x.len()).map(|j| {
        let mut e = vec![0.0; x.len()];
        e[j] = 1.0;
        e
    });
    let directions: Vec<Vec<f64>> = axes.chain(along.iter().cloned()).collect();
    let mut trial = x.clone();
    while step > 1e-9 {
        let mut improved = false;
        for d in &directions {
            for sign in [1.0, -1.0] {
                if evaluations >= COMPASS_BUDGET {
                    return Minimum {
                        cost: best,
                        point: x,
                        converged: false,
                    };
                }
                evaluations += 1;
                for ((t, xi), di) in trial.iter_mut().zip(&x).zip(d) {
                    *t = xi + sign * step * di;
                }
                let c = total_cost(task, &trial);
                if c < best {
                    best = c;
                    x.copy_from_slice(&trial);
                    improved = true;
                }
            }
        }
        if !improved {
            step *= 0.5;
        }
    }
    Minimum {
        cost: best,
        point: x,
        converged: true,
    }
}

fn mean_over_sessions(r: &ConfigResult, f: impl Fn(&UpdateSummary) -> f64) -> Vec<f64> {
    let n = r
        .sessions
        .iter()
        .map(|s| s.summaries.len())
        .min()
        .unwrap_or(0);
    (0..n)
        .map(|u| {
            r.sessions.iter().map(|s| f(&s.summaries[u])).sum::<f64>() / r.sessions.len() as f64
        })
        .collect()
}

impl ConfigResult {
    /// Mean over sessions of the evaluation rollout's total cost at each update (the learning
    /// curve), as long as the shortest session.
    pub fn mean_eval_cost(&self) -> Vec<f64> {
        mean_over_sessions(self, |s| s.eval_cost)
    }

    /// Mean over sessions of the standard deviation of the exploration-rollout costs.
    pub fn mean_exploration_std(&self) -> Vec<f64> {
        mean_over_sessions(self, |s| s.exploration_cost_std)
    }

    /// Mean over sessions of λ_u.
    pub fn mean_lambda(&self) -> Vec<f64> {
        mean_over_sessions(self, |s| s.lambda)
    }

    /// The three curves of `mean_curves.csv`, the summary table and Fig. 2: the means over
    /// sessions of the eval cost, the exploration-cost standard deviation and λ_u.
    pub fn mean_curves(&self) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        (
            self.mean_eval_cost(),
            self.mean_exploration_std(),
            self.mean_lambda(),
        )
    }

    /// The first update u ≥ the change from which the mean eval cost stays within 10% of the
    /// jump above the optimum: c(v) ≤ c* + 0.1·(c(change) − c*) for every v ≥ u. `None` if the
    /// run never gets there (or has no change).
    pub fn reconvergence_update(&self) -> Option<u64> {
        let (change, opt) = (self.change_at?, self.optimum_after_change?);
        let c = self.mean_eval_cost();
        let start = change as usize;
        if start >= c.len() {
            return None;
        }
        let threshold = opt + 0.1 * (c[start] - opt);
        let mut first = None;
        for (u, &v) in c.iter().enumerate().skip(start) {
            if v <= threshold {
                first.get_or_insert(u as u64);
            } else {
                first = None;
            }
        }
        first
    }
}

pub(crate) fn weighting_label(w: Weighting) -> &'static str {
    match w {
        Weighting::Episodic => "episodic",
        Weighting::PerTimeStep {
            temporal: pi2cma::TemporalAveraging::RemainingSteps,
        } => "per-time-step",
        Weighting::PerTimeStep {
            temporal: pi2cma::TemporalAveraging::BasisActivation,
        } => "per-time-step-basis-activation",
    }
}

/// Per-update rows of every session: `updates.csv`.
pub fn write_updates_csv(path: &Path, results: &[ConfigResult]) -> std::io::Result<()> {
    let mut s = String::from(
        "config,weighting,session,seed,update,eval_cost,exploration_cost_mean,exploration_cost_std,lambda,mean,covariance\n",
    );
    for r in results {
        for (i, sess) in r.sessions.iter().enumerate() {
            for (u, sum) in sess.summaries.iter().enumerate() {
                let (m, c) = &sess.distributions[u];
                let join = |v: &[f64]| {
                    v.iter()
                        .map(|x| format!("{x:e}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                };
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{:e},{:e},{:e},{:e},{},{}",
                    r.name,
                    weighting_label(r.weighting),
                    i,
                    sess.seed,
                    u,
                    sum.eval_cost,
                    sum.exploration_cost_mean,
                    sum.exploration_cost_std,
                    sum.lambda,
                    join(m.as_slice()),
                    join(c.as_slice())
                );
            }
        }
    }
    std::fs::write(path, s)
}

/// Mean curves per config: `mean_curves.csv`.
pub fn write_mean_csv(path: &Path, results: &[ConfigResult]) -> std::io::Result<()> {
    let mut s = String::from("config,weighting,update,eval_cost,exploration_cost_std,lambda\n");
    for r in results {
        let (e, sd, l) = r.mean_curves();
        for u in 0..e.len() {
            let _ = writeln!(
                s,
                "{},{},{},{:e},{:e},{:e}",
                r.name,
                weighting_label(r.weighting),
                u,
                e[u],
                sd[u],
                l[u]
            );
        }
    }
    std::fs::write(path, s)
}

/// The summary table printed after an experiment and saved as `summary.md`. Its middle columns
/// are the updates around each config's last task change: the one before it and its own
/// (u=19, u=20 for the paper's change after 20 updates), named by number when every config
/// changes at the same update, else as "before change" / "at change" with the update in
/// each cell.
pub fn summary_table(results: &[ConfigResult]) -> String {
    let first = results.first().and_then(|r| r.change_at);
    let shared = first.filter(|&c| c >= 1 && results.iter().all(|r| r.change_at == Some(c)));
    let (before, at_change) = match shared {
        Some(c) => (format!("u={}", c - 1), format!("u={c}")),
        None => ("before change".to_string(), "at change".to_string()),
    };
    let mut s = format!(
        "| config | weighting | sessions | eval cost u=0 | {before} | {at_change} | last | expl. std {before} | λ u=0 | λ {before} | λ max after change | λ last | re-converged at |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in results {
        let (e, sd, l) = r.mean_curves();
        if e.is_empty() {
            continue;
        }
        let at = |v: &[f64], u: usize| v.get(u).map_or("–".into(), |x| fmt(*x));
        // The update a cell is at, said in it where the header cannot say it for every row.
        let around = |v: &[f64], u: Option<u64>| match u.and_then(|u| Some((u, v.get(u as usize)?)))
        {
            None => "–".to_string(),
            Some((_, x)) if shared.is_some() => fmt(*x),
            Some((u, x)) => format!("{} (u={u})", fmt(*x)),
        };
        let before = r.change_at.and_then(|c| c.checked_sub(1));
        // Without a change (or a change after the last update) there is no such maximum.
        let lmax = r
            .change_at
            .map(|c| l.iter().skip(c as usize).cloned().fold(f64::NAN, f64::max))
            .filter(|m| !m.is_nan())
            .map_or("–".into(), fmt);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.name,
            weighting_label(r.weighting),
            r.sessions.len(),
            at(&e, 0),
            around(&e, before),
            around(&e, r.change_at),
            fmt(e[e.len() - 1]),
            around(&sd, before),
            at(&l, 0),
            around(&l, before),
            lmax,
            fmt(l[l.len() - 1]),
            match (r.change_at, r.reconvergence_update()) {
                (None, _) => "no change".to_string(),
                // A run stopped (Ctrl-C) or ended before its change: "not re-converged" said
                // it had failed to re-learn a change it never saw.
                (Some(c), _) if c as usize >= e.len() => format!("change (u={c}) not reached"),
                (Some(_), at) => {
                    let at = at.map_or("not re-converged".to_string(), |u| u.to_string());
                    match r.optimum_converged {
                        true => at,
                        false => format!("{at} (reference search stopped at its budget)"),
                    }
                }
            }
        );
    }
    s
}

/// What the table's last column means, and the reference each config's was measured against:
/// printed below the table and saved with it. Without the reference, "re-converged at 31" could
/// not be checked against the curves (the progress lines count updates from 1, the table from 0).
pub fn summary_notes(results: &[ConfigResult]) -> String {
    let references: Vec<String> = results
        .iter()
        .filter_map(|r| Some(format!("{} {}", r.name, fmt(r.optimum_after_change?))))
        .collect();
    if references.is_empty() {
        return String::new();
    }
    // After a blank line: GitHub's Markdown reads a line right below a table as its last row.
    format!(
        "\nre-converged at: the first update u (counted from 0, as the u= columns; progress line \
         `update u+1/…`) from which the mean eval cost stays at or below optimum + 10% of its \
         jump above the optimum at the change, the optimum being the lowest total cost of the \
         changed task found by a compass search: {}\n",
        references.join(", ")
    )
}

fn fmt(x: f64) -> String {
    if x.abs() >= 1e4 || (x != 0.0 && x.abs() < 1e-2) {
        format!("{x:.2e}")
    } else {
        format!("{x:.3}")
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // a failed unwrap is a failed test

    use super::*;

    /// A session of the default config (A1) with its task change at `from_update` and
    /// `updates` updates.
    fn a1(from_update: u64, updates: u64) -> ConfigResult {
        let text = session::DEFAULT_CONFIG
            .replace("from_update = 20", &format!("from_update = {from_update}"));
        let mut cfg = RunConfig::parse(&text, Path::new("a1.toml")).unwrap();
        cfg.run.updates = Some(updates);
        run_config(&cfg, 1).unwrap()
    }

    /// The columns were u=19 and u=20 whatever the config, "–" for a run of fewer updates
    /// with its change at update 1 (found by a user test of the README).
    #[test]
    fn the_table_shows_the_updates_around_the_last_task_change() {
        let table = summary_table(&[a1(1, 3)]);
        let mut lines = table.lines();
        let header = lines.next().unwrap();
        assert!(
            header.contains("| eval cost u=0 | u=0 | u=1 | last | expl. std u=0 | λ u=0 | λ u=0 |"),
            "{table}"
        );
        let row = lines.nth(1).unwrap();
        assert!(!row.contains('–'), "{table}");

        // Configs changing at different updates: the header cannot name them.
        let table = summary_table(&[a1(1, 3), a1(2, 3)]);
        assert!(
            table.contains("| before change | at change | last | expl. std before change |"),
            "{table}"
        );
        assert_eq!(table.matches("(u=0)").count(), 3, "{table}");
        assert_eq!(table.matches("(u=2)").count(), 1, "{table}");
    }

    /// A run stopped (Ctrl-C) or ended before its task change said "not re-converged", as if it
    /// had failed to re-learn a change it never saw (found by a user test of the README).
    #[test]
    fn a_run_that_ends_before_its_change_is_not_called_unconverged() {
        let r = a1(5, 3);
        let table = summary_table(std::slice::from_ref(&r));
        assert!(
            table.contains("| change (u=5) not reached |") && !table.contains("not re-converged"),
            "{table}"
        );
        // The reference the column is measured against is printed, with the numbering.
        let notes = summary_notes(std::slice::from_ref(&r));
        let reference = fmt(r.optimum_after_change.unwrap());
        assert!(
            notes.contains("counted from 0") && notes.ends_with(&format!("A1 {reference}\n")),
            "{notes}"
        );
    }

    /// The reference optimum of re-convergence is the task's, whatever the config that learned
    /// it: a search along the axes stopped wherever it met the via-point's valley, 63.44 for
    /// C1's sessions and 63.25 for A2's, the same task after the same change.
    #[test]
    fn every_config_of_a_task_gets_the_same_reference_optimum() {
        let reference = |name: &str| {
            let path =
                Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../config/{name}.toml"));
            run_config(&RunConfig::load(&path).unwrap(), 10)
                .unwrap()
                .optimum_after_change
                .unwrap()
        };
        let (c1, a2) = (reference("C1"), reference("A2"));
        assert!((c1 - a2).abs() < 1e-6, "C1 {c1}, A2 {a2}");
    }
}
