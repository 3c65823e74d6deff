//! How a control-path process waits for its input (`[graph] wait`): the pure parts, driven
//! by the loops of the mapper, safety and the bridge.
//!
//! * `event`: the process sleeps until the publisher's notification (the loop's own wait).
//! * `predictive`: the tick grid is known (the bridge is the only clock), so [`Phase`] learns
//!   from the messages' own stamps when the input is published relative to its tick's start
//!   (the robot state's `t_ns`), keeps the last [`WINDOW`] offsets, and gives a poll window:
//!   it opens a guard before the earliest offset and lasts a budget derived from their spread
//!   (at most [`BUDGET_SHARE`] of a period). [`wait_input`] sleeps until the window opens (with
//!   the input's event armed and a nanosecond timeout, so an early input still wakes it),
//!   polls the subscriber in a bounded busy loop until the window closes, then falls back to
//!   the event wait.
//! * `spin`: [`wait_input`] polls until the input comes or the wait's deadline.
//!
//! Whatever the strategy, a wait never lasts past its deadline: an input that does not come
//! is left to the event wait, and the bridge counts the tick missed at its command deadline
//! (`the_input_that_never_comes_falls_back_to_the_event_and_ends_at_the_deadline`).

pub use scl_config::WaitStrategy;

/// How many recent offsets [`Phase`] keeps.
pub const WINDOW: usize = 32;

/// How many offsets [`Phase`] needs before it predicts (until then: the event wait).
pub const MIN_SAMPLES: usize = 8;

/// Fixed part of the guard (ns): the wake-up's own latency on the absolute clock.
pub const MARGIN_NS: u64 = 20_000;

/// The poll budget is at most this share of a period ...
pub const BUDGET_SHARE: f64 = 0.125;

/// ... and at most this long (ns): an input whose arrival spreads wider is not worth polling
/// for, the event wait takes it.
pub const MAX_BUDGET_NS: u64 = 1_000_000;

/// The quantiles of the offsets that place the window: it opens a guard before the low one
/// and covers up to the high one (a stray early or late arrival does not stretch it).
pub const LOW_Q: f64 = 0.1;
/// See [`LOW_Q`].
pub const HIGH_Q: f64 = 0.9;

/// A poll window on the monotonic clock (ns).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// When to start polling.
    pub open_ns: u64,
    /// When to stop polling and fall back to the event wait.
    pub close_ns: u64,
}

/// The arrival phase of one input relative to the tick grid, learned from the messages'
/// stamps: each message names its tick `k` and carries its state's stamp `t_k`. The bridge's
/// ticks start on an ideal grid `origin + k·P` and are stamped when it wakes, a little late,
/// so the grid's origin is the least `t_k − k·P` of the recent ticks; an input's offset is
/// its publication stamp less its tick's start on that grid.
#[derive(Debug, Clone)]
pub struct Phase {
    period_ns: u64,
    offsets: [i64; WINDOW],
    origins: [i64; WINDOW],
    len: usize,
    next: usize,
    /// The newest tick seen.
    last_tick: Option<u64>,
}

impl Phase {
    /// An empty phase for ticks of `period_ns`.
    pub fn new(period_ns: u64) -> Self {
        Self {
            period_ns: period_ns.max(1),
            offsets: [0; WINDOW],
            origins: [0; WINDOW],
            len: 0,
            next: 0,
            last_tick: None,
        }
    }

    fn grid(&self, tick: u64) -> i64 {
        (tick as i64).wrapping_mul(self.period_ns as i64)
    }

    /// The grid's origin: the least `t_k − k·P` kept.
    fn origin(&self) -> Option<i64> {
        self.origins[..self.len].iter().copied().min()
    }

    /// Takes a message of `tick`, whose state was stamped `state_t_ns`, published at
    /// `sent_ns`. An older tick than the newest seen changes nothing.
    pub fn observe(&mut self, tick: u64, state_t_ns: u64, sent_ns: u64) {
        if self.last_tick.is_some_and(|k| tick <= k) {
            return;
        }
        self.last_tick = Some(tick);
        self.origins[self.next] = state_t_ns as i64 - self.grid(tick);
        let origin = self.origins[..self.len.max(self.next + 1)]
            .iter()
            .copied()
            .min()
            .unwrap_or(0);
        self.offsets[self.next] = sent_ns as i64 - (origin + self.grid(tick));
        self.next = (self.next + 1) % WINDOW;
        self.len = (self.len + 1).min(WINDOW);
    }

    /// Takes one offset (ns) of an input after its own tick's start, where the caller knows
    /// that start (the bridge, from its own state); the grid is not used.
    pub fn observe_offset(&mut self, offset_ns: i64) {
        self.offsets[self.next] = offset_ns;
        self.next = (self.next + 1) % WINDOW;
        self.len = (self.len + 1).min(WINDOW);
    }

    /// The window relative to a tick's start: (open offset, budget) in ns, once enough
    /// offsets are known. With `lo`, `mid`, `hi` the [`LOW_Q`], median and [`HIGH_Q`]
    /// offsets: the guard is `mid − lo` plus [`MARGIN_NS`], the window opens a guard before
    /// `lo` and lasts until a guard after `hi`, at most [`BUDGET_SHARE`] of a period and
    /// [`MAX_BUDGET_NS`].
    pub fn relative(&self) -> Option<(i64, u64)> {
        if self.len < MIN_SAMPLES {
            return None;
        }
        let mut s = self.offsets;
        let s = &mut s[..self.len];
        s.sort_unstable();
        let at = |q: f64| s[((s.len() - 1) as f64 * q).round() as usize];
        let (lo, mid, hi) = (at(LOW_Q), at(0.5), at(HIGH_Q));
        let guard = (mid - lo) as u64 + MARGIN_NS;
        let cap = ((self.period_ns as f64 * BUDGET_SHARE) as u64).min(MAX_BUDGET_NS);
        let budget = ((hi - lo) as u64 + 2 * guard).min(cap);
        Some((lo - guard as i64, budget))
    }

    /// The window for the tick that starts at `start_ns`.
    pub fn window_at(&self, start_ns: u64) -> Option<Window> {
        let (open, budget) = self.relative()?;
        let open_ns = (start_ns as i64).saturating_add(open).max(0) as u64;
        Some(Window {
            open_ns,
            close_ns: open_ns + budget,
        })
    }

    /// The window of the tick after the newest seen, on the grid; if it has closed by
    /// `now_ns`, the first one after that has not.
    pub fn next_window(&self, now_ns: u64) -> Option<Window> {
        let k = self.last_tick?;
        let start = self.origin()? + self.grid(k + 1);
        let w = self.window_at(start.max(0) as u64)?;
        if w.close_ns > now_ns {
            return Some(w);
        }
        let periods = (now_ns - w.close_ns) / self.period_ns + 1;
        let shift = periods * self.period_ns;
        Some(Window {
            open_ns: w.open_ns + shift,
            close_ns: w.close_ns + shift,
        })
    }
}

/// The clock a wait runs on (the monotonic clock; a fake one in tests).
pub trait WaitClock {
    /// Now (ns).
    fn now_ns(&mut self) -> u64;
}

/// `CLOCK_MONOTONIC`.
#[derive(Debug, Default, Clone, Copy)]
pub struct Monotonic;

impl WaitClock for Monotonic {
    fn now_ns(&mut self) -> u64 {
        ipc_types::time::now_ns()
    }
}

/// How one wait polls: not at all, in a window, or until the deadline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Poll {
    /// The event wait only.
    No,
    /// Sleep until the window opens, poll until it closes, then the event wait.
    In(Window),
    /// Poll until the deadline.
    Always,
}

impl Poll {
    /// The polling of `strategy` with `phase`'s next window (`predictive` without enough
    /// offsets yet: none).
    pub fn of(strategy: WaitStrategy, window: Option<Window>) -> Self {
        match (strategy, window) {
            (WaitStrategy::Spin, _) => Self::Always,
            (WaitStrategy::Predictive, Some(w)) => Self::In(w),
            _ => Self::No,
        }
    }
}

/// What one wait did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Waited {
    /// What `ready` returned last (0: nothing came by the deadline, or the event wait ended
    /// without it).
    pub ready: u64,
    /// Time spent polling (ns).
    pub spin_ns: u64,
    /// Whether the input was found by polling.
    pub by_poll: bool,
    /// Whether the wait fell back to the event wait (a poll window passed without input).
    pub fell_back: bool,
    /// Whether the input came before the window opened (its event woke the sleep).
    pub early: bool,
}

/// Waits for an input until `deadline_ns`: `sleep(until_ns)` sleeps until the window opens
/// (a `ppoll` on the input's event with a nanosecond timeout, so an input earlier than
/// predicted still wakes the process at once; non-zero: it came), `ready` polls the
/// subscriber (non-zero: what came), `event(until_ns)` is the loop's own event wait, here
/// until the deadline. Never waits past the deadline: an input that has not come by then is
/// the caller's miss.
pub fn wait_input(
    poll: Poll,
    deadline_ns: u64,
    clock: &mut impl WaitClock,
    mut sleep: impl FnMut(u64) -> u64,
    mut ready: impl FnMut() -> u64,
    mut event: impl FnMut(u64) -> u64,
) -> Waited {
    let mut w = Waited::default();
    let (open, close) = match poll {
        Poll::No => (None, 0),
        Poll::In(win) => (Some(win.open_ns), win.close_ns.min(deadline_ns)),
        Poll::Always => (Some(0), deadline_ns),
    };
    if let Some(open) = open
        && open < close
    {
        if clock.now_ns() < open {
            // An input already there (its notification consumed before this wait) is not
            // slept past.
            let r = ready();
            if r != 0 {
                w.ready = r;
                w.by_poll = true;
                return w;
            }
            let r = sleep(open);
            if r != 0 {
                w.ready = r;
                w.early = true;
                return w;
            }
        }
        let t0 = clock.now_ns();
        let mut now = t0;
        while now < close {
            let r = ready();
            if r != 0 {
                w.ready = r;
                w.by_poll = true;
                break;
            }
            std::hint::spin_loop();
            now = clock.now_ns();
        }
        w.spin_ns = clock.now_ns().saturating_sub(t0);
        if w.by_poll {
            return w;
        }
        w.fell_back = matches!(poll, Poll::In(_));
    }
    if clock.now_ns() < deadline_ns {
        w.ready = event(deadline_ns);
    }
    w
}

/// A process's polling figures, reported in one log line at its end
/// ([`SpinStats::log`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpinStats {
    /// Ticks handled.
    pub ticks: u64,
    /// Time spent polling (ns).
    pub spin_ns: u64,
    /// Inputs found by polling.
    pub polled: u64,
    /// Poll windows that passed without the input (the event wait took over).
    pub fell_back: u64,
    /// Inputs that came before their window opened.
    pub early: u64,
}

impl SpinStats {
    /// Adds one wait.
    pub fn add(&mut self, w: &Waited) {
        self.spin_ns += w.spin_ns;
        self.polled += u64::from(w.by_poll);
        self.fell_back += u64::from(w.fell_back);
        self.early += u64::from(w.early);
    }

    /// Polling time per tick (µs).
    pub fn per_tick_us(&self) -> f64 {
        self.spin_ns as f64 * 1e-3 / self.ticks.max(1) as f64
    }

    /// Logs the figures (`scl bench latency` reads `spin_us_per_tick`).
    pub fn log(&self, process: &str, strategy: WaitStrategy) {
        tracing::info!(
            process = %process,
            wait = %strategy,
            spin_us_per_tick = format!("{:.2}", self.per_tick_us()),
            ticks = self.ticks,
            polled = self.polled,
            fell_back = self.fell_back,
            early = self.early,
            "wait strategy"
        );
    }
}

/// The CPUs online (at least 1).
pub fn online_cpus() -> usize {
    // SAFETY: sysconf reads a system value.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    usize::try_from(n).unwrap_or(1).max(1)
}

/// This machine's CPUs for the placement: the online count and the CPUs the kernel isolates
/// (`/sys/devices/system/cpu/isolated`; none where it cannot be read or parsed, said in the
/// log).
pub fn machine_cpus() -> scl_config::placement::MachineCpus {
    const ISOLATED: &str = "/sys/devices/system/cpu/isolated";
    let isolated = match std::fs::read_to_string(ISOLATED) {
        Ok(text) => scl_config::placement::parse_cpu_list(&text).unwrap_or_else(|e| {
            tracing::warn!("{ISOLATED}: {e}; taken as no isolated CPU");
            Vec::new()
        }),
        Err(_) => Vec::new(),
    };
    let online = online_cpus();
    scl_config::placement::MachineCpus {
        online,
        isolated: isolated.into_iter().filter(|c| *c < online).collect(),
    }
}

/// How `role` waits on this machine ([`scl_config::GraphSection::placement`]): refused when
/// polling would starve another control-path process; says in the log when it falls back to
/// the event and why. A polling process also gets tight timers ([`tight_timers`]).
pub fn strategy_of(
    graph: &scl_config::GraphSection,
    role: scl_config::RtRole,
    process: &str,
) -> Result<WaitStrategy, scl_config::ConfigError> {
    let p = graph.placement(&machine_cpus())?;
    for note in p.notes.iter().filter(|n| n.starts_with(process)) {
        tracing::info!("wait: {note}");
    }
    let w = p.wait_of(role);
    if w.polls() {
        tight_timers();
    }
    Ok(w)
}

/// Lets the calling thread's timers fire as asked (timer slack 1 ns instead of the normal
/// scheduler's 50 µs), so a window opens on time. Best effort.
pub fn tight_timers() {
    let slack_ns: libc::c_ulong = 1;
    // SAFETY: prctl with PR_SET_TIMERSLACK and an integer argument changes only the calling
    // thread's timer slack.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, slack_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::cell::{Cell, RefCell};

    /// A clock that advances by `step` on every reading and jumps on a sleep.
    struct Fake {
        now: Cell<u64>,
        step: u64,
        slept_to: RefCell<Vec<u64>>,
    }

    impl WaitClock for &Fake {
        fn now_ns(&mut self) -> u64 {
            self.now.set(self.now.get() + self.step);
            self.now.get()
        }
    }

    impl Fake {
        fn new(step: u64) -> Self {
            Self {
                now: Cell::new(0),
                step,
                slept_to: RefCell::new(Vec::new()),
            }
        }

        /// A sleep until `ns` that no event ends early.
        fn sleep(&self, ns: u64) -> u64 {
            self.slept_to.borrow_mut().push(ns);
            self.now.set(self.now.get().max(ns));
            0
        }
    }

    const P: u64 = 1_000_000;

    fn learned(offsets: &[i64]) -> Phase {
        let mut ph = Phase::new(P);
        for o in offsets {
            ph.observe_offset(*o);
        }
        ph
    }

    #[test]
    fn the_window_opens_a_guard_before_the_early_offsets_and_its_budget_is_bounded() {
        assert_eq!(learned(&[50_000; 7]).relative(), None);
        let ph = learned(&[50_000; 8]);
        // No spread: the margin alone, on both sides.
        assert_eq!(ph.relative(), Some((30_000, 40_000)));
        let w = ph.window_at(10_000_000).unwrap();
        assert_eq!((w.open_ns, w.close_ns), (10_030_000, 10_070_000));
        // Offsets 40..=80 µs: the 10 % one 40, the median 60, the 90 % one 80; the guard is
        // 20 + 20 µs, the budget 40 + 80 µs.
        let ph = learned(&[
            40_000, 50_000, 60_000, 60_000, 70_000, 80_000, 60_000, 50_000, 40_000, 80_000, 60_000,
        ]);
        assert_eq!(ph.relative(), Some((0, 120_000)));
        // One stray arrival does not move the window.
        let mut stray = vec![50_000; 15];
        stray.push(-5_000_000);
        assert_eq!(learned(&stray).relative(), Some((30_000, 40_000)));
        // A wild spread is cut at an eighth of the period (and at 1 ms); only the newest
        // WINDOW count.
        let mut ph = learned(&[0, 900_000, 0, 900_000, 0, 900_000, 0, 900_000]);
        assert_eq!(ph.relative().unwrap().1, P / 8);
        let mut slow = Phase::new(25_000_000);
        for o in [0, 9_000_000, 0, 9_000_000, 0, 9_000_000, 0, 9_000_000] {
            slow.observe_offset(o);
        }
        assert_eq!(slow.relative().unwrap().1, MAX_BUDGET_NS);
        for _ in 0..WINDOW {
            ph.observe_offset(100_000);
        }
        assert_eq!(ph.relative(), Some((80_000, 40_000)));
    }

    /// The offsets come from the messages' stamps against the bridge's ideal grid, whose
    /// origin is the least `t_k − k·P`: a late tick stamp (its state published late) does
    /// not shift the next window; the next window follows the newest tick, and one that has
    /// closed rolls on by whole periods.
    #[test]
    fn the_phase_is_learned_from_the_stamps_on_the_ideal_grid() {
        let mut ph = Phase::new(P);
        let t0 = 5_000_000;
        for k in 0..10u64 {
            // Tick k stamped 3 µs after its ideal start (tick 4: 700 µs); its message sent
            // 60 µs after the stamp.
            let late = if k == 4 { 700_000 } else { 3_000 };
            let state = t0 + k * P + late;
            ph.observe(k, state, state + 60_000);
        }
        // The grid's origin is t0 + 3 µs: nine offsets of 60 µs, one of 757 µs (not
        // counted: above the 90 % one).
        assert_eq!(ph.relative(), Some((40_000, 40_000)));
        // An older tick changes nothing.
        let before = ph.clone().relative();
        ph.observe(3, 0, 0);
        assert_eq!(ph.relative(), before);
        let start10 = t0 + 10 * P;
        let w = ph.next_window(start10 - 500_000).unwrap();
        assert_eq!(
            (w.open_ns, w.close_ns),
            (start10 + 43_000, start10 + 83_000)
        );
        let later = ph.next_window(start10 + 2 * P).unwrap();
        assert_eq!(later.open_ns, start10 + 2 * P + 43_000);
        assert!(later.close_ns > start10 + 2 * P);
    }

    #[test]
    fn predictive_sleeps_until_the_window_then_takes_the_input_by_polling() {
        let w = Window {
            open_ns: 1_000,
            close_ns: 2_000,
        };
        let c = Fake::new(10);
        let mut polls = 0;
        let got = wait_input(
            Poll::In(w),
            10_000,
            &mut &c,
            |u| c.sleep(u),
            || {
                polls += 1;
                u64::from(polls == 5)
            },
            |_| panic!("no event wait when polling found it"),
        );
        assert_eq!(*c.slept_to.borrow(), [1_000]);
        assert!(got.by_poll && !got.fell_back && got.ready == 1, "{got:?}");
        assert!(got.spin_ns > 0 && got.spin_ns <= 1_000);
        // An input earlier than predicted wakes the sleep: no polling after it.
        let c = Fake::new(10);
        let mut polls = 0;
        let got = wait_input(
            Poll::In(w),
            10_000,
            &mut &c,
            |_| 1,
            || {
                polls += 1;
                0
            },
            |_| 0,
        );
        assert!(got.early && !got.by_poll && got.ready == 1 && got.spin_ns == 0);
        assert_eq!(polls, 1, "one look before the sleep");
        // An input already there is taken before any sleep.
        let c = Fake::new(10);
        let got = wait_input(Poll::In(w), 10_000, &mut &c, |u| c.sleep(u), || 1, |_| 0);
        assert!(got.by_poll && c.slept_to.borrow().is_empty());
    }

    /// The safety rule: the input never comes, so polling ends at the window's close (within
    /// the budget), the event wait takes over up to the deadline and nothing is returned: the
    /// bridge counts the tick missed and executes nothing late.
    #[test]
    fn the_input_that_never_comes_falls_back_to_the_event_and_ends_at_the_deadline() {
        for poll in [
            Poll::In(Window {
                open_ns: 1_000,
                close_ns: 3_000,
            }),
            Poll::Always,
            Poll::No,
        ] {
            let c = Fake::new(7);
            let mut until = Vec::new();
            let got = wait_input(
                poll,
                8_000,
                &mut &c,
                |u| c.sleep(u),
                || 0,
                |u| {
                    until.push(u);
                    0
                },
            );
            assert_eq!(got.ready, 0, "{poll:?}");
            assert!(!got.by_poll && !got.early);
            match poll {
                Poll::In(_) => {
                    assert!(got.fell_back && got.spin_ns <= 2_000 + 14, "{got:?}");
                    assert_eq!(until, [8_000]);
                }
                Poll::Always => {
                    assert!(!got.fell_back && got.spin_ns <= 8_000, "{got:?}");
                    // Polled up to the deadline: no event wait after it.
                    assert!(until.is_empty());
                }
                Poll::No => assert_eq!((got.spin_ns, until.as_slice()), (0, &[8_000][..])),
            }
        }
        // A window that opens after the deadline is not waited for.
        let c = Fake::new(1);
        let w = Window {
            open_ns: 9_000,
            close_ns: 9_500,
        };
        let got = wait_input(Poll::In(w), 8_000, &mut &c, |u| c.sleep(u), || 1, |_| 0);
        assert!(c.slept_to.borrow().is_empty() && !got.by_poll && got.ready == 0);
    }

    #[test]
    fn spin_stats_count_per_tick() {
        let mut s = SpinStats::default();
        s.add(&Waited {
            ready: 1,
            spin_ns: 3_000,
            by_poll: true,
            ..Waited::default()
        });
        s.add(&Waited {
            spin_ns: 1_000,
            fell_back: true,
            ..Waited::default()
        });
        s.ticks = 2;
        assert_eq!((s.polled, s.fell_back), (1, 1));
        assert!((s.per_tick_us() - 2.0).abs() < 1e-12);
    }
}
