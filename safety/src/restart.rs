//! Restart prevention (IEC 60204-1: no unexpected start-up after a stop): once a fault has
//! stopped the arm, and at start-up, motion resumes only after the operator's input has
//! passed through neutral. A small state machine, `fault -> awaiting neutral -> armed`,
//! driven once per tick by the filter with what the mapper's command says of the input.
//!
//! Neutral means the stick at rest (`|a| <= NEUTRAL_MAX_ACTION`) and, when the deadman is
//! required, the deadman released and pressed again since the stop, both at once at the
//! tick that arms: a released-and-pressed deadman with the stick still deflected waits for
//! the stick. A map that ignores the action by design (the drill map) needs only the deadman
//! when it is required, else the stick at rest all the same.
//!
//! Only a usable sample that answers a robot tick tells anything: a missing, non-finite or
//! stale one (whose action the mapper zeroed), one from a device that is gone (the last three
//! are faults themselves) or one published before its source saw a tick (a joystick's start-up
//! sample, flagged `input-no-tick` by the mapper) is not the operator at neutral.

/// Largest action length `|a|` that counts as the stick at rest. The evdev source applies its
/// mapping's radial deadzone (inside it the axes are exactly 0), the keyboard source ramps to
/// 0 and scripts are exact, so any stick at rest reads well below it.
pub const NEUTRAL_MAX_ACTION: f64 = 0.05;

/// The operator's input at one tick, from a usable joystick sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Operator {
    /// Length of the action fed to the map.
    pub action_norm: f64,
    /// The deadman button is held.
    pub deadman: bool,
    /// The map uses the action (false: it ignores it by design).
    pub uses_input: bool,
}

/// Where the guard is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestartState {
    /// A fault stopped the arm (or the graph just started): no motion until neutral input.
    AwaitingNeutral {
        /// The deadman was seen released since the stop.
        deadman_released: bool,
    },
    /// The input passed through neutral: commands go through.
    Armed,
}

/// The restart-prevention state machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RestartGuard {
    deadman_required: bool,
    state: RestartState,
}

impl RestartGuard {
    /// A guard awaiting neutral input: the first motion after start-up needs a deliberate
    /// action too. `deadman_required`: `[safety] deadman`.
    pub fn new(deadman_required: bool) -> Self {
        Self {
            deadman_required,
            state: RestartState::AwaitingNeutral {
                deadman_released: false,
            },
        }
    }

    /// The current state.
    pub fn state(&self) -> RestartState {
        self.state
    }

    /// Whether commands go through.
    pub fn armed(&self) -> bool {
        self.state == RestartState::Armed
    }

    /// A fault that happened between ticks (missed ticks, a command the bridge did not
    /// execute): awaiting neutral from now on; this tick's input may already re-arm.
    pub fn interrupt(&mut self) {
        self.state = RestartState::AwaitingNeutral {
            deadman_released: false,
        };
    }

    /// One tick: `fault` whether a fault stops the arm this tick, `input` the operator's
    /// input if this tick's sample is usable. Returns whether the guard is armed afterwards.
    pub fn tick(&mut self, fault: bool, input: Option<Operator>) -> bool {
        let released = input.is_some_and(|i| !i.deadman);
        if fault {
            // A release seen now counts for the re-arming after the fault.
            self.state = RestartState::AwaitingNeutral {
                deadman_released: released,
            };
            return false;
        }
        let RestartState::AwaitingNeutral { deadman_released } = &mut self.state else {
            return true;
        };
        let Some(i) = input else {
            return false;
        };
        *deadman_released |= released;
        let stick = (self.deadman_required && !i.uses_input) || i.action_norm <= NEUTRAL_MAX_ACTION;
        let deadman = !self.deadman_required || (*deadman_released && i.deadman);
        if stick && deadman {
            self.state = RestartState::Armed;
        }
        self.armed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn stick(norm: f64) -> Option<Operator> {
        Some(Operator {
            action_norm: norm,
            deadman: false,
            uses_input: true,
        })
    }

    fn with_deadman(norm: f64, held: bool, uses_input: bool) -> Option<Operator> {
        Some(Operator {
            action_norm: norm,
            deadman: held,
            uses_input,
        })
    }

    #[test]
    fn start_up_waits_for_the_stick_at_rest() {
        let mut g = RestartGuard::new(false);
        assert!(!g.armed());
        assert!(!g.tick(false, stick(0.8)));
        assert!(!g.tick(false, None), "no sample is not neutral");
        assert!(g.tick(false, stick(NEUTRAL_MAX_ACTION)));
        assert!(g.tick(false, stick(1.0)), "armed: the stick moves the arm");
    }

    #[test]
    fn a_fault_waits_for_neutral_then_arms() {
        let mut g = RestartGuard::new(false);
        g.tick(false, stick(0.0));
        assert!(
            !g.tick(true, stick(0.0)),
            "no arming during the fault itself"
        );
        assert!(
            !g.tick(false, stick(0.7)),
            "deflected after the fault: still waiting"
        );
        assert!(!g.tick(false, stick(0.06)));
        assert!(g.tick(false, stick(0.01)));
        assert!(g.tick(false, stick(0.9)));
        assert_eq!(g.state(), RestartState::Armed);
    }

    #[test]
    fn an_interruption_between_ticks_rearms_at_a_neutral_tick_at_once() {
        let mut g = RestartGuard::new(false);
        g.tick(false, stick(0.0));
        g.interrupt();
        assert!(g.tick(false, stick(0.0)));
        g.interrupt();
        assert!(!g.tick(false, stick(0.5)));
        assert!(!g.tick(false, None));
        assert!(g.tick(false, stick(0.0)));
    }

    #[test]
    fn with_the_deadman_it_must_be_released_and_pressed_with_the_stick_at_rest() {
        let mut g = RestartGuard::new(true);
        // Held all along, stick at rest: not enough.
        assert!(!g.tick(false, with_deadman(0.0, true, true)));
        assert!(!g.tick(false, with_deadman(0.0, false, true)));
        // Pressed again with the stick deflected: waits for the stick.
        assert!(!g.tick(false, with_deadman(0.6, true, true)));
        assert!(g.tick(false, with_deadman(0.0, true, true)));
        // A fault while held: release and press again.
        assert!(!g.tick(true, with_deadman(0.0, true, true)));
        assert!(!g.tick(false, with_deadman(0.0, true, true)));
        // A release during the fault counts.
        assert!(!g.tick(true, with_deadman(0.0, false, true)));
        assert!(g.tick(false, with_deadman(0.0, true, true)));
    }

    #[test]
    fn a_map_that_ignores_the_stick_needs_the_deadman_or_else_the_stick() {
        let mut g = RestartGuard::new(true);
        assert!(!g.tick(false, with_deadman(0.9, false, false)));
        assert!(g.tick(false, with_deadman(0.9, true, false)));
        // Without the deadman the stick at rest still applies.
        let mut g = RestartGuard::new(false);
        assert!(!g.tick(false, with_deadman(0.9, false, false)));
        assert!(g.tick(false, with_deadman(0.0, false, false)));
    }

    proptest! {
        /// Whatever the sequence, the guard arms only at a non-fault tick with a usable sample
        /// whose stick is at rest (or ignored, with the deadman), never during a fault, and
        /// with the deadman required only at a held deadman released since the last fault.
        #[test]
        fn arms_only_at_neutral_input(
            deadman_required in any::<bool>(),
            ticks in proptest::collection::vec(
                (any::<bool>(), any::<bool>(), 0.0f64..1.0, any::<bool>(), any::<bool>(), any::<bool>()),
                1..60,
            ),
        ) {
            let mut g = RestartGuard::new(deadman_required);
            let mut released_since_fault = false;
            for (fault, usable, norm, held, uses, interrupt) in ticks {
                if interrupt {
                    g.interrupt();
                    released_since_fault = false;
                }
                let was_armed = g.armed();
                let input = usable.then_some(Operator { action_norm: norm, deadman: held, uses_input: uses });
                let armed = g.tick(fault, input);
                if fault {
                    released_since_fault = usable && !held;
                    prop_assert!(!armed);
                    continue;
                }
                if usable && !held {
                    released_since_fault = true;
                }
                if armed && !was_armed {
                    prop_assert!(usable);
                    prop_assert!(norm <= NEUTRAL_MAX_ACTION || (deadman_required && !uses));
                    if deadman_required {
                        prop_assert!(held && released_since_fault);
                    }
                }
                if was_armed {
                    prop_assert!(armed, "only a fault disarms");
                }
            }
        }
    }
}
