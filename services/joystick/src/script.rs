//! The scripted source: a slow circle, a step pattern or a constant input, evaluated at the
//! tick the sample answers, so a scripted run is deterministic. Every script starts at rest
//! for [`START_REST_S`]: safety moves the arm only after the operator's input has passed
//! through neutral (restart prevention, also at start-up), which a script's rest is.

use ipc_types::{JoystickInput, NO_TICK};

use scl_config::JoystickConfig;

/// Every script holds the stick at rest this long from the first robot tick (s), then
/// starts its pattern from its beginning; a joystick process started later in a running graph
/// (restarted) rests this long from the first tick it sees, then joins the pattern at the
/// graph's time.
pub const START_REST_S: f64 = 0.5;

/// The scripts by name: what `[joystick] script`, `scl up --script` and `scl joystick
/// --script` accept. [`Script::from_config`] parses the name with this type, so the help (its
/// possible values) and the parser cannot disagree.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ScriptName {
    /// A slow circle (`circle_period_s`).
    Circle,
    /// Steps: +x, 0, +y, 0, -x, 0, -y, 0 (`step_hold_s`, `step_rest_s`).
    Step,
    /// `[joystick] constant_axes` held.
    Constant,
}

impl ScriptName {
    /// The script called `name`, if there is one.
    pub fn parse(name: &str) -> Option<Self> {
        <Self as clap::ValueEnum>::from_str(name, false).ok()
    }

    /// The name as written in the config and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Circle => "circle",
            Self::Step => "step",
            Self::Constant => "constant",
        }
    }

    /// Every name, in order.
    pub fn names() -> Vec<&'static str> {
        <Self as clap::ValueEnum>::value_variants()
            .iter()
            .map(|s| s.name())
            .collect()
    }
}

/// A scripted input: `a(t)` with `|a| <= amplitude`.
#[derive(Debug, Clone, PartialEq)]
pub enum Script {
    /// `a = A [cos(2π t / T), sin(2π t / T)]`.
    Circle {
        /// Period T (s).
        period_s: f64,
        /// Amplitude A.
        amplitude: f64,
    },
    /// The same axes all the time (driving into a bound on purpose).
    Constant {
        /// The axes.
        axes: [f64; 2],
    },
    /// `+x, 0, +y, 0, -x, 0, -y, 0`, each direction held `hold_s`, each rest `rest_s`.
    Step {
        /// Hold time (s).
        hold_s: f64,
        /// Rest time (s).
        rest_s: f64,
        /// Amplitude.
        amplitude: f64,
    },
}

/// Checks `[joystick] constant_axes`: two finite numbers within the stick's disc (`|a| <= 1`,
/// the range the mapper takes: it clamps every action radially to the disc, so `[1e9, 0]`
/// would be held as `[1, 0]`, not as written). The error says what is wrong with the pair.
pub fn check_constant_axes(axes: [f64; 2]) -> Result<(), String> {
    if let Some(i) = axes.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "[{}, {}]: entry {i} is {}; both must be finite numbers",
            axes[0], axes[1], axes[i]
        ));
    }
    let norm = axes[0].hypot(axes[1]);
    if norm > 1.0 {
        return Err(format!(
            "[{}, {}] has length {norm}; it must be within the stick's disc (|a| <= 1)",
            axes[0], axes[1]
        ));
    }
    Ok(())
}

impl Script {
    /// The script named in the config, or `None` for an unknown name.
    pub fn from_config(c: &JoystickConfig) -> Option<Self> {
        Some(match ScriptName::parse(&c.script)? {
            ScriptName::Circle => Self::Circle {
                period_s: c.circle_period_s,
                amplitude: c.amplitude,
            },
            ScriptName::Constant => Self::Constant {
                axes: [
                    c.amplitude * c.constant_axes[0],
                    c.amplitude * c.constant_axes[1],
                ],
            },
            ScriptName::Step => Self::Step {
                hold_s: c.step_hold_s,
                rest_s: c.step_rest_s,
                amplitude: c.amplitude,
            },
        })
    }

    /// The axes at time `t_s` since the script started.
    pub fn axes(&self, t_s: f64) -> [f32; 2] {
        match *self {
            Self::Circle {
                period_s,
                amplitude,
            } => {
                let w = 2.0 * std::f64::consts::PI * t_s / period_s;
                [(amplitude * w.cos()) as f32, (amplitude * w.sin()) as f32]
            }
            Self::Constant { axes } => [axes[0] as f32, axes[1] as f32],
            Self::Step {
                hold_s,
                rest_s,
                amplitude,
            } => {
                const DIRS: [[f64; 2]; 4] = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]];
                let seg = hold_s + rest_s;
                let phase = t_s.rem_euclid(4.0 * seg);
                let i = ((phase / seg) as usize).min(3);
                if phase - i as f64 * seg < hold_s {
                    [
                        (amplitude * DIRS[i][0]) as f32,
                        (amplitude * DIRS[i][1]) as f32,
                    ]
                } else {
                    [0.0, 0.0]
                }
            }
        }
    }

    /// The sample answering robot tick `tick` (time = tick × period): at rest until
    /// [`START_REST_S`], then the pattern from its start.
    pub fn sample(&self, tick: u64, period_s: f64, seq: u64, t_ns: u64) -> JoystickInput {
        let t_s = if tick == NO_TICK {
            0.0
        } else {
            tick as f64 * period_s
        };
        let axes = if t_s < START_REST_S {
            [0.0, 0.0]
        } else {
            self.axes(t_s - START_REST_S)
        };
        JoystickInput {
            tick,
            t_ns,
            seq,
            axes,
            gripper: 0.0,
            buttons: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name `--script` lists is a script, and nothing else is.
    #[test]
    fn every_listed_script_name_parses_and_no_other() {
        let mut c = JoystickConfig::default();
        assert_eq!(ScriptName::names(), ["circle", "step", "constant"]);
        for name in ScriptName::names() {
            c.script = name.to_owned();
            assert!(Script::from_config(&c).is_some(), "{name}");
        }
        for name in ["", "Circle", "sine", "circle "] {
            c.script = name.to_owned();
            assert!(Script::from_config(&c).is_none(), "{name:?}");
        }
    }

    #[test]
    fn circle_is_unit_and_periodic() {
        let s = Script::Circle {
            period_s: 8.0,
            amplitude: 1.0,
        };
        assert_eq!(s.axes(0.0), [1.0, 0.0]);
        let q = s.axes(2.0);
        assert!(q[0].abs() < 1e-6 && (q[1] - 1.0).abs() < 1e-6);
        for k in 0..100 {
            let a = s.axes(k as f64 * 0.1);
            assert!((a[0].hypot(a[1]) - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn step_pattern_holds_and_rests() {
        let s = Script::Step {
            hold_s: 2.0,
            rest_s: 0.5,
            amplitude: 0.8,
        };
        assert_eq!(s.axes(0.0), [0.8, 0.0]);
        assert_eq!(s.axes(1.9), [0.8, 0.0]);
        assert_eq!(s.axes(2.2), [0.0, 0.0]);
        assert_eq!(s.axes(2.6), [0.0, 0.8]);
        assert_eq!(s.axes(5.1), [-0.8, 0.0]);
        assert_eq!(s.axes(7.6), [0.0, -0.8]);
        assert_eq!(s.axes(10.1), [0.8, 0.0]);
    }

    /// Every number of `[joystick]`: non-finite and out-of-range values are refused by
    /// `validate` naming the key; the constant script's axes must lie in the stick's disc.
    #[test]
    fn numbers_out_of_range_are_refused_naming_the_key() {
        type Set = fn(&mut JoystickConfig);
        let cases: [(&str, Set, &str); 12] = [
            (
                "constant_axes",
                |j| j.constant_axes = [f64::NAN, 0.0],
                "finite",
            ),
            (
                "constant_axes",
                |j| j.constant_axes = [0.0, f64::INFINITY],
                "finite",
            ),
            ("constant_axes", |j| j.constant_axes = [1e9, 0.0], "disc"),
            ("constant_axes", |j| j.constant_axes = [0.8, 0.8], "disc"),
            ("amplitude", |j| j.amplitude = f64::NAN, "(0, 1]"),
            ("amplitude", |j| j.amplitude = 1.5, "(0, 1]"),
            (
                "circle_period_s",
                |j| j.circle_period_s = f64::NAN,
                "finite",
            ),
            (
                "circle_period_s",
                |j| j.circle_period_s = f64::INFINITY,
                "finite",
            ),
            ("step_hold_s", |j| j.step_hold_s = -1.0, "finite"),
            ("step_rest_s", |j| j.step_rest_s = f64::NAN, "finite"),
            ("keyboard_ramp_s", |j| j.keyboard_ramp_s = 0.0, "finite"),
            (
                "reconnect_interval_ms",
                |j| j.reconnect_interval_ms = 0,
                "below",
            ),
        ];
        for (key, set, needle) in cases {
            // Whatever the script: a key is checked whether or not its source reads it.
            for script in ["constant", "circle"] {
                let mut j = JoystickConfig {
                    script: script.into(),
                    ..JoystickConfig::default()
                };
                set(&mut j);
                let e = crate::validate(&j).unwrap_err().to_string();
                assert!(
                    e.contains(&format!("joystick.{key}:")) && e.contains(needle),
                    "{key} ({script}): {e}"
                );
            }
        }
        // The disc's edge and the defaults are fine.
        for axes in [[1.0, 0.0], [0.6, -0.8], [0.0, 0.0], [-0.5, 0.5]] {
            check_constant_axes(axes).unwrap();
            let j = JoystickConfig {
                script: "constant".into(),
                constant_axes: axes,
                ..JoystickConfig::default()
            };
            crate::validate(&j).unwrap();
        }
    }

    #[test]
    fn samples_follow_the_tick() {
        let s = Script::Circle {
            period_s: 8.0,
            amplitude: 1.0,
        };
        let j = s.sample(80, 0.025, 3, 99);
        assert_eq!((j.tick, j.seq, j.t_ns), (80, 3, 99));
        assert_eq!(j.axes, s.axes(2.0 - START_REST_S));
        // At rest before the first tick and for the first half second, then from the start.
        assert_eq!(s.sample(NO_TICK, 0.025, 0, 0).axes, [0.0, 0.0]);
        assert_eq!(s.sample(19, 0.025, 0, 0).axes, [0.0, 0.0]);
        assert_eq!(s.sample(20, 0.025, 0, 0).axes, s.axes(0.0));
    }
}
