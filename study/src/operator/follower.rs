//! The demonstration-following operator (`operator = "follower"`): what the map allows along
//! the route its demonstrations took, with a person's hand. Where the expert plans its own
//! way to the next subgoal, the follower only reproduces a demonstration, as a person
//! follows a route: by where the gripper is and how it is turned. Each tick it finds where
//! along the demonstration the tool is (the nearest tool pose with the same gripper state,
//! never back along it), and picks the stick whose tool twist through the served map
//! (`J(q) s map(q, c, a)`) comes closest to the demonstration's own motion from there (to
//! where the demonstration's tool is [`FOLLOW_AHEAD_S`] later) plus a slow pull back onto
//! it, turning weighed against moving by the operator's metres per radian. It never passes a
//! grasp or a release of the demonstration before its own gripper has done the same, and it
//! closes or opens the gripper as the other operators do, within the tolerance of a grip
//! subgoal. When the arm stands still under a pushed stick for [`UNANSWERED_S`] (safety
//! holds it after a stop until the stick is at rest), it lets go for a moment.
//!
//! So a report can tell the map's limit from the planner's: a map the follower drives along
//! its demonstrations to their end can do what they did; where the expert then fails from
//! the study's start, the planner is in the way.
//!
//! It acts through the same hand as the other operators (reaction delay, stick rate, noise)
//! and the graph's safety filter acts on what it commands.

use std::sync::Arc;

use ipc_types::{JoystickInput, MAX_JOINTS, buttons};
use kinematics::{KinError, RobotProfile};
use learning::dataset::Trajectory;
use learning::goals::Tolerances;
use mapper::rng::Rng;
use nalgebra::{Isometry3, Vector3, Vector6};

use super::greedy::Probes;
use super::{Hand, Operate, Seen};
use crate::setup::SimParams;

/// How far ahead along the demonstration the follower aims (s): the motion it reproduces.
pub const FOLLOW_AHEAD_S: f64 = 0.25;

/// How fast it steers back towards the demonstration where the map lets it (s: the time
/// constant of the correction added to the demonstration's own motion).
const CORRECT_S: f64 = 1.0;

/// How far along its path it looks for where the tool is now (s): it never jumps further
/// than this, nor back.
const SEARCH_S: f64 = 2.0;

/// How long the arm may stand still under a pushed stick before the follower lets go of it
/// (s): safety holds the arm after a stop until the stick is at rest, and a person told so
/// lets go when the arm does not answer.
pub const UNANSWERED_S: f64 = 0.5;

/// How long it then leaves the stick at rest (s).
pub const LET_GO_S: f64 = 0.3;

/// How close (m, turning counted at the operator's metres per radian) the tool must be to
/// where along the demonstration it is for the follower to go on at the demonstration's own
/// pace where the tool alone would not carry it on (a slow start, a hold).
pub const KEEP_UP_M: f64 = 0.02;

/// One tick of a demonstration.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoPoint {
    /// The joint angles (rad).
    pub q: Vec<f64>,
    /// The gripper (0 open .. 1 closed).
    pub c: f64,
    /// The tool's pose there.
    pub tool: Isometry3<f64>,
}

/// A demonstration as the follower remembers it.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoPath {
    /// Its name (the trajectory's file name).
    pub name: String,
    /// Each tick.
    pub points: Vec<DemoPoint>,
}

impl DemoPath {
    /// The path of `traj` on `robot`'s arm (with the forward kinematics of each tuple).
    pub fn of(robot: &RobotProfile, traj: &Trajectory) -> Result<Self, KinError> {
        let points = traj
            .q
            .iter()
            .zip(&traj.c)
            .map(|(q, c)| {
                robot.arm().fk(q).map(|tool| DemoPoint {
                    q: q.clone(),
                    c: *c,
                    tool,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            name: traj.name.clone(),
            points,
        })
    }

    /// Ticks on the path.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// It has no ticks.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The tick among `lo..hi` whose joint angles are nearest `q` (squared distance) with
    /// the gripper `c`'s state (open or closed); `None` if no tick there has it.
    pub fn nearest(&self, q: &[f64], c: f64, lo: usize, hi: usize) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        for (i, x) in self.points.iter().enumerate().take(hi).skip(lo) {
            if (x.c - c).abs() >= 0.5 {
                continue;
            }
            let d: f64 = x.q.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((i, d));
            }
        }
        best
    }

    /// The tick among `lo..hi` whose tool pose is nearest `tool` (the distance plus
    /// `m_per_rad` times the angle between the two orientations) with the gripper `c`'s
    /// state (open or closed); `None` if no tick there has it.
    pub fn nearest_pose(
        &self,
        tool: &Isometry3<f64>,
        c: f64,
        m_per_rad: f64,
        lo: usize,
        hi: usize,
    ) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        for (i, x) in self.points.iter().enumerate().take(hi).skip(lo) {
            if (x.c - c).abs() >= 0.5 {
                continue;
            }
            let d = pose_distance(&x.tool, tool, m_per_rad);
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((i, d));
            }
        }
        best
    }

    /// The tick `ticks` after `i`, but not past the path's end nor past a change of the
    /// gripper from `c`'s state.
    pub fn ahead(&self, i: usize, c: f64, ticks: usize) -> usize {
        let mut j = i;
        while j + 1 < self.len() && j < i + ticks {
            if (self.points[j + 1].c - c).abs() >= 0.5 {
                break;
            }
            j += 1;
        }
        j
    }
}

/// How far apart two tool poses are for the follower (m): the distance between them plus
/// `m_per_rad` times the angle between their orientations.
pub fn pose_distance(a: &Isometry3<f64>, b: &Isometry3<f64>, m_per_rad: f64) -> f64 {
    (a.translation.vector - b.translation.vector).norm()
        + m_per_rad * a.rotation.angle_to(&b.rotation)
}

/// [`FOLLOW_AHEAD_S`] in ticks of `dt` seconds (at least one).
pub fn ahead_ticks(dt: f64) -> usize {
    ((FOLLOW_AHEAD_S / dt).round() as usize).max(1)
}

/// The nearest tick of all of `paths` (numbered) to `q` with the gripper `c`'s state:
/// (path, tick).
pub fn nearest_of<'a>(
    paths: impl Iterator<Item = (usize, &'a DemoPath)>,
    q: &[f64],
    c: f64,
) -> Option<(usize, usize)> {
    paths
        .filter_map(|(pi, p)| p.nearest(q, c, 0, p.len()).map(|(i, d)| (pi, i, d)))
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(pi, i, _)| (pi, i))
}

/// How far a follower got along its demonstration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Followed {
    /// The demonstration (index into the paths it was given).
    pub path: usize,
    /// The furthest tick of the path it was at (0-based).
    pub furthest: usize,
    /// The path's ticks.
    pub len: usize,
    /// The tool came within the position tolerance of the path's end.
    pub reached_end: bool,
    /// The closest the tool came to the path's end (m).
    pub closest_to_end_m: f64,
}

/// The follower of one attempt.
pub(crate) struct Follower<'a> {
    params: SimParams,
    tol: Tolerances,
    dt: f64,
    probes: Probes<'a>,
    hand: Hand,
    paths: Arc<Vec<DemoPath>>,
    /// Only this path (a demonstration's own start and scene); else the nearest.
    only: Option<usize>,
    /// The path followed and where along it the tool is.
    at: Option<(usize, usize)>,
    ahead: usize,
    search: usize,
    cands: Vec<[f64; 2]>,
    out: [f64; MAX_JOINTS],
    chosen: [f64; 2],
    followed: Option<Followed>,
    /// Ticks the arm has stood still under a pushed stick.
    unanswered: u32,
    /// Ticks left with the stick let go.
    let_go: u32,
}

impl<'a> Follower<'a> {
    /// A follower of the nearest of `paths` (of `only`, if given).
    pub(crate) fn new(
        params: &SimParams,
        tol: Tolerances,
        dt: f64,
        probes: Probes<'a>,
        paths: Arc<Vec<DemoPath>>,
        only: Option<usize>,
    ) -> Self {
        Self {
            params: params.clone(),
            tol,
            dt,
            probes,
            hand: Hand::new(params, dt),
            paths,
            only,
            at: None,
            ahead: ahead_ticks(dt),
            search: ((SEARCH_S / dt).round() as usize).max(1),
            cands: Vec::with_capacity(params.candidates + 4),
            out: [0.0; MAX_JOINTS],
            chosen: [0.0; 2],
            followed: None,
            unanswered: 0,
            let_go: 0,
        }
    }

    /// Where along the paths the tool is: at first the nearest joint angles with the same
    /// gripper state (open or closed) of all paths (the attempt starts on one); then the
    /// nearest tool pose on the path followed, from where it was, no further than the search
    /// window, or a tick on if the tool keeps up ([`KEEP_UP_M`]). A person follows a route by
    /// where the gripper is and how it is turned, not by the joint angles.
    fn locate(&mut self, q: &[f64], tool: &Isometry3<f64>, c: f64) -> Option<(usize, usize)> {
        let w = self.params.tilt_weight_m_per_rad;
        let best = match self.at {
            Some((pi, i)) => {
                let path = self.paths.get(pi)?;
                let near = path
                    .nearest_pose(tool, c, w, i, (i + self.search).min(path.len()))
                    .map_or(i, |(k, _)| k);
                // The demonstration's own pace where it is slow or holds still (a start from
                // rest, a held tilt): a tick on while the tool keeps up with it.
                let clock = match path.points.get(i) {
                    Some(x) if pose_distance(&x.tool, tool, w) <= KEEP_UP_M => path.ahead(i, c, 1),
                    _ => i,
                };
                Some((pi, near.max(clock)))
            }
            None => {
                let only = self.only;
                nearest_of(
                    self.paths
                        .iter()
                        .enumerate()
                        .filter(|(pi, _)| only.is_none_or(|o| o == *pi)),
                    q,
                    c,
                )
            }
        };
        best.or(self.at)
    }

    /// The point the follower aims at from tick `i` of path `pi`: [`FOLLOW_AHEAD_S`] ahead,
    /// but not past a change of the gripper it has not made yet.
    fn target(&self, pi: usize, i: usize, c: f64) -> Option<&DemoPoint> {
        let path = self.paths.get(pi)?;
        path.points.get(path.ahead(i, c, self.ahead))
    }

    fn note(&mut self, pi: usize, i: usize, p: &Vector3<f64>) {
        let Some(path) = self.paths.get(pi) else {
            return;
        };
        let Some(end) = path.points.last() else {
            return;
        };
        let d = (end.tool.translation.vector - p).norm();
        let f = self.followed.get_or_insert(Followed {
            path: pi,
            furthest: i,
            len: path.len(),
            reached_end: false,
            closest_to_end_m: d,
        });
        f.furthest = f.furthest.max(i);
        f.closest_to_end_m = f.closest_to_end_m.min(d);
        f.reached_end |= d <= self.tol.position_m && i + self.ahead >= path.len();
    }

    /// The tool twist (linear m/s, angular rad/s, in the base frame) the follower wants: the
    /// demonstration's own motion from `here` to `target` in [`FOLLOW_AHEAD_S`], from where
    /// the tool is, and a slow pull back onto the demonstration (time constant
    /// [`CORRECT_S`]), as far as the map's two directions allow.
    fn wanted(
        &self,
        tool: &Isometry3<f64>,
        here: &Isometry3<f64>,
        target: &Isometry3<f64>,
    ) -> Vector6<f64> {
        let horizon = self.ahead as f64 * self.dt;
        let k = FOLLOW_AHEAD_S / CORRECT_S;
        let dp = (target.translation.vector - here.translation.vector)
            + k * (here.translation.vector - tool.translation.vector);
        let dr = (target.rotation * here.rotation.inverse()).scaled_axis()
            + k * (here.rotation * tool.rotation.inverse()).scaled_axis();
        let mut w = Vector6::zeros();
        w.fixed_rows_mut::<3>(0).copy_from(&(dp / horizon));
        w.fixed_rows_mut::<3>(3).copy_from(&(dr / horizon));
        w
    }

    /// The tool twist of stick `a` in mode `mode` through the map at the state seen
    /// (`J(q) s map(q, c, a)`), its turning weighted by the operator's metres per radian;
    /// `None` if the map gave nothing.
    fn twist(&mut self, seen: &Seen<'_>, mode: usize, a: &[f64; 2]) -> Option<Vector6<f64>> {
        let n = (seen.state.n_joints as usize).min(MAX_JOINTS);
        let scale = self.probes.eval(
            mode,
            seen.state.q(),
            seen.state.gripper,
            a,
            &mut self.out[..n],
        )?;
        let mut v = super::tool_twist(seen.jac, &self.out[..n], scale);
        let w = self.params.tilt_weight_m_per_rad;
        for r in 3..6 {
            v[r] *= w;
        }
        Some(v)
    }

    /// The stick whose tool twist through the map comes closest to `want` (turning weighted
    /// as in [`Self::twist`]).
    fn choose(&mut self, seen: &Seen<'_>, want: &Vector6<f64>, rng: &mut Rng) -> [f64; 2] {
        let mut want = *want;
        let w = self.params.tilt_weight_m_per_rad;
        for r in 3..6 {
            want[r] *= w;
        }
        let mode = seen.mode.unwrap_or(0);
        super::draw_candidates(&mut self.cands, self.chosen, self.params.candidates, rng);
        if let Some(a) = self.least_squares(seen, mode, &want) {
            self.cands.push(a);
        }
        let mut best = ([0.0; 2], f64::INFINITY);
        let cands = std::mem::take(&mut self.cands);
        for a in &cands {
            let Some(v) = self.twist(seen, mode, a) else {
                continue;
            };
            let e = (v - want).norm_squared();
            if e < best.1 {
                best = (*a, e);
            }
        }
        self.cands = cands;
        tracing::trace!(
            want = want.norm(),
            residual = best.1.sqrt(),
            "the follower's best stick"
        );
        best.0
    }

    /// The stick that best reproduces `want` (weighted) if the map is linear in the stick at
    /// this state (SCL and PCA are; the CAE's decoder nearly so for small inputs): the
    /// twists for rest and the two unit inputs give `v(a) = v0 + A a`, the least-squares `a`
    /// is brought into the stick's disc. The random candidates cover a map that is not.
    fn least_squares(
        &mut self,
        seen: &Seen<'_>,
        mode: usize,
        want: &Vector6<f64>,
    ) -> Option<[f64; 2]> {
        let v0 = self.twist(seen, mode, &[0.0, 0.0])?;
        let a0 = self.twist(seen, mode, &[1.0, 0.0])? - v0;
        let a1 = self.twist(seen, mode, &[0.0, 1.0])? - v0;
        let r = want - v0;
        let (g00, g01, g11) = (a0.dot(&a0), a0.dot(&a1), a1.dot(&a1));
        let (b0, b1) = (a0.dot(&r), a1.dot(&r));
        let det = g00 * g11 - g01 * g01;
        if det.abs() < 1e-12 {
            return None;
        }
        let a = [(g11 * b0 - g01 * b1) / det, (g00 * b1 - g01 * b0) / det];
        let norm = a[0].hypot(a[1]);
        Some(if norm > 1.0 {
            [a[0] / norm, a[1] / norm]
        } else {
            a
        })
    }
}

impl Operate for Follower<'_> {
    fn act(&mut self, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
        let p = seen.tool.translation.vector;
        let c = seen.state.gripper;
        let mut gripper = 0.0f32;
        let mut choice = [0.0; 2];
        let n = (seen.state.n_joints as usize).min(MAX_JOINTS);
        let still = seen.state.qdot_rad_s[..n].iter().all(|v| v.abs() < 1e-3);
        if still && self.hand.stick[0].hypot(self.hand.stick[1]) > 0.2 {
            self.unanswered += 1;
        } else {
            self.unanswered = 0;
        }
        if self.unanswered as f64 * self.dt >= UNANSWERED_S {
            self.unanswered = 0;
            self.let_go = (LET_GO_S / self.dt).round() as u32;
            self.hand.let_go();
        }
        let resting = self.let_go > 0;
        if resting {
            self.let_go -= 1;
        } else if let Some(aim) = seen.aim {
            self.at = self.locate(seen.state.q(), seen.tool, c);
            if let Some((pi, i)) = self.at {
                self.note(pi, i, &p);
                if let (Some(target), Some(here)) = (
                    self.target(pi, i, c).map(|x| x.tool),
                    self.paths
                        .get(pi)
                        .and_then(|x| x.points.get(i))
                        .map(|x| x.tool),
                ) {
                    let want = self.wanted(seen.tool, &here, &target);
                    choice = self.choose(seen, &want, rng);
                    tracing::trace!(
                        path = pi,
                        at = i,
                        off_m = (here.translation.vector - p).norm(),
                        off_rad = here.rotation.angle_to(&seen.tool.rotation),
                        ?choice,
                        "the follower"
                    );
                }
            }
            if let Some(close) = aim.grip
                && aim.distance(&p) <= self.tol.position_m
            {
                gripper = if close { 1.0 } else { -1.0 };
            }
        }
        self.chosen = choice;
        self.hand.sample(
            &self.params,
            self.dt,
            choice,
            resting,
            seen.state,
            seen.t_ns,
            gripper,
            buttons::DEADMAN,
            rng,
        )
    }

    fn presses(&self) -> u32 {
        0
    }

    fn followed(&self) -> Option<Followed> {
        self.followed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::setup::SimError;
    use mapper::LoadedModel;

    /// Mode switching on the default robot, as the served map.
    fn modeswitch() -> Result<LoadedModel, SimError> {
        LoadedModel::load_for("modeswitch", RobotProfile::default_robot())
            .map_err(|e| SimError::Setup(e.to_string()))
    }

    fn follower(paths: Vec<DemoPath>) -> Follower<'static> {
        let probes = Probes::new(&modeswitch).expect("the map");
        Follower::new(
            &SimParams::default(),
            Tolerances::default(),
            0.025,
            probes,
            Arc::new(paths),
            None,
        )
    }

    /// A straight path along joint 1 with the gripper closing at tick 20.
    fn path() -> DemoPath {
        let robot = RobotProfile::default_robot();
        let points = (0..40)
            .map(|k| {
                let q = vec![0.01 * k as f64, -0.28, 1.309, 0.0, -1.047, 0.0];
                DemoPoint {
                    tool: robot.arm().fk(&q).expect("fk"),
                    q,
                    c: if k >= 20 { 1.0 } else { 0.0 },
                }
            })
            .collect();
        DemoPath {
            name: "line".into(),
            points,
        }
    }

    #[test]
    fn it_aims_ahead_but_not_past_a_grip_it_has_not_made() {
        let f = follower(vec![path()]);
        let ahead = f.ahead;
        assert_eq!(ahead, 10);
        let t = f.target(0, 2, 0.0).expect("a target");
        assert_eq!(t.q[0], 0.01 * 12.0);
        // Open, near the grasp: it waits at the last open tick.
        let t = f.target(0, 15, 0.0).expect("a target");
        assert_eq!(t.q[0], 0.01 * 19.0);
        // Closed: on it goes.
        let t = f.target(0, 20, 1.0).expect("a target");
        assert_eq!(t.q[0], 0.01 * 30.0);
    }

    #[test]
    fn it_never_goes_back_along_the_path_nor_past_a_grip() {
        let mut f = follower(vec![path()]);
        let robot = RobotProfile::default_robot();
        let q = |x: f64| [x, -0.28, 1.309, 0.0, -1.047, 0.0];
        let tool = |x: f64| robot.arm().fk(&q(x)).expect("fk");
        // At first by the joint angles, of every path.
        assert_eq!(f.locate(&q(0.05), &tool(0.05), 0.0), Some((0, 5)));
        f.at = Some((0, 10));
        // Then by the tool's pose. Nearer to tick 2, but it does not go back.
        assert_eq!(f.locate(&q(0.02), &tool(0.02), 0.0), Some((0, 10)));
        assert_eq!(f.locate(&q(0.14), &tool(0.14), 0.0), Some((0, 14)));
        // Where the tool keeps up with the demonstration: a tick on at its pace.
        f.at = Some((0, 5));
        assert_eq!(f.locate(&q(0.05), &tool(0.05), 0.0), Some((0, 6)));
        // Past the grasp with the gripper still open: the last open tick.
        assert_eq!(f.locate(&q(0.25), &tool(0.25), 0.0), Some((0, 19)));
    }

    /// The arm stands still under a pushed stick (safety holds it until the stick is at
    /// rest): after [`UNANSWERED_S`] the follower lets go for [`LET_GO_S`].
    #[test]
    fn it_lets_go_of_a_stick_the_arm_does_not_answer() {
        let robot = RobotProfile::default_robot();
        let mut f = follower(vec![path()]);
        // A hand whose stick stays where it is, without noise.
        f.params.stick_rate_per_s = 1e-9;
        f.params.input_noise = 0.0;
        f.hand.stick = [0.5, 0.0];
        let at = crate::operator::AtRest::new(robot, learning::tasks::Task::PickAndPlace, &[]);
        let seen = at.seen(None);
        let mut rng = Rng::new(1);
        let unanswered = (UNANSWERED_S / 0.025).round() as usize;
        let let_go = (LET_GO_S / 0.025).round() as usize;
        let axes: Vec<f32> = (0..unanswered + let_go + 1)
            .map(|_| f.act(&seen, &mut rng).axes[0])
            .collect();
        assert!(axes[..unanswered - 1].iter().all(|a| *a > 0.4), "{axes:?}");
        assert!(
            axes[unanswered..unanswered + let_go]
                .iter()
                .all(|a| *a == 0.0),
            "{axes:?}"
        );
    }

    #[test]
    fn the_path_of_a_trajectory_is_its_forward_kinematics() {
        let robot = RobotProfile::default_robot();
        let traj = Trajectory {
            name: "t".into(),
            t: vec![0.0, 0.025],
            q: vec![vec![0.0, -0.28, 1.309, 0.0, -1.047, 0.0]; 2],
            c: vec![0.0, 0.5],
            qdot: vec![vec![0.0; 6]; 2],
            cdot: vec![0.0; 2],
        };
        let p = DemoPath::of(robot, &traj).expect("fk");
        assert_eq!(p.len(), 2);
        assert_eq!(p.points[1].c, 0.5);
        let home = robot.arm().fk(&traj.q[0]).expect("fk");
        assert_eq!(p.points[0].tool, home);
    }
}
