//! The SVG figures of one recording ([`plot`]): the learning curve (`curves`), the ellipses of a
//! 2-D policy's distribution (`distribution`), and the rollout time and timeline per worker
//! (`workers`), with the palette and helpers they share. The experiment's mean curves are drawn
//! by `experiment`, with `curves`. It draws from the recording in memory and writes nothing but
//! the SVG files; the numbers in the figures are the recorded ones, not recomputed.

mod curves;
mod distribution;
mod workers;

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::io;
use crate::digest::TIMELINE_UPDATES;
use crate::{RecordError, Recording, UpdatePoint};
pub(super) use curves::{draw_curves, Curve, Values};
use distribution::plot_ellipses;
use workers::{plot_worker_time, plot_worker_timeline, timeline};

/// matplotlib's tab10.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

pub(super) fn perr<E: std::fmt::Debug>(file: &Path, figure: &str) -> impl FnOnce(E) -> RecordError {
    let file = file.to_path_buf();
    let figure = figure.to_string();
    move |e| RecordError::Plot {
        file,
        figure,
        what: format!("{e:?}"),
    }
}

/// The framed legend of a chart's labelled series, at `position`.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|x| format!("{x:?}"))
}

/// Range with a margin; never empty.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let span = (hi - lo).abs().max(1e-12 * hi.abs().max(1.0));
    (lo - 0.05 * span, hi + 0.05 * span)
}

fn log_range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in vals.filter(|v| *v > 0.0 && v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !(lo.is_finite() && hi > 0.0) {
        return (0.1, 10.0);
    }
    (lo / 1.5, hi * 1.5)
}

/// What `analyze` says for a recording without updates instead of drawing figures.
pub const NOTHING_TO_PLOT: &str = "no figures: no update recorded, nothing to plot";

/// Draws the figures of one recording into `dir`: `learning_curve.svg`, `worker_time.svg`, and
/// for 2-D policies `distribution.svg`; none (an empty list) for a recording without updates
/// ([`NOTHING_TO_PLOT`]).
pub fn plot(rec: &Recording, dir: &Path) -> Result<Vec<PathBuf>, RecordError> {
    let points = &rec.digest.points;
    if points.is_empty() {
        // Empty axes presented as figures; the callers say there is nothing to plot.
        return Ok(Vec::new());
    }
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let changes: Vec<u64> = rec.task_changes.iter().map(|c| c.update).collect();

    let path = dir.join("learning_curve.svg");
    {
        let root = SVGBackend::new(&path, (900, 650)).into_drawing_area();
        let column = |v: fn(&UpdatePoint) -> f64| points.iter().map(v).collect::<Vec<f64>>();
        let x = column(|p| p.update as f64);
        let curves = [
            Curve::new(
                "exploration mean ± std".into(),
                Values {
                    x: &x,
                    y: &column(|p| p.exploration_cost_mean),
                    band: Some(&column(|p| p.exploration_cost_std)),
                    // λ is the exploration's size: drawn in its colour (in the evaluation's it
                    // read as a property of rollout 0).
                    lambda: Some(&column(|p| p.lambda)),
                },
            ),
            Curve::new(
                "evaluation (rollout 0)".into(),
                Values {
                    x: &x,
                    y: &column(|p| p.eval_cost),
                    band: None,
                    lambda: None,
                },
            ),
        ];
        draw_curves(
            &root,
            &format!("{}: learning curve", rec.name()),
            &curves,
            &changes,
            "cost",
        )
        .map_err(perr(&path, "learning_curve"))?;
    }
    files.push(path);

    let dim = rec.run_info().map(|r| r.dim).unwrap_or(0);
    if dim == 2 && !points.is_empty() {
        let path = dir.join("distribution.svg");
        plot_ellipses(rec, &path).map_err(perr(&path, "distribution"))?;
        files.push(path);
    }

    let path = dir.join("worker_time.svg");
    plot_worker_time(rec, &path).map_err(perr(&path, "worker_time"))?;
    files.push(path);

    let bars = timeline(rec, TIMELINE_UPDATES);
    if !bars.is_empty() {
        let path = dir.join("worker_timeline.svg");
        plot_worker_timeline(rec, &bars, &path).map_err(perr(&path, "worker_timeline"))?;
        files.push(path);
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::experiment;
    use crate::analyze::test_support::rec_with;
    use crate::proto;

    /// A recording without updates gets no figures (they were empty axes) and says so; one
    /// of a single update gets that update drawn (a line through one point was invisible).
    #[test]
    fn a_recording_of_0_or_1_update_has_no_empty_figures() {
        let dir = std::env::temp_dir().join(format!("pi2cma-0-1-updates-{}", std::process::id()));
        let mut none = rec_with(&[], None);
        none.run.push(proto::RunInfo::default());
        assert!(plot(&none, &dir.join("none")).unwrap().is_empty());
        assert!(!dir.join("none").exists());
        let report = experiment(&[none], Some(&dir), 0.05, true, false).unwrap();
        assert!(
            report.table.contains("mean_curves.svg not drawn"),
            "{}",
            report.table
        );
        assert!(!dir.join("mean_curves.svg").exists());

        let mut one = rec_with(&[3.0], None);
        one.run.push(proto::RunInfo::default());
        let files = plot(&one, &dir.join("one")).unwrap();
        assert!(files.iter().any(|f| f.ends_with("learning_curve.svg")));
        let svg = std::fs::read_to_string(dir.join("one/learning_curve.svg")).unwrap();
        // The eval cost and λ as dots, the exploration band as a bar with its dot.
        assert_eq!(svg.matches("<circle").count(), 3, "{svg}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
