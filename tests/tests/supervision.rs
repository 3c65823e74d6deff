//! Whole-graph tests of supervision and live mapper swaps: real `scl up`, `scl swap`,
//! `scl status` and `scl safety` processes over real shared memory.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use ipc_types::{NO_TICK, NodeRole, Prefix, phase, state_flags, time::now_ns};
use kinematics::gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, assert_stop_within_two_ticks, joint_reach_pca, run_polling,
    scl, serial, temp_dir, unique_prefix, wait_clean,
};

const DT: f64 = 0.025;

/// A second, different model: PCA on the joint-reach data with a lower speed scale.
fn slow_model(dir: &Path) -> PathBuf {
    joint_reach_pca(dir, Some(0.3))
}

/// Parses `swapped: mapper A -> B at tick T, X ms after the request, M ticks missed`.
fn parse_swap(stdout: &str) -> (u32, u32, u64, f64, u64) {
    let w: Vec<&str> = stdout.split_whitespace().collect();
    assert_eq!(w[0], "swapped:", "{stdout}");
    let num = |s: &str| s.trim_end_matches(',').to_owned();
    (
        num(w[2]).parse().unwrap(),
        num(w[4]).parse().unwrap(),
        num(w[7]).parse().unwrap(),
        num(w[8]).parse().unwrap(),
        num(w[13]).parse().unwrap(),
    )
}

fn status_json(prefix: &Prefix, rec: &mut Recorder) -> serde_json::Value {
    let mut c = scl(prefix);
    c.args(["status", "--json"]);
    let out = run_polling(c, rec);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

fn stop_up(mut guard: ChildGuard, rec: &mut Recorder) -> serde_json::Value {
    // SAFETY: signalling our own child.
    unsafe {
        libc::kill(guard.child().id() as libc::pid_t, libc::SIGTERM);
    }
    while guard.child().try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
    }
    rec.poll();
    let out = guard.take().wait_with_output().unwrap();
    assert!(out.status.success(), "scl up: {:?}", out.status);
    serde_json::from_slice(&out.stdout).unwrap()
}

fn running_states(rec: &Recorder) -> Vec<ipc_types::RobotState> {
    rec.robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .collect()
}

#[test]
fn twenty_live_swaps_miss_no_tick() {
    let _serial = serial();
    let prefix = unique_prefix("swap");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("swap");
    let slow = slow_model(&dir);
    let corrupt = dir.join("corrupt.safetensors");
    std::fs::write(&corrupt, b"not a model at all").unwrap();

    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "120s", "--json"]);
    let guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 40));

    // `scl status` shows the four nodes alive and mapper 1 active.
    let st = status_json(&prefix, &mut rec);
    let nodes = st["nodes"].as_array().unwrap();
    let alive: Vec<&str> = nodes
        .iter()
        .filter(|n| n["alive"] == true)
        .map(|n| n["role"].as_str().unwrap())
        .collect();
    for role in ["joystick", "mapper", "safety", "bridge"] {
        assert!(alive.contains(&role), "{role} not alive in {st}");
    }
    assert_eq!(st["active_mapper"], 1);

    // A second safety process cannot publish the arm's command.
    let mut second = scl(&prefix);
    second.arg("safety");
    let out = run_polling(second, &mut rec);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains(&format!(
            "cannot create a publisher on `{prefix}/safe_command`"
        )),
        "{err}"
    );

    // A swap to a corrupt model is refused with the reason; mapper 1 keeps running.
    let mut bad = scl(&prefix);
    bad.arg("swap").arg(&corrupt);
    let out = run_polling(bad, &mut rec);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("refused") && err.contains("not a safetensors file"),
        "{err}"
    );

    // Twenty swaps back and forth.
    let mut switches: Vec<(u64, u32)> = Vec::new();
    let mut elapsed_ms = Vec::new();
    let mut expected_old = 1;
    for i in 0..20 {
        let model = if i % 2 == 0 {
            slow.display().to_string()
        } else {
            "bundled".to_owned()
        };
        let mut c = scl(&prefix);
        c.args(["swap", &model]);
        let out = run_polling(c, &mut rec);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "swap {i}: {text} {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let (old, new, tick, ms, missed) = parse_swap(&text);
        assert_eq!(old, expected_old);
        assert_eq!(missed, 0, "swap {i} missed ticks");
        expected_old = new;
        switches.push((tick, new));
        elapsed_ms.push(ms);
    }
    let st = status_json(&prefix, &mut rec);
    assert_eq!(st["active_mapper"], expected_old);
    let summary = stop_up(guard, &mut rec);
    assert_eq!(summary["missed"], 0, "{summary}");
    assert_eq!(summary["swaps"], 20);
    elapsed_ms.sort_by(f64::total_cmp);
    eprintln!(
        "swap: request -> switch-over, median {:.1} ms, max {:.1} ms over 20 swaps",
        elapsed_ms[10], elapsed_ms[19]
    );

    // Every tick executed the command of its own tick.
    let states = running_states(&rec);
    for w in states.windows(2) {
        assert_eq!(w[1].tick, w[0].tick + 1);
        assert_eq!(w[1].applied_tick, w[0].tick, "tick {} missed", w[0].tick);
    }
    // Every executed command came from the mapper active at its tick.
    let first = switches[0].0;
    let active_at = |tick: u64| {
        switches
            .iter()
            .rev()
            .find(|(t, _)| *t <= tick)
            .map_or(1, |(_, id)| *id)
    };
    let mut seen = std::collections::BTreeSet::new();
    for c in &rec.safe_commands {
        assert_eq!(c.mapper_id, active_at(c.tick), "tick {}", c.tick);
        seen.insert(c.mapper_id);
    }
    assert_eq!(
        seen.len(),
        21,
        "commands of every mapper executed: {seen:?}"
    );
    assert!(rec.safe_commands.iter().any(|c| c.tick < first));
    // A change of map never jumps beyond the acceleration limit.
    for w in rec.safe_commands.windows(2) {
        if w[1].tick != w[0].tick + 1 {
            continue;
        }
        for j in 0..6 {
            let dv = (w[1].qdot_rad_s[j] - w[0].qdot_rad_s[j]).abs();
            assert!(
                dv <= DEFAULT_ACCELERATION_RAD_S2[j] * DT * (1.0 + 1e-9),
                "tick {} joint {j}: {dv}",
                w[1].tick
            );
        }
    }
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// The newest heartbeat pid of `role` that differs from `old`, once it is running.
fn restarted_pid(rec: &Recorder, role: NodeRole, old: u32) -> Option<u32> {
    rec.statuses
        .iter()
        .rev()
        .find(|s| {
            s.role == role as u32 && s.pid != old && s.phase == phase::RUNNING && s.handled > 5
        })
        .map(|s| s.pid)
}

#[test]
fn killed_processes_are_restarted_and_the_arm_stops_meanwhile() {
    let _serial = serial();
    let prefix = unique_prefix("restart");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("restart");
    let config = dir.join("graph.toml");
    std::fs::write(
        &config,
        "[supervisor]\nbackoff_initial_ms = 200\n\n[supervisor.restart]\n\
         joystick = \"on-failure\"\nmapper = \"on-failure\"\nsafety = \"on-failure\"\n\
         bridge = \"on-failure\"\n",
    )
    .unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "120s", "--json", "--config"])
        .arg(&config);
    let guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 40));

    for role in [
        NodeRole::Mapper,
        NodeRole::Safety,
        NodeRole::Joystick,
        NodeRole::Bridge,
    ] {
        let pid = rec.pid_of(role).unwrap();
        let before = rec.robot_states.len();
        let last_before = *rec.robot_states.last().unwrap();
        let t_kill = now_ns();
        // SAFETY: signalling a process of the graph under test.
        unsafe {
            libc::kill(pid as libc::pid_t, libc::SIGKILL);
        }
        assert!(
            rec.poll_until(Duration::from_secs(20), |r| restarted_pid(r, role, pid)
                .is_some()),
            "{} was not restarted",
            role.name()
        );
        let n = rec.robot_states.len();
        assert!(rec.poll_until(Duration::from_secs(10), |r| r.robot_states.len() > n + 40));
        let after: Vec<_> = rec.robot_states[before..]
            .iter()
            .filter(|s| s.t_ns > t_kill)
            .copied()
            .collect();
        if role == NodeRole::Bridge {
            // The new bridge continues the tick count from a stop, where the arm was.
            let first = after[0];
            assert!(first.tick > last_before.tick, "ticks went back");
            assert_eq!(
                first.applied_tick, NO_TICK,
                "the new bridge did not start from a stop"
            );
            for j in 0..6 {
                assert!(
                    (first.q_rad[j] - last_before.q_rad[j]).abs() < 0.05,
                    "joint {j} jumped"
                );
            }
        } else {
            assert_stop_within_two_ticks(&after, role.name());
        }
        // Commands resume, and none computed before the kill is executed after the stop.
        let missed: Vec<u64> = after
            .iter()
            .rev()
            .take(20)
            .filter(|s| s.applied_tick != s.tick - 1)
            .map(|s| s.tick)
            .collect();
        assert!(
            missed.is_empty(),
            "{}: commands did not resume: ticks {missed:?} executed nothing (kill before tick {}, last tick {})",
            role.name(),
            after[0].tick,
            after.last().unwrap().tick
        );
        for s in after.iter().skip(1) {
            if s.applied_tick == NO_TICK {
                continue;
            }
            assert_eq!(s.applied_tick, s.tick - 1);
            let c = rec
                .safe_commands
                .iter()
                .find(|c| c.tick == s.applied_tick)
                .expect("executed command not recorded");
            assert!(
                c.t_ns > t_kill,
                "tick {} executed a command from before the kill",
                s.tick
            );
        }
    }
    let summary = stop_up(guard, &mut rec);
    assert_eq!(summary["restarts"], 4, "{summary}");
    assert!(summary["failure"].is_null());
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
