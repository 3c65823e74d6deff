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

use super::expert::Learner;
use super::internal::InternalModel;
use super::{Hand, ModeButton, Operate, Seen};
use crate::setup::SimParams;

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
    fn act(&mut self, seen: &Seen<'_>, rng: &mut Rng) -> JoystickInput {
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
