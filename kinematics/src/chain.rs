//! A serial chain, precomputed for the control loop: forward kinematics to any link of the
//! chain and the geometric Jacobian of its tip, with no allocation per call.
//!
//! [`crate::RobotModel::chain`] builds it from a URDF: consecutive fixed joints are folded
//! into the origin of the next movable joint (or into the tip offset), and everything lives
//! in fixed arrays of [`MAX_DOF`] entries. Evaluation writes into caller-owned values
//! ([`nalgebra::Isometry3`], [`Jacobian`]), all on the stack.
//!
//! Conventions: poses are in the base link's frame; the Jacobian's rows are the linear
//! velocity of the tip (m/s per unit joint rate, rows 0-2) over the angular velocity (rad/s,
//! rows 3-5), both in the base frame, as in the usual geometric Jacobian.

use nalgebra::{
    Dyn, Isometry3, MatrixView, SMatrix, Translation3, U1, U6, Unit, UnitQuaternion, Vector3,
};

/// Most movable joints a chain may have (the message types' `MAX_JOINTS`).
pub const MAX_DOF: usize = 8;

/// Why a chain could not be evaluated for the given input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum KinError {
    /// The joint vector has the wrong length.
    #[error("{found} joint values given for a chain of {expected} movable joints")]
    Length {
        /// The chain's number of movable joints.
        expected: usize,
        /// The length given.
        found: usize,
    },
    /// An input holds NaN or infinity.
    #[error("the {what} holds a non-finite value (at index {index})")]
    NonFinite {
        /// Which input (`joint vector`, `Jacobian`, `task error`).
        what: &'static str,
        /// The first bad index.
        index: usize,
    },
}

/// How a movable joint moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Rotation about the axis (rad).
    Revolute,
    /// Translation along the axis (m).
    Prismatic,
}

/// One joint of a chain before precomputation (`kind == None` for a fixed joint).
#[derive(Debug, Clone)]
pub(crate) struct ChainJoint {
    pub name: String,
    pub child: String,
    pub kind: Option<JointKind>,
    pub origin: Isometry3<f64>,
    pub axis: Unit<Vector3<f64>>,
    pub lower: f64,
    pub upper: f64,
    pub velocity: f64,
}

/// A movable joint's axis in the base frame at one configuration (see [`Chain::link_poses`]):
/// what the Jacobian of any point moved by the joint is made of.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointAxis {
    /// How the joint moves.
    pub kind: JointKind,
    /// A point on the axis: the joint frame's origin (m, base frame).
    pub origin: Vector3<f64>,
    /// The unit direction of the axis (base frame).
    pub direction: Vector3<f64>,
}

impl JointAxis {
    /// An unused entry (a revolute axis along z through the origin).
    pub const UNUSED: JointAxis = JointAxis {
        kind: JointKind::Revolute,
        origin: Vector3::new(0.0, 0.0, 0.0),
        direction: Vector3::new(0.0, 0.0, 1.0),
    };

    /// Velocity of the point `p` (base frame) per unit rate of this joint, when `p` moves
    /// with it: `direction x (p - origin)` for a revolute joint, `direction` for a prismatic one.
    pub fn point_velocity(&self, p: &Vector3<f64>) -> Vector3<f64> {
        match self.kind {
            JointKind::Revolute => self.direction.cross(&(p - self.origin)),
            JointKind::Prismatic => self.direction,
        }
    }
}

/// A link of the chain, by position: see [`Chain::link_id`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LinkId(usize);

#[derive(Debug, Clone, PartialEq)]
struct ChainLink {
    name: String,
    /// Movable joints applied before this link (0 ..= n).
    after: usize,
    /// Pose of the link in the frame reached after those joints.
    offset: Isometry3<f64>,
}

/// The geometric Jacobian of a chain's tip: 6 rows (linear over angular velocity, base frame)
/// by `n` columns, one per movable joint. Stored in a fixed 6 x [`MAX_DOF`] matrix whose
/// unused columns are zero, so filling it never allocates.
#[derive(Debug, Clone, PartialEq)]
pub struct Jacobian {
    data: SMatrix<f64, 6, MAX_DOF>,
    n: usize,
}

impl Jacobian {
    /// A zero Jacobian for `n` joints (at most [`MAX_DOF`]; larger values are cut to it).
    pub fn zeros(n: usize) -> Self {
        Self {
            data: SMatrix::zeros(),
            n: n.min(MAX_DOF),
        }
    }

    /// Number of columns in use.
    pub fn n_joints(&self) -> usize {
        self.n
    }

    /// The 6 x n matrix (a view; no copy).
    pub fn matrix(&self) -> MatrixView<'_, f64, U6, Dyn, U1, U6> {
        self.data.columns(0, self.n)
    }

    /// The whole fixed-size storage (columns `n..` are zero).
    pub fn padded(&self) -> &SMatrix<f64, 6, MAX_DOF> {
        &self.data
    }

    /// Entry at `row` (0-5), `col` (joint); 0 outside the matrix.
    pub fn get(&self, row: usize, col: usize) -> f64 {
        if row < 6 && col < self.n {
            self.data[(row, col)]
        } else {
            0.0
        }
    }
}

/// A serial kinematic chain from a base link to a tip link (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    file: String,
    base: String,
    tip: String,
    n: usize,
    names: Vec<String>,
    kinds: [JointKind; MAX_DOF],
    origins: [Isometry3<f64>; MAX_DOF],
    axes: [Unit<Vector3<f64>>; MAX_DOF],
    lower: [f64; MAX_DOF],
    upper: [f64; MAX_DOF],
    velocity: [f64; MAX_DOF],
    tip_offset: Isometry3<f64>,
    links: Vec<ChainLink>,
}

impl Chain {
    /// Precomputes a chain from its joints in base-to-tip order. The error says what is not
    /// supported.
    pub(crate) fn build(
        file: &str,
        base: &str,
        tip: &str,
        joints: &[ChainJoint],
    ) -> Result<Self, String> {
        let movable = joints.iter().filter(|j| j.kind.is_some()).count();
        if movable > MAX_DOF {
            return Err(format!(
                "{movable} movable joints; at most {MAX_DOF} are supported"
            ));
        }
        let mut c = Chain {
            file: file.to_owned(),
            base: base.to_owned(),
            tip: tip.to_owned(),
            n: movable,
            names: Vec::with_capacity(movable),
            kinds: [JointKind::Revolute; MAX_DOF],
            origins: [Isometry3::identity(); MAX_DOF],
            axes: [Vector3::z_axis(); MAX_DOF],
            lower: [0.0; MAX_DOF],
            upper: [0.0; MAX_DOF],
            velocity: [0.0; MAX_DOF],
            tip_offset: Isometry3::identity(),
            links: vec![ChainLink {
                name: base.to_owned(),
                after: 0,
                offset: Isometry3::identity(),
            }],
        };
        let mut acc = Isometry3::identity();
        let mut i = 0;
        for j in joints {
            match j.kind {
                None => acc *= j.origin,
                Some(kind) => {
                    c.origins[i] = acc * j.origin;
                    c.kinds[i] = kind;
                    c.axes[i] = j.axis;
                    c.lower[i] = j.lower;
                    c.upper[i] = j.upper;
                    c.velocity[i] = j.velocity;
                    c.names.push(j.name.clone());
                    acc = Isometry3::identity();
                    i += 1;
                }
            }
            c.links.push(ChainLink {
                name: j.child.clone(),
                after: i,
                offset: acc,
            });
        }
        c.tip_offset = acc;
        Ok(c)
    }

    /// Gives the joints whose position is unlimited in the description (URDF `continuous`)
    /// the software limits `[-limit_rad, limit_rad]`, so that every joint of the chain has a
    /// finite range; returns which joints were unlimited. Limited joints are left as they are.
    pub(crate) fn limit_unlimited(&mut self, limit_rad: f64) -> [bool; MAX_DOF] {
        let mut unlimited = [false; MAX_DOF];
        let n = self.n;
        for ((lo, hi), u) in self
            .lower
            .iter_mut()
            .zip(self.upper.iter_mut())
            .zip(unlimited.iter_mut())
            .take(n)
        {
            if !(lo.is_finite() && hi.is_finite()) {
                *lo = -limit_rad;
                *hi = limit_rad;
                *u = true;
            }
        }
        unlimited
    }

    /// The file the chain was read from.
    pub fn file(&self) -> &str {
        &self.file
    }
    /// The base link (the frame every pose is expressed in).
    pub fn base(&self) -> &str {
        &self.base
    }
    /// The tip link (the frame [`Chain::fk`] and the Jacobian are about).
    pub fn tip(&self) -> &str {
        &self.tip
    }
    /// Number of movable joints.
    pub fn n_joints(&self) -> usize {
        self.n
    }
    /// Movable joint names, base to tip.
    pub fn joint_names(&self) -> &[String] {
        &self.names
    }
    /// How each movable joint moves.
    pub fn joint_kinds(&self) -> &[JointKind] {
        &self.kinds[..self.n]
    }
    /// Lower position limits (rad or m).
    pub fn lower(&self) -> &[f64] {
        &self.lower[..self.n]
    }
    /// Upper position limits (rad or m).
    pub fn upper(&self) -> &[f64] {
        &self.upper[..self.n]
    }
    /// Velocity limits from the file (rad/s or m/s).
    pub fn velocity_limits(&self) -> &[f64] {
        &self.velocity[..self.n]
    }
    /// Names of the links along the chain, base first, tip last.
    pub fn link_names(&self) -> impl Iterator<Item = &str> {
        self.links.iter().map(|l| l.name.as_str())
    }
    /// The id of a link of the chain, for [`Chain::link_pose`].
    pub fn link_id(&self, name: &str) -> Option<LinkId> {
        self.links.iter().position(|l| l.name == name).map(LinkId)
    }

    /// Number of links along the chain (base and tip included), the length of
    /// [`Chain::link_names`].
    pub fn n_links(&self) -> usize {
        self.links.len()
    }
    /// How many movable joints (the first ones of the chain) move a link: 0 for the base.
    pub fn joints_before(&self, link: LinkId) -> usize {
        self.links.get(link.0).map_or(self.n, |l| l.after)
    }
    /// The position of a link along the chain (its index in [`Chain::link_names`]).
    pub fn link_index(&self, link: LinkId) -> usize {
        link.0
    }

    /// Whether every joint of `q` is inside its position limits.
    pub fn within_limits(&self, q: &[f64]) -> bool {
        q.len() == self.n
            && q.iter()
                .zip(self.lower())
                .zip(self.upper())
                .all(|((v, lo), hi)| *v >= *lo && *v <= *hi)
    }

    /// Clamps `q` into the position limits in place; returns whether a joint was clamped.
    pub fn clamp_to_limits(&self, q: &mut [f64]) -> bool {
        let mut clamped = false;
        for ((v, lo), hi) in q.iter_mut().zip(self.lower()).zip(self.upper()) {
            let c = v.clamp(*lo, *hi);
            if c != *v {
                *v = c;
                clamped = true;
            }
        }
        clamped
    }

    fn check(&self, q: &[f64]) -> Result<(), KinError> {
        if q.len() != self.n {
            return Err(KinError::Length {
                expected: self.n,
                found: q.len(),
            });
        }
        Ok(())
    }

    fn motion(&self, i: usize, qi: f64) -> Isometry3<f64> {
        match self.kinds[i] {
            JointKind::Revolute => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&self.axes[i], qi),
            ),
            JointKind::Prismatic => Isometry3::from_parts(
                Translation3::from(self.axes[i].into_inner() * qi),
                UnitQuaternion::identity(),
            ),
        }
    }

    /// Pose of the frame reached after the first `k` movable joints; fills `frames[i]` with
    /// the pose of joint `i`'s frame (before its own motion) for `i < k`.
    fn walk(&self, q: &[f64], k: usize, frames: &mut [Isometry3<f64>; MAX_DOF]) -> Isometry3<f64> {
        let mut t = Isometry3::identity();
        for i in 0..k {
            t *= self.origins[i];
            frames[i] = t;
            t *= self.motion(i, q[i]);
        }
        t
    }

    /// Pose of the tip in the base frame.
    pub fn fk(&self, q: &[f64]) -> Result<Isometry3<f64>, KinError> {
        self.check(q)?;
        let mut frames = [Isometry3::identity(); MAX_DOF];
        Ok(self.walk(q, self.n, &mut frames) * self.tip_offset)
    }

    /// Pose of any link of the chain in the base frame.
    pub fn link_pose(&self, q: &[f64], link: LinkId) -> Result<Isometry3<f64>, KinError> {
        self.check(q)?;
        let l = &self.links[link.0.min(self.links.len() - 1)];
        let mut frames = [Isometry3::identity(); MAX_DOF];
        Ok(self.walk(q, l.after, &mut frames) * l.offset)
    }

    /// Poses of the links along the chain in the base frame, in one pass: `links[i]` gets the
    /// pose of the `i`-th of [`Chain::link_names`] (entries beyond `links.len()` are not
    /// computed, extra entries are left alone), and `axes[i]` the axis of movable joint `i` at
    /// `q` (entries from [`Chain::n_joints`] on are [`JointAxis::UNUSED`]). Allocation-free.
    pub fn link_poses(
        &self,
        q: &[f64],
        links: &mut [Isometry3<f64>],
        axes: &mut [JointAxis; MAX_DOF],
    ) -> Result<(), KinError> {
        self.check(q)?;
        *axes = [JointAxis::UNUSED; MAX_DOF];
        let mut t = Isometry3::identity();
        let mut done = 0;
        for (l, out) in self.links.iter().zip(links.iter_mut()) {
            while done < l.after {
                t *= self.origins[done];
                axes[done] = JointAxis {
                    kind: self.kinds[done],
                    origin: t.translation.vector,
                    direction: t.rotation * self.axes[done].into_inner(),
                };
                t *= self.motion(done, q[done]);
                done += 1;
            }
            *out = t * l.offset;
        }
        // Axes of joints past the last link asked for.
        while done < self.n {
            t *= self.origins[done];
            axes[done] = JointAxis {
                kind: self.kinds[done],
                origin: t.translation.vector,
                direction: t.rotation * self.axes[done].into_inner(),
            };
            t *= self.motion(done, q[done]);
            done += 1;
        }
        Ok(())
    }

    /// Pose of the tip and the geometric Jacobian of the tip, in one pass, written into
    /// `jac` (which is resized to this chain). Allocation-free.
    pub fn fk_jacobian(&self, q: &[f64], jac: &mut Jacobian) -> Result<Isometry3<f64>, KinError> {
        self.check(q)?;
        let mut frames = [Isometry3::identity(); MAX_DOF];
        let tip = self.walk(q, self.n, &mut frames) * self.tip_offset;
        let p_tip = tip.translation.vector;
        jac.n = self.n;
        jac.data.fill(0.0);
        for (i, frame) in frames.iter().enumerate().take(self.n) {
            let z = frame.rotation * self.axes[i].into_inner();
            let (lin, ang) = match self.kinds[i] {
                JointKind::Revolute => (z.cross(&(p_tip - frame.translation.vector)), z),
                JointKind::Prismatic => (z, Vector3::zeros()),
            };
            for r in 0..3 {
                jac.data[(r, i)] = lin[r];
                jac.data[(r + 3, i)] = ang[r];
            }
        }
        Ok(tip)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RobotModel;

    const TWO_LINK: &str = r#"<robot name="two">
      <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
      <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1"/></joint>
      <joint name="j2" type="prismatic"><parent link="b"/><child link="c"/>
        <origin xyz="1 0 0"/><axis xyz="1 0 0"/><limit lower="0" upper="0.5" velocity="0.2"/></joint>
      <joint name="f" type="fixed"><parent link="c"/><child link="d"/><origin xyz="0 0 0.1"/></joint>
    </robot>"#;

    #[test]
    fn revolute_then_prismatic() {
        let m = RobotModel::from_urdf_str(TWO_LINK, "two.urdf").unwrap();
        let c = m.chain("a", "d").unwrap();
        assert_eq!(c.n_joints(), 2);
        assert_eq!(
            c.joint_kinds(),
            &[JointKind::Revolute, JointKind::Prismatic]
        );
        let q = [std::f64::consts::FRAC_PI_2, 0.25];
        let t = c.fk(&q).unwrap();
        // Rotated 90° about z, the 1.25 m reach points along +y; the fixed offset along z.
        assert!((t.translation.vector - Vector3::new(0.0, 1.25, 0.1)).norm() < 1e-12);
        let mut j = Jacobian::zeros(0);
        let t2 = c.fk_jacobian(&q, &mut j).unwrap();
        assert_eq!(t, t2);
        assert_eq!(j.n_joints(), 2);
        // d p / d q1 = z x p = (-1.25, 0, 0); d p / d q2 = the rotated x axis = (0, 1, 0).
        assert!((j.get(0, 0) + 1.25).abs() < 1e-12);
        assert!((j.get(5, 0) - 1.0).abs() < 1e-12);
        assert!((j.get(1, 1) - 1.0).abs() < 1e-12);
        assert_eq!(j.get(5, 1), 0.0);
        assert_eq!(j.get(6, 0), 0.0);
        // Links along the chain.
        let names: Vec<&str> = c.link_names().collect();
        assert_eq!(names, ["a", "b", "c", "d"]);
        let b = c.link_pose(&q, c.link_id("b").unwrap()).unwrap();
        assert!(b.translation.vector.norm() < 1e-12);
        let cc = c.link_pose(&q, c.link_id("c").unwrap()).unwrap();
        assert!((cc.translation.vector - Vector3::new(0.0, 1.25, 0.0)).norm() < 1e-12);
        assert!(c.link_id("zz").is_none());
        // All link poses in one pass, and the joint axes.
        let mut poses = [Isometry3::identity(); 4];
        let mut axes = [JointAxis::UNUSED; MAX_DOF];
        c.link_poses(&q, &mut poses, &mut axes).unwrap();
        assert_eq!(c.n_links(), 4);
        for (i, name) in ["a", "b", "c", "d"].into_iter().enumerate() {
            let id = c.link_id(name).unwrap();
            assert_eq!(c.link_index(id), i);
            let want = c.link_pose(&q, id).unwrap();
            assert!((poses[i].translation.vector - want.translation.vector).norm() < 1e-12);
            assert!(poses[i].rotation.angle_to(&want.rotation) < 1e-12);
        }
        assert_eq!(c.joints_before(c.link_id("a").unwrap()), 0);
        assert_eq!(c.joints_before(c.link_id("b").unwrap()), 1);
        assert_eq!(c.joints_before(c.link_id("d").unwrap()), 2);
        // The axes make the Jacobian's linear rows for the tip.
        let tip = t.translation.vector;
        for (i, axis) in axes.iter().take(2).enumerate() {
            let v = axis.point_velocity(&tip);
            for r in 0..3 {
                assert!((v[r] - j.get(r, i)).abs() < 1e-12);
            }
        }
        assert_eq!(axes[1].kind, JointKind::Prismatic);
        assert_eq!(axes[2], JointAxis::UNUSED);
        // Fewer slots than links: the first ones are filled, the axes all the same.
        let mut two = [Isometry3::identity(); 2];
        let mut axes2 = [JointAxis::UNUSED; MAX_DOF];
        c.link_poses(&q, &mut two, &mut axes2).unwrap();
        assert_eq!(two[1], poses[1]);
        assert_eq!(axes2, axes);
        assert!(c.link_poses(&[0.0], &mut two, &mut axes2).is_err());
    }

    #[test]
    fn wrong_length_is_an_error() {
        let m = RobotModel::from_urdf_str(TWO_LINK, "two.urdf").unwrap();
        let c = m.chain("a", "d").unwrap();
        let e = c.fk(&[0.0]).unwrap_err();
        assert_eq!(
            e,
            KinError::Length {
                expected: 2,
                found: 1
            }
        );
        assert_eq!(
            e.to_string(),
            "1 joint values given for a chain of 2 movable joints"
        );
        let mut j = Jacobian::zeros(2);
        assert!(c.fk_jacobian(&[0.0; 3], &mut j).is_err());
    }

    #[test]
    fn limits_and_clamping() {
        let m = RobotModel::from_urdf_str(TWO_LINK, "two.urdf").unwrap();
        let c = m.chain("a", "d").unwrap();
        assert_eq!(c.lower(), &[-1.0, 0.0]);
        assert_eq!(c.upper(), &[1.0, 0.5]);
        assert_eq!(c.velocity_limits(), &[1.0, 0.2]);
        assert!(c.within_limits(&[0.0, 0.1]));
        assert!(!c.within_limits(&[0.0, 0.6]));
        let mut q = [2.0, -1.0];
        assert!(c.clamp_to_limits(&mut q));
        assert_eq!(q, [1.0, 0.0]);
        assert!(!c.clamp_to_limits(&mut q));
    }
}
