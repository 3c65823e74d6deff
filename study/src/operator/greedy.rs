//! The greedy operator (`operator = "greedy"`, the default): each tick it draws
//! [`SimParams::candidates`] stick inputs uniformly over the stick's disc (plus rest and its
//! current input) and picks the one whose tool pose one tick ahead through the served map
//! (`qdot = map(q, c, a)`, the tool's twist `J(q) qdot`) is closest to the subgoal. It closes
//! or opens the gripper when a grip subgoal's point is within the tolerance. With a map that
//! has modes it presses the mode button when another mode would reduce the error by
//! [`SimParams::mode_switch_margin`] more than the current one, letting go of the stick for
//! [`SimParams::mode_switch_s`]; every press is counted. It never looks further than one tick
//! and never backs off: the lower bound of what a map allows.

use ipc_types::{JoystickInput, MAX_JOINTS, RobotState, buttons};
use kinematics::Jacobian;
use learning::goals::{Aim, Tolerances, tilt};
use mapper::LoadedModel;
use mapper::rng::Rng;
use nalgebra::{Isometry3, Vector3};

use super::{Hand, ModeButton, Operate, Seen};
use crate::setup::{ModelFactory, SimError, SimParams};

/// The operator's copies of the served map, one per mode, to try candidates on. A map with
/// modes (mode switching) keeps state between ticks (its twist ramps under acceleration
/// limits), so each candidate is tried on a fresh copy in that mode: what the input does
/// from rest, which is what a person learns of it.
pub struct Probes<'a> {
    maps: Vec<LoadedModel>,
    stateful: bool,
    /// Fresh copies for a map with modes.
    make: &'a ModelFactory<'a>,
}

impl<'a> Probes<'a> {
    /// One copy of the served map per mode, made by `make` (which a map with modes keeps
    /// using: a fresh copy per candidate).
    pub fn new(make: &'a ModelFactory<'a>) -> Result<Self, SimError> {
        let first = make()?;
        if first.map.mode().is_none() {
            return Ok(Self {
                maps: vec![first],
                stateful: false,
                make,
            });
        }
        let mut maps = vec![first];
        for k in 1..8u32 {
            let mut m = make()?;
            for _ in 0..k {
                m.map.press(buttons::MODE);
            }
            if m.map.mode().is_some_and(|x| x.index == 0) {
                break;
            }
            maps.push(m);
        }
        Ok(Self {
            maps,
            stateful: true,
            make,
        })
    }

    /// Mode `m`'s output for action `a` at `(q, c)` into `out`; the speed scale.
    pub(crate) fn eval(
        &mut self,
        m: usize,
        q: &[f64],
        c: f64,
        a: &[f64],
        out: &mut [f64],
    ) -> Option<f64> {
        if self.stateful {
            let mut copy = (self.make)().ok()?;
            for _ in 0..m {
                copy.map.press(buttons::MODE);
            }
            *self.maps.get_mut(m)? = copy;
        }
        let model = self.maps.get_mut(m)?;
        model.map.eval(q, c, a, out);
        Some(model.header.speed_scale_rad_s)
    }
}

/// The greedy operator of one attempt.
pub(crate) struct Greedy<'a> {
    params: SimParams,
    tol: Tolerances,
    dt: f64,
    probes: Probes<'a>,
    hand: Hand,
    /// What the operator chose last.
    chosen: [f64; 2],
    /// The mode button, pressed as a person does.
    button: ModeButton,
    cands: Vec<[f64; 2]>,
    out: [f64; MAX_JOINTS],
}

impl<'a> Greedy<'a> {
    pub(crate) fn new(params: &SimParams, tol: Tolerances, dt: f64, probes: Probes<'a>) -> Self {
        Self {
            params: params.clone(),
            tol,
            dt,
            probes,
            hand: Hand::new(params, dt),
            chosen: [0.0; 2],
            button: ModeButton::default(),
            cands: Vec::with_capacity(params.candidates + 2),
            out: [0.0; MAX_JOINTS],
        }
    }

    fn error(&self, p: &Vector3<f64>, t: f64, aim: &Aim) -> f64 {
        let e = aim.distance(p);
        match aim.tilt {
            Some(goal) => e + self.params.tilt_weight_m_per_rad * (goal - t).abs(),
            None => e,
        }
    }

    /// The best candidate in mode `m` and its error one tick ahead.
    fn best(
        &mut self,
        m: usize,
        state: &RobotState,
        tool: &Isometry3<f64>,
        jac: &Jacobian,
        aim: &Aim,
    ) -> ([f64; 2], f64) {
        let n = state.n_joints as usize;
        let p = tool.translation.vector;
        let z = tool.rotation * Vector3::z();
        let t0 = tilt(&tool.rotation);
        let mut best = ([0.0; 2], f64::INFINITY);
        for a in &self.cands {
            let Some(scale) = self
                .probes
                .eval(m, state.q(), state.gripper, a, &mut self.out[..n])
            else {
                continue;
            };
            let v = super::tool_twist(jac, &self.out[..n], scale);
            let pn = p + Vector3::new(v[0], v[1], v[2]) * self.dt;
            let tn = t0 + Vector3::new(v[3], v[4], v[5]).dot(&z) * self.dt;
            let e = {
                let e = aim.distance(&pn);
                match aim.tilt {
                    Some(goal) => e + self.params.tilt_weight_m_per_rad * (goal - tn).abs(),
                    None => e,
                }
            };
            if e < best.1 {
                best = (*a, e);
            }
        }
        best
    }

    /// This tick's joystick sample.
    #[allow(clippy::too_many_arguments)]
    fn answer(
        &mut self,
        state: &RobotState,
        tool: &Isometry3<f64>,
        jac: &Jacobian,
        aim: Option<Aim>,
        mode: Option<usize>,
        t_ns: u64,
        rng: &mut Rng,
    ) -> JoystickInput {
        let mut buttons_now = buttons::DEADMAN;
        let mut gripper = 0.0f32;
        let mut choice = [0.0; 2];
        if let Some(b) = self.button.tick() {
            buttons_now |= b;
        } else if let Some(aim) = aim {
            let p = tool.translation.vector;
            let now = self.error(&p, tilt(&tool.rotation), &aim);
            super::draw_candidates(&mut self.cands, self.chosen, self.params.candidates, rng);
            let cur = mode.unwrap_or(0);
            let (a, e) = self.best(cur, state, tool, jac, &aim);
            choice = a;
            let modes = self.probes.maps.len();
            // Within the tolerance of a position (a grip, the end of a reach) there is nothing
            // to switch for.
            // A zone (a lift, over the mark) is done once the tool is in it: never settled
            // short of it.
            let settled = aim.tilt.is_none()
                && aim.zone == learning::goals::Zone::Point
                && aim.distance(&p) <= self.tol.position_m;
            if modes > 1 && !settled {
                let gain = now - e;
                let mut other: Option<(usize, f64)> = None;
                for m in (0..modes).filter(|&m| m != cur) {
                    let (_, em) = self.best(m, state, tool, jac, &aim);
                    if other.is_none_or(|(_, g)| now - em > g) {
                        other = Some((m, now - em));
                    }
                }
                if let Some((m, g)) = other
                    && g > (1.0 + self.params.mode_switch_margin) * gain.max(0.0) + 1e-5
                {
                    // Let go of the stick, press until the mode comes round, rest.
                    self.button
                        .switch(cur, m, modes, self.params.mode_switch_s, self.dt);
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
        self.chosen = choice;
        let resting = self.button.busy();
        self.hand.sample(
            &self.params,
            self.dt,
            choice,
            resting,
            state,
            t_ns,
            gripper,
            buttons_now,
            rng,
        )
    }
}

impl Operate for Greedy<'_> {
    fn act(&mut self, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
        self.answer(
            seen.state, seen.tool, seen.jac, seen.aim, seen.mode, seen.t_ns, rng,
        )
    }

    fn presses(&self) -> u32 {
        self.button.presses()
    }
}
