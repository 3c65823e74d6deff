//! The output of [`CollisionModel::clearance`](super::CollisionModel::clearance) and the rate
//! rows computed from it.

use nalgebra::{Isometry3, Point3, Vector3};

use super::MAX_ARM_JOINTS;
use super::{
    Capsule, CapsuleRef, CollisionLink, Contact, MAX_CAPSULES, MAX_PAIRS, PairId, Scene, Target,
    geometry,
};
use crate::chain::{JointAxis, JointKind, MAX_DOF};

/// The clearance of one joint state (see
/// [`CollisionModel::clearance`](super::CollisionModel::clearance)): fixed arrays on the stack
/// (about 10 kB), reused call after call.
#[derive(Debug, Clone, PartialEq)]
pub struct Clearance {
    pub(super) n: usize,
    pub(super) ids: [PairId; MAX_PAIRS],
    pub(super) distances_m: [f64; MAX_PAIRS],
    pub(super) closest: Option<Contact>,
    pub(super) n_capsules: usize,
    pub(super) capsules: [Capsule; MAX_CAPSULES],
    pub(super) refs: [CapsuleRef; MAX_CAPSULES],
    pub(super) link_poses: [Isometry3<f64>; CollisionLink::MAX],
    pub(super) link_moved_by: [u8; CollisionLink::MAX],
    pub(super) axes: [JointAxis; MAX_DOF],
    pub(super) n_joints: usize,
    pub(super) scene: Scene,
}

impl Default for Clearance {
    fn default() -> Self {
        let cref = CapsuleRef {
            link: CollisionLink::Base,
            index: 0,
        };
        let o = Point3::origin();
        Self {
            n: 0,
            ids: [PairId {
                a: cref,
                b: Target::Table,
            }; MAX_PAIRS],
            distances_m: [f64::INFINITY; MAX_PAIRS],
            closest: None,
            n_capsules: 0,
            capsules: [Capsule::new(o, o, 0.0); MAX_CAPSULES],
            refs: [cref; MAX_CAPSULES],
            link_poses: [Isometry3::identity(); CollisionLink::MAX],
            link_moved_by: [0; CollisionLink::MAX],
            axes: [JointAxis::UNUSED; MAX_DOF],
            n_joints: 0,
            scene: Scene::empty(),
        }
    }
}

impl Clearance {
    /// The closest pair of all, with its closest points; `None` before the first
    /// [`CollisionModel::clearance`](super::CollisionModel::clearance) (or with no pair to check).
    pub fn closest(&self) -> Option<&Contact> {
        self.closest.as_ref()
    }

    /// The smallest distance of all pairs (m); `+inf` when there is none.
    pub fn min_distance_m(&self) -> f64 {
        self.closest.map_or(f64::INFINITY, |c| c.distance_m)
    }

    /// Every pair's signed distance (m), in the order of [`Clearance::pairs`].
    pub fn distances_m(&self) -> &[f64] {
        &self.distances_m[..self.n]
    }

    /// Which pair each entry of [`Clearance::distances_m`] is.
    pub fn pairs(&self) -> &[PairId] {
        &self.ids[..self.n]
    }

    /// The capsules in the base frame at the state, in the order of
    /// [`CollisionModel::capsule_refs`](super::CollisionModel::capsule_refs).
    pub fn capsules(&self) -> &[Capsule] {
        &self.capsules[..self.n_capsules]
    }

    /// The pose of a link in the base frame at the state.
    pub fn link_pose(&self, link: CollisionLink) -> &Isometry3<f64> {
        &self.link_poses[link.index()]
    }

    /// The scene the clearance was computed in.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub(super) fn capsule(&self, r: CapsuleRef) -> Option<&Capsule> {
        self.refs[..self.n_capsules]
            .iter()
            .position(|x| *x == r)
            .map(|i| &self.capsules[i])
    }

    /// The closest points of pair `index` (an index into [`Clearance::distances_m`]).
    pub fn contact(&self, index: usize) -> Option<Contact> {
        if index >= self.n {
            return None;
        }
        let pair = self.ids[index];
        let a = self.capsule(pair.a)?;
        let p = match pair.b {
            Target::Capsule(b) => geometry::capsule_capsule(a, self.capsule(b)?),
            Target::Table => geometry::capsule_plane(a, self.scene.table_z_m()?),
            Target::Box(k) => geometry::capsule_box(a, self.scene.boxes().get(k as usize)?),
        };
        Some(Contact {
            pair,
            index,
            distance_m: p.distance_m,
            point_a: p.point_a,
            point_b: p.point_b,
            normal: p.normal,
            gradient: p.gradient,
        })
    }

    /// Number of arm joints of the model that computed this state: the used columns of
    /// [`Clearance::rate_row`], [`Clearance::point_jacobian`] and
    /// [`Clearance::angular_jacobian`] (the rest are zero).
    pub fn n_joints(&self) -> usize {
        self.n_joints
    }

    /// The row `g` with `d_dot = g · qdot` (m/s for `qdot` in rad/s, the arm joints) for a
    /// contact of this state: `g = nᵀ (J_a - J_b)`, `J_a` and `J_b` the translational
    /// Jacobians of the closest points as points of their links (zero for the scene), `n`
    /// the contact's gradient (its unit normal but deep in a box). The gripper is held
    /// still. `None` when the contact has no normal (deep overlap).
    ///
    /// Entry `j` is arm joint `j`, for the model's [`Clearance::n_joints`] joints (six on a
    /// Gen3 lite, seven on a Gen3); the entries beyond are zero, so `g · qdot` may take a
    /// `qdot` of just the arm's joints.
    ///
    /// Exact where the closest points move smoothly; where the closest pair of features
    /// switches (parallel segments, a capsule's axis level with the table) the distance has
    /// one-sided derivatives and this is one of them.
    pub fn rate_row(&self, contact: &Contact) -> Option<[f64; MAX_ARM_JOINTS]> {
        let g = contact.gradient?;
        let normal = contact.normal?;
        let mut row = [0.0; MAX_ARM_JOINTS];
        let mut add = |link: CollisionLink, p: &Point3<f64>, sign: f64| {
            let cols = self.point_jacobian(link, p);
            for (r, col) in row.iter_mut().zip(&cols).take(self.n_joints) {
                *r += sign * g.dot(col);
            }
        };
        // The velocities are those of the closest points of the capsules' axes (the surface
        // points less the radius along the normal): where the gradient is not the normal
        // (deep in a box) the surface point's own turning would add a spurious term.
        let a = self.capsule(contact.pair.a)?;
        add(
            contact.pair.a.link,
            &(contact.point_a + normal * a.radius_m),
            1.0,
        );
        if let Target::Capsule(b) = contact.pair.b {
            let cb = self.capsule(b)?;
            add(b.link, &(contact.point_b - normal * cb.radius_m), -1.0);
        }
        Some(row)
    }

    /// The translational Jacobian of the point `p` (base frame) moving with `link` at this
    /// state: column `j` is the point's velocity (m/s) per rad/s of arm joint `j`, zero for
    /// the joints that do not move the link (the gripper held still) and beyond the model's
    /// [`Clearance::n_joints`]. `J qdot` is the point's velocity. Allocation-free.
    pub fn point_jacobian(
        &self,
        link: CollisionLink,
        p: &Point3<f64>,
    ) -> [Vector3<f64>; MAX_ARM_JOINTS] {
        let mut cols = [Vector3::zeros(); MAX_ARM_JOINTS];
        let moved = usize::from(self.link_moved_by[link.index()]).min(self.n_joints);
        for (c, axis) in cols.iter_mut().zip(&self.axes).take(moved) {
            *c = axis.point_velocity(&p.coords);
        }
        cols
    }

    /// The angular Jacobian of `link` at this state: column `j` is the link's angular
    /// velocity (rad/s, base frame) per rad/s of arm joint `j` (the axis of a revolute joint
    /// that moves the link, else zero; zero beyond the model's [`Clearance::n_joints`]).
    pub fn angular_jacobian(&self, link: CollisionLink) -> [Vector3<f64>; MAX_ARM_JOINTS] {
        let mut cols = [Vector3::zeros(); MAX_ARM_JOINTS];
        let moved = usize::from(self.link_moved_by[link.index()]).min(self.n_joints);
        for (c, axis) in cols.iter_mut().zip(&self.axes).take(moved) {
            if axis.kind == JointKind::Revolute {
                *c = axis.direction;
            }
        }
        cols
    }

    /// [`Clearance::rate_row`] of the closest pair.
    pub fn closest_rate_row(&self) -> Option<[f64; MAX_ARM_JOINTS]> {
        self.rate_row(self.closest.as_ref()?)
    }
}
