//! Whole-graph tests of what must not restart the arm: a mapper SIGKILLed and restarted by
//! the supervisor (policy `on-failure`) while the stick is held deflected leaves the arm
//! stopped until the stick has returned to neutral (restart prevention), and an e-stop pressed
//! on the joystick while the mapper is dead latches at once and holds until `scl reset`. Real
//! `scl up` processes, a replayed joystick input, real shared memory.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use ipc_types::{
    NodeRole, Prefix, RobotState, SafeCommand, buttons, phase, safe_flags, safety_state,
    state_flags, time::now_ns,
};
use scl_tests::{
    ChildGuard, DomainGuard, InputRow, Recorder, assert_stop_within_two_ticks, run_polling, scl,
    serial, temp_dir, unique_prefix, wait_clean, write_replay,
};

/// The stick's deflection in these tests: the bundled model moves every joint slowly.
const HELD: [f32; 2] = [0.4, 0.0];
const REST: [f32; 2] = [0.0, 0.0];

fn row(t_s: f64, axes: [f32; 2], buttons: u32) -> InputRow {
    InputRow { t_s, axes, buttons }
}

/// A running `scl up` with its recorder. Fields drop in order: the graph stops, then the
/// recorder leaves, then the domain is released.
struct Run {
    guard: ChildGuard,
    rec: Recorder,
    prefix: Prefix,
    dir: PathBuf,
    _domain: DomainGuard,
}

/// Starts `scl up --for SECS` with the replayed input `rows`, the mapper restarted on
/// failure after `backoff_ms`, and waits until the arm moves.
fn start(tag: &str, rows: &[InputRow], backoff_ms: u64, secs: u32) -> Run {
    let dir = temp_dir(tag);
    write_replay(&dir.join("input.csv"), rows);
    let toml = format!(
        "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n\n\
         [supervisor]\nbackoff_initial_ms = {backoff_ms}\n\n\
         [supervisor.restart]\nmapper = \"on-failure\"\n"
    );
    start_with(tag, dir, &toml, secs)
}

/// Starts `scl up --for SECS` with the graph configuration `toml` (in `dir`), and waits
/// until the arm moves.
fn start_with(tag: &str, dir: PathBuf, toml: &str, secs: u32) -> Run {
    let prefix = unique_prefix(tag);
    let domain = DomainGuard(prefix.clone());
    let cfg = dir.join("graph.toml");
    std::fs::write(&cfg, toml).unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--json", "--for", &format!("{secs}s"), "--config"])
        .arg(&cfg)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join("up.log")).unwrap());
    let guard = ChildGuard(Some(up.spawn().unwrap()));
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| r
            .safe_commands
            .iter()
            .any(moving)),
        "the arm never moved"
    );
    Run {
        guard,
        rec,
        prefix,
        dir,
        _domain: domain,
    }
}

impl Run {
    /// Waits for `scl up` to end by itself and checks its summary: one restart, no failure.
    fn finish(mut self) {
        while self.guard.child().try_wait().unwrap().is_none() {
            self.rec.poll();
            std::thread::sleep(Duration::from_millis(2));
        }
        self.rec.poll();
        let out = self.guard.take().wait_with_output().unwrap();
        let log = std::fs::read_to_string(self.dir.join("up.log")).unwrap();
        assert!(out.status.success(), "scl up: {:?}\n{log}", out.status);
        let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(summary["restarts"], 1, "{summary}");
        assert!(summary["failure"].is_null(), "{summary}");
        std::fs::remove_dir_all(&self.dir).unwrap();
        let prefix = self.prefix.clone();
        drop(self);
        assert_eq!(
            wait_clean(&prefix, Duration::from_secs(5)),
            Vec::<String>::new()
        );
    }

    /// Kills the mapper with SIGKILL; returns its pid and the time.
    fn kill_mapper(&mut self) -> (u32, u64) {
        self.rec.poll();
        let pid = self.rec.pid_of(NodeRole::Mapper).unwrap();
        let t = now_ns();
        scl_tests::send_signal(pid, scl_tests::Signal::SIGKILL);
        (pid, t)
    }

    /// Polls until the supervisor restarted the mapper `old`; returns the first heartbeat
    /// time of the new one.
    fn wait_restarted(&mut self, old: u32) -> u64 {
        let new = |r: &Recorder| {
            r.statuses
                .iter()
                .find(|s| s.role == NodeRole::Mapper as u32 && s.pid != old)
                .map(|s| (s.pid, s.t_ns))
        };
        assert!(
            self.rec.poll_until(Duration::from_secs(20), |r| {
                let Some((pid, _)) = new(r) else {
                    return false;
                };
                r.statuses
                    .iter()
                    .any(|s| s.pid == pid && s.phase == phase::RUNNING && s.handled > 5)
            }),
            "the mapper was not restarted"
        );
        new(&self.rec).unwrap().1
    }

    /// The time of the first joystick sample after `t_ns` that `pred` accepts.
    fn sample_after(&self, t_ns: u64, pred: impl Fn(&ipc_types::JoystickInput) -> bool) -> u64 {
        self.rec
            .joystick_samples
            .iter()
            .find(|j| j.t_ns > t_ns && pred(j))
            .map(|j| j.t_ns)
            .expect("no such joystick sample")
    }

    fn states_between(&self, from_ns: u64, to_ns: u64) -> Vec<RobotState> {
        self.rec
            .robot_states
            .iter()
            .filter(|s| s.t_ns > from_ns && s.t_ns <= to_ns && s.flags & state_flags::SHUTDOWN == 0)
            .copied()
            .collect()
    }
}

fn moving(c: &SafeCommand) -> bool {
    c.qdot_rad_s.iter().any(|v| *v != 0.0)
}

fn speed(s: &RobotState) -> f64 {
    s.qdot_rad_s.iter().map(|v| v.abs()).fold(0.0, f64::max)
}

fn deflected(j: &ipc_types::JoystickInput) -> bool {
    j.axes != REST
}

/// The stick held deflected, the mapper SIGKILLed and restarted: the arm stops, and stays
/// stopped after the restart, with the stick still held, until the stick returns to neutral;
/// then it follows the stick again. Before restart prevention, the new mapper's first
/// commands moved the arm on the still-deflected stick a few ticks after it started.
#[test]
fn a_restarted_mapper_waits_for_the_stick_to_pass_through_neutral() {
    let _serial = serial();
    // Held from 0.5 s to 8 s (the kill at about 1.5 s, the restart well before 8 s), at rest
    // for 1 s, held again for 2 s.
    let rows = [
        row(0.0, REST, 0),
        row(0.5, HELD, 0),
        row(8.0, REST, 0),
        row(9.0, HELD, 0),
        row(11.0, REST, 0),
    ];
    let mut run = start("neutral", &rows, 200, 13);
    assert!(
        run.rec
            .poll_until(Duration::from_secs(10), |r| r.robot_states.len() > 60)
    );
    let (old, t_kill) = run.kill_mapper();
    let t_restarted = run.wait_restarted(old);
    // `scl status` says why the arm does not move.
    let mut c = scl(&run.prefix);
    c.args(["status", "--json"]);
    let out = run_polling(c, &mut run.rec);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let st: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let t_status = now_ns();
    assert!(
        st["safety_state"]
            .as_array()
            .unwrap()
            .iter()
            .any(|s| s == "waiting for neutral input"),
        "{st}"
    );
    // The stick returns to neutral and is deflected again: the arm follows.
    assert!(
        run.rec.poll_until(Duration::from_secs(20), |r| {
            let Some(again) = r
                .joystick_samples
                .iter()
                .skip_while(|j| j.t_ns < t_kill || deflected(j))
                .find(|j| deflected(j))
            else {
                return false;
            };
            r.safe_commands
                .iter()
                .any(|c| c.joystick_t_ns >= again.t_ns && moving(c))
        }),
        "the arm did not follow the stick after its return to neutral"
    );
    let t_neutral = run.sample_after(t_kill, |j| !deflected(j));
    let t_again = run.sample_after(t_neutral, deflected);
    assert!(
        t_status < t_neutral,
        "the machine was too slow: the mapper restarted and `scl status` answered only \
         {:.1} s after the kill, when the stick was back at neutral",
        (t_status - t_kill) as f64 / 1e9
    );

    // The arm stopped within two ticks of the kill.
    assert_stop_within_two_ticks(&run.states_between(t_kill, u64::MAX), "mapper SIGKILL");
    // Every command of the new mapper mapped from the still-deflected stick was a stop, most
    // of them for want of a neutral input, for at least a second.
    let waiting: Vec<&SafeCommand> = run
        .rec
        .safe_commands
        .iter()
        .filter(|c| c.mapper_t_ns > t_kill && c.joystick_t_ns < t_neutral)
        .collect();
    assert!(
        waiting.len() >= 40,
        "only {} ticks from the restart to the neutral input",
        waiting.len()
    );
    for c in &waiting {
        assert!(
            c.flags & safe_flags::STOP != 0,
            "tick {}: the restarted mapper moved the arm on the deflected stick (flags {:#x}, {:?})",
            c.tick,
            c.flags,
            &c.qdot_rad_s[..6]
        );
    }
    let awaiting = waiting
        .iter()
        .filter(|c| c.flags & safe_flags::AWAITING_NEUTRAL != 0)
        .count();
    assert!(
        awaiting >= waiting.len() - 10,
        "{awaiting} of {}",
        waiting.len()
    );
    // The arm came to rest and stayed there until the stick was deflected again.
    let after = run.states_between(t_kill, t_again);
    let still = after
        .iter()
        .position(|s| speed(s) == 0.0)
        .expect("the arm never stood still");
    for s in &after[still..] {
        assert_eq!(
            speed(s),
            0.0,
            "tick {}: moving before the stick was deflected again",
            s.tick
        );
    }
    // Safety's heartbeat said so meanwhile, and no longer once the stick was at rest.
    let safety = |from: u64, to: u64| {
        run.rec
            .statuses
            .iter()
            .filter(move |s| s.role == NodeRole::Safety as u32 && s.t_ns > from && s.t_ns < to)
            .map(|s| s.safety_state & safety_state::AWAITING_NEUTRAL != 0)
            .collect::<Vec<_>>()
    };
    let during = safety(t_restarted, t_neutral);
    assert!(!during.is_empty() && during.iter().all(|w| *w));
    assert!(safety(t_again, u64::MAX).iter().any(|w| !*w));
    run.finish();
}

/// An e-stop pressed on the joystick while the mapper is dead (SIGKILLed, restarted only 5 s
/// later): the joystick publishes it on the e-stop topic itself, safety latches it at once,
/// and the arm stays stopped after the mapper's restart until `scl reset`, and then until the
/// stick has passed through neutral. Before, the press travelled only as a bit through the
/// mapper, so with the mapper dead it was lost.
#[test]
fn an_estop_pressed_on_the_joystick_latches_while_the_mapper_is_dead() {
    let _serial = serial();
    // Held from 0.5 s (the kill as soon as the arm moves), the e-stop pressed at 3 s for
    // 0.3 s, at rest from 12 s for 1 s, held again for 2 s.
    let rows = [
        row(0.0, REST, 0),
        row(0.5, HELD, 0),
        row(3.0, HELD, buttons::ESTOP),
        row(3.3, HELD, 0),
        row(12.0, REST, 0),
        row(13.0, HELD, 0),
        row(15.0, REST, 0),
    ];
    let mut run = start("estopjoy", &rows, 5000, 17);
    let (old, t_kill) = run.kill_mapper();
    // The press, and safety's heartbeat saying the e-stop is latched.
    assert!(
        run.rec.poll_until(Duration::from_secs(10), |r| r
            .joystick_samples
            .iter()
            .any(|j| j.buttons & buttons::ESTOP != 0)),
        "the joystick never pressed the e-stop"
    );
    let t_press = run.sample_after(t_kill, |j| j.buttons & buttons::ESTOP != 0);
    let latched = |r: &Recorder| {
        r.statuses
            .iter()
            .find(|s| {
                s.role == NodeRole::Safety as u32
                    && s.t_ns > t_press
                    && s.safety_state & safety_state::ESTOP != 0
            })
            .map(|s| s.t_ns)
    };
    assert!(
        run.rec
            .poll_until(Duration::from_secs(5), |r| latched(r).is_some()),
        "safety never latched the e-stop pressed on the joystick with the mapper dead"
    );
    let t_latched = latched(&run.rec).unwrap();
    let t_restarted = run.wait_restarted(old);
    assert!(
        t_latched < t_restarted,
        "latched only after the mapper's restart"
    );
    assert!(
        t_latched - t_press < 300_000_000,
        "latched {} ms after the press",
        (t_latched - t_press) / 1_000_000
    );
    // The restarted mapper's commands: zero, flagged e-stop, for a second.
    assert!(run.rec.poll_until(Duration::from_secs(10), |r| {
        r.safe_commands
            .iter()
            .filter(|c| c.mapper_t_ns > t_restarted)
            .count()
            > 40
    }));
    // Every command published before the reset was asked for must still be latched.
    let t_reset_asked = now_ns();
    let mut c = scl(&run.prefix);
    c.arg("reset");
    let out = run_polling(c, &mut run.rec);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let t_reset = now_ns();
    // Then motion once the stick passed through neutral and was deflected again.
    assert!(
        run.rec.poll_until(Duration::from_secs(20), |r| {
            r.safe_commands
                .iter()
                .any(|c| c.mapper_t_ns > t_reset && moving(c))
        }),
        "the arm did not move again after the reset and the neutral input"
    );
    let t_neutral = run.sample_after(t_press, |j| !deflected(j));
    let t_again = run.sample_after(t_neutral, deflected);
    assert!(
        t_reset < t_neutral,
        "the machine was too slow: the reset was confirmed {:.1} s after the press, when \
         the stick was back at neutral",
        (t_reset - t_press) as f64 / 1e9
    );

    let cmds = |from: u64, to: u64| -> Vec<SafeCommand> {
        run.rec
            .safe_commands
            .iter()
            .filter(|c| c.t_ns > from && c.t_ns < to)
            .copied()
            .collect()
    };
    // Latched: every command from the restart to the reset zero and flagged.
    let latched_cmds = cmds(t_restarted, t_reset_asked);
    assert!(latched_cmds.len() > 40);
    for c in &latched_cmds {
        assert!(
            c.flags & safe_flags::ESTOP != 0 && !moving(c),
            "tick {}: flags {:#x}, {:?}",
            c.tick,
            c.flags,
            &c.qdot_rad_s[..6]
        );
    }
    // Released with the stick still deflected: zero, waiting for neutral.
    let after_reset: Vec<SafeCommand> = cmds(t_reset, t_neutral)
        .into_iter()
        .filter(|c| c.flags & safe_flags::ESTOP == 0)
        .collect();
    assert!(
        !after_reset.is_empty(),
        "no command between the reset and the neutral input"
    );
    for c in &after_reset {
        assert!(
            c.flags & safe_flags::AWAITING_NEUTRAL != 0 && !moving(c),
            "tick {}: the released e-stop moved the deflected stick's arm (flags {:#x})",
            c.tick,
            c.flags
        );
    }
    // The arm stood still from the restart until the stick was deflected again.
    for s in run.states_between(t_restarted, t_again) {
        assert_eq!(speed(&s), 0.0, "tick {}", s.tick);
    }
    run.finish();
}

/// `scl estop` while the mapper is dead (SIGKILLed, restarted only 5 s later) and the bridge
/// brakes the arm slowly (its controlled stop at 0.02 rad/s²): safety answers the robot
/// states itself, so the arm's velocity is zero at the first robot state after safety
/// latched the e-stop (two at most), not at the end of the bridge's controlled stop. Before,
/// safety published only when a mapper command came: the arm kept the bridge's decaying stop
/// for seconds.
#[test]
fn scl_estop_stops_the_arm_at_once_while_the_mapper_is_dead() {
    let _serial = serial();
    let tag = "estopdead";
    let dir = temp_dir(tag);
    write_replay(
        &dir.join("input.csv"),
        &[row(0.0, REST, 0), row(0.5, HELD, 0), row(30.0, REST, 0)],
    );
    let toml = "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n\n\
                [bridge]\nstop_acceleration_rad_s2 = [0.02, 0.02, 0.02, 0.02, 0.02, 0.02]\n\n\
                [supervisor]\nbackoff_initial_ms = 5000\n\n\
                [supervisor.restart]\nmapper = \"on-failure\"\n";
    let mut run = start_with(tag, dir, toml, 12);
    // At the stick's speed.
    run.rec.poll_for(Duration::from_secs(1));
    let (_, t_kill) = run.kill_mapper();
    let mut c = scl(&run.prefix);
    c.arg("estop");
    let out = run_polling(c, &mut run.rec);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let latched = |r: &Recorder| {
        r.statuses
            .iter()
            .find(|s| {
                s.role == NodeRole::Safety as u32
                    && s.t_ns > t_kill
                    && s.safety_state & safety_state::ESTOP != 0
            })
            .map(|s| s.t_ns)
    };
    assert!(
        run.rec
            .poll_until(Duration::from_secs(5), |r| latched(r).is_some()),
        "safety never latched the e-stop"
    );
    let t_latched = latched(&run.rec).unwrap();
    run.rec.poll_for(Duration::from_secs(1));
    let before = run.states_between(t_kill, t_latched);
    let after = run.states_between(t_latched, u64::MAX);
    assert!(
        before.last().is_some_and(|s| speed(s) > 0.0),
        "the machine was too slow: the bridge's stop had ended before the e-stop latched \
         ({} ms after the kill)",
        (t_latched - t_kill) / 1_000_000
    );
    assert!(after.len() > 20, "{} states after the latch", after.len());
    // Ticks counted by the states' own numbers: zero velocity from the first or second
    // state after the latch on, with no decaying stop in between.
    let first = after[0].tick;
    let still = after
        .iter()
        .position(|s| speed(s) == 0.0)
        .expect("the arm never stood still after the e-stop");
    assert!(
        after[still].tick <= first + 1,
        "the arm moved for {} ticks after the e-stop latched: {:?}",
        after[still].tick - first,
        after[..still].iter().map(speed).collect::<Vec<_>>()
    );
    for s in &after[still..] {
        assert_eq!(speed(s), 0.0, "tick {}", s.tick);
    }
    // The commands that stopped it are safety's own: no mapper command, zero, e-stop.
    let own: Vec<&SafeCommand> = run
        .rec
        .safe_commands
        .iter()
        .filter(|c| c.t_ns > t_latched && c.mapper_t_ns == 0)
        .collect();
    assert!(!own.is_empty(), "safety answered no robot state itself");
    for c in own {
        assert!(
            c.flags & safe_flags::ESTOP != 0 && !moving(c),
            "tick {}: flags {:#x}",
            c.tick,
            c.flags
        );
    }
    run.finish();
}

/// A scripted joystick (the stick held deflected once its start-up rest is over) SIGKILLed
/// and restarted by the supervisor: its samples stop (a stale-joystick stop, then neutral
/// required), and the restarted script's stick is deflected from its first tick on, so the
/// arm stays stopped. Before, the restarted joystick's first sample, neutral and made before
/// its first tick, re-armed safety, and the script's deflected stick moved the arm.
#[test]
fn a_restarted_scripted_joystick_does_not_rearm_the_arm() {
    let _serial = serial();
    let tag = "joyrestart";
    let dir = temp_dir(tag);
    let toml = "[joystick]\nsource = \"script\"\nscript = \"constant\"\namplitude = 0.4\n\
                constant_axes = [1.0, 0.0]\n\n\
                [supervisor]\nbackoff_initial_ms = 200\n\n\
                [supervisor.restart]\njoystick = \"on-failure\"\n";
    let mut run = start_with(tag, dir, toml, 8);
    run.rec.poll_for(Duration::from_millis(500));
    run.rec.poll();
    let old = run.rec.pid_of(NodeRole::Joystick).unwrap();
    let t_kill = now_ns();
    scl_tests::send_signal(old, scl_tests::Signal::SIGKILL);
    let restarted = |r: &Recorder| {
        r.statuses
            .iter()
            .find(|s| {
                s.role == NodeRole::Joystick as u32
                    && s.pid != old
                    && s.phase == phase::RUNNING
                    && s.handled > 60
            })
            .map(|s| s.t_ns)
    };
    assert!(
        run.rec
            .poll_until(Duration::from_secs(20), |r| restarted(r).is_some()),
        "the joystick was not restarted"
    );
    // The new process numbers its samples from 0.
    let t_new = run.sample_after(t_kill, |j| j.seq == 0);
    // Every command mapped from the new joystick's samples is a stop that never speeds a
    // joint up, waiting for neutral unless the supervisor's hold or a stale input is (also) a
    // reason (`AWAITING_NEUTRAL` marks only the ticks it is the sole reason), and the arm
    // ends at rest waiting for neutral. A restart quicker than the stop ramp brings the new
    // samples while the arm still brakes at the acceleration limit: those stops still move.
    let new: Vec<&SafeCommand> = run
        .rec
        .safe_commands
        .iter()
        .filter(|c| c.joystick_t_ns >= t_new)
        .collect();
    assert!(new.len() > 40, "{} commands", new.len());
    let fastest = |c: &SafeCommand| c.qdot_rad_s.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let first = run
        .rec
        .safe_commands
        .iter()
        .position(|c| c.joystick_t_ns >= t_new)
        .unwrap_or(0);
    let mut prev_speed = first
        .checked_sub(1)
        .map_or(0.0, |i| fastest(&run.rec.safe_commands[i]));
    for c in &new {
        let speed = fastest(c);
        let other_reason = safe_flags::HOLD
            | safe_flags::STALE_JOYSTICK
            | safe_flags::STALE_COMMAND
            | safe_flags::STALE_STATE;
        let waiting = c.flags & (safe_flags::AWAITING_NEUTRAL | other_reason) != 0;
        let braking = c.flags & safe_flags::STOP != 0 && speed <= prev_speed;
        assert!(
            waiting && braking,
            "tick {}: the restarted joystick's deflected stick moved the arm (flags {:#x}, \
             fastest joint {speed} rad/s, {prev_speed} rad/s the command before)",
            c.tick,
            c.flags
        );
        prev_speed = speed;
    }
    let last = new[new.len() - 1];
    assert!(
        last.flags & safe_flags::AWAITING_NEUTRAL != 0 && !moving(last),
        "tick {}: the arm did not end stopped waiting for neutral (flags {:#x})",
        last.tick,
        last.flags
    );
    run.finish();
}
