//! Percentiles of latency samples, as the status line and the JSON summary report them.

use serde::Serialize;

/// p50 / p99 / max of a set of samples, in microseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest sample.
    pub max: f64,
}

/// The `q`-quantile (0..=1) of sorted samples, nearest rank.
pub fn quantile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// Percentiles in µs of samples given in ns.
pub fn percentiles_us(samples_ns: &[u64]) -> Percentiles {
    let mut s = samples_ns.to_vec();
    s.sort_unstable();
    let us = |ns: u64| ns as f64 / 1000.0;
    Percentiles {
        p50: us(quantile(&s, 0.50)),
        p99: us(quantile(&s, 0.99)),
        max: us(s.last().copied().unwrap_or(0)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank() {
        let s: Vec<u64> = (1..=100).collect();
        assert_eq!(quantile(&s, 0.5), 50);
        assert_eq!(quantile(&s, 0.99), 99);
        assert_eq!(quantile(&s, 1.0), 100);
        assert_eq!(quantile(&[], 0.5), 0);
        let p = percentiles_us(&[3000, 1000, 2000]);
        assert_eq!((p.p50, p.p99, p.max), (2.0, 3.0, 3.0));
    }
}
