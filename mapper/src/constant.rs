//! The drill map: one fixed joint velocity, whatever the stick, for tests and for labs checking
//! their set-up (does the arm move, which way, does the deadman stop it, does a fault stop it
//! and does it stay stopped). It ignores the action by design ([`ActionMap::uses_input`] is
//! false), so the arm moves whenever safety lets it: with `[safety] deadman = true` while the
//! deadman is held, else always (after the operator's input passed through neutral once, like
//! any map; see `safety::restart`).
//!
//! Served under the model spec `constant:qdot=v1,v2,v3,v4,v5,v6` (rad/s, the Gen3 lite's six
//! joints, each finite and within the URDF's velocity limit; another robot profile: one per joint
//! of its arm), like `modeswitch`:
//!
//! ```
//! use mapper::LoadedModel;
//!
//! let mut m = LoadedModel::load("constant:qdot=0,-0.4,0,0,0,0").unwrap();
//! assert!(!m.map.uses_input());
//! let mut out = [0.0; 6];
//! m.map.eval(&[0.0; 6], 0.0, &[0.7, -0.2], &mut out);
//! assert_eq!(out, [0.0, -0.4, 0.0, 0.0, 0.0, 0.0]);
//! assert!(LoadedModel::load("constant:qdot=0,-9,0,0,0,0").is_err());
//! ```

use ipc_types::MAX_JOINTS;
use kinematics::RobotProfile;

use crate::ActionMap;
use crate::model::{FORMAT, ModelError, ModelHeader, ModelKind, TrainingInfo, VERSION};

/// The spec's name: `constant:qdot=...`.
pub const SPEC: &str = "constant";

/// Whether `spec` names the drill map (`constant` or `constant:...`) rather than a file.
pub fn is_spec(spec: &str) -> bool {
    spec == SPEC
        || spec
            .strip_prefix(SPEC)
            .is_some_and(|rest| rest.starts_with(':'))
}

/// The drill map on a robot's arm: `qdot` at every tick.
#[derive(Debug, Clone, PartialEq)]
pub struct ConstantMap {
    qdot: [f64; MAX_JOINTS],
    n_joints: usize,
}

impl ConstantMap {
    /// The map commanding `qdot` (rad/s, one entry per joint of `robot`'s arm); refuses a
    /// wrong count, a non-finite velocity or one above the URDF's velocity limit, naming the
    /// joint. `model` names the map in the error.
    pub fn new(qdot: &[f64], robot: &RobotProfile, model: &str) -> Result<Self, ModelError> {
        let bad = |reason: String| ModelError::Parameters {
            model: model.to_owned(),
            reason,
        };
        let n = robot.n_joints();
        if qdot.len() != n || n > MAX_JOINTS {
            return Err(bad(format!(
                "qdot has {} entries; the {} has {n} joints",
                qdot.len(),
                robot.description()
            )));
        }
        let limits = robot.urdf_velocity_rad_s();
        for (j, (v, lim)) in qdot.iter().zip(limits).enumerate() {
            if !v.is_finite() || v.abs() > *lim {
                return Err(bad(format!(
                    "qdot entry {j} ({}) is {v} rad/s; it must be a finite number within \
                     the URDF velocity limit ±{lim} rad/s",
                    robot.joint_names()[j]
                )));
            }
        }
        let mut fixed = [0.0; MAX_JOINTS];
        fixed[..n].copy_from_slice(qdot);
        Ok(Self {
            qdot: fixed,
            n_joints: n,
        })
    }

    /// The commanded joint velocity (rad/s).
    pub fn qdot(&self) -> &[f64] {
        &self.qdot[..self.n_joints]
    }

    /// The map and header for a spec `constant:qdot=v1,...,v6` on the default robot.
    pub fn from_spec(spec: &str) -> Result<(ModelHeader, Self), ModelError> {
        Self::from_spec_for(RobotProfile::default_robot(), spec)
    }

    /// The map and header for a spec `constant:qdot=v1,...,vN` on `robot`'s arm.
    pub fn from_spec_for(
        robot: &RobotProfile,
        spec: &str,
    ) -> Result<(ModelHeader, Self), ModelError> {
        let bad = |reason: String| ModelError::Parameters {
            model: spec.to_owned(),
            reason,
        };
        let n = robot.n_joints();
        let list = spec
            .strip_prefix(SPEC)
            .and_then(|r| r.strip_prefix(':'))
            .and_then(|r| r.trim().strip_prefix("qdot="))
            .ok_or_else(|| {
                bad(format!(
                    "the drill map needs its joint velocity: `{SPEC}:qdot=v1,...,v{n}` (rad/s), \
                     e.g. `{SPEC}:qdot=0,-0.4,0,0,0,0`"
                ))
            })?;
        let qdot = list
            .split(',')
            .map(str::trim)
            .enumerate()
            .map(|(j, v)| {
                v.parse::<f64>()
                    .map_err(|_| bad(format!("qdot entry {j} `{v}` is not a number")))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        let map = Self::new(&qdot, robot, spec)?;
        Ok((header(spec, robot), map))
    }
}

/// The header of the drill map on `robot` (speed scale 1: the output is in rad/s).
fn header(command: &str, robot: &RobotProfile) -> ModelHeader {
    ModelHeader {
        format: FORMAT.to_owned(),
        version: VERSION,
        kind: ModelKind::Constant,
        n_joints: robot.n_joints(),
        latent_dim: ipc_types::ACTION_DIM,
        joint_names: robot.joint_names().to_vec(),
        speed_scale_rad_s: 1.0,
        lipschitz_bound: None,
        network: None,
        training: TrainingInfo {
            command: command.to_owned(),
            ..TrainingInfo::default()
        },
    }
}

impl ActionMap for ConstantMap {
    fn kind(&self) -> ModelKind {
        ModelKind::Constant
    }

    fn n_joints(&self) -> usize {
        self.n_joints
    }

    fn latent_dim(&self) -> usize {
        ipc_types::ACTION_DIM
    }

    fn eval(&mut self, _q: &[f64], _c: f64, _a: &[f64], out: &mut [f64]) {
        for (o, v) in out.iter_mut().zip(&self.qdot) {
            *o = *v;
        }
    }

    fn uses_input(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LoadedModel;
    use crate::step::MapperStep;
    use ipc_types::{JoystickInput, RobotState, mapper_flags};
    use proptest::prelude::*;

    #[test]
    fn the_spec_is_built_in_and_loads() {
        assert!(is_spec("constant") && is_spec("constant:qdot=0,0,0,0,0,0"));
        assert!(!is_spec("constant.safetensors") && !is_spec("constants:qdot=1"));
        assert!(crate::model::is_builtin("constant:qdot=0,-0.4,0,0,0,0"));
        let m = LoadedModel::load("constant:qdot=0, -0.4, 0, 0, 0, 0.25").unwrap();
        assert_eq!(m.header.kind, ModelKind::Constant);
        assert_eq!(m.map.kind(), ModelKind::Constant);
        assert_eq!(m.header.speed_scale_rad_s, 1.0);
        assert_eq!(m.source, "constant:qdot=0, -0.4, 0, 0, 0, 0.25");
        m.expect_dims(6, 2).unwrap();
        assert!(!m.map.uses_input());
    }

    #[test]
    fn bad_specs_say_what_is_wrong() {
        let err = |spec: &str| LoadedModel::load(spec).unwrap_err().to_string();
        let e = err("constant");
        assert!(e.contains("constant:qdot=v1,...,v6"), "{e}");
        assert!(err("constant:speed=1").contains("needs its joint velocity"));
        let e = err("constant:qdot=0,0,0");
        assert!(e.contains("3 entries") && e.contains("6 joints"), "{e}");
        let e = err("constant:qdot=0,x,0,0,0,0");
        assert!(e.contains("entry 1 `x` is not a number"), "{e}");
        for bad in ["NaN", "inf", "-inf", "1.7", "-1.61"] {
            let e = err(&format!("constant:qdot=0,{bad},0,0,0,0"));
            assert!(
                e.starts_with(&format!(
                    "model constant:qdot=0,{bad},0,0,0,0: qdot entry 1 (joint_2)"
                )) && e.contains("URDF velocity limit ±1.6 rad/s"),
                "{e}"
            );
        }
        // The wrist's limit is 3.2 rad/s.
        LoadedModel::load("constant:qdot=0,0,0,0,0,3.2").unwrap();
        assert!(err("constant:qdot=0,0,0,0,0,3.3").contains("joint_6"));
    }

    #[test]
    fn the_mapper_step_commands_it_whatever_the_stick_and_says_it_ignores_the_input() {
        let m = LoadedModel::load("constant:qdot=0,-0.4,0,0,0,0").unwrap();
        let mut step = MapperStep::new(3, m, 6).unwrap();
        let state = RobotState::at_rest(7, 1000, 6);
        for axes in [[0.0, 0.0], [1.0, 0.0], [-0.3, 0.9]] {
            let joy = JoystickInput {
                tick: 7,
                t_ns: 900,
                seq: 1,
                axes,
                gripper: 0.0,
                buttons: 0,
            };
            let c = step.step(&state, Some(&joy));
            assert_eq!(&c.qdot_rad_s[..6], &[0.0, -0.4, 0.0, 0.0, 0.0, 0.0]);
            assert_eq!(c.flags, mapper_flags::IGNORES_INPUT);
            // The stick is still reported, for safety's restart prevention.
            assert_eq!(c.action, axes);
        }
        let c = step.step(&state, None);
        assert_eq!(
            c.flags,
            mapper_flags::IGNORES_INPUT | mapper_flags::NO_INPUT
        );
        assert_eq!(c.qdot_rad_s[1], -0.4);
    }

    proptest! {
        /// Any six numbers: accepted exactly when each is finite and within its URDF limit,
        /// and then commanded as given.
        #[test]
        fn accepts_exactly_the_velocities_within_the_urdf_limits(
            qdot in proptest::array::uniform6(prop_oneof![
                8 => -4.0f64..4.0,
                1 => Just(f64::NAN),
                1 => Just(f64::INFINITY),
            ]),
        ) {
            let limits = RobotProfile::default_robot().urdf_velocity_rad_s();
            let ok = qdot.iter().zip(limits).all(|(v, l)| v.is_finite() && v.abs() <= *l);
            let spec = format!(
                "constant:qdot={}",
                qdot.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
            );
            match LoadedModel::load(&spec) {
                Ok(mut m) => {
                    prop_assert!(ok, "{spec} accepted");
                    let mut out = [0.0; 6];
                    m.map.eval(&[0.0; 6], 0.0, &[0.5, 0.5], &mut out);
                    prop_assert_eq!(out, qdot);
                }
                Err(e) => prop_assert!(!ok, "{spec} refused: {e}"),
            }
        }
    }
}
