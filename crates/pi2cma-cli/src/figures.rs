//! Figures in the style of the paper's Fig. 2, as SVG: per config, left the search distribution
//! (mean and 1-σ covariance ellipse per update) in parameter space, right the mean eval-cost
//! learning curve with a ±std band of the exploration rollouts and λ on a log axis.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;
use record::ticks::{self, Along, Ticks};

use crate::experiment::{weighting_label, ConfigResult};

/// A figure could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("cannot draw {path}: {reason}")]
pub struct FigureError {
    /// The SVG file being drawn.
    pub path: String,
    /// What the drawing library reported.
    pub reason: String,
}

/// Points of the 1-σ ellipse of a 2×2 covariance around `mean`.
pub fn ellipse(mean: [f64; 2], cov: [[f64; 2]; 2], points: usize) -> Vec<(f64, f64)> {
    let (l, v) = pi2cma::boundcovar::eigen2(cov[0][0], cov[0][1], cov[1][1]);
    let (s0, s1) = (l[0].max(0.0).sqrt(), l[1].max(0.0).sqrt());
    (0..=points)
        .map(|i| {
            let t = i as f64 / points as f64 * std::f64::consts::TAU;
            let (a, b) = (s0 * t.cos(), s1 * t.sin());
            (
                mean[0] + a * v[0][0] + b * v[1][0],
                mean[1] + a * v[0][1] + b * v[1][1],
            )
        })
        .collect()
}

fn palette(u: usize, n: usize) -> RGBColor {
    // From dark to light blue over the updates, as in the paper's distribution plots.
    let f = if n > 1 {
        u as f64 / (n - 1) as f64
    } else {
        0.0
    };
    RGBColor(
        (20.0 + 180.0 * f) as u8,
        (40.0 + 160.0 * f) as u8,
        (140.0 + 100.0 * f) as u8,
    )
}

/// Height of the legend strip above the grid, in pixels.
const LEGEND_PX: u32 = 44;

/// Colours of the learning curve: eval cost, its band, λ.
const COST: RGBColor = RGBColor(20, 60, 180);
const BAND: RGBColor = RGBColor(120, 170, 230);
const LAMBDA: RGBColor = RGBColor(20, 150, 40);

/// What a legend entry shows next to its text.
enum Swatch {
    Line(RGBColor, u32),
    Vertical(RGBAColor),
    Band(RGBAColor),
    MeanPath,
}

/// The legend strip: what each colour and line of the panels below means, above the left
/// (distribution) and right (learning curve) column. The title alone explained the colours,
/// and light/dark ellipses and the grey line at the task change not at all (found by a user
/// test of the README).
fn draw_legend(area: &DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    let (w, _) = area.dim_in_pixel();
    let half = (w / 2) as i32;
    let entries: [(i32, i32, Swatch, &str); 7] = [
        (
            0,
            0,
            Swatch::Line(palette(0, 2), 1),
            "1σ ellipse, first update (dark)",
        ),
        (
            0,
            1,
            Swatch::Line(palette(1, 2), 1),
            "… last update (light)",
        ),
        (1, 0, Swatch::MeanPath, "mean θ per update"),
        (2, 0, Swatch::Line(COST, 2), "eval cost"),
        (
            2,
            1,
            Swatch::Band(BAND.mix(0.35)),
            "± std of the exploration costs",
        ),
        (3, 0, Swatch::Line(LAMBDA, 2), "λ (right axis, log)"),
        (3, 1, Swatch::Vertical(BLACK.mix(0.4)), "task change"),
    ];
    for (col, row, swatch, text) in entries {
        // Two columns of entries per half of the figure, two rows each.
        let x = 60 + (col / 2) * half + (col % 2) * 230;
        let y = 12 + row * 20;
        match swatch {
            Swatch::Line(c, width) => area.draw(&PathElement::new(
                vec![(x, y), (x + 24, y)],
                c.stroke_width(width),
            )),
            Swatch::Vertical(c) => {
                area.draw(&PathElement::new(vec![(x + 12, y - 7), (x + 12, y + 7)], c))
            }
            Swatch::Band(c) => {
                area.draw(&Rectangle::new([(x, y - 5), (x + 24, y + 5)], c.filled()))
            }
            Swatch::MeanPath => area
                .draw(&PathElement::new(vec![(x, y + 3), (x + 24, y - 3)], BLACK))
                .and_then(|()| area.draw(&Circle::new((x + 12, y), 2, BLACK.filled()))),
        }
        .map_err(|x| e(&x))?;
        area.draw(&Text::new(text, (x + 30, y - 6), ("sans-serif", 12)))
            .map_err(|x| e(&x))?;
    }
    Ok(())
}

/// Draws the Fig. 2-style grid: one row per config.
pub fn fig2(path: &Path, results: &[ConfigResult]) -> Result<(), FigureError> {
    let err = |e: &dyn std::fmt::Display| FigureError {
        path: path.display().to_string(),
        reason: e.to_string(),
    };
    let rows = results.len().max(1);
    let root = SVGBackend::new(path, (1100, LEGEND_PX + 260 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (legend, grid) = root.split_vertically(LEGEND_PX);
    draw_legend(&legend).map_err(|e| err(&e))?;
    let cells = grid.split_evenly((rows, 2));
    let cell = cells[0].dim_in_pixel();

    // Shared parameter-space limits across configs, as in the paper.
    let mut lim = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for r in results {
        for s in &r.sessions {
            for (m, c) in &s.distributions {
                if m.len() != 2 {
                    continue;
                }
                let sx = c[(0, 0)].max(0.0).sqrt();
                let sy = c[(1, 1)].max(0.0).sqrt();
                lim[0] = lim[0].min(m[0] - sx);
                lim[1] = lim[1].max(m[0] + sx);
                lim[2] = lim[2].min(m[1] - sy);
                lim[3] = lim[3].max(m[1] + sy);
            }
        }
    }
    // The limits are the ellipses' bounding box: an ellipse reaching one would run along the
    // axis, as if cut off there. A margin of 5% of each span keeps every one clear of the frame.
    for k in [0, 2] {
        if !lim[k].is_finite() {
            continue;
        }
        let pad = 0.05 * (lim[k + 1] - lim[k]);
        // A single point (a zero covariance) still needs a range to draw in.
        let pad = if pad > 0.0 {
            pad
        } else {
            lim[k].abs().max(1.0) * 0.05
        };
        lim[k] -= pad;
        lim[k + 1] += pad;
    }
    for (i, r) in results.iter().enumerate() {
        let title = format!("{} ({})", r.name, weighting_label(r.weighting));
        // Left: distribution of session 0 (the paper shows one session).
        if let Some(s) = r.sessions.first().filter(|s| {
            s.distributions.first().is_some_and(|d| d.0.len() == 2) && lim[0].is_finite()
        }) {
            let (w, h) = ticks::plot_size(cell, 6, 52, 0, 28, 14);
            let xt = Ticks::linear(lim[0], lim[1], w, Along::Horizontal);
            let yt = Ticks::linear(lim[2], lim[3], h, Along::Vertical);
            let mut chart = ChartBuilder::on(&cells[2 * i])
                .caption(
                    format!("{title}: θ and 1σ ellipse of Σ (session 0; axes not to scale)"),
                    ("sans-serif", 14),
                )
                .margin(6)
                .x_label_area_size(28)
                .y_label_area_size(52)
                .build_cartesian_2d(xt.on(lim[0], lim[1]), yt.on(lim[2], lim[3]))
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc("θ₁")
                .y_desc("θ₂")
                .light_line_style(WHITE)
                .draw()
                .map_err(|e| err(&e))?;
            let n = s.distributions.len();
            for (u, (m, c)) in s.distributions.iter().enumerate() {
                let pts = ellipse(
                    [m[0], m[1]],
                    [[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]],
                    60,
                );
                let color = palette(u, n);
                chart
                    .draw_series(LineSeries::new(pts, color.stroke_width(1)))
                    .map_err(|e| err(&e))?;
            }
            chart
                .draw_series(LineSeries::new(
                    s.distributions.iter().map(|(m, _)| (m[0], m[1])),
                    BLACK.stroke_width(1),
                ))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(
                    s.distributions
                        .iter()
                        .map(|(m, _)| Circle::new((m[0], m[1]), 2, BLACK.filled())),
                )
                .map_err(|e| err(&e))?;
        }

        // Right: learning curve, band and λ.
        let (e, sd, l) = r.mean_curves();
        if e.is_empty() {
            continue;
        }
        let n = e.len() as f64;
        let ymax = e
            .iter()
            .zip(&sd)
            .map(|(a, b)| a + b)
            .fold(0.0, f64::max)
            .min(3.0 * e.iter().cloned().fold(0.0, f64::max))
            .max(1e-9);
        let (lmin, lmax) = l
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let (lmin, lmax) = (lmin.max(1e-6) / 2.0, lmax.max(1e-6) * 2.0);
        let (w, h) = ticks::plot_size(cell, 6, 52, 64, 28, 14);
        let xt = Ticks::linear(0.0, n, w, Along::Horizontal);
        let yt = Ticks::linear(0.0, ymax, h, Along::Vertical);
        let lt = Ticks::log(lmin, lmax, h, Along::Vertical);
        let mut chart = ChartBuilder::on(&cells[2 * i + 1])
            .caption(
                format!(
                    "{title}: learning curve (mean of {} sessions)",
                    r.sessions.len()
                ),
                ("sans-serif", 14),
            )
            .margin(6)
            .x_label_area_size(28)
            .y_label_area_size(52)
            .right_y_label_area_size(64)
            .build_cartesian_2d(xt.on(0.0, n), yt.on(0.0, ymax))
            .map_err(|e| err(&e))?
            .set_secondary_coord(xt.on(0.0, n), lt.on_log(lmin, lmax));
        chart
            .configure_mesh()
            .x_desc("update")
            .y_desc("cost")
            .light_line_style(WHITE)
            .draw()
            .map_err(|e| err(&e))?;
        chart
            .configure_secondary_axes()
            .y_desc("λ (log)")
            .draw()
            .map_err(|e| err(&e))?;
        let upper: Vec<(f64, f64)> = e
            .iter()
            .zip(&sd)
            .enumerate()
            .map(|(u, (a, b))| (u as f64, (a + b).min(ymax)))
            .collect();
        let lower: Vec<(f64, f64)> = e
            .iter()
            .zip(&sd)
            .enumerate()
            .rev()
            .map(|(u, (a, b))| (u as f64, (a - b).max(0.0)))
            .collect();
        let band: Vec<(f64, f64)> = upper.into_iter().chain(lower).collect();
        chart
            .draw_series(std::iter::once(Polygon::new(band, BAND.mix(0.35).filled())))
            .map_err(|e| err(&e))?;
        chart
            .draw_series(LineSeries::new(
                e.iter().enumerate().map(|(u, v)| (u as f64, *v)),
                COST.stroke_width(2),
            ))
            .map_err(|e| err(&e))?;
        chart
            .draw_secondary_series(LineSeries::new(
                l.iter().enumerate().map(|(u, v)| (u as f64, *v)),
                LAMBDA.stroke_width(2),
            ))
            .map_err(|e| err(&e))?;
        if let Some(c) = r.change_at {
            chart
                .draw_series(LineSeries::new(
                    [(c as f64, 0.0), (c as f64, ymax)],
                    BLACK.mix(0.4).stroke_width(1),
                ))
                .map_err(|e| err(&e))?;
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // a failed unwrap is a failed test

    use super::*;

    /// The points of the polylines in `svg` that `keep` keeps, given their stroke colour.
    fn polylines(svg: &str, keep: impl Fn(&str, &[(f64, f64)]) -> bool) -> Vec<Vec<(f64, f64)>> {
        svg.split("<polyline")
            .skip(1)
            .filter_map(|p| {
                let stroke = p.split("stroke=\"").nth(1)?.split('"').next()?;
                let points: Vec<(f64, f64)> = p
                    .split("points=\"")
                    .nth(1)?
                    .split('"')
                    .next()?
                    .split_whitespace()
                    .filter_map(|xy| {
                        let (x, y) = xy.split_once(',')?;
                        Some((x.parse().ok()?, y.parse().ok()?))
                    })
                    .collect();
                keep(stroke, &points).then_some(points)
            })
            .collect()
    }

    /// The SVG text of fig2 of the built-in default config (seed 1), written to a temporary
    /// file named after `name`.
    fn default_fig2(name: &str) -> String {
        let cfg = session::RunConfig::default_config();
        let result = crate::experiment::run_config(&cfg, 1).unwrap();
        let path = std::env::temp_dir().join(format!("{name}-{}.svg", std::process::id()));
        fig2(&path, &[result]).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        svg
    }

    /// fig2 explained its colours only in the titles, light/dark ellipses and the grey line at
    /// the task change not at all, and labelled updates `0.0, 5.0`, λ `10000.0` (found by a user
    /// test of the README): a legend names every colour and line, and ticks are plain.
    #[test]
    fn fig2_has_a_legend_and_plain_tick_labels() {
        let svg = default_fig2("fig2-legend");
        let texts: Vec<&str> = svg
            .split("<text")
            .skip(1)
            .filter_map(|t| Some(t.split_once('>')?.1.split_once("</text>")?.0.trim()))
            .collect();
        for entry in [
            "1σ ellipse, first update (dark)",
            "… last update (light)",
            "mean θ per update",
            "eval cost",
            "± std of the exploration costs",
            "λ (right axis, log)",
            "task change",
        ] {
            assert!(
                texts.contains(&entry),
                "no legend entry {entry:?}: {texts:?}"
            );
        }
        for t in &texts {
            assert!(
                !t.ends_with(".0") && *t != "-0",
                "tick label {t:?}: {texts:?}"
            );
        }
        assert!(texts.contains(&"20"), "{texts:?}");
    }

    /// The later ellipses of A1 (session 0, seed 1) reached the very edge of the axes and
    /// looked cut off below about −690 (found by a user test of the README): the axes were
    /// exactly the ellipses' bounding box. Every ellipse now keeps clear of the frame.
    #[test]
    fn every_ellipse_lies_inside_the_axes_clear_of_their_frame() {
        let svg = default_fig2("fig2");
        // The left chart's axes: the first long black vertical and horizontal lines.
        let axes = polylines(&svg, |stroke, p| {
            stroke == "#000000"
                && p.len() == 2
                && (p[1].0 - p[0].0).abs() + (p[1].1 - p[0].1).abs() > 100.0
        });
        let y_axis = axes.iter().find(|p| p[0].0 == p[1].0).unwrap();
        let x_axis = axes.iter().find(|p| p[0].1 == p[1].1).unwrap();
        let (left, right) = (x_axis[0].0.min(x_axis[1].0), x_axis[0].0.max(x_axis[1].0));
        let (top, bottom) = (y_axis[0].1.min(y_axis[1].1), y_axis[0].1.max(y_axis[1].1));
        let ellipses = polylines(&svg, |stroke, p| {
            // The legend strip's swatches above the grid are no ellipses.
            stroke != "#000000"
                && stroke != "#FFFFFF"
                && p.iter()
                    .all(|&(x, y)| x <= right && y > f64::from(LEGEND_PX))
        });
        assert!(ellipses.len() > 40, "{} ellipses", ellipses.len());
        let clear = 3.0;
        for &(x, y) in ellipses.iter().flatten() {
            assert!(
                x >= left + clear && x <= right - clear && y >= top + clear && y <= bottom - clear,
                "({x}, {y}) is not inside the axes x {left}..{right}, y {top}..{bottom} by {clear} px"
            );
        }
    }
}
