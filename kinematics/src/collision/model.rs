//! The model at run time: its parts, and the clearance of a joint state.

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};

use super::{
    Capsule, CapsuleRef, Clearance, CollisionLink, Exclusion, MAX_CHAIN_LINKS, PairId, Scene,
    Target, geometry,
};
use crate::chain::{Chain, KinError};

/// Where a link's frame comes from.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Source {
    /// A link the model does not have (no capsules; its pose is the identity).
    Absent,
    /// A link along the arm chain, by index in [`Chain::link_names`].
    Chain(usize),
    /// A link hung from `parent` by one joint turned by the gripper (the gripper joint itself
    /// or one mimicking it): `angle = multiplier * gripper + offset`; a fixed joint has
    /// multiplier and offset 0.
    Joint {
        parent: Parent,
        origin: Isometry3<f64>,
        axis: Unit<Vector3<f64>>,
        multiplier: f64,
        offset: f64,
    },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Parent {
    Chain(usize),
    Link(usize),
}

#[derive(Debug, Clone, PartialEq)]
pub(super) struct LinkGeom {
    pub(super) source: Source,
    /// The first `moved_by` arm joints move this link.
    pub(super) moved_by: usize,
    /// Range of its capsules in the model's capsule list.
    pub(super) first: usize,
    pub(super) end: usize,
    pub(super) table: bool,
}

/// The collision model of an arm: see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionModel {
    pub(super) file: String,
    /// The links the model has, in index order.
    pub(super) present: Vec<CollisionLink>,
    /// The link the arm stands on.
    pub(super) base: CollisionLink,
    /// The link the tool is fixed to.
    pub(super) tool: CollisionLink,
    /// The gripper joint's range `(lower, upper)` (rad); `(0, 0)` without a gripper joint.
    pub(super) gripper_range: (f64, f64),
    pub(super) margin_m: f64,
    pub(super) gripper_default_rad: f64,
    pub(super) chain: Chain,
    pub(super) links: Vec<LinkGeom>,
    /// Capsules in their link frames, radius with the margin, link by link in
    /// index order (one entry per link index up to the model's last, absent ones empty).
    pub(super) capsules: Vec<Capsule>,
    pub(super) refs: Vec<CapsuleRef>,
    pub(super) self_pairs: Vec<(u16, u16)>,
    pub(super) self_ids: Vec<PairId>,
    pub(super) table_capsules: Vec<u16>,
    pub(super) exclusions: Vec<Exclusion>,
}

impl CollisionModel {
    /// The file the model was read from.
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The margin added to every radius (m).
    pub fn margin_m(&self) -> f64 {
        self.margin_m
    }

    /// The gripper joint's value used when [`CollisionModel::clearance`] is given the arm
    /// joints only (rad).
    pub fn gripper_default_rad(&self) -> f64 {
        self.gripper_default_rad
    }

    /// The gripper joint's range `(lower, upper)` in the robot description (rad); `(0, 0)`
    /// for a model without a gripper joint. Which end is open is the profile's
    /// ([`crate::Gripper`]); for the Gen3 lite the upper end is open.
    pub fn gripper_range(&self) -> (f64, f64) {
        self.gripper_range
    }

    /// The links the model has (with capsules), base to tip.
    pub fn links(&self) -> &[CollisionLink] {
        &self.present
    }

    /// The link the arm stands on ([`super::ModelArm::base_link`]): no joint moves it.
    pub fn base_link(&self) -> CollisionLink {
        self.base
    }

    /// The link the tool is fixed to ([`super::ModelArm::tool_link`]), the arm chain's tip.
    pub fn tool_link(&self) -> CollisionLink {
        self.tool
    }

    /// Whether the model has capsules on `link`.
    pub fn has_link(&self, link: CollisionLink) -> bool {
        self.present.contains(&link)
    }

    /// Number of arm joints the model's chain has (the length of `q` without the gripper).
    pub fn n_joints(&self) -> usize {
        self.chain.n_joints()
    }

    /// The capsules of a link in its own frame, margin included (none for a link the model
    /// does not have).
    pub fn link_capsules(&self, link: CollisionLink) -> &[Capsule] {
        self.links
            .get(link.index())
            .and_then(|l| self.capsules.get(l.first..l.end))
            .unwrap_or(&[])
    }

    /// Every capsule of the model, in the order of [`Clearance::capsules`].
    pub fn capsule_refs(&self) -> &[CapsuleRef] {
        &self.refs
    }

    /// Whether a link is checked against the table.
    pub fn checks_table(&self, link: CollisionLink) -> bool {
        self.links.get(link.index()).is_some_and(|l| l.table)
    }

    /// The capsule pairs checked against each other, in the order of the first entries of
    /// [`Clearance::distances_m`].
    pub fn self_pairs(&self) -> &[PairId] {
        &self.self_ids
    }

    /// The link pairs left unchecked, with the file's reasons.
    pub fn exclusions(&self) -> &[Exclusion] {
        &self.exclusions
    }

    /// Whether the pair of links is excluded from the self-collision check.
    pub fn is_excluded(&self, a: CollisionLink, b: CollisionLink) -> bool {
        self.exclusions
            .iter()
            .any(|x| (x.a == a && x.b == b) || (x.a == b && x.b == a))
    }

    /// The clearance of the arm at `q` in `scene`, written into `out`: every pair's signed
    /// distance (self pairs in [`CollisionModel::self_pairs`] order, then each capsule of a
    /// link checked against the table, then each capsule against box 0, box 1, ...), the
    /// closest pair with its closest points, and what [`Clearance::rate_row`] needs.
    /// Allocation-free.
    ///
    /// `q` holds the arm joints (rad; [`CollisionModel::n_joints`] of them, six on a Gen3
    /// lite), optionally followed by the gripper joint's value (rad, see
    /// [`CollisionModel::gripper_range`]); without it the gripper is at
    /// [`CollisionModel::gripper_default_rad`].
    pub fn clearance(&self, q: &[f64], scene: &Scene, out: &mut Clearance) -> Result<(), KinError> {
        let n_joints = self.chain.n_joints();
        let (arm_q, gripper) = match q.len() {
            n if n == n_joints => (q, self.gripper_default_rad),
            n if n == n_joints + 1 => (&q[..n_joints], q[n_joints]),
            n => {
                return Err(KinError::Length {
                    expected: n_joints,
                    found: n,
                });
            }
        };
        if let Some(index) = q.iter().position(|v| !v.is_finite()) {
            return Err(KinError::NonFinite {
                what: "joint vector",
                index,
            });
        }
        let mut chain_poses = [Isometry3::identity(); MAX_CHAIN_LINKS];
        self.chain
            .link_poses(arm_q, &mut chain_poses, &mut out.axes)?;
        for (k, l) in self.links.iter().enumerate() {
            let pose = match &l.source {
                Source::Absent => Isometry3::identity(),
                Source::Chain(i) => chain_poses[*i],
                Source::Joint {
                    parent,
                    origin,
                    axis,
                    multiplier,
                    offset,
                } => {
                    let parent_pose = match parent {
                        Parent::Chain(i) => chain_poses[*i],
                        Parent::Link(j) => out.link_poses[*j],
                    };
                    let turn = UnitQuaternion::from_axis_angle(axis, multiplier * gripper + offset);
                    parent_pose * origin * Isometry3::from_parts(Translation3::identity(), turn)
                }
            };
            out.link_poses[k] = pose;
            out.link_moved_by[k] = l.moved_by as u8;
            for c in l.first..l.end {
                let local = &self.capsules[c];
                out.capsules[c] = Capsule::new(pose * local.a, pose * local.b, local.radius_m);
            }
        }
        out.n_capsules = self.capsules.len();
        out.n_joints = n_joints;
        out.refs[..self.refs.len()].copy_from_slice(&self.refs);
        out.scene = *scene;

        let mut n = 0;
        let mut best = (f64::INFINITY, 0);
        let mut record = |out: &mut Clearance, id: PairId, d: f64| {
            out.ids[n] = id;
            out.distances_m[n] = d;
            if d < best.0 {
                best = (d, n);
            }
            n += 1;
        };
        for (&(a, b), id) in self.self_pairs.iter().zip(&self.self_ids) {
            let d = geometry::capsule_capsule(&out.capsules[a as usize], &out.capsules[b as usize]);
            record(out, *id, d.distance_m);
        }
        if let Some(z) = scene.table_z_m() {
            for &c in &self.table_capsules {
                let d = geometry::capsule_plane(&out.capsules[c as usize], z);
                let id = PairId {
                    a: self.refs[c as usize],
                    b: Target::Table,
                };
                record(out, id, d.distance_m);
            }
        }
        for (k, bx) in scene.boxes().iter().enumerate() {
            for c in 0..self.capsules.len() {
                let d = geometry::capsule_box(&out.capsules[c], bx);
                let id = PairId {
                    a: self.refs[c],
                    b: Target::Box(k as u8),
                };
                record(out, id, d.distance_m);
            }
        }
        out.n = n;
        out.closest = if n == 0 { None } else { out.contact(best.1) };
        Ok(())
    }
}
