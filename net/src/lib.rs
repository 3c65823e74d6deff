//! The graph's link to other machines, on Zenoh (the `zenoh` crate, TCP and user/password
//! authentication only): iceoryx2 stays the transport inside the robot PC, and this crate is
//! what the gateway process (`scl-gateway`) and a remote operator (`scl joystick --remote`)
//! share:
//!
//! * [`keys`]: the key expressions of one graph below its namespace;
//! * [`wire`]: the messages on the wire (their own bytes, typed by the encoding's schema) and
//!   the gateway's [`wire::GatewayStatus`];
//! * [`credentials`]: the `user:password` file, refused unless only its owner can read it;
//! * [`session`]: `[network]` as a Zenoh configuration, and opening a session;
//! * [`ports`]: typed publishers, subscribers and liveliness tokens;
//! * [`observe`]: a remote observer's side (every topic, what each process runs, the clocks);
//! * [`link`]: the remote operator's link as the gateway judges it (pure: who drives, stale
//!   and lost input, neutral before motion);
//! * [`netns`] and [`relay`]: two test hosts on one machine (network namespaces and a veth
//!   pair) and a delay line between them, for the benchmark and the network tests.
#![cfg_attr(test, allow(clippy::unwrap_used))]

pub mod credentials;
pub mod keys;
pub mod link;
pub mod netns;
pub mod observe;
pub mod ports;
pub mod relay;
pub mod ros2;
pub mod session;
pub mod wire;

pub use credentials::{Credentials, CredentialsError};
pub use keys::Keys;
pub use link::OperatorLink;
pub use session::{SessionError, SessionSpec};
pub use wire::{GatewayStatus, Wire};
/// The Zenoh crate, for the types of sessions and ports its users keep.
pub use zenoh;
