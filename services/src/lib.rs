//! The processes of an SCL graph and the tools around them, wired into the `scl` command.
//!
//! Each process module is a thin loop (wait, read, step, publish) around a pure step function
//! from a library crate: [`joystick`] (script source), [`mapper_node`], [`safety_node`],
//! [`bridge_node`]. [`up`] supervises the four as child processes. [`config`] is the graph
//! TOML, [`signals`] the shutdown flag every loop polls. [`tools`] (demos, PCA) and
//! [`learning`] (network training, import, offline evaluation) are the offline commands.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod bridge_node;
pub mod config;
pub mod joystick;
pub mod learning;
pub mod mapper_node;
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
    /// Training a network failed.
    #[error(transparent)]
    Train(#[from] mapper::train::TrainError),
    /// Importing weights failed.
    #[error(transparent)]
    Import(#[from] mapper::import::ImportError),
    /// An offline evaluation failed.
    #[error(transparent)]
    Eval(#[from] mapper::eval::EvalError),
    /// Writing training artefacts or reading learning options failed.
    #[error(transparent)]
    Learning(#[from] learning::LearningError),
    /// The supervisor's graph failed (a child died, did not start, ...).
    #[error("{0}")]
    Graph(String),
}
