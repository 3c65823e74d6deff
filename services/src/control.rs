//! The commands that talk to a running graph: `scl swap` (a request to its supervisor) and
//! `scl status` (read from the heartbeats every node publishes, so it also works for a graph
//! started by hand).

use std::path::Path;
use std::time::{Duration, Instant};

use ipc_types::control::{ControlRequest, ControlResponse, Text, request_kind};
use ipc_types::{Graph, NodeRole, NodeStatus, Prefix, phase, time::now_ns};
use serde::Serialize;

use crate::SclError;

/// Asks the supervisor of graph `prefix` to swap the active mapper for one serving `model`
/// (a path, made absolute here since the supervisor's working directory may differ, or
/// `bundled`).
pub fn swap(prefix: &Prefix, model: &str, timeout: Duration) -> Result<ControlResponse, SclError> {
    let spec = if mapper::model::is_builtin(model) {
        model.to_owned()
    } else {
        let p = Path::new(model);
        let abs = std::fs::canonicalize(p)
            .map_err(|e| SclError::Graph(format!("model file {model}: {e}")))?;
        abs.display().to_string()
    };
    if spec.len() > ipc_types::control::TEXT_CAP {
        return Err(SclError::Graph(format!(
            "model path {spec} is longer than {} bytes",
            ipc_types::control::TEXT_CAP
        )));
    }
    let graph = Graph::join(prefix, &format!("swap-{}", std::process::id()))?;
    let req = ControlRequest {
        kind: request_kind::SWAP,
        reserved: 0,
        path: Text::new(&spec),
    };
    Ok(graph.request(req, timeout)?)
}

/// Sends an e-stop or a reset (an `estop_action` value) to graph `prefix` and waits up to
/// `timeout` for a safety process to confirm the new state in its heartbeat. Returns the
/// confirming process's pid, or `None` if none did. The publisher stays alive until then: a
/// sample of a publisher that is gone is not delivered.
pub fn estop(
    prefix: &Prefix,
    transport: ipc_types::Transport,
    action: u32,
    timeout: Duration,
) -> Result<Option<u32>, SclError> {
    use ipc_types::control::{EstopCommand, estop_action};
    let graph = Graph::join_with(prefix, &format!("estop-{}", std::process::id()), transport)?;
    let status = graph.status_subscriber()?;
    let publisher = graph.estop_publisher()?;
    publisher
        .send_copy(EstopCommand {
            t_ns: now_ns(),
            action,
            source_pid: std::process::id(),
        })
        .map_err(|e| SclError::Graph(format!("cannot send the e-stop command: {e}")))?;
    let want = action == estop_action::ESTOP;
    let sent = now_ns();
    let t0 = Instant::now();
    while t0.elapsed() < timeout {
        let mut confirmed = None;
        status.drain(|s| {
            let latched = s.safety_state & ipc_types::safety_state::ESTOP != 0;
            if s.role == NodeRole::Safety as u32 && s.t_ns > sent && latched == want {
                confirmed = Some(s.pid);
            }
        })?;
        if confirmed.is_some() {
            return Ok(confirmed);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(None)
}

/// One node as `scl status` shows it.
#[derive(Debug, Clone, Serialize)]
pub struct NodeRow {
    /// Role name.
    pub role: String,
    /// Process id.
    pub pid: u32,
    /// Mapper id (mappers: their own; safety: the active one; bridge: last executed).
    pub mapper_id: u32,
    /// `ready`, `running` or `stopping`.
    pub phase: String,
    /// Newest tick handled.
    pub tick: Option<u64>,
    /// Ticks handled.
    pub handled: u64,
    /// Faults (bridge: missed ticks).
    pub faults: u64,
    /// Age of the newest heartbeat (ms).
    pub heartbeat_age_ms: f64,
    /// Whether the node counts as alive: heartbeat younger than 250 ms and its iceoryx2
    /// node alive.
    pub alive: bool,
    /// Safety: how many ticks each rule acted (only rules that did).
    pub rules: Vec<(String, u32)>,
    /// Mapper with modes (mode switching): the current mode's name.
    pub mode: Option<String>,
    /// Mapper with modes: mode switches since it started.
    pub mode_switches: Option<u32>,
}

/// The graph as `scl status` shows it.
#[derive(Debug, Clone, Serialize)]
pub struct GraphStatus {
    /// The prefix.
    pub prefix: String,
    /// Nodes with heartbeats, by role.
    pub nodes: Vec<NodeRow>,
    /// Other iceoryx2 nodes of the graph (supervisor, observers): name and pid.
    pub other_nodes: Vec<(String, u32)>,
    /// The mapper safety forwards.
    pub active_mapper: Option<u32>,
    /// The bridge's newest end-to-end latency (µs).
    pub bridge_latency_us: Option<f64>,
    /// The bridge's joint travel (rad).
    pub joint_travel_rad: Option<f64>,
}

/// Reads the heartbeats of graph `prefix` for `listen`.
pub fn status(
    prefix: &Prefix,
    transport: ipc_types::Transport,
    listen: Duration,
) -> Result<GraphStatus, SclError> {
    let me = format!("status-{}", std::process::id());
    let graph = Graph::join_with(prefix, &me, transport)?;
    let sub = graph.status_subscriber()?;
    let mut latest: Vec<NodeStatus> = Vec::new();
    let t0 = Instant::now();
    while t0.elapsed() < listen {
        sub.drain(|s| {
            match latest
                .iter_mut()
                .find(|l| l.pid == s.pid && l.role == s.role)
            {
                Some(l) => *l = *s,
                None => latest.push(*s),
            }
        })?;
        std::thread::sleep(Duration::from_millis(10));
    }
    let alive = graph.alive_nodes();
    let now = now_ns();
    latest.sort_by_key(|s| (s.role, s.mapper_id, s.pid));
    let mut out = GraphStatus {
        prefix: prefix.to_string(),
        nodes: Vec::new(),
        other_nodes: Vec::new(),
        active_mapper: None,
        bridge_latency_us: None,
        joint_travel_rad: None,
    };
    for s in &latest {
        let role = NodeRole::from_u32(s.role);
        let age_ms = now.saturating_sub(s.t_ns) as f64 / 1e6;
        let node_alive = alive.iter().any(|(_, pid)| *pid == s.pid);
        let row = NodeRow {
            role: role.map_or("unknown", NodeRole::name).to_owned(),
            pid: s.pid,
            mapper_id: s.mapper_id,
            phase: match s.phase {
                phase::READY => "ready",
                phase::RUNNING => "running",
                phase::STOPPING => "stopping",
                _ => "?",
            }
            .to_owned(),
            tick: (s.tick != ipc_types::NO_TICK).then_some(s.tick),
            handled: s.handled,
            faults: s.faults,
            heartbeat_age_ms: age_ms,
            alive: age_ms < 250.0 && node_alive && s.phase != phase::STOPPING,
            rules: ipc_types::safe_flags::NAMES
                .iter()
                .zip(s.rule_counts)
                .filter(|(_, c)| *c > 0)
                .map(|(n, c)| ((*n).to_owned(), c))
                .collect(),
            mode: (s.mode > 0).then(|| mode_name(s.mode)),
            mode_switches: (s.mode > 0).then_some(s.mode_switches),
        };
        if row.alive {
            match role {
                Some(NodeRole::Safety) => out.active_mapper = Some(s.mapper_id),
                Some(NodeRole::Bridge) => {
                    out.bridge_latency_us = Some(s.latency_ns as f64 / 1e3);
                    out.joint_travel_rad = Some(s.joint_travel_rad);
                }
                _ => {}
            }
        }
        out.nodes.push(row);
    }
    out.other_nodes = alive
        .into_iter()
        .filter(|(name, pid)| *name != me && !latest.iter().any(|s| s.pid == *pid))
        .collect();
    Ok(out)
}

/// The name of a heartbeat's [`NodeStatus::mode`] (mode plus one; the mode-switching map's
/// modes are the only ones so far).
fn mode_name(mode: u32) -> String {
    let index = (mode as usize).saturating_sub(1);
    mapper::modeswitch::Mode::from_index(index)
        .map_or_else(|| format!("mode {index}"), |m| m.name().to_owned())
}

/// The table `scl status` prints.
pub fn render(st: &GraphStatus) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let alive = st.nodes.iter().filter(|n| n.alive).count();
    let _ = writeln!(
        s,
        "graph `{}`: {alive} of {} nodes alive, active mapper {}",
        st.prefix,
        st.nodes.len(),
        st.active_mapper.map_or("none".into(), |m| m.to_string())
    );
    let _ = writeln!(
        s,
        "{:<9} {:>8} {:>3} {:<9} {:>8} {:>8} {:>6} {:>10}  LIVENESS",
        "ROLE", "PID", "ID", "PHASE", "TICK", "HANDLED", "FAULTS", "HEARTBEAT"
    );
    for n in &st.nodes {
        let _ = writeln!(
            s,
            "{:<9} {:>8} {:>3} {:<9} {:>8} {:>8} {:>6} {:>7.0} ms  {}",
            n.role,
            n.pid,
            if n.mapper_id > 0 {
                n.mapper_id.to_string()
            } else {
                "-".into()
            },
            n.phase,
            n.tick.map_or("-".into(), |t| t.to_string()),
            n.handled,
            n.faults,
            n.heartbeat_age_ms,
            if n.alive { "alive" } else { "gone" }
        );
    }
    for n in st.nodes.iter().filter(|n| !n.rules.is_empty()) {
        let rules: Vec<String> = n.rules.iter().map(|(r, c)| format!("{r} {c}")).collect();
        let _ = writeln!(
            s,
            "{} (pid {}) rules acted: {}",
            n.role,
            n.pid,
            rules.join(", ")
        );
    }
    for n in &st.nodes {
        if let (Some(mode), Some(switches)) = (&n.mode, n.mode_switches) {
            let _ = writeln!(
                s,
                "{} {} (pid {}): mode {mode}, {switches} mode switches",
                n.role, n.mapper_id, n.pid
            );
        }
    }
    for (name, pid) in &st.other_nodes {
        let _ = writeln!(
            s,
            "{name:<9} {pid:>8}   (no heartbeat: supervisor or observer)"
        );
    }
    if let (Some(l), Some(t)) = (st.bridge_latency_us, st.joint_travel_rad) {
        let _ = writeln!(
            s,
            "bridge: last end-to-end latency {l:.1} µs, joint travel {t:.3} rad"
        );
    }
    s
}
