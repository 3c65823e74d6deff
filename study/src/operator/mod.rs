//! The simulated participants' operators, one interface ([`Operate`]) chosen in the study
//! file's `[simulation] operator` ([`OperatorKind`]), the same for every condition:
//!
//! * [`OperatorKind::Greedy`] ([`greedy`]): each tick the stick input whose tool pose one tick
//!   ahead through the served map is closest to the subgoal; the lower bound.
//! * [`OperatorKind::Expert`] ([`expert`]): plans stick sequences of about 1.5 s with the served
//!   map itself as its forward model, mode presses included, re-planned each tick: what the
//!   map allows at best ("can this map do the task at all?").
//!
//! Every operator sees what a person sees ([`Seen`]: the tool's pose, the gripper, the map's
//! mode, the task's scene and next subgoal) and acts through the same hand (`Hand`: a
//! reaction delay, a bounded stick rate, input noise).
//! * [`OperatorKind::Practiced`] ([`practiced`]): a person after the practice phase: learns an
//!   internal model of the map from what it saw in the study's practice time
//!   ([`internal::InternalModel`]), then plans like the expert with that model, never with the
//!   map.
//! * [`OperatorKind::Follower`] ([`follower`]): follows the nearest demonstration by the tool,
//!   reproducing its motion through the served map: the map's limit along the route its
//!   demonstrations took, apart from any planner's.

pub mod expert;
pub mod follower;
pub mod greedy;
pub mod internal;
pub mod practiced;

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use ipc_types::{JoystickInput, RobotState, buttons};
use kinematics::{Jacobian, RobotProfile};
use learning::goals::{Aim, GoalRun, Tolerances};
use mapper::rng::Rng;
use nalgebra::{Isometry3, Vector6};

pub use crate::setup::OperatorKind;
use crate::setup::{ModelFactory, SimError, SimParams};

/// What the operator sees at one tick: what the experimenter's screen and the scene show a
/// person, never the map's internals.
#[derive(Debug, Clone, Copy)]
pub struct Seen<'a> {
    /// The robot state (joint angles, the gripper).
    pub state: &'a RobotState,
    /// The tool's pose.
    pub tool: &'a Isometry3<f64>,
    /// The arm's Jacobian at the state (the greedy operator's one-tick prediction).
    pub jac: &'a Jacobian,
    /// What the next subgoal asks for (`None` once every subgoal is done).
    pub aim: Option<Aim>,
    /// The task's progress and scene (the objects on the table, the subgoals to come).
    pub run: &'a GoalRun,
    /// The map's mode as the screen shows it (0 the first), for maps that have modes.
    pub mode: Option<usize>,
    /// The sample's time (ns).
    pub t_ns: u64,
}

/// A test's arm at rest at some joint angles at the start of a task: what an operator sees
/// there ([`AtRest::seen`]).
#[cfg(test)]
pub(crate) struct AtRest {
    pub(crate) state: RobotState,
    pub(crate) tool: Isometry3<f64>,
    pub(crate) jac: Jacobian,
    pub(crate) run: GoalRun,
}

#[cfg(test)]
impl AtRest {
    /// `robot`'s arm at rest at `q` (its first joints; the rest zero), at the start of `task`.
    pub(crate) fn new(robot: &RobotProfile, task: learning::tasks::Task, q: &[f64]) -> Self {
        let n = robot.n_joints();
        let mut state = RobotState::at_rest(0, 0, n as u32);
        state.q_rad[..q.len()].copy_from_slice(q);
        let mut jac = Jacobian::zeros(n);
        let tool = robot
            .arm()
            .fk_jacobian(&state.q_rad[..n], &mut jac)
            .expect("fk");
        let goals = learning::goals::TaskGoals::of(task, Tolerances::default()).expect("goals");
        Self {
            state,
            tool,
            jac,
            run: GoalRun::new(&goals),
        }
    }

    /// What the operator sees, the map in `mode`, with no aim.
    pub(crate) fn seen(&self, mode: Option<usize>) -> Seen<'_> {
        Seen {
            state: &self.state,
            tool: &self.tool,
            jac: &self.jac,
            aim: None,
            run: &self.run,
            mode,
            t_ns: 0,
        }
    }
}

/// A simulated operator: answers each robot state with a joystick sample.
pub trait Operate {
    /// This tick's joystick sample; `rng` is the attempt's random stream. Only the operators
    /// that evaluate the served map hold its factory (given to [`operator`]); the practiced
    /// operator and the practice explorer are built without one, so they cannot.
    fn act(&mut self, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput;
    /// Mode presses so far.
    fn presses(&self) -> u32;
    /// It has done what it set out to do before the time ran out (trying the stick in
    /// practice); a task attempt ends with the task.
    fn finished(&self) -> bool {
        false
    }
    /// What it learned of the map (the operators that learn).
    fn into_learned(self: Box<Self>) -> Option<internal::InternalModel> {
        None
    }
    /// How far it got along its demonstration (the follower).
    fn followed(&self) -> Option<follower::Followed> {
        None
    }
}

/// The demonstrations a follower reproduces: their paths, and which one (a demonstration's
/// own start and scene) or the nearest.
#[derive(Debug, Clone)]
pub struct Demos {
    /// The paths.
    pub paths: Arc<Vec<follower::DemoPath>>,
    /// Only this one; else the nearest to the tool.
    pub only: Option<usize>,
}

/// The operator of one attempt of kind `params.operator` on `robot` (`safety`: the graph's
/// safety configuration, whose whole-arm stop the expert foresees). `aim_out` is the attempt's
/// [`AttemptSetup::aim_out`](crate::simulate::AttemptSetup::aim_out): a scripted map that
/// moves straight to the operator's aim reads it, so the expert writes its predicted aims
/// there while it predicts (and puts back what it found). `learned`: what the practiced
/// operator learned in practice (it is refused without).
#[allow(clippy::too_many_arguments)]
pub fn operator<'a>(
    params: &SimParams,
    robot: &'static RobotProfile,
    safety: &safety::SafetyConfig,
    tol: Tolerances,
    dt: f64,
    make: &'a ModelFactory<'a>,
    aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
    learned: Option<&internal::InternalModel>,
    demos: Option<&Demos>,
) -> Result<Box<dyn Operate + 'a>, SimError> {
    Ok(match params.operator {
        OperatorKind::Greedy => Box::new(greedy::Greedy::new(
            params,
            tol,
            dt,
            greedy::Probes::new(make)?,
        )),
        OperatorKind::Expert => Box::new(expert::Expert::new(
            params,
            robot,
            safety,
            tol,
            dt,
            make,
            aim_out,
            demos.map(expert::Route::of),
        )?),
        OperatorKind::Follower => {
            let demos = demos.ok_or_else(|| {
                SimError::Setup("the follower has no demonstrations to follow".into())
            })?;
            Box::new(follower::Follower::new(
                params,
                tol,
                dt,
                greedy::Probes::new(make)?,
                demos.paths.clone(),
                demos.only,
            ))
        }
        OperatorKind::Practiced => {
            let model = learned.ok_or_else(|| {
                SimError::Setup("the practiced operator has not practised this map".into())
            })?;
            Box::new(expert::Expert::practiced(
                params,
                robot,
                safety,
                tol,
                dt,
                expert::Learner::new(model.clone(), true, dt),
            ))
        }
    })
}

/// The stick inputs a one-tick operator weighs: rest, what it chose last, and `n` drawn
/// uniformly over the stick's disc (into `out`, emptied first).
pub(crate) fn draw_candidates(out: &mut Vec<[f64; 2]>, chosen: [f64; 2], n: usize, rng: &mut Rng) {
    out.clear();
    out.push([0.0; 2]);
    out.push(chosen);
    for _ in 0..n {
        let r = rng.uniform().sqrt();
        let th = rng.range(0.0, std::f64::consts::TAU);
        out.push([r * th.cos(), r * th.sin()]);
    }
}

/// The tool's twist (linear, then angular, in the base frame) of the joint velocities
/// `qdot * scale` at the Jacobian `jac`: a map's output through the arm. A joint the map gave
/// no finite velocity contributes nothing.
pub(crate) fn tool_twist(jac: &Jacobian, qdot: &[f64], scale: f64) -> Vector6<f64> {
    let jm = jac.matrix();
    let mut v = Vector6::zeros();
    for (j, qd) in qdot.iter().enumerate() {
        if qd.is_finite() {
            v += jm.column(j) * (qd * scale);
        }
    }
    v
}

/// The mode button as a person presses it: to switch modes, one press (a tick down, a tick
/// up) until the wanted mode comes round, then a rest with the stick let go; the presses
/// are counted for the attempt's figures.
#[derive(Debug, Default)]
pub(crate) struct ModeButton {
    presses_left: u32,
    rest_ticks: u32,
    down: bool,
    presses: u32,
}

impl ModeButton {
    /// Starts a switch from mode `from` to mode `to` of `modes` (the button steps forward),
    /// then `rest_s` of rest at ticks of `dt`.
    pub(crate) fn switch(&mut self, from: usize, to: usize, modes: usize, rest_s: f64, dt: f64) {
        self.presses_left = ((to + modes - from) % modes) as u32;
        self.rest_ticks = (rest_s / dt).round() as u32;
    }

    /// This tick's part of a switch under way: `Some(buttons)` (the mode bit at a press) while
    /// the switch lasts, `None` once the operator is free to steer.
    pub(crate) fn tick(&mut self) -> Option<u32> {
        if self.down {
            self.down = false;
            Some(0)
        } else if self.presses_left > 0 {
            self.presses_left -= 1;
            self.presses += 1;
            self.down = true;
            Some(buttons::MODE)
        } else if self.rest_ticks > 0 {
            self.rest_ticks -= 1;
            Some(0)
        } else {
            None
        }
    }

    /// A switch is under way (the stick is let go).
    pub(crate) fn busy(&self) -> bool {
        self.presses_left > 0 || self.down || self.rest_ticks > 0
    }

    /// Presses so far.
    pub(crate) fn presses(&self) -> u32 {
        self.presses
    }
}

/// The hand between what the operator chose and the stick: a reaction delay (the stick
/// carries out what was chosen that long ago), a bounded rate of change of the stick,
/// Gaussian noise on each axis.
pub(crate) struct Hand {
    delay: VecDeque<[f64; 2]>,
    /// The stick's position (before the noise).
    pub(crate) stick: [f64; 2],
    seq: u64,
}

impl Hand {
    pub(crate) fn new(params: &SimParams, dt: f64) -> Self {
        let delay_ticks = (params.reaction_delay_s / dt).round() as usize;
        Self {
            delay: std::iter::repeat_n([0.0; 2], delay_ticks).collect(),
            stick: [0.0; 2],
            seq: 0,
        }
    }

    /// What was chosen and is still to be carried out, oldest first.
    pub(crate) fn pending(&self) -> impl ExactSizeIterator<Item = &[f64; 2]> {
        self.delay.iter()
    }

    /// Lets go of the stick (a mode press): nothing chosen is carried out.
    pub(crate) fn let_go(&mut self) {
        self.delay.iter_mut().for_each(|d| *d = [0.0; 2]);
        self.stick = [0.0; 2];
    }

    /// The sample that carries out `choice` (after the delay); `resting`: the stick is let
    /// go (around a mode press).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn sample(
        &mut self,
        params: &SimParams,
        dt: f64,
        choice: [f64; 2],
        resting: bool,
        state: &RobotState,
        t_ns: u64,
        gripper: f32,
        buttons: u32,
        rng: &mut Rng,
    ) -> JoystickInput {
        self.delay.push_back(choice);
        let intended = self.delay.pop_front().unwrap_or([0.0; 2]);
        let intended = if resting { [0.0; 2] } else { intended };
        let step = params.stick_rate_per_s * dt;
        let d = [intended[0] - self.stick[0], intended[1] - self.stick[1]];
        let dn = d[0].hypot(d[1]);
        let k = if dn > step { step / dn } else { 1.0 };
        self.stick = [self.stick[0] + d[0] * k, self.stick[1] + d[1] * k];
        let mut a = self.stick;
        if !resting && params.input_noise > 0.0 {
            a[0] += params.input_noise * rng.normal();
            a[1] += params.input_noise * rng.normal();
        }
        let an = a[0].hypot(a[1]);
        if an > 1.0 {
            a = [a[0] / an, a[1] / an];
        }
        self.seq += 1;
        JoystickInput {
            tick: state.tick,
            t_ns,
            seq: self.seq,
            axes: [a[0] as f32, a[1] as f32],
            gripper,
            buttons,
        }
    }
}
