//! Fixtures shared by the safety filter's tests: a mapper command and a robot state for any
//! number of joints, stamped around [`NOW`].
#![allow(dead_code)]

use ipc_types::{MAX_JOINTS, MapperCommand, NO_TICK, RobotState, SafeCommand, safe_flags};
use kinematics::collision::PairId;

/// The filter's time in the tests (ns).
pub const NOW: u64 = 1_000_000_000;

/// Mapper 1's command for `tick`: joint velocities `qdot` (one per joint, the command's
/// `n_joints`) and `gripper_rate`, mapped 0.5 ms before [`NOW`] from the state of 1 ms before
/// and a joystick sample of 10 ms before.
pub fn command(tick: u64, qdot: &[f64], gripper_rate: f64) -> MapperCommand {
    let mut q = [0.0; MAX_JOINTS];
    q[..qdot.len()].copy_from_slice(qdot);
    MapperCommand {
        tick,
        t_ns: NOW - 500_000,
        state_t_ns: NOW - 1_000_000,
        state_rx_ns: 0,
        joystick_t_ns: NOW - 10_000_000,
        joystick_rx_ns: 0,
        joystick_seq: 1,
        compute_ns: 100,
        mapper_id: 1,
        n_joints: qdot.len() as u32,
        flags: 0,
        buttons: 0,
        action: [0.0; 2],
        qdot_rad_s: q,
        gripper_rate,
    }
}

/// The state at `tick` (1 ms before [`NOW`]): pose `q` (one entry per joint), moving at
/// `qdot`, which was the command of the tick before (`executed`) or the robot's own
/// measurement.
pub fn moving_state(tick: u64, q: &[f64], qdot: &[f64], executed: bool) -> RobotState {
    let n = q.len();
    let mut s = RobotState::at_rest(tick, NOW - 1_000_000, n as u32);
    s.q_rad[..n].copy_from_slice(q);
    s.qdot_rad_s[..n].copy_from_slice(qdot);
    s.applied_tick = if executed { tick - 1 } else { NO_TICK };
    s
}

/// The state at `tick` (1 ms before [`NOW`]) of an arm of `n_joints` joints at rest, having
/// executed the command of the tick before.
pub fn resting_state(tick: u64, n_joints: u32) -> RobotState {
    let mut s = RobotState::at_rest(tick, NOW - 1_000_000, n_joints);
    s.applied_tick = tick.wrapping_sub(1);
    s
}

/// A whole-arm drill's end: the last command `last` holds the arm at rest by the clearance
/// rule, within 5 mm of the stop distance `stop`, reporting the closest pair `closest` and its
/// distance. `what` and `name` name the drill in the messages; `q` is where the arm rests.
pub fn assert_at_rest_at_the_stop_distance(
    what: &str,
    name: &str,
    q: &[f64],
    last: &SafeCommand,
    closest: (PairId, f64),
    stop: f64,
) {
    eprintln!(
        "{what} {name}: closest {} at {:.4} m, at rest at q {q:.3?}",
        closest.0, closest.1
    );
    assert!(
        last.flags & safe_flags::CLEARANCE_LIMITED != 0,
        "{name}: {:#x}",
        last.flags
    );
    assert!(
        last.qdot_rad_s.iter().all(|v| v.abs() < 1e-3),
        "{name}: {last:?}"
    );
    assert!(
        closest.1 < stop + 0.005,
        "{name}: stopped {} m short",
        closest.1
    );
    assert_eq!(last.closest_pair, closest.0.code(), "{name}");
    assert!((last.clearance_m - closest.1).abs() < 1e-3, "{name}");
}
