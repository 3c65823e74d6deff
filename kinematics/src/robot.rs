//! A robot description read from URDF: links, joints, their origins, axes and limits.
//!
//! [`RobotModel::from_urdf_str`] parses with `urdf-rs` and then checks what the kinematics
//! needs: unique names, joints that connect links of the file, a `<limit>` with
//! `lower < upper` and a positive `velocity` on every revolute and prismatic joint, a usable
//! axis. Every error names the file and the element. [`RobotModel::chain`] cuts a serial
//! [`Chain`] out of the tree, from a base link to a tip link.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::chain::{Chain, ChainJoint, JointKind};

/// Why a URDF could not be loaded or a chain could not be cut out of it. Every message starts
/// with the file it is about.
#[derive(Debug, thiserror::Error)]
pub enum UrdfError {
    /// The file could not be read.
    #[error("{path}: cannot read the URDF: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The text is not well-formed XML.
    #[error("{file}: not well-formed XML: {reason}")]
    Xml {
        /// The file.
        file: String,
        /// The XML reader's message (with line and column).
        reason: String,
    },
    /// One element does not follow the URDF schema (a missing attribute, a value that is not
    /// a number, ...).
    #[error("{file}: {element}: {reason}")]
    Element {
        /// The file.
        file: String,
        /// The element, e.g. `<joint name="joint_3">`.
        element: String,
        /// What is wrong.
        reason: String,
    },
    /// A revolute or prismatic joint has no `<limit>` element.
    #[error(
        "{file}: <joint name=\"{joint}\">: a {kind} joint needs a <limit lower=.. upper=.. velocity=..> element, and it has none"
    )]
    MissingLimit {
        /// The file.
        file: String,
        /// The joint.
        joint: String,
        /// Its type (`revolute`, `prismatic`).
        kind: &'static str,
    },
    /// A joint's limits are unusable.
    #[error("{file}: <joint name=\"{joint}\"> <limit>: {reason}")]
    BadLimit {
        /// The file.
        file: String,
        /// The joint.
        joint: String,
        /// What is wrong.
        reason: String,
    },
    /// A joint's axis or origin is unusable.
    #[error("{file}: <joint name=\"{joint}\">: {reason}")]
    BadJoint {
        /// The file.
        file: String,
        /// The joint.
        joint: String,
        /// What is wrong.
        reason: String,
    },
    /// Two links or two joints have the same name, or a link has two parents.
    #[error("{file}: {reason}")]
    Structure {
        /// The file.
        file: String,
        /// What is wrong.
        reason: String,
    },
    /// A link named by the caller is not in the file.
    #[error("{file}: there is no <link name=\"{link}\"> (links: {known})")]
    UnknownLink {
        /// The file.
        file: String,
        /// The requested link.
        link: String,
        /// The links the file has, comma-separated.
        known: String,
    },
    /// The tip is not below the base in the tree, so no chain leads from one to the other.
    #[error(
        "{file}: no chain from <link name=\"{base}\"> reaches <link name=\"{tip}\">: going up from the tip ends at the root <link name=\"{root}\">"
    )]
    Unreachable {
        /// The file.
        file: String,
        /// The requested base.
        base: String,
        /// The requested tip.
        tip: String,
        /// Where the walk from the tip towards the root ended.
        root: String,
    },
    /// The chain holds a joint the kinematics does not model (floating, planar, spherical,
    /// mimic), or more joints than [`crate::MAX_DOF`].
    #[error("{file}: chain {base} -> {tip}: {reason}")]
    Unsupported {
        /// The file.
        file: String,
        /// The requested base.
        base: String,
        /// The requested tip.
        tip: String,
        /// What is not supported.
        reason: String,
    },
}

/// The type of a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointType {
    /// Rigid connection.
    Fixed,
    /// Rotation about the axis, within `[lower, upper]`.
    Revolute,
    /// Rotation about the axis without position limits.
    Continuous,
    /// Translation along the axis, within `[lower, upper]`.
    Prismatic,
    /// A type the kinematics does not model (`floating`, `planar`, `spherical`).
    Other,
}

impl JointType {
    /// The URDF spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            JointType::Fixed => "fixed",
            JointType::Revolute => "revolute",
            JointType::Continuous => "continuous",
            JointType::Prismatic => "prismatic",
            JointType::Other => "floating/planar/spherical",
        }
    }
}

/// One joint of the file, checked.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSpec {
    /// The joint's name.
    pub name: String,
    /// Its type.
    pub kind: JointType,
    /// The parent link.
    pub parent: String,
    /// The child link.
    pub child: String,
    /// Pose of the joint frame in the parent link frame.
    pub origin: Isometry3<f64>,
    /// Unit axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Lower position limit (rad or m; `-inf` for continuous and fixed joints).
    pub lower: f64,
    /// Upper position limit (rad or m; `+inf` for continuous and fixed joints).
    pub upper: f64,
    /// Velocity limit (rad/s or m/s; `+inf` when the file gives none for a continuous joint).
    pub velocity: f64,
    /// Effort limit (N·m or N; 0 when the file gives none).
    pub effort: f64,
    /// The joint this one mimics, if any.
    pub mimic: Option<Mimic>,
}

/// A joint that follows another: `q = multiplier * q_followed + offset`.
#[derive(Debug, Clone, PartialEq)]
pub struct Mimic {
    /// The joint followed.
    pub joint: String,
    /// Factor on the followed joint's value (1 when the file gives none).
    pub multiplier: f64,
    /// Offset added (rad or m; 0 when the file gives none).
    pub offset: f64,
}

/// A robot description: the links and checked joints of one URDF file.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotModel {
    file: String,
    name: String,
    links: Vec<String>,
    joints: Vec<JointSpec>,
}

impl RobotModel {
    /// Reads and checks a URDF file.
    pub fn from_file(path: &Path) -> Result<Self, UrdfError> {
        let text = std::fs::read_to_string(path).map_err(|source| UrdfError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_urdf_str(&text, &path.display().to_string())
    }

    /// Parses and checks URDF text; `file` names it in errors.
    pub fn from_urdf_str(text: &str, file: &str) -> Result<Self, UrdfError> {
        let robot = match urdf_rs::read_from_string(text) {
            Ok(r) => r,
            Err(e) => return Err(locate_parse_error(text, file, &e.to_string())),
        };
        if robot.links.is_empty() {
            return Err(UrdfError::Structure {
                file: file.to_owned(),
                reason: "no <link> elements: not a <robot> description".into(),
            });
        }
        let mut links: Vec<String> = Vec::with_capacity(robot.links.len());
        for l in &robot.links {
            if links.contains(&l.name) {
                return Err(UrdfError::Structure {
                    file: file.to_owned(),
                    reason: format!("two <link> elements are named `{}`", l.name),
                });
            }
            links.push(l.name.clone());
        }
        let mut joints: Vec<JointSpec> = Vec::with_capacity(robot.joints.len());
        for j in &robot.joints {
            let spec = check_joint(j, file)?;
            if joints.iter().any(|o| o.name == spec.name) {
                return Err(UrdfError::Structure {
                    file: file.to_owned(),
                    reason: format!("two <joint> elements are named `{}`", spec.name),
                });
            }
            for (role, link) in [("parent", &spec.parent), ("child", &spec.child)] {
                if !links.contains(link) {
                    return Err(UrdfError::BadJoint {
                        file: file.to_owned(),
                        joint: spec.name.clone(),
                        reason: format!("its {role} link `{link}` is not a <link> of the file"),
                    });
                }
            }
            if let Some(other) = joints.iter().find(|o| o.child == spec.child) {
                return Err(UrdfError::Structure {
                    file: file.to_owned(),
                    reason: format!(
                        "link `{}` is the child of two joints (`{}` and `{}`)",
                        spec.child, other.name, spec.name
                    ),
                });
            }
            joints.push(spec);
        }
        Ok(Self {
            file: file.to_owned(),
            name: robot.name,
            links,
            joints,
        })
    }

    /// The file this model was read from (as named in errors).
    pub fn file(&self) -> &str {
        &self.file
    }

    /// The robot's name (`<robot name=..>`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Every link name, in file order.
    pub fn links(&self) -> &[String] {
        &self.links
    }

    /// Every joint, in file order.
    pub fn joints(&self) -> &[JointSpec] {
        &self.joints
    }

    /// The joint called `name`.
    pub fn joint(&self, name: &str) -> Option<&JointSpec> {
        self.joints.iter().find(|j| j.name == name)
    }

    fn unknown_link(&self, link: &str) -> UrdfError {
        UrdfError::UnknownLink {
            file: self.file.clone(),
            link: link.to_owned(),
            known: self.links.join(", "),
        }
    }

    /// The serial chain from link `base` to link `tip`: the joints on the path, fixed ones
    /// folded into the origins of the movable ones, in fixed arrays ready for
    /// allocation-free evaluation.
    pub fn chain(&self, base: &str, tip: &str) -> Result<Chain, UrdfError> {
        for l in [base, tip] {
            if !self.links.iter().any(|k| k == l) {
                return Err(self.unknown_link(l));
            }
        }
        // Walk up from the tip to the base.
        let mut path: Vec<&JointSpec> = Vec::new();
        let mut at = tip;
        while at != base {
            match self.joints.iter().find(|j| j.child == at) {
                Some(j) => {
                    path.push(j);
                    at = &j.parent;
                }
                None => {
                    return Err(UrdfError::Unreachable {
                        file: self.file.clone(),
                        base: base.to_owned(),
                        tip: tip.to_owned(),
                        root: at.to_owned(),
                    });
                }
            }
            if path.len() > self.joints.len() {
                return Err(UrdfError::Structure {
                    file: self.file.clone(),
                    reason: format!("the joints above link `{tip}` form a loop"),
                });
            }
        }
        path.reverse();
        let unsupported = |reason: String| UrdfError::Unsupported {
            file: self.file.clone(),
            base: base.to_owned(),
            tip: tip.to_owned(),
            reason,
        };
        let mut joints = Vec::with_capacity(path.len());
        for j in path {
            let kind = match j.kind {
                JointType::Fixed => None,
                JointType::Revolute | JointType::Continuous => Some(JointKind::Revolute),
                JointType::Prismatic => Some(JointKind::Prismatic),
                JointType::Other => {
                    return Err(unsupported(format!(
                        "joint `{}` is of a type the kinematics does not model ({})",
                        j.name,
                        j.kind.as_str()
                    )));
                }
            };
            if let (Some(_), Some(m)) = (kind, &j.mimic) {
                return Err(unsupported(format!(
                    "joint `{}` mimics `{}`; chains through mimic joints are not modelled",
                    j.name, m.joint
                )));
            }
            joints.push(ChainJoint {
                name: j.name.clone(),
                child: j.child.clone(),
                kind,
                origin: j.origin,
                axis: j.axis,
                lower: j.lower,
                upper: j.upper,
                velocity: j.velocity,
            });
        }
        Chain::build(&self.file, base, tip, &joints).map_err(unsupported)
    }
}

fn check_joint(j: &urdf_rs::Joint, file: &str) -> Result<JointSpec, UrdfError> {
    let bad = |reason: String| UrdfError::BadJoint {
        file: file.to_owned(),
        joint: j.name.clone(),
        reason,
    };
    let kind = match j.joint_type {
        urdf_rs::JointType::Fixed => JointType::Fixed,
        urdf_rs::JointType::Revolute => JointType::Revolute,
        urdf_rs::JointType::Continuous => JointType::Continuous,
        urdf_rs::JointType::Prismatic => JointType::Prismatic,
        _ => JointType::Other,
    };
    let xyz = j.origin.xyz.0;
    let rpy = j.origin.rpy.0;
    if xyz.iter().chain(&rpy).any(|v| !v.is_finite()) {
        return Err(bad(format!(
            "<origin xyz=\"{xyz:?}\" rpy=\"{rpy:?}\"> has a non-finite value"
        )));
    }
    let origin = Isometry3::from_parts(
        Translation3::new(xyz[0], xyz[1], xyz[2]),
        UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]),
    );
    let a = Vector3::from(j.axis.xyz.0);
    let movable = !matches!(kind, JointType::Fixed | JointType::Other);
    let axis = if movable {
        let norm = a.norm();
        if !(norm.is_finite() && norm > 1e-9) {
            return Err(bad(format!(
                "<axis xyz=\"{} {} {}\"> is not a usable direction",
                a.x, a.y, a.z
            )));
        }
        Unit::new_normalize(a)
    } else {
        Vector3::z_axis()
    };
    let lim = &j.limit;
    let (lower, upper, velocity) = joint_range(j, kind, file)?;
    let mimic = match &j.mimic {
        None => None,
        Some(m) => {
            let multiplier = m.multiplier.unwrap_or(1.0);
            let offset = m.offset.unwrap_or(0.0);
            if !(multiplier.is_finite() && offset.is_finite()) {
                return Err(bad(format!(
                    "<mimic joint=\"{}\" multiplier=\"{multiplier}\" offset=\"{offset}\">: both must be finite numbers",
                    m.joint
                )));
            }
            Some(Mimic {
                joint: m.joint.clone(),
                multiplier,
                offset,
            })
        }
    };
    Ok(JointSpec {
        name: j.name.clone(),
        kind,
        parent: j.parent.link.clone(),
        child: j.child.link.clone(),
        origin,
        axis,
        lower,
        upper,
        velocity,
        effort: if lim.effort.is_finite() {
            lim.effort
        } else {
            0.0
        },
        mimic,
    })
}

/// A joint's (lower, upper, velocity) limits: required and checked for a revolute or
/// prismatic joint, unbounded for the others (a continuous joint's velocity if given).
fn joint_range(
    j: &urdf_rs::Joint,
    kind: JointType,
    file: &str,
) -> Result<(f64, f64, f64), UrdfError> {
    let bad_limit = |reason: String| UrdfError::BadLimit {
        file: file.to_owned(),
        joint: j.name.clone(),
        reason,
    };
    let lim = &j.limit;
    Ok(match kind {
        JointType::Revolute | JointType::Prismatic => {
            // urdf-rs fills an absent <limit> with zeros (URDF 1.0) and absent attributes
            // with infinities (URDF 1.2); a real limit has lower < upper and velocity > 0.
            if *lim == urdf_rs::JointLimit::default() {
                return Err(UrdfError::MissingLimit {
                    file: file.to_owned(),
                    joint: j.name.clone(),
                    kind: kind.as_str(),
                });
            }
            if !(lim.lower.is_finite() && lim.upper.is_finite()) {
                return Err(bad_limit(format!(
                    "lower ({}) and upper ({}) must both be given as finite numbers",
                    lim.lower, lim.upper
                )));
            }
            if lim.lower >= lim.upper {
                return Err(bad_limit(format!(
                    "lower ({}) must be below upper ({})",
                    lim.lower, lim.upper
                )));
            }
            if !(lim.velocity.is_finite() && lim.velocity > 0.0) {
                return Err(bad_limit(format!(
                    "velocity ({}) must be a positive number",
                    lim.velocity
                )));
            }
            (lim.lower, lim.upper, lim.velocity)
        }
        JointType::Continuous => {
            let v = if lim.velocity > 0.0 {
                lim.velocity
            } else {
                f64::INFINITY
            };
            (f64::NEG_INFINITY, f64::INFINITY, v)
        }
        JointType::Fixed | JointType::Other => (f64::NEG_INFINITY, f64::INFINITY, f64::INFINITY),
    })
}

/// Turns a urdf-rs error into one that names the element: well-formedness errors come from
/// the XML reader (with line and column); schema errors are found by reading each top-level
/// element of the file on its own.
fn locate_parse_error(text: &str, file: &str, whole: &str) -> UrdfError {
    if let Some(reason) = xml_syntax_error(text) {
        return UrdfError::Xml {
            file: file.to_owned(),
            reason,
        };
    }
    let root: xml::Element = match text.parse() {
        Ok(r) => r,
        Err(e) => {
            return UrdfError::Xml {
                file: file.to_owned(),
                reason: e.to_string(),
            };
        }
    };
    if root.name != "robot" {
        return UrdfError::Element {
            file: file.to_owned(),
            element: format!("<{}>", root.name),
            reason: "the root element must be <robot>".into(),
        };
    }
    for child in &root.children {
        let xml::Xml::ElementNode(el) = child else {
            continue;
        };
        let mut alone = root.clone();
        alone.children = vec![xml::Xml::ElementNode(el.clone())];
        if let Err(e) = urdf_rs::read_from_string(&alone.to_string()) {
            let element = match el.get_attribute("name", None) {
                Some(n) => format!("<{} name=\"{n}\">", el.name),
                None => format!("<{}> (without a name)", el.name),
            };
            let reason = e.to_string();
            // serde-xml-rs prefixes schema errors with "custom: ".
            let reason = reason
                .strip_prefix("custom: ")
                .unwrap_or(&reason)
                .to_owned();
            return UrdfError::Element {
                file: file.to_owned(),
                element,
                reason,
            };
        }
    }
    UrdfError::Element {
        file: file.to_owned(),
        element: "<robot>".into(),
        reason: whole.to_owned(),
    }
}

/// The first well-formedness error of `text`: the reader's own (with line and column), or an
/// end tag that closes the wrong element, or an element left open, naming the element.
fn xml_syntax_error(text: &str) -> Option<String> {
    let describe = |t: &xml::StartTag| match t.attributes.get(&("name".to_owned(), None)) {
        Some(n) => format!("<{} name=\"{n}\">", t.name),
        None => format!("<{}>", t.name),
    };
    let mut parser = xml::Parser::new();
    parser.feed_str(text);
    let mut open: Vec<(String, String)> = Vec::new();
    let mut seen_root = false;
    for event in parser {
        match event {
            Err(e) => return Some(e.to_string()),
            Ok(xml::Event::ElementStart(t)) => {
                seen_root = true;
                open.push((t.name.clone(), describe(&t)));
            }
            Ok(xml::Event::ElementEnd(t)) => match open.pop() {
                Some((name, _)) if name == t.name => {}
                Some((_, what)) => return Some(format!("</{}> does not close {what}", t.name)),
                None => return Some(format!("</{}> closes no element", t.name)),
            },
            Ok(_) => {}
        }
    }
    match open.last() {
        Some((_, what)) => Some(format!("{what} is not closed before the end of the text")),
        None if !seen_root => Some("there is no element".to_owned()),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gen3_lite::URDF;

    fn err(text: &str) -> String {
        RobotModel::from_urdf_str(text, "bad.urdf")
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn malformed_xml_names_the_file_and_position() {
        let e = err(&URDF.replace(
            "</joint>\n\n  <joint name=\"joint_3\"",
            "</jont>\n\n  <joint name=\"joint_3\"",
        ));
        assert_eq!(
            e,
            "bad.urdf: not well-formed XML: </jont> does not close <joint name=\"joint_2\">"
        );
        let e = err(&URDF.replace("</robot>", ""));
        assert_eq!(
            e,
            "bad.urdf: not well-formed XML: <robot name=\"gen3_lite\"> is not closed before the end of the text"
        );
        let e = err(&URDF.replace("<link name=\"tool_frame\"/>", "<link name=\"tool_frame\"/"));
        assert!(e.starts_with("bad.urdf: not well-formed XML: "), "{e}");
        assert!(e.contains("Line: 36"), "{e}");
        assert_eq!(
            err(""),
            "bad.urdf: not well-formed XML: there is no element"
        );
        let e = err("<robt name=\"x\"/>");
        assert_eq!(e, "bad.urdf: no <link> elements: not a <robot> description");
    }

    #[test]
    fn schema_errors_name_the_element() {
        let e = err(&URDF.replace("velocity=\"1.6\" effort=\"14\"", "effort=\"14\""));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_2\">: missing field `velocity`"
        );
        let e = err(&URDF.replace(
            "name=\"joint_4\" type=\"revolute\"",
            "name=\"joint_4\" type=\"twisty\"",
        ));
        assert!(
            e.starts_with("bad.urdf: <joint name=\"joint_4\">: unknown variant `twisty`"),
            "{e}"
        );
        let e = err(&URDF.replace("<parent link=\"arm_link\"/>", ""));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_3\">: missing field `parent`"
        );
        let e = err(&URDF.replace("0 -0.03 0.115", "0 abc 0.115"));
        assert!(e.starts_with("bad.urdf: <joint name=\"joint_2\">: "), "{e}");
        let e = err(&URDF.replace("<link name=\"arm_link\"/>", "<link/>"));
        assert_eq!(e, "bad.urdf: <link> (without a name): missing field `name`");
    }

    #[test]
    fn a_missing_limit_is_named() {
        let e = err(&URDF.replace(
            "<limit lower=\"-2.61\" upper=\"2.61\" velocity=\"1.6\" effort=\"14\"/>",
            "",
        ));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_2\">: a revolute joint needs a <limit lower=.. upper=.. velocity=..> element, and it has none"
        );
        // URDF 1.2 reads absent attributes as "no limit": still refused for a revolute joint.
        let v12 = URDF
            .replace(
                "<robot name=\"gen3_lite\">",
                "<robot name=\"gen3_lite\" version=\"1.2\">",
            )
            .replace(
                "lower=\"-2.6\" upper=\"2.6\" velocity=\"3.2\"",
                "velocity=\"3.2\"",
            );
        let e = err(&v12);
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_6\"> <limit>: lower (-inf) and upper (inf) must both be given as finite numbers"
        );
    }

    #[test]
    fn bad_limits_and_axes_are_named() {
        let e = err(&URDF.replace(
            "lower=\"-2.6\" upper=\"2.6\" velocity=\"3.2\"",
            "lower=\"2.6\" upper=\"-2.6\" velocity=\"3.2\"",
        ));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_6\"> <limit>: lower (2.6) must be below upper (-2.6)"
        );
        let e = err(&URDF.replace("velocity=\"3.2\"", "velocity=\"0\""));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_6\"> <limit>: velocity (0) must be a positive number"
        );
        let e = err(&URDF.replace(
            "<axis xyz=\"0 0 1\"/>\n    <limit lower=\"-2.53\"",
            "<axis xyz=\"0 0 0\"/>\n    <limit lower=\"-2.53\"",
        ));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_5\">: <axis xyz=\"0 0 0\"> is not a usable direction"
        );
    }

    #[test]
    fn structure_errors() {
        let e = err(&URDF.replace(
            "<link name=\"arm_link\"/>",
            "<link name=\"arm_link\"/><link name=\"arm_link\"/>",
        ));
        assert_eq!(e, "bad.urdf: two <link> elements are named `arm_link`");
        let e = err(&URDF.replace("<child link=\"forearm_link\"/>", "<child link=\"elbow\"/>"));
        assert_eq!(
            e,
            "bad.urdf: <joint name=\"joint_3\">: its child link `elbow` is not a <link> of the file"
        );
        let e = err(&URDF.replace(
            "<child link=\"gripper_base_link\"/>",
            "<child link=\"tool_frame\"/>",
        ));
        assert_eq!(
            e,
            "bad.urdf: link `tool_frame` is the child of two joints (`tool_frame_joint` and `gripper_base_joint`)"
        );
    }

    #[test]
    fn chains_that_do_not_reach_are_refused() {
        let m = RobotModel::from_urdf_str(URDF, "g.urdf").unwrap();
        let e = m.chain("base_link", "flange").unwrap_err().to_string();
        assert!(
            e.starts_with(
                "g.urdf: there is no <link name=\"flange\"> (links: base_link, shoulder_link"
            ),
            "{e}"
        );
        let e = m
            .chain("gripper_base_link", "tool_frame")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "g.urdf: no chain from <link name=\"gripper_base_link\"> reaches <link name=\"tool_frame\">: going up from the tip ends at the root <link name=\"base_link\">"
        );
        // A chain may start anywhere above its tip, and may end at a finger.
        let c = m.chain("forearm_link", "tool_frame").unwrap();
        assert_eq!(c.joint_names(), ["joint_4", "joint_5", "joint_6"]);
        let c = m.chain("base_link", "right_finger_prox_link").unwrap();
        assert_eq!(c.n_joints(), 7);
        assert_eq!(c.upper()[6], 0.96);
        let c = m.chain("tool_frame", "tool_frame").unwrap();
        assert_eq!(c.n_joints(), 0);
    }

    #[test]
    fn unsupported_joints_in_a_chain() {
        let mimic = URDF.replace(
            "<limit lower=\"-0.09\" upper=\"0.96\" velocity=\"0.6\"/>",
            "<limit lower=\"-0.09\" upper=\"0.96\" velocity=\"0.6\"/><mimic joint=\"joint_6\"/>",
        );
        let m = RobotModel::from_urdf_str(&mimic, "m.urdf").unwrap();
        assert!(m.chain("base_link", "tool_frame").is_ok());
        let e = m.chain("base_link", "right_finger_prox_link").unwrap_err();
        assert_eq!(
            e.to_string(),
            "m.urdf: chain base_link -> right_finger_prox_link: joint `right_finger_bottom_joint` mimics `joint_6`; chains through mimic joints are not modelled"
        );
        let floating = URDF.replace(
            "name=\"tool_frame_joint\" type=\"fixed\"",
            "name=\"tool_frame_joint\" type=\"floating\"",
        );
        let m = RobotModel::from_urdf_str(&floating, "f.urdf").unwrap();
        let e = m.chain("base_link", "tool_frame").unwrap_err().to_string();
        assert!(
            e.contains("joint `tool_frame_joint` is of a type the kinematics does not model"),
            "{e}"
        );
    }

    #[test]
    fn mimic_factors_are_read() {
        let m = RobotModel::from_urdf_str(URDF, "g.urdf").unwrap();
        let tip = m.joint("left_finger_tip_joint").unwrap();
        assert_eq!(
            tip.mimic,
            Some(Mimic {
                joint: "right_finger_bottom_joint".into(),
                multiplier: -0.676,
                offset: 0.149
            })
        );
        assert_eq!(m.joint("right_finger_bottom_joint").unwrap().mimic, None);
        let defaults = URDF.replace("multiplier=\"-1.0\" offset=\"0.0\"", "");
        let m = RobotModel::from_urdf_str(&defaults, "g.urdf").unwrap();
        let left = m
            .joint("left_finger_bottom_joint")
            .unwrap()
            .mimic
            .clone()
            .unwrap();
        assert_eq!((left.multiplier, left.offset), (1.0, 0.0));
        let e = err(&URDF.replace("multiplier=\"-1.0\"", "multiplier=\"inf\""));
        assert!(
            e.starts_with("bad.urdf: <joint name=\"left_finger_bottom_joint\">: <mimic"),
            "{e}"
        );
    }

    #[test]
    fn too_many_joints() {
        let mut text = String::from("<robot name=\"long\"><link name=\"l0\"/>");
        for i in 1..=9 {
            text.push_str(&format!(
                "<link name=\"l{i}\"/><joint name=\"j{i}\" type=\"continuous\"><parent link=\"l{}\"/><child link=\"l{i}\"/></joint>",
                i - 1
            ));
        }
        text.push_str("</robot>");
        let m = RobotModel::from_urdf_str(&text, "long.urdf").unwrap();
        assert_eq!(m.joint("j1").unwrap().velocity, f64::INFINITY);
        assert!(m.chain("l0", "l8").is_ok());
        let e = m.chain("l0", "l9").unwrap_err().to_string();
        assert_eq!(
            e,
            "long.urdf: chain l0 -> l9: 9 movable joints; at most 8 are supported"
        );
    }

    #[test]
    fn unreadable_file() {
        let e = RobotModel::from_file(Path::new("/nonexistent/robot.urdf")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/robot.urdf: cannot read the URDF: "),
            "{e}"
        );
    }
}
