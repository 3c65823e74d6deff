//! The processes of an SCL graph and the tools around them, wired into the `scl` command.
//!
//! Each process module is a thin loop (wait, read, step, publish) around a pure step function
//! from a library crate: [`joystick`] (script, evdev, keyboard and replay sources),
//! [`mapper_node`], [`safety_node`],
//! [`bridge_node`]. [`up`] supervises the four as child processes and serves live swaps;
//! [`control`] is the client side (`scl swap`, `scl status`). [`config`] is the graph
//! TOML, [`signals`] the shutdown flag every loop polls. [`tools`] and [`plot`] are the offline
//! commands (`demos`, `train`, `plot`); [`bench`] runs the latency benchmark. The read-only
//! observers: [`record`] (`scl record`, MCAP in the [`mcap_log`] format), [`to_dataset`]
//! (`scl dataset`, recordings to training data) and [`top`] (`scl top`, the terminal dashboard).
//! [`fake_kortex`] serves a fake Gen3 lite over the Kortex protocol on loopback
//! (`scl fake-kortex`).
//! [`learning`] (network training, import, offline evaluation) joins [`tools`] offline;
//! [`experiments`] runs the paper's experiments end to end (`scl eval EXPERIMENT --out DIR`).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod bench;
pub mod bridge_node;
pub mod config;
pub mod control;
pub mod experiments;
pub mod fake_kortex;
pub mod joystick;
pub mod learning;
pub mod mapper_node;
pub mod mcap_log;
pub mod plot;
pub mod record;
pub mod rt;
pub mod safety_node;
pub mod signals;
pub mod stats;
pub mod to_dataset;
pub mod tools;
pub mod top;
pub mod up;

/// Errors that end a process, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum SclError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] ipc_types::IpcError),
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] mapper::ModelError),
    /// A data set could not be read or written.
    #[error(transparent)]
    Dataset(#[from] mapper::dataset::DatasetError),
    /// Fitting PCA failed.
    #[error(transparent)]
    Fit(#[from] mapper::pca::FitError),
    /// Generating task demonstrations failed.
    #[error(transparent)]
    Tasks(#[from] mapper::tasks::TaskError),
    /// An input source (device mapping, recorded input, terminal) could not be set up.
    #[error(transparent)]
    Joystick(#[from] joystick::JoystickError),
    /// Drawing a plot failed.
    #[error(transparent)]
    Plot(#[from] plot::PlotError),
    /// A recording could not be written, read or recovered.
    #[error(transparent)]
    Record(#[from] mcap_log::RecordError),
    /// The dashboard could not run.
    #[error(transparent)]
    Top(#[from] top::TopError),
    /// The robot failed (Kortex: connection, session, an error from the robot).
    #[error(transparent)]
    Robot(#[from] hw_bridge::RobotError),
    /// The Kortex credentials could not be found or read (the message never holds them).
    #[error("{0}")]
    Credentials(String),
    /// The fake Kortex robot could not start.
    #[error(transparent)]
    FakeKortex(#[from] hw_bridge::kortex::fake::FakeError),
    /// Training a network failed.
    #[error(transparent)]
    Train(#[from] mapper::train::TrainError),
    /// Importing weights failed.
    #[error(transparent)]
    Import(#[from] mapper::import::ImportError),
    /// An offline evaluation failed.
    #[error(transparent)]
    Eval(#[from] mapper::eval::EvalError),
    /// An experiment (`scl eval EXPERIMENT`) could not run.
    #[error(transparent)]
    Experiment(#[from] experiments::ExperimentError),
    /// Writing training artefacts or reading learning options failed.
    #[error(transparent)]
    Learning(#[from] learning::LearningError),
    /// The supervisor's graph failed (a child died, did not start, ...).
    #[error("{0}")]
    Graph(String),
}
