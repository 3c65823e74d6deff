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

use ipc_types::{
    JoystickInput, MapperCommand, NodeRole, NodeStatus, Prefix, RobotState, time::now_ns,
};
use mapper::step::MapperStep;
use node_rt::node::{Heartbeat, Node, Turn};
use node_rt::poller::{Polled, Poller, TickStart};
use transport::{Graph, TopicPublisher, TopicSubscriber};

use scl_config::{FaultConfig, GraphSection, RtRole};

/// Runs the mapper process until a shutdown is requested.
///
/// Each turn of the loop: wait for a state or a joystick sample (or, with `rt_prewarm_us`,
/// warm the map just before the next state is due), take the newest sample, and on a new
/// state map it and publish the command, then the heartbeat.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    faults: &FaultConfig,
    model: &str,
    id: u32,
) -> Result<(), MapperNodeError> {
    let step = MapperStep::load(model, id, graph_cfg.profile()?, graph_cfg.period_s())?;
    let graph = Graph::join_with(prefix, &format!("mapper-{id}"), graph_cfg.transport)?;
    let states = graph.robot_state_subscriber(true)?;
    let joystick = graph.joystick_subscriber(true)?;
    let commands = graph.mapper_command_publisher()?;
    let status = graph.status_publisher()?;
    let wait = node_rt::wait::strategy_of(graph_cfg, RtRole::Mapper, "mapper")?;
    // Initialised at normal priority (a mapper starting for a live swap must not compete
    // with the running one); real-time from here on.
    node_rt::rt::elevate(graph_cfg, RtRole::Mapper);
    let heartbeat = Heartbeat::ready(&status, NodeRole::Mapper, |st| {
        st.mapper_id = id;
        set_mode(st, &step);
    })?;
    say_serving(&step, id);
    let mut node = Mapper {
        step,
        states,
        joystick,
        commands,
        joy: None,
        joy_rx_ns: 0,
        prewarm: Prewarm::new(graph_cfg),
        // Polls for the state before the event wait (`spin`: also for joystick samples).
        poller: Poller::new(wait, graph_cfg.period_ns()).with_early_arrival(),
        faults,
        id,
    };
    node_rt::node::run(&mut node, heartbeat)?;
    Ok(())
}

/// The mapper's loop: its topics, the map and the newest joystick sample.
struct Mapper<'a> {
    step: MapperStep,
    states: TopicSubscriber<RobotState>,
    joystick: TopicSubscriber<JoystickInput>,
    commands: TopicPublisher<MapperCommand>,
    /// The newest joystick sample and when it arrived; samples are taken as they come (the
    /// joystick publishes on change), the map runs on each robot state.
    joy: Option<JoystickInput>,
    joy_rx_ns: u64,
    prewarm: Prewarm,
    poller: Poller,
    faults: &'a FaultConfig,
    id: u32,
}

impl Node for Mapper<'_> {
    type Error = MapperNodeError;

    fn step(&mut self, st: &mut NodeStatus) -> Result<Turn, MapperNodeError> {
        let polled = self.poller.poll(
            TickStart::Grid,
            now_ns() + 100_000_000,
            &self.states,
            Some(&self.joystick),
        );
        let woke = match polled {
            Polled::Came(bits) => Some(bits),
            _ => {
                let wakes: [&dyn transport::graph::Wakeable; 2] = [&self.states, &self.joystick];
                self.prewarm.wait(&wakes, &mut self.step)
            }
        };
        let Some(woke) = woke else {
            return Ok(Turn::Quiet);
        };
        let rx_ns = now_ns();
        if let Some(j) = self.joystick.latest()? {
            self.joy = Some(j);
            self.joy_rx_ns = rx_ns;
        }
        if woke & 1 == 0 {
            return Ok(Turn::Quiet);
        }
        let Some(state) = self.states.latest()? else {
            return Ok(Turn::Quiet);
        };
        self.prewarm.last = Some(state);
        // A state carries no stamp of its publication (its `t_ns` is its tick's start): its
        // arrival is the time it was taken, exact when polled.
        self.poller.took(state.tick, state.t_ns, rx_ns);
        let joy_rx = if self.joy.is_some() {
            self.joy_rx_ns
        } else {
            0
        };
        let cmd = map_state(
            &mut self.step,
            &state,
            self.joy.as_ref(),
            rx_ns,
            joy_rx,
            self.faults,
        );
        self.commands.send(cmd)?;
        count_tick(st, &self.step, &cmd, state.tick, self.id);
        Ok(Turn::Beat)
    }

    fn finish(&mut self, _: &mut NodeStatus) -> Result<(), MapperNodeError> {
        self.poller.log("mapper");
        Ok(())
    }
}

/// Says which model the mapper serves.
fn say_serving(step: &MapperStep, id: u32) {
    let h = &step.model().header;
    tracing::info!(
        id,
        kind = %h.kind,
        model = %step.model().source,
        speed_scale_rad_s = h.speed_scale_rad_s,
        "serving"
    );
}

/// `rt_prewarm_us`: wake that long before the next state (the last one's time plus a
/// period) and warm the map once; a state or sample arriving meanwhile is handled as usual.
struct Prewarm {
    prewarm_ns: u64,
    period_ns: u64,
    /// The last state mapped, until the map has been warmed for the next one.
    last: Option<ipc_types::RobotState>,
    warm_out: [f64; ipc_types::MAX_JOINTS],
}

impl Prewarm {
    fn new(graph_cfg: &GraphSection) -> Self {
        let prewarm_ns = u64::from(graph_cfg.rt_prewarm_us) * 1000;
        if prewarm_ns > 0 {
            tracing::info!(
                prewarm_us = graph_cfg.rt_prewarm_us,
                "warming the map before each tick"
            );
        }
        Self {
            prewarm_ns,
            period_ns: (graph_cfg.period_s() * 1e9).round() as u64,
            last: None,
            warm_out: [0.0; ipc_types::MAX_JOINTS],
        }
    }

    /// Waits for a state or a joystick sample: the bits of [`transport::wait_any`], or `None`
    /// when the wait ended at the warm-up time and the map was warmed.
    fn wait(
        &mut self,
        wakes: &[&dyn transport::graph::Wakeable; 2],
        step: &mut MapperStep,
    ) -> Option<u64> {
        if self.prewarm_ns > 0
            && let Some(l) = &self.last
        {
            let at = l.t_ns + self.period_ns - self.prewarm_ns;
            let now = now_ns();
            if now < at {
                let w = transport::wait_any(wakes, Duration::from_nanos(at - now));
                if w == 0 {
                    let n = (l.n_joints as usize).min(ipc_types::MAX_JOINTS);
                    step.warm(l, &mut self.warm_out[..n]);
                    self.last = None;
                    return None;
                }
                return Some(w);
            }
        }
        Some(transport::wait_any(wakes, Duration::from_millis(100)))
    }
}

/// Maps `state` with the newest joystick sample into the tick's command, stamped with its
/// compute time and arrival times (`mapper_nan_at_tick` injects its fault here).
fn map_state(
    step: &mut MapperStep,
    state: &ipc_types::RobotState,
    joy: Option<&ipc_types::JoystickInput>,
    rx_ns: u64,
    joy_rx_ns: u64,
    faults: &FaultConfig,
) -> ipc_types::MapperCommand {
    let t0 = now_ns();
    let mut cmd = step.step(state, joy);
    let t1 = now_ns();
    cmd.compute_ns = t1 - t0;
    cmd.state_rx_ns = rx_ns;
    cmd.joystick_rx_ns = joy_rx_ns;
    if faults.mapper_nan_at_tick != 0 && state.tick == faults.mapper_nan_at_tick {
        tracing::warn!(tick = state.tick, "fault injection: a NaN velocity");
        cmd.qdot_rad_s[0] = f64::NAN;
    }
    cmd.t_ns = now_ns();
    cmd
}

/// Counts a published command in the heartbeat `st` and says a mode switch.
fn count_tick(
    st: &mut NodeStatus,
    step: &MapperStep,
    cmd: &ipc_types::MapperCommand,
    tick: u64,
    id: u32,
) {
    st.t_ns = cmd.t_ns;
    st.tick = tick;
    st.handled += 1;
    if cmd.flags != 0 {
        st.faults += 1;
    }
    if set_mode(st, step) {
        tracing::info!(
            id,
            tick,
            mode = step.mode().map_or("-", |m| m.name),
            switches = st.mode_switches,
            "mode switch"
        );
    }
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
