//! The drill map: one fixed joint velocity, whatever the stick, for tests and for labs checking
//! their set-up (does the arm move, which way, does the deadman stop it, does a fault stop it
//! and does it stay stopped). It ignores the action by design ([`ActionMap::uses_input`] is
//! false), so the arm moves whenever safety lets it: with `[safety] deadman = true` while the
//! deadman is held, else always (after the operator's input passed through neutral once, like
//! any map; see `safety::restart`).
//!
//! Served under the model spec `constant:qdot=v1,v2,v3,v4,v5,v6` (rad/s, the Gen3 lite's six
//! joints, each finite and within the URDF's velocity limit), like `modeswitch`:
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

use kinematics::{Gen3Lite, gen3_lite};

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

/// The drill map on the Gen3 lite: `qdot` at every tick.
#[derive(Debug, Clone, PartialEq)]
pub struct ConstantMap {
    qdot: [f64; gen3_lite::N_JOINTS],
}

impl ConstantMap {
    /// The map commanding `qdot` (rad/s); refuses a non-finite velocity or one above the
    /// URDF's velocity limit, naming the joint. `model` names the map in the error.
    pub fn new(qdot: [f64; gen3_lite::N_JOINTS], model: &str) -> Result<Self, ModelError> {
        let limits = Gen3Lite::get().arm().velocity_limits();
        for (j, (v, lim)) in qdot.iter().zip(limits).enumerate() {
            if !v.is_finite() || v.abs() > *lim {
                return Err(ModelError::Parameters {
                    model: model.to_owned(),
                    reason: format!(
                        "qdot entry {j} ({}) is {v} rad/s; it must be a finite number within \
                         the URDF velocity limit ±{lim} rad/s",
                        gen3_lite::JOINT_NAMES[j]
                    ),
                });
            }
        }
        Ok(Self { qdot })
    }

    /// The commanded joint velocity (rad/s).
    pub fn qdot(&self) -> &[f64; gen3_lite::N_JOINTS] {
        &self.qdot
    }

    /// The map and header for a spec `constant:qdot=v1,...,v6`.
    pub fn from_spec(spec: &str) -> Result<(ModelHeader, Self), ModelError> {
        let bad = |reason: String| ModelError::Parameters {
            model: spec.to_owned(),
            reason,
        };
        let n = gen3_lite::N_JOINTS;
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
        let values: Vec<&str> = list.split(',').map(str::trim).collect();
        if values.len() != n {
            return Err(bad(format!(
                "qdot has {} entries; the Gen3 lite has {n} joints",
                values.len()
            )));
        }
        let mut qdot = [0.0; gen3_lite::N_JOINTS];
        for (j, (q, v)) in qdot.iter_mut().zip(&values).enumerate() {
            *q = v
                .parse::<f64>()
                .map_err(|_| bad(format!("qdot entry {j} `{v}` is not a number")))?;
        }
        let map = Self::new(qdot, spec)?;
        Ok((header(spec), map))
    }
}

/// The header of the drill map on the Gen3 lite (speed scale 1: the output is in rad/s).
fn header(command: &str) -> ModelHeader {
    ModelHeader {
        format: FORMAT.to_owned(),
        version: VERSION,
        kind: ModelKind::Constant,
        n_joints: gen3_lite::N_JOINTS,
        latent_dim: ipc_types::ACTION_DIM,
        joint_names: gen3_lite::JOINT_NAMES
            .iter()
            .map(|s| (*s).to_owned())
            .collect(),
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
        gen3_lite::N_JOINTS
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
    use ipc_types::{JoystickInput, NO_TICK, RobotState, mapper_flags};
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
                tick: NO_TICK,
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
            let limits = Gen3Lite::get().arm().velocity_limits();
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
