//! The `[task.tball]` section of a run config: every length, mass and contact parameter of the
//! simulation is a key, none is hidden in code.

use serde::Deserialize;

/// Geometry, contact parameters, policy and cost of the T-ball task. Lengths in metres, angles
/// in radians, masses in kg; frame: x forward, y to the robot's left, z up, ground at z = 0.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TballConfig {
    /// Movement duration (s) and DMP time step (s); N = duration/dt + 1.
    pub duration: f64,
    pub dt: f64,
    /// Basis functions per joint (the paper: 3).
    pub basis_functions: usize,
    /// Joint angles at the start and at the end of the minimum-jerk swing the DMP is fitted to
    /// (order: shoulder yaw, pitch, roll, elbow, forearm rotation, wrist pitch, wrist roll).
    pub start_pose: [f64; 7],
    pub end_pose: [f64; 7],
    /// Fixed position of the right shoulder (the torso does not move).
    pub shoulder: [f64; 3],
    pub upper_arm: f64,
    pub forearm: f64,
    /// Wrist to grip.
    pub hand: f64,
    pub bat_length: f64,
    pub bat_radius: f64,
    /// Mass the bat presents at the contact (the arm is kinematic; this only scales the impulse).
    pub bat_effective_mass: f64,
    pub ball_radius: f64,
    pub ball_mass: f64,
    /// Bat–ball (and tee) coefficient of restitution, and bat–ball Coulomb friction.
    pub restitution: f64,
    pub friction: f64,
    /// Restitution of the tee's support when a hit above the ball's centre drives it downward
    /// (0: a soft tee absorbs the downward velocity; 1: a rigid tee reflects it).
    pub tee_restitution: f64,
    /// Position of the ball's centre while it rests on the tee. `ball_height` is also a setting
    /// a schedule may change (the paper lowers it by 5 cm after 20 updates).
    pub tee_x: f64,
    pub tee_y: f64,
    pub ball_height: f64,
    pub gravity: f64,
    /// The target area: a strip of ground with y in [target_y_min, target_y_max] (the paper gives
    /// only its y extent, −1 to −1.5 m).
    pub target_y_min: f64,
    pub target_y_max: f64,
    /// Weight of the acceleration term of Eq. 4 (the paper: 0.01).
    pub acceleration_weight: f64,
    /// Terminal cost of a swing that misses the ball:
    /// miss_cost + miss_gap_weight · (closest gap between bat and ball surfaces, m).
    pub miss_cost: f64,
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
