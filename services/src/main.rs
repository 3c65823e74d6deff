//! `scl`: the SCL teleoperation stack in one command. See `scl --help`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use ipc_types::Prefix;
use ipc_types::signals;
use learning::train::TrainConfig;
use mapper::model::ModelKind;
use scl_node::config::GraphConfig;
use services::SclError;

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
    Up {
        /// Stop after this long (e.g. `60s`, `2m`, `500ms`); default: until Ctrl-C.
        #[arg(long = "for", value_name = "DURATION", value_parser = parse_duration)]
        duration: Option<Duration>,
        /// Print one JSON summary object on stdout at the end. Its `joint_travel_rad` is the
        /// arm's joint-space path length: the Euclidean norm of each tick's change of the
        /// joint angles, summed (not the sum of every joint's absolute change).
        #[arg(long)]
        json: bool,
        /// Serve this model file (or `bundled`, `modeswitch[:key=value,...]` for Cartesian
        /// mode switching, or the drill map `constant:qdot=v1,...,v6`: that joint velocity in
        /// rad/s whenever safety lets it, whatever the stick, each within the URDF's limits)
        /// instead of the config's.
        #[arg(long, value_name = "FILE")]
        model: Option<String>,
        /// Joystick script instead of the config's: `circle` or `step`.
        #[arg(long)]
        script: Option<String>,
        /// Joystick source instead of the config's: `script`, `evdev`, `keyboard`, `replay`,
        /// or `external` (no joystick process: the input comes from whoever publishes it on
        /// the graph's joystick topic, e.g. a Python agent).
        #[arg(long, value_name = "SOURCE")]
        joystick: Option<String>,
        /// Record every message of the graph to this MCAP file (a supervised `scl record`,
        /// started before the bridge and stopped last).
        #[arg(long, value_name = "FILE")]
        record: Option<PathBuf>,
        /// Serve the graph to Foxglove while it runs (a `scl live` child, started before the
        /// bridge): connect Foxglove to ws://ADDR:PORT (default 127.0.0.1:8765, loopback
        /// only; any other address is reachable from that network and a warning says so).
        #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1, default_missing_value = scl_live::DEFAULT_LISTEN)]
        live: Option<String>,
    },
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
    Swap {
        /// Model file, `bundled`, `modeswitch[:key=value,...]`, the drill map
        /// `constant:qdot=v1,...,v6` (rad/s, whatever the stick), or the go-to map
        /// `goto:pose=home` / `goto:q=v1,...,v6[;speed=S]` (drives to the pose while the
        /// deadman is held: a "go home" button).
        model: String,
        /// How long to wait for the switch-over.
        #[arg(long, default_value = "30s", value_parser = parse_duration)]
        timeout: Duration,
    },
    /// Latch the running graph's e-stop: safety commands zero at once and keeps doing so
    /// until `scl reset`.
    Estop,
    /// Release a latched e-stop.
    Reset,
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchCmd,
    },
    /// Is this machine ready to drive the arm? Checks real-time rights, the kernel, CPU power
    /// settings, shared memory and leftovers, joysticks, the configuration (`--config`), its
    /// model and, with `[bridge] robot = "kortex"`, the arm itself through a read-only session.
    /// Prints ok / warn / fail with what to do; exit code 1 on any fail.
    Doctor(scl_doctor::DoctorArgs),
    /// Show the running graph: nodes, pids, liveness, active mapper, counters.
    Status {
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Print the messages' memory layout as JSON (size, alignment, every field's offset and
    /// type, iceoryx2 type names, topic settings, bit names): what a binding in another
    /// language must match; the Python package's drift test compares itself with it.
    Layout,
    /// The joystick process: a script, a joystick or gamepad (evdev), the keyboard, or a
    /// recorded input file; `--list` shows the input devices attached.
    Joystick(scl_joystick::JoystickArgs),
    /// A mapper process serving one model.
    Mapper {
        /// Model file, `bundled`, `modeswitch[:key=value,...]` or the drill map
        /// `constant:qdot=v1,...,v6` (rad/s, whatever the stick).
        #[arg(long, value_name = "FILE")]
        model: Option<String>,
        /// Mapper id (safety forwards only the active id).
        #[arg(long)]
        id: Option<u32>,
    },
    /// The safety process (the one publisher of the executed command).
    Safety,
    /// The hardware bridge: the robot and the graph's clock.
    Bridge {
        /// Robot backend: `mock` or `kortex` (a Gen3 lite over the Kortex API).
        #[arg(long)]
        robot: Option<String>,
        /// First tick number (a restarted bridge continues its predecessor's count).
        #[arg(long)]
        start_tick: Option<u64>,
        /// Mock arm: start from these joint angles (rad, comma-separated) instead of the
        /// configured pose.
        #[arg(long, value_name = "Q0,Q1,...", value_delimiter = ',')]
        resume_q: Option<Vec<f64>>,
        /// Mock arm: start with this gripper state (0 open .. 1 closed).
        #[arg(long, default_value_t = 0.0)]
        resume_gripper: f64,
        /// Kortex: the robot's IP address (instead of bridge.kortex.address).
        #[arg(long, value_name = "IP")]
        address: Option<String>,
        /// Kortex: the robot's TCP port (instead of bridge.kortex.port).
        #[arg(long)]
        port: Option<u16>,
        /// Kortex: user name (else bridge.kortex.credentials_file).
        #[arg(long, env = scl_bridge_node::USER_ENV, hide_env_values = true)]
        user: Option<scl_bridge_node::Secret>,
        /// Kortex: password; prefer the environment variable or the credentials file, since a
        /// command line is visible to other users.
        #[arg(long, env = scl_bridge_node::PASSWORD_ENV, hide_env_values = true)]
        password: Option<scl_bridge_node::Secret>,
    },
    /// A fake Gen3 lite speaking the Kortex protocol on 127.0.0.1 (user admin, password
    /// admin), for trying `bridge --robot kortex` without an arm.
    FakeKortex {
        /// TCP port on 127.0.0.1 (0: a free one; the first line on stdout names it); the
        /// low-level cyclic channel listens on UDP with the same number.
        #[arg(long, default_value_t = hw_bridge::kortex::DEFAULT_PORT)]
        port: u16,
        /// For tests of the bridge's low-level entry check: misread the cyclic command as a
        /// robot that reads its layout differently would: `zero` (every position as 0°) or
        /// `offset:JOINT:RAD` (one joint's position off by RAD). The arm then leaves the
        /// position the bridge holds at entry, and the bridge must stop it.
        #[arg(long, value_name = "zero|offset:JOINT:RAD")]
        misread_cyclic: Option<hw_bridge::kortex::CyclicMisread>,
    },
    /// Generate demonstrations as CSV trajectories.
    Demos {
        /// Task: `joint-reach` (joint-space reaches from home, the bundled model's data), the
        /// paper's Gen3 lite tasks `table-cleaning`, `pick-and-place`, `pouring`, or its 5-DOF
        /// `planar-reach`.
        #[arg(long, default_value = "joint-reach")]
        task: String,
        /// Output directory (gets train/ and val/); existing files are never overwritten.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Training trajectories (default: the task's; the paper's 3, 6, 8 for table-cleaning,
        /// pick-and-place, pouring; 40 for planar-reach; 6 for joint-reach).
        #[arg(long = "train")]
        n_train: Option<usize>,
        /// Validation trajectories (default: the task's; 2, or 10 for planar-reach).
        #[arg(long = "val")]
        n_val: Option<usize>,
        /// Also draw the TCP paths to this PNG (as `scl plot` does).
        #[arg(long, value_name = "FILE.png")]
        plot: Option<PathBuf>,
    },
    /// Draw the TCP paths of demonstrations (top and side view) to a PNG.
    Plot {
        /// Data set: a directory (train/*.csv, val/*.csv; *.json too) or one CSV / JSON file.
        #[arg(long, value_name = "DIR")]
        data: PathBuf,
        /// The PNG to write.
        #[arg(long, value_name = "FILE.png")]
        out: PathBuf,
        /// Figure title (default: the data's name and counts).
        #[arg(long)]
        title: Option<String>,
        /// TrueType font for the text (default: a common system font; none: no text).
        #[arg(long, value_name = "FILE.ttf")]
        font: Option<PathBuf>,
        /// Replace an existing PNG.
        #[arg(long)]
        force: bool,
    },
    /// Fit a model on demonstrations and write a model file (with, for networks, a loss log
    /// `<out>.loss.csv` and loss curves `<out>.loss.png` next to it).
    Train(Box<TrainArgs>),
    /// Build a model file from network weights trained elsewhere (the SCL authors' JSON
    /// layout `{"linear_1": [W, b], ...}`, W shaped (in, out)).
    Import {
        /// The JSON weights of the decoder.
        #[arg(long, value_name = "FILE")]
        json: PathBuf,
        /// Model kind: `scl` (decoder outputs m*d, reshaped row-major) or `cae`.
        #[arg(long, default_value = "scl")]
        kind: String,
        /// Joints m.
        #[arg(long, default_value_t = 6)]
        joints: usize,
        /// Action dimension d.
        #[arg(long, default_value_t = 2)]
        latent_dim: usize,
        /// Speed scale s in rad/s the network's output is multiplied by.
        #[arg(long)]
        speed_scale: f64,
        /// Serve H without Gram-Schmidt (scl).
        #[arg(long)]
        no_gram_schmidt: bool,
        /// Input normalisation mean, comma-separated (default: none).
        #[arg(long, value_name = "LIST", requires = "input_std")]
        input_mean: Option<String>,
        /// Input normalisation scale, comma-separated.
        #[arg(long, value_name = "LIST", requires = "input_mean")]
        input_std: Option<String>,
        /// Model file to write.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Overwrite an existing model file.
        #[arg(long)]
        force: bool,
    },
    /// Evaluate model files offline.
    Eval {
        #[command(subcommand)]
        what: EvalCmd,
    },
}

/// `scl eval EXPERIMENT --out DIR`: the paper's experiments (docs/experiments.md).
///
/// Every experiment shares the options of `learning::experiments::CommonArgs` (--out, --seeds,
/// --epochs, --threads, --data, --models, --hidden); each experiment flattens them into its
/// own arguments.
#[derive(Subcommand, Debug)]
enum EvalCmd {
    /// Proportionality and soft reversibility on the mock Gen3 lite (the paper's figure):
    /// a for 1 s, stop, -a for 1 s, 10 models per kind (SCL, CAE, PCA) x 10 start states.
    Reversibility(learning::experiments::reversibility::ReversibilityArgs),
    /// The soft-reversibility inequality over sampled states and actions, for SCL without
    /// Gram-Schmidt (the theorem: must always hold), with Gram-Schmidt, and CAE.
    /// `--models FILE...` checks given files (the former `scl eval reversibility --model`).
    Theorem(learning::experiments::theorem::TheoremArgs),
    /// Validation reconstruction loss of every kind on the three Gen3 lite tasks (with
    /// `--models FILE... --data DIR`: of given files on one data set).
    Reconstruction(learning::experiments::reconstruction::ReconstructionArgs),
    /// The paper's simulated greedy user on the 5-DOF planar reach: SCL with and without
    /// Gram-Schmidt and CAE over the Li et al. loss grid (10 models each, 1000 epochs); the
    /// best of 4096 Gaussian actions per step, to the end state and back to the start of 100
    /// test trajectories; violin plots, Kruskal-Wallis and Dunn's test. Long at the paper's
    /// defaults (hours): resumable, and --seeds / --epochs / --test-trajectories give a quick
    /// look.
    GreedyUser(learning::experiments::greedy_user::GreedyUserArgs),
}

/// `scl train`: every option, with the paper's defaults.
#[derive(clap::Args, Debug)]
struct TrainArgs {
    /// Model kind: `pca`, `scl` or `cae`.
    #[arg(long, default_value = "pca")]
    kind: String,
    /// Data set directory (train/*.csv, val/*.csv).
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// Action dimension d.
    #[arg(long, default_value_t = 2)]
    latent_dim: usize,
    /// Speed scale s in rad/s (default: 95th percentile of the demonstrated speed).
    #[arg(long)]
    speed_scale: Option<f64>,
    /// Model file to write.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// Overwrite an existing model file (and its loss log and picture).
    #[arg(long)]
    force: bool,
    /// Epochs per seed (scl, cae).
    #[arg(long, default_value_t = 200)]
    epochs: usize,
    /// Seeds to train; the best by validation loss is kept (scl, cae).
    #[arg(long, default_value_t = 10)]
    seeds: usize,
    /// Seed of the first run; run i uses seed + i.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Seeds trained at once, one thread each (0: one per CPU).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Mini-batch size.
    #[arg(long, default_value_t = 256)]
    batch: usize,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    lr: f64,
    /// Hidden layer widths, comma-separated.
    #[arg(long, default_value = "256,256")]
    hidden: String,
    /// Lipschitz bound L of the decoder w.r.t. the raw (q, c) (default 1 for scl, none for
    /// cae).
    #[arg(long, conflicts_with = "no_lipschitz")]
    lipschitz: Option<f64>,
    /// Train the SCL decoder without a Lipschitz bound.
    #[arg(long)]
    no_lipschitz: bool,
    /// Power iterations per optimiser step of the Lipschitz projection.
    #[arg(long, default_value_t = 1)]
    power_iterations: usize,
    /// Train and serve SCL without Gram-Schmidt.
    #[arg(long)]
    no_gram_schmidt: bool,
    /// Training encoder: `mlp` (the paper's) or `projection` (a = H'^T qdot, scl only).
    #[arg(long, default_value = "mlp")]
    encoder: String,
    /// Decoder input: `q-c` (joint angles and gripper) or `q`.
    #[arg(long, default_value = "q-c")]
    inputs: String,
    /// Li et al. loss terms for cae, comma-separated: consistency, proportionality,
    /// reversibility.
    #[arg(long, value_name = "TERMS")]
    li_losses: Option<String>,
    /// Weight of each Li term.
    #[arg(long, default_value_t = 1.0)]
    li_weight: f64,
    /// Temperature gamma of the consistency term.
    #[arg(long, default_value_t = learning::train::li::DEFAULT_GAMMA)]
    li_gamma: f64,
    /// Sampling range of alpha in the proportionality term, `lo,hi`.
    #[arg(long, default_value = "0.1,1.0")]
    li_alpha: String,
    /// Time step (s) of the reversibility term's transition.
    #[arg(long, default_value_t = learning::train::li::DEFAULT_STEP_S)]
    li_step: f64,
}

impl TrainArgs {
    /// The training configuration of a network kind.
    fn config(&self, kind: ModelKind) -> Result<TrainConfig, SclError> {
        use learning::cli::{parse_encoder, parse_inputs, parse_list};
        let mut li = match &self.li_losses {
            Some(list) => learning::train::li::parse_terms(list).map_err(|reason| {
                learning::cli::LearningError::Option {
                    option: "--li-losses",
                    reason,
                }
            })?,
            None => None,
        };
        if let Some(li) = &mut li {
            li.weight = self.li_weight;
            li.step_s = self.li_step;
            if li.consistency_gamma.is_some() {
                li.consistency_gamma = Some(self.li_gamma);
            }
            if li.proportionality_alpha.is_some() {
                let r: Vec<f64> = parse_list(&self.li_alpha, "--li-alpha")?;
                let [lo, hi] = r[..] else {
                    return Err(learning::cli::LearningError::Option {
                        option: "--li-alpha",
                        reason: format!("`{}`: expected two numbers `lo,hi`", self.li_alpha),
                    }
                    .into());
                };
                li.proportionality_alpha = Some([lo, hi]);
            }
        }
        Ok(TrainConfig {
            kind,
            latent_dim: self.latent_dim,
            hidden: parse_list(&self.hidden, "--hidden")?,
            epochs: self.epochs,
            batch: self.batch,
            learning_rate: self.lr,
            seeds: self.seeds,
            base_seed: self.seed,
            threads: self.threads,
            // The paper bounds the SCL decoder with L = 1; a CAE is bounded only when asked.
            lipschitz: match kind {
                _ if self.no_lipschitz => None,
                ModelKind::Scl => Some(self.lipschitz.unwrap_or(1.0)),
                _ => self.lipschitz,
            },
            power_iterations: self.power_iterations,
            gram_schmidt: kind == ModelKind::Scl && !self.no_gram_schmidt,
            encoder: parse_encoder(&self.encoder)?,
            inputs: parse_inputs(&self.inputs)?,
            speed_scale: self.speed_scale,
            li,
        })
    }
}

#[derive(Subcommand, Debug)]
enum BenchCmd {
    /// Run the full graph and report per-hop, end-to-end, sample-age, tick-lateness and
    /// compute figures (p50 / p90 / p99 / p99.9 / max), on iceoryx2, on Unix-domain datagram
    /// sockets, or both one after the other with the ratio of each figure.
    Latency {
        /// How long each transport runs.
        #[arg(long = "for", value_name = "DURATION", default_value = "60s", value_parser = parse_duration)]
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
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Keep the report (report.json), the plot (headroom.png), the runs' configs and logs
        /// in DIR.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// A busy loop (the load processes of `--load`).
    #[command(hide = true)]
    Burn,
}

/// The real-time settings of a benchmark's graph.
#[derive(clap::Args, Debug, Clone)]
struct RtArgs {
    /// Ask for the standard real-time tuning on the control path: SCHED_FIFO priorities,
    /// mlockall, pinning to the last CPU, and `/dev/cpu_dma_latency` held at 0 while the
    /// graph runs (the report says what each process got and what the machine refused).
    #[arg(long, conflicts_with = "rt_only")]
    rt: bool,
    /// Ask for one real-time setting alone, to measure its effect: `fifo`, `mlock`, `pin` or
    /// `dma-latency`.
    #[arg(long, value_name = "SETTING")]
    rt_only: Option<String>,
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

fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    let (num, unit) = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map_or((s, "s"), |i| (&s[..i], &s[i..]));
    let v: f64 = num
        .parse()
        .map_err(|_| format!("`{s}` is not a duration; write e.g. 60s, 2m or 500ms"))?;
    let secs = match unit {
        "ms" => v / 1000.0,
        "s" => v,
        "m" | "min" => v * 60.0,
        "h" => v * 3600.0,
        _ => return Err(format!("unknown unit `{unit}` in `{s}`; use ms, s, m or h")),
    };
    if !(secs.is_finite() && secs > 0.0) {
        return Err(format!("`{s}` must be a positive duration"));
    }
    Ok(Duration::from_secs_f64(secs))
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
        let code = scl_doctor::run(cli.config.as_deref(), args)?;
        return Ok(ExitCode::from(code as u8));
    }
    let mut cfg = GraphConfig::load(cli.config.as_deref())?;
    if let Some(p) = &cli.prefix {
        cfg.graph.prefix = p.clone();
    }
    let prefix =
        Prefix::new(&cfg.graph.prefix).map_err(|e| scl_node::config::ConfigError::Value {
            key: "prefix".into(),
            reason: e.to_string(),
        })?;
    let period_s = cfg.period_s();
    match cli.cmd {
        Cmd::Up {
            duration,
            json,
            model,
            script,
            joystick,
            record,
            live,
        } => {
            if let Some(m) = model {
                cfg.mapper.model = m;
            }
            if let Some(s) = script {
                cfg.joystick.script = s;
            }
            if let Some(s) = joystick {
                cfg.joystick.source = s;
            }
            let opts = scl_supervisor::up::UpOptions {
                prefix,
                config_path: cli.config.clone(),
                config: cfg,
                duration,
                json,
                record: record.map(|p| scl_recorder::absolute(&p)),
                live,
            };
            let summary = scl_supervisor::up::run(&opts)?;
            if json {
                let text = serde_json::to_string(&summary)
                    .map_err(|e| SclError::Other(format!("cannot encode the summary: {e}")))?;
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
        Cmd::Swap { model, timeout } => {
            let r = scl_supervisor::control::swap(&prefix, &model, timeout)?;
            if r.ok == 1 {
                println!("{}", scl_supervisor::control::swap_line(&r));
                Ok(ExitCode::SUCCESS)
            } else {
                eprintln!("scl swap: refused: {}", r.message.as_string());
                Ok(ExitCode::from(1))
            }
        }
        Cmd::Estop | Cmd::Reset => {
            let (action, what) = if matches!(cli.cmd, Cmd::Estop) {
                (ipc_types::control::estop_action::ESTOP, "e-stop latched")
            } else {
                (ipc_types::control::estop_action::RESET, "e-stop reset")
            };
            match scl_supervisor::control::estop(
                &prefix,
                cfg.graph.transport,
                action,
                Duration::from_secs(2),
            )? {
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
        Cmd::Bench { what } => match what {
            BenchCmd::Burn => scl_bench::burn(),
            BenchCmd::Latency {
                duration,
                rt,
                load,
                transport,
                rate_hz,
                json,
                live,
                out,
            } => {
                let transports = parse_transports(&transport)?;
                if let Some(r) = rate_hz {
                    cfg.set_rate_hz(r);
                }
                cfg.validate()?;
                let opts = scl_bench::LatencyOptions {
                    duration,
                    rt: rt.settings()?,
                    load,
                    transports,
                    config: cfg,
                    out: out.clone(),
                    live,
                };
                let report = scl_bench::latency(&opts)?;
                let text = serde_json::to_string_pretty(&report)
                    .map_err(|e| SclError::Other(format!("cannot encode the report: {e}")))?;
                if let Some(dir) = &out {
                    let p = dir.join("report.json");
                    std::fs::write(&p, &text)
                        .map_err(|e| SclError::Other(format!("{}: {e}", p.display())))?;
                }
                if json {
                    println!("{text}");
                } else {
                    print!("{}", scl_bench::render(&report));
                }
                Ok(ExitCode::SUCCESS)
            }
            BenchCmd::Headroom {
                secs,
                rates,
                rt,
                load,
                transport,
                json,
                out,
            } => {
                if !(secs.is_finite() && secs > 0.0) {
                    return Err(SclError::Other(format!(
                        "--secs {secs}: must be a positive number of seconds"
                    )));
                }
                for r in &rates {
                    let mut c = cfg.clone();
                    c.set_rate_hz(*r);
                    c.validate()
                        .map_err(|e| SclError::Other(format!("--rates {r}: {e}")))?;
                }
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
                let text = serde_json::to_string_pretty(&report)
                    .map_err(|e| SclError::Other(format!("cannot encode the report: {e}")))?;
                if let Some(dir) = &out {
                    let p = dir.join("report.json");
                    std::fs::write(&p, &text)
                        .map_err(|e| SclError::Other(format!("{}: {e}", p.display())))?;
                }
                if json {
                    println!("{text}");
                } else {
                    print!("{}", scl_bench::headroom::render(&report));
                }
                Ok(ExitCode::SUCCESS)
            }
        },
        Cmd::Status { json } => {
            let st = scl_supervisor::control::status(
                &prefix,
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
                let text = serde_json::to_string_pretty(&st)
                    .map_err(|e| SclError::Other(format!("cannot encode the status: {e}")))?;
                println!("{text}");
            } else {
                print!("{}", scl_supervisor::control::render(&st));
            }
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Layout => {
            let text = serde_json::to_string_pretty(&ipc_types::layout::describe())
                .map_err(|e| SclError::Other(format!("cannot encode the layout: {e}")))?;
            println!("{text}");
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Joystick(args) => {
            scl_joystick::main(&prefix, &mut cfg, &args)?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Mapper { model, id } => {
            let model = model.unwrap_or(cfg.mapper.model);
            scl_mapper_node::run(
                &prefix,
                &cfg.graph,
                &cfg.faults,
                &model,
                id.unwrap_or(cfg.mapper.id),
            )?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Safety => {
            scl_safety_node::run(&prefix, &cfg.graph, &cfg.safety, &cfg.faults, period_s)?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Bridge {
            robot,
            start_tick,
            resume_q,
            resume_gripper,
            address,
            port,
            user,
            password,
        } => {
            if let Some(r) = robot {
                cfg.bridge.robot = r;
            }
            if let Some(a) = address {
                cfg.bridge.kortex.address = a;
            }
            if let Some(p) = port {
                cfg.bridge.kortex.port = p;
            }
            cfg.validate()?;
            let resume = scl_bridge_node::Resume {
                start_tick,
                pose: resume_q.map(|q| (q, resume_gripper)),
            };
            let creds = scl_bridge_node::CredentialArgs {
                user: user.map(scl_bridge_node::Secret::into_inner),
                password: password.map(scl_bridge_node::Secret::into_inner),
            };
            scl_bridge_node::run(
                &prefix,
                &cfg.graph,
                &cfg.bridge,
                &cfg.faults,
                &resume,
                &creds,
            )?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::FakeKortex {
            port,
            misread_cyclic,
        } => {
            scl_bridge_node::fake_kortex::run(port, misread_cyclic)?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Demos {
            task,
            out,
            seed,
            n_train,
            n_val,
            plot,
        } => {
            learning::tools::demos(&task, &out, seed, (n_train, n_val), plot.as_deref())?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Plot {
            data,
            out,
            title,
            font,
            force,
        } => {
            learning::tools::plot(&data, &out, title.as_deref(), font.as_deref(), force)?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Train(t) => {
            let command = std::env::args().collect::<Vec<_>>().join(" ");
            match t.kind.as_str() {
                "pca" => {
                    learning::tools::train_pca(&learning::tools::TrainOptions {
                        data: &t.data,
                        out: &t.out,
                        latent_dim: t.latent_dim,
                        speed_scale: t.speed_scale,
                        force: t.force,
                        command,
                    })?;
                }
                "scl" | "cae" => {
                    let kind = if t.kind == "scl" {
                        ModelKind::Scl
                    } else {
                        ModelKind::Cae
                    };
                    let cfg = t.config(kind)?;
                    learning::cli::train_network(&cfg, &t.data, &t.out, t.force, &command)?;
                }
                other => {
                    return Err(SclError::Other(format!(
                        "--kind {other}: expected pca, scl or cae"
                    )));
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Import {
            json,
            kind,
            joints,
            latent_dim,
            speed_scale,
            no_gram_schmidt,
            input_mean,
            input_std,
            out,
            force,
        } => {
            use learning::cli::parse_list;
            let kind = match kind.as_str() {
                "scl" => ModelKind::Scl,
                "cae" => ModelKind::Cae,
                other => {
                    return Err(SclError::Other(format!(
                        "--kind {other}: expected scl or cae"
                    )));
                }
            };
            if !(speed_scale.is_finite() && speed_scale > 0.0) {
                return Err(SclError::Other(format!(
                    "--speed-scale {speed_scale}: expected a positive number (rad/s)"
                )));
            }
            let normalisation = match (input_mean, input_std) {
                (Some(m), Some(s)) => Some((
                    parse_list(&m, "--input-mean")?,
                    parse_list(&s, "--input-std")?,
                )),
                _ => None,
            };
            let opts = learning::import::ImportOptions {
                kind,
                n_joints: joints,
                latent_dim,
                speed_scale,
                gram_schmidt: !no_gram_schmidt,
                normalisation,
                command: std::env::args().collect::<Vec<_>>().join(" "),
            };
            learning::cli::import_weights(&json, &opts, &out, force)?;
            Ok(ExitCode::SUCCESS)
        }
        Cmd::Eval { what } => {
            let command = std::env::args().collect::<Vec<_>>().join(" ");
            use learning::experiments as ex;
            let (out, verdict) = match what {
                EvalCmd::Reversibility(args) => {
                    let o = ex::reversibility::run(&args, period_s, &command)?;
                    let failed: Vec<_> = o.checks.iter().filter(|c| !c.holds).collect();
                    (
                        o.out,
                        if failed.is_empty() {
                            "the expected shape holds".to_owned()
                        } else {
                            format!("{} expected-shape statement(s) do not hold", failed.len())
                        },
                    )
                }
                EvalCmd::Theorem(args) => {
                    let o = ex::theorem::run(&args, period_s, &command)?;
                    if !o.theorem_holds {
                        eprintln!(
                            "scl eval theorem: the inequality FAILED where the theorem applies (a bug); see {}",
                            o.out.join("summary.md").display()
                        );
                        return Ok(ExitCode::from(1));
                    }
                    (
                        o.out,
                        "the inequality held wherever the theorem applies".to_owned(),
                    )
                }
                EvalCmd::Reconstruction(args) => {
                    let o = ex::reconstruction::run(&args, &command)?;
                    (o.out, format!("{} models evaluated", o.entries.len()))
                }
                EvalCmd::GreedyUser(args) => {
                    let o = ex::greedy_user::run(&args, &command)?;
                    let failed = o.checks.iter().filter(|c| !c.holds).count();
                    (
                        o.out,
                        if failed == 0 {
                            "the paper's statements hold".to_owned()
                        } else {
                            format!("{failed} of the paper's statement(s) do not hold")
                        },
                    )
                }
            };
            eprintln!("{verdict}; summary: {}", out.join("summary.md").display());
            Ok(ExitCode::SUCCESS)
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let role = match &cli.cmd {
        Cmd::Up { .. } => "up",
        Cmd::Swap { .. } => "swap",
        Cmd::Status { .. } => "status",
        Cmd::Estop => "estop",
        Cmd::Bench { .. } => "bench",
        Cmd::Reset => "reset",
        Cmd::Layout => "layout",
        Cmd::Joystick(_) => "joystick",
        Cmd::Mapper { .. } => "mapper",
        Cmd::Safety => "safety",
        Cmd::Bridge { .. } => "bridge",
        Cmd::FakeKortex { .. } => "fake-kortex",
        Cmd::Demos { .. } => "demos",
        Cmd::Plot { .. } => "plot",
        Cmd::Record(_) => "record",
        Cmd::Study { .. } => "study",
        Cmd::Live(_) => "live",
        Cmd::Dataset(_) => "dataset",
        Cmd::Replay(_) => "replay",
        Cmd::Top(_) => "top",
        Cmd::Doctor(_) => "doctor",
        Cmd::Train(_) => "train",
        Cmd::Import { .. } => "import",
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

    #[test]
    fn durations() {
        assert_eq!(parse_duration("60s"), Ok(Duration::from_secs(60)));
        assert_eq!(parse_duration("2m"), Ok(Duration::from_secs(120)));
        assert_eq!(parse_duration("500ms"), Ok(Duration::from_millis(500)));
        assert_eq!(parse_duration("5"), Ok(Duration::from_secs(5)));
        assert!(parse_duration("5 parsecs").is_err());
        assert!(parse_duration("-1s").is_err());
        assert!(parse_duration("0s").is_err());
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
        let Cmd::Bridge { password, .. } = cli.cmd else {
            panic!("not the bridge")
        };
        assert_eq!(password.unwrap().into_inner(), "dbg-pass-y");
    }
}
