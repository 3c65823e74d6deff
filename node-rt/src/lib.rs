//! What a process of an SCL graph does about time: its real-time set-up along the control
//! path ([`rt`]: SCHED_FIFO, memory locking, CPU pinning, CPU DMA latency, from the graph
//! TOML's `[graph]` table) and the latency percentiles the supervisor, the benchmark and the
//! dashboard report ([`stats`]), and how the control-path loops wait for their input
//! ([`wait`]: `[graph] wait`; [`poller`]: the one poller the loops own). The stop flag every loop polls is `scl-signals` (`transport::signals`).
//! The one node contract ([`node`]): the `READY` / `RUNNING` / `STOPPING` heartbeat on the
//! status topic and the loop that turns a node's step until a stop is requested.
//! Besides: how a child tells its parent it is ready ([`ready`]), and the process's own log
//! records on the graph's `log` topic ([`log`]).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod log;
pub mod node;
pub mod poller;
pub mod ready;
pub mod rt;
pub mod stats;
pub mod wait;
