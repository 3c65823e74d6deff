//! The whole-arm rules: the distance between every checked pair of the robot profile's
//! collision model (each link against the others and against the scene,
//! `kinematics::collision`), and the Cartesian speed of the tool and of every link capsule's
//! ends, for an arm of any number of joints up to [`MAX_ARM_JOINTS`] (the Gen3 lite's six,
//! the Gen3's seven).
//!
//! The rules are pure functions on slices, like [`crate::rules`]: a checked pair is a
//! [`Near`] (its distance `d` and the row `g` with `d_dot = g · qdot`), a point is its
//! translational Jacobian. Rows and Jacobians have [`MAX_ARM_JOINTS`] columns, the arm's
//! joints then zeros; `qdot` is the arm's joints only (a longer one would see the zeros). [`WholeArm`] computes them at a tick's state (the clearance once,
//! the rows of the pairs that matter, the Jacobians of the capsule ends), allocation-free.
//!
//! * Slow-down ([`slowdown_scale`]): a pair within the slowdown distance may approach at most
//!   at `max_tcp_speed_m_s · (d - stop) / (slowdown - stop)`, so the command is scaled down
//!   as the pair nears the stop distance, to zero at it.
//! * Braking ([`clearance_scale`]): each approaching pair is a bound `d - stop` away,
//!   approached at `-d_dot`, braked along the command's direction within the acceleration
//!   limits (the joint-limit rule's [`crate::rules::brake_speed`] at `alpha · (-d_dot)`); with
//!   `hard`, only "not past it within the next tick".
//! * Speed ([`speed_scale`]): one factor so that no point moves faster than the cap.
//!
//! All of them scale the whole command by one factor, so it keeps its direction; motion that
//! opens a gap (`d_dot >= 0`) is never limited by it.

use kinematics::RobotProfile;
pub use kinematics::collision::MAX_ARM_JOINTS;
use kinematics::collision::{Clearance, CollisionModel, Scene, Target, side_code};
use nalgebra::{Point3, Vector3};

/// Slack kept above the stop distance (m): the rules predict a distance over one tick to
/// first order (`d + g · qdot · dt`), and this covers the rest (the points' curved paths,
/// about `|v| |omega| dt² / 2`, 0.2 mm at the speed caps). [`WholeArm::verify`] then checks
/// the exact distances at the next tick's pose.
pub const CLEARANCE_SLACK_M: f64 = 0.001;

/// How much closer the exact check ([`WholeArm::verify`]) lets a pair already inside the stop
/// distance come in one tick (m). The first-order rules already forbid it to approach; this
/// is what the next pose's exact distance may lose to round-off and to the curve of the
/// points' paths before the check scales the command. A pair's distance is the least over
/// its features (a capsule's two ends against a box's faces), so where the nearest feature
/// moves away and another approaches, the first-order rate sees only the first: a proptest
/// found an upper wrist 1.36 cm from a box coming 0.65 mm closer that way.
pub const BELOW_STOP_SLACK_M: f64 = 0.0001;

/// The share of the braking the acceleration limits allow that the braking rule plans with.
/// A distance's rate per unit of joint speed changes along the way (a folding link closes
/// faster as it nears: the fold onto the upper arm by 20 %); planning the stop with three
/// quarters of the braking leaves the rest for that, so the stop stays within the
/// acceleration limits instead of needing the hard guarantee.
pub const BRAKE_SHARE: f64 = 0.75;

/// Refinements of [`WholeArm::verify`] before it stops the arm instead.
const VERIFY_STEPS: usize = 4;

// Every arm the filter takes (`ipc_types::MAX_JOINTS` joints at most) fits the rows.
const _: () = assert!(ipc_types::MAX_JOINTS <= MAX_ARM_JOINTS);

/// A row over the arm's joints: entry `j` per rad/s of joint `j`, zero beyond the arm's
/// joints.
pub type JointRow = [f64; MAX_ARM_JOINTS];

/// A translational Jacobian: row `i` is axis `i`, column `j` joint `j` (m per rad), zero
/// beyond the arm's joints.
pub type PointJacobian = [JointRow; 3];

/// A checked pair as the rules see it: its signed distance and the row `g` of
/// `d_dot = g · qdot`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Near {
    /// Signed distance (m).
    pub distance_m: f64,
    /// `d_dot = rate_row · qdot` (m/s for rad/s), zero beyond the arm's joints.
    pub rate_row: JointRow,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The factor `<= 1` for `v` so that every pair it brings closer (`g · v < 0`) can still stop
/// before `stop_m`, braking along `v`'s direction at `alpha` (1/s, the command's
/// [`crate::rules::brake_rate`]: a pair approaching at `s` slows at `alpha · s`, planned at
/// [`BRAKE_SHARE`] of it); with `hard`,
/// so that it is not closer than `stop_m` within the next tick to first order. A pair at or
/// below `stop_m` may not approach at all. Motion that opens every gap gives 1.
pub fn clearance_scale(
    pairs: &[Near],
    v: &[f64],
    stop_m: f64,
    alpha: f64,
    dt: f64,
    hard: bool,
) -> f64 {
    let mut k: f64 = 1.0;
    for p in pairs {
        let s = -dot(&p.rate_row, v);
        if s <= 0.0 {
            continue;
        }
        let dist = p.distance_m - stop_m;
        let allowed = if hard {
            dist.max(0.0) / dt
        } else {
            crate::rules::brake_speed(BRAKE_SHARE * alpha * s, dist, dt)
        };
        k = k.min(allowed / s);
    }
    k.max(0.0)
}

/// The factor `<= 1` for `v` so that every pair within `slowdown_m` that `v` brings closer
/// approaches at most at `approach_m_s · (d - stop_m) / (slowdown_m - stop_m)`: full speed at
/// the slowdown distance, zero at the stop distance (and below it). Motion that opens every
/// gap gives 1.
pub fn slowdown_scale(
    pairs: &[Near],
    v: &[f64],
    stop_m: f64,
    slowdown_m: f64,
    approach_m_s: f64,
) -> f64 {
    let mut k: f64 = 1.0;
    for p in pairs.iter().filter(|p| p.distance_m < slowdown_m) {
        let s = -dot(&p.rate_row, v);
        if s <= 0.0 {
            continue;
        }
        let frac = ((p.distance_m - stop_m) / (slowdown_m - stop_m)).clamp(0.0, 1.0);
        k = k.min(approach_m_s * frac / s);
    }
    k.max(0.0)
}

/// `|J v|`: the speed of a point with translational Jacobian `j` under `v` (m/s).
pub fn point_speed(j: &PointJacobian, v: &[f64]) -> f64 {
    j.iter().map(|row| dot(row, v).powi(2)).sum::<f64>().sqrt()
}

/// The largest factor `<= 1` for `v` so that no point (by its Jacobian, or an angular
/// Jacobian for an angular speed) moves faster than `cap`.
pub fn speed_scale(points: &[PointJacobian], v: &[f64], cap: f64) -> f64 {
    points
        .iter()
        .map(|j| point_speed(j, v))
        .filter(|s| *s > cap)
        .fold(1.0, |k: f64, s| k.min(cap / s))
}

/// The whole-arm model at one tick: the collision model's clearance of the state in the
/// scene, the rows of the pairs that matter, and the Jacobians of the points whose speed is
/// capped. Buffers are allocated once ([`WholeArm::new`]); a tick allocates nothing.
#[derive(Debug)]
pub struct WholeArm {
    model: &'static CollisionModel,
    scene: Scene,
    /// The profile's gripper joint when open and when closed (rad); `None` without a gripper.
    gripper: Option<(f64, f64)>,
    /// The tool (`tool_frame`) in the gripper base's frame.
    tool_offset: Point3<f64>,
    now: Box<Clearance>,
    next: Box<Clearance>,
    /// The arm's joints (the model's).
    n: usize,
    /// The arm joints of the last [`WholeArm::update`], then the gripper joint (the first
    /// `n + 1` entries are used).
    q: [f64; MAX_ARM_JOINTS + 1],
    valid: bool,
    near: Vec<Near>,
    /// Capsule ends, then the tool (last).
    points: Vec<PointJacobian>,
    angular: PointJacobian,
    closest: Option<(f64, [u16; 2])>,
}

/// Whether a pair never changes: the base (which no joint moves) against the scene. Those
/// pairs are left out of the rules and of the reported clearance: a mount box under the base
/// would otherwise report its constant overlap as the closest pair.
fn is_static(model: &CollisionModel, pair: &kinematics::collision::PairId) -> bool {
    pair.a.link == model.base_link() && !matches!(pair.b, Target::Capsule(_))
}

impl WholeArm {
    /// `robot`'s collision model in `scene`; `None` if the profile has no collision model
    /// or its arm does not have the model's joints (at most [`MAX_ARM_JOINTS`]).
    pub fn new(robot: &RobotProfile, scene: Scene) -> Option<Self> {
        let model = robot.collision_model()?;
        let n = model.n_joints();
        if robot.n_joints() != n || n > MAX_ARM_JOINTS {
            return None;
        }
        let home = robot.named_pose("home")?;
        let mut now = Box::new(Clearance::default());
        // The tool (the arm chain's tip) is fixed to the gripper base: its offset from any
        // pose.
        let tool_offset = match (
            model.clearance(home, &scene, &mut now),
            robot.arm().fk(home),
        ) {
            (Ok(()), Ok(tcp)) => {
                now.link_pose(model.tool_link()).inverse() * Point3::from(tcp.translation.vector)
            }
            _ => Point3::origin(),
        };
        let n_points = 2 * model.capsule_refs().len() + 1;
        Some(Self {
            model,
            scene,
            gripper: robot.gripper().map(|g| (g.open_rad(), g.closed_rad())),
            tool_offset,
            now,
            next: Box::new(Clearance::default()),
            n,
            q: [0.0; MAX_ARM_JOINTS + 1],
            valid: false,
            near: Vec::with_capacity(kinematics::collision::MAX_PAIRS),
            points: Vec::with_capacity(n_points),
            angular: [[0.0; MAX_ARM_JOINTS]; 3],
            closest: None,
        })
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The arm's number of joints (the length of `q` in [`WholeArm::update`]).
    pub fn n_joints(&self) -> usize {
        self.n
    }

    /// Computes the clearance at the arm joints `q` with the gripper at `gripper` (the
    /// robot state's `c`: 0 open, 1 closed, as the profile's gripper maps it; not finite, or a
    /// profile without a gripper: the model's default) and the
    /// Jacobians of the capsule ends and the tool. Returns whether the model gave finite
    /// values (if not, the rules are off this tick and [`WholeArm::closest`] is `None`).
    pub fn update(&mut self, q: &[f64], gripper: f64) -> bool {
        self.valid = false;
        self.closest = None;
        self.near.clear();
        self.points.clear();
        let n = self.n;
        if q.len() != n {
            return false;
        }
        self.q[..n].copy_from_slice(q);
        // The profile says which end of the joint's range is open (the Gen3 lite's upper end,
        // the Gen3's 2F-85 its lower one).
        self.q[n] = match self.gripper {
            Some((open, closed)) if gripper.is_finite() => {
                open - gripper.clamp(0.0, 1.0) * (open - closed)
            }
            _ => self.model.gripper_default_rad(),
        };
        if self
            .model
            .clearance(&self.q[..=n], &self.scene, &mut self.now)
            .is_err()
        {
            return false;
        }
        let c = &self.now;
        for (cap, r) in c.capsules().iter().zip(self.model.capsule_refs()) {
            for p in [&cap.a, &cap.b] {
                self.points.push(rows(&c.point_jacobian(r.link, p)));
            }
        }
        let tool_link = self.model.tool_link();
        let tool = c.link_pose(tool_link) * self.tool_offset;
        self.points.push(rows(&c.point_jacobian(tool_link, &tool)));
        self.angular = rows(&c.angular_jacobian(tool_link));
        for (d, pair) in c.distances_m().iter().zip(c.pairs()) {
            if !is_static(self.model, pair) && self.closest.is_none_or(|(m, _)| *d < m) {
                self.closest = Some((*d, pair.code()));
            }
        }
        self.valid = self
            .points
            .iter()
            .flatten()
            .flatten()
            .all(|v| v.is_finite())
            && c.distances_m().iter().all(|d| d.is_finite());
        if !self.valid {
            self.closest = None;
        }
        self.valid
    }

    /// Collects the pairs closer than `horizon_m` with their rate rows ([`WholeArm::near`]);
    /// pairs whose direction is undefined (two capsule axes crossing: deep overlap) and the
    /// base against the scene are left out.
    pub fn collect(&mut self, horizon_m: f64) {
        self.near.clear();
        if !self.valid {
            return;
        }
        let c = &self.now;
        for (i, (d, pair)) in c.distances_m().iter().zip(c.pairs()).enumerate() {
            if *d >= horizon_m || is_static(self.model, pair) {
                continue;
            }
            if let Some(row) = c.contact(i).and_then(|ct| c.rate_row(&ct)) {
                self.near.push(Near {
                    distance_m: *d,
                    rate_row: row,
                });
            }
        }
    }

    /// The pairs [`WholeArm::collect`] kept.
    pub fn near(&self) -> &[Near] {
        &self.near
    }

    /// The translational Jacobians of every capsule end and, last, of the tool.
    pub fn points(&self) -> &[PointJacobian] {
        &self.points
    }

    /// The tool's translational Jacobian.
    pub fn tool(&self) -> Option<&PointJacobian> {
        self.points.last()
    }

    /// The tool's angular Jacobian.
    pub fn angular(&self) -> &PointJacobian {
        &self.angular
    }

    /// The fastest point's speed under `v` (m/s).
    pub fn max_point_speed(&self, v: &[f64]) -> f64 {
        self.points
            .iter()
            .map(|j| point_speed(j, v))
            .fold(0.0, f64::max)
    }

    /// The smallest distance of a checked pair and the pair's code, at the state of the last
    /// [`WholeArm::update`].
    pub fn closest(&self) -> Option<(f64, [u16; 2])> {
        self.closest
    }

    /// The clearance at the state of the last [`WholeArm::update`].
    pub fn clearance(&self) -> &Clearance {
        &self.now
    }

    /// The exact check of the next tick: the clearance at `q + v · dt` (the state of the
    /// last [`WholeArm::update`]); every pair at or beyond `stop_m` now must be so then too,
    /// and every pair inside it no closer than [`BELOW_STOP_SLACK_M`] less. If one is not,
    /// `v` is scaled down (by the secant of the pair's distance along the step, a few times,
    /// else to zero). Returns the factor applied. Skipped (1) when no pair can come that
    /// close: none is inside `stop_m` or within four times the fastest point's travel of it.
    pub fn verify(&mut self, v: &mut [f64], stop_m: f64, dt: f64) -> f64 {
        if !self.valid || v.len() != self.n {
            return 1.0;
        }
        let reach = 4.0 * self.max_point_speed(v) * dt + 2.0 * CLEARANCE_SLACK_M;
        let near = self
            .now
            .distances_m()
            .iter()
            .zip(self.now.pairs())
            .any(|(d, p)| !is_static(self.model, p) && *d - stop_m < reach);
        if !near {
            return 1.0;
        }
        let mut k = 1.0;
        let mut ok = false;
        for _ in 0..VERIFY_STEPS {
            let mut q = self.q;
            for (qj, vj) in q.iter_mut().zip(v.iter()) {
                *qj += k * vj * dt;
            }
            if self
                .model
                .clearance(&q[..=self.n], &self.scene, &mut self.next)
                .is_err()
            {
                break;
            }
            let mut worst: f64 = 1.0;
            for ((d0, d1), p) in self
                .now
                .distances_m()
                .iter()
                .zip(self.next.distances_m())
                .zip(self.now.pairs())
            {
                if is_static(self.model, p) {
                    continue;
                }
                // The distance is nearly linear in the step's size: aim 10 % short of the
                // stop distance, or of the slack inside it.
                if *d0 >= stop_m && *d1 < stop_m {
                    worst = worst.min(0.9 * (d0 - stop_m) / (d0 - d1));
                } else if *d0 < stop_m && *d1 < d0 - BELOW_STOP_SLACK_M {
                    worst = worst.min(0.9 * BELOW_STOP_SLACK_M / (d0 - d1));
                }
            }
            if worst >= 1.0 {
                ok = true;
                break;
            }
            k *= worst.max(0.0);
        }
        if !ok {
            k = 0.0;
        }
        if k < 1.0 {
            v.iter_mut().for_each(|x| *x *= k);
        }
        k
    }

    /// The side codes of nothing checked.
    pub const NO_PAIR: [u16; 2] = [side_code::NONE; 2];
}

fn rows(cols: &[Vector3<f64>; MAX_ARM_JOINTS]) -> PointJacobian {
    let mut j = [[0.0; MAX_ARM_JOINTS]; 3];
    for (c, col) in cols.iter().enumerate() {
        for (i, row) in j.iter_mut().enumerate() {
            row[c] = col[i];
        }
    }
    j
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gripper joint the model is given is the profile's angle for the state's `c`:
    /// open at `c = 0` whichever end of the joint's range that is (the Gen3 lite's upper
    /// end, 0.96 rad; the Gen3's 2F-85 its lower one, 0 rad), the model's default when `c`
    /// is not finite.
    #[test]
    fn the_gripper_joint_follows_the_profiles_open_and_closed_ends() {
        for (name, open, closed) in [("gen3_lite", 0.96, -0.09), ("gen3", 0.0, 0.8)] {
            let robot = RobotProfile::by_name(name).unwrap();
            let g = robot.gripper().unwrap();
            assert_eq!((g.open_rad(), g.closed_rad()), (open, closed), "{name}");
            let mut arm = WholeArm::new(robot, Scene::default()).unwrap();
            let n = robot.n_joints();
            let home = robot.named_pose("home").unwrap();
            for (c, want) in [(0.0, open), (1.0, closed), (0.5, g.angle(0.5))] {
                assert!(arm.update(home, c), "{name}");
                assert!(
                    (arm.q[n] - want).abs() < 1e-15,
                    "{name} c = {c}: {}",
                    arm.q[n]
                );
            }
            assert!(arm.update(home, f64::NAN));
            let default = robot.collision_model().unwrap().gripper_default_rad();
            assert_eq!(arm.q[n], default, "{name}");
        }
    }
}
