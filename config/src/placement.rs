//! Where the control-path processes run and which of them may poll (`[graph] wait`,
//! `rt_cpu`, `rt_cpus`): a pure rule of the configuration and the machine's CPU count.
//!
//! A process that polls at a SCHED_FIFO priority keeps its CPU until its input comes or its
//! poll budget ends; every process of lower priority on that CPU waits meanwhile, and a
//! producer of lower priority cannot even produce the input polled for. Hence:
//!
//! * `spin` (poll always) with SCHED_FIFO needs a CPU of its own for each polling process
//!   (bridge, safety, mappers), shared with no other control-path process: otherwise the
//!   configuration is refused, naming `graph.rt_cpus` and `graph.wait`.
//! * `predictive` polls in bounded windows, just before its input is due. A process keeps it
//!   only where its window cannot hold up the process it waits for: that producer runs on
//!   another CPU, or at a higher priority (it preempts the poller). Otherwise the process
//!   falls back to `event`. Along the chain the mapper waits for the bridge (higher), safety
//!   for the mapper (lower), the bridge for safety (lower): on one shared CPU only the mapper
//!   polls.
//! * Without SCHED_FIFO (the normal scheduler shares a CPU fairly), every process waits as
//!   configured.
//!
//! Two processes share a CPU when both are pinned to it, or when one is not pinned and the
//! machine has fewer CPUs than the four control-path processes.

use crate::{ConfigError, GraphSection, RtRole, WaitStrategy};

/// The control-path processes in the order of `rt_cpus`.
pub const RT_CPU_ORDER: [RtRole; 4] = [
    RtRole::Bridge,
    RtRole::Safety,
    RtRole::Mapper,
    RtRole::Joystick,
];

/// The process whose output `role` waits for, if `role` may poll.
fn producer(role: RtRole) -> Option<RtRole> {
    match role {
        RtRole::Mapper => Some(RtRole::Bridge),
        RtRole::Safety => Some(RtRole::Mapper),
        RtRole::Bridge => Some(RtRole::Safety),
        RtRole::Joystick | RtRole::Supervisor => None,
    }
}

fn name(role: RtRole) -> &'static str {
    match role {
        RtRole::Bridge => "bridge",
        RtRole::Safety => "safety",
        RtRole::Mapper => "mapper",
        RtRole::Joystick => "joystick",
        RtRole::Supervisor => "supervisor",
    }
}

fn index(role: RtRole) -> Option<usize> {
    RT_CPU_ORDER.iter().position(|r| *r == role)
}

/// Checks `rt_cpus`: empty or one CPU (0 or more) per control-path process, and not given
/// together with `rt_cpu`.
pub fn check_rt_cpus(g: &GraphSection) -> Result<(), ConfigError> {
    let err = |reason: String| ConfigError::Value {
        key: "graph.rt_cpus".into(),
        reason,
    };
    if g.rt_cpus.is_empty() {
        return Ok(());
    }
    if g.rt_cpus.len() != RT_CPU_ORDER.len() {
        return Err(err(format!(
            "has {} entries; give one CPU each for bridge, safety, mappers and joystick, or []",
            g.rt_cpus.len()
        )));
    }
    if let Some(c) = g.rt_cpus.iter().find(|c| **c < 0) {
        return Err(err(format!("{c} is not a CPU (0 or more)")));
    }
    if g.rt_cpu >= 0 {
        return Err(err(format!(
            "given with graph.rt_cpu = {}; use one of the two",
            g.rt_cpu
        )));
    }
    Ok(())
}

/// A CPU for each control-path process on a machine with `online_cpus` CPUs, so that as
/// many as can poll (`rt_cpus` in [`RT_CPU_ORDER`]): with four or more, one each from the
/// last CPU down; with three, the mapper and the joystick share the first; with two, the
/// bridge has the first and the rest share the last; with one, all share it.
pub fn spread_cpus(online_cpus: usize) -> Vec<i32> {
    let n = online_cpus as i32;
    match online_cpus {
        0 | 1 => vec![0; 4],
        2 => vec![0, 1, 1, 1],
        3 => vec![2, 1, 0, 0],
        _ => vec![n - 1, n - 2, n - 3, n - 4],
    }
}

impl GraphSection {
    /// The CPU `role` is pinned to with `realtime` (`rt_cpus`, else `rt_cpu`), if any.
    pub fn cpu_of(&self, role: RtRole) -> Option<usize> {
        if !self.realtime || role == RtRole::Supervisor {
            return None;
        }
        if let Some(i) = index(role)
            && let Some(c) = self.rt_cpus.get(i)
        {
            return usize::try_from(*c).ok();
        }
        usize::try_from(self.rt_cpu).ok()
    }

    /// Where each control-path process runs and how it waits, on a machine with
    /// `online_cpus` CPUs (see the module's documentation); a `spin` that would starve
    /// another control-path process is refused naming the keys.
    pub fn placement(&self, online_cpus: usize) -> Result<Placement, ConfigError> {
        let mut p = Placement {
            cpus: RT_CPU_ORDER.map(|r| self.cpu_of(r)),
            waits: RT_CPU_ORDER.map(|r| match producer(r) {
                Some(_) => self.wait,
                None => WaitStrategy::Event,
            }),
            notes: Vec::new(),
        };
        if !(self.realtime && self.rt_fifo && self.wait.polls()) {
            return Ok(p);
        }
        let shares = |a: usize, b: usize| match (p.cpus[a], p.cpus[b]) {
            (Some(x), Some(y)) => x == y,
            _ => online_cpus < RT_CPU_ORDER.len(),
        };
        let prio = |r: RtRole| self.rt_priority_of(r).unwrap_or(0);
        for (i, role) in RT_CPU_ORDER.into_iter().enumerate() {
            let Some(from) = producer(role) else {
                continue;
            };
            match self.wait {
                WaitStrategy::Spin => {
                    if let Some(j) = (0..RT_CPU_ORDER.len()).find(|j| *j != i && shares(i, *j)) {
                        return Err(ConfigError::Value {
                            key: "graph.rt_cpus".into(),
                            reason: format!(
                                "with graph.wait = \"spin\" and SCHED_FIFO (graph.realtime, \
                                 graph.rt_fifo) the {} polls at a real-time priority on a CPU \
                                 it shares with the {} ({}; {online_cpus} CPUs online), which it \
                                 would starve: give each control-path process its own CPU in \
                                 graph.rt_cpus, or use graph.wait = \"predictive\" or \"event\"",
                                name(role),
                                name(RT_CPU_ORDER[j]),
                                match (p.cpus[i], p.cpus[j]) {
                                    (Some(c), Some(_)) => format!("both on CPU {c}"),
                                    _ => "not both pinned".to_owned(),
                                }
                            ),
                        });
                    }
                }
                WaitStrategy::Predictive => {
                    let j = index(from).unwrap_or(0);
                    if shares(i, j) && prio(role) > prio(from) {
                        p.waits[i] = WaitStrategy::Event;
                        p.notes.push(format!(
                            "{} waits on events: its poll window would hold up the {} it waits \
                             for (same CPU, lower priority)",
                            name(role),
                            name(from)
                        ));
                    }
                }
                WaitStrategy::Event => {}
            }
        }
        Ok(p)
    }
}

/// Each control-path process's CPU and wait strategy ([`GraphSection::placement`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Placement {
    /// The CPU of each process of [`RT_CPU_ORDER`], if pinned.
    pub cpus: [Option<usize>; 4],
    /// The wait strategy of each process of [`RT_CPU_ORDER`] (the joystick: `event`).
    pub waits: [WaitStrategy; 4],
    /// What was changed from the configuration, and why (one line each).
    pub notes: Vec<String>,
}

impl Placement {
    /// How `role` waits (`event` for the joystick and the supervisor).
    pub fn wait_of(&self, role: RtRole) -> WaitStrategy {
        index(role).map_or(WaitStrategy::Event, |i| self.waits[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use WaitStrategy::{Event, Predictive, Spin};

    fn graph(wait: WaitStrategy, rt_cpu: i32, rt_cpus: &[i32]) -> GraphSection {
        GraphSection {
            wait,
            rt_cpu,
            rt_cpus: rt_cpus.to_vec(),
            ..GraphSection::default()
        }
    }

    #[test]
    fn event_is_unchanged_and_the_joystick_never_polls() {
        let p = graph(Event, 1, &[]).placement(2).unwrap();
        assert_eq!(p.waits, [Event; 4]);
        assert_eq!(p.cpus, [Some(1); 4]);
        let p = graph(Spin, -1, &[0, 1, 2, 3]).placement(4).unwrap();
        assert_eq!(p.waits, [Spin, Spin, Spin, Event]);
        assert_eq!(p.wait_of(RtRole::Supervisor), Event);
        assert!(p.notes.is_empty());
    }

    #[test]
    fn spin_sharing_a_cpu_at_a_real_time_priority_is_refused_naming_the_keys() {
        for (g, cpus) in [
            (graph(Spin, 1, &[]), 2),
            (graph(Spin, -1, &[0, 1, 2, 2]), 4),
            (graph(Spin, -1, &[]), 2),
        ] {
            let e = g.placement(cpus).unwrap_err().to_string();
            assert!(
                e.contains("graph.rt_cpus") && e.contains("graph.wait"),
                "{e}"
            );
        }
        // Unpinned on a machine with a CPU per process, or without SCHED_FIFO: allowed.
        graph(Spin, -1, &[]).placement(4).unwrap();
        let mut g = graph(Spin, 1, &[]);
        g.rt_fifo = false;
        assert_eq!(g.placement(2).unwrap().waits, [Spin, Spin, Spin, Event]);
        g.rt_fifo = true;
        g.realtime = false;
        g.placement(1).unwrap();
    }

    /// On one shared CPU only the mapper keeps polling (it waits for the bridge, which
    /// preempts it); safety and the bridge wait for lower-priority producers and fall back.
    #[test]
    fn predictive_on_shared_cpus_keeps_only_windows_that_cannot_hold_up_their_producer() {
        let p = graph(Predictive, 1, &[]).placement(2).unwrap();
        assert_eq!(p.waits, [Event, Event, Predictive, Event]);
        assert_eq!(p.notes.len(), 2, "{:?}", p.notes);
        // Fewer CPUs than processes and no pinning: the same.
        let p = graph(Predictive, -1, &[]).placement(2).unwrap();
        assert_eq!(p.waits, [Event, Event, Predictive, Event]);
        // Safety on its own CPU: it polls; the bridge shares with the mapper, whose output it
        // does not wait for, and polls too.
        let p = graph(Predictive, -1, &[0, 1, 0, 0]).placement(2).unwrap();
        assert_eq!(p.waits, [Predictive, Predictive, Predictive, Event]);
        // Bridge and safety together: the bridge would hold safety up.
        let p = graph(Predictive, -1, &[0, 0, 1, 1]).placement(2).unwrap();
        assert_eq!(p.waits, [Event, Predictive, Predictive, Event]);
        // A CPU each: everyone polls.
        let p = graph(Predictive, -1, &[0, 1, 2, 3]).placement(4).unwrap();
        assert_eq!(p.waits, [Predictive, Predictive, Predictive, Event]);
        assert!(p.notes.is_empty());
    }

    /// The spread placement lets the bridge and the mapper poll on two CPUs (safety waits
    /// for the mapper beside it on events), and everyone from three CPUs on; spin needs four.
    #[test]
    fn spread_cpus_let_as_many_poll_as_the_machine_allows() {
        let waits = |n: usize, w| {
            let cpus = spread_cpus(n);
            graph(w, -1, &cpus).placement(n).map(|p| p.waits)
        };
        assert_eq!(
            waits(2, Predictive).unwrap(),
            [Predictive, Event, Predictive, Event]
        );
        assert_eq!(
            waits(3, Predictive).unwrap(),
            [Predictive, Predictive, Predictive, Event]
        );
        assert_eq!(
            waits(1, Predictive).unwrap(),
            [Event, Event, Predictive, Event]
        );
        assert!(waits(3, Spin).is_err());
        assert_eq!(waits(8, Spin).unwrap(), [Spin, Spin, Spin, Event]);
        assert_eq!(spread_cpus(8), [7, 6, 5, 4]);
    }

    #[test]
    fn rt_cpus_is_one_cpu_per_process_and_excludes_rt_cpu() {
        check_rt_cpus(&graph(Event, -1, &[])).unwrap();
        check_rt_cpus(&graph(Event, -1, &[0, 1, 0, 1])).unwrap();
        for g in [
            graph(Event, -1, &[0, 1]),
            graph(Event, -1, &[0, 1, -1, 1]),
            graph(Event, 0, &[0, 1, 0, 1]),
        ] {
            let e = check_rt_cpus(&g).unwrap_err().to_string();
            assert!(e.contains("graph.rt_cpus"), "{e}");
        }
        let g = graph(Event, -1, &[3, 2, 1, 0]);
        assert_eq!(g.cpu_of(RtRole::Bridge), Some(3));
        assert_eq!(g.cpu_of(RtRole::Joystick), Some(0));
        assert_eq!(g.cpu_of(RtRole::Supervisor), None);
    }
}
