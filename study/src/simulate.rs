//! Simulated participants (`scl study simulate`): the study's protocol run without people,
//! through the same step functions as the live graph (the served map in
//! [`mapper::step::MapperStep`], the [`safety::SafetyFilter`] of the graph, the mock arm),
//! faster than real time and deterministic for a seed.
//!
//! The simulated operator sees what a person sees: the tool's pose, the gripper, the map's
//! mode (the screen shows it) and the next subgoal ([`learning::goals`]); not the map's
//! internals. Which operator runs is the study file's `[simulation] operator`
//! ([`crate::operator`]): the greedy one (one tick ahead, the lower bound), the practiced one
//! (learns the map in the practice time from what it sees, [`practice`], then plans with
//! what it learned) or the expert one (plans with the served map as its forward model: what
//! the map allows at best). All act through the same hand: a reaction delay, a bounded rate
//! of change of the stick, Gaussian input noise, time to press the mode button.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use ipc_types::{JoystickInput, MapperCommand, RobotState, SafeCommand, state_flags};
use kinematics::{Jacobian, RobotProfile};
use learning::goals::{GoalRun, Subgoal, TaskGoals};
use learning::tasks::Task as GoalTask;
use mapper::LoadedModel;
use mapper::rng::Rng;
use mapper::step::MapperStep;
use nalgebra::Vector6;

use crate::operator::expert::{Expert, Learner};
use crate::operator::internal::{InternalModel, Widths};
use crate::operator::practiced::Explorer;
use crate::operator::{Demos, Operate, Seen, operator};
pub use crate::setup::{ModelFactory, OperatorKind, SimError, SimParams};

use crate::data::{Appender, Outcome, STUDY_COPY, TRIALS, TrialRow};
use crate::diagnose::Diagnoser;
pub use crate::diagnose::{Diagnosis, TickNote};
use crate::plan::{StartPose, Study};
use crate::{Participant, StudyError};

/// The closed loop a simulated attempt runs in.
#[derive(Debug, Clone)]
pub struct Loop {
    /// The robot.
    pub robot: &'static RobotProfile,
    /// The graph's safety configuration.
    pub safety: safety::SafetyConfig,
    /// The control period (s).
    pub period_s: f64,
}

/// How one simulated attempt ended.
#[derive(Debug, Clone, PartialEq)]
pub struct AttemptResult {
    /// Success (every subgoal in time) or timeout.
    pub outcome: Outcome,
    /// Subgoals done (%).
    pub completion_pct: f64,
    /// Time to the success, else the time limit (s).
    pub duration_s: f64,
    /// Mode presses.
    pub mode_switches: u32,
    /// Why it ended where it did ([`run_attempt`] gives it; the live graph's runner does not).
    pub diagnosis: Option<Diagnosis>,
    /// The attempt's recording, relative to the participant's directory (`--record`).
    pub recording: Option<String>,
}

/// What one attempt needs.
pub struct AttemptSetup<'a> {
    /// The closed loop.
    pub sim: &'a Loop,
    /// The start pose (rad).
    pub start_q: &'a [f64],
    /// The task's goals.
    pub goals: &'a TaskGoals,
    /// The time limit (s).
    pub time_limit_s: f64,
    /// The operator.
    pub params: &'a SimParams,
    /// Fresh instances of the condition's model.
    pub model: &'a ModelFactory<'a>,
    /// The random stream's seed.
    pub seed: u64,
    /// For scripted maps that move straight to the goal: each tick the pose error to the
    /// operator's current aim ([`learning::goals::Aim::error`]) is written here before the map is evaluated.
    pub aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
    /// What the practiced operator learned in practice with this map ([`practice`]).
    pub learned: Option<&'a InternalModel>,
    /// The demonstrations the follower reproduces.
    pub demos: Option<&'a Demos>,
}

/// What the operator does with a robot state ([`AttemptDriver::on_state`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    /// The attempt goes on: publish this joystick sample (the graph applies it at the next
    /// tick).
    Sample(JoystickInput),
    /// The attempt is over.
    Done(AttemptResult),
}

/// One simulated attempt from the operator's side, whatever closes the loop: it takes each
/// robot state and answers with the next joystick sample or the attempt's end. The in-process
/// loop ([`run_attempt`]) and the live graph (`scl study simulate --live`) both drive it, so
/// the operator, the goals and the clock are the same code in both.
///
/// The attempt's clock is the state's tick counted from the first state it was given: a
/// state the live loop could not answer in time still counts its tick.
pub struct AttemptDriver<'a> {
    robot: &'static RobotProfile,
    dt: f64,
    ticks: u64,
    time_limit_s: f64,
    aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
    op: Box<dyn Operate + 'a>,
    run: GoalRun,
    rng: Rng,
    jac: Jacobian,
    first_tick: Option<u64>,
    last_k: u64,
    note: TickNote,
}

impl<'a> AttemptDriver<'a> {
    /// The operator of attempt `s`, before its first state.
    pub fn new(s: &AttemptSetup<'a>) -> Result<Self, SimError> {
        let op = operator(
            s.params,
            s.sim.robot,
            &s.sim.safety,
            s.goals.tol,
            s.sim.period_s,
            s.model,
            s.aim_out.clone(),
            s.learned,
            s.demos,
        )?;
        Ok(Self::with_operator(s, op))
    }

    /// Attempt `s` with the operator `op`.
    fn with_operator(s: &AttemptSetup<'a>, op: Box<dyn Operate + 'a>) -> Self {
        let dt = s.sim.period_s;
        Self {
            robot: s.sim.robot,
            dt,
            ticks: (s.time_limit_s / dt).ceil() as u64,
            time_limit_s: s.time_limit_s,
            aim_out: s.aim_out.clone(),
            op,
            run: GoalRun::new(s.goals),
            rng: Rng::new(s.seed),
            jac: Jacobian::zeros(s.sim.robot.n_joints()),
            first_tick: None,
            last_k: 0,
            note: TickNote::default(),
        }
    }

    /// The operator's answer to `state`. `mode` is the map's mode as the screen shows it (the
    /// mapper's heartbeat of the previous tick: 0 the first mode), `t_ns` the sample's time.
    pub fn on_state(
        &mut self,
        state: &RobotState,
        mode: Option<usize>,
        t_ns: u64,
    ) -> Result<Answer, SimError> {
        let first = *self.first_tick.get_or_insert(state.tick);
        let k = state.tick.saturating_sub(first);
        let tool = self
            .robot
            .arm()
            .fk_jacobian(state.q(), &mut self.jac)
            .map_err(|e| SimError::Setup(format!("forward kinematics: {e}")))?;
        let elapsed = (k - self.last_k.min(k)) as f64 * self.dt;
        self.last_k = k;
        self.run.update(&tool, state.gripper, elapsed);
        self.note = TickNote {
            tick: k,
            t_ns: state.t_ns,
            subgoals_done: self.run.subgoals_done(),
            subgoal: self.run.current().map(Subgoal::name),
            tool: tool.translation.vector.into(),
            mode,
            ..TickNote::default()
        };
        if self.run.done() {
            return Ok(Answer::Done(AttemptResult {
                outcome: Outcome::Success,
                completion_pct: 100.0,
                duration_s: k as f64 * self.dt,
                mode_switches: self.op.presses(),
                diagnosis: None,
                recording: None,
            }));
        }
        if k >= self.ticks || self.op.finished() {
            return Ok(Answer::Done(AttemptResult {
                outcome: Outcome::Timeout,
                completion_pct: self.run.completion_pct(),
                duration_s: if self.op.finished() {
                    k as f64 * self.dt
                } else {
                    self.time_limit_s
                },
                mode_switches: self.op.presses(),
                diagnosis: None,
                recording: None,
            }));
        }
        let aim = self
            .run
            .aim(&tool, state.q().last().copied().unwrap_or(0.0));
        if let (Some(cell), Some(a)) = (&self.aim_out, &aim)
            && let Ok(mut e) = cell.lock()
        {
            *e = a.error(&tool);
        }
        if let Some(a) = &aim {
            self.note.distance_m = Some(a.distance(&tool.translation.vector));
            self.note.aim = Some(a.position.into());
            self.note.facing_error_rad = a.face.then(|| a.facing_error(&tool.rotation));
        }
        let seen = Seen {
            state,
            tool: &tool,
            jac: &self.jac,
            aim,
            run: &self.run,
            mode,
            t_ns,
        };
        let joy = self.op.act(&seen, &mut self.rng);
        tracing::trace!(
            tick = k,
            tool = ?tool.translation.vector.as_slice(),
            tilt = learning::goals::tilt(&tool.rotation),
            q = ?state.q(),
            aim = ?aim.map(|a| a.position),
            axes = ?joy.axes,
            gripper = state.gripper,
            subgoal = ?self.run.current().map(Subgoal::name),
            mode = ?mode,
            buttons = joy.buttons,
            "simulated operator"
        );
        Ok(Answer::Sample(joy))
    }

    /// What the tracker and the operator saw at the last state given.
    pub fn note(&self) -> &TickNote {
        &self.note
    }
}

/// One tick of an in-process attempt as the graph would publish it, for a recording
/// ([`run_attempt_observed`]).
#[derive(Debug, Clone, Copy)]
pub struct Observed<'a> {
    /// The robot state of the tick.
    pub state: &'a RobotState,
    /// The operator's answer to it (the mapper uses it at the next tick).
    pub sample: &'a JoystickInput,
    /// The mapper's command of the tick.
    pub mapper: &'a MapperCommand,
    /// Safety's command of the tick.
    pub safe: &'a SafeCommand,
    /// The map's mode after the tick's step, as the mapper's heartbeat carries it
    /// ([`ipc_types::NodeStatus::mode`]: 0 for a map without modes, 1 + the mode's index).
    pub mode: u32,
    /// The map's mode switches so far ([`ipc_types::NodeStatus::mode_switches`]).
    pub mode_switches: u32,
    /// What the tracker and the operator saw.
    pub note: &'a TickNote,
}

/// Takes each tick of an in-process attempt (`scl study simulate --record` writes them).
pub trait Observe {
    /// One tick; an error ends the attempt.
    fn tick(&mut self, t: &Observed<'_>) -> Result<(), SimError>;
}

/// Runs one attempt from the start pose until every subgoal is done or the time runs out, in
/// process on simulated time: the graph's pipeline tick by tick. The robot state of tick `k`
/// goes to the operator and to the mapper; the mapper maps the newest sample it has, the one
/// the operator gave for tick `k - 1` (the live graph's mapper has computed tick `k` before
/// the operator's answer to it arrives); safety filters; the mock arm executes.
pub fn run_attempt(s: &AttemptSetup<'_>) -> Result<AttemptResult, SimError> {
    run_driver(s, AttemptDriver::new(s)?, None).map(|(r, _)| r)
}

/// [`run_attempt`], each tick given to `obs` as it is published.
pub fn run_attempt_observed(
    s: &AttemptSetup<'_>,
    obs: &mut dyn Observe,
) -> Result<AttemptResult, SimError> {
    run_driver(s, AttemptDriver::new(s)?, Some(obs)).map(|(r, _)| r)
}

/// [`run_attempt`], and how far a follower got along its demonstration.
pub fn run_attempt_followed(
    s: &AttemptSetup<'_>,
) -> Result<(AttemptResult, Option<crate::operator::follower::Followed>), SimError> {
    run_driver(s, AttemptDriver::new(s)?, None).map(|(r, op)| (r, op.followed()))
}

/// [`run_attempt`] with the operator of `driver`, each tick to `obs`; gives the operator back.
/// The result carries its [`Diagnosis`] (the map's directions only for a failed attempt).
fn run_driver<'a>(
    s: &AttemptSetup<'_>,
    mut driver: AttemptDriver<'a>,
    mut obs: Option<&mut dyn Observe>,
) -> Result<(AttemptResult, Box<dyn Operate + 'a>), SimError> {
    let robot = s.sim.robot;
    let n = robot.n_joints();
    let dt = s.sim.period_s;
    let period_ns = (dt * 1e9).round() as u64;
    let served = (s.model)()?;
    // As the mapper process serves it: continuous joints wrapped for the map.
    let mut step = MapperStep::for_robot(0, served, robot).map_err(|source| SimError::Model {
        spec: "the served model".into(),
        source,
    })?;
    let mut filter = safety::SafetyFilter::for_graph(s.sim.safety.clone(), robot, dt)
        .map_err(|e| SimError::Setup(format!("the safety filter: {e}")))?;
    let mut arm =
        hw_bridge::mock::MockArm::for_robot(robot, hw_bridge::mock::MockConfig::for_robot(robot))
            .map_err(|e| SimError::Setup(format!("the mock arm: {e}")))?;
    arm.resume(s.start_q, 0.0);
    let mut state = RobotState::at_rest(0, period_ns, n as u32);
    state.q_rad[..n].copy_from_slice(&s.start_q[..n.min(s.start_q.len())]);
    state.flags = state_flags::MOCK;
    let mut newest: Option<JoystickInput> = None;
    let mut diag = Diagnoser::default();
    let mut k = 0u64;
    loop {
        let t_ns = (k + 1) * period_ns;
        state.tick = k;
        state.t_ns = t_ns;
        // The screen shows the mode of the mapper's last heartbeat: after tick k - 1.
        let mode = step.mode().map(|m| m.index as usize);
        let joy = match driver.on_state(&state, mode, t_ns)? {
            Answer::Done(mut r) => {
                let map = if r.outcome == Outcome::Success {
                    None
                } else {
                    (s.model)().ok()
                };
                r.diagnosis = Some(diag.finish(robot, dt, map));
                return Ok((r, driver.op));
            }
            Answer::Sample(j) => j,
        };
        let mut cmd = step.step(&state, newest.as_ref());
        newest = Some(joy);
        cmd.t_ns = t_ns;
        let mut safe = filter.step(&cmd, &state, t_ns);
        safe.t_ns = t_ns;
        tracing::trace!(tick = k, safety_flags = safe.flags, "simulated tick");
        diag.tick(driver.note(), &state, safe.flags);
        if let Some(o) = obs.as_deref_mut() {
            let mode = step.mode();
            o.tick(&Observed {
                state: &state,
                sample: &joy,
                mapper: &cmd,
                safe: &safe,
                mode: mode.map_or(0, |m| m.index + 1),
                mode_switches: mode.map_or(0, |m| m.switches),
                note: driver.note(),
            })?;
        }
        arm.set_command(&safe.qdot_rad_s[..n], safe.gripper_rate);
        let r = arm.step(dt);
        state.q_rad = r.q_rad;
        state.qdot_rad_s = r.qdot_rad_s;
        state.gripper = r.gripper;
        state.applied_tick = k;
        k += 1;
    }
}

/// The practiced operator's practice with the map of `s` for `practice_s` (the task's
/// practice time), in process on simulated time, from the task's start pose as the study
/// does: first trying the stick in each mode (`operator::practiced::Explorer`), then attempts of the task
/// (each to the task's time limit or its end) planned with what it has learned so far, learning
/// on. Returns what it learned. `s.seed` seeds each part's own stream.
pub fn practice(s: &AttemptSetup<'_>, practice_s: f64) -> Result<InternalModel, SimError> {
    let dt = s.sim.period_s;
    let mut model = InternalModel::new(Widths::of(&s.params.practiced));
    let mut used = 0.0;
    let mut round = 0u64;
    while used + dt < practice_s {
        let left = practice_s - used;
        let limit = left.min(s.time_limit_s);
        let part = AttemptSetup {
            sim: s.sim,
            start_q: s.start_q,
            goals: s.goals,
            time_limit_s: limit,
            params: s.params,
            model: s.model,
            seed: attempt_seed(s.seed, &[round]),
            aim_out: s.aim_out.clone(),
            learned: None,
            demos: None,
        };
        let op: Box<dyn Operate> = if round == 0 {
            Box::new(Explorer::new(s.params, dt, model))
        } else {
            Box::new(Expert::practiced(
                s.params,
                s.sim.robot,
                &s.sim.safety,
                s.goals.tol,
                dt,
                Learner::new(model, true, dt),
            ))
        };
        let (r, op) = run_driver(&part, AttemptDriver::with_operator(&part, op), None)?;
        model = op
            .into_learned()
            .ok_or_else(|| SimError::Setup("practice: the operator learned nothing".into()))?;
        tracing::debug!(
            round,
            outcome = ?r.outcome,
            duration_s = r.duration_s,
            observations = model.observations(),
            modes = model.modes(),
            general = ?(0..model.modes()).map(|m| model.general(m)).collect::<Vec<_>>(),
            "practice"
        );
        used += r.duration_s.max(dt);
        round += 1;
    }
    Ok(model)
}

/// A seed for one attempt, from the study's seed and where the attempt is in the plan (the
/// same attempt gets the same stream whatever else runs).
pub fn attempt_seed(seed: u64, parts: &[u64]) -> u64 {
    let mut h = seed ^ 0x9e37_79b9_7f4a_7c15;
    for &p in parts {
        h ^= p.wrapping_add(0x9e37_79b9_7f4a_7c15);
        h = h.wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h ^= h >> 31;
        h = h.wrapping_mul(0x94d0_49bb_1331_11eb);
        h ^= h >> 29;
    }
    h
}

/// The goals of each task of `study` (its `goals` key, else its name, with its tolerances) on
/// `robot`'s arm, in the scene its demonstrations use ([`TaskGoals::on`]).
pub fn study_goals(study: &Study, robot: &RobotProfile) -> Result<Vec<TaskGoals>, SimError> {
    study
        .file
        .tasks
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let which = t.goals.as_deref().unwrap_or(&t.name);
            let bad = |reason: String| SimError::Goals {
                path: study.path.clone(),
                index: i,
                reason,
            };
            let task = GoalTask::from_name(which).map_err(|e| {
                bad(format!(
                    "task `{}`: {e}; set `goals` to the task it is",
                    t.name
                ))
            })?;
            TaskGoals::on(task, t.tolerances(), robot)
                .ok_or_else(|| bad(format!("`{which}` has no scene to simulate")))
        })
        .collect()
}

/// The seed of the demonstrations the shipped study models were trained on
/// (`scripts/study-models.sh`: `scl demos --task T --seed 1`), which the follower reproduces
/// in a study.
pub const DEMOS_SEED: u64 = 1;

/// The training demonstrations of a task on an arm: the generator's at the paper's counts
/// and [`DEMOS_SEED`], the ones the shipped study models learned from.
#[derive(Debug)]
pub struct TrainingDemos {
    /// Each demonstration.
    pub trajectories: Vec<learning::dataset::Trajectory>,
    /// The scene each was made in (its goals: [`TaskGoals::in_scene`]).
    pub scenes: Vec<learning::goals::Scene>,
    /// Each one's path (the forward kinematics of its ticks), as the follower and the expert's
    /// route take them.
    pub paths: Arc<Vec<crate::operator::follower::DemoPath>>,
}

/// The [`TrainingDemos`] of `task` on `robot`'s arm, made once per process (every participant
/// and check of a run shares them; the generator is deterministic, so they are the same
/// either way).
pub fn training_demos(
    task: GoalTask,
    robot: &'static RobotProfile,
) -> Result<Arc<TrainingDemos>, SimError> {
    type Made = std::collections::HashMap<(GoalTask, String), Arc<TrainingDemos>>;
    static MADE: std::sync::OnceLock<Mutex<Made>> = std::sync::OnceLock::new();
    let key = (task, robot.name().to_owned());
    let made = MADE.get_or_init(Default::default);
    if let Some(d) = made.lock().map_err(|_| poisoned())?.get(&key) {
        return Ok(d.clone());
    }
    let (n_train, _) = task.default_counts();
    let (ds, scenes) = learning::tasks::generate_scenes_for(task, robot, n_train, 0, DEMOS_SEED)
        .map_err(|e| SimError::Setup(format!("the training demonstrations: {e}")))?;
    let paths = ds
        .train
        .iter()
        .map(|t| crate::operator::follower::DemoPath::of(robot, t))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| SimError::Setup(format!("the training demonstrations: {e}")))?;
    let d = Arc::new(TrainingDemos {
        trajectories: ds.train,
        scenes,
        paths: Arc::new(paths),
    });
    made.lock().map_err(|_| poisoned())?.insert(key, d.clone());
    Ok(d)
}

fn poisoned() -> SimError {
    SimError::Setup("the training demonstrations' store was poisoned by a panic".into())
}

/// The training demonstrations of `task` on `robot`'s arm that a follower reproduces in a
/// study (the nearest to the tool), and whose paths are the expert's route
/// ([`training_demos`]).
pub fn task_demos(task: GoalTask, robot: &'static RobotProfile) -> Result<Demos, SimError> {
    Ok(Demos {
        paths: training_demos(task, robot)?.paths.clone(),
        only: None,
    })
}

/// The start pose of a task as joint angles.
pub fn start_q(robot: &RobotProfile, start: &StartPose) -> Option<Vec<f64>> {
    match start {
        StartPose::Named(name) => robot.named_pose(name).map(<[f64]>::to_vec),
        StartPose::Joints(q) => Some(q.clone()),
    }
}

/// Which attempt of the plan a runner is given ([`simulate_participant_with`]).
#[derive(Debug, Clone)]
pub struct AttemptInfo<'a> {
    /// The condition's model spec for this task (what the graph serves).
    pub spec: &'a str,
    /// A name for its files: `P01-t1-c2-a1` (participant, task, condition, attempt; 1-based).
    pub name: String,
    /// The study task's name (`[[tasks]] name`).
    pub task: &'a str,
    /// Which of the paper's tasks its goals are (`[[tasks]] goals`, else its name).
    pub goals: &'a str,
}

/// Part of a study's protocol to simulate (`scl study simulate --task --condition`): all of
/// it by default. The order and Latin-square positions stay those of the whole plan.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Selection {
    /// Only the task of this name.
    pub task: Option<String>,
    /// Only the condition of this label (or name).
    pub condition: Option<String>,
}

impl Selection {
    /// Checks that the names are the study's; the error lists what there is.
    pub fn check(&self, study: &Study) -> Result<(), StudyError> {
        let f = &study.file;
        if let Some(t) = &self.task
            && !f.tasks.iter().any(|x| &x.name == t)
        {
            return Err(StudyError::Invalid {
                path: study.path.clone(),
                key: "--task".into(),
                reason: format!(
                    "`{t}` is not a task of the study; its tasks: {}",
                    f.tasks
                        .iter()
                        .map(|x| x.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        if let Some(c) = &self.condition
            && !f.conditions.iter().any(|x| &x.label == c || &x.name == c)
        {
            return Err(StudyError::Invalid {
                path: study.path.clone(),
                key: "--condition".into(),
                reason: format!(
                    "`{c}` is not a condition of the study; its labels: {}",
                    f.conditions
                        .iter()
                        .map(|x| x.label.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
        Ok(())
    }

    fn task(&self, t: &crate::plan::Task) -> bool {
        self.task.as_ref().is_none_or(|n| &t.name == n)
    }

    fn condition(&self, c: &crate::plan::Condition) -> bool {
        self.condition
            .as_ref()
            .is_none_or(|n| &c.label == n || &c.name == n)
    }

    /// How many attempts one participant makes.
    pub fn attempts(&self, study: &Study) -> u64 {
        let conditions = study
            .file
            .conditions
            .iter()
            .filter(|c| self.condition(c))
            .count();
        study
            .file
            .tasks
            .iter()
            .filter(|t| self.task(t))
            .map(|t| u64::from(t.attempts))
            .sum::<u64>()
            * conditions as u64
    }
}

/// Runs one attempt of a simulated study: in process ([`run_attempt`]) or through the live
/// graph (`scl study simulate --live`).
pub type AttemptRunner<'r> =
    dyn Fn(&AttemptSetup<'_>, &AttemptInfo<'_>) -> Result<AttemptResult, SimError> + Sync + 'r;

/// Runs participant `p`'s protocol (tasks in order, conditions in their Latin-square order,
/// every attempt; practice only for the practiced operator, before each condition's attempts) and writes `dir/trials.csv` (refusing a directory that
/// has one) and a copy of the study file. `progress` is called after each attempt; `stop`
/// before each (true: stop there, an error saying how far it got).
pub fn simulate_participant(
    study: &Study,
    sim: &Loop,
    p: Participant,
    seed: u64,
    dir: &Path,
    progress: &(dyn Fn() + Sync),
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Vec<TrialRow>, StudyError> {
    simulate_participant_with(
        study,
        sim,
        p,
        seed,
        dir,
        &Selection::default(),
        progress,
        stop,
        &|s, _| run_attempt(s),
    )
}

/// A simulated participant's files in `dir` (made if missing): the study file's copy, and
/// the trials and diagnosis files opened for appending, neither of which may exist yet
/// (simulated data is never written over). Gives the trials file's path and both appenders.
fn open_participant_files(
    study: &Study,
    dir: &Path,
) -> Result<(PathBuf, Appender, Appender), StudyError> {
    let trials = dir.join(TRIALS);
    let diagnosis = dir.join(crate::diagnose::DIAGNOSIS);
    for path in [&trials, &diagnosis] {
        if path.exists() {
            return Err(StudyError::Data {
                path: path.clone(),
                reason: "exists: simulated data is never written over; choose another --out".into(),
            });
        }
    }
    std::fs::create_dir_all(dir).map_err(|source| StudyError::Write {
        path: dir.to_owned(),
        source,
    })?;
    let copy = dir.join(STUDY_COPY);
    std::fs::write(&copy, &study.text)
        .map_err(|source| StudyError::Write { path: copy, source })?;
    let out = Appender::open(&trials)?;
    let diag_out = Appender::open(&diagnosis)?;
    Ok((trials, out, diag_out))
}

/// [`simulate_participant`] with each attempt run by `runner`.
#[allow(clippy::too_many_arguments)]
pub fn simulate_participant_with(
    study: &Study,
    sim: &Loop,
    p: Participant,
    seed: u64,
    dir: &Path,
    only: &Selection,
    progress: &(dyn Fn() + Sync),
    stop: &(dyn Fn() -> bool + Sync),
    runner: &AttemptRunner<'_>,
) -> Result<Vec<TrialRow>, StudyError> {
    only.check(study)?;
    let goals = study_goals(study, sim.robot)?;
    let params = study.file.simulation.clone();
    let (trials, mut out, mut diag_out) = open_participant_files(study, dir)?;
    let mut rows = Vec::new();
    let mut clock = 0.0;
    for (ti, task) in study.file.tasks.iter().enumerate() {
        if !only.task(task) {
            continue;
        }
        let q0 = start_q(sim.robot, &task.start).ok_or_else(|| StudyError::Invalid {
            path: study.path.clone(),
            key: format!("tasks[{ti}].start"),
            reason: "not a pose of the robot".into(),
        })?;
        let demos = if matches!(
            params.operator,
            OperatorKind::Follower | OperatorKind::Expert
        ) {
            Some(task_demos(goals[ti].task, sim.robot)?)
        } else {
            None
        };
        for (pos, &ci) in study.order(p).iter().enumerate() {
            let c = &study.file.conditions[ci];
            if !only.condition(c) {
                continue;
            }
            let spec = &study.models[ci][ti];
            let make = || {
                LoadedModel::load_for(spec, sim.robot)
                    .map(|m| m.at_period(sim.period_s))
                    .map_err(|source| SimError::Model {
                        spec: spec.clone(),
                        source,
                    })
            };
            // The practiced operator practises with the map first, as people did.
            let learned = if params.operator == OperatorKind::Practiced {
                let setup = AttemptSetup {
                    sim,
                    start_q: &q0,
                    goals: &goals[ti],
                    time_limit_s: task.time_limit_s,
                    params: &params,
                    model: &make,
                    seed: attempt_seed(seed, &[u64::from(p.0), ti as u64, ci as u64, 0]),
                    aim_out: None,
                    learned: None,
                    demos: None,
                };
                Some(practice(&setup, task.practice_s)?)
            } else {
                None
            };
            for attempt in 1..=task.attempts {
                if stop() {
                    return Err(StudyError::Data {
                        path: trials.clone(),
                        reason: format!("stopped after {} attempts", rows.len()),
                    });
                }
                let setup = AttemptSetup {
                    sim,
                    start_q: &q0,
                    goals: &goals[ti],
                    time_limit_s: task.time_limit_s,
                    params: &params,
                    model: &make,
                    seed: attempt_seed(
                        seed,
                        &[u64::from(p.0), ti as u64, ci as u64, u64::from(attempt)],
                    ),
                    aim_out: None,
                    learned: learned.as_ref(),
                    demos: demos.as_ref(),
                };
                let info = AttemptInfo {
                    spec,
                    name: format!("{p}-t{}-c{}-a{attempt}", ti + 1, ci + 1),
                    task: &task.name,
                    goals: task.goals.as_deref().unwrap_or(&task.name),
                };
                let r = runner(&setup, &info)?;
                tracing::debug!(participant = %p, task = %task.name, condition = %c.name, attempt, ?r, "simulated attempt");
                let row = TrialRow {
                    study: study.file.name.clone(),
                    participant: p.to_string(),
                    task: task.name.clone(),
                    label: c.label.clone(),
                    condition: c.name.clone(),
                    model: spec.clone(),
                    position: pos as u32 + 1,
                    attempt,
                    repeated: false,
                    outcome: r.outcome,
                    completion_pct: r.completion_pct,
                    duration_s: r.duration_s,
                    mode_switches: r.mode_switches,
                    estops: 0,
                    recording: r.recording.clone().unwrap_or_default(),
                    started_unix_s: clock,
                };
                clock += r.duration_s;
                out.push(&row)?;
                if let Some(d) = &r.diagnosis {
                    diag_out.push(&crate::diagnose::DiagnosisRow::of(&row, d))?;
                }
                rows.push(row);
                progress();
            }
        }
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kinematics::Dls;
    use learning::goals::Tolerances;
    use mapper::ActionMap;
    use mapper::model::ModelKind;

    fn robot() -> &'static RobotProfile {
        RobotProfile::default_robot()
    }

    fn sim() -> Loop {
        Loop {
            robot: robot(),
            safety: safety::SafetyConfig::for_robot(robot()),
            period_s: 0.025,
        }
    }

    /// The scripted perfect map: the damped pseudo-inverse of the Jacobian applied to the
    /// pose error to the operator's aim (3 /s, at most 0.15 m/s and 1 rad/s), times the
    /// first stick axis. `None`: the zero map.
    struct Scripted {
        aim: Option<Arc<Mutex<Vector6<f64>>>>,
        jac: Jacobian,
    }

    impl ActionMap for Scripted {
        fn kind(&self) -> ModelKind {
            ModelKind::Scl
        }
        fn n_joints(&self) -> usize {
            robot().n_joints()
        }
        fn latent_dim(&self) -> usize {
            2
        }
        fn eval(&mut self, q: &[f64], _c: f64, a: &[f64], out: &mut [f64]) {
            out.fill(0.0);
            let Some(cell) = &self.aim else { return };
            let mut e = *cell.lock().unwrap() * 3.0;
            let lin = e.fixed_rows::<3>(0).norm();
            if lin > 0.15 {
                e.fixed_rows_mut::<3>(0).scale_mut(0.15 / lin);
            }
            let ang = e.fixed_rows::<3>(3).norm();
            if ang > 1.0 {
                e.fixed_rows_mut::<3>(3).scale_mut(1.0 / ang);
            }
            robot().arm().fk_jacobian(q, &mut self.jac).unwrap();
            Dls::default().step(&self.jac, &e, out).unwrap();
            out.iter_mut().for_each(|v| *v *= a[0]);
        }
    }

    fn scripted(aim: Option<Arc<Mutex<Vector6<f64>>>>) -> Result<LoadedModel, SimError> {
        let mut m = LoadedModel::load_for(mapper::model::BUNDLED_NAME, robot()).unwrap();
        m.map = Box::new(Scripted {
            aim,
            jac: Jacobian::zeros(robot().n_joints()),
        });
        m.header.speed_scale_rad_s = 1.0;
        Ok(m)
    }

    /// The map of a test attempt.
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Map {
        /// The scripted perfect map.
        Perfect,
        /// The scripted zero map.
        Zero,
        /// Mode switching (the `modeswitch` spec).
        ModeSwitch,
    }

    /// The task's start pose, as the study files write it: table cleaning over the patch, the
    /// others at `home`.
    fn start(task: GoalTask) -> Vec<f64> {
        learning::tasks::start_pose(robot(), task).unwrap()
    }

    fn attempt_with(
        task: GoalTask,
        map: Map,
        params: &SimParams,
        seed: u64,
        limit: f64,
    ) -> AttemptResult {
        let sim = sim();
        let goals = TaskGoals::of(task, Tolerances::default()).unwrap();
        let cell = Arc::new(Mutex::new(Vector6::zeros()));
        let aim = (map == Map::Perfect).then(|| cell.clone());
        let make = move || match map {
            Map::ModeSwitch => LoadedModel::load_for("modeswitch", robot())
                .map(|m| m.at_period(0.025))
                .map_err(|source| SimError::Model {
                    spec: "modeswitch".into(),
                    source,
                }),
            _ => scripted(aim.clone()),
        };
        let q0 = start(task);
        run_attempt(&AttemptSetup {
            sim: &sim,
            start_q: &q0,
            goals: &goals,
            time_limit_s: limit,
            params,
            model: &make,
            seed,
            aim_out: (map == Map::Perfect).then_some(cell),
            learned: None,
            demos: None,
        })
        .unwrap()
    }

    fn attempt(task: GoalTask, perfect: bool, seed: u64, limit: f64) -> AttemptResult {
        let sim = sim();
        let goals = TaskGoals::of(task, Tolerances::default()).unwrap();
        let cell = Arc::new(Mutex::new(Vector6::zeros()));
        let aim = perfect.then(|| cell.clone());
        let make = move || scripted(aim.clone());
        let q0 = robot().named_pose("home").unwrap().to_vec();
        run_attempt(&AttemptSetup {
            sim: &sim,
            start_q: &q0,
            goals: &goals,
            time_limit_s: limit,
            params: &SimParams::default(),
            model: &make,
            seed,
            aim_out: Some(cell),
            learned: None,
            demos: None,
        })
        .unwrap()
    }

    fn expert() -> SimParams {
        SimParams {
            operator: OperatorKind::Expert,
            ..SimParams::default()
        }
    }

    /// With the expert operator, `map` succeeds on `task` with two seeds, from the task's
    /// start pose in the study files, under the default safety configuration.
    fn expert_succeeds(task: GoalTask, map: Map, limit: f64) {
        let mut failed = Vec::new();
        for seed in [1, 2] {
            let r = attempt_with(task, map, &expert(), seed, limit);
            eprintln!("expert {task:?} {map:?} seed {seed}: {r:?}");
            if !(r.outcome == Outcome::Success && r.duration_s < limit && r.completion_pct == 100.0)
            {
                failed.push(format!("seed {seed}: {r:?}"));
            }
            if map == Map::Perfect {
                assert_eq!(r.mode_switches, 0, "a map without modes: no presses");
            }
        }
        assert!(failed.is_empty(), "{task:?} {map:?}: {failed:#?}");
    }

    #[test]
    fn the_expert_succeeds_at_table_cleaning_with_the_perfect_map() {
        expert_succeeds(GoalTask::TableCleaning, Map::Perfect, 60.0);
    }

    #[test]
    fn the_expert_succeeds_at_table_cleaning_with_mode_switching() {
        expert_succeeds(GoalTask::TableCleaning, Map::ModeSwitch, 60.0);
    }

    #[test]
    fn the_expert_succeeds_at_pick_and_place_with_the_perfect_map() {
        expert_succeeds(GoalTask::PickAndPlace, Map::Perfect, 90.0);
    }

    #[test]
    fn the_expert_succeeds_at_pick_and_place_with_mode_switching() {
        expert_succeeds(GoalTask::PickAndPlace, Map::ModeSwitch, 90.0);
    }

    #[test]
    fn the_expert_succeeds_at_pouring_with_the_perfect_map() {
        expert_succeeds(GoalTask::Pouring, Map::Perfect, 120.0);
    }

    #[test]
    fn the_expert_succeeds_at_pouring_with_mode_switching() {
        expert_succeeds(GoalTask::Pouring, Map::ModeSwitch, 120.0);
    }

    /// Two attempts with mode switching that the expert once failed (the seeds of
    /// `examples/study/feasibility.toml`'s attempts): pouring (seed 1, P02, attempt 1: the
    /// return upright blocked by the safety filter's clearance rule, which its predictions
    /// did not know then: a timeout at 83 % with 53 presses; the whole-arm stop in the
    /// predictions has its own test, `the_prediction_stops_at_the_whole_arm_stop_distance`)
    /// and table cleaning (seed 2, P04, attempt 2: 2.4 cm from the point behind an object in
    /// the z-yaw mode, within the position tolerance, where it did not weigh switching back
    /// to x-y: a timeout at 60 % with 13 presses).
    #[test]
    fn the_expert_succeeds_in_the_attempts_it_once_failed() {
        for (task, seed, limit) in [
            (GoalTask::Pouring, attempt_seed(1, &[2, 2, 0, 1]), 120.0),
            (
                GoalTask::TableCleaning,
                attempt_seed(2, &[4, 0, 0, 2]),
                60.0,
            ),
        ] {
            let r = attempt_with(task, Map::ModeSwitch, &expert(), seed, limit);
            assert_eq!(r.outcome, Outcome::Success, "{task:?}: {r:?}");
        }
    }

    #[test]
    fn the_expert_never_succeeds_with_the_zero_map() {
        for task in [
            GoalTask::TableCleaning,
            GoalTask::PickAndPlace,
            GoalTask::Pouring,
        ] {
            let r = attempt_with(task, Map::Zero, &expert(), 1, 20.0);
            assert!(
                r.outcome == Outcome::Timeout && r.completion_pct < 100.0 && r.duration_s == 20.0,
                "zero {task:?}: {r:?}"
            );
        }
    }

    #[test]
    fn a_perfect_map_succeeds_on_every_task_and_a_zero_map_never_does() {
        let mut failed = Vec::new();
        for (task, limit) in [
            (GoalTask::TableCleaning, 60.0),
            (GoalTask::PickAndPlace, 90.0),
            (GoalTask::Pouring, 120.0),
        ] {
            for seed in [1, 2] {
                let r = attempt(task, true, seed, limit);
                if !(r.outcome == Outcome::Success
                    && r.duration_s < limit
                    && r.completion_pct == 100.0)
                {
                    failed.push(format!("perfect {task:?} seed {seed}: {r:?}"));
                }
            }
            let r = attempt(task, false, 1, limit);
            if !(r.outcome == Outcome::Timeout && r.completion_pct < 100.0 && r.duration_s == limit)
            {
                failed.push(format!("zero {task:?}: {r:?}"));
            }
        }
        assert!(failed.is_empty(), "{failed:#?}");
    }

    const STUDY: &str = r#"
name = "sim"
participants = 2
[[tasks]]
name = "pick-and-place"
start = "home"
time_limit_s = 4
practice_s = 6
attempts = 2
[[conditions]]
label = "A"
name = "bundled"
model = "bundled"
[[conditions]]
label = "B"
name = "mode switching"
model = "modeswitch"
[simulation]
candidates = 16
"#;

    #[test]
    fn the_same_seed_gives_the_same_trials_file() {
        same_seed_same_trials("greedy");
    }

    #[test]
    fn the_same_seed_gives_the_same_trials_file_with_the_expert() {
        same_seed_same_trials("expert");
    }

    #[test]
    fn the_same_seed_gives_the_same_trials_file_with_the_practiced_operator() {
        same_seed_same_trials("practiced");
    }

    /// Mode switching with the stick turned a quarter turn: what the stick's x does, its y
    /// does (and x does what -y did).
    struct Turned(Box<dyn ActionMap>);

    impl ActionMap for Turned {
        fn kind(&self) -> ModelKind {
            self.0.kind()
        }
        fn n_joints(&self) -> usize {
            self.0.n_joints()
        }
        fn latent_dim(&self) -> usize {
            self.0.latent_dim()
        }
        fn eval(&mut self, q: &[f64], c: f64, a: &[f64], out: &mut [f64]) {
            self.0.eval(q, c, &[-a[1], a[0]], out);
        }
        fn press(&mut self, pressed: u32) {
            self.0.press(pressed);
        }
        fn mode(&self) -> Option<mapper::MapMode> {
            self.0.mode()
        }
        fn set_period(&mut self, period_s: f64) {
            self.0.set_period(period_s);
        }
    }

    fn modeswitch(turned: bool) -> Result<LoadedModel, SimError> {
        let mut m = LoadedModel::load_for("modeswitch", robot())
            .map(|m| m.at_period(0.025))
            .map_err(|source| SimError::Model {
                spec: "modeswitch".into(),
                source,
            })?;
        if turned {
            let zero = Scripted {
                aim: None,
                jac: Jacobian::zeros(robot().n_joints()),
            };
            let inner = std::mem::replace(&mut m.map, Box::new(zero));
            m.map = Box::new(Turned(inner));
        }
        Ok(m)
    }

    /// The practiced operator practises pouring for `practice_s` with mode switching
    /// (`turned`: with its stick turned), then makes an attempt with mode switching. Also
    /// the times the attempt asked for a copy of the map.
    fn practiced_pouring(turned: bool, practice_s: f64, seed: u64) -> (AttemptResult, usize) {
        let sim = sim();
        let goals = TaskGoals::of(GoalTask::Pouring, Tolerances::default()).unwrap();
        // Without slips of the thumb: the test is about what it learned.
        let mut params = SimParams {
            operator: OperatorKind::Practiced,
            ..SimParams::default()
        };
        params.practiced.mode_slip = 0.0;
        let q0 = start(GoalTask::Pouring);
        let practice_map = move || modeswitch(turned);
        let learned = practice(
            &AttemptSetup {
                sim: &sim,
                start_q: &q0,
                goals: &goals,
                time_limit_s: 120.0,
                params: &params,
                model: &practice_map,
                seed,
                aim_out: None,
                learned: None,
                demos: None,
            },
            practice_s,
        )
        .unwrap();
        assert!(learned.observations() > 1000, "{}", learned.observations());
        assert_eq!(learned.modes(), 3);
        let calls = std::sync::atomic::AtomicUsize::new(0);
        let map = || {
            calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            modeswitch(false)
        };
        let r = run_attempt(&AttemptSetup {
            sim: &sim,
            start_q: &q0,
            goals: &goals,
            time_limit_s: 120.0,
            params: &params,
            model: &map,
            seed: seed + 100,
            aim_out: None,
            learned: Some(&learned),
            demos: None,
        })
        .unwrap();
        (r, calls.into_inner())
    }

    /// The practiced operator knows the map only from practice: after practising with the
    /// map it is tested on it pours; after practising with the stick turned a quarter turn
    /// (the same map otherwise) it does worse with the same seeds. It never asks for a copy
    /// of the map: the one copy made is the one the graph serves (the expert, for
    /// comparison, asks for one per prediction).
    #[test]
    fn the_practiced_operator_knows_the_map_only_from_practice() {
        let mut same = Vec::new();
        let mut swapped = Vec::new();
        for seed in [1, 2] {
            let (r, calls) = practiced_pouring(false, 240.0, seed);
            assert_eq!(calls, 1, "only the served copy: {calls}");
            same.push(r);
            swapped.push(practiced_pouring(true, 240.0, seed).0);
        }
        eprintln!("practised with the map: {same:#?}\npractised turned: {swapped:#?}");
        let score = |rs: &[AttemptResult]| -> f64 {
            rs.iter()
                .map(|r| r.completion_pct - r.duration_s / 120.0)
                .sum()
        };
        assert!(
            same.iter().all(|r| r.outcome == Outcome::Success),
            "{same:#?}"
        );
        assert!(score(&swapped) < score(&same), "{swapped:#?}\n{same:#?}");
        let expert_calls = std::sync::atomic::AtomicUsize::new(0);
        let map = || {
            expert_calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            modeswitch(false)
        };
        let goals = TaskGoals::of(GoalTask::Pouring, Tolerances::default()).unwrap();
        let q0 = start(GoalTask::Pouring);
        run_attempt(&AttemptSetup {
            sim: &sim(),
            start_q: &q0,
            goals: &goals,
            time_limit_s: 1.0,
            params: &expert(),
            model: &map,
            seed: 1,
            aim_out: None,
            learned: None,
            demos: None,
        })
        .unwrap();
        assert!(expert_calls.into_inner() > 10);
    }

    /// Without practice the practiced operator has nothing to go on.
    #[test]
    fn the_practiced_operator_is_refused_without_practice() {
        let sim = sim();
        let goals = TaskGoals::of(GoalTask::Pouring, Tolerances::default()).unwrap();
        let params = SimParams {
            operator: OperatorKind::Practiced,
            ..SimParams::default()
        };
        let q0 = start(GoalTask::Pouring);
        let map = || modeswitch(false);
        let e = run_attempt(&AttemptSetup {
            sim: &sim,
            start_q: &q0,
            goals: &goals,
            time_limit_s: 1.0,
            params: &params,
            model: &map,
            seed: 1,
            aim_out: None,
            learned: None,
            demos: None,
        })
        .unwrap_err();
        assert!(e.to_string().contains("not practised"), "{e}");
    }

    fn same_seed_same_trials(operator: &str) {
        let dir =
            std::env::temp_dir().join(format!("scl-study-sim-{operator}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let text = format!("{STUDY}operator = \"{operator}\"\n");
        let study = Study::parse(&text, &dir.join("s.toml"), robot()).unwrap();
        assert_eq!(study.file.simulation.operator.name(), operator);
        let run = |sub: &str, seed: u64| {
            let d = dir.join(sub);
            let rows =
                simulate_participant(&study, &sim(), Participant(2), seed, &d, &|| {}, &|| false)
                    .unwrap();
            assert_eq!(rows.len(), 4);
            std::fs::read(d.join(TRIALS)).unwrap()
        };
        let a = run("a", 7);
        assert_eq!(a, run("b", 7));
        let e = simulate_participant(
            &study,
            &sim(),
            Participant(2),
            7,
            &dir.join("a"),
            &|| {},
            &|| false,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("never written over"), "{e}");
        let data = crate::report::Data::load(&[dir.join("a")]).unwrap();
        let r = crate::report::analyse(&data, None).unwrap();
        assert_eq!(r.conditions, ["bundled", "mode switching"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[cfg(test)]
mod operator_key_tests {
    use super::*;

    const STUDY: &str = r#"
name = "sim"
participants = 2
[[tasks]]
name = "pouring"
start = "home"
time_limit_s = 4
attempts = 1
[[conditions]]
label = "A"
name = "bundled"
model = "bundled"
[[conditions]]
label = "B"
name = "mode switching"
model = "modeswitch"
[simulation]
"#;

    fn parse(extra: &str) -> Result<Study, StudyError> {
        Study::parse(
            &format!("{STUDY}{extra}"),
            Path::new("s.toml"),
            RobotProfile::default_robot(),
        )
    }

    #[test]
    fn the_operator_is_greedy_unless_the_study_file_names_another() {
        assert_eq!(
            parse("").unwrap().file.simulation.operator,
            OperatorKind::Greedy
        );
        assert_eq!(
            parse("operator = \"expert\"\n")
                .unwrap()
                .file
                .simulation
                .operator,
            OperatorKind::Expert
        );
    }

    #[test]
    fn an_unknown_operator_is_refused_naming_the_key_and_the_operators() {
        let e = parse("operator = \"careful\"\n").unwrap_err().to_string();
        for want in [
            "s.toml",
            "simulation.operator",
            "careful",
            "greedy, practiced, expert",
        ] {
            assert!(e.contains(want), "`{want}` in: {e}");
        }
    }

    #[test]
    fn the_feasibility_study_loads_and_runs_the_expert() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/study/feasibility.toml");
        let s = Study::load(&path, RobotProfile::default_robot()).unwrap();
        assert_eq!(s.file.simulation.operator, OperatorKind::Expert);
        assert_eq!(s.file.tasks.len(), 3);
        assert_eq!(
            study_goals(&s, RobotProfile::default_robot())
                .unwrap()
                .len(),
            3
        );
    }

    /// `examples/study/gen3.toml` on the Gen3: its goals lie in the Gen3's scene (15 cm
    /// further out than the Gen3 lite's, as its demonstrations), the Gen3 lite refuses it (its
    /// table-cleaning start has seven joints), and a participant's pick-and-place with mode
    /// switching succeeds with the expert operator.
    #[test]
    fn the_gen3_study_runs_on_the_gen3() {
        let gen3 = RobotProfile::by_name("gen3").unwrap();
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/study/gen3.toml");
        let s = Study::load(&path, gen3).unwrap();
        assert_eq!(s.file.tasks.len(), 3);
        let goals = study_goals(&s, gen3).unwrap();
        let lite = TaskGoals::of(
            GoalTask::PickAndPlace,
            learning::goals::Tolerances::default(),
        )
        .unwrap();
        let at = |g: &Subgoal| match g {
            Subgoal::Reach { at, .. } | Subgoal::Approach { at, .. } => *at,
            other => panic!("{other:?}"),
        };
        let d = at(&goals[1].subgoals[0]) - at(&lite.subgoals[0]);
        assert!(
            (d.x - 0.15).abs() < 1e-9 && d.y == 0.0 && d.z == 0.0,
            "{d:?}"
        );
        assert!((goals[0].table_centre.x - 0.53).abs() < 1e-9);
        assert!(Study::load(&path, RobotProfile::default_robot()).is_err());
        let dir = std::env::temp_dir().join(format!("scl-study-gen3-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let sim = Loop {
            robot: gen3,
            safety: safety::SafetyConfig::for_robot(gen3),
            period_s: 0.025,
        };
        let only = Selection {
            task: Some("pick-and-place".into()),
            condition: Some("A".into()),
        };
        let rows = simulate_participant_with(
            &s,
            &sim,
            Participant(1),
            1,
            &dir,
            &only,
            &|| {},
            &|| false,
            &|setup, _| run_attempt(setup),
        )
        .unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!(
            rows[0].outcome,
            crate::data::Outcome::Success,
            "{:?}",
            rows[0]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_bad_expert_setting_is_refused_naming_the_key() {
        let e = parse("operator = \"expert\"\n[simulation.expert]\nsamples = 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("simulation.expert.samples"), "{e}");
        let e = parse("[simulation.expert]\nhorizon_s = 0.01\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("simulation.expert.horizon_s"), "{e}");
        let e = parse("[simulation.expert]\nsample = 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample"), "{e}");
    }

    #[test]
    fn a_bad_practiced_setting_is_refused_naming_the_key() {
        let p =
            parse("operator = \"practiced\"\n[simulation.practiced]\nmode_slip = 0.3\n").unwrap();
        assert_eq!(p.file.simulation.operator, OperatorKind::Practiced);
        assert_eq!(p.file.simulation.practiced.mode_slip, 0.3);
        for (text, key) in [
            ("mode_slip = 1.5", "simulation.practiced.mode_slip"),
            (
                "position_width_m = 0",
                "simulation.practiced.position_width_m",
            ),
            ("explore_s = -1", "simulation.practiced.explore_s"),
            (
                "[simulation.practiced.planner]\nsamples = 0",
                "simulation.practiced.planner.samples",
            ),
        ] {
            let e = parse(&format!("[simulation.practiced]\n{text}\n"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(key), "{text}: {e}");
        }
    }
}
