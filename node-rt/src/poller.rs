//! The one way a control-path loop polls for its input before its event wait
//! (`[graph] wait`): [`Poller`] holds the strategy, the input's learned [`Phase`], the
//! fall-back and the polling figures; the loops of the mapper, safety and the bridge each own
//! one and know nothing else about waiting. A new wait strategy is a change here and in
//! [`crate::wait`].

use ipc_types::time::now_ns;
use transport::Pollable;

use crate::wait::{MARGIN_NS, Monotonic, Phase, Poll, SpinStats, WaitStrategy, wait_input};

/// When the input's tick starts, for placing the poll window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TickStart {
    /// Not known to the caller: the next tick on the grid learned from the inputs' stamps
    /// (the mapper, safety).
    Grid,
    /// Known (ns): the bridge, which published the tick's state itself.
    At(u64),
}

/// What one [`Poller::poll`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Polled {
    /// Nothing: the strategy does not poll now (the event wait only).
    Skipped,
    /// The input came: the bits of what came (1: the input, 2: the second input).
    Came(u64),
    /// It polled, and nothing came by the window's close or the deadline.
    Nothing,
}

impl Polled {
    /// Whether the input came.
    pub fn came(self) -> bool {
        matches!(self, Self::Came(_))
    }
}

/// How a loop polls for its input: not at all (`event`), in a window learned from the
/// inputs' stamps (`predictive`), or up to the deadline (`spin`).
#[derive(Debug, Clone)]
pub struct Poller {
    wait: WaitStrategy,
    /// When the input is published on the tick grid.
    phase: Phase,
    /// A window passed without the input: the event wait until one is taken.
    awaiting: bool,
    /// Whether a window that passed keeps polling off until the next input is taken (the
    /// mapper, safety) or only for this tick (the bridge).
    sticky_fall_back: bool,
    /// Whether an input that comes before its window opens counts as arriving a margin
    /// before the opening (the mapper: a state carries no stamp of its publication).
    early_arrival: bool,
    /// The input came before the window opened at this time (its event woke the loop).
    early_before: Option<u64>,
    /// The polling figures, logged at the end ([`Poller::log`]).
    pub spin: SpinStats,
}

impl Poller {
    /// A poller for `wait` with ticks of `period_ns`; a window that passes without the input
    /// keeps polling off until an input is taken.
    pub fn new(wait: WaitStrategy, period_ns: u64) -> Self {
        Self {
            wait,
            phase: Phase::new(period_ns),
            awaiting: false,
            sticky_fall_back: true,
            early_arrival: false,
            early_before: None,
            spin: SpinStats::default(),
        }
    }

    /// An input that comes before its window opens is taken as arriving a margin before the
    /// opening, so the window moves earlier until polling measures the arrival (an input with
    /// no stamp of its publication: the robot state).
    pub fn with_early_arrival(mut self) -> Self {
        self.early_arrival = true;
        self
    }

    /// Polls again at the next tick even when this tick's window passed without the input.
    pub fn polling_every_tick(mut self) -> Self {
        self.sticky_fall_back = false;
        self
    }

    /// The strategy.
    pub fn strategy(&self) -> WaitStrategy {
        self.wait
    }

    /// Polls `input` (and, with `spin`, `second`) as the strategy says, until the window
    /// closes or `deadline_ns`; when nothing came, the caller's event wait takes over.
    pub fn poll(
        &mut self,
        start: TickStart,
        deadline_ns: u64,
        input: &dyn Pollable,
        second: Option<&dyn Pollable>,
    ) -> Polled {
        if !self.wait.polls() || self.awaiting {
            return Polled::Skipped;
        }
        let now = now_ns();
        let window = match start {
            TickStart::Grid => self.phase.next_window(now),
            TickStart::At(t) => self.phase.window_at(t),
        };
        let poll = Poll::of(self.wait, window);
        if poll == Poll::No {
            return Polled::Skipped;
        }
        // The notifications of what is taken by polling would wake the next event wait.
        input.consume_notifications();
        let second = second.filter(|_| self.wait == WaitStrategy::Spin);
        if let Some(s) = second {
            s.consume_notifications();
        }
        let w = wait_input(
            poll,
            deadline_ns,
            &mut Monotonic,
            |until| u64::from(input.wait_until(until)),
            || {
                let j = if second.is_some_and(|s| s.has_pending()) {
                    2
                } else {
                    0
                };
                u64::from(input.has_pending()) | j
            },
            |_| 0,
        );
        self.spin.add(&w);
        self.awaiting = self.sticky_fall_back && w.fell_back;
        if self.early_arrival {
            self.early_before = window.filter(|_| w.early).map(|w| w.open_ns);
        }
        if w.ready != 0 {
            Polled::Came(w.ready)
        } else {
            Polled::Nothing
        }
    }

    /// An input of `tick`, whose state was stamped `state_t_ns`, was published (or taken) at
    /// `sent_ns`: learn its phase on the grid, count the tick, poll again from the next.
    pub fn took(&mut self, tick: u64, state_t_ns: u64, sent_ns: u64) {
        let arrived = match self.early_before.take() {
            Some(open) => open.saturating_sub(MARGIN_NS).min(sent_ns),
            None => sent_ns,
        };
        self.phase.observe(tick, state_t_ns, arrived);
        self.spin.ticks += 1;
        self.awaiting = false;
    }

    /// An input came `offset_ns` after its tick's start, where the caller knows that start
    /// (the bridge); the tick is counted by the caller.
    pub fn took_offset(&mut self, offset_ns: i64) {
        self.phase.observe_offset(offset_ns);
        self.awaiting = false;
    }

    /// Logs the polling figures of `process` at its end, if it polled.
    pub fn log(&self, process: &str) {
        if self.wait.polls() {
            self.spin.log(process, self.wait);
        }
    }
}
