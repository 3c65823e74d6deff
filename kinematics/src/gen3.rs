//! Kinova Gen3 (7 DoF) with a Robotiq 2F-85 gripper: the robot description
//! (`robots/gen3.urdf`, embedded) and the teleoperation facts that are not in a URDF. The graph
//! takes them through the profile `gen3` ([`crate::RobotProfile::by_name`]).
//!
//! # Sources
//!
//! * Joint origins, axes, velocity limits (80 °/s for the large actuators of joints 1-4,
//!   70 °/s for the small ones of joints 5-7) and the position limits of joints 2, 4, 6
//!   (±128.9°, ±147.8°, ±120.3°): `robots/gen3.urdf`, whose header cites Kinova's Gen3 user
//!   guide and robot description for each number. `kinematics/tests/gen3_dh.rs` checks the
//!   file against the user guide's classical DH table.
//! * Named poses: the Gen3 user guide, "Home and retract positions" (7 DoF), as the arm
//!   reports them (degrees in [0, 360)): home (0, 15, 180, 230, 0, 55, 90), retract
//!   (0, 340, 180, 214, 0, 310, 90); zero is every actuator at 0 (the arm straight up, a
//!   singular pose). Here in radians, each angle brought into (-π, π]. Kinova's MoveIt
//!   configuration of the Gen3 7 DoF (ros2_kortex, `kinova_gen3_7dof_robotiq_2f_85_moveit_config/
//!   config/gen3.srdf`, states `Home`, `Retract`, `Vertical`) has the same values to 0.01 rad.
//! * Control rate: 40 Hz, the Kortex high-level API's rate (the same base controller as the
//!   Gen3 lite's, shared/reference/gen3-lite.md).
//! * Gripper: the Robotiq 2F-85 as Kinova describes it on the Gen3 (`finger_joint`, 0 open ..
//!   0.8 rad closed, see the URDF). Its lag: a full 85 mm stroke at the 2F-85's top speed of
//!   150 mm/s takes 0.57 s (Robotiq 2F-85 specifications); a first-order lag reaches 90 % in
//!   2.3 τ, so τ = 0.25 s.
//! * Teleoperation speed and acceleration defaults: the project's choice, well inside the
//!   URDF's limits (0.5 rad/s = 36 % of the large actuators' 1.3963 rad/s, 0.6 rad/s = 49 % of
//!   the small ones' 1.2218 rad/s; 1 rad/s² and 2 rad/s²), in the proportions the Gen3 lite's
//!   defaults have to its actuators.
//!
//! # Continuous joints
//!
//! Joints 1, 3, 5 and 7 turn without end on the arm (slip rings; the URDF writes them
//! `continuous`). The profile treats them so:
//!
//! * **Limits for safety's margins**: they get the software limits ±[`CONTINUOUS_LIMIT_RAD`]
//!   (2π, the range Kinova's own ROS 2 driver gives their position commands): every joint
//!   of the profile has a finite range, so the safety filter's joint-limit margins, the mock
//!   arm's clamp, the dashboard's bars and the samplers of the learning crate work unchanged.
//!   One turn either way from zero is more than teleoperation needs; beyond it the filter
//!   stops the joint as at any limit, which also keeps a drifting joint from winding up.
//! * **Angles are continuous numbers**: a joint state holds the joint's angle as it moved,
//!   not wrapped (the home pose's joint 3 sits at π, so wrapping to (-π, π] would make it jump
//!   by 2π at the smallest motion). A bridge that reads angles in [0, 360°) must unwrap them
//!   (track the turn count from its first sample).
//! * **Wrapping for the maps' inputs**: learned maps see each continuous joint brought into
//!   the turn centred on the home pose, `(home - π, home + π]`
//!   ([`crate::RobotProfile::wrap_for_maps`]): the same arm pose always gives the same input,
//!   and the working region around home has no jump. Limited joints pass unchanged.

use std::sync::OnceLock;

use crate::collision::{CollisionError, CollisionModel, ModelArm};
use crate::robot::RobotModel;

/// Number of arm joints.
pub const N_JOINTS: usize = 7;

/// Joint names of the arm chain (as in the URDF).
pub const JOINT_NAMES: [&str; N_JOINTS] = [
    "joint_1", "joint_2", "joint_3", "joint_4", "joint_5", "joint_6", "joint_7",
];

/// The robot description, `robots/gen3.urdf`, embedded at build time.
pub const URDF: &str = include_str!("../../robots/gen3.urdf");

/// How the embedded description is named in messages.
pub const URDF_NAME: &str = "robots/gen3.urdf";

/// The base link: every pose is expressed in its frame.
pub const BASE_LINK: &str = "base_link";

/// The flange (the tool interface of the last actuator).
pub const FLANGE_LINK: &str = "end_effector_link";

/// The tool centre point between the 2F-85's fingers, 120 mm beyond the flange.
pub const TCP_LINK: &str = "tool_frame";

/// The 2F-85's one actuated joint.
pub const GRIPPER_JOINT: &str = "finger_joint";

/// The gripper joint's value when open (rad).
pub const GRIPPER_OPEN_RAD: f64 = 0.0;

/// The gripper joint's value when closed (rad).
pub const GRIPPER_CLOSED_RAD: f64 = 0.8;

/// Software position limit of the continuous joints 1, 3, 5, 7: ±2π (see the module docs).
pub const CONTINUOUS_LIMIT_RAD: f64 = 2.0 * std::f64::consts::PI;

/// Teleoperation default velocity limits (rad/s): large actuators, then small ones.
pub const DEFAULT_VELOCITY_RAD_S: [f64; N_JOINTS] = [0.5, 0.5, 0.5, 0.5, 0.6, 0.6, 0.6];

/// Teleoperation default acceleration limits (rad/s²).
pub const DEFAULT_ACCELERATION_RAD_S2: [f64; N_JOINTS] = [1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0];

/// Degrees to radians for the tables below.
const fn deg(d: f64) -> f64 {
    d * std::f64::consts::PI / 180.0
}

/// The zero pose: every actuator at 0, the arm straight up (singular).
pub const ZERO: [f64; N_JOINTS] = [0.0; N_JOINTS];

/// The home pose: (0, 15, 180, 230, 0, 55, 90)° as the arm reports it, in (-π, π].
pub const HOME: [f64; N_JOINTS] = [
    0.0,
    deg(15.0),
    deg(180.0),
    deg(-130.0),
    0.0,
    deg(55.0),
    deg(90.0),
];

/// The retract pose: (0, 340, 180, 214, 0, 310, 90)° as the arm reports it, in (-π, π].
pub const RETRACT: [f64; N_JOINTS] = [
    0.0,
    deg(-20.0),
    deg(180.0),
    deg(-146.0),
    0.0,
    deg(-50.0),
    deg(90.0),
];

/// The rate of the high-level API (Hz).
pub const CONTROL_RATE_HZ: f64 = 40.0;

/// Gripper: time constant of the first-order lag used by the mock (s).
pub const GRIPPER_TIME_CONSTANT_S: f64 = 0.25;

/// The Gen3's bundled model, `models/gen3.safetensors`: SCL (d = 2, 2 x 128 tanh,
/// Gram-Schmidt, L = 1, 200 epochs, best of 10 seeds) on the generated Gen3 pick-and-place
/// demonstrations in `data/gen3-pick-and-place`, speed scale 0.6 rad/s
/// (`scripts/regenerate-bundled-model.sh gen3`).
pub const BUNDLED_MODEL: &[u8] = include_bytes!("../../models/gen3.safetensors");

/// The collision model, `robots/gen3_collision.toml`, embedded at build time.
pub const COLLISION_TOML: &str = include_str!("../../robots/gen3_collision.toml");

/// How the embedded collision model is named in messages.
pub const COLLISION_TOML_NAME: &str = "robots/gen3_collision.toml";

/// The arm as the collision model's loader checks it. The 2F-85's fingers are one envelope
/// on `gripper_base_link`, so no finger link hangs from the gripper joint.
pub const COLLISION_ARM: ModelArm<'static> = ModelArm {
    name: "the Gen3",
    joint_names: &JOINT_NAMES,
    base_link: BASE_LINK,
    tool_link: "gripper_base_link",
    gripper_joint: Some(GRIPPER_JOINT),
};

/// Loads the embedded collision model on the embedded URDF.
pub fn load_collision_model() -> Result<CollisionModel, CollisionError> {
    let robot = RobotModel::from_urdf_str(URDF, URDF_NAME)?;
    CollisionModel::for_arm(COLLISION_TOML, COLLISION_TOML_NAME, &robot, &COLLISION_ARM)
}

/// The embedded collision model, loaded once per process.
///
/// # Panics
///
/// If the embedded `robots/gen3_collision.toml` does not load, a build defect that the
/// crate's tests catch (`the_collision_model_loads`).
pub fn collision_model() -> &'static CollisionModel {
    static MODEL: OnceLock<CollisionModel> = OnceLock::new();
    MODEL.get_or_init(|| match load_collision_model() {
        Ok(m) => m,
        Err(e) => panic!("the embedded Gen3 collision model is broken: {e}"),
    })
}

/// A named pose by name (`zero`, `home`, `retract`).
pub fn named_pose(name: &str) -> Option<[f64; N_JOINTS]> {
    match name {
        "zero" => Some(ZERO),
        "home" => Some(HOME),
        "retract" => Some(RETRACT),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RobotProfile;
    use nalgebra::Vector3;
    use std::f64::consts::PI;

    #[test]
    fn the_profile_is_the_gen3() {
        let p = RobotProfile::by_name("gen3").unwrap();
        assert_eq!(p.n_joints(), N_JOINTS);
        assert_eq!(p.joint_names(), JOINT_NAMES);
        assert_eq!(p.description(), "Gen3");
        assert_eq!(p.control_rate_hz(), 40.0);
        assert_eq!(p.gripper_time_constant_s(), GRIPPER_TIME_CONSTANT_S);
        for name in ["zero", "home", "retract"] {
            assert_eq!(p.named_pose(name).unwrap(), named_pose(name).unwrap());
        }
        assert!(named_pose("nowhere").is_none());
        let g = p.gripper().unwrap();
        assert_eq!(g.joint(), GRIPPER_JOINT);
        assert_eq!((g.open_rad(), g.closed_rad()), (0.0, 0.8));
        assert!((g.angle(0.5) - 0.4).abs() < 1e-15);
    }

    #[test]
    fn the_collision_model_loads() {
        use crate::collision::{Clearance, CollisionLink, Scene};
        let m = load_collision_model().unwrap();
        assert_eq!(m.n_joints(), N_JOINTS);
        assert_eq!(m.links().len(), 9);
        assert!(m.has_link(CollisionLink::Bracelet) && !m.has_link(CollisionLink::Arm));
        assert_eq!(m.capsule_refs().len(), 10);
        assert_eq!(m.exclusions().len(), 25);
        // 36 link pairs less 25 excluded: 11; four of them have the gripper's two capsules.
        assert_eq!(m.self_pairs().len(), 15);
        assert!(m.link_capsules(CollisionLink::Arm).is_empty());
        assert_eq!(m.gripper_range(), (0.0, 0.8));
        let p = RobotProfile::by_name("gen3").unwrap();
        assert!(std::ptr::eq(
            p.collision_model().unwrap(),
            collision_model()
        ));
        // Kinova's poses are free of self-collision, and clear of a table at z = 0 but for
        // the base and shoulder, which stand on it.
        let mut out = Clearance::default();
        for name in ["home", "retract", "zero"] {
            let q = named_pose(name).unwrap();
            m.clearance(&q, &Scene::default(), &mut out).unwrap();
            let c = out.closest().unwrap();
            assert!(
                c.distance_m > 0.0,
                "{name}: {} at {} m",
                c.pair,
                c.distance_m
            );
            assert_eq!(out.n_joints(), N_JOINTS);
            match out.rate_row(c) {
                // Seven columns, zero beyond.
                Some(g) => assert!(g[N_JOINTS..].iter().all(|v| *v == 0.0), "{g:?}"),
                None => assert!(c.normal.is_none()),
            }
        }
    }

    /// A pose away from the singular zero pose that moves every joint.
    const SOMEWHERE: [f64; N_JOINTS] = [0.3, 0.5, -2.6, -1.9, 0.4, 0.8, -0.7];

    /// The point and angular Jacobians of every capsule end (seven columns, zero beyond)
    /// against finite differences of the capsule ends and the link poses.
    #[test]
    fn capsule_end_jacobians_match_finite_differences() {
        use crate::collision::{Clearance, MAX_ARM_JOINTS, Scene};
        let m = collision_model();
        let scene = Scene::default();
        let mut out = Clearance::default();
        let mut moved = Clearance::default();
        m.clearance(&SOMEWHERE, &scene, &mut out).unwrap();
        assert_eq!(out.n_joints(), N_JOINTS);
        let h = 1e-7;
        let mut moving = [false; N_JOINTS];
        for (k, r) in m.capsule_refs().iter().enumerate() {
            let c = out.capsules()[k];
            let rot = out.link_pose(r.link).rotation;
            for (end, p) in [("a", c.a), ("b", c.b)] {
                let jp = out.point_jacobian(r.link, &p);
                let jw = out.angular_jacobian(r.link);
                assert!(
                    jp[N_JOINTS..MAX_ARM_JOINTS]
                        .iter()
                        .all(|v| *v == Vector3::zeros())
                );
                assert!(
                    jw[N_JOINTS..MAX_ARM_JOINTS]
                        .iter()
                        .all(|v| *v == Vector3::zeros())
                );
                for j in 0..N_JOINTS {
                    let mut qh = SOMEWHERE;
                    qh[j] += h;
                    m.clearance(&qh, &scene, &mut moved).unwrap();
                    let ch = moved.capsules()[k];
                    let fd = (if end == "a" { ch.a } else { ch.b } - p) / h;
                    assert!(
                        (fd - jp[j]).norm() < 1e-6,
                        "{r}.{end} joint {j}: {fd} vs {}",
                        jp[j]
                    );
                    let w = (moved.link_pose(r.link).rotation * rot.inverse()).scaled_axis() / h;
                    assert!((w - jw[j]).norm() < 1e-6, "{r} joint {j}: {w} vs {}", jw[j]);
                    moving[j] |= fd.norm() > 1e-3;
                }
            }
        }
        // Every joint, the seventh included, moves some capsule end.
        assert_eq!(moving, [true; N_JOINTS]);
    }

    /// `d_dot = g · qdot` against central differences of each pair's distance along `qdot`,
    /// with a table and a box near the gripper: every pair with a normal whose distance is
    /// smooth there (the differences over h and 2h agree), the seventh joint moving.
    #[test]
    fn rate_rows_are_the_derivative_of_the_distances() {
        use crate::collision::{Clearance, Scene};
        use nalgebra::Point3;
        let m = collision_model();
        let mut scene = Scene::with_table(-0.02).unwrap();
        let mut out = Clearance::default();
        m.clearance(&SOMEWHERE, &scene, &mut out).unwrap();
        let tool = out
            .link_pose(crate::collision::CollisionLink::GripperBase)
            .translation;
        let c = Point3::from(tool.vector);
        scene
            .add_box(
                c + Vector3::new(0.05, -0.1, -0.1),
                c + Vector3::new(0.2, 0.1, 0.1),
            )
            .unwrap();
        let distances = |q: &[f64]| {
            let mut o = Clearance::default();
            m.clearance(q, &scene, &mut o).unwrap();
            o.distances_m().to_vec()
        };
        for qdot in [
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            [0.3, -0.5, 0.2, 0.7, -0.4, 0.6, -0.8],
        ] {
            let step = |h: f64| {
                let q: Vec<f64> = SOMEWHERE.iter().zip(qdot).map(|(q, v)| q + h * v).collect();
                distances(&q)
            };
            let h = 1e-5;
            let (p1, m1, p2, m2) = (step(h), step(-h), step(2.0 * h), step(-2.0 * h));
            m.clearance(&SOMEWHERE, &scene, &mut out).unwrap();
            let mut checked = 0;
            let mut moving = 0;
            for i in 0..out.distances_m().len() {
                let contact = out.contact(i).unwrap();
                let Some(g) = out.rate_row(&contact) else {
                    continue;
                };
                let fd1 = (p1[i] - m1[i]) / (2.0 * h);
                let fd2 = (p2[i] - m2[i]) / (4.0 * h);
                if (fd1 - fd2).abs() > 1e-6 {
                    continue;
                }
                let analytic: f64 = g.iter().zip(qdot).map(|(g, v)| g * v).sum();
                assert!(
                    (analytic - fd1).abs() < 1e-5,
                    "{}: d_dot {analytic} vs finite differences {fd1}",
                    contact.pair
                );
                checked += 1;
                moving += usize::from(fd1.abs() > 1e-3);
            }
            assert!(
                checked > 10 && moving > 0,
                "{checked} pairs, {moving} moving"
            );
        }
    }

    #[test]
    fn limits_come_from_the_urdf_and_the_continuous_joints_get_two_turns() {
        let p = RobotProfile::by_name("gen3").unwrap();
        let l = p.limits();
        let w = CONTINUOUS_LIMIT_RAD;
        assert_eq!(l.upper_rad, [w, 2.2497, w, 2.5796, w, 2.0996, w]);
        assert_eq!(l.lower_rad, [-w, -2.2497, -w, -2.5796, -w, -2.0996, -w]);
        assert_eq!(p.arm().lower(), l.lower_rad);
        assert_eq!(
            p.urdf_velocity_rad_s(),
            [1.3963, 1.3963, 1.3963, 1.3963, 1.2218, 1.2218, 1.2218]
        );
        // The defaults are below the actuators' speeds, so they stand.
        assert_eq!(l.max_velocity_rad_s, DEFAULT_VELOCITY_RAD_S);
        assert_eq!(l.max_acceleration_rad_s2, DEFAULT_ACCELERATION_RAD_S2);
        assert_eq!(
            p.continuous_joints(),
            [true, false, true, false, true, false, true]
        );
    }

    #[test]
    fn named_poses_are_kinovas_in_degrees() {
        let d = |q: [f64; N_JOINTS]| q.map(|v| (v.to_degrees() * 1e9).round() / 1e9);
        assert_eq!(d(HOME), [0.0, 15.0, 180.0, -130.0, 0.0, 55.0, 90.0]);
        assert_eq!(d(RETRACT), [0.0, -20.0, 180.0, -146.0, 0.0, -50.0, 90.0]);
        // As the arm reports them, in [0, 360).
        let wire = |q: [f64; N_JOINTS]| d(q).map(|v| v.rem_euclid(360.0));
        assert_eq!(wire(HOME), [0.0, 15.0, 180.0, 230.0, 0.0, 55.0, 90.0]);
        assert_eq!(wire(RETRACT), [0.0, 340.0, 180.0, 214.0, 0.0, 310.0, 90.0]);
        let p = RobotProfile::by_name("gen3").unwrap();
        for name in ["zero", "home", "retract"] {
            let mut q = named_pose(name).unwrap();
            assert!(!p.limits().clamp_position(&mut q), "{name}");
        }
    }

    /// The maps see continuous joints in the turn centred on home; the arm pose is the same.
    #[test]
    fn wrapping_for_the_maps_keeps_the_pose_and_centres_on_home() {
        let p = RobotProfile::by_name("gen3").unwrap();
        let mut q = HOME;
        p.wrap_for_maps(&mut q);
        assert_eq!(q, HOME);
        // Joint 3 a little past π (home's value), reported as a continuous angle and as
        // the wrapped -π + ε: both reach the maps as π + ε.
        let eps = 0.01;
        for j3 in [PI + eps, -PI + eps, 3.0 * PI + eps] {
            let mut q = HOME;
            q[2] = j3;
            // A limited joint outside (-π, π] is left alone (its limits hold it anyway).
            q[3] = -2.5;
            p.wrap_for_maps(&mut q);
            assert!((q[2] - (PI + eps)).abs() < 1e-12, "{j3}: {}", q[2]);
            assert_eq!(q[3], -2.5);
        }
        let t = |q: &[f64]| p.arm().fk(q).unwrap();
        let mut q = HOME;
        q[0] = 1.5 * PI;
        q[6] = -1.9 * PI;
        let before = t(&q);
        p.wrap_for_maps(&mut q);
        assert!((q[0] + 0.5 * PI).abs() < 1e-12 && (q[6] - 0.1 * PI).abs() < 1e-12);
        let after = t(&q);
        assert!((before.translation.vector - after.translation.vector).norm() < 1e-12);
        assert!(before.rotation.angle_to(&after.rotation) < 1e-12);
    }
}
