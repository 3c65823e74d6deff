//! The mock arm: a kinematic simulation of the graph's robot profile
//! ([`kinematics::RobotProfile`]: its joint limits, named poses and gripper lag) that closes
//! the loop in tests and is the default when no robot is attached.

use std::collections::VecDeque;

use ipc_types::MAX_JOINTS;
use kinematics::{ArmLimits, RobotProfile};
use serde::{Deserialize, Serialize};

use crate::{Reading, Robot, RobotError};

/// Settings of the mock: the `[bridge.mock]` table of the graph TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MockConfig {
    /// Start pose: one of the robot profile's named poses (`home`, `zero` or `retract` on the
    /// default arm).
    pub initial_pose: String,
    /// Start at these joint angles (rad, one per joint, inside the position limits) instead of
    /// `initial_pose`: how `scl study simulate --live` starts each attempt exactly at the
    /// task's start pose. Unset by default.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_q: Option<Vec<f64>>,
    /// Initial gripper state in `[0, 1]`.
    pub initial_gripper: f64,
    /// Time constant of the gripper's first-order lag (s).
    pub gripper_time_constant_s: f64,
    /// Commands take effect this many ticks after they are given (fault injection).
    pub latency_ticks: u32,
    /// Every n-th command is lost, the previous one staying in force (0 = none).
    pub drop_every: u32,
}

impl Default for MockConfig {
    /// [`MockConfig::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

impl MockConfig {
    /// The defaults for `robot`: its `home` pose, open gripper with its lag, no faults.
    pub fn for_robot(robot: &RobotProfile) -> Self {
        Self {
            initial_pose: "home".into(),
            initial_q: None,
            initial_gripper: 0.0,
            gripper_time_constant_s: robot.gripper_time_constant_s(),
            latency_ticks: 0,
            drop_every: 0,
        }
    }
}

/// Why a mock configuration was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("bridge.mock.{key}: {reason}")]
pub struct MockConfigError {
    /// The key under `[bridge.mock]`.
    pub key: &'static str,
    /// What is wrong.
    pub reason: String,
}

const _: () = assert!(kinematics::MAX_DOF <= MAX_JOINTS);

/// Checks `[bridge.mock] initial_q`: one finite angle per joint of `robot`, inside its
/// position limits.
fn check_initial_q(robot: &RobotProfile, q: &[f64]) -> Result<(), MockConfigError> {
    let bad = |reason: String| MockConfigError {
        key: "initial_q",
        reason,
    };
    let n = robot.n_joints();
    if q.len() != n {
        return Err(bad(format!(
            "{} angles given; {} has {n} joints",
            q.len(),
            robot.name()
        )));
    }
    let l = robot.limits();
    for (j, &v) in q.iter().enumerate() {
        if !v.is_finite() {
            return Err(bad(format!(
                "joint {} ({}): {v} is not a number",
                j + 1,
                l.names[j]
            )));
        }
        if v < l.lower_rad[j] || v > l.upper_rad[j] {
            return Err(bad(format!(
                "joint {} ({}): {v} rad is outside its limits [{}, {}]",
                j + 1,
                l.names[j],
                l.lower_rad[j],
                l.upper_rad[j]
            )));
        }
    }
    Ok(())
}

/// The simulated arm.
#[derive(Debug, Clone)]
pub struct MockArm {
    limits: ArmLimits,
    cfg: MockConfig,
    q: [f64; MAX_JOINTS],
    qdot: [f64; MAX_JOINTS],
    /// Commanded velocity currently in force.
    cmd: [f64; MAX_JOINTS],
    gripper_rate: f64,
    gripper_target: f64,
    gripper: f64,
    pending: VecDeque<([f64; MAX_JOINTS], f64)>,
    commands_seen: u64,
}

impl MockArm {
    /// A mock of the default robot profile with the given settings
    /// ([`MockArm::for_robot`]).
    pub fn new(cfg: MockConfig) -> Result<Self, MockConfigError> {
        Self::for_robot(RobotProfile::default_robot(), cfg)
    }

    /// A mock of `robot` with the given settings.
    pub fn for_robot(robot: &RobotProfile, cfg: MockConfig) -> Result<Self, MockConfigError> {
        // A chain has at most MAX_DOF joints, which the messages carry (asserted below).
        let n = robot.n_joints();
        let named = robot
            .named_pose(&cfg.initial_pose)
            .ok_or_else(|| MockConfigError {
                key: "initial_pose",
                reason: format!(
                    "`{}` is not a named pose of {}; use {}",
                    cfg.initial_pose,
                    robot.name(),
                    robot.pose_names().collect::<Vec<_>>().join(", ")
                ),
            })?;
        let pose = match &cfg.initial_q {
            None => named,
            Some(q) => {
                check_initial_q(robot, q)?;
                q.as_slice()
            }
        };
        if !(0.0..=1.0).contains(&cfg.initial_gripper) {
            return Err(MockConfigError {
                key: "initial_gripper",
                reason: format!("{} is outside [0, 1]", cfg.initial_gripper),
            });
        }
        if !(cfg.gripper_time_constant_s.is_finite() && cfg.gripper_time_constant_s > 0.0) {
            return Err(MockConfigError {
                key: "gripper_time_constant_s",
                reason: format!("{} must be a positive number", cfg.gripper_time_constant_s),
            });
        }
        let mut q = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(pose);
        Ok(Self {
            limits: robot.limits().clone(),
            q,
            qdot: [0.0; MAX_JOINTS],
            cmd: [0.0; MAX_JOINTS],
            gripper_rate: 0.0,
            gripper_target: cfg.initial_gripper,
            gripper: cfg.initial_gripper,
            pending: VecDeque::new(),
            commands_seen: 0,
            cfg,
        })
    }

    /// The joint limits the mock respects.
    pub fn limits(&self) -> &ArmLimits {
        &self.limits
    }

    /// Puts the simulated arm at pose `q` (clamped into the limits) and gripper state
    /// `gripper`, at rest with no command in force: how a restarted bridge takes over the arm
    /// its predecessor left (a real arm keeps its pose by itself).
    pub fn resume(&mut self, q: &[f64], gripper: f64) {
        let n = self.limits.n_joints().min(q.len());
        self.q = [0.0; MAX_JOINTS];
        self.q[..n].copy_from_slice(&q[..n]);
        self.limits
            .clamp_position(&mut self.q[..self.limits.n_joints()]);
        let c = if gripper.is_finite() {
            gripper.clamp(0.0, 1.0)
        } else {
            0.0
        };
        self.gripper = c;
        self.gripper_target = c;
        self.halt();
        self.qdot = [0.0; MAX_JOINTS];
    }

    /// The velocity command currently in force.
    pub fn command_in_force(&self) -> &[f64] {
        &self.cmd[..self.limits.n_joints()]
    }
}

impl MockArm {
    /// Lets `dt` seconds of the command in force pass and returns the new state.
    pub fn step(&mut self, dt: f64) -> Reading {
        let n = self.limits.n_joints();
        let mut at_limit = false;
        for j in 0..n {
            let before = self.q[j];
            let next = (before + self.cmd[j] * dt)
                .clamp(self.limits.lower_rad[j], self.limits.upper_rad[j]);
            if next == self.limits.lower_rad[j] || next == self.limits.upper_rad[j] {
                at_limit = true;
            }
            self.qdot[j] = (next - before) / dt;
            self.q[j] = next;
        }
        self.gripper_target = (self.gripper_target + self.gripper_rate * dt).clamp(0.0, 1.0);
        let alpha = 1.0 - (-dt / self.cfg.gripper_time_constant_s).exp();
        self.gripper += (self.gripper_target - self.gripper) * alpha;
        Reading {
            q_rad: self.q,
            qdot_rad_s: self.qdot,
            gripper: self.gripper,
            at_limit,
        }
    }

    /// Gives a velocity command (rad/s) and gripper rate (1/s), subject to the configured
    /// latency and drops.
    pub fn set_command(&mut self, qdot_rad_s: &[f64], gripper_rate: f64) {
        self.commands_seen += 1;
        if self.cfg.drop_every > 0
            && self
                .commands_seen
                .is_multiple_of(u64::from(self.cfg.drop_every))
        {
            return;
        }
        let mut c = [0.0; MAX_JOINTS];
        let n = self.limits.n_joints().min(qdot_rad_s.len());
        c[..n].copy_from_slice(&qdot_rad_s[..n]);
        self.pending.push_back((c, gripper_rate));
        while self.pending.len() > self.cfg.latency_ticks as usize {
            if let Some((c, g)) = self.pending.pop_front() {
                self.cmd = c;
                self.gripper_rate = g;
            }
        }
    }

    /// Zeroes the command at once (pending commands are dropped); the gripper keeps moving
    /// to its target.
    pub fn halt(&mut self) {
        self.pending.clear();
        self.cmd = [0.0; MAX_JOINTS];
        self.gripper_rate = 0.0;
    }

    /// Sets the gripper's target position `0` open .. `1` closed (a position command, as
    /// the Kortex gripper takes it); the rate stops.
    pub fn set_gripper_target(&mut self, c: f64) {
        if c.is_finite() {
            self.gripper_target = c.clamp(0.0, 1.0);
        }
        self.gripper_rate = 0.0;
    }

    /// The gripper's target position.
    pub fn gripper_target(&self) -> f64 {
        self.gripper_target
    }
}

impl Robot for MockArm {
    fn n_joints(&self) -> usize {
        self.limits.n_joints()
    }

    fn advance(&mut self, dt: f64) -> Result<Reading, RobotError> {
        Ok(self.step(dt))
    }

    fn command(&mut self, qdot_rad_s: &[f64], gripper_rate: f64) -> Result<(), RobotError> {
        self.set_command(qdot_rad_s, gripper_rate);
        Ok(())
    }

    fn stop(&mut self) -> Result<(), RobotError> {
        self.halt();
        Ok(())
    }

    fn shutdown(&mut self) -> Result<Reading, RobotError> {
        self.halt();
        // The final state, without letting a period pass.
        Ok(self.step(1e-9))
    }

    fn is_mock(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics::gen3_lite;

    const DT: f64 = 0.025;

    #[test]
    fn integrates_from_home() {
        let mut arm = MockArm::new(MockConfig::default()).unwrap();
        let r0 = arm.step(DT);
        assert_eq!(&r0.q_rad[..6], &gen3_lite::HOME);
        arm.set_command(&[0.4, 0.0, 0.0, 0.0, 0.0, -0.2], 0.0);
        for _ in 0..40 {
            arm.step(DT);
        }
        let r = arm.step(1e-9);
        assert!((r.q_rad[0] - 0.4).abs() < 1e-9);
        assert!((r.q_rad[5] + 0.2).abs() < 1e-9);
        assert_eq!(r.q_rad[1], gen3_lite::HOME[1]);
    }

    #[test]
    fn stops_at_joint_limits() {
        let mut arm = MockArm::new(MockConfig::default()).unwrap();
        arm.set_command(&[2.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0);
        let mut r = arm.step(DT);
        for _ in 0..200 {
            r = arm.step(DT);
        }
        assert_eq!(r.q_rad[0], 2.68);
        assert_eq!(r.qdot_rad_s[0], 0.0);
        assert!(r.at_limit);
        // Motion away from the limit is possible.
        arm.set_command(&[-0.5, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0);
        let r = arm.step(DT);
        assert!(r.q_rad[0] < 2.68);
        assert!(!r.at_limit);
    }

    #[test]
    fn gripper_is_a_first_order_lag() {
        let mut arm = MockArm::new(MockConfig::default()).unwrap();
        arm.set_command(&[0.0; 6], 10.0); // target reaches 1 within 0.1 s
        let mut prev = 0.0;
        let mut r = arm.step(DT);
        for _ in 0..4 {
            r = arm.step(DT);
            assert!(r.gripper > prev);
            prev = r.gripper;
        }
        assert!(r.gripper < 1.0);
        for _ in 0..80 {
            r = arm.step(DT);
        }
        assert!((r.gripper - 1.0).abs() < 1e-3);
    }

    #[test]
    fn latency_and_drops() {
        let cfg = MockConfig {
            latency_ticks: 2,
            ..MockConfig::default()
        };
        let mut arm = MockArm::new(cfg).unwrap();
        arm.set_command(&[0.1; 6], 0.0);
        assert_eq!(arm.command_in_force(), &[0.0; 6]);
        arm.set_command(&[0.2; 6], 0.0);
        assert_eq!(arm.command_in_force(), &[0.0; 6]);
        arm.set_command(&[0.3; 6], 0.0);
        assert_eq!(arm.command_in_force(), &[0.1; 6]);

        let cfg = MockConfig {
            drop_every: 2,
            ..MockConfig::default()
        };
        let mut arm = MockArm::new(cfg).unwrap();
        arm.set_command(&[0.1; 6], 0.0);
        arm.set_command(&[0.2; 6], 0.0); // dropped
        assert_eq!(arm.command_in_force(), &[0.1; 6]);
        arm.set_command(&[0.3; 6], 0.0);
        assert_eq!(arm.command_in_force(), &[0.3; 6]);
        arm.halt();
        assert_eq!(arm.command_in_force(), &[0.0; 6]);
    }

    #[test]
    fn resume_takes_over_a_pose_at_rest() {
        let mut arm = MockArm::new(MockConfig::default()).unwrap();
        arm.set_command(&[0.3; 6], 1.0);
        arm.resume(&[0.1, 0.2, 0.3, 0.4, 0.5, 9.0], 0.7);
        assert_eq!(arm.command_in_force(), &[0.0; 6]);
        let r = arm.step(DT);
        assert_eq!(&r.q_rad[..5], &[0.1, 0.2, 0.3, 0.4, 0.5]);
        assert_eq!(r.q_rad[5], 2.6, "clamped into the limit");
        assert!((r.gripper - 0.7).abs() < 1e-12);
    }

    #[test]
    fn refuses_bad_settings() {
        let e = MockArm::new(MockConfig {
            initial_pose: "sideways".into(),
            ..MockConfig::default()
        })
        .unwrap_err();
        assert_eq!(e.key, "initial_pose");
        let e = MockArm::new(MockConfig {
            gripper_time_constant_s: 0.0,
            ..MockConfig::default()
        })
        .unwrap_err();
        assert_eq!(e.key, "gripper_time_constant_s");
    }

    #[test]
    fn starts_at_a_joint_vector_inside_the_limits_and_refuses_others() {
        let q = [0.1, 0.2, 1.5, -0.3, 0.4, 0.5];
        let mut arm = MockArm::new(MockConfig {
            initial_q: Some(q.to_vec()),
            ..MockConfig::default()
        })
        .unwrap();
        assert_eq!(&arm.step(DT).q_rad[..6], &q);
        let refused = |q: Vec<f64>| {
            MockArm::new(MockConfig {
                initial_q: Some(q),
                ..MockConfig::default()
            })
            .unwrap_err()
        };
        let e = refused(vec![0.0; 5]);
        assert_eq!(e.key, "initial_q");
        assert!(e.reason.contains("5 angles given"), "{e}");
        let e = refused(vec![0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0]);
        assert!(e.reason.contains("joint 2"), "{e}");
        let mut far = q.to_vec();
        far[1] = 10.0;
        let e = refused(far);
        assert!(
            e.reason.contains("joint 2") && e.reason.contains("outside"),
            "{e}"
        );
        // It survives the graph TOML's round trip.
        let cfg = MockConfig {
            initial_q: Some(q.to_vec()),
            ..MockConfig::default()
        };
        let text = toml::to_string(&cfg).unwrap();
        assert_eq!(toml::from_str::<MockConfig>(&text).unwrap(), cfg);
        assert!(
            !toml::to_string(&MockConfig::default())
                .unwrap()
                .contains("initial_q")
        );
    }

    /// The mock follows the profile it is given: another arm's joints, limits and poses.
    #[test]
    fn simulates_the_robot_profile_it_is_given() {
        let planar = RobotProfile::new(&kinematics::ProfileSpec::planar5()).unwrap();
        let mut arm = MockArm::for_robot(&planar, MockConfig::for_robot(&planar)).unwrap();
        assert_eq!(arm.n_joints(), 5);
        arm.set_command(&[10.0, 0.0, 0.0, 0.0, 0.0, 7.0], 0.0);
        let mut r = arm.step(DT);
        for _ in 0..100 {
            r = arm.step(DT);
        }
        assert_eq!(r.q_rad[0], planar.limits().upper_rad[0]);
        assert_eq!(r.q_rad[5], 0.0, "no sixth joint");
        let e = MockArm::for_robot(
            &planar,
            MockConfig {
                initial_pose: "retract".into(),
                ..MockConfig::for_robot(&planar)
            },
        )
        .unwrap_err();
        assert_eq!(
            e.reason,
            "`retract` is not a named pose of planar5; use home"
        );
    }
}
