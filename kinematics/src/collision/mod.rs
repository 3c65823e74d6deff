//! Collision models: capsules on every link, the pairs that can touch, a scene (table and
//! boxes), and the clearance of a joint state with the rate at which it changes. The Gen3
//! lite's is [`CollisionModel::get`]; the Gen3's is [`crate::gen3::collision_model`]; a
//! profile gives its arm's ([`crate::RobotProfile::collision_model`]). Another arm's model is
//! read with [`CollisionModel::for_arm`]: its links are the file's, by their URDF names.
//!
//! * The geometry is data: `robots/gen3_lite_collision.toml` (embedded, [`COLLISION_TOML`]),
//!   one or two capsules per link in the link's own frame, each with the reference fit it
//!   comes from; a margin is added to every radius at load. [`CollisionModel::load`] reads and
//!   checks it against the embedded URDF (errors name the file, the link and the field);
//!   [`CollisionModel::from_file`] reads a user's file of the same form.
//! * The pairs are built at load: every capsule against every capsule of another link,
//!   except the link pairs the file excludes (adjacent links, and those Kinova's MoveIt
//!   configuration marks as never colliding; each exclusion carries its reason).
//! * [`CollisionModel::clearance`] computes, for joint angles `q` (the arm joints, six on
//!   a Gen3 lite and seven on a Gen3, and the gripper joint if known) and a [`Scene`], every
//!   pair's exact signed distance (self pairs, then each link against the table, then
//!   against each box), the closest pair with its closest points, into a caller-owned
//!   [`Clearance`]: fixed arrays, no allocation. The
//!   base is not checked against the table: it stands on it by design (nor is the shoulder,
//!   which joint 1 only turns about the vertical: its height above the table is fixed).
//! * [`Clearance::rate_row`] gives the row `g` with `d_dot = g · qdot` for a pair's distance
//!   (one entry per arm joint of the model, zeros up to [`MAX_ARM_JOINTS`]):
//!   `g = nᵀ (J_a - J_b)`, `n` the unit normal between the closest points (for a capsule deep
//!   in a box where two faces are equally near, the weighted mix of their normals that is the
//!   depth's exact gradient) and `J` the translational Jacobians of those points as points of
//!   their links (zero for the scene's point).
//!
//! ```
//! use kinematics::collision::{CollisionModel, Clearance, Scene};
//! use kinematics::gen3_lite;
//!
//! let model = CollisionModel::get();
//! let mut out = Clearance::default();
//! model.clearance(&gen3_lite::HOME, &Scene::default(), &mut out).unwrap();
//! let closest = out.closest().unwrap();
//! assert!(closest.distance_m > 0.0, "{}", closest.pair);
//! let g = out.rate_row(closest).unwrap();
//! let qdot = [0.1, 0.0, 0.0, 0.0, 0.0, 0.0];
//! let d_dot: f64 = g.iter().zip(qdot).map(|(g, v)| g * v).sum();
//! assert!(d_dot.is_finite());
//! ```

mod clearance;
pub mod geometry;
mod load;
mod model;
pub mod scene;

use std::fmt;

use nalgebra::{Point3, Vector3};

pub use clearance::Clearance;
pub use geometry::{Aabb, Capsule, Proximity};
pub use load::{CollisionError, ModelArm};
pub use model::CollisionModel;
pub use scene::{MAX_BOXES, Scene, SceneError};

/// The collision model, `robots/gen3_lite_collision.toml`, embedded at build time.
pub const COLLISION_TOML: &str = include_str!("../../../robots/gen3_lite_collision.toml");

/// How the embedded collision model is named in messages.
pub const COLLISION_TOML_NAME: &str = "robots/gen3_lite_collision.toml";

/// The version of the file format this crate reads.
pub const FILE_VERSION: u32 = 1;

/// Most capsules a model may have.
pub const MAX_CAPSULES: usize = 32;

/// Most arm joints a model may have: the width of the rate rows and point Jacobians of a
/// [`Clearance`] (the model's own [`Clearance::n_joints`] columns, then zeros). Every arm a
/// [`crate::chain::Chain`] can hold fits.
pub const MAX_ARM_JOINTS: usize = crate::chain::MAX_DOF;

/// Most capsule pairs a model may check against each other.
pub const MAX_SELF_PAIRS: usize = 256;

/// Most pairs a [`Clearance`] holds: the self pairs, and every capsule against the table and
/// each box.
pub const MAX_PAIRS: usize = MAX_SELF_PAIRS + MAX_CAPSULES * (1 + MAX_BOXES);

/// Most links along the arm chain ([`ModelArm::base_link`] to [`ModelArm::tool_link`]).
pub(super) const MAX_CHAIN_LINKS: usize = 16;

/// A link that has collision geometry, by its URDF name: an index into this process's table
/// of link names. The table starts with the Gen3 lite's links, base to fingertips, then the
/// Gen3's own (the constants below, so the codes in recorded messages keep their meaning);
/// loading a model adds the names of its file's other links ([`CollisionLink::intern`]), so
/// a new arm's links need no code. A model has the links its file names
/// ([`CollisionModel::links`]).
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CollisionLink(u8);

/// The link names the table starts with, in index order.
const KNOWN_LINKS: [&str; 16] = [
    "base_link",
    "shoulder_link",
    "arm_link",
    "forearm_link",
    "lower_wrist_link",
    "upper_wrist_link",
    "gripper_base_link",
    "right_finger_prox_link",
    "right_finger_dist_link",
    "left_finger_prox_link",
    "left_finger_dist_link",
    "half_arm_1_link",
    "half_arm_2_link",
    "spherical_wrist_1_link",
    "spherical_wrist_2_link",
    "bracelet_link",
];

/// The process's link names: [`KNOWN_LINKS`], then the names models added. Names are only
/// added, never removed, so an index keeps its name for the life of the process.
fn link_table() -> &'static std::sync::RwLock<Vec<&'static str>> {
    static TABLE: std::sync::OnceLock<std::sync::RwLock<Vec<&'static str>>> =
        std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::sync::RwLock::new(KNOWN_LINKS.to_vec()))
}

#[allow(non_upper_case_globals)]
impl CollisionLink {
    /// `base_link`: fixed on the table.
    pub const Base: Self = Self(0);
    /// `shoulder_link`: turned by joint 1.
    pub const Shoulder: Self = Self(1);
    /// `arm_link` (Gen3 lite), the upper arm: joint 2.
    pub const Arm: Self = Self(2);
    /// `forearm_link`: joint 3 (Gen3 lite), 4 (Gen3).
    pub const Forearm: Self = Self(3);
    /// `lower_wrist_link` (Gen3 lite): joint 4.
    pub const LowerWrist: Self = Self(4);
    /// `upper_wrist_link` (Gen3 lite): joint 5.
    pub const UpperWrist: Self = Self(5);
    /// `gripper_base_link`: fixed to the flange.
    pub const GripperBase: Self = Self(6);
    /// `right_finger_prox_link` (Gen3 lite): the actuated finger joint.
    pub const RightFingerProx: Self = Self(7);
    /// `right_finger_dist_link` (Gen3 lite).
    pub const RightFingerDist: Self = Self(8);
    /// `left_finger_prox_link` (Gen3 lite).
    pub const LeftFingerProx: Self = Self(9);
    /// `left_finger_dist_link` (Gen3 lite).
    pub const LeftFingerDist: Self = Self(10);
    /// `half_arm_1_link` (Gen3): joint 2.
    pub const HalfArm1: Self = Self(11);
    /// `half_arm_2_link` (Gen3): joint 3.
    pub const HalfArm2: Self = Self(12);
    /// `spherical_wrist_1_link` (Gen3): joint 5.
    pub const SphericalWrist1: Self = Self(13);
    /// `spherical_wrist_2_link` (Gen3): joint 6.
    pub const SphericalWrist2: Self = Self(14);
    /// `bracelet_link` (Gen3): joint 7, the flange's actuator.
    pub const Bracelet: Self = Self(15);

    /// The Gen3 lite's links, parents before children (what a Gen3 lite model has; a model's
    /// own links are [`CollisionModel::links`]).
    pub const ALL: [CollisionLink; 11] = [
        CollisionLink::Base,
        CollisionLink::Shoulder,
        CollisionLink::Arm,
        CollisionLink::Forearm,
        CollisionLink::LowerWrist,
        CollisionLink::UpperWrist,
        CollisionLink::GripperBase,
        CollisionLink::RightFingerProx,
        CollisionLink::RightFingerDist,
        CollisionLink::LeftFingerProx,
        CollisionLink::LeftFingerDist,
    ];

    /// Most links the process's table holds: the size of the per-link arrays of a
    /// [`Clearance`] (a link's index is the high byte of a [`CapsuleRef::code`], below the
    /// scene's codes).
    pub const MAX: usize = 64;

    /// The URDF name.
    pub fn name(self) -> &'static str {
        link_table()
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get(self.index())
            .copied()
            .unwrap_or("(unknown link)")
    }

    /// The link with this URDF name, if the table has it.
    pub fn from_name(name: &str) -> Option<Self> {
        let table = link_table()
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let i = table.iter().position(|n| *n == name)?;
        u8::try_from(i).ok().map(Self)
    }

    /// The link with this URDF name, added to the table if it is new; `None` when the table
    /// is full ([`CollisionLink::MAX`] names).
    pub fn intern(name: &str) -> Option<Self> {
        if let Some(l) = Self::from_name(name) {
            return Some(l);
        }
        let mut table = link_table()
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(i) = table.iter().position(|n| *n == name) {
            return u8::try_from(i).ok().map(Self);
        }
        if table.len() >= Self::MAX {
            return None;
        }
        // Leaked once per distinct name: the table only grows, by the links of the models
        // the process loads.
        table.push(Box::leak(name.to_owned().into_boxed_str()));
        u8::try_from(table.len() - 1).ok().map(Self)
    }

    /// The link of this index, if the table has it.
    pub fn from_index(index: usize) -> Option<Self> {
        let len = link_table()
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .len();
        (index < len).then(|| u8::try_from(index).ok().map(Self))?
    }

    /// Its index in the process's table of link names.
    pub fn index(self) -> usize {
        usize::from(self.0)
    }

    /// The name without `_link`, for status lines: `forearm`, `gripper_base`.
    pub fn short_name(self) -> &'static str {
        let n = self.name();
        n.strip_suffix("_link").unwrap_or(n)
    }
}

impl fmt::Debug for CollisionLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "CollisionLink({})", self.name())
    }
}

impl fmt::Display for CollisionLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One capsule of the model: its link and its position among that link's capsules.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CapsuleRef {
    /// The link.
    pub link: CollisionLink,
    /// Index among the link's capsules (file order).
    pub index: u8,
}

/// Compact codes of a pair's sides, for fixed-size messages (a `[u16; 2]` per pair, see
/// [`PairId::code`]): a capsule is `link index << 8 | capsule index`.
pub mod side_code {
    /// The scene's table.
    pub const TABLE: u16 = 0xFF00;
    /// The scene's box `k` is `BOX | k`.
    pub const BOX: u16 = 0xFE00;
    /// No pair (nothing was checked).
    pub const NONE: u16 = 0xFFFF;
}

impl CapsuleRef {
    /// The side's code: `link index << 8 | capsule index`.
    pub fn code(self) -> u16 {
        ((self.link.index() as u16) << 8) | u16::from(self.index)
    }

    /// The capsule of a [`CapsuleRef::code`].
    pub fn from_code(code: u16) -> Option<Self> {
        let link = CollisionLink::from_index(usize::from(code >> 8))?;
        Some(Self {
            link,
            index: (code & 0xFF) as u8,
        })
    }
}

impl Target {
    /// The side's code: a capsule's [`CapsuleRef::code`], [`side_code::TABLE`], or
    /// [`side_code::BOX`] plus the box's index.
    pub fn code(self) -> u16 {
        match self {
            Target::Capsule(c) => c.code(),
            Target::Table => side_code::TABLE,
            Target::Box(k) => side_code::BOX | u16::from(k),
        }
    }

    /// The target of a [`Target::code`]; `None` for [`side_code::NONE`] or an unknown code.
    pub fn from_code(code: u16) -> Option<Self> {
        match code {
            side_code::NONE => None,
            side_code::TABLE => Some(Target::Table),
            c if c & 0xFF00 == side_code::BOX => Some(Target::Box((c & 0xFF) as u8)),
            c => CapsuleRef::from_code(c).map(Target::Capsule),
        }
    }
}

impl fmt::Display for CapsuleRef {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}[{}]", self.link, self.index)
    }
}

/// What a capsule is checked against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Target {
    /// A capsule of another link.
    Capsule(CapsuleRef),
    /// The scene's table.
    Table,
    /// The scene's box of this index ([`Scene::boxes`]).
    Box(u8),
}

/// A checked pair: a capsule of the arm and what it must keep clear of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PairId {
    /// The arm's capsule (for a self pair, the one nearer the base).
    pub a: CapsuleRef,
    /// The other side.
    pub b: Target,
}

impl PairId {
    /// Whether the two sides are links `x` and `y` (in either order; a scene target never
    /// matches).
    pub fn is_links(&self, x: CollisionLink, y: CollisionLink) -> bool {
        match self.b {
            Target::Capsule(b) => {
                (self.a.link == x && b.link == y) || (self.a.link == y && b.link == x)
            }
            _ => false,
        }
    }
}

impl PairId {
    /// Both sides' codes ([`CapsuleRef::code`], [`Target::code`]), for messages.
    pub fn code(&self) -> [u16; 2] {
        [self.a.code(), self.b.code()]
    }

    /// The pair of a [`PairId::code`]; `None` for `[NONE, NONE]` or an unknown code.
    pub fn from_code(code: [u16; 2]) -> Option<Self> {
        let a = CapsuleRef::from_code(code[0])?;
        Some(Self {
            a,
            b: Target::from_code(code[1])?,
        })
    }
}

impl fmt::Display for PairId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.b {
            Target::Capsule(b) => write!(f, "{} / {b}", self.a),
            Target::Table => write!(f, "{} / table", self.a),
            Target::Box(k) => write!(f, "{} / box {k}", self.a),
        }
    }
}

/// A pair with its distance and closest points at one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Which pair.
    pub pair: PairId,
    /// Its index in [`Clearance::distances_m`].
    pub index: usize,
    /// Signed distance (m): the gap, negative when the shapes overlap.
    pub distance_m: f64,
    /// Closest point of `pair.a` (base frame).
    pub point_a: Point3<f64>,
    /// Closest point of `pair.b` (base frame).
    pub point_b: Point3<f64>,
    /// Unit vector from `point_b` towards `point_a`: moving `a` along it opens the gap.
    /// `None` when undefined (the axes of two capsules cross: deep overlap).
    pub normal: Option<Vector3<f64>>,
    /// `d_dot = gradient · (v_a - v_b)` for the velocities of the closest points as points
    /// of their bodies: `normal`, except for a capsule deep in a box (see
    /// [`geometry::Proximity::gradient`]).
    pub gradient: Option<Vector3<f64>>,
}

/// A link pair the file leaves unchecked, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Exclusion {
    /// One link.
    pub a: CollisionLink,
    /// The other.
    pub b: CollisionLink,
    /// The file's reason.
    pub why: String,
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_model_loads() {
        let m = CollisionModel::load().unwrap();
        assert_eq!(m.file(), COLLISION_TOML_NAME);
        assert_eq!(m.margin_m(), 0.005);
        assert_eq!(m.capsule_refs().len(), 15);
        assert_eq!(m.exclusions().len(), 34);
        assert_eq!(m.self_pairs().len(), 42);
        assert!(!m.checks_table(CollisionLink::Base));
        assert!(m.checks_table(CollisionLink::Forearm));
        let c = m.link_capsules(CollisionLink::Shoulder);
        assert_eq!(c.len(), 1);
        assert!((c[0].radius_m - (0.0447 + 0.005)).abs() < 1e-15);
        for link in CollisionLink::ALL {
            assert_eq!(CollisionLink::from_name(link.name()), Some(link));
        }
        assert_eq!(CollisionLink::UpperWrist.short_name(), "upper_wrist");
        // Every pair's code names it back.
        let mut out = Clearance::default();
        let mut scene = Scene::default();
        scene
            .add_box(Point3::new(0.3, 0.3, 0.0), Point3::new(0.5, 0.5, 0.2))
            .unwrap();
        m.clearance(&crate::gen3_lite::HOME, &scene, &mut out)
            .unwrap();
        for p in out.pairs() {
            assert_eq!(PairId::from_code(p.code()), Some(*p), "{p}");
        }
        assert_eq!(PairId::from_code([side_code::NONE; 2]), None);
    }
}
