//! A rollout worker for a task of your own: the template for putting your simulator or your
//! robot behind the pipeline. `config/external-reach.toml` runs it:
//!
//! ```sh
//! cargo build --release -p supervisor --example reach-worker
//! cargo run --release -p supervisor -- run config/external-reach.toml
//! ```
//!
//! The task — a planar two-link arm whose hand should pass through a target halfway through a
//! 1 s reach — lives only here. The update side knows it only by what `[task.external]` declares
//! (P = 10, N = 101, the initial mean, the settings `target_x` and `target_y`); the supervisor
//! starts, restarts and scales this program like its own workers, and every run is recorded as
//! usual. Replace `rollout` with a call into your simulator, or with executing the movement on a
//! robot and measuring the cost: nothing else changes. A long rollout should look at
//! `pipeline::worker::stop_requested()` as this one's real-time wait does, so that a stop or a
//! scale-down does not wait for it to end.
//!
//! Copied into a crate of your own outside this workspace: copy the workspace's `Cargo.lock`
//! along, so that your worker is built with the iceoryx2 version the rest of the pipeline uses
//! (iceoryx2 connects only processes of the same version, patch included).

use dmp::{AffineDmp, Dmp, Gains, Trajectory};
use session::RunConfig;
use tasks::{Task, TaskError};

/// Joint angles (rad) at the start and the end of the reach; the DMP's goal.
const START: [f64; 2] = [0.3, 1.6];
const END: [f64; 2] = [1.4, 0.5];
/// Upper arm and forearm (m).
const LINKS: [f64; 2] = [0.5, 0.4];
const BASIS: usize = 5;
const DURATION: f64 = 1.0;
const DT: f64 = 0.01;
/// Weight of the hand's squared distance (m²) to the target at mid-reach, against the
/// acceleration cost.
const TARGET_WEIGHT: f64 = 1e4;
/// How often a rollout that takes `--rollout-ms` looks whether the worker is to stop.
const CONTROL_CYCLE: std::time::Duration = std::time::Duration::from_millis(10);
/// A rollout at least this long says when it begins, as a robot's log would: an operator (or a
/// test) can then tell a worker in a rollout from one waiting for work.
const SLOW_ROLLOUT: std::time::Duration = std::time::Duration::from_secs(1);

struct Reach {
    /// The DMP weights of a minimum-jerk reach from START to END: the initial mean, printed by
    /// `reach-worker --initial-mean` for the config.
    min_jerk: Vec<f64>,
    /// ψ per step and parameter, printed by `reach-worker --basis-activations` for the config.
    activations: Vec<f64>,
    dmp: AffineDmp,
    trajectory: Trajectory,
    target: [f64; 2],
    delay: std::time::Duration,
}

impl Reach {
    fn new(_config: &RunConfig) -> anyhow::Result<Self> {
        let dmp = Dmp::new(
            START.to_vec(),
            END.to_vec(),
            BASIS,
            DURATION,
            DT,
            Gains::default(),
        )?;
        let trajectory = Trajectory::zeros(dmp.steps(), 2, DT);
        Ok(Self {
            min_jerk: dmp.fit_min_jerk(DURATION),
            activations: dmp.parameter_activations(),
            dmp: dmp.affine(),
            trajectory,
            // The run's [task.external.settings] come with every work item, before its rollout.
            target: [f64::NAN; 2],
            delay: std::time::Duration::ZERO,
        })
    }

    fn hand(q: &[f64]) -> [f64; 2] {
        [
            LINKS[0] * q[0].cos() + LINKS[1] * (q[0] + q[1]).cos(),
            LINKS[0] * q[0].sin() + LINKS[1] * (q[0] + q[1]).sin(),
        ]
    }
}

impl Task for Reach {
    fn name(&self) -> &'static str {
        "reach"
    }
    fn parameters(&self) -> usize {
        self.dmp.parameters()
    }
    fn steps(&self) -> usize {
        self.dmp.steps()
    }
    fn initial_mean(&self) -> Vec<f64> {
        self.min_jerk.clone()
    }
    fn basis_activations(&self) -> Option<Vec<f64>> {
        Some(self.activations.clone())
    }

    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
        let start = std::time::Instant::now();
        self.dmp.rollout_into(theta, &mut self.trajectory);
        let n = per_step.len();
        for (i, c) in per_step.iter_mut().enumerate() {
            let acc = &self.trajectory.acc[2 * i..2 * i + 2];
            *c = 1e-3 * (acc[0] * acc[0] + acc[1] * acc[1]) / n as f64;
        }
        let mid = (n - 1) / 2;
        let hand = Self::hand(&self.trajectory.pos[2 * mid..2 * mid + 2]);
        let miss = (hand[0] - self.target[0]).powi(2) + (hand[1] - self.target[1]).powi(2);
        per_step[mid] += TARGET_WEIGHT * miss;
        // The real-time part of a rollout (a robot's movement, a simulator's steps) is where a
        // stop or a scale-down would otherwise wait for the rollout to end: look for one every
        // control cycle and leave at once. The worker abandons a rollout left this way.
        if self.delay >= SLOW_ROLLOUT {
            eprintln!("a rollout of {} ms begins", self.delay.as_millis());
        }
        while let Some(rest) = self
            .delay
            .checked_sub(start.elapsed())
            .filter(|r| !r.is_zero())
        {
            if pipeline::worker::stop_requested() {
                break;
            }
            std::thread::sleep(rest.min(CONTROL_CYCLE));
        }
        0.0
    }

    /// Alphabetical, as `[task.external.settings]` sends them.
    fn settings(&self) -> Vec<(&'static str, f64)> {
        vec![("target_x", self.target[0]), ("target_y", self.target[1])]
    }

    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        let i = match name {
            "target_x" => 0,
            "target_y" => 1,
            _ => {
                return Err(TaskError::UnknownSetting {
                    task: "reach",
                    name: name.into(),
                    known: "target_x, target_y".into(),
                })
            }
        };
        // The run's check (finite values) knows nothing of this arm: a target it cannot reach
        // is refused here. The pipeline then runs the update with the target it had, and the
        // run goes on.
        let mut target = self.target;
        target[i] = value;
        let (reach, distance) = (LINKS[0] + LINKS[1], target[0].hypot(target[1]));
        if distance > reach {
            return Err(TaskError::Invalid {
                task: "reach",
                reason: format!(
                    "target ({}, {}) is {distance:.2} m from the shoulder, out of the arm's \
                     reach ({reach} m)",
                    target[0], target[1]
                ),
            });
        }
        self.target = target;
        Ok(())
    }
}

/// The arguments the supervisor passes (`WorkerArgs`) and this program's own, from
/// `task.external.worker` in the config.
#[derive(clap::Parser)]
#[command(name = "reach-worker")]
struct Cli {
    /// Each rollout takes at least this long: a stand-in for a simulator or robot that runs in
    /// real time.
    #[arg(long, default_value_t = 0.0, value_parser = rollout_ms)]
    rollout_ms: f64,
    /// Print the `initial_mean` line for `[task.external]` (the DMP weights of the reach) and
    /// exit.
    #[arg(long, exclusive = true)]
    initial_mean: bool,
    /// Print the `basis_activations` rows for `[task.external]` (what
    /// `temporal_averaging = "basis-activation"` needs) and exit.
    #[arg(long, exclusive = true)]
    basis_activations: bool,
    /// Run the whole of CONFIG in this process, without the pipeline
    /// (`session::InProcess::with_task`), and print the final distribution's bits: those of
    /// `supervisor run CONFIG`'s result file.
    #[arg(long, exclusive = true, value_name = "CONFIG")]
    in_process: Option<std::path::PathBuf>,
    #[command(flatten)]
    worker: pipeline::worker::WorkerArgs,
}

fn rollout_ms(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(ms) if (0.0..=3.6e6).contains(&ms) => Ok(ms),
        _ => Err(format!("{s}: milliseconds from 0 to 3600000 (an hour)")),
    }
}

fn main() -> std::process::ExitCode {
    use clap::Parser as _;
    // For `[task.external]` (Reach::new does not read the config): the initial mean, and the
    // basis activations that `temporal_averaging = "basis-activation"` needs.
    let print = |line: fn(&Reach) -> String| {
        let reach = Reach::new(&RunConfig::default_config()).expect("the constants are valid");
        println!("{}", line(&reach));
        std::process::ExitCode::SUCCESS
    };
    // These two run without the worker arguments, which clap would require first; they are
    // declared in `Cli` for `--help` and to refuse them among other arguments.
    let alone = |flag: &str| std::env::args().skip(1).eq([flag.to_string()]);
    if alone("--initial-mean") {
        return print(|r| format!("initial_mean = {:?}", r.initial_mean()));
    }
    if alone("--basis-activations") {
        return print(|r| {
            let rows: Vec<String> = r
                .activations
                .chunks(r.parameters())
                .map(|row| format!("{row:?}"))
                .collect();
            format!("basis_activations = [\n  {},\n]", rows.join(",\n  "))
        });
    }
    if let [flag, config] = &std::env::args().skip(1).collect::<Vec<_>>()[..] {
        if flag == "--in-process" {
            return pipeline::run_main("reach-worker", || in_process(config.as_ref()));
        }
    }
    // Without arguments of its own, `pipeline::worker::serve_main("reach-worker", Reach::new)`
    // would be the whole of main.
    let cli = Cli::parse();
    let delay = std::time::Duration::from_secs_f64(cli.rollout_ms / 1e3);
    pipeline::run_main("reach-worker", || {
        let make_task = |config: &RunConfig| Reach::new(config).map(|r| Reach { delay, ..r });
        Ok(pipeline::worker::serve(&cli.worker, make_task)?)
    })
}

/// The task of your own without the pipeline: the config's update side in this thread, with the
/// config's initial mean and settings, the schedule at its updates, and the same noise, so the
/// same bits as the pipeline's run of the config.
fn in_process(path: &std::path::Path) -> anyhow::Result<()> {
    let config = RunConfig::load(path)?;
    let task = Reach::new(&config)?;
    let mut run = session::InProcess::with_task(&config, config.run.seed, Box::new(task))?;
    run.run(&mut session::NoObserver, &|| false)?;
    let d = run.optimizer().distribution();
    let bits = |v: &[f64]| pipeline::result::bits(v);
    println!("mean_bits = {:?}", bits(d.mean.as_slice()));
    println!("covariance_bits = {:?}", bits(d.covariance.as_slice()));
    Ok(())
}
