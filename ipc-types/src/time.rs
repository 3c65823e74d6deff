//! The one clock of the graph: `CLOCK_MONOTONIC` in nanoseconds.
//!
//! Every process reads the same kernel clock, so a timestamp written by one process can be
//! subtracted from a timestamp taken in another (sample age, end-to-end latency) without any
//! synchronisation.

/// Nanoseconds of `CLOCK_MONOTONIC`. Shared by every process on the machine.
pub fn now_ns() -> u64 {
    use nix::time::{ClockId, clock_gettime};
    // CLOCK_MONOTONIC always exists on Linux, so this cannot fail (0 would only mean "no time").
    clock_gettime(ClockId::CLOCK_MONOTONIC).map_or(0, |ts| {
        ts.tv_sec() as u64 * 1_000_000_000 + ts.tv_nsec() as u64
    })
}

/// Age of a timestamp `t_ns` at time `now_ns`, saturating at zero (a timestamp from the
/// future, which can only come from a corrupt message, has age zero; callers that care check
/// for it separately).
pub fn age_ns(now_ns: u64, t_ns: u64) -> u64 {
    now_ns.saturating_sub(t_ns)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_and_ages() {
        let a = now_ns();
        let b = now_ns();
        assert!(b >= a);
        assert_eq!(age_ns(10, 3), 7);
        assert_eq!(age_ns(3, 10), 0);
    }
}
