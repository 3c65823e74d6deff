//! `scl bench latency`: the full graph (scripted joystick, mapper, safety, mock bridge) run for
//! a while on one or both transports, with optional CPU load and real-time settings, and every
//! tick's timestamps collected from the bridge's `TickReport`s.
//!
//! Figures, each as p50 / p90 / p99 / p99.9 / max (µs):
//! * first, what the operator feels: the joystick sample read -> the command that carries it
//!   received by the bridge, which executes it at once (`joystick_executed_us`); with
//!   `--wait predictive` or `spin` the joystick reads its input a margin before each tick
//!   (`scl_joystick::sampling`), and its samples that missed are counted
//!   (`joystick_late_missed`);
//! * per hop: joystick -> mapper (sample produced -> received), bridge -> mapper (RobotState
//!   published -> received), mapper -> safety, safety -> bridge;
//! * end to end within a tick: RobotState(k) published -> SafeCommand(k) received by the
//!   bridge;
//! * the joystick sample's age when the mapper used it;
//! * the bridge's tick lateness against the ideal grid, and missed ticks;
//! * compute inside the mapper (the map) and safety (the filter), apart from transport.
//!
//! Each run is `scl up` as a child process under a fresh prefix; the benchmark observes it
//! read-only on the same transport. Load processes are plain busy loops.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

/// Why the benchmark stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The graph or the process failed (a child died, a thread did not start, ...).
    #[error("{0}")]
    Graph(String),
    /// A run's graph published no tick report the benchmark could see: nothing was measured.
    #[error(
        "the {transport} run's graph (prefix {prefix}) published no tick report; its log: {log}"
    )]
    NoTicks {
        /// The run's transport.
        transport: Transport,
        /// The run's prefix.
        prefix: String,
        /// The run's log.
        log: String,
    },
}

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ipc_types::{Prefix, TickReport, Transport};
use serde::Serialize;
use transport::Graph;

use ipc_types::stats::quantile;
use node_rt::stats::sorted_us;
use scl_config::{GraphConfig, WaitStrategy};
use transport::signals;

pub mod headroom;
pub mod hops;
pub mod proc_cpu;
pub mod remote;

/// The real-time settings a benchmark's graph asks for, each on its own so that one can be
/// measured alone (`--rt` asks for all, `--rt-only NAME` for one).
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Eq, Default)]
pub struct RtSettings {
    /// SCHED_FIFO priorities along the control path (`[graph] rt_fifo`).
    pub fifo: bool,
    /// `mlockall` in every control-path process (`[graph] rt_mlock`).
    pub mlock: bool,
    /// The control path pinned to the last CPU (`[graph] rt_cpu`).
    pub pin: bool,
    /// `/dev/cpu_dma_latency` held at 0 while the graph runs
    /// (`[graph] rt_cpu_dma_latency_us`).
    pub dma_latency: bool,
}

impl RtSettings {
    /// Nothing asked for: the normal scheduler, unpinned.
    pub const NONE: Self = Self {
        fifo: false,
        mlock: false,
        pin: false,
        dma_latency: false,
    };
    /// Everything (`--rt`).
    pub const ALL: Self = Self {
        fifo: true,
        mlock: true,
        pin: true,
        dma_latency: true,
    };
    /// The names `--rt-only` takes.
    pub const NAMES: [&'static str; 4] = ["fifo", "mlock", "pin", "dma-latency"];

    /// One setting alone, by name (`fifo`, `mlock`, `pin`, `dma-latency`).
    pub fn only(name: &str) -> Result<Self, String> {
        let mut s = Self::NONE;
        match name {
            "fifo" => s.fifo = true,
            "mlock" => s.mlock = true,
            "pin" => s.pin = true,
            "dma-latency" => s.dma_latency = true,
            other => {
                return Err(format!(
                    "`{other}` is not a real-time setting; use one of {}",
                    Self::NAMES.join(", ")
                ));
            }
        }
        Ok(s)
    }

    /// Whether anything is asked for.
    pub fn any(&self) -> bool {
        *self != Self::NONE
    }

    /// A short label: `none`, `all`, or the settings' names joined by `+`.
    pub fn label(&self) -> String {
        match *self {
            Self::NONE => "none".to_owned(),
            Self::ALL => "all".to_owned(),
            s => {
                let on = [s.fifo, s.mlock, s.pin, s.dma_latency];
                Self::NAMES
                    .iter()
                    .zip(on)
                    .filter(|(_, on)| *on)
                    .map(|(n, _)| *n)
                    .collect::<Vec<_>>()
                    .join("+")
            }
        }
    }

    /// Sets the `[graph]` keys of these settings on a machine with `cores` CPUs: pinning keeps
    /// the base configuration's `rt_cpus` if it has them; otherwise it puts the control path
    /// on the last CPU with `wait = "event"`, and with a polling `wait` leaves the choice to
    /// the graph's own rule (`rt_auto_pin`: [`scl_config::placement::MachineCpus::auto_cpus`],
    /// the isolated CPUs or else spread over the last ones), so that the processes that can
    /// poll do. Without pinning nothing is pinned, automatically or not.
    pub fn apply(&self, graph: &mut scl_config::GraphSection, cores: usize) {
        graph.realtime = self.any();
        graph.rt_fifo = self.fifo;
        graph.rt_mlock = self.mlock;
        graph.rt_auto_pin = self.pin;
        graph.rt_cpu_dma_latency_us = if self.dma_latency { 0 } else { -1 };
        if self.pin && !graph.rt_cpus.is_empty() {
            graph.rt_cpu = -1;
            return;
        }
        graph.rt_cpus = Vec::new();
        graph.rt_cpu = if self.pin && !graph.wait.polls() {
            cores as i32 - 1
        } else {
            -1
        };
    }
}

/// What `scl bench latency` was asked to do.
#[derive(Debug, Clone)]
pub struct LatencyOptions {
    /// How long each transport runs.
    pub duration: Duration,
    /// The real-time settings asked for.
    pub rt: RtSettings,
    /// Busy processes running beside the graph.
    pub load: usize,
    /// The transports, run one after the other.
    pub transports: Vec<Transport>,
    /// The wait strategies (`[graph] wait`), each run on each transport, in this order.
    pub waits: Vec<WaitStrategy>,
    /// The base configuration (its transport and real-time settings are overridden).
    pub config: GraphConfig,
    /// Where to write the JSON (and the raw samples); none: stdout only.
    pub out: Option<PathBuf>,
    /// Run the graph with `scl up --live` on a free loopback port and a Foxglove WebSocket
    /// client subscribed to every channel for the whole run: the live observer's effect on
    /// the control loop.
    pub live: bool,
}

/// p50 / p90 / p99 / p99.9 / max of one figure, µs, and its sample count.
#[derive(Debug, Clone, Copy, Serialize, Default, PartialEq)]
pub struct Dist {
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// Largest.
    pub max: f64,
    /// Samples.
    pub n: usize,
}

impl Dist {
    /// The distribution of samples given in ns.
    pub fn of(samples_ns: &[u64]) -> Self {
        let s = sorted_us(samples_ns);
        let us = |q: f64| if s.is_empty() { 0.0 } else { quantile(&s, q) };
        Self {
            p50: us(0.5),
            p90: us(0.9),
            p99: us(0.99),
            p999: us(0.999),
            max: us(1.0),
            n: s.len(),
        }
    }
}

/// The per-hop samples of a run (ns), as collected from the tick reports.
#[derive(Debug, Clone, Default)]
pub struct Samples {
    /// joystick -> mapper.
    pub joystick_mapper: Vec<u64>,
    /// bridge -> mapper.
    pub bridge_mapper: Vec<u64>,
    /// mapper -> safety.
    pub mapper_safety: Vec<u64>,
    /// safety -> bridge.
    pub safety_bridge: Vec<u64>,
    /// End to end.
    pub e2e: Vec<u64>,
    /// Joystick sample age when used.
    pub joystick_age: Vec<u64>,
    /// Joystick sample produced -> the command that used it received by the bridge, which
    /// executes it at once.
    pub joystick_executed: Vec<u64>,
    /// Tick lateness.
    pub lateness: Vec<u64>,
    /// Mapper compute.
    pub mapper_compute: Vec<u64>,
    /// Safety compute.
    pub safety_compute: Vec<u64>,
    /// Ticks seen.
    pub ticks: u64,
    /// Missed ticks (the bridge's own count at the last report).
    pub missed: u64,
}

impl Samples {
    /// Adds one tick.
    pub fn take(&mut self, r: &TickReport) {
        self.ticks += 1;
        self.missed = r.missed;
        self.lateness.push(r.lateness_ns);
        if r.executed == 0 {
            return;
        }
        let d = |a: u64, b: u64| b.saturating_sub(a);
        if r.joystick_t_ns != 0 && r.joystick_rx_ns != 0 {
            // The sample's hop, and its age when the map ran (the command's publication less
            // the map's own time).
            self.joystick_mapper
                .push(d(r.joystick_t_ns, r.joystick_rx_ns));
            let used = r.mapper_t_ns.saturating_sub(r.mapper_compute_ns);
            self.joystick_age.push(d(r.joystick_t_ns, used));
            self.joystick_executed
                .push(d(r.joystick_t_ns, r.safe_rx_ns));
        }
        self.bridge_mapper.push(d(r.state_t_ns, r.state_rx_ns));
        self.mapper_safety.push(d(r.mapper_t_ns, r.mapper_rx_ns));
        self.safety_bridge.push(d(r.safe_t_ns, r.safe_rx_ns));
        self.e2e.push(d(r.state_t_ns, r.safe_rx_ns));
        self.mapper_compute.push(r.mapper_compute_ns);
        self.safety_compute.push(r.safety_compute_ns);
    }
}

/// The figures of one transport's run.
#[derive(Debug, Clone, Serialize)]
pub struct RunReport {
    /// The joystick sample produced -> the command that used it received by the bridge,
    /// which executes it at once (µs): the operator's input to the arm's motion, the figure
    /// a user reads first.
    pub joystick_executed_us: Dist,
    /// The transport.
    pub transport: Transport,
    /// How the control path waited (`[graph] wait`).
    pub wait: WaitStrategy,
    /// Each polling process's time spent polling per tick (µs), from its log line at its end
    /// (`wait strategy ... spin_us_per_tick`); empty with `event`.
    pub spin_us_per_tick: Vec<(String, f64)>,
    /// Each process's share of one CPU (CPU time per tick × rate).
    pub cpu_share: Vec<(String, f64)>,
    /// Ticks observed.
    pub ticks: u64,
    /// Ticks missed.
    pub missed: u64,
    /// Per hop (µs).
    pub hops_us: Hops,
    /// RobotState(k) published -> SafeCommand(k) received by the bridge (µs).
    pub e2e_us: Dist,
    /// Age of the joystick sample when the mapper used it (µs).
    pub joystick_age_us: Dist,
    /// The bridge's lateness against the ideal grid (µs).
    pub tick_lateness_us: Dist,
    /// Compute inside the processes (µs).
    pub compute_us: Compute,
    /// What the processes said about their real-time settings.
    pub realtime: Vec<String>,
    /// With `--live`: messages the connected Foxglove client received over the run.
    pub live_client_messages: Option<u64>,
    /// The graph's rate (Hz).
    pub rate_hz: f64,
    /// Misses the machine took (the bridge's `held_up`): part of `missed`.
    pub held_up: u64,
    /// The joystick's late samples that missed their tick, so the previous one served (its
    /// heartbeat's `held_up`; 0 with `event`, which samples on each state's arrival).
    pub joystick_late_missed: u64,
    /// Each process's CPU time per tick (µs, user + system, every thread), measured between
    /// its first heartbeat and the end of the run: bridge, safety, mapper, joystick, the
    /// gateway (with `[network] enabled`) and the supervisor (`scl up`).
    pub cpu_per_tick_us: Vec<(String, f64)>,
    /// Each process's resident, peak resident and locked memory at the end of the run.
    pub memory: Vec<(String, proc_cpu::Memory)>,
    /// With a remote operator: its process and how it ended.
    pub operator: Option<OperatorRun>,
}

/// A run's remote operator (`scl joystick --remote`).
#[derive(Debug, Clone, Serialize)]
pub struct OperatorRun {
    /// Its process id (none: it never started, the graph never ticked).
    pub pid: Option<u32>,
    /// How it ended.
    pub exit: Option<String>,
    /// Whether it read this machine's monotonic clock (one time namespace), so that its
    /// samples' stamps compare with the graph's; `None`: it was gone before it was checked.
    pub same_clock: Option<bool>,
    /// The operator's samples the gateway forwarded to the graph (seen on its joystick topic).
    pub forwarded: u64,
    /// The gateway's stand-ins (neutral, `NO_DEVICE`) while no operator drove.
    pub stand_ins: u64,
    /// The operator's round trip (a sample sent -> the gateway's acknowledgement), p50 / p99
    /// / max (µs), from the summary it logs at its end; none if it logged none.
    pub round_trip_us: Option<(f64, f64, f64)>,
}

/// The round trip `scl joystick --remote` logs at its end (`round trip to the gateway ...
/// p50_us="400" p99_us="609" max_us="3188"`), as (p50, p99, max) µs.
pub fn round_trip_from_log(log: &str) -> Option<(f64, f64, f64)> {
    let line = log
        .lines()
        .map(strip_ansi)
        .find(|l| l.contains("round trip to the gateway"))?;
    let field = |name: &str| {
        line.split_whitespace()
            .find_map(|t| t.strip_prefix(name))
            .and_then(|v| v.trim_matches('"').parse::<f64>().ok())
    };
    Some((field("p50_us=")?, field("p99_us=")?, field("max_us=")?))
}

/// The samples a gateway forwarded from a remote operator, by their kept creation stamp, and
/// the tick reports' joystick stamps, so that only the commands an operator's sample drove
/// count.
#[derive(Debug, Default)]
struct OperatorSamples {
    stamps: std::collections::HashSet<u64>,
    stand_ins: u64,
    /// (joystick_t_ns, joystick_rx_ns, safe_rx_ns) of each executed tick.
    ticks: Vec<(u64, u64, u64)>,
}

impl OperatorSamples {
    fn sample(&mut self, s: &ipc_types::JoystickInput) {
        if s.buttons & ipc_types::buttons::NO_DEVICE != 0 {
            self.stand_ins += 1;
        } else {
            self.stamps.insert(s.t_ns);
        }
    }

    fn report(&mut self, r: &TickReport) {
        if r.executed != 0 && r.joystick_t_ns != 0 {
            self.ticks
                .push((r.joystick_t_ns, r.joystick_rx_ns, r.safe_rx_ns));
        }
    }

    /// (sample -> mapper, sample -> executed) of the ticks an operator's sample drove (ns).
    fn hops(&self) -> (Vec<u64>, Vec<u64>) {
        self.ticks
            .iter()
            .filter(|(t, _, _)| self.stamps.contains(t))
            .map(|(t, rx, safe)| (rx.saturating_sub(*t), safe.saturating_sub(*t)))
            .unzip()
    }
}

/// Per-hop distributions.
#[derive(Debug, Clone, Serialize)]
pub struct Hops {
    /// Joystick sample produced -> received by the mapper.
    pub joystick_mapper: Dist,
    /// RobotState published -> received by the mapper.
    pub bridge_mapper: Dist,
    /// MapperCommand published -> received by safety.
    pub mapper_safety: Dist,
    /// SafeCommand published -> received by the bridge.
    pub safety_bridge: Dist,
}

/// Compute distributions.
#[derive(Debug, Clone, Serialize)]
pub struct Compute {
    /// The map in the mapper.
    pub mapper: Dist,
    /// The safety filter.
    pub safety: Dist,
}

impl RunReport {
    fn new(transport: Transport, s: &Samples, realtime: Vec<String>, rate_hz: f64) -> Self {
        Self {
            wait: WaitStrategy::Event,
            spin_us_per_tick: Vec::new(),
            cpu_share: Vec::new(),
            rate_hz,
            held_up: 0,
            joystick_late_missed: 0,
            cpu_per_tick_us: Vec::new(),
            memory: Vec::new(),
            operator: None,
            transport,
            live_client_messages: None,
            ticks: s.ticks,
            missed: s.missed,
            hops_us: Hops {
                joystick_mapper: Dist::of(&s.joystick_mapper),
                bridge_mapper: Dist::of(&s.bridge_mapper),
                mapper_safety: Dist::of(&s.mapper_safety),
                safety_bridge: Dist::of(&s.safety_bridge),
            },
            e2e_us: Dist::of(&s.e2e),
            joystick_age_us: Dist::of(&s.joystick_age),
            joystick_executed_us: Dist::of(&s.joystick_executed),
            tick_lateness_us: Dist::of(&s.lateness),
            compute_us: Compute {
                mapper: Dist::of(&s.mapper_compute),
                safety: Dist::of(&s.safety_compute),
            },
            realtime,
        }
    }

    /// The named figures, for tables and ratios.
    pub fn figures(&self) -> Vec<(&'static str, Dist)> {
        vec![
            ("joystick -> executed", self.joystick_executed_us),
            ("joystick -> mapper", self.hops_us.joystick_mapper),
            ("bridge -> mapper", self.hops_us.bridge_mapper),
            ("mapper -> safety", self.hops_us.mapper_safety),
            ("safety -> bridge", self.hops_us.safety_bridge),
            ("end to end", self.e2e_us),
            ("joystick sample age", self.joystick_age_us),
            ("tick lateness", self.tick_lateness_us),
            ("mapper compute", self.compute_us.mapper),
            ("safety compute", self.compute_us.safety),
        ]
    }
}

/// The machine the figures come from.
#[derive(Debug, Clone, Serialize)]
pub struct Machine {
    /// Online CPUs.
    pub cores: usize,
    /// `uname -r`.
    pub kernel: String,
    /// CPU model name.
    pub cpu: String,
    /// Whether the CPU reports running under a hypervisor.
    pub virtualised: bool,
}

impl std::fmt::Display for Machine {
    /// `N cores, CPU, kernel K[, virtualised]`: the first words of every report.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} cores, {}, kernel {}{}",
            self.cores,
            self.cpu,
            self.kernel,
            if self.virtualised {
                ", virtualised"
            } else {
                ""
            }
        )
    }
}

impl Machine {
    /// Reads the machine's description from /proc.
    pub fn detect() -> Self {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let field = |name: &str| {
            cpuinfo
                .lines()
                .find(|l| l.starts_with(name))
                .and_then(|l| l.split(':').nth(1))
                .map_or(String::new(), |v| v.trim().to_owned())
        };
        Self {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            kernel: std::fs::read_to_string("/proc/sys/kernel/osrelease")
                .map_or(String::new(), |s| s.trim().to_owned()),
            cpu: field("model name"),
            virtualised: field("flags").split_whitespace().any(|f| f == "hypervisor"),
        }
    }
}

/// The whole benchmark's result (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct LatencyReport {
    /// The machine.
    pub machine: Machine,
    /// Seconds per transport.
    pub duration_s: f64,
    /// Any real-time setting asked for (`--rt` or `--rt-only`).
    pub rt: bool,
    /// Which real-time settings were asked for.
    pub rt_settings: RtSettings,
    /// `--load` busy processes.
    pub load: usize,
    /// The graph that ran: the model the mapper served, the joystick script, the bridge's
    /// rate and the CPU the control path was pinned to (-1: none).
    pub settings: BenchSettings,
    /// One run per transport.
    pub runs: Vec<RunReport>,
    /// iceoryx2 / uds of every figure's p50, p99 and max, when both ran (with the first
    /// wait strategy).
    pub ratios: Vec<(String, f64, f64, f64)>,
    /// Per transport and polling strategy, that strategy / `event` of every figure's p50, p99
    /// and max, when both ran: (transport, strategy, figure, p50, p99, max).
    pub wait_ratios: Vec<(Transport, WaitStrategy, String, f64, f64, f64)>,
}

/// The settings of a benchmark's graph, as reported in its JSON.
#[derive(Debug, Clone, Serialize)]
pub struct BenchSettings {
    /// The robot profile the mock arm simulates (`[graph] robot`).
    pub robot: String,
    /// The mapper's model (`bundled`, a file, or a spec such as `modeswitch`).
    pub model: String,
    /// The scripted joystick's pattern.
    pub script: String,
    /// The bridge's rate (Hz).
    pub rate_hz: f64,
    /// The bridge's command deadline, as a fraction of the period.
    pub command_deadline: f64,
    /// The CPU the control path was pinned to with `--rt` (-1: none).
    pub rt_cpu: i32,
    /// `/dev/cpu_dma_latency` requested while the graph ran (µs; -1: none).
    pub rt_cpu_dma_latency_us: i32,
    /// The transports, in the order they ran.
    pub transports: Vec<Transport>,
    /// The wait strategies, in the order they ran on each transport.
    pub waits: Vec<WaitStrategy>,
}

struct Burners(Vec<Child>);

impl Drop for Burners {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn spawn_scl(args: &[String]) -> Result<Command, BenchError> {
    let exe = std::env::current_exe()
        .map_err(|e| BenchError::Graph(format!("cannot find the scl executable: {e}")))?;
    let mut c = Command::new(exe);
    c.args(args);
    Ok(c)
}

/// A busy loop until killed: the `--load` processes.
pub fn burn() -> ! {
    let mut x: u64 = 1;
    loop {
        x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        std::hint::black_box(x);
    }
}

/// Each process's polling time per tick (µs) from a run's log: the `wait strategy` lines the
/// polling processes write at their end (`process=mapper ... spin_us_per_tick=1.25`).
pub fn spin_from_log(log: &str) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for line in log.lines().map(strip_ansi) {
        if !line.contains("wait strategy") {
            continue;
        }
        let field = |name: &str| {
            line.split_whitespace()
                .find_map(|t| t.strip_prefix(name))
                .map(|v| v.trim_matches('"').to_owned())
        };
        if let (Some(p), Some(us)) = (
            field("process="),
            field("spin_us_per_tick=").and_then(|v| v.parse::<f64>().ok()),
        ) {
            out.push((p, us));
        }
    }
    out.sort_by_key(|(p, _)| proc_cpu::ORDER.iter().position(|o| o == p));
    out
}

/// `line` without its terminal colour sequences (`ESC [ ... m`).
fn strip_ansi(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// Runs the graph of `opts` on `transport` with `wait` once; `tag` tells its files and prefix
/// apart from the other runs of the benchmark.
pub(crate) fn run_one(
    opts: &LatencyOptions,
    transport: Transport,
    wait: WaitStrategy,
    dir: &Path,
    tag: &str,
) -> Result<(RunReport, Samples), BenchError> {
    run_with(opts, transport, wait, dir, tag, &Extra::default())
}

/// What a run adds to the plain graph: `scl up` inside a network namespace, and a remote
/// operator started once the graph ticks.
#[derive(Debug, Clone, Default)]
pub(crate) struct Extra {
    /// The command `scl up` runs under (`ip netns exec NS`); empty: none.
    pub(crate) up_wrap: Vec<String>,
    /// The operator: its wrapper (as `up_wrap`) and its `scl` arguments.
    pub(crate) operator: Option<(Vec<String>, Vec<String>)>,
}

/// `scl ARGS` under `wrap` (a command that runs its arguments, e.g. `ip netns exec NS`).
fn spawn_wrapped(wrap: &[String], args: &[String]) -> Result<Command, BenchError> {
    let Some((first, rest)) = wrap.split_first() else {
        return spawn_scl(args);
    };
    let exe = std::env::current_exe()
        .map_err(|e| BenchError::Graph(format!("cannot find the scl executable: {e}")))?;
    let mut c = Command::new(first);
    c.args(rest).arg(exe).args(args);
    Ok(c)
}

/// The remote operator of a run: started once the graph ticks, stopped (SIGINT, as a
/// person's Ctrl-C) a second before the graph's end.
struct OperatorChild {
    child: Option<Child>,
    stopped: bool,
    /// Whether it read the same monotonic clock as this process, seen before it was stopped.
    same_clock: Option<bool>,
}

/// Whether process `pid` reads the same `CLOCK_MONOTONIC` as this one: both in one time
/// namespace (`/proc/PID/ns/time`; a kernel without time namespaces has one clock). `None`
/// when `pid` is gone.
pub fn same_monotonic_clock(pid: u32) -> Option<bool> {
    let Ok(mine) = std::fs::read_link("/proc/self/ns/time") else {
        return std::path::Path::new(&format!("/proc/{pid}"))
            .exists()
            .then_some(true);
    };
    let theirs = std::fs::read_link(format!("/proc/{pid}/ns/time")).ok()?;
    Some(mine == theirs)
}

impl OperatorChild {
    fn interrupt(&mut self) {
        if let Some(c) = &self.child
            && !self.stopped
        {
            self.stopped = true;
            self.same_clock = same_monotonic_clock(c.id());
            // Our own child; an error means it has exited already.
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(c.id() as i32),
                nix::sys::signal::Signal::SIGINT,
            );
        }
    }

    /// Waits up to 5 s for the operator to end, then kills it; its exit status.
    fn finish(&mut self) -> Option<std::process::ExitStatus> {
        self.interrupt();
        let c = self.child.as_mut()?;
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(s)) = c.try_wait() {
                self.child = None;
                return Some(s);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = c.kill();
        let s = c.wait().ok();
        self.child = None;
        s
    }
}

impl Drop for OperatorChild {
    fn drop(&mut self) {
        if let Some(c) = &mut self.child {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// [`run_one`] with `extra`.
pub(crate) fn run_with(
    opts: &LatencyOptions,
    transport: Transport,
    wait: WaitStrategy,
    dir: &Path,
    tag: &str,
    extra: &Extra,
) -> Result<(RunReport, Samples), BenchError> {
    let prefix = Prefix::new(&format!("bench{}{}{tag}", std::process::id(), transport))
        .map_err(|e| BenchError::Graph(e.to_string()))?;
    let cfg = run_config(opts, transport, wait, &prefix);
    let cfg_path = dir.join(format!("graph-{transport}{tag}.toml"));
    write_config(&cfg, &cfg_path)?;

    let burners = start_load(opts.load)?;
    let graph = Graph::join_with(&prefix, &format!("bench-{}", std::process::id()), transport)?;
    let reports = graph.tick_report_subscriber()?;
    let heartbeats = graph.status_subscriber()?;
    // With a remote operator: the samples the gateway forwards, to tell the operator's (its
    // creation stamp kept) from the gateway's stand-ins (`NO_DEVICE`, stamped here).
    let joysticks = match extra.operator {
        Some(_) => Some(graph.joystick_subscriber(false)?),
        None => None,
    };
    let log_path = dir.join(format!("scl-up-{transport}{tag}.log"));
    let secs = opts.duration.as_secs_f64();
    let (mut up, live) = start_graph(opts, extra, &prefix, &cfg_path, &log_path)?;

    eprintln!(
        "bench: {transport}, wait {wait}, {} Hz, {secs:.0} s, load {}, rt {}",
        cfg.graph.rate_hz,
        opts.load,
        opts.rt.label()
    );
    let mut obs = Observer {
        reports,
        heartbeats,
        joysticks,
        t: RunTally {
            samples: Samples::default(),
            from_operator: OperatorSamples::default(),
            cpu: proc_cpu::CpuWatch::new(up.id()),
            held_up: 0,
            late_missed: 0,
        },
    };
    let op_log = dir.join(format!("operator-{transport}{tag}.log"));
    let mut operator = OperatorChild {
        child: None,
        stopped: false,
        same_clock: None,
    };
    obs.watch(&mut up, extra, &mut operator, &op_log, secs)?;
    obs.drain_inputs()?;
    drop(obs.joysticks.take());
    if extra.operator.is_some() {
        // Only the commands an operator's sample drove: not the stand-ins before it joined.
        let (mapper, executed) = obs.t.from_operator.hops();
        obs.t.samples.joystick_mapper = mapper;
        obs.t.samples.joystick_executed = executed;
    }
    let operator_pid = operator.child.as_ref().map(Child::id);
    let operator_exit = operator.finish();
    let live_messages = live.map(LiveClient::finish);
    let (held_up, late_missed) = (&mut obs.t.held_up, &mut obs.t.late_missed);
    obs.heartbeats.drain(|s| counts(s, held_up, late_missed))?;
    let Observer {
        reports,
        heartbeats,
        t,
        ..
    } = obs;
    drop(burners);
    drop(heartbeats);
    drop(reports);
    drop(graph);
    release_graph(&prefix);
    let log_text = std::fs::read_to_string(&log_path).unwrap_or_default();
    if t.samples.ticks == 0 {
        return Err(BenchError::NoTicks {
            transport,
            prefix: prefix.to_string(),
            log: log_path.display().to_string(),
        });
    }
    let mut report = t.report(transport, wait, cfg.graph.rate_hz, &log_text);
    report.live_client_messages = live_messages;
    if extra.operator.is_some() {
        let op_text = std::fs::read_to_string(&op_log).unwrap_or_default();
        report.operator = Some(OperatorRun {
            round_trip_us: round_trip_from_log(&op_text),
            forwarded: t.from_operator.stamps.len() as u64,
            stand_ins: t.from_operator.stand_ins,
            same_clock: operator.same_clock,
            pid: operator_pid,
            exit: operator_exit.map(|s| s.to_string()),
        });
    }
    Ok((report, t.samples))
}

/// Writes the run's configuration to `path`.
fn write_config(cfg: &GraphConfig, path: &Path) -> Result<(), BenchError> {
    let text = toml::to_string(cfg)
        .map_err(|e| BenchError::Graph(format!("cannot write the run's config: {e}")))?;
    std::fs::write(path, text).map_err(|e| BenchError::Graph(format!("{}: {e}", path.display())))
}

/// Releases the run's graph: its shared memory domain and its sockets.
fn release_graph(prefix: &Prefix) {
    let _ = transport::graph::release_domain(prefix);
    transport::uds::remove_graph(prefix.as_str());
}

/// The run's graph configuration: the base one on `transport` with `wait`, the real-time
/// settings and `prefix`, always the scripted joystick on the mock arm.
fn run_config(
    opts: &LatencyOptions,
    transport: Transport,
    wait: WaitStrategy,
    prefix: &Prefix,
) -> GraphConfig {
    let mut cfg = opts.config.clone();
    cfg.graph.transport = transport;
    cfg.graph.wait = wait;
    opts.rt.apply(&mut cfg.graph, Machine::detect().cores);
    cfg.graph.prefix = prefix.to_string();
    // The benchmark's graph is always the scripted joystick on the mock arm, whatever the base
    // configuration says: it must never drive a real arm, nor wait for a person's input.
    cfg.bridge.robot = "mock".to_owned();
    cfg.joystick.source = "script".to_owned();
    cfg
}

/// `load` processes burning a core each (`scl bench burn`), killed when dropped.
fn start_load(load: usize) -> Result<Burners, BenchError> {
    let mut burners = Burners(Vec::new());
    for _ in 0..load {
        let c = spawn_scl(&["bench".into(), "burn".into()])?
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .map_err(|e| BenchError::Graph(format!("cannot start a load process: {e}")))?;
        burners.0.push(c);
    }
    Ok(burners)
}

/// Starts `scl up` on `cfg_path` for the run's duration (under `extra`'s wrapper, its log
/// to a new file at `log_path`), with a live client if `--live`.
fn start_graph(
    opts: &LatencyOptions,
    extra: &Extra,
    prefix: &Prefix,
    cfg_path: &Path,
    log_path: &Path,
) -> Result<(Child, Option<LiveClient>), BenchError> {
    let log = std::fs::File::create(log_path)
        .map_err(|e| BenchError::Graph(format!("{}: {e}", log_path.display())))?;
    let secs = opts.duration.as_secs_f64();
    // The prefix on the command line too: an `SCL_PREFIX` in the environment would otherwise
    // move the child's graph away from the one observed here.
    let mut up_args = vec![
        "up".into(),
        "--prefix".into(),
        prefix.to_string(),
        "--config".into(),
        cfg_path.display().to_string(),
        "--for".into(),
        format!("{secs}s"),
    ];
    let live = if opts.live {
        let addr = free_loopback_port()
            .map(|p| format!("127.0.0.1:{p}"))
            .map_err(|e| BenchError::Graph(format!("no free port for --live: {e}")))?;
        up_args.extend(["--live".into(), addr.clone()]);
        Some(LiveClient::start(addr))
    } else {
        None
    };
    let up = spawn_wrapped(&extra.up_wrap, &up_args)?
        .env("SCL_LOG", "info")
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .map_err(|e| BenchError::Graph(format!("cannot start the graph: {e}")))?;
    Ok((up, live))
}

/// What the benchmark reads from the graph while it runs: the tick reports, the heartbeats,
/// the forwarded joystick samples (with a remote operator), and what they add up to.
struct Observer {
    reports: transport::TopicSubscriber<TickReport>,
    heartbeats: transport::TopicSubscriber<ipc_types::NodeStatus>,
    joysticks: Option<transport::TopicSubscriber<ipc_types::JoystickInput>>,
    t: RunTally,
}

/// What a run's messages add up to: the samples, the operator's, the CPU and memory per
/// process, the bridge's misses held up by the machine, the joystick's late samples.
struct RunTally {
    samples: Samples,
    from_operator: OperatorSamples,
    cpu: proc_cpu::CpuWatch,
    held_up: u64,
    late_missed: u64,
}

impl Observer {
    /// Reads the graph every 5 ms until `scl up` ends (after `secs`, or when asked to stop):
    /// starts the operator at the first tick and stops it a second before the graph, reads
    /// the CPU every 0.25 s and prints progress every 10 s.
    fn watch(
        &mut self,
        up: &mut Child,
        extra: &Extra,
        operator: &mut OperatorChild,
        op_log: &Path,
        secs: f64,
    ) -> Result<(), BenchError> {
        let t0 = Instant::now();
        let mut next = 10.0;
        let mut next_cpu = 0.0;
        // The operator stops a second before the graph (a shorter run: at 80 % of it).
        let operator_stop = if secs > 5.0 { secs - 1.0 } else { secs * 0.8 };
        while up
            .try_wait()
            .map_err(|e| BenchError::Graph(e.to_string()))?
            .is_none()
        {
            self.drain_inputs()?;
            let (cpu, held_up, late_missed) = (
                &mut self.t.cpu,
                &mut self.t.held_up,
                &mut self.t.late_missed,
            );
            self.heartbeats.drain(|s| {
                cpu.heartbeat(s);
                counts(s, held_up, late_missed);
            })?;
            if signals::stop_requested() {
                // Our own child; an error means it has exited, which try_wait sees next.
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(up.id() as i32),
                    nix::sys::signal::Signal::SIGTERM,
                );
            }
            let el = t0.elapsed().as_secs_f64();
            if let Some((wrap, args)) = &extra.operator {
                if operator.child.is_none() && !operator.stopped && self.t.samples.ticks > 0 {
                    operator.child = Some(start_operator(wrap, args, op_log)?);
                }
                if el >= operator_stop {
                    operator.interrupt();
                }
            }
            if el >= next_cpu {
                // Read often enough that the last reading is close to the graph's end.
                next_cpu = el + 0.25;
                self.t.cpu.read(self.t.samples.ticks);
            }
            if el >= next {
                next += 10.0;
                let e = Dist::of(&self.t.samples.e2e);
                eprintln!(
                    "bench: {el:>5.0} s  ticks {}  missed {}  e2e p50 {:.1} µs  p99 {:.1} µs",
                    self.t.samples.ticks, self.t.samples.missed, e.p50, e.p99
                );
            }
            // The tick reports' buffer holds 256: a quarter of a second at 1 kHz.
            std::thread::sleep(Duration::from_millis(5));
        }
        Ok(())
    }

    /// Takes the forwarded joystick samples (if watched) and the tick reports waiting.
    fn drain_inputs(&mut self) -> Result<(), BenchError> {
        let (samples, from_operator) = (&mut self.t.samples, &mut self.t.from_operator);
        if let Some(j) = &self.joysticks {
            j.drain(|s| from_operator.sample(s))?;
        }
        self.reports.drain(|r| {
            samples.take(r);
            from_operator.report(r);
        })?;
        Ok(())
    }
}

impl RunTally {
    /// The run's report: its samples, the counts from the heartbeats, the CPU and memory
    /// per process, and what `scl up`'s log (`log_text`) says of real time and polling.
    fn report(
        &self,
        transport: Transport,
        wait: WaitStrategy,
        rate_hz: f64,
        log_text: &str,
    ) -> RunReport {
        let realtime = log_text
            .lines()
            .filter(|l| l.contains("real-time"))
            .map(|l| l.trim().to_owned())
            .collect();
        let mut report = RunReport::new(transport, &self.samples, realtime, rate_hz);
        report.held_up = self.held_up;
        report.joystick_late_missed = self.late_missed;
        report.wait = wait;
        report.spin_us_per_tick = spin_from_log(log_text);
        report.cpu_per_tick_us = self.cpu.per_tick_us();
        report.memory = self.cpu.memory();
        report.cpu_share = report
            .cpu_per_tick_us
            .iter()
            .map(|(n, us)| (n.clone(), us * 1e-6 * rate_hz))
            .collect();
        report
    }
}

/// Starts the remote operator (`scl ARGS` under `wrap`), its log to `op_log`.
fn start_operator(wrap: &[String], args: &[String], op_log: &Path) -> Result<Child, BenchError> {
    let f = std::fs::File::create(op_log)
        .map_err(|e| BenchError::Graph(format!("{}: {e}", op_log.display())))?;
    spawn_wrapped(wrap, args)?
        .env("SCL_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(f)
        .spawn()
        .map_err(|e| BenchError::Graph(format!("cannot start the operator: {e}")))
}

/// The counts a heartbeat carries: the bridge's misses held up by the machine, the
/// joystick's late samples that missed.
fn counts(s: &ipc_types::NodeStatus, held_up: &mut u64, late_missed: &mut u64) {
    if s.role == ipc_types::NodeRole::Bridge as u32 {
        *held_up = u64::from(s.held_up);
    } else if s.role == ipc_types::NodeRole::Joystick as u32 {
        *late_missed = u64::from(s.held_up);
    }
}

/// A free port on the loopback, or the error saying there is none.
pub(crate) fn free_loopback_port_or_err() -> Result<u16, BenchError> {
    free_loopback_port().map_err(|e| BenchError::Graph(format!("no free loopback port: {e}")))
}

fn free_loopback_port() -> std::io::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// A Foxglove client subscribed to every channel of `scl up --live` for the whole run.
struct LiveClient {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: std::thread::JoinHandle<u64>,
}

impl LiveClient {
    fn start(addr: String) -> Self {
        use std::sync::atomic::Ordering;
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let s2 = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut n = 0;
            while !s2.load(Ordering::SeqCst) {
                let Ok(mut c) = viz::client::Client::connect(&addr, Duration::from_secs(1)) else {
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                };
                let ids: Vec<u64> = c.channels.keys().copied().collect();
                if ids.is_empty() || c.subscribe(&ids).is_err() {
                    continue;
                }
                eprintln!(
                    "bench: a Foxglove client subscribed to {} channels",
                    ids.len()
                );
                while !s2.load(Ordering::SeqCst) {
                    match c.next_frame() {
                        Ok(Some(_)) => n += 1,
                        Ok(None) => {}
                        Err(_) => break,
                    }
                }
                c.close();
            }
            n
        });
        Self { stop, thread }
    }

    fn finish(self) -> u64 {
        self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
        self.thread.join().unwrap_or(0)
    }
}

/// Log-spaced histogram of samples (ns): counts in bins from 1 µs to 100 ms, 8 per decade,
/// as (bin centre in µs, fraction of samples).
pub fn histogram(samples_ns: &[u64]) -> Vec<(f64, f64)> {
    const PER_DECADE: f64 = 8.0;
    let bins = (5.0 * PER_DECADE) as usize;
    let mut counts = vec![0usize; bins];
    for v in samples_ns {
        let us = (*v as f64 / 1000.0).max(1.0);
        let i = ((us.log10() * PER_DECADE) as usize).min(bins - 1);
        counts[i] += 1;
    }
    let n = samples_ns.len().max(1) as f64;
    counts
        .iter()
        .enumerate()
        .map(|(i, c)| (10f64.powf((i as f64 + 0.5) / PER_DECADE), *c as f64 / n))
        .collect()
}

/// Draws the histograms of six figures, one line per transport, into an RGB buffer of
/// [`learning::plot::SIZE`].
pub fn render_histograms(
    runs: &[(Transport, &Samples)],
    title: &str,
    text: bool,
) -> Result<Vec<u8>, learning::plot::PlotError> {
    use plotters::prelude::*;
    let draw = |e: &dyn std::fmt::Display| learning::plot::PlotError::Draw(e.to_string());
    let (w, h) = learning::plot::SIZE;
    let mut buf = vec![0u8; (w as usize) * (h as usize) * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw(&e))?;
        let body = if text {
            root.titled(title, ("sans-serif", 24))
                .map_err(|e| draw(&e))?
        } else {
            root.clone()
        };
        let panels = body.split_evenly((2, 3));
        type Pick = fn(&Samples) -> &Vec<u64>;
        let figures: [(&str, Pick); 6] = [
            ("end to end", |s| &s.e2e),
            ("bridge -> mapper", |s| &s.bridge_mapper),
            ("mapper -> safety", |s| &s.mapper_safety),
            ("safety -> bridge", |s| &s.safety_bridge),
            ("joystick -> mapper", |s| &s.joystick_mapper),
            ("tick lateness", |s| &s.lateness),
        ];
        let colours = [RGBColor(31, 119, 180), RGBColor(255, 127, 14)];
        for (panel, (name, pick)) in panels.iter().zip(figures) {
            let hists: Vec<(Transport, Vec<(f64, f64)>)> =
                runs.iter().map(|(t, s)| (*t, histogram(pick(s)))).collect();
            let top = hists
                .iter()
                .flat_map(|(_, h)| h.iter().map(|(_, f)| *f))
                .fold(0.0, f64::max)
                .max(0.01)
                * 1.1;
            let mut chart = ChartBuilder::on(panel);
            chart.margin(8);
            if text {
                chart
                    .caption(name, ("sans-serif", 18))
                    .x_label_area_size(30)
                    .y_label_area_size(40);
            }
            let mut chart = chart
                .build_cartesian_2d((1.0f64..100_000.0).log_scale(), 0.0..top)
                .map_err(|e| draw(&e))?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.x_desc("µs")
                    .y_desc("fraction")
                    .x_label_formatter(&|v| format!("{v:.0}"));
            } else {
                mesh.disable_x_mesh().disable_y_mesh();
            }
            mesh.draw().map_err(|e| draw(&e))?;
            for (k, (t, hist)) in hists.iter().enumerate() {
                let colour = colours[k % colours.len()];
                let series = chart
                    .draw_series(LineSeries::new(
                        hist.iter().copied(),
                        colour.stroke_width(2),
                    ))
                    .map_err(|e| draw(&e))?;
                if text {
                    series
                        .label(t.to_string())
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
                }
            }
            if text {
                chart
                    .configure_series_labels()
                    .border_style(BLACK)
                    .draw()
                    .map_err(|e| draw(&e))?;
            }
        }
        root.present().map_err(|e| draw(&e))?;
    }
    Ok(buf)
}

/// Runs the benchmark.
pub fn latency(opts: &LatencyOptions) -> Result<LatencyReport, BenchError> {
    let dir = match &opts.out {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("scl-bench-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir)
        .map_err(|e| BenchError::Graph(format!("{}: {e}", dir.display())))?;
    let mut runs = Vec::new();
    let mut all_samples = Vec::new();
    for t in &opts.transports {
        for w in &opts.waits {
            if signals::stop_requested() {
                break;
            }
            let tag = if opts.waits.len() > 1 {
                format!("-{w}")
            } else {
                String::new()
            };
            let (report, samples) = run_one(opts, *t, *w, &dir, &tag)?;
            runs.push(report);
            all_samples.push((*t, samples));
        }
    }
    if opts.out.is_some() {
        write_histograms(opts, &dir, &all_samples)?;
    }
    let ratios = transport_ratios(opts, &runs);
    let wait_ratios = wait_ratios(opts, &runs);
    if opts.out.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    let machine = Machine::detect();
    let settings = BenchSettings {
        robot: opts.config.graph.robot.clone(),
        model: opts.config.mapper.model.clone(),
        script: opts.config.joystick.script.clone(),
        rate_hz: opts.config.graph.rate_hz,
        command_deadline: opts.config.bridge.command_deadline,
        rt_cpu: if opts.rt.pin {
            machine.cores as i32 - 1
        } else {
            -1
        },
        rt_cpu_dma_latency_us: if opts.rt.dma_latency { 0 } else { -1 },
        transports: opts.transports.clone(),
        waits: opts.waits.clone(),
    };
    Ok(LatencyReport {
        machine,
        duration_s: opts.duration.as_secs_f64(),
        rt: opts.rt.any(),
        rt_settings: opts.rt,
        load: opts.load,
        settings,
        runs,
        ratios,
        wait_ratios,
    })
}

/// Writes `latency.png` into `dir`: the histograms of every transport's samples.
fn write_histograms(
    opts: &LatencyOptions,
    dir: &Path,
    all_samples: &[(Transport, Samples)],
) -> Result<(), BenchError> {
    let font = learning::plot::load_font(None).map_err(|e| BenchError::Graph(e.to_string()))?;
    let refs: Vec<(Transport, &Samples)> = all_samples.iter().map(|(t, s)| (*t, s)).collect();
    let title = format!(
        "scl bench latency: {} Hz, {:.0} s per transport, load {}, rt {}",
        opts.config.graph.rate_hz,
        opts.duration.as_secs_f64(),
        opts.load,
        opts.rt.label()
    );
    let rgb = render_histograms(&refs, &title, font.is_some())
        .map_err(|e| BenchError::Graph(e.to_string()))?;
    let png = dir.join("latency.png");
    learning::plot::write_png(&png, &rgb, true).map_err(|e| BenchError::Graph(e.to_string()))?;
    eprintln!("bench: histograms in {}", png.display());
    Ok(())
}

/// The ratio `x / y` (NaN when `y` is not positive).
fn ratio(x: f64, y: f64) -> f64 {
    if y > 0.0 { x / y } else { f64::NAN }
}

/// The run on transport `t` with wait strategy `w`, if it ran.
fn find_run(runs: &[RunReport], t: Transport, w: WaitStrategy) -> Option<&RunReport> {
    runs.iter().find(|x| x.transport == t && x.wait == w)
}

/// [`LatencyReport::ratios`] of `runs`.
fn transport_ratios(opts: &LatencyOptions, runs: &[RunReport]) -> Vec<(String, f64, f64, f64)> {
    let r = ratio;
    let mut ratios = Vec::new();
    let first_wait = opts.waits.first().copied().unwrap_or_default();
    if let (Some(i), Some(u)) = (
        find_run(runs, Transport::Iceoryx2, first_wait),
        find_run(runs, Transport::Uds, first_wait),
    ) {
        for ((name, a), (_, b)) in i.figures().into_iter().zip(u.figures()) {
            ratios.push((
                name.to_owned(),
                r(a.p50, b.p50),
                r(a.p99, b.p99),
                r(a.max, b.max),
            ));
        }
    }
    ratios
}

/// [`LatencyReport::wait_ratios`] of `runs`.
fn wait_ratios(
    opts: &LatencyOptions,
    runs: &[RunReport],
) -> Vec<(Transport, WaitStrategy, String, f64, f64, f64)> {
    let r = ratio;
    let mut wait_ratios = Vec::new();
    for t in &opts.transports {
        let Some(ev) = find_run(runs, *t, WaitStrategy::Event) else {
            continue;
        };
        for w in opts.waits.iter().filter(|w| w.polls()) {
            let Some(run) = find_run(runs, *t, *w) else {
                continue;
            };
            for ((name, a), (_, b)) in run.figures().into_iter().zip(ev.figures()) {
                wait_ratios.push((
                    *t,
                    *w,
                    name.to_owned(),
                    r(a.p50, b.p50),
                    r(a.p99, b.p99),
                    r(a.max, b.max),
                ));
            }
        }
    }
    wait_ratios
}

/// The report as a table.
pub fn render(r: &LatencyReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}; {:.0} s per transport, load {}, rt {}",
        r.machine,
        r.duration_s,
        r.load,
        r.rt_settings.label()
    );
    let _ = writeln!(
        s,
        "graph: model {}, scripted joystick ({}), mock {} at {} Hz",
        r.settings.model, r.settings.script, r.settings.robot, r.settings.rate_hz
    );
    for run in &r.runs {
        push_run(&mut s, run);
    }
    let mut last = None;
    for (t, w, name, a, b, c) in &r.wait_ratios {
        if last != Some((*t, *w)) {
            last = Some((*t, *w));
            let _ = writeln!(s, "\n{t}: {w} / event (below 1: {w} faster)");
            let _ = writeln!(s, "  {:<20} {:>7} {:>7} {:>7}", "", "p50", "p99", "max");
        }
        let _ = writeln!(s, "  {name:<20} {a:>7.2} {b:>7.2} {c:>7.2}");
    }
    if !r.ratios.is_empty() {
        let _ = writeln!(s, "\niceoryx2 / uds (below 1: iceoryx2 faster)");
        let _ = writeln!(s, "  {:<20} {:>7} {:>7} {:>7}", "", "p50", "p99", "max");
        for (name, a, b, c) in &r.ratios {
            let _ = writeln!(s, "  {name:<20} {a:>7.2} {b:>7.2} {c:>7.2}");
        }
    }
    s
}

/// One run's part of the latency report: its ticks, the latency figures, the resources it
/// used, the polling and the real-time settings.
fn push_run(s: &mut String, run: &RunReport) {
    use std::fmt::Write as _;
    let _ = writeln!(
        s,
        "\n{}, wait {}: {} ticks, {} missed ({} held up by the machine)",
        run.transport, run.wait, run.ticks, run.missed, run.held_up
    );
    if run.wait.polls() {
        let _ = writeln!(
            s,
            "  the joystick sampled late, a margin before each tick: {} missed it",
            run.joystick_late_missed
        );
    }
    if let Some(n) = run.live_client_messages {
        let _ = writeln!(
            s,
            "  with scl up --live and a Foxglove client: {n} messages received"
        );
    }
    let _ = writeln!(
        s,
        "  {:<20} {:>9} {:>9} {:>9} {:>9} {:>9}   (µs)",
        "", "p50", "p90", "p99", "p99.9", "max"
    );
    for (name, d) in run.figures() {
        let _ = writeln!(
            s,
            "  {name:<20} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
            d.p50, d.p90, d.p99, d.p999, d.max
        );
    }
    push_resources(s, run);
    if run.wait.polls() {
        let spin: Vec<String> = run
            .spin_us_per_tick
            .iter()
            .map(|(n, us)| format!("{n} {us:.2}"))
            .collect();
        let _ = writeln!(
            s,
            "  polling per tick (µs): {}",
            if spin.is_empty() {
                "none reported".to_owned()
            } else {
                spin.join(", ")
            }
        );
    }
    for line in &run.realtime {
        let _ = writeln!(s, "  {line}");
    }
}

/// One run's CPU time per tick and share, memory and page faults per process.
fn push_resources(s: &mut String, run: &RunReport) {
    use std::fmt::Write as _;
    if !run.cpu_per_tick_us.is_empty() {
        let cpu: Vec<String> = run
            .cpu_per_tick_us
            .iter()
            .map(|(n, us)| format!("{n} {us:.1}"))
            .collect();
        let _ = writeln!(s, "  CPU per tick (µs): {}", cpu.join(", "));
        let share: Vec<String> = run
            .cpu_share
            .iter()
            .map(|(n, f)| format!("{n} {:.2}", f * 100.0))
            .collect();
        let _ = writeln!(s, "  CPU share (% of one CPU): {}", share.join(", "));
    }
    if !run.memory.is_empty() {
        let mem: Vec<String> = run
            .memory
            .iter()
            .map(|(n, m)| {
                format!(
                    "{n} {:.1}/{:.1}/{:.1}",
                    m.rss_kib as f64 / 1024.0,
                    m.peak_rss_kib as f64 / 1024.0,
                    m.locked_kib as f64 / 1024.0
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "  memory, resident/peak/locked (MiB): {}",
            mem.join(", ")
        );
        let faults: Vec<String> = run
            .memory
            .iter()
            .map(|(n, m)| format!("{n} {}/{}", m.minor_faults, m.major_faults))
            .collect();
        let _ = writeln!(
            s,
            "  page faults in the run, minor/major: {}",
            faults.join(", ")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--rt` with a polling wait leaves the CPUs to the graph's automatic choice; one other
    /// setting alone (`--rt-only fifo`) pins nothing, automatically or not.
    #[test]
    fn rt_settings_pin_only_when_pinning_is_asked_for() {
        use scl_config::placement::MachineCpus;
        let four = MachineCpus::online(4);
        let mut g = scl_config::GraphSection {
            wait: scl_config::WaitStrategy::Predictive,
            ..scl_config::GraphSection::default()
        };
        RtSettings::ALL.apply(&mut g, 4);
        let p = g.placement(&four).unwrap();
        assert_eq!(p.cpus, [Some(3), Some(2), Some(1), Some(0)]);
        RtSettings::only("fifo").unwrap().apply(&mut g, 4);
        assert_eq!(g.placement(&four).unwrap().cpus, [None; 4]);
        g.wait = scl_config::WaitStrategy::Event;
        RtSettings::ALL.apply(&mut g, 4);
        assert_eq!(g.placement(&four).unwrap().cpus, [Some(3); 4]);
    }

    fn report(tick: u64, executed: bool) -> TickReport {
        TickReport {
            tick,
            ideal_ns: 1_000,
            lateness_ns: 50_000,
            state_t_ns: 1_000_000,
            state_rx_ns: 1_040_000,
            joystick_t_ns: 990_000,
            joystick_rx_ns: 1_000_000,
            mapper_t_ns: 1_050_000,
            mapper_rx_ns: 1_080_000,
            safe_t_ns: 1_090_000,
            safe_rx_ns: 1_120_000,
            mapper_compute_ns: 2_000,
            safety_compute_ns: 500,
            missed: u64::from(!executed),
            executed: u32::from(executed),
            reserved: 0,
        }
    }

    #[test]
    fn hops_from_a_tick_report() {
        let mut s = Samples::default();
        s.take(&report(1, true));
        assert_eq!(s.bridge_mapper, vec![40_000]);
        assert_eq!(s.mapper_safety, vec![30_000]);
        assert_eq!(s.safety_bridge, vec![30_000]);
        assert_eq!(s.e2e, vec![120_000]);
        assert_eq!(s.joystick_mapper, vec![10_000]);
        assert_eq!(s.joystick_age, vec![58_000]);
        assert_eq!(s.joystick_executed, vec![130_000]);
        // A missed tick counts, but has no hops.
        s.take(&report(2, false));
        assert_eq!(
            (s.ticks, s.missed, s.e2e.len(), s.lateness.len()),
            (2, 1, 1, 2)
        );
        let d = Dist::of(&s.e2e);
        assert_eq!((d.p50, d.max, d.n), (120.0, 120.0, 1));
    }

    #[test]
    fn the_operators_round_trip_is_read_from_its_log() {
        let log = " INFO scl{role=\"joystick\"}: round trip to the gateway (sample sent -> its \
                   acknowledgement) acknowledged=179 p50_us=\"11689\" p99_us=\"13091\" \
                   max_us=\"21843\"\n";
        assert_eq!(round_trip_from_log(log), Some((11689.0, 13091.0, 21843.0)));
        assert_eq!(round_trip_from_log("nothing\n"), None);
    }

    #[test]
    fn spin_per_tick_is_read_from_the_polling_processes_log_lines() {
        let log = "2026-11-27T13:00:00Z  INFO scl_safety_node: wait strategy process=\"safety\" \
                   wait=predictive spin_us_per_tick=3.50 ticks=2400 polled=2390 fell_back=10\n\
                   INFO real-time: SCHED_FIFO priority 80\n\
                   \u{1b}[2m...\u{1b}[0m wait strategy \u{1b}[3mprocess\u{1b}[0m\u{1b}[2m=\u{1b}[0mmapper \
                   \u{1b}[3mspin_us_per_tick\u{1b}[0m\u{1b}[2m=\u{1b}[0m1.25\n";
        assert_eq!(
            spin_from_log(log),
            [("safety".to_owned(), 3.5), ("mapper".to_owned(), 1.25)]
        );
    }
}
