//! Per-tick cost of the safety filter, `SafetyFilter::step`, on the Gen3 lite limits: a
//! command in the middle of the range, one braking toward a joint limit, and one with the
//! workspace rule on (a linear tool model, to time the rule itself; the real forward
//! kinematics adds its own cost); then the safety process's filter, with the whole-arm rules
//! (the collision model's clearance every tick, the speed caps) and the real tool model: at
//! home (nothing near), with the gripper 5 cm above the table and driving down (braking, the
//! exact check of the next tick), and with two boxes in the scene; last, two of these after a
//! sweep of the caches, as the safety process meets them at each 40 Hz tick; last, the Gen3
//! (7 joints) beside the Gen3 lite with each profile's own filter.
//!
//! Run: `cargo bench -p safety --bench filter` (the two profiles alone: `-- gen3`).
#![allow(missing_docs, clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use ipc_types::{MAX_JOINTS, MapperCommand, RobotState};
use safety::{SafetyConfig, SafetyFilter, TcpModel};
use std::hint::black_box;

const NOW: u64 = 1_000_000_000;

struct LinearTcp;

impl TcpModel for LinearTcp {
    fn tcp(&mut self, q: &[f64], p: &mut [f64; 3], jv: &mut [[f64; MAX_JOINTS]; 3]) {
        *jv = [[0.0; MAX_JOINTS]; 3];
        jv[0][1] = 0.3;
        jv[1][0] = 0.4;
        jv[2][1] = -0.3;
        jv[2][2] = -0.25;
        *p = [0.4 + 0.3 * q[1], 0.4 * q[0], 0.3 - 0.3 * q[1] - 0.25 * q[2]];
    }
}

fn cmd(tick: u64, q0: f64) -> MapperCommand {
    cmd_of(tick, [q0, -0.2, 0.1, 0.3, -0.1, 0.2])
}

fn cmd_of(tick: u64, v: [f64; 6]) -> MapperCommand {
    let mut qdot = [0.0; MAX_JOINTS];
    qdot[..6].copy_from_slice(&v);
    MapperCommand {
        tick,
        t_ns: NOW - 500_000,
        state_t_ns: NOW - 1_000_000,
        state_rx_ns: 0,
        joystick_t_ns: NOW - 10_000_000,
        joystick_rx_ns: 0,
        joystick_seq: 1,
        compute_ns: 0,
        mapper_id: 1,
        n_joints: 6,
        flags: 0,
        buttons: 0,
        action: [0.0; 2],
        qdot_rad_s: qdot,
        gripper_rate: 0.0,
    }
}

fn bench(c: &mut Criterion) {
    let limits = kinematics::gen3_lite::limits();
    let mut state = RobotState::at_rest(0, NOW - 1_000_000, 6);
    state.q_rad[..6].copy_from_slice(&kinematics::gen3_lite::HOME);

    let mut f = SafetyFilter::new(SafetyConfig::default(), &limits, 0.025).unwrap();
    let mut tick = 0u64;
    c.bench_function("safety step (mid-range)", |b| {
        b.iter(|| {
            tick += 1;
            state.tick = tick;
            state.applied_tick = tick - 1;
            black_box(f.step(black_box(&cmd(tick, 0.3)), &state, NOW))
        })
    });

    let mut near = state;
    near.q_rad[0] = 2.62;
    let mut f = SafetyFilter::new(SafetyConfig::default(), &limits, 0.025).unwrap();
    c.bench_function("safety step (braking at a joint limit)", |b| {
        b.iter(|| {
            tick += 1;
            near.tick = tick;
            near.applied_tick = tick - 1;
            black_box(f.step(black_box(&cmd(tick, 0.4)), &near, NOW))
        })
    });

    let mut f = SafetyFilter::new(SafetyConfig::default(), &limits, 0.025)
        .unwrap()
        .with_tcp_model(Box::new(LinearTcp));
    c.bench_function("safety step (workspace rule, linear tool model)", |b| {
        b.iter(|| {
            tick += 1;
            state.tick = tick;
            state.applied_tick = tick - 1;
            black_box(f.step(black_box(&cmd(tick, 0.3)), &state, NOW))
        })
    });
}

fn whole_arm(cfg: SafetyConfig) -> SafetyFilter {
    SafetyFilter::new(cfg, &kinematics::gen3_lite::limits(), 0.025)
        .unwrap()
        .with_tcp_model(Box::new(safety::ChainTcp::of(
            kinematics::RobotProfile::default_robot(),
        )))
        .with_whole_arm(kinematics::RobotProfile::default_robot())
        .unwrap()
}

fn bench_whole_arm(c: &mut Criterion) {
    let mut state = RobotState::at_rest(0, NOW - 1_000_000, 6);
    state.q_rad[..6].copy_from_slice(&kinematics::gen3_lite::HOME);
    let mut tick = 0u64;
    let mut run = |c: &mut Criterion, name: &str, f: &mut SafetyFilter, s: &mut RobotState, v| {
        c.bench_function(name, |b| {
            b.iter(|| {
                tick += 1;
                s.tick = tick;
                s.applied_tick = tick - 1;
                black_box(f.step(black_box(&cmd_of(tick, v)), s, NOW))
            })
        });
    };
    let mid = [0.3, -0.2, 0.1, 0.3, -0.1, 0.2];
    let mut f = whole_arm(SafetyConfig::default());
    run(
        c,
        "safety step (whole arm, table, at home)",
        &mut f,
        &mut state,
        mid,
    );

    // The gripper about 5 cm above the table, the shoulder driving it down.
    let mut near = state;
    near.q_rad[1] = -0.98;
    let mut f = whole_arm(SafetyConfig::default());
    let down = [0.0, -0.2, 0.0, 0.0, 0.0, 0.0];
    let out = f.step(&cmd_of(1, down), &near, NOW);
    assert!(out.clearance_m < 0.07, "{}", out.clearance_m);
    run(
        c,
        "safety step (whole arm, table, braking near it)",
        &mut f,
        &mut near,
        down,
    );

    let mut cfg = SafetyConfig::default();
    for (name, min, max) in [
        ("fixture", [0.5, -0.3, 0.0], [0.8, 0.3, 0.4]),
        ("wall", [-0.8, 0.6, 0.0], [0.8, 0.7, 1.0]),
    ] {
        cfg.scene.boxes.push(safety::BoxConfig {
            name: name.into(),
            min,
            max,
        });
    }
    let mut f = whole_arm(cfg);
    run(
        c,
        "safety step (whole arm, table + 2 boxes, at home)",
        &mut f,
        &mut state,
        mid,
    );
}

/// The safety process runs once every 25 ms, in between the machine runs everything else: its
/// caches are cold at each tick. These cases sweep a buffer larger than the last-level cache
/// before each step (outside the timed part), to put the hot-loop figures above next to the
/// ones `scl bench latency` reports from inside the process.
fn bench_cold(c: &mut Criterion) {
    const SWEEP: usize = 64 << 20;
    let mut buf = vec![1u8; SWEEP];
    let mut sweep = move || {
        for i in (0..SWEEP).step_by(64) {
            buf[i] = buf[i].wrapping_add(1);
        }
        black_box(buf[SWEEP / 2]);
    };
    let mut state = RobotState::at_rest(0, NOW - 1_000_000, 6);
    state.q_rad[..6].copy_from_slice(&kinematics::gen3_lite::HOME);
    let state = state;
    let mid = [0.3, -0.2, 0.1, 0.3, -0.1, 0.2];
    let mut tick = 0u64;
    let limits = kinematics::gen3_lite::limits();
    let mut plain = SafetyFilter::new(SafetyConfig::default(), &limits, 0.025).unwrap();
    let mut arm = whole_arm(SafetyConfig::default());
    for (name, f) in [
        ("safety step (mid-range, caches swept)", &mut plain),
        (
            "safety step (whole arm, table, at home, caches swept)",
            &mut arm,
        ),
    ] {
        c.bench_function(name, |b| {
            b.iter_batched(
                || {
                    sweep();
                    tick += 1;
                    let mut s = state;
                    s.tick = tick;
                    s.applied_tick = tick - 1;
                    (cmd_of(tick, mid), s)
                },
                |(cmd, s)| black_box(f.step(black_box(&cmd), &s, NOW).clearance_m),
                criterion::BatchSize::PerIteration,
            )
        });
    }
}

/// A command of `v.len()` joints.
fn cmd_n(tick: u64, v: &[f64]) -> MapperCommand {
    let mut c = cmd_of(tick, [0.0; 6]);
    c.qdot_rad_s = [0.0; MAX_JOINTS];
    c.qdot_rad_s[..v.len()].copy_from_slice(v);
    c.n_joints = v.len() as u32;
    c
}

/// The Gen3 (7 joints) beside the Gen3 lite (6), each with the filter the safety process
/// builds for its profile (`SafetyFilter::for_graph`: the workspace rule on the arm chain's
/// tool, the whole-arm rules on the profile's collision model, the default table): at home
/// with a command in the middle of the range, and with the gripper about 5 cm above the table
/// and the shoulder driving it down (braking, the exact check of the next tick). Run alone:
/// `cargo bench -p safety --bench filter -- gen3`.
fn bench_profiles(c: &mut Criterion) {
    let mut tick = 0u64;
    for (name, mid, shoulder, down) in [
        (
            "gen3_lite",
            &[0.3, -0.2, 0.1, 0.3, -0.1, 0.2][..],
            -0.98,
            &[0.0, -0.2, 0.0, 0.0, 0.0, 0.0][..],
        ),
        (
            "gen3",
            &[0.3, -0.2, 0.1, 0.3, -0.1, 0.2, 0.1][..],
            0.82,
            &[0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0][..],
        ),
    ] {
        let robot = kinematics::RobotProfile::by_name(name).unwrap();
        let n = robot.n_joints();
        let dt = 1.0 / robot.control_rate_hz();
        let mut home = RobotState::at_rest(0, NOW - 1_000_000, n as u32);
        home.q_rad[..n].copy_from_slice(robot.named_pose("home").unwrap());
        let mut near = home;
        near.q_rad[1] = shoulder;
        for (case, s, v) in [
            ("at home", home, mid),
            ("braking near the table", near, down),
        ] {
            let mut s = s;
            let mut f = SafetyFilter::for_graph(SafetyConfig::for_robot(robot), robot, dt).unwrap();
            let out = f.step(&cmd_n(1, v), &s, NOW);
            assert!(out.clearance_m.is_finite(), "{name}: {out:?}");
            if case != "at home" {
                assert!(out.clearance_m < 0.07, "{name}: {}", out.clearance_m);
            }
            c.bench_function(
                &format!("{name}: safety step (whole arm, table, {case})"),
                |b| {
                    b.iter(|| {
                        tick += 1;
                        s.tick = tick;
                        s.applied_tick = tick - 1;
                        black_box(f.step(black_box(&cmd_n(tick, v)), &s, NOW))
                    })
                },
            );
        }
    }
}

criterion_group!(benches, bench, bench_whole_arm, bench_cold, bench_profiles);
criterion_main!(benches);
