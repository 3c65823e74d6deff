//! `scl up`: starts the four processes of the graph as children, supervises them, serves live
//! mapper swaps, reports once a second, and stops them in a safe order (bridge first, so the
//! arm is stopped before anything else goes).
//!
//! * Start: joystick, mapper and safety, each awaited until it reports ready, then the bridge
//!   (the clock), so the first tick already finds every process listening.
//! * A child that exits is reaped at once and what it left in shared memory is cleaned up in
//!   the same loop iteration, before any successor starts; the node directory is scanned for
//!   dead nodes only then, before a restart, and once a second as a safety net
//!   ([`CleanupSchedule`]), not on every 2 ms iteration. The child's restart policy
//!   (`[supervisor.restart]`) decides ([`decide_restart`]): `never` stops the graph with a
//!   non-zero status and a message naming it; `on-failure` / `always` restart it after an
//!   exponential backoff. The arm is stopped meanwhile (the bridge misses the tick, or for a
//!   dead bridge the robot's own watchdog acts). A restarted bridge continues the tick count
//!   and starts from a stop.
//! * `scl swap MODEL` (a request on the supervisor's control service) is make-before-break:
//!   a new mapper process with a new id starts beside the old one; once it has produced valid
//!   commands for `swap_valid_ticks` consecutive ticks ([`Warmup`]), safety is told to forward
//!   its commands from a tick boundary on; when the bridge has received the first of them, the
//!   old mapper is stopped. A model that does not load, or a new mapper that fails or does not
//!   warm up within `swap_timeout_s`, is refused with the reason and the old mapper keeps
//!   running.

use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use ipc_types::control::{ControlResponse, SafetyControl, Text, request_kind};
use ipc_types::{
    MapperCommand, NodeRole, NodeStatus, Prefix, RobotState, SafeCommand, mapper_flags, phase,
    time::now_ns,
};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde::Serialize;
use transport::Graph;
use transport::control::{ActiveControlRequest, SafetyControlPublisher};

use crate::histogram::Histogram;
use crate::{LiveStartError, SupervisorError};
use mapper::step::MapperStep;
use node_rt::stats::Percentiles;
use scl_config::{GraphConfig, RestartPolicy, SupervisorConfig};
use transport::signals;

/// What `scl up` was asked to do.
#[derive(Debug, Clone)]
pub struct UpOptions {
    /// The graph prefix.
    pub prefix: Prefix,
    /// The config file given, passed on to the children.
    pub config_path: Option<PathBuf>,
    /// The effective configuration (file plus flags).
    pub config: GraphConfig,
    /// Stop after this long; run until Ctrl-C if `None`.
    pub duration: Option<Duration>,
    /// Print the summary as JSON on stdout.
    pub json: bool,
    /// Record the graph to this MCAP file: `scl record` as a supervised child, started first
    /// and stopped last.
    pub record: Option<PathBuf>,
    /// Serve the graph to Foxglove on this `ADDR:PORT`: `scl live` as a child, started before
    /// the bridge and stopped last. It is an optional view: if it dies the graph goes on.
    pub live: Option<String>,
}

/// The end-of-run summary (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Ticks the bridge ran (over every bridge process of the run).
    pub ticks: u64,
    /// Ticks without a valid command in time.
    pub missed: u64,
    /// How many of `missed` the machine took: periods the bridge was not run through, and
    /// commands that came late although the mapper's and safety's work fitted the deadline
    /// (`NodeStatus::held_up`). The graph's own misses are `missed - held_up`.
    pub held_up: u64,
    /// RobotState(k) published -> SafeCommand(k) received by the bridge, µs.
    pub latency_us: Percentiles,
    /// Lateness of the bridge's clock against the ideal grid, µs.
    pub tick_lateness_us: Percentiles,
    /// Joint-space path length of the arm (rad): the Euclidean norm of each tick's change of
    /// the joint angles, summed (`NodeStatus::joint_travel_rad`, over every bridge process).
    /// The sum of every joint's absolute change is up to `sqrt(n_joints)` times larger; the
    /// Python example `load_recording.py` computes this one from a recording.
    pub joint_travel_rad: f64,
    /// Latency samples behind the percentiles (counted in a histogram: each percentile is
    /// within 0.8 % of the sample it stands for; `max` is exact).
    pub latency_samples: usize,
    /// Wall time of the run (s).
    pub duration_s: f64,
    /// The graph prefix.
    pub prefix: String,
    /// The mapper whose commands reached the arm last.
    pub active_mapper: u32,
    /// Processes restarted by their restart policy.
    pub restarts: u32,
    /// Live swaps completed.
    pub swaps: u32,
    /// Set when a child died and was not restarted: which, and how.
    pub failure: Option<String>,
    /// The smallest distance between any pair of the collision model safety checked over the
    /// run (m; `SafeCommand::clearance_m`, at each tick's state); `null` if none was checked.
    pub min_clearance_m: Option<f64>,
    /// The fastest tool speed safety commanded over the run (m/s; `SafeCommand::tcp_speed_m_s`
    /// at each tick's state); `null` if none was checked.
    pub max_tcp_speed_m_s: Option<f64>,
}

/// A supervised child process.
struct Managed {
    role: NodeRole,
    /// Mapper id (mappers only).
    mapper_id: u32,
    args: Vec<String>,
    child: Option<Child>,
    pid: u32,
    started: Instant,
    /// Consecutive failures, for the backoff.
    failures: u32,
    restart_at: Option<Instant>,
    /// Being stopped on purpose (the old mapper after a swap, a refused new one).
    retiring: bool,
}

impl Managed {
    fn label(&self) -> String {
        if self.role == NodeRole::Mapper {
            format!(
                "the mapper process (id {}, pid {})",
                self.mapper_id, self.pid
            )
        } else {
            format!("the {} process (pid {})", self.role.name(), self.pid)
        }
    }
}

fn describe(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exited with status {c}"),
        (None, Some(9)) => "was killed by signal 9 (SIGKILL)".into(),
        (None, Some(s)) => format!("was killed by signal {s}"),
        _ => "ended".into(),
    }
}

/// What happens to a child that exited on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RestartDecision {
    /// Its policy does not restart it: the graph stops.
    Stop,
    /// Restart it after `delay`; `failures` is its new count of consecutive failures.
    After { delay: Duration, failures: u32 },
}

/// The restart decision for a `role` child that exited (`clean_exit`: status 0) after running
/// for `ran_for`, with `failures` consecutive failures before this one.
///
/// `never` stops the graph; `on-failure` restarts after a crash or a non-zero status only;
/// `always` restarts after any exit. The delay starts at `backoff_initial_ms` and doubles
/// with each consecutive failure up to `backoff_max_ms`; a child that ran longer than
/// `stable_after_s` starts the count afresh.
fn decide_restart(
    sv: &SupervisorConfig,
    role: NodeRole,
    clean_exit: bool,
    ran_for: Duration,
    failures: u32,
) -> RestartDecision {
    let restart = match sv.restart.of(role) {
        RestartPolicy::Never => false,
        RestartPolicy::OnFailure => !clean_exit,
        RestartPolicy::Always => true,
    };
    if !restart {
        return RestartDecision::Stop;
    }
    let before = if ran_for.as_secs_f64() > sv.stable_after_s {
        0
    } else {
        failures
    };
    let failures = before.saturating_add(1);
    let factor = 1u64 << (failures - 1).min(20);
    let delay = Duration::from_millis(
        sv.backoff_initial_ms
            .saturating_mul(factor)
            .min(sv.backoff_max_ms),
    );
    RestartDecision::After { delay, failures }
}

/// Whether a new mapper's command counts towards the swap's warm-up: no invalid input,
/// output or state, and every velocity finite.
fn command_valid(c: &MapperCommand) -> bool {
    let bad = mapper_flags::INPUT_NON_FINITE
        | mapper_flags::OUTPUT_NON_FINITE
        | mapper_flags::STATE_INVALID;
    c.flags & bad == 0 && c.qdot_rad_s.iter().all(|v| v.is_finite())
}

/// The swap's warm-up counter: valid commands of the new mapper on consecutive ticks. An
/// invalid command resets it to zero; a skipped tick (a missing command) restarts it at the
/// command that follows the gap.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Warmup {
    /// Valid commands on consecutive ticks, ending at `last_tick`.
    valid: u32,
    /// The tick of the newest command taken.
    last_tick: Option<u64>,
}

impl Warmup {
    /// Takes the new mapper's command for `tick` (`ok`: [`command_valid`]); returns the count
    /// of valid commands on consecutive ticks ending at it. A valid repeat of the newest tick
    /// is not counted twice.
    fn observe(&mut self, tick: u64, ok: bool) -> u32 {
        if ok && self.last_tick == Some(tick) {
            return self.valid;
        }
        let consecutive = self.last_tick.is_none_or(|t| tick == t.wrapping_add(1));
        self.valid = match (ok, consecutive) {
            (true, true) => self.valid.saturating_add(1),
            (true, false) => 1,
            (false, _) => 0,
        };
        self.last_tick = Some(tick);
        self.valid
    }
}

/// When the supervisor scans iceoryx2's node directory for dead nodes (a file-system walk):
/// in the loop iteration that reaped a child, so its resources go before a successor needs
/// them, and otherwise at most once per `every`, for processes of the graph it did not start.
#[derive(Debug, Clone, Copy)]
struct CleanupSchedule {
    every: Duration,
    last: Option<Instant>,
}

impl CleanupSchedule {
    fn new(every: Duration) -> Self {
        Self { every, last: None }
    }

    /// Whether to scan now (`reaped`: a child was reaped in this iteration); a scan resets
    /// the safety-net timer.
    fn due(&mut self, reaped: bool, now: Instant) -> bool {
        let due = reaped
            || self
                .last
                .is_none_or(|t| now.saturating_duration_since(t) >= self.every);
        if due {
            self.last = Some(now);
        }
        due
    }
}

/// What the supervisor learns from the heartbeats.
#[derive(Default)]
struct Telemetry {
    ready: Vec<(NodeRole, u32)>,
    bridge_pid: u32,
    base_ticks: u64,
    base_missed: u64,
    base_held_up: u64,
    base_travel: f64,
    cur_ticks: u64,
    cur_missed: u64,
    cur_held_up: u64,
    cur_travel: f64,
    active_mapper: u32,
    /// End-to-end latencies and the bridge's lateness of every tick, in ns: of fixed size,
    /// whatever the run's length.
    latency_ns: Histogram,
    lateness_ns: Histogram,
    last_bridge_tick: Option<u64>,
    min_clearance_m: Option<f64>,
    max_tcp_speed_m_s: Option<f64>,
    /// When the bridge last published a heartbeat of a new tick (for systemd's watchdog).
    last_bridge_beat: Option<Instant>,
}

impl Telemetry {
    fn take(&mut self, s: &NodeStatus) {
        let Some(role) = NodeRole::from_u32(s.role) else {
            return;
        };
        if s.phase == phase::READY && !self.ready.contains(&(role, s.pid)) {
            self.ready.push((role, s.pid));
        }
        if role != NodeRole::Bridge || s.phase == phase::READY {
            return;
        }
        if s.pid != self.bridge_pid {
            // A new bridge process: bank the counts of the one before.
            self.base_ticks += self.cur_ticks;
            self.base_missed += self.cur_missed;
            self.base_held_up += self.cur_held_up;
            self.base_travel += self.cur_travel;
            self.bridge_pid = s.pid;
        }
        self.cur_ticks = s.handled;
        self.cur_missed = s.faults;
        self.cur_held_up = u64::from(s.held_up);
        self.cur_travel = s.joint_travel_rad;
        if s.phase == phase::RUNNING && self.last_bridge_tick != Some(s.tick) {
            self.last_bridge_tick = Some(s.tick);
            self.last_bridge_beat = Some(Instant::now());
            if s.latency_ns > 0 {
                self.latency_ns.record(s.latency_ns);
                self.active_mapper = s.mapper_id;
            }
            self.lateness_ns.record(s.lateness_ns);
        }
    }

    /// Takes in a command safety published: its whole-arm figures, where it checked them
    /// (a finite clearance).
    fn take_safe(&mut self, c: &SafeCommand) {
        let (d, v) = (c.clearance_m, c.tcp_speed_m_s);
        if d.is_finite() {
            self.min_clearance_m = Some(self.min_clearance_m.map_or(d, |m| m.min(d)));
            if v.is_finite() {
                self.max_tcp_speed_m_s = Some(self.max_tcp_speed_m_s.map_or(v, |m| m.max(v)));
            }
        }
    }

    fn is_ready(&self, role: NodeRole, pid: u32) -> bool {
        self.ready.contains(&(role, pid))
    }

    fn ticks(&self) -> u64 {
        self.base_ticks + self.cur_ticks
    }

    fn missed(&self) -> u64 {
        self.base_missed + self.cur_missed
    }

    fn held_up(&self) -> u64 {
        self.base_held_up + self.cur_held_up
    }

    fn travel(&self) -> f64 {
        self.base_travel + self.cur_travel
    }
}

type Request = ActiveControlRequest;

enum SwapPhase {
    /// Waiting for the new mapper's valid consecutive commands.
    Warmup(Warmup),
    /// Safety was told to switch at `from_tick`; waiting for the bridge to get its command.
    Switching { from_tick: u64 },
}

struct Swap {
    request: Request,
    new_id: u32,
    old_id: u32,
    started: Instant,
    missed_at_start: u64,
    /// `Telemetry::held_up` when the request came.
    held_up_at_start: u64,
    phase: SwapPhase,
}

/// Everything the supervisor keeps while the graph runs.
struct Supervisor<'a> {
    opts: &'a UpOptions,
    graph: Graph,
    procs: Vec<Managed>,
    tel: Telemetry,
    last_state: Option<RobotState>,
    next_mapper_id: u32,
    active_mapper: u32,
    restarts: u32,
    swaps: u32,
    control_seq: u64,
    swap: Option<Swap>,
    switch_publisher: Option<SafetyControlPublisher>,
    /// The switch last sent to safety: mapper id and first tick.
    switch: (u32, u64),
    /// Whether safety is told to hold the arm (the joystick is down).
    hold: bool,
    /// E-stop state relayed to safety: change counter and latched or not.
    estop: (u32, bool),
    /// When to scan for dead nodes.
    cleanup: CleanupSchedule,
}

fn spawn(args: &[String]) -> std::io::Result<Child> {
    command(args)?.spawn()
}

/// The command line of a child: this binary with `args`, in its own process group, sent
/// SIGTERM if the supervisor dies.
fn command(args: &[String]) -> std::io::Result<Command> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.args(args);
    // SAFETY: setpgid and prctl are async-signal-safe and the closure allocates nothing.
    // Each child gets its own process group, so a terminal's Ctrl-C reaches only the
    // supervisor, which then stops the graph in order (bridge first); and each child gets
    // SIGTERM if the supervisor dies, so no process of the graph outlives it. Failures are
    // ignored, as before: the child runs either way.
    unsafe {
        cmd.pre_exec(|| {
            let _ = nix::unistd::setpgid(Pid::from_raw(0), Pid::from_raw(0));
            let _ = nix::sys::prctl::set_pdeathsig(Signal::SIGTERM);
            Ok(())
        });
    }
    Ok(cmd)
}

fn terminate(child: &Child) {
    // Our own child's pid; an error means it is gone already, which the caller's wait sees.
    let _ = kill(Pid::from_raw(child.id() as i32), Signal::SIGTERM);
}

/// Starts `scl live --listen addr --announce` and waits until it says it serves (or could
/// not start, or exits). The child announces itself on its standard output
/// ([`node_rt::ready`]) once its own server listens and it has joined the graph, so another
/// program that happens to listen on the same port is never taken for it: the live server's
/// error (the port in use, ...) is then this function's, and the graph does not start.
fn start_live(
    sv: &Supervisor<'_>,
    addr: &str,
    timeout: Duration,
) -> Result<Child, SupervisorError> {
    use node_rt::ready::{self, Announcement};
    let _: std::net::SocketAddr = addr
        .parse()
        .map_err(|source| SupervisorError::LiveAddress {
            addr: addr.to_owned(),
            source,
        })?;
    let mut args = sv.child_args("live");
    args.extend([
        "--listen".to_owned(),
        addr.to_owned(),
        "--announce".to_owned(),
    ]);
    let spawn_error = |source| SupervisorError::Spawn {
        process: "live",
        source,
    };
    let mut cmd = command(&args).map_err(spawn_error)?;
    let mut child = cmd
        .stdout(std::process::Stdio::piped())
        .spawn()
        .map_err(spawn_error)?;
    let (tx, rx) = std::sync::mpsc::channel();
    if let Some(out) = child.stdout.take() {
        // Reads the announcement, then whatever else the child writes there (nothing, today)
        // until it exits, so it never writes into a closed pipe.
        let reader = std::thread::Builder::new()
            .name("live-announce".into())
            .spawn(move || {
                use std::io::BufRead;
                let mut lines = std::io::BufReader::new(out).lines();
                for line in lines.by_ref() {
                    let Ok(line) = line else { break };
                    if let Some(a) = ready::parse(&line) {
                        let _ = tx.send(a);
                        break;
                    }
                }
                lines.for_each(drop);
            });
        if let Err(e) = reader {
            stop_live(&mut child);
            return Err(LiveStartError::Announcement(e).into());
        }
    }
    let t0 = Instant::now();
    loop {
        match rx.recv_timeout(Duration::from_millis(20)) {
            Ok(Announcement::Ready(at)) => {
                tracing::info!("Foxglove: open a connection to ws://{at}");
                return Ok(child);
            }
            Ok(Announcement::Failed(reason)) => {
                let st = wait_exit(&mut child);
                return Err(LiveStartError::Refused { status: st, reason }.into());
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                // Its standard output closed without a word: it exited (or closed it).
                let st = wait_exit(&mut child);
                return Err(LiveStartError::Exited {
                    status: st,
                    addr: addr.to_owned(),
                }
                .into());
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
        }
        if t0.elapsed() > timeout {
            stop_live(&mut child);
            return Err(LiveStartError::Timeout {
                addr: addr.to_owned(),
                timeout,
            }
            .into());
        }
    }
}

/// Waits for a live child that is exiting by itself (SIGTERM, then SIGKILL after 3 s, if it
/// does not); says how it ended.
fn wait_exit(child: &mut Child) -> String {
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(3) {
        if let Ok(Some(st)) = child.try_wait() {
            return st.to_string();
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    stop_live(child);
    "still running; stopped".to_owned()
}

/// Stops the live child (SIGTERM, then SIGKILL after 3 s); says if it had died already.
fn stop_live(child: &mut Child) {
    if let Ok(Some(st)) = child.try_wait() {
        tracing::warn!("scl live had exited during the run ({st})");
        return;
    }
    terminate(child);
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(3) {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    tracing::warn!("scl live did not stop within 3 s; killing it");
    let _ = child.kill();
    let _ = child.wait();
}

fn signal_and_wait(p: &mut Managed, timeout: Duration) {
    let label = p.label();
    let Some(child) = p.child.as_mut() else {
        return;
    };
    terminate(child);
    let start = Instant::now();
    loop {
        if let Ok(Some(_)) = child.try_wait() {
            break;
        }
        if start.elapsed() > timeout {
            tracing::warn!("{label} did not stop within {timeout:?}; killing it");
            let _ = child.kill();
            let _ = child.wait();
            break;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    p.child = None;
}

impl<'a> Supervisor<'a> {
    fn child_args(&self, sub: &str) -> Vec<String> {
        let mut a = vec![
            sub.to_owned(),
            "--prefix".into(),
            self.opts.prefix.to_string(),
        ];
        if let Some(p) = &self.opts.config_path {
            a.push("--config".into());
            a.push(p.display().to_string());
        }
        a
    }

    fn mapper_args(&self, model: &str, id: u32) -> Vec<String> {
        let mut a = self.child_args("mapper");
        a.extend([
            "--model".into(),
            model.to_owned(),
            "--id".into(),
            id.to_string(),
        ]);
        a
    }

    /// Starts (or restarts) process `i`. A restarted bridge resumes from the last state.
    fn start(&mut self, i: usize) -> Result<(), SupervisorError> {
        let mut args = self.procs[i].args.clone();
        if self.procs[i].role == NodeRole::Bridge
            && let Some(s) = &self.last_state
        {
            let q: Vec<String> = s.q().iter().map(|v| format!("{v:.9}")).collect();
            args.push(format!("--start-tick={}", s.tick + 1));
            args.push(format!("--resume-q={}", q.join(",")));
            args.push(format!("--resume-gripper={:.9}", s.gripper));
            // The periods until the new bridge's first state are counted as missed.
            args.push(format!("--resume-t-ns={}", s.t_ns));
        }
        let p = &mut self.procs[i];
        let child = spawn(&args).map_err(|source| SupervisorError::Spawn {
            process: p.role.name(),
            source,
        })?;
        p.pid = child.id();
        p.child = Some(child);
        p.started = Instant::now();
        p.restart_at = None;
        Ok(())
    }

    fn push(&mut self, role: NodeRole, mapper_id: u32, args: Vec<String>) -> usize {
        self.procs.push(Managed {
            role,
            mapper_id,
            args,
            child: None,
            pid: 0,
            started: Instant::now(),
            failures: 0,
            restart_at: None,
            retiring: false,
        });
        self.procs.len() - 1
    }

    /// Reaps exited children; returns a failure message if the graph must stop.
    fn reap(&mut self) -> Option<String> {
        let sv = &self.opts.config.supervisor;
        let mut failure = None;
        let mut refuse_swap = None;
        let mut reaped = false;
        for p in self.procs.iter_mut() {
            let Some(child) = p.child.as_mut() else {
                continue;
            };
            let Ok(Some(status)) = child.try_wait() else {
                continue;
            };
            reaped = true;
            p.child = None;
            let what = format!("{} {}", p.label(), describe(status));
            if p.retiring {
                tracing::info!("{what}");
                continue;
            }
            if self.swap.as_ref().is_some_and(|s| s.new_id == p.mapper_id)
                && p.role == NodeRole::Mapper
            {
                p.retiring = true;
                refuse_swap = Some(format!(
                    "the new mapper stopped before the switch-over: {what}"
                ));
                continue;
            }
            let decision = decide_restart(
                sv,
                p.role,
                status.success(),
                p.started.elapsed(),
                p.failures,
            );
            let RestartDecision::After { delay, failures } = decision else {
                failure = Some(what);
                break;
            };
            if signals::stop_requested() {
                failure = Some(what);
                break;
            }
            p.failures = failures;
            p.restart_at = Some(Instant::now() + delay);
            self.restarts += 1;
            tracing::warn!(
                "{what}; restarting it in {delay:?} (restart {} of this process)",
                p.failures
            );
        }
        // What the dead left in shared memory (ports, a publisher slot) goes now, before a
        // successor needs it.
        if self.cleanup.due(reaped, Instant::now()) {
            self.cleanup_dead_nodes();
        }
        self.procs.retain(|p| !(p.retiring && p.child.is_none()));
        if let Some(reason) = refuse_swap {
            self.finish_swap(Err(reason));
        }
        failure
    }

    /// Removes the resources of the graph's dead nodes.
    fn cleanup_dead_nodes(&self) {
        let cleaned = self.graph.cleanup_dead_nodes();
        if cleaned > 0 {
            tracing::debug!(cleaned, "removed resources of dead processes");
        }
    }

    fn restart_due(&mut self) -> Result<(), SupervisorError> {
        let now = Instant::now();
        let mut scanned = false;
        for i in 0..self.procs.len() {
            if self.procs[i].restart_at.is_some_and(|t| t <= now) {
                if !scanned {
                    // Already done when the child was reaped; again in case its node was
                    // not yet seen dead then. Restarts are rare.
                    self.cleanup.due(true, now);
                    self.cleanup_dead_nodes();
                    scanned = true;
                }
                self.start(i)?;
                tracing::info!("restarted {}", self.procs[i].label());
            }
        }
        Ok(())
    }

    fn publish_switch(&mut self, id: u32, from_tick: u64) -> Result<(), SupervisorError> {
        self.switch = (id, from_tick);
        self.publish_control()
    }

    /// Holds the arm while the joystick process (or the gateway that stands for a remote
    /// operator) is down or restarting (not yet ready): the mapper would otherwise keep
    /// acting on its last sample until safety found it stale.
    fn update_hold(&mut self) -> Result<(), SupervisorError> {
        let remote_joystick =
            self.opts.config.network.enabled && self.opts.config.network.accept_joystick;
        let down = self.procs.iter().any(|p| {
            (p.role == NodeRole::Joystick || (remote_joystick && p.role == NodeRole::Gateway))
                && !p.retiring
                && (p.child.is_none() || !self.tel.is_ready(p.role, p.pid))
        });
        if down != self.hold {
            self.hold = down;
            if down {
                tracing::warn!("the joystick is down: safety holds the arm");
            } else {
                tracing::info!("the joystick is back: hold released");
            }
            self.publish_control()?;
        }
        Ok(())
    }

    fn publish_control(&mut self) -> Result<(), SupervisorError> {
        let (id, from_tick) = self.switch;
        self.control_seq += 1;
        let publisher = match self.switch_publisher.take() {
            Some(p) => p,
            None => self.graph.safety_control_publisher()?,
        };
        let msg = SafetyControl {
            seq: self.control_seq,
            t_ns: now_ns(),
            from_tick,
            active_mapper: id,
            hold: u32::from(self.hold),
            estop_seq: self.estop.0,
            estop: u32::from(self.estop.1),
        };
        publisher.send(msg)?;
        // Keep the publisher (and with it the topic's history for a restarted safety).
        self.switch_publisher = Some(publisher);
        Ok(())
    }

    fn begin_swap(&mut self, request: Request) {
        let req = *request.payload();
        let refuse = |request: &Request, reason: &str| {
            tracing::warn!("swap refused: {reason}");
            let _ = request.send_copy(ControlResponse::refused(reason));
        };
        if self.swap.is_some() {
            refuse(&request, "another swap is in progress");
            return;
        }
        if req.kind != request_kind::SWAP {
            refuse(&request, &format!("unknown request kind {}", req.kind));
            return;
        }
        let model = req.path.as_string();
        let new_id = self.next_mapper_id;
        let loaded = self.opts.config.profile().map_or_else(
            |e| Err(SupervisorError::from(e)),
            |robot| {
                let period_s = self.opts.config.period_s();
                Ok(MapperStep::load(&model, new_id, robot, period_s)?)
            },
        );
        if let Err(e) = loaded {
            refuse(&request, &e.to_string());
            return;
        }
        self.next_mapper_id += 1;
        let args = self.mapper_args(&model, new_id);
        let i = self.push(NodeRole::Mapper, new_id, args);
        if let Err(e) = self.start(i) {
            self.procs.remove(i);
            refuse(&request, &e.to_string());
            return;
        }
        tracing::info!(new_id, model = %model, "swap: new mapper started, warming up");
        self.swap = Some(Swap {
            request,
            new_id,
            old_id: self.active_mapper,
            started: Instant::now(),
            missed_at_start: self.tel.missed(),
            held_up_at_start: self.tel.held_up(),
            phase: SwapPhase::Warmup(Warmup::default()),
        });
    }

    fn on_mapper_command(&mut self, c: &MapperCommand) -> Result<(), SupervisorError> {
        let need = self.opts.config.supervisor.swap_valid_ticks;
        let Some(swap) = self.swap.as_mut() else {
            return Ok(());
        };
        let SwapPhase::Warmup(warmup) = &mut swap.phase else {
            return Ok(());
        };
        if c.mapper_id != swap.new_id {
            return Ok(());
        }
        if warmup.observe(c.tick, command_valid(c)) >= need {
            // Two ticks ahead: safety has the switch before that tick's commands arrive.
            let from_tick = c.tick + 2;
            let new_id = swap.new_id;
            swap.phase = SwapPhase::Switching { from_tick };
            self.publish_switch(new_id, from_tick)?;
            tracing::info!(
                new_id,
                from_tick,
                "swap: safety switches at tick {from_tick}"
            );
        }
        Ok(())
    }

    fn on_safe_command(&mut self, tick: u64, mapper_id: u32) {
        let Some(swap) = self.swap.as_ref() else {
            return;
        };
        if let SwapPhase::Switching { from_tick } = swap.phase
            && tick >= from_tick
            && mapper_id == swap.new_id
        {
            self.finish_swap(Ok(tick));
        }
    }

    /// Ends the swap in flight: on success stops the old mapper; on failure stops the new one
    /// and, if safety was already told to switch, tells it to switch back.
    fn finish_swap(&mut self, result: Result<u64, String>) {
        let Some(swap) = self.swap.take() else {
            return;
        };
        let retire = match &result {
            Ok(_) => swap.old_id,
            Err(_) => swap.new_id,
        };
        for p in self.procs.iter_mut() {
            if p.role == NodeRole::Mapper && p.mapper_id == retire && !p.retiring {
                p.retiring = true;
                p.restart_at = None;
                if let Some(c) = p.child.as_ref() {
                    terminate(c);
                }
            }
        }
        let resp = match result {
            Ok(switch_tick) => {
                // A late command's verdict comes a tick after its miss: at most the misses.
                let missed_during = self.tel.missed().saturating_sub(swap.missed_at_start);
                let held_up_during = self
                    .tel
                    .held_up()
                    .saturating_sub(swap.held_up_at_start)
                    .min(missed_during);
                self.active_mapper = swap.new_id;
                self.swaps += 1;
                let r = ControlResponse {
                    ok: 1,
                    new_mapper: swap.new_id,
                    old_mapper: swap.old_id,
                    held_up_during: u32::try_from(held_up_during).unwrap_or(u32::MAX),
                    switch_tick,
                    elapsed_ns: swap.started.elapsed().as_nanos() as u64,
                    missed_during,
                    message: Text::new("switched"),
                };
                tracing::info!(
                    new = swap.new_id,
                    old = swap.old_id,
                    switch_tick,
                    elapsed_ms = r.elapsed_ns as f64 / 1e6,
                    missed = r.missed_during,
                    held_up = r.held_up_during,
                    "swap done"
                );
                r
            }
            Err(reason) => {
                if matches!(swap.phase, SwapPhase::Switching { .. }) {
                    let back = self.last_state.map_or(0, |s| s.tick + 2);
                    if let Err(e) = self.publish_switch(swap.old_id, back) {
                        tracing::error!("cannot switch safety back: {e}");
                    }
                }
                tracing::warn!("swap refused: {reason}");
                ControlResponse::refused(&reason)
            }
        };
        if let Err(e) = swap.request.send_copy(resp) {
            tracing::warn!("cannot answer the swap request: {e}");
        }
    }

    fn check_swap_timeout(&mut self) {
        let timeout = Duration::from_secs_f64(self.opts.config.supervisor.swap_timeout_s);
        let Some(swap) = self.swap.as_ref() else {
            return;
        };
        if swap.started.elapsed() < timeout {
            return;
        }
        let reason = match swap.phase {
            SwapPhase::Warmup(Warmup { valid, .. }) => format!(
                "the new mapper produced {valid} valid consecutive commands in {timeout:?}, {} needed",
                self.opts.config.supervisor.swap_valid_ticks
            ),
            SwapPhase::Switching { from_tick } => {
                format!("safety did not forward the new mapper's commands from tick {from_tick}")
            }
        };
        self.finish_swap(Err(reason));
    }
}

/// Runs the graph; returns the summary, with `failure` set if a child died for good.
///
/// The caller has checked `[joystick]` (`scl_joystick::validate`, the joystick's sources and
/// their files: `scl up` does, before this) so that a bad one is refused before anything
/// starts; the graph configuration and the model are checked here.
///
/// The steps: check, join the graph, start the children in order ([`start_children`]),
/// supervise every 2 ms until a shutdown, a lasting failure or `--for` ends the run, stop the
/// children bridge first ([`Supervisor::stop_children`]), release the graph.
pub fn run(opts: &UpOptions) -> Result<Summary, SupervisorError> {
    let cfg = &opts.config;
    check_before_start(opts)?;
    let graph = join_graph(opts)?;
    let ports = Ports::open(&graph)?;
    let mut sv = Supervisor::new(opts, graph);
    // Reaping and holding the arm must not wait behind other load; below the control path.
    node_rt::rt::elevate(&cfg.graph, scl_config::RtRole::Supervisor);
    // Idle CPUs kept out of deep sleep while the graph runs; released when `_dma` drops.
    let (_dma, _) = node_rt::rt::hold_dma_latency(&cfg.graph);
    let start_timeout = Duration::from_secs_f64(cfg.graph.start_timeout_s);
    let mut live = match &opts.live {
        Some(addr) => Some(start_live(&sv, addr, start_timeout)?),
        None => None,
    };
    let plan = start_plan(&sv);
    let mut failure = start_children(&mut sv, plan, &ports.status, start_timeout)?;

    let started = Instant::now();
    let mut next_report = Duration::from_secs(1);
    let (notifier, mut watchdog) = systemd_notifier(cfg);
    while failure.is_none() && !signals::stop_requested() {
        std::thread::sleep(Duration::from_millis(2));
        if let Some(f) = sv.reap() {
            failure = Some(f);
            break;
        }
        sv.restart_due()?;
        ports.status.drain(|s| sv.tel.take(s))?;
        sv.update_hold()?;
        sv.relay_estops(&ports.estops)?;
        sv.take_commands(&ports)?;
        sv.serve_swaps(&ports.server)?;
        if let Some(n) = &notifier
            && let Some(notice) =
                watchdog.poll(Instant::now(), sv.tel.ticks() > 0, sv.tel.last_bridge_beat)
        {
            n.send(notice.message());
        }

        let elapsed = started.elapsed();
        if elapsed >= next_report {
            next_report += Duration::from_secs(1);
            sv.report_progress(elapsed);
        }
        if opts.duration.is_some_and(|d| elapsed >= d) {
            break;
        }
    }
    let duration_s = started.elapsed().as_secs_f64();
    if let Some(n) = &notifier {
        n.send("STOPPING=1");
    }
    if sv.swap.is_some() {
        sv.finish_swap(Err("the graph is shutting down".into()));
    }
    sv.stop_children(&ports.status);
    if let Some(child) = live.as_mut() {
        stop_live(child);
    }
    ports.status.drain(|s| sv.tel.take(s))?;
    ports.safe_commands.drain(|c| sv.tel.take_safe(c))?;
    let summary = sv.summary(duration_s, failure);
    drop(ports);
    drop(sv);
    // Last one out: remove what killed children left and the domain itself, unless an
    // observer (a recorder, a test) is still attached; it releases the domain when it leaves.
    transport::graph::release_domain(&opts.prefix)?;
    if cfg.graph.transport == ipc_types::Transport::Uds {
        transport::uds::remove_graph(opts.prefix.as_str());
    }
    if let Some(f) = &summary.failure {
        tracing::error!("{f}; the graph was stopped (bridge first)");
    }
    Ok(summary)
}

/// Refuses a bad configuration, model or credentials file, or a recording over an existing
/// file, before anything starts.
fn check_before_start(opts: &UpOptions) -> Result<(), SupervisorError> {
    let cfg = &opts.config;
    cfg.validate_file(opts.config_path.as_deref())?;
    // A polling process that would starve another is refused here, before any starts.
    let placement = cfg.graph.placement(&node_rt::wait::machine_cpus())?;
    for note in &placement.notes {
        tracing::info!("wait: {note}");
    }
    MapperStep::load(
        &cfg.mapper.model,
        cfg.mapper.id,
        cfg.profile()?,
        cfg.period_s(),
    )?;
    if let Some(p) = opts.record.as_ref().filter(|p| p.exists()) {
        return Err(recording::RecordError::Exists(p.clone()).into());
    }
    // Both credentials files, by the one rule (`scl_config::secret`): refused here, naming
    // the file and its mode, rather than by the gateway or the bridge once the others run.
    let net = &cfg.network;
    if net.enabled && !net.credentials.is_empty() {
        scl_net::Credentials::load(std::path::Path::new(&net.credentials))?;
    }
    let kortex = &cfg.bridge.kortex;
    if cfg.bridge.robot == "kortex" && !kortex.credentials_file.is_empty() {
        scl_config::secret::read_kortex_credentials(std::path::Path::new(
            &kortex.credentials_file,
        ))?;
    }
    Ok(())
}

/// Removes what dead processes of the graph left, then joins it as the supervisor.
fn join_graph(opts: &UpOptions) -> Result<Graph, SupervisorError> {
    let cleaned = transport::graph::cleanup_dead_nodes(&opts.prefix)?;
    if cleaned > 0 {
        tracing::info!(
            cleaned,
            "removed resources of dead processes of graph `{}`",
            opts.prefix
        );
    }
    Ok(Graph::join_with(
        &opts.prefix,
        "supervisor",
        opts.config.graph.transport,
    )?)
}

/// The topics and services the supervisor reads while the graph runs (dropped in this
/// order, before the graph).
struct Ports {
    status: transport::TopicSubscriber<NodeStatus>,
    states: transport::TopicSubscriber<RobotState>,
    mapper_commands: transport::TopicSubscriber<MapperCommand>,
    safe_commands: transport::TopicSubscriber<SafeCommand>,
    server: transport::control::ControlServer,
    estops: transport::control::EstopSubscriber,
}

impl Ports {
    fn open(graph: &Graph) -> Result<Self, SupervisorError> {
        Ok(Self {
            status: graph.status_subscriber()?,
            states: graph.robot_state_subscriber(false)?,
            mapper_commands: graph.mapper_command_subscriber(false)?,
            safe_commands: graph.safe_command_subscriber(false)?,
            server: graph.control_server()?,
            estops: graph.estop_subscriber()?,
        })
    }
}

/// The children to start, in order: role, mapper id, arguments.
type StartPlan = Vec<(NodeRole, u32, Vec<String>)>;

/// The children to start, in order: the recorder (if recording), the joystick (unless the
/// source is external or a remote operator's), the gateway (`[network] enabled`), the mapper,
/// safety, and the bridge (the clock) last.
fn start_plan(sv: &Supervisor<'_>) -> StartPlan {
    let (opts, cfg) = (sv.opts, &sv.opts.config);
    let mut plan = Vec::new();
    if let Some(path) = &opts.record {
        // The recorder first: it sees the graph from its first message on.
        let mut args = sv.child_args("record");
        args.extend(["--out".to_owned(), path.display().to_string()]);
        plan.push((NodeRole::Recorder, 0, args));
    }
    let net = &cfg.network;
    if net.enabled && net.accept_joystick {
        // The gateway is the joystick: a remote operator's samples, or a neutral "device
        // gone" sample on every tick while none drives.
        tracing::info!(
            "[network] accept_joystick: the joystick is a remote operator's, through the gateway"
        );
    } else if cfg.joystick.source == scl_config::EXTERNAL_JOYSTICK {
        // No joystick process: the operator publishes from outside (nothing to hold for).
        tracing::info!(
            "joystick source `external`: the input comes from whoever publishes on `{}`",
            opts.prefix.service(ipc_types::topics::JOYSTICK.name)
        );
    } else {
        plan.push((NodeRole::Joystick, 0, {
            // `scl up --script` overrides the config file the child reads.
            let mut a = sv.child_args("joystick");
            a.extend(["--script".to_owned(), cfg.joystick.script.clone()]);
            a
        }));
    }
    if net.enabled {
        plan.push((NodeRole::Gateway, 0, sv.child_args("gateway")));
    }
    plan.extend([
        (
            NodeRole::Mapper,
            cfg.mapper.id,
            sv.mapper_args(&cfg.mapper.model, cfg.mapper.id),
        ),
        (NodeRole::Safety, 0, sv.child_args("safety")),
        (NodeRole::Bridge, 0, sv.child_args("bridge")),
    ]);
    plan
}

/// Starts the children of `plan` in order, each awaited until it reports ready; returns why
/// the start-up stopped (a child died, or did not report ready within `start_timeout`), if
/// it did.
fn start_children(
    sv: &mut Supervisor<'_>,
    plan: StartPlan,
    status: &transport::TopicSubscriber<NodeStatus>,
    start_timeout: Duration,
) -> Result<Option<String>, SupervisorError> {
    for (role, id, args) in plan {
        let i = sv.push(role, id, args);
        sv.start(i)?;
        let t0 = Instant::now();
        while !sv.tel.is_ready(role, sv.procs[i].pid) {
            status.drain(|s| sv.tel.take(s))?;
            if let Some(c) = sv.procs[i].child.as_mut()
                && let Ok(Some(s)) = c.try_wait()
            {
                sv.procs[i].child = None;
                return Ok(Some(format!(
                    "the {} process {} during start-up",
                    role.name(),
                    describe(s)
                )));
            }
            if t0.elapsed() > start_timeout || signals::stop_requested() {
                return Ok(Some(format!(
                    "the {} process did not report ready within {start_timeout:?}",
                    role.name()
                )));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    Ok(None)
}

/// Under systemd (Type=notify): ready after the first executed tick, the watchdog petted
/// while the bridge beats (ten periods of silence make it stale).
fn systemd_notifier(
    cfg: &GraphConfig,
) -> (Option<crate::notify::Notifier>, crate::notify::Watchdog) {
    let notifier = crate::notify::Notifier::from_env().unwrap_or_else(|e| {
        tracing::warn!("{e}; systemd will not be notified");
        None
    });
    let watchdog = crate::notify::Watchdog::new(
        crate::notify::watchdog_from_env(),
        Duration::from_secs_f64(10.0 * cfg.period_s()),
    );
    (notifier, watchdog)
}

impl<'a> Supervisor<'a> {
    /// A supervisor of the graph `graph` with no child yet.
    fn new(opts: &'a UpOptions, graph: Graph) -> Self {
        let cfg = &opts.config;
        Self {
            opts,
            graph,
            procs: Vec::new(),
            tel: Telemetry::default(),
            last_state: None,
            next_mapper_id: cfg.mapper.id + 1,
            active_mapper: cfg.mapper.id,
            restarts: 0,
            swaps: 0,
            control_seq: 0,
            swap: None,
            switch_publisher: None,
            switch: (cfg.mapper.id, 0),
            hold: false,
            estop: (0, false),
            cleanup: CleanupSchedule::new(Duration::from_secs(1)),
        }
    }

    /// Relays e-stops into the control topic, whose history outlives `scl estop`: a
    /// restarted safety comes up still latched.
    fn relay_estops(
        &mut self,
        estops: &transport::control::EstopSubscriber,
    ) -> Result<(), SupervisorError> {
        let mut pending = Vec::new();
        estops.drain(|e| pending.push(*e))?;
        for e in pending {
            self.estop = (
                self.estop.0.wrapping_add(1),
                e.action == ipc_types::control::estop_action::ESTOP,
            );
            self.publish_control()?;
        }
        Ok(())
    }

    /// Takes what the graph published since the last turn: the newest state, the mappers'
    /// commands (a swap's warm-up), the commands safety forwarded (the telemetry, a swap's
    /// switch).
    fn take_commands(&mut self, ports: &Ports) -> Result<(), SupervisorError> {
        ports.states.drain(|s| self.last_state = Some(*s))?;
        let mut cmds = Vec::new();
        ports.mapper_commands.drain(|c| cmds.push(*c))?;
        for c in &cmds {
            self.on_mapper_command(c)?;
        }
        let mut executed = Vec::new();
        ports.safe_commands.drain(|c| {
            executed.push((c.tick, c.mapper_id));
            self.tel.take_safe(c);
        })?;
        for (tick, id) in executed {
            self.on_safe_command(tick, id);
        }
        Ok(())
    }

    /// Begins the swaps requested on the control service and refuses one that took too long.
    fn serve_swaps(
        &mut self,
        server: &transport::control::ControlServer,
    ) -> Result<(), SupervisorError> {
        while let Some(request) = server.receive().map_err(|e| SupervisorError::Control {
            what: "cannot read the control service",
            source: e.into(),
        })? {
            self.begin_swap(request);
        }
        self.check_swap_timeout();
        Ok(())
    }

    /// Prints the once-a-second progress line.
    fn report_progress(&self, elapsed: Duration) {
        let l = self.tel.latency_ns.percentiles_us();
        let restarts = if self.restarts > 0 {
            format!("  restarts {}", self.restarts)
        } else {
            String::new()
        };
        eprintln!(
            "scl up: {:>4.0}s  ticks {:>6}  missed {:>3}  e2e p50 {:>6.1} µs  p99 {:>7.1} µs  mapper {}{restarts}",
            elapsed.as_secs_f64(),
            self.tel.ticks(),
            self.tel.missed(),
            l.p50,
            l.p99,
            self.active_mapper,
        );
    }

    /// Stops the children: the bridge first (it stops the arm at once and publishes a final
    /// state), the recorder last, so the file holds everything up to the end. The heartbeats
    /// are taken in after each process is gone: the bridge's last one carries its final
    /// counts, and the others' heartbeats while they are stopped (one per period at 1 kHz)
    /// would otherwise overwrite it in the subscriber's buffer before the summary reads them
    /// (seen on a CPU-throttled machine: the summary's `held_up` 5 short of the log's).
    fn stop_children(&mut self, status: &transport::TopicSubscriber<NodeStatus>) {
        for role in [
            NodeRole::Bridge,
            NodeRole::Safety,
            NodeRole::Mapper,
            NodeRole::Joystick,
            NodeRole::Gateway,
            NodeRole::Recorder,
        ] {
            for p in self.procs.iter_mut().filter(|p| p.role == role) {
                signal_and_wait(p, Duration::from_secs(3));
            }
            // Every child is stopped whatever the heartbeats say: a failed read is logged.
            if let Err(e) = status.drain(|s| self.tel.take(s)) {
                tracing::warn!("while stopping the graph, the heartbeats could not be read: {e}");
            }
        }
    }

    /// The run's summary, `duration_s` long, with the `failure` that ended it.
    fn summary(&self, duration_s: f64, failure: Option<String>) -> Summary {
        Summary {
            ticks: self.tel.ticks(),
            missed: self.tel.missed(),
            held_up: self.tel.held_up(),
            latency_us: self.tel.latency_ns.percentiles_us(),
            tick_lateness_us: self.tel.lateness_ns.percentiles_us(),
            joint_travel_rad: self.tel.travel(),
            latency_samples: self.tel.latency_ns.len() as usize,
            duration_s,
            prefix: self.opts.prefix.to_string(),
            active_mapper: self.tel.active_mapper,
            restarts: self.restarts,
            swaps: self.swaps,
            failure,
            min_clearance_m: self.tel.min_clearance_m,
            max_tcp_speed_m_s: self.tel.max_tcp_speed_m_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use scl_config::RestartPolicies;

    const MS: fn(u64) -> Duration = Duration::from_millis;

    /// Both credentials files follow one rule, checked before anything starts: a Kortex
    /// file others may read is refused naming its mode, as the network's is; a private one
    /// passes (and with the mock arm the Kortex file is not read).
    #[test]
    fn a_kortex_credentials_file_others_may_read_is_refused_before_the_start() {
        use std::os::unix::fs::PermissionsExt as _;
        let dir = std::env::temp_dir().join(format!("scl-up-creds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("kortex.toml");
        std::fs::write(&f, "username = \"u\"\npassword = \"p\"\n").unwrap();
        let mut config = GraphConfig::default();
        config.bridge.kortex.credentials_file = f.display().to_string();
        let mut opts = UpOptions {
            prefix: Prefix::new("upcreds").unwrap(),
            config_path: None,
            config,
            duration: None,
            json: false,
            record: None,
            live: None,
        };
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o644)).unwrap();
        check_before_start(&opts).unwrap();
        opts.config.bridge.robot = "kortex".into();
        let e = check_before_start(&opts).unwrap_err().to_string();
        assert!(e.contains("0644") && e.contains("kortex.toml"), "{e}");
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o600)).unwrap();
        check_before_start(&opts).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn config(policy: RestartPolicy) -> SupervisorConfig {
        SupervisorConfig {
            backoff_initial_ms: 100,
            backoff_max_ms: 1000,
            stable_after_s: 10.0,
            restart: RestartPolicies {
                joystick: policy,
                mapper: policy,
                safety: policy,
                bridge: policy,
                gateway: policy,
            },
            ..SupervisorConfig::default()
        }
    }

    fn after(delay_ms: u64, failures: u32) -> RestartDecision {
        RestartDecision::After {
            delay: MS(delay_ms),
            failures,
        }
    }

    #[test]
    fn policies_decide_which_exits_restart() {
        let roles = [
            NodeRole::Joystick,
            NodeRole::Mapper,
            NodeRole::Safety,
            NodeRole::Bridge,
        ];
        for role in roles {
            let never = config(RestartPolicy::Never);
            let on_failure = config(RestartPolicy::OnFailure);
            let always = config(RestartPolicy::Always);
            let ran = MS(50);
            assert_eq!(
                decide_restart(&never, role, false, ran, 0),
                RestartDecision::Stop
            );
            assert_eq!(
                decide_restart(&never, role, true, ran, 0),
                RestartDecision::Stop
            );
            assert_eq!(
                decide_restart(&on_failure, role, false, ran, 0),
                after(100, 1)
            );
            assert_eq!(
                decide_restart(&on_failure, role, true, ran, 0),
                RestartDecision::Stop,
                "a clean exit under on-failure stops the graph"
            );
            assert_eq!(decide_restart(&always, role, false, ran, 0), after(100, 1));
            assert_eq!(decide_restart(&always, role, true, ran, 0), after(100, 1));
        }
        // A recorder is never restarted, whatever the policies say.
        let always = config(RestartPolicy::Always);
        assert_eq!(
            decide_restart(&always, NodeRole::Recorder, false, MS(50), 0),
            RestartDecision::Stop
        );
    }

    #[test]
    fn policies_apply_per_role() {
        let mut sv = config(RestartPolicy::Never);
        sv.restart.safety = RestartPolicy::Always;
        assert_eq!(
            decide_restart(&sv, NodeRole::Mapper, false, MS(1), 0),
            RestartDecision::Stop
        );
        assert_eq!(
            decide_restart(&sv, NodeRole::Safety, false, MS(1), 0),
            after(100, 1)
        );
    }

    #[test]
    fn backoff_doubles_up_to_the_maximum() {
        let sv = config(RestartPolicy::OnFailure);
        let mut failures = 0;
        let mut delays = Vec::new();
        for _ in 0..7 {
            let RestartDecision::After { delay, failures: f } =
                decide_restart(&sv, NodeRole::Mapper, false, MS(200), failures)
            else {
                panic!("on-failure did not restart a crash");
            };
            assert_eq!(f, failures + 1);
            failures = f;
            delays.push(delay.as_millis());
        }
        assert_eq!(delays, [100, 200, 400, 800, 1000, 1000, 1000]);
        // No overflow however long a process keeps failing.
        assert_eq!(
            decide_restart(&sv, NodeRole::Mapper, false, MS(1), u32::MAX),
            after(1000, u32::MAX)
        );
        let huge = SupervisorConfig {
            backoff_initial_ms: u64::MAX / 2,
            backoff_max_ms: u64::MAX,
            ..sv
        };
        assert_eq!(
            decide_restart(&huge, NodeRole::Mapper, false, MS(1), 40),
            after(u64::MAX, 41)
        );
    }

    #[test]
    fn a_stable_run_resets_the_backoff() {
        let sv = config(RestartPolicy::Always);
        // Failed five times in quick succession: 1600 ms capped at 1000.
        assert_eq!(
            decide_restart(&sv, NodeRole::Bridge, false, MS(9_000), 5),
            after(1000, 6)
        );
        // At exactly stable_after_s the count goes on; beyond it, it starts afresh.
        assert_eq!(
            decide_restart(&sv, NodeRole::Bridge, false, MS(10_000), 5),
            after(1000, 6)
        );
        assert_eq!(
            decide_restart(&sv, NodeRole::Bridge, false, MS(10_001), 5),
            after(100, 1)
        );
        assert_eq!(
            decide_restart(&sv, NodeRole::Bridge, true, Duration::from_secs(3600), 9),
            after(100, 1)
        );
    }

    fn command(tick: u64, flags: u32) -> MapperCommand {
        MapperCommand {
            tick,
            t_ns: 1,
            state_t_ns: 0,
            state_rx_ns: 0,
            joystick_t_ns: 0,
            joystick_rx_ns: 0,
            joystick_seq: 0,
            compute_ns: 0,
            mapper_id: 2,
            n_joints: 6,
            flags,
            buttons: 0,
            action: [0.0; ipc_types::ACTION_DIM],
            qdot_rad_s: [0.1; ipc_types::MAX_JOINTS],
            gripper_rate: 0.0,
        }
    }

    #[test]
    fn only_finite_commands_of_a_valid_state_count() {
        assert!(command_valid(&command(3, 0)));
        // Flags that are not faults: no sample yet, a clamped action, a stale joystick.
        for f in [
            mapper_flags::NO_INPUT,
            mapper_flags::INPUT_CLAMPED,
            mapper_flags::INPUT_STALE,
        ] {
            assert!(command_valid(&command(3, f)), "flag {f:#x}");
        }
        for f in [
            mapper_flags::INPUT_NON_FINITE,
            mapper_flags::OUTPUT_NON_FINITE,
            mapper_flags::STATE_INVALID,
        ] {
            assert!(!command_valid(&command(3, f)), "flag {f:#x}");
        }
        let mut c = command(3, 0);
        c.qdot_rad_s[7] = f64::NAN;
        assert!(!command_valid(&c), "a NaN in any slot");
        c.qdot_rad_s[7] = f64::INFINITY;
        assert!(!command_valid(&c));
    }

    /// Feeds `(tick, ok)` pairs; returns the count after each.
    fn counts(ticks: &[(u64, bool)]) -> Vec<u32> {
        let mut w = Warmup::default();
        ticks.iter().map(|&(t, ok)| w.observe(t, ok)).collect()
    }

    #[test]
    fn warmup_counts_consecutive_valid_ticks() {
        let ticks: Vec<(u64, bool)> = (100..110).map(|t| (t, true)).collect();
        assert_eq!(counts(&ticks), (1..=10).collect::<Vec<u32>>());
    }

    #[test]
    fn an_invalid_command_resets_the_warmup() {
        assert_eq!(
            counts(&[
                (1, true),
                (2, true),
                (3, true),
                (4, false),
                (5, true),
                (6, true)
            ]),
            [1, 2, 3, 0, 1, 2]
        );
        // Invalid from the start: nothing counts.
        assert_eq!(counts(&[(7, false), (8, false), (9, true)]), [0, 0, 1]);
    }

    #[test]
    fn a_missing_tick_restarts_the_warmup() {
        assert_eq!(
            counts(&[(1, true), (2, true), (3, true), (5, true), (6, true)]),
            [1, 2, 3, 1, 2]
        );
        // Ticks going back (a new bridge would not, but a stray one) count as a gap too.
        assert_eq!(counts(&[(10, true), (11, true), (4, true)]), [1, 2, 1]);
        // A gap after an invalid command: the valid one after it starts at 1.
        assert_eq!(counts(&[(1, true), (2, false), (9, true)]), [1, 0, 1]);
    }

    #[test]
    fn a_repeated_tick_is_not_counted_twice() {
        assert_eq!(
            counts(&[(1, true), (2, true), (2, true), (3, true)]),
            [1, 2, 2, 3]
        );
        // An invalid repeat still resets.
        assert_eq!(
            counts(&[(1, true), (2, true), (2, false), (3, true)]),
            [1, 2, 0, 1]
        );
    }

    #[test]
    fn warmup_reaches_the_threshold_only_after_n_in_a_row() {
        let need = 10;
        let mut w = Warmup::default();
        // Nine valid, one invalid, then nine valid: never ready.
        for t in 0..9 {
            assert!(w.observe(t, true) < need);
        }
        assert_eq!(w.observe(9, false), 0);
        for t in 10..19 {
            assert!(w.observe(t, true) < need);
        }
        assert_eq!(w.observe(19, true), need);
        assert_eq!(w.valid, need);
        assert_eq!(w.last_tick, Some(19));
    }

    #[test]
    fn dead_nodes_are_scanned_after_a_reap_and_once_a_second() {
        let t0 = Instant::now();
        let mut c = CleanupSchedule::new(Duration::from_secs(1));
        // The first iteration scans (what a previous run left).
        assert!(c.due(false, t0));
        // Then not on every 2 ms iteration.
        for ms in (2..1000).step_by(2) {
            assert!(!c.due(false, t0 + MS(ms)), "{ms} ms");
        }
        assert!(c.due(false, t0 + MS(1000)));
        // A reap scans at once, whenever it happens, and restarts the safety-net timer.
        assert!(c.due(true, t0 + MS(1002)));
        assert!(c.due(true, t0 + MS(1004)));
        assert!(!c.due(false, t0 + MS(1500)));
        assert!(!c.due(false, t0 + MS(2003)));
        assert!(c.due(false, t0 + MS(2004)));
        // A clock that seems to go back does not panic or scan.
        assert!(!c.due(false, t0));
    }

    /// The summary's whole-arm figures: the smallest clearance and the fastest tool speed of
    /// the commands safety published, ignoring those where it checked nothing.
    #[test]
    fn the_summary_takes_the_smallest_clearance_and_the_fastest_tool() {
        let mut t = Telemetry::default();
        let c = |clearance_m: f64, tcp_speed_m_s: f64| SafeCommand {
            tick: 1,
            mapper_id: 1,
            n_joints: 6,
            clearance_m,
            tcp_speed_m_s,
            ..SafeCommand::zeroed()
        };
        t.take_safe(&c(f64::INFINITY, 0.0));
        assert_eq!((t.min_clearance_m, t.max_tcp_speed_m_s), (None, None));
        for (d, v) in [(0.12, 0.1), (0.043, 0.2), (0.08, 0.05)] {
            t.take_safe(&c(d, v));
        }
        assert_eq!(t.min_clearance_m, Some(0.043));
        assert_eq!(t.max_tcp_speed_m_s, Some(0.2));
    }
}
