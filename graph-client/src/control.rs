//! The commands that talk to a running graph: `scl swap` (a request to its supervisor) and
//! `scl status` (read from the heartbeats every node publishes, so it also works for a graph
//! started by hand).

use std::path::Path;
use std::time::{Duration, Instant};

use ipc_types::control::{ControlRequest, ControlResponse, Text, request_kind};
use ipc_types::{NodeRole, NodeStatus, Prefix, SafeCommand, phase, time::now_ns};
use serde::Serialize;
use transport::Graph;

use crate::ControlError;

/// Asks the supervisor of graph `prefix` to swap the active mapper for one serving `model`
/// (a path, made absolute here since the supervisor's working directory may differ, or
/// `bundled`).
pub fn swap(
    prefix: &Prefix,
    model: &str,
    timeout: Duration,
) -> Result<ControlResponse, ControlError> {
    let spec = if mapper::model::is_builtin(model) {
        model.to_owned()
    } else {
        let p = Path::new(model);
        let abs = std::fs::canonicalize(p).map_err(|source| ControlError::ModelFile {
            model: model.to_owned(),
            source,
        })?;
        abs.display().to_string()
    };
    if spec.len() > ipc_types::control::TEXT_CAP {
        return Err(ControlError::ModelPathTooLong {
            spec,
            cap: ipc_types::control::TEXT_CAP,
        });
    }
    crate::require_graph(prefix)?;
    let graph = Graph::join(prefix, &format!("swap-{}", std::process::id()))?;
    let req = ControlRequest {
        kind: request_kind::SWAP,
        reserved: 0,
        path: Text::new(&spec),
    };
    Ok(graph.request(req, timeout)?)
}

/// The line `scl swap` prints for a swap that succeeded: the mappers, the switch tick, the
/// time it took, and the ticks missed meanwhile with the machine's share of them
/// (`held_up_during`, as `scl up --json` reports `held_up`) apart from the graph's own.
pub fn swap_line(r: &ControlResponse) -> String {
    let held_up = u64::from(r.held_up_during).min(r.missed_during);
    format!(
        "swapped: mapper {} -> {} at tick {}, {:.1} ms after the request, {} ticks missed \
         ({held_up} held up by the machine, {} the graph's own)",
        r.old_mapper,
        r.new_mapper,
        r.switch_tick,
        r.elapsed_ns as f64 / 1e6,
        r.missed_during,
        r.missed_during - held_up,
    )
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
) -> Result<Option<u32>, ControlError> {
    use ipc_types::control::{EstopCommand, estop_action};
    crate::require_graph(prefix)?;
    let graph = Graph::join_with(prefix, &format!("estop-{}", std::process::id()), transport)?;
    let status = graph.status_subscriber()?;
    let publisher = graph.estop_publisher()?;
    publisher
        .send(EstopCommand {
            t_ns: now_ns(),
            action,
            source_pid: std::process::id(),
        })
        .map_err(ControlError::SendEstop)?;
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
    /// The closest pair of the arm's collision model in safety's newest command.
    pub closest: Option<Closest>,
    /// What holds the arm on safety's side ([`safety_state_names`]): `e-stop latched`,
    /// `held by the supervisor`, `waiting for neutral input`; empty when nothing does.
    pub safety_state: Vec<String>,
}

/// The names of a safety heartbeat's [`ipc_types::safety_state`] bits, as `scl status`
/// shows them.
pub fn safety_state_names(bits: u32) -> Vec<String> {
    use ipc_types::safety_state;
    [
        (safety_state::ESTOP, "e-stop latched"),
        (safety_state::HOLD, "held by the supervisor"),
        (safety_state::AWAITING_NEUTRAL, "waiting for neutral input"),
    ]
    .into_iter()
    .filter(|(bit, _)| bits & bit != 0)
    .map(|(_, name)| name.to_owned())
    .collect()
}

/// The closest pair safety checked at one tick (`SafeCommand::closest_pair`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Closest {
    /// The tick of the command.
    pub tick: u64,
    /// The pair's name: `forearm-table`, `base-upper_wrist`, `gripper_base-fixture`.
    pub pair: String,
    /// Its distance (m).
    pub distance_m: f64,
    /// The tool's commanded speed (m/s).
    pub tcp_speed_m_s: f64,
}

impl Closest {
    /// The closest pair of a command, its boxes named by `box_names` (`[safety.scene]`, in
    /// order); `None` if safety checked nothing.
    pub fn of(c: &SafeCommand, box_names: &[String]) -> Option<Self> {
        if !c.clearance_m.is_finite() {
            return None;
        }
        Some(Self {
            tick: c.tick,
            pair: safety::scene::pair_name(c.closest_pair, box_names)?,
            distance_m: c.clearance_m,
            tcp_speed_m_s: c.tcp_speed_m_s,
        })
    }

    /// `closest: forearm-table 0.043 m`, as `scl status` and `scl top` print it.
    pub fn text(&self) -> String {
        format!("closest: {} {:.3} m", self.pair, self.distance_m)
    }
}

/// Reads the heartbeats of graph `prefix` for `listen`, and safety's newest command for the
/// closest pair (its scene's boxes named by `box_names`).
pub fn status(
    prefix: &Prefix,
    transport: ipc_types::Transport,
    listen: Duration,
    box_names: &[String],
) -> Result<GraphStatus, ControlError> {
    crate::require_graph(prefix)?;
    let me = format!("status-{}", std::process::id());
    let graph = Graph::join_with(prefix, &me, transport)?;
    let sub = graph.status_subscriber()?;
    let commands = graph.safe_command_subscriber(false)?;
    let mut newest: Option<SafeCommand> = None;
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
        commands.drain(|c| {
            if newest.is_none_or(|n| c.tick >= n.tick) {
                newest = Some(*c);
            }
        })?;
        std::thread::sleep(Duration::from_millis(10));
    }
    let alive = graph.alive_nodes();
    let mut st = status_from_heartbeats(prefix.as_str(), latest, alive, &me, now_ns());
    st.closest = newest.and_then(|c| Closest::of(&c, box_names));
    Ok(st)
}

/// The graph as `scl status` shows it, from the newest heartbeat of each node (`latest`),
/// the graph's live iceoryx2 nodes (`alive`: name and pid; `me`, the asking process, is left
/// out) at monotonic time `now`: a pure function, so what `scl status` prints is testable
/// without a graph.
pub fn status_from_heartbeats(
    prefix: &str,
    mut latest: Vec<NodeStatus>,
    alive: Vec<(String, u32)>,
    me: &str,
    now: u64,
) -> GraphStatus {
    latest.sort_by_key(|s| (s.role, s.mapper_id, s.pid));
    let mut out = GraphStatus {
        prefix: prefix.to_owned(),
        nodes: Vec::new(),
        other_nodes: Vec::new(),
        active_mapper: None,
        bridge_latency_us: None,
        joint_travel_rad: None,
        safety_state: Vec::new(),
        closest: None,
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
                Some(NodeRole::Safety) => {
                    out.active_mapper = Some(s.mapper_id);
                    out.safety_state = safety_state_names(s.safety_state);
                }
                Some(NodeRole::Bridge) => {
                    out.bridge_latency_us = Some(s.latency_ns as f64 / 1e3);
                    out.joint_travel_rad = Some(s.joint_travel_rad);
                }
                _ => {}
            }
        }
        out.nodes.push(row);
    }
    // A process's log publisher (`<process>-log`, `node_rt::log`) is that process, not
    // another node.
    out.other_nodes = alive
        .into_iter()
        .filter(|(name, pid)| {
            *name != me && !name.ends_with("-log") && !latest.iter().any(|s| s.pid == *pid)
        })
        .collect();
    out
}

pub use mapper::modeswitch::status_mode_name as mode_name;

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
    if !st.safety_state.is_empty() {
        let _ = writeln!(s, "safety: {}", st.safety_state.join(", "));
    }
    if let (Some(l), Some(t)) = (st.bridge_latency_us, st.joint_travel_rad) {
        let _ = writeln!(
            s,
            "bridge: last end-to-end latency {l:.1} µs, joint travel {t:.3} rad"
        );
    }
    if let Some(c) = &st.closest {
        let _ = writeln!(
            s,
            "safety: {} (tick {}), tool {:.3} m/s",
            c.text(),
            c.tick,
            c.tcp_speed_m_s
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::safe_flags;

    #[test]
    fn the_swap_line_counts_the_machines_misses_apart() {
        let r = ControlResponse {
            ok: 1,
            new_mapper: 3,
            old_mapper: 2,
            held_up_during: 9,
            switch_tick: 1200,
            elapsed_ns: 412_300_000,
            missed_during: 10,
            message: Text::new("switched"),
        };
        assert_eq!(
            swap_line(&r),
            "swapped: mapper 2 -> 3 at tick 1200, 412.3 ms after the request, 10 ticks missed \
             (9 held up by the machine, 1 the graph's own)"
        );
        // The machine's share is never more than the misses (a late command's verdict comes
        // a tick after its miss).
        let r = ControlResponse {
            held_up_during: 4,
            missed_during: 2,
            ..r
        };
        assert!(
            swap_line(&r).ends_with("2 ticks missed (2 held up by the machine, 0 the graph's own)")
        );
    }

    fn hb(role: NodeRole, pid: u32, mapper_id: u32, t_ms: u64) -> NodeStatus {
        let mut s = NodeStatus::new(role, phase::RUNNING, t_ms * 1_000_000);
        s.pid = pid;
        s.mapper_id = mapper_id;
        s.tick = 400;
        s.handled = 400;
        s
    }

    /// A running graph with a mode-switching mapper (z-yaw after 3 switches), a PCA mapper
    /// without modes, and a safety whose rules acted.
    fn graph() -> GraphStatus {
        let mut mapper = hb(NodeRole::Mapper, 2001, 1, 990);
        mapper.mode = 2;
        mapper.mode_switches = 3;
        let pca = hb(NodeRole::Mapper, 2002, 2, 990);
        let mut safety = hb(NodeRole::Safety, 2003, 1, 995);
        safety.rule_counts[safe_flags::NAMES
            .iter()
            .position(|n| *n == "velocity")
            .unwrap()] = 120;
        safety.rule_counts[safe_flags::NAMES.iter().position(|n| *n == "stop").unwrap()] = 7;
        let mut bridge = hb(NodeRole::Bridge, 2004, 1, 998);
        bridge.latency_ns = 85_500;
        bridge.joint_travel_rad = 1.25;
        let alive = [2001, 2002, 2003, 2004, 2005, 2006]
            .into_iter()
            .map(|p| (format!("node-{p}"), p))
            .chain([("status-1".to_owned(), 1)])
            .collect();
        status_from_heartbeats(
            "lab2",
            vec![bridge, safety, pca, mapper],
            alive,
            "status-1",
            1_000_000_000,
        )
    }

    #[test]
    fn status_shows_the_mode_its_switches_and_the_rules_that_acted() {
        let st = graph();
        assert_eq!(st.active_mapper, Some(1));
        assert_eq!(st.bridge_latency_us, Some(85.5));
        let text = render(&st);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0], "graph `lab2`: 4 of 4 nodes alive, active mapper 1",
            "{text}"
        );
        // Rows by role: mappers, safety, bridge.
        let roles: Vec<&str> = lines[2..6]
            .iter()
            .map(|l| l.split_whitespace().next().unwrap())
            .collect();
        assert_eq!(roles, ["mapper", "mapper", "safety", "bridge"], "{text}");
        assert!(lines.iter().all(|l| !l.contains("gone")), "{text}");
        // The mode-switching mapper's mode and switch count; none for the map without modes.
        assert!(
            text.contains("mapper 1 (pid 2001): mode z-yaw, 3 mode switches"),
            "{text}"
        );
        assert!(!text.contains("(pid 2002): mode"), "{text}");
        // The safety rules that acted, with their counts (the others are left out).
        assert!(
            text.contains("safety (pid 2003) rules acted: velocity 120, stop 7\n"),
            "{text}"
        );
        assert_eq!(text.matches("rules acted").count(), 1, "{text}");
        // Live nodes without heartbeats (supervisor, observers), but not the asker.
        assert!(
            text.contains("node-2005     2005   (no heartbeat"),
            "{text}"
        );
        assert!(!text.contains("status-1"), "{text}");
        assert!(
            text.contains("last end-to-end latency 85.5 µs, joint travel 1.250 rad"),
            "{text}"
        );
        // Nothing holds the arm: no safety line.
        assert!(
            st.safety_state.is_empty() && !text.contains("safety:"),
            "{text}"
        );
    }

    #[test]
    fn status_says_when_safety_waits_for_neutral_input() {
        use ipc_types::safety_state;
        let mut safety = hb(NodeRole::Safety, 3001, 1, 100);
        safety.safety_state = safety_state::AWAITING_NEUTRAL;
        let alive = vec![("s".to_owned(), 3001)];
        let st = status_from_heartbeats("g", vec![safety], alive.clone(), "me", 100_000_000);
        assert_eq!(st.safety_state, ["waiting for neutral input"]);
        assert!(
            render(&st).contains("\nsafety: waiting for neutral input\n"),
            "{}",
            render(&st)
        );
        safety.safety_state = safety_state::ESTOP | safety_state::AWAITING_NEUTRAL;
        let st = status_from_heartbeats("g", vec![safety], alive, "me", 100_000_000);
        assert!(render(&st).contains("safety: e-stop latched, waiting for neutral input"));
        // The JSON form carries the same names.
        let json = serde_json::to_value(&st).unwrap();
        assert_eq!(json["safety_state"][1], "waiting for neutral input");
    }

    #[test]
    fn status_names_the_closest_pair() {
        let mut st = graph();
        assert!(!render(&st).contains("closest"));
        let mut c = SafeCommand {
            tick: 400,
            mapper_id: 1,
            n_joints: 6,
            clearance_m: 0.0431,
            tcp_speed_m_s: 0.12,
            // forearm_link[1] / table
            closest_pair: [0x0301, 0xFF00],
            ..SafeCommand::zeroed()
        };
        st.closest = Closest::of(&c, &[]);
        assert!(
            render(&st)
                .contains("safety: closest: forearm-table 0.043 m (tick 400), tool 0.120 m/s\n"),
            "{}",
            render(&st)
        );
        // A box by its name from the scene.
        c.closest_pair = [0x0600, 0xFE01];
        let names = ["mount".to_owned(), "fixture".to_owned()];
        assert_eq!(
            Closest::of(&c, &names).unwrap().text(),
            "closest: gripper_base-fixture 0.043 m"
        );
        // Nothing checked: no line.
        c.clearance_m = f64::INFINITY;
        c.closest_pair = [0xFFFF; 2];
        assert_eq!(Closest::of(&c, &names), None);
    }

    #[test]
    fn a_stale_or_dead_node_is_gone_and_names_no_active_mapper() {
        let safety = hb(NodeRole::Safety, 3001, 4, 0);
        // Heartbeat 1 s old: gone, so no active mapper.
        let st = status_from_heartbeats(
            "g",
            vec![safety],
            vec![("s".into(), 3001)],
            "me",
            1e9 as u64,
        );
        assert_eq!(st.active_mapper, None);
        assert!(render(&st).contains("gone"));
        // Fresh, but its process is no longer a node of the graph: gone too.
        let st = status_from_heartbeats("g", vec![safety], vec![], "me", 100_000_000);
        assert_eq!(st.active_mapper, None);
        // Fresh and listed: alive.
        let st = status_from_heartbeats(
            "g",
            vec![safety],
            vec![("s".into(), 3001)],
            "me",
            100_000_000,
        );
        assert_eq!(st.active_mapper, Some(4));
    }

    #[test]
    fn mode_names_follow_the_mode_switching_map() {
        assert_eq!(mode_name(1), "x-y");
        assert_eq!(mode_name(2), "z-yaw");
        assert_eq!(mode_name(3), "roll-pitch");
        assert_eq!(mode_name(9), "mode 8");
    }
}
