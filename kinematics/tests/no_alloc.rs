//! The control-path calls allocate nothing: FK, FK + Jacobian, link poses, a DLS step, a
//! whole IK solve, and the collision model's clearance with its rate rows, counted by a global
//! allocator that counts this thread's allocations.
//!
//! One test in this file, so no other test shares the process's allocator while it counts.
#![allow(clippy::unwrap_used)]

use kinematics::collision::{Clearance, CollisionModel, Scene};
use kinematics::{Dls, Gen3Lite, Ik, Jacobian, JointAxis, MAX_DOF, gen3_lite, pose_error};
use nalgebra::{Isometry3, Point3, Translation3};

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
    let collision = CollisionModel::get();
    let mut scene = Scene::default();
    scene
        .add_box(Point3::new(0.3, -0.3, 0.0), Point3::new(0.5, -0.1, 0.2))
        .unwrap();
    let mut clearance = Box::new(Clearance::default());
    let mut poses = [Isometry3::identity(); 8];
    let mut axes = [JointAxis::UNUSED; MAX_DOF];

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
        arm.link_poses(&q, &mut poses, &mut axes).unwrap();
        acc += poses[3].translation.z;
        // The collision model, with and without the gripper's value.
        collision.clearance(&q, &scene, &mut clearance).unwrap();
        let mut qg = [0.0; 7];
        qg[..6].copy_from_slice(&q);
        qg[6] = 0.3;
        collision.clearance(&qg, &scene, &mut clearance).unwrap();
        acc += clearance.min_distance_m();
        acc += clearance.closest_rate_row().map_or(0.0, |g| g[1]);
        if let Some(c) = clearance.contact(k % clearance.distances_m().len()) {
            acc += clearance.rate_row(&c).map_or(0.0, |g| g[0]);
            let link = c.pair.a.link;
            acc += clearance.point_jacobian(link, &c.point_a)[0].x;
            acc += clearance.angular_jacobian(link)[0].z;
        }
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
