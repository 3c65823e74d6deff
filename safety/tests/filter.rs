//! The safety filter's rules one by one (velocity, acceleration, position, workspace, the
//! e-stop, hold, deadman, mapper switches, configuration errors) and the guarantees they keep
//! together in closed loop (property tests).
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use ipc_types::{
    MAX_JOINTS, MapperCommand, NO_TICK, RobotState, SafeCommand, buttons, mapper_flags, safe_flags,
};
use kinematics::ArmLimits;
use kinematics::gen3_lite;
use proptest::prelude::*;
use safety::*;

mod common;
use common::NOW;

const DT: f64 = 0.025;

fn limits() -> ArmLimits {
    gen3_lite::limits()
}

/// The Gen3 lite's tool model (`base_link -> tool_frame`).
fn gen3_lite_tcp() -> ChainTcp {
    ChainTcp::of(kinematics::RobotProfile::by_name("gen3_lite").unwrap())
}

fn state(tick: u64) -> RobotState {
    common::resting_state(tick, 6)
}

fn cmd(tick: u64, qdot: [f64; 6]) -> MapperCommand {
    common::command(tick, &qdot, 0.5)
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

    // A robot that reports a non-finite velocity is a fault too, executed or not.
    for applied in [4, NO_TICK] {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut s = state(5);
            s.applied_tick = applied;
            s.qdot_rad_s[4] = bad;
            let out = f.step(&cmd(5, [0.1; 6]), &s, NOW);
            assert_eq!(out.flags, safe_flags::NON_FINITE | safe_flags::STOP);
            assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
        }
    }
}

#[test]
fn no_joystick_sample_yet_is_stale_unless_the_map_ignores_the_input() {
    let mut c = cmd(5, [0.0; 6]);
    c.joystick_t_ns = 0;
    c.flags = mapper_flags::NO_INPUT;
    assert_eq!(
        filter().step(&c, &state(5), NOW).flags,
        safe_flags::STALE_JOYSTICK | safe_flags::STOP
    );
    c.flags |= mapper_flags::IGNORES_INPUT;
    let mut f = filter();
    // Not stale; but no sample is no neutral input either: the arm waits for one.
    assert_eq!(
        f.step(&c, &state(5), NOW).flags,
        safe_flags::AWAITING_NEUTRAL | safe_flags::STOP
    );
    let mut c = cmd(6, [0.0; 6]);
    c.flags = mapper_flags::IGNORES_INPUT;
    assert_eq!(f.step(&c, &state(6), NOW).flags, 0);
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
    // A missed tick and a robot reporting a NaN velocity: the stop goes on decelerating
    // from the last output (the best estimate left) instead of jumping to zero.
    let prev = out.qdot_rad_s;
    let mut s = state(35);
    s.applied_tick = NO_TICK;
    s.qdot_rad_s[1] = f64::NAN;
    let out = f.step(&cmd(35, want), &s, NOW);
    assert_eq!(
        out.flags,
        safe_flags::NON_FINITE | safe_flags::STOP | safe_flags::ACCEL_LIMITED
    );
    for j in 0..6 {
        assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * DT + 1e-12);
        assert!(out.qdot_rad_s[j].abs() < prev[j].abs() || prev[j] == 0.0);
    }
}

/// The period-tied rules at 40 Hz and at 1 kHz, with the period as the only parameter:
/// the velocity changes by at most `max_acceleration * period` per tick (so a ramp takes
/// the same time, 25 times the ticks), and a state older than the default age limit at
/// that period (80 % of it) is stale while one of this tick is not.
#[test]
fn period_tied_rules_follow_the_period_at_40_hz_and_1_khz() {
    let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
    let want = [0.4, -0.4, 0.2, 0.0, 0.5, 0.0];
    for (rate_hz, ramp_ticks) in [(40.0, 32u64), (1000.0, 800)] {
        let dt = 1.0 / rate_hz;
        let period_ns = (dt * 1e9) as u64;
        let cfg = SafetyConfig {
            max_state_age_ms: SafetyConfig::state_age_ms_for(dt),
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), dt).unwrap();
        // A state published a tenth of a period ago and a sample one period old.
        let at = |tick: u64, state_age_ns: u64| {
            let mut s = RobotState::at_rest(tick, NOW - state_age_ns, 6);
            s.applied_tick = tick.wrapping_sub(1);
            let mut c = cmd(tick, want);
            c.state_t_ns = s.t_ns;
            c.joystick_t_ns = NOW - period_ns;
            (c, s)
        };
        let mut prev = [0.0; 6];
        let mut reached = None;
        for k in 1..2000u64 {
            let (c, s) = at(k, period_ns / 10);
            let out = f.step(&c, &s, NOW);
            for j in 0..6 {
                let dv = (out.qdot_rad_s[j] - prev[j]).abs();
                assert!(
                    dv <= accel[j] * dt + 1e-12,
                    "{rate_hz} Hz tick {k} joint {j}: {dv}"
                );
                prev[j] = out.qdot_rad_s[j];
            }
            if out.flags == 0 {
                reached = Some(k);
                break;
            }
            assert_eq!(
                out.flags,
                safe_flags::ACCEL_LIMITED,
                "{rate_hz} Hz tick {k}"
            );
        }
        // Joint 2 (0.4 rad/s at 0.5 rad/s²) sets the ramp: 0.8 s at either rate.
        let reached = reached.unwrap();
        assert!(
            reached.abs_diff(ramp_ticks) <= 1,
            "{rate_hz} Hz: reached at tick {reached}, expected {ramp_ticks}"
        );
        // A state 90 % of a period old is stale at this rate: a stop.
        let (c, s) = at(reached + 1, period_ns * 9 / 10);
        let out = f.step(&c, &s, NOW);
        assert_ne!(out.flags & safe_flags::STALE_STATE, 0, "{rate_hz} Hz");
        for j in 0..6 {
            assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * dt + 1e-12);
        }
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

/// Whether `p` is above the table plane and in the box of `w`, to `tol` (m): the test's
/// own oracle, independent of [`Bounds`].
fn in_workspace(w: &WorkspaceConfig, p: &[f64; 3], tol: f64) -> bool {
    p[2] >= w.table_z_m - tol
        && (0..3).all(|i| p[i] >= w.box_min_m[i] - tol && p[i] <= w.box_max_m[i] + tol)
}

/// The half-spaces `n·x >= b` the filter keeps the tool in: the configured bounds less
/// the slack.
fn planes(w: &WorkspaceConfig) -> [([f64; 3], f64); 7] {
    let s = WORKSPACE_SLACK_M;
    let (lo, hi) = (w.box_min_m, w.box_max_m);
    [
        ([0.0, 0.0, 1.0], w.table_z_m + s),
        ([1.0, 0.0, 0.0], lo[0] + s),
        ([0.0, 1.0, 0.0], lo[1] + s),
        ([0.0, 0.0, 1.0], lo[2] + s),
        ([-1.0, 0.0, 0.0], -(hi[0] - s)),
        ([0.0, -1.0, 0.0], -(hi[1] - s)),
        ([0.0, 0.0, -1.0], -(hi[2] - s)),
    ]
}

/// Whether the arm at `q` moving at `base` was already too fast: even braking along its
/// direction as hard as the acceleration limits allow (the hardest stop that keeps the
/// direction), some joint, or the tool (to first order, by its position `p` and Jacobian
/// `jv`), would cross its bound within the next tick, or go further out of one it is
/// already past. Only then may the hard guarantees exceed the acceleration limit.
fn too_fast_to_brake(
    cfg: &SafetyConfig,
    q: &[f64],
    base: &[f64],
    tool: Option<([f64; 3], [[f64; MAX_JOINTS]; 3])>,
) -> bool {
    let l = limits();
    let m = cfg.joint_margin_rad;
    let amax = &cfg.max_acceleration_rad_s2;
    let c = (1.0 - rules::brake_rate(&base[..6], amax) * DT).max(0.0);
    let braked: [f64; 6] = std::array::from_fn(|j| base[j] * c);
    // Approaching at `speed` with `dist` left (nothing left past the bound).
    let crosses = |dist: f64, speed: f64| speed > 0.0 && speed * DT > dist.max(0.0) - 1e-12;
    let joint = (0..6).any(|j| {
        crosses(l.upper_rad[j] - m - q[j], braked[j])
            || crosses(q[j] - (l.lower_rad[j] + m), -braked[j])
    });
    let tool = tool.is_some_and(|(p, jv)| {
        let v = rules::tcp_velocity(&jv, &braked);
        planes(&cfg.workspace).iter().any(|(nrm, b)| {
            let dist = nrm[0] * p[0] + nrm[1] * p[1] + nrm[2] * p[2] - b;
            crosses(dist, -(nrm[0] * v[0] + nrm[1] * v[1] + nrm[2] * v[2]))
        })
    });
    joint || tool
}

/// Checks the acceleration invariant of one output: every joint changes by at most its
/// limit per tick from the arm's velocity `base` (the filter must agree on it), unless
/// the e-stop latched or a hard guarantee overrode an arm that was already too fast to
/// brake in time.
fn check_acceleration(
    f: &SafetyFilter,
    out: &SafeCommand,
    base: &[f64; MAX_JOINTS],
    q: &[f64],
    tool: Option<([f64; 3], [[f64; MAX_JOINTS]; 3])>,
) -> Result<(), TestCaseError> {
    let r = f.last_report();
    prop_assert_eq!(
        &r.base_rad_s[..6],
        &base[..6],
        "the filter's idea of the arm's velocity"
    );
    let amax = &f.config().max_acceleration_rad_s2;
    let over = (0..6).find(|&j| (out.qdot_rad_s[j] - base[j]).abs() > amax[j] * DT * (1.0 + 1e-9));
    if let Some(j) = over {
        prop_assert!(
            out.flags & safe_flags::ESTOP != 0 || r.hard_override(),
            "joint {j} changed by {} (limit {}), flags {:#x}, no hard override",
            out.qdot_rad_s[j] - base[j],
            amax[j] * DT,
            out.flags
        );
        prop_assert!(
            out.flags & safe_flags::ESTOP != 0 || too_fast_to_brake(f.config(), q, base, tool),
            "joint {j}: the hard override broke the acceleration limit of an arm that could brake in time (flags {:#x})",
            out.flags
        );
    }
    Ok(())
}

fn any_pose() -> impl Strategy<Value = [f64; 6]> {
    (any_q(0), any_q(1), any_q(2), any_q(3), any_q(4), any_q(5))
        .prop_map(|(a, b, c, d, e, f)| [a, b, c, d, e, f])
}

proptest! {
    /// Closed loop: the arm integrates the filter's own outputs from arbitrary poses and
    /// arbitrary (also non-finite) commands, and at times reports a velocity of its own (a
    /// missed tick, garbage); every output is finite, within the velocity and acceleration
    /// limits (only a latched e-stop or a hard guarantee on an arm already too fast may
    /// change it faster), never carries a joint past its margin and never takes the tool
    /// out of the workspace.
    #[test]
    fn every_guarantee_holds_in_closed_loop(
        start in any_pose(),
        cmds in proptest::collection::vec(
            (
                proptest::array::uniform6(any_f64()),
                any_f64(),
                0u64..2,
                any::<bool>(),
                0u32..4,
                proptest::option::weighted(0.2, proptest::array::uniform6(prop_oneof![
                    8 => -2.0f64..2.0,
                    1 => Just(f64::NAN),
                ])),
            ),
            1..30,
        ),
    ) {
        let model = LinearTcp::gen3_like();
        let mut f = filter().with_tcp_model(Box::new(LinearTcp::gen3_like()));
        let vmax = gen3_lite::DEFAULT_VELOCITY_RAD_S;
        let w = WorkspaceConfig::default();
        let limits = limits();
        let mut q = [0.0; MAX_JOINTS];
        q[..6].copy_from_slice(&start);
        let mut prev = [0.0; MAX_JOINTS];
        for (k, (qdot, gripper, stale, executed, btn, measured)) in cmds.into_iter().enumerate() {
            let tick = k as u64 + 1;
            let mut c = cmd(tick, qdot);
            c.gripper_rate = gripper;
            c.buttons = if btn == 3 { buttons::ESTOP } else { 0 };
            let mut s = state_at(tick + stale, q);
            s.qdot_rad_s = prev;
            if let Some(m) = measured {
                s.qdot_rad_s[..6].copy_from_slice(&m);
            }
            if !executed {
                s.applied_tick = NO_TICK;
            }
            // The arm's velocity as the filter must take it: the previous output if the
            // bridge executed it or the robot reports garbage, else the measured one.
            let mut base = prev;
            if !(executed && stale == 0 && k > 0) && s.qdot_rad_s.iter().all(|v| v.is_finite()) {
                for j in 0..6 { base[j] = s.qdot_rad_s[j].clamp(-vmax[j], vmax[j]); }
            }
            let out = f.step(&c, &s, NOW);
            let q_ok = q[..6].iter().all(|v| v.is_finite());
            let p_inside = q_ok && in_workspace(&w, &model.at(&q[..6]), 0.0);
            let tool = q_ok.then(|| (model.at(&q[..6]), model.a));
            check_acceleration(&f, &out, &base, &q[..6], tool)?;
            for j in 0..6 {
                let v = out.qdot_rad_s[j];
                prop_assert!(v.is_finite());
                prop_assert!(v.abs() <= vmax[j]);
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
                    prop_assert!(in_workspace(&w, &model.at(&next[..6]), 1e-12), "tool left the workspace");
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
        let mut f = filter().with_tcp_model(Box::new(gen3_lite_tcp()));
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
}

/// Joint velocity limits at or below the URDF's, down to 1 % of it.
fn any_vmax() -> impl Strategy<Value = [f64; 6]> {
    let urdf = kinematics::Gen3Lite::get().arm().velocity_limits().to_vec();
    proptest::array::uniform6(prop_oneof![1 => Just(1.0), 3 => 0.01f64..1.0])
        .prop_map(move |frac| std::array::from_fn(|j| urdf[j] * frac[j]))
}

/// Joint acceleration limits from barely moving to nearly unlimited.
fn any_amax() -> impl Strategy<Value = [f64; 6]> {
    proptest::array::uniform6(prop_oneof![
        1 => Just(1e-3),
        4 => 0.01f64..20.0,
        1 => Just(1e4),
    ])
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// The real Gen3 lite kinematics (nonlinear) in closed loop against a table plane and
    /// a small box around the tool's start (2 mm to 12 cm to each face): held arbitrary
    /// commands, executed or reported back by the robot, never take the tool below the
    /// table or out of the box (the rule predicts one tick to first order; the slack
    /// covers the rest), and the acceleration limit holds but where a hard guarantee
    /// stopped an arm already too fast (the curved path's second-order rest).
    #[test]
    fn the_gen3_lite_tool_stays_above_the_table_and_in_the_box(
        start in proptest::array::uniform6(-2.4f64..2.4),
        below in 0.002f64..0.12,
        lo in proptest::array::uniform3(0.002f64..0.12),
        hi in proptest::array::uniform3(0.002f64..0.12),
        cmds in proptest::collection::vec(
            (proptest::array::uniform6(-3.0f64..3.0), 1usize..12, any::<bool>()),
            1..12,
        ),
    ) {
        let mut model = gen3_lite_tcp();
        let tool = |model: &mut ChainTcp, q: &[f64]| {
            let (mut p, mut jv) = ([0.0; 3], [[0.0; MAX_JOINTS]; 3]);
            model.tcp(q, &mut p, &mut jv);
            (p, jv)
        };
        let mut q = [0.0; MAX_JOINTS];
        q[..6].copy_from_slice(&start);
        let (p0, _) = tool(&mut model, &q[..6]);
        let mut cfg = SafetyConfig::default();
        cfg.workspace.table_z_m = p0[2] - below;
        cfg.workspace.box_min_m = std::array::from_fn(|i| p0[i] - lo[i]);
        cfg.workspace.box_max_m = std::array::from_fn(|i| p0[i] + hi[i]);
        let w = cfg.workspace.clone();
        let mut f = SafetyFilter::new(cfg, &limits(), DT)
            .unwrap()
            .with_tcp_model(Box::new(gen3_lite_tcp()));
        let mut prev = [0.0; MAX_JOINTS];
        let mut tick = 0;
        for (qdot, hold, executed) in cmds {
            for _ in 0..hold {
                tick += 1;
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                if !executed {
                    s.applied_tick = NO_TICK;
                }
                let out = f.step(&cmd(tick, qdot), &s, NOW);
                let at = tool(&mut model, &q[..6]);
                check_acceleration(&f, &out, &prev, &q[..6], Some(at))?;
                for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                let (p, _) = tool(&mut model, &q[..6]);
                prop_assert!(p[2] >= w.table_z_m, "tick {tick}: tool at z {} below the table {}", p[2], w.table_z_m);
                prop_assert!(in_workspace(&w, &p, 0.0), "tick {tick}: tool at {p:?} out of the box {:?} .. {:?}", w.box_min_m, w.box_max_m);
                prev = out.qdot_rad_s;
            }
        }
    }

    /// An arm that does what the filter says (every output executed, a fault now and
    /// then), from rest in range and inside the workspace, with any speed override and
    /// limits, never needs the hard guarantees to break the acceleration limit: the
    /// braking rules keep it able to stop within it, so no output changes faster than it
    /// allows, whatever the commands (held a while, then changed in any direction), and
    /// no joint passes its margin nor the tool a bound (a linear tool model: exact).
    #[test]
    fn an_arm_that_follows_the_filter_never_brakes_harder_than_allowed(
        start in proptest::array::uniform6(-2.45f64..2.45),
        speed in prop_oneof![1 => Just(1.0), 2 => 0.05f64..1.0],
        vmax in prop_oneof![1 => Just(gen3_lite::DEFAULT_VELOCITY_RAD_S), 1 => any_vmax()],
        amax in prop_oneof![1 => Just(gen3_lite::DEFAULT_ACCELERATION_RAD_S2), 1 => any_amax()],
        cmds in proptest::collection::vec(
            (proptest::array::uniform6(-3.0f64..3.0), 1usize..30, 0u8..8),
            1..8,
        ),
    ) {
        let model = LinearTcp::gen3_like();
        let cfg = SafetyConfig {
            max_velocity_rad_s: vmax.to_vec(),
            max_acceleration_rad_s2: amax.to_vec(),
            speed_override: speed,
            ..SafetyConfig::default()
        };
        let w = cfg.workspace.clone();
        let inside = |q: &[f64], slack: f64| {
            in_workspace(&w, &model.at(q), slack)
        };
        // Pull the start toward q = 0 (the tool well inside) until the tool is inside.
        let mut q = [0.0; MAX_JOINTS];
        for i in 0..40 {
            let s = 0.8f64.powi(i);
            for j in 0..6 { q[j] = start[j] * s; }
            if inside(&q[..6], -WORKSPACE_SLACK_M) { break; }
        }
        prop_assert!(inside(&q[..6], -WORKSPACE_SLACK_M));
        let mut f = SafetyFilter::new(cfg, &limits(), DT)
            .unwrap()
            .with_tcp_model(Box::new(LinearTcp::gen3_like()));
        let l = limits();
        let mut prev = [0.0; MAX_JOINTS];
        let mut tick = 0;
        for (qdot, hold, fault) in cmds {
            for _ in 0..hold {
                tick += 1;
                let mut c = cmd(tick, qdot);
                match fault {
                    0 => c.qdot_rad_s[1] = f64::NAN,
                    1 => c.flags = mapper_flags::INPUT_STALE,
                    _ => {}
                }
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                let out = f.step(&c, &s, NOW);
                let r = f.last_report();
                for j in 0..6 {
                    let v = out.qdot_rad_s[j];
                    prop_assert!(v.abs() <= vmax[j]);
                    prop_assert!(
                        (v - prev[j]).abs() <= amax[j] * DT * (1.0 + 1e-9),
                        "tick {tick} joint {j}: changed by {} (limit {}), flags {:#x}, {r:?}",
                        v - prev[j], amax[j] * DT, out.flags
                    );
                    q[j] += v * DT;
                    prop_assert!(q[j] <= l.upper_rad[j] - 0.05 + 1e-12 && q[j] >= l.lower_rad[j] + 0.05 - 1e-12);
                }
                prop_assert!(inside(&q[..6], 1e-12), "tick {tick}: tool out at {:?}", model.at(&q[..6]));
                prev = out.qdot_rad_s;
            }
        }
    }

    /// From arbitrary in-range poses and arm velocities, with the speed override and the
    /// velocity and acceleration limits anywhere in their ranges (also at the URDF limit
    /// and at the extremes): whenever the velocity limit is the only rule that acted, the
    /// output is a positive multiple of the command, as large as the tightest joint allows;
    /// with no rule acting it is the command times the override, exactly.
    #[test]
    fn only_the_velocity_limit_keeps_the_direction(
        q in proptest::array::uniform6(-2.4f64..2.4),
        qdot in proptest::array::uniform6(prop_oneof![4 => -5.0f64..5.0, 1 => Just(0.0)]),
        speed in prop_oneof![1 => Just(1.0), 1 => Just(1e-3), 4 => 1e-3f64..1.0],
        vmax in any_vmax(),
        amax in any_amax(),
        near in proptest::array::uniform6(-0.99f64..0.99),
        from_rest in any::<bool>(),
        tool in any::<bool>(),
    ) {
        let cfg = SafetyConfig {
            max_velocity_rad_s: vmax.to_vec(),
            max_acceleration_rad_s2: amax.to_vec(),
            speed_override: speed,
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
        if tool {
            f = f.with_tcp_model(Box::new(gen3_lite_tcp()));
        }
        // The arm moves at rest or near the velocity the command asks for (within one
        // tick's acceleration of it), so the acceleration limit does not have to act.
        let wanted: [f64; 6] = std::array::from_fn(|j| qdot[j] * speed);
        let k = uniform_scale(&wanted, &vmax);
        let mut s = state_at(5, [q[0], q[1], q[2], q[3], q[4], q[5], 0.0, 0.0]);
        s.applied_tick = NO_TICK;
        if !from_rest {
            for j in 0..6 {
                s.qdot_rad_s[j] = (wanted[j] * k + near[j] * amax[j] * DT).clamp(-vmax[j], vmax[j]);
            }
        }
        let c = cmd(5, qdot);
        let out = f.step(&c, &s, NOW);
        let v = &out.qdot_rad_s;
        prop_assert!(v.iter().all(|x| x.is_finite()));
        if out.flags & (safe_flags::POSITION_LIMITED | safe_flags::WORKSPACE_LIMITED) == 0 && !from_rest {
            // Nothing but the velocity limit changed the target, and it is within reach.
            prop_assert_eq!(out.flags & safe_flags::ACCEL_LIMITED, 0);
        }
        if out.flags & !safe_flags::VELOCITY_SCALED == 0 {
            // One factor c for every joint: v = c * qdot.
            let big = (0..6).max_by(|a, b| qdot[*a].abs().total_cmp(&qdot[*b].abs())).unwrap();
            let c_out = if qdot[big] == 0.0 { 0.0 } else { v[big] / qdot[big] };
            for j in 0..6 {
                prop_assert!(
                    (v[j] - c_out * qdot[j]).abs() <= 1e-12 * (1.0 + qdot[j].abs()),
                    "joint {j}: {} is not {c_out} x {}", v[j], qdot[j]
                );
                prop_assert!(v[j].abs() <= vmax[j] * (1.0 + 1e-12));
            }
            prop_assert!(c_out >= 0.0 && c_out <= speed * (1.0 + 1e-12));
            if out.flags == 0 {
                prop_assert_eq!(&v[..6], &wanted[..]);
            } else {
                // Scaled as little as the tightest joint allows: that joint at its limit.
                prop_assert!(qdot[big] != 0.0);
                let tight = (0..6).map(|j| v[j].abs() / vmax[j]).fold(0.0, f64::max);
                prop_assert!((tight - 1.0).abs() < 1e-9, "tightest joint at {tight} of its limit");
            }
        }
    }
}

/// The filter takes the arm from the robot profile it is given.
#[test]
fn a_filter_for_another_arm() {
    let planar = kinematics::RobotProfile::new(&kinematics::ProfileSpec::planar5()).unwrap();
    let cfg = SafetyConfig::for_robot(&planar);
    assert_eq!(cfg.max_velocity_rad_s, [1.0; 5]);
    // Checked against the default arm's description, five joints are refused ...
    assert!(SafetyFilter::new(cfg.clone(), planar.limits(), DT).is_err());
    // ... and accepted for their own robot, with its tool model.
    let mut f = SafetyFilter::for_robot(cfg, &planar, DT)
        .unwrap()
        .with_tcp_model(Box::new(ChainTcp::of(&planar)));
    let mut s = RobotState::at_rest(5, NOW - 1_000_000, 5);
    s.applied_tick = 4;
    s.q_rad[..5].copy_from_slice(&[0.3, 0.4, 0.3, 0.2, 0.1]);
    let mut m = cmd(5, [5.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    m.n_joints = 5;
    let out = f.step(&m, &s, NOW);
    assert!(
        out.qdot_rad_s[0] > 0.0 && out.qdot_rad_s[0] <= 1.0,
        "{out:?}"
    );
    assert_eq!(out.qdot_rad_s[5], 0.0);
}

/// A tick no mapper command came for, answered by safety itself
/// ([`SafetyFilter::step_unanswered`]): flagged a stale command and a stop, naming no mapper
/// command (`mapper_t_ns` 0) and the active mapper; without the e-stop a controlled stop from
/// the arm's velocity, with the e-stop latched zero at once.
#[test]
fn a_tick_without_a_command_is_a_stop_and_zero_under_the_estop() {
    let mut f = filter();
    let mut prev = [0.0; MAX_JOINTS];
    for k in 1..=10 {
        prev = f
            .step(&cmd(k, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(k), NOW)
            .qdot_rad_s;
    }
    assert!(prev[0] > 0.1);
    let out = f.step_unanswered(1, &state(11), NOW);
    assert_eq!(
        out.flags & !safe_flags::ACCEL_LIMITED,
        safe_flags::STALE_COMMAND | safe_flags::STOP
    );
    assert_eq!((out.tick, out.mapper_t_ns, out.mapper_id), (11, 0, 1));
    assert!(out.qdot_rad_s[0] > 0.0 && out.qdot_rad_s[0] < prev[0]);
    f.estop();
    let out = f.step_unanswered(1, &state(12), NOW);
    assert_eq!(
        out.flags,
        safe_flags::ESTOP | safe_flags::STALE_COMMAND | safe_flags::STOP
    );
    assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
    // The next mapper command follows on from the answered tick: its neutral input re-arms.
    f.reset();
    let out = f.step(&cmd(13, [0.0; 6]), &state(13), NOW);
    assert_eq!(out.flags, 0);
}
