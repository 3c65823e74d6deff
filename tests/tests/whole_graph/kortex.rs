//! Whole-graph tests on the Kortex backend: `scl up` with `[bridge] robot = "kortex"`, its four
//! real processes over real shared memory, the bridge talking TCP on loopback to a fake
//! Gen3 lite that runs inside the test (`hw_bridge::kortex::FakeKortex`, a free port of
//! 127.0.0.1), so the test sees both sides: what the graph published and what the robot did.
//! The Gen3 (`[graph] robot = "gen3"`) runs against `scl fake-kortex --robot gen3`, a process
//! of its own, and a Gen3 lite fake is refused by it.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use hw_bridge::kortex::{Credentials, CyclicMisread, FakeConfig, FakeKortex, Fault, Function};
use ipc_types::{NodeRole, state_flags};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, Signal, assert_misses_only_held_up, clean_run_at_end,
    miss_report, scl_binary, serial, unique_prefix, wait_clean,
};

const USER: &str = "kx-operator";
const PASSWORD: &str = "kx-s3cret-pw";

/// A temporary directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let d = std::env::temp_dir().join(format!("scl-kortex-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn fake() -> FakeKortex {
    FakeKortex::start(FakeConfig {
        credentials: Credentials::new(USER, PASSWORD),
        ..FakeConfig::default()
    })
    .unwrap()
}

/// Writes the graph config pointing the bridge at `fake`; with `creds_file` the credentials
/// go in a file next to it, else the caller passes them in the environment. `extra` lines go
/// into `[bridge.kortex]`.
fn write_config(dir: &Path, fake: &FakeKortex, creds_file: bool, extra: &str) -> PathBuf {
    let mut text = format!(
        "[bridge]\nrobot = \"kortex\"\n\n[bridge.kortex]\naddress = \"127.0.0.1\"\nport = {}\n{extra}",
        fake.addr().port()
    );
    if creds_file {
        let f = dir.join("kortex-credentials.toml");
        std::fs::write(
            &f,
            format!("username = \"{USER}\"\npassword = \"{PASSWORD}\"\n"),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)).unwrap();
        text.push_str("credentials_file = \"kortex-credentials.toml\"\n");
    }
    let p = dir.join("graph.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// `scl up --config FILE --for 60s --json`, stderr (debug logs of every process) to `log`.
fn up(prefix: &ipc_types::Prefix, config: &Path, log: &Path, creds_env: bool) -> ChildGuard {
    let mut c = Command::new(scl_binary());
    c.args([
        "up",
        "--config",
        config.to_str().unwrap(),
        "--for",
        "60s",
        "--json",
    ])
    .env("SCL_PREFIX", prefix.as_str())
    .env("SCL_LOG", "debug")
    .env_remove("SCL_KORTEX_USER")
    .env_remove("SCL_KORTEX_PASSWORD")
    .stdout(Stdio::piped())
    .stderr(std::fs::File::create(log).unwrap());
    if creds_env {
        c.env("SCL_KORTEX_USER", USER)
            .env("SCL_KORTEX_PASSWORD", PASSWORD);
    }
    ChildGuard(Some(c.spawn().unwrap()))
}

fn running_states(rec: &Recorder) -> Vec<ipc_types::RobotState> {
    rec.robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .collect()
}

fn wait_for_exit(rec: &mut Recorder, guard: &mut ChildGuard) -> std::process::Output {
    let t0 = Instant::now();
    while guard.child().try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "scl up did not exit"
        );
    }
    rec.poll();
    guard.take().wait_with_output().unwrap()
}

fn assert_no_credentials(log: &str) {
    assert!(
        log.contains("Kortex session open"),
        "the log does not show the bridge's session: {log}"
    );
    assert!(!log.contains(PASSWORD), "the password is in the logs");
    assert!(!log.contains(USER), "the user name is in the logs");
}

#[test]
fn the_graph_drives_the_fake_kortex_arm_for_400_ticks_without_a_miss() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("run");
    // The fake robot shares two cores with the graph and the test: a reply it is slow to send
    // is counted late rather than ending the run (the connection timeout stays at 200 ms).
    let config = write_config(&dir.0, &fake, true, "reply_timeout_ms = 1000\n");
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kortex");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up(&prefix, &config, &log, false);
    // 400 ticks in a row without a miss. A tick the machine itself takes from the bridge
    // (its process not run for more than a period: the bridge logs it as held up) restarts
    // the count rather than failing the run; anything the graph misses fails it below.
    let clean = rec.poll_until(Duration::from_secs(60), |r| {
        clean_run_at_end(&running_states(r)) >= 400
    });
    // Stop the graph (SIGTERM: bridge first) whether or not it got there.
    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    let misses = miss_report(&log_text);
    assert!(clean, "no 400 ticks in a row without a miss:\n{misses}");
    assert!(out.status.success(), "scl up failed: {log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ticks = summary["ticks"].as_u64().unwrap();
    assert!(ticks >= 400, "{summary}");
    assert!(summary["failure"].is_null(), "{summary}");
    // Every miss there was is the machine's: the graph itself (joystick, mapper, safety, the
    // pipelined Kortex link) delivered every command in time. (A reply the fake robot, in
    // this test's process, was slow to send is a stale reading, not a miss.)
    assert_misses_only_held_up(&summary, &log_text, "kortex graph");
    let missed = summary["missed"].as_u64().unwrap();

    // The graph's view: every tick in turn from a real robot (no MOCK flag); in the last 400
    // at least, each executing its own command.
    let states = running_states(&rec);
    assert!(states.len() >= 400);
    for w in states.windows(2) {
        assert_eq!(w[1].tick, w[0].tick + 1, "gap in ticks");
        assert_eq!(w[1].flags & state_flags::MOCK, 0);
    }
    assert!(clean_run_at_end(&states) >= 400, "{misses}");

    // The robot's view: it received the commands safety let through for the ticks the graph
    // executed, in order, converted to deg/s and back; the only other commands it got are
    // the bridge's controlled stops, one per miss.
    let log = fake.joint_speed_log();
    let safe = &rec.safe_commands;
    let executed: Vec<&ipc_types::SafeCommand> = states
        .windows(2)
        .filter(|w| w[1].applied_tick == w[0].tick)
        .map(|w| {
            safe.iter()
                .find(|c| c.tick == w[0].tick)
                .unwrap_or_else(|| panic!("tick {} executed a command never sent", w[0].tick))
        })
        .collect();
    assert!(executed.len() >= 399);
    let same = |got: &[f64], sent: &ipc_types::SafeCommand| {
        (0..6).all(|j| (got[j] - sent.qdot_rad_s[j]).abs() < 1e-6)
    };
    let mut at = 0;
    let mut other = 0;
    for sent in &executed {
        while at < log.len() && !same(&log[at], sent) {
            other += 1;
            at += 1;
        }
        assert!(
            at < log.len(),
            "the command of tick {} ({:?} rad/s) never reached the robot",
            sent.tick,
            &sent.qdot_rad_s[..6]
        );
        at += 1;
    }
    assert!(
        other as u64 <= missed,
        "the robot got {other} commands that safety did not send, with {missed} missed ticks"
    );
    let travel = summary["joint_travel_rad"].as_f64().unwrap();
    assert!(travel > 0.5, "the arm hardly moved: {travel} rad");

    // The arm stopped and the session closed at the end; the last state published is the
    // robot's own, after the stop.
    let s = fake.snapshot();
    assert!(!s.commanded_to_move());
    assert_eq!(s.stats.sessions_closed, 1);
    assert!(s.stats.stops >= 1);
    assert_eq!(s.stats.connection_timeouts, 0);
    let last = rec.robot_states.last().unwrap();
    assert!(last.flags & state_flags::SHUTDOWN != 0);
    for j in 0..6 {
        assert!((last.q_rad[j] - s.q_rad[j]).abs() < 1e-5, "joint {j}");
    }
    assert_no_credentials(&log_text);
    let late = log_text
        .lines()
        .rev()
        .find(|l| l.contains("bridge exiting"))
        .unwrap_or_default()
        .to_owned();
    eprintln!(
        "kortex graph: {ticks} ticks, {} missed, {} commands executed by the fake robot; {late}",
        summary["missed"],
        log.len()
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn killing_the_bridge_lets_the_robot_stop_the_arm_on_its_connection_timeout() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("kill");
    let config = write_config(&dir.0, &fake, false, "");
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxkill");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up(&prefix, &config, &log, true);
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| running_states(r).len() >= 80),
        "the graph did not start: {}",
        std::fs::read_to_string(&log).unwrap()
    );
    let before = fake.snapshot();
    assert!(
        before.commanded_to_move(),
        "the arm is not moving: {before:?}"
    );
    let pid = rec.pid_of(NodeRole::Bridge).unwrap();
    scl_tests::send_signal(pid, Signal::SIGKILL);
    // Nobody stops the arm but the robot's own watchdog. Waited for until it fired after the
    // bridge's last frame: a machine that held the bridge up for the timeout before the kill
    // fires it once early, and the bridge's next frame re-arms it, as on the robot.
    let t0 = Instant::now();
    let fired_after_last_frame = |s: &hw_bridge::kortex::FakeSnapshot| {
        s.stats.connection_timeouts > 0
            && !s.commanded_to_move()
            && s.since_last_frame
                .is_some_and(|d| d > Duration::from_millis(200))
    };
    while !fired_after_last_frame(&fake.snapshot()) {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the connection timeout never stopped the arm: {:?}",
            fake.snapshot()
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    let after = fake.snapshot();
    assert!(!after.commanded_to_move(), "{after:?}");
    assert_eq!(
        after.stats.stops, before.stats.stops,
        "a Stop came from a dead bridge"
    );
    assert_eq!(after.stats.sessions_closed, 0);
    let gap = after.last_timeout_gap.unwrap();
    assert!(gap >= Duration::from_millis(200), "stopped after {gap:?}");
    // The arm stays stopped.
    let q = after.q_rad;
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(fake.snapshot().q_rad, q);

    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(out.status.code(), Some(1), "{log_text}");
    assert!(
        log_text.contains("the bridge process") && log_text.contains("SIGKILL"),
        "{log_text}"
    );
    assert_no_credentials(&log_text);
    eprintln!(
        "kortex kill: the fake robot stopped the arm {} ms after the bridge's last frame",
        gap.as_millis()
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// With the bridge restarted by the supervisor (`on-failure`), the robot's own connection
/// timeout stops the arm while no bridge runs; the new bridge opens a new session, starts from
/// a stop and drives the arm again.
#[test]
fn a_restarted_bridge_reconnects_after_the_robot_stopped_the_arm_itself() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("restart");
    let config = write_config(
        &dir.0,
        &fake,
        false,
        // A restart delay longer than the robot's connection timeout (200 ms), so that the
        // robot's watchdog, not the new bridge, stops the arm (the fake models a new session
        // that comes sooner: a_new_session_does_not_cancel_the_frozen_sessions_connection_timeout).
        // The step script's stick returns to neutral every 2.5 s: the restarted bridge starts
        // from a stop, and the arm moves again only once the stick has passed through neutral
        // (restart prevention); the circle never does.
        "\n[supervisor]\nbackoff_initial_ms = 1000\n[supervisor.restart]\nbridge = \"on-failure\"\n\
         [joystick]\nscript = \"step\"\n",
    );
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxrestart");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up(&prefix, &config, &log, true);
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| running_states(r).len() >= 80),
        "the graph did not start: {}",
        std::fs::read_to_string(&log).unwrap()
    );
    let before = fake.snapshot();
    assert!(
        before.commanded_to_move(),
        "the arm is not moving: {before:?}"
    );
    let last_before = *rec.robot_states.last().unwrap();
    let pid = rec.pid_of(NodeRole::Bridge).unwrap();
    scl_tests::send_signal(pid, Signal::SIGKILL);
    // The robot's watchdog stops the arm before any new session exists (the restart waits
    // for its backoff, 1 s).
    let t0 = Instant::now();
    let stopped = loop {
        let s = fake.snapshot();
        if s.stats.connection_timeouts > before.stats.connection_timeouts {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the connection timeout never stopped the arm: {s:?}"
        );
        std::thread::sleep(Duration::from_millis(1));
    };
    assert!(!stopped.commanded_to_move(), "{stopped:?}");
    assert_eq!(
        stopped.stats.sessions_opened, before.stats.sessions_opened,
        "a new session opened before the robot stopped the arm"
    );
    assert_eq!(
        stopped.stats.stops, before.stats.stops,
        "a Stop came from a dead bridge"
    );
    // The new bridge: a new session, then the arm moves again.
    let t0 = Instant::now();
    loop {
        let s = fake.snapshot();
        if s.stats.sessions_opened > before.stats.sessions_opened && s.commanded_to_move() {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the restarted bridge did not drive the arm: {s:?}\n{}",
            std::fs::read_to_string(&log).unwrap()
        );
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
    }
    rec.poll_for(Duration::from_millis(200));
    // Its first state continues the tick count and reports a stop, not the last command.
    let first = rec
        .robot_states
        .iter()
        .find(|s| s.tick > last_before.tick && s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .expect("no state from the restarted bridge");
    assert_eq!(
        first.applied_tick,
        ipc_types::NO_TICK,
        "the new bridge did not start from a stop"
    );

    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(out.status.success(), "{log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["restarts"], 1, "{summary}");
    assert_no_credentials(&log_text);
    // The new bridge closed its session on the way out.
    assert!(fake.snapshot().stats.sessions_closed >= 1);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_robot_error_stops_the_arm_and_ends_the_graph_with_its_name() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("fault");
    let config = write_config(&dir.0, &fake, false, "");
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxfault");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up(&prefix, &config, &log, true);
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| running_states(r).len() >= 40),
        "the graph did not start: {}",
        std::fs::read_to_string(&log).unwrap()
    );
    assert!(fake.snapshot().commanded_to_move());
    fake.inject(
        Fault::ErrorReply {
            code: 3,
            sub_code: 22,
            detail: "actuator 4 over temperature".into(),
        },
        Some(Function::SendJointSpeedsCommand),
    );
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(out.status.code(), Some(1), "{log_text}");
    assert!(
        log_text.contains("the robot refused Base.SendJointSpeedsCommand (message")
            && log_text.contains(
                "device error (code 3), robot in fault (sub-code 22): actuator 4 over temperature"
            ),
        "{log_text}"
    );
    assert!(
        log_text.contains("the bridge process") && log_text.contains("exited with status 2"),
        "{log_text}"
    );
    let s = fake.snapshot();
    assert!(!s.commanded_to_move(), "{s:?}");
    assert!(s.stats.stops >= 1, "{s:?}");
    assert_eq!(s.stats.sessions_closed, 1);
    let last = rec.robot_states.last().unwrap();
    assert!(
        last.flags & state_flags::SHUTDOWN != 0,
        "the bridge did not publish its stop"
    );
    assert_no_credentials(&log_text);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// A fake robot for low-level mode (its cyclic timeout long for a loaded machine; the
/// product's figure is the robot's; reading the cyclic command wrongly with `misread`) and
/// `scl up --for RUN_FOR --script circle` on it at 1 kHz with `mode = "low-level"`.
struct LowLevelRun {
    fake: FakeKortex,
    start_q: Vec<f64>,
    dir: TempDir,
    log: PathBuf,
    prefix: ipc_types::Prefix,
    rec: Recorder,
    guard: ChildGuard,
}

fn low_level_up(tag: &str, run_for: &str, misread: Option<CyclicMisread>) -> LowLevelRun {
    low_level_up_on(
        kinematics::RobotProfile::default_robot(),
        tag,
        run_for,
        misread,
    )
}

/// [`low_level_up`] on the arm of `robot` (the fake plays it, `[graph] robot` names it).
fn low_level_up_on(
    robot: &'static kinematics::RobotProfile,
    tag: &str,
    run_for: &str,
    misread: Option<CyclicMisread>,
) -> LowLevelRun {
    let fake = FakeKortex::start(FakeConfig {
        credentials: Credentials::new(USER, PASSWORD),
        cyclic_timeout: Duration::from_millis(500),
        cyclic_misread: misread,
        ..FakeConfig::for_robot(robot)
    })
    .unwrap();
    let start_q = fake.snapshot().q_rad;
    let dir = TempDir::new(tag);
    let config = dir.0.join("graph.toml");
    std::fs::write(
        &config,
        format!(
            "[graph]\nrobot = \"{}\"\nrate_hz = 1000\n\n[bridge]\nrobot = \"kortex\"\n\n\
             [bridge.kortex]\naddress = \"127.0.0.1\"\nport = {}\ncyclic_port = {}\n\
             mode = \"low-level\"\nreply_timeout_ms = 1000\n",
            robot.name(),
            fake.addr().port(),
            fake.cyclic_addr().port()
        ),
    )
    .unwrap();
    let log = dir.0.join("up.log");
    let prefix = unique_prefix(tag);
    let rec = Recorder::join(&prefix);
    let guard = ChildGuard(Some(
        Command::new(scl_binary())
            .arg("--config")
            .arg(&config)
            .args(["up", "--for", run_for, "--json", "--script", "circle"])
            .env("SCL_PREFIX", prefix.as_str())
            .env("SCL_LOG", "info")
            .env("SCL_KORTEX_USER", USER)
            .env("SCL_KORTEX_PASSWORD", PASSWORD)
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    ));
    LowLevelRun {
        fake,
        start_q,
        dir,
        log,
        prefix,
        rec,
        guard,
    }
}

/// `[bridge.kortex] mode = "low-level"` at 1 kHz for a few seconds: the bridge drives the fake
/// arm with a BaseCyclic.Refresh per tick over UDP (position commands integrated from the safe
/// joint speeds), no joint speed command ever, and goes back to single-level servoing at the
/// end. It checks the logic, not the timing: the machine's hold-ups are tolerated (the fake's
/// cyclic timeout is long for a loaded machine; the product's figure is the robot's).
#[test]
fn the_graph_drives_the_fake_arm_in_low_level_mode_at_1_khz() {
    let _serial = serial();
    drives_in_low_level_mode(kinematics::RobotProfile::default_robot(), "kxlow");
}

/// The same on the 7-joint Gen3: seven actuators on the cyclic channel, its bundled model.
#[test]
fn the_graph_drives_a_fake_gen3_in_low_level_mode_at_1_khz() {
    let _serial = serial();
    let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
    drives_in_low_level_mode(gen3, "kxlow7");
}

fn drives_in_low_level_mode(robot: &'static kinematics::RobotProfile, tag: &str) {
    let n = robot.n_joints();
    let LowLevelRun {
        fake,
        start_q,
        dir: _dir,
        log,
        prefix,
        mut rec,
        mut guard,
    } = low_level_up_on(robot, tag, "3s", None);
    let _domain = DomainGuard(prefix.clone());
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(out.status.success(), "scl up failed: {log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(summary["failure"].is_null(), "{summary}");
    let ticks = summary["ticks"].as_u64().unwrap();
    assert!(ticks >= 1000, "{summary}");
    assert!(
        log_text.contains("first position command = the measured position"),
        "{log_text}"
    );
    // The entry check held the measured position, counted the commands it held back (said
    // once), and let the graph's commands apply after it.
    assert!(
        log_text.contains("low-level entry check passed")
            && log_text.contains("commands held back during the hold"),
        "{log_text}"
    );
    assert_eq!(
        log_text.matches("held back during the hold").count(),
        1,
        "{log_text}"
    );

    eprintln!(
        "low-level graph at 1 kHz on the {}: {summary}",
        robot.name()
    );
    assert_eq!(rec.robot_states.last().unwrap().n_joints as usize, n);
    let s = fake.snapshot();
    // The first command was the measured position (the arm at rest at its start pose).
    let first = s.first_position_command.clone().unwrap();
    for j in 0..n {
        assert!((first[j] - start_q[j]).abs() < 1e-4, "joint {j}: {s:?}");
    }
    // A Refresh per tick (the bridge's stops hold the position with one too), no joint speeds.
    assert!(s.stats.refreshes >= ticks / 2, "{ticks} ticks: {s:?}");
    assert_eq!(s.stats.joint_speed_commands, 0, "{s:?}");
    assert_eq!(s.stats.cyclic_timeouts, 0, "{s:?}");
    assert!(!s.in_fault, "{s:?}");
    // The arm moved through its position commands as far as safety let the stick move it (on
    // a loaded machine a stale state may hold it still until the stick is neutral: the
    // integration itself is tested in hw-bridge's kortex_low_level), and the last state the
    // graph published is the robot's own.
    let travel = summary["joint_travel_rad"].as_f64().unwrap();
    let moved: f64 = (0..n).map(|j| (s.q_rad[j] - start_q[j]).abs()).sum();
    assert!(travel == 0.0 || moved > 0.0, "travel {travel} rad: {s:?}");
    let last = rec.robot_states.last().unwrap();
    assert!(last.flags & state_flags::SHUTDOWN != 0);
    for j in 0..n {
        assert!(
            (last.q_rad[j] - s.q_rad[j]).abs() < 1e-4,
            "joint {j}: {s:?}"
        );
    }
    // Back to single-level servoing, both sessions closed.
    assert!(s.single_level_servoing && !s.low_level_servoing, "{s:?}");
    assert!(!s.session_open && !s.cyclic_session_open, "{s:?}");
    assert_no_credentials(&log_text);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// Low-level mode: the arm is pushed off its position command and held; the bridge's
/// following-error check stops the arm and ends the graph with a clear error, and the robot is
/// back in single-level servoing.
#[test]
fn a_following_error_in_low_level_mode_stops_the_graph() {
    let _serial = serial();
    let LowLevelRun {
        fake,
        dir: _dir,
        log,
        prefix,
        mut rec,
        mut guard,
        ..
    } = low_level_up("kxfollow", "15s", None);
    let _domain = DomainGuard(prefix.clone());
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| running_states(r).len() >= 300),
        "the graph did not start: {}",
        std::fs::read_to_string(&log).unwrap()
    );
    // Whatever the stick does (safety may hold the arm still on a loaded machine), the arm is
    // pushed 0.1 rad off its command on joint 3 and held there.
    fake.block_arm(true);
    fake.push_arm(&[0.0, 0.0, 0.0, 0.1, 0.0, 0.0]);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}: {log_text}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(
        log_text.contains("following error: joint 3")
            && log_text.contains("bridge.kortex.following_error_rad = 0.05"),
        "{log_text}"
    );
    let s = fake.snapshot();
    assert!(s.single_level_servoing && !s.low_level_servoing, "{s:?}");
    assert!(!s.session_open && !s.cyclic_session_open, "{s:?}");
    assert!(!s.commanded_to_move(), "{s:?}");
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// Low-level mode on a robot that reads the cyclic command differently than the bridge means
/// (here: every position as 0°): during the entry hold the arm leaves the measured position the
/// bridge holds; the bridge stops it, goes back to single-level servoing, and the graph ends
/// with the entry check's error naming the joint, the measured and the held position. The
/// graph's commands never reached the arm: every Refresh carried the held position.
#[test]
fn a_robot_that_misreads_the_cyclic_command_fails_the_entry_check_and_ends_the_graph() {
    let _serial = serial();
    let LowLevelRun {
        fake,
        start_q,
        dir: _dir,
        log,
        prefix,
        mut rec,
        mut guard,
    } = low_level_up("kxentry", "15s", Some(CyclicMisread::ZeroPosition));
    let _domain = DomainGuard(prefix.clone());
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}: {log_text}",
        String::from_utf8_lossy(&out.stdout)
    );
    // Joint 1 is the first joint of the start pose away from 0.
    assert!(
        log_text.contains("low-level entry check failed: joint 1")
            && log_text.contains(&format!("held it at {:.4} rad", start_q[1]))
            && log_text.contains("did not follow the held position")
            && log_text.contains("bridge.kortex.entry_hold_tolerance_rad = 0.005"),
        "{log_text}"
    );
    assert!(!log_text.contains("entry check passed"), "{log_text}");
    let s = fake.snapshot();
    assert!(s.single_level_servoing && !s.low_level_servoing, "{s:?}");
    assert!(!s.session_open && !s.cyclic_session_open, "{s:?}");
    assert!(!s.commanded_to_move(), "{s:?}");
    let (first, last) = (
        s.first_position_command.clone().unwrap(),
        s.last_position_command.clone().unwrap(),
    );
    for j in 0..6 {
        assert!((first[j] - start_q[j]).abs() < 1e-4, "joint {j}: {s:?}");
        assert!((last[j] - first[j]).abs() < 1e-6, "joint {j}: {s:?}");
    }
    // The arm had moved towards the misread position, beyond the tolerance, when the bridge
    // stopped it.
    assert!((s.q_rad[1] - start_q[1]).abs() > 0.005, "{s:?}");
    assert_no_credentials(&log_text);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// The periods lost between two states `t0_ns` and `t1_ns` (monotonic ns) of a graph ticking
/// every `period_ns`: whole periods to the nearest, less the one between consecutive states.
fn lost_periods(t0_ns: u64, t1_ns: u64, period_ns: u64) -> u64 {
    ((t1_ns.saturating_sub(t0_ns) + period_ns / 2) / period_ns).saturating_sub(1)
}

/// The states of the bridge that followed the one killed after `last_before`: those after
/// the first gap of more than three periods (the restart takes at least the supervisor's
/// backoff, 100 ms); with the last state of the killed bridge.
fn after_restart(
    states: &[ipc_types::RobotState],
    last_before: &ipc_types::RobotState,
) -> Option<(ipc_types::RobotState, Vec<ipc_types::RobotState>)> {
    let k = states.iter().position(|s| s.tick == last_before.tick)?;
    let split =
        (k + 1..states.len()).find(|&i| states[i].t_ns - states[i - 1].t_ns > 75_000_000)?;
    Some((states[split - 1], states[split..].to_vec()))
}

/// Issue 29, items 1 and 5: the bridge is killed while the drill map moves joint 0 at
/// 0.4 rad/s, and restarted (`on-failure`) before the robot's own connection timeout (2 s
/// here, Kinova's example value) stops the arm: the arm is still moving when the new bridge
/// connects. The new bridge must start from a stop: none of its states reports an executed
/// command until the measured speed is ~0 (and the robot's first motion request from the new
/// session is a Stop, not joint speeds); motion resumes only after the operator's input was
/// neutral (the stick is held deflected across the restart). The periods lost while no bridge
/// ran (from the timestamps of the last state before and the first after) are counted in
/// `scl up --json` `missed` and in the new bridge's states.
#[test]
fn a_restarted_bridge_that_finds_the_arm_moving_stops_it_first_then_waits_for_neutral() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("moving");
    // Stick: at rest 0.5 s (the first motion needs neutral), then deflected for 6 s with
    // 0.6 s at rest between; the drill map ignores it, so the arm moves all along.
    scl_tests::write_replay(
        &dir.0.join("input.csv"),
        &scl_tests::pulses([0.8, 0.0], 6.0, 0.6, 120.0),
    );
    let config = write_config(
        &dir.0,
        &fake,
        false,
        "connection_timeout_ms = 2000\n\n[supervisor.restart]\nbridge = \"on-failure\"\n\n\
         [mapper]\nmodel = \"constant:qdot=0.4,0,0,0,0,0\"\n\n\
         [joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n",
    );
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxmoving");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up(&prefix, &config, &log, true);
    let deflected = |r: &Recorder| {
        r.joystick_samples
            .last()
            .is_some_and(|j| j.axes[0].abs() > 0.5)
    };
    // Kill early in a deflected stretch, with the arm moving at 0.4 rad/s: the stick stays
    // deflected for seconds after the restart.
    let ready = rec.poll_until(Duration::from_secs(60), |r| {
        let states = running_states(r);
        states.len() >= 40
            && states
                .last()
                .is_some_and(|s| (s.qdot_rad_s[0] - 0.4).abs() < 0.01)
            && deflected(r)
    });
    assert!(
        ready,
        "the arm never moved at 0.4 rad/s with the stick deflected: {}",
        std::fs::read_to_string(&log).unwrap()
    );
    let last_before = *running_states(&rec).last().unwrap();
    let sessions_before = fake.snapshot().stats.sessions_opened;
    let pid = rec.pid_of(NodeRole::Bridge).unwrap();
    scl_tests::send_signal(pid, Signal::SIGKILL);

    // The new bridge: wait until it executes a moving command again.
    let moved_again = rec.poll_until(Duration::from_secs(40), |r| {
        let Some((_, new)) = after_restart(&running_states(r), &last_before) else {
            return false;
        };
        new.iter().any(|s| {
            s.applied_tick != ipc_types::NO_TICK
                && r.safe_commands
                    .iter()
                    .any(|c| c.tick == s.applied_tick && c.qdot_rad_s[0].abs() > 1e-3)
        })
    });
    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(moved_again, "the arm never moved again: {log_text}");
    assert!(out.status.success(), "{log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["restarts"], 1, "{summary}");

    // What the graph published before the kill and after the restart.
    let (last_before, new) = after_restart(&running_states(&rec), &last_before).unwrap();
    let first = new[0];
    assert_eq!(first.tick, last_before.tick + 1, "the tick count goes on");
    assert!(
        first.qdot_rad_s[0] > 0.3,
        "the arm was not moving when the new bridge connected (the robot's timeout is 2 s): \
         {first:?}"
    );
    // Item 5: the periods lost while no bridge ran are counted as missed.
    let lost = lost_periods(last_before.t_ns, first.t_ns, 25_000_000);
    assert!(lost >= 3, "a restart within {lost} periods? {first:?}");
    assert!(
        first.missed >= lost,
        "{lost} periods lost, the new bridge counts {}",
        first.missed
    );
    let missed = summary["missed"].as_u64().unwrap();
    assert!(
        missed >= lost,
        "{lost} periods lost, scl up reports missed {missed}: {summary}"
    );

    let speed =
        |s: &ipc_types::RobotState| s.qdot_rad_s[..6].iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // Stops only until the arm is at rest: no state up to the first at rest reports an executed
    // command, and each is flagged stopping.
    let mut rest = None;
    for (i, s) in new.iter().enumerate() {
        assert_eq!(
            s.applied_tick,
            ipc_types::NO_TICK,
            "the new bridge executed a command before the arm was at rest: {s:?}"
        );
        assert!(s.flags & state_flags::STOPPING != 0, "{s:?}");
        if speed(s) <= 0.01 {
            rest = Some(i);
            break;
        }
    }
    let rest = rest.expect("the arm never came to rest");
    // The robot's view: the new session's first motion request was a Stop.
    let requests = fake.request_log();
    let opened = requests
        .iter()
        .enumerate()
        .filter(|(_, r)| r.function() == Some(Function::CreateSession))
        .map(|(i, _)| i)
        .nth(usize::try_from(sessions_before).unwrap())
        .expect("no new session");
    let first_motion = requests[opened..]
        .iter()
        .filter_map(|r| r.function())
        .find(|f| matches!(f, Function::Stop | Function::SendJointSpeedsCommand));
    assert_eq!(first_motion, Some(Function::Stop), "{requests:?}");

    // Motion resumes only after neutral input: the first moving command executed by the new
    // bridge answers a tick at or after a mapper command whose stick was at rest, and the stick
    // was still deflected after the restart (the neutral requirement was exercised).
    let executed_moving = new
        .iter()
        .filter(|s| s.applied_tick != ipc_types::NO_TICK)
        .filter_map(|s| {
            rec.safe_commands
                .iter()
                .find(|c| c.tick == s.applied_tick && c.qdot_rad_s[0].abs() > 1e-3)
        })
        .map(|c| c.tick)
        .min()
        .unwrap();
    let new_mapper: Vec<&ipc_types::MapperCommand> = rec
        .mapper_commands
        .iter()
        .filter(|m| m.tick >= first.tick && m.tick <= executed_moving)
        .collect();
    let norm = |m: &ipc_types::MapperCommand| f64::from(m.action[0]).hypot(f64::from(m.action[1]));
    let neutral_at = new_mapper
        .iter()
        .find(|m| norm(m) <= 0.05)
        .map(|m| m.tick)
        .unwrap_or_else(|| {
            panic!("motion resumed at tick {executed_moving} without neutral input")
        });
    assert!(
        new_mapper
            .iter()
            .any(|m| m.tick < neutral_at && norm(m) > 0.5),
        "the stick was not deflected after the restart: the test did not exercise the neutral \
         requirement"
    );
    let rest_tick = new[rest].tick;

    let travel = (new[rest].q_rad[0] - last_before.q_rad[0]).abs();
    let stop_ms = (new[rest].t_ns - last_before.t_ns) as f64 * 1e-6;
    eprintln!(
        "kortex restart while moving: {lost} periods lost ({:.0} ms down), first state at \
         {:.3} rad/s, at rest {} ticks later ({stop_ms:.0} ms, {travel:.3} rad from the last \
         state before the kill), moving again {} ticks after rest (neutral at tick +{}); \
         missed {missed}",
        (first.t_ns - last_before.t_ns) as f64 * 1e-6,
        first.qdot_rad_s[0],
        rest,
        executed_moving - rest_tick,
        neutral_at - first.tick,
    );
    assert_no_credentials(&log_text);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// `scl fake-kortex --robot ROBOT --port 0` as a child: its guard and the TCP port from its
/// first line on stdout.
fn fake_kortex_process(robot: &str) -> (ChildGuard, u16) {
    use std::io::BufRead;
    let mut guard = ChildGuard(Some(
        Command::new(scl_binary())
            .args(["fake-kortex", "--robot", robot, "--port", "0"])
            .env("SCL_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    ));
    let stdout = guard.child().stdout.take().unwrap();
    let mut line = String::new();
    std::io::BufReader::new(stdout)
        .read_line(&mut line)
        .unwrap();
    let port = line
        .trim()
        .strip_prefix("listening on 127.0.0.1:")
        .unwrap_or_else(|| panic!("scl fake-kortex said {line:?}"))
        .parse()
        .unwrap();
    (guard, port)
}

/// The graph config of a Gen3 (`[graph] robot = "gen3"`) on the Kortex robot at `port`.
fn write_gen3_config(dir: &Path, port: u16) -> PathBuf {
    let p = dir.join("graph.toml");
    std::fs::write(
        &p,
        format!(
            "[graph]\nrobot = \"gen3\"\n\n[bridge]\nrobot = \"kortex\"\n\n[bridge.kortex]\n\
             address = \"127.0.0.1\"\nport = {port}\nreply_timeout_ms = 1000\n"
        ),
    )
    .unwrap();
    p
}

/// `scl up --config FILE --for 60s --json --model modeswitch` (the Cartesian map: its motion
/// does not depend on a trained model),
/// credentials `user` / `password` in the environment.
fn up_gen3(
    prefix: &ipc_types::Prefix,
    config: &Path,
    log: &Path,
    user: &str,
    password: &str,
) -> ChildGuard {
    ChildGuard(Some(
        Command::new(scl_binary())
            .args(["up", "--config", config.to_str().unwrap()])
            .args(["--for", "60s", "--json", "--model", "modeswitch"])
            .env("SCL_PREFIX", prefix.as_str())
            .env("SCL_LOG", "info")
            .env("SCL_KORTEX_USER", user)
            .env("SCL_KORTEX_PASSWORD", password)
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(log).unwrap())
            .spawn()
            .unwrap(),
    ))
}

/// A Gen3 graph on `scl fake-kortex --robot gen3`: 200 ticks in a row without a miss, seven
/// joints in every state, the arm moved and stopped at the end.
#[test]
fn a_gen3_graph_drives_scl_fake_kortex_gen3_for_200_ticks_without_a_miss() {
    let _serial = serial();
    let (mut fake, port) = fake_kortex_process("gen3");
    let dir = TempDir::new("gen3");
    let config = write_gen3_config(&dir.0, port);
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxgen3");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up_gen3(&prefix, &config, &log, "admin", "admin");
    let clean = rec.poll_until(Duration::from_secs(60), |r| {
        clean_run_at_end(&running_states(r)) >= 200
    });
    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    let misses = miss_report(&log_text);
    assert!(
        clean,
        "no 200 ticks in a row without a miss:\n{misses}\n{log_text}"
    );
    assert!(out.status.success(), "scl up failed: {log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(summary["failure"].is_null(), "{summary}");
    assert_misses_only_held_up(&summary, &log_text, "kortex gen3 graph");
    assert!(
        log_text.contains("Kortex session open; a Gen3 (Kortex model L53, 7 actuators)"),
        "{log_text}"
    );
    let states = running_states(&rec);
    assert!(states.len() >= 200);
    for s in &states {
        assert_eq!(s.flags & state_flags::MOCK, 0);
        assert!(s.q_rad[..7].iter().all(|q| q.is_finite()));
        assert_eq!(s.q_rad[7], 0.0, "an eighth joint: {:?}", s.q_rad);
    }
    let moved = states
        .iter()
        .any(|s| (0..7).any(|j| (s.q_rad[j] - states[0].q_rad[j]).abs() > 1e-3));
    assert!(moved, "the Gen3 never moved");
    let last = rec.robot_states.last().unwrap();
    assert!(last.flags & state_flags::SHUTDOWN != 0);
    assert!(
        last.qdot_rad_s[..7].iter().all(|v| v.abs() < 1e-6),
        "{:?}",
        last.qdot_rad_s
    );
    eprintln!(
        "kortex gen3 graph: {} ticks, {} missed",
        summary["ticks"], summary["missed"]
    );
    scl_tests::send_signal(fake.child().id(), Signal::SIGTERM);
    let status = fake.take().wait().unwrap();
    assert!(status.success(), "scl fake-kortex: {status}");
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// A Gen3 graph on a Gen3 lite: the bridge refuses the arm at connect, before commanding
/// anything, naming the robot found and the profile configured; the graph does not start.
#[test]
fn a_gen3_graph_refuses_a_gen3_lite_naming_both() {
    let _serial = serial();
    let fake = fake();
    let dir = TempDir::new("gen3-lite");
    let config = write_gen3_config(&dir.0, fake.addr().port());
    let log = dir.0.join("up.log");
    let prefix = unique_prefix("kxwrong");
    let _domain = DomainGuard(prefix.clone());
    let mut rec = Recorder::join(&prefix);
    let mut guard = up_gen3(&prefix, &config, &log, USER, PASSWORD);
    let out = wait_for_exit(&mut rec, &mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert_ne!(out.status.code(), Some(0), "{log_text}");
    assert!(
        log_text.contains(
            "wrong robot: the robot found is a Gen3 lite (Kortex model L31, 6 actuators), but \
             the configured robot profile `gen3` is a Gen3 (Kortex model L53, 7 actuators)"
        ),
        "{log_text}"
    );
    assert!(running_states(&rec).is_empty(), "the graph ticked");
    let s = fake.snapshot();
    assert!(!s.single_level_servoing && !s.commanded_to_move(), "{s:?}");
    assert_eq!(s.stats.joint_speed_commands, 0);
    assert_eq!((s.stats.sessions_opened, s.stats.sessions_closed), (1, 1));
    assert_no_credentials_at_all(&log_text);
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

fn assert_no_credentials_at_all(log: &str) {
    assert!(!log.contains(PASSWORD), "the password is in the logs");
    assert!(!log.contains(USER), "the user name is in the logs");
}
