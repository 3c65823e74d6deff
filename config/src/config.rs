//! The graph configuration: one TOML file, every key optional, every default written out in
//! `examples/graph.toml`. Unknown keys are errors that name the key, so a typo never silently
//! falls back to a default.
//!
//! `[graph] robot` names the robot profile ([`kinematics::RobotProfile::by_name`]); the keys
//! that depend on the arm (speed and acceleration limits, tick rate, the mock's gripper lag)
//! default to that profile's values ([`GraphConfig::for_robot`]), so another arm needs only
//! its name here.

use std::path::{Path, PathBuf};

use hw_bridge::kortex::KortexConfig;
use hw_bridge::mock::MockConfig;
use kinematics::RobotProfile;
use safety::SafetyConfig;
use serde::{Deserialize, Serialize};

/// The highest `[graph] rate_hz` (Hz): the Gen3 lite's low-level servo rate.
pub const MAX_RATE_HZ: f64 = 1000.0;

/// The longest wait a key in seconds may ask for (`[graph] start_timeout_s`, `[supervisor]
/// stable_after_s`, `swap_timeout_s`): an hour. A longer one is a slip of units (ms written
/// for s) and, far enough, a duration the clock cannot hold.
pub const MAX_WAIT_S: f64 = 3600.0;

/// The whole graph configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraphConfig {
    /// `[graph]`: graph-wide settings.
    pub graph: GraphSection,
    /// `[joystick]`: the input source.
    pub joystick: JoystickConfig,
    /// `[mapper]`: the model served.
    pub mapper: MapperConfig,
    /// `[safety]`: the safety filter.
    pub safety: SafetyConfig,
    /// `[bridge]`: the robot and the clock.
    pub bridge: BridgeConfig,
    /// `[supervisor]`: what `scl up` does when a process dies, and live swaps.
    pub supervisor: SupervisorConfig,
    /// `[faults]`: fault injection for tests and drills; all off by default.
    pub faults: FaultConfig,
    /// `[network]`: the Zenoh gateway to other machines; off by default.
    pub network: crate::NetworkConfig,
}

impl Default for GraphConfig {
    /// [`GraphConfig::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

/// `[faults]`: make a process misbehave on purpose, to see the stack stop the arm. 0 is off.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct FaultConfig {
    /// The mapper publishes a NaN velocity for this one tick.
    pub mapper_nan_at_tick: u64,
    /// The joystick stops publishing samples after this many ticks (the process lives on).
    pub joystick_silent_after_ticks: u64,
    /// The joystick publishes NaN axes for [`NAN_INPUT_TICKS`] ticks from this one
    /// (non-finite operator input; more than one, so the mapper sees it whichever sample it
    /// takes).
    pub joystick_nan_at_tick: u64,
    /// The joystick publishes [`OUT_OF_RANGE_AXES`], far outside the stick's disc, for
    /// [`NAN_INPUT_TICKS`] ticks from this one (a broken device's reading; the mapper clamps
    /// every action to the disc).
    pub joystick_out_of_range_at_tick: u64,
    /// The bridge stops publishing robot states after this many ticks (its clock goes on).
    pub bridge_states_stop_after_ticks: u64,
    /// Safety stalls for 1.2 periods before it filters this one tick's command, as if the
    /// machine did not run it: the command reaches the bridge after the next tick began,
    /// which counts the miss as held up (`NodeStatus::held_up`).
    pub safety_stall_at_tick: u64,
}

/// How many ticks `[faults] joystick_nan_at_tick` and `joystick_out_of_range_at_tick` last.
pub const NAN_INPUT_TICKS: u64 = 4;

/// The axes `[faults] joystick_out_of_range_at_tick` sends: finite, 50 times the disc's radius.
pub const OUT_OF_RANGE_AXES: [f32; 2] = [40.0, -30.0];

/// What the supervisor does when a process exits on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// Stop the whole graph (bridge first) and exit non-zero, naming the process.
    Never,
    /// Restart it after a crash or a non-zero exit, with exponential backoff; a clean exit
    /// stops the graph.
    OnFailure,
    /// Restart it whenever it exits, with exponential backoff.
    Always,
}

/// `[supervisor.restart]`: one policy per process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RestartPolicies {
    /// The joystick process.
    pub joystick: RestartPolicy,
    /// Mapper processes.
    pub mapper: RestartPolicy,
    /// The safety process.
    pub safety: RestartPolicy,
    /// The bridge (a restarted bridge resumes the tick count and starts from a stop).
    pub bridge: RestartPolicy,
    /// The network gateway (`[network] enabled`; a restarted one makes a remote operator
    /// join anew: a new session, then neutral input).
    pub gateway: RestartPolicy,
}

impl Default for RestartPolicies {
    fn default() -> Self {
        Self {
            joystick: RestartPolicy::Never,
            mapper: RestartPolicy::Never,
            safety: RestartPolicy::Never,
            bridge: RestartPolicy::Never,
            gateway: RestartPolicy::Never,
        }
    }
}

impl RestartPolicies {
    /// The policy of a role.
    pub fn of(&self, role: ipc_types::NodeRole) -> RestartPolicy {
        match role {
            ipc_types::NodeRole::Joystick => self.joystick,
            ipc_types::NodeRole::Mapper => self.mapper,
            ipc_types::NodeRole::Safety => self.safety,
            ipc_types::NodeRole::Bridge => self.bridge,
            ipc_types::NodeRole::Gateway => self.gateway,
            // A recorder is not restarted (its file is not reopened): if it dies, the graph
            // stops, so no run goes unrecorded.
            ipc_types::NodeRole::Recorder => RestartPolicy::Never,
        }
    }
}

/// `[supervisor]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SupervisorConfig {
    /// First restart delay (ms); doubles with each consecutive failure.
    pub backoff_initial_ms: u64,
    /// Longest restart delay (ms).
    pub backoff_max_ms: u64,
    /// A process that ran this long before failing starts its backoff afresh (s, in `(0,
    /// MAX_WAIT_S]`).
    pub stable_after_s: f64,
    /// A new mapper must produce valid commands for this many consecutive ticks before
    /// safety switches to it.
    pub swap_valid_ticks: u32,
    /// A swap that has not switched over by then is refused and undone (s, in `(0,
    /// MAX_WAIT_S]`).
    pub swap_timeout_s: f64,
    /// `[supervisor.restart]`: restart policy per process.
    pub restart: RestartPolicies,
}

impl Default for SupervisorConfig {
    fn default() -> Self {
        Self {
            backoff_initial_ms: 100,
            backoff_max_ms: 5000,
            stable_after_s: 10.0,
            swap_valid_ticks: 10,
            swap_timeout_s: 10.0,
            restart: RestartPolicies::default(),
        }
    }
}

/// `[graph]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraphSection {
    /// Service-name prefix; `--prefix` and `SCL_PREFIX` override it.
    pub prefix: String,
    /// The robot profile the graph drives ([`RobotProfile::by_name`]): its joint limits,
    /// kinematics, named poses and rate; the arm-dependent keys default to its values.
    pub robot: String,
    /// How long `scl up` waits for each child to report ready (s, in `(0, MAX_WAIT_S]`).
    pub start_timeout_s: f64,
    /// The control-path processes (bridge, safety, mappers, joystick) ask for SCHED_FIFO and
    /// mlockall once initialised; each says in one line what it was refused.
    pub realtime: bool,
    /// SCHED_FIFO priority of the bridge; safety, mappers and the joystick take the next
    /// three below it, in the order the data flows back from the clock.
    pub rt_priority: i32,
    /// With `realtime`: the control-path processes ask for SCHED_FIFO (bridge at
    /// `rt_priority`, the others below it). Off, they keep the normal scheduler (to measure
    /// the other settings alone).
    pub rt_fifo: bool,
    /// With `realtime`: the control-path processes lock their memory (`mlockall`).
    pub rt_mlock: bool,
    /// CPU the control-path processes are pinned to when real-time is on (`-1`: not pinned;
    /// below -1 is refused).
    pub rt_cpu: i32,
    /// With `realtime`: `scl up` holds `/dev/cpu_dma_latency` at this many µs while the graph
    /// runs (the PM QoS request cyclictest makes: idle CPUs stay out of deep sleep states
    /// between ticks); `-1`: no request (below -1 is refused).
    pub rt_cpu_dma_latency_us: i32,
    /// The mapper wakes this long (µs) before each expected robot state and evaluates its map
    /// once without changing it (`MapperStep::warm`), so the tick's own evaluation finds the
    /// map's weights and code in cache; 0 (default): off. At most half a period. Measured in
    /// docs/benchmarks.md ("Warming the map before the tick").
    pub rt_prewarm_us: u32,
    /// The graph's tick rate (Hz, at most 1000): the bridge's clock, the mock arm, the scripted
    /// joystick, and everything tied to the period (the command deadline, the acceleration per
    /// tick, staleness in ticks, the heartbeat cadence). Default: the robot profile's control
    /// rate (the Gen3 lite's high-level API runs at 40 Hz). `[bridge] rate_hz` is its
    /// deprecated alias.
    pub rate_hz: f64,
    /// Transport of the data-plane topics: `iceoryx2` (the product) or `uds` (Unix-domain
    /// datagram sockets, for latency comparisons; no single-publisher guarantee).
    pub transport: ipc_types::Transport,
    /// With `realtime`: one CPU per control-path process, in the order bridge, safety,
    /// mappers, joystick (`[]`: `rt_cpu` for all, or no pinning; see `rt_auto_pin`).
    /// Exclusive with `rt_cpu`.
    pub rt_cpus: Vec<i32>,
    /// With `realtime`, a polling `wait` and neither `rt_cpus` nor `rt_cpu`: pin the control
    /// path automatically ([`crate::placement::MachineCpus::auto_cpus`]); `false`: leave it
    /// unpinned (`scl bench --rt-only` measures a setting without pinning so).
    pub rt_auto_pin: bool,
    /// How the mapper, safety and the bridge wait for their input: `event` (sleep until the
    /// publisher's notification), `predictive` (sleep on the clock until shortly before the
    /// input is due, learned from the messages' stamps, then poll for a bounded time, then
    /// the event) or `spin` (poll always). See [`crate::placement`] for where polling is
    /// allowed with SCHED_FIFO.
    pub wait: WaitStrategy,
}

/// `[graph] wait`: how a control-path process waits for its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WaitStrategy {
    /// Sleep until the publisher's notification (one wake-up per hop).
    #[default]
    Event,
    /// Sleep on the absolute clock until shortly before the input is due, then poll the
    /// subscriber for a bounded time, then fall back to the event.
    Predictive,
    /// Poll the subscriber always (a CPU per process).
    Spin,
}

impl WaitStrategy {
    /// The names the key takes.
    pub const NAMES: [&'static str; 3] = ["event", "predictive", "spin"];

    /// Whether the process polls its subscriber (`predictive` or `spin`).
    pub fn polls(self) -> bool {
        self != Self::Event
    }

    /// The key's value for this strategy.
    pub fn name(self) -> &'static str {
        match self {
            Self::Event => "event",
            Self::Predictive => "predictive",
            Self::Spin => "spin",
        }
    }
}

impl std::fmt::Display for WaitStrategy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for WaitStrategy {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "event" => Ok(Self::Event),
            "predictive" => Ok(Self::Predictive),
            "spin" => Ok(Self::Spin),
            other => Err(format!(
                "`{other}` is not a wait strategy; use one of {}",
                Self::NAMES.join(", ")
            )),
        }
    }
}

/// A process of the control path, for its real-time priority.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RtRole {
    /// The bridge: `rt_priority`.
    Bridge,
    /// Safety: one below.
    Safety,
    /// Mappers: two below.
    Mapper,
    /// The joystick: three below.
    Joystick,
    /// The supervisor (`scl up`), which reaps dead children and holds the arm: four below.
    Supervisor,
}

impl GraphSection {
    /// The robot profile named by `robot`; the error names the key and the known robots.
    pub fn profile(&self) -> Result<&'static RobotProfile, ConfigError> {
        RobotProfile::by_name(&self.robot).map_err(|e| ConfigError::Value {
            key: "graph.robot".into(),
            reason: e.to_string(),
        })
    }

    /// The tick period (s): `1 / rate_hz`.
    pub fn period_s(&self) -> f64 {
        1.0 / self.rate_hz
    }

    /// The tick period (ns), as the bridge's clock counts it.
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz) as u64
    }

    /// The SCHED_FIFO priority of `role`, or `None` when real-time is off.
    pub fn rt_priority_of(&self, role: RtRole) -> Option<i32> {
        let below = match role {
            RtRole::Bridge => 0,
            RtRole::Safety => 1,
            RtRole::Mapper => 2,
            RtRole::Joystick => 3,
            RtRole::Supervisor => 4,
        };
        self.realtime.then_some(self.rt_priority - below)
    }
}

impl Default for GraphSection {
    fn default() -> Self {
        Self {
            prefix: ipc_types::prefix::DEFAULT_PREFIX.to_owned(),
            robot: RobotProfile::default_name().to_owned(),
            start_timeout_s: 10.0,
            realtime: true,
            rt_priority: 80,
            rt_fifo: true,
            rt_mlock: true,
            rt_cpu: -1,
            rt_cpu_dma_latency_us: -1,
            rt_prewarm_us: 0,
            rate_hz: RobotProfile::default_robot().control_rate_hz(),
            transport: ipc_types::Transport::Iceoryx2,
            rt_cpus: Vec::new(),
            rt_auto_pin: true,
            wait: WaitStrategy::Event,
        }
    }
}

/// `[joystick]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JoystickConfig {
    /// Input source: `script`, `evdev` (a joystick or gamepad), `keyboard` (a person at the
    /// terminal), `replay` (a recorded input file) or `external` (no joystick process: the
    /// samples come from whoever publishes them, e.g. a Python agent).
    pub source: String,
    /// Script: `circle` (a slow circle), `step` (+x, +y, -x, -y holds with rests) or
    /// `constant` (`constant_axes` held).
    pub script: String,
    /// Circle: period of one turn (s).
    pub circle_period_s: f64,
    /// Script amplitude, `|a|` at full deflection, in `(0, 1]`.
    pub amplitude: f64,
    /// Step: how long each direction is held (s).
    pub step_hold_s: f64,
    /// Step: rest at zero between holds (s).
    pub step_rest_s: f64,
    /// Constant: the axes held (scaled by `amplitude`): a point of the stick's disc, finite
    /// with `|a| <= 1` (the mapper clamps every action radially to that disc, so a point
    /// outside it would not be held as written).
    pub constant_axes: [f64; 2],
    /// evdev: the device: a path (`/dev/input/event5`), part of its name (`xbox`), or empty
    /// for the first joystick or gamepad that has the mapping's axes.
    pub device: String,
    /// evdev: the mapping of axes and buttons: `xbox` or `generic` (built in) or a mapping
    /// file (TOML; a relative path is relative to the config file's directory).
    pub mapping: String,
    /// evdev: how often an unplugged or missing device is looked for again (ms).
    pub reconnect_interval_ms: u64,
    /// Keyboard: time from rest to full deflection (s).
    pub keyboard_ramp_s: f64,
    /// Keyboard: a key counts as held this long after its first press (ms); terminals
    /// report auto-repeats but rarely releases.
    pub keyboard_first_hold_ms: u64,
    /// Keyboard: ... and this long after each auto-repeat (ms).
    pub keyboard_repeat_hold_ms: u64,
    /// Replay: the recorded input file (CSV `t_s,a0,a1,gripper,buttons`), played with its
    /// original timing from the first robot tick.
    pub replay_file: String,
    /// Any source: also record the published input to this file (same CSV; an existing file
    /// is refused); empty: off.
    pub record_input: String,
    /// With `[graph] wait` = `predictive` or `spin`: the joystick reads its input this long
    /// (µs) before each tick and publishes it then, so the mapper maps a sample about this
    /// old instead of one read right after the previous tick. 0 (default): 1 ms, at most a
    /// quarter of a period. At most half a period. Not used with `event`, nor by a remote
    /// operator (`scl joystick --remote`).
    pub sample_margin_us: u32,
}

impl Default for JoystickConfig {
    fn default() -> Self {
        Self {
            source: "script".into(),
            script: "circle".into(),
            circle_period_s: 8.0,
            amplitude: 1.0,
            step_hold_s: 2.0,
            step_rest_s: 0.5,
            constant_axes: [1.0, 0.0],
            device: String::new(),
            mapping: "xbox".into(),
            reconnect_interval_ms: 500,
            keyboard_ramp_s: 0.5,
            keyboard_first_hold_ms: 600,
            keyboard_repeat_hold_ms: 150,
            replay_file: String::new(),
            record_input: String::new(),
            sample_margin_us: 0,
        }
    }
}

/// `[mapper]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapperConfig {
    /// Model file, `bundled` for the model built into `scl`, or `modeswitch` (optionally
    /// `modeswitch:key=value,...`) for the Cartesian mode-switching map. A relative path is
    /// taken relative to the config file's directory.
    pub model: String,
    /// Id of the mapper process started by `scl up`; safety forwards this id.
    pub id: u32,
}

impl Default for MapperConfig {
    fn default() -> Self {
        Self {
            model: mapper::model::BUNDLED_NAME.into(),
            id: 1,
        }
    }
}

/// `[bridge]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    /// Robot backend: `mock` (the simulation of the graph's robot profile) or `kortex` (the
    /// arm over the Kortex API, settings in `[bridge.kortex]`).
    pub robot: String,
    /// Deprecated alias of `[graph] rate_hz`, still read (with a warning) so older files and
    /// recordings keep working; a file giving both with different values is refused. Parsing
    /// moves it to `[graph] rate_hz`, so it is always `None` in a parsed configuration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rate_hz: Option<f64>,
    /// How far into the period the bridge waits for the tick's command, as a fraction of the
    /// period; a command later than this is a miss.
    pub command_deadline: f64,
    /// Acceleration limits for the bridge's controlled stop (rad/s²). Default: the robot
    /// profile's teleoperation accelerations.
    pub stop_acceleration_rad_s2: Vec<f64>,
    /// `[bridge.mock]`: the mock arm.
    pub mock: MockConfig,
    /// `[bridge.kortex]`: the Kortex client (address, port, timeouts, credentials file).
    pub kortex: KortexConfig,
}

impl Default for BridgeConfig {
    /// [`BridgeConfig::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

impl BridgeConfig {
    /// The defaults for `robot`: the mock backend at the robot's control rate, stopping within
    /// its accelerations.
    pub fn for_robot(robot: &RobotProfile) -> Self {
        Self {
            robot: "mock".into(),
            rate_hz: None,
            command_deadline: 0.6,
            stop_acceleration_rad_s2: robot.limits().max_acceleration_rad_s2.clone(),
            mock: MockConfig::for_robot(robot),
            kortex: KortexConfig::default(),
        }
    }
}

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file is not valid TOML for the graph.
    #[error("config {path}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (names the key and line).
        reason: String,
    },
    /// A value is out of range.
    #[error("config: {key}: {reason}")]
    Value {
        /// The dotted key.
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// A value of a configuration file is out of range ([`ConfigError::in_file`]).
    #[error("config {}: {key}: {reason}", path.display())]
    FileValue {
        /// The file.
        path: PathBuf,
        /// The dotted key.
        key: String,
        /// What is wrong.
        reason: String,
    },
}

impl ConfigError {
    /// The error of a configuration read from `path` (if it came from a file): a value out
    /// of range names the file too; every other error already does or is not the file's.
    pub fn in_file(self, path: Option<&Path>) -> Self {
        match (self, path) {
            (Self::Value { key, reason }, Some(path)) => Self::FileValue {
                path: path.to_owned(),
                key,
                reason,
            },
            (e, _) => e,
        }
    }
}

/// The evdev mappings built into the joystick process (`scl_joystick::mapping::BUILTIN`
/// has their text; a test there keeps the two lists equal).
pub const BUILTIN_MAPPINGS: [&str; 2] = ["xbox", "generic"];

/// Resolves `[joystick]`'s file paths (a mapping file, the replay and record files) against
/// the config file's directory; built-in mapping names stay as they are.
pub fn resolve_joystick_paths(cfg: &mut JoystickConfig, dir: &Path) {
    let builtin_mapping = BUILTIN_MAPPINGS.contains(&cfg.mapping.as_str());
    let fix = |s: &mut String| {
        let p = Path::new(s.as_str());
        if !s.is_empty() && p.is_relative() {
            *s = dir.join(p).display().to_string();
        }
    };
    if !builtin_mapping {
        fix(&mut cfg.mapping);
    }
    fix(&mut cfg.replay_file);
    fix(&mut cfg.record_input);
}

/// Sets every key of `over` in `base`, descending into tables present in both.
fn merge_tables(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

impl GraphConfig {
    /// The defaults for the robot profile `robot` (`[graph] robot` names it): its speed and
    /// acceleration limits in `[safety]`, its control rate and accelerations in `[bridge]`,
    /// its gripper lag in `[bridge.mock]`; everything else as for any arm.
    pub fn for_robot(robot: &RobotProfile) -> Self {
        Self {
            graph: GraphSection {
                robot: robot.name().to_owned(),
                rate_hz: robot.control_rate_hz(),
                ..GraphSection::default()
            },
            joystick: JoystickConfig::default(),
            mapper: MapperConfig::default(),
            safety: SafetyConfig {
                max_state_age_ms: SafetyConfig::state_age_ms_for(1.0 / robot.control_rate_hz()),
                ..SafetyConfig::for_robot(robot)
            },
            bridge: BridgeConfig::for_robot(robot),
            supervisor: SupervisorConfig::default(),
            faults: FaultConfig::default(),
            network: crate::NetworkConfig::default(),
        }
    }

    /// The robot profile of `[graph] robot`.
    pub fn profile(&self) -> Result<&'static RobotProfile, ConfigError> {
        self.graph.profile()
    }

    /// Parses a graph TOML: keys it leaves out take the defaults of the robot it names
    /// ([`GraphConfig::for_robot`]); `path` names the file in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let parse_err = |reason: String| ConfigError::Parse {
            path: path.to_owned(),
            reason,
        };
        // Typed first, so errors name the key and its line.
        let cfg: Self = toml::from_str(text).map_err(|e| parse_err(e.to_string()))?;
        let Ok(robot) = cfg.profile() else {
            // An unknown robot: `validate` names it.
            return Ok(cfg);
        };
        if robot.name() == RobotProfile::default_name() {
            return cfg.settle_rate(text, path);
        }
        Self::parse_for(text, path, robot)
    }

    /// Settles the rate of a parsed file: moves the deprecated `[bridge] rate_hz` to
    /// `[graph] rate_hz` (with a warning; both given with different values is an error naming
    /// the file and both keys), and gives `[safety] max_state_age_ms`, if the file leaves it
    /// out, its default at that rate.
    fn settle_rate(mut self, text: &str, path: &Path) -> Result<Self, ConfigError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let given =
            |section: &str, key: &str| table.get(section).and_then(|g| g.get(key)).is_some();
        if let Some(old) = self.bridge.rate_hz.take() {
            if given("graph", "rate_hz") && self.graph.rate_hz != old {
                return Err(ConfigError::Parse {
                    path: path.to_owned(),
                    reason: format!(
                        "graph.rate_hz = {} and the deprecated bridge.rate_hz = {old} disagree; \
                         keep graph.rate_hz only",
                        self.graph.rate_hz
                    ),
                });
            }
            tracing::warn!(
                file = %path.display(),
                "bridge.rate_hz is deprecated: it is read as graph.rate_hz = {old}; move it to [graph]"
            );
            self.graph.rate_hz = old;
        }
        if !given("safety", "max_state_age_ms") {
            self.safety.max_state_age_ms = SafetyConfig::state_age_ms_for(self.period_s());
        }
        Ok(self)
    }

    /// Sets the graph's rate, and with it the period-tied defaults still at their value for
    /// the old rate (`[safety] max_state_age_ms`); explicitly set values stay and
    /// [`GraphConfig::validate`] checks them against the new period.
    pub fn set_rate_hz(&mut self, rate_hz: f64) {
        if self.safety.max_state_age_ms == SafetyConfig::state_age_ms_for(self.period_s()) {
            self.safety.max_state_age_ms = SafetyConfig::state_age_ms_for(1.0 / rate_hz);
        }
        self.graph.rate_hz = rate_hz;
    }

    /// Parses a graph TOML whose left-out keys take `robot`'s defaults.
    fn parse_for(text: &str, path: &Path, robot: &RobotProfile) -> Result<Self, ConfigError> {
        let parse_err = |reason: String| ConfigError::Parse {
            path: path.to_owned(),
            reason,
        };
        let over: toml::Table = toml::from_str(text).map_err(|e| parse_err(e.to_string()))?;
        let mut table = toml::Table::try_from(Self::for_robot(robot))
            .map_err(|e| parse_err(format!("the defaults of robot {}: {e}", robot.name())))?;
        merge_tables(&mut table, over);
        let cfg: Self = table.try_into().map_err(|e| parse_err(e.to_string()))?;
        cfg.settle_rate(text, path)
    }

    /// Reads `path`, or the defaults if `None`. Relative model paths are resolved against
    /// the file's directory.
    pub fn load(path: Option<&Path>) -> Result<Self, ConfigError> {
        let Some(path) = path else {
            return Ok(Self::default());
        };
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.to_owned(),
            source,
        })?;
        let mut cfg = Self::parse(&text, path)?;
        if let Some(dir) = path.parent() {
            resolve_joystick_paths(&mut cfg.joystick, dir);
        }
        if !mapper::model::is_builtin(&cfg.mapper.model) {
            let p = Path::new(&cfg.mapper.model);
            if p.is_relative()
                && let Some(dir) = path.parent()
            {
                cfg.mapper.model = dir.join(p).display().to_string();
            }
        }
        if let Some(dir) = path.parent() {
            cfg.network.resolve_paths(dir);
        }
        let creds = &mut cfg.bridge.kortex.credentials_file;
        if !creds.is_empty() {
            let p = Path::new(creds.as_str());
            if p.is_relative()
                && let Some(dir) = path.parent()
            {
                *creds = dir.join(p).display().to_string();
            }
        }
        Ok(cfg)
    }

    /// [`GraphConfig::validate`] of the configuration read from `path` (`None`: the
    /// defaults): an error names the file as well as the key.
    pub fn validate_file(&self, path: Option<&Path>) -> Result<(), ConfigError> {
        self.validate().map_err(|e| e.in_file(path))
    }

    /// Checks every value that no single crate checks; the crates check their own tables
    /// when they build from them. `[joystick]`'s sources and their files are checked by
    /// `scl_joystick::validate` (the supervisor and every process call both).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: key.to_owned(),
            reason,
        };
        ipc_types::Prefix::new(&self.graph.prefix)
            .map_err(|e| err("graph.prefix", e.to_string()))?;
        let robot = self.profile()?;
        self.validate_graph_timing()?;
        let b = &self.bridge;
        if b.robot != "mock" && b.robot != "kortex" {
            return Err(err(
                "bridge.robot",
                format!("`{}` is not a robot; use `mock` or `kortex`", b.robot),
            ));
        }
        self.validate_rate()?;
        self.validate_bridge(robot)?;
        self.safety
            .validate_for_robot(robot)
            .and_then(|()| self.safety.validate_ages(self.period_s()))
            .map_err(|e| err(&format!("safety.{}", e.key), e.reason))?;
        if self.mapper.id == 0 {
            return Err(err("mapper.id", "must be at least 1".into()));
        }
        self.validate_supervisor()?;
        self.network.validate()
    }

    /// `[graph]`'s start timeout, real-time CPUs and priority.
    fn validate_graph_timing(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: key.to_owned(),
            reason,
        };
        let t = self.graph.start_timeout_s;
        if !(t.is_finite() && t > 0.0 && t <= MAX_WAIT_S) {
            return Err(err(
                "graph.start_timeout_s",
                format!("is {t}; it must be a finite number of seconds in (0, {MAX_WAIT_S}]"),
            ));
        }
        for (key, v) in [
            ("graph.rt_cpu", self.graph.rt_cpu),
            (
                "graph.rt_cpu_dma_latency_us",
                self.graph.rt_cpu_dma_latency_us,
            ),
        ] {
            if v < -1 {
                return Err(err(
                    key,
                    format!("is {v}; it must be -1 (off) or 0 or more"),
                ));
            }
        }
        crate::placement::check_rt_cpus(&self.graph)?;
        if !(5..=99).contains(&self.graph.rt_priority) {
            return Err(err(
                "graph.rt_priority",
                format!(
                    "{} is outside 5..=99 (the four processes after the bridge take the priorities below it)",
                    self.graph.rt_priority
                ),
            ));
        }
        Ok(())
    }

    /// The rate, and the margins that must fit in half a period.
    fn validate_rate(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: key.to_owned(),
            reason,
        };
        let rate = self.graph.rate_hz;
        if !(rate.is_finite() && rate > 0.0 && rate <= MAX_RATE_HZ) {
            return Err(err(
                "graph.rate_hz",
                format!("{rate} is outside (0, {MAX_RATE_HZ}]"),
            ));
        }
        let half_period_us = 0.5e6 / rate;
        if f64::from(self.graph.rt_prewarm_us) > half_period_us {
            return Err(err(
                "graph.rt_prewarm_us",
                format!(
                    "{} µs is more than half a period ({half_period_us:.0} µs at {rate} Hz)",
                    self.graph.rt_prewarm_us
                ),
            ));
        }
        if f64::from(self.joystick.sample_margin_us) > half_period_us {
            return Err(err(
                "joystick.sample_margin_us",
                format!(
                    "{} µs is more than half a period ({half_period_us:.0} µs at {rate} Hz)",
                    self.joystick.sample_margin_us
                ),
            ));
        }
        Ok(())
    }

    /// `[bridge]` (its robot checked before): no deprecated rate, the deadline, the stop
    /// accelerations, the mock arm, the Kortex settings and the transport a real arm needs.
    fn validate_bridge(&self, robot: &RobotProfile) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: key.to_owned(),
            reason,
        };
        let b = &self.bridge;
        if let Some(r) = b.rate_hz {
            // Only a configuration built in code gets here with the alias set.
            return Err(err(
                "bridge.rate_hz",
                format!("{r}: deprecated, set graph.rate_hz instead"),
            ));
        }
        if !(b.command_deadline > 0.0 && b.command_deadline < 1.0) {
            return Err(err(
                "bridge.command_deadline",
                format!(
                    "{} is outside (0, 1): a fraction of the period",
                    b.command_deadline
                ),
            ));
        }
        let n = robot.n_joints();
        if b.stop_acceleration_rad_s2.len() != n
            || b.stop_acceleration_rad_s2
                .iter()
                .any(|a| !(a.is_finite() && *a > 0.0))
        {
            return Err(err(
                "bridge.stop_acceleration_rad_s2",
                format!("needs {n} positive numbers"),
            ));
        }
        hw_bridge::mock::MockArm::for_robot(robot, b.mock.clone())
            .map_err(|e| err(&format!("bridge.mock.{}", e.key), e.reason))?;
        b.kortex
            .validate(self.period_s())
            .map_err(|e| err(&format!("bridge.kortex.{}", e.key), e.reason))?;
        if self.graph.transport == ipc_types::Transport::Uds && b.robot == "kortex" {
            return Err(err(
                "graph.transport",
                "`uds` cannot enforce that safety is the one publisher of the arm's command; \
                 with bridge.robot = \"kortex\" (a real arm) use `iceoryx2` (`uds` is for \
                 latency comparisons on the mock arm)"
                    .into(),
            ));
        }
        Ok(())
    }

    /// `[supervisor]`'s backoff, waits and swap ticks.
    fn validate_supervisor(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: key.to_owned(),
            reason,
        };
        let sv = &self.supervisor;
        if sv.backoff_initial_ms == 0 || sv.backoff_max_ms < sv.backoff_initial_ms {
            return Err(err(
                "supervisor.backoff_max_ms",
                "backoff_initial_ms must be positive and at most backoff_max_ms".into(),
            ));
        }
        for (key, v) in [
            ("supervisor.stable_after_s", sv.stable_after_s),
            ("supervisor.swap_timeout_s", sv.swap_timeout_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= MAX_WAIT_S) {
                return Err(err(
                    key,
                    format!("is {v}; it must be a finite number of seconds in (0, {MAX_WAIT_S}]"),
                ));
            }
        }
        if sv.swap_valid_ticks == 0 {
            return Err(err(
                "supervisor.swap_valid_ticks",
                "must be at least 1".into(),
            ));
        }
        Ok(())
    }

    /// The tick period (s).
    pub fn period_s(&self) -> f64 {
        self.graph.period_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn example_file_is_the_defaults() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/graph.toml"
        ));
        let cfg = GraphConfig::load(Some(path)).unwrap();
        assert_eq!(cfg, GraphConfig::default());
        cfg.validate().unwrap();
    }

    #[test]
    fn the_robot_is_a_profile_and_its_defaults_follow_it() {
        let cfg = GraphConfig::default();
        assert_eq!(cfg.graph.robot, "gen3_lite");
        let robot = cfg.profile().unwrap();
        assert_eq!(
            cfg.safety.max_velocity_rad_s,
            robot.limits().max_velocity_rad_s
        );
        assert_eq!(cfg.graph.rate_hz, robot.control_rate_hz());
        // Another arm: the keys a file leaves out take its defaults; the keys it sets win.
        let planar = RobotProfile::new(&kinematics::ProfileSpec::planar5()).unwrap();
        let text = "[graph]\nrobot = \"planar5\"\n[safety]\nspeed_override = 0.5\n\
                    [bridge]\nrate_hz = 20.0\n";
        let cfg = GraphConfig::parse_for(text, Path::new("g.toml"), &planar).unwrap();
        assert_eq!(cfg.graph.robot, "planar5");
        assert_eq!(cfg.safety.max_velocity_rad_s, [1.0; 5]);
        assert_eq!(cfg.safety.speed_override, 0.5);
        assert_eq!(cfg.bridge.stop_acceleration_rad_s2, [2.0; 5]);
        // The deprecated `[bridge] rate_hz` lands in `[graph] rate_hz`.
        assert_eq!((cfg.graph.rate_hz, cfg.bridge.rate_hz), (20.0, None));
        assert_eq!(cfg.bridge.mock.gripper_time_constant_s, 0.1);
        assert_eq!(cfg.joystick, JoystickConfig::default());
        // An unknown robot is refused by name, with the known ones.
        let cfg: GraphConfig =
            GraphConfig::parse("[graph]\nrobot = \"ur5\"\n", Path::new("g.toml")).unwrap();
        let e = cfg.validate().unwrap_err().to_string();
        assert_eq!(
            e,
            "config: graph.robot: `ur5` is not a known robot; known: gen3_lite, gen3"
        );
    }

    #[test]
    fn the_rate_is_a_graph_setting_with_the_bridge_key_as_its_alias() {
        let p = Path::new("g.toml");
        let cfg = GraphConfig::parse("[graph]\nrate_hz = 1000\n", p).unwrap();
        cfg.validate().unwrap();
        assert_eq!((cfg.period_s(), cfg.graph.period_ns()), (1e-3, 1_000_000));
        // The state age limit left out follows the period; one given stays and is checked.
        assert!((cfg.safety.max_state_age_ms - 0.8).abs() < 1e-12);
        let set = "[graph]\nrate_hz = 1000\n[safety]\nmax_state_age_ms = 20.0\n";
        let e = GraphConfig::parse(set, p).unwrap().validate().unwrap_err();
        assert!(e.to_string().contains("safety.max_state_age_ms"), "{e}");
        let mut cfg = GraphConfig::default();
        cfg.set_rate_hz(500.0);
        cfg.validate().unwrap();
        assert_eq!(
            (cfg.graph.rate_hz, cfg.safety.max_state_age_ms),
            (500.0, 1.6)
        );
        let cfg = GraphConfig::parse("[bridge]\nrate_hz = 500\n", p).unwrap();
        assert_eq!((cfg.graph.rate_hz, cfg.bridge.rate_hz), (500.0, None));
        // A parsed configuration writes only the new key, and reads back the same.
        let text = toml::to_string(&cfg).unwrap();
        assert!(!text.contains("[bridge]\nrate_hz"), "{text}");
        assert_eq!(GraphConfig::parse(&text, p).unwrap(), cfg);
        // Both keys: the same value is fine, different values are refused naming both.
        let both = "[graph]\nrate_hz = 250\n[bridge]\nrate_hz = 250\n";
        assert_eq!(GraphConfig::parse(both, p).unwrap().graph.rate_hz, 250.0);
        let e = GraphConfig::parse("[graph]\nrate_hz = 250\n[bridge]\nrate_hz = 40\n", p)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("g.toml") && e.contains("graph.rate_hz") && e.contains("bridge.rate_hz"),
            "{e}"
        );
        // Set in code, the alias is refused by name.
        let mut cfg = GraphConfig::default();
        cfg.bridge.rate_hz = Some(100.0);
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("bridge.rate_hz"), "{e}");
    }

    /// Every numeric key of the graph's own tables (and the `[safety]` ones it passes on) is
    /// checked for finiteness and range where it is read: each bad value is refused naming
    /// the key and saying what it must be.
    #[test]
    fn out_of_range_and_non_finite_numbers_are_refused_naming_the_key() {
        let cases = [
            (
                "[graph]\nstart_timeout_s = nan",
                "graph.start_timeout_s",
                "finite",
            ),
            (
                "[graph]\nstart_timeout_s = inf",
                "graph.start_timeout_s",
                "finite",
            ),
            (
                "[graph]\nstart_timeout_s = 1e300",
                "graph.start_timeout_s",
                "3600",
            ),
            (
                "[graph]\nstart_timeout_s = 0",
                "graph.start_timeout_s",
                "(0, 3600]",
            ),
            ("[graph]\nrate_hz = nan", "graph.rate_hz", "(0, 1000]"),
            ("[graph]\nrt_cpu = -2", "graph.rt_cpu", "-1 (off)"),
            (
                "[graph]\nrt_cpu_dma_latency_us = -5",
                "graph.rt_cpu_dma_latency_us",
                "-1 (off)",
            ),
            (
                "[bridge]\ncommand_deadline = nan",
                "bridge.command_deadline",
                "(0, 1)",
            ),
            (
                "[supervisor]\nstable_after_s = nan",
                "supervisor.stable_after_s",
                "finite",
            ),
            (
                "[supervisor]\nstable_after_s = 1e300",
                "supervisor.stable_after_s",
                "3600",
            ),
            (
                "[supervisor]\nswap_timeout_s = inf",
                "supervisor.swap_timeout_s",
                "finite",
            ),
            (
                "[supervisor]\nswap_timeout_s = 1e300",
                "supervisor.swap_timeout_s",
                "3600",
            ),
            (
                "[safety.scene]\ntable_z_m = nan",
                "safety.scene.table_z_m",
                "finite",
            ),
            (
                "[safety.workspace]\ntable_z_m = nan",
                "safety.workspace.table_z_m",
                "finite",
            ),
            (
                "[safety]\njoint_margin_rad = nan",
                "safety.joint_margin_rad",
                "finite",
            ),
            (
                "[safety]\nspeed_override = nan",
                "safety.speed_override",
                "finite",
            ),
        ];
        for (text, key, needle) in cases {
            let e = GraphConfig::parse(text, Path::new("g.toml"))
                .unwrap()
                .validate()
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("{key}:")) && e.contains(needle),
                "{text}: {e}"
            );
        }
        // The bounds themselves are fine.
        let ok = "[graph]\nstart_timeout_s = 3600\nrt_cpu = -1\nrt_cpu_dma_latency_us = 0\n\
                  [supervisor]\nstable_after_s = 3600\nswap_timeout_s = 0.5\n";
        GraphConfig::parse(ok, Path::new("g.toml"))
            .unwrap()
            .validate()
            .unwrap();
    }

    #[test]
    fn kortex_example_is_valid_and_points_at_loopback() {
        let path = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/kortex-fake.toml"
        ));
        let cfg = GraphConfig::load(Some(path)).unwrap();
        cfg.validate().unwrap();
        assert_eq!(cfg.bridge.robot, "kortex");
        assert_eq!(
            cfg.bridge.kortex.socket_addr().unwrap(),
            "127.0.0.1:10000".parse().unwrap()
        );
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let dir = std::env::temp_dir().join(format!("scl-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("g.toml");
        std::fs::write(&p, "[safety]\nmax_velocity = 1.0\n").unwrap();
        let e = GraphConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("max_velocity"), "{e}");
        std::fs::write(&p, "[graph]\nrate_hz = 1001\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("graph.rate_hz") && e.contains("1000"), "{e}");
        // Checked as the file's, the error names the file too.
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate_file(Some(&p))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(&format!(
                "config {}: graph.rate_hz: 1001 is outside",
                p.display()
            )),
            "{e}"
        );
        // The pre-warm is at most half a period: 12.5 ms at 40 Hz, 0.5 ms at 1 kHz.
        std::fs::write(&p, "[graph]\nrt_prewarm_us = 12500\n").unwrap();
        GraphConfig::load(Some(&p)).unwrap().validate().unwrap();
        std::fs::write(&p, "[graph]\nrate_hz = 1000\nrt_prewarm_us = 600\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("graph.rt_prewarm_us") && e.contains("500 µs"),
            "{e}"
        );
        // So is the joystick's sampling margin.
        std::fs::write(
            &p,
            "[graph]\nrate_hz = 1000\n[joystick]\nsample_margin_us = 501\n",
        )
        .unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("joystick.sample_margin_us") && e.contains("500 µs"),
            "{e}"
        );
        std::fs::write(&p, "[bridge]\nrate_hz = -4\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("graph.rate_hz"), "{e}");
        std::fs::write(&p, "[safety]\nmax_velocity_rad_s = [1, 1, 1, 1, 1, 0]\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("safety.max_velocity_rad_s"), "{e}");
        std::fs::write(&p, "[bridge.mock]\ninitial_pose = \"up\"\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("bridge.mock.initial_pose"), "{e}");
        std::fs::write(&p, "[bridge]\nrobot = \"ur5\"\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("bridge.robot") && e.contains("kortex"), "{e}");
        std::fs::write(
            &p,
            "[bridge]\nrobot = \"kortex\"\n[bridge.kortex]\naddress = \"127.0.0.1\"\nport = 10123\n\
             credentials_file = \"creds.toml\"\nconnection_timeout_ms = 20\n",
        )
        .unwrap();
        let cfg = GraphConfig::load(Some(&p)).unwrap();
        assert_eq!(cfg.bridge.kortex.port, 10123);
        assert_eq!(
            cfg.bridge.kortex.credentials_file,
            dir.join("creds.toml").display().to_string()
        );
        let e = cfg.validate().unwrap_err().to_string();
        assert!(e.contains("bridge.kortex.connection_timeout_ms"), "{e}");
        // The socket transport cannot keep a second publisher off a real arm.
        std::fs::write(
            &p,
            "[graph]\ntransport = \"uds\"\n[bridge]\nrobot = \"kortex\"\n",
        )
        .unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("graph.transport") && e.contains("bridge.robot = \"kortex\""),
            "{e}"
        );
        std::fs::write(&p, "[graph]\ntransport = \"uds\"\n").unwrap();
        GraphConfig::load(Some(&p)).unwrap().validate().unwrap();
        // Age limits are checked against the period: 20 ms is a whole period at 50 Hz.
        std::fs::write(
            &p,
            "[bridge]\nrate_hz = 50.0\n[safety]\nmax_state_age_ms = 20.0\n",
        )
        .unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("safety.max_state_age_ms"), "{e}");
        std::fs::write(&p, "[safety]\nmax_joystick_age_ms = 1e9\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("safety.max_joystick_age_ms"), "{e}");
        std::fs::write(&p, "[bridge.kortex]\npassword = \"admin\"\n").unwrap();
        let e = GraphConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("unknown field `password`"), "{e}");
        std::fs::write(&p, "[mapper]\nmodel = \"m.safetensors\"\n").unwrap();
        let cfg = GraphConfig::load(Some(&p)).unwrap();
        assert_eq!(
            cfg.mapper.model,
            dir.join("m.safetensors").display().to_string()
        );
        std::fs::write(&p, "[supervisor.restart]\nmapper = \"sometimes\"\n").unwrap();
        let e = GraphConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("sometimes") && e.contains("on-failure"), "{e}");
        std::fs::write(&p, "[supervisor.restart]\nmapper = \"on-failure\"\n").unwrap();
        let cfg = GraphConfig::load(Some(&p)).unwrap();
        assert_eq!(cfg.supervisor.restart.mapper, RestartPolicy::OnFailure);
        std::fs::write(&p, "[graph]\nwait = \"sometimes\"\n").unwrap();
        let e = GraphConfig::load(Some(&p)).unwrap_err().to_string();
        assert!(e.contains("wait") && e.contains("predictive"), "{e}");
        std::fs::write(
            &p,
            "[graph]\nwait = \"predictive\"\nrt_cpus = [0, 1, 0, 1]\n",
        )
        .unwrap();
        let cfg = GraphConfig::load(Some(&p)).unwrap();
        cfg.validate().unwrap();
        assert_eq!(cfg.graph.wait, WaitStrategy::Predictive);
        std::fs::write(&p, "[graph]\nrt_cpus = [0, 1]\n").unwrap();
        let e = GraphConfig::load(Some(&p))
            .unwrap()
            .validate()
            .unwrap_err()
            .to_string();
        assert!(e.contains("graph.rt_cpus"), "{e}");
        std::fs::write(&p, "not toml [").unwrap();
        assert!(matches!(
            GraphConfig::load(Some(&p)),
            Err(ConfigError::Parse { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
