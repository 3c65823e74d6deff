//! The hardware side of the graph.
//!
//! * [`Robot`]: the backend trait (the mock Gen3 lite now, the Kortex client later).
//! * [`mock::MockArm`]: integrates commanded joint velocities at 40 Hz inside the joint
//!   limits, with a first-order gripper, and injectable command latency and drops.
//! * [`core::BridgeCore`]: the pure tick logic: publish the state of tick k, execute only the
//!   command for tick k, count a miss and start a controlled stop otherwise.
//! * [`clock`]: the graph's only clock, an absolute-deadline timer, and the real-time settings
//!   (SCHED_FIFO, mlockall) the bridge asks for.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod clock;
pub mod core;
pub mod mock;

/// What a robot reports at the start of a tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Joint angles (rad); entries past the joint count are 0.
    pub q_rad: [f64; ipc_types::MAX_JOINTS],
    /// Joint velocities (rad/s).
    pub qdot_rad_s: [f64; ipc_types::MAX_JOINTS],
    /// Gripper state `c` in `[0, 1]`.
    pub gripper: f64,
    /// A joint is at a position limit.
    pub at_limit: bool,
}

/// A robot backend driven once per tick.
pub trait Robot: Send {
    /// Number of arm joints.
    fn n_joints(&self) -> usize;
    /// Lets `dt` seconds of the current command pass (a real robot moves by itself; the
    /// mock integrates) and returns the state at the new tick.
    fn advance(&mut self, dt: f64) -> Reading;
    /// Commands joint velocities (rad/s) and a gripper rate (1/s) that stay in force until
    /// the next command, as on the Gen3 lite.
    fn command(&mut self, qdot_rad_s: &[f64], gripper_rate: f64);
    /// Stops the arm at once (Kortex `Stop`; the mock zeroes the command).
    fn stop(&mut self);
    /// Whether this is a simulation.
    fn is_mock(&self) -> bool;
}
