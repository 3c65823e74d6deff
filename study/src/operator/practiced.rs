//! The practiced operator (`operator = "practiced"`): a person after the practice phase. It
//! never evaluates the map. In the study's practice time (`practice_s` of the task, with the
//! condition's map served) it learns an internal model of the map ([`InternalModel`]) from
//! what it sees: the stick it pushed and the tool's resulting motion at the states it visited.
//! Practice has two parts:
//!
//! 1. **Trying the stick** (`Explorer`): from the task's start pose, in each mode the screen
//!    shows, it pushes the stick in a random direction and back ([`PracticedParams::explore_s`]
//!    per mode), then presses the mode button for the next, until the modes come round.
//! 2. **Practising the task**: attempts of the task from the start pose, planned with what it
//!    has learned so far and learning on, until the practice time is used.
//!
//! Then it does the study's attempts with what practice taught, learning no more (the
//! attempts measure the practice; each is independent of the one before). It plans like the
//! expert operator (model-predictive path integral control over stick sequences and mode
//! presses, [`PracticedParams::planner`]) with its internal model in place of the map, and has
//! the same person's limits: reaction delay, input noise, bounded stick rate, time to press the
//! mode button, backing off when it makes no progress.
//!
//! What it may query is exactly what it observed: `expert::Learner` takes
//! the tool's pose each tick and the sample it sent; nothing else of the map reaches it.

use ipc_types::{JoystickInput, buttons};
use mapper::rng::Rng;
use serde::{Deserialize, Serialize};

use super::expert::{ExpertParams, Learner};
use super::internal::{InternalModel, Widths};
use super::{Hand, ModeButton, Operate, Seen};
use crate::simulate::{ModelFactory, SimParams};

/// The practiced operator's parameters: `[simulation.practiced]` of the study file. Set once
/// by the calibration on mode switching (`scripts/calibrate-practiced.sh`), the same for
/// every condition and map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PracticedParams {
    /// How long it tries the stick in each mode at the start of practice (s). Default 10.
    pub explore_s: f64,
    /// How far apart two tool positions are for its model (m): the kernel's width. Default
    /// 0.05.
    pub position_width_m: f64,
    /// How far apart two tool orientations are for its model (rad). Default 0.35 (20°).
    pub angle_width_rad: f64,
    /// Press the mode button when another mode's plan gains this fraction more than the
    /// current one's (the calibrated key). Default 0.25.
    pub mode_switch_margin: f64,
    /// The chance that a mode switch it decides on ends one press too far (the thumb slips
    /// or loses count); it then sees the mode it got and switches again if it must. The
    /// calibrated key: set so that its presses on pouring with mode switching match the
    /// paper's participants (17.55 per attempt). Default 0.8, the calibrated value
    /// (`scripts/calibrate-practiced.sh`, 13 participants, 2026-11-27: 16.5 presses per
    /// pouring attempt; docs/simulated-participants.md). It stands in for every reason people
    /// press more than this planner does.
    pub mode_slip: f64,
    /// A turn of the tool the subgoal does not ask for costs this much in its plans (m per
    /// rad): a person keeps the tool's orientation unless the task needs it turned, and so
    /// does not wind the wrist into its joint limits. Default 0.05.
    pub rotation_weight_m_per_rad: f64,
    /// Its planner (`[simulation.practiced.planner]`: the keys of `[simulation.expert]`).
    pub planner: ExpertParams,
}

impl Default for PracticedParams {
    fn default() -> Self {
        Self {
            explore_s: 10.0,
            position_width_m: 0.05,
            angle_width_rad: 0.35,
            mode_switch_margin: 0.25,
            rotation_weight_m_per_rad: 0.05,
            mode_slip: 0.8,
            planner: ExpertParams::default(),
        }
    }
}

impl PracticedParams {
    /// Checks the values; the error names the key (within `[simulation.practiced]`).
    pub fn check(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, r: &str| Err((k.to_owned(), r.to_owned()));
        for (k, v) in [
            ("position_width_m", self.position_width_m),
            ("angle_width_rad", self.angle_width_rad),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(k, "must be positive");
            }
        }
        if !(0.0..=1.0).contains(&self.mode_slip) {
            return bad("mode_slip", "must be 0 to 1");
        }
        for (k, v) in [
            ("explore_s", self.explore_s),
            ("mode_switch_margin", self.mode_switch_margin),
            ("rotation_weight_m_per_rad", self.rotation_weight_m_per_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(k, "must be 0 or more");
            }
        }
        self.planner
            .check()
            .map_err(|(k, r)| (format!("planner.{k}"), r))
    }

    /// The internal model's kernel widths.
    pub fn widths(&self) -> Widths {
        Widths {
            position_m: self.position_width_m,
            angle_rad: self.angle_width_rad,
            gripper: 0.5,
        }
    }
}

/// The first part of practice: it tries the stick in random directions in each mode, learning
/// what each does, and presses the mode button for the next mode until the modes come round.
pub(crate) struct Explorer {
    params: SimParams,
    dt: f64,
    hand: Hand,
    learner: Learner,
    button: ModeButton,
    /// Ticks spent in the mode now.
    in_mode: u32,
    /// The direction held and the ticks left of it.
    hold: ([f64; 2], u32),
    /// Pushes so far (every second one undoes the one before).
    pushes: u32,
    /// Modes tried so far.
    modes_tried: usize,
    finished: bool,
}

/// One push of the stick while trying it (s), then a rest as long as a quarter of it.
const PUSH_S: f64 = 0.6;

impl Explorer {
    pub(crate) fn new(params: &SimParams, dt: f64, model: InternalModel) -> Self {
        Self {
            params: params.clone(),
            dt,
            hand: Hand::new(params, dt),
            learner: Learner::new(model, true, dt),
            button: ModeButton::default(),
            in_mode: 0,
            hold: ([0.0; 2], 0),
            pushes: 0,
            modes_tried: 0,
            finished: false,
        }
    }
}

impl Operate for Explorer {
    fn act(&mut self, _make: &ModelFactory<'_>, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
        self.learner.see(seen);
        let mut buttons_now = buttons::DEADMAN;
        let mut choice = [0.0; 2];
        let per_mode = (self.params.practiced.explore_s / self.dt).round() as u32;
        if let Some(b) = self.button.tick() {
            buttons_now |= b;
        } else if self.modes_tried > 0 && self.in_mode == 0 && seen.mode == Some(0) {
            // The presses brought the first mode back: every mode is tried.
            self.finished = true;
        } else if self.in_mode >= per_mode {
            // This mode is tried: on to the next one (a map without modes has one).
            self.modes_tried += 1;
            let mode = seen.mode.unwrap_or(0);
            if seen.mode.is_none() || self.modes_tried >= 8 {
                self.finished = true;
            } else {
                self.button
                    .switch(mode, mode + 1, mode + 2, self.params.mode_switch_s, self.dt);
                self.hand.let_go();
                self.in_mode = 0;
                self.hold = ([0.0; 2], 0);
                self.pushes = 0;
            }
        } else {
            self.in_mode += 1;
            let push = (PUSH_S / self.dt).round().max(1.0) as u32;
            if self.hold.1 == 0 {
                // A push, then the push back: the tool stays about where it started.
                self.pushes += 1;
                self.hold.0 = if self.pushes.is_multiple_of(2) {
                    [-self.hold.0[0], -self.hold.0[1]]
                } else {
                    let th = rng.range(0.0, std::f64::consts::TAU);
                    let r = rng.range(0.5, 1.0);
                    [r * th.cos(), r * th.sin()]
                };
                self.hold.1 = push + push / 4;
            }
            self.hold.1 -= 1;
            if self.hold.1 >= push / 4 {
                choice = self.hold.0;
            }
        }
        let resting = self.button.busy();
        let joy = self.hand.sample(
            &self.params,
            self.dt,
            choice,
            resting,
            seen.state,
            seen.t_ns,
            0.0,
            buttons_now,
            rng,
        );
        self.learner.sent(&joy);
        joy
    }

    fn presses(&self) -> u32 {
        self.button.presses()
    }

    fn finished(&self) -> bool {
        self.finished
    }

    fn into_learned(self: Box<Self>) -> Option<InternalModel> {
        Some(self.learner.model)
    }
}
