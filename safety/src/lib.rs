//! The safety filter: a pure function of (command, newest robot state, configuration, time)
//! to (command, flags). The safety process is a thin loop around [`SafetyFilter::step`].
//!
//! What it does each tick: non-finite input -> stop, stale command / state / joystick sample
//! -> stop, joint velocity limits by one uniform scale factor (so the direction of the command,
//! and with it the span of the map, is kept), and acceleration limits: the change from the
//! previous output is scaled down as a whole until every joint's change fits its limit, so a
//! stop decelerates and a change of map (a live swap) never jumps. It also decides which
//! mapper is active, switching at a tick boundary. Joint position and workspace limits,
//! deadman and e-stop come with the full filter.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

use ipc_types::{MAX_JOINTS, MapperCommand, RobotState, SafeCommand, safe_flags};
use serde::{Deserialize, Serialize};

/// Configuration of the filter: the `[safety]` table of the graph TOML.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SafetyConfig {
    /// Joint speed limits (rad/s), one per joint. Default: the Gen3 lite planning defaults.
    pub max_velocity_rad_s: Vec<f64>,
    /// Joint acceleration limits (rad/s²), one per joint. Default: the Gen3 lite simulator
    /// accelerations.
    pub max_acceleration_rad_s2: Vec<f64>,
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
            max_acceleration_rad_s2: kinematics::gen3_lite::DEFAULT_ACCELERATION_RAD_S2.to_vec(),
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
        for (key, limits) in [
            ("max_velocity_rad_s", &self.max_velocity_rad_s),
            ("max_acceleration_rad_s2", &self.max_acceleration_rad_s2),
        ] {
            if limits.len() != n_joints {
                return Err(err(
                    key,
                    format!(
                        "has {} entries, the robot has {n_joints} joints",
                        limits.len()
                    ),
                ));
            }
            for (i, v) in limits.iter().enumerate() {
                if !(v.is_finite() && *v > 0.0) {
                    return Err(err(
                        key,
                        format!("entry {i} is {v}; every limit must be a positive number"),
                    ));
                }
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

/// The filter: its configuration and what it remembers between ticks (the previous output,
/// the active mapper and a pending switch).
#[derive(Debug, Clone)]
pub struct SafetyFilter {
    cfg: SafetyConfig,
    dt: f64,
    max_joystick_age_ns: u64,
    max_state_age_ns: u64,
    prev_tick: u64,
    prev_out: [f64; MAX_JOINTS],
    active: u32,
    pending: Option<(u32, u64)>,
    hold: bool,
}

fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6) as u64
}

impl SafetyFilter {
    /// A filter for `n_joints` joints ticking every `period_s` seconds; refuses an invalid
    /// configuration.
    pub fn new(cfg: SafetyConfig, n_joints: usize, period_s: f64) -> Result<Self, ConfigError> {
        cfg.validate(n_joints)?;
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(ConfigError {
                key: "period".into(),
                reason: format!("{period_s} s is not a positive period"),
            });
        }
        Ok(Self {
            max_joystick_age_ns: ms_to_ns(cfg.max_joystick_age_ms),
            max_state_age_ns: ms_to_ns(cfg.max_state_age_ms),
            dt: period_s,
            prev_tick: ipc_types::NO_TICK,
            prev_out: [0.0; MAX_JOINTS],
            active: cfg.active_mapper,
            pending: None,
            hold: false,
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SafetyConfig {
        &self.cfg
    }

    /// Asks for mapper `id` to become active from tick `from_tick` on (a tick boundary: the
    /// command of `from_tick - 1` still comes from the old mapper).
    pub fn request_switch(&mut self, id: u32, from_tick: u64) {
        self.pending = Some((id, from_tick));
    }

    /// The mapper whose command is forwarded at `tick`, applying a pending switch that is due.
    pub fn active_for_tick(&mut self, tick: u64) -> u32 {
        if let Some((id, from)) = self.pending
            && tick >= from
        {
            self.active = id;
            self.pending = None;
        }
        self.active
    }

    /// Holds the arm (every output a controlled stop, flagged [`safe_flags::HOLD`]) until
    /// released.
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// The active mapper as of the last tick handled.
    pub fn active(&self) -> u32 {
        self.active
    }

    /// Filters `cmd` against the newest robot state `state` at time `now_ns`.
    ///
    /// Returns the command to execute at `cmd.tick` with [`SafeCommand::flags`] naming every
    /// rule that acted. A fault makes the target zero (a stop); the acceleration limit then
    /// turns it into a deceleration. Times `t_ns` / `compute_ns` are left at 0 for the caller
    /// to stamp.
    pub fn step(&mut self, cmd: &MapperCommand, state: &RobotState, now_ns: u64) -> SafeCommand {
        let n = self.cfg.max_velocity_rad_s.len();
        let mut flags = 0;
        let mut target = [0.0; MAX_JOINTS];
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
        if self.hold {
            flags |= safe_flags::HOLD;
        }

        if flags == 0 {
            target[..n].copy_from_slice(&cmd.qdot_rad_s[..n]);
            let scale = uniform_scale(&target[..n], &self.cfg.max_velocity_rad_s);
            if scale < 1.0 {
                flags |= safe_flags::VELOCITY_SCALED;
                target[..n].iter_mut().for_each(|v| *v *= scale);
            }
            gripper = cmd
                .gripper_rate
                .clamp(-self.cfg.max_gripper_rate, self.cfg.max_gripper_rate);
        } else {
            flags |= safe_flags::STOP;
        }

        // The velocity the arm has now: our previous output if the bridge executed it,
        // otherwise what the robot reports (after a miss the bridge was stopping).
        let mut base = [0.0; MAX_JOINTS];
        let executed = self.prev_tick != ipc_types::NO_TICK
            && state.applied_tick == self.prev_tick
            && cmd.tick == self.prev_tick.wrapping_add(1);
        if executed {
            base[..n].copy_from_slice(&self.prev_out[..n]);
        } else if state.qdot_rad_s[..n].iter().all(|v| v.is_finite()) {
            base[..n].copy_from_slice(&state.qdot_rad_s[..n]);
        }
        let mut out = target;
        if limit_change(
            &base[..n],
            &mut out[..n],
            &self.cfg.max_acceleration_rad_s2,
            self.dt,
        ) {
            flags |= safe_flags::ACCEL_LIMITED;
        }
        self.prev_tick = cmd.tick;
        self.prev_out = out;

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
            qdot_rad_s: out,
            gripper_rate: gripper,
        }
    }
}

/// Limits the change from `base` to `out` (in place) so that every joint changes by at most
/// `accel_j * dt`, scaling the whole change by one factor: the result lies on the segment from
/// `base` to the requested `out`. Returns whether it acted.
pub fn limit_change(base: &[f64], out: &mut [f64], accel: &[f64], dt: f64) -> bool {
    let mut k: f64 = 1.0;
    for ((b, o), a) in base.iter().zip(out.iter()).zip(accel) {
        let d = (o - b).abs();
        if d > a * dt {
            k = k.min(a * dt / d);
        }
    }
    if k < 1.0 {
        for (b, o) in base.iter().zip(out.iter_mut()) {
            *o = b + k * (*o - b);
        }
        true
    } else {
        false
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
    const DT: f64 = 0.025;

    fn state(tick: u64) -> RobotState {
        let mut s = RobotState::at_rest(tick, NOW - 1_000_000, 6);
        s.applied_tick = tick.wrapping_sub(1);
        s
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

    /// Default limits.
    fn filter() -> SafetyFilter {
        SafetyFilter::new(SafetyConfig::default(), 6, DT).unwrap()
    }

    /// Acceleration limits out of the way, to test the other rules alone.
    fn filter_without_accel_limit() -> SafetyFilter {
        let cfg = SafetyConfig {
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        SafetyFilter::new(cfg, 6, DT).unwrap()
    }

    #[test]
    fn passes_a_good_command_unchanged() {
        let c = cmd(5, [0.1, -0.2, 0.0, 0.3, 0.0, 0.1]);
        let out = filter_without_accel_limit().step(&c, &state(5), NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s, c.qdot_rad_s);
        assert_eq!(out.tick, 5);
        assert_eq!(out.mapper_t_ns, c.t_ns);
        assert_eq!(out.gripper_rate, 0.5);
    }

    #[test]
    fn scales_uniformly_to_the_tightest_limit() {
        let c = cmd(5, [0.96, 0.0, 0.0, 0.38, 0.0, 0.0]);
        let out = filter_without_accel_limit().step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::VELOCITY_SCALED);
        assert!((out.qdot_rad_s[0] - 0.48).abs() < 1e-12);
        assert!((out.qdot_rad_s[3] - 0.19).abs() < 1e-12);
    }

    #[test]
    fn stops_on_each_fault() {
        let mut f = filter_without_accel_limit();
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
    fn acceleration_is_limited_and_a_stop_decelerates() {
        let mut f = filter();
        let accel = kinematics::gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
        let want = [0.4, -0.4, 0.2, 0.0, 0.5, 0.0];
        let mut prev = [0.0; 6];
        let mut reached = None;
        for k in 1..200u64 {
            let out = f.step(&cmd(k, want), &state(k), NOW);
            for j in 0..6 {
                let dv = (out.qdot_rad_s[j] - prev[j]).abs();
                assert!(dv <= accel[j] * DT + 1e-12, "tick {k} joint {j}: {dv}");
                prev[j] = out.qdot_rad_s[j];
            }
            if out.flags == 0 {
                reached = Some(k);
                break;
            }
            assert_eq!(out.flags, safe_flags::ACCEL_LIMITED);
        }
        // Joint 2 (0.4 rad/s at 0.5 rad/s²) sets the ramp: 0.8 s = 32 ticks.
        assert_eq!(reached, Some(32));
        assert_eq!(&prev, &want);
        // A fault: the output decelerates toward zero within the limits.
        let mut c = cmd(33, want);
        c.qdot_rad_s[0] = f64::NAN;
        let out = f.step(&c, &state(33), NOW);
        assert_eq!(
            out.flags,
            safe_flags::NON_FINITE | safe_flags::STOP | safe_flags::ACCEL_LIMITED
        );
        for j in 0..6 {
            assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * DT + 1e-12);
            assert!(out.qdot_rad_s[j].abs() <= prev[j].abs());
        }
    }

    #[test]
    fn after_a_miss_the_ramp_starts_from_the_measured_velocity() {
        let mut f = filter();
        f.step(&cmd(1, [0.0; 6]), &state(1), NOW);
        // Tick 2 was missed: the state of tick 3 reports no command applied and the robot
        // moving at 0.3 rad/s on joint 0.
        let mut s = state(3);
        s.applied_tick = ipc_types::NO_TICK;
        s.qdot_rad_s[0] = 0.3;
        let out = f.step(&cmd(3, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &s, NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s[0], 0.3);
    }

    #[test]
    fn a_hold_stops_until_released() {
        let mut f = filter_without_accel_limit();
        f.set_hold(true);
        let out = f.step(&cmd(5, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::HOLD | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
        f.set_hold(false);
        let out = f.step(&cmd(6, [0.1; 6]), &state(6), NOW);
        assert_eq!(out.flags, 0);
    }

    #[test]
    fn switches_mapper_at_the_requested_tick() {
        let mut f = filter();
        assert_eq!(f.active_for_tick(10), 1);
        f.request_switch(2, 12);
        assert_eq!(f.active_for_tick(11), 1);
        assert_eq!(f.active_for_tick(12), 2);
        assert_eq!(f.active_for_tick(13), 2);
        assert_eq!(f.active(), 2);
    }

    #[test]
    fn config_errors_name_the_key() {
        let mut cfg = SafetyConfig::default();
        cfg.max_velocity_rad_s[3] = -1.0;
        let e = SafetyFilter::new(cfg, 6, DT).unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert!(
            e.to_string()
                .starts_with("safety.max_velocity_rad_s: entry 3 is -1")
        );
        let e = SafetyFilter::new(SafetyConfig::default(), 7, DT).unwrap_err();
        assert!(e.reason.contains("7 joints"));
        let cfg = SafetyConfig {
            max_joystick_age_ms: 0.0,
            ..SafetyConfig::default()
        };
        assert_eq!(
            SafetyFilter::new(cfg, 6, DT).unwrap_err().key,
            "max_joystick_age_ms"
        );
        let cfg = SafetyConfig {
            max_acceleration_rad_s2: vec![1.0; 5],
            ..SafetyConfig::default()
        };
        assert_eq!(
            SafetyFilter::new(cfg, 6, DT).unwrap_err().key,
            "max_acceleration_rad_s2"
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
            cmds in proptest::collection::vec(
                (proptest::array::uniform6(any_f64()), any_f64(), 0u64..2, any::<bool>()),
                1..20,
            ),
        ) {
            let mut f = filter();
            let vmax = f.config().max_velocity_rad_s.clone();
            let amax = f.config().max_acceleration_rad_s2.clone();
            let mut prev = [0.0; MAX_JOINTS];
            for (k, (qdot, gripper, stale, executed)) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut c = cmd(tick, qdot);
                c.gripper_rate = gripper;
                // The arm moves at the last output (whether or not the bridge reports it as
                // executed: after a miss its controlled stop starts from there).
                let mut s = state(tick + stale);
                s.qdot_rad_s = prev;
                if !executed {
                    s.applied_tick = ipc_types::NO_TICK;
                }
                let out = f.step(&c, &s, NOW);
                for j in 0..6 {
                    prop_assert!(out.qdot_rad_s[j].is_finite());
                    prop_assert!(out.qdot_rad_s[j].abs() <= vmax[j] * (1.0 + 1e-12));
                    prop_assert!((out.qdot_rad_s[j] - prev[j]).abs() <= amax[j] * DT * (1.0 + 1e-9));
                }
                prop_assert!(out.gripper_rate.is_finite());
                prop_assert!(out.gripper_rate.abs() <= f.config().max_gripper_rate);
                prop_assert!(out.qdot_rad_s[6..].iter().all(|v| *v == 0.0));
                prev = out.qdot_rad_s;
            }
        }

        #[test]
        fn velocity_scaling_keeps_direction(qdot in proptest::array::uniform6(-5.0f64..5.0)) {
            // From rest the acceleration limit scales the change from zero, so the output is
            // still a positive multiple of the input.
            let mut f = filter();
            let out = f.step(&cmd(5, qdot), &state(5), NOW);
            prop_assert_eq!(
                out.flags & !(safe_flags::VELOCITY_SCALED | safe_flags::ACCEL_LIMITED),
                0
            );
            let n_in: f64 = qdot.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n_in > 1e-9 {
                let dot: f64 = (0..6).map(|j| qdot[j] * out.qdot_rad_s[j]).sum();
                let n_out: f64 = out.qdot_rad_s.iter().map(|v| v * v).sum::<f64>().sqrt();
                prop_assert!((dot - n_in * n_out).abs() <= 1e-9 * n_in * n_out.max(1e-12) + 1e-15);
            }
        }
    }
}
