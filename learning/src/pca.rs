//! Fitting the PCA baseline ([`mapper::pca::PcaMap`]) to demonstrated joint velocities: the
//! top-d principal components, deterministic in order and sign.

use mapper::pca::PcaMap;
use nalgebra::{DMatrix, DVector, SymmetricEigen};

/// Why a PCA fit failed.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    /// Fewer samples than needed.
    #[error("PCA needs at least {needed} velocity samples, the data has {found}")]
    TooFewSamples {
        /// Required.
        needed: usize,
        /// Present.
        found: usize,
    },
    /// More components asked for than there are joints.
    #[error("cannot take {d} principal components of {m}-joint velocities")]
    TooManyComponents {
        /// Asked.
        d: usize,
        /// Joints.
        m: usize,
    },
    /// The data has fewer than `d` directions of motion.
    #[error(
        "the demonstrations move in fewer than {d} independent directions (eigenvalue {index} is {value:.3e}); record more varied motion"
    )]
    Degenerate {
        /// Asked components.
        d: usize,
        /// Index of the vanishing eigenvalue.
        index: usize,
        /// Its value.
        value: f64,
    },
}

/// Fits the top-`d` principal components of the velocity rows `qdot` (each of length `m`,
/// mean-centred as in standard PCA). Columns are sorted by explained variance and their
/// signs fixed (largest-magnitude entry positive), so the result is deterministic.
pub fn fit(qdot: &[Vec<f64>], d: usize) -> Result<PcaMap, FitError> {
    let m = qdot.first().map_or(0, Vec::len);
    if qdot.len() < 2 {
        return Err(FitError::TooFewSamples {
            needed: 2,
            found: qdot.len(),
        });
    }
    if d == 0 || d > m {
        return Err(FitError::TooManyComponents { d, m });
    }
    let n = qdot.len() as f64;
    let mut mean = DVector::<f64>::zeros(m);
    for row in qdot {
        mean += DVector::from_column_slice(row);
    }
    mean /= n;
    let mut cov = DMatrix::<f64>::zeros(m, m);
    for row in qdot {
        let x = DVector::from_column_slice(row) - &mean;
        cov.ger(1.0, &x, &x, 1.0);
    }
    cov /= n - 1.0;
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
    let top = eig.eigenvalues[order[0]].max(f64::MIN_POSITIVE);
    let mut basis = DMatrix::<f64>::zeros(m, d);
    for (k, &idx) in order.iter().take(d).enumerate() {
        let value = eig.eigenvalues[idx];
        if value <= top * 1e-12 {
            return Err(FitError::Degenerate { d, index: k, value });
        }
        let mut col = eig.eigenvectors.column(idx).into_owned();
        col /= col.norm();
        let imax = col.iamax();
        if col[imax] < 0.0 {
            col = -col;
        }
        basis.set_column(k, &col);
    }
    Ok(PcaMap::new(basis))
}

/// Mean squared reconstruction error of `qdot` through the map's projection
/// `Σ Σᵀ qdot` (the best a state-independent orthonormal map can do), averaged over samples
/// and joints.
pub fn reconstruction_mse(map: &PcaMap, qdot: &[Vec<f64>]) -> f64 {
    if qdot.is_empty() {
        return 0.0;
    }
    let b = map.basis();
    let mut sum = 0.0;
    let mut count = 0usize;
    for row in qdot {
        let x = DVector::from_column_slice(row);
        let r = &x - b * (b.transpose() * &x);
        sum += r.norm_squared();
        count += row.len();
    }
    sum / count as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapper::rng::Rng;
    use proptest::prelude::*;

    /// Velocities in the span of two known directions, plus a little noise.
    fn planar_data(n: usize, seed: u64) -> (Vec<Vec<f64>>, DMatrix<f64>) {
        let mut rng = Rng::new(seed);
        let u = DVector::from_vec(vec![1.0, 2.0, 0.0, -1.0, 0.5, 0.0]).normalize();
        let mut v = DVector::from_vec(vec![0.0, 0.0, 1.0, 0.0, 1.0, 1.0]);
        v -= &u * u.dot(&v);
        let v = v.normalize();
        let mut data = Vec::new();
        for _ in 0..n {
            let x = &u * rng.normal() * 0.5
                + &v * rng.normal() * 0.2
                + DVector::from_fn(6, |_, _| rng.normal() * 0.005);
            data.push(x.iter().copied().collect());
        }
        let truth = DMatrix::from_columns(&[u, v]);
        (data, truth)
    }

    #[test]
    fn fit_recovers_the_subspace_in_order() {
        let (data, truth) = planar_data(2000, 1);
        let map = fit(&data, 2).unwrap();
        let b = map.basis();
        // First component along u, second along v (up to sign, fixed by the convention).
        assert!(b.column(0).dot(&truth.column(0)).abs() > 0.999);
        assert!(b.column(1).dot(&truth.column(1)).abs() > 0.999);
        assert!(reconstruction_mse(&map, &data) < 1e-4);
        let one = fit(&data, 1).unwrap();
        assert!(reconstruction_mse(&one, &data) > reconstruction_mse(&map, &data));
    }

    #[test]
    fn fit_refuses_bad_requests() {
        let (data, _) = planar_data(10, 2);
        assert!(matches!(
            fit(&data, 7),
            Err(FitError::TooManyComponents { .. })
        ));
        assert!(matches!(
            fit(&data[..1], 2),
            Err(FitError::TooFewSamples { .. })
        ));
        let line: Vec<Vec<f64>> = (0..50).map(|i| vec![i as f64, 0.0, 0.0]).collect();
        assert!(matches!(fit(&line, 2), Err(FitError::Degenerate { .. })));
    }

    proptest! {
        #[test]
        fn fitted_bases_are_orthonormal_and_deterministic(seed in 0u64..1000, d in 1usize..=3) {
            let (data, _) = planar_data(200, seed);
            let a = fit(&data, d).unwrap();
            let b = fit(&data, d).unwrap();
            prop_assert_eq!(a.basis(), b.basis());
            let gram = a.basis().transpose() * a.basis();
            prop_assert!((gram - DMatrix::<f64>::identity(d, d)).amax() < 1e-9);
        }
    }
}
