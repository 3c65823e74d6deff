//! The whole-arm rules: each rule alone ([`safety::clearance`]), the scene's configuration
//! checks, and the filter with the Gen3 lite's collision model in closed loop (the arm
//! integrates the filter's outputs, `q += qdot · dt`): drives into the table and onto the
//! base stop at the stop distance and back out; from random states and commands no pair
//! comes closer than the stop distance in one tick, no point moves faster than the caps, and
//! the output is a non-negative multiple of the command when only these rules act.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

use ipc_types::{MapperCommand, RobotState, SafeCommand, safe_flags};
use kinematics::collision::{Clearance, CollisionLink, CollisionModel, PairId, Scene, Target};
use kinematics::gen3_lite;
use proptest::prelude::*;
use safety::clearance::{self, Near, WholeArm};
use safety::{SafetyConfig, SafetyFilter};

mod common;
use common::NOW;

const DT: f64 = 0.025;

fn cmd(tick: u64, qdot: [f64; 6]) -> MapperCommand {
    common::command(tick, &qdot, 0.0)
}

/// The state at `tick`: pose `q`, moving at `qdot` ([`common::moving_state`], six joints).
fn state(tick: u64, q: &[f64], qdot: &[f64], executed: bool) -> RobotState {
    common::moving_state(tick, &q[..6], &qdot[..6], executed)
}

fn whole_arm(cfg: SafetyConfig) -> SafetyFilter {
    SafetyFilter::new(cfg, &gen3_lite::limits(), DT)
        .unwrap()
        .with_whole_arm(kinematics::RobotProfile::default_robot())
        .unwrap()
}

/// Whether the filter checks a pair (the base against the scene never moves: left out).
fn checked(p: &PairId) -> bool {
    p.a.link != CollisionLink::Base || matches!(p.b, Target::Capsule(_))
}

/// Every checked pair's distance at `q` (open gripper), the test's own oracle.
fn distances(q: &[f64], scene: &Scene) -> Vec<(PairId, f64)> {
    let mut c = Clearance::default();
    CollisionModel::get()
        .clearance(&q[..6], scene, &mut c)
        .unwrap();
    c.pairs()
        .iter()
        .zip(c.distances_m())
        .filter(|(p, _)| checked(p))
        .map(|(p, d)| (*p, *d))
        .collect()
}

fn min_distance(q: &[f64], scene: &Scene) -> (PairId, f64) {
    distances(q, scene)
        .into_iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap()
}

/// Runs the filter in closed loop from `q0` at rest with the constant `qdot` for `ticks`;
/// returns the final pose, the last output and the smallest distance of any checked pair
/// over the run, asserting on the way that none comes closer than `stop` and that every
/// output kept within the acceleration limits (every stop braked in time).
fn drill(
    f: &mut SafetyFilter,
    q0: [f64; 6],
    qdot: [f64; 6],
    ticks: u64,
    first_tick: u64,
    stop: f64,
) -> ([f64; 6], SafeCommand, (PairId, f64)) {
    let scene = f.config().scene.scene().unwrap();
    let amax = f.config().max_acceleration_rad_s2.clone();
    let mut q = q0;
    let mut prev = [0.0; 6];
    let mut closest = min_distance(&q, &scene);
    let mut out = None;
    for k in 0..ticks {
        let tick = first_tick + k;
        let o = f.step(&cmd(tick, qdot), &state(tick, &q, &prev, k > 0), NOW);
        prev.copy_from_slice(&o.qdot_rad_s[..6]);
        for j in 0..6 {
            q[j] += prev[j] * DT;
        }
        let (pair, d) = min_distance(&q, &scene);
        assert!(
            d >= stop - 1e-9,
            "tick {tick}: {pair} at {d} m, below the stop distance {stop} m (flags {:#x})",
            o.flags
        );
        if d < closest.1 {
            closest = (pair, d);
        }
        for j in 0..6 {
            let change = o.qdot_rad_s[j] - f.last_report().base_rad_s[j];
            assert!(
                change.abs() <= amax[j] * DT * (1.0 + 1e-9),
                "tick {tick} joint {j}: changed by {change}, more than the acceleration limit ({:?})",
                f.last_report()
            );
        }
        out = Some(o);
    }
    (q, out.unwrap(), closest)
}

/// The table drill's start and command, the fold's, and both at once: each for 20 s.
const DRILLS: [(&str, [f64; 6]); 3] = [
    // Joint 2 negative from home: the arm leans forward, the tool goes down into the table.
    ("table", [0.0, -0.4, 0.0, 0.0, 0.0, 0.0]),
    // Joint 3 positive: the forearm folds back, the wrist onto the upper arm and the base.
    ("fold", [0.0, 0.0, 0.4, 0.0, 0.0, 0.0]),
    ("both", [0.0, -0.3, 0.3, 0.0, 0.0, 0.0]),
];

/// Closed loop from home with each drill's constant command for 20 s (800 ticks): every pair
/// stays at or above the stop distance, the arm comes to rest within a few millimetres of it
/// (at the stop distance plus the rule's slack), braking within the acceleration limits; the
/// reversed command backs out, the distance growing.
#[test]
fn driving_into_the_table_or_onto_the_arm_stops_at_the_stop_distance_and_backs_out() {
    for (name, qdot) in DRILLS {
        let cfg = SafetyConfig::default();
        let stop = cfg.stop_distance_m;
        let scene = cfg.scene.scene().unwrap();
        let mut f = whole_arm(cfg);
        let (q, last, closest) = drill(&mut f, gen3_lite::HOME, qdot, 800, 1, stop);
        common::assert_at_rest_at_the_stop_distance("drill", name, &q, &last, closest, stop);
        let held = min_distance(&q, &scene).1;
        let back = qdot.map(|v| -v);
        let (q, out, _) = drill(&mut f, q, back, 80, 801, stop);
        let after = min_distance(&q, &scene).1;
        assert!(
            after > held + 0.02,
            "{name}: backed out from {held} to {after} m"
        );
        assert_eq!(out.flags & safe_flags::CLEARANCE_LIMITED, 0, "{name}");
    }
}

/// A box in front of the arm (`[safety.scene]`), 12 cm ahead of the tool at home: the table
/// drill stops at it, not at the table.
#[test]
fn a_box_of_the_scene_stops_the_arm() {
    let mut cfg = SafetyConfig::default();
    cfg.scene.boxes.push(safety::BoxConfig {
        name: "fixture".into(),
        min: [0.56, -0.3, 0.0],
        max: [0.8, 0.3, 0.5],
    });
    let stop = cfg.stop_distance_m;
    let names = cfg.scene.box_names();
    let mut f = whole_arm(cfg);
    let (_, last, closest) = drill(
        &mut f,
        gen3_lite::HOME,
        [0.0, -0.4, 0.0, 0.0, 0.0, 0.0],
        400,
        1,
        stop,
    );
    assert_eq!(closest.0.b, Target::Box(0), "{}", closest.0);
    let name = clearance_name(last.closest_pair, &names);
    assert!(name.ends_with("-fixture"), "{name}");
    assert!(last.qdot_rad_s.iter().all(|v| v.abs() < 1e-3), "{last:?}");
}

fn clearance_name(code: [u16; 2], names: &[String]) -> String {
    safety::scene::pair_name(code, names).unwrap()
}

#[test]
fn the_command_reports_the_closest_pair_and_the_tool_speed() {
    let mut f = whole_arm(SafetyConfig::default());
    let q = gen3_lite::HOME;
    let out = f.step(&cmd(1, [0.0; 6]), &state(1, &q, &[0.0; 6], false), NOW);
    let (pair, d) = min_distance(&q, &Scene::default());
    assert_eq!(out.closest_pair, pair.code());
    assert_eq!(out.clearance_m, d);
    assert_eq!(out.tcp_speed_m_s, 0.0);
    assert_eq!(out.flags, 0);
    // Moving: the tool's speed under the output (the arm chain's own Jacobian as oracle).
    let v = [0.1, 0.0, 0.0, 0.0, 0.0, 0.0];
    let out = f.step(&cmd(2, v), &state(2, &q, &v, true), NOW);
    let want = tool_twist(&q, &out.qdot_rad_s[..6]).0;
    assert!(
        (out.tcp_speed_m_s - want).abs() < 1e-9,
        "{} vs {want}",
        out.tcp_speed_m_s
    );
    // Without the whole-arm rules nothing is checked.
    let mut plain = SafetyFilter::new(SafetyConfig::default(), &gen3_lite::limits(), DT).unwrap();
    let out = plain.step(&cmd(1, [0.0; 6]), &state(1, &q, &[0.0; 6], false), NOW);
    assert_eq!(out.clearance_m, f64::INFINITY);
    assert_eq!(out.closest_pair, WholeArm::NO_PAIR);
    assert!(safety::scene::pair_name(out.closest_pair, &[]).is_none());
}

/// A mount box under the base: the base's (constant) overlap with it is not a checked pair;
/// everything that moves still is.
#[test]
fn the_base_against_the_scene_is_not_reported() {
    let mut cfg = SafetyConfig::default();
    cfg.scene.table_z_m = -0.1;
    cfg.scene.boxes.push(safety::BoxConfig {
        name: "mount".into(),
        min: [-0.1, -0.1, -0.1],
        max: [0.1, 0.1, 0.0],
    });
    let mut f = whole_arm(cfg);
    let out = f.step(
        &cmd(1, [0.0; 6]),
        &state(1, &gen3_lite::HOME, &[0.0; 6], false),
        NOW,
    );
    assert!(out.clearance_m > 0.0, "{}", out.clearance_m);
    let name = clearance_name(out.closest_pair, &["mount".to_owned()]);
    assert!(!name.starts_with("base-mount"), "{name}");
}

// ---- each rule alone ----

fn near(distance_m: f64, row: [f64; 6]) -> Near {
    let mut rate_row = [0.0; clearance::MAX_ARM_JOINTS];
    rate_row[..6].copy_from_slice(&row);
    Near {
        distance_m,
        rate_row,
    }
}

#[test]
fn braking_for_a_pair_stops_before_the_stop_distance() {
    // d_dot = -0.5 m/s per rad/s of joint 0.
    let row = [0.5, 0.0, 0.0, 0.0, 0.0, 0.0];
    let v = [-0.4, 0.0, 0.0, 0.0, 0.0, 0.0];
    let alpha = 1.0;
    for d in [0.021, 0.03, 0.06, 0.1, 0.5] {
        let p = near(d, row);
        let k = clearance::clearance_scale(&[p], &v, 0.02, alpha, DT, false);
        // Braking from k·v along its direction at alpha (planned at BRAKE_SHARE): the pair
        // travels no further than d - stop.
        let mut s = k * 0.2;
        let mut gone = 0.0;
        while s > 0.0 {
            gone += s * DT;
            s = (s - clearance::BRAKE_SHARE * alpha * 0.2 * DT).max(0.0);
        }
        assert!(gone <= d - 0.02 + 1e-12, "{d}: {gone}");
        assert!((0.0..=1.0).contains(&k));
    }
    // Far away: free. Moving apart: free, even below the stop distance.
    assert_eq!(
        clearance::clearance_scale(&[near(1.0, row)], &v, 0.02, alpha, DT, false),
        1.0
    );
    let apart = v.map(|x| -x);
    assert_eq!(
        clearance::clearance_scale(&[near(0.01, row)], &apart, 0.02, alpha, DT, false),
        1.0
    );
    // Below it, approaching: stopped, also for the one-tick guarantee.
    assert_eq!(
        clearance::clearance_scale(&[near(0.01, row)], &v, 0.02, alpha, DT, true),
        0.0
    );
    // One tick: exactly down to the stop distance, to first order.
    let k = clearance::clearance_scale(&[near(0.022, row)], &v, 0.02, f64::INFINITY, DT, true);
    assert!((k * 0.2 * DT - 0.002).abs() < 1e-15, "{k}");
    // Several pairs: the tightest counts; a pair the command does not move is ignored.
    let pairs = [
        near(0.05, row),
        near(0.03, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]),
        near(0.025, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
        near(0.04, [0.2, 0.0, 0.0, 0.0, 0.0, 0.0]),
    ];
    let k = clearance::clearance_scale(&pairs, &v, 0.02, alpha, DT, false);
    let k0 = clearance::clearance_scale(&pairs[..1], &v, 0.02, alpha, DT, false);
    let k3 = clearance::clearance_scale(&pairs[3..], &v, 0.02, alpha, DT, false);
    assert_eq!(k, k0.min(k3));
}

#[test]
fn the_slowdown_scales_the_approach_down_to_zero_at_the_stop_distance() {
    let row = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    let v = [-0.25, 0.0, 0.0, 0.0, 0.0, 0.0]; // approaching at 0.25 m/s
    let k = |d: f64| clearance::slowdown_scale(&[near(d, row)], &v, 0.02, 0.1, 0.25);
    assert_eq!(k(0.2), 1.0);
    assert_eq!(k(0.1), 1.0);
    assert!((k(0.06) - 0.5).abs() < 1e-12);
    assert_eq!(k(0.02), 0.0);
    assert_eq!(k(0.0), 0.0);
    // Slower approaches are slowed later: at 0.1 m/s, only below 0.052 m.
    let slow = v.map(|x| x * 0.4);
    assert_eq!(
        clearance::slowdown_scale(&[near(0.06, row)], &slow, 0.02, 0.1, 0.25),
        1.0
    );
    // Motion apart is never slowed.
    let apart = v.map(|x| -x);
    assert_eq!(
        clearance::slowdown_scale(&[near(0.03, row)], &apart, 0.02, 0.1, 0.25),
        1.0
    );
}

#[test]
fn the_speed_cap_scales_the_fastest_point_to_the_cap() {
    let mut a = [[0.0; clearance::MAX_ARM_JOINTS]; 3];
    a[0][0] = 0.5; // 0.5 m/s per rad/s of joint 0 along x
    let mut b = [[0.0; clearance::MAX_ARM_JOINTS]; 3];
    b[1][0] = 0.3;
    b[2][1] = 0.4; // |(0, 0.3 q0, 0.4 q1)|
    let v = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0];
    assert!((clearance::point_speed(&a, &v) - 0.5).abs() < 1e-15);
    assert!((clearance::point_speed(&b, &v) - 0.5).abs() < 1e-15);
    let k = clearance::speed_scale(&[a, b], &v, 0.25);
    assert!((k - 0.5).abs() < 1e-15);
    assert_eq!(clearance::speed_scale(&[a, b], &v, 1.0), 1.0);
    assert_eq!(clearance::speed_scale(&[a], &[0.0; 6], 0.25), 1.0);
}

// ---- configuration ----

#[test]
fn whole_arm_keys_are_checked_and_errors_name_them() {
    let l = gen3_lite::limits();
    let d = SafetyConfig::default;
    let bad = |cfg: SafetyConfig| SafetyFilter::new(cfg, &l, DT).unwrap_err();
    let e = bad(SafetyConfig {
        stop_distance_m: 0.0,
        ..d()
    });
    assert_eq!(e.key, "stop_distance_m");
    let e = bad(SafetyConfig {
        slowdown_distance_m: 0.02,
        ..d()
    });
    assert_eq!(e.key, "slowdown_distance_m");
    assert!(e.reason.contains("stop_distance_m"), "{e}");
    assert_eq!(
        bad(SafetyConfig {
            slowdown_distance_m: f64::NAN,
            ..d()
        })
        .key,
        "slowdown_distance_m"
    );
    assert_eq!(
        bad(SafetyConfig {
            max_tcp_speed_m_s: -0.1,
            ..d()
        })
        .key,
        "max_tcp_speed_m_s"
    );
    assert_eq!(
        bad(SafetyConfig {
            max_tcp_angular_speed_rad_s: f64::INFINITY,
            ..d()
        })
        .key,
        "max_tcp_angular_speed_rad_s"
    );
    let scene = |f: &dyn Fn(&mut SafetyConfig)| {
        let mut c = d();
        f(&mut c);
        bad(c)
    };
    let e = scene(&|c| c.scene.table_z_m = 0.05);
    assert_eq!(
        e.to_string().split(':').next(),
        Some("safety.scene.table_z_m")
    );
    assert_eq!(
        scene(&|c| c.scene.table_z_m = f64::NAN).key,
        "scene.table_z_m"
    );
    let b = |name: &str, min: [f64; 3], max: [f64; 3]| safety::BoxConfig {
        name: name.into(),
        min,
        max,
    };
    let e = scene(&|c| c.scene.boxes.push(b("a", [0.0, 0.0, 0.5], [1.0, 1.0, 0.4])));
    assert_eq!(e.key, "scene.boxes[0].min");
    assert!(e.reason.contains("axis 2"), "{e}");
    let e = scene(&|c| {
        c.scene.boxes.push(b("a", [0.0; 3], [1.0; 3]));
        c.scene.boxes.push(b("b", [0.0, f64::NAN, 0.0], [1.0; 3]));
    });
    assert_eq!(e.key, "scene.boxes[1].min");
    let e = scene(&|c| {
        c.scene.boxes.push(b("a", [0.0; 3], [1.0; 3]));
        c.scene.boxes.push(b("a", [2.0; 3], [3.0; 3]));
    });
    assert_eq!(e.key, "scene.boxes[1].name");
    assert_eq!(
        scene(&|c| c.scene.boxes.push(b(" ", [0.0; 3], [1.0; 3]))).key,
        "scene.boxes[0].name"
    );
    let e = scene(&|c| {
        for i in 0..=kinematics::collision::MAX_BOXES {
            c.scene
                .boxes
                .push(b(&format!("b{i}"), [i as f64; 3], [i as f64 + 0.5; 3]));
        }
    });
    assert_eq!(e.key, "scene.boxes");
    // The most boxes the model holds are fine.
    let mut c = d();
    for i in 0..kinematics::collision::MAX_BOXES {
        c.scene.boxes.push(b(
            &format!("b{i}"),
            [2.0 + i as f64; 3],
            [2.5 + i as f64; 3],
        ));
    }
    whole_arm(c);
}

#[test]
fn the_scene_reads_from_toml() {
    let cfg: SafetyConfig = toml::from_str(
        r#"
        stop_distance_m = 0.03
        [scene]
        table_z_m = -0.05
        boxes = [
            { name = "mount", min = [-0.2, -0.2, -0.05], max = [0.2, 0.2, 0.0] },
            { name = "wall", min = [-1.0, 0.6, -0.05], max = [1.0, 0.7, 1.0] },
        ]
        "#,
    )
    .unwrap();
    assert_eq!(cfg.stop_distance_m, 0.03);
    assert_eq!(cfg.scene.box_names(), ["mount", "wall"]);
    let scene = cfg.scene.scene().unwrap();
    assert_eq!(scene.table_z_m(), Some(-0.05));
    assert_eq!(scene.boxes()[1].min.y, 0.6);
    whole_arm(cfg);
    let e = toml::from_str::<SafetyConfig>("[scene]\nboxes = [{ name = \"a\", min = [0, 0, 0] }]")
        .unwrap_err();
    assert!(e.to_string().contains("max"), "{e}");
}

#[test]
fn pairs_have_short_names() {
    use kinematics::collision::{CapsuleRef, side_code};
    let forearm = CapsuleRef {
        link: CollisionLink::Forearm,
        index: 1,
    };
    let p = PairId {
        a: forearm,
        b: Target::Table,
    };
    assert_eq!(clearance_name(p.code(), &[]), "forearm-table");
    let p = PairId {
        a: forearm,
        b: Target::Box(1),
    };
    let names = ["mount".to_owned(), "wall".to_owned()];
    assert_eq!(clearance_name(p.code(), &names), "forearm-wall");
    assert_eq!(clearance_name(p.code(), &names[..1]), "forearm-box 1");
    let p = PairId {
        a: CapsuleRef {
            link: CollisionLink::Base,
            index: 0,
        },
        b: Target::Capsule(CapsuleRef {
            link: CollisionLink::UpperWrist,
            index: 0,
        }),
    };
    assert_eq!(clearance_name(p.code(), &[]), "base-upper_wrist");
    assert_eq!(safety::scene::pair_name([side_code::NONE; 2], &[]), None);
}

// ---- properties ----

/// The tool's linear and angular speed under `v` at `q`, from the arm chain's own geometric
/// Jacobian (base -> tool_frame): an oracle independent of the collision model's.
fn tool_twist(q: &[f64], v: &[f64]) -> (f64, f64) {
    let arm = gen3_lite::Gen3Lite::get().arm();
    let mut jac = kinematics::Jacobian::zeros(6);
    arm.fk_jacobian(q, &mut jac).unwrap();
    let row = |i: usize| (0..6).map(|j| jac.get(i, j) * v[j]).sum::<f64>();
    let lin = (0..3).map(|i| row(i).powi(2)).sum::<f64>().sqrt();
    let ang = (3..6).map(|i| row(i).powi(2)).sum::<f64>().sqrt();
    (lin, ang)
}

/// The fastest capsule end under `v` at `q`, by finite differences of the capsules' ends.
fn fastest_capsule_end(q: &[f64], v: &[f64]) -> f64 {
    let m = CollisionModel::get();
    let scene = Scene::empty();
    let (mut a, mut b) = (Clearance::default(), Clearance::default());
    let h = 1e-7;
    let qh: Vec<f64> = q.iter().zip(v).map(|(q, v)| q + h * v).collect();
    m.clearance(q, &scene, &mut a).unwrap();
    m.clearance(&qh, &scene, &mut b).unwrap();
    a.capsules()
        .iter()
        .zip(b.capsules())
        .flat_map(|(x, y)| [(y.a - x.a).norm() / h, (y.b - x.b).norm() / h])
        .fold(0.0, f64::max)
}

/// A pose inside the joint limits less the margin.
fn any_pose() -> impl Strategy<Value = [f64; 6]> {
    let l = gen3_lite::limits();
    let r: Vec<(f64, f64)> = (0..6)
        .map(|j| (l.lower_rad[j] + 0.05, l.upper_rad[j] - 0.05))
        .collect();
    proptest::array::uniform6(0.0f64..1.0)
        .prop_map(move |u| std::array::from_fn(|j| r[j].0 + u[j] * (r[j].1 - r[j].0)))
}

/// How much closer a pair already below the stop distance may come in one tick: what the
/// filter's exact check of the next pose allows ([`clearance::BELOW_STOP_SLACK_M`]); the
/// loop integrates the output as that check does, so only round-off is added.
const BELOW_STOP_TOLERANCE_M: f64 = clearance::BELOW_STOP_SLACK_M + 1e-9;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// Closed loop from random poses inside the joint limits, at random velocities, with
    /// random held commands (executed, or reported back by the robot) and now and then a box
    /// near the tool: after every tick no checked pair is closer than the stop distance
    /// unless it already was, and such a pair comes no closer (to the tolerance above); no
    /// capsule end nor the tool moves faster than the linear cap, the tool turns no faster
    /// than the angular cap.
    #[test]
    fn no_pair_passes_the_stop_distance_and_no_point_the_speed_cap(
        start in any_pose(),
        moving in proptest::array::uniform6(-1.0f64..1.0),
        with_box in any::<bool>(),
        cmds in proptest::collection::vec(
            (proptest::array::uniform6(-2.0f64..2.0), 1u64..15, any::<bool>()),
            1..5,
        ),
    ) {
        let mut cfg = SafetyConfig::default();
        let tool = gen3_lite::Gen3Lite::get().tcp(&start).unwrap().translation.vector;
        if with_box {
            cfg.scene.boxes.push(safety::BoxConfig {
                name: "near".into(),
                min: [tool.x + 0.05, tool.y - 0.2, tool.z - 0.2],
                max: [tool.x + 0.3, tool.y + 0.2, tool.z + 0.2],
            });
        }
        let stop = cfg.stop_distance_m;
        let (lin_cap, ang_cap) = (cfg.max_tcp_speed_m_s, cfg.max_tcp_angular_speed_rad_s);
        let vmax = cfg.max_velocity_rad_s.clone();
        let scene = cfg.scene.scene().unwrap();
        let mut f = whole_arm(cfg);
        let mut q = start;
        let mut prev: [f64; 6] = std::array::from_fn(|j| moving[j] * vmax[j]);
        let mut tick = 0;
        for (qdot, hold, executed) in cmds {
            for _ in 0..hold {
                tick += 1;
                let before = distances(&q, &scene);
                let out = f.step(&cmd(tick, qdot), &state(tick, &q, &prev, executed && tick > 1), NOW);
                let v: [f64; 6] = std::array::from_fn(|j| out.qdot_rad_s[j]);
                let (lin, ang) = tool_twist(&q, &v);
                prop_assert!(lin <= lin_cap * (1.0 + 1e-9), "tick {tick}: tool at {lin} m/s");
                prop_assert!((lin - out.tcp_speed_m_s).abs() < 1e-9);
                prop_assert!(ang <= ang_cap * (1.0 + 1e-9), "tick {tick}: tool turning at {ang} rad/s");
                let end = fastest_capsule_end(&q, &v);
                prop_assert!(end <= lin_cap * (1.0 + 1e-6), "tick {tick}: a capsule end at {end} m/s");
                for j in 0..6 { q[j] += v[j] * DT; }
                for ((pair, d0), (_, d1)) in before.iter().zip(distances(&q, &scene)) {
                    if *d0 >= stop {
                        prop_assert!(d1 >= stop - 1e-9, "tick {tick}: {pair} from {d0} to {d1} m (flags {:#x})", out.flags);
                    } else {
                        prop_assert!(d1 >= d0 - BELOW_STOP_TOLERANCE_M, "tick {tick}: {pair} below the stop distance from {d0} to {d1} m");
                    }
                }
                prev = v;
            }
        }
    }

    /// With the acceleration limit out of the way, or the arm already moving at the commanded
    /// velocity: whenever only the distance, speed and joint-limit rules act, the output is a
    /// non-negative multiple of the command, at most the command itself.
    #[test]
    fn only_scaling_rules_keep_the_direction(
        q in any_pose(),
        qdot in proptest::array::uniform6(-2.0f64..2.0),
        accel_off in any::<bool>(),
    ) {
        let mut cfg = SafetyConfig::default();
        if accel_off {
            cfg.max_acceleration_rad_s2 = vec![1e12; 6];
        }
        let vmax = cfg.max_velocity_rad_s.clone();
        let mut f = whole_arm(cfg);
        // The arm moves at the command as the velocity limit leaves it.
        let k = safety::uniform_scale(&qdot, &vmax);
        let moving: [f64; 6] = std::array::from_fn(|j| qdot[j] * k);
        let out = f.step(&cmd(5, qdot), &state(5, &q, &moving, false), NOW);
        let scaling = safe_flags::VELOCITY_SCALED
            | safe_flags::POSITION_LIMITED
            | safe_flags::WORKSPACE_LIMITED
            | safe_flags::CLEARANCE_LIMITED
            | safe_flags::SPEED_CAPPED;
        if out.flags & !scaling == 0 {
            let big = (0..6).max_by(|a, b| qdot[*a].abs().total_cmp(&qdot[*b].abs())).unwrap();
            let c = out.qdot_rad_s[big] / qdot[big];
            prop_assert!((0.0..=1.0 + 1e-12).contains(&c), "factor {c}");
            for j in 0..6 {
                prop_assert!(
                    (out.qdot_rad_s[j] - c * qdot[j]).abs() <= 1e-12 * (1.0 + qdot[j].abs()),
                    "joint {j}: {} is not {c} x {} (flags {:#x})", out.qdot_rad_s[j], qdot[j], out.flags
                );
            }
        } else {
            prop_assert!(!accel_off || out.flags & safe_flags::ACCEL_LIMITED == 0);
        }
    }
}
