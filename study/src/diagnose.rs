//! Why a simulated attempt failed: what the tracker and the operator saw each tick
//! ([`TickNote`], the `/scl/sim/operator` channel of a recorded attempt) and, at the end of
//! an attempt, the subgoal it reached, how close it came to the next one and what was in the
//! way there ([`Diagnosis`]): the safety rules that acted, the joints at their limits, and the
//! tool directions the map offers at the closest point against the direction to the subgoal.

use std::collections::BTreeMap;

use ipc_types::{RobotState, safe_flags};
use kinematics::{Jacobian, RobotProfile};
use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// A joint this close to a position limit (rad) counts as at its limit: 3°.
pub const AT_LIMIT_RAD: f64 = 0.052_359_877_559_829_89;

/// What the goal tracker and the operator saw at one tick of a simulated attempt.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TickNote {
    /// The attempt's tick (from 0).
    pub tick: u64,
    /// The robot state's time (ns).
    pub t_ns: u64,
    /// Subgoals done so far.
    pub subgoals_done: usize,
    /// The subgoal under way (`None` once every one is done).
    pub subgoal: Option<String>,
    /// How far the tool point is from what the subgoal asks for (m).
    pub distance_m: Option<f64>,
    /// Where the operator aims the tool point (m, base frame).
    pub aim: Option<[f64; 3]>,
    /// How far the tool's approach axis is turned from facing the aim, for a side grasp (rad).
    pub facing_error_rad: Option<f64>,
    /// The tool point (m, base frame).
    pub tool: [f64; 3],
    /// The map's mode as the screen shows it.
    pub mode: Option<usize>,
}

/// Why an attempt ended where it did: the subgoal reached, the closest the tool came to the
/// next one, and what was in the way there.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    /// Subgoals done.
    pub subgoals_done: usize,
    /// The last subgoal done (`None`: not even the first).
    pub reached: Option<String>,
    /// The subgoal not reached (`None`: all were).
    pub next: Option<String>,
    /// The closest the tool point came to the next subgoal (m).
    pub closest_m: Option<f64>,
    /// When (s from the attempt's start).
    pub closest_at_s: Option<f64>,
    /// Ticks each safety rule acted in the attempt (the [`safe_flags::NAMES`] of the safety
    /// commands' flags), rules that never acted left out.
    pub safety_ticks: BTreeMap<String, u64>,
    /// Joints (1-based) within [`AT_LIMIT_RAD`] of a position limit at the closest point.
    pub joints_at_limit: Vec<usize>,
    /// At the closest point, the angle (degrees) between the direction to the subgoal and the
    /// tool velocities the map gives for the stick's two axes there (in the mode shown): 0 when
    /// some stick deflection moves the tool straight towards it, 90 when none moves it any
    /// closer.
    pub off_map_deg: Option<f64>,
    /// At the closest point, the fastest the tool point moves towards the subgoal at full
    /// stick (m/s; 0: no deflection moves it any closer).
    pub towards_m_s: Option<f64>,
}

impl Diagnosis {
    /// The safety rules that acted, most ticks first: `position 120, accel 8`.
    pub fn safety_summary(&self) -> String {
        let mut v: Vec<(&String, &u64)> = self.safety_ticks.iter().collect();
        v.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
        v.iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The diagnosis file's name in a simulated participant's directory: one [`DiagnosisRow`]
/// per attempt, beside `trials.csv` (which keeps its columns).
pub const DIAGNOSIS: &str = "diagnosis.csv";

/// One attempt's [`Diagnosis`]: a row of [`DIAGNOSIS`], matched to its `trials.csv` row by
/// participant, task, label and attempt.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosisRow {
    /// `P03`.
    pub participant: String,
    /// The task.
    pub task: String,
    /// The condition's blind label.
    pub label: String,
    /// The condition's name.
    pub condition: String,
    /// 1-based attempt.
    pub attempt: u32,
    /// Success or timeout.
    pub outcome: crate::data::Outcome,
    /// Subgoals done.
    pub subgoals_done: usize,
    /// The last subgoal done (empty: none).
    pub reached: String,
    /// The subgoal not reached (empty: none).
    pub next: String,
    /// The closest the tool came to it (m; empty: not known).
    pub closest_m: Option<f64>,
    /// When (s).
    pub closest_at_s: Option<f64>,
    /// Ticks each safety rule acted: `position 120, accel 8`.
    pub safety: String,
    /// Joints at a limit at the closest point, 1-based, space-separated.
    pub joints_at_limit: String,
    /// [`Diagnosis::off_map_deg`].
    pub off_map_deg: Option<f64>,
    /// [`Diagnosis::towards_m_s`].
    pub towards_m_s: Option<f64>,
    /// The attempt's recording (`--record`; empty: none).
    pub recording: String,
}

impl DiagnosisRow {
    /// The row of `d` for trial `row`.
    pub fn of(row: &crate::data::TrialRow, d: &Diagnosis) -> Self {
        Self {
            participant: row.participant.clone(),
            task: row.task.clone(),
            label: row.label.clone(),
            condition: row.condition.clone(),
            attempt: row.attempt,
            outcome: row.outcome,
            subgoals_done: d.subgoals_done,
            reached: d.reached.clone().unwrap_or_default(),
            next: d.next.clone().unwrap_or_default(),
            closest_m: d.closest_m,
            closest_at_s: d.closest_at_s,
            safety: d.safety_summary(),
            joints_at_limit: d
                .joints_at_limit
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(" "),
            off_map_deg: d.off_map_deg,
            towards_m_s: d.towards_m_s,
            recording: row.recording.clone(),
        }
    }
}

/// Where the tool came closest to the subgoal under way.
#[derive(Debug, Clone)]
struct Closest {
    distance_m: f64,
    tick: u64,
    q: Vec<f64>,
    gripper: f64,
    mode: usize,
    /// Unit direction from the tool point to the aim.
    dir: Option<Vector3<f64>>,
}

/// Collects a [`Diagnosis`] tick by tick.
#[derive(Debug, Clone, Default)]
pub struct Diagnoser {
    counts: [u64; safe_flags::COUNT],
    subgoal: usize,
    closest: Option<Closest>,
    last: Option<String>,
    current: Option<String>,
    done: usize,
}

impl Diagnoser {
    /// Takes one tick: its note, the robot state and the safety command's flags.
    pub fn tick(&mut self, note: &TickNote, state: &RobotState, safety_flags: u32) {
        for (i, c) in self.counts.iter_mut().enumerate() {
            if safety_flags & (1 << i) != 0 {
                *c += 1;
            }
        }
        self.note(note, state);
    }

    /// Takes what the tracker says at a state (also the last one, which is not stepped).
    pub fn note(&mut self, note: &TickNote, state: &RobotState) {
        if note.subgoals_done != self.subgoal {
            self.subgoal = note.subgoals_done;
            self.closest = None;
            self.last = self.current.take();
        }
        if note.subgoal.is_some() {
            self.current.clone_from(&note.subgoal);
        }
        self.done = note.subgoals_done;
        let Some(d) = note.distance_m else {
            return;
        };
        if self.closest.as_ref().is_some_and(|c| c.distance_m <= d) {
            return;
        }
        let tool = Vector3::from(note.tool);
        let dir = note.aim.and_then(|a| {
            let v = Vector3::from(a) - tool;
            (v.norm() > 1e-9).then(|| v / v.norm())
        });
        self.closest = Some(Closest {
            distance_m: d,
            tick: note.tick,
            q: state.q().to_vec(),
            gripper: state.gripper,
            mode: note.mode.unwrap_or(0),
            dir,
        });
    }

    /// The diagnosis; with `map` (a fresh copy of the served model) the map's tool directions
    /// at the closest point.
    pub fn finish(
        self,
        robot: &RobotProfile,
        dt: f64,
        map: Option<mapper::LoadedModel>,
    ) -> Diagnosis {
        let safety_ticks = self
            .counts
            .iter()
            .enumerate()
            .filter(|(_, n)| **n > 0)
            .map(|(i, n)| (safe_flags::NAMES[i].to_owned(), *n))
            .collect();
        let mut d = Diagnosis {
            subgoals_done: self.done,
            reached: self.last,
            next: if self.current.is_some() && self.closest.is_some() {
                self.current
            } else {
                None
            },
            safety_ticks,
            ..Diagnosis::default()
        };
        let Some(c) = self.closest else {
            return d;
        };
        d.closest_m = Some(c.distance_m);
        d.closest_at_s = Some(c.tick as f64 * dt);
        let limits = robot.limits();
        d.joints_at_limit =
            c.q.iter()
                .enumerate()
                .filter(|&(i, v)| {
                    let lo = limits
                        .lower_rad
                        .get(i)
                        .copied()
                        .unwrap_or(f64::NEG_INFINITY);
                    let hi = limits.upper_rad.get(i).copied().unwrap_or(f64::INFINITY);
                    v - lo < AT_LIMIT_RAD || hi - v < AT_LIMIT_RAD
                })
                .map(|(i, _)| i + 1)
                .collect();
        if let (Some(m), Some(dir)) = (map, c.dir)
            && let Some((angle, speed)) = map_towards(robot, m, &c, &dir)
        {
            d.off_map_deg = Some(angle);
            d.towards_m_s = Some(speed);
        }
        d
    }
}

/// The angle (degrees) between `dir` and the plane of the tool velocities the map `m` gives at
/// `c` for the stick's two axes (in the mode shown there), and the fastest speed towards
/// `dir` at full stick (m/s). `None` if the map cannot be evaluated there.
fn map_towards(
    robot: &RobotProfile,
    mut m: mapper::LoadedModel,
    c: &Closest,
    dir: &Vector3<f64>,
) -> Option<(f64, f64)> {
    let n = robot.n_joints();
    if m.header.n_joints != n || c.q.len() < n {
        return None;
    }
    for _ in 0..c.mode {
        m.map.press(ipc_types::buttons::MODE);
    }
    let mut jac = Jacobian::zeros(n);
    robot.arm().fk_jacobian(&c.q[..n], &mut jac).ok()?;
    let mut q = c.q[..n].to_vec();
    robot.wrap_for_maps(&mut q);
    let s = m.header.speed_scale_rad_s;
    let mut v = [Vector3::zeros(); 2];
    for (j, vj) in v.iter_mut().enumerate() {
        let mut a = [0.0; ipc_types::ACTION_DIM];
        a[j] = 1.0;
        let mut qdot = vec![0.0; n];
        m.map.eval(&q, c.gripper, &a, &mut qdot);
        let qdot = nalgebra::DVector::from_iterator(n, qdot.iter().map(|x| x * s));
        let lin = jac.matrix().rows(0, 3) * qdot;
        *vj = Vector3::new(lin[0], lin[1], lin[2]);
    }
    if !v.iter().all(|x| x.iter().all(|e| e.is_finite())) {
        return None;
    }
    // The fastest along `dir` over the unit disc of the stick: |(v1·d, v2·d)|.
    let towards = Vector2::new(v[0].dot(dir), v[1].dot(dir)).norm();
    // The angle between `dir` and the span of v1, v2 (Gram-Schmidt).
    let mut basis: Vec<Vector3<f64>> = Vec::new();
    for x in v {
        let r = basis.iter().fold(x, |r, b| r - b * b.dot(&r));
        if r.norm() > 1e-9 {
            basis.push(r / r.norm());
        }
    }
    if basis.is_empty() {
        return Some((90.0, 0.0));
    }
    let proj: Vector3<f64> = basis.iter().map(|b| b * b.dot(dir)).sum();
    let cos = proj.norm().clamp(0.0, 1.0);
    Some((cos.acos().to_degrees(), towards))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn note(tick: u64, done: usize, d: f64, tool: [f64; 3]) -> TickNote {
        TickNote {
            tick,
            t_ns: tick,
            subgoals_done: done,
            subgoal: Some(format!("goal {done}")),
            distance_m: Some(d),
            aim: Some([0.5, 0.0, 0.2]),
            facing_error_rad: None,
            tool,
            mode: None,
        }
    }

    /// The closest point is the one to the subgoal still under way at the end; rules are
    /// counted per tick; the reached subgoal is the last one done.
    #[test]
    fn the_diagnosis_names_the_subgoal_reached_and_the_closest_to_the_next() {
        let robot = RobotProfile::default_robot();
        let q = robot.named_pose("home").unwrap();
        let mut st = RobotState::at_rest(0, 0, robot.n_joints() as u32);
        st.q_rad[..q.len()].copy_from_slice(q);
        let mut dg = Diagnoser::default();
        dg.tick(
            &note(0, 0, 0.01, [0.49, 0.0, 0.2]),
            &st,
            safe_flags::ACCEL_LIMITED,
        );
        dg.tick(&note(1, 1, 0.30, [0.49, 0.0, 0.2]), &st, 0);
        dg.tick(
            &note(2, 1, 0.10, [0.4, 0.0, 0.2]),
            &st,
            safe_flags::ACCEL_LIMITED | safe_flags::POSITION_LIMITED,
        );
        dg.tick(&note(3, 1, 0.20, [0.3, 0.0, 0.2]), &st, 0);
        let map = mapper::LoadedModel::load_for("modeswitch", robot).ok();
        let d = dg.finish(robot, 0.5, map);
        assert_eq!(d.subgoals_done, 1);
        assert_eq!(d.reached.as_deref(), Some("goal 0"));
        assert_eq!(d.next.as_deref(), Some("goal 1"));
        assert_eq!(d.closest_m, Some(0.10));
        assert_eq!(d.closest_at_s, Some(1.0));
        let name = |bit: u32| safe_flags::NAMES[bit.trailing_zeros() as usize];
        let (accel, position) = (
            name(safe_flags::ACCEL_LIMITED),
            name(safe_flags::POSITION_LIMITED),
        );
        assert_eq!(d.safety_ticks[accel], 2);
        assert_eq!(d.safety_ticks[position], 1);
        assert_eq!(d.safety_summary(), format!("{accel} 2, {position} 1"));
        // Mode switching's first mode moves the tool in x and y: straight towards +x.
        let a = d.off_map_deg.unwrap();
        assert!(a < 1.0, "{a}");
        assert!(d.towards_m_s.unwrap() > 0.0, "{d:?}");
    }

    /// A direction the map's mode cannot move the tool in is 90° off.
    #[test]
    fn a_direction_the_mode_cannot_move_in_is_off_the_map() {
        let robot = RobotProfile::default_robot();
        let q = robot.named_pose("home").unwrap().to_vec();
        let c = Closest {
            distance_m: 0.1,
            tick: 0,
            q,
            gripper: 0.0,
            mode: 0,
            dir: None,
        };
        let m = mapper::LoadedModel::load_for("modeswitch", robot).unwrap();
        let (angle, towards) = map_towards(robot, m, &c, &Vector3::z()).unwrap();
        assert!(angle > 89.0, "{angle}");
        assert!(towards < 1e-3, "{towards}");
    }
}
