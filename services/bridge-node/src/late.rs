//! Whose miss was it: the machine's or the graph's.
//!
//! A tick missed for want of its command is the graph's fault unless the command did come,
//! late, and the chain's own work on it (the mapper's map and the safety filter, as the
//! command's stamps say) would have fitted in the time the chain has on the ideal grid (the
//! tick's ideal start to its command deadline): then the rest of the time went to processes
//! waiting to be run, the bridge among them when it began the tick late, which the graph
//! cannot keep. The bridge's own hold-ups (periods its process slept through) are told apart
//! by its clock, not here.
//!
//! A missed tick whose command never comes is the machine's too when the chain skipped it:
//! the next command of the same mapper came (for a later tick) with the chain's work within
//! the budget. The chain answers every state it is run for, newest first; it leaves one out
//! only when it was not run between that state and the next. A command of another mapper
//! proves nothing (a live swap that loses a tick is the graph's miss), nor does one after
//! more than [`SKIP_MAX`] ticks the bridge began on time and got no command for (a chain
//! silent while the bridge runs is a mapper or safety that died and came back under the
//! same id, not one the machine held up: a held-up machine holds the bridge up too, and the
//! ticks it loses that way are not counted here).

use std::collections::VecDeque;

use ipc_types::SafeCommand;

/// How long after its deadline a late command is still matched (ns), whatever the rate.
const KEEP_NS: u64 = 1_000_000_000;
/// A command after at most this many missed ticks in a row that never got their own (the
/// bridge on time for each) can settle those misses as the machine's.
pub const SKIP_MAX: usize = 2;
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
    /// The mapper of the last command received before the miss.
    mapper_before: Option<u32>,
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
    /// No command came for the tick: the chain answered a later state first (the stamps
    /// are that later command's; `late_ns` is 0).
    pub skipped: bool,
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
    /// The mapper of the last command received.
    last_mapper: Option<u32>,
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
            mapper_before: self.last_mapper,
        });
    }

    /// Takes in any command received (on time or not): the missed ticks before its tick
    /// whose commands never came are settled. Where the command is of the mapper that
    /// commanded before the miss, a verdict on each goes to `out` ([`Verdict::skipped`]);
    /// otherwise they stay the graph's, with no verdict. Call after [`Self::arrived`].
    pub fn superseded(&mut self, c: &SafeCommand, out: &mut Vec<Verdict>) {
        // Every remembered miss since the last command received: the ticks the chain was
        // silent while the bridge ran on time.
        let silent = self.awaiting.iter().take_while(|a| a.tick < c.tick).count();
        for _ in 0..silent {
            let Some(a) = self.awaiting.pop_front() else {
                break;
            };
            if a.mapper_before == Some(c.mapper_id) && silent <= SKIP_MAX {
                out.push(Verdict {
                    tick: a.tick,
                    late_ns: 0,
                    mapper_wake_ns: c.state_rx_ns.saturating_sub(a.state_t_ns),
                    safety_wake_ns: c.mapper_rx_ns.saturating_sub(c.mapper_t_ns),
                    work_ns: c.mapper_compute_ns.saturating_add(c.compute_ns),
                    budget_ns: a.deadline_ns.saturating_sub(a.ideal_ns),
                    skipped: true,
                });
            }
        }
        self.last_mapper = Some(c.mapper_id);
    }

    /// How many missed ticks still wait for their commands.
    pub fn awaiting(&self) -> usize {
        self.awaiting.len()
    }

    /// Takes in a command that came for another tick than the bridge's current one: the
    /// verdict on its own tick, if that was a missed one ([`Self::arrived`]), and on the
    /// misses before it ([`Self::superseded`]), into `out`.
    pub fn other_tick(&mut self, c: &SafeCommand, out: &mut Vec<Verdict>) {
        out.extend(self.arrived(c));
        self.superseded(c, out);
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
            skipped: false,
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

    #[test]
    fn a_tick_the_chain_skipped_is_the_machines_when_the_same_mapper_goes_on() {
        let mut l = LateCommands::default();
        let mut out = Vec::new();
        let mut on_time = late(9, 75 * MS, 100_000);
        on_time.mapper_id = 4;
        l.superseded(&on_time, &mut out);
        l.missed(10, 100 * MS, 100 * MS, 115 * MS);
        // No command for tick 10 ever; tick 11's comes, from the same mapper, woken 30 ms
        // after tick 10's state with 100 µs of work.
        let mut next = late(11, 130 * MS, 100_000);
        next.mapper_id = 4;
        assert_eq!(l.arrived(&next), None);
        l.superseded(&next, &mut out);
        assert_eq!(out.len(), 1);
        let v = out[0];
        assert!(v.skipped && v.held_up(), "{v:?}");
        assert_eq!((v.tick, v.mapper_wake_ns, v.late_ns), (10, 30 * MS, 0));
        // Settled once.
        l.superseded(&next, &mut out);
        assert_eq!(out.len(), 1);
    }

    #[test]
    fn a_tick_skipped_around_a_change_of_mapper_or_by_slow_work_is_the_graphs() {
        let mut l = LateCommands::default();
        let mut out = Vec::new();
        let mut before = late(9, 75 * MS, 100_000);
        before.mapper_id = 1;
        l.superseded(&before, &mut out);
        l.missed(10, 100 * MS, 100 * MS, 115 * MS);
        let mut swapped = late(11, 125 * MS, 100_000);
        swapped.mapper_id = 2;
        l.superseded(&swapped, &mut out);
        assert!(out.is_empty(), "a swap that loses a tick: {out:?}");
        l.missed(12, 150 * MS, 150 * MS, 165 * MS);
        let mut slow = late(13, 150 * MS, 20 * MS);
        slow.mapper_id = 2;
        l.superseded(&slow, &mut out);
        assert_eq!(out.len(), 1);
        assert!(out[0].skipped && !out[0].held_up(), "{:?}", out[0]);
        // A mapper back after a restart (same id, three ticks missed on time) proves
        // nothing.
        for t in 20..23 {
            l.missed(t, t * 25 * MS, t * 25 * MS, t * 25 * MS + 15 * MS);
        }
        let mut back = late(30, 750 * MS, 100_000);
        back.mapper_id = 2;
        l.superseded(&back, &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        // Ticks the bridge itself lost in between are not the chain's silence: a command
        // eight ticks after one on-time miss still settles it.
        l.missed(40, 1000 * MS, 1000 * MS, 1015 * MS);
        let mut after = late(48, 1200 * MS, 100_000);
        after.mapper_id = 2;
        l.superseded(&after, &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert!(out[1].held_up());
    }
}
