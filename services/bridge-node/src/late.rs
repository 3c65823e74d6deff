//! Whose miss was it: the machine's or the graph's.
//!
//! A tick missed for want of its command is the graph's fault unless the command did come,
//! late, and the chain's own work on it (the mapper's map and the safety filter, as the
//! command's stamps say) would have fitted in the time the chain has on the ideal grid (the
//! tick's ideal start to its command deadline): then the rest of the time went to processes
//! waiting to be run, the bridge among them when it began the tick late, which the graph
//! cannot keep. The bridge's own hold-ups (periods its process slept through) are told apart
//! by its clock, not here.

use std::collections::VecDeque;

use ipc_types::SafeCommand;

/// How long after its deadline a late command is still matched (ns), whatever the rate.
const KEEP_NS: u64 = 1_000_000_000;
/// At most this many missed ticks are remembered (a graph that misses every tick at 1 kHz
/// keeps a quarter of a second of them).
const KEEP_MAX: usize = 256;

/// A missed tick whose command may still come.
#[derive(Debug, Clone, Copy)]
struct Awaiting {
    tick: u64,
    ideal_ns: u64,
    state_t_ns: u64,
    deadline_ns: u64,
}

/// What a late command says about its tick's miss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    /// The missed tick.
    pub tick: u64,
    /// How long after the bridge's command deadline safety published it (ns).
    pub late_ns: u64,
    /// The robot state's publication to the mapper's wake-up (ns).
    pub mapper_wake_ns: u64,
    /// The mapper's publication to safety's wake-up (ns).
    pub safety_wake_ns: u64,
    /// The mapper's and the safety filter's work on it (ns).
    pub work_ns: u64,
    /// The time the chain has on the ideal grid: the tick's ideal start to its command
    /// deadline (ns).
    pub budget_ns: u64,
}

impl Verdict {
    /// The machine took the tick: the chain's own work fitted the budget.
    pub fn held_up(&self) -> bool {
        self.work_ns < self.budget_ns
    }
}

/// The missed ticks of the last [`KEEP_NS`] (at most [`KEEP_MAX`]) whose commands have not
/// come.
#[derive(Debug, Default)]
pub struct LateCommands {
    awaiting: VecDeque<Awaiting>,
}

impl LateCommands {
    /// Notes that `tick` was missed without its command; `ideal_ns` is its start on the
    /// ideal grid, `state_t_ns` when its state went out, `deadline_ns` when its command was
    /// due.
    pub fn missed(&mut self, tick: u64, ideal_ns: u64, state_t_ns: u64, deadline_ns: u64) {
        while self.awaiting.front().is_some_and(|a| {
            a.deadline_ns + KEEP_NS < deadline_ns || self.awaiting.len() >= KEEP_MAX
        }) {
            self.awaiting.pop_front();
        }
        self.awaiting.push_back(Awaiting {
            tick,
            ideal_ns,
            state_t_ns,
            deadline_ns,
        });
    }

    /// Matches a command that came for another tick than the bridge's current one: the
    /// verdict on its tick if that tick was missed and is still remembered (once per tick).
    pub fn arrived(&mut self, c: &SafeCommand) -> Option<Verdict> {
        let i = self.awaiting.iter().position(|a| a.tick == c.tick)?;
        let a = self.awaiting.remove(i)?;
        Some(Verdict {
            tick: a.tick,
            late_ns: c.t_ns.saturating_sub(a.deadline_ns),
            mapper_wake_ns: c.state_rx_ns.saturating_sub(a.state_t_ns),
            safety_wake_ns: c.mapper_rx_ns.saturating_sub(c.mapper_t_ns),
            work_ns: c.mapper_compute_ns.saturating_add(c.compute_ns),
            budget_ns: a.deadline_ns.saturating_sub(a.ideal_ns),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn late(tick: u64, mapper_rx: u64, work: u64) -> SafeCommand {
        let mut c: SafeCommand = zerocopy::FromZeros::new_zeroed();
        c.tick = tick;
        c.state_rx_ns = mapper_rx;
        c.mapper_compute_ns = work / 2;
        c.mapper_t_ns = mapper_rx + work / 2;
        c.mapper_rx_ns = c.mapper_t_ns + 50_000;
        c.compute_ns = work / 2;
        c.t_ns = c.mapper_rx_ns + work / 2;
        c
    }

    #[test]
    fn a_late_command_with_little_work_is_the_machines() {
        let mut l = LateCommands::default();
        // Tick 10's state went out at 100 ms, its command was due at 115 ms; the mapper woke
        // 20 ms late and both steps took 100 µs.
        l.missed(10, 100 * MS, 100 * MS, 115 * MS);
        let v = l.arrived(&late(10, 120 * MS, 100_000)).unwrap();
        assert!(v.held_up(), "{v:?}");
        assert_eq!(v.mapper_wake_ns, 20 * MS);
        assert_eq!(v.budget_ns, 15 * MS);
        assert!(v.late_ns > 5 * MS && v.late_ns < 6 * MS, "{v:?}");
        // Matched once.
        assert_eq!(l.arrived(&late(10, 120 * MS, 100_000)), None);
    }

    #[test]
    fn a_late_command_that_took_its_time_to_compute_is_the_graphs() {
        let mut l = LateCommands::default();
        l.missed(10, 100 * MS, 100 * MS, 115 * MS);
        let v = l.arrived(&late(10, 100 * MS + 50_000, 16 * MS)).unwrap();
        assert!(!v.held_up(), "{v:?}");
        // A tick the bridge began late leaves the chain less time, but the budget is the
        // grid's: 1 ms of work is the machine's, whenever the state went out.
        l.missed(11, 125 * MS, 139 * MS, 140 * MS);
        let v = l.arrived(&late(11, 139 * MS, MS)).unwrap();
        assert!(v.held_up(), "{v:?}");
        assert_eq!(v.budget_ns, 15 * MS);
    }

    #[test]
    fn commands_of_ticks_not_missed_or_long_ago_say_nothing() {
        let mut l = LateCommands::default();
        assert_eq!(l.arrived(&late(3, 0, 0)), None);
        l.missed(10, 100 * MS, 100 * MS, 115 * MS);
        l.missed(20, 350 * MS, 350 * MS, 365 * MS);
        l.missed(30, 600 * MS, 600 * MS, 615 * MS);
        assert!(
            l.arrived(&late(20, 620 * MS, 0)).is_some(),
            "within a second"
        );
        l.missed(90, 1200 * MS, 1200 * MS, 1215 * MS);
        assert_eq!(
            l.arrived(&late(10, 1220 * MS, 0)),
            None,
            "forgotten after a second"
        );
        assert!(l.arrived(&late(30, 1220 * MS, 0)).is_some());
    }
}
