//! [`KortexArm`]: a Kinova arm (the graph's robot profile; the Gen3 lite by default) over one
//! Kortex TCP session, as a [`Robot`].
//!
//! Start-up (each call waits for its reply, bounded by `reply_timeout_ms`):
//! CreateSession (credentials, session and connection inactivity timeouts; the session id is
//! read from the reply); the arm's identity, before anything is commanded: GetActuatorCount
//! (must be the profile's joint count) and GetProductConfiguration (the Kortex model, which
//! must be the profile's where the arm reports one: [`super::KortexModel`]; an arm that reports
//! none, or a model the bridge does not know, or answers the call with an error, as older
//! firmware may, is identified by its actuator count alone); a mismatch is
//! [`KortexError::WrongRobot`], naming the robot found and the profile configured. Then
//! SetServoingMode(single-level), ClearFaults, GetKinematicHardLimits (the bridge scales every
//! command into the robot's own joint speed limits), RefreshFeedback (the first reading).
//!
//! The 40 Hz loop is pipelined and never waits on the socket: a reader thread owns the
//! receiving half of the socket, decodes frames and hands them to the control loop through a
//! crossbeam channel. At tick k, [`Robot::advance`] only takes whatever replies arrived
//! (matched by message id; one that arrives after the tick it was due in is counted late) and
//! returns the newest feedback, so the state goes out at once; [`Robot::command`] (or
//! [`Robot::stop`]) then sends JointSpeeds (a gripper position when the target moved) and the
//! request for the next feedback in one write, without waiting for any reply. The state
//! published at tick k is therefore the feedback asked for right after the command of tick
//! k-1.
//!
//! No KeepAlive is ever sent: if the control loop freezes or dies, frames stop, and the robot
//! stops the arm when `connection_timeout_ms` passes.
//!
//! With `mode = "low-level"` ([`super::cyclic`]), start-up goes on: the measured joint speeds
//! must be ~0, the UDP session opens, SetServoingMode(low-level), and a first Refresh with the
//! measured position (awaited). Each tick then takes the newest cyclic feedback (arm-in-fault
//! check; the entry check during the entry hold, the following-error check after it) and sends
//! the next position command. For the first `entry_hold_ms` of ticks (the entry check,
//! [`cyclic::EntryHold`]) that command is the measured position of the entry whatever the
//! graph asks, the graph's commands counted and not applied; the ticks go on as usual. A stop
//! holds the commanded position; the TCP session gets a RefreshFeedback every 25 ms from the
//! control loop. Exit and every fault go back to single-level servoing and close the UDP
//! session before the Stop.
//!
//! Every fault (an error reply, a reply for an unknown message id, an undecodable frame, a
//! reply timeout, a closed or reset connection) stops the arm and closes the session as far as
//! the connection still works, then returns the error; so does [`Robot::shutdown`] and `Drop`.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpStream};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TryRecvError};
use ipc_types::MAX_JOINTS;
use kinematics::{ArmLimits, RobotProfile};
use prost::Message as _;

use super::cyclic::{self, CyclicSession};
use super::wire::{Decoded, Frame, FrameDecoder, FrameType, WireError};
use super::{
    Credentials, FoundRobot, Function, KortexConfig, KortexError, KortexMode, function_name,
    gripper_position_msg, joint_speeds_msg, msg, reading_from_feedback, scale_to_limits,
};
use crate::{LinkStats, Reading, Robot, RobotError};

/// How long the TCP connect may take.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);

/// A gripper target that moved less than this since the last position sent is not sent.
const GRIPPER_EPS: f64 = 1e-4;

/// Low-level mode: the TCP session gets a RefreshFeedback from the control loop at least this
/// often, so that its connection inactivity timeout does not fire while the commands go over
/// UDP (the reference is silent on whether the cyclic session's frames count for the TCP
/// session; the bridge assumes they do not). 25 ms: the high-level rate.
const TCP_FRAME_EVERY: Duration = Duration::from_millis(25);

/// What a read-only session ([`KortexArm::probe`]) told about the arm.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmInfo {
    /// The address it answered on.
    pub addr: SocketAddr,
    /// `DeviceConfig.GetFirmwareVersion`'s value (see [`ArmInfo::firmware`]).
    pub firmware_version: u32,
    /// Actuators reported by `Base.GetActuatorCount`.
    pub actuators: u32,
    /// What the arm says it is: its actuator count and the Kortex model of
    /// `Base.GetProductConfiguration` ([`super::FoundRobot::check`] against a profile).
    pub found: super::FoundRobot,
    /// The joint speed hard limits (rad/s).
    pub speed_limits_rad_s: Vec<f64>,
}

impl ArmInfo {
    /// The firmware version as `major.minor.patch`, read as one byte each from bits 23..16,
    /// 15..8 and 7..0 of the reported value (the raw value follows in brackets).
    pub fn firmware(&self) -> String {
        let v = self.firmware_version;
        format!(
            "{}.{}.{} (0x{v:06x})",
            (v >> 16) & 0xff,
            (v >> 8) & 0xff,
            v & 0xff
        )
    }
}

/// Counters of the client.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct KortexStats {
    /// Requests sent.
    pub requests: u64,
    /// Replies matched to a request.
    pub replies: u64,
    /// Replies that arrived after the tick they were due in.
    pub late_replies: u64,
    /// Ticks that reused the previous reading (the newest feedback had not arrived).
    pub stale_readings: u64,
    /// Bytes dropped to resynchronise the stream.
    pub skipped_bytes: u64,
    /// Frames other than replies (notifications, pings), ignored.
    pub other_frames: u64,
    /// Commands slowed down to the robot's speed limits.
    pub clamped_commands: u64,
    /// Gripper position commands sent.
    pub gripper_commands: u64,
}

/// What the reader thread hands to the control loop.
enum ReaderEvent {
    Frame(Frame),
    Skipped(usize),
    Bad(WireError),
    Eof,
    Truncated { have: usize, need: usize },
    Failed(std::io::Error),
}

fn reader_loop(mut stream: TcpStream, tx: Sender<ReaderEvent>) {
    let mut decoder = FrameDecoder::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = match stream.read(&mut buf) {
            Ok(0) => {
                let ev = match decoder.truncated() {
                    Some((have, need)) => ReaderEvent::Truncated { have, need },
                    None => ReaderEvent::Eof,
                };
                let _ = tx.send(ev);
                return;
            }
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => {
                let _ = tx.send(ReaderEvent::Failed(e));
                return;
            }
        };
        decoder.push(&buf[..n]);
        while let Some(r) = decoder.next_frame() {
            let ev = match r {
                Ok(Decoded::Frame(f)) => ReaderEvent::Frame(f),
                Ok(Decoded::Skipped(n)) => ReaderEvent::Skipped(n),
                Err(e) => ReaderEvent::Bad(e),
            };
            if tx.send(ev).is_err() {
                return;
            }
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Pending {
    message_id: u16,
    function: Function,
    sent_tick: u64,
    sent_at: Instant,
}

/// A reply matched to its request.
struct Reply {
    pending: Pending,
    frame: Frame,
}

/// A Kinova arm over a Kortex session. See the module documentation.
pub struct KortexArm {
    robot: &'static RobotProfile,
    addr: SocketAddr,
    stream: TcpStream,
    events: Receiver<ReaderEvent>,
    reader: Option<JoinHandle<()>>,
    reply_timeout: Duration,
    session_id: u16,
    session_open: bool,
    connected: bool,
    closing: bool,
    next_message_id: u16,
    pending: Vec<Pending>,
    tick: u64,
    dt: f64,
    limits: ArmLimits,
    speed_limit_rad_s: [f64; MAX_JOINTS],
    reading: Reading,
    feedback_pending: Option<u16>,
    feedback_requested_tick: Option<u64>,
    gripper_target: f64,
    gripper_sent: f64,
    stats: KortexStats,
    out: Vec<u8>,
    /// Low-level mode: the UDP session (from its opening until the exit).
    cyclic: Option<CyclicSession>,
    /// Low-level servoing was set on the robot (to be undone on exit).
    low_level_set: bool,
    following_error_rad: f64,
    /// Low-level mode: the entry check (from the first position command; kept after it
    /// passed, for its counts).
    entry: Option<cyclic::EntryHold>,
    last_tcp_sent: Instant,
    gripper_warned: bool,
}

impl std::fmt::Debug for KortexArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KortexArm")
            .field("addr", &self.addr)
            .field("session_id", &self.session_id)
            .field("session_open", &self.session_open)
            .field("tick", &self.tick)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl KortexArm {
    /// [`KortexArm::connect_to`] for the default robot profile.
    pub fn connect(cfg: &KortexConfig, credentials: &Credentials) -> Result<Self, KortexError> {
        Self::connect_to(RobotProfile::default_robot(), cfg, credentials)
    }

    /// Connects to the robot of `cfg`, an arm of profile `robot`, opens a session with
    /// `credentials` and prepares it for joint speed control (see the module documentation).
    /// On any failure the session is closed again and the error names what failed.
    pub fn connect_to(
        robot: &'static RobotProfile,
        cfg: &KortexConfig,
        credentials: &Credentials,
    ) -> Result<Self, KortexError> {
        let mut arm = Self::open(robot, cfg, CONNECT_TIMEOUT)?;
        match arm.start(cfg, credentials) {
            Ok(()) => Ok(arm),
            Err(e) => Err(arm.fault(e)),
        }
    }

    /// A read-only look at the arm of `cfg` for `scl doctor`: connects within `timeout`,
    /// opens a session with `credentials`, reads the firmware version, the actuator count, the
    /// Kortex model (as the bridge's start-up does) and the joint speed hard limits, and closes
    /// the session. Nothing is commanded: no servoing
    /// mode, no fault clearing, no Stop (each reply is awaited at most `timeout` too).
    pub fn probe(
        cfg: &KortexConfig,
        credentials: &Credentials,
        timeout: Duration,
    ) -> Result<ArmInfo, KortexError> {
        let mut cfg = cfg.clone();
        cfg.reply_timeout_ms = u32::try_from(timeout.as_millis())
            .unwrap_or(u32::MAX)
            .max(1);
        let mut arm = Self::open(RobotProfile::default_robot(), &cfg, timeout)?;
        let result = arm.read_info(&cfg, credentials);
        if arm.session_open && arm.connected {
            let closed = arm.call(Function::CloseSession, Vec::new());
            arm.session_open = false;
            if result.is_ok() {
                closed?;
            }
        }
        arm.session_open = false;
        arm.disconnect();
        result
    }

    fn read_info(
        &mut self,
        cfg: &KortexConfig,
        credentials: &Credentials,
    ) -> Result<ArmInfo, KortexError> {
        let info = msg::CreateSessionInfo {
            username: credentials.username().to_owned(),
            session_inactivity_timeout: cfg.session_timeout_ms,
            password: credentials.password().to_owned(),
            connection_inactivity_timeout: cfg.connection_timeout_ms,
        };
        let reply = self.call(Function::CreateSession, info.encode_to_vec())?;
        self.session_id = reply.frame.header().session_id();
        self.session_open = true;
        let reply = self.call(Function::GetFirmwareVersion, Vec::new())?;
        let fw: msg::FirmwareVersion = decode(Function::GetFirmwareVersion, &reply)?;
        let found = self.identify()?;
        let reply = self.call(Function::GetKinematicHardLimits, Vec::new())?;
        let limits: msg::KinematicLimits = decode(Function::GetKinematicHardLimits, &reply)?;
        Ok(ArmInfo {
            addr: self.addr,
            firmware_version: fw.firmware_version,
            actuators: found.actuators,
            found,
            speed_limits_rad_s: limits
                .joint_speed_limits
                .iter()
                .map(|v| f64::from(*v).to_radians())
                .collect(),
        })
    }

    /// Connects (within `connect_timeout`) and starts the reader thread; no request yet.
    fn open(
        robot: &'static RobotProfile,
        cfg: &KortexConfig,
        connect_timeout: Duration,
    ) -> Result<Self, KortexError> {
        let addr = cfg.socket_addr()?;
        let stream = TcpStream::connect_timeout(&addr, connect_timeout)
            .map_err(|source| KortexError::Connect { addr, source })?;
        let io = |during, source| KortexError::Io {
            addr,
            during,
            source,
        };
        let reply_timeout = Duration::from_millis(u64::from(cfg.reply_timeout_ms));
        stream
            .set_nodelay(true)
            .map_err(|e| io("setting TCP_NODELAY", e))?;
        stream
            .set_write_timeout(Some(reply_timeout))
            .map_err(|e| io("setting the write timeout", e))?;
        let rx_stream = stream
            .try_clone()
            .map_err(|e| io("cloning the socket for the reader thread", e))?;
        let (tx, events) = crossbeam_channel::unbounded();
        let reader = std::thread::Builder::new()
            .name("kortex-reader".into())
            .spawn(move || reader_loop(rx_stream, tx))
            .map_err(|e| io("starting the reader thread", e))?;
        let limits = robot.limits().clone();
        let arm = Self {
            robot,
            addr,
            stream,
            events,
            reader: Some(reader),
            reply_timeout,
            session_id: 0,
            session_open: false,
            connected: true,
            closing: false,
            next_message_id: 1,
            pending: Vec::with_capacity(16),
            tick: 0,
            dt: 1.0 / robot.control_rate_hz(),
            speed_limit_rad_s: [0.0; MAX_JOINTS],
            reading: Reading {
                q_rad: [0.0; MAX_JOINTS],
                qdot_rad_s: [0.0; MAX_JOINTS],
                gripper: 0.0,
                at_limit: false,
            },
            feedback_pending: None,
            feedback_requested_tick: None,
            gripper_target: 0.0,
            gripper_sent: 0.0,
            stats: KortexStats::default(),
            out: Vec::with_capacity(256),
            limits,
            cyclic: None,
            low_level_set: false,
            following_error_rad: cfg.following_error_rad,
            entry: None,
            last_tcp_sent: Instant::now(),
            gripper_warned: false,
        };
        Ok(arm)
    }

    fn start(&mut self, cfg: &KortexConfig, credentials: &Credentials) -> Result<(), KortexError> {
        let info = msg::CreateSessionInfo {
            username: credentials.username().to_owned(),
            session_inactivity_timeout: cfg.session_timeout_ms,
            password: credentials.password().to_owned(),
            connection_inactivity_timeout: cfg.connection_timeout_ms,
        };
        let reply = self.call(Function::CreateSession, info.encode_to_vec())?;
        self.session_id = reply.frame.header().session_id();
        self.session_open = true;
        let found = self.identify()?;
        found.check(self.robot)?;
        self.call(
            Function::SetServoingMode,
            msg::ServoingModeInformation {
                servoing_mode: msg::servoing_mode::SINGLE_LEVEL,
            }
            .encode_to_vec(),
        )?;
        self.call(Function::ClearFaults, Vec::new())?;
        let n = self.robot.n_joints();
        let reply = self.call(Function::GetKinematicHardLimits, Vec::new())?;
        let limits: msg::KinematicLimits = decode(Function::GetKinematicHardLimits, &reply)?;
        self.speed_limit_rad_s = speed_limits_from(&limits, n)?;
        let reply = self.call(Function::RefreshFeedback, Vec::new())?;
        let fb: msg::Feedback = decode(Function::RefreshFeedback, &reply)?;
        // The first reading: continuous joints in (-π, π] (unwrapped against zero).
        self.reading = self.reading_of(&fb)?;
        self.gripper_target = self.reading.gripper;
        self.gripper_sent = self.reading.gripper;
        let limits_deg: Vec<String> = limits
            .joint_speed_limits
            .iter()
            .map(|v| format!("{v:.1}"))
            .collect();
        tracing::info!(
            address = %self.addr,
            session = format_args!("{:#06x}", self.session_id),
            connection_timeout_ms = cfg.connection_timeout_ms,
            session_timeout_ms = cfg.session_timeout_ms,
            "Kortex session open; {found}; joint speed hard limits [{}] deg/s",
            limits_deg.join(", ")
        );
        if cfg.mode == KortexMode::LowLevel {
            self.enter_low_level(cfg, credentials)?;
        }
        Ok(())
    }

    /// What the arm says it is: `Base.GetActuatorCount` and `Base.GetProductConfiguration`'s
    /// model (read-only calls). An error reply to the latter (older firmware) leaves the
    /// model unreported; any other failure is returned.
    fn identify(&mut self) -> Result<FoundRobot, KortexError> {
        let reply = self.call(Function::GetActuatorCount, Vec::new())?;
        let count: msg::ActuatorInformation = decode(Function::GetActuatorCount, &reply)?;
        let (model, refused) = match self.call(Function::GetProductConfiguration, Vec::new()) {
            Ok(reply) => {
                let c: msg::CompleteProductConfiguration =
                    decode(Function::GetProductConfiguration, &reply)?;
                (c.model, false)
            }
            Err(e @ KortexError::Robot { .. }) => {
                tracing::warn!(
                    "{e}: the arm's model is unknown; its actuator count alone identifies it"
                );
                (msg::model_id::UNSPECIFIED, true)
            }
            Err(e) => return Err(e),
        };
        let found = FoundRobot {
            model,
            actuators: count.count,
        };
        if found.kortex_model().is_none() && !refused {
            tracing::warn!(
                "the arm reports no Kortex model the bridge knows ({found}): its actuator count \
                 alone identifies it"
            );
        }
        Ok(found)
    }

    /// Low-level mode, entered only from rest: checks the measured joint speeds, opens the UDP
    /// session, sets low-level servoing, sends the first position command, equal to the
    /// measured position (awaited), and starts the entry hold (its reply is the hold's first
    /// check). On failure the caller's fault path goes back to single-level servoing and
    /// closes both sessions.
    fn enter_low_level(
        &mut self,
        cfg: &KortexConfig,
        credentials: &Credentials,
    ) -> Result<(), KortexError> {
        let n = self.robot.n_joints();
        cyclic::check_at_rest(&self.reading.qdot_rad_s[..n], cyclic::REST_SPEED_RAD_S)?;
        let addr = cfg.cyclic_addr()?;
        self.cyclic = Some(CyclicSession::open_with(
            addr,
            credentials,
            cfg.connection_timeout_ms,
            cfg.session_timeout_ms,
            n,
            self.reply_timeout,
        )?);
        // The robot may have moved since the speeds were read: read them again right before
        // the mode changes.
        let reply = self.call(Function::RefreshFeedback, Vec::new())?;
        let fb: msg::Feedback = decode(Function::RefreshFeedback, &reply)?;
        self.reading = self.reading_of(&fb)?;
        cyclic::check_at_rest(&self.reading.qdot_rad_s[..n], cyclic::REST_SPEED_RAD_S)?;
        self.call(
            Function::SetServoingMode,
            msg::ServoingModeInformation {
                servoing_mode: msg::servoing_mode::LOW_LEVEL,
            }
            .encode_to_vec(),
        )?;
        self.low_level_set = true;
        self.last_tcp_sent = Instant::now();
        let q = self.reading.q_rad;
        let Some(c) = self.cyclic.as_mut() else {
            return Err(KortexError::SessionClosed);
        };
        let fb = c.first_command(&q[..n])?;
        let session = c.session_id();
        self.entry = Some(cyclic::EntryHold::new(
            cfg.entry_hold_ms,
            cfg.entry_hold_tolerance_rad,
        ));
        self.take_cyclic_feedback(Some(&fb), 0.0)?;
        tracing::info!(
            address = %addr,
            session = format_args!("{session:#06x}"),
            following_error_rad = self.following_error_rad,
            entry_hold_ms = cfg.entry_hold_ms,
            entry_hold_tolerance_rad = cfg.entry_hold_tolerance_rad,
            "low-level servoing: first position command = the measured position; held for the \
             entry check before the graph's commands apply"
        );
        Ok(())
    }

    /// Whether low-level servoing is in force.
    pub fn is_low_level(&self) -> bool {
        self.low_level_set && self.cyclic.is_some()
    }

    /// The entry check of low-level mode: `None` before the first position command; then
    /// its state (holding, or passed with its counts).
    pub fn entry_hold(&self) -> Option<&cyclic::EntryHold> {
        self.entry.as_ref()
    }

    /// Whether the entry hold is on: the graph's commands are not applied yet.
    fn entry_holding(&self) -> bool {
        self.entry.as_ref().is_some_and(cyclic::EntryHold::holding)
    }

    /// The low-level position command in force (rad), if in low-level mode.
    pub fn position_command(&self) -> Option<&[f64]> {
        self.cyclic.as_ref().map(CyclicSession::q_cmd)
    }

    /// The reading of a feedback: see [`reading_from_feedback`]; the profile's continuous
    /// joints then unwrapped against the previous reading ([`unwrap_continuous`]).
    fn reading_of(&self, fb: &msg::Feedback) -> Result<Reading, KortexError> {
        let mut r = reading_from_feedback(
            fb,
            self.robot.n_joints(),
            &self.limits,
            self.reading.gripper,
        )
        .map_err(|reason| KortexError::Payload {
            function: Function::RefreshFeedback.name(),
            reason,
        })?;
        unwrap_continuous(
            &mut r,
            &self.reading.q_rad,
            self.robot.continuous_joints(),
            &self.limits,
        );
        Ok(r)
    }

    /// A tick's cyclic feedback (`None`: none arrived) after `period_s` (0: the first
    /// command's reply): the arm's state (an arm in fault is an error), the new reading, and
    /// during the entry hold the entry check against the held position, after it the
    /// following-error check against the position command.
    fn take_cyclic_feedback(
        &mut self,
        fb: Option<&msg::Feedback>,
        period_s: f64,
    ) -> Result<(), KortexError> {
        if let Some(fb) = fb {
            if let Some(b) = fb.base.as_ref()
                && b.active_state == msg::arm_state::IN_FAULT
            {
                return Err(KortexError::ArmInFault {
                    state: b.active_state,
                });
            }
            self.reading = self.reading_of(fb)?;
        }
        let n = self.robot.n_joints();
        let Some(c) = self.cyclic.as_ref() else {
            return Ok(());
        };
        if let Some(hold) = self.entry.as_mut().filter(|h| h.holding()) {
            // The position command is the held one: the entry position.
            let measured = fb.map(|_| &self.reading.q_rad[..n]);
            let step = hold.step(measured, c.q_cmd(), period_s);
            match &step {
                Ok(cyclic::EntryStep::Passed) => tracing::info!(
                    hold_ms = hold.hold_ms(),
                    ticks = hold.ticks(),
                    feedbacks = hold.feedbacks(),
                    worst_rad = hold.worst_rad(),
                    "low-level entry check passed: the arm held the measured position; {} \
                     commands held back during the hold ({} asked for motion); the graph's \
                     commands apply from now on",
                    hold.held_back(),
                    hold.held_back_moving()
                ),
                Ok(cyclic::EntryStep::Holding) => {}
                Err(_) => tracing::warn!(
                    ticks = hold.ticks(),
                    "low-level entry check: {} commands held back before it failed ({} asked \
                     for motion)",
                    hold.held_back(),
                    hold.held_back_moving()
                ),
            }
            return step.map(|_| ());
        }
        if fb.is_some() {
            cyclic::check_following(
                &self.reading.q_rad[..n],
                c.q_cmd(),
                self.following_error_rad,
            )?;
        }
        Ok(())
    }

    /// Back to single-level servoing and the UDP session closed (each awaited; every step
    /// tried, the first error returned).
    fn leave_low_level(&mut self) -> Result<(), KortexError> {
        let mut first_err = None;
        if self.low_level_set && self.connected {
            self.low_level_set = false;
            match self.call(
                Function::SetServoingMode,
                msg::ServoingModeInformation {
                    servoing_mode: msg::servoing_mode::SINGLE_LEVEL,
                }
                .encode_to_vec(),
            ) {
                Ok(_) => tracing::info!("low-level servoing left: back to single-level"),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        if let Some(mut c) = self.cyclic.take()
            && let Err(e) = c.close()
        {
            first_err.get_or_insert(e);
        }
        first_err.map_or(Ok(()), Err)
    }

    /// Low-level ticks: takes the newest cyclic feedback and keeps the TCP session's frames
    /// coming.
    fn advance_low_level(&mut self) -> Result<(), KortexError> {
        let fb = match self.cyclic.as_mut() {
            Some(c) => c.poll()?,
            None => return Err(KortexError::SessionClosed),
        };
        if fb.is_none() {
            self.stats.stale_readings += 1;
        }
        self.take_cyclic_feedback(fb.as_ref(), self.dt)?;
        if self.last_tcp_sent.elapsed() >= TCP_FRAME_EVERY {
            self.queue_feedback_request()?;
            self.flush()?;
            self.last_tcp_sent = Instant::now();
        }
        Ok(())
    }

    /// The client's counters.
    pub fn stats(&self) -> KortexStats {
        self.stats
    }

    /// The session id the robot gave.
    pub fn session_id(&self) -> u16 {
        self.session_id
    }

    /// The robot's joint speed limits the commands are scaled into (rad/s).
    pub fn speed_limits_rad_s(&self) -> &[f64] {
        &self.speed_limit_rad_s[..self.robot.n_joints()]
    }

    /// Whether the session is open (false after a fault or shutdown).
    pub fn is_open(&self) -> bool {
        self.session_open && self.connected
    }

    fn next_id(&mut self) -> u16 {
        let id = self.next_message_id;
        self.next_message_id = if id == u16::MAX { 1 } else { id + 1 };
        id
    }

    /// Sends a request without waiting; returns its message id.
    fn send(&mut self, function: Function, payload: Vec<u8>) -> Result<u16, KortexError> {
        let id = self.queue(function, payload)?;
        self.flush()?;
        Ok(id)
    }

    /// Encodes a request into the output buffer (sent by [`Self::flush`]) and books it as
    /// waiting for its reply; returns its message id.
    fn queue(&mut self, function: Function, payload: Vec<u8>) -> Result<u16, KortexError> {
        if !self.connected {
            return Err(KortexError::SessionClosed);
        }
        let message_id = self.next_id();
        if self.pending.iter().any(|p| p.message_id == message_id) {
            // 65535 requests in flight cannot happen within a reply timeout; refuse anyway.
            return Err(KortexError::ReplyTimeout {
                function: function.name(),
                message_id,
                waited_ms: self.reply_timeout.as_millis() as u64,
                note: "; the message id is still in use".into(),
            });
        }
        let frame = Frame::new(
            FrameType::Request,
            self.session_id,
            message_id,
            function.uid(),
            payload,
        )
        .map_err(|source| KortexError::Encode {
            function: function.name(),
            source,
        })?;
        frame
            .encode_tcp(&mut self.out)
            .map_err(|source| KortexError::Encode {
                function: function.name(),
                source,
            })?;
        self.stats.requests += 1;
        self.pending.push(Pending {
            message_id,
            function,
            sent_tick: self.tick,
            sent_at: Instant::now(),
        });
        Ok(message_id)
    }

    /// Writes the queued requests in one write.
    fn flush(&mut self) -> Result<(), KortexError> {
        if self.out.is_empty() {
            return Ok(());
        }
        let r = self.stream.write_all(&self.out);
        self.out.clear();
        r.map_err(|source| {
            self.connected = false;
            KortexError::Io {
                addr: self.addr,
                during: "sending a request",
                source,
            }
        })
    }

    /// Queues the next feedback request unless one is still waiting for its reply.
    fn queue_feedback_request(&mut self) -> Result<(), KortexError> {
        if self.feedback_pending.is_none() {
            self.feedback_pending = Some(self.queue(Function::RefreshFeedback, Vec::new())?);
            self.feedback_requested_tick = Some(self.tick);
        }
        Ok(())
    }

    /// Sends a request and waits for its reply (start-up and shutdown only).
    fn call(&mut self, function: Function, payload: Vec<u8>) -> Result<Reply, KortexError> {
        let id = self.send(function, payload)?;
        let deadline = Instant::now() + self.reply_timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let ev = match self.events.recv_timeout(left) {
                Ok(ev) => ev,
                Err(RecvTimeoutError::Timeout) => {
                    return Err(self.timeout_error(function, id));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    self.connected = false;
                    return Err(KortexError::Closed { addr: self.addr });
                }
            };
            if let Some(reply) = self.handle(ev)? {
                if reply.pending.message_id == id {
                    return Ok(reply);
                }
                self.take_reply(reply)?;
            }
        }
    }

    fn timeout_error(&self, function: Function, message_id: u16) -> KortexError {
        KortexError::ReplyTimeout {
            function: function.name(),
            message_id,
            waited_ms: self.reply_timeout.as_millis() as u64,
            note: if self.stats.skipped_bytes > 0 {
                format!(
                    "; {} bytes of the stream were skipped to resynchronise (wrong magic)",
                    self.stats.skipped_bytes
                )
            } else {
                String::new()
            },
        }
    }

    /// One event from the reader: a matched reply, nothing (skipped bytes, notifications,
    /// and while closing anything unexpected), or an error.
    fn handle(&mut self, ev: ReaderEvent) -> Result<Option<Reply>, KortexError> {
        let frame = match ev {
            ReaderEvent::Frame(f) => f,
            ReaderEvent::Skipped(n) => {
                self.stats.skipped_bytes += n as u64;
                tracing::warn!(
                    bytes = n,
                    total = self.stats.skipped_bytes,
                    "wrong magic from the robot: bytes skipped to resynchronise"
                );
                return Ok(None);
            }
            ReaderEvent::Bad(source) => {
                if self.closing {
                    return Ok(None);
                }
                return Err(KortexError::Wire {
                    addr: self.addr,
                    source,
                });
            }
            ReaderEvent::Eof => {
                self.connected = false;
                return Err(KortexError::Closed { addr: self.addr });
            }
            ReaderEvent::Truncated { have, need } => {
                self.connected = false;
                return Err(KortexError::Truncated {
                    addr: self.addr,
                    have,
                    need,
                });
            }
            ReaderEvent::Failed(source) => {
                self.connected = false;
                return Err(KortexError::Io {
                    addr: self.addr,
                    during: "reading",
                    source,
                });
            }
        };
        let h = frame.header();
        if h.frame_type() != Some(FrameType::Response) {
            self.stats.other_frames += 1;
            tracing::debug!(
                frame_type = h.frame_type_bits(),
                function = %function_name(h.function_uid()),
                "ignoring a frame that is not a reply"
            );
            return Ok(None);
        }
        let Some(i) = self
            .pending
            .iter()
            .position(|p| p.message_id == h.message_id())
        else {
            if self.closing {
                return Ok(None);
            }
            return Err(KortexError::UnknownReply {
                message_id: h.message_id(),
                function: function_name(h.function_uid()),
            });
        };
        let pending = self.pending.swap_remove(i);
        self.stats.replies += 1;
        if let Some(fault) = frame.error() {
            return Err(KortexError::Robot {
                function: pending.function.name(),
                message_id: pending.message_id,
                fault,
            });
        }
        Ok(Some(Reply { pending, frame }))
    }

    /// Books a reply that arrived in the loop: counts it late if it missed its tick, and takes
    /// a feedback in.
    fn take_reply(&mut self, reply: Reply) -> Result<(), KortexError> {
        if reply.pending.sent_tick < self.tick {
            self.stats.late_replies += 1;
            if self.stats.late_replies <= 10 || self.stats.late_replies.is_power_of_two() {
                tracing::warn!(
                    function = reply.pending.function.name(),
                    message_id = reply.pending.message_id,
                    ticks_late = self.tick - reply.pending.sent_tick,
                    late_replies = self.stats.late_replies,
                    "late reply from the robot"
                );
            }
        }
        if reply.pending.function == Function::RefreshFeedback {
            if self.feedback_pending == Some(reply.pending.message_id) {
                self.feedback_pending = None;
            }
            let fb: msg::Feedback = decode(Function::RefreshFeedback, &reply)?;
            // In low-level mode the reading comes from the cyclic channel.
            if !self.is_low_level() {
                self.reading = self.reading_of(&fb)?;
            }
        }
        Ok(())
    }

    /// Takes in every reply that has arrived, without waiting; then checks reply timeouts.
    fn drain(&mut self) -> Result<(), KortexError> {
        loop {
            match self.events.try_recv() {
                Ok(ev) => {
                    if let Some(reply) = self.handle(ev)? {
                        self.take_reply(reply)?;
                    }
                }
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    self.connected = false;
                    return Err(KortexError::Closed { addr: self.addr });
                }
            }
        }
        if let Some(p) = self
            .pending
            .iter()
            .find(|p| p.sent_at.elapsed() > self.reply_timeout)
            .copied()
        {
            return Err(self.timeout_error(p.function, p.message_id));
        }
        Ok(())
    }

    fn ensure_open(&self) -> Result<(), KortexError> {
        if self.is_open() {
            Ok(())
        } else {
            Err(KortexError::SessionClosed)
        }
    }

    /// Ends the run after `e`: stops the arm and closes the session if the connection still
    /// works, drops the connection, and returns `e` for the caller to report.
    fn fault(&mut self, e: KortexError) -> KortexError {
        if self.session_open && self.connected && e.connection_usable() {
            tracing::error!("{e}; stopping the arm and closing the session");
            if let Err(e2) = self.stop_and_close(false) {
                tracing::warn!(
                    "could not stop the arm and close the session cleanly ({e2}); the robot \
                     stops it when the connection timeout passes"
                );
            }
        } else if self.session_open {
            tracing::error!(
                "{e}; the robot cannot be reached: it stops the arm when the connection \
                 timeout passes"
            );
        }
        self.disconnect();
        e
    }

    /// Stop, optionally a last feedback, CloseSession; each waits for its reply. Returns the
    /// first error but tries every step.
    fn stop_and_close(&mut self, last_feedback: bool) -> Result<(), KortexError> {
        self.closing = true;
        // Replies still in flight are of no interest any more.
        self.pending.clear();
        self.feedback_pending = None;
        let mut first_err = None;
        if let Err(e) = self.leave_low_level() {
            first_err.get_or_insert(e);
        }
        if let Err(e) = self.call(Function::Stop, Vec::new()) {
            first_err.get_or_insert(e);
        }
        if last_feedback
            && self.connected
            && let Ok(reply) = self.call(Function::RefreshFeedback, Vec::new())
            && let Ok(fb) = decode::<msg::Feedback>(Function::RefreshFeedback, &reply)
            && let Ok(r) = self.reading_of(&fb)
        {
            self.reading = r;
        }
        if self.connected
            && let Err(e) = self.call(Function::CloseSession, Vec::new())
        {
            first_err.get_or_insert(e);
        }
        self.session_open = false;
        match first_err {
            None => {
                tracing::info!(
                    address = %self.addr,
                    requests = self.stats.requests,
                    late_replies = self.stats.late_replies,
                    stale_readings = self.stats.stale_readings,
                    skipped_bytes = self.stats.skipped_bytes,
                    "arm stopped; Kortex session closed"
                );
                Ok(())
            }
            Some(e) => Err(e),
        }
    }

    fn disconnect(&mut self) {
        self.session_open = false;
        self.connected = false;
        let _ = self.stream.shutdown(Shutdown::Both);
        if let Some(h) = self.reader.take() {
            let _ = h.join();
        }
    }

    fn in_loop<T>(&mut self, r: Result<T, KortexError>) -> Result<T, RobotError> {
        r.map_err(|e| RobotError::Kortex(self.fault(e)))
    }
}

/// The arm reports every angle in `[0, 360)`, which [`reading_from_feedback`] brings to
/// `(-π, π]`; a continuous joint (`continuous[j]`, one the arm turns past a half turn, such as
/// the Gen3's joints 1, 3, 5 and 7) may be anywhere within its software limits, so its
/// reading is the angle nearest to its previous one `prev_rad` (no jump of 2π when it turns
/// past ±π), and flags the limit as [`reading_from_feedback`] does. The first reading is
/// unwrapped against zero: in `(-π, π]`.
pub fn unwrap_continuous(
    r: &mut Reading,
    prev_rad: &[f64],
    continuous: &[bool],
    limits: &ArmLimits,
) {
    for (j, (&c, &prev)) in continuous.iter().zip(prev_rad).enumerate() {
        if !c {
            continue;
        }
        let d = super::wrap_deg((r.q_rad[j] - prev).to_degrees()).to_radians();
        r.q_rad[j] = prev + d;
        if let (Some(lo), Some(hi)) = (limits.lower_rad.get(j), limits.upper_rad.get(j))
            && (r.q_rad[j] <= lo + 0.01 || r.q_rad[j] >= hi - 0.01)
        {
            r.at_limit = true;
        }
    }
}

fn decode<M: prost::Message + Default>(
    function: Function,
    reply: &Reply,
) -> Result<M, KortexError> {
    M::decode(reply.frame.payload.as_slice()).map_err(|e| KortexError::Payload {
        function: function.name(),
        reason: e.to_string(),
    })
}

fn speed_limits_from(
    limits: &msg::KinematicLimits,
    n: usize,
) -> Result<[f64; MAX_JOINTS], KortexError> {
    if limits.joint_speed_limits.len() != n {
        return Err(KortexError::Limits {
            reason: format!(
                "{} joint speed limits for {n} joints",
                limits.joint_speed_limits.len()
            ),
        });
    }
    let mut out = [0.0; MAX_JOINTS];
    for (j, v) in limits.joint_speed_limits.iter().enumerate() {
        let v = f64::from(*v);
        if !(v.is_finite() && v > 0.0) {
            return Err(KortexError::Limits {
                reason: format!("joint {j} speed limit is {v} deg/s"),
            });
        }
        out[j] = v.to_radians();
    }
    Ok(out)
}

impl Robot for KortexArm {
    fn n_joints(&self) -> usize {
        self.robot.n_joints()
    }

    fn advance(&mut self, dt: f64) -> Result<Reading, RobotError> {
        let r = self.ensure_open();
        self.in_loop(r)?;
        self.dt = dt;
        let r = self.drain();
        self.in_loop(r)?;
        if self.is_low_level() {
            self.tick += 1;
            let r = self.advance_low_level();
            self.in_loop(r)?;
            return Ok(self.reading);
        }
        let previous = self.tick;
        self.tick += 1;
        if self.feedback_pending.is_some() {
            // The feedback asked for in the previous tick has not arrived.
            self.stats.stale_readings += 1;
        } else if self.feedback_requested_tick != Some(previous) {
            // No command or stop asked for one in the previous tick (the first tick): ask now.
            let r = self.queue_feedback_request().and_then(|()| self.flush());
            self.in_loop(r)?;
        }
        Ok(self.reading)
    }

    fn command(&mut self, qdot_rad_s: &[f64], gripper_rate: f64) -> Result<(), RobotError> {
        let r = self.ensure_open();
        self.in_loop(r)?;
        let n = self.robot.n_joints();
        let mut v = [0.0; MAX_JOINTS];
        let m = n.min(qdot_rad_s.len());
        v[..m].copy_from_slice(&qdot_rad_s[..m]);
        if scale_to_limits(&mut v[..n], &self.speed_limit_rad_s[..n]) < 1.0 {
            self.stats.clamped_commands += 1;
        }
        if self.is_low_level() {
            if gripper_rate.is_finite() && gripper_rate != 0.0 && !self.gripper_warned {
                // The reference names no cyclic gripper command: none is sent.
                self.gripper_warned = true;
                tracing::warn!("low-level mode: gripper commands are not sent (the gripper holds)");
            }
            // During the entry hold the command (the graph's, or a controlled stop's ramp) is
            // counted, not applied: the held position goes out again.
            let holding = self.entry_holding();
            if holding && let Some(h) = self.entry.as_mut() {
                h.hold_back(&v[..n]);
            }
            let (dt, limits) = (self.dt, &self.limits);
            let r = match self.cyclic.as_mut() {
                Some(c) if holding => c.refresh(),
                Some(c) => c.command(&v[..n], dt, limits),
                None => Err(KortexError::SessionClosed),
            };
            return self.in_loop(r);
        }
        let payload = joint_speeds_msg(&v[..n]).encode_to_vec();
        let r = self.queue(Function::SendJointSpeedsCommand, payload);
        self.in_loop(r)?;
        if gripper_rate.is_finite() {
            self.gripper_target = (self.gripper_target + gripper_rate * self.dt).clamp(0.0, 1.0);
        }
        if (self.gripper_target - self.gripper_sent).abs() > GRIPPER_EPS {
            let payload = gripper_position_msg(self.gripper_target).encode_to_vec();
            let r = self.queue(Function::SendGripperCommand, payload);
            self.in_loop(r)?;
            self.gripper_sent = self.gripper_target;
            self.stats.gripper_commands += 1;
        }
        // The next tick's feedback, in the same write.
        let r = self.queue_feedback_request().and_then(|()| self.flush());
        self.in_loop(r)
    }

    fn stop(&mut self) -> Result<(), RobotError> {
        let r = self.ensure_open();
        self.in_loop(r)?;
        if self.is_low_level() {
            // Holds the commanded position.
            let r = match self.cyclic.as_mut() {
                Some(c) => c.refresh(),
                None => Err(KortexError::SessionClosed),
            };
            return self.in_loop(r);
        }
        let r = self
            .queue(Function::Stop, Vec::new())
            .and_then(|_| self.queue_feedback_request())
            .and_then(|()| self.flush());
        self.in_loop(r)
    }

    fn shutdown(&mut self) -> Result<Reading, RobotError> {
        if !self.is_open() {
            self.disconnect();
            return Ok(self.reading);
        }
        let r = self.stop_and_close(true);
        self.disconnect();
        r?;
        Ok(self.reading)
    }

    fn is_mock(&self) -> bool {
        false
    }

    fn link_stats(&self) -> LinkStats {
        LinkStats {
            requests: self.stats.requests,
            late_replies: self.stats.late_replies,
            stale_readings: self.stats.stale_readings,
            skipped_bytes: self.stats.skipped_bytes,
            clamped_commands: self.stats.clamped_commands,
        }
    }
}

impl Drop for KortexArm {
    fn drop(&mut self) {
        if self.is_open() {
            tracing::warn!("Kortex client dropped with its session open: stopping the arm");
            if let Err(e) = self.stop_and_close(false) {
                tracing::warn!("{e}");
            }
        }
        self.disconnect();
    }
}
