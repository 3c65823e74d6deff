//! Percentiles of latency samples, as the status line and the JSON summary report them
//! (the quantile is [`ipc_types::stats::quantile`]: linear interpolation between the closest
//! ranks).

use ipc_types::stats::quantile;
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

/// Samples in ns as µs, sorted: the input of [`ipc_types::stats::quantile`].
pub fn sorted_us(samples_ns: &[u64]) -> Vec<f64> {
    let mut s: Vec<f64> = samples_ns.iter().map(|ns| *ns as f64 / 1000.0).collect();
    s.sort_by(f64::total_cmp);
    s
}

/// Percentiles in µs of samples given in ns (zeros when there are none).
pub fn percentiles_us(samples_ns: &[u64]) -> Percentiles {
    let s = sorted_us(samples_ns);
    if s.is_empty() {
        return Percentiles::default();
    }
    Percentiles {
        p50: quantile(&s, 0.50),
        p99: quantile(&s, 0.99),
        max: s[s.len() - 1],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate() {
        let p = percentiles_us(&[3000, 1000, 2000]);
        assert_eq!((p.p50, p.max), (2.0, 3.0));
        assert!((p.p99 - 2.98).abs() < 1e-12, "{p:?}");
        assert_eq!(percentiles_us(&[]), Percentiles::default());
        let s = sorted_us(&[2500, 500]);
        assert_eq!(s, vec![0.5, 2.5]);
    }
}
