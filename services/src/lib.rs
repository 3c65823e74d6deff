//! The processes of an SCL graph and the tools around them, wired into the `scl` command.
//!
//! Each process module is a thin loop (wait, read, step, publish) around a pure step function
//! from a library crate: [`joystick`] (script, evdev, keyboard and replay sources),
//! [`mapper_node`], [`safety_node`],
//! [`bridge_node`]. [`up`] supervises the four as child processes and serves live swaps;
//! [`control`] is the client side (`scl swap`, `scl status`). [`config`] is the graph
//! TOML, [`signals`] the shutdown flag every loop polls. [`tools`] and [`plot`] are the offline
//! commands (`demos`, `train`, `plot`); [`bench`] runs the latency benchmark.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod bench;
pub mod bridge_node;
pub mod config;
pub mod control;
pub mod joystick;
pub mod mapper_node;
pub mod plot;
pub mod rt;
pub mod safety_node;
pub mod signals;
pub mod stats;
pub mod tools;
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
    /// The supervisor's graph failed (a child died, did not start, ...).
    #[error("{0}")]
    Graph(String),
}
