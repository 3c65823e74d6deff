//! `/scl/log` (`foxglove.Log`): what the graph's processes and the safety filter say, as an
//! observer sees it in the graph's messages, one line per change (never one per tick):
//!
//! * a process's heartbeats: first seen (info), a new phase (info), new faults (warning, at
//!   most once a second per process), safety's state entering or leaving e-stop, hold or
//!   "waiting for neutral input" (warning on entering, info on leaving);
//! * safety's commands: a rule that starts acting (warning for the rules that stop the arm or
//!   refuse input: e-stop, hold, stop, stale or non-finite input, bad shape, deadman, waiting
//!   for neutral; info for the limits that scale: velocity, acceleration, position,
//!   workspace, clearance, speed cap);
//! * e-stop and reset requests (error / info) and the supervisor's switches and holds (info).
//!
//! Each line's `name` is the process (`safety`, `mapper-2`, `supervisor`, `pid 1234`), its
//! timestamp the monotonic time of the message it comes from.
//!
//! Beside these, the processes' own log records (what each wrote to its log at INFO and
//! above, [`LogRecord`], from the graph's `log` topic) become lines too ([`record_line`]):
//! name the process, level its level, message its text.

use std::collections::BTreeMap;

use foxglove::messages::Log;
use foxglove::messages::log::Level;
use ipc_types::control::{EstopCommand, SafetyControl, estop_action};
use ipc_types::{
    LogRecord, NodeRole, NodeStatus, SafeCommand, log_level, phase, safe_flags, safety_state,
};
use recording::Payload;

use crate::scene::timestamp;

/// The safety rules whose start is a warning (the others scale a command: info).
const WARN_RULES: u32 = safe_flags::NON_FINITE
    | safe_flags::STALE_STATE
    | safe_flags::STALE_JOYSTICK
    | safe_flags::STALE_COMMAND
    | safe_flags::STOP
    | safe_flags::BAD_SHAPE
    | safe_flags::HOLD
    | safe_flags::DEADMAN
    | safe_flags::ESTOP
    | safe_flags::AWAITING_NEUTRAL;

/// How often a process's growing fault count is logged at most (ns).
const FAULTS_EVERY_NS: u64 = 1_000_000_000;

/// What a process last said.
#[derive(Debug, Clone, Copy, Default)]
struct Seen {
    phase: u32,
    faults: u64,
    safety_state: u32,
    faults_logged_ns: Option<u64>,
}

/// The log's state: what each process and the filter last said.
#[derive(Debug, Default)]
pub struct LogView {
    processes: BTreeMap<u32, Seen>,
    /// The rules acting in the last safe command.
    last_flags: u32,
    last_control: Option<SafetyControl>,
}

fn line(level: Level, name: &str, t_ns: u64, message: String) -> Log {
    Log {
        timestamp: Some(timestamp(t_ns)),
        level: level as i32,
        message,
        name: name.to_owned(),
        file: String::new(),
        line: 0,
    }
}

/// The `/scl/log` line of a process's own log record.
pub fn record_line(r: &LogRecord) -> Log {
    let level = match r.level {
        log_level::ERROR => Level::Error,
        log_level::WARN => Level::Warning,
        log_level::INFO => Level::Info,
        log_level::DEBUG | log_level::TRACE => Level::Debug,
        _ => Level::Unknown,
    };
    let name = r.process();
    let name = if name.is_empty() {
        format!("pid {}", r.pid)
    } else {
        name.into_owned()
    };
    line(level, &name, r.t_ns, r.text().into_owned())
}

fn process_name(st: &NodeStatus) -> String {
    match NodeRole::from_u32(st.role) {
        Some(NodeRole::Mapper) => format!("mapper-{}", st.mapper_id),
        Some(r) => r.name().to_owned(),
        None => format!("pid {}", st.pid),
    }
}

fn phase_name(p: u32) -> &'static str {
    match p {
        phase::READY => "ready",
        phase::RUNNING => "running",
        phase::STOPPING => "stopping",
        _ => "starting",
    }
}

fn names(bits: u32, all: &[&str]) -> String {
    all.iter()
        .enumerate()
        .filter(|(i, _)| bits & (1 << i) != 0)
        .map(|(_, n)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

impl LogView {
    /// The lines message `p` adds, appended to `out`.
    pub fn observe(&mut self, p: &Payload, out: &mut Vec<Log>) {
        match p {
            Payload::Status(st) => self.status(st, out),
            Payload::SafeCommand(c) => self.safe(c, out),
            Payload::Estop(e) => Self::estop(e, out),
            Payload::SafetyControl(c) => self.control(c, out),
            _ => {}
        }
    }

    fn status(&mut self, st: &NodeStatus, out: &mut Vec<Log>) {
        let name = process_name(st);
        let t = st.t_ns;
        let Some(seen) = self.processes.get_mut(&st.pid) else {
            out.push(line(
                Level::Info,
                &name,
                t,
                format!("{name} (pid {}) is {}", st.pid, phase_name(st.phase)),
            ));
            self.processes.insert(
                st.pid,
                Seen {
                    phase: st.phase,
                    faults: st.faults,
                    safety_state: st.safety_state,
                    faults_logged_ns: None,
                },
            );
            return;
        };
        if st.phase != seen.phase {
            out.push(line(
                Level::Info,
                &name,
                t,
                format!("{name} (pid {}) is {}", st.pid, phase_name(st.phase)),
            ));
            seen.phase = st.phase;
        }
        if st.faults > seen.faults
            && seen
                .faults_logged_ns
                .is_none_or(|w| t < w || t - w >= FAULTS_EVERY_NS)
        {
            out.push(line(
                Level::Warning,
                &name,
                t,
                format!(
                    "{name}: {} new faults ({} in all)",
                    st.faults - seen.faults,
                    st.faults
                ),
            ));
            seen.faults = st.faults;
            seen.faults_logged_ns = Some(t);
        }
        if NodeRole::from_u32(st.role) == Some(NodeRole::Safety)
            && st.safety_state != seen.safety_state
        {
            let entered = st.safety_state & !seen.safety_state;
            let left = seen.safety_state & !st.safety_state;
            if entered != 0 {
                out.push(line(
                    Level::Warning,
                    &name,
                    t,
                    format!("safety: {}", names(entered, &safety_state::NAMES)),
                ));
            }
            if left != 0 {
                out.push(line(
                    Level::Info,
                    &name,
                    t,
                    format!("safety: {} cleared", names(left, &safety_state::NAMES)),
                ));
            }
            seen.safety_state = st.safety_state;
        }
    }

    fn safe(&mut self, c: &SafeCommand, out: &mut Vec<Log>) {
        let started = c.flags & !self.last_flags;
        self.last_flags = c.flags;
        let warn = started & WARN_RULES;
        let info = started & !WARN_RULES;
        if warn != 0 {
            out.push(line(
                Level::Warning,
                "safety",
                c.t_ns,
                format!(
                    "safety, tick {}: {}",
                    c.tick,
                    names(warn, &safe_flags::NAMES)
                ),
            ));
        }
        if info != 0 {
            out.push(line(
                Level::Info,
                "safety",
                c.t_ns,
                format!(
                    "safety, tick {}: {}",
                    c.tick,
                    names(info, &safe_flags::NAMES)
                ),
            ));
        }
    }

    fn estop(e: &EstopCommand, out: &mut Vec<Log>) {
        let (level, what) = match e.action {
            estop_action::ESTOP => (Level::Error, "e-stop"),
            estop_action::RESET => (Level::Info, "reset"),
            _ => (Level::Warning, "unknown e-stop action"),
        };
        out.push(line(
            level,
            "estop",
            e.t_ns,
            format!("{what} requested by pid {}", e.source_pid),
        ));
    }

    fn control(&mut self, c: &SafetyControl, out: &mut Vec<Log>) {
        let last = self.last_control.replace(*c);
        if last.is_none_or(|l| l.active_mapper != c.active_mapper) {
            out.push(line(
                Level::Info,
                "supervisor",
                c.t_ns,
                format!(
                    "mapper {} drives the arm from tick {}",
                    c.active_mapper, c.from_tick
                ),
            ));
        }
        if last.map_or(c.hold != 0, |l| l.hold != c.hold) {
            let (level, what) = if c.hold != 0 {
                (
                    Level::Warning,
                    "holds the arm (an input-side process is down)",
                )
            } else {
                (Level::Info, "releases the hold")
            };
            out.push(line(
                level,
                "supervisor",
                c.t_ns,
                format!("supervisor {what}"),
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn safe(tick: u64, flags: u32) -> Payload {
        Payload::SafeCommand(SafeCommand {
            tick,
            t_ns: tick * 25_000_000,
            flags,
            ..SafeCommand::zeroed()
        })
    }

    #[test]
    fn a_process_log_record_is_a_line_with_its_name_and_level() {
        let mut r = LogRecord::zeroed();
        r.t_ns = 1_500_000_000;
        r.pid = 9;
        r.level = log_level::WARN;
        r.set_process("mapper-2");
        r.push_text("input stale tick=4");
        let l = record_line(&r);
        assert_eq!(
            (l.level, l.name.as_str(), l.message.as_str()),
            (Level::Warning as i32, "mapper-2", "input stale tick=4")
        );
        assert_eq!(l.timestamp.unwrap().sec(), 1);
        r.process = [0; ipc_types::LOG_PROCESS_BYTES];
        assert_eq!(record_line(&r).name, "pid 9");
    }

    #[test]
    fn a_rule_is_logged_when_it_starts_acting_not_every_tick() {
        let mut v = LogView::default();
        let mut out = Vec::new();
        v.observe(&safe(1, 0), &mut out);
        assert!(out.is_empty());
        v.observe(
            &safe(2, safe_flags::STALE_JOYSTICK | safe_flags::ACCEL_LIMITED),
            &mut out,
        );
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].level, Level::Warning as i32);
        assert!(
            out[0].message.contains("stale-joystick"),
            "{}",
            out[0].message
        );
        assert_eq!(out[1].level, Level::Info as i32);
        out.clear();
        for k in 3..50 {
            v.observe(&safe(k, safe_flags::STALE_JOYSTICK), &mut out);
        }
        assert!(out.is_empty(), "{out:?}");
    }

    #[test]
    fn processes_safety_states_and_estops_are_logged_once_each() {
        let mut v = LogView::default();
        let mut out = Vec::new();
        let mut st = NodeStatus::new(NodeRole::Safety, phase::READY, 10);
        st.pid = 42;
        v.observe(&Payload::Status(st), &mut out);
        st.phase = phase::RUNNING;
        v.observe(&Payload::Status(st), &mut out);
        v.observe(&Payload::Status(st), &mut out);
        st.safety_state = safety_state::ESTOP;
        v.observe(&Payload::Status(st), &mut out);
        st.safety_state = 0;
        v.observe(&Payload::Status(st), &mut out);
        v.observe(
            &Payload::Estop(EstopCommand {
                t_ns: 5,
                action: estop_action::ESTOP,
                source_pid: 7,
            }),
            &mut out,
        );
        let msgs: Vec<(i32, &str)> = out.iter().map(|l| (l.level, l.message.as_str())).collect();
        assert_eq!(
            msgs,
            vec![
                (Level::Info as i32, "safety (pid 42) is ready"),
                (Level::Info as i32, "safety (pid 42) is running"),
                (Level::Warning as i32, "safety: e-stop"),
                (Level::Info as i32, "safety: e-stop cleared"),
                (Level::Error as i32, "e-stop requested by pid 7"),
            ]
        );
    }
}
