//! Dynamic Movement Primitives: multi-dimensional, B Gaussian basis functions per dimension,
//! integrated on a fixed time grid, initialised by least squares from a minimum-jerk movement.
//!
//! Formulation (Ijspeert, Nakanishi & Schaal 2002; the one that reproduces the paper's via-point
//! results most closely):
//!
//! ```text
//! τ·ż = α_z·(β_z·(g − y) − z) + f(x),   τ·ẏ = z,   x(t) = exp(−α_x·t/τ)
//! f(x) = x · Σ_b ψ_b(x)·w_b / Σ_b ψ_b(x),  ψ_b(x) = exp(−h_b·(x − c_b)²)
//! ```
//!
//! with α_z = 25, β_z = α_z/4, α_x = 4; centres c_b equally spaced in time over [0, τ] and widths
//! h_b set so that neighbouring basis functions cross at half height. The forcing term is not
//! scaled by (g − y0), so the weights θ are in the units of the trajectory's acceleration·τ²: the
//! exploration magnitude λ only means something together with this formulation. Integration is
//! semi-implicit Euler on the grid t_i = i·dt, i = 0…N−1.
//!
//! The trajectory is affine in the weights, y(t) = y_base(t) + Φ(t)·θ, and Φ does not depend on θ:
//! [`AffineDmp`] precomputes it once, so a rollout is a few multiply-adds per step. This crate is
//! a policy representation only; it knows nothing of costs or learning.
//!
//! # As a policy in your own task
//!
//! Build the [`Dmp`] once, take its minimum-jerk weights as the search's initial mean, and turn
//! each θ the optimizer asks for into a trajectory with the precomputed [`AffineDmp`]. θ holds
//! the B weights of dimension 0, then those of dimension 1, and so on; a weight moves its own
//! dimension only, most around its basis function's centre in time:
//!
//! ```
//! use dmp::{Dmp, Gains, Trajectory};
//!
//! // Two joints from (0.3, 1.6) rad to (1.4, 0.5) rad in 1 s on a 10 ms grid, 5 basis
//! // functions per joint: N = 101 steps, P = 10 weights.
//! let dmp = Dmp::new(vec![0.3, 1.6], vec![1.4, 0.5], 5, 1.0, 0.01, Gains::default())?;
//! assert_eq!((dmp.steps(), dmp.parameters()), (101, 10));
//! let theta = dmp.fit_min_jerk(1.0);
//! let affine = dmp.affine();
//! let mut reach = Trajectory::zeros(dmp.steps(), dmp.dims(), dmp.dt());
//! affine.rollout_into(&theta, &mut reach);
//! // Row-major N × D: joint d at step i is at i·D + d. The fitted reach starts where it
//! // should and ends within 5 mrad of the goal.
//! assert_eq!(&reach.pos[..2], &[0.3, 1.6]);
//! let end = &reach.pos[100 * 2..];
//! assert!((end[0] - 1.4).abs() < 5e-3 && (end[1] - 0.5).abs() < 5e-3, "{end:?}");
//!
//! // Raising joint 1's third weight (index 5 + 2; its basis function is centred at t = 0.5 s)
//! // bends joint 1 by 18 mrad mid-reach and leaves joint 0 as it was, bit for bit.
//! let mut bent = theta.clone();
//! bent[5 + 2] += 50.0;
//! let moved = affine.rollout(&bent);
//! assert_eq!(moved.pos[50 * 2], reach.pos[50 * 2]);
//! assert!(moved.pos[50 * 2 + 1] - reach.pos[50 * 2 + 1] > 0.01);
//! # Ok::<(), dmp::DmpError>(())
//! ```

#![warn(missing_docs)]

use nalgebra::{DMatrix, DVector};
use thiserror::Error;

/// A DMP specification [`Dmp::new`] refuses.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum DmpError {
    /// One argument of [`Dmp::new`] is out of range; nothing was built.
    #[error("{field} = {value}: {reason}")]
    Invalid {
        /// The argument, by the name a config gives it (`basis_functions`, `duration`, `dt`,
        /// `goal`, `start/goal`).
        field: &'static str,
        /// The value given, as text.
        value: String,
        /// What the value must be.
        reason: &'static str,
    },
}

fn invalid(field: &'static str, value: impl ToString, reason: &'static str) -> DmpError {
    DmpError::Invalid {
        field,
        value: value.to_string(),
        reason,
    }
}

/// Gains of the transformation and phase systems (dimensionless: time enters through τ). The
/// default, α_z = 25, β_z = α_z/4, α_x = 4, is critically damped and is what every built-in task
/// and the paper's results use; the weights' scale, and so λ, depend on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gains {
    /// α_z: stiffness-like gain of the transformation system τ·ż = α_z·(β_z·(g − y) − z) + f.
    pub alpha_z: f64,
    /// β_z: with α_z, the spring towards the goal; α_z/4 makes the system critically damped.
    pub beta_z: f64,
    /// α_x: decay rate of the phase x = exp(−α_x·t/τ), which falls from 1 to e^−α_x at t = τ.
    pub alpha_x: f64,
}

impl Default for Gains {
    fn default() -> Self {
        Self {
            alpha_z: 25.0,
            beta_z: 25.0 / 4.0,
            alpha_x: 4.0,
        }
    }
}

/// A DMP: start, goal, duration, time grid and basis functions. The weights are passed to
/// [`Dmp::integrate`] so that one DMP serves every sample of a batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Dmp {
    y0: Vec<f64>,
    goal: Vec<f64>,
    basis: usize,
    tau: f64,
    dt: f64,
    steps: usize,
    gains: Gains,
    centers: Vec<f64>,
    widths: Vec<f64>,
}

/// Positions, velocities and accelerations on the time grid, row-major N × D: the value of
/// dimension d at step i (time i·dt) is at index i·D + d. Velocities and accelerations are per
/// second (units of y per s and per s²), not per unit of phase.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// D: the number of dimensions (e.g. joints); at least 1.
    pub dims: usize,
    /// The grid's step, in seconds.
    pub dt: f64,
    /// y: N × D positions.
    pub pos: Vec<f64>,
    /// ẏ: N × D velocities, per second.
    pub vel: Vec<f64>,
    /// ÿ: N × D accelerations, per second².
    pub acc: Vec<f64>,
}

impl Trajectory {
    /// An all-zero trajectory of `steps` × `dims`: the buffer [`AffineDmp::rollout_into`] fills.
    pub fn zeros(steps: usize, dims: usize, dt: f64) -> Self {
        Self {
            dims,
            dt,
            pos: vec![0.0; steps * dims],
            vel: vec![0.0; steps * dims],
            acc: vec![0.0; steps * dims],
        }
    }

    /// N: the number of grid points (`pos.len() / dims`).
    pub fn steps(&self) -> usize {
        self.pos.len() / self.dims
    }
}

/// y0 + (g − y0)·(10s³ − 15s⁴ + 6s⁵), s = t/T, with its derivatives; constant after T.
pub fn min_jerk(y0: &[f64], goal: &[f64], duration: f64, dt: f64, steps: usize) -> Trajectory {
    let dims = y0.len();
    let mut tr = Trajectory::zeros(steps, dims, dt);
    for i in 0..steps {
        let s = ((i as f64 * dt) / duration).min(1.0);
        let inside = s < 1.0;
        let p = 10.0 * s.powi(3) - 15.0 * s.powi(4) + 6.0 * s.powi(5);
        let v = (30.0 * s.powi(2) - 60.0 * s.powi(3) + 30.0 * s.powi(4)) / duration;
        let a = (60.0 * s - 180.0 * s.powi(2) + 120.0 * s.powi(3)) / (duration * duration);
        for d in 0..dims {
            let amp = goal[d] - y0[d];
            tr.pos[i * dims + d] = y0[d] + amp * p;
            tr.vel[i * dims + d] = if inside { amp * v } else { 0.0 };
            tr.acc[i * dims + d] = if inside { amp * a } else { 0.0 };
        }
    }
    tr
}

impl Dmp {
    /// A DMP from `y0` to `goal` over `duration` seconds, sampled every `dt` (N = duration/dt + 1
    /// steps, so both ends are on the grid), with `basis` basis functions per dimension.
    ///
    /// Fails with [`DmpError::Invalid`] when `y0` and `goal` differ in length or are empty or
    /// not finite, `basis` is 0, `duration` is not finite and positive, or `dt` is not in
    /// (0, duration] or does not divide `duration` into a whole number of steps.
    pub fn new(
        y0: Vec<f64>,
        goal: Vec<f64>,
        basis: usize,
        duration: f64,
        dt: f64,
        gains: Gains,
    ) -> Result<Self, DmpError> {
        if y0.is_empty() || y0.len() != goal.len() {
            return Err(invalid(
                "goal",
                format!("{} values", goal.len()),
                "start and goal must have the same, non-zero number of dimensions",
            ));
        }
        if y0.iter().chain(&goal).any(|v| !v.is_finite()) {
            return Err(invalid("start/goal", "non-finite", "must be finite"));
        }
        if basis == 0 {
            return Err(invalid("basis_functions", basis, "must be at least 1"));
        }
        if !(duration.is_finite() && duration > 0.0) {
            return Err(invalid("duration", duration, "must be finite and > 0"));
        }
        if !(dt.is_finite() && dt > 0.0 && dt <= duration) {
            return Err(invalid("dt", dt, "must be in (0, duration]"));
        }
        let ratio = duration / dt;
        if (ratio - ratio.round()).abs() > 1e-9 * ratio {
            return Err(invalid(
                "dt",
                dt,
                "duration must be a whole number of steps",
            ));
        }
        let steps = ratio.round() as usize + 1;
        let centers: Vec<f64> = (0..basis)
            .map(|b| {
                let t = if basis == 1 {
                    0.5
                } else {
                    b as f64 / (basis - 1) as f64
                };
                (-gains.alpha_x * t).exp()
            })
            .collect();
        let widths = (0..basis)
            .map(|b| {
                if basis == 1 {
                    return 1.0;
                }
                let d = if b + 1 < basis {
                    centers[b] - centers[b + 1]
                } else {
                    centers[b - 1] - centers[b]
                };
                4.0 * std::f64::consts::LN_2 / (d * d)
            })
            .collect();
        Ok(Self {
            y0,
            goal,
            basis,
            tau: duration,
            dt,
            steps,
            gains,
            centers,
            widths,
        })
    }

    /// D: the number of dimensions (the length of start and goal).
    pub fn dims(&self) -> usize {
        self.y0.len()
    }

    /// B: basis functions per dimension.
    pub fn basis(&self) -> usize {
        self.basis
    }

    /// P = D·B: the length of the weight vector.
    pub fn parameters(&self) -> usize {
        self.dims() * self.basis
    }

    /// N = duration/dt + 1: grid points, both ends included.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// The grid's step, in seconds.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// τ, in seconds: the movement's duration and the DMP's time constant.
    pub fn duration(&self) -> f64 {
        self.tau
    }

    /// The phase x(t_i) = exp(−α_x·i·dt/τ) at step `i`: 1 at the start, e^−α_x at t = τ.
    pub fn phase(&self, i: usize) -> f64 {
        (-self.gains.alpha_x * i as f64 * self.dt / self.tau).exp()
    }

    /// Normalised basis activations ψ_b/Σψ at step i, written into `out` (B values).
    pub fn activations_at(&self, i: usize, out: &mut [f64]) {
        let x = self.phase(i);
        let mut sum = 0.0;
        for b in 0..self.basis {
            let d = x - self.centers[b];
            out[b] = (-self.widths[b] * d * d).exp();
            sum += out[b];
        }
        for o in out.iter_mut() {
            *o /= sum;
        }
    }

    /// Row-major N × P activations for per-parameter temporal weighting (the original PI²):
    /// weight θ_{d,b} gets ψ_b(t_i)/Σψ at step i, the same for every dimension d.
    pub fn parameter_activations(&self) -> Vec<f64> {
        let (n, b, p) = (self.steps, self.basis, self.parameters());
        let mut out = vec![0.0; n * p];
        let mut act = vec![0.0; b];
        for i in 0..n {
            self.activations_at(i, &mut act);
            for d in 0..self.dims() {
                out[i * p + d * b..i * p + (d + 1) * b].copy_from_slice(&act);
            }
        }
        out
    }

    /// Integrates the DMP with weights θ (layout: B weights of dimension 0, then dimension 1, …).
    ///
    /// # Panics
    ///
    /// If `weights` does not have [`Dmp::parameters`] values.
    pub fn integrate(&self, weights: &[f64]) -> Trajectory {
        assert_eq!(weights.len(), self.parameters(), "wrong number of weights");
        let (dims, b) = (self.dims(), self.basis);
        let Gains {
            alpha_z, beta_z, ..
        } = self.gains;
        let tau = self.tau;
        let mut tr = Trajectory::zeros(self.steps, dims, self.dt);
        let mut act = vec![0.0; b];
        let mut y = self.y0.clone();
        let mut z = vec![0.0; dims];
        for i in 0..self.steps {
            self.activations_at(i, &mut act);
            let x = self.phase(i);
            for d in 0..dims {
                let f: f64 = x * (0..b).map(|k| act[k] * weights[d * b + k]).sum::<f64>();
                let zdot = (alpha_z * (beta_z * (self.goal[d] - y[d]) - z[d]) + f) / tau;
                tr.pos[i * dims + d] = y[d];
                tr.vel[i * dims + d] = z[d] / tau;
                tr.acc[i * dims + d] = zdot / tau;
                z[d] += self.dt * zdot;
                y[d] += self.dt * z[d] / tau;
            }
        }
        tr
    }

    /// The precomputed affine form of this DMP.
    pub fn affine(&self) -> AffineDmp {
        let (n, dims, b) = (self.steps, self.dims(), self.basis);
        let base = self.integrate(&vec![0.0; self.parameters()]);
        let by_dim = |v: &[f64]| -> Vec<f64> {
            (0..dims)
                .flat_map(|d| (0..n).map(move |i| v[i * dims + d]))
                .collect()
        };
        // Each dimension integrates independently with the same phase and basis, so the response
        // to a unit weight of dimension 0 serves every dimension.
        let single = Dmp {
            y0: vec![0.0],
            goal: vec![0.0],
            ..self.clone()
        };
        let (mut phi_pos, mut phi_vel, mut phi_acc) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..b {
            let mut w = vec![0.0; b];
            w[k] = 1.0;
            let r = single.integrate(&w);
            phi_pos.extend_from_slice(&r.pos);
            phi_vel.extend_from_slice(&r.vel);
            phi_acc.extend_from_slice(&r.acc);
        }
        AffineDmp {
            steps: n,
            dims,
            basis: b,
            dt: self.dt,
            base_pos: by_dim(&base.pos),
            base_vel: by_dim(&base.vel),
            base_acc: by_dim(&base.acc),
            phi_pos,
            phi_vel,
            phi_acc,
        }
    }

    /// Least-squares weights that make the DMP reproduce the minimum-jerk movement from y0 to g
    /// over `duration` on this DMP's grid: min_θ ‖y_base + Φ·θ − y_minjerk‖² per dimension.
    pub fn fit_min_jerk(&self, duration: f64) -> Vec<f64> {
        let target = min_jerk(&self.y0, &self.goal, duration, self.dt, self.steps);
        self.fit(&target)
    }

    /// Least-squares weights reproducing the positions of `target`, which must be on this DMP's
    /// grid (N × D positions; velocities and accelerations are not used).
    pub fn fit(&self, target: &Trajectory) -> Vec<f64> {
        let aff = self.affine();
        let (n, dims, b) = (self.steps, self.dims(), self.basis);
        let phi = DMatrix::from_column_slice(n, b, &aff.phi_pos);
        let svd = phi.clone().svd(true, true);
        let mut w = vec![0.0; dims * b];
        for d in 0..dims {
            let rhs =
                DVector::from_fn(n, |i, _| target.pos[i * dims + d] - aff.base_pos[d * n + i]);
            let sol = svd
                .solve(&rhs, 1e-12)
                .expect("SVD was computed with both U and V");
            w[d * b..(d + 1) * b].copy_from_slice(sol.as_slice());
        }
        w
    }
}

/// y(t) = y_base(t) + Φ(t)·θ_d for each dimension, with Φ precomputed. Stored by dimension
/// (base) and by basis function (Φ), N contiguous values each, so that a whole trajectory is a
/// few vectorisable axpy passes.
#[derive(Debug, Clone, PartialEq)]
pub struct AffineDmp {
    steps: usize,
    dims: usize,
    basis: usize,
    dt: f64,
    base_pos: Vec<f64>,
    base_vel: Vec<f64>,
    base_acc: Vec<f64>,
    phi_pos: Vec<f64>,
    phi_vel: Vec<f64>,
    phi_acc: Vec<f64>,
}

impl AffineDmp {
    /// N, as [`Dmp::steps`].
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// D, as [`Dmp::dims`].
    pub fn dims(&self) -> usize {
        self.dims
    }

    /// B, as [`Dmp::basis`].
    pub fn basis(&self) -> usize {
        self.basis
    }

    /// P = D·B: the length of the weight vector, as [`Dmp::parameters`].
    pub fn parameters(&self) -> usize {
        self.dims * self.basis
    }

    /// The grid's step, in seconds.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    #[inline]
    fn eval(&self, base: &[f64], phi: &[f64], i: usize, d: usize, weights: &[f64]) -> f64 {
        let (n, b) = (self.steps, self.basis);
        let mut v = base[d * n + i];
        for k in 0..b {
            v += phi[k * n + i] * weights[d * b + k];
        }
        v
    }

    #[inline]
    fn eval_all(&self, base: &[f64], phi: &[f64], d: usize, weights: &[f64], out: &mut [f64]) {
        let (n, b) = (self.steps, self.basis);
        affine_rows(
            &base[d * n..(d + 1) * n],
            &phi[..b * n],
            &weights[d * b..(d + 1) * b],
            out,
        );
    }

    /// y_d(t_i) for weights θ (layout as in [`Dmp::integrate`]), without integrating the rest:
    /// B multiply-adds. Panics if `i` ≥ N, `d` ≥ D or θ is too short.
    #[inline]
    pub fn position(&self, i: usize, d: usize, weights: &[f64]) -> f64 {
        self.eval(&self.base_pos, &self.phi_pos, i, d, weights)
    }

    /// ẏ_d(t_i) per second, as [`AffineDmp::position`].
    #[inline]
    pub fn velocity(&self, i: usize, d: usize, weights: &[f64]) -> f64 {
        self.eval(&self.base_vel, &self.phi_vel, i, d, weights)
    }

    /// ÿ_d(t_i) per second², as [`AffineDmp::position`].
    #[inline]
    pub fn acceleration(&self, i: usize, d: usize, weights: &[f64]) -> f64 {
        self.eval(&self.base_acc, &self.phi_acc, i, d, weights)
    }

    /// Positions of dimension `d` at every step into `out` (N values).
    pub fn positions_into(&self, d: usize, weights: &[f64], out: &mut [f64]) {
        self.eval_all(&self.base_pos, &self.phi_pos, d, weights, out)
    }

    /// Velocities of dimension `d` at every step into `out` (N values).
    pub fn velocities_into(&self, d: usize, weights: &[f64], out: &mut [f64]) {
        self.eval_all(&self.base_vel, &self.phi_vel, d, weights, out)
    }

    /// Accelerations of dimension `d` at every step into `out` (N values).
    pub fn accelerations_into(&self, d: usize, weights: &[f64], out: &mut [f64]) {
        self.eval_all(&self.base_acc, &self.phi_acc, d, weights, out)
    }

    /// The whole trajectory for θ into `out` (no allocation): what a task's rollout calls once
    /// per θ. `out` must be N × D, e.g. `Trajectory::zeros(steps, dims, dt)` made once.
    pub fn rollout_into(&self, weights: &[f64], out: &mut Trajectory) {
        for i in 0..self.steps {
            for d in 0..self.dims {
                let j = i * self.dims + d;
                out.pos[j] = self.position(i, d, weights);
                out.vel[j] = self.velocity(i, d, weights);
                out.acc[j] = self.acceleration(i, d, weights);
            }
        }
    }

    /// The whole trajectory for θ, allocated: [`AffineDmp::rollout_into`] for a one-off.
    pub fn rollout(&self, weights: &[f64]) -> Trajectory {
        let mut t = Trajectory::zeros(self.steps, self.dims, self.dt);
        self.rollout_into(weights, &mut t);
        t
    }
}

/// out = base + Σ_k w_k·φ_k over rows of N values; compiled for several instruction sets and
/// chosen at run time (element-wise IEEE operations in a fixed order: every variant gives the
/// same bits).
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
fn affine_rows(base: &[f64], phi: &[f64], weights: &[f64], out: &mut [f64]) {
    let n = base.len();
    out.copy_from_slice(base);
    for (k, &w) in weights.iter().enumerate() {
        for (o, p) in out.iter_mut().zip(&phi[k * n..(k + 1) * n]) {
            *o += p * w;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn affine_form_matches_integration() {
        let dmp = Dmp::new(
            vec![0.0, 1.0],
            vec![1.0, -0.5],
            4,
            1.0,
            0.01,
            Gains::default(),
        )
        .unwrap();
        let w: Vec<f64> = (0..8).map(|k| (k as f64 - 3.5) * 37.0).collect();
        let direct = dmp.integrate(&w);
        let aff = dmp.affine().rollout(&w);
        assert!(max_abs_diff(&direct.pos, &aff.pos) < 1e-10);
        assert!(max_abs_diff(&direct.vel, &aff.vel) < 1e-9);
        assert!(max_abs_diff(&direct.acc, &aff.acc) < 1e-7);
    }

    #[test]
    fn min_jerk_initialised_dmp_reproduces_min_jerk() {
        let dmp = Dmp::new(vec![0.0], vec![1.0], 20, 1.0, 0.01, Gains::default()).unwrap();
        let w = dmp.fit_min_jerk(1.0);
        let traj = dmp.integrate(&w);
        let mj = min_jerk(&[0.0], &[1.0], 1.0, 0.01, dmp.steps());
        let err = max_abs_diff(&traj.pos, &mj.pos);
        assert!(err < 5e-3, "position error {err}");
        assert!((traj.pos[dmp.steps() - 1] - 1.0).abs() < 5e-3);
        // The paper's 2-basis DMP can only approximate it; it must still start and end right.
        let dmp2 = Dmp::new(vec![0.0], vec![1.0], 2, 1.0, 0.01, Gains::default()).unwrap();
        let t2 = dmp2.integrate(&dmp2.fit_min_jerk(1.0));
        assert_eq!(t2.pos[0], 0.0);
        let err2 = max_abs_diff(&t2.pos, &mj.pos);
        let unfitted = max_abs_diff(&dmp2.integrate(&[0.0, 0.0]).pos, &mj.pos);
        assert!(
            err2 < 0.15 && err2 < 0.5 * unfitted,
            "2-basis error {err2} vs {unfitted}"
        );
    }

    #[test]
    fn min_jerk_endpoints_and_peak_velocity() {
        let mj = min_jerk(&[0.0], &[2.0], 1.0, 0.01, 101);
        assert_eq!(mj.pos[0], 0.0);
        assert!((mj.pos[100] - 2.0).abs() < 1e-12);
        assert!((mj.vel[50] - 2.0 * 1.875).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_specs() {
        let g = Gains::default();
        assert!(Dmp::new(vec![0.0], vec![1.0], 0, 1.0, 0.01, g).is_err());
        assert!(Dmp::new(vec![0.0], vec![1.0, 2.0], 2, 1.0, 0.01, g).is_err());
        assert!(Dmp::new(vec![0.0], vec![1.0], 2, 1.0, 0.03, g).is_err());
        assert!(Dmp::new(vec![0.0], vec![1.0], 2, -1.0, 0.01, g).is_err());
    }

    #[test]
    fn activations_are_normalised() {
        let dmp = Dmp::new(
            vec![0.0, 0.0],
            vec![1.0, 1.0],
            3,
            1.0,
            0.01,
            Gains::default(),
        )
        .unwrap();
        let a = dmp.parameter_activations();
        assert_eq!(a.len(), 101 * 6);
        for i in 0..101 {
            let s: f64 = a[i * 6..i * 6 + 3].iter().sum();
            assert!((s - 1.0).abs() < 1e-12);
            assert_eq!(a[i * 6..i * 6 + 3], a[i * 6 + 3..i * 6 + 6]);
        }
    }
}
