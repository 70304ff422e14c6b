//! The TOML run configuration. Every key is known (unknown ones are rejected), every value is
//! range-checked, and every error names the file, the field and the value.

use std::path::{Path, PathBuf};

use pi2cma::{
    CostMapping, EigenvalueBounds, Exploration, Hyperparameters, TemporalAveraging, Weighting,
};
use serde::Deserialize;
use tasks::{TaskChange, TaskSchedule, ViaPointSpec};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: cannot read: {reason}")]
    Read { file: PathBuf, reason: String },
    #[error("{file}: {message}")]
    Parse { file: PathBuf, message: String },
    #[error("{file}: {field} = {value}: {reason}")]
    Invalid {
        file: PathBuf,
        field: String,
        value: String,
        reason: String,
    },
}

/// A whole run: what to learn, with which update rule, for how long.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    pub run: RunSection,
    pub optimizer: OptimizerSection,
    pub task: TaskSection,
    /// Task changes at given updates (e.g. the via-point moving from 0.3 to 0.1 after update 20).
    #[serde(default)]
    pub schedule: Vec<ScheduleEntry>,
    /// How the multiprocess pipeline (`supervisor run`) runs this config; the in-process runner
    /// ignores it. Absent means [`PipelineSection::default`].
    #[serde(default)]
    pub pipeline: Option<PipelineSection>,
    /// How the run's MCAP recording is written (both executors). Absent: one file.
    #[serde(default)]
    pub recording: Option<RecordingSection>,
    /// Where the file came from, for error messages; not a TOML key.
    #[serde(skip)]
    pub origin: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// A label for results and figures (e.g. "A1").
    pub name: String,
    /// Seed of session 0; session s of an experiment uses seed + s.
    pub seed: u64,
    /// Number of updates; absent means unbounded (continual learning, stopped from outside).
    pub updates: Option<u64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Cross-Entropy Method: elites, covariance around the old mean.
    Cem,
    /// PI² with constant exploration Σ = λ·I.
    Pi2,
    /// PI² with decaying exploration Σ ← D·Σ.
    Pi2Decay,
    /// PI²-CMA: PI² weights, covariance adaptation, boundcovar.
    Pi2Cma,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WeightingName {
    Episodic,
    PerTimeStep,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TemporalName {
    RemainingSteps,
    BasisActivation,
}

/// The update rule. Method-specific keys are rejected for the other methods, so a setting that
/// would be silently ignored is an error instead.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerSection {
    pub method: Method,
    /// K, including the noise-free evaluation rollout 0.
    pub rollouts: usize,
    /// Whether rollout 0 enters the update (the authors' 2012 code) or only evaluates.
    pub evaluation_in_update: bool,
    pub weighting: WeightingName,
    /// Only with `weighting = "per-time-step"`; default "remaining-steps" (Algorithm 1).
    pub temporal_averaging: Option<TemporalName>,
    /// Σ_init = λ_init·I.
    pub lambda_init: f64,
    /// h, for the PI² methods.
    pub eliteness: Option<f64>,
    /// K_e, for CEM.
    pub elites: Option<usize>,
    /// D, for pi2-decay.
    pub decay: Option<f64>,
    /// Eigenvalue bounds, for pi2-cma (required) and cem (optional, default unbounded).
    pub lambda_min: Option<f64>,
    pub lambda_max: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "kebab-case")]
pub enum TaskSection {
    ViaPoint(ViaPointConfig),
    /// `[task.tball]`: the T-ball task of Section IV-B (keys documented in `tball::TballConfig`).
    Tball(Box<tball::TballConfig>),
    /// `[task.external]`: a task of the user's own, whose rollouts run in their own rollout
    /// workers (`worker`, see `pipeline::worker::serve`); only the pipeline can run it.
    External(ExternalConfig),
}

/// `[task.external]`: what the update side needs to know of a task whose policy and cost live
/// in the user's own rollout worker.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalConfig {
    /// The command that runs one rollout worker: program, then arguments. The supervisor appends
    /// `--config FILE --run-dir DIR --run-id HEX --worker W --incarnation I`. A program path
    /// with a `/` is relative to this config file's directory; a bare name is looked up in PATH.
    pub worker: Vec<String>,
    /// P: the length of θ.
    pub parameters: usize,
    /// N: the number of immediate costs of a rollout.
    pub steps: usize,
    /// The initial mean of the search distribution (P values).
    pub initial_mean: Vec<f64>,
    /// Named task settings that task changes (`[[schedule]]`, `supervisor set`) may change, with
    /// their initial values. They reach the worker with every work item, in the alphabetical
    /// order of their names.
    #[serde(default)]
    pub settings: std::collections::BTreeMap<String, f64>,
    /// The policy's basis activations: `steps` rows of `parameters` non-negative numbers, ψ of
    /// parameter j's basis function at step i. Needed for `temporal_averaging =
    /// "basis-activation"`, which the update side cannot compute for a policy that runs
    /// elsewhere; in the config, so that the recorded config reruns the run.
    #[serde(default)]
    pub basis_activations: Option<Vec<Vec<f64>>>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViaPointConfig {
    pub basis_functions: usize,
    pub duration: f64,
    pub dt: f64,
    pub start: f64,
    pub goal: f64,
    pub viapoint: f64,
    pub viapoint_time: f64,
    pub viapoint_weight: f64,
    /// Each rollout blocks at least this long (a stand-in for a robot or external simulator).
    #[serde(default)]
    pub rollout_delay_ms: f64,
}

impl ViaPointConfig {
    pub fn spec(&self) -> ViaPointSpec {
        ViaPointSpec {
            basis_functions: self.basis_functions,
            duration: self.duration,
            dt: self.dt,
            start: self.start,
            goal: self.goal,
            viapoint: self.viapoint,
            viapoint_time: self.viapoint_time,
            viapoint_weight: self.viapoint_weight,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleEntry {
    /// The first update (0-based) that sees the new value.
    pub from_update: u64,
    pub set: String,
    pub value: f64,
}

/// Settings of the run's MCAP recording (crate `record`).
#[derive(Debug, Clone, PartialEq, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingSection {
    /// Split the recording into parts of about this many MB (messages before compression): a
    /// continual run's recording is then a series of finished, indexed files rather than one
    /// that grows without end. Unset: one file.
    pub split_mb: Option<u64>,
}

/// Settings of the multiprocess pipeline (crates `wire`, `pipeline`, `supervisor`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineSection {
    /// Rollout workers started with the run (changeable at runtime with `supervisor scale`).
    pub workers: usize,
    /// The most workers the run may scale to; sizes the shared-memory services.
    pub max_workers: usize,
    /// Worker restarts allowed within `restart_window_s`; one more fails the run.
    pub restart_limit: u32,
    pub restart_window_s: f64,
    /// Bound on each process's readiness handshake at start.
    pub startup_timeout_ms: u64,
    /// Bound on an orderly shutdown; then the whole group is killed.
    pub shutdown_timeout_ms: u64,
    /// Longest a rollout worker polls for its next work before it blocks (adaptive, see
    /// `pipeline::Spin`); 0 never polls.
    pub worker_spin_us: u64,
    /// Longest a worker may hold a chunk, per rollout in it; a worker over it is taken to hang
    /// (a simulator or robot that stopped answering), is killed and restarted, and its
    /// rollouts go to the others. Unset: no limit (a rollout may take any time).
    pub rollout_timeout_ms: Option<u64>,
    /// FAULT INJECTION, for tests only: from this update on, workers report NaN costs.
    pub fault_nan_from_update: Option<u64>,
    /// FAULT INJECTION, for tests only: the first incarnation of every worker stops answering
    /// (sleeps instead of running its chunk) at its first chunk of this update or a later one;
    /// restarted workers do not.
    pub fault_hang_at_update: Option<u64>,
}

impl PipelineSection {
    /// The largest `max_workers` the wire layout supports.
    pub const WORKER_LIMIT: usize = 256;
}

impl Default for PipelineSection {
    fn default() -> Self {
        Self {
            workers: 3,
            max_workers: 16,
            restart_limit: 5,
            restart_window_s: 60.0,
            startup_timeout_ms: 10_000,
            shutdown_timeout_ms: 5_000,
            worker_spin_us: 200,
            rollout_timeout_ms: None,
            fault_nan_from_update: None,
            fault_hang_at_update: None,
        }
    }
}

/// The built-in default: PI²-CMA on the paper's via-point task (the A1 run), episodic weighting.
pub const DEFAULT_CONFIG: &str = include_str!("default.toml");

impl RunConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with_text(path).map(|(cfg, _)| cfg)
    }

    /// [`RunConfig::load`], and the file's text (which a recording keeps as it is).
    pub fn load_with_text(path: &Path) -> Result<(Self, String), ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
            file: path.to_path_buf(),
            reason: e.to_string(),
        })?;
        Ok((Self::parse(&text, path)?, text))
    }

    pub fn default_config() -> Self {
        Self::parse(DEFAULT_CONFIG, Path::new("<built-in default>"))
            .expect("the built-in default config is valid")
    }

    pub fn parse(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let mut cfg: RunConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            file: origin.to_path_buf(),
            message: e.to_string().trim_end().replace('\n', "\n  "),
        })?;
        cfg.origin = origin.to_path_buf();
        cfg.validate()?;
        Ok(cfg)
    }

    /// `text` with the `run` table's integer fields set as given (command-line options such as
    /// `--updates` and `--seed`; `None` leaves a field as it is), parsed, and that text: what the
    /// run records and hands to its processes, so a recorded config reruns the run that was
    /// made. Comments of `text` are lost if anything is set.
    pub fn with_run_overrides(
        text: &str,
        origin: &Path,
        overrides: &[(&str, Option<u64>)],
    ) -> Result<(Self, String), ConfigError> {
        if overrides.iter().all(|(_, v)| v.is_none()) {
            return Ok((Self::parse(text, origin)?, text.to_string()));
        }
        let parse_error = |e: &dyn std::fmt::Display| ConfigError::Parse {
            file: origin.to_path_buf(),
            message: e.to_string().trim_end().replace('\n', "\n  "),
        };
        let mut table: toml::Table = text.parse().map_err(|e| parse_error(&e))?;
        let run = table
            .entry("run")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let Some(run) = run.as_table_mut() else {
            return Err(parse_error(&"`run` is not a table"));
        };
        for &(field, value) in overrides {
            let Some(value) = value else { continue };
            // TOML integers are i64; a larger value cannot be written, so it is refused here.
            let n = i64::try_from(value).map_err(|_| ConfigError::Invalid {
                file: origin.to_path_buf(),
                field: format!("run.{field}"),
                value: value.to_string(),
                reason: "too large for a TOML integer".into(),
            })?;
            run.insert(field.into(), toml::Value::Integer(n));
        }
        let text = toml::to_string(&table).map_err(|e| parse_error(&e))?;
        Ok((Self::parse(&text, origin)?, text))
    }

    fn invalid(&self, field: &str, value: impl ToString, reason: &str) -> ConfigError {
        ConfigError::Invalid {
            file: self.origin.clone(),
            field: field.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }

    /// Checks every range and cross-field rule; call again after changing fields in code.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let o = &self.optimizer;
        let only = |field: &str, present: bool, methods: &str| -> Result<(), ConfigError> {
            if present {
                Err(self.invalid(
                    &format!("optimizer.{field}"),
                    "(set)",
                    &format!("only applies to method {methods}"),
                ))
            } else {
                Ok(())
            }
        };
        let is_pi2 = o.method != Method::Cem;
        only(
            "eliteness",
            o.eliteness.is_some() && !is_pi2,
            "pi2, pi2-decay, pi2-cma",
        )?;
        only("elites", o.elites.is_some() && is_pi2, "cem")?;
        only(
            "decay",
            o.decay.is_some() && o.method != Method::Pi2Decay,
            "pi2-decay",
        )?;
        let bounded = matches!(o.method, Method::Pi2Cma | Method::Cem);
        only(
            "lambda_min",
            o.lambda_min.is_some() && !bounded,
            "pi2-cma, cem",
        )?;
        only(
            "lambda_max",
            o.lambda_max.is_some() && !bounded,
            "pi2-cma, cem",
        )?;
        only(
            "temporal_averaging",
            o.temporal_averaging.is_some() && o.weighting == WeightingName::Episodic,
            "any, with weighting = \"per-time-step\"",
        )?;
        if is_pi2 && o.eliteness.is_none() {
            return Err(self.invalid(
                "optimizer.eliteness",
                "(missing)",
                "required for PI² methods",
            ));
        }
        if o.method == Method::Cem && o.elites.is_none() {
            return Err(self.invalid("optimizer.elites", "(missing)", "required for cem"));
        }
        if o.method == Method::Pi2Decay && o.decay.is_none() {
            return Err(self.invalid("optimizer.decay", "(missing)", "required for pi2-decay"));
        }
        if o.method == Method::Pi2Cma && (o.lambda_min.is_none() || o.lambda_max.is_none()) {
            return Err(self.invalid(
                "optimizer.lambda_min/lambda_max",
                "(missing)",
                "pi2-cma needs both bounds explicitly (lambda_max = inf for no upper bound)",
            ));
        }
        if !(o.lambda_init.is_finite() && o.lambda_init > 0.0) {
            return Err(self.invalid(
                "optimizer.lambda_init",
                o.lambda_init,
                "must be finite and > 0",
            ));
        }
        if let (Some(lo), Some(hi)) = (o.lambda_min, o.lambda_max) {
            if !(lo <= o.lambda_init && o.lambda_init <= hi) {
                return Err(self.invalid(
                    "optimizer.lambda_init",
                    o.lambda_init,
                    "must lie within [lambda_min, lambda_max]",
                ));
            }
        }
        if o.rollouts > 100_000 {
            return Err(self.invalid("optimizer.rollouts", o.rollouts, "must be at most 100000"));
        }
        self.hyperparameters()
            .check()
            .map_err(|e| self.invalid_param(e))?;
        if self.run.name.trim().is_empty() {
            return Err(self.invalid("run.name", "\"\"", "must not be empty"));
        }
        if self.run.updates == Some(0) {
            return Err(self.invalid("run.updates", 0, "must be at least 1 (omit for unbounded)"));
        }
        let (delay_field, delay_ms) = match &self.task {
            TaskSection::ViaPoint(v) => ("task.via-point.rollout_delay_ms", v.rollout_delay_ms),
            TaskSection::Tball(t) => ("task.tball.rollout_delay_ms", t.rollout_delay_ms),
            TaskSection::External(e) => {
                self.validate_external(e)?;
                ("", 0.0)
            }
        };
        if !(delay_ms.is_finite() && (0.0..=3.6e6).contains(&delay_ms)) {
            return Err(self.invalid(delay_field, delay_ms, "must be between 0 and 3600000"));
        }
        if self.recording.as_ref().and_then(|r| r.split_mb) == Some(0) {
            return Err(self.invalid(
                "recording.split_mb",
                0,
                "must be > 0 (leave it out for one file)",
            ));
        }
        if let Some(p) = &self.pipeline {
            if !(1..=PipelineSection::WORKER_LIMIT).contains(&p.max_workers) {
                return Err(self.invalid(
                    "pipeline.max_workers",
                    p.max_workers,
                    &format!("must be between 1 and {}", PipelineSection::WORKER_LIMIT),
                ));
            }
            if !(1..=p.max_workers).contains(&p.workers) {
                return Err(self.invalid(
                    "pipeline.workers",
                    p.workers,
                    &format!(
                        "must be between 1 and pipeline.max_workers = {}",
                        p.max_workers
                    ),
                ));
            }
            if !(p.restart_window_s.is_finite() && p.restart_window_s > 0.0) {
                return Err(self.invalid(
                    "pipeline.restart_window_s",
                    p.restart_window_s,
                    "must be finite and > 0",
                ));
            }
            if p.worker_spin_us > 100_000 {
                return Err(self.invalid(
                    "pipeline.worker_spin_us",
                    p.worker_spin_us,
                    "must be at most 100000 (0.1 s)",
                ));
            }
            for (field, v) in [
                ("startup_timeout_ms", p.startup_timeout_ms),
                ("shutdown_timeout_ms", p.shutdown_timeout_ms),
            ] {
                if v == 0 {
                    return Err(self.invalid(&format!("pipeline.{field}"), v, "must be > 0"));
                }
            }
            if p.rollout_timeout_ms == Some(0) {
                return Err(self.invalid(
                    "pipeline.rollout_timeout_ms",
                    0,
                    "must be > 0 (leave it out for no limit)",
                ));
            }
        }
        let mut task = self
            .build_task()
            .map_err(|e| self.invalid("task", "", &e.to_string()))?;
        self.schedule()
            .validate(&mut task)
            .map_err(|e| self.invalid("schedule", "", &e.to_string()))?;
        Ok(())
    }

    fn validate_external(&self, e: &ExternalConfig) -> Result<(), ConfigError> {
        if e.worker.first().is_none_or(|p| p.trim().is_empty()) {
            return Err(self.invalid(
                "task.external.worker",
                format!("{:?}", e.worker),
                "must name the program that runs a rollout worker, then its arguments",
            ));
        }
        for (field, v) in [("parameters", e.parameters), ("steps", e.steps)] {
            if !(1..=1_000_000).contains(&v) {
                return Err(self.invalid(
                    &format!("task.external.{field}"),
                    v,
                    "must be between 1 and 1000000",
                ));
            }
        }
        if e.initial_mean.len() != e.parameters {
            return Err(self.invalid(
                "task.external.initial_mean",
                format!("({} values)", e.initial_mean.len()),
                &format!("must have parameters = {} values", e.parameters),
            ));
        }
        if let Some(i) = e.initial_mean.iter().position(|v| !v.is_finite()) {
            return Err(self.invalid(
                &format!("task.external.initial_mean[{i}]"),
                e.initial_mean[i],
                "must be finite",
            ));
        }
        for (name, v) in &e.settings {
            let well_formed = !name.is_empty()
                && name.len() <= 32
                && name
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
            if !well_formed {
                return Err(self.invalid(
                    &format!("task.external.settings.{name}"),
                    v,
                    "a setting name is 1 to 32 of A-Z, a-z, 0-9, _ and -",
                ));
            }
            if !v.is_finite() {
                return Err(self.invalid(
                    &format!("task.external.settings.{name}"),
                    v,
                    "must be finite",
                ));
            }
        }
        if self.external_basis_activations()?.is_none()
            && self.optimizer.temporal_averaging == Some(TemporalName::BasisActivation)
        {
            return Err(self.invalid(
                "task.external.basis_activations",
                "(none)",
                "optimizer.temporal_averaging = \"basis-activation\" needs the policy's basis \
                 activations: `steps` rows of `parameters` values",
            ));
        }
        Ok(())
    }

    /// `[task.external] basis_activations` as row-major N × P, checked, if the config has them.
    pub fn external_basis_activations(&self) -> Result<Option<Vec<f64>>, ConfigError> {
        let TaskSection::External(e) = &self.task else {
            return Ok(None);
        };
        let Some(rows) = &e.basis_activations else {
            return Ok(None);
        };
        let field = "task.external.basis_activations";
        if rows.len() != e.steps {
            return Err(self.invalid(
                field,
                format!("({} rows)", rows.len()),
                &format!("must have steps = {} rows", e.steps),
            ));
        }
        let mut values = Vec::with_capacity(e.steps * e.parameters);
        for (i, row) in rows.iter().enumerate() {
            if row.len() != e.parameters {
                return Err(self.invalid(
                    &format!("{field}[{i}]"),
                    format!("({} values)", row.len()),
                    &format!("must have parameters = {} values", e.parameters),
                ));
            }
            if let Some(j) = row.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
                return Err(self.invalid(
                    &format!("{field}[{i}][{j}]"),
                    row[j],
                    "must be finite and not negative",
                ));
            }
            values.extend_from_slice(row);
        }
        Ok(Some(values))
    }

    /// The program and arguments of an external task's rollout worker, the program resolved
    /// against the config file's directory when it is a path; `None` for built-in tasks.
    pub fn external_worker(&self) -> Option<(PathBuf, Vec<String>)> {
        let TaskSection::External(e) = &self.task else {
            return None;
        };
        let (program, args) = e.worker.split_first()?;
        let program = if program.contains('/') {
            self.origin.parent().unwrap_or(Path::new("")).join(program)
        } else {
            PathBuf::from(program)
        };
        Some((program, args.to_vec()))
    }

    fn invalid_param(&self, e: pi2cma::ParameterError) -> ConfigError {
        match e {
            pi2cma::ParameterError::OutOfRange {
                field,
                value,
                reason,
            } => self.invalid(&format!("optimizer.{field}"), value, reason),
            other => self.invalid("optimizer", "", &other.to_string()),
        }
    }

    pub fn weighting(&self) -> Weighting {
        match self.optimizer.weighting {
            WeightingName::Episodic => Weighting::Episodic,
            WeightingName::PerTimeStep => Weighting::PerTimeStep {
                temporal: match self.optimizer.temporal_averaging {
                    None | Some(TemporalName::RemainingSteps) => TemporalAveraging::RemainingSteps,
                    Some(TemporalName::BasisActivation) => TemporalAveraging::BasisActivation,
                },
            },
        }
    }

    /// The core's hyperparameters. Bounds that fail the core's own check are reported by
    /// `validate` before this is used for a run.
    pub fn hyperparameters(&self) -> Hyperparameters {
        let o = &self.optimizer;
        let bounds = EigenvalueBounds {
            min: o.lambda_min.unwrap_or(0.0),
            max: o.lambda_max.unwrap_or(f64::INFINITY),
        };
        Hyperparameters {
            rollouts: o.rollouts,
            mapping: match o.method {
                Method::Cem => CostMapping::Elites {
                    count: o.elites.unwrap_or(0),
                },
                _ => CostMapping::Exponential {
                    eliteness: o.eliteness.unwrap_or(f64::NAN),
                },
            },
            exploration: match o.method {
                Method::Pi2 => Exploration::Constant,
                Method::Pi2Decay => Exploration::Decay {
                    factor: o.decay.unwrap_or(f64::NAN),
                },
                Method::Pi2Cma | Method::Cem => Exploration::Adaptive { bounds },
            },
            weighting: self.weighting(),
            evaluation_in_update: o.evaluation_in_update,
        }
    }

    pub fn schedule(&self) -> TaskSchedule {
        TaskSchedule::new(
            self.schedule
                .iter()
                .map(|s| TaskChange {
                    from_update: s.from_update,
                    name: s.set.clone(),
                    value: s.value,
                })
                .collect(),
        )
    }

    /// The pipeline settings, or their defaults when the config has no `[pipeline]` section.
    pub fn pipeline(&self) -> PipelineSection {
        self.pipeline.clone().unwrap_or_default()
    }

    /// The rollout delay of the task, if any.
    pub fn rollout_delay(&self) -> std::time::Duration {
        let delay_ms = match &self.task {
            TaskSection::ViaPoint(v) => v.rollout_delay_ms,
            TaskSection::Tball(t) => t.rollout_delay_ms,
            TaskSection::External(_) => 0.0,
        };
        std::time::Duration::from_secs_f64(delay_ms / 1e3)
    }

    /// Builds the task without its rollout delay (see [`crate::build_task`] for the full one).
    /// For `[task.external]` this is the task's shape ([`tasks::External`]): enough for the
    /// updater, sampler, recorder and supervisor, which never run rollouts; not runnable.
    pub fn build_task(&self) -> Result<Box<dyn tasks::Task>, tasks::TaskError> {
        match &self.task {
            TaskSection::ViaPoint(v) => Ok(Box::new(tasks::ViaPoint::new(&v.spec())?)),
            TaskSection::Tball(t) => Ok(Box::new(tball::Tball::new(t)?)),
            TaskSection::External(e) => {
                let settings: Vec<(String, f64)> =
                    e.settings.iter().map(|(n, v)| (n.clone(), *v)).collect();
                let task =
                    tasks::External::new(e.parameters, e.steps, e.initial_mean.clone(), &settings)?;
                // Checked by `validate` when the config was loaded.
                let task = match self.external_basis_activations() {
                    Ok(None) => task,
                    Ok(Some(psi)) => task.with_basis_activations(psi)?,
                    Err(e) => {
                        return Err(tasks::TaskError::Invalid {
                            task: "external",
                            reason: e.to_string(),
                        })
                    }
                };
                Ok(Box::new(task))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<RunConfig, ConfigError> {
        RunConfig::parse(text, Path::new("test.toml"))
    }

    #[test]
    fn run_fields_can_be_overridden_in_the_text() {
        let origin = Path::new("a.toml");
        let (cfg, text) = RunConfig::with_run_overrides(
            DEFAULT_CONFIG,
            origin,
            &[("updates", Some(55)), ("seed", Some(7))],
        )
        .unwrap();
        assert_eq!(cfg.run.updates, Some(55));
        let mut expected = RunConfig::default_config();
        expected.run.updates = Some(55);
        expected.run.seed = 7;
        expected.origin = origin.into();
        assert_eq!(cfg, expected);
        assert_eq!(RunConfig::parse(&text, origin).unwrap(), cfg);
        let e = RunConfig::with_run_overrides(DEFAULT_CONFIG, origin, &[("updates", Some(0))])
            .unwrap_err();
        assert!(e.to_string().starts_with("a.toml: run.updates = 0"), "{e}");
        let e = RunConfig::with_run_overrides(DEFAULT_CONFIG, origin, &[("seed", Some(u64::MAX))])
            .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("a.toml: run.seed = 18446744073709551615"),
            "{e}"
        );
    }

    #[test]
    fn default_config_is_valid() {
        let c = RunConfig::default_config();
        assert_eq!(c.optimizer.method, Method::Pi2Cma);
        assert_eq!(c.schedule().changes().len(), 1);
    }

    #[test]
    fn unknown_key_is_rejected_with_file_and_key() {
        let text = DEFAULT_CONFIG.replace("[optimizer]", "[optimizer]\nlamda_min = 3.0");
        let e = parse(&text).unwrap_err().to_string();
        assert!(e.starts_with("test.toml:"), "{e}");
        assert!(e.contains("unknown field `lamda_min`"), "{e}");
    }

    #[test]
    fn out_of_range_values_name_field_and_value() {
        let text = DEFAULT_CONFIG.replace("eliteness = 15.0", "eliteness = -1.0");
        let e = parse(&text).unwrap_err().to_string();
        assert_eq!(
            e,
            "test.toml: optimizer.eliteness = -1: must be finite and > 0"
        );
        let text = DEFAULT_CONFIG.replace("lambda_min = 2.0", "lambda_min = 5000.0");
        let e = parse(&text).unwrap_err().to_string();
        assert!(e.contains("optimizer.lambda_init = 2000"), "{e}");
        let text = DEFAULT_CONFIG.replace("[pipeline]", "[pipeline]\nworker_spin_us = 200000");
        let e = parse(&text).unwrap_err().to_string();
        assert_eq!(
            e,
            "test.toml: pipeline.worker_spin_us = 200000: must be at most 100000 (0.1 s)"
        );
        let text = DEFAULT_CONFIG.replace("[pipeline]", "[pipeline]\nrollout_timeout_ms = 0");
        let e = parse(&text).unwrap_err().to_string();
        assert_eq!(
            e,
            "test.toml: pipeline.rollout_timeout_ms = 0: must be > 0 (leave it out for no limit)"
        );
        let text = DEFAULT_CONFIG.replace("[pipeline]", "[pipeline]\nrollout_timeout_ms = 500");
        assert_eq!(
            parse(&text).unwrap().pipeline().rollout_timeout_ms,
            Some(500)
        );
    }

    #[test]
    fn settings_of_other_methods_are_rejected() {
        let text = DEFAULT_CONFIG.replace("[optimizer]", "[optimizer]\ndecay = 0.8");
        let e = parse(&text).unwrap_err().to_string();
        assert!(
            e.contains("optimizer.decay") && e.contains("pi2-decay"),
            "{e}"
        );
    }

    #[test]
    fn bad_schedule_setting_is_rejected() {
        let text = DEFAULT_CONFIG.replace("set = \"viapoint\"", "set = \"goal\"");
        let e = parse(&text).unwrap_err().to_string();
        assert!(
            e.contains("schedule") && e.contains("no setting `goal`"),
            "{e}"
        );
    }

    #[test]
    fn tball_config_parses_and_rejects_unknown_keys() {
        let text = include_str!("../../../config/tball.toml");
        let c = parse(text).unwrap();
        assert!(matches!(c.task, TaskSection::Tball(_)));
        assert_eq!(c.build_task().unwrap().name(), "tball");
        let e = parse(&text.replace("[task.tball]", "[task.tball]\nbat_radiu = 0.1"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown field `bat_radiu`"), "{e}");
        let e = parse(&text.replace("set = \"ball_height\"", "set = \"ball_hight\""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no setting `ball_hight`"), "{e}");
    }

    #[test]
    fn external_task_declares_its_shape_and_worker_and_is_checked() {
        let text = include_str!("../../../config/external-reach.toml");
        let c = RunConfig::parse(text, Path::new("config/external-reach.toml")).unwrap();
        let t = c.build_task().unwrap();
        assert_eq!((t.name(), t.parameters(), t.steps()), ("external", 10, 101));
        assert_eq!(t.settings(), vec![("target_x", 0.30), ("target_y", 0.70)]);
        let (program, args) = c.external_worker().unwrap();
        assert_eq!(
            program,
            Path::new("config/../target/release/examples/reach-worker")
        );
        assert!(args.is_empty());
        // Not runnable in process, and the error says where it runs.
        let e = crate::build_task(&c).err().unwrap().to_string();
        assert!(
            e.contains("supervisor run config/external-reach.toml"),
            "{e}"
        );

        for (from, to, expect) in [
            (
                "parameters = 10",
                "parameters = 10\nparameter = 3",
                "unknown field `parameter`",
            ),
            (
                "parameters = 10",
                "parameters = 11",
                "task.external.initial_mean = (10 values)",
            ),
            (
                "target_x = 0.30",
                "\"target x\" = 0.30",
                "task.external.settings.target x",
            ),
            (
                "target_x = 0.30",
                "target_x = nan",
                "task.external.settings.target_x = NaN",
            ),
            (
                "set = \"target_y\"",
                "set = \"target_z\"",
                "no setting `target_z`",
            ),
            (
                "worker = [\"../target/release/examples/reach-worker\"]",
                "worker = []",
                "task.external.worker = []",
            ),
        ] {
            assert!(text.contains(from), "{from}");
            let e = parse(&text.replacen(from, to, 1)).unwrap_err().to_string();
            assert!(e.contains(expect), "{expect}: {e}");
        }
        // A bare program name is looked up in PATH, not next to the config.
        let c = parse(&text.replace("../target/release/examples/reach-worker", "my-sim")).unwrap();
        assert_eq!(c.external_worker().unwrap().0, Path::new("my-sim"));
    }

    #[test]
    fn external_basis_activations_have_the_declared_shape() {
        // The reach example shrunk to P = 2, N = 3.
        let text: String = include_str!("../../../config/external-reach.toml")
            .lines()
            .map(|l| match l {
                "parameters = 10" => "parameters = 2",
                "steps = 101" => "steps = 3",
                l if l.starts_with("initial_mean = ") => "initial_mean = [0.0, 0.0]",
                l => l,
            })
            .collect::<Vec<_>>()
            .join("\n");
        let with = |rows: &str| {
            text.replace(
                "[task.external.settings]",
                &format!("basis_activations = {rows}\n\n[task.external.settings]"),
            )
        };
        let per_time_step = text.replace(
            "weighting = \"episodic\"",
            "weighting = \"per-time-step\"\ntemporal_averaging = \"basis-activation\"",
        );
        let e = parse(&per_time_step).unwrap_err().to_string();
        assert!(
            e.contains("task.external.basis_activations = (none): optimizer.temporal_averaging"),
            "{e}"
        );
        assert_eq!(
            parse(&text)
                .unwrap()
                .build_task()
                .unwrap()
                .basis_activations(),
            None
        );
        let c = parse(&with("[[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]]")).unwrap();
        assert_eq!(
            c.build_task().unwrap().basis_activations(),
            Some(vec![1.0, 0.0, 0.5, 0.5, 0.0, 1.0])
        );
        for (rows, expect) in [
            (
                "[[1.0, 0.0], [0.5, 0.5]]",
                "task.external.basis_activations = (2 rows): must have steps = 3 rows",
            ),
            (
                "[[1.0, 0.0], [0.5], [0.0, 1.0]]",
                "task.external.basis_activations[1] = (1 values): must have parameters = 2",
            ),
            (
                "[[1.0, 0.0], [0.5, -0.5], [0.0, 1.0]]",
                "task.external.basis_activations[1][1] = -0.5: must be finite and not negative",
            ),
            (
                "[[1.0, 0.0], [0.5, nan], [0.0, 1.0]]",
                "task.external.basis_activations[1][1] = NaN",
            ),
        ] {
            let e = parse(&with(rows)).unwrap_err().to_string();
            assert!(
                e.starts_with("test.toml: ") && e.contains(expect),
                "{expect}: {e}"
            );
        }
    }

    #[test]
    fn malformed_toml_names_file() {
        let e = parse("[run\nname=").unwrap_err().to_string();
        assert!(e.starts_with("test.toml: "), "{e}");
    }
}
