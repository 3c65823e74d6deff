//! The safety filter: the last word before the arm. A pure function of (command, newest
//! robot state, configuration, time) to (command, flags), with a little memory between ticks
//! (the previous output, the active mapper, a latched e-stop). The safety process is a thin
//! loop around [`SafetyFilter::step`].
//!
//! Each tick applies the rules in the order [`SafetyFilter::step`] states, one named phase
//! each.
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

    /// The factor `<= 1` for `v` of the clearance rule of step 4: the slow-down of every
    /// approaching pair within `slowdown_distance_m`, and braking before the stop distance
    /// ([`SafetyFilter::clearance_brake`]); 1 without the whole-arm rules.
    fn clearance_slowdown(&self, v: &[f64]) -> f64 {
        let Some(arm) = self.arm.as_ref() else {
            return 1.0;
        };
        clearance::slowdown_scale(
            arm.near(),
            v,
            self.cfg.stop_distance_m + clearance::CLEARANCE_SLACK_M,
            self.cfg.slowdown_distance_m,
            self.cfg.max_tcp_speed_m_s,
        )
        .min(self.clearance_brake(v))
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
    ///
    /// The rules, in this order:
    /// 1. Faults stop the arm: a non-finite value (in the command, the state or the
    ///    operator's input), a mis-shaped command, a stale robot state, joystick sample (also
    ///    none at all, unless the map ignores the input by design) or command (also none for
    ///    the tick, [`SafetyFilter::step_unanswered`]), a supervisor hold, a released
    ///    deadman. The target becomes zero and the acceleration limit turns that into a
    ///    controlled stop. After a fault (these, or ticks the bridge did not execute:
    ///    missed, a process that died or restarted) and at start-up, the arm stays stopped
    ///    until the operator's input has passed through neutral ([`restart`], flagged
    ///    [`safe_flags::AWAITING_NEUTRAL`]).
    /// 2. A latched e-stop (joystick button or `scl estop`, released only by `scl reset`)
    ///    commands zero at once, the one rule that does not wait for the acceleration limit.
    /// 3. The speed override, then the joint velocity limits by one uniform factor (the command
    ///    keeps its direction, and so stays in the span of the map), then (with
    ///    [`SafetyFilter::with_whole_arm`]) the Cartesian speed caps: the tool and every link
    ///    capsule's ends at most `max_tcp_speed_m_s`, the tool's turning at most
    ///    `max_tcp_angular_speed_rad_s`, by one factor ([`clearance::speed_scale`]).
    /// 4. Joint position limits less a margin and workspace bounds on the tool (table plane,
    ///    box): a joint or the tool may approach a bound no faster than it can stop before it;
    ///    motion away from a bound is free. Both scale the whole command. Stopping keeps the
    ///    direction (the acceleration rule scales a change as a whole), so a joint brakes only as
    ///    fast as the command's slowest joint lets it: the braking distances use that
    ///    deceleration ([`rules::brake_rate`]), not each joint's own limit. With the whole-arm
    ///    rules, every checked pair of the collision model (each link against the others and
    ///    against `[safety.scene]`) is such a bound `d - stop_distance_m` away, approached at
    ///    `-d_dot`, and within `slowdown_distance_m` an approaching pair also slows the command
    ///    down, to zero at the stop distance ([`clearance`]).
    /// 5. The acceleration limits: the change from the arm's current velocity is scaled as a
    ///    whole until every joint's change fits. If that leaves an output that could not stop
    ///    in time (the arm's velocity and the target point in different directions), it is
    ///    moved toward braking the arm's velocity along its own direction, which can whenever
    ///    the previous output could, and is within the acceleration limits too.
    /// 6. Hard guarantees last: no joint past its margin and the tool not out of the workspace
    ///    within the next tick, even where that means braking harder than the acceleration
    ///    limit: only when even the hardest braking of the arm's velocity within the limits
    ///    would cross a bound this tick, i.e. the arm was already too fast (a fault elsewhere,
    ///    a robot not doing what it was told; with a curved tool path, the second-order rest
    ///    of the one-tick prediction). Then the speed caps again, and no checked pair closer
    ///    than the stop distance at the next tick: to first order, then by the exact distances
    ///    at the next tick's pose ([`clearance::WholeArm::verify`]).
    ///
    ///
    /// Each step is one phase below, called in this order; every rule that scales the whole
    /// command does it through one helper that also sets its flag and reports its factor.
    pub fn step(&mut self, cmd: &MapperCommand, state: &RobotState, now_ns: u64) -> SafeCommand {
        self.step_with(cmd, true, state, now_ns)
    }

    /// Answers `state` when no mapper command for its tick came in time: the step of a
    /// command that asks for nothing (zero velocity, no operator input), flagged
    /// [`safe_flags::STALE_COMMAND`] and a stop: with the e-stop latched zero at once, else a
    /// controlled stop. The command's [`SafeCommand::mapper_t_ns`] is 0 (no mapper command)
    /// and its `mapper_id` is `mapper_id` (the active mapper). The safety process calls it
    /// with the e-stop latched, so the e-stop acts at the next tick whether a mapper is there
    /// or not; the replay of a recording calls it for each such command.
    pub fn step_unanswered(
        &mut self,
        mapper_id: u32,
        state: &RobotState,
        now_ns: u64,
    ) -> SafeCommand {
        self.step_with(&unanswered_command(mapper_id, state), false, state, now_ns)
    }

    /// [`SafetyFilter::step`] of `cmd`, a mapper's (`answered`) or one that stands in for
    /// none ([`SafetyFilter::step_unanswered`]).
    fn step_with(
        &mut self,
        cmd: &MapperCommand,
        answered: bool,
        state: &RobotState,
        now_ns: u64,
    ) -> SafeCommand {
        let control = self.take_control();
        // 1. Faults, the e-stop's latch and restart prevention.
        let mut t = self.classify_faults(cmd, answered, state, now_ns);
        t.report.base_rad_s = self.base_velocity(cmd, state, t.qdot_ok);
        t.arm_ok = self.update_arm(&t);
        let out = if t.flags & safe_flags::ESTOP != 0 {
            // 2. A latched e-stop: zero at once.
            [0.0; MAX_JOINTS]
        } else {
            let mut target = self.target(cmd, &t);
            t.tool = self.tool_at(&t);
            // 3. and 4. The rules that scale the target, in their order.
            self.scale_target(&mut t, &mut target);
            // 5. The acceleration limits, and braking in time.
            let mut out = self.limit_acceleration(&mut t, target);
            // 6. The hard guarantees.
            self.hard_guarantees(&mut t, &mut out);
            out
        };
        self.finish(cmd, t, control, out)
    }

    /// The control inputs this step begins with ([`SafeCommand::control`]); clears the
    /// interruption flag.
    fn take_control(&mut self) -> u32 {
        use ipc_types::safe_control;
        let mut control = safe_control::RECORDED;
        if self.estop {
            control |= safe_control::ESTOP;
        }
        if self.hold {
            control |= safe_control::HOLD;
        }
        if std::mem::take(&mut self.interrupted) {
            control |= safe_control::INTERRUPTED;
        }
        control
    }

    /// Step 1: the faults of this tick (each its flag), a button's e-stop latched, and
    /// restart prevention ticked; `stop` if any of these stops the arm.
    fn classify_faults<'s>(
        &mut self,
        cmd: &MapperCommand,
        answered: bool,
        state: &'s RobotState,
        now_ns: u64,
    ) -> Tick<'s> {
        let n = self.n;
        let mut flags = 0;
        if cmd.n_joints as usize != n || state.n_joints as usize != n {
            flags |= safe_flags::BAD_SHAPE;
        }
        let q_ok = all_finite(&state.q_rad[..n]);
        let qdot_ok = all_finite(&state.qdot_rad_s[..n]);
        // The operator's input too: a non-finite sample is a fault like a stale one.
        let input_ok = cmd.flags & mapper_flags::INPUT_NON_FINITE == 0
            && cmd.action.iter().all(|a| a.is_finite());
        if !(all_finite(&cmd.qdot_rad_s)
            && cmd.gripper_rate.is_finite()
            && input_ok
            && q_ok
            && qdot_ok)
        {
            flags |= safe_flags::NON_FINITE;
        }
        if cmd.tick != state.tick || !answered {
            flags |= safe_flags::STALE_COMMAND;
        }
        if now_ns.saturating_sub(cmd.state_t_ns) > self.max_state_age_ns {
            flags |= safe_flags::STALE_STATE;
        }
        let joystick_stale = if cmd.joystick_t_ns == 0 {
            // No sample ever: only a map that ignores the input by design may move.
            cmd.flags & mapper_flags::IGNORES_INPUT == 0
        } else {
            now_ns.saturating_sub(cmd.joystick_t_ns) > self.max_joystick_age_ns
        };
        if answered && (joystick_stale || cmd.flags & mapper_flags::INPUT_STALE != 0) {
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
        let armed = self.restart_prevention(cmd, state, flags != 0);
        if answered && self.cfg.deadman && cmd.buttons & buttons::DEADMAN == 0 {
            flags |= safe_flags::DEADMAN;
        }
        if !armed && flags == 0 {
            flags |= safe_flags::AWAITING_NEUTRAL;
        }
        Tick {
            state,
            n,
            flags,
            stop: flags != 0,
            q_ok,
            qdot_ok,
            arm_ok: false,
            tool: None,
            report: StepReport::default(),
        }
    }

    /// Restart prevention ([`restart`]): any fault of this tick, a device that is gone, or
    /// ticks the bridge did not execute since our last command (missed, or a process of the
    /// graph died or restarted meanwhile) wait for neutral input. Returns whether motion is
    /// allowed (armed).
    fn restart_prevention(&mut self, cmd: &MapperCommand, state: &RobotState, fault: bool) -> bool {
        let device_gone = cmd.buttons & buttons::NO_DEVICE != 0;
        if self.prev_tick != NO_TICK
            && !(cmd.tick == self.prev_tick.wrapping_add(1) && state.applied_tick == self.prev_tick)
        {
            self.restart.interrupt();
        }
        // Only a usable sample that answers a robot tick is the operator's input.
        let unusable = mapper_flags::NO_INPUT
            | mapper_flags::INPUT_NON_FINITE
            | mapper_flags::INPUT_STALE
            | mapper_flags::INPUT_NO_TICK;
        let operator =
            (cmd.flags & unusable == 0 && !device_gone && cmd.action.iter().all(|a| a.is_finite()))
                .then(|| restart::Operator {
                    action_norm: f64::from(cmd.action[0]).hypot(f64::from(cmd.action[1])),
                    deadman: cmd.buttons & buttons::DEADMAN != 0,
                    uses_input: cmd.flags & mapper_flags::IGNORES_INPUT == 0,
                });
        self.restart.tick(fault || device_gone, operator)
    }

    /// The velocity the arm has now: our previous output if the bridge executed it,
    /// otherwise what the robot reports (if it reports garbage, which is a fault and a stop,
    /// our previous output: the stop decelerates from there); never more than the limits.
    fn base_velocity(
        &self,
        cmd: &MapperCommand,
        state: &RobotState,
        qdot_ok: bool,
    ) -> [f64; MAX_JOINTS] {
        let n = self.n;
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
        base
    }

    /// The whole arm's clearance at this state (also reported while stopped): whether the
    /// whole-arm rules can run this tick.
    fn update_arm(&mut self, t: &Tick<'_>) -> bool {
        t.q_ok
            && self
                .arm
                .as_mut()
                .is_some_and(|a| a.update(&t.state.q_rad[..t.n], t.state.gripper))
    }

    /// The tool at this state, for the workspace rules (none with non-finite joint angles).
    fn tool_at(&mut self, t: &Tick<'_>) -> Option<Tool> {
        if t.q_ok {
            self.tool(&t.state.q_rad[..t.n])
        } else {
            None
        }
    }

    /// What the rules start from: the command at the speed override, or zero on a stop.
    fn target(&self, cmd: &MapperCommand, t: &Tick<'_>) -> [f64; MAX_JOINTS] {
        let mut target = [0.0; MAX_JOINTS];
        if !t.stop {
            for (v, c) in target.iter_mut().zip(&cmd.qdot_rad_s).take(t.n) {
                *v = c * self.cfg.speed_override;
            }
        }
        target
    }

    /// Steps 3 and 4: the rules that scale the target, in this order, each on what the ones
    /// before left: the joint velocity limits, the speed caps, then braking before the joint
    /// margins, the workspace bounds and every checked pair (with its slow-down).
    fn scale_target(&mut self, t: &mut Tick<'_>, target: &mut [f64; MAX_JOINTS]) {
        let n = t.n;
        let target = &mut target[..n];
        if !t.stop {
            let k = uniform_scale(target, &self.vmax[..n]);
            t.scale(Scaling::Velocity, target, k);
        }
        if let Some(arm) = self.arm.as_mut().filter(|_| t.arm_ok) {
            let k = Self::speed_cap(arm, &self.cfg, target);
            t.scale(Scaling::SpeedCap, target, k);
            // Every output this tick lies between the target, the arm's velocity and zero, so
            // no point moves faster than the faster of the two: the pairs that can need
            // braking are those within the distance the fastest pair (both sides moving)
            // covers in a tick and a stop at the slowest braking rate the rule plans with.
            let fastest = arm
                .max_point_speed(target)
                .max(arm.max_point_speed(&t.report.base_rad_s[..n]));
            let reach =
                2.0 * fastest * (2.0 * self.dt + 0.5 / (clearance::BRAKE_SHARE * self.alpha_min));
            let stop = self.cfg.stop_distance_m + clearance::CLEARANCE_SLACK_M;
            arm.collect(self.cfg.slowdown_distance_m.max(stop + reach));
        }
        if !t.q_ok {
            return;
        }
        let state = t.state;
        let k = self.position_brake(&state.q_rad[..n], target);
        t.scale(Scaling::Position, target, k);
        let k = self.workspace_brake(t.tool.as_ref(), target);
        t.scale(Scaling::Workspace, target, k);
        if t.arm_ok {
            let k = self.clearance_slowdown(target);
            t.scale(Scaling::Clearance, target, k);
        }
    }

    /// Step 5: the change from the arm's velocity scaled as a whole into the acceleration
    /// limits; an output that then could not brake in time is moved toward braking.
    fn limit_acceleration(&self, t: &mut Tick<'_>, target: [f64; MAX_JOINTS]) -> [f64; MAX_JOINTS] {
        let n = t.n;
        let mut out = target;
        if limit_change(
            &t.report.base_rad_s[..n],
            &mut out[..n],
            &self.amax[..n],
            self.dt,
        ) {
            t.flags |= safe_flags::ACCEL_LIMITED;
        }
        if t.q_ok {
            self.brake_in_time(t, &mut out);
        }
        out
    }

    /// The acceleration limit may have left the output between the arm's velocity and the
    /// target, in a direction that cannot brake in time (a joint or the tool braked only at
    /// the pace of the slowest joint of the change). Then this moves it toward braking the
    /// arm's velocity along its own direction, which can, if the arm could last tick: both
    /// are within the acceleration limits, and so is the segment.
    fn brake_in_time(&self, t: &mut Tick<'_>, out: &mut [f64; MAX_JOINTS]) {
        let n = t.n;
        let state = t.state;
        let q = &state.q_rad[..n];
        let (tool, arm_ok, base) = (t.tool, t.arm_ok, t.report.base_rad_s);
        let fits = |v: &[f64]| {
            (
                self.position_brake(q, v) >= 1.0 - BRAKE_TOLERANCE,
                self.workspace_brake(tool.as_ref(), v) >= 1.0 - BRAKE_TOLERANCE,
                !arm_ok || self.clearance_brake(v) >= 1.0 - BRAKE_TOLERANCE,
            )
        };
        let (pos_ok, ws_ok, clear_ok) = fits(&out[..n]);
        if pos_ok && ws_ok && clear_ok {
            return;
        }
        for (ok, flag) in [
            (pos_ok, safe_flags::POSITION_LIMITED),
            (ws_ok, safe_flags::WORKSPACE_LIMITED),
            (clear_ok, safe_flags::CLEARANCE_LIMITED),
        ] {
            if !ok {
                t.flags |= flag;
            }
        }
        let c = (1.0 - rules::brake_rate(&base[..n], &self.amax[..n]) * self.dt).max(0.0);
        let mut brake = [0.0; MAX_JOINTS];
        for (b, v) in brake.iter_mut().zip(&base).take(n) {
            *b = v * c;
        }
        let limited = *out;
        let at = |lambda: f64| {
            let mut v = [0.0; MAX_JOINTS];
            for j in 0..n {
                v[j] = brake[j] + lambda * (limited[j] - brake[j]);
            }
            v
        };
        let (mut lo, mut hi) = (0.0, 1.0);
        for _ in 0..BRAKE_BISECTIONS {
            let mid = 0.5 * (lo + hi);
            let (p, w, c) = fits(&at(mid)[..n]);
            if p && w && c {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        *out = at(lo);
        t.report.toward_braking = Some(lo);
    }

    /// Step 6: the hard guarantees over the acceleration limit (joint margins, workspace,
    /// speed caps, clearance at the next tick), then the velocity limits against rounding.
    fn hard_guarantees(&mut self, t: &mut Tick<'_>, out: &mut [f64; MAX_JOINTS]) {
        let n = t.n;
        let v = &mut out[..n];
        if t.q_ok {
            let k = rules::position_scale(
                &t.state.q_rad[..n],
                v,
                &self.lower[..n],
                &self.upper[..n],
                &self.amax[..n],
                f64::INFINITY,
                self.dt,
                true,
            );
            t.scale(Scaling::HardPosition, v, k);
        }
        if let Some((p, jv)) = t.tool {
            let tool_v = rules::tcp_velocity(&jv, v);
            let k = self
                .bounds
                .scale(&p, &tool_v, 1.0, f64::INFINITY, self.dt, true);
            t.scale(Scaling::HardWorkspace, v, k);
        }
        if let Some(arm) = self.arm.as_mut().filter(|_| t.arm_ok) {
            let k = Self::speed_cap(arm, &self.cfg, v);
            t.scale(Scaling::HardSpeed, v, k);
            let stop = self.cfg.stop_distance_m;
            let k = clearance::clearance_scale(
                arm.near(),
                v,
                stop + clearance::CLEARANCE_SLACK_M,
                f64::INFINITY,
                self.dt,
                true,
            );
            // Then the exact distances at the next tick's pose (scales `v` itself): the
            // first-order rule sees each pair's nearest feature only.
            t.scale(Scaling::HardClearance, v, k);
            if arm.verify(v, stop, self.dt) < 1.0 {
                t.mark(Scaling::HardClearance, 1.0);
            }
        }
        // Every step above only scales or interpolates within the limits; this keeps the
        // rounding of those products within them too.
        for (x, l) in v.iter_mut().zip(&self.vmax) {
            *x = x.clamp(-l, *l);
        }
    }

    /// Counts the rules that acted, remembers this tick's output, and builds the command.
    fn finish(
        &mut self,
        cmd: &MapperCommand,
        t: Tick<'_>,
        control: u32,
        out: [f64; MAX_JOINTS],
    ) -> SafeCommand {
        let n = t.n;
        let mut flags = t.flags;
        if t.stop {
            flags |= safe_flags::STOP;
        }
        let gripper = if t.stop {
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
        self.report = t.report;
        let (clearance_m, closest_pair, tcp_speed_m_s) =
            match self.arm.as_ref().filter(|_| t.arm_ok) {
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

/// The command [`SafetyFilter::step_unanswered`] stands in for the one that did not come for
/// `state`'s tick: of mapper `mapper_id`, asking for nothing (zero velocity, no operator
/// input), at no time (`t_ns` 0).
pub fn unanswered_command(mapper_id: u32, state: &RobotState) -> MapperCommand {
    MapperCommand {
        tick: state.tick,
        t_ns: 0,
        state_t_ns: state.t_ns,
        state_rx_ns: 0,
        joystick_t_ns: 0,
        joystick_rx_ns: 0,
        joystick_seq: 0,
        compute_ns: 0,
        mapper_id,
        n_joints: state.n_joints,
        flags: mapper_flags::NO_INPUT,
        buttons: 0,
        action: [0.0; 2],
        qdot_rad_s: [0.0; MAX_JOINTS],
        gripper_rate: 0.0,
    }
}

/// What the phases of one [`SafetyFilter::step`] hand on to each other.
struct Tick<'s> {
    /// The robot state of the tick.
    state: &'s RobotState,
    /// The joints the filter handles.
    n: usize,
    /// The rules that acted so far ([`safe_flags`]).
    flags: u32,
    /// A fault (or restart prevention, a deadman, the e-stop) stops the arm: the target is
    /// zero.
    stop: bool,
    /// The state's joint angles are finite: the position, workspace and clearance rules run.
    q_ok: bool,
    /// The state's joint velocities are finite.
    qdot_ok: bool,
    /// The collision model is at this state: the whole-arm rules run.
    arm_ok: bool,
    /// The tool at this state, with the workspace rule on.
    tool: Option<Tool>,
    /// What the step reports beyond its flags.
    report: StepReport,
}

/// A rule that scales the whole command by one factor (the command keeps its direction).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scaling {
    /// Step 3: into the joint velocity limits.
    Velocity,
    /// Step 3: the Cartesian speed caps.
    SpeedCap,
    /// Step 4: braking before the joint limit margins.
    Position,
    /// Step 4: braking before the workspace bounds.
    Workspace,
    /// Step 4: slow-down and braking by clearance.
    Clearance,
    /// Step 6: no joint past its margin within the next tick.
    HardPosition,
    /// Step 6: the tool not out of the workspace within the next tick.
    HardWorkspace,
    /// Step 6: the speed caps again.
    HardSpeed,
    /// Step 6: no checked pair closer than the stop distance at the next tick.
    HardClearance,
}

impl Scaling {
    /// The bit of [`safe_flags`] the rule sets when it acts.
    fn flag(self) -> u32 {
        match self {
            Self::Velocity => safe_flags::VELOCITY_SCALED,
            Self::SpeedCap | Self::HardSpeed => safe_flags::SPEED_CAPPED,
            Self::Position | Self::HardPosition => safe_flags::POSITION_LIMITED,
            Self::Workspace | Self::HardWorkspace => safe_flags::WORKSPACE_LIMITED,
            Self::Clearance | Self::HardClearance => safe_flags::CLEARANCE_LIMITED,
        }
    }
}

impl Tick<'_> {
    /// `rule` acted with factor `k`: its flag set, its factor (steps 3 and 4) or its hard
    /// guarantee (step 6) reported.
    fn mark(&mut self, rule: Scaling, k: f64) {
        self.flags |= rule.flag();
        let r = &mut self.report;
        match rule {
            Scaling::Velocity => r.scales.velocity = k,
            Scaling::SpeedCap => r.scales.speed_cap = k,
            Scaling::Position => r.scales.position = k,
            Scaling::Workspace => r.scales.workspace = k,
            Scaling::Clearance => r.scales.clearance = k,
            Scaling::HardPosition => r.hard_position = true,
            Scaling::HardWorkspace => r.hard_workspace = true,
            Scaling::HardSpeed => r.hard_speed = true,
            Scaling::HardClearance => r.hard_clearance = true,
        }
    }

    /// Scales the whole command `v` by `k` if `k < 1` and marks `rule` ([`Tick::mark`]);
    /// returns whether it did.
    fn scale(&mut self, rule: Scaling, v: &mut [f64], k: f64) -> bool {
        if k < 1.0 {
            v.iter_mut().for_each(|x| *x *= k);
            self.mark(rule, k);
        }
        k < 1.0
    }
}
