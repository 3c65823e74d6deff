//! The bridge's tick logic, free of I/O: the process loop calls [`BridgeCore::begin_tick`] on
//! the clock's deadline, publishes the state, waits for the command and hands whatever arrived
//! to [`BridgeCore::finish_tick`].
//!
//! Invariant: a command is executed only at the tick it names. A missing, late, wrong-tick,
//! mis-shaped or non-finite command is never executed; it is counted as a miss and answered
//! with a controlled stop (deceleration within the acceleration limits, keeping the direction
//! of motion, then zero).
//!
//! A robot error ([`RobotError`]) is passed up to the process loop, which ends the run with
//! [`BridgeCore::shutdown`]: the arm is stopped as far as the robot can still be reached (and
//! a Kortex robot stops by itself when its connection inactivity timeout passes).
//!
//! Start from a stop ([`StartGate`]): a bridge that finds the arm moving at its first reading
//! (a restarted bridge whose predecessor died with a motion in force: the robot keeps it until
//! its own connection timeout) executes no command until the arm is at rest; every tick until
//! then sends a stop ([`Robot::stop`]: Kortex `Base.Stop`, the arm braking within its own
//! limits) and publishes a state flagged [`state_flags::STOPPING`] with no applied tick. The
//! safety filter sees every such tick as an interruption (its command was not executed) and
//! demands the operator's input to pass through neutral before it lets motion through again
//! (restart prevention): so the arm moves again only once it has stopped and the input was
//! neutral.

use ipc_types::{MAX_JOINTS, NO_TICK, RobotState, SafeCommand, safe_flags, state_flags};

use crate::{Reading, Robot, RobotError};

/// What happened to a tick's command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The command for this tick was executed.
    Executed,
    /// No usable command: counted, controlled stop.
    Missed(MissReason),
    /// A usable command, not executed: the arm was found moving at start and is not at rest
    /// yet ([`StartGate`]); a stop went out instead. Not a miss.
    StoppingAtStart,
}

/// Why a tick counted as missed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MissReason {
    /// Nothing arrived before the deadline.
    NoCommand,
    /// A command arrived for another tick.
    WrongTick,
    /// The command's joint count is not the robot's.
    BadShape,
    /// The command had a non-finite value.
    NonFinite,
}

/// The velocity after one period of a controlled stop from `v`: every joint decelerates by at
/// most its limit `accel * dt`, all by one common factor so the direction of motion is kept.
/// Reaches exactly zero.
pub fn controlled_stop_step(v: &mut [f64], accel: &[f64], dt: f64) {
    let mut keep: f64 = 0.0;
    for (vj, aj) in v.iter().zip(accel) {
        if vj.abs() > 0.0 {
            keep = keep.max(1.0 - aj * dt / vj.abs());
        }
    }
    let keep = keep.clamp(0.0, 1.0);
    v.iter_mut().for_each(|x| *x *= keep);
}

/// Every measured joint speed at or below this (rad/s, about 0.57°/s) is "at rest" for the
/// [`StartGate`]: the bound low-level mode is entered within
/// ([`crate::kortex::cyclic::REST_SPEED_RAD_S`]).
pub const AT_REST_RAD_S: f64 = crate::kortex::cyclic::REST_SPEED_RAD_S;

/// Whether every speed is finite and at most `rest_rad_s` in size.
pub fn at_rest(qdot_rad_s: &[f64], rest_rad_s: f64) -> bool {
    qdot_rad_s.iter().all(|v| v.abs() <= rest_rad_s)
}

/// Start from a stop: the gate a bridge's commands pass only once the arm has been seen at
/// rest. Fed each tick's measured joint speeds ([`StartGate::observe`]); the first reading
/// decides: at rest, the gate opens at once (the usual start); moving, it stays closed (only
/// stops go out) until a reading at rest. Once open it stays open for the process's life.
/// A non-finite speed is not rest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StartGate {
    /// No reading yet.
    #[default]
    Unknown,
    /// The arm was found moving: only stops until it is at rest.
    Stopping {
        /// Readings seen moving so far.
        ticks: u32,
    },
    /// The arm was seen at rest: commands execute.
    Open,
}

/// What a reading changed at the [`StartGate`], for the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GateChange {
    /// The first reading showed the arm moving: `joint` at `speed_rad_s`, the fastest.
    FoundMoving {
        /// The fastest joint (0-based).
        joint: usize,
        /// Its speed (rad/s; NaN if not finite).
        speed_rad_s: f64,
    },
    /// The arm came to rest after `ticks` readings moving: commands execute from now on.
    CameToRest {
        /// Readings it was seen moving.
        ticks: u32,
    },
}

/// The fastest joint and its speed's size; the first non-finite one (NaN) wins.
fn fastest(qdot_rad_s: &[f64]) -> (usize, f64) {
    let mut best = (0, 0.0);
    for (j, v) in qdot_rad_s.iter().enumerate() {
        if !v.is_finite() {
            return (j, f64::NAN);
        }
        if v.abs() > best.1 {
            best = (j, v.abs());
        }
    }
    best
}

impl StartGate {
    /// Takes one tick's measured joint speeds; returns what changed, if anything.
    pub fn observe(&mut self, qdot_rad_s: &[f64], rest_rad_s: f64) -> Option<GateChange> {
        let rest = at_rest(qdot_rad_s, rest_rad_s);
        match *self {
            Self::Open => None,
            Self::Unknown if rest => {
                *self = Self::Open;
                None
            }
            Self::Unknown => {
                *self = Self::Stopping { ticks: 1 };
                let (joint, speed_rad_s) = fastest(qdot_rad_s);
                Some(GateChange::FoundMoving { joint, speed_rad_s })
            }
            Self::Stopping { ticks } if rest => {
                *self = Self::Open;
                Some(GateChange::CameToRest { ticks })
            }
            Self::Stopping { ticks } => {
                *self = Self::Stopping {
                    ticks: ticks.saturating_add(1),
                };
                None
            }
        }
    }

    /// Whether commands may execute.
    pub fn is_open(&self) -> bool {
        *self == Self::Open
    }

    /// Whether the arm was found moving and is not at rest yet (only stops go out).
    pub fn is_stopping(&self) -> bool {
        matches!(self, Self::Stopping { .. })
    }
}

/// The reading of a robot that never gave one (all zero).
const FALLBACK_READING: Reading = Reading {
    q_rad: [0.0; MAX_JOINTS],
    qdot_rad_s: [0.0; MAX_JOINTS],
    gripper: 0.0,
    at_limit: false,
};

/// The bridge's state between ticks.
#[derive(Debug)]
pub struct BridgeCore<R: Robot> {
    robot: R,
    dt: f64,
    accel: Vec<f64>,
    tick: u64,
    missed: u64,
    /// `missed` as the last published state reported it: a state after a miss carries
    /// [`state_flags::MISSED`].
    missed_reported: u64,
    applied_tick: u64,
    in_force: [f64; MAX_JOINTS],
    stopping: bool,
    safety_stop: bool,
    travel: f64,
    last_q: Option<[f64; MAX_JOINTS]>,
    last_reading: Option<Reading>,
    gate: StartGate,
    gate_change: Option<GateChange>,
}

impl<R: Robot> BridgeCore<R> {
    /// A bridge for `robot` ticking every `period_s` seconds, stopping within `accel` (rad/s²
    /// per joint) on a miss.
    pub fn new(robot: R, period_s: f64, accel: Vec<f64>) -> Self {
        Self {
            robot,
            dt: period_s,
            accel,
            tick: NO_TICK,
            missed: 0,
            missed_reported: 0,
            applied_tick: NO_TICK,
            in_force: [0.0; MAX_JOINTS],
            stopping: false,
            safety_stop: false,
            travel: 0.0,
            last_q: None,
            last_reading: None,
            gate: StartGate::Unknown,
            gate_change: None,
        }
    }

    /// The robot.
    pub fn robot(&self) -> &R {
        &self.robot
    }

    /// The robot, mutably (set-up before the first tick).
    pub fn robot_mut(&mut self) -> &mut R {
        &mut self.robot
    }

    /// Makes the next tick `first`: a restarted bridge continues its predecessor's count, so
    /// tick numbers never repeat within a graph.
    pub fn start_at(&mut self, first: u64) {
        self.tick = first.wrapping_sub(1);
    }

    /// The current tick ([`NO_TICK`] before the first).
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Ticks missed so far.
    pub fn missed(&self) -> u64 {
        self.missed
    }

    /// Counts ticks the clock itself skipped (the bridge process was held up for more than a
    /// period) as missed.
    pub fn add_skipped(&mut self, n: u64) {
        self.missed += n;
    }

    /// Joint-space path length travelled so far (rad).
    pub fn joint_travel_rad(&self) -> f64 {
        self.travel
    }

    /// Whether the bridge is executing a controlled stop.
    pub fn stopping(&self) -> bool {
        self.stopping
    }

    /// Where the start-from-a-stop gate is ([`StartGate`]).
    pub fn start_gate(&self) -> StartGate {
        self.gate
    }

    /// What the last [`BridgeCore::begin_tick`] changed at the start gate, once.
    pub fn take_gate_change(&mut self) -> Option<GateChange> {
        self.gate_change.take()
    }

    /// Starts the next tick: lets one period of the command in force pass and returns the
    /// state to publish, stamped `now_ns`.
    pub fn begin_tick(&mut self, now_ns: u64) -> Result<RobotState, RobotError> {
        self.tick = self.tick.wrapping_add(1);
        let r = self.robot.advance(self.dt)?;
        self.last_reading = Some(r);
        let n = self.robot.n_joints();
        self.gate_change = self.gate.observe(&r.qdot_rad_s[..n], AT_REST_RAD_S);
        if self.gate.is_stopping() {
            self.stopping = true;
            self.safety_stop = false;
        }
        Ok(self.state_from(r, now_ns, 0))
    }

    fn state_from(&mut self, r: Reading, now_ns: u64, extra: u32) -> RobotState {
        let n = self.robot.n_joints();
        if let Some(prev) = self.last_q {
            self.travel += (0..n)
                .map(|j| (r.q_rad[j] - prev[j]).powi(2))
                .sum::<f64>()
                .sqrt();
        }
        self.last_q = Some(r.q_rad);
        let mut flags = extra;
        if self.missed != self.missed_reported {
            // A tick missed (no valid command in time, or the clock skipped ticks) since the
            // state before.
            flags |= state_flags::MISSED;
            self.missed_reported = self.missed;
        }
        if self.stopping {
            flags |= state_flags::STOPPING;
        }
        if self.safety_stop {
            flags |= state_flags::SAFETY_STOP;
        }
        if r.at_limit {
            flags |= state_flags::AT_LIMIT;
        }
        if self.robot.is_mock() {
            flags |= state_flags::MOCK;
        }
        RobotState {
            tick: self.tick,
            t_ns: now_ns,
            applied_tick: self.applied_tick,
            missed: self.missed,
            n_joints: n as u32,
            flags,
            q_rad: r.q_rad,
            qdot_rad_s: r.qdot_rad_s,
            gripper: r.gripper,
        }
    }

    /// Ends the current tick with the command that arrived for it, if any. An error means the
    /// robot failed: the caller ends the run with [`BridgeCore::shutdown`].
    pub fn finish_tick(&mut self, cmd: Option<&SafeCommand>) -> Result<Outcome, RobotError> {
        let n = self.robot.n_joints();
        let verdict = match cmd {
            None => Err(MissReason::NoCommand),
            Some(c) if c.tick != self.tick => Err(MissReason::WrongTick),
            Some(c) if c.n_joints as usize != n => Err(MissReason::BadShape),
            Some(c)
                if !(c.qdot_rad_s[..n].iter().all(|v| v.is_finite())
                    && c.gripper_rate.is_finite()) =>
            {
                Err(MissReason::NonFinite)
            }
            Some(c) => Ok(c),
        };
        match verdict {
            Ok(_) if !self.gate.is_open() => {
                // Found moving at start: a stop until the arm is at rest, whatever comes.
                self.in_force = [0.0; MAX_JOINTS];
                self.applied_tick = NO_TICK;
                self.stopping = true;
                self.safety_stop = false;
                self.robot.stop()?;
                Ok(Outcome::StoppingAtStart)
            }
            Ok(c) => {
                self.in_force = [0.0; MAX_JOINTS];
                self.in_force[..n].copy_from_slice(&c.qdot_rad_s[..n]);
                // Marked not executed until the robot took it.
                self.applied_tick = NO_TICK;
                self.robot.command(&self.in_force[..n], c.gripper_rate)?;
                self.applied_tick = self.tick;
                self.stopping = false;
                self.safety_stop = c.flags & safe_flags::STOP != 0;
                Ok(Outcome::Executed)
            }
            Err(reason) => {
                self.missed += 1;
                self.stop_step()?;
                Ok(Outcome::Missed(reason))
            }
        }
    }

    fn stop_step(&mut self) -> Result<(), RobotError> {
        let n = self.robot.n_joints();
        controlled_stop_step(&mut self.in_force[..n], &self.accel, self.dt);
        self.applied_tick = NO_TICK;
        self.stopping = true;
        self.safety_stop = false;
        if self.in_force[..n].iter().all(|v| *v == 0.0) {
            self.robot.stop()
        } else {
            self.robot.command(&self.in_force[..n], 0.0)
        }
    }

    /// Stops the arm at once and releases the robot (shutdown, or after a robot error) and
    /// returns the final state to publish, flagged [`state_flags::SHUTDOWN`], with the
    /// outcome of the robot's own shutdown. If the robot cannot be reached the state is the
    /// last reading it gave.
    pub fn shutdown(&mut self, now_ns: u64) -> (RobotState, Result<(), RobotError>) {
        self.in_force = [0.0; MAX_JOINTS];
        self.stopping = true;
        self.applied_tick = NO_TICK;
        let (r, result) = match self.robot.shutdown() {
            Ok(r) => (r, Ok(())),
            Err(e) => (self.last_reading.unwrap_or(FALLBACK_READING), Err(e)),
        };
        self.last_reading = Some(r);
        (self.state_from(r, now_ns, state_flags::SHUTDOWN), result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mock::{MockArm, MockConfig};
    use crate::{Reading, Robot, RobotError};
    use kinematics::gen3_lite;
    use proptest::prelude::*;

    const DT: f64 = 0.025;

    fn core() -> BridgeCore<MockArm> {
        BridgeCore::new(
            MockArm::new(MockConfig::default()).unwrap(),
            DT,
            gen3_lite::DEFAULT_ACCELERATION_RAD_S2.to_vec(),
        )
    }

    fn cmd(tick: u64, v: f64) -> SafeCommand {
        let mut q = [0.0; MAX_JOINTS];
        q[0] = v;
        q[1] = -v / 2.0;
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

    /// The controlled stop at 40 Hz and at 1 kHz (the period as the only parameter): each
    /// step decelerates every joint by at most `accel * period`, keeps the direction, and the
    /// stop takes the same time at both rates (25 times the ticks at 1 kHz).
    #[test]
    fn the_controlled_stop_follows_the_period_at_40_hz_and_1_khz() {
        let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
        let v0 = [0.4, -0.2, 0.1, 0.0, 1.0, 0.0];
        let mut times = Vec::new();
        for dt in [0.025, 0.001] {
            let mut v = v0;
            let mut ticks = 0u32;
            while v.iter().any(|x| *x != 0.0) {
                let before = v;
                controlled_stop_step(&mut v, &accel, dt);
                for j in 0..6 {
                    assert!((before[j] - v[j]).abs() <= accel[j] * dt + 1e-12);
                    // The direction is kept: every joint by one common factor.
                    assert!(v[j] * v0[j] >= 0.0 && v[j].abs() <= before[j].abs());
                }
                ticks += 1;
                assert!(ticks < 10_000);
            }
            times.push(f64::from(ticks) * dt);
        }
        // Joint 1 (0.2 rad/s at 0.5 rad/s²) sets the stop: 0.4 s at either rate, to a tick.
        assert!((times[0] - 0.4).abs() <= 0.025 + 1e-9, "{times:?}");
        assert!((times[1] - 0.4).abs() <= 0.001 + 1e-9, "{times:?}");
    }

    #[test]
    fn executes_only_the_command_of_its_tick() {
        let mut b = core();
        let s0 = b.begin_tick(10).unwrap();
        assert_eq!((s0.tick, s0.applied_tick), (0, NO_TICK));
        assert_eq!(
            b.finish_tick(Some(&cmd(0, 0.2))).unwrap(),
            Outcome::Executed
        );
        let s1 = b.begin_tick(20).unwrap();
        assert_eq!((s1.tick, s1.applied_tick, s1.missed), (1, 0, 0));
        assert_eq!(s1.flags & state_flags::MISSED, 0);
        assert!((s1.q_rad[0] - 0.2 * DT).abs() < 1e-12);
        // A command for the previous tick is never executed.
        assert_eq!(
            b.finish_tick(Some(&cmd(0, 0.4))).unwrap(),
            Outcome::Missed(MissReason::WrongTick)
        );
        let s2 = b.begin_tick(30).unwrap();
        assert_eq!((s2.applied_tick, s2.missed), (NO_TICK, 1));
        assert!(s2.flags & state_flags::MISSED != 0);
        assert!(s2.flags & state_flags::STOPPING != 0);
        assert!(s2.flags & state_flags::MOCK != 0);
        assert!(s2.qdot_rad_s[0] < 0.2, "decelerating, not executing 0.4");
        // The flag marks the state after a miss only; ticks the clock skipped are misses too.
        assert_eq!(
            b.finish_tick(Some(&cmd(2, 0.0))).unwrap(),
            Outcome::Executed
        );
        let s3 = b.begin_tick(40).unwrap();
        assert_eq!(
            (s3.applied_tick, s3.missed, s3.flags & state_flags::MISSED),
            (2, 1, 0)
        );
        b.add_skipped(2);
        let s4 = b.begin_tick(90).unwrap();
        assert_eq!(s4.missed, 3);
        assert!(s4.flags & state_flags::MISSED != 0);
    }

    #[test]
    fn the_start_gate_opens_at_once_on_an_arm_at_rest() {
        let mut g = StartGate::default();
        assert!(!g.is_open() && !g.is_stopping());
        assert_eq!(
            g.observe(&[0.0, 0.005, -0.01, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            None
        );
        assert!(g.is_open());
        // Open for good: later motion is the graph's own.
        assert_eq!(g.observe(&[0.4; 6], AT_REST_RAD_S), None);
        assert!(g.is_open());
    }

    #[test]
    fn the_start_gate_holds_a_moving_arm_until_it_is_at_rest() {
        let mut g = StartGate::default();
        assert_eq!(
            g.observe(&[0.1, -0.406, 0.0, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            Some(GateChange::FoundMoving {
                joint: 1,
                speed_rad_s: 0.406
            })
        );
        assert!(g.is_stopping() && !g.is_open());
        assert_eq!(
            g.observe(&[0.0, -0.2, 0.0, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            None
        );
        // Just above the bound is still moving; a non-finite speed is never rest.
        assert_eq!(
            g.observe(&[0.0, 0.0101, 0.0, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            None
        );
        assert_eq!(
            g.observe(&[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            None
        );
        assert_eq!(g, StartGate::Stopping { ticks: 4 });
        assert_eq!(
            g.observe(&[0.0, 0.009, 0.0, 0.0, 0.0, 0.0], AT_REST_RAD_S),
            Some(GateChange::CameToRest { ticks: 4 })
        );
        assert!(g.is_open());
        let mut g = StartGate::default();
        let change = g.observe(&[0.0, 1.0, f64::INFINITY, 0.0], AT_REST_RAD_S);
        assert!(
            matches!(change, Some(GateChange::FoundMoving { joint: 2, speed_rad_s }) if speed_rad_s.is_nan()),
            "{change:?}"
        );
    }

    /// A restarted bridge that finds the arm moving (its predecessor's motion still in force on
    /// the robot): it executes no command, only stops, until the arm is at rest, and says so in
    /// its states (STOPPING, no applied tick: safety's restart prevention sees an
    /// interruption); not counted as misses. Then commands execute again.
    #[test]
    fn a_bridge_that_finds_the_arm_moving_stops_it_before_executing_anything() {
        let mut b = core();
        b.start_at(700);
        b.robot_mut()
            .set_command(&[0.4, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0);
        let s = b.begin_tick(0).unwrap();
        assert!((s.qdot_rad_s[0] - 0.4).abs() < 1e-9, "{s:?}");
        assert_eq!(s.applied_tick, NO_TICK);
        assert!(s.flags & state_flags::STOPPING != 0);
        assert!(matches!(
            b.take_gate_change(),
            Some(GateChange::FoundMoving { joint: 0, .. })
        ));
        assert_eq!(b.take_gate_change(), None);
        // Safety's command for this very tick is not executed: a stop goes out.
        assert_eq!(
            b.finish_tick(Some(&cmd(700, 0.39))).unwrap(),
            Outcome::StoppingAtStart
        );
        assert_eq!(b.robot().command_in_force(), &[0.0; 6]);
        assert_eq!(b.missed(), 0);
        // At rest now: the gate opens at the next reading, whose state still shows the stop.
        let s = b.begin_tick(0).unwrap();
        assert_eq!(s.applied_tick, NO_TICK);
        assert!(s.qdot_rad_s.iter().all(|v| *v == 0.0));
        assert_eq!(
            b.take_gate_change(),
            Some(GateChange::CameToRest { ticks: 1 })
        );
        assert_eq!(
            b.finish_tick(Some(&cmd(701, 0.1))).unwrap(),
            Outcome::Executed
        );
        let s = b.begin_tick(0).unwrap();
        assert_eq!(s.applied_tick, 701);
        assert!(s.flags & state_flags::STOPPING == 0);
    }

    /// A miss while the gate holds is still a miss (counted), and the arm gets a stop.
    #[test]
    fn a_miss_during_the_start_stop_is_counted() {
        let mut b = core();
        b.robot_mut()
            .set_command(&[0.0, 0.3, 0.0, 0.0, 0.0, 0.0], 0.0);
        b.begin_tick(0).unwrap();
        assert_eq!(
            b.finish_tick(None).unwrap(),
            Outcome::Missed(MissReason::NoCommand)
        );
        assert_eq!(b.missed(), 1);
        assert_eq!(b.robot().command_in_force(), &[0.0; 6]);
    }

    #[test]
    fn a_restarted_bridge_continues_the_tick_count() {
        let mut b = core();
        b.start_at(500);
        let s = b.begin_tick(0).unwrap();
        assert_eq!((s.tick, s.applied_tick), (500, NO_TICK));
        assert_eq!(
            b.finish_tick(Some(&cmd(500, 0.1))).unwrap(),
            Outcome::Executed
        );
        assert_eq!(b.begin_tick(0).unwrap().applied_tick, 500);
    }

    #[test]
    fn refuses_non_finite_and_misshaped_commands() {
        let mut b = core();
        b.begin_tick(0).unwrap();
        let mut c = cmd(0, 0.1);
        c.qdot_rad_s[3] = f64::NAN;
        assert_eq!(
            b.finish_tick(Some(&c)).unwrap(),
            Outcome::Missed(MissReason::NonFinite)
        );
        b.begin_tick(1).unwrap();
        let mut c = cmd(1, 0.1);
        c.n_joints = 5;
        assert_eq!(
            b.finish_tick(Some(&c)).unwrap(),
            Outcome::Missed(MissReason::BadShape)
        );
        b.begin_tick(2).unwrap();
        assert_eq!(
            b.finish_tick(None).unwrap(),
            Outcome::Missed(MissReason::NoCommand)
        );
        assert_eq!(b.missed(), 3);
    }

    #[test]
    fn a_miss_starts_a_controlled_stop_that_ends_at_zero() {
        let mut b = core();
        b.begin_tick(0).unwrap();
        b.finish_tick(Some(&cmd(0, 0.48))).unwrap();
        let mut last = b.begin_tick(1).unwrap();
        let mut ticks = 0;
        loop {
            b.finish_tick(None).unwrap();
            let s = b.begin_tick(0).unwrap();
            // Deceleration within the limits, direction kept.
            for j in 0..6 {
                let dv = (s.qdot_rad_s[j] - last.qdot_rad_s[j]).abs();
                assert!(dv <= gen3_lite::DEFAULT_ACCELERATION_RAD_S2[j] * DT + 1e-9);
            }
            assert!(s.qdot_rad_s[0] >= 0.0 && s.qdot_rad_s[1] <= 0.0);
            last = s;
            ticks += 1;
            if s.qdot_rad_s.iter().all(|v| *v == 0.0) {
                break;
            }
            assert!(ticks < 100);
        }
        assert!(ticks > 1);
        // Joint 2 (0.24 rad/s at 0.5 rad/s²) limits the stop to about 0.48 s.
        assert!(ticks <= 21, "{ticks}");
    }

    #[test]
    fn a_safety_stop_is_executed_and_reported() {
        let mut b = core();
        b.begin_tick(0).unwrap();
        let mut c = cmd(0, 0.0);
        c.flags = safe_flags::STOP | safe_flags::STALE_JOYSTICK;
        assert_eq!(b.finish_tick(Some(&c)).unwrap(), Outcome::Executed);
        let s = b.begin_tick(1).unwrap();
        assert_eq!(s.applied_tick, 0);
        assert!(s.flags & state_flags::SAFETY_STOP != 0);
        assert!(s.flags & state_flags::STOPPING == 0);
        b.finish_tick(Some(&cmd(1, 0.1))).unwrap();
        assert!(b.begin_tick(2).unwrap().flags & state_flags::SAFETY_STOP == 0);
    }

    #[test]
    fn shutdown_stops_at_once_and_says_so() {
        let mut b = core();
        b.begin_tick(0).unwrap();
        b.finish_tick(Some(&cmd(0, 0.3))).unwrap();
        b.begin_tick(1).unwrap();
        let (s, result) = b.shutdown(2);
        result.unwrap();
        assert!(s.flags & state_flags::SHUTDOWN != 0);
        assert_eq!(s.applied_tick, NO_TICK);
        assert_eq!(b.robot().command_in_force(), &[0.0; 6]);
    }

    #[test]
    fn travel_is_the_joint_path_length() {
        let mut b = core();
        b.begin_tick(0).unwrap();
        for k in 0..40 {
            b.finish_tick(Some(&cmd(k, 0.2))).unwrap();
            b.begin_tick(0).unwrap();
        }
        let expect = 40.0 * DT * (0.2f64.powi(2) + 0.1f64.powi(2)).sqrt();
        assert!((b.joint_travel_rad() - expect).abs() < 1e-9);
    }

    /// A mock arm whose calls fail while `fail` is set.
    struct Failing {
        arm: MockArm,
        fail: std::sync::Arc<std::sync::atomic::AtomicBool>,
    }

    impl Failing {
        fn check(&self) -> Result<(), RobotError> {
            if self.fail.load(std::sync::atomic::Ordering::SeqCst) {
                Err(crate::kortex::KortexError::SessionClosed.into())
            } else {
                Ok(())
            }
        }
    }

    impl Robot for Failing {
        fn n_joints(&self) -> usize {
            6
        }
        fn advance(&mut self, dt: f64) -> Result<Reading, RobotError> {
            self.check()?;
            self.arm.advance(dt)
        }
        fn command(&mut self, v: &[f64], g: f64) -> Result<(), RobotError> {
            self.check()?;
            self.arm.command(v, g)
        }
        fn stop(&mut self) -> Result<(), RobotError> {
            self.check()?;
            self.arm.stop()
        }
        fn shutdown(&mut self) -> Result<Reading, RobotError> {
            self.check()?;
            self.arm.shutdown()
        }
        fn is_mock(&self) -> bool {
            true
        }
    }

    #[test]
    fn robot_errors_reach_the_caller_and_shutdown_keeps_the_last_reading() {
        let fail = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let set = |v: bool| fail.store(v, std::sync::atomic::Ordering::SeqCst);
        let robot = Failing {
            arm: MockArm::new(MockConfig::default()).unwrap(),
            fail: fail.clone(),
        };
        let mut b = BridgeCore::new(robot, DT, gen3_lite::DEFAULT_ACCELERATION_RAD_S2.to_vec());
        b.begin_tick(0).unwrap();
        b.finish_tick(Some(&cmd(0, 0.2))).unwrap();
        let s1 = b.begin_tick(1).unwrap();
        assert_eq!(s1.applied_tick, 0);
        // A command the robot did not take is not reported as executed.
        set(true);
        assert!(b.finish_tick(Some(&cmd(1, 0.2))).is_err());
        set(false);
        let s2 = b.begin_tick(2).unwrap();
        assert_eq!(s2.applied_tick, NO_TICK);
        // A miss whose stop fails is still counted, and the error reaches the caller.
        set(true);
        assert!(b.finish_tick(None).is_err());
        assert_eq!(b.missed(), 1);
        assert!(b.begin_tick(3).is_err());
        // The robot cannot be reached: the final state is the last reading, flagged.
        let (last, result) = b.shutdown(4);
        assert!(result.is_err());
        assert!(last.flags & state_flags::SHUTDOWN != 0);
        assert_eq!(last.applied_tick, NO_TICK);
        assert_eq!(last.q_rad, s2.q_rad);
    }

    proptest! {
        #[test]
        fn stop_step_respects_limits_and_direction(
            v in proptest::array::uniform6(-3.0f64..3.0),
        ) {
            let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
            let mut w = v;
            controlled_stop_step(&mut w, &accel, DT);
            let mut k: Option<f64> = None;
            for j in 0..6 {
                prop_assert!((w[j] - v[j]).abs() <= accel[j] * DT + 1e-12);
                prop_assert!(w[j].abs() <= v[j].abs());
                if v[j].abs() > 1e-9 {
                    let r = w[j] / v[j];
                    prop_assert!(r >= 0.0);
                    if let Some(k) = k { prop_assert!((r - k).abs() < 1e-9); }
                    k = Some(r);
                }
            }
        }
    }
}
