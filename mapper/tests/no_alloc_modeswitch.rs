//! The mapper's step with the mode-switching map allocates nothing per tick: the Jacobian,
//! the condition number, the damped least-squares solve and the mode presses all stay on the
//! stack, counted by a global allocator that counts this thread's allocations. On the 6-joint
//! Gen3 lite and on the 7-joint Gen3, where the null-space task runs too.
//!
//! One test in this file, so no other test shares the process's allocator while it counts.
#![allow(clippy::unwrap_used)]

use ipc_types::{JoystickInput, RobotState, buttons};
use kinematics::RobotProfile;
use mapper::LoadedModel;
use mapper::step::MapperStep;

#[global_allocator]
static GLOBAL: test_support::CountingAllocator = test_support::CountingAllocator;

fn allocations() -> usize {
    test_support::thread_allocations()
}

#[test]
fn the_mode_switching_step_does_not_allocate() {
    for name in ["gen3_lite", "gen3"] {
        let robot = RobotProfile::by_name(name).unwrap();
        let n = robot.n_joints();
        // Set-up may allocate: load the map (parses the URDF once), build the step.
        let mut step =
            MapperStep::new(1, LoadedModel::load_for("modeswitch", robot).unwrap(), n).unwrap();
        let mut state = RobotState::at_rest(0, 1, n as u32);
        state.q_rad[..n].copy_from_slice(robot.named_pose("home").unwrap());

        // The counter sees allocations (so a zero below means something).
        let before = allocations();
        drop(std::hint::black_box(Vec::<u64>::with_capacity(16)));
        assert_eq!(allocations(), before + 1);

        let before = allocations();
        let mut moved = 0.0;
        for k in 0..3000u64 {
            let th = k as f32 * 0.01;
            let j = JoystickInput {
                tick: k,
                t_ns: 1,
                seq: k,
                axes: [th.cos(), th.sin()],
                gripper: 0.0,
                // The mode button pressed every 100 ticks for 5 ticks: 30 switches.
                buttons: if k % 100 < 5 { buttons::MODE } else { 0 },
            };
            state.tick = k;
            let c = step.step(&state, Some(&j));
            for i in 0..n {
                state.q_rad[i] += c.qdot_rad_s[i] * 0.001;
                moved += c.qdot_rad_s[i].abs();
            }
        }
        // Including the singular zero pose.
        state.q_rad = [0.0; 8];
        let c = step.step(&state, None);
        let after = allocations();
        let mode = step.mode().unwrap();
        assert!(moved > 0.0 && c.qdot_rad_s.iter().all(|v| v.is_finite()));
        assert_eq!(mode.switches, 30);
        assert_eq!(
            after - before,
            0,
            "{name}: the mapper step allocated {} times",
            after - before
        );
    }
}
