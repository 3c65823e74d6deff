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
    // SAFETY: a zeroed cpu_set_t is a valid empty set; CPU_SET writes within it for
    // cpu < CPU_SETSIZE (checked); sched_setaffinity reads it.
    unsafe {
        if cpu >= libc::CPU_SETSIZE as usize {
            return Err(std::io::Error::from(std::io::ErrorKind::InvalidInput));
        }
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        if libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set) == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}
