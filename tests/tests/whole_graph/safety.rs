//! Whole-graph tests of the safety filter: the arm driven into a joint limit, the e-stop, and
//! injected faults (a NaN from the mapper, a silent joystick, robot states that stop), each
//! with real processes over real shared memory.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::process::Stdio;
use std::time::Duration;

use ipc_types::{NodeRole, Prefix, RobotState, SafeCommand, phase, safe_flags, state_flags};
use kinematics::gen3_lite::{DEFAULT_ACCELERATION_RAD_S2, DEFAULT_VELOCITY_RAD_S};
use scl_tests::{
    ChildGuard, DomainGuard, InputRow, Recorder, joint_reach_pca, pulses, run_polling, scl, serial,
    temp_dir, unique_prefix, wait_clean, write_replay,
};

const DT: f64 = 0.025;
const MARGIN: f64 = 0.05;

/// One recorded run of the graph. Fields drop in order: the recorder leaves before the
/// domain is released.
struct Run {
    rec: Recorder,
    prefix: Prefix,
    _domain: DomainGuard,
}

impl Run {
    /// Checks that the run left nothing behind.
    fn finish(self) {
        let prefix = self.prefix.clone();
        drop(self);
        assert_eq!(
            wait_clean(&prefix, Duration::from_secs(5)),
            Vec::<String>::new()
        );
    }

    fn running(&self) -> Vec<RobotState> {
        self.rec
            .robot_states
            .iter()
            .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
            .copied()
            .collect()
    }

    fn first_command_with(&self, flag: u32) -> Option<SafeCommand> {
        self.rec
            .safe_commands
            .iter()
            .find(|c| c.flags & flag != 0)
            .copied()
    }
}

/// Runs `scl up` with `config` for `secs` seconds while recording; `during` is called once
/// the graph has run `after_ticks` ticks.
fn run_graph(
    tag: &str,
    config: &str,
    secs: u32,
    after_ticks: usize,
    during: impl FnOnce(&Prefix, &mut Recorder),
) -> Run {
    run_graph_with_input(tag, config, &[], secs, after_ticks, during)
}

/// [`run_graph`] with the recorded input `input` in the run's directory as `input.csv`, for
/// the replay source (`[joystick] source = "replay"`, `replay_file = "input.csv"`).
fn run_graph_with_input(
    tag: &str,
    config: &str,
    input: &[InputRow],
    secs: u32,
    after_ticks: usize,
    during: impl FnOnce(&Prefix, &mut Recorder),
) -> Run {
    let prefix = unique_prefix(tag);
    let domain = DomainGuard(prefix.clone());
    let dir = temp_dir(tag);
    if !input.is_empty() {
        write_replay(&dir.join("input.csv"), input);
    }
    let cfg = dir.join("graph.toml");
    // `@PCA@` stands for a model with known directions (see `joint_reach_pca`).
    let config = config.replace("@PCA@", &joint_reach_pca(&dir, None).display().to_string());
    std::fs::write(&cfg, config).unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--json", "--for", &format!("{secs}s"), "--config"])
        .arg(&cfg);
    let mut guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len()
            > after_ticks),
        "the graph did not run {after_ticks} ticks"
    );
    during(&prefix, &mut rec);
    let out = rec.record_until_exit(&mut guard);
    assert!(out.status.success(), "scl up: {:?}", out.status);
    std::fs::remove_dir_all(&dir).unwrap();
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        summary["ticks"].as_u64().unwrap() >= u64::from(secs) * 20,
        "{summary}"
    );
    Run {
        rec,
        prefix,
        _domain: domain,
    }
}

fn speed(s: &RobotState) -> f64 {
    s.qdot_rad_s.iter().map(|v| v.abs()).fold(0.0, f64::max)
}

/// Ticks from a stop's start until the arm stood still, checking that it decelerated within
/// the acceleration limits all the way.
fn ticks_to_standstill(states: &[RobotState], from_tick: u64) -> u64 {
    let mut prev: Option<&RobotState> = None;
    for s in states.iter().filter(|s| s.tick >= from_tick) {
        if let Some(p) = prev {
            for j in 0..6 {
                assert!(
                    s.qdot_rad_s[j].abs() <= p.qdot_rad_s[j].abs() + 1e-12,
                    "tick {}: sped up during a stop",
                    s.tick
                );
                let dv = (s.qdot_rad_s[j] - p.qdot_rad_s[j]).abs();
                assert!(
                    dv <= DEFAULT_ACCELERATION_RAD_S2[j] * DT * (1.0 + 1e-9),
                    "tick {} joint {j}: {dv}",
                    s.tick
                );
            }
        }
        if speed(s) == 0.0 {
            return s.tick - from_tick;
        }
        prev = Some(s);
    }
    panic!("the arm never stood still after tick {from_tick}");
}

/// The replayed stick of the tests that drive into a bound: held at `axes`, back to neutral
/// for 0.25 s every 2 s. A released e-stop, and any stop a fault caused (a machine's hold-up
/// of the bridge), lets the arm move again only once the stick has passed through neutral
/// (restart prevention); a constant stick never does.
fn held_with_rests(axes: [f32; 2], secs: u32) -> Vec<InputRow> {
    pulses(axes, 2.0, 0.25, f64::from(secs))
}

const REPLAY: &str = "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n";

#[test]
fn driving_into_a_joint_limit_stops_at_the_margin_and_estop_latches() {
    let _serial = serial();
    let run = run_graph_with_input(
        "limit",
        &format!("[mapper]\nmodel = \"@PCA@\"\n{REPLAY}"),
        &held_with_rests([1.0, 0.0], 14),
        14,
        30,
        |prefix, rec| {
            // E-stop while moving: zero at once, latched until the reset.
            let mut c = scl(prefix);
            c.arg("estop");
            let out = run_polling(c, rec);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            rec.poll_for(Duration::from_millis(300));
            let mut c = scl(prefix);
            c.arg("reset");
            assert!(run_polling(c, rec).status.success());
        },
    );
    // Missed ticks are not this test's subject (a loaded machine may miss one; each is a
    // controlled stop, which the checks below hold to as well).
    let cmds = &run.rec.safe_commands;
    let first = cmds
        .iter()
        .position(|c| c.flags & safe_flags::ESTOP != 0)
        .expect("no e-stop");
    let last = cmds
        .iter()
        .rposition(|c| c.flags & safe_flags::ESTOP != 0)
        .unwrap();
    assert!(
        cmds[first - 1].qdot_rad_s.iter().any(|v| *v != 0.0),
        "not moving before the e-stop"
    );
    assert!(last - first >= 10, "the e-stop did not stay latched");
    for c in &cmds[first..=last] {
        assert!(c.flags & safe_flags::ESTOP != 0 && c.qdot_rad_s.iter().all(|v| *v == 0.0));
    }
    assert!(
        cmds[last + 1..]
            .iter()
            .any(|c| c.qdot_rad_s.iter().any(|v| *v != 0.0)),
        "motion did not resume after the reset"
    );
    // But only once the stick had passed through neutral (it rests every 2 s): the mapper
    // mapped a neutral stick between the reset and the first motion.
    let moved = cmds[last + 1..]
        .iter()
        .find(|c| c.qdot_rad_s.iter().any(|v| *v != 0.0))
        .unwrap();
    assert!(
        run.rec
            .mapper_commands
            .iter()
            .any(|m| m.tick > cmds[last].tick && m.tick <= moved.tick && m.action == [0.0, 0.0]),
        "moved at tick {} after the reset without a neutral input",
        moved.tick
    );
    assert!(
        run.first_command_with(safe_flags::POSITION_LIMITED)
            .is_some(),
        "the position rule never acted"
    );

    // No joint ever went past its margin, and the arm came to rest at one (the Gen3 lite's
    // limits are symmetric).
    let upper = kinematics::gen3_lite::limits().upper_rad;
    let states = run.running();
    for s in &states {
        for j in 0..6 {
            let lim = upper[j] - MARGIN;
            assert!(
                s.q_rad[j].abs() <= lim + 1e-9,
                "tick {} joint {j} at {}",
                s.tick,
                s.q_rad[j]
            );
        }
    }
    let end = states.last().unwrap();
    assert!(
        speed(end) < 1e-9,
        "still moving at the end: {:?}",
        end.qdot_rad_s
    );
    let at_margin = (0..6).any(|j| (end.q_rad[j].abs() - (upper[j] - MARGIN)).abs() < 0.01);
    assert!(
        at_margin,
        "stopped away from any margin: {:?}",
        &end.q_rad[..6]
    );
    // Velocity limits held on every executed command; acceleration limits too, except at the
    // e-stop (zero at once, by design).
    for w in cmds.windows(2) {
        for j in 0..6 {
            assert!(w[1].qdot_rad_s[j].abs() <= DEFAULT_VELOCITY_RAD_S[j] + 1e-12);
            if w[1].tick == w[0].tick + 1 && (w[0].flags | w[1].flags) & safe_flags::ESTOP == 0 {
                let dv = (w[1].qdot_rad_s[j] - w[0].qdot_rad_s[j]).abs();
                assert!(
                    dv <= DEFAULT_ACCELERATION_RAD_S2[j] * DT * (1.0 + 1e-9),
                    "tick {} joint {j}: {dv}",
                    w[1].tick
                );
            }
        }
    }
    run.finish();
}

#[test]
fn a_nan_from_the_mapper_is_a_controlled_stop_for_that_tick() {
    let _serial = serial();
    // Twelve seconds: after the NaN (3 s) the stick rests and pushes again four times, so a
    // stop the machine causes (a held-up bridge's controlled stop, which also waits for
    // neutral) still leaves a later push to resume on.
    let run = run_graph_with_input(
        "nan",
        &format!("[faults]\nmapper_nan_at_tick = 120\n{REPLAY}"),
        &held_with_rests([1.0, 0.0], 12),
        12,
        0,
        |_, _| {},
    );
    let bad = run
        .first_command_with(safe_flags::NON_FINITE)
        .expect("the NaN was not caught");
    assert_eq!(bad.tick, 120);
    assert!(bad.flags & safe_flags::STOP != 0);
    assert!(bad.qdot_rad_s.iter().all(|v| v.is_finite()));
    // The arm's velocity when safety filtered tick 120: what state 120 reports (the command
    // executed at tick 119, or the bridge's own stop had that tick been missed).
    let before = run
        .rec
        .robot_states
        .iter()
        .find(|s| s.tick == 120)
        .expect("state 120 was not recorded");
    assert!(
        before.qdot_rad_s.iter().any(|v| *v != 0.0),
        "not moving before the fault"
    );
    for j in 0..6 {
        // A deceleration within the limits, not a jump.
        assert!(bad.qdot_rad_s[j].abs() <= before.qdot_rad_s[j].abs());
        assert!(
            (bad.qdot_rad_s[j] - before.qdot_rad_s[j]).abs()
                <= DEFAULT_ACCELERATION_RAD_S2[j] * DT * (1.0 + 1e-9)
        );
    }
    // Only that tick: the commands after it are normal again, once the operator's input has
    // passed through neutral (the stick rests every 2 s; until then the arm waits for it).
    assert!(
        run.rec
            .safe_commands
            .iter()
            .filter(|c| c.flags & safe_flags::NON_FINITE != 0)
            .count()
            == 1
    );
    let after: Vec<_> = run
        .rec
        .safe_commands
        .iter()
        .filter(|c| c.tick > 120)
        .collect();
    let resumed = after
        .iter()
        .position(|c| c.flags & safe_flags::STOP == 0)
        .expect("the arm never moved again");
    assert!(resumed > 0, "moved on at once with the stick held");
    assert!(
        after[..resumed]
            .iter()
            .any(|c| c.flags & safe_flags::AWAITING_NEUTRAL != 0),
        "the stop after the NaN did not wait for a neutral input"
    );
    assert!(
        after[resumed..]
            .iter()
            .any(|c| c.flags == 0 && c.qdot_rad_s.iter().any(|v| *v != 0.0)),
        "no normal command after the neutral input"
    );
    run.finish();
}

#[test]
fn a_silent_joystick_stops_the_arm_within_the_configured_age() {
    let _serial = serial();
    let run = run_graph(
        "silent",
        "[joystick]\nscript = \"constant\"\n[faults]\njoystick_silent_after_ticks = 60\n",
        6,
        0,
        |_, _| {},
    );
    let last_sample = run
        .rec
        .joystick_samples
        .iter()
        .rfind(|j| j.tick != ipc_types::NO_TICK)
        .unwrap();
    // The first stale command after the last sample (a command before the joystick's first
    // sample is stale too: no sample at all).
    let stale = *run
        .rec
        .safe_commands
        .iter()
        .find(|c| c.tick > last_sample.tick && c.flags & safe_flags::STALE_JOYSTICK != 0)
        .expect("no stale-joystick stop");
    assert!(stale.flags & safe_flags::STOP != 0);
    // Configured age 100 ms = 4 ticks, plus the tick the last sample answered.
    assert!(
        stale.tick - last_sample.tick <= 4 + 1,
        "stopped at tick {} after the last sample of tick {}",
        stale.tick,
        last_sample.tick
    );
    let states = run.running();
    let t = ticks_to_standstill(&states, stale.tick + 1);
    // From at most 0.48 rad/s at 0.4 rad/s² (joint 3): 1.2 s = 48 ticks.
    assert!(t <= 49, "standstill after {t} ticks");
    assert!(
        states
            .iter()
            .filter(|s| s.tick > stale.tick + 1 + t)
            .all(|s| speed(s) == 0.0)
    );
    run.finish();
}

#[test]
fn robot_states_that_stop_arriving_end_in_a_controlled_stop() {
    let _serial = serial();
    let run = run_graph(
        "nostate",
        "[joystick]\nscript = \"constant\"\n[faults]\nbridge_states_stop_after_ticks = 60\n",
        5,
        0,
        |_, _| {},
    );
    // The recorder sees no state after the fault; the bridge's heartbeat shows every tick
    // missed from then on and the arm's travel coming to a halt.
    assert!(
        run.rec
            .robot_states
            .iter()
            .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
            .all(|s| s.tick < 60)
    );
    let bridge: Vec<_> = run
        .rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Bridge as u32 && s.phase == phase::RUNNING)
        .copied()
        .collect();
    let after: Vec<_> = bridge.iter().filter(|s| s.tick >= 60).collect();
    assert!(
        after.len() > 60,
        "only {} bridge ticks after the fault",
        after.len()
    );
    // From the fault on, every tick is one more miss (counted relative to the misses before
    // it, which a loaded machine may have had).
    assert!(after[0].faults >= 1, "tick {} not counted", after[0].tick);
    for w in after.windows(2) {
        assert_eq!(
            w[1].faults - w[0].faults,
            w[1].tick - w[0].tick,
            "ticks {}..{} not all counted as missed",
            w[0].tick,
            w[1].tick
        );
    }
    // Travel per tick never grows and reaches zero within the stop time (48 ticks).
    let steps: Vec<f64> = after
        .windows(2)
        .map(|w| w[1].joint_travel_rad - w[0].joint_travel_rad)
        .collect();
    assert!(
        steps[0] > 0.0,
        "the arm was not moving when the states stopped"
    );
    for w in steps.windows(2) {
        assert!(w[1] <= w[0] + 1e-12, "sped up during the stop");
    }
    let still = steps
        .iter()
        .position(|d| *d == 0.0)
        .expect("the arm never stopped");
    assert!(still <= 49, "standstill after {still} ticks");
    run.finish();
}

#[test]
fn driving_into_the_table_stops_at_the_plane() {
    let _serial = serial();
    // The subject is the tool's workspace plane (2 cm above the table): the scene's table is
    // put far below, so the whole-arm clearance rule (whose fingers-table stop at 2 cm would
    // hold the tool about 6 cm up) does not act first. At the 0.25 m/s tool speed cap the
    // tool needs about 10 s to get there: 20 s of input.
    let run = run_graph_with_input(
        "table",
        &format!("[mapper]\nmodel = \"@PCA@\"\n[safety.scene]\ntable_z_m = -0.5\n{REPLAY}"),
        &held_with_rests([0.0, -1.0], 20),
        20,
        0,
        |_, _| {},
    );
    assert!(
        run.first_command_with(safe_flags::WORKSPACE_LIMITED)
            .is_some(),
        "the workspace rule never acted"
    );
    let arm = kinematics::Gen3Lite::get().arm();
    let tcp = |s: &RobotState| arm.fk(s.q()).unwrap().translation.vector;
    let states = run.running();
    let mut lowest = f64::MAX;
    for s in &states {
        let p = tcp(s);
        lowest = lowest.min(p.z);
        // The default workspace: above the table plane at 2 cm, inside the box.
        assert!(
            p.z >= 0.02,
            "tick {}: tool at z {:.4} m, in the table",
            s.tick,
            p.z
        );
        assert!(
            p.x.abs() <= 0.8 && p.y.abs() <= 0.8 && p.z <= 1.1,
            "tick {}: out of the box",
            s.tick
        );
    }
    let end = states.last().unwrap();
    assert!(
        speed(end) < 1e-9,
        "still moving at the end: {:?}",
        end.qdot_rad_s
    );
    // It came to rest at the plane (within a centimetre), not short of it.
    assert!(
        lowest < 0.03,
        "the tool never got near the table: lowest z {lowest:.4} m"
    );
    run.finish();
}

/// One drill of the whole-arm protection on the mock arm: the drill map drives `qdot` from
/// the home pose for 20 s (into the table, or folding the arm onto itself), then `scl swap`
/// reverses it for 6 s. The arm stops with every checked pair at or above
/// `stop_distance_m` (0.02 m) and backs out once the command reverses; returns the closest
/// distance reached.
fn whole_arm_drill(tag: &str, qdot: [f64; 6]) -> f64 {
    const STOP_M: f64 = 0.02;
    let spec = |v: [f64; 6]| {
        let list: Vec<String> = v.iter().map(f64::to_string).collect();
        format!("constant:qdot={}", list.join(","))
    };
    let reverse = spec(qdot.map(|v| -v));
    let mut t_swap = 0;
    let run = run_graph(
        tag,
        // The step script rests at neutral between its holds: a hold-up of the machine (a
        // fault stop) re-arms at the next rest.
        &format!(
            "[mapper]\nmodel = \"{}\"\n[joystick]\nscript = \"step\"\n",
            spec(qdot)
        ),
        28,
        800,
        |prefix, rec| {
            t_swap = ipc_types::time::now_ns();
            let mut c = scl(prefix);
            c.args(["swap", &reverse]);
            let out = run_polling(c, rec);
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
        },
    );
    let cmds = &run.rec.safe_commands;
    let checked: Vec<&SafeCommand> = cmds.iter().filter(|c| c.clearance_m.is_finite()).collect();
    assert!(
        checked.len() > 900,
        "{} commands with a clearance",
        checked.len()
    );
    let (closest, at) = checked
        .iter()
        .map(|c| (c.clearance_m, c.tick))
        .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a });
    // Every pair at or above the stop distance on every tick (the filter keeps 1 mm of
    // slack above it for the second-order rest of its one-tick prediction).
    assert!(
        closest >= STOP_M,
        "tick {at}: a pair at {closest:.4} m, below the stop distance"
    );
    let before: Vec<&&SafeCommand> = checked.iter().filter(|c| c.t_ns < t_swap).collect();
    assert!(
        before
            .iter()
            .any(|c| c.flags & safe_flags::CLEARANCE_LIMITED != 0),
        "the clearance rule never acted"
    );
    // Stopped at the obstacle before the swap: the last second commanded nothing (the
    // approach is geometric, each tick a fraction of the gap left, so "nothing" is a
    // micro-radian per second, a nanometre per tick).
    let last = &before[before.len().saturating_sub(40)..];
    assert!(
        last.iter()
            .all(|c| c.qdot_rad_s.iter().all(|v| v.abs() < 1e-6)),
        "still moving before the swap: {:?}",
        last.last().map(|c| c.qdot_rad_s)
    );
    let stopped_at = last.last().map_or(f64::NAN, |c| c.clearance_m);
    assert!(
        stopped_at < 0.03,
        "stopped {stopped_at:.4} m away, not at the obstacle"
    );
    // Reversed: the gap opens.
    let end = checked.last().unwrap().clearance_m;
    assert!(
        end > stopped_at + 0.05,
        "did not back out: {stopped_at:.4} m at the swap, {end:.4} m at the end"
    );
    run.finish();
    closest
}

#[test]
fn the_drill_into_the_table_stops_every_link_at_the_stop_distance_and_backs_out() {
    let _serial = serial();
    // From home, joint 2 negative lowers the tool into the table.
    let closest = whole_arm_drill("drilltable", [0.0, -0.4, 0.0, 0.0, 0.0, 0.0]);
    println!("closest pair distance, table drill: {closest:.4} m");
}

#[test]
fn the_drill_folding_the_wrist_back_stops_at_the_stop_distance_and_backs_out() {
    let _serial = serial();
    // From home, joint 3 positive folds the wrist back towards the base.
    let closest = whole_arm_drill("drillfold", [0.0, 0.0, 0.4, 0.0, 0.0, 0.0]);
    println!("closest pair distance, fold drill: {closest:.4} m");
}

/// Safety does not listen on robot states (it reads them when it needs them, at times it
/// computes): every listener is a wake-up the bridge pays on every tick. In the default
/// graph the mapper and the scripted joystick wait on states, nothing else. Before, safety
/// held a third listener it used only while the e-stop was latched or the mapper silent.
#[test]
fn safety_does_not_listen_on_robot_states() {
    let _serial = serial();
    let mut listeners = None;
    let run = run_graph("nolisten", "", 2, 10, |prefix, _| {
        let graph = transport::Graph::join(prefix, "test-listeners").unwrap();
        listeners = Some(graph.robot_state_listeners().unwrap());
    });
    assert_eq!(listeners, Some(2), "listeners of the robot states");
    run.finish();
}
