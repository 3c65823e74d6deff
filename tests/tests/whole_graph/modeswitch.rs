//! Whole-graph test of mode switching: `scl up --model modeswitch` with a replayed input that
//! holds one axis at a time and presses the mode button between holds; the tool's motion is
//! checked with forward kinematics on the robot states the bridge published.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::process::Stdio;
use std::time::Duration;

use ipc_types::{NO_TICK, NodeRole, RobotState, buttons, safe_flags, state_flags};
use kinematics::{Gen3Lite, pose_error};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, scl, serial, temp_dir, unique_prefix, wait_clean,
};

/// One hold of the input: the mode it runs in, the axes, and the motion expected of the tool:
/// the twist row it drives (0-2 linear x y z, 3-5 angular about x y z) and its sign.
struct Hold {
    mode: &'static str,
    axes: [f32; 2],
    row: usize,
    sign: f64,
}

/// A route that keeps the arm well away from its singularities (the Jacobian's condition
/// number stays between 10 and 14), where the damped least squares follows the twist exactly.
const HOLDS: [Hold; 6] = [
    Hold {
        mode: "x-y",
        axes: [-0.5, 0.0],
        row: 0,
        sign: -1.0,
    },
    Hold {
        mode: "z-yaw",
        axes: [0.0, -0.5],
        row: 2,
        sign: -1.0,
    },
    Hold {
        mode: "z-yaw",
        axes: [0.5, 0.0],
        row: 5,
        sign: 1.0,
    },
    Hold {
        mode: "roll-pitch",
        axes: [0.5, 0.0],
        row: 3,
        sign: 1.0,
    },
    Hold {
        mode: "roll-pitch",
        axes: [0.0, -0.5],
        row: 4,
        sign: -1.0,
    },
    Hold {
        mode: "x-y",
        axes: [0.0, 0.5],
        row: 1,
        sign: 1.0,
    },
];

/// The replayed input: before each hold whose mode differs from the previous one, the mode
/// button is pressed for 0.2 s; each hold lasts 1 s and is followed by 1.5 s of rest, long
/// enough for the arm to come to a stop within the acceleration limits.
fn script() -> String {
    let mut s = String::from("t_s,a0,a1,gripper,buttons\n0.0,0,0,0,0\n");
    let mut t = 0.5;
    let mut mode = "x-y";
    for h in &HOLDS {
        if h.mode != mode {
            s += &format!("{t:.3},0,0,0,{}\n{:.3},0,0,0,0\n", buttons::MODE, t + 0.2);
            t += 0.5;
            mode = h.mode;
        }
        s += &format!(
            "{t:.3},{},{},0,0\n{:.3},0,0,0,0\n",
            h.axes[0],
            h.axes[1],
            t + 1.0
        );
        t += 2.5;
    }
    s += &format!("{t:.3},0,0,0,0\n");
    s
}

#[test]
fn mode_switching_moves_the_tool_along_each_modes_axes() {
    let _serial = serial();
    let prefix = unique_prefix("modes");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("modes");
    std::fs::write(dir.join("input.csv"), script()).unwrap();
    std::fs::write(
        dir.join("graph.toml"),
        "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n",
    )
    .unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut cmd = scl(&prefix);
    cmd.arg("up")
        .arg("--config")
        .arg(dir.join("graph.toml"))
        .args(["--model", "modeswitch", "--for", "20s", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut guard = ChildGuard(Some(cmd.spawn().unwrap()));
    let out = rec.record_until_exit(&mut guard);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up failed: {stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // Missed ticks are not this test's subject (each is a controlled stop); that it ran is.
    assert!(summary["ticks"].as_u64().unwrap() >= 400, "{summary}");

    let states: Vec<RobotState> = rec
        .robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .collect();
    let state_at = |tick: u64| states.iter().find(|s| s.tick == tick).copied().unwrap();
    let samples: Vec<_> = rec
        .joystick_samples
        .iter()
        .filter(|j| j.tick != NO_TICK)
        .copied()
        .collect();
    // The mode button reached the graph as three presses, and the mapper counted three.
    let presses = samples
        .windows(2)
        .filter(|w| w[1].buttons & buttons::MODE != 0 && w[0].buttons & buttons::MODE == 0)
        .count();
    assert_eq!(presses, 3);
    let mapper_status: Vec<_> = rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Mapper as u32 && s.tick != NO_TICK)
        .copied()
        .collect();
    let last = mapper_status.last().unwrap();
    assert_eq!(
        (last.mode, last.mode_switches),
        (1, 3),
        "back in x-y after 3 switches"
    );

    let arm = Gen3Lite::get().arm();
    let mode_index = |name: &str| {
        mapper::modeswitch::Mode::ALL
            .iter()
            .position(|m| m.name() == name)
            .unwrap() as u32
    };
    // The holds as they reached the graph: runs of samples with the axes off rest.
    let mut runs: Vec<(usize, usize)> = Vec::new();
    for (k, j) in samples.iter().enumerate() {
        let moving = j.axes != [0.0, 0.0];
        match runs.last_mut() {
            Some(r) if moving && r.1 == k => r.1 = k + 1,
            _ if moving => runs.push((k, k + 1)),
            _ => {}
        }
    }
    assert_eq!(runs.len(), HOLDS.len(), "holds seen: {runs:?}");
    let mut failures = Vec::new();
    let mut disturbed = Vec::new();
    for (i, h) in HOLDS.iter().enumerate() {
        // The ticks the hold's input answered; the motion runs from the state before the
        // first to the state before the next hold (or the last state), which includes the stop.
        let run = &samples[runs[i].0..runs[i].1];
        assert!(run.iter().all(|j| j.axes == h.axes), "hold {i}: {run:?}");
        let ticks: Vec<u64> = run.iter().map(|j| j.tick).collect();
        assert!(ticks.len() >= 30, "hold {i}: only {} samples", ticks.len());
        let first = ticks[0];
        let next = runs
            .get(i + 1)
            .map_or(states.last().unwrap().tick + 1, |r| samples[r.0].tick);
        let (a, b) = (state_at(first - 1), state_at(next - 1));
        let speed = b.qdot_rad_s.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(
            speed < 1e-3,
            "hold {i}: the arm still moves at {speed} rad/s at its end"
        );
        // The mapper served the hold in the hold's mode.
        for s in mapper_status.iter().filter(|s| ticks.contains(&s.tick)) {
            assert_eq!(
                s.mode,
                mode_index(h.mode) + 1,
                "hold {i} at tick {}",
                s.tick
            );
        }
        let e = pose_error(&arm.fk(a.q()).unwrap(), &arm.fk(b.q()).unwrap());
        let along = e[h.row] * h.sign;
        let (mut lin, mut ang) = (0.0f64, 0.0f64);
        for r in (0..6).filter(|r| *r != h.row) {
            if r < 3 {
                lin = lin.hypot(e[r]);
            } else {
                ang = ang.hypot(e[r]);
            }
        }
        // Which safety rules acted meanwhile, for the message.
        let mut rules = std::collections::BTreeMap::new();
        for c in rec
            .safe_commands
            .iter()
            .filter(|c| c.tick >= first && c.tick < next)
        {
            for (bit, name) in ipc_types::safe_flags::NAMES.iter().enumerate() {
                if c.flags & (1 << bit) != 0 {
                    *rules.entry(*name).or_insert(0) += 1;
                }
            }
        }
        let what = format!(
            "hold {i} ({} {:?}, ticks {first}..{next}, {} input ticks): along {along:.4}, other translation {:.2} mm, other rotation {:.2} mrad; safety rules acted: {rules:?}",
            h.mode,
            h.axes,
            ticks.len(),
            lin * 1e3,
            ang * 1e3
        );
        eprintln!("{what}");
        // Moved along the intended axis, the right way: nominally 0.15 m or 0.425 rad (half
        // deflection for 1 s); less where the joint speed limits cap the twist, more or less as
        // the joint acceleration limits ramp it up and bring it to a stop.
        let nominal = if h.row < 3 { 0.15 } else { 0.425 };
        // A tick the bridge missed or an input that came too late (a loaded machine) stops
        // the arm, and safety then waits for neutral input: the rest of that hold does not
        // move it, as promised. A stop on the two ticks before the hold's first sample counts
        // too (the stick goes from rest to pushed with no rest sample after the stop). Such a
        // hold is checked for direction and leakage only, and at most two of the five may be.
        let from = first.saturating_sub(2);
        let late = safe_flags::STALE_STATE | safe_flags::STALE_JOYSTICK | safe_flags::STALE_COMMAND;
        let missed = states
            .iter()
            .any(|s| s.tick >= from && s.tick < next && s.flags & state_flags::MISSED != 0)
            || rec
                .safe_commands
                .iter()
                .any(|c| c.tick >= from && c.tick < next && c.flags & late != 0);
        let cut_short = missed && rules.contains_key("stop");
        if cut_short {
            disturbed.push(what.clone());
        }
        let shortest = if cut_short { -0.02 } else { 0.4 } * nominal;
        if !(along > shortest && along < 1.5 * nominal) {
            failures.push(what.clone());
        }
        // ... and hardly along the other five: under 1 mm and 3 mrad (measured: 0.07 mm and
        // 0.4 mrad at most, over 9 .. 16 cm or 0.41 .. 0.44 rad). A stop in mid-hold ramps the
        // joints down along the joint-space direction they had while the pose moves on, so the
        // tool drifts off the mode's axis by the Jacobian's change over the stopping distance
        // (measured with the graph held up 35-60 ms every 2 s: up to 3.1 mm and 3.8 mrad):
        // under 1 cm and 10 mrad then.
        let (lin_max, ang_max) = if cut_short {
            (1e-2, 1e-2)
        } else {
            (1e-3, 3e-3)
        };
        if !(lin < lin_max && ang < ang_max) {
            failures.push(what);
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(
        disturbed.len() <= 2,
        "more than two holds cut short by missed ticks: {disturbed:#?}"
    );
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
