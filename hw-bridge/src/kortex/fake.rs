//! [`FakeKortex`]: a fake Kinova arm that speaks the Kortex protocol on loopback, for tests and
//! for trying the bridge without an arm (`scl fake-kortex`).
//!
//! It plays the arm of a robot profile ([`FakeConfig::robot`]; the Gen3 lite by default,
//! [`FakeConfig::for_robot`] for another): the profile's actuator count, joint position limits
//! (the simulated arm's), joint speed and acceleration limits (GetKinematicHardLimits), joint
//! arrays of the profile's length in every message, on both channels, and its Kortex model in
//! GetProductConfiguration ([`super::KortexModel`]).
//!
//! It listens on `127.0.0.1` only, keeps a kinematic simulation of the arm ([`MockArm`],
//! brought up to the present whenever it is looked at, since a real robot moves by itself),
//! checks the credentials, serves the calls the bridge makes, and enforces the session's
//! connection inactivity timeout: a watchdog thread sleeps until the deadline and, if no frame
//! has arrived for that long, stops the arm, as the robot does. A closed connection alone does
//! not stop the arm (the worst case: only the timeout does); the next frame re-arms the watchdog.
//! A new session from another connection (a restarted bridge) does not cancel the old one's
//! timeout: it still stops the motion the old session started, unless the new session has
//! commanded since. The session itself ends after the session inactivity timeout.
//!
//! Several sessions may be open at once, each on its own connection (at most
//! [`MAX_SESSIONS`]): the bridge's, and observing ones beside it (Kinova's Web App or Python
//! tools reading the arm's state). A session that only made read-only calls (the `Get...`
//! calls, RefreshFeedback, KeepAlive) observes: its connection timeout and its CloseSession
//! leave the arm alone. A session that made any other call (servoing mode, faults, a motion
//! command, a stop) controls: its connection timeout stops the motion it started (not one a
//! session that commanded since started) and its CloseSession stops the arm.
//!
//! Served over TCP: Session.CreateSession / CloseSession / KeepAlive; Base.Stop,
//! ApplyEmergencyStop, ClearFaults, SetServoingMode (single-level, low-level),
//! GetServoingMode, GetActuatorCount, GetArmState, GetMeasuredJointAngles,
//! SendJointSpeedsCommand, SendGripperCommand (position mode, finger 1),
//! GetProductConfiguration (the model and degrees of freedom of the profile's arm);
//! BaseCyclic.RefreshFeedback; ControlConfig.GetKinematicHardLimits;
//! DeviceConfig.GetFirmwareVersion. Not served (answered with a protocol-server error naming
//! the function): every other call, among them notifications (`OnNotification...Topic`),
//! actions and trajectories, Cartesian commands and poses, twist commands, the device
//! manager (`DeviceManager.ReadAllDevices`), actuator and interconnect configuration, user
//! profiles, and servoing mode bypass.
//!
//! Like a robot left in another servoing mode by a previous client, the fake starts in no
//! servoing mode a client may rely on: it refuses joint speed and gripper commands with a device
//! error until a session sets single-level servoing (`Base.SetServoingMode`). It records every
//! request it receives ([`FakeKortex::request_log`]) and the inactivity timeouts of the last
//! session opened ([`FakeSnapshot::connection_timeout_ms`]), so tests can check what the client
//! sent and in which order.
//!
//! Threads: the watchdog, a blocking accept loop, one thread per connection that reads,
//! answers, and holds delayed replies until they are due, and the cyclic channel's UDP thread
//! (which also watches for the missing cyclic command). They sleep unless something happens,
//! so the fake takes little from the processes it is tested with.
//!
//! Faults can be injected ([`FakeKortex::inject`]): drop or delay a reply, close the
//! connection, answer with an error frame, send garbage before a reply, damage a reply's magic,
//! cut a reply short, answer with an unknown message id.
//!
//! Low-level servoing: the fake also listens on UDP ([`FakeKortex::cyclic_addr`]; by default
//! the same port number as TCP) for the cyclic channel's own session (CreateSession,
//! CloseSession, `BaseCyclic.Refresh`, `BaseCyclic.RefreshFeedback`, bare frames). After
//! `Base.SetServoingMode(low-level)` it refuses joint speed and gripper commands, takes each
//! Refresh's joint positions as the arm's new position (unless [`FakeKortex::block_arm`] holds
//! it, for following-error tests) and answers with the feedback. The arm's own reaction to a
//! missing cyclic command: if no Refresh arrives within [`FakeConfig::cyclic_timeout`] while in
//! low-level servoing, the arm stops where it is and goes into fault (feedback active state
//! "in fault"; further Refreshes are refused with "robot in fault", sub-code 22, until
//! `Base.ClearFaults`). The reference gives neither the real arm's timeout nor its exact
//! reaction; this is the conservative reading (it stops and demands attention).
//!
//! For tests of the bridge's entry check, the fake can misread the cyclic command
//! ([`FakeConfig::cyclic_misread`], `scl fake-kortex --misread-cyclic`): a robot that reads it
//! differently than the bridge means. The arm then servos towards the misread position at its
//! joint speed limits (a position loop does not jump), so the error grows over a few ticks.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, Shutdown, SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ipc_types::MAX_JOINTS;
use kinematics::RobotProfile;
use prost::Message as _;

use super::wire::{Decoded, ErrorPayload, Frame, FrameDecoder, FrameType, Header, MAGIC};
use super::{Credentials, FoundRobot, Function, angle_rad_to_wire_deg, msg};
use crate::Reading;
use crate::mock::{MockArm, MockConfig, MockConfigError};

/// Sessions open at once, at most (a further CreateSession is refused).
pub const MAX_SESSIONS: usize = 8;

/// The longest the watchdog sleeps (so that shutting down is prompt).
const WATCHDOG_MAX_SLEEP: Duration = Duration::from_millis(50);

/// Joint speed commands kept in the log (about eight minutes at 40 Hz); also the number of
/// requests kept in the request log.
const LOG_CAPACITY: usize = 20_000;

/// Settings of the fake robot.
#[derive(Debug, Clone)]
pub struct FakeConfig {
    /// TCP port on 127.0.0.1; 0 takes a free one ([`FakeKortex::addr`] tells which).
    pub port: u16,
    /// The credentials it accepts.
    pub credentials: Credentials,
    /// The arm it plays: its joints (every joint array, both channels), position limits (the
    /// simulated arm's) and named poses ([`MockConfig::initial_pose`]).
    pub robot: &'static RobotProfile,
    /// What GetActuatorCount answers (the profile's joint count; other values test the
    /// bridge).
    pub actuator_count: u32,
    /// What GetProductConfiguration answers for the model ([`msg::model_id`]: the profile's
    /// Kortex model; 0, not reported, as older firmware may; other values test the bridge).
    pub model: i32,
    /// What GetKinematicHardLimits answers for the joint speeds (deg/s).
    pub joint_speed_limits_deg_s: Vec<f32>,
    /// What GetKinematicHardLimits answers for the joint accelerations (deg/s²).
    pub joint_acceleration_limits_deg_s2: Vec<f32>,
    /// What DeviceConfig.GetFirmwareVersion answers.
    pub firmware_version: u32,
    /// The simulated arm.
    pub mock: MockConfig,
    /// UDP port of the cyclic channel on 127.0.0.1: `None` takes the TCP port's number,
    /// `Some(0)` a free one ([`FakeKortex::cyclic_addr`] tells which).
    pub cyclic_port: Option<u16>,
    /// In low-level servoing, the arm faults when no Refresh arrives for this long. The
    /// reference does not give the real arm's figure; 50 ms is the fake's choice.
    pub cyclic_timeout: Duration,
    /// Misread the cyclic command (tests of the bridge's entry check); `None`: read it as the
    /// bridge means it.
    pub cyclic_misread: Option<CyclicMisread>,
}

/// How the fake robot misreads a `BaseCyclic.Refresh` command: what a robot that reads the
/// command's layout differently than the bridge would do. The arm servos towards the misread
/// position at its joint speed limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CyclicMisread {
    /// Every actuator's position read as 0° (as if it came from a field the bridge leaves at
    /// 0, such as the velocity).
    ZeroPosition,
    /// One joint's position read `offset_rad` off (a wrong zero or unit).
    Offset {
        /// The joint (0-based).
        joint: usize,
        /// The offset (rad).
        offset_rad: f64,
    },
}

impl CyclicMisread {
    /// The position the fake reads from the commanded `q_rad` (in place).
    pub fn apply(&self, q_rad: &mut [f64]) {
        match *self {
            Self::ZeroPosition => q_rad.iter_mut().for_each(|q| *q = 0.0),
            Self::Offset { joint, offset_rad } => {
                if let Some(q) = q_rad.get_mut(joint) {
                    *q += offset_rad;
                }
            }
        }
    }
}

impl std::str::FromStr for CyclicMisread {
    type Err = String;

    /// `zero`, or `offset:JOINT:RAD` (e.g. `offset:3:0.02`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let usage = || {
            format!(
                "`{s}` is not a cyclic misread: use `zero` or `offset:JOINT:RAD` (e.g. offset:3:0.02)"
            )
        };
        if s == "zero" {
            return Ok(Self::ZeroPosition);
        }
        let mut parts = s.split(':');
        match (parts.next(), parts.next(), parts.next(), parts.next()) {
            (Some("offset"), Some(j), Some(r), None) => {
                let joint: usize = j.parse().map_err(|_| usage())?;
                let offset_rad: f64 = r.parse().map_err(|_| usage())?;
                // The arm's own joint count is checked when the fake starts.
                if joint >= MAX_JOINTS || !offset_rad.is_finite() {
                    return Err(usage());
                }
                Ok(Self::Offset { joint, offset_rad })
            }
            _ => Err(usage()),
        }
    }
}

impl Default for FakeConfig {
    /// [`FakeConfig::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

impl FakeConfig {
    /// A fake of the arm of `robot`, on a free port, accepting admin / admin: the profile's
    /// actuator count and Kortex model, its URDF velocity limits as the joint speed hard
    /// limits and its acceleration limits (both in deg/s and deg/s², as the robot reports
    /// them), the simulated arm at its `home` pose.
    pub fn for_robot(robot: &'static RobotProfile) -> Self {
        let found = FoundRobot::of_profile(robot);
        let deg = |v: &[f64]| v.iter().map(|v| v.to_degrees() as f32).collect();
        Self {
            port: 0,
            credentials: Credentials::new("admin", "admin"),
            robot,
            actuator_count: found.actuators,
            model: found.model,
            joint_speed_limits_deg_s: deg(robot.urdf_velocity_rad_s()),
            joint_acceleration_limits_deg_s2: deg(&robot.limits().max_acceleration_rad_s2),
            firmware_version: 0x02_03_00,
            mock: MockConfig::for_robot(robot),
            cyclic_port: None,
            cyclic_timeout: Duration::from_millis(50),
            cyclic_misread: None,
        }
    }
}

/// A fault to inject into the fake's next reply (to the next request of a given function, or
/// of any function).
#[derive(Debug, Clone, PartialEq)]
pub enum Fault {
    /// The request is executed but not answered.
    DropReply,
    /// The reply is sent this much later (the stream behind it waits too).
    DelayReply(Duration),
    /// The connection is closed instead of answering (a reset, for the client).
    CloseConnection,
    /// The request is not executed; an error frame answers it.
    ErrorReply {
        /// Error code (1 protocol server, 2 protocol client, 3 device, 4 internal).
        code: u8,
        /// Sub-code (12 invalid session, 15 invalid password, 22 robot in fault, ...).
        sub_code: u16,
        /// The error's text.
        detail: String,
    },
    /// These bytes go out before the reply (garbage: a wrong magic for the client).
    GarbageBefore(Vec<u8>),
    /// The reply goes out with a damaged magic.
    CorruptMagic,
    /// Only the first this-many bytes of the reply go out, then the connection is closed.
    TruncateReply(usize),
    /// The reply carries a message id no request had.
    WrongMessageId,
}

/// Counters of the fake robot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeStats {
    /// Connections accepted.
    pub connections: u64,
    /// Frames received.
    pub frames: u64,
    /// Sessions opened.
    pub sessions_opened: u64,
    /// Sessions closed by CloseSession.
    pub sessions_closed: u64,
    /// Sessions ended by the session inactivity timeout.
    pub sessions_expired: u64,
    /// Times the connection inactivity timeout stopped the arm.
    pub connection_timeouts: u64,
    /// Stop (and ApplyEmergencyStop) requests.
    pub stops: u64,
    /// Joint speed commands executed.
    pub joint_speed_commands: u64,
    /// Gripper commands executed.
    pub gripper_commands: u64,
    /// Feedback requests answered.
    pub feedback_requests: u64,
    /// Error frames sent.
    pub error_replies: u64,
    /// Injected faults applied.
    pub faults_fired: u64,
    /// Bytes from clients skipped to resynchronise.
    pub skipped_bytes: u64,
    /// Joint speed or gripper commands refused because single-level servoing was not set.
    pub refused_not_servoing: u64,
    /// Cyclic (UDP) sessions opened.
    pub cyclic_sessions_opened: u64,
    /// Cyclic (UDP) sessions closed by CloseSession.
    pub cyclic_sessions_closed: u64,
    /// `BaseCyclic.Refresh` commands executed.
    pub refreshes: u64,
    /// Times a missing cyclic command put the arm in fault.
    pub cyclic_timeouts: u64,
}

/// A request the fake robot received, in the order of arrival ([`FakeKortex::request_log`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FakeRequest {
    /// The function UID of its header: `(service id << 16) | function id`.
    pub function_uid: u32,
    /// Its message id.
    pub message_id: u16,
    /// The session id of its header (0 before CreateSession answered).
    pub session_id: u16,
}

impl FakeRequest {
    /// The function requested, if the bridge knows it.
    pub fn function(&self) -> Option<Function> {
        Function::from_uid(self.function_uid)
    }
}

/// What the fake robot looks like now. Joint lists have one entry per joint of the profile.
#[derive(Debug, Clone, PartialEq)]
pub struct FakeSnapshot {
    /// Joint angles (rad).
    pub q_rad: Vec<f64>,
    /// Joint speeds (rad/s).
    pub qdot_rad_s: Vec<f64>,
    /// Gripper position (0 open .. 1 closed).
    pub gripper: f64,
    /// The gripper's commanded position.
    pub gripper_target: f64,
    /// The joint speed command in force (rad/s).
    pub command_in_force: Vec<f64>,
    /// A session exists.
    pub session_open: bool,
    /// Sessions open now (the bridge's and observing ones).
    pub open_sessions: usize,
    /// The counters.
    pub stats: FakeStats,
    /// At the last connection timeout: how long it had been since the last frame.
    pub last_timeout_gap: Option<Duration>,
    /// Time since the last frame of the newest session's connection.
    pub since_last_frame: Option<Duration>,
    /// The connection inactivity timeout (ms) the last session opened was created with, as the
    /// client sent it (0: none); `None` before any session. Kept after the session ends.
    pub connection_timeout_ms: Option<u32>,
    /// The session inactivity timeout (ms) the last session opened was created with, as the
    /// client sent it (0: none); `None` before any session. Kept after the session ends.
    pub session_timeout_ms: Option<u32>,
    /// Single-level servoing is set (joint speed and gripper commands are accepted).
    pub single_level_servoing: bool,
    /// Low-level servoing is set (Refresh commands are accepted).
    pub low_level_servoing: bool,
    /// The arm is in fault (until ClearFaults).
    pub in_fault: bool,
    /// The joint positions of the first Refresh of the last low-level entry (rad).
    pub first_position_command: Option<Vec<f64>>,
    /// The joint positions of the last Refresh (rad).
    pub last_position_command: Option<Vec<f64>>,
    /// A cyclic (UDP) session exists.
    pub cyclic_session_open: bool,
}

impl FakeSnapshot {
    /// Whether a non-zero joint speed command is in force.
    pub fn commanded_to_move(&self) -> bool {
        self.command_in_force.iter().any(|v| *v != 0.0)
    }
}

/// Why the fake robot could not start.
#[derive(Debug, thiserror::Error)]
pub enum FakeError {
    /// The simulated arm's settings are unusable.
    #[error(transparent)]
    Mock(#[from] MockConfigError),
    /// The port could not be bound.
    #[error("fake Kortex robot: cannot listen on 127.0.0.1:{port}: {source}")]
    Bind {
        /// The port asked for.
        port: u16,
        /// The OS error.
        source: std::io::Error,
    },
    /// A thread could not be started.
    #[error("fake Kortex robot: cannot start a thread: {0}")]
    Thread(std::io::Error),
    /// The cyclic misread names a joint the arm does not have.
    #[error(
        "fake Kortex robot: the cyclic misread names joint {joint} (0-based), but a {robot} has \
         {n} joints"
    )]
    MisreadJoint {
        /// The joint named.
        joint: usize,
        /// The profile's arm, as people call it.
        robot: String,
        /// Its joint count.
        n: usize,
    },
}

struct Session {
    id: u16,
    conn: u64,
    connection_timeout: Option<Duration>,
    session_timeout: Option<Duration>,
    last_frame: Instant,
    timed_out: bool,
    /// It made a call that is not read-only ([`read_only`]).
    controls: bool,
    /// Its connection is closed: the session lives on until its session timeout, or until a
    /// new session needs its place once its connection timeout has fired.
    closed: bool,
}

struct State {
    /// Joints of the profile's arm.
    n: usize,
    arm: MockArm,
    reading: Reading,
    last_step: Instant,
    /// The open sessions, oldest first.
    sessions: Vec<Session>,
    /// The session whose joint speeds are in force.
    command_from: Option<u16>,
    next_session_id: u16,
    faults: VecDeque<(Option<Function>, Fault)>,
    stats: FakeStats,
    last_timeout_gap: Option<Duration>,
    log: VecDeque<[f64; MAX_JOINTS]>,
    requests: VecDeque<FakeRequest>,
    /// (connection, session) inactivity timeouts (ms) of the last CreateSession that opened a
    /// session.
    created_timeouts_ms: Option<(u32, u32)>,
    /// Robot-wide, as on the real arm: it outlives sessions.
    single_level_servoing: bool,
    low_level_servoing: bool,
    in_fault: bool,
    /// The cyclic session (id, peer).
    cyclic: Option<(u16, SocketAddr)>,
    /// The last Refresh (or the entry into low-level servoing).
    last_refresh: Instant,
    /// Joint speeds implied by the last two Refreshes (rad/s).
    cyclic_qdot: [f64; MAX_JOINTS],
    arm_blocked: bool,
    first_cmd: Option<[f64; MAX_JOINTS]>,
    last_cmd: Option<[f64; MAX_JOINTS]>,
}

struct Shared {
    cfg: FakeConfig,
    stop: AtomicBool,
    next_conn: AtomicU64,
    state: Mutex<State>,
    threads: Mutex<Vec<JoinHandle<()>>>,
    /// A handle on every open connection, to shut them down when the fake stops.
    conns: Mutex<Vec<(u64, TcpStream)>>,
}

impl Shared {
    /// The state, with the simulated arm brought up to now.
    fn state(&self) -> MutexGuard<'_, State> {
        let mut st = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        let now = Instant::now();
        let dt = now.duration_since(st.last_step).as_secs_f64();
        if dt > 0.0 {
            st.reading = st.arm.step(dt);
            st.last_step = now;
        }
        st
    }

    fn conns(&self) -> MutexGuard<'_, Vec<(u64, TcpStream)>> {
        self.conns.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// A running fake robot; stops its threads when dropped.
pub struct FakeKortex {
    addr: SocketAddr,
    cyclic_addr: SocketAddr,
    shared: Arc<Shared>,
}

impl std::fmt::Debug for FakeKortex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FakeKortex")
            .field("addr", &self.addr)
            .finish_non_exhaustive()
    }
}

impl FakeKortex {
    /// Starts the fake robot on `127.0.0.1:cfg.port`.
    pub fn start(cfg: FakeConfig) -> Result<Self, FakeError> {
        let n = cfg.robot.n_joints();
        if let Some(CyclicMisread::Offset { joint, .. }) = cfg.cyclic_misread
            && joint >= n
        {
            return Err(FakeError::MisreadJoint {
                joint,
                robot: cfg.robot.description().to_owned(),
                n,
            });
        }
        let mut arm = MockArm::for_robot(cfg.robot, cfg.mock.clone())?;
        let reading = arm.step(1e-9);
        let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, cfg.port)).map_err(|source| {
            FakeError::Bind {
                port: cfg.port,
                source,
            }
        })?;
        let bind_err = |source| FakeError::Bind {
            port: cfg.port,
            source,
        };
        let addr = listener.local_addr().map_err(bind_err)?;
        let udp_port = cfg.cyclic_port.unwrap_or(addr.port());
        let udp = match UdpSocket::bind((Ipv4Addr::LOCALHOST, udp_port)) {
            // A free TCP port whose number is taken on UDP: any free UDP port.
            Err(_) if cfg.port == 0 && cfg.cyclic_port.is_none() => {
                UdpSocket::bind((Ipv4Addr::LOCALHOST, 0))
            }
            r => r,
        }
        .map_err(|source| FakeError::Bind {
            port: udp_port,
            source,
        })?;
        let cyclic_addr = udp.local_addr().map_err(|source| FakeError::Bind {
            port: udp_port,
            source,
        })?;
        let shared = Arc::new(Shared {
            cfg,
            stop: AtomicBool::new(false),
            next_conn: AtomicU64::new(1),
            state: Mutex::new(State {
                n,
                arm,
                reading,
                last_step: Instant::now(),
                sessions: Vec::new(),
                command_from: None,
                next_session_id: 0x1234,
                faults: VecDeque::new(),
                stats: FakeStats::default(),
                last_timeout_gap: None,
                log: VecDeque::new(),
                requests: VecDeque::new(),
                created_timeouts_ms: None,
                single_level_servoing: false,
                low_level_servoing: false,
                in_fault: false,
                cyclic: None,
                last_refresh: Instant::now(),
                cyclic_qdot: [0.0; MAX_JOINTS],
                arm_blocked: false,
                first_cmd: None,
                last_cmd: None,
            }),
            threads: Mutex::new(Vec::new()),
            conns: Mutex::new(Vec::new()),
        });
        let fake = Self {
            addr,
            cyclic_addr,
            shared,
        };
        let sh = fake.shared.clone();
        fake.spawn("fake-kortex-watchdog", move || watchdog_loop(sh))?;
        let sh = fake.shared.clone();
        fake.spawn("fake-kortex-cyclic", move || cyclic_loop(sh, udp))?;
        let sh = fake.shared.clone();
        fake.spawn("fake-kortex-accept", move || accept_loop(sh, listener))?;
        tracing::info!(
            address = %addr,
            robot = fake.shared.cfg.robot.name(),
            "fake Kortex robot listening"
        );
        Ok(fake)
    }

    fn spawn(&self, name: &str, f: impl FnOnce() + Send + 'static) -> Result<(), FakeError> {
        let h = std::thread::Builder::new()
            .name(name.into())
            .spawn(f)
            .map_err(FakeError::Thread)?;
        self.shared
            .threads
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(h);
        Ok(())
    }

    /// The address it listens on (always 127.0.0.1).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The UDP address of the cyclic channel (always 127.0.0.1).
    pub fn cyclic_addr(&self) -> SocketAddr {
        self.cyclic_addr
    }

    /// Holds the arm where it is whatever the position commands say (an obstacle, a blocked
    /// joint): what the bridge's following-error check must catch.
    pub fn block_arm(&self, blocked: bool) {
        self.shared.state().arm_blocked = blocked;
    }

    /// Moves the arm by `delta_rad` at once (a push, a collision), kept inside the limits.
    /// With [`FakeKortex::block_arm`] it stays there whatever the commands say.
    pub fn push_arm(&self, delta_rad: &[f64]) {
        let mut st = self.shared.state();
        let mut q = st.reading.q_rad;
        for (q, d) in q.iter_mut().zip(delta_rad) {
            *q += d;
        }
        let gripper = st.reading.gripper;
        st.arm.resume(&q, gripper);
        st.reading = st.arm.step(1e-9);
    }

    /// Puts joint speeds `qdot_rad_s` in force as if another client had commanded them (for
    /// tests of what may only start from rest).
    pub fn set_joint_speeds(&self, qdot_rad_s: &[f64]) {
        self.shared.state().arm.set_command(qdot_rad_s, 0.0);
    }

    /// Queues `fault` for the next request of `on` (any function if `None`).
    pub fn inject(&self, fault: Fault, on: Option<Function>) {
        self.shared.state().faults.push_back((on, fault));
    }

    /// The arm and the counters now.
    pub fn snapshot(&self) -> FakeSnapshot {
        let st = self.shared.state();
        let n = st.n;
        FakeSnapshot {
            q_rad: st.reading.q_rad[..n].to_vec(),
            qdot_rad_s: st.reading.qdot_rad_s[..n].to_vec(),
            gripper: st.reading.gripper,
            gripper_target: st.arm.gripper_target(),
            command_in_force: st.arm.command_in_force()[..n].to_vec(),
            session_open: !st.sessions.is_empty(),
            open_sessions: st.sessions.len(),
            stats: st.stats,
            last_timeout_gap: st.last_timeout_gap,
            since_last_frame: st.sessions.last().map(|s| s.last_frame.elapsed()),
            connection_timeout_ms: st.created_timeouts_ms.map(|(c, _)| c),
            session_timeout_ms: st.created_timeouts_ms.map(|(_, s)| s),
            single_level_servoing: st.single_level_servoing,
            low_level_servoing: st.low_level_servoing,
            in_fault: st.in_fault,
            first_position_command: st.first_cmd.map(|q| q[..n].to_vec()),
            last_position_command: st.last_cmd.map(|q| q[..n].to_vec()),
            cyclic_session_open: st.cyclic.is_some(),
        }
    }

    /// The arm it plays.
    pub fn robot(&self) -> &'static RobotProfile {
        self.shared.cfg.robot
    }

    /// The joint speed commands executed, oldest first (rad/s, as decoded from deg/s; one
    /// entry per joint), up to the last 20 000.
    pub fn joint_speed_log(&self) -> Vec<Vec<f64>> {
        let st = self.shared.state();
        st.log.iter().map(|v| v[..st.n].to_vec()).collect()
    }

    /// The requests received, oldest first (every connection, whatever the fake answered, up
    /// to the last 20 000).
    pub fn request_log(&self) -> Vec<FakeRequest> {
        self.shared.state().requests.iter().copied().collect()
    }

    /// Stops the fake robot and waits for its threads.
    pub fn shutdown(self) {
        drop(self);
    }
}

impl Drop for FakeKortex {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        // Wake the blocking accept and every blocking read.
        let _ = TcpStream::connect(self.addr);
        for (_, c) in self.shared.conns().iter() {
            let _ = c.shutdown(Shutdown::Both);
        }
        loop {
            let h = self
                .shared
                .threads
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .pop();
            match h {
                Some(h) => {
                    let _ = h.join();
                }
                None => break,
            }
        }
    }
}

fn watchdog_loop(sh: Arc<Shared>) {
    while !sh.stop.load(Ordering::SeqCst) {
        let sleep = {
            let mut st = sh.state();
            watchdog_step(&mut st, Instant::now()).map_or(WATCHDOG_MAX_SLEEP, |due| {
                // Just past the deadline, so that the gap is over the timeout when it wakes.
                (due.saturating_duration_since(Instant::now()) + Duration::from_micros(200))
                    .min(WATCHDOG_MAX_SLEEP)
            })
        };
        std::thread::sleep(sleep);
    }
}

/// The robot's watchdogs at `now`: each session's connection inactivity timeout (it stops the
/// motion the session started, if it controls and no other open session has commanded
/// since), then each session's inactivity timeout (the session ends). Returns the next
/// deadline.
fn watchdog_step(st: &mut State, now: Instant) -> Option<Instant> {
    let mut next: Option<Instant> = None;
    let mut soonest = |due: Instant| next = Some(next.map_or(due, |n: Instant| n.min(due)));
    for i in 0..st.sessions.len() {
        let s = &st.sessions[i];
        let Some(t) = s.connection_timeout.filter(|_| !s.timed_out) else {
            continue;
        };
        let gap = now.duration_since(s.last_frame);
        if gap <= t {
            soonest(s.last_frame + t);
            continue;
        }
        let (id, controls) = (s.id, s.controls);
        st.sessions[i].timed_out = true;
        // Another open session that commanded since has taken the arm over.
        let taken_over = st
            .command_from
            .is_some_and(|c| c != id && st.sessions.iter().any(|o| o.id == c));
        if controls && !taken_over {
            st.arm.halt();
            st.stats.connection_timeouts += 1;
            st.last_timeout_gap = Some(gap);
            tracing::warn!(
                session = format_args!("{id:#06x}"),
                "fake Kortex: no frame for {} ms: connection inactivity timeout, arm stopped",
                gap.as_millis()
            );
        }
    }
    let before = st.sessions.len();
    st.sessions.retain(|s| {
        let gap = now.duration_since(s.last_frame);
        match s.session_timeout {
            Some(t) if gap > t => {
                tracing::warn!("fake Kortex: no frame for {gap:?}: session timed out");
                false
            }
            Some(t) => {
                soonest(s.last_frame + t);
                true
            }
            None => true,
        }
    });
    st.stats.sessions_expired += (before - st.sessions.len()) as u64;
    next
}

/// Whether a call only reads (an observing session's calls).
fn read_only(function: Function) -> bool {
    matches!(
        function,
        Function::CreateSession
            | Function::CloseSession
            | Function::KeepAlive
            | Function::GetMeasuredJointAngles
            | Function::GetActuatorCount
            | Function::GetArmState
            | Function::GetServoingMode
            | Function::GetProductConfiguration
            | Function::GetKinematicHardLimits
            | Function::GetFirmwareVersion
            | Function::RefreshFeedback
    )
}

fn accept_loop(sh: Arc<Shared>, listener: TcpListener) {
    let mut conns: Vec<JoinHandle<()>> = Vec::new();
    for stream in listener.incoming() {
        if sh.stop.load(Ordering::SeqCst) {
            break;
        }
        let stream = match stream {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("fake Kortex: accept failed: {e}");
                std::thread::sleep(Duration::from_millis(5));
                continue;
            }
        };
        let conn = sh.next_conn.fetch_add(1, Ordering::SeqCst);
        let peer = stream.peer_addr().ok();
        sh.state().stats.connections += 1;
        tracing::info!(?peer, conn, "fake Kortex: connection");
        match stream.try_clone() {
            Ok(handle) => sh.conns().push((conn, handle)),
            Err(e) => {
                tracing::error!("fake Kortex: cannot serve a connection: {e}");
                continue;
            }
        }
        let sh2 = sh.clone();
        match std::thread::Builder::new()
            .name("fake-kortex-conn".into())
            .spawn(move || serve_connection(sh2, stream, conn))
        {
            Ok(h) => conns.push(h),
            Err(e) => tracing::error!("fake Kortex: cannot serve a connection: {e}"),
        }
        conns.retain(|h| !h.is_finished());
    }
    for h in conns {
        let _ = h.join();
    }
}

/// What a request produced: bytes to send when due, or closing the connection.
enum Out {
    Bytes { due: Instant, bytes: Vec<u8> },
    Close { due: Instant },
}

impl Out {
    fn due(&self) -> Instant {
        match self {
            Self::Bytes { due, .. } | Self::Close { due } => *due,
        }
    }
}

fn serve_connection(sh: Arc<Shared>, stream: TcpStream, conn: u64) {
    let _ = stream.set_nodelay(true);
    serve(&sh, stream, conn);
    sh.conns().retain(|(c, _)| *c != conn);
    for s in sh.state().sessions.iter_mut().filter(|s| s.conn == conn) {
        s.closed = true;
    }
    tracing::info!(conn, "fake Kortex: connection closed");
}

/// Reads frames, answers them, and sends held (delayed) outputs in order when due; blocks in
/// `read` until a frame or the next due output.
fn serve(sh: &Shared, mut stream: TcpStream, conn: u64) {
    let mut decoder = FrameDecoder::new();
    let mut buf = [0u8; 4096];
    let mut held: VecDeque<Out> = VecDeque::new();
    loop {
        // Send what is due, in order.
        while held.front().is_some_and(|o| o.due() <= Instant::now()) {
            let Some(out) = held.pop_front() else {
                break;
            };
            let open = match out {
                Out::Bytes { bytes, .. } => stream.write_all(&bytes).is_ok(),
                Out::Close { .. } => {
                    let _ = stream.shutdown(Shutdown::Both);
                    false
                }
            };
            if !open {
                return;
            }
        }
        if sh.stop.load(Ordering::SeqCst) {
            return;
        }
        let timeout = held.front().map(|o| {
            o.due()
                .saturating_duration_since(Instant::now())
                .max(Duration::from_micros(100))
        });
        if stream.set_read_timeout(timeout).is_err() {
            return;
        }
        let n = match stream.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                continue;
            }
            Err(_) => return,
        };
        decoder.push(&buf[..n]);
        while let Some(r) = decoder.next_frame() {
            match r {
                Ok(Decoded::Frame(frame)) => held.extend(on_frame(sh, conn, &frame)),
                Ok(Decoded::Skipped(k)) => sh.state().stats.skipped_bytes += k as u64,
                Err(e) => tracing::warn!("fake Kortex: bad frame from the client: {e}"),
            }
        }
    }
}

type CallResult = Result<Vec<u8>, (u8, u16, String)>;

fn on_frame(sh: &Shared, conn: u64, frame: &Frame) -> Vec<Out> {
    let now = Instant::now();
    let mut st = sh.state();
    st.stats.frames += 1;
    if let Some(s) = st.sessions.iter_mut().find(|s| s.conn == conn) {
        s.last_frame = now;
        // A frame re-arms the watchdog: the next silence stops the arm again.
        s.timed_out = false;
    }
    let h = frame.header();
    if h.frame_type() != Some(FrameType::Request) {
        return Vec::new();
    }
    if st.requests.len() == LOG_CAPACITY {
        st.requests.pop_front();
    }
    st.requests.push_back(FakeRequest {
        function_uid: h.function_uid(),
        message_id: h.message_id(),
        session_id: h.session_id(),
    });
    let function = Function::from_uid(h.function_uid());
    let fault = st
        .faults
        .iter()
        .position(|(on, _)| on.is_none() || *on == function)
        .and_then(|i| st.faults.remove(i))
        .map(|(_, f)| f);
    if fault.is_some() {
        st.stats.faults_fired += 1;
    }
    let result = match &fault {
        Some(Fault::ErrorReply {
            code,
            sub_code,
            detail,
        }) => Err((*code, *sub_code, detail.clone())),
        _ => execute(&sh.cfg, &mut st, conn, function, h.function_uid(), frame),
    };
    let session_id = st
        .sessions
        .iter()
        .find(|s| s.conn == conn)
        .map_or(h.session_id(), |s| s.id);
    let message_id = match fault {
        Some(Fault::WrongMessageId) => h.message_id().wrapping_add(0x7000),
        _ => h.message_id(),
    };
    let reply = match result {
        Ok(payload) => Frame {
            header: Header::new(
                FrameType::Response,
                session_id,
                message_id,
                h.function_uid(),
                payload.len(),
            )
            .ok(),
            payload,
        },
        Err((code, sub_code, detail)) => {
            st.stats.error_replies += 1;
            let payload = ErrorPayload {
                error_code: i32::from(code),
                error_sub_code: u32::from(sub_code),
                error_sub_string: detail,
            }
            .encode_to_vec();
            Frame {
                header: Header::new(
                    FrameType::Response,
                    session_id,
                    message_id,
                    h.function_uid(),
                    payload.len(),
                )
                .ok()
                .map(|hd| hd.with_error(code, sub_code)),
                payload,
            }
        }
    };
    drop(st);
    let mut bytes = Vec::new();
    if reply.encode_tcp(&mut bytes).is_err() {
        return Vec::new();
    }
    with_fault(fault, bytes, now)
}

/// What goes out for a reply's `bytes` at `now`, as the injected `fault` (if any) has it:
/// nothing, later, garbage first, corrupted, truncated, or the connection closed.
fn with_fault(fault: Option<Fault>, mut bytes: Vec<u8>, now: Instant) -> Vec<Out> {
    match fault {
        Some(Fault::DropReply) => Vec::new(),
        Some(Fault::DelayReply(d)) => vec![Out::Bytes {
            due: now + d,
            bytes,
        }],
        Some(Fault::CloseConnection) => vec![Out::Close { due: now }],
        Some(Fault::GarbageBefore(g)) => vec![
            Out::Bytes { due: now, bytes: g },
            Out::Bytes { due: now, bytes },
        ],
        Some(Fault::CorruptMagic) => {
            bytes[..MAGIC.len()].copy_from_slice(b"NOTMAGIC");
            vec![Out::Bytes { due: now, bytes }]
        }
        Some(Fault::TruncateReply(n)) => {
            bytes.truncate(n);
            vec![Out::Bytes { due: now, bytes }, Out::Close { due: now }]
        }
        _ => vec![Out::Bytes { due: now, bytes }],
    }
}

fn decode_req<M: prost::Message + Default>(
    frame: &Frame,
    what: &str,
) -> Result<M, (u8, u16, String)> {
    M::decode(frame.payload.as_slice()).map_err(|e| (2, 0, format!("cannot decode {what}: {e}")))
}

/// Serves one call on connection `conn`: a session first, then the function.
fn execute(
    cfg: &FakeConfig,
    st: &mut State,
    conn: u64,
    function: Option<Function>,
    uid: u32,
    frame: &Frame,
) -> CallResult {
    let Some(function) = function else {
        return Err((
            1,
            0,
            format!("function {uid:#x} is not served by this fake robot"),
        ));
    };
    if function == Function::CreateSession {
        return create_session(cfg, st, conn, frame);
    }
    let Some(si) = st.sessions.iter().position(|s| s.conn == conn) else {
        return Err((1, 12, "no session on this connection".into()));
    };
    if !read_only(function) {
        st.sessions[si].controls = true;
    }
    match function {
        Function::CreateSession | Function::KeepAlive => Ok(Vec::new()),
        Function::ClearFaults => {
            st.in_fault = false;
            Ok(Vec::new())
        }
        Function::Refresh => refresh(cfg, st, frame),
        Function::CloseSession => {
            // An observing session's end leaves the arm alone.
            if st.sessions.remove(si).controls {
                st.arm.halt();
            }
            st.stats.sessions_closed += 1;
            tracing::info!("fake Kortex: session closed");
            Ok(Vec::new())
        }
        Function::Stop | Function::ApplyEmergencyStop => {
            st.arm.halt();
            st.stats.stops += 1;
            Ok(Vec::new())
        }
        Function::SetServoingMode => set_servoing_mode(st, frame),
        Function::GetActuatorCount
        | Function::GetFirmwareVersion
        | Function::GetServoingMode
        | Function::GetProductConfiguration
        | Function::GetArmState
        | Function::GetKinematicHardLimits
        | Function::GetMeasuredJointAngles => Ok(query(cfg, st, function)),
        Function::RefreshFeedback => {
            st.stats.feedback_requests += 1;
            Ok(state_feedback(st).encode_to_vec())
        }
        Function::SendJointSpeedsCommand | Function::SendGripperCommand
            if !st.single_level_servoing =>
        {
            st.stats.refused_not_servoing += 1;
            Err((
                3,
                0,
                format!(
                    "{} refused: the robot is not in single-level servoing (call \
                     Base.SetServoingMode first)",
                    function.name()
                ),
            ))
        }
        Function::SendJointSpeedsCommand => send_joint_speeds(cfg, st, si, frame),
        Function::SendGripperCommand => send_gripper_command(st, frame),
    }
}

/// `CreateSession`: checks the credentials and opens a session on `conn` (replacing its
/// previous one; making room in a full table from a timed-out closed session).
fn create_session(cfg: &FakeConfig, st: &mut State, conn: u64, frame: &Frame) -> CallResult {
    let info: msg::CreateSessionInfo = decode_req(frame, "CreateSessionInfo")?;
    if info.username != cfg.credentials.username() || info.password != cfg.credentials.password() {
        return Err((1, 15, "wrong user name or password".into()));
    }
    // A second CreateSession on one connection replaces that connection's session.
    st.sessions.retain(|s| s.conn != conn);
    if st.sessions.len() >= MAX_SESSIONS {
        // The table is full: the oldest session whose connection is gone makes room (its
        // watchdog first, if it has not fired yet).
        if let Some(i) = st.sessions.iter().position(|s| s.closed && s.timed_out) {
            st.sessions.remove(i);
        }
    }
    if st.sessions.len() >= MAX_SESSIONS {
        return Err((
            1,
            0,
            format!("this fake robot holds at most {MAX_SESSIONS} sessions at once"),
        ));
    }
    let id = st.next_session_id;
    st.next_session_id = st.next_session_id.wrapping_add(1).max(1);
    let ms = |v: u32| (v > 0).then(|| Duration::from_millis(u64::from(v)));
    st.sessions.push(Session {
        id,
        conn,
        connection_timeout: ms(info.connection_inactivity_timeout),
        session_timeout: ms(info.session_inactivity_timeout),
        last_frame: Instant::now(),
        timed_out: false,
        controls: false,
        closed: false,
    });
    st.stats.sessions_opened += 1;
    st.created_timeouts_ms = Some((
        info.connection_inactivity_timeout,
        info.session_inactivity_timeout,
    ));
    tracing::info!(
        session = format_args!("{id:#06x}"),
        connection_timeout_ms = info.connection_inactivity_timeout,
        session_timeout_ms = info.session_inactivity_timeout,
        "fake Kortex: session open"
    );
    Ok(Vec::new())
}

/// `SetServoingMode`: single-level (speeds) or low-level (positions; not in fault).
fn set_servoing_mode(st: &mut State, frame: &Frame) -> CallResult {
    let m: msg::ServoingModeInformation = decode_req(frame, "ServoingModeInformation")?;
    match m.servoing_mode {
        msg::servoing_mode::SINGLE_LEVEL => {
            st.single_level_servoing = true;
            st.low_level_servoing = false;
        }
        msg::servoing_mode::LOW_LEVEL => {
            if st.in_fault {
                return Err((3, 22, "the robot is in fault".into()));
            }
            // Speeds in force stop: from now on positions drive the arm.
            st.arm.halt();
            st.single_level_servoing = false;
            st.low_level_servoing = true;
            st.last_refresh = Instant::now();
            st.cyclic_qdot = [0.0; MAX_JOINTS];
            st.first_cmd = None;
            tracing::info!("fake Kortex: low-level servoing");
        }
        other => {
            return Err((
                3,
                0,
                format!("this fake robot does not serve servoing mode {other}"),
            ));
        }
    }
    Ok(Vec::new())
}

/// The reply of a query (`Get...`): the fake's configuration or the arm's state.
fn query(cfg: &FakeConfig, st: &State, function: Function) -> Vec<u8> {
    let n = st.n;
    match function {
        Function::GetActuatorCount => msg::ActuatorInformation {
            count: cfg.actuator_count,
        }
        .encode_to_vec(),
        Function::GetFirmwareVersion => msg::FirmwareVersion {
            firmware_version: cfg.firmware_version,
        }
        .encode_to_vec(),
        Function::GetServoingMode => msg::ServoingModeInformation {
            // Unspecified (0) until a session sets one, as the fake starts.
            servoing_mode: if st.low_level_servoing {
                msg::servoing_mode::LOW_LEVEL
            } else if st.single_level_servoing {
                msg::servoing_mode::SINGLE_LEVEL
            } else {
                0
            },
        }
        .encode_to_vec(),
        Function::GetProductConfiguration => msg::CompleteProductConfiguration {
            kin: String::new(),
            model: cfg.model,
            degree_of_freedom: u32::try_from(n).unwrap_or(u32::MAX),
        }
        .encode_to_vec(),
        Function::GetArmState => msg::ArmStateInformation {
            active_state: msg::arm_state::SERVOING_READY,
        }
        .encode_to_vec(),
        Function::GetKinematicHardLimits => msg::KinematicLimits {
            control_mode: 0,
            twist_linear: 0.3,
            twist_angular: 0.85f32.to_degrees(),
            joint_speed_limits: cfg.joint_speed_limits_deg_s.clone(),
            joint_acceleration_limits: cfg.joint_acceleration_limits_deg_s2.clone(),
        }
        .encode_to_vec(),
        Function::GetMeasuredJointAngles => msg::JointAngles {
            joint_angles: (0..n)
                .map(|j| msg::JointAngle {
                    joint_identifier: j as u32,
                    value: angle_rad_to_wire_deg(st.reading.q_rad[j]) as f32,
                })
                .collect(),
        }
        .encode_to_vec(),
        // Not a query: no payload (`execute` sends only queries here).
        _ => Vec::new(),
    }
}

/// `SendJointSpeedsCommand`: every joint's speed, within its limit, drives the arm.
fn send_joint_speeds(cfg: &FakeConfig, st: &mut State, si: usize, frame: &Frame) -> CallResult {
    let n = st.n;
    let m: msg::JointSpeeds = decode_req(frame, "JointSpeeds")?;
    let mut v = [0.0; MAX_JOINTS];
    let mut seen = [false; MAX_JOINTS];
    for s in &m.joint_speeds {
        let j = s.joint_identifier as usize;
        let value = f64::from(s.value);
        if j >= n || seen[j] || !value.is_finite() {
            return Err((3, 0, format!("bad joint speed entry {s:?}")));
        }
        let limit = cfg.joint_speed_limits_deg_s.get(j).copied().unwrap_or(0.0);
        if value.abs() > f64::from(limit) * 1.0001 {
            return Err((
                3,
                0,
                format!("joint {j}: {value} deg/s is above the limit {limit} deg/s"),
            ));
        }
        seen[j] = true;
        v[j] = value.to_radians();
    }
    if !seen[..n].iter().all(|s| *s) {
        return Err((3, 0, "joint speed commands must name every joint".into()));
    }
    st.arm.set_command(&v[..n], 0.0);
    st.command_from = Some(st.sessions[si].id);
    st.stats.joint_speed_commands += 1;
    if st.log.len() == LOG_CAPACITY {
        st.log.pop_front();
    }
    st.log.push_back(v);
    Ok(Vec::new())
}

/// `SendGripperCommand`: a position target in [0, 1] for the gripper's finger.
fn send_gripper_command(st: &mut State, frame: &Frame) -> CallResult {
    let m: msg::GripperCommand = decode_req(frame, "GripperCommand")?;
    let finger = m
        .gripper
        .as_ref()
        .and_then(|g| g.finger.first())
        .filter(|f| f.finger_identifier == msg::GRIPPER_FINGER_ID);
    match (m.mode, finger) {
        (msg::gripper_mode::POSITION, Some(f)) if (0.0..=1.0).contains(&f.value) => {
            st.arm.set_gripper_target(f64::from(f.value));
            st.stats.gripper_commands += 1;
            Ok(Vec::new())
        }
        _ => Err((3, 0, format!("unsupported gripper command {m:?}"))),
    }
}

/// The feedback of the arm now: the arm's state, and in low-level servoing the speeds the
/// position commands imply.
fn state_feedback(st: &State) -> msg::Feedback {
    let mut r = st.reading;
    if st.low_level_servoing {
        r.qdot_rad_s = st.cyclic_qdot;
    }
    let mut fb = feedback(&r, st.n);
    if st.in_fault
        && let Some(b) = fb.base.as_mut()
    {
        b.active_state = msg::arm_state::IN_FAULT;
    }
    fb
}

/// `BaseCyclic.Refresh`: the command's positions become the arm's (unless blocked); with a
/// misread, the arm servos towards the misread positions at its joint speed limits.
fn refresh(cfg: &FakeConfig, st: &mut State, frame: &Frame) -> CallResult {
    if st.in_fault {
        return Err((
            3,
            22,
            "BaseCyclic.Refresh refused: the robot is in fault".into(),
        ));
    }
    if !st.low_level_servoing {
        return Err((
            3,
            0,
            "BaseCyclic.Refresh refused: the robot is not in low-level servoing".into(),
        ));
    }
    let m: msg::Command = decode_req(frame, "Command")?;
    let n = st.n;
    if m.actuators.len() != n {
        return Err((
            3,
            0,
            format!("{} actuator commands for {n} actuators", m.actuators.len()),
        ));
    }
    let mut q = [0.0; MAX_JOINTS];
    for (j, a) in m.actuators.iter().enumerate() {
        let p = f64::from(a.position);
        if !p.is_finite() {
            return Err((3, 0, format!("actuator {j}: position {p} deg")));
        }
        q[j] = super::angle_deg_to_rad(p);
    }
    // The arm's continuous joints turn past a half turn: the commanded angle nearest to where
    // each is (the wire carries angles in [0, 360)).
    let at = st.reading.q_rad;
    for (j, c) in cfg.robot.continuous_joints().iter().enumerate() {
        if *c {
            q[j] = at[j] + super::wrap_deg((q[j] - at[j]).to_degrees()).to_radians();
        }
    }
    if st.first_cmd.is_none() {
        st.first_cmd = Some(q);
    }
    st.last_cmd = Some(q);
    let now = Instant::now();
    let dt = now.duration_since(st.last_refresh).as_secs_f64().max(1e-4);
    st.last_refresh = now;
    if !st.arm_blocked {
        let before = st.reading.q_rad;
        let gripper = st.reading.gripper;
        if let Some(m) = cfg.cyclic_misread {
            m.apply(&mut q[..n]);
            for (j, (q, b)) in q.iter_mut().zip(before).take(n).enumerate() {
                let deg_s = cfg.joint_speed_limits_deg_s.get(j).copied().unwrap_or(0.0);
                let step = f64::from(deg_s).to_radians() * dt;
                *q = b + (*q - b).clamp(-step, step);
            }
        }
        st.arm.resume(&q[..n], gripper);
        st.reading = st.arm.step(1e-9);
        let now_q = st.reading.q_rad;
        for ((v, q), b) in st.cyclic_qdot.iter_mut().zip(now_q).zip(before).take(n) {
            *v = (q - b) / dt;
        }
    } else {
        st.cyclic_qdot = [0.0; MAX_JOINTS];
    }
    st.stats.refreshes += 1;
    Ok(state_feedback(st).encode_to_vec())
}

/// The cyclic channel: bare frames over UDP, its own session; and the arm's reaction to a
/// missing cyclic command.
fn cyclic_loop(sh: Arc<Shared>, udp: UdpSocket) {
    let mut buf = vec![0u8; 65_536];
    while !sh.stop.load(Ordering::SeqCst) {
        let wait = {
            let mut st = sh.state();
            let now = Instant::now();
            let due = st.last_refresh + sh.cfg.cyclic_timeout;
            if st.low_level_servoing && !st.in_fault {
                if now > due {
                    st.in_fault = true;
                    st.arm.halt();
                    st.cyclic_qdot = [0.0; MAX_JOINTS];
                    st.stats.cyclic_timeouts += 1;
                    tracing::warn!(
                        "fake Kortex: no cyclic command for {} ms in low-level servoing: arm                          stopped, in fault",
                        now.duration_since(st.last_refresh).as_millis()
                    );
                    WATCHDOG_MAX_SLEEP
                } else {
                    (due - now + Duration::from_micros(200)).min(WATCHDOG_MAX_SLEEP)
                }
            } else {
                WATCHDOG_MAX_SLEEP
            }
        };
        if udp.set_read_timeout(Some(wait)).is_err() {
            return;
        }
        let (len, peer) = match udp.recv_from(&mut buf) {
            Ok(x) => x,
            Err(_) => continue,
        };
        let Ok(frame) = Frame::decode(&buf[..len]) else {
            tracing::warn!("fake Kortex: an undecodable cyclic datagram");
            continue;
        };
        if let Some(reply) = on_datagram(&sh, peer, &frame) {
            let _ = udp.send_to(&reply.encode_bare(), peer);
        }
    }
}

fn on_datagram(sh: &Shared, peer: SocketAddr, frame: &Frame) -> Option<Frame> {
    let h = frame.header();
    if h.frame_type() != Some(FrameType::Request) {
        return None;
    }
    let mut st = sh.state();
    st.stats.frames += 1;
    if st.requests.len() == LOG_CAPACITY {
        st.requests.pop_front();
    }
    st.requests.push_back(FakeRequest {
        function_uid: h.function_uid(),
        message_id: h.message_id(),
        session_id: h.session_id(),
    });
    let function = Function::from_uid(h.function_uid());
    let mut session_id = h.session_id();
    let result: CallResult = match function {
        Some(Function::CreateSession) => {
            match decode_req::<msg::CreateSessionInfo>(frame, "CreateSessionInfo") {
                Ok(info)
                    if info.username == sh.cfg.credentials.username()
                        && info.password == sh.cfg.credentials.password() =>
                {
                    let id = st.next_session_id;
                    st.next_session_id = st.next_session_id.wrapping_add(1).max(1);
                    st.cyclic = Some((id, peer));
                    st.stats.cyclic_sessions_opened += 1;
                    session_id = id;
                    tracing::info!(
                        session = format_args!("{id:#06x}"),
                        "fake Kortex: cyclic session open"
                    );
                    Ok(Vec::new())
                }
                Ok(_) => Err((1, 15, "wrong user name or password".into())),
                Err(e) => Err(e),
            }
        }
        _ if st
            .cyclic
            .is_none_or(|(id, p)| id != h.session_id() || p != peer) =>
        {
            Err((1, 12, "no cyclic session for this peer".into()))
        }
        Some(Function::CloseSession) => {
            st.cyclic = None;
            st.stats.cyclic_sessions_closed += 1;
            tracing::info!("fake Kortex: cyclic session closed");
            Ok(Vec::new())
        }
        Some(Function::Refresh) => refresh(&sh.cfg, &mut st, frame),
        Some(Function::RefreshFeedback) => {
            st.stats.feedback_requests += 1;
            Ok(state_feedback(&st).encode_to_vec())
        }
        _ => Err((
            1,
            0,
            format!(
                "{} is not served on the cyclic channel",
                super::function_name(h.function_uid())
            ),
        )),
    };
    let (payload, err) = match result {
        Ok(p) => (p, None),
        Err((code, sub, detail)) => {
            st.stats.error_replies += 1;
            (
                ErrorPayload {
                    error_code: i32::from(code),
                    error_sub_code: u32::from(sub),
                    error_sub_string: detail,
                }
                .encode_to_vec(),
                Some((code, sub)),
            )
        }
    };
    let header = Header::new(
        FrameType::Response,
        session_id,
        h.message_id(),
        h.function_uid(),
        payload.len(),
    )
    .ok()?;
    let header = match err {
        Some((code, sub)) => header.with_error(code, sub),
        None => header,
    };
    Some(Frame {
        header: Some(header),
        payload,
    })
}

fn feedback(r: &Reading, n: usize) -> msg::Feedback {
    msg::Feedback {
        frame_id: 0,
        base: Some(msg::BaseFeedback {
            active_state: msg::arm_state::SERVOING_READY,
            ..Default::default()
        }),
        actuators: (0..n)
            .map(|j| msg::ActuatorFeedback {
                position: angle_rad_to_wire_deg(r.q_rad[j]) as f32,
                velocity: r.qdot_rad_s[j].to_degrees() as f32,
                ..Default::default()
            })
            .collect(),
        interconnect: Some(msg::InterconnectFeedback {
            gripper_feedback: Some(msg::GripperFeedback {
                motor: vec![msg::MotorFeedback {
                    motor_id: 1,
                    position: (r.gripper * 100.0) as f32,
                    velocity: 0.0,
                }],
            }),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fake plays the profile's arm; a misread naming a joint the arm lacks is refused.
    #[test]
    fn the_fake_plays_the_profiles_arm_and_refuses_a_misread_past_its_joints() {
        for name in RobotProfile::names() {
            let robot = RobotProfile::by_name(name).unwrap();
            let n = robot.n_joints();
            let cfg = FakeConfig::for_robot(robot);
            assert_eq!(cfg.actuator_count as usize, n);
            assert_eq!(cfg.joint_speed_limits_deg_s.len(), n);
            assert_eq!(cfg.joint_acceleration_limits_deg_s2.len(), n);
            assert_eq!(cfg.model, FoundRobot::of_profile(robot).model);
            assert_ne!(cfg.model, msg::model_id::UNSPECIFIED, "{name}");
            let fake = FakeKortex::start(cfg.clone()).unwrap();
            let s = fake.snapshot();
            assert_eq!((s.q_rad.len(), s.command_in_force.len()), (n, n));
            let home = robot.named_pose("home").unwrap();
            assert!(
                s.q_rad.iter().zip(home).all(|(a, b)| (a - b).abs() < 1e-9),
                "{name}: {:?}",
                s.q_rad
            );
            drop(fake);
            let misread = |joint| FakeConfig {
                cyclic_misread: Some(CyclicMisread::Offset {
                    joint,
                    offset_rad: 0.1,
                }),
                ..cfg.clone()
            };
            let e = FakeKortex::start(misread(n)).unwrap_err().to_string();
            assert!(
                e.contains(&format!("joint {n}")) && e.contains(&format!("has {n} joints")),
                "{e}"
            );
            FakeKortex::start(misread(n - 1)).unwrap();
        }
    }

    #[test]
    fn cyclic_misreads_parse_and_apply() {
        assert_eq!(
            "zero".parse::<CyclicMisread>(),
            Ok(CyclicMisread::ZeroPosition)
        );
        let m: CyclicMisread = "offset:3:0.02".parse().unwrap();
        assert_eq!(
            m,
            CyclicMisread::Offset {
                joint: 3,
                offset_rad: 0.02
            }
        );
        let mut q = [0.1, 0.2, 0.3, 0.5, 0.5, 0.6];
        m.apply(&mut q);
        assert_eq!(q, [0.1, 0.2, 0.3, 0.5 + 0.02, 0.5, 0.6]);
        CyclicMisread::ZeroPosition.apply(&mut q);
        assert_eq!(q, [0.0; 6]);
        for bad in [
            "",
            "zeros",
            "offset",
            "offset:3",
            "offset:8:0.1",
            "offset:x:0.1",
            "offset:1:nan",
            "offset:1:0.1:2",
        ] {
            let e = bad.parse::<CyclicMisread>().unwrap_err();
            assert!(e.contains("offset:JOINT:RAD"), "{bad}: {e}");
        }
    }
}
