//! What every process of an SCL graph shares: the graph TOML ([`config`]), real-time set-up
//! along the control path ([`rt`]) and the latency percentiles the supervisor, the benchmark
//! and the dashboard report ([`stats`]). The stop flag every loop polls is
//! [`ipc_types::signals`].
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod config;
pub mod rt;
pub mod stats;

pub use config::{ConfigError, GraphConfig};
