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
//! The map drives the arm of a robot profile ([`kinematics::RobotProfile`], the graph's robot;
//! [`ModeSwitchMap::new_for`], [`LoadedModel::load_for`](crate::LoadedModel::load_for)): its
//! chain gives the Jacobian, its teleoperation limits the joint limits below.
//!
//! The arm's joint limits (the safety filter's defaults) shape the twist before the safety
//! filter has to: a twist the joints cannot follow is scaled down as a whole, and the twist is
//! ramped: each tick's is `x P + y T`, last tick's `P` and the input's `T` blended as close to
//! `T` as the joint acceleration limits allow from last tick's command (a two-variable convex
//! programme). Where merely holding a fast twist would take most of the acceleration room (the
//! Jacobian turning quickly as the arm moves), the twist is capped lower. So the safety
//! filter's joint-space acceleration limit, which scales each joint's change and would bend the
//! tool's path, rarely acts; a hold along one axis stays on that axis from start to stop, and a
//! release stops the tool on its path.
//!
//! On a redundant arm (more joints than the twist's six rows: the 7-joint Gen3) a secondary
//! task runs in the Jacobian's null space: each limited joint is pushed back towards the
//! middle of its range, the push projected so that the tool does not feel it
//! ([`ModeSwitchParams::null_space_gain_rad_s`]), in proportion to the twist's speed, so the
//! arm is still when the stick is released. It goes through the same ramp and limits as the
//! twist's joint velocities, and allocates nothing.
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

use kinematics::{Chain, Dls, Jacobian, RobotProfile, TaskMask};
use nalgebra::{Matrix6, Vector6};
use serde::{Deserialize, Serialize};

use crate::model::{FORMAT, HEADER_KEY, ModelError, ModelHeader, ModelKind, TrainingInfo, VERSION};
use crate::{ActionMap, MapMode};

/// The model spec that serves a mode-switching map with default parameters; `SPEC:key=value,...`
/// sets some.
pub const SPEC: &str = "modeswitch";

/// The ramp takes this fraction of the room the acceleration limits leave, keeping some for
/// the midpoint correction.
const RAMP_MARGIN: f64 = 0.97;

/// The share of the joint acceleration room that merely holding the twist may take before the
/// twist is capped.
const HOLD_SHARE: f64 = 0.5;

/// One joint's numbers for [`blend`]: its velocity for last tick's twist and for the input's
/// at this pose, last tick's command, the change allowed in one tick, the speed limit.
#[derive(Debug, Clone, Copy, Default)]
struct Limit {
    hold: f64,
    want: f64,
    last: f64,
    room: f64,
    speed: f64,
}

/// The largest factor `k <= 1` by which the change from each joint's last command to `to(l)`
/// fits its acceleration room.
fn change_scale(lim: &[Limit], to: impl Fn(&Limit) -> f64) -> f64 {
    lim.iter()
        .map(|l| {
            let d = (to(l) - l.last).abs();
            if d > l.room { l.room / d } else { 1.0 }
        })
        .fold(1.0, f64::min)
}

/// The weights `(x, y)` of the twist `x P + y T` closest to `T` (in the metric whose Gram
/// matrix of `(P, T)` is `gram`) with `0 <= x, y <= 1` whose joint velocities `x hold + y want`
/// are within every joint's speed limit and within its acceleration room of last tick's
/// command; `None` if there is none. A two-variable convex quadratic programme over a
/// polygon: the unconstrained optimum `(0, 1)` if feasible, else the best point on an edge.
fn blend(lim: &[Limit], gram: [[f64; 2]; 2]) -> Option<(f64, f64)> {
    // Half-planes a . (x, y) <= b.
    const MAX: usize = 4 * kinematics::MAX_DOF + 4;
    let mut hp = [([0.0f64; 2], 0.0f64); MAX];
    let mut m = 0;
    let mut add = |a: [f64; 2], b: f64| {
        hp[m] = (a, b);
        m += 1;
    };
    for l in lim {
        let a = [l.hold, l.want];
        let neg = [-l.hold, -l.want];
        add(a, l.last + l.room);
        add(neg, l.room - l.last);
        add(a, l.speed);
        add(neg, l.speed);
    }
    add([-1.0, 0.0], 0.0);
    add([0.0, -1.0], 0.0);
    add([1.0, 0.0], 1.0);
    add([0.0, 1.0], 1.0);
    let hp = &hp[..m];
    let tol = |b: f64| 1e-12 * (1.0 + b.abs());
    let feasible = |z: [f64; 2]| {
        hp.iter()
            .all(|(a, b)| a[0] * z[0] + a[1] * z[1] <= b + tol(*b))
    };
    // f(x, y) = |x P + (y - 1) T|^2.
    let f = |z: [f64; 2]| {
        let (u, v) = (z[0], z[1] - 1.0);
        gram[0][0] * u * u + 2.0 * gram[0][1] * u * v + gram[1][1] * v * v
    };
    if feasible([0.0, 1.0]) {
        return Some((0.0, 1.0));
    }
    let mut best: Option<([f64; 2], f64)> = None;
    for (k, (a, b)) in hp.iter().enumerate() {
        let nn = a[0] * a[0] + a[1] * a[1];
        if nn < 1e-300 {
            continue;
        }
        // The line a . z = b: z = z0 + t d.
        let z0 = [a[0] * b / nn, a[1] * b / nn];
        let d = [-a[1], a[0]];
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for (i, (c, e)) in hp.iter().enumerate() {
            if i == k {
                continue;
            }
            let cd = c[0] * d[0] + c[1] * d[1];
            let slack = e - (c[0] * z0[0] + c[1] * z0[1]);
            if cd.abs() < 1e-300 {
                if slack < -tol(*e) {
                    lo = f64::INFINITY;
                }
            } else if cd > 0.0 {
                hi = hi.min(slack / cd);
            } else {
                lo = lo.max(slack / cd);
            }
        }
        if lo.is_nan() || hi.is_nan() || lo > hi + 1e-12 {
            continue;
        }
        // f along the line: alpha t^2 + beta t + const.
        let (u0, v0) = (z0[0], z0[1] - 1.0);
        let alpha =
            gram[0][0] * d[0] * d[0] + 2.0 * gram[0][1] * d[0] * d[1] + gram[1][1] * d[1] * d[1];
        let beta = 2.0
            * (gram[0][0] * u0 * d[0]
                + gram[0][1] * (u0 * d[1] + v0 * d[0])
                + gram[1][1] * v0 * d[1]);
        let t = if alpha > 1e-300 {
            -beta / (2.0 * alpha)
        } else {
            0.0
        };
        let t = t.clamp(lo, hi.max(lo));
        let z = [z0[0] + t * d[0], z0[1] + t * d[1]];
        if !t.is_finite() || !feasible(z) {
            continue;
        }
        let v = f(z);
        if best.is_none_or(|(_, bv)| v < bv) {
            best = Some((z, v));
        }
    }
    best.map(|(z, _)| (z[0].clamp(0.0, 1.0), z[1].clamp(0.0, 1.0)))
}

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

/// Parameters of a mode-switching map; every one has a default (the arm's from its robot
/// profile, [`ModeSwitchParams::for_robot`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// The tick period (s), for the acceleration ramp.
    pub period_s: f64,
    /// Joint speed limits (rad/s), the safety filter's defaults: a twist that would need more
    /// is scaled down as a whole (as the safety filter would) before it is ramped to.
    pub max_joint_velocity_rad_s: Vec<f64>,
    /// Joint acceleration limits the twist is ramped within (rad/s²), the safety filter's
    /// defaults: the twist changes (towards the input, and back to rest) only as fast as the
    /// joints may follow, so the safety filter's joint-space acceleration limit, which would
    /// bend the tool's path, does not have to act.
    pub max_joint_acceleration_rad_s2: Vec<f64>,
    /// The null-space secondary task on a redundant arm (more joints than the twist's six
    /// rows; nothing on a 6-joint arm): the joint velocity (rad/s) with which a joint at its
    /// limit is pushed back towards the middle of its range, at full twist speed. The push
    /// grows with the cube of the joint's offset from the middle (an eighth of it half-way),
    /// is projected into the Jacobian's null space (it does not change the tool's twist),
    /// scales with the twist's speed (the arm stays still when the stick is released), and
    /// leaves the continuous joints alone (they have no limits to keep away from). 0 turns it
    /// off.
    pub null_space_gain_rad_s: f64,
}

impl Default for ModeSwitchParams {
    /// [`ModeSwitchParams::for_robot`] of the default robot profile.
    fn default() -> Self {
        Self::for_robot(RobotProfile::default_robot())
    }
}

impl ModeSwitchParams {
    /// The defaults on `robot`: its control period, its teleoperation joint limits (the safety
    /// filter's defaults), the twist limits and damping for any arm.
    pub fn for_robot(robot: &RobotProfile) -> Self {
        let dls = Dls::default();
        let rate_hz = robot.control_rate_hz();
        Self {
            max_linear_m_s: 0.3,
            max_angular_rad_s: 0.85,
            slowdown_start_condition: 40.0,
            slowdown_full_condition: 150.0,
            slowdown_min_fraction: 0.2,
            dls_singular_threshold: dls.singular_threshold,
            dls_max_damping: dls.max_damping,
            lookahead_s: 0.5 / rate_hz,
            period_s: 1.0 / rate_hz,
            max_joint_velocity_rad_s: robot.limits().max_velocity_rad_s.clone(),
            max_joint_acceleration_rad_s2: robot.limits().max_acceleration_rad_s2.clone(),
            null_space_gain_rad_s: 0.2,
        }
    }

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
            ("period_s", self.period_s),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err((key, format!("{v} must be a positive number")));
            }
        }
        for (key, values) in [
            ("max_joint_velocity_rad_s", &self.max_joint_velocity_rad_s),
            (
                "max_joint_acceleration_rad_s2",
                &self.max_joint_acceleration_rad_s2,
            ),
        ] {
            if let Some(a) = values.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
                return Err((key, format!("{a} must be a positive number")));
            }
        }
        if !(self.null_space_gain_rad_s.is_finite() && self.null_space_gain_rad_s >= 0.0) {
            return Err((
                "null_space_gain_rad_s",
                format!(
                    "{} must be a number of at least 0",
                    self.null_space_gain_rad_s
                ),
            ));
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
                "period_s" => &mut self.period_s,
                "null_space_gain_rad_s" => &mut self.null_space_gain_rad_s,
                other => {
                    return Err(format!(
                        "`{other}` is not a parameter (max_linear_m_s, max_angular_rad_s, \
                         slowdown_start_condition, slowdown_full_condition, \
                         slowdown_min_fraction, dls_singular_threshold, dls_max_damping, \
                         lookahead_s, period_s, null_space_gain_rad_s; the joint limits only \
                         in a model file)"
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
    /// The share `y` of the input's twist `T` in the command's `x P + y T` (`P` last tick's);
    /// when `P` and `T` are parallel only `x |P| + y |T|` is determined.
    pub ramp: f64,
    /// The share `x` of last tick's twist carried over.
    pub carry: f64,
    /// The joint limits kept the command's twist from the input's this tick.
    pub limited: bool,
    /// No twist in the span of last tick's and the input's met the joint limits: the joints
    /// were moved towards the input's command within their acceleration limits instead.
    pub fallback: bool,
    /// The factor that brought the input's twist within the joint speed limits (1: none).
    pub joint_speed_fit: f64,
    /// The further factor that kept the twist slow enough to be held within the joint
    /// acceleration limits where the arm's pose turns quickly (1: none).
    pub speed_cap: f64,
}

/// The mode-switching map on a robot profile's arm.
#[derive(Debug, Clone)]
pub struct ModeSwitchMap {
    robot: &'static RobotProfile,
    chain: &'static Chain,
    params: ModeSwitchParams,
    dls: Dls,
    mode: Mode,
    switches: u32,
    jac: Jacobian,
    /// The twist commanded last tick (after the ramp) and the joint velocity it gave.
    twist: Vector6<f64>,
    qdot: [f64; kinematics::MAX_DOF],
    last: Diagnostics,
}

impl ModeSwitchMap {
    /// A map on the default robot profile's arm ([`ModeSwitchMap::new_for`]).
    pub fn new(params: ModeSwitchParams, model: &str) -> Result<Self, ModelError> {
        Self::new_for(RobotProfile::default_robot(), params, model)
    }

    /// A map on `robot`'s arm, in the x-y mode; `model` names it in the error when a
    /// parameter is out of range or the joint limits do not fit the arm.
    pub fn new_for(
        robot: &'static RobotProfile,
        params: ModeSwitchParams,
        model: &str,
    ) -> Result<Self, ModelError> {
        params.validate(model)?;
        let chain = robot.arm();
        let n = chain.n_joints();
        for (key, values) in [
            ("max_joint_velocity_rad_s", &params.max_joint_velocity_rad_s),
            (
                "max_joint_acceleration_rad_s2",
                &params.max_joint_acceleration_rad_s2,
            ),
        ] {
            if values.len() != n {
                return Err(ModelError::Parameters {
                    model: model.to_owned(),
                    reason: format!(
                        "{key}: {} entries; {} has {n} joints",
                        values.len(),
                        robot.name()
                    ),
                });
            }
        }
        let dls = Dls {
            mask: TaskMask::POSE,
            singular_threshold: params.dls_singular_threshold,
            max_damping: params.dls_max_damping,
            ..Dls::default()
        };
        Ok(Self {
            robot,
            chain,
            params,
            dls,
            mode: Mode::XY,
            switches: 0,
            jac: Jacobian::zeros(chain.n_joints()),
            twist: Vector6::zeros(),
            qdot: [0.0; kinematics::MAX_DOF],
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

    /// The robot profile the map drives.
    pub fn robot(&self) -> &'static RobotProfile {
        self.robot
    }

    /// The header of a mode-switching model on the default robot profile
    /// ([`ModeSwitchMap::header_for`]).
    pub fn header(command: &str) -> ModelHeader {
        Self::header_for(RobotProfile::default_robot(), command)
    }

    /// The header of a mode-switching model on `robot` (speed scale 1: the output is in
    /// rad/s).
    pub fn header_for(robot: &RobotProfile, command: &str) -> ModelHeader {
        ModelHeader {
            format: FORMAT.to_owned(),
            version: VERSION,
            kind: ModelKind::ModeSwitch,
            n_joints: robot.n_joints(),
            latent_dim: ipc_types::ACTION_DIM,
            joint_names: robot.joint_names().to_vec(),
            speed_scale_rad_s: 1.0,
            lipschitz_bound: None,
            network: None,
            training: TrainingInfo {
                command: command.to_owned(),
                ..TrainingInfo::default()
            },
        }
    }

    /// The map and header for a spec `modeswitch[:key=value,...]` on the default robot
    /// profile ([`ModeSwitchMap::from_spec_for`]).
    pub fn from_spec(spec: &str) -> Result<(ModelHeader, Self), ModelError> {
        Self::from_spec_for(RobotProfile::default_robot(), spec)
    }

    /// The map and header for a spec `modeswitch[:key=value,...]` on `robot`.
    pub fn from_spec_for(
        robot: &'static RobotProfile,
        spec: &str,
    ) -> Result<(ModelHeader, Self), ModelError> {
        let overrides = spec.strip_prefix(SPEC).unwrap_or_default();
        let overrides = overrides.strip_prefix(':').unwrap_or(overrides);
        let bad = |reason: String| ModelError::Parameters {
            model: spec.to_owned(),
            reason,
        };
        let params = ModeSwitchParams::for_robot(robot)
            .with_overrides(overrides)
            .map_err(bad)?;
        let map = Self::new_for(robot, params, spec)?;
        Ok((Self::header_for(robot, spec), map))
    }

    /// The map of a header-only model file of kind `modeswitch` on the default robot profile
    /// ([`ModeSwitchMap::from_file_for`]).
    pub fn from_file(bytes: &[u8], header: &ModelHeader, path: &Path) -> Result<Self, ModelError> {
        Self::from_file_for(RobotProfile::default_robot(), bytes, header, path)
    }

    /// The map of a header-only model file of kind `modeswitch` on `robot`: parameters from
    /// the metadata entry [`PARAMS_KEY`] (the robot's defaults where absent). The header must
    /// name the robot's arm joints.
    pub fn from_file_for(
        robot: &'static RobotProfile,
        bytes: &[u8],
        header: &ModelHeader,
        path: &Path,
    ) -> Result<Self, ModelError> {
        if header.joint_names != robot.joint_names() {
            return Err(ModelError::BadHeader {
                path: path.to_owned(),
                reason: format!(
                    "a modeswitch model drives the {}'s joints {:?}, the header names {:?}",
                    robot.description(),
                    robot.joint_names(),
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
            None => ModeSwitchParams::for_robot(robot),
        };
        Self::new_for(robot, params, &path.display().to_string())
    }

    /// The inner product of twists that weighs a rotation at the angular limit like a
    /// translation at the linear one.
    fn dot(&self, u: &Vector6<f64>, v: &Vector6<f64>) -> f64 {
        let r = self.params.max_linear_m_s / self.params.max_angular_rad_s;
        (0..6)
            .map(|i| u[i] * v[i] * if i < 3 { 1.0 } else { r * r })
            .sum()
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

    /// The twist's speed as a fraction of full speed (in `[0, 1]`): what the null-space task
    /// is scaled by.
    fn speed_fraction(&self, twist: &Vector6<f64>) -> f64 {
        (self.dot(twist, twist).sqrt() / self.params.max_linear_m_s).min(1.0)
    }

    /// The null-space secondary task at `q` at full twist speed, with the Jacobian at `q` in
    /// `self.jac`, into `out[..n]`: the push of each limited joint back towards the middle of
    /// its range ([`ModeSwitchParams::null_space_gain_rad_s`]), less what of it the tool
    /// would feel, `g - J⁺ (J g)` with the damped pseudo-inverse. Zero on an arm with no more
    /// joints than the task's rows, where the null space is empty.
    fn null_motion(&self, q: &[f64], out: &mut [f64]) -> Option<()> {
        let n = self.chain.n_joints();
        let out = out.get_mut(..n)?;
        out.fill(0.0);
        let gain = self.params.null_space_gain_rad_s;
        if gain == 0.0 || n <= self.dls.mask.dim() {
            return Some(());
        }
        let limits = self.robot.limits();
        let mut g = nalgebra::SVector::<f64, { kinematics::MAX_DOF }>::zeros();
        for (j, continuous) in self.robot.continuous_joints().iter().enumerate().take(n) {
            let (lo, hi) = (*limits.lower_rad.get(j)?, *limits.upper_rad.get(j)?);
            if *continuous || hi <= lo {
                continue;
            }
            let r = ((*q.get(j)? - 0.5 * (lo + hi)) / (0.5 * (hi - lo))).clamp(-1.0, 1.0);
            g[j] = -gain * r * r * r;
        }
        let seen: Vector6<f64> = self.jac.padded() * g;
        let mut back = [0.0; kinematics::MAX_DOF];
        self.dls.step(&self.jac, &seen, &mut back[..n]).ok()?;
        for ((o, gj), b) in out.iter_mut().zip(g.iter()).zip(back) {
            *o = gj - b;
        }
        Some(())
    }

    /// [`ActionMap::direction`]: the current mode's twist for a full deflection of `axis`
    /// (with the slowdown near singularities) through damped least squares at `q`.
    fn direction_inner(&mut self, q: &[f64], axis: usize, out: &mut [f64]) -> Option<()> {
        let n = self.chain.n_joints();
        let out = out.get_mut(..n)?;
        let q = q.get(..n)?;
        let row = *self.mode.rows().get(axis)?;
        let condition = self.jacobian(q)?;
        let limit = if row < 3 {
            self.params.max_linear_m_s
        } else {
            self.params.max_angular_rad_s
        };
        let mut target = Vector6::zeros();
        target[row] = limit * self.params.slowdown(condition);
        self.dls.step(&self.jac, &target, out).ok()?;
        Some(())
    }

    /// [`ActionMap::eval`]: the joint velocities for input `a` at `q`, in phases: the input's
    /// twist, each joint's limits for it, the twist scaled to fit them, the blend with last
    /// tick's twist, the midpoint correction and the acceleration clamp.
    fn eval_inner(&mut self, q: &[f64], a: &[f64], out: &mut [f64]) -> Option<()> {
        let n = self.chain.n_joints();
        let out = out.get_mut(..n)?;
        let q = q.get(..n)?;
        let (a0, a1) = (*a.first()?, *a.get(1)?);
        if a0 == 0.0 && a1 == 0.0 && self.twist == Vector6::zeros() {
            self.stay_at_rest();
            return Some(());
        }
        let condition = self.jacobian(q)?;
        let slowdown = self.params.slowdown(condition);
        let mut target = self.input_twist(a0, a1, slowdown);
        let (mut lim, mut step) = self.joint_limits(q, &target)?;
        let lim = &mut lim[..n];
        let (speed_fit, fit) = self.fit_to_limits(lim, &mut target);
        let (twist, x, ramp, fallback) = self.blend_with_last_twist(lim, &target, out);
        if self.params.lookahead_s > 0.0 {
            step = self.midpoint_correction(q, &twist, out)?;
        }
        clamp_to_acceleration(lim, out);
        self.twist = twist;
        self.qdot[..n].copy_from_slice(out);
        self.last = Diagnostics {
            condition,
            slowdown,
            twist: twist.into(),
            sigma_min: step.sigma_min,
            ramp,
            carry: x,
            limited: fallback || (twist - target).norm() > 1e-9 * (1.0 + target.norm()),
            fallback,
            joint_speed_fit: speed_fit,
            speed_cap: fit / speed_fit,
        };
        Some(())
    }

    /// No input and no twist to carry: the command is zero and so are the diagnostics.
    fn stay_at_rest(&mut self) {
        self.qdot = [0.0; kinematics::MAX_DOF];
        self.last = Diagnostics {
            slowdown: 1.0,
            ramp: 1.0,
            joint_speed_fit: 1.0,
            speed_cap: 1.0,
            ..Diagnostics::default()
        };
    }

    /// The input's twist: the mode's two rows at their speed limits times the deflections,
    /// slowed near singularities.
    fn input_twist(&self, a0: f64, a1: f64, slowdown: f64) -> Vector6<f64> {
        let limit = |row: usize| {
            if row < 3 {
                self.params.max_linear_m_s
            } else {
                self.params.max_angular_rad_s
            }
        };
        let [r0, r1] = self.mode.rows();
        let mut target = Vector6::zeros();
        target[r0] = a0 * limit(r0) * slowdown;
        target[r1] = a1 * limit(r1) * slowdown;
        target
    }

    /// Each joint's [`Limit`] at `q` (the Jacobian already computed there): its velocity for
    /// last tick's twist and for `target`, null-space task included, last tick's command and
    /// its speed and acceleration limits; with the damped least-squares step of `target`.
    fn joint_limits(
        &self,
        q: &[f64],
        target: &Vector6<f64>,
    ) -> Option<([Limit; kinematics::MAX_DOF], kinematics::DlsStep)> {
        let n = self.chain.n_joints();
        // The joint velocities of last tick's twist and of the input's, at this pose (the
        // step is linear in the twist for a given Jacobian).
        let mut hold = [0.0; kinematics::MAX_DOF];
        let mut want = [0.0; kinematics::MAX_DOF];
        self.dls.step(&self.jac, &self.twist, &mut hold[..n]).ok()?;
        let step = self.dls.step(&self.jac, target, &mut want[..n]).ok()?;
        // On a redundant arm each twist's joint velocity carries the null-space task in
        // proportion to its speed, so the limits below see the command as it will be.
        let mut null = [0.0; kinematics::MAX_DOF];
        self.null_motion(q, &mut null)?;
        let (s_hold, s_want) = (
            self.speed_fraction(&self.twist),
            self.speed_fraction(target),
        );
        for ((h, w), v) in hold.iter_mut().zip(want.iter_mut()).zip(null) {
            *h += s_hold * v;
            *w += s_want * v;
        }
        let mut lim = [Limit::default(); kinematics::MAX_DOF];
        for (j, l) in lim.iter_mut().enumerate().take(n) {
            *l = Limit {
                hold: hold[j],
                want: want[j],
                last: self.qdot[j],
                room: self.params.max_joint_acceleration_rad_s2[j] * self.params.period_s,
                speed: self.params.max_joint_velocity_rad_s[j],
            };
        }
        Some((lim, step))
    }

    /// Scales `target` (and each joint's `want`) down as a whole to the joint speed limits
    /// and to the acceleration room holding last tick's twist leaves; returns the speed fit
    /// and the whole factor applied.
    fn fit_to_limits(&self, lim: &mut [Limit], target: &mut Vector6<f64>) -> (f64, f64) {
        // A twist the joints cannot follow is scaled down as a whole.
        let speed_fit = lim
            .iter()
            .map(|l| {
                if l.want.abs() > l.speed {
                    l.speed / l.want.abs()
                } else {
                    1.0
                }
            })
            .fold(1.0, f64::min);
        let mut fit = speed_fit;
        // Holding a twist takes joint accelerations that grow with the square of its speed
        // (the Jacobian turns as the arm moves); when last tick's twist used more than a share
        // of the acceleration room just to be held, the input's is capped below it, so there
        // is room left to steer and to stop on the path.
        let geometric = lim
            .iter()
            .map(|l| (l.hold - l.last).abs() / l.room)
            .fold(0.0, f64::max);
        if geometric > HOLD_SHARE {
            let cap = self.dot(&self.twist, &self.twist).sqrt() * (HOLD_SHARE / geometric).sqrt();
            let t = self.dot(target, target).sqrt();
            if t * fit > cap {
                fit = cap / t;
            }
        }
        if fit < 1.0 {
            *target *= fit;
            lim.iter_mut().for_each(|l| l.want *= fit);
        }
        (speed_fit, fit)
    }

    /// The command's twist and joint velocities (into `out`), blended from last tick's twist
    /// and `target` within the limits; returns the twist, the weight of last tick's, the ramp
    /// and whether no blend fitted (the joints then move towards the input's command).
    fn blend_with_last_twist(
        &self,
        lim: &[Limit],
        target: &Vector6<f64>,
        out: &mut [f64],
    ) -> (Vector6<f64>, f64, f64, bool) {
        let n = lim.len();
        // The command's twist, W = x P + y T (P last tick's, T the input's): as close to T as
        // the joint speed limits and the joint acceleration limits (from last tick's command)
        // allow, with a margin for the midpoint correction below, which moves the result a
        // little. W stays in the span of P and T, so a hold along one axis stays on it, and a
        // release brings the tool to rest along its path, as fast as the joints may stop.
        let mut tight = [Limit::default(); kinematics::MAX_DOF];
        for (t, l) in tight.iter_mut().zip(lim.iter()) {
            *t = Limit {
                room: l.room * RAMP_MARGIN,
                ..*l
            };
        }
        let p = self.twist;
        let gram = [
            [self.dot(&p, &p), self.dot(&p, target)],
            [self.dot(&p, target), self.dot(target, target)],
        ];
        match blend(&tight[..n], gram) {
            Some((x, y)) => {
                for (o, l) in out.iter_mut().zip(lim.iter()) {
                    *o = x * l.hold + y * l.want;
                }
                (p * x + target * y, x, y, false)
            }
            None => {
                // No such twist (the arm moves too fast for its pose to be held or left in
                // one tick): the joints move towards the input's command within their
                // acceleration limits, as the safety filter would have them, and the twist is
                // what that gives.
                let k = change_scale(lim, |l| l.want);
                for (o, l) in out.iter_mut().zip(lim.iter()) {
                    *o = l.last + k * (l.want - l.last);
                }
                let mut qd = nalgebra::SVector::<f64, { kinematics::MAX_DOF }>::zeros();
                qd.as_mut_slice()[..n].copy_from_slice(out);
                (self.jac.padded() * qd, 0.0, k, true)
            }
        }
    }

    /// The midpoint rule: `out` solved again for `twist` with the Jacobian half a period
    /// ahead (the lookahead), null-space task included; returns that step.
    fn midpoint_correction(
        &mut self,
        q: &[f64],
        twist: &Vector6<f64>,
        out: &mut [f64],
    ) -> Option<kinematics::DlsStep> {
        let n = out.len();
        let mut mid = [0.0; kinematics::MAX_DOF];
        for ((m, qi), v) in mid.iter_mut().zip(q).zip(out.iter()) {
            *m = qi + v * self.params.lookahead_s;
        }
        self.jacobian(&mid[..n])?;
        let step = self.dls.step(&self.jac, twist, out).ok()?;
        let mut null = [0.0; kinematics::MAX_DOF];
        self.null_motion(&mid[..n], &mut null)?;
        let s = self.speed_fraction(twist);
        for (o, v) in out.iter_mut().zip(null) {
            *o += s * v;
        }
        Some(step)
    }
}

/// The acceleration limit holds exactly: a change of `out` from each joint's last command
/// still past it is scaled down whole.
fn clamp_to_acceleration(lim: &mut [Limit], out: &mut [f64]) {
    for (l, o) in lim.iter_mut().zip(out.iter()) {
        l.want = *o;
    }
    let k = change_scale(lim, |l| l.want);
    if k < 1.0 {
        for (o, l) in out.iter_mut().zip(lim.iter()) {
            *o = l.last + k * (l.want - l.last);
        }
    }
}

impl ActionMap for ModeSwitchMap {
    fn kind(&self) -> ModelKind {
        ModelKind::ModeSwitch
    }

    /// The period and the look-ahead follow the graph's rate unless the spec or the model
    /// file set them to something else than the robot profile's defaults.
    fn set_period(&mut self, period_s: f64) {
        if !(period_s.is_finite() && period_s > 0.0) {
            return;
        }
        let rate_hz = self.robot.control_rate_hz();
        if self.params.period_s == 1.0 / rate_hz {
            self.params.period_s = period_s;
        }
        if self.params.lookahead_s == 0.5 / rate_hz {
            self.params.lookahead_s = 0.5 * period_s;
        }
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

    fn direction(&mut self, q: &[f64], _c: f64, axis: usize, out: &mut [f64]) {
        out.iter_mut().for_each(|v| *v = 0.0);
        if self.direction_inner(q, axis, out).is_none() {
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

/// A header-only model file of kind `modeswitch` on the default robot profile
/// ([`to_bytes_for`]).
pub fn to_bytes(params: &ModeSwitchParams, command: &str) -> Result<Vec<u8>, ModelError> {
    to_bytes_for(RobotProfile::default_robot(), params, command)
}

/// A header-only model file of kind `modeswitch` on `robot` holding `params` (safetensors
/// bytes, no tensors). `command` is recorded in the header's provenance.
pub fn to_bytes_for(
    robot: &RobotProfile,
    params: &ModeSwitchParams,
    command: &str,
) -> Result<Vec<u8>, ModelError> {
    let header = ModeSwitchMap::header_for(robot, command);
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

/// The name of a heartbeat's [`ipc_types::NodeStatus::mode`] (mode plus one; the mode-switching map's
/// modes are the only ones so far): `x-y`, `z-yaw`, `roll-pitch`, else `mode N`.
pub fn status_mode_name(mode: u32) -> String {
    let index = (mode as usize).saturating_sub(1);
    Mode::from_index(index).map_or_else(|| format!("mode {index}"), |m| m.name().to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::LoadedModel;
    use crate::step::MapperStep;
    use ipc_types::{JoystickInput, NO_TICK, RobotState, buttons};
    use kinematics::{Gen3Lite, gen3_lite};
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
            let mut j = joy(axes, 0);
            j.tick = k;
            let c = step.step(&state_at(q, k), Some(&j));
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
        // (mode, axes, linear or angular, the base axis of the motion, its sign)
        let cases = [
            (Mode::XY, [1.0, 0.0], false, 0, 1.0),
            (Mode::XY, [0.0, 1.0], false, 1, 1.0),
            (Mode::XY, [-1.0, 0.0], false, 0, -1.0),
            (Mode::ZYaw, [0.0, 1.0], false, 2, 1.0),
            (Mode::ZYaw, [0.0, -1.0], false, 2, -1.0),
            (Mode::ZYaw, [1.0, 0.0], true, 2, 1.0),
            (Mode::RollPitch, [1.0, 0.0], true, 0, 1.0),
            (Mode::RollPitch, [0.0, 1.0], true, 1, 1.0),
            (Mode::RollPitch, [0.0, -1.0], true, 1, -1.0),
        ];
        for (mode, axes, angular, axis, sign) in cases {
            let mut step = modeswitch_step();
            let mut q = gen3_lite::HOME;
            for _ in 0..mode.index() {
                press_mode(&mut step, &q);
            }
            assert_eq!(step.mode().unwrap().name, mode.name());
            // 1 s of full deflection from rest (the twist ramps up within the joint
            // acceleration limits), then 2 s of rest (it ramps down to a stop).
            let (a, _) = drive(&mut step, &mut q, axes, 40);
            let (_, b) = drive(&mut step, &mut q, [0.0, 0.0], 80);
            let c = step.step(&state_at(&q, 0), Some(&joy([0.0, 0.0], 0)));
            assert!(
                c.qdot_rad_s.iter().all(|v| *v == 0.0),
                "{mode:?}: not stopped"
            );
            let (dp, dr) = motion(&a, &b);
            let (moved, other_lin, other_ang) = if angular {
                let mut rest = dr;
                rest[axis] = 0.0;
                (dr[axis] * sign, dp.norm(), rest.norm())
            } else {
                let mut rest = dp;
                rest[axis] = 0.0;
                (dp[axis] * sign, rest.norm(), dr.norm())
            };
            let what = format!("{} {axes:?}: dp {dp:?} dr {dr:?}", mode.name());
            // Moved the intended way: at least 3 cm or 0.1 rad (measured: 4.3 cm .. 0.47 rad).
            assert!(moved > if angular { 0.1 } else { 0.03 }, "{what}");
            eprintln!("{what}");
            // Cross-talk: under 1 mm of other translation and 4 mrad of other rotation
            // (measured: 0.3 mm and 2.2 mrad at most, over 4 .. 17 cm or 0.35 .. 0.8 rad).
            assert!(other_lin < 1e-3, "{what}: other translation {other_lin}");
            assert!(other_ang < 4e-3, "{what}: other rotation {other_ang}");
        }
    }

    /// Parameters without joint limits to speak of, so the Cartesian ones act alone.
    fn cartesian_only() -> ModeSwitchParams {
        ModeSwitchParams {
            max_joint_velocity_rad_s: vec![100.0; 6],
            max_joint_acceleration_rad_s2: vec![1e6; 6],
            ..ModeSwitchParams::default()
        }
    }

    /// The map at the graph's rate: at 40 Hz and at 1 kHz the period and the look-ahead
    /// follow the graph (a value the spec sets stays), and the ramp's per-tick change is
    /// `max_joint_acceleration * period` at each.
    #[test]
    fn the_period_follows_the_graph_at_40_hz_and_1_khz() {
        for dt in [0.025, 0.001] {
            let model = LoadedModel::load(SPEC).unwrap().at_period(dt);
            let mut step = MapperStep::new(3, model, 6).unwrap();
            let p = ModeSwitchParams {
                period_s: dt,
                lookahead_s: 0.5 * dt,
                ..ModeSwitchParams::default()
            };
            let q = gen3_lite::HOME;
            let mut prev = [0.0; 6];
            let mut limited = 0;
            for k in 0..40u64 {
                let c = step.step(&state_at(&q, k), Some(&joy([1.0, 0.0], 0)));
                for j in 0..6 {
                    let dv = (c.qdot_rad_s[j] - prev[j]).abs();
                    let room = p.max_joint_acceleration_rad_s2[j] * dt;
                    assert!(
                        dv <= room * 1.02 + 1e-9,
                        "{dt} s tick {k} joint {j}: {dv} > {room}"
                    );
                    limited += usize::from(dv > 0.9 * room);
                    prev[j] = c.qdot_rad_s[j];
                }
            }
            assert!(limited > 0, "{dt} s: the ramp never acted");
        }
        // The map's own parameters: followed unless given.
        let mut m = ModeSwitchMap::from_spec(SPEC).unwrap().1;
        m.set_period(0.001);
        assert_eq!(
            (m.params().period_s, m.params().lookahead_s),
            (0.001, 0.0005)
        );
        let mut m = ModeSwitchMap::from_spec("modeswitch:period_s=0.01")
            .unwrap()
            .1;
        m.set_period(0.001);
        assert_eq!(
            (m.params().period_s, m.params().lookahead_s),
            (0.01, 0.0005)
        );
    }

    #[test]
    fn the_twist_ramps_within_the_joint_limits() {
        let p = ModeSwitchParams::default();
        let mut map = ModeSwitchMap::new(p.clone(), SPEC).unwrap();
        let mut q = gen3_lite::HOME;
        let mut prev = [0.0; 6];
        let mut qd = [0.0; 6];
        let mut ramped = 0;
        // Full deflection for 3 s, a quarter turn of the stick, then release for 3 s.
        for k in 0..240 {
            let a = match k {
                0..120 => [1.0, 0.0],
                120..140 => [0.0, 1.0],
                _ => [0.0, 0.0],
            };
            map.eval(&q, 0.0, &a, &mut qd);
            for j in 0..6 {
                let dv = (qd[j] - prev[j]).abs();
                let room = p.max_joint_acceleration_rad_s2[j] * p.period_s;
                assert!(
                    dv <= room * 1.02 + 1e-9,
                    "tick {k} joint {j}: {dv} > {room}"
                );
                assert!(
                    qd[j].abs() <= p.max_joint_velocity_rad_s[j] * 1.02,
                    "tick {k}"
                );
                q[j] += qd[j] * DT;
            }
            if map.diagnostics().limited {
                ramped += 1;
            }
            prev = qd;
        }
        // The ramp acted (else this test would prove nothing), and the arm came to rest.
        assert!(ramped > 40, "{ramped}");
        assert_eq!(qd, [0.0; 6]);
        assert_eq!(map.diagnostics().twist, [0.0; 6]);
    }

    #[test]
    fn twist_is_within_the_cartesian_limits() {
        let arm = Gen3Lite::get().arm();
        let mut map = ModeSwitchMap::new(cartesian_only(), SPEC).unwrap();
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
        // With the joint limits, a full deflection is scaled down as a whole: the input's
        // direction is kept and no joint goes past its speed limit.
        let p = ModeSwitchParams::default();
        let mut map = ModeSwitchMap::new(p.clone(), SPEC).unwrap();
        let mut qd = [0.0; 6];
        for _ in 0..400 {
            map.eval(&q, 0.0, &[0.6, 0.8], &mut qd);
        }
        let d = map.diagnostics();
        assert!(d.joint_speed_fit < 1.0, "{d:?}");
        assert!((d.twist[1] / d.twist[0] - 0.8 / 0.6).abs() < 1e-9, "{d:?}");
        assert!(d.twist[2..].iter().all(|v| *v == 0.0));
        let worst = (0..6)
            .map(|j| qd[j].abs() / p.max_joint_velocity_rad_s[j])
            .fold(0.0, f64::max);
        assert!((worst - 1.0).abs() < 0.02, "{worst}");
        // At rest, a zero input is a zero command, without touching the kinematics.
        let mut map = ModeSwitchMap::new(p.clone(), SPEC).unwrap();
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

        let mut map = ModeSwitchMap::new(p.clone(), SPEC).unwrap();
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
            ..cartesian_only()
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
    fn blend_finds_the_closest_twist_within_the_joint_limits() {
        let l = |hold: f64, want: f64, last: f64| Limit {
            hold,
            want,
            last,
            room: 0.1,
            speed: 1.0,
        };
        // P = 0, T within reach: all of T.
        let g = [[0.0, 0.0], [0.0, 1.0]];
        assert_eq!(blend(&[l(0.0, 0.05, 0.0)], g), Some((0.0, 1.0)));
        // From rest towards a T needing 0.5 of one joint: a fifth of it (0.1 / 0.5).
        let (x, y) = blend(&[l(0.0, 0.5, 0.0), l(0.0, -0.2, 0.0)], g).unwrap();
        assert!(x.abs() < 1e-12 && (y - 0.2).abs() < 1e-12, "{x} {y}");
        // Released (T = 0) while P needs 0.5: slow down along P by the room, to 0.4 / 0.5.
        let g = [[1.0, 0.0], [0.0, 0.0]];
        let (x, _) = blend(&[l(0.5, 0.0, 0.5)], g).unwrap();
        assert!((x - 0.8).abs() < 1e-12, "{x}");
        // The speed limit binds too.
        let g = [[0.0, 0.0], [0.0, 1.0]];
        let (_, y) = blend(&[l(0.0, 2.0, 0.95)], g).unwrap();
        assert!((y - 0.5).abs() < 1e-12, "{y}");
        // Last tick's command out of reach of every blend: none.
        assert_eq!(blend(&[l(0.0, 0.0, 1.0)], g), None);
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

    /// The map drives the arm of the robot profile it is given: its chain, joints and limits.
    #[test]
    fn a_map_on_another_arm_drives_that_arm() {
        let planar: &'static RobotProfile = Box::leak(Box::new(
            RobotProfile::new(&kinematics::ProfileSpec::planar5()).unwrap(),
        ));
        let (header, mut map) = ModeSwitchMap::from_spec_for(planar, SPEC).unwrap();
        assert_eq!(header.n_joints, 5);
        assert_eq!(header.joint_names, planar.joint_names());
        assert_eq!(map.params().max_joint_velocity_rad_s, [1.0; 5]);
        // Bent arm; +y on the stick moves the tip along +y.
        let q = [0.3, 0.4, 0.3, 0.2, 0.1];
        let mut qd = [0.0; 5];
        for _ in 0..10 {
            map.eval(&q, 0.0, &[0.0, 1.0], &mut qd);
        }
        assert!(
            qd.iter().all(|v| v.is_finite() && v.abs() <= 1.0 + 1e-9),
            "{qd:?}"
        );
        let arm = planar.arm();
        let mut next = q;
        for j in 0..5 {
            next[j] += qd[j] * 1e-3;
        }
        let dp = arm.fk(&next).unwrap().translation.vector - arm.fk(&q).unwrap().translation.vector;
        assert!(dp.y > 0.0 && dp.y > 10.0 * dp.x.abs(), "{dp:?}");
        // Joint limits of the wrong length are refused, naming the robot.
        let params = ModeSwitchParams::default();
        let e = ModeSwitchMap::new_for(planar, params, SPEC)
            .unwrap_err()
            .to_string();
        assert!(e.contains("planar5 has 5 joints"), "{e}");
    }

    #[test]
    fn direction_is_the_modes_axis_twist_and_leaves_the_memory_alone() {
        let arm = Gen3Lite::get().arm();
        let mut map = ModeSwitchMap::new(cartesian_only(), SPEC).unwrap();
        let q = gen3_lite::HOME;
        let mut jac = kinematics::Jacobian::zeros(6);
        arm.fk_jacobian(&q, &mut jac).unwrap();
        for mode in Mode::ALL {
            // A command first, so the map has a twist in memory.
            let mut qd = [0.0; 6];
            map.eval(&q, 0.0, &[0.3, 0.0], &mut qd);
            let before = (map.twist, map.qdot);
            for axis in 0..2 {
                let mut d = [0.0; 6];
                map.direction(&q, 0.0, axis, &mut d);
                let twist = jac.matrix() * nalgebra::DVector::from_row_slice(&d);
                let row = mode.rows()[axis];
                let limit = if row < 3 { 0.3 } else { 0.85 };
                for r in 0..6 {
                    let want = if r == row { limit } else { 0.0 };
                    assert!((twist[r] - want).abs() < 1e-3 * limit, "{mode:?} {twist:?}");
                }
            }
            assert_eq!(
                (map.twist, map.qdot),
                before,
                "direction changed the memory"
            );
            let mut d = [1.0; 6];
            map.direction(&q, 0.0, 2, &mut d);
            assert_eq!(d, [0.0; 6]);
            map.press(buttons::MODE);
        }
    }

    fn gen3() -> &'static RobotProfile {
        RobotProfile::by_name("gen3").unwrap()
    }

    /// A Gen3 pose with joint 6 near its limit, where the elbow's self-motion turns it (at
    /// home it hardly does: there the null space turns the continuous joints 1, 3, 5 and 7).
    const NEAR_JOINT_6_LIMIT: [f64; 7] = [0.08, 0.68, 1.37, 1.73, -1.09, 1.91, -0.15];

    /// The null-space task on the 7-joint Gen3: it changes no component of the tool's twist
    /// (`J n ≈ 0`) at random poses, pushes a joint near its limit back, and is nothing on the
    /// 6-joint Gen3 lite or with the gain at 0.
    #[test]
    fn the_null_space_task_leaves_the_tool_alone_and_pushes_away_from_a_limit() {
        let robot = gen3();
        let mut map =
            ModeSwitchMap::new_for(robot, ModeSwitchParams::for_robot(robot), SPEC).unwrap();
        let home = robot.named_pose("home").unwrap().to_vec();
        let mut rng = crate::rng::Rng::new(7);
        let limits = robot.limits().clone();
        for trial in 0..50 {
            let q: Vec<f64> = if trial == 0 {
                home.clone()
            } else {
                home.iter()
                    .enumerate()
                    .map(|(j, h)| {
                        (h + rng.range(-0.6, 0.6))
                            .clamp(limits.lower_rad[j] + 0.05, limits.upper_rad[j] - 0.05)
                    })
                    .collect()
            };
            map.jacobian(&q).unwrap();
            let mut n = [0.0; kinematics::MAX_DOF];
            map.null_motion(&q, &mut n).unwrap();
            let mut v = nalgebra::SVector::<f64, { kinematics::MAX_DOF }>::zeros();
            v.as_mut_slice()[..7].copy_from_slice(&n[..7]);
            let tool = map.jac.padded() * v;
            assert!(
                tool.norm() < 1e-6 * (1.0 + v.norm()),
                "trial {trial}: J n = {tool:?} for n = {n:?}"
            );
            for (j, c) in robot.continuous_joints().iter().enumerate() {
                if *c {
                    // Moved only as the tool's constraint asks, never pushed by a limit.
                    assert!(n[j].abs() < 0.2, "{j}: {}", n[j]);
                }
            }
        }
        // Where the elbow's self-motion turns joint 6 (index 5; 1.91 rad, 91 % of the way to
        // its 2.10 rad limit), the task turns it back.
        let near = NEAR_JOINT_6_LIMIT.to_vec();
        map.jacobian(&near).unwrap();
        let mut n = [0.0; kinematics::MAX_DOF];
        map.null_motion(&near, &mut n).unwrap();
        assert!(n[5] < -0.03, "{n:?}");
        // Nothing on the Gen3 lite, and nothing with the gain at 0.
        let mut lite = ModeSwitchMap::new(ModeSwitchParams::default(), SPEC).unwrap();
        lite.jacobian(&gen3_lite::HOME).unwrap();
        let mut n = [1.0; kinematics::MAX_DOF];
        lite.null_motion(&gen3_lite::HOME, &mut n).unwrap();
        assert_eq!(n[..6], [0.0; 6]);
        let off = ModeSwitchParams {
            null_space_gain_rad_s: 0.0,
            ..ModeSwitchParams::for_robot(robot)
        };
        let mut map = ModeSwitchMap::new_for(robot, off, SPEC).unwrap();
        map.jacobian(&home).unwrap();
        map.null_motion(&home, &mut n).unwrap();
        assert_eq!(n[..7], [0.0; 7]);
    }

    /// Driving the Gen3 along +x from a pose with joint 6 near its limit: with the null-space
    /// task the tool moves as without it (within 1 %), joint 6 ends further from its limit,
    /// and once the stick is released the arm comes to rest.
    #[test]
    fn on_the_gen3_the_null_space_task_turns_joint_6_off_its_limit_and_not_the_tool() {
        let robot = gen3();
        let arm = robot.arm();
        let run = |gain: f64| {
            let params = ModeSwitchParams {
                null_space_gain_rad_s: gain,
                ..ModeSwitchParams::for_robot(robot)
            };
            let mut map = ModeSwitchMap::new_for(robot, params, SPEC).unwrap();
            let mut q = NEAR_JOINT_6_LIMIT.to_vec();
            let start = arm.fk(&q).unwrap();
            let mut qd = [0.0; 7];
            let dt = 1.0 / robot.control_rate_hz();
            for _ in 0..40 {
                map.eval(&q, 0.0, &[1.0, 0.0], &mut qd);
                for j in 0..7 {
                    q[j] += qd[j] * dt;
                }
            }
            // Released: the map ramps the twist and its null-space share to zero.
            for _ in 0..40 {
                map.eval(&q, 0.0, &[0.0, 0.0], &mut qd);
                for j in 0..7 {
                    q[j] += qd[j] * dt;
                }
            }
            let end = arm.fk(&q).unwrap();
            (q, end.translation.vector - start.translation.vector, qd)
        };
        let (q_off, moved_off, _) = run(0.0);
        let (q_on, moved_on, rest) = run(0.2);
        assert!(moved_off.x > 0.1, "{moved_off:?}");
        assert!(
            (moved_on - moved_off).norm() < 0.01 * moved_off.norm(),
            "{moved_on:?} vs {moved_off:?}"
        );
        assert!(q_on[5] < q_off[5] - 0.01, "{} vs {}", q_on[5], q_off[5]);
        assert!(rest.iter().all(|v| v.abs() < 1e-9), "{rest:?}");
    }
}
