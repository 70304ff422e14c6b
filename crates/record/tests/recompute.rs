//! A recorded in-process run re-read from its MCAP: every update recomputed from the recorded
//! inputs with the core gives the recorded new distribution bit for bit.

#![allow(clippy::unwrap_used)] // test helpers; a failed unwrap is a failed test

#[path = "../../../tests/config_edit.rs"]
mod config_edit;
#[path = "../../../tests/scratch.rs"]
mod scratch;

use std::path::PathBuf;

use config_edit::edited;
use record::recompute::{recompute_update, verify};
use record::{read_recording, McapRecorder};
use session::{run_session, RunConfig};

fn tmp(name: &str) -> PathBuf {
    scratch::shared("recompute").join(name)
}

fn record(cfg: &RunConfig, seed: u64, name: &str) -> PathBuf {
    let path = tmp(name);
    let mut rec = McapRecorder::create(&path).unwrap();
    run_session(cfg, seed, &mut rec).unwrap();
    assert_eq!(rec.finish().unwrap(), cfg.run.updates.unwrap());
    path
}

#[test]
fn every_update_recomputes_bit_identically() {
    let cfg = RunConfig::default_config();
    let path = record(&cfg, 7, "default.mcap");
    let rec = read_recording(&path).unwrap();
    assert!(rec.indexed, "a finished recording has a summary section");
    assert!(rec.truncated.is_none());
    assert_eq!(rec.updates.len(), 40);
    assert_eq!(rec.summaries.len(), 40);
    assert_eq!(rec.rollouts.len(), 40 * 15);
    // Every rollout timed by the in-process executor, within its update's interval.
    for r in &rec.rollouts {
        let u = &rec.updates[r.update as usize];
        assert_eq!(r.worker, "in-process");
        assert!(r.start_ns > 0 && r.start_ns <= r.end_ns, "{r:?}");
        assert!(
            u.batch_start_ns <= r.start_ns && r.end_ns <= u.batch_end_ns,
            "{r:?}"
        );
    }
    assert_eq!(rec.task_changes.len(), 1);
    assert_eq!(rec.task_changes[0].update, 20);
    let events: Vec<&str> = rec.logs.iter().map(|l| l.event.as_str()).collect();
    assert_eq!(events, ["start", "exit"]);
    let report = verify(&rec).unwrap();
    assert_eq!(report.updates, 40);
    assert!(report.mismatches.is_empty(), "{report:?}");

    // And the recorded distributions are the ones the run itself produced.
    let (summaries, last) = run_session(&cfg, 7, &mut session::NoObserver).unwrap();
    let last_recorded = recompute_update(&rec, rec.updates.last().unwrap()).unwrap();
    assert_eq!(last_recorded.after, last);
    for (s, r) in summaries.iter().zip(&rec.summaries) {
        assert_eq!(s.eval_cost.to_bits(), r.eval_cost.to_bits());
        assert_eq!(s.lambda.to_bits(), r.lambda.to_bits());
    }
}

/// A rollout whose first execution reported NaN was rerun (`run.nonfinite_reruns`): the
/// recording logs the rejected execution as a warning, and holds the accepted costs, from which
/// every update recomputes; the run is the one without the fault.
#[test]
fn a_rerun_rollout_is_logged_and_its_accepted_costs_recompute() {
    let text = session::DEFAULT_CONFIG.replace(
        "seed = 1\n",
        "seed = 1\nnonfinite_reruns = 1\nfault_nan_first_attempt = { update = 5, rollout = 3 }\n",
    );
    let cfg = RunConfig::parse(&text, std::path::Path::new("rerun.toml")).unwrap();
    let rec = read_recording(&record(&cfg, 7, "rerun.mcap")).unwrap();
    let warnings: Vec<(u64, &str, &str)> = rec
        .logs
        .iter()
        .filter(|l| l.event == "warning")
        .map(|l| (l.update, l.name.as_str(), l.message.as_str()))
        .collect();
    assert_eq!(
        warnings,
        [(
            5,
            "in-process",
            "update 5: cost of rollout 3 (terminal) is NaN; costs must be finite (attempt 1 of at \
             most 2, by in-process): rerunning it with the same parameters \
             (run.nonfinite_reruns = 1)"
        )]
    );
    assert_eq!(rec.rollouts.len(), 40 * 15, "one interval per rollout");
    let report = verify(&rec).unwrap();
    assert_eq!(report.updates, 40);
    assert!(report.mismatches.is_empty(), "{report:?}");
    let (_, without_fault) =
        run_session(&RunConfig::default_config(), 7, &mut session::NoObserver).unwrap();
    let last = recompute_update(&rec, rec.updates.last().unwrap()).unwrap();
    assert_eq!(last.after, without_fault);
}

#[test]
fn recompute_covers_every_update_rule() {
    let variants = [
        (
            "cem",
            "method = \"pi2-cma\"",
            "method = \"cem\"",
            "eliteness = 15.0",
            "elites = 7",
        ),
        (
            "pi2",
            "method = \"pi2-cma\"",
            "method = \"pi2\"",
            "lambda_min = 2.0",
            "",
        ),
        (
            "per-step",
            "weighting = \"episodic\"",
            "weighting = \"per-time-step\"",
            "",
            "",
        ),
    ];
    for (name, a, b, c, d) in variants {
        let pi2 = if name == "pi2" {
            "lambda_max = inf"
        } else {
            ""
        };
        // Each edit must apply: one that did not left the variant the default (episodic
        // PI²-CMA), and its update rule went unchecked.
        let edits: Vec<(&str, &str)> = [(a, b), ("updates = 40", "updates = 6"), (c, d), (pi2, "")]
            .into_iter()
            .filter(|(from, _)| !from.is_empty())
            .collect();
        let text = edited(session::DEFAULT_CONFIG, &edits);
        let cfg = RunConfig::parse(&text, std::path::Path::new(name)).unwrap();
        let path = record(&cfg, 3, &format!("{name}.mcap"));
        let rec = read_recording(&path).unwrap();
        let report = verify(&rec).unwrap();
        assert_eq!(report.updates, 6, "{name}");
        assert!(report.mismatches.is_empty(), "{name}: {report:?}");
    }
}

#[test]
fn a_changed_recording_no_longer_matches() {
    let mut cfg = RunConfig::default_config();
    cfg.run.updates = Some(3);
    let path = record(&cfg, 1, "tampered.mcap");
    let mut rec = read_recording(&path).unwrap();
    rec.updates[1].cost_terminal[3] += 1.0;
    let report = verify(&rec).unwrap();
    assert_eq!(report.mismatches, vec![1]);
}

/// `recording.step_costs = false`: no K × N step costs in the file, each rollout's total
/// (`cost_total`) instead, from which every update of an episodic run still recomputes bit
/// for bit, at a fraction of the bytes. With step costs, `cost_total` is their sum as the core
/// adds it.
#[test]
fn without_step_costs_every_update_still_recomputes_from_the_totals() {
    let full = RunConfig::default_config();
    let text = format!(
        "{}\n[recording]\nstep_costs = false\n",
        session::DEFAULT_CONFIG
    );
    let light = RunConfig::parse(&text, std::path::Path::new("light.toml")).unwrap();
    let with = read_recording(&record(&full, 3, "with-steps.mcap")).unwrap();
    let without = read_recording(&record(&light, 3, "without-steps.mcap")).unwrap();
    assert_eq!(without.updates.len(), 40);
    for (w, o) in with.updates.iter().zip(&without.updates) {
        let (k, n) = (w.rollouts as usize, w.steps as usize);
        assert_eq!(w.cost_per_step.len(), k * n);
        assert!(o.cost_per_step.is_empty());
        assert_eq!(o.cost_terminal, w.cost_terminal);
        assert_eq!(o.cost_total, w.cost_total);
        for r in 0..k {
            let total =
                pi2cma::total_cost(&w.cost_per_step[r * n..(r + 1) * n], w.cost_terminal[r]);
            assert_eq!(w.cost_total[r].to_bits(), total.to_bits());
        }
        assert_eq!(o.after, w.after, "update {}", w.update);
    }
    let report = verify(&without).unwrap();
    assert_eq!(report.updates, 40);
    assert!(report.mismatches.is_empty(), "{report:?}");
    // A step cost changed in a full recording is caught; a total changed here is too.
    let mut tampered = without.clone();
    tampered.updates[7].cost_total[4] += 1.0;
    let report = verify(&tampered).unwrap();
    assert_eq!(report.mismatches.len(), 1, "{report:?}");
    let size = |p: &str| std::fs::metadata(tmp(p)).unwrap().len();
    let (big, small) = (size("with-steps.mcap"), size("without-steps.mcap"));
    assert!(small * 2 < big, "{small} of {big} bytes");
}
