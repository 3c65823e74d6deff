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
//!
//! A polling wait at real-time settings with no CPUs given (`rt_cpus = []`, `rt_cpu = -1`)
//! and `rt_auto_pin` (the default) pins the processes itself ([`MachineCpus::auto_cpus`]): from the CPUs the kernel isolates
//! (`isolcpus=`, `/sys/devices/system/cpu/isolated`) where it has any, else from the last
//! CPUs, one each where there are four, so that as many as can poll.

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

/// The machine's CPUs as the placement sees them.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct MachineCpus {
    /// CPUs online.
    pub online: usize,
    /// CPUs the kernel keeps other work off (`isolcpus=`; `/sys/devices/system/cpu/isolated`),
    /// ascending.
    pub isolated: Vec<usize>,
}

impl MachineCpus {
    /// A machine with `online` CPUs and none isolated.
    pub fn online(online: usize) -> Self {
        Self {
            online,
            isolated: Vec::new(),
        }
    }

    /// The CPUs a polling control path is pinned to when the configuration names none
    /// (`rt_cpus` in [`RT_CPU_ORDER`]): [`spread_cpus`] over the isolated CPUs where the
    /// kernel isolates any (the pattern on their count, the last of them first), else over
    /// all the online CPUs.
    pub fn auto_cpus(&self) -> Vec<i32> {
        if self.isolated.is_empty() {
            return spread_cpus(self.online);
        }
        spread_cpus(self.isolated.len())
            .into_iter()
            .map(|i| {
                let k = usize::try_from(i).unwrap_or(0);
                self.isolated
                    .get(k)
                    .and_then(|c| i32::try_from(*c).ok())
                    .unwrap_or(0)
            })
            .collect()
    }
}

/// Parses a kernel CPU list (`/sys/devices/system/cpu/isolated`: `2-5,7`, empty for none).
pub fn parse_cpu_list(text: &str) -> Result<Vec<usize>, String> {
    let mut cpus = Vec::new();
    for part in text
        .trim()
        .split(',')
        .map(str::trim)
        .filter(|p| !p.is_empty())
    {
        let num = |s: &str| {
            s.trim()
                .parse::<usize>()
                .map_err(|_| format!("`{part}` is not a CPU or a range of CPUs"))
        };
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(a)?, num(b)?);
                if b < a || b - a > 4096 {
                    return Err(format!("`{part}` is not an ascending range of CPUs"));
                }
                cpus.extend(a..=b);
            }
            None => cpus.push(num(part)?),
        }
    }
    cpus.sort_unstable();
    cpus.dedup();
    Ok(cpus)
}

impl GraphSection {
    /// Whether the processes pin themselves ([`MachineCpus::auto_cpus`]): a polling wait with
    /// real-time settings, `rt_auto_pin`, and neither `rt_cpus` nor `rt_cpu` given.
    pub fn auto_pins(&self) -> bool {
        self.realtime
            && self.rt_auto_pin
            && self.wait.polls()
            && self.rt_cpus.is_empty()
            && self.rt_cpu < 0
    }

    /// The CPU `role` is pinned to on `machine`: [`GraphSection::cpu_of`], else, where
    /// [`GraphSection::auto_pins`], the machine's [`MachineCpus::auto_cpus`].
    pub fn cpu_on(&self, role: RtRole, machine: &MachineCpus) -> Option<usize> {
        if let Some(c) = self.cpu_of(role) {
            return Some(c);
        }
        if !self.auto_pins() {
            return None;
        }
        let i = index(role)?;
        machine
            .auto_cpus()
            .get(i)
            .and_then(|c| usize::try_from(*c).ok())
    }

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

    /// Where each control-path process runs and how it waits on `machine` (see the module's
    /// documentation); a `spin` that would starve another control-path process is refused
    /// naming the keys.
    pub fn placement(&self, machine: &MachineCpus) -> Result<Placement, ConfigError> {
        let online_cpus = machine.online;
        let mut p = Placement {
            cpus: RT_CPU_ORDER.map(|r| self.cpu_on(r, machine)),
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
        let p = graph(Event, 1, &[])
            .placement(&MachineCpus::online(2))
            .unwrap();
        assert_eq!(p.waits, [Event; 4]);
        assert_eq!(p.cpus, [Some(1); 4]);
        let p = graph(Spin, -1, &[0, 1, 2, 3])
            .placement(&MachineCpus::online(4))
            .unwrap();
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
            let e = g
                .placement(&MachineCpus::online(cpus))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("graph.rt_cpus") && e.contains("graph.wait"),
                "{e}"
            );
        }
        // Unpinned on a machine with a CPU per process, or without SCHED_FIFO: allowed.
        graph(Spin, -1, &[])
            .placement(&MachineCpus::online(4))
            .unwrap();
        let mut g = graph(Spin, 1, &[]);
        g.rt_fifo = false;
        assert_eq!(
            g.placement(&MachineCpus::online(2)).unwrap().waits,
            [Spin, Spin, Spin, Event]
        );
        g.rt_fifo = true;
        g.realtime = false;
        g.placement(&MachineCpus::online(1)).unwrap();
    }

    /// On one shared CPU only the mapper keeps polling (it waits for the bridge, which
    /// preempts it); safety and the bridge wait for lower-priority producers and fall back.
    #[test]
    fn predictive_on_shared_cpus_keeps_only_windows_that_cannot_hold_up_their_producer() {
        let p = graph(Predictive, 1, &[])
            .placement(&MachineCpus::online(2))
            .unwrap();
        assert_eq!(p.waits, [Event, Event, Predictive, Event]);
        assert_eq!(p.notes.len(), 2, "{:?}", p.notes);
        // No CPUs given: pinned as spread_cpus would (the bridge alone on CPU 0), so the
        // bridge polls too.
        let p = graph(Predictive, -1, &[])
            .placement(&MachineCpus::online(2))
            .unwrap();
        assert_eq!(p.cpus, [Some(0), Some(1), Some(1), Some(1)]);
        assert_eq!(p.waits, [Predictive, Event, Predictive, Event]);
        // Safety on its own CPU: it polls; the bridge shares with the mapper, whose output it
        // does not wait for, and polls too.
        let p = graph(Predictive, -1, &[0, 1, 0, 0])
            .placement(&MachineCpus::online(2))
            .unwrap();
        assert_eq!(p.waits, [Predictive, Predictive, Predictive, Event]);
        // Bridge and safety together: the bridge would hold safety up.
        let p = graph(Predictive, -1, &[0, 0, 1, 1])
            .placement(&MachineCpus::online(2))
            .unwrap();
        assert_eq!(p.waits, [Event, Predictive, Predictive, Event]);
        // A CPU each: everyone polls.
        let p = graph(Predictive, -1, &[0, 1, 2, 3])
            .placement(&MachineCpus::online(4))
            .unwrap();
        assert_eq!(p.waits, [Predictive, Predictive, Predictive, Event]);
        assert!(p.notes.is_empty());
    }

    /// The spread placement lets the bridge and the mapper poll on two CPUs (safety waits
    /// for the mapper beside it on events), and everyone from three CPUs on; spin needs four.
    #[test]
    fn spread_cpus_let_as_many_poll_as_the_machine_allows() {
        let waits = |n: usize, w| {
            let cpus = spread_cpus(n);
            graph(w, -1, &cpus)
                .placement(&MachineCpus::online(n))
                .map(|p| p.waits)
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

    /// With a polling wait and no CPUs given, the processes pin themselves: on the isolated
    /// CPUs where the kernel has any, else on the last ones; never with `event`, with CPUs
    /// given, or without real-time settings.
    #[test]
    fn a_polling_path_without_cpus_given_takes_the_isolated_or_the_last_cpus() {
        let m = MachineCpus {
            online: 16,
            isolated: parse_cpu_list("4-7,12\n").unwrap(),
        };
        assert_eq!(m.isolated, [4, 5, 6, 7, 12]);
        assert_eq!(m.auto_cpus(), [12, 7, 6, 5]);
        assert_eq!(MachineCpus::online(16).auto_cpus(), [15, 14, 13, 12]);
        let two = MachineCpus {
            online: 8,
            isolated: vec![2, 3],
        };
        assert_eq!(two.auto_cpus(), [2, 3, 3, 3]);
        let p = graph(Predictive, -1, &[]).placement(&m).unwrap();
        assert_eq!(p.cpus, [Some(12), Some(7), Some(6), Some(5)]);
        assert_eq!(p.waits, [Predictive, Predictive, Predictive, Event]);
        let p = graph(Spin, -1, &[])
            .placement(&MachineCpus::online(4))
            .unwrap();
        assert_eq!(p.cpus, [Some(3), Some(2), Some(1), Some(0)]);
        // Not with event, nor with CPUs given, nor without real-time settings.
        assert_eq!(graph(Event, -1, &[]).placement(&m).unwrap().cpus, [None; 4]);
        let given = graph(Predictive, -1, &[0, 1, 2, 3]).placement(&m).unwrap();
        assert_eq!(given.cpus, [Some(0), Some(1), Some(2), Some(3)]);
        let mut off = graph(Predictive, -1, &[]);
        off.realtime = false;
        assert_eq!(off.placement(&m).unwrap().cpus, [None; 4]);
        let mut off = graph(Predictive, -1, &[]);
        off.rt_auto_pin = false;
        assert_eq!(off.placement(&m).unwrap().cpus, [None; 4]);
        // The kernel's list: ranges, singles, blanks; anything else is an error.
        assert_eq!(parse_cpu_list("").unwrap(), Vec::<usize>::new());
        assert_eq!(parse_cpu_list("3,1-2").unwrap(), [1, 2, 3]);
        assert!(parse_cpu_list("a-b").is_err());
        assert!(parse_cpu_list("5-2").is_err());
    }
}
