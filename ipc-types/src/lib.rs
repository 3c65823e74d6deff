//! What flows through an SCL teleoperation graph, and how it is opened.
//!
//! * [`msg`]: the fixed-size `#[repr(C)]` message types. They know nothing of iceoryx2
//!   beyond the `ZeroCopySend` derive and a stable type name, so step functions and unit tests
//!   use them directly.
//! * [`prefix`]: the graph prefix that isolates one graph from another on the same machine.
//! * [`graph`]: the one place that opens every service with its settings (history, buffers,
//!   publisher limits), and thin publisher / subscriber wrappers that pair a data service with
//!   its wake-up event.
//! * [`control`]: the control plane: `scl swap` requests to the supervisor, and the
//!   active-mapper switch the supervisor sends to safety.
//! * [`uds`]: the comparison transport (Unix-domain datagram sockets) for benchmarks.
//! * [`time`]: the monotonic clock every process stamps its messages with.
//! * `json` (feature `json`): the messages' JSON form and JSON schema, derived from the types
//!   (serde, schemars); the recording crate enables it.
//! * [`layout`]: the messages' memory layout as data (size, alignment, every field's offset
//!   and type, iceoryx2 type names, topic settings), for bindings in other languages.
//! * [`stats`]: the one quantile definition (latency percentiles, experiment quartiles).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod control;
pub mod graph;
#[cfg(feature = "json")]
pub mod json;
pub mod layout;
pub mod msg;
pub mod prefix;
pub mod signals;
pub mod stats;
pub mod time;
pub mod uds;

pub use graph::{Graph, IpcError, TopicPublisher, TopicSubscriber, Transport, wait_any};
pub use msg::*;
pub use prefix::{Prefix, PrefixError};
