//! Whole-graph tests of the joystick process's sources: an input recorded from one run plays
//! back in another with its timing, and a device that is not there gives neutral, flagged
//! samples on every tick while the arm stays still.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::Path;
use std::process::{Output, Stdio};
use std::time::Duration;

use ipc_types::{JoystickInput, NO_TICK, NodeRole, buttons, state_flags};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, scl, serial, temp_dir, unique_prefix, wait_clean,
};

/// Runs `scl up --config CONFIG --for SECS --json` under `prefix`, recording the graph.
fn up(prefix: &ipc_types::Prefix, config: &Path, secs: &str) -> (Recorder, Output) {
    let mut rec = Recorder::join(prefix);
    let mut cmd = scl(prefix);
    cmd.arg("up")
        .arg("--config")
        .arg(config)
        .args(["--for", secs, "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut guard = ChildGuard(Some(cmd.spawn().unwrap()));
    let out = rec.record_until_exit(&mut guard);
    (rec, out)
}

/// The successive distinct inputs of `samples` (axes, gripper, buttons), with the first tick
/// each was published at, without the neutral ones at either end.
fn changes(samples: &[JoystickInput]) -> Vec<(u64, [f32; 2], u32)> {
    let mut v: Vec<(u64, [f32; 2], u32)> = Vec::new();
    for s in samples {
        if v.last().is_none_or(|l| (l.1, l.2) != (s.axes, s.buttons)) {
            v.push((s.tick, s.axes, s.buttons));
        }
    }
    let neutral = |c: &(u64, [f32; 2], u32)| c.1 == [0.0, 0.0] && c.2 == 0;
    while v.first().is_some_and(neutral) {
        v.remove(0);
    }
    while v.last().is_some_and(neutral) {
        v.pop();
    }
    v
}

#[test]
fn a_recorded_input_replays_with_its_timing() {
    let _serial = serial();
    let dir = temp_dir("replay");
    // Record the step script (holds of 0.6 s, rests of 0.3 s) for 4 s.
    let prefix = unique_prefix("rec");
    let _domain = DomainGuard(prefix.clone());
    let record = dir.join("record.toml");
    std::fs::write(
        &record,
        "[joystick]\nscript = \"step\"\nstep_hold_s = 0.6\nstep_rest_s = 0.3\nrecord_input = \"input.csv\"\n",
    )
    .unwrap();
    let (rec, out) = up(&prefix, &record, "4s");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    let text = std::fs::read_to_string(dir.join("input.csv")).unwrap();
    let rows: Vec<(f64, [f32; 2], u32)> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("t_s"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[0].parse().unwrap(),
                [f[1].parse().unwrap(), f[2].parse().unwrap()],
                f[4].parse().unwrap(),
            )
        })
        .collect();
    // Holds and rests of the script, each a row (the last row ends the recording).
    assert!(rows.len() >= 8, "{text}");

    // Play it back in a fresh graph.
    let prefix = unique_prefix("play");
    let _domain = DomainGuard(prefix.clone());
    let play = dir.join("play.toml");
    std::fs::write(
        &play,
        "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n",
    )
    .unwrap();
    let (rec, out) = up(&prefix, &play, "6s");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let played = changes(&rec.joystick_samples);
    let mut expected: Vec<(f64, [f32; 2], u32)> = rows[..rows.len() - 1].to_vec();
    expected.dedup_by(|b, a| (a.1, a.2) == (b.1, b.2));
    let neutral = |r: &(f64, [f32; 2], u32)| r.1 == [0.0, 0.0] && r.2 == 0;
    while expected.first().is_some_and(neutral) {
        expected.remove(0);
    }
    while expected.last().is_some_and(neutral) {
        expected.pop();
    }
    let values = |v: &[(f64, [f32; 2], u32)]| v.iter().map(|r| (r.1, r.2)).collect::<Vec<_>>();
    let played_values: Vec<_> = played.iter().map(|c| (c.1, c.2)).collect();
    assert_eq!(played_values, values(&expected), "replayed inputs differ");
    // With the recording's timing: each change a tick count from the first that matches its
    // time in the file, to within 4 ticks (100 ms).
    let (t0, k0) = (expected[0].0, played[0].0);
    for (e, p) in expected.iter().zip(&played) {
        let want = ((e.0 - t0) * 40.0).round() as i64;
        let got = p.0 as i64 - k0 as i64;
        assert!(
            (got - want).abs() <= 4,
            "change at {} s came {got} ticks in, not {want}",
            e.0
        );
    }
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_missing_device_gives_neutral_flagged_samples_and_no_motion() {
    let _serial = serial();
    let dir = temp_dir("nodevice");
    let prefix = unique_prefix("nodev");
    let _domain = DomainGuard(prefix.clone());
    let config = dir.join("graph.toml");
    std::fs::write(
        &config,
        "[joystick]\nsource = \"evdev\"\ndevice = \"/dev/input/scl-test-no-such-device\"\n",
    )
    .unwrap();
    let (rec, out) = up(&prefix, &config, "3s");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("scl-test-no-such-device"), "{stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // Missed ticks are not this test's subject: each is a controlled stop.
    assert_eq!(summary["joint_travel_rad"].as_f64(), Some(0.0), "{summary}");
    // Every sample is neutral and flagged, and every robot tick got one.
    assert!(!rec.joystick_samples.is_empty());
    for s in &rec.joystick_samples {
        assert_eq!(
            (s.axes, s.gripper, s.buttons),
            ([0.0, 0.0], 0.0, buttons::NO_DEVICE)
        );
    }
    let answered: Vec<u64> = rec
        .joystick_samples
        .iter()
        .map(|s| s.tick)
        .filter(|t| *t != NO_TICK)
        .collect();
    let states: Vec<u64> = rec
        .robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .map(|s| s.tick)
        .collect();
    assert!(states.len() > 80);
    for t in &states[..states.len() - 1] {
        assert!(answered.contains(t), "tick {t} was not answered");
    }
    // The joystick counts the ticks it had no device in its heartbeat.
    let faults = rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Joystick as u32)
        .map(|s| s.faults)
        .max()
        .unwrap();
    assert!(faults > 80, "{faults}");
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_late_sampling_joystick_is_executed_a_fraction_of_a_period_after_it_read_the_stick() {
    // With `wait = "predictive"` the joystick reads its input a margin (here 2 ms) before
    // each tick, so the command executed at tick k carries a sample read shortly before
    // tick k's state: not one read a period earlier, right after tick k-1's, nor one that
    // answers tick k itself. Counts carried in the messages, no wall-clock limit: the share
    // of commands whose sample was read in the quarter period before their state.
    let _serial = serial();
    let dir = temp_dir("latejoy");
    let prefix = unique_prefix("latejoy");
    let _domain = DomainGuard(prefix.clone());
    let config = dir.join("graph.toml");
    std::fs::write(
        &config,
        "[graph]\nwait = \"predictive\"\nrealtime = false\n[joystick]\nsample_margin_us = 2000\n",
    )
    .unwrap();
    let file = dir.join("run.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut cmd = scl(&prefix);
    cmd.arg("up")
        .arg("--config")
        .arg(&config)
        .args(["--for", "5s", "--json", "--record"])
        .arg(&file)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut guard = ChildGuard(Some(cmd.spawn().unwrap()));
    let out = rec.record_until_exit(&mut guard);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let period_ns = 25_000_000i64;
    // From tick 10 on: the joystick places the grid after a few states.
    let used: Vec<i64> = rec
        .safe_commands
        .iter()
        .filter(|c| c.tick >= 10 && c.joystick_t_ns != 0)
        .map(|c| c.state_t_ns as i64 - c.joystick_t_ns as i64)
        .collect();
    assert!(used.len() > 120, "{} commands", used.len());
    let fresh = used
        .iter()
        .filter(|age| **age > 0 && **age < period_ns / 4)
        .count();
    let missed = rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Joystick as u32)
        .map(|s| s.held_up)
        .max()
        .unwrap();
    let mut ages: Vec<i64> = used.clone();
    ages.sort_unstable();
    let what = format!(
        "{fresh} of {} commands carry a sample read in the quarter period before their \
         state; the joystick counted {missed} late samples missed; sample age at the state \
         p50 {} µs",
        used.len(),
        ages[ages.len() / 2] / 1000
    );
    eprintln!("{what}");
    assert!(fresh * 10 >= used.len() * 8, "{what}");
    assert!(u64::from(missed) * 5 <= used.len() as u64, "{what}");
    // The extra samples change nothing for replay: it is still bit for bit.
    let replay = std::process::Command::new(scl_tests::scl_binary())
        .env("SCL_LOG", "warn")
        .args(["replay", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    assert_eq!(replay.status.code(), Some(0), "{v}");
    assert_eq!(v["diverged"].as_u64(), Some(0), "{v}");
    assert_eq!(v["identical"], v["ticks"], "{v}");
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
