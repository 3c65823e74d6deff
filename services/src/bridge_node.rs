//! The hardware bridge process: the graph's only clock.
//!
//! On every deadline of the absolute 40 Hz timer it publishes `RobotState(k)`, waits until
//! `command_deadline` into the period for `SafeCommand(k)`, and executes it; anything else is
//! a counted miss answered by a controlled stop. On shutdown it stops the arm first and
//! publishes a last state flagged `SHUTDOWN`.

use std::time::Duration;

use hw_bridge::clock::{Clock, Wake};
use hw_bridge::core::{BridgeCore, Outcome};
use hw_bridge::mock::MockArm;
use ipc_types::{
    Graph, NodeRole, NodeStatus, Prefix, SafeCommand, TickReport, phase, time::now_ns,
};

use crate::config::{BridgeConfig, FaultConfig, GraphSection, RtRole};
use crate::{SclError, signals};

/// Where a restarted bridge takes over (given by the supervisor from the last state its
/// predecessor published).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resume {
    /// The first tick to publish.
    pub start_tick: Option<u64>,
    /// The mock arm's pose and gripper state to start from.
    pub pose: Option<(Vec<f64>, f64)>,
}

/// Runs the bridge until a shutdown is requested.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    cfg: &BridgeConfig,
    faults: &FaultConfig,
    resume: &Resume,
) -> Result<(), SclError> {
    let mut robot =
        MockArm::new(cfg.mock.clone()).map_err(|e| SclError::Graph(format!("config: {e}")))?;
    if let Some((q, c)) = &resume.pose {
        robot.resume(q, *c);
    }
    let period_ns = (1e9 / cfg.rate_hz) as u64;
    let period_s = period_ns as f64 * 1e-9;
    let wait_ns = (period_ns as f64 * cfg.command_deadline) as u64;
    crate::rt::elevate(graph_cfg, RtRole::Bridge);
    let graph = Graph::join_with(prefix, "bridge", graph_cfg.transport)?;
    let states = graph.robot_state_publisher()?;
    let commands = graph.safe_command_subscriber(true)?;
    let status = graph.status_publisher()?;
    let reports = graph.tick_report_publisher()?;
    let mut core = BridgeCore::new(robot, period_s, cfg.stop_acceleration_rad_s2.clone());
    if let Some(t) = resume.start_tick {
        core.start_at(t);
        tracing::info!(
            start_tick = t,
            "resuming the graph's tick count from a stop"
        );
    }
    let mut st = NodeStatus::new(NodeRole::Bridge, phase::READY, now_ns());
    status.send(st)?;
    st.phase = phase::RUNNING;
    tracing::info!(rate_hz = cfg.rate_hz, robot = %cfg.robot, "ticking");

    let mut clock = Clock::new(now_ns() + period_ns, period_ns);
    // Drop whatever commands are left over from an earlier bridge of this graph.
    commands.drain(|_| {})?;
    while !signals::stop_requested() {
        let (ideal_ns, lateness_ns, skipped) = match clock.wait() {
            Wake::Interrupted => continue,
            Wake::Tick {
                ideal_ns,
                lateness_ns,
                skipped,
            } => (ideal_ns, lateness_ns, skipped),
        };
        if signals::stop_requested() {
            break;
        }
        if skipped > 0 {
            tracing::warn!(skipped, "the bridge was held up for more than a period");
            core.add_skipped(skipped);
        }
        let state = core.begin_tick(now_ns());
        let stop_after = faults.bridge_states_stop_after_ticks;
        if stop_after == 0 || st.handled < stop_after {
            states.send(state)?;
        } else if st.handled == stop_after {
            tracing::warn!(tick = state.tick, "fault injection: robot states stop");
        }

        let deadline = ideal_ns + wait_ns;
        let mut found: Option<SafeCommand> = None;
        let mut other: Option<SafeCommand> = None;
        let mut received_ns = 0;
        loop {
            commands.drain(|c| {
                if c.tick == state.tick {
                    found = Some(*c);
                } else {
                    other = Some(*c);
                }
            })?;
            let now = now_ns();
            if found.is_some() {
                received_ns = now;
                break;
            }
            if now >= deadline || signals::stop_requested() {
                break;
            }
            commands.wait(Duration::from_nanos(deadline - now))?;
        }
        let outcome = core.finish_tick(found.as_ref().or(other.as_ref()));
        st.latency_ns = match outcome {
            Outcome::Executed => received_ns - state.t_ns,
            Outcome::Missed(reason) => {
                if core.missed() <= 10 || core.missed().is_power_of_two() {
                    tracing::warn!(
                        tick = state.tick,
                        ?reason,
                        missed = core.missed(),
                        "missed tick: controlled stop"
                    );
                }
                0
            }
        };
        st.t_ns = now_ns();
        st.tick = state.tick;
        st.handled += 1;
        st.faults = core.missed();
        st.lateness_ns = lateness_ns;
        st.joint_travel_rad = core.joint_travel_rad();
        st.mapper_id = found.map_or(0, |c| c.mapper_id);
        status.send(st)?;
        let executed = matches!(outcome, Outcome::Executed);
        let c = found.filter(|_| executed);
        reports.send(TickReport {
            tick: state.tick,
            ideal_ns,
            lateness_ns,
            state_t_ns: state.t_ns,
            state_rx_ns: c.map_or(0, |c| c.state_rx_ns),
            joystick_t_ns: c.map_or(0, |c| c.joystick_t_ns),
            joystick_rx_ns: c.map_or(0, |c| c.joystick_rx_ns),
            mapper_t_ns: c.map_or(0, |c| c.mapper_t_ns),
            mapper_rx_ns: c.map_or(0, |c| c.mapper_rx_ns),
            safe_t_ns: c.map_or(0, |c| c.t_ns),
            safe_rx_ns: if executed { received_ns } else { 0 },
            mapper_compute_ns: c.map_or(0, |c| c.mapper_compute_ns),
            safety_compute_ns: c.map_or(0, |c| c.compute_ns),
            missed: core.missed(),
            executed: u32::from(executed),
            reserved: 0,
        })?;
    }
    // Stop the arm first, then say so.
    let last = core.shutdown(now_ns());
    states.send(last)?;
    st.phase = phase::STOPPING;
    st.t_ns = now_ns();
    st.latency_ns = 0;
    status.send(st)?;
    tracing::info!(
        ticks = st.handled,
        missed = core.missed(),
        signal = signals::signal(),
        "arm stopped; bridge exiting"
    );
    Ok(())
}
