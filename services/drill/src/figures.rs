//! What one drill run measured, from the graph's own recording, and how it is judged: pure
//! functions of the recorded messages, so a unit test judges a made-up run.

use ipc_types::{JoystickInput, NodeRole, NodeStatus, RobotState, SafeCommand, safe_flags};
use serde::Serialize;

/// Largest `|a|` that counts as the stick at rest (safety's restart prevention,
/// `safety::restart::NEUTRAL_MAX_ACTION`; docs/configuration.md "Restart prevention").
pub const NEUTRAL_MAX_ACTION: f64 = 0.05;

/// A joint speed below this is at rest (rad/s).
const AT_REST_RAD_S: f64 = 1e-9;

/// The messages of one run, in recording order.
#[derive(Debug, Default, Clone)]
pub struct Recorded {
    /// Every robot state.
    pub states: Vec<RobotState>,
    /// Every executed command (safety's output).
    pub commands: Vec<SafeCommand>,
    /// Every joystick sample.
    pub joystick: Vec<JoystickInput>,
    /// Every heartbeat.
    pub status: Vec<NodeStatus>,
    /// The tick of every mapper command and the norm of the action it mapped.
    pub mapper: Vec<(u64, f64)>,
    /// Every e-stop and reset command.
    pub estops: Vec<ipc_types::control::EstopCommand>,
}

impl Recorded {
    /// Appends the robot states of `seen` (the drill's own view, in order) published after the
    /// recording's last one: a killed recorder's file ends up to a second before the kill (its
    /// last chunk is lost), and the graph runs on until its bridge has stopped the arm. A
    /// recording that holds the bridge's last state gets nothing.
    pub fn fill_after_end(&mut self, seen: &[RobotState]) {
        let end = self.states.last().map_or(0, |s| s.t_ns);
        let after: Vec<RobotState> = seen.iter().filter(|s| s.t_ns > end).copied().collect();
        if !after.is_empty() {
            tracing::debug!(states = after.len(), "states after the recording's end");
        }
        self.states.extend(after);
    }

    /// When the first e-stop (`action`: an `estop_action`) was sent, if one was.
    pub fn estop_sent(&self, action: u32) -> Option<u64> {
        self.estops
            .iter()
            .find(|e| e.action == action)
            .map(|e| e.t_ns)
    }
}

/// What the run promised, from the documentation and the configuration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Promise {
    /// Whether the fault must stop the arm (`false`: a swap, which must not).
    pub stops: bool,
    /// Ticks from the fault to the first stopped tick, at most.
    pub stop_ticks: u64,
    /// The documented stop deceleration of each joint (rad/s²): the robot profile's
    /// teleoperation accelerations (`[safety] max_acceleration_rad_s2` and `[bridge]
    /// stop_acceleration_rad_s2` default to them).
    pub decel_rad_s2: Vec<f64>,
    /// The control period (s).
    pub period_s: f64,
}

impl Promise {
    /// The braking time from the joint speeds `v` (s): the stop scales the whole command, so
    /// every joint reaches zero together, when the slowest to brake at its documented
    /// deceleration does.
    pub fn braking_s(&self, v: &[f64]) -> f64 {
        v.iter()
            .zip(&self.decel_rad_s2)
            .fold(0.0, |t, (v, a)| t.max(v.abs() / a))
    }

    /// Each joint's stop distance from the speeds `v` at the start of the stop (rad): two
    /// ticks at its speed (the tick the stop is commanded in, and one of slack for the grid),
    /// then a linear ramp to zero over [`Self::braking_s`].
    pub fn stop_distances(&self, v: &[f64]) -> Vec<f64> {
        let t = self.braking_s(v);
        v.iter()
            .map(|v| {
                let v = v.abs();
                v * self.period_s * 2.0 + v * t / 2.0 + 1e-6
            })
            .collect()
    }
}

/// The figures of one run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Figures {
    /// The tick of the fault (the first state at or after it).
    pub fault_tick: u64,
    /// The fastest joint's speed at the fault (rad/s).
    pub speed_at_fault_rad_s: f64,
    /// Ticks from the fault to the first tick the arm was stopping (`null`: never).
    pub stop_ticks: Option<u64>,
    /// Time from the fault to rest (ms; `null`: not at rest by the end).
    pub rest_ms: Option<f64>,
    /// The largest joint travel from the fault to rest (rad).
    pub fault_travel_rad: f64,
    /// The joint travel from the start of the stop to rest (rad), on the joint that used most
    /// of its promised stop distance.
    pub travel_rad: f64,
    /// That joint's stop distance at the documented deceleration (rad).
    pub promised_travel_rad: f64,
    /// The fastest joint speed from the fault until rest (rad/s).
    pub peak_speed_rad_s: f64,
    /// Whether any joint went faster during the stop than at its start, beyond one tick of
    /// the documented acceleration.
    pub sped_up: bool,
    /// Motion after the stop: `none`, `after-neutral`, `before-neutral`.
    pub resumed: &'static str,
    /// Commands flagged `stop` after the fault (a swap must have none).
    pub stop_commands: u64,
    /// Ticks the bridge missed over the run.
    pub missed: u64,
    /// How many of them the machine held up.
    pub held_up: u64,
    /// The largest finite stick reading the joystick sent from the fault on (`|axes|`).
    pub max_input: f64,
    /// The largest action the mapper mapped from the fault on (`|a|`; the stick's disc is
    /// `|a| <= 1`, to which the mapper clamps every input).
    pub max_action: f64,
}

/// Where the joystick sample is neutral and usable.
fn neutral(j: &JoystickInput) -> bool {
    let [x, y] = j.axes.map(f64::from);
    x.is_finite() && y.is_finite() && x.hypot(y) <= NEUTRAL_MAX_ACTION
}

pub(crate) fn max_speed(s: &RobotState) -> f64 {
    let n = s.n_joints as usize;
    s.qdot_rad_s[..n.min(s.qdot_rad_s.len())]
        .iter()
        .fold(0.0, |m, v| m.max(v.abs()))
}

/// The bridge's missed ticks and those held up over the run: the newest heartbeat of each
/// bridge process, summed.
fn misses(status: &[NodeStatus]) -> (u64, u64) {
    let mut newest: Vec<&NodeStatus> = Vec::new();
    for s in status.iter().filter(|s| s.role == NodeRole::Bridge as u32) {
        match newest.iter_mut().find(|n| n.pid == s.pid) {
            Some(n) if n.t_ns <= s.t_ns => *n = s,
            Some(_) => {}
            None => newest.push(s),
        }
    }
    newest.iter().fold((0, 0), |(m, h), s| {
        (m + s.faults, h + u64::from(s.held_up).min(s.faults))
    })
}

/// Measures a run whose fault came at monotonic time `fault_ns` (or, for a fault set by tick,
/// the state of that tick's time).
pub fn measure(rec: &Recorded, fault_ns: u64, promise: &Promise) -> Option<Figures> {
    let states: Vec<&RobotState> = rec.states.iter().collect();
    let at = states.iter().position(|s| s.t_ns >= fault_ns)?;
    let fault = states[at];
    // The arm at the fault: the state before it (what the fault interrupted).
    let before = if at > 0 { states[at - 1] } else { fault };
    let n = (before.n_joints as usize).min(before.qdot_rad_s.len());
    let v0: Vec<f64> = before.qdot_rad_s[..n].iter().map(|v| v.abs()).collect();
    let stopping = ipc_types::state_flags::STOPPING
        | ipc_types::state_flags::MISSED
        | ipc_types::state_flags::SAFETY_STOP
        | ipc_types::state_flags::SHUTDOWN;
    let stop_at = states[at..]
        .iter()
        .position(|s| s.flags & stopping != 0 || max_speed(s) <= AT_REST_RAD_S);
    let stop_ticks = stop_at.map(|i| states[at + i].tick.saturating_sub(fault.tick));
    // Motion again after the stop began: the first executed command that is not a stop. A
    // stop ends at rest, or there, when the operator's neutral input allowed motion before
    // the arm was at rest (the ramp of a slow joint outlasts a short release of the stick).
    let stop_tick = stop_at.map(|i| states[at + i].tick);
    let resume = stop_tick.and_then(|t| {
        rec.commands.iter().find(|c| {
            c.tick > t
                && c.flags & safe_flags::STOP == 0
                && c.qdot_rad_s.iter().any(|v| v.abs() > AT_REST_RAD_S)
        })
    });
    let rest_at = stop_at.and_then(|i| {
        states[at + i..]
            .iter()
            .position(|s| max_speed(s) <= AT_REST_RAD_S || resume.is_some_and(|c| s.tick > c.tick))
            .map(|k| at + i + k)
    });
    let end = rest_at.unwrap_or(states.len() - 1);
    // The stop is judged from its start: the state before the first stopping one.
    let start = stop_at
        .map_or(at, |i| (at + i).saturating_sub(1))
        .max(at.saturating_sub(1));
    let vs: Vec<f64> = states[start].qdot_rad_s[..n]
        .iter()
        .map(|v| v.abs())
        .collect();
    let mut travel = 0.0;
    let mut promised = 0.0;
    let mut worst = -1.0;
    let mut fault_travel = 0.0f64;
    for (j, allowed) in promise.stop_distances(&vs).into_iter().enumerate() {
        fault_travel = fault_travel.max((states[end].q_rad[j] - before.q_rad[j]).abs());
        let d = (states[end].q_rad[j] - states[start].q_rad[j]).abs();
        if d / allowed > worst {
            worst = d / allowed;
            travel = d;
            promised = allowed;
        }
    }
    let (peak, sped_up) = peak_and_speed_up(&states, (at, start, end), &vs, promise);
    let resumed = how_resumed(rec, fault, resume);
    let stop_commands = rec
        .commands
        .iter()
        .filter(|c| c.tick >= fault.tick && c.flags & safe_flags::STOP != 0)
        .count() as u64;
    let (missed, held_up) = misses(&rec.status);
    let max_action = rec
        .mapper
        .iter()
        .filter(|(t, _)| *t >= fault.tick)
        .fold(0.0f64, |m, (_, a)| m.max(*a));
    let max_input = rec
        .joystick
        .iter()
        .filter(|j| j.tick != ipc_types::NO_TICK && j.tick >= fault.tick)
        .map(|j| f64::from(j.axes[0]).hypot(f64::from(j.axes[1])))
        .filter(|a| a.is_finite())
        .fold(0.0f64, f64::max);
    Some(Figures {
        fault_tick: fault.tick,
        speed_at_fault_rad_s: v0.iter().fold(0.0, |m, v| m.max(*v)),
        stop_ticks,
        rest_ms: rest_at.map(|i| states[i].t_ns.saturating_sub(fault_ns) as f64 / 1e6),
        fault_travel_rad: fault_travel,
        travel_rad: travel,
        promised_travel_rad: promised,
        peak_speed_rad_s: peak,
        sped_up,
        resumed,
        stop_commands,
        missed,
        held_up,
        max_input,
        max_action,
    })
}

/// Over the states from the fault (index `at`) to the end of the stop (`end`): the peak
/// joint speed, and whether a joint sped up, after the stop's start (`start`), past what its
/// deceleration allows from `vs` (the speeds at the stop's start) in a period.
fn peak_and_speed_up(
    states: &[&RobotState],
    (at, start, end): (usize, usize, usize),
    vs: &[f64],
    promise: &Promise,
) -> (f64, bool) {
    let mut peak = 0.0f64;
    let mut sped_up = false;
    for (i, s) in states.iter().enumerate().take(end + 1).skip(at) {
        peak = peak.max(max_speed(s));
        if i <= start {
            continue;
        }
        for (j, v) in vs.iter().enumerate() {
            let a = promise
                .decel_rad_s2
                .get(j)
                .copied()
                .unwrap_or(f64::INFINITY);
            if s.qdot_rad_s[j].abs() > v + a * promise.period_s + 1e-9 {
                sped_up = true;
            }
        }
    }
    (peak, sped_up)
}

/// How motion resumed after the stop (`resume`: the first moving command): `none`, or
/// `after-neutral` / `before-neutral` as the joystick passed through neutral since the
/// fault or not.
fn how_resumed(rec: &Recorded, fault: &RobotState, resume: Option<&SafeCommand>) -> &'static str {
    match resume {
        None => "none",
        Some(m) => {
            let seen = rec
                .joystick
                .iter()
                .any(|j| j.tick >= fault.tick && j.tick <= m.tick && neutral(j));
            if seen {
                "after-neutral"
            } else {
                "before-neutral"
            }
        }
    }
}

/// Why a run broke its promise (empty: it kept it).
pub fn judge(f: &Figures, promise: &Promise, leftovers: usize) -> Vec<String> {
    let mut why = Vec::new();
    if promise.stops {
        match f.stop_ticks {
            None => why.push("the arm never stopped".to_owned()),
            Some(t) if t > promise.stop_ticks => why.push(format!(
                "stopped {t} ticks after the fault, promised {}",
                promise.stop_ticks
            )),
            Some(_) => {}
        }
        if f.rest_ms.is_none() {
            why.push("not at rest by the end".to_owned());
        }
        if f.travel_rad > f.promised_travel_rad {
            why.push(format!(
                "travelled {:.4} rad from the start of the stop, {:.0} % of the promised stop distance {:.4} rad",
                f.travel_rad,
                100.0 * f.travel_rad / f.promised_travel_rad,
                f.promised_travel_rad
            ));
        }
        if f.sped_up {
            why.push(format!(
                "a joint sped up during the stop (peak {:.3} rad/s, {:.3} at the fault)",
                f.peak_speed_rad_s, f.speed_at_fault_rad_s
            ));
        }
        if f.resumed == "before-neutral" {
            why.push("moved again before neutral input".to_owned());
        }
    } else {
        if f.stop_commands > 0 {
            why.push(format!("{} stop commands after the fault", f.stop_commands));
        }
        let own = f.missed - f.held_up.min(f.missed);
        if own > 0 {
            why.push(format!(
                "{own} ticks missed by the graph ({} more held up by the machine)",
                f.held_up
            ));
        }
    }
    if f.max_action > 1.0 + 1e-6 {
        why.push(format!(
            "the mapper mapped an action of |a| = {:.3}, outside the stick's disc",
            f.max_action
        ));
    }
    if leftovers > 0 {
        why.push(format!(
            "{leftovers} shared-memory files left after the graph ended"
        ));
    }
    why
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::state_flags;

    const P: f64 = 0.025;

    fn promise(stops: bool) -> Promise {
        Promise {
            stops,
            stop_ticks: 2,
            decel_rad_s2: vec![1.0; 6],
            period_s: P,
        }
    }

    /// A run at `v0` on joint 0 that stops at `decel` from tick 10 (the fault's), then
    /// resumes at tick `resume` with the stick neutral from tick `neutral_at`.
    fn run(v0: f64, decel: f64, resume: u64, neutral_at: u64) -> Recorded {
        let mut rec = Recorded::default();
        let mut q = 0.0;
        let mut v = v0;
        for k in 0..60u64 {
            let mut s = RobotState::at_rest(k, 1_000 + k * 25_000_000, 6);
            if k >= 10 {
                v = (v - decel * P).max(0.0);
                s.flags |= state_flags::SAFETY_STOP;
            }
            if k >= resume {
                v = 0.1;
                s.flags = 0;
            }
            q += v * P;
            s.q_rad[0] = q;
            s.qdot_rad_s[0] = v;
            rec.states.push(s);
            let mut c = SafeCommand::zeroed();
            c.tick = k;
            c.n_joints = 6;
            c.qdot_rad_s[0] = v;
            if (10..resume).contains(&k) {
                c.flags = safe_flags::STOP;
            }
            rec.commands.push(c);
            rec.joystick.push(JoystickInput {
                tick: k,
                t_ns: 0,
                seq: k,
                axes: if k >= neutral_at {
                    [0.0, 0.0]
                } else {
                    [1.0, 0.0]
                },
                gripper: 0.0,
                buttons: 0,
            });
        }
        rec
    }

    #[test]
    fn a_stop_at_the_documented_deceleration_keeps_the_promise() {
        let rec = run(0.5, 1.0, 45, 40);
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(true)).unwrap();
        assert_eq!(f.fault_tick, 10);
        assert_eq!(f.stop_ticks, Some(0));
        assert!(f.travel_rad <= f.promised_travel_rad, "{f:?}");
        assert_eq!(f.resumed, "after-neutral");
        assert!(judge(&f, &promise(true), 0).is_empty());
    }

    /// A stop at a fifth of the documented deceleration travels five times the braking
    /// distance: the row fails, naming the distance.
    #[test]
    fn a_slower_stop_breaks_the_distance_promise() {
        let rec = run(0.5, 0.2, 59, 0);
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(true)).unwrap();
        let why = judge(&f, &promise(true), 0);
        assert!(
            why.iter().any(|w| w.contains("promised stop distance")),
            "{why:?}"
        );
    }

    #[test]
    fn motion_before_neutral_and_leftovers_fail() {
        let rec = run(0.5, 1.0, 45, 50);
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(true)).unwrap();
        assert_eq!(f.resumed, "before-neutral");
        let why = judge(&f, &promise(true), 3);
        assert_eq!(why.len(), 2, "{why:?}");
    }

    /// A recording cut before the fault (its recorder killed) is filled in from the drill's
    /// own view after its end, and the stop measured there; a whole one gets nothing.
    #[test]
    fn the_drills_view_fills_in_after_a_cut_recording() {
        let whole = run(0.5, 1.0, 45, 40);
        let mut cut = whole.clone();
        cut.states.truncate(8);
        let fault_ns = 1_000 + 10 * 25_000_000;
        assert!(measure(&cut, fault_ns, &promise(true)).is_none());
        cut.fill_after_end(&whole.states);
        assert_eq!(cut.states, whole.states);
        let f = measure(&cut, fault_ns, &promise(true)).unwrap();
        assert_eq!(f.stop_ticks, Some(0));
        let mut again = whole.clone();
        again.fill_after_end(&whole.states[..20]);
        assert_eq!(again.states, whole.states);
    }

    /// An action outside the stick's disc mapped after the fault breaks every row's promise
    /// (the mapper clamps each input to the disc); one on its edge does not.
    #[test]
    fn an_action_outside_the_disc_fails() {
        let mut rec = run(0.5, 1.0, 45, 40);
        rec.mapper = vec![(5, 7.0), (10, 1.0), (11, 0.3)];
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(true)).unwrap();
        assert_eq!(f.max_action, 1.0);
        assert!(judge(&f, &promise(true), 0).is_empty());
        rec.mapper.push((12, 50.0));
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(true)).unwrap();
        let why = judge(&f, &promise(true), 0);
        assert!(
            why.iter().any(|w| w.contains("outside the stick's disc")),
            "{why:?}"
        );
    }

    #[test]
    fn a_swap_must_not_stop() {
        let rec = run(0.5, 1.0, 45, 40);
        let f = measure(&rec, 1_000 + 10 * 25_000_000, &promise(false)).unwrap();
        let why = judge(&f, &promise(false), 0);
        assert!(why.iter().any(|w| w.contains("stop commands")), "{why:?}");
    }
}
