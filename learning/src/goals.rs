//! The goals of the Gen3 lite tasks in task space, beside their demonstration generators
//! ([`crate::tasks`]): what a person must get done for an attempt to count as a success, as
//! a sequence of subgoals with tolerances, and a tracker ([`GoalRun`]) that checks a run of
//! tool poses and gripper positions against them.
//!
//! The scenes are the centres of the generators' random ranges (the base frame, the table
//! the plane `z = 0`):
//!
//! * **pick-and-place**: the bottle at (0.525, −0.12), the target mark at (0.505, 0.16),
//!   grasped 7 cm above the table. In front of the bottle (10 cm back along the side
//!   approach the demonstrations use), to it, close the gripper, lift (6 cm), carry to above
//!   the mark, lower to the place point, open: seven subgoals.
//! * **table cleaning**: five objects on a round patch of table (the demonstrations' scrubbing
//!   circle, centre (0.38, 0), radius [`TABLE_RADIUS_M`]) at [`OBJECT_RING_M`] from its
//!   centre. An object is pushed when the tool passes through it at table height (below
//!   [`CONTACT_HEIGHT_M`]): it moves ahead of the tool; it is out when its centre leaves the
//!   patch, which is where the tool pushed it. Each object out is one subgoal.
//! * **pouring**: the cup at (0.525, −0.14), grasped 6 cm up; the bowl at (0.525, 0.10).
//!   Reach the cup, close the gripper, carry the cup over the bowl (5.5 cm short of its centre,
//!   17 cm up), tilt (roll the wrist about the approach axis) to the pouring angle, hold it
//!   there, return upright: six subgoals.
//!
//! A reach is done when the tool point is within the position tolerance; a grip when the
//! gripper is closed (`c >= 0.9`) or open (`c <= 0.1`) with the tool within the tolerance of
//! where it grips; the tilt, the hold and the return upright within twice the tolerance of the
//! pouring point. The tilt is the roll of the tool about its approach axis (tool z) from the
//! upright side grasp the generators use (tool x horizontal): 0 at the home pose.

use nalgebra::{Isometry3, UnitQuaternion, Vector2, Vector3, Vector6};

use crate::tasks::Task;

/// The gripper counts as closed at or above this (`c`, 0 open .. 1 closed).
pub const GRIP_CLOSED: f64 = 0.9;
/// The gripper counts as open at or below this.
pub const GRIP_OPEN: f64 = 0.1;
/// Table cleaning: the patch's centre (m, base frame; the demonstrations' scrubbing centre).
pub const TABLE_CENTRE: [f64; 2] = [0.38, 0.0];
/// Table cleaning: the patch's radius (m): about the demonstrations' largest scrubbing
/// circle (6 cm) plus an object's diameter.
pub const TABLE_RADIUS_M: f64 = 0.085;
/// Table cleaning: how far from the centre the objects lie (m).
pub const OBJECT_RING_M: f64 = 0.045;
/// Table cleaning: an object's radius (m): a 3 cm crumb, cap or sponge.
pub const OBJECT_RADIUS_M: f64 = 0.015;
/// Table cleaning: the radius of the tool as a pusher (m): the Gen3 lite's fingers.
pub const PUSHER_RADIUS_M: f64 = 0.02;
/// Table cleaning: the tool pushes objects when its point is below this height (m): the
/// objects are 8 cm tall (cans, cups, a sponge box). The tool point cannot scrub the table
/// itself under the default safety configuration: the whole-arm rule keeps the gripper's
/// capsules 2 cm off the table, which holds the tool point about 5.5 cm up.
pub const CONTACT_HEIGHT_M: f64 = 0.08;
/// Table cleaning: the height the operator pushes at (m).
pub const PUSH_HEIGHT_M: f64 = 0.065;

/// Tolerances of a task's goals (the study file's optional task keys).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// Position tolerance of reaches and grips (m).
    pub position_m: f64,
    /// Pouring: the tilt that pours (rad, either direction).
    pub pour_angle_rad: f64,
    /// Pouring: how long the tilt is held (s).
    pub hold_s: f64,
    /// Pouring: the tilt that counts as upright again (rad).
    pub upright_rad: f64,
}

impl Default for Tolerances {
    /// 3 cm (the clearance of the Gen3 lite's open fingers around a 6-7 cm bottle or cup,
    /// plus the depth of the fingers); a 90° tilt held 1 s (liquid leaves a cup once its rim
    /// is below its base; the demonstrations roll 95-120° and hold 0.15-0.25 of the pour);
    /// upright within 20°.
    fn default() -> Self {
        Self {
            position_m: 0.03,
            pour_angle_rad: 90f64.to_radians(),
            hold_s: 1.0,
            upright_rad: 20f64.to_radians(),
        }
    }
}

/// One subgoal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Subgoal {
    /// The tool point within the tolerance of `at`.
    Reach {
        /// Its name (`above the bottle`).
        name: &'static str,
        /// Where (m, base frame).
        at: Vector3<f64>,
    },
    /// The gripper closed (or open) with the tool within the tolerance of `at`.
    Grip {
        /// Its name.
        name: &'static str,
        /// Where the tool must be.
        at: Vector3<f64>,
        /// Close (else open).
        close: bool,
    },
    /// The tilt at least the pouring angle, held for the hold time, near `at`.
    Tilt {
        /// Its name.
        name: &'static str,
        /// Where the tool must stay (within twice the tolerance).
        at: Vector3<f64>,
        /// Hold it (else reaching the angle is enough).
        hold: bool,
    },
    /// The tilt back within the upright tolerance near `at`.
    Upright {
        /// Its name.
        name: &'static str,
        /// Where the tool must stay (within twice the tolerance).
        at: Vector3<f64>,
    },
    /// Table cleaning: object `index` pushed off the patch.
    PushOut {
        /// The object.
        index: usize,
    },
}

impl Subgoal {
    /// Its name.
    pub fn name(&self) -> String {
        match self {
            Self::Reach { name, .. }
            | Self::Grip { name, .. }
            | Self::Tilt { name, .. }
            | Self::Upright { name, .. } => (*name).to_owned(),
            Self::PushOut { index } => format!("object {} pushed out", index + 1),
        }
    }
}

/// A task's goals.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskGoals {
    /// The task.
    pub task: Task,
    /// The subgoals, in order.
    pub subgoals: Vec<Subgoal>,
    /// The tolerances.
    pub tol: Tolerances,
    /// Table cleaning: the objects' start positions (m, on the table); empty otherwise.
    pub objects: Vec<Vector2<f64>>,
    /// Table cleaning: the middle of the patch the objects are pushed off (m, on the table;
    /// [`TABLE_CENTRE`] on the Gen3 lite).
    pub table_centre: Vector2<f64>,
}

impl TaskGoals {
    /// The goals of `task` on `robot`'s arm: the Gen3 lite's scene ([`TaskGoals::of`]) moved
    /// out along x as the demonstrations' scenes are ([`crate::tasks::scene_shift_m`]: 15 cm
    /// on the Gen3). `None` for the planar reaches (no scene) or an arm whose home pose the
    /// kinematics refuse.
    pub fn on(task: Task, tol: Tolerances, robot: &kinematics::RobotProfile) -> Option<Self> {
        let mut g = Self::of(task, tol)?;
        let dx = crate::tasks::scene_shift_m(robot, task).ok()?;
        let shift3 = Vector3::x() * dx;
        let shift2 = Vector2::x() * dx;
        for s in &mut g.subgoals {
            match s {
                Subgoal::Reach { at, .. }
                | Subgoal::Grip { at, .. }
                | Subgoal::Tilt { at, .. }
                | Subgoal::Upright { at, .. } => *at += shift3,
                Subgoal::PushOut { .. } => {}
            }
        }
        for o in &mut g.objects {
            *o += shift2;
        }
        g.table_centre += shift2;
        Some(g)
    }

    /// The goals of `task` in the Gen3 lite's scene (none for the planar reaches: no scene).
    pub fn of(task: Task, tol: Tolerances) -> Option<Self> {
        let v = Vector3::<f64>::new;
        let mut objects = Vec::new();
        let subgoals = match task {
            Task::PickAndPlace => {
                let (bottle, mark, grasp_z, lift) =
                    (v(0.525, -0.12, 0.0), v(0.505, 0.16, 0.0), 0.07, 0.06);
                let up = |p: Vector3<f64>, z: f64| p + Vector3::z() * z;
                // The demonstrations approach from the side: 10 cm back along the approach
                // (heading to the bottle, pitched 10° down).
                let psi = bottle.y.atan2(bottle.x);
                let pitch = 10f64.to_radians();
                let approach = v(
                    psi.cos() * pitch.cos(),
                    psi.sin() * pitch.cos(),
                    -pitch.sin(),
                );
                vec![
                    Subgoal::Reach {
                        name: "in front of the bottle",
                        at: up(bottle, grasp_z) - approach * 0.10,
                    },
                    Subgoal::Reach {
                        name: "to the bottle",
                        at: up(bottle, grasp_z),
                    },
                    Subgoal::Grip {
                        name: "close on the bottle",
                        at: up(bottle, grasp_z),
                        close: true,
                    },
                    Subgoal::Reach {
                        name: "lift",
                        at: up(bottle, grasp_z + lift),
                    },
                    Subgoal::Reach {
                        name: "above the mark",
                        at: up(mark, grasp_z + lift),
                    },
                    Subgoal::Reach {
                        name: "lower onto the mark",
                        at: up(mark, grasp_z),
                    },
                    Subgoal::Grip {
                        name: "open on the mark",
                        at: up(mark, grasp_z),
                        close: false,
                    },
                ]
            }
            Task::Pouring => {
                let cup = v(0.525, -0.14, 0.06);
                let over = v(0.525, 0.10 - 0.055, 0.17);
                vec![
                    Subgoal::Reach {
                        name: "reach the cup",
                        at: cup,
                    },
                    Subgoal::Grip {
                        name: "grasp the cup",
                        at: cup,
                        close: true,
                    },
                    Subgoal::Reach {
                        name: "over the bowl",
                        at: over,
                    },
                    Subgoal::Tilt {
                        name: "tilt to pour",
                        at: over,
                        hold: false,
                    },
                    Subgoal::Tilt {
                        name: "hold the pour",
                        at: over,
                        hold: true,
                    },
                    Subgoal::Upright {
                        name: "return upright",
                        at: over,
                    },
                ]
            }
            Task::TableCleaning => {
                let c = Vector2::new(TABLE_CENTRE[0], TABLE_CENTRE[1]);
                objects = (0..5)
                    .map(|i| {
                        // Spread over the half of the patch facing away from the robot's
                        // base, so every object has a way out that does not cross the others.
                        let a = -1.2 + 0.6 * f64::from(i);
                        c + Vector2::new(a.cos(), a.sin()) * OBJECT_RING_M
                    })
                    .collect();
                (0..5).map(|index| Subgoal::PushOut { index }).collect()
            }
            Task::PlanarReach => return None,
        };
        Some(Self {
            task,
            subgoals,
            tol,
            objects,
            table_centre: Vector2::new(TABLE_CENTRE[0], TABLE_CENTRE[1]),
        })
    }
}

/// The tilt of a tool orientation: its roll about its approach axis (tool z) away from the
/// orientation with tool x horizontal (rad, in `(-π, π]`); 0 for a tool pointing straight up
/// or down (no horizontal reference).
pub fn tilt(r: &UnitQuaternion<f64>) -> f64 {
    let z = r * Vector3::z();
    let x = r * Vector3::x();
    let h = Vector3::z().cross(&z);
    let n = h.norm();
    if n < 1e-6 {
        return 0.0;
    }
    let h = h / n;
    h.cross(&x).dot(&z).atan2(h.dot(&x))
}

/// What the operator aims at now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aim {
    /// Where the tool point should go (m).
    pub position: Vector3<f64>,
    /// The tilt to reach (rad), if the subgoal is about the tilt.
    pub tilt: Option<f64>,
    /// Close (`Some(true)`) or open the gripper once within the tolerance.
    pub grip: Option<bool>,
    /// The tool should point down at the table (table cleaning, as the demonstrations
    /// scrub; the arm's links keep clear of the table that way).
    pub down: bool,
}

impl Aim {
    /// The pose error to close (position, then the rotation about the tool's approach axis
    /// for a tilt), for a scripted map that moves straight to the goal.
    pub fn error(&self, tool: &Isometry3<f64>) -> Vector6<f64> {
        let dp = self.position - tool.translation.vector;
        let z = tool.rotation * Vector3::z();
        let w = match self.tilt {
            Some(t) => z * (t - tilt(&tool.rotation)),
            None if self.down => {
                let axis = z.cross(&-Vector3::z());
                let angle = z.dot(&-Vector3::z()).clamp(-1.0, 1.0).acos();
                if axis.norm() > 1e-9 {
                    axis / axis.norm() * angle
                } else {
                    Vector3::zeros()
                }
            }
            None => Vector3::zeros(),
        };
        // Otherwise a side grasp: the approach turned towards the target, as the
        // demonstrations grasp (heading of the tool's z about the base's z).
        let w = if self.down || self.position.xy().norm() < 1e-6 || z.xy().norm() < 1e-6 {
            w
        } else {
            let want = self.position.y.atan2(self.position.x);
            let have = z.y.atan2(z.x);
            let d = (want - have + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            w + Vector3::z() * d
        };
        Vector6::new(dp.x, dp.y, dp.z, w.x, w.y, w.z)
    }
}

/// Table-cleaning phases of the object being pushed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Push {
    /// To the point behind the object, at the pushing height.
    Behind,
    /// Through it, out of the patch.
    Through,
}

/// One attempt's progress through a task's goals.
#[derive(Debug, Clone)]
pub struct GoalRun {
    goals: TaskGoals,
    next: usize,
    held_s: f64,
    objects: Vec<Vector2<f64>>,
    out: Vec<bool>,
    push: Push,
    last_xy: Option<Vector2<f64>>,
    roll_dir: Option<f64>,
}

impl GoalRun {
    /// The start of an attempt.
    pub fn new(goals: &TaskGoals) -> Self {
        Self {
            objects: goals.objects.clone(),
            out: vec![false; goals.objects.len()],
            goals: goals.clone(),
            next: 0,
            held_s: 0.0,
            push: Push::Behind,
            last_xy: None,
            roll_dir: None,
        }
    }

    /// Every subgoal is done.
    pub fn done(&self) -> bool {
        self.next >= self.goals.subgoals.len()
    }

    /// Subgoals done.
    pub fn subgoals_done(&self) -> usize {
        self.next.min(self.goals.subgoals.len())
    }

    /// The share of subgoals done (%).
    pub fn completion_pct(&self) -> f64 {
        100.0 * self.subgoals_done() as f64 / self.goals.subgoals.len().max(1) as f64
    }

    /// The subgoal under way (`None` once done).
    pub fn current(&self) -> Option<&Subgoal> {
        self.goals.subgoals.get(self.next)
    }

    /// Table cleaning: the objects' positions now.
    pub fn objects(&self) -> &[Vector2<f64>] {
        &self.objects
    }

    /// Takes one tick's tool pose and gripper position (`dt` s after the last) and moves on
    /// past every subgoal they complete.
    pub fn update(&mut self, tool: &Isometry3<f64>, gripper: f64, dt: f64) {
        let p = tool.translation.vector;
        self.push_objects(&p);
        let tol = self.goals.tol;
        while let Some(g) = self.goals.subgoals.get(self.next).copied() {
            let near = |at: &Vector3<f64>, k: f64| (p - at).norm() <= k * tol.position_m;
            let t = tilt(&tool.rotation);
            let ok = match g {
                Subgoal::Reach { at, .. } => near(&at, 1.0),
                Subgoal::Grip { at, close, .. } => {
                    near(&at, 1.0)
                        && if close {
                            gripper >= GRIP_CLOSED
                        } else {
                            gripper <= GRIP_OPEN
                        }
                }
                Subgoal::Tilt { at, hold, .. } => {
                    let tilted = near(&at, 2.0) && t.abs() >= tol.pour_angle_rad;
                    if !hold {
                        tilted
                    } else if tilted {
                        self.held_s += dt;
                        self.held_s >= tol.hold_s
                    } else {
                        self.held_s = 0.0;
                        false
                    }
                }
                Subgoal::Upright { at, .. } => near(&at, 2.0) && t.abs() <= tol.upright_rad,
                Subgoal::PushOut { index } => self.out.get(index).copied().unwrap_or(true),
            };
            if !ok {
                break;
            }
            self.next += 1;
            self.held_s = 0.0;
            self.push = Push::Behind;
        }
    }

    fn push_objects(&mut self, p: &Vector3<f64>) {
        let xy = Vector2::new(p.x, p.y);
        let last = self.last_xy.replace(xy);
        if self.objects.is_empty() || p.z > CONTACT_HEIGHT_M {
            return;
        }
        let centre = self.goals.table_centre;
        for (o, out) in self.objects.iter_mut().zip(&mut self.out) {
            if *out {
                continue;
            }
            // In contact: the gripper's fingers (a pusher of radius PUSHER_RADIUS_M) are
            // against it; moving towards it carries it along with the tool.
            let d = *o - xy;
            if d.norm() >= OBJECT_RADIUS_M + PUSHER_RADIUS_M {
                continue;
            }
            let Some(step) = last.map(|l| xy - l) else {
                continue;
            };
            if step.dot(&d) <= 0.0 {
                continue;
            }
            *o += step;
            if (*o - centre).norm() > TABLE_RADIUS_M {
                *out = true;
            }
        }
    }

    /// What the operator aims at, seeing the tool's pose `tool` (and, for table cleaning, the
    /// objects). `wrist_rad` is the last wrist joint's angle: a pour rolls the way that turns
    /// it back towards zero (as the demonstrations do), which a person sees as the way the
    /// wrist can still turn.
    pub fn aim(&mut self, tool: &Isometry3<f64>, wrist_rad: f64) -> Option<Aim> {
        let p = tool.translation.vector;
        let tol = self.goals.tol;
        let g = *self.goals.subgoals.get(self.next)?;
        let reach = |at: Vector3<f64>| Aim {
            position: at,
            tilt: None,
            grip: None,
            down: false,
        };
        Some(match g {
            Subgoal::Reach { at, .. } => reach(at),
            Subgoal::Grip { at, close, .. } => Aim {
                grip: Some(close),
                ..reach(at)
            },
            Subgoal::Tilt { at, .. } => {
                let dir = *self
                    .roll_dir
                    .get_or_insert(if wrist_rad > 0.0 { -1.0 } else { 1.0 });
                let target = (tol.pour_angle_rad + 10f64.to_radians()) * dir;
                Aim {
                    tilt: Some(target),
                    ..reach(at)
                }
            }
            Subgoal::Upright { at, .. } => Aim {
                tilt: Some(0.0),
                ..reach(at)
            },
            Subgoal::PushOut { index } => {
                let o = self.objects.get(index).copied()?;
                let centre = self.goals.table_centre;
                let out = o - centre;
                let dir = if out.norm() > 1e-9 {
                    out / out.norm()
                } else {
                    Vector2::x()
                };
                let behind = o - dir * (OBJECT_RADIUS_M + PUSHER_RADIUS_M + 0.01);
                let beyond = centre + dir * (TABLE_RADIUS_M + OBJECT_RADIUS_M + 0.03);
                let xy = Vector2::new(p.x, p.y);
                let at = |q: Vector2<f64>, z: f64| Vector3::new(q.x, q.y, z);
                let close = tol.position_m.min(0.015);
                // The tool behind the object, in line with the way out: push; else go round.
                let along = (xy - o).dot(&dir);
                let across = ((xy - o) - dir * along).norm();
                if self.push == Push::Through && (along > 0.0 || across > PUSHER_RADIUS_M) {
                    self.push = Push::Behind;
                }
                if self.push == Push::Behind
                    && (xy - behind).norm() <= close
                    && p.z <= CONTACT_HEIGHT_M
                {
                    self.push = Push::Through;
                }
                let position = match self.push {
                    Push::Behind => at(behind, PUSH_HEIGHT_M),
                    Push::Through => at(beyond, PUSH_HEIGHT_M),
                };
                Aim {
                    down: true,
                    ..reach(position)
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tilt_is_zero_at_home_and_follows_a_roll_about_the_approach_axis() {
        let g = kinematics::gen3_lite::Gen3Lite::get();
        let home = g.tcp(&kinematics::gen3_lite::HOME).expect("home");
        assert!(tilt(&home.rotation).abs() < 0.1, "{}", tilt(&home.rotation));
        let z = home.rotation * Vector3::z();
        for a in [-2.0, -0.5, 0.3, 1.6] {
            let r = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(z), a)
                * home.rotation;
            let d = tilt(&r) - tilt(&home.rotation);
            assert!((d - a).abs() < 1e-9, "{a}: {d}");
        }
    }

    #[test]
    fn a_pushed_object_moves_ahead_of_the_tool_and_leaves_the_patch() {
        let goals = TaskGoals::of(Task::TableCleaning, Tolerances::default()).expect("goals");
        let mut run = GoalRun::new(&goals);
        let o = goals.objects[2];
        let c = Vector2::new(TABLE_CENTRE[0], TABLE_CENTRE[1]);
        let dir = (o - c) / (o - c).norm();
        let r = UnitQuaternion::identity();
        // Above the table: nothing moves.
        let mut xy = o - dir * 0.03;
        for _ in 0..100 {
            xy += dir * 0.002;
            run.update(
                &Isometry3::from_parts(Vector3::new(xy.x, xy.y, 0.2).into(), r),
                0.0,
                0.025,
            );
        }
        assert_eq!(run.objects()[2], o);
        xy = o - dir * 0.03;
        for _ in 0..100 {
            xy += dir * 0.002;
            run.update(
                &Isometry3::from_parts(Vector3::new(xy.x, xy.y, 0.06).into(), r),
                0.0,
                0.025,
            );
        }
        assert!((run.objects()[2] - c).norm() > TABLE_RADIUS_M);
        assert_eq!(run.subgoals_done(), 0, "object 1 is still there");
        assert!(run.out[2]);
    }
}
