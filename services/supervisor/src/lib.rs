//! The supervisor and its clients: [`up`] (`scl up`: starts the graph's processes in order,
//! reaps and restarts them, cleans up after dead ones, serves live swaps and holds),
//! [`control`] (`scl swap`, `scl status`, `scl estop` / `scl reset`: the client side), and
//! [`notify`] (systemd readiness and watchdog for `scl up` as a `Type=notify` service).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod control;
pub mod notify;
pub mod up;

/// Why the supervisor or a control request stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum SupervisorError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_node::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] ipc_types::IpcError),
    /// The model file is unusable.
    #[error(transparent)]
    Model(#[from] mapper::ModelError),
    /// The joystick's configuration or sources are unusable.
    #[error(transparent)]
    Joystick(#[from] scl_joystick::JoystickError),
    /// A mapper could not be set up (its model, its topics).
    #[error(transparent)]
    MapperNode(#[from] scl_mapper_node::MapperNodeError),
    /// A recording cannot be made (`--record` over an existing file).
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// The graph or the process failed (a child died, a thread did not start, ...).
    #[error("{0}")]
    Graph(String),
}
