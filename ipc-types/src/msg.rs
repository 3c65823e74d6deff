//! The message types of the graph.
//!
//! Every message is fixed-size, `Copy`, `#[repr(C)]`, free of pointers and of padding (a gap
//! is an explicit `reserved` field, always 0; the `zerocopy` derives refuse a message with
//! padding or with invalid bit patterns at compile time, so `transport::uds` can send its
//! bytes), and carries
//! * the tick it belongs to (the bridge's clock is the only clock; see [`RobotState::tick`]),
//! * `t_ns`, the monotonic time at which it was produced ([`crate::time::now_ns`]),
//! * the timestamps it inherited from the messages it was computed from,
//!
//! so that any process can compute a sample's age or the end-to-end latency without a clock of
//! its own. Type names are stable strings (`scl::RobotState`), so separately built binaries
//! connect. Joint arrays are sized by [`MAX_JOINTS`] with an explicit count.
//!
//! Each message is declared once, through [`crate::fields`]' `message!`, which also yields its
//! field visitor and layout ([`crate::fields::Fields`]); each flag bit once, with its short name,
//! through `bits!`.

#[cfg(feature = "json")]
pub mod json;

use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout};

use crate::fields::message;

/// Capacity of every joint array. The Gen3 lite uses 6.
pub const MAX_JOINTS: usize = 8;

/// Number of joystick axes the maps take (the paper's 2-D action).
pub const ACTION_DIM: usize = 2;

/// The tick value of "no tick": a joystick sample taken before the first robot state, a robot
/// state that executed no command.
pub const NO_TICK: u64 = u64::MAX;

/// Joystick button bits in [`JoystickInput::buttons`].
pub mod buttons {
    crate::fields::bits! {
        /// The deadman button is held.
        DEADMAN = 1 << 0, "deadman";
        /// The mode-switch button is pressed.
        MODE = 1 << 1, "mode";
        /// The e-stop button is pressed.
        ESTOP = 1 << 2, "estop";
        /// The gripper button is held (close while held).
        GRIPPER = 1 << 3, "gripper";
        /// The input device is gone (unplugged, or not found yet): the sample is neutral and the
        /// joystick process is waiting for the device to come back.
        NO_DEVICE = 1 << 4, "no-device";
    }
}

message! {
    /// One sample of the operator's input device.
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::JoystickInput")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct JoystickInput {
        /// Newest [`RobotState::tick`] the joystick process had seen when it took this sample
        /// ([`NO_TICK`] before the first; `null` in JSON).
        #[cfg_attr(
            feature = "json",
            serde(with = "crate::msg::json::tick"),
            schemars(with = "crate::msg::json::tick::Schema")
        )]
        pub tick: u64,
        /// When the device was read (monotonic ns).
        pub t_ns: u64,
        /// Sample counter of the publishing process, from 0.
        pub seq: u64,
        /// The two axes, each nominally in `[-1, 1]`; the mapper enforces `|a| <= 1`.
        pub axes: [f32; ACTION_DIM],
        /// Gripper rate input in `[-1, 1]`: positive closes, negative opens.
        pub gripper: f32,
        /// Button bits, see [`buttons`].
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = buttons::NAMES)))]
        pub buttons: u32,
    }
}

impl JoystickInput {
    /// A neutral sample (axes at rest) produced at `t_ns`.
    pub fn neutral(t_ns: u64) -> Self {
        Self {
            tick: NO_TICK,
            t_ns,
            seq: 0,
            axes: [0.0; ACTION_DIM],
            gripper: 0.0,
            buttons: 0,
        }
    }
}

/// [`RobotState::flags`] bits.
pub mod state_flags {
    crate::fields::bits! {
        /// The bridge is executing a controlled stop this period.
        STOPPING = 1 << 0, "stopping";
        /// No valid command for the previous tick arrived in time (a counted miss).
        MISSED = 1 << 1, "missed";
        /// The bridge is shutting down; this is its last state.
        SHUTDOWN = 1 << 2, "shutdown";
        /// A joint is at its position limit.
        AT_LIMIT = 1 << 3, "at-limit";
        /// The robot is the mock Gen3 lite, not hardware.
        MOCK = 1 << 4, "mock";
        /// The command executed during the last period was a stop decided by the safety filter
        /// (its `SafeCommand` carried `safe_flags::STOP`).
        SAFETY_STOP = 1 << 5, "safety-stop";
    }
}

message! {
    /// The arm's state at tick `tick`, published by the hardware bridge (the graph's only clock).
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::RobotState")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct RobotState {
        /// Tick number, from 0, one every period (25 ms at 40 Hz).
        pub tick: u64,
        /// When the state was published (monotonic ns).
        pub t_ns: u64,
        /// The tick of the command executed during the period that ended with this state, or
        /// [`NO_TICK`] (`null` in JSON) if the bridge executed a stop instead.
        #[cfg_attr(
            feature = "json",
            serde(with = "crate::msg::json::tick"),
            schemars(with = "crate::msg::json::tick::Schema")
        )]
        pub applied_tick: u64,
        /// Ticks missed since the bridge started (cumulative).
        pub missed: u64,
        /// Number of valid entries in the joint arrays.
        pub n_joints: u32,
        /// [`state_flags`] bits.
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = state_flags::NAMES)))]
        pub flags: u32,
        /// Joint angles (rad).
        pub q_rad: [f64; MAX_JOINTS],
        /// Joint velocities (rad/s).
        pub qdot_rad_s: [f64; MAX_JOINTS],
        /// Gripper state `c` in `[0, 1]` (0 open, 1 closed).
        pub gripper: f64,
    }
}

impl RobotState {
    /// The state of an arm of `n_joints` joints at rest at the zero pose, with gripper open,
    /// at tick `tick`, stamped `t_ns`; nothing executed, nothing missed.
    pub fn at_rest(tick: u64, t_ns: u64, n_joints: u32) -> Self {
        Self {
            tick,
            t_ns,
            applied_tick: NO_TICK,
            missed: 0,
            n_joints,
            flags: 0,
            q_rad: [0.0; MAX_JOINTS],
            qdot_rad_s: [0.0; MAX_JOINTS],
            gripper: 0.0,
        }
    }

    /// The valid joint angles.
    pub fn q(&self) -> &[f64] {
        &self.q_rad[..(self.n_joints as usize).min(MAX_JOINTS)]
    }

    /// The valid joint velocities.
    pub fn qdot(&self) -> &[f64] {
        &self.qdot_rad_s[..(self.n_joints as usize).min(MAX_JOINTS)]
    }
}

/// [`MapperCommand::flags`] bits.
pub mod mapper_flags {
    crate::fields::bits! {
        /// No joystick sample has arrived yet; the action was zero.
        NO_INPUT = 1 << 0, "no-input";
        /// The joystick sample had a non-finite axis; the action was zero.
        INPUT_NON_FINITE = 1 << 1, "input-non-finite";
        /// The action was longer than 1 and was clamped radially.
        INPUT_CLAMPED = 1 << 2, "input-clamped";
        /// The model produced a non-finite velocity; the command was zeroed.
        OUTPUT_NON_FINITE = 1 << 3, "output-non-finite";
        /// The robot state was unusable (non-finite joint angle, wrong joint count); the command
        /// was zeroed.
        STATE_INVALID = 1 << 4, "state-invalid";
        /// The newest joystick sample answers a tick two or more before this one: the joystick,
        /// which answers every tick, has stopped. The action was zero; safety stops the arm.
        INPUT_STALE = 1 << 5, "input-stale";
        /// The map ignores the action by design (the drill map `constant:qdot=...`): it moves
        /// whenever safety lets it, so a command without any joystick sample yet is not stale,
        /// and with the deadman required its release and press alone re-arm the arm after a
        /// stop.
        IGNORES_INPUT = 1 << 6, "ignores-input";
        /// The joystick sample answers no robot tick (its source published it before it saw
        /// one: a device's reading at start-up, an external operator's first sample). Used as
        /// usual, but not as the operator's neutral input for restart prevention.
        INPUT_NO_TICK = 1 << 7, "input-no-tick";
    }
}

message! {
    /// A joint-velocity command for tick `tick`, produced by one mapper process.
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::MapperCommand")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct MapperCommand {
        /// The tick of the robot state this command was computed from.
        pub tick: u64,
        /// When the command was published (monotonic ns).
        pub t_ns: u64,
        /// Inherited: `t_ns` of the robot state used.
        pub state_t_ns: u64,
        /// When the mapper received that robot state (monotonic ns).
        pub state_rx_ns: u64,
        /// Inherited: `t_ns` of the joystick sample used (0 if none).
        pub joystick_t_ns: u64,
        /// When the mapper received that joystick sample (monotonic ns; 0 if none).
        pub joystick_rx_ns: u64,
        /// Inherited: `seq` of the joystick sample used.
        pub joystick_seq: u64,
        /// Time spent in the map itself (ns), for compute-versus-transport figures.
        pub compute_ns: u64,
        /// Id of the mapper process; safety forwards only the active id.
        pub mapper_id: u32,
        /// Number of valid entries in `qdot_rad_s`.
        pub n_joints: u32,
        /// [`mapper_flags`] bits.
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = mapper_flags::NAMES)))]
        pub flags: u32,
        /// Inherited: the joystick's [`buttons`] bits (deadman, e-stop) of the sample used.
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = buttons::NAMES)))]
        pub buttons: u32,
        /// The action `a` after clamping, as fed to the map.
        pub action: [f32; ACTION_DIM],
        /// Commanded joint velocities (rad/s).
        pub qdot_rad_s: [f64; MAX_JOINTS],
        /// Commanded gripper rate (1/s on the `c` scale; positive closes).
        pub gripper_rate: f64,
    }
    /// The mapper process's own stamps, which the replayed step does not compute: when it
    /// published (`t_ns`), when it received the robot state and the joystick sample
    /// (`state_rx_ns`, `joystick_rx_ns`) and how long its map took (`compute_ns`).
    not_replayed: [t_ns, state_rx_ns, joystick_rx_ns, compute_ns];
}

/// [`SafeCommand::flags`] bits: which rule of the safety filter acted this tick.
pub mod safe_flags {
    crate::fields::bits! {
        /// A non-finite value in the command, the state or the operator's input (the mapper's
        /// `input-non-finite`, or a non-finite action): controlled stop, fault.
        NON_FINITE = 1 << 0, "non-finite";
        /// The command's robot state was older than allowed: stop.
        STALE_STATE = 1 << 1, "stale-state";
        /// The command's joystick sample was older than allowed: stop.
        STALE_JOYSTICK = 1 << 2, "stale-joystick";
        /// The command's tick was not the newest robot tick: stop.
        STALE_COMMAND = 1 << 3, "stale-command";
        /// The velocity was scaled down uniformly to respect a joint speed limit.
        VELOCITY_SCALED = 1 << 4, "velocity";
        /// The output is a stop (zero velocity) decided by the filter.
        STOP = 1 << 5, "stop";
        /// The command's joint count does not match the robot's.
        BAD_SHAPE = 1 << 6, "bad-shape";
        /// The change from the previous command was scaled down to the acceleration limits.
        ACCEL_LIMITED = 1 << 7, "acceleration";
        /// The supervisor holds the arm (a process of the input side is down): stop.
        HOLD = 1 << 8, "hold";
        /// A joint would have passed its limit margin: the command was scaled down (braking in
        /// time, motion away from the limit stays free).
        POSITION_LIMITED = 1 << 9, "position";
        /// The tool would have left the workspace (table plane, box): the command was scaled
        /// down; motion back inside stays free.
        WORKSPACE_LIMITED = 1 << 10, "workspace";
        /// The deadman button is required and was not held: stop.
        DEADMAN = 1 << 11, "deadman";
        /// The e-stop is latched (joystick button or `scl estop`) until `scl reset`: zero at once.
        ESTOP = 1 << 12, "e-stop";
        /// Restart prevention: after a stop a fault caused (and at start-up), the arm stays
        /// stopped until the operator's input has passed through neutral (the stick within
        /// `safety::restart::NEUTRAL_MAX_ACTION`, and with the deadman required, the deadman
        /// released and pressed again). Set on the ticks this is the only reason for the stop.
        AWAITING_NEUTRAL = 1 << 13, "awaiting-neutral";
        /// A pair of the arm's collision model (self or scene) was approaching within the
        /// slowdown distance, or could not have stopped before the stop distance: the command
        /// was scaled down; motion that opens every gap stays free.
        CLEARANCE_LIMITED = 1 << 14, "clearance";
        /// The tool or a link's capsule end would have moved faster than the Cartesian speed
        /// cap (or the tool turned faster than its angular cap): the command was scaled down.
        SPEED_CAPPED = 1 << 15, "tcp-speed";
    }
    /// Number of flag bits, for per-rule counters.
    pub const COUNT: usize = NAMES.len();
}

/// [`SafeCommand::control`] bits: what the safety process had told the filter before it
/// filtered this tick's command (the control plane's effect, at its tick boundary).
pub mod safe_control {
    crate::fields::bits! {
        /// The e-stop was latched when the step began (from `scl estop`, the supervisor's relay or
        /// an earlier e-stop button); a button pressed in this tick's sample latches it too.
        ESTOP = 1 << 0, "e-stop";
        /// The supervisor held the arm.
        HOLD = 1 << 1, "hold";
        /// The command stream had been interrupted (no command for 100 ms) since the last step:
        /// restart prevention was re-armed before this step.
        INTERRUPTED = 1 << 2, "interrupted";
    }
    /// Set on every command of a safety process that fills these bits (a recording made
    /// before has none set): the replay then knows the bits above are complete.
    pub const RECORDED: u32 = 1 << 31;
}

message! {
    /// The command the arm executes at tick `tick`: the safety process's output, the only one the
    /// bridge accepts. The service admits exactly one publisher.
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::SafeCommand")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct SafeCommand {
        /// The tick this command is for; the bridge executes it only at this tick.
        pub tick: u64,
        /// When it was published (monotonic ns).
        pub t_ns: u64,
        /// Inherited: `t_ns` of the robot state of this tick.
        pub state_t_ns: u64,
        /// Inherited: when the mapper received that state.
        pub state_rx_ns: u64,
        /// Inherited: `t_ns` of the joystick sample behind the command.
        pub joystick_t_ns: u64,
        /// Inherited: when the mapper received that joystick sample.
        pub joystick_rx_ns: u64,
        /// Inherited: `t_ns` of the mapper command.
        pub mapper_t_ns: u64,
        /// When safety received the mapper command (monotonic ns).
        pub mapper_rx_ns: u64,
        /// Inherited: the mapper's compute time (ns).
        pub mapper_compute_ns: u64,
        /// Time spent in the safety filter (ns).
        pub compute_ns: u64,
        /// The mapper the command came from.
        pub mapper_id: u32,
        /// Number of valid entries in `qdot_rad_s`.
        pub n_joints: u32,
        /// [`safe_flags`] bits: which rules acted.
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = safe_flags::NAMES)))]
        pub flags: u32,
        /// [`safe_control`] bits: the filter's control inputs at this tick (e-stop latched, hold,
        /// an interruption), so a recording replays the filter exactly. Formerly padding, always 0
        /// (recordings made before read as 0; the layout is unchanged).
        #[cfg_attr(feature = "json", serde(default))]
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = safe_control::NAMES)))]
        pub control: u32,
        /// Joint velocities to execute (rad/s).
        pub qdot_rad_s: [f64; MAX_JOINTS],
        /// Gripper rate (1/s on the `c` scale).
        pub gripper_rate: f64,
        /// The smallest distance between any checked pair of the collision model (self and
        /// scene) at this tick's robot state (m, negative when overlapping); `+inf` when nothing
        /// was checked (no collision model, unusable state).
        pub clearance_m: f64,
        /// The tool's linear speed under this command at this tick's state (m/s); 0 when
        /// nothing was checked.
        pub tcp_speed_m_s: f64,
        /// The two sides of the pair at `clearance_m`, as `kinematics::collision::PairId::code`
        /// (`safety::clearance::pair_name` names them, `forearm-table`); `[0xFFFF; 2]` when
        /// nothing was checked.
        pub closest_pair: [u16; 2],
        /// Padding, always 0.
        pub reserved_tail: u32,
    }
    /// The processes' own stamps, which the replayed filter does not compute: safety's (when
    /// it published, `t_ns`; when it received the mapper command, `mapper_rx_ns`; how long the
    /// filter took, `compute_ns`) and those of the mapper it inherits (`state_rx_ns`,
    /// `joystick_rx_ns`, `mapper_t_ns`, `mapper_compute_ns`); and the padding
    /// `reserved_tail`. (`control` is compared only where the recording has it,
    /// [`safe_control::RECORDED`]: `replay::safe_diff`.)
    not_replayed: [
        t_ns,
        state_rx_ns,
        joystick_rx_ns,
        mapper_t_ns,
        mapper_rx_ns,
        mapper_compute_ns,
        compute_ns,
        reserved_tail,
    ];
}

impl SafeCommand {
    /// Every field zero (zerocopy's `FromZeros::new_zeroed`): the base of a command built
    /// field by field, `SafeCommand { tick, qdot_rad_s, ..SafeCommand::zeroed() }`.
    pub fn zeroed() -> Self {
        <Self as zerocopy::FromZeros>::new_zeroed()
    }
}

message! {
    /// The bridge's account of one tick: every timestamp the tick's messages carried, for
    /// per-hop latency figures (`scl bench latency`).
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::TickReport")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct TickReport {
        /// The tick.
        pub tick: u64,
        /// Where the tick should have started on the ideal period grid (ns).
        pub ideal_ns: u64,
        /// How late the bridge woke against it (ns).
        pub lateness_ns: u64,
        /// RobotState(k) published.
        pub state_t_ns: u64,
        /// The mapper received it (0 on a miss, as every field below).
        pub state_rx_ns: u64,
        /// The joystick sample used was produced.
        pub joystick_t_ns: u64,
        /// The mapper received that sample.
        pub joystick_rx_ns: u64,
        /// The mapper published its command.
        pub mapper_t_ns: u64,
        /// Safety received it.
        pub mapper_rx_ns: u64,
        /// Safety published SafeCommand(k).
        pub safe_t_ns: u64,
        /// The bridge received it.
        pub safe_rx_ns: u64,
        /// Time in the mapper's map (ns).
        pub mapper_compute_ns: u64,
        /// Time in the safety filter (ns).
        pub safety_compute_ns: u64,
        /// Ticks missed since the bridge started.
        pub missed: u64,
        /// 1 if this tick's command was executed, 0 if missed.
        pub executed: u32,
        /// Padding, always 0.
        pub reserved: u32,
    }
}

/// Which process a [`NodeStatus`] comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum NodeRole {
    /// The joystick (input) process.
    Joystick = 1,
    /// A mapper process.
    Mapper = 2,
    /// The safety process.
    Safety = 3,
    /// The hardware bridge (the clock).
    Bridge = 4,
    /// The recorder (`scl record`): an observer that publishes nothing but its heartbeat.
    Recorder = 5,
    /// The network gateway (`scl gateway`): the graph's topics out through Zenoh and, when
    /// accepted, a remote operator's joystick in.
    Gateway = 6,
}

impl NodeRole {
    /// Decodes a raw role value.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(Self::Joystick),
            2 => Some(Self::Mapper),
            3 => Some(Self::Safety),
            4 => Some(Self::Bridge),
            5 => Some(Self::Recorder),
            6 => Some(Self::Gateway),
            _ => None,
        }
    }

    /// The role's name as the CLI and the status line spell it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Joystick => "joystick",
            Self::Mapper => "mapper",
            Self::Safety => "safety",
            Self::Bridge => "bridge",
            Self::Recorder => "recorder",
            Self::Gateway => "gateway",
        }
    }
}

/// Node life-cycle phases in [`NodeStatus::phase`].
pub mod phase {
    /// Ports are open; the node is ready to take part in the next tick.
    pub const READY: u32 = 1;
    /// The node is handling ticks.
    pub const RUNNING: u32 = 2;
    /// The node is shutting down (its last status).
    pub const STOPPING: u32 = 3;
}

/// [`NodeStatus::safety_state`] bits.
pub mod safety_state {
    crate::fields::bits! {
        /// The e-stop is latched.
        ESTOP = 1 << 0, "e-stop";
        /// The supervisor holds the arm.
        HOLD = 1 << 1, "hold";
        /// Restart prevention: the arm waits for the operator's input to pass through neutral
        /// before it moves again (see [`super::safe_flags::AWAITING_NEUTRAL`]).
        AWAITING_NEUTRAL = 1 << 2, "awaiting-neutral";
    }
}

/// Indices of a gateway's counts in [`NodeStatus::rule_counts`] (saturating at `u32::MAX`);
/// its `handled` counts ticks, its `faults` the operator samples it refused.
pub mod gateway_counts {
    /// Operator samples forwarded to the graph.
    pub const FORWARDED: usize = 0;
    /// Times the driving operator's session ended or its link was lost.
    pub const LINK_LOSSES: usize = 1;
    /// Times the driving operator's input went stale.
    pub const STALE_STOPS: usize = 2;
    /// Ticks the gateway stood in with a neutral "device gone" sample (no operator drove).
    pub const STOOD_IN: usize = 3;
    /// Observer messages dropped because the network side was behind.
    pub const OUTBOUND_DROPPED: usize = 4;
    /// Inbound messages dropped because the gateway's loop was behind.
    pub const INBOUND_DROPPED: usize = 5;
    /// E-stop requests passed to safety.
    pub const ESTOPS: usize = 6;
    /// Resets passed to safety.
    pub const RESETS: usize = 7;
    /// The operator link's state (`scl_net::wire::link_state`).
    pub const LINK: usize = 8;
    /// Short names, by index.
    pub const NAMES: [&str; 9] = [
        "forwarded",
        "link-losses",
        "stale-stops",
        "stood-in",
        "outbound-dropped",
        "inbound-dropped",
        "estops",
        "resets",
        "link",
    ];
}

message! {
    /// Heartbeat of one process, published once per tick it handled (and once when ready).
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::NodeStatus")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct NodeStatus {
        /// When it was published (monotonic ns).
        pub t_ns: u64,
        /// Newest tick the node handled ([`NO_TICK`] before the first; `null` in JSON).
        #[cfg_attr(
            feature = "json",
            serde(with = "crate::msg::json::tick"),
            schemars(with = "crate::msg::json::tick::Schema")
        )]
        pub tick: u64,
        /// Ticks handled since the node started.
        pub handled: u64,
        /// Bridge: ticks missed since start. Others: inputs refused (non-finite, stale, shape).
        pub faults: u64,
        /// Bridge: RobotState(k) published -> SafeCommand(k) received, this tick (ns; 0 on a miss).
        pub latency_ns: u64,
        /// Bridge: lateness of this tick against the ideal period grid (ns).
        pub lateness_ns: u64,
        /// Bridge: joint-space path length travelled since start (rad, L2 per tick, summed).
        pub joint_travel_rad: f64,
        /// Process id.
        pub pid: u32,
        /// [`NodeRole`] as u32.
        #[cfg_attr(feature = "json", schemars(extend("x-value-names" = crate::msg::json::role_names())))]
        pub role: u32,
        /// [`phase`] value.
        #[cfg_attr(feature = "json", schemars(extend("x-value-names" = crate::msg::json::phase_names())))]
        pub phase: u32,
        /// Mapper id (mappers: their own; safety and bridge: the active / last executed one).
        pub mapper_id: u32,
        /// Safety: [`safety_state`] bits.
        #[cfg_attr(feature = "json", schemars(extend("x-bit-names" = safety_state::NAMES)))]
        pub safety_state: u32,
        /// Safety: how many ticks each rule of [`safe_flags`] acted, by bit. Gateway: its
        /// counts, by [`gateway_counts`] index.
        #[cfg_attr(feature = "json", schemars(extend("x-item-names" = safe_flags::NAMES)))]
        pub rule_counts: [u32; 16],
        /// Mapper: the map's current mode plus one (mode switching: 1 x-y, 2 z-yaw,
        /// 3 roll-pitch); 0 for a map without modes.
        pub mode: u32,
        /// Mapper: mode switches since the mapper started (presses of the mode button).
        pub mode_switches: u32,
        /// Bridge: how many of `faults` the machine took (the bridge process not run through
        /// a period, or a command that came late while the chain's own work fit the deadline;
        /// see `scl_bridge_node`). Joystick: its late samples (`[graph] wait` = `predictive` or
        /// `spin`) that missed their tick, so the previous sample served (`scl_joystick::sampling`).
        /// 0 for the other roles. Was padding: older recordings read 0.
        #[cfg_attr(feature = "json", serde(default))]
        pub held_up: u32,
    }
}

/// [`LogRecord::level`] values (`tracing`'s levels).
pub mod log_level {
    /// Trace.
    pub const TRACE: u32 = 1;
    /// Debug.
    pub const DEBUG: u32 = 2;
    /// Info.
    pub const INFO: u32 = 3;
    /// Warning.
    pub const WARN: u32 = 4;
    /// Error.
    pub const ERROR: u32 = 5;
}

/// Bytes of [`LogRecord::text`].
pub const LOG_TEXT_BYTES: usize = 472;
/// Bytes of [`LogRecord::process`].
pub const LOG_PROCESS_BYTES: usize = 16;

/// One log line of a process of the graph (its own `tracing` record, at INFO and above), as
/// the process wrote it: fixed size, the text cut at [`LOG_TEXT_BYTES`] on a character
/// boundary. Published on the `log` topic by every process of the graph, read by `scl live`
/// (Foxglove's `/scl/log`). Not part of the control path: a process drops (and counts) the
/// records it cannot hand over at once.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("scl::LogRecord")]
#[repr(C)]
#[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
pub struct LogRecord {
    /// When it was logged (monotonic ns).
    pub t_ns: u64,
    /// Process id.
    pub pid: u32,
    /// [`log_level`] value.
    pub level: u32,
    /// Records this process dropped before this one, since it started (the hand-off was
    /// full or the topic could not take them).
    pub dropped: u32,
    /// Bytes of `text` in use.
    pub text_len: u32,
    /// The process as the log names it (`supervisor`, `mapper-2`, `safety`, ...), UTF-8,
    /// zero-padded.
    pub process: [u8; LOG_PROCESS_BYTES],
    /// The message and its fields (`message key=value ...`), UTF-8.
    pub text: [u8; LOG_TEXT_BYTES],
}

impl LogRecord {
    /// An empty record.
    pub fn zeroed() -> Self {
        <Self as zerocopy::FromZeros>::new_zeroed()
    }

    /// The text (the bytes in use; a record from elsewhere with broken UTF-8 reads lossily).
    pub fn text(&self) -> std::borrow::Cow<'_, str> {
        let n = (self.text_len as usize).min(LOG_TEXT_BYTES);
        String::from_utf8_lossy(&self.text[..n])
    }

    /// The process's name.
    pub fn process(&self) -> std::borrow::Cow<'_, str> {
        let n = self
            .process
            .iter()
            .position(|b| *b == 0)
            .unwrap_or(LOG_PROCESS_BYTES);
        String::from_utf8_lossy(&self.process[..n])
    }

    /// Sets the process's name, cut to [`LOG_PROCESS_BYTES`] on a character boundary.
    pub fn set_process(&mut self, name: &str) {
        self.process = [0; LOG_PROCESS_BYTES];
        let n = floor_char_boundary(name, LOG_PROCESS_BYTES);
        self.process[..n].copy_from_slice(&name.as_bytes()[..n]);
    }

    /// Appends `s` to the text, cut on a character boundary where the text is full; returns
    /// whether all of it fit.
    pub fn push_text(&mut self, s: &str) -> bool {
        let at = (self.text_len as usize).min(LOG_TEXT_BYTES);
        let n = floor_char_boundary(s, LOG_TEXT_BYTES - at);
        self.text[at..at + n].copy_from_slice(&s.as_bytes()[..n]);
        self.text_len = (at + n) as u32;
        n == s.len()
    }
}

/// The largest `n <= max` at which `s` can be cut.
fn floor_char_boundary(s: &str, max: usize) -> usize {
    if s.len() <= max {
        return s.len();
    }
    (0..=max)
        .rev()
        .find(|i| s.is_char_boundary(*i))
        .unwrap_or(0)
}

impl NodeStatus {
    /// A status for `role` in `phase` with every counter at zero.
    pub fn new(role: NodeRole, phase: u32, t_ns: u64) -> Self {
        Self {
            t_ns,
            tick: NO_TICK,
            handled: 0,
            faults: 0,
            latency_ns: 0,
            lateness_ns: 0,
            joint_travel_rad: 0.0,
            pid: std::process::id(),
            role: role as u32,
            phase,
            mapper_id: 0,
            safety_state: 0,
            rule_counts: [0; 16],
            mode: 0,
            mode_switches: 0,
            held_up: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn type_names_are_stable() {
        // SAFETY: type_name only returns the string given to the derive.
        unsafe {
            assert_eq!(JoystickInput::type_name(), "scl::JoystickInput");
            assert_eq!(RobotState::type_name(), "scl::RobotState");
            assert_eq!(MapperCommand::type_name(), "scl::MapperCommand");
            assert_eq!(SafeCommand::type_name(), "scl::SafeCommand");
            assert_eq!(NodeStatus::type_name(), "scl::NodeStatus");
            assert_eq!(LogRecord::type_name(), "scl::LogRecord");
        }
    }

    #[test]
    fn sizes_are_fixed() {
        // A change of layout breaks binaries built from another version: make it visible.
        assert_eq!(std::mem::size_of::<JoystickInput>(), 40);
        assert_eq!(std::mem::size_of::<RobotState>(), 176);
        assert_eq!(std::mem::size_of::<MapperCommand>(), 160);
        assert_eq!(std::mem::size_of::<SafeCommand>(), 192);
        assert_eq!(std::mem::size_of::<TickReport>(), 120);
        assert_eq!(std::mem::size_of::<NodeStatus>(), 152);
        assert_eq!(std::mem::size_of::<LogRecord>(), 512);
    }

    #[test]
    fn log_text_is_cut_on_a_character_boundary() {
        let mut r = LogRecord::zeroed();
        r.set_process("a-process-name-longer-than-16");
        assert_eq!(r.process(), "a-process-name-l");
        assert!(r.push_text("abc"));
        let long = "é".repeat(LOG_TEXT_BYTES);
        assert!(!r.push_text(&long));
        assert_eq!(
            r.text_len as usize,
            LOG_TEXT_BYTES - 1,
            "3 + 2k bytes, one short"
        );
        assert!(r.text().starts_with("abcé"));
        assert!(!r.text().contains('\u{fffd}'));
        assert!(r.push_text("x"), "the last byte");
        assert!(!r.push_text("y"));
        assert_eq!(r.text_len as usize, LOG_TEXT_BYTES);
    }

    #[test]
    fn bit_names_name_every_bit() {
        let highest = |b: u32| b.trailing_zeros() as usize + 1;
        assert_eq!(buttons::NAMES.len(), highest(buttons::NO_DEVICE));
        assert_eq!(state_flags::NAMES.len(), highest(state_flags::SAFETY_STOP));
        assert_eq!(
            mapper_flags::NAMES.len(),
            highest(mapper_flags::INPUT_NO_TICK)
        );
        assert_eq!(safe_flags::NAMES.len(), highest(safe_flags::SPEED_CAPPED));
        assert_eq!(
            safety_state::NAMES.len(),
            highest(safety_state::AWAITING_NEUTRAL)
        );
    }

    #[test]
    fn roles_round_trip() {
        for r in [
            NodeRole::Joystick,
            NodeRole::Mapper,
            NodeRole::Safety,
            NodeRole::Bridge,
            NodeRole::Recorder,
            NodeRole::Gateway,
        ] {
            assert_eq!(NodeRole::from_u32(r as u32), Some(r));
        }
        assert_eq!(NodeRole::from_u32(0), None);
    }
}
