//! Whole-graph tests of supervision and live mapper swaps: real `scl up`, `scl swap`,
//! `scl status` and `scl safety` processes over real shared memory.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use ipc_types::{
    NO_TICK, NodeRole, Prefix, RobotState, phase, safe_flags, state_flags, time::now_ns,
};
use kinematics::gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, Signal, assert_stop_within_two_ticks, joint_reach_pca,
    leftovers, run_polling, scl, serial, temp_dir, unique_prefix, wait_clean,
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

/// `scl swap MODEL` on the running graph, which must succeed; its parsed answer
/// ([`parse_swap`]).
fn swap(prefix: &Prefix, rec: &mut Recorder, model: &str) -> (u32, u32, u64, f64, u64) {
    let mut c = scl(prefix);
    c.args(["swap", model]);
    let out = run_polling(c, rec);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "swap to {model}: {text} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    parse_swap(&text)
}

/// The mapper active at `tick`, from the swaps' `(switch tick, new mapper)` in order (mapper 1
/// before the first).
fn active_at(switches: &[(u64, u32)], tick: u64) -> u32 {
    switches
        .iter()
        .rev()
        .find(|(t, _)| *t <= tick)
        .map_or(1, |(_, id)| *id)
}

/// A change of map never jumps beyond the acceleration limit: no command changed the arm's
/// speed by more than `accel[j] * DT` on each joint `j` of `accel`
/// ([`scl_tests::assert_acceleration_limited`]).
fn assert_acceleration_limited(rec: &Recorder, accel: &[f64]) {
    let checked = scl_tests::assert_acceleration_limited(
        &rec.robot_states,
        &rec.safe_commands,
        accel,
        DT,
        "swaps",
    );
    assert!(checked > 20, "{checked} commands checked");
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

/// Stops `scl up` with SIGTERM; see [`stop_up_with`].
fn stop_up(guard: ChildGuard, rec: &mut Recorder) -> serde_json::Value {
    stop_up_with(guard, rec, Signal::SIGTERM)
}

/// Stops `scl up` with `signal` (SIGTERM, or SIGINT as a terminal's Ctrl-C sends it) and
/// returns its JSON summary, after checking the shutdown order: the bridge stopped the arm
/// and published its last state, flagged `SHUTDOWN`, before any other process of the graph
/// said it was stopping.
fn stop_up_with(mut guard: ChildGuard, rec: &mut Recorder, signal: Signal) -> serde_json::Value {
    rec.poll();
    let t_signal = now_ns();
    scl_tests::send_signal(guard.child().id(), signal);
    let out = rec.record_until_exit(&mut guard);
    assert!(out.status.success(), "scl up: {:?}", out.status);

    // The bridge stopped the arm first: its last state says so, with the arm at rest.
    let last = *rec.robot_states.last().unwrap();
    assert!(
        last.flags & state_flags::SHUTDOWN != 0,
        "signal {signal}: the last robot state is not the bridge's shutdown state: {last:?}"
    );
    assert!(
        last.t_ns > t_signal,
        "signal {signal}: shutdown state before the signal"
    );
    assert!(
        last.qdot_rad_s.iter().all(|v| *v == 0.0),
        "signal {signal}: the arm was still moving at shutdown: {:?}",
        last.qdot_rad_s
    );
    // Nothing upstream of the bridge went first: no tick missed between signal and shutdown,
    // but ticks the machine took from the bridge meanwhile (its `held_up` count, grown since
    // its last heartbeat before the signal).
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let held_up_before = rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Bridge as u32 && s.t_ns <= t_signal)
        .map(|s| u64::from(s.held_up))
        .max()
        .unwrap_or(0);
    let held_up = summary["held_up"].as_u64().unwrap() - held_up_before;
    let missed: Vec<u64> = rec
        .robot_states
        .iter()
        .filter(|s| s.t_ns > t_signal && s.flags & state_flags::MISSED != 0)
        .map(|s| s.tick)
        .collect();
    assert!(
        missed.len() as u64 <= held_up,
        "signal {signal}: ticks {missed:?} missed during the shutdown, {held_up} held up by the machine"
    );
    // The other processes said they were stopping only after the bridge's last state.
    let stopping: Vec<_> = rec
        .statuses
        .iter()
        .filter(|s| s.phase == phase::STOPPING && s.t_ns > t_signal)
        .collect();
    assert!(
        stopping.iter().any(|s| s.role == NodeRole::Bridge as u32),
        "signal {signal}: no stopping heartbeat of the bridge"
    );
    for s in &stopping {
        if s.role != NodeRole::Bridge as u32 {
            assert!(
                s.t_ns > last.t_ns,
                "signal {signal}: the {} process (pid {}) stopped before the bridge",
                NodeRole::from_u32(s.role).map_or("?", NodeRole::name),
                s.pid
            );
        }
    }
    for role in [NodeRole::Safety, NodeRole::Mapper, NodeRole::Joystick] {
        assert!(
            stopping.iter().any(|s| s.role == role as u32),
            "signal {signal}: no stopping heartbeat of the {} process",
            role.name()
        );
    }
    summary
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
    let log = dir.join("up.log");
    up.stderr(std::fs::File::create(&log).unwrap());
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
    let mut missed_in_swaps = 0;
    for i in 0..20 {
        let model = if i % 2 == 0 {
            slow.display().to_string()
        } else {
            "bundled".to_owned()
        };
        let (old, new, tick, ms, missed) = swap(&prefix, &mut rec, &model);
        assert_eq!(old, expected_old);
        missed_in_swaps += missed;
        expected_old = new;
        switches.push((tick, new));
        elapsed_ms.push(ms);
    }
    let st = status_json(&prefix, &mut rec);
    assert_eq!(st["active_mapper"], expected_old);
    let summary = stop_up(guard, &mut rec);
    // No tick missed, in the swaps or between them, but those the machine took from the
    // bridge (its process not run for more than a period), which the graph cannot keep.
    let missed = summary["missed"].as_u64().unwrap();
    assert!(missed_in_swaps <= missed, "{summary}");
    scl_tests::assert_misses_only_held_up(
        &summary,
        &std::fs::read_to_string(&log).unwrap(),
        "20 swaps",
    );
    assert_eq!(summary["swaps"], 20);
    elapsed_ms.sort_by(f64::total_cmp);
    eprintln!(
        "swap: request -> switch-over, median {:.1} ms, max {:.1} ms over 20 swaps",
        elapsed_ms[10], elapsed_ms[19]
    );

    // Every tick executed the command of its own tick, but those the machine held up
    // (checked above), which executed none.
    let states = running_states(&rec);
    scl_tests::assert_each_tick_ran_its_own_command(&states, &summary);

    // Every executed command came from the mapper active at its tick.
    let first = switches[0].0;
    let mut seen = std::collections::BTreeSet::new();
    for c in &rec.safe_commands {
        assert_eq!(c.mapper_id, active_at(&switches, c.tick), "tick {}", c.tick);
        seen.insert(c.mapper_id);
    }
    assert_eq!(
        seen.len(),
        21,
        "commands of every mapper executed: {seen:?}"
    );
    assert!(rec.safe_commands.iter().any(|c| c.tick < first));
    assert_acceleration_limited(&rec, &DEFAULT_ACCELERATION_RAD_S2);
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// The Gen3 (seven joints) under the same supervision: its mock arm at 40 Hz with mode
/// switching, four live swaps to the go-to map and back, no
/// miss the machine did not take, seven joints in every state and command, the Gen3's
/// acceleration limit per tick on each, and the bridge first at the stop.
#[test]
fn a_gen3_graph_swaps_maps_live_and_stops_in_order() {
    let _serial = serial();
    let prefix = unique_prefix("gen3swap");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("gen3swap");
    let cfg = dir.join("graph.toml");
    std::fs::write(&cfg, "[graph]\nrobot = \"gen3\"\n").unwrap();
    let accel = kinematics::RobotProfile::by_name("gen3")
        .unwrap()
        .limits()
        .max_acceleration_rad_s2
        .clone();
    assert_eq!(accel.len(), 7);

    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.arg("up").arg("--config").arg(&cfg).args([
        "--for",
        "120s",
        "--json",
        "--model",
        "modeswitch",
    ]);
    let log = dir.join("up.log");
    up.stderr(std::fs::File::create(&log).unwrap());
    let guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 40));

    let mut expected_old = 1;
    let mut missed_in_swaps = 0;
    let mut switches: Vec<(u64, u32)> = Vec::new();
    for i in 0..4 {
        let model = if i % 2 == 0 {
            "goto:pose=retract"
        } else {
            "modeswitch"
        };
        let (old, new, tick, _, missed) = swap(&prefix, &mut rec, model);
        assert_eq!(old, expected_old);
        expected_old = new;
        missed_in_swaps += missed;
        switches.push((tick, new));
        // Some ticks of each map.
        let until = tick + 20;
        assert!(rec.poll_until(Duration::from_secs(10), |r| {
            r.robot_states.last().is_some_and(|s| s.tick > until)
        }));
    }
    let summary = stop_up(guard, &mut rec);
    let missed = summary["missed"].as_u64().unwrap();
    assert!(missed_in_swaps <= missed, "{summary}");
    scl_tests::assert_misses_only_held_up(
        &summary,
        &std::fs::read_to_string(&log).unwrap(),
        "Gen3 swaps",
    );
    assert_eq!(summary["swaps"], 4);
    assert!(
        summary["joint_travel_rad"].as_f64().unwrap() > 0.0,
        "{summary}"
    );

    assert!(rec.robot_states.iter().all(|s| s.n_joints == 7));
    for c in &rec.safe_commands {
        assert_eq!(c.n_joints, 7, "tick {}", c.tick);
        assert_eq!(c.mapper_id, active_at(&switches, c.tick), "tick {}", c.tick);
    }
    assert_acceleration_limited(&rec, &accel);
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// The robot states published after `t_ns`.
fn states_after(rec: &Recorder, t_ns: u64) -> Vec<RobotState> {
    rec.robot_states
        .iter()
        .filter(|s| s.t_ns > t_ns)
        .copied()
        .collect()
}

/// Whether a state reports a stop (controlled, decided by safety, or the bridge's last).
fn is_stop(s: &RobotState) -> bool {
    s.flags & (state_flags::STOPPING | state_flags::SAFETY_STOP | state_flags::SHUTDOWN) != 0
}

/// Whether the state's previous tick executed its own command.
fn executed(s: &RobotState) -> bool {
    s.applied_tick != NO_TICK && s.applied_tick + 1 == s.tick
}

/// The last tick of the first run of `n` consecutive ticks in `states` that each executed
/// their own command and were not stops.
fn executed_run(states: &[RobotState], n: usize) -> Option<u64> {
    let mut run = 0;
    let mut prev: Option<u64> = None;
    for s in states {
        let ok = executed(s) && !is_stop(s);
        run = match (ok, prev) {
            (false, _) => 0,
            (true, Some(p)) if s.tick == p + 1 => run + 1,
            (true, _) => 1,
        };
        prev = Some(s.tick);
        if run >= n {
            return Some(s.tick);
        }
    }
    None
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
        // The step script's stick returns to neutral every 1.3 s: after each kill the arm
        // moves again only once it has (restart prevention); the circle never does.
        "[joystick]\nscript = \"step\"\nstep_hold_s = 1.0\nstep_rest_s = 0.3\n\n\
         [supervisor]\nbackoff_initial_ms = 200\n\n[supervisor.restart]\n\
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
        let last_before = *rec.robot_states.last().unwrap();
        let t_kill = now_ns();
        scl_tests::send_signal(pid, Signal::SIGKILL);
        assert!(
            rec.poll_until(Duration::from_secs(20), |r| restarted_pid(r, role, pid)
                .is_some()),
            "{} was not restarted",
            role.name()
        );
        // The states of the ticks after the kill, up to a stop (the bridge: its first).
        assert!(
            rec.poll_until(Duration::from_secs(10), |r| {
                let after = states_after(r, t_kill);
                after.len() > 3 && (role == NodeRole::Bridge || after.iter().any(is_stop))
            }),
            "{}: no state reported a stop",
            role.name()
        );
        let after = states_after(&rec, t_kill);
        let stopped_at = if role == NodeRole::Bridge {
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
            0
        } else {
            assert_stop_within_two_ticks(&after, role.name())
        };
        // Commands resume: 20 consecutive ticks executed somewhere after the stop (a single
        // miss under load elsewhere does not matter).
        let resumed = rec.poll_until(Duration::from_secs(20), |r| {
            executed_run(&states_after(r, t_kill)[stopped_at..], 20).is_some()
        });
        let after = states_after(&rec, t_kill);
        assert!(
            resumed,
            "{}: commands did not resume for 20 consecutive ticks: executed ticks {:?} (kill before tick {}, last tick {})",
            role.name(),
            after
                .iter()
                .filter(|s| executed(s))
                .map(|s| s.tick)
                .collect::<Vec<_>>(),
            after[0].tick,
            after.last().unwrap().tick
        );
        // No command from before the kill is executed after it. Every executed command of a
        // tick whose state was published after the kill was mapped from that state (by a
        // mapper after the kill), not an older command reissued; after a joystick kill, once
        // the stop was commanded, every executed command that is not itself a stop was
        // mapped from a sample the restarted joystick took after the kill.
        let first_tick = after[0].tick;
        let stop_tick = after[stopped_at].tick.saturating_sub(1);
        let mut checked = 0;
        for s in &after {
            if s.applied_tick == NO_TICK || s.applied_tick < first_tick {
                continue;
            }
            assert_eq!(s.applied_tick, s.tick - 1);
            let c = rec
                .safe_commands
                .iter()
                .rev()
                .find(|c| c.tick == s.applied_tick)
                .expect("executed command not recorded");
            assert!(
                c.state_t_ns > t_kill && c.mapper_t_ns > t_kill,
                "{}: tick {} executed a command mapped before the kill ({} ns before)",
                role.name(),
                c.tick,
                t_kill.saturating_sub(c.mapper_t_ns)
            );
            if role == NodeRole::Joystick && c.tick >= stop_tick && c.flags & safe_flags::STOP == 0
            {
                assert!(
                    c.joystick_t_ns > t_kill,
                    "tick {} moved the arm on a joystick sample from before the kill ({} ns before)",
                    c.tick,
                    t_kill.saturating_sub(c.joystick_t_ns)
                );
            }
            checked += 1;
        }
        assert!(
            checked >= 10,
            "{}: only {checked} executed commands checked",
            role.name()
        );
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

/// Polls until the process `pid` is gone (reaped by its parent), up to `timeout`.
fn wait_gone(rec: &mut Recorder, pid: u32, timeout: Duration) -> bool {
    let proc = PathBuf::from(format!("/proc/{pid}"));
    rec.poll_until(timeout, |_| !proc.exists())
}

/// The pid of the mapper process with id `id`, from its heartbeats.
fn mapper_pid(rec: &Recorder, id: u32) -> Option<u32> {
    rec.statuses
        .iter()
        .rev()
        .find(|s| s.role == NodeRole::Mapper as u32 && s.mapper_id == id)
        .map(|s| s.pid)
}

#[test]
fn a_swap_that_never_warms_up_is_refused_and_the_old_mapper_keeps_driving() {
    let _serial = serial();
    let prefix = unique_prefix("swapfail");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("swapfail");
    let slow = slow_model(&dir);
    // No new mapper can ever produce this many valid ticks before the swap times out.
    let config = dir.join("graph.toml");
    std::fs::write(
        &config,
        // The step script's stick returns to neutral every 2.5 s, so a tick the machine takes
        // from the bridge (a fault: the arm then waits for neutral input) does not stop the
        // old mapper's driving for good.
        "[joystick]\nscript = \"step\"\n\n\
         [supervisor]\nswap_valid_ticks = 1000000\nswap_timeout_s = 4.0\n",
    )
    .unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "120s", "--json", "--config"])
        .arg(&config);
    let guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 40));
    let old_pid = mapper_pid(&rec, 1).unwrap();
    let t_first = now_ns();

    // 1. The new mapper starts and maps, but never long enough: refused at the timeout.
    let mut c = scl(&prefix);
    c.arg("swap").arg(&slow);
    let out = run_polling(c, &mut rec);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("refused")
            && err.contains("valid consecutive commands")
            && err.contains("1000000 needed"),
        "{err}"
    );
    assert!(
        rec.mapper_commands
            .iter()
            .any(|c| c.mapper_id == 2 && c.t_ns > t_first),
        "the new mapper never produced a command"
    );
    let new_pid = mapper_pid(&rec, 2).expect("no heartbeat of the new mapper");
    assert!(
        wait_gone(&mut rec, new_pid, Duration::from_secs(10)),
        "the refused mapper (pid {new_pid}) is still running"
    );
    let t_refused = now_ns();
    assert!(
        rec.poll_until(Duration::from_secs(10), |r| {
            executed_run(&states_after(r, t_refused), 20).is_some()
        }),
        "the old mapper did not keep driving after the first refusal"
    );

    // 2. The new mapper is killed during its warm-up: refused, naming it.
    let mut c = scl(&prefix);
    c.args(["swap", "bundled"]);
    let mut swap = c
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    assert!(
        rec.poll_until(Duration::from_secs(3), |r| mapper_pid(r, 3).is_some()),
        "the second new mapper never reported"
    );
    let victim = mapper_pid(&rec, 3).unwrap();
    scl_tests::send_signal(victim, Signal::SIGKILL);
    while swap.try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
    }
    let out = swap.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("refused")
            && err.contains(&format!(
                "the mapper process (id 3, pid {victim}) was killed by signal 9"
            )),
        "{err}"
    );
    let t_refused = now_ns();
    assert!(
        rec.poll_until(Duration::from_secs(10), |r| {
            executed_run(&states_after(r, t_refused), 20).is_some()
        }),
        "the old mapper did not keep driving after the second refusal"
    );

    // The active mapper is unchanged, the same process as before.
    let st = status_json(&prefix, &mut rec);
    assert_eq!(st["active_mapper"], 1, "{st}");
    assert_eq!(mapper_pid(&rec, 1), Some(old_pid));
    assert!(
        rec.statuses
            .iter()
            .any(|s| s.pid == old_pid && s.phase == phase::RUNNING && s.t_ns > t_refused),
        "the old mapper stopped running"
    );
    // Only the old mapper ever reached the arm, and neither swap stopped it: no stop decided
    // by safety (a hold, a stale or missing input) from the first request on. The stops
    // allowed are the machine's: a command computed on a state the machine delivered late
    // (stale state alone: the new mappers' start-up shares two cores with the graph), and
    // restart prevention's after a tick the machine took from the bridge or after such a
    // stop, waiting for the stick's next rest.
    let machine_only = |flags: u32| {
        flags & safe_flags::STALE_STATE != 0
            && flags
                & (safe_flags::STALE_JOYSTICK
                    | safe_flags::STALE_COMMAND
                    | safe_flags::HOLD
                    | safe_flags::NON_FINITE
                    | safe_flags::BAD_SHAPE
                    | safe_flags::ESTOP
                    | safe_flags::DEADMAN)
                == 0
    };
    for c in &rec.safe_commands {
        assert_eq!(
            c.mapper_id, 1,
            "tick {} came from mapper {}",
            c.tick, c.mapper_id
        );
    }
    let after = states_after(&rec, t_first);
    for (i, s) in after.iter().enumerate() {
        if s.flags & state_flags::SAFETY_STOP == 0 {
            continue;
        }
        let c = rec
            .safe_commands
            .iter()
            .rev()
            .find(|c| c.tick == s.applied_tick)
            .expect("executed command not recorded");
        let after_the_machine = after[..i].iter().any(|m| {
            m.applied_tick == NO_TICK
                || rec
                    .safe_commands
                    .iter()
                    .any(|x| x.tick == m.applied_tick && machine_only(x.flags))
        });
        assert!(
            machine_only(c.flags)
                || (c.flags & safe_flags::AWAITING_NEUTRAL != 0 && after_the_machine),
            "tick {}: safety stopped the arm during a refused swap (flags {:#x})",
            s.tick,
            c.flags
        );
    }
    let summary = stop_up(guard, &mut rec);
    assert_eq!(summary["swaps"], 0, "{summary}");
    assert_eq!(summary["restarts"], 0, "{summary}");
    assert!(summary["failure"].is_null(), "{summary}");
    assert_eq!(summary["active_mapper"], 1, "{summary}");
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn ctrl_c_stops_the_bridge_first_and_leaves_nothing_behind() {
    let _serial = serial();
    let prefix = unique_prefix("sigint");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "120s", "--json"]);
    let guard = ChildGuard(Some(up.stdout(Stdio::piped()).spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 40));
    let summary = stop_up_with(guard, &mut rec, Signal::SIGINT);
    assert!(summary["failure"].is_null(), "{summary}");
    assert!(summary["ticks"].as_u64().unwrap() > 40, "{summary}");
    // `scl up` left no dead process's resources behind; only the observer is still there.
    assert_eq!(transport::graph::cleanup_dead_nodes(&prefix).unwrap(), 0);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// A command that asks a graph (`status`, `estop`, `reset`, `swap`, `top --once`) on a prefix
/// where none runs fails, saying so, and leaves nothing in shared memory (before: each exited
/// having created the prefix's iceoryx2 files, and `top --once` exited 0).
#[test]
fn commands_on_a_prefix_with_no_graph_fail_and_leave_no_shared_memory() {
    let cases: [&[&str]; 6] = [
        &["status"],
        &["status", "--json"],
        &["estop"],
        &["reset"],
        &["swap", "bundled"],
        &["top", "--once"],
    ];
    for args in cases {
        let prefix = unique_prefix("nograph");
        let out = scl(&prefix).args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "scl {args:?} succeeded: {stderr}");
        assert!(
            stderr.contains("no graph is running under the prefix"),
            "scl {args:?}: {stderr}"
        );
        assert_eq!(leftovers(&prefix), Vec::<String>::new(), "scl {args:?}");
    }
}
