//! The scripted source: a slow circle, a step pattern or a constant input, evaluated at the
//! tick the sample answers, so a scripted run is deterministic. Every script starts at rest
//! for [`START_REST_S`]: safety moves the arm only after the operator's input has passed
//! through neutral (restart prevention, also at start-up), which a script's rest is.

use ipc_types::{JoystickInput, NO_TICK};

use scl_config::JoystickConfig;

/// Every script holds the stick at rest this long from the first robot tick (s), then
/// starts its pattern from its beginning.
pub const START_REST_S: f64 = 0.5;

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

impl Script {
    /// The script named in the config, or `None` for an unknown name.
    pub fn from_config(c: &JoystickConfig) -> Option<Self> {
        match c.script.as_str() {
            "circle" => Some(Self::Circle {
                period_s: c.circle_period_s,
                amplitude: c.amplitude,
            }),
            "constant" => Some(Self::Constant {
                axes: [
                    c.amplitude * c.constant_axes[0],
                    c.amplitude * c.constant_axes[1],
                ],
            }),
            "step" => Some(Self::Step {
                hold_s: c.step_hold_s,
                rest_s: c.step_rest_s,
                amplitude: c.amplitude,
            }),
            _ => None,
        }
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
