//! The paper's T-ball experiment (Section IV-B, Fig. 4): runs S learning sessions of a config
//! in-process, writes per-update CSVs and Fig. 4-style SVGs into an output directory, and prints
//! a summary table.
//!
//! ```text
//! cargo run --release -p tball --example tball-experiment -- \
//!     [--config config/tball.toml] [--sessions 10] [--out runs/tball] [--weighting per-time-step]
//!     [--covariance per-dimension]
//! ```
//!
//! Updates are numbered from 1 in the output, as in the paper: "after 20 updates" is update 20,
//! the last one with the ball at its first height; update 21 is the first with the lowered ball.

use std::error::Error;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use plotters::prelude::*;
use record::ticks::{self, Along, Ticks};
use session::{CovarianceName, Observer, RunConfig, UpdateRecord, WeightingName};
use tasks::Task;
use tball::{Tball, Trace};

mod common;

type Res<T> = Result<T, Box<dyn Error>>;

/// One update of one session, as recorded.
struct UpdateRow {
    eval_cost: f64,
    eval_terminal: f64,
    landing_y: Option<f64>,
    lambda: f64,
    exploration_mean: f64,
    exploration_std: f64,
    /// The K parameter vectors (row 0: the evaluation rollout) and the ball height.
    samples: Vec<Vec<f64>>,
    ball_height: f64,
}

struct Recorder {
    task: Tball,
    rows: Vec<UpdateRow>,
}

impl Observer for Recorder {
    fn on_update(&mut self, r: &UpdateRecord<'_>) {
        for (name, value) in r.task_settings {
            // The settings come from the same task type; a failure would be a bug here.
            self.task
                .set(name, *value)
                .expect("settings reported by the task are valid");
        }
        let samples: Vec<Vec<f64>> = (0..r.samples.rollouts)
            .map(|k| r.samples.row(k).to_vec())
            .collect();
        let outcome = self.task.trace(&samples[0]).outcome;
        self.rows.push(UpdateRow {
            eval_cost: r.summary.eval_cost,
            eval_terminal: r.costs.terminal(0),
            landing_y: outcome.hit.map(|h| h.landing[1]),
            lambda: r.summary.lambda,
            exploration_mean: r.summary.exploration_cost_mean,
            exploration_std: r.summary.exploration_cost_std,
            samples,
            ball_height: self.task.resting_ball()[2],
        });
    }
}

/// Runs S learning sessions of a T-ball config in-process and writes CSVs, Fig. 4-style SVGs
/// and a summary into an output directory.
#[derive(clap::Parser)]
#[command(name = "tball-experiment")]
struct Args {
    /// A `[task.tball]` run config.
    #[arg(long, default_value = "config/tball.toml")]
    config: PathBuf,
    /// Learning sessions (seeds run.seed, run.seed + 1, …).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    sessions: u64,
    /// Output directory.
    #[arg(long, default_value = "runs/tball")]
    out: PathBuf,
    /// Overrides `optimizer.weighting`, to compare the two modes on the same run.
    #[arg(long, value_enum)]
    weighting: Option<Weighting>,
    /// Overrides `optimizer.covariance`: one covariance over all the weights of the 7 joints,
    /// or one B × B covariance per joint (`per-dimension`, also accepted as `per-joint`), as the
    /// paper's Σ_init = λ_init·I_3 implies.
    #[arg(long, value_enum)]
    covariance: Option<Covariance>,
}

#[derive(Clone, Copy, PartialEq, clap::ValueEnum)]
enum Covariance {
    Full,
    #[value(alias = "per-joint")]
    PerDimension,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Weighting {
    Episodic,
    PerTimeStep,
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n as f64
}

fn geometric_mean(v: impl Iterator<Item = f64>) -> f64 {
    mean(v.map(f64::ln)).exp()
}

fn main() -> std::process::ExitCode {
    common::main(run)
}

fn run() -> Res<()> {
    let args = <Args as clap::Parser>::parse();
    let mut cfg = RunConfig::load(&args.config)?;
    if let Some(w) = args.weighting {
        cfg.optimizer.weighting = match w {
            Weighting::Episodic => WeightingName::Episodic,
            Weighting::PerTimeStep => WeightingName::PerTimeStep,
        };
        cfg.validate()?;
    }
    if let Some(c) = args.covariance {
        cfg.optimizer.covariance = match c {
            Covariance::Full => CovarianceName::Full,
            Covariance::PerDimension => CovarianceName::PerDimension,
        };
        cfg.validate()?;
    }
    println!(
        "{}: {} sessions, weighting {:?}{}",
        args.config.display(),
        args.sessions,
        cfg.optimizer.weighting,
        match cfg.optimizer.covariance {
            CovarianceName::Full => "",
            CovarianceName::PerDimension => ", one covariance per joint",
        }
    );
    let task_cfg = common::tball_task(&cfg, &args.config)?;
    std::fs::create_dir_all(&args.out)?;
    let mut sessions = Vec::new();
    let start = std::time::Instant::now();
    for s in 0..args.sessions {
        let mut rec = Recorder {
            task: Tball::new(task_cfg)?,
            rows: Vec::new(),
        };
        session::run_session(&cfg, cfg.run.seed + s, &mut rec)?;
        sessions.push(rec.rows);
    }
    let elapsed = start.elapsed();
    write_csv(&args.out, &sessions)?;
    let change = cfg.schedule.first().map(|c| c.from_update as usize);
    let summary = print_summary(&sessions, change);
    std::fs::write(args.out.join("summary.txt"), summary)?;
    println!(
        "{} sessions × {} updates in {:.2} s",
        sessions.len(),
        sessions[0].len(),
        elapsed.as_secs_f64()
    );
    let task = Tball::new(task_cfg)?;
    // The line marks the config's change, named as given (not the paper's "5 cm lower" whatever
    // the schedule says); numbered from 1 like the figure's updates.
    let change_label = cfg.schedule.first().map(|c| {
        format!(
            "{} = {} from update {}",
            c.set,
            tasks::value_text(c.value),
            c.from_update + 1
        )
    });
    plot_learning_curve(
        &args.out.join("cost_lambda.svg"),
        &sessions,
        change.zip(change_label.as_deref()),
    )?;
    plot_ball(&args.out.join("ball_trajectories.svg"), &task, &sessions[0])?;
    plot_bat(&args.out.join("bat_paths.svg"), &task, &sessions[0])?;
    println!("wrote {}", args.out.display());
    Ok(())
}

fn write_csv(out: &Path, sessions: &[Vec<UpdateRow>]) -> Res<()> {
    let mut all = String::from(
        "session,update,eval_cost,eval_terminal,landing_y,in_target,lambda,exploration_mean,exploration_std,ball_height\n",
    );
    for (s, rows) in sessions.iter().enumerate() {
        for (u, r) in rows.iter().enumerate() {
            writeln!(
                all,
                "{s},{},{},{},{},{},{},{},{},{}",
                u + 1,
                r.eval_cost,
                r.eval_terminal,
                r.landing_y.map_or(String::from("miss"), |y| y.to_string()),
                u8::from(r.landing_y.is_some() && r.eval_terminal == 0.0),
                r.lambda,
                r.exploration_mean,
                r.exploration_std,
                r.ball_height,
            )?;
        }
    }
    std::fs::write(out.join("sessions.csv"), all)?;
    let mut m = String::from(
        "update,eval_cost_mean,lambda_mean,lambda_geometric_mean,in_target_fraction\n",
    );
    for u in 0..sessions[0].len() {
        writeln!(
            m,
            "{},{},{},{},{}",
            u + 1,
            mean(sessions.iter().map(|s| s[u].eval_cost)),
            mean(sessions.iter().map(|s| s[u].lambda)),
            geometric_mean(sessions.iter().map(|s| s[u].lambda)),
            mean(sessions.iter().map(|s| f64::from(u8::from(
                s[u].eval_terminal == 0.0 && s[u].landing_y.is_some()
            )))),
        )?;
    }
    std::fs::write(out.join("mean.csv"), m)?;
    Ok(())
}

fn in_target(r: &UpdateRow) -> bool {
    r.landing_y.is_some() && r.eval_terminal == 0.0
}

fn print_summary(sessions: &[Vec<UpdateRow>], change: Option<usize>) -> String {
    let mut out = String::new();
    // Writing to a String cannot fail.
    let _ = summary_table(&mut out, sessions, change);
    print!("{out}");
    out
}

fn summary_table(
    out: &mut String,
    sessions: &[Vec<UpdateRow>],
    change: Option<usize>,
) -> std::fmt::Result {
    let n = sessions[0].len();
    // The updates either side of the change (the paper's 20 and 21 without one) and the last:
    // the headers said cost@20, cost@21 and cost@40 whatever the config's schedule and length.
    let before = change.unwrap_or(20);
    let after = before + 1;
    writeln!(
        out,
        "{:>7} {:>10} {:>9} {:>9} {:>9} {:>10} {:>9} {:>9}",
        "session",
        "first_hit",
        "cost@1",
        format!("cost@{before}"),
        format!("cost@{after}"),
        "λpeak@",
        format!("cost@{n}"),
        format!("target@{n}")
    )?;
    let at = |rows: &[UpdateRow], u: usize| rows.get(u - 1).map_or(f64::NAN, |r| r.eval_cost);
    let mut firsts = Vec::new();
    let mut peaks = Vec::new();
    for (s, rows) in sessions.iter().enumerate() {
        let before_change = &rows[..change.unwrap_or(rows.len()).min(rows.len())];
        let first = before_change.iter().position(in_target).map(|u| u + 1);
        let peak = change.filter(|&c| c < n).map(|c| {
            let (i, _) = rows[c..]
                .iter()
                .enumerate()
                .fold((0, f64::MIN), |b, (i, r)| {
                    if r.lambda > b.1 {
                        (i, r.lambda)
                    } else {
                        b
                    }
                });
            c + i + 1
        });
        firsts.extend(first.map(|f| f as f64));
        peaks.extend(peak.map(|p| p as f64));
        writeln!(
            out,
            "{:>7} {:>10} {:>9.3} {:>9.3} {:>9.3} {:>10} {:>9.3} {:>9}",
            s,
            first.map_or("never".into(), |f| f.to_string()),
            at(rows, 1),
            at(rows, before),
            at(rows, after),
            peak.map_or("-".into(), |p| p.to_string()),
            at(rows, n),
            rows.last().is_some_and(in_target),
        )?;
    }
    writeln!(
        out,
        "{:>7} {:>10.1} {:>9.3} {:>9.3} {:>9.3} {:>10.1} {:>9.3} {:>9.2}",
        "mean",
        mean(firsts.iter().copied()),
        mean(sessions.iter().map(|r| at(r, 1))),
        mean(sessions.iter().map(|r| at(r, before))),
        mean(sessions.iter().map(|r| at(r, after))),
        mean(peaks.iter().copied()),
        mean(sessions.iter().map(|r| at(r, n))),
        mean(
            sessions
                .iter()
                .map(|r| f64::from(u8::from(r.last().is_some_and(in_target))))
        ),
    )?;
    if firsts.len() < sessions.len() {
        writeln!(
            out,
            "(first_hit: first update in the target before the change; {} sessions never were)",
            sessions.len() - firsts.len()
        )?;
    }
    Ok(())
}

/// Cost of the evaluation rollout (mean over sessions, with the mean ± std of the exploration
/// rollouts' costs as a band) and λ on a log axis, per update.
fn plot_learning_curve(
    path: &Path,
    sessions: &[Vec<UpdateRow>],
    change: Option<(usize, &str)>,
) -> Res<()> {
    let n = sessions[0].len();
    let cost: Vec<(f64, f64)> = (0..n)
        .map(|u| {
            (
                (u + 1) as f64,
                mean(sessions.iter().map(|s| s[u].eval_cost)),
            )
        })
        .collect();
    let band: Vec<(f64, f64, f64)> = (0..n)
        .map(|u| {
            let m = mean(sessions.iter().map(|s| s[u].exploration_mean));
            let sd = mean(sessions.iter().map(|s| s[u].exploration_std));
            ((u + 1) as f64, m - sd, m + sd)
        })
        .collect();
    // λ spans orders of magnitude and jumps between updates: its geometric mean over sessions
    // is what a log axis shows faithfully.
    let lambda: Vec<(f64, f64)> = (0..n)
        .map(|u| {
            (
                (u + 1) as f64,
                geometric_mean(sessions.iter().map(|s| s[u].lambda)),
            )
        })
        .collect();
    let y_max = band
        .iter()
        .map(|b| b.2)
        .chain(cost.iter().map(|c| c.1))
        .fold(0.0f64, f64::max)
        * 1.05;
    let root = SVGBackend::new(path, (800, 600)).into_drawing_area();
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(300);
    let xmax = n as f64 + 1.0;
    let (w, h) = ticks::plot_size(top.dim_in_pixel(), 10, 50, 0, 30, 16);
    let xt = Ticks::linear(0.0, xmax, w, Along::Horizontal);
    let yt = Ticks::linear(0.0, y_max, h, Along::Vertical);
    let mut c = ChartBuilder::on(&top)
        .caption(
            format!(
                "T-ball: cost of the evaluation rollout (mean of {} sessions)",
                sessions.len()
            ),
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(xt.on(0.0, xmax), yt.on(0.0, y_max))?;
    c.configure_mesh().x_desc("update").y_desc("cost").draw()?;
    let band_poly: Vec<(f64, f64)> = band
        .iter()
        .map(|b| (b.0, b.2.max(0.0)))
        .chain(band.iter().rev().map(|b| (b.0, b.1.max(0.0))))
        .collect();
    c.draw_series(std::iter::once(Polygon::new(band_poly, BLUE.mix(0.15))))?
        .label("exploration rollouts: mean ± std")
        .legend(|(x, y)| Rectangle::new([(x, y - 4), (x + 15, y + 4)], BLUE.mix(0.15).filled()));
    c.draw_series(LineSeries::new(cost, BLUE.stroke_width(2)))?
        .label("evaluation rollout")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], BLUE.stroke_width(2)));
    if let Some((ch, label)) = change {
        let x = ch as f64 + 0.5;
        c.draw_series(std::iter::once(PathElement::new(
            vec![(x, 0.0), (x, y_max)],
            BLACK.mix(0.5),
        )))?
        .label(label)
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 15, y)], BLACK.mix(0.5)));
    }
    c.configure_series_labels()
        .position(SeriesLabelPosition::LowerLeft)
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()?;

    let (lo, hi) = lambda.iter().fold((f64::MAX, f64::MIN), |(lo, hi), l| {
        (lo.min(l.1), hi.max(l.1))
    });
    let (_, h) = ticks::plot_size(bottom.dim_in_pixel(), 10, 50, 0, 30, 16);
    let (lo, hi) = (lo * 0.5, hi * 2.0);
    let lt = Ticks::log(lo, hi, h, Along::Vertical);
    let mut c = ChartBuilder::on(&bottom)
        .caption(
            "exploration magnitude λ (largest eigenvalue of Σ), geometric mean over sessions",
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(xt.on(0.0, xmax), lt.on_log(lo, hi))?;
    c.configure_mesh()
        .x_desc("update")
        .y_desc("λ (log)")
        .draw()?;
    c.draw_series(LineSeries::new(lambda, RED.stroke_width(2)))?;
    root.present()?;
    Ok(())
}

/// Ball trajectories (side view: y–z, to scale) of the evaluation rollouts of updates 1, 20, 21,
/// 40 (numbered from 1: the evaluation rollout of update u runs the mean of u − 1 updates), one
/// panel above the other, under a legend of target, tee and ball.
fn plot_ball(path: &Path, task: &Tball, rows: &[UpdateRow]) -> Res<()> {
    let updates = [1usize, 20, 21, 40];
    let cfg = task.config();
    // Every panel's flight, tee and ball, to fit one z range to them all.
    let mut panels = Vec::new();
    for &u in &updates {
        let Some(row) = rows.get(u - 1) else { continue };
        let mut t = task.clone();
        t.set("ball_height", row.ball_height)?;
        let trace: Trace = t.trace(&row.samples[0]);
        let flight = trace.ball_path(0.01, cfg.gravity, t.resting_ball());
        let label = match trace.outcome.hit {
            Some(h) => landing_text(&t, h.landing),
            None => "the bat misses the ball".into(),
        };
        panels.push((u, t.resting_ball(), flight, label));
    }
    // The z axis ran to 1.2 m for flights under 0.55 m: fitted to the data with a margin.
    let z_top = panels
        .iter()
        .flat_map(|(_, ball, flight, _)| flight.iter().map(|p| p[2]).chain([ball[2]]))
        .fold(0.0f64, f64::max);
    let (y_range, z_range) = ((-2.5, 0.5), (0.0, z_top + 0.08));
    let (width, panel_h, legend_h) = (900u32, 230u32, 30u32);
    let root = SVGBackend::new(path, (width, legend_h + panel_h * panels.len() as u32))
        .into_drawing_area();
    root.fill(&WHITE)?;
    let (legend, grid) = root.split_vertically(legend_h);
    legend_strip(
        &legend,
        &[
            (Swatch::Band(GREEN.mix(0.6)), "target area"),
            (Swatch::Stick(BLACK), "tee"),
            (
                Swatch::Flight(BLUE),
                "ball: on the tee (dot) and its flight",
            ),
        ],
    )?;
    let areas = grid.split_evenly((panels.len().max(1), 1));
    for (area, (u, ball, flight, label)) in areas.iter().zip(&panels) {
        // A side view: a metre as long across as up.
        let (w, h) = ticks::plot_size(area.dim_in_pixel(), 8, 45, 0, 35, 14);
        let ((y0, y1), (z0, z1)) = ticks::equal_scale(y_range, z_range, w, h);
        // Widened about the middle: the ground stays at the bottom.
        let (z0, z1) = (0.0, z1 - z0);
        let yt = Ticks::linear(y0, y1, w, Along::Horizontal);
        let zt = Ticks::linear(z0, z1, h, Along::Vertical);
        let mut c = ChartBuilder::on(area)
            .caption(
                format!(
                    "session 0, update {u}, evaluation rollout (side view y–z, to scale): {label}"
                ),
                ("sans-serif", 14),
            )
            .margin(8)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(yt.on(y0, y1), zt.on(z0, z1))?;
        c.configure_mesh().x_desc("y (m)").y_desc("z (m)").draw()?;
        c.draw_series(std::iter::once(Rectangle::new(
            [(cfg.target_y_min, 0.0), (cfg.target_y_max, 0.03)],
            GREEN.mix(0.6).filled(),
        )))?;
        c.draw_series(std::iter::once(PathElement::new(
            vec![(ball[1], 0.0), (ball[1], ball[2] - cfg.ball_radius)],
            BLACK.stroke_width(2),
        )))?;
        c.draw_series(LineSeries::new(
            flight.iter().map(|p| (p[1], p[2])),
            BLUE.stroke_width(2),
        ))?;
        // The ball on the tee before the swing.
        c.draw_series(std::iter::once(Circle::new(
            (ball[1], ball[2]),
            3,
            BLUE.filled(),
        )))?;
    }
    root.present()?;
    Ok(())
}

/// Where a ball lands against the target, for a caption. "lands at y = -1.50 m" alone did not
/// say whether -1.5004 m was in the target; a miss under a centimetre is given in mm, not as
/// "0.00 m".
fn landing_text(task: &Tball, landing: tball::Vec3) -> String {
    let y = landing[1];
    let off = task.distance_to_target(landing);
    let place = if off == 0.0 {
        "in the target".to_string()
    } else {
        let side = if y > task.config().target_y_max {
            "short of"
        } else {
            "past"
        };
        if off < 0.01 {
            format!("{:.1} mm {side} the target", off * 1e3)
        } else {
            format!("{off:.2} m {side} the target")
        }
    };
    format!("lands at y = {y:.2} m, {place}")
}

/// What a legend entry shows next to its text.
enum Swatch {
    Band(RGBAColor),
    Stick(RGBColor),
    Flight(RGBColor),
    Line(RGBAColor, u32),
    Dot(RGBColor),
}

/// A one-row legend across `area`.
fn legend_strip(
    area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    entries: &[(Swatch, &str)],
) -> Res<()> {
    let (mut x, y) = (60i32, (area.dim_in_pixel().1 / 2) as i32);
    for (swatch, text) in entries {
        match swatch {
            Swatch::Band(c) => {
                area.draw(&Rectangle::new([(x, y - 3), (x + 24, y + 3)], c.filled()))?
            }
            Swatch::Stick(c) => area.draw(&PathElement::new(
                vec![(x + 12, y - 8), (x + 12, y + 8)],
                c.stroke_width(2),
            ))?,
            Swatch::Flight(c) => {
                area.draw(&PathElement::new(
                    vec![(x, y + 6), (x + 24, y - 2)],
                    c.stroke_width(2),
                ))?;
                area.draw(&Circle::new((x + 24, y - 2), 3, c.filled()))?;
            }
            Swatch::Line(c, w) => area.draw(&PathElement::new(
                vec![(x, y), (x + 24, y)],
                c.stroke_width(*w),
            ))?,
            Swatch::Dot(c) => area.draw(&Circle::new((x + 12, y), 4, c.filled()))?,
        }
        area.draw(&Text::new(*text, (x + 30, y - 6), ("sans-serif", 12)))?;
        x += 30 + ticks::label_width(text) as i32 + 20;
    }
    Ok(())
}

/// Bat tip paths projected onto the y–z plane (front view, to scale) of the K rollouts of
/// updates 1, 20, 27, 40, under a legend.
fn plot_bat(path: &Path, task: &Tball, rows: &[UpdateRow]) -> Res<()> {
    let updates = [1usize, 20, 27, 40];
    let mut panels = Vec::new();
    for &u in &updates {
        let Some(row) = rows.get(u - 1) else { continue };
        let mut t = task.clone();
        t.set("ball_height", row.ball_height)?;
        let tips: Vec<Vec<(f64, f64)>> = row
            .samples
            .iter()
            .map(|theta| {
                t.trace(theta)
                    .bat_tip
                    .iter()
                    .map(|p| (p[1], p[2]))
                    .collect()
            })
            .collect();
        let ball = t.resting_ball();
        panels.push((u, tips, (ball[1], ball[2])));
    }
    // One range for all panels, fitted to the paths and the ball with a margin.
    let (mut y0, mut y1, mut z0, mut z1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (_, tips, ball) in &panels {
        for &(y, z) in tips.iter().flatten().chain([ball]) {
            (y0, y1, z0, z1) = (y0.min(y), y1.max(y), z0.min(z), z1.max(z));
        }
    }
    let pad = 0.05 * (y1 - y0).max(z1 - z0);
    let (y_range, z_range) = ((y0 - pad, y1 + pad), (z0 - pad, z1 + pad));
    let legend_h = 30u32;
    let root = SVGBackend::new(path, (1000, 300 + legend_h)).into_drawing_area();
    root.fill(&WHITE)?;
    let (legend, grid) = root.split_vertically(legend_h);
    legend_strip(
        &legend,
        &[
            (
                Swatch::Line(BLACK.into(), 2),
                "bat tip, evaluation rollout (the mean)",
            ),
            (
                Swatch::Line(RED.mix(0.6), 1),
                "bat tip, exploration rollouts",
            ),
            (Swatch::Dot(BLUE), "ball on the tee"),
        ],
    )?;
    for (area, (u, tips, ball)) in grid.split_evenly((1, 4)).iter().zip(&panels) {
        let (w, h) = ticks::plot_size(area.dim_in_pixel(), 8, 40, 0, 35, 13);
        let ((y0, y1), (z0, z1)) = ticks::equal_scale(y_range, z_range, w, h);
        let yt = Ticks::linear(y0, y1, w, Along::Horizontal);
        let zt = Ticks::linear(z0, z1, h, Along::Vertical);
        let mut c = ChartBuilder::on(area)
            .caption(format!("bat tip onto y–z, update {u}"), ("sans-serif", 13))
            .margin(8)
            .x_label_area_size(35)
            .y_label_area_size(40)
            .build_cartesian_2d(yt.on(y0, y1), zt.on(z0, z1))?;
        c.configure_mesh().x_desc("y (m)").y_desc("z (m)").draw()?;
        // The exploration rollouts under the evaluation rollout (row 0).
        for (k, tip) in tips.iter().enumerate().rev() {
            let style = if k == 0 {
                BLACK.stroke_width(2)
            } else {
                RED.mix(0.6).stroke_width(1)
            };
            c.draw_series(LineSeries::new(tip.iter().copied(), style))?;
        }
        c.draw_series(std::iter::once(Circle::new(*ball, 4, BLUE.filled())))?;
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_caption_says_where_the_ball_lands_against_the_target() {
        let task = Tball::new(&tball::TballConfig::default()).unwrap();
        let at = |y: f64| landing_text(&task, [0.4, y, 0.035]);
        assert_eq!(at(-1.5), "lands at y = -1.50 m, in the target");
        assert_eq!(at(-1.5004), "lands at y = -1.50 m, 0.4 mm past the target");
        assert_eq!(
            at(-0.91),
            "lands at y = -0.91 m, 0.09 m short of the target"
        );
        assert_eq!(at(-1.65), "lands at y = -1.65 m, 0.15 m past the target");
    }

    /// The table's headers said cost@20, cost@21 and cost@40 for any config; a run of 6
    /// updates changing after 2 printed its update 6 under "cost@40".
    #[test]
    fn the_summary_names_the_updates_it_shows() {
        let row = |u: usize| UpdateRow {
            eval_cost: u as f64,
            eval_terminal: 1.0,
            landing_y: None,
            lambda: 1.0,
            exploration_mean: 0.0,
            exploration_std: 0.0,
            samples: Vec::new(),
            ball_height: 0.5,
        };
        let sessions = vec![(1..=6).map(row).collect::<Vec<_>>()];
        let mut out = String::new();
        summary_table(&mut out, &sessions, Some(2)).unwrap();
        let mut lines = out.lines();
        let header: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
        assert_eq!(
            header,
            [
                "session",
                "first_hit",
                "cost@1",
                "cost@2",
                "cost@3",
                "λpeak@",
                "cost@6",
                "target@6"
            ]
        );
        // Each column holds the cost of the update its header names (the cost of update u is
        // u here).
        let row0: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
        assert_eq!(row0[2..5], ["1.000", "2.000", "3.000"]);
        assert_eq!(row0[6], "6.000");
    }
}
