//! What a simulated operator is set up with, below both the operators ([`crate::operator`])
//! and the loop that drives them ([`crate::simulate`]): the study file's `[simulation]`
//! section ([`SimParams`], with the expert's and the practiced operator's own sections), the
//! factory of the served map for the operators that evaluate it ([`ModelFactory`]), and the
//! error of setting an attempt up ([`SimError`]).

use std::path::PathBuf;

use mapper::LoadedModel;
use mapper::model::ModelError;
use serde::{Deserialize, Serialize};

/// Which simulated operator runs the attempts (`[simulation] operator`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OperatorKind {
    /// One tick ahead through the served map, the best of a few sampled inputs (the default,
    /// the lower bound).
    #[default]
    Greedy,
    /// Plans with the served map as its forward model (sampling-based model-predictive
    /// control over stick sequences and mode presses): what the map allows at best.
    Expert,
    /// Learns the map in the study's practice time from what it sees, then plans with what
    /// it learned: a person after practice.
    Practiced,
    /// Follows the nearest demonstration by the tool, reproducing its motion through the
    /// served map: what the map allows along its demonstrations' route.
    Follower,
}

impl OperatorKind {
    /// Every kind, as the study file spells it.
    pub const NAMES: [&'static str; 4] = ["greedy", "practiced", "expert", "follower"];

    /// Its name in the study file.
    pub fn name(self) -> &'static str {
        match self {
            Self::Greedy => "greedy",
            Self::Expert => "expert",
            Self::Practiced => "practiced",
            Self::Follower => "follower",
        }
    }

    /// The kind the study file names `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Greedy, Self::Practiced, Self::Expert, Self::Follower]
            .into_iter()
            .find(|k| k.name() == name)
    }
}

impl<'de> Deserialize<'de> for OperatorKind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Self::from_name(&name).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "`simulation.operator`: no operator `{name}`; the operators: {}",
                Self::NAMES.join(", ")
            ))
        })
    }
}

/// The simulated operator's parameters: the study file's `[simulation]` section. The same for
/// every condition (never tuned per model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimParams {
    /// Which operator runs the attempts: `greedy` (one tick ahead; the default) or `expert`
    /// (plans with the served map as its forward model).
    pub operator: OperatorKind,
    /// Candidate stick inputs drawn per tick (the greedy user's idea, with far fewer than its
    /// 4096: a person weighs a handful of directions, not thousands). Default 64.
    pub candidates: usize,
    /// Reaction delay (s): the stick carries out what was chosen this long ago. Default 0.2 s,
    /// the visuomotor delay of manual tracking.
    pub reaction_delay_s: f64,
    /// Standard deviation of the noise added to each stick axis (fraction of full
    /// deflection). Default 0.05.
    pub input_noise: f64,
    /// Largest rate of change of the stick (full deflections per second). Default 5: rest to
    /// full deflection in 0.2 s.
    pub stick_rate_per_s: f64,
    /// Press the mode button when another mode would reduce the error one tick ahead by this
    /// fraction more than the current one (0.25: a quarter more). Default 0.25.
    pub mode_switch_margin: f64,
    /// The stick rests this long around a mode press (s): the thumb leaves the stick for the
    /// button and the operator re-orients. Default 0.5 s.
    pub mode_switch_s: f64,
    /// How the operator weighs a tilt error against a position error (m per rad): 1 rad of
    /// tilt counts as 10 cm. Default 0.1.
    pub tilt_weight_m_per_rad: f64,
    /// The expert operator's planner (`[simulation.expert]`).
    pub expert: ExpertParams,
    /// The practiced operator (`[simulation.practiced]`).
    pub practiced: PracticedParams,
}

impl Default for SimParams {
    fn default() -> Self {
        Self {
            candidates: 64,
            reaction_delay_s: 0.2,
            input_noise: 0.05,
            stick_rate_per_s: 5.0,
            mode_switch_margin: 0.25,
            mode_switch_s: 0.5,
            tilt_weight_m_per_rad: 0.1,
            operator: OperatorKind::default(),
            expert: ExpertParams::default(),
            practiced: PracticedParams::default(),
        }
    }
}

impl SimParams {
    /// Checks the values; the error names the key.
    pub fn check(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, r: &str| Err((format!("simulation.{k}"), r.to_owned()));
        if self.candidates == 0 || self.candidates > 100_000 {
            return bad("candidates", "must be 1 to 100000");
        }
        for (k, v) in [
            ("reaction_delay_s", self.reaction_delay_s),
            ("input_noise", self.input_noise),
            ("mode_switch_margin", self.mode_switch_margin),
            ("mode_switch_s", self.mode_switch_s),
            ("tilt_weight_m_per_rad", self.tilt_weight_m_per_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(k, "must be 0 or more");
            }
        }
        if !(self.stick_rate_per_s.is_finite() && self.stick_rate_per_s > 0.0) {
            return bad("stick_rate_per_s", "must be positive");
        }
        self.expert
            .check()
            .map_err(|(k, r)| (format!("simulation.expert.{k}"), r))?;
        self.practiced
            .check()
            .map_err(|(k, r)| (format!("simulation.practiced.{k}"), r))
    }
}

/// The expert operator's planner: `[simulation.expert]` of the study file. The same for
/// every condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExpertParams {
    /// Stick sequences tried per plan (in each mode considered), besides the last plan and
    /// rest. Default 16.
    pub samples: usize,
    /// How far ahead it plans (s). Default 1.5.
    pub horizon_s: f64,
    /// The plan's knots: the stick is held this long between them (s). Default 0.1.
    pub step_s: f64,
    /// Standard deviation of the sequences drawn around the last plan (fraction of full
    /// deflection). Default 0.3.
    pub spread: f64,
    /// How sharply the plan follows the best sequences: the weights are
    /// `exp(-(J - J_min) / (temperature (J_mean - J_min)))`. Default 0.02: close to
    /// following the best sequence, which reached the goals sooner than 0.1 with mode
    /// switching.
    pub temperature: f64,
    /// Maps with modes: how often the other modes are planned in too (s). Default 0.25.
    pub mode_check_s: f64,
    /// No progress (5 mm closer, or a subgoal done) for this long: back off (s). Default 3.
    pub stuck_s: f64,
    /// How long it backs off (s). Default 1.
    pub back_off_s: f64,
    /// How far it backs off (m). Default 0.08.
    pub back_off_m: f64,
    /// The route: what a predicted tool position further than [`ExpertParams::route_radius_m`]
    /// from the task's demonstrated paths costs, per metre beyond (m per m; 0: the
    /// straight line to the next subgoal only). Default 1: a person who practised the task
    /// keeps to its route (in front of the cup, then in; lift, carry, lower), where the map
    /// was taught to move.
    pub route_weight: f64,
    /// How far from the demonstrated paths the route costs nothing (m). Default 0.02.
    pub route_radius_m: f64,
    /// On the way to an object and at it, what a turn of the fingers away from facing it
    /// costs (m per rad; [`learning::goals::Aim::facing_error`]). Default 0.1, as a tilt:
    /// a bottle or cup is grasped from the side with the fingers level and facing it.
    pub face_weight_m_per_rad: f64,
}

impl Default for ExpertParams {
    fn default() -> Self {
        Self {
            samples: 16,
            horizon_s: 1.5,
            step_s: 0.1,
            spread: 0.3,
            temperature: 0.02,
            mode_check_s: 0.25,
            stuck_s: 3.0,
            back_off_s: 1.0,
            back_off_m: 0.08,
            route_weight: 1.0,
            route_radius_m: 0.02,
            face_weight_m_per_rad: 0.1,
        }
    }
}

impl ExpertParams {
    /// Checks the values; the error names the key (within `[simulation.expert]`).
    pub fn check(&self) -> Result<(), (String, String)> {
        let bad = |k: &str, r: &str| Err((k.to_owned(), r.to_owned()));
        if self.samples == 0 || self.samples > 1000 {
            return bad("samples", "must be 1 to 1000");
        }
        for (k, v) in [
            ("step_s", self.step_s),
            ("temperature", self.temperature),
            ("mode_check_s", self.mode_check_s),
            ("stuck_s", self.stuck_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(k, "must be positive");
            }
        }
        for (k, v) in [
            ("spread", self.spread),
            ("back_off_s", self.back_off_s),
            ("back_off_m", self.back_off_m),
            ("route_weight", self.route_weight),
            ("route_radius_m", self.route_radius_m),
            ("face_weight_m_per_rad", self.face_weight_m_per_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(k, "must be 0 or more");
            }
        }
        if !(self.horizon_s.is_finite() && self.horizon_s >= self.step_s && self.horizon_s <= 10.0)
        {
            return bad("horizon_s", "must be one step_s to 10 s");
        }
        if self.horizon_s / self.step_s > 200.0 {
            return bad("horizon_s", "must be at most 200 steps of step_s");
        }
        Ok(())
    }
}

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
}

/// Why a simulation could not run.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A model did not load.
    #[error("model `{spec}`: {source}")]
    Model {
        /// The spec.
        spec: String,
        /// Why.
        source: ModelError,
    },
    /// The safety filter or the mock arm refused its configuration.
    #[error("{0}")]
    Setup(String),
    /// The live graph of `--live` failed (it did not start, stopped or died).
    #[error("the live graph: {0}")]
    Live(String),
    /// A task has no simulated goals.
    #[error("{path}: `tasks[{index}].goals`: {reason}", path = path.display())]
    Goals {
        /// The study file.
        path: PathBuf,
        /// The task's index.
        index: usize,
        /// Why.
        reason: String,
    },
}

/// Makes a fresh instance of the served model (the map served and the operator's copies).
pub type ModelFactory<'a> = dyn Fn() -> Result<LoadedModel, SimError> + 'a;
