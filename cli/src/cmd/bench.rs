//! `scl bench`: the latency and headroom benchmarks.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Subcommand;
use scl::SclError;
use scl_config::GraphConfig;

use super::parse_duration;

#[derive(Subcommand, Debug)]
pub(crate) enum BenchCmd {
    /// Run the full graph and report what the operator feels first (joystick -> executed:
    /// the stick's sample read -> the bridge executing the command that carries it), then
    /// per-hop, end-to-end, sample-age, tick-lateness and compute figures (p50 / p90 / p99 /
    /// p99.9 / max), on iceoryx2, on Unix-domain datagram sockets, or both one after the
    /// other with the ratio of each figure.
    Latency {
        /// How long each transport runs.
        #[arg(long = "for", value_name = "DURATION", default_value = "60s", value_parser = parse_duration, allow_hyphen_values = true)]
        duration: Duration,
        #[command(flatten)]
        rt: RtArgs,
        /// Busy processes to run beside the graph.
        #[arg(long, default_value_t = 0)]
        load: usize,
        /// `iceoryx2`, `uds` or `both`.
        #[arg(long, default_value = "iceoryx2")]
        transport: String,
        /// The graph's tick rate (Hz, up to 1000); default: `[graph] rate_hz` of the config.
        #[arg(long, value_name = "HZ")]
        rate_hz: Option<f64>,
        /// How the mapper, safety and the bridge wait for their input (`[graph] wait`):
        /// `event` (a wake-up per hop), `predictive` (sleep until shortly before the input is
        /// due, then poll briefly) or `spin` (poll always); with either of the last two the
        /// joystick reads its input a margin before each tick (`[joystick] sample_margin_us`)
        /// and the report counts its samples that missed. Comma-separated, each runs on each
        /// transport in turn and the report compares every polling strategy with `event`.
        /// The report adds each polling process's time spent polling per tick. Default: the
        /// config's.
        #[arg(long, value_name = "WAIT", value_delimiter = ',')]
        wait: Vec<scl_config::WaitStrategy>,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Run the graph with `scl up --live` (a free loopback port) and a Foxglove WebSocket
        /// client subscribed to every channel for the whole run; compare with a run without.
        #[arg(long)]
        live: bool,
        /// Keep the report (report.json), the runs' configs and logs in DIR.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// The remote operator instead: the control path with the gateway off and on (the
        /// local joystick, end to end p50 / p99 / max and their ratio), then per link the
        /// graph with its gateway taking the joystick and `scl joystick --remote` (the
        /// config's script, `circle` by default) driving it through Zenoh, for `--for` each:
        /// joystick -> executed (the operator's sample created -> the bridge executing the
        /// command that used it; one monotonic clock, both sides on this machine),
        /// joystick -> mapper, the graph's end to end, the gateway's CPU time per tick and
        /// missed ticks. Links, comma-separated: `loopback`, `veth` (the graph and the
        /// operator in two network namespaces joined by a veth pair: needs root and `ip`,
        /// iproute2) and `veth+Nms` (N ms added each way by a TCP relay in the operator's
        /// namespace; this project's kernels have no netem). A link that cannot run is a
        /// failed row naming what is missing, and the command exits with failure.
        /// `--remote default`: loopback,veth,veth+1ms,veth+5ms.
        #[arg(
            long,
            value_name = "LINKS",
            value_delimiter = ',',
            conflicts_with = "live"
        )]
        remote: Vec<String>,
    },
    /// Run the graph at rising rates (40, 100, 250, 500, 1000 Hz unless `--rates`) and report
    /// per rate the missed ticks (and how many the machine took), end to end p50 / p99 / max,
    /// the tick lateness, and each process's CPU time per tick; a table (or `--json`), and
    /// with `--out` report.json and headroom.png.
    Headroom {
        /// How long each rate runs on each transport.
        #[arg(long, value_name = "SECONDS", default_value_t = 30.0)]
        secs: f64,
        /// The rates (Hz, comma-separated, each up to 1000).
        #[arg(long, value_delimiter = ',', default_values_t = scl_bench::headroom::DEFAULT_RATES)]
        rates: Vec<f64>,
        #[command(flatten)]
        rt: RtArgs,
        /// Busy processes to run beside the graph.
        #[arg(long, default_value_t = 0)]
        load: usize,
        /// `iceoryx2`, `uds` or `both` (each rate on each transport).
        #[arg(long, default_value = "iceoryx2")]
        transport: String,
        /// How the mapper, safety and the bridge wait for their input (`[graph] wait`:
        /// `event`, `predictive` or `spin`); each row then shows the polling time per tick.
        /// Default: the config's.
        #[arg(long, value_name = "WAIT")]
        wait: Option<scl_config::WaitStrategy>,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Keep the report (report.json), the plot (headroom.png), the runs' configs and logs
        /// in DIR.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// The floor under the graph's figures: one hop's publish-to-receive latency on iceoryx2
    /// and on Unix-domain datagram sockets, with the receiver polling its subscriber and
    /// with it waiting for the event, in one run (p50 / p99 / max, and iceoryx2 / uds).
    Hops {
        /// Messages per transport and wait.
        #[arg(long, default_value_t = 5000)]
        count: usize,
        /// Time between two messages (the graph's period at 1 kHz by default).
        #[arg(long, value_name = "DURATION", default_value = "1ms", value_parser = parse_duration, allow_hyphen_values = true)]
        interval: Duration,
        /// `iceoryx2`, `uds` or `both`.
        #[arg(long, default_value = "both")]
        transport: String,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// A busy loop (the load processes of `--load`).
    #[command(hide = true)]
    Burn,
}

/// The real-time settings of a benchmark's graph.
#[derive(clap::Args, Debug, Clone)]
pub(crate) struct RtArgs {
    /// Ask for the standard real-time tuning on the control path: SCHED_FIFO priorities,
    /// mlockall, pinning to the last CPU (with a polling `--wait`: spread over the CPUs so
    /// that each polling process can poll, e.g. on 2 CPUs the bridge on CPU 0, the others on
    /// CPU 1; the config's `[graph] rt_cpus` if it sets them), and `/dev/cpu_dma_latency` held at 0 while the graph runs (the report says what
    /// each process got and what the machine refused).
    #[arg(long, conflicts_with = "rt_only")]
    pub(crate) rt: bool,
    /// Ask for one real-time setting alone, to measure its effect: `fifo`, `mlock`, `pin` or
    /// `dma-latency`.
    #[arg(long, value_name = "SETTING")]
    pub(crate) rt_only: Option<String>,
}

impl RtArgs {
    fn settings(&self) -> Result<scl_bench::RtSettings, SclError> {
        match (&self.rt_only, self.rt) {
            (Some(name), _) => scl_bench::RtSettings::only(name)
                .map_err(|e| SclError::Other(format!("--rt-only {e}"))),
            (None, true) => Ok(scl_bench::RtSettings::ALL),
            (None, false) => Ok(scl_bench::RtSettings::NONE),
        }
    }
}

/// The transports of `--transport`.
fn parse_transports(t: &str) -> Result<Vec<ipc_types::Transport>, SclError> {
    match t {
        "iceoryx2" => Ok(vec![ipc_types::Transport::Iceoryx2]),
        "uds" => Ok(vec![ipc_types::Transport::Uds]),
        "both" => Ok(vec![
            ipc_types::Transport::Iceoryx2,
            ipc_types::Transport::Uds,
        ]),
        other => Err(SclError::Other(format!(
            "--transport {other}: use iceoryx2, uds or both"
        ))),
    }
}

/// `scl bench latency --remote LINKS`.
fn run_remote(
    opts: &scl_bench::LatencyOptions,
    links: &[String],
    json: bool,
    out: Option<&std::path::Path>,
) -> Result<ExitCode, SclError> {
    use scl_bench::remote::Link;
    let mut parsed = Vec::new();
    for l in links {
        if l == "default" {
            parsed.extend(Link::DEFAULT);
        } else {
            parsed.push(l.parse::<Link>().map_err(SclError::Link)?);
        }
    }
    if opts.transports.len() > 1 || opts.waits.len() > 1 {
        return Err(SclError::Other(
            "--remote runs one transport and one wait strategy: give one of each".into(),
        ));
    }
    let report = scl_bench::remote::remote(opts, &parsed)?;
    emit_report(&report, out, json, || scl_bench::remote::render(&report))?;
    let failed = report.failures();
    if failed.is_empty() {
        Ok(ExitCode::SUCCESS)
    } else {
        for f in &failed {
            tracing::error!("bench --remote: {f}");
        }
        Ok(ExitCode::FAILURE)
    }
}

/// `scl bench WHAT` on the graph configured by `cfg`.
pub(crate) fn run(what: BenchCmd, mut cfg: GraphConfig) -> Result<ExitCode, SclError> {
    match what {
        BenchCmd::Burn => scl_bench::burn(),
        BenchCmd::Latency {
            duration,
            rt,
            load,
            transport,
            rate_hz,
            wait,
            json,
            live,
            out,
            remote,
        } => {
            let transports = parse_transports(&transport)?;
            if let Some(r) = rate_hz {
                cfg.set_rate_hz(r);
            }
            cfg.validate()?;
            let waits = if wait.is_empty() {
                vec![cfg.graph.wait]
            } else {
                wait
            };
            let opts = scl_bench::LatencyOptions {
                duration,
                rt: rt.settings()?,
                load,
                transports,
                waits,
                config: cfg,
                out: out.clone(),
                live,
            };
            if !remote.is_empty() {
                return run_remote(&opts, &remote, json, out.as_deref());
            }
            let report = scl_bench::latency(&opts)?;
            emit_report(&report, out.as_deref(), json, || scl_bench::render(&report))
        }
        BenchCmd::Headroom {
            secs,
            rates,
            rt,
            load,
            transport,
            wait,
            json,
            out,
        } => {
            if let Some(w) = wait {
                cfg.graph.wait = w;
            }
            if !(secs.is_finite() && secs > 0.0) {
                return Err(SclError::Other(format!(
                    "--secs {secs}: must be a positive number of seconds"
                )));
            }
            check_rates(&cfg, &rates)?;
            let opts = scl_bench::headroom::HeadroomOptions {
                rates,
                duration: Duration::from_secs_f64(secs),
                rt: rt.settings()?,
                load,
                transports: parse_transports(&transport)?,
                config: cfg,
                out: out.clone(),
            };
            let report = scl_bench::headroom::headroom(&opts)?;
            emit_report(&report, out.as_deref(), json, || {
                scl_bench::headroom::render(&report)
            })
        }
        BenchCmd::Hops {
            count,
            interval,
            transport,
            json,
        } => hops(count, interval, &transport, json),
    }
}

/// `scl bench hops`: the per-hop latencies, as JSON or text.
fn hops(
    count: usize,
    interval: Duration,
    transport: &str,
    json: bool,
) -> Result<ExitCode, SclError> {
    if count == 0 || interval.is_zero() {
        return Err(SclError::Other(
            "--count and --interval must be positive".into(),
        ));
    }
    let opts = scl_bench::hops::HopsOptions {
        count,
        interval,
        transports: parse_transports(transport)?,
    };
    let report = scl_bench::hops::hops(&opts)?;
    emit_report(&report, None, json, || scl_bench::hops::render(&report))
}

/// Every rate of `rates` makes a valid configuration of `cfg`.
fn check_rates(cfg: &GraphConfig, rates: &[f64]) -> Result<(), SclError> {
    for r in rates {
        let mut c = cfg.clone();
        c.set_rate_hz(*r);
        c.validate()
            .map_err(|source| SclError::Rate { rate: *r, source })?;
    }
    Ok(())
}

/// A report as JSON, written to `out/report.json` if given, printed as JSON or as `text`.
fn emit_report(
    report: &impl serde::Serialize,
    out: Option<&std::path::Path>,
    json: bool,
    text: impl FnOnce() -> String,
) -> Result<ExitCode, SclError> {
    let encoded = serde_json::to_string_pretty(report).map_err(|source| SclError::Encode {
        what: "report",
        source,
    })?;
    if let Some(dir) = out {
        let p = dir.join("report.json");
        std::fs::write(&p, &encoded).map_err(|source| SclError::Write {
            path: p.clone(),
            source,
        })?;
    }
    if json {
        println!("{encoded}");
    } else {
        print!("{}", text());
    }
    Ok(ExitCode::SUCCESS)
}
