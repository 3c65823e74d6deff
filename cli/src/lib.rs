//! The `scl` command: parses the command line and dispatches to the crate of each process or
//! tool. The processes live beside this crate, one crate each: `scl-joystick`,
//! `scl-mapper-node`, `scl-safety-node`, `scl-bridge-node` (with the fake Kortex robot),
//! `scl-supervisor` (`up`), the observers `scl-recorder`,
//! `scl-live` and `scl-dashboard`, and `scl-bench`; `scl doctor` is here ([`doctor`]). What
//! they share lives in libraries below them: the graph TOML (`scl-config`), real-time set-up
//! (`node-rt`), the commands that talk to a running graph (`graph-client`). The offline
//! commands are the `learning` crate's.

pub mod doctor;

/// Why `scl` failed: the error of whichever process or tool ran, with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum SclError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] mapper::ModelError),
    /// The joystick process.
    #[error(transparent)]
    Joystick(#[from] scl_joystick::JoystickError),
    /// The mapper process.
    #[error(transparent)]
    MapperNode(#[from] scl_mapper_node::MapperNodeError),
    /// The safety process.
    #[error(transparent)]
    SafetyNode(#[from] scl_safety_node::SafetyNodeError),
    /// The bridge process or the fake Kortex robot.
    #[error(transparent)]
    BridgeNode(#[from] scl_bridge_node::BridgeNodeError),
    /// The network gateway.
    #[error(transparent)]
    Gateway(#[from] scl_gateway::GatewayError),
    /// The supervisor (`up`).
    #[error(transparent)]
    Supervisor(#[from] scl_supervisor::SupervisorError),
    /// A control request to a running graph (`swap`, `status`, `estop`, `reset`).
    #[error(transparent)]
    Control(#[from] graph_client::ControlError),
    /// The recorder.
    #[error(transparent)]
    Recorder(#[from] scl_recorder::RecorderError),
    /// The live Foxglove server.
    #[error(transparent)]
    Live(#[from] scl_live::LiveError),
    /// A recording could not be written, read or recovered.
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// A recording could not be replayed.
    #[error(transparent)]
    Replay(#[from] replay::ReplayError),
    /// The dashboard.
    #[error(transparent)]
    Top(#[from] scl_dashboard::TopError),
    /// `scl doctor` could not write its report.
    #[error(transparent)]
    Doctor(#[from] crate::doctor::DoctorError),
    /// `scl study`.
    #[error(transparent)]
    Study(#[from] scl_study::StudyRunError),
    /// The benchmark.
    #[error(transparent)]
    Bench(#[from] scl_bench::BenchError),
    /// `scl drill` could not run.
    #[error(transparent)]
    Drill(#[from] scl_drill::DrillError),
    /// A learning command (`train`, `eval`, `demos`, `plot`, `import`, `dataset`).
    #[error(transparent)]
    Tool(#[from] learning::ToolError),
    /// A learning option could not be read.
    #[error(transparent)]
    Learning(#[from] learning::cli::LearningError),
    /// A report or summary could not be encoded as JSON.
    #[error("cannot encode the {what}: {source}")]
    Encode {
        /// What was being encoded.
        what: &'static str,
        /// What serde_json said.
        source: serde_json::Error,
    },
    /// An output file could not be written.
    #[error("{}: {source}", path.display())]
    Write {
        /// The file.
        path: std::path::PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// `--remote`: a link that cannot be read.
    #[error("--remote {0}")]
    Link(#[source] scl_bench::remote::LinkError),
    /// `--rates`: a rate the graph configuration refuses.
    #[error("--rates {rate}: {source}")]
    Rate {
        /// The rate (Hz).
        rate: f64,
        /// What the configuration's checks said.
        source: scl_config::ConfigError,
    },
    /// `--robot`: not a robot this build knows.
    #[error("--robot: {0}")]
    Robot(#[source] kinematics::ProfileError),
    /// The command line itself (an option out of range or that does not go with another).
    #[error("{0}")]
    Other(String),
}
