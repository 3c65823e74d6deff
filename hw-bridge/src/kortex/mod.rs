//! The Kortex backend: a clean-room client of Kinova's Kortex API for the Kinova arm of the
//! graph's robot profile (the Gen3 lite, the 7-joint Gen3), written from the protocol facts in
//! `shared/reference/kortex-protocol.md`. At connect it checks that the arm is the profile's
//! ([`FoundRobot`], [`KortexModel`]).
//!
//! * [`wire`]: TCP framing and the protobuf envelope (`Frame`, `Header`), the streaming
//!   decoder that resynchronises on a wrong magic.
//! * [`msg`]: the project's own prost definitions of the messages the bridge exchanges.
//! * [`arm::KortexArm`]: the [`crate::Robot`] over one TCP session: start-up (session with
//!   both inactivity timeouts, servoing mode, clear faults, actuator count, kinematic hard
//!   limits), then a pipelined 40 Hz exchange (joint speeds, gripper position, feedback; replies
//!   matched by message id on a socket reader thread), and Stop + CloseSession on exit and on
//!   every fault.
//! * [`cyclic`]: low-level servoing (`mode = "low-level"`): the second session over UDP, a
//!   `BaseCyclic.Refresh` per tick with joint positions integrated from the safe speeds,
//!   entered only from rest at the measured position, the entry check (the measured position
//!   held for `entry_hold_ms` before the graph's commands apply), the following-error check;
//!   where the cyclic command's layout comes from and what is still assumed is listed there.
//! * [`fake::FakeKortex`]: a fake robot on loopback speaking the same protocol (the cyclic
//!   channel included), playing the arm of a robot profile, for tests and for trying the
//!   bridge without an arm.
//!
//! Units at this boundary: the stack speaks radians and rad/s; the wire speaks degrees and
//! deg/s, angles in `[0, 360)` ([`wrap_deg`] brings them to `(-180, 180]`).
//!
//! ```
//! use hw_bridge::Robot;
//! use hw_bridge::kortex::{Credentials, FakeConfig, FakeKortex, KortexArm, KortexConfig};
//!
//! // A fake Gen3 lite on a free port of 127.0.0.1, and the client on it.
//! let fake = FakeKortex::start(FakeConfig::default())?;
//! let cfg = KortexConfig {
//!     address: "127.0.0.1".into(),
//!     port: fake.addr().port(),
//!     ..KortexConfig::default()
//! };
//! let mut arm = KortexArm::connect(&cfg, &Credentials::new("admin", "admin"))?;
//! let reading = arm.advance(0.025)?; // the newest feedback; asks for the next one
//! assert!((reading.q_rad[2] - 1.309).abs() < 1e-4); // the fake starts at home
//! arm.command(&[0.1, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0)?; // rad/s, sent as deg/s, not awaited
//! arm.shutdown()?; // Stop, a last feedback, CloseSession: each awaited
//! assert!(!fake.snapshot().commanded_to_move());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod arm;
pub mod cyclic;
pub mod fake;
pub mod msg;
pub mod wire;

use std::net::{IpAddr, SocketAddr};

use serde::{Deserialize, Serialize};

pub use arm::{ArmInfo, KortexArm, KortexStats};
pub use fake::{
    CyclicMisread, FakeConfig, FakeKortex, FakeRequest, FakeSnapshot, FakeStats, Fault,
};

/// The functions of the Kortex API the bridge (and the fake robot) use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Function {
    /// `Session.CreateSession`.
    CreateSession,
    /// `Session.CloseSession`.
    CloseSession,
    /// `Session.KeepAlive` (never sent by the bridge: a frozen loop must let the session
    /// time out).
    KeepAlive,
    /// `Base.Stop`.
    Stop,
    /// `Base.GetMeasuredJointAngles`.
    GetMeasuredJointAngles,
    /// `Base.SendJointSpeedsCommand`.
    SendJointSpeedsCommand,
    /// `Base.SendGripperCommand`.
    SendGripperCommand,
    /// `Base.ApplyEmergencyStop`.
    ApplyEmergencyStop,
    /// `Base.ClearFaults`.
    ClearFaults,
    /// `Base.SetServoingMode`.
    SetServoingMode,
    /// `Base.GetActuatorCount`.
    GetActuatorCount,
    /// `Base.GetArmState`.
    GetArmState,
    /// `BaseCyclic.RefreshFeedback`.
    RefreshFeedback,
    /// `BaseCyclic.Refresh` (a cyclic command, answered with a Feedback): the low-level
    /// channel over UDP. Its UID is not in the protocol reference; it follows from Kinova's
    /// published API documentation (see [`msg::Command`]).
    Refresh,
    /// `ControlConfig.GetKinematicHardLimits`.
    GetKinematicHardLimits,
    /// `DeviceConfig.GetFirmwareVersion` (read by `scl doctor` only).
    GetFirmwareVersion,
    /// `Base.GetServoingMode` (never sent by the bridge; served by the fake robot, which
    /// Kinova's own tools ask on connect). Not in the protocol reference: the UID follows
    /// SetServoingMode's in Kinova's published client sources (BaseClientRpc.h, KortexAPI 2.x).
    GetServoingMode,
    /// `Base.GetProductConfiguration` (the arm's model, read at connect: see
    /// [`KortexModel`]). UID from Kinova's published client sources (BaseClientRpc.h,
    /// KortexAPI 2.x), not the protocol reference.
    GetProductConfiguration,
}

impl Function {
    /// Every function, for look-ups.
    pub const ALL: [Function; 18] = [
        Self::CreateSession,
        Self::CloseSession,
        Self::KeepAlive,
        Self::Stop,
        Self::GetMeasuredJointAngles,
        Self::SendJointSpeedsCommand,
        Self::SendGripperCommand,
        Self::ApplyEmergencyStop,
        Self::ClearFaults,
        Self::SetServoingMode,
        Self::GetActuatorCount,
        Self::GetArmState,
        Self::RefreshFeedback,
        Self::Refresh,
        Self::GetKinematicHardLimits,
        Self::GetFirmwareVersion,
        Self::GetServoingMode,
        Self::GetProductConfiguration,
    ];

    /// Function UID: `(service id << 16) | function id`.
    pub fn uid(self) -> u32 {
        match self {
            Self::CreateSession => 0x1_0001,
            Self::CloseSession => 0x1_0002,
            Self::KeepAlive => 0x1_0003,
            Self::Stop => 0x2_0070,
            Self::GetMeasuredJointAngles => 0x2_007E,
            Self::SendJointSpeedsCommand => 0x2_0084,
            Self::SendGripperCommand => 0x2_0088,
            Self::ApplyEmergencyStop => 0x2_0091,
            Self::ClearFaults => 0x2_0092,
            Self::SetServoingMode => 0x2_0098,
            Self::GetActuatorCount => 0x2_00AB,
            Self::GetArmState => 0x2_00AF,
            Self::RefreshFeedback => 0x3_0003,
            // Not in the reference: function 1 of BaseCyclic, the first of its RPCs in Kinova's
            // published API documentation, whose third is RefreshFeedback (0x30003, in the
            // reference). See msg::Command.
            Self::Refresh => 0x3_0001,
            Self::GetKinematicHardLimits => 0x10_0012,
            Self::GetFirmwareVersion => 0x9_0004,
            Self::GetServoingMode => 0x2_0099,
            Self::GetProductConfiguration => 0x2_00C6,
        }
    }

    /// `Service.Function`, as Kinova names it.
    pub fn name(self) -> &'static str {
        match self {
            Self::CreateSession => "Session.CreateSession",
            Self::CloseSession => "Session.CloseSession",
            Self::KeepAlive => "Session.KeepAlive",
            Self::Stop => "Base.Stop",
            Self::GetMeasuredJointAngles => "Base.GetMeasuredJointAngles",
            Self::SendJointSpeedsCommand => "Base.SendJointSpeedsCommand",
            Self::SendGripperCommand => "Base.SendGripperCommand",
            Self::ApplyEmergencyStop => "Base.ApplyEmergencyStop",
            Self::ClearFaults => "Base.ClearFaults",
            Self::SetServoingMode => "Base.SetServoingMode",
            Self::GetActuatorCount => "Base.GetActuatorCount",
            Self::GetArmState => "Base.GetArmState",
            Self::RefreshFeedback => "BaseCyclic.RefreshFeedback",
            Self::Refresh => "BaseCyclic.Refresh",
            Self::GetKinematicHardLimits => "ControlConfig.GetKinematicHardLimits",
            Self::GetFirmwareVersion => "DeviceConfig.GetFirmwareVersion",
            Self::GetServoingMode => "Base.GetServoingMode",
            Self::GetProductConfiguration => "Base.GetProductConfiguration",
        }
    }

    /// The function of a UID, if the bridge knows it.
    pub fn from_uid(uid: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.uid() == uid)
    }
}

/// The name of the function of `uid`, or the UID in hex.
pub fn function_name(uid: u32) -> String {
    Function::from_uid(uid).map_or_else(|| format!("function {uid:#x}"), |f| f.name().to_owned())
}

/// Settings of the Kortex client: the `[bridge.kortex]` table of the graph TOML.
/// Credentials are not here: they come from the environment or from `credentials_file`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KortexConfig {
    /// The robot's IP address.
    pub address: String,
    /// The robot's TCP port.
    pub port: u16,
    /// A TOML file with `username` and `password` (empty: the environment only). A relative
    /// path is relative to the config file's directory.
    pub credentials_file: String,
    /// The robot stops the arm after this long without a frame from the bridge (ms): the
    /// robot-side watchdog that stops the arm if the bridge freezes or dies.
    pub connection_timeout_ms: u32,
    /// The robot ends the session after this long without a frame (ms).
    pub session_timeout_ms: u32,
    /// A request without a reply for this long is a fault (ms).
    pub reply_timeout_ms: u32,
    /// How the arm is driven: [`KortexMode::SingleLevel`] (joint speeds over TCP, the
    /// default) or [`KortexMode::LowLevel`] (position commands every tick over UDP).
    pub mode: KortexMode,
    /// The robot's UDP port of the low-level cyclic channel (low-level mode only).
    pub cyclic_port: u16,
    /// Low-level mode: a measured joint angle further than this from its commanded position
    /// stops the arm and the graph (rad).
    pub following_error_rad: f64,
    /// Low-level mode, the entry check: after the first position command, the bridge holds
    /// the measured position this long (ms) before the graph's commands apply.
    pub entry_hold_ms: u32,
    /// Low-level mode, the entry check: a joint further than this from the held position
    /// during the hold stops the arm and the graph (rad; at most `following_error_rad`).
    pub entry_hold_tolerance_rad: f64,
}

/// How the bridge drives the arm (`[bridge.kortex] mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum KortexMode {
    /// Single-level servoing: joint speed commands over the TCP session, pipelined.
    #[default]
    SingleLevel,
    /// Low-level servoing: a second session over UDP, a `BaseCyclic.Refresh` with joint
    /// position commands every tick (see [`cyclic`]).
    LowLevel,
}

/// The period of the low-level cyclic channel (s): 1 kHz.
pub const LOW_LEVEL_PERIOD_S: f64 = 0.001;

/// The robot's UDP port of the low-level cyclic channel.
pub const DEFAULT_CYCLIC_PORT: u16 = 10001;

/// Default following-error bound of low-level mode (rad, about 2.9°). The reference is silent
/// on the robot's own bound; this is the bridge's, chosen tight: at 1 kHz the fastest joint
/// (3.2 rad/s) moves 0.0032 rad per tick.
pub const DEFAULT_FOLLOWING_ERROR_RAD: f64 = 0.05;

/// The widest following-error bound accepted (rad, about 29°): beyond it the check protects
/// nothing.
pub const MAX_FOLLOWING_ERROR_RAD: f64 = 0.5;

/// Default length of the low-level entry check's hold (ms): 100 ticks at 1 kHz.
pub const DEFAULT_ENTRY_HOLD_MS: u32 = 100;

/// The shortest entry hold accepted (ms): 20 ticks at 1 kHz, enough for a misread command to
/// show in the measured position.
pub const MIN_ENTRY_HOLD_MS: u32 = 20;

/// The longest entry hold accepted (ms): the graph's commands wait this long at start.
pub const MAX_ENTRY_HOLD_MS: u32 = 1000;

/// Default tolerance of the low-level entry check (rad, about 0.29°): a joint held still
/// moves much less; a command read differently than the bridge means moves the arm further
/// within a few ticks.
pub const DEFAULT_ENTRY_HOLD_TOLERANCE_RAD: f64 = 0.005;

/// The robot's default address (never contacted unless a configuration names it).
pub const DEFAULT_ADDRESS: &str = "192.168.1.10";

/// The robot's TCP port for everything high level.
pub const DEFAULT_PORT: u16 = 10000;

impl Default for KortexConfig {
    fn default() -> Self {
        Self {
            address: DEFAULT_ADDRESS.into(),
            port: DEFAULT_PORT,
            credentials_file: String::new(),
            connection_timeout_ms: 200,
            session_timeout_ms: 60_000,
            reply_timeout_ms: 200,
            mode: KortexMode::SingleLevel,
            cyclic_port: DEFAULT_CYCLIC_PORT,
            following_error_rad: DEFAULT_FOLLOWING_ERROR_RAD,
            entry_hold_ms: DEFAULT_ENTRY_HOLD_MS,
            entry_hold_tolerance_rad: DEFAULT_ENTRY_HOLD_TOLERANCE_RAD,
        }
    }
}

/// Why a Kortex configuration was refused.
#[derive(Debug, Clone, thiserror::Error, PartialEq)]
#[error("bridge.kortex.{key}: {reason}")]
pub struct KortexConfigError {
    /// The key under `[bridge.kortex]`.
    pub key: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl KortexConfig {
    /// Checks the settings for a bridge ticking every `period_s` seconds.
    pub fn validate(&self, period_s: f64) -> Result<(), KortexConfigError> {
        self.socket_addr()?;
        let err = |key, reason| Err(KortexConfigError { key, reason });
        if self.port == 0 {
            return err("port", "0 is not a port".into());
        }
        let period_ms = period_s * 1e3;
        let conn = f64::from(self.connection_timeout_ms);
        if conn < 2.0 * period_ms {
            return err(
                "connection_timeout_ms",
                format!(
                    "{} ms is shorter than two periods ({:.0} ms): the session would time out \
                     between two ticks",
                    self.connection_timeout_ms,
                    2.0 * period_ms
                ),
            );
        }
        if self.session_timeout_ms < self.connection_timeout_ms {
            return err(
                "session_timeout_ms",
                format!(
                    "{} ms is shorter than connection_timeout_ms ({} ms)",
                    self.session_timeout_ms, self.connection_timeout_ms
                ),
            );
        }
        if f64::from(self.reply_timeout_ms) < period_ms {
            return err(
                "reply_timeout_ms",
                format!(
                    "{} ms is shorter than one period ({period_ms:.0} ms)",
                    self.reply_timeout_ms
                ),
            );
        }
        if self.cyclic_port == 0 {
            return err("cyclic_port", "0 is not a port".into());
        }
        let fe = self.following_error_rad;
        if !(fe.is_finite() && fe > 0.0 && fe <= MAX_FOLLOWING_ERROR_RAD) {
            return err(
                "following_error_rad",
                format!("{fe} rad is not in (0, {MAX_FOLLOWING_ERROR_RAD}]"),
            );
        }
        if !(MIN_ENTRY_HOLD_MS..=MAX_ENTRY_HOLD_MS).contains(&self.entry_hold_ms) {
            return err(
                "entry_hold_ms",
                format!(
                    "{} ms is not in [{MIN_ENTRY_HOLD_MS}, {MAX_ENTRY_HOLD_MS}]",
                    self.entry_hold_ms
                ),
            );
        }
        let tol = self.entry_hold_tolerance_rad;
        if !(tol.is_finite() && tol > 0.0 && tol <= fe) {
            return err(
                "entry_hold_tolerance_rad",
                format!("{tol} rad is not in (0, following_error_rad = {fe}]"),
            );
        }
        if self.mode == KortexMode::LowLevel {
            // The Gen3 lite's cyclic channel expects a command every millisecond (issue 22;
            // the reference gives no tolerance): refuse a slower graph rather than guess.
            if period_s > LOW_LEVEL_PERIOD_S * 1.0001 {
                return err(
                    "mode",
                    format!(
                        "\"low-level\" sends a command every tick and the arm expects one every \
                         millisecond: the graph's period is {period_ms} ms; set [graph] \
                         rate_hz = 1000"
                    ),
                );
            }
            // Any address: the cyclic command's layout follows Kinova's published API
            // documentation (see msg::Command), and the entry check (entry_hold_ms) stops the
            // arm if the robot reads it differently.
        }
        Ok(())
    }

    /// The robot's UDP address of the cyclic channel.
    pub fn cyclic_addr(&self) -> Result<SocketAddr, KortexConfigError> {
        Ok(SocketAddr::new(self.socket_addr()?.ip(), self.cyclic_port))
    }

    /// The robot's socket address.
    pub fn socket_addr(&self) -> Result<SocketAddr, KortexConfigError> {
        let ip: IpAddr = self.address.parse().map_err(|_| KortexConfigError {
            key: "address",
            reason: format!("`{}` is not an IP address", self.address),
        })?;
        Ok(SocketAddr::new(ip, self.port))
    }
}

/// A user name and password for `CreateSession`. Neither appears in `Debug` output, logs or
/// error messages.
#[derive(Clone, PartialEq, Eq)]
pub struct Credentials {
    username: String,
    password: String,
}

impl Credentials {
    /// Credentials from a user name and a password.
    pub fn new(username: impl Into<String>, password: impl Into<String>) -> Self {
        Self {
            username: username.into(),
            password: password.into(),
        }
    }

    pub(crate) fn username(&self) -> &str {
        &self.username
    }

    pub(crate) fn password(&self) -> &str {
        &self.password
    }
}

impl std::fmt::Debug for Credentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Credentials(<redacted>)")
    }
}

/// What went wrong talking to the robot. Every variant names the robot's address or the call.
#[derive(Debug, thiserror::Error)]
pub enum KortexError {
    /// The configuration is unusable.
    #[error(transparent)]
    Config(#[from] KortexConfigError),
    /// The TCP connection could not be made.
    #[error("cannot connect to the Kortex robot at {addr}: {source}")]
    Connect {
        /// The robot's address.
        addr: SocketAddr,
        /// The OS error (refused, unreachable, timed out, ...).
        source: std::io::Error,
    },
    /// Reading or writing the socket failed (reset, broken pipe, write timeout).
    #[error("the connection to the Kortex robot at {addr} failed while {during}: {source}")]
    Io {
        /// The robot's address.
        addr: SocketAddr,
        /// What the bridge was doing.
        during: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
    /// The robot closed the connection between two frames.
    #[error("the Kortex robot at {addr} closed the connection")]
    Closed {
        /// The robot's address.
        addr: SocketAddr,
    },
    /// The robot closed the connection inside a frame.
    #[error(
        "the Kortex robot at {addr} closed the connection inside a frame \
         (truncated frame: {have} of {need} bytes)"
    )]
    Truncated {
        /// The robot's address.
        addr: SocketAddr,
        /// Bytes of the frame received.
        have: usize,
        /// Bytes the frame needed (at least).
        need: usize,
    },
    /// A frame from the robot could not be decoded.
    #[error("bad frame from the Kortex robot at {addr}: {source}")]
    Wire {
        /// The robot's address.
        addr: SocketAddr,
        /// The decoder's error.
        source: wire::WireError,
    },
    /// A request could not be encoded.
    #[error("cannot encode {function}: {source}")]
    Encode {
        /// The call.
        function: &'static str,
        /// The encoder's error.
        source: wire::WireError,
    },
    /// The robot answered a call with an error.
    #[error("the robot refused {function} (message {message_id}): {fault}")]
    Robot {
        /// The call.
        function: &'static str,
        /// The request's message id.
        message_id: u16,
        /// The decoded error code, sub-code and text.
        fault: wire::RobotFault,
    },
    /// A reply came for a message id no request is waiting for.
    #[error(
        "the robot sent a reply for message id {message_id} ({function}) that no request is \
         waiting for"
    )]
    UnknownReply {
        /// The reply's message id.
        message_id: u16,
        /// The function named in the reply.
        function: String,
    },
    /// A request had no reply in time.
    #[error("no reply to {function} (message {message_id}) within {waited_ms} ms{note}")]
    ReplyTimeout {
        /// The call.
        function: &'static str,
        /// The request's message id.
        message_id: u16,
        /// How long the bridge waited.
        waited_ms: u64,
        /// What else is known (bytes skipped to resynchronise the stream).
        note: String,
    },
    /// A reply's payload did not decode as the message it should be.
    #[error("cannot decode the reply to {function}: {reason}")]
    Payload {
        /// The call.
        function: &'static str,
        /// What was wrong.
        reason: String,
    },
    /// The robot is not the arm of the graph's robot profile: its actuator count, or the
    /// model it reports, is another arm's.
    #[error(
        "wrong robot: the robot found is {found}, but the configured robot profile `{profile}` \
         is {expected}; set [graph] robot to the arm's profile, or connect to the arm the \
         profile describes"
    )]
    WrongRobot {
        /// What the robot reported.
        found: FoundRobot,
        /// The configured profile's name (`[graph] robot`).
        profile: String,
        /// The profile's arm, as [`FoundRobot`] would say it (`a Gen3 (Kortex model L53, 7
        /// actuators)`).
        expected: String,
    },
    /// The robot's kinematic hard limits are unusable.
    #[error("the robot's kinematic hard limits are unusable: {reason}")]
    Limits {
        /// What was wrong.
        reason: String,
    },
    /// The session is closed (after a fault or shutdown).
    #[error("the Kortex session is closed")]
    SessionClosed,
    /// Low-level mode is entered only from rest, and a joint was moving.
    #[error(
        "low-level mode refused: the arm is not at rest (joint {joint} moves at {speed_rad_s:.4} \
         rad/s; at rest is below {rest_rad_s} rad/s)"
    )]
    NotAtRest {
        /// The first joint found moving (0-based).
        joint: usize,
        /// Its measured speed (rad/s).
        speed_rad_s: f64,
        /// The bound of "at rest" (rad/s).
        rest_rad_s: f64,
    },
    /// Low-level mode: a joint is further from its commanded position than the bound.
    #[error(
        "following error: joint {joint} measured {measured_rad:.4} rad, commanded \
         {commanded_rad:.4} rad ({error_rad:.4} rad apart; bridge.kortex.following_error_rad \
         = {bound_rad})"
    )]
    FollowingError {
        /// The joint (0-based).
        joint: usize,
        /// Its measured angle (rad).
        measured_rad: f64,
        /// Its commanded angle (rad).
        commanded_rad: f64,
        /// The distance between them (rad).
        error_rad: f64,
        /// The bound (rad).
        bound_rad: f64,
    },
    /// Low-level mode, the entry check: while the bridge held the measured position, a joint
    /// moved further than the tolerance from it. The arm did not do what the bridge commanded:
    /// the cyclic command's encoding, or the arm's state, is suspect.
    #[error(
        "low-level entry check failed: joint {joint} measured {measured_rad:.4} rad while the \
         bridge held it at {held_rad:.4} rad ({error_rad:.4} rad apart, {after_ms:.0} ms into the \
         {hold_ms} ms hold; bridge.kortex.entry_hold_tolerance_rad = {tolerance_rad}): the arm \
         did not follow the held position, so the cyclic command's encoding or the arm's state \
         is suspect"
    )]
    EntryHold {
        /// The first joint found beyond the tolerance (0-based).
        joint: usize,
        /// Its measured angle (rad).
        measured_rad: f64,
        /// The position the bridge held it at (rad): the measured one at entry.
        held_rad: f64,
        /// The distance between them (rad, on the circle).
        error_rad: f64,
        /// The tolerance (rad).
        tolerance_rad: f64,
        /// How far into the hold (ms of ticks).
        after_ms: f64,
        /// The hold's length (ms).
        hold_ms: u32,
    },
    /// Low-level mode: the robot's feedback reports the arm in fault.
    #[error("the robot reports the arm in fault during low-level servoing (active state {state})")]
    ArmInFault {
        /// `BaseFeedback.active_state`.
        state: i32,
    },
}

impl KortexError {
    /// Whether frames can still be sent after this error (to stop the arm and close the
    /// session).
    pub fn connection_usable(&self) -> bool {
        !matches!(
            self,
            Self::Connect { .. }
                | Self::Io { .. }
                | Self::Closed { .. }
                | Self::Truncated { .. }
                | Self::SessionClosed
        )
    }
}

/// A Kinova arm model as the Kortex API names it (`CompleteProductConfiguration.model`,
/// [`msg::model_id`]), with the product name Kinova sells it under.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KortexModel {
    /// The `ModelId` value.
    pub id: i32,
    /// Kinova's code for it (`L53`).
    pub code: &'static str,
    /// The product name (`Gen3`): a robot profile whose description is this name is this
    /// model.
    pub product: &'static str,
}

/// The Kortex models the bridge knows (see [`msg::model_id`] for the source of the values).
pub const KORTEX_MODELS: [KortexModel; 3] = [
    KortexModel {
        id: msg::model_id::L53,
        code: "L53",
        product: "Gen3",
    },
    KortexModel {
        id: msg::model_id::L31,
        code: "L31",
        product: "Gen3 lite",
    },
    KortexModel {
        id: msg::model_id::HDK,
        code: "HDK",
        product: "hardware development kit",
    },
];

impl KortexModel {
    /// The model of a `ModelId` value, if the bridge knows it (`None` for 0, not reported).
    pub fn from_id(id: i32) -> Option<Self> {
        KORTEX_MODELS.into_iter().find(|m| m.id == id)
    }

    /// The model of the arm `robot` describes: the one whose product name is the profile's
    /// description (`None`: not a Kinova arm the bridge knows).
    pub fn of_profile(robot: &kinematics::RobotProfile) -> Option<Self> {
        KORTEX_MODELS
            .into_iter()
            .find(|m| m.product == robot.description())
    }
}

/// What a robot says it is at connect: `Base.GetActuatorCount` and the model of
/// `Base.GetProductConfiguration`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FoundRobot {
    /// `CompleteProductConfiguration.model` ([`msg::model_id`]; 0: not reported).
    pub model: i32,
    /// Actuators reported.
    pub actuators: u32,
}

impl FoundRobot {
    /// The model, if reported and known.
    pub fn kortex_model(&self) -> Option<KortexModel> {
        KortexModel::from_id(self.model)
    }

    /// What the arm of `robot` would report (its model 0 if it is not a Kinova arm the
    /// bridge knows).
    pub fn of_profile(robot: &kinematics::RobotProfile) -> Self {
        Self {
            model: KortexModel::of_profile(robot).map_or(msg::model_id::UNSPECIFIED, |m| m.id),
            actuators: u32::try_from(robot.n_joints()).unwrap_or(u32::MAX),
        }
    }

    /// Whether this is the arm of `robot`: the actuator count always; the model where the arm
    /// reports one the bridge knows (a Kinova model found where the profile describes another
    /// arm, or none the bridge knows, is a mismatch).
    pub fn check(&self, robot: &kinematics::RobotProfile) -> Result<(), KortexError> {
        let count_ok = self.actuators as usize == robot.n_joints();
        let model_ok = match self.kortex_model() {
            None => true,
            Some(m) => KortexModel::of_profile(robot).is_some_and(|p| p.id == m.id),
        };
        if count_ok && model_ok {
            return Ok(());
        }
        let expected = FoundRobot::of_profile(robot);
        let expected = match expected.kortex_model() {
            Some(_) => expected.to_string(),
            None => format!(
                "a {} ({} joints; not a Kortex model the bridge knows)",
                robot.description(),
                robot.n_joints()
            ),
        };
        Err(KortexError::WrongRobot {
            found: *self,
            profile: robot.name().to_owned(),
            expected,
        })
    }
}

impl std::fmt::Display for FoundRobot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self.actuators;
        match self.kortex_model() {
            Some(m) => write!(
                f,
                "a {} (Kortex model {}, {n} actuators)",
                m.product, m.code
            ),
            None if self.model == msg::model_id::UNSPECIFIED => {
                write!(f, "an arm of {n} actuators (model not reported)")
            }
            None => write!(
                f,
                "an arm of {n} actuators (Kortex model {}, unknown to the bridge)",
                self.model
            ),
        }
    }
}

/// Wraps an angle in degrees to `(-180, 180]` (the robot reports `[0, 360)`).
pub fn wrap_deg(deg: f64) -> f64 {
    let x = deg.rem_euclid(360.0);
    if x > 180.0 { x - 360.0 } else { x }
}

/// Angle (deg, any range) to radians in `(-pi, pi]`.
pub fn angle_deg_to_rad(deg: f64) -> f64 {
    wrap_deg(deg).to_radians()
}

/// Angle (rad) to degrees in `[0, 360)`, as the robot reports it.
pub fn angle_rad_to_wire_deg(rad: f64) -> f64 {
    let d = rad.to_degrees().rem_euclid(360.0);
    // rem_euclid can round up to exactly 360 for tiny negative inputs.
    if d >= 360.0 { 0.0 } else { d }
}

/// Scales `v` by one common factor so that every `|v[j]| <= limit[j]`, keeping its direction.
/// Returns the factor (1 when nothing was too fast).
pub fn scale_to_limits(v: &mut [f64], limit: &[f64]) -> f64 {
    let mut k: f64 = 1.0;
    for (x, l) in v.iter().zip(limit) {
        if x.abs() > *l {
            k = k.min(l / x.abs());
        }
    }
    if k < 1.0 {
        v.iter_mut().for_each(|x| *x *= k);
    }
    k
}

/// The JointSpeeds message for joint velocities in rad/s (every joint named, 0-based).
pub fn joint_speeds_msg(qdot_rad_s: &[f64]) -> msg::JointSpeeds {
    msg::JointSpeeds {
        joint_speeds: qdot_rad_s
            .iter()
            .enumerate()
            .map(|(j, v)| msg::JointSpeed {
                joint_identifier: j as u32,
                value: v.to_degrees() as f32,
                duration: 0,
            })
            .collect(),
        duration: 0,
    }
}

/// The GripperCommand message for a position `0` open .. `1` closed.
pub fn gripper_position_msg(position: f64) -> msg::GripperCommand {
    msg::GripperCommand {
        mode: msg::gripper_mode::POSITION,
        gripper: Some(msg::Gripper {
            finger: vec![msg::Finger {
                finger_identifier: msg::GRIPPER_FINGER_ID,
                value: position.clamp(0.0, 1.0) as f32,
            }],
        }),
        duration: 0,
    }
}

/// The stack's reading from a Feedback message of an arm of `n` joints: angles wrapped and in
/// radians, speeds in rad/s, the gripper from percent to `[0, 1]` (`gripper_fallback` when
/// the feedback has no gripper). `limits` flags a joint within 0.01 rad of its limit.
pub fn reading_from_feedback(
    fb: &msg::Feedback,
    n: usize,
    limits: &kinematics::ArmLimits,
    gripper_fallback: f64,
) -> Result<crate::Reading, String> {
    if fb.actuators.len() != n {
        return Err(format!(
            "feedback has {} actuators, expected {n}",
            fb.actuators.len()
        ));
    }
    let mut r = crate::Reading {
        q_rad: [0.0; ipc_types::MAX_JOINTS],
        qdot_rad_s: [0.0; ipc_types::MAX_JOINTS],
        gripper: gripper_fallback,
        at_limit: false,
    };
    for (j, a) in fb.actuators.iter().enumerate() {
        let (p, v) = (f64::from(a.position), f64::from(a.velocity));
        if !(p.is_finite() && v.is_finite()) {
            return Err(format!(
                "actuator {j} reports a non-finite angle or speed ({p} deg, {v} deg/s)"
            ));
        }
        r.q_rad[j] = angle_deg_to_rad(p);
        r.qdot_rad_s[j] = v.to_radians();
        if let (Some(lo), Some(hi)) = (limits.lower_rad.get(j), limits.upper_rad.get(j))
            && (r.q_rad[j] <= lo + 0.01 || r.q_rad[j] >= hi - 0.01)
        {
            r.at_limit = true;
        }
    }
    if let Some(m) = fb
        .interconnect
        .as_ref()
        .and_then(|i| i.gripper_feedback.as_ref())
        .and_then(|g| g.motor.first())
    {
        let c = f64::from(m.position) / 100.0;
        if c.is_finite() {
            r.gripper = c.clamp(0.0, 1.0);
        }
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::msg::*;
    use super::wire::*;
    use super::*;
    use prost::Message as _;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    fn tcp(session: u16, id: u16, f: Function, payload: Vec<u8>) -> Vec<u8> {
        let frame = Frame::new(FrameType::Request, session, id, f.uid(), payload).unwrap();
        let mut out = Vec::new();
        frame.encode_tcp(&mut out).unwrap();
        out
    }

    fn admin_session() -> CreateSessionInfo {
        CreateSessionInfo {
            username: "admin".into(),
            session_inactivity_timeout: 60_000,
            password: "admin".into(),
            connection_inactivity_timeout: 2000,
        }
    }

    // The "Expected encodings (hex)" of kortex-protocol.md, every one of them.

    #[test]
    fn encoding_create_session_info_payload() {
        assert_eq!(
            admin_session().encode_to_vec(),
            hex("0a 05 61 64 6d 69 6e 10 e0 d4 03 1a 05 61 64 6d 69 6e 20 d0 0f")
        );
    }

    #[test]
    fn encoding_create_session_request() {
        assert_eq!(
            tcp(
                0,
                1,
                Function::CreateSession,
                admin_session().encode_to_vec()
            ),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 2d 0a 14 0d 00 00 00 11 15 01 00 00 00 1d 01 00 \
                 01 10 25 15 00 00 00 12 15 0a 05 61 64 6d 69 6e 10 e0 d4 03 1a 05 61 64 6d 69 6e \
                 20 d0 0f"
            )
        );
    }

    #[test]
    fn encoding_set_servoing_mode_request() {
        let payload = ServoingModeInformation {
            servoing_mode: servoing_mode::SINGLE_LEVEL,
        }
        .encode_to_vec();
        assert_eq!(
            tcp(0x1234, 2, Function::SetServoingMode, payload),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 1a 0a 14 0d 00 00 00 11 15 02 00 34 12 1d 98 00 \
                 02 10 25 02 00 00 00 12 02 08 02"
            )
        );
    }

    #[test]
    fn encoding_send_joint_speeds_request() {
        // From rad/s, as the bridge builds it: [10, -5, 0, 0, 0, 20] deg/s.
        let qdot: Vec<f64> = [10.0f64, -5.0, 0.0, 0.0, 0.0, 20.0]
            .iter()
            .map(|d| d.to_radians())
            .collect();
        let payload = joint_speeds_msg(&qdot).encode_to_vec();
        assert_eq!(
            tcp(0x1234, 3, Function::SendJointSpeedsCommand, payload),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 3d 0a 14 0d 00 00 00 11 15 03 00 34 12 1d 84 00 \
                 02 10 25 25 00 00 00 12 25 0a 05 15 00 00 20 41 0a 07 08 01 15 00 00 a0 c0 0a 02 \
                 08 02 0a 02 08 03 0a 02 08 04 0a 07 08 05 15 00 00 a0 41"
            )
        );
    }

    #[test]
    fn encoding_get_measured_joint_angles_request() {
        assert_eq!(
            tcp(0x1234, 4, Function::GetMeasuredJointAngles, Vec::new()),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 11 0a 0f 0d 00 00 00 11 15 04 00 34 12 1d 7e 00 \
                 02 10"
            )
        );
    }

    #[test]
    fn encoding_stop_request() {
        assert_eq!(
            tcp(0x1234, 5, Function::Stop, Vec::new()),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 11 0a 0f 0d 00 00 00 11 15 05 00 34 12 1d 70 00 \
                 02 10"
            )
        );
    }

    #[test]
    fn encoding_gripper_command_payload() {
        assert_eq!(
            gripper_position_msg(0.5).encode_to_vec(),
            hex("08 03 12 09 0a 07 08 01 15 00 00 00 3f")
        );
    }

    #[test]
    fn encoding_refresh_feedback_udp_bare_frame() {
        let frame = Frame::new(
            FrameType::Request,
            0x1234,
            6,
            Function::RefreshFeedback.uid(),
            Vec::new(),
        )
        .unwrap();
        assert_eq!(
            frame.encode_bare(),
            hex("0a 0f 0d 00 00 00 11 15 06 00 34 12 1d 03 00 03 10")
        );
    }

    #[test]
    fn encoding_keep_alive_request() {
        assert_eq!(
            tcp(0x1234, 7, Function::KeepAlive, Vec::new()),
            hex(
                "07 78 45 74 52 6f 4b 07 00 00 00 11 0a 0f 0d 00 00 00 11 15 07 00 34 12 1d 03 00 \
                 01 10"
            )
        );
    }

    #[test]
    fn expected_frames_decode_to_what_they_say() {
        let bytes = hex(
            "07 78 45 74 52 6f 4b 07 00 00 00 1a 0a 14 0d 00 00 00 11 15 02 00 34 12 1d 98 00 02 \
             10 25 02 00 00 00 12 02 08 02",
        );
        let mut d = FrameDecoder::new();
        d.push(&bytes);
        let Some(Ok(Decoded::Frame(f))) = d.next_frame() else {
            panic!("no frame")
        };
        let h = f.header();
        assert_eq!(h.frame_type(), Some(FrameType::Request));
        assert_eq!((h.session_id(), h.message_id()), (0x1234, 2));
        assert_eq!(
            Function::from_uid(h.function_uid()),
            Some(Function::SetServoingMode)
        );
        assert_eq!(h.payload_len(), 2);
        let m = ServoingModeInformation::decode(f.payload.as_slice()).unwrap();
        assert_eq!(m.servoing_mode, servoing_mode::SINGLE_LEVEL);
    }

    #[test]
    fn function_uids_and_names() {
        for f in Function::ALL {
            assert_eq!(Function::from_uid(f.uid()), Some(f));
            assert!(f.name().contains('.'));
        }
        assert_eq!(function_name(0x2_0084), "Base.SendJointSpeedsCommand");
        assert_eq!(function_name(0x9_9999), "function 0x99999");
    }

    #[test]
    fn angles_wrap_into_minus_180_to_180() {
        for (d, w) in [
            (0.0, 0.0),
            (90.0, 90.0),
            (180.0, 180.0),
            (180.5, -179.5),
            (359.5, -0.5),
            (360.0, 0.0),
            (-180.0, 180.0),
            (-190.0, 170.0),
            (720.0 + 45.0, 45.0),
        ] {
            assert!((wrap_deg(d) - w).abs() < 1e-9, "{d} -> {}", wrap_deg(d));
        }
        for q in [-3.1, -1.0, -1e-12, 0.0, 0.5, 2.68, std::f64::consts::PI] {
            let wire = angle_rad_to_wire_deg(q);
            assert!((0.0..360.0).contains(&wire), "{q} -> {wire}");
            let back = angle_deg_to_rad(wire);
            assert!((back - q).abs() < 1e-9, "{q} -> {wire} -> {back}");
        }
    }

    #[test]
    fn scaling_to_limits_keeps_the_direction() {
        let mut v = [1.0, -0.5, 0.1];
        let k = scale_to_limits(&mut v, &[0.5, 0.5, 0.5]);
        assert_eq!(k, 0.5);
        assert_eq!(v, [0.5, -0.25, 0.05]);
        let mut v = [0.2, -0.3];
        assert_eq!(scale_to_limits(&mut v, &[0.5, 0.5]), 1.0);
        assert_eq!(v, [0.2, -0.3]);
    }

    #[test]
    fn feedback_becomes_a_reading() {
        let limits = kinematics::gen3_lite::limits();
        let mut fb = Feedback::default();
        for (p, v) in [
            (350.0, -10.0),
            (10.0, 5.0),
            (180.0, 0.0),
            (0.0, 0.0),
            (153.9, 0.0),
            (0.0, 0.0),
        ] {
            fb.actuators.push(ActuatorFeedback {
                position: p,
                velocity: v,
                ..Default::default()
            });
        }
        let r = reading_from_feedback(&fb, 6, &limits, 0.3).unwrap();
        assert!((r.q_rad[0] + 10f64.to_radians()).abs() < 1e-6);
        assert!((r.qdot_rad_s[0] + 10f64.to_radians()).abs() < 1e-6);
        assert!((r.q_rad[2] - std::f64::consts::PI).abs() < 1e-6);
        assert!(r.at_limit, "joint 3 at 180 deg is past its limit");
        assert_eq!(r.gripper, 0.3, "no gripper in the feedback: the fallback");
        fb.interconnect = Some(InterconnectFeedback {
            gripper_feedback: Some(GripperFeedback {
                motor: vec![MotorFeedback {
                    position: 40.0,
                    ..Default::default()
                }],
            }),
        });
        assert!((reading_from_feedback(&fb, 6, &limits, 0.3).unwrap().gripper - 0.4).abs() < 1e-6);
        let e = reading_from_feedback(&fb, 7, &limits, 0.0).unwrap_err();
        assert!(e.contains("6 actuators, expected 7"), "{e}");
        fb.actuators[1].position = f32::NAN;
        assert!(reading_from_feedback(&fb, 6, &limits, 0.0).is_err());
    }

    #[test]
    fn config_defaults_are_valid_and_bad_values_are_named() {
        let period = 0.025;
        KortexConfig::default().validate(period).unwrap();
        let bad = |c: KortexConfig| c.validate(period).unwrap_err().to_string();
        let e = bad(KortexConfig {
            address: "robot.local".into(),
            ..Default::default()
        });
        assert!(e.starts_with("bridge.kortex.address:"), "{e}");
        let e = bad(KortexConfig {
            connection_timeout_ms: 30,
            ..Default::default()
        });
        assert!(
            e.contains("connection_timeout_ms") && e.contains("two periods"),
            "{e}"
        );
        let e = bad(KortexConfig {
            session_timeout_ms: 100,
            ..Default::default()
        });
        assert!(e.contains("session_timeout_ms"), "{e}");
        let e = bad(KortexConfig {
            port: 0,
            ..Default::default()
        });
        assert!(e.contains("port"), "{e}");
        let e = bad(KortexConfig {
            reply_timeout_ms: 10,
            ..Default::default()
        });
        assert!(e.contains("reply_timeout_ms"), "{e}");
    }

    #[test]
    fn low_level_settings_are_validated_and_named() {
        let period = 0.001;
        let local = KortexConfig {
            address: "127.0.0.1".into(),
            mode: KortexMode::LowLevel,
            ..Default::default()
        };
        local.validate(period).unwrap();
        assert_eq!(local.cyclic_addr().unwrap().port(), DEFAULT_CYCLIC_PORT);
        // A real arm's address is accepted (validation only: nothing is contacted).
        let arm = KortexConfig {
            address: DEFAULT_ADDRESS.into(),
            ..local.clone()
        };
        arm.validate(period).unwrap();
        assert_eq!(
            arm.cyclic_addr().unwrap(),
            SocketAddr::from(([192, 168, 1, 10], DEFAULT_CYCLIC_PORT))
        );
        let bad = |c: KortexConfig| c.validate(period).unwrap_err().to_string();
        for fe in [0.0, -0.1, f64::NAN, 0.6] {
            let e = bad(KortexConfig {
                following_error_rad: fe,
                ..local.clone()
            });
            assert!(e.starts_with("bridge.kortex.following_error_rad:"), "{e}");
        }
        let e = bad(KortexConfig {
            cyclic_port: 0,
            ..local.clone()
        });
        assert!(e.starts_with("bridge.kortex.cyclic_port:"), "{e}");
        let e = local.validate(0.025).unwrap_err().to_string();
        assert!(
            e.starts_with("bridge.kortex.mode:") && e.contains("rate_hz = 1000"),
            "{e}"
        );
        // The slower-rate refusal holds for a real arm's address too.
        let e = arm.validate(0.025).unwrap_err().to_string();
        assert!(e.starts_with("bridge.kortex.mode:"), "{e}");
        // The mode's spelling in TOML.
        let c: KortexConfig = toml::from_str("mode = \"low-level\"").unwrap();
        assert_eq!(c.mode, KortexMode::LowLevel);
        let c: KortexConfig = toml::from_str("").unwrap();
        assert_eq!(c.mode, KortexMode::SingleLevel);
        assert!(toml::from_str::<KortexConfig>("mode = \"lowlevel\"").is_err());
    }

    #[test]
    fn entry_hold_keys_are_validated_and_bad_values_named() {
        let period = 0.001;
        let cfg = KortexConfig {
            mode: KortexMode::LowLevel,
            ..Default::default()
        };
        assert_eq!(cfg.entry_hold_ms, 100);
        assert_eq!(cfg.entry_hold_tolerance_rad, 0.005);
        cfg.validate(period).unwrap();
        let bad = |c: KortexConfig| c.validate(period).unwrap_err().to_string();
        for ms in [MIN_ENTRY_HOLD_MS, 250, MAX_ENTRY_HOLD_MS] {
            KortexConfig {
                entry_hold_ms: ms,
                ..cfg.clone()
            }
            .validate(period)
            .unwrap();
        }
        for ms in [0, MIN_ENTRY_HOLD_MS - 1, MAX_ENTRY_HOLD_MS + 1, u32::MAX] {
            let e = bad(KortexConfig {
                entry_hold_ms: ms,
                ..cfg.clone()
            });
            assert!(
                e.starts_with("bridge.kortex.entry_hold_ms:")
                    && e.contains(&format!("{ms} ms"))
                    && e.contains("[20, 1000]"),
                "{e}"
            );
        }
        // Up to the following-error bound, which is the check after the hold.
        for tol in [1e-4, 0.05] {
            KortexConfig {
                entry_hold_tolerance_rad: tol,
                ..cfg.clone()
            }
            .validate(period)
            .unwrap();
        }
        for tol in [0.0, -0.001, 0.051, f64::NAN, f64::INFINITY] {
            let e = bad(KortexConfig {
                entry_hold_tolerance_rad: tol,
                ..cfg.clone()
            });
            assert!(
                e.starts_with("bridge.kortex.entry_hold_tolerance_rad:")
                    && e.contains(&format!("{tol} rad"))
                    && e.contains("following_error_rad = 0.05"),
                "{e}"
            );
        }
        let e = bad(KortexConfig {
            following_error_rad: 0.01,
            entry_hold_tolerance_rad: 0.02,
            ..cfg.clone()
        });
        assert!(
            e.starts_with("bridge.kortex.entry_hold_tolerance_rad:"),
            "{e}"
        );
        // Both keys in TOML, and unknown spellings refused.
        let c: KortexConfig =
            toml::from_str("entry_hold_ms = 200\nentry_hold_tolerance_rad = 0.002").unwrap();
        assert_eq!((c.entry_hold_ms, c.entry_hold_tolerance_rad), (200, 0.002));
        assert!(toml::from_str::<KortexConfig>("entry_hold = 200").is_err());
    }

    #[test]
    fn credentials_never_show_in_debug() {
        let c = Credentials::new("the-user", "pa55word");
        let text = format!("{c:?} {c:#?}");
        assert!(
            !text.contains("the-user") && !text.contains("pa55word"),
            "{text}"
        );
    }
}
