//! PCA, the paper's linear baseline: `map(o, a) = Σ a`, where the columns of `Σ` (m × d) are
//! the top-d principal components of the demonstrated joint velocities. The map does not
//! depend on the state.

use std::path::Path;

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use safetensors::SafeTensors;

use crate::ActionMap;
use crate::model::{ModelError, ModelHeader, ModelKind, tensor_f32};

/// Name of the basis tensor in a PCA model file: f32, shape `[n_joints, latent_dim]`.
pub const BASIS_TENSOR: &str = "basis";

/// Largest departure from orthonormality (`|ΣᵀΣ - I|`, elementwise) a PCA file may have.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-4;

/// A PCA map with its basis.
#[derive(Debug, Clone)]
pub struct PcaMap {
    basis: DMatrix<f64>,
}

impl PcaMap {
    /// A map with the given basis (m × d). The caller guarantees orthonormal columns.
    pub fn new(basis: DMatrix<f64>) -> Self {
        Self { basis }
    }

    /// The basis Σ.
    pub fn basis(&self) -> &DMatrix<f64> {
        &self.basis
    }

    /// Reads the basis from a model file's tensors and checks that it is orthonormal.
    pub fn from_tensors(
        st: &SafeTensors<'_>,
        header: &ModelHeader,
        path: &Path,
    ) -> Result<Self, ModelError> {
        let (m, d) = (header.n_joints, header.latent_dim);
        let values = tensor_f32(st, BASIS_TENSOR, &[m, d], path)?;
        let basis = DMatrix::from_row_iterator(m, d, values.iter().map(|v| f64::from(*v)));
        let gram = basis.transpose() * &basis;
        let err = (gram - DMatrix::<f64>::identity(d, d)).amax();
        if err > ORTHONORMAL_TOLERANCE {
            return Err(ModelError::BadTensor {
                path: path.to_owned(),
                name: BASIS_TENSOR.to_owned(),
                reason: format!(
                    "columns are not orthonormal (largest |ΣᵀΣ - I| entry {err:.2e}, allowed {ORTHONORMAL_TOLERANCE:.0e})"
                ),
            });
        }
        Ok(Self { basis })
    }

    /// The basis as row-major f32, the layout of [`BASIS_TENSOR`].
    pub fn basis_row_major_f32(&self) -> Vec<f32> {
        let (m, d) = self.basis.shape();
        (0..m)
            .flat_map(|i| (0..d).map(move |j| (i, j)))
            .map(|(i, j)| self.basis[(i, j)] as f32)
            .collect()
    }
}

impl ActionMap for PcaMap {
    fn kind(&self) -> ModelKind {
        ModelKind::Pca
    }
    fn n_joints(&self) -> usize {
        self.basis.nrows()
    }
    fn latent_dim(&self) -> usize {
        self.basis.ncols()
    }
    fn eval(&mut self, _q: &[f64], _c: f64, a: &[f64], out: &mut [f64]) {
        let (m, d) = self.basis.shape();
        for (i, o) in out.iter_mut().enumerate().take(m) {
            let mut acc = 0.0;
            for (j, aj) in a.iter().enumerate().take(d) {
                acc += self.basis[(i, j)] * aj;
            }
            *o = acc;
        }
    }
}

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
pub(crate) mod tests {
    use super::*;
    use crate::model::{FORMAT, ModelHeader, PCA_VERSION, TrainingInfo};
    use crate::rng::Rng;
    use proptest::prelude::*;

    pub(crate) fn sample_header() -> ModelHeader {
        ModelHeader {
            format: FORMAT.to_owned(),
            version: PCA_VERSION,
            kind: ModelKind::Pca,
            n_joints: 6,
            latent_dim: 2,
            joint_names: (1..=6).map(|i| format!("joint_{i}")).collect(),
            speed_scale_rad_s: 0.4,
            lipschitz_bound: None,
            network: None,
            training: TrainingInfo::default(),
        }
    }

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

    #[test]
    fn eval_is_basis_times_action() {
        let (data, _) = planar_data(500, 3);
        let mut map = fit(&data, 2).unwrap();
        let mut out = [0.0; 6];
        map.eval(&[0.0; 6], 0.0, &[0.3, -0.7], &mut out);
        let expect = map.basis() * DVector::from_vec(vec![0.3, -0.7]);
        for i in 0..6 {
            assert!((out[i] - expect[i]).abs() < 1e-12);
        }
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
