//! The demonstration-following operator (`operator = "follower"`): what the map allows along
//! the route its demonstrations took, with a person's hand. Where the expert plans its own
//! way to the next subgoal, the follower only reproduces a demonstration: each tick it finds
//! where along the nearest demonstration the arm is (the nearest joint angles with the same
//! gripper state), and picks the stick whose joint velocity through the served map
//! (`s map(q, c, a)`, the quantity the maps were trained to reproduce) comes closest to the
//! demonstration's motion from there: the joint velocity that takes the arm to where the
//! demonstration is [`FOLLOW_AHEAD_S`] later. It never passes a grasp or a release of the
//! demonstration before its own gripper has done the same, and it closes or opens the
//! gripper as the other operators do, within the tolerance of a grip subgoal.
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
use nalgebra::{Isometry3, Vector3};

use super::greedy::Probes;
use super::{Hand, Operate, Seen};
use crate::simulate::{ModelFactory, SimParams};

/// How far ahead along the demonstration the follower aims (s): the motion it reproduces.
pub const FOLLOW_AHEAD_S: f64 = 0.25;

/// How fast it steers back towards the demonstration where the map lets it (s: the time
/// constant of the correction added to the demonstration's own motion).
const CORRECT_S: f64 = 1.0;

/// How far along its path it looks for where the tool is now (s): it never jumps further
/// than this, nor back.
const SEARCH_S: f64 = 2.0;

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
pub(crate) struct Follower {
    params: SimParams,
    tol: Tolerances,
    dt: f64,
    probes: Probes,
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
}

impl Follower {
    /// A follower of the nearest of `paths` (of `only`, if given).
    pub(crate) fn new(
        params: &SimParams,
        tol: Tolerances,
        dt: f64,
        probes: Probes,
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
        }
    }

    /// Where along the paths the arm at `q` with the gripper `c` is: the nearest joint angles
    /// with the same gripper state (open or closed), on the path followed from where it was,
    /// no further than the search window.
    fn locate(&mut self, q: &[f64], c: f64) -> Option<(usize, usize)> {
        let best = match self.at {
            Some((pi, i)) => {
                let path = self.paths.get(pi)?;
                path.nearest(q, c, i, (i + self.search).min(path.len()))
                    .map(|(i, _)| (pi, i))
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

    /// The stick whose joint velocity through the map comes closest to the one that takes the
    /// arm from where it is to `target` in [`FOLLOW_AHEAD_S`].
    fn choose(
        &mut self,
        make: &ModelFactory<'_>,
        seen: &Seen<'_>,
        target: &[f64],
        rng: &mut Rng,
    ) -> [f64; 2] {
        let n = (seen.state.n_joints as usize).min(MAX_JOINTS);
        let horizon = self.ahead as f64 * self.dt;
        let q = seen.state.q();
        let mut want = [0.0; MAX_JOINTS];
        for ((w, t), qj) in want.iter_mut().zip(target).zip(q).take(n) {
            *w = (t - qj) / horizon;
        }
        let mode = seen.mode.unwrap_or(0);
        super::draw_candidates(&mut self.cands, self.chosen, self.params.candidates, rng);
        if let Some(a) = self.least_squares(make, seen, mode, &want[..n]) {
            self.cands.push(a);
        }
        let mut best = ([0.0; 2], f64::INFINITY);
        let cands = std::mem::take(&mut self.cands);
        for a in &cands {
            let Some(scale) = self.probes.eval(
                make,
                mode,
                seen.state.q(),
                seen.state.gripper,
                a,
                &mut self.out[..n],
            ) else {
                continue;
            };
            let e: f64 = self.out[..n]
                .iter()
                .zip(&want[..n])
                .map(|(qd, w)| {
                    let v = if qd.is_finite() { qd * scale } else { 0.0 };
                    (v - w) * (v - w)
                })
                .sum();
            if e < best.1 {
                best = (*a, e);
            }
        }
        self.cands = cands;
        let wn: f64 = want[..n].iter().map(|w| w * w).sum::<f64>().sqrt();
        tracing::trace!(
            want_rad_s = wn,
            residual_rad_s = best.1.sqrt(),
            "the follower's best stick"
        );
        best.0
    }
}

impl Follower {
    /// The stick that best reproduces `want` if the map is linear in the stick at this state
    /// (SCL and PCA are; the CAE's decoder nearly so for small inputs): the map's outputs for
    /// rest and the two unit inputs give `v(a) = v0 + A a`, the least-squares `a` is brought
    /// into the stick's disc. The random candidates cover a map that is not.
    fn least_squares(
        &mut self,
        make: &ModelFactory<'_>,
        seen: &Seen<'_>,
        mode: usize,
        want: &[f64],
    ) -> Option<[f64; 2]> {
        let n = want.len();
        let q = seen.state.q();
        let c = seen.state.gripper;
        let mut cols = [[0.0; MAX_JOINTS]; 3];
        for (col, a) in cols.iter_mut().zip([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]) {
            let scale = self.probes.eval(make, mode, q, c, &a, &mut self.out[..n])?;
            for (x, v) in col.iter_mut().zip(&self.out[..n]) {
                *x = if v.is_finite() { v * scale } else { 0.0 };
            }
        }
        let (mut g, mut b) = ([[0.0; 2]; 2], [0.0; 2]);
        for j in 0..n {
            let a0 = cols[1][j] - cols[0][j];
            let a1 = cols[2][j] - cols[0][j];
            let r = want[j] - cols[0][j];
            g[0][0] += a0 * a0;
            g[0][1] += a0 * a1;
            g[1][1] += a1 * a1;
            b[0] += a0 * r;
            b[1] += a1 * r;
        }
        let det = g[0][0] * g[1][1] - g[0][1] * g[0][1];
        if det.abs() < 1e-12 {
            return None;
        }
        let a = [
            (g[1][1] * b[0] - g[0][1] * b[1]) / det,
            (g[0][0] * b[1] - g[0][1] * b[0]) / det,
        ];
        let norm = a[0].hypot(a[1]);
        Some(if norm > 1.0 {
            [a[0] / norm, a[1] / norm]
        } else {
            a
        })
    }
}

impl Operate for Follower {
    fn act(&mut self, make: &ModelFactory<'_>, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
        let p = seen.tool.translation.vector;
        let c = seen.state.gripper;
        let mut gripper = 0.0f32;
        let mut choice = [0.0; 2];
        if let Some(aim) = seen.aim {
            self.at = self.locate(seen.state.q(), c);
            if let Some((pi, i)) = self.at {
                self.note(pi, i, &p);
                if let (Some(target), Some(here)) = (
                    self.target(pi, i, c),
                    self.paths.get(pi).and_then(|x| x.points.get(i)),
                ) {
                    // The demonstration's next motion from the nearest point, from where the
                    // arm is, and a slow pull back onto the demonstration (as far as the map's
                    // two directions allow).
                    let k = FOLLOW_AHEAD_S / CORRECT_S;
                    let q: Vec<f64> = target
                        .q
                        .iter()
                        .zip(&here.q)
                        .zip(seen.state.q())
                        .map(|((t, h), now)| now + (t - h) + k * (h - now))
                        .collect();
                    // How far off the demonstration: computed only when traced.
                    let off = tracing::enabled!(tracing::Level::TRACE).then(|| {
                        let off_rad: f64 = here
                            .q
                            .iter()
                            .zip(seen.state.q())
                            .map(|(a, b)| (a - b) * (a - b))
                            .sum::<f64>()
                            .sqrt();
                        ((here.tool.translation.vector - p).norm(), off_rad)
                    });
                    choice = self.choose(make, seen, &q, rng);
                    if let Some((off_m, off_rad)) = off {
                        tracing::trace!(path = pi, at = i, off_m, off_rad, ?choice, "the follower");
                    }
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
            false,
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
    use crate::simulate::SimError;
    use mapper::LoadedModel;

    fn follower(paths: Vec<DemoPath>) -> Follower {
        let robot = RobotProfile::default_robot();
        let make = || {
            LoadedModel::load_for("modeswitch", robot).map_err(|e| SimError::Setup(e.to_string()))
        };
        let probes = Probes::new(&make).expect("the map");
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
        let q = |x: f64| [x, -0.28, 1.309, 0.0, -1.047, 0.0];
        assert_eq!(f.locate(&q(0.05), 0.0), Some((0, 5)));
        f.at = Some((0, 5));
        // Nearer to tick 2, but it does not go back.
        assert_eq!(f.locate(&q(0.02), 0.0), Some((0, 5)));
        // Past the grasp with the gripper still open: the last open tick.
        assert_eq!(f.locate(&q(0.25), 0.0), Some((0, 19)));
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
