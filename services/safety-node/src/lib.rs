//! The safety process: wakes on mapper commands, forwards the active mapper's command for the
//! newest tick through the filter, as the one publisher of `SafeCommand`. Switches of the
//! active mapper arrive on the safety-control topic and take effect at their tick.
//!
//! While the e-stop is latched, or when no mapper command has come for a period (a mapper
//! dead or restarting), it also wakes once per tick, [`ANSWER_AFTER`] of a period after each
//! robot state is due (the newest state's time plus whole periods); with the e-stop latched
//! it answers the state itself ([`SafetyFilter::step_unanswered`]: zero velocity) when no
//! command for its tick has come by then, so the e-stop acts at the next tick whether a
//! mapper is there or not. Other ticks without a command are left to the bridge, which
//! counts them missed and stops the arm under control.
//!
//! Safety does not listen on robot states: a listener is a wake-up the bridge pays on every
//! tick, and safety needs states only in those rare cases, when it reads them at times it
//! can compute (the whole-graph test `safety_does_not_listen_on_robot_states` keeps it so).
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
    /// `[safety]` does not fit the robot or the rate (the filter could not be built).
    #[error("config: {0}")]
    Filter(#[from] safety::ConfigError),
}

use std::time::Duration;

use ipc_types::control::{EstopCommand, SafetyControl, estop_action};
use ipc_types::{
    MapperCommand, NO_TICK, NodeRole, NodeStatus, Prefix, RobotState, SafeCommand, mapper_flags,
    safe_flags, safety_state, time::now_ns,
};
use node_rt::node::{Heartbeat, Node, Turn};
use node_rt::poller::{Poller, TickStart};
use safety::{SafetyConfig, SafetyFilter};
use transport::control::{EstopSubscriber, SafetyControlSubscriber};
use transport::{Graph, TopicPublisher, TopicSubscriber};

use scl_config::{FaultConfig, GraphSection, RtRole};

/// Without a command for this long (ns) the graph has stopped sending them: the arm will
/// wait for neutral input when they resume (safety's own gap check says so too, at the next
/// command; this only shows it meanwhile in the heartbeat).
const NO_COMMANDS_NS: u64 = 100_000_000;

/// With the e-stop latched, safety answers a robot state itself when no mapper command for
/// its tick has come this share of a period after the state was published: well before the
/// bridge's command deadline (`[bridge] command_deadline`, 0.6 of the period by default).
pub const ANSWER_AFTER: f64 = 0.25;

/// The stop reasons of a normal start: no usable joystick sample yet (stale), the deadman not
/// yet pressed, the wait for neutral input, and the stop's own flags. Until the arm is first
/// allowed to move, a stop for these alone is the start, logged as information, not a fault.
const START_REASONS: u32 = safe_flags::STOP
    | safe_flags::STALE_JOYSTICK
    | safe_flags::DEADMAN
    | safe_flags::AWAITING_NEUTRAL
    | safe_flags::ACCEL_LIMITED;

/// The longest wait for a command (also how often the heartbeat goes out without one).
const MAX_WAIT: Duration = Duration::from_millis(100);

/// The names of the bits set in `flags`, comma-separated.
fn bit_names(flags: u32, names: &[&str]) -> String {
    names
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
        bits |= safety_state::ESTOP;
    }
    if f.held() {
        bits |= safety_state::HOLD;
    }
    if f.awaiting_neutral() {
        bits |= safety_state::AWAITING_NEUTRAL;
    }
    bits
}

/// The supervisor's control message: the active mapper from its tick, the hold, and a
/// relayed e-stop when its counter changed since `estop_seq`.
fn apply_control(filter: &mut SafetyFilter, c: &SafetyControl, estop_seq: &mut u32) {
    tracing::info!(
        mapper = c.active_mapper,
        from_tick = c.from_tick,
        hold = c.hold,
        "control from the supervisor"
    );
    filter.request_switch(c.active_mapper, c.from_tick);
    filter.set_hold(c.hold != 0);
    if c.estop_seq != *estop_seq {
        *estop_seq = c.estop_seq;
        if c.estop != 0 {
            tracing::warn!("E-STOP latched (relayed by the supervisor)");
            filter.estop();
        } else {
            filter.reset();
        }
    }
}

/// `scl estop` / `scl reset` (or a joystick's e-stop button).
fn apply_estop(filter: &mut SafetyFilter, e: &EstopCommand) {
    match e.action {
        estop_action::ESTOP => {
            tracing::warn!(from_pid = e.source_pid, "E-STOP latched");
            filter.estop();
        }
        estop_action::RESET => {
            tracing::info!(from_pid = e.source_pid, "e-stop reset");
            filter.reset();
        }
        other => tracing::warn!(action = other, "unknown e-stop action ignored"),
    }
}

/// The data-plane ports of the loop.
struct Ports {
    commands: TopicSubscriber<MapperCommand>,
    states: TopicSubscriber<RobotState>,
    out: TopicPublisher<SafeCommand>,
}

/// What the loop remembers between wake-ups.
struct Forwarder {
    filter: SafetyFilter,
    /// The newest robot state.
    state: Option<RobotState>,
    /// The tick of the last command published.
    last_tick: u64,
    /// The stop reasons last logged.
    last_stop_flags: u32,
    /// When the filter last stepped.
    last_step_ns: u64,
    /// When the last command of the active mapper arrived.
    last_command_ns: u64,
    period_ns: u64,
    /// `[safety] deadman`, for the log.
    deadman: bool,
    /// `[faults] safety_stall_at_tick`.
    stall_at_tick: u64,
    /// The arm has been allowed to move since this process started (restart prevention
    /// passed once): stops from now on are faults.
    started: bool,
}

impl Forwarder {
    fn new(filter: SafetyFilter, period_s: f64, stall_at_tick: u64) -> Self {
        let now = now_ns();
        Self {
            deadman: filter.config().deadman,
            filter,
            state: None,
            last_tick: NO_TICK,
            last_stop_flags: 0,
            last_step_ns: now,
            last_command_ns: now,
            period_ns: (period_s * 1e9).round() as u64,
            stall_at_tick,
            started: false,
        }
    }

    /// When safety answers the newest state itself (the e-stop latched, no command for its
    /// tick): [`ANSWER_AFTER`] of a period after it was published. `None` when there is
    /// nothing to answer at `now`: no state, the e-stop not latched, the tick answered, or
    /// the state a period old (the bridge has gone on without it).
    fn answer_at(&self, now: u64) -> Option<u64> {
        let s = self.state.as_ref()?;
        (self.filter.estopped() && s.tick != self.last_tick && now < s.t_ns + self.period_ns)
            .then(|| s.t_ns + (self.period_ns as f64 * ANSWER_AFTER) as u64)
    }

    /// No command of the active mapper for more than a period (none in flight either).
    fn quiet(&self, now: u64) -> bool {
        now.saturating_sub(self.last_command_ns) > self.period_ns
    }

    /// When to look for the next robot state, if safety answers states now (the e-stop
    /// latched or no command for a period): [`ANSWER_AFTER`] of a period after the state
    /// that follows the newest one is due. When that state is late, every twentieth of a
    /// period until it comes; when none has come for three periods (no bridge), once a
    /// period. Without a state yet, a period from `now`.
    fn next_look(&self, now: u64) -> u64 {
        let period = self.period_ns.max(1);
        let Some(s) = self.state.as_ref() else {
            return now + period;
        };
        let due = s.t_ns + period + (period as f64 * ANSWER_AFTER) as u64;
        if due > now {
            due
        } else if now < s.t_ns + 3 * period {
            now + period / 20
        } else {
            now + period
        }
    }

    /// Waits for a mapper command, and while the e-stop is latched or no command has come
    /// for a period, also until the next state is due ([`Self::next_look`]): returns
    /// whether a command came or an answer is due.
    fn wait(&mut self, p: &Ports) -> Result<bool, SafetyNodeError> {
        let now = now_ns();
        if !(self.quiet(now) || self.filter.estopped()) {
            return Ok(p.commands.wait(MAX_WAIT)?);
        }
        self.take_newest_state(p)?;
        let timeout = match self.answer_at(now) {
            Some(at) if at <= now => return Ok(true),
            Some(at) => at - now,
            None => self.next_look(now) - now,
        };
        // A poll on the event's descriptor (ppoll: the timer's own precision), not the
        // listener's timed wait, whose socket timeout counts in jiffies: with 250 Hz kernels
        // it slept up to 4 ms past the answer time (e-stop answers 10.3 to 13.3 ms after the
        // state instead of a quarter period, measured by `scl drill --only estop-no-mapper`).
        let woke = p
            .commands
            .wait_until(now + timeout.min(MAX_WAIT.as_nanos() as u64));
        self.take_newest_state(p)?;
        let now = now_ns();
        Ok(woke || self.answer_at(now).is_some_and(|at| now >= at))
    }

    /// Keeps the newest robot state published since the last look, if any.
    fn take_newest_state(&mut self, p: &Ports) -> Result<(), SafetyNodeError> {
        if let Some(s) = p.states.latest()? {
            self.state = Some(s);
        }
        Ok(())
    }

    /// Nothing came: says in the heartbeat what state safety is in, so `scl estop` can
    /// confirm and `scl status` shows it alive, and, after 100 ms without a command, that the
    /// arm will wait for neutral input when they resume (a wait can also end without one: a
    /// signal, another mapper joining).
    fn idle(&mut self, st: &mut NodeStatus, rx_ns: u64) {
        if rx_ns.saturating_sub(self.last_step_ns) > NO_COMMANDS_NS {
            self.filter.interrupt();
        }
        st.t_ns = now_ns();
        st.safety_state = safety_state_bits(&self.filter);
    }

    /// The command to publish now, if any: the active mapper's command for the newest
    /// state's tick through the filter, or with the e-stop latched and none in time, safety's
    /// own answer (its mapper named in the heartbeat `st`).
    fn next(
        &mut self,
        p: &Ports,
        rx_ns: u64,
        st: &mut NodeStatus,
    ) -> Result<Option<(SafeCommand, Option<MapperCommand>)>, SafetyNodeError> {
        self.take_newest_state(p)?;
        let Some(state) = self.state else {
            return Ok(None);
        };
        let active = self.filter.active_for_tick(state.tick);
        let mut pending = None;
        p.commands.drain(|c| {
            if c.mapper_id == active && c.tick == state.tick {
                pending = Some(*c);
            }
        })?;
        if pending.is_some() {
            self.last_command_ns = rx_ns;
        }
        let answer = self.answer_at(rx_ns).is_some_and(|at| rx_ns >= at);
        if state.tick == self.last_tick || !(pending.is_some() || answer) {
            return Ok(None);
        }
        self.last_tick = state.tick;
        if self.stall_at_tick != 0 && state.tick == self.stall_at_tick {
            tracing::warn!(tick = state.tick, "fault injection: safety stalls");
            std::thread::sleep(Duration::from_nanos(self.period_ns * 6 / 5));
        }
        let t0 = now_ns();
        self.last_step_ns = t0;
        let mut safe = match &pending {
            Some(cmd) => self.filter.step(cmd, &state, t0),
            None => self.filter.step_unanswered(active, &state, t0),
        };
        // One reading for both, so `t_ns - compute_ns` is the filter's time argument exactly
        // (a recording replays the step with it).
        let t1 = now_ns();
        safe.mapper_rx_ns = if pending.is_some() { rx_ns } else { 0 };
        safe.compute_ns = t1 - t0;
        safe.t_ns = t1;
        st.mapper_id = active;
        Ok(Some((safe, pending)))
    }

    /// Counts the published command in the heartbeat `st` and logs what changed: restart
    /// prevention waiting or released, the stop reasons (once per episode, not every tick).
    fn published(
        &mut self,
        st: &mut NodeStatus,
        safe: &SafeCommand,
        mapper: Option<&MapperCommand>,
    ) {
        st.t_ns = safe.t_ns;
        st.tick = safe.tick;
        st.handled += 1;
        st.rule_counts = self.filter.rule_counts();
        let was_awaiting = st.safety_state & safety_state::AWAITING_NEUTRAL != 0;
        st.safety_state = safety_state_bits(&self.filter);
        if safe.flags & safe_flags::STOP != 0 {
            st.faults += 1;
        }
        if self.filter.awaiting_neutral() != was_awaiting {
            if was_awaiting {
                tracing::info!(tick = safe.tick, "neutral input seen: motion allowed again");
            } else {
                tracing::warn!(
                    tick = safe.tick,
                    "waiting for neutral input: the arm moves again once the stick is at rest{}",
                    if self.deadman {
                        " and the deadman released and pressed again"
                    } else {
                        ""
                    }
                );
            }
        }
        let stop_flags = if safe.flags & safe_flags::STOP != 0 {
            safe.flags
        } else {
            0
        };
        let starting = !self.started && stop_flags & !START_REASONS == 0;
        self.started |= !self.filter.awaiting_neutral() && stop_flags == 0;
        if stop_flags != self.last_stop_flags {
            if stop_flags != 0 && starting {
                tracing::info!(
                    tick = safe.tick,
                    rules = %bit_names(stop_flags, &safe_flags::NAMES),
                    "starting with the arm stopped: it moves once the stick is at rest{}",
                    if self.deadman {
                        " and the deadman pressed"
                    } else {
                        ""
                    }
                );
            } else if stop_flags != 0 {
                let input = mapper.map_or_else(
                    || "no mapper command for the tick".into(),
                    |c| bit_names(c.flags, &mapper_flags::NAMES),
                );
                tracing::warn!(
                    tick = safe.tick,
                    rules = %bit_names(stop_flags, &safe_flags::NAMES),
                    mapper = %input,
                    "stopping the arm"
                );
            } else {
                tracing::info!(tick = safe.tick, "stop cleared");
            }
            self.last_stop_flags = stop_flags;
        }
    }
}

/// The supervisor's control messages and the e-stop commands that arrived.
struct Inputs {
    control: SafetyControlSubscriber,
    estops: EstopSubscriber,
    /// The counter of the last relayed e-stop applied.
    estop_seq: u32,
}

impl Inputs {
    /// Applies what arrived to `filter`.
    fn apply(&mut self, filter: &mut SafetyFilter) -> Result<(), SafetyNodeError> {
        let estop_seq = &mut self.estop_seq;
        self.control
            .drain(|c| apply_control(filter, c, estop_seq))?;
        self.estops.drain(|e| apply_estop(filter, e))?;
        Ok(())
    }
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
    let filter = SafetyFilter::for_graph(cfg.clone(), robot, period_s)?;
    let graph = Graph::join_with(prefix, "safety", graph_cfg.transport)?;
    let ports = Ports {
        commands: graph.mapper_command_subscriber(true)?,
        // Read, never waited on: see the module's documentation.
        states: graph.robot_state_subscriber(false)?,
        // Fails if another safety process already publishes: the arm listens to one only.
        out: graph.safe_command_publisher()?,
    };
    let status = graph.status_publisher()?;
    // A restarted safety learns the active mapper (and a relayed e-stop) from the topic's
    // history.
    let mut inputs = Inputs {
        control: graph.safety_control_subscriber()?,
        estops: graph.estop_subscriber()?,
        estop_seq: 0,
    };
    let mut f = Forwarder::new(filter, period_s, faults.safety_stall_at_tick);
    inputs.apply(&mut f.filter)?;
    let wait = node_rt::wait::strategy_of(graph_cfg, RtRole::Safety, "safety")?;
    let poller = Poller::new(wait, graph_cfg.period_ns());
    node_rt::rt::elevate(graph_cfg, RtRole::Safety);
    let heartbeat = Heartbeat::ready(&status, NodeRole::Safety, |st| {
        st.mapper_id = f.filter.active_for_tick(0);
        // At start-up too the arm waits for neutral input (restart prevention).
        st.safety_state = safety_state_bits(&f.filter);
    })?;
    tracing::info!(
        active_mapper = heartbeat.status().mapper_id,
        "forwarding to {}",
        ports.out.service()
    );
    let mut node = Safety {
        ports,
        inputs,
        f,
        poller,
    };
    node_rt::node::run(&mut node, heartbeat)?;
    Ok(())
}

/// Safety's loop: its ports, the forwarder and the poller.
struct Safety {
    ports: Ports,
    inputs: Inputs,
    f: Forwarder,
    poller: Poller,
}

impl Node for Safety {
    type Error = SafetyNodeError;

    fn step(&mut self, st: &mut NodeStatus) -> Result<Turn, SafetyNodeError> {
        let Self {
            ports,
            inputs,
            f,
            poller,
        } = self;
        // Polling only while commands flow (the e-stop's and a quiet graph's timed answers
        // keep the event wait).
        let now = now_ns();
        let polled = !(f.quiet(now) || f.filter.estopped())
            && poller
                .poll(
                    TickStart::Grid,
                    now + MAX_WAIT.as_nanos() as u64,
                    &ports.commands,
                    None,
                )
                .came();
        let woke = polled || f.wait(ports)?;
        let rx_ns = now_ns();
        inputs.apply(&mut f.filter)?;
        let next = if woke {
            f.next(ports, rx_ns, st)?
        } else {
            None
        };
        match next {
            Some((safe, cmd)) => {
                ports.out.send(safe)?;
                if let Some(c) = &cmd {
                    poller.took(c.tick, c.state_t_ns, c.t_ns);
                }
                f.published(st, &safe, cmd.as_ref());
                Ok(Turn::Beat)
            }
            // Nothing to forward: with no command for a while, the heartbeat says so.
            None if !woke || f.quiet(rx_ns) => {
                f.idle(st, rx_ns);
                Ok(Turn::Beat)
            }
            None => Ok(Turn::Quiet),
        }
    }

    fn finish(&mut self, _: &mut NodeStatus) -> Result<(), SafetyNodeError> {
        self.poller.log("safety");
        Ok(())
    }
}
