//! The graph in Foxglove's well-known schemas, beside the recording's JSON topics: what the
//! recorder writes into every recording, what `scl live` serves over Foxglove's WebSocket
//! protocol, and what `scl record --convert` adds to an older recording.
//!
//! * [`scene`]: pure builders, state -> `foxglove.FrameTransforms` / `foxglove.SceneUpdate`.
//! * [`Viz`]: the observer's state machine. It takes the graph's messages in the order an
//!   observer sees them ([`recording::Payload`]) and produces, for each robot state, the
//!   frames of every link and the tool ([`VizTopic::Tf`]), the arm's capsules coloured by
//!   clearance ([`VizTopic::Arm`]), the map's two directions and the executed tool velocity
//!   ([`VizTopic::Map`]), the table, boxes and workspace bounds once a second
//!   ([`VizTopic::World`]), and one JSON row of plottable numbers ([`VizTopic::Tick`]).
//! * [`convert`]: `scl record --convert OLD.mcap --out NEW.mcap`.
//! * [`client`]: a minimal Foxglove WebSocket client (the tests, `scl bench latency --live`).
//!
//! The map's directions: for stick axis `i` the arrow is the tool twist `J(q)·s·H(o)·e_i` of
//! a full deflection, `s` the model's speed scale and `H(o)·e_i` what
//! [`mapper::ActionMap::direction`] gives at the state (a column of `H` for SCL and PCA; the
//! current mode's axis for mode switching). The observer evaluates the same model the mapper
//! serves (loaded from the mapper's command line, or from the recording's attachment), on a
//! copy of its own: exact for maps without memory, and for mode switching the mode is the
//! one the mapper's latest heartbeat reports. That keeps the messages of the graph as they
//! are (the mapper publishing `H` would grow `MapperCommand` by 12 doubles for every
//! consumer) and the observer off the control path.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod client;
pub mod convert;
pub mod log;
pub mod scene;

use std::collections::BTreeMap;

use foxglove::Encode;
use ipc_types::{MAX_JOINTS, NodeRole, RobotState, SafeCommand, buttons, safe_flags};
use kinematics::collision::{CapsuleRef, CollisionModel, MAX_ARM_JOINTS};

use kinematics::{Chain, Clearance, Jacobian, RobotProfile, Scene};
use mapper::LoadedModel;
use nalgebra::{DVector, Vector3};
use recording::{Payload, SchemaInfo};
use scl_config::GraphConfig;
use serde::Serialize;

pub use scene::{ANGULAR_ARROW_M_PER_RAD_S, LINEAR_ARROW_S, TOOL_FRAME};

/// What can go wrong building the 3D view or converting a recording.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// The graph configuration (its robot) is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// The `[safety]` scene is unusable.
    #[error(transparent)]
    Scene(#[from] safety::ConfigError),
    /// A state's kinematics could not be computed (what for: `forward kinematics`, ...).
    #[error("{what}: {source}")]
    Kinematics {
        /// What was being computed.
        what: &'static str,
        /// Why.
        source: kinematics::KinError,
    },
    /// A recording could not be read or written.
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// A mapper's model could not be loaded for the map's arrows.
    #[error("mapper {mapper_id}: cannot load its model for the map's arrows: {source}")]
    Model {
        /// The mapper.
        mapper_id: u32,
        /// Why.
        source: mapper::ModelError,
    },
    /// A message could not be encoded.
    #[error("cannot encode a {topic} message: {reason}")]
    Encode {
        /// The topic.
        topic: &'static str,
        /// Why.
        reason: String,
    },
}

/// The channels the 3D view adds beside the recording's JSON topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum VizTopic {
    /// `/tf`: `foxglove.FrameTransforms`, every link and the tool, every robot state.
    Tf,
    /// `/scl/arm`: `foxglove.SceneUpdate`, the collision capsules coloured by clearance.
    Arm,
    /// `/scl/map`: `foxglove.SceneUpdate`, the map's two directions and the executed velocity.
    Map,
    /// `/scl/world`: `foxglove.SceneUpdate`, table, boxes and workspace bounds (once a second).
    World,
    /// `/scl/tick`: JSON, the plottable numbers of a tick ([`TickView`]).
    Tick,
    /// `/scl/log`: `foxglove.Log`, what the processes and the safety filter say, and the
    /// processes' own log records ([`log`]).
    Log,
}

impl VizTopic {
    /// Every channel, in a fixed order.
    pub const ALL: [VizTopic; 6] = [
        VizTopic::Tf,
        VizTopic::Arm,
        VizTopic::Map,
        VizTopic::World,
        VizTopic::Tick,
        VizTopic::Log,
    ];

    /// The channel's topic.
    pub fn topic(self) -> &'static str {
        match self {
            VizTopic::Tf => "/tf",
            VizTopic::Arm => "/scl/arm",
            VizTopic::Map => "/scl/map",
            VizTopic::World => "/scl/world",
            VizTopic::Tick => "/scl/tick",
            VizTopic::Log => "/scl/log",
        }
    }

    /// The channel of a topic name.
    pub fn from_topic(topic: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.topic() == topic)
    }

    /// The message encoding (`protobuf` or `json`).
    pub fn message_encoding(self) -> &'static str {
        match self {
            VizTopic::Tick => "json",
            _ => "protobuf",
        }
    }

    /// The channel's schema: Foxglove's protobuf descriptors, or the JSON schema of [`TickView`].
    pub fn schema(self) -> SchemaInfo {
        let fg = match self {
            VizTopic::Tf => foxglove::messages::FrameTransforms::get_schema(),
            VizTopic::Arm | VizTopic::Map | VizTopic::World => {
                foxglove::messages::SceneUpdate::get_schema()
            }
            VizTopic::Log => foxglove::messages::Log::get_schema(),
            VizTopic::Tick => None,
        };
        match fg {
            Some(s) => SchemaInfo {
                name: s.name,
                encoding: s.encoding,
                data: s.data.into_owned(),
            },
            None => SchemaInfo {
                name: "scl.TickView".into(),
                encoding: "jsonschema".into(),
                data: serde_json::to_vec(&schemars::schema_for!(TickView)).unwrap_or_default(),
            },
        }
    }
}

/// One message of the 3D view: its channel, its time (the state's monotonic `t_ns`, the
/// recording's clock) and its encoded bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct VizMessage {
    /// The channel.
    pub topic: VizTopic,
    /// Log time (monotonic ns).
    pub t_ns: u64,
    /// Encoded message.
    pub data: Vec<u8>,
}

/// The plottable numbers of one robot state (`/scl/tick`, JSON): the tool, the map's
/// directions, the clearance, and the last executed command's latency and safety rules.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct TickView {
    /// The robot state's tick.
    pub tick: u64,
    /// Tool position in the base frame (m).
    pub tool_m: [f64; 3],
    /// Executed tool velocity `J·qdot` from the measured joint velocities (m/s).
    pub tool_velocity_m_s: [f64; 3],
    /// Its norm (m/s).
    pub tool_speed_m_s: f64,
    /// `J·s·H·e_1`: tool velocity a full deflection of stick axis 1 would command (m/s);
    /// `null` while the map is not known.
    pub axis1_m_s: Option<[f64; 3]>,
    /// `J·s·H·e_2` (m/s).
    pub axis2_m_s: Option<[f64; 3]>,
    /// Angular part of `J·s·H·e_1` (rad/s).
    pub axis1_rad_s: Option<[f64; 3]>,
    /// Angular part of `J·s·H·e_2` (rad/s).
    pub axis2_rad_s: Option<[f64; 3]>,
    /// The mapper whose map the arrows show.
    pub mapper_id: Option<u32>,
    /// Its mode (mode switching: `x-y`, `z-yaw`, `roll-pitch`).
    pub mode: Option<String>,
    /// Smallest clearance of any checked pair (m); `null` without a collision model.
    pub clearance_m: Option<f64>,
    /// The closest pair (`forearm-table`).
    pub closest_pair: Option<String>,
    /// Tick of the newest executed command seen.
    pub command_tick: Option<u64>,
    /// Its latency from the robot state to the safe command (ms).
    pub latency_ms: Option<f64>,
    /// Its safety rules acting, as bits ([`ipc_types::safe_flags`]).
    pub rule_bits: u32,
    /// The same rules by name.
    pub rules: Vec<String>,
}

/// A mapper's model as the observer holds it.
struct Mapper {
    model: LoadedModel,
    /// The mode its heartbeat reports (mode + 1; 0 without modes).
    mode: u32,
}

/// The observer's state: the robot, the scene, the mappers' models, and what it last saw.
pub struct Viz {
    robot: &'static RobotProfile,
    collision: Option<&'static CollisionModel>,
    refs: Vec<CapsuleRef>,
    scene: Scene,
    boxes: Vec<(String, [f64; 3], [f64; 3])>,
    workspace: Option<([f64; 3], [f64; 3])>,
    clearance: Box<Clearance>,
    jac: Jacobian,
    mappers: BTreeMap<u32, Mapper>,
    /// The active mapper (of the newest safe command), else the newest loaded.
    active: Option<u32>,
    last_safe: Option<SafeCommand>,
    last_world_ns: Option<u64>,
    /// Each capsule's clearance colour step as last sent ([`scene::clearance_step`]).
    steps: Vec<Option<u8>>,
    last_arm_ns: Option<u64>,
    log: log::LogView,
    log_lines: Vec<foxglove::messages::Log>,
}

impl std::fmt::Debug for Viz {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Viz")
            .field("robot", &self.robot.name())
            .field("mappers", &self.mappers.keys().collect::<Vec<_>>())
            .finish_non_exhaustive()
    }
}

/// How often the static scene (table, boxes, bounds) and every capsule of the arm are sent
/// (ns); in between, a capsule is sent when its clearance colour step changes.
pub const WORLD_EVERY_NS: u64 = 1_000_000_000;

fn due(last: Option<u64>, t: u64) -> bool {
    last.is_none_or(|w| t < w || t - w >= WORLD_EVERY_NS)
}

fn encode<T: Encode>(topic: VizTopic, m: &T) -> Result<Vec<u8>, VizError> {
    let mut buf = Vec::with_capacity(m.encoded_len().unwrap_or(256));
    m.encode(&mut buf).map_err(|e| VizError::Encode {
        topic: topic.topic(),
        reason: e.to_string(),
    })?;
    Ok(buf)
}

impl Viz {
    /// The view of a graph with configuration `cfg`: its robot and its `[safety]` scene and
    /// workspace bounds.
    pub fn new(cfg: &GraphConfig) -> Result<Self, VizError> {
        let robot = cfg.profile()?;
        let mut v = Self {
            robot,
            collision: None,
            refs: Vec::new(),
            scene: Scene::empty(),
            boxes: Vec::new(),
            workspace: None,
            clearance: Box::default(),
            jac: Jacobian::zeros(robot.n_joints()),
            mappers: BTreeMap::new(),
            active: None,
            last_safe: None,
            last_world_ns: None,
            steps: Vec::new(),
            last_arm_ns: None,
            log: log::LogView::default(),
            log_lines: Vec::new(),
        };
        v.configure(cfg)?;
        Ok(v)
    }

    /// Takes the robot, scene and bounds of `cfg` (the safety process's configuration); the
    /// models loaded so far stay if the robot is the same.
    pub fn configure(&mut self, cfg: &GraphConfig) -> Result<(), VizError> {
        let robot = cfg.profile()?;
        if robot.name() != self.robot.name() {
            self.mappers.clear();
            self.active = None;
        }
        self.robot = robot;
        self.jac = Jacobian::zeros(robot.n_joints());
        self.collision = robot.collision_model();
        self.refs = self
            .collision
            .map(|c| c.capsule_refs().to_vec())
            .unwrap_or_default();
        let sc = &cfg.safety.scene;
        self.scene = sc.scene()?;
        self.boxes = sc
            .boxes
            .iter()
            .map(|b| (b.name.clone(), b.min, b.max))
            .collect();
        let w = &cfg.safety.workspace;
        self.workspace = w.enabled.then_some((w.box_min_m, w.box_max_m));
        // Send the world and the whole arm again with the next state.
        self.last_world_ns = None;
        self.last_arm_ns = None;
        self.steps = vec![None; self.refs.len()];
        Ok(())
    }

    /// The robot drawn.
    pub fn robot(&self) -> &'static RobotProfile {
        self.robot
    }

    /// Serves mapper `mapper_id`'s model for the map's arrows (replacing an earlier one).
    pub fn set_model(&mut self, mapper_id: u32, model: LoadedModel) {
        self.mappers.insert(mapper_id, Mapper { model, mode: 0 });
        if self.last_safe.is_none() {
            self.active = Some(mapper_id);
        }
    }

    /// Takes what a mapper or safety process runs (as read from its command line): a safety
    /// process's configuration gives the robot, scene and bounds; a mapper's model spec (a
    /// file or a built-in name) is loaded for the map's arrows.
    pub fn take_process(
        &mut self,
        role: NodeRole,
        mapper_id: u32,
        cfg: Option<&GraphConfig>,
        model: Option<&str>,
    ) -> Result<(), VizError> {
        if role == NodeRole::Safety
            && let Some(c) = cfg
        {
            self.configure(c)?;
        }
        if role == NodeRole::Mapper
            && let Some(spec) = model
        {
            let m = LoadedModel::load_for(spec, self.robot)
                .map_err(|source| VizError::Model { mapper_id, source })?;
            self.set_model(mapper_id, m);
        }
        Ok(())
    }

    /// Whether a model is known for `mapper_id`.
    pub fn has_model(&self, mapper_id: u32) -> bool {
        self.mappers.contains_key(&mapper_id)
    }

    /// Takes one message of the graph; appends what it produces to `out`: the 3D view for a
    /// robot state (commands and heartbeats update what the next state shows), and the
    /// `/scl/log` lines of any message that changes what a process or the filter says.
    pub fn observe(&mut self, p: &Payload, out: &mut Vec<VizMessage>) -> Result<(), VizError> {
        self.log_lines.clear();
        self.log.observe(p, &mut self.log_lines);
        for l in &self.log_lines {
            out.push(VizMessage {
                topic: VizTopic::Log,
                t_ns: p.t_ns(),
                data: encode(VizTopic::Log, l)?,
            });
        }
        match p {
            Payload::RobotState(s) => self.state(s, out)?,
            Payload::SafeCommand(c) => {
                self.active = Some(c.mapper_id);
                self.last_safe = Some(*c);
            }
            Payload::Status(st) if NodeRole::from_u32(st.role) == Some(NodeRole::Mapper) => {
                if let Some(m) = self.mappers.get_mut(&st.mapper_id) {
                    m.mode = st.mode;
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Takes one of the processes' own log records (the graph's `log` topic); appends its
    /// `/scl/log` line to `out`.
    pub fn observe_log(
        &mut self,
        r: &ipc_types::LogRecord,
        out: &mut Vec<VizMessage>,
    ) -> Result<(), VizError> {
        out.push(VizMessage {
            topic: VizTopic::Log,
            t_ns: r.t_ns,
            data: encode(VizTopic::Log, &log::record_line(r))?,
        });
        Ok(())
    }

    /// `s·H·e_i` of the active mapper at `s` (joint velocities per axis), with its id and mode.
    fn directions(
        &mut self,
        s: &RobotState,
    ) -> Option<([[f64; MAX_JOINTS]; 2], u32, Option<String>)> {
        let id = self.active?;
        let n = self.robot.n_joints();
        let m = self.mappers.get_mut(&id)?;
        if m.model.header.n_joints != n || s.n_joints as usize != n {
            return None;
        }
        // Bring the copy's mode to the mapper's (mode switching cycles through 3 modes).
        if m.mode > 0 {
            for _ in 0..8 {
                match m.model.map.mode() {
                    Some(mm) if mm.index + 1 != m.mode => m.model.map.press(buttons::MODE),
                    _ => break,
                }
            }
        }
        let scale = m.model.header.speed_scale_rad_s;
        let mut cols = [[0.0; MAX_JOINTS]; 2];
        for (i, col) in cols.iter_mut().enumerate() {
            m.model.map.direction(s.q(), s.gripper, i, &mut col[..n]);
            col[..n].iter_mut().for_each(|v| *v *= scale);
        }
        let mode = m.model.map.mode().map(|mm| mm.name.to_owned());
        cols.iter()
            .all(|c| c.iter().all(|v| v.is_finite()))
            .then_some((cols, id, mode))
    }

    /// A robot state's messages: the frames, the arm's capsules with their clearances, the
    /// map's arrows, the world (now and then) and the tick's row.
    fn state(&mut self, s: &RobotState, out: &mut Vec<VizMessage>) -> Result<(), VizError> {
        let chain: &Chain = self.robot.arm();
        let n = chain.n_joints();
        if s.n_joints as usize != n || !s.q().iter().all(|v| v.is_finite()) {
            // Nothing to draw from a state of another arm or a broken one.
            return Ok(());
        }
        let t = s.t_ns;
        let frame = scene::root_frame(chain).to_owned();
        let mut tf =
            scene::frame_transforms(chain, s.q(), t).map_err(|source| VizError::Kinematics {
                what: "forward kinematics",
                source,
            })?;
        let (clearance, arm) = match self.collision {
            Some(cm) => self.collision_update(cm, chain, s, &mut tf)?,
            None => (None, None),
        };
        out.push(VizMessage {
            topic: VizTopic::Tf,
            t_ns: t,
            data: encode(VizTopic::Tf, &tf)?,
        });
        if let Some(arm) = arm {
            out.push(VizMessage {
                topic: VizTopic::Arm,
                t_ns: t,
                data: encode(VizTopic::Arm, &arm)?,
            });
        }
        let tool =
            chain
                .fk_jacobian(s.q(), &mut self.jac)
                .map_err(|source| VizError::Kinematics {
                    what: "Jacobian",
                    source,
                })?;
        let jm = self.jac.matrix().into_owned();
        let twist = |qd: &[f64]| {
            let v = &jm * DVector::from_column_slice(&qd[..n]);
            (
                Vector3::new(v[0], v[1], v[2]),
                Vector3::new(v[3], v[4], v[5]),
            )
        };
        let executed = twist(&s.qdot_rad_s).0;
        let dirs = self.directions(s);
        let (axes_linear, axes_angular) = match &dirs {
            Some((cols, _, _)) => {
                let (l0, a0) = twist(&cols[0]);
                let (l1, a1) = twist(&cols[1]);
                (Some([l0, l1]), Some([a0, a1]))
            }
            None => (None, None),
        };
        let twists = scene::ToolTwists {
            tool: tool.translation.vector,
            axes_linear,
            axes_angular,
            executed_linear: executed,
        };
        out.push(VizMessage {
            topic: VizTopic::Map,
            t_ns: t,
            data: encode(VizTopic::Map, &scene::map_entities(&twists, &frame, t))?,
        });
        self.push_world_if_due(&frame, t, out)?;
        let row = self.tick_view(s, &twists, dirs, clearance);
        out.push(VizMessage {
            topic: VizTopic::Tick,
            t_ns: t,
            data: serde_json::to_vec(&row).map_err(|e| VizError::Encode {
                topic: VizTopic::Tick.topic(),
                reason: e.to_string(),
            })?,
        });
        Ok(())
    }

    /// The collision model at `s`: the gripper's links hung from the chain's tip in `tf`,
    /// the arm's capsules whose clearance step changed (all of them now and then), and the
    /// closest pair; nothing if the clearances could not be computed.
    fn collision_update(
        &mut self,
        cm: &'static CollisionModel,
        chain: &Chain,
        s: &RobotState,
        tf: &mut foxglove::messages::FrameTransforms,
    ) -> Result<CollisionView, VizError> {
        let n = chain.n_joints();
        let t = s.t_ns;
        // The gripper joint from the state's gripper, as the safety filter takes it.
        let (lo, hi) = cm.gripper_range();
        // The arm's joints (six on a Gen3 lite, seven on a Gen3), then the gripper's.
        let mut q = [0.0; MAX_ARM_JOINTS + 1];
        let nq = n.min(MAX_ARM_JOINTS);
        q[..nq].copy_from_slice(&s.q()[..nq]);
        q[nq] = if s.gripper.is_finite() {
            hi - s.gripper.clamp(0.0, 1.0) * (hi - lo)
        } else {
            cm.gripper_default_rad()
        };
        if n > MAX_ARM_JOINTS
            || cm
                .clearance(&q[..=nq], &self.scene, &mut self.clearance)
                .is_err()
        {
            return Ok((None, None));
        }
        // The collision model's links the chain does not have (the gripper's), hung
        // from the chain's tip link.
        for &link in cm.links() {
            if chain.link_id(link.name()).is_none() {
                let rel = scene::from_tip(chain, s.q(), self.clearance.link_pose(link)).map_err(
                    |source| VizError::Kinematics {
                        what: "forward kinematics",
                        source,
                    },
                )?;
                tf.transforms
                    .push(scene::transform(t, chain.tip(), link.name(), &rel));
            }
        }
        let full = due(self.last_arm_ns, t);
        let steps: Vec<u8> = self
            .refs
            .iter()
            .map(|r| scene::clearance_step(scene::capsule_clearance(&self.clearance, *r)))
            .collect();
        let send: Vec<bool> = steps
            .iter()
            .zip(&self.steps)
            .map(|(now, last)| full || *last != Some(*now))
            .collect();
        let mut arm = None;
        if send.iter().any(|b| *b) {
            arm = Some(scene::arm_entities(
                cm,
                &self.clearance,
                |i| send.get(i).copied().unwrap_or(false),
                t,
            ));
            self.steps = steps.into_iter().map(Some).collect();
        }
        if full {
            self.last_arm_ns = Some(t);
        }
        let clearance = self
            .clearance
            .closest()
            .map(|c| (c.distance_m, self.pair_name(&c.pair)));
        Ok((clearance, arm))
    }

    /// A pair's short name: `link-link`, `link-table` or `link-<box name>`.
    fn pair_name(&self, pair: &kinematics::collision::PairId) -> String {
        match pair.b {
            kinematics::collision::Target::Capsule(b) => {
                format!("{}-{}", pair.a.link.short_name(), b.link.short_name())
            }
            kinematics::collision::Target::Table => {
                format!("{}-table", pair.a.link.short_name())
            }
            kinematics::collision::Target::Box(k) => format!(
                "{}-{}",
                pair.a.link.short_name(),
                self.boxes
                    .get(usize::from(k))
                    .map_or_else(|| format!("box{k}"), |b| b.0.clone())
            ),
        }
    }

    /// The world (table, boxes, workspace) when it is due.
    fn push_world_if_due(
        &mut self,
        frame: &str,
        t: u64,
        out: &mut Vec<VizMessage>,
    ) -> Result<(), VizError> {
        if due(self.last_world_ns, t) {
            let world = scene::world_entities(
                self.scene.table_z_m(),
                &self.boxes,
                self.workspace,
                frame,
                t,
            );
            out.push(VizMessage {
                topic: VizTopic::World,
                t_ns: t,
                data: encode(VizTopic::World, &world)?,
            });
            self.last_world_ns = Some(t);
        }
        Ok(())
    }

    /// The tick's row: the tool's motion, the map's axes, the clearance and the last safe
    /// command's rules and latency.
    fn tick_view(
        &self,
        s: &RobotState,
        twists: &scene::ToolTwists,
        dirs: Option<([[f64; MAX_JOINTS]; 2], u32, Option<String>)>,
        clearance: Option<(f64, String)>,
    ) -> TickView {
        let arr = |v: &Vector3<f64>| [v.x, v.y, v.z];
        let (axes_linear, axes_angular) = (twists.axes_linear, twists.axes_angular);
        let executed = twists.executed_linear;
        let safe = self.last_safe;
        TickView {
            tick: s.tick,
            tool_m: arr(&twists.tool),
            tool_velocity_m_s: arr(&executed),
            tool_speed_m_s: executed.norm(),
            axis1_m_s: axes_linear.map(|a| arr(&a[0])),
            axis2_m_s: axes_linear.map(|a| arr(&a[1])),
            axis1_rad_s: axes_angular.map(|a| arr(&a[0])),
            axis2_rad_s: axes_angular.map(|a| arr(&a[1])),
            mapper_id: dirs.as_ref().map(|d| d.1),
            mode: dirs.and_then(|d| d.2),
            clearance_m: clearance.as_ref().map(|c| c.0),
            closest_pair: clearance.map(|c| c.1),
            command_tick: safe.map(|c| c.tick),
            latency_ms: safe.map(|c| c.t_ns.saturating_sub(c.state_t_ns) as f64 / 1e6),
            rule_bits: safe.map_or(0, |c| c.flags),
            rules: safe.map_or_else(Vec::new, |c| rule_names(c.flags)),
        }
    }
}

/// The collision model's part of a state's messages: the closest pair (distance, name) and
/// the arm's capsules to send, if any.
type CollisionView = (
    Option<(f64, String)>,
    Option<foxglove::messages::SceneUpdate>,
);

/// The names of the safety rules in `bits` ([`ipc_types::safe_flags::NAMES`]).
pub fn rule_names(bits: u32) -> Vec<String> {
    safe_flags::NAMES
        .iter()
        .enumerate()
        .filter(|(i, _)| bits & (1 << i) != 0)
        .map(|(_, n)| (*n).to_owned())
        .collect()
}

#[cfg(test)]
mod tests;
