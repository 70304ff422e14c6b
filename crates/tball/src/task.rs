//! The T-ball task: DMP → joint trajectory → bat motion → impact → flight → cost.

use dmp::{AffineDmp, Dmp, Gains};
use tasks::{Task, TaskError};

use crate::arm::{Arm, Vec3};
use crate::config::TballConfig;
use crate::contact::{
    ball_at, closest_on_segment, flight, touch_within, BatStep, ContactModel, Impact,
};

const NAME: &str = "tball";

/// The bat hit the ball.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Time of the impact since the start of the swing (s).
    pub time: f64,
    /// The ball's centre at the impact (still on the tee).
    pub ball: Vec3,
    /// Where on the bat the contact was and the velocities it exchanged.
    pub impact: Impact,
    /// Time from the impact until the ball touches the ground (s).
    pub flight_time: f64,
    /// The ball's centre when it touches the ground.
    pub landing: Vec3,
}

/// What one swing did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// The first impact of the bat on the ball and the flight it started; None for a miss.
    pub hit: Option<Hit>,
    /// Smallest distance between the bat's and the ball's surfaces before any impact (m; 0 if hit).
    pub closest_gap: f64,
    /// φ of Eq. 5, or the miss cost.
    pub terminal_cost: f64,
}

impl Outcome {
    /// Whether the ball landed in the target area (φ = 0 exactly).
    pub fn in_target(&self) -> bool {
        self.hit.is_some() && self.terminal_cost == 0.0
    }
}

/// A swing with everything needed to draw it.
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// What the swing did, as [`Tball::simulate`] returns it.
    pub outcome: Outcome,
    /// Time of every step (s).
    pub time: Vec<f64>,
    /// Bat end-point at every step.
    pub bat_tip: Vec<Vec3>,
    /// Start of the bat's axis (the hand end) at every step; with `bat_tip` the bat's segment.
    pub grip: Vec<Vec3>,
    /// Joint angles at every step.
    pub joints: Vec<[f64; 7]>,
}

impl Trace {
    /// The ball's centre from the start of the swing until it lands (or the end of the swing if
    /// it is never hit), sampled every `dt` seconds.
    pub fn ball_path(&self, dt: f64, gravity: f64, resting: Vec3) -> Vec<Vec3> {
        match &self.outcome.hit {
            None => vec![resting, resting],
            Some(hit) => {
                let mut path = vec![hit.ball];
                let n = (hit.flight_time / dt).ceil() as usize;
                for k in 1..n {
                    path.push(ball_at(
                        hit.ball,
                        hit.impact.ball_velocity,
                        gravity,
                        k as f64 * dt,
                    ));
                }
                path.push(hit.landing);
                path
            }
        }
    }
}

/// The paper's T-ball task (Section IV-B) with the simulation described in the crate docs.
#[derive(Debug, Clone)]
pub struct Tball {
    config: TballConfig,
    dmp: Dmp,
    affine: AffineDmp,
    initial_mean: Vec<f64>,
    arm: Arm,
    contact: ContactModel,
    /// Reused by `rollout`, so a rollout allocates nothing.
    buffers: Buffers,
}

/// Joint positions (by joint, N values each) and one joint's accelerations (N values).
#[derive(Debug, Clone, Default)]
struct Buffers {
    joints: Vec<f64>,
    accelerations: Vec<f64>,
}

fn invalid(name: &str, value: f64, reason: &'static str) -> TaskError {
    TaskError::InvalidSetting {
        task: NAME,
        name: name.into(),
        value,
        reason,
    }
}

impl Tball {
    /// The task for `config`: checks every length, mass and coefficient (an invalid one is a
    /// [`TaskError`] naming the key) and fits the DMP to the minimum-jerk swing from
    /// `start_pose` to `end_pose`, whose parameters are the initial mean.
    pub fn new(config: &TballConfig) -> Result<Self, TaskError> {
        let c = config;
        let positive = [
            ("upper_arm", c.upper_arm),
            ("forearm", c.forearm),
            ("hand", c.hand),
            ("bat_length", c.bat_length),
            ("bat_radius", c.bat_radius),
            ("bat_effective_mass", c.bat_effective_mass),
            ("ball_radius", c.ball_radius),
            ("ball_mass", c.ball_mass),
            ("gravity", c.gravity),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(name, v, "must be finite and > 0"));
            }
        }
        let non_negative = [
            ("friction", c.friction),
            ("acceleration_weight", c.acceleration_weight),
            ("miss_cost", c.miss_cost),
            ("miss_gap_weight", c.miss_gap_weight),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(invalid(name, v, "must be finite and >= 0"));
            }
        }
        for (name, v) in [
            ("restitution", c.restitution),
            ("tee_restitution", c.tee_restitution),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(name, v, "must be in [0, 1]"));
            }
        }
        for (name, v) in [
            ("target_y_min", c.target_y_min),
            ("target_y_max", c.target_y_max),
        ] {
            if !v.is_finite() {
                return Err(invalid(name, v, "must be finite"));
            }
        }
        if c.target_y_min >= c.target_y_max {
            return Err(invalid(
                "target_y_min",
                c.target_y_min,
                "must be below target_y_max (the target strip runs from target_y_min to \
                 target_y_max)",
            ));
        }
        let finite = c
            .start_pose
            .iter()
            .chain(&c.end_pose)
            .chain(&c.shoulder)
            .all(|v| v.is_finite());
        if !finite {
            return Err(TaskError::Invalid {
                task: NAME,
                reason: "start_pose, end_pose and shoulder must be finite".into(),
            });
        }
        let dmp = Dmp::new(
            c.start_pose.to_vec(),
            c.end_pose.to_vec(),
            c.basis_functions,
            c.duration,
            c.dt,
            Gains::default(),
        )
        .map_err(|e| TaskError::Invalid {
            task: NAME,
            reason: e.to_string(),
        })?;
        let initial_mean = dmp.fit_min_jerk(c.duration);
        let mut task = Self {
            affine: dmp.affine(),
            dmp,
            initial_mean,
            arm: Arm {
                shoulder: c.shoulder,
                upper_arm: c.upper_arm,
                forearm: c.forearm,
                hand: c.hand,
                bat_length: c.bat_length,
            },
            contact: ContactModel {
                restitution: c.restitution,
                friction: c.friction,
                tee_restitution: c.tee_restitution,
                ball_mass: c.ball_mass,
                bat_effective_mass: c.bat_effective_mass,
            },
            config: c.clone(),
            buffers: Buffers::default(),
        };
        // Through `set`, so the settings are checked exactly as a schedule's changes are.
        task.set("tee_x", c.tee_x)?;
        task.set("tee_y", c.tee_y)?;
        task.set("ball_height", c.ball_height)?;
        Ok(task)
    }

    /// The configuration, with the settings (`ball_height`, `tee_x`, `tee_y`) as last set.
    pub fn config(&self) -> &TballConfig {
        &self.config
    }

    /// The highest ball centre the bat can touch: the arm and bat stretched straight up from the
    /// shoulder, plus the bat's and the ball's radii. Whatever the tee's x and y, a higher ball
    /// is never hit.
    fn highest_reachable_ball(&self) -> f64 {
        self.config.shoulder[2] + self.farthest_reachable_tee()
    }

    /// The farthest the tee can be from the shoulder, horizontally, for the bat to touch the
    /// ball: no point of the arm and bat is farther from the shoulder than their lengths, plus
    /// the bat's and the ball's radii for the touch. Whatever the ball's height, a farther tee is
    /// never hit.
    fn farthest_reachable_tee(&self) -> f64 {
        let c = &self.config;
        c.upper_arm + c.forearm + c.hand + c.bat_length + c.bat_radius + c.ball_radius
    }

    /// The tee's horizontal distance from the shoulder were `name` (`tee_x` or `tee_y`) set to
    /// `value`, the other coordinate as it is.
    fn tee_distance(&self, name: &str, value: f64) -> f64 {
        let c = &self.config;
        let (x, y) = if name == "tee_x" {
            (value, c.tee_y)
        } else {
            (c.tee_x, value)
        };
        (x - c.shoulder[0]).hypot(y - c.shoulder[1])
    }

    /// The ball's centre while it rests on the tee.
    pub fn resting_ball(&self) -> Vec3 {
        [
            self.config.tee_x,
            self.config.tee_y,
            self.config.ball_height,
        ]
    }

    /// Distance from a landing point to the target area (0 inside).
    pub fn distance_to_target(&self, landing: Vec3) -> f64 {
        let y = landing[1];
        if y > self.config.target_y_max {
            y - self.config.target_y_max
        } else if y < self.config.target_y_min {
            self.config.target_y_min - y
        } else {
            0.0
        }
    }

    /// Runs the swing θ (P values): immediate costs into `per_step` (at least N values), and,
    /// when `trace` is given, the bat's path over the whole swing. Panics if θ or `per_step` is
    /// shorter, as every [`Task::rollout`] may: executors check the lengths first.
    pub fn simulate(
        &self,
        theta: &[f64],
        per_step: &mut [f64],
        trace: Option<&mut Trace>,
    ) -> Outcome {
        self.simulate_with(theta, per_step, trace, &mut Buffers::default())
    }

    fn simulate_with(
        &self,
        theta: &[f64],
        per_step: &mut [f64],
        mut trace: Option<&mut Trace>,
        buffers: &mut Buffers,
    ) -> Outcome {
        let n = self.affine.steps();
        let dims = self.affine.dims();
        let weight = self.config.acceleration_weight / n as f64;
        // Whole trajectories per joint: the DMP is affine in θ, so these are a few axpy passes.
        buffers.accelerations.resize(n, 0.0);
        buffers.joints.resize(dims * n, 0.0);
        let per_step = &mut per_step[..n];
        per_step.fill(0.0);
        for d in 0..dims {
            self.affine
                .accelerations_into(d, theta, &mut buffers.accelerations);
            for (q, a) in per_step.iter_mut().zip(&buffers.accelerations) {
                *q += a * a;
            }
            self.affine
                .positions_into(d, theta, &mut buffers.joints[d * n..(d + 1) * n]);
        }
        for q in per_step.iter_mut() {
            *q *= weight;
        }
        let joints = &buffers.joints;
        let joints_at = |i: usize| -> [f64; 7] { std::array::from_fn(|d| joints[d * n + i]) };

        let ball = self.resting_ball();
        let reach = self.config.bat_radius + self.config.ball_radius;
        let dt = self.affine.dt();
        let mut hit = None;
        let mut closest = f64::INFINITY;
        let mut prev = self.arm.pose(&joints_at(0));
        // Only a bat surface arriving at the ball counts as a hit: one that starts inside the
        // ball, or touches it while moving away, must first separate from it again.
        let mut apart = closest_on_segment(prev.grip, prev.tip, ball).1 > reach;
        if let Some(t) = trace.as_deref_mut() {
            t.time.clear();
            t.bat_tip.clear();
            t.grip.clear();
            t.joints.clear();
        }
        for i in 0..n {
            let q = joints_at(i);
            let pose = if i == 0 { prev } else { self.arm.pose(&q) };
            if let Some(t) = trace.as_deref_mut() {
                t.time.push(i as f64 * dt);
                t.bat_tip.push(pose.tip);
                t.grip.push(pose.grip);
                t.joints.push(q);
            }
            if hit.is_none() {
                let d = closest_on_segment(pose.grip, pose.tip, ball).1;
                closest = closest.min(d);
                if d <= reach && apart && i > 0 {
                    let step = BatStep {
                        grip0: prev.grip,
                        tip0: prev.tip,
                        grip1: pose.grip,
                        tip1: pose.tip,
                        dt,
                    };
                    let (s, along) = touch_within(&step, ball, reach);
                    if let Some(impact) = self.contact.impact(&step, ball, s, along) {
                        let (flight_time, landing) = flight(
                            ball,
                            impact.ball_velocity,
                            self.config.gravity,
                            self.config.ball_radius,
                        );
                        hit = Some(Hit {
                            time: (i as f64 - 1.0 + s) * dt,
                            ball,
                            impact,
                            flight_time,
                            landing,
                        });
                        if trace.is_none() {
                            break;
                        }
                    }
                }
                apart = d > reach;
            }
            prev = pose;
        }
        let (closest_gap, terminal_cost) = match &hit {
            Some(h) => (0.0, self.distance_to_target(h.landing)),
            None => {
                let gap = (closest - reach).max(0.0);
                (
                    gap,
                    self.config.miss_cost + self.config.miss_gap_weight * gap,
                )
            }
        };
        let outcome = Outcome {
            hit,
            closest_gap,
            terminal_cost,
        };
        if let Some(t) = trace {
            t.outcome = outcome;
        }
        outcome
    }

    /// The swing θ with its bat path, for figures.
    pub fn trace(&self, theta: &[f64]) -> Trace {
        let mut trace = Trace {
            outcome: Outcome {
                hit: None,
                closest_gap: 0.0,
                terminal_cost: 0.0,
            },
            time: Vec::new(),
            bat_tip: Vec::new(),
            grip: Vec::new(),
            joints: Vec::new(),
        };
        let mut per_step = vec![0.0; self.affine.steps()];
        self.simulate(theta, &mut per_step, Some(&mut trace));
        trace
    }
}

impl Task for Tball {
    fn name(&self) -> &'static str {
        NAME
    }

    fn parameters(&self) -> usize {
        self.dmp.parameters()
    }

    fn steps(&self) -> usize {
        self.dmp.steps()
    }

    fn initial_mean(&self) -> Vec<f64> {
        self.initial_mean.clone()
    }

    fn basis_activations(&self) -> Option<Vec<f64>> {
        Some(self.dmp.parameter_activations())
    }

    fn rollout(&mut self, theta: &[f64], per_step: &mut [f64]) -> f64 {
        let mut buffers = std::mem::take(&mut self.buffers);
        let outcome = self.simulate_with(theta, per_step, None, &mut buffers);
        self.buffers = buffers;
        outcome.terminal_cost
    }

    fn settings(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("ball_height", self.config.ball_height),
            ("tee_x", self.config.tee_x),
            ("tee_y", self.config.tee_y),
        ]
    }

    fn set(&mut self, name: &str, value: f64) -> Result<(), TaskError> {
        let known = ["ball_height", "tee_x", "tee_y"];
        if known.contains(&name) && !value.is_finite() {
            return Err(invalid(name, value, "must be finite"));
        }
        match name {
            "ball_height" if value < self.config.ball_radius => Err(invalid(
                name,
                value,
                "the ball's centre must be at least its radius above the ground",
            )),
            // A ball no pose of the arm can touch makes every rollout a miss, and the run learns
            // nothing from then on: a height given in cm (47 for 0.47) is the likely cause.
            "ball_height" if value > self.highest_reachable_ball() => Err(invalid(
                name,
                value,
                "out of the bat's reach: the ball's centre can be at most shoulder[2] + \
                 upper_arm + forearm + hand + bat_length + bat_radius + ball_radius above the \
                 ground (2.435 m with config/tball.toml's arm); heights are in metres",
            )),
            "ball_height" => {
                self.config.ball_height = value;
                Ok(())
            }
            // As for the ball's height: a tee no pose can reach makes every rollout a miss
            // (`set tee_x 3` was accepted, and the run learnt nothing from then on). The other
            // coordinate is the one in force, so a change is judged with the tee where it is.
            "tee_x" | "tee_y" if self.tee_distance(name, value) > self.farthest_reachable_tee() => {
                Err(invalid(
                    name,
                    value,
                    "out of the bat's reach: the tee can be at most upper_arm + forearm + hand + \
                     bat_length + bat_radius + ball_radius (1.185 m with config/tball.toml's \
                     arm) from the shoulder, horizontally: hypot(tee_x - shoulder[0], tee_y - \
                     shoulder[1]), with the tee's other coordinate as set; positions are in \
                     metres",
                ))
            }
            "tee_x" => {
                self.config.tee_x = value;
                Ok(())
            }
            "tee_y" => {
                self.config.tee_y = value;
                Ok(())
            }
            _ => Err(TaskError::UnknownSetting {
                task: NAME,
                name: name.into(),
                known: known.join(", "),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arm::{norm, sub};

    fn task() -> Tball {
        Tball::new(&TballConfig::default()).unwrap()
    }

    #[test]
    fn immediate_cost_is_equation_4() {
        let mut t = task();
        let theta = t.initial_mean();
        let mut q = vec![0.0; t.steps()];
        t.rollout(&theta, &mut q);
        let traj = t.dmp.integrate(&theta);
        let n = t.steps() as f64;
        for i in [0, 1, 500, 1000] {
            let expected: f64 = (0..7).map(|d| traj.acc[i * 7 + d].powi(2)).sum::<f64>() * 0.01 / n;
            assert!(
                (q[i] - expected).abs() <= 1e-9 * expected.max(1e-9),
                "{i}: {} vs {expected}",
                q[i]
            );
        }
    }

    #[test]
    fn terminal_cost_is_distance_to_the_target_strip() {
        let t = task();
        assert_eq!(t.distance_to_target([0.3, -1.2, 0.0]), 0.0);
        assert!((t.distance_to_target([0.0, -0.7, 0.0]) - 0.3).abs() < 1e-12);
        assert!((t.distance_to_target([2.0, -1.9, 0.0]) - 0.4).abs() < 1e-12);
        let theta = t.initial_mean();
        let o = t.trace(&theta).outcome;
        let hit = o.hit.expect("the initial swing hits the default ball");
        assert_eq!(o.terminal_cost, t.distance_to_target(hit.landing));
        // The ball lands on the ground, having left from the tee.
        assert!((hit.landing[2] - t.config().ball_radius).abs() < 1e-9);
        assert!(hit.time > 0.0 && hit.time < t.config().duration);
    }

    #[test]
    fn a_miss_costs_the_documented_penalty() {
        let mut t = task();
        // Behind the robot, within reach: the forward swing misses it.
        t.set("tee_x", -0.9).unwrap();
        let theta = t.initial_mean();
        let trace = t.trace(&theta);
        assert!(trace.outcome.hit.is_none());
        let reach = t.config().bat_radius + t.config().ball_radius;
        let ball = t.resting_ball();
        let gap = trace
            .grip
            .iter()
            .zip(&trace.bat_tip)
            .map(|(&g, &p)| closest_on_segment(g, p, ball).1 - reach)
            .fold(f64::INFINITY, f64::min);
        assert!(gap > 1.0);
        let expected = 2.0 + 100.0 * gap;
        assert!((trace.outcome.terminal_cost - expected).abs() < 1e-9);
        assert!(trace.outcome.terminal_cost.is_finite());
    }

    #[test]
    fn rollouts_are_deterministic_and_trace_agrees() {
        let mut t = task();
        let mut theta = t.initial_mean();
        theta[4] += 3.0;
        let mut a = vec![0.0; t.steps()];
        let mut b = vec![0.0; t.steps()];
        let pa = t.rollout(&theta, &mut a);
        let pb = t.rollout(&theta, &mut b);
        assert_eq!((pa, &a), (pb, &b));
        assert_eq!(t.trace(&theta).outcome.terminal_cost, pa);
    }

    #[test]
    fn bat_tip_follows_the_joint_trajectory() {
        let t = task();
        let trace = t.trace(&t.initial_mean());
        assert_eq!(trace.bat_tip.len(), t.steps());
        let p = t.arm.pose(&trace.joints[300]);
        assert_eq!(p.tip, trace.bat_tip[300]);
        let reach = t.arm.upper_arm + t.arm.forearm + t.arm.hand + t.arm.bat_length;
        assert!(norm(sub(trace.bat_tip[0], t.arm.shoulder)) <= reach + 1e-9);
    }

    #[test]
    fn settings_are_checked() {
        let mut t = task();
        assert!(matches!(
            t.set("ball_hieght", 0.5),
            Err(TaskError::UnknownSetting { .. })
        ));
        assert!(t.set("ball_height", 0.01).is_err());
        assert!(t.set("ball_height", f64::NAN).is_err());
        t.set("ball_height", 0.6).unwrap();
        assert_eq!(t.resting_ball()[2], 0.6);
        let bouncy = TballConfig {
            restitution: 1.5,
            ..TballConfig::default()
        };
        assert!(Tball::new(&bouncy).is_err());
        let empty_target = TballConfig {
            target_y_min: -0.5,
            ..TballConfig::default()
        };
        assert!(Tball::new(&empty_target).is_err());
    }

    /// A ball no pose can reach was accepted (`supervisor set ball_height 47`, a height in cm):
    /// every rollout then missed, and the run learnt nothing more.
    #[test]
    fn a_ball_out_of_the_bats_reach_is_refused() {
        let mut t = task();
        for far in [47.0, 2.44, 1e300] {
            match t.set("ball_height", far) {
                Err(TaskError::InvalidSetting { name, reason, .. }) => {
                    assert_eq!(name, "ball_height");
                    assert!(reason.contains("out of the bat's reach"), "{reason}");
                }
                other => panic!("{far}: {other:?}"),
            }
            assert_eq!(t.resting_ball()[2], 0.52, "a refused value leaves the task");
        }
        let config = TballConfig {
            ball_height: 52.0,
            ..TballConfig::default()
        };
        assert!(Tball::new(&config).is_err());
        // The bound is the arm and bat pointing straight up (shoulder pitch π), touching the
        // ball from below; the number the message quotes for config/tball.toml's arm.
        let up = t
            .arm
            .pose(&[0.0, std::f64::consts::PI, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let c = t.config();
        let touching = up.tip[2] + c.bat_radius + c.ball_radius;
        assert!((touching - t.highest_reachable_ball()).abs() < 1e-12);
        assert!((t.highest_reachable_ball() - 2.435).abs() < 1e-12);
        t.set("ball_height", touching).unwrap();
    }

    /// A tee no pose can reach was accepted (`supervisor set tee_x 3`, or `tee_y = 76` in
    /// [task.tball], a position in cm): every rollout then missed, and the run learnt nothing
    /// more.
    #[test]
    fn a_tee_out_of_the_bats_reach_is_refused() {
        let mut t = task();
        let refused = |t: &mut Tball, name: &str, far: f64| match t.set(name, far) {
            Err(TaskError::InvalidSetting {
                name: n,
                value,
                reason,
                ..
            }) => {
                assert_eq!((n.as_str(), value), (name, far));
                assert!(reason.contains("out of the bat's reach"), "{reason}");
            }
            other => panic!("{name} = {far}: {other:?}"),
        };
        for (name, far) in [
            ("tee_x", 3.0),
            ("tee_x", -1.2),
            ("tee_y", 76.0),
            ("tee_y", 1e300),
        ] {
            refused(&mut t, name, far);
            assert_eq!(
                t.resting_ball(),
                [0.76, -0.53, 0.52],
                "a refused value leaves the task"
            );
        }
        for config in [
            TballConfig {
                tee_x: 3.0,
                ..TballConfig::default()
            },
            TballConfig {
                tee_y: 76.0,
                ..TballConfig::default()
            },
        ] {
            assert!(matches!(
                Tball::new(&config),
                Err(TaskError::InvalidSetting { .. })
            ));
        }
        // Each coordinate is judged with the other as it is: either move alone is in reach
        // (1.053 m, 1.103 m from the shoulder), both together are not (1.281 m).
        t.set("tee_x", 1.0).unwrap();
        t.set("tee_x", 0.76).unwrap();
        t.set("tee_y", 0.6).unwrap();
        refused(&mut t, "tee_x", 1.0);
        // The bound is the arm and bat stretched out forward (shoulder pitch π/2), touching the
        // ball level with the shoulder; the number the message quotes for config/tball.toml's
        // arm.
        let out = t
            .arm
            .pose(&[0.0, std::f64::consts::FRAC_PI_2, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let c = t.config().clone();
        assert!((out.tip[2] - c.shoulder[2]).abs() < 1e-12, "{:?}", out.tip);
        let level = (out.tip[0] - c.shoulder[0]).hypot(out.tip[1] - c.shoulder[1]);
        let reach = level + c.bat_radius + c.ball_radius;
        assert!((reach - t.farthest_reachable_tee()).abs() < 1e-12);
        assert!((reach - 1.185).abs() < 1e-12);
        // Straight ahead of the shoulder, at that distance: in reach, and no farther.
        let touching = c.shoulder[0] + reach;
        t.set("tee_y", c.shoulder[1]).unwrap();
        t.set("tee_x", touching).unwrap();
        refused(&mut t, "tee_x", touching + 1e-9);
    }

    /// `target_y_max = nan` was reported as `target_y_min = -1.5`, the valid one.
    #[test]
    fn a_bad_target_bound_is_named() {
        let nan_max = TballConfig {
            target_y_max: f64::NAN,
            ..TballConfig::default()
        };
        match Tball::new(&nan_max) {
            Err(TaskError::InvalidSetting { name, value, .. }) => {
                assert_eq!(name, "target_y_max");
                assert!(value.is_nan());
            }
            other => panic!("{other:?}"),
        }
        let crossed = TballConfig {
            target_y_min: -0.5,
            ..TballConfig::default()
        };
        match Tball::new(&crossed) {
            Err(TaskError::InvalidSetting {
                name,
                value,
                reason,
                ..
            }) => {
                assert_eq!((name.as_str(), value), ("target_y_min", -0.5));
                assert!(reason.contains("below target_y_max"), "{reason}");
            }
            other => panic!("{other:?}"),
        }
    }
}
