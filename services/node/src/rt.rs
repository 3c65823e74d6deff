//! Real-time settings for the control-path processes: each asks, once initialised, for
//! SCHED_FIFO at its priority, locks its memory and optionally pins itself to a CPU, and says
//! in one line what it got.

use crate::config::{GraphSection, RtRole};

/// Applies the real-time settings of `role` from the `[graph]` table; logs the outcome and
/// returns it as one line (empty when real-time is off).
pub fn elevate(graph: &GraphSection, role: RtRole) -> String {
    let Some(priority) = graph.rt_priority_of(role) else {
        return String::new();
    };
    let rt = hw_bridge::clock::request_realtime(priority);
    let mut line = rt.summary();
    let mut ok = rt.fifo.is_ok() && rt.mlock.is_ok();
    if graph.rt_cpu >= 0 && role != RtRole::Supervisor {
        match pin_to_cpu(graph.rt_cpu as usize) {
            Ok(()) => line.push_str(&format!("; pinned to CPU {}", graph.rt_cpu)),
            Err(e) => {
                ok = false;
                line.push_str(&format!("; not pinned to CPU {} ({e})", graph.rt_cpu));
            }
        }
    }
    if ok {
        tracing::info!("real-time: {line}");
    } else {
        tracing::warn!("real-time not fully available: {line}");
    }
    line
}

/// Pins the calling process to `cpu`.
pub fn pin_to_cpu(cpu: usize) -> std::io::Result<()> {
    use nix::sched::{CpuSet, sched_setaffinity};
    use nix::unistd::Pid;
    if cpu >= CpuSet::count() {
        return Err(std::io::Error::from(std::io::ErrorKind::InvalidInput));
    }
    let mut set = CpuSet::new();
    set.set(cpu)?;
    sched_setaffinity(Pid::from_raw(0), &set)?;
    Ok(())
}
