//! The `[task.tball]` section of a run config: every length, mass and contact parameter of the
//! simulation is a key, none is hidden in code.

use serde::Deserialize;

/// Geometry, contact parameters, policy and cost of the T-ball task. Lengths in metres, angles
/// in radians, masses in kg; frame: x forward, y to the robot's left, z up, ground at z = 0.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TballConfig {
    /// Movement duration (s); the paper's swing lasts 1 s. N = duration/dt + 1 time steps.
    pub duration: f64,
    /// DMP integration and simulation time step (s). Bat–ball contact is detected at the steps
    /// and located to sub-step precision within the first step that ends in contact; the bat
    /// must move much less than bat_radius + ball_radius per step for no contact to be skipped
    /// (the initial swing: 3 mm against 6.5 cm at 1 ms).
    pub dt: f64,
    /// Basis functions per joint (the paper: 3), so the policy has 7·basis_functions parameters.
    pub basis_functions: usize,
    /// Joint angles (rad) at the start of the minimum-jerk swing the DMP is fitted to. Order and
    /// axes: shoulder yaw (z), shoulder pitch (y), shoulder roll (x), elbow (y), forearm rotation
    /// (z), wrist pitch (y), wrist roll (x); all zero is the arm hanging straight down.
    pub start_pose: [f64; 7],
    /// Joint angles (rad) at the end of that swing, in the order of `start_pose`. The paper shows
    /// its start and end poses only in a figure; these are chosen for this arm.
    pub end_pose: [f64; 7],
    /// Fixed position of the right shoulder (m; the torso does not move).
    pub shoulder: [f64; 3],
    /// Shoulder to elbow (m).
    pub upper_arm: f64,
    /// Elbow to wrist (m).
    pub forearm: f64,
    /// Wrist to grip (m).
    pub hand: f64,
    /// Length of the bat's axis from the grip to its end-point (m); the bat continues the hand's
    /// axis.
    pub bat_length: f64,
    /// Radius of the capsule around the bat's axis (m).
    pub bat_radius: f64,
    /// Mass the bat presents at the contact (kg; the arm is kinematic, this only scales the
    /// impulse by M/(M + m)).
    pub bat_effective_mass: f64,
    /// Radius of the ball (m).
    pub ball_radius: f64,
    /// Mass of the ball (kg).
    pub ball_mass: f64,
    /// Bat–ball coefficient of restitution, in [0, 1]: the fraction of the normal approach speed
    /// returned.
    pub restitution: f64,
    /// Bat–ball Coulomb friction coefficient μ: the tangential impulse is at most μ times the
    /// normal one.
    pub friction: f64,
    /// Restitution of the tee's support when a hit above the ball's centre drives it downward
    /// (0: a soft tee absorbs the downward velocity; 1: a rigid tee reflects it).
    pub tee_restitution: f64,
    /// x of the ball's centre while it rests on the tee (m); a setting a schedule may change.
    /// `tee_x` and `tee_y` are refused where the tee is farther from the shoulder, horizontally,
    /// than `upper_arm + forearm + hand + bat_length + bat_radius + ball_radius` (1.185 m
    /// here): every swing would miss. Each is judged with the other as set.
    pub tee_x: f64,
    /// y of the ball's centre while it rests on the tee (m); a setting a schedule may change.
    pub tee_y: f64,
    /// Height of the ball's centre above the ground while it rests on the tee (m). A setting a
    /// schedule may change: the paper lowers the ball by 5 cm after 20 updates. Refused below
    /// `ball_radius` (under the ground) and above the highest point the bat can touch,
    /// `shoulder[2] + upper_arm + forearm + hand + bat_length + bat_radius + ball_radius`
    /// (2.435 m here), where every swing would miss.
    pub ball_height: f64,
    /// Gravitational acceleration of the ball's flight (m/s², acting along −z).
    pub gravity: f64,
    /// Lower y bound of the target area, a strip of ground over all x (m; the paper gives only
    /// its y extent, −1 to −1.5 m).
    pub target_y_min: f64,
    /// Upper y bound of the target area (m); must exceed `target_y_min`.
    pub target_y_max: f64,
    /// Weight of the acceleration term of Eq. 4 (the paper: 0.01).
    pub acceleration_weight: f64,
    /// Terminal cost of a swing that misses the ball:
    /// miss_cost + miss_gap_weight · (closest gap between bat and ball surfaces, m). Eq. 5 does
    /// not cover a miss; this penalty is this implementation's.
    pub miss_cost: f64,
    /// Cost per metre of the closest bat–ball gap of a miss (see `miss_cost`), so a near miss
    /// costs less than a wild one.
    pub miss_gap_weight: f64,
    /// Each rollout blocks at least this long (a stand-in for a robot or external simulator).
    #[serde(default)]
    pub rollout_delay_ms: f64,
}

impl Default for TballConfig {
    /// The configuration of `config/tball.toml` (the paper's run).
    fn default() -> Self {
        Self {
            duration: 1.0,
            dt: 0.001,
            basis_functions: 3,
            start_pose: [0.8, -0.85, 0.1, 0.3, 0.0, 0.1, 0.0],
            end_pose: [-0.8, -1.0, -0.1, 0.1, 0.2, -0.1, 0.0],
            shoulder: [0.0, -0.20, 1.25],
            upper_arm: 0.28,
            forearm: 0.26,
            hand: 0.08,
            bat_length: 0.5,
            bat_radius: 0.03,
            bat_effective_mass: 1.0,
            ball_radius: 0.035,
            ball_mass: 0.05,
            restitution: 0.6,
            friction: 0.3,
            tee_restitution: 0.0,
            tee_x: 0.76,
            tee_y: -0.53,
            ball_height: 0.52,
            gravity: 9.81,
            target_y_min: -1.5,
            target_y_max: -1.0,
            acceleration_weight: 0.01,
            miss_cost: 2.0,
            miss_gap_weight: 100.0,
            rollout_delay_ms: 0.0,
        }
    }
}
