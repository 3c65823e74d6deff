//! Deterministic replay of a recording (`scl replay RUN.mcap`): the mapper's step
//! ([`mapper::step::MapperStep`]) and the safety filter ([`safety::SafetyFilter`]) re-run tick
//! by tick on what the recording says they were given, and every [`MapperCommand`] and
//! [`SafeCommand`] compared bit for bit with the recorded one.
//!
//! What each step consumed, and where the recording keeps it:
//!
//! * the model of each mapper process and safety's configuration: the attachments and the
//!   [`recording::PROCESS_METADATA`] records the recorder writes when it first sees a process
//!   (at start, at every swap and restart), with their SHA-256;
//! * the robot state of the tick: `/robot_state`, found by the `state_t_ns` the command
//!   inherited;
//! * the joystick sample the mapper used: `/joystick`, found by the `joystick_t_ns` and
//!   `joystick_seq` the command inherited (its receive time is the command's
//!   `joystick_rx_ns`; the step does not read it). A sample the recorder did not get is
//!   rebuilt from the command (`action`, `buttons`, `gripper_rate`) and the replay says so;
//! * the mapper's memory (held buttons, a map's mode): the same commands in the same order,
//!   one [`MapperStep`] per mapper process (a restarted process starts afresh: its first
//!   heartbeat tells when);
//! * the filter's inputs beyond the command and the state: its time argument
//!   (`t_ns - compute_ns` of the recorded command), its control inputs
//!   ([`SafeCommand::control`]: e-stop, hold, interruption) and which mapper it forwarded
//!   (`mapper_id` and `mapper_t_ns` name the command); one filter per safety process.
//!
//! Recordings made before these were recorded (no process records, control bits not
//! recorded) replay what they can: the [`Replay::notes`] say what was missing and how it was
//! stood in for.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod edit;
pub mod explain;
pub mod whatif;

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use ipc_types::fields::{Fields, Value};
use ipc_types::{
    JoystickInput, MapperCommand, NO_TICK, NodeRole, NodeStatus, RobotState, SafeCommand,
    mapper_flags, safe_control, safe_flags,
};
use mapper::LoadedModel;
use mapper::step::MapperStep;
use recording::{Event, RecordError, Topic};
use safety::SafetyFilter;
use serde::Serialize;

/// Why a recording could not be replayed, each naming the file and what was wrong.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The recording could not be read or a message did not decode.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// An embedded model (or the model spec of a mapper process) does not load.
    #[error("{path}: the model of mapper {mapper_id} (process {pid}) does not load: {source}")]
    Model {
        /// The recording.
        path: PathBuf,
        /// The mapper id.
        mapper_id: u32,
        /// Its process id.
        pid: u32,
        /// Why.
        source: mapper::ModelError,
    },
    /// The embedded configuration does not parse or gives no usable filter.
    #[error("{path}: {what}: {reason}")]
    Config {
        /// The recording.
        path: PathBuf,
        /// Which configuration.
        what: String,
        /// Why.
        reason: String,
    },
    /// The recording has nothing to replay.
    #[error("{path}: {reason}")]
    Empty {
        /// The recording.
        path: PathBuf,
        /// What is missing.
        reason: String,
    },
    /// The recording is cut or damaged and `--partial` was not given.
    #[error(
        "{path}: the recording is incomplete: {stopped}; `--partial` replays what can be read (`scl record --recover` makes a finished copy of it)"
    )]
    Incomplete {
        /// The recording.
        path: PathBuf,
        /// Where and why reading stopped.
        stopped: recording::Stopped,
    },
    /// `--tick K` names a tick the recording has no command for.
    #[error(
        "{path}: no safety command for tick {tick} (the recording has ticks {first} to {last})"
    )]
    NoSuchTick {
        /// The recording.
        path: PathBuf,
        /// The tick asked for.
        tick: u64,
        /// The first tick recorded.
        first: u64,
        /// The last tick recorded.
        last: u64,
    },
}

/// A mapper or safety process as the recording describes it.
#[derive(Debug, Clone, Default)]
pub struct ProcessRecord {
    /// Its pid.
    pub pid: u32,
    /// The `scl.process` metadata entries (role, mapper id, model spec, attachments, ...).
    pub entries: BTreeMap<String, String>,
}

/// A recording, read and indexed for replay.
#[derive(Debug, Default)]
pub struct Recording {
    /// The file.
    pub path: PathBuf,
    /// Robot states by `t_ns`.
    pub states: HashMap<u64, RobotState>,
    /// Joystick samples by (`t_ns`, `seq`).
    pub joystick: HashMap<(u64, u64), JoystickInput>,
    /// Mapper commands in file order.
    pub mapper: Vec<MapperCommand>,
    /// Safety commands in file order.
    pub safe: Vec<SafeCommand>,
    /// First heartbeat of each mapper / safety process: (role, mapper id, pid, t_ns), in file
    /// order.
    pub incarnations: Vec<(NodeRole, u32, u32, u64)>,
    /// The process records by pid.
    pub processes: HashMap<u32, ProcessRecord>,
    /// Attachments by name.
    pub attachments: HashMap<String, Vec<u8>>,
    /// Whether the file ended properly; if not, where and why reading stopped.
    pub stopped: Option<recording::Stopped>,
    /// Messages left out because they did not decode.
    pub undecodable: u64,
}

impl Recording {
    /// Reads `path`: every message the replay needs, the process records and attachments.
    /// A cut recording reads up to its last whole chunk ([`Recording::stopped`] says where).
    pub fn read(path: &Path) -> Result<Self, ReplayError> {
        let mut r = Recording {
            path: path.to_owned(),
            ..Recording::default()
        };
        let mut seen_pids = std::collections::HashSet::new();
        let mut undecodable = 0u64;
        let summary = recording::read_file(path, |ev| {
            match ev {
                Event::Message {
                    channel,
                    sequence,
                    data,
                    ..
                } => match r.take(path, channel, sequence, data, &mut seen_pids) {
                    Ok(()) => {}
                    // A message that does not decode (a non-finite value a fault drill
                    // injected is written as `null`) is left out and counted.
                    Err(RecordError::Decode { .. }) => undecodable += 1,
                    Err(e) => return Err(e),
                },
                Event::Metadata { name, entries } if name == recording::PROCESS_METADATA => {
                    let pid = entries
                        .get("pid")
                        .and_then(|p| p.parse().ok())
                        .unwrap_or_default();
                    r.processes.insert(
                        pid,
                        ProcessRecord {
                            pid,
                            entries: entries.clone(),
                        },
                    );
                }
                Event::Attachment { name, data, .. } => {
                    r.attachments.insert(name.to_owned(), data.to_vec());
                }
                _ => {}
            }
            Ok(())
        })?;
        r.stopped = summary.stopped;
        r.undecodable = undecodable;
        if r.safe.is_empty()
            && let Some(stopped) = &r.stopped
        {
            // Nothing readable before the damage: say where the file stopped reading.
            return Err(ReplayError::Incomplete {
                path: path.to_owned(),
                stopped: stopped.clone(),
            });
        }
        if r.safe.is_empty() {
            return Err(ReplayError::Empty {
                path: path.to_owned(),
                reason: "no /safe_command messages: nothing to replay (recorded with --topics \
                         leaving it out, or cut before the first tick)"
                    .into(),
            });
        }
        Ok(r)
    }

    /// Files one message of the recording.
    fn take(
        &mut self,
        path: &Path,
        channel: &recording::ChannelInfo,
        sequence: u32,
        data: &[u8],
        seen_pids: &mut std::collections::HashSet<u32>,
    ) -> Result<(), RecordError> {
        let r = self;
        match Topic::from_channel(&channel.topic) {
            Some(Topic::RobotState) => {
                let s = recording::decode_robot_state(path, channel, sequence, data)?;
                r.states.insert(s.t_ns, s);
            }
            Some(Topic::Joystick) => {
                let j: JoystickInput = recording::decode(path, channel, sequence, data)?;
                r.joystick.insert((j.t_ns, j.seq), j);
            }
            Some(Topic::MapperCommand) => {
                r.mapper
                    .push(recording::decode(path, channel, sequence, data)?);
            }
            Some(Topic::SafeCommand) => {
                r.safe
                    .push(recording::decode(path, channel, sequence, data)?);
            }
            Some(Topic::Status) => {
                let st: NodeStatus = recording::decode(path, channel, sequence, data)?;
                if let Some(role) = NodeRole::from_u32(st.role)
                    && matches!(role, NodeRole::Mapper | NodeRole::Safety)
                    && seen_pids.insert(st.pid)
                {
                    r.incarnations.push((role, st.mapper_id, st.pid, st.t_ns));
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// The pid of the `role` process (of mapper `mapper_id`) that produced a message at
    /// `t_ns`: the newest first heartbeat at or before it, else the first (a recorder that
    /// attached to a running graph saw its processes late); 0 if none was seen.
    fn incarnation(&self, role: NodeRole, mapper_id: u32, t_ns: u64) -> u32 {
        let mut first = None;
        let mut best = None;
        for &(r, id, pid, t) in &self.incarnations {
            if r != role || (role == NodeRole::Mapper && id != mapper_id) {
                continue;
            }
            first.get_or_insert(pid);
            if t <= t_ns {
                best = Some(pid);
            }
        }
        best.or(first).unwrap_or(0)
    }

    /// The safety process's configuration: the embedded graph TOML of the first safety
    /// process record, else the defaults (with a note).
    fn graph_config(
        &self,
        notes: &mut Vec<String>,
    ) -> Result<scl_config::GraphConfig, ReplayError> {
        let safety = self
            .processes
            .values()
            .filter(|p| p.entries.get("role").map(String::as_str) == Some("safety"))
            .min_by_key(|p| p.entries.get("t_ns").and_then(|t| t.parse::<u64>().ok()));
        let Some(p) = safety else {
            notes.push(
                "no safety process record (a recording made before configurations were \
                 embedded): safety replays with the default graph configuration"
                    .into(),
            );
            return Ok(scl_config::GraphConfig::default());
        };
        let Some(name) = p.entries.get("config_attachment") else {
            notes.push(format!(
                "the safety process record has no configuration ({}): safety replays with \
                 the defaults",
                p.entries
                    .get("error")
                    .map_or("none embedded", String::as_str)
            ));
            return Ok(scl_config::GraphConfig::default());
        };
        let bad = |reason: String| ReplayError::Config {
            path: self.path.clone(),
            what: format!("the embedded configuration {name}"),
            reason,
        };
        let bytes = self
            .attachments
            .get(name)
            .ok_or_else(|| bad("named by the process record but not in the file".into()))?;
        let text = std::str::from_utf8(bytes).map_err(|e| bad(e.to_string()))?;
        if let Some(want) = p.entries.get("config_sha256")
            && *want != recording::sha256_hex(bytes)
        {
            notes.push(format!(
                "the embedded configuration {name} does not match its recorded SHA-256"
            ));
        }
        scl_config::GraphConfig::parse(text, Path::new(name)).map_err(|e| bad(e.to_string()))
    }

    /// The model mapper process `pid` (mapper `mapper_id`) served.
    fn model(
        &self,
        mapper_id: u32,
        pid: u32,
        robot: &'static kinematics::RobotProfile,
        notes: &mut Vec<String>,
    ) -> Result<Option<(LoadedModel, String, bool)>, ReplayError> {
        let merr = |source| ReplayError::Model {
            path: self.path.clone(),
            mapper_id,
            pid,
            source,
        };
        let Some(p) = self.processes.get(&pid) else {
            notes.push(format!(
                "mapper {mapper_id} (process {pid}): no process record (a recording made \
                 before models were embedded): its commands are not re-executed, safety \
                 replays on the recorded ones"
            ));
            return Ok(None);
        };
        if let Some(name) = p.entries.get("model_attachment") {
            let Some(bytes) = self.attachments.get(name) else {
                notes.push(format!(
                    "mapper {mapper_id}: the model attachment {name} is missing: not re-executed"
                ));
                return Ok(None);
            };
            let sha = recording::sha256_hex(bytes);
            let altered = p.entries.get("model_sha256").is_some_and(|w| *w != sha);
            if altered {
                notes.push(format!(
                    "mapper {mapper_id}: the embedded model {name} does not match its recorded \
                     SHA-256 (the file was altered after recording)"
                ));
            }
            let m = LoadedModel::from_bytes_for(bytes, Path::new(name), robot).map_err(merr)?;
            return Ok(Some((m, format!("{name} (sha256 {sha})"), altered)));
        }
        match p.entries.get("model_spec") {
            Some(spec) if mapper::model::is_builtin(spec) => {
                let m = LoadedModel::load_for(spec, robot).map_err(merr)?;
                Ok(Some((m, spec.clone(), false)))
            }
            _ => {
                notes.push(format!(
                    "mapper {mapper_id} (process {pid}): its model is not in the recording ({}): \
                     not re-executed",
                    p.entries
                        .get("error")
                        .map_or("none embedded", String::as_str)
                ));
                Ok(None)
            }
        }
    }
}

/// One field that differs between the recorded and the replayed command.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldDiff {
    /// The field (`qdot_rad_s[2]`, `flags`, ...).
    pub field: String,
    /// Its recorded value.
    pub recorded: String,
    /// Its replayed value.
    pub replayed: String,
}

/// The first tick at which a replayed command differs from the recorded one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Divergence {
    /// The tick.
    pub tick: u64,
    /// Which step: `mapper` or `safety`.
    pub stage: String,
    /// The mapper id (of the mapper whose command differs, or the one safety forwarded).
    pub mapper_id: u32,
    /// The fields that differ.
    pub fields: Vec<FieldDiff>,
    /// The recorded command's flags, by name.
    pub recorded_flags: Vec<String>,
    /// The replayed command's flags, by name.
    pub replayed_flags: Vec<String>,
    /// Which input differed from the recording, or that none did.
    pub input: String,
}

/// A control event of the run, at the tick it took effect (from the recorded safety
/// commands: the mapper they came from and their control bits).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ControlEvent {
    /// The first tick it applied to.
    pub tick: u64,
    /// `swap`, `estop`, `reset`, `hold`, `release` or `interrupted`.
    pub event: String,
    /// For a swap, the mapper safety forwarded from this tick on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mapper_id: Option<u32>,
}

/// The control events of a run, in tick order: swaps (the forwarded mapper changed), the
/// e-stop latched and reset, holds and their release, interruptions.
pub fn control_events(safe: &[SafeCommand]) -> Vec<ControlEvent> {
    let mut out = Vec::new();
    let mut prev: Option<&SafeCommand> = None;
    let ev = |tick, e: &str, mapper_id| ControlEvent {
        tick,
        event: e.to_owned(),
        mapper_id,
    };
    for c in safe {
        let estop = c.flags & safe_flags::ESTOP != 0;
        let hold = c.flags & safe_flags::HOLD != 0;
        let (pestop, phold, pid) = prev.map_or((false, false, c.mapper_id), |p| {
            (
                p.flags & safe_flags::ESTOP != 0,
                p.flags & safe_flags::HOLD != 0,
                p.mapper_id,
            )
        });
        if pid != c.mapper_id {
            out.push(ev(c.tick, "swap", Some(c.mapper_id)));
        }
        if estop != pestop {
            out.push(ev(c.tick, if estop { "estop" } else { "reset" }, None));
        }
        if hold != phold {
            out.push(ev(c.tick, if hold { "hold" } else { "release" }, None));
        }
        if c.control & safe_control::INTERRUPTED != 0 {
            out.push(ev(c.tick, "interrupted", None));
        }
        prev = Some(c);
    }
    out
}

/// The outcome of replaying a recording.
#[derive(Debug, Clone, Serialize)]
pub struct Replay {
    /// Ticks replayed (safety commands re-executed).
    pub ticks: u64,
    /// Ticks whose safety command and the mapper command behind it both replayed bit for bit.
    pub identical: u64,
    /// Ticks where either differed.
    pub diverged: u64,
    /// Of those, the ticks whose mapper command was fed a joystick sample the recording lacks
    /// (lost before the recorder: a remote recorder's network path drops and counts what it
    /// cannot carry), rebuilt from the command: what the recording cannot replay, not a
    /// divergence of the graph. Only those ticks: a later tick whose safety step diverged
    /// because of one (the filter keeps state from tick to tick) counts as an ordinary
    /// divergence.
    pub diverged_on_lost_input: u64,
    /// The first divergence, if any.
    pub first_divergence: Option<Divergence>,
    /// Mapper commands re-executed (every mapper's, also those safety did not forward).
    pub mapper_commands: u64,
    /// Of those, the ones that replayed bit for bit.
    pub mapper_identical: u64,
    /// Commands not re-executed (no model, no state in the recording).
    pub skipped: u64,
    /// The run's control events (swaps, e-stop and reset, holds, interruptions).
    pub events: Vec<ControlEvent>,
    /// What the recording lacked and how the replay stood in for it.
    pub notes: Vec<String>,
}

/// Names of the bits set in `bits`.
pub fn bit_names(bits: u32, names: &[&str]) -> Vec<String> {
    names
        .iter()
        .enumerate()
        .filter(|(i, _)| bits & (1 << i) != 0)
        .map(|(_, n)| (*n).to_owned())
        .collect()
}

/// The fields of two messages that differ, bit for bit, but the message's
/// [`Fields::NOT_REPLAYED`] and those `skip` names. Floats compare by their bits (an `f32` is
/// shown as its bits, an `f64` as its value), arrays of floats element by element
/// (`qdot_rad_s[3]`), every other field as a whole (`closest_pair`).
fn fields_diff<T: Fields>(rec: &T, rep: &T, skip: impl Fn(&str) -> bool) -> Vec<FieldDiff> {
    let mut d = Vec::new();
    for ((name, a), (_, b)) in rec.fields().into_iter().zip(rep.fields()) {
        if T::NOT_REPLAYED.contains(&name) || skip(name) {
            continue;
        }
        value_diff(&mut d, name, a, b);
    }
    d
}

/// Adds field `name` to `out` if its values `a` and `b` (of one field of one type) differ.
fn value_diff(out: &mut Vec<FieldDiff>, name: &str, a: Value<'_>, b: Value<'_>) {
    match (a, b) {
        (Value::F64(a), Value::F64(b)) => f64_diff(out, name, a, b),
        (Value::F32(a), Value::F32(b)) => int_diff(out, name, a.to_bits(), b.to_bits()),
        (Value::F64s(a), Value::F64s(b)) => {
            for (i, (a, b)) in a.iter().zip(b).enumerate() {
                f64_diff(out, &format!("{name}[{i}]"), *a, *b);
            }
        }
        (Value::F32s(a), Value::F32s(b)) => {
            for (i, (a, b)) in a.iter().zip(b).enumerate() {
                int_diff(out, &format!("{name}[{i}]"), a.to_bits(), b.to_bits());
            }
        }
        (a, b) => {
            if a != b {
                out.push(FieldDiff {
                    field: name.to_owned(),
                    recorded: a.to_string(),
                    replayed: b.to_string(),
                });
            }
        }
    }
}

fn f64_diff(out: &mut Vec<FieldDiff>, field: &str, a: f64, b: f64) {
    if a.to_bits() != b.to_bits() {
        out.push(FieldDiff {
            field: field.to_owned(),
            recorded: format!("{a:?}"),
            replayed: format!("{b:?}"),
        });
    }
}

fn int_diff<T: PartialEq + std::fmt::Debug>(out: &mut Vec<FieldDiff>, field: &str, a: T, b: T) {
    if a != b {
        out.push(FieldDiff {
            field: field.to_owned(),
            recorded: format!("{a:?}"),
            replayed: format!("{b:?}"),
        });
    }
}

/// The fields of two mapper commands that differ, bit for bit: every field but
/// [`MapperCommand`]'s [`Fields::NOT_REPLAYED`] (the mapper's own stamps).
pub fn mapper_diff(rec: &MapperCommand, rep: &MapperCommand) -> Vec<FieldDiff> {
    fields_diff(rec, rep, |_| false)
}

/// The fields of two safety commands that differ, bit for bit: every field but
/// [`SafeCommand`]'s [`Fields::NOT_REPLAYED`] (the processes' own stamps, padding), and
/// `control` only where the recording has it ([`safe_control::RECORDED`]; before, the replay
/// rebuilds it from the flags).
pub fn safe_diff(rec: &SafeCommand, rep: &SafeCommand) -> Vec<FieldDiff> {
    let control_recorded = rec.control & safe_control::RECORDED != 0;
    fields_diff(rec, rep, |name| name == "control" && !control_recorded)
}

/// The joystick sample behind a recorded mapper command: the recorded sample it names, or
/// one rebuilt from the command itself (`true`: rebuilt).
pub fn joystick_for(rec: &Recording, cmd: &MapperCommand) -> Option<(JoystickInput, bool)> {
    if cmd.joystick_t_ns == 0 {
        return None;
    }
    if let Some(j) = rec.joystick.get(&(cmd.joystick_t_ns, cmd.joystick_seq)) {
        return Some((*j, false));
    }
    // Not recorded (dropped, or --topics without joystick): what the command says of it.
    // Its tick is unknown; a stale sample is given the tick that makes it stale again.
    let tick = if cmd.flags & mapper_flags::INPUT_STALE != 0 {
        cmd.tick.saturating_sub(2)
    } else {
        NO_TICK
    };
    Some((
        JoystickInput {
            tick,
            t_ns: cmd.joystick_t_ns,
            seq: cmd.joystick_seq,
            axes: cmd.action,
            gripper: cmd.gripper_rate as f32,
            buttons: cmd.buttons,
        },
        true,
    ))
}

/// What the replay of one tick's safety step saw and did, for `--explain`.
#[derive(Debug, Clone)]
pub struct TickTrace {
    /// The robot state.
    pub state: RobotState,
    /// The joystick sample the mapper used (and whether it was rebuilt).
    pub joystick: Option<(JoystickInput, bool)>,
    /// The model that mapper served.
    pub model: Option<String>,
    /// For a map linear in the action (SCL, PCA): `s·H(q, c)` at this state, one column
    /// per action axis (rad/s per unit action).
    pub h: Option<[[f64; ipc_types::MAX_JOINTS]; ipc_types::ACTION_DIM]>,
    /// The recorded mapper command.
    pub mapper_recorded: MapperCommand,
    /// The replayed mapper command (`None`: not re-executed).
    pub mapper_replayed: Option<MapperCommand>,
    /// The filter's time argument.
    pub now_ns: u64,
    /// The control bits applied before the step.
    pub control: u32,
    /// The recorded safety command.
    pub safe_recorded: SafeCommand,
    /// The replayed safety command.
    pub safe_replayed: SafeCommand,
    /// The filter's report of the step.
    pub report: safety::StepReport,
    /// The filter's configuration.
    pub config: safety::SafetyConfig,
}

/// `s·H(q, c)` of mapper process `pid`'s model at `state`, if the map is linear in the action
/// (SCL, PCA): probed column by column on a fresh copy of the model.
fn linear_map_at(
    rec: &Recording,
    pid: u32,
    robot: &'static kinematics::RobotProfile,
    state: &RobotState,
) -> Option<[[f64; ipc_types::MAX_JOINTS]; ipc_types::ACTION_DIM]> {
    let (mut model, _, _) = rec.model(0, pid, robot, &mut Vec::new()).ok()??;
    if !matches!(
        model.header.kind,
        mapper::model::ModelKind::Scl | mapper::model::ModelKind::Pca
    ) {
        return None;
    }
    let n = robot.n_joints().min(ipc_types::MAX_JOINTS);
    if state.n_joints as usize != n
        || model.header.n_joints != n
        || !state.q().iter().all(|v| v.is_finite())
        || !state.gripper.is_finite()
    {
        return None;
    }
    let s = model.header.speed_scale_rad_s;
    let mut h = [[0.0; ipc_types::MAX_JOINTS]; ipc_types::ACTION_DIM];
    for (j, col) in h.iter_mut().enumerate() {
        let mut a = [0.0; ipc_types::ACTION_DIM];
        a[j] = 1.0;
        model.map.eval(state.q(), state.gripper, &a, &mut col[..n]);
        col[..n].iter_mut().for_each(|v| *v *= s);
    }
    Some(h)
}

/// Mapper commands keyed by (mapper id, tick, t_ns): their replayed version.
type Replayed = HashMap<(u32, u64, u64), MapperCommand>;

/// Replays `rec`: every mapper command through its mapper's step, then every safety command
/// through the filter, each compared with the recorded one. With `explain_tick`, also the
/// trace of that tick.
pub fn replay(
    rec: &Recording,
    explain_tick: Option<u64>,
) -> Result<(Replay, Option<TickTrace>), ReplayError> {
    let mut notes = recording_notes(rec);
    let cfg = rec.graph_config(&mut notes)?;
    let robot = cfg
        .profile()
        .map_err(|e| graph_config_error(rec, e.to_string()))?;
    let period_s = cfg.period_s();
    let mappers = replay_mappers(rec, robot, period_s, &mut notes)?;
    let SafetyReplay {
        mut out,
        mut first,
        trace,
        old_control,
    } = replay_safety(rec, &cfg, robot, period_s, &mappers, explain_tick)?;
    // A mapper that diverged before any tick safety forwarded from it (a swap's warm-up)
    // is the first divergence if it came first.
    if let Some(m) = mappers.divs.values().next()
        && first.as_ref().is_none_or(|f| m.tick < f.tick)
    {
        first = Some(m.clone());
    }
    if old_control {
        notes.push(
            "the recording has no control bits (made before they were recorded): e-stop and \
             hold taken from the recorded flags, interruptions unknown, the filter's time \
             approximate"
                .into(),
        );
    }
    if out.ticks == 0 {
        return Err(ReplayError::Empty {
            path: rec.path.clone(),
            reason: "no safety command could be replayed (their mapper commands or robot \
                     states are not in the recording)"
                .into(),
        });
    }
    if let Some(t) = explain_tick
        && trace.is_none()
    {
        let first_tick = rec.safe.iter().map(|s| s.tick).min().unwrap_or(0);
        let last_tick = rec.safe.iter().map(|s| s.tick).max().unwrap_or(0);
        return Err(ReplayError::NoSuchTick {
            path: rec.path.clone(),
            tick: t,
            first: first_tick,
            last: last_tick,
        });
    }
    out.first_divergence = first;
    out.notes = notes;
    Ok((out, trace))
}

/// What the reader of a replay must know of the recording itself: it is cut, or some of
/// its messages did not decode.
fn recording_notes(rec: &Recording) -> Vec<String> {
    let mut notes = Vec::new();
    if let Some(why) = &rec.stopped {
        notes.push(format!(
            "the recording is incomplete ({why}): replayed up to its end"
        ));
    }
    if rec.undecodable > 0 {
        notes.push(format!(
            "{} messages did not decode (a non-finite value is written as null) and were left out",
            rec.undecodable
        ));
    }
    notes
}

/// The recorded graph configuration is unusable: `reason`.
fn graph_config_error(rec: &Recording, reason: String) -> ReplayError {
    ReplayError::Config {
        path: rec.path.clone(),
        what: "the graph configuration".into(),
        reason,
    }
}

/// A mapper process's step, with its model's name and whether the model file was altered
/// after the recording; `None` when the recording does not hold its model.
type ReplayedMapper = Option<(MapperStep, String, bool)>;

/// The mappers' replay.
#[derive(Default)]
struct MapperReplay {
    /// Each mapper process's step, by process id.
    steps: HashMap<u32, ReplayedMapper>,
    /// The replayed commands.
    replayed: Replayed,
    /// The first divergence of each (tick, mapper id).
    divs: BTreeMap<(u64, u32), Divergence>,
    /// Of those, the ones whose joystick sample was not in the recording (rebuilt).
    lost_input: std::collections::BTreeSet<(u64, u32)>,
    /// Commands replayed.
    commands: u64,
    /// Commands replayed bit for bit.
    identical: u64,
    /// Commands whose model or robot state is not in the recording.
    skipped: u64,
}

/// Replays every mapper command through its process's step, in recorded order.
fn replay_mappers(
    rec: &Recording,
    robot: &'static kinematics::RobotProfile,
    period_s: f64,
    notes: &mut Vec<String>,
) -> Result<MapperReplay, ReplayError> {
    let mut m = MapperReplay::default();
    let mut rebuilt = 0u64;
    for cmd in &rec.mapper {
        let pid = rec.incarnation(NodeRole::Mapper, cmd.mapper_id, cmd.t_ns);
        if let std::collections::hash_map::Entry::Vacant(slot) = m.steps.entry(pid) {
            slot.insert(mapper_step(
                rec,
                cmd.mapper_id,
                pid,
                robot,
                period_s,
                notes,
            )?);
        }
        let Some(Some((step, model_name, altered))) = m.steps.get_mut(&pid) else {
            m.skipped += 1;
            continue;
        };
        let Some(state) = rec.states.get(&cmd.state_t_ns) else {
            m.skipped += 1;
            continue;
        };
        let joy = joystick_for(rec, cmd);
        if joy.is_some_and(|(_, r)| r) {
            rebuilt += 1;
        }
        let mut out = step.step(state, joy.as_ref().map(|(j, _)| j));
        out.t_ns = cmd.t_ns;
        out.state_rx_ns = cmd.state_rx_ns;
        out.joystick_rx_ns = cmd.joystick_rx_ns;
        out.compute_ns = cmd.compute_ns;
        m.commands += 1;
        let d = mapper_diff(cmd, &out);
        if d.is_empty() {
            m.identical += 1;
        } else {
            let rebuilt_joy = matches!(joy, Some((_, true)));
            if rebuilt_joy {
                m.lost_input.insert((cmd.tick, cmd.mapper_id));
            }
            let input = mapper_input(*altered, rebuilt_joy, model_name, state.tick, cmd);
            m.divs
                .entry((cmd.tick, cmd.mapper_id))
                .or_insert_with(|| Divergence {
                    tick: cmd.tick,
                    stage: "mapper".into(),
                    mapper_id: cmd.mapper_id,
                    fields: d,
                    recorded_flags: bit_names(cmd.flags, &ipc_types::mapper_flags::NAMES),
                    replayed_flags: bit_names(out.flags, &ipc_types::mapper_flags::NAMES),
                    input,
                });
        }
        m.replayed.insert((cmd.mapper_id, cmd.tick, cmd.t_ns), out);
    }
    if rebuilt > 0 {
        notes.push(format!(
            "{rebuilt} joystick samples were not in the recording and were rebuilt from the \
             mapper's commands"
        ));
    }
    Ok(m)
}

/// The step of mapper `mapper_id`'s process `pid`, from the model the recording holds.
fn mapper_step(
    rec: &Recording,
    mapper_id: u32,
    pid: u32,
    robot: &'static kinematics::RobotProfile,
    period_s: f64,
    notes: &mut Vec<String>,
) -> Result<ReplayedMapper, ReplayError> {
    Ok(match rec.model(mapper_id, pid, robot, notes)? {
        Some((model, name, altered)) => Some((
            MapperStep::for_robot(mapper_id, model.at_period(period_s), robot).map_err(
                |source| ReplayError::Model {
                    path: rec.path.clone(),
                    mapper_id,
                    pid,
                    source,
                },
            )?,
            name,
            altered,
        )),
        None => None,
    })
}

/// What was not fed as recorded to a mapper command that diverged (its divergence's
/// `input`): the model file (`altered`), the joystick sample (`rebuilt`), or nothing.
fn mapper_input(
    altered: bool,
    rebuilt: bool,
    model_name: &str,
    state_tick: u64,
    cmd: &MapperCommand,
) -> String {
    if altered {
        format!(
            "the model: {model_name} is not the file recorded (its SHA-256 differs from \
             the one recorded with it); the robot state (tick {state_tick}) and joystick sample \
             (seq {}) were fed as recorded",
            cmd.joystick_seq
        )
    } else if rebuilt {
        format!(
            "the joystick sample (seq {}) is not in the recording and was rebuilt from \
             the command",
            cmd.joystick_seq
        )
    } else {
        format!(
            "none: the recorded robot state (tick {state_tick}) and joystick sample (seq {}) were \
             fed as recorded; the model ({model_name}) or the map's state differs",
            cmd.joystick_seq
        )
    }
}

/// The safety filter's replay.
struct SafetyReplay {
    /// The counts (the first divergence and the notes not yet set).
    out: Replay,
    /// The first tick that diverged, at the mapper or at safety.
    first: Option<Divergence>,
    /// The trace of the tick asked for.
    trace: Option<TickTrace>,
    /// Whether commands recorded before the control bits were replayed.
    old_control: bool,
}

/// Replays every safety command through its process's filter, in recorded order, each fed
/// the mapper command as replayed (as recorded where it was not).
fn replay_safety(
    rec: &Recording,
    cfg: &scl_config::GraphConfig,
    robot: &'static kinematics::RobotProfile,
    period_s: f64,
    mappers: &MapperReplay,
    explain_tick: Option<u64>,
) -> Result<SafetyReplay, ReplayError> {
    let recorded_mapper: HashMap<(u32, u64, u64), &MapperCommand> = rec
        .mapper
        .iter()
        .map(|c| ((c.mapper_id, c.tick, c.t_ns), c))
        .collect();
    let mut filters: HashMap<u32, SafetyFilter> = HashMap::new();
    let mut r = SafetyReplay {
        out: Replay {
            ticks: 0,
            identical: 0,
            diverged: 0,
            diverged_on_lost_input: 0,
            first_divergence: None,
            mapper_commands: mappers.commands,
            mapper_identical: mappers.identical,
            skipped: mappers.skipped,
            events: control_events(&rec.safe),
            notes: Vec::new(),
        },
        first: None,
        trace: None,
        old_control: false,
    };
    for safe in &rec.safe {
        let key = (safe.mapper_id, safe.tick, safe.mapper_t_ns);
        let Some(state) = rec.states.get(&safe.state_t_ns) else {
            r.out.skipped += 1;
            continue;
        };
        // A tick safety answered itself (the e-stop latched, no mapper command in time): it
        // names no mapper command (`mapper_t_ns` 0) and is replayed as it ran.
        let unanswered = safe.mapper_t_ns == 0 && !recorded_mapper.contains_key(&key);
        let stand_in = unanswered.then(|| safety::unanswered_command(safe.mapper_id, state));
        let Some(rec_cmd) = recorded_mapper.get(&key).copied().or(stand_in.as_ref()) else {
            r.out.skipped += 1;
            continue;
        };
        let pid = rec.incarnation(NodeRole::Safety, 0, safe.t_ns);
        let filter = match filters.entry(pid) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(v) => v.insert(
                SafetyFilter::for_graph(cfg.safety.clone(), robot, period_s)
                    .map_err(|e| graph_config_error(rec, format!("the safety filter: {e}")))?,
            ),
        };
        let rep_cmd = mappers.replayed.get(&key);
        let input_cmd = rep_cmd.copied().unwrap_or(*rec_cmd);
        let (control, recorded) = control_bits(safe);
        r.old_control |= !recorded;
        let input = (!unanswered).then_some(&input_cmd);
        let (res, now_ns) = step_as_recorded(filter, safe, state, input, control, recorded);
        r.out.ticks += 1;
        let d = safe_diff(safe, &res);
        let mapper_div = mappers.divs.get(&(safe.tick, safe.mapper_id));
        if d.is_empty() && mapper_div.is_none() {
            r.out.identical += 1;
        } else {
            r.out.diverged += 1;
            if mapper_div.is_some() && mappers.lost_input.contains(&(safe.tick, safe.mapper_id)) {
                r.out.diverged_on_lost_input += 1;
            }
            if r.first.is_none() {
                r.first = Some(match mapper_div {
                    Some(m) => m.clone(),
                    None => safety_divergence(safe, &res, d),
                });
            }
        }
        if explain_tick == Some(safe.tick) {
            let mapper_pid = rec.incarnation(NodeRole::Mapper, safe.mapper_id, rec_cmd.t_ns);
            r.trace = Some(TickTrace {
                state: *state,
                joystick: joystick_for(rec, rec_cmd),
                model: mappers
                    .steps
                    .get(&mapper_pid)
                    .and_then(|s| s.as_ref().map(|(_, n, _)| n.clone())),
                h: linear_map_at(rec, mapper_pid, robot, state),
                mapper_recorded: *rec_cmd,
                mapper_replayed: rep_cmd.copied(),
                now_ns,
                control,
                safe_recorded: *safe,
                safe_replayed: res,
                report: filter.last_report(),
                config: filter.config().clone(),
            });
        }
    }
    Ok(r)
}

/// Steps `filter` as safety did for the recorded `safe`: `control` applied, at the time it
/// began, on the mapper command `input` (`None`: a tick safety answered itself); the result
/// stamped as recorded (with the recorded control field if the bits were not `recorded`).
/// Returns it and the filter's time argument.
fn step_as_recorded(
    filter: &mut SafetyFilter,
    safe: &SafeCommand,
    state: &RobotState,
    input: Option<&MapperCommand>,
    control: u32,
    recorded: bool,
) -> (SafeCommand, u64) {
    filter.apply_control(control);
    let now_ns = safe.t_ns.saturating_sub(safe.compute_ns);
    let mut res = match input {
        None => filter.step_unanswered(safe.mapper_id, state, now_ns),
        Some(cmd) => filter.step(cmd, state, now_ns),
    };
    res.t_ns = safe.t_ns;
    res.mapper_rx_ns = safe.mapper_rx_ns;
    res.compute_ns = safe.compute_ns;
    if !recorded {
        res.control = safe.control;
    }
    (res, now_ns)
}

/// The control bits safety applied before a recorded step, and whether they were recorded:
/// before they were, the flags say whether the e-stop was latched and the arm held (an
/// interruption is not known).
fn control_bits(safe: &SafeCommand) -> (u32, bool) {
    if safe.control & safe_control::RECORDED != 0 {
        return (safe.control, true);
    }
    let mut c = 0;
    if safe.flags & safe_flags::ESTOP != 0 {
        c |= safe_control::ESTOP;
    }
    if safe.flags & safe_flags::HOLD != 0 {
        c |= safe_control::HOLD;
    }
    (c, false)
}

/// A safety command `res` that replayed differently from the recorded `safe` (fields `d`),
/// fed as recorded.
fn safety_divergence(safe: &SafeCommand, res: &SafeCommand, d: Vec<FieldDiff>) -> Divergence {
    Divergence {
        tick: safe.tick,
        stage: "safety".into(),
        mapper_id: safe.mapper_id,
        fields: d,
        recorded_flags: bit_names(safe.flags, &safe_flags::NAMES),
        replayed_flags: bit_names(res.flags, &safe_flags::NAMES),
        input: "none: the mapper command, robot state, control inputs and time \
                were fed as recorded; the filter or its configuration differs"
            .into(),
    }
}

/// The human-readable report of a replay.
pub fn render(path: &Path, r: &Replay) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for n in &r.notes {
        let _ = writeln!(s, "note: {n}");
    }
    let _ = writeln!(
        s,
        "{}: {} ticks replayed, {} identical, {} diverged; mapper commands {} of {} identical{}",
        path.display(),
        r.ticks,
        r.identical,
        r.diverged,
        r.mapper_identical,
        r.mapper_commands,
        if r.skipped > 0 {
            format!(", {} not re-executed", r.skipped)
        } else {
            String::new()
        }
    );
    if !r.events.is_empty() {
        let ev: Vec<String> = r
            .events
            .iter()
            .map(|e| match e.mapper_id {
                Some(m) => format!("{} {} to mapper {m}", e.tick, e.event),
                None => format!("{} {}", e.tick, e.event),
            })
            .collect();
        let _ = writeln!(s, "control events (tick event): {}", ev.join(", "));
    }
    if let Some(d) = &r.first_divergence {
        let _ = writeln!(
            s,
            "first divergence at tick {} in the {} (mapper {}):",
            d.tick, d.stage, d.mapper_id
        );
        for f in &d.fields {
            let _ = writeln!(
                s,
                "  {:<16} recorded {:<24} replayed {}",
                f.field, f.recorded, f.replayed
            );
        }
        let _ = writeln!(
            s,
            "  flags recorded [{}] replayed [{}]",
            d.recorded_flags.join(", "),
            d.replayed_flags.join(", ")
        );
        let _ = writeln!(s, "  input that differed: {}", d.input);
    } else {
        let _ = writeln!(s, "every command replayed bit for bit");
    }
    s
}

#[cfg(test)]
mod tests;

/// `scl replay`'s arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// The recording to replay (`scl up --record` / `scl record`).
    pub file: PathBuf,
    /// Print `{"ticks", "identical", "diverged", "first_divergence", ...}` as one JSON
    /// object on stdout instead of the text report.
    #[arg(long)]
    pub json: bool,
    /// The tick to explain (with `--explain`).
    #[arg(long, value_name = "K")]
    pub tick: Option<u64>,
    /// For tick K: its inputs, the map's output, what each safety rule did, the command.
    #[arg(long, requires = "tick")]
    pub explain: bool,
    /// Counterfactual: the recorded states and joystick samples through this model instead
    /// (a file, `bundled`, `modeswitch[:...]`, `constant:qdot=...`), open loop; needs --out.
    #[arg(long, value_name = "MODEL", requires = "out")]
    pub model: Option<String>,
    /// Counterfactual: the `[safety]` of this graph TOML instead of the recorded one; needs
    /// --out.
    #[arg(long, value_name = "FILE", requires = "out")]
    pub safety: Option<PathBuf>,
    /// Counterfactual: drive a mock arm of the recorded robot from the recorded first state
    /// with the what-if commands, instead of the recorded states ("where would the tool have
    /// gone"); needs --out.
    #[arg(long, requires = "out")]
    pub closed_loop: bool,
    /// Replay what can be read of a cut or damaged recording (up to its first unreadable
    /// record) instead of refusing it; the report says where reading stopped.
    #[arg(long)]
    pub partial: bool,
    /// Counterfactual: write the recording with the what-if commands beside the recorded
    /// ones (`/whatif/mapper_command`, `/whatif/safe_command`) to this MCAP file (never
    /// overwritten).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// `scl replay`: replays the recording and reports; exit code 1 if any command diverged.
pub fn cli(args: &ReplayArgs) -> Result<std::process::ExitCode, ReplayError> {
    let started = std::time::Instant::now();
    let rec = Recording::read(&args.file)?;
    let read_s = started.elapsed().as_secs_f64();
    if let Some(stopped) = &rec.stopped {
        if !args.partial {
            return Err(ReplayError::Incomplete {
                path: args.file.clone(),
                stopped: stopped.clone(),
            });
        }
        eprintln!(
            "scl replay --partial: {}: {stopped}; replaying the {} safety commands before it",
            args.file.display(),
            rec.safe.len()
        );
    }
    if let Some(out) = &args.out {
        let what = whatif::WhatIf {
            model: args.model.clone(),
            safety: args.safety.clone(),
            closed_loop: args.closed_loop,
        };
        let s = whatif::run(&rec, &what, out)?;
        if args.json {
            let text = serde_json::to_string(&s).map_err(|e| ReplayError::Empty {
                path: args.file.clone(),
                reason: format!("cannot encode the summary: {e}"),
            })?;
            println!("{text}");
        } else {
            print!("{}", whatif::render(&s));
        }
        return Ok(std::process::ExitCode::SUCCESS);
    }
    let (r, trace) = replay(&rec, args.tick.filter(|_| args.explain))?;
    let total_s = started.elapsed().as_secs_f64();
    tracing::debug!(
        ticks = r.ticks,
        read_s,
        total_s,
        "replayed {}",
        args.file.display()
    );
    if let Some(t) = &trace {
        print!("{}", explain::render(t));
    }
    if args.json {
        let text = serde_json::to_string(&r).map_err(|e| ReplayError::Empty {
            path: args.file.clone(),
            reason: format!("cannot encode the report: {e}"),
        })?;
        println!("{text}");
    } else if trace.is_none() {
        print!("{}", render(&args.file, &r));
        println!(
            "read in {read_s:.2} s, replayed in {:.2} s",
            total_s - read_s
        );
    } else {
        for n in &r.notes {
            eprintln!("note: {n}");
        }
    }
    Ok(if r.diverged > 0 || r.first_divergence.is_some() {
        std::process::ExitCode::from(1)
    } else {
        std::process::ExitCode::SUCCESS
    })
}
