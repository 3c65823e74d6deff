//! Real-time settings for the control-path processes: each asks, once initialised, for
//! SCHED_FIFO at its priority and locks its memory, and says in one line what it got.

use crate::config::{GraphSection, RtRole};

/// Applies the real-time settings of `role` from the `[graph]` table; logs the outcome.
pub fn elevate(graph: &GraphSection, role: RtRole) {
    let Some(priority) = graph.rt_priority_of(role) else {
        return;
    };
    let rt = hw_bridge::clock::request_realtime(priority);
    if rt.fifo.is_ok() && rt.mlock.is_ok() {
        tracing::info!("real-time: {}", rt.summary());
    } else {
        tracing::warn!("real-time not fully available: {}", rt.summary());
    }
}
