//! Helpers for whole-graph tests: the `scl` binary, unique graph prefixes, a read-only
//! recorder of the graph's topics, and the check that a graph left nothing behind.
#![allow(clippy::unwrap_used)]

pub mod workspace;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use ipc_types::{JoystickInput, MapperCommand, NodeStatus, Prefix, RobotState, SafeCommand};
pub use nix::sys::signal::Signal;
use transport::{Graph, TopicSubscriber};

/// Path of the `scl` binary of this build, built once per test process. `cargo test` does
/// not build other packages' binaries for a test crate, so this asks cargo (a no-op when the
/// binary is up to date) with the same profile as the running test.
pub fn scl_binary() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        let exe = std::env::current_exe().unwrap();
        // target/<profile>/deps/<test> -> target/<profile>
        let profile_dir = exe.parent().unwrap().parent().unwrap().to_owned();
        let release = profile_dir.file_name().is_some_and(|n| n == "release");
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args(["build", "-q", "-p", "scl", "--bin", "scl"]);
        if release {
            cmd.arg("--release");
        }
        cmd.current_dir(env!("CARGO_MANIFEST_DIR"));
        let status = cmd.status().unwrap();
        assert!(status.success(), "building the scl binary failed");
        let bin = profile_dir.join("scl");
        assert!(bin.exists(), "{} was not built", bin.display());
        bin
    })
    .clone()
}

/// A prefix no other test (or test run) uses.
pub fn unique_prefix(tag: &str) -> Prefix {
    static N: AtomicU32 = AtomicU32::new(0);
    let n = N.fetch_add(1, Ordering::SeqCst);
    Prefix::new(&format!("t{tag}{}x{n}", std::process::id())).unwrap()
}

/// Files of graph `prefix` left in `/dev/shm` or iceoryx2's directory.
pub fn leftovers(prefix: &Prefix) -> Vec<String> {
    files_named(&prefix.file_prefix())
}

/// Files under `/dev/shm` and iceoryx2's directory whose name holds `needle` (a graph's file
/// prefix, or a part every graph of one run shares): [`transport::graph::files_named`].
pub fn files_named(needle: &str) -> Vec<String> {
    transport::graph::files_named(needle)
        .into_iter()
        .map(|p| p.display().to_string())
        .collect()
}

/// Releases the domain of graph `prefix` (the test's recorder was the last node) and waits
/// until the graph has left nothing behind, or returns what is left after `timeout`.
pub fn wait_clean(prefix: &Prefix, timeout: Duration) -> Vec<String> {
    let t0 = Instant::now();
    loop {
        let _ = transport::graph::release_domain(prefix);
        let left = leftovers(prefix);
        if left.is_empty() || t0.elapsed() > timeout {
            return left;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A read-only observer of a graph: every robot state, joystick sample, mapper command,
/// executed command and heartbeat, with the monotonic time it was seen.
pub struct Recorder {
    states: TopicSubscriber<RobotState>,
    joystick: TopicSubscriber<JoystickInput>,
    safe: TopicSubscriber<SafeCommand>,
    mapper: TopicSubscriber<MapperCommand>,
    status: TopicSubscriber<NodeStatus>,
    /// Robot states, in order.
    pub robot_states: Vec<RobotState>,
    /// Joystick samples, in order.
    pub joystick_samples: Vec<JoystickInput>,
    /// Commands sent to the bridge, in order.
    pub safe_commands: Vec<SafeCommand>,
    /// Commands of every mapper, in order.
    pub mapper_commands: Vec<MapperCommand>,
    /// Heartbeats, in order.
    pub statuses: Vec<NodeStatus>,
    // Declared last: dropped after its ports.
    _graph: Graph,
}

impl Recorder {
    /// Joins graph `prefix` as an observer.
    pub fn join(prefix: &Prefix) -> Self {
        let graph = Graph::join(prefix, "test-recorder").unwrap();
        Self {
            states: graph.robot_state_subscriber(false).unwrap(),
            joystick: graph.joystick_subscriber(false).unwrap(),
            safe: graph.safe_command_subscriber(false).unwrap(),
            mapper: graph.mapper_command_subscriber(false).unwrap(),
            status: graph.status_subscriber().unwrap(),
            robot_states: Vec::new(),
            joystick_samples: Vec::new(),
            safe_commands: Vec::new(),
            mapper_commands: Vec::new(),
            statuses: Vec::new(),
            _graph: graph,
        }
    }

    /// Takes in everything published since the last poll.
    pub fn poll(&mut self) {
        self.states.drain(|m| self.robot_states.push(*m)).unwrap();
        self.joystick
            .drain(|m| self.joystick_samples.push(*m))
            .unwrap();
        self.safe.drain(|m| self.safe_commands.push(*m)).unwrap();
        self.mapper
            .drain(|m| self.mapper_commands.push(*m))
            .unwrap();
        self.status.drain(|m| self.statuses.push(*m)).unwrap();
    }

    /// Polls every 2 ms for `d`.
    pub fn poll_for(&mut self, d: Duration) {
        let t0 = Instant::now();
        while t0.elapsed() < d {
            self.poll();
            std::thread::sleep(Duration::from_millis(2));
        }
        self.poll();
    }

    /// Polls until `pred` holds or `timeout` passes; returns whether it held.
    pub fn poll_until(&mut self, timeout: Duration, mut pred: impl FnMut(&Self) -> bool) -> bool {
        let t0 = Instant::now();
        loop {
            self.poll();
            if pred(self) {
                return true;
            }
            if t0.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Records while `guard`'s child (`scl up`) runs, then takes in what it published last
    /// and returns the child's output.
    pub fn record_until_exit(&mut self, guard: &mut ChildGuard) -> Output {
        while guard.child().try_wait().unwrap().is_none() {
            self.poll();
            std::thread::sleep(Duration::from_millis(2));
        }
        self.poll();
        guard.take().wait_with_output().unwrap()
    }

    /// The pid of the newest heartbeat of `role`.
    pub fn pid_of(&self, role: ipc_types::NodeRole) -> Option<u32> {
        self.statuses
            .iter()
            .rev()
            .find(|s| s.role == role as u32)
            .map(|s| s.pid)
    }
}

/// Owns a running `scl up` (or any child): on drop, even when the test panics, the child is
/// asked to stop (SIGTERM: bridge first), and killed if it has not within 5 s.
pub struct ChildGuard(pub Option<Child>);

impl ChildGuard {
    /// The child.
    pub fn child(&mut self) -> &mut Child {
        self.0.as_mut().unwrap()
    }

    /// Takes the child out (the test waits for it itself).
    pub fn take(&mut self) -> Child {
        self.0.take().unwrap()
    }
}

/// Sends `signal` to process `pid` (a child of the test or a process of the graph under
/// test); a process already gone is not an error here.
pub fn send_signal(pid: u32, signal: Signal) {
    let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid as i32), signal);
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let Some(child) = self.0.as_mut() else {
            return;
        };
        if let Ok(None) = child.try_wait() {
            send_signal(child.id(), Signal::SIGTERM);
            let t0 = Instant::now();
            while let Ok(None) = child.try_wait() {
                if t0.elapsed() > Duration::from_secs(5) {
                    let _ = child.kill();
                    let _ = child.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        }
    }
}

/// Releases a graph's domain when dropped, even when the test panics; declare it before the
/// recorder and the child guard so it is dropped after them.
pub struct DomainGuard(pub Prefix);

impl Drop for DomainGuard {
    fn drop(&mut self) {
        let _ = transport::graph::release_domain(&self.0);
    }
}

/// Checks that the bridge commanded a stop within the first two ticks after an event at
/// `t_ns` (a kill), given the robot states recorded after it. A state reports the command
/// executed during the period before it (`applied_tick`, flags), so a stop commanded at the
/// second tick after the event shows in the third state; a shutdown state reports itself and
/// repeats the tick it stopped in.
/// Returns the index of the first state that reports the stop.
pub fn assert_stop_within_two_ticks(after: &[RobotState], what: &str) -> usize {
    let stop = ipc_types::state_flags::STOPPING
        | ipc_types::state_flags::SAFETY_STOP
        | ipc_types::state_flags::SHUTDOWN;
    let first = after
        .iter()
        .position(|s| s.flags & stop != 0)
        .unwrap_or_else(|| panic!("{what}: the bridge never reported a stop"));
    // Counted in the states' own ticks (a shutdown state repeats the tick of the period it
    // stopped in). A stop already reported by the first state was commanded before the
    // event: at once.
    let ticks_in = after[first].tick.saturating_sub(after[0].tick) as usize;
    let commanded_at = if after[first].flags & ipc_types::state_flags::SHUTDOWN != 0 {
        ticks_in
    } else {
        ticks_in.saturating_sub(1)
    };
    assert!(
        commanded_at < 2,
        "{what}: the stop was commanded at the {}th tick after the event",
        commanded_at + 1
    );
    first
}

/// Asserts that every command of `cmds` changed the arm's velocity by at most
/// `accel[j] * dt` on each joint `j` of `accel`: against the mock arm's state of the command's
/// own tick in `states`, the velocity safety's filter limited from (the mock arm moves at its
/// last executed command). Consecutive commands may differ by more after a tick the machine
/// held up: the bridge braked on its own, and the next command starts from where it braked.
/// Returns how many commands were checked (those whose state was recorded); `what` names the
/// run.
pub fn assert_acceleration_limited(
    states: &[RobotState],
    cmds: &[SafeCommand],
    accel: &[f64],
    dt: f64,
    what: &str,
) -> usize {
    // A shutdown state repeats the tick of the period it stopped in.
    let by_tick: std::collections::HashMap<u64, &RobotState> = states
        .iter()
        .filter(|s| s.flags & ipc_types::state_flags::SHUTDOWN == 0)
        .map(|s| (s.tick, s))
        .collect();
    let mut checked = 0;
    for c in cmds {
        let Some(s) = by_tick.get(&c.tick) else {
            continue;
        };
        for (j, a) in accel.iter().enumerate() {
            let dv = (c.qdot_rad_s[j] - s.qdot_rad_s[j]).abs();
            assert!(
                dv <= a * dt * (1.0 + 1e-9) + 1e-12,
                "{what}: tick {} joint {j}: the command changes the arm's speed by {dv} rad/s",
                c.tick
            );
        }
        checked += 1;
    }
    checked
}

/// An `scl` command for graph `prefix`, logging warnings only.
pub fn scl(prefix: &Prefix) -> Command {
    let mut c = Command::new(scl_binary());
    c.env("SCL_PREFIX", prefix.as_str()).env("SCL_LOG", "warn");
    c
}

/// A PCA model trained by `scl train` on the shipped joint-space reaching demonstrations
/// (`data/joint-reach`), at `speed_scale_rad_s` or the default speed scale, written into
/// `dir`. Tests that need known map directions (a joint limit reached by a constant input,
/// the table plane) use it instead of the bundled model, whose directions change whenever it
/// is retrained.
pub fn joint_reach_pca(dir: &Path, speed_scale_rad_s: Option<f64>) -> PathBuf {
    let name = speed_scale_rad_s.map_or("pca".to_owned(), |s| format!("pca-{s}"));
    let out = dir.join(format!("{name}.safetensors"));
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/joint-reach");
    let mut cmd = Command::new(scl_binary());
    cmd.args(["train", "--kind", "pca", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&out)
        .stderr(Stdio::null());
    if let Some(s) = speed_scale_rad_s {
        cmd.args(["--speed-scale", &s.to_string()]);
    }
    let st = cmd.status().expect("run scl train");
    assert!(st.success(), "scl train --kind pca on {}", data.display());
    out
}

/// One row of a recorded joystick input (the replay source's CSV): from `t_s` on, the axes
/// `axes` and the button bits `buttons`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputRow {
    /// Seconds from the replay's start (its first robot tick).
    pub t_s: f64,
    /// The two axes.
    pub axes: [f32; 2],
    /// `ipc_types::buttons` bits.
    pub buttons: u32,
}

/// Writes `rows` as a recorded input file the replay source plays (`[joystick] source =
/// "replay"`); after the last row the input is neutral.
pub fn write_replay(path: &Path, rows: &[InputRow]) {
    let mut text = String::from("t_s,a0,a1,gripper,buttons\n");
    for r in rows {
        text += &format!("{:.3},{},{},0,{}\n", r.t_s, r.axes[0], r.axes[1], r.buttons);
    }
    std::fs::write(path, text).unwrap();
}

/// A stick held at `axes` with short returns to neutral: at rest for the first 0.5 s (the
/// arm's first motion needs a neutral input), then `axes` for `hold_s` and rest for `rest_s`,
/// repeated until `until_s`. Tests that hold a direction use it instead of the constant
/// script where the arm must move again after a stop a fault caused (a machine's hold-up of
/// the bridge is one): it waits for the next neutral pass (restart prevention).
pub fn pulses(axes: [f32; 2], hold_s: f64, rest_s: f64, until_s: f64) -> Vec<InputRow> {
    let mut rows = vec![InputRow {
        t_s: 0.0,
        axes: [0.0, 0.0],
        buttons: 0,
    }];
    let mut t = 0.5;
    while t < until_s {
        rows.push(InputRow {
            t_s: t,
            axes,
            buttons: 0,
        });
        rows.push(InputRow {
            t_s: t + hold_s,
            axes: [0.0, 0.0],
            buttons: 0,
        });
        t += hold_s + rest_s;
    }
    rows
}

/// A fresh temporary directory for one test.
pub fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("scl-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `cmd` to completion (stdout and stderr captured) while `rec` keeps polling.
pub fn run_polling(mut cmd: Command, rec: &mut Recorder) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
        assert!(t0.elapsed() < Duration::from_secs(120), "command hung");
    }
    rec.poll();
    child.wait_with_output().unwrap()
}

/// A serial lock for whole-graph tests: they share two cores and must not overlap.
pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The stretch of `states` (robot states in order, shutdown state excluded) without a miss
/// that ends with the last state: how many states in a row, counted back from the last one,
/// follow their predecessor's tick, report its command executed and leave the bridge's miss
/// counter unchanged. Tests that must see N ticks without a miss poll until this reaches N.
pub fn clean_run_at_end(states: &[RobotState]) -> usize {
    let clean = |w: &[RobotState]| {
        w[1].tick == w[0].tick + 1 && w[1].applied_tick == w[0].tick && w[1].missed == w[0].missed
    };
    match states.windows(2).rev().position(|w| !clean(w)) {
        Some(n) => n + 1,
        None => states.len(),
    }
}

/// The lines of an `scl` log that report a missed tick, with its cause (a command that did
/// not come in time, or the bridge held up by the machine), and the real-time settings each
/// process obtained: what a test prints when it finds a miss.
pub fn miss_report(log: &str) -> String {
    log.lines()
        .filter(|l| {
            l.contains("missed tick") || l.contains("late reply") || l.contains("real-time")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Ticks an `scl` log says the machine took: the `held up` warnings' `ticks_lost=N` (the
/// bridge not run through a period, or a command late while its chain's work fitted the
/// deadline). The same count travels in the bridge's heartbeat (`NodeStatus::held_up`,
/// `scl up --json`'s `held_up`); tests check that one and use this to cross-check it.
pub fn held_up_skips(log: &str) -> u64 {
    log.lines()
        .filter(|l| l.contains("held up"))
        .filter_map(|l| log_field::<u64>(l, "ticks_lost"))
        .sum()
}

/// The value of field `key` (`key=value`) of one `scl` log line, parsed.
pub fn log_field<T: std::str::FromStr>(line: &str, key: &str) -> Option<T> {
    line.split(&format!("{key}="))
        .nth(1)?
        .split(' ')
        .next()?
        .parse()
        .ok()
}

/// How many times a whole-graph test that requires no miss lets the machine hold the graph
/// up in a run of `duration_s` seconds (see [`held_up_skips`]): two, and one more for every
/// [`HELD_UP_EVERY_S`] of the run. A shared CI machine held a 12 s graph up twice
/// (2026-11-29's failed run); a graph whose own wake-ups were late would miss a tick in
/// every few, far above this.
pub fn max_held_up(duration_s: f64) -> usize {
    2 + (duration_s.max(0.0) / HELD_UP_EVERY_S) as usize
}

/// See [`max_held_up`].
pub const HELD_UP_EVERY_S: f64 = 4.0;

/// Asserts that every miss of an `scl up --json` run (`summary`) is one the machine took
/// (its `held_up`, as the bridge counted them), in at most [`max_held_up`] of the run's
/// `duration_s` hold-ups per its log `log`; `what` names the run.
pub fn assert_misses_only_held_up(summary: &serde_json::Value, log: &str, what: &str) {
    let missed = summary["missed"].as_u64().unwrap_or(u64::MAX);
    let held_up = summary["held_up"].as_u64().unwrap_or(u64::MAX);
    let allowed = max_held_up(summary["duration_s"].as_f64().unwrap_or(0.0));
    let events = log.lines().filter(|l| l.contains("held up")).count();
    assert!(
        missed == held_up && events <= allowed && held_up_skips(log) == held_up,
        "{what}: {missed} missed ticks, {held_up} of them taken by the machine in {events} hold-up(s) ({allowed} allowed):\n{}",
        miss_report(log)
    );
    if missed > 0 {
        eprintln!(
            "{what}: the machine held the graph up, {missed} tick(s) lost:\n{}",
            miss_report(log)
        );
    }
}

/// Every state of `states` (consecutive ticks) reports that the command of the tick before it
/// was executed, but at most the ticks the machine held up (`summary`'s `held_up`, the
/// bridge's count), which executed no command: never another tick's command.
pub fn assert_each_tick_ran_its_own_command(states: &[RobotState], summary: &serde_json::Value) {
    let held_up = summary["held_up"].as_u64().unwrap_or(0);
    let mut lost = 0;
    for w in states.windows(2) {
        assert_eq!(w[1].tick, w[0].tick + 1, "gap in ticks");
        if w[1].applied_tick != w[0].tick {
            assert_eq!(
                w[1].applied_tick,
                u64::MAX,
                "tick {} executed tick {}'s command",
                w[1].tick,
                w[1].applied_tick
            );
            lost += 1;
        }
    }
    assert!(
        lost <= held_up,
        "{lost} ticks executed no command, {held_up} held up by the machine: {summary}"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(tick: u64, applied_tick: u64, missed: u64) -> RobotState {
        RobotState {
            applied_tick,
            missed,
            ..RobotState::at_rest(tick, 0, 6)
        }
    }

    #[test]
    fn the_clean_run_counts_back_from_the_last_state_to_the_last_miss() {
        assert_eq!(clean_run_at_end(&[]), 0);
        assert_eq!(clean_run_at_end(&[state(5, 4, 0)]), 1);
        let mut s: Vec<_> = (1..=10).map(|t| state(t, t - 1, 0)).collect();
        assert_eq!(clean_run_at_end(&s), 10);
        // Tick 6 did not execute tick 5's command: the run restarts at 6.
        s[5].applied_tick = u64::MAX;
        for st in &mut s[5..] {
            st.missed = 1;
        }
        assert_eq!(clean_run_at_end(&s), 5);
        // A skipped tick (the clock jumped) breaks the run too.
        s.push(state(12, 11, 1));
        assert_eq!(clean_run_at_end(&s), 1);
        // So does a miss counted without a visible gap.
        s.push(state(13, 12, 2));
        assert_eq!(clean_run_at_end(&s), 1);
    }

    #[test]
    fn held_up_ticks_are_read_from_the_bridge_warnings() {
        let log = "2026 WARN scl::bridge_node: missed tick: the bridge was held up for more than a period ticks_lost=1 late_ms=26.1\n\
                   2026 WARN scl::bridge_node: missed tick: controlled stop tick=7 reason=NoCommand missed=2\n\
                   2026 WARN scl::bridge_node: missed tick: the bridge was held up for more than a period ticks_lost=2 late_ms=61.0\n";
        assert_eq!(held_up_skips(log), 3);
        assert_eq!(held_up_skips(""), 0);
        assert_eq!(miss_report(log).lines().count(), 3);
    }
}
