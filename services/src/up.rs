//! `scl up`: starts the four processes of the graph as children, reports once a second, and
//! stops them in a safe order (bridge first, so the arm is stopped before anything else goes).
//!
//! Start order: joystick, mapper and safety, each awaited until it reports ready, then the
//! bridge (the clock), so the first tick already finds every process listening. A child that
//! exits while the graph runs ends the run with a non-zero status and a message naming it.

use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus};
use std::time::{Duration, Instant};

use ipc_types::{Graph, NodeRole, NodeStatus, Prefix, phase};
use serde::Serialize;

use crate::config::GraphConfig;
use crate::stats::{Percentiles, percentiles_us};
use crate::{SclError, signals};

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
}

/// The end-of-run summary (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Ticks the bridge ran.
    pub ticks: u64,
    /// Ticks without a valid command in time.
    pub missed: u64,
    /// RobotState(k) published -> SafeCommand(k) received by the bridge, µs.
    pub latency_us: Percentiles,
    /// Lateness of the bridge's clock against the ideal grid, µs.
    pub tick_lateness_us: Percentiles,
    /// Joint-space path length of the arm (rad).
    pub joint_travel_rad: f64,
    /// Latency samples behind the percentiles.
    pub latency_samples: usize,
    /// Wall time of the run (s).
    pub duration_s: f64,
    /// The graph prefix.
    pub prefix: String,
    /// The mapper whose commands the bridge executed last.
    pub active_mapper: u32,
    /// Set when a child died: which, and how.
    pub failure: Option<String>,
}

struct Proc {
    name: &'static str,
    child: Child,
    exited: Option<ExitStatus>,
}

fn describe(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exited with status {c}"),
        (None, Some(9)) => "was killed by signal 9 (SIGKILL)".into(),
        (None, Some(s)) => format!("was killed by signal {s}"),
        _ => "ended".into(),
    }
}

#[derive(Default)]
struct Collector {
    ready: Vec<NodeRole>,
    ticks: u64,
    missed: u64,
    travel: f64,
    active_mapper: u32,
    latency_ns: Vec<u64>,
    lateness_ns: Vec<u64>,
    last_bridge_tick: Option<u64>,
}

impl Collector {
    fn take(&mut self, s: &NodeStatus) {
        let Some(role) = NodeRole::from_u32(s.role) else {
            return;
        };
        if s.phase == phase::READY && !self.ready.contains(&role) {
            self.ready.push(role);
        }
        if role != NodeRole::Bridge || s.phase == phase::READY {
            return;
        }
        self.ticks = self.ticks.max(s.handled);
        self.missed = self.missed.max(s.faults);
        self.travel = s.joint_travel_rad;
        if s.phase == phase::RUNNING && self.last_bridge_tick != Some(s.tick) {
            self.last_bridge_tick = Some(s.tick);
            if s.latency_ns > 0 {
                self.latency_ns.push(s.latency_ns);
                self.active_mapper = s.mapper_id;
            }
            self.lateness_ns.push(s.lateness_ns);
        }
    }
}

fn spawn(name: &'static str, args: &[String]) -> Result<Proc, SclError> {
    let exe = std::env::current_exe()
        .map_err(|e| SclError::Graph(format!("cannot find the scl executable: {e}")))?;
    let mut cmd = Command::new(exe);
    cmd.args(args);
    // SAFETY: setpgid and prctl are async-signal-safe. Each child gets its own process
    // group, so a terminal's Ctrl-C reaches only the supervisor, which then stops the graph
    // in order (bridge first); and each child gets SIGTERM if the supervisor dies, so no
    // process of the graph outlives it.
    unsafe {
        cmd.pre_exec(|| {
            libc::setpgid(0, 0);
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    let child = cmd
        .spawn()
        .map_err(|e| SclError::Graph(format!("cannot start the {name} process: {e}")))?;
    Ok(Proc {
        name,
        child,
        exited: None,
    })
}

fn child_args(opts: &UpOptions, sub: &str) -> Vec<String> {
    let mut a = vec![sub.to_owned(), "--prefix".into(), opts.prefix.to_string()];
    if let Some(p) = &opts.config_path {
        a.push("--config".into());
        a.push(p.display().to_string());
    }
    a
}

fn signal_and_wait(p: &mut Proc, timeout: Duration) {
    if p.exited.is_some() {
        return;
    }
    // SAFETY: sending a signal to our own child's pid.
    unsafe {
        libc::kill(p.child.id() as libc::pid_t, libc::SIGTERM);
    }
    let start = Instant::now();
    loop {
        if let Ok(Some(s)) = p.child.try_wait() {
            p.exited = Some(s);
            return;
        }
        if start.elapsed() > timeout {
            tracing::warn!("{} did not stop within {timeout:?}; killing it", p.name);
            let _ = p.child.kill();
            p.exited = p.child.wait().ok();
            return;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Runs the graph; returns the summary, with `failure` set if a child died.
pub fn run(opts: &UpOptions) -> Result<Summary, SclError> {
    let cfg = &opts.config;
    cfg.validate()?;
    // Refuse a bad model before anything starts.
    crate::mapper_node::load_step(&cfg.mapper.model, cfg.mapper.id)?;
    let cleaned = ipc_types::graph::cleanup_dead_nodes(&opts.prefix)?;
    if cleaned > 0 {
        tracing::info!(
            cleaned,
            "removed resources of dead processes of graph `{}`",
            opts.prefix
        );
    }
    let graph = Graph::join(&opts.prefix, "supervisor")?;
    let status = graph.status_subscriber()?;
    let mut col = Collector::default();
    let mut procs: Vec<Proc> = Vec::new();
    let start_timeout = Duration::from_secs_f64(cfg.graph.start_timeout_s);

    let mut mapper_args = child_args(opts, "mapper");
    mapper_args.extend([
        "--model".into(),
        cfg.mapper.model.clone(),
        "--id".into(),
        cfg.mapper.id.to_string(),
    ]);
    let plan: [(&'static str, Vec<String>, NodeRole); 4] = [
        ("joystick", child_args(opts, "joystick"), NodeRole::Joystick),
        ("mapper", mapper_args, NodeRole::Mapper),
        ("safety", child_args(opts, "safety"), NodeRole::Safety),
        ("bridge", child_args(opts, "bridge"), NodeRole::Bridge),
    ];
    let mut failure: Option<String> = None;
    'start: for (name, args, role) in plan {
        procs.push(spawn(name, &args)?);
        let t0 = Instant::now();
        while !col.ready.contains(&role) {
            status.drain(|s| col.take(s))?;
            if let Some(p) = procs.last_mut()
                && let Ok(Some(s)) = p.child.try_wait()
            {
                p.exited = Some(s);
                failure = Some(format!(
                    "the {name} process {} during start-up",
                    describe(s)
                ));
                break 'start;
            }
            if t0.elapsed() > start_timeout || signals::stop_requested() {
                failure = Some(format!(
                    "the {name} process did not report ready within {start_timeout:?}"
                ));
                break 'start;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    let started = Instant::now();
    let mut next_report = Duration::from_secs(1);
    while failure.is_none() && !signals::stop_requested() {
        std::thread::sleep(Duration::from_millis(5));
        for p in procs.iter_mut() {
            if let Ok(Some(s)) = p.child.try_wait() {
                p.exited = Some(s);
                failure = Some(format!(
                    "the {} process (pid {}) {}",
                    p.name,
                    p.child.id(),
                    describe(s)
                ));
                break;
            }
        }
        status.drain(|s| col.take(s))?;
        let elapsed = started.elapsed();
        if elapsed >= next_report {
            next_report += Duration::from_secs(1);
            let l = percentiles_us(&col.latency_ns);
            eprintln!(
                "scl up: {:>4.0}s  ticks {:>6}  missed {:>3}  e2e p50 {:>6.1} µs  p99 {:>7.1} µs  mapper {}",
                elapsed.as_secs_f64(),
                col.ticks,
                col.missed,
                l.p50,
                l.p99,
                col.active_mapper
            );
        }
        if opts.duration.is_some_and(|d| elapsed >= d) {
            break;
        }
    }
    let duration_s = started.elapsed().as_secs_f64();

    // Bridge first: it stops the arm at once and publishes a final state.
    let order = ["bridge", "safety", "mapper", "joystick"];
    for name in order {
        if let Some(p) = procs.iter_mut().find(|p| p.name == name) {
            signal_and_wait(p, Duration::from_secs(3));
        }
    }
    status.drain(|s| col.take(s))?;
    drop(status);
    drop(graph);
    // Last one out: remove what killed children left and the domain itself, unless an
    // observer (a recorder, a test) is still attached; it releases the domain when it leaves.
    ipc_types::graph::release_domain(&opts.prefix)?;

    if let Some(f) = &failure {
        tracing::error!("{f}; the graph was stopped (bridge first)");
    }
    Ok(Summary {
        ticks: col.ticks,
        missed: col.missed,
        latency_us: percentiles_us(&col.latency_ns),
        tick_lateness_us: percentiles_us(&col.lateness_ns),
        joint_travel_rad: col.travel,
        latency_samples: col.latency_ns.len(),
        duration_s,
        prefix: opts.prefix.to_string(),
        active_mapper: col.active_mapper,
        failure,
    })
}
