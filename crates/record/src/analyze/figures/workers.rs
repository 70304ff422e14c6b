//! Where the rollouts' time went, per worker: `worker_time.svg` (each rollout's time, or per
//! bucket of updates their mean and range, for a long run) and `worker_timeline.svg` (what each
//! worker ran in the last updates, on the workers' own clocks). From the recorded times only:
//! it measures nothing itself.

use std::path::Path;

use plotters::prelude::*;

use super::{draw_legend, PALETTE};
use crate::digest::{TimeBucket, TimelineBar, WorkerSummary, WorkerTimes, TIMELINE_UPDATES};
use crate::ticks::{self, Along, Ticks};
use crate::Recording;

/// The narrowest bar of `worker_timeline.svg`, in pixels: 1.5 covers at least one whole pixel
/// wherever the bar begins.
const MIN_BAR_PIXELS: f64 = 1.5;

// No two updates of a timeline share a colour.
const _: () = assert!(PALETTE.len() >= TIMELINE_UPDATES);

/// The timed rollouts of the last `updates` updates that have any (at most
/// [`TIMELINE_UPDATES`]: what the digest keeps), in start order: when each worker ran what (the
/// workers' own clocks in the pipeline), so idle workers, stragglers and the gaps between
/// updates show.
pub fn timeline(rec: &Recording, updates: usize) -> Vec<TimelineBar> {
    let timed = &rec.digest.timeline;
    let mut last: Vec<u64> = timed.iter().map(|r| r.update).collect();
    last.sort_unstable();
    last.dedup();
    let from = last.len().checked_sub(updates).map_or(0, |i| last[i]);
    let mut bars: Vec<TimelineBar> = timed.iter().filter(|r| r.update >= from).cloned().collect();
    bars.sort_by_key(|b| (b.start_ns, b.update, b.rollout));
    bars
}

pub(super) fn plot_worker_timeline(
    rec: &Recording,
    bars: &[TimelineBar],
    path: &Path,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    let t0 = bars.iter().map(|b| b.start_ns).min().unwrap_or(0);
    let ms = |t: u64| (t - t0) as f64 / 1e6;
    let xmax = bars.iter().map(|b| ms(b.end_ns)).fold(0.0f64, f64::max);
    let mut workers: Vec<&str> = bars.iter().map(|b| b.worker.as_str()).collect();
    workers.sort_unstable();
    workers.dedup();
    let row = |w: &str| workers.iter().position(|x| *x == w).unwrap_or(0) as f64;
    let (first, last) = (
        bars.iter().map(|b| b.update).min().unwrap_or(0),
        bars.iter().map(|b| b.update).max().unwrap_or(0),
    );
    // Tall enough for the legend of TIMELINE_UPDATES entries, which sits in room kept free at
    // the right (the x range runs 18 % past the last bar).
    let height = (120 + 40 * workers.len() as u32).max(330);
    let root = SVGBackend::new(path, (1000, height)).into_drawing_area();
    let xright = (xmax * 1.18).max(1e-3);
    let (w, _) = ticks::plot_size(root.dim_in_pixel(), 10, 90, 0, 30, 18);
    let xt = Ticks::linear(0.0, xright, w, Along::Horizontal);
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "{}: what each worker ran, updates {first} to {last}",
                rec.name()
            ),
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(90)
        .build_cartesian_2d(xt.on(0f64, xright), -0.5f64..(workers.len() as f64 - 0.5))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("time [ms]")
        .y_labels(workers.len())
        .y_label_formatter(&|y| {
            let i = y.round();
            if (y - i).abs() < 1e-6 && i >= 0.0 {
                workers
                    .get(i as usize)
                    .map(|w| w.to_string())
                    .unwrap_or_default()
            } else {
                String::new()
            }
        })
        .disable_y_mesh()
        .draw()
        .map_err(|x| e(&x))?;
    // The SVG backend draws on whole pixels: a rollout shorter than one (a via-point rollout
    // takes a microsecond, the timeline spans milliseconds) became a rectangle 0 wide, and an
    // update whose rollouts were all that short was missing from the figure. Every bar is at
    // least MIN_BAR_PIXELS wide.
    let (x_range, plot_pixels) = (
        chart.x_range(),
        chart.plotting_area().dim_in_pixel().0.max(1),
    );
    let min_width = MIN_BAR_PIXELS * (x_range.end - x_range.start) / f64::from(plot_pixels);
    // One colour per update shown (TIMELINE_UPDATES of them), named in the legend.
    let mut updates: Vec<u64> = bars.iter().map(|b| b.update).collect();
    updates.sort_unstable();
    updates.dedup();
    for (i, u) in updates.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(bars.iter().filter(|b| b.update == *u).map(|b| {
                let y = row(&b.worker);
                Rectangle::new(
                    [
                        (ms(b.start_ns), y - 0.35),
                        (ms(b.end_ns).max(ms(b.start_ns) + min_width), y + 0.35),
                    ],
                    color.filled(),
                )
            }))
            .map_err(|x| e(&x))?
            .label(format!("update {u}"))
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 12, y + 4)], color.filled()));
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

/// A time in ms with 3 significant digits, in the unit that keeps them whole-ish (ns, µs, ms
/// or s): each worker's own, so a worker of microseconds beside one of seconds does not read
/// "0.001 ms".
fn format_time(ms: f64) -> String {
    let (v, unit) = match ms.abs() {
        t if t >= 1e3 => (ms / 1e3, "s"),
        t if t >= 1.0 || t == 0.0 => (ms, "ms"),
        t if t >= 1e-3 => (ms * 1e3, "µs"),
        _ => (ms * 1e6, "ns"),
    };
    let digits = if v == 0.0 {
        0
    } else {
        (2 - v.abs().log10().floor() as i32).max(0) as usize
    };
    format!("{v:.digits$} {unit}")
}

/// A worker's entry in the legend: how many rollouts, their median (the times are skewed:
/// a few slow rollouts pull the mean up) and mean.
fn legend_label(s: &WorkerSummary) -> String {
    format!(
        "{}: {} rollouts, median {}{}, mean {}",
        s.worker,
        s.count,
        if s.median_exact { "" } else { "≈ " },
        format_time(s.median),
        format_time(s.mean)
    )
}

pub(super) fn plot_worker_time(rec: &Recording, path: &Path) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Debug| format!("{x:?}");
    // Rollouts without their own timing (the in-process runner) have the update's wall time
    // divided by K, under "`<worker>` (update time / K)" (see `Digest::add_rollout`).
    let times = &rec.digest.worker_times;
    let xmax = rec
        .digest
        .points
        .last()
        .map(|u| u.update as f64 + 1.0)
        .unwrap_or(1.0);
    let ymax = match times {
        WorkerTimes::Each(m) => m
            .values()
            .flat_map(|v| v.iter().map(|p| p.1))
            .fold(0.0f64, f64::max),
        WorkerTimes::Buckets { per_worker, .. } => per_worker
            .values()
            .flat_map(|b| b.values().map(|t| t.max))
            .fold(0.0f64, f64::max),
    };
    // In-process via-point rollouts take well under a millisecond: µs then, not "0.000 ms".
    let (scale, unit) = if ymax < 1.0 {
        (1e3, "µs")
    } else {
        (1.0, "ms")
    };
    let ymax = ymax * scale;
    let root = SVGBackend::new(path, (900, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let caption = match times {
        WorkerTimes::Each(_) => format!("{}: rollout time per worker", rec.name()),
        WorkerTimes::Buckets { width, .. } => format!(
            "{}: rollout time per worker, per {width} updates: mean (dot), range (line)",
            rec.name()
        ),
    };
    let ytop = (ymax * 1.1).max(1e-3);
    let (w, h) = ticks::plot_size(root.dim_in_pixel(), 10, 70, 0, 30, 20);
    let (xt, yt) = (
        Ticks::linear(0.0, xmax, w, Along::Horizontal),
        Ticks::linear(0.0, ytop, h, Along::Vertical),
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(70)
        .build_cartesian_2d(xt.on(0f64, xmax), yt.on(0f64, ytop))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("update")
        .y_desc(format!("rollout time [{unit}]"))
        .draw()
        .map_err(|x| e(&x))?;
    let labels: Vec<String> = times.summaries().iter().map(legend_label).collect();
    match times {
        WorkerTimes::Each(m) => {
            for (i, pts) in m.values().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                chart
                    .draw_series(
                        pts.iter().map(|(u, ms)| {
                            Circle::new((*u as f64, *ms * scale), 2, color.filled())
                        }),
                    )
                    .map_err(|x| e(&x))?
                    .label(&labels[i])
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
            }
        }
        WorkerTimes::Buckets {
            width, per_worker, ..
        } => {
            let w = *width as f64;
            for (i, buckets) in per_worker.values().enumerate() {
                let color = PALETTE[i % PALETTE.len()];
                let middle = |i: u64| (i as f64 + 0.5) * w;
                chart
                    .draw_series(buckets.iter().map(|(i, b)| {
                        PathElement::new(
                            vec![(middle(*i), b.min * scale), (middle(*i), b.max * scale)],
                            color.mix(0.5).stroke_width(1),
                        )
                    }))
                    .map_err(|x| e(&x))?;
                chart
                    .draw_series(buckets.iter().map(|(i, b): (&u64, &TimeBucket)| {
                        Circle::new(
                            (middle(*i), scale * b.sum / b.count.max(1) as f64),
                            2,
                            color.filled(),
                        )
                    }))
                    .map_err(|x| e(&x))?
                    .label(&labels[i])
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
            }
        }
    }
    draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto;

    #[test]
    fn the_timeline_holds_the_last_timed_updates_in_start_order() {
        let mut r = Recording::default();
        for u in 0..5u64 {
            for k in 0..2u32 {
                r.digest.add_rollout(&proto::Rollout {
                    update: u,
                    rollout: k,
                    worker: format!("worker-{k}"),
                    start_ns: 1_000 * u + 10 * u64::from(1 - k) + 1,
                    end_ns: 1_000 * u + 500,
                    ..Default::default()
                });
            }
        }
        // An untimed rollout (a worker that does not stamp, before any arrival) is left out.
        r.digest.add_rollout(&proto::Rollout {
            update: 5,
            ..Default::default()
        });
        let bars = timeline(&r, 2);
        let got: Vec<(u64, u32, &str)> = bars
            .iter()
            .map(|b| (b.update, b.rollout, b.worker.as_str()))
            .collect();
        assert_eq!(
            got,
            [
                (3, 1, "worker-1"),
                (3, 0, "worker-0"),
                (4, 1, "worker-1"),
                (4, 0, "worker-0")
            ]
        );
        assert_eq!(timeline(&r, 100).len(), 10);
        assert!(timeline(&Recording::default(), 10).is_empty());
    }

    /// Rollouts of a microsecond on a timeline of milliseconds (pipelined via-point runs): every
    /// update still has its bars, at least a pixel wide.
    #[test]
    fn the_timeline_draws_every_rollout_however_short() {
        let mut r = Recording::default();
        for u in 0..10u64 {
            for k in 0..15u32 {
                let start = 1_000_000 + 100_000 * u + 600 * u64::from(k);
                r.digest.add_rollout(&proto::Rollout {
                    update: u,
                    rollout: k,
                    worker: format!("worker-{}", k % 3),
                    start_ns: start,
                    end_ns: start + 250,
                    ..Default::default()
                });
            }
        }
        let dir = std::env::temp_dir().join(format!("pi2cma-timeline-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("worker_timeline.svg");
        plot_worker_timeline(&r, &timeline(&r, 10), &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        // The bars are the filled rectangles other than the background, the legend's box and
        // its 12 × 8 swatches.
        let widths: Vec<u32> = svg
            .split("<rect ")
            .skip(1)
            .filter(|r| {
                ![
                    "fill=\"#FFFFFF\"",
                    "fill=\"none\"",
                    "width=\"12\" height=\"8\"",
                ]
                .iter()
                .any(|not_a_bar| r.contains(not_a_bar))
            })
            .filter_map(|r| {
                let w = r.split("width=\"").nth(1)?.split('"').next()?;
                w.parse().ok()
            })
            .collect();
        assert_eq!(widths.len(), 150, "{svg}");
        assert!(widths.iter().all(|w| *w >= 1), "bars 0 px wide: {widths:?}");
    }

    /// A worker of microseconds beside one of tens of milliseconds (a pipelined via-point run
    /// with a slow worker): each legend entry keeps 3 significant digits in its own unit, and
    /// gives the median beside the mean of skewed times.
    #[test]
    fn the_worker_time_legend_gives_each_worker_median_and_mean_in_its_own_unit() {
        let mut r = Recording::default();
        // ns: fast gets 1 µs, 1 µs, 1.3 µs (median 1.00, mean 1.10); slow 20, 20, 50 ms.
        for (k, (fast, slow)) in [
            (1_000u64, 20_000_000u64),
            (1_000, 20_000_000),
            (1_300, 50_000_000),
        ]
        .into_iter()
        .enumerate()
        {
            for (worker, ns) in [("fast", fast), ("slow", slow)] {
                r.digest.add_rollout(&proto::Rollout {
                    update: k as u64,
                    worker: worker.into(),
                    start_ns: 1_000,
                    end_ns: 1_000 + ns,
                    ..Default::default()
                });
            }
        }
        let dir = std::env::temp_dir().join(format!("pi2cma-worker-time-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("worker_time.svg");
        plot_worker_time(&r, &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        for label in [
            "fast: 3 rollouts, median 1.00 µs, mean 1.10 µs",
            "slow: 3 rollouts, median 20.0 ms, mean 30.0 ms",
        ] {
            assert!(svg.contains(label), "no {label:?} in {svg}");
        }
        assert_eq!(format_time(1234.5), "1.23 s");
        assert_eq!(format_time(0.000_5), "500 ns");
        assert_eq!(format_time(0.0), "0 ms");
    }
}
