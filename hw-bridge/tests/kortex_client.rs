//! The Kortex client against the fake robot over TCP on loopback: start-up, the pipelined
//! loop, the gripper, the robot's limits, and every bad input ending in a stopped arm and a
//! clear message. Each test runs its own fake robot on a free port of 127.0.0.1.
//!
//! The machine running these may be loaded (two shared cores): where the reply timeout is not
//! the point, the client waits [`REPLY_TIMEOUT_MS`] for a reply, so a starved fake thread
//! cannot fail a tick; the connection inactivity timeout stays at the product's 200 ms.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use hw_bridge::kortex::wire::{Decoded, Frame, FrameDecoder, FrameType, RobotFault};
use hw_bridge::kortex::{
    Credentials, FakeConfig, FakeKortex, Fault, Function, KortexArm, KortexConfig, KortexError,
    gripper_position_msg, joint_speeds_msg, msg,
};
use hw_bridge::tick::BridgeCore;
use hw_bridge::{Robot, RobotError};
use ipc_types::{MAX_JOINTS, NO_TICK, SafeCommand, state_flags};
use kinematics::{RobotProfile, gen3_lite};
use prost::Message as _;

const DT: f64 = 0.025;
const PERIOD: Duration = Duration::from_millis(25);
const MOVE: [f64; 6] = [0.2, -0.1, 0.0, 0.0, 0.0, 0.3];

/// The client's reply timeout where timing is not the point (the product's default is 200 ms).
const REPLY_TIMEOUT_MS: u32 = 2_000;

/// The reply timeout of the tests that wait for one to pass: long enough for a loaded machine,
/// short enough to keep them quick.
const SHORT_REPLY_TIMEOUT_MS: u32 = 1_000;

/// The start-up requests, in the order `KortexArm::connect` sends them: the arm's identity
/// (read only) before anything is commanded.
const START_UP: [Function; 7] = [
    Function::CreateSession,
    Function::GetActuatorCount,
    Function::GetProductConfiguration,
    Function::SetServoingMode,
    Function::ClearFaults,
    Function::GetKinematicHardLimits,
    Function::RefreshFeedback,
];

fn start_fake(cfg: FakeConfig) -> FakeKortex {
    FakeKortex::start(cfg).unwrap()
}

/// The default client settings on `fake`, with a reply timeout of [`REPLY_TIMEOUT_MS`].
fn client_cfg(fake: &FakeKortex) -> KortexConfig {
    KortexConfig {
        address: "127.0.0.1".into(),
        port: fake.addr().port(),
        reply_timeout_ms: REPLY_TIMEOUT_MS,
        ..KortexConfig::default()
    }
}

fn admin() -> Credentials {
    Credentials::new("admin", "admin")
}

fn connect(fake: &FakeKortex) -> KortexArm {
    KortexArm::connect(&client_cfg(fake), &admin()).unwrap()
}

/// A client whose reply timeout is [`SHORT_REPLY_TIMEOUT_MS`], for the tests that wait for it.
fn connect_short_reply_timeout(fake: &FakeKortex) -> KortexArm {
    let cfg = KortexConfig {
        reply_timeout_ms: SHORT_REPLY_TIMEOUT_MS,
        ..client_cfg(fake)
    };
    KortexArm::connect(&cfg, &admin()).unwrap()
}

/// The functions the fake received, in order.
fn requested(fake: &FakeKortex) -> Vec<Function> {
    fake.request_log()
        .iter()
        .map(|r| r.function().unwrap())
        .collect()
}

/// One tick of the bridge's loop: advance, command, then the rest of the period.
fn tick(arm: &mut KortexArm, v: &[f64], gripper_rate: f64) -> Result<(), RobotError> {
    arm.advance(DT)?;
    arm.command(v, gripper_rate)?;
    std::thread::sleep(PERIOD);
    Ok(())
}

fn kortex(e: RobotError) -> KortexError {
    match e {
        RobotError::Kortex(k) => k,
    }
}

/// Ticks until the client fails (at most `max` ticks).
fn tick_until_error(arm: &mut KortexArm, max: usize) -> KortexError {
    for _ in 0..max {
        if let Err(e) = tick(arm, &MOVE, 0.0) {
            return kortex(e);
        }
    }
    panic!("no error within {max} ticks");
}

fn wait_until(
    fake: &FakeKortex,
    what: &str,
    pred: impl Fn(&hw_bridge::kortex::FakeSnapshot) -> bool,
) {
    let t0 = Instant::now();
    while !pred(&fake.snapshot()) {
        assert!(t0.elapsed() < Duration::from_secs(10), "never: {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The arm was moving as commanded, then a fault: it must end stopped, by the client's Stop
/// (and CloseSession) when the connection still works.
fn assert_stopped_by_the_client(fake: &FakeKortex) {
    let s = fake.snapshot();
    assert!(!s.commanded_to_move(), "the arm still moves: {s:?}");
    assert!(s.stats.stops >= 1, "no Stop reached the robot: {s:?}");
    assert_eq!(
        s.stats.sessions_closed, 1,
        "the session was not closed: {s:?}"
    );
    // `connection_timeouts` is not checked: on a loaded machine the test thread may be
    // starved past the 200 ms connection timeout before the fault, which the fake rightly
    // counts; the Stop and CloseSession above are what this checks.
}

/// The connection is gone: the robot's connection inactivity timeout must stop the arm.
/// `timeouts_before` is the fake's count of connection timeouts before the fault (a starved
/// test thread may have let one pass earlier).
fn assert_stopped_by_the_timeout(fake: &FakeKortex, timeouts_before: u64) {
    wait_until(fake, "the connection timeout stops the arm", |s| {
        s.stats.connection_timeouts > timeouts_before
    });
    let s = fake.snapshot();
    assert!(!s.commanded_to_move(), "{s:?}");
    assert!(s.last_timeout_gap.unwrap() >= Duration::from_millis(200));
}

/// Ticks until the fake has the motion command in force (a halt by the connection timeout of
/// a starved test thread is undone by the next command).
fn moving(fake: &FakeKortex, arm: &mut KortexArm) {
    let t0 = Instant::now();
    for _ in 0..4 {
        tick(arm, &MOVE, 0.0).unwrap();
    }
    while !fake.snapshot().commanded_to_move() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the arm never moves"
        );
        tick(arm, &MOVE, 0.0).unwrap();
    }
}

/// The fake's count of connection timeouts now.
fn connection_timeouts(fake: &FakeKortex) -> u64 {
    fake.snapshot().stats.connection_timeouts
}

#[test]
fn start_up_then_the_arm_moves_as_commanded_and_shutdown_stops_and_closes() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    assert_eq!(arm.session_id(), 0x1234);
    assert_eq!(arm.n_joints(), 6);
    assert!(!arm.is_mock());
    let first = arm.advance(DT).unwrap();
    for j in 0..6 {
        assert!((first.q_rad[j] - gen3_lite::HOME[j]).abs() < 1e-5, "{j}");
    }
    let q0 = fake.snapshot().q_rad;
    for _ in 0..40 {
        tick(&mut arm, &MOVE, 0.0).unwrap();
    }
    let reading = arm.advance(DT).unwrap();
    let s = fake.snapshot();
    // Every command reached the robot as sent (deg/s on the wire, rad/s here).
    let log = fake.joint_speed_log();
    assert_eq!(log.len(), 40);
    for cmd in &log {
        for j in 0..6 {
            assert!((cmd[j] - MOVE[j]).abs() < 1e-6, "{cmd:?}");
        }
    }
    // The arm moved along the command: joint 1 twice as far as joint 2, the other way.
    let d: Vec<f64> = (0..6).map(|j| s.q_rad[j] - q0[j]).collect();
    assert!(d[0] > 0.1, "{d:?}");
    assert!((d[1] / d[0] + 0.5).abs() < 0.01, "{d:?}");
    assert!((d[5] / d[0] - 1.5).abs() < 0.01, "{d:?}");
    assert_eq!(d[2], 0.0);
    // The reading is the robot's feedback, wrapped back to radians (one period old at most).
    assert!(reading.q_rad[0] > q0[0] + 0.1 && reading.q_rad[0] <= s.q_rad[0] + 1e-6);
    assert!((reading.qdot_rad_s[0] - 0.2).abs() < 1e-3, "{reading:?}");
    arm.shutdown().unwrap();
    let s = fake.snapshot();
    assert!(!s.commanded_to_move());
    assert_eq!((s.stats.stops, s.stats.sessions_closed), (1, 1));
    // Nothing but the client's own requests reached the robot (no KeepAlive thread).
    assert_eq!(s.stats.frames, arm.stats().requests);
    assert!(arm.advance(DT).is_err(), "the session is closed");
}

#[test]
fn the_session_asks_for_exactly_the_configured_inactivity_timeouts() {
    // The defaults: 200 ms for the connection (the robot-side watchdog), 60 s for the session.
    let defaults = KortexConfig::default();
    assert_eq!(
        (defaults.connection_timeout_ms, defaults.session_timeout_ms),
        (200, 60_000)
    );
    let fake = start_fake(FakeConfig::default());
    assert_eq!(fake.snapshot().connection_timeout_ms, None);
    let mut arm = connect(&fake);
    let s = fake.snapshot();
    assert_eq!(s.connection_timeout_ms, Some(200), "{s:?}");
    assert_eq!(s.session_timeout_ms, Some(60_000), "{s:?}");
    arm.shutdown().unwrap();
    // Other values reach the robot as configured, not a constant of the client.
    let fake = start_fake(FakeConfig::default());
    let cfg = KortexConfig {
        connection_timeout_ms: 345,
        session_timeout_ms: 4_321,
        ..client_cfg(&fake)
    };
    let mut arm = KortexArm::connect(&cfg, &admin()).unwrap();
    let s = fake.snapshot();
    assert_eq!(
        (s.connection_timeout_ms, s.session_timeout_ms),
        (Some(345), Some(4_321)),
        "{s:?}"
    );
    arm.shutdown().unwrap();
}

#[test]
fn start_up_identifies_the_arm_then_sets_servoing_and_clears_faults_in_order() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    assert_eq!(requested(&fake), START_UP);
    let log = fake.request_log();
    // Message ids count up from 1; the session id is 0 until CreateSession answered.
    let ids: Vec<u16> = log.iter().map(|r| r.message_id).collect();
    assert_eq!(ids, [1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(log[0].session_id, 0);
    assert!(log[1..].iter().all(|r| r.session_id == 0x1234), "{log:?}");
    assert!(fake.snapshot().single_level_servoing);
    // The loop, then Stop, a last feedback and CloseSession.
    tick(&mut arm, &MOVE, 0.0).unwrap();
    arm.shutdown().unwrap();
    assert_eq!(
        requested(&fake)[START_UP.len()..],
        [
            // The first tick asks for feedback in `advance`; `command` asks for none while
            // that one is still waiting for its reply.
            Function::RefreshFeedback,
            Function::SendJointSpeedsCommand,
            Function::Stop,
            Function::RefreshFeedback,
            Function::CloseSession,
        ]
    );
    assert_eq!(fake.snapshot().stats.refused_not_servoing, 0);
}

/// A bare Kortex client's session on a connection of its own to `fake`, with the robot-side
/// watchdog `connection_inactivity_timeout_ms` (0: none): the stream, its decoder and the
/// session id (CreateSession is message 1).
fn raw_session(
    fake: &FakeKortex,
    connection_inactivity_timeout_ms: u32,
) -> (TcpStream, FrameDecoder, u16) {
    let mut stream = TcpStream::connect(fake.addr()).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut dec = FrameDecoder::new();
    let info = msg::CreateSessionInfo {
        username: "admin".into(),
        session_inactivity_timeout: 60_000,
        password: "admin".into(),
        connection_inactivity_timeout: connection_inactivity_timeout_ms,
    };
    let reply = raw_call(
        &mut stream,
        &mut dec,
        0,
        1,
        Function::CreateSession,
        info.encode_to_vec(),
    );
    assert_eq!(reply.error(), None);
    let session = reply.header().session_id();
    (stream, dec, session)
}

/// A bare Kortex client on `stream`: sends one request, returns the reply.
fn raw_call(
    stream: &mut TcpStream,
    decoder: &mut FrameDecoder,
    session: u16,
    message_id: u16,
    function: Function,
    payload: Vec<u8>,
) -> Frame {
    raw_call_uid(
        stream,
        decoder,
        session,
        message_id,
        function.uid(),
        payload,
    )
}

/// [`raw_call`] of any function UID.
fn raw_call_uid(
    stream: &mut TcpStream,
    decoder: &mut FrameDecoder,
    session: u16,
    message_id: u16,
    uid: u32,
    payload: Vec<u8>,
) -> Frame {
    let mut out = Vec::new();
    Frame::new(FrameType::Request, session, message_id, uid, payload)
        .unwrap()
        .encode_tcp(&mut out)
        .unwrap();
    stream.write_all(&out).unwrap();
    let mut buf = [0u8; 4096];
    loop {
        while let Some(r) = decoder.next_frame() {
            if let Decoded::Frame(f) = r.unwrap() {
                assert_eq!(f.header().message_id(), message_id);
                return f;
            }
        }
        let n = stream.read(&mut buf).unwrap();
        assert!(n > 0, "the fake closed the connection");
        decoder.push(&buf[..n]);
    }
}

#[test]
fn the_fake_refuses_motion_until_single_level_servoing_is_set() {
    let fake = start_fake(FakeConfig::default());
    // No robot-side watchdog: this test is about servoing, whatever the machine's load.
    let (mut stream, mut dec, session) = raw_session(&fake, 0);
    // A client that skips SetServoingMode: its commands are refused, the arm does not move.
    let speeds = joint_speeds_msg(&MOVE).encode_to_vec();
    let refused = |f: &Frame| {
        matches!(f.error(), Some(RobotFault { code: 3, ref detail, .. })
            if detail.contains("not in single-level servoing"))
    };
    let f = Function::SendJointSpeedsCommand;
    let reply = raw_call(&mut stream, &mut dec, session, 2, f, speeds.clone());
    assert!(refused(&reply), "{:?}", reply.error());
    let gripper = gripper_position_msg(0.5).encode_to_vec();
    let g = Function::SendGripperCommand;
    let reply = raw_call(&mut stream, &mut dec, session, 3, g, gripper.clone());
    assert!(refused(&reply), "{:?}", reply.error());
    let s = fake.snapshot();
    assert!(!s.commanded_to_move() && !s.single_level_servoing, "{s:?}");
    assert_eq!(s.gripper_target, 0.0);
    assert_eq!(s.stats.refused_not_servoing, 2);
    assert_eq!(s.stats.joint_speed_commands, 0);
    // Single-level servoing set: the same commands are executed.
    let mode = msg::ServoingModeInformation {
        servoing_mode: msg::servoing_mode::SINGLE_LEVEL,
    }
    .encode_to_vec();
    let reply = raw_call(
        &mut stream,
        &mut dec,
        session,
        4,
        Function::SetServoingMode,
        mode,
    );
    assert_eq!(reply.error(), None);
    let reply = raw_call(&mut stream, &mut dec, session, 5, f, speeds);
    assert_eq!(reply.error(), None);
    let reply = raw_call(&mut stream, &mut dec, session, 6, g, gripper);
    assert_eq!(reply.error(), None);
    let s = fake.snapshot();
    assert!(s.commanded_to_move() && s.single_level_servoing, "{s:?}");
    assert_eq!(s.gripper_target, 0.5);
    assert_eq!(s.stats.refused_not_servoing, 2);
    let reply = raw_call(
        &mut stream,
        &mut dec,
        session,
        7,
        Function::Stop,
        Vec::new(),
    );
    assert_eq!(reply.error(), None);
    let close = Function::CloseSession;
    let reply = raw_call(&mut stream, &mut dec, session, 8, close, Vec::new());
    assert_eq!(reply.error(), None);
}

#[test]
fn the_gripper_rate_is_integrated_into_position_commands() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    // 2 /s for 10 ticks of 25 ms: the target closes to 0.5.
    for _ in 0..10 {
        tick(&mut arm, &[0.0; 6], 2.0).unwrap();
    }
    wait_until(&fake, "ten gripper commands", |s| {
        s.stats.gripper_commands == 10
    });
    assert!((fake.snapshot().gripper_target - 0.5).abs() < 1e-6);
    // No rate, no gripper command.
    for _ in 0..3 {
        tick(&mut arm, &[0.0; 6], 0.0).unwrap();
    }
    assert_eq!(arm.stats().gripper_commands, 10);
    // Opening fast stops at 0 (fully open).
    for _ in 0..4 {
        tick(&mut arm, &[0.0; 6], -10.0).unwrap();
    }
    wait_until(&fake, "the gripper opens", |s| s.gripper_target == 0.0);
    assert_eq!(arm.stats().gripper_commands, 12);
    // The reading follows the fake gripper's feedback.
    wait_until(&fake, "the gripper is open", |s| s.gripper < 0.05);
    tick(&mut arm, &[0.0; 6], 0.0).unwrap();
    assert!(arm.advance(DT).unwrap().gripper < 0.1);
    arm.shutdown().unwrap();
}

#[test]
fn commands_are_scaled_into_the_robots_own_hard_limits() {
    let fake = start_fake(FakeConfig {
        joint_speed_limits_deg_s: vec![10.0; 6],
        ..FakeConfig::default()
    });
    let mut arm = connect(&fake);
    for l in arm.speed_limits_rad_s() {
        assert!((l - 10f64.to_radians()).abs() < 1e-6);
    }
    // 1 rad/s is 57 deg/s: the fake refuses anything above 10 deg/s with an error frame, so
    // the run only goes on if the client scaled the command down.
    for _ in 0..5 {
        tick(&mut arm, &[1.0, -0.5, 0.0, 0.0, 0.0, 0.0], 0.0).unwrap();
    }
    let log = fake.joint_speed_log();
    assert_eq!(log.len(), 5);
    for cmd in log {
        assert!((cmd[0] - 10f64.to_radians()).abs() < 1e-6, "{cmd:?}");
        assert!((cmd[1] + 5f64.to_radians()).abs() < 1e-6, "{cmd:?}");
    }
    assert_eq!(arm.stats().clamped_commands, 5);
    arm.shutdown().unwrap();
}

#[test]
fn the_loop_is_pipelined_and_late_replies_are_counted() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    // The reply to one command comes 80 ms late (and the stream behind it with it); the
    // client keeps sending a command every tick without waiting for it.
    fake.inject(
        Fault::DelayReply(Duration::from_millis(80)),
        Some(Function::SendJointSpeedsCommand),
    );
    for _ in 0..12 {
        tick(&mut arm, &MOVE, 0.0).unwrap();
    }
    let stats = arm.stats();
    assert!(stats.late_replies >= 1, "{stats:?}");
    assert!(stats.stale_readings >= 1, "{stats:?}");
    wait_until(&fake, "every command arrived", |s| {
        s.stats.joint_speed_commands == 4 + 12
    });
    assert!(arm.is_open());
    arm.shutdown().unwrap();
}

#[test]
fn a_wrong_password_is_refused_by_name_and_not_repeated() {
    let fake = start_fake(FakeConfig::default());
    let e = KortexArm::connect(
        &client_cfg(&fake),
        &Credentials::new("admin", "wr0ng-pw-123"),
    )
    .unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("Session.CreateSession") && text.contains("invalid password (sub-code 15)"),
        "{text}"
    );
    assert!(
        !text.contains("wr0ng") && !format!("{e:?}").contains("wr0ng"),
        "{text}"
    );
    assert_eq!(fake.snapshot().stats.sessions_opened, 0);
}

/// A client of profile `robot` on `fake` (reply timeout [`REPLY_TIMEOUT_MS`]).
fn connect_as(fake: &FakeKortex, robot: &str) -> Result<KortexArm, KortexError> {
    KortexArm::connect_to(
        RobotProfile::by_name(robot).unwrap(),
        &client_cfg(fake),
        &admin(),
    )
}

/// A refused start-up went as far as the arm's identity, then Stop and CloseSession: nothing
/// was commanded but the stop.
fn assert_refused_at_identity(fake: &FakeKortex) {
    let s = fake.snapshot();
    assert_eq!((s.stats.sessions_opened, s.stats.sessions_closed), (1, 1));
    assert!(!s.single_level_servoing && !s.commanded_to_move(), "{s:?}");
    assert_eq!(
        requested(fake),
        [
            Function::CreateSession,
            Function::GetActuatorCount,
            Function::GetProductConfiguration,
            Function::Stop,
            Function::CloseSession,
        ]
    );
}

#[test]
fn a_gen3_lite_is_refused_by_a_gen3_profile_naming_both() {
    let fake = start_fake(FakeConfig::default());
    let e = connect_as(&fake, "gen3").unwrap_err();
    assert!(
        matches!(&e, KortexError::WrongRobot { found, profile, .. }
            if found.actuators == 6 && found.model == msg::model_id::L31 && profile == "gen3"),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "wrong robot: the robot found is a Gen3 lite (Kortex model L31, 6 actuators), but the \
         configured robot profile `gen3` is a Gen3 (Kortex model L53, 7 actuators); set [graph] \
         robot to the arm's profile, or connect to the arm the profile describes"
    );
    assert_refused_at_identity(&fake);
}

#[test]
fn a_gen3_is_refused_by_a_gen3_lite_profile_naming_both() {
    let fake = start_fake(FakeConfig::for_robot(
        RobotProfile::by_name("gen3").unwrap(),
    ));
    let e = connect_as(&fake, "gen3_lite").unwrap_err();
    assert_eq!(
        e.to_string(),
        "wrong robot: the robot found is a Gen3 (Kortex model L53, 7 actuators), but the \
         configured robot profile `gen3_lite` is a Gen3 lite (Kortex model L31, 6 actuators); \
         set [graph] robot to the arm's profile, or connect to the arm the profile describes"
    );
    assert_refused_at_identity(&fake);
    // The default profile is the Gen3 lite's: `connect` refuses it too.
    let fake = start_fake(FakeConfig::for_robot(
        RobotProfile::by_name("gen3").unwrap(),
    ));
    let e = KortexArm::connect(&client_cfg(&fake), &admin()).unwrap_err();
    assert!(matches!(e, KortexError::WrongRobot { .. }), "{e}");
}

#[test]
fn the_model_alone_refuses_an_arm_with_the_profiles_actuator_count() {
    // A Gen3 with the Gen3 lite's six actuators (Kinova sells a 6-joint Gen3): the count
    // matches the gen3_lite profile, the model does not.
    let fake = start_fake(FakeConfig {
        model: msg::model_id::L53,
        ..FakeConfig::default()
    });
    let e = connect_as(&fake, "gen3_lite").unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("the robot found is a Gen3 (Kortex model L53, 6 actuators)")
            && text.contains("profile `gen3_lite` is a Gen3 lite"),
        "{text}"
    );
    assert_refused_at_identity(&fake);
}

#[test]
fn an_arm_that_reports_no_model_is_known_by_its_actuator_count_alone() {
    // Older firmware may report no model: the count decides, both ways.
    let fake = start_fake(FakeConfig {
        model: msg::model_id::UNSPECIFIED,
        ..FakeConfig::default()
    });
    let mut arm = connect_as(&fake, "gen3_lite").unwrap();
    tick(&mut arm, &MOVE, 0.0).unwrap();
    arm.shutdown().unwrap();
    let fake = start_fake(FakeConfig {
        model: msg::model_id::UNSPECIFIED,
        ..FakeConfig::default()
    });
    let e = connect_as(&fake, "gen3").unwrap_err();
    assert!(
        e.to_string().contains(
            "the robot found is an arm of 6 actuators (model not reported), but the configured \
             robot profile `gen3` is a Gen3 (Kortex model L53, 7 actuators)"
        ),
        "{e}"
    );
    assert_refused_at_identity(&fake);
    // An arm that answers GetProductConfiguration with an error (a function its firmware
    // does not serve) is known by its count too.
    let fake = start_fake(FakeConfig::default());
    fake.inject(
        Fault::ErrorReply {
            code: 1,
            sub_code: 0,
            detail: "unknown function".into(),
        },
        Some(Function::GetProductConfiguration),
    );
    let mut arm = connect_as(&fake, "gen3_lite").unwrap();
    tick(&mut arm, &MOVE, 0.0).unwrap();
    arm.shutdown().unwrap();
    // A model the bridge does not know (a later arm) is too.
    let fake = start_fake(FakeConfig {
        model: 42,
        ..FakeConfig::default()
    });
    let e = connect_as(&fake, "gen3").unwrap_err();
    assert!(
        e.to_string()
            .contains("an arm of 6 actuators (Kortex model 42, unknown to the bridge)"),
        "{e}"
    );
}

#[test]
fn a_robot_with_another_actuator_count_is_refused_and_its_session_closed() {
    let fake = start_fake(FakeConfig {
        actuator_count: 7,
        ..FakeConfig::default()
    });
    let e = KortexArm::connect(&client_cfg(&fake), &admin()).unwrap_err();
    assert!(
        matches!(&e, KortexError::WrongRobot { found, .. } if found.actuators == 7),
        "{e}"
    );
    assert!(
        e.to_string().contains(
            "the robot found is a Gen3 lite (Kortex model L31, 7 actuators), but the configured \
             robot profile `gen3_lite` is a Gen3 lite (Kortex model L31, 6 actuators)"
        ),
        "{e}"
    );
    assert_refused_at_identity(&fake);
}

/// The client drives a fake Gen3: seven joints in every message, the Gen3's own speed limits.
#[test]
fn the_client_drives_a_fake_gen3_with_seven_joints() {
    let gen3 = RobotProfile::by_name("gen3").unwrap();
    let fake = start_fake(FakeConfig::for_robot(gen3));
    let mut arm = connect_as(&fake, "gen3").unwrap();
    assert_eq!(requested(&fake), START_UP);
    assert_eq!(arm.speed_limits_rad_s().len(), 7);
    for (got, want) in arm
        .speed_limits_rad_s()
        .iter()
        .zip(gen3.urdf_velocity_rad_s())
    {
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
    }
    let home = gen3.named_pose("home").unwrap();
    let first = arm.advance(DT).unwrap();
    for j in 0..7 {
        assert!((first.q_rad[j] - home[j]).abs() < 1e-4, "joint {j}");
    }
    let s = fake.snapshot();
    assert_eq!((s.q_rad.len(), s.command_in_force.len()), (7, 7));
    // Every joint moves, the seventh too.
    let v = [0.1, -0.1, 0.1, -0.1, 0.1, -0.1, 0.2];
    for _ in 0..8 {
        tick(&mut arm, &v, 0.0).unwrap();
    }
    wait_until(&fake, "the seven-joint command arrived", |s| {
        s.stats.joint_speed_commands >= 8
    });
    let log = fake.joint_speed_log();
    let last = log.last().unwrap();
    assert_eq!(last.len(), 7);
    for j in 0..7 {
        assert!((last[j] - v[j]).abs() < 1e-5, "joint {j}: {last:?}");
    }
    let r = arm.advance(DT).unwrap();
    assert!(r.q_rad[6] - first.q_rad[6] > 0.01, "{r:?}");
    assert_eq!(r.q_rad[7], 0.0, "nothing past the seventh joint");
    arm.shutdown().unwrap();
    assert!(!fake.snapshot().commanded_to_move());
}

/// The Gen3's joint 3 is at a half turn at home (180°): the arm reports it in `[0, 360)`, so
/// turning it on past 180° reads 181° on the wire. The client's reading stays continuous (past
/// π, not a jump to -π) for the profile's continuous joints.
#[test]
fn a_gen3_joint_turning_past_a_half_turn_reads_without_a_jump() {
    let gen3 = RobotProfile::by_name("gen3").unwrap();
    assert!(gen3.continuous_joints()[2]);
    let fake = start_fake(FakeConfig::for_robot(gen3));
    let mut arm = connect_as(&fake, "gen3").unwrap();
    let v = [0.0, 0.0, 0.4, 0.0, 0.0, 0.0, 0.0];
    let mut last = arm.advance(DT).unwrap().q_rad[2];
    let t0 = Instant::now();
    while last < std::f64::consts::PI + 0.05 {
        arm.command(&v, 0.0).unwrap();
        std::thread::sleep(PERIOD);
        let q = arm.advance(DT).unwrap().q_rad[2];
        assert!(q >= last - 1e-9 && q - last < 0.1, "{last} -> {q}");
        last = q;
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "joint 3 stays at {last}"
        );
    }
    // The fake arm agrees (it tracks the joint past the half turn too).
    arm.command(&[0.0; 7], 0.0).unwrap();
    let s = fake.snapshot();
    assert!(s.q_rad[2] > std::f64::consts::PI, "{s:?}");
    arm.shutdown().unwrap();
}

#[test]
fn a_refused_connection_is_a_clear_error() {
    let port = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let cfg = KortexConfig {
        address: "127.0.0.1".into(),
        port,
        ..KortexConfig::default()
    };
    let e = KortexArm::connect(&cfg, &admin()).unwrap_err();
    let text = e.to_string();
    assert!(
        text.starts_with(&format!(
            "cannot connect to the Kortex robot at 127.0.0.1:{port}"
        )),
        "{text}"
    );
    assert!(text.to_lowercase().contains("refused"), "{text}");
}

#[test]
fn an_error_frame_is_reported_by_name_and_stops_the_arm() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    fake.inject(
        Fault::ErrorReply {
            code: 3,
            sub_code: 22,
            detail: "joint 2 over current".into(),
        },
        Some(Function::SendJointSpeedsCommand),
    );
    let e = tick_until_error(&mut arm, 10);
    let text = e.to_string();
    assert!(
        text.starts_with("the robot refused Base.SendJointSpeedsCommand (message ")
            && text.ends_with(
                "device error (code 3), robot in fault (sub-code 22): joint 2 over current"
            ),
        "{text}"
    );
    assert_stopped_by_the_client(&fake);
    assert!(!arm.is_open());
}

#[test]
fn a_reply_for_an_unknown_message_id_stops_the_arm() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    fake.inject(
        Fault::WrongMessageId,
        Some(Function::SendJointSpeedsCommand),
    );
    let e = tick_until_error(&mut arm, 10);
    assert!(matches!(e, KortexError::UnknownReply { .. }), "{e}");
    assert!(
        e.to_string()
            .contains("(Base.SendJointSpeedsCommand) that no request is waiting for"),
        "{e}"
    );
    assert_stopped_by_the_client(&fake);
}

#[test]
fn a_damaged_magic_is_resynchronised_and_the_lost_reply_ends_in_a_stop() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect_short_reply_timeout(&fake);
    moving(&fake, &mut arm);
    fake.inject(Fault::CorruptMagic, Some(Function::SendJointSpeedsCommand));
    let e = tick_until_error(&mut arm, 400);
    let text = e.to_string();
    assert!(
        matches!(
            e,
            KortexError::ReplyTimeout {
                function: "Base.SendJointSpeedsCommand",
                ..
            }
        ),
        "{text}"
    );
    assert!(
        text.contains(&format!("within {SHORT_REPLY_TIMEOUT_MS} ms"))
            && text.contains("skipped to resynchronise"),
        "{text}"
    );
    // The stream was resynchronised: the frames after the damaged one were decoded (the
    // loop went on until the timeout), and the Stop and CloseSession got their replies.
    assert!(arm.stats().skipped_bytes > 0);
    assert_stopped_by_the_client(&fake);
}

#[test]
fn garbage_between_frames_is_skipped_and_the_loop_goes_on() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    let garbage = b"\x00\x07\x78garbage\x07".to_vec();
    fake.inject(
        Fault::GarbageBefore(garbage.clone()),
        Some(Function::RefreshFeedback),
    );
    for _ in 0..10 {
        tick(&mut arm, &MOVE, 0.0).unwrap();
    }
    assert_eq!(arm.stats().skipped_bytes, garbage.len() as u64);
    assert!(arm.is_open());
    assert!(fake.snapshot().commanded_to_move());
    arm.shutdown().unwrap();
}

#[test]
fn a_dropped_reply_ends_in_a_reply_timeout_and_a_stop() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect_short_reply_timeout(&fake);
    moving(&fake, &mut arm);
    fake.inject(Fault::DropReply, Some(Function::RefreshFeedback));
    let e = tick_until_error(&mut arm, 400);
    assert_eq!(
        e.to_string().split(" (message").next().unwrap(),
        "no reply to BaseCyclic.RefreshFeedback"
    );
    assert!(arm.stats().stale_readings >= 1);
    assert_stopped_by_the_client(&fake);
}

#[test]
fn a_truncated_reply_is_reported_and_the_connection_timeout_stops_the_arm() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    let before = connection_timeouts(&fake);
    fake.inject(
        Fault::TruncateReply(20),
        Some(Function::SendJointSpeedsCommand),
    );
    let e = tick_until_error(&mut arm, 10);
    assert!(matches!(e, KortexError::Truncated { have: 20, .. }), "{e}");
    assert!(e.to_string().contains("truncated frame: 20 of"), "{e}");
    // The connection is gone: no Stop could be sent; the robot's watchdog stops the arm.
    assert_stopped_by_the_timeout(&fake, before);
    assert_eq!(fake.snapshot().stats.stops, 0);
}

#[test]
fn a_reset_connection_is_reported_and_the_connection_timeout_stops_the_arm() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    let before = connection_timeouts(&fake);
    fake.inject(
        Fault::CloseConnection,
        Some(Function::SendJointSpeedsCommand),
    );
    let e = tick_until_error(&mut arm, 10);
    assert!(
        matches!(e, KortexError::Closed { .. } | KortexError::Io { .. }),
        "{e}"
    );
    assert!(e.to_string().contains("127.0.0.1"), "{e}");
    assert_stopped_by_the_timeout(&fake, before);
    assert_eq!(fake.snapshot().stats.stops, 0);
}

#[test]
fn a_frozen_loop_lets_the_connection_time_out_and_the_robot_stops_the_arm() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    // The control loop freezes: no frame goes out, and no thread of the client keeps the
    // session alive.
    let before = connection_timeouts(&fake);
    assert_stopped_by_the_timeout(&fake, before);
    assert_eq!(fake.snapshot().stats.stops, 0);
    // The session itself lives on (session timeout 60 s): the loop resumes.
    moving(&fake, &mut arm);
    // The frames re-armed the watchdog: a second freeze stops the arm again.
    let before = connection_timeouts(&fake);
    assert_stopped_by_the_timeout(&fake, before);
    assert_eq!(fake.snapshot().stats.stops, 0);
    assert!(fake.snapshot().session_open);
    arm.shutdown().unwrap();
}

/// A frozen client replaced by a new one (a restarted bridge) before its connection timeout
/// fired: the robot still stops the motion the frozen session started, until the new session
/// commands; then the new session drives the arm.
#[test]
fn a_new_session_does_not_cancel_the_frozen_sessions_connection_timeout() {
    let fake = start_fake(FakeConfig::default());
    let mut frozen = connect(&fake);
    moving(&fake, &mut frozen);
    let before = connection_timeouts(&fake);
    // The new client opens its session at once, and sends no motion yet.
    let mut next = connect(&fake);
    assert_eq!(fake.snapshot().stats.sessions_opened, 2);
    assert_stopped_by_the_timeout(&fake, before);
    assert_eq!(fake.snapshot().stats.stops, 0, "nobody sent a Stop");
    // The new session's commands are in force from its first tick on.
    moving(&fake, &mut next);
    next.shutdown().unwrap();
    drop(frozen);
}

#[test]
fn dropping_the_client_stops_the_arm_and_closes_the_session() {
    let fake = start_fake(FakeConfig::default());
    let mut arm = connect(&fake);
    moving(&fake, &mut arm);
    drop(arm);
    assert_stopped_by_the_client(&fake);
}

fn safe_command(tick: u64, v: &[f64]) -> SafeCommand {
    let mut q = [0.0; MAX_JOINTS];
    q[..v.len()].copy_from_slice(v);
    SafeCommand {
        tick,
        mapper_id: 1,
        n_joints: 6,
        qdot_rad_s: q,
        clearance_m: f64::INFINITY,
        closest_pair: [0xFFFF; 2],
        ..SafeCommand::zeroed()
    }
}

#[test]
fn the_bridge_core_drives_the_robot_and_a_miss_ends_in_a_stop() {
    let fake = start_fake(FakeConfig::default());
    let arm = connect(&fake);
    let mut core = BridgeCore::new(arm, DT, gen3_lite::DEFAULT_ACCELERATION_RAD_S2.to_vec());
    for _ in 0..8 {
        let s = core.begin_tick(0).unwrap();
        assert_eq!(s.flags & state_flags::MOCK, 0, "a real robot");
        core.finish_tick(Some(&safe_command(s.tick, &[0.3, 0.0, 0.0, 0.0, 0.0, 0.0])))
            .unwrap();
        std::thread::sleep(PERIOD);
    }
    // Commands stop coming: a controlled stop (0.3 rad/s at 1 rad/s² takes 12 ticks), then
    // a Stop.
    let mut ticks = 0;
    while fake.snapshot().stats.stops == 0 {
        let s = core.begin_tick(0).unwrap();
        if ticks > 0 {
            assert!(s.flags & state_flags::STOPPING != 0);
            assert_eq!(s.applied_tick, NO_TICK);
        }
        core.finish_tick(None).unwrap();
        std::thread::sleep(PERIOD);
        ticks += 1;
        assert!(ticks < 40, "no Stop after {ticks} missed ticks");
    }
    let log = fake.joint_speed_log();
    let decel: Vec<f64> = log[8..].iter().map(|c| c[0]).collect();
    assert!(decel.len() >= 10, "{decel:?}");
    for w in decel.windows(2) {
        assert!(w[1] < w[0] && w[0] - w[1] <= 1.0 * DT + 1e-6, "{decel:?}");
    }
    let (last, result) = core.shutdown(0);
    result.unwrap();
    assert!(last.flags & state_flags::SHUTDOWN != 0);
    let s = fake.snapshot();
    assert!(!s.commanded_to_move());
    assert_eq!(s.stats.sessions_closed, 1);
}

/// What Kinova's own tools do beside a running bridge: a second, observing session on another
/// connection reads the arm (GetServoingMode, GetArmState, GetActuatorCount,
/// GetMeasuredJointAngles, RefreshFeedback, GetProductConfiguration, the hard limits) while
/// the bridge drives it; the observer's silence past its connection timeout and its
/// CloseSession leave the bridge's motion alone; a call the fake does not serve is an error
/// frame naming it.
#[test]
fn an_observing_session_reads_the_arm_beside_the_bridge_without_stopping_it() {
    let fake = start_fake(FakeConfig::default());
    // The bridge's own connection timeout is long here: any timeout the fake counts below is
    // the observer's (the machine may starve the test thread for 200 ms).
    let cfg = KortexConfig {
        connection_timeout_ms: 10_000,
        ..client_cfg(&fake)
    };
    let mut arm = KortexArm::connect(&cfg, &admin()).unwrap();
    moving(&fake, &mut arm);

    let (mut stream, mut dec, session) = raw_session(&fake, 50);
    assert_ne!(session, arm.session_id());
    assert_eq!(fake.snapshot().open_sessions, 2);
    let mut id = 1;
    let mut call = |function: Function| {
        id += 1;
        let reply = raw_call(&mut stream, &mut dec, session, id, function, Vec::new());
        assert_eq!(reply.error(), None, "{}", function.name());
        reply
    };
    let mode: msg::ServoingModeInformation =
        msg::ServoingModeInformation::decode(call(Function::GetServoingMode).payload.as_slice())
            .unwrap();
    assert_eq!(mode.servoing_mode, msg::servoing_mode::SINGLE_LEVEL);
    let state =
        msg::ArmStateInformation::decode(call(Function::GetArmState).payload.as_slice()).unwrap();
    assert_eq!(state.active_state, msg::arm_state::SERVOING_READY);
    let count =
        msg::ActuatorInformation::decode(call(Function::GetActuatorCount).payload.as_slice())
            .unwrap();
    assert_eq!(count.count, 6);
    let q = msg::JointAngles::decode(call(Function::GetMeasuredJointAngles).payload.as_slice())
        .unwrap();
    assert_eq!(q.joint_angles.len(), 6);
    let fb = msg::Feedback::decode(call(Function::RefreshFeedback).payload.as_slice()).unwrap();
    assert_eq!(fb.actuators.len(), 6);
    call(Function::GetProductConfiguration);
    call(Function::GetKinematicHardLimits);
    // A call the fake does not serve (Base.GetMeasuredCartesianPose, 0x20073): named.
    id += 1;
    let reply = raw_call_uid(&mut stream, &mut dec, session, id, 0x2_0073, Vec::new());
    let e = reply.error().expect("an unserved call is an error");
    assert_eq!(e.code, 1);
    assert!(
        e.detail.contains("0x20073") && e.detail.contains("not served"),
        "{e:?}"
    );

    // The observer goes silent past its 50 ms connection timeout while the bridge ticks: the
    // arm moves on, and the bridge's session works.
    let timeouts = connection_timeouts(&fake);
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(300) {
        tick(&mut arm, &MOVE, 0.0).unwrap();
    }
    let s = fake.snapshot();
    assert_eq!(s.stats.connection_timeouts, timeouts, "{s:?}");
    assert!(s.commanded_to_move(), "{s:?}");
    // Its CloseSession leaves the arm moving too.
    id += 1;
    let reply = raw_call(
        &mut stream,
        &mut dec,
        session,
        id,
        Function::CloseSession,
        Vec::new(),
    );
    assert_eq!(reply.error(), None);
    let s = fake.snapshot();
    assert!(s.commanded_to_move() && s.open_sessions == 1, "{s:?}");
    tick(&mut arm, &MOVE, 0.0).unwrap();
    arm.shutdown().unwrap();
    let s = fake.snapshot();
    assert!(!s.commanded_to_move() && !s.session_open, "{s:?}");
}
