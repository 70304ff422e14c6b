//! Analytic bat–ball contact and the ball's ballistic flight.
//!
//! The bat is a capsule (a segment with a radius) whose motion is prescribed: the arm is
//! kinematic, so the bat is not slowed by the ball except through an effective-mass factor. The
//! ball is a sphere resting on a tee. One impact is modelled:
//!
//! - Normal: the ball leaves with (1 + e)·v_n·M/(M + m) along the contact normal, where v_n is
//!   the bat's approach speed at the contact point, e the restitution, M the bat's effective
//!   mass at the contact and m the ball's mass.
//! - Tangential: Coulomb friction drags the ball along with the bat's tangential velocity, at most
//!   μ times the normal impulse and at most 2/7 of the tangential slip: a solid sphere at rest
//!   (moment of inertia 2/5·m·r²) rolls on the bat once its centre has taken 2/7 of the slip. Its
//!   spin is then ignored in flight, and unlike the normal impulse this bound leaves out the
//!   bat's recoil (M/(M + m)), which would lower it by about 1.4 % at the default masses.
//! - Tee: if the impact drives the ball downward (a hit above its centre), the tee under it
//!   pushes back: the vertical velocity is reflected with the tee's own restitution (0 for a soft
//!   tee that absorbs it, so the ball leaves horizontally). This is a crude stand-in for the ball being squeezed between bat and tee, where full simulators
//!   disagree with each other by decimetres (see the crate docs).
//!
//! After the impact the ball flies without drag or spin until its lowest point touches the
//! ground (z = radius), in closed form.

use crate::arm::{add, dot, lerp, norm, scale, sub, Vec3};

/// Material and mass parameters of the impact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ContactModel {
    pub(crate) restitution: f64,
    pub(crate) friction: f64,
    pub(crate) tee_restitution: f64,
    pub(crate) ball_mass: f64,
    pub(crate) bat_effective_mass: f64,
}

/// Closest point to `c` on the segment a–b: (parameter u in [0, 1], distance).
#[inline]
pub(crate) fn closest_on_segment(a: Vec3, b: Vec3, c: Vec3) -> (f64, f64) {
    let ab = sub(b, a);
    let len2 = dot(ab, ab);
    let u = if len2 > 0.0 {
        (dot(sub(c, a), ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (u, norm(sub(c, lerp(a, b, u))))
}

/// The bat segment at two consecutive time steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BatStep {
    pub(crate) grip0: Vec3,
    pub(crate) tip0: Vec3,
    pub(crate) grip1: Vec3,
    pub(crate) tip1: Vec3,
    pub(crate) dt: f64,
}

/// Where and how the bat touched the ball.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Impact {
    /// Fraction of the step at which the surfaces touch.
    pub step_fraction: f64,
    /// Contact point on the bat's axis as a fraction of its length from the grip.
    pub along_bat: f64,
    /// Unit normal from the bat's axis to the ball's centre.
    pub normal: Vec3,
    /// Velocity of the bat's material point at the contact (m/s).
    pub bat_velocity: Vec3,
    /// The ball's velocity right after the impact (m/s).
    pub ball_velocity: Vec3,
}

/// Finds the moment within one step where the bat's surface reaches the ball's surface, given
/// that it was apart at the start of the step and touching or overlapping at its end. Between
/// steps both ends of the bat move linearly, so its material points move with constant velocity.
pub(crate) fn touch_within(step: &BatStep, ball: Vec3, reach: f64) -> (f64, f64) {
    let dist = |s: f64| {
        closest_on_segment(
            lerp(step.grip0, step.grip1, s),
            lerp(step.tip0, step.tip1, s),
            ball,
        )
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    // 40 halvings: 2⁻⁴⁰ of a step (1e-15 s at dt = 1 ms), far below any length that matters.
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if dist(mid).1 > reach {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (hi, dist(hi).0)
}

impl ContactModel {
    /// The impact of the bat on a ball at `ball` when they touch at fraction `s` of `step`, or
    /// None if the bat's surface is not approaching the ball there.
    pub(crate) fn impact(
        &self,
        step: &BatStep,
        ball: Vec3,
        s: f64,
        along_bat: f64,
    ) -> Option<Impact> {
        let axis_point = lerp(
            lerp(step.grip0, step.grip1, s),
            lerp(step.tip0, step.tip1, s),
            along_bat,
        );
        let to_ball = sub(ball, axis_point);
        let d = norm(to_ball);
        if d == 0.0 {
            return None;
        }
        let normal = scale(to_ball, 1.0 / d);
        let start = lerp(step.grip0, step.tip0, along_bat);
        let end = lerp(step.grip1, step.tip1, along_bat);
        let bat_velocity = scale(sub(end, start), 1.0 / step.dt);
        let approach = dot(bat_velocity, normal);
        if approach <= 0.0 {
            return None;
        }
        let mass_ratio = self.bat_effective_mass / (self.bat_effective_mass + self.ball_mass);
        let normal_change = (1.0 + self.restitution) * approach * mass_ratio;
        let slip = sub(bat_velocity, scale(normal, approach));
        let slip_speed = norm(slip);
        let mut v = scale(normal, normal_change);
        if slip_speed > 0.0 {
            let tangential = (self.friction * normal_change).min(2.0 / 7.0 * slip_speed);
            v = add(v, scale(slip, tangential / slip_speed));
        }
        if v[2] < 0.0 {
            v[2] *= -self.tee_restitution;
        }
        Some(Impact {
            step_fraction: s,
            along_bat,
            normal,
            bat_velocity,
            ball_velocity: v,
        })
    }
}

/// Drag-free flight from `start` with velocity `v` under gravity `g` until the ball's lowest
/// point touches the ground: (time of flight, landing position of the centre).
pub(crate) fn flight(start: Vec3, v: Vec3, g: f64, radius: f64) -> (f64, Vec3) {
    let drop = (start[2] - radius).max(0.0);
    let t = (v[2] + (v[2] * v[2] + 2.0 * g * drop).sqrt()) / g;
    (t, ball_at(start, v, g, t))
}

/// The ball's centre `t` seconds into a flight.
pub(crate) fn ball_at(start: Vec3, v: Vec3, g: f64, t: f64) -> Vec3 {
    [
        start[0] + v[0] * t,
        start[1] + v[1] * t,
        start[2] + v[2] * t - 0.5 * g * t * t,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    const MODEL: ContactModel = ContactModel {
        restitution: 0.6,
        friction: 0.3,
        tee_restitution: 0.5,
        ball_mass: 0.05,
        bat_effective_mass: 1.0,
    };

    /// A horizontal bat along x, at height z, moving in −y at `speed`.
    fn sweep(z: f64, y0: f64, speed: f64, dt: f64) -> BatStep {
        BatStep {
            grip0: [-0.25, y0, z],
            tip0: [0.25, y0, z],
            grip1: [-0.25, y0 - speed * dt, z],
            tip1: [0.25, y0 - speed * dt, z],
            dt,
        }
    }

    #[test]
    fn head_on_hit_follows_newton_restitution() {
        let ball = [0.0, 0.0, 0.0];
        // Bat starts 0.07 m from the ball centre and moves 0.01 m; contact at 0.065.
        let step = sweep(0.0, 0.07, 2.0, 0.005);
        let (s, u) = touch_within(&step, ball, 0.065);
        assert!((s - 0.5).abs() < 1e-9, "{s}");
        assert!((u - 0.5).abs() < 1e-9);
        let hit = MODEL.impact(&step, ball, s, u).unwrap();
        let expected = -(1.6 * 2.0 / 1.05);
        assert!((hit.ball_velocity[1] - expected).abs() < 1e-9, "{:?}", hit);
        assert!(hit.ball_velocity[0].abs() < 1e-12 && hit.ball_velocity[2].abs() < 1e-12);
    }

    #[test]
    fn hit_above_centre_is_bounced_up_by_the_tee() {
        // Bat axis 0.04 m above the ball centre: the normal points down and sideways.
        let ball = [0.0, 0.0, 0.0];
        let step = sweep(0.04, 0.06, 2.0, 0.01);
        let (s, u) = touch_within(&step, ball, 0.065);
        let hit = MODEL.impact(&step, ball, s, u).unwrap();
        assert!(hit.normal[2] < -0.5, "{:?}", hit.normal);
        assert!(
            hit.ball_velocity[2] > 0.0,
            "tee reflects: {:?}",
            hit.ball_velocity
        );
        assert!(hit.ball_velocity[1] < 0.0);
    }

    #[test]
    fn receding_bat_does_not_hit() {
        let ball = [0.0, 0.0, 0.0];
        let step = sweep(0.0, 0.06, -2.0, 0.01);
        assert!(MODEL.impact(&step, ball, 0.0, 0.5).is_none());
    }

    #[test]
    fn flight_lands_where_gravity_says() {
        let (t, p) = flight([0.0, 0.0, 1.0], [0.0, -2.0, 0.0], 9.81, 0.0);
        assert!((t - (2.0f64 / 9.81).sqrt()).abs() < 1e-12);
        assert!((p[1] + 2.0 * t).abs() < 1e-12 && p[2].abs() < 1e-12);
        let (t_up, _) = flight([0.0, 0.0, 1.0], [0.0, 0.0, 3.0], 9.81, 0.0);
        assert!(t_up > t);
    }
}
