//! `distribution.svg`: the 2σ ellipses of a 2-D policy's search distribution, update by update
//! (those the digest kept, for a long run), dark for late ones, red for the first update after
//! a task change. Only for P = 2: a distribution of more dimensions is not projected.

use std::path::Path;

use plotters::prelude::*;

use super::{draw_legend, padded};
use crate::ticks::{self, Along, Ticks};
use crate::{distribution_from_proto, Recording};

/// Points of the 2σ ellipse of a 2×2 covariance around `m`.
fn ellipse(m: [f64; 2], c: [[f64; 2]; 2]) -> Vec<(f64, f64)> {
    let (a, b, d) = (c[0][0], c[0][1], c[1][1]);
    let tr = 0.5 * (a + d);
    let disc = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    let (l1, l2) = ((tr + disc).max(0.0), (tr - disc).max(0.0));
    let angle = if b == 0.0 && a >= d {
        0.0
    } else if b == 0.0 {
        std::f64::consts::FRAC_PI_2
    } else {
        (l1 - a).atan2(b)
    };
    let (ca, sa) = (angle.cos(), angle.sin());
    (0..=64)
        .map(|i| {
            let t = i as f64 / 64.0 * std::f64::consts::TAU;
            let (x, y) = (2.0 * l1.sqrt() * t.cos(), 2.0 * l2.sqrt() * t.sin());
            (m[0] + ca * x - sa * y, m[1] + sa * x + ca * y)
        })
        .collect()
}

/// The smallest half-axis, in pixels, the ellipse of the first update after a task change is
/// drawn with: with λ small at the change (the run had converged), its 2σ ellipse was under a
/// pixel, and the red mark of the change was invisible.
pub const MIN_CHANGE_ELLIPSE_PIXELS: f64 = 6.0;

/// The ellipse `pts` around `centre`, scaled up about it to a largest half-axis of `least` if
/// smaller (a circle of that radius if it has none).
fn at_least(pts: &[(f64, f64)], centre: (f64, f64), least: f64) -> Vec<(f64, f64)> {
    let radius = pts
        .iter()
        .map(|p| (p.0 - centre.0).hypot(p.1 - centre.1))
        .fold(0.0f64, f64::max);
    if radius >= least {
        return pts.to_vec();
    }
    if radius > 0.0 {
        let k = least / radius;
        return pts
            .iter()
            .map(|p| {
                (
                    centre.0 + k * (p.0 - centre.0),
                    centre.1 + k * (p.1 - centre.1),
                )
            })
            .collect();
    }
    (0..=64)
        .map(|i| {
            let a = f64::from(i) / 64.0 * std::f64::consts::TAU;
            (centre.0 + least * a.cos(), centre.1 + least * a.sin())
        })
        .collect()
}

pub(super) fn plot_ellipses(rec: &Recording, path: &Path) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    // Every update's, or for a long run those the digest kept (DISTRIBUTIONS_SHOWN).
    let kept = &rec.digest.distributions;
    let from = |d| distribution_from_proto(d).map_err(|w| w.to_string());
    let mut dists = Vec::new();
    for s in &kept.shown {
        dists.push((s.update, from(&s.distribution)?));
    }
    if let Some((u, last)) = &kept.last {
        dists.push((*u, from(last)?));
    }
    let thinned = kept.shown.len() < rec.digest.points.len();
    let n = dists.len().max(1);
    let ellipses: Vec<(u64, Vec<(f64, f64)>)> = dists
        .iter()
        .map(|(u, d)| {
            let m = [d.mean[0], d.mean[1]];
            let c = [
                [d.covariance[(0, 0)], d.covariance[(0, 1)]],
                [d.covariance[(1, 0)], d.covariance[(1, 1)]],
            ];
            (*u, ellipse(m, c))
        })
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (_, pts) in &ellipses {
        for (x, y) in pts {
            x0 = x0.min(*x);
            x1 = x1.max(*x);
            y0 = y0.min(*y);
            y1 = y1.max(*y);
        }
    }
    let (x0, x1) = padded(x0, x1);
    let (y0, y1) = padded(y0, y1);
    let (width, height) = (750u32, 700u32);
    let (margin, x_labels, y_labels, caption) = (10u32, 35u32, 70u32, 18u32);
    // Both axes to one scale: an ellipse's shape and tilt are what the figure is for (with
    // the data's ranges, Σ = λ·I was drawn 3× wider than tall).
    let plot_w = f64::from(width - 2 * margin - y_labels);
    let plot_h = f64::from(height - 2 * margin - x_labels - caption - margin);
    let ((x0, x1), (y0, y1)) = ticks::equal_scale((x0, x1), (y0, y1), plot_w, plot_h);
    let per_pixel = (x1 - x0) / plot_w;
    let (xt, yt) = (
        Ticks::linear(x0, x1, plot_w, Along::Horizontal),
        Ticks::linear(y0, y1, plot_h, Along::Vertical),
    );
    let root = SVGBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart =
        ChartBuilder::on(&root)
            .caption(
                format!(
                "{}: 2σ ellipses of the search distribution{} (dark = late; red = first update \
                 after a task change)",
                rec.name(),
                if thinned {
                    format!(", {} of {} updates", dists.len(), rec.digest.points.len() + 1)
                } else {
                    String::new()
                }
            ),
                ("sans-serif", caption),
            )
            .margin(margin)
            .x_label_area_size(x_labels)
            .y_label_area_size(y_labels)
            .build_cartesian_2d(xt.on(x0, x1), yt.on(y0, y1))
            .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("θ₁")
        .y_desc("θ₂")
        .draw()
        .map_err(|x| e(&x))?;
    let changes: Vec<u64> = rec.task_changes.iter().map(|c| c.update).collect();
    for (i, ((u, pts), (_, d))) in ellipses.iter().zip(&dists).enumerate() {
        let t = i as f64 / n as f64;
        let (color, pts) = if changes.contains(u) {
            let centre = (d.mean[0], d.mean[1]);
            (
                RGBColor(214, 39, 40).stroke_width(2),
                at_least(pts, centre, MIN_CHANGE_ELLIPSE_PIXELS * per_pixel),
            )
        } else {
            let g = (200.0 * (1.0 - t)) as u8;
            (
                RGBColor(g, g, 255u8.saturating_sub((100.0 * t) as u8)).stroke_width(1),
                pts.clone(),
            )
        };
        chart
            .draw_series(LineSeries::new(pts, color))
            .map_err(|x| e(&x))?;
    }
    chart
        .draw_series(LineSeries::new(
            dists.iter().map(|(_, d)| (d.mean[0], d.mean[1])),
            BLACK.stroke_width(1),
        ))
        .map_err(|x| e(&x))?
        .label(if thinned {
            "mean θ of the updates drawn"
        } else {
            "mean θ per update"
        })
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
    chart
        .draw_series(
            dists
                .iter()
                .map(|(_, d)| Circle::new((d.mean[0], d.mean[1]), 2, BLACK.filled())),
        )
        .map_err(|x| e(&x))?;
    draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto;

    /// The first update after a task change is marked by a red ellipse; with λ small there it
    /// was under a pixel. It is drawn at least MIN_CHANGE_ELLIPSE_PIXELS in half-axis.
    #[test]
    fn the_ellipse_after_a_task_change_stays_visible_when_lambda_is_small() {
        let mut r = Recording::default();
        r.run.push(proto::RunInfo {
            dim: 2,
            ..Default::default()
        });
        let change = proto::TaskChange {
            update: 3,
            ..Default::default()
        };
        r.digest.add_task_change(&change);
        r.task_changes.push(change);
        let d = |m: f64, var: f64| proto::Distribution {
            dim: 2,
            mean: vec![m, -m],
            covariance: vec![var, 0.0, 0.0, var],
        };
        for u in 0..6u64 {
            // Converged before the change: a variance of 1e-12 against 1 at the start.
            let var = if u < 2 { 1.0 } else { 1e-12 };
            r.digest.add_update(&proto::Update {
                update: u,
                dim: 2,
                before: Some(d(u as f64, var)),
                after: Some(d(u as f64 + 1.0, var)),
                ..Default::default()
            });
        }
        let dir = std::env::temp_dir().join(format!("pi2cma-red-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("distribution.svg");
        plot_ellipses(&r, &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let red = svg
            .split("<polyline")
            .find(|p| p.contains("stroke=\"#D62728\""))
            .expect("a red ellipse");
        let pts: Vec<(f64, f64)> = red
            .split("points=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap()
            .split_whitespace()
            .filter_map(|p| {
                let (x, y) = p.split_once(',')?;
                Some((x.parse().ok()?, y.parse().ok()?))
            })
            .collect();
        let span = |f: fn(&(f64, f64)) -> f64| {
            let v: Vec<f64> = pts.iter().map(f).collect();
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        // Whole pixels: 2 × 6 px across, give or take the rounding of each end.
        assert!(span(|p| p.0) >= 10.0 && span(|p| p.1) >= 10.0, "{red}");
    }

    #[test]
    fn ellipse_axes_follow_the_eigenvectors() {
        // Σ = diag(4, 1): 2σ half-axes 4 along x and 2 along y.
        let pts = ellipse([1.0, 2.0], [[4.0, 0.0], [0.0, 1.0]]);
        let maxx = pts.iter().map(|p| p.0).fold(f64::MIN, f64::max);
        let maxy = pts.iter().map(|p| p.1).fold(f64::MIN, f64::max);
        assert!(
            (maxx - 5.0).abs() < 1e-9 && (maxy - 4.0).abs() < 1e-2,
            "{maxx} {maxy}"
        );
        // A rotated one: Σ with eigenvalues 3 and 1 along (1,1)/√2 and (1,−1)/√2.
        let pts = ellipse([0.0, 0.0], [[2.0, 1.0], [1.0, 2.0]]);
        let far = pts
            .iter()
            .max_by(|a, b| (a.0 * a.0 + a.1 * a.1).total_cmp(&(b.0 * b.0 + b.1 * b.1)))
            .copied()
            .unwrap();
        assert!((far.0.abs() - far.1.abs()).abs() < 1e-9, "{far:?}");
        assert!(((far.0 * far.0 + far.1 * far.1).sqrt() - 2.0 * 3f64.sqrt()).abs() < 1e-9);
    }
}
