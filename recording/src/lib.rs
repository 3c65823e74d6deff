//! The recording format: every topic of a graph as one MCAP channel of JSON messages.
//!
//! * One channel per service, named `/<topic>` (`/robot_state`, `/safe_command`, ...), with
//!   message encoding `json` and a JSON schema (schema encoding `jsonschema`), so a recording
//!   opens in Foxglove and any MCAP reader with named, typed fields.
//! * `log_time` and `publish_time` are the message's own `t_ns` (`CLOCK_MONOTONIC`), the one
//!   clock of the graph; the `scl.recording` metadata record pairs a monotonic and a wall-clock
//!   reading taken together, so a reader can convert.
//! * Chunks are uncompressed (zstd / lz4 would build C libraries) and written whole, each with
//!   its CRC: a file cut anywhere reads back up to its last complete chunk ([`read`] tolerates
//!   the cut, [`recover`] rewrites the readable prefix as a finished file).
//!
//! [`Payload`] is a message as it came off shared memory; its JSON form is a mirror struct
//! per type (`*Json`), whose fields the schemas describe one by one.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use ipc_types::control::{EstopCommand, SafetyControl, estop_action};
use ipc_types::{
    JoystickInput, MapperCommand, NO_TICK, NodeRole, NodeStatus, RobotState, SafeCommand, buttons,
    mapper_flags, phase, safe_flags, state_flags,
};
use mcap::records::{MessageHeader, Metadata};
use mcap::write::NoSeek;
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// Metadata record written when a recording starts.
pub const START_METADATA: &str = "scl.recording";
/// Metadata record written when a recording is closed cleanly: counts per topic.
pub const END_METADATA: &str = "scl.recording.end";
/// Metadata record [`recover`] adds to the file it writes.
pub const RECOVERED_METADATA: &str = "scl.recovered";

/// Why a recording could not be written, read or recovered.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// A file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The output file exists; recordings are never overwritten.
    #[error("{0} already exists; choose another --out or remove it first")]
    Exists(PathBuf),
    /// The file does not start like an MCAP file.
    #[error("{path}: not an MCAP file ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the reader said.
        reason: String,
    },
    /// The MCAP writer refused a record.
    #[error("{path}: cannot write the recording: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the writer said.
        reason: String,
    },
    /// A `--topics` entry is not a topic of the graph.
    #[error("unknown topic `{0}` in --topics; known topics: {known}", known = Topic::known())]
    UnknownTopic(String),
    /// A message does not decode as the type its channel names.
    #[error("{path}: message {sequence} on {topic} does not decode: {reason}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The message's sequence number.
        sequence: u32,
        /// What serde said.
        reason: String,
    },
}

/// A topic of the graph, as the recorder subscribes to it and names its channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    /// Joystick samples.
    Joystick,
    /// Robot states, one per tick.
    RobotState,
    /// Every mapper's commands.
    MapperCommand,
    /// The executed commands (safety's output).
    SafeCommand,
    /// Every node's heartbeat.
    Status,
    /// The supervisor's active-mapper switches, holds and relayed e-stops.
    SafetyControl,
    /// E-stop and reset commands.
    Estop,
}

impl Topic {
    /// Number of topics.
    pub const COUNT: usize = 7;
    /// Every topic, in channel order.
    pub const ALL: [Topic; Self::COUNT] = [
        Topic::Joystick,
        Topic::RobotState,
        Topic::MapperCommand,
        Topic::SafeCommand,
        Topic::Status,
        Topic::SafetyControl,
        Topic::Estop,
    ];

    /// The topic's service name below the graph prefix (`robot_state`).
    pub fn name(self) -> &'static str {
        match self {
            Topic::Joystick => ipc_types::graph::JOYSTICK.name,
            Topic::RobotState => ipc_types::graph::ROBOT_STATE.name,
            Topic::MapperCommand => ipc_types::graph::MAPPER_COMMAND.name,
            Topic::SafeCommand => ipc_types::graph::SAFE_COMMAND.name,
            Topic::Status => ipc_types::graph::STATUS.name,
            Topic::SafetyControl => ipc_types::control::SAFETY_CONTROL,
            Topic::Estop => ipc_types::control::ESTOP,
        }
    }

    /// The MCAP channel topic (`/robot_state`).
    pub fn channel(self) -> String {
        format!("/{}", self.name())
    }

    /// The schema name (`scl.RobotState`).
    pub fn schema_name(self) -> &'static str {
        match self {
            Topic::Joystick => "scl.JoystickInput",
            Topic::RobotState => "scl.RobotState",
            Topic::MapperCommand => "scl.MapperCommand",
            Topic::SafeCommand => "scl.SafeCommand",
            Topic::Status => "scl.NodeStatus",
            Topic::SafetyControl => "scl.SafetyControl",
            Topic::Estop => "scl.EstopCommand",
        }
    }

    /// Position in [`Topic::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The topic named `s` (`robot_state` or `/robot_state`).
    pub fn from_name(s: &str) -> Option<Topic> {
        let s = s.trim().trim_start_matches('/');
        Self::ALL.into_iter().find(|t| t.name() == s)
    }

    /// The topic of MCAP channel `channel`, if it is one of the graph's.
    pub fn from_channel(channel: &str) -> Option<Topic> {
        channel.strip_prefix('/').and_then(Self::from_name)
    }

    /// Parses a `--topics` list (names separated by commas); empty means every topic.
    pub fn parse_list(list: &[String]) -> Result<Vec<Topic>, RecordError> {
        let mut out = Vec::new();
        for item in list.iter().flat_map(|s| s.split(',')) {
            if item.trim().is_empty() {
                continue;
            }
            let t = Topic::from_name(item).ok_or_else(|| RecordError::UnknownTopic(item.into()))?;
            if !out.contains(&t) {
                out.push(t);
            }
        }
        if out.is_empty() {
            out = Self::ALL.to_vec();
        }
        out.sort();
        Ok(out)
    }

    fn known() -> String {
        Self::ALL.map(Topic::name).join(", ")
    }

    /// The JSON schema (draft 2020-12) of the topic's messages.
    pub fn schema(self) -> Value {
        schema::of(self)
    }
}

/// One message as it came off shared memory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Payload {
    /// A joystick sample.
    Joystick(JoystickInput),
    /// A robot state.
    RobotState(RobotState),
    /// A mapper command.
    MapperCommand(MapperCommand),
    /// An executed command.
    SafeCommand(SafeCommand),
    /// A heartbeat.
    Status(NodeStatus),
    /// A supervisor control message.
    SafetyControl(SafetyControl),
    /// An e-stop or reset command.
    Estop(EstopCommand),
}

impl Payload {
    /// The topic it was published on.
    pub fn topic(&self) -> Topic {
        match self {
            Payload::Joystick(_) => Topic::Joystick,
            Payload::RobotState(_) => Topic::RobotState,
            Payload::MapperCommand(_) => Topic::MapperCommand,
            Payload::SafeCommand(_) => Topic::SafeCommand,
            Payload::Status(_) => Topic::Status,
            Payload::SafetyControl(_) => Topic::SafetyControl,
            Payload::Estop(_) => Topic::Estop,
        }
    }

    /// When it was produced (monotonic ns): its log and publish time in the recording.
    pub fn t_ns(&self) -> u64 {
        match self {
            Payload::Joystick(m) => m.t_ns,
            Payload::RobotState(m) => m.t_ns,
            Payload::MapperCommand(m) => m.t_ns,
            Payload::SafeCommand(m) => m.t_ns,
            Payload::Status(m) => m.t_ns,
            Payload::SafetyControl(m) => m.t_ns,
            Payload::Estop(m) => m.t_ns,
        }
    }

    /// Appends its JSON form to `out`.
    pub fn write_json(&self, out: &mut Vec<u8>) -> serde_json::Result<()> {
        match self {
            Payload::Joystick(m) => serde_json::to_writer(out, &JoystickJson::from(m)),
            Payload::RobotState(m) => serde_json::to_writer(out, &RobotStateJson::from(m)),
            Payload::MapperCommand(m) => serde_json::to_writer(out, &MapperCommandJson::from(m)),
            Payload::SafeCommand(m) => serde_json::to_writer(out, &SafeCommandJson::from(m)),
            Payload::Status(m) => serde_json::to_writer(out, &NodeStatusJson::from(m)),
            Payload::SafetyControl(m) => serde_json::to_writer(out, &SafetyControlJson::from(m)),
            Payload::Estop(m) => serde_json::to_writer(out, &EstopJson::from(m)),
        }
    }
}

fn tick_or_none(t: u64) -> Option<u64> {
    (t != NO_TICK).then_some(t)
}

fn bit_names(bits: u32, names: &[&str]) -> Vec<String> {
    names
        .iter()
        .enumerate()
        .filter(|(i, _)| bits & (1 << i) != 0)
        .map(|(_, n)| (*n).to_owned())
        .collect()
}

const BUTTON_NAMES: [&str; 4] = ["deadman", "mode", "estop", "gripper"];
const STATE_FLAG_NAMES: [&str; 6] = [
    "stopping",
    "missed",
    "shutdown",
    "at-limit",
    "mock",
    "safety-stop",
];
const MAPPER_FLAG_NAMES: [&str; 6] = [
    "no-input",
    "input-non-finite",
    "input-clamped",
    "output-non-finite",
    "state-invalid",
    "input-stale",
];

// The bit positions the name tables above rely on.
const _: () = {
    assert!(buttons::GRIPPER == 1 << 3);
    assert!(state_flags::SAFETY_STOP == 1 << 5);
    assert!(mapper_flags::STATE_INVALID == 1 << 4);
    assert!(mapper_flags::INPUT_STALE == 1 << 5);
};

fn joints(v: &[f64; ipc_types::MAX_JOINTS], n: u32) -> Vec<f64> {
    v[..(n as usize).min(ipc_types::MAX_JOINTS)].to_vec()
}

/// JSON form of [`JoystickInput`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JoystickJson {
    /// Newest robot tick seen when sampled (`null` before the first).
    pub tick: Option<u64>,
    /// Sample time (monotonic ns).
    pub t_ns: u64,
    /// Sample counter.
    pub seq: u64,
    /// The two axes.
    pub axes: [f32; 2],
    /// Gripper rate input.
    pub gripper: f32,
    /// Button bits.
    pub buttons: u32,
    /// Names of the pressed buttons.
    pub pressed: Vec<String>,
}

impl From<&JoystickInput> for JoystickJson {
    fn from(m: &JoystickInput) -> Self {
        Self {
            tick: tick_or_none(m.tick),
            t_ns: m.t_ns,
            seq: m.seq,
            axes: m.axes,
            gripper: m.gripper,
            buttons: m.buttons,
            pressed: bit_names(m.buttons, &BUTTON_NAMES),
        }
    }
}

/// JSON form of [`RobotState`]; joint arrays hold the valid joints only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotStateJson {
    /// Tick number.
    pub tick: u64,
    /// Publication time (monotonic ns).
    pub t_ns: u64,
    /// Tick of the command executed during the period before (`null`: a stop).
    pub applied_tick: Option<u64>,
    /// Ticks missed since the bridge started.
    pub missed: u64,
    /// Flag bits.
    pub flags: u32,
    /// Names of the set flags.
    pub flag_names: Vec<String>,
    /// Joint angles (rad).
    pub q_rad: Vec<f64>,
    /// Joint velocities (rad/s).
    pub qdot_rad_s: Vec<f64>,
    /// Gripper state (0 open .. 1 closed).
    pub gripper: f64,
}

impl From<&RobotState> for RobotStateJson {
    fn from(m: &RobotState) -> Self {
        Self {
            tick: m.tick,
            t_ns: m.t_ns,
            applied_tick: tick_or_none(m.applied_tick),
            missed: m.missed,
            flags: m.flags,
            flag_names: bit_names(m.flags, &STATE_FLAG_NAMES),
            q_rad: joints(&m.q_rad, m.n_joints),
            qdot_rad_s: joints(&m.qdot_rad_s, m.n_joints),
            gripper: m.gripper,
        }
    }
}

/// JSON form of [`MapperCommand`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapperCommandJson {
    /// Tick of the robot state it answers.
    pub tick: u64,
    /// Publication time (monotonic ns).
    pub t_ns: u64,
    /// The robot state's time.
    pub state_t_ns: u64,
    /// When the mapper received the robot state.
    pub state_rx_ns: u64,
    /// The joystick sample's time (0: none).
    pub joystick_t_ns: u64,
    /// When the mapper received the joystick sample (0: none).
    pub joystick_rx_ns: u64,
    /// The joystick sample's counter.
    pub joystick_seq: u64,
    /// Time in the map (ns).
    pub compute_ns: u64,
    /// The mapper's id.
    pub mapper_id: u32,
    /// Flag bits.
    pub flags: u32,
    /// Names of the set flags.
    pub flag_names: Vec<String>,
    /// The joystick buttons of the sample used.
    pub buttons: u32,
    /// The action fed to the map.
    pub action: [f32; 2],
    /// Commanded joint velocities (rad/s).
    pub qdot_rad_s: Vec<f64>,
    /// Commanded gripper rate (1/s).
    pub gripper_rate: f64,
}

impl From<&MapperCommand> for MapperCommandJson {
    fn from(m: &MapperCommand) -> Self {
        Self {
            tick: m.tick,
            t_ns: m.t_ns,
            state_t_ns: m.state_t_ns,
            state_rx_ns: m.state_rx_ns,
            joystick_t_ns: m.joystick_t_ns,
            joystick_rx_ns: m.joystick_rx_ns,
            joystick_seq: m.joystick_seq,
            compute_ns: m.compute_ns,
            mapper_id: m.mapper_id,
            flags: m.flags,
            flag_names: bit_names(m.flags, &MAPPER_FLAG_NAMES),
            buttons: m.buttons,
            action: m.action,
            qdot_rad_s: joints(&m.qdot_rad_s, m.n_joints),
            gripper_rate: m.gripper_rate,
        }
    }
}

/// JSON form of [`SafeCommand`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SafeCommandJson {
    /// The tick it is for.
    pub tick: u64,
    /// Publication time (monotonic ns).
    pub t_ns: u64,
    /// The robot state's time.
    pub state_t_ns: u64,
    /// When the mapper received the robot state.
    pub state_rx_ns: u64,
    /// The joystick sample's time.
    pub joystick_t_ns: u64,
    /// When the mapper received the joystick sample.
    pub joystick_rx_ns: u64,
    /// The mapper command's time.
    pub mapper_t_ns: u64,
    /// When safety received the mapper command.
    pub mapper_rx_ns: u64,
    /// The mapper's compute time (ns).
    pub mapper_compute_ns: u64,
    /// Time in the safety filter (ns).
    pub compute_ns: u64,
    /// The mapper it came from.
    pub mapper_id: u32,
    /// Rule bits.
    pub flags: u32,
    /// Names of the rules that acted.
    pub rules: Vec<String>,
    /// Joint velocities to execute (rad/s).
    pub qdot_rad_s: Vec<f64>,
    /// Gripper rate (1/s).
    pub gripper_rate: f64,
}

impl From<&SafeCommand> for SafeCommandJson {
    fn from(m: &SafeCommand) -> Self {
        Self {
            tick: m.tick,
            t_ns: m.t_ns,
            state_t_ns: m.state_t_ns,
            state_rx_ns: m.state_rx_ns,
            joystick_t_ns: m.joystick_t_ns,
            joystick_rx_ns: m.joystick_rx_ns,
            mapper_t_ns: m.mapper_t_ns,
            mapper_rx_ns: m.mapper_rx_ns,
            mapper_compute_ns: m.mapper_compute_ns,
            compute_ns: m.compute_ns,
            mapper_id: m.mapper_id,
            flags: m.flags,
            rules: bit_names(m.flags, &safe_flags::NAMES),
            qdot_rad_s: joints(&m.qdot_rad_s, m.n_joints),
            gripper_rate: m.gripper_rate,
        }
    }
}

/// JSON form of [`NodeStatus`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NodeStatusJson {
    /// Publication time (monotonic ns).
    pub t_ns: u64,
    /// Newest tick handled (`null` before the first).
    pub tick: Option<u64>,
    /// Ticks handled.
    pub handled: u64,
    /// Faults (bridge: missed ticks; recorder: dropped messages).
    pub faults: u64,
    /// Bridge: end-to-end latency of this tick (ns).
    pub latency_ns: u64,
    /// Bridge: lateness of this tick (ns).
    pub lateness_ns: u64,
    /// Bridge: joint travel (rad).
    pub joint_travel_rad: f64,
    /// Process id.
    pub pid: u32,
    /// Role name.
    pub role: String,
    /// Phase name.
    pub phase: String,
    /// Mapper id.
    pub mapper_id: u32,
    /// Safety: state bits (1 e-stop, 2 hold).
    pub safety_state: u32,
    /// Safety: ticks each rule acted, by rule name.
    pub rule_counts: BTreeMap<String, u32>,
}

impl From<&NodeStatus> for NodeStatusJson {
    fn from(m: &NodeStatus) -> Self {
        Self {
            t_ns: m.t_ns,
            tick: tick_or_none(m.tick),
            handled: m.handled,
            faults: m.faults,
            latency_ns: m.latency_ns,
            lateness_ns: m.lateness_ns,
            joint_travel_rad: m.joint_travel_rad,
            pid: m.pid,
            role: NodeRole::from_u32(m.role)
                .map_or_else(|| format!("role-{}", m.role), |r| r.name().to_owned()),
            phase: match m.phase {
                phase::READY => "ready".to_owned(),
                phase::RUNNING => "running".to_owned(),
                phase::STOPPING => "stopping".to_owned(),
                other => format!("phase-{other}"),
            },
            mapper_id: m.mapper_id,
            safety_state: m.safety_state,
            rule_counts: safe_flags::NAMES
                .iter()
                .zip(m.rule_counts)
                .map(|(n, c)| ((*n).to_owned(), c))
                .collect(),
        }
    }
}

/// JSON form of [`SafetyControl`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SafetyControlJson {
    /// The supervisor's counter.
    pub seq: u64,
    /// Publication time (monotonic ns).
    pub t_ns: u64,
    /// First tick of the active mapper.
    pub from_tick: u64,
    /// The mapper safety forwards.
    pub active_mapper: u32,
    /// Whether the arm is held.
    pub hold: bool,
    /// E-stop change counter.
    pub estop_seq: u32,
    /// Whether the relayed e-stop is latched.
    pub estop: bool,
}

impl From<&SafetyControl> for SafetyControlJson {
    fn from(m: &SafetyControl) -> Self {
        Self {
            seq: m.seq,
            t_ns: m.t_ns,
            from_tick: m.from_tick,
            active_mapper: m.active_mapper,
            hold: m.hold != 0,
            estop_seq: m.estop_seq,
            estop: m.estop != 0,
        }
    }
}

/// JSON form of [`EstopCommand`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstopJson {
    /// When it was sent (monotonic ns).
    pub t_ns: u64,
    /// `estop`, `reset` or `unknown`.
    pub action: String,
    /// The sender's pid.
    pub source_pid: u32,
}

impl From<&EstopCommand> for EstopJson {
    fn from(m: &EstopCommand) -> Self {
        Self {
            t_ns: m.t_ns,
            action: match m.action {
                estop_action::ESTOP => "estop",
                estop_action::RESET => "reset",
                _ => "unknown",
            }
            .to_owned(),
            source_pid: m.source_pid,
        }
    }
}

/// The JSON schemas, written out field by field (the `*Json` structs are their source).
mod schema {
    use serde_json::{Value, json};

    use super::Topic;

    fn int(d: &str) -> Value {
        json!({"type": "integer", "minimum": 0, "description": d})
    }
    fn opt_int(d: &str) -> Value {
        json!({"type": ["integer", "null"], "minimum": 0, "description": d})
    }
    fn num(d: &str) -> Value {
        json!({"type": "number", "description": d})
    }
    fn boolean(d: &str) -> Value {
        json!({"type": "boolean", "description": d})
    }
    fn text(d: &str) -> Value {
        json!({"type": "string", "description": d})
    }
    fn nums(d: &str) -> Value {
        json!({"type": "array", "items": {"type": "number"}, "description": d})
    }
    fn names(d: &str) -> Value {
        json!({"type": "array", "items": {"type": "string"}, "description": d})
    }
    fn pair(d: &str) -> Value {
        json!({"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2, "description": d})
    }

    fn object(title: &str, description: &str, fields: Vec<(&str, Value)>) -> Value {
        let required: Vec<&str> = fields.iter().map(|(k, _)| *k).collect();
        let properties: serde_json::Map<String, Value> =
            fields.into_iter().map(|(k, v)| (k.to_owned(), v)).collect();
        json!({
            "$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": title,
            "description": description,
            "type": "object",
            "properties": properties,
            "required": required,
            "additionalProperties": false,
        })
    }

    pub(super) fn of(topic: Topic) -> Value {
        let t_ns = || int("when it was produced (CLOCK_MONOTONIC ns)");
        match topic {
            Topic::Joystick => object(
                "scl.JoystickInput",
                "one sample of the operator's input device",
                vec![
                    ("tick", opt_int("newest robot tick seen when sampled")),
                    ("t_ns", t_ns()),
                    ("seq", int("sample counter")),
                    ("axes", pair("the two axes, nominally in [-1, 1]")),
                    (
                        "gripper",
                        num("gripper rate input in [-1, 1], positive closes"),
                    ),
                    ("buttons", int("button bits")),
                    ("pressed", names("names of the pressed buttons")),
                ],
            ),
            Topic::RobotState => object(
                "scl.RobotState",
                "the arm's state at a tick, from the bridge (the graph's clock)",
                vec![
                    ("tick", int("tick number")),
                    ("t_ns", t_ns()),
                    (
                        "applied_tick",
                        opt_int("tick of the command executed in the period before; null: a stop"),
                    ),
                    ("missed", int("ticks missed since the bridge started")),
                    ("flags", int("state flag bits")),
                    ("flag_names", names("names of the set flags")),
                    ("q_rad", nums("joint angles (rad)")),
                    ("qdot_rad_s", nums("joint velocities (rad/s)")),
                    ("gripper", num("gripper state, 0 open .. 1 closed")),
                ],
            ),
            Topic::MapperCommand => object(
                "scl.MapperCommand",
                "a joint-velocity command from one mapper",
                vec![
                    ("tick", int("tick of the robot state it answers")),
                    ("t_ns", t_ns()),
                    ("state_t_ns", int("t_ns of the robot state used")),
                    ("state_rx_ns", int("when the mapper received that state")),
                    (
                        "joystick_t_ns",
                        int("t_ns of the joystick sample used (0: none)"),
                    ),
                    (
                        "joystick_rx_ns",
                        int("when the mapper received that sample (0: none)"),
                    ),
                    ("joystick_seq", int("seq of the joystick sample used")),
                    ("compute_ns", int("time in the map (ns)")),
                    ("mapper_id", int("the mapper's id")),
                    ("flags", int("mapper flag bits")),
                    ("flag_names", names("names of the set flags")),
                    ("buttons", int("joystick buttons of the sample used")),
                    ("action", pair("the action fed to the map")),
                    ("qdot_rad_s", nums("commanded joint velocities (rad/s)")),
                    ("gripper_rate", num("commanded gripper rate (1/s)")),
                ],
            ),
            Topic::SafeCommand => object(
                "scl.SafeCommand",
                "the command the arm executes at its tick (safety's output)",
                vec![
                    ("tick", int("the tick it is for")),
                    ("t_ns", t_ns()),
                    ("state_t_ns", int("t_ns of the robot state of this tick")),
                    ("state_rx_ns", int("when the mapper received that state")),
                    (
                        "joystick_t_ns",
                        int("t_ns of the joystick sample behind it"),
                    ),
                    (
                        "joystick_rx_ns",
                        int("when the mapper received that sample"),
                    ),
                    ("mapper_t_ns", int("t_ns of the mapper command")),
                    (
                        "mapper_rx_ns",
                        int("when safety received the mapper command"),
                    ),
                    ("mapper_compute_ns", int("the mapper's compute time (ns)")),
                    ("compute_ns", int("time in the safety filter (ns)")),
                    ("mapper_id", int("the mapper it came from")),
                    ("flags", int("safety rule bits")),
                    ("rules", names("names of the rules that acted")),
                    ("qdot_rad_s", nums("joint velocities to execute (rad/s)")),
                    ("gripper_rate", num("gripper rate (1/s)")),
                ],
            ),
            Topic::Status => object(
                "scl.NodeStatus",
                "a process's heartbeat",
                vec![
                    ("t_ns", t_ns()),
                    ("tick", opt_int("newest tick handled")),
                    (
                        "handled",
                        int("ticks handled (recorder: messages received)"),
                    ),
                    (
                        "faults",
                        int(
                            "bridge: missed ticks; recorder: dropped messages; others: refused inputs",
                        ),
                    ),
                    (
                        "latency_ns",
                        int("bridge: RobotState(k) to SafeCommand(k) (ns)"),
                    ),
                    (
                        "lateness_ns",
                        int("bridge: lateness against the tick grid (ns)"),
                    ),
                    (
                        "joint_travel_rad",
                        num("bridge: joint-space path length (rad)"),
                    ),
                    ("pid", int("process id")),
                    ("role", text("joystick, mapper, safety, bridge or recorder")),
                    ("phase", text("ready, running or stopping")),
                    ("mapper_id", int("mapper id (own, active or last executed)")),
                    ("safety_state", int("safety: 1 e-stop latched, 2 hold")),
                    (
                        "rule_counts",
                        json!({
                            "type": "object",
                            "additionalProperties": {"type": "integer", "minimum": 0},
                            "description": "safety: ticks each rule acted, by rule name",
                        }),
                    ),
                ],
            ),
            Topic::SafetyControl => object(
                "scl.SafetyControl",
                "the supervisor's switch, hold and e-stop relay to safety",
                vec![
                    ("seq", int("the supervisor's counter")),
                    ("t_ns", t_ns()),
                    ("from_tick", int("first tick of the active mapper")),
                    ("active_mapper", int("the mapper safety forwards")),
                    ("hold", boolean("the arm is held")),
                    ("estop_seq", int("e-stop change counter")),
                    ("estop", boolean("the relayed e-stop is latched")),
                ],
            ),
            Topic::Estop => object(
                "scl.EstopCommand",
                "scl estop / scl reset",
                vec![
                    ("t_ns", t_ns()),
                    ("action", text("estop, reset or unknown")),
                    ("source_pid", int("the sender's pid")),
                ],
            ),
        }
    }
}

/// A channel of a recording, as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// Channel id in the file.
    pub id: u16,
    /// Topic (`/robot_state`).
    pub topic: String,
    /// Message encoding (`json`).
    pub message_encoding: String,
    /// Channel metadata.
    pub metadata: BTreeMap<String, String>,
    /// Its schema, if it has one.
    pub schema: Option<SchemaInfo>,
}

/// A schema of a recording, as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemaInfo {
    /// Schema name.
    pub name: String,
    /// Schema encoding (`jsonschema`).
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
}

/// Writes a recording: channels, JSON messages, metadata, in whole CRC-checked chunks that
/// are closed by [`LogWriter::flush`] (the recorder flushes once a second) or by
/// [`LogWriter::finish`]. Generic over the sink so tests write to memory or `/dev/full`.
pub struct LogWriter<W: Write> {
    mcap: mcap::Writer<NoSeek<W>>,
    topics: [Option<u16>; Topic::COUNT],
    sequence: [u32; Topic::COUNT],
    json: Vec<u8>,
    path: PathBuf,
}

impl<W: Write> std::fmt::Debug for LogWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogWriter")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

/// Metadata `name` with the given entries.
pub fn metadata(name: &str, entries: BTreeMap<String, String>) -> Metadata {
    Metadata {
        name: name.to_owned(),
        metadata: entries,
    }
}

impl<W: Write> LogWriter<W> {
    /// Starts a recording into `sink` (named `path` in errors): the header and the `start`
    /// metadata. Channels are added with [`LogWriter::add_topic`] or [`LogWriter::add_channel`].
    pub fn new(sink: W, path: &Path, start: Option<Metadata>) -> Result<Self, RecordError> {
        let opts = mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .library(format!("scl-teleop {}", env!("CARGO_PKG_VERSION")))
            // Chunks close when the recorder flushes, so a chunk on disk is always whole.
            .chunk_size(None)
            .disable_seeking(true);
        let werr = |e: mcap::McapError| RecordError::Write {
            path: path.to_owned(),
            reason: e.to_string(),
        };
        let mut mcap = opts.create(NoSeek::new(sink)).map_err(werr)?;
        if let Some(m) = start {
            mcap.write_metadata(&m).map_err(werr)?;
        }
        Ok(Self {
            mcap,
            topics: [None; Topic::COUNT],
            sequence: [0; Topic::COUNT],
            json: Vec::with_capacity(1024),
            path: path.to_owned(),
        })
    }

    fn werr(&self, e: mcap::McapError) -> RecordError {
        RecordError::Write {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    /// Adds a channel with its schema; returns its id.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema: Option<&SchemaInfo>,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<u16, RecordError> {
        let schema_id = match schema {
            Some(s) => self
                .mcap
                .add_schema(&s.name, &s.encoding, &s.data)
                .map_err(|e| self.werr(e))?,
            None => 0,
        };
        self.mcap
            .add_channel(schema_id, topic, message_encoding, metadata)
            .map_err(|e| self.werr(e))
    }

    /// Adds the channel of a graph topic (JSON messages with the topic's JSON schema);
    /// `metadata` goes on the channel (e.g. the graph prefix).
    pub fn add_topic(
        &mut self,
        topic: Topic,
        metadata: &BTreeMap<String, String>,
    ) -> Result<u16, RecordError> {
        let schema = SchemaInfo {
            name: topic.schema_name().to_owned(),
            encoding: "jsonschema".to_owned(),
            data: topic.schema().to_string().into_bytes(),
        };
        let id = self.add_channel(&topic.channel(), Some(&schema), "json", metadata)?;
        self.topics[topic.index()] = Some(id);
        Ok(id)
    }

    /// Writes raw message bytes on channel `channel_id`.
    pub fn write_raw(
        &mut self,
        channel_id: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<(), RecordError> {
        let header = MessageHeader {
            channel_id,
            sequence,
            log_time,
            publish_time,
        };
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|e| self.werr(e))
    }

    /// Writes a message of the graph as JSON on its topic's channel (added with
    /// [`LogWriter::add_topic`]); returns the bytes of JSON written.
    pub fn write(&mut self, p: &Payload) -> Result<usize, RecordError> {
        let topic = p.topic();
        let Some(channel_id) = self.topics[topic.index()] else {
            return Err(RecordError::Write {
                path: self.path.clone(),
                reason: format!("no channel for topic {}", topic.name()),
            });
        };
        self.json.clear();
        p.write_json(&mut self.json)
            .map_err(|e| RecordError::Write {
                path: self.path.clone(),
                reason: format!("cannot encode a {} message: {e}", topic.name()),
            })?;
        let seq = &mut self.sequence[topic.index()];
        *seq = seq.wrapping_add(1);
        let header = MessageHeader {
            channel_id,
            sequence: *seq,
            log_time: p.t_ns(),
            publish_time: p.t_ns(),
        };
        let n = self.json.len();
        self.mcap
            .write_to_known_channel(&header, &self.json)
            .map_err(|e| RecordError::Write {
                path: self.path.clone(),
                reason: e.to_string(),
            })?;
        Ok(n)
    }

    /// Closes the current chunk (if any) and pushes everything to the sink: what was written
    /// so far survives a crash of the process.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.mcap.flush().map_err(|e| self.werr(e))
    }

    /// Writes `end` metadata (if any), the summary (statistics, indexes) and the footer;
    /// returns the sink, flushed.
    pub fn finish(mut self, end: Option<Metadata>) -> Result<W, RecordError> {
        if let Some(m) = end {
            self.mcap.write_metadata(&m).map_err(|e| self.werr(e))?;
        }
        self.mcap.finish().map_err(|e| self.werr(e))?;
        let path = self.path.clone();
        let mut sink = self.mcap.into_inner().into_inner();
        sink.flush()
            .map_err(|source| RecordError::Io { path, source })?;
        Ok(sink)
    }
}

/// One event of a recording, in file order.
#[derive(Debug)]
pub enum Event<'a> {
    /// A channel was defined.
    Channel(&'a ChannelInfo),
    /// A message.
    Message {
        /// Its channel.
        channel: &'a ChannelInfo,
        /// Sequence number.
        sequence: u32,
        /// Log time (ns).
        log_time: u64,
        /// Publish time (ns).
        publish_time: u64,
        /// The message bytes (JSON for the graph's topics).
        data: &'a [u8],
    },
    /// A metadata record.
    Metadata {
        /// Its name.
        name: &'a str,
        /// Its entries.
        entries: &'a BTreeMap<String, String>,
    },
}

/// How far a recording could be read.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ReadSummary {
    /// Messages read.
    pub messages: u64,
    /// Whether the data section ended properly (a clean stop). A recording cut by a crash is
    /// read up to its last complete chunk and is not complete.
    pub complete: bool,
    /// Why reading stopped before the end of the data, for an incomplete recording.
    pub stopped: Option<String>,
}

/// Reads the recording from `src` (named `path` in errors) in file order, calling `on` for
/// every channel, message and metadata record. Tolerates a cut or damaged tail: whole chunks
/// before it are read, the summary tells where it stopped. Fails only if the source is not an
/// MCAP file, cannot be read from the start, or `on` fails.
pub fn read<R: Read>(
    mut src: R,
    path: &Path,
    mut on: impl FnMut(Event<'_>) -> Result<(), RecordError>,
) -> Result<ReadSummary, RecordError> {
    use mcap::records::Record;
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(false)
            // A chunk yields its records only once its whole body checked out.
            .with_prevalidate_chunk_crcs(true),
    );
    let mut schemas: BTreeMap<u16, SchemaInfo> = BTreeMap::new();
    let mut channels: BTreeMap<u16, ChannelInfo> = BTreeMap::new();
    let mut summary = ReadSummary::default();
    let mut started = false;
    let stop = |summary: &mut ReadSummary, why: String, started: bool| {
        if started {
            summary.stopped = Some(why);
            Ok(())
        } else {
            Err(RecordError::NotMcap {
                path: path.to_owned(),
                reason: why,
            })
        }
    };
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(e) => e,
            Err(e) => {
                let why = match e {
                    mcap::McapError::UnexpectedEof => {
                        "the file ends inside a record (cut off by a crash?)".to_owned()
                    }
                    other => other.to_string(),
                };
                stop(&mut summary, why, started)?;
                break;
            }
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let buf = reader.insert(need);
                let n = loop {
                    match src.read(buf) {
                        Ok(n) => break n,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(source) => {
                            return Err(RecordError::Io {
                                path: path.to_owned(),
                                source,
                            });
                        }
                    }
                };
                reader.notify_read(n);
            }
            LinearReadEvent::Record { opcode, data } => {
                let record = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) => {
                        stop(&mut summary, format!("bad record: {e}"), started)?;
                        break;
                    }
                };
                started = true;
                match record {
                    Record::Schema { header, data } => {
                        schemas.insert(
                            header.id,
                            SchemaInfo {
                                name: header.name,
                                encoding: header.encoding,
                                data: data.into_owned(),
                            },
                        );
                    }
                    Record::Channel(c) => {
                        if channels.contains_key(&c.id) {
                            continue;
                        }
                        let info = ChannelInfo {
                            id: c.id,
                            topic: c.topic,
                            message_encoding: c.message_encoding,
                            metadata: c.metadata,
                            schema: schemas.get(&c.schema_id).cloned(),
                        };
                        on(Event::Channel(&info))?;
                        channels.insert(c.id, info);
                    }
                    Record::Message { header, data } => {
                        let Some(channel) = channels.get(&header.channel_id) else {
                            stop(
                                &mut summary,
                                format!(
                                    "message {} names channel {}, which was not defined",
                                    header.sequence, header.channel_id
                                ),
                                started,
                            )?;
                            break;
                        };
                        summary.messages += 1;
                        on(Event::Message {
                            channel,
                            sequence: header.sequence,
                            log_time: header.log_time,
                            publish_time: header.publish_time,
                            data: &data,
                        })?;
                    }
                    Record::Metadata(m) => on(Event::Metadata {
                        name: &m.name,
                        entries: &m.metadata,
                    })?,
                    Record::DataEnd(_) => {
                        summary.complete = true;
                        break;
                    }
                    _ => {}
                }
            }
        }
    }
    if !summary.complete && summary.stopped.is_none() {
        summary.stopped = Some("the file ends without its data-end record".to_owned());
    }
    Ok(summary)
}

/// Opens `path` and [`read`]s it.
pub fn read_file(
    path: &Path,
    on: impl FnMut(Event<'_>) -> Result<(), RecordError>,
) -> Result<ReadSummary, RecordError> {
    let f = std::fs::File::open(path).map_err(|source| RecordError::Io {
        path: path.to_owned(),
        source,
    })?;
    read(std::io::BufReader::new(f), path, on)
}

/// Decodes a message of `topic` from its JSON.
pub fn decode<T: serde::de::DeserializeOwned>(
    path: &Path,
    topic: &str,
    sequence: u32,
    data: &[u8],
) -> Result<T, RecordError> {
    serde_json::from_slice(data).map_err(|e| RecordError::Decode {
        path: path.to_owned(),
        topic: topic.to_owned(),
        sequence,
        reason: e.to_string(),
    })
}

/// Opens `path` for a new file, refusing to replace an existing one.
pub fn create_new(path: &Path) -> Result<std::fs::File, RecordError> {
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(|source| {
            if source.kind() == std::io::ErrorKind::AlreadyExists {
                RecordError::Exists(path.to_owned())
            } else {
                RecordError::Io {
                    path: path.to_owned(),
                    source,
                }
            }
        })
}

/// What [`recover`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoverReport {
    /// Messages copied.
    pub messages: u64,
    /// Channels copied.
    pub channels: usize,
    /// Whether the source was complete already.
    pub source_complete: bool,
    /// Why reading the source stopped early.
    pub stopped: Option<String>,
}

/// Rewrites the readable part of recording `from` (cut by a crash) as a finished recording
/// `to`: the same channels, schemas, metadata and messages, plus a [`RECOVERED_METADATA`]
/// record. Refuses to replace `to`.
pub fn recover(from: &Path, to: &Path) -> Result<RecoverReport, RecordError> {
    let src = std::fs::File::open(from).map_err(|source| RecordError::Io {
        path: from.to_owned(),
        source,
    })?;
    let out = create_new(to)?;
    let result = recover_into(
        std::io::BufReader::new(src),
        from,
        std::io::BufWriter::new(out),
        to,
    );
    if result.is_err() {
        // Leave no half-written output behind; the source is untouched.
        let _ = std::fs::remove_file(to);
    }
    result.map(|(r, _)| r)
}

/// [`recover`] between streams; returns the report and the sink.
pub fn recover_into<R: Read, W: Write>(
    src: R,
    from: &Path,
    sink: W,
    to: &Path,
) -> Result<(RecoverReport, W), RecordError> {
    let mut w = LogWriter::new(sink, to, None)?;
    let mut ids: BTreeMap<u16, u16> = BTreeMap::new();
    let mut channels = 0;
    let summary = read(src, from, |ev| {
        match ev {
            Event::Channel(c) => {
                let id = w.add_channel(
                    &c.topic,
                    c.schema.as_ref(),
                    &c.message_encoding,
                    &c.metadata,
                )?;
                ids.insert(c.id, id);
                channels += 1;
            }
            Event::Message {
                channel,
                sequence,
                log_time,
                publish_time,
                data,
            } => {
                let id = ids.get(&channel.id).copied().unwrap_or_default();
                w.write_raw(id, sequence, log_time, publish_time, data)?;
            }
            Event::Metadata { name, entries } => {
                w.mcap
                    .write_metadata(&metadata(name, entries.clone()))
                    .map_err(|e| RecordError::Write {
                        path: to.to_owned(),
                        reason: e.to_string(),
                    })?;
            }
        }
        Ok(())
    })?;
    let mut entries = BTreeMap::new();
    entries.insert("source".to_owned(), from.display().to_string());
    entries.insert("messages".to_owned(), summary.messages.to_string());
    entries.insert("source_complete".to_owned(), summary.complete.to_string());
    if let Some(s) = &summary.stopped {
        entries.insert("source_stopped".to_owned(), s.clone());
    }
    let sink = w.finish(Some(metadata(RECOVERED_METADATA, entries)))?;
    Ok((
        RecoverReport {
            messages: summary.messages,
            channels,
            source_complete: summary.complete,
            stopped: summary.stopped,
        },
        sink,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn state(tick: u64) -> RobotState {
        let mut s = RobotState::at_rest(tick, 1_000_000 + tick * 25_000_000, 6);
        s.applied_tick = tick.wrapping_sub(1);
        for j in 0..6 {
            s.q_rad[j] = 0.1 * j as f64 + 1e-3 * tick as f64;
            s.qdot_rad_s[j] = 0.04;
        }
        s.gripper = 0.25;
        s.flags = state_flags::MOCK;
        s
    }

    pub(crate) fn samples() -> Vec<Payload> {
        let mut status = NodeStatus::new(NodeRole::Safety, phase::RUNNING, 7);
        status.rule_counts[4] = 3;
        let mut safe = SafeCommand {
            tick: 3,
            t_ns: 9,
            state_t_ns: 8,
            state_rx_ns: 8,
            joystick_t_ns: 5,
            joystick_rx_ns: 6,
            mapper_t_ns: 8,
            mapper_rx_ns: 9,
            mapper_compute_ns: 100,
            compute_ns: 200,
            mapper_id: 1,
            n_joints: 6,
            flags: safe_flags::VELOCITY_SCALED | safe_flags::ACCEL_LIMITED,
            reserved: 0,
            qdot_rad_s: [0.5; 8],
            gripper_rate: 0.0,
            clearance_m: 0.125,
            tcp_speed_m_s: 0.05,
            closest_pair: [0x0300, 0xFF00],
            reserved_tail: 0,
        };
        safe.qdot_rad_s[6] = 99.0; // beyond n_joints: not recorded
        let mapper = MapperCommand {
            tick: 3,
            t_ns: 8,
            state_t_ns: 7,
            state_rx_ns: 7,
            joystick_t_ns: 5,
            joystick_rx_ns: 6,
            joystick_seq: 2,
            compute_ns: 100,
            mapper_id: 1,
            n_joints: 6,
            flags: mapper_flags::INPUT_CLAMPED,
            buttons: buttons::DEADMAN,
            action: [0.6, -0.8],
            qdot_rad_s: [0.1; 8],
            gripper_rate: 0.5,
        };
        let mut joy = JoystickInput::neutral(5);
        joy.axes = [0.6, -0.8];
        joy.buttons = buttons::DEADMAN | buttons::ESTOP;
        vec![
            Payload::Joystick(joy),
            Payload::RobotState(state(3)),
            Payload::MapperCommand(mapper),
            Payload::SafeCommand(safe),
            Payload::Status(status),
            Payload::SafetyControl(SafetyControl {
                seq: 1,
                t_ns: 2,
                from_tick: 0,
                active_mapper: 1,
                hold: 1,
                estop_seq: 0,
                estop: 0,
            }),
            Payload::Estop(EstopCommand {
                t_ns: 4,
                action: estop_action::ESTOP,
                source_pid: 42,
            }),
        ]
    }

    /// Checks `v` against the subset of JSON schema the schemas use; returns what is wrong.
    fn check(v: &Value, s: &Value, at: &str) -> Vec<String> {
        let mut errs = Vec::new();
        let types: Vec<&str> = match &s["type"] {
            Value::String(t) => vec![t.as_str()],
            Value::Array(ts) => ts.iter().filter_map(Value::as_str).collect(),
            _ => vec![],
        };
        let is = |t: &str| match t {
            "object" => v.is_object(),
            "array" => v.is_array(),
            "string" => v.is_string(),
            "boolean" => v.is_boolean(),
            "null" => v.is_null(),
            "integer" => v.is_u64() || v.is_i64(),
            "number" => v.is_number(),
            _ => false,
        };
        if !types.is_empty() && !types.iter().any(|t| is(t)) {
            errs.push(format!("{at}: {v} is not {types:?}"));
            return errs;
        }
        if let Some(min) = s["minimum"].as_f64()
            && v.as_f64().is_some_and(|x| x < min)
        {
            errs.push(format!("{at}: {v} < {min}"));
        }
        if let (Some(obj), Some(props)) = (v.as_object(), s["properties"].as_object()) {
            for (k, val) in obj {
                match props.get(k) {
                    Some(ps) => errs.extend(check(val, ps, &format!("{at}.{k}"))),
                    None => errs.push(format!("{at}: field `{k}` is not in the schema")),
                }
            }
            for r in s["required"].as_array().into_iter().flatten() {
                if let Some(r) = r.as_str()
                    && !obj.contains_key(r)
                {
                    errs.push(format!("{at}: required field `{r}` is missing"));
                }
            }
        }
        if let (Some(obj), Some(ap)) = (v.as_object(), s.get("additionalProperties"))
            && ap.is_object()
        {
            for (k, val) in obj {
                errs.extend(check(val, ap, &format!("{at}.{k}")));
            }
        }
        if let (Some(items), Some(is)) = (v.as_array(), s.get("items")) {
            for (i, x) in items.iter().enumerate() {
                errs.extend(check(x, is, &format!("{at}[{i}]")));
            }
            if let Some(n) = s["minItems"].as_u64()
                && (items.len() as u64) < n
            {
                errs.push(format!("{at}: fewer than {n} items"));
            }
        }
        errs
    }

    #[test]
    fn every_message_matches_its_schema() {
        let all = samples();
        assert_eq!(all.len(), Topic::COUNT);
        for p in &all {
            let mut buf = Vec::new();
            p.write_json(&mut buf).unwrap();
            let v: Value = serde_json::from_slice(&buf).unwrap();
            let errs = check(&v, &p.topic().schema(), p.topic().name());
            assert!(errs.is_empty(), "{errs:#?}");
        }
        // The checker itself catches a wrong type and an extra field.
        let s = Topic::Estop.schema();
        assert!(
            !check(
                &json!({"t_ns": -1, "action": "estop", "source_pid": 1}),
                &s,
                "e"
            )
            .is_empty()
        );
        assert!(!check(&json!({"t_ns": 1, "action": 3, "source_pid": 1}), &s, "e").is_empty());
        assert!(
            !check(
                &json!({"t_ns": 1, "action": "x", "source_pid": 1, "extra": 0}),
                &s,
                "e"
            )
            .is_empty()
        );
        assert!(!check(&json!({"t_ns": 1, "action": "x"}), &s, "e").is_empty());
    }

    #[test]
    fn json_forms_keep_the_values() {
        let s = state(7);
        let mut buf = Vec::new();
        Payload::RobotState(s).write_json(&mut buf).unwrap();
        let back: RobotStateJson = serde_json::from_slice(&buf).unwrap();
        assert_eq!(back.tick, 7);
        assert_eq!(back.applied_tick, Some(6));
        assert_eq!(back.q_rad.len(), 6);
        for j in 0..6 {
            assert!((back.q_rad[j] - s.q_rad[j]).abs() < 1e-15);
        }
        assert_eq!(back.flag_names, vec!["mock".to_owned()]);
        let at_rest = RobotState::at_rest(0, 1, 6);
        buf.clear();
        Payload::RobotState(at_rest).write_json(&mut buf).unwrap();
        let v: Value = serde_json::from_slice(&buf).unwrap();
        assert!(v["applied_tick"].is_null(), "NO_TICK is null: {v}");
        let safe = samples()[3];
        buf.clear();
        safe.write_json(&mut buf).unwrap();
        let v: SafeCommandJson = serde_json::from_slice(&buf).unwrap();
        assert_eq!(v.rules, vec!["velocity", "acceleration"]);
        assert_eq!(v.qdot_rad_s.len(), 6);
    }

    #[test]
    fn topic_names_parse() {
        assert_eq!(Topic::from_name("/robot_state"), Some(Topic::RobotState));
        assert_eq!(Topic::from_channel("/estop"), Some(Topic::Estop));
        assert_eq!(Topic::from_channel("estop"), None);
        assert_eq!(Topic::parse_list(&[]).unwrap(), Topic::ALL.to_vec());
        assert_eq!(
            Topic::parse_list(&["safe_command,robot_state".into()]).unwrap(),
            vec![Topic::RobotState, Topic::SafeCommand]
        );
        let e = Topic::parse_list(&["robot_states".into()]).unwrap_err();
        assert!(e.to_string().contains("`robot_states`"), "{e}");
        for t in Topic::ALL {
            assert_eq!(Topic::ALL[t.index()], t);
        }
    }

    /// A sink the test can look into while the writer owns it.
    #[derive(Clone, Default)]
    struct Shared(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Shared {
        fn len(&self) -> usize {
            self.0.lock().unwrap().len()
        }
        fn bytes(&self) -> Vec<u8> {
            self.0.lock().unwrap().clone()
        }
    }

    /// A recording of `n` robot states, flushed (a chunk closed) every `per_chunk` messages,
    /// finished or left as a crash leaves it; the file length after each flush; the bytes.
    fn recording(n: u64, per_chunk: u64, finish: bool) -> (Vec<usize>, Vec<u8>) {
        let path = Path::new("mem.mcap");
        let sink = Shared::default();
        let mut start = BTreeMap::new();
        start.insert("prefix".to_owned(), "unit".to_owned());
        let mut w =
            LogWriter::new(sink.clone(), path, Some(metadata(START_METADATA, start))).unwrap();
        for t in Topic::ALL {
            w.add_topic(t, &BTreeMap::new()).unwrap();
        }
        w.flush().unwrap();
        let mut ends = Vec::new();
        for k in 0..n {
            w.write(&Payload::RobotState(state(k))).unwrap();
            if (k + 1) % per_chunk == 0 {
                w.flush().unwrap();
                ends.push(sink.len());
            }
        }
        if finish {
            w.finish(None).unwrap();
        } else {
            w.flush().unwrap();
            // A crash: the process is gone without finishing (no summary, no footer).
            std::mem::forget(w);
        }
        (ends, sink.bytes())
    }

    fn states_in(bytes: &[u8]) -> (ReadSummary, Vec<u64>) {
        let mut ticks = Vec::new();
        let s = read(bytes, Path::new("mem.mcap"), |ev| {
            if let Event::Message {
                channel,
                data,
                sequence,
                ..
            } = ev
                && channel.topic == "/robot_state"
            {
                let m: RobotStateJson =
                    decode(Path::new("mem.mcap"), &channel.topic, sequence, data)?;
                ticks.push(m.tick);
            }
            Ok(())
        })
        .unwrap();
        (s, ticks)
    }

    #[test]
    fn a_finished_recording_reads_whole_and_opens_with_the_mcap_crate() {
        let (_, bytes) = recording(100, 10, true);
        let (s, ticks) = states_in(&bytes);
        assert!(s.complete, "{s:?}");
        assert_eq!(ticks, (0..100).collect::<Vec<_>>());
        // The strict reader of the mcap crate and its summary agree.
        let n = mcap::MessageStream::new(&bytes).unwrap().count();
        assert_eq!(n, 100);
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let stats = summary.stats.unwrap();
        assert_eq!(stats.message_count, 100);
        assert_eq!(stats.channel_count, Topic::COUNT as u32);
        assert_eq!(summary.schemas.len(), Topic::COUNT);
        let ch = summary
            .channels
            .values()
            .find(|c| c.topic == "/robot_state")
            .unwrap();
        assert_eq!(ch.message_encoding, "json");
        assert_eq!(ch.schema.as_ref().unwrap().encoding, "jsonschema");
        assert_eq!(stats.message_start_time, state(0).t_ns);
        assert_eq!(stats.message_end_time, state(99).t_ns);
    }

    #[test]
    fn a_cut_recording_reads_up_to_its_last_complete_chunk() {
        let (ends, bytes) = recording(60, 10, false);
        assert_eq!(ends.len(), 6);
        let (whole, ticks) = states_in(&bytes);
        assert!(!whole.complete);
        assert_eq!(
            ticks.len(),
            60,
            "every flushed chunk is readable: {whole:?}"
        );
        let mut last = 0;
        for cut in (0..=bytes.len()).step_by(7) {
            let mut n = 0;
            match read(&bytes[..cut], Path::new("cut.mcap"), |ev| {
                if matches!(ev, Event::Message { .. }) {
                    n += 1;
                }
                Ok(())
            }) {
                Err(RecordError::NotMcap { .. }) => {
                    assert!(cut < 64, "cut at {cut} refused as not MCAP");
                    continue;
                }
                Err(e) => panic!("cut at {cut}: {e}"),
                Ok(s) => {
                    assert_eq!(s.messages, n);
                    assert!(!s.complete && s.stopped.is_some(), "cut at {cut}: {s:?}");
                }
            }
            let whole_chunks = ends.iter().filter(|e| **e <= cut).count() as u64;
            // Whole chunks only, and at least every chunk that ended before the cut (a cut
            // in the message indexes after a chunk keeps that chunk too).
            assert_eq!(n % 10, 0, "cut at {cut}: {n} messages, a partial chunk");
            assert!(
                n >= 10 * whole_chunks && n <= 10 * whole_chunks + 10,
                "cut at {cut}: {n}"
            );
            assert!(n >= last, "cut at {cut}: fewer messages than a shorter cut");
            last = n;
        }
        assert_eq!(last, 60);
    }

    #[test]
    fn a_damaged_chunk_is_not_read() {
        let (ends, mut bytes) = recording(30, 10, false);
        // Flip a byte inside the second chunk of states: its CRC no longer matches.
        let at = (ends[0] + ends[1]) / 2;
        bytes[at] ^= 0x55;
        let (s, ticks) = states_in(&bytes);
        assert_eq!(ticks, (0..10).collect::<Vec<_>>(), "{s:?}");
        assert!(s.stopped.is_some());
    }

    #[test]
    fn recover_writes_a_finished_file_of_the_readable_prefix() {
        let (ends, bytes) = recording(40, 10, false);
        let cut = &bytes[..ends[2] + 5];
        let (report, fixed) = recover_into(
            cut,
            Path::new("cut.mcap"),
            Vec::new(),
            Path::new("fixed.mcap"),
        )
        .unwrap();
        assert_eq!(report.messages, 30);
        assert_eq!(report.channels, Topic::COUNT);
        assert!(!report.source_complete);
        let (s, ticks) = states_in(&fixed);
        assert!(s.complete, "{s:?}");
        assert_eq!(ticks, (0..30).collect::<Vec<_>>());
        // A strict reader accepts it, and its summary has the channels and schemas.
        assert_eq!(mcap::MessageStream::new(&fixed).unwrap().count(), 30);
        let summary = mcap::Summary::read(&fixed).unwrap().unwrap();
        assert_eq!(summary.channels.len(), Topic::COUNT);
        let mut names = Vec::new();
        read(fixed.as_slice(), Path::new("fixed.mcap"), |ev| {
            if let Event::Metadata { name, .. } = ev {
                names.push(name.to_owned());
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(names, vec![START_METADATA, RECOVERED_METADATA]);
    }

    #[test]
    fn not_an_mcap_file_is_refused() {
        let e = read(&b"t,q0\n0,1\n"[..], Path::new("x.csv"), |_| Ok(())).unwrap_err();
        assert!(matches!(e, RecordError::NotMcap { .. }), "{e}");
        assert!(e.to_string().starts_with("x.csv: not an MCAP file"), "{e}");
    }

    #[test]
    fn a_full_disk_is_an_error_not_a_panic() {
        let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
            return; // no /dev/full on this system
        };
        let path = Path::new("/dev/full");
        let mut w = LogWriter::new(std::io::BufWriter::new(full), path, None).unwrap();
        w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
        for k in 0..10 {
            w.write(&Payload::RobotState(state(k))).unwrap();
        }
        let e = w.flush().unwrap_err();
        assert!(e.to_string().starts_with("/dev/full: cannot write"), "{e}");
        // Later flushes fail the same way; finishing fails without a panic.
        let _ = w.write(&Payload::RobotState(state(11)));
        assert!(w.flush().is_err());
        assert!(w.finish(None).is_err());
    }
}
