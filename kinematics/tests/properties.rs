//! Property tests of the kinematics: FK is finite everywhere, the Jacobian is the derivative
//! of the FK, a damped least-squares step is bounded, IK stays finite and inside the limits.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

mod common;

use common::numeric_jacobian;
use kinematics::{Dls, Gen3Lite, Ik, Jacobian, TaskMask, planar5};
use nalgebra::{Isometry3, Vector6};
use proptest::prelude::*;

/// Six joint values inside the Gen3 lite's limits.
fn gen3_q() -> impl Strategy<Value = Vec<f64>> {
    let arm = Gen3Lite::get().arm();
    let ranges: Vec<_> = arm
        .lower()
        .iter()
        .zip(arm.upper())
        .map(|(lo, hi)| *lo..*hi)
        .collect();
    ranges
}

fn task_error() -> impl Strategy<Value = Vector6<f64>> {
    prop::array::uniform6(-1.0..1.0f64).prop_map(Vector6::from)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn fk_is_finite_and_rigid(q in prop::collection::vec(-10.0..10.0f64, 6)) {
        let t = Gen3Lite::get().arm().fk(&q).unwrap();
        prop_assert!(t.translation.vector.iter().all(|v| v.is_finite()));
        // The TCP never leaves the sphere of the arm's reach around the shoulder.
        let shoulder = nalgebra::Vector3::new(0.0, 0.0, 0.24325);
        prop_assert!((t.translation.vector - shoulder).norm() < 0.85);
        prop_assert!((t.rotation.quaternion().norm() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn jacobian_is_the_derivative_of_fk(q in gen3_q()) {
        let arm = Gen3Lite::get().arm();
        let mut jac = Jacobian::zeros(6);
        arm.fk_jacobian(&q, &mut jac).unwrap();
        let num = numeric_jacobian(arm, &q, 1e-6);
        let diff = (jac.padded() - num).abs().max();
        prop_assert!(diff < 1e-7, "max difference {}", diff);
    }

    #[test]
    fn planar_jacobian_is_the_derivative_of_fk(q in prop::collection::vec(-2.6..2.6f64, 5)) {
        let chain = planar5::get();
        let mut jac = Jacobian::zeros(5);
        chain.fk_jacobian(&q, &mut jac).unwrap();
        let num = numeric_jacobian(chain, &q, 1e-6);
        prop_assert!((jac.padded() - num).abs().max() < 1e-7);
    }

    /// DLS singular values are σ / (σ² + λ²) ≤ min(1/σ_min, 1/(2λ)): the step is never
    /// longer than |e| times that, and never longer than the configured bound.
    #[test]
    fn dls_step_is_bounded(
        q in gen3_q(),
        e in task_error(),
        max_step in 0.01..2.0f64,
        position_only in any::<bool>(),
    ) {
        let arm = Gen3Lite::get().arm();
        let mut jac = Jacobian::zeros(6);
        arm.fk_jacobian(&q, &mut jac).unwrap();
        let mask = if position_only { TaskMask::POSITION } else { TaskMask::POSE };
        let mut e_task = e;
        for r in 0..6 {
            if !mask.0[r] {
                e_task[r] = 0.0;
            }
        }
        let mut dq = [0.0; 6];
        let free = Dls { mask, ..Dls::default() };
        let s = free.step(&jac, &e, &mut dq).unwrap();
        let norm = dq.iter().map(|v| v * v).sum::<f64>().sqrt();
        prop_assert!(dq.iter().all(|v| v.is_finite()));
        let gain = (1.0 / s.sigma_min).min(1.0 / (2.0 * s.damping));
        prop_assert!(norm <= e_task.norm() * gain * (1.0 + 1e-9) + 1e-12,
            "|dq| {} > |e| {} x {}", norm, e_task.norm(), gain);
        prop_assert!((norm - s.raw_norm).abs() < 1e-9);
        let bounded = Dls { max_step, ..free };
        bounded.step(&jac, &e, &mut dq).unwrap();
        let norm2 = dq.iter().map(|v| v * v).sum::<f64>().sqrt();
        prop_assert!(norm2 <= max_step * (1.0 + 1e-12));
    }

    /// Whatever the target (reachable or not), IK ends finite and inside the limits, and no
    /// farther from the target than it started.
    #[test]
    fn ik_stays_finite_and_inside_the_limits(
        seed in gen3_q(),
        x in -1.5..1.5f64, y in -1.5..1.5f64, z in -0.5..1.5f64,
    ) {
        let arm = Gen3Lite::get().arm();
        let target = Isometry3::translation(x, y, z);
        let ik = Ik {
            dls: Dls { mask: TaskMask::POSITION, ..Ik::default().dls },
            max_iterations: 60,
            ..Ik::default()
        };
        let start = (arm.fk(&seed).unwrap().translation.vector - target.translation.vector).norm();
        let mut q = seed.clone();
        let r = ik.solve(arm, &target, &mut q).unwrap();
        prop_assert!(q.iter().all(|v| v.is_finite()));
        prop_assert!(arm.within_limits(&q));
        prop_assert!(r.position_error <= start + 1e-9, "{} > {}", r.position_error, start);
    }
}
