//! The whole-graph tests, one module per subject, in one test binary (one link of the
//! dependency tree instead of one per file). Each test runs real `scl` processes on real
//! shared memory under its own prefix; the tests that run a graph take
//! [`scl_tests::serial`], a process-wide lock, so no two graphs overlap on a small machine.
//!
//! Run one subject: `cargo test -p scl-tests --test whole_graph -- rate::`.
#![allow(clippy::unwrap_used, missing_docs)]

mod bench;
mod deploy;
mod drill;
mod graph;
mod joystick;
mod kortex;
mod live;
mod live_log;
mod live_port;
mod modeswitch;
mod network;
mod rate;
mod recording;
mod replay;
mod restart;
mod safety;
mod study;
mod supervision;
mod wait;
