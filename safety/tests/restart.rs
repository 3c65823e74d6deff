//! Restart prevention in the filter: after a stop a fault caused, and at start-up, the arm
//! moves again only once the operator's input has passed through neutral.
#![allow(clippy::unwrap_used, missing_docs)]

use ipc_types::{MapperCommand, NO_TICK, RobotState, buttons, mapper_flags, safe_flags};
use kinematics::gen3_lite;
use proptest::prelude::*;
use safety::{NEUTRAL_MAX_ACTION, SafetyConfig, SafetyFilter};

mod common;
use common::NOW;

const DT: f64 = 0.025;
const QDOT: [f64; 6] = [0.1, -0.1, 0.0, 0.05, 0.0, 0.0];

/// Acceleration limits out of the way: an armed command goes through unchanged.
fn filter(deadman: bool) -> SafetyFilter {
    let cfg = SafetyConfig {
        max_acceleration_rad_s2: vec![1e12; 6],
        deadman,
        ..SafetyConfig::default()
    };
    SafetyFilter::new(cfg, &gen3_lite::limits(), DT).unwrap()
}

/// The state of `tick`, having executed the command of the tick before.
fn state(tick: u64) -> RobotState {
    common::resting_state(tick, 6)
}

/// A command for `tick` from a stick at `a` (the map's velocity `QDOT` scaled by `|a|`, as
/// a linear map gives), with `buttons`.
fn cmd(tick: u64, a: [f32; 2], buttons: u32) -> MapperCommand {
    let norm = f64::from(a[0]).hypot(f64::from(a[1]));
    let qdot: [f64; 6] = std::array::from_fn(|j| QDOT[j] * norm);
    MapperCommand {
        buttons,
        action: a,
        ..common::command(tick, &qdot, 0.0)
    }
}

fn moving(out: &ipc_types::SafeCommand) -> bool {
    out.qdot_rad_s.iter().any(|v| *v != 0.0)
}

const HELD: [f32; 2] = [0.8, 0.0];
const REST: [f32; 2] = [0.0, 0.0];

#[test]
fn start_up_with_the_stick_deflected_waits_for_neutral() {
    let mut f = filter(false);
    for k in 1..10 {
        let out = f.step(&cmd(k, HELD, 0), &state(k), NOW);
        assert_eq!(out.flags, safe_flags::AWAITING_NEUTRAL | safe_flags::STOP);
        assert!(!moving(&out));
        assert!(f.awaiting_neutral());
    }
    assert_eq!(f.step(&cmd(10, REST, 0), &state(10), NOW).flags, 0);
    assert!(!f.awaiting_neutral());
    let out = f.step(&cmd(11, HELD, 0), &state(11), NOW);
    assert_eq!(out.flags, 0);
    assert!(moving(&out));
}

/// Arms the filter (a neutral tick) and moves it for a few ticks, up to `tick`.
fn armed_and_moving(f: &mut SafetyFilter, to_tick: u64) {
    f.step(&cmd(1, REST, 0), &state(1), NOW);
    for k in 2..=to_tick {
        assert!(moving(&f.step(&cmd(k, HELD, 0), &state(k), NOW)));
    }
}

#[test]
fn a_restarted_mapper_does_not_resume_a_deflected_stick() {
    let mut f = filter(false);
    armed_and_moving(&mut f, 20);
    // The mapper died after tick 20: no commands for ticks 21..40, the bridge stopped the arm.
    // A new mapper maps tick 41 with the stick still deflected.
    let mut s = state(41);
    s.applied_tick = NO_TICK;
    let out = f.step(&cmd(41, HELD, 0), &s, NOW);
    assert_eq!(out.flags, safe_flags::AWAITING_NEUTRAL | safe_flags::STOP);
    for k in 42..60 {
        let out = f.step(&cmd(k, HELD, 0), &state(k), NOW);
        assert!(!moving(&out), "tick {k}");
    }
    // Just outside the neutral zone: still waiting; inside: armed, and the stick drives.
    let edge = (NEUTRAL_MAX_ACTION * 1.2) as f32;
    assert!(!moving(&f.step(&cmd(60, [edge, 0.0], 0), &state(60), NOW)));
    assert_eq!(f.step(&cmd(61, REST, 0), &state(61), NOW).flags, 0);
    assert!(moving(&f.step(&cmd(62, HELD, 0), &state(62), NOW)));
}

#[test]
fn a_missed_tick_with_the_stick_at_rest_rearms_at_once() {
    let mut f = filter(false);
    armed_and_moving(&mut f, 5);
    let mut s = state(7);
    s.applied_tick = NO_TICK;
    assert_eq!(f.step(&cmd(7, REST, 0), &s, NOW).flags, 0);
    assert!(moving(&f.step(&cmd(8, HELD, 0), &state(8), NOW)));
}

#[test]
fn every_fault_waits_for_neutral_afterwards() {
    type Fault = fn(&mut SafetyFilter, &mut MapperCommand, &mut RobotState);
    let faults: [(&str, Fault); 7] = [
        ("nan", |_, c, _| c.qdot_rad_s[1] = f64::NAN),
        ("stale joystick", |_, c, _| {
            c.flags |= mapper_flags::INPUT_STALE
        }),
        ("old joystick", |_, c, _| {
            c.joystick_t_ns = NOW - 200_000_000
        }),
        ("stale state", |_, c, _| c.state_t_ns = NOW - 40_000_000),
        ("bad shape", |_, c, _| c.n_joints = 5),
        ("hold", |f, _, _| f.set_hold(true)),
        ("device gone", |_, c, _| {
            c.buttons |= buttons::NO_DEVICE;
            c.action = REST;
        }),
    ];
    for (what, fault) in faults {
        let mut f = filter(false);
        armed_and_moving(&mut f, 5);
        let (mut c, mut s) = (cmd(6, HELD, 0), state(6));
        fault(&mut f, &mut c, &mut s);
        assert!(f.step(&c, &s, NOW).flags & safe_flags::STOP != 0, "{what}");
        f.set_hold(false);
        for k in 7..15 {
            let out = f.step(&cmd(k, HELD, 0), &state(k), NOW);
            assert_eq!(
                out.flags,
                safe_flags::AWAITING_NEUTRAL | safe_flags::STOP,
                "{what}: tick {k}"
            );
        }
        assert_eq!(
            f.step(&cmd(15, REST, 0), &state(15), NOW).flags,
            0,
            "{what}"
        );
        assert!(
            moving(&f.step(&cmd(16, HELD, 0), &state(16), NOW)),
            "{what}"
        );
    }
}

#[test]
fn a_released_estop_waits_for_neutral() {
    let mut f = filter(false);
    armed_and_moving(&mut f, 5);
    f.estop();
    assert!(f.step(&cmd(6, HELD, 0), &state(6), NOW).flags & safe_flags::ESTOP != 0);
    f.reset();
    let out = f.step(&cmd(7, HELD, 0), &state(7), NOW);
    assert_eq!(out.flags, safe_flags::AWAITING_NEUTRAL | safe_flags::STOP);
    assert!(f.awaiting_neutral());
    assert_eq!(f.step(&cmd(8, REST, 0), &state(8), NOW).flags, 0);
}

#[test]
fn with_the_deadman_a_fault_needs_a_release_and_a_press_at_neutral() {
    let d = buttons::DEADMAN;
    let mut f = filter(true);
    // Start-up: held from the start is not a press.
    assert!(!moving(&f.step(&cmd(1, REST, d), &state(1), NOW)));
    assert_eq!(
        f.step(&cmd(2, REST, 0), &state(2), NOW).flags,
        safe_flags::DEADMAN | safe_flags::STOP
    );
    assert_eq!(f.step(&cmd(3, REST, d), &state(3), NOW).flags, 0);
    assert!(moving(&f.step(&cmd(4, HELD, d), &state(4), NOW)));
    // A fault while the deadman stays held and the stick at rest: not enough.
    f.set_hold(true);
    f.step(&cmd(5, HELD, d), &state(5), NOW);
    f.set_hold(false);
    let out = f.step(&cmd(6, REST, d), &state(6), NOW);
    assert_eq!(out.flags, safe_flags::AWAITING_NEUTRAL | safe_flags::STOP);
    f.step(&cmd(7, HELD, 0), &state(7), NOW);
    // Pressed again with the stick deflected: waits for the stick.
    assert!(!moving(&f.step(&cmd(8, HELD, d), &state(8), NOW)));
    assert_eq!(f.step(&cmd(9, REST, d), &state(9), NOW).flags, 0);
    assert!(moving(&f.step(&cmd(10, HELD, d), &state(10), NOW)));
}

#[test]
fn a_map_that_ignores_the_stick_rearms_on_the_deadman_alone() {
    let d = buttons::DEADMAN;
    let drill = |tick, buttons| {
        let mut c = cmd(tick, HELD, buttons);
        c.flags = mapper_flags::IGNORES_INPUT;
        c
    };
    let mut f = filter(true);
    assert!(!moving(&f.step(&drill(1, d), &state(1), NOW)));
    assert!(!moving(&f.step(&drill(2, 0), &state(2), NOW)));
    assert!(moving(&f.step(&drill(3, d), &state(3), NOW)));
    // Without the deadman the stick at rest still applies.
    let mut f = filter(false);
    assert!(!moving(&f.step(&drill(1, 0), &state(1), NOW)));
    let mut c = drill(2, 0);
    c.action = REST;
    f.step(&c, &state(2), NOW);
    assert!(moving(&f.step(&drill(3, 0), &state(3), NOW)));
}

proptest! {
    /// Whatever the faults and inputs, the arm moves only at ticks after a neutral tick that
    /// followed the last fault (or start-up): never after a fault with the stick held.
    #[test]
    fn no_motion_after_a_fault_until_the_stick_was_at_rest(
        ticks in proptest::collection::vec((0u8..12, 0.0f32..1.0, any::<bool>()), 1..80),
    ) {
        let mut f = filter(false);
        let mut neutral_since_fault = false;
        let mut tick = 0u64;
        for (kind, a, skip) in ticks {
            // A skipped tick: the bridge missed one and stopped, the state says so.
            let gap = skip && tick > 0;
            tick += 1 + u64::from(gap);
            let mut c = cmd(tick, [a, 0.0], 0);
            let mut s = state(tick);
            if gap {
                s.applied_tick = NO_TICK;
            }
            let fault = match kind {
                1 => { c.qdot_rad_s[0] = f64::NAN; true }
                2 => { c.flags = mapper_flags::INPUT_STALE; true }
                3 => { f.set_hold(true); true }
                _ => false,
            };
            let out = f.step(&c, &s, NOW);
            f.set_hold(false);
            if fault {
                neutral_since_fault = false;
            } else {
                if gap {
                    neutral_since_fault = false;
                }
                if f64::from(a) <= NEUTRAL_MAX_ACTION {
                    neutral_since_fault = true;
                }
            }
            if moving(&out) {
                prop_assert!(neutral_since_fault, "tick {tick}: moved without a neutral pass");
            }
            prop_assert_eq!(f.awaiting_neutral(), !neutral_since_fault);
        }
    }
}

/// The operator's input turns non-finite (a NaN axis: the mapper flags `input-non-finite`
/// and zeroes the action and the command) for 40 ticks while the stick was held, then comes
/// back deflected: a stop flagged non-finite at each of those ticks, counted, and no motion
/// until the stick has passed through neutral. Before, only the acceleration limit acted:
/// the arm slowed to the zero command, and moved again on the deflected stick at once.
#[test]
fn non_finite_operator_input_is_a_fault_that_waits_for_neutral() {
    let mut f = filter(false);
    armed_and_moving(&mut f, 5);
    let before = f.rule_counts();
    for k in 6..46 {
        let mut c = cmd(k, REST, 0);
        c.flags = mapper_flags::INPUT_NON_FINITE;
        let out = f.step(&c, &state(k), NOW);
        assert_eq!(
            out.flags,
            safe_flags::NON_FINITE | safe_flags::STOP,
            "tick {k}"
        );
        assert!(!moving(&out));
    }
    let bit = safe_flags::NON_FINITE.trailing_zeros() as usize;
    assert_eq!(f.rule_counts()[bit] - before[bit], 40);
    for k in 46..50 {
        let out = f.step(&cmd(k, HELD, 0), &state(k), NOW);
        assert_eq!(
            out.flags,
            safe_flags::AWAITING_NEUTRAL | safe_flags::STOP,
            "tick {k}"
        );
    }
    assert_eq!(f.step(&cmd(50, REST, 0), &state(50), NOW).flags, 0);
    assert!(moving(&f.step(&cmd(51, HELD, 0), &state(51), NOW)));
}

/// Non-finite axes that reach safety in the command's action itself (a mapper that did not
/// flag them) are the same fault: a stop, then neutral required.
#[test]
fn a_non_finite_action_is_a_fault_that_waits_for_neutral() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut f = filter(false);
        armed_and_moving(&mut f, 5);
        let mut c = cmd(6, HELD, 0);
        c.action = [bad, 0.0];
        let out = f.step(&c, &state(6), NOW);
        assert_eq!(
            out.flags,
            safe_flags::NON_FINITE | safe_flags::STOP,
            "{bad}"
        );
        let out = f.step(&cmd(7, HELD, 0), &state(7), NOW);
        assert_eq!(
            out.flags,
            safe_flags::AWAITING_NEUTRAL | safe_flags::STOP,
            "{bad}"
        );
        assert_eq!(f.step(&cmd(8, REST, 0), &state(8), NOW).flags, 0, "{bad}");
    }
}

/// A sample that answers no robot tick (published by a joystick before it saw one: the
/// mapper flags `input-no-tick`) is not the operator at neutral: at start-up and after a
/// fault the arm still waits for a neutral sample that answers a tick. Before, a restarted
/// scripted joystick's first sample (neutral, made before its first tick) re-armed safety,
/// and the script's deflected stick moved the arm.
#[test]
fn a_sample_that_answers_no_tick_is_not_neutral() {
    let unticked = |tick, a| {
        let mut c = cmd(tick, a, 0);
        c.flags = mapper_flags::INPUT_NO_TICK;
        c
    };
    // At start-up.
    let mut f = filter(false);
    let out = f.step(&unticked(1, REST), &state(1), NOW);
    assert_eq!(out.flags, safe_flags::AWAITING_NEUTRAL | safe_flags::STOP);
    assert!(!moving(&f.step(&cmd(2, HELD, 0), &state(2), NOW)));
    // After a fault (the joystick restarted: its samples went stale).
    let mut f = filter(false);
    armed_and_moving(&mut f, 5);
    let mut c = cmd(6, REST, 0);
    c.flags = mapper_flags::INPUT_STALE;
    f.step(&c, &state(6), NOW);
    assert!(f.awaiting_neutral());
    for k in 7..10 {
        let out = f.step(&unticked(k, REST), &state(k), NOW);
        assert_eq!(
            out.flags,
            safe_flags::AWAITING_NEUTRAL | safe_flags::STOP,
            "tick {k}"
        );
    }
    assert!(!moving(&f.step(&cmd(10, HELD, 0), &state(10), NOW)));
    assert!(f.awaiting_neutral());
    // A neutral sample that answers a tick re-arms.
    assert_eq!(f.step(&cmd(11, REST, 0), &state(11), NOW).flags, 0);
    assert!(moving(&f.step(&cmd(12, HELD, 0), &state(12), NOW)));
}
