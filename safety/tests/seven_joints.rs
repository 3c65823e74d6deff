//! The safety filter's guarantees as properties for every built-in robot profile, so that they
//! run for the Gen3 lite (6 joints) and the Gen3 (7 joints) alike: in closed loop (the arm
//! integrates the filter's outputs, `q += qdot · dt`, at the profile's control rate) from
//! random poses, velocities and commands,
//!
//! * every output is finite, within the velocity limits, and never carries a joint past its
//!   limit less the margin (the Gen3's continuous joints included: their software limits);
//! * with the whole-arm rules (the profile's collision model): no checked pair comes closer
//!   than the stop distance within a tick, and neither the tool nor any capsule end moves
//!   faster than the linear cap, the tool turns no faster than the angular cap.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

use ipc_types::MapperCommand;
use kinematics::RobotProfile;
use kinematics::collision::{Clearance, CollisionLink, PairId, Scene, Target};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use safety::{SafetyConfig, SafetyFilter, clearance};

mod common;
use common::{NOW, moving_state as state};

fn cmd(tick: u64, qdot: &[f64]) -> MapperCommand {
    common::command(tick, qdot, 0.0)
}

/// One random closed-loop run: a start pose (fractions of each joint's range inside the
/// margins), a start velocity (fractions of the velocity limits) and held commands.
#[derive(Debug, Clone)]
struct Run {
    start: Vec<f64>,
    moving: Vec<f64>,
    cmds: Vec<(Vec<f64>, u64, bool)>,
}

fn runs(n: usize, max_cmds: usize) -> impl Strategy<Value = Run> {
    (
        proptest::collection::vec(0.0f64..1.0, n),
        proptest::collection::vec(-1.0f64..1.0, n),
        proptest::collection::vec(
            (
                proptest::collection::vec(-2.0f64..2.0, n),
                1u64..15,
                any::<bool>(),
            ),
            1..max_cmds,
        ),
    )
        .prop_map(|(start, moving, cmds)| Run {
            start,
            moving,
            cmds,
        })
}

/// The start pose of a run: inside the limits less the margin.
fn start_pose(robot: &RobotProfile, margin: f64, u: &[f64]) -> Vec<f64> {
    let l = robot.limits();
    (0..robot.n_joints())
        .map(|j| {
            let (lo, hi) = (l.lower_rad[j] + margin, l.upper_rad[j] - margin);
            lo + u[j] * (hi - lo)
        })
        .collect()
}

fn period(robot: &RobotProfile) -> f64 {
    1.0 / robot.control_rate_hz()
}

/// The joint-limit and velocity guarantees in closed loop, for `robot`.
fn joint_limits_hold(robot: &'static RobotProfile) {
    let n = robot.n_joints();
    let dt = period(robot);
    let cfg = SafetyConfig::for_robot(robot);
    let margin = cfg.joint_margin_rad;
    let vmax = cfg.max_velocity_rad_s.clone();
    let l = robot.limits().clone();
    let mut runner = TestRunner::new(Config::with_cases(128));
    runner
        .run(&runs(n, 8), |run| {
            let mut f = SafetyFilter::for_robot(cfg.clone(), robot, dt).unwrap();
            let mut q = start_pose(robot, margin, &run.start);
            let mut prev: Vec<f64> = (0..n).map(|j| run.moving[j] * vmax[j]).collect();
            let mut tick = 0;
            for (qdot, hold, executed) in &run.cmds {
                for _ in 0..*hold {
                    tick += 1;
                    let out = f.step(
                        &cmd(tick, qdot),
                        &state(tick, &q, &prev, *executed && tick > 1),
                        NOW,
                    );
                    for j in 0..n {
                        let v = out.qdot_rad_s[j];
                        prop_assert!(v.is_finite(), "joint {j}: {v}");
                        prop_assert!(v.abs() <= vmax[j] * (1.0 + 1e-12), "joint {j}: {v} rad/s");
                        let (lo, hi) = (l.lower_rad[j] + margin, l.upper_rad[j] - margin);
                        let next = q[j] + v * dt;
                        prop_assert!(
                            next <= hi + 1e-12 && next >= lo - 1e-12,
                            "{}: tick {tick}: joint {j} from {} to {next}, past [{lo}, {hi}]",
                            robot.name(),
                            q[j]
                        );
                        q[j] = next;
                    }
                    prop_assert!(out.qdot_rad_s[n..].iter().all(|v| *v == 0.0));
                    prev = out.qdot_rad_s[..n].to_vec();
                }
            }
            Ok(())
        })
        .unwrap();
}

#[test]
fn joint_limits_hold_for_the_gen3_lite() {
    joint_limits_hold(RobotProfile::by_name("gen3_lite").unwrap());
}

#[test]
fn joint_limits_hold_for_the_gen3() {
    joint_limits_hold(RobotProfile::by_name("gen3").unwrap());
}

/// Whether the filter checks a pair (the base against the scene never moves: left out).
fn checked(p: &PairId) -> bool {
    p.a.link != CollisionLink::Base || matches!(p.b, Target::Capsule(_))
}

/// Every checked pair's distance at `q` (the model's default gripper), the test's oracle.
fn distances(robot: &RobotProfile, q: &[f64], scene: &Scene) -> Vec<(PairId, f64)> {
    let mut c = Clearance::default();
    robot
        .collision_model()
        .unwrap()
        .clearance(q, scene, &mut c)
        .unwrap();
    c.pairs()
        .iter()
        .zip(c.distances_m())
        .filter(|(p, _)| checked(p))
        .map(|(p, d)| (*p, *d))
        .collect()
}

/// The tool's linear and angular speed under `v` at `q`, from the arm chain's geometric
/// Jacobian (base -> TCP): an oracle independent of the collision model's.
fn tool_twist(robot: &RobotProfile, q: &[f64], v: &[f64]) -> (f64, f64) {
    let n = robot.n_joints();
    let mut jac = kinematics::Jacobian::zeros(n);
    robot.arm().fk_jacobian(q, &mut jac).unwrap();
    let row = |i: usize| (0..n).map(|j| jac.get(i, j) * v[j]).sum::<f64>();
    let lin = (0..3).map(|i| row(i).powi(2)).sum::<f64>().sqrt();
    let ang = (3..6).map(|i| row(i).powi(2)).sum::<f64>().sqrt();
    (lin, ang)
}

/// The fastest capsule end under `v` at `q`, by finite differences of the capsules' ends.
fn fastest_capsule_end(robot: &RobotProfile, q: &[f64], v: &[f64]) -> f64 {
    let m = robot.collision_model().unwrap();
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

/// How much closer a pair already below the stop distance may come in one tick: what the
/// filter's exact check of the next pose allows ([`clearance::BELOW_STOP_SLACK_M`]); the
/// loop integrates the output as that check does, so only round-off is added.
const BELOW_STOP_TOLERANCE_M: f64 = clearance::BELOW_STOP_SLACK_M + 1e-9;

/// The whole-arm guarantees in closed loop, for `robot` with its collision model.
fn whole_arm_holds(robot: &'static RobotProfile) {
    let n = robot.n_joints();
    let dt = period(robot);
    let base_cfg = SafetyConfig::for_robot(robot);
    let margin = base_cfg.joint_margin_rad;
    let mut runner = TestRunner::new(Config::with_cases(64));
    runner
        .run(&(runs(n, 5), any::<bool>()), |(run, with_box)| {
            let mut cfg = base_cfg.clone();
            let start = start_pose(robot, margin, &run.start);
            let tool = robot.arm().fk(&start).unwrap().translation.vector;
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
            let mut f = SafetyFilter::for_robot(cfg, robot, dt)
                .unwrap()
                .with_whole_arm(robot)
                .unwrap();
            let mut q = start;
            let mut prev: Vec<f64> = (0..n).map(|j| run.moving[j] * vmax[j]).collect();
            let mut tick = 0;
            for (qdot, hold, executed) in &run.cmds {
                for _ in 0..*hold {
                    tick += 1;
                    let before = distances(robot, &q, &scene);
                    let out = f.step(
                        &cmd(tick, qdot),
                        &state(tick, &q, &prev, *executed && tick > 1),
                        NOW,
                    );
                    let v = out.qdot_rad_s[..n].to_vec();
                    let (lin, ang) = tool_twist(robot, &q, &v);
                    prop_assert!(
                        lin <= lin_cap * (1.0 + 1e-9),
                        "tick {tick}: tool at {lin} m/s"
                    );
                    prop_assert!(
                        ang <= ang_cap * (1.0 + 1e-9),
                        "tick {tick}: tool turning at {ang} rad/s"
                    );
                    let end = fastest_capsule_end(robot, &q, &v);
                    prop_assert!(
                        end <= lin_cap * (1.0 + 1e-6),
                        "tick {tick}: a capsule end at {end} m/s"
                    );
                    for j in 0..n {
                        q[j] += v[j] * dt;
                    }
                    for ((pair, d0), (_, d1)) in before.iter().zip(distances(robot, &q, &scene)) {
                        if *d0 >= stop {
                            prop_assert!(
                                d1 >= stop - 1e-9,
                                "{}: tick {tick}: {pair} from {d0} to {d1} m (flags {:#x})",
                                robot.name(),
                                out.flags
                            );
                        } else {
                            prop_assert!(
                                d1 >= d0 - BELOW_STOP_TOLERANCE_M,
                                "tick {tick}: {pair} below the stop distance from {d0} to {d1} m"
                            );
                        }
                    }
                    prev = v;
                }
            }
            Ok(())
        })
        .unwrap();
}

#[test]
fn no_pair_passes_the_stop_distance_and_no_point_the_speed_cap_on_the_gen3_lite() {
    whole_arm_holds(RobotProfile::by_name("gen3_lite").unwrap());
}

#[test]
fn no_pair_passes_the_stop_distance_and_no_point_the_speed_cap_on_the_gen3() {
    whole_arm_holds(RobotProfile::by_name("gen3").unwrap());
}

/// Every built-in profile is covered by the tests above.
#[test]
fn every_builtin_profile_is_covered() {
    let names: Vec<&str> = RobotProfile::names().collect();
    assert_eq!(names, ["gen3_lite", "gen3"]);
}

/// Runs `robot`'s filter ([`SafetyFilter::for_graph`], as the safety process builds it) in
/// closed loop from `q0` at rest with the constant command `qdot` for `ticks`; returns the
/// final pose, the last output and the closest checked pair over the run, asserting on the
/// way that no pair comes closer than the stop distance and that every output kept within the
/// acceleration limits (every stop braked in time).
fn drive(
    f: &mut SafetyFilter,
    robot: &RobotProfile,
    q0: &[f64],
    qdot: &[f64],
    ticks: u64,
    first_tick: u64,
) -> (Vec<f64>, ipc_types::SafeCommand, (PairId, f64)) {
    let n = robot.n_joints();
    let dt = period(robot);
    let stop = f.config().stop_distance_m;
    let amax = f.config().max_acceleration_rad_s2.clone();
    let scene = f.config().scene.scene().unwrap();
    let closest_at = |q: &[f64]| {
        distances(robot, q, &scene)
            .into_iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
    };
    let mut q = q0.to_vec();
    let mut prev = vec![0.0; n];
    let mut closest = closest_at(&q);
    let mut out = None;
    for k in 0..ticks {
        let tick = first_tick + k;
        let o = f.step(&cmd(tick, qdot), &state(tick, &q, &prev, k > 0), NOW);
        for j in 0..n {
            let change = o.qdot_rad_s[j] - f.last_report().base_rad_s[j];
            assert!(
                change.abs() <= amax[j] * dt * (1.0 + 1e-9),
                "tick {tick} joint {j}: changed by {change}, more than the acceleration limit"
            );
            prev[j] = o.qdot_rad_s[j];
            q[j] += prev[j] * dt;
        }
        let (pair, d) = closest_at(&q);
        assert!(
            d >= stop - 1e-9,
            "tick {tick}: {pair} at {d} m, below the stop distance {stop} m (flags {:#x})",
            o.flags
        );
        if d < closest.1 {
            closest = (pair, d);
        }
        out = Some(o);
    }
    (q, out.unwrap(), closest)
}

/// The Gen3 (seven joints) from home, driven for 20 s into the table (joint 2 forward) and
/// folded onto itself (joint 6 bending the gripper back onto the shoulder): the filter the safety process builds
/// takes the Gen3's collision model, no pair comes closer than the stop distance, the arm
/// comes to rest within a few millimetres of it, braking within the acceleration limits,
/// with the closest pair (a Gen3 link) and its distance reported; the reversed command backs
/// out.
#[test]
fn the_gen3_driven_into_the_table_or_onto_itself_stops_at_the_stop_distance() {
    let robot = RobotProfile::by_name("gen3").unwrap();
    let home = robot.named_pose("home").unwrap();
    for (name, qdot) in [
        ("table", [0.0, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0]),
        ("fold", [0.0, 0.0, 0.0, 0.0, 0.0, -0.4, 0.0]),
    ] {
        let cfg = SafetyConfig::for_robot(robot);
        let stop = cfg.stop_distance_m;
        let mut f = SafetyFilter::for_graph(cfg, robot, period(robot)).unwrap();
        let (q, last, closest) = drive(&mut f, robot, home, &qdot, 800, 1);
        common::assert_at_rest_at_the_stop_distance("gen3 drill", name, &q, &last, closest, stop);
        let back: Vec<f64> = qdot.iter().map(|v| -v).collect();
        let (_, out, _) = drive(&mut f, robot, &q, &back, 80, 801);
        assert_eq!(
            out.flags & ipc_types::safe_flags::CLEARANCE_LIMITED,
            0,
            "{name}"
        );
        assert!(
            out.clearance_m > closest.1 + 0.02,
            "{name}: {}",
            out.clearance_m
        );
    }
}

/// The Gen3's whole-arm model takes its seven joints: the tool's translational and angular
/// Jacobians are the arm chain's (base -> TCP) in all seven columns, zero beyond, and a joint
/// vector of another length is refused.
#[test]
fn the_gen3s_whole_arm_jacobians_are_the_chains_in_seven_columns() {
    use safety::clearance::{MAX_ARM_JOINTS, WholeArm};
    let robot = RobotProfile::by_name("gen3").unwrap();
    let mut arm = WholeArm::new(robot, Scene::default()).unwrap();
    assert_eq!(arm.n_joints(), 7);
    let q = [0.3, 0.5, -2.6, -1.9, 0.4, 0.8, -0.7];
    assert!(arm.update(&q, 0.5));
    let mut jac = kinematics::Jacobian::zeros(7);
    robot.arm().fk_jacobian(&q, &mut jac).unwrap();
    let tool = arm.tool().unwrap();
    let angular = arm.angular();
    for i in 0..3 {
        for j in 0..7 {
            assert!(
                (tool[i][j] - jac.get(i, j)).abs() < 1e-12,
                "linear ({i}, {j}): {} vs {}",
                tool[i][j],
                jac.get(i, j)
            );
            assert!(
                (angular[i][j] - jac.get(i + 3, j)).abs() < 1e-12,
                "angular ({i}, {j})"
            );
        }
        assert!(tool[i][7..MAX_ARM_JOINTS].iter().all(|v| *v == 0.0));
    }
    assert!(arm.closest().is_some());
    assert!(!arm.update(&q[..6], 0.5));
    assert!(arm.closest().is_none());
}
