//! The safety process: wakes on mapper commands, forwards the active mapper's command for the
//! newest tick through the filter, as the one publisher of `SafeCommand`. Switches of the
//! active mapper arrive on the safety-control topic and take effect at their tick.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

/// Why the safety process stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum SafetyNodeError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The graph or the process failed (a child died, a thread did not start, ...).
    #[error("{0}")]
    Graph(String),
}

use std::time::Duration;

use ipc_types::{NO_TICK, NodeRole, NodeStatus, Prefix, phase, time::now_ns};
use safety::{SafetyConfig, SafetyFilter};
use transport::Graph;

use scl_config::{FaultConfig, GraphSection, RtRole};
use transport::signals;

/// Without a command for this long (ns) the graph has stopped sending them: the arm will
/// wait for neutral input when they resume (safety's own gap check says so too, at the next
/// command; this only shows it meanwhile in the heartbeat).
const NO_COMMANDS_NS: u64 = 100_000_000;

/// The names of the rules set in `flags`, comma-separated.
fn rule_names(flags: u32) -> String {
    ipc_types::safe_flags::NAMES
        .iter()
        .enumerate()
        .filter(|(bit, _)| flags & (1 << bit) != 0)
        .map(|(_, n)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

fn safety_state_bits(f: &SafetyFilter) -> u32 {
    let mut bits = 0;
    if f.estopped() {
        bits |= ipc_types::safety_state::ESTOP;
    }
    if f.held() {
        bits |= ipc_types::safety_state::HOLD;
    }
    if f.awaiting_neutral() {
        bits |= ipc_types::safety_state::AWAITING_NEUTRAL;
    }
    bits
}

/// Runs the safety process until a shutdown is requested.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    cfg: &SafetyConfig,
    faults: &FaultConfig,
    period_s: f64,
) -> Result<(), SafetyNodeError> {
    let robot = graph_cfg.profile()?;
    // The workspace rule if enabled, every link against the others and the scene, and the
    // Cartesian speed caps.
    let mut filter = SafetyFilter::for_graph(cfg.clone(), robot, period_s)
        .map_err(|e| SafetyNodeError::Graph(format!("config: {e}")))?;
    let graph = Graph::join_with(prefix, "safety", graph_cfg.transport)?;
    let commands = graph.mapper_command_subscriber(true)?;
    let states = graph.robot_state_subscriber(false)?;
    let control = graph.safety_control_subscriber()?;
    let estops = graph.estop_subscriber()?;
    // Fails if another safety process already publishes: the arm listens to one only.
    let out = graph.safe_command_publisher()?;
    let status = graph.status_publisher()?;
    let mut st = NodeStatus::new(NodeRole::Safety, phase::READY, now_ns());
    // A restarted safety learns the active mapper from the topic's history.
    let mut estop_seq = 0;
    let mut apply_control = |filter: &mut SafetyFilter| -> Result<(), SafetyNodeError> {
        while let Some(c) = control.receive().map_err(|e| {
            SafetyNodeError::Ipc(transport::IpcError::Io {
                service: prefix.service(ipc_types::control::SAFETY_CONTROL),
                op: "receive",
                source: e.into(),
            })
        })? {
            tracing::info!(
                mapper = c.active_mapper,
                from_tick = c.from_tick,
                hold = c.hold,
                "control from the supervisor"
            );
            filter.request_switch(c.active_mapper, c.from_tick);
            filter.set_hold(c.hold != 0);
            if c.estop_seq != estop_seq {
                estop_seq = c.estop_seq;
                if c.estop != 0 {
                    tracing::warn!("E-STOP latched (relayed by the supervisor)");
                    filter.estop();
                } else {
                    filter.reset();
                }
            }
        }
        Ok(())
    };
    let apply_estop = |filter: &mut SafetyFilter| -> Result<(), SafetyNodeError> {
        while let Some(e) = estops.receive().map_err(|e| {
            SafetyNodeError::Ipc(transport::IpcError::Io {
                service: prefix.service(ipc_types::control::ESTOP),
                op: "receive",
                source: e.into(),
            })
        })? {
            match e.action {
                ipc_types::control::estop_action::ESTOP => {
                    tracing::warn!(from_pid = e.source_pid, "E-STOP latched");
                    filter.estop();
                }
                ipc_types::control::estop_action::RESET => {
                    tracing::info!(from_pid = e.source_pid, "e-stop reset");
                    filter.reset();
                }
                other => tracing::warn!(action = other, "unknown e-stop action ignored"),
            }
        }
        Ok(())
    };
    apply_control(&mut filter)?;
    apply_estop(&mut filter)?;
    node_rt::rt::elevate(graph_cfg, RtRole::Safety);
    st.mapper_id = filter.active_for_tick(0);
    // At start-up too the arm waits for neutral input (restart prevention).
    st.safety_state = safety_state_bits(&filter);
    status.send(st)?;
    tracing::info!(
        active_mapper = st.mapper_id,
        "forwarding to {}",
        out.service()
    );
    st.phase = phase::RUNNING;
    let mut state = None;
    let mut last_tick = NO_TICK;
    let mut last_stop_flags = 0;
    let mut last_step_ns = now_ns();
    while !signals::stop_requested() {
        let woke = commands.wait(Duration::from_millis(100))?;
        let rx_ns = now_ns();
        apply_control(&mut filter)?;
        apply_estop(&mut filter)?;
        if !woke {
            // No commands (no mapper, no ticks): still say what state safety is in, so
            // `scl estop` can confirm and `scl status` shows it alive, and, after 100 ms
            // without a command, that the arm will wait for neutral input when they resume
            // (a wait can also end without one: a signal, another mapper joining).
            if rx_ns.saturating_sub(last_step_ns) > NO_COMMANDS_NS {
                filter.interrupt();
            }
            st.t_ns = now_ns();
            st.safety_state = safety_state_bits(&filter);
            status.send(st)?;
            continue;
        }
        if let Some(s) = states.latest()? {
            state = Some(s);
        }
        let Some(state) = state else {
            continue;
        };
        let active = filter.active_for_tick(state.tick);
        let mut pending = None;
        commands.drain(|c| {
            if c.mapper_id == active && c.tick == state.tick {
                pending = Some(*c);
            }
        })?;
        let Some(cmd) = pending else {
            continue;
        };
        if cmd.tick == last_tick {
            continue;
        }
        last_tick = cmd.tick;
        if faults.safety_stall_at_tick != 0 && cmd.tick == faults.safety_stall_at_tick {
            tracing::warn!(tick = cmd.tick, "fault injection: safety stalls");
            std::thread::sleep(Duration::from_secs_f64(1.2 * period_s));
        }
        let t0 = now_ns();
        last_step_ns = t0;
        let mut safe = filter.step(&cmd, &state, t0);
        // One reading for both, so `t_ns - compute_ns` is the filter's time argument exactly
        // (a recording replays the step with it).
        let t1 = now_ns();
        safe.mapper_rx_ns = rx_ns;
        safe.compute_ns = t1 - t0;
        safe.t_ns = t1;
        out.send(safe)?;
        st.t_ns = safe.t_ns;
        st.tick = safe.tick;
        st.handled += 1;
        st.mapper_id = active;
        st.rule_counts = filter.rule_counts();
        let was_awaiting = st.safety_state & ipc_types::safety_state::AWAITING_NEUTRAL != 0;
        st.safety_state = safety_state_bits(&filter);
        if safe.flags & ipc_types::safe_flags::STOP != 0 {
            st.faults += 1;
        }
        if filter.awaiting_neutral() != was_awaiting {
            if was_awaiting {
                tracing::info!(tick = safe.tick, "neutral input seen: motion allowed again");
            } else {
                tracing::warn!(
                    tick = safe.tick,
                    "waiting for neutral input: the arm moves again once the stick is at rest{}",
                    if cfg.deadman {
                        " and the deadman released and pressed again"
                    } else {
                        ""
                    }
                );
            }
        }
        // Say when the set of stop reasons changes, not every tick of a stop.
        let stop_flags = if safe.flags & ipc_types::safe_flags::STOP != 0 {
            safe.flags
        } else {
            0
        };
        if stop_flags != last_stop_flags {
            if stop_flags != 0 {
                tracing::warn!(tick = safe.tick, rules = %rule_names(stop_flags), "stopping the arm");
            } else {
                tracing::info!(tick = safe.tick, "stop cleared");
            }
            last_stop_flags = stop_flags;
        }
        status.send(st)?;
    }
    st.phase = phase::STOPPING;
    st.t_ns = now_ns();
    status.send(st)?;
    Ok(())
}
