//! The control-path calls allocate nothing: FK, FK + Jacobian, link poses, a DLS step and a
//! whole IK solve, counted by a global allocator that counts this thread's allocations.
//!
//! One test in this file, so no other test shares the process's allocator while it counts.
#![allow(clippy::unwrap_used)]

use kinematics::{Dls, Gen3Lite, Ik, Jacobian, gen3_lite, pose_error};
use nalgebra::{Isometry3, Translation3};

#[global_allocator]
static GLOBAL: test_support::CountingAllocator = test_support::CountingAllocator;

fn allocations() -> usize {
    test_support::thread_allocations()
}

#[test]
fn the_hot_path_does_not_allocate() {
    // Set-up may allocate: parse the URDF, build the chain and the buffers.
    let g = Gen3Lite::get();
    let arm = g.arm();
    let mut jac = Jacobian::zeros(arm.n_joints());
    let mut dq = [0.0; 6];
    let dls = Dls::default();
    let ik = Ik::default();
    let flange = arm.link_id("end_effector_link").unwrap();
    let home = arm.fk(&gen3_lite::HOME).unwrap();
    let target = Isometry3::from_parts(Translation3::new(0.35, -0.1, 0.3), home.rotation);

    // The counter sees allocations (so a zero below means something).
    let before = allocations();
    let v: Vec<u64> = Vec::with_capacity(16);
    drop(std::hint::black_box(v));
    assert_eq!(allocations(), before + 1);

    let before = allocations();
    let mut q = gen3_lite::HOME;
    let mut acc = 0.0;
    for k in 0..2000 {
        q[0] = 0.001 * k as f64;
        q[3] = -0.0005 * k as f64;
        let tcp = arm.fk_jacobian(&q, &mut jac).unwrap();
        acc += arm.fk(&q).unwrap().translation.x;
        acc += arm.link_pose(&q, flange).unwrap().translation.z;
        acc += g.tcp_pose(&q).unwrap().position.x as f64;
        let e = pose_error(&tcp, &target);
        let s = dls.step(&jac, &e, &mut dq).unwrap();
        acc += s.damping + dq[0];
    }
    // Including the singular zero pose.
    arm.fk_jacobian(&gen3_lite::ZERO, &mut jac).unwrap();
    let e = pose_error(&arm.fk(&gen3_lite::ZERO).unwrap(), &target);
    dls.step(&jac, &e, &mut dq).unwrap();
    let mut q = gen3_lite::HOME;
    let r = ik.solve(arm, &target, &mut q).unwrap();
    let after = allocations();
    assert!(r.converged && acc.is_finite());
    assert_eq!(
        after - before,
        0,
        "the control path allocated {} times",
        after - before
    );
}
