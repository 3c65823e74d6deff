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
    run_attempt_followed, training_demos,
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
        let follower = self.params.operator == OperatorKind::Follower;
        let nearest = if self.spec == NEAREST_DEMONSTRATION {
            if !follower {
                return Err(SimError::Setup(format!(
                    "the {NEAREST_DEMONSTRATION} map drives the follower only (--operator \
                     follower): it searches every demonstrated tick on each evaluation, too \
                     slow for the {} operator's planning",
                    self.params.operator.name()
                )));
            }
            Some(self.nearest_demonstration()?)
        } else {
            None
        };
        let make = || match &nearest {
            Some((paths, speed)) => {
                let mut m = LoadedModel::load_for(mapper::model::BUNDLED_NAME, sim.robot)
                    .map_err(|source| SimError::Model {
                        spec: self.spec.to_owned(),
                        source,
                    })?
                    .at_period(sim.period_s);
                m.map = Box::new(NearestDemonstration::new(
                    paths.clone(),
                    sim.robot.n_joints(),
                    sim.period_s,
                ));
                m.header.speed_scale_rad_s = *speed;
                Ok(m)
            }
            None => LoadedModel::load_for(self.spec, sim.robot)
                .map(|m| m.at_period(sim.period_s))
                .map_err(|source| SimError::Model {
                    spec: self.spec.to_owned(),
                    source,
                }),
        };
        // Refuse a model that does not load before anything runs.
        make()?;
        let attempts = if follower {
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

    /// The task's training demonstrations' paths and the speed scale a map trained on them
    /// gets ([`learning::train::default_speed_scale`], within the robot's largest).
    fn nearest_demonstration(&self) -> Result<(Arc<Vec<DemoPath>>, f64), SimError> {
        let robot = self.sim.robot;
        let demos = training_demos(self.task, robot)?;
        let qdot: Vec<Vec<f64>> = demos
            .trajectories
            .iter()
            .flat_map(|t| t.qdot.iter().cloned())
            .collect();
        let speed = learning::train::default_speed_scale(&qdot)
            .ok_or_else(|| SimError::Setup("the demonstrations never move".into()))?
            .min(mapper::model::max_speed_scale_rad_s(robot));
        Ok((demos.paths.clone(), speed))
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
                let seed = attempt_seed(i, &[self.task as u64]);
                let (result, _) = self.attempt(make, &q0, &goals, seed, &demos)?;
                Ok(CapabilityAttempt {
                    name: format!("seed {i}"),
                    result,
                    followed_pct: None,
                })
            })
            .collect()
    }

    /// One attempt from `q0` at `goals` with the task's time limit; progress told after it.
    fn attempt(
        &self,
        make: &(dyn Fn() -> Result<LoadedModel, SimError> + Sync),
        q0: &[f64],
        goals: &TaskGoals,
        seed: u64,
        demos: &Demos,
    ) -> Result<(AttemptResult, Option<crate::operator::follower::Followed>), SimError> {
        let setup = AttemptSetup {
            sim: self.sim,
            start_q: q0,
            goals,
            time_limit_s: time_limit_s(self.task),
            params: self.params,
            model: make,
            seed,
            aim_out: None,
            learned: None,
            demos: Some(demos),
        };
        let r = run_attempt_followed(&setup)?;
        (self.progress)();
        Ok(r)
    }

    fn attempts_along_demonstrations(
        &self,
        make: &(dyn Fn() -> Result<LoadedModel, SimError> + Sync),
    ) -> Result<Vec<CapabilityAttempt>, SimError> {
        let demos = training_demos(self.task, self.sim.robot)?;
        let paths = demos.paths.clone();
        let tol = Tolerances::default();
        demos
            .trajectories
            .par_iter()
            .zip(&demos.scenes)
            .enumerate()
            .map(|(i, (traj, scene))| {
                let goals = TaskGoals::in_scene(scene, tol);
                let demos = Demos {
                    paths: paths.clone(),
                    only: Some(i),
                };
                let q0 = traj.q.first().cloned().unwrap_or_default();
                let seed = attempt_seed(DEMOS_SEED, &[self.task as u64, i as u64]);
                let (result, followed) = self.attempt(make, &q0, &goals, seed, &demos)?;
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

/// The map `scl eval capability` takes by this name: the task's own training
/// demonstrations as a map ([`NearestDemonstration`]), what any state-conditioned map learned
/// from them could do at best.
pub const NEAREST_DEMONSTRATION: &str = "nearest-demonstration";

/// A state-conditioned map made of demonstrations: at `(q, c)` the nearest demonstrated
/// joint angles with the same gripper state (open or closed), `H`'s first column the
/// demonstration's motion from there over [`crate::operator::follower::FOLLOW_AHEAD_S`], the
/// second the way back onto it, orthonormalised (Gram-Schmidt, as SCL's `H`). It reproduces
/// the demonstrations exactly where they went, so the follower driving it along them says
/// whether the demonstrations themselves can be reproduced in this loop (the safety filter,
/// the hand): a learned map cannot do better than this along them. Its search is a linear
/// scan of every demonstrated tick, fast enough for the follower's few probes per tick, not
/// for the expert's planning.
pub struct NearestDemonstration {
    paths: Arc<Vec<DemoPath>>,
    n: usize,
    ahead: usize,
}

impl NearestDemonstration {
    /// The map of `paths` for an arm of `n` joints at a control period of `dt` seconds.
    pub fn new(paths: Arc<Vec<DemoPath>>, n: usize, dt: f64) -> Self {
        let ahead = crate::operator::follower::ahead_ticks(dt);
        Self { paths, n, ahead }
    }

    /// The nearest demonstrated tick with the gripper `c`'s state: (path, tick).
    fn nearest(&self, q: &[f64], c: f64) -> Option<(usize, usize)> {
        crate::operator::follower::nearest_of(self.paths.iter().enumerate(), q, c)
    }
}

impl mapper::ActionMap for NearestDemonstration {
    fn kind(&self) -> mapper::model::ModelKind {
        mapper::model::ModelKind::Scl
    }
    fn n_joints(&self) -> usize {
        self.n
    }
    fn latent_dim(&self) -> usize {
        2
    }
    fn eval(&mut self, q: &[f64], c: f64, a: &[f64], out: &mut [f64]) {
        let n = self.n.min(out.len()).min(q.len());
        out.fill(0.0);
        let Some((pi, i)) = self.nearest(&q[..n], c) else {
            return;
        };
        let p = &self.paths[pi];
        let j = p.ahead(i, c, self.ahead);
        let (here, there) = (&p.points[i].q, &p.points[j].q);
        let mut cols = [[0.0; ipc_types::MAX_JOINTS]; 2];
        for k in 0..n {
            cols[0][k] = there[k] - here[k];
            cols[1][k] = here[k] - q[k];
        }
        // Gram-Schmidt; a column that vanishes (a grip: the arm stands) gives way to the next.
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm(&cols[0][..n]) < 1e-9 {
            cols.swap(0, 1);
            cols[1] = [0.0; ipc_types::MAX_JOINTS];
        }
        let n0 = norm(&cols[0][..n]);
        if n0 < 1e-12 {
            return;
        }
        cols[0][..n].iter_mut().for_each(|x| *x /= n0);
        let dot: f64 = (0..n).map(|k| cols[0][k] * cols[1][k]).sum();
        let [c0, c1] = &mut cols;
        for (x, y) in c1.iter_mut().zip(c0.iter()).take(n) {
            *x -= dot * y;
        }
        let n1 = norm(&cols[1][..n]);
        let k1 = if n1 > 1e-9 { 1.0 / n1 } else { 0.0 };
        for (k, o) in out.iter_mut().enumerate().take(n) {
            *o = cols[0][k] * a[0] + cols[1][k] * k1 * a[1];
        }
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
        let nearest = CapabilityCheck {
            spec: NEAREST_DEMONSTRATION,
            ..check
        };
        let e = nearest.run().expect_err("the expert cannot plan with it");
        assert!(e.to_string().contains("--operator follower"), "{e}");
    }

    /// On a demonstration the map's first direction is the demonstration's own motion from
    /// there (unit length), its second is orthogonal to it; off it the second pulls back.
    #[test]
    fn the_nearest_demonstration_map_moves_along_its_demonstration() {
        let robot = RobotProfile::default_robot();
        let ds = learning::tasks::generate_for(Task::PickAndPlace, robot, 2, 0, DEMOS_SEED)
            .expect("demonstrations");
        let paths: Vec<DemoPath> = ds
            .train
            .iter()
            .map(|t| DemoPath::of(robot, t).expect("kinematics"))
            .collect();
        let n = robot.n_joints();
        let mut map = NearestDemonstration::new(Arc::new(paths.clone()), n, 0.025);
        use mapper::ActionMap;
        let (p, i) = (&paths[1], 40);
        let (q, c) = (&p.points[i].q, p.points[i].c);
        let mut h0 = vec![0.0; n];
        let mut h1 = vec![0.0; n];
        map.eval(q, c, &[1.0, 0.0], &mut h0);
        map.eval(q, c, &[0.0, 1.0], &mut h1);
        let ahead = &p.points[i + 10].q;
        let motion: Vec<f64> = (0..n).map(|k| ahead[k] - q[k]).collect();
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        assert!((norm(&h0) - 1.0).abs() < 1e-9, "{h0:?}");
        assert!(
            dot(&h0, &motion) / norm(&motion) > 1.0 - 1e-9,
            "{h0:?} {motion:?}"
        );
        assert!(dot(&h0, &h1).abs() < 1e-9, "{h0:?} {h1:?}");
        // Off the demonstration (0.05 rad on the shoulder): the second direction leads back.
        let mut off = q.clone();
        off[1] += 0.05;
        map.eval(&off, c, &[0.0, 1.0], &mut h1);
        assert!(h1[1] < -0.5, "{h1:?}");
    }
}
