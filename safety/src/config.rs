//! The `[safety]` table of the graph TOML, checked against the robot at start-up.

use kinematics::{ArmLimits, RobotProfile};
use serde::{Deserialize, Serialize};

use crate::scene::SceneConfig;

/// Configuration of the filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Joint speed limits (rad/s), one per joint, at most the URDF's velocity limits.
    /// Default: the robot profile's teleoperation limits (`RobotProfile::limits`: its
    /// defaults capped by the URDF).
    pub max_velocity_rad_s: Vec<f64>,
    /// Joint acceleration limits (rad/s²), one per joint. Default: the robot profile's
    /// teleoperation accelerations.
    pub max_acceleration_rad_s2: Vec<f64>,
    /// Distance kept from each joint's position limits (rad).
    pub joint_margin_rad: f64,
    /// Scale applied to every command, in `(0, 1]`: 0.3 lets a new operator start slowly.
    pub speed_override: f64,
    /// Largest gripper rate passed on (1/s on the `c` scale).
    pub max_gripper_rate: f64,
    /// A command whose joystick sample is older than this stops the arm (ms). At least two
    /// periods (50 ms at 40 Hz: a sample answers the previous tick) and at most
    /// [`MAX_JOYSTICK_AGE_LIMIT_MS`].
    pub max_joystick_age_ms: f64,
    /// A command computed from a robot state older than this stops the arm (ms). Above 0 and
    /// shorter than the period; the graph's default is [`SafetyConfig::state_age_ms_for`]
    /// its period (20 ms at 40 Hz, 0.8 ms at 1 kHz).
    pub max_state_age_ms: f64,
    /// Require the joystick's deadman button to be held; released means stop.
    pub deadman: bool,
    /// Id of the mapper whose commands are forwarded at start; commands of any other id never
    /// reach the arm.
    pub active_mapper: u32,
    /// `[safety.workspace]`: where the tool may go.
    pub workspace: WorkspaceConfig,
    /// Below this distance between any checked pair of the collision model (every link
    /// against the others and the scene) an approaching command is slowed down (m).
    pub slowdown_distance_m: f64,
    /// No command brings a checked pair closer than this within the next tick, braking in
    /// time for it; a pair already closer may only move apart (m).
    pub stop_distance_m: f64,
    /// Largest linear speed of the tool and of every link capsule's ends (m/s).
    pub max_tcp_speed_m_s: f64,
    /// Largest angular speed of the tool (rad/s).
    pub max_tcp_angular_speed_rad_s: f64,
    /// `[safety.scene]`: the table and boxes the whole arm keeps clear of.
    pub scene: SceneConfig,
}

impl Default for SafetyConfig {
    /// [`SafetyConfig::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

impl SafetyConfig {
    /// The defaults for `robot`: [`SafetyConfig::from_limits`] of its teleoperation limits.
    pub fn for_robot(robot: &RobotProfile) -> Self {
        Self::from_limits(robot.limits())
    }

    /// The defaults for a robot with the teleoperation limits `limits` (velocity limits
    /// already capped by its URDF): its speed and acceleration limits, the rest the defaults.
    pub fn from_limits(limits: &ArmLimits) -> Self {
        Self {
            max_velocity_rad_s: limits.max_velocity_rad_s.clone(),
            max_acceleration_rad_s2: limits.max_acceleration_rad_s2.clone(),
            joint_margin_rad: 0.05,
            speed_override: 1.0,
            max_gripper_rate: 2.0,
            max_joystick_age_ms: 100.0,
            max_state_age_ms: 20.0,
            deadman: false,
            active_mapper: 1,
            workspace: WorkspaceConfig::default(),
            // MoveIt Servo starts slowing at 0.01 m (self) / 0.02 m (scene); we slow from
            // 10 cm and stop at 2 cm for every pair.
            slowdown_distance_m: 0.10,
            stop_distance_m: 0.02,
            // The collaborative-robot reduced speed, and Kinova's listed maximum translation
            // speed of the Gen3 lite (shared/reference/gen3-lite.md: 25 cm/s).
            max_tcp_speed_m_s: 0.25,
            // Kinova's twist-controller angular limit for the Gen3 lite (ros2_kortex
            // `twist_limits.yaml`: 0.85 rad/s).
            max_tcp_angular_speed_rad_s: 0.85,
            scene: SceneConfig::default(),
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

/// The largest `max_joystick_age_ms` accepted (ms): an operator's input older than half a
/// second is not trusted to move the arm, whatever the configuration.
pub const MAX_JOYSTICK_AGE_LIMIT_MS: f64 = 500.0;

/// A configuration value that cannot be used; the message names the key.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("safety.{key}: {reason}")]
pub struct ConfigError {
    /// The TOML key under `[safety]`.
    pub key: String,
    /// What is wrong with it.
    pub reason: String,
}

pub(crate) fn err(key: &str, reason: String) -> ConfigError {
    ConfigError {
        key: key.to_owned(),
        reason,
    }
}

pub(crate) fn positive(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(err(
            key,
            format!("is {v}; it must be a finite number above 0"),
        ))
    }
}

impl SafetyConfig {
    /// Checks the configuration for the default robot profile's arm with the joint limits
    /// `limits`: [`SafetyConfig::validate_for`] with that profile's URDF velocity limits.
    /// For the graph's robot, use [`SafetyConfig::validate_for_robot`].
    pub fn validate(&self, limits: &ArmLimits) -> Result<(), ConfigError> {
        self.validate_for(limits, RobotProfile::default_robot().urdf_velocity_rad_s())
    }

    /// Checks the configuration for `robot`: its limits and its URDF's velocity limits.
    pub fn validate_for_robot(&self, robot: &RobotProfile) -> Result<(), ConfigError> {
        self.validate_for(robot.limits(), robot.urdf_velocity_rad_s())
    }

    /// Checks the configuration for a robot with the joint limits `limits` whose robot
    /// description allows at most `urdf_velocity_rad_s` per joint: no configured speed may
    /// exceed it.
    pub fn validate_for(
        &self,
        limits: &ArmLimits,
        urdf_velocity_rad_s: &[f64],
    ) -> Result<(), ConfigError> {
        self.validate_joint_limits(limits, urdf_velocity_rad_s)?;
        if !(self.speed_override > 0.0 && self.speed_override <= 1.0) {
            return Err(err(
                "speed_override",
                format!(
                    "is {}; it must be a finite number in (0, 1]",
                    self.speed_override
                ),
            ));
        }
        positive("max_gripper_rate", self.max_gripper_rate)?;
        self.validate_workspace()?;
        crate::scene::validate(self)
    }

    /// The joint speed and acceleration limits (one positive finite number per joint, the
    /// speeds within the URDF's) and the joint margin (leaving each joint a range).
    fn validate_joint_limits(
        &self,
        limits: &ArmLimits,
        urdf_velocity_rad_s: &[f64],
    ) -> Result<(), ConfigError> {
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
                        format!("entry {i} is {v}; every limit must be a finite number above 0"),
                    ));
                }
            }
        }
        if urdf_velocity_rad_s.len() != n_joints {
            return Err(err(
                "max_velocity_rad_s",
                format!(
                    "the robot description has {} velocity limits for {n_joints} joints",
                    urdf_velocity_rad_s.len()
                ),
            ));
        }
        for (i, (v, urdf)) in self
            .max_velocity_rad_s
            .iter()
            .zip(urdf_velocity_rad_s)
            .enumerate()
        {
            if v > urdf {
                return Err(err(
                    "max_velocity_rad_s",
                    format!(
                        "entry {i} ({}) is {v} rad/s, above the URDF velocity limit {urdf} rad/s",
                        limits.names[i]
                    ),
                ));
            }
        }
        let m = self.joint_margin_rad;
        if !(m.is_finite() && m >= 0.0) {
            return Err(err(
                "joint_margin_rad",
                format!("is {m}; it must be a finite number, 0 or more"),
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
        Ok(())
    }

    /// `[safety.workspace]`: a positive deceleration, a box with finite corners, min below
    /// max, the table below its top.
    fn validate_workspace(&self) -> Result<(), ConfigError> {
        let w = &self.workspace;
        positive("workspace.deceleration_m_s2", w.deceleration_m_s2)?;
        for (key, corner) in [
            ("workspace.box_min_m", &w.box_min_m),
            ("workspace.box_max_m", &w.box_max_m),
        ] {
            if let Some(a) = corner.iter().position(|v| !v.is_finite()) {
                return Err(err(
                    key,
                    format!("axis {a} is {}; it must be a finite number", corner[a]),
                ));
            }
        }
        for i in 0..3 {
            if w.box_min_m[i] >= w.box_max_m[i] {
                return Err(err(
                    "workspace.box_min_m",
                    format!(
                        "axis {i}: {} .. {} is not a range (min must be below max)",
                        w.box_min_m[i], w.box_max_m[i]
                    ),
                ));
            }
        }
        if !w.table_z_m.is_finite() {
            return Err(err(
                "workspace.table_z_m",
                format!("is {}; it must be a finite number (m)", w.table_z_m),
            ));
        }
        if w.table_z_m >= w.box_max_m[2] {
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

    /// The default `max_state_age_ms` at a tick period of `period_s`: 80 % of the period, so a
    /// state from the previous tick is always stale and this tick's never is.
    pub fn state_age_ms_for(period_s: f64) -> f64 {
        800.0 * period_s
    }

    /// Checks the age limits against the tick period `period_s`: a limit that would disable
    /// its check (0, negative, not a number, or so long it never acts) or make it act on every
    /// tick is an error naming the key, never saturated silently.
    ///
    /// * `max_state_age_ms` in `(0, period)`: a state a period old is the previous tick's.
    /// * `max_joystick_age_ms` in `[2 periods, MAX_JOYSTICK_AGE_LIMIT_MS]`: the sample a
    ///   command uses answers the previous tick, so a younger limit stops a healthy graph.
    pub fn validate_ages(&self, period_s: f64) -> Result<(), ConfigError> {
        let period_ms = period_s * 1e3;
        let s = self.max_state_age_ms;
        if !(s.is_finite() && s > 0.0 && s < period_ms) {
            return Err(err(
                "max_state_age_ms",
                format!(
                    "is {s} ms; it must be above 0 and below the period ({period_ms} ms): \
                     a state a period old is the previous tick's"
                ),
            ));
        }
        let j = self.max_joystick_age_ms;
        let lo = 2.0 * period_ms;
        if !(j.is_finite() && j >= lo && j <= MAX_JOYSTICK_AGE_LIMIT_MS) {
            return Err(err(
                "max_joystick_age_ms",
                format!(
                    "is {j} ms; it must be from two periods ({lo} ms: a sample answers the \
                     previous tick) to {MAX_JOYSTICK_AGE_LIMIT_MS} ms"
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use kinematics::{Gen3Lite, gen3_lite};

    #[test]
    fn defaults_are_the_urdf_derived_limits() {
        let l = gen3_lite::limits();
        let d = SafetyConfig::default();
        assert_eq!(d, SafetyConfig::from_limits(&l));
        assert_eq!(d.max_velocity_rad_s, l.max_velocity_rad_s);
        assert_eq!(d.max_acceleration_rad_s2, l.max_acceleration_rad_s2);
        d.validate(&l).unwrap();
        // A description with a slower wrist caps the default speed, not the constant.
        let g = slow_wrist();
        let d = SafetyConfig::from_limits(&g.limits());
        assert_eq!(d.max_velocity_rad_s, [0.48, 0.48, 0.48, 0.76, 0.76, 1.0]);
        d.validate_for(&g.limits(), g.arm().velocity_limits())
            .unwrap();
    }

    #[test]
    fn age_limits_that_disable_their_check_are_refused_naming_the_key() {
        let d = SafetyConfig::default();
        d.validate_ages(0.025).unwrap();
        let key = |cfg: SafetyConfig, period: f64| cfg.validate_ages(period).unwrap_err().key;
        for bad in [0.0, -1.0, 25.0, 1e300, f64::NAN, f64::INFINITY] {
            let cfg = SafetyConfig {
                max_state_age_ms: bad,
                ..d.clone()
            };
            assert_eq!(key(cfg, 0.025), "max_state_age_ms", "{bad}");
        }
        for bad in [0.0, -5.0, 49.0, 500.1, 1e300, f64::NAN, f64::INFINITY] {
            let cfg = SafetyConfig {
                max_joystick_age_ms: bad,
                ..d.clone()
            };
            assert_eq!(key(cfg, 0.025), "max_joystick_age_ms", "{bad}");
        }
        // The bounds themselves are fine.
        for ok in [50.0, MAX_JOYSTICK_AGE_LIMIT_MS] {
            SafetyConfig {
                max_joystick_age_ms: ok,
                ..d.clone()
            }
            .validate_ages(0.025)
            .unwrap();
        }
        // The state's limit follows the period: 20 ms is too long at 100 Hz.
        assert_eq!(key(d.clone(), 0.01), "max_state_age_ms");
        // So does the filter, and the message says why.
        let e = crate::SafetyFilter::new(
            SafetyConfig {
                max_state_age_ms: 30.0,
                ..d
            },
            &gen3_lite::limits(),
            0.025,
        )
        .unwrap_err();
        assert_eq!(e.key, "max_state_age_ms");
        assert!(e.to_string().contains("below the period (25 ms)"), "{e}");
    }

    #[test]
    fn the_default_state_age_follows_the_period_at_40_hz_and_1_khz() {
        for rate_hz in [40.0, 1000.0] {
            let period_s = 1.0 / rate_hz;
            let ms = SafetyConfig::state_age_ms_for(period_s);
            let cfg = SafetyConfig {
                max_state_age_ms: ms,
                ..SafetyConfig::default()
            };
            cfg.validate_ages(period_s).unwrap();
            assert!(ms > 0.5 * period_s * 1e3 && ms < period_s * 1e3, "{ms}");
        }
        assert_eq!(SafetyConfig::state_age_ms_for(0.025), 20.0);
        assert!((SafetyConfig::state_age_ms_for(0.001) - 0.8).abs() < 1e-12);
        // The 40 Hz default is refused at 1 kHz: a configuration built for one rate does not
        // pass silently at another.
        let at_40 = SafetyConfig::default();
        assert_eq!(
            at_40.validate_ages(0.001).unwrap_err().key,
            "max_state_age_ms"
        );
    }

    proptest::proptest! {
        /// Any pair of age limits at any rate from 4 to 1000 Hz: accepted exactly when the
        /// state's is in (0, period) and the joystick's in [2 periods, 500 ms].
        #[test]
        fn age_limits_are_accepted_exactly_within_their_bounds(
            state_ms in proptest::prop_oneof![
                4 => -10.0f64..300.0,
                1 => proptest::strategy::Just(f64::NAN),
                1 => proptest::strategy::Just(f64::INFINITY),
            ],
            joystick_ms in proptest::prop_oneof![
                4 => -10.0f64..1000.0,
                1 => proptest::strategy::Just(f64::NAN),
                1 => proptest::strategy::Just(1e300),
            ],
            rate_hz in 4.0f64..1000.0,
        ) {
            let period_ms = 1e3 / rate_hz;
            let cfg = SafetyConfig {
                max_state_age_ms: state_ms,
                max_joystick_age_ms: joystick_ms,
                ..SafetyConfig::default()
            };
            let state_ok = state_ms > 0.0 && state_ms < period_ms;
            let joystick_ok =
                joystick_ms >= 2.0 * period_ms && joystick_ms <= MAX_JOYSTICK_AGE_LIMIT_MS;
            match cfg.validate_ages(1.0 / rate_hz) {
                Ok(()) => proptest::prop_assert!(state_ok && joystick_ok),
                Err(e) if !state_ok => proptest::prop_assert_eq!(e.key, "max_state_age_ms"),
                Err(e) => {
                    proptest::prop_assert!(!joystick_ok);
                    proptest::prop_assert_eq!(e.key, "max_joystick_age_ms");
                }
            }
        }
    }

    /// Every number of `[safety]` and its tables: NaN and the infinities are refused naming
    /// the key and saying it must be finite.
    #[test]
    fn non_finite_numbers_are_refused_naming_the_key() {
        type Set = fn(&mut SafetyConfig, f64);
        let keys: [(&str, Set); 16] = [
            ("max_velocity_rad_s", |c, v| c.max_velocity_rad_s[2] = v),
            ("max_acceleration_rad_s2", |c, v| {
                c.max_acceleration_rad_s2[0] = v
            }),
            ("joint_margin_rad", |c, v| c.joint_margin_rad = v),
            ("speed_override", |c, v| c.speed_override = v),
            ("max_gripper_rate", |c, v| c.max_gripper_rate = v),
            ("workspace.table_z_m", |c, v| c.workspace.table_z_m = v),
            ("workspace.box_min_m", |c, v| c.workspace.box_min_m[1] = v),
            ("workspace.box_max_m", |c, v| c.workspace.box_max_m[2] = v),
            ("workspace.deceleration_m_s2", |c, v| {
                c.workspace.deceleration_m_s2 = v
            }),
            ("slowdown_distance_m", |c, v| c.slowdown_distance_m = v),
            ("stop_distance_m", |c, v| c.stop_distance_m = v),
            ("max_tcp_speed_m_s", |c, v| c.max_tcp_speed_m_s = v),
            ("max_tcp_angular_speed_rad_s", |c, v| {
                c.max_tcp_angular_speed_rad_s = v
            }),
            ("scene.table_z_m", |c, v| c.scene.table_z_m = v),
            ("scene.boxes[0].min", |c, v| c.scene.boxes[0].min[0] = v),
            ("scene.boxes[0].max", |c, v| c.scene.boxes[0].max[2] = v),
        ];
        let l = gen3_lite::limits();
        let mut base = SafetyConfig::default();
        base.scene.boxes.push(crate::scene::BoxConfig {
            name: "mount".into(),
            min: [-0.5, -0.5, -0.3],
            max: [-0.3, -0.3, -0.01],
        });
        base.validate(&l).unwrap();
        for (key, set) in keys {
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                let mut cfg = base.clone();
                set(&mut cfg, bad);
                let e = cfg.validate(&l).unwrap_err();
                assert_eq!(e.key, key, "{key} = {bad}: {e}");
                assert!(e.reason.contains("finite"), "{key} = {bad}: {e}");
            }
        }
        // The message for a table at NaN says what is wrong (not "below the box top").
        let mut cfg = base;
        cfg.scene.table_z_m = f64::NAN;
        let e = cfg.validate(&l).unwrap_err().to_string();
        assert!(e.contains("scene.table_z_m") && e.contains("finite"), "{e}");
    }

    /// The Gen3 lite with its wrist's URDF velocity limit lowered from 3.2 to 1 rad/s.
    fn slow_wrist() -> Gen3Lite {
        let slow = gen3_lite::URDF.replace("velocity=\"3.2\"", "velocity=\"1.0\"");
        Gen3Lite::from_urdf_str(&slow, "slow.urdf").unwrap()
    }

    #[test]
    fn speeds_above_the_urdf_velocity_limits_are_refused() {
        let l = gen3_lite::limits();
        let urdf = Gen3Lite::get().arm().velocity_limits();
        assert_eq!(urdf, [1.6, 1.6, 1.6, 1.6, 1.6, 3.2]);
        // Up to the URDF's limits is allowed, also above the teleoperation defaults.
        let mut cfg = SafetyConfig {
            max_velocity_rad_s: urdf.to_vec(),
            ..SafetyConfig::default()
        };
        cfg.validate(&l).unwrap();
        cfg.max_velocity_rad_s[5] = 3.3;
        let e = cfg.validate(&l).unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert_eq!(
            e.to_string(),
            "safety.max_velocity_rad_s: entry 5 (joint_6) is 3.3 rad/s, \
             above the URDF velocity limit 3.2 rad/s"
        );
        // So does the filter.
        assert_eq!(crate::SafetyFilter::new(cfg, &l, 0.025).unwrap_err(), e);

        // A description with a slower wrist: the Gen3 lite default 1.52 rad/s is too fast.
        let g = slow_wrist();
        let e = SafetyConfig::default()
            .validate_for(&g.limits(), g.arm().velocity_limits())
            .unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert!(
            e.reason.contains("joint_6") && e.reason.contains("limit 1 rad/s"),
            "{e}"
        );

        // A description without a velocity limit per joint cannot be checked against.
        let e = SafetyConfig::default()
            .validate_for(&l, &urdf[..5])
            .unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
    }
}
