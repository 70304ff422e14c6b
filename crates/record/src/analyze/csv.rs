//! CSV export: a file per topic of one recording ([`export_csv`]), floats in their shortest
//! exact form, and the streaming [`Csv`] writer that the experiment's tables use too. It
//! neither draws nor aggregates: a row is one recorded message, or one rollout of an update.

use std::path::{Path, PathBuf};

use super::info::describe_hp;
use super::io;
use crate::{proto, Decoded, RecordError, Recording};

pub(super) fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

pub(super) fn f(v: f64) -> String {
    // Shortest representation that round-trips exactly.
    format!("{v:?}")
}

fn ts(t: &Option<prost_types::Timestamp>) -> String {
    t.map(|t| (t.seconds as i128 * 1_000_000_000 + t.nanos as i128).to_string())
        .unwrap_or_default()
}

/// A CSV file written as its rows come (an `update_rollouts.csv` can outgrow the RAM). The
/// first write error is kept and returned by [`Csv::write`].
pub(super) struct Csv {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    error: Option<std::io::Error>,
}

impl Csv {
    pub(super) fn new(dir: &Path, name: &str, header: &[String]) -> Result<Self, RecordError> {
        let path = dir.join(name);
        let file = std::fs::File::create(&path).map_err(io(&path))?;
        let mut csv = Self {
            out: std::io::BufWriter::with_capacity(1 << 20, file),
            path,
            error: None,
        };
        csv.row(header.to_vec());
        Ok(csv)
    }
    pub(super) fn row(&mut self, cells: Vec<String>) {
        use std::io::Write as _;
        if self.error.is_none() {
            if let Err(e) = writeln!(self.out, "{}", cells.join(",")) {
                self.error = Some(e);
            }
        }
    }
    pub(super) fn write(mut self) -> Result<PathBuf, RecordError> {
        use std::io::Write as _;
        match self.error.take() {
            Some(e) => Err(e),
            None => self.out.flush(),
        }
        .map_err(io(&self.path))?;
        Ok(self.path)
    }
}

/// The columns `update.csv` and `summary.csv` begin with: an update's costs and λ.
const SUMMARY_COLUMNS: [&str; 7] = [
    "timestamp_ns",
    "update",
    "eval_cost",
    "exploration_cost_mean",
    "exploration_cost_std",
    "lambda",
    "lambda_next",
];

/// The [`SUMMARY_COLUMNS`] of an update's summary.
fn summary_cells(s: &proto::UpdateSummary) -> Vec<String> {
    vec![
        ts(&s.timestamp),
        s.update.to_string(),
        f(s.eval_cost),
        f(s.exploration_cost_mean),
        f(s.exploration_cost_std),
        f(s.lambda),
        f(s.lambda_next),
    ]
}

fn names(prefix: &str, n: usize) -> Vec<String> {
    (0..n).map(|i| format!("{prefix}{i}")).collect()
}

/// Writes one CSV per topic into `dir` (created if needed): `run.csv`, `update.csv` (scalars,
/// means and covariances before/after), `update_rollouts.csv` (one row per update and rollout:
/// weight, costs, θ), `summary.csv`, `rollout.csv`, `task_change.csv`, `log.csv`. Floats are
/// written in their shortest exact form.
pub fn export_csv(rec: &Recording, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let p = rec
        .run_info()
        .map(|r| r.dim as usize)
        .unwrap_or_else(|| rec.updates.first().map(|u| u.dim as usize).unwrap_or(0));
    let steps = rec.updates.first().map(|u| u.steps as usize).unwrap_or(0);

    let mut run = Csv::new(
        dir,
        "run.csv",
        &[
            "timestamp_ns",
            "update",
            "name",
            "seed",
            "dim",
            "steps",
            "rollouts",
            "executor",
            "hyperparameters",
        ]
        .map(String::from),
    )?;
    for r in &rec.run {
        let hp = r.hyperparameters.unwrap_or_default();
        run.row(vec![
            ts(&r.timestamp),
            r.update.to_string(),
            csv_field(&r.name),
            r.seed.to_string(),
            r.dim.to_string(),
            r.steps.to_string(),
            hp.rollouts.to_string(),
            csv_field(&r.executor),
            csv_field(&describe_hp(&hp)),
        ]);
    }
    files.push(run.write()?);

    let mut header: Vec<String> = SUMMARY_COLUMNS.map(String::from).to_vec();
    header.extend(["batch_start_ns", "batch_end_ns"].map(String::from));
    header.extend(names("before_mean_", p));
    header.extend(names("after_mean_", p));
    header.extend(names("before_cov_", p * p));
    header.extend(names("after_cov_", p * p));
    let mut upd = Csv::new(dir, "update.csv", &header)?;
    let mut header: Vec<String> = ["update", "rollout", "weight", "total_cost", "terminal_cost"]
        .map(String::from)
        .to_vec();
    header.extend(names("theta_", p));
    header.extend(names("cost_step_", steps));
    let mut rol = Csv::new(dir, "update_rollouts.csv", &header)?;
    let mut header: Vec<String> = SUMMARY_COLUMNS.map(String::from).to_vec();
    header.extend(names("mean_next_", p));
    let mut sum = Csv::new(dir, "summary.csv", &header)?;
    let mut ro = Csv::new(
        dir,
        "rollout.csv",
        &[
            "timestamp_ns",
            "update",
            "rollout",
            "worker",
            "start_ns",
            "end_ns",
            "total_cost",
        ]
        .map(String::from),
    )?;
    let mut lg = Csv::new(
        dir,
        "log.csv",
        &[
            "timestamp_ns",
            "update",
            "level",
            "event",
            "name",
            "pid",
            "message",
        ]
        .map(String::from),
    )?;
    // One pass over the files for a recording read slim: its messages are not in memory.
    rec.for_each_message(|m| {
        match m {
            Decoded::Update(u) => update_rows(u, &mut upd, &mut rol),
            Decoded::Summary(s) => {
                let mut row = summary_cells(s);
                row.extend(s.mean.iter().map(|x| f(*x)));
                sum.row(row);
            }
            Decoded::Rollout(r) => ro.row(vec![
                ts(&r.timestamp),
                r.update.to_string(),
                r.rollout.to_string(),
                csv_field(&r.worker),
                r.start_ns.to_string(),
                r.end_ns.to_string(),
                f(r.total_cost),
            ]),
            Decoded::Log(l) => {
                let level = proto::foxglove::log::Level::try_from(l.level)
                    .map(|v| v.as_str_name().to_string())
                    .unwrap_or_else(|_| l.level.to_string());
                lg.row(vec![
                    ts(&l.timestamp),
                    l.update.to_string(),
                    level,
                    csv_field(&l.event),
                    csv_field(&l.name),
                    l.pid.to_string(),
                    csv_field(&l.message),
                ]);
            }
        }
        Ok(())
    })?;
    files.push(upd.write()?);
    files.push(rol.write()?);
    files.push(sum.write()?);
    files.push(ro.write()?);

    let mut tc = Csv::new(
        dir,
        "task_change.csv",
        &["timestamp_ns", "update", "name", "value"].map(String::from),
    )?;
    for c in &rec.task_changes {
        tc.row(vec![
            ts(&c.timestamp),
            c.update.to_string(),
            csv_field(&c.name),
            f(c.value),
        ]);
    }
    files.push(tc.write()?);
    files.push(lg.write()?);
    Ok(files)
}

/// The `update.csv` row and the `update_rollouts.csv` rows of one update.
fn update_rows(u: &proto::Update, upd: &mut Csv, rol: &mut Csv) {
    let mut row = summary_cells(&crate::reader::curve_row(u));
    row.extend([u.batch_start_ns.to_string(), u.batch_end_ns.to_string()]);
    let (b, a) = (
        u.before.clone().unwrap_or_default(),
        u.after.clone().unwrap_or_default(),
    );
    for v in [&b.mean, &a.mean, &b.covariance, &a.covariance] {
        row.extend(v.iter().map(|x| f(*x)));
    }
    upd.row(row);
    let (k, pd, n) = (u.rollouts as usize, u.dim as usize, u.steps as usize);
    for r in 0..k {
        let step = u.cost_per_step.get(r * n..(r + 1) * n).unwrap_or(&[]);
        let terminal = u.cost_terminal.get(r).copied().unwrap_or(f64::NAN);
        // Recorded without step costs (`recording.step_costs = false`), the total is what is
        // left of them; older recordings have no `cost_total`.
        let total = match u.cost_total.get(r) {
            Some(t) if step.is_empty() => *t,
            _ => pi2cma::total_cost(step, terminal),
        };
        let mut row = vec![
            u.update.to_string(),
            r.to_string(),
            f(u.weights.get(r).copied().unwrap_or(f64::NAN)),
            f(total),
            f(terminal),
        ];
        row.extend(
            u.samples
                .get(r * pd..(r + 1) * pd)
                .unwrap_or(&[])
                .iter()
                .map(|x| f(*x)),
        );
        row.extend(step.iter().map(|x| f(*x)));
        // No step costs: empty cells, so that every row has the header's columns.
        row.resize(row.len() + n - step.len(), String::new());
        rol.row(row);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_fields_are_quoted_and_floats_exact() {
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
        let v = 0.1 + 0.2;
        assert_eq!(f(v).parse::<f64>().unwrap().to_bits(), v.to_bits());
    }

    /// `total_cost` is S_0 as the update used it (the eval cost of rollout 0, `/rollout`'s
    /// total): the CSV summed the step costs in an order of its own, and 507 of the 600 rows of
    /// a recorded A1 run differed from `rollout.csv` in the last digits.
    #[test]
    fn update_rollouts_total_cost_is_the_updates() {
        let (steps, terminal) = ([1.0, 1e16, -1e16, 1.0, 0.5], 0.25);
        let mut batch = pi2cma::CostBatch::new(1, steps.len());
        batch.insert(0, &steps, terminal).unwrap();
        let u = proto::Update {
            rollouts: 1,
            dim: 1,
            steps: steps.len() as u32,
            samples: vec![0.0],
            cost_per_step: steps.to_vec(),
            cost_terminal: vec![terminal],
            weights: vec![1.0],
            ..Default::default()
        };
        let dir = std::env::temp_dir().join(format!("csv-total-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (mut upd, mut rol) = (
            Csv::new(&dir, "update.csv", &[]).unwrap(),
            Csv::new(&dir, "update_rollouts.csv", &[]).unwrap(),
        );
        update_rows(&u, &mut upd, &mut rol);
        // Recorded without step costs: the recorded total, and empty step cells.
        let light = proto::Update {
            cost_per_step: Vec::new(),
            cost_total: vec![batch.total(0)],
            ..u.clone()
        };
        update_rows(&light, &mut upd, &mut rol);
        let path = rol.write().unwrap();
        let text = std::fs::read_to_string(path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let cells = |line: usize| -> Vec<String> {
            let row = text.lines().nth(line).unwrap();
            row.split(',').map(str::to_owned).collect()
        };
        assert_eq!(cells(1)[3], f(batch.total(0)), "{text}");
        assert_eq!(cells(2)[3], f(batch.total(0)), "{text}");
        assert_eq!(cells(2).len(), cells(1).len(), "{text}");
        assert!(cells(2)[6..].iter().all(String::is_empty), "{text}");
    }
}
