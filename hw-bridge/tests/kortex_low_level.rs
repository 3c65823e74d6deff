//! Low-level servoing (`mode = "low-level"`) against the fake robot: entry from rest (and the
//! refusal when moving), the first command equal to the measured position, the entry check
//! (the measured position held for `entry_hold_ms` of ticks, the graph's commands held back; a
//! robot that misreads the command stopped), the following-error check, the fake arm's own
//! reaction to a missing cyclic command, and the clean exit back to single-level servoing.
//! Each test runs its own fake robot on free loopback ports.
//!
//! The machine may be loaded (two shared cores): the client waits long for replies and the
//! fake's cyclic timeout is generous where it is not the point.
#![allow(clippy::unwrap_used, missing_docs)]

use std::time::{Duration, Instant};

use hw_bridge::kortex::{
    Credentials, CyclicMisread, FakeConfig, FakeKortex, FakeSnapshot, Function, KortexArm,
    KortexConfig, KortexError, KortexMode,
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

fn misreading_fake(m: CyclicMisread) -> FakeKortex {
    FakeKortex::start(FakeConfig {
        cyclic_timeout: Duration::from_millis(500),
        cyclic_misread: Some(m),
        ..FakeConfig::default()
    })
    .unwrap()
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

/// Ticks with the graph's command `v` through the entry hold: every tick is answered (a
/// Refresh goes out) and carries the held position, whatever `v` asks. Returns after the
/// tick whose feedback ended the hold, with that tick's command sent (it applies), and the
/// number of the graph's commands held back.
fn through_entry_hold(arm: &mut KortexArm, v: &[f64]) -> u64 {
    let held = arm.position_command().unwrap().to_vec();
    assert!(
        arm.entry_hold().unwrap().holding(),
        "connect returns at once"
    );
    let mut held_back = 0;
    loop {
        arm.advance(DT).unwrap();
        let passed = !arm.entry_hold().unwrap().holding();
        arm.command(v, 0.0).unwrap();
        std::thread::sleep(PERIOD);
        if passed {
            return held_back;
        }
        held_back += 1;
        assert_eq!(arm.position_command().unwrap(), held.as_slice());
        assert!(held_back < 10_000, "the entry hold never ends");
    }
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
    // The entry hold, then 300 ticks at 1 kHz: q_cmd += qdot * period (the tick that ended
    // the hold applied its command too).
    through_entry_hold(&mut arm, &MOVE);
    for _ in 0..300 {
        tick(&mut arm, &MOVE).unwrap();
    }
    let q_cmd = arm.position_command().unwrap().to_vec();
    for j in 0..6 {
        let expected = before[j] + MOVE[j] * 0.301;
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

/// The entry check on a robot that reads the command as meant: the bridge holds the measured
/// position for `entry_hold_ms` of ticks (100 at 1 kHz), answering every tick, the graph's
/// commands counted and not applied; then they apply.
#[test]
fn the_entry_hold_holds_the_measured_position_then_the_graphs_commands_apply() {
    let fake = fake();
    let mut arm = connect(&fake).unwrap();
    let held = arm.position_command().unwrap().to_vec();
    let refreshes_before = fake.snapshot().stats.refreshes;
    let held_back = through_entry_hold(&mut arm, &MOVE);
    let hold = arm.entry_hold().unwrap().clone();
    assert!(!hold.holding());
    assert_eq!(hold.hold_ms(), 100);
    // 100 ms of ticks at 1 kHz; more only if a feedback was late at the end.
    assert!(hold.ticks() >= 100, "{hold:?}");
    assert_eq!(hold.ticks(), held_back + 1, "{hold:?}");
    assert_eq!(
        (hold.held_back(), hold.held_back_moving()),
        (held_back, held_back)
    );
    assert!(hold.worst_rad() < 1e-4, "{hold:?}");
    // Every tick of the hold sent a Refresh with the held position.
    let s = fake.snapshot();
    assert!(
        s.stats.refreshes > refreshes_before + held_back,
        "{held_back} ticks held: {s:?}"
    );
    // The tick that ended the hold applied the graph's command: one period of MOVE.
    let q_cmd = arm.position_command().unwrap();
    for j in 0..6 {
        assert!(
            (q_cmd[j] - (held[j] + MOVE[j] * DT)).abs() < 1e-9,
            "joint {j}: {q_cmd:?}"
        );
    }
    for _ in 0..20 {
        tick(&mut arm, &MOVE).unwrap();
    }
    assert!((arm.position_command().unwrap()[5] - (held[5] + MOVE[5] * 0.021)).abs() < 1e-9);
    arm.shutdown().unwrap();
    assert_back_to_single_level(&fake.snapshot());
}

/// A robot that reads the cyclic command differently than the bridge means (here: joint 3
/// 0.02 rad off, less than the following-error bound of 0.05 rad, so only the entry check can
/// see it): during the entry hold the arm leaves the held position; the bridge stops it, goes
/// back to single-level servoing and ends with an error that names the joint, the measured
/// and the held position. None of the graph's commands was applied.
#[test]
fn a_robot_that_misreads_the_command_fails_the_entry_check_and_is_stopped() {
    let fake = misreading_fake(CyclicMisread::Offset {
        joint: 3,
        offset_rad: 0.02,
    });
    let start = fake.snapshot().q_rad;
    let mut ticks = 0;
    // On a slow machine the first command's reply may already show it (connect fails).
    let e = match connect(&fake) {
        Err(e) => e,
        Ok(mut arm) => {
            let e = loop {
                if let Err(e) = tick(&mut arm, &MOVE) {
                    break e;
                }
                ticks += 1;
                assert!(ticks < 100, "the entry check did not fire within the hold");
            };
            assert!(!arm.is_open());
            e
        }
    };
    let text = e.to_string();
    eprintln!("entry check fired after {ticks} ticks: {text}");
    let KortexError::EntryHold {
        joint,
        measured_rad,
        held_rad,
        error_rad,
        tolerance_rad,
        hold_ms,
        ..
    } = e
    else {
        panic!("{e}")
    };
    assert_eq!((joint, tolerance_rad, hold_ms), (3, 0.005, 100), "{text}");
    assert!((held_rad - start[3]).abs() < 1e-4, "{text}");
    assert!(
        error_rad > 0.005 && error_rad <= 0.02 + 1e-4 && measured_rad > held_rad,
        "{text}"
    );
    assert!(
        text.contains("entry check failed: joint 3")
            && text.contains(&format!("measured {measured_rad:.4} rad"))
            && text.contains(&format!("held it at {held_rad:.4} rad"))
            && text.contains("did not follow the held position"),
        "{text}"
    );
    let s = fake.snapshot();
    assert_back_to_single_level(&s);
    assert!(!s.in_fault, "{s:?}");
    // Every Refresh carried the held position: the graph's commands were not applied.
    let (first, last) = (
        s.first_position_command.clone().unwrap(),
        s.last_position_command.clone().unwrap(),
    );
    for j in 0..6 {
        assert!((first[j] - start[j]).abs() < 1e-4, "joint {j}: {s:?}");
        assert!((last[j] - first[j]).abs() < 1e-6, "joint {j}: {s:?}");
    }
    // Low-level, then back to single-level, over TCP.
    let modes = fake
        .request_log()
        .iter()
        .filter(|r| r.function() == Some(Function::SetServoingMode))
        .count();
    assert_eq!(modes, 3, "single-level, low-level, single-level");
}

/// The same with a robot that reads every position as 0°: the first joint that is not at 0 in
/// the start pose (joint 1) leaves first.
#[test]
fn a_robot_that_reads_the_position_as_zero_fails_the_entry_check() {
    let fake = misreading_fake(CyclicMisread::ZeroPosition);
    let mut ticks = 0;
    let e = match connect(&fake) {
        Err(e) => e,
        Ok(mut arm) => loop {
            if let Err(e) = tick(&mut arm, &[0.0; 6]) {
                break e;
            }
            ticks += 1;
            assert!(ticks < 100, "the entry check did not fire within the hold");
        },
    };
    assert!(matches!(e, KortexError::EntryHold { joint: 1, .. }), "{e}");
    assert_back_to_single_level(&fake.snapshot());
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
    through_entry_hold(&mut arm, &MOVE);
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
    through_entry_hold(&mut arm, &MOVE);
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

/// Low-level servoing of a fake Gen3: seven actuators in every position command and feedback,
/// the seventh moved too; joint 3, at a half turn at home (180°, where the wire's `[0, 360)`
/// angle wraps), turns past it without a jump in the reading or the following-error check
/// firing.
#[test]
fn low_level_drives_a_fake_gen3_with_seven_actuators() {
    let gen3 = kinematics::RobotProfile::by_name("gen3").unwrap();
    let fake = FakeKortex::start(FakeConfig {
        cyclic_timeout: Duration::from_millis(500),
        ..FakeConfig::for_robot(gen3)
    })
    .unwrap();
    let before = fake.snapshot().q_rad;
    assert_eq!(before.len(), 7);
    let mut arm = KortexArm::connect_to(
        gen3,
        &low_level_cfg(&fake),
        &Credentials::new("admin", "admin"),
    )
    .unwrap();
    assert!(arm.is_low_level());
    assert_eq!(arm.position_command().unwrap().len(), 7);
    let v = [0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.2];
    through_entry_hold(&mut arm, &v);
    for _ in 0..200 {
        tick(&mut arm, &v).unwrap();
    }
    let q_cmd = arm.position_command().unwrap().to_vec();
    let s = fake.snapshot();
    let first = s.first_position_command.clone().unwrap();
    assert_eq!((first.len(), s.q_rad.len()), (7, 7));
    for j in [2, 6] {
        assert!(q_cmd[j] - before[j] > 0.03, "joint {j}: {q_cmd:?}");
        assert!((s.q_rad[j] - q_cmd[j]).abs() < 1e-3, "joint {j}: {s:?}");
    }
    // Past the half turn, continuous: no jump of 2π.
    let r = arm.advance(DT).unwrap();
    assert!(r.q_rad[2] > std::f64::consts::PI, "{:?}", r.q_rad);
    assert!((r.q_rad[2] - q_cmd[2]).abs() < 1e-3, "{:?}", r.q_rad);
    arm.command(&[0.0; 7], 0.0).unwrap();
    arm.shutdown().unwrap();
    let s = fake.snapshot();
    assert_back_to_single_level(&s);
    assert!(!s.in_fault && s.stats.cyclic_timeouts == 0, "{s:?}");
}
