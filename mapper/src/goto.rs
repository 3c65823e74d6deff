//! The go-to map: drives the arm to a joint pose at a limited speed, whatever the stick, so a
//! study (or a lab's "go home" button) moves the arm to a task's start pose through the same
//! graph and the same safety filter as any map, without stopping the graph.
//!
//! Served under the spec `goto:pose=NAME` (a named pose of the robot profile: `home`, `zero`,
//! `retract` on the Gen3 lite) or `goto:q=v1,...,v6` (rad, within the position limits), with
//! an optional `;speed=S` (rad/s, the fastest joint's speed, default [`DEFAULT_SPEED_RAD_S`]).
//! The joints move on a straight line in joint space, all arriving together, slowing in the
//! last [`SLOWDOWN_RAD`]; within [`ARRIVED_RAD`] of the pose on every joint it commands zero
//! and reports `arrived` as its mode (the mapper's status, `scl top`). It ignores the action
//! ([`ActionMap::uses_input`] is false), so with `[safety] deadman = true` the arm moves only
//! while the deadman is held.
//!
//! ```
//! use mapper::LoadedModel;
//!
//! let mut m = LoadedModel::load("goto:q=0.5,0,0,0,0,0;speed=0.2").unwrap();
//! let mut out = [0.0; 6];
//! m.map.eval(&[0.0; 6], 0.0, &[0.7, -0.2], &mut out);
//! assert_eq!(out, [0.2, 0.0, 0.0, 0.0, 0.0, 0.0]);
//! assert_eq!(m.map.mode().unwrap().name, "moving");
//! assert!(LoadedModel::load("goto:pose=nowhere").is_err());
//! ```

use ipc_types::MAX_JOINTS;
use kinematics::RobotProfile;

use crate::model::{FORMAT, ModelError, ModelHeader, ModelKind, TrainingInfo, VERSION};
use crate::{ActionMap, MapMode};

/// The spec's name: `goto:...`.
pub const SPEC: &str = "goto";
/// The fastest joint's speed when the spec names none (rad/s): a third of the Gen3 lite's
/// slowest joint limit, slow enough for a person beside the arm to follow.
pub const DEFAULT_SPEED_RAD_S: f64 = 0.3;
/// Within this distance of the pose on every joint (rad) the map commands zero: arrived.
pub const ARRIVED_RAD: f64 = 0.01;
/// Within this distance (the largest joint error, rad) the speed falls linearly to zero.
pub const SLOWDOWN_RAD: f64 = 0.15;

/// Whether `spec` names the go-to map rather than a file.
pub fn is_spec(spec: &str) -> bool {
    spec.strip_prefix(SPEC)
        .is_some_and(|rest| rest.starts_with(':'))
}

/// The go-to map on a robot's arm.
#[derive(Debug, Clone, PartialEq)]
pub struct GotoMap {
    goal: [f64; MAX_JOINTS],
    n_joints: usize,
    speed: f64,
    arrived: bool,
}

impl GotoMap {
    /// The map to `goal` (rad, one per joint of `robot`'s arm, within its position limits) at
    /// `speed` (rad/s, positive, within the slowest joint's velocity limit); `model` names the
    /// map in errors.
    pub fn new(
        goal: &[f64],
        speed: f64,
        robot: &RobotProfile,
        model: &str,
    ) -> Result<Self, ModelError> {
        let bad = |reason: String| ModelError::Parameters {
            model: model.to_owned(),
            reason,
        };
        let n = robot.n_joints();
        if goal.len() != n || n > MAX_JOINTS {
            return Err(bad(format!(
                "the pose has {} joints; the {} has {n}",
                goal.len(),
                robot.description()
            )));
        }
        for (j, q) in goal.iter().enumerate() {
            let (lo, hi) = (robot.limits().lower_rad[j], robot.limits().upper_rad[j]);
            if !q.is_finite() || *q < lo || *q > hi {
                return Err(bad(format!(
                    "joint {j} ({}) of the pose is {q} rad, outside its limits [{lo}, {hi}]",
                    robot.joint_names()[j]
                )));
            }
        }
        let slowest = robot
            .urdf_velocity_rad_s()
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        if !(speed.is_finite() && speed > 0.0 && speed <= slowest) {
            return Err(bad(format!(
                "speed {speed} rad/s must be positive and at most the slowest joint's limit \
                 {slowest} rad/s"
            )));
        }
        let mut fixed = [0.0; MAX_JOINTS];
        fixed[..n].copy_from_slice(goal);
        Ok(Self {
            goal: fixed,
            n_joints: n,
            speed,
            arrived: false,
        })
    }

    /// The pose it drives to (rad).
    pub fn goal(&self) -> &[f64] {
        &self.goal[..self.n_joints]
    }

    /// Whether `q` is at the pose: within [`ARRIVED_RAD`] on every joint.
    pub fn is_at(&self, q: &[f64]) -> bool {
        largest_error(self.goal(), q) <= ARRIVED_RAD
    }

    /// Parses `goto:pose=NAME[;speed=S]` or `goto:q=v1,...,vN[;speed=S]` for `robot`.
    pub fn from_spec_for(
        robot: &RobotProfile,
        spec: &str,
    ) -> Result<(ModelHeader, Self), ModelError> {
        let bad = |reason: String| ModelError::Parameters {
            model: spec.to_owned(),
            reason,
        };
        let n = robot.n_joints();
        let usage = || {
            let names: Vec<&str> = robot.pose_names().collect();
            bad(format!(
                "the go-to map needs a pose: `{SPEC}:pose=NAME` (one of {}) or \
                 `{SPEC}:q=v1,...,v{n}` (rad), optionally `;speed=S` (rad/s)",
                names.join(", ")
            ))
        };
        let body = spec
            .strip_prefix(SPEC)
            .and_then(|r| r.strip_prefix(':'))
            .ok_or_else(usage)?;
        let mut goal: Option<Vec<f64>> = None;
        let mut speed = DEFAULT_SPEED_RAD_S;
        for part in body.split(';').map(str::trim) {
            if let Some(name) = part.strip_prefix("pose=") {
                let q = robot.named_pose(name.trim()).ok_or_else(|| {
                    let names: Vec<&str> = robot.pose_names().collect();
                    bad(format!(
                        "the {} has no pose `{name}`; its poses: {}",
                        robot.description(),
                        names.join(", ")
                    ))
                })?;
                goal = Some(q.to_vec());
            } else if let Some(list) = part.strip_prefix("q=") {
                goal = Some(
                    list.split(',')
                        .map(str::trim)
                        .enumerate()
                        .map(|(j, v)| {
                            v.parse::<f64>()
                                .map_err(|_| bad(format!("q entry {j} `{v}` is not a number")))
                        })
                        .collect::<Result<_, _>>()?,
                );
            } else if let Some(s) = part.strip_prefix("speed=") {
                speed = s
                    .trim()
                    .parse()
                    .map_err(|_| bad(format!("speed `{s}` is not a number")))?;
            } else {
                return Err(usage());
            }
        }
        let goal = goal.ok_or_else(usage)?;
        let map = Self::new(&goal, speed, robot, spec)?;
        Ok((header(spec, robot), map))
    }
}

fn largest_error(goal: &[f64], q: &[f64]) -> f64 {
    goal.iter()
        .zip(q)
        .map(|(g, q)| (g - q).abs())
        .fold(0.0, f64::max)
}

/// The header of the go-to map on `robot` (speed scale 1: the output is in rad/s).
fn header(command: &str, robot: &RobotProfile) -> ModelHeader {
    ModelHeader {
        format: FORMAT.to_owned(),
        version: VERSION,
        kind: ModelKind::Goto,
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

impl ActionMap for GotoMap {
    fn kind(&self) -> ModelKind {
        ModelKind::Goto
    }

    fn n_joints(&self) -> usize {
        self.n_joints
    }

    fn latent_dim(&self) -> usize {
        ipc_types::ACTION_DIM
    }

    fn eval(&mut self, q: &[f64], _c: f64, _a: &[f64], out: &mut [f64]) {
        let n = self.n_joints.min(q.len()).min(out.len());
        let d = largest_error(&self.goal[..n], &q[..n]);
        self.arrived = d <= ARRIVED_RAD;
        // The fastest joint at `speed`, slowing linearly within SLOWDOWN_RAD; a non-finite
        // joint reading gives a non-finite command, which safety refuses.
        let scale = if self.arrived {
            0.0
        } else {
            self.speed * (d / SLOWDOWN_RAD).min(1.0) / d
        };
        for j in 0..n {
            out[j] = (self.goal[j] - q[j]) * scale;
        }
    }

    fn mode(&self) -> Option<MapMode> {
        Some(MapMode {
            index: u32::from(self.arrived),
            name: if self.arrived { "arrived" } else { "moving" },
            switches: 0,
        })
    }

    fn uses_input(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn robot() -> &'static RobotProfile {
        RobotProfile::default_robot()
    }

    #[test]
    fn named_poses_and_joint_vectors_parse_and_bad_specs_say_why() {
        let (h, m) = GotoMap::from_spec_for(robot(), "goto:pose=home").unwrap();
        assert_eq!(h.kind, ModelKind::Goto);
        assert_eq!(m.goal(), robot().named_pose("home").unwrap());
        assert_eq!(m.speed, DEFAULT_SPEED_RAD_S);
        let (_, m) = GotoMap::from_spec_for(robot(), "goto:q=0,0.1,0.2,0,0,0; speed=0.5").unwrap();
        assert_eq!(m.goal(), &[0.0, 0.1, 0.2, 0.0, 0.0, 0.0]);
        assert_eq!(m.speed, 0.5);
        for (spec, says) in [
            ("goto:", "needs a pose"),
            ("goto:pose=moon", "no pose `moon`"),
            ("goto:q=0,0,0", "has 3 joints"),
            ("goto:q=0,0,x,0,0,0", "`x` is not a number"),
            ("goto:q=0,99,0,0,0,0", "outside its limits"),
            ("goto:pose=home;speed=-1", "must be positive"),
            ("goto:pose=home;speed=50", "at most the slowest"),
            ("goto:pose=home;fast", "needs a pose"),
        ] {
            let e = GotoMap::from_spec_for(robot(), spec)
                .unwrap_err()
                .to_string();
            assert!(e.contains(says), "{spec}: {e}");
        }
    }

    #[test]
    fn it_arrives_in_closed_loop_and_then_commands_zero() {
        let (_, mut m) = GotoMap::from_spec_for(robot(), "goto:pose=home").unwrap();
        let mut q = [0.0; 6];
        let dt = 0.025;
        let mut out = [0.0; 6];
        let mut ticks = 0;
        while m.mode().unwrap().name != "arrived" {
            m.eval(&q, 0.0, &[0.0; 2], &mut out);
            for j in 0..6 {
                q[j] += out[j] * dt;
            }
            ticks += 1;
            assert!(ticks < 4000, "never arrived: {q:?}");
        }
        assert!(m.is_at(&q));
        m.eval(&q, 0.0, &[1.0, 1.0], &mut out);
        assert_eq!(out, [0.0; 6]);
    }

    proptest! {
        /// The command points at the goal (all joints together), never exceeds the speed on
        /// any joint, and is zero only at the goal.
        #[test]
        fn the_command_is_a_capped_step_towards_the_goal(
            q in proptest::collection::vec(-1.5f64..1.5, 6),
            speed in 0.05f64..1.0,
        ) {
            let goal = [0.3, -0.2, 0.5, 0.0, 0.4, -0.1];
            let mut m = GotoMap::new(&goal, speed, robot(), "t").unwrap();
            let mut out = [0.0; 6];
            m.eval(&q, 0.0, &[0.0; 2], &mut out);
            let d = largest_error(&goal, &q);
            let top = out.iter().map(|v| v.abs()).fold(0.0, f64::max);
            prop_assert!(top <= speed * (1.0 + 1e-12));
            if d > ARRIVED_RAD {
                prop_assert!(top > 0.0);
                for j in 0..6 {
                    // Parallel to the error, same sign.
                    prop_assert!((out[j] * d - (goal[j] - q[j]) * top).abs() < 1e-9);
                }
            } else {
                prop_assert_eq!(top, 0.0);
            }
        }
    }
}
