//! What flows through an SCL teleoperation graph: the messages, as data. This crate does not
//! link iceoryx2 (the `transport` crate opens the services); the messages implement its
//! `ZeroCopySend` trait through the small crates that define the trait and its derive.
//!
//! * [`msg`]: the fixed-size `#[repr(C)]` message types. Step functions and unit tests use
//!   them directly.
//! * [`control`]: the control plane's messages: `scl swap` requests to the supervisor, the
//!   e-stop commands, and the active-mapper switch the supervisor sends to safety.
//! * [`topics`]: each topic's name and settings (history, buffers, publisher limits), and
//!   which transport the data-plane topics travel on.
//! * [`prefix`]: the graph prefix that isolates one graph from another on the same machine.
//! * [`time`]: the monotonic clock every process stamps its messages with.
//! * `json` (feature `json`): the messages' JSON form and JSON schema, derived from the types
//!   (serde, schemars); the recording crate enables it.
//! * [`fields`]: each message's fields by name and value, from one declaration per message
//!   (the struct, its layout, the fields `scl replay` does not compare), and the bit sets'
//!   names from one declaration per bit.
//! * [`layout`]: the messages' memory layout as data (size, alignment, every field's offset
//!   and type, iceoryx2 type names, topic settings), for bindings in other languages.
//! * [`stats`]: the one quantile definition (latency percentiles, experiment quartiles).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod control;
pub mod fields;
#[cfg(feature = "json")]
pub mod json;
pub mod layout;
pub mod msg;
pub mod prefix;
pub mod stats;
pub mod time;
pub mod topics;

pub use control::{EstopCommand, SafetyControl};
pub use msg::*;
pub use prefix::{Prefix, PrefixError};
pub use topics::{Plane, TopicDef, TopicSettings, Transport};
