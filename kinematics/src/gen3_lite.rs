//! Kinova Gen3 lite: the robot description (`robots/gen3_lite.urdf`, embedded), its arm
//! chain and the teleoperation facts that are not in a URDF (shared/reference/gen3-lite.md).
//!
//! Position limits and the URDF velocity limits come from the URDF; the teleoperation speed
//! and acceleration defaults, the named poses and the control rate are documented constants.

use std::sync::OnceLock;

use nalgebra::Isometry3;

use crate::ArmLimits;
use crate::cartesian::TcpPose;
use crate::chain::{Chain, KinError};
use crate::robot::{RobotModel, UrdfError};

/// Number of arm joints.
pub const N_JOINTS: usize = 6;

/// Joint names of the arm chain (as in the URDF).
pub const JOINT_NAMES: [&str; N_JOINTS] = [
    "joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6",
];

/// The robot description, `robots/gen3_lite.urdf`, embedded at build time.
pub const URDF: &str = include_str!("../../robots/gen3_lite.urdf");

/// How the embedded description is named in messages.
pub const URDF_NAME: &str = "robots/gen3_lite.urdf";

/// The base link: every pose is expressed in its frame.
pub const BASE_LINK: &str = "base_link";

/// The tool centre point between the fingers, 130 mm beyond the flange.
pub const TCP_LINK: &str = "tool_frame";

/// The one actuated finger joint (-0.09 closed .. 0.96 open).
pub const GRIPPER_JOINT: &str = "right_finger_bottom_joint";

/// Teleoperation default velocity limits: the planning default velocities (rad/s).
pub const DEFAULT_VELOCITY_RAD_S: [f64; N_JOINTS] = [0.48, 0.48, 0.48, 0.76, 0.76, 1.52];

/// Teleoperation default acceleration limits: the simulator accelerations (rad/s²).
pub const DEFAULT_ACCELERATION_RAD_S2: [f64; N_JOINTS] = [1.0, 0.5, 0.4, 1.0, 10.0, 10.0];

/// The zero pose (arm straight up; singular: the Jacobian loses rank here).
pub const ZERO: [f64; N_JOINTS] = [0.0; N_JOINTS];
/// The home pose.
pub const HOME: [f64; N_JOINTS] = [0.0, -0.28, 1.309, 0.0, -1.047, 0.0];
/// The retract pose.
pub const RETRACT: [f64; N_JOINTS] = [-0.0522, 0.3664, 2.53, -1.536, -0.6981, -1.5184];

/// The rate of the high-level API (Hz): 40, fixed by the robot.
pub const CONTROL_RATE_HZ: f64 = 40.0;

/// Gripper: time constant of the first-order lag used by the mock (s).
pub const GRIPPER_TIME_CONSTANT_S: f64 = 0.15;

/// The Gen3 lite's bundled model, `models/default.safetensors` (its name from before there
/// were profiles): SCL with the paper's defaults on the generated pick-and-place
/// demonstrations, speed scale 0.6 rad/s (`scripts/regenerate-bundled-model.sh`).
pub const BUNDLED_MODEL: &[u8] = include_bytes!("../../models/default.safetensors");

/// A named pose by name (`zero`, `home`, `retract`).
pub fn named_pose(name: &str) -> Option<[f64; N_JOINTS]> {
    match name {
        "zero" => Some(ZERO),
        "home" => Some(HOME),
        "retract" => Some(RETRACT),
        _ => None,
    }
}

/// The Gen3 lite model: the parsed URDF, the arm chain `base_link -> tool_frame` and the
/// gripper joint's range. Other crates take FK (the TCP for workspace limits) and the
/// Jacobian (Cartesian modes) from [`Gen3Lite::arm`].
#[derive(Debug, Clone, PartialEq)]
pub struct Gen3Lite {
    model: RobotModel,
    arm: Chain,
    gripper_lower: f64,
    gripper_upper: f64,
    gripper_velocity: f64,
}

static MODEL: OnceLock<Gen3Lite> = OnceLock::new();

impl Gen3Lite {
    /// Parses the embedded URDF.
    pub fn load() -> Result<Self, UrdfError> {
        Self::from_urdf_str(URDF, URDF_NAME)
    }

    /// Builds the model from another Gen3 lite description (same link and joint names).
    pub fn from_urdf_str(text: &str, file: &str) -> Result<Self, UrdfError> {
        let model = RobotModel::from_urdf_str(text, file)?;
        let arm = model.chain(BASE_LINK, TCP_LINK)?;
        if arm.joint_names() != JOINT_NAMES {
            return Err(UrdfError::Structure {
                file: file.to_owned(),
                reason: format!(
                    "the chain {BASE_LINK} -> {TCP_LINK} has the joints {:?}; a Gen3 lite has {JOINT_NAMES:?}",
                    arm.joint_names()
                ),
            });
        }
        let g = model
            .joint(GRIPPER_JOINT)
            .ok_or_else(|| UrdfError::Structure {
                file: file.to_owned(),
                reason: format!("there is no <joint name=\"{GRIPPER_JOINT}\"> (the gripper)"),
            })?;
        let (gripper_lower, gripper_upper, gripper_velocity) = (g.lower, g.upper, g.velocity);
        Ok(Self {
            model,
            arm,
            gripper_lower,
            gripper_upper,
            gripper_velocity,
        })
    }

    /// The model parsed from the embedded URDF, once per process.
    ///
    /// # Panics
    ///
    /// If the embedded `robots/gen3_lite.urdf` does not load, which is a build defect that
    /// the crate's tests catch (`embedded_urdf_loads`).
    pub fn get() -> &'static Gen3Lite {
        MODEL.get_or_init(|| match Self::load() {
            Ok(m) => m,
            Err(e) => panic!("the embedded Gen3 lite description is broken: {e}"),
        })
    }

    /// The parsed robot description.
    pub fn model(&self) -> &RobotModel {
        &self.model
    }

    /// The arm chain `base_link -> tool_frame` (6 revolute joints).
    pub fn arm(&self) -> &Chain {
        &self.arm
    }

    /// The gripper joint's range `(closed, open)` (rad).
    pub fn gripper_range(&self) -> (f64, f64) {
        (self.gripper_lower, self.gripper_upper)
    }

    /// The gripper joint's velocity limit (rad/s).
    pub fn gripper_velocity(&self) -> f64 {
        self.gripper_velocity
    }

    /// Pose of the TCP (`tool_frame`) in the base frame.
    pub fn tcp(&self, q: &[f64]) -> Result<Isometry3<f64>, KinError> {
        self.arm.fk(q)
    }

    /// Pose of the TCP in glam f32 types.
    pub fn tcp_pose(&self, q: &[f64]) -> Result<TcpPose, KinError> {
        Ok(TcpPose::from(&self.arm.fk(q)?))
    }

    /// Teleoperation limits: position limits from the URDF; velocity limits the teleoperation
    /// defaults, capped by the URDF velocity limits; the default accelerations.
    pub fn limits(&self) -> ArmLimits {
        ArmLimits {
            names: self.arm.joint_names().to_vec(),
            lower_rad: self.arm.lower().to_vec(),
            upper_rad: self.arm.upper().to_vec(),
            max_velocity_rad_s: DEFAULT_VELOCITY_RAD_S
                .iter()
                .zip(self.arm.velocity_limits())
                .map(|(d, u)| d.min(*u))
                .collect(),
            max_acceleration_rad_s2: DEFAULT_ACCELERATION_RAD_S2.to_vec(),
        }
    }
}

/// The Gen3 lite's teleoperation limits (see [`Gen3Lite::limits`]), read from the embedded
/// URDF.
pub fn limits() -> ArmLimits {
    Gen3Lite::get().limits()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn embedded_urdf_loads() {
        let g = Gen3Lite::load().unwrap();
        assert_eq!(g.arm().n_joints(), N_JOINTS);
        assert_eq!(g.arm().joint_names(), JOINT_NAMES);
        assert_eq!(g.gripper_range(), (-0.09, 0.96));
        assert_eq!(g.gripper_velocity(), 0.6);
        assert_eq!(g.model().name(), "gen3_lite");
    }

    #[test]
    fn limits_come_from_the_urdf() {
        let l = limits();
        assert_eq!(l.names, JOINT_NAMES);
        assert_eq!(l.upper_rad, [2.68, 2.61, 2.61, 2.6, 2.53, 2.6]);
        assert_eq!(l.lower_rad, [-2.68, -2.61, -2.61, -2.6, -2.53, -2.6]);
        assert_eq!(
            Gen3Lite::get().arm().velocity_limits(),
            &[1.6, 1.6, 1.6, 1.6, 1.6, 3.2]
        );
        // The teleoperation defaults are below the URDF's velocity limits, so they stand.
        assert_eq!(l.max_velocity_rad_s, DEFAULT_VELOCITY_RAD_S);
        assert_eq!(l.max_acceleration_rad_s2, DEFAULT_ACCELERATION_RAD_S2);
    }

    #[test]
    fn a_slower_urdf_caps_the_teleop_velocity() {
        let slow = URDF.replace("velocity=\"3.2\"", "velocity=\"1.0\"");
        let g = Gen3Lite::from_urdf_str(&slow, "slow.urdf").unwrap();
        assert_eq!(g.limits().max_velocity_rad_s[5], 1.0);
        assert_eq!(g.limits().max_velocity_rad_s[0], 0.48);
    }

    #[test]
    fn a_description_without_the_gripper_is_refused() {
        let text = URDF.replace(GRIPPER_JOINT, "some_other_joint");
        let e = Gen3Lite::from_urdf_str(&text, "nogrip.urdf").unwrap_err();
        assert_eq!(
            e.to_string(),
            "nogrip.urdf: there is no <joint name=\"right_finger_bottom_joint\"> (the gripper)"
        );
    }

    /// The reference table of shared/reference/gen3-lite.md, to 0.1 mm.
    #[test]
    fn fk_matches_the_reference_table() {
        let g = Gen3Lite::get();
        let cases = [
            (ZERO, Vector3::new(0.05700, -0.01000, 1.00325)),
            (HOME, Vector3::new(0.43882, 0.19349, 0.44876)),
        ];
        for (q, want) in cases {
            let t = g.tcp(&q).unwrap();
            let err = (t.translation.vector - want).norm();
            assert!(
                err < 1e-4,
                "{q:?}: {} vs {want}: {err} m",
                t.translation.vector
            );
        }
        // Zero pose: the tool frame is turned +90° about z.
        let r = g.tcp(&ZERO).unwrap().rotation;
        let want =
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        assert!(r.angle_to(&want) < 1e-9, "{:?}", r.euler_angles());
        let p = g.tcp_pose(&HOME).unwrap();
        assert!((f64::from(p.position.x) - 0.43882).abs() < 1e-4);
    }

    #[test]
    fn named_poses_are_within_limits() {
        let l = limits();
        for name in ["zero", "home", "retract"] {
            let mut q = named_pose(name).unwrap();
            assert!(!l.clamp_position(&mut q), "{name} is outside the limits");
            assert!(Gen3Lite::get().arm().within_limits(&q));
        }
        assert!(named_pose("nowhere").is_none());
    }
}
