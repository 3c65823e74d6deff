//! Cartesian mode switching, the paper's strongest baseline: the 2-D input drives two of the six
//! components of a Cartesian twist of the tool centre point, in one of three modes (x-y, z-yaw,
//! roll-pitch, the order of the assistive arms), and a mode button cycles the modes.
//!
//! The twist (base frame; the angular part turns the tool about the TCP) is turned into joint
//! velocities by damped least squares on the arm's geometric Jacobian ([`kinematics::Dls`],
//! the full 6-row task, so the four components the mode does not drive are held at zero). The
//! twist is limited to [`ModeSwitchParams::max_linear_m_s`] and
//! [`ModeSwitchParams::max_angular_rad_s`] at full deflection, and scaled down near
//! singularities: when the Jacobian's condition number `κ = σ_max / σ_min` passes
//! [`ModeSwitchParams::slowdown_start_condition`] the speed falls linearly in `κ`, down to
//! [`ModeSwitchParams::slowdown_min_fraction`] at [`ModeSwitchParams::slowdown_full_condition`]
//! and beyond (never to zero, so the operator can drive back out).
//!
//! The map's output is already in rad/s: its header's speed scale is 1. It is served under
//! the model spec [`SPEC`] (`modeswitch`, or `modeswitch:key=value,...` to set parameters, e.g.
//! `modeswitch:max_linear_m_s=0.15`), or from a header-only model file of kind `modeswitch`
//! whose parameters sit in the file's metadata under [`PARAMS_KEY`] ([`to_bytes`] writes one).
//!
//! ```
//! use mapper::{LoadedModel, modeswitch::Mode};
//!
//! let mut m = LoadedModel::load("modeswitch").unwrap();
//! assert_eq!(m.map.mode().map(|s| s.name), Some(Mode::XY.name()));
//! m.map.press(ipc_types::buttons::MODE);
//! assert_eq!(m.map.mode().map(|s| (s.name, s.switches)), Some(("z-yaw", 1)));
//! ```

use std::collections::HashMap;
use std::path::Path;

use kinematics::{Chain, Dls, Gen3Lite, Jacobian, TaskMask, gen3_lite};
use nalgebra::{Matrix6, Vector6};
use serde::{Deserialize, Serialize};

use crate::model::{FORMAT, HEADER_KEY, ModelError, ModelHeader, ModelKind, TrainingInfo, VERSION};
use crate::{ActionMap, MapMode};

/// The model spec that serves a mode-switching map with default parameters; `SPEC:key=value,...`
/// sets some.
pub const SPEC: &str = "modeswitch";

/// Metadata key of a mode-switching model file's parameters (JSON of [`ModeSwitchParams`]).
pub const PARAMS_KEY: &str = "modeswitch";

/// One mode: which two twist components the two axes drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// `a0 -> vx`, `a1 -> vy`: the tool moves in the horizontal plane.
    XY,
    /// `a0 -> ωz` (yaw, about the vertical through the TCP), `a1 -> vz` (up and down).
    ZYaw,
    /// `a0 -> ωx` (roll, about the base x axis), `a1 -> ωy` (pitch, about the base y axis),
    /// both about the TCP.
    RollPitch,
}

impl Mode {
    /// Every mode, in the order the mode button cycles through them.
    pub const ALL: [Mode; 3] = [Mode::XY, Mode::ZYaw, Mode::RollPitch];

    /// The mode's name as the status and the log spell it.
    pub fn name(self) -> &'static str {
        match self {
            Self::XY => "x-y",
            Self::ZYaw => "z-yaw",
            Self::RollPitch => "roll-pitch",
        }
    }

    /// Position in [`Mode::ALL`].
    pub fn index(self) -> usize {
        match self {
            Self::XY => 0,
            Self::ZYaw => 1,
            Self::RollPitch => 2,
        }
    }

    /// The mode at position `i` of [`Mode::ALL`].
    pub fn from_index(i: usize) -> Option<Self> {
        Self::ALL.get(i).copied()
    }

    /// The mode after this one.
    pub fn next(self) -> Self {
        Self::ALL[(self.index() + 1) % Self::ALL.len()]
    }

    /// Rows of the twist `[vx, vy, vz, ωx, ωy, ωz]` driven by `a0` and `a1`.
    pub fn rows(self) -> [usize; 2] {
        match self {
            Self::XY => [0, 1],
            Self::ZYaw => [5, 2],
            Self::RollPitch => [3, 4],
        }
    }
}

/// Parameters of a mode-switching map; every one has a default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModeSwitchParams {
    /// TCP speed at full deflection in a translation (m/s); Kinova's twist limit.
    pub max_linear_m_s: f64,
    /// Tool turn rate at full deflection in a rotation (rad/s); Kinova's twist limit.
    pub max_angular_rad_s: f64,
    /// Condition number of the Jacobian above which the twist is slowed down.
    pub slowdown_start_condition: f64,
    /// Condition number at (and above) which the twist is at its slowest.
    pub slowdown_full_condition: f64,
    /// The slowest fraction of the twist kept near a singularity, in `(0, 1]`.
    pub slowdown_min_fraction: f64,
    /// Damped least squares: smallest singular value below which the damping grows.
    pub dls_singular_threshold: f64,
    /// Damped least squares: damping added at a singularity.
    pub dls_max_damping: f64,
    /// How far ahead the Jacobian is taken (s): half the tick period by default, so a joint
    /// velocity held for one period moves the TCP along the twist to second order (the
    /// midpoint rule) instead of drifting off it as the arm turns; 0 takes it at the current
    /// pose (one solve instead of two).
    pub lookahead_s: f64,
}

impl Default for ModeSwitchParams {
    fn default() -> Self {
        let dls = Dls::default();
        Self {
            max_linear_m_s: 0.3,
            max_angular_rad_s: 0.85,
            slowdown_start_condition: 40.0,
            slowdown_full_condition: 150.0,
            slowdown_min_fraction: 0.2,
            dls_singular_threshold: dls.singular_threshold,
            dls_max_damping: dls.max_damping,
            lookahead_s: 0.5 / gen3_lite::CONTROL_RATE_HZ,
        }
    }
}

impl ModeSwitchParams {
    /// Checks every value; the error names the model (`model`) and the key.
    pub fn validate(&self, model: &str) -> Result<(), ModelError> {
        self.check()
            .map_err(|(key, reason)| ModelError::Parameters {
                model: model.to_owned(),
                reason: format!("{key}: {reason}"),
            })
    }

    fn check(&self) -> Result<(), (&'static str, String)> {
        let positive = [
            ("max_linear_m_s", self.max_linear_m_s),
            ("max_angular_rad_s", self.max_angular_rad_s),
            ("dls_singular_threshold", self.dls_singular_threshold),
            ("dls_max_damping", self.dls_max_damping),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err((key, format!("{v} must be a positive number")));
            }
        }
        if !(self.lookahead_s.is_finite() && (0.0..=1.0).contains(&self.lookahead_s)) {
            return Err((
                "lookahead_s",
                format!("{} is outside [0, 1] s", self.lookahead_s),
            ));
        }
        if !(self.slowdown_start_condition.is_finite() && self.slowdown_start_condition >= 1.0) {
            return Err((
                "slowdown_start_condition",
                format!(
                    "{} must be at least 1 (a condition number)",
                    self.slowdown_start_condition
                ),
            ));
        }
        if !(self.slowdown_full_condition.is_finite()
            && self.slowdown_full_condition > self.slowdown_start_condition)
        {
            return Err((
                "slowdown_full_condition",
                format!(
                    "{} must be above slowdown_start_condition ({})",
                    self.slowdown_full_condition, self.slowdown_start_condition
                ),
            ));
        }
        if !(self.slowdown_min_fraction > 0.0 && self.slowdown_min_fraction <= 1.0) {
            return Err((
                "slowdown_min_fraction",
                format!("{} is outside (0, 1]", self.slowdown_min_fraction),
            ));
        }
        Ok(())
    }

    /// The fraction of the twist kept at condition number `kappa`.
    pub fn slowdown(&self, kappa: f64) -> f64 {
        let (lo, hi) = (self.slowdown_start_condition, self.slowdown_full_condition);
        if kappa <= lo {
            1.0
        } else if kappa >= hi || !kappa.is_finite() {
            self.slowdown_min_fraction
        } else {
            1.0 - (1.0 - self.slowdown_min_fraction) * (kappa - lo) / (hi - lo)
        }
    }

    /// Parses the `key=value,...` part of a spec such as `modeswitch:max_linear_m_s=0.15`.
    fn with_overrides(mut self, list: &str) -> Result<Self, String> {
        for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| format!("`{item}` is not key=value"))?;
            let (key, value) = (key.trim(), value.trim());
            let v: f64 = value
                .parse()
                .map_err(|_| format!("{key}: `{value}` is not a number"))?;
            let slot = match key {
                "max_linear_m_s" => &mut self.max_linear_m_s,
                "max_angular_rad_s" => &mut self.max_angular_rad_s,
                "slowdown_start_condition" => &mut self.slowdown_start_condition,
                "slowdown_full_condition" => &mut self.slowdown_full_condition,
                "slowdown_min_fraction" => &mut self.slowdown_min_fraction,
                "dls_singular_threshold" => &mut self.dls_singular_threshold,
                "dls_max_damping" => &mut self.dls_max_damping,
                "lookahead_s" => &mut self.lookahead_s,
                other => {
                    return Err(format!(
                        "`{other}` is not a parameter (max_linear_m_s, max_angular_rad_s, \
                         slowdown_start_condition, slowdown_full_condition, \
                         slowdown_min_fraction, dls_singular_threshold, dls_max_damping, \
                         lookahead_s)"
                    ));
                }
            };
            *slot = v;
        }
        Ok(self)
    }
}

/// Whether `spec` names the mode-switching map (`modeswitch` or `modeswitch:...`) rather than
/// a file.
pub fn is_spec(spec: &str) -> bool {
    spec == SPEC
        || spec
            .strip_prefix(SPEC)
            .is_some_and(|rest| rest.starts_with(':'))
}

/// What the map did at its last evaluation, for tests and diagnostics.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Diagnostics {
    /// The Jacobian's condition number (infinite at a singularity).
    pub condition: f64,
    /// The fraction of the twist kept ([`ModeSwitchParams::slowdown`]).
    pub slowdown: f64,
    /// The twist asked of the TCP, after the slowdown.
    pub twist: [f64; 6],
    /// Smallest singular value seen by the damped least-squares step.
    pub sigma_min: f64,
}

/// The mode-switching map on the Gen3 lite arm.
#[derive(Debug, Clone)]
pub struct ModeSwitchMap {
    chain: &'static Chain,
    params: ModeSwitchParams,
    dls: Dls,
    mode: Mode,
    switches: u32,
    jac: Jacobian,
    last: Diagnostics,
}

impl ModeSwitchMap {
    /// A map on the Gen3 lite arm, in the x-y mode; `model` names it in the error when a
    /// parameter is out of range.
    pub fn new(params: ModeSwitchParams, model: &str) -> Result<Self, ModelError> {
        params.validate(model)?;
        let chain = Gen3Lite::get().arm();
        Ok(Self {
            chain,
            params,
            dls: Dls {
                mask: TaskMask::POSE,
                singular_threshold: params.dls_singular_threshold,
                max_damping: params.dls_max_damping,
                ..Dls::default()
            },
            mode: Mode::XY,
            switches: 0,
            jac: Jacobian::zeros(chain.n_joints()),
            last: Diagnostics::default(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ModeSwitchParams {
        &self.params
    }

    /// The current mode.
    pub fn current_mode(&self) -> Mode {
        self.mode
    }

    /// What the last evaluation did.
    pub fn diagnostics(&self) -> Diagnostics {
        self.last
    }

    /// The header of a mode-switching model on the Gen3 lite (speed scale 1: the output is
    /// in rad/s).
    pub fn header(command: &str) -> ModelHeader {
        ModelHeader {
            format: FORMAT.to_owned(),
            version: VERSION,
            kind: ModelKind::ModeSwitch,
            n_joints: gen3_lite::N_JOINTS,
            latent_dim: ipc_types::ACTION_DIM,
            joint_names: gen3_lite::JOINT_NAMES
                .iter()
                .map(|s| (*s).to_owned())
                .collect(),
            speed_scale_rad_s: 1.0,
            lipschitz_bound: None,
            training: TrainingInfo {
                command: command.to_owned(),
                ..TrainingInfo::default()
            },
        }
    }

    /// The map and header for a spec `modeswitch[:key=value,...]`.
    pub fn from_spec(spec: &str) -> Result<(ModelHeader, Self), ModelError> {
        let overrides = spec.strip_prefix(SPEC).unwrap_or_default();
        let overrides = overrides.strip_prefix(':').unwrap_or(overrides);
        let bad = |reason: String| ModelError::Parameters {
            model: spec.to_owned(),
            reason,
        };
        let params = ModeSwitchParams::default()
            .with_overrides(overrides)
            .map_err(bad)?;
        let map = Self::new(params, spec)?;
        Ok((Self::header(spec), map))
    }

    /// The map of a header-only model file of kind `modeswitch`: parameters from the
    /// metadata entry [`PARAMS_KEY`] (defaults where absent). The header must describe the
    /// Gen3 lite arm.
    pub fn from_file(bytes: &[u8], header: &ModelHeader, path: &Path) -> Result<Self, ModelError> {
        let names_match = header.joint_names.len() == gen3_lite::N_JOINTS
            && header
                .joint_names
                .iter()
                .zip(gen3_lite::JOINT_NAMES)
                .all(|(a, b)| a == b);
        if !names_match {
            return Err(ModelError::BadHeader {
                path: path.to_owned(),
                reason: format!(
                    "a modeswitch model drives the Gen3 lite's joints {:?}, the header names {:?}",
                    gen3_lite::JOINT_NAMES,
                    header.joint_names
                ),
            });
        }
        let bad = |reason: String| ModelError::Parameters {
            model: path.display().to_string(),
            reason,
        };
        let (_, meta) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| {
            ModelError::NotSafetensors {
                path: path.to_owned(),
                reason: e.to_string(),
            }
        })?;
        let params = match meta.metadata().as_ref().and_then(|m| m.get(PARAMS_KEY)) {
            Some(json) => serde_json::from_str(json)
                .map_err(|e| bad(format!("metadata `{PARAMS_KEY}`: {e}")))?,
            None => ModeSwitchParams::default(),
        };
        Self::new(params, &path.display().to_string())
    }

    /// The Jacobian at `q` into `self.jac`, and its condition number.
    fn jacobian(&mut self, q: &[f64]) -> Option<f64> {
        self.chain.fk_jacobian(q, &mut self.jac).ok()?;
        let j = self.jac.padded();
        let jjt: Matrix6<f64> = j * j.transpose();
        let eig = jjt.symmetric_eigenvalues();
        let (lo, hi) = (eig.min().max(0.0), eig.max().max(0.0));
        Some(if lo > 0.0 {
            (hi / lo).sqrt()
        } else {
            f64::INFINITY
        })
    }

    fn eval_inner(&mut self, q: &[f64], a: &[f64], out: &mut [f64]) -> Option<()> {
        let n = self.chain.n_joints();
        let out = out.get_mut(..n)?;
        let q = q.get(..n)?;
        let (a0, a1) = (*a.first()?, *a.get(1)?);
        if a0 == 0.0 && a1 == 0.0 {
            self.last.twist = [0.0; 6];
            return Some(());
        }
        let condition = self.jacobian(q)?;
        let slowdown = self.params.slowdown(condition);
        let limit = |row: usize| {
            if row < 3 {
                self.params.max_linear_m_s
            } else {
                self.params.max_angular_rad_s
            }
        };
        let [r0, r1] = self.mode.rows();
        let mut twist = Vector6::zeros();
        twist[r0] = a0 * limit(r0) * slowdown;
        twist[r1] = a1 * limit(r1) * slowdown;
        let mut step = self.dls.step(&self.jac, &twist, out).ok()?;
        if self.params.lookahead_s > 0.0 {
            // The midpoint rule: solve again with the Jacobian half a period ahead.
            let mut mid = [0.0; kinematics::MAX_DOF];
            for ((m, qi), v) in mid.iter_mut().zip(q).zip(out.iter()) {
                *m = qi + v * self.params.lookahead_s;
            }
            self.jacobian(&mid[..n])?;
            step = self.dls.step(&self.jac, &twist, out).ok()?;
        }
        self.last = Diagnostics {
            condition,
            slowdown,
            twist: twist.into(),
            sigma_min: step.sigma_min,
        };
        Some(())
    }
}

impl ActionMap for ModeSwitchMap {
    fn kind(&self) -> ModelKind {
        ModelKind::ModeSwitch
    }

    fn n_joints(&self) -> usize {
        self.chain.n_joints()
    }

    fn latent_dim(&self) -> usize {
        ipc_types::ACTION_DIM
    }

    fn eval(&mut self, q: &[f64], _c: f64, a: &[f64], out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        if self.eval_inner(q, a, out).is_none() {
            // A mis-shaped or non-finite input: no motion.
            out.iter_mut().for_each(|v| *v = 0.0);
        }
    }

    fn press(&mut self, pressed: u32) {
        if pressed & ipc_types::buttons::MODE != 0 {
            self.mode = self.mode.next();
            self.switches = self.switches.saturating_add(1);
        }
    }

    fn mode(&self) -> Option<MapMode> {
        Some(MapMode {
            index: self.mode.index() as u32,
            name: self.mode.name(),
            switches: self.switches,
        })
    }
}

/// A header-only model file of kind `modeswitch` holding `params` (safetensors bytes, no
/// tensors). `command` is recorded in the header's provenance.
pub fn to_bytes(params: &ModeSwitchParams, command: &str) -> Result<Vec<u8>, ModelError> {
    let header = ModeSwitchMap::header(command);
    let encode = |e: serde_json::Error| ModelError::BadHeader {
        path: Path::new(SPEC).to_owned(),
        reason: e.to_string(),
    };
    let meta = HashMap::from([
        (
            HEADER_KEY.to_owned(),
            serde_json::to_string(&header).map_err(encode)?,
        ),
        (
            PARAMS_KEY.to_owned(),
            serde_json::to_string(params).map_err(encode)?,
        ),
    ]);
    let none: Vec<(String, safetensors::tensor::TensorView<'_>)> = Vec::new();
    safetensors::serialize(none, Some(meta)).map_err(|e| ModelError::NotSafetensors {
        path: Path::new(SPEC).to_owned(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LoadedModel;
    use crate::step::MapperStep;
    use ipc_types::{JoystickInput, NO_TICK, RobotState, buttons};
    use nalgebra::{Isometry3, Vector3};

    const DT: f64 = 0.025;

    fn joy(axes: [f32; 2], buttons: u32) -> JoystickInput {
        JoystickInput {
            tick: NO_TICK,
            t_ns: 1,
            seq: 0,
            axes,
            gripper: 0.0,
            buttons,
        }
    }

    fn state_at(q: &[f64; 6], tick: u64) -> RobotState {
        let mut s = RobotState::at_rest(tick, 1, 6);
        s.q_rad[..6].copy_from_slice(q);
        s
    }

    /// Drives a mapper step for `ticks` ticks with `axes` held, integrating the commanded joint
    /// velocities like the mock arm; returns the TCP pose before and after.
    fn drive(
        step: &mut MapperStep,
        q: &mut [f64; 6],
        axes: [f32; 2],
        ticks: u64,
    ) -> (Isometry3<f64>, Isometry3<f64>) {
        let arm = Gen3Lite::get().arm();
        let before = arm.fk(q).unwrap();
        for k in 0..ticks {
            let c = step.step(&state_at(q, k), Some(&joy(axes, 0)));
            assert_eq!(c.flags, 0);
            for i in 0..6 {
                q[i] += c.qdot_rad_s[i] * DT;
            }
        }
        (before, arm.fk(q).unwrap())
    }

    fn modeswitch_step() -> MapperStep {
        MapperStep::new(3, LoadedModel::load(SPEC).unwrap(), 6).unwrap()
    }

    /// Presses and releases the mode button once (two ticks).
    fn press_mode(step: &mut MapperStep, q: &[f64; 6]) {
        step.step(&state_at(q, 0), Some(&joy([0.0, 0.0], buttons::MODE)));
        step.step(&state_at(q, 1), Some(&joy([0.0, 0.0], 0)));
    }

    /// Linear displacement and rotation vector (base frame) from `a` to `b`.
    fn motion(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        let e = kinematics::pose_error(a, b);
        (
            Vector3::new(e[0], e[1], e[2]),
            Vector3::new(e[3], e[4], e[5]),
        )
    }

    #[test]
    fn each_mode_moves_the_tcp_along_its_own_axes_only() {
        // (mode, axes, linear or angular, the base axis of the motion, the expected amount)
        let cases = [
            (Mode::XY, [1.0, 0.0], false, 0, 0.3),
            (Mode::XY, [0.0, 1.0], false, 1, 0.3),
            (Mode::XY, [-1.0, 0.0], false, 0, -0.3),
            (Mode::ZYaw, [0.0, 1.0], false, 2, 0.3),
            (Mode::ZYaw, [0.0, -1.0], false, 2, -0.3),
            (Mode::ZYaw, [1.0, 0.0], true, 2, 0.85),
            (Mode::RollPitch, [1.0, 0.0], true, 0, 0.85),
            (Mode::RollPitch, [0.0, 1.0], true, 1, 0.85),
            (Mode::RollPitch, [0.0, -1.0], true, 1, -0.85),
        ];
        let ticks = 20; // 0.5 s
        for (mode, axes, angular, axis, rate) in cases {
            let mut step = modeswitch_step();
            let mut q = gen3_lite::HOME;
            for _ in 0..mode.index() {
                press_mode(&mut step, &q);
            }
            assert_eq!(step.mode().unwrap().name, mode.name());
            let (a, b) = drive(&mut step, &mut q, axes, ticks);
            let (dp, dr) = motion(&a, &b);
            let expected = rate * ticks as f64 * DT;
            let (moved, other_lin, other_ang) = if angular {
                let mut rest = dr;
                rest[axis] = 0.0;
                (dr[axis], dp.norm(), rest.norm())
            } else {
                let mut rest = dp;
                rest[axis] = 0.0;
                (dp[axis], rest.norm(), dr.norm())
            };
            let what = format!("{} {axes:?}: dp {dp:?} dr {dr:?}", mode.name());
            // Near home the arm is far from singular: the full speed.
            assert!((moved - expected).abs() < 0.01 * expected.abs(), "{what}");
            // Cross-talk: under 0.5 mm of other translation and 1 mrad of other rotation,
            // over 0.15 m or 0.42 rad of motion (measured: 0.05 mm, 0.16 mrad at most).
            assert!(other_lin < 5e-4, "{what}: other translation {other_lin}");
            assert!(other_ang < 1e-3, "{what}: other rotation {other_ang}");
        }
    }

    #[test]
    fn twist_is_within_the_cartesian_limits() {
        let arm = Gen3Lite::get().arm();
        let mut map = ModeSwitchMap::new(ModeSwitchParams::default(), SPEC).unwrap();
        let q = gen3_lite::HOME;
        let start = arm.fk(&q).unwrap();
        for mode in Mode::ALL {
            for k in 0..16 {
                let th = k as f64 * std::f64::consts::PI / 8.0;
                let a = [th.cos(), th.sin()];
                let mut qd = [0.0; 6];
                map.eval(&q, 0.0, &a, &mut qd);
                // The TCP's motion over one tick with the command held, as the arm runs it.
                let mut next = q;
                for i in 0..6 {
                    next[i] += qd[i] * DT;
                }
                let v = kinematics::pose_error(&start, &arm.fk(&next).unwrap()) / DT;
                let lin = v.fixed_rows::<3>(0).norm();
                let ang = v.fixed_rows::<3>(3).norm();
                assert!(lin <= 0.3 * 1.001 && ang <= 0.85 * 1.001, "{mode:?} {a:?}");
                // The driven components are as asked, to 0.1 %.
                let [r0, r1] = mode.rows();
                let limit = |r: usize| if r < 3 { 0.3 } else { 0.85 };
                assert!(
                    (v[r0] - a[0] * limit(r0)).abs() < 1e-3 * limit(r0),
                    "{mode:?} {v:?}"
                );
                assert!(
                    (v[r1] - a[1] * limit(r1)).abs() < 1e-3 * limit(r1),
                    "{mode:?} {v:?}"
                );
            }
            map.press(buttons::MODE);
        }
        // A zero input is a zero command, without touching the kinematics.
        let mut qd = [1.0; 6];
        map.eval(&gen3_lite::HOME, 0.0, &[0.0, 0.0], &mut qd);
        assert_eq!(qd, [0.0; 6]);
    }

    #[test]
    fn the_mode_button_counts_presses_not_held_ticks() {
        let mut step = modeswitch_step();
        let q = gen3_lite::HOME;
        let mode_of = |s: &MapperStep| s.mode().map(|m| (m.name, m.switches));
        assert_eq!(mode_of(&step), Some(("x-y", 0)));
        // Held for 10 ticks: one press.
        for k in 0..10 {
            step.step(&state_at(&q, k), Some(&joy([0.0, 0.0], buttons::MODE)));
        }
        assert_eq!(mode_of(&step), Some(("z-yaw", 1)));
        // Other buttons do not switch; a stale sample neither releases nor presses.
        step.step(&state_at(&q, 10), Some(&joy([0.0, 0.0], buttons::DEADMAN)));
        assert_eq!(mode_of(&step), Some(("z-yaw", 1)));
        let mut stale = joy([0.0, 0.0], buttons::MODE);
        stale.tick = 3;
        step.step(&state_at(&q, 11), Some(&stale));
        step.step(&state_at(&q, 12), None);
        assert_eq!(mode_of(&step), Some(("z-yaw", 1)));
        // Two more presses: roll-pitch, then back to x-y.
        press_mode(&mut step, &q);
        assert_eq!(mode_of(&step), Some(("roll-pitch", 2)));
        step.step(
            &state_at(&q, 2),
            Some(&joy([0.0, 0.0], buttons::MODE | buttons::DEADMAN)),
        );
        assert_eq!(mode_of(&step), Some(("x-y", 3)));
        // A map without modes reports none.
        let pca = MapperStep::new(1, LoadedModel::load("bundled").unwrap(), 6).unwrap();
        assert_eq!(pca.mode(), None);
    }

    #[test]
    fn slows_down_near_a_singularity_and_stays_bounded() {
        let p = ModeSwitchParams::default();
        assert_eq!(p.slowdown(1.0), 1.0);
        assert_eq!(p.slowdown(p.slowdown_start_condition), 1.0);
        assert_eq!(
            p.slowdown(p.slowdown_full_condition),
            p.slowdown_min_fraction
        );
        assert_eq!(p.slowdown(f64::INFINITY), p.slowdown_min_fraction);
        let mid = 0.5 * (p.slowdown_start_condition + p.slowdown_full_condition);
        assert!((p.slowdown(mid) - 0.5 * (1.0 + p.slowdown_min_fraction)).abs() < 1e-12);

        let mut map = ModeSwitchMap::new(p, SPEC).unwrap();
        let mut qd = [0.0; 6];
        map.eval(&gen3_lite::HOME, 0.0, &[1.0, 0.0], &mut qd);
        let home = map.diagnostics();
        assert_eq!(home.slowdown, 1.0, "{home:?}");
        // The zero pose (arm straight up) is singular: the twist is cut to its slowest, and
        // the damped step stays finite and bounded.
        let near_zero = [0.0, 1e-3, 0.0, 0.0, 1e-3, 0.0];
        for mode in Mode::ALL {
            for a in [[1.0, 0.0], [0.0, 1.0], [0.7, -0.7]] {
                map.eval(&near_zero, 0.0, &a, &mut qd);
                let d = map.diagnostics();
                assert!(d.condition > p.slowdown_full_condition, "{mode:?}: {d:?}");
                assert_eq!(d.slowdown, p.slowdown_min_fraction);
                let n = qd.iter().map(|v| v * v).sum::<f64>().sqrt();
                assert!(
                    qd.iter().all(|v| v.is_finite()) && n < 10.0,
                    "{mode:?}: {n}"
                );
            }
            map.press(buttons::MODE);
        }
    }

    #[test]
    fn specs_and_files() {
        assert!(is_spec("modeswitch") && is_spec("modeswitch:max_linear_m_s=0.1"));
        assert!(!is_spec("modeswitch.safetensors") && !is_spec("bundled"));
        assert!(crate::model::is_builtin("modeswitch") && crate::model::is_builtin("bundled"));
        let m =
            LoadedModel::load("modeswitch:max_linear_m_s=0.1, slowdown_min_fraction=0.5").unwrap();
        assert_eq!(m.header.kind, ModelKind::ModeSwitch);
        assert_eq!(m.header.speed_scale_rad_s, 1.0);
        m.expect_dims(6, 2).unwrap();
        for (spec, needle) in [
            ("modeswitch:max_linear_m_s=-1", "max_linear_m_s"),
            ("modeswitch:speed=1", "`speed` is not a parameter"),
            (
                "modeswitch:max_angular_rad_s=fast",
                "`fast` is not a number",
            ),
            ("modeswitch:max_angular_rad_s", "not key=value"),
            (
                "modeswitch:slowdown_full_condition=10",
                "slowdown_full_condition",
            ),
        ] {
            let e = LoadedModel::load(spec).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains(spec), "{spec}: {e}");
        }
        // A header-only file with parameters in its metadata.
        let params = ModeSwitchParams {
            max_linear_m_s: 0.2,
            ..ModeSwitchParams::default()
        };
        let bytes = to_bytes(&params, "test").unwrap();
        let m = LoadedModel::from_bytes(&bytes, Path::new("ms.safetensors")).unwrap();
        assert_eq!(m.header.kind, ModelKind::ModeSwitch);
        assert_eq!(m.map.kind(), ModelKind::ModeSwitch);
        let mut qd = [0.0; 6];
        let mut map = m.map;
        map.eval(&gen3_lite::HOME, 0.0, &[1.0, 0.0], &mut qd);
        let arm = Gen3Lite::get().arm();
        let mut next = gen3_lite::HOME;
        for i in 0..6 {
            next[i] += qd[i] * DT;
        }
        let v = kinematics::pose_error(&arm.fk(&gen3_lite::HOME).unwrap(), &arm.fk(&next).unwrap())
            / DT;
        assert!((v[0] - 0.2).abs() < 1e-3, "{v:?}");
        // Bad parameters in a file name the file.
        let bad = ModeSwitchParams {
            slowdown_min_fraction: 0.0,
            ..ModeSwitchParams::default()
        };
        let e = LoadedModel::from_bytes(&to_bytes(&bad, "t").unwrap(), Path::new("ms.st"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("ms.st") && e.contains("slowdown_min_fraction"),
            "{e}"
        );
    }

    #[test]
    fn modes_cycle_in_order() {
        assert_eq!(Mode::XY.next(), Mode::ZYaw);
        assert_eq!(Mode::ZYaw.next(), Mode::RollPitch);
        assert_eq!(Mode::RollPitch.next(), Mode::XY);
        for m in Mode::ALL {
            assert_eq!(Mode::from_index(m.index()), Some(m));
        }
        assert_eq!(Mode::from_index(3), None);
    }
}
