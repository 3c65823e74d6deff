//! `scl up`: the whole graph as supervised children.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use ipc_types::Prefix;
use scl::SclError;
use scl_config::GraphConfig;

use super::parse_duration;

/// `scl up`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct UpArgs {
    /// Stop after this long (e.g. `60s`, `2m`, `500ms`); default: until Ctrl-C.
    #[arg(long = "for", value_name = "DURATION", value_parser = parse_duration, allow_hyphen_values = true)]
    pub(crate) duration: Option<Duration>,
    /// Print one JSON summary object on stdout at the end. Its `joint_travel_rad` is the
    /// arm's joint-space path length: the Euclidean norm of each tick's change of the
    /// joint angles, summed (not the sum of every joint's absolute change).
    #[arg(long)]
    pub(crate) json: bool,
    /// Serve this model file (or `bundled`, `modeswitch[:key=value,...]` for Cartesian
    /// mode switching, or the drill map `constant:qdot=v1,...,v6`: that joint velocity in
    /// rad/s whenever safety lets it, whatever the stick, each within the URDF's limits, or
    /// the go-to map `goto:pose=home` / `goto:q=q1,...,q6[;speed=0.3]`: to a named pose or a
    /// joint vector on a straight line in joint space) instead of the config's.
    #[arg(long, value_name = "FILE")]
    pub(crate) model: Option<String>,
    /// Joystick script instead of the config's (`[joystick] script`).
    #[arg(long, value_enum)]
    pub(crate) script: Option<scl_joystick::script::ScriptName>,
    /// Joystick source instead of the config's: `script`, `evdev`, `keyboard`, `replay`,
    /// or `external` (no joystick process: the input comes from whoever publishes it on
    /// the graph's joystick topic, e.g. a Python agent).
    #[arg(long, value_name = "SOURCE")]
    pub(crate) joystick: Option<String>,
    /// Record every message of the graph to this MCAP file (a supervised `scl record`,
    /// started before the bridge and stopped last).
    #[arg(long, value_name = "FILE")]
    pub(crate) record: Option<PathBuf>,
    /// Serve the graph to Foxglove while it runs (a `scl live` child, started before the
    /// bridge): connect Foxglove to ws://ADDR:PORT (default 127.0.0.1:8765, loopback
    /// only; any other address is reachable from that network and a warning says so).
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1, default_missing_value = scl_live::DEFAULT_LISTEN)]
    pub(crate) live: Option<String>,
}

/// `scl up`: the config file `config_path` with the options applied, run until the duration
/// passes or Ctrl-C; prints the summary. Exit code 1 when a child died for good.
pub(crate) fn run(
    prefix: Prefix,
    config_path: Option<PathBuf>,
    mut cfg: GraphConfig,
    args: UpArgs,
) -> Result<ExitCode, SclError> {
    let UpArgs {
        duration,
        json,
        model,
        script,
        joystick,
        record,
        live,
    } = args;
    if let Some(m) = model {
        cfg.mapper.model = m;
    }
    if let Some(s) = script {
        cfg.joystick.script = s.name().to_owned();
    }
    if let Some(s) = joystick {
        cfg.joystick.source = s;
    }
    // `[joystick]` and its files are the joystick crate's to check: refused here,
    // before the supervisor starts anything (after the checks of the whole file).
    cfg.validate_file(config_path.as_deref())?;
    scl_joystick::validate(&cfg.joystick)?;
    let opts = scl_supervisor::up::UpOptions {
        prefix,
        config_path,
        config: cfg,
        duration,
        json,
        record: record.map(|p| scl_recorder::absolute(&p)),
        live,
    };
    let summary = scl_supervisor::up::run(&opts).inspect_err(|_| {
        // A graph that did not start (its live server could not serve, ...) leaves nothing
        // behind: the supervisor's node is gone; its domain goes too, unless another process
        // of this prefix is alive.
        let _ = transport::graph::release_domain(&opts.prefix);
    })?;
    if json {
        let text = serde_json::to_string(&summary).map_err(|source| SclError::Encode {
            what: "summary",
            source,
        })?;
        println!("{text}");
    } else {
        eprintln!(
            "scl up: {} ticks, {} missed, e2e latency p50 {:.1} µs p99 {:.1} µs max {:.1} µs, joint travel {:.3} rad",
            summary.ticks,
            summary.missed,
            summary.latency_us.p50,
            summary.latency_us.p99,
            summary.latency_us.max,
            summary.joint_travel_rad
        );
    }
    if let Some(f) = summary.failure {
        eprintln!("scl up: {f}");
        return Ok(ExitCode::from(1));
    }
    Ok(ExitCode::SUCCESS)
}
