//! The mapper process: wakes on each robot state, maps the newest joystick sample through the
//! model, publishes the command for that tick.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

/// Why the mapper process stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum MapperNodeError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] mapper::ModelError),
}

use std::time::Duration;

use ipc_types::{NodeRole, NodeStatus, Prefix, phase, time::now_ns};
use mapper::step::MapperStep;
use transport::Graph;

use scl_config::{FaultConfig, GraphSection, RtRole};
use transport::signals;

/// Runs the mapper process until a shutdown is requested.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    faults: &FaultConfig,
    model: &str,
    id: u32,
) -> Result<(), MapperNodeError> {
    let mut step = MapperStep::load(model, id, graph_cfg.profile()?, graph_cfg.period_s())?;
    let graph = Graph::join_with(prefix, &format!("mapper-{id}"), graph_cfg.transport)?;
    let states = graph.robot_state_subscriber(true)?;
    let joystick = graph.joystick_subscriber(true)?;
    let commands = graph.mapper_command_publisher()?;
    let status = graph.status_publisher()?;
    // Initialised at normal priority (a mapper starting for a live swap must not compete
    // with the running one); real-time from here on.
    node_rt::rt::elevate(graph_cfg, RtRole::Mapper);
    let mut st = NodeStatus::new(NodeRole::Mapper, phase::READY, now_ns());
    st.mapper_id = id;
    set_mode(&mut st, &step);
    status.send(st)?;
    let h = &step.model().header;
    tracing::info!(
        id,
        kind = %h.kind,
        model = %step.model().source,
        speed_scale_rad_s = h.speed_scale_rad_s,
        "serving"
    );
    st.phase = phase::RUNNING;
    // The newest joystick sample and when it arrived; samples are taken as they come (the
    // joystick publishes on change), the map runs on each robot state.
    let mut joy = None;
    let mut joy_rx_ns = 0;
    let wakes: [&dyn transport::graph::Wakeable; 2] = [&states, &joystick];
    // `rt_prewarm_us`: wake that long before the next state (the last one's time plus a
    // period) and warm the map once; a state or sample arriving meanwhile is handled as usual.
    let prewarm_ns = u64::from(graph_cfg.rt_prewarm_us) * 1000;
    let period_ns = (graph_cfg.period_s() * 1e9).round() as u64;
    let mut last: Option<ipc_types::RobotState> = None;
    let mut warm_out = [0.0f64; ipc_types::MAX_JOINTS];
    if prewarm_ns > 0 {
        tracing::info!(
            prewarm_us = graph_cfg.rt_prewarm_us,
            "warming the map before each tick"
        );
    }
    while !signals::stop_requested() {
        let mut woke_pre = None;
        if prewarm_ns > 0
            && let Some(l) = &last
        {
            let at = l.t_ns + period_ns - prewarm_ns;
            let now = now_ns();
            if now < at {
                let w = transport::wait_any(&wakes, Duration::from_nanos(at - now));
                if w == 0 {
                    let n = (l.n_joints as usize).min(ipc_types::MAX_JOINTS);
                    step.warm(l, &mut warm_out[..n]);
                    last = None;
                    continue;
                }
                woke_pre = Some(w);
            }
        }
        let woke = match woke_pre {
            Some(w) => w,
            None => transport::wait_any(&wakes, Duration::from_millis(100)),
        };
        let rx_ns = now_ns();
        if let Some(j) = joystick.latest()? {
            joy = Some(j);
            joy_rx_ns = rx_ns;
        }
        if woke & 1 == 0 {
            continue;
        }
        let Some(state) = states.latest()? else {
            continue;
        };
        last = Some(state);
        let t0 = now_ns();
        let mut cmd = step.step(&state, joy.as_ref());
        let t1 = now_ns();
        cmd.compute_ns = t1 - t0;
        cmd.state_rx_ns = rx_ns;
        cmd.joystick_rx_ns = if joy.is_some() { joy_rx_ns } else { 0 };
        if faults.mapper_nan_at_tick != 0 && state.tick == faults.mapper_nan_at_tick {
            tracing::warn!(tick = state.tick, "fault injection: a NaN velocity");
            cmd.qdot_rad_s[0] = f64::NAN;
        }
        cmd.t_ns = now_ns();
        commands.send(cmd)?;
        st.t_ns = cmd.t_ns;
        st.tick = state.tick;
        st.handled += 1;
        if cmd.flags != 0 {
            st.faults += 1;
        }
        if set_mode(&mut st, &step) {
            tracing::info!(
                id,
                tick = state.tick,
                mode = step.mode().map_or("-", |m| m.name),
                switches = st.mode_switches,
                "mode switch"
            );
        }
        status.send(st)?;
    }
    st.phase = phase::STOPPING;
    st.t_ns = now_ns();
    status.send(st)?;
    Ok(())
}

/// Copies the map's mode into the heartbeat (see [`NodeStatus::mode`]); returns whether the
/// switch count changed.
fn set_mode(st: &mut NodeStatus, step: &MapperStep) -> bool {
    let Some(m) = step.mode() else {
        return false;
    };
    let changed = st.mode_switches != m.switches;
    st.mode = m.index + 1;
    st.mode_switches = m.switches;
    changed
}
