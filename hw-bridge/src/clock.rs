//! The graph's one clock: an absolute-deadline timer on `CLOCK_MONOTONIC`
//! (`clock_nanosleep(TIMER_ABSTIME)`), which does not drift the way a relative sleep does, and
//! the real-time settings the bridge asks for.
//!
//! A sleep wakes tens to hundreds of µs late on a virtual machine. [`Clock::wait_hybrid`]
//! sleeps until a margin before the deadline and spins on the clock for the rest; [`Hybrid`]
//! learns the margin from the sleeps' own lateness and counts the time spun, its CPU cost.

use nix::errno::Errno;
use nix::sys::mman::{MlockAllFlags, mlockall};
use nix::sys::time::TimeSpec;
use nix::time::{ClockId, ClockNanosleepFlags, clock_nanosleep};

/// What [`Clock::wait`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// The deadline passed.
    Tick {
        /// The ideal time of this tick on the period grid (ns).
        ideal_ns: u64,
        /// How late the wake-up was against it (ns).
        lateness_ns: u64,
        /// Whole periods skipped because the process was held up for longer than a period.
        skipped: u64,
    },
    /// A signal interrupted the wait; the caller checks its flags and waits again.
    Interrupted,
}

/// A periodic absolute-deadline timer.
#[derive(Debug, Clone)]
pub struct Clock {
    period_ns: u64,
    next_ns: u64,
}

fn to_timespec(ns: u64) -> TimeSpec {
    TimeSpec::from(std::time::Duration::from_nanos(ns))
}

impl Clock {
    /// A clock whose first deadline is `first_ns` and then every `period_ns`.
    pub fn new(first_ns: u64, period_ns: u64) -> Self {
        Self {
            period_ns: period_ns.max(1),
            next_ns: first_ns,
        }
    }

    /// The period (ns).
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Sleeps until the next deadline.
    pub fn wait(&mut self) -> Wake {
        let ts = to_timespec(self.next_ns);
        let rc = clock_nanosleep(
            ClockId::CLOCK_MONOTONIC,
            ClockNanosleepFlags::TIMER_ABSTIME,
            &ts,
        );
        if rc == Err(Errno::EINTR) {
            return Wake::Interrupted;
        }
        self.on_wake(ipc_types::time::now_ns())
    }

    /// Sleeps until `hybrid`'s margin before the next deadline, then spins on the clock until
    /// the deadline: the tick starts within the clock's own resolution of it unless the
    /// sleep woke later than the margin. The sleep's lateness teaches `hybrid` its margin.
    pub fn wait_hybrid(&mut self, hybrid: &mut Hybrid) -> Wake {
        let target = self.next_ns.saturating_sub(hybrid.margin_ns());
        if ipc_types::time::now_ns() < target {
            let rc = clock_nanosleep(
                ClockId::CLOCK_MONOTONIC,
                ClockNanosleepFlags::TIMER_ABSTIME,
                &to_timespec(target),
            );
            if rc == Err(Errno::EINTR) {
                return Wake::Interrupted;
            }
            hybrid.observe(ipc_types::time::now_ns().saturating_sub(target));
        }
        let woke = ipc_types::time::now_ns();
        let mut now = woke;
        while now < self.next_ns {
            std::hint::spin_loop();
            now = ipc_types::time::now_ns();
        }
        hybrid.spun(now - woke);
        self.on_wake(now)
    }

    /// Accounts a wake-up at `now_ns` (split out of [`Clock::wait`] for tests): returns the
    /// tick and moves the deadline on by one period, or past `now_ns` if more than a whole
    /// period was lost (those periods are reported as skipped, never caught up in a burst).
    pub fn on_wake(&mut self, now_ns: u64) -> Wake {
        let ideal = self.next_ns;
        let lateness = now_ns.saturating_sub(ideal);
        let skipped = lateness / self.period_ns;
        let ideal_ns = ideal + skipped * self.period_ns;
        self.next_ns = ideal_ns + self.period_ns;
        Wake::Tick {
            ideal_ns,
            lateness_ns: now_ns.saturating_sub(ideal_ns),
            skipped,
        }
    }

    /// The next deadline (ns).
    pub fn next_deadline_ns(&self) -> u64 {
        self.next_ns
    }
}

/// How many recent sleeps' lateness [`Hybrid`] keeps.
pub const HYBRID_KEPT: usize = 128;

/// [`Hybrid`]'s first margin, before it has seen a sleep (ns).
pub const HYBRID_START_NS: u64 = 100_000;

/// Added to the latest sleep's lateness seen recently (ns).
pub const HYBRID_GUARD_NS: u64 = 5_000;

/// The least margin (ns).
pub const HYBRID_MIN_NS: u64 = 10_000;

/// The margin is at most this share of a period ...
pub const HYBRID_MAX_SHARE: f64 = 0.05;

/// ... and at most this long (ns): a machine whose sleeps are later than that does not get a
/// CPU spinning for it; its ticks start late instead.
pub const HYBRID_MAX_NS: u64 = 1_000_000;

/// The margin of [`Clock::wait_hybrid`]: the largest lateness of the last [`HYBRID_KEPT`]
/// sleeps plus [`HYBRID_GUARD_NS`], between [`HYBRID_MIN_NS`] and [`HYBRID_MAX_SHARE`] of a
/// period (at most [`HYBRID_MAX_NS`]); and the time spun, the hybrid wait's CPU cost.
#[derive(Debug, Clone)]
pub struct Hybrid {
    late: [u64; HYBRID_KEPT],
    len: usize,
    next: usize,
    max_ns: u64,
    margin_ns: u64,
    /// Time spun on the clock (ns).
    pub spin_ns: u64,
    /// Waits.
    pub ticks: u64,
}

impl Hybrid {
    /// A margin for ticks of `period_ns`.
    pub fn new(period_ns: u64) -> Self {
        let max_ns =
            ((period_ns as f64 * HYBRID_MAX_SHARE) as u64).clamp(HYBRID_MIN_NS, HYBRID_MAX_NS);
        Self {
            late: [0; HYBRID_KEPT],
            len: 0,
            next: 0,
            max_ns,
            margin_ns: HYBRID_START_NS.clamp(HYBRID_MIN_NS, max_ns),
            spin_ns: 0,
            ticks: 0,
        }
    }

    /// The margin now (ns).
    pub fn margin_ns(&self) -> u64 {
        self.margin_ns
    }

    /// A sleep woke `lateness_ns` after its target.
    pub fn observe(&mut self, lateness_ns: u64) {
        self.late[self.next] = lateness_ns;
        self.next = (self.next + 1) % HYBRID_KEPT;
        self.len = (self.len + 1).min(HYBRID_KEPT);
        let worst = self.late[..self.len].iter().copied().max().unwrap_or(0);
        self.margin_ns = (worst + HYBRID_GUARD_NS).clamp(HYBRID_MIN_NS, self.max_ns);
    }

    /// One wait spun `ns` on the clock.
    pub fn spun(&mut self, ns: u64) {
        self.spin_ns += ns;
        self.ticks += 1;
    }

    /// Time spun per tick (µs).
    pub fn per_tick_us(&self) -> f64 {
        self.spin_ns as f64 * 1e-3 / self.ticks.max(1) as f64
    }
}

/// Which real-time settings the process obtained (`None`: not asked for).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtReport {
    /// SCHED_FIFO at the given priority, or why not.
    pub fifo: Option<Result<i32, String>>,
    /// mlockall(MCL_CURRENT | MCL_FUTURE), or why not.
    pub mlock: Option<Result<(), String>>,
}

impl RtReport {
    /// One line for the log: what was obtained, what was refused (one note each) and what
    /// was not asked for.
    pub fn summary(&self) -> String {
        let fifo = match &self.fifo {
            Some(Ok(p)) => format!("SCHED_FIFO priority {p}"),
            Some(Err(e)) => {
                format!("no SCHED_FIFO ({e}); tick lateness will suffer under CPU load")
            }
            None => "SCHED_FIFO not asked for".to_owned(),
        };
        let mlock = match &self.mlock {
            Some(Ok(())) => "memory locked".to_owned(),
            Some(Err(e)) => format!("memory not locked ({e})"),
            None => "memory lock not asked for".to_owned(),
        };
        format!("{fifo}; {mlock}")
    }

    /// Whether everything asked for was obtained.
    pub fn ok(&self) -> bool {
        !matches!(self.fifo, Some(Err(_))) && !matches!(self.mlock, Some(Err(_)))
    }
}

/// Asks for SCHED_FIFO at `priority` and locks the process's memory. Never fails: what could
/// not be had is reported, and the caller warns in one line.
pub fn request_realtime(priority: i32) -> RtReport {
    request(Some(priority), true)
}

/// Asks for SCHED_FIFO at `fifo` (if given) and for `mlockall` (if `mlock`); each is asked and
/// reported on its own, so a benchmark can measure one setting alone.
pub fn request(fifo: Option<i32>, mlock: bool) -> RtReport {
    let fifo = fifo.map(|priority| {
        let param = libc::sched_param {
            sched_priority: priority,
        };
        // libc: nix 0.29 has no sched_setscheduler.
        // SAFETY: a plain system call on the calling process with a valid sched_param.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } == 0 {
            Ok(priority)
        } else {
            Err(std::io::Error::last_os_error().to_string())
        }
    });
    let mlock = mlock.then(|| {
        mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE)
            .map_err(|e| std::io::Error::from(e).to_string())
    });
    RtReport { fifo, mlock }
}

/// Lowers the calling thread's scheduling priority to nice 10: for an observer's threads (the
/// recorder's writer, the live server's view and runtime), so they yield the CPU to the
/// control path. Failure is harmless and ignored.
pub fn lower_priority() {
    // libc: nix 0.29 has no setpriority.
    // SAFETY: gettid and setpriority are plain system calls on the calling thread only (its
    // tid); they take no pointers.
    unsafe {
        let tid = libc::gettid();
        libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 10);
    }
}

/// The PM QoS request of `/dev/cpu_dma_latency` (what cyclictest holds): while this value is
/// alive, idle CPUs do not enter sleep states whose exit latency exceeds the request, so a
/// wake-up between ticks does not pay a deep C-state's exit. Dropping it (closing the file)
/// ends the request.
#[derive(Debug)]
pub struct DmaLatency {
    _file: std::fs::File,
    us: i32,
}

/// Where the kernel takes the CPU wake-up latency request.
pub const CPU_DMA_LATENCY: &str = "/dev/cpu_dma_latency";

impl DmaLatency {
    /// Requests a CPU wake-up latency of at most `us` µs (0: no idle state with an exit
    /// latency) for as long as the value lives; the error says why the machine refused.
    pub fn hold(us: i32) -> std::io::Result<Self> {
        use std::io::Write as _;
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .open(CPU_DMA_LATENCY)?;
        // The kernel takes a binary s32 (or a hex string); the request lasts while the file
        // is open.
        file.write_all(&us.to_ne_bytes())?;
        Ok(Self { _file: file, us })
    }

    /// The latency held (µs).
    pub fn us(&self) -> i32 {
        self.us
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hybrid_margin_follows_the_latest_recent_sleep_within_its_bounds() {
        let mut h = Hybrid::new(25_000_000);
        assert_eq!(h.margin_ns(), HYBRID_START_NS);
        h.observe(40_000);
        assert_eq!(h.margin_ns(), 45_000);
        h.observe(240_000);
        h.observe(60_000);
        assert_eq!(h.margin_ns(), 245_000);
        // The late one is forgotten after HYBRID_KEPT sleeps.
        for _ in 0..HYBRID_KEPT {
            h.observe(30_000);
        }
        assert_eq!(h.margin_ns(), 35_000);
        // Never below the least margin, nor above the cap (5 % of 25 ms, at most 1 ms).
        for _ in 0..HYBRID_KEPT {
            h.observe(0);
        }
        assert_eq!(h.margin_ns(), HYBRID_MIN_NS);
        h.observe(50_000_000);
        assert_eq!(h.margin_ns(), HYBRID_MAX_NS);
        // At 1 kHz the cap is 50 µs.
        let mut k = Hybrid::new(1_000_000);
        assert_eq!(k.margin_ns(), 50_000);
        k.observe(5_000);
        assert_eq!(k.margin_ns(), HYBRID_MIN_NS);
        k.spun(30_000);
        k.spun(10_000);
        assert!((k.per_tick_us() - 20.0).abs() < 1e-9);
    }

    #[test]
    fn a_hybrid_wait_starts_the_tick_at_its_deadline_not_before() {
        let period = 2_000_000;
        let mut h = Hybrid::new(period);
        let mut c = Clock::new(ipc_types::time::now_ns() + period, period);
        for _ in 0..5 {
            let deadline = c.next_deadline_ns();
            match c.wait_hybrid(&mut h) {
                Wake::Tick { ideal_ns, .. } => assert!(ideal_ns >= deadline),
                Wake::Interrupted => {}
            }
            assert!(ipc_types::time::now_ns() >= deadline);
        }
        assert!(h.ticks >= 4);
    }

    #[test]
    fn on_time_and_late_wakes() {
        let mut c = Clock::new(1_000, 100);
        assert_eq!(
            c.on_wake(1_010),
            Wake::Tick {
                ideal_ns: 1_000,
                lateness_ns: 10,
                skipped: 0
            }
        );
        assert_eq!(c.next_deadline_ns(), 1_100);
        // Held up for 2.5 periods: two skipped, no burst of catch-up ticks.
        assert_eq!(
            c.on_wake(1_350),
            Wake::Tick {
                ideal_ns: 1_300,
                lateness_ns: 50,
                skipped: 2
            }
        );
        assert_eq!(c.next_deadline_ns(), 1_400);
    }

    /// The clock's grid and its skipped-period count at 40 Hz and at 1 kHz: the same hold-up
    /// of 60 ms costs two periods at 40 Hz and 60 at 1 kHz, never a burst of catch-up ticks.
    #[test]
    fn held_up_periods_follow_the_period_at_40_hz_and_1_khz() {
        for (period_ns, skipped) in [(25_000_000u64, 2u64), (1_000_000, 60)] {
            let mut c = Clock::new(period_ns, period_ns);
            assert!(matches!(
                c.on_wake(period_ns + 10_000),
                Wake::Tick { skipped: 0, .. }
            ));
            assert_eq!(c.next_deadline_ns(), 2 * period_ns);
            let Wake::Tick {
                ideal_ns,
                skipped: s,
                lateness_ns,
            } = c.on_wake(2 * period_ns + 60_000_000)
            else {
                panic!("a tick")
            };
            assert_eq!(s, skipped);
            assert_eq!(ideal_ns % period_ns, 0);
            assert!(lateness_ns < period_ns);
            assert_eq!(c.next_deadline_ns(), ideal_ns + period_ns);
        }
    }

    #[test]
    fn real_sleep_reaches_the_deadline() {
        let start = ipc_types::time::now_ns();
        let mut c = Clock::new(start + 2_000_000, 2_000_000);
        for _ in 0..3 {
            match c.wait() {
                Wake::Tick { ideal_ns, .. } => {
                    assert!(ipc_types::time::now_ns() >= ideal_ns);
                }
                Wake::Interrupted => {}
            }
        }
        assert!(ipc_types::time::now_ns() >= start + 6_000_000);
    }
}
