//! Robot models of the SCL stack: URDF loading, forward kinematics, geometric Jacobians,
//! damped least squares and joint limits.
//!
//! * [`RobotModel`]: a URDF read with `urdf-rs` and checked (every revolute / prismatic joint
//!   has usable limits; errors name the file and the element).
//! * [`Chain`]: a serial chain cut out of a model, precomputed into fixed arrays: FK to any
//!   link of the chain and the tip's geometric [`Jacobian`], allocation-free per call.
//! * [`dls`]: damped least-squares steps with a damping that grows near singularities, and an
//!   iterative inverse kinematics ([`Ik`]).
//! * [`gen3_lite`]: the Kinova Gen3 lite (`robots/gen3_lite.urdf`, embedded): [`Gen3Lite`],
//!   its teleoperation limits ([`ArmLimits`], position limits read from the URDF), named
//!   poses, rates.
//! * [`gen3`]: the Kinova Gen3, 7 DoF, with a Robotiq 2F-85 (`robots/gen3.urdf`, embedded):
//!   its named poses, rates, teleoperation defaults and how its continuous joints are
//!   treated (software limits, wrapping for the maps).
//! * [`planar5`]: the paper's 5-DOF planar reaching arm (`robots/planar5.urdf`).
//! * [`profile`]: [`RobotProfile`], the robot the graph drives, chosen by name
//!   (`RobotProfile::by_name`): description, arm chain, limits, named poses, rates.
//! * [`cartesian`]: TCP poses in `glam` f32 types for the Cartesian side.
//! * [`collision`]: capsule models of the arms (`robots/gen3_lite_collision.toml` and
//!   `robots/gen3_collision.toml`, embedded), the pairs that can touch, a table and boxes ([`collision::Scene`]), exact
//!   distances with closest points and the rate of change of a distance, allocation-free.
//!
//! ```
//! use kinematics::gen3_lite::{self, Gen3Lite};
//!
//! let arm = Gen3Lite::get().arm();
//! let tcp = arm.fk(&gen3_lite::HOME).unwrap();
//! assert!((tcp.translation.x - 0.43882).abs() < 1e-4);
//! ```
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod cartesian;
pub mod chain;
pub mod collision;
pub mod dls;
pub mod gen3;
pub mod gen3_lite;
pub mod planar5;
pub mod profile;
pub mod robot;

pub use cartesian::TcpPose;
pub use chain::{Chain, Jacobian, JointAxis, JointKind, KinError, LinkId, MAX_DOF};
pub use collision::{Clearance, CollisionError, CollisionLink, CollisionModel, Scene};
pub use dls::{Dls, DlsStep, Ik, IkReport, TaskMask, pose_error};
pub use gen3_lite::Gen3Lite;
pub use profile::{Gripper, GripperSpec, ModelBytes, ProfileError, ProfileSpec, RobotProfile};
pub use robot::{JointSpec, JointType, Mimic, RobotModel, UrdfError};

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clamp_reports_and_clamps() {
        let l = gen3_lite::limits();
        let mut q = [3.0, 0.0, 0.0, 0.0, -3.0, 0.0];
        assert!(l.clamp_position(&mut q));
        assert_eq!(q[0], 2.68);
        assert_eq!(q[4], -2.53);
        assert!(!l.clamp_position(&mut q));
    }
}
