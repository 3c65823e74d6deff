//! The goals of the Gen3 lite tasks in task space, beside their demonstration generators
//! ([`crate::tasks`]): what a person must get done for an attempt to count as a success, as
//! a sequence of subgoals with tolerances, and a tracker ([`GoalRun`]) that checks a run of
//! tool poses and gripper positions against them.
//!
//! The scenes are the centres of the generators' random ranges (the base frame, the table
//! the plane `z = 0`):
//!
//! * **pick-and-place**: the bottle at (0.525, −0.12), the target mark at (0.505, 0.16),
//!   grasped 7 cm above the table. In front of the bottle (about 10 cm back along the side
//!   approach the demonstrations use, within [`APPROACH_RADIUS_M`]), to it, close the gripper,
//!   lift (the bottle at least [`LIFT_M`] off the table within [`NEAR_M`] of where it stood),
//!   carry it over the mark (within the tolerance across, still at least [`CLEAR_M`] above
//!   where it will stand), lower it onto the place point, open: seven subgoals.
//! * **table cleaning**: five objects on a round patch of table (the demonstrations' scrubbing
//!   circle, centre (0.38, 0), radius [`TABLE_RADIUS_M`]) at [`OBJECT_RING_M`] from its
//!   centre. An object is pushed when the tool passes through it at table height (below
//!   [`CONTACT_HEIGHT_M`]): it moves ahead of the tool; it is out when its centre leaves the
//!   patch, which is where the tool pushed it. Each object out is one subgoal.
//! * **pouring**: the cup at (0.525, −0.14), grasped 6 cm up; the bowl at (0.525, 0.10).
//!   Reach the cup, close the gripper, carry the cup over the bowl (5.5 cm short of its
//!   centre, 17 cm up), tilt (roll the wrist about the approach axis) to the pouring angle,
//!   hold it there, return upright: six subgoals. (An approach point in front of the cup,
//!   as pick-and-place has, made the scripted perfect map stall at the cup under the
//!   whole-arm clearance rule; it is not there until that is understood.)
//!
//! Each generated demonstration passes the goals of its own scene ([`Scene`], drawn by the
//! generator: `the_demonstrations_pass_their_own_goals` in `learning/tests/goals.rs`): a
//! demonstration is a success by definition, so a goal it does not pass asks for something
//! the task does not need. The subgoals are therefore stated by what the physical task
//! needs (a bottle clear of the table, over the mark), not as points the demonstrations'
//! carrying arcs need not pass through.
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
/// Grasping tasks: how far back along the side approach the point in front of the object
/// lies (m): the fingers, open, clear of a 6-7 cm bottle or cup before they come in.
pub const APPROACH_BACK_M: f64 = 0.10;
/// Grasping tasks: the side approach's pitch below the horizontal (degrees): the middle of
/// the demonstrations' 5-15°.
pub const APPROACH_PITCH_DEG: f64 = 10.0;
/// Grasping tasks: the radius of the point in front of the object (m). It is a waypoint,
/// not a contact: anywhere within 4 cm of it the open fingers are on the side of the
/// object facing the arm and at least 6 cm from its centre, so they come in from the side
/// without touching it. (The demonstrations' own pre-grasp points lie 8-12 cm back, with
/// the heading and pitch of the approach varied by ±0.15 rad and 5-15°: up to 2.9 cm from
/// the nominal point.)
pub const APPROACH_RADIUS_M: f64 = 0.04;
/// Pick-and-place: the bottle counts as lifted once the tool holding it is this much above
/// where it grasped (m): its base is then clear of the table, and it can be carried without
/// being dragged (a bottle dragged across a table tips over).
pub const LIFT_M: f64 = 0.03;
/// Pick-and-place: a lift counts only this close to where the bottle stood (m, across):
/// about a bottle's width, so it was raised, not dragged off its place first.
pub const NEAR_M: f64 = 0.06;
/// Pick-and-place: a bottle carried over the mark is still this much above where it will
/// stand (m): it arrives over the mark clear of the table, not pushed onto it from the side.
pub const CLEAR_M: f64 = 0.01;

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
    /// plus the depth of the fingers); a 90° tilt (liquid or beans leave a cup once its rim
    /// is below its base; the demonstrations roll 95-120°) held 0.8 s: a demonstration is a
    /// success by definition, and the shortest hold past 90° among 1000 generated pourings
    /// on each arm is 1.08 s on the Gen3 lite and 0.85 s on the Gen3 (whose shorter
    /// validation pourings hold 0.15-0.25 of a shorter pour; `pour_holds` in
    /// `learning/tests/goals.rs` prints the figures); upright within 20°.
    fn default() -> Self {
        Self {
            position_m: 0.03,
            pour_angle_rad: 90f64.to_radians(),
            hold_s: 0.8,
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
    /// A waypoint on the way to an object: the tool point within [`APPROACH_RADIUS_M`] of
    /// `at`.
    Approach {
        /// Its name (`in front of the bottle`).
        name: &'static str,
        /// Where (m, base frame).
        at: Vector3<f64>,
    },
    /// The tool point at least `rise_m` above `from` and within [`NEAR_M`] of it across (a
    /// grasped object raised off the table where it stood).
    Lift {
        /// Its name.
        name: &'static str,
        /// Where the object was grasped (m).
        from: Vector3<f64>,
        /// How far up (m).
        rise_m: f64,
    },
    /// The tool point within the position tolerance of `at` across and at least `clear_m`
    /// above it (a carried object over where it goes, still clear of the table).
    Over {
        /// Its name.
        name: &'static str,
        /// Where the object will be put down (m).
        at: Vector3<f64>,
        /// How far above it (m).
        clear_m: f64,
    },
}

impl Subgoal {
    /// Its name.
    pub fn name(&self) -> String {
        match self {
            Self::Reach { name, .. }
            | Self::Grip { name, .. }
            | Self::Tilt { name, .. }
            | Self::Upright { name, .. }
            | Self::Approach { name, .. }
            | Self::Lift { name, .. }
            | Self::Over { name, .. } => (*name).to_owned(),
            Self::PushOut { index } => format!("object {} pushed out", index + 1),
        }
    }

    /// Moves its place by `d` (a scene moved out on another arm).
    fn shift(&mut self, d: Vector3<f64>) {
        match self {
            Self::Reach { at, .. }
            | Self::Grip { at, .. }
            | Self::Tilt { at, .. }
            | Self::Upright { at, .. }
            | Self::Approach { at, .. }
            | Self::Over { at, .. } => *at += d,
            Self::Lift { from, .. } => *from += d,
            Self::PushOut { .. } => {}
        }
    }
}

/// Where a task's objects stand: what the goals are laid out around. The generator draws one
/// per demonstration ([`crate::tasks::generate_scenes_for`]); a study runs in
/// [`Scene::centre`], the middle of the generator's ranges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scene {
    /// Pick-and-place: the bottle and the mark it goes to (m, on the table), and the height
    /// it is grasped at (m).
    PickAndPlace {
        /// The bottle.
        bottle: Vector2<f64>,
        /// The target mark.
        mark: Vector2<f64>,
        /// The grasp height (m).
        grasp_z: f64,
    },
    /// Pouring: the cup and the bowl (m, on the table), and the height the cup is grasped at.
    Pouring {
        /// The cup.
        cup: Vector2<f64>,
        /// The bowl.
        bowl: Vector2<f64>,
        /// The grasp height (m).
        grasp_z: f64,
    },
    /// Table cleaning: the middle of the patch to clear (m, on the table).
    TableCleaning {
        /// The patch's centre.
        centre: Vector2<f64>,
    },
}

impl Scene {
    /// The scene of `task` on the Gen3 lite at the middle of the generator's ranges (none
    /// for the planar reaches).
    pub fn centre(task: Task) -> Option<Self> {
        let v = Vector2::new;
        Some(match task {
            Task::PickAndPlace => Self::PickAndPlace {
                bottle: v(0.525, -0.12),
                mark: v(0.505, 0.16),
                grasp_z: 0.07,
            },
            Task::Pouring => Self::Pouring {
                cup: v(0.525, -0.14),
                bowl: v(0.525, 0.10),
                grasp_z: 0.06,
            },
            Task::TableCleaning => Self::TableCleaning {
                centre: v(TABLE_CENTRE[0], TABLE_CENTRE[1]),
            },
            Task::PlanarReach => return None,
        })
    }

    /// Its task.
    pub fn task(&self) -> Task {
        match self {
            Self::PickAndPlace { .. } => Task::PickAndPlace,
            Self::Pouring { .. } => Task::Pouring,
            Self::TableCleaning { .. } => Task::TableCleaning,
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
        for s in &mut g.subgoals {
            s.shift(Vector3::x() * dx);
        }
        for o in &mut g.objects {
            *o += Vector2::x() * dx;
        }
        g.table_centre += Vector2::x() * dx;
        Some(g)
    }

    /// The goals of `task` in the Gen3 lite's scene (none for the planar reaches: no scene).
    pub fn of(task: Task, tol: Tolerances) -> Option<Self> {
        Scene::centre(task).map(|scene| Self::in_scene(&scene, tol))
    }

    /// The goals in `scene` (a demonstration's own: [`crate::tasks::generate_scenes_for`]; its
    /// positions already where the arm meets them).
    pub fn in_scene(scene: &Scene, tol: Tolerances) -> Self {
        let at = |p: Vector2<f64>, z: f64| Vector3::new(p.x, p.y, z);
        // The side approach the demonstrations use: heading to the object, pitched 10° down.
        let in_front = |p: Vector3<f64>| {
            let psi = p.y.atan2(p.x);
            let pitch = APPROACH_PITCH_DEG.to_radians();
            let approach = Vector3::new(
                psi.cos() * pitch.cos(),
                psi.sin() * pitch.cos(),
                -pitch.sin(),
            );
            p - approach * APPROACH_BACK_M
        };
        let mut objects = Vec::new();
        let mut table_centre = Vector2::new(TABLE_CENTRE[0], TABLE_CENTRE[1]);
        let subgoals = match *scene {
            Scene::PickAndPlace {
                bottle,
                mark,
                grasp_z,
            } => {
                let (grasp, place) = (at(bottle, grasp_z), at(mark, grasp_z));
                vec![
                    Subgoal::Approach {
                        name: "in front of the bottle",
                        at: in_front(grasp),
                    },
                    Subgoal::Reach {
                        name: "to the bottle",
                        at: grasp,
                    },
                    Subgoal::Grip {
                        name: "close on the bottle",
                        at: grasp,
                        close: true,
                    },
                    Subgoal::Lift {
                        name: "lift",
                        from: grasp,
                        rise_m: LIFT_M,
                    },
                    Subgoal::Over {
                        name: "over the mark",
                        at: place,
                        clear_m: CLEAR_M,
                    },
                    Subgoal::Reach {
                        name: "lower onto the mark",
                        at: place,
                    },
                    Subgoal::Grip {
                        name: "open on the mark",
                        at: place,
                        close: false,
                    },
                ]
            }
            Scene::Pouring { cup, bowl, grasp_z } => {
                let grasp = at(cup, grasp_z);
                // Beside the bowl's rim, high enough to pour.
                let over = at(bowl, 0.17) - Vector3::y() * 0.055;
                vec![
                    Subgoal::Reach {
                        name: "reach the cup",
                        at: grasp,
                    },
                    Subgoal::Grip {
                        name: "grasp the cup",
                        at: grasp,
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
            Scene::TableCleaning { centre } => {
                table_centre = centre;
                objects = (0..5)
                    .map(|i| {
                        // Spread over the half of the patch facing away from the robot's
                        // base, so every object has a way out that does not cross the others.
                        let a = -1.2 + 0.6 * f64::from(i);
                        centre + Vector2::new(a.cos(), a.sin()) * OBJECT_RING_M
                    })
                    .collect();
                (0..5).map(|index| Subgoal::PushOut { index }).collect()
            }
        };
        Self {
            task: scene.task(),
            subgoals,
            tol,
            objects,
            table_centre,
        }
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

/// The shape of the place a subgoal asks the tool point into.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Zone {
    /// A point: the operator closes the distance to it (the tracker's tolerance decides when
    /// it is reached).
    Point,
    /// Anywhere above `floor_m` and within `radius_m` across of the aim's position: the
    /// distance is to that region (0 inside).
    Column {
        /// How far across (m).
        radius_m: f64,
        /// The lowest height (m).
        floor_m: f64,
    },
}

impl Zone {
    /// The distance from `p` to the zone about `centre` (m).
    pub fn distance(&self, centre: &Vector3<f64>, p: &Vector3<f64>) -> f64 {
        match *self {
            Self::Point => (centre - p).norm(),
            Self::Column { radius_m, floor_m } => {
                let across = ((centre - p).xy().norm() - radius_m).max(0.0);
                let up = (floor_m - p.z).max(0.0);
                across.hypot(up)
            }
        }
    }
}

/// What the operator aims at now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aim {
    /// Where the tool point should go (m): the point, or for a zone the middle of its floor
    /// and 1 cm in.
    pub position: Vector3<f64>,
    /// The place around `position` that will do ([`Aim::distance`]).
    pub zone: Zone,
    /// The tilt to reach (rad), if the subgoal is about the tilt.
    pub tilt: Option<f64>,
    /// Close (`Some(true)`) or open the gripper once within the tolerance.
    pub grip: Option<bool>,
    /// The tool should point down at the table (table cleaning, as the demonstrations
    /// scrub; the arm's links keep clear of the table that way).
    pub down: bool,
    /// The fingers should face the object, as for a side grasp ([`Aim::facing_error`]): on
    /// the way to an object and at it.
    pub face: bool,
}

impl Aim {
    /// How far the tool point `p` is from what the aim asks for (m): the distance to the
    /// point, or to the zone.
    pub fn distance(&self, p: &Vector3<f64>) -> f64 {
        self.zone.distance(&self.position, p)
    }

    /// How far the tool's approach axis (tool z) is turned from facing the aim's position
    /// for a side grasp (rad): the heading from the base to the position, pitched
    /// [`APPROACH_PITCH_DEG`] down, as the demonstrations grasp. 0 when the aim does not ask
    /// to face ([`Aim::face`]). A bottle or cup is grasped from the side with the fingers
    /// level and facing it; pitched further down, the fingers meet the table first.
    pub fn facing_error(&self, r: &UnitQuaternion<f64>) -> f64 {
        if !self.face || self.position.xy().norm() < 1e-6 {
            return 0.0;
        }
        let psi = self.position.y.atan2(self.position.x);
        let pitch = APPROACH_PITCH_DEG.to_radians();
        let want = Vector3::new(
            psi.cos() * pitch.cos(),
            psi.sin() * pitch.cos(),
            -pitch.sin(),
        );
        (r * Vector3::z()).dot(&want).clamp(-1.0, 1.0).acos()
    }

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
                Subgoal::Approach { at, .. } => (p - at).norm() <= APPROACH_RADIUS_M,
                Subgoal::Lift { from, rise_m, .. } => {
                    Zone::Column {
                        radius_m: NEAR_M,
                        floor_m: from.z + rise_m,
                    }
                    .distance(&from, &p)
                        <= 0.0
                }
                Subgoal::Over { at, clear_m, .. } => {
                    Zone::Column {
                        radius_m: tol.position_m,
                        floor_m: at.z + clear_m,
                    }
                    .distance(&at, &p)
                        <= 0.0
                }
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
            zone: Zone::Point,
            tilt: None,
            grip: None,
            down: false,
            face: false,
        };
        let facing = |at: Vector3<f64>| Aim {
            face: true,
            ..reach(at)
        };
        // A column's aim point: its axis, 1 cm above its floor.
        let column = |at: Vector3<f64>, radius_m: f64, floor_m: f64| Aim {
            position: Vector3::new(at.x, at.y, floor_m + 0.01),
            zone: Zone::Column { radius_m, floor_m },
            ..reach(at)
        };
        Some(match g {
            Subgoal::Approach { at, .. } => facing(at),
            // Reaching an object to grasp it: face it.
            Subgoal::Reach { at, .. }
                if matches!(
                    self.goals.subgoals.get(self.next + 1),
                    Some(Subgoal::Grip { close: true, .. })
                ) =>
            {
                facing(at)
            }
            Subgoal::Reach { at, .. } => reach(at),
            Subgoal::Lift { from, rise_m, .. } => column(from, NEAR_M, from.z + rise_m),
            Subgoal::Over { at, clear_m, .. } => column(at, tol.position_m, at.z + clear_m),
            Subgoal::Grip { at, close, .. } => Aim {
                grip: Some(close),
                face: close,
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

/// A recorded or generated run through `goals`: each tuple's tool pose (the forward kinematics
/// of `robot`'s arm at its joint angles) and gripper, a period of `dt` s apart. The tracker
/// as the run left it, and the tuples it took to finish (`None` if it did not).
pub fn track(
    goals: &TaskGoals,
    robot: &kinematics::RobotProfile,
    traj: &crate::dataset::Trajectory,
    dt: f64,
) -> Result<(GoalRun, Option<usize>), kinematics::KinError> {
    let mut run = GoalRun::new(goals);
    for (k, (q, c)) in traj.q.iter().zip(&traj.c).enumerate() {
        let tool = robot.arm().fk(q)?;
        run.update(&tool, *c, dt);
        if run.done() {
            return Ok((run, Some(k + 1)));
        }
    }
    Ok((run, None))
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
