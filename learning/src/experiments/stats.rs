//! The rank tests the paper reports: Kruskal-Wallis across groups, then Dunn's pairwise test
//! (with Holm's and Bonferroni's adjustments), both with the correction for ties.
//!
//! * Kruskal-Wallis: `H = [12 / (N (N + 1)) Σ R_i² / n_i − 3 (N + 1)] / C`, with `R_i` the
//!   rank sum of group `i` (average ranks for ties) and `C = 1 − Σ (t³ − t) / (N³ − N)` over
//!   the tie groups; `p = P(χ²_{k−1} ≥ H)`, the regularised upper incomplete gamma
//!   `Q((k − 1) / 2, H / 2)`.
//! * Dunn: `z = (R̄_i − R̄_j) / sqrt((N (N + 1) / 12 − Σ (t³ − t) / (12 (N − 1))) (1/n_i + 1/n_j))`,
//!   two-sided `p = erfc(|z| / √2) = Q(1/2, z² / 2)`.
//!
//! The tails are statrs's (`ChiSquared`; the normal one through it, see [`two_sided`]); the tests check them against values
//! computed with arbitrary precision. Medians and quartiles are [`ipc_types::stats::quantile`]
//! (linear interpolation between the closest ranks).

use ipc_types::stats as quantiles;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// The Kruskal-Wallis test of `k` groups.
#[derive(Debug, Clone, PartialEq)]
pub struct KruskalWallis {
    /// The statistic `H`, corrected for ties.
    pub h: f64,
    /// Degrees of freedom, `k − 1`.
    pub df: usize,
    /// `P(χ²_df ≥ H)`.
    pub p: f64,
    /// Observations in all groups.
    pub n: usize,
}

/// Dunn's test of one pair of groups.
#[derive(Debug, Clone, PartialEq)]
pub struct DunnPair {
    /// First group (index).
    pub a: usize,
    /// Second group (index).
    pub b: usize,
    /// Mean rank of `a` minus mean rank of `b`, standardised.
    pub z: f64,
    /// Two-sided p-value.
    pub p: f64,
    /// Holm-adjusted p-value (over all pairs).
    pub p_holm: f64,
    /// Bonferroni-adjusted p-value.
    pub p_bonferroni: f64,
}

/// Both tests on the same groups.
#[derive(Debug, Clone, PartialEq)]
pub struct RankTests {
    /// Kruskal-Wallis across all groups.
    pub kruskal: KruskalWallis,
    /// Dunn's test of every pair `a < b`.
    pub dunn: Vec<DunnPair>,
}

/// Average ranks (1-based) of the pooled values, the group of each, and the tie term
/// `Σ (t³ − t)`.
fn pooled_ranks(groups: &[&[f64]]) -> (Vec<f64>, Vec<usize>, f64) {
    let mut all: Vec<(f64, usize)> = groups
        .iter()
        .enumerate()
        .flat_map(|(g, v)| v.iter().map(move |x| (*x, g)))
        .collect();
    all.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = all.len();
    let mut ranks = vec![0.0; n];
    let mut ties = 0.0;
    let mut i = 0;
    while i < n {
        let mut j = i;
        while j + 1 < n && all[j + 1].0 == all[i].0 {
            j += 1;
        }
        let r = (i + j) as f64 / 2.0 + 1.0;
        ranks[i..=j].fill(r);
        let t = (j - i + 1) as f64;
        ties += t * t * t - t;
        i = j + 1;
    }
    (ranks, all.into_iter().map(|(_, g)| g).collect(), ties)
}

/// Kruskal-Wallis and Dunn's test of `groups` (each a sample; non-finite values are left
/// out). `None` when fewer than two groups have values, or when all values are equal (no
/// ranking to test).
pub fn rank_tests(groups: &[&[f64]]) -> Option<RankTests> {
    let clean: Vec<Vec<f64>> = groups
        .iter()
        .map(|g| g.iter().copied().filter(|v| v.is_finite()).collect())
        .collect();
    let refs: Vec<&[f64]> = clean.iter().map(Vec::as_slice).collect();
    if refs.iter().filter(|g| !g.is_empty()).count() < 2 {
        return None;
    }
    let (ranks, group_of, ties) = pooled_ranks(&refs);
    let n = ranks.len() as f64;
    let correction = 1.0 - ties / (n * n * n - n);
    if correction <= 0.0 {
        return None;
    }
    let k = refs.len();
    let mut sums = vec![0.0; k];
    for (r, g) in ranks.iter().zip(&group_of) {
        sums[*g] += r;
    }
    let h_raw = 12.0 / (n * (n + 1.0))
        * refs
            .iter()
            .zip(&sums)
            .filter(|(g, _)| !g.is_empty())
            .map(|(g, s)| s * s / g.len() as f64)
            .sum::<f64>()
        - 3.0 * (n + 1.0);
    let h = (h_raw / correction).max(0.0);
    let df = refs.iter().filter(|g| !g.is_empty()).count() - 1;
    let kruskal = KruskalWallis {
        h,
        df,
        p: chi2_sf(h, df as f64),
        n: ranks.len(),
    };
    let var_unit = n * (n + 1.0) / 12.0 - ties / (12.0 * (n - 1.0));
    let mut dunn = Vec::new();
    for a in 0..k {
        for b in a + 1..k {
            let (na, nb) = (refs[a].len() as f64, refs[b].len() as f64);
            if na == 0.0 || nb == 0.0 {
                continue;
            }
            let z = (sums[a] / na - sums[b] / nb) / (var_unit * (1.0 / na + 1.0 / nb)).sqrt();
            dunn.push(DunnPair {
                a,
                b,
                z,
                p: two_sided(z),
                p_holm: f64::NAN,
                p_bonferroni: f64::NAN,
            });
        }
    }
    let p: Vec<f64> = dunn.iter().map(|d| d.p).collect();
    for ((d, h), b) in dunn.iter_mut().zip(holm(&p)).zip(bonferroni(&p)) {
        d.p_holm = h;
        d.p_bonferroni = b;
    }
    Some(RankTests { kruskal, dunn })
}

/// Holm's step-down adjustment of `p` (returned in the input order).
pub fn holm(p: &[f64]) -> Vec<f64> {
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|a, b| p[*a].total_cmp(&p[*b]));
    let mut out = vec![0.0; m];
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * p[i]).min(1.0));
        out[i] = running;
    }
    out
}

/// Bonferroni's adjustment of `p`.
pub fn bonferroni(p: &[f64]) -> Vec<f64> {
    p.iter().map(|v| (v * p.len() as f64).min(1.0)).collect()
}

/// Two-sided normal tail `P(|Z| ≥ |z|) = erfc(|z| / √2)`.
pub fn two_sided(z: f64) -> f64 {
    if z.is_nan() {
        return f64::NAN;
    }
    // P(|Z| ≥ |z|) = P(χ²_1 ≥ z²): statrs's chi-squared tail (the incomplete gamma function)
    // is exact to 1e-16 here, its normal tail (erfc) is not: measured with statrs 0.19.1 at
    // z = 1.959963984540054, 2 Normal::sf(z) = 0.04999999999775 (relative error 4.5e-11),
    // χ²_1 sf(z²) = 0.04999999999999999 (mpmath: 0.05).
    chi2_sf(z * z, 1.0)
}

/// Survival function `P(χ²_df ≥ x)` of the chi-square distribution with `df` degrees of
/// freedom (NaN for `df <= 0`).
pub fn chi2_sf(x: f64, df: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    ChiSquared::new(df).map_or(f64::NAN, |d| d.sf(x))
}

/// The median of `values` (NaN for none; non-finite values are left out).
pub fn median(values: &[f64]) -> f64 {
    quantile(values, 0.5)
}

/// The `q`-quantile of `values`, `q` in `[0, 1]` ([`ipc_types::stats::quantile`] of the finite
/// values; NaN for none).
pub fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    v.sort_by(f64::total_cmp);
    quantiles::quantile(&v, q)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs().max(1e-300)
    }

    #[test]
    fn tails_match_arbitrary_precision() {
        // Q(a, x) = P(χ²_2a ≥ 2x), from mpmath.gammainc(a, x, inf, regularized=True).
        for (a, x, q) in [
            (0.5, 0.1, 0.654_720_846_018_577),
            (0.5, 8.0, 6.334_248_366_623_985e-5),
            (1.5, 2.0, 0.261_464_129_949_110_6),
            (4.5, 3.0, 0.739_918_292_094_653_7),
            (2.5, 20.0, 1.493_367_900_050_395_2e-7),
            (10.0, 3.0, 0.998_897_511_869_884_5),
        ] {
            let got = chi2_sf(2.0 * x, 2.0 * a);
            assert!(close(got, q, 1e-12), "Q({a}, {x}) = {got}, expected {q}");
        }
        // Two degrees of freedom: P = e^(-x/2); the normal tail at its 97.5 % point.
        assert!(close(chi2_sf(7.4, 2.0), (-3.7f64).exp(), 1e-13));
        assert!(close(two_sided(1.959_963_984_540_054), 0.05, 1e-12));
        assert!(close(two_sided(-1.959_963_984_540_054), 0.05, 1e-12));
        assert_eq!(two_sided(0.0), 1.0);
        assert_eq!(chi2_sf(0.0, 3.0), 1.0);
        assert!(chi2_sf(1.0, 0.0).is_nan() && two_sided(f64::NAN).is_nan());
    }

    #[test]
    fn kruskal_wallis_with_ties_is_the_textbook_value() {
        // H = 5 / (1 - 144/504) = 7; chi-square with 2 dof: p = e^-3.5.
        let t = rank_tests(&[&[1.0, 1.0, 1.0], &[2.0, 2.0, 2.0], &[2.0, 2.0]]).unwrap();
        assert!(close(t.kruskal.h, 7.0, 1e-12), "{t:?}");
        assert!(close(t.kruskal.p, (-3.5f64).exp(), 1e-12), "{t:?}");
        assert_eq!((t.kruskal.df, t.kruskal.n), (2, 8));
        // Dunn (reference: the formulas evaluated with mpmath).
        let z: Vec<f64> = t.dunn.iter().map(|d| d.z).collect();
        assert!(close(z[0], -2.366_431_913_239_85, 1e-12), "{z:?}");
        assert!(close(z[1], -2.116_601_048_851_67, 1e-12), "{z:?}");
        assert_eq!(z[2], 0.0);
        assert!(close(t.dunn[0].p, 0.017_960_477_526_078_8, 1e-10));
        assert!(close(t.dunn[1].p, 0.034_293_721_036_492_8, 1e-10));
        assert_eq!(t.dunn[2].p, 1.0);
        // Holm: 3 p, then max(previous, 2 p), then 1.
        assert!(close(
            t.dunn[0].p_holm,
            3.0 * 0.017_960_477_526_078_8,
            1e-10
        ));
        assert!(close(
            t.dunn[1].p_holm,
            2.0 * 0.034_293_721_036_492_8,
            1e-10
        ));
        assert_eq!(t.dunn[2].p_holm, 1.0);
        assert!(close(
            t.dunn[1].p_bonferroni,
            3.0 * 0.034_293_721_036_492_8,
            1e-10
        ));
    }

    #[test]
    fn kruskal_wallis_on_hollander_wolfe_and_separated_groups() {
        // Hollander & Wolfe's example (scipy.stats.kruskal's documentation): H = 0.7714,
        // p = 0.68.
        let t = rank_tests(&[
            &[2.9, 3.0, 2.5, 2.6, 3.2],
            &[3.8, 2.7, 4.0, 2.4],
            &[2.8, 3.4, 3.7, 2.2, 2.0],
        ])
        .unwrap();
        assert!(close(t.kruskal.h, 0.771_428_571_428_572_2, 1e-12), "{t:?}");
        assert!(close(t.kruskal.p, 0.679_964_773_578_894, 1e-10), "{t:?}");
        assert!(close(t.dunn[2].z, 0.855_235_974_119_758, 1e-12));
        assert!(close(t.dunn[2].p, 0.392_420_524_476_582, 1e-10));
        // Two groups, no ties: H = 0.2727, p = 0.6015; Dunn's p equals it.
        let t = rank_tests(&[&[1.0, 3.0, 5.0, 7.0, 9.0], &[2.0, 4.0, 6.0, 8.0, 10.0]]).unwrap();
        assert!(close(t.kruskal.h, 0.272_727_272_727_273_4, 1e-12));
        assert!(close(t.kruskal.p, 0.601_508_134_440_589, 1e-10));
        assert!(close(t.dunn[0].p, t.kruskal.p, 1e-10));
        // Separated groups.
        let t = rank_tests(&[
            &[0.1, 0.2, 0.3, 0.15],
            &[0.5, 0.6, 0.55, 0.7, 0.65],
            &[0.9, 1.0, 0.95, 0.85],
        ])
        .unwrap();
        assert!(close(t.kruskal.h, 10.681_318_681_318_686, 1e-12));
        assert!(close(t.kruskal.p, 0.004_792_709_639_965_79, 1e-10));
        assert!(close(t.dunn[1].z, -3.268_228_676_411_53, 1e-12));
        assert!(close(t.dunn[1].p, 0.001_082_228_864_258_38, 1e-9));
    }

    #[test]
    fn degenerate_inputs() {
        assert!(rank_tests(&[&[1.0, 2.0]]).is_none());
        assert!(rank_tests(&[&[1.0, 2.0], &[]]).is_none());
        assert!(rank_tests(&[&[1.0, 1.0], &[1.0]]).is_none());
        // NaN is left out.
        let t = rank_tests(&[&[1.0, f64::NAN, 3.0], &[2.0, 4.0]]).unwrap();
        assert_eq!(t.kruskal.n, 4);
        let h = holm(&[0.01, 0.04, 0.03]);
        for (got, want) in h.iter().zip([0.03, 0.06, 0.06]) {
            assert!(close(*got, want, 1e-12), "{h:?}");
        }
        assert_eq!(median(&[3.0, 1.0, 2.0, 10.0]), 2.5);
        assert_eq!(quantile(&[0.0, 10.0], 0.25), 2.5);
        assert!(median(&[]).is_nan());
    }
}
