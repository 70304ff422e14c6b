//! Forward kinematics of the 7-joint right arm and the bat fixed to its hand.
//!
//! Frame: x forward, y to the robot's left, z up; metres and radians. In the zero pose the arm
//! hangs straight down from the shoulder. Joint order and axes (each in the frame of the link
//! before it):
//!
//! | # | joint | axis |
//! |---|---|---|
//! | 0 | shoulder yaw | z |
//! | 1 | shoulder pitch | y |
//! | 2 | shoulder roll | x |
//! | 3 | elbow | y (after the upper arm) |
//! | 4 | forearm rotation | z (along the forearm) |
//! | 5 | wrist pitch | y (after the forearm) |
//! | 6 | wrist roll | x |
//!
//! The hand reaches from the wrist to the grip; the bat continues from the grip along the hand's
//! axis (a straight extension of the hand), so the bat end-point is the tip of that segment.

/// A point or a vector in the task frame (x forward, y to the robot's left, z up): metres for
/// positions, m/s for velocities.
pub type Vec3 = [f64; 3];

#[inline]
pub(crate) fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub(crate) fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
pub(crate) fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline]
pub(crate) fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(crate) fn norm(a: Vec3) -> f64 {
    dot(a, a).sqrt()
}

/// a + s·(b − a).
#[inline]
pub(crate) fn lerp(a: Vec3, b: Vec3, s: f64) -> Vec3 {
    add(a, scale(sub(b, a), s))
}

/// Row-major 3 × 3 rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rot([[f64; 3]; 3]);

impl Rot {
    const IDENTITY: Rot = Rot([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);

    #[inline]
    fn about(axis: usize, angle: f64) -> Rot {
        let (s, c) = angle.sin_cos();
        match axis {
            0 => Rot([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]),
            1 => Rot([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]),
            _ => Rot([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
        }
    }

    #[inline]
    fn then(&self, other: &Rot) -> Rot {
        let (a, b) = (&self.0, &other.0);
        let mut m = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c];
            }
        }
        Rot(m)
    }

    /// This rotation applied to (0, 0, −length): a link hanging along the local −z axis.
    #[inline]
    fn down(&self, length: f64) -> Vec3 {
        let m = &self.0;
        [-m[0][2] * length, -m[1][2] * length, -m[2][2] * length]
    }
}

/// Joint axes in chain order (0 = x, 1 = y, 2 = z); see the module table.
const AXES: [usize; 7] = [2, 1, 0, 1, 2, 1, 0];

/// Link lengths and the fixed shoulder position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Arm {
    pub(crate) shoulder: Vec3,
    pub(crate) upper_arm: f64,
    pub(crate) forearm: f64,
    /// Wrist to grip.
    pub(crate) hand: f64,
    pub(crate) bat_length: f64,
}

/// Where the arm and the bat are for one joint configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ArmPose {
    pub(crate) elbow: Vec3,
    pub(crate) wrist: Vec3,
    /// Start of the bat's axis (the hand end).
    pub(crate) grip: Vec3,
    /// End-point of the bat.
    pub(crate) tip: Vec3,
}

impl Arm {
    pub(crate) fn pose(&self, q: &[f64; 7]) -> ArmPose {
        let mut r = Rot::IDENTITY;
        for j in 0..3 {
            r = r.then(&Rot::about(AXES[j], q[j]));
        }
        let elbow = add(self.shoulder, r.down(self.upper_arm));
        r = r.then(&Rot::about(AXES[3], q[3]));
        let wrist = add(elbow, r.down(self.forearm));
        for j in 4..7 {
            r = r.then(&Rot::about(AXES[j], q[j]));
        }
        let grip = add(wrist, r.down(self.hand));
        let tip = add(grip, r.down(self.bat_length));
        ArmPose {
            elbow,
            wrist,
            grip,
            tip,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm() -> Arm {
        Arm {
            shoulder: [0.0, -0.2, 1.25],
            upper_arm: 0.28,
            forearm: 0.26,
            hand: 0.08,
            bat_length: 0.5,
        }
    }

    fn close(a: Vec3, b: Vec3) -> bool {
        norm(sub(a, b)) < 1e-12
    }

    #[test]
    fn zero_pose_hangs_down() {
        let p = arm().pose(&[0.0; 7]);
        assert!(close(p.elbow, [0.0, -0.2, 1.25 - 0.28]));
        assert!(close(p.tip, [0.0, -0.2, 1.25 - 1.12]));
    }

    #[test]
    fn pitch_then_yaw_swings_a_straight_arm_around_the_vertical() {
        // Pitch −90° about y points the straight arm forward (+x); yaw +90° then turns it left.
        let p = arm().pose(&[0.0, -std::f64::consts::FRAC_PI_2, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(close(p.tip, [1.12, -0.2, 1.25]), "{:?}", p.tip);
        let q = [
            std::f64::consts::FRAC_PI_2,
            -std::f64::consts::FRAC_PI_2,
            0.,
            0.,
            0.,
            0.,
            0.,
        ];
        let p = arm().pose(&q);
        assert!(close(p.tip, [0.0, 0.92, 1.25]), "{:?}", p.tip);
    }

    #[test]
    fn elbow_bends_only_the_forearm() {
        let p = arm().pose(&[0.0, 0.0, 0.0, std::f64::consts::FRAC_PI_2, 0.0, 0.0, 0.0]);
        assert!(close(p.elbow, [0.0, -0.2, 0.97]));
        // R_y(90°)·(0, 0, −1) = (−1, 0, 0): the forearm points backward.
        assert!(close(p.wrist, [-0.26, -0.2, 0.97]), "{:?}", p.wrist);
    }
}
