//! The safety filter: the last word before the arm. A pure function of (command, newest
//! robot state, configuration, time) to (command, flags), with a little memory between ticks
//! (the previous output, the active mapper, a latched e-stop). The safety process is a thin
//! loop around [`SafetyFilter::step`].
//!
//! Each tick, in this order:
//! 1. Faults stop the arm: a non-finite value, a mis-shaped command, a stale robot state,
//!    joystick sample or command, a supervisor hold, a released deadman. The target becomes
//!    zero and the acceleration limit turns that into a controlled stop.
//! 2. A latched e-stop (joystick button or `scl estop`, released only by `scl reset`)
//!    commands zero at once, the one rule that does not wait for the acceleration limit.
//! 3. The speed override, then the joint velocity limits by one uniform factor (the command
//!    keeps its direction, and so stays in the span of the map).
//! 4. Joint position limits less a margin and workspace bounds on the tool (table plane,
//!    box): a joint or the tool may approach a bound no faster than it can stop before it;
//!    motion away from a bound is free. Both scale the whole command.
//! 5. The acceleration limits: the change from the arm's current velocity is scaled as a
//!    whole until every joint's change fits.
//! 6. Hard guarantees last: no joint past its margin and the tool not out of the workspace
//!    within the next tick, even where that means braking harder than the acceleration
//!    limit (only possible when the arm was already too fast, e.g. after a fault elsewhere).
//!
//! Every rule that acted sets its bit in [`SafeCommand::flags`]; the filter counts them.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod config;
pub mod rules;

pub use config::{ConfigError, SafetyConfig, WorkspaceConfig};
pub use rules::{Bounds, ChainTcp, TcpModel, limit_change, uniform_scale};

use ipc_types::{
    MAX_JOINTS, MapperCommand, NO_TICK, RobotState, SafeCommand, buttons, mapper_flags, safe_flags,
};
use kinematics::ArmLimits;

/// Slack kept inside the configured workspace bounds (m): the rule predicts the tool's motion
/// to first order over one tick, and this covers the second-order rest.
pub const WORKSPACE_SLACK_M: f64 = 0.001;

/// The filter: its configuration and what it remembers between ticks.
pub struct SafetyFilter {
    cfg: SafetyConfig,
    dt: f64,
    n: usize,
    lower: [f64; MAX_JOINTS],
    upper: [f64; MAX_JOINTS],
    vmax: [f64; MAX_JOINTS],
    amax: [f64; MAX_JOINTS],
    max_joystick_age_ns: u64,
    max_state_age_ns: u64,
    prev_tick: u64,
    prev_out: [f64; MAX_JOINTS],
    active: u32,
    pending: Option<(u32, u64)>,
    hold: bool,
    estop: bool,
    tcp: Option<Box<dyn TcpModel>>,
    bounds: Bounds,
    counts: [u32; 16],
}

impl std::fmt::Debug for SafetyFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SafetyFilter")
            .field("cfg", &self.cfg)
            .field("active", &self.active)
            .field("estop", &self.estop)
            .field("hold", &self.hold)
            .field("workspace_model", &self.tcp.is_some())
            .finish()
    }
}

fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6) as u64
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SafetyFilter {
    /// A filter for an arm with `limits`, ticking every `period_s` seconds; refuses an
    /// invalid configuration. Without [`SafetyFilter::with_tcp_model`] the workspace rule is
    /// inactive.
    pub fn new(cfg: SafetyConfig, limits: &ArmLimits, period_s: f64) -> Result<Self, ConfigError> {
        cfg.validate(limits)?;
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(ConfigError {
                key: "period".into(),
                reason: format!("{period_s} s is not a positive period"),
            });
        }
        let n = limits.n_joints().min(MAX_JOINTS);
        let mut f = Self {
            dt: period_s,
            n,
            lower: [0.0; MAX_JOINTS],
            upper: [0.0; MAX_JOINTS],
            vmax: [0.0; MAX_JOINTS],
            amax: [0.0; MAX_JOINTS],
            max_joystick_age_ns: ms_to_ns(cfg.max_joystick_age_ms),
            max_state_age_ns: ms_to_ns(cfg.max_state_age_ms),
            prev_tick: NO_TICK,
            prev_out: [0.0; MAX_JOINTS],
            active: cfg.active_mapper,
            pending: None,
            hold: false,
            estop: false,
            tcp: None,
            bounds: Bounds::new(0.0, [0.0; 3], [0.0; 3]),
            counts: [0; 16],
            cfg,
        };
        let w = &f.cfg.workspace;
        let s = WORKSPACE_SLACK_M;
        f.bounds = Bounds::new(
            w.table_z_m + s,
            [w.box_min_m[0] + s, w.box_min_m[1] + s, w.box_min_m[2] + s],
            [w.box_max_m[0] - s, w.box_max_m[1] - s, w.box_max_m[2] - s],
        );
        for j in 0..n {
            f.lower[j] = limits.lower_rad[j] + f.cfg.joint_margin_rad;
            f.upper[j] = limits.upper_rad[j] - f.cfg.joint_margin_rad;
            f.vmax[j] = f.cfg.max_velocity_rad_s[j];
            f.amax[j] = f.cfg.max_acceleration_rad_s2[j];
        }
        Ok(f)
    }

    /// Enables the workspace rule with the robot's forward kinematics.
    pub fn with_tcp_model(mut self, model: Box<dyn TcpModel>) -> Self {
        self.tcp = Some(model);
        self
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

    /// The active mapper as of the last tick handled.
    pub fn active(&self) -> u32 {
        self.active
    }

    /// Holds the arm (every output a controlled stop, flagged [`safe_flags::HOLD`]) until
    /// released.
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// Whether the supervisor holds the arm.
    pub fn held(&self) -> bool {
        self.hold
    }

    /// Latches the e-stop: zero velocity from the next tick on, until [`SafetyFilter::reset`].
    pub fn estop(&mut self) {
        self.estop = true;
    }

    /// Releases a latched e-stop.
    pub fn reset(&mut self) {
        self.estop = false;
    }

    /// Whether the e-stop is latched.
    pub fn estopped(&self) -> bool {
        self.estop
    }

    /// How many ticks each rule acted, by bit of [`safe_flags`].
    pub fn rule_counts(&self) -> [u32; 16] {
        self.counts
    }

    /// Filters `cmd` against the newest robot state `state` at time `now_ns`.
    ///
    /// Returns the command to execute at `cmd.tick` with [`SafeCommand::flags`] naming every
    /// rule that acted. Times `t_ns` / `compute_ns` are left at 0 for the caller to stamp.
    pub fn step(&mut self, cmd: &MapperCommand, state: &RobotState, now_ns: u64) -> SafeCommand {
        let n = self.n;
        let mut flags = 0;

        if cmd.n_joints as usize != n || state.n_joints as usize != n {
            flags |= safe_flags::BAD_SHAPE;
        }
        let q_ok = all_finite(&state.q_rad[..n]);
        if !(all_finite(&cmd.qdot_rad_s) && cmd.gripper_rate.is_finite() && q_ok) {
            flags |= safe_flags::NON_FINITE;
        }
        if cmd.tick != state.tick {
            flags |= safe_flags::STALE_COMMAND;
        }
        if now_ns.saturating_sub(cmd.state_t_ns) > self.max_state_age_ns {
            flags |= safe_flags::STALE_STATE;
        }
        if (cmd.joystick_t_ns != 0
            && now_ns.saturating_sub(cmd.joystick_t_ns) > self.max_joystick_age_ns)
            || cmd.flags & mapper_flags::INPUT_STALE != 0
        {
            flags |= safe_flags::STALE_JOYSTICK;
        }
        if self.hold {
            flags |= safe_flags::HOLD;
        }
        if self.cfg.deadman && cmd.buttons & buttons::DEADMAN == 0 {
            flags |= safe_flags::DEADMAN;
        }
        if cmd.buttons & buttons::ESTOP != 0 {
            self.estop = true;
        }
        if self.estop {
            flags |= safe_flags::ESTOP;
        }
        let stop = flags != 0;

        // The velocity the arm has now: our previous output if the bridge executed it,
        // otherwise what the robot reports; never more than the limits.
        let mut base = [0.0; MAX_JOINTS];
        let executed = self.prev_tick != NO_TICK
            && state.applied_tick == self.prev_tick
            && cmd.tick == self.prev_tick.wrapping_add(1);
        if executed {
            base[..n].copy_from_slice(&self.prev_out[..n]);
        } else if all_finite(&state.qdot_rad_s[..n]) {
            base[..n].copy_from_slice(&state.qdot_rad_s[..n]);
        }
        for (b, v) in base.iter_mut().zip(&self.vmax).take(n) {
            *b = b.clamp(-v, *v);
        }

        let mut out = [0.0; MAX_JOINTS];
        if flags & safe_flags::ESTOP == 0 {
            let mut target = [0.0; MAX_JOINTS];
            if !stop {
                for (t, c) in target.iter_mut().zip(&cmd.qdot_rad_s).take(n) {
                    *t = c * self.cfg.speed_override;
                }
                let k = uniform_scale(&target[..n], &self.vmax[..n]);
                if k < 1.0 {
                    flags |= safe_flags::VELOCITY_SCALED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
            let mut tcp = None;
            if q_ok {
                let q = &state.q_rad[..n];
                let k = rules::position_scale(
                    q,
                    &target[..n],
                    &self.lower[..n],
                    &self.upper[..n],
                    &self.amax[..n],
                    self.dt,
                    false,
                );
                if k < 1.0 {
                    flags |= safe_flags::POSITION_LIMITED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
                if self.cfg.workspace.enabled
                    && let Some(model) = self.tcp.as_mut()
                {
                    let mut p = [0.0; 3];
                    let mut jv = [[0.0; MAX_JOINTS]; 3];
                    model.tcp(q, &mut p, &mut jv);
                    if p.iter().all(|v| v.is_finite()) && jv.iter().all(|r| all_finite(r)) {
                        let v = rules::tcp_velocity(&jv, &target[..n]);
                        let decel = self.cfg.workspace.deceleration_m_s2;
                        let k = self.bounds.scale(&p, &v, decel, self.dt, false);
                        if k < 1.0 {
                            flags |= safe_flags::WORKSPACE_LIMITED;
                            target[..n].iter_mut().for_each(|v| *v *= k);
                        }
                        tcp = Some((p, jv));
                    }
                }
            }
            out = target;
            if limit_change(&base[..n], &mut out[..n], &self.amax[..n], self.dt) {
                flags |= safe_flags::ACCEL_LIMITED;
            }
            // Hard guarantees over the acceleration limit.
            if q_ok {
                let k = rules::position_scale(
                    &state.q_rad[..n],
                    &out[..n],
                    &self.lower[..n],
                    &self.upper[..n],
                    &self.amax[..n],
                    self.dt,
                    true,
                );
                if k < 1.0 {
                    flags |= safe_flags::POSITION_LIMITED;
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
            if let Some((p, jv)) = tcp {
                let v = rules::tcp_velocity(&jv, &out[..n]);
                let k = self.bounds.scale(&p, &v, 1.0, self.dt, true);
                if k < 1.0 {
                    flags |= safe_flags::WORKSPACE_LIMITED;
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
        }
        if stop {
            flags |= safe_flags::STOP;
        }
        let gripper = if stop {
            0.0
        } else {
            cmd.gripper_rate
                .clamp(-self.cfg.max_gripper_rate, self.cfg.max_gripper_rate)
        };
        for (bit, c) in self.counts.iter_mut().enumerate() {
            if flags & (1 << bit) != 0 {
                *c = c.saturating_add(1);
            }
        }
        self.prev_tick = cmd.tick;
        self.prev_out = out;

        SafeCommand {
            tick: cmd.tick,
            t_ns: 0,
            state_t_ns: cmd.state_t_ns,
            state_rx_ns: cmd.state_rx_ns,
            joystick_t_ns: cmd.joystick_t_ns,
            joystick_rx_ns: cmd.joystick_rx_ns,
            mapper_t_ns: cmd.t_ns,
            mapper_rx_ns: 0,
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

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics::gen3_lite;
    use proptest::prelude::*;

    const NOW: u64 = 1_000_000_000;
    const DT: f64 = 0.025;

    fn limits() -> ArmLimits {
        gen3_lite::limits()
    }

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
            state_rx_ns: 0,
            joystick_t_ns: NOW - 10_000_000,
            joystick_rx_ns: 0,
            joystick_seq: 1,
            compute_ns: 100,
            mapper_id: 1,
            n_joints: 6,
            flags: 0,
            buttons: 0,
            action: [0.0; 2],
            qdot_rad_s: q,
            gripper_rate: 0.5,
        }
    }

    /// Default limits.
    fn filter() -> SafetyFilter {
        SafetyFilter::new(SafetyConfig::default(), &limits(), DT).unwrap()
    }

    /// Acceleration limits out of the way, to test the other rules alone.
    fn filter_without_accel_limit() -> SafetyFilter {
        let cfg = SafetyConfig {
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        SafetyFilter::new(cfg, &limits(), DT).unwrap()
    }

    /// A tool model linear in q: p = p0 + A q. Exact to first order, so the workspace
    /// guarantee can be checked without tolerance.
    struct LinearTcp {
        p0: [f64; 3],
        a: [[f64; MAX_JOINTS]; 3],
    }

    impl LinearTcp {
        fn gen3_like() -> Self {
            let mut a = [[0.0; MAX_JOINTS]; 3];
            a[0][..6].copy_from_slice(&[0.0, 0.3, 0.2, 0.0, 0.1, 0.0]);
            a[1][..6].copy_from_slice(&[0.4, 0.0, 0.0, 0.05, 0.0, 0.0]);
            a[2][..6].copy_from_slice(&[0.0, -0.3, -0.25, 0.0, -0.1, 0.0]);
            Self {
                p0: [0.4, 0.0, 0.3],
                a,
            }
        }

        fn at(&self, q: &[f64]) -> [f64; 3] {
            let mut p = self.p0;
            for i in 0..3 {
                for j in 0..q.len() {
                    p[i] += self.a[i][j] * q[j];
                }
            }
            p
        }
    }

    impl TcpModel for LinearTcp {
        fn tcp(&mut self, q: &[f64], p: &mut [f64; 3], jv: &mut [[f64; MAX_JOINTS]; 3]) {
            *p = self.at(q);
            *jv = self.a;
        }
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
    fn speed_override_scales_everything() {
        let cfg = SafetyConfig {
            speed_override: 0.25,
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
        let out = f.step(&cmd(5, [0.4, 0.0, 0.0, 0.0, 0.0, -0.2]), &state(5), NOW);
        assert_eq!(out.flags, 0);
        assert!((out.qdot_rad_s[0] - 0.1).abs() < 1e-12);
        assert!((out.qdot_rad_s[5] + 0.05).abs() < 1e-12);
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
        c.flags = mapper_flags::INPUT_STALE;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_JOYSTICK | safe_flags::STOP);

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
        let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
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
        s.applied_tick = NO_TICK;
        s.qdot_rad_s[0] = 0.3;
        let out = f.step(&cmd(3, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &s, NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s[0], 0.3);
    }

    #[test]
    fn joints_brake_before_their_margin_and_move_away_freely() {
        let mut f = filter_without_accel_limit();
        let mut s = state(5);
        // Joint 0 at 1 mrad from its margin (limit 2.68, margin 0.05).
        s.q_rad[0] = 2.68 - 0.05 - 0.001;
        let out = f.step(&cmd(5, [0.3, 0.1, 0.0, 0.0, 0.0, 0.0]), &s, NOW);
        assert!(out.flags & safe_flags::POSITION_LIMITED != 0);
        assert!(s.q_rad[0] + out.qdot_rad_s[0] * DT <= 2.63 + 1e-12);
        // The whole command is scaled, so it keeps its direction.
        assert!((out.qdot_rad_s[1] / out.qdot_rad_s[0] - 1.0 / 3.0).abs() < 1e-9);
        // Away from the limit: untouched.
        let out = f.step(
            &cmd(6, [-0.3, 0.1, 0.0, 0.0, 0.0, 0.0]),
            &state_at(6, s.q_rad),
            NOW,
        );
        assert_eq!(out.flags & safe_flags::POSITION_LIMITED, 0);
        assert_eq!(out.qdot_rad_s[0], -0.3);
    }

    fn state_at(tick: u64, q: [f64; MAX_JOINTS]) -> RobotState {
        let mut s = state(tick);
        s.q_rad = q;
        s
    }

    #[test]
    fn the_tool_stops_at_the_table_and_may_lift() {
        let model = LinearTcp::gen3_like();
        // Find q with the tool 2 mm above the table plane (z = 0.02 + slack).
        let mut q = [0.0; MAX_JOINTS];
        q[1] = (model.p0[2] - 0.022) / 0.3;
        assert!((model.at(&q[..6])[2] - 0.022).abs() < 1e-12);
        let mut f = filter_without_accel_limit().with_tcp_model(Box::new(LinearTcp::gen3_like()));
        // Joint 1 positive moves the tool down.
        let out = f.step(
            &cmd(5, [0.0, 0.4, 0.0, 0.0, 0.0, 0.0]),
            &state_at(5, q),
            NOW,
        );
        assert!(out.flags & safe_flags::WORKSPACE_LIMITED != 0);
        let mut next = q;
        next[1] += out.qdot_rad_s[1] * DT;
        assert!(model.at(&next[..6])[2] >= 0.02, "into the table");
        let out = f.step(
            &cmd(6, [0.0, -0.4, 0.0, 0.0, 0.0, 0.0]),
            &state_at(6, q),
            NOW,
        );
        assert_eq!(out.flags & safe_flags::WORKSPACE_LIMITED, 0);
    }

    #[test]
    fn deadman_must_be_held_when_required() {
        let cfg = SafetyConfig {
            deadman: true,
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
        let out = f.step(&cmd(5, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::DEADMAN | safe_flags::STOP);
        let mut c = cmd(6, [0.1; 6]);
        c.buttons = buttons::DEADMAN;
        assert_eq!(f.step(&c, &state(6), NOW).flags, 0);
    }

    #[test]
    fn estop_latches_until_reset_and_stops_at_once() {
        let mut f = filter();
        for k in 1..40 {
            f.step(&cmd(k, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(k), NOW);
        }
        let mut c = cmd(40, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]);
        c.buttons = buttons::ESTOP;
        let out = f.step(&c, &state(40), NOW);
        assert_eq!(out.flags, safe_flags::ESTOP | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
        // Releasing the button does not release the e-stop.
        let out = f.step(&cmd(41, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(41), NOW);
        assert!(out.flags & safe_flags::ESTOP != 0);
        assert!(f.estopped());
        f.reset();
        let out = f.step(&cmd(42, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(42), NOW);
        assert_eq!(out.flags, safe_flags::ACCEL_LIMITED);
        f.estop();
        assert!(f.step(&cmd(43, [0.0; 6]), &state(43), NOW).flags & safe_flags::ESTOP != 0);
        let counts = f.rule_counts();
        assert_eq!(counts[12], 3);
        assert_eq!(counts[5], 3);
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
        let l = limits();
        let mut cfg = SafetyConfig::default();
        cfg.max_velocity_rad_s[3] = -1.0;
        let e = SafetyFilter::new(cfg, &l, DT).unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert!(
            e.to_string()
                .starts_with("safety.max_velocity_rad_s: entry 3 is -1")
        );
        let mut seven = l.clone();
        for v in [
            &mut seven.lower_rad,
            &mut seven.upper_rad,
            &mut seven.max_velocity_rad_s,
            &mut seven.max_acceleration_rad_s2,
        ] {
            v.push(1.0);
        }
        seven.names.push("joint_7".into());
        let e = SafetyFilter::new(SafetyConfig::default(), &seven, DT).unwrap_err();
        assert!(e.reason.contains("7 joints"));
        let bad = |cfg: SafetyConfig| SafetyFilter::new(cfg, &l, DT).unwrap_err().key;
        let d = SafetyConfig::default;
        assert_eq!(
            bad(SafetyConfig {
                max_joystick_age_ms: 0.0,
                ..d()
            }),
            "max_joystick_age_ms"
        );
        assert_eq!(
            bad(SafetyConfig {
                max_acceleration_rad_s2: vec![1.0; 5],
                ..d()
            }),
            "max_acceleration_rad_s2"
        );
        let e = SafetyFilter::new(
            SafetyConfig {
                joint_margin_rad: 2.6,
                ..d()
            },
            &l,
            DT,
        )
        .unwrap_err();
        assert_eq!(e.key, "joint_margin_rad");
        assert!(e.reason.contains("joint_4"), "{e}");
        assert_eq!(
            bad(SafetyConfig {
                speed_override: 1.5,
                ..d()
            }),
            "speed_override"
        );
        let mut w = d();
        w.workspace.box_min_m[2] = 2.0;
        assert_eq!(bad(w), "workspace.box_min_m");
        let mut w = d();
        w.workspace.table_z_m = 5.0;
        assert_eq!(bad(w), "workspace.table_z_m");
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            6 => -3.0f64..3.0,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(f64::NEG_INFINITY),
            1 => Just(1e300),
            1 => Just(-1e-300),
        ]
    }

    /// A joint angle: anywhere in the range, at or just beyond its margin, or garbage.
    fn any_q(j: usize) -> impl Strategy<Value = f64> {
        let hi = gen3_lite::limits().upper_rad[j];
        prop_oneof![
            4 => -hi..hi,
            1 => Just(hi - 0.05),
            1 => Just(-(hi - 0.05)),
            1 => (hi - 0.06)..(hi - 0.04),
            1 => Just(f64::NAN),
        ]
    }

    fn any_pose() -> impl Strategy<Value = [f64; 6]> {
        (any_q(0), any_q(1), any_q(2), any_q(3), any_q(4), any_q(5))
            .prop_map(|(a, b, c, d, e, f)| [a, b, c, d, e, f])
    }

    proptest! {
        /// Closed loop: the arm integrates the filter's own outputs from arbitrary poses and
        /// arbitrary (also non-finite) commands; every output is finite, within the velocity
        /// and acceleration limits, never carries a joint past its margin and never takes the
        /// tool out of the workspace.
        #[test]
        fn every_guarantee_holds_in_closed_loop(
            start in any_pose(),
            cmds in proptest::collection::vec(
                (proptest::array::uniform6(any_f64()), any_f64(), 0u64..2, any::<bool>(), 0u32..4),
                1..30,
            ),
        ) {
            let model = LinearTcp::gen3_like();
            let mut f = filter().with_tcp_model(Box::new(LinearTcp::gen3_like()));
            let (vmax, amax) = (gen3_lite::DEFAULT_VELOCITY_RAD_S, gen3_lite::DEFAULT_ACCELERATION_RAD_S2);
            let bounds = Bounds::new(0.02, [-0.8, -0.8, -0.1], [0.8, 0.8, 1.1]);
            let limits = limits();
            let mut q = [0.0; MAX_JOINTS];
            q[..6].copy_from_slice(&start);
            let mut prev = [0.0; MAX_JOINTS];
            for (k, (qdot, gripper, stale, executed, btn)) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut c = cmd(tick, qdot);
                c.gripper_rate = gripper;
                c.buttons = if btn == 3 { buttons::ESTOP } else { 0 };
                let mut s = state_at(tick + stale, q);
                s.qdot_rad_s = prev;
                if !executed {
                    s.applied_tick = NO_TICK;
                }
                let out = f.step(&c, &s, NOW);
                let q_ok = q[..6].iter().all(|v| v.is_finite());
                let p_inside = q_ok && bounds.contains(&model.at(&q[..6]), 0.0);
                for j in 0..6 {
                    let v = out.qdot_rad_s[j];
                    prop_assert!(v.is_finite());
                    prop_assert!(v.abs() <= vmax[j] * (1.0 + 1e-12));
                    let hard_acted = out.flags & (safe_flags::ESTOP | safe_flags::POSITION_LIMITED | safe_flags::WORKSPACE_LIMITED) != 0;
                    if !hard_acted {
                        prop_assert!((v - prev[j]).abs() <= amax[j] * DT * (1.0 + 1e-9), "joint {j}");
                    }
                    if q_ok {
                        let (lo, hi) = (limits.lower_rad[j] + 0.05, limits.upper_rad[j] - 0.05);
                        let next = q[j] + v * DT;
                        if q[j] <= hi { prop_assert!(next <= hi + 1e-12, "joint {j} past its upper margin"); }
                        else { prop_assert!(v <= 0.0); }
                        if q[j] >= lo { prop_assert!(next >= lo - 1e-12, "joint {j} past its lower margin"); }
                        else { prop_assert!(v >= 0.0); }
                    }
                }
                prop_assert!(out.gripper_rate.is_finite());
                prop_assert!(out.gripper_rate.abs() <= f.config().max_gripper_rate);
                prop_assert!(out.qdot_rad_s[6..].iter().all(|v| *v == 0.0));
                if q_ok {
                    let mut next = q;
                    for j in 0..6 { next[j] += out.qdot_rad_s[j] * DT; }
                    if p_inside {
                        prop_assert!(bounds.contains(&model.at(&next[..6]), 1e-12), "tool left the workspace");
                    }
                    q = next;
                }
                if btn == 3 { f.reset(); }
                prev = out.qdot_rad_s;
            }
        }

        /// The tool starts 0 to 5 cm above the table and is driven by arbitrary commands: it
        /// never goes below the table plane.
        #[test]
        fn the_tool_never_enters_the_table(
            others in proptest::array::uniform5(-0.5f64..0.5),
            height in 0.0f64..0.05,
            cmds in proptest::collection::vec(proptest::array::uniform6(-3.0f64..3.0), 1..40),
        ) {
            let model = LinearTcp::gen3_like();
            let mut q = [0.0; MAX_JOINTS];
            q[0] = others[0];
            q[2] = others[1];
            q[3] = others[2];
            q[4] = others[3];
            q[5] = others[4];
            // z = p0z - 0.3 q1 - 0.25 q2 - 0.1 q4: solve for q1.
            q[1] = (model.p0[2] - (0.02 + height) - 0.25 * q[2] - 0.1 * q[4]) / 0.3;
            prop_assume!(Bounds::new(0.02, [-0.8, -0.8, -0.1], [0.8, 0.8, 1.1]).contains(&model.at(&q[..6]), 0.0));
            let mut f = filter().with_tcp_model(Box::new(LinearTcp::gen3_like()));
            let mut prev = [0.0; MAX_JOINTS];
            for (k, qdot) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                let out = f.step(&cmd(tick, qdot), &s, NOW);
                for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                prop_assert!(model.at(&q[..6])[2] >= 0.02 - 1e-12, "tool at z {}", model.at(&q[..6])[2]);
                prev = out.qdot_rad_s;
            }
        }

        /// The same with the real Gen3 lite kinematics (nonlinear): from poses with the tool
        /// just above the table, arbitrary commands never take it below the plane (the rule
        /// predicts one tick to first order; the slack covers the rest).
        #[test]
        fn the_gen3_lite_tool_never_enters_the_table(
            start in proptest::array::uniform6(-1.5f64..1.5),
            height in 0.011f64..0.06,
            cmds in proptest::collection::vec(proptest::array::uniform6(-3.0f64..3.0), 1..40),
        ) {
            let arm = kinematics::Gen3Lite::get().arm();
            let z = |q: &[f64]| arm.fk(q).unwrap().translation.vector.z;
            let mut q = [0.0; MAX_JOINTS];
            q[..6].copy_from_slice(&start);
            // Put the tool `height` above the table plane by the shoulder angle.
            let shoulder = (0..=520)
                .map(|i| -2.6 + i as f64 * 0.01)
                .find(|a| { q[1] = *a; (z(&q[..6]) - 0.02 - height).abs() < 0.005 });
            prop_assume!(shoulder.is_some());
            prop_assume!(!limits().clamp_position(&mut q[..6].to_vec()));
            let mut f = filter().with_tcp_model(Box::new(ChainTcp::gen3_lite()));
            let mut prev = [0.0; MAX_JOINTS];
            for (k, qdot) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                let out = f.step(&cmd(tick, qdot), &s, NOW);
                for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                prop_assert!(z(&q[..6]) >= 0.02, "tool at z {}", z(&q[..6]));
                prev = out.qdot_rad_s;
            }
        }

        #[test]
        fn velocity_scaling_keeps_direction(qdot in proptest::array::uniform6(-5.0f64..5.0)) {
            // From rest the acceleration limit scales the change from zero, so the output is
            // still a positive multiple of the input; in the middle of the range, away from
            // every bound, no other rule acts.
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
