//! The supervisor: [`up`] (`scl up`: starts the graph's processes in order, reaps and
//! restarts them, cleans up after dead ones, serves live swaps and holds) and [`notify`]
//! (systemd readiness and watchdog for `scl up` as a `Type=notify` service). The commands
//! that talk to a running graph (`scl swap`, `scl status`, `scl estop`) are `graph-client`'s.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod notify;
pub mod up;

/// Why the supervisor stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum SupervisorError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] mapper::ModelError),
    /// A recording cannot be made (`--record` over an existing file).
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// The graph or the process failed (a child died, a thread did not start, ...).
    #[error("{0}")]
    Graph(String),
}
