//! The supervisor: [`up`] (`scl up`: starts the graph's processes in order, reaps and
//! restarts them, cleans up after dead ones, serves live swaps and holds) and [`notify`]
//! (systemd readiness and watchdog for `scl up` as a `Type=notify` service). The commands
//! that talk to a running graph (`scl swap`, `scl status`, `scl estop`) are `graph-client`'s.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

mod histogram;
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
    /// The network gateway's credentials file is unusable.
    #[error(transparent)]
    Credentials(#[from] scl_net::CredentialsError),
    /// The Kortex credentials file (`[bridge.kortex] credentials_file`) is unusable.
    #[error(transparent)]
    KortexCredentials(#[from] scl_config::secret::KortexCredentialsError),
    /// A recording cannot be made (`--record` over an existing file).
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// A process of the graph could not be started.
    #[error("cannot start the {process} process: {source}")]
    Spawn {
        /// Its role (`mapper`, `live`, ...).
        process: &'static str,
        /// Why.
        source: std::io::Error,
    },
    /// `--live ADDR`: not an address and a port.
    #[error("--live {addr}: expected ADDR:PORT, e.g. 127.0.0.1:8765 ({source})")]
    LiveAddress {
        /// The address as given.
        addr: String,
        /// Why it does not parse.
        source: std::net::AddrParseError,
    },
    /// The live server did not come up (the graph does not start without it).
    #[error(transparent)]
    Live(#[from] LiveStartError),
    /// One of the graph's control topics failed (the switch to safety, the e-stop relay, the
    /// control service).
    #[error("{what}: {source}")]
    Control {
        /// Which, and what the supervisor was doing.
        what: &'static str,
        /// What the transport said.
        source: transport::graph::IoError,
    },
}

/// Why `scl up --live` could not start its live server.
#[derive(Debug, thiserror::Error)]
pub enum LiveStartError {
    /// Its standard output could not be read (the reader thread did not start).
    #[error("cannot read the live process's announcement: {0}")]
    Announcement(#[source] std::io::Error),
    /// It announced that it failed (the port in use, ...), and exited.
    #[error("the live server did not start ({status}): {reason}")]
    Refused {
        /// How the process ended.
        status: String,
        /// Its own words, from its announcement.
        reason: String,
    },
    /// It exited without announcing anything.
    #[error("scl live exited ({status}) before serving on {addr}")]
    Exited {
        /// How the process ended.
        status: String,
        /// The address it was to serve on.
        addr: String,
    },
    /// It announced nothing in time; it was stopped.
    #[error("scl live did not serve on {addr} within {timeout:?}")]
    Timeout {
        /// The address it was to serve on.
        addr: String,
        /// How long the supervisor waited.
        timeout: std::time::Duration,
    },
}
