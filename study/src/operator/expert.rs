//! The expert operator (`operator = "expert"`): what a map allows at best. It plans with the
//! served map itself as its forward model: from the state it sees, it predicts where stick
//! sequences of [`ExpertParams::horizon_s`] take the tool (`q += s map(q, c, a) dt` at knots
//! [`ExpertParams::step_s`] apart, the joints kept within their limits, the gripper closing
//! where the operator would close it) and scores each prediction by the task's own progress
//! (a copy of the attempt's [`GoalRun`]: subgoals done along the way, the distance to each
//! next subgoal). It re-plans every tick by one step of model-predictive path integral
//! control (MPPI): [`ExpertParams::samples`] sequences drawn around its last plan and as
//! constant deflections, weighted by their cost. With a map that has modes it plans in each
//! mode every [`ExpertParams::mode_check_s`] (starting with the presses and the rest a
//! switch takes) and presses the mode button when another mode's plan gains more than
//! [`SimParams::mode_switch_margin`] over the current one's.
//!
//! The prediction knows two rules of the safety filter, as a person sees the arm stop: a step
//! that brings a pair of the arm's collision model closer than the safety configuration's
//! stop distance is not taken, nor one that takes a joint further past its limit less the
//! configuration's joint margin (the filter stops the whole arm there, not the one joint). A scripted map that reads the operator's aim
//! ([`crate::simulate::AttemptSetup::aim_out`]) is given the predicted aim while predicting.
//!
//! It has the person's limits of the greedy operator: the plan starts after the reaction
//! delay (what the hand still has to carry out is part of the prediction), the stick's rate
//! is bounded, the mode button takes [`SimParams::mode_switch_s`] with the stick let go, the
//! input is noisy. When it makes no progress for [`ExpertParams::stuck_s`] it backs off:
//! for [`ExpertParams::back_off_s`] it plans to a point [`ExpertParams::back_off_m`] away in a
//! random direction (upwards), then goes back to the task.
//!
//! Everything it draws comes from the attempt's random stream: the same seed gives the same
//! attempt.

use ipc_types::{JoystickInput, MAX_JOINTS, buttons};
use kinematics::RobotProfile;
use learning::goals::{Aim, GoalRun, Tolerances, tilt};
use mapper::LoadedModel;
use mapper::rng::Rng;
use nalgebra::{Isometry3, Vector3, Vector6};
use safety::clearance::WholeArm;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use super::internal::{InternalModel, ToolState, twist_between};
use super::{Hand, ModeButton, Operate, Seen};
use crate::setup::{ExpertParams, ModelFactory, SimError, SimParams};

/// What a subgoal done is worth, in metres of mean distance over the horizon: more than any
/// distance in the workspace, so finishing a subgoal always beats staying near it.
const SUBGOAL_M: f64 = 1.0;

/// A mode switch must gain at least this much (m of mean distance over the horizon).
const SWITCH_MIN_M: f64 = 0.001;

/// Progress smaller than this (m) does not count against being stuck.
const PROGRESS_M: f64 = 0.005;

/// The task's route as the expert knows it: the tool positions of the task's demonstrations,
/// with the gripper open or closed there (every [`ROUTE_STRIDE`]th tick).
#[derive(Debug, Clone, Default)]
pub struct Route {
    points: Vec<(Vector3<f64>, bool)>,
}

/// Every how many ticks of a demonstration the route keeps a point (0.1 s at 40 Hz: at most
/// 3 cm apart at the demonstrations' speeds).
pub const ROUTE_STRIDE: usize = 4;

impl Route {
    /// The route of `demos`.
    pub fn of(demos: &super::Demos) -> Self {
        let points = demos
            .paths
            .iter()
            .flat_map(|p| p.points.iter().step_by(ROUTE_STRIDE))
            .map(|x| (x.tool.translation.vector, x.c >= 0.5))
            .collect();
        Self { points }
    }

    /// How far `p` is from the route where the gripper is as `closed` says (m; infinite for
    /// an empty route).
    pub fn distance(&self, p: &Vector3<f64>, closed: bool) -> f64 {
        self.points
            .iter()
            .filter(|(_, c)| *c == closed)
            .map(|(x, _)| (x - p).norm_squared())
            .fold(f64::INFINITY, f64::min)
            .sqrt()
    }
}

/// What a prediction is scored against.
#[derive(Debug, Clone, Copy)]
enum Target {
    /// The task's subgoals.
    Task,
    /// A point to back off to.
    Point(Vector3<f64>),
}

/// The forward model a planning operator predicts with.
pub(crate) enum Forward<'a> {
    /// The served map (the expert operator). Its copies, one per mode, for a map without
    /// memory; empty for a map with memory (its twist ramps): each prediction then starts
    /// from a fresh copy, at rest, made by `make`.
    Map {
        /// The copies.
        copies: Vec<LoadedModel>,
        /// The served map's factory.
        make: &'a ModelFactory<'a>,
    },
    /// What practice taught (the practiced operator): never the map.
    Learned(Learner),
}

/// The practiced operator's internal model and, while it practises, what it learns from: the
/// tool poses it saw and the samples it sent.
pub(crate) struct Learner {
    pub(crate) model: InternalModel,
    /// It learns from what it sees (practice); otherwise the model stays as practice left it.
    pub(crate) learning: bool,
    /// The last ticks.
    history: VecDeque<Tick>,
    dt: f64,
}

/// What the practiced operator saw and did at one tick.
struct Tick {
    /// The tool's pose seen.
    tool: Isometry3<f64>,
    /// The gripper seen.
    gripper: f64,
    /// The mode shown.
    mode: Option<usize>,
    /// The stick sent.
    axes: [f64; 2],
    /// The buttons sent.
    buttons: u32,
}

impl Learner {
    /// What practice taught, `learning` or not from here on.
    pub(crate) fn new(model: InternalModel, learning: bool, dt: f64) -> Self {
        Self {
            model,
            learning,
            history: VecDeque::new(),
            dt,
        }
    }

    /// Takes what is seen this tick. The sample sent two ticks ago moved the tool between
    /// the last tick and this one (the mapper maps tick `k - 1` with the sample answered at
    /// `k - 2`, and the arm executes it until tick `k`), in the mode shown now.
    pub(crate) fn see(&mut self, seen: &Seen<'_>) {
        if !self.learning {
            return;
        }
        if let (Some(last), Some(sent)) = (self.history.back(), self.history.iter().rev().nth(1))
            && last.mode == seen.mode
            && sent.buttons & buttons::MODE == 0
        {
            let v = twist_between(&last.tool, seen.tool, self.dt);
            let at = ToolState::of(&last.tool, last.gripper);
            self.model
                .observe(seen.mode.unwrap_or(0), &at, sent.axes, &v);
        }
        self.history.push_back(Tick {
            tool: *seen.tool,
            gripper: seen.state.gripper,
            mode: seen.mode,
            axes: [0.0; 2],
            buttons: 0,
        });
        while self.history.len() > 3 {
            self.history.pop_front();
        }
    }

    /// Notes the sample sent this tick.
    pub(crate) fn sent(&mut self, joy: &JoystickInput) {
        if let Some(last) = self.history.back_mut() {
            last.axes = [f64::from(joy.axes[0]), f64::from(joy.axes[1])];
            last.buttons = joy.buttons;
        }
    }
}

/// The expert operator of one attempt, and the practiced one (the same planner with what
/// practice taught as its forward model).
pub(crate) struct Expert<'a> {
    params: SimParams,
    ex: ExpertParams,
    robot: &'static RobotProfile,
    tol: Tolerances,
    dt: f64,
    hand: Hand,
    /// What it predicts with: the served map (the expert) or what practice taught (the
    /// practiced operator).
    forward: Forward<'a>,
    /// Press the mode button when another mode's plan gains this fraction more.
    switch_margin: f64,
    /// What a turn of the tool that the subgoal does not ask for costs (m per rad).
    rotation_weight: f64,
    /// The chance that a switch ends one press too far (a slip of the thumb).
    slip: f64,
    modes: usize,
    speed_scale: f64,
    /// Knots per plan.
    knots: usize,
    /// Ticks per knot.
    ticks_per_knot: f64,
    /// The plan in each mode (the stick at each knot after the lead).
    plans: Vec<Vec<[f64; 2]>>,
    /// The mode button, pressed as a person does.
    button: ModeButton,
    /// The mode being switched to (its plan waits).
    switching_to: Option<usize>,
    ticks: u64,
    best_progress: f64,
    stale_ticks: u32,
    back_off: Option<(Vector3<f64>, u32)>,
    seqs: Vec<Vec<[f64; 2]>>,
    costs: Vec<f64>,
    out: [f64; MAX_JOINTS],
    /// A scripted map's aim ([`crate::simulate::AttemptSetup::aim_out`]).
    aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
    /// The arm's collision model in the safety configuration's scene, and its stop
    /// distance: a predicted step that brings a pair closer than that is not taken (the
    /// safety filter stops it).
    whole_arm: Option<(WholeArm, f64)>,
    /// Each joint's range less the safety configuration's joint margin (rad): a predicted
    /// step that takes a joint further past it is not taken, as the filter's position rule
    /// stops the whole arm there (it scales the whole command), not the one joint.
    joint_bounds: Vec<(f64, f64)>,
    /// The closest pair's distance now (m).
    clearance_now: f64,
    /// The joint angles at the end of the last prediction.
    predicted_q: [f64; MAX_JOINTS],
    /// The task's route (the expert's knowledge of it), if it has one.
    route: Option<Route>,
}

impl<'a> Expert<'a> {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        params: &SimParams,
        robot: &'static RobotProfile,
        safety: &safety::SafetyConfig,
        tol: Tolerances,
        dt: f64,
        make: &'a ModelFactory<'a>,
        aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
        route: Option<Route>,
    ) -> Result<Self, SimError> {
        let ex = params.expert.clone();
        let first = make()?;
        let speed_scale = first.header.speed_scale_rad_s;
        let (copies, modes) = if first.map.mode().is_none() {
            let mut first = first;
            first.map.set_period(ex.step_s);
            (vec![first], 1)
        } else {
            let mut modes = 1;
            for k in 1..8u32 {
                let mut m = make()?;
                for _ in 0..k {
                    m.map.press(buttons::MODE);
                }
                if m.map.mode().is_some_and(|x| x.index == 0) {
                    break;
                }
                modes += 1;
            }
            (Vec::new(), modes)
        };
        let mut op = Self::with(
            params,
            ex,
            params.mode_switch_margin,
            robot,
            safety,
            tol,
            dt,
            Forward::Map { copies, make },
            modes,
            aim_out,
        );
        op.speed_scale = speed_scale;
        op.route = route.filter(|_| op.ex.route_weight > 0.0);
        Ok(op)
    }

    /// The practiced operator: plans with `learner`'s model (the modes it has seen), never
    /// with the map.
    pub(crate) fn practiced(
        params: &SimParams,
        robot: &'static RobotProfile,
        safety: &safety::SafetyConfig,
        tol: Tolerances,
        dt: f64,
        learner: Learner,
    ) -> Self {
        let pr = &params.practiced;
        let modes = learner.model.modes();
        let mut op = Self::with(
            params,
            pr.planner.clone(),
            pr.mode_switch_margin,
            robot,
            safety,
            tol,
            dt,
            Forward::Learned(learner),
            modes,
            None,
        );
        // It sees the table and the arm stop at it; its own floor stands for that.
        op.whole_arm = None;
        // It is not given the task's route or the facing of a grasp (its calibration on mode
        // switching was made without them): what it knows, it learned in practice.
        op.ex.route_weight = 0.0;
        op.ex.face_weight_m_per_rad = 0.0;
        op.rotation_weight = pr.rotation_weight_m_per_rad;
        op.slip = pr.mode_slip;
        op
    }

    #[allow(clippy::too_many_arguments)]
    fn with(
        params: &SimParams,
        ex: ExpertParams,
        switch_margin: f64,
        robot: &'static RobotProfile,
        safety: &safety::SafetyConfig,
        tol: Tolerances,
        dt: f64,
        forward: Forward<'a>,
        modes: usize,
        aim_out: Option<Arc<Mutex<Vector6<f64>>>>,
    ) -> Self {
        let knots = ((ex.horizon_s / ex.step_s).round() as usize).max(1);
        Self {
            hand: Hand::new(params, dt),
            params: params.clone(),
            robot,
            tol,
            dt,
            forward,
            switch_margin,
            rotation_weight: 0.0,
            slip: 0.0,
            modes,
            speed_scale: 1.0,
            knots,
            ticks_per_knot: (ex.step_s / dt).max(1e-9),
            plans: vec![vec![[0.0; 2]; knots]; modes],
            button: ModeButton::default(),
            switching_to: None,
            ticks: 0,
            best_progress: f64::NEG_INFINITY,
            stale_ticks: 0,
            back_off: None,
            seqs: Vec::new(),
            costs: Vec::new(),
            out: [0.0; MAX_JOINTS],
            aim_out,
            whole_arm: safety
                .scene
                .scene()
                .ok()
                .and_then(|scene| WholeArm::new(robot, scene))
                .map(|a| (a, safety.stop_distance_m)),
            joint_bounds: {
                let l = robot.limits();
                let m = safety.joint_margin_rad;
                l.lower_rad
                    .iter()
                    .zip(&l.upper_rad)
                    .map(|(lo, hi)| (lo + m, hi - m))
                    .collect()
            },
            clearance_now: f64::INFINITY,
            predicted_q: [0.0; MAX_JOINTS],
            route: None,
            ex,
        }
    }

    fn error(&self, aim: &Aim, p: &Vector3<f64>, r: &nalgebra::UnitQuaternion<f64>) -> f64 {
        aim_error(
            aim,
            p,
            r,
            self.params.tilt_weight_m_per_rad,
            self.ex.face_weight_m_per_rad,
        )
    }

    /// The knots before the plan starts in mode `m` (`cur` the mode now): what the hand still
    /// carries out; after a switch, the presses and the rest with the stick let go, then the
    /// reaction delay.
    fn lead(&self, m: usize, cur: usize) -> Vec<[f64; 2]> {
        let tpk = self.ticks_per_knot;
        if m == cur {
            let pending: Vec<[f64; 2]> = self.hand.pending().copied().collect();
            let n = (pending.len() as f64 / tpk).ceil() as usize;
            (0..n)
                .map(|k| {
                    let lo = (k as f64 * tpk).round() as usize;
                    let hi = (((k + 1) as f64) * tpk).round() as usize;
                    let part = &pending[lo.min(pending.len())..hi.min(pending.len())];
                    if part.is_empty() {
                        return [0.0; 2];
                    }
                    let s = part
                        .iter()
                        .fold([0.0; 2], |a, x| [a[0] + x[0], a[1] + x[1]]);
                    [s[0] / part.len() as f64, s[1] / part.len() as f64]
                })
                .collect()
        } else {
            let presses = (m + self.modes - cur) % self.modes;
            let ticks = 2 * presses
                + (self.params.mode_switch_s / self.dt).round() as usize
                + self.hand.pending().len();
            vec![[0.0; 2]; (ticks as f64 / tpk).ceil() as usize]
        }
    }

    /// The cost of the stick sequence `lead` then `plan` in mode `m` from what is seen now,
    /// the stick at `stick` (lower is better; infinite if the map could not be evaluated).
    #[allow(clippy::too_many_arguments)]
    fn rollout(
        &mut self,
        m: usize,
        lead: &[[f64; 2]],
        plan: &[[f64; 2]],
        stick: [f64; 2],
        seen: &Seen<'_>,
        target: Target,
    ) -> f64 {
        // A map with memory: a fresh copy in mode m, at rest.
        let mut fresh = match &self.forward {
            Forward::Map { copies, make } if copies.is_empty() => {
                let Ok(mut copy) = make() else {
                    return f64::INFINITY;
                };
                for _ in 0..m {
                    copy.map.press(buttons::MODE);
                }
                copy.map.set_period(self.ex.step_s);
                Some(copy)
            }
            _ => None,
        };
        let chain = self.robot.arm();
        let n = (seen.state.n_joints as usize).min(MAX_JOINTS);
        let h = self.knots;
        let step = self.ex.step_s;
        let rate = self.params.stick_rate_per_s * step;
        let tilt_weight = self.params.tilt_weight_m_per_rad;
        let face_weight = self.ex.face_weight_m_per_rad;
        let mut q = [0.0; MAX_JOINTS];
        q[..n].copy_from_slice(&seen.state.q()[..n]);
        let mut c = seen.state.gripper;
        let mut clearance = self.clearance_now;
        let mut tool: Isometry3<f64> = *seen.tool;
        let mut p = tool.translation.vector;
        let mut run: Option<GoalRun> = matches!(target, Target::Task).then(|| seen.run.clone());
        let mut aim = seen.aim;
        let mut a = stick;
        let mut x = ToolState::of(seen.tool, c);
        let wrist = seen.state.q().last().copied().unwrap_or(0.0);
        let (mut cost, mut bonus) = (0.0, 0.0);
        for i in 0..h {
            let u = lead
                .get(i)
                .or_else(|| plan.get(i - lead.len().min(i)))
                .copied()
                .unwrap_or([0.0; 2]);
            let d = [u[0] - a[0], u[1] - a[1]];
            let dn = d[0].hypot(d[1]);
            let k = if dn > rate { rate / dn } else { 1.0 };
            a = [a[0] + d[0] * k, a[1] + d[1] * k];
            if let Some(g) = aim
                && let Some(close) = g.grip
                && g.distance(&p) <= self.tol.position_m
            {
                c = (c + if close { step } else { -step }).clamp(0.0, 1.0);
            }
            if let Some(cell) = &self.aim_out {
                let g = match target {
                    Target::Task => aim,
                    Target::Point(w) => Some(Aim {
                        position: w,
                        zone: learning::goals::Zone::Point,
                        tilt: None,
                        grip: None,
                        down: false,
                        face: false,
                    }),
                };
                if let (Some(g), Ok(mut e)) = (g, cell.lock()) {
                    *e = g.error(&tool);
                }
            }
            let next = match (&mut self.forward, fresh.as_mut()) {
                (Forward::Learned(l), _) => {
                    x.c = c;
                    let v = l.model.twist(m, &x, a);
                    x = l.model.advance(&x, &v, step);
                    Isometry3::from_parts(x.p.into(), x.r)
                }
                (Forward::Map { copies, .. }, f) => {
                    let Some(model) = f.or_else(|| copies.get_mut(m)) else {
                        return f64::INFINITY;
                    };
                    model.map.eval(&q[..n], c, &a, &mut self.out[..n]);
                    let before = q;
                    for (qj, v) in q[..n].iter_mut().zip(&self.out[..n]) {
                        if v.is_finite() {
                            *qj += v * self.speed_scale * step;
                        }
                    }
                    // The position rule's stop: a step that takes a joint further past its
                    // margin is not taken (the filter stops the whole arm there).
                    let past = |j: usize, (lo, hi): (f64, f64)| {
                        (q[j] > hi && q[j] > before[j]) || (q[j] < lo && q[j] < before[j])
                    };
                    if self
                        .joint_bounds
                        .iter()
                        .take(n)
                        .enumerate()
                        .any(|(j, b)| past(j, *b))
                    {
                        q = before;
                    }
                    chain.clamp_to_limits(&mut q[..n]);
                    // The whole-arm stop: a step that brings a pair of the collision model
                    // closer than the stop distance is not taken.
                    if let Some((arm, stop)) = self.whole_arm.as_mut()
                        && arm.update(&q[..n], c)
                        && let Some((d, _)) = arm.closest()
                    {
                        if d < *stop && d < clearance {
                            q = before;
                        } else {
                            clearance = d;
                        }
                    }
                    let Ok(next) = chain.fk(&q[..n]) else {
                        return f64::INFINITY;
                    };
                    next
                }
            };
            tool = next;
            p = tool.translation.vector;
            let e = match (&mut run, target) {
                (Some(run), _) => {
                    let before = run.subgoals_done();
                    run.update(&tool, c, step);
                    let wrist = match self.forward {
                        Forward::Map { .. } => q[n.saturating_sub(1)],
                        Forward::Learned(_) => wrist,
                    };
                    aim = run.aim(&tool, wrist);
                    let done = run.subgoals_done() - before;
                    bonus += done as f64 * SUBGOAL_M * (2.0 - i as f64 / h as f64);
                    aim.map_or(0.0, |g| {
                        aim_error(&g, &p, &tool.rotation, tilt_weight, face_weight)
                    })
                }
                (None, Target::Point(w)) => (w - p).norm(),
                (None, Target::Task) => 0.0,
            };
            let off_route = match (&self.route, target) {
                (Some(route), Target::Task) => {
                    self.ex.route_weight
                        * (route.distance(&p, c >= 0.5) - self.ex.route_radius_m).max(0.0)
                }
                _ => 0.0,
            };
            let turn = if self.rotation_weight > 0.0 {
                let tilt_asked = aim.is_some_and(|g| g.tilt.is_some());
                self.rotation_weight * unasked_turn(&seen.tool.rotation, &tool.rotation, tilt_asked)
            } else {
                0.0
            };
            cost += e + turn + off_route;
        }
        self.predicted_q = q;
        cost / h as f64 - bonus
    }

    /// One MPPI step of the plan in mode `m`: the best cost among the sequences tried and the
    /// cost of rest.
    fn optimise(
        &mut self,
        m: usize,
        cur: usize,
        seen: &Seen<'_>,
        target: Target,
        rng: &mut Rng,
    ) -> (f64, f64) {
        let lead = self.lead(m, cur);
        let free = self.knots.saturating_sub(lead.len());
        let stick = if m == cur { self.hand.stick } else { [0.0; 2] };
        let plan = self.plans.get(m).cloned().unwrap_or_default();
        let s = self.ex.spread;
        self.seqs.clear();
        self.seqs.push(plan[..free.min(plan.len())].to_vec());
        self.seqs.push(vec![[0.0; 2]; free]);
        for k in 0..self.ex.samples {
            let seq: Vec<[f64; 2]> = if k % 2 == 0 {
                let off = [s * rng.normal(), s * rng.normal()];
                (0..free)
                    .map(|i| {
                        let base = plan.get(i).copied().unwrap_or([0.0; 2]);
                        disc([
                            base[0] + off[0] + 0.5 * s * rng.normal(),
                            base[1] + off[1] + 0.5 * s * rng.normal(),
                        ])
                    })
                    .collect()
            } else {
                let r = rng.uniform().sqrt();
                let th = rng.range(0.0, std::f64::consts::TAU);
                vec![[r * th.cos(), r * th.sin()]; free]
            };
            self.seqs.push(seq);
        }
        let seqs = std::mem::take(&mut self.seqs);
        self.costs.clear();
        for seq in &seqs {
            let j = self.rollout(m, &lead, seq, stick, seen, target);
            self.costs.push(j);
        }
        let rest = self.costs.get(1).copied().unwrap_or(f64::INFINITY);
        let finite = self.costs.iter().copied().filter(|j| j.is_finite());
        let (min, sum, count) = finite.fold((f64::INFINITY, 0.0, 0usize), |(lo, s, n), j| {
            (lo.min(j), s + j, n + 1)
        });
        if count > 0 && free > 0 {
            let mean = sum / count as f64;
            let lambda = (self.ex.temperature * (mean - min)).max(1e-12);
            let mut acc = vec![[0.0; 2]; free];
            let mut total = 0.0;
            for (seq, j) in seqs.iter().zip(&self.costs) {
                if !j.is_finite() {
                    continue;
                }
                let w = (-(j - min) / lambda).exp();
                total += w;
                for (a, u) in acc.iter_mut().zip(seq) {
                    a[0] += w * u[0];
                    a[1] += w * u[1];
                }
            }
            if total > 0.0
                && let Some(plan) = self.plans.get_mut(m)
            {
                for (pk, a) in plan.iter_mut().zip(&acc) {
                    *pk = disc([a[0] / total, a[1] / total]);
                }
            }
        }
        self.seqs = seqs;
        (min, rest)
    }

    /// Moves every plan (but the one of a mode being switched to) one tick on.
    fn shift_plans(&mut self) {
        let f = (1.0 / self.ticks_per_knot).min(1.0);
        for (m, plan) in self.plans.iter_mut().enumerate() {
            if self.switching_to == Some(m) {
                continue;
            }
            let n = plan.len();
            for i in 0..n {
                let next = plan.get(i + 1).copied().unwrap_or(plan[i]);
                plan[i] = [
                    plan[i][0] * (1.0 - f) + next[0] * f,
                    plan[i][1] * (1.0 - f) + next[1] * f,
                ];
            }
        }
    }

    /// Tracks progress; backs off when there has been none for a while. The target to plan
    /// for.
    fn progress(&mut self, seen: &Seen<'_>, aim: &Aim, rng: &mut Rng) -> Target {
        let p = seen.tool.translation.vector;
        let now =
            seen.run.subgoals_done() as f64 * SUBGOAL_M - self.error(aim, &p, &seen.tool.rotation);
        if let Some((w, left)) = self.back_off {
            if left > 1 {
                self.back_off = Some((w, left - 1));
                return Target::Point(w);
            }
            self.back_off = None;
            self.best_progress = now;
            self.stale_ticks = 0;
        }
        if now > self.best_progress + PROGRESS_M {
            self.best_progress = now;
            self.stale_ticks = 0;
        } else {
            self.stale_ticks += 1;
        }
        let back_off_ticks = (self.ex.back_off_s / self.dt).round() as u32;
        if f64::from(self.stale_ticks) * self.dt >= self.ex.stuck_s && back_off_ticks > 0 {
            let d = Vector3::new(rng.normal(), rng.normal(), rng.normal().abs());
            let d = if d.norm() > 1e-9 {
                d / d.norm()
            } else {
                Vector3::z()
            };
            let w = p + d * self.ex.back_off_m;
            tracing::trace!(at = ?p.as_slice(), to = ?w.as_slice(), "the expert operator backs off");
            self.back_off = Some((w, back_off_ticks));
            self.stale_ticks = 0;
            return Target::Point(w);
        }
        Target::Task
    }
}

/// The distance to `aim` at `p` with the tilt `t` (a tilt error weighs `tilt_weight` m per
/// rad).
fn aim_error(
    aim: &Aim,
    p: &Vector3<f64>,
    r: &nalgebra::UnitQuaternion<f64>,
    tilt_weight: f64,
    face_weight: f64,
) -> f64 {
    let t = tilt(r);
    let e = aim.distance(p) + face_weight * aim.facing_error(r);
    match aim.tilt {
        Some(goal) => e + tilt_weight * (goal - t).abs(),
        None => e,
    }
}

/// How far the tool turned from `now` to `then` in ways the subgoal does not ask for (rad):
/// the whole turn, or with a tilt asked for, the turn of the approach axis (tool z) alone.
fn unasked_turn(
    now: &nalgebra::UnitQuaternion<f64>,
    then: &nalgebra::UnitQuaternion<f64>,
    tilt_asked: bool,
) -> f64 {
    if tilt_asked {
        let a = now * Vector3::z();
        let b = then * Vector3::z();
        a.dot(&b).clamp(-1.0, 1.0).acos()
    } else {
        now.angle_to(then)
    }
}

/// `u` brought into the stick's disc.
fn disc(u: [f64; 2]) -> [f64; 2] {
    let n = u[0].hypot(u[1]);
    if n > 1.0 { [u[0] / n, u[1] / n] } else { u }
}

impl Operate for Expert<'_> {
    fn act(&mut self, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
        let mut buttons_now = buttons::DEADMAN;
        let mut gripper = 0.0f32;
        let mut choice = [0.0; 2];
        let found = self
            .aim_out
            .as_ref()
            .and_then(|c| c.lock().ok().map(|e| *e));
        if let Forward::Learned(l) = &mut self.forward {
            l.see(seen);
        }
        self.shift_plans();
        if let Some(b) = self.button.tick() {
            buttons_now |= b;
        } else if let Some(aim) = seen.aim {
            self.switching_to = None;
            let n = (seen.state.n_joints as usize).min(MAX_JOINTS);
            self.clearance_now = f64::INFINITY;
            if let Some((arm, _)) = self.whole_arm.as_mut()
                && arm.update(&seen.state.q()[..n], seen.state.gripper)
                && let Some((d, _)) = arm.closest()
            {
                self.clearance_now = d;
            }
            let p = seen.tool.translation.vector;
            let target = self.progress(seen, &aim, rng);
            let cur = seen.mode.unwrap_or(0).min(self.modes - 1);
            let (best, rest) = self.optimise(cur, cur, seen, target, rng);
            choice = self
                .plans
                .get(cur)
                .and_then(|p| p.first())
                .copied()
                .unwrap_or([0.0; 2]);
            let check = ((self.ex.mode_check_s / self.dt).round() as u64).max(1);
            // Unlike the greedy operator it also weighs a switch within the position
            // tolerance: table cleaning's pushes start from a point 1.5 cm behind the object.
            if self.modes > 1 && self.ticks.is_multiple_of(check) {
                let gain = rest - best;
                let mut other: Option<(usize, f64)> = None;
                for m in (0..self.modes).filter(|&m| m != cur) {
                    let (bm, _) = self.optimise(m, cur, seen, target, rng);
                    if other.is_none_or(|(_, g)| rest - bm > g) {
                        other = Some((m, rest - bm));
                    }
                }
                tracing::trace!(cur, best, rest, ?other, "the planner weighs the modes");
                if let Some((m, g)) = other
                    && g > (1.0 + self.switch_margin) * gain.max(0.0) + SWITCH_MIN_M
                {
                    // A slip: one press too many; it sees the mode it got and goes on from
                    // there.
                    let to = if self.slip > 0.0 && rng.uniform() < self.slip {
                        (m + 1) % self.modes
                    } else {
                        m
                    };
                    self.button
                        .switch(cur, to, self.modes, self.params.mode_switch_s, self.dt);
                    self.switching_to = Some(to);
                    self.hand.let_go();
                    choice = [0.0; 2];
                }
            }
            if let Some(close) = aim.grip
                && aim.distance(&p) <= self.tol.position_m
            {
                gripper = if close { 1.0 } else { -1.0 };
            }
        }
        if let (Some(cell), Some(found)) = (&self.aim_out, found)
            && let Ok(mut e) = cell.lock()
        {
            *e = found;
        }
        self.ticks += 1;
        let resting = self.button.busy();
        let joy = self.hand.sample(
            &self.params,
            self.dt,
            choice,
            resting,
            seen.state,
            seen.t_ns,
            gripper,
            buttons_now,
            rng,
        );
        if let Forward::Learned(l) = &mut self.forward {
            l.sent(&joy);
        }
        joy
    }

    fn presses(&self) -> u32 {
        self.button.presses()
    }

    fn into_learned(self: Box<Self>) -> Option<InternalModel> {
        match self.forward {
            Forward::Learned(l) => Some(l.model),
            Forward::Map { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::operator::AtRest;
    use learning::tasks::Task;

    /// The prediction stops the whole arm where a joint would pass its margin, as the
    /// filter's position rule does (it scales the whole command): with every joint's bounds
    /// a milliradian around the start, a plan that moves the arm is predicted not to move it
    /// at all; with the arm's own bounds it moves.
    #[test]
    fn the_prediction_stops_the_arm_at_a_joint_margin() {
        let robot = RobotProfile::default_robot();
        let safety = safety::SafetyConfig::for_robot(robot);
        let make = || {
            LoadedModel::load_for("modeswitch", robot)
                .map(|m| m.at_period(0.025))
                .map_err(|e| SimError::Setup(e.to_string()))
        };
        let q0 = [0.0, -0.35, 1.9, 1.57, 0.9, 0.0];
        let at = AtRest::new(robot, Task::PickAndPlace, &q0);
        let (n, seen) = (robot.n_joints(), at.seen(Some(0)));
        let ahead = Target::Point(at.tool.translation.vector + Vector3::x());
        let mut moved = Vec::new();
        for tight in [true, false] {
            let mut ex = Expert::new(
                &SimParams::default(),
                robot,
                &safety,
                Tolerances::default(),
                0.025,
                &make,
                None,
                None,
            )
            .unwrap();
            ex.whole_arm = None;
            if tight {
                ex.joint_bounds = q0.iter().map(|q| (q - 1e-3, q + 1e-3)).collect();
            }
            let plan = vec![[1.0, 0.0]; ex.knots];
            let j = ex.rollout(0, &[], &plan, [0.0; 2], &seen, ahead);
            assert!(j.is_finite());
            let d: f64 = ex.predicted_q[..n]
                .iter()
                .zip(&q0)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            moved.push(d);
        }
        assert!(moved[0] <= 1e-3 + 1e-12 && moved[1] > 0.05, "{moved:?}");
    }

    /// The prediction stops the arm where the safety filter's whole-arm rule stops it: mode
    /// switching's z axis (z-yaw's second) held down from table cleaning's start (the tool
    /// 6.5 cm over the table) keeps every pair of the collision model at the stop distance or more, where the map
    /// alone would take the gripper into the table.
    #[test]
    fn the_prediction_stops_at_the_whole_arm_stop_distance() {
        let robot = RobotProfile::default_robot();
        let safety = safety::SafetyConfig::for_robot(robot);
        let make = || {
            LoadedModel::load_for("modeswitch", robot)
                .map(|m| m.at_period(0.025))
                .map_err(|e| SimError::Setup(e.to_string()))
        };
        let q0 = learning::tasks::start_pose(robot, Task::TableCleaning).unwrap();
        let at = AtRest::new(robot, Task::TableCleaning, &q0);
        let (n, seen) = (robot.n_joints(), at.seen(Some(1)));
        let down = Target::Point(at.tool.translation.vector - Vector3::z());
        let mut lowest = Vec::new();
        for with_rule in [true, false] {
            let mut ex = Expert::new(
                &SimParams::default(),
                robot,
                &safety,
                Tolerances::default(),
                0.025,
                &make,
                None,
                None,
            )
            .unwrap();
            assert_eq!(ex.modes, 3);
            if !with_rule {
                ex.whole_arm = None;
            }
            let plan = vec![[0.0, -1.0]; ex.knots];
            let j = ex.rollout(1, &[], &plan, [0.0; 2], &seen, down);
            assert!(j.is_finite());
            let q = &ex.predicted_q[..n];
            let mut arm = WholeArm::new(robot, safety.scene.scene().unwrap()).unwrap();
            assert!(arm.update(q, 0.0));
            let (d, _) = arm.closest().unwrap();
            lowest.push((robot.arm().fk(q).unwrap().translation.z, d));
        }
        let [(z_rule, d_rule), (z_map, d_map)] = lowest[..] else {
            unreachable!()
        };
        assert!(d_rule >= safety.stop_distance_m - 1e-9, "{lowest:?}");
        assert!(
            d_map < safety.stop_distance_m && z_map < z_rule,
            "{lowest:?}"
        );
    }
}
