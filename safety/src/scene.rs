//! `[safety.scene]`: what the whole arm keeps clear of besides itself (a table plane and a few
//! boxes, base frame, metres), the distances and speeds of the whole-arm rules, their checks at
//! load, and the names of checked pairs for status lines (`forearm-table`).

use kinematics::collision::{MAX_BOXES, PairId, Scene, Target, side_code};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::config::{ConfigError, SafetyConfig, err, positive};

/// `[safety.scene]`: the table and the boxes every link's capsules are checked against.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Height of the table top in the base frame (m): everything below is solid. The base's
    /// foot is at z = 0, so the table is at or below it (0: the arm stands on the table).
    pub table_z_m: f64,
    /// Boxes the arm keeps clear of (a mount, a fixture, a wall), at most
    /// [`kinematics::collision::MAX_BOXES`].
    pub boxes: Vec<BoxConfig>,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            table_z_m: 0.0,
            boxes: Vec::new(),
        }
    }
}

/// One box of `[safety.scene]`: `{ name = "mount", min = [..], max = [..] }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxConfig {
    /// The box's name in status lines (`gripper_base-mount`).
    pub name: String,
    /// The corner with the smallest coordinates (m, base frame).
    pub min: [f64; 3],
    /// The corner with the largest coordinates (m, base frame).
    pub max: [f64; 3],
}

impl SceneConfig {
    /// The scene of the collision model: the table and the boxes in order (box `k` of the
    /// scene is `boxes[k]`). The configuration must have passed [`validate`].
    pub fn scene(&self) -> Result<Scene, ConfigError> {
        let mut s =
            Scene::with_table(self.table_z_m).map_err(|e| err("scene.table_z_m", e.to_string()))?;
        for (i, b) in self.boxes.iter().enumerate() {
            s.add_box(Point3::from(b.min), Point3::from(b.max))
                .map_err(|e| err(&format!("scene.boxes[{i}]"), e.to_string()))?;
        }
        Ok(s)
    }

    /// The boxes' names, in scene order.
    pub fn box_names(&self) -> Vec<String> {
        self.boxes.iter().map(|b| b.name.clone()).collect()
    }
}

/// Checks the whole-arm keys of `[safety]`: the distances (`0 < stop_distance_m <
/// slowdown_distance_m`), the speed caps (positive) and `[safety.scene]` (a finite table at
/// or below the base's foot; at most [`MAX_BOXES`] boxes, each named once, finite, `min <
/// max` on every axis). Errors name the key.
pub fn validate(cfg: &SafetyConfig) -> Result<(), ConfigError> {
    positive("stop_distance_m", cfg.stop_distance_m)?;
    positive("slowdown_distance_m", cfg.slowdown_distance_m)?;
    if cfg.slowdown_distance_m <= cfg.stop_distance_m {
        return Err(err(
            "slowdown_distance_m",
            format!(
                "is {} m; it must be larger than stop_distance_m ({} m)",
                cfg.slowdown_distance_m, cfg.stop_distance_m
            ),
        ));
    }
    positive("max_tcp_speed_m_s", cfg.max_tcp_speed_m_s)?;
    positive(
        "max_tcp_angular_speed_rad_s",
        cfg.max_tcp_angular_speed_rad_s,
    )?;
    let s = &cfg.scene;
    if !(s.table_z_m.is_finite() && s.table_z_m <= 0.0) {
        return Err(err(
            "scene.table_z_m",
            format!(
                "is {}; the table top must be a finite number at or below 0 (m): the base's \
                 foot is at z = 0 (a pedestal: negative)",
                s.table_z_m
            ),
        ));
    }
    if s.boxes.len() > MAX_BOXES {
        return Err(err(
            "scene.boxes",
            format!(
                "has {} boxes; at most {MAX_BOXES} (merge some into one enclosing box)",
                s.boxes.len()
            ),
        ));
    }
    for (i, b) in s.boxes.iter().enumerate() {
        if b.name.trim().is_empty() {
            return Err(err(
                &format!("scene.boxes[{i}].name"),
                "is empty; give every box a name for status lines".into(),
            ));
        }
        if s.boxes[..i].iter().any(|o| o.name == b.name) {
            return Err(err(
                &format!("scene.boxes[{i}].name"),
                format!("`{}` names two boxes", b.name),
            ));
        }
        for (key, corner) in [("min", &b.min), ("max", &b.max)] {
            if let Some(a) = corner.iter().position(|v| !v.is_finite()) {
                return Err(err(
                    &format!("scene.boxes[{i}].{key}"),
                    format!("axis {a} is {}; it must be a finite number", corner[a]),
                ));
            }
        }
        if let Some(a) = (0..3).find(|&a| b.min[a] >= b.max[a]) {
            return Err(err(
                &format!("scene.boxes[{i}].min"),
                format!(
                    "axis {a}: {} .. {} is not a range (min must be below max)",
                    b.min[a], b.max[a]
                ),
            ));
        }
    }
    Ok(())
}

/// The name of a side ([`Target::code`]) for status lines: the link without `_link`, `table`,
/// the box's name from `box_names` (or `box K`); `None` for [`side_code::NONE`].
pub fn side_name(code: u16, box_names: &[String]) -> Option<String> {
    Some(match Target::from_code(code)? {
        Target::Capsule(c) => c.link.short_name().to_owned(),
        Target::Table => "table".to_owned(),
        Target::Box(k) => box_names
            .get(usize::from(k))
            .cloned()
            .unwrap_or_else(|| format!("box {k}")),
    })
}

/// The name of a pair ([`PairId::code`], as in `SafeCommand::closest_pair`) for status
/// lines: `forearm-table`, `base-upper_wrist`, `gripper_base-mount`; `None` when no pair was
/// checked (`[0xFFFF; 2]`) or the code is unknown.
pub fn pair_name(code: [u16; 2], box_names: &[String]) -> Option<String> {
    PairId::from_code(code)?;
    Some(format!(
        "{}-{}",
        side_name(code[0], box_names)?,
        side_name(code[1], box_names)?
    ))
}

/// Whether `code` is [`side_code::NONE`] on both sides (nothing was checked).
pub fn no_pair(code: [u16; 2]) -> bool {
    code == [side_code::NONE; 2]
}
