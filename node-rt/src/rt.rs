//! Real-time settings for the control-path processes: each asks, once initialised, for
//! SCHED_FIFO at its priority, locks its memory and optionally pins itself to a CPU, and says
//! in one line what it got.

use scl_config::{GraphSection, RtRole};

pub use hw_bridge::clock::lower_priority;

/// Applies the real-time settings of `role` from the `[graph]` table; logs the outcome and
/// returns it as one line (empty when real-time is off).
pub fn elevate(graph: &GraphSection, role: RtRole) -> String {
    let Some(priority) = graph.rt_priority_of(role) else {
        return String::new();
    };
    let rt = hw_bridge::clock::request(graph.rt_fifo.then_some(priority), graph.rt_mlock);
    let mut line = rt.summary();
    let mut ok = rt.ok();
    if let Some(cpu) = graph.cpu_on(role, &crate::wait::machine_cpus()) {
        match pin_to_cpu(cpu) {
            Ok(()) => line.push_str(&format!("; pinned to CPU {cpu}")),
            Err(e) => {
                ok = false;
                line.push_str(&format!("; not pinned to CPU {cpu} ({e})"));
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

/// Holds `[graph] rt_cpu_dma_latency_us` (with `realtime`) for as long as the returned value
/// lives (`scl up` holds it while the graph runs); logs one line saying what was held or why
/// the machine refused it, and returns that line (empty when not asked for).
pub fn hold_dma_latency(graph: &GraphSection) -> (Option<hw_bridge::clock::DmaLatency>, String) {
    if !graph.realtime || graph.rt_cpu_dma_latency_us < 0 {
        return (None, String::new());
    }
    let us = graph.rt_cpu_dma_latency_us;
    match hw_bridge::clock::DmaLatency::hold(us) {
        Ok(h) => {
            let line = format!(
                "{} held at {us} µs while the graph runs",
                hw_bridge::clock::CPU_DMA_LATENCY
            );
            tracing::info!("real-time: {line}");
            (Some(h), line)
        }
        Err(e) => {
            let line = format!(
                "{} not held at {us} µs ({e}); idle CPUs may sleep deeply between ticks",
                hw_bridge::clock::CPU_DMA_LATENCY
            );
            tracing::warn!("real-time not fully available: {line}");
            (None, line)
        }
    }
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
