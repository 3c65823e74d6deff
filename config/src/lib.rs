//! The graph configuration every process of an SCL graph reads: one TOML file
//! ([`GraphConfig`]), every key optional, with its loading ([`GraphConfig::load`]) and the
//! checks no single crate makes ([`GraphConfig::validate`]).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

mod config;
mod network;
pub mod placement;
pub mod secret;

pub use config::*;
pub use network::*;

/// The `[joystick] source` of a graph whose operator is outside it: `scl up` starts no
/// joystick process and the mapper takes `JoystickInput` from whoever publishes it on the
/// joystick topic (one publisher at a time: the topic admits one). The rules downstream are
/// those of any source: a sample must answer the newest robot tick (`JoystickInput::tick`), so
/// input that stops stops the arm within two ticks; no input at all is stale; the deadman and
/// e-stop bits act in safety.
pub const EXTERNAL_JOYSTICK: &str = "external";
