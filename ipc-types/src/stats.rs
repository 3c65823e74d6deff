//! The one quantile definition of the project: the latency percentiles of `scl up`, `scl top`
//! and `scl bench latency`, and the medians and quartiles of the experiments, all mean the
//! same thing.
//!
//! It lives here, beside the clock the latencies are measured with, because every process
//! and tool links this crate and it needs nothing.

/// The `q`-quantile of `sorted` (ascending, finite), `q` in `[0, 1]` (clamped): linear
/// interpolation between the closest ranks (Hyndman and Fan's definition 7, the default of
/// numpy and R). With `n` values and `h = q (n - 1)`, it is
/// `sorted[⌊h⌋] + (h - ⌊h⌋) (sorted[⌊h⌋ + 1] - sorted[⌊h⌋])`; so `q = 0.5` is the median
/// (the mean of the middle two for an even `n`), `q = 1` the largest value. NaN when `sorted`
/// is empty.
///
/// ```
/// use ipc_types::stats::quantile;
/// let v = [1.0, 2.0, 3.0, 4.0];
/// assert_eq!(quantile(&v, 0.5), 2.5);
/// assert_eq!(quantile(&v, 0.25), 1.75);
/// assert_eq!(quantile(&v, 1.0), 4.0);
/// assert!(quantile(&[], 0.5).is_nan());
/// ```
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let Some(last) = sorted.len().checked_sub(1) else {
        return f64::NAN;
    };
    let h = q.clamp(0.0, 1.0) * last as f64;
    let lo = h.floor() as usize;
    let frac = h - lo as f64;
    if frac == 0.0 || lo == last {
        sorted[lo]
    } else {
        sorted[lo] + frac * (sorted[lo + 1] - sorted[lo])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_between_closest_ranks() {
        let s: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&s, 0.0), 1.0);
        assert_eq!(quantile(&s, 0.5), 50.5);
        assert!((quantile(&s, 0.99) - 99.01).abs() < 1e-12);
        assert_eq!(quantile(&s, 1.0), 100.0);
        assert_eq!(quantile(&s, 2.0), 100.0);
        assert_eq!(quantile(&[7.0], 0.3), 7.0);
        assert_eq!(quantile(&[0.0, 10.0], 0.25), 2.5);
        assert_eq!(quantile(&[1.0, 2.0, 3.0], 0.5), 2.0);
    }
}
