//! The `[safety]` table of the graph TOML, checked against the robot at start-up.

use kinematics::ArmLimits;
use serde::{Deserialize, Serialize};

/// Configuration of the filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Joint speed limits (rad/s), one per joint. Default: the Gen3 lite planning defaults.
    pub max_velocity_rad_s: Vec<f64>,
    /// Joint acceleration limits (rad/s²), one per joint. Default: the Gen3 lite simulator
    /// accelerations.
    pub max_acceleration_rad_s2: Vec<f64>,
    /// Distance kept from each joint's position limits (rad).
    pub joint_margin_rad: f64,
    /// Scale applied to every command, in `(0, 1]`: 0.3 lets a new operator start slowly.
    pub speed_override: f64,
    /// Largest gripper rate passed on (1/s on the `c` scale).
    pub max_gripper_rate: f64,
    /// A command whose joystick sample is older than this stops the arm (ms).
    pub max_joystick_age_ms: f64,
    /// A command computed from a robot state older than this stops the arm (ms). Must be
    /// shorter than the 25 ms period.
    pub max_state_age_ms: f64,
    /// Require the joystick's deadman button to be held; released means stop.
    pub deadman: bool,
    /// Id of the mapper whose commands are forwarded at start; commands of any other id never
    /// reach the arm.
    pub active_mapper: u32,
    /// `[safety.workspace]`: where the tool may go.
    pub workspace: WorkspaceConfig,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            max_velocity_rad_s: kinematics::gen3_lite::DEFAULT_VELOCITY_RAD_S.to_vec(),
            max_acceleration_rad_s2: kinematics::gen3_lite::DEFAULT_ACCELERATION_RAD_S2.to_vec(),
            joint_margin_rad: 0.05,
            speed_override: 1.0,
            max_gripper_rate: 2.0,
            max_joystick_age_ms: 100.0,
            max_state_age_ms: 20.0,
            deadman: false,
            active_mapper: 1,
            workspace: WorkspaceConfig::default(),
        }
    }
}

/// `[safety.workspace]`: bounds on the tool centre point, in the robot's base frame (m).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WorkspaceConfig {
    /// Enforce the bounds (needs the robot's forward kinematics).
    pub enabled: bool,
    /// The table plane: the tool stays above this height.
    pub table_z_m: f64,
    /// Lower corner of the box the tool stays in.
    pub box_min_m: [f64; 3],
    /// Upper corner of the box.
    pub box_max_m: [f64; 3],
    /// Deceleration used to approach a bound so the tool can stop at it (m/s²).
    pub deceleration_m_s2: f64,
}

impl Default for WorkspaceConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            table_z_m: 0.02,
            box_min_m: [-0.8, -0.8, -0.1],
            box_max_m: [0.8, 0.8, 1.1],
            deceleration_m_s2: 0.5,
        }
    }
}

/// A configuration value that cannot be used; the message names the key.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("safety.{key}: {reason}")]
pub struct ConfigError {
    /// The TOML key under `[safety]`.
    pub key: String,
    /// What is wrong with it.
    pub reason: String,
}

fn err(key: &str, reason: String) -> ConfigError {
    ConfigError {
        key: key.to_owned(),
        reason,
    }
}

fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(err(key, format!("is {v}; it must be a positive number")))
    }
}

impl SafetyConfig {
    /// Checks the configuration for a robot with the given joint limits.
    pub fn validate(&self, limits: &ArmLimits) -> Result<(), ConfigError> {
        let n_joints = limits.n_joints();
        for (key, values) in [
            ("max_velocity_rad_s", &self.max_velocity_rad_s),
            ("max_acceleration_rad_s2", &self.max_acceleration_rad_s2),
        ] {
            if values.len() != n_joints {
                return Err(err(
                    key,
                    format!(
                        "has {} entries, the robot has {n_joints} joints",
                        values.len()
                    ),
                ));
            }
            for (i, v) in values.iter().enumerate() {
                if !(v.is_finite() && *v > 0.0) {
                    return Err(err(
                        key,
                        format!("entry {i} is {v}; every limit must be a positive number"),
                    ));
                }
            }
        }
        let m = self.joint_margin_rad;
        if !(m.is_finite() && m >= 0.0) {
            return Err(err(
                "joint_margin_rad",
                format!("is {m}; it must be 0 or more"),
            ));
        }
        for j in 0..n_joints {
            let (lo, hi) = (limits.lower_rad[j], limits.upper_rad[j]);
            if 2.0 * m >= hi - lo {
                return Err(err(
                    "joint_margin_rad",
                    format!(
                        "{m} rad leaves no range for {} ({lo} .. {hi} rad)",
                        limits.names[j]
                    ),
                ));
            }
        }
        if !(self.speed_override > 0.0 && self.speed_override <= 1.0) {
            return Err(err(
                "speed_override",
                format!("is {}; it must be in (0, 1]", self.speed_override),
            ));
        }
        positive("max_gripper_rate", self.max_gripper_rate)?;
        positive("max_joystick_age_ms", self.max_joystick_age_ms)?;
        positive("max_state_age_ms", self.max_state_age_ms)?;
        let w = &self.workspace;
        positive("workspace.deceleration_m_s2", w.deceleration_m_s2)?;
        for i in 0..3 {
            if !(w.box_min_m[i].is_finite() && w.box_max_m[i].is_finite())
                || w.box_min_m[i] >= w.box_max_m[i]
            {
                return Err(err(
                    "workspace.box_min_m",
                    format!(
                        "axis {i}: {} .. {} is not a range (min must be below max)",
                        w.box_min_m[i], w.box_max_m[i]
                    ),
                ));
            }
        }
        if !w.table_z_m.is_finite() || w.table_z_m >= w.box_max_m[2] {
            return Err(err(
                "workspace.table_z_m",
                format!(
                    "{} must be below the box top ({} m)",
                    w.table_z_m, w.box_max_m[2]
                ),
            ));
        }
        Ok(())
    }
}
