//! Conversions between the core's types and the recorded protobuf messages, and the run config
//! back to TOML text.

use nalgebra::{DMatrix, DVector};
use pi2cma::{
    CostMapping, CovarianceStructure, Distribution, EigenvalueBounds, Exploration, Hyperparameters,
    TemporalAveraging, Weighting,
};
use session::{CovarianceName, RunConfig, TaskSection};

use crate::proto;

/// A recorded distribution or hyperparameters message that does not convert back to the core's
/// type. It knows no file: the caller, which read the message, names the file and update
/// ([`crate::RecordError::Update`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ConvertError {
    /// A distribution whose mean or covariance does not have the length its `dim` says.
    #[error(
        "distribution of dim {dim} has {mean} mean and {covariance} covariance entries \
         (expected {dim} and {})",
        dim * dim
    )]
    DistributionShape {
        /// The dimension P the message states.
        dim: usize,
        /// How many mean values it holds (should be P).
        mean: usize,
        /// How many covariance values it holds (should be P × P).
        covariance: usize,
    },
    /// An enum field of the hyperparameters holding a value this build does not know (a
    /// recording from a newer build, or damage).
    #[error("hyperparameters.{field} = {value}: unknown")]
    UnknownValue {
        /// The hyperparameters field (e.g. `weighting`).
        field: &'static str,
        /// The value it holds.
        value: i32,
    },
}

pub(crate) fn distribution_to_proto(d: &Distribution) -> proto::Distribution {
    let n = d.dim();
    let mut covariance = Vec::with_capacity(n * n);
    for r in 0..n {
        for c in 0..n {
            covariance.push(d.covariance[(r, c)]);
        }
    }
    proto::Distribution {
        dim: n as u32,
        mean: d.mean.as_slice().to_vec(),
        covariance,
    }
}

/// The recorded distribution, bit for bit (not re-validated: a recording holds what the core
/// produced). Errors name the inconsistent length.
pub fn distribution_from_proto(d: &proto::Distribution) -> Result<Distribution, ConvertError> {
    let n = d.dim as usize;
    if d.mean.len() != n || d.covariance.len() != n * n {
        return Err(ConvertError::DistributionShape {
            dim: n,
            mean: d.mean.len(),
            covariance: d.covariance.len(),
        });
    }
    Ok(Distribution {
        mean: DVector::from_column_slice(&d.mean),
        covariance: DMatrix::from_row_slice(n, n, &d.covariance),
    })
}

pub(crate) fn hyperparameters_to_proto(hp: &Hyperparameters) -> proto::Hyperparameters {
    let mut p = proto::Hyperparameters {
        rollouts: hp.rollouts as u32,
        evaluation_in_update: hp.evaluation_in_update,
        covariance_block: match hp.covariance {
            CovarianceStructure::Full => 0,
            CovarianceStructure::PerDimension { block } => block as u32,
        },
        ..Default::default()
    };
    match hp.mapping {
        CostMapping::Exponential { eliteness } => {
            p.set_mapping(proto::CostMapping::Exponential);
            p.eliteness = eliteness;
        }
        CostMapping::Elites { count } => {
            p.set_mapping(proto::CostMapping::Elites);
            p.elites = count as u32;
        }
    }
    match hp.exploration {
        Exploration::Constant => p.set_exploration(proto::Exploration::Constant),
        Exploration::Decay { factor } => {
            p.set_exploration(proto::Exploration::Decay);
            p.decay = factor;
        }
        Exploration::Adaptive { bounds } => {
            p.set_exploration(proto::Exploration::Adaptive);
            p.lambda_min = bounds.min;
            p.lambda_max = bounds.max;
        }
    }
    p.set_weighting(match hp.weighting {
        Weighting::Episodic => proto::Weighting::Episodic,
        Weighting::PerTimeStep {
            temporal: TemporalAveraging::RemainingSteps,
        } => proto::Weighting::PerTimeStepRemainingSteps,
        Weighting::PerTimeStep {
            temporal: TemporalAveraging::BasisActivation,
        } => proto::Weighting::PerTimeStepBasisActivation,
    });
    p
}

/// The core's hyperparameters from their recorded form; errors name the unknown field value.
pub fn hyperparameters_from_proto(
    p: &proto::Hyperparameters,
) -> Result<Hyperparameters, ConvertError> {
    let unknown = |field, value| ConvertError::UnknownValue { field, value };
    let mapping = match proto::CostMapping::try_from(p.mapping) {
        Ok(proto::CostMapping::Exponential) => CostMapping::Exponential {
            eliteness: p.eliteness,
        },
        Ok(proto::CostMapping::Elites) => CostMapping::Elites {
            count: p.elites as usize,
        },
        _ => return Err(unknown("mapping", p.mapping)),
    };
    let exploration = match proto::Exploration::try_from(p.exploration) {
        Ok(proto::Exploration::Constant) => Exploration::Constant,
        Ok(proto::Exploration::Decay) => Exploration::Decay { factor: p.decay },
        Ok(proto::Exploration::Adaptive) => Exploration::Adaptive {
            bounds: EigenvalueBounds {
                min: p.lambda_min,
                max: p.lambda_max,
            },
        },
        _ => return Err(unknown("exploration", p.exploration)),
    };
    let weighting = match proto::Weighting::try_from(p.weighting) {
        Ok(proto::Weighting::Episodic) => Weighting::Episodic,
        Ok(proto::Weighting::PerTimeStepRemainingSteps) => Weighting::PerTimeStep {
            temporal: TemporalAveraging::RemainingSteps,
        },
        Ok(proto::Weighting::PerTimeStepBasisActivation) => Weighting::PerTimeStep {
            temporal: TemporalAveraging::BasisActivation,
        },
        _ => return Err(unknown("weighting", p.weighting)),
    };
    Ok(Hyperparameters {
        rollouts: p.rollouts as usize,
        mapping,
        exploration,
        weighting,
        evaluation_in_update: p.evaluation_in_update,
        covariance: match p.covariance_block {
            0 => CovarianceStructure::Full,
            block => CovarianceStructure::PerDimension {
                block: block as usize,
            },
        },
    })
}

/// The config as TOML that [`RunConfig::parse`] reads back to an equal config. Used when the
/// caller has no original file text to record.
pub fn config_to_toml(cfg: &RunConfig) -> String {
    use toml::{Table, Value};
    let mut root = Table::new();

    let mut run = Table::new();
    run.insert("name".into(), Value::String(cfg.run.name.clone()));
    run.insert("seed".into(), int(cfg.run.seed));
    if let Some(n) = cfg.run.updates {
        run.insert("updates".into(), int(n));
    }
    if cfg.run.nonfinite_reruns > 0 {
        run.insert(
            "nonfinite_reruns".into(),
            int(u64::from(cfg.run.nonfinite_reruns)),
        );
    }
    if let Some(f) = cfg.run.fault_nan_first_attempt {
        let mut t = Table::new();
        if let Some(u) = f.update {
            t.insert("update".into(), int(u));
        }
        if let Some(k) = f.rollout {
            t.insert("rollout".into(), int(k as u64));
        }
        run.insert("fault_nan_first_attempt".into(), Value::Table(t));
    }
    root.insert("run".into(), Value::Table(run));

    let o = &cfg.optimizer;
    let mut opt = Table::new();
    opt.insert("method".into(), Value::String(o.method.name().into()));
    opt.insert("rollouts".into(), int(o.rollouts as u64));
    opt.insert(
        "evaluation_in_update".into(),
        Value::Boolean(o.evaluation_in_update),
    );
    opt.insert("weighting".into(), Value::String(o.weighting.name().into()));
    if o.temporal_averaging.is_some() {
        let t = match cfg.weighting() {
            Weighting::PerTimeStep {
                temporal: TemporalAveraging::BasisActivation,
            } => "basis-activation",
            _ => "remaining-steps",
        };
        opt.insert("temporal_averaging".into(), Value::String(t.into()));
    }
    // Written only when not the default, so that configs of earlier runs read back unchanged.
    if o.covariance == CovarianceName::PerDimension {
        opt.insert("covariance".into(), Value::String("per-dimension".into()));
    }
    opt.insert("lambda_init".into(), Value::Float(o.lambda_init));
    let floats = [
        ("eliteness", o.eliteness),
        ("decay", o.decay),
        ("lambda_min", o.lambda_min),
        ("lambda_max", o.lambda_max),
    ];
    for (k, v) in floats {
        if let Some(v) = v {
            opt.insert(k.into(), Value::Float(v));
        }
    }
    if let Some(e) = o.elites {
        opt.insert("elites".into(), int(e as u64));
    }
    root.insert("optimizer".into(), Value::Table(opt));

    let mut task = Table::new();
    let mut unrendered = Vec::new();
    match &cfg.task {
        TaskSection::ViaPoint(v) => {
            let mut t = Table::new();
            t.insert("basis_functions".into(), int(v.basis_functions as u64));
            for (k, x) in [
                ("duration", v.duration),
                ("dt", v.dt),
                ("start", v.start),
                ("goal", v.goal),
                ("viapoint", v.viapoint),
                ("viapoint_time", v.viapoint_time),
                ("viapoint_weight", v.viapoint_weight),
                ("rollout_delay_ms", v.rollout_delay_ms),
            ] {
                t.insert(k.into(), Value::Float(x));
            }
            task.insert("via-point".into(), Value::Table(t));
        }
        other => unrendered.push(format!("task: {other:?}")),
    }
    root.insert("task".into(), Value::Table(task));

    if !cfg.schedule.is_empty() {
        let entries = cfg
            .schedule
            .iter()
            .map(|s| {
                let mut t = Table::new();
                t.insert("from_update".into(), int(s.from_update));
                t.insert("set".into(), Value::String(s.set.clone()));
                t.insert("value".into(), Value::Float(s.value));
                Value::Table(t)
            })
            .collect();
        root.insert("schedule".into(), Value::Array(entries));
    }
    if let Some(r) = &cfg.recording {
        let mut t = Table::new();
        if let Some(mb) = r.split_mb {
            t.insert("split_mb".into(), int(mb));
        }
        if !r.step_costs {
            t.insert("step_costs".into(), Value::Boolean(false));
        }
        root.insert("recording".into(), Value::Table(t));
    }
    if let Some(p) = &cfg.pipeline {
        let mut t = Table::new();
        t.insert("workers".into(), int(p.workers as u64));
        t.insert("max_workers".into(), int(p.max_workers as u64));
        t.insert("restart_limit".into(), int(u64::from(p.restart_limit)));
        t.insert("restart_window_s".into(), Value::Float(p.restart_window_s));
        t.insert("startup_timeout_ms".into(), int(p.startup_timeout_ms));
        t.insert("shutdown_timeout_ms".into(), int(p.shutdown_timeout_ms));
        t.insert("worker_spin_us".into(), int(p.worker_spin_us));
        if let Some(ms) = p.rollout_timeout_ms {
            t.insert("rollout_timeout_ms".into(), int(ms));
        }
        if let Some(u) = p.fault_nan_from_update {
            t.insert("fault_nan_from_update".into(), int(u));
        }
        if let Some(u) = p.fault_hang_at_update {
            t.insert("fault_hang_at_update".into(), int(u));
        }
        if let Some(r) = p.fault_hang_at_chunk_rollout {
            t.insert("fault_hang_at_chunk_rollout".into(), int(u64::from(r)));
        }
        root.insert("pipeline".into(), Value::Table(t));
    }
    let mut text =
        toml::to_string(&root).unwrap_or_else(|e| format!("# config could not be rendered: {e}\n"));
    // Sections this renderer does not know are kept as comments rather than dropped silently;
    // callers with the original file text should pass it instead (McapRecorder::with_config_text).
    for u in unrendered {
        text.push_str(&format!("# not rendered as TOML: {u}\n"));
    }
    text
}

fn int(v: u64) -> toml::Value {
    // TOML integers are i64: a seed above i64::MAX is clamped here (the exact seed is in the
    // metadata and in /run).
    toml::Value::Integer(i64::try_from(v).unwrap_or(i64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn config_round_trips_through_toml() {
        let mut cfg = RunConfig::default_config();
        let text = config_to_toml(&cfg);
        let back = RunConfig::parse(&text, Path::new("<built-in default>")).unwrap();
        assert_eq!(back, cfg, "{text}");
        cfg.optimizer.covariance = CovarianceName::PerDimension;
        let text = config_to_toml(&cfg);
        let back = RunConfig::parse(&text, Path::new("<built-in default>")).unwrap();
        assert_eq!(back, cfg, "{text}");
        cfg.run.nonfinite_reruns = 3;
        for (update, rollout) in [(Some(7), Some(2)), (Some(7), None), (None, None)] {
            cfg.run.fault_nan_first_attempt = Some(session::RolloutAt { update, rollout });
            let text = config_to_toml(&cfg);
            let back = RunConfig::parse(&text, Path::new("<built-in default>")).unwrap();
            assert_eq!(back, cfg, "{text}");
        }
    }

    /// The setting travels in the recorded hyperparameters; a recording from before the field
    /// existed (0, proto3's default) reads as one full covariance.
    #[test]
    fn covariance_structure_round_trips_and_defaults_to_full() {
        let mut cfg = RunConfig::default_config();
        cfg.optimizer.covariance = CovarianceName::PerDimension;
        let hp = cfg.hyperparameters();
        assert_eq!(
            hp.covariance,
            CovarianceStructure::PerDimension { block: 2 }
        );
        let p = hyperparameters_to_proto(&hp);
        assert_eq!(p.covariance_block, 2);
        assert_eq!(hyperparameters_from_proto(&p).unwrap(), hp);
        let old = proto::Hyperparameters {
            covariance_block: 0,
            ..p
        };
        assert_eq!(
            hyperparameters_from_proto(&old).unwrap().covariance,
            CovarianceStructure::Full
        );
    }

    #[test]
    fn hyperparameters_round_trip() {
        let cfg = RunConfig::default_config();
        let hp = cfg.hyperparameters();
        let back = hyperparameters_from_proto(&hyperparameters_to_proto(&hp)).unwrap();
        assert_eq!(back, hp);
    }

    #[test]
    fn distribution_round_trips_bit_for_bit() {
        let cov = DMatrix::from_row_slice(2, 2, &[4.0, 1.0 / 3.0, 1.0 / 3.0, 1.0]);
        let d = Distribution::new(DVector::from_vec(vec![0.1, -2.5]), cov).unwrap();
        assert_eq!(
            distribution_from_proto(&distribution_to_proto(&d)).unwrap(),
            d
        );
        let bad = proto::Distribution {
            dim: 3,
            mean: vec![0.0; 3],
            covariance: vec![0.0; 4],
        };
        assert_eq!(
            distribution_from_proto(&bad).unwrap_err().to_string(),
            "distribution of dim 3 has 3 mean and 4 covariance entries (expected 3 and 9)"
        );
    }
}
