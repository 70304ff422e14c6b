//! Learning curves: lines with a ±band over the updates above a λ panel on a log axis, broken
//! where updates are missing, decimated to each bucket's extremes for a long run, with dashed
//! lines at task changes. One run's `learning_curve.svg` and an experiment's `mean_curves.svg`
//! are drawn with it; it computes no statistics: its callers give it the values.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{draw_legend, log_range, padded, PALETTE};
use crate::ticks::{self, Along, Ticks};

/// Up to this many updates, a learning curve is drawn through every update; beyond, through
/// each of [`CURVE_BUCKETS`] runs of consecutive updates' lowest and highest value.
pub const CURVE_POINTS: usize = 4000;

/// For a longer curve: into how many runs of consecutive updates (buckets) it is split. Each
/// line goes through every bucket's lowest and highest value, in the order they occur, and the
/// band spans each bucket's extremes, so that a spike (the cost after a task change) shows as
/// it would undecimated, in an SVG that does not grow with the run.
pub const CURVE_BUCKETS: usize = 1000;

/// One line of a learning-curve figure: per update x, a centre value and a ±band, and λ.
pub(in crate::analyze) struct Curve {
    label: String,
    /// The last update (a decimated line need not reach it).
    x_max: f64,
    /// Each stretch of consecutive updates (a missing update breaks the line).
    pub(in crate::analyze) pieces: Vec<Piece>,
}

/// What a [`Curve`] draws over a stretch of consecutive updates.
#[derive(Debug, Default, PartialEq)]
pub(in crate::analyze) struct Piece {
    line: Vec<(f64, f64)>,
    /// The band's outline: its upper edge forward, its lower edge back.
    band: Option<Vec<(f64, f64)>>,
    lambda: Vec<(f64, f64)>,
}

/// A curve's values per update, as [`Curve::new`] takes them.
pub(in crate::analyze) struct Values<'a> {
    pub(in crate::analyze) x: &'a [f64],
    pub(in crate::analyze) y: &'a [f64],
    pub(in crate::analyze) band: Option<&'a [f64]>,
    pub(in crate::analyze) lambda: Option<&'a [f64]>,
}

impl Curve {
    pub(in crate::analyze) fn new(label: String, v: Values<'_>) -> Self {
        // Buckets of `width` updates; 1 draws every update.
        let width = if v.x.len() > CURVE_POINTS {
            v.x.len().div_ceil(CURVE_BUCKETS)
        } else {
            1
        };
        let pieces = contiguous(v.x)
            .into_iter()
            .map(|r| {
                let x = &v.x[r.clone()];
                let y = &v.y[r.clone()];
                Piece {
                    line: extremes(x, y, width),
                    band: v.band.map(|b| band(x, y, &b[r.clone()], width)),
                    lambda: v
                        .lambda
                        .map(|l| extremes(x, &l[r.clone()], width))
                        .unwrap_or_default(),
                }
            })
            .collect();
        Self {
            label,
            x_max: v.x.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            pieces,
        }
    }
}

/// The points of `y` over `x` a line goes through: every one, or with `width` > 1 per bucket of
/// `width` its lowest and highest, in the order they occur.
fn extremes(x: &[f64], y: &[f64], width: usize) -> Vec<(f64, f64)> {
    if width <= 1 {
        return x.iter().copied().zip(y.iter().copied()).collect();
    }
    let mut out = Vec::new();
    for (xs, ys) in x.chunks(width).zip(y.chunks(width)) {
        let lowest = (0..ys.len()).min_by(|a, b| ys[*a].total_cmp(&ys[*b]));
        let highest = (0..ys.len()).max_by(|a, b| ys[*a].total_cmp(&ys[*b]));
        if let (Some(lo), Some(hi)) = (lowest, highest) {
            let (a, b) = (lo.min(hi), lo.max(hi));
            out.push((xs[a], ys[a]));
            if b != a {
                out.push((xs[b], ys[b]));
            }
        }
    }
    out
}

/// The outline of the band y ± b: per update, or with `width` > 1 per bucket its highest
/// y + b and lowest y − b over the bucket's updates.
fn band(x: &[f64], y: &[f64], b: &[f64], width: usize) -> Vec<(f64, f64)> {
    let upper: Vec<f64> = y.iter().zip(b).map(|(y, b)| y + b).collect();
    let lower: Vec<f64> = y.iter().zip(b).map(|(y, b)| y - b).collect();
    if width <= 1 {
        let mut pts: Vec<(f64, f64)> = x.iter().copied().zip(upper).collect();
        pts.extend(x.iter().copied().zip(lower).rev());
        return pts;
    }
    let (mut top, mut bottom) = (Vec::new(), Vec::new());
    for ((xs, us), ls) in x
        .chunks(width)
        .zip(upper.chunks(width))
        .zip(lower.chunks(width))
    {
        let (first, last) = (xs[0], xs[xs.len() - 1]);
        let u = us.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let l = ls.iter().copied().fold(f64::INFINITY, f64::min);
        top.extend([(first, u), (last, u)]);
        bottom.extend([(first, l), (last, l)]);
    }
    top.extend(bottom.into_iter().rev());
    top
}

/// The index ranges of `x` (update numbers, ascending) without a missing update inside.
fn contiguous(x: &[f64]) -> Vec<std::ops::Range<usize>> {
    let mut ranges = Vec::new();
    let mut start = 0;
    for i in 1..=x.len() {
        if i == x.len() || x[i] - x[i - 1] > 1.0 {
            if start < i {
                ranges.push(start..i);
            }
            start = i;
        }
    }
    ranges
}

/// Cost panel (lines + bands) above a λ panel on a log axis; dashed lines at task changes.
pub(in crate::analyze) fn draw_curves(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    title: &str,
    curves: &[Curve],
    changes: &[u64],
    cost_label: &str,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    area.fill(&WHITE).map_err(|x| e(&x))?;
    let (top, bottom) = area.split_vertically((area.dim_in_pixel().1 as f64 * 0.62) as u32);
    let xmax = curves.iter().map(|c| c.x_max).fold(1.0f64, f64::max);
    // A single update would sit on the axis at update 0: centred instead.
    let lone = curves
        .iter()
        .all(|c| c.pieces.iter().map(|p| p.line.len()).sum::<usize>() <= 1);
    let last = curves.iter().map(|c| c.x_max).fold(0.0f64, f64::max);
    let (xmin, xmax) = if lone {
        (last - 1.0, last + 1.0)
    } else {
        (0.0, xmax)
    };
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in curves.iter().flat_map(|c| &c.pieces) {
        for (_, y) in p.line.iter().chain(p.band.iter().flatten()) {
            lo = lo.min(*y);
            hi = hi.max(*y);
        }
    }
    // Costs that fall over more than two decades (80 to 0.05) were a flat line after the
    // first updates on a linear axis: a log axis then, over the lines' values; a band's
    // lower edge at or below zero runs along its bottom.
    let log = ticks::wants_log(
        curves
            .iter()
            .flat_map(|c| &c.pieces)
            .flat_map(|p| p.line.iter().map(|pt| pt.1)),
    );
    let (lo, hi) = if log {
        log_range(
            curves
                .iter()
                .flat_map(|c| &c.pieces)
                .flat_map(|p| p.line.iter().map(|pt| pt.1)),
        )
    } else {
        padded(lo.min(0.0), hi)
    };
    let (margin, x_area, y_area, caption) = (10, 30, 70, 20);
    let (w, h) = ticks::plot_size(top.dim_in_pixel(), margin, y_area, 0, x_area, caption);
    let xt = Ticks::linear(xmin, xmax, w, Along::Horizontal);
    let (yt, y_desc) = if log {
        (
            Ticks::log(lo, hi, h, Along::Vertical),
            format!("{cost_label} (log)"),
        )
    } else {
        (
            Ticks::linear(lo, hi, h, Along::Vertical),
            cost_label.to_string(),
        )
    };
    // On a log axis the chart draws log10 of each cost (a band edge at or below zero at the
    // axis' bottom): one coordinate type for both scales.
    let fy = |y: f64| if log { y.max(lo).log10() } else { y };
    let yt = Ticks {
        values: yt.values.iter().map(|v| fy(*v)).collect(),
        labels: yt.labels,
    };
    let (lo, hi) = (fy(lo), fy(hi));
    let mut chart = ChartBuilder::on(&top)
        .caption(title, ("sans-serif", caption))
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(xt.on(xmin, xmax), yt.on(lo, hi))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc(y_desc)
        .draw()
        .map_err(|x| e(&x))?;
    let map =
        |pts: &[(f64, f64)]| -> Vec<(f64, f64)> { pts.iter().map(|&(x, y)| (x, fy(y))).collect() };
    for (i, c) in curves.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        // Updates a recording lacks (a restarted recorder's gap) break the line, rather than
        // being drawn over as if they had been there.
        for (n, p) in c.pieces.iter().enumerate() {
            // A line and a band through one update (a run of one update, or one between two
            // missing ones) are invisible: that update is a dot with a bar instead.
            let single = p.line.len() == 1;
            if let Some(b) = &p.band {
                if single {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            map(b),
                            color.mix(0.5).stroke_width(3),
                        )))
                        .map_err(|x| e(&x))?;
                } else {
                    chart
                        .draw_series(std::iter::once(Polygon::new(
                            map(b),
                            color.mix(0.2).filled(),
                        )))
                        .map_err(|x| e(&x))?;
                }
            }
            let line = if single {
                chart.draw_series(
                    map(&p.line)
                        .into_iter()
                        .map(|pt| Circle::new(pt, 3, color.filled())),
                )
            } else {
                chart.draw_series(LineSeries::new(map(&p.line), color.stroke_width(2)))
            }
            .map_err(|x| e(&x))?;
            if n == 0 {
                line.label(c.label.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
            }
        }
    }
    mark_changes(&mut chart, changes, (lo, hi), true)?;
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;

    let (llo, lhi) = log_range(
        curves
            .iter()
            .flat_map(|c| &c.pieces)
            .flat_map(|p| p.lambda.iter().map(|l| l.1)),
    );
    let (_, h) = ticks::plot_size(bottom.dim_in_pixel(), margin, y_area, 0, x_area, 0);
    let lt = Ticks::log(llo, lhi, h, Along::Vertical);
    let mut chart = ChartBuilder::on(&bottom)
        .margin(margin)
        .x_label_area_size(x_area)
        .y_label_area_size(y_area)
        .build_cartesian_2d(xt.on(xmin, xmax), lt.on_log(llo, lhi))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc("λ (log)")
        .draw()
        .map_err(|x| e(&x))?;
    // λ rising again after a change is the point of the method: the change is marked here too.
    mark_changes(&mut chart, changes, (llo, lhi), false)?;
    for (i, c) in curves.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        for p in c.pieces.iter().filter(|p| !p.lambda.is_empty()) {
            let positive = p.lambda.iter().copied().filter(|(_, l)| *l > 0.0);
            if p.lambda.len() == 1 {
                chart
                    .draw_series(positive.map(|pt| Circle::new(pt, 3, color.filled())))
                    .map_err(|x| e(&x))?;
            } else {
                chart
                    .draw_series(LineSeries::new(positive, color.stroke_width(2)))
                    .map_err(|x| e(&x))?;
            }
        }
    }
    area.present().map_err(|x| e(&x))?;
    Ok(())
}

/// A dashed vertical line from `y.0` to `y.1` at each task change's update; with `legend`, one
/// legend entry for them (the dashes were unexplained in the figure).
fn mark_changes<DB, CT>(
    chart: &mut ChartContext<'_, DB, CT>,
    changes: &[u64],
    y: (f64, f64),
    legend: bool,
) -> Result<(), String>
where
    DB: DrawingBackend,
    CT: CoordTranslate<From = (f64, f64)>,
{
    for (i, &u) in changes.iter().enumerate() {
        let x = u as f64;
        let series = chart
            .draw_series(DashedLineSeries::new(
                vec![(x, y.0), (x, y.1)],
                5,
                5,
                BLACK.mix(0.6).stroke_width(1),
            ))
            .map_err(|x| format!("{x:?}"))?;
        if legend && i == 0 {
            series
                .label("task change (in force from this update)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.6)));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analyze::plot;
    use crate::analyze::test_support::rec_with;
    use crate::{proto, Recording};

    /// The tick labels of an SVG plotters wrote (the text of its <text> elements).
    fn svg_texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| {
                Some(
                    t.split_once('>')?
                        .1
                        .split_once("</text>")?
                        .0
                        .trim()
                        .to_string(),
                )
            })
            .collect()
    }

    /// A run whose cost falls from 80 to 0.05 was a flat line after update 2 on the linear cost
    /// axis, and the update axis was labelled `0.0, 5.0` (found by a user test of the README):
    /// the cost axis is logarithmic, says so, and integer ticks have no decimals.
    #[test]
    fn learning_curve_of_costs_over_three_decades_has_a_log_axis_and_plain_ticks() {
        let costs: Vec<f64> = (0..30).map(|u| 80.0 * 0.78f64.powi(u)).collect();
        let mut r = Recording::default();
        for (u, c) in costs.iter().enumerate() {
            r.digest.add_update(&proto::Update {
                update: u as u64,
                eval_cost: *c,
                exploration_cost_mean: 1.05 * c,
                exploration_cost_std: 0.5 * c,
                lambda: 10f64.powi(u as i32 % 5),
                ..Default::default()
            });
        }
        let dir = std::env::temp_dir().join(format!("lc-log-{}", std::process::id()));
        let files = plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(&files[0]).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let texts = svg_texts(&svg);
        assert!(texts.iter().any(|t| t == "cost (log)"), "{texts:?}");
        for t in &texts {
            assert!(!t.ends_with(".0") && t != "-0", "tick label {t}: {texts:?}");
        }
        assert!(texts.iter().any(|t| t == "10000"), "{texts:?}");
        // Costs within two decades keep a linear axis.
        let r = rec_with(&[5.0, 4.0, 3.0], None);
        let files = plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(&files[0]).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(!svg_texts(&svg).iter().any(|t| t == "cost (log)"));
    }

    /// λ rising again after a task change is what the figure is for: the change is marked on
    /// the λ panel as well as on the cost panel.
    #[test]
    fn a_task_change_is_marked_on_both_panels_of_the_learning_curve() {
        let mut r = rec_with(&[5.0, 4.0, 3.0, 2.0, 6.0, 5.0], Some(4));
        r.run.push(proto::RunInfo::default());
        let dir = std::env::temp_dir().join(format!("pi2cma-marks-{}", std::process::id()));
        plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(dir.join("learning_curve.svg")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // Dashes are short vertical polylines at one x; the panels split at 62 % of the height.
        let height: f64 = svg
            .split_once("height=\"")
            .and_then(|(_, t)| t.split('"').next()?.parse().ok())
            .expect("an svg height");
        let mut dash_ys = Vec::new();
        for p in svg.split("<polyline").skip(1) {
            let Some((_, pts)) = p.split_once("points=\"") else {
                continue;
            };
            let pts: Vec<(f64, f64)> = pts
                .split('"')
                .next()
                .unwrap_or("")
                .split_whitespace()
                .filter_map(|xy| {
                    let (x, y) = xy.split_once(',')?;
                    Some((x.parse().ok()?, y.parse().ok()?))
                })
                .collect();
            if pts.len() == 2
                && pts[0].0 == pts[1].0
                && pts[0].1 != pts[1].1
                && p.contains("opacity=\"0.6")
            {
                dash_ys.push(pts[0].1);
            }
        }
        let split = height * 0.62;
        assert!(
            dash_ys.iter().any(|y| *y < split),
            "no dash on the cost panel: {dash_ys:?}"
        );
        assert!(
            dash_ys.iter().any(|y| *y > split),
            "no dash on the λ panel: {dash_ys:?}"
        );
        // And the legend says what the dashes are (they were unexplained).
        let legend = "task change (in force from this update)";
        assert!(svg_texts(&svg).iter().any(|t| t == legend), "{svg}");
        // Only where there is one.
        let mut r = rec_with(&[5.0, 4.0, 3.0, 2.0, 6.0, 5.0], None);
        r.run.push(proto::RunInfo::default());
        plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(dir.join("learning_curve.svg")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(!svg_texts(&svg).iter().any(|t| t == legend));
    }

    /// λ is drawn in the colour of the exploration it measures, not in that of the evaluation
    /// line (rollout 0), above which it was orange too.
    #[test]
    fn lambda_has_the_exploration_lines_colour() {
        let r = rec_with(&[5.0, 4.0, 3.0, 2.0, 6.0, 5.0], None);
        let dir = std::env::temp_dir().join(format!("pi2cma-lambda-colour-{}", std::process::id()));
        plot(&r, &dir).unwrap();
        let svg = std::fs::read_to_string(dir.join("learning_curve.svg")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // The lines of 6 points, in drawing order: exploration, evaluation, λ.
        let strokes: Vec<&str> = svg
            .split("<polyline")
            .skip(1)
            .filter(|p| {
                p.split_once("points=\"")
                    .and_then(|(_, pts)| pts.split('"').next())
                    .is_some_and(|pts| pts.split_whitespace().count() == 6)
            })
            .filter_map(|p| p.split_once("stroke=\"")?.1.split('"').next())
            .collect();
        assert_eq!(strokes.len(), 3, "{strokes:?}");
        assert_eq!(strokes[2], strokes[0], "{strokes:?}");
        assert_ne!(strokes[2], strokes[1], "{strokes:?}");
    }

    #[test]
    fn curves_break_where_updates_are_missing() {
        assert_eq!(contiguous(&[]), Vec::<std::ops::Range<usize>>::new());
        let whole = contiguous(&[0.0, 1.0, 2.0]);
        assert_eq!((whole.len(), whole[0].clone()), (1, 0..3));
        assert_eq!(contiguous(&[0.0, 1.0, 4.0, 5.0, 9.0]), [0..2, 2..4, 4..5]);
    }
}
