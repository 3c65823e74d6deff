//! Each graph process's CPU time per tick: the processes are found by their heartbeats'
//! `pid` (the supervisor by its child id) and read through their CPU-time clocks
//! (`clock_getcpuclockid`: user + system time of every thread, in ns, where `/proc/PID/stat`
//! counts 10 ms clock ticks).

use ipc_types::{NodeRole, NodeStatus};

/// A process's CPU time so far (ns), or `None` once it is gone (or not ours to read).
pub fn cpu_ns(pid: u32) -> Option<u64> {
    let pid = i32::try_from(pid).ok()?;
    let clock = nix::time::clock_getcpuclockid(nix::unistd::Pid::from_raw(pid)).ok()?;
    let t = nix::time::clock_gettime(clock).ok()?;
    u64::try_from(t.tv_sec())
        .ok()?
        .checked_mul(1_000_000_000)?
        .checked_add(u64::try_from(t.tv_nsec()).ok()?)
}

/// A process's memory, from `/proc/PID/status` (KiB).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Memory {
    /// Resident now (`VmRSS`).
    pub rss_kib: u64,
    /// The most ever resident (`VmHWM`).
    pub peak_rss_kib: u64,
    /// Locked in memory (`VmLck`: all of it after `mlockall`).
    pub locked_kib: u64,
    /// Minor page faults between the first and the latest reading of the run (a page mapped
    /// without reading the disk; `/proc/PID/stat`).
    pub minor_faults: u64,
    /// Major page faults between the first and the latest reading (a page read from disk).
    pub major_faults: u64,
}

/// A process's page faults so far, (minor, major), from `/proc/PID/stat`; `None` once it is
/// gone.
pub fn faults(pid: u32) -> Option<(u64, u64)> {
    parse_stat_faults(&std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?)
}

/// Fields 10 (`minflt`) and 12 (`majflt`) of a `/proc/PID/stat` line; the command name (field
/// 2) is in parentheses and may hold spaces, so the count starts after its last `)`.
fn parse_stat_faults(text: &str) -> Option<(u64, u64)> {
    let rest = &text[text.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // After the name: field 3 (state) is index 0, so field N is index N - 3.
    Some((fields.get(7)?.parse().ok()?, fields.get(9)?.parse().ok()?))
}

/// A process's memory now, or `None` once it is gone (or not ours to read).
pub fn memory(pid: u32) -> Option<Memory> {
    parse_status(&std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?)
}

fn parse_status(text: &str) -> Option<Memory> {
    let field = |key: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
    };
    Some(Memory {
        rss_kib: field("VmRSS:")?,
        peak_rss_kib: field("VmHWM:")?,
        locked_kib: field("VmLck:").unwrap_or(0),
        minor_faults: 0,
        major_faults: 0,
    })
}

#[derive(Debug, Clone)]
struct Watched {
    name: &'static str,
    pid: u32,
    /// Memory at the latest reading.
    mem: Option<Memory>,
    /// Page faults (minor, major) at the first and at the latest reading.
    faults: Option<((u64, u64), (u64, u64))>,
    /// (CPU ns, ticks seen) at the first and at the latest reading.
    first: Option<(u64, u64)>,
    last: Option<(u64, u64)>,
}

impl Watched {
    /// Process `pid`, not read yet.
    fn new(name: &'static str, pid: u32) -> Self {
        Self {
            name,
            pid,
            mem: None,
            faults: None,
            first: None,
            last: None,
        }
    }
}

/// The processes of one run and their CPU readings.
#[derive(Debug, Clone)]
pub struct CpuWatch {
    procs: Vec<Watched>,
}

/// The order processes are reported in: the control path from the clock back, then the
/// supervisor.
pub const ORDER: [&str; 6] = [
    "bridge",
    "safety",
    "mapper",
    "joystick",
    "gateway",
    "supervisor",
];

impl CpuWatch {
    /// Watches the supervisor (`scl up`, process `supervisor_pid`) and every control-path
    /// process that sends a heartbeat.
    pub fn new(supervisor_pid: u32) -> Self {
        Self {
            procs: vec![Watched::new("supervisor", supervisor_pid)],
        }
    }

    /// Takes a heartbeat: a new process (or a restarted one) is watched from the next reading.
    pub fn heartbeat(&mut self, s: &NodeStatus) {
        let name = match NodeRole::from_u32(s.role) {
            Some(NodeRole::Bridge) => "bridge",
            Some(NodeRole::Safety) => "safety",
            Some(NodeRole::Mapper) => "mapper",
            Some(NodeRole::Joystick) => "joystick",
            Some(NodeRole::Gateway) => "gateway",
            _ => return,
        };
        match self.procs.iter_mut().find(|p| p.name == name) {
            Some(p) if p.pid == s.pid => {}
            Some(p) => {
                // A restart: the new process's time from its own first reading.
                *p = Watched::new(name, s.pid);
            }
            None => self.procs.push(Watched::new(name, s.pid)),
        }
    }

    /// Reads every watched process's CPU time at `ticks` ticks into the run.
    pub fn read(&mut self, ticks: u64) {
        for p in &mut self.procs {
            if let Some(m) = memory(p.pid) {
                p.mem = Some(m);
            }
            if let Some(f) = faults(p.pid) {
                p.faults = Some((p.faults.map_or(f, |(first, _)| first), f));
            }
            if let Some(ns) = cpu_ns(p.pid) {
                if p.first.is_none() {
                    p.first = Some((ns, ticks));
                } else {
                    p.last = Some((ns, ticks));
                }
            }
        }
    }

    /// CPU time per tick (µs) of each process read at least twice with ticks in between, in
    /// [`ORDER`].
    pub fn per_tick_us(&self) -> Vec<(String, f64)> {
        ORDER
            .iter()
            .filter_map(|name| {
                let p = self.procs.iter().find(|p| p.name == *name)?;
                per_tick_us(p.first?, p.last?).map(|us| ((*name).to_owned(), us))
            })
            .collect()
    }
}

impl CpuWatch {
    /// Each process's memory at its latest reading, in [`ORDER`].
    pub fn memory(&self) -> Vec<(String, Memory)> {
        ORDER
            .iter()
            .filter_map(|name| {
                let p = self.procs.iter().find(|p| p.name == *name)?;
                let mut m = p.mem?;
                if let Some((first, last)) = p.faults {
                    m.minor_faults = last.0.saturating_sub(first.0);
                    m.major_faults = last.1.saturating_sub(first.1);
                }
                Some(((*name).to_owned(), m))
            })
            .collect()
    }
}

/// CPU µs per tick between two (CPU ns, ticks) readings; `None` without ticks in between.
pub fn per_tick_us(first: (u64, u64), last: (u64, u64)) -> Option<f64> {
    let ticks = last.1.checked_sub(first.1).filter(|t| *t > 0)?;
    Some(last.0.saturating_sub(first.0) as f64 / ticks as f64 * 1e-3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_is_read_from_the_status_file_and_our_own_is_there() {
        let m = parse_status("Name:\tscl\nVmHWM:\t  2048 kB\nVmRSS:\t  1024 kB\nVmLck:\t 512 kB\n")
            .unwrap();
        assert_eq!(
            m,
            Memory {
                rss_kib: 1024,
                peak_rss_kib: 2048,
                locked_kib: 512,
                minor_faults: 0,
                major_faults: 0,
            }
        );
        // The name may hold spaces and parentheses; the fields count from its last `)`.
        let stat = "42 (scl (a) b) S 1 42 42 0 -1 4194560 1234 0 5 0 10 2 0 0 20 0 1 0";
        assert_eq!(parse_stat_faults(stat), Some((1234, 5)));
        assert_eq!(parse_stat_faults("42 (scl) S 1"), None);
        let (minor, _) = faults(std::process::id()).unwrap();
        assert!(minor > 0);
        assert_eq!(parse_status("Name:\tkthread\n"), None);
        let own = memory(std::process::id()).unwrap();
        assert!(own.rss_kib > 0 && own.peak_rss_kib >= own.rss_kib);
    }

    #[test]
    fn own_cpu_time_grows_and_per_tick_divides() {
        let me = std::process::id();
        let a = cpu_ns(me).unwrap();
        let mut x = 0u64;
        for i in 0..2_000_000u64 {
            x = std::hint::black_box(x.wrapping_add(i));
        }
        assert!(cpu_ns(me).unwrap() > a);
        assert_eq!(per_tick_us((1_000, 10), (41_000, 50)), Some(1.0));
        assert_eq!(per_tick_us((1_000, 10), (2_000, 10)), None);
        // A pid that is not running.
        assert_eq!(cpu_ns(u32::MAX), None);
    }

    #[test]
    fn processes_are_found_by_heartbeat_and_reported_in_order() {
        let mut w = CpuWatch::new(std::process::id());
        let mut hb = NodeStatus::new(NodeRole::Bridge, ipc_types::phase::RUNNING, 0);
        hb.pid = std::process::id();
        w.heartbeat(&hb);
        w.read(0);
        w.read(100);
        let names: Vec<String> = w.per_tick_us().into_iter().map(|(n, _)| n).collect();
        assert_eq!(names, ["bridge", "supervisor"]);
    }
}
