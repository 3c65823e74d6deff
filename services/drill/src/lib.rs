//! `scl drill`: the fault drills, on the lab's own machine and graph configuration. Each
//! drill runs the configured graph (`scl up`, the mock arm unless `--arm`) with a scripted
//! stick that keeps the arm moving and the graph recording itself, injects one fault at a
//! tick while the arm moves, and measures from the recording what the promise of the README
//! and docs/configuration.md is about: ticks to the stop, joint travel and time to rest against
//! the stop distance at the documented deceleration, no joint faster after the fault, motion
//! only after neutral input, missed ticks (and those the machine held up), and shared memory
//! left behind. [`run`] runs every fault `repeat` times; [`render`] prints the table.
#![cfg_attr(test, allow(clippy::unwrap_used))]

pub mod figures;

use std::io::{BufRead as _, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ipc_types::control::estop_action;
use ipc_types::{NodeRole, NodeStatus, Prefix, RobotState, time::now_ns};
use nix::sys::signal::Signal;
use scl_config::{GraphConfig, RestartPolicy};
use serde::Serialize;

use figures::{Figures, Promise, Recorded};

/// Why a drill could not be run (a fault that breaks a promise is a row, not an error).
#[derive(Debug, thiserror::Error)]
pub enum DrillError {
    /// The configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// A file of the drill could not be written or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The recording could not be read.
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// `--out` holds a drill's files already: nothing recorded is overwritten.
    #[error("{0} exists: give --out an empty or new directory")]
    Exists(PathBuf),
    /// `--only` names no fault.
    #[error("`{0}` is not a drill; known: {1}")]
    UnknownFault(String, String),
    /// The prompt before driving a real arm was not answered `yes`.
    #[error("{0}")]
    NotConfirmed(String),
    /// The graph did not run.
    #[error("drill {fault}: {what} (log: {log})")]
    Graph {
        /// The drill.
        fault: &'static str,
        /// What went wrong.
        what: String,
        /// `scl up`'s log.
        log: PathBuf,
    },
    /// The configuration could not be written for the drill's graph.
    #[error("cannot write the drill's configuration: {0}")]
    Encode(#[from] toml::ser::Error),
    /// `--only` names a drill the configuration gives nothing to drill.
    #[error("drill {drill} cannot run on this configuration: {why}")]
    NotApplicable {
        /// The drill.
        drill: &'static str,
        /// Why.
        why: &'static str,
    },
    /// The remote operator's relay (the link the link-cut drill cuts) did not start.
    #[error(transparent)]
    Relay(#[from] scl_net::relay::RelayError),
}

/// `scl drill`'s options.
#[derive(clap::Args, Debug, Clone)]
pub struct DrillArgs {
    /// Runs of each drill.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub repeat: u32,
    /// Print one JSON object (`rows`, each with the drill, its figures and `result`) instead
    /// of the table.
    #[arg(long)]
    pub json: bool,
    /// Keep each run's configuration, recording and log here (default: a temporary directory,
    /// removed at the end).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Drive the arm the configuration names (`[bridge] robot = "kortex"`: `scl fake-kortex`
    /// or a real arm), after a prompt that names it and the motion. Without it the drill runs
    /// the configuration on the mock arm.
    #[arg(long)]
    pub arm: bool,
    /// Only these drills (comma-separated names; default: every one).
    #[arg(long, value_delimiter = ',', value_name = "DRILL")]
    pub only: Vec<String>,
}

/// One fault the drill injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// `kill -9` of a process of the graph.
    Kill(NodeRole),
    /// `kill -9` of `scl up` itself.
    KillSupervisor,
    /// `kill -9` of the recorder, which is never restarted: the graph stops, bridge first.
    KillRecorder,
    /// SIGSTOP of a process for longer than the stale limit, then SIGCONT.
    Stall(NodeRole),
    /// The joystick goes silent (`[faults] joystick_silent_after_ticks`).
    StaleJoystick,
    /// NaN operator input for a few ticks (`[faults] joystick_nan_at_tick`).
    NanInput,
    /// Operator input far outside the stick's disc for a few ticks (`[faults]
    /// joystick_out_of_range_at_tick`): the mapper clamps it, nothing stops.
    RangeInput,
    /// A NaN command from the mapper (`[faults] mapper_nan_at_tick`).
    NanCommand,
    /// `scl estop` while the mapper runs, `scl reset` a second later.
    Estop,
    /// `kill -9` of the mapper (its restart delayed), then `scl estop` while none runs.
    EstopWithoutMapper,
    /// A live swap to a model file that does not load.
    SwapBad,
    /// A live swap to a model that loads.
    SwapGood,
    /// `kill -9` of the network gateway (`[network] enabled`): with `accept_joystick`, the
    /// remote operator's input is gone and the arm stops as for a dead joystick; without, the
    /// gateway only serves observers and nothing may stop.
    KillGateway,
    /// A remote operator's link cut, silently, as a pulled cable (`[network] enabled` and
    /// `accept_joystick`): the gateway finds the input stale and stands in with neutral.
    LinkCut,
}

impl Fault {
    /// Every drill, in the order they run.
    pub const ALL: [Fault; 19] = [
        Fault::Kill(NodeRole::Joystick),
        Fault::Kill(NodeRole::Mapper),
        Fault::Kill(NodeRole::Safety),
        Fault::Kill(NodeRole::Bridge),
        Fault::KillSupervisor,
        Fault::KillRecorder,
        Fault::Stall(NodeRole::Joystick),
        Fault::Stall(NodeRole::Mapper),
        Fault::Stall(NodeRole::Safety),
        Fault::StaleJoystick,
        Fault::NanInput,
        Fault::RangeInput,
        Fault::NanCommand,
        Fault::Estop,
        Fault::EstopWithoutMapper,
        Fault::SwapBad,
        Fault::SwapGood,
        Fault::KillGateway,
        Fault::LinkCut,
    ];

    /// The drill's name (`--only`, the table, the JSON rows).
    pub fn name(self) -> &'static str {
        match self {
            Fault::Kill(NodeRole::Joystick) => "kill-joystick",
            Fault::Kill(NodeRole::Mapper) => "kill-mapper",
            Fault::Kill(NodeRole::Safety) => "kill-safety",
            Fault::Kill(NodeRole::Bridge) => "kill-bridge",
            Fault::Kill(_) => "kill-other",
            Fault::KillSupervisor => "kill-supervisor",
            Fault::KillRecorder => "kill-recorder",
            Fault::Stall(NodeRole::Joystick) => "stall-joystick",
            Fault::Stall(NodeRole::Mapper) => "stall-mapper",
            Fault::Stall(NodeRole::Safety) => "stall-safety",
            Fault::Stall(_) => "stall-other",
            Fault::StaleJoystick => "stale-joystick",
            Fault::NanInput => "nan-input",
            Fault::RangeInput => "out-of-range",
            Fault::NanCommand => "nan-command",
            Fault::Estop => "estop",
            Fault::EstopWithoutMapper => "estop-no-mapper",
            Fault::SwapBad => "swap-bad-model",
            Fault::SwapGood => "swap-good-model",
            Fault::KillGateway => "kill-gateway",
            Fault::LinkCut => "link-cut",
        }
    }

    /// Why this drill does not apply to a graph of `cfg` (`None`: it does).
    pub fn not_applicable(self, cfg: &GraphConfig) -> Option<&'static str> {
        match self {
            Fault::KillGateway if !cfg.network.enabled => {
                Some("the configuration runs no gateway (`[network] enabled = false`)")
            }
            Fault::LinkCut if !(cfg.network.enabled && cfg.network.accept_joystick) => Some(
                "the configuration takes no remote operator (`[network] enabled` and `accept_joystick` are not both true)",
            ),
            _ => None,
        }
    }

    /// Whether the drill's graph takes the stick from the network: a remote operator the
    /// drill runs drives it through the gateway.
    fn remote_stick(self, cfg: &GraphConfig) -> bool {
        matches!(self, Fault::KillGateway | Fault::LinkCut)
            && cfg.network.enabled
            && cfg.network.accept_joystick
    }

    /// The drill of `name`.
    pub fn by_name(name: &str) -> Result<Fault, DrillError> {
        Self::ALL
            .into_iter()
            .find(|f| f.name() == name)
            .ok_or_else(|| {
                let known: Vec<&str> = Self::ALL.iter().map(|f| f.name()).collect();
                DrillError::UnknownFault(name.to_owned(), known.join(", "))
            })
    }

    /// Whether the joystick's age limit decides when the stop comes (on a graph of `cfg`).
    fn waits_for_stale_input(self, cfg: &GraphConfig) -> bool {
        matches!(
            self,
            Fault::Kill(NodeRole::Joystick)
                | Fault::Stall(NodeRole::Joystick)
                | Fault::StaleJoystick
        ) || (self == Fault::KillGateway && self.remote_stick(cfg))
    }
}

/// The stick's script during a drill: `step` (+x, 0, +y, 0, ...), each direction held 1 s,
/// each rest 0.3 s: the arm moves most of the time and the stick passes through neutral every
/// 1.3 s, so a stopped arm may move again.
const HOLD_S: f64 = 1.0;
const REST_S: f64 = 0.3;
/// The script rests this long at its start.
const REST_START_S: f64 = 0.5;
/// The fault comes in the middle of the first hold.
const FAULT_AT_S: f64 = REST_START_S + 0.6;
/// The graph runs this long after the fault: the stop, a restart, two passes through neutral.
const AFTER_S: f64 = 3.4;

/// Something the drill does at a tick.
#[derive(Debug, Clone)]
enum Action {
    Signal(NodeRole, Signal),
    ResumeStalled,
    KillSupervisor,
    /// `kill -9` of the recorder: the graph ends by design.
    KillRecorder,
    Estop(u32),
    Swap {
        model: String,
        loads: bool,
    },
    /// The remote operator's link cut.
    CutLink,
}

/// One run of one drill.
#[derive(Debug, Clone, Serialize)]
pub struct RunResult {
    /// The figures (`null`: the recording had no state after the fault).
    pub figures: Option<Figures>,
    /// E-stop without a mapper: the ticks safety answered itself / the ticks it should have.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estop_answers: Option<(u64, u64)>,
    /// E-stop without a mapper: safety's latest own answer after its state (ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estop_answer_max_ms: Option<f64>,
    /// Shared-memory files left after the graph ended.
    pub leftovers: usize,
    /// Why the run broke its promise (empty: kept).
    pub broken: Vec<String>,
}

/// One drill over its runs.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// The drill.
    pub fault: &'static str,
    /// What it promised.
    pub promise: Promise,
    /// Each run.
    pub runs: Vec<RunResult>,
    /// `PASS` when every run kept the promise, else `FAIL`.
    pub result: &'static str,
}

/// A drill left out because the configuration gives it nothing to drill.
#[derive(Debug, Clone, Serialize)]
pub struct NotRun {
    /// The drill.
    pub fault: &'static str,
    /// Why.
    pub why: &'static str,
}

/// The whole drill.
#[derive(Debug, Clone, Serialize)]
pub struct DrillReport {
    /// The configuration file (`null`: the defaults).
    pub config: Option<PathBuf>,
    /// The robot profile.
    pub robot: String,
    /// `[bridge] robot`.
    pub arm: String,
    /// `[graph] rate_hz`.
    pub rate_hz: f64,
    /// Runs of each drill.
    pub repeat: u32,
    /// The rows.
    pub rows: Vec<Row>,
    /// The drills left out (with no `--only`) and why.
    pub not_run: Vec<NotRun>,
    /// Every row passed.
    pub passed: bool,
}

/// The graph of one run: the user's configuration, with the drill's script, restart policies
/// that bring a killed process back, and the fault's injection.
fn drill_config(base: &GraphConfig, fault: Fault, fault_tick: u64) -> GraphConfig {
    let mut cfg = base.clone();
    cfg.joystick.source = "script".into();
    cfg.joystick.script = "step".into();
    cfg.joystick.step_hold_s = HOLD_S;
    cfg.joystick.step_rest_s = REST_S;
    let r = &mut cfg.supervisor.restart;
    r.joystick = RestartPolicy::OnFailure;
    r.mapper = RestartPolicy::OnFailure;
    r.safety = RestartPolicy::OnFailure;
    r.bridge = RestartPolicy::OnFailure;
    cfg.supervisor.backoff_initial_ms = if fault == Fault::EstopWithoutMapper {
        // The mapper stays dead while the e-stop is latched.
        2_500
    } else {
        200
    };
    cfg.supervisor.backoff_max_ms = cfg
        .supervisor
        .backoff_max_ms
        .max(cfg.supervisor.backoff_initial_ms);
    if cfg.network.enabled {
        // The drill's own gateway: on loopback (a free port each run, [`run_once`]), reached
        // by nothing outside this machine. Only the network drills take the stick from the
        // network (a remote operator the drill runs); every other drill drives with the
        // local script, as its promise is about the processes here.
        let n = &mut cfg.network;
        n.accept_joystick &= fault.remote_stick(base);
        n.accept_reset = false;
        n.ros2_joy = false;
        n.connect.clear();
        n.mode = scl_config::NetworkMode::Peer;
        n.multicast_scouting = false;
        cfg.supervisor.restart.gateway = RestartPolicy::OnFailure;
    }
    cfg.faults = scl_config::FaultConfig::default();
    match fault {
        Fault::StaleJoystick => cfg.faults.joystick_silent_after_ticks = fault_tick,
        Fault::NanInput => cfg.faults.joystick_nan_at_tick = fault_tick,
        Fault::RangeInput => cfg.faults.joystick_out_of_range_at_tick = fault_tick,
        Fault::NanCommand => cfg.faults.mapper_nan_at_tick = fault_tick,
        _ => {}
    }
    cfg
}

/// The promise of `fault` under `cfg`: what the README and docs/configuration.md say.
fn promise_of(cfg: &GraphConfig, fault: Fault) -> Result<Promise, DrillError> {
    let period_s = cfg.period_s();
    let ticks = |s: f64| (s / period_s).ceil() as u64;
    // A fault is seen at the tick it happens (a miss, a non-finite value, the e-stop), the
    // stop starting at the next; a silent joystick once its sample is older than the limit.
    let mut stop_ticks = 2;
    if fault.waits_for_stale_input(cfg) {
        stop_ticks += ticks(cfg.safety.max_joystick_age_ms / 1000.0);
    }
    if fault == Fault::LinkCut {
        // The gateway's rule: the input is stale once it answers a tick this far behind.
        stop_ticks += scl_net::link::STALE_AFTER_TICKS;
    }
    // A gateway that serves only observers must not disturb the loop when it dies.
    let observers_only = fault == Fault::KillGateway && !fault.remote_stick(cfg);
    Ok(Promise {
        stops: !matches!(fault, Fault::SwapBad | Fault::SwapGood | Fault::RangeInput)
            && !observers_only,
        stop_ticks,
        decel_rad_s2: cfg.profile()?.limits().max_acceleration_rad_s2.clone(),
        period_s,
    })
}

/// What the drill does, by tick, in one run.
fn schedule(
    fault: Fault,
    f: u64,
    period_s: f64,
    cfg: &GraphConfig,
    dir: &Path,
) -> Vec<(u64, Action)> {
    let at = |s: f64| f + (s / period_s).round() as u64;
    let stall_s = cfg.safety.max_joystick_age_ms / 1000.0 + 0.2;
    match fault {
        Fault::Kill(role) => vec![(f, Action::Signal(role, Signal::SIGKILL))],
        Fault::KillSupervisor => vec![(f, Action::KillSupervisor)],
        Fault::KillRecorder => vec![(f, Action::KillRecorder)],
        Fault::Stall(role) => vec![
            (f, Action::Signal(role, Signal::SIGSTOP)),
            (at(stall_s), Action::ResumeStalled),
        ],
        Fault::StaleJoystick | Fault::NanInput | Fault::RangeInput | Fault::NanCommand => {
            vec![]
        }
        Fault::Estop => vec![
            (f, Action::Estop(estop_action::ESTOP)),
            (at(1.0), Action::Estop(estop_action::RESET)),
        ],
        Fault::EstopWithoutMapper => vec![
            (f, Action::Signal(NodeRole::Mapper, Signal::SIGKILL)),
            (at(0.3), Action::Estop(estop_action::ESTOP)),
            (at(2.0), Action::Estop(estop_action::RESET)),
        ],
        Fault::SwapBad => vec![(
            f,
            Action::Swap {
                model: dir.join("not-a-model.safetensors").display().to_string(),
                loads: false,
            },
        )],
        Fault::SwapGood => vec![(
            f,
            Action::Swap {
                model: "bundled".into(),
                loads: true,
            },
        )],
        Fault::KillGateway => vec![(f, Action::Signal(NodeRole::Gateway, Signal::SIGKILL))],
        Fault::LinkCut => vec![(f, Action::CutLink)],
    }
}

/// The drill's view of the running graph: the newest tick, each role's newest process, and
/// every robot state it saw (what fills in after the recording's end when the recorder is
/// killed).
struct Watch {
    states: transport::TopicSubscriber<RobotState>,
    status: transport::TopicSubscriber<NodeStatus>,
    seen: Vec<RobotState>,
    newest: Vec<NodeStatus>,
    graph: transport::Graph,
}

impl Watch {
    fn join(prefix: &Prefix, cfg: &GraphConfig) -> Result<Self, DrillError> {
        let graph = transport::Graph::join_with(prefix, "drill", cfg.graph.transport)?;
        Ok(Self {
            states: graph.robot_state_subscriber(false)?,
            status: graph.status_subscriber()?,
            seen: Vec::new(),
            newest: Vec::new(),
            graph,
        })
    }

    fn poll(&mut self) -> Result<(), DrillError> {
        let seen = &mut self.seen;
        self.states.drain(|s| seen.push(*s))?;
        let newest = &mut self.newest;
        self.status
            .drain(|s| match newest.iter_mut().find(|n| n.role == s.role) {
                Some(n) if n.t_ns <= s.t_ns => *n = *s,
                Some(_) => {}
                None => newest.push(*s),
            })?;
        Ok(())
    }

    /// The newest tick seen.
    fn tick(&self) -> Option<u64> {
        self.seen.last().map(|s| s.tick)
    }

    fn pid_of(&self, role: NodeRole) -> Option<u32> {
        self.newest
            .iter()
            .find(|s| s.role == role as u32 && s.pid != 0)
            .map(|s| s.pid)
    }
}

fn signal(pid: u32, sig: Signal) {
    // A process of the graph this drill started; an error means it is gone already, which
    // the figures show.
    let _ = nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid as i32), sig);
}

/// Waits up to `timeout` for `child` to exit; kills it after that.
fn wait_exit(child: &mut Child, timeout: Duration) -> Option<std::process::ExitStatus> {
    let t0 = Instant::now();
    while t0.elapsed() < timeout {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    child.wait().ok()
}

/// Files of graph `prefix` left in `/dev/shm` or iceoryx2's directory.
pub fn leftovers(prefix: &Prefix) -> Vec<PathBuf> {
    transport::graph::files_named(&prefix.file_prefix())
}

/// Reads the run's recording. A message with a non-finite value (a fault drill's NaN) is
/// written as `null` and does not decode; it is left out, as `scl replay` leaves it out.
fn read_recording(path: &Path) -> Result<Recorded, DrillError> {
    use recording::{Event, Topic, decode};
    let mut rec = Recorded::default();
    let mut undecoded = 0u64;
    recording::read_file(path, |ev| {
        let Event::Message {
            channel,
            sequence,
            data,
            ..
        } = ev
        else {
            return Ok(());
        };
        let ok = match Topic::from_channel(&channel.topic) {
            Some(Topic::RobotState) => recording::decode_robot_state(path, channel, sequence, data)
                .map(|m| rec.states.push(m))
                .is_ok(),
            Some(Topic::SafeCommand) => decode(path, channel, sequence, data)
                .map(|m| rec.commands.push(m))
                .is_ok(),
            Some(Topic::Joystick) => decode(path, channel, sequence, data)
                .map(|m| rec.joystick.push(m))
                .is_ok(),
            Some(Topic::Status) => decode(path, channel, sequence, data)
                .map(|m| rec.status.push(m))
                .is_ok(),
            Some(Topic::Estop) => decode(path, channel, sequence, data)
                .map(|m| rec.estops.push(m))
                .is_ok(),
            Some(Topic::MapperCommand) => {
                decode::<ipc_types::MapperCommand>(path, channel, sequence, data)
                    .map(|m| {
                        let [x, y] = m.action.map(f64::from);
                        rec.mapper.push((m.tick, x.hypot(y)));
                    })
                    .is_ok()
            }
            _ => true,
        };
        undecoded += u64::from(!ok);
        Ok(())
    })?;
    if undecoded > 0 {
        tracing::debug!(undecoded, "messages with a non-finite value left out");
    }
    Ok(rec)
}

/// E-stop without a mapper: of the ticks from the e-stop's second tick to the reset that no
/// mapper answered, how many safety answered itself with a stop, and its latest answer after
/// the state (ms).
fn estop_answers(rec: &Recorded, from_ns: u64, to_ns: u64) -> (u64, u64, f64) {
    let mut due = 0;
    let mut answered = 0;
    let mut latest_ms = 0.0f64;
    let states: Vec<&RobotState> = rec
        .states
        .iter()
        .filter(|s| s.t_ns > from_ns && s.t_ns < to_ns)
        .skip(1)
        .collect();
    for s in states {
        if rec.mapper.iter().any(|(t, _)| *t == s.tick) {
            continue;
        }
        due += 1;
        if let Some(c) = rec
            .commands
            .iter()
            .find(|c| c.tick == s.tick && c.flags & ipc_types::safe_flags::ESTOP != 0)
        {
            answered += 1;
            let ms = c.t_ns.saturating_sub(s.t_ns) as f64 / 1e6;
            tracing::debug!(tick = s.tick, ms, "safety's own e-stop answer");
            latest_ms = latest_ms.max(ms);
        }
    }
    (answered, due, latest_ms)
}

/// Runs drill `fault` once under `prefix`, its files in `dir` named by `tag`.
fn run_once(
    fault: Fault,
    base: &GraphConfig,
    prefix: &Prefix,
    dir: &Path,
    tag: &str,
) -> Result<RunResult, DrillError> {
    let period_s = base.period_s();
    let fault_tick = (FAULT_AT_S / period_s).round() as u64;
    let end_tick = fault_tick + (AFTER_S / period_s).round() as u64;
    let mut cfg = drill_config(base, fault, fault_tick);
    if cfg.network.enabled {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(io_error(Path::new("127.0.0.1:0")))?
            .port();
        cfg.network.listen = vec![format!("tcp/127.0.0.1:{port}")];
    }
    let promise = promise_of(&cfg, fault)?;
    let (files, log) = RunFiles::create(fault, &cfg, dir, tag)?;
    let exe = std::env::current_exe().map_err(io_error(Path::new("scl")))?;
    let operator = if fault.remote_stick(&cfg) {
        Some(RemoteOperator::new(&exe, &cfg, &files, dir, tag, prefix)?)
    } else {
        None
    };
    let watch = Watch::join(prefix, &cfg)?;
    let up = files.start_graph(exe, log, prefix)?;
    let mut plan = schedule(fault, fault_tick, period_s, &cfg, dir);
    plan.reverse();
    let mut drive = Drive {
        fault,
        prefix,
        cfg: &cfg,
        log_path: &files.log,
        up,
        watch,
        plan,
        fault_tick,
        end_tick,
        operator,
        fault_ns: None,
        stalled: None,
        estop_window: (0, u64::MAX),
        graph_ends: false,
    };
    // An error from watching the graph or sending the e-stop ends the drill, one of the graph
    // ends the run; either way the `scl up` child is stopped and the domain released first.
    let result = drive.run().and_then(|r| r);
    if let Some(pid) = drive.stalled {
        signal(pid, Signal::SIGCONT);
    }
    let Drive {
        mut up,
        mut watch,
        fault_ns,
        fault_tick,
        estop_window,
        operator,
        ..
    } = drive;
    if let Some(op) = operator {
        op.stop();
    }
    let status = match result {
        Ok(s) => Some(s),
        Err(e) => {
            signal(up.id(), Signal::SIGINT);
            wait_exit(&mut up, Duration::from_secs(20));
            drop(watch);
            let _ = transport::graph::cleanup_dead_nodes(prefix);
            let _ = transport::graph::release_domain(prefix);
            return Err(e);
        }
    };
    watch.poll()?;
    let seen = std::mem::take(&mut watch.seen);
    leave_graph(fault, watch, prefix)?;
    let left = leftovers(prefix).len();
    tracing::debug!(?status, "scl up ended");
    let mut rec = read_recording(&files.rec)?;
    rec.fill_after_end(&seen);
    let fault_ns = match fault_ns {
        // The e-stop from the moment it was sent (the drill joins the graph to send it).
        _ if fault == Fault::Estop => rec.estop_sent(estop_action::ESTOP).unwrap_or(u64::MAX),
        Some(0) | None => rec
            .states
            .iter()
            .find(|s| s.tick >= fault_tick)
            .map_or(u64::MAX, |s| s.t_ns),
        Some(t) => t,
    };
    let figures = figures::measure(&rec, fault_ns, &promise);
    let (estop_answers, estop_answer_max_ms) = if fault == Fault::EstopWithoutMapper {
        let from = rec
            .estop_sent(estop_action::ESTOP)
            .unwrap_or(estop_window.0);
        let to = rec
            .estop_sent(estop_action::RESET)
            .unwrap_or(estop_window.1);
        let (a, d, ms) = estop_answers(&rec, from, to);
        (Some((a, d)), Some(ms))
    } else {
        (None, None)
    };
    let mut broken = match &figures {
        Some(f) => figures::judge(f, &promise, left),
        None => vec!["no robot state after the fault".to_owned()],
    };
    if let Some((a, d)) = estop_answers {
        let deadline_ms = cfg.bridge.command_deadline * period_s * 1e3;
        broken.extend(estop_broken(a, d, estop_answer_max_ms, deadline_ms));
    }
    Ok(RunResult {
        figures,
        estop_answers,
        estop_answer_max_ms,
        leftovers: left,
        broken,
    })
}

/// The promises the e-stop without a mapper broke: safety answered `a` of `d` ticks itself,
/// its latest answer `max_ms` after the state, against the bridge's deadline.
fn estop_broken(a: u64, d: u64, max_ms: Option<f64>, deadline_ms: f64) -> Vec<String> {
    let mut broken = Vec::new();
    if a < d {
        broken.push(format!(
            "safety answered {a} of {d} ticks with the e-stop latched and no mapper"
        ));
    }
    if max_ms.is_some_and(|ms| ms > deadline_ms) {
        broken.push(format!(
            "safety's own e-stop answer came {:.1} ms after the state, after the bridge's {deadline_ms:.1} ms deadline",
            max_ms.unwrap_or_default()
        ));
    }
    broken
}

/// The files of one run: the configuration, the recording and `scl up`'s log.
struct RunFiles {
    cfg: PathBuf,
    rec: PathBuf,
    log: PathBuf,
}

impl RunFiles {
    /// Names the run's files in `dir` by `tag` (none may exist), writes the configuration
    /// (and, for the bad swap, the file that is not a model) and creates the log.
    fn create(
        fault: Fault,
        cfg: &GraphConfig,
        dir: &Path,
        tag: &str,
    ) -> Result<(Self, std::fs::File), DrillError> {
        let files = Self {
            cfg: dir.join(format!("{tag}.toml")),
            rec: dir.join(format!("{tag}.mcap")),
            log: dir.join(format!("{tag}.log")),
        };
        for p in [&files.cfg, &files.rec, &files.log] {
            if p.exists() {
                return Err(DrillError::Exists(p.clone()));
            }
        }
        std::fs::write(&files.cfg, toml::to_string(cfg)?).map_err(io_error(&files.cfg))?;
        if fault == Fault::SwapBad {
            let bad = dir.join("not-a-model.safetensors");
            std::fs::write(&bad, b"not a model").map_err(io_error(&bad))?;
        }
        let log = std::fs::File::create(&files.log).map_err(io_error(&files.log))?;
        Ok((files, log))
    }

    /// Starts `scl up` (`exe`) on the configuration, recording, its stderr to `log`.
    fn start_graph(
        &self,
        exe: PathBuf,
        log: std::fs::File,
        prefix: &Prefix,
    ) -> Result<Child, DrillError> {
        Command::new(exe)
            .args([
                "up",
                "--json",
                "--for",
                "120s",
                "--prefix",
                prefix.as_str(),
                "--config",
            ])
            .arg(&self.cfg)
            .arg("--record")
            .arg(&self.rec)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(io_error(Path::new("scl up")))
    }
}

/// An I/O error on `path`.
fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> DrillError {
    let path = path.to_owned();
    move |source| DrillError::Io { path, source }
}

/// After `scl up` ended: the drill leaves the graph (after a killed supervisor, once its
/// children have stopped) and releases the domain.
fn leave_graph(fault: Fault, mut watch: Watch, prefix: &Prefix) -> Result<(), DrillError> {
    if fault == Fault::KillSupervisor {
        // Its children got SIGTERM and stop by themselves; give them time to.
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(10) {
            watch.poll()?;
            let alive = watch.graph.alive_nodes();
            if alive.iter().all(|(name, _)| name == "drill") {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    drop(watch);
    if fault == Fault::KillSupervisor {
        // The supervisor's own node, as `scl up` removes a dead one's at its next start.
        let _ = transport::graph::cleanup_dead_nodes(prefix);
    }
    let _ = transport::graph::release_domain(prefix);
    Ok(())
}

/// The remote operator of a network drill: `scl joystick --remote` with the drill's script
/// and the configuration's credentials, on this machine, reaching the drill's gateway through
/// a relay on loopback, which the link-cut drill cuts as a pulled cable would.
struct RemoteOperator {
    relay: scl_net::relay::Relay,
    /// The command, until it is started (once the gateway is up).
    cmd: Option<Command>,
    child: Option<Child>,
    /// Since when the drill waits for it (its start, then its first motion).
    since: Instant,
    /// The arm has moved under its input.
    driving: bool,
}

impl RemoteOperator {
    /// The operator of run `tag` (its log `dir/<tag>-operator.log`), not started yet.
    fn new(
        exe: &Path,
        cfg: &GraphConfig,
        files: &RunFiles,
        dir: &Path,
        tag: &str,
        prefix: &Prefix,
    ) -> Result<Self, DrillError> {
        let gateway = cfg
            .network
            .listen
            .first()
            .and_then(|e| e.strip_prefix("tcp/"))
            .unwrap_or_default()
            .to_owned();
        let relay = scl_net::relay::Relay::start_here(gateway)?;
        let log_path = dir.join(format!("{tag}-operator.log"));
        let log = std::fs::File::create(&log_path).map_err(io_error(&log_path))?;
        let mut cmd = Command::new(exe);
        cmd.env("SCL_PREFIX", prefix.as_str())
            .arg("joystick")
            .arg("--config")
            .arg(&files.cfg)
            .args(["--source", "script", "--script", "step", "--remote"])
            .arg(relay.endpoint())
            .arg("--credentials")
            .arg(&cfg.network.credentials)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log);
        Ok(Self {
            relay,
            cmd: Some(cmd),
            child: None,
            since: Instant::now(),
            driving: false,
        })
    }

    /// Starts the operator once `gateway_up`; an operator that exited is an error.
    fn poll(&mut self, gateway_up: bool) -> Result<(), String> {
        if let Some(c) = self.child.as_mut() {
            return match c.try_wait() {
                Ok(Some(status)) => Err(format!(
                    "the remote operator (scl joystick --remote) exited ({status}) before it drove"
                )),
                _ => Ok(()),
            };
        }
        if gateway_up && let Some(mut cmd) = self.cmd.take() {
            let child = cmd
                .spawn()
                .map_err(|e| format!("cannot start the remote operator: {e}"))?;
            self.child = Some(child);
            self.since = Instant::now();
        }
        Ok(())
    }

    /// Stops the relay, then the operator (SIGINT, then SIGKILL after 5 s): with its link
    /// closed (not cut) its session ends at once.
    fn stop(self) {
        drop(self.relay);
        if let Some(mut c) = self.child {
            signal(c.id(), Signal::SIGINT);
            wait_exit(&mut c, Duration::from_secs(5));
        }
    }
}

/// How a run ended: `scl up`'s exit status, or an error after which the graph is stopped.
type Ended = Result<std::process::ExitStatus, DrillError>;

/// One run's graph while the drill drives it: `scl up`, the drill's view of the graph, the
/// fault plan (last step first) and what its steps leave to undo or measure.
struct Drive<'a> {
    fault: Fault,
    prefix: &'a Prefix,
    cfg: &'a GraphConfig,
    log_path: &'a Path,
    up: Child,
    watch: Watch,
    plan: Vec<(u64, Action)>,
    /// The fault's tick (moved on once a remote operator drives) and the tick the run ends.
    fault_tick: u64,
    end_tick: u64,
    /// The remote operator of a network drill.
    operator: Option<RemoteOperator>,
    /// When the fault began (0: at its tick, set in the configuration).
    fault_ns: Option<u64>,
    /// The process stopped with SIGSTOP, to resume.
    stalled: Option<u32>,
    /// When the e-stop was sent and reset.
    estop_window: (u64, u64),
    /// `scl up` is to end: the drill stopped or killed it, or the fault ends the graph.
    graph_ends: bool,
}

impl Drive<'_> {
    /// The graph failed the drill (`scl up`'s log says more).
    fn graph_err(&self, what: String) -> DrillError {
        DrillError::Graph {
            fault: self.fault.name(),
            what,
            log: self.log_path.to_owned(),
        }
    }

    /// Polls the graph every 2 ms, applying the plan's steps at their ticks and stopping
    /// `scl up` at `end_tick`, until it ends. An error outside (watching the graph, sending the
    /// e-stop) ends the drill; one inside ends the run. The caller stops the graph after
    /// either.
    fn run(&mut self) -> Result<Ended, DrillError> {
        let mut last_progress = Instant::now();
        let mut last_tick = None;
        loop {
            self.watch.poll()?;
            if self.watch.tick() != last_tick {
                last_tick = self.watch.tick();
                last_progress = Instant::now();
            }
            if let Ok(Some(status)) = self.up.try_wait() {
                if self.graph_ends || self.watch.tick().is_some_and(|t| t >= self.end_tick) {
                    return Ok(Ok(status));
                }
                return Ok(Err(self.graph_err(format!("scl up ended early ({status})"))));
            }
            if last_progress.elapsed() > Duration::from_secs(30) {
                return Ok(Err(self.graph_err("no tick for 30 s".into())));
            }
            match self.operator_drives() {
                Ok(true) => {}
                Ok(false) => {
                    std::thread::sleep(Duration::from_millis(2));
                    continue;
                }
                Err(e) => return Ok(Err(e)),
            }
            let (fault_tick, end_tick) = (self.fault_tick, self.end_tick);
            let tick = self.watch.tick().unwrap_or(0);
            if self.watch.tick().is_some()
                && self.fault_ns.is_none()
                && tick >= fault_tick
                && self.plan.is_empty()
            {
                // A fault set by tick in the configuration: measured from that tick's state.
                self.fault_ns = Some(0);
            }
            if let Some((at, _)) = self.plan.last()
                && self.watch.tick().is_some()
                && tick >= *at
            {
                let Some((_, action)) = self.plan.pop() else {
                    continue;
                };
                let now = now_ns();
                if self.fault_ns.is_none() {
                    self.fault_ns = Some(now);
                }
                if let Err(e) = self.act(action, now)? {
                    return Ok(Err(e));
                }
                continue;
            }
            if self.plan.is_empty() && !self.graph_ends && tick >= end_tick {
                signal(self.up.id(), Signal::SIGINT);
                self.graph_ends = true;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Whether the plan may go on: no remote operator, or the arm has moved under its input.
    /// Starts the operator once the gateway is up; once the arm first moves, moves the fault
    /// (and the plan and the run's end with it) to as far into the stick's first hold as the
    /// drill's fault comes for a local stick. An error ends the run.
    fn operator_drives(&mut self) -> Result<bool, DrillError> {
        const PATIENCE: Duration = Duration::from_secs(60);
        let gateway_up = self.watch.pid_of(NodeRole::Gateway).is_some();
        let moving = self
            .watch
            .seen
            .last()
            .is_some_and(|s| figures::max_speed(s) > 0.01);
        let tick = self.watch.tick().unwrap_or(0);
        let Some(op) = self.operator.as_mut() else {
            return Ok(true);
        };
        if op.driving {
            return Ok(true);
        }
        let problem = match op.poll(gateway_up) {
            Err(e) => Some(e),
            Ok(()) if moving => {
                op.driving = true;
                let lead = ((FAULT_AT_S - REST_START_S) / self.cfg.period_s()).round() as u64;
                let shift = (tick + lead).saturating_sub(self.fault_tick);
                self.fault_tick += shift;
                self.end_tick += shift;
                for (t, _) in &mut self.plan {
                    *t += shift;
                }
                tracing::debug!(
                    tick,
                    fault_tick = self.fault_tick,
                    "the remote operator drives"
                );
                return Ok(true);
            }
            Ok(()) if op.since.elapsed() > PATIENCE => Some(format!(
                "the remote operator did not move the arm within {} s",
                PATIENCE.as_secs()
            )),
            Ok(()) => None,
        };
        match problem {
            Some(what) => Err(self.graph_err(what)),
            None => Ok(false),
        }
    }

    /// Applies one step of the plan at `now`. An error outside ends the drill at once; one
    /// inside ends the run.
    fn act(&mut self, action: Action, now: u64) -> Result<Result<(), DrillError>, DrillError> {
        match action {
            Action::Signal(role, sig) => {
                let Some(pid) = self.watch.pid_of(role) else {
                    return Ok(Err(
                        self.graph_err(format!("no {} process to signal", role.name()))
                    ));
                };
                if sig == Signal::SIGSTOP {
                    self.stalled = Some(pid);
                }
                signal(pid, sig);
            }
            Action::ResumeStalled => {
                if let Some(pid) = self.stalled.take() {
                    signal(pid, Signal::SIGCONT);
                }
            }
            Action::KillSupervisor => {
                self.graph_ends = true;
                let _ = self.up.kill();
            }
            Action::KillRecorder => {
                let Some(pid) = self.watch.pid_of(NodeRole::Recorder) else {
                    return Ok(Err(self.graph_err("no recorder process to kill".into())));
                };
                self.graph_ends = true;
                signal(pid, Signal::SIGKILL);
            }
            Action::Estop(action) => {
                if action == estop_action::ESTOP {
                    self.estop_window.0 = now;
                } else {
                    self.estop_window.1 = now;
                }
                graph_client::control::estop(
                    self.prefix,
                    self.cfg.graph.transport,
                    action,
                    Duration::from_secs(2),
                )
                .map_err(|e| self.graph_err(format!("e-stop: {e}")))?;
            }
            Action::CutLink => match &self.operator {
                Some(op) => op.relay.cut(),
                None => {
                    return Ok(Err(
                        self.graph_err("no remote operator's link to cut".into())
                    ));
                }
            },
            Action::Swap { model, loads } => {
                let r = graph_client::control::swap(self.prefix, &model, Duration::from_secs(20));
                let ok = matches!(&r, Ok(resp) if resp.ok != 0);
                if ok != loads {
                    return Ok(Err(self.graph_err(format!(
                        "the swap to {model} {}: {r:?}",
                        if loads { "was refused" } else { "was accepted" }
                    ))));
                }
            }
        }
        Ok(Ok(()))
    }
}

/// Asks the person at the terminal to confirm a drill that moves a real arm (or
/// `scl fake-kortex`): `yes` on standard input goes on.
fn confirm(cfg: &GraphConfig, drills: usize, repeat: u32) -> Result<(), DrillError> {
    let k = &cfg.bridge.kortex;
    let vmax = cfg
        .safety
        .max_velocity_rad_s
        .iter()
        .fold(0.0f64, |m, v| m.max(*v));
    eprint!(
        "scl drill drives the {} arm at {}:{} (profile {}) through {} runs of about {:.0} s: a \
         scripted stick moves every joint at up to {vmax:.2} rad/s and each fault stops it. Keep \
         the arm's workspace clear and the e-stop at hand. Type `yes` to go on: ",
        cfg.bridge.robot,
        k.address,
        k.port,
        cfg.graph.robot,
        drills * repeat as usize,
        FAULT_AT_S + AFTER_S + 1.0
    );
    let _ = std::io::stderr().flush();
    let mut line = String::new();
    let _ = std::io::stdin().lock().read_line(&mut line);
    if line.trim() == "yes" {
        Ok(())
    } else {
        Err(DrillError::NotConfirmed(
            "not confirmed: the arm was not moved".into(),
        ))
    }
}

/// Runs the drills of `args` on the graph `cfg` (read from `config`).
pub fn run(
    config: Option<&Path>,
    cfg: &GraphConfig,
    args: &DrillArgs,
) -> Result<DrillReport, DrillError> {
    cfg.validate_file(config)?;
    let mut not_run = Vec::new();
    let faults = if args.only.is_empty() {
        Fault::ALL
            .into_iter()
            .filter(|f| match f.not_applicable(cfg) {
                None => true,
                Some(why) => {
                    not_run.push(NotRun {
                        fault: f.name(),
                        why,
                    });
                    false
                }
            })
            .collect()
    } else {
        let faults = args
            .only
            .iter()
            .map(|n| Fault::by_name(n.trim()))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some((f, why)) = faults
            .iter()
            .find_map(|f| f.not_applicable(cfg).map(|why| (f, why)))
        {
            return Err(DrillError::NotApplicable {
                drill: f.name(),
                why,
            });
        }
        faults
    };
    let mut cfg = cfg.clone();
    if cfg.bridge.robot != "mock" {
        if args.arm {
            confirm(&cfg, faults.len(), args.repeat)?;
        } else {
            eprintln!(
                "scl drill: on the mock arm instead of the configured `{}` arm at {}:{} (--arm drives that one, after a prompt)",
                cfg.bridge.robot, cfg.bridge.kortex.address, cfg.bridge.kortex.port
            );
            cfg.bridge.robot = "mock".into();
        }
    }
    let cfg = &cfg;
    let (dir, keep) = match &args.out {
        Some(d) => (d.clone(), true),
        None => (
            std::env::temp_dir().join(format!("scl-drill-{}", std::process::id())),
            false,
        ),
    };
    std::fs::create_dir_all(&dir).map_err(|source| DrillError::Io {
        path: dir.clone(),
        source,
    })?;
    let mut rows = Vec::new();
    let mut n = 0;
    for fault in faults {
        let mut runs = Vec::new();
        for rep in 0..args.repeat {
            n += 1;
            let prefix = Prefix::new(&format!("drill{}x{n}", std::process::id())).map_err(|e| {
                scl_config::ConfigError::Value {
                    key: "prefix".into(),
                    reason: e.to_string(),
                }
            })?;
            let tag = format!("{}-{}", fault.name(), rep + 1);
            tracing::info!(drill = fault.name(), run = rep + 1, "drill");
            let r = run_once(fault, cfg, &prefix, &dir, &tag)?;
            if !args.json {
                eprintln!(
                    "scl drill: {tag}: {}",
                    if r.broken.is_empty() {
                        "kept".to_owned()
                    } else {
                        r.broken.join("; ")
                    }
                );
            }
            runs.push(r);
        }
        let passed = runs.iter().all(|r| r.broken.is_empty());
        rows.push(Row {
            fault: fault.name(),
            promise: promise_of(&drill_config(cfg, fault, 0), fault)?,
            runs,
            result: if passed { "PASS" } else { "FAIL" },
        });
    }
    if !keep {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(DrillReport {
        config: config.map(Path::to_owned),
        robot: cfg.graph.robot.clone(),
        arm: cfg.bridge.robot.clone(),
        rate_hz: cfg.graph.rate_hz,
        repeat: args.repeat,
        passed: rows.iter().all(|r| r.result == "PASS"),
        rows,
        not_run,
    })
}

fn max_of(rows: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    rows.flatten()
        .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))))
}

/// The table `scl drill` prints: one line per drill, each figure the worst of its runs.
pub fn render(r: &DrillReport) -> String {
    let mut out = format!(
        "scl drill: {} on the {} arm ({}), {} Hz, {} runs each\n",
        r.config.as_ref().map_or_else(
            || "the default graph".to_owned(),
            |p| p.display().to_string()
        ),
        r.arm,
        r.robot,
        r.rate_hz,
        r.repeat
    );
    out.push_str(
        "drill            stop ticks  rest ms  travel/promised rad  peak/at fault rad/s  resumed        missed (held up)  left  result\n",
    );
    for row in &r.rows {
        let figs: Vec<&Figures> = row.runs.iter().filter_map(|x| x.figures.as_ref()).collect();
        let stop = figs
            .iter()
            .map(|f| f.stop_ticks)
            .try_fold(0u64, |m, t| t.map(|t| m.max(t)));
        let rest = max_of(figs.iter().map(|f| f.rest_ms));
        if !row.promise.stops {
            out.push_str(&render_non_stopping(row, &figs));
            continue;
        }
        let worst = figs.iter().max_by(|a, b| {
            (a.travel_rad / a.promised_travel_rad)
                .total_cmp(&(b.travel_rad / b.promised_travel_rad))
        });
        let peak = figs
            .iter()
            .max_by(|a, b| a.peak_speed_rad_s.total_cmp(&b.peak_speed_rad_s));
        let resumed = if figs.iter().any(|f| f.resumed == "before-neutral") {
            "before-neutral"
        } else if figs.iter().any(|f| f.resumed == "after-neutral") {
            "after-neutral"
        } else {
            "none"
        };
        let missed: u64 = figs.iter().map(|f| f.missed).max().unwrap_or(0);
        let held: u64 = figs.iter().map(|f| f.held_up).max().unwrap_or(0);
        let left: usize = row.runs.iter().map(|x| x.leftovers).max().unwrap_or(0);
        out.push_str(&format!(
            "{:<16} {:>5} /{:<3} {:>8} {:>9} / {:<9} {:>8} / {:<8} {:<14} {:>7} ({:>3})    {:>4}  {}\n",
            row.fault,
            stop.map_or("-".to_owned(), |t| t.to_string()),
            if row.promise.stops {
                row.promise.stop_ticks.to_string()
            } else {
                "-".to_owned()
            },
            rest.map_or("-".to_owned(), |v| format!("{v:.0}")),
            worst.map_or("-".to_owned(), |f| format!("{:.4}", f.travel_rad)),
            worst.map_or("-".to_owned(), |f| format!("{:.4}", f.promised_travel_rad)),
            peak.map_or("-".to_owned(), |f| format!("{:.3}", f.peak_speed_rad_s)),
            peak.map_or("-".to_owned(), |f| format!("{:.3}", f.speed_at_fault_rad_s)),
            resumed,
            missed,
            held,
            left,
            row.result
        ));
        for (i, run) in row.runs.iter().enumerate() {
            if let Some((a, d)) = run.estop_answers {
                out.push_str(&format!(
                    "  run {}: safety answered {a}/{d} ticks itself, latest {:.1} ms after the state\n",
                    i + 1,
                    run.estop_answer_max_ms.unwrap_or_default()
                ));
            }
            for why in &run.broken {
                out.push_str(&format!("  run {}: {why}\n", i + 1));
            }
        }
    }
    for n in &r.not_run {
        out.push_str(&format!("{:<16} not run: {}\n", n.fault, n.why));
    }
    out.push_str(if r.passed {
        "every drill kept its promise\n"
    } else {
        "FAIL: a drill broke its promise (see above)\n"
    });
    out
}

/// A drill's line (and its runs' broken promises) when its fault need not stop the arm:
/// the stop commands sent instead of the stop figures, and a stick reading outside the disc
/// with the largest action mapped from it.
fn render_non_stopping(row: &Row, figs: &[&Figures]) -> String {
    let mut out = String::new();
    let stops: u64 = figs.iter().map(|f| f.stop_commands).max().unwrap_or(0);
    let input = figs.iter().map(|f| f.max_input).fold(0.0f64, f64::max);
    let action = figs.iter().map(|f| f.max_action).fold(0.0f64, f64::max);
    let clamped = if input > 1.0 {
        format!("input {input:.0} -> {action:.3}")
    } else {
        "-".to_owned()
    };
    out.push_str(&format!(
        "{:<16} {:>10} {:>8} {:>21} {:>20} {:<14} {:>7} ({:>3})    {:>4}  {}\n",
        row.fault,
        "-",
        "-",
        format!("{stops} stop commands"),
        clamped,
        "-",
        figs.iter().map(|f| f.missed).max().unwrap_or(0),
        figs.iter().map(|f| f.held_up).max().unwrap_or(0),
        row.runs.iter().map(|x| x.leftovers).max().unwrap_or(0),
        row.result
    ));
    for (i, run) in row.runs.iter().enumerate() {
        for why in &run.broken {
            out.push_str(&format!("  run {}: {why}\n", i + 1));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_drill_has_a_name_of_its_own() {
        let names: Vec<&str> = Fault::ALL.iter().map(|f| f.name()).collect();
        for n in &names {
            assert_eq!(names.iter().filter(|m| m == &n).count(), 1, "{n}");
            assert_eq!(Fault::by_name(n).unwrap().name(), *n);
        }
        let e = Fault::by_name("kill-everything").unwrap_err().to_string();
        assert!(
            e.contains("kill-everything") && e.contains("stale-joystick"),
            "{e}"
        );
    }

    /// The drill's graph keeps the user's configuration but the stick, the restarts and the
    /// fault; its promise comes from the profile's documented decelerations, not from
    /// `[safety]`, so a slower configured stop breaks it.
    #[test]
    fn the_drill_graph_and_its_promise() {
        let mut base = GraphConfig::default();
        base.safety
            .max_acceleration_rad_s2
            .iter_mut()
            .for_each(|a| *a /= 5.0);
        let cfg = drill_config(&base, Fault::StaleJoystick, 44);
        assert_eq!(cfg.faults.joystick_silent_after_ticks, 44);
        assert_eq!(cfg.joystick.script, "step");
        assert_eq!(cfg.supervisor.restart.safety, RestartPolicy::OnFailure);
        assert_eq!(
            cfg.safety.max_acceleration_rad_s2,
            base.safety.max_acceleration_rad_s2
        );
        let p = promise_of(&cfg, Fault::StaleJoystick).unwrap();
        assert_eq!(
            p.decel_rad_s2,
            GraphConfig::default().safety.max_acceleration_rad_s2
        );
        // 100 ms at 40 Hz is 4 ticks, plus the two of any fault.
        assert_eq!(p.stop_ticks, 6);
        assert_eq!(promise_of(&cfg, Fault::Estop).unwrap().stop_ticks, 2);
        assert!(!promise_of(&cfg, Fault::SwapGood).unwrap().stops);
        let cfg = drill_config(&base, Fault::RangeInput, 44);
        assert_eq!(cfg.faults.joystick_out_of_range_at_tick, 44);
        assert!(!promise_of(&cfg, Fault::RangeInput).unwrap().stops);
        assert_eq!(promise_of(&cfg, Fault::KillRecorder).unwrap().stop_ticks, 2);
    }

    /// The network drills run only where the configuration gives them something to drill;
    /// their graph's gateway listens on loopback, and only they take the stick from the
    /// network. A cut link stops within the gateway's staleness rule, a dead gateway that
    /// carried the stick within the joystick's age limit, and one that served only observers
    /// must not stop anything.
    #[test]
    fn the_network_drills_and_their_promises() {
        let mut base = GraphConfig::default();
        assert!(Fault::KillGateway.not_applicable(&base).is_some());
        assert!(Fault::LinkCut.not_applicable(&base).is_some());
        base.network.enabled = true;
        assert!(Fault::KillGateway.not_applicable(&base).is_none());
        assert!(Fault::LinkCut.not_applicable(&base).is_some());
        let observed = drill_config(&base, Fault::KillGateway, 44);
        assert!(!promise_of(&observed, Fault::KillGateway).unwrap().stops);
        base.network.accept_joystick = true;
        base.network.accept_reset = true;
        base.network.connect = vec!["tcp/192.0.2.10:7447".into()];
        assert!(Fault::LinkCut.not_applicable(&base).is_none());
        let cut = drill_config(&base, Fault::LinkCut, 44);
        assert!(cut.network.accept_joystick && !cut.network.accept_reset);
        assert!(cut.network.connect.is_empty());
        assert_eq!(cut.supervisor.restart.gateway, RestartPolicy::OnFailure);
        assert_eq!(promise_of(&cut, Fault::LinkCut).unwrap().stop_ticks, 2 + 2);
        let killed = drill_config(&base, Fault::KillGateway, 44);
        let p = promise_of(&killed, Fault::KillGateway).unwrap();
        assert!(p.stops);
        assert_eq!(p.stop_ticks, 2 + 4);
        // Every other drill drives with the local stick.
        let other = drill_config(&base, Fault::Kill(NodeRole::Joystick), 44);
        assert!(other.network.enabled && !other.network.accept_joystick);
    }
}
