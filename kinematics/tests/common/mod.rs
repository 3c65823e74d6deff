//! Helpers shared by the integration tests.
#![allow(dead_code, clippy::unwrap_used)]

use kinematics::{Chain, pose_error};
use nalgebra::SMatrix;

/// Central finite-difference Jacobian of the chain's tip: linear rows from the position,
/// angular rows from the rotation vector between the two perturbed orientations.
pub fn numeric_jacobian(chain: &Chain, q: &[f64], h: f64) -> SMatrix<f64, 6, 8> {
    let mut out = SMatrix::<f64, 6, 8>::zeros();
    let mut qp = q.to_vec();
    let mut qm = q.to_vec();
    for i in 0..chain.n_joints() {
        qp.copy_from_slice(q);
        qm.copy_from_slice(q);
        qp[i] += h;
        qm[i] -= h;
        let tp = chain.fk(&qp).unwrap();
        let tm = chain.fk(&qm).unwrap();
        // pose_error(a, b) is b - a: the twist that takes tm to tp, over 2h.
        let d = pose_error(&tm, &tp) / (2.0 * h);
        for r in 0..6 {
            out[(r, i)] = d[r];
        }
    }
    out
}

/// A small deterministic generator for test poses (SplitMix64).
pub struct Lcg(pub u64);

impl Lcg {
    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        lo + (hi - lo) * ((z >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// A configuration uniformly inside the chain's limits, shrunk by `margin` on each side.
    pub fn config(&mut self, chain: &Chain, margin: f64) -> Vec<f64> {
        chain
            .lower()
            .iter()
            .zip(chain.upper())
            .map(|(lo, hi)| self.range(lo + margin, hi - margin))
            .collect()
    }
}
