//! Mapping files: which evdev axis or button of a device is which control of the stack (the
//! two action axes, the gripper, the deadman, mode and e-stop buttons), with the deadzone,
//! per-axis inversion, scaling and range.
//!
//! A mapping is a TOML file (see `examples/joystick/`); two ship inside `scl` by name:
//! [`BUILTIN`] (`xbox`, `generic`). Codes are the kernel's names (`ABS_X`, `BTN_SOUTH`,
//! `KEY_SPACE`) and are resolved to numbers when the file is loaded, so a typo is an error at
//! start-up naming the file and the key.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::Deserialize;

use super::JoystickError;

/// The mappings built into `scl`, by name: the files under `examples/joystick/`.
pub const BUILTIN: [(&str, &str); 2] = [
    ("xbox", include_str!("../../../examples/joystick/xbox.toml")),
    (
        "generic",
        include_str!("../../../examples/joystick/generic.toml"),
    ),
];

/// Default deadzone (fraction of full deflection).
pub const DEFAULT_DEADZONE: f64 = 0.1;

/// `[axes]` entry as written in the file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxisFile {
    code: String,
    #[serde(default)]
    invert: bool,
    #[serde(default = "one")]
    scale: f64,
    #[serde(default)]
    min: Option<i32>,
    #[serde(default)]
    max: Option<i32>,
}

fn one() -> f64 {
    1.0
}

fn default_deadzone() -> f64 {
    DEFAULT_DEADZONE
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct AxesFile {
    x: AxisFile,
    y: AxisFile,
}

#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct GripperFile {
    close: String,
    open: String,
}

#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct ButtonsFile {
    deadman: String,
    mode: String,
    estop: String,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct MappingFile {
    #[serde(default = "default_deadzone")]
    deadzone: f64,
    axes: AxesFile,
    #[serde(default)]
    gripper: GripperFile,
    #[serde(default)]
    buttons: ButtonsFile,
}

/// One evdev input, resolved to its numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Code {
    /// An absolute axis (`EV_ABS`), by code.
    Abs(u16),
    /// A key or button (`EV_KEY`), by code.
    Key(u16),
}

impl Code {
    /// Parses a kernel name: `ABS_*` is an axis, `BTN_*` / `KEY_*` a key.
    pub fn parse(name: &str) -> Option<Self> {
        if name.starts_with("ABS_") {
            evdev::AbsoluteAxisCode::from_str(name)
                .ok()
                .map(|c| Self::Abs(c.0))
        } else {
            evdev::KeyCode::from_str(name)
                .ok()
                .map(|c| Self::Key(c.code()))
        }
    }

    /// The kernel name, for messages.
    pub fn name(self) -> String {
        match self {
            Self::Abs(c) => format!("{:?}", evdev::AbsoluteAxisCode(c)),
            Self::Key(c) => format!("{:?}", evdev::KeyCode::new(c)),
        }
    }
}

/// One action axis of a mapping.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisMap {
    /// The device axis (always [`Code::Abs`]).
    pub code: u16,
    /// Flip the sign.
    pub invert: bool,
    /// Factor applied after the deadzone.
    pub scale: f64,
    /// Range override (else the device's own).
    pub range: Option<(i32, i32)>,
}

/// A checked mapping: every code resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// Where it came from (a built-in name or a file).
    pub source: String,
    /// Radial deadzone of the stick, deadzone of analog gripper inputs, in `[0, 1)`.
    pub deadzone: f64,
    /// The action axes a0, a1.
    pub axes: [AxisMap; 2],
    /// Closes the gripper (a key, or an axis pulled from its minimum like a trigger).
    pub gripper_close: Option<Code>,
    /// Opens the gripper.
    pub gripper_open: Option<Code>,
    /// The deadman button.
    pub deadman: Option<Code>,
    /// The mode-switch button.
    pub mode: Option<Code>,
    /// The e-stop button.
    pub estop: Option<Code>,
}

impl Mapping {
    /// Loads a mapping by built-in name ([`BUILTIN`]) or file path.
    pub fn load(spec: &str) -> Result<Self, JoystickError> {
        if let Some((name, text)) = BUILTIN.iter().find(|(n, _)| *n == spec) {
            return Self::parse(text, name);
        }
        let path = Path::new(spec);
        let text = std::fs::read_to_string(path).map_err(|source| JoystickError::File {
            action: "cannot read the mapping file",
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, spec)
    }

    /// Parses and resolves a mapping's TOML text; `source` names it in errors.
    pub fn parse(text: &str, source: &str) -> Result<Self, JoystickError> {
        let bad = |key: &str, reason: String| JoystickError::Mapping {
            file: PathBuf::from(source),
            key: key.to_owned(),
            reason,
        };
        let file: MappingFile = toml::from_str(text).map_err(|e| JoystickError::Mapping {
            file: PathBuf::from(source),
            key: "(file)".into(),
            reason: e.to_string(),
        })?;
        if !(file.deadzone.is_finite() && (0.0..1.0).contains(&file.deadzone)) {
            return Err(bad(
                "deadzone",
                format!("{} is outside [0, 1)", file.deadzone),
            ));
        }
        let axis = |key: &str, a: &AxisFile| -> Result<AxisMap, JoystickError> {
            let code = match Code::parse(&a.code) {
                Some(Code::Abs(c)) => c,
                Some(Code::Key(_)) => {
                    return Err(bad(
                        &format!("axes.{key}.code"),
                        format!(
                            "`{}` is a button; an action axis needs an ABS_ axis",
                            a.code
                        ),
                    ));
                }
                None => {
                    return Err(bad(
                        &format!("axes.{key}.code"),
                        format!(
                            "`{}` is not an evdev axis name (ABS_X, ABS_RY, ...)",
                            a.code
                        ),
                    ));
                }
            };
            if !(a.scale.is_finite() && a.scale > 0.0 && a.scale <= 4.0) {
                return Err(bad(
                    &format!("axes.{key}.scale"),
                    format!("{} is outside (0, 4]", a.scale),
                ));
            }
            let range = match (a.min, a.max) {
                (None, None) => None,
                (Some(lo), Some(hi)) if lo < hi => Some((lo, hi)),
                (Some(lo), Some(hi)) => {
                    return Err(bad(
                        &format!("axes.{key}.max"),
                        format!("{hi} is not above min {lo}"),
                    ));
                }
                _ => {
                    return Err(bad(
                        &format!("axes.{key}"),
                        "give both min and max, or neither".into(),
                    ));
                }
            };
            Ok(AxisMap {
                code,
                invert: a.invert,
                scale: a.scale,
                range,
            })
        };
        let control = |key: &str, name: &str| -> Result<Option<Code>, JoystickError> {
            if name.is_empty() {
                return Ok(None);
            }
            Code::parse(name).map(Some).ok_or_else(|| {
                bad(
                    key,
                    format!(
                        "`{name}` is not an evdev code name (ABS_Z, BTN_SOUTH, KEY_SPACE, ...)"
                    ),
                )
            })
        };
        Ok(Self {
            source: source.to_owned(),
            deadzone: file.deadzone,
            axes: [axis("x", &file.axes.x)?, axis("y", &file.axes.y)?],
            gripper_close: control("gripper.close", &file.gripper.close)?,
            gripper_open: control("gripper.open", &file.gripper.open)?,
            deadman: control("buttons.deadman", &file.buttons.deadman)?,
            mode: control("buttons.mode", &file.buttons.mode)?,
            estop: control("buttons.estop", &file.buttons.estop)?,
        })
    }

    /// Every device input the mapping reads, with the role it plays.
    pub fn controls(&self) -> Vec<(&'static str, Code)> {
        let mut v = vec![
            ("axis x", Code::Abs(self.axes[0].code)),
            ("axis y", Code::Abs(self.axes[1].code)),
        ];
        for (role, c) in [
            ("gripper close", self.gripper_close),
            ("gripper open", self.gripper_open),
            ("deadman", self.deadman),
            ("mode", self.mode),
            ("e-stop", self.estop),
        ] {
            if let Some(c) = c {
                v.push((role, c));
            }
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_mappings_load() {
        for (name, _) in BUILTIN {
            let m = Mapping::load(name).unwrap();
            assert_eq!(m.deadzone, 0.1);
            assert_eq!(m.axes[0].code, evdev::AbsoluteAxisCode::ABS_X.0);
            assert!(m.axes[1].invert);
            assert!(m.mode.is_some() && m.estop.is_some() && m.deadman.is_some());
            assert!(m.gripper_close.is_some() && m.gripper_open.is_some());
        }
        let x = Mapping::load("xbox").unwrap();
        assert_eq!(x.mode, Some(Code::Key(evdev::KeyCode::BTN_SOUTH.code())));
        assert_eq!(
            x.gripper_close,
            Some(Code::Abs(evdev::AbsoluteAxisCode::ABS_RZ.0))
        );
        // The files on disk are the ones built in.
        let dir = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../examples/joystick"
        ));
        for (name, _) in BUILTIN {
            let p = dir.join(format!("{name}.toml"));
            let from_file = Mapping::load(p.to_str().unwrap()).unwrap();
            assert_eq!(from_file.axes, Mapping::load(name).unwrap().axes);
        }
    }

    #[test]
    fn errors_name_the_source_and_the_key() {
        let cases = [
            (
                "deadzone = 1.5\n[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\" }",
                "deadzone",
            ),
            (
                "[axes]\nx = { code = \"ABS_NOPE\" }\ny = { code = \"ABS_Y\" }",
                "axes.x.code",
            ),
            (
                "[axes]\nx = { code = \"BTN_SOUTH\" }\ny = { code = \"ABS_Y\" }",
                "is a button",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\", scale = 0 }\ny = { code = \"ABS_Y\" }",
                "axes.x.scale",
            ),
            (
                "deadzone = nan\n[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\" }",
                "deadzone: NaN",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\", scale = inf }\ny = { code = \"ABS_Y\" }",
                "axes.x.scale: inf",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\", scale = nan }",
                "axes.y.scale: NaN",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\", min = 5 }\ny = { code = \"ABS_Y\" }",
                "min and max",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\" }\n[buttons]\nmode = \"BTN_NOPE\"",
                "buttons.mode",
            ),
            (
                "[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\" }\n[buttons]\nmodes = \"BTN_A\"",
                "modes",
            ),
            ("[axes]\nx = { code = \"ABS_X\" }", "y"),
        ];
        for (text, needle) in cases {
            let e = Mapping::parse(text, "pad.toml").unwrap_err().to_string();
            assert!(
                e.contains("pad.toml") && e.contains(needle),
                "{needle}: {e}"
            );
        }
        let e = Mapping::load("/nonexistent/pad.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/pad.toml"), "{e}");
    }

    #[test]
    fn a_mapping_without_a_deadzone_gets_the_default() {
        let axes = "[axes]\nx = { code = \"ABS_X\" }\ny = { code = \"ABS_Y\" }\n";
        let m = Mapping::parse(axes, "pad.toml").unwrap();
        assert_eq!(m.deadzone, 0.1);
        assert_eq!(DEFAULT_DEADZONE, 0.1);
        // Every other control is optional too: unmapped, axes not inverted, scale 1.
        assert_eq!(
            (m.gripper_close, m.gripper_open, m.deadman, m.mode, m.estop),
            (None, None, None, None, None)
        );
        assert_eq!(
            m.axes[1],
            AxisMap {
                code: 1,
                invert: false,
                scale: 1.0,
                range: None
            }
        );
        // A deadzone given is taken as written, zero included.
        for dz in [0.0, 0.25] {
            let m = Mapping::parse(&format!("deadzone = {dz:?}\n{axes}"), "pad.toml").unwrap();
            assert_eq!(m.deadzone, dz);
        }
    }

    #[test]
    fn codes_parse_and_name() {
        assert_eq!(Code::parse("ABS_RZ"), Some(Code::Abs(5)));
        assert_eq!(Code::parse("BTN_SOUTH"), Some(Code::Key(0x130)));
        assert_eq!(Code::parse("KEY_SPACE"), Some(Code::Key(57)));
        assert_eq!(Code::parse("ABS_WHATEVER"), None);
        assert_eq!(Code::Key(0x130).name(), "BTN_SOUTH");
        assert_eq!(Code::Abs(0).name(), "ABS_X");
    }
}
