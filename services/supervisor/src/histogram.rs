//! A latency histogram of fixed size: `scl up` takes two samples a tick (end-to-end latency,
//! the bridge's lateness) for its whole run, which kept as a list grew the supervisor by
//! 16 bytes a tick (about 55 MiB an hour at 1 kHz, found by `scripts/soak.sh`) and made the
//! once-a-second progress line sort every sample so far. The histogram's buckets are
//! log-linear (as HdrHistogram's): values below 256 ns exactly, above that 128 buckets per
//! power of two, so a percentile is within 1/128 (0.8 %) of the sample it stands for; the
//! largest sample is kept exactly.

use node_rt::stats::Percentiles;

/// Sub-buckets per power of two, as a power of two: 2^7 = 128.
const SUB_BITS: u32 = 7;
const SUB: u64 = 1 << SUB_BITS;
/// Buckets for every `u64`: the exact range [0, 2 * SUB), then SUB for each of the 56 powers
/// of two above it (7424 buckets).
const BUCKETS: usize = ((64 - SUB_BITS + 1) as usize) * SUB as usize;

/// Bucket index of `v`.
fn index(v: u64) -> usize {
    if v < 2 * SUB {
        return v as usize;
    }
    // `v`'s top SUB_BITS + 1 bits: `sub` in [SUB, 2 * SUB), `v` = sub << shift + rest.
    let shift = 63 - v.leading_zeros() - SUB_BITS;
    let sub = v >> shift;
    (shift as usize) * SUB as usize + sub as usize
}

/// The smallest value of bucket `i` and the bucket's width.
fn bounds(i: usize) -> (u64, u64) {
    if i < 2 * SUB as usize {
        return (i as u64, 1);
    }
    let shift = (i / SUB as usize - 1) as u32;
    let sub = (i % SUB as usize) as u64 + SUB;
    (sub << shift, 1 << shift)
}

/// Samples in ns, counted per bucket; 58 KiB once the first sample came, whatever the count.
#[derive(Debug, Default, Clone)]
pub(crate) struct Histogram {
    counts: Vec<u64>,
    n: u64,
    max: u64,
}

impl Histogram {
    /// Counts sample `ns`.
    pub(crate) fn record(&mut self, ns: u64) {
        if self.counts.is_empty() {
            self.counts = vec![0; BUCKETS];
        }
        self.counts[index(ns)] += 1;
        self.n += 1;
        self.max = self.max.max(ns);
    }

    /// How many samples were counted.
    pub(crate) fn len(&self) -> u64 {
        self.n
    }

    /// The sample of rank `r` (0-based, in ascending order) as its bucket's middle, or the
    /// largest sample for the last rank (and never above it).
    fn at_rank(&self, r: u64) -> f64 {
        if r + 1 >= self.n {
            return self.max as f64;
        }
        let mut seen = 0;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen > r {
                let (lo, w) = bounds(i);
                let mid = lo as f64 + (w - 1) as f64 / 2.0;
                return mid.min(self.max as f64);
            }
        }
        self.max as f64
    }

    /// The quantile `q` in ns: linear interpolation between the closest ranks, as
    /// `ipc_types::stats::quantile` over the sorted samples.
    fn quantile(&self, q: f64) -> f64 {
        let pos = q * (self.n - 1) as f64;
        let lo = pos.floor() as u64;
        let frac = pos - lo as f64;
        let a = self.at_rank(lo);
        if frac == 0.0 {
            return a;
        }
        a + (self.at_rank(lo + 1) - a) * frac
    }

    /// p50 / p99 / max in µs (zeros when there are no samples), as
    /// `node_rt::stats::percentiles_us` of the samples.
    pub(crate) fn percentiles_us(&self) -> Percentiles {
        if self.n == 0 {
            return Percentiles::default();
        }
        Percentiles {
            p50: self.quantile(0.50) / 1000.0,
            p99: self.quantile(0.99) / 1000.0,
            max: self.max as f64 / 1000.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use node_rt::stats::percentiles_us;

    #[test]
    fn every_value_falls_in_its_bucket() {
        let mut v = 0u64;
        let mut last = 0;
        // Every value below 2^20, then a sparse walk up to u64::MAX.
        while v < u64::MAX {
            let i = index(v);
            assert!(i < BUCKETS, "{v}: {i}");
            assert!(i >= last, "{v}: buckets out of order");
            let (lo, w) = bounds(i);
            assert!(
                lo <= v && v - lo < w,
                "{v}: bucket {i} is [{lo}, {lo} + {w})"
            );
            // Relative width at most 1/128 above the exact range.
            assert!(lo < 2 * SUB || w * SUB <= lo, "{v}: width {w} at {lo}");
            last = i;
            v = if v < 1 << 20 {
                v + 1
            } else {
                v.saturating_add(v / 97 + 1)
            };
        }
        assert_eq!(index(u64::MAX), BUCKETS - 1);
    }

    #[test]
    fn percentiles_match_the_exact_ones_within_a_bucket() {
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
            assert!((x - y).abs() <= y / 128.0, "{a:?} against {b:?}");
        }
        // Small samples are exact.
        let mut h = Histogram::default();
        for s in [3000, 1000, 2000] {
            h.record(s);
        }
        let p = h.percentiles_us();
        assert_eq!(p.max, 3.0);
        assert!((p.p50 - 2.0).abs() <= 2.0 / 128.0, "{p:?}");
    }
}
