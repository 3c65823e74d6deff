//! `scl`: the SCL teleoperation stack in one command. See `scl --help`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use ipc_types::Prefix;
use scl::SclError;
use scl_config::GraphConfig;
use transport::signals;

mod cmd;

/// Teleoperate a 6- or 7-joint arm (Kinova Gen3 lite, Gen3) with a 2-axis joystick through a
/// learned action map.
///
/// The graph is four processes talking through iceoryx2 shared memory: joystick -> mapper ->
/// safety -> bridge, with the bridge as the only clock (`[graph] rate_hz`, 40 Hz by default,
/// up to 1000). `scl up` runs all four on the mock arm of `[graph] robot` (the Gen3 lite by
/// default) with a scripted joystick and the profile's bundled model.
#[derive(Parser, Debug)]
#[command(name = "scl", version, propagate_version = true)]
struct Cli {
    /// `--prefix` before the command (`scl --prefix lab status`), as earlier versions took it;
    /// hidden, since the commands that use it list it. Refused with an offline command.
    #[arg(long, hide = true, value_name = "PREFIX")]
    prefix: Option<String>,
    /// `--config` before the command, as earlier versions took it (see `prefix`).
    #[arg(long, hide = true, value_name = "FILE")]
    config: Option<PathBuf>,
    #[command(subcommand)]
    cmd: Cmd,
}

impl Cmd {
    /// The command's graph options, if it has them.
    fn graph_args(&mut self) -> Option<&mut GraphArgs> {
        match self {
            Cmd::Up { graph, .. }
            | Cmd::Record { graph, .. }
            | Cmd::Study { graph, .. }
            | Cmd::Live { graph, .. }
            | Cmd::Top { graph, .. }
            | Cmd::Swap { graph, .. }
            | Cmd::Estop { graph }
            | Cmd::Reset { graph }
            | Cmd::Status { graph, .. }
            | Cmd::Joystick { graph, .. }
            | Cmd::Mapper { graph, .. }
            | Cmd::Safety { graph }
            | Cmd::Bridge { graph, .. }
            | Cmd::Gateway { graph } => Some(graph),
            _ => None,
        }
    }

    /// The command's `--config`, if it takes one.
    fn config_args(&mut self) -> Option<&mut ConfigArgs> {
        match self {
            Cmd::Bench { config, .. }
            | Cmd::Doctor { config, .. }
            | Cmd::Eval { config, .. }
            | Cmd::Drill { config, .. } => Some(config),
            other => other.graph_args().map(|g| &mut g.config),
        }
    }

    /// Takes `--prefix` and `--config` given before the command name; the command's own
    /// options win. An option the command does not take is an error naming it.
    fn take_early(
        &mut self,
        prefix: Option<String>,
        config: Option<PathBuf>,
        name: &str,
    ) -> Result<(), SclError> {
        let refuse =
            |opt: &str| SclError::Other(format!("`{opt}` is not an option of `scl {name}`"));
        if let Some(p) = prefix {
            let g = self.graph_args().ok_or_else(|| refuse("--prefix"))?;
            g.prefix.get_or_insert(p);
        }
        if let Some(c) = config {
            let a = self.config_args().ok_or_else(|| refuse("--config"))?;
            a.config.get_or_insert(c);
        }
        Ok(())
    }
}

/// Where a command finds its graph: the options of every command that starts, joins or
/// talks to a graph (and of nothing else).
#[derive(clap::Args, Debug, Clone, Default)]
struct GraphArgs {
    /// Graph prefix: isolates this graph's services and shared memory from every other graph
    /// (else the SCL_PREFIX environment variable, else the config's `[graph] prefix`, `scl`).
    #[arg(long, global = true)]
    prefix: Option<String>,
    #[command(flatten)]
    config: ConfigArgs,
}

/// The graph configuration, for the commands that read it but join no graph of a prefix
/// given to them (`doctor`, `bench`, `eval`).
#[derive(clap::Args, Debug, Clone, Default)]
struct ConfigArgs {
    /// Graph configuration (TOML); every key is optional, see examples/graph.toml.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,
}

impl ConfigArgs {
    fn load(&self) -> Result<GraphConfig, SclError> {
        Ok(GraphConfig::load(self.config.as_deref())?)
    }
}

impl GraphArgs {
    /// The graph's prefix and configuration: the file's, with `--prefix` (or `SCL_PREFIX`)
    /// over its `[graph] prefix`.
    fn load(&self) -> Result<(Prefix, GraphConfig), SclError> {
        let mut cfg = self.config.load()?;
        // The flag, else the environment (read here, not by clap, so that a `--prefix` given
        // before the command name still wins over the environment).
        if let Some(p) = self
            .prefix
            .clone()
            .or_else(|| std::env::var(ipc_types::prefix::PREFIX_ENV).ok())
        {
            cfg.graph.prefix = p;
        }
        let prefix =
            Prefix::new(&cfg.graph.prefix).map_err(|e| scl_config::ConfigError::Value {
                key: "prefix".into(),
                reason: e.to_string(),
            })?;
        Ok((prefix, cfg))
    }
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run the whole graph: joystick, mapper, safety and bridge as supervised children.
    Up {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: cmd::up::UpArgs,
    },
    /// Record every message of a running graph to an MCAP file (read-only; Foxglove opens
    /// it), until Ctrl-C. `--recover` repairs a recording cut by a crash.
    Record {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: scl_recorder::RecordArgs,
    },
    /// User studies as the paper ran them: `run` walks a participant through a study file on
    /// the live graph, `report` draws the figures and runs the tests, `plan` prints the
    /// counterbalanced orders, `simulate` runs simulated participants on the mock arm.
    Study {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(subcommand)]
        what: scl_study::StudyCmd,
    },
    /// Serve a running graph to Foxglove over its WebSocket protocol (read-only): the
    /// recording's topics plus the 3D view (/tf, the arm's capsules coloured by clearance, the
    /// map's two directions at the tool, /scl/tick), until Ctrl-C. Open Foxglove, "Open
    /// connection", Foxglove WebSocket, ws://127.0.0.1:8765, and load docs/foxglove-layout.json.
    Live {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: scl_live::LiveArgs,
    },
    /// Turn recordings into a training data set (CSV trajectories in train/ and val/).
    Dataset(learning::to_dataset::DatasetArgs),
    /// Re-execute a recording tick by tick (the mapper's and safety's steps on the recorded
    /// states, joystick samples and control events) and compare every command bit for bit;
    /// exits 1 on a divergence, naming its tick. `--tick K --explain` spells one tick out.
    Replay(replay::ReplayArgs),
    /// A terminal dashboard of a running graph (works over SSH in 80x24).
    Top {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: scl_dashboard::TopArgs,
    },
    /// Swap the running graph's mapper for one serving MODEL, without missing a tick.
    ///
    /// The supervisor starts a new mapper process beside the old one, waits until it has
    /// produced valid commands for `swap_valid_ticks` consecutive ticks, has safety switch to
    /// it at a tick boundary, then stops the old one. A model that does not load is refused
    /// and the old mapper keeps running. The reply counts the ticks the bridge missed
    /// meanwhile and how many of them the machine took (held up, as `scl up --json` counts
    /// `held_up`): without real-time scheduling, a loaded machine can hold the graph up
    /// during a swap, whose start-up work competes with it.
    Swap {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: cmd::control::SwapArgs,
    },
    /// Latch the running graph's e-stop: safety commands zero at once and keeps doing so
    /// until `scl reset`.
    Estop {
        #[command(flatten)]
        graph: GraphArgs,
    },
    /// Release a latched e-stop.
    Reset {
        #[command(flatten)]
        graph: GraphArgs,
    },
    /// Benchmarks (each runs its own graphs, under prefixes of its own).
    Bench {
        #[command(flatten)]
        config: ConfigArgs,
        #[command(subcommand)]
        what: cmd::bench::BenchCmd,
    },
    /// Is this machine ready to drive the arm? Checks real-time rights, the kernel, CPU power
    /// settings, shared memory and leftovers, joysticks, the configuration (`--config`), its
    /// model and, with `[bridge] robot = "kortex"`, the arm itself through a read-only session.
    /// Prints ok / warn / fail with what to do; exit code 1 on any fail.
    Doctor {
        #[command(flatten)]
        config: ConfigArgs,
        #[command(flatten)]
        args: scl::doctor::DoctorArgs,
    },
    /// Run the fault drills on this machine with this configuration: the graph (the mock arm
    /// unless `--arm`) records itself while a scripted stick keeps the arm moving, and each
    /// fault in turn (kill -9 or SIGSTOP of each process, stale, non-finite and out-of-range
    /// input, the e-stop with and without a mapper, live swaps; with `[network]` on, the
    /// gateway's kill -9 and, with `accept_joystick`, a remote operator's link cut) is measured
    /// from the recording against the documented promise: ticks to the stop, travel and time
    /// to rest, no speed-up, motion only after neutral input, actions within the stick's disc,
    /// missed ticks, shared memory left. Prints one PASS / FAIL row per drill; exit code 1 on
    /// any FAIL. See docs/safety-drills.md.
    Drill {
        #[command(flatten)]
        config: ConfigArgs,
        #[command(flatten)]
        args: scl_drill::DrillArgs,
    },
    /// Show the running graph: nodes, pids, liveness, active mapper, counters.
    Status {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: cmd::control::StatusArgs,
    },
    /// Print the messages' memory layout as JSON (size, alignment, every field's offset and
    /// type, iceoryx2 type names, topic settings, bit names): what a binding in another
    /// language must match; the Python package's drift test compares itself with it.
    Layout,
    /// The joystick process: a script, a joystick or gamepad (evdev), the keyboard, or a
    /// recorded input file; `--list` shows the input devices attached.
    Joystick {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: scl_joystick::JoystickArgs,
    },
    /// A mapper process serving one model.
    Mapper {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: cmd::nodes::MapperArgs,
    },
    /// The safety process (the one publisher of the executed command).
    Safety {
        #[command(flatten)]
        graph: GraphArgs,
    },
    /// The network gateway (`scl up` starts it when `[network] enabled`): the graph's topics
    /// out to other machines through Zenoh for remote observers, and with `[network]
    /// accept_joystick` a remote operator's joystick in (`scl joystick --remote`),
    /// authenticated, its link watched: a lost link or stale input stops the arm. See
    /// docs/network.md.
    Gateway {
        #[command(flatten)]
        graph: GraphArgs,
    },
    /// The hardware bridge: the robot and the graph's clock.
    Bridge {
        #[command(flatten)]
        graph: GraphArgs,
        #[command(flatten)]
        args: cmd::nodes::BridgeArgs,
    },
    /// A fake Kinova arm speaking the Kortex protocol on 127.0.0.1 (user admin, password
    /// admin), for trying `bridge --robot kortex` without an arm: the Gen3 lite, or the arm of
    /// the robot profile `--robot` names (`gen3`: the 7-joint Gen3).
    ///
    /// Serves over TCP: Session.CreateSession, CloseSession, KeepAlive; Base.Stop,
    /// ApplyEmergencyStop, ClearFaults, SetServoingMode (single-level, low-level),
    /// GetServoingMode, GetActuatorCount, GetArmState, GetMeasuredJointAngles,
    /// SendJointSpeedsCommand, SendGripperCommand (position, finger 1), GetProductConfiguration
    /// (the arm's Kortex model and degrees of freedom); BaseCyclic.RefreshFeedback;
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
    /// Evaluate model files offline (the control period comes from the configuration's
    /// `[graph] rate_hz`).
    Eval {
        #[command(flatten)]
        config: ConfigArgs,
        #[command(subcommand)]
        what: cmd::learn::EvalCmd,
    },
}

fn init_logging() {
    use tracing_subscriber::Layer as _;
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    // Zenoh's own records (its session ids, its endpoints) only from warnings up, unless
    // SCL_LOG asks for them.
    let filter = tracing_subscriber::EnvFilter::try_from_env("SCL_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn"));
    let stderr = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .without_time()
        .with_filter(filter);
    // INFO and above also go to the graph's `log` topic once the process has joined a graph
    // (`node_rt::log::publish`), whatever SCL_LOG shows on stderr.
    let graph =
        node_rt::log::GraphLogLayer.with_filter(tracing_subscriber::filter::LevelFilter::INFO);
    tracing_subscriber::registry()
        .with(stderr)
        .with(graph)
        .init();
}

/// Publishes this process's log records on graph `prefix`'s `log` topic as `process` until
/// the returned guard drops (`node_rt::log`).
fn graph_log(prefix: &Prefix, process: &str) -> Option<node_rt::log::LogPublisher> {
    node_rt::log::publish(prefix, process)
}

fn run(cli: Cli, role: &str) -> Result<ExitCode, SclError> {
    let Cli {
        prefix,
        config,
        mut cmd,
    } = cli;
    cmd.take_early(prefix, config, role)?;
    match cmd {
        Cmd::Up { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            let _log = graph_log(&prefix, "supervisor");
            cmd::up::run(prefix, graph.config.config, cfg, args)
        }
        // The doctor reports a bad configuration as one of its findings.
        Cmd::Doctor { config, args } => {
            let code = scl::doctor::run(config.config.as_deref(), &args)?;
            Ok(ExitCode::from(code as u8))
        }
        Cmd::Record { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            // Recording this machine's graph, not repairing or converting a file, nor
            // recording a remote graph (whose shared memory is not here).
            let live = args.recover.is_none() && args.convert.is_none() && args.remote.is_none();
            let _log = live.then(|| graph_log(&prefix, "recorder"));
            Ok(scl_recorder::cli(&prefix, &args, &cfg.network)?)
        }
        Cmd::Study { graph, what } => {
            let (prefix, cfg) = graph.load()?;
            Ok(scl_study::cli(&prefix, cfg.graph.profile()?, &what, &cfg)?)
        }
        Cmd::Live { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            Ok(scl_live::cli(&prefix, cfg, &args)?)
        }
        Cmd::Dataset(args) => Ok(learning::to_dataset::cli(&args)?),
        Cmd::Replay(args) => Ok(replay::cli(&args)?),
        Cmd::Top { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            Ok(scl_dashboard::cli(
                &prefix,
                &args,
                &cfg.network,
                cfg.profile()?,
                cfg.safety.scene.box_names(),
            )?)
        }
        Cmd::Swap { graph, args } => cmd::control::swap(&graph.load()?.0, args),
        Cmd::Estop { graph } => {
            let (prefix, cfg) = graph.load()?;
            cmd::control::estop(&prefix, &cfg, true)
        }
        Cmd::Reset { graph } => {
            let (prefix, cfg) = graph.load()?;
            cmd::control::estop(&prefix, &cfg, false)
        }
        Cmd::Bench { config, what } => cmd::bench::run(what, config.load()?),
        Cmd::Status { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            cmd::control::status(&prefix, &cfg, args)
        }
        Cmd::Layout => cmd::layout(),
        Cmd::Joystick { graph, args } => {
            let (prefix, mut cfg) = graph.load()?;
            // A remote operator is on another machine than the graph: no log topic there.
            let _log =
                (!args.list && args.remote.is_none()).then(|| graph_log(&prefix, "joystick"));
            cmd::nodes::joystick(&prefix, &mut cfg, &args)
        }
        Cmd::Mapper { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            let id = args.id.unwrap_or(cfg.mapper.id);
            let _log = graph_log(&prefix, &format!("mapper-{id}"));
            cmd::nodes::mapper(&prefix, cfg, args)
        }
        Cmd::Safety { graph } => {
            let (prefix, cfg) = graph.load()?;
            let _log = graph_log(&prefix, "safety");
            cmd::nodes::safety(&prefix, &cfg)
        }
        Cmd::Bridge { graph, args } => {
            let (prefix, cfg) = graph.load()?;
            let _log = graph_log(&prefix, "bridge");
            cmd::nodes::bridge(&prefix, cfg, args)
        }
        Cmd::Gateway { graph } => {
            let (prefix, cfg) = graph.load()?;
            let _log = graph_log(&prefix, "gateway");
            cmd::nodes::gateway(&prefix, &cfg)
        }
        Cmd::Drill { config, args } => {
            let cfg = config.load()?;
            let report = scl_drill::run(config.config.as_deref(), &cfg, &args)?;
            if args.json {
                let text = serde_json::to_string(&report).map_err(|source| SclError::Encode {
                    what: "drill report",
                    source,
                })?;
                println!("{text}");
            } else {
                print!("{}", scl_drill::render(&report));
            }
            Ok(if report.passed {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            })
        }
        Cmd::FakeKortex(args) => cmd::nodes::fake_kortex(args),
        Cmd::Demos(args) => cmd::learn::demos(args),
        Cmd::Plot(args) => cmd::learn::plot(args),
        Cmd::Train(t) => cmd::learn::train(&t),
        Cmd::Import(args) => cmd::learn::import(args),
        Cmd::Eval { config, what } => cmd::learn::eval(what, &config.load()?),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let role = match &cli.cmd {
        Cmd::Up { .. } => "up",
        Cmd::Swap { .. } => "swap",
        Cmd::Status { .. } => "status",
        Cmd::Estop { .. } => "estop",
        Cmd::Bench { .. } => "bench",
        Cmd::Reset { .. } => "reset",
        Cmd::Layout => "layout",
        Cmd::Joystick { .. } => "joystick",
        Cmd::Mapper { .. } => "mapper",
        Cmd::Safety { .. } => "safety",
        Cmd::Bridge { .. } => "bridge",
        Cmd::Gateway { .. } => "gateway",
        Cmd::FakeKortex(_) => "fake-kortex",
        Cmd::Demos(_) => "demos",
        Cmd::Plot(_) => "plot",
        Cmd::Record { .. } => "record",
        Cmd::Study { .. } => "study",
        Cmd::Live { .. } => "live",
        Cmd::Dataset(_) => "dataset",
        Cmd::Replay(_) => "replay",
        Cmd::Top { .. } => "top",
        Cmd::Doctor { .. } => "doctor",
        Cmd::Drill { .. } => "drill",
        Cmd::Train(_) => "train",
        Cmd::Import(_) => "import",
        Cmd::Eval { .. } => "eval",
    };
    init_logging();
    let span = tracing::info_span!("scl", role);
    let _guard = span.enter();
    signals::install();
    match run(cli, role) {
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

    /// `scl fake-kortex --robot`: the default profile when absent, a profile by the name
    /// `[graph] robot` takes, and an unknown name refused naming the flag and the known ones.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn fake_kortex_takes_a_robot_profile_by_name() {
        let robot = |extra: &[&str]| {
            let mut argv = vec!["scl", "fake-kortex"];
            argv.extend_from_slice(extra);
            Cli::try_parse_from(argv).map(|c| match c.cmd {
                Cmd::FakeKortex(a) => a.robot.name().to_owned(),
                _ => panic!("not fake-kortex"),
            })
        };
        let default = kinematics::RobotProfile::default_name();
        assert_eq!(robot(&[]).unwrap(), default);
        for name in kinematics::RobotProfile::names() {
            assert_eq!(robot(&["--robot", name]).unwrap(), name);
        }
        let e = robot(&["--robot", "ur5"]).unwrap_err().to_string();
        assert!(
            e.contains("--robot") && e.contains("`ur5` is not a known robot"),
            "{e}"
        );
        for name in kinematics::RobotProfile::names() {
            assert!(e.contains(name), "{e}");
        }
    }

    /// `scl demos --robot` and `scl eval reconstruction|reversibility --robot` take a profile
    /// by name (the default profile when absent); an unknown one is refused naming the flag.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn demos_and_eval_take_a_robot_profile_by_name() {
        let demos = |extra: &[&str]| {
            let mut argv = vec!["scl", "demos", "--task", "pouring", "--out", "d"];
            argv.extend_from_slice(extra);
            Cli::try_parse_from(argv).map(|c| match c.cmd {
                Cmd::Demos(a) => a.robot.name().to_owned(),
                _ => panic!("not demos"),
            })
        };
        assert_eq!(
            demos(&[]).unwrap(),
            kinematics::RobotProfile::default_name()
        );
        assert_eq!(demos(&["--robot", "gen3"]).unwrap(), "gen3");
        let e = demos(&["--robot", "ur5"]).unwrap_err().to_string();
        assert!(
            e.contains("--robot") && e.contains("`ur5` is not a known robot"),
            "{e}"
        );
        for eval in ["reconstruction", "reversibility"] {
            let c = Cli::try_parse_from(["scl", "eval", eval, "--out", "o", "--robot", "gen3"])
                .unwrap();
            let robot = match c.cmd {
                Cmd::Eval {
                    what: cmd::learn::EvalCmd::Reconstruction(a),
                    ..
                } => a.common.robot,
                Cmd::Eval {
                    what: cmd::learn::EvalCmd::Reversibility(a),
                    ..
                } => a.common.robot,
                _ => panic!("not eval {eval}"),
            };
            assert_eq!(robot.name(), "gen3");
        }
    }

    /// `scl train` checks a model on the paper's task its data directory is named after, or
    /// the one `--check-task` names; none with `--no-check` or for other data.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn train_checks_the_task_its_data_is_named_after() {
        use learning::tasks::Task;
        let task = |argv: &[&str]| {
            let mut all = vec!["scl", "train", "--out", "m.safetensors"];
            all.extend_from_slice(argv);
            let Cmd::Train(t) = Cli::try_parse_from(all).unwrap().cmd else {
                panic!("not train")
            };
            t.check_task()
        };
        assert_eq!(
            task(&["--data", "data/study/pick-and-place"]).unwrap(),
            Some(Task::PickAndPlace)
        );
        assert_eq!(task(&["--data", "data/joint-reach"]).unwrap(), None);
        assert_eq!(
            task(&["--data", "demos", "--check-task", "pouring"]).unwrap(),
            Some(Task::Pouring)
        );
        assert_eq!(
            task(&["--data", "data/pouring", "--no-check"]).unwrap(),
            None
        );
        let e = task(&["--data", "d", "--check-task", "planar-reach"]).unwrap_err();
        assert!(e.to_string().contains("--check-task planar-reach"), "{e}");
        assert!(
            Cli::try_parse_from([
                "scl",
                "train",
                "--data",
                "d",
                "--out",
                "m",
                "--check-task",
                "pouring",
                "--no-check"
            ])
            .is_err()
        );
    }

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

    /// `--prefix` and `--config` appear on the commands that use them and on no other:
    /// every subcommand is in exactly one of the three lists.
    #[test]
    fn prefix_and_config_only_where_they_are_used() {
        use clap::CommandFactory;
        const GRAPH: [&str; 14] = [
            "up", "record", "study", "live", "top", "swap", "estop", "reset", "status", "joystick",
            "mapper", "safety", "bridge", "gateway",
        ];
        const CONFIG_ONLY: [&str; 4] = ["bench", "doctor", "eval", "drill"];
        const OFFLINE: [&str; 8] = [
            "dataset",
            "replay",
            "layout",
            "fake-kortex",
            "demos",
            "plot",
            "train",
            "import",
        ];
        let mut cli = Cli::command();
        cli.build();
        // Hidden ones (before the command name, as earlier versions took them) do not count.
        let has = |c: &clap::Command, id: &str| {
            c.get_arguments()
                .any(|a| a.get_id() == id && !a.is_hide_set())
        };
        assert!(!has(&cli, "prefix") && !has(&cli, "config"));
        for sub in cli.get_subcommands().filter(|c| c.get_name() != "help") {
            let name = sub.get_name();
            let want = if GRAPH.contains(&name) {
                (true, true)
            } else if CONFIG_ONLY.contains(&name) {
                (false, true)
            } else {
                assert!(OFFLINE.contains(&name), "`scl {name}` is in no list");
                (false, false)
            };
            // The command and each of its own subcommands (`scl study run --prefix x`).
            let own = sub.get_subcommands().filter(|c| c.get_name() != "help");
            for c in std::iter::once(sub).chain(own) {
                assert_eq!(
                    (has(c, "prefix"), has(c, "config")),
                    want,
                    "`scl {name}` ({}): (--prefix, --config)",
                    c.get_name()
                );
            }
        }
    }

    /// `scl up --script` lists exactly the scripts the joystick's parser takes (one type,
    /// `ScriptName`, is both the possible values and the parser).
    #[test]
    #[allow(clippy::unwrap_used)]
    fn up_script_help_lists_every_script_the_joystick_takes() {
        use clap::CommandFactory;
        let cli = Cli::command();
        let up = cli.find_subcommand("up").unwrap();
        let script = up.get_arguments().find(|a| a.get_id() == "script").unwrap();
        let listed: Vec<String> = script
            .get_possible_values()
            .iter()
            .map(|v| v.get_name().to_owned())
            .collect();
        assert_eq!(listed, scl_joystick::script::ScriptName::names());
        let mut j = scl_config::JoystickConfig::default();
        for name in &listed {
            j.script = name.clone();
            assert!(
                scl_joystick::script::Script::from_config(&j).is_some(),
                "{name}"
            );
            assert!(
                Cli::try_parse_from(["scl", "up", "--script", name]).is_ok(),
                "{name}"
            );
        }
        assert!(Cli::try_parse_from(["scl", "up", "--script", "sine"]).is_err());
        // And `--model`'s help names the model specs that are not files.
        let model = up.get_arguments().find(|a| a.get_id() == "model").unwrap();
        let help = model.get_help().unwrap().to_string();
        for spec in ["bundled", "modeswitch", "constant:", "goto:"] {
            assert!(help.contains(spec), "--model help lacks {spec}: {help}");
        }
    }

    /// A hand-off of no room and a `--meta` without `=` are refused while parsing, naming the
    /// flag and the value; a pair splits at the first `=`.
    #[test]
    fn record_and_live_arguments_are_checked_while_parsing() {
        for argv in [
            &["scl", "record", "--out", "x.mcap", "--queue", "0"][..],
            &["scl", "live", "--queue", "0"][..],
            &["scl", "record", "--out", "x.mcap", "--meta", "participant"][..],
        ] {
            let e = Cli::try_parse_from(argv).expect_err("refused").to_string();
            assert!(e.contains(argv[argv.len() - 2]), "{e}");
        }
        let cli = Cli::try_parse_from(["scl", "record", "--out", "x.mcap", "--meta", " p = a=b"])
            .expect("a pair");
        let Cmd::Record { args, .. } = cli.cmd else {
            panic!("not record")
        };
        assert_eq!(args.meta, [("p".to_owned(), " a=b".to_owned())]);
    }

    /// The graph commands take `--prefix` before or after their own options, and
    /// `SCL_PREFIX` as before; an offline command refuses `--prefix`.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn prefix_goes_with_the_graph_commands() {
        let cli = Cli::try_parse_from(["scl", "status", "--prefix", "lab"]).unwrap();
        let Cmd::Status { graph, .. } = cli.cmd else {
            panic!("not status")
        };
        assert_eq!(graph.prefix.as_deref(), Some("lab"));
        assert!(Cli::try_parse_from(["scl", "train", "--prefix", "lab"]).is_err());
        // Before the command name, as earlier versions took them: given to the command; its
        // own option wins; an offline command refuses them.
        let early = |argv: &[&str]| {
            let cli = Cli::try_parse_from(argv).unwrap();
            let mut cmd = cli.cmd;
            cmd.take_early(cli.prefix, cli.config, "x").map(|()| cmd)
        };
        let Ok(Cmd::Status { graph, .. }) = early(&["scl", "--prefix", "lab", "status"]) else {
            panic!("not status")
        };
        assert_eq!(graph.prefix.as_deref(), Some("lab"));
        let Ok(Cmd::Up { graph, .. }) = early(&["scl", "--prefix", "a", "up", "--prefix", "b"])
        else {
            panic!("not up")
        };
        assert_eq!(graph.prefix.as_deref(), Some("b"));
        let Ok(Cmd::Bench { config, .. }) = early(&[
            "scl", "--config", "f.toml", "bench", "latency", "--for", "1s",
        ]) else {
            panic!("not bench")
        };
        assert_eq!(
            config.config.as_deref(),
            Some(std::path::Path::new("f.toml"))
        );
        let e = early(&["scl", "--prefix", "lab", "layout"]).err().unwrap();
        assert!(e.to_string().contains("`--prefix` is not an option"), "{e}");
        assert!(
            early(&[
                "scl", "--config", "f.toml", "train", "--data", "d", "--out", "m"
            ])
            .is_err()
        );
    }

    /// A negative duration reaches the duration parser, which refuses it as negative (not
    /// clap's "unexpected argument '-5'").
    #[test]
    fn a_negative_duration_is_refused_as_negative() {
        for argv in [
            &["scl", "up", "--for", "-5s"][..],
            &["scl", "bench", "latency", "--for", "-5s"][..],
        ] {
            let e = Cli::try_parse_from(argv).expect_err("refused").to_string();
            assert!(e.contains("`-5s` is negative"), "{e}");
        }
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
        let Cmd::Bridge { args: bridge, .. } = cli.cmd else {
            panic!("not the bridge")
        };
        assert_eq!(bridge.password.unwrap().into_inner(), "dbg-pass-y");
    }
}
