//! The hardware side of the graph.
//!
//! * [`Robot`]: the backend trait, fallible ([`RobotError`]) because a real robot can fail.
//! * [`mock::MockArm`]: integrates commanded joint velocities at 40 Hz inside the joint
//!   limits, with a first-order gripper, and injectable command latency and drops.
//! * [`kortex`]: the Kortex client for the Kinova arm of the robot profile
//!   ([`kortex::KortexArm`]) and a fake robot of any profile speaking the same protocol on
//!   loopback ([`kortex::FakeKortex`]).
//! * [`tick::BridgeCore`]: the pure tick logic: publish the state of tick k, execute only the
//!   command for tick k, count a miss and start a controlled stop otherwise.
//! * [`clock`]: the graph's only clock, an absolute-deadline timer, and the real-time settings
//!   (SCHED_FIFO, mlockall) the bridge asks for.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod clock;
pub mod kortex;
pub mod mock;
pub mod tick;

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

/// Why a robot backend failed. The bridge answers every one by stopping the arm (as far as
/// the robot can still be reached) and exiting with the message.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    /// The Kortex client failed.
    #[error(transparent)]
    Kortex(#[from] kortex::KortexError),
}

/// Counters of a backend's link to the robot (all zero for the mock).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Requests sent.
    pub requests: u64,
    /// Replies that arrived after the tick they were due in.
    pub late_replies: u64,
    /// Ticks that reused the previous reading because the newest feedback had not arrived.
    pub stale_readings: u64,
    /// Bytes dropped to resynchronise the stream (wrong magic).
    pub skipped_bytes: u64,
    /// Commands slowed down (one common factor) to the robot's own speed limits.
    pub clamped_commands: u64,
}

/// A robot backend driven once per tick.
pub trait Robot: Send {
    /// Number of arm joints.
    fn n_joints(&self) -> usize;
    /// Lets `dt` seconds of the current command pass (a real robot moves by itself; the
    /// mock integrates) and returns the state at the new tick.
    fn advance(&mut self, dt: f64) -> Result<Reading, RobotError>;
    /// Commands joint velocities (rad/s) and a gripper rate (1/s) that stay in force until
    /// the next command, as on the Gen3 lite.
    fn command(&mut self, qdot_rad_s: &[f64], gripper_rate: f64) -> Result<(), RobotError>;
    /// Stops the arm at once (Kortex `Stop`; the mock zeroes the command).
    fn stop(&mut self) -> Result<(), RobotError>;
    /// Stops the arm and releases the robot (Kortex: Stop, a last feedback, CloseSession);
    /// returns the last reading. Called once at exit; later calls return the same reading.
    fn shutdown(&mut self) -> Result<Reading, RobotError>;
    /// Whether this is a simulation.
    fn is_mock(&self) -> bool;
    /// Counters of the link to the robot.
    fn link_stats(&self) -> LinkStats {
        LinkStats::default()
    }
}
