//! Low-level servoing (`[bridge.kortex] mode = "low-level"`): the cyclic channel over UDP.
//!
//! What the protocol reference gives: UDP port 10001 carries only the low-level cyclic
//! channel, in its own session; datagrams carry the bare serialized `Frame`; the servoing mode
//! is set with `Base.SetServoingMode(low-level 3)`; `BaseCyclic` answers with a `Feedback`.
//! What it does not give, and where the bridge takes it from or decides conservatively (each
//! said again where it is used):
//!
//! * the UID of `BaseCyclic.Refresh` and the layout of its `Command`: from the order of RPCs
//!   and members in Kinova's published Kortex API documentation, consistent with the
//!   reference's numbered messages (see [`msg::Command`]). Not yet run on an arm by this
//!   project: the first use is guarded by the entry check ([`EntryHold`]);
//! * that the UDP session is opened with the same `CreateSession` as the TCP one (it is the
//!   only session call the reference names);
//! * what "at rest" means to the robot: the bridge takes every measured joint speed below
//!   [`REST_SPEED_RAD_S`];
//! * what the robot does with a late or missing reply: the bridge treats a Refresh with no
//!   reply within `reply_timeout_ms` as a fault, even one lost datagram;
//! * the gripper: the reference names no cyclic gripper command, so in low-level mode the
//!   bridge sends none (the gripper holds where it is).
//!
//! The entry check: after the switch to low-level servoing and the first Refresh (the
//! measured position), the bridge holds that position for `entry_hold_ms`, whatever the graph
//! commands (its commands are counted, not applied; the ticks go on as usual), and every joint
//! must stay within `entry_hold_tolerance_rad` of it. An arm that reads the command
//! differently than the bridge means moves away from a position it was told to hold: the
//! bridge stops it and ends the run ([`KortexError::EntryHold`]). Only then do the graph's
//! commands apply, watched by the following-error check.
//!
//! The pure steps ([`check_at_rest`], [`integrate`], [`check_following`], [`command_msg`],
//! [`EntryHold::step`]) take the period as a parameter and are tested at 40 Hz and 1 kHz.

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use ipc_types::MAX_JOINTS;
use kinematics::ArmLimits;
use prost::Message as _;

use super::wire::{Frame, FrameType};
use super::{Credentials, Function, KortexError, angle_rad_to_wire_deg, msg};

/// Every measured joint speed below this is "at rest" (rad/s, about 0.57°/s). The reference is
/// silent on the robot's own notion; this one is strict.
pub const REST_SPEED_RAD_S: f64 = 0.01;

/// Refuses low-level mode unless every joint speed is below `rest_rad_s`.
pub fn check_at_rest(qdot_rad_s: &[f64], rest_rad_s: f64) -> Result<(), KortexError> {
    match qdot_rad_s
        .iter()
        .enumerate()
        .find(|(_, v)| v.abs() >= rest_rad_s || v.is_nan())
    {
        Some((joint, v)) => Err(KortexError::NotAtRest {
            joint,
            speed_rad_s: *v,
            rest_rad_s,
        }),
        None => Ok(()),
    }
}

/// One tick of the position command: `q_cmd += qdot * period_s`, each joint kept inside its
/// limits (a joint without limits in `limits` is not clamped). Non-finite speeds count as 0.
pub fn integrate(q_cmd: &mut [f64], qdot_rad_s: &[f64], period_s: f64, limits: &ArmLimits) {
    for (j, (q, v)) in q_cmd.iter_mut().zip(qdot_rad_s).enumerate() {
        let v = if v.is_finite() { *v } else { 0.0 };
        let mut next = *q + v * period_s;
        if let (Some(lo), Some(hi)) = (limits.lower_rad.get(j), limits.upper_rad.get(j)) {
            next = next.clamp(*lo, *hi);
        }
        *q = next;
    }
}

/// The following-error check: every measured angle within `bound_rad` of its commanded one
/// (angles compared on the circle, so -179° and 179° are 2° apart).
pub fn check_following(
    measured_rad: &[f64],
    commanded_rad: &[f64],
    bound_rad: f64,
) -> Result<(), KortexError> {
    for (joint, (m, c)) in measured_rad.iter().zip(commanded_rad).enumerate() {
        let d = (m - c).rem_euclid(std::f64::consts::TAU);
        let error_rad = d.min(std::f64::consts::TAU - d);
        if error_rad > bound_rad || error_rad.is_nan() {
            return Err(KortexError::FollowingError {
                joint,
                measured_rad: *m,
                commanded_rad: *c,
                error_rad,
                bound_rad,
            });
        }
    }
    Ok(())
}

/// The cyclic command for joint positions `q_cmd` (rad; sent as degrees in `[0, 360)`).
pub fn command_msg(q_cmd: &[f64], frame_id: u32) -> msg::Command {
    msg::Command {
        frame_id,
        actuators: q_cmd
            .iter()
            .map(|q| msg::ActuatorCommand {
                // Device id 0 (upper 16 bits, as Kinova's examples send), the sequence
                // number in the lower 16: the frame counter wraps there.
                command_id: frame_id & 0xFFFF,
                flags: 0,
                position: angle_rad_to_wire_deg(*q) as f32,
                velocity: 0.0,
                torque_joint: 0.0,
                current_motor: 0.0,
            })
            .collect(),
    }
}

/// What a tick of the entry hold concluded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntryStep {
    /// Still holding: the graph's commands are not applied yet.
    Holding,
    /// The hold is over and every joint stayed within the tolerance: from now on the graph's
    /// commands apply.
    Passed,
}

/// The entry check of low-level mode, a pure step: the bridge holds the measured position for
/// `hold_ms` and every measured joint must stay within `tolerance_rad` of it (see the module
/// documentation). The time is counted in ticks of the period given to [`EntryHold::step`],
/// so the hold lasts at least `hold_ms` of executed ticks; it ends at the first tick at or past
/// that time whose feedback is fresh and within the tolerance.
#[derive(Debug, Clone, PartialEq)]
pub struct EntryHold {
    hold_ms: u32,
    tolerance_rad: f64,
    elapsed_s: f64,
    ticks: u64,
    feedbacks: u64,
    held_back: u64,
    held_back_moving: u64,
    worst_rad: f64,
    passed: bool,
}

impl EntryHold {
    /// A hold of `hold_ms` with a tolerance of `tolerance_rad`, starting now (at the first
    /// position command).
    pub fn new(hold_ms: u32, tolerance_rad: f64) -> Self {
        Self {
            hold_ms,
            tolerance_rad,
            elapsed_s: 0.0,
            ticks: 0,
            feedbacks: 0,
            held_back: 0,
            held_back_moving: 0,
            worst_rad: 0.0,
            passed: false,
        }
    }

    /// One step: checks the measured angles of a fresh feedback (`None`: none arrived this
    /// tick) against the `held_rad` position, angles compared on the circle, then lets
    /// `period_s` pass (0 for the reply to the first command, before the first tick). A joint
    /// beyond the tolerance (or a non-finite angle) is [`KortexError::EntryHold`]. After the
    /// hold has passed, steps change nothing and return [`EntryStep::Passed`].
    pub fn step(
        &mut self,
        measured_rad: Option<&[f64]>,
        held_rad: &[f64],
        period_s: f64,
    ) -> Result<EntryStep, KortexError> {
        if self.passed {
            return Ok(EntryStep::Passed);
        }
        if period_s > 0.0 {
            self.ticks += 1;
            self.elapsed_s += period_s;
        }
        if let Some(measured) = measured_rad {
            self.feedbacks += 1;
            for (joint, (m, h)) in measured.iter().zip(held_rad).enumerate() {
                let d = (m - h).rem_euclid(std::f64::consts::TAU);
                let error_rad = d.min(std::f64::consts::TAU - d);
                if error_rad > self.tolerance_rad || error_rad.is_nan() {
                    return Err(KortexError::EntryHold {
                        joint,
                        measured_rad: *m,
                        held_rad: *h,
                        error_rad,
                        tolerance_rad: self.tolerance_rad,
                        after_ms: self.elapsed_s * 1e3,
                        hold_ms: self.hold_ms,
                    });
                }
                self.worst_rad = self.worst_rad.max(error_rad);
            }
        }
        // Half a microsecond of slack for the sum of the periods' rounding.
        let over = self.elapsed_s * 1e3 + 5e-4 >= f64::from(self.hold_ms);
        if over && measured_rad.is_some() {
            self.passed = true;
            return Ok(EntryStep::Passed);
        }
        Ok(EntryStep::Holding)
    }

    /// Counts a command that the hold did not apply (the graph's, or a controlled stop's ramp;
    /// `qdot_rad_s`: what it asked for, a non-zero finite speed being a request for motion).
    pub fn hold_back(&mut self, qdot_rad_s: &[f64]) {
        self.held_back += 1;
        if qdot_rad_s.iter().any(|v| v.is_finite() && *v != 0.0) {
            self.held_back_moving += 1;
        }
    }

    /// Whether the hold is still on (the graph's commands are not applied).
    pub fn holding(&self) -> bool {
        !self.passed
    }

    /// The hold's length (ms).
    pub fn hold_ms(&self) -> u32 {
        self.hold_ms
    }

    /// Ticks counted so far.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// Time counted so far (s): the sum of the steps' periods.
    pub fn elapsed_s(&self) -> f64 {
        self.elapsed_s
    }

    /// Feedbacks checked (the first command's reply included).
    pub fn feedbacks(&self) -> u64 {
        self.feedbacks
    }

    /// Commands held back.
    pub fn held_back(&self) -> u64 {
        self.held_back
    }

    /// Commands held back that asked for motion.
    pub fn held_back_moving(&self) -> u64 {
        self.held_back_moving
    }

    /// The largest distance of a joint from the held position seen so far (rad).
    pub fn worst_rad(&self) -> f64 {
        self.worst_rad
    }
}

/// Counters of the cyclic channel.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CyclicStats {
    /// Refresh commands sent.
    pub refreshes: u64,
    /// Feedbacks received.
    pub feedbacks: u64,
    /// Datagrams that were not a reply to a waiting Refresh (ignored).
    pub other_datagrams: u64,
}

/// The low-level session over UDP: the position command in force and the Refreshes waiting
/// for their reply.
pub struct CyclicSession {
    addr: SocketAddr,
    socket: UdpSocket,
    session_id: u16,
    session_open: bool,
    next_message_id: u16,
    n: usize,
    q_cmd: [f64; MAX_JOINTS],
    frame_id: u32,
    pending: VecDeque<(u16, Instant)>,
    reply_timeout: Duration,
    stats: CyclicStats,
    buf: Vec<u8>,
}

impl std::fmt::Debug for CyclicSession {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CyclicSession")
            .field("addr", &self.addr)
            .field("session_id", &self.session_id)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl CyclicSession {
    /// Opens the UDP session at `addr` for an arm of `n` joints: CreateSession with
    /// `credentials` and the two inactivity timeouts, awaited for at most `reply_timeout`.
    pub fn open(
        addr: SocketAddr,
        info: &msg::CreateSessionInfo,
        n: usize,
        reply_timeout: Duration,
    ) -> Result<Self, KortexError> {
        let io = |during, source| KortexError::Io {
            addr,
            during,
            source,
        };
        let local: SocketAddr = if addr.is_ipv4() {
            ([0, 0, 0, 0], 0).into()
        } else {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        };
        let socket = UdpSocket::bind(local).map_err(|e| io("binding the cyclic UDP socket", e))?;
        socket
            .connect(addr)
            .map_err(|e| io("connecting the cyclic UDP socket", e))?;
        let mut s = Self {
            addr,
            socket,
            session_id: 0,
            session_open: false,
            next_message_id: 1,
            n: n.min(MAX_JOINTS),
            q_cmd: [0.0; MAX_JOINTS],
            frame_id: 0,
            pending: VecDeque::with_capacity(64),
            reply_timeout,
            stats: CyclicStats::default(),
            buf: vec![0u8; 65_536],
        };
        let reply = s.call(Function::CreateSession, info.encode_to_vec())?;
        s.session_id = reply.header().session_id();
        s.session_open = true;
        Ok(s)
    }

    /// [`Self::open`] with the credentials and timeouts of the TCP session.
    pub fn open_with(
        addr: SocketAddr,
        credentials: &Credentials,
        connection_timeout_ms: u32,
        session_timeout_ms: u32,
        n: usize,
        reply_timeout: Duration,
    ) -> Result<Self, KortexError> {
        let info = msg::CreateSessionInfo {
            username: credentials.username().to_owned(),
            session_inactivity_timeout: session_timeout_ms,
            password: credentials.password().to_owned(),
            connection_inactivity_timeout: connection_timeout_ms,
        };
        Self::open(addr, &info, n, reply_timeout)
    }

    /// The session id the robot gave the UDP session.
    pub fn session_id(&self) -> u16 {
        self.session_id
    }

    /// The position command in force (rad).
    pub fn q_cmd(&self) -> &[f64] {
        &self.q_cmd[..self.n]
    }

    /// The counters.
    pub fn stats(&self) -> CyclicStats {
        self.stats
    }

    fn next_id(&mut self) -> u16 {
        let id = self.next_message_id;
        self.next_message_id = if id == u16::MAX { 1 } else { id + 1 };
        id
    }

    fn send_frame(&mut self, function: Function, payload: Vec<u8>) -> Result<u16, KortexError> {
        let id = self.next_id();
        let frame = Frame::new(
            FrameType::Request,
            self.session_id,
            id,
            function.uid(),
            payload,
        )
        .map_err(|source| KortexError::Encode {
            function: function.name(),
            source,
        })?;
        self.socket
            .send(&frame.encode_bare())
            .map_err(|source| KortexError::Io {
                addr: self.addr,
                during: "sending a cyclic datagram",
                source,
            })?;
        Ok(id)
    }

    /// One datagram, if one is there within `wait` (`None`: do not wait).
    fn recv(&mut self, wait: Option<Duration>) -> Result<Option<Frame>, KortexError> {
        let addr = self.addr;
        let io = |during, source| KortexError::Io {
            addr,
            during,
            source,
        };
        match wait {
            None => self
                .socket
                .set_nonblocking(true)
                .map_err(|e| io("setting the cyclic socket non-blocking", e))?,
            Some(w) => {
                self.socket
                    .set_nonblocking(false)
                    .map_err(|e| io("setting the cyclic socket blocking", e))?;
                self.socket
                    .set_read_timeout(Some(w.max(Duration::from_micros(100))))
                    .map_err(|e| io("setting the cyclic read timeout", e))?;
            }
        }
        let n = match self.socket.recv(&mut self.buf) {
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                return Ok(None);
            }
            Err(e) => return Err(io("reading the cyclic socket", e)),
        };
        let frame = Frame::decode(&self.buf[..n]).map_err(|e| KortexError::Wire {
            addr,
            source: super::wire::WireError::Decode {
                len: n,
                reason: e.to_string(),
            },
        })?;
        Ok(Some(frame))
    }

    /// Sends a request and waits for its reply (start and end of the session only).
    fn call(&mut self, function: Function, payload: Vec<u8>) -> Result<Frame, KortexError> {
        let id = self.send_frame(function, payload)?;
        let deadline = Instant::now() + self.reply_timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(KortexError::ReplyTimeout {
                    function: function.name(),
                    message_id: id,
                    waited_ms: self.reply_timeout.as_millis() as u64,
                    note: " (cyclic channel, UDP)".into(),
                });
            }
            let Some(frame) = self.recv(Some(left))? else {
                continue;
            };
            let h = frame.header();
            if h.frame_type() != Some(FrameType::Response) || h.message_id() != id {
                self.stats.other_datagrams += 1;
                continue;
            }
            if let Some(fault) = frame.error() {
                return Err(KortexError::Robot {
                    function: function.name(),
                    message_id: id,
                    fault,
                });
            }
            return Ok(frame);
        }
    }

    /// Sets the position command to the measured `q_rad` and sends it, waiting for the reply:
    /// the first command of low-level mode. Returns the reply's feedback.
    pub fn first_command(&mut self, q_rad: &[f64]) -> Result<msg::Feedback, KortexError> {
        let n = self.n.min(q_rad.len());
        self.q_cmd[..n].copy_from_slice(&q_rad[..n]);
        self.frame_id = self.frame_id.wrapping_add(1);
        let payload = command_msg(&self.q_cmd[..self.n], self.frame_id).encode_to_vec();
        self.stats.refreshes += 1;
        let reply = self.call(Function::Refresh, payload)?;
        self.stats.feedbacks += 1;
        decode_feedback(&reply)
    }

    /// Integrates `qdot_rad_s` over `period_s` into the position command (kept inside
    /// `limits`) and sends it without waiting for the reply.
    pub fn command(
        &mut self,
        qdot_rad_s: &[f64],
        period_s: f64,
        limits: &ArmLimits,
    ) -> Result<(), KortexError> {
        let n = self.n;
        integrate(&mut self.q_cmd[..n], qdot_rad_s, period_s, limits);
        self.refresh()
    }

    /// Sends the position command in force again (holding the arm where it is commanded).
    pub fn refresh(&mut self) -> Result<(), KortexError> {
        self.frame_id = self.frame_id.wrapping_add(1);
        let payload = command_msg(&self.q_cmd[..self.n], self.frame_id).encode_to_vec();
        let id = self.send_frame(Function::Refresh, payload)?;
        self.pending.push_back((id, Instant::now()));
        self.stats.refreshes += 1;
        Ok(())
    }

    /// Takes every reply that has arrived without waiting; returns the newest feedback. A
    /// Refresh without a reply within the reply timeout is an error (one lost datagram too:
    /// the reference says nothing about the robot's tolerance, so the bridge has none).
    pub fn poll(&mut self) -> Result<Option<msg::Feedback>, KortexError> {
        let mut newest = None;
        while let Some(frame) = self.recv(None)? {
            let h = frame.header();
            let Some(i) = self.pending.iter().position(|(id, _)| {
                h.frame_type() == Some(FrameType::Response) && *id == h.message_id()
            }) else {
                self.stats.other_datagrams += 1;
                continue;
            };
            let (id, _) = self.pending.remove(i).unwrap_or((0, Instant::now()));
            if let Some(fault) = frame.error() {
                return Err(KortexError::Robot {
                    function: Function::Refresh.name(),
                    message_id: id,
                    fault,
                });
            }
            self.stats.feedbacks += 1;
            newest = Some(decode_feedback(&frame)?);
        }
        if let Some((id, at)) = self.pending.front()
            && at.elapsed() > self.reply_timeout
        {
            return Err(KortexError::ReplyTimeout {
                function: Function::Refresh.name(),
                message_id: *id,
                waited_ms: self.reply_timeout.as_millis() as u64,
                note: " (cyclic channel, UDP)".into(),
            });
        }
        Ok(newest)
    }

    /// Closes the UDP session (CloseSession, awaited); replies in flight are dropped.
    pub fn close(&mut self) -> Result<(), KortexError> {
        self.pending.clear();
        if !self.session_open {
            return Ok(());
        }
        self.session_open = false;
        self.call(Function::CloseSession, Vec::new()).map(|_| ())
    }
}

fn decode_feedback(frame: &Frame) -> Result<msg::Feedback, KortexError> {
    msg::Feedback::decode(frame.payload.as_slice()).map_err(|e| KortexError::Payload {
        function: Function::Refresh.name(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const RATES_HZ: [f64; 2] = [40.0, 1000.0];

    #[test]
    fn at_rest_is_every_joint_below_the_bound() {
        check_at_rest(&[0.0, 0.005, -0.009, 0.0, 0.0, 0.0], REST_SPEED_RAD_S).unwrap();
        let e = check_at_rest(&[0.0, 0.0, -0.2, 0.0, 0.0, 0.0], REST_SPEED_RAD_S).unwrap_err();
        assert!(matches!(e, KortexError::NotAtRest { joint: 2, .. }), "{e}");
        assert!(e.to_string().contains("not at rest"), "{e}");
        assert!(check_at_rest(&[f64::NAN], REST_SPEED_RAD_S).is_err());
    }

    #[test]
    fn integration_follows_the_speed_for_any_period_and_stays_in_the_limits() {
        let limits = kinematics::gen3_lite::limits();
        for hz in RATES_HZ {
            let period = 1.0 / hz;
            let mut q = [0.0, 0.5, 1.0, 0.0, 0.0, 0.0];
            let qdot = [0.2, -0.1, 0.0, f64::NAN, 0.0, 0.0];
            for _ in 0..hz as usize {
                integrate(&mut q, &qdot, period, &limits);
            }
            // One second of motion whatever the rate.
            assert!((q[0] - 0.2).abs() < 1e-9, "{hz} Hz: {q:?}");
            assert!((q[1] - 0.4).abs() < 1e-9, "{hz} Hz: {q:?}");
            assert_eq!(q[3], 0.0, "a non-finite speed does not move the joint");
            let mut q = [2.6, 0.0, 0.0, 0.0, 0.0, 0.0];
            integrate(&mut q, &[10.0, 0.0, 0.0, 0.0, 0.0, 0.0], period, &limits);
            assert!(q[0] <= limits.upper_rad[0] + 1e-12, "{hz} Hz: {q:?}");
        }
    }

    #[test]
    fn following_error_is_measured_on_the_circle() {
        check_following(&[0.01, -3.13], &[0.0, 3.13], 0.05).unwrap();
        let e = check_following(&[0.0, 0.2], &[0.0, 0.1], 0.05).unwrap_err();
        assert!(
            matches!(e, KortexError::FollowingError { joint: 1, .. }),
            "{e}"
        );
        assert!(e.to_string().contains("following_error_rad"), "{e}");
        assert!(check_following(&[f64::NAN], &[0.0], 0.05).is_err());
    }

    #[test]
    fn the_entry_hold_lasts_its_time_at_any_rate_and_passes_a_still_arm() {
        use std::f64::consts::PI;
        // Joints 3 and 5 held next to +-pi: their measured angles cross it.
        let held = [0.1, -0.28, 1.309, -(PI - 0.001), -1.047, PI - 0.001];
        for hz in RATES_HZ {
            let period = 1.0 / hz;
            let mut hold = EntryHold::new(100, 0.005);
            // The first command's reply, before the first tick.
            assert_eq!(
                hold.step(Some(&held), &held, 0.0).unwrap(),
                EntryStep::Holding
            );
            // The arm sways a little (joints 3 and 5 across +-pi, 0.003 rad away).
            let mut measured = held;
            measured[0] += 0.004;
            measured[3] = PI - 0.002;
            measured[5] = -PI + 0.002;
            let mut ticks = 0;
            while hold.step(Some(&measured), &held, period).unwrap() == EntryStep::Holding {
                hold.hold_back(&[0.0, 0.1, 0.0, 0.0, 0.0, 0.0]);
                ticks += 1;
                assert!(ticks < 10_000, "{hz} Hz: the hold never ends");
            }
            // 100 ms of ticks whatever the rate: 100 at 1 kHz, 4 at 40 Hz.
            let expected = (0.1 * hz).round() as u64;
            assert_eq!(hold.ticks(), expected, "{hz} Hz");
            assert_eq!(hold.held_back(), expected - 1, "{hz} Hz");
            assert_eq!(hold.held_back_moving(), expected - 1, "{hz} Hz");
            assert_eq!(hold.feedbacks(), expected + 1, "{hz} Hz");
            assert!(!hold.holding());
            assert!((hold.worst_rad() - 0.004).abs() < 1e-9, "{hz} Hz");
            assert!((hold.elapsed_s() - 0.1).abs() < 1e-9, "{hz} Hz");
            // Passed for good: a later step changes nothing.
            let far = [3.0; 6];
            assert_eq!(
                hold.step(Some(&far), &held, period).unwrap(),
                EntryStep::Passed
            );
        }
    }

    #[test]
    fn the_entry_hold_waits_for_a_fresh_feedback_to_end() {
        for hz in RATES_HZ {
            let period = 1.0 / hz;
            let held = [0.0; 6];
            let mut hold = EntryHold::new(50, 0.005);
            let due = (0.05 * hz).round() as u64;
            for _ in 0..due {
                assert_eq!(hold.step(None, &held, period).unwrap(), EntryStep::Holding);
            }
            // Time is up, but no feedback has shown the arm: still holding.
            assert!(hold.holding());
            assert_eq!(hold.step(None, &held, period).unwrap(), EntryStep::Holding);
            assert_eq!(
                hold.step(Some(&held), &held, period).unwrap(),
                EntryStep::Passed
            );
            assert_eq!(hold.ticks(), due + 2, "{hz} Hz");
        }
    }

    #[test]
    fn an_arm_that_leaves_the_held_position_fails_the_entry_check() {
        for hz in RATES_HZ {
            let period = 1.0 / hz;
            let held = [0.0, -0.28, 1.309, 0.0, -1.047, 0.0];
            let mut hold = EntryHold::new(100, 0.005);
            hold.step(Some(&held), &held, 0.0).unwrap();
            // Joint 3 drifts at 1.6 rad/s: out of the tolerance within a few ms.
            let mut measured = held;
            let e = loop {
                measured[3] += 1.6 * period;
                match hold.step(Some(&measured), &held, period) {
                    Ok(EntryStep::Holding) => {}
                    Ok(EntryStep::Passed) => panic!("{hz} Hz: passed"),
                    Err(e) => break e,
                }
            };
            let KortexError::EntryHold {
                joint,
                measured_rad,
                held_rad,
                error_rad,
                tolerance_rad,
                after_ms,
                hold_ms,
            } = e
            else {
                panic!("{e}")
            };
            assert_eq!(
                (joint, held_rad, tolerance_rad, hold_ms),
                (3, 0.0, 0.005, 100)
            );
            assert_eq!(measured_rad, measured[3]);
            assert!(error_rad > 0.005, "{hz} Hz: {error_rad}");
            assert!(after_ms <= 100.0, "{hz} Hz: {after_ms}");
            let text = e.to_string();
            assert!(
                text.contains("entry check failed: joint 3")
                    && text.contains("held it at 0.0000 rad")
                    && text.contains("did not follow the held position")
                    && text.contains("entry_hold_tolerance_rad = 0.005"),
                "{text}"
            );
        }
        // Already off in the first command's reply; a non-finite angle fails too.
        let mut hold = EntryHold::new(100, 0.005);
        let e = hold.step(Some(&[0.0, 0.5]), &[0.0, 0.0], 0.0).unwrap_err();
        assert!(matches!(e, KortexError::EntryHold { joint: 1, .. }), "{e}");
        let mut hold = EntryHold::new(100, 0.005);
        assert!(hold.step(Some(&[f64::NAN]), &[0.0], 0.001).is_err());
    }

    #[test]
    fn the_command_carries_every_joint_in_wire_degrees() {
        let m = command_msg(&[-0.5f64.to_radians() * 2.0, 0.0, 1.0], 7);
        assert_eq!(m.frame_id, 7);
        assert_eq!(m.actuators.len(), 3);
        assert!((m.actuators[0].position - 359.0).abs() < 1e-3);
        assert!((m.actuators[2].position - 1.0f64.to_degrees() as f32).abs() < 1e-3);
        assert_eq!(m.actuators[0].command_id, 7);
        // The sequence number wraps in the lower 16 bits; the device id stays 0.
        let m = command_msg(&[0.0], 0x0001_0005);
        assert_eq!((m.frame_id, m.actuators[0].command_id), (0x0001_0005, 5));
    }
}
