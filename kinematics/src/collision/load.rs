//! Reading and checking a collision model file, and building the model on a robot
//! description: the link frames, the capsules with the margin, the pairs.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use nalgebra::Point3;
use serde::Deserialize;

use super::model::{LinkGeom, Parent, Source};
use super::{
    COLLISION_TOML, COLLISION_TOML_NAME, Capsule, CapsuleRef, CollisionLink, CollisionModel,
    Exclusion, FILE_VERSION, MAX_CAPSULES, MAX_CHAIN_LINKS, MAX_SELF_PAIRS, PairId, Target,
};
use crate::chain::Chain;
use crate::gen3_lite;
use crate::robot::{JointType, RobotModel, UrdfError};

/// Why a collision model could not be loaded. Every message starts with the file.
#[derive(Debug, thiserror::Error)]
pub enum CollisionError {
    /// The file could not be read.
    #[error("{path}: cannot read the collision model: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not TOML, or not of the expected form (a missing or unknown key, a wrong type).
    #[error("{file}: {reason}")]
    Parse {
        /// The file.
        file: String,
        /// The TOML reader's message (with line and column).
        reason: String,
    },
    /// A format version this crate does not read.
    #[error("{file}: version = {found}: this build reads version {FILE_VERSION}")]
    Version {
        /// The file.
        file: String,
        /// The version in the file.
        found: u32,
    },
    /// A link name that is not one of the arm's links with geometry.
    #[error("{file}: {field}: `{name}` is not a link of {arm} with geometry (links: {known})")]
    UnknownLink {
        /// The arm (`the Gen3 lite`).
        arm: Box<str>,
        /// The file.
        file: String,
        /// Where the name is (`link[3].name`, `exclude[2].links`).
        field: String,
        /// The name given.
        name: String,
        /// The known names, comma-separated.
        known: String,
    },
    /// A link is listed twice, or not at all, or with no capsule.
    #[error("{file}: link `{link}`: {reason}")]
    Link {
        /// The file.
        file: String,
        /// The link.
        link: String,
        /// What is wrong.
        reason: String,
    },
    /// A value is out of range: a radius that is not positive and finite, a coordinate that
    /// is not finite or implausibly large, a negative margin.
    #[error("{file}: link `{link}`: {field} = {value}: {reason}")]
    Value {
        /// The file.
        file: String,
        /// The link (`(file)` for a top-level key).
        link: String,
        /// The field, e.g. `capsule[1].radius_m`.
        field: String,
        /// The value given.
        value: String,
        /// What is wrong.
        reason: String,
    },
    /// An `[[exclude]]` entry is unusable.
    #[error("{file}: exclude[{index}]: {reason}")]
    Exclusion {
        /// The file.
        file: String,
        /// Its position among the `[[exclude]]` entries.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// More capsules or pairs than the fixed capacity.
    #[error("{file}: {reason}")]
    Capacity {
        /// The file.
        file: String,
        /// What is over capacity.
        reason: String,
    },
    /// The robot description does not fit the collision model (a link missing, a finger
    /// joint that is neither the gripper joint nor mimics it).
    #[error("{file}: {reason}")]
    Robot {
        /// The robot description.
        file: String,
        /// What does not fit.
        reason: String,
    },
    /// The robot description itself did not load.
    #[error(transparent)]
    Urdf(#[from] UrdfError),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileToml {
    version: u32,
    margin_m: f64,
    gripper_default_rad: f64,
    link: Vec<LinkToml>,
    #[serde(default)]
    exclude: Vec<ExcludeToml>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LinkToml {
    name: String,
    #[serde(default = "yes")]
    table: bool,
    #[serde(default)]
    capsule: Vec<CapsuleToml>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CapsuleToml {
    a: [f64; 3],
    b: [f64; 3],
    radius_m: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExcludeToml {
    links: [String; 2],
    why: String,
}

/// Largest plausible capsule coordinate in a link frame (m): a larger one is a unit mistake.
const MAX_COORDINATE_M: f64 = 2.0;

static MODEL: OnceLock<CollisionModel> = OnceLock::new();

/// The facts of the arm a collision model is read for, beside its robot description.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelArm<'a> {
    /// How messages name the arm (`the Gen3 lite`).
    pub name: &'a str,
    /// The joints of the chain [`ModelArm::base_link`] -> [`ModelArm::tool_link`], base to
    /// tip.
    pub joint_names: &'a [&'a str],
    /// The link the arm stands on (the chain's root; no joint moves it).
    pub base_link: &'a str,
    /// The link the tool is fixed to (the chain's tip: the gripper's base on the flange).
    /// It needs capsules; safety's tool speed cap follows it.
    pub tool_link: &'a str,
    /// The gripper joint that moves the finger links (their joints are it or mimic it), if
    /// the model has finger links.
    pub gripper_joint: Option<&'a str>,
}

impl ModelArm<'static> {
    /// The Gen3 lite with its 2-finger gripper.
    pub const GEN3_LITE: ModelArm<'static> = ModelArm {
        name: "the Gen3 lite",
        joint_names: &gen3_lite::JOINT_NAMES,
        base_link: gen3_lite::BASE_LINK,
        tool_link: "gripper_base_link",
        gripper_joint: Some(gen3_lite::GRIPPER_JOINT),
    };
}

impl CollisionModel {
    /// The embedded model ([`COLLISION_TOML`]) on the embedded URDF.
    pub fn load() -> Result<Self, CollisionError> {
        Self::from_toml_str(
            COLLISION_TOML,
            COLLISION_TOML_NAME,
            gen3_lite::Gen3Lite::get().model(),
        )
    }

    /// The embedded model, loaded once per process.
    ///
    /// # Panics
    ///
    /// If the embedded `robots/gen3_lite_collision.toml` does not load, a build defect that
    /// the crate's tests catch (`the_embedded_model_loads`).
    pub fn get() -> &'static CollisionModel {
        MODEL.get_or_init(|| match Self::load() {
            Ok(m) => m,
            Err(e) => panic!("the embedded Gen3 lite collision model is broken: {e}"),
        })
    }

    /// Reads a collision model file of the same form as the embedded one, on the embedded
    /// URDF.
    pub fn from_file(path: &Path) -> Result<Self, CollisionError> {
        let text = std::fs::read_to_string(path).map_err(|source| CollisionError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_toml_str(
            &text,
            &path.display().to_string(),
            gen3_lite::Gen3Lite::get().model(),
        )
    }

    /// Parses and checks a collision model (`file` names it in errors) for the links of
    /// `robot`, a Gen3 lite description.
    pub fn from_toml_str(
        text: &str,
        file: &str,
        robot: &RobotModel,
    ) -> Result<Self, CollisionError> {
        Self::for_arm(text, file, robot, &ModelArm::GEN3_LITE)
    }

    /// Parses and checks a collision model (`file` names it in errors) for `arm`, whose
    /// description is `robot`: the file's links must be links of `robot` (their names join
    /// the process's table, [`CollisionLink::intern`]), and every link of the arm chain
    /// ([`ModelArm::base_link`] to [`ModelArm::tool_link`]) needs capsules.
    pub fn for_arm(
        text: &str,
        file: &str,
        robot: &RobotModel,
        arm: &ModelArm<'_>,
    ) -> Result<Self, CollisionError> {
        let load = Loader { file, robot, arm };
        let parsed = load.parse(text)?;
        let chain = load.arm_chain()?;
        let (file_links, own) = load.intern_links(&parsed)?;
        let by_link = load.check_links(&parsed, &file_links)?;
        load.check_bodies(&chain, &own, &by_link)?;
        let (base_name, tip_name) = (arm.base_link, arm.tool_link);
        let (Some(base), Some(tool)) = (find(&own, base_name), find(&own, tip_name)) else {
            return Err(load.robot_err(format!("{base_name} and {tip_name} need capsules")));
        };
        let n_capsules: usize = parsed.link.iter().map(|l| l.capsule.len()).sum();
        if n_capsules > MAX_CAPSULES {
            return Err(CollisionError::Capacity {
                file: file.to_owned(),
                reason: format!("{n_capsules} capsules; a model holds at most {MAX_CAPSULES}"),
            });
        }
        let exclusions = load.exclusions(&parsed, &own)?;
        let geometry = load.geometry(&parsed, &chain, &own, &by_link, n_capsules)?;
        let (self_pairs, self_ids) = load.self_pairs(&own, &geometry, &exclusions)?;
        let Geometry {
            links,
            capsules,
            refs,
        } = geometry;
        let table_capsules = links
            .iter()
            .filter(|l| l.table)
            .flat_map(|l| (l.first..l.end).map(|c| c as u16))
            .collect();
        let gripper_range = arm
            .gripper_joint
            .and_then(|g| robot.joint(g))
            .map_or((0.0, 0.0), |j| (j.lower, j.upper));
        Ok(Self {
            file: file.to_owned(),
            present: own,
            base,
            tool,
            gripper_range,
            margin_m: parsed.margin_m,
            gripper_default_rad: parsed.gripper_default_rad,
            chain,
            links,
            capsules,
            refs,
            self_pairs,
            self_ids,
            table_capsules,
            exclusions,
        })
    }
}

/// The model's link `name`, if the file gives it capsules (`own`: the model's links).
fn find(own: &[CollisionLink], name: &str) -> Option<CollisionLink> {
    CollisionLink::from_name(name).filter(|l| own.contains(l))
}

/// Whether the pair `a` / `b` (either way round) is excluded.
fn is_excluded(exclusions: &[Exclusion], a: CollisionLink, b: CollisionLink) -> bool {
    exclusions
        .iter()
        .any(|x| (x.a == a && x.b == b) || (x.a == b && x.b == a))
}

/// The capsule pairs of the arm to check (indices into the capsules) and their names.
type SelfPairs = (Vec<(u16, u16)>, Vec<PairId>);

/// The links, capsules (margin included) and capsule names of a model, in link index order.
struct Geometry {
    links: Vec<LinkGeom>,
    capsules: Vec<Capsule>,
    refs: Vec<CapsuleRef>,
}

/// What [`CollisionModel::for_arm`] reads a file against, and names in its errors: the
/// file, the robot description and the arm.
struct Loader<'a> {
    file: &'a str,
    robot: &'a RobotModel,
    arm: &'a ModelArm<'a>,
}

impl Loader<'_> {
    /// A field of the file (of `link`, or `(file)`) with a bad value.
    fn value(&self, link: &str, field: &str, v: String, reason: &str) -> CollisionError {
        CollisionError::Value {
            file: self.file.to_owned(),
            link: link.to_owned(),
            field: field.to_owned(),
            value: v,
            reason: reason.to_owned(),
        }
    }

    /// The robot description does not fit the arm.
    fn robot_err(&self, reason: String) -> CollisionError {
        CollisionError::Robot {
            file: self.robot.file().to_owned(),
            reason,
        }
    }

    /// The robot description's links, for an unknown-link error.
    fn known(&self) -> String {
        self.robot.links().join(", ")
    }

    /// Parses the file and checks its version, margin and default gripper angle.
    fn parse(&self, text: &str) -> Result<FileToml, CollisionError> {
        let file = self.file;
        let parsed: FileToml = toml::from_str(text).map_err(|e| CollisionError::Parse {
            file: file.to_owned(),
            reason: e.to_string().trim_end().to_owned(),
        })?;
        if parsed.version != FILE_VERSION {
            return Err(CollisionError::Version {
                file: file.to_owned(),
                found: parsed.version,
            });
        }
        if !(parsed.margin_m.is_finite() && (0.0..=0.1).contains(&parsed.margin_m)) {
            return Err(self.value(
                "(file)",
                "margin_m",
                parsed.margin_m.to_string(),
                "the margin must be a finite number of metres in [0, 0.1]",
            ));
        }
        if !parsed.gripper_default_rad.is_finite() {
            return Err(self.value(
                "(file)",
                "gripper_default_rad",
                parsed.gripper_default_rad.to_string(),
                "must be a finite angle (rad)",
            ));
        }
        Ok(parsed)
    }

    /// Kinematics: the arm chain to the tool link (the other links hang from it), checked
    /// against the arm's joints and the supported length.
    fn arm_chain(&self) -> Result<Chain, CollisionError> {
        let (robot, arm) = (self.robot, self.arm);
        let chain = robot.chain(arm.base_link, arm.tool_link)?;
        let (base_name, tip_name) = (arm.base_link, arm.tool_link);
        if chain.joint_names() != arm.joint_names {
            return Err(self.robot_err(format!(
                "the chain {base_name} -> {tip_name} has the joints {:?}; {} has {:?}",
                chain.joint_names(),
                arm.name,
                arm.joint_names
            )));
        }
        if chain.n_links() > MAX_CHAIN_LINKS {
            return Err(self.robot_err(format!(
                "the chain {base_name} -> {tip_name} has {} links; at most {MAX_CHAIN_LINKS} are supported",
                chain.n_links()
            )));
        }
        Ok(chain)
    }

    /// The file's links: links of the robot description, by name. Returns each `[[link]]`'s
    /// link, in file order, and the model's links, in index order.
    fn intern_links(
        &self,
        parsed: &FileToml,
    ) -> Result<(Vec<CollisionLink>, Vec<CollisionLink>), CollisionError> {
        let file = self.file;
        let mut file_links: Vec<CollisionLink> = Vec::with_capacity(parsed.link.len());
        let mut own: Vec<CollisionLink> = Vec::with_capacity(parsed.link.len());
        for (i, l) in parsed.link.iter().enumerate() {
            if !self.robot.links().contains(&l.name) {
                return Err(CollisionError::UnknownLink {
                    arm: self.arm.name.into(),
                    file: file.to_owned(),
                    field: format!("link[{i}].name"),
                    name: l.name.clone(),
                    known: self.known(),
                });
            }
            let link = CollisionLink::intern(&l.name).ok_or_else(|| CollisionError::Capacity {
                file: file.to_owned(),
                reason: format!(
                    "link `{}`: the process knows {} link names already, the most it holds",
                    l.name,
                    CollisionLink::MAX
                ),
            })?;
            file_links.push(link);
            if !own.contains(&link) {
                own.push(link);
            }
        }
        own.sort();
        Ok((file_links, own))
    }

    /// Links: each at most once, with at least one capsule, every capsule finite and within
    /// reach. Returns the `[[link]]` index of each link (by link index).
    fn check_links(
        &self,
        parsed: &FileToml,
        file_links: &[CollisionLink],
    ) -> Result<Vec<Option<usize>>, CollisionError> {
        let file = self.file;
        let mut by_link = vec![None; CollisionLink::MAX];
        for (i, (l, link)) in parsed.link.iter().zip(file_links).enumerate() {
            if by_link[link.index()].is_some() {
                return Err(CollisionError::Link {
                    file: file.to_owned(),
                    link: l.name.clone(),
                    reason: "listed twice; give all its capsules under one [[link]]".into(),
                });
            }
            if l.capsule.is_empty() {
                return Err(CollisionError::Link {
                    file: file.to_owned(),
                    link: l.name.clone(),
                    reason: "has no [[link.capsule]]; every link needs at least one".into(),
                });
            }
            for (k, c) in l.capsule.iter().enumerate() {
                self.check_capsule(&l.name, k, c)?;
            }
            by_link[link.index()] = Some(i);
        }
        Ok(by_link)
    }

    /// Capsule `k` of `link`: finite end points within reach of the link frame, a positive
    /// finite radius.
    fn check_capsule(&self, link: &str, k: usize, c: &CapsuleToml) -> Result<(), CollisionError> {
        for (end, p) in [("a", c.a), ("b", c.b)] {
            if let Some(v) = p
                .iter()
                .find(|v| !(v.is_finite() && v.abs() <= MAX_COORDINATE_M))
            {
                return Err(self.value(
                    link,
                    &format!("capsule[{k}].{end}"),
                    format!("{p:?}"),
                    &format!(
                        "{v} is not a finite coordinate within {MAX_COORDINATE_M} m of the link frame (the unit is metres)"
                    ),
                ));
            }
        }
        if !(c.radius_m.is_finite() && c.radius_m > 0.0 && c.radius_m <= MAX_COORDINATE_M) {
            return Err(self.value(
                link,
                &format!("capsule[{k}].radius_m"),
                c.radius_m.to_string(),
                "a radius must be a positive finite number of metres",
            ));
        }
        Ok(())
    }

    /// The bodies of the chain: the links that the same joints move are one body (a link
    /// and the frames fixed to it, such as an end-effector frame), and each body needs
    /// capsules on one of its links.
    fn check_bodies(
        &self,
        chain: &Chain,
        own: &[CollisionLink],
        by_link: &[Option<usize>],
    ) -> Result<(), CollisionError> {
        let (base_name, tip_name) = (self.arm.base_link, self.arm.tool_link);
        let moved = |n: &str| chain.link_id(n).map_or(0, |id| chain.joints_before(id));
        let has = |n: &str| find(own, n).is_some_and(|l| by_link[l.index()].is_some());
        for k in 0..=chain.n_joints() {
            let body: Vec<&str> = chain.link_names().filter(|n| moved(n) == k).collect();
            if !body.is_empty() && !body.iter().any(|n| has(n)) {
                return Err(CollisionError::Link {
                    file: self.file.to_owned(),
                    link: body.join(" / "),
                    reason: format!(
                        "has no [[link]] entry; every body of {}'s chain {base_name} -> {tip_name} (the links the same joints move) needs capsules",
                        self.arm.name
                    ),
                });
            }
        }
        Ok(())
    }

    /// The excluded pairs: links of the model, each pair once, never a link with itself,
    /// each with a reason.
    fn exclusions(
        &self,
        parsed: &FileToml,
        own: &[CollisionLink],
    ) -> Result<Vec<Exclusion>, CollisionError> {
        let file = self.file;
        let mut exclusions: Vec<Exclusion> = Vec::with_capacity(parsed.exclude.len());
        for (index, e) in parsed.exclude.iter().enumerate() {
            let bad = |reason: String| CollisionError::Exclusion {
                file: file.to_owned(),
                index,
                reason,
            };
            let mut pair = [CollisionLink::Base; 2];
            for (slot, name) in pair.iter_mut().zip(&e.links) {
                *slot = find(own, name).ok_or_else(|| CollisionError::UnknownLink {
                    arm: self.arm.name.into(),
                    file: file.to_owned(),
                    field: format!("exclude[{index}].links"),
                    name: name.clone(),
                    known: self.known(),
                })?;
            }
            let [a, b] = pair;
            if a == b {
                return Err(bad(format!("`{a}` is paired with itself")));
            }
            if e.why.trim().is_empty() {
                return Err(bad(format!(
                    "{a} / {b}: `why` is empty; say why the pair cannot collide"
                )));
            }
            if is_excluded(&exclusions, a, b) {
                return Err(bad(format!("{a} / {b} is excluded twice")));
            }
            exclusions.push(Exclusion {
                a,
                b,
                why: e.why.clone(),
            });
        }
        Ok(exclusions)
    }

    /// Each link's frame (on the chain or hung from it), the joints that move it and its
    /// capsules, with the margin added to their radii.
    fn geometry(
        &self,
        parsed: &FileToml,
        chain: &Chain,
        own: &[CollisionLink],
        by_link: &[Option<usize>],
        n_capsules: usize,
    ) -> Result<Geometry, CollisionError> {
        let robot_err = |reason: String| self.robot_err(reason);
        let n_links = own.last().map_or(0, |l| l.index() + 1);
        let mut links: Vec<LinkGeom> = Vec::with_capacity(n_links);
        let mut capsules = Vec::with_capacity(n_capsules);
        let mut refs = Vec::with_capacity(n_capsules);
        for link in (0..n_links).filter_map(CollisionLink::from_index) {
            let Some(entry) = by_link[link.index()].map(|i| &parsed.link[i]) else {
                links.push(LinkGeom {
                    source: Source::Absent,
                    moved_by: 0,
                    first: capsules.len(),
                    end: capsules.len(),
                    table: false,
                });
                continue;
            };
            let source = match chain.link_id(link.name()) {
                Some(id) => Source::Chain(chain.link_index(id)),
                None => hang(self.robot, chain, link, self.arm.gripper_joint, &robot_err)?,
            };
            let moved_by = match &source {
                Source::Chain(i) => chain_moved_by(chain, *i),
                Source::Joint { parent, .. } => match parent {
                    Parent::Chain(i) => chain_moved_by(chain, *i),
                    Parent::Link(k) => links[*k].moved_by,
                },
                Source::Absent => 0,
            };
            let first = capsules.len();
            for (k, c) in entry.capsule.iter().enumerate() {
                capsules.push(Capsule::new(
                    Point3::from(c.a),
                    Point3::from(c.b),
                    c.radius_m + parsed.margin_m,
                ));
                refs.push(CapsuleRef {
                    link,
                    index: u8::try_from(k).unwrap_or(u8::MAX),
                });
            }
            links.push(LinkGeom {
                source,
                moved_by,
                first,
                end: capsules.len(),
                table: entry.table,
            });
        }
        Ok(Geometry {
            links,
            capsules,
            refs,
        })
    }

    /// The capsule pairs to check against each other: every capsule of each link pair that
    /// is not excluded, with their names; at most [`MAX_SELF_PAIRS`].
    fn self_pairs(
        &self,
        own: &[CollisionLink],
        geometry: &Geometry,
        exclusions: &[Exclusion],
    ) -> Result<SelfPairs, CollisionError> {
        let (links, refs) = (&geometry.links, &geometry.refs);
        let mut self_pairs = Vec::new();
        let mut self_ids = Vec::new();
        for (i, la) in own.iter().copied().enumerate() {
            for lb in own.iter().copied().skip(i + 1) {
                if is_excluded(exclusions, la, lb) {
                    continue;
                }
                for ca in links[la.index()].first..links[la.index()].end {
                    for cb in links[lb.index()].first..links[lb.index()].end {
                        self_pairs.push((ca as u16, cb as u16));
                        self_ids.push(PairId {
                            a: refs[ca],
                            b: Target::Capsule(refs[cb]),
                        });
                    }
                }
            }
        }
        if self_pairs.len() > MAX_SELF_PAIRS {
            return Err(CollisionError::Capacity {
                file: self.file.to_owned(),
                reason: format!(
                    "{} capsule pairs to check; at most {MAX_SELF_PAIRS} are supported (exclude more link pairs or use fewer capsules)",
                    self_pairs.len()
                ),
            });
        }
        Ok((self_pairs, self_ids))
    }
}

/// How many arm joints move the `i`-th link of the chain.
fn chain_moved_by(chain: &Chain, i: usize) -> usize {
    chain
        .link_names()
        .nth(i)
        .and_then(|name| chain.link_id(name))
        .map_or(0, |id| chain.joints_before(id))
}

/// The frame of a link off the arm chain: the one URDF joint above it, which must be fixed,
/// the gripper joint, or a joint mimicking it, and whose parent is on the chain or a link
/// before it in the process's table of link names (a file names a parent before its
/// children).
fn hang(
    robot: &RobotModel,
    chain: &Chain,
    link: CollisionLink,
    gripper: Option<&str>,
    robot_err: &dyn Fn(String) -> CollisionError,
) -> Result<Source, CollisionError> {
    let name = link.name();
    let Some(j) = robot.joints().iter().find(|j| j.child == name) else {
        return Err(robot_err(format!(
            "no joint has the link `{name}` as its child: the collision model needs it"
        )));
    };
    let parent = match (
        chain.link_id(&j.parent),
        CollisionLink::from_name(&j.parent),
    ) {
        (Some(id), _) => Parent::Chain(chain.link_index(id)),
        (None, Some(p)) if p.index() < link.index() => Parent::Link(p.index()),
        _ => {
            return Err(robot_err(format!(
                "joint `{}`: the parent of `{name}` is `{}`, neither on the arm chain nor a link with geometry before it",
                j.name, j.parent
            )));
        }
    };
    let (multiplier, offset) = match (j.kind, &j.mimic) {
        (JointType::Fixed, _) => (0.0, 0.0),
        (JointType::Revolute | JointType::Continuous, None) if Some(j.name.as_str()) == gripper => {
            (1.0, 0.0)
        }
        (JointType::Revolute | JointType::Continuous, Some(m))
            if Some(m.joint.as_str()) == gripper =>
        {
            (m.multiplier, m.offset)
        }
        _ => {
            return Err(robot_err(format!(
                "joint `{}` above `{name}` is neither fixed, nor the gripper joint `{}`, nor a revolute joint mimicking it",
                j.name,
                gripper.unwrap_or("(none)")
            )));
        }
    };
    Ok(Source::Joint {
        parent,
        origin: j.origin,
        axis: j.axis,
        multiplier,
        offset,
    })
}
