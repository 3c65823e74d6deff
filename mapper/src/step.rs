//! The mapper process's step function: one robot state and the newest joystick sample in,
//! one [`MapperCommand`] out. Pure and allocation-free; the process loop around it only
//! waits, reads, stamps times and publishes.

use ipc_types::{
    ACTION_DIM, JoystickInput, MAX_JOINTS, MapperCommand, NO_TICK, RobotState, mapper_flags,
};

use crate::MapMode;
use crate::model::{LoadedModel, ModelError};

/// Gripper rate at full gripper input (1/s on the `c` scale): open to closed in 1 s.
pub const DEFAULT_GRIPPER_RATE: f64 = 1.0;

/// The state of one mapper: its id, its model and preallocated buffers.
#[derive(Debug)]
pub struct MapperStep {
    id: u32,
    model: LoadedModel,
    gripper_rate: f64,
    /// Buttons of the last usable joystick sample, for press (rising-edge) detection.
    held: u32,
    out: [f64; MAX_JOINTS],
    /// The arm, when known: its continuous joints are wrapped into the turn around home
    /// before the map sees them ([`kinematics::RobotProfile::wrap_for_maps`]).
    robot: Option<&'static kinematics::RobotProfile>,
}

impl MapperStep {
    /// A mapper with id `id` serving `model` for a robot with `n_joints` joints. Refuses a
    /// model of another shape.
    pub fn new(id: u32, model: LoadedModel, n_joints: usize) -> Result<Self, ModelError> {
        model.expect_dims(n_joints, ACTION_DIM)?;
        Ok(Self {
            id,
            model,
            gripper_rate: DEFAULT_GRIPPER_RATE,
            held: 0,
            out: [0.0; MAX_JOINTS],
            robot: None,
        })
    }

    /// [`MapperStep::new`] for the arm of `robot`, whose continuous joints the map sees
    /// wrapped into the turn around home: the same pose, the same command.
    pub fn for_robot(
        id: u32,
        model: LoadedModel,
        robot: &'static kinematics::RobotProfile,
    ) -> Result<Self, ModelError> {
        let mut s = Self::new(id, model, robot.n_joints())?;
        s.robot = Some(robot);
        Ok(s)
    }

    /// The joint angles the map sees: `state`'s, continuous joints wrapped (on the stack).
    fn map_q(&self, state: &RobotState, m: usize) -> [f64; MAX_JOINTS] {
        let mut q = [0.0; MAX_JOINTS];
        let n = m.min(state.q().len());
        q[..n].copy_from_slice(&state.q()[..n]);
        if let Some(r) = self.robot {
            r.wrap_for_maps(&mut q[..n]);
        }
        q
    }

    /// Loads and checks the model `spec` for the arm of `robot` (the graph's robot profile),
    /// ticking every `period_s` seconds (`[graph] rate_hz`): every problem is reported here, at
    /// start-up, never at tick time.
    pub fn load(
        spec: &str,
        id: u32,
        robot: &'static kinematics::RobotProfile,
        period_s: f64,
    ) -> Result<Self, ModelError> {
        let model = LoadedModel::load_for(spec, robot)?.at_period(period_s);
        Self::for_robot(id, model, robot)
    }

    /// The mapper id.
    pub fn id(&self) -> u32 {
        self.id
    }

    /// The model served.
    pub fn model(&self) -> &LoadedModel {
        &self.model
    }

    /// The map's current mode, for maps that have modes (see [`crate::ActionMap::mode`]).
    pub fn mode(&self) -> Option<MapMode> {
        self.model.map.mode()
    }

    /// Evaluates the map once at `state` without changing it ([`crate::ActionMap::direction`]
    /// of the first axis into `out`), so that the next [`MapperStep::step`] finds the map's
    /// weights and code in cache (`[graph] rt_prewarm_us`). The next step's command is the
    /// same with or without it.
    pub fn warm(&mut self, state: &RobotState, out: &mut [f64]) {
        let m = self.model.header.n_joints;
        if state.n_joints as usize != m || out.len() < m {
            return;
        }
        let q = self.map_q(state, m);
        self.model
            .map
            .direction(&q[..m], state.gripper, 0, &mut out[..m]);
    }

    /// Computes the command for `state`'s tick from the newest joystick sample `joy`.
    ///
    /// The action is zero when there is no sample or a non-finite one, and clamped radially to
    /// `|a| <= 1`. A non-finite model output or an unusable state gives a zero command. Each
    /// case sets its bit in [`MapperCommand::flags`]. Times (`t_ns`, `compute_ns`) are left at
    /// 0 for the caller to stamp.
    ///
    /// Buttons pressed since the last usable sample (rising edges, so a button held over many
    /// ticks is one press) go to the map before it is evaluated ([`crate::ActionMap::press`]);
    /// a missing, non-finite or stale sample leaves the held buttons as they were.
    pub fn step(&mut self, state: &RobotState, joy: Option<&JoystickInput>) -> MapperCommand {
        let m = self.model.header.n_joints;
        let mut flags = if self.model.map.uses_input() {
            0
        } else {
            mapper_flags::IGNORES_INPUT
        };
        let mut a = [0.0f64; ACTION_DIM];
        let mut gripper = 0.0;
        match joy {
            None => flags |= mapper_flags::NO_INPUT,
            Some(j) if j.axes.iter().any(|v| !v.is_finite()) => {
                flags |= mapper_flags::INPUT_NON_FINITE;
            }
            Some(j) if j.tick != NO_TICK && state.tick > j.tick.saturating_add(1) => {
                flags |= mapper_flags::INPUT_STALE;
            }
            Some(j) => {
                if j.tick == NO_TICK {
                    flags |= mapper_flags::INPUT_NO_TICK;
                }
                let pressed = j.buttons & !self.held;
                self.held = j.buttons;
                if pressed != 0 {
                    self.model.map.press(pressed);
                }
                for (ai, v) in a.iter_mut().zip(j.axes) {
                    *ai = f64::from(v);
                }
                let norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
                if norm > 1.0 {
                    flags |= mapper_flags::INPUT_CLAMPED;
                    a.iter_mut().for_each(|v| *v /= norm);
                }
                if j.gripper.is_finite() {
                    gripper = f64::from(j.gripper).clamp(-1.0, 1.0) * self.gripper_rate;
                }
            }
        }
        let state_ok = state.n_joints as usize == m
            && state.q().iter().all(|v| v.is_finite())
            && state.gripper.is_finite();
        self.out = [0.0; MAX_JOINTS];
        if !state_ok {
            flags |= mapper_flags::STATE_INVALID;
            gripper = 0.0;
        } else {
            let q = self.map_q(state, m);
            self.model
                .map
                .eval(&q[..m], state.gripper, &a, &mut self.out[..m]);
            let s = self.model.header.speed_scale_rad_s;
            self.out[..m].iter_mut().for_each(|v| *v *= s);
            if self.out[..m].iter().any(|v| !v.is_finite()) {
                flags |= mapper_flags::OUTPUT_NON_FINITE;
                self.out = [0.0; MAX_JOINTS];
            }
        }
        MapperCommand {
            tick: state.tick,
            t_ns: 0,
            state_t_ns: state.t_ns,
            state_rx_ns: 0,
            joystick_t_ns: joy.map_or(0, |j| j.t_ns),
            joystick_rx_ns: 0,
            joystick_seq: joy.map_or(0, |j| j.seq),
            compute_ns: 0,
            mapper_id: self.id,
            n_joints: m as u32,
            flags,
            buttons: joy.map_or(0, |j| j.buttons),
            action: [a[0] as f32, a[1] as f32],
            qdot_rad_s: self.out,
            gripper_rate: gripper,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_continuous_joint_a_turn_away_gives_the_same_command() {
        let robot = kinematics::RobotProfile::by_name("gen3").unwrap();
        let mut step = MapperStep::load("bundled", 1, robot, 0.025).unwrap();
        let home = robot.named_pose("home").unwrap();
        let joint = robot.continuous_joints().iter().position(|c| *c).unwrap();
        let state = |extra: f64| {
            let mut s = RobotState::at_rest(5, 1, robot.n_joints() as u32);
            s.q_rad[..home.len()].copy_from_slice(home);
            s.q_rad[joint] += extra;
            s
        };
        let joy = JoystickInput {
            tick: 5,
            axes: [0.7, 0.2],
            ..JoystickInput::neutral(1)
        };
        let at_home = step.step(&state(0.0), Some(&joy)).qdot_rad_s;
        let turned = step
            .step(&state(std::f64::consts::TAU), Some(&joy))
            .qdot_rad_s;
        assert!(at_home.iter().any(|v| *v != 0.0));
        for (a, b) in at_home.iter().zip(turned) {
            assert!((a - b).abs() < 1e-9, "{at_home:?} against {turned:?}");
        }
    }
    use crate::model::BUNDLED_NAME;
    use crate::pca::PcaMap;
    use nalgebra::DMatrix;

    fn state(tick: u64) -> RobotState {
        RobotState::at_rest(tick, 1000, 6)
    }

    fn joy(axes: [f32; 2]) -> JoystickInput {
        JoystickInput {
            tick: NO_TICK,
            t_ns: 900,
            seq: 42,
            axes,
            gripper: 0.5,
            buttons: 0,
        }
    }

    fn step_with_basis() -> (MapperStep, DMatrix<f64>) {
        let model = LoadedModel::load(BUNDLED_NAME).unwrap();
        let s = model.header.speed_scale_rad_s;
        let step = MapperStep::new(7, model, 6).unwrap();
        // Recover the bundled map's basis at this state through the map itself (the map is
        // linear in the action at a fixed state; every state here has the same joints).
        let mut probe = MapperStep::new(7, LoadedModel::load(BUNDLED_NAME).unwrap(), 6).unwrap();
        let mut b = DMatrix::zeros(6, 2);
        for j in 0..2 {
            let mut a = [0.0f32; 2];
            a[j] = 1.0;
            let c = probe.step(&state(0), Some(&joy(a)));
            for i in 0..6 {
                b[(i, j)] = c.qdot_rad_s[i] / s;
            }
        }
        (step, b)
    }

    #[test]
    fn command_is_scaled_map_of_action_with_inherited_times() {
        let (mut step, b) = step_with_basis();
        let s = step.model().header.speed_scale_rad_s;
        let mut j = joy([0.3, -0.4]);
        j.tick = 11;
        let c = step.step(&state(11), Some(&j));
        assert_eq!(c.tick, 11);
        assert_eq!(c.mapper_id, 7);
        assert_eq!(
            (c.state_t_ns, c.joystick_t_ns, c.joystick_seq),
            (1000, 900, 42)
        );
        assert_eq!(c.flags, 0);
        for i in 0..6 {
            let e = s * (b[(i, 0)] * 0.3 - b[(i, 1)] * 0.4);
            assert!((c.qdot_rad_s[i] - e).abs() < 1e-6);
        }
        assert_eq!(&c.qdot_rad_s[6..], &[0.0, 0.0]);
        assert!((c.gripper_rate - 0.5).abs() < 1e-9);
        // The basis is orthonormal, so the speed is s * |a|.
        let n: f64 = c.qdot_rad_s.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((n - 0.5 * s).abs() < 1e-5);
    }

    #[test]
    fn long_actions_are_clamped_radially() {
        let (mut step, _) = step_with_basis();
        let mut j = joy([3.0, 4.0]);
        j.tick = 1;
        let c = step.step(&state(1), Some(&j));
        assert_eq!(c.flags, mapper_flags::INPUT_CLAMPED);
        assert!((c.action[0] - 0.6).abs() < 1e-6 && (c.action[1] - 0.8).abs() < 1e-6);
    }

    #[test]
    fn missing_or_bad_input_gives_zero_command() {
        let (mut step, _) = step_with_basis();
        let c = step.step(&state(1), None);
        assert_eq!(c.flags, mapper_flags::NO_INPUT);
        assert!(c.qdot_rad_s.iter().all(|v| *v == 0.0));
        let c = step.step(&state(1), Some(&joy([f32::NAN, 0.0])));
        assert_eq!(c.flags, mapper_flags::INPUT_NON_FINITE);
        assert!(c.qdot_rad_s.iter().all(|v| *v == 0.0));
        assert_eq!(c.gripper_rate, 0.0);
        let mut j = joy([1.0, 0.0]);
        j.tick = 1;
        let mut s = state(1);
        s.q_rad[2] = f64::INFINITY;
        let c = step.step(&s, Some(&j));
        assert_eq!(c.flags, mapper_flags::STATE_INVALID);
        assert!(c.qdot_rad_s.iter().all(|v| *v == 0.0));
        let mut s = state(1);
        s.n_joints = 5;
        let c = step.step(&s, Some(&j));
        assert_eq!(c.flags, mapper_flags::STATE_INVALID);
    }

    /// Warming leaves every map as it was: the same commands with and without it, for the
    /// stateless network and for mode switching (its ramp and mode are state).
    #[test]
    fn warming_changes_no_command() {
        for spec in [BUNDLED_NAME, "modeswitch"] {
            let mk = || {
                let m = LoadedModel::load(spec).unwrap().at_period(0.025);
                MapperStep::new(1, m, 6).unwrap()
            };
            let (mut plain, mut warmed) = (mk(), mk());
            let mut out = [0.0; 6];
            for k in 0..40u64 {
                let mut st = state(k);
                st.q_rad[..6].copy_from_slice(&[0.0, 0.3, 1.2, 0.1, -0.9, 0.2]);
                let mut j = joy([0.6, -0.3]);
                j.buttons = if k == 10 { ipc_types::buttons::MODE } else { 0 };
                warmed.warm(&st, &mut out);
                let (a, b) = (plain.step(&st, Some(&j)), warmed.step(&st, Some(&j)));
                assert_eq!(a.qdot_rad_s, b.qdot_rad_s, "{spec} tick {k}");
                assert_eq!(
                    plain.mode().map(|m| m.index),
                    warmed.mode().map(|m| m.index)
                );
            }
            // A state of another arm is not evaluated.
            let other = RobotState::at_rest(0, 1000, 5);
            out = [7.0; 6];
            warmed.warm(&other, &mut out);
            assert_eq!(out, [7.0; 6]);
        }
    }

    #[test]
    fn a_joystick_two_ticks_behind_is_stale() {
        let (mut step, _) = step_with_basis();
        let mut j = joy([1.0, 0.0]);
        j.tick = 9;
        // Answering the previous tick (or this one) is normal.
        assert_eq!(step.step(&state(10), Some(&j)).flags, 0);
        j.tick = 10;
        assert_eq!(step.step(&state(10), Some(&j)).flags, 0);
        // Two behind: the joystick stopped answering.
        let c = step.step(&state(12), Some(&j));
        assert_eq!(c.flags, mapper_flags::INPUT_STALE);
        assert!(c.qdot_rad_s.iter().all(|v| *v == 0.0));
        assert_eq!(c.gripper_rate, 0.0);
        // The start-up sample answers no tick: not stale (the age rule in safety covers it),
        // flagged so safety does not take it for the operator's neutral.
        j.tick = NO_TICK;
        assert_eq!(
            step.step(&state(12), Some(&j)).flags,
            mapper_flags::INPUT_NO_TICK
        );
    }

    #[test]
    fn non_finite_model_output_is_zeroed() {
        let mut b = DMatrix::zeros(6, 2);
        b[(0, 0)] = f64::MAX;
        b[(1, 0)] = 1.0;
        let mut model = LoadedModel::load(BUNDLED_NAME).unwrap();
        model.map = Box::new(PcaMap::new(b));
        model.header.speed_scale_rad_s = 10.0;
        let mut step = MapperStep::new(1, model, 6).unwrap();
        let mut j = joy([1.0, 0.0]);
        j.tick = 1;
        let c = step.step(&state(1), Some(&j));
        assert_eq!(c.flags, mapper_flags::OUTPUT_NON_FINITE);
        assert!(c.qdot_rad_s.iter().all(|v| *v == 0.0));
    }

    #[test]
    fn refuses_a_model_for_another_robot() {
        let model = LoadedModel::load(BUNDLED_NAME).unwrap();
        assert!(MapperStep::new(1, model, 7).is_err());
    }
}
