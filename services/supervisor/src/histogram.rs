//! A latency histogram of fixed size: `scl up` takes two samples a tick (end-to-end latency,
//! the bridge's lateness) for its whole run, which kept as a list grew the supervisor by
//! 16 bytes a tick (about 55 MiB an hour at 1 kHz, found by `scripts/soak.sh`) and made the
//! once-a-second progress line sort every sample so far. The counts are an HdrHistogram
//! (`hdrhistogram`) at three significant digits, from 1 ns to a minute, allocated once (about
//! 0.4 MiB): a percentile is within 0.1 % of the sample it stands for; the largest sample is
//! kept exactly.

use node_rt::stats::Percentiles;

/// The largest sample counted as itself (ns): a minute; a longer one counts as a minute.
const HIGHEST_NS: u64 = 60_000_000_000;
/// Significant digits kept.
const SIGFIG: u8 = 3;

/// Samples in ns, counted; its size does not grow with the count.
#[derive(Debug, Clone)]
pub(crate) struct Histogram {
    /// `None` only if `hdrhistogram` refused the constant bounds (it does not): then
    /// nothing is counted and the percentiles are zeros.
    counts: Option<hdrhistogram::Histogram<u64>>,
    max: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self {
            counts: hdrhistogram::Histogram::new_with_bounds(1, HIGHEST_NS, SIGFIG).ok(),
            max: 0,
        }
    }
}

impl Histogram {
    /// Counts sample `ns`.
    pub(crate) fn record(&mut self, ns: u64) {
        if let Some(h) = self.counts.as_mut() {
            h.saturating_record(ns);
            self.max = self.max.max(ns);
        }
    }

    /// How many samples were counted.
    pub(crate) fn len(&self) -> u64 {
        self.counts.as_ref().map_or(0, |h| h.len())
    }

    /// p50 / p99 / max in µs (zeros when there are no samples), as
    /// `node_rt::stats::percentiles_us` of the samples, to the histogram's precision.
    pub(crate) fn percentiles_us(&self) -> Percentiles {
        match self.counts.as_ref().filter(|h| !h.is_empty()) {
            None => Percentiles::default(),
            Some(h) => {
                let q = |q: f64| (h.value_at_quantile(q).min(self.max)) as f64 / 1000.0;
                Percentiles {
                    p50: q(0.50),
                    p99: q(0.99),
                    max: self.max as f64 / 1000.0,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use node_rt::stats::percentiles_us;

    #[test]
    fn percentiles_match_the_exact_ones_to_the_histograms_precision() {
        assert_eq!(
            Histogram::default().percentiles_us(),
            Percentiles::default()
        );
        // Latencies of a run: 200 µs with a tail to 35 ms, and a few exact small ones.
        let samples: Vec<u64> = (0..100_000u64)
            .map(|k| 150_000 + (k * 7919) % 100_000 + if k % 1000 == 0 { 35_000_000 } else { 0 })
            .chain([3, 100, 255])
            .collect();
        let mut h = Histogram::default();
        for s in &samples {
            h.record(*s);
        }
        assert_eq!(h.len(), samples.len() as u64);
        let (a, b) = (h.percentiles_us(), percentiles_us(&samples));
        assert_eq!(a.max, b.max);
        for (x, y) in [(a.p50, b.p50), (a.p99, b.p99)] {
            assert!((x - y).abs() <= y / 500.0, "{a:?} against {b:?}");
        }
        // Small samples are exact.
        let mut h = Histogram::default();
        for s in [3000, 1000, 2000] {
            h.record(s);
        }
        let p = h.percentiles_us();
        assert_eq!(p.max, 3.0);
        assert_eq!(p.p50, 2.0, "{p:?}");
    }

    #[test]
    fn its_size_does_not_grow_with_the_count() {
        let mut h = Histogram::default();
        let before = h.counts.as_ref().map(|c| c.distinct_values());
        for k in 0..1_000_000u64 {
            h.record(k * 60_000);
        }
        assert_eq!(h.counts.as_ref().map(|c| c.distinct_values()), before);
        assert_eq!(h.len(), 1_000_000);
    }
}
