//! The safety process: wakes on mapper commands, forwards the active mapper's command for the
//! newest tick through the filter, as the one publisher of `SafeCommand`.

use std::time::Duration;

use ipc_types::{Graph, NO_TICK, NodeRole, NodeStatus, Prefix, phase, time::now_ns};
use safety::{SafetyConfig, SafetyFilter};

use crate::{SclError, signals};

/// Runs the safety process until a shutdown is requested.
pub fn run(prefix: &Prefix, cfg: &SafetyConfig) -> Result<(), SclError> {
    let filter = SafetyFilter::new(cfg.clone(), kinematics::gen3_lite::N_JOINTS)
        .map_err(|e| SclError::Graph(format!("config: {e}")))?;
    let graph = Graph::join(prefix, "safety")?;
    let commands = graph.mapper_command_subscriber(true)?;
    let states = graph.robot_state_subscriber(false)?;
    // Fails if another safety process already publishes: the arm listens to one only.
    let out = graph.safe_command_publisher()?;
    let status = graph.status_publisher()?;
    let mut st = NodeStatus::new(NodeRole::Safety, phase::READY, now_ns());
    st.mapper_id = cfg.active_mapper;
    status.send(st)?;
    tracing::info!(
        active_mapper = cfg.active_mapper,
        "forwarding to {}",
        out.service()
    );
    st.phase = phase::RUNNING;
    let mut state = None;
    let mut last_tick = NO_TICK;
    while !signals::stop_requested() {
        if !commands.wait(Duration::from_millis(100))? {
            continue;
        }
        if let Some(s) = states.latest()? {
            state = Some(s);
        }
        let Some(state) = state else {
            continue;
        };
        let mut pending = None;
        commands.drain(|c| {
            if filter.is_active(c.mapper_id) && c.tick == state.tick {
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
        let t0 = now_ns();
        let mut safe = filter.step(&cmd, &state, t0);
        safe.compute_ns = now_ns() - t0;
        safe.t_ns = now_ns();
        out.send(safe)?;
        st.t_ns = safe.t_ns;
        st.tick = safe.tick;
        st.handled += 1;
        if safe.flags & ipc_types::safe_flags::STOP != 0 {
            st.faults += 1;
            tracing::warn!(
                tick = safe.tick,
                flags = format!("{:#x}", safe.flags),
                "stop"
            );
        }
        status.send(st)?;
    }
    st.phase = phase::STOPPING;
    st.t_ns = now_ns();
    status.send(st)?;
    Ok(())
}
