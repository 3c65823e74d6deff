//! The Gen3 lite's collision model against its URDF and its data file: load-time checks and
//! their messages, the excluded pairs, every joint origin inside its links' capsules, the
//! named poses clear of the table and of themselves, a pose into the table reported.
#![allow(clippy::unwrap_used)]

mod common;

use kinematics::collision::{
    COLLISION_TOML, COLLISION_TOML_NAME, Clearance, CollisionError, CollisionLink, CollisionModel,
    Scene, Target,
};
use kinematics::{Gen3Lite, KinError, gen3_lite};
use nalgebra::{Isometry3, Point3};

fn load(text: &str) -> Result<CollisionModel, CollisionError> {
    CollisionModel::from_toml_str(text, "bad.toml", Gen3Lite::get().model())
}

fn err(text: &str) -> String {
    load(text).unwrap_err().to_string()
}

#[test]
fn the_embedded_file_and_a_user_file_load() {
    let m = CollisionModel::get();
    assert_eq!(m.file(), COLLISION_TOML_NAME);
    let dir = std::env::temp_dir().join(format!("collision-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("mine.toml");
    std::fs::write(
        &path,
        COLLISION_TOML.replace("margin_m = 0.005", "margin_m = 0.01"),
    )
    .unwrap();
    let mine = CollisionModel::from_file(&path).unwrap();
    assert_eq!(mine.margin_m(), 0.01);
    let r = |m: &CollisionModel| m.link_capsules(CollisionLink::Forearm)[1].radius_m;
    assert!((r(&mine) - r(m) - 0.005).abs() < 1e-15);
    std::fs::remove_dir_all(&dir).unwrap();
    let e = CollisionModel::from_file(&dir.join("none.toml")).unwrap_err();
    assert!(
        e.to_string()
            .contains("none.toml: cannot read the collision model: "),
        "{e}"
    );
}

#[test]
fn bad_files_are_refused_with_file_link_and_field() {
    // Unknown link name.
    let e = err(&COLLISION_TOML.replace("name = \"forearm_link\"", "name = \"elbow_link\""));
    assert!(
        e.starts_with(
            "bad.toml: link[3].name: `elbow_link` is not a link of the Gen3 lite with geometry (links: base_link, shoulder_link"
        ),
        "{e}"
    );
    // Negative and non-finite radius, non-finite and huge coordinates.
    let e = err(&COLLISION_TOML.replace("radius_m = 0.0536", "radius_m = -0.0536"));
    assert_eq!(
        e,
        "bad.toml: link `forearm_link`: capsule[1].radius_m = -0.0536: a radius must be a positive finite number of metres"
    );
    let e = err(&COLLISION_TOML.replace("radius_m = 0.0536", "radius_m = nan"));
    assert!(
        e.starts_with("bad.toml: link `forearm_link`: capsule[1].radius_m = NaN: "),
        "{e}"
    );
    let e =
        err(&COLLISION_TOML.replace("a = [0.0001, -0.1249, 0.0389]", "a = [0.0001, inf, 0.0389]"));
    assert!(
        e.starts_with("bad.toml: link `forearm_link`: capsule[1].a = [0.0001, inf, 0.0389]: inf is not a finite coordinate"),
        "{e}"
    );
    let e = err(&COLLISION_TOML.replace(
        "a = [0.0001, -0.1249, 0.0389]",
        "a = [0.0001, -124.9, 0.0389]",
    ));
    assert!(e.contains("(the unit is metres)"), "{e}");
    // Top-level values.
    let e = err(&COLLISION_TOML.replace("margin_m = 0.005", "margin_m = -0.005"));
    assert!(
        e.starts_with("bad.toml: link `(file)`: margin_m = -0.005: "),
        "{e}"
    );
    let e = err(&COLLISION_TOML.replace("version = 1", "version = 2"));
    assert_eq!(e, "bad.toml: version = 2: this build reads version 1");
    // A typo in a key, a missing key: the TOML reader names the line.
    let e = err(&COLLISION_TOML.replace("radius_m = 0.0536", "raduis_m = 0.0536"));
    assert!(e.starts_with("bad.toml: TOML parse error at line "), "{e}");
    assert!(e.contains("raduis_m"), "{e}");
    // A link twice, a link missing, a link without capsules.
    let e = err(&COLLISION_TOML.replace("name = \"forearm_link\"", "name = \"arm_link\""));
    assert_eq!(
        e,
        "bad.toml: link `arm_link`: listed twice; give all its capsules under one [[link]]"
    );
    let no_wrist = COLLISION_TOML.replace("[[link]]\nname = \"lower_wrist_link\"\n", "");
    let e = err(&no_wrist);
    // Its capsule now belongs to the forearm, and the wrist has no entry.
    assert_eq!(
        e,
        "bad.toml: link `lower_wrist_link`: has no [[link]] entry; every body of the Gen3 lite's chain base_link -> gripper_base_link (the links the same joints move) needs capsules"
    );
    // Exclusions.
    let e = err(&COLLISION_TOML.replace(
        "links = [\"base_link\", \"shoulder_link\"]",
        "links = [\"base_link\", \"base_link\"]",
    ));
    assert_eq!(e, "bad.toml: exclude[0]: `base_link` is paired with itself");
    let e = err(&COLLISION_TOML.replace(
        "links = [\"arm_link\", \"base_link\"]",
        "links = [\"shoulder_link\", \"base_link\"]",
    ));
    assert_eq!(
        e,
        "bad.toml: exclude[10]: shoulder_link / base_link is excluded twice"
    );
    let e = err(&COLLISION_TOML.replace("why = \"adjacent (joint_1)\"", "why = \" \""));
    assert!(
        e.starts_with("bad.toml: exclude[0]: base_link / shoulder_link: `why` is empty"),
        "{e}"
    );
    let e = err(&COLLISION_TOML.replace(
        "links = [\"base_link\", \"shoulder_link\"]",
        "links = [\"base_link\", \"shoulder\"]",
    ));
    assert!(
        e.starts_with("bad.toml: exclude[0].links: `shoulder` is not a link"),
        "{e}"
    );
}

/// A new arm needs no code for its links: the Gen3 lite with every collision link renamed
/// (in its description and its collision file) loads through [`CollisionModel::for_arm`]
/// alone, with the same capsules, pairs and distances, and its pair codes name its links.
#[test]
fn an_arm_with_link_names_the_code_has_never_seen_loads() {
    let rename = |text: &str| {
        let mut t = text.to_owned();
        for l in CollisionLink::ALL {
            let new = format!("newarm_{}", l.short_name());
            t = t.replace(&format!("\"{}\"", l.name()), &format!("\"{new}\""));
        }
        t
    };
    let robot =
        kinematics::RobotModel::from_urdf_str(&rename(gen3_lite::URDF), "new.urdf").unwrap();
    let arm = kinematics::collision::ModelArm {
        name: "the new arm",
        base_link: "newarm_base",
        tool_link: "newarm_gripper_base",
        ..kinematics::collision::ModelArm::GEN3_LITE
    };
    let new = CollisionModel::for_arm(&rename(COLLISION_TOML), "new.toml", &robot, &arm).unwrap();
    let old = CollisionModel::get();
    assert_eq!(new.capsule_refs().len(), old.capsule_refs().len());
    assert_eq!(new.self_pairs().len(), old.self_pairs().len());
    assert_eq!(new.exclusions().len(), old.exclusions().len());
    assert_eq!(new.base_link().name(), "newarm_base");
    assert_eq!(new.tool_link().name(), "newarm_gripper_base");
    assert!(!new.checks_table(new.base_link()));
    let names: Vec<_> = new.links().iter().map(|l| l.name()).collect();
    assert!(names.iter().all(|n| n.starts_with("newarm_")), "{names:?}");
    let (mut a, mut b) = (Clearance::default(), Clearance::default());
    let scene = Scene::default();
    new.clearance(&gen3_lite::HOME, &scene, &mut a).unwrap();
    old.clearance(&gen3_lite::HOME, &scene, &mut b).unwrap();
    assert_eq!(a.distances_m(), b.distances_m());
    for (pa, pb) in a.pairs().iter().zip(b.pairs()) {
        // The same pair under the new names; its code decodes to them.
        assert_eq!(
            format!("newarm_{}", pb.a.link.short_name()),
            pa.a.link.name()
        );
        let back = Target::from_code(pa.a.code()).unwrap();
        assert_eq!(back, Target::Capsule(pa.a));
    }
}

#[test]
fn a_robot_without_the_finger_joints_is_refused() {
    // Finger tips that follow nothing: they could be anywhere.
    let urdf = gen3_lite::URDF.replace(
        "<mimic joint=\"right_finger_bottom_joint\" multiplier=\"-0.676\" offset=\"0.149\"/>",
        "",
    );
    let robot = kinematics::RobotModel::from_urdf_str(&urdf, "free.urdf").unwrap();
    let e = CollisionModel::from_toml_str(COLLISION_TOML, "c.toml", &robot).unwrap_err();
    assert_eq!(
        e.to_string(),
        "free.urdf: joint `right_finger_tip_joint` above `right_finger_dist_link` is neither fixed, nor the gripper joint `right_finger_bottom_joint`, nor a revolute joint mimicking it"
    );
    // A description without the finger links.
    let start = gen3_lite::URDF
        .find("  <joint name=\"right_finger_tip_joint\"")
        .unwrap();
    let end = gen3_lite::URDF.find("</robot>").unwrap();
    let old = format!("{}{}", &gen3_lite::URDF[..start], &gen3_lite::URDF[end..]);
    let robot = kinematics::RobotModel::from_urdf_str(&old, "old.urdf").unwrap();
    let e = CollisionModel::from_toml_str(COLLISION_TOML, "c.toml", &robot).unwrap_err();
    assert_eq!(
        e.to_string(),
        "old.urdf: no joint has the link `right_finger_dist_link` as its child: the collision model needs it"
    );
}

/// Links joined by a joint (the flange `end_effector_link` has no geometry: it is the gripper
/// base's frame, fixed to it) are excluded, and every exclusion says why.
#[test]
fn adjacent_links_are_excluded() {
    let m = CollisionModel::get();
    let robot = Gen3Lite::get().model();
    let geometry = |name: &str| match name {
        "end_effector_link" => Some(CollisionLink::GripperBase),
        n => CollisionLink::from_name(n),
    };
    let mut adjacent = 0;
    for j in robot.joints() {
        if let (Some(a), Some(b)) = (geometry(&j.parent), geometry(&j.child))
            && a != b
        {
            assert!(
                m.is_excluded(a, b),
                "{a} / {b} (joint {}) is checked",
                j.name
            );
            adjacent += 1;
        }
    }
    assert_eq!(adjacent, 10);
    assert_eq!(m.exclusions().len(), 34);
    for x in m.exclusions() {
        assert!(x.why.starts_with("adjacent") || x.why.starts_with("never in collision"));
    }
    // Every link pair not excluded is checked, capsule by capsule, and nothing else.
    let mut n = 0;
    for (i, a) in CollisionLink::ALL.into_iter().enumerate() {
        for b in CollisionLink::ALL.into_iter().skip(i + 1) {
            let pairs = m.self_pairs().iter().filter(|p| p.is_links(a, b)).count();
            let want = if m.is_excluded(a, b) {
                0
            } else {
                m.link_capsules(a).len() * m.link_capsules(b).len()
            };
            assert_eq!(pairs, want, "{a} / {b}");
            n += usize::from(!m.is_excluded(a, b));
        }
    }
    assert_eq!(n, 21);
    assert_eq!(m.self_pairs().len(), 42);
}

/// The model's dimensions against the URDF: the origin of every joint between two links with
/// geometry lies inside the union of those links' capsules, at several poses.
#[test]
fn every_joint_origin_is_inside_its_links() {
    let m = CollisionModel::get();
    let robot = Gen3Lite::get().model();
    let geometry = |name: &str| match name {
        "end_effector_link" => Some(CollisionLink::GripperBase),
        n => CollisionLink::from_name(n),
    };
    let mut rng = common::Lcg(5);
    let arm = Gen3Lite::get().arm();
    let mut out = Clearance::default();
    let mut poses: Vec<Vec<f64>> = vec![gen3_lite::HOME.to_vec(), gen3_lite::ZERO.to_vec()];
    for _ in 0..20 {
        let mut q = rng.config(arm, 0.0);
        q.push(rng.range(-0.09, 0.96));
        poses.push(q);
    }
    let mut deepest_shallow: f64 = f64::NEG_INFINITY;
    for q in &poses {
        m.clearance(q, &Scene::empty(), &mut out).unwrap();
        let mut n = 0;
        for j in robot.joints() {
            let (Some(a), Some(b)) = (geometry(&j.parent), geometry(&j.child)) else {
                continue;
            };
            if a == b {
                continue;
            }
            // The joint frame in the base frame: the parent's pose, then the origin (the
            // flange's pose is the gripper base's).
            let at: Isometry3<f64> = out.link_pose(a) * j.origin;
            let p = Point3::from(at.translation.vector);
            let inside = m
                .capsule_refs()
                .iter()
                .zip(out.capsules())
                .filter(|(r, _)| r.link == a || r.link == b)
                .map(|(_, c)| c.point_distance(&p))
                .fold(f64::INFINITY, f64::min);
            assert!(
                inside < -0.005,
                "joint {} at {p} is {inside} m from the capsules of {a} and {b}",
                j.name
            );
            deepest_shallow = deepest_shallow.max(inside);
            n += 1;
        }
        assert_eq!(n, 10);
    }
    println!(
        "every joint origin at least {:.1} mm inside",
        -deepest_shallow * 1e3
    );
}

fn pair_min(out: &Clearance, f: impl Fn(&kinematics::collision::PairId) -> bool) -> f64 {
    out.pairs()
        .iter()
        .zip(out.distances_m())
        .filter(|(p, _)| f(p))
        .map(|(_, d)| *d)
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn the_named_poses_are_clear_and_a_pose_into_the_table_is_not() {
    let m = CollisionModel::get();
    let scene = Scene::default();
    let (closed, open) = Gen3Lite::get().gripper_range();
    let mut out = Clearance::default();
    for name in ["zero", "home", "retract"] {
        let q = gen3_lite::named_pose(name).unwrap();
        for gripper in [None, Some(closed), Some(open), Some(0.4)] {
            let mut qg = q.to_vec();
            qg.extend(gripper);
            m.clearance(&qg, &scene, &mut out).unwrap();
            let c = out.closest().unwrap();
            assert!(
                c.distance_m > 0.02,
                "{name} (gripper {gripper:?}): {} at {} m",
                c.pair,
                c.distance_m
            );
            assert_eq!(out.min_distance_m(), c.distance_m);
            assert!(out.distances_m().iter().all(|d| *d >= c.distance_m));
        }
    }
    // Home: the arm is well above the table.
    m.clearance(&gen3_lite::HOME, &scene, &mut out).unwrap();
    assert!(pair_min(&out, |p| p.b == Target::Table) > 0.15);

    // Shoulder forward, elbow straight: the forearm and the wrist go through the table.
    let into = [0.0, 2.2, 0.0, 0.0, 0.0, 0.0];
    m.clearance(&into, &scene, &mut out).unwrap();
    let forearm_or_wrist = |p: &kinematics::collision::PairId| {
        p.b == Target::Table
            && matches!(
                p.a.link,
                CollisionLink::Forearm | CollisionLink::LowerWrist | CollisionLink::UpperWrist
            )
    };
    assert!(pair_min(&out, forearm_or_wrist) < -0.05);
    assert!(out.closest().unwrap().distance_m < -0.05);
    assert_eq!(out.closest().unwrap().pair.b, Target::Table);
    // Just above it: small and positive, and closing when the shoulder goes on forward.
    let above = [0.0, 2.2, 0.5, 0.0, 0.0, 0.0];
    m.clearance(&above, &scene, &mut out).unwrap();
    let d = pair_min(&out, forearm_or_wrist);
    assert!(d > 0.0 && d < 0.01, "{d}");
    let c = out.closest().unwrap();
    assert!(forearm_or_wrist(&c.pair), "{}", c.pair);
    let g = out.closest_rate_row().unwrap();
    assert!(g[1] < -0.1, "{g:?}");
    // The closest points: on the forearm's capsule and on the table, the normal up.
    assert!((c.point_b.z - 0.0).abs() < 1e-12);
    assert!((c.point_a.z - c.point_b.z - c.distance_m).abs() < 1e-12);
    // The base is left out of the table: it stands on it.
    assert!(
        !out.pairs()
            .iter()
            .any(|p| p.a.link == CollisionLink::Base && p.b == Target::Table)
    );
    // Without a table there is no table pair.
    m.clearance(&into, &Scene::empty(), &mut out).unwrap();
    assert!(!out.pairs().iter().any(|p| p.b == Target::Table));
}

#[test]
fn a_box_at_the_tool_is_reported() {
    let m = CollisionModel::get();
    let mut scene = Scene::default();
    let tcp = Gen3Lite::get()
        .tcp(&gen3_lite::HOME)
        .unwrap()
        .translation
        .vector;
    let k = scene
        .add_box(
            Point3::from(tcp) + nalgebra::Vector3::new(-0.05, -0.05, -0.2),
            Point3::from(tcp) + nalgebra::Vector3::new(0.05, 0.05, -0.1),
        )
        .unwrap();
    let mut out = Clearance::default();
    m.clearance(&gen3_lite::HOME, &scene, &mut out).unwrap();
    let c = out.closest().unwrap();
    assert_eq!(c.pair.b, Target::Box(k as u8));
    assert!(matches!(
        c.pair.a.link,
        CollisionLink::GripperBase
            | CollisionLink::RightFingerDist
            | CollisionLink::LeftFingerDist
            | CollisionLink::RightFingerProx
            | CollisionLink::LeftFingerProx
    ));
    assert!(
        c.distance_m > -0.01 && c.distance_m < 0.1,
        "{}",
        c.distance_m
    );
    // Every capsule is checked against the box, the base's too.
    let n_box = out.pairs().iter().filter(|p| p.b == Target::Box(0)).count();
    assert_eq!(n_box, m.capsule_refs().len());
    assert_eq!(out.scene(), &scene);
}

#[test]
fn bad_joint_vectors_are_errors() {
    let m = CollisionModel::get();
    let mut out = Clearance::default();
    let s = Scene::default();
    assert_eq!(
        m.clearance(&[0.0; 5], &s, &mut out),
        Err(KinError::Length {
            expected: 6,
            found: 5
        })
    );
    assert_eq!(
        m.clearance(&[0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0], &s, &mut out),
        Err(KinError::NonFinite {
            what: "joint vector",
            index: 2
        })
    );
    assert!(out.closest().is_none());
    assert!(out.contact(0).is_none());
}

/// The point and angular Jacobians of every link against finite differences of the link
/// poses: a capsule end's velocity and the link's angular velocity, at a pose away from the
/// singular zero pose.
#[test]
fn point_and_angular_jacobians_match_finite_differences() {
    let m = CollisionModel::get();
    let scene = Scene::default();
    let q = [0.3, -0.5, 1.1, 0.4, -0.9, 0.7];
    let mut out = Clearance::default();
    let mut moved = Clearance::default();
    m.clearance(&q, &scene, &mut out).unwrap();
    let h = 1e-7;
    for (c, r) in out.capsules().iter().zip(m.capsule_refs()) {
        let local = out.link_pose(r.link).inverse() * c.b;
        let jp = out.point_jacobian(r.link, &c.b);
        let jw = out.angular_jacobian(r.link);
        for j in 0..6 {
            let mut qh = q;
            qh[j] += h;
            m.clearance(&qh, &scene, &mut moved).unwrap();
            let pose = moved.link_pose(r.link);
            let fd = (pose * local - c.b) / h;
            assert!(
                (fd - jp[j]).norm() < 1e-6,
                "{r} joint {j}: {fd} vs {}",
                jp[j]
            );
            let dr = pose.rotation * out.link_pose(r.link).rotation.inverse();
            let w = dr.scaled_axis() / h;
            assert!((w - jw[j]).norm() < 1e-6, "{r} joint {j}: {w} vs {}", jw[j]);
        }
    }
}
