//! The Gen3's robot description (`robots/gen3.urdf`, through the profile `gen3`) against
//! Kinova's published kinematics, computed here independently, and its Jacobian against
//! finite differences and the `k` crate.
//!
//! The independent numbers come from the classical DH table of the Kinova Gen3 user guide
//! (Kinova Gen3 Ultra lightweight robot, User Guide, "Classical DH parameters", 7 DoF without
//! vision module; also reproduced, citing the guide, in public code such as
//! mattking-smith/Denavit-Hartenberg-Kinematics, `scripts/KinovaGen3_DH.m`):
//!
//! | frame | α (rad) | a (m) | d (m)              | θ (rad) |
//! |-------|---------|-------|--------------------|---------|
//! | B->0  | π       | 0     | 0                  | 0       |
//! | 1     | π/2     | 0     | -(0.1564 + 0.1284) | q1      |
//! | 2     | π/2     | 0     | -(0.0054 + 0.0064) | q2 + π  |
//! | 3     | π/2     | 0     | -(0.2104 + 0.2104) | q3 + π  |
//! | 4     | π/2     | 0     | -(0.0064 + 0.0064) | q4 + π  |
//! | 5     | π/2     | 0     | -(0.2084 + 0.1059) | q5 + π  |
//! | 6     | π/2     | 0     | 0                  | q6 + π  |
//! | 7     | π       | 0     | -(0.1059 + 0.0615) | q7 + π  |
//!
//! `T_i = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)`; frame 7 is the tool interface (the flange,
//! `end_effector_link`). The guide gives lengths to 0.1 mm where the URDF has 0.01 mm, so the
//! two agree to the rounding: at most 12 rounded lengths of 0.05 mm each, 0.6 mm; the test
//! allows 1 mm and prints the largest difference.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

mod common;

use std::f64::consts::{FRAC_PI_2, PI};

use common::{Lcg, numeric_jacobian};
use kinematics::{Jacobian, RobotProfile, gen3};
use nalgebra::{Isometry3, Matrix4, Rotation3, Vector3};

/// One row of the DH table: (α, d, θ offset); a is 0 in every row.
const DH: [(f64, f64, f64); 7] = [
    (FRAC_PI_2, -(0.1564 + 0.1284), 0.0),
    (FRAC_PI_2, -(0.0054 + 0.0064), PI),
    (FRAC_PI_2, -(0.2104 + 0.2104), PI),
    (FRAC_PI_2, -(0.0064 + 0.0064), PI),
    (FRAC_PI_2, -(0.2084 + 0.1059), PI),
    (FRAC_PI_2, 0.0, PI),
    (PI, -(0.1059 + 0.0615), PI),
];

/// Classical DH transform, written out as a matrix (no nalgebra geometry helpers).
fn dh(alpha: f64, a: f64, d: f64, theta: f64) -> Matrix4<f64> {
    let (st, ct) = theta.sin_cos();
    let (sa, ca) = alpha.sin_cos();
    Matrix4::new(
        ct,
        -st * ca,
        st * sa,
        a * ct,
        st,
        ct * ca,
        -ct * sa,
        a * st,
        0.0,
        sa,
        ca,
        d,
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

/// The flange's pose from the user guide's DH table.
fn dh_flange(q: &[f64]) -> Matrix4<f64> {
    let mut t = dh(PI, 0.0, 0.0, 0.0);
    for (i, (alpha, d, offset)) in DH.iter().enumerate() {
        t *= dh(*alpha, 0.0, *d, q[i] + offset);
    }
    t
}

fn position(t: &Matrix4<f64>) -> Vector3<f64> {
    Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)])
}

fn rotation(t: &Matrix4<f64>) -> Rotation3<f64> {
    Rotation3::from_matrix_unchecked(t.fixed_view::<3, 3>(0, 0).into_owned())
}

/// Poses: Kinova's named poses, and random ones over the whole range (continuous joints
/// over one turn either way).
fn poses() -> Vec<[f64; 7]> {
    let mut out = vec![gen3::ZERO, gen3::HOME, gen3::RETRACT];
    let p = RobotProfile::by_name("gen3").unwrap();
    let mut rng = Lcg(70);
    for _ in 0..200 {
        let mut q = [0.0; 7];
        for j in 0..7 {
            q[j] = rng.range(p.limits().lower_rad[j], p.limits().upper_rad[j]);
        }
        out.push(q);
    }
    out
}

#[test]
fn the_flange_is_where_the_dh_table_puts_it() {
    let p = RobotProfile::by_name("gen3").unwrap();
    let flange = p.model().chain(gen3::BASE_LINK, gen3::FLANGE_LINK).unwrap();
    let (mut worst_p, mut worst_r): (f64, f64) = (0.0, 0.0);
    for q in poses() {
        let want = dh_flange(&q);
        let got: Isometry3<f64> = flange.fk(&q).unwrap();
        worst_p = worst_p.max((got.translation.vector - position(&want)).norm());
        let r = got.rotation.to_rotation_matrix();
        worst_r = worst_r.max(r.angle_to(&rotation(&want)));
    }
    println!("URDF vs DH: flange position {worst_p:.2e} m, orientation {worst_r:.2e} rad");
    assert!(worst_p < 1e-3, "flange position differs by {worst_p} m");
    // angle_to goes through acos: about 1e-8 rad of rounding near zero.
    assert!(
        worst_r < 1e-6,
        "flange orientation differs by {worst_r} rad"
    );
}

/// The zero pose, by hand from the table: the arm straight up, the flange at the sum of the
/// vertical lengths, offset along -y... by the two 'sideways' lengths, facing up.
#[test]
fn the_zero_pose_by_hand() {
    let p = RobotProfile::by_name("gen3").unwrap();
    let up = 0.1564 + 0.1284 + 0.2104 + 0.2104 + 0.2084 + 0.1059 + 0.1059 + 0.0615;
    let side = 0.0054 + 0.0064 + 0.0064 + 0.0064;
    let tcp = p.arm().fk(&gen3::ZERO).unwrap();
    let want = Vector3::new(0.0, -side, up + 0.120);
    let err = (tcp.translation.vector - want).norm();
    assert!(err < 1e-3, "{} vs {want}: {err} m", tcp.translation.vector);
    // The tool points up: its z is the base's z.
    let z = tcp.rotation * Vector3::z();
    assert!((z - Vector3::z()).norm() < 1e-9, "{z}");
    // And matches the DH table's flange, 120 mm further along its z.
    let t = dh_flange(&gen3::ZERO);
    let dh_tcp = position(&t) + rotation(&t) * Vector3::new(0.0, 0.0, 0.120);
    assert!((tcp.translation.vector - dh_tcp).norm() < 1e-3);
}

/// The TCP is the DH flange 120 mm along the flange's z, at every pose.
#[test]
fn the_tcp_is_the_dh_flange_plus_the_gripper() {
    let p = RobotProfile::by_name("gen3").unwrap();
    let mut worst: f64 = 0.0;
    for q in poses() {
        let t = dh_flange(&q);
        let want = position(&t) + rotation(&t) * Vector3::new(0.0, 0.0, 0.120);
        let got = p.arm().fk(&q).unwrap().translation.vector;
        worst = worst.max((got - want).norm());
    }
    println!("URDF vs DH: TCP position {worst:.2e} m");
    assert!(worst < 1e-3, "TCP differs by {worst} m");
}

#[test]
fn gen3_jacobian_matches_finite_differences() {
    let arm = RobotProfile::by_name("gen3").unwrap().arm();
    let mut rng = Lcg(71);
    let mut jac = Jacobian::zeros(7);
    let mut worst: f64 = 0.0;
    for _ in 0..200 {
        let q = rng.config(arm, 0.0);
        arm.fk_jacobian(&q, &mut jac).unwrap();
        let num = numeric_jacobian(arm, &q, 1e-6);
        worst = worst.max((jac.padded() - num).abs().max());
    }
    assert_eq!(jac.n_joints(), 7);
    assert!(worst < 1e-7, "largest difference {worst}");
}

/// The `k` crate reads the same file with its own code (continuous joints included).
#[test]
fn gen3_matches_the_k_crate() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../robots/gen3.urdf");
    let tree = k::Chain::<f64>::from_urdf_file(path).unwrap();
    let serial = k::SerialChain::from_end(tree.find_link("tool_frame").unwrap());
    assert_eq!(serial.dof(), 7);
    let arm = RobotProfile::by_name("gen3").unwrap().arm();
    let mut jac = Jacobian::zeros(7);
    let mut worst: f64 = 0.0;
    for q in poses() {
        serial.set_joint_positions_unchecked(&q);
        serial.update_transforms();
        let theirs = k::jacobian(&serial);
        let end = serial.end_transform();
        let pose = arm.fk_jacobian(&q, &mut jac).unwrap();
        for r in 0..6 {
            for c in 0..7 {
                worst = worst.max((jac.get(r, c) - theirs[(r, c)]).abs());
            }
        }
        let theirs = end.translation.vector;
        let theirs = Vector3::new(theirs[0], theirs[1], theirs[2]);
        worst = worst.max((pose.translation.vector - theirs).norm());
    }
    assert!(worst < 1e-12, "differs from k by {worst}");
}
