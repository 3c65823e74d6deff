//! The safety process: wakes on mapper commands, forwards the active mapper's command for the
//! newest tick through the filter, as the one publisher of `SafeCommand`. Switches of the
//! active mapper arrive on the safety-control topic and take effect at their tick.

use std::time::Duration;

use ipc_types::{Graph, NO_TICK, NodeRole, NodeStatus, Prefix, phase, time::now_ns};
use safety::{SafetyConfig, SafetyFilter};

use crate::config::{GraphSection, RtRole};
use crate::{SclError, signals};

/// Runs the safety process until a shutdown is requested.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    cfg: &SafetyConfig,
    period_s: f64,
) -> Result<(), SclError> {
    let mut filter = SafetyFilter::new(cfg.clone(), kinematics::gen3_lite::N_JOINTS, period_s)
        .map_err(|e| SclError::Graph(format!("config: {e}")))?;
    let graph = Graph::join(prefix, "safety")?;
    let commands = graph.mapper_command_subscriber(true)?;
    let states = graph.robot_state_subscriber(false)?;
    let control = graph.safety_control_subscriber()?;
    // Fails if another safety process already publishes: the arm listens to one only.
    let out = graph.safe_command_publisher()?;
    let status = graph.status_publisher()?;
    let mut st = NodeStatus::new(NodeRole::Safety, phase::READY, now_ns());
    // A restarted safety learns the active mapper from the topic's history.
    let apply_control = |filter: &mut SafetyFilter| -> Result<(), SclError> {
        while let Some(c) = control.receive().map_err(|e| {
            SclError::Ipc(ipc_types::IpcError::Io {
                service: prefix.service(ipc_types::control::SAFETY_CONTROL),
                op: "receive",
                reason: e.to_string(),
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
        }
        Ok(())
    };
    apply_control(&mut filter)?;
    crate::rt::elevate(graph_cfg, RtRole::Safety);
    st.mapper_id = filter.active_for_tick(0);
    status.send(st)?;
    tracing::info!(
        active_mapper = st.mapper_id,
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
        apply_control(&mut filter)?;
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
        let t0 = now_ns();
        let mut safe = filter.step(&cmd, &state, t0);
        safe.compute_ns = now_ns() - t0;
        safe.t_ns = now_ns();
        out.send(safe)?;
        st.t_ns = safe.t_ns;
        st.tick = safe.tick;
        st.handled += 1;
        st.mapper_id = active;
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
