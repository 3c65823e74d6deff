//! Pure builders of Foxglove's well-known messages from the arm's state: no I/O, no time.

use foxglove::messages::{
    ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive, FrameTransform, FrameTransforms,
    LinePrimitive, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive,
    Timestamp, Vector3 as FgVector3,
};
use kinematics::collision::{CapsuleRef, Clearance, CollisionModel, Target};
use kinematics::{Chain, KinError};
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

/// The frame every entity and transform hangs from: the arm's base link (the chain's base).
pub fn root_frame(chain: &Chain) -> &str {
    chain.base()
}

/// The child frame id of the tool (the chain's tip with the tool offset: `Chain::fk`).
pub const TOOL_FRAME: &str = "tool";

/// How long an arrow of the map's directions is per m/s of tool speed (s): the arrow ends
/// where the tool would be after this long at that velocity.
pub const LINEAR_ARROW_S: f64 = 1.0;

/// How long an arrow of a tool turn rate is per rad/s (m).
pub const ANGULAR_ARROW_M_PER_RAD_S: f64 = 0.2;

/// Clearance at and above which a capsule is drawn green (m); red at 0 and below.
pub const CLEAR_M: f64 = 0.10;

/// A monotonic time in ns as a Foxglove timestamp.
pub fn timestamp(t_ns: u64) -> Timestamp {
    let sec = u32::try_from(t_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new(sec, (t_ns % 1_000_000_000) as u32)
}

fn vec3(v: &Vector3<f64>) -> FgVector3 {
    FgVector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

fn quat(q: &UnitQuaternion<f64>) -> Quaternion {
    Quaternion {
        x: q.i,
        y: q.j,
        z: q.k,
        w: q.w,
    }
}

fn pose(position: &Vector3<f64>, orientation: &UnitQuaternion<f64>) -> Pose {
    Pose {
        position: Some(vec3(position)),
        orientation: Some(quat(orientation)),
    }
}

fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

/// One transform: `child` in `parent` at `iso`.
pub fn transform(t_ns: u64, parent: &str, child: &str, iso: &Isometry3<f64>) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(t_ns)),
        parent_frame_id: parent.to_owned(),
        child_frame_id: child.to_owned(),
        translation: Some(vec3(&iso.translation.vector)),
        rotation: Some(quat(&iso.rotation)),
    }
}

/// Every link of `chain` at `q` (forward kinematics, [`Chain::link_poses`]), each in its
/// parent link's frame (the link before it along the chain), then the tool frame
/// ([`TOOL_FRAME`], [`Chain::fk`]) in the tip link's; the base itself is the root and has no
/// transform. Foxglove's transform tree is then the arm's own.
pub fn frame_transforms(chain: &Chain, q: &[f64], t_ns: u64) -> Result<FrameTransforms, KinError> {
    let mut poses = vec![Isometry3::identity(); chain.n_links()];
    let mut axes = [kinematics::JointAxis::UNUSED; kinematics::MAX_DOF];
    chain.link_poses(q, &mut poses, &mut axes)?;
    let names: Vec<&str> = chain.link_names().collect();
    let mut transforms: Vec<FrameTransform> = (1..names.len())
        .map(|i| {
            let rel = poses[i - 1].inverse() * poses[i];
            transform(t_ns, names[i - 1], names[i], &rel)
        })
        .collect();
    let tip = names.len() - 1;
    transforms.push(transform(
        t_ns,
        names[tip],
        TOOL_FRAME,
        &(poses[tip].inverse() * chain.fk(q)?),
    ));
    Ok(FrameTransforms { transforms })
}

/// The pose of a frame hung from the tip link, given its pose in the base frame: how the
/// gripper's links (from the collision model) join the tree.
pub fn from_tip(
    chain: &Chain,
    q: &[f64],
    in_base: &Isometry3<f64>,
) -> Result<Isometry3<f64>, KinError> {
    let tip = chain
        .link_id(chain.tip())
        .map_or_else(|| chain.fk(q), |id| chain.link_pose(q, id))?;
    Ok(tip.inverse() * in_base)
}

/// The colour of a clearance: green at [`CLEAR_M`] and above, through yellow, to red at 0.
pub fn clearance_color(d_m: f64) -> Color {
    let x = if d_m.is_finite() {
        (d_m / CLEAR_M).clamp(0.0, 1.0)
    } else {
        1.0
    };
    if x < 0.5 {
        rgba(1.0, 2.0 * x, 0.1, 0.8)
    } else {
        rgba(2.0 * (1.0 - x), 1.0, 0.1, 0.8)
    }
}

/// The smallest distance of any checked pair with capsule `c` on either side.
pub fn capsule_clearance(cl: &Clearance, c: CapsuleRef) -> f64 {
    cl.pairs()
        .iter()
        .zip(cl.distances_m())
        .filter(|(p, _)| p.a == c || p.b == Target::Capsule(c))
        .map(|(_, d)| *d)
        .fold(f64::INFINITY, f64::min)
}

/// The rotation that turns `from` onto the direction of `to` (identity for a zero `to`).
fn turn(from: &Vector3<f64>, to: &Vector3<f64>) -> UnitQuaternion<f64> {
    if to.norm() < 1e-12 {
        return UnitQuaternion::identity();
    }
    UnitQuaternion::rotation_between(from, to).unwrap_or_else(|| {
        // Opposite directions: half a turn about any perpendicular axis.
        let axis = if from.x.abs() < 0.9 {
            Vector3::x_axis()
        } else {
            Vector3::y_axis()
        };
        UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI)
    })
}

/// The colour step of a clearance: 0 (touching) to 8 (at least [`CLEAR_M`]); an entity is
/// sent again when its step changes.
pub fn clearance_step(d_m: f64) -> u8 {
    if d_m.is_finite() {
        (d_m / CLEAR_M * 8.0).floor().clamp(0.0, 8.0) as u8
    } else {
        8
    }
}

/// The arm drawn as its collision capsules, each a cylinder with a sphere at either end in its
/// link's frame (frame-locked: it moves with `/tf`), coloured by its own clearance in `cl`
/// ([`capsule_clearance`], [`clearance_color`]); one entity per capsule, id
/// `capsule/LINK[i]`, with its clearance in the entity's metadata. Only the capsules `send`
/// picks are in the update (the others keep their last colour).
pub fn arm_entities(
    model: &CollisionModel,
    cl: &Clearance,
    send: impl Fn(usize) -> bool,
    t_ns: u64,
) -> SceneUpdate {
    let entities = model
        .capsule_refs()
        .iter()
        .enumerate()
        .filter(|(i, _)| send(*i))
        .filter_map(|(_, r)| {
            let c = model.link_capsules(r.link).get(usize::from(r.index))?;
            let d = capsule_clearance(cl, *r);
            let color = clearance_color(d);
            let axis = c.b - c.a;
            let mid = (c.a.coords + c.b.coords) / 2.0;
            let size = 2.0 * c.radius_m;
            let sphere = |p: &Point3<f64>| SpherePrimitive {
                pose: Some(pose(&p.coords, &UnitQuaternion::identity())),
                size: Some(vec3(&Vector3::new(size, size, size))),
                color: Some(color),
            };
            Some(SceneEntity {
                timestamp: Some(timestamp(t_ns)),
                frame_id: r.link.name().to_owned(),
                id: format!("capsule/{r}"),
                frame_locked: true,
                metadata: vec![foxglove::messages::KeyValuePair {
                    key: "clearance_m".into(),
                    value: format!("{d:.4}"),
                }],
                cylinders: vec![CylinderPrimitive {
                    pose: Some(pose(&mid, &turn(&Vector3::z(), &axis))),
                    size: Some(vec3(&Vector3::new(size, size, axis.norm()))),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color: Some(color),
                }],
                spheres: vec![sphere(&c.a), sphere(&c.b)],
                ..Default::default()
            })
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// The scene the arm keeps clear of and the tool's bounds: the table (a thin slab under
/// `table_z_m`), the named boxes, and the workspace box as lines. Static: sent once a second.
pub fn world_entities(
    table_z_m: Option<f64>,
    boxes: &[(String, [f64; 3], [f64; 3])],
    workspace: Option<([f64; 3], [f64; 3])>,
    frame: &str,
    t_ns: u64,
) -> SceneUpdate {
    let entity = |id: &str| SceneEntity {
        timestamp: Some(timestamp(t_ns)),
        frame_id: frame.to_owned(),
        id: id.to_owned(),
        ..Default::default()
    };
    let cube = |min: [f64; 3], max: [f64; 3], color: Color| {
        let lo = Vector3::from(min);
        let hi = Vector3::from(max);
        CubePrimitive {
            pose: Some(pose(&((lo + hi) / 2.0), &UnitQuaternion::identity())),
            size: Some(vec3(&(hi - lo))),
            color: Some(color),
        }
    };
    let mut entities = Vec::new();
    if let Some(z) = table_z_m {
        let mut e = entity("table");
        e.cubes.push(cube(
            [-1.0, -1.0, z - 0.02],
            [1.0, 1.0, z],
            rgba(0.55, 0.45, 0.35, 0.6),
        ));
        entities.push(e);
    }
    for (name, min, max) in boxes {
        let mut e = entity(&format!("box/{name}"));
        e.cubes.push(cube(*min, *max, rgba(0.5, 0.5, 0.55, 0.7)));
        e.texts.push(TextPrimitive {
            pose: Some(pose(
                &Vector3::new(
                    (min[0] + max[0]) / 2.0,
                    (min[1] + max[1]) / 2.0,
                    max[2] + 0.03,
                ),
                &UnitQuaternion::identity(),
            )),
            billboard: true,
            font_size: 12.0,
            scale_invariant: true,
            color: Some(rgba(1.0, 1.0, 1.0, 1.0)),
            text: name.clone(),
        });
        entities.push(e);
    }
    if let Some((lo, hi)) = workspace {
        let corner = |i: usize| foxglove::messages::Point3 {
            x: if i & 1 == 0 { lo[0] } else { hi[0] },
            y: if i & 2 == 0 { lo[1] } else { hi[1] },
            z: if i & 4 == 0 { lo[2] } else { hi[2] },
        };
        // The 12 edges: corners that differ in one coordinate bit.
        let mut points = Vec::with_capacity(24);
        for i in 0..8usize {
            for bit in [1usize, 2, 4] {
                if i & bit == 0 {
                    points.push(corner(i));
                    points.push(corner(i | bit));
                }
            }
        }
        let mut e = entity("workspace");
        e.lines.push(LinePrimitive {
            r#type: foxglove::messages::line_primitive::Type::LineList as i32,
            pose: Some(pose(&Vector3::zeros(), &UnitQuaternion::identity())),
            thickness: 2.0,
            scale_invariant: true,
            points,
            color: Some(rgba(0.3, 0.6, 1.0, 0.8)),
            ..Default::default()
        });
        entities.push(e);
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// An arrow from `origin` along `v` scaled by `per_unit` (m per unit of `v`): the arrow's
/// pose points its +x along `v`, and its whole length (shaft + head) is `|v| * per_unit`.
pub fn arrow(
    origin: &Vector3<f64>,
    v: &Vector3<f64>,
    per_unit: f64,
    color: Color,
) -> ArrowPrimitive {
    let length = v.norm() * per_unit;
    let head = (0.25 * length).min(0.04);
    ArrowPrimitive {
        pose: Some(pose(origin, &turn(&Vector3::x(), v))),
        shaft_length: length - head,
        shaft_diameter: 0.01,
        head_length: head,
        head_diameter: 0.025,
        color: Some(color),
    }
}

/// What the map's arrows show at one tick: tool twists (linear m/s, angular rad/s, base frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToolTwists {
    /// The tool's position.
    pub tool: Vector3<f64>,
    /// `J·s·H·e_i` for each stick axis (linear part), if the map is known.
    pub axes_linear: Option<[Vector3<f64>; 2]>,
    /// `J·s·H·e_i` for each stick axis (angular part), if the map is known.
    pub axes_angular: Option<[Vector3<f64>; 2]>,
    /// `J·qdot` of the state's measured joint velocities (linear part): what was executed.
    pub executed_linear: Vector3<f64>,
}

/// Colours of the map's arrows: stick axis 1, axis 2, the executed velocity.
pub const AXIS_COLORS: [(f64, f64, f64); 3] = [(1.0, 0.2, 0.2), (0.2, 0.4, 1.0), (1.0, 1.0, 1.0)];

/// The map's directions at the tool as arrows: entity `map/axis1` and `map/axis2` (each a
/// linear arrow, [`LINEAR_ARROW_S`] per m/s, and a thinner angular one,
/// [`ANGULAR_ARROW_M_PER_RAD_S`] per rad/s), and `map/executed` (the executed tool velocity).
pub fn map_entities(t: &ToolTwists, frame: &str, t_ns: u64) -> SceneUpdate {
    let entity = |id: &str, arrows: Vec<ArrowPrimitive>| SceneEntity {
        timestamp: Some(timestamp(t_ns)),
        frame_id: frame.to_owned(),
        id: id.to_owned(),
        arrows,
        ..Default::default()
    };
    let mut entities = Vec::new();
    let mut deletions = Vec::new();
    match (t.axes_linear, t.axes_angular) {
        (Some(lin), Some(ang)) => {
            for i in 0..2 {
                let (r, g, b) = AXIS_COLORS[i];
                let mut angular = arrow(
                    &t.tool,
                    &ang[i],
                    ANGULAR_ARROW_M_PER_RAD_S,
                    rgba(r, g, b, 0.5),
                );
                angular.shaft_diameter = 0.004;
                angular.head_diameter = 0.012;
                entities.push(entity(
                    &format!("map/axis{}", i + 1),
                    vec![
                        arrow(&t.tool, &lin[i], LINEAR_ARROW_S, rgba(r, g, b, 1.0)),
                        angular,
                    ],
                ));
            }
        }
        _ => {
            for i in 0..2 {
                deletions.push(foxglove::messages::SceneEntityDeletion {
                    timestamp: Some(timestamp(t_ns)),
                    r#type: foxglove::messages::scene_entity_deletion::Type::MatchingId as i32,
                    id: format!("map/axis{}", i + 1),
                });
            }
        }
    }
    let (r, g, b) = AXIS_COLORS[2];
    entities.push(entity(
        "map/executed",
        vec![arrow(
            &t.tool,
            &t.executed_linear,
            LINEAR_ARROW_S,
            rgba(r, g, b, 0.9),
        )],
    ));
    SceneUpdate {
        deletions,
        entities,
    }
}
