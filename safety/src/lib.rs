//! The safety filter: a pure function of (command, newest robot state, configuration, time)
//! to (command, flags). The safety process is a thin loop around [`SafetyFilter::step`].
//!
//! This is the minimal filter of the foundation: non-finite input -> stop, stale command /
//! state / joystick sample -> stop, joint velocity limits by one uniform scale factor (so the
//! direction of the command, and with it the span of the map, is kept). Joint position,
//! acceleration and workspace limits, deadman and e-stop come with the full filter.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

use ipc_types::{MAX_JOINTS, MapperCommand, RobotState, SafeCommand, safe_flags};
use serde::{Deserialize, Serialize};

/// Configuration of the filter: the `[safety]` table of the graph TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Joint speed limits (rad/s), one per joint. Default: the Gen3 lite planning defaults.
    pub max_velocity_rad_s: Vec<f64>,
    /// Largest gripper rate passed on (1/s on the `c` scale).
    pub max_gripper_rate: f64,
    /// A command whose joystick sample is older than this stops the arm (ms).
    pub max_joystick_age_ms: f64,
    /// A command computed from a robot state older than this stops the arm (ms). Must be
    /// shorter than the 25 ms period.
    pub max_state_age_ms: f64,
    /// Id of the mapper whose commands are forwarded; commands of any other id never reach
    /// the arm.
    pub active_mapper: u32,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            max_velocity_rad_s: kinematics::gen3_lite::DEFAULT_VELOCITY_RAD_S.to_vec(),
            max_gripper_rate: 2.0,
            max_joystick_age_ms: 100.0,
            max_state_age_ms: 20.0,
            active_mapper: 1,
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

impl SafetyConfig {
    /// Checks the configuration for a robot with `n_joints` joints.
    pub fn validate(&self, n_joints: usize) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError {
            key: key.to_owned(),
            reason,
        };
        if self.max_velocity_rad_s.len() != n_joints {
            return Err(err(
                "max_velocity_rad_s",
                format!(
                    "has {} entries, the robot has {n_joints} joints",
                    self.max_velocity_rad_s.len()
                ),
            ));
        }
        for (i, v) in self.max_velocity_rad_s.iter().enumerate() {
            if !(v.is_finite() && *v > 0.0) {
                return Err(err(
                    "max_velocity_rad_s",
                    format!("entry {i} is {v}; every limit must be a positive number"),
                ));
            }
        }
        let positive = [
            ("max_gripper_rate", self.max_gripper_rate),
            ("max_joystick_age_ms", self.max_joystick_age_ms),
            ("max_state_age_ms", self.max_state_age_ms),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(err(key, format!("is {v}; it must be a positive number")));
            }
        }
        Ok(())
    }
}

/// The filter and its configuration.
#[derive(Debug, Clone)]
pub struct SafetyFilter {
    cfg: SafetyConfig,
    max_joystick_age_ns: u64,
    max_state_age_ns: u64,
}

fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6) as u64
}

impl SafetyFilter {
    /// A filter for `n_joints` joints; refuses an invalid configuration.
    pub fn new(cfg: SafetyConfig, n_joints: usize) -> Result<Self, ConfigError> {
        cfg.validate(n_joints)?;
        Ok(Self {
            max_joystick_age_ns: ms_to_ns(cfg.max_joystick_age_ms),
            max_state_age_ns: ms_to_ns(cfg.max_state_age_ms),
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SafetyConfig {
        &self.cfg
    }

    /// Whether commands of mapper `id` are forwarded.
    pub fn is_active(&self, id: u32) -> bool {
        id == self.cfg.active_mapper
    }

    /// Filters `cmd` against the newest robot state `state` at time `now_ns`.
    ///
    /// Returns the command to execute at `cmd.tick` with [`SafeCommand::flags`] naming every
    /// rule that acted. A stop is a zero velocity. Times `t_ns` / `compute_ns` are left at 0
    /// for the caller to stamp.
    pub fn step(&self, cmd: &MapperCommand, state: &RobotState, now_ns: u64) -> SafeCommand {
        let n = self.cfg.max_velocity_rad_s.len();
        let mut flags = 0;
        let mut qdot = [0.0; MAX_JOINTS];
        let mut gripper = 0.0;

        if cmd.n_joints as usize != n || state.n_joints as usize != n {
            flags |= safe_flags::BAD_SHAPE;
        }
        let finite = cmd.qdot_rad_s.iter().all(|v| v.is_finite())
            && cmd.gripper_rate.is_finite()
            && state.q_rad.iter().all(|v| v.is_finite());
        if !finite {
            flags |= safe_flags::NON_FINITE;
        }
        if cmd.tick != state.tick {
            flags |= safe_flags::STALE_COMMAND;
        }
        if now_ns.saturating_sub(cmd.state_t_ns) > self.max_state_age_ns {
            flags |= safe_flags::STALE_STATE;
        }
        if cmd.joystick_t_ns != 0
            && now_ns.saturating_sub(cmd.joystick_t_ns) > self.max_joystick_age_ns
        {
            flags |= safe_flags::STALE_JOYSTICK;
        }

        if flags == 0 {
            qdot[..n].copy_from_slice(&cmd.qdot_rad_s[..n]);
            let scale = uniform_scale(&qdot[..n], &self.cfg.max_velocity_rad_s);
            if scale < 1.0 {
                flags |= safe_flags::VELOCITY_SCALED;
                qdot[..n].iter_mut().for_each(|v| *v *= scale);
            }
            gripper = cmd
                .gripper_rate
                .clamp(-self.cfg.max_gripper_rate, self.cfg.max_gripper_rate);
        } else {
            flags |= safe_flags::STOP;
        }

        SafeCommand {
            tick: cmd.tick,
            t_ns: 0,
            state_t_ns: cmd.state_t_ns,
            joystick_t_ns: cmd.joystick_t_ns,
            mapper_t_ns: cmd.t_ns,
            mapper_compute_ns: cmd.compute_ns,
            compute_ns: 0,
            mapper_id: cmd.mapper_id,
            n_joints: n as u32,
            flags,
            reserved: 0,
            qdot_rad_s: qdot,
            gripper_rate: gripper,
        }
    }
}

/// The largest factor `<= 1` that brings every `|qdot_j|` within `limit_j`: one factor for all
/// joints, so the direction of `qdot` is kept.
pub fn uniform_scale(qdot: &[f64], limit: &[f64]) -> f64 {
    qdot.iter()
        .zip(limit)
        .filter(|(v, _)| v.abs() > 0.0)
        .map(|(v, l)| l / v.abs())
        .fold(1.0, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const NOW: u64 = 1_000_000_000;

    fn state(tick: u64) -> RobotState {
        RobotState::at_rest(tick, NOW - 1_000_000, 6)
    }

    fn cmd(tick: u64, qdot: [f64; 6]) -> MapperCommand {
        let mut q = [0.0; MAX_JOINTS];
        q[..6].copy_from_slice(&qdot);
        MapperCommand {
            tick,
            t_ns: NOW - 500_000,
            state_t_ns: NOW - 1_000_000,
            joystick_t_ns: NOW - 10_000_000,
            joystick_seq: 1,
            compute_ns: 100,
            mapper_id: 1,
            n_joints: 6,
            flags: 0,
            reserved: 0,
            action: [0.0; 2],
            qdot_rad_s: q,
            gripper_rate: 0.5,
        }
    }

    fn filter() -> SafetyFilter {
        SafetyFilter::new(SafetyConfig::default(), 6).unwrap()
    }

    #[test]
    fn passes_a_good_command_unchanged() {
        let c = cmd(5, [0.1, -0.2, 0.0, 0.3, 0.0, 0.1]);
        let out = filter().step(&c, &state(5), NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s, c.qdot_rad_s);
        assert_eq!(out.tick, 5);
        assert_eq!(out.mapper_t_ns, c.t_ns);
        assert_eq!(out.gripper_rate, 0.5);
    }

    #[test]
    fn scales_uniformly_to_the_tightest_limit() {
        let c = cmd(5, [0.96, 0.0, 0.0, 0.38, 0.0, 0.0]);
        let out = filter().step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::VELOCITY_SCALED);
        assert!((out.qdot_rad_s[0] - 0.48).abs() < 1e-12);
        assert!((out.qdot_rad_s[3] - 0.19).abs() < 1e-12);
    }

    #[test]
    fn stops_on_each_fault() {
        let f = filter();
        let mut c = cmd(5, [0.1; 6]);
        c.qdot_rad_s[2] = f64::NAN;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::NON_FINITE | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));

        let out = f.step(&cmd(4, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_COMMAND | safe_flags::STOP);

        let mut c = cmd(5, [0.1; 6]);
        c.joystick_t_ns = NOW - 150_000_000;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_JOYSTICK | safe_flags::STOP);
        assert_eq!(out.gripper_rate, 0.0);

        let mut c = cmd(5, [0.1; 6]);
        c.state_t_ns = NOW - 30_000_000;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_STATE | safe_flags::STOP);

        let mut c = cmd(5, [0.1; 6]);
        c.n_joints = 7;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::BAD_SHAPE | safe_flags::STOP);
    }

    #[test]
    fn no_joystick_sample_yet_is_not_stale() {
        let mut c = cmd(5, [0.0; 6]);
        c.joystick_t_ns = 0;
        assert_eq!(filter().step(&c, &state(5), NOW).flags, 0);
    }

    #[test]
    fn config_errors_name_the_key() {
        let mut cfg = SafetyConfig::default();
        cfg.max_velocity_rad_s[3] = -1.0;
        let e = SafetyFilter::new(cfg, 6).unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert!(
            e.to_string()
                .starts_with("safety.max_velocity_rad_s: entry 3 is -1")
        );
        let e = SafetyFilter::new(SafetyConfig::default(), 7).unwrap_err();
        assert!(e.reason.contains("7 joints"));
        let cfg = SafetyConfig {
            max_joystick_age_ms: 0.0,
            ..SafetyConfig::default()
        };
        assert_eq!(
            SafetyFilter::new(cfg, 6).unwrap_err().key,
            "max_joystick_age_ms"
        );
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            4 => -10.0f64..10.0,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(f64::NEG_INFINITY),
            1 => Just(1e300),
            1 => Just(-1e-300),
        ]
    }

    proptest! {
        #[test]
        fn output_is_finite_and_within_limits(
            qdot in proptest::array::uniform6(any_f64()),
            gripper in any_f64(),
            tick_offset in 0u64..2,
        ) {
            let f = filter();
            let mut c = cmd(5, qdot);
            c.gripper_rate = gripper;
            let out = f.step(&c, &state(5 + tick_offset), NOW);
            let lim = &f.config().max_velocity_rad_s;
            for j in 0..6 {
                prop_assert!(out.qdot_rad_s[j].is_finite());
                prop_assert!(out.qdot_rad_s[j].abs() <= lim[j] * (1.0 + 1e-12));
            }
            prop_assert!(out.gripper_rate.is_finite());
            prop_assert!(out.gripper_rate.abs() <= f.config().max_gripper_rate);
            prop_assert!(out.qdot_rad_s[6..].iter().all(|v| *v == 0.0));
        }

        #[test]
        fn velocity_scaling_keeps_direction(qdot in proptest::array::uniform6(-5.0f64..5.0)) {
            let f = filter();
            let out = f.step(&cmd(5, qdot), &state(5), NOW);
            prop_assert_eq!(out.flags & !safe_flags::VELOCITY_SCALED, 0);
            // out = k * in with one k in (0, 1].
            let n_in: f64 = qdot.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n_in > 1e-9 {
                let dot: f64 = (0..6).map(|j| qdot[j] * out.qdot_rad_s[j]).sum();
                let n_out: f64 = out.qdot_rad_s.iter().map(|v| v * v).sum::<f64>().sqrt();
                prop_assert!((dot - n_in * n_out).abs() <= 1e-9 * n_in * n_out.max(1e-12) + 1e-15);
            }
        }
    }
}
