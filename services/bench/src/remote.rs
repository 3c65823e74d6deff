//! `scl bench latency --remote LINKS`: the remote operator's figures. For each link, the graph
//! runs with its gateway taking the joystick (`[network] accept_joystick`) and `scl joystick
//! --remote` (the scripted joystick) drives it through Zenoh; the tick reports give, per
//! executed command, the time from the operator's sample to the bridge's execution of the
//! command that used it.
//!
//! Links:
//! * `loopback`: graph and operator on this machine's loopback;
//! * `veth`: the graph in one network namespace, the operator in another, joined by a veth
//!   pair (needs root and `ip`, iproute2);
//! * `veth+Nms`: the veth pair with N ms added each way by a TCP relay in the operator's
//!   namespace that holds every chunk for N ms before passing it on (the project's machines'
//!   kernels have no `netem`: `CONFIG_NET_SCH_NETEM` is not set).
//!
//! The same run measures the control path with the gateway off and on (read-only, on a
//! loopback port, the local scripted joystick), so the gateway's effect is seen beside noise.
//!
//! The clock: the gateway normally stamps a remote sample on arrival (another machine's
//! clock means nothing here). The benchmark's operator runs on this machine, so its graphs
//! set `[network] keep_operator_stamps`: the sample keeps its creation stamp, and the tick
//! reports' `joystick_t_ns` is the operator's. Both sides read `CLOCK_MONOTONIC`; network
//! namespaces do not change it, and the benchmark checks that the operator is in this
//! process's time namespace (a run where it is not is refused).

use std::path::{Path, PathBuf};
use std::time::Duration;

use scl_net::netns::{Side, VethPair};
use serde::Serialize;

use crate::{BenchError, Dist, Extra, LatencyOptions, Machine, RunReport, run_with};

/// The port the gateway listens on inside the robot's namespace.
const VETH_PORT: u16 = 7447;
/// The largest delay a `veth+Nms` link takes.
const MAX_DELAY_MS: u32 = 10_000;

/// One link the operator drives over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Link {
    /// This machine's loopback.
    Loopback,
    /// A veth pair between two network namespaces, with this many ms added each way.
    Veth {
        /// Added delay each way (ms).
        delay_ms: u32,
    },
}

impl std::fmt::Display for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Loopback => f.write_str("loopback"),
            Self::Veth { delay_ms: 0 } => f.write_str("veth"),
            Self::Veth { delay_ms } => write!(f, "veth+{delay_ms}ms"),
        }
    }
}

/// A `--remote` link that is not one.
#[derive(Debug, thiserror::Error)]
#[error(
    "`{0}` is not a link: use loopback, veth or veth+Nms (N whole milliseconds, 1 to {MAX_DELAY_MS})"
)]
pub struct LinkError(String);

impl std::str::FromStr for Link {
    type Err = LinkError;

    fn from_str(s: &str) -> Result<Self, LinkError> {
        let bad = || LinkError(s.to_owned());
        match s.trim() {
            "loopback" => Ok(Self::Loopback),
            "veth" => Ok(Self::Veth { delay_ms: 0 }),
            t => {
                let ms = t
                    .strip_prefix("veth+")
                    .and_then(|r| r.strip_suffix("ms"))
                    .ok_or_else(bad)?;
                match ms.parse::<u32>() {
                    Ok(n) if (1..=MAX_DELAY_MS).contains(&n) => Ok(Self::Veth { delay_ms: n }),
                    _ => Err(bad()),
                }
            }
        }
    }
}

impl Link {
    /// The default links: loopback, the veth pair, and it with 1 and 5 ms each way.
    pub const DEFAULT: [Link; 4] = [
        Link::Loopback,
        Link::Veth { delay_ms: 0 },
        Link::Veth { delay_ms: 1 },
        Link::Veth { delay_ms: 5 },
    ];

    /// A short tag for the run's prefix and files.
    fn tag(&self) -> String {
        match self {
            Self::Loopback => "lo".to_owned(),
            Self::Veth { delay_ms } => format!("veth{delay_ms}"),
        }
    }
}

/// One link's row.
#[derive(Debug, Clone, Serialize)]
pub struct LinkRow {
    /// The link.
    pub link: String,
    /// Added delay each way (ms; a relay, not netem).
    pub delay_ms: u32,
    /// Why the link did not run or was not measured (none: it was).
    pub error: Option<String>,
    /// The operator's sample (its creation on the operator's side) -> the command that used
    /// it received by the bridge, which executes it at once (µs). One per executed command
    /// driven by an operator's sample.
    pub joystick_executed_us: Dist,
    /// The operator's sample -> received by the mapper (µs): the network and the gateway.
    pub joystick_mapper_us: Dist,
    /// The control path's end to end: RobotState(k) published -> SafeCommand(k) at the
    /// bridge (µs).
    pub e2e_us: Dist,
    /// The gateway's CPU time per tick (µs, every thread, Zenoh's included).
    pub gateway_cpu_per_tick_us: Option<f64>,
    /// The operator's round trip, a sample sent -> the gateway's acknowledgement, p50 / p99 /
    /// max (µs, from its log).
    pub round_trip_us: Option<(f64, f64, f64)>,
    /// Ticks observed.
    pub ticks: u64,
    /// Ticks missed.
    pub missed: u64,
    /// Misses the machine took (part of `missed`).
    pub held_up: u64,
    /// The whole run's report.
    pub run: Option<RunReport>,
}

impl LinkRow {
    fn failed(link: Link, e: String) -> Self {
        Self {
            link: link.to_string(),
            delay_ms: match link {
                Link::Loopback => 0,
                Link::Veth { delay_ms } => delay_ms,
            },
            error: Some(e),
            joystick_executed_us: Dist::default(),
            joystick_mapper_us: Dist::default(),
            e2e_us: Dist::default(),
            gateway_cpu_per_tick_us: None,
            round_trip_us: None,
            ticks: 0,
            missed: 0,
            held_up: 0,
            run: None,
        }
    }

    fn of(link: Link, run: RunReport) -> Self {
        let mut row = Self::failed(link, String::new());
        row.error = check(&run);
        row.joystick_executed_us = run.joystick_executed_us;
        row.joystick_mapper_us = run.hops_us.joystick_mapper;
        row.e2e_us = run.e2e_us;
        row.gateway_cpu_per_tick_us = gateway_cpu(&run);
        row.round_trip_us = run.operator.as_ref().and_then(|o| o.round_trip_us);
        row.ticks = run.ticks;
        row.missed = run.missed;
        row.held_up = run.held_up;
        row.run = Some(run);
        row
    }
}

/// The gateway's CPU time per tick in a run.
fn gateway_cpu(run: &RunReport) -> Option<f64> {
    run.cpu_per_tick_us
        .iter()
        .find(|(n, _)| n == "gateway")
        .map(|(_, us)| *us)
}

/// What makes a remote run's figures unusable, if anything.
fn check(run: &RunReport) -> Option<String> {
    let op = run.operator.as_ref()?;
    if op.pid.is_none() {
        return Some("the operator never started (the graph did not tick)".into());
    }
    match op.same_clock {
        Some(true) => {}
        Some(false) => {
            return Some(
                "the operator runs in another time namespace: its stamps do not compare".into(),
            );
        }
        None => return Some("the operator ended before the run did".into()),
    }
    if run.joystick_executed_us.n == 0 {
        return Some("no executed command used an operator's sample".into());
    }
    None
}

/// The remote benchmark's result (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct RemoteReport {
    /// The machine.
    pub machine: Machine,
    /// Seconds per run.
    pub duration_s: f64,
    /// The graph's rate (Hz).
    pub rate_hz: f64,
    /// The operator's script.
    pub script: String,
    /// How delay was added.
    pub delay_method: String,
    /// How the two sides' stamps compare.
    pub clock: String,
    /// The control path with the gateway off, then on (read-only, the local joystick).
    pub gateway_off: Option<RunReport>,
    /// See `gateway_off`.
    pub gateway_on: Option<RunReport>,
    /// on / off of the end to end's p50, p99 and max.
    pub gateway_on_off_e2e: Option<(f64, f64, f64)>,
    /// One row per link, in the order asked for.
    pub links: Vec<LinkRow>,
}

impl RemoteReport {
    /// The links that failed, as `link: why`.
    pub fn failures(&self) -> Vec<String> {
        self.links
            .iter()
            .filter_map(|r| r.error.as_ref().map(|e| format!("{}: {e}", r.link)))
            .collect()
    }
}

/// A credentials file of one `user:password` line, mode 0600.
fn credentials(dir: &Path) -> Result<PathBuf, BenchError> {
    use std::os::unix::fs::PermissionsExt as _;
    let p = dir.join("bench.creds");
    std::fs::write(&p, "operator:bench-only\n")
        .and_then(|()| std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)))
        .map_err(|e| BenchError::Graph(format!("{}: {e}", p.display())))?;
    Ok(p)
}

/// Runs the control path with the gateway off and on, then the operator over each of
/// `links`. A link that cannot run (no root, no `ip`, ...) gives a row with its error; the
/// others still run.
pub fn remote(opts: &LatencyOptions, links: &[Link]) -> Result<RemoteReport, BenchError> {
    let dir = match &opts.out {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!("scl-bench-remote-{}", std::process::id())),
    };
    std::fs::create_dir_all(&dir)
        .map_err(|e| BenchError::Graph(format!("{}: {e}", dir.display())))?;
    let transport = opts
        .transports
        .first()
        .copied()
        .unwrap_or(ipc_types::Transport::Iceoryx2);
    let wait = opts
        .waits
        .first()
        .copied()
        .unwrap_or(opts.config.graph.wait);
    let creds = credentials(&dir)?;

    // The control path with the gateway off, then on (read-only), the local joystick.
    let mut off = opts.clone();
    off.config.network.enabled = false;
    let (off_run, _) = run_with(&off, transport, wait, &dir, "-gwoff", &Extra::default())?;
    let mut on = opts.clone();
    on.config.network = scl_config::NetworkConfig {
        enabled: true,
        listen: vec![format!(
            "tcp/127.0.0.1:{}",
            crate::free_loopback_port_or_err()?
        )],
        ..scl_config::NetworkConfig::default()
    };
    let (on_run, _) = run_with(&on, transport, wait, &dir, "-gwon", &Extra::default())?;
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
    let on_off = (
        ratio(on_run.e2e_us.p50, off_run.e2e_us.p50),
        ratio(on_run.e2e_us.p99, off_run.e2e_us.p99),
        ratio(on_run.e2e_us.max, off_run.e2e_us.max),
    );

    let mut veth: Option<Result<VethPair, String>> = None;
    let mut rows = Vec::new();
    for link in links {
        if transport::signals::stop_requested() {
            break;
        }
        let row = match run_link(opts, *link, transport, wait, &dir, &creds, &mut veth) {
            Ok(run) => LinkRow::of(*link, run),
            Err(e) => LinkRow::failed(*link, e),
        };
        if let Some(e) = &row.error {
            eprintln!("bench: {link}: {e}");
        }
        rows.push(row);
    }
    drop(veth);
    if opts.out.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    Ok(RemoteReport {
        machine: Machine::detect(),
        duration_s: opts.duration.as_secs_f64(),
        rate_hz: opts.config.graph.rate_hz,
        script: opts.config.joystick.script.clone(),
        delay_method: "a TCP relay in the operator's namespace holding every chunk for the \
                       delay, each way (not netem: the project's machines' kernels have no \
                       CONFIG_NET_SCH_NETEM)"
            .into(),
        clock: "CLOCK_MONOTONIC on both sides, one time namespace (checked per run); the \
                gateway keeps the operator's stamps ([network] keep_operator_stamps)"
            .into(),
        gateway_off: Some(off_run),
        gateway_on: Some(on_run),
        gateway_on_off_e2e: Some(on_off),
        links: rows,
    })
}

/// One link's run; its error as the user reads it.
fn run_link(
    opts: &LatencyOptions,
    link: Link,
    transport: ipc_types::Transport,
    wait: scl_config::WaitStrategy,
    dir: &Path,
    creds: &Path,
    veth: &mut Option<Result<VethPair, String>>,
) -> Result<RunReport, String> {
    let tag = format!("-{}", link.tag());
    let namespace = format!("sclbench/{}{}", std::process::id(), link.tag());
    let mut cfg = opts.config.clone();
    cfg.joystick.source = "script".into();
    cfg.network = scl_config::NetworkConfig {
        enabled: true,
        accept_joystick: true,
        credentials: creds.display().to_string(),
        namespace: namespace.clone(),
        keep_operator_stamps: true,
        ..scl_config::NetworkConfig::default()
    };
    let mut extra = Extra::default();
    let mut relay = None;
    let endpoint = match link {
        Link::Loopback => {
            let port = crate::free_loopback_port_or_err().map_err(|e| e.to_string())?;
            cfg.network.listen = vec![format!("tcp/127.0.0.1:{port}")];
            format!("tcp/127.0.0.1:{port}")
        }
        Link::Veth { delay_ms } => {
            let v = veth
                .get_or_insert_with(|| VethPair::new("b").map_err(|e| e.to_string()))
                .as_ref()
                .map_err(Clone::clone)?;
            let robot_ip = v.addr(Side::Robot);
            cfg.network.listen = vec![format!("tcp/{robot_ip}:{VETH_PORT}")];
            extra.up_wrap = v.exec_prefix(Side::Robot);
            let direct = format!("tcp/{robot_ip}:{VETH_PORT}");
            let op_wrap = v.exec_prefix(Side::Operator);
            let endpoint = if delay_ms > 0 {
                let r = scl_net::relay::Relay::start(
                    v.netns(Side::Operator),
                    format!("{robot_ip}:{VETH_PORT}"),
                    Duration::from_millis(u64::from(delay_ms)),
                )
                .map_err(|e| e.to_string())?;
                let e = r.endpoint();
                relay = Some(r);
                e
            } else {
                direct
            };
            extra.operator = Some((op_wrap, Vec::new()));
            endpoint
        }
    };
    // The operator reads the same graph configuration (its rate, its script).
    let op_cfg = dir.join(format!("operator{tag}.toml"));
    let text = toml::to_string(&cfg).map_err(|e| format!("cannot write the config: {e}"))?;
    std::fs::write(&op_cfg, text).map_err(|e| format!("{}: {e}", op_cfg.display()))?;
    let args: Vec<String> = [
        "joystick",
        "--prefix",
        &format!("benchop{}", std::process::id()),
        "--config",
        &op_cfg.display().to_string(),
        "--remote",
        &endpoint,
        "--credentials",
        &creds.display().to_string(),
        "--namespace",
        &namespace,
        "--source",
        "script",
        "--script",
        &cfg.joystick.script,
    ]
    .map(str::to_owned)
    .to_vec();
    let wrap = extra.operator.take().map(|(w, _)| w).unwrap_or_default();
    extra.operator = Some((wrap, args));
    let mut o = opts.clone();
    o.config = cfg;
    eprintln!("bench: remote operator over {link}");
    let run = run_with(&o, transport, wait, dir, &tag, &extra)
        .map(|(r, _)| r)
        .map_err(|e| e.to_string());
    drop(relay);
    run
}

/// The report as a table.
pub fn render(r: &RemoteReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}; {:.0} s per run, {} Hz, operator: scl joystick --remote, script {}",
        r.machine, r.duration_s, r.rate_hz, r.script
    );
    let _ = writeln!(s, "clock: {}", r.clock);
    let _ = writeln!(s, "delay: {}", r.delay_method);
    if let (Some(off), Some(on)) = (&r.gateway_off, &r.gateway_on) {
        let _ = writeln!(
            s,
            "\ncontrol path, local joystick: end to end p50 / p99 / max (µs), missed (held up)"
        );
        for (name, run) in [("gateway off", off), ("gateway on", on)] {
            let _ = writeln!(
                s,
                "  {name:<12} {:>8.1} {:>8.1} {:>8.1}   {} ({})",
                run.e2e_us.p50, run.e2e_us.p99, run.e2e_us.max, run.missed, run.held_up
            );
        }
        if let Some((a, b, c)) = r.gateway_on_off_e2e {
            let _ = writeln!(s, "  {:<12} {a:>8.2} {b:>8.2} {c:>8.2}", "on / off");
        }
    }
    let _ = writeln!(
        s,
        "\nremote operator, p50 / p99 / max (µs): joystick -> executed (the operator's sample \
         -> the bridge executing the command that used it), joystick -> mapper, graph e2e"
    );
    let _ = writeln!(
        s,
        "  {:<11} {:>26} {:>24} {:>20} {:>9} {:>7} {:>13}",
        "link",
        "joystick -> executed",
        "joystick -> mapper",
        "graph e2e",
        "gw CPU/tick",
        "ticks",
        "missed (held)"
    );
    let d = |d: &Dist| format!("{:.0} / {:.0} / {:.0}", d.p50, d.p99, d.max);
    for row in &r.links {
        if row.run.is_none() {
            let _ = writeln!(
                s,
                "  {:<11} FAILED: {}",
                row.link,
                row.error.as_deref().unwrap_or("")
            );
            continue;
        }
        let _ = writeln!(
            s,
            "  {:<11} {:>26} {:>24} {:>20} {:>9} {:>7} {:>13}",
            row.link,
            d(&row.joystick_executed_us),
            d(&row.joystick_mapper_us),
            format!("{:.0} / {:.0}", row.e2e_us.p50, row.e2e_us.p99),
            row.gateway_cpu_per_tick_us
                .map_or("-".to_owned(), |us| format!("{us:.0} µs")),
            row.ticks,
            format!("{} ({})", row.missed, row.held_up)
        );
        if let Some((a, b, c)) = row.round_trip_us {
            let _ = writeln!(
                s,
                "    the operator's round trip (sample sent -> the gateway's acknowledgement): \
                 {a:.0} / {b:.0} / {c:.0}"
            );
        }
        if let Some(e) = &row.error {
            let _ = writeln!(s, "    FAILED: {e}");
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn links_parse_and_a_bad_one_is_named() {
        let l: Vec<Link> = ["loopback", "veth", "veth+1ms", "veth+5ms"]
            .iter()
            .map(|s| s.parse().unwrap())
            .collect();
        assert_eq!(l, Link::DEFAULT);
        assert_eq!(
            l.iter().map(ToString::to_string).collect::<Vec<_>>(),
            ["loopback", "veth", "veth+1ms", "veth+5ms"]
        );
        for bad in ["lo", "veth+", "veth+0ms", "veth+1.5ms", "veth+5", "wifi"] {
            let e = bad.parse::<Link>().unwrap_err().to_string();
            assert!(e.contains(&format!("`{bad}`")), "{e}");
        }
    }

    #[test]
    fn this_process_reads_its_own_clock() {
        assert_eq!(crate::same_monotonic_clock(std::process::id()), Some(true));
    }
}
