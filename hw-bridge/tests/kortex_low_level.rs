//! Low-level servoing (`mode = "low-level"`) against the fake robot: entry from rest (and the
//! refusal when moving), the first command equal to the measured position, the following-error
//! check, the fake arm's own reaction to a missing cyclic command, and the clean exit back to
//! single-level servoing. Each test runs its own fake robot on free loopback ports.
//!
//! The machine may be loaded (two shared cores): the client waits long for replies and the
//! fake's cyclic timeout is generous where it is not the point.
#![allow(clippy::unwrap_used, missing_docs)]

use std::time::{Duration, Instant};

use hw_bridge::kortex::{
    Credentials, FakeConfig, FakeKortex, FakeSnapshot, Function, KortexArm, KortexConfig,
    KortexError, KortexMode,
};
use hw_bridge::{Robot, RobotError};

/// 1 kHz, the low-level rate.
const DT: f64 = 0.001;
const PERIOD: Duration = Duration::from_millis(1);
const MOVE: [f64; 6] = [0.2, -0.1, 0.0, 0.0, 0.0, 0.3];

fn fake_with_cyclic_timeout(t: Duration) -> FakeKortex {
    FakeKortex::start(FakeConfig {
        cyclic_timeout: t,
        ..FakeConfig::default()
    })
    .unwrap()
}

fn fake() -> FakeKortex {
    fake_with_cyclic_timeout(Duration::from_millis(500))
}

fn low_level_cfg(fake: &FakeKortex) -> KortexConfig {
    KortexConfig {
        address: "127.0.0.1".into(),
        port: fake.addr().port(),
        cyclic_port: fake.cyclic_addr().port(),
        reply_timeout_ms: 2_000,
        mode: KortexMode::LowLevel,
        ..KortexConfig::default()
    }
}

fn connect(fake: &FakeKortex) -> Result<KortexArm, KortexError> {
    KortexArm::connect(&low_level_cfg(fake), &Credentials::new("admin", "admin"))
}

fn kortex(e: RobotError) -> KortexError {
    match e {
        RobotError::Kortex(k) => k,
    }
}

fn tick(arm: &mut KortexArm, v: &[f64]) -> Result<(), KortexError> {
    arm.advance(DT).map_err(kortex)?;
    arm.command(v, 0.0).map_err(kortex)?;
    std::thread::sleep(PERIOD);
    Ok(())
}

/// After the session: back in single-level servoing, both sessions closed, the arm still.
fn assert_back_to_single_level(s: &FakeSnapshot) {
    assert!(s.single_level_servoing, "{s:?}");
    assert!(!s.low_level_servoing, "{s:?}");
    assert!(!s.cyclic_session_open && !s.session_open, "{s:?}");
    assert!(!s.commanded_to_move(), "{s:?}");
}

#[test]
fn entry_from_rest_starts_at_the_measured_position_moves_and_exits_to_single_level() {
    let fake = fake();
    let before = fake.snapshot().q_rad;
    let mut arm = connect(&fake).unwrap();
    assert!(arm.is_low_level());
    let s = fake.snapshot();
    assert!(s.low_level_servoing && s.cyclic_session_open, "{s:?}");
    let first = s.first_position_command.unwrap();
    for j in 0..6 {
        assert!(
            (first[j] - before[j]).abs() < 1e-4,
            "joint {j}: first command {} rad, measured {} rad",
            first[j],
            before[j]
        );
    }
    // 300 ticks at 1 kHz: q_cmd += qdot * period.
    for _ in 0..300 {
        tick(&mut arm, &MOVE).unwrap();
    }
    let q_cmd = arm.position_command().unwrap().to_vec();
    for j in 0..6 {
        let expected = before[j] + MOVE[j] * 0.3;
        assert!(
            (q_cmd[j] - expected).abs() < 1e-6,
            "joint {j}: {} vs {expected}",
            q_cmd[j]
        );
    }
    let s = fake.snapshot();
    assert!(s.stats.refreshes >= 300, "{s:?}");
    assert!((s.q_rad[0] - q_cmd[0]).abs() < 1e-4, "{s:?}");
    assert_eq!(
        s.stats.joint_speed_commands, 0,
        "no joint speeds in low level"
    );
    arm.shutdown().unwrap();
    let s = fake.snapshot();
    assert_back_to_single_level(&s);
    assert!(!s.in_fault && s.stats.cyclic_timeouts == 0, "{s:?}");
    assert_eq!(s.stats.cyclic_sessions_closed, 1);
    // The mode went low-level then back to single-level over TCP.
    let modes = fake
        .request_log()
        .iter()
        .filter(|r| r.function() == Some(Function::SetServoingMode))
        .count();
    assert_eq!(modes, 3, "single-level, low-level, single-level");
}

#[test]
fn entry_is_refused_while_the_arm_moves() {
    let fake = fake();
    fake.set_joint_speeds(&[0.0, 0.0, 0.3, 0.0, 0.0, 0.0]);
    std::thread::sleep(Duration::from_millis(20));
    let e = connect(&fake).unwrap_err();
    assert!(matches!(e, KortexError::NotAtRest { joint: 2, .. }), "{e}");
    assert!(e.to_string().contains("not at rest"), "{e}");
    let s = fake.snapshot();
    assert!(s.first_position_command.is_none(), "{s:?}");
    assert!(!s.low_level_servoing && !s.session_open, "{s:?}");
    assert!(
        !s.commanded_to_move(),
        "the client's Stop stopped the arm: {s:?}"
    );
}

#[test]
fn a_following_error_stops_the_arm_and_goes_back_to_single_level() {
    let fake = fake();
    let mut arm = connect(&fake).unwrap();
    for _ in 0..50 {
        tick(&mut arm, &MOVE).unwrap();
    }
    fake.block_arm(true);
    let t0 = Instant::now();
    let e = loop {
        if let Err(e) = tick(&mut arm, &MOVE) {
            break e;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "no following error");
    };
    let KortexError::FollowingError {
        joint, error_rad, ..
    } = e
    else {
        panic!("{e}")
    };
    // Joint 5 moves fastest.
    assert_eq!(joint, 5, "{e}");
    assert!(error_rad > 0.05, "{e}");
    assert!(e.to_string().contains("following_error_rad"), "{e}");
    assert!(!arm.is_open());
    assert_back_to_single_level(&fake.snapshot());
}

#[test]
fn a_missing_cyclic_command_faults_the_fake_arm_and_the_bridge_sees_it() {
    let fake = fake_with_cyclic_timeout(Duration::from_millis(100));
    let mut arm = connect(&fake).unwrap();
    for _ in 0..50 {
        tick(&mut arm, &MOVE).unwrap();
    }
    // The control loop stalls.
    std::thread::sleep(Duration::from_millis(180));
    let s = fake.snapshot();
    assert!(s.in_fault, "{s:?}");
    assert_eq!(s.stats.cyclic_timeouts, 1, "{s:?}");
    let q = s.q_rad;
    std::thread::sleep(Duration::from_millis(30));
    assert_eq!(fake.snapshot().q_rad, q, "the arm stopped where it was");
    // The next ticks: the robot refuses the Refresh (in fault); the bridge stops.
    let t0 = Instant::now();
    let e = loop {
        if let Err(e) = tick(&mut arm, &MOVE) {
            break e;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "no error");
    };
    assert!(
        matches!(&e, KortexError::Robot { function, fault, .. }
            if *function == "BaseCyclic.Refresh" && fault.sub_code == 22)
            || matches!(e, KortexError::ArmInFault { .. }),
        "{e}"
    );
    assert_back_to_single_level(&fake.snapshot());
}

#[test]
fn stop_holds_the_commanded_position() {
    let fake = fake();
    let mut arm = connect(&fake).unwrap();
    for _ in 0..30 {
        tick(&mut arm, &MOVE).unwrap();
    }
    let held = arm.position_command().unwrap().to_vec();
    for _ in 0..30 {
        arm.advance(DT).unwrap();
        arm.stop().unwrap();
        std::thread::sleep(PERIOD);
    }
    assert_eq!(arm.position_command().unwrap(), held.as_slice());
    arm.shutdown().unwrap();
    assert_back_to_single_level(&fake.snapshot());
}
