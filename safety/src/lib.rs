//! The safety filter: the last word before the arm. A pure function of (command, newest
//! robot state, configuration, time) to (command, flags), with a little memory between ticks
//! (the previous output, the active mapper, a latched e-stop). The safety process is a thin
//! loop around [`SafetyFilter::step`].
//!
//! Each tick, in this order:
//! 1. Faults stop the arm: a non-finite value, a mis-shaped command, a stale robot state,
//!    joystick sample (also none at all, unless the map ignores the input by design) or
//!    command, a supervisor hold, a released deadman. The target becomes zero and the
//!    acceleration limit turns that into a controlled stop. After a fault (these, or ticks
//!    the bridge did not execute: missed, a process that died or restarted) and at start-up,
//!    the arm stays stopped until the operator's input has passed through neutral
//!    ([`restart`], flagged [`safe_flags::AWAITING_NEUTRAL`]).
//! 2. A latched e-stop (joystick button or `scl estop`, released only by `scl reset`)
//!    commands zero at once, the one rule that does not wait for the acceleration limit.
//! 3. The speed override, then the joint velocity limits by one uniform factor (the command
//!    keeps its direction, and so stays in the span of the map), then (with
//!    [`SafetyFilter::with_whole_arm`]) the Cartesian speed caps: the tool and every link
//!    capsule's ends at most `max_tcp_speed_m_s`, the tool's turning at most
//!    `max_tcp_angular_speed_rad_s`, by one factor ([`clearance::speed_scale`]).
//! 4. Joint position limits less a margin and workspace bounds on the tool (table plane,
//!    box): a joint or the tool may approach a bound no faster than it can stop before it;
//!    motion away from a bound is free. Both scale the whole command. Stopping keeps the
//!    direction (the acceleration rule scales a change as a whole), so a joint brakes only as
//!    fast as the command's slowest joint lets it: the braking distances use that
//!    deceleration ([`rules::brake_rate`]), not each joint's own limit. With the whole-arm
//!    rules, every checked pair of the collision model (each link against the others and
//!    against `[safety.scene]`) is such a bound `d - stop_distance_m` away, approached at
//!    `-d_dot`, and within `slowdown_distance_m` an approaching pair also slows the command
//!    down, to zero at the stop distance ([`clearance`]).
//! 5. The acceleration limits: the change from the arm's current velocity is scaled as a
//!    whole until every joint's change fits. If that leaves an output that could not stop
//!    in time (the arm's velocity and the target point in different directions), it is
//!    moved toward braking the arm's velocity along its own direction, which can whenever
//!    the previous output could, and is within the acceleration limits too.
//! 6. Hard guarantees last: no joint past its margin and the tool not out of the workspace
//!    within the next tick, even where that means braking harder than the acceleration
//!    limit: only when even the hardest braking of the arm's velocity within the limits
//!    would cross a bound this tick, i.e. the arm was already too fast (a fault elsewhere,
//!    a robot not doing what it was told; with a curved tool path, the second-order rest
//!    of the one-tick prediction). Then the speed caps again, and no checked pair closer
//!    than the stop distance at the next tick: to first order, then by the exact distances
//!    at the next tick's pose ([`clearance::WholeArm::verify`]).
//!
//! Every rule that acted sets its bit in [`SafeCommand::flags`]; the filter counts them.
//! The braking of steps 4 and 5 and the hard guarantees of step 6 share the position and
//! workspace bits; [`SafetyFilter::last_report`] tells them apart (only the hard guarantees
//! may exceed the acceleration limit).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod clearance;
pub mod config;
pub mod restart;
pub mod rules;
pub mod scene;

pub use config::{ConfigError, SafetyConfig, WorkspaceConfig};
pub use restart::{NEUTRAL_MAX_ACTION, RestartGuard, RestartState};
pub use rules::{Bounds, ChainTcp, TcpModel, limit_change, uniform_scale};
pub use scene::{BoxConfig, SceneConfig};

use ipc_types::{
    MAX_JOINTS, MapperCommand, NO_TICK, RobotState, SafeCommand, buttons, mapper_flags, safe_flags,
};
use kinematics::ArmLimits;

/// Slack kept inside the configured workspace bounds (m): the rule predicts the tool's motion
/// to first order over one tick, and this covers the second-order rest.
pub const WORKSPACE_SLACK_M: f64 = 0.001;

/// Relative rounding allowed when checking that an output can brake in time.
const BRAKE_TOLERANCE: f64 = 1e-9;

/// Bisection steps toward braking when the acceleration-limited output cannot brake in time.
const BRAKE_BISECTIONS: usize = 20;

/// The tool's position (m) and the linear rows of its Jacobian at the current pose.
type Tool = ([f64; 3], [[f64; MAX_JOINTS]; 3]);

/// The filter: its configuration and what it remembers between ticks.
pub struct SafetyFilter {
    cfg: SafetyConfig,
    dt: f64,
    n: usize,
    lower: [f64; MAX_JOINTS],
    upper: [f64; MAX_JOINTS],
    vmax: [f64; MAX_JOINTS],
    amax: [f64; MAX_JOINTS],
    max_joystick_age_ns: u64,
    max_state_age_ns: u64,
    prev_tick: u64,
    prev_out: [f64; MAX_JOINTS],
    active: u32,
    pending: Option<(u32, u64)>,
    hold: bool,
    estop: bool,
    /// [`SafetyFilter::interrupt`] was called since the last step (for [`SafeCommand::control`]).
    interrupted: bool,
    restart: RestartGuard,
    tcp: Option<Box<dyn TcpModel>>,
    bounds: Bounds,
    arm: Option<Box<clearance::WholeArm>>,
    /// The slowest braking rate any command can have, `min_j amax_j / vmax_j` (1/s): how far
    /// ahead the clearance rule looks.
    alpha_min: f64,
    counts: [u32; 16],
    report: StepReport,
}

/// What the last [`SafetyFilter::step`] did beyond its flags: which hard guarantee (step 6),
/// if any, scaled the acceleration-limited output. Those are the only rules allowed to change
/// the output by more than the acceleration limit (besides a latched e-stop), and only when
/// the arm was already too fast to brake in time; the flags do not tell them apart from the
/// braking of steps 4 and 5, which sets the same bits.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepReport {
    /// The hard position guarantee scaled the output: a joint would otherwise have passed its
    /// margin within the next tick.
    pub hard_position: bool,
    /// The hard workspace guarantee scaled the output: the tool would otherwise have left the
    /// workspace within the next tick.
    pub hard_workspace: bool,
    /// The hard clearance guarantee scaled the output: a checked pair would otherwise have
    /// come closer than the stop distance within the next tick (to first order, or in the
    /// exact check of the next tick's pose), or a pair below it closer still.
    pub hard_clearance: bool,
    /// The speed caps scaled the acceleration-limited output (the arm was moving faster
    /// than the caps allow at this pose).
    pub hard_speed: bool,
    /// The velocity the output was limited from (the arm's current velocity as the filter
    /// estimates it: the previous output if executed, else the measured one).
    pub base_rad_s: [f64; MAX_JOINTS],
    /// The factor each rule of steps 3 and 4 scaled the target by (1 where it did not act).
    pub scales: TargetScales,
    /// Where between braking the arm's velocity (0) and the acceleration-limited output (1)
    /// step 5 put the output, when that output could not have braked in time.
    pub toward_braking: Option<f64>,
}

/// The factors the scaling rules applied to the target this tick (1: the rule did not act),
/// for explaining a tick ([`StepReport::scales`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetScales {
    /// Uniform scaling into the joint speed limits.
    pub velocity: f64,
    /// The Cartesian speed caps.
    pub speed_cap: f64,
    /// Braking before the joint limit margins.
    pub position: f64,
    /// Braking before the workspace bounds.
    pub workspace: f64,
    /// Slow-down and braking by clearance.
    pub clearance: f64,
}

impl Default for TargetScales {
    fn default() -> Self {
        Self {
            velocity: 1.0,
            speed_cap: 1.0,
            position: 1.0,
            workspace: 1.0,
            clearance: 1.0,
        }
    }
}

impl StepReport {
    /// Whether a hard guarantee overrode the acceleration limit's output this tick.
    pub fn hard_override(&self) -> bool {
        self.hard_position || self.hard_workspace || self.hard_clearance || self.hard_speed
    }
}

impl std::fmt::Debug for SafetyFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SafetyFilter")
            .field("cfg", &self.cfg)
            .field("active", &self.active)
            .field("estop", &self.estop)
            .field("hold", &self.hold)
            .field("restart", &self.restart.state())
            .field("workspace_model", &self.tcp.is_some())
            .field("whole_arm", &self.arm.is_some())
            .finish()
    }
}

fn ms_to_ns(ms: f64) -> u64 {
    (ms * 1e6) as u64
}

fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl SafetyFilter {
    /// A filter for an arm of the default robot profile with `limits`, ticking every
    /// `period_s` seconds; refuses an invalid configuration. Without
    /// [`SafetyFilter::with_tcp_model`] the workspace rule is inactive.
    pub fn new(cfg: SafetyConfig, limits: &ArmLimits, period_s: f64) -> Result<Self, ConfigError> {
        cfg.validate(limits)?;
        Self::checked(cfg, limits, period_s)
    }

    /// A filter for `robot`'s arm (its limits; the configuration checked against its URDF),
    /// ticking every `period_s` seconds. Without [`SafetyFilter::with_tcp_model`] (e.g.
    /// [`ChainTcp::of`] the same robot) the workspace rule is inactive.
    pub fn for_robot(
        cfg: SafetyConfig,
        robot: &kinematics::RobotProfile,
        period_s: f64,
    ) -> Result<Self, ConfigError> {
        cfg.validate_for_robot(robot)?;
        Self::checked(cfg, robot.limits(), period_s)
    }

    /// The filter of a configuration already checked against `limits`.
    fn checked(cfg: SafetyConfig, limits: &ArmLimits, period_s: f64) -> Result<Self, ConfigError> {
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(ConfigError {
                key: "period".into(),
                reason: format!("{period_s} s is not a positive period"),
            });
        }
        cfg.validate_ages(period_s)?;
        let n = limits.n_joints().min(MAX_JOINTS);
        let mut f = Self {
            dt: period_s,
            n,
            lower: [0.0; MAX_JOINTS],
            upper: [0.0; MAX_JOINTS],
            vmax: [0.0; MAX_JOINTS],
            amax: [0.0; MAX_JOINTS],
            max_joystick_age_ns: ms_to_ns(cfg.max_joystick_age_ms),
            max_state_age_ns: ms_to_ns(cfg.max_state_age_ms),
            prev_tick: NO_TICK,
            prev_out: [0.0; MAX_JOINTS],
            active: cfg.active_mapper,
            pending: None,
            hold: false,
            estop: false,
            interrupted: false,
            restart: RestartGuard::new(cfg.deadman),
            tcp: None,
            bounds: Bounds::new(0.0, [0.0; 3], [0.0; 3]),
            arm: None,
            alpha_min: f64::INFINITY,
            counts: [0; 16],
            report: StepReport::default(),
            cfg,
        };
        let w = &f.cfg.workspace;
        let s = WORKSPACE_SLACK_M;
        f.bounds = Bounds::new(
            w.table_z_m + s,
            [w.box_min_m[0] + s, w.box_min_m[1] + s, w.box_min_m[2] + s],
            [w.box_max_m[0] - s, w.box_max_m[1] - s, w.box_max_m[2] - s],
        );
        for j in 0..n {
            f.lower[j] = limits.lower_rad[j] + f.cfg.joint_margin_rad;
            f.upper[j] = limits.upper_rad[j] - f.cfg.joint_margin_rad;
            f.vmax[j] = f.cfg.max_velocity_rad_s[j];
            f.amax[j] = f.cfg.max_acceleration_rad_s2[j];
            f.alpha_min = f.alpha_min.min(f.amax[j] / f.vmax[j]);
        }
        Ok(f)
    }

    /// The filter the safety process runs for a graph: [`SafetyFilter::for_robot`], the
    /// workspace rule on `robot`'s tool when `cfg.workspace.enabled`, and the whole-arm rules
    /// ([`SafetyFilter::with_whole_arm`]). The one construction the process and the replay
    /// of a recording share.
    pub fn for_graph(
        cfg: SafetyConfig,
        robot: &kinematics::RobotProfile,
        period_s: f64,
    ) -> Result<Self, ConfigError> {
        let workspace = cfg.workspace.enabled;
        let mut f = Self::for_robot(cfg, robot, period_s)?;
        if workspace {
            f = f.with_tcp_model(Box::new(ChainTcp::of(robot)));
        }
        f.with_whole_arm(robot)
    }

    /// Enables the whole-arm rules (`robot`'s collision model in `[safety.scene]`: slow-down
    /// and stop by distance for every checked pair, the Cartesian speed caps); refuses a
    /// robot profile without a collision model for this arm.
    pub fn with_whole_arm(mut self, robot: &kinematics::RobotProfile) -> Result<Self, ConfigError> {
        let scene = self.cfg.scene.scene()?;
        let arm = (self.n == robot.n_joints())
            .then(|| clearance::WholeArm::new(robot, scene))
            .flatten()
            .ok_or_else(|| ConfigError {
                key: "scene".into(),
                reason: format!(
                    "the {} profile has no collision model for this {}-joint arm",
                    robot.description(),
                    self.n
                ),
            })?;
        self.arm = Some(Box::new(arm));
        Ok(self)
    }

    /// Enables the workspace rule with the robot's forward kinematics.
    pub fn with_tcp_model(mut self, model: Box<dyn TcpModel>) -> Self {
        self.tcp = Some(model);
        self
    }

    /// The configuration.
    pub fn config(&self) -> &SafetyConfig {
        &self.cfg
    }

    /// Asks for mapper `id` to become active from tick `from_tick` on (a tick boundary: the
    /// command of `from_tick - 1` still comes from the old mapper).
    pub fn request_switch(&mut self, id: u32, from_tick: u64) {
        self.pending = Some((id, from_tick));
    }

    /// The mapper whose command is forwarded at `tick`, applying a pending switch that is due.
    pub fn active_for_tick(&mut self, tick: u64) -> u32 {
        if let Some((id, from)) = self.pending
            && tick >= from
        {
            self.active = id;
            self.pending = None;
        }
        self.active
    }

    /// The active mapper as of the last tick handled.
    pub fn active(&self) -> u32 {
        self.active
    }

    /// Holds the arm (every output a controlled stop, flagged [`safe_flags::HOLD`]) until
    /// released.
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// Whether the supervisor holds the arm.
    pub fn held(&self) -> bool {
        self.hold
    }

    /// Latches the e-stop: zero velocity from the next tick on, until [`SafetyFilter::reset`].
    pub fn estop(&mut self) {
        self.estop = true;
    }

    /// Releases a latched e-stop.
    pub fn reset(&mut self) {
        self.estop = false;
    }

    /// Whether the e-stop is latched.
    pub fn estopped(&self) -> bool {
        self.estop
    }

    /// The graph has stopped sending commands (no mapper, no ticks): whenever they resume,
    /// the arm waits for neutral input first (as it would on seeing the gap in the ticks).
    pub fn interrupt(&mut self) {
        self.interrupted = true;
        self.restart.interrupt();
    }

    /// Puts the control inputs a recorded step began with back ([`SafeCommand::control`]
    /// bits, [`ipc_types::safe_control`]): the e-stop latched or not, the hold, an
    /// interruption. What the safety process did through [`SafetyFilter::estop`],
    /// [`SafetyFilter::reset`], [`SafetyFilter::set_hold`] and [`SafetyFilter::interrupt`]
    /// before that step, for deterministic replay.
    pub fn apply_control(&mut self, control: u32) {
        use ipc_types::safe_control;
        self.estop = control & safe_control::ESTOP != 0;
        self.hold = control & safe_control::HOLD != 0;
        if control & safe_control::INTERRUPTED != 0 {
            self.interrupt();
        }
    }

    /// Whether the arm waits for the operator's input to pass through neutral before it
    /// moves again (restart prevention, [`restart`]).
    pub fn awaiting_neutral(&self) -> bool {
        !self.restart.armed()
    }

    /// How many ticks each rule acted, by bit of [`safe_flags`].
    pub fn rule_counts(&self) -> [u32; 16] {
        self.counts
    }

    /// What the last [`SafetyFilter::step`] did beyond its flags (default before the first).
    pub fn last_report(&self) -> StepReport {
        self.report
    }

    /// The tool's position and the linear rows of its Jacobian at `q`, if the workspace rule
    /// is on and the model gives finite values.
    fn tool(&mut self, q: &[f64]) -> Option<Tool> {
        if !self.cfg.workspace.enabled {
            return None;
        }
        let model = self.tcp.as_mut()?;
        let mut p = [0.0; 3];
        let mut jv = [[0.0; MAX_JOINTS]; 3];
        model.tcp(q, &mut p, &mut jv);
        (p.iter().all(|v| v.is_finite()) && jv.iter().all(|r| all_finite(r))).then_some((p, jv))
    }

    /// The factor `<= 1` for `v` so that every joint at `q` moving toward its margin can
    /// still stop before it, braking along `v`'s direction within the acceleration limits.
    fn position_brake(&self, q: &[f64], v: &[f64]) -> f64 {
        let n = v.len();
        rules::position_scale(
            q,
            v,
            &self.lower[..n],
            &self.upper[..n],
            &self.amax[..n],
            rules::brake_rate(v, &self.amax[..n]),
            self.dt,
            false,
        )
    }

    /// The factor `<= 1` for `v` so that the tool can still stop before every bound it
    /// approaches, braking along `v`'s direction within the acceleration limits and at most
    /// at the configured deceleration; 1 without a tool model.
    fn workspace_brake(&self, tool: Option<&Tool>, v: &[f64]) -> f64 {
        let Some((p, jv)) = tool else {
            return 1.0;
        };
        let n = v.len();
        self.bounds.scale(
            p,
            &rules::tcp_velocity(jv, v),
            self.cfg.workspace.deceleration_m_s2,
            rules::brake_rate(v, &self.amax[..n]),
            self.dt,
            false,
        )
    }

    /// The factor `<= 1` for `v` so that every checked pair it brings closer can still stop
    /// at the stop distance (plus [`clearance::CLEARANCE_SLACK_M`]), braking along `v`'s
    /// direction within the acceleration limits; 1 without the whole-arm rules.
    fn clearance_brake(&self, v: &[f64]) -> f64 {
        let Some(arm) = self.arm.as_ref() else {
            return 1.0;
        };
        clearance::clearance_scale(
            arm.near(),
            v,
            self.cfg.stop_distance_m + clearance::CLEARANCE_SLACK_M,
            rules::brake_rate(v, &self.amax[..v.len()]),
            self.dt,
            false,
        )
    }

    /// The factor `<= 1` for `v` within the speed caps: every capsule end and the tool at
    /// most `max_tcp_speed_m_s`, the tool's turning at most `max_tcp_angular_speed_rad_s`.
    fn speed_cap(arm: &clearance::WholeArm, cfg: &SafetyConfig, v: &[f64]) -> f64 {
        clearance::speed_scale(arm.points(), v, cfg.max_tcp_speed_m_s).min(clearance::speed_scale(
            std::slice::from_ref(arm.angular()),
            v,
            cfg.max_tcp_angular_speed_rad_s,
        ))
    }

    /// Filters `cmd` against the newest robot state `state` at time `now_ns`.
    ///
    /// Returns the command to execute at `cmd.tick` with [`SafeCommand::flags`] naming every
    /// rule that acted, and [`SafeCommand::control`] the control inputs it began with. Times
    /// `t_ns` / `compute_ns` are left at 0 for the caller to stamp; the safety process stamps
    /// `t_ns = now_ns + compute_ns`, so a recorded command gives its `now_ns` back exactly.
    pub fn step(&mut self, cmd: &MapperCommand, state: &RobotState, now_ns: u64) -> SafeCommand {
        let n = self.n;
        let mut flags = 0;
        let mut control = ipc_types::safe_control::RECORDED;
        if self.estop {
            control |= ipc_types::safe_control::ESTOP;
        }
        if self.hold {
            control |= ipc_types::safe_control::HOLD;
        }
        if std::mem::take(&mut self.interrupted) {
            control |= ipc_types::safe_control::INTERRUPTED;
        }

        if cmd.n_joints as usize != n || state.n_joints as usize != n {
            flags |= safe_flags::BAD_SHAPE;
        }
        let q_ok = all_finite(&state.q_rad[..n]);
        let qdot_ok = all_finite(&state.qdot_rad_s[..n]);
        if !(all_finite(&cmd.qdot_rad_s) && cmd.gripper_rate.is_finite() && q_ok && qdot_ok) {
            flags |= safe_flags::NON_FINITE;
        }
        if cmd.tick != state.tick {
            flags |= safe_flags::STALE_COMMAND;
        }
        if now_ns.saturating_sub(cmd.state_t_ns) > self.max_state_age_ns {
            flags |= safe_flags::STALE_STATE;
        }
        let ignores_input = cmd.flags & mapper_flags::IGNORES_INPUT != 0;
        let joystick_stale = if cmd.joystick_t_ns == 0 {
            // No sample ever: only a map that ignores the input by design may move.
            !ignores_input
        } else {
            now_ns.saturating_sub(cmd.joystick_t_ns) > self.max_joystick_age_ns
        };
        if joystick_stale || cmd.flags & mapper_flags::INPUT_STALE != 0 {
            flags |= safe_flags::STALE_JOYSTICK;
        }
        if self.hold {
            flags |= safe_flags::HOLD;
        }
        if cmd.buttons & buttons::ESTOP != 0 {
            self.estop = true;
        }
        if self.estop {
            flags |= safe_flags::ESTOP;
        }
        // Restart prevention: any fault above, a device that is gone, or ticks the bridge did
        // not execute since our last command (missed, or a process of the graph died or
        // restarted meanwhile) wait for neutral input.
        let device_gone = cmd.buttons & buttons::NO_DEVICE != 0;
        if self.prev_tick != NO_TICK
            && !(cmd.tick == self.prev_tick.wrapping_add(1) && state.applied_tick == self.prev_tick)
        {
            self.restart.interrupt();
        }
        let unusable =
            mapper_flags::NO_INPUT | mapper_flags::INPUT_NON_FINITE | mapper_flags::INPUT_STALE;
        let operator =
            (cmd.flags & unusable == 0 && !device_gone && cmd.action.iter().all(|a| a.is_finite()))
                .then(|| restart::Operator {
                    action_norm: f64::from(cmd.action[0]).hypot(f64::from(cmd.action[1])),
                    deadman: cmd.buttons & buttons::DEADMAN != 0,
                    uses_input: !ignores_input,
                });
        let armed = self.restart.tick(flags != 0 || device_gone, operator);
        if self.cfg.deadman && cmd.buttons & buttons::DEADMAN == 0 {
            flags |= safe_flags::DEADMAN;
        }
        if !armed && flags == 0 {
            flags |= safe_flags::AWAITING_NEUTRAL;
        }
        let stop = flags != 0;

        // The velocity the arm has now: our previous output if the bridge executed it,
        // otherwise what the robot reports (if it reports garbage, which is a fault and a
        // stop, our previous output: the stop decelerates from there); never more than the
        // limits.
        let mut base = [0.0; MAX_JOINTS];
        let executed = self.prev_tick != NO_TICK
            && state.applied_tick == self.prev_tick
            && cmd.tick == self.prev_tick.wrapping_add(1);
        if executed || !qdot_ok {
            base[..n].copy_from_slice(&self.prev_out[..n]);
        } else {
            base[..n].copy_from_slice(&state.qdot_rad_s[..n]);
        }
        for (b, v) in base.iter_mut().zip(&self.vmax).take(n) {
            *b = b.clamp(-v, *v);
        }

        let mut report = StepReport {
            base_rad_s: base,
            ..StepReport::default()
        };
        // The whole arm's clearance at this state, also reported while stopped.
        let arm_ok = q_ok
            && self
                .arm
                .as_mut()
                .is_some_and(|a| a.update(&state.q_rad[..n], state.gripper));
        let mut out = [0.0; MAX_JOINTS];
        if flags & safe_flags::ESTOP == 0 {
            let mut target = [0.0; MAX_JOINTS];
            if !stop {
                for (t, c) in target.iter_mut().zip(&cmd.qdot_rad_s).take(n) {
                    *t = c * self.cfg.speed_override;
                }
                let k = uniform_scale(&target[..n], &self.vmax[..n]);
                if k < 1.0 {
                    report.scales.velocity = k;
                    flags |= safe_flags::VELOCITY_SCALED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
            let tcp = if q_ok {
                self.tool(&state.q_rad[..n])
            } else {
                None
            };
            if let Some(arm) = self.arm.as_mut().filter(|_| arm_ok) {
                let k = Self::speed_cap(arm, &self.cfg, &target[..n]);
                if k < 1.0 {
                    report.scales.speed_cap = k;
                    flags |= safe_flags::SPEED_CAPPED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
                // Every output this tick lies between the target, the arm's velocity and
                // zero, so no point moves faster than the faster of the two: the pairs that
                // can need braking are those within the distance the fastest pair (both
                // sides moving) covers in a tick and a stop at the slowest braking rate the
                // rule plans with.
                let fastest = arm
                    .max_point_speed(&target[..n])
                    .max(arm.max_point_speed(&base[..n]));
                let reach = 2.0
                    * fastest
                    * (2.0 * self.dt + 0.5 / (clearance::BRAKE_SHARE * self.alpha_min));
                let stop = self.cfg.stop_distance_m + clearance::CLEARANCE_SLACK_M;
                arm.collect(self.cfg.slowdown_distance_m.max(stop + reach));
            }
            if q_ok {
                let q = &state.q_rad[..n];
                let k = self.position_brake(q, &target[..n]);
                if k < 1.0 {
                    report.scales.position = k;
                    flags |= safe_flags::POSITION_LIMITED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
                let k = self.workspace_brake(tcp.as_ref(), &target[..n]);
                if k < 1.0 {
                    report.scales.workspace = k;
                    flags |= safe_flags::WORKSPACE_LIMITED;
                    target[..n].iter_mut().for_each(|v| *v *= k);
                }
                if let Some(arm) = self.arm.as_ref().filter(|_| arm_ok) {
                    let k = clearance::slowdown_scale(
                        arm.near(),
                        &target[..n],
                        self.cfg.stop_distance_m + clearance::CLEARANCE_SLACK_M,
                        self.cfg.slowdown_distance_m,
                        self.cfg.max_tcp_speed_m_s,
                    )
                    .min(self.clearance_brake(&target[..n]));
                    if k < 1.0 {
                        report.scales.clearance = k;
                        flags |= safe_flags::CLEARANCE_LIMITED;
                        target[..n].iter_mut().for_each(|v| *v *= k);
                    }
                }
            }
            out = target;
            if limit_change(&base[..n], &mut out[..n], &self.amax[..n], self.dt) {
                flags |= safe_flags::ACCEL_LIMITED;
            }
            // The acceleration limit may have left the output between the arm's velocity and
            // the target, in a direction that cannot brake in time (a joint or the tool
            // braked only at the pace of the slowest joint of the change). Then move it toward
            // braking the arm's velocity along its own direction, which can, if the arm could
            // last tick: both are within the acceleration limits, and so is the segment.
            if q_ok {
                let q = &state.q_rad[..n];
                let fits = |f: &Self, v: &[f64]| {
                    (
                        f.position_brake(q, v) >= 1.0 - BRAKE_TOLERANCE,
                        f.workspace_brake(tcp.as_ref(), v) >= 1.0 - BRAKE_TOLERANCE,
                        !arm_ok || f.clearance_brake(v) >= 1.0 - BRAKE_TOLERANCE,
                    )
                };
                let (pos_ok, ws_ok, clear_ok) = fits(self, &out[..n]);
                if !(pos_ok && ws_ok && clear_ok) {
                    if !pos_ok {
                        flags |= safe_flags::POSITION_LIMITED;
                    }
                    if !ws_ok {
                        flags |= safe_flags::WORKSPACE_LIMITED;
                    }
                    if !clear_ok {
                        flags |= safe_flags::CLEARANCE_LIMITED;
                    }
                    let c =
                        (1.0 - rules::brake_rate(&base[..n], &self.amax[..n]) * self.dt).max(0.0);
                    let mut brake = [0.0; MAX_JOINTS];
                    for (b, v) in brake.iter_mut().zip(&base).take(n) {
                        *b = v * c;
                    }
                    let at = |lambda: f64| {
                        let mut v = [0.0; MAX_JOINTS];
                        for j in 0..n {
                            v[j] = brake[j] + lambda * (out[j] - brake[j]);
                        }
                        v
                    };
                    let (mut lo, mut hi) = (0.0, 1.0);
                    for _ in 0..BRAKE_BISECTIONS {
                        let mid = 0.5 * (lo + hi);
                        let (p, w, c) = fits(self, &at(mid)[..n]);
                        if p && w && c {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    out = at(lo);
                    report.toward_braking = Some(lo);
                }
            }
            // Hard guarantees over the acceleration limit.
            if q_ok {
                let k = rules::position_scale(
                    &state.q_rad[..n],
                    &out[..n],
                    &self.lower[..n],
                    &self.upper[..n],
                    &self.amax[..n],
                    f64::INFINITY,
                    self.dt,
                    true,
                );
                if k < 1.0 {
                    flags |= safe_flags::POSITION_LIMITED;
                    report.hard_position = true;
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
            if let Some((p, jv)) = tcp {
                let v = rules::tcp_velocity(&jv, &out[..n]);
                let k = self.bounds.scale(&p, &v, 1.0, f64::INFINITY, self.dt, true);
                if k < 1.0 {
                    flags |= safe_flags::WORKSPACE_LIMITED;
                    report.hard_workspace = true;
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
            }
            if let Some(arm) = self.arm.as_mut().filter(|_| arm_ok) {
                let k = Self::speed_cap(arm, &self.cfg, &out[..n]);
                if k < 1.0 {
                    flags |= safe_flags::SPEED_CAPPED;
                    report.hard_speed = true;
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
                let stop = self.cfg.stop_distance_m;
                let k = clearance::clearance_scale(
                    arm.near(),
                    &out[..n],
                    stop + clearance::CLEARANCE_SLACK_M,
                    f64::INFINITY,
                    self.dt,
                    true,
                );
                if k < 1.0 {
                    out[..n].iter_mut().for_each(|v| *v *= k);
                }
                // The exact distances at the next tick's pose (scales `out` itself).
                if k < 1.0 || arm.verify(&mut out[..n], stop, self.dt) < 1.0 {
                    flags |= safe_flags::CLEARANCE_LIMITED;
                    report.hard_clearance = true;
                }
            }
            // Every step above only scales or interpolates within the limits; this keeps the
            // rounding of those products within them too.
            for (v, l) in out.iter_mut().zip(&self.vmax).take(n) {
                *v = v.clamp(-l, *l);
            }
        }
        if stop {
            flags |= safe_flags::STOP;
        }
        let gripper = if stop {
            0.0
        } else {
            cmd.gripper_rate
                .clamp(-self.cfg.max_gripper_rate, self.cfg.max_gripper_rate)
        };
        for (bit, c) in self.counts.iter_mut().enumerate() {
            if flags & (1 << bit) != 0 {
                *c = c.saturating_add(1);
            }
        }
        self.prev_tick = cmd.tick;
        self.prev_out = out;
        self.report = report;
        let (clearance_m, closest_pair, tcp_speed_m_s) = match self.arm.as_ref().filter(|_| arm_ok)
        {
            Some(arm) => {
                let (d, pair) = arm
                    .closest()
                    .unwrap_or((f64::INFINITY, clearance::WholeArm::NO_PAIR));
                let speed = arm
                    .tool()
                    .map_or(0.0, |j| clearance::point_speed(j, &out[..n]));
                (d, pair, speed)
            }
            None => (f64::INFINITY, clearance::WholeArm::NO_PAIR, 0.0),
        };

        SafeCommand {
            tick: cmd.tick,
            t_ns: 0,
            state_t_ns: cmd.state_t_ns,
            state_rx_ns: cmd.state_rx_ns,
            joystick_t_ns: cmd.joystick_t_ns,
            joystick_rx_ns: cmd.joystick_rx_ns,
            mapper_t_ns: cmd.t_ns,
            mapper_rx_ns: 0,
            mapper_compute_ns: cmd.compute_ns,
            compute_ns: 0,
            mapper_id: cmd.mapper_id,
            n_joints: n as u32,
            flags,
            control,
            qdot_rad_s: out,
            gripper_rate: gripper,
            clearance_m,
            tcp_speed_m_s,
            closest_pair,
            reserved_tail: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics::gen3_lite;
    use proptest::prelude::*;

    const NOW: u64 = 1_000_000_000;
    const DT: f64 = 0.025;

    fn limits() -> ArmLimits {
        gen3_lite::limits()
    }

    /// The Gen3 lite's tool model (`base_link -> tool_frame`).
    fn gen3_lite_tcp() -> ChainTcp {
        ChainTcp::of(kinematics::RobotProfile::by_name("gen3_lite").unwrap())
    }

    fn state(tick: u64) -> RobotState {
        let mut s = RobotState::at_rest(tick, NOW - 1_000_000, 6);
        s.applied_tick = tick.wrapping_sub(1);
        s
    }

    fn cmd(tick: u64, qdot: [f64; 6]) -> MapperCommand {
        let mut q = [0.0; MAX_JOINTS];
        q[..6].copy_from_slice(&qdot);
        MapperCommand {
            tick,
            t_ns: NOW - 500_000,
            state_t_ns: NOW - 1_000_000,
            state_rx_ns: 0,
            joystick_t_ns: NOW - 10_000_000,
            joystick_rx_ns: 0,
            joystick_seq: 1,
            compute_ns: 100,
            mapper_id: 1,
            n_joints: 6,
            flags: 0,
            buttons: 0,
            action: [0.0; 2],
            qdot_rad_s: q,
            gripper_rate: 0.5,
        }
    }

    /// Default limits.
    fn filter() -> SafetyFilter {
        SafetyFilter::new(SafetyConfig::default(), &limits(), DT).unwrap()
    }

    /// Acceleration limits out of the way, to test the other rules alone.
    fn filter_without_accel_limit() -> SafetyFilter {
        let cfg = SafetyConfig {
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        SafetyFilter::new(cfg, &limits(), DT).unwrap()
    }

    /// A tool model linear in q: p = p0 + A q. Exact to first order, so the workspace
    /// guarantee can be checked without tolerance.
    struct LinearTcp {
        p0: [f64; 3],
        a: [[f64; MAX_JOINTS]; 3],
    }

    impl LinearTcp {
        fn gen3_like() -> Self {
            let mut a = [[0.0; MAX_JOINTS]; 3];
            a[0][..6].copy_from_slice(&[0.0, 0.3, 0.2, 0.0, 0.1, 0.0]);
            a[1][..6].copy_from_slice(&[0.4, 0.0, 0.0, 0.05, 0.0, 0.0]);
            a[2][..6].copy_from_slice(&[0.0, -0.3, -0.25, 0.0, -0.1, 0.0]);
            Self {
                p0: [0.4, 0.0, 0.3],
                a,
            }
        }

        fn at(&self, q: &[f64]) -> [f64; 3] {
            let mut p = self.p0;
            for i in 0..3 {
                for j in 0..q.len() {
                    p[i] += self.a[i][j] * q[j];
                }
            }
            p
        }
    }

    impl TcpModel for LinearTcp {
        fn tcp(&mut self, q: &[f64], p: &mut [f64; 3], jv: &mut [[f64; MAX_JOINTS]; 3]) {
            *p = self.at(q);
            *jv = self.a;
        }
    }

    #[test]
    fn passes_a_good_command_unchanged() {
        let c = cmd(5, [0.1, -0.2, 0.0, 0.3, 0.0, 0.1]);
        let out = filter_without_accel_limit().step(&c, &state(5), NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s, c.qdot_rad_s);
        assert_eq!(out.tick, 5);
        assert_eq!(out.mapper_t_ns, c.t_ns);
        assert_eq!(out.gripper_rate, 0.5);
    }

    #[test]
    fn scales_uniformly_to_the_tightest_limit() {
        let c = cmd(5, [0.96, 0.0, 0.0, 0.38, 0.0, 0.0]);
        let out = filter_without_accel_limit().step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::VELOCITY_SCALED);
        assert!((out.qdot_rad_s[0] - 0.48).abs() < 1e-12);
        assert!((out.qdot_rad_s[3] - 0.19).abs() < 1e-12);
    }

    #[test]
    fn speed_override_scales_everything() {
        let cfg = SafetyConfig {
            speed_override: 0.25,
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
        let out = f.step(&cmd(5, [0.4, 0.0, 0.0, 0.0, 0.0, -0.2]), &state(5), NOW);
        assert_eq!(out.flags, 0);
        assert!((out.qdot_rad_s[0] - 0.1).abs() < 1e-12);
        assert!((out.qdot_rad_s[5] + 0.05).abs() < 1e-12);
    }

    #[test]
    fn stops_on_each_fault() {
        let mut f = filter_without_accel_limit();
        let mut c = cmd(5, [0.1; 6]);
        c.qdot_rad_s[2] = f64::NAN;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::NON_FINITE | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));

        let out = f.step(&cmd(4, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_COMMAND | safe_flags::STOP);

        let mut c = cmd(5, [0.1; 6]);
        c.joystick_t_ns = NOW - 150_000_000;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_JOYSTICK | safe_flags::STOP);
        assert_eq!(out.gripper_rate, 0.0);

        let mut c = cmd(5, [0.1; 6]);
        c.flags = mapper_flags::INPUT_STALE;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_JOYSTICK | safe_flags::STOP);

        let mut c = cmd(5, [0.1; 6]);
        c.state_t_ns = NOW - 30_000_000;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::STALE_STATE | safe_flags::STOP);

        let mut c = cmd(5, [0.1; 6]);
        c.n_joints = 7;
        let out = f.step(&c, &state(5), NOW);
        assert_eq!(out.flags, safe_flags::BAD_SHAPE | safe_flags::STOP);

        // A robot that reports a non-finite velocity is a fault too, executed or not.
        for applied in [4, NO_TICK] {
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                let mut s = state(5);
                s.applied_tick = applied;
                s.qdot_rad_s[4] = bad;
                let out = f.step(&cmd(5, [0.1; 6]), &s, NOW);
                assert_eq!(out.flags, safe_flags::NON_FINITE | safe_flags::STOP);
                assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
            }
        }
    }

    #[test]
    fn no_joystick_sample_yet_is_stale_unless_the_map_ignores_the_input() {
        let mut c = cmd(5, [0.0; 6]);
        c.joystick_t_ns = 0;
        c.flags = mapper_flags::NO_INPUT;
        assert_eq!(
            filter().step(&c, &state(5), NOW).flags,
            safe_flags::STALE_JOYSTICK | safe_flags::STOP
        );
        c.flags |= mapper_flags::IGNORES_INPUT;
        let mut f = filter();
        // Not stale; but no sample is no neutral input either: the arm waits for one.
        assert_eq!(
            f.step(&c, &state(5), NOW).flags,
            safe_flags::AWAITING_NEUTRAL | safe_flags::STOP
        );
        let mut c = cmd(6, [0.0; 6]);
        c.flags = mapper_flags::IGNORES_INPUT;
        assert_eq!(f.step(&c, &state(6), NOW).flags, 0);
    }

    #[test]
    fn acceleration_is_limited_and_a_stop_decelerates() {
        let mut f = filter();
        let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
        let want = [0.4, -0.4, 0.2, 0.0, 0.5, 0.0];
        let mut prev = [0.0; 6];
        let mut reached = None;
        for k in 1..200u64 {
            let out = f.step(&cmd(k, want), &state(k), NOW);
            for j in 0..6 {
                let dv = (out.qdot_rad_s[j] - prev[j]).abs();
                assert!(dv <= accel[j] * DT + 1e-12, "tick {k} joint {j}: {dv}");
                prev[j] = out.qdot_rad_s[j];
            }
            if out.flags == 0 {
                reached = Some(k);
                break;
            }
            assert_eq!(out.flags, safe_flags::ACCEL_LIMITED);
        }
        // Joint 2 (0.4 rad/s at 0.5 rad/s²) sets the ramp: 0.8 s = 32 ticks.
        assert_eq!(reached, Some(32));
        assert_eq!(&prev, &want);
        // A fault: the output decelerates toward zero within the limits.
        let mut c = cmd(33, want);
        c.qdot_rad_s[0] = f64::NAN;
        let out = f.step(&c, &state(33), NOW);
        assert_eq!(
            out.flags,
            safe_flags::NON_FINITE | safe_flags::STOP | safe_flags::ACCEL_LIMITED
        );
        for j in 0..6 {
            assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * DT + 1e-12);
            assert!(out.qdot_rad_s[j].abs() <= prev[j].abs());
        }
        // A missed tick and a robot reporting a NaN velocity: the stop goes on decelerating
        // from the last output (the best estimate left) instead of jumping to zero.
        let prev = out.qdot_rad_s;
        let mut s = state(35);
        s.applied_tick = NO_TICK;
        s.qdot_rad_s[1] = f64::NAN;
        let out = f.step(&cmd(35, want), &s, NOW);
        assert_eq!(
            out.flags,
            safe_flags::NON_FINITE | safe_flags::STOP | safe_flags::ACCEL_LIMITED
        );
        for j in 0..6 {
            assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * DT + 1e-12);
            assert!(out.qdot_rad_s[j].abs() < prev[j].abs() || prev[j] == 0.0);
        }
    }

    /// The period-tied rules at 40 Hz and at 1 kHz, with the period as the only parameter:
    /// the velocity changes by at most `max_acceleration * period` per tick (so a ramp takes
    /// the same time, 25 times the ticks), and a state older than the default age limit at
    /// that period (80 % of it) is stale while one of this tick is not.
    #[test]
    fn period_tied_rules_follow_the_period_at_40_hz_and_1_khz() {
        let accel = gen3_lite::DEFAULT_ACCELERATION_RAD_S2;
        let want = [0.4, -0.4, 0.2, 0.0, 0.5, 0.0];
        for (rate_hz, ramp_ticks) in [(40.0, 32u64), (1000.0, 800)] {
            let dt = 1.0 / rate_hz;
            let period_ns = (dt * 1e9) as u64;
            let cfg = SafetyConfig {
                max_state_age_ms: SafetyConfig::state_age_ms_for(dt),
                ..SafetyConfig::default()
            };
            let mut f = SafetyFilter::new(cfg, &limits(), dt).unwrap();
            // A state published a tenth of a period ago and a sample one period old.
            let at = |tick: u64, state_age_ns: u64| {
                let mut s = RobotState::at_rest(tick, NOW - state_age_ns, 6);
                s.applied_tick = tick.wrapping_sub(1);
                let mut c = cmd(tick, want);
                c.state_t_ns = s.t_ns;
                c.joystick_t_ns = NOW - period_ns;
                (c, s)
            };
            let mut prev = [0.0; 6];
            let mut reached = None;
            for k in 1..2000u64 {
                let (c, s) = at(k, period_ns / 10);
                let out = f.step(&c, &s, NOW);
                for j in 0..6 {
                    let dv = (out.qdot_rad_s[j] - prev[j]).abs();
                    assert!(
                        dv <= accel[j] * dt + 1e-12,
                        "{rate_hz} Hz tick {k} joint {j}: {dv}"
                    );
                    prev[j] = out.qdot_rad_s[j];
                }
                if out.flags == 0 {
                    reached = Some(k);
                    break;
                }
                assert_eq!(
                    out.flags,
                    safe_flags::ACCEL_LIMITED,
                    "{rate_hz} Hz tick {k}"
                );
            }
            // Joint 2 (0.4 rad/s at 0.5 rad/s²) sets the ramp: 0.8 s at either rate.
            let reached = reached.unwrap();
            assert!(
                reached.abs_diff(ramp_ticks) <= 1,
                "{rate_hz} Hz: reached at tick {reached}, expected {ramp_ticks}"
            );
            // A state 90 % of a period old is stale at this rate: a stop.
            let (c, s) = at(reached + 1, period_ns * 9 / 10);
            let out = f.step(&c, &s, NOW);
            assert_ne!(out.flags & safe_flags::STALE_STATE, 0, "{rate_hz} Hz");
            for j in 0..6 {
                assert!((out.qdot_rad_s[j] - prev[j]).abs() <= accel[j] * dt + 1e-12);
            }
        }
    }

    #[test]
    fn after_a_miss_the_ramp_starts_from_the_measured_velocity() {
        let mut f = filter();
        f.step(&cmd(1, [0.0; 6]), &state(1), NOW);
        // Tick 2 was missed: the state of tick 3 reports no command applied and the robot
        // moving at 0.3 rad/s on joint 0.
        let mut s = state(3);
        s.applied_tick = NO_TICK;
        s.qdot_rad_s[0] = 0.3;
        let out = f.step(&cmd(3, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &s, NOW);
        assert_eq!(out.flags, 0);
        assert_eq!(out.qdot_rad_s[0], 0.3);
    }

    #[test]
    fn joints_brake_before_their_margin_and_move_away_freely() {
        let mut f = filter_without_accel_limit();
        let mut s = state(5);
        // Joint 0 at 1 mrad from its margin (limit 2.68, margin 0.05).
        s.q_rad[0] = 2.68 - 0.05 - 0.001;
        let out = f.step(&cmd(5, [0.3, 0.1, 0.0, 0.0, 0.0, 0.0]), &s, NOW);
        assert!(out.flags & safe_flags::POSITION_LIMITED != 0);
        assert!(s.q_rad[0] + out.qdot_rad_s[0] * DT <= 2.63 + 1e-12);
        // The whole command is scaled, so it keeps its direction.
        assert!((out.qdot_rad_s[1] / out.qdot_rad_s[0] - 1.0 / 3.0).abs() < 1e-9);
        // Away from the limit: untouched.
        let out = f.step(
            &cmd(6, [-0.3, 0.1, 0.0, 0.0, 0.0, 0.0]),
            &state_at(6, s.q_rad),
            NOW,
        );
        assert_eq!(out.flags & safe_flags::POSITION_LIMITED, 0);
        assert_eq!(out.qdot_rad_s[0], -0.3);
    }

    fn state_at(tick: u64, q: [f64; MAX_JOINTS]) -> RobotState {
        let mut s = state(tick);
        s.q_rad = q;
        s
    }

    #[test]
    fn the_tool_stops_at_the_table_and_may_lift() {
        let model = LinearTcp::gen3_like();
        // Find q with the tool 2 mm above the table plane (z = 0.02 + slack).
        let mut q = [0.0; MAX_JOINTS];
        q[1] = (model.p0[2] - 0.022) / 0.3;
        assert!((model.at(&q[..6])[2] - 0.022).abs() < 1e-12);
        let mut f = filter_without_accel_limit().with_tcp_model(Box::new(LinearTcp::gen3_like()));
        // Joint 1 positive moves the tool down.
        let out = f.step(
            &cmd(5, [0.0, 0.4, 0.0, 0.0, 0.0, 0.0]),
            &state_at(5, q),
            NOW,
        );
        assert!(out.flags & safe_flags::WORKSPACE_LIMITED != 0);
        let mut next = q;
        next[1] += out.qdot_rad_s[1] * DT;
        assert!(model.at(&next[..6])[2] >= 0.02, "into the table");
        let out = f.step(
            &cmd(6, [0.0, -0.4, 0.0, 0.0, 0.0, 0.0]),
            &state_at(6, q),
            NOW,
        );
        assert_eq!(out.flags & safe_flags::WORKSPACE_LIMITED, 0);
    }

    #[test]
    fn deadman_must_be_held_when_required() {
        let cfg = SafetyConfig {
            deadman: true,
            max_acceleration_rad_s2: vec![1e12; 6],
            ..SafetyConfig::default()
        };
        let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
        let out = f.step(&cmd(5, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::DEADMAN | safe_flags::STOP);
        let mut c = cmd(6, [0.1; 6]);
        c.buttons = buttons::DEADMAN;
        assert_eq!(f.step(&c, &state(6), NOW).flags, 0);
    }

    #[test]
    fn estop_latches_until_reset_and_stops_at_once() {
        let mut f = filter();
        for k in 1..40 {
            f.step(&cmd(k, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(k), NOW);
        }
        let mut c = cmd(40, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]);
        c.buttons = buttons::ESTOP;
        let out = f.step(&c, &state(40), NOW);
        assert_eq!(out.flags, safe_flags::ESTOP | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
        // Releasing the button does not release the e-stop.
        let out = f.step(&cmd(41, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(41), NOW);
        assert!(out.flags & safe_flags::ESTOP != 0);
        assert!(f.estopped());
        f.reset();
        let out = f.step(&cmd(42, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0]), &state(42), NOW);
        assert_eq!(out.flags, safe_flags::ACCEL_LIMITED);
        f.estop();
        assert!(f.step(&cmd(43, [0.0; 6]), &state(43), NOW).flags & safe_flags::ESTOP != 0);
        let counts = f.rule_counts();
        assert_eq!(counts[12], 3);
        assert_eq!(counts[5], 3);
    }

    #[test]
    fn a_hold_stops_until_released() {
        let mut f = filter_without_accel_limit();
        f.set_hold(true);
        let out = f.step(&cmd(5, [0.1; 6]), &state(5), NOW);
        assert_eq!(out.flags, safe_flags::HOLD | safe_flags::STOP);
        assert!(out.qdot_rad_s.iter().all(|v| *v == 0.0));
        f.set_hold(false);
        let out = f.step(&cmd(6, [0.1; 6]), &state(6), NOW);
        assert_eq!(out.flags, 0);
    }

    #[test]
    fn switches_mapper_at_the_requested_tick() {
        let mut f = filter();
        assert_eq!(f.active_for_tick(10), 1);
        f.request_switch(2, 12);
        assert_eq!(f.active_for_tick(11), 1);
        assert_eq!(f.active_for_tick(12), 2);
        assert_eq!(f.active_for_tick(13), 2);
        assert_eq!(f.active(), 2);
    }

    #[test]
    fn config_errors_name_the_key() {
        let l = limits();
        let mut cfg = SafetyConfig::default();
        cfg.max_velocity_rad_s[3] = -1.0;
        let e = SafetyFilter::new(cfg, &l, DT).unwrap_err();
        assert_eq!(e.key, "max_velocity_rad_s");
        assert!(
            e.to_string()
                .starts_with("safety.max_velocity_rad_s: entry 3 is -1")
        );
        let mut seven = l.clone();
        for v in [
            &mut seven.lower_rad,
            &mut seven.upper_rad,
            &mut seven.max_velocity_rad_s,
            &mut seven.max_acceleration_rad_s2,
        ] {
            v.push(1.0);
        }
        seven.names.push("joint_7".into());
        let e = SafetyFilter::new(SafetyConfig::default(), &seven, DT).unwrap_err();
        assert!(e.reason.contains("7 joints"));
        let bad = |cfg: SafetyConfig| SafetyFilter::new(cfg, &l, DT).unwrap_err().key;
        let d = SafetyConfig::default;
        assert_eq!(
            bad(SafetyConfig {
                max_joystick_age_ms: 0.0,
                ..d()
            }),
            "max_joystick_age_ms"
        );
        assert_eq!(
            bad(SafetyConfig {
                max_acceleration_rad_s2: vec![1.0; 5],
                ..d()
            }),
            "max_acceleration_rad_s2"
        );
        let e = SafetyFilter::new(
            SafetyConfig {
                joint_margin_rad: 2.6,
                ..d()
            },
            &l,
            DT,
        )
        .unwrap_err();
        assert_eq!(e.key, "joint_margin_rad");
        assert!(e.reason.contains("joint_4"), "{e}");
        assert_eq!(
            bad(SafetyConfig {
                speed_override: 1.5,
                ..d()
            }),
            "speed_override"
        );
        let mut w = d();
        w.workspace.box_min_m[2] = 2.0;
        assert_eq!(bad(w), "workspace.box_min_m");
        let mut w = d();
        w.workspace.table_z_m = 5.0;
        assert_eq!(bad(w), "workspace.table_z_m");
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            6 => -3.0f64..3.0,
            1 => Just(f64::NAN),
            1 => Just(f64::INFINITY),
            1 => Just(f64::NEG_INFINITY),
            1 => Just(1e300),
            1 => Just(-1e-300),
        ]
    }

    /// A joint angle: anywhere in the range, at or just beyond its margin, or garbage.
    fn any_q(j: usize) -> impl Strategy<Value = f64> {
        let hi = gen3_lite::limits().upper_rad[j];
        prop_oneof![
            4 => -hi..hi,
            1 => Just(hi - 0.05),
            1 => Just(-(hi - 0.05)),
            1 => (hi - 0.06)..(hi - 0.04),
            1 => Just(f64::NAN),
        ]
    }

    /// Whether `p` is above the table plane and in the box of `w`, to `tol` (m): the test's
    /// own oracle, independent of [`Bounds`].
    fn in_workspace(w: &WorkspaceConfig, p: &[f64; 3], tol: f64) -> bool {
        p[2] >= w.table_z_m - tol
            && (0..3).all(|i| p[i] >= w.box_min_m[i] - tol && p[i] <= w.box_max_m[i] + tol)
    }

    /// The half-spaces `n·x >= b` the filter keeps the tool in: the configured bounds less
    /// the slack.
    fn planes(w: &WorkspaceConfig) -> [([f64; 3], f64); 7] {
        let s = WORKSPACE_SLACK_M;
        let (lo, hi) = (w.box_min_m, w.box_max_m);
        [
            ([0.0, 0.0, 1.0], w.table_z_m + s),
            ([1.0, 0.0, 0.0], lo[0] + s),
            ([0.0, 1.0, 0.0], lo[1] + s),
            ([0.0, 0.0, 1.0], lo[2] + s),
            ([-1.0, 0.0, 0.0], -(hi[0] - s)),
            ([0.0, -1.0, 0.0], -(hi[1] - s)),
            ([0.0, 0.0, -1.0], -(hi[2] - s)),
        ]
    }

    /// Whether the arm at `q` moving at `base` was already too fast: even braking along its
    /// direction as hard as the acceleration limits allow (the hardest stop that keeps the
    /// direction), some joint, or the tool (to first order, by its position `p` and Jacobian
    /// `jv`), would cross its bound within the next tick, or go further out of one it is
    /// already past. Only then may the hard guarantees exceed the acceleration limit.
    fn too_fast_to_brake(
        cfg: &SafetyConfig,
        q: &[f64],
        base: &[f64],
        tool: Option<([f64; 3], [[f64; MAX_JOINTS]; 3])>,
    ) -> bool {
        let l = limits();
        let m = cfg.joint_margin_rad;
        let amax = &cfg.max_acceleration_rad_s2;
        let c = (1.0 - rules::brake_rate(&base[..6], amax) * DT).max(0.0);
        let braked: [f64; 6] = std::array::from_fn(|j| base[j] * c);
        // Approaching at `speed` with `dist` left (nothing left past the bound).
        let crosses = |dist: f64, speed: f64| speed > 0.0 && speed * DT > dist.max(0.0) - 1e-12;
        let joint = (0..6).any(|j| {
            crosses(l.upper_rad[j] - m - q[j], braked[j])
                || crosses(q[j] - (l.lower_rad[j] + m), -braked[j])
        });
        let tool = tool.is_some_and(|(p, jv)| {
            let v = rules::tcp_velocity(&jv, &braked);
            planes(&cfg.workspace).iter().any(|(nrm, b)| {
                let dist = nrm[0] * p[0] + nrm[1] * p[1] + nrm[2] * p[2] - b;
                crosses(dist, -(nrm[0] * v[0] + nrm[1] * v[1] + nrm[2] * v[2]))
            })
        });
        joint || tool
    }

    /// Checks the acceleration invariant of one output: every joint changes by at most its
    /// limit per tick from the arm's velocity `base` (the filter must agree on it), unless
    /// the e-stop latched or a hard guarantee overrode an arm that was already too fast to
    /// brake in time.
    fn check_acceleration(
        f: &SafetyFilter,
        out: &SafeCommand,
        base: &[f64; MAX_JOINTS],
        q: &[f64],
        tool: Option<([f64; 3], [[f64; MAX_JOINTS]; 3])>,
    ) -> Result<(), TestCaseError> {
        let r = f.last_report();
        prop_assert_eq!(
            &r.base_rad_s[..6],
            &base[..6],
            "the filter's idea of the arm's velocity"
        );
        let amax = &f.config().max_acceleration_rad_s2;
        let over =
            (0..6).find(|&j| (out.qdot_rad_s[j] - base[j]).abs() > amax[j] * DT * (1.0 + 1e-9));
        if let Some(j) = over {
            prop_assert!(
                out.flags & safe_flags::ESTOP != 0 || r.hard_override(),
                "joint {j} changed by {} (limit {}), flags {:#x}, no hard override",
                out.qdot_rad_s[j] - base[j],
                amax[j] * DT,
                out.flags
            );
            prop_assert!(
                out.flags & safe_flags::ESTOP != 0 || too_fast_to_brake(f.config(), q, base, tool),
                "joint {j}: the hard override broke the acceleration limit of an arm that could brake in time (flags {:#x})",
                out.flags
            );
        }
        Ok(())
    }

    fn any_pose() -> impl Strategy<Value = [f64; 6]> {
        (any_q(0), any_q(1), any_q(2), any_q(3), any_q(4), any_q(5))
            .prop_map(|(a, b, c, d, e, f)| [a, b, c, d, e, f])
    }

    proptest! {
        /// Closed loop: the arm integrates the filter's own outputs from arbitrary poses and
        /// arbitrary (also non-finite) commands, and at times reports a velocity of its own (a
        /// missed tick, garbage); every output is finite, within the velocity and acceleration
        /// limits (only a latched e-stop or a hard guarantee on an arm already too fast may
        /// change it faster), never carries a joint past its margin and never takes the tool
        /// out of the workspace.
        #[test]
        fn every_guarantee_holds_in_closed_loop(
            start in any_pose(),
            cmds in proptest::collection::vec(
                (
                    proptest::array::uniform6(any_f64()),
                    any_f64(),
                    0u64..2,
                    any::<bool>(),
                    0u32..4,
                    proptest::option::weighted(0.2, proptest::array::uniform6(prop_oneof![
                        8 => -2.0f64..2.0,
                        1 => Just(f64::NAN),
                    ])),
                ),
                1..30,
            ),
        ) {
            let model = LinearTcp::gen3_like();
            let mut f = filter().with_tcp_model(Box::new(LinearTcp::gen3_like()));
            let vmax = gen3_lite::DEFAULT_VELOCITY_RAD_S;
            let w = WorkspaceConfig::default();
            let limits = limits();
            let mut q = [0.0; MAX_JOINTS];
            q[..6].copy_from_slice(&start);
            let mut prev = [0.0; MAX_JOINTS];
            for (k, (qdot, gripper, stale, executed, btn, measured)) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut c = cmd(tick, qdot);
                c.gripper_rate = gripper;
                c.buttons = if btn == 3 { buttons::ESTOP } else { 0 };
                let mut s = state_at(tick + stale, q);
                s.qdot_rad_s = prev;
                if let Some(m) = measured {
                    s.qdot_rad_s[..6].copy_from_slice(&m);
                }
                if !executed {
                    s.applied_tick = NO_TICK;
                }
                // The arm's velocity as the filter must take it: the previous output if the
                // bridge executed it or the robot reports garbage, else the measured one.
                let mut base = prev;
                if !(executed && stale == 0 && k > 0) && s.qdot_rad_s.iter().all(|v| v.is_finite()) {
                    for j in 0..6 { base[j] = s.qdot_rad_s[j].clamp(-vmax[j], vmax[j]); }
                }
                let out = f.step(&c, &s, NOW);
                let q_ok = q[..6].iter().all(|v| v.is_finite());
                let p_inside = q_ok && in_workspace(&w, &model.at(&q[..6]), 0.0);
                let tool = q_ok.then(|| (model.at(&q[..6]), model.a));
                check_acceleration(&f, &out, &base, &q[..6], tool)?;
                for j in 0..6 {
                    let v = out.qdot_rad_s[j];
                    prop_assert!(v.is_finite());
                    prop_assert!(v.abs() <= vmax[j]);
                    if q_ok {
                        let (lo, hi) = (limits.lower_rad[j] + 0.05, limits.upper_rad[j] - 0.05);
                        let next = q[j] + v * DT;
                        if q[j] <= hi { prop_assert!(next <= hi + 1e-12, "joint {j} past its upper margin"); }
                        else { prop_assert!(v <= 0.0); }
                        if q[j] >= lo { prop_assert!(next >= lo - 1e-12, "joint {j} past its lower margin"); }
                        else { prop_assert!(v >= 0.0); }
                    }
                }
                prop_assert!(out.gripper_rate.is_finite());
                prop_assert!(out.gripper_rate.abs() <= f.config().max_gripper_rate);
                prop_assert!(out.qdot_rad_s[6..].iter().all(|v| *v == 0.0));
                if q_ok {
                    let mut next = q;
                    for j in 0..6 { next[j] += out.qdot_rad_s[j] * DT; }
                    if p_inside {
                        prop_assert!(in_workspace(&w, &model.at(&next[..6]), 1e-12), "tool left the workspace");
                    }
                    q = next;
                }
                if btn == 3 { f.reset(); }
                prev = out.qdot_rad_s;
            }
        }

        /// The tool starts 0 to 5 cm above the table and is driven by arbitrary commands: it
        /// never goes below the table plane.
        #[test]
        fn the_tool_never_enters_the_table(
            others in proptest::array::uniform5(-0.5f64..0.5),
            height in 0.0f64..0.05,
            cmds in proptest::collection::vec(proptest::array::uniform6(-3.0f64..3.0), 1..40),
        ) {
            let model = LinearTcp::gen3_like();
            let mut q = [0.0; MAX_JOINTS];
            q[0] = others[0];
            q[2] = others[1];
            q[3] = others[2];
            q[4] = others[3];
            q[5] = others[4];
            // z = p0z - 0.3 q1 - 0.25 q2 - 0.1 q4: solve for q1.
            q[1] = (model.p0[2] - (0.02 + height) - 0.25 * q[2] - 0.1 * q[4]) / 0.3;
            prop_assume!(Bounds::new(0.02, [-0.8, -0.8, -0.1], [0.8, 0.8, 1.1]).contains(&model.at(&q[..6]), 0.0));
            let mut f = filter().with_tcp_model(Box::new(LinearTcp::gen3_like()));
            let mut prev = [0.0; MAX_JOINTS];
            for (k, qdot) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                let out = f.step(&cmd(tick, qdot), &s, NOW);
                for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                prop_assert!(model.at(&q[..6])[2] >= 0.02 - 1e-12, "tool at z {}", model.at(&q[..6])[2]);
                prev = out.qdot_rad_s;
            }
        }

        /// The same with the real Gen3 lite kinematics (nonlinear): from poses with the tool
        /// just above the table, arbitrary commands never take it below the plane (the rule
        /// predicts one tick to first order; the slack covers the rest).
        #[test]
        fn the_gen3_lite_tool_never_enters_the_table(
            start in proptest::array::uniform6(-1.5f64..1.5),
            height in 0.011f64..0.06,
            cmds in proptest::collection::vec(proptest::array::uniform6(-3.0f64..3.0), 1..40),
        ) {
            let arm = kinematics::Gen3Lite::get().arm();
            let z = |q: &[f64]| arm.fk(q).unwrap().translation.vector.z;
            let mut q = [0.0; MAX_JOINTS];
            q[..6].copy_from_slice(&start);
            // Put the tool `height` above the table plane by the shoulder angle.
            let shoulder = (0..=520)
                .map(|i| -2.6 + i as f64 * 0.01)
                .find(|a| { q[1] = *a; (z(&q[..6]) - 0.02 - height).abs() < 0.005 });
            prop_assume!(shoulder.is_some());
            prop_assume!(!limits().clamp_position(&mut q[..6].to_vec()));
            let mut f = filter().with_tcp_model(Box::new(gen3_lite_tcp()));
            let mut prev = [0.0; MAX_JOINTS];
            for (k, qdot) in cmds.into_iter().enumerate() {
                let tick = k as u64 + 1;
                let mut s = state_at(tick, q);
                s.qdot_rad_s = prev;
                let out = f.step(&cmd(tick, qdot), &s, NOW);
                for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                prop_assert!(z(&q[..6]) >= 0.02, "tool at z {}", z(&q[..6]));
                prev = out.qdot_rad_s;
            }
        }
    }

    /// Joint velocity limits at or below the URDF's, down to 1 % of it.
    fn any_vmax() -> impl Strategy<Value = [f64; 6]> {
        let urdf = kinematics::Gen3Lite::get().arm().velocity_limits().to_vec();
        proptest::array::uniform6(prop_oneof![1 => Just(1.0), 3 => 0.01f64..1.0])
            .prop_map(move |frac| std::array::from_fn(|j| urdf[j] * frac[j]))
    }

    /// Joint acceleration limits from barely moving to nearly unlimited.
    fn any_amax() -> impl Strategy<Value = [f64; 6]> {
        proptest::array::uniform6(prop_oneof![
            1 => Just(1e-3),
            4 => 0.01f64..20.0,
            1 => Just(1e4),
        ])
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The real Gen3 lite kinematics (nonlinear) in closed loop against a table plane and
        /// a small box around the tool's start (2 mm to 12 cm to each face): held arbitrary
        /// commands, executed or reported back by the robot, never take the tool below the
        /// table or out of the box (the rule predicts one tick to first order; the slack
        /// covers the rest), and the acceleration limit holds but where a hard guarantee
        /// stopped an arm already too fast (the curved path's second-order rest).
        #[test]
        fn the_gen3_lite_tool_stays_above_the_table_and_in_the_box(
            start in proptest::array::uniform6(-2.4f64..2.4),
            below in 0.002f64..0.12,
            lo in proptest::array::uniform3(0.002f64..0.12),
            hi in proptest::array::uniform3(0.002f64..0.12),
            cmds in proptest::collection::vec(
                (proptest::array::uniform6(-3.0f64..3.0), 1usize..12, any::<bool>()),
                1..12,
            ),
        ) {
            let mut model = gen3_lite_tcp();
            let tool = |model: &mut ChainTcp, q: &[f64]| {
                let (mut p, mut jv) = ([0.0; 3], [[0.0; MAX_JOINTS]; 3]);
                model.tcp(q, &mut p, &mut jv);
                (p, jv)
            };
            let mut q = [0.0; MAX_JOINTS];
            q[..6].copy_from_slice(&start);
            let (p0, _) = tool(&mut model, &q[..6]);
            let mut cfg = SafetyConfig::default();
            cfg.workspace.table_z_m = p0[2] - below;
            cfg.workspace.box_min_m = std::array::from_fn(|i| p0[i] - lo[i]);
            cfg.workspace.box_max_m = std::array::from_fn(|i| p0[i] + hi[i]);
            let w = cfg.workspace.clone();
            let mut f = SafetyFilter::new(cfg, &limits(), DT)
                .unwrap()
                .with_tcp_model(Box::new(gen3_lite_tcp()));
            let mut prev = [0.0; MAX_JOINTS];
            let mut tick = 0;
            for (qdot, hold, executed) in cmds {
                for _ in 0..hold {
                    tick += 1;
                    let mut s = state_at(tick, q);
                    s.qdot_rad_s = prev;
                    if !executed {
                        s.applied_tick = NO_TICK;
                    }
                    let out = f.step(&cmd(tick, qdot), &s, NOW);
                    let at = tool(&mut model, &q[..6]);
                    check_acceleration(&f, &out, &prev, &q[..6], Some(at))?;
                    for j in 0..6 { q[j] += out.qdot_rad_s[j] * DT; }
                    let (p, _) = tool(&mut model, &q[..6]);
                    prop_assert!(p[2] >= w.table_z_m, "tick {tick}: tool at z {} below the table {}", p[2], w.table_z_m);
                    prop_assert!(in_workspace(&w, &p, 0.0), "tick {tick}: tool at {p:?} out of the box {:?} .. {:?}", w.box_min_m, w.box_max_m);
                    prev = out.qdot_rad_s;
                }
            }
        }

        /// An arm that does what the filter says (every output executed, a fault now and
        /// then), from rest in range and inside the workspace, with any speed override and
        /// limits, never needs the hard guarantees to break the acceleration limit: the
        /// braking rules keep it able to stop within it, so no output changes faster than it
        /// allows, whatever the commands (held a while, then changed in any direction), and
        /// no joint passes its margin nor the tool a bound (a linear tool model: exact).
        #[test]
        fn an_arm_that_follows_the_filter_never_brakes_harder_than_allowed(
            start in proptest::array::uniform6(-2.45f64..2.45),
            speed in prop_oneof![1 => Just(1.0), 2 => 0.05f64..1.0],
            vmax in prop_oneof![1 => Just(gen3_lite::DEFAULT_VELOCITY_RAD_S), 1 => any_vmax()],
            amax in prop_oneof![1 => Just(gen3_lite::DEFAULT_ACCELERATION_RAD_S2), 1 => any_amax()],
            cmds in proptest::collection::vec(
                (proptest::array::uniform6(-3.0f64..3.0), 1usize..30, 0u8..8),
                1..8,
            ),
        ) {
            let model = LinearTcp::gen3_like();
            let cfg = SafetyConfig {
                max_velocity_rad_s: vmax.to_vec(),
                max_acceleration_rad_s2: amax.to_vec(),
                speed_override: speed,
                ..SafetyConfig::default()
            };
            let w = cfg.workspace.clone();
            let inside = |q: &[f64], slack: f64| {
                in_workspace(&w, &model.at(q), slack)
            };
            // Pull the start toward q = 0 (the tool well inside) until the tool is inside.
            let mut q = [0.0; MAX_JOINTS];
            for i in 0..40 {
                let s = 0.8f64.powi(i);
                for j in 0..6 { q[j] = start[j] * s; }
                if inside(&q[..6], -WORKSPACE_SLACK_M) { break; }
            }
            prop_assert!(inside(&q[..6], -WORKSPACE_SLACK_M));
            let mut f = SafetyFilter::new(cfg, &limits(), DT)
                .unwrap()
                .with_tcp_model(Box::new(LinearTcp::gen3_like()));
            let l = limits();
            let mut prev = [0.0; MAX_JOINTS];
            let mut tick = 0;
            for (qdot, hold, fault) in cmds {
                for _ in 0..hold {
                    tick += 1;
                    let mut c = cmd(tick, qdot);
                    match fault {
                        0 => c.qdot_rad_s[1] = f64::NAN,
                        1 => c.flags = mapper_flags::INPUT_STALE,
                        _ => {}
                    }
                    let mut s = state_at(tick, q);
                    s.qdot_rad_s = prev;
                    let out = f.step(&c, &s, NOW);
                    let r = f.last_report();
                    for j in 0..6 {
                        let v = out.qdot_rad_s[j];
                        prop_assert!(v.abs() <= vmax[j]);
                        prop_assert!(
                            (v - prev[j]).abs() <= amax[j] * DT * (1.0 + 1e-9),
                            "tick {tick} joint {j}: changed by {} (limit {}), flags {:#x}, {r:?}",
                            v - prev[j], amax[j] * DT, out.flags
                        );
                        q[j] += v * DT;
                        prop_assert!(q[j] <= l.upper_rad[j] - 0.05 + 1e-12 && q[j] >= l.lower_rad[j] + 0.05 - 1e-12);
                    }
                    prop_assert!(inside(&q[..6], 1e-12), "tick {tick}: tool out at {:?}", model.at(&q[..6]));
                    prev = out.qdot_rad_s;
                }
            }
        }

        /// From arbitrary in-range poses and arm velocities, with the speed override and the
        /// velocity and acceleration limits anywhere in their ranges (also at the URDF limit
        /// and at the extremes): whenever the velocity limit is the only rule that acted, the
        /// output is a positive multiple of the command, as large as the tightest joint allows;
        /// with no rule acting it is the command times the override, exactly.
        #[test]
        fn only_the_velocity_limit_keeps_the_direction(
            q in proptest::array::uniform6(-2.4f64..2.4),
            qdot in proptest::array::uniform6(prop_oneof![4 => -5.0f64..5.0, 1 => Just(0.0)]),
            speed in prop_oneof![1 => Just(1.0), 1 => Just(1e-3), 4 => 1e-3f64..1.0],
            vmax in any_vmax(),
            amax in any_amax(),
            near in proptest::array::uniform6(-0.99f64..0.99),
            from_rest in any::<bool>(),
            tool in any::<bool>(),
        ) {
            let cfg = SafetyConfig {
                max_velocity_rad_s: vmax.to_vec(),
                max_acceleration_rad_s2: amax.to_vec(),
                speed_override: speed,
                ..SafetyConfig::default()
            };
            let mut f = SafetyFilter::new(cfg, &limits(), DT).unwrap();
            if tool {
                f = f.with_tcp_model(Box::new(gen3_lite_tcp()));
            }
            // The arm moves at rest or near the velocity the command asks for (within one
            // tick's acceleration of it), so the acceleration limit does not have to act.
            let wanted: [f64; 6] = std::array::from_fn(|j| qdot[j] * speed);
            let k = uniform_scale(&wanted, &vmax);
            let mut s = state_at(5, [q[0], q[1], q[2], q[3], q[4], q[5], 0.0, 0.0]);
            s.applied_tick = NO_TICK;
            if !from_rest {
                for j in 0..6 {
                    s.qdot_rad_s[j] = (wanted[j] * k + near[j] * amax[j] * DT).clamp(-vmax[j], vmax[j]);
                }
            }
            let c = cmd(5, qdot);
            let out = f.step(&c, &s, NOW);
            let v = &out.qdot_rad_s;
            prop_assert!(v.iter().all(|x| x.is_finite()));
            if out.flags & (safe_flags::POSITION_LIMITED | safe_flags::WORKSPACE_LIMITED) == 0 && !from_rest {
                // Nothing but the velocity limit changed the target, and it is within reach.
                prop_assert_eq!(out.flags & safe_flags::ACCEL_LIMITED, 0);
            }
            if out.flags & !safe_flags::VELOCITY_SCALED == 0 {
                // One factor c for every joint: v = c * qdot.
                let big = (0..6).max_by(|a, b| qdot[*a].abs().total_cmp(&qdot[*b].abs())).unwrap();
                let c_out = if qdot[big] == 0.0 { 0.0 } else { v[big] / qdot[big] };
                for j in 0..6 {
                    prop_assert!(
                        (v[j] - c_out * qdot[j]).abs() <= 1e-12 * (1.0 + qdot[j].abs()),
                        "joint {j}: {} is not {c_out} x {}", v[j], qdot[j]
                    );
                    prop_assert!(v[j].abs() <= vmax[j] * (1.0 + 1e-12));
                }
                prop_assert!(c_out >= 0.0 && c_out <= speed * (1.0 + 1e-12));
                if out.flags == 0 {
                    prop_assert_eq!(&v[..6], &wanted[..]);
                } else {
                    // Scaled as little as the tightest joint allows: that joint at its limit.
                    prop_assert!(qdot[big] != 0.0);
                    let tight = (0..6).map(|j| v[j].abs() / vmax[j]).fold(0.0, f64::max);
                    prop_assert!((tight - 1.0).abs() < 1e-9, "tightest joint at {tight} of its limit");
                }
            }
        }
    }

    /// The filter takes the arm from the robot profile it is given.
    #[test]
    fn a_filter_for_another_arm() {
        let planar = kinematics::RobotProfile::new(&kinematics::ProfileSpec::planar5()).unwrap();
        let cfg = SafetyConfig::for_robot(&planar);
        assert_eq!(cfg.max_velocity_rad_s, [1.0; 5]);
        // Checked against the default arm's description, five joints are refused ...
        assert!(SafetyFilter::new(cfg.clone(), planar.limits(), DT).is_err());
        // ... and accepted for their own robot, with its tool model.
        let mut f = SafetyFilter::for_robot(cfg, &planar, DT)
            .unwrap()
            .with_tcp_model(Box::new(ChainTcp::of(&planar)));
        let mut s = RobotState::at_rest(5, NOW - 1_000_000, 5);
        s.applied_tick = 4;
        s.q_rad[..5].copy_from_slice(&[0.3, 0.4, 0.3, 0.2, 0.1]);
        let mut m = cmd(5, [5.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        m.n_joints = 5;
        let out = f.step(&m, &s, NOW);
        assert!(
            out.qdot_rad_s[0] > 0.0 && out.qdot_rad_s[0] <= 1.0,
            "{out:?}"
        );
        assert_eq!(out.qdot_rad_s[5], 0.0);
    }
}
