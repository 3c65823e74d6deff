//! PCA, the paper's linear baseline: `map(o, a) = Σ a`, where the columns of `Σ` (m × d) are
//! the top-d principal components of the demonstrated joint velocities. The map does not
//! depend on the state.

use std::path::Path;

use nalgebra::DMatrix;
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::model::{FORMAT, ModelHeader, PCA_VERSION, TrainingInfo};
    use crate::rng::Rng;
    use nalgebra::DVector;

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
    fn eval_is_basis_times_action() {
        let (_, truth) = planar_data(500, 3);
        let mut map = PcaMap::new(DMatrix::from_columns(&[truth.column(0), truth.column(1)]));
        let mut out = [0.0; 6];
        map.eval(&[0.0; 6], 0.0, &[0.3, -0.7], &mut out);
        let expect = map.basis() * DVector::from_vec(vec![0.3, -0.7]);
        for i in 0..6 {
            assert!((out[i] - expect[i]).abs() < 1e-12);
        }
    }
}
