//! planar5: the 5-DOF planar arm of the paper's simulated reaching study
//! (`robots/planar5.urdf`, embedded). Five revolute joints about z, five 0.2 m links along x:
//! at `q = 0` the tip is at `(1.0, 0, 0)`.

use std::sync::OnceLock;

use crate::chain::Chain;
use crate::robot::{RobotModel, UrdfError};

/// Number of joints.
pub const N_JOINTS: usize = 5;

/// Length of each link (m).
pub const LINK_LENGTH_M: f64 = 0.2;

/// The robot description, `robots/planar5.urdf`, embedded at build time.
pub const URDF: &str = include_str!("../../robots/planar5.urdf");

/// How the embedded description is named in messages.
pub const URDF_NAME: &str = "robots/planar5.urdf";

/// The base link.
pub const BASE_LINK: &str = "base_link";

/// The tip link, 0.2 m beyond the fifth joint.
pub const TIP_LINK: &str = "tip";

static CHAIN: OnceLock<Chain> = OnceLock::new();

/// Parses the embedded URDF into the chain `base_link -> tip`.
pub fn load() -> Result<Chain, UrdfError> {
    RobotModel::from_urdf_str(URDF, URDF_NAME)?.chain(BASE_LINK, TIP_LINK)
}

/// The chain parsed from the embedded URDF, once per process.
///
/// # Panics
///
/// If the embedded `robots/planar5.urdf` does not load, a build defect that the crate's
/// tests catch (`embedded_planar5_loads`).
pub fn get() -> &'static Chain {
    CHAIN.get_or_init(|| match load() {
        Ok(c) => c,
        Err(e) => panic!("the embedded planar5 description is broken: {e}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_planar5_loads() {
        let c = load().unwrap();
        assert_eq!(c.n_joints(), N_JOINTS);
        let t = c.fk(&[0.0; 5]).unwrap();
        assert!((t.translation.vector - nalgebra::Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        // Folded back at the second joint: one link out, four back.
        let t = c
            .fk(&[0.0, std::f64::consts::PI - 1e-12, 0.0, 0.0, 0.0])
            .unwrap();
        assert!((t.translation.x + 0.6).abs() < 1e-9, "{}", t.translation.x);
        assert_eq!(get().velocity_limits(), &[1.0; 5]);
    }
}
