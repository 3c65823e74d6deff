//! Whether a map can do a task at all, before a person sits down (`scl eval capability`):
//!
//! * **from the study's start** ([`OperatorKind::Expert`], or any operator but the follower):
//!   attempts of the task in its scene ([`TaskGoals::on`]) from where an attempt starts
//!   ([`learning::tasks::start_pose`]), with the paper's time limit, each with its own seed;
//!   the success rate.
//! * **along its demonstrations** ([`OperatorKind::Follower`]): the follower reproduces each
//!   of the task's training demonstrations (the generator's at [`DEMOS_SEED`], the ones the
//!   shipped study models learned from) from that demonstration's start, in its own scene
//!   ([`TaskGoals::in_scene`], goals every demonstration passes); the share it tracks to the
//!   end (every goal of its scene done in time).
//!
//! A map the follower drives to the end of its demonstrations can do what they did; if the
//! expert then fails from the study's start, the planner, not the map, is in the way.
//!
//! Everything runs in process through the step functions of the graph (the served map, the
//! safety filter, the mock arm), on simulated time: [`crate::simulate::run_attempt`], the
//! attempts in parallel on rayon's pool (the caller's `install` sets its size).

use std::sync::Arc;

use rayon::prelude::*;

use kinematics::RobotProfile;
use learning::goals::{TaskGoals, Tolerances};
use learning::tasks::Task;
use mapper::LoadedModel;

use crate::data::Outcome;
use crate::operator::follower::DemoPath;
use crate::operator::{Demos, OperatorKind};
use crate::simulate::{
    AttemptResult, AttemptSetup, DEMOS_SEED, Loop, SimError, SimParams, attempt_seed,
    run_attempt_followed,
};

/// The paper's time limit of an attempt at `task` (s): 60 for table cleaning, 90 for
/// pick-and-place, 120 for pouring (the study files in `examples/study/`).
pub fn time_limit_s(task: Task) -> f64 {
    match task {
        Task::TableCleaning => 60.0,
        Task::PickAndPlace => 90.0,
        Task::Pouring | Task::PlanarReach => 120.0,
    }
}

/// One attempt of a capability check.
#[derive(Debug, Clone, PartialEq)]
pub struct CapabilityAttempt {
    /// The seed's number (from the study's start) or the demonstration's name (along it).
    pub name: String,
    /// How it ended.
    pub result: AttemptResult,
    /// The follower: the share of its demonstration it got along (%).
    pub followed_pct: Option<f64>,
}

/// What a capability check found.
#[derive(Debug, Clone, PartialEq)]
pub struct Capability {
    /// The task.
    pub task: Task,
    /// The operator.
    pub operator: OperatorKind,
    /// Every attempt.
    pub attempts: Vec<CapabilityAttempt>,
}

impl Capability {
    /// Attempts that succeeded.
    pub fn successes(&self) -> usize {
        self.attempts
            .iter()
            .filter(|a| a.result.outcome == Outcome::Success)
            .count()
    }

    /// The share of attempts that succeeded (0..1).
    pub fn rate(&self) -> f64 {
        self.successes() as f64 / self.attempts.len().max(1) as f64
    }

    /// A line for a person: `pick-and-place, expert from the start: 20 / 26 (77 %)`.
    pub fn summary(&self) -> String {
        let how = if self.operator == OperatorKind::Follower {
            "along its training demonstrations, tracked to the end"
        } else {
            "from the study's start"
        };
        format!(
            "{}, {} {how}: {} / {} ({:.0} %)",
            self.task.name(),
            self.operator.name(),
            self.successes(),
            self.attempts.len(),
            100.0 * self.rate()
        )
    }
}

/// What to check.
pub struct CapabilityCheck<'a> {
    /// The closed loop (robot, safety configuration, period).
    pub sim: &'a Loop,
    /// The model (a file or a built-in map's name, as `--model` takes it).
    pub spec: &'a str,
    /// The task.
    pub task: Task,
    /// The operator and the hand (`operator` says which).
    pub params: &'a SimParams,
    /// Attempts from the study's start (ignored by the follower, which makes one per
    /// demonstration).
    pub seeds: u64,
    /// Called after each attempt.
    pub progress: &'a (dyn Fn() + Sync),
}

impl CapabilityCheck<'_> {
    /// How many attempts [`CapabilityCheck::run`] makes.
    pub fn attempts(&self) -> u64 {
        if self.params.operator == OperatorKind::Follower {
            self.task.default_counts().0 as u64
        } else {
            self.seeds
        }
    }

    /// Runs the check.
    pub fn run(&self) -> Result<Capability, SimError> {
        let sim = self.sim;
        let make = || {
            LoadedModel::load_for(self.spec, sim.robot)
                .map(|m| m.at_period(sim.period_s))
                .map_err(|source| SimError::Model {
                    spec: self.spec.to_owned(),
                    source,
                })
        };
        // Refuse a model that does not load before anything runs.
        make()?;
        let attempts = if self.params.operator == OperatorKind::Follower {
            self.attempts_along_demonstrations(&make)?
        } else {
            self.attempts_from_the_start(&make)?
        };
        Ok(Capability {
            task: self.task,
            operator: self.params.operator,
            attempts,
        })
    }

    fn attempts_from_the_start(
        &self,
        make: &(dyn Fn() -> Result<LoadedModel, SimError> + Sync),
    ) -> Result<Vec<CapabilityAttempt>, SimError> {
        let robot = self.sim.robot;
        let goals = goals_on(self.task, robot)?;
        let q0 = learning::tasks::start_pose(robot, self.task)
            .map_err(|e| SimError::Setup(format!("the start pose: {e}")))?;
        // The expert knows the task's route: its training demonstrations' paths.
        let demos = crate::simulate::task_demos(self.task, robot)?;
        (1..=self.seeds)
            .into_par_iter()
            .map(|i| {
                let setup = AttemptSetup {
                    sim: self.sim,
                    start_q: &q0,
                    goals: &goals,
                    time_limit_s: time_limit_s(self.task),
                    params: self.params,
                    model: make,
                    seed: attempt_seed(i, &[self.task as u64]),
                    aim_out: None,
                    learned: None,
                    demos: Some(&demos),
                };
                let (result, _) = run_attempt_followed(&setup)?;
                (self.progress)();
                Ok(CapabilityAttempt {
                    name: format!("seed {i}"),
                    result,
                    followed_pct: None,
                })
            })
            .collect()
    }

    fn attempts_along_demonstrations(
        &self,
        make: &(dyn Fn() -> Result<LoadedModel, SimError> + Sync),
    ) -> Result<Vec<CapabilityAttempt>, SimError> {
        let robot = self.sim.robot;
        let (n_train, _) = self.task.default_counts();
        let (ds, scenes) =
            learning::tasks::generate_scenes_for(self.task, robot, n_train, 0, DEMOS_SEED)
                .map_err(|e| SimError::Setup(format!("the demonstrations: {e}")))?;
        let paths = ds
            .train
            .iter()
            .map(|t| DemoPath::of(robot, t))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| SimError::Setup(format!("the demonstrations: {e}")))?;
        let paths = Arc::new(paths);
        let tol = Tolerances::default();
        ds.train
            .par_iter()
            .zip(&scenes)
            .enumerate()
            .map(|(i, (traj, scene))| {
                let goals = TaskGoals::in_scene(scene, tol);
                let demos = Demos {
                    paths: paths.clone(),
                    only: Some(i),
                };
                let q0 = traj.q.first().cloned().unwrap_or_default();
                let setup = AttemptSetup {
                    sim: self.sim,
                    start_q: &q0,
                    goals: &goals,
                    time_limit_s: time_limit_s(self.task),
                    params: self.params,
                    model: make,
                    seed: attempt_seed(DEMOS_SEED, &[self.task as u64, i as u64]),
                    aim_out: None,
                    learned: None,
                    demos: Some(&demos),
                };
                let (result, followed) = run_attempt_followed(&setup)?;
                (self.progress)();
                Ok(CapabilityAttempt {
                    name: traj.name.clone(),
                    result,
                    followed_pct: followed
                        .map(|f| 100.0 * (f.furthest + 1) as f64 / f.len.max(1) as f64),
                })
            })
            .collect()
    }
}

/// The goals of `task` in its study scene on `robot`'s arm.
fn goals_on(task: Task, robot: &RobotProfile) -> Result<TaskGoals, SimError> {
    TaskGoals::on(task, Tolerances::default(), robot)
        .ok_or_else(|| SimError::Setup(format!("{} has no scene to simulate", task.name())))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mode switching, which the expert drives through every task, passes the check from the
    /// study's start; a map that does not load is refused before anything runs.
    #[test]
    fn mode_switching_is_capable_of_pick_and_place_and_a_missing_model_is_refused() {
        let robot = RobotProfile::default_robot();
        let sim = Loop {
            robot,
            safety: safety::SafetyConfig::for_robot(robot),
            period_s: 0.025,
        };
        let params = SimParams {
            operator: OperatorKind::Expert,
            ..SimParams::default()
        };
        let check = CapabilityCheck {
            sim: &sim,
            spec: "modeswitch",
            task: Task::PickAndPlace,
            params: &params,
            seeds: 1,
            progress: &|| {},
        };
        assert_eq!(check.attempts(), 1);
        let c = check.run().expect("the check runs");
        assert_eq!((c.successes(), c.attempts.len()), (1, 1), "{c:?}");
        assert!(c.summary().contains("1 / 1"), "{}", c.summary());
        let missing = CapabilityCheck {
            spec: "/nonexistent/model.safetensors",
            ..check
        };
        assert!(matches!(missing.run(), Err(SimError::Model { .. })));
    }
}
