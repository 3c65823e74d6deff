//! A tick of the safety process's filter allocates nothing, for every built-in profile (the
//! Gen3 lite's six joints and the Gen3's seven): `SafetyFilter::for_graph` with the workspace
//! rule and the whole-arm rules, in closed loop from home into the table and a box (the
//! clearance, the pairs collected, braking, the exact check of the next tick), counted by a
//! global allocator that counts this thread's allocations.
//!
//! One test in this file, so no other test shares the process's allocator while it counts.
#![allow(clippy::unwrap_used)]

use ipc_types::{MAX_JOINTS, MapperCommand, NO_TICK, RobotState, safe_flags};
use kinematics::RobotProfile;
use safety::{BoxConfig, SafetyConfig, SafetyFilter};

#[global_allocator]
static GLOBAL: test_support::CountingAllocator = test_support::CountingAllocator;

mod common;

use common::NOW;

fn cmd(tick: u64, qdot: &[f64]) -> MapperCommand {
    common::command(tick, qdot, 0.0)
}

#[test]
fn a_tick_of_the_filter_does_not_allocate_for_any_profile() {
    // The counter sees allocations (so a zero below means something).
    let n = test_support::count_allocations(|| {
        drop(std::hint::black_box(Vec::<u64>::with_capacity(4)));
    });
    assert_eq!(n, 1);

    for name in RobotProfile::names() {
        let robot = RobotProfile::by_name(name).unwrap();
        let n = robot.n_joints();
        let dt = 1.0 / robot.control_rate_hz();
        // Set-up may allocate.
        let mut cfg = SafetyConfig::for_robot(robot);
        cfg.scene.boxes.push(BoxConfig {
            name: "fixture".into(),
            min: [0.45, -0.3, 0.0],
            max: [0.8, 0.3, 0.3],
        });
        let mut f = SafetyFilter::for_graph(cfg, robot, dt).unwrap();
        let home = robot.named_pose("home").unwrap();
        // Every joint moving, the shoulder leaning forward: into the box and the table.
        let qdot: Vec<f64> = (0..n)
            .map(|j| if j == 1 { 0.4 } else { 0.05 * (j as f64 - 2.5) })
            .map(|v| if name == "gen3_lite" { -v } else { v })
            .collect();
        let mut q = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(home);
        let mut flags = 0;
        let allocated = test_support::count_allocations(|| {
            let mut prev = [0.0; MAX_JOINTS];
            for tick in 1..=400 {
                let mut s = RobotState::at_rest(tick, NOW - 1_000_000, n as u32);
                s.q_rad = q;
                s.qdot_rad_s = prev;
                s.applied_tick = if tick > 1 { tick - 1 } else { NO_TICK };
                s.gripper = 0.5;
                let out = f.step(&cmd(tick, &qdot), &s, NOW);
                flags |= out.flags;
                prev = out.qdot_rad_s;
                for (qj, v) in q.iter_mut().zip(&prev).take(n) {
                    *qj += v * dt;
                }
            }
        });
        // The whole-arm rules acted (so their buffers were used).
        assert!(
            flags & safe_flags::CLEARANCE_LIMITED != 0,
            "{name}: {flags:#x}"
        );
        assert_eq!(allocated, 0, "{name}: a tick allocated {allocated} times");
    }
}
