//! The commands that talk to a running graph: `scl swap`, `scl estop` / `scl reset`,
//! `scl status`.

use std::process::ExitCode;
use std::time::Duration;

use ipc_types::Prefix;
use scl::SclError;
use scl_config::GraphConfig;

use super::parse_duration;

/// `scl swap`'s arguments.
#[derive(clap::Args, Debug)]
pub(crate) struct SwapArgs {
    /// Model file, `bundled`, `modeswitch[:key=value,...]`, the drill map
    /// `constant:qdot=v1,...,v6` (rad/s, whatever the stick), or the go-to map
    /// `goto:pose=home` / `goto:q=v1,...,v6[;speed=S]` (drives to the pose while the
    /// deadman is held: a "go home" button).
    pub(crate) model: String,
    /// How long to wait for the switch-over.
    #[arg(long, default_value = "30s", value_parser = parse_duration, allow_hyphen_values = true)]
    pub(crate) timeout: Duration,
}

/// `scl status`'s options.
#[derive(clap::Args, Debug)]
pub(crate) struct StatusArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub(crate) json: bool,
}

/// `scl swap MODEL`: exit code 1 when the supervisor refused.
pub(crate) fn swap(prefix: &Prefix, args: SwapArgs) -> Result<ExitCode, SclError> {
    let SwapArgs { model, timeout } = args;
    let r = graph_client::control::swap(prefix, &model, timeout)?;
    if r.ok == 1 {
        println!("{}", graph_client::control::swap_line(&r));
        Ok(ExitCode::SUCCESS)
    } else {
        eprintln!("scl swap: refused: {}", r.message.as_string());
        Ok(ExitCode::from(1))
    }
}

/// `scl estop` (`latch`) or `scl reset`: exit code 1 when no safety process confirmed it.
pub(crate) fn estop(prefix: &Prefix, cfg: &GraphConfig, latch: bool) -> Result<ExitCode, SclError> {
    let (action, what) = if latch {
        (ipc_types::control::estop_action::ESTOP, "e-stop latched")
    } else {
        (ipc_types::control::estop_action::RESET, "e-stop reset")
    };
    match graph_client::control::estop(prefix, cfg.graph.transport, action, Duration::from_secs(2))?
    {
        Some(pid) => {
            println!("{what} (confirmed by safety, pid {pid}, graph `{prefix}`)");
            Ok(ExitCode::SUCCESS)
        }
        None => {
            eprintln!(
                "scl: no safety process of graph `{prefix}` confirmed it within 2 s; is the graph running?"
            );
            Ok(ExitCode::from(1))
        }
    }
}

/// `scl status`: exit code 1 when no node sent a heartbeat.
pub(crate) fn status(
    prefix: &Prefix,
    cfg: &GraphConfig,
    args: StatusArgs,
) -> Result<ExitCode, SclError> {
    let StatusArgs { json } = args;
    let st = graph_client::control::status(
        prefix,
        cfg.graph.transport,
        Duration::from_millis(300),
        &cfg.safety.scene.box_names(),
    )?;
    if st.nodes.is_empty() {
        eprintln!(
            "scl status: no node of graph `{prefix}` sent a heartbeat in 300 ms; is it running?"
        );
        return Ok(ExitCode::from(1));
    }
    if json {
        let text = serde_json::to_string_pretty(&st).map_err(|source| SclError::Encode {
            what: "status",
            source,
        })?;
        println!("{text}");
    } else {
        print!("{}", graph_client::control::render(&st));
    }
    Ok(ExitCode::SUCCESS)
}
