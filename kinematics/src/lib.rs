//! Robot descriptions for the SCL stack.
//!
//! For now this crate holds the one table of Kinova Gen3 lite joint facts that the mock arm
//! and the safety limits read ([`gen3_lite`]). Loading the same facts from
//! `robots/gen3_lite.urdf`, forward kinematics, the Jacobian and damped least squares come
//! with the robot-model issue; callers already go through [`ArmLimits`], so the source of the
//! numbers can change without touching them.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

/// Per-joint limits of an arm, all in SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmLimits {
    /// Joint names, in chain order.
    pub names: Vec<String>,
    /// Lower position limits (rad).
    pub lower_rad: Vec<f64>,
    /// Upper position limits (rad).
    pub upper_rad: Vec<f64>,
    /// Velocity limits used for teleoperation (rad/s).
    pub max_velocity_rad_s: Vec<f64>,
    /// Acceleration limits used for teleoperation (rad/s²).
    pub max_acceleration_rad_s2: Vec<f64>,
}

impl ArmLimits {
    /// Number of joints.
    pub fn n_joints(&self) -> usize {
        self.names.len()
    }

    /// Clamps `q` into the position limits in place; returns whether any joint was clamped.
    pub fn clamp_position(&self, q: &mut [f64]) -> bool {
        let mut clamped = false;
        for ((qi, lo), hi) in q.iter_mut().zip(&self.lower_rad).zip(&self.upper_rad) {
            let c = qi.clamp(*lo, *hi);
            if c != *qi {
                clamped = true;
                *qi = c;
            }
        }
        clamped
    }
}

/// Kinova Gen3 lite facts (shared/reference/gen3-lite.md).
pub mod gen3_lite {
    use super::ArmLimits;

    /// Number of arm joints.
    pub const N_JOINTS: usize = 6;

    /// Joint names of the arm chain.
    pub const JOINT_NAMES: [&str; N_JOINTS] = [
        "joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6",
    ];

    /// Position limits (rad), symmetric: lower = -upper.
    pub const POSITION_LIMIT_RAD: [f64; N_JOINTS] = [2.68, 2.61, 2.61, 2.6, 2.53, 2.6];

    /// Teleoperation default velocity limits: the planning default velocities (rad/s).
    pub const DEFAULT_VELOCITY_RAD_S: [f64; N_JOINTS] = [0.48, 0.48, 0.48, 0.76, 0.76, 1.52];

    /// Teleoperation default acceleration limits: the simulator accelerations (rad/s²).
    pub const DEFAULT_ACCELERATION_RAD_S2: [f64; N_JOINTS] = [1.0, 0.5, 0.4, 1.0, 10.0, 10.0];

    /// The zero pose (arm straight up; singular).
    pub const ZERO: [f64; N_JOINTS] = [0.0; N_JOINTS];
    /// The home pose.
    pub const HOME: [f64; N_JOINTS] = [0.0, -0.28, 1.309, 0.0, -1.047, 0.0];
    /// The retract pose.
    pub const RETRACT: [f64; N_JOINTS] = [-0.0522, 0.3664, 2.53, -1.536, -0.6981, -1.5184];

    /// The rate of the high-level API (Hz): 40, fixed by the robot.
    pub const CONTROL_RATE_HZ: f64 = 40.0;

    /// Gripper: time constant of the first-order lag used by the mock (s).
    pub const GRIPPER_TIME_CONSTANT_S: f64 = 0.15;

    /// The Gen3 lite's teleoperation limits.
    pub fn limits() -> ArmLimits {
        ArmLimits {
            names: JOINT_NAMES.iter().map(|s| (*s).to_owned()).collect(),
            lower_rad: POSITION_LIMIT_RAD.iter().map(|v| -v).collect(),
            upper_rad: POSITION_LIMIT_RAD.to_vec(),
            max_velocity_rad_s: DEFAULT_VELOCITY_RAD_S.to_vec(),
            max_acceleration_rad_s2: DEFAULT_ACCELERATION_RAD_S2.to_vec(),
        }
    }

    /// A named pose by name (`zero`, `home`, `retract`).
    pub fn named_pose(name: &str) -> Option<[f64; N_JOINTS]> {
        match name {
            "zero" => Some(ZERO),
            "home" => Some(HOME),
            "retract" => Some(RETRACT),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_poses_are_within_limits() {
        let l = gen3_lite::limits();
        for name in ["zero", "home", "retract"] {
            let mut q = gen3_lite::named_pose(name).unwrap();
            assert!(!l.clamp_position(&mut q), "{name} is outside the limits");
        }
        assert!(gen3_lite::named_pose("nowhere").is_none());
    }

    #[test]
    fn clamp_reports_and_clamps() {
        let l = gen3_lite::limits();
        let mut q = [3.0, 0.0, 0.0, 0.0, -3.0, 0.0];
        assert!(l.clamp_position(&mut q));
        assert_eq!(q[0], 2.68);
        assert_eq!(q[4], -2.53);
    }
}
