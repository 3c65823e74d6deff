//! The remote operator's link, as the gateway sees it: a pure state machine fed with the
//! operators' liveliness tokens, their samples and the robot's ticks. It decides which sample
//! reaches the graph and when the gateway stands in with a neutral "device gone" sample
//! (the arm stops, and moves again only after neutral input), and counts everything.
//!
//! The rules, each a test below:
//! * one operator drives at a time: the first session with a live token that sends a
//!   neutral sample; a second is refused until the first is gone;
//! * a session whose token went (the link was lost, its lease ran out, it quit) never drives
//!   again; its operator must open a new session;
//! * a sample must answer a tick the gateway has seen, at most one behind the newest (the
//!   mapper's own staleness rule); a stale one stops the arm (counted once per episode);
//! * after joining, a loss or stale input, the operator's input passes only once it is
//!   neutral;
//! * while no operator drives, every tick gets a neutral sample flagged `NO_DEVICE`, as a
//!   joystick whose device is unplugged: the arm stops at the next tick and safety's restart
//!   prevention waits for neutral input.

use ipc_types::{JoystickInput, NO_TICK, buttons};

use crate::wire::{GatewayStatus, link_state};

/// The largest stick deflection that counts as neutral (safety's restart prevention uses the
/// same bound, `safety::restart::NEUTRAL_MAX_ACTION`: a test in the gateway keeps them equal).
pub const NEUTRAL_MAX_ACTION: f64 = 0.05;

/// The driving operator's input is stale at the robot tick this many ticks after the newest
/// tick it answered (one behind is still fresh: the mapper's own rule): the gateway then
/// stands in with neutral input and safety stops the arm.
pub const STALE_AFTER_TICKS: u64 = 2;

/// Sessions remembered as ended (the oldest forgotten first).
const ENDED_KEPT: usize = 64;

/// Why an operator's sample or request was not passed on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Axes or gripper not finite.
    NonFinite,
    /// From a session whose liveliness token went.
    EndedSession,
    /// From a session that declared no liveliness token (yet).
    NoSession,
    /// Another operator drives.
    SecondOperator,
    /// It answers no tick (the operator has not seen a robot state yet).
    NoTick,
    /// It answers a tick the gateway has not seen.
    FromTheFuture,
    /// It answers a tick two or more behind the newest.
    Stale,
    /// The input must pass through neutral first.
    NotNeutral,
    /// A reset, which this gateway does not accept from the network.
    ResetNotAccepted,
    /// An e-stop request with an unknown action.
    UnknownAction,
}

impl Refusal {
    /// A short name for logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::NonFinite => "non-finite",
            Self::EndedSession => "ended session",
            Self::NoSession => "no liveliness token",
            Self::SecondOperator => "second operator",
            Self::NoTick => "no tick",
            Self::FromTheFuture => "tick from the future",
            Self::Stale => "stale",
            Self::NotNeutral => "not neutral",
            Self::ResetNotAccepted => "reset not accepted",
            Self::UnknownAction => "unknown action",
        }
    }
}

/// Why the driving operator's input stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// Its liveliness token went: the session ended or the link is gone.
    LinkLost,
    /// Its newest sample is two or more ticks old.
    Stale,
}

#[derive(Debug, Clone)]
struct Driver {
    zid: String,
    /// Newest tick its forwarded samples answered.
    newest: u64,
    armed: bool,
}

/// The link's state and counts.
#[derive(Debug, Clone, Default)]
pub struct OperatorLink {
    alive: Vec<String>,
    ended: std::collections::VecDeque<String>,
    driver: Option<Driver>,
    lost: bool,
    newest_tick: u64,
    acked_seq: Option<u64>,
    status: GatewayStatus,
}

impl OperatorLink {
    /// No operator yet.
    pub fn new() -> Self {
        Self {
            newest_tick: NO_TICK,
            ..Self::default()
        }
    }

    /// An operator's liveliness token appeared (`alive`) or went. Returns the stop it causes,
    /// if the session was driving.
    pub fn token(&mut self, zid: &str, alive: bool) -> Option<Stop> {
        if alive {
            if !self.ended.iter().any(|z| z == zid) && !self.alive.iter().any(|z| z == zid) {
                self.alive.push(zid.to_owned());
            }
            return None;
        }
        self.alive.retain(|z| z != zid);
        if !self.ended.iter().any(|z| z == zid) {
            if self.ended.len() == ENDED_KEPT {
                self.ended.pop_front();
            }
            self.ended.push_back(zid.to_owned());
        }
        if self.driver.as_ref().is_some_and(|d| d.zid == zid) {
            self.driver = None;
            self.lost = true;
            self.status.link_losses += 1;
            return Some(Stop::LinkLost);
        }
        None
    }

    /// A sample from session `zid`: the sample to publish on the graph (the caller stamps
    /// its own time and sequence number), or why not.
    pub fn sample(&mut self, zid: &str, s: &JoystickInput) -> Result<JoystickInput, Refusal> {
        let r = self.judge(zid, s);
        match r {
            Ok(_) => {
                self.status.forwarded += 1;
                self.acked_seq = Some(s.seq);
            }
            Err(_) => self.status.refused += 1,
        }
        r
    }

    fn judge(&mut self, zid: &str, s: &JoystickInput) -> Result<JoystickInput, Refusal> {
        if !(s.axes.iter().all(|a| a.is_finite()) && s.gripper.is_finite()) {
            return Err(Refusal::NonFinite);
        }
        if self.ended.iter().any(|z| z == zid) {
            return Err(Refusal::EndedSession);
        }
        if !self.alive.iter().any(|z| z == zid) {
            return Err(Refusal::NoSession);
        }
        if self.driver.as_ref().is_some_and(|d| d.zid != zid) {
            return Err(Refusal::SecondOperator);
        }
        if s.tick == NO_TICK {
            return Err(Refusal::NoTick);
        }
        if self.newest_tick == NO_TICK || s.tick > self.newest_tick {
            return Err(Refusal::FromTheFuture);
        }
        let driver = self.driver.get_or_insert_with(|| Driver {
            zid: zid.to_owned(),
            newest: s.tick,
            armed: false,
        });
        if s.tick.saturating_add(1) < self.newest_tick {
            if driver.armed {
                driver.armed = false;
                self.status.stale_stops += 1;
            }
            return Err(Refusal::Stale);
        }
        if !driver.armed {
            if !is_neutral(s) {
                return Err(Refusal::NotNeutral);
            }
            driver.armed = true;
            self.lost = false;
        }
        driver.newest = driver.newest.max(s.tick);
        Ok(*s)
    }

    /// Robot tick `tick` began. Returns the stop it finds (the driver's input went stale),
    /// and whether the gateway must stand in with a neutral `NO_DEVICE` sample answering it
    /// ([`Self::placeholder`]).
    pub fn tick(&mut self, tick: u64) -> (Option<Stop>, bool) {
        self.newest_tick = tick;
        self.status.tick = tick;
        let mut stop = None;
        if let Some(d) = self.driver.as_mut()
            && d.armed
            && d.newest.saturating_add(STALE_AFTER_TICKS) <= tick
        {
            d.armed = false;
            self.status.stale_stops += 1;
            stop = Some(Stop::Stale);
        }
        let driving = self.driver.as_ref().is_some_and(|d| d.armed);
        (stop, !driving)
    }

    /// The neutral "device gone" sample that answers `tick` while no operator drives.
    pub fn placeholder(tick: u64, t_ns: u64) -> JoystickInput {
        JoystickInput {
            tick,
            buttons: buttons::NO_DEVICE,
            ..JoystickInput::neutral(t_ns)
        }
    }

    /// The link's account now (the caller sets `t_ns` and `outbound_dropped`).
    pub fn status(&self) -> GatewayStatus {
        GatewayStatus {
            acked_seq: self.acked_seq.unwrap_or(u64::MAX),
            link: match &self.driver {
                Some(d) if d.armed => link_state::LIVE,
                Some(_) if !self.lost => link_state::AWAITING_NEUTRAL,
                Some(_) => link_state::LOST,
                None if self.lost => link_state::LOST,
                None => link_state::NONE,
            },
            ..self.status
        }
    }
}

/// Whether a sample is at rest: the stick within [`NEUTRAL_MAX_ACTION`], the gripper still.
pub fn is_neutral(s: &JoystickInput) -> bool {
    let norm = f64::from(s.axes[0]).hypot(f64::from(s.axes[1]));
    norm <= NEUTRAL_MAX_ACTION && f64::from(s.gripper).abs() <= NEUTRAL_MAX_ACTION
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(tick: u64, x: f32) -> JoystickInput {
        JoystickInput {
            tick,
            seq: tick,
            axes: [x, 0.0],
            ..JoystickInput::neutral(1)
        }
    }

    /// A link at tick 10 with operator `a1` joined and driving.
    fn driving() -> OperatorLink {
        let mut l = OperatorLink::new();
        l.tick(10);
        l.token("a1", true);
        l.sample("a1", &sample(10, 0.0)).unwrap();
        assert_eq!(l.status().link, link_state::LIVE);
        l
    }

    #[test]
    fn an_operator_drives_only_after_its_token_and_a_neutral_sample() {
        let mut l = OperatorLink::new();
        assert_eq!(l.tick(10), (None, true), "no operator: stand in");
        assert_eq!(l.sample("a1", &sample(10, 0.0)), Err(Refusal::NoSession));
        l.token("a1", true);
        assert_eq!(l.sample("a1", &sample(10, 0.8)), Err(Refusal::NotNeutral));
        assert_eq!(l.status().link, link_state::AWAITING_NEUTRAL);
        assert!(l.sample("a1", &sample(10, 0.01)).is_ok());
        assert!(l.sample("a1", &sample(10, 0.8)).is_ok());
        assert_eq!(l.tick(11), (None, false), "driving: no stand-in");
        assert_eq!(l.status().acked_seq, 10);
        assert_eq!(l.status().refused, 2);
        assert_eq!(l.status().forwarded, 2);
    }

    #[test]
    fn a_second_operator_is_refused_while_the_first_drives() {
        let mut l = driving();
        l.token("b2", true);
        assert_eq!(
            l.sample("b2", &sample(10, 0.0)),
            Err(Refusal::SecondOperator)
        );
        l.token("a1", false);
        assert!(
            l.sample("b2", &sample(10, 0.0)).is_ok(),
            "the first is gone"
        );
    }

    #[test]
    fn a_lost_session_stops_the_arm_and_never_drives_again() {
        let mut l = driving();
        assert_eq!(l.token("a1", false), Some(Stop::LinkLost));
        assert_eq!(l.status().link, link_state::LOST);
        assert_eq!(l.status().link_losses, 1);
        assert_eq!(l.tick(11), (None, true));
        assert_eq!(l.sample("a1", &sample(11, 0.0)), Err(Refusal::EndedSession));
        l.token("a1", true);
        assert_eq!(
            l.sample("a1", &sample(11, 0.0)),
            Err(Refusal::EndedSession),
            "a token of an ended session does not revive it"
        );
        l.token("c3", true);
        assert_eq!(l.sample("c3", &sample(11, 0.5)), Err(Refusal::NotNeutral));
        assert!(l.sample("c3", &sample(11, 0.0)).is_ok());
        assert_eq!(l.status().link, link_state::LIVE);
    }

    #[test]
    fn stale_input_stops_once_and_resumes_after_neutral() {
        let mut l = driving();
        assert_eq!(l.tick(11), (None, false), "one behind is fresh");
        assert_eq!(l.tick(12), (Some(Stop::Stale), true));
        assert_eq!(l.tick(13), (None, true), "counted once");
        assert_eq!(l.status().stale_stops, 1);
        assert_eq!(l.sample("a1", &sample(11, 0.0)), Err(Refusal::Stale));
        assert_eq!(l.status().stale_stops, 1, "still the same episode");
        assert_eq!(l.sample("a1", &sample(13, 0.7)), Err(Refusal::NotNeutral));
        assert!(
            l.sample("a1", &sample(12, 0.0)).is_ok(),
            "one behind, neutral"
        );
        assert!(l.sample("a1", &sample(13, 0.7)).is_ok(), "driving again");
        assert_eq!(l.tick(14), (None, false));
        assert_eq!(l.tick(15), (Some(Stop::Stale), true), "a second episode");
        assert_eq!(l.status().stale_stops, 2);
    }

    #[test]
    fn samples_that_answer_no_seen_tick_or_are_not_finite_are_refused() {
        let mut l = driving();
        assert_eq!(
            l.sample("a1", &sample(11, 0.0)),
            Err(Refusal::FromTheFuture)
        );
        assert_eq!(l.sample("a1", &sample(NO_TICK, 0.0)), Err(Refusal::NoTick));
        assert_eq!(
            l.sample("a1", &sample(10, f32::NAN)),
            Err(Refusal::NonFinite)
        );
        let mut g = sample(10, 0.0);
        g.gripper = f32::INFINITY;
        assert_eq!(l.sample("a1", &g), Err(Refusal::NonFinite));
        assert_eq!(
            l.status().link,
            link_state::LIVE,
            "refusals alone do not stop"
        );
    }

    #[test]
    fn the_stand_in_is_neutral_and_flags_the_device_gone() {
        let p = OperatorLink::placeholder(5, 99);
        assert_eq!((p.tick, p.t_ns), (5, 99));
        assert!(is_neutral(&p));
        assert_eq!(p.buttons, buttons::NO_DEVICE);
    }
}
