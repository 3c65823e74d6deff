//! Talking to a running graph from outside it, for the commands and observers that are not
//! its control path: [`control`] (`scl swap`, `scl status`, `scl estop` / `scl reset`, and
//! the dashboard's keys), [`observe`] (every recorded topic, read-only, as payloads: the
//! recorder's, `scl live`'s and the gateway's reading of the graph) and [`process`] (what each
//! process of the graph runs, read from `/proc` and written into a recording by `scl record`
//! and `scl live`).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod control;
pub mod observe;
pub mod process;

/// Why a control request to a running graph failed, with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The model file of a swap cannot be found.
    #[error("model file {model}: {source}")]
    ModelFile {
        /// The model as given.
        model: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// The model path of a swap does not fit a control request.
    #[error("model path {spec} is longer than {cap} bytes")]
    ModelPathTooLong {
        /// The absolute path.
        spec: String,
        /// The request's text capacity.
        cap: usize,
    },
    /// No process of the graph is alive: nothing to ask, and joining would leave the graph's
    /// shared memory behind.
    #[error(
        "no graph is running under the prefix `{prefix}` (no live process); start one with `scl up --prefix {prefix}`"
    )]
    NoGraph {
        /// The graph prefix asked for.
        prefix: String,
    },
    /// The e-stop command could not be sent.
    #[error("cannot send the e-stop command: {0}")]
    SendEstop(#[source] transport::IpcError),
}

/// Fails with [`ControlError::NoGraph`] when no process of graph `prefix` is alive, without
/// joining the graph (a node would create the graph's shared memory, which a graph that is
/// not there never cleans up).
pub fn require_graph(prefix: &ipc_types::Prefix) -> Result<(), ControlError> {
    let (alive, _dead) = transport::graph::census(prefix)?;
    if alive == 0 {
        return Err(ControlError::NoGraph {
            prefix: prefix.as_str().to_owned(),
        });
    }
    Ok(())
}
