//! `scl`: the SCL teleoperation stack in one command. See `scl --help`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use ipc_types::Prefix;
use scl::SclError;
use scl_config::GraphConfig;
use transport::signals;

mod cmd;

/// Teleoperate a 6-joint arm with a 2-axis joystick through a learned action map.
///
/// The graph is four processes talking through iceoryx2 shared memory: joystick -> mapper ->
/// safety -> bridge, with the bridge as the only clock (`[graph] rate_hz`, 40 Hz by default,
/// up to 1000). `scl up` runs all four on the
/// mock Gen3 lite with a scripted joystick and the bundled model.
#[derive(Parser, Debug)]
#[command(name = "scl", version, propagate_version = true)]
struct Cli {
    /// Graph prefix: isolates this graph's services and shared memory from every other graph.
    #[arg(long, global = true, env = ipc_types::prefix::PREFIX_ENV)]
    prefix: Option<String>,
    /// Graph configuration (TOML); every key is optional, see examples/graph.toml.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run the whole graph: joystick, mapper, safety and bridge as supervised children.
    Up(cmd::up::UpArgs),
    /// Record every message of a running graph to an MCAP file (read-only; Foxglove opens
    /// it), until Ctrl-C. `--recover` repairs a recording cut by a crash.
    Record(scl_recorder::RecordArgs),
    /// User studies as the paper ran them: `run` walks a participant through a study file on
    /// the live graph, `report` draws the figures and runs the tests, `plan` prints the
    /// counterbalanced orders, `simulate` runs simulated participants on the mock arm.
    Study {
        #[command(subcommand)]
        what: scl_study::StudyCmd,
    },
    /// Serve a running graph to Foxglove over its WebSocket protocol (read-only): the
    /// recording's topics plus the 3D view (/tf, the arm's capsules coloured by clearance, the
    /// map's two directions at the tool, /scl/tick), until Ctrl-C. Open Foxglove, "Open
    /// connection", Foxglove WebSocket, ws://127.0.0.1:8765, and load docs/foxglove-layout.json.
    Live(scl_live::LiveArgs),
    /// Turn recordings into a training data set (CSV trajectories in train/ and val/).
    Dataset(learning::to_dataset::DatasetArgs),
    /// Re-execute a recording tick by tick (the mapper's and safety's steps on the recorded
    /// states, joystick samples and control events) and compare every command bit for bit;
    /// exits 1 on a divergence, naming its tick. `--tick K --explain` spells one tick out.
    Replay(replay::ReplayArgs),
    /// A terminal dashboard of a running graph (works over SSH in 80x24).
    Top(scl_dashboard::TopArgs),
    /// Swap the running graph's mapper for one serving MODEL, without missing a tick.
    ///
    /// The supervisor starts a new mapper process beside the old one, waits until it has
    /// produced valid commands for `swap_valid_ticks` consecutive ticks, has safety switch to
    /// it at a tick boundary, then stops the old one. A model that does not load is refused
    /// and the old mapper keeps running. The reply counts the ticks the bridge missed
    /// meanwhile and how many of them the machine took (held up, as `scl up --json` counts
    /// `held_up`): without real-time scheduling, a loaded machine can hold the graph up
    /// during a swap, whose start-up work competes with it.
    Swap(cmd::control::SwapArgs),
    /// Latch the running graph's e-stop: safety commands zero at once and keeps doing so
    /// until `scl reset`.
    Estop,
    /// Release a latched e-stop.
    Reset,
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: cmd::bench::BenchCmd,
    },
    /// Is this machine ready to drive the arm? Checks real-time rights, the kernel, CPU power
    /// settings, shared memory and leftovers, joysticks, the configuration (`--config`), its
    /// model and, with `[bridge] robot = "kortex"`, the arm itself through a read-only session.
    /// Prints ok / warn / fail with what to do; exit code 1 on any fail.
    Doctor(scl::doctor::DoctorArgs),
    /// Show the running graph: nodes, pids, liveness, active mapper, counters.
    Status(cmd::control::StatusArgs),
    /// Print the messages' memory layout as JSON (size, alignment, every field's offset and
    /// type, iceoryx2 type names, topic settings, bit names): what a binding in another
    /// language must match; the Python package's drift test compares itself with it.
    Layout,
    /// The joystick process: a script, a joystick or gamepad (evdev), the keyboard, or a
    /// recorded input file; `--list` shows the input devices attached.
    Joystick(scl_joystick::JoystickArgs),
    /// A mapper process serving one model.
    Mapper(cmd::nodes::MapperArgs),
    /// The safety process (the one publisher of the executed command).
    Safety,
    /// The hardware bridge: the robot and the graph's clock.
    Bridge(cmd::nodes::BridgeArgs),
    /// A fake Gen3 lite speaking the Kortex protocol on 127.0.0.1 (user admin, password
    /// admin), for trying `bridge --robot kortex` without an arm.
    ///
    /// Serves over TCP: Session.CreateSession, CloseSession, KeepAlive; Base.Stop,
    /// ApplyEmergencyStop, ClearFaults, SetServoingMode (single-level, low-level),
    /// GetServoingMode, GetActuatorCount, GetArmState, GetMeasuredJointAngles,
    /// SendJointSpeedsCommand, SendGripperCommand (position, finger 1), GetProductConfiguration
    /// (an empty CompleteProductConfiguration); BaseCyclic.RefreshFeedback;
    /// ControlConfig.GetKinematicHardLimits; DeviceConfig.GetFirmwareVersion; over UDP the
    /// cyclic channel (CreateSession, CloseSession, BaseCyclic.Refresh, RefreshFeedback).
    ///
    /// Up to 8 sessions at once, one per connection: the bridge's, and observing ones beside
    /// it (read-only calls only: their connection timeout and CloseSession leave the arm
    /// alone). A session that made any other call controls: its connection inactivity timeout
    /// stops the motion it started.
    ///
    /// Not served (an error frame naming the function): everything else, among them
    /// notifications (OnNotification...Topic), actions and trajectories, Cartesian and twist
    /// commands, poses, DeviceManager.ReadAllDevices, actuator and interconnect configuration,
    /// user profiles, and bypass servoing.
    FakeKortex(cmd::nodes::FakeKortexArgs),
    /// Generate demonstrations as CSV trajectories.
    Demos(cmd::learn::DemosArgs),
    /// Draw the TCP paths of demonstrations (top and side view) to a PNG.
    Plot(cmd::learn::PlotArgs),
    /// Fit a model on demonstrations and write a model file (with, for networks, a loss log
    /// `<out>.loss.csv` and loss curves `<out>.loss.png` next to it).
    Train(Box<cmd::learn::TrainArgs>),
    /// Build a model file from network weights trained elsewhere (the SCL authors' JSON
    /// layout `{"linear_1": [W, b], ...}`, W shaped (in, out)).
    Import(cmd::learn::ImportArgs),
    /// Evaluate model files offline.
    Eval {
        #[command(subcommand)]
        what: cmd::learn::EvalCmd,
    },
}

fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_env("SCL_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .without_time()
        .init();
}

fn run(cli: Cli) -> Result<ExitCode, SclError> {
    // The doctor reports a bad configuration as one of its findings.
    if let Cmd::Doctor(args) = &cli.cmd {
        let code = scl::doctor::run(cli.config.as_deref(), args)?;
        return Ok(ExitCode::from(code as u8));
    }
    let mut cfg = GraphConfig::load(cli.config.as_deref())?;
    if let Some(p) = &cli.prefix {
        cfg.graph.prefix = p.clone();
    }
    let prefix = Prefix::new(&cfg.graph.prefix).map_err(|e| scl_config::ConfigError::Value {
        key: "prefix".into(),
        reason: e.to_string(),
    })?;
    let period_s = cfg.period_s();
    match cli.cmd {
        Cmd::Up(args) => cmd::up::run(prefix, cli.config, cfg, args),
        Cmd::Doctor(_) => unreachable!("scl doctor runs before the configuration is loaded"),
        Cmd::Record(args) => Ok(scl_recorder::cli(&prefix, &args)?),
        Cmd::Study { what } => Ok(scl_study::cli(&prefix, cfg.graph.profile()?, &what, &cfg)?),
        Cmd::Live(args) => Ok(scl_live::cli(&prefix, cfg, &args)?),
        Cmd::Dataset(args) => Ok(learning::to_dataset::cli(&args)?),
        Cmd::Replay(args) => Ok(replay::cli(&args)?),
        Cmd::Top(args) => Ok(scl_dashboard::cli(
            &prefix,
            &args,
            cfg.profile()?,
            cfg.safety.scene.box_names(),
        )?),
        Cmd::Swap(args) => cmd::control::swap(&prefix, args),
        Cmd::Estop => cmd::control::estop(&prefix, &cfg, true),
        Cmd::Reset => cmd::control::estop(&prefix, &cfg, false),
        Cmd::Bench { what } => cmd::bench::run(what, cfg),
        Cmd::Status(args) => cmd::control::status(&prefix, &cfg, args),
        Cmd::Layout => cmd::layout(),
        Cmd::Joystick(args) => cmd::nodes::joystick(&prefix, &mut cfg, &args),
        Cmd::Mapper(args) => cmd::nodes::mapper(&prefix, cfg, args),
        Cmd::Safety => cmd::nodes::safety(&prefix, &cfg),
        Cmd::Bridge(args) => cmd::nodes::bridge(&prefix, cfg, args),
        Cmd::FakeKortex(args) => cmd::nodes::fake_kortex(args),
        Cmd::Demos(args) => cmd::learn::demos(args),
        Cmd::Plot(args) => cmd::learn::plot(args),
        Cmd::Train(t) => cmd::learn::train(&t),
        Cmd::Import(args) => cmd::learn::import(args),
        Cmd::Eval { what } => cmd::learn::eval(what, period_s),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let role = match &cli.cmd {
        Cmd::Up(_) => "up",
        Cmd::Swap(_) => "swap",
        Cmd::Status(_) => "status",
        Cmd::Estop => "estop",
        Cmd::Bench { .. } => "bench",
        Cmd::Reset => "reset",
        Cmd::Layout => "layout",
        Cmd::Joystick(_) => "joystick",
        Cmd::Mapper(_) => "mapper",
        Cmd::Safety => "safety",
        Cmd::Bridge(_) => "bridge",
        Cmd::FakeKortex(_) => "fake-kortex",
        Cmd::Demos(_) => "demos",
        Cmd::Plot(_) => "plot",
        Cmd::Record(_) => "record",
        Cmd::Study { .. } => "study",
        Cmd::Live(_) => "live",
        Cmd::Dataset(_) => "dataset",
        Cmd::Replay(_) => "replay",
        Cmd::Top(_) => "top",
        Cmd::Doctor(_) => "doctor",
        Cmd::Train(_) => "train",
        Cmd::Import(_) => "import",
        Cmd::Eval { .. } => "eval",
    };
    init_logging();
    let span = tracing::info_span!("scl", role);
    let _guard = span.enter();
    signals::install();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("scl {role}: error: {e}");
            ExitCode::from(2)
        }
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use learning::train::TrainConfig;
    use mapper::model::ModelKind;

    /// `scl train` with nothing but the kind, the data and the output trains the paper's
    /// models: the same settings as the library's defaults.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn train_defaults_are_the_papers() {
        let args = |extra: &[&str]| {
            let mut argv = vec!["scl", "train", "--data", "d", "--out", "m.safetensors"];
            argv.extend_from_slice(extra);
            let Cmd::Train(t) = Cli::try_parse_from(argv).unwrap().cmd else {
                panic!("not train")
            };
            t
        };
        assert_eq!(
            args(&["--kind", "scl"]).config(ModelKind::Scl).unwrap(),
            TrainConfig::default()
        );
        assert_eq!(
            args(&["--kind", "cae"]).config(ModelKind::Cae).unwrap(),
            TrainConfig::cae()
        );
        // The Li et al. terms at the paper's settings: γ = 2, α in [0.1, 1], one control
        // period for the reversibility step, weight 1.
        let li = args(&[
            "--kind",
            "cae",
            "--li-losses",
            "consistency,proportionality,reversibility",
        ])
        .config(ModelKind::Cae)
        .unwrap()
        .li
        .unwrap();
        assert_eq!(li.consistency_gamma, Some(2.0));
        assert_eq!(li.proportionality_alpha, Some([0.1, 1.0]));
        assert!(li.reversibility);
        assert_eq!((li.weight, li.step_s), (1.0, 0.025));
        // The ablations are one flag each.
        let c = args(&["--no-gram-schmidt", "--no-lipschitz"])
            .config(ModelKind::Scl)
            .unwrap();
        assert!(!c.gram_schmidt && c.lipschitz.is_none());
        assert!(
            args(&["--li-alpha", "0.5", "--li-losses", "proportionality"])
                .config(ModelKind::Cae)
                .is_err()
        );
    }

    #[test]
    fn cli_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn kortex_credentials_never_show_in_debug_output() {
        let cli = Cli::try_parse_from([
            "scl",
            "bridge",
            "--robot",
            "kortex",
            "--user",
            "dbg-user-x",
            "--password",
            "dbg-pass-y",
        ])
        .unwrap();
        let text = format!("{cli:?}");
        assert!(text.contains("kortex"), "{text}");
        assert!(
            !text.contains("dbg-user-x") && !text.contains("dbg-pass-y"),
            "{text}"
        );
        let Cmd::Bridge(bridge) = cli.cmd else {
            panic!("not the bridge")
        };
        assert_eq!(bridge.password.unwrap().into_inner(), "dbg-pass-y");
    }
}
