//! The geometric Jacobian against finite differences of the FK, and against openrr's `k`
//! crate (an independent URDF reader and Jacobian) at random poses.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

mod common;

use common::{Lcg, numeric_jacobian};
use kinematics::{Gen3Lite, Jacobian, planar5};

#[test]
fn gen3_lite_jacobian_matches_finite_differences() {
    let arm = Gen3Lite::get().arm();
    let mut rng = Lcg(11);
    let mut jac = Jacobian::zeros(6);
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let q = rng.config(arm, 0.0);
        arm.fk_jacobian(&q, &mut jac).unwrap();
        let num = numeric_jacobian(arm, &q, 1e-6);
        worst = worst.max((jac.padded() - num).abs().max());
    }
    assert!(worst < 1e-7, "largest difference {worst}");
}

#[test]
fn planar5_jacobian_matches_finite_differences() {
    let chain = planar5::get();
    let mut rng = Lcg(12);
    let mut jac = Jacobian::zeros(5);
    for _ in 0..100 {
        let q = rng.config(chain, 0.0);
        chain.fk_jacobian(&q, &mut jac).unwrap();
        let num = numeric_jacobian(chain, &q, 1e-6);
        assert!((jac.padded() - num).abs().max() < 1e-7);
        // A planar arm: no z velocity, no roll or pitch, unit yaw rate per joint.
        for c in 0..5 {
            assert_eq!(jac.get(2, c), 0.0);
            assert!(jac.get(3, c).abs() < 1e-15 && jac.get(4, c).abs() < 1e-15);
            assert!((jac.get(5, c) - 1.0).abs() < 1e-12);
        }
    }
}

/// The `k` crate reads the same URDF file with its own code and computes its own Jacobian.
#[test]
fn gen3_lite_matches_the_k_crate() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../robots/gen3_lite.urdf");
    let tree = k::Chain::<f64>::from_urdf_file(path).unwrap();
    let tcp = tree.find_link("tool_frame").unwrap();
    let serial = k::SerialChain::from_end(tcp);
    assert_eq!(serial.dof(), 6);
    let arm = Gen3Lite::get().arm();
    let mut rng = Lcg(13);
    let mut jac = Jacobian::zeros(6);
    let (mut worst_j, mut worst_p): (f64, f64) = (0.0, 0.0);
    for _ in 0..500 {
        let q = rng.config(arm, 1e-6);
        serial.set_joint_positions(&q).unwrap();
        serial.update_transforms();
        let theirs = k::jacobian(&serial);
        let end = serial.end_transform();
        let pose = arm.fk_jacobian(&q, &mut jac).unwrap();
        for r in 0..6 {
            for c in 0..6 {
                worst_j = worst_j.max((jac.get(r, c) - theirs[(r, c)]).abs());
            }
        }
        for r in 0..3 {
            worst_p = worst_p.max((pose.translation.vector[r] - end.translation.vector[r]).abs());
        }
        let (a, b) = (pose.rotation.quaternion(), end.rotation.quaternion());
        let dot = a.w * b.w + a.i * b.i + a.j * b.j + a.k * b.k;
        assert!(dot.abs() > 1.0 - 1e-12, "orientation differs at {q:?}");
    }
    println!("Jacobian vs k: max |difference| {worst_j:.3e}; TCP position {worst_p:.3e} m");
    assert!(worst_j < 1e-12, "Jacobian differs from k's by {worst_j}");
    assert!(worst_p < 1e-12, "TCP differs from k's by {worst_p} m");
}
