//! How the messages of an SCL graph travel: the one place that opens every service of a
//! graph with its settings. The messages themselves are [`ipc_types`]'s.
//!
//! * [`graph`]: joining a graph ([`Graph`]), its publishers and subscribers (each pairs a
//!   data service with its wake-up event), waiting on several ([`wait_any`]), cleaning up
//!   after dead processes, and the typed errors ([`IpcError`], iceoryx2's error as the
//!   source).
//! * [`control`]: the control plane's services (the supervisor's request-response service,
//!   the e-stop topic, the active-mapper switch).
//! * [`uds`]: the comparison transport (Unix-domain datagram sockets) for benchmarks.
//! * [`signals`]: the stop flag every process's loop polls (SIGINT / SIGTERM).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod control;
pub mod graph;
pub mod uds;

/// The stop flag every process's loop polls: the `scl-signals` crate, re-exported here so a
/// process that opens the graph reaches it through one dependency.
pub use scl_signals as signals;

pub use graph::{Graph, IpcError, Pollable, TopicPublisher, TopicSubscriber, Waker, wait_any};
