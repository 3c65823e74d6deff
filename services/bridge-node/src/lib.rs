//! The hardware bridge process: the graph's only clock.
//!
//! On every deadline of the absolute timer (`[graph] rate_hz`, 40 Hz by default) it publishes `RobotState(k)`, waits until
//! `command_deadline` into the period for `SafeCommand(k)`, and executes it; anything else is
//! a counted miss answered by a controlled stop. On shutdown it stops the arm first and
//! publishes a last state flagged `SHUTDOWN`.
//!
//! The robot is the mock (`robot = "mock"`) or a Gen3 lite over Kortex (`robot = "kortex"`,
//! [`hw_bridge::kortex::KortexArm`]). A robot error ends the run the same way as a shutdown
//! (stop, last state) and the process exits with the error's message.
//!
//! Start from a stop: a bridge that finds the arm moving at its first reading (a restarted
//! bridge whose predecessor died with a motion in force) executes no command until the arm is
//! at rest, only stops ([`hw_bridge::tick::StartGate`]); safety sees those ticks as an
//! interruption and waits for neutral input. A restarted bridge counts the periods lost while
//! no bridge ran ([`downtime_periods`], from the predecessor's last state, `--resume-t-ns`) as
//! missed, in its states, heartbeat and tick reports.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod fake_kortex;
pub mod late;

/// Why the bridge process stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum BridgeNodeError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The robot failed (Kortex: connection, session, an error from the robot).
    #[error(transparent)]
    Robot(#[from] hw_bridge::RobotError),
    /// The Kortex credentials could not be found or read (the message never holds them).
    #[error(transparent)]
    Credentials(#[from] CredentialsError),
    /// The fake Kortex robot could not start.
    #[error(transparent)]
    FakeKortex(#[from] hw_bridge::kortex::fake::FakeError),
    /// `[bridge.mock]` does not fit the robot.
    #[error("config: {0}")]
    Mock(#[from] hw_bridge::mock::MockConfigError),
    /// `[bridge] robot` names no backend.
    #[error("bridge.robot: `{name}` is not a robot; use mock or kortex")]
    UnknownRobot {
        /// The name as written.
        name: String,
    },
}

/// Why the Kortex credentials could not be had. No variant holds or shows them.
#[derive(Debug, thiserror::Error)]
pub enum CredentialsError {
    /// `[bridge.kortex] credentials_file` could not be read, others may read it, or it is
    /// not the expected TOML.
    #[error(transparent)]
    File(#[from] scl_config::secret::KortexCredentialsError),
    /// Neither the arguments, their environment variables nor the file gave them.
    #[error(
        "no Kortex {missing}: set {USER_ENV} and {PASSWORD_ENV}, or bridge.kortex.credentials_file (a TOML file with username and password)"
    )]
    Missing {
        /// `user name and password`, `user name` or `password`.
        missing: &'static str,
    },
}

use std::path::Path;
use std::time::Duration;

use hw_bridge::clock::{Clock, Hybrid, Wake};
use hw_bridge::kortex::{Credentials, KortexArm, KortexConfig};
use hw_bridge::mock::MockArm;
use hw_bridge::tick::{BridgeCore, GateChange, MissReason, Outcome};
use hw_bridge::{Robot, RobotError};
use ipc_types::{NodeRole, NodeStatus, Prefix, RobotState, SafeCommand, TickReport, time::now_ns};
use node_rt::node::Heartbeat;
use transport::Graph;

use scl_config::{BridgeConfig, FaultConfig, GraphSection, RtRole};
use transport::signals;

/// How long a stopped bridge waits for the late commands of its last missed ticks
/// ([`Ticker::settle_late`]); the arm is already stopped by then.
const SETTLE_NS: u64 = 50_000_000;

/// Environment variable with the Kortex user name (`scl bridge --user`).
pub const USER_ENV: &str = "SCL_KORTEX_USER";
/// Environment variable with the Kortex password (`scl bridge --password`).
pub const PASSWORD_ENV: &str = "SCL_KORTEX_PASSWORD";

/// A command-line value that must not show in `Debug` output (the Kortex user name and
/// password flags).
#[derive(Clone, PartialEq, Eq)]
pub struct Secret(String);

impl Secret {
    /// The value.
    pub fn into_inner(self) -> String {
        self.0
    }
}

impl std::str::FromStr for Secret {
    type Err = std::convert::Infallible;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(Self(s.to_owned()))
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("<redacted>")
    }
}

/// Kortex credentials given on the command line or in the environment; they take precedence
/// over `bridge.kortex.credentials_file`. Never printed.
#[derive(Clone, Default)]
pub struct CredentialArgs {
    /// `--user` / `SCL_KORTEX_USER`.
    pub user: Option<String>,
    /// `--password` / `SCL_KORTEX_PASSWORD`.
    pub password: Option<String>,
}

impl std::fmt::Debug for CredentialArgs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("CredentialArgs(<redacted>)")
    }
}

/// The credentials for the Kortex session: `--user` / `--password` (or their environment
/// variables) first, then `credentials_file`. Both must be found.
pub fn kortex_credentials(
    cfg: &KortexConfig,
    args: &CredentialArgs,
) -> Result<Credentials, BridgeNodeError> {
    let mut user = args.user.clone().filter(|s| !s.is_empty());
    let mut password = args.password.clone().filter(|s| !s.is_empty());
    if (user.is_none() || password.is_none()) && !cfg.credentials_file.is_empty() {
        let file = scl_config::secret::read_kortex_credentials(Path::new(&cfg.credentials_file))
            .map_err(CredentialsError::File)?;
        user = user.or(file.username);
        password = password.or(file.password);
    }
    match (user, password) {
        (Some(u), Some(p)) => Ok(Credentials::new(u, p)),
        (u, p) => {
            let missing = match (u.is_none(), p.is_none()) {
                (true, true) => "user name and password",
                (true, false) => "user name",
                _ => "password",
            };
            Err(CredentialsError::Missing { missing }.into())
        }
    }
}

/// Where a restarted bridge takes over (given by the supervisor from the last state its
/// predecessor published).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resume {
    /// The first tick to publish.
    pub start_tick: Option<u64>,
    /// The mock arm's pose and gripper state to start from (a real arm keeps its own).
    pub pose: Option<(Vec<f64>, f64)>,
    /// When the predecessor published its last state (monotonic ns): the periods from then to
    /// this bridge's first state, less one, were lost while no bridge ran and are counted as
    /// missed ([`downtime_periods`]).
    pub last_state_t_ns: Option<u64>,
}

enum Backend {
    Mock(Box<MockArm>),
    Kortex(Credentials),
}

/// Runs the bridge until a shutdown is requested or the robot fails.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    cfg: &BridgeConfig,
    faults: &FaultConfig,
    resume: &Resume,
    creds: &CredentialArgs,
) -> Result<(), BridgeNodeError> {
    // Everything that can be refused without touching the network, first.
    let robot = graph_cfg.profile()?;
    let backend = match cfg.robot.as_str() {
        "mock" => {
            let mut arm = MockArm::for_robot(robot, cfg.mock.clone())?;
            if let Some((q, c)) = &resume.pose {
                arm.resume(q, *c);
            }
            Backend::Mock(Box::new(arm))
        }
        "kortex" => Backend::Kortex(kortex_credentials(&cfg.kortex, creds)?),
        other => {
            return Err(BridgeNodeError::UnknownRobot {
                name: other.to_owned(),
            });
        }
    };
    let wait = node_rt::wait::strategy_of(graph_cfg, RtRole::Bridge, "bridge")?;
    node_rt::rt::elevate(graph_cfg, RtRole::Bridge);
    let graph = Graph::join_with(prefix, "bridge", graph_cfg.transport)?;
    let ctx = Ctx {
        wait,
        graph: &graph,
        period_ns: graph_cfg.period_ns(),
        cfg,
        faults,
        resume,
    };
    match backend {
        Backend::Mock(arm) => tick_loop(&ctx, *arm),
        Backend::Kortex(credentials) => {
            // Connect as late as possible: from here on a frame must go out at least every
            // connection_timeout_ms, and the first tick follows within one period.
            let arm = KortexArm::connect_to(robot, &cfg.kortex, &credentials)
                .map_err(RobotError::from)?;
            tick_loop(&ctx, arm)
        }
    }
}

/// Says what a command that came after its tick's deadline tells about the miss: the
/// machine's (a `held up` warning, `ticks_lost=1`, counted in the heartbeat's `held_up`) or
/// the chain's own work too slow for the deadline.
fn say_late(v: &late::Verdict) {
    let ms = |ns: u64| ns as f64 * 1e-6;
    if v.skipped && v.held_up() {
        tracing::warn!(
            tick = v.tick,
            ticks_lost = 1,
            mapper_wake_ms = ms(v.mapper_wake_ns),
            work_ms = ms(v.work_ns),
            "missed tick: the mapper or safety was held up (no command came for it: the same mapper answered a later state first, its work fitted the deadline)"
        );
    } else if v.skipped {
        tracing::warn!(
            tick = v.tick,
            work_ms = ms(v.work_ns),
            budget_ms = ms(v.budget_ns),
            "missed tick: no command came for it, and the mapper's and safety's work on the next took longer than the command deadline"
        );
    } else if v.held_up() {
        tracing::warn!(
            tick = v.tick,
            ticks_lost = 1,
            late_ms = ms(v.late_ns),
            mapper_wake_ms = ms(v.mapper_wake_ns),
            safety_wake_ms = ms(v.safety_wake_ns),
            work_ms = ms(v.work_ns),
            "missed tick: the mapper or safety was held up (its command came late, its work fitted the deadline)"
        );
    } else {
        tracing::warn!(
            tick = v.tick,
            late_ms = ms(v.late_ns),
            work_ms = ms(v.work_ns),
            budget_ms = ms(v.budget_ns),
            "missed tick: the mapper's and safety's work took longer than the command deadline"
        );
    }
}

/// How long into each period the bridge waits for the tick's command (ns): the period's
/// `command_deadline` fraction.
pub fn command_wait_ns(period_ns: u64, command_deadline: f64) -> u64 {
    (period_ns as f64 * command_deadline) as u64
}

/// The ticks a wake-up `lateness_ns` past its deadline, after `skipped` whole periods slept
/// through, lost to the machine: the skipped periods, and this tick too if it started past its
/// command wait `wait_ns` and was `missed` (its state went out, but its command could not come
/// back in time; one already there is executed, and that tick is not lost).
pub fn ticks_lost(skipped: u64, lateness_ns: u64, wait_ns: u64, missed: bool) -> u64 {
    skipped + u64::from(missed && lateness_ns >= wait_ns)
}

/// The periods lost while no bridge ran: from the predecessor's last state at `last_t_ns` to
/// this bridge's first at `first_t_ns`, whole periods of `period_ns` (rounded to the nearest),
/// less the one between two consecutive states. 0 if the first state is not later.
pub fn downtime_periods(last_t_ns: u64, first_t_ns: u64, period_ns: u64) -> u64 {
    if period_ns == 0 {
        return 0;
    }
    let gap = first_t_ns.saturating_sub(last_t_ns);
    (gap.saturating_add(period_ns / 2) / period_ns).saturating_sub(1)
}

/// Says what the start gate changed ([`hw_bridge::tick::StartGate`]).
fn say_gate(change: GateChange, tick: u64) {
    match change {
        GateChange::FoundMoving { joint, speed_rad_s } => tracing::warn!(
            tick,
            joint,
            speed_rad_s,
            "the arm is moving at start (left moving by a bridge before this one): only stops \
             go out until it is at rest; then motion needs the operator's input at neutral"
        ),
        GateChange::CameToRest { ticks } => tracing::info!(
            tick,
            stop_ticks = ticks,
            "the arm is at rest: the graph's commands execute again (safety waits for neutral \
             input first)"
        ),
    }
}

struct Ctx<'a> {
    /// How the tick's command is waited for after the state went out (`[graph] wait`).
    wait: node_rt::wait::WaitStrategy,
    graph: &'a Graph,
    /// The tick period (`[graph] rate_hz`).
    period_ns: u64,
    cfg: &'a BridgeConfig,
    faults: &'a FaultConfig,
    resume: &'a Resume,
}

/// The tick loop: on each deadline of the clock, begin the tick (read the robot), publish
/// the state, wait for the tick's command until the command deadline, execute it (or stop),
/// count what was held up, then send the heartbeat and the tick report. A robot error ends
/// the loop like a shutdown: the arm is stopped, then the last state goes out.
fn tick_loop<R: Robot>(ctx: &Ctx<'_>, robot: R) -> Result<(), BridgeNodeError> {
    let mut t = Ticker::start(ctx, robot)?;
    let mut clock = Clock::new(now_ns() + ctx.period_ns, ctx.period_ns);
    // Where the chain polls, the clock does too: it sleeps to a margin before each tick and
    // spins the rest.
    let mut hybrid = ctx.wait.polls().then(|| Hybrid::new(ctx.period_ns));
    // Drop whatever commands are left over from an earlier bridge of this graph.
    t.commands.drain(|_| {})?;
    let mut failure: Option<RobotError> = None;
    while !signals::stop_requested() {
        let wake = match &mut hybrid {
            Some(h) => clock.wait_hybrid(h),
            None => clock.wait(),
        };
        let (ideal_ns, lateness_ns, skipped) = match wake {
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
        let woke = Woke {
            ideal_ns,
            lateness_ns,
            skipped,
            deadline_ns: ideal_ns + t.wait_ns,
        };
        let state = match t.begin(skipped) {
            Ok(s) => s,
            Err(e) => {
                failure = Some(e);
                break;
            }
        };
        t.publish_state(state)?;
        let mut verdicts = Vec::new();
        let reply = t.await_command(&state, woke.deadline_ns, &mut verdicts)?;
        let outcome = match t
            .core
            .finish_tick(reply.found.as_ref().or(reply.other.as_ref()))
        {
            Ok(o) => o,
            Err(e) => {
                failure = Some(e);
                break;
            }
        };
        t.count_hold_ups(&woke, matches!(outcome, Outcome::Missed(_)), verdicts);
        let latency_ns = t.settle(outcome, &state, &woke, reply.received_ns);
        t.send_status(latency_ns, &state, &woke, &reply)?;
        t.send_report(outcome, &state, &woke, &reply)?;
    }
    if let Some(h) = &hybrid {
        // `scl bench latency` reads `spin_us_per_tick`: the hybrid clock's CPU cost.
        tracing::info!(
            process = %"clock",
            wait = %ctx.wait,
            spin_us_per_tick = format!("{:.2}", h.per_tick_us()),
            margin_us = h.margin_ns() / 1000,
            ticks = h.ticks,
            "wait strategy: the clock slept to a margin before each tick and spun the rest"
        );
    }
    t.shutdown(failure)
}

/// One wake-up of the clock: the tick's place on the ideal grid and how late it began.
struct Woke {
    /// The tick's ideal start (ns).
    ideal_ns: u64,
    /// How late the wake-up was against it (ns).
    lateness_ns: u64,
    /// Whole periods slept through before it.
    skipped: u64,
    /// When the tick's command is due (ns): the ideal start plus the command wait.
    deadline_ns: u64,
}

/// What came back for a tick by its command deadline.
#[derive(Default)]
struct Reply {
    /// The tick's own command.
    found: Option<SafeCommand>,
    /// The newest command for another tick.
    other: Option<SafeCommand>,
    /// When the tick's own command was taken (ns); 0 if it did not come.
    received_ns: u64,
}

/// The bridge's running state: its ports, the core, the heartbeat and the missed ticks
/// whose commands may still come.
struct Ticker<'a, R: Robot> {
    ctx: &'a Ctx<'a>,
    /// How long into each period the tick's command is waited for (ns).
    wait_ns: u64,
    states: transport::TopicPublisher<RobotState>,
    commands: transport::TopicSubscriber<SafeCommand>,
    reports: transport::TopicPublisher<TickReport>,
    core: BridgeCore<R>,
    /// The heartbeat on the status topic.
    heartbeat: Heartbeat<transport::TopicPublisher<NodeStatus>>,
    late: late::LateCommands,
    /// Until the first tick has begun (a restarted bridge counts its downtime then).
    first_tick: bool,
    /// Polls for the tick's command (`[graph] wait`), in a window placed after the state.
    poller: node_rt::poller::Poller,
}

impl<'a, R: Robot> Ticker<'a, R> {
    /// Opens the ports, sets up the core (from the resumed tick count) and says `READY`.
    fn start(ctx: &'a Ctx<'a>, robot: R) -> Result<Self, BridgeNodeError> {
        let (graph, cfg) = (ctx.graph, ctx.cfg);
        let period_ns = ctx.period_ns;
        let period_s = period_ns as f64 * 1e-9;
        let wait_ns = command_wait_ns(period_ns, cfg.command_deadline);
        let states = graph.robot_state_publisher()?;
        let commands = graph.safe_command_subscriber(true)?;
        let status = graph.status_publisher()?;
        let reports = graph.tick_report_publisher()?;
        let mut core = BridgeCore::new(robot, period_s, cfg.stop_acceleration_rad_s2.clone());
        if let Some(t) = ctx.resume.start_tick {
            core.start_at(t);
            tracing::info!(
                start_tick = t,
                "resuming the graph's tick count from a stop"
            );
        }
        let heartbeat = Heartbeat::ready(status, NodeRole::Bridge, |_| {})?;
        tracing::info!(rate_hz = 1e9 / period_ns as f64, robot = %cfg.robot, "ticking");
        Ok(Self {
            ctx,
            wait_ns,
            states,
            commands,
            reports,
            core,
            heartbeat,
            late: late::LateCommands::default(),
            first_tick: true,
            poller: node_rt::poller::Poller::new(ctx.wait, period_ns).polling_every_tick(),
        })
    }

    /// Begins the tick: counts the periods slept through (and, at the first tick of a
    /// restarted bridge, those no bridge ran through), reads the robot, says what the start
    /// gate changed.
    fn begin(&mut self, skipped: u64) -> Result<RobotState, RobotError> {
        // Woken this long after the deadline it slept for, the process was not run by the
        // operating system (or the host of a virtual machine): the periods it slept through
        // are lost, and so is this tick if it starts past its command deadline and misses
        // (its state goes out, but no command can come back in time: the bridge brakes).
        self.core.add_skipped(skipped);
        let begin_ns = now_ns();
        if std::mem::take(&mut self.first_tick)
            && let Some(last) = self.ctx.resume.last_state_t_ns
        {
            // The periods no bridge ran through: the graph's loss, counted as missed.
            let lost = downtime_periods(last, begin_ns, self.ctx.period_ns);
            if lost > 0 {
                self.core.add_skipped(lost);
                tracing::warn!(
                    ticks_lost = lost,
                    down_ms = begin_ns.saturating_sub(last) as f64 * 1e-6,
                    "missed ticks: no bridge ran between the last state before the restart and \
                     this bridge's first"
                );
            }
        }
        let state = self.core.begin_tick(begin_ns)?;
        if let Some(change) = self.core.take_gate_change() {
            say_gate(change, state.tick);
        }
        Ok(state)
    }

    /// Publishes the tick's state, unless the fault injection `bridge_states_stop_after_ticks`
    /// has stopped them.
    fn publish_state(&self, state: RobotState) -> Result<(), BridgeNodeError> {
        let stop_after = self.ctx.faults.bridge_states_stop_after_ticks;
        let handled = self.heartbeat.status().handled;
        if stop_after == 0 || handled < stop_after {
            self.states.send(state)?;
        } else if handled == stop_after {
            tracing::warn!(tick = state.tick, "fault injection: robot states stop");
        }
        Ok(())
    }

    /// Waits until the command of `state`'s tick comes or `deadline_ns` passes; late commands
    /// for missed ticks add their verdicts to `verdicts`. With `predictive` or `spin` the
    /// subscriber is polled first ([`node_rt::poller::Poller`]: in the window learned from
    /// the commands' stamps, or up to the deadline), then the event wait takes over; nothing
    /// is waited for past the deadline.
    fn await_command(
        &mut self,
        state: &RobotState,
        deadline_ns: u64,
        verdicts: &mut Vec<late::Verdict>,
    ) -> Result<Reply, BridgeNodeError> {
        use node_rt::poller::{Polled, TickStart};
        let tick = state.tick;
        let mut reply = Reply::default();
        let late = &mut self.late;
        let mut polled = false;
        self.poller.spin.ticks += 1;
        loop {
            self.commands.drain(|c| {
                if c.tick == tick {
                    reply.found = Some(*c);
                    late.superseded(c, verdicts);
                } else {
                    late.other_tick(c, verdicts);
                    reply.other = Some(*c);
                }
            })?;
            let now = now_ns();
            if let Some(c) = &reply.found {
                reply.received_ns = now;
                self.poller.took_offset(c.t_ns as i64 - state.t_ns as i64);
                break;
            }
            // A stop requested meanwhile waits for the command all the same: the supervisor
            // stops the bridge first, so the command still comes, and leaving now would count
            // the graph's last tick as its own miss. The stop follows at the end of this tick,
            // at most the command wait later.
            if now >= deadline_ns {
                break;
            }
            // Once per tick: poll, then the event wait below.
            if !std::mem::replace(&mut polled, true)
                && self
                    .poller
                    .poll(TickStart::At(state.t_ns), deadline_ns, &self.commands, None)
                    != Polled::Skipped
            {
                continue;
            }
            self.commands
                .wait(Duration::from_nanos(deadline_ns - now))?;
        }
        Ok(reply)
    }

    /// Counts in the heartbeat the ticks the machine held up: the bridge's own (periods slept
    /// through, this tick if it began past its command wait and `missed`) and the chain's
    /// (late commands whose work fitted the deadline), and says them.
    fn count_hold_ups(&mut self, woke: &Woke, missed: bool, verdicts: Vec<late::Verdict>) {
        let lost = ticks_lost(woke.skipped, woke.lateness_ns, self.wait_ns, missed);
        if lost > 0 {
            let late_ms = (woke.skipped * self.ctx.period_ns + woke.lateness_ns) as f64 * 1e-6;
            tracing::warn!(
                ticks_lost = lost,
                late_ms,
                "missed tick: the bridge was held up past a command deadline"
            );
            let st = self.heartbeat.status_mut();
            st.held_up = st.held_up.saturating_add(lost as u32);
        }
        self.take_verdicts(verdicts);
    }

    /// Says each late command's verdict and counts the machine's in the heartbeat.
    fn take_verdicts(&mut self, verdicts: Vec<late::Verdict>) {
        for v in verdicts {
            say_late(&v);
            if v.held_up() {
                let st = self.heartbeat.status_mut();
                st.held_up = st.held_up.saturating_add(1);
            }
        }
    }

    /// The tick's latency for the heartbeat (the state's publication to its command's
    /// arrival; 0 unless executed); a miss is noted for its late command and said.
    fn settle(
        &mut self,
        outcome: Outcome,
        state: &RobotState,
        woke: &Woke,
        received_ns: u64,
    ) -> u64 {
        match outcome {
            Outcome::Executed => received_ns - state.t_ns,
            // The arm found moving at start: a stop, not a miss (said by say_gate).
            Outcome::StoppingAtStart => 0,
            Outcome::Missed(reason) => {
                // A tick begun past its deadline is the bridge's own hold-up, counted above.
                if matches!(reason, MissReason::NoCommand | MissReason::WrongTick)
                    && woke.lateness_ns < self.wait_ns
                {
                    self.late
                        .missed(state.tick, woke.ideal_ns, state.t_ns, woke.deadline_ns);
                }
                let missed = self.core.missed();
                if missed <= 10 || missed.is_power_of_two() {
                    tracing::warn!(
                        tick = state.tick,
                        ?reason,
                        missed,
                        "missed tick: controlled stop"
                    );
                }
                0
            }
        }
    }

    /// Sends the heartbeat for the tick.
    fn send_status(
        &mut self,
        latency_ns: u64,
        state: &RobotState,
        woke: &Woke,
        reply: &Reply,
    ) -> Result<(), BridgeNodeError> {
        let st = self.heartbeat.status_mut();
        st.latency_ns = latency_ns;
        st.t_ns = now_ns();
        st.tick = state.tick;
        st.handled += 1;
        st.faults = self.core.missed();
        st.lateness_ns = woke.lateness_ns;
        st.joint_travel_rad = self.core.joint_travel_rad();
        st.mapper_id = reply.found.map_or(0, |c| c.mapper_id);
        self.heartbeat.beat()?;
        Ok(())
    }

    /// Sends the tick's timing report (the command's stamps only if it was executed).
    fn send_report(
        &self,
        outcome: Outcome,
        state: &RobotState,
        woke: &Woke,
        reply: &Reply,
    ) -> Result<(), BridgeNodeError> {
        let executed = matches!(outcome, Outcome::Executed);
        let c = reply.found.filter(|_| executed);
        self.reports.send(TickReport {
            tick: state.tick,
            ideal_ns: woke.ideal_ns,
            lateness_ns: woke.lateness_ns,
            state_t_ns: state.t_ns,
            state_rx_ns: c.map_or(0, |c| c.state_rx_ns),
            joystick_t_ns: c.map_or(0, |c| c.joystick_t_ns),
            joystick_rx_ns: c.map_or(0, |c| c.joystick_rx_ns),
            mapper_t_ns: c.map_or(0, |c| c.mapper_t_ns),
            mapper_rx_ns: c.map_or(0, |c| c.mapper_rx_ns),
            safe_t_ns: c.map_or(0, |c| c.t_ns),
            safe_rx_ns: if executed { reply.received_ns } else { 0 },
            mapper_compute_ns: c.map_or(0, |c| c.mapper_compute_ns),
            safety_compute_ns: c.map_or(0, |c| c.compute_ns),
            missed: self.core.missed(),
            executed: u32::from(executed),
            reserved: 0,
        })?;
        Ok(())
    }

    /// With the arm stopped: waits a little (at most [`SETTLE_NS`]) for the late commands of
    /// the last missed ticks, so that the final heartbeat counts the hold-ups they show. The
    /// chain is still running (the supervisor stops the bridge first); without this, the
    /// ticks the machine held up just before the stop stayed the graph's misses (seen on a
    /// CPU-throttled machine at 1 kHz: 3-11 of them per run).
    fn settle_late(&mut self) -> Result<(), BridgeNodeError> {
        let until = now_ns() + SETTLE_NS;
        let mut verdicts = Vec::new();
        while self.late.awaiting() > 0 && now_ns() < until {
            let late = &mut self.late;
            self.commands.drain(|c| late.other_tick(c, &mut verdicts))?;
            if self.late.awaiting() > 0 {
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        self.take_verdicts(verdicts);
        Ok(())
    }

    /// Stops the arm first (also after a robot error: as far as the robot can be reached),
    /// then says so: the last state, a `STOPPING` heartbeat, the link's counts. Returns the
    /// robot's error, if any.
    fn shutdown(mut self, mut failure: Option<RobotError>) -> Result<(), BridgeNodeError> {
        self.poller.log("bridge");
        let (last, stopped) = self.core.shutdown(now_ns());
        if let Err(e) = stopped {
            match &failure {
                None => failure = Some(e),
                Some(_) => tracing::warn!("while stopping after the failure: {e}"),
            }
        }
        self.states.send(last)?;
        self.settle_late()?;
        self.heartbeat.status_mut().latency_ns = 0;
        let st = self.heartbeat.stop()?;
        let link = self.core.robot().link_stats();
        tracing::info!(
            ticks = st.handled,
            missed = self.core.missed(),
            requests = link.requests,
            late_replies = link.late_replies,
            stale_readings = link.stale_readings,
            skipped_bytes = link.skipped_bytes,
            clamped_commands = link.clamped_commands,
            signal = signals::signal(),
            "arm stopped; bridge exiting"
        );
        match failure {
            Some(e) => Err(BridgeNodeError::Robot(e)),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("scl-creds-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// A credentials file only its owner may read (the rule of every credentials file).
    fn write_private(f: &Path, text: &str) {
        use std::os::unix::fs::PermissionsExt as _;
        std::fs::write(f, text).unwrap();
        std::fs::set_permissions(f, std::fs::Permissions::from_mode(0o600)).unwrap();
    }

    /// The command deadline and the hold-up count at 40 Hz and at 1 kHz: the default
    /// 0.6 of the period is 15 ms and 0.6 ms; a wake-up 1 ms late loses no tick at 40 Hz and
    /// this tick at 1 kHz.
    #[test]
    fn the_deadline_and_the_lost_ticks_follow_the_period_at_40_hz_and_1_khz() {
        assert_eq!(command_wait_ns(25_000_000, 0.6), 15_000_000);
        assert_eq!(command_wait_ns(1_000_000, 0.6), 600_000);
        let late_1ms = 1_000_000;
        let (wait_40, wait_1k) = (
            command_wait_ns(25_000_000, 0.6),
            command_wait_ns(1_000_000, 0.6),
        );
        assert_eq!(ticks_lost(0, late_1ms, wait_40, true), 0);
        // At 1 kHz the clock reports 1 ms late as one whole period skipped.
        assert_eq!(ticks_lost(1, 0, wait_1k, false), 1);
        assert_eq!(ticks_lost(0, 700_000, wait_1k, true), 1);
        assert_eq!(ticks_lost(3, 700_000, wait_1k, true), 4);
        assert_eq!(ticks_lost(3, 100_000, wait_1k, true), 3);
        // Begun past its deadline with its command already there: executed, not lost.
        assert_eq!(ticks_lost(0, 700_000, wait_1k, false), 0);
    }

    /// The periods lost while no bridge ran, at 40 Hz and at 1 kHz: consecutive states lose
    /// none (also a little late or early), a 187 ms gap at 40 Hz loses 6.
    #[test]
    fn downtime_is_the_periods_between_the_states_less_one() {
        let p40 = 25_000_000;
        assert_eq!(downtime_periods(1_000, 1_000 + p40, p40), 0);
        assert_eq!(downtime_periods(1_000, 1_000 + p40 * 3 / 2 - 1, p40), 0);
        assert_eq!(downtime_periods(1_000, 1_000 + 187_000_000, p40), 6);
        assert_eq!(downtime_periods(1_000, 1_000 + 2 * p40, p40), 1);
        assert_eq!(
            downtime_periods(1_000_000, 1_000_000 + 187_000_000, 1_000_000),
            186
        );
        // Clock oddities lose nothing.
        assert_eq!(downtime_periods(5_000, 1_000, p40), 0);
        assert_eq!(downtime_periods(0, u64::MAX, 0), 0);
    }

    #[test]
    fn flags_and_environment_come_before_the_file() {
        let d = dir("order");
        let f = d.join("kortex.toml");
        write_private(&f, "username = \"file-user\"\npassword = \"file-pw\"\n");
        let cfg = KortexConfig {
            credentials_file: f.display().to_string(),
            ..KortexConfig::default()
        };
        let from_file = kortex_credentials(&cfg, &CredentialArgs::default()).unwrap();
        assert_eq!(from_file, Credentials::new("file-user", "file-pw"));
        let args = CredentialArgs {
            user: Some("flag-user".into()),
            password: None,
        };
        assert_eq!(
            kortex_credentials(&cfg, &args).unwrap(),
            Credentials::new("flag-user", "file-pw")
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn missing_or_bad_credentials_are_named_without_the_secret() {
        let e = kortex_credentials(&KortexConfig::default(), &CredentialArgs::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("user name and password") && e.contains(USER_ENV),
            "{e}"
        );
        let args = CredentialArgs {
            user: Some("u".into()),
            password: None,
        };
        let e = kortex_credentials(&KortexConfig::default(), &args)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no Kortex password"), "{e}");

        let d = dir("bad");
        let f = d.join("kortex.toml");
        // An unquoted password: the TOML parser would quote the line; the message must not.
        write_private(&f, "username = \"admin\"\npassword = sup3r-s3cret\n");
        let cfg = KortexConfig {
            credentials_file: f.display().to_string(),
            ..KortexConfig::default()
        };
        let e = kortex_credentials(&cfg, &CredentialArgs::default()).unwrap_err();
        assert!(
            matches!(
                e,
                BridgeNodeError::Credentials(CredentialsError::File(
                    scl_config::secret::KortexCredentialsError::Parse { line: Some(2), .. }
                ))
            ),
            "{e:?}"
        );
        let e = e.to_string();
        assert!(e.contains("line 2") && e.contains("kortex.toml"), "{e}");
        assert!(!e.contains("sup3r"), "{e}");
        let args = CredentialArgs {
            user: Some("qx-user".into()),
            password: Some("qz-pass".into()),
        };
        let text = format!("{args:?}");
        assert!(
            !text.contains("qx-user") && !text.contains("qz-pass"),
            "{text}"
        );
        std::fs::remove_dir_all(&d).unwrap();
        let e = kortex_credentials(&cfg, &CredentialArgs::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("credentials file") && e.contains("No such file"),
            "{e}"
        );
    }
}
