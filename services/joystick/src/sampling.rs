//! When the joystick reads its device: right after each robot state (`[graph] wait =
//! "event"`), or late, a margin before the next tick (`predictive` and `spin`).
//!
//! The mapper maps the newest sample at tick `k`. A sample read when state `k-1` arrived is a
//! whole period old by then (25 ms at 40 Hz), and with real-time priorities the mapper always
//! runs before the joystick answers state `k`, so that period is what the operator feels.
//! [`SampleClock`] places the ticks on the bridge's grid, learned from the states' own stamps
//! and the configured rate (the bridge is the only clock), and says when a sample is due:
//!
//! * [`Due::Late`], `margin` before tick `k`: the device's newest input, answering state
//!   `k-1`, read just before the mapper takes it;
//! * [`Due::Fallback`], half a period after state `k-1`: the answer to it, as today's sample
//!   on arrival but away from the mapper's own tick, so that the sample that serves when the
//!   late one misses is at most half a period old and never races the mapper.
//!
//! A late sample that misses its tick (not published before the tick's state arrived, so the
//! mapper may have taken the one before) is counted ([`SampleClock::missed`], the joystick's
//! heartbeat `held_up`): the fallback serves, and the mapper's rule (the newest sample, stale
//! two ticks behind) is unchanged. [`SampleClock::sent`] also says whether a late sample went
//! out after its tick's start on the grid (it may still have come before the state, which the
//! bridge stamps when it wakes, a little later). Until the grid is known ([`MIN_STATES`]) samples go out on
//! each state's arrival, as with `event`.

/// States seen before the grid is trusted.
pub const MIN_STATES: usize = 4;

/// How many recent states place the grid.
const KEPT: usize = 32;

/// The margin used when `[joystick] sample_margin_us` is 0 (ns)...
pub const AUTO_MARGIN_NS: u64 = 1_000_000;

/// ... at most this share of a period.
pub const AUTO_MARGIN_SHARE: f64 = 0.25;

/// The margin (ns) for `configured_us` (0: [`AUTO_MARGIN_NS`], at most [`AUTO_MARGIN_SHARE`]
/// of `period_ns`).
pub fn margin_ns(configured_us: u32, period_ns: u64) -> u64 {
    if configured_us == 0 {
        AUTO_MARGIN_NS.min((period_ns as f64 * AUTO_MARGIN_SHARE) as u64)
    } else {
        u64::from(configured_us) * 1000
    }
}

/// A sample the clock says is due.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Due {
    /// Half a period after the newest state: the answer that serves if the late one misses.
    Fallback,
    /// The margin before the next tick: the answer the mapper should take.
    Late,
}

/// The tick grid and the samples due on it (all times monotonic ns, as the stamps).
#[derive(Debug, Clone)]
pub struct SampleClock {
    period_ns: u64,
    margin_ns: u64,
    /// `t_k − k·P` of the recent states; the least is the grid's origin (the bridge stamps a
    /// state when it wakes, a little after its tick's start).
    origins: [i64; KEPT],
    len: usize,
    next: usize,
    /// The newest tick seen.
    tick: Option<u64>,
    fallback_sent: bool,
    late_sent: bool,
    missed: u32,
    late: u64,
}

impl SampleClock {
    /// A clock for ticks of `period_ns`, sampling `margin_ns` before each.
    pub fn new(period_ns: u64, margin_ns: u64) -> Self {
        Self {
            period_ns: period_ns.max(1),
            margin_ns: margin_ns.min(period_ns / 2),
            origins: [0; KEPT],
            len: 0,
            next: 0,
            tick: None,
            fallback_sent: false,
            late_sent: false,
            missed: 0,
            late: 0,
        }
    }

    /// Whether the grid is known, so samples go out on it rather than on arrival.
    pub fn learnt(&self) -> bool {
        self.len >= MIN_STATES
    }

    /// Takes state `tick`, stamped `state_t_ns`. A state older than the newest changes
    /// nothing. Counts the previous tick's late sample missed if it never went out.
    pub fn state(&mut self, tick: u64, state_t_ns: u64) {
        if self.tick.is_some_and(|k| tick <= k) {
            return;
        }
        if self.learnt() && self.tick.is_some() && !self.late_sent {
            self.missed = self.missed.saturating_add(1);
        }
        self.tick = Some(tick);
        self.origins[self.next] =
            state_t_ns as i64 - (tick as i64).wrapping_mul(self.period_ns as i64);
        self.next = (self.next + 1) % KEPT;
        self.len = (self.len + 1).min(KEPT);
        self.fallback_sent = false;
        self.late_sent = false;
    }

    /// The start of tick `k` on the grid.
    fn start(&self, k: u64) -> Option<u64> {
        let origin = self.origins[..self.len].iter().copied().min()?;
        Some(
            origin
                .saturating_add((k as i64).wrapping_mul(self.period_ns as i64))
                .max(0) as u64,
        )
    }

    /// When each sample for the newest tick is due: (fallback, late).
    fn times(&self) -> Option<(u64, u64)> {
        if !self.learnt() {
            return None;
        }
        let k = self.tick?;
        let this = self.start(k)?;
        let next = self.start(k + 1)?;
        Some((
            this + self.period_ns / 2,
            next.saturating_sub(self.margin_ns),
        ))
    }

    /// The sample due at `now_ns`, if any (the late one once its time has come, whether or
    /// not the fallback went out).
    pub fn due(&self, now_ns: u64) -> Option<Due> {
        let (fallback, late) = self.times()?;
        if !self.late_sent && now_ns >= late {
            Some(Due::Late)
        } else if !self.fallback_sent && !self.late_sent && now_ns >= fallback {
            Some(Due::Fallback)
        } else {
            None
        }
    }

    /// When the next sample is due (for the loop's wait), if one is still to go out for the
    /// newest tick.
    pub fn next_due_ns(&self) -> Option<u64> {
        let (fallback, late) = self.times()?;
        if self.late_sent {
            None
        } else if self.fallback_sent {
            Some(late)
        } else {
            Some(fallback.min(late))
        }
    }

    /// The sample `due` went out at `now_ns`. Returns whether a late one went out at or
    /// after its tick's start on the grid (not counted: only the state's arrival tells
    /// whether it missed).
    pub fn sent(&mut self, due: Due, now_ns: u64) -> bool {
        match due {
            Due::Fallback => {
                self.fallback_sent = true;
                false
            }
            Due::Late => {
                self.late_sent = true;
                self.fallback_sent = true;
                self.late += 1;
                self.tick
                    .and_then(|k| self.start(k + 1))
                    .is_some_and(|start| now_ns >= start)
            }
        }
    }

    /// Late samples that missed their tick since the start.
    pub fn missed(&self) -> u32 {
        self.missed
    }

    /// Late samples sent since the start.
    pub fn late_sent(&self) -> u64 {
        self.late
    }

    /// The margin (ns).
    pub fn margin_ns(&self) -> u64 {
        self.margin_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u64 = 25_000_000;
    const M: u64 = 1_000_000;

    /// A clock that has seen ticks 0..n, each stamped `late` after its grid start `t0 + k·P`.
    fn clock(n: u64, t0: u64, late: impl Fn(u64) -> u64) -> SampleClock {
        let mut c = SampleClock::new(P, M);
        for k in 0..n {
            c.state(k, t0 + k * P + late(k));
            if c.learnt() && k + 1 < n {
                let (_, at) = c.times().unwrap();
                assert!(!c.sent(Due::Late, at));
            }
        }
        c
    }

    #[test]
    fn the_late_sample_is_due_a_margin_before_the_next_tick_on_the_earliest_stamps_grid() {
        let t0 = 1_000_000_000;
        // Stamps 40 to 240 µs late: the grid is the earliest.
        let c = clock(10, t0, |k| 40_000 + (k % 3) * 100_000);
        let g0 = t0 + 40_000;
        let next = g0 + 10 * P;
        assert_eq!(c.next_due_ns(), Some(g0 + 9 * P + P / 2));
        assert_eq!(c.due(g0 + 9 * P + 100_000), None);
        assert_eq!(c.due(g0 + 9 * P + P / 2), Some(Due::Fallback));
        let mut c2 = c.clone();
        assert!(!c2.sent(Due::Fallback, g0 + 9 * P + P / 2));
        assert_eq!(c2.next_due_ns(), Some(next - M));
        assert_eq!(c2.due(next - M - 1), None);
        assert_eq!(c2.due(next - M), Some(Due::Late));
        assert!(!c2.sent(Due::Late, next - M + 50_000));
        assert_eq!(
            (c2.due(next), c2.next_due_ns(), c2.missed()),
            (None, None, 0)
        );
        // A fallback never sent: the late sample is due all the same.
        assert_eq!(c.due(next - M), Some(Due::Late));
    }

    #[test]
    fn a_late_sample_not_sent_before_its_ticks_state_is_counted_missed() {
        let t0 = 5_000_000;
        let mut c = clock(6, t0, |_| 10_000);
        let next = t0 + 10_000 + 6 * P;
        // Sent after the grid's start, but before the state came: not a miss.
        assert!(c.sent(Due::Late, next + 1));
        assert_eq!(c.missed(), 0);
        // Tick 6 arrives; its late sample never goes out before tick 7's state.
        c.state(6, next + 10_000);
        c.state(7, next + P + 10_000);
        assert_eq!(c.missed(), 1);
        // An old or repeated state counts nothing.
        c.state(7, next + P + 10_000);
        c.state(3, t0 + 3 * P);
        assert_eq!(c.missed(), 1);
    }

    #[test]
    fn nothing_is_due_on_the_grid_until_it_is_known() {
        let mut c = SampleClock::new(P, M);
        for k in 0..MIN_STATES as u64 - 1 {
            c.state(k, k * P);
            assert!(!c.learnt());
            assert_eq!((c.due(u64::MAX), c.next_due_ns()), (None, None));
        }
        c.state(MIN_STATES as u64, MIN_STATES as u64 * P);
        assert!(c.learnt());
        // Learning counts no miss for the ticks before.
        assert_eq!(c.missed(), 0);
    }

    #[test]
    fn the_automatic_margin_is_a_millisecond_at_most_a_quarter_period() {
        assert_eq!(margin_ns(0, P), 1_000_000);
        assert_eq!(margin_ns(0, 1_000_000), 250_000);
        assert_eq!(margin_ns(300, 1_000_000), 300_000);
        // Never more than half a period, whatever it is told.
        assert_eq!(SampleClock::new(1_000_000, 900_000).margin_ns(), 500_000);
    }
}
