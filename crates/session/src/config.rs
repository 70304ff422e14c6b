//! The TOML run configuration. Every key is known (unknown ones are rejected), every value is
//! range-checked, and every error names the file, the field and the value.

use std::path::{Path, PathBuf};

use pi2cma::{
    CostMapping, CovarianceStructure, EigenvalueBounds, Exploration, Hyperparameters,
    TemporalAveraging, Weighting,
};
use serde::Deserialize;
use tasks::{TaskChange, TaskSchedule, ViaPointSpec};

/// Why a config was refused. Each names where it came from and what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{file}: cannot read: {reason}")]
    Read {
        /// The config file.
        file: PathBuf,
        /// The system's reason.
        reason: String,
    },
    /// Not TOML, or not this schema: a syntax error, a missing or unknown key, a value of the
    /// wrong type.
    #[error("{file}: {message}")]
    Parse {
        /// The config file (or the name given to [`RunConfig::parse`]).
        file: PathBuf,
        /// The parser's message, led by the key's path where it is known.
        message: String,
    },
    /// A value of the right type out of range, or values that do not go together.
    #[error("{file}: {field} = {value}: {reason}")]
    Invalid {
        /// The config file.
        file: PathBuf,
        /// The key's path, e.g. `optimizer.lambda_min`.
        field: String,
        /// The value given, as written.
        value: String,
        /// What it must be, and why.
        reason: String,
    },
    /// A value given as a command-line option (`--updates 0`): the user typed it, so the error
    /// names the option, not a field of a file that does not hold it.
    #[error("{option} {value}: {reason}")]
    Option {
        /// The option, e.g. `--updates`.
        option: String,
        /// The value given.
        value: String,
        /// What it must be.
        reason: String,
    },
}

impl ConfigError {
    /// This error as one of `option` if it is about `field`, which that option set.
    pub fn of_option(self, field: &str, option: &str) -> Self {
        match self {
            ConfigError::Invalid {
                field: f,
                value,
                reason,
                ..
            } if f == field => ConfigError::Option {
                option: option.to_string(),
                value,
                reason,
            },
            e => e,
        }
    }
}

/// The command-line option that sets the `run` field `field` (`--updates` for `updates`).
fn option_of(field: &str) -> String {
    format!("--{}", field.replace('_', "-"))
}

/// A whole run: what to learn, with which update rule, for how long.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// `[run]`: name, seed, number of updates.
    pub run: RunSection,
    /// `[optimizer]`: the method and its hyperparameters.
    pub optimizer: OptimizerSection,
    /// `[task.…]`: which task, with its parameters.
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
    /// The `run` fields the command line set (`updates`, `seed`): their values are in no file,
    /// so messages about them name the option ([`RunConfig::option_setting`]); not a TOML key.
    #[serde(skip)]
    pub set_by_options: Vec<String>,
}

/// `[run]`: what a run is called, its seed and length, and how it treats non-finite costs.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSection {
    /// A label for results and figures (e.g. "A1").
    pub name: String,
    /// Seed of session 0; session s of an experiment uses seed + s.
    pub seed: u64,
    /// Number of updates; absent means unbounded (continual learning, stopped from outside).
    pub updates: Option<u64>,
    /// How often a rollout that reports a non-finite cost (NaN, ±∞: a sensor dropout, a
    /// diverged simulator step) is run again with the same parameters before the run fails; the
    /// update waits for it. 0: the first such cost fails the run.
    #[serde(default)]
    pub nonfinite_reruns: u32,
    /// FAULT INJECTION, for tests only: the first execution of this rollout (without `rollout`:
    /// of every rollout of the update; without `update` too: of every rollout of every update)
    /// reports a NaN terminal cost, its reruns what the task computes (a transient fault; both
    /// executors).
    #[serde(default)]
    pub fault_nan_first_attempt: Option<RolloutAt>,
}

/// One rollout of one update (`{ update = 3, rollout = 2 }`), all of an update's
/// (`{ update = 3 }`), or all rollouts of all updates (`{}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RolloutAt {
    /// The update (0-based); absent: every update.
    #[serde(default)]
    pub update: Option<u64>,
    /// The rollout (0: the evaluation); absent: every rollout.
    #[serde(default)]
    pub rollout: Option<usize>,
}

impl RunSection {
    /// Whether the fault injection `fault_nan_first_attempt` turns this execution of rollout
    /// `rollout` of update `update` (`rerun`: not its first) into a NaN terminal cost.
    pub fn fault_nan(&self, update: u64, rollout: usize, rerun: bool) -> bool {
        !rerun
            && self.fault_nan_first_attempt.is_some_and(|f| {
                f.update.is_none_or(|u| u == update) && f.rollout.is_none_or(|k| k == rollout)
            })
    }
}

/// `optimizer.method`: which update rule ([`RunConfig::hyperparameters`] maps it to the core's).
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

impl Method {
    /// The value of `optimizer.method` that selects it.
    pub fn name(self) -> &'static str {
        match self {
            Method::Cem => "cem",
            Method::Pi2 => "pi2",
            Method::Pi2Decay => "pi2-decay",
            Method::Pi2Cma => "pi2-cma",
        }
    }
}

/// `optimizer.weighting`: how costs become rollout probabilities ([`pi2cma::Weighting`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WeightingName {
    /// `"episodic"`: one probability per rollout, from its total cost.
    Episodic,
    /// `"per-time-step"`: probabilities per step from the cost-to-go (the paper's Algorithm 1),
    /// averaged over time as `temporal_averaging` says.
    PerTimeStep,
}

impl WeightingName {
    /// The value of `optimizer.weighting` that selects it.
    pub fn name(self) -> &'static str {
        match self {
            WeightingName::Episodic => "episodic",
            WeightingName::PerTimeStep => "per-time-step",
        }
    }
}

/// `optimizer.covariance`: the shape of Σ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CovarianceName {
    /// One P×P covariance over all of the policy's parameters.
    #[default]
    Full,
    /// One B×B covariance per DMP dimension (the paper's Σ_init = λ_init·I_B per joint): Σ is
    /// block-diagonal, B = the task's `basis_functions`.
    PerDimension,
}

/// `optimizer.temporal_averaging`: how per-step probabilities are averaged over time
/// ([`pi2cma::TemporalAveraging`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TemporalName {
    /// `"remaining-steps"`: step i weighted by the N − i steps left (Algorithm 1; default).
    RemainingSteps,
    /// `"basis-activation"`: parameter j at step i weighted by (N − i)·ψ_j(t_i), its basis
    /// function's activation (the original PI²); needs the task's basis activations.
    BasisActivation,
}

impl TemporalName {
    /// The value of `optimizer.temporal_averaging` that selects it.
    pub fn name(self) -> &'static str {
        match self {
            TemporalName::RemainingSteps => "remaining-steps",
            TemporalName::BasisActivation => "basis-activation",
        }
    }
}

/// The update rule. Method-specific keys are rejected for the other methods, so a setting that
/// would be silently ignored is an error instead.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimizerSection {
    /// `pi2-cma`, `pi2`, `pi2-decay` or `cem`.
    pub method: Method,
    /// K, including the noise-free evaluation rollout 0.
    pub rollouts: usize,
    /// Whether rollout 0 enters the update (the authors' 2012 code) or only evaluates.
    pub evaluation_in_update: bool,
    /// `episodic` or `per-time-step`.
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
    /// Eigenvalue bounds, for pi2-cma (required) and cem (optional, default unbounded): the
    /// the lower bound on Σ's eigenvalues after an update (0: none).
    pub lambda_min: Option<f64>,
    /// The upper bound on Σ's eigenvalues after an update (`inf`: none); with `lambda_min`.
    pub lambda_max: Option<f64>,
    /// The shape of Σ; default "full".
    #[serde(default)]
    pub covariance: CovarianceName,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, rename_all = "kebab-case")]
/// `[task.…]`: exactly one task section.
pub enum TaskSection {
    /// `[task.via-point]`: the via-point task of Section IV-A.
    ViaPoint(ViaPointConfig),
    /// `[task.tball]`: the T-ball task of Section IV-B (keys documented in `tball::TballConfig`).
    Tball(Box<tball::TballConfig>),
    /// `[task.external]`: a task of the user's own, whose rollouts run in their own rollout
    /// workers (`worker`, see `pipeline::worker::serve`), or in their own process with
    /// [`crate::InProcess::with_task`]; [`crate::InProcess::new`] cannot run it.
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
    #[serde(deserialize_with = "worker_command")]
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

/// `task.external.worker`, a list of strings, whose error for anything else shows the form:
/// `worker = "./my_worker.py"` was refused with only `expected a sequence`.
fn worker_command<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    struct Command;
    impl<'de> serde::de::Visitor<'de> for Command {
        type Value = Vec<String>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str(
                "a list of strings, the program then its arguments, as in \
                 worker = [\"./my_worker.py\"]",
            )
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(
            self,
            mut seq: A,
        ) -> Result<Self::Value, A::Error> {
            let mut words = Vec::new();
            while let Some(word) = seq.next_element()? {
                words.push(word);
            }
            Ok(words)
        }
    }
    d.deserialize_seq(Command)
}

/// `[task.via-point]`: the fields of [`ViaPointSpec`], and a rollout delay.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViaPointConfig {
    /// B, as [`ViaPointSpec::basis_functions`].
    pub basis_functions: usize,
    /// Seconds, as [`ViaPointSpec::duration`].
    pub duration: f64,
    /// Seconds, as [`ViaPointSpec::dt`].
    pub dt: f64,
    /// As [`ViaPointSpec::start`].
    pub start: f64,
    /// As [`ViaPointSpec::goal`].
    pub goal: f64,
    /// The initial value of the `viapoint` setting, as [`ViaPointSpec::viapoint`].
    pub viapoint: f64,
    /// Seconds, as [`ViaPointSpec::viapoint_time`].
    pub viapoint_time: f64,
    /// As [`ViaPointSpec::viapoint_weight`].
    pub viapoint_weight: f64,
    /// Each rollout blocks at least this long (a stand-in for a robot or external simulator).
    #[serde(default)]
    pub rollout_delay_ms: f64,
}

impl ViaPointConfig {
    /// The task's specification (everything but the delay), for [`tasks::ViaPoint::new`].
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

/// `[[schedule]]`: one task change, `{ from_update, set, value }` ([`tasks::TaskChange`]).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleEntry {
    /// The first update (0-based) that sees the new value.
    pub from_update: u64,
    /// The setting's name, as the task lists it ([`tasks::Task::settings`]).
    pub set: String,
    /// Its new value.
    pub value: f64,
}

/// The parts a continual run's recording is split into without `recording.split_mb`
/// ([`RunConfig::recording_split_mb`]), in MB: a part's index is then at most about 20 MB
/// (via-point updates of 13.6 kB); a full-speed via-point recorder levelled off at 74 MB of RSS.
pub const CONTINUAL_SPLIT_MB: u64 = 1024;

/// Settings of the run's MCAP recording (crate `record`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingSection {
    /// Split the recording into parts of about this many MB (messages before compression): a
    /// continual run's recording is then a series of finished, indexed files rather than one
    /// that grows without end. Unset: one file, except for a continual run
    /// ([`RunConfig::recording_split_mb`]).
    pub split_mb: Option<u64>,
    /// Record the K × N step costs of every update (default). `false` keeps each rollout's
    /// terminal and total cost only: files 5–8× smaller and less for the recorder to write,
    /// and with episodic weighting every update is still recomputed exactly from the totals;
    /// refused with per-time-step weighting, whose updates need the step costs.
    pub step_costs: bool,
}

impl Default for RecordingSection {
    fn default() -> Self {
        Self {
            split_mb: None,
            step_costs: true,
        }
    }
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
    /// The sliding window, in seconds, in which `restart_limit` counts restarts.
    pub restart_window_s: f64,
    /// Bound on each process's readiness handshake at start.
    pub startup_timeout_ms: u64,
    /// Bound on an orderly shutdown; then the whole group is killed.
    pub shutdown_timeout_ms: u64,
    /// Longest a rollout worker polls for its next work before it blocks (adaptive, see
    /// `pipeline::Spin`); 0 never polls.
    pub worker_spin_us: u64,
    /// Longest one rollout may take: a worker that holds a chunk and sends no cost for longer
    /// is taken to hang (a simulator or robot that stopped answering), is killed and
    /// restarted, and its rollouts go to the others. Unset: no limit (a rollout may take any
    /// time).
    pub rollout_timeout_ms: Option<u64>,
    /// FAULT INJECTION, for tests only: from this update on, workers report NaN costs.
    pub fault_nan_from_update: Option<u64>,
    /// FAULT INJECTION, for tests only: the first incarnation of every worker stops answering
    /// (sleeps instead of running its chunk) at its first chunk of this update or a later one;
    /// restarted workers do not.
    pub fault_hang_at_update: Option<u64>,
    /// FAULT INJECTION, for tests only: with `fault_hang_at_update`, the rollout of the chunk
    /// (1: its first, the default) in which the worker stops answering, after sending the
    /// costs of those before; a chunk with fewer rollouts runs to its end.
    pub fault_hang_at_chunk_rollout: Option<u32>,
}

impl PipelineSection {
    /// The largest `max_workers` a config may ask for. Not a bound of the wire layout: every
    /// service is sized for `max_workers` (publishers, nodes, buffers: `wire::Limits`), so a
    /// slip such as `max_workers = 10000` would have each process reserve ports and shared
    /// memory for workers that never come. A machine running more than 256 rollout workers
    /// of one run is not one this was written for.
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
            fault_hang_at_chunk_rollout: None,
        }
    }
}

/// The most reruns of a rollout whose costs are not finite (`run.nonfinite_reruns`).
pub const MAX_NONFINITE_RERUNS: u32 = 100;
/// The most rollouts per update: the update keeps four K×K matrices (3.2 GB at K = 10000).
pub const MAX_ROLLOUTS: usize = 10_000;
/// The most policy parameters: the update keeps several P×P covariances and eigen-decomposes
/// them every update.
pub const MAX_PARAMETERS: usize = 5_000;
/// The most time steps of a rollout: about 1000 s at 1 kHz.
pub const MAX_STEPS: usize = 1_000_000;
/// The most work of building a DMP policy (via-point, T-ball): it integrates the DMP once per
/// basis function, N × B² basis-function evaluations.
pub const MAX_DMP_WORK: f64 = 1e8;
/// Basis-function evaluations per second of a DMP's construction (measured: 10⁸ took 3.2–4.4 s
/// for B = 10, 100 and 1000), for the time the error message states.
const DMP_WORK_PER_SECOND: f64 = 3e7;
/// The most memory the run may need ([`RunConfig::memory_need`]).
pub const MEMORY_LIMIT_BYTES: u64 = 4 << 30;
/// The most settings an external task may declare: the pipeline's wire headers carry this many
/// (`wire::MAX_SETTINGS`; crate `pipeline` checks that the two agree).
pub const MAX_EXTERNAL_SETTINGS: usize = 8;
/// The range of every variance λ (λ_init, λ_min unless 0, λ_max unless inf).
pub const LAMBDA_RANGE: (f64, f64) = (1e-50, 1e50);
const LAMBDA_WHY: &str = "λ is a variance of the parameters, and the update squares Σ's entries \
                          (λ² must stay a finite, normal double)";
const PARAMETERS_WHY: &str = "the update keeps several P×P covariances and eigen-decomposes them \
                              every update (at P = 5000: about 1.2 GB, minutes per update)";

/// P and N of a config's task, known without building it.
#[derive(Debug, Clone, PartialEq)]
struct TaskShape {
    section: &'static str,
    parameters: usize,
    steps: usize,
    /// The field (and its value) that sets P, and the one that sets N.
    p_field: (String, String),
    n_field: (String, String),
    /// For a DMP policy: basis functions per dimension, dimensions.
    dmp: Option<(usize, usize)>,
}

/// The memory a run needs at its peak, by what it is for ([`RunConfig::memory_need`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryNeed {
    /// What the memory is for, part by part.
    pub parts: Vec<MemoryPart>,
    /// K.
    pub rollouts: usize,
    /// P.
    pub parameters: usize,
    /// N.
    pub steps: usize,
}

impl MemoryNeed {
    /// In bytes.
    pub fn total(&self) -> f64 {
        self.parts.iter().map(|p| p.bytes).sum()
    }
}

/// One item of a [`MemoryNeed`].
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryPart {
    /// What it holds, e.g. `"P×P covariances"`.
    pub what: &'static str,
    /// Its size in bytes, an upper estimate.
    pub bytes: f64,
    /// Which sizes it grows with, to name the field in an error.
    blame: Blame,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Blame {
    Rollouts,
    Parameters,
    RolloutsSteps,
    RolloutsParameters,
    StepsParameters,
}

/// `program` as an absolute path to an executable file: a path as it is (made absolute, so that
/// it does not depend on the children's working directory), a bare name looked up in PATH.
pub fn resolve_program(program: &Path) -> Option<PathBuf> {
    if program.components().count() > 1 {
        return executable_file(program)
            .then(|| std::path::absolute(program).ok())
            .flatten();
    }
    std::env::split_paths(&std::env::var_os("PATH")?)
        .map(|dir| dir.join(program))
        .find(|p| executable_file(p))
}

/// What is wrong with `program`, a path [`resolve_program`] did not take: a user who forgot
/// `chmod +x` on a script was told only "not an executable file", as for a typo in its name.
fn missing_program(program: &Path) -> String {
    match program.metadata() {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "there is no such file".into(),
        Err(e) => format!("cannot read it ({e})"),
        Ok(m) if m.is_dir() => "a directory".into(),
        Ok(m) if m.is_file() => format!(
            "it has no execute permission (`chmod +x {}`)",
            program.display()
        ),
        Ok(_) => "not a regular file".into(),
    }
}

/// Why an executable file is not a program the supervisor can start: a script without a `#!`
/// line (or an empty file) is handed to /bin/sh by `execvp`, so a Python worker without one
/// died of `Syntax error: word unexpected` from the shell, was restarted up to the restart
/// limit, and nothing named the missing line. `None` for an ELF binary or a `#!` script (and
/// for a file that cannot be read, which the start then reports).
fn unstartable(program: &Path) -> Option<String> {
    use std::io::Read as _;
    let mut head = Vec::with_capacity(64);
    std::fs::File::open(program)
        .ok()?
        .take(64)
        .read_to_end(&mut head)
        .ok()?;
    if head.starts_with(b"#!") || head.starts_with(b"\x7fELF") {
        return None;
    }
    let text = String::from_utf8_lossy(&head);
    let first = text.lines().next().unwrap_or("").trim();
    let cut = if text.contains('\n') { "" } else { "…" };
    let begins = if head.is_empty() {
        "it is empty".to_string()
    } else {
        format!("it begins `{first}{cut}`")
    };
    Some(format!(
        "neither a binary nor a script with a `#!` line ({begins}), which the system would run \
         with /bin/sh: begin the script with its interpreter, e.g. `#!/usr/bin/env python3` \
         (`#!/bin/sh` for a shell script)"
    ))
}

/// Whether `p` is a file that may be executed (some execute bit set).
pub fn executable_file(p: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt as _;
    p.metadata()
        .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
}

// A number as a config would write it: plainly, or with an exponent when it is very large or
// very small (1e-12 rather than 0.000000000001).
use tasks::value_text as num;

/// A task's settings as a TOML inline table, `{viapoint = 0.3}`.
fn settings_text(task: &dyn tasks::Task) -> String {
    format!("{{{}}}", tasks::settings_text(task.settings()))
}

/// Bytes in decimal units, as in "about 7.2 GB".
fn bytes(b: f64) -> String {
    match b {
        b if b >= 1e12 => format!("{:.1} TB", b / 1e12),
        b if b >= 1e9 => format!("{:.1} GB", b / 1e9),
        b if b >= 1e6 => format!("{:.1} MB", b / 1e6),
        b => format!("{:.0} kB", b / 1e3),
    }
}

/// Where a config's bytes stop being UTF-8, for the error. `read_to_string` said only "stream
/// did not contain valid UTF-8", leaving the user to search the file for what a Latin-1 editor
/// (`λ_min`, `° `) or a binary given by mistake put there.
fn not_utf8(bytes: &[u8], e: std::str::Utf8Error) -> String {
    let at = e.valid_up_to();
    let before = &bytes[..at];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let line_start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    // Columns in characters, as the TOML parser's messages count them.
    let column = String::from_utf8_lossy(&before[line_start..])
        .chars()
        .count()
        + 1;
    format!(
        "not UTF-8 text, which TOML must be: byte {at} (0x{:02x}, line {line}, column {column}) \
         is not valid UTF-8 (a file saved in another encoding, such as Latin-1, or not a config)",
        bytes[at]
    )
}

/// The built-in default: PI²-CMA on the paper's via-point task (the A1 run), episodic weighting.
pub const DEFAULT_CONFIG: &str = include_str!("default.toml");

impl RunConfig {
    /// Reads and checks the config file at `path` ([`RunConfig::parse`]); errors name `path`.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        Self::load_with_text(path).map(|(cfg, _)| cfg)
    }

    /// [`RunConfig::load`], and the file's text (which a recording keeps as it is).
    pub fn load_with_text(path: &Path) -> Result<(Self, String), ConfigError> {
        let read = |reason: String| ConfigError::Read {
            file: path.to_path_buf(),
            reason,
        };
        let bytes = std::fs::read(path).map_err(|e| read(e.to_string()))?;
        let text =
            String::from_utf8(bytes).map_err(|e| read(not_utf8(e.as_bytes(), e.utf8_error())))?;
        Ok((Self::parse(&text, path)?, text))
    }

    /// [`DEFAULT_CONFIG`], parsed: PI²-CMA on the paper's via-point task (run A1).
    pub fn default_config() -> Self {
        Self::parse(DEFAULT_CONFIG, Path::new("<built-in default>"))
            .expect("the built-in default config is valid")
    }

    /// Parses and checks a config's TOML `text`; `origin` is the file it came from, which
    /// errors name and relative paths (`task.external.worker`) are resolved against. Unknown
    /// keys, values out of range, method-specific keys of another method and a run that would
    /// need more than [`MEMORY_LIMIT_BYTES`] are refused; for a built-in task, so are settings
    /// and scheduled changes under which the initial mean's costs are not finite.
    pub fn parse(text: &str, origin: &Path) -> Result<Self, ConfigError> {
        let mut cfg: RunConfig = toml::from_str(text).map_err(|e| {
            Self::task_sections_error(text, origin).unwrap_or_else(|| {
                let message = e.to_string().trim_end().replace('\n', "\n  ");
                // The TOML crate names the line, not the table: `rollouts = "15"` could be in
                // any section.
                let key = e.span().and_then(|span| key_path_at(text, span.start));
                ConfigError::Parse {
                    file: origin.to_path_buf(),
                    message: match key {
                        Some(key) => format!("{key}: {message}"),
                        None => message,
                    },
                }
            })
        })?;
        cfg.origin = origin.to_path_buf();
        cfg.validate()?;
        Ok(cfg)
    }

    /// What is valid but likely not meant, for the binaries to show as notes: a scheduled
    /// change at or past the end of a bounded run (it takes effect only in a run resumed with
    /// more updates, so it is not an error), and one that a later entry replaces (the same
    /// setting from the same update: the later as written is the one in force, which is how a
    /// runtime `set` over a scheduled change is replayed, but a copied entry whose
    /// `from_update` was not changed looks the same).
    pub fn notes(&self) -> Vec<String> {
        let file = self.origin.display();
        let mut notes = Vec::new();
        if let Some(updates) = self.run.updates {
            for (i, c) in self.schedule.iter().enumerate() {
                if c.from_update >= updates {
                    notes.push(format!(
                        "{file}: schedule[{i}].from_update = {} is not before the run's end ({}): \
                         {} = {} takes effect only if the run is resumed with more updates",
                        c.from_update,
                        self.option_setting("updates", updates)
                            .unwrap_or_else(|| format!("run.updates = {updates}")),
                        c.set,
                        num(c.value)
                    ));
                }
            }
        }
        for (i, c) in self.schedule.iter().enumerate() {
            let later = self.schedule[i + 1..]
                .iter()
                .position(|d| d.from_update == c.from_update && d.set == c.set);
            if let Some(k) = later {
                let j = i + 1 + k;
                notes.push(format!(
                    "{file}: schedule[{i}] ({} = {} from update {}) never takes effect: \
                     schedule[{j}] sets {} = {} from the same update, and the later entry is \
                     the one in force",
                    c.set,
                    num(c.value),
                    c.from_update,
                    c.set,
                    num(self.schedule[j].value)
                ));
            }
        }
        notes
    }

    /// `--updates 5` when the command line set the `run` field `field` (to `value`): what a
    /// message about the value names, as the user typed it; `None` when the value is the
    /// config's, which the message names by its key and file.
    pub fn option_setting(&self, field: &str, value: impl std::fmt::Display) -> Option<String> {
        self.set_by_options
            .iter()
            .any(|f| f == field)
            .then(|| format!("{} {value}", option_of(field)))
    }

    /// A `task` table without exactly one section, which serde would report as "wanted
    /// exactly 1 element"; `None` when that is not what is wrong with `text`.
    fn task_sections_error(text: &str, origin: &Path) -> Option<ConfigError> {
        let table: toml::Table = text.parse().ok()?;
        let sections = table.get("task")?.as_table()?;
        if sections.len() == 1 {
            return None;
        }
        let found = if sections.is_empty() {
            "none".to_string()
        } else {
            sections
                .keys()
                .map(|k| format!("[task.{k}]"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        Some(ConfigError::Parse {
            file: origin.to_path_buf(),
            message: format!(
                "task: exactly one of [task.via-point], [task.tball], [task.external] (found: \
                 {found})"
            ),
        })
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
            let n = i64::try_from(value).map_err(|_| ConfigError::Option {
                option: option_of(field),
                value: value.to_string(),
                reason: format!("too large (at most {})", i64::MAX),
            })?;
            run.insert(field.into(), toml::Value::Integer(n));
        }
        let text = toml::to_string(&table).map_err(|e| parse_error(&e))?;
        let set: Vec<&str> = overrides
            .iter()
            .filter(|(_, v)| v.is_some())
            .map(|(field, _)| *field)
            .collect();
        let mut cfg = Self::parse(&text, origin).map_err(|e| {
            set.iter().fold(e, |e, field| {
                e.of_option(&format!("run.{field}"), &option_of(field))
            })
        })?;
        cfg.set_by_options = set.into_iter().map(str::to_string).collect();
        Ok((cfg, text))
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
    ///
    /// Nothing large is built before the sizes it depends on are known to be sane: P and N come
    /// from the task section's fields (`TaskShape`), the memory the run needs is estimated from
    /// K, P and N ([`RunConfig::memory_need`]), and only then is the task built.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let o = &self.optimizer;
        // A key of another method (or weighting) than the config's: named with its value and
        // what the config has instead, so that it is clear which of the two to change.
        let method = format!("method = \"{}\"", o.method.name());
        let only = |field: &str, given: Option<String>, applies_to: &str, instead: &str| {
            given.map_or(Ok(()), |value| {
                Err(self.invalid(
                    &format!("optimizer.{field}"),
                    value,
                    &format!("only applies to {applies_to}, not to {instead}: remove it"),
                ))
            })
        };
        let is_pi2 = o.method != Method::Cem;
        let all_pi2 = "method pi2, pi2-decay, pi2-cma";
        only(
            "eliteness",
            o.eliteness.filter(|_| !is_pi2).map(num),
            all_pi2,
            &method,
        )?;
        let elites = o.elites.filter(|_| is_pi2).map(|e| e.to_string());
        only("elites", elites, "method cem", &method)?;
        let decay = o.decay.filter(|_| o.method != Method::Pi2Decay).map(num);
        only("decay", decay, "method pi2-decay", &method)?;
        let bounded = matches!(o.method, Method::Pi2Cma | Method::Cem);
        for (field, bound) in [("lambda_min", o.lambda_min), ("lambda_max", o.lambda_max)] {
            let given = bound.filter(|_| !bounded).map(num);
            only(field, given, "method pi2-cma, cem", &method)?;
        }
        let temporal = o
            .temporal_averaging
            .filter(|_| o.weighting == WeightingName::Episodic)
            .map(|t| format!("\"{}\"", t.name()));
        only(
            "temporal_averaging",
            temporal,
            "weighting = \"per-time-step\"",
            "weighting = \"episodic\"",
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
        self.validate_lambdas()?;
        if o.covariance == CovarianceName::PerDimension {
            if !bounded {
                return Err(self.invalid(
                    "optimizer.covariance",
                    "\"per-dimension\"",
                    "only applies to method pi2-cma, cem (the others do not adapt Σ, which stays \
                     λ·I: block-diagonal already)",
                ));
            }
            if let TaskSection::External(_) = self.task {
                return Err(self.invalid(
                    "optimizer.covariance",
                    "\"per-dimension\"",
                    "needs the policy's DMP shape (basis functions per dimension), which \
                     [task.external] does not declare: use \"full\"",
                ));
            }
        }
        if o.rollouts > MAX_ROLLOUTS {
            return Err(self.invalid(
                "optimizer.rollouts",
                o.rollouts,
                &format!(
                    "must be at most {MAX_ROLLOUTS} (the update keeps four K×K matrices: {} at \
                     K = {MAX_ROLLOUTS})",
                    bytes(4.0 * 8.0 * (MAX_ROLLOUTS as f64).powi(2))
                ),
            ));
        }
        self.hyperparameters()
            .check()
            .map_err(|e| self.invalid_param(e))?;
        if self.run.name.trim().is_empty() {
            return Err(self.invalid("run.name", "\"\"", "must not be empty"));
        }
        if self.run.updates == Some(0) {
            return Err(self.invalid(
                "run.updates",
                0,
                "must be at least 1 (a run without run.updates is unbounded)",
            ));
        }
        if self.run.nonfinite_reruns > MAX_NONFINITE_RERUNS {
            return Err(self.invalid(
                "run.nonfinite_reruns",
                self.run.nonfinite_reruns,
                &format!(
                    "must be at most {MAX_NONFINITE_RERUNS}: a rerun repeats the rollout (on a \
                     robot, for real), and a cost that is still not finite after that many is no \
                     transient fault"
                ),
            ));
        }
        if let Some(f) = self.run.fault_nan_first_attempt {
            if let Some(k) = f.rollout.filter(|&k| k >= o.rollouts) {
                return Err(self.invalid(
                    "run.fault_nan_first_attempt.rollout",
                    k,
                    &format!("must be below optimizer.rollouts = {}", o.rollouts),
                ));
            }
        }
        let shape = self.task_shape()?;
        self.check_memory(&shape)?;
        let (delay_field, delay_ms) = match &self.task {
            TaskSection::ViaPoint(v) => ("task.via-point.rollout_delay_ms", v.rollout_delay_ms),
            TaskSection::Tball(t) => ("task.tball.rollout_delay_ms", t.rollout_delay_ms),
            TaskSection::External(_) => ("", 0.0),
        };
        if !(delay_ms.is_finite() && (0.0..=3.6e6).contains(&delay_ms)) {
            return Err(self.invalid(delay_field, num(delay_ms), "must be between 0 and 3600000"));
        }
        if self.recording.as_ref().and_then(|r| r.split_mb) == Some(0) {
            return Err(self.invalid(
                "recording.split_mb",
                0,
                "must be > 0 (leave it out for one file)",
            ));
        }
        if !self.recording_step_costs() && matches!(self.weighting(), Weighting::PerTimeStep { .. })
        {
            return Err(self.invalid(
                "recording.step_costs",
                false,
                "needs optimizer.weighting = \"episodic\": a per-time-step update is recomputed \
                 from the step costs, which the recording would not have",
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
                    num(p.restart_window_s),
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
            if p.fault_hang_at_chunk_rollout == Some(0) {
                return Err(self.invalid(
                    "pipeline.fault_hang_at_chunk_rollout",
                    0,
                    "must be ≥ 1 (1: a chunk's first rollout)",
                ));
            }
        }
        let mut task = self
            .build_task()
            .map_err(|e| self.task_error(shape.section, e))?;
        let runs_here = !matches!(self.task, TaskSection::External(_));
        if runs_here {
            tasks::check_initial_rollout(task.as_mut()).map_err(|e| {
                self.invalid(
                    &format!("task.{}", shape.section),
                    settings_text(task.as_ref()),
                    &e.to_string(),
                )
            })?;
        }
        self.validate_schedule(task.as_mut(), runs_here)
    }

    /// λ_min and λ_max each on their own first (so that a bad bound is reported as itself, not
    /// as λ_init outside it), then λ_init.
    fn validate_lambdas(&self) -> Result<(), ConfigError> {
        let o = &self.optimizer;
        let (lo, hi) = LAMBDA_RANGE;
        let sane = |v: f64| (lo..=hi).contains(&v);
        let range = format!("[{}, {}]", num(lo), num(hi));
        if let Some(min) = o.lambda_min.filter(|v| !(*v == 0.0 || sane(*v))) {
            return Err(self.invalid(
                "optimizer.lambda_min",
                num(min),
                &format!("must be 0 (no lower bound) or within {range}: {LAMBDA_WHY}"),
            ));
        }
        if let Some(max) = o.lambda_max.filter(|v| !(*v == f64::INFINITY || sane(*v))) {
            return Err(self.invalid(
                "optimizer.lambda_max",
                num(max),
                &format!("must be inf (no upper bound) or within {range}: {LAMBDA_WHY}"),
            ));
        }
        let (min, max) = (
            o.lambda_min.unwrap_or(0.0),
            o.lambda_max.unwrap_or(f64::INFINITY),
        );
        if max < min {
            return Err(self.invalid(
                "optimizer.lambda_max",
                num(max),
                &format!("must be >= lambda_min = {}", num(min)),
            ));
        }
        if !(o.lambda_init.is_finite() && o.lambda_init > 0.0) {
            return Err(self.invalid(
                "optimizer.lambda_init",
                num(o.lambda_init),
                "must be finite and > 0",
            ));
        }
        if !sane(o.lambda_init) {
            return Err(self.invalid(
                "optimizer.lambda_init",
                num(o.lambda_init),
                &format!("must be within {range}: {LAMBDA_WHY}"),
            ));
        }
        if !(min <= o.lambda_init && o.lambda_init <= max) {
            return Err(self.invalid(
                "optimizer.lambda_init",
                num(o.lambda_init),
                &format!(
                    "must lie within [lambda_min, lambda_max] = [{}, {}]",
                    num(min),
                    num(max)
                ),
            ));
        }
        Ok(())
    }

    /// P and N of the task, from its section's fields alone: what building it would allocate
    /// (a DMP of N steps and P weights) is checked before it is built.
    fn task_shape(&self) -> Result<TaskShape, ConfigError> {
        match &self.task {
            TaskSection::ViaPoint(v) => {
                for (field, value) in [
                    ("start", v.start),
                    ("goal", v.goal),
                    ("viapoint", v.viapoint),
                ] {
                    if !value.is_finite() {
                        return Err(self.invalid(
                            &format!("task.via-point.{field}"),
                            num(value),
                            "must be finite",
                        ));
                    }
                }
                self.dmp_shape("via-point", 1, v.basis_functions, v.duration, v.dt)
            }
            TaskSection::Tball(t) => {
                for (field, values) in [
                    ("start_pose", &t.start_pose[..]),
                    ("end_pose", &t.end_pose[..]),
                    ("shoulder", &t.shoulder[..]),
                ] {
                    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                        return Err(self.invalid(
                            &format!("task.tball.{field}[{i}]"),
                            num(values[i]),
                            "must be finite",
                        ));
                    }
                }
                let joints = t.start_pose.len();
                self.dmp_shape("tball", joints, t.basis_functions, t.duration, t.dt)
            }
            TaskSection::External(e) => {
                self.validate_external(e)?;
                Ok(TaskShape {
                    section: "external",
                    parameters: e.parameters,
                    steps: e.steps,
                    p_field: ("task.external.parameters".into(), e.parameters.to_string()),
                    n_field: ("task.external.steps".into(), e.steps.to_string()),
                    dmp: None,
                })
            }
        }
    }

    /// The checks of `dmp::Dmp::new`, plus the sizes: N = duration/dt + 1 steps, P = dims × B
    /// weights, and the work of building the DMP (N·B² basis-function evaluations).
    fn dmp_shape(
        &self,
        section: &'static str,
        dims: usize,
        basis: usize,
        duration: f64,
        dt: f64,
    ) -> Result<TaskShape, ConfigError> {
        let field = |name: &str| format!("task.{section}.{name}");
        if basis == 0 {
            return Err(self.invalid(&field("basis_functions"), 0, "must be at least 1"));
        }
        if !(duration.is_finite() && duration > 0.0) {
            return Err(self.invalid(&field("duration"), num(duration), "must be finite and > 0"));
        }
        if !(dt.is_finite() && dt > 0.0 && dt <= duration) {
            return Err(self.invalid(
                &field("dt"),
                num(dt),
                &format!("must be > 0 and at most duration = {}", num(duration)),
            ));
        }
        let ratio = duration / dt;
        let steps = ratio.round() + 1.0;
        if steps > MAX_STEPS as f64 {
            return Err(self.invalid(
                &field("dt"),
                num(dt),
                &format!(
                    "N = duration/dt + 1 = {} steps; at most {MAX_STEPS}",
                    num(steps)
                ),
            ));
        }
        if (ratio - ratio.round()).abs() > 1e-9 * ratio {
            return Err(self.invalid(
                &field("dt"),
                num(dt),
                &format!(
                    "duration = {} must be a whole number of steps",
                    num(duration)
                ),
            ));
        }
        let steps = steps as usize;
        let parameters = dims.saturating_mul(basis);
        if parameters > MAX_PARAMETERS {
            let p = if dims == 1 {
                String::new()
            } else {
                format!(" ({dims} joints × {basis} = {parameters} parameters)")
            };
            return Err(self.invalid(
                &field("basis_functions"),
                basis,
                &format!("P must be at most {MAX_PARAMETERS}{p}: {PARAMETERS_WHY}"),
            ));
        }
        let work = steps as f64 * (basis as f64).powi(2);
        if work > MAX_DMP_WORK {
            return Err(self.invalid(
                &field("basis_functions"),
                basis,
                &format!(
                    "with N = {steps} steps, building the DMP takes N × basis_functions² = \
                     {work:.1e} basis-function evaluations (about {:.0} s); at most {} (a few \
                     seconds): fewer basis functions or a larger dt",
                    work / DMP_WORK_PER_SECOND,
                    num(MAX_DMP_WORK)
                ),
            ));
        }
        Ok(TaskShape {
            section,
            parameters,
            steps,
            p_field: (field("basis_functions"), basis.to_string()),
            n_field: (field("dt"), num(dt)),
            dmp: Some((basis, dims)),
        })
    }

    /// The fields that set P and N, as messages name them (`task.tball.basis_functions`,
    /// `task.tball.dt`; `task.external.parameters`, `task.external.steps`): for a limit that
    /// grows with them, such as the pipeline's shared memory.
    pub fn size_fields(&self) -> Result<(String, String), ConfigError> {
        let shape = self.task_shape()?;
        Ok((shape.p_field.0, shape.n_field.0))
    }

    /// What one process that runs the update (the in-process runner, the pipeline's updater)
    /// holds at its peak, by what scales with K, P and N: an upper estimate (transient copies
    /// are counted as if they coexisted), from the allocations of `pi2cma::UpdateRule::new`,
    /// `UpdateRule::update`, the distribution's eigen-decompositions and the executor's batches.
    /// Measured peaks (a counting allocator around ask/tell; 18 cases, K up to 4000, P up to
    /// 5000, N up to 10⁶) were 0.79–1.03 times it, the 0.79 where the per-time-step low-rank
    /// kernel's partial sums and the P×P copies, counted together here, do not coexist.
    pub fn memory_need(&self) -> Result<MemoryNeed, ConfigError> {
        Ok(self.memory_need_of(&self.task_shape()?))
    }

    fn memory_need_of(&self, shape: &TaskShape) -> MemoryNeed {
        let o = &self.optimizer;
        let (k, p, n) = (
            o.rollouts as f64,
            shape.parameters as f64,
            shape.steps as f64,
        );
        // Rollouts that enter the update.
        let m = (o.rollouts - usize::from(!o.evaluation_in_update)) as f64;
        let per_step = o.weighting == WeightingName::PerTimeStep;
        let adaptive = matches!(o.method, Method::Pi2Cma | Method::Cem);
        let unbounded = o.lambda_min.unwrap_or(0.0) == 0.0
            && o.lambda_max.unwrap_or(f64::INFINITY).is_infinite();
        // The update's covariance kernel: P = 2 closed form, P ≤ m dense, else low rank.
        let low_rank = shape.parameters != 2 && p > m;
        let mut parts = Vec::new();
        // Four m × m scratch matrices, allocated whatever the kernel; the per-time-step low-rank
        // kernel also keeps one m × m partial sum per block of 50 steps until it adds them.
        let mut kk = 4.0 * m * m;
        if per_step && adaptive && !unbounded && low_rank {
            kk += ((n / 50.0).ceil() + 2.0) * m * m;
        }
        parts.push(MemoryPart {
            what: "K×K matrices of the update",
            bytes: 8.0 * kk,
            blame: Blame::Rollouts,
        });
        // The K × N cost batch; per time step, the cost-to-go and probabilities of the m
        // updating rollouts (m × N each) and a few N-vectors.
        let kn = k * n + if per_step { 2.0 * m * n + 5.0 * n } else { 0.0 };
        parts.push(MemoryPart {
            what: if per_step {
                "K×N costs, cost-to-go and probabilities"
            } else {
                "K×N costs"
            },
            bytes: 8.0 * kn,
            blame: Blame::RolloutsSteps,
        });
        // Σ before and after, the accumulator, the sampler's factor and the copies of an
        // eigen-decomposition; the dense kernel also bounds a P × P matrix (every step, per
        // time step), with copies of its own.
        let dense = adaptive && !unbounded && shape.parameters != 2 && !low_rank;
        let pp = if dense { 8.0 } else { 6.0 } * p * p;
        parts.push(MemoryPart {
            what: "P×P covariances",
            bytes: 8.0 * pp,
            blame: Blame::Parameters,
        });
        // Samples (and the executor's copy), deviations, per-parameter weights.
        parts.push(MemoryPart {
            what: "K×P samples",
            bytes: 8.0 * 4.0 * k * p,
            blame: Blame::RolloutsParameters,
        });
        if o.temporal_averaging == Some(TemporalName::BasisActivation) {
            // The task's activations, the copy handed to the update and its normalised weights
            // (an external task's also in the config, twice).
            let copies = if shape.dmp.is_some() { 2.0 } else { 4.0 };
            parts.push(MemoryPart {
                what: "N×P basis activations",
                bytes: 8.0 * copies * n * p,
                blame: Blame::StepsParameters,
            });
        }
        if let Some((basis, dims)) = shape.dmp {
            // The DMP's precomputed responses: position, velocity and acceleration of every
            // basis function and of every dimension's base, N values each.
            parts.push(MemoryPart {
                what: "the DMP's N×B precomputed responses",
                bytes: 8.0 * (3.0 * n * (basis + dims) as f64 + 8.0 * n),
                blame: Blame::StepsParameters,
            });
        }
        MemoryNeed {
            parts,
            rollouts: o.rollouts,
            parameters: shape.parameters,
            steps: shape.steps,
        }
    }

    fn check_memory(&self, shape: &TaskShape) -> Result<(), ConfigError> {
        let need = self.memory_need_of(shape);
        let total = need.total();
        if total <= MEMORY_LIMIT_BYTES as f64 {
            return Ok(());
        }
        let mut parts: Vec<&MemoryPart> = need.parts.iter().collect();
        parts.sort_by(|a, b| b.bytes.total_cmp(&a.bytes));
        let Some(main) = parts.first() else {
            return Ok(());
        };
        // Of two factors, the one nearer its own limit is the one to name.
        let k = self.optimizer.rollouts as f64 / MAX_ROLLOUTS as f64;
        let p = shape.parameters as f64 / MAX_PARAMETERS as f64;
        let n = shape.steps as f64 / MAX_STEPS as f64;
        let rollouts = (
            "optimizer.rollouts".to_string(),
            self.optimizer.rollouts.to_string(),
        );
        let (field, value) = match main.blame {
            Blame::Rollouts => &rollouts,
            Blame::Parameters => &shape.p_field,
            Blame::RolloutsSteps if k >= n => &rollouts,
            Blame::RolloutsSteps => &shape.n_field,
            Blame::RolloutsParameters if k >= p => &rollouts,
            Blame::RolloutsParameters => &shape.p_field,
            Blame::StepsParameters if n >= p => &shape.n_field,
            Blame::StepsParameters => &shape.p_field,
        };
        let list = parts
            .iter()
            .filter(|part| part.bytes >= 0.1 * total)
            .map(|part| format!("{}: {}", part.what, bytes(part.bytes)))
            .collect::<Vec<_>>()
            .join(", ");
        Err(self.invalid(
            field,
            value,
            &format!(
                "with K = {} rollouts, P = {} parameters and N = {} steps the run would need \
                 about {} of memory ({list}); at most {} (4 GiB)",
                need.rollouts,
                need.parameters,
                need.steps,
                bytes(total),
                bytes(MEMORY_LIMIT_BYTES as f64),
            ),
        ))
    }

    /// A task's own error, as an error of the field of its section it names.
    fn task_error(&self, section: &str, e: tasks::TaskError) -> ConfigError {
        match e {
            tasks::TaskError::InvalidSetting {
                name,
                value,
                reason,
                ..
            } => self.invalid(&format!("task.{section}.{name}"), num(value), reason),
            // Not reached by a config that passed the checks above; still named by section.
            other => self.invalid(&format!("task.{section}"), "(section)", &other.to_string()),
        }
    }

    /// Every `[[schedule]]` entry against the task's settings, named by its place in the file.
    /// With `probe`, each change is also checked by a rollout of the initial mean, applied in
    /// the order a run applies them (by update, then as written).
    fn validate_schedule(
        &self,
        task: &mut dyn tasks::Task,
        probe: bool,
    ) -> Result<(), ConfigError> {
        let mut order: Vec<(usize, &ScheduleEntry)> = self.schedule.iter().enumerate().collect();
        order.sort_by_key(|(_, s)| s.from_update);
        for (i, s) in order {
            task.set(&s.set, s.value).map_err(|e| match e {
                tasks::TaskError::UnknownSetting { .. } => self.invalid(
                    &format!("schedule[{i}].set"),
                    format!("{:?}", s.set),
                    &e.to_string(),
                ),
                tasks::TaskError::InvalidSetting {
                    task, name, reason, ..
                } => self.invalid(
                    &format!("schedule[{i}].value"),
                    num(s.value),
                    &format!("task `{task}`, setting `{name}`: {reason}"),
                ),
                other => self.invalid(&format!("schedule[{i}]"), "(entry)", &other.to_string()),
            })?;
            if probe {
                tasks::check_initial_rollout(task).map_err(|e| {
                    self.invalid(
                        &format!("schedule[{i}].value"),
                        num(s.value),
                        &format!(
                            "from update {} the settings would be {}: {e}",
                            s.from_update,
                            settings_text(task)
                        ),
                    )
                })?;
            }
        }
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
        if !(1..=MAX_PARAMETERS).contains(&e.parameters) {
            return Err(self.invalid(
                "task.external.parameters",
                e.parameters,
                &format!("must be between 1 and {MAX_PARAMETERS}: {PARAMETERS_WHY}"),
            ));
        }
        if !(1..=MAX_STEPS).contains(&e.steps) {
            return Err(self.invalid(
                "task.external.steps",
                e.steps,
                &format!("must be between 1 and {MAX_STEPS}"),
            ));
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
                num(e.initial_mean[i]),
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
                    num(*v),
                    "a setting name is 1 to 32 of A-Z, a-z, 0-9, _ and -",
                ));
            }
            if !v.is_finite() {
                return Err(self.invalid(
                    &format!("task.external.settings.{name}"),
                    num(*v),
                    "must be finite",
                ));
            }
        }
        if e.settings.len() > MAX_EXTERNAL_SETTINGS {
            return Err(self.invalid(
                "task.external.settings",
                format!("({} settings)", e.settings.len()),
                &format!(
                    "at most {MAX_EXTERNAL_SETTINGS}: the pipeline's work items and costs carry \
                     that many"
                ),
            ));
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
        // Sized by what the file holds, not by the declared shape (a short row is an error).
        let mut values = Vec::with_capacity(rows.iter().map(Vec::len).sum());
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
                    num(row[j]),
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

    /// [`RunConfig::external_worker`] with its program resolved to an executable file (an
    /// absolute path); an error naming the field when there is none. Not part of
    /// [`RunConfig::validate`]: the processes of a run read a copy of the config elsewhere, from
    /// which a relative program would not resolve; the supervisor and `pi2cma check` call it.
    pub fn external_worker_program(&self) -> Result<Option<(PathBuf, Vec<String>)>, ConfigError> {
        let Some((program, args)) = self.external_worker() else {
            return Ok(None);
        };
        let refused = |reason: &str| {
            Err(self.invalid(
                "task.external.worker",
                format!("\"{}\"", program.display()),
                reason,
            ))
        };
        match resolve_program(&program) {
            Some(resolved) => match unstartable(&resolved) {
                Some(why) => refused(&why),
                None => Ok(Some((resolved, args))),
            },
            None if program.components().count() > 1 => refused(&format!(
                "not an executable file: {} (a path with a `/` is relative to the config file's \
                 directory)",
                missing_program(&program)
            )),
            None => refused("not an executable file in PATH"),
        }
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

    /// The core's [`Weighting`] for `optimizer.weighting` and `temporal_averaging`.
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
            covariance: match o.covariance {
                CovarianceName::Full => CovarianceStructure::Full,
                // P = dims × B for the DMP tasks; `validate` refuses the external task, whose
                // shape is unknown (block 0 fails the core's own check).
                CovarianceName::PerDimension => CovarianceStructure::PerDimension {
                    block: match &self.task {
                        TaskSection::ViaPoint(v) => v.basis_functions,
                        TaskSection::Tball(t) => t.basis_functions,
                        TaskSection::External(_) => 0,
                    },
                },
            },
        }
    }

    /// The `[[schedule]]` entries as a [`TaskSchedule`], in update order.
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

    /// MB per part of the run's recording (`recording.split_mb`), `None` for one file. A
    /// continual run (no `run.updates`) without one is split at `CONTINUAL_SPLIT_MB` (1024): one
    /// file's writer keeps an index entry per update in memory until the file is finished (the
    /// MCAP summary), about 256 bytes per update, so a recorder of a via-point run at full
    /// speed grew by 1.6 MB/s (74 MB after 240 000 updates) without end.
    pub fn recording_split_mb(&self) -> Option<u64> {
        self.recording
            .as_ref()
            .and_then(|r| r.split_mb)
            .or_else(|| self.run.updates.is_none().then_some(CONTINUAL_SPLIT_MB))
    }

    /// Whether the recording carries the step costs (`recording.step_costs`, default true).
    pub fn recording_step_costs(&self) -> bool {
        self.recording.as_ref().is_none_or(|r| r.step_costs)
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
    /// Whether a runtime task change (`supervisor set`) can be made: the setting exists, takes
    /// the value, and (for a task that runs here) the initial mean's rollout still has finite
    /// costs: a change under which every cost overflows would end a continual run at the update
    /// it takes effect from. `in_force` are the settings the change joins (those the run has
    /// reached, which earlier changes may have made other than the config's): a change is
    /// judged with them, not with the config's.
    pub fn check_task_change(
        &self,
        in_force: &[(String, f64)],
        name: &str,
        value: f64,
    ) -> Result<(), tasks::TaskError> {
        let mut task = self.build_task()?;
        let from_config = task.settings();
        tasks::set_all(task.as_mut(), in_force)?;
        // Name the settings that made the difference, if any besides the change did: a value
        // refused only because of them (a T-ball tee in reach of the shoulder along x alone,
        // not with the tee's y in force) would otherwise read as refused on its own.
        let with_others = |task: &dyn tasks::Task, e: tasks::TaskError| {
            let others = tasks::settings_text(task.settings().into_iter().filter(|&(n, v)| {
                n != name
                    && from_config
                        .iter()
                        .any(|&(c, cv)| c == n && cv.to_bits() != v.to_bits())
            }));
            let in_force = |reason: String| {
                format!(
                    "{reason} (together with the settings in force that differ from the \
                     config: {others})"
                )
            };
            match e {
                _ if others.is_empty() => e,
                tasks::TaskError::Invalid { task, reason } => tasks::TaskError::Invalid {
                    task,
                    reason: in_force(reason),
                },
                tasks::TaskError::InvalidSetting {
                    task,
                    name,
                    value,
                    reason,
                } => tasks::TaskError::Invalid {
                    task,
                    reason: in_force(format!("{name} = {}: {reason}", num(value))),
                },
                e => e,
            }
        };
        if let Err(e) = task.set(name, value) {
            return Err(with_others(task.as_ref(), e));
        }
        if matches!(self.task, TaskSection::External(_)) {
            return Ok(());
        }
        tasks::check_initial_rollout(task.as_mut()).map_err(|e| with_others(task.as_ref(), e))
    }

    /// The config's task at its initial settings, without a rollout delay. For
    /// `[task.external]`, an [`tasks::External`]: the declared shape, which cannot run
    /// rollouts (the executors use [`crate::build_task`], which refuses it).
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

/// The dotted path of the key whose line holds byte `offset` of a TOML text, as the config
/// errors name fields (`optimizer.rollouts`, `schedule[1].value`): the last table header above
/// it and the key before the line's `=`. `None` where that is not a `key = value` line (a
/// header, a value spread over lines).
fn key_path_at(text: &str, offset: usize) -> Option<String> {
    let offset = offset.min(text.len());
    let line_start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    let bare = |k: &str| {
        !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
    };
    if !bare(key) {
        return None;
    }
    let mut table = String::new();
    let mut arrays: std::collections::BTreeMap<String, usize> = Default::default();
    for header in text[..line_start].lines().map(str::trim) {
        if let Some(name) = header
            .strip_prefix("[[")
            .and_then(|h| h.split_once("]]"))
            .map(|(name, _)| name.trim())
        {
            let n = arrays.entry(name.to_string()).or_insert(0);
            table = format!("{name}[{n}]");
            *n += 1;
        } else if let Some(name) = header
            .strip_prefix('[')
            .and_then(|h| h.split_once(']'))
            .map(|(name, _)| name.trim())
        {
            table = name.to_string();
        }
    }
    Some(if table.is_empty() {
        key.to_string()
    } else {
        format!("{table}.{key}")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default config with an external task of P = 2, N = 3 run by `worker` (TOML).
    fn external_config(worker: &str) -> String {
        format!(
            "{}\n[task.external]\nworker = {worker}\nparameters = 2\nsteps = 3\ninitial_mean = [0.0, 0.0]\n",
            DEFAULT_CONFIG
                .split("[task.via-point]")
                .next()
                .unwrap()
                .replace("[[schedule]]\nfrom_update = 20\nset = \"viapoint\"\nvalue = 0.1\n", "")
        )
    }

    /// A config that is not UTF-8 is refused naming where: the line and column of the first
    /// byte that is not, and the byte.
    #[test]
    fn a_config_that_is_not_utf8_names_the_line_column_and_byte() {
        let dir = std::env::temp_dir().join(format!("p2c-latin1-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("latin1.toml");
        // `# λ ≥ 0 °C` with the degree sign in Latin-1 (0xb0) after two UTF-8 characters.
        let mut bytes = b"[run]\nname = \"A1\"\n# \xce\xbb \xe2\x89\xa5 0 ".to_vec();
        bytes.extend_from_slice(b"\xb0C\n");
        std::fs::write(&file, &bytes).unwrap();
        let e = RunConfig::load(&file).unwrap_err().to_string();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(
            e,
            format!(
                "{}: cannot read: not UTF-8 text, which TOML must be: byte 29 (0xb0, line 3, \
                 column 9) is not valid UTF-8 (a file saved in another encoding, such as \
                 Latin-1, or not a config)",
                file.display()
            )
        );
    }

    #[test]
    fn a_worker_program_is_an_executable_path_or_found_in_path() {
        let sh = resolve_program(Path::new("sh")).expect("sh in PATH");
        assert!(sh.is_absolute() && sh.ends_with("sh"), "{}", sh.display());
        assert_eq!(resolve_program(Path::new("no-such-program-p2c")), None);
        let dir = std::env::temp_dir().join(format!("p2c-resolve-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("worker");
        std::fs::write(&file, "#!/bin/sh\n").unwrap();
        // Not executable yet.
        assert_eq!(resolve_program(&file), None);
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o755)).unwrap();
        assert_eq!(resolve_program(&file), Some(file.clone()));
        assert_eq!(resolve_program(&dir), None, "a directory is not a program");
        // Through the config: relative to its file, and named in the error.
        let text = external_config("[\"./worker\"]");
        let cfg = RunConfig::parse(&text, &dir.join("c.toml")).unwrap();
        let (program, _) = cfg.external_worker_program().unwrap().unwrap();
        assert_eq!(program, file);
        let elsewhere = RunConfig::parse(&text, Path::new("/nonexistent/c.toml")).unwrap();
        let e = elsewhere.external_worker_program().unwrap_err().to_string();
        assert!(
            e.starts_with("/nonexistent/c.toml: task.external.worker = \"/nonexistent/./worker\": not an executable file: there is no such file"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// What a user's worker file lacks is named: a forgotten `chmod +x`, a directory, and a
    /// script without a `#!` line, which `execvp` would hand to /bin/sh (a Python worker then
    /// died of the shell's `Syntax error`, restarted up to the restart limit).
    #[test]
    fn a_worker_file_that_cannot_be_started_is_refused_saying_why() {
        use std::os::unix::fs::PermissionsExt as _;
        let dir = std::env::temp_dir().join(format!("p2c-unstartable-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let text = external_config("[\"./w\"]");
        let refusal = |program: &str| {
            let cfg = RunConfig::parse(&text.replace("./w", program), &dir.join("c.toml")).unwrap();
            match cfg.external_worker_program() {
                Ok(p) => panic!("{program}: taken as {p:?}"),
                Err(e) => e.to_string(),
            }
        };
        let write = |name: &str, content: &str, mode: u32| {
            std::fs::write(dir.join(name), content).unwrap();
            std::fs::set_permissions(dir.join(name), std::fs::Permissions::from_mode(mode))
                .unwrap();
        };
        write("plain.py", "#!/usr/bin/env python3\nprint()\n", 0o644);
        let e = refusal("./plain.py");
        let chmod = format!(
            "it has no execute permission (`chmod +x {}`)",
            dir.join("./plain.py").display()
        );
        assert!(e.contains(&chmod), "{e}");
        assert!(refusal("./sub").contains("not an executable file: a directory"));
        write("noshebang.py", "import math\nprint(math.pi)\n", 0o755);
        let e = refusal("./noshebang.py");
        assert!(
            e.contains("/noshebang.py\"")
                && e.contains(
                    "neither a binary nor a script with a `#!` line (it begins `import math`)"
                )
                && e.contains("#!/usr/bin/env python3"),
            "{e}"
        );
        write("empty", "", 0o755);
        assert!(refusal("./empty").contains("(it is empty)"));
        // A script with its `#!` line and a binary are taken.
        write("ok.py", "#!/usr/bin/env python3\n", 0o755);
        let cfg = RunConfig::parse(&text.replace("./w", "./ok.py"), &dir.join("c.toml")).unwrap();
        assert!(cfg.external_worker_program().is_ok());
        let sh = resolve_program(Path::new("sh")).unwrap();
        let cfg = RunConfig::parse(
            &text.replace("./w", &sh.display().to_string()),
            &dir.join("c.toml"),
        )
        .unwrap();
        assert!(cfg.external_worker_program().is_ok(), "{}", sh.display());
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn parse(text: &str) -> Result<RunConfig, ConfigError> {
        RunConfig::parse(text, Path::new("test.toml"))
    }

    /// A worker given as one string, not a list, is refused showing the form to write.
    #[test]
    fn a_worker_command_that_is_not_a_list_shows_the_form() {
        let text = external_config;
        let e = parse(&text("\"./my_worker.py\"")).unwrap_err().to_string();
        assert!(
            e.contains("task.external.worker")
                && e.contains("invalid type: string \"./my_worker.py\", expected a list of strings, the program then its arguments, as in worker = [\"./my_worker.py\"]"),
            "{e}"
        );
        let e = parse(&text("[\"python3\", 3]")).unwrap_err().to_string();
        assert!(
            e.contains("invalid type: integer `3`, expected a string"),
            "{e}"
        );
        let cfg = parse(&text("[\"python3\", \"w.py\"]")).unwrap();
        let TaskSection::External(x) = &cfg.task else {
            panic!("{:?}", cfg.task)
        };
        assert_eq!(x.worker, ["python3", "w.py"]);
    }

    /// A continual run's recording is split even without `recording.split_mb`: one file's index
    /// would grow in the recorder's memory for as long as the run goes on. A bounded run's is
    /// one file unless split, and a `split_mb` given is what counts.
    #[test]
    fn a_continual_runs_recording_is_split_unless_told_otherwise() {
        let continual = DEFAULT_CONFIG.replace("updates = 40\n", "");
        assert_eq!(
            parse(&continual).unwrap().recording_split_mb(),
            Some(CONTINUAL_SPLIT_MB)
        );
        assert_eq!(parse(DEFAULT_CONFIG).unwrap().recording_split_mb(), None);
        for text in [continual, DEFAULT_CONFIG.to_string()] {
            let split = format!("{text}\n[recording]\nsplit_mb = 5\n");
            assert_eq!(parse(&split).unwrap().recording_split_mb(), Some(5));
        }
    }

    /// `recording.step_costs` is on unless set off, and off only with episodic weighting; the
    /// error names the field, the value and what it needs.
    #[test]
    fn recording_without_step_costs_needs_episodic_weighting() {
        assert!(parse(DEFAULT_CONFIG).unwrap().recording_step_costs());
        let off = format!("{DEFAULT_CONFIG}\n[recording]\nstep_costs = false\n");
        assert!(!parse(&off).unwrap().recording_step_costs());
        let on = format!("{DEFAULT_CONFIG}\n[recording]\nsplit_mb = 5\n");
        assert!(parse(&on).unwrap().recording_step_costs());
        let per_step = off.replace("weighting = \"episodic\"", "weighting = \"per-time-step\"");
        assert_ne!(per_step, off);
        let e = parse(&per_step).unwrap_err().to_string();
        assert!(
            e.contains("test.toml")
                && e.contains("recording.step_costs")
                && e.contains("false")
                && e.contains("needs optimizer.weighting = \"episodic\""),
            "{e}"
        );
        let typo = format!("{DEFAULT_CONFIG}\n[recording]\nstep_cost = false\n");
        let e = parse(&typo).unwrap_err().to_string();
        assert!(e.contains("step_cost"), "{e}");
    }

    /// A scheduled change past a bounded run's end is valid (a resumed run may reach it) but
    /// named; one inside the run, or in a continual run, is not.
    #[test]
    fn a_change_scheduled_past_the_end_is_noted() {
        let late = DEFAULT_CONFIG.replace("from_update = 20", "from_update = 40");
        let notes = parse(&late).unwrap().notes();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(
            notes[0].starts_with("test.toml: schedule[0].from_update = 40 is not before the run's end (run.updates = 40): viapoint = 0.1"),
            "{}",
            notes[0]
        );
        assert!(parse(DEFAULT_CONFIG).unwrap().notes().is_empty());
        let continual = late.replace("updates = 40\n", "");
        assert!(parse(&continual).unwrap().notes().is_empty());
        // The run's end set by `--updates 5` is named as typed: the file says 40.
        let (cfg, _) = RunConfig::with_run_overrides(
            DEFAULT_CONFIG,
            Path::new("a.toml"),
            &[("updates", Some(5))],
        )
        .unwrap();
        let notes = cfg.notes();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert!(
            notes[0].starts_with("a.toml: schedule[0].from_update = 20 is not before the run's end (--updates 5): viapoint = 0.1"),
            "{}",
            notes[0]
        );
    }

    /// Two entries that set one setting from the same update: the earlier never takes effect,
    /// which is noted (valid: a replay of a runtime `set` over a scheduled change is written so).
    #[test]
    fn a_scheduled_change_replaced_at_its_update_is_noted() {
        let twice = DEFAULT_CONFIG.replace(
            "[[schedule]]",
            "[[schedule]]\nfrom_update = 20\nset = \"viapoint\"\nvalue = 0.2\n\n[[schedule]]",
        );
        let notes = parse(&twice).unwrap().notes();
        assert_eq!(
            notes,
            [
                "test.toml: schedule[0] (viapoint = 0.2 from update 20) never takes effect: \
              schedule[1] sets viapoint = 0.1 from the same update, and the later entry is the \
              one in force"
            ]
        );
        let apart = twice.replacen("from_update = 20", "from_update = 21", 1);
        assert!(parse(&apart).unwrap().notes().is_empty());
    }

    /// A value of the wrong type is reported with its table, not only its line: `rollouts`,
    /// `dt` or `value` alone could be in several places.
    #[test]
    fn type_errors_name_the_key_with_its_table() {
        let cases = [
            (
                "rollouts = 15",
                "rollouts = \"15\"",
                "test.toml: optimizer.rollouts: ",
            ),
            ("seed = 1", "seed = -1", "test.toml: run.seed: "),
            (
                "value = 0.1",
                "value = \"low\"",
                "test.toml: schedule[0].value: ",
            ),
        ];
        for (from, to, expected) in cases {
            assert!(DEFAULT_CONFIG.contains(from), "{from}");
            let e = parse(&DEFAULT_CONFIG.replacen(from, to, 1))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(expected), "{e}");
            assert!(e.contains(to), "the line is still shown: {e}");
        }
        let text = "[run]\nname = \"a\"\n\n[[schedule]]\nfrom_update = 1\n[[schedule]]\n  from_update = \"x\" # two\n";
        let at = text.find("\"x\"").unwrap();
        assert_eq!(
            key_path_at(text, at).as_deref(),
            Some("schedule[1].from_update")
        );
        assert_eq!(key_path_at(text, 1), None, "a header is no key");
        assert_eq!(key_path_at("a = [\n 1,\n \"x\"]\n", 13), None);
        assert_eq!(key_path_at("top = 1", 6).as_deref(), Some("top"));
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
        expected.set_by_options = vec!["updates".into(), "seed".into()];
        assert_eq!(cfg, expected);
        // The text reruns the run; its values are then the file's.
        expected.set_by_options.clear();
        assert_eq!(RunConfig::parse(&text, origin).unwrap(), expected);
    }

    /// A value the user typed as an option is reported as that option, not as a field of a
    /// config file that does not have it (`<built-in default>: run.updates = 0` was the error
    /// of `--updates 0`); the same value in the file still names the file and field.
    #[test]
    fn a_bad_override_is_reported_as_its_option() {
        let origin = Path::new("a.toml");
        let e = RunConfig::with_run_overrides(DEFAULT_CONFIG, origin, &[("updates", Some(0))])
            .unwrap_err();
        assert!(
            e.to_string().starts_with("--updates 0: must be at least 1"),
            "{e}"
        );
        let e = RunConfig::with_run_overrides(DEFAULT_CONFIG, origin, &[("seed", Some(u64::MAX))])
            .unwrap_err();
        assert!(
            e.to_string().starts_with("--seed 18446744073709551615: "),
            "{e}"
        );
        let zero = DEFAULT_CONFIG.replace("updates = 40", "updates = 0");
        let e = RunConfig::with_run_overrides(&zero, origin, &[("seed", Some(3))]).unwrap_err();
        assert!(e.to_string().starts_with("a.toml: run.updates = 0"), "{e}");
        let e = RunConfig::with_run_overrides(&zero, origin, &[]).unwrap_err();
        assert!(e.to_string().starts_with("a.toml: run.updates = 0"), "{e}");
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
    fn nonfinite_reruns_are_a_bounded_count_and_the_fault_names_a_rollout_of_the_update() {
        assert_eq!(RunConfig::default_config().run.nonfinite_reruns, 0);
        let with = |line: &str| {
            parse(&DEFAULT_CONFIG.replace("seed = 1\n", &format!("seed = 1\n{line}\n")))
        };
        assert_eq!(
            with("nonfinite_reruns = 100").unwrap().run.nonfinite_reruns,
            100
        );
        assert_eq!(
            with("nonfinite_reruns = 101").unwrap_err().to_string(),
            "test.toml: run.nonfinite_reruns = 101: must be at most 100: a rerun repeats the \
             rollout (on a robot, for real), and a cost that is still not finite after that many \
             is no transient fault"
        );
        for bad in [
            "nonfinite_reruns = -1",
            "nonfinite_reruns = 1.5",
            "nonfinite_reruns = \"2\"",
        ] {
            let e = with(bad).unwrap_err().to_string();
            assert!(e.starts_with("test.toml: run.nonfinite_reruns: "), "{e}");
            assert!(e.contains(bad), "the line is shown: {e}");
        }
        let e = with("nonfinite_rerun = 2").unwrap_err().to_string();
        assert!(e.contains("unknown field `nonfinite_rerun`"), "{e}");

        let cfg = with("fault_nan_first_attempt = { update = 3, rollout = 14 }").unwrap();
        assert!(cfg.run.fault_nan(3, 14, false));
        assert!(!cfg.run.fault_nan(3, 14, true), "a rerun is not hit");
        assert!(!cfg.run.fault_nan(3, 13, false) && !cfg.run.fault_nan(4, 14, false));
        assert_eq!(
            with("fault_nan_first_attempt = { update = 3, rollout = 15 }")
                .unwrap_err()
                .to_string(),
            "test.toml: run.fault_nan_first_attempt.rollout = 15: must be below \
             optimizer.rollouts = 15"
        );
        let e = with("fault_nan_first_attempt = { update = 3, rollout = 1, attempts = 2 }")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown field `attempts`"), "{e}");
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
    fn the_fields_that_set_p_and_n_are_named_as_messages_name_them() {
        let fields = |text: &str| parse(text).unwrap().size_fields().unwrap();
        assert_eq!(
            fields(include_str!("../../../config/tball.toml")),
            ("task.tball.basis_functions".into(), "task.tball.dt".into())
        );
        assert_eq!(
            fields(include_str!("../../../config/external-reach.toml")),
            (
                "task.external.parameters".into(),
                "task.external.steps".into()
            )
        );
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
            (
                "target_y = 0.70",
                "target_y = 0.70\na = 1.0\nb = 1.0\nc = 1.0\nd = 1.0\ne = 1.0\nf = 1.0\ng = 1.0",
                "task.external.settings = (9 settings): at most 8",
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

    /// `text` with each `(from, to)` replaced once; `from` must be there.
    fn edit(text: &str, edits: &[(&str, &str)]) -> String {
        edits.iter().fold(text.to_string(), |t, (from, to)| {
            assert!(t.contains(from), "{from}");
            t.replacen(from, to, 1)
        })
    }

    fn error(text: &str) -> String {
        parse(text).unwrap_err().to_string()
    }

    const TBALL: &str = include_str!("../../../config/tball.toml");
    const EXTERNAL: &str = include_str!("../../../config/external-reach.toml");

    #[test]
    fn sizes_that_would_abort_or_hang_are_refused_before_anything_is_built() {
        // K: the update keeps four K×K matrices (K = 100000 aborted on an allocation).
        assert_eq!(
            error(&edit(
                DEFAULT_CONFIG,
                &[("rollouts = 15", "rollouts = 100000")]
            )),
            "test.toml: optimizer.rollouts = 100000: must be at most 10000 (the update keeps \
             four K×K matrices: 3.2 GB at K = 10000)"
        );
        let at_most = parse(&edit(
            DEFAULT_CONFIG,
            &[("rollouts = 15", "rollouts = 10000")],
        ));
        assert_eq!(at_most.unwrap().optimizer.rollouts, MAX_ROLLOUTS);
        // P: a P×P covariance (P = 1000000 aborted on an 8 TB allocation).
        assert_eq!(
            error(&edit(
                EXTERNAL,
                &[("parameters = 10", "parameters = 1000000")]
            )),
            format!(
                "test.toml: task.external.parameters = 1000000: must be between 1 and 5000: \
                 {PARAMETERS_WHY}"
            )
        );
        assert!(
            error(&edit(EXTERNAL, &[("steps = 101", "steps = 1000001")])).starts_with(
                "test.toml: task.external.steps = 1000001: must be between 1 and 1000000"
            )
        );
        // N = duration/dt + 1, computed without building the DMP (which aborted in `check`).
        assert_eq!(
            error(&edit(DEFAULT_CONFIG, &[("dt = 0.01", "dt = 1e-12")])),
            "test.toml: task.via-point.dt = 1e-12: N = duration/dt + 1 = 1000000000001 steps; \
             at most 1000000"
        );
        assert_eq!(
            error(&edit(TBALL, &[("dt = 0.001", "dt = 1e-12")])),
            "test.toml: task.tball.dt = 1e-12: N = duration/dt + 1 = 1000000000001 steps; at \
             most 1000000"
        );
        // Basis functions: building the DMP takes N·B² evaluations (3000: 23 s, 10000: hung),
        // and P = dimensions × B.
        let start = std::time::Instant::now();
        let e = error(&edit(
            DEFAULT_CONFIG,
            &[("basis_functions = 2", "basis_functions = 3000")],
        ));
        assert!(
            e.starts_with(
                "test.toml: task.via-point.basis_functions = 3000: with N = 101 steps, building \
                 the DMP takes N × basis_functions² = 9.1e8 basis-function evaluations"
            ),
            "{e}"
        );
        for b in ["10000", "100000000"] {
            let e = error(&edit(
                DEFAULT_CONFIG,
                &[("basis_functions = 2", &format!("basis_functions = {b}"))],
            ));
            assert!(
                e.starts_with(&format!(
                    "test.toml: task.via-point.basis_functions = {b}: P must be at most 5000"
                )),
                "{e}"
            );
        }
        let e = error(&edit(
            TBALL,
            &[("basis_functions = 3", "basis_functions = 800")],
        ));
        assert!(
            e.starts_with(
                "test.toml: task.tball.basis_functions = 800: P must be at most 5000 (7 joints × \
                 800 = 5600 parameters)"
            ),
            "{e}"
        );
        assert!(start.elapsed() < std::time::Duration::from_secs(5));
    }

    #[test]
    fn memory_the_run_would_need_is_checked_from_k_p_and_n() {
        let per_time_step = |text: &str| {
            edit(
                text,
                &[("weighting = \"episodic\"", "weighting = \"per-time-step\"")],
            )
        };
        // K×N dominates; K is nearer its limit than N, so K is named.
        let text = per_time_step(&edit(
            DEFAULT_CONFIG,
            &[
                ("rollouts = 15", "rollouts = 5000"),
                ("dt = 0.01", "dt = 1e-5"),
            ],
        ));
        assert_eq!(
            error(&text),
            "test.toml: optimizer.rollouts = 5000: with K = 5000 rollouts, P = 2 parameters and \
             N = 100001 steps the run would need about 12.8 GB of memory (K×N costs, cost-to-go \
             and probabilities: 12.0 GB); at most 4.3 GB (4 GiB)"
        );
        // Episodic, a little fewer: the cost batch (3.2 GB) and the K×K matrices (0.5 GB).
        let episodic = edit(
            DEFAULT_CONFIG,
            &[
                ("rollouts = 15", "rollouts = 4000"),
                ("dt = 0.01", "dt = 1e-5"),
            ],
        );
        let need = parse(&episodic).unwrap().memory_need().unwrap();
        assert!((3.70e9..3.75e9).contains(&need.total()), "{need:?}");
        // N nearer its limit: the field that sets N is named.
        let text = per_time_step(&edit(
            EXTERNAL,
            &[
                ("rollouts = 10", "rollouts = 200"),
                ("steps = 101", "steps = 1000000"),
            ],
        ));
        assert_eq!(
            error(&text),
            "test.toml: task.external.steps = 1000000: with K = 200 rollouts, P = 10 parameters \
             and N = 1000000 steps the run would need about 4.8 GB of memory (K×N costs, \
             cost-to-go and probabilities: 4.8 GB); at most 4.3 GB (4 GiB)"
        );
        // The paper's runs need next to nothing.
        for text in [DEFAULT_CONFIG, TBALL, EXTERNAL] {
            assert!(parse(text).unwrap().memory_need().unwrap().total() < 1e6);
        }
        // The pieces that scale: K×K (4 matrices of the 14 rollouts that enter the update when
        // rollout 0 does not), P×P, K×P.
        let text = edit(
            EXTERNAL,
            &[
                ("parameters = 10", "parameters = 3"),
                (
                    "evaluation_in_update = true",
                    "evaluation_in_update = false",
                ),
            ],
        )
        .lines()
        .map(|l| {
            if l.starts_with("initial_mean") {
                "initial_mean = [0.0, 0.0, 0.0]"
            } else {
                l
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
        let need = parse(&text).unwrap().memory_need().unwrap();
        let part = |what: &str| need.parts.iter().find(|p| p.what == what).unwrap().bytes;
        assert_eq!(part("K×K matrices of the update"), 8.0 * 4.0 * 9.0 * 9.0);
        assert_eq!(part("P×P covariances"), 8.0 * 8.0 * 9.0);
        assert_eq!(part("K×P samples"), 8.0 * 4.0 * 10.0 * 3.0);
        assert_eq!(part("K×N costs"), 8.0 * 10.0 * 101.0);
    }

    #[test]
    fn lambdas_are_bounded_where_the_arithmetic_stays_finite() {
        let why = LAMBDA_WHY;
        for (from, to, expect) in [
            (
                "lambda_init = 2000.0",
                "lambda_init = 1e300",
                format!("optimizer.lambda_init = 1e300: must be within [1e-50, 1e50]: {why}"),
            ),
            (
                "lambda_min = 2.0",
                "lambda_min = 1e-60",
                format!(
                    "optimizer.lambda_min = 1e-60: must be 0 (no lower bound) or within \
                     [1e-50, 1e50]: {why}"
                ),
            ),
            (
                "lambda_max = inf",
                "lambda_max = 1e60",
                format!(
                    "optimizer.lambda_max = 1e60: must be inf (no upper bound) or within \
                     [1e-50, 1e50]: {why}"
                ),
            ),
        ] {
            let text = edit(DEFAULT_CONFIG, &[(from, to)]);
            assert_eq!(error(&text), format!("test.toml: {expect}"));
        }
        // The ends of the range are allowed, and λ_min = 0 means no lower bound.
        let text = edit(
            DEFAULT_CONFIG,
            &[
                ("lambda_min = 2.0", "lambda_min = 0.0"),
                ("lambda_max = inf", "lambda_max = 1e50"),
            ],
        );
        parse(&text).unwrap();
    }

    /// Where the λ bounds come from: past about 1e154, λ² overflows in the per-time-step update
    /// of P = 2, which the core refuses (if it learns to compute these, the bounds can be
    /// widened and this test changed). The eliteness h has no upper bound: the core computes
    /// the update for any finite h (weights reach down to exp(−h), which underflows to 0).
    #[test]
    fn past_the_lambda_bounds_the_update_overflows_and_any_eliteness_computes() {
        let run = |cfg: &RunConfig| crate::run_session(cfg, cfg.run.seed, &mut crate::NoObserver);
        let per_step = parse(&edit(
            DEFAULT_CONFIG,
            &[("weighting = \"episodic\"", "weighting = \"per-time-step\"")],
        ))
        .unwrap();
        for (lambda, overflows) in [(1e50, false), (1e160, true)] {
            let mut cfg = per_step.clone();
            cfg.optimizer.lambda_init = lambda;
            cfg.optimizer.lambda_min = Some(lambda);
            match run(&cfg) {
                Ok((_, last)) => {
                    assert!(!overflows, "λ = {lambda:e} computed");
                    assert!(last.covariance.iter().all(|v| v.is_finite()));
                }
                Err(e) => {
                    assert!(overflows, "λ = {lambda:e}: {e}");
                    assert!(e.to_string().contains("non-finite"), "{e}");
                }
            }
        }
        // Two rollouts: the one exploration rollout's weight is about exp(−h); h = 400 gave NaN
        // before the core scaled its eigen-decompositions (exp(−2h)·λ² left f64's range).
        for weighting in ["episodic", "per-time-step"] {
            for h in [400.0, 1e308] {
                let mut cfg = parse(&edit(
                    DEFAULT_CONFIG,
                    &[
                        ("rollouts = 15", "rollouts = 2"),
                        ("lambda_init = 2000.0", "lambda_init = 1.0"),
                        ("lambda_min = 2.0", "lambda_min = 1.0"),
                        (
                            "weighting = \"episodic\"",
                            &format!("weighting = \"{weighting}\""),
                        ),
                    ],
                ))
                .unwrap();
                cfg.optimizer.eliteness = Some(h);
                let (_, last) = run(&cfg).unwrap_or_else(|e| panic!("h = {h:e}: {e}"));
                assert!(last.covariance.iter().all(|v| v.is_finite()), "h = {h:e}");
            }
        }
        let cfg = parse(&edit(
            DEFAULT_CONFIG,
            &[("eliteness = 15.0", "eliteness = 1e308")],
        ))
        .unwrap();
        assert_eq!(cfg.optimizer.eliteness, Some(1e308));
    }

    #[test]
    fn a_bad_lambda_bound_is_named_itself_not_lambda_init() {
        let why = LAMBDA_WHY;
        for (from, to, expect) in [
            (
                "lambda_min = 2.0",
                "lambda_min = inf",
                format!(
                    "optimizer.lambda_min = inf: must be 0 (no lower bound) or within \
                     [1e-50, 1e50]: {why}"
                ),
            ),
            (
                "lambda_min = 2.0",
                "lambda_min = nan",
                format!(
                    "optimizer.lambda_min = NaN: must be 0 (no lower bound) or within \
                     [1e-50, 1e50]: {why}"
                ),
            ),
            (
                "lambda_max = inf",
                "lambda_max = nan",
                format!(
                    "optimizer.lambda_max = NaN: must be inf (no upper bound) or within \
                     [1e-50, 1e50]: {why}"
                ),
            ),
            (
                "lambda_max = inf",
                "lambda_max = 1.0",
                "optimizer.lambda_max = 1: must be >= lambda_min = 2".to_string(),
            ),
            (
                "lambda_min = 2.0",
                "lambda_min = 5000.0",
                "optimizer.lambda_init = 2000: must lie within [lambda_min, lambda_max] = \
                 [5000, inf]"
                    .to_string(),
            ),
        ] {
            let text = edit(DEFAULT_CONFIG, &[(from, to)]);
            assert_eq!(error(&text), format!("test.toml: {expect}"));
        }
    }

    #[test]
    fn task_and_schedule_errors_name_the_field_and_value() {
        for (text, expect) in [
            (
                edit(DEFAULT_CONFIG, &[("dt = 0.01", "dt = 0.0")]),
                "task.via-point.dt = 0: must be > 0 and at most duration = 1",
            ),
            (
                edit(DEFAULT_CONFIG, &[("dt = 0.01", "dt = 0.03")]),
                "task.via-point.dt = 0.03: duration = 1 must be a whole number of steps",
            ),
            (
                edit(
                    DEFAULT_CONFIG,
                    &[("basis_functions = 2", "basis_functions = 0")],
                ),
                "task.via-point.basis_functions = 0: must be at least 1",
            ),
            (
                edit(DEFAULT_CONFIG, &[("goal = 1.0", "goal = nan")]),
                "task.via-point.goal = NaN: must be finite",
            ),
            (
                edit(
                    DEFAULT_CONFIG,
                    &[("viapoint_time = 0.5", "viapoint_time = 0.555")],
                ),
                "task.via-point.viapoint_time = 0.555: must be a grid point within [0, duration]",
            ),
            (
                edit(TBALL, &[("ball_height = 0.52", "ball_height = 0.01")]),
                "task.tball.ball_height = 0.01: the ball's centre must be at least its radius \
                 above the ground",
            ),
            (
                edit(TBALL, &[("start_pose = [0.8,", "start_pose = [nan,")]),
                "task.tball.start_pose[0] = NaN: must be finite",
            ),
            (
                edit(TBALL, &[("duration = 1.0", "duration = -1.0")]),
                "task.tball.duration = -1: must be finite and > 0",
            ),
        ] {
            assert_eq!(error(&text), format!("test.toml: {expect}"));
        }
        // Several [[schedule]] entries: the bad one is named by its place (0-based).
        let three = |set: &str, value: &str| {
            DEFAULT_CONFIG.replace(
                "[[schedule]]",
                &format!(
                    "[[schedule]]\nfrom_update = 5\nset = \"viapoint\"\nvalue = 0.2\n\n\
                     [[schedule]]\nfrom_update = 10\nset = \"{set}\"\nvalue = {value}\n\n\
                     [[schedule]]"
                ),
            )
        };
        parse(&three("viapoint", "0.25")).unwrap();
        assert_eq!(
            error(&three("viapiont", "0.25")),
            "test.toml: schedule[1].set = \"viapiont\": task `via-point` has no setting \
             `viapiont` (it has: viapoint)"
        );
        assert_eq!(
            error(&three("viapoint", "nan")),
            "test.toml: schedule[1].value = NaN: task `via-point`, setting `viapoint`: must be \
             finite"
        );
        let text = edit(TBALL, &[("value = 0.47", "value = 0.01")]);
        assert_eq!(
            error(&text),
            "test.toml: schedule[0].value = 0.01: task `tball`, setting `ball_height`: the \
             ball's centre must be at least its radius above the ground"
        );
        // The paper's 5 cm lower ball given in cm: accepted, it made every rollout from update
        // 20 on a miss.
        let text = edit(TBALL, &[("value = 0.47", "value = 47")]);
        assert_eq!(
            error(&text),
            "test.toml: schedule[0].value = 47: task `tball`, setting `ball_height`: out of the \
             bat's reach: the ball's centre can be at most shoulder[2] + upper_arm + forearm + \
             hand + bat_length + bat_radius + ball_radius above the ground (2.435 m with \
             config/tball.toml's arm); heights are in metres"
        );
        // Finite settings under which every rollout's cost overflows passed, and failed the
        // run at its first update, or at the schedule's after learning up to it.
        let text = edit(
            TBALL,
            &[
                ("miss_gap_weight = 100.0", "miss_gap_weight = 1e308"),
                ("ball_height = 0.52", "ball_height = 2.4"),
                ("tee_x = 0.76", "tee_x = -0.9"),
            ],
        );
        assert_eq!(
            error(&text),
            "test.toml: task.tball = {ball_height = 2.4, tee_x = -0.9, tee_y = -0.53}: task \
             `tball`: with these settings a rollout of the initial mean gives the terminal cost \
             = inf: costs must be finite, so every update would fail"
        );
        // A tee given in cm (76 for 0.76): accepted, and every rollout missed.
        let text = edit(TBALL, &[("tee_x = 0.76", "tee_x = 76")]);
        assert_eq!(
            error(&text),
            "test.toml: task.tball.tee_x = 76: out of the bat's reach: the tee can be at most \
             upper_arm + forearm + hand + bat_length + bat_radius + ball_radius (1.185 m with \
             config/tball.toml's arm) from the shoulder, horizontally: hypot(tee_x - \
             shoulder[0], tee_y - shoulder[1]), with the tee's other coordinate as set; \
             positions are in metres"
        );
        assert_eq!(
            error(&three("viapoint", "1e308")),
            "test.toml: schedule[1].value = 1e308: from update 10 the settings would be \
             {viapoint = 1e308}: task `via-point`: with these settings a rollout of the initial \
             mean gives the cost of step 50 = inf: costs must be finite, so every update would \
             fail"
        );
    }

    #[test]
    fn two_task_sections_are_one_clear_error() {
        let text = format!("{DEFAULT_CONFIG}\n[task.tball]\nduration = 1.0\n");
        assert_eq!(
            error(&text),
            "test.toml: task: exactly one of [task.via-point], [task.tball], [task.external] \
             (found: [task.tball], [task.via-point])"
        );
        let start = DEFAULT_CONFIG.find("[task.via-point]").unwrap();
        let end = DEFAULT_CONFIG.find("[[schedule]]").unwrap();
        let text = format!(
            "{}[task]\n\n{}",
            &DEFAULT_CONFIG[..start],
            &DEFAULT_CONFIG[end..]
        );
        assert_eq!(
            error(&text),
            "test.toml: task: exactly one of [task.via-point], [task.tball], [task.external] \
             (found: none)"
        );
    }

    /// Rollout 0 is θ itself: with K = 1 the update sees only it and learns nothing, whether or
    /// not it enters the update. K = 2 learns.
    #[test]
    fn one_rollout_is_refused_as_it_learns_nothing() {
        for eval in ["true", "false"] {
            for k in ["0", "1"] {
                let text = edit(
                    DEFAULT_CONFIG,
                    &[
                        ("rollouts = 15", &format!("rollouts = {k}")),
                        (
                            "evaluation_in_update = true",
                            &format!("evaluation_in_update = {eval}"),
                        ),
                    ],
                );
                assert_eq!(
                    error(&text),
                    format!(
                        "test.toml: optimizer.rollouts = {k}: too few rollouts: at least one \
                         must enter the update besides the evaluation rollout (rollout 0 is θ \
                         itself and cannot move the distribution, even when it enters the \
                         update), so at least 2"
                    )
                );
            }
        }
        // K = 2 learns, with or without the evaluation in the update.
        let mut cfg = RunConfig::default_config();
        cfg.run.updates = Some(5);
        for eval in [true, false] {
            cfg.optimizer.rollouts = 2;
            cfg.optimizer.evaluation_in_update = eval;
            cfg.validate().unwrap();
            let (summaries, _) =
                crate::run_session(&cfg, cfg.run.seed, &mut crate::NoObserver).unwrap();
            assert!(summaries[4].eval_cost < summaries[0].eval_cost, "{eval}");
        }
    }

    #[test]
    fn a_task_change_is_judged_with_the_settings_in_force() {
        let cfg = parse(TBALL).unwrap();
        // Alone, a tee 1 m along x is within the bat's reach (1.053 m from the shoulder, at
        // most 1.185 m)…
        cfg.check_task_change(&[], "tee_x", 1.0).unwrap();
        // …but not once an earlier change has moved it to y = 0.6 (1.281 m): judged with the
        // config's tee_y = -0.53 instead, it would pass.
        let in_force = [("tee_y".to_string(), 0.6)];
        let e = cfg
            .check_task_change(&in_force, "tee_x", 1.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("task `tball`: tee_x = 1: out of the bat's reach")
                && e.ends_with("(together with the settings in force that differ from the config: tee_y = 0.6)"),
            "{e}"
        );
        // The same for costs that overflow only together. With a miss's gap weighted 10³⁰⁸ per
        // m, a ball at 2.4 m (gap 1.504 m) or a tee at x = -0.9, behind the robot (1.187 m),
        // is missed at a finite cost, both together (1.852 m) at an infinite one.
        let text = edit(
            TBALL,
            &[("miss_gap_weight = 100.0", "miss_gap_weight = 1e308")],
        );
        let cfg = parse(&text).unwrap();
        cfg.check_task_change(&[], "tee_x", -0.9).unwrap();
        cfg.check_task_change(&[], "ball_height", 2.4).unwrap();
        let in_force = [("ball_height".to_string(), 2.4)];
        let e = cfg
            .check_task_change(&in_force, "tee_x", -0.9)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("terminal cost = inf")
                && e.ends_with("(together with the settings in force that differ from the config: ball_height = 2.4)"),
            "{e}"
        );
        // A tee the run reached by moving y, then x (1.15 m straight ahead of the shoulder), is
        // in force whatever order its coordinates are set in: x first, with the config's
        // y = -0.53, is out of reach (1.196 m), and every change was refused.
        let ahead = [("tee_x".to_string(), 1.15), ("tee_y".to_string(), -0.2)];
        let tball = parse(TBALL).unwrap();
        tball.check_task_change(&ahead, "ball_height", 0.5).unwrap();
        // Settings in force that the change replaces are not named.
        let e = cfg
            .check_task_change(&[("tee_x".to_string(), 0.1)], "tee_x", 1e300)
            .unwrap_err()
            .to_string();
        assert!(!e.contains("in force"), "{e}");
        // An unknown setting in force is an error, not ignored.
        assert!(cfg
            .check_task_change(&[("tee_z".to_string(), 0.0)], "tee_x", 0.1)
            .is_err());
    }

    #[test]
    fn a_setting_for_another_method_or_weighting_says_what_it_applies_to() {
        assert_eq!(
            error(&edit(
                DEFAULT_CONFIG,
                &[(
                    "weighting = \"episodic\"",
                    "weighting = \"episodic\"\ntemporal_averaging = \"basis-activation\""
                )]
            )),
            "test.toml: optimizer.temporal_averaging = \"basis-activation\": only applies to \
             weighting = \"per-time-step\", not to weighting = \"episodic\": remove it"
        );
        assert_eq!(
            error(&edit(
                DEFAULT_CONFIG,
                &[("eliteness = 15.0", "eliteness = 15.0\nelites = 3")]
            )),
            "test.toml: optimizer.elites = 3: only applies to method cem, not to method = \
             \"pi2-cma\": remove it"
        );
    }

    /// `optimizer.covariance`: "full" (the default, also when absent) or "per-dimension", whose
    /// block size is the task's basis functions per DMP dimension; anything else, a method
    /// that does not adapt Σ, or a task without a DMP shape is refused by name.
    #[test]
    fn covariance_structure_is_a_checked_setting() {
        let tball = include_str!("../../../config/tball.toml");
        assert_eq!(
            parse(tball).unwrap().hyperparameters().covariance,
            CovarianceStructure::Full
        );
        let per_dim = tball.replace(
            "[optimizer]\n",
            "[optimizer]\ncovariance = \"per-dimension\"\n",
        );
        assert_eq!(
            parse(&per_dim).unwrap().hyperparameters().covariance,
            CovarianceStructure::PerDimension { block: 3 }
        );
        let full = tball.replace("[optimizer]\n", "[optimizer]\ncovariance = \"full\"\n");
        assert_eq!(
            parse(&full).unwrap().hyperparameters(),
            parse(tball).unwrap().hyperparameters()
        );
        let e = parse(&tball.replace("[optimizer]\n", "[optimizer]\ncovariance = \"per-joint\"\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("test.toml: optimizer.covariance: ")
                && e.contains("per-joint")
                && e.contains("expected `full` or `per-dimension`"),
            "{e}"
        );
        let pi2 = DEFAULT_CONFIG
            .replace("method = \"pi2-cma\"", "method = \"pi2\"")
            .replace("lambda_min = 2.0\n", "")
            .replace("lambda_max = inf\n", "")
            .replace(
                "[optimizer]\n",
                "[optimizer]\ncovariance = \"per-dimension\"\n",
            );
        let e = parse(&pi2).unwrap_err().to_string();
        assert!(
            e.starts_with("test.toml: optimizer.covariance = \"per-dimension\": only applies"),
            "{e}"
        );
        let external = include_str!("../../../config/external-reach.toml").replace(
            "[optimizer]\n",
            "[optimizer]\ncovariance = \"per-dimension\"\n",
        );
        let e = parse(&external).unwrap_err().to_string();
        assert!(
            e.contains("optimizer.covariance = \"per-dimension\": needs the policy's DMP shape"),
            "{e}"
        );
    }
}
