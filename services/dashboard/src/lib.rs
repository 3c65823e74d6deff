//! `scl top`: a terminal dashboard of a running graph, made for an 80x24 terminal over SSH.
//!
//! Three layers, so the picture is testable without a terminal or a graph:
//!
//! * [`Model`] takes in messages (heartbeats, robot states, joystick samples, executed
//!   commands) and keeps what the dashboard needs: per-node heartbeat history for rates and
//!   liveness, a window of the bridge's end-to-end latencies and misses.
//! * [`Model::view`] turns it into a [`View`]: plain values, no history.
//! * [`render`] draws a [`View`] into a ratatui frame, a pure function of the view.
//!
//! The loop ([`cli`]) subscribes read-only, redraws ten times a second, and maps keys
//! ([`key_action`], a pure function) to `scl estop` / `scl reset` ([`graph_client::control::estop`],
//! in a thread so the picture keeps moving while safety confirms) and `q` to quit. `scl top --once` prints one 80x24 frame as
//! text after listening for a second, for scripts and logs.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use ipc_types::{
    JoystickInput, NO_TICK, NodeRole, NodeStatus, Prefix, RobotState, SafeCommand, buttons, phase,
    safe_flags, safety_state, time::now_ns,
};
use kinematics::{ArmLimits, RobotProfile};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Modifier, Style};
use ratatui::symbols::Marker;
use ratatui::text::{Line, Span};
use ratatui::widgets::canvas::{Canvas, Circle};
use ratatui::widgets::{Block, Borders, Paragraph};
use transport::Graph;

use node_rt::stats::{Percentiles, percentiles_us};

/// Width and height the dashboard is laid out for (it uses more when it gets it).
pub const SIZE: (u16, u16) = (80, 24);

/// Heartbeats older than this count as gone (ms), as in `scl status`.
pub const ALIVE_MS: f64 = 250.0;

/// Window of the latency percentiles and recent misses (s).
pub const WINDOW_S: f64 = 10.0;

/// How long `--once` listens before it draws (s).
const ONCE_LISTEN: Duration = Duration::from_secs(1);

/// A node that sent no heartbeat for this long leaves the table (ns).
const FORGET_NS: u64 = 30_000_000_000;

/// Heartbeat history kept for a node's rate (ns).
const RATE_SPAN_NS: u64 = 2_000_000_000;

/// `scl top`'s arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct TopArgs {
    /// Listen for a second, print one 80x24 frame as text and exit (no terminal needed).
    #[arg(long)]
    pub once: bool,
    /// Watch a graph on another machine through its Zenoh gateway (`[network]` there): its
    /// endpoint, e.g. `tcp/192.0.2.10:7447`. The keys' e-stop and reset go through the gateway
    /// (which must accept them from this login).
    #[arg(long, value_name = "ENDPOINT")]
    pub remote: Option<String>,
    /// With `--remote`: a credentials file (`user:password`, mode 0600; default `[network]
    /// credentials`, if any); without one, the view is read-only.
    #[arg(long, value_name = "FILE", requires = "remote")]
    pub credentials: Option<std::path::PathBuf>,
}

/// Why the dashboard could not run.
#[derive(Debug, thiserror::Error)]
pub enum TopError {
    /// The terminal could not be set up or drawn to.
    #[error(
        "cannot drive the terminal: {0} (scl top needs an interactive terminal; `scl top --once` prints a snapshot)"
    )]
    Terminal(std::io::Error),
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// An e-stop or reset request failed.
    #[error(transparent)]
    Control(#[from] graph_client::ControlError),
    /// The Zenoh session to a remote graph's gateway.
    #[error(transparent)]
    Session(#[from] scl_net::SessionError),
    /// A client session to a remote graph's gateway could not be opened.
    #[error(transparent)]
    Client(#[from] scl_net::session::ClientError),
}

/// One node as the dashboard shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeView {
    /// Role name.
    pub role: String,
    /// Process id.
    pub pid: u32,
    /// Mapper id (0: none).
    pub mapper_id: u32,
    /// Heartbeat fresh and process alive.
    pub alive: bool,
    /// Ticks (recorder: messages) handled per second, once measurable.
    pub rate_hz: Option<f64>,
    /// Ticks handled (recorder: messages received).
    pub handled: u64,
    /// Faults (bridge: missed ticks; recorder: dropped messages).
    pub faults: u64,
}

/// One joint against its limits.
#[derive(Debug, Clone, PartialEq)]
pub struct JointView {
    /// Short name (`j1`).
    pub name: String,
    /// Angle (rad).
    pub q_rad: f64,
    /// Lower limit (rad).
    pub lower_rad: f64,
    /// Upper limit (rad).
    pub upper_rad: f64,
    /// Velocity (rad/s).
    pub qdot_rad_s: f64,
}

/// The joystick's newest sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JoystickView {
    /// The two axes.
    pub axes: [f32; 2],
    /// Button bits.
    pub buttons: u32,
}

/// Everything the dashboard draws: plain values, so [`render`] is a pure function of it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct View {
    /// The graph prefix.
    pub prefix: String,
    /// The newest robot tick.
    pub tick: Option<u64>,
    /// The mapper safety forwards.
    pub active_mapper: Option<u32>,
    /// The active mapper's mode (`x-y`, `z-yaw`, `roll-pitch`), from its heartbeat; `None`
    /// for a map without modes, or while no mapper is known to be active.
    pub mode: Option<String>,
    /// The active mapper's mode switches since it started (with [`View::mode`]).
    pub mode_switches: Option<u32>,
    /// Safety's e-stop is latched.
    pub estop: bool,
    /// The supervisor holds the arm.
    pub hold: bool,
    /// Nodes with heartbeats.
    pub nodes: Vec<NodeView>,
    /// End-to-end latency over the last [`WINDOW_S`] (µs).
    pub latency_us: Option<Percentiles>,
    /// Tick lateness p99 over the window (µs).
    pub lateness_p99_us: Option<f64>,
    /// Ticks missed since the bridge started.
    pub missed_total: u64,
    /// Ticks missed in the last [`WINDOW_S`] ("recent").
    pub missed_recent: u64,
    /// Ticks each safety rule acted, by bit of `safe_flags`.
    pub rule_counts: [u32; safe_flags::COUNT],
    /// The newest executed command's rule bits.
    pub latest_flags: Option<u32>,
    /// The closest pair of the arm's collision model in the newest command (`None`: no
    /// command yet, or safety checked nothing).
    pub closest: Option<graph_client::control::Closest>,
    /// The newest joystick sample.
    pub joystick: Option<JoystickView>,
    /// The arm's joints.
    pub joints: Vec<JointView>,
    /// The gripper state.
    pub gripper: Option<f64>,
    /// A one-line message (the result of a key press, a warning).
    pub message: String,
}

struct Track {
    last: NodeStatus,
    /// (t_ns, handled), oldest first.
    samples: VecDeque<(u64, u64)>,
}

/// What the dashboard keeps of the graph's messages.
pub struct Model {
    prefix: String,
    limits: ArmLimits,
    tracks: Vec<Track>,
    /// Bridge heartbeats of new ticks: (t_ns, latency_ns, lateness_ns, faults, pid).
    bridge: VecDeque<(u64, u64, u64, u64, u32)>,
    last_bridge_tick: Option<u64>,
    state: Option<RobotState>,
    joystick: Option<JoystickInput>,
    safe: Option<SafeCommand>,
    alive_pids: Option<Vec<u32>>,
    box_names: Vec<String>,
    /// The message line.
    pub message: String,
}

impl Model {
    /// An empty model of graph `prefix` for an arm with `limits`.
    pub fn new(prefix: &str, limits: ArmLimits) -> Self {
        Self {
            prefix: prefix.to_owned(),
            limits,
            tracks: Vec::new(),
            bridge: VecDeque::new(),
            last_bridge_tick: None,
            state: None,
            joystick: None,
            safe: None,
            alive_pids: None,
            box_names: Vec::new(),
            message: String::new(),
        }
    }

    /// Names the scene's boxes (`[safety.scene]`, in order) in the closest pair's line.
    pub fn with_box_names(mut self, names: Vec<String>) -> Self {
        self.box_names = names;
        self
    }

    /// Takes in a heartbeat.
    pub fn take_status(&mut self, s: &NodeStatus) {
        let i = match self
            .tracks
            .iter()
            .position(|t| t.last.pid == s.pid && t.last.role == s.role)
        {
            Some(i) => i,
            None => {
                self.tracks.push(Track {
                    last: *s,
                    samples: VecDeque::new(),
                });
                self.tracks.len() - 1
            }
        };
        let t = &mut self.tracks[i];
        if s.t_ns >= t.last.t_ns {
            t.last = *s;
        }
        t.samples.push_back((s.t_ns, s.handled));
        while t
            .samples
            .front()
            .is_some_and(|(t0, _)| s.t_ns.saturating_sub(*t0) > RATE_SPAN_NS)
        {
            t.samples.pop_front();
        }
        if s.role == NodeRole::Bridge as u32
            && s.phase == phase::RUNNING
            && s.tick != NO_TICK
            && self.last_bridge_tick != Some(s.tick)
        {
            self.last_bridge_tick = Some(s.tick);
            self.bridge
                .push_back((s.t_ns, s.latency_ns, s.lateness_ns, s.faults, s.pid));
            let window_ns = (WINDOW_S * 1e9) as u64;
            while self
                .bridge
                .front()
                .is_some_and(|b| s.t_ns.saturating_sub(b.0) > window_ns)
            {
                self.bridge.pop_front();
            }
        }
    }

    /// Takes in a robot state.
    pub fn take_state(&mut self, s: &RobotState) {
        if self
            .state
            .is_none_or(|o| s.tick >= o.tick || s.t_ns > o.t_ns)
        {
            self.state = Some(*s);
        }
    }

    /// Takes in a joystick sample.
    pub fn take_joystick(&mut self, j: &JoystickInput) {
        self.joystick = Some(*j);
    }

    /// Takes in an executed command.
    pub fn take_safe(&mut self, c: &SafeCommand) {
        self.safe = Some(*c);
    }

    /// Sets the process ids of the graph's live iceoryx2 nodes (liveness beyond heartbeats).
    pub fn set_alive(&mut self, pids: Vec<u32>) {
        self.alive_pids = Some(pids);
    }

    /// The bridge's recent latency and lateness percentiles and its recent misses, into `v`.
    fn bridge_figures(&self, v: &mut View) {
        let lat: Vec<u64> = self.bridge.iter().map(|b| b.1).filter(|l| *l > 0).collect();
        if !lat.is_empty() {
            v.latency_us = Some(percentiles_us(&lat));
        }
        let late: Vec<u64> = self.bridge.iter().map(|b| b.2).collect();
        v.lateness_p99_us = Some(percentiles_us(&late).p99);
        if let (Some(first), Some(last)) = (self.bridge.front(), self.bridge.back()) {
            // A restarted bridge counts from zero: only a same-process difference counts.
            v.missed_recent = if first.4 == last.4 {
                last.3.saturating_sub(first.3)
            } else {
                last.3
            };
        }
    }

    /// The view at monotonic time `now`.
    pub fn view(&self, now: u64) -> View {
        let mut v = View {
            prefix: self.prefix.clone(),
            message: self.message.clone(),
            ..View::default()
        };
        let mut tracks: Vec<&Track> = self
            .tracks
            .iter()
            .filter(|t| now.saturating_sub(t.last.t_ns) < FORGET_NS)
            .collect();
        tracks.sort_by_key(|t| (t.last.role, t.last.mapper_id, t.last.pid));
        for t in tracks {
            let s = &t.last;
            let age_ms = now.saturating_sub(s.t_ns) as f64 / 1e6;
            let alive = age_ms < ALIVE_MS
                && s.phase != phase::STOPPING
                && self.alive_pids.as_ref().is_none_or(|p| p.contains(&s.pid));
            let rate_hz = match (t.samples.front(), t.samples.back()) {
                (Some(a), Some(b)) if b.0.saturating_sub(a.0) >= 400_000_000 && alive => {
                    Some(b.1.saturating_sub(a.1) as f64 / ((b.0 - a.0) as f64 / 1e9))
                }
                _ => None,
            };
            let role = NodeRole::from_u32(s.role);
            if alive && role == Some(NodeRole::Safety) {
                v.active_mapper = Some(s.mapper_id);
                v.estop = s.safety_state & safety_state::ESTOP != 0;
                v.hold = s.safety_state & safety_state::HOLD != 0;
                for (i, c) in v.rule_counts.iter_mut().enumerate() {
                    *c = s.rule_counts[i];
                }
            }
            if role == Some(NodeRole::Bridge) && s.phase != phase::READY {
                v.missed_total = s.faults;
                if v.tick.is_none() && s.tick != NO_TICK {
                    v.tick = Some(s.tick);
                }
            }
            v.nodes.push(NodeView {
                role: role.map_or_else(|| format!("role {}", s.role), |r| r.name().to_owned()),
                pid: s.pid,
                mapper_id: s.mapper_id,
                alive,
                rate_hz,
                handled: s.handled,
                faults: s.faults,
            });
        }
        if !self.bridge.is_empty() {
            self.bridge_figures(&mut v);
        }
        if let Some(s) = &self.state {
            v.tick = Some(s.tick);
            let n = (s.n_joints as usize).min(self.limits.n_joints());
            v.joints = (0..n)
                .map(|j| JointView {
                    name: format!("j{}", j + 1),
                    q_rad: s.q_rad[j],
                    lower_rad: self.limits.lower_rad[j],
                    upper_rad: self.limits.upper_rad[j],
                    qdot_rad_s: s.qdot_rad_s[j],
                })
                .collect();
            v.gripper = Some(s.gripper);
        }
        // The active mapper's mode: from its own heartbeat, once safety names it.
        if let Some(active) = v.active_mapper
            && let Some(m) = self
                .tracks
                .iter()
                .map(|t| &t.last)
                .filter(|s| {
                    s.role == NodeRole::Mapper as u32
                        && s.mapper_id == active
                        && s.mode > 0
                        && s.phase != phase::STOPPING
                        && now.saturating_sub(s.t_ns) as f64 / 1e6 < ALIVE_MS
                })
                .max_by_key(|s| s.t_ns)
        {
            v.mode = Some(graph_client::control::mode_name(m.mode));
            v.mode_switches = Some(m.mode_switches);
        }
        v.joystick = self.joystick.map(|j| JoystickView {
            axes: j.axes,
            buttons: j.buttons,
        });
        v.latest_flags = self.safe.map(|c| c.flags);
        v.closest = self
            .safe
            .and_then(|c| graph_client::control::Closest::of(&c, &self.box_names));
        v
    }
}

/// A bar of `width` cells for `q` between `lo` and `hi`: `─` track, `┼` at zero, `●` at `q`
/// (clamped to the bar; `◀` / `▶` when beyond a limit).
pub fn joint_bar(q: f64, lo: f64, hi: f64, width: usize) -> String {
    if width == 0 || hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return String::new();
    }
    let cell = |x: f64| {
        let f = (x - lo) / (hi - lo);
        ((f * width as f64).floor() as i64).clamp(0, width as i64 - 1) as usize
    };
    let mut cells = vec!['─'; width];
    if lo < 0.0 && hi > 0.0 {
        cells[cell(0.0)] = '┼';
    }
    cells[cell(q)] = if !q.is_finite() {
        '?'
    } else if q < lo {
        '◀'
    } else if q > hi {
        '▶'
    } else {
        '●'
    };
    cells.into_iter().collect()
}

/// How close a joint is to its nearest limit, as a fraction of its range (0 at a limit).
fn limit_distance(j: &JointView) -> f64 {
    let range = j.upper_rad - j.lower_rad;
    ((j.q_rad - j.lower_rad).min(j.upper_rad - j.q_rad) / range).max(0.0)
}

/// The dot of the joystick in its unit circle: a canvas in `area` (text beside it).
fn joystick_canvas(
    j: Option<JoystickView>,
) -> Canvas<'static, impl Fn(&mut ratatui::widgets::canvas::Context<'_>)> {
    Canvas::default()
        .marker(Marker::Braille)
        .x_bounds([-1.25, 1.25])
        .y_bounds([-1.25, 1.25])
        .paint(move |ctx| {
            ctx.draw(&Circle {
                x: 0.0,
                y: 0.0,
                radius: 1.0,
                color: Color::DarkGray,
            });
            ctx.layer();
            match j {
                Some(j) => {
                    let (x, y) = (f64::from(j.axes[0]), f64::from(j.axes[1]));
                    let (x, y) = if x.is_finite() && y.is_finite() {
                        (x.clamp(-1.2, 1.2), y.clamp(-1.2, 1.2))
                    } else {
                        (0.0, 0.0)
                    };
                    ctx.print(x, y, Span::styled("●", Style::new().fg(Color::Yellow)));
                }
                None => ctx.print(0.0, 0.0, "?"),
            }
        })
}

fn fmt_us(us: f64) -> String {
    if us >= 10_000.0 {
        format!("{:.0} ms", us / 1000.0)
    } else if us >= 1000.0 {
        format!("{:.1} ms", us / 1000.0)
    } else {
        format!("{us:.0} µs")
    }
}

/// The mode as the title shows it, in the longest of its forms (`z-yaw (2 switches)`,
/// `z-yaw (2 sw)`, `z-yaw`) that leaves `room` cells; `-` without a mode.
fn mode_text(v: &View, room: usize) -> String {
    let Some(name) = v.mode.as_deref() else {
        return "-".to_owned();
    };
    let Some(n) = v.mode_switches else {
        return name.to_owned();
    };
    let plural = if n == 1 { "switch" } else { "switches" };
    [format!("{name} ({n} {plural})"), format!("{name} ({n} sw)")]
        .into_iter()
        .find(|t| t.chars().count() <= room)
        .unwrap_or_else(|| name.to_owned())
}

/// The title row for a terminal `width` cells wide: the mode's text shrinks first, so the
/// e-stop state at the end stays in view.
fn title_line(v: &View, width: usize) -> Line<'static> {
    let bold = Style::new().add_modifier(Modifier::BOLD);
    let mut spans = vec![
        Span::styled(" scl top ", bold.add_modifier(Modifier::REVERSED)),
        Span::raw(format!(" graph `{}`", v.prefix)),
        Span::raw(format!(
            "  tick {}",
            v.tick.map_or("-".to_owned(), |t| t.to_string())
        )),
        Span::raw(format!(
            "  mapper {}",
            v.active_mapper.map_or("-".to_owned(), |m| m.to_string())
        )),
    ];
    let mut tail = vec![Span::raw("  ")];
    if v.estop {
        tail.push(Span::styled(
            " E-STOP ",
            Style::new()
                .fg(Color::White)
                .bg(Color::Red)
                .add_modifier(Modifier::BOLD),
        ));
    } else {
        tail.push(Span::styled("e-stop off", Style::new().fg(Color::Green)));
    }
    if v.hold {
        tail.push(Span::styled(" HOLD", Style::new().fg(Color::Yellow)));
    }
    let used: usize = spans.iter().chain(&tail).map(Span::width).sum();
    let label = "  mode ";
    let room = width.saturating_sub(used + label.len());
    spans.push(Span::raw(format!("{label}{}", mode_text(v, room))));
    spans.extend(tail);
    Line::from(spans)
}

fn node_lines(v: &View, rows: usize) -> Vec<Line<'static>> {
    let mut out = vec![Line::styled(
        format!(
            "{:<9}{:>8} {:>3} {:<5} {:>6} {:>9} {:>6}",
            "NODE", "PID", "ID", "LIVE", "HZ", "HANDLED", "FAULTS"
        ),
        Style::new().add_modifier(Modifier::BOLD),
    )];
    if v.nodes.is_empty() {
        out.push(Line::styled(
            "no heartbeat yet: is the graph running with this prefix?",
            Style::new().fg(Color::Yellow),
        ));
    }
    let shown = v.nodes.len().min(rows.saturating_sub(1));
    for n in &v.nodes[..shown] {
        let live = if n.alive {
            Span::styled(format!("{:<5}", "yes"), Style::new().fg(Color::Green))
        } else {
            Span::styled(format!("{:<5}", "GONE"), Style::new().fg(Color::Red))
        };
        let faults_style = if n.faults > 0 {
            Style::new().fg(Color::Yellow)
        } else {
            Style::new()
        };
        out.push(Line::from(vec![
            Span::raw(format!(
                "{:<9}{:>8} {:>3} ",
                n.role,
                n.pid,
                if n.mapper_id > 0 {
                    n.mapper_id.to_string()
                } else {
                    "-".into()
                }
            )),
            live,
            Span::raw(format!(
                " {:>6} {:>9} ",
                n.rate_hz.map_or("-".to_owned(), |r| format!("{r:.1}")),
                n.handled
            )),
            Span::styled(format!("{:>6}", n.faults), faults_style),
        ]));
    }
    if v.nodes.len() > shown
        && let Some(last) = out.last_mut()
    {
        *last = Line::raw(format!("… and {} more nodes", v.nodes.len() - shown + 1));
    }
    out
}

fn timing_line(v: &View) -> Line<'static> {
    let lat = match &v.latency_us {
        Some(p) => format!(
            "e2e p50 {}  p99 {}  max {}",
            fmt_us(p.p50),
            fmt_us(p.p99),
            fmt_us(p.max)
        ),
        None => "e2e latency: no ticks yet".to_owned(),
    };
    let missed_style = if v.missed_recent > 0 {
        Style::new().fg(Color::Red).add_modifier(Modifier::BOLD)
    } else {
        Style::new()
    };
    Line::from(vec![
        Span::raw(format!("{lat}  ")),
        Span::styled(
            format!("missed {} ({} recent)", v.missed_total, v.missed_recent),
            missed_style,
        ),
        Span::raw(format!(
            "  late p99 {}",
            v.lateness_p99_us.map_or("-".to_owned(), fmt_us)
        )),
    ])
}

/// `closest: forearm-table 0.043 m  tool 0.120 m/s`, in yellow while the clearance rule acts.
fn closest_line(v: &View) -> Line<'static> {
    let Some(c) = &v.closest else {
        return Line::styled("closest: -", Style::new().fg(Color::DarkGray));
    };
    let acting = v
        .latest_flags
        .is_some_and(|f| f & safe_flags::CLEARANCE_LIMITED != 0);
    let style = if acting {
        Style::new().fg(Color::Yellow).add_modifier(Modifier::BOLD)
    } else {
        Style::new()
    };
    Line::from(vec![
        Span::styled(c.text(), style),
        Span::raw(format!("  tool {:.3} m/s", c.tcp_speed_m_s)),
    ])
}

/// The rules that acted, in rows of `width` cells: `name count`, in reverse video where the
/// newest executed command had the rule act. Rules that never acted are left out, so a long
/// run's large counts still fit.
fn rule_lines(v: &View, width: usize, rows: usize) -> Vec<Line<'static>> {
    let mut lines: Vec<Vec<Span<'static>>> = vec![Vec::new()];
    let mut used = 0;
    let mut shown = 0;
    let acted: Vec<usize> = (0..safe_flags::COUNT)
        .filter(|bit| {
            v.rule_counts[*bit] > 0 || v.latest_flags.is_some_and(|f| f & (1 << bit) != 0)
        })
        .collect();
    for &bit in &acted {
        let acting = v.latest_flags.is_some_and(|f| f & (1 << bit) != 0);
        let text = format!("{} {}", safe_flags::NAMES[bit], v.rule_counts[bit]);
        let cell = text.chars().count() + 2;
        if used + cell > width && used > 0 {
            if lines.len() == rows {
                break;
            }
            lines.push(Vec::new());
            used = 0;
        }
        let style = if acting {
            Style::new().add_modifier(Modifier::REVERSED | Modifier::BOLD)
        } else {
            Style::new()
        };
        if let Some(l) = lines.last_mut() {
            l.push(Span::styled(text, style));
            l.push(Span::raw("  "));
        }
        used += cell;
        shown += 1;
    }
    if acted.is_empty() {
        lines[0].push(Span::styled(
            "no rule has acted",
            Style::new().fg(Color::DarkGray),
        ));
    } else if shown < acted.len()
        && let Some(l) = lines.last_mut()
    {
        l.push(Span::raw(format!("+{} more", acted.len() - shown)));
    }
    lines.into_iter().map(Line::from).collect()
}

fn joint_lines(v: &View, width: usize) -> Vec<Line<'static>> {
    // "j1  -2.68[" + bar + "]+2.68   +1.234 rad  +0.100 rad/s"
    let fixed = 10 + 33;
    let bar_w = width.saturating_sub(fixed).max(8);
    let mut out: Vec<Line<'static>> = v
        .joints
        .iter()
        .map(|j| {
            let d = limit_distance(j);
            let style = if d < 0.02 {
                Style::new().fg(Color::Red).add_modifier(Modifier::BOLD)
            } else if d < 0.1 {
                Style::new().fg(Color::Yellow)
            } else {
                Style::new().fg(Color::Cyan)
            };
            Line::from(vec![
                Span::raw(format!("{:<3}{:>+6.2}[", j.name, j.lower_rad)),
                Span::styled(joint_bar(j.q_rad, j.lower_rad, j.upper_rad, bar_w), style),
                Span::raw(format!(
                    "]{:<+7.2}{:>+7.3} rad {:>+7.3} rad/s",
                    j.upper_rad, j.q_rad, j.qdot_rad_s
                )),
            ])
        })
        .collect();
    if out.is_empty() {
        out.push(Line::raw("no robot state yet"));
    }
    if let Some(c) = v.gripper {
        let w = bar_w;
        let filled = ((c.clamp(0.0, 1.0)) * w as f64).round() as usize;
        out.push(Line::raw(format!(
            "c  {:>6}[{}{}] {:.2} (0 open, 1 closed)",
            "",
            "█".repeat(filled),
            "·".repeat(w - filled),
            c
        )));
    }
    out
}

fn joystick_text(j: Option<JoystickView>) -> Vec<Line<'static>> {
    let Some(j) = j else {
        return vec![Line::raw("no input")];
    };
    let mut out = vec![
        Line::raw(format!("x {:>+5.2}", j.axes[0])),
        Line::raw(format!("y {:>+5.2}", j.axes[1])),
    ];
    for (bit, name) in [
        (buttons::DEADMAN, "deadman"),
        (buttons::ESTOP, "E-STOP"),
        (buttons::GRIPPER, "gripper"),
        (buttons::MODE, "mode"),
    ] {
        if j.buttons & bit != 0 {
            out.push(Line::styled(
                name.to_owned(),
                Style::new().add_modifier(Modifier::BOLD),
            ));
        }
    }
    out
}

/// Draws `v` into `frame`: a pure function of the view.
pub fn render(frame: &mut Frame<'_>, v: &View) {
    let area = frame.area();
    let [
        title,
        top,
        timing,
        closest,
        safety,
        joints,
        _,
        message,
        keys,
    ] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Length(7),
        Constraint::Length(1),
        Constraint::Length(1),
        Constraint::Length(4),
        Constraint::Length(8),
        Constraint::Min(0),
        Constraint::Length(1),
        Constraint::Length(1),
    ])
    .areas(area);
    frame.render_widget(Paragraph::new(title_line(v, title.width as usize)), title);

    let [nodes, stick] =
        Layout::horizontal([Constraint::Min(40), Constraint::Length(26)]).areas(top);
    frame.render_widget(Paragraph::new(node_lines(v, nodes.height as usize)), nodes);
    let stick_block = Block::new().borders(Borders::ALL).title(" joystick ");
    let inner = stick_block.inner(stick);
    frame.render_widget(stick_block, stick);
    let [circle, _, text] = Layout::horizontal([
        Constraint::Length(11),
        Constraint::Length(1),
        Constraint::Min(0),
    ])
    .areas(inner);
    frame.render_widget(joystick_canvas(v.joystick), circle);
    frame.render_widget(Paragraph::new(joystick_text(v.joystick)), text);

    frame.render_widget(Paragraph::new(timing_line(v)), timing);
    frame.render_widget(Paragraph::new(closest_line(v)), closest);

    let rules_block = Block::new()
        .borders(Borders::TOP)
        .title(" safety rules: ticks acted (highlighted: acting now) ");
    let rules_inner = rules_block.inner(safety);
    frame.render_widget(rules_block, safety);
    frame.render_widget(
        Paragraph::new(rule_lines(
            v,
            rules_inner.width as usize,
            rules_inner.height as usize,
        )),
        rules_inner,
    );

    let joints_block = Block::new()
        .borders(Borders::TOP)
        .title(" joints (rad) against their limits ");
    let joints_inner = joints_block.inner(joints);
    frame.render_widget(joints_block, joints);
    frame.render_widget(
        Paragraph::new(joint_lines(v, joints_inner.width as usize)),
        joints_inner,
    );

    frame.render_widget(
        Paragraph::new(Line::styled(
            v.message.clone(),
            Style::new().fg(Color::Yellow),
        )),
        message,
    );
    frame.render_widget(
        Paragraph::new(Line::from(vec![
            Span::styled(" q ", Style::new().add_modifier(Modifier::REVERSED)),
            Span::raw(" quit   "),
            Span::styled(" e ", Style::new().add_modifier(Modifier::REVERSED)),
            Span::raw(" e-stop   "),
            Span::styled(" r ", Style::new().add_modifier(Modifier::REVERSED)),
            Span::raw(" reset e-stop"),
        ])),
        keys,
    );
}

/// The text of a rendered buffer, one string per row (trailing blanks kept).
pub fn buffer_lines(buf: &ratatui::buffer::Buffer) -> Vec<String> {
    let w = buf.area.width as usize;
    buf.content()
        .chunks(w.max(1))
        .map(|row| row.iter().map(|c| c.symbol()).collect())
        .collect()
}

/// `v` drawn on an off-screen terminal of `width` x `height`, as text rows.
pub fn render_text(v: &View, width: u16, height: u16) -> Result<Vec<String>, TopError> {
    let mut t = ratatui::Terminal::new(ratatui::backend::TestBackend::new(width, height))
        .map_err(|e| TopError::Terminal(std::io::Error::other(e.to_string())))?;
    let frame = t
        .draw(|f| render(f, v))
        .map_err(|e| TopError::Terminal(std::io::Error::other(e.to_string())))?;
    Ok(buffer_lines(frame.buffer))
}

/// Where the dashboard's messages come from.
enum Feed {
    /// This machine's graph.
    Local(Box<LocalFeed>),
    /// A graph on another machine, through its gateway.
    Remote(RemoteFeed),
}

impl Feed {
    fn open(prefix: &Prefix, remote: Option<&RemoteOptions>) -> Result<Self, TopError> {
        Ok(match remote {
            Some(r) => Self::Remote(RemoteFeed::open(r)?),
            None => Self::Local(Box::new(LocalFeed::open(prefix)?)),
        })
    }

    fn poll(&mut self, m: &mut Model) -> Result<(), TopError> {
        match self {
            Self::Local(f) => f.poll(m),
            Self::Remote(f) => {
                f.poll(m);
                Ok(())
            }
        }
    }

    fn alive(&self) -> Vec<u32> {
        match self {
            Self::Local(f) => f.alive(),
            Self::Remote(f) => f.alive(),
        }
    }

    fn send_estop(&self, prefix: &Prefix, action: u32) -> std::sync::mpsc::Receiver<String> {
        match self {
            Self::Local(_) => send_estop(prefix, action),
            Self::Remote(f) => {
                let (tx, rx) = std::sync::mpsc::channel();
                let _ = tx.send(f.send_estop(action));
                rx
            }
        }
    }
}

/// `scl top --remote`: the gateway's endpoint, the login, the graph's namespace.
#[derive(Debug, Clone)]
pub struct RemoteOptions {
    /// The gateway's endpoint.
    pub endpoint: String,
    /// The credentials file, if any.
    pub credentials: Option<std::path::PathBuf>,
    /// The graph's namespace.
    pub namespace: String,
    /// Zenoh's lease (ms).
    pub lease_ms: u64,
}

/// A message from the gateway.
enum Arrived {
    Status(NodeStatus),
    State(RobotState),
    Joystick(JoystickInput),
    Safe(SafeCommand),
}

/// The dashboard's subscriptions to a remote graph's gateway.
struct RemoteFeed {
    rx: crossbeam_channel::Receiver<Arrived>,
    /// Each heartbeat's process and when it was last heard (the remote graph's processes
    /// cannot be listed from here).
    heard: std::collections::HashMap<u32, Instant>,
    estop: Option<scl_net::ports::Out<ipc_types::control::EstopCommand>>,
    _subscribers: Vec<scl_net::zenoh::pubsub::Subscriber<()>>,
    _session: scl_net::zenoh::Session,
}

impl RemoteFeed {
    fn open(o: &RemoteOptions) -> Result<Self, TopError> {
        use ipc_types::topics;
        use scl_net::ports::{self, Urgency};
        let (session, creds) =
            scl_net::session::open_client(&o.endpoint, o.credentials.as_deref(), o.lease_ms)?;
        let keys = scl_net::Keys::new(&o.namespace);
        let (tx, rx) = crossbeam_channel::bounded(4096);
        let mut subs = Vec::new();
        macro_rules! sub {
            ($ty:ty, $topic:expr, $variant:ident) => {{
                let tx = tx.clone();
                subs.push(ports::subscribe::<$ty, _>(
                    &session,
                    keys.topic($topic.name),
                    move |_, m| {
                        if let Ok(m) = m {
                            // A full queue drops: the view catches up on the next ones.
                            let _ = tx.try_send(Arrived::$variant(m));
                        }
                    },
                )?);
            }};
        }
        sub!(NodeStatus, topics::STATUS, Status);
        sub!(RobotState, topics::ROBOT_STATE, State);
        sub!(JoystickInput, topics::JOYSTICK, Joystick);
        sub!(SafeCommand, topics::SAFE_COMMAND, Safe);
        let estop = if creds.is_some() {
            Some(ports::publisher(&session, keys.estop(), Urgency::Control)?)
        } else {
            None
        };
        Ok(Self {
            rx,
            heard: std::collections::HashMap::new(),
            estop,
            _subscribers: subs,
            _session: session,
        })
    }

    fn poll(&mut self, m: &mut Model) {
        while let Ok(a) = self.rx.try_recv() {
            match a {
                Arrived::Status(s) => {
                    self.heard.insert(s.pid, Instant::now());
                    m.take_status(&s);
                }
                Arrived::State(s) => m.take_state(&s),
                Arrived::Joystick(j) => m.take_joystick(&j),
                Arrived::Safe(c) => m.take_safe(&c),
            }
        }
    }

    fn alive(&self) -> Vec<u32> {
        self.heard
            .iter()
            .filter(|(_, t)| t.elapsed() < Duration::from_secs(1))
            .map(|(p, _)| *p)
            .collect()
    }

    fn send_estop(&self, action: u32) -> String {
        let what = if action == ipc_types::control::estop_action::ESTOP {
            "e-stop"
        } else {
            "reset"
        };
        let Some(p) = &self.estop else {
            return format!("{what}: not sent: a remote view without --credentials is read-only");
        };
        match p.put(&ipc_types::control::EstopCommand {
            t_ns: now_ns(),
            action,
            source_pid: std::process::id(),
        }) {
            Ok(()) => {
                format!("{what} sent through the gateway; the title shows when safety has it")
            }
            Err(e) => format!("{what}: failed: {e}"),
        }
    }
}

/// The dashboard's read-only subscriptions.
struct LocalFeed {
    status: transport::TopicSubscriber<NodeStatus>,
    states: transport::TopicSubscriber<RobotState>,
    joystick: transport::TopicSubscriber<JoystickInput>,
    safe: transport::TopicSubscriber<SafeCommand>,
    graph: Graph,
}

impl LocalFeed {
    fn open(prefix: &Prefix) -> Result<Self, TopError> {
        let graph = Graph::join(prefix, &format!("top-{}", std::process::id()))?;
        Ok(Self {
            status: graph.status_subscriber()?,
            states: graph.robot_state_subscriber(false)?,
            joystick: graph.joystick_subscriber(false)?,
            safe: graph.safe_command_subscriber(false)?,
            graph,
        })
    }

    fn poll(&self, m: &mut Model) -> Result<(), TopError> {
        self.status.drain(|s| m.take_status(s))?;
        self.states.drain(|s| m.take_state(s))?;
        self.joystick.drain(|j| m.take_joystick(j))?;
        self.safe.drain(|c| m.take_safe(c))?;
        Ok(())
    }

    fn alive(&self) -> Vec<u32> {
        self.graph
            .alive_nodes()
            .into_iter()
            .map(|(_, p)| p)
            .collect()
    }
}

/// Sends an e-stop or reset in a thread; its result arrives on the returned channel.
fn send_estop(prefix: &Prefix, action: u32) -> std::sync::mpsc::Receiver<String> {
    let (tx, rx) = std::sync::mpsc::channel();
    let prefix = prefix.clone();
    std::thread::spawn(move || {
        let what = if action == ipc_types::control::estop_action::ESTOP {
            "e-stop latched"
        } else {
            "e-stop reset"
        };
        let msg = match graph_client::control::estop(
            &prefix,
            ipc_types::Transport::Iceoryx2,
            action,
            Duration::from_secs(2),
        ) {
            Ok(Some(pid)) => format!("{what} (confirmed by safety, pid {pid})"),
            Ok(None) => format!("{what}: NOT confirmed by safety within 2 s"),
            Err(e) => format!("{what}: failed: {e}"),
        };
        let _ = tx.send(msg);
    });
    rx
}

/// What a key does on the dashboard.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action {
    /// Leave the dashboard: `q`, Esc, Ctrl-C.
    Quit,
    /// Latch the e-stop: `e` or space.
    Estop,
    /// Reset the e-stop: `r`.
    Reset,
}

/// The action of a terminal key event, if any; only presses act (a held key's repeats and
/// releases do not send a second e-stop or reset).
pub fn key_action(k: &ratatui::crossterm::event::KeyEvent) -> Option<Action> {
    use ratatui::crossterm::event::{KeyCode, KeyEventKind, KeyModifiers};
    if k.kind != KeyEventKind::Press {
        return None;
    }
    match k.code {
        KeyCode::Char('c') if k.modifiers.contains(KeyModifiers::CONTROL) => Some(Action::Quit),
        KeyCode::Char('q') | KeyCode::Esc => Some(Action::Quit),
        KeyCode::Char('e') | KeyCode::Char(' ') => Some(Action::Estop),
        KeyCode::Char('r') => Some(Action::Reset),
        _ => None,
    }
}

fn run_terminal(
    prefix: &Prefix,
    remote: Option<&RemoteOptions>,
    robot: &RobotProfile,
    box_names: Vec<String>,
) -> Result<(), TopError> {
    use ratatui::crossterm::event::{self, Event};

    let mut feed = Feed::open(prefix, remote)?;
    let mut model = Model::new(prefix.as_str(), robot.limits().clone()).with_box_names(box_names);
    let mut terminal = ratatui::try_init().map_err(TopError::Terminal)?;
    let mut pending: Vec<std::sync::mpsc::Receiver<String>> = Vec::new();
    let mut last_alive = Instant::now() - Duration::from_secs(10);
    let result = (|| -> Result<(), TopError> {
        while !transport::signals::stop_requested() {
            feed.poll(&mut model)?;
            if last_alive.elapsed() >= Duration::from_secs(1) {
                model.set_alive(feed.alive());
                last_alive = Instant::now();
            }
            pending.retain(|rx| match rx.try_recv() {
                Ok(msg) => {
                    model.message = msg;
                    false
                }
                Err(std::sync::mpsc::TryRecvError::Empty) => true,
                Err(std::sync::mpsc::TryRecvError::Disconnected) => false,
            });
            let view = model.view(now_ns());
            terminal
                .draw(|f| render(f, &view))
                .map_err(TopError::Terminal)?;
            if !event::poll(Duration::from_millis(100)).map_err(TopError::Terminal)? {
                continue;
            }
            let Event::Key(k) = event::read().map_err(TopError::Terminal)? else {
                continue;
            };
            match key_action(&k) {
                Some(Action::Quit) => return Ok(()),
                Some(Action::Estop) => {
                    model.message = "e-stop sent, waiting for safety...".into();
                    pending.push(feed.send_estop(prefix, ipc_types::control::estop_action::ESTOP));
                }
                Some(Action::Reset) => {
                    model.message = "reset sent, waiting for safety...".into();
                    pending.push(feed.send_estop(prefix, ipc_types::control::estop_action::RESET));
                }
                None => {}
            }
        }
        Ok(())
    })();
    ratatui::restore();
    result
}

/// `scl top` on a graph driving `robot` (the graph config's robot profile): the joints are
/// shown against its limits; `box_names` name the scene's boxes (`[safety.scene]`) in
/// the closest pair's line.
pub fn cli(
    prefix: &Prefix,
    args: &TopArgs,
    network: &scl_config::NetworkConfig,
    robot: &RobotProfile,
    box_names: Vec<String>,
) -> Result<std::process::ExitCode, TopError> {
    let remote = args.remote.as_ref().map(|endpoint| RemoteOptions {
        endpoint: endpoint.clone(),
        credentials: args.credentials.clone().or_else(|| {
            (!network.credentials.is_empty())
                .then(|| std::path::PathBuf::from(&network.credentials))
        }),
        namespace: network.namespace_for(prefix.as_str()),
        lease_ms: network.lease_ms,
    });
    if args.once {
        if remote.is_none() {
            graph_client::require_graph(prefix)?;
        }
        let mut feed = Feed::open(prefix, remote.as_ref())?;
        let mut model =
            Model::new(prefix.as_str(), robot.limits().clone()).with_box_names(box_names);
        let t0 = Instant::now();
        while t0.elapsed() < ONCE_LISTEN {
            feed.poll(&mut model)?;
            std::thread::sleep(Duration::from_millis(10));
        }
        feed.poll(&mut model)?;
        model.set_alive(feed.alive());
        for line in render_text(&model.view(now_ns()), SIZE.0, SIZE.1)? {
            println!("{}", line.trim_end());
        }
        return Ok(std::process::ExitCode::SUCCESS);
    }
    run_terminal(prefix, remote.as_ref(), robot, box_names)?;
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fixed_view() -> View {
        let limits = kinematics::gen3_lite::limits();
        let q = [0.0, -2.6, 1.309, 0.5, -1.047, 2.55];
        View {
            prefix: "lab2".into(),
            tick: Some(12345),
            active_mapper: Some(2),
            mode: Some("z-yaw".into()),
            mode_switches: Some(2),
            estop: false,
            hold: false,
            nodes: vec![
                NodeView {
                    role: "joystick".into(),
                    pid: 1001,
                    mapper_id: 0,
                    alive: true,
                    rate_hz: Some(40.0),
                    handled: 12340,
                    faults: 0,
                },
                NodeView {
                    role: "mapper".into(),
                    pid: 1002,
                    mapper_id: 2,
                    alive: true,
                    rate_hz: Some(40.0),
                    handled: 5000,
                    faults: 0,
                },
                NodeView {
                    role: "safety".into(),
                    pid: 1003,
                    mapper_id: 2,
                    alive: true,
                    rate_hz: Some(39.9),
                    handled: 12344,
                    faults: 0,
                },
                NodeView {
                    role: "bridge".into(),
                    pid: 1004,
                    mapper_id: 2,
                    alive: false,
                    rate_hz: None,
                    handled: 12345,
                    faults: 3,
                },
                NodeView {
                    role: "recorder".into(),
                    pid: 1005,
                    mapper_id: 0,
                    alive: true,
                    rate_hz: Some(280.0),
                    handled: 345_678,
                    faults: 0,
                },
            ],
            latency_us: Some(Percentiles {
                p50: 85.0,
                p99: 240.0,
                max: 1250.0,
            }),
            lateness_p99_us: Some(140.0),
            missed_total: 3,
            missed_recent: 1,
            rule_counts: [0, 0, 0, 0, 120, 7, 0, 40, 0, 2, 0, 0, 0, 0, 0, 0],
            latest_flags: Some(safe_flags::VELOCITY_SCALED | safe_flags::ACCEL_LIMITED),
            closest: Some(graph_client::control::Closest {
                tick: 12345,
                pair: "forearm-table".into(),
                distance_m: 0.0431,
                tcp_speed_m_s: 0.12,
            }),
            joystick: Some(JoystickView {
                axes: [0.8, 0.0],
                buttons: buttons::DEADMAN,
            }),
            joints: (0..6)
                .map(|j| JointView {
                    name: format!("j{}", j + 1),
                    q_rad: q[j],
                    lower_rad: limits.lower_rad[j],
                    upper_rad: limits.upper_rad[j],
                    qdot_rad_s: 0.125,
                })
                .collect(),
            gripper: Some(0.5),
            message: "e-stop reset (confirmed by safety, pid 1003)".into(),
        }
    }

    fn row_with<'a>(lines: &'a [String], needle: &str) -> &'a str {
        lines
            .iter()
            .find(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("no row with `{needle}`:\n{}", lines.join("\n")))
    }

    /// Column (in characters) of `needle` in `line`.
    fn col(line: &str, needle: &str) -> usize {
        let b = line.find(needle).unwrap();
        line[..b].chars().count()
    }

    #[test]
    fn fixed_view_in_80x24() {
        let lines = render_text(&fixed_view(), 80, 24).unwrap();
        assert_eq!(lines.len(), 24);
        let text = lines.join("\n");
        let title = &lines[0];
        for want in [
            "graph `lab2`",
            "tick 12345",
            "mapper 2",
            // The long form ("z-yaw (2 switches)") needs one cell more than 80 columns give.
            "mode z-yaw (2 sw)",
            "e-stop off",
        ] {
            assert!(title.contains(want), "title lacks `{want}`: {title}");
        }
        // Nodes: liveness, rates and faults.
        let bridge: String = row_with(&lines, "bridge ").chars().take(54).collect();
        assert!(
            bridge.contains("GONE") && bridge.contains("12345") && bridge.trim_end().ends_with('3'),
            "{bridge}"
        );
        let joy = row_with(&lines, "joystick  ");
        assert!(joy.contains(" yes ") && joy.contains("40.0"), "{joy}");
        assert!(row_with(&lines, "recorder").contains("280.0"));
        // Timing.
        let timing = row_with(&lines, "e2e p50");
        for want in [
            "p50 85 µs",
            "p99 240 µs",
            "max 1.2 ms",
            "missed 3 (1 recent)",
            "late p99 140 µs",
        ] {
            assert!(timing.contains(want), "timing lacks `{want}`: {timing}");
        }
        // The closest pair of the collision model, on its own row below the timing.
        let closest = row_with(&lines, "closest:");
        assert!(
            closest.starts_with("closest: forearm-table 0.043 m  tool 0.120 m/s"),
            "{closest}"
        );
        assert_eq!(
            lines.iter().position(|l| l.contains("closest:")),
            lines
                .iter()
                .position(|l| l.contains("e2e p50"))
                .map(|i| i + 1)
        );
        // Every rule that acted is named with its count; the others are left out.
        for (name, count) in safe_flags::NAMES.iter().zip(fixed_view().rule_counts) {
            let shown = text.contains(&format!("{name} {count}"));
            assert_eq!(shown, count > 0, "rule {name} ({count}):\n{text}");
        }
        // Joints: six bars; j2 sits at its lower limit end, j6 at its upper end, j1 at zero.
        for j in 1..=6 {
            let l = row_with(&lines, &format!("j{j} "));
            assert_eq!(l.chars().filter(|c| *c == '●').count(), 1, "{l}");
        }
        let (j1, j2, j6) = (
            row_with(&lines, "j1 "),
            row_with(&lines, "j2 "),
            row_with(&lines, "j6 "),
        );
        assert_eq!(col(j1, "●"), col(j2, "┼"), "j1 at zero:\n{j1}\n{j2}");
        assert_eq!(col(j2, "●"), col(j2, "[") + 1, "{j2}");
        assert_eq!(col(j6, "●") + 1, col(j6, "]"), "{j6}");
        assert!(
            j1.contains("+0.000 rad") && j1.contains("+0.125 rad/s"),
            "{j1}"
        );
        assert!(row_with(&lines, "c  ").contains("0.50"));
        assert!(
            text.contains("x +0.80") && text.contains("deadman"),
            "{text}"
        );
        // Message and keys.
        assert!(
            lines[22].contains("e-stop reset (confirmed by safety, pid 1003)"),
            "{}",
            lines[22]
        );
        for want in ["q  quit", "e  e-stop", "r  reset"] {
            assert!(
                lines[23].contains(want),
                "keys lack `{want}`: {}",
                lines[23]
            );
        }
        // Nothing runs past 80 columns (every row is exactly the terminal's width).
        assert!(lines.iter().all(|l| l.chars().count() == 80));
    }

    #[test]
    fn the_joystick_dot_follows_the_axes() {
        let mut v = fixed_view();
        let dot_col = |v: &View| {
            let lines = render_text(v, 80, 24).unwrap();
            let rows: Vec<(usize, usize)> = lines[1..8]
                .iter()
                .enumerate()
                .filter_map(|(r, l)| {
                    let stick: String = l.chars().skip(80 - 26).collect();
                    stick.find('●').map(|b| (r, stick[..b].chars().count()))
                })
                .collect();
            assert_eq!(rows.len(), 1, "one dot:\n{}", lines.join("\n"));
            rows[0]
        };
        v.joystick = Some(JoystickView {
            axes: [0.0, 0.0],
            buttons: 0,
        });
        let centre = dot_col(&v);
        v.joystick = Some(JoystickView {
            axes: [0.9, 0.0],
            buttons: 0,
        });
        let right = dot_col(&v);
        v.joystick = Some(JoystickView {
            axes: [-0.9, 0.0],
            buttons: 0,
        });
        let left = dot_col(&v);
        v.joystick = Some(JoystickView {
            axes: [0.0, 0.9],
            buttons: 0,
        });
        let up = dot_col(&v);
        assert!(
            right.1 > centre.1 + 2 && left.1 + 2 < centre.1,
            "{left:?} {centre:?} {right:?}"
        );
        assert_eq!(right.0, centre.0);
        assert!(up.0 < centre.0, "{up:?} {centre:?}");
    }

    #[test]
    fn estop_and_hold_show_in_the_title_and_acting_rules_are_highlighted() {
        let mut v = fixed_view();
        v.estop = true;
        v.hold = true;
        let mut t = ratatui::Terminal::new(ratatui::backend::TestBackend::new(80, 24)).unwrap();
        let frame = t.draw(|f| render(f, &v)).unwrap();
        let lines = buffer_lines(frame.buffer);
        assert!(
            lines[0].contains(" E-STOP ") && lines[0].contains("HOLD"),
            "{}",
            lines[0]
        );
        let buf = frame.buffer.clone();
        let find = |needle: &str| {
            let (r, l) = lines
                .iter()
                .enumerate()
                .find(|(_, l)| l.contains(needle))
                .unwrap();
            (col(l, needle) as u16, r as u16)
        };
        let (x, y) = find("velocity 120");
        assert!(
            buf[(x, y)].modifier.contains(Modifier::REVERSED),
            "velocity acts now"
        );
        let (x, y) = find("stop 7");
        assert!(
            !buf[(x, y)].modifier.contains(Modifier::REVERSED),
            "stop does not"
        );
        let (x, y) = find(" E-STOP ");
        assert_eq!(buf[(x, y)].bg, Color::Red);
    }

    #[test]
    fn the_mode_shrinks_before_the_estop_state_leaves_the_title() {
        let title = |v: &View, w: u16| render_text(v, w, 24).unwrap()[0].trim_end().to_owned();
        let mut v = fixed_view();
        // Room enough: the long form, then the e-stop state.
        let t = title(&v, 120);
        assert!(
            t.ends_with("mapper 2  mode z-yaw (2 switches)  e-stop off"),
            "{t}"
        );
        v.mode_switches = Some(1);
        assert!(title(&v, 120).contains("mode z-yaw (1 switch)  "));
        // Latched and held with a long mode name and many switches in 80 columns: the mode
        // is cut to its name, the e-stop and the hold stay in view.
        v.estop = true;
        v.hold = true;
        v.mode = Some("roll-pitch".into());
        v.mode_switches = Some(123);
        let t = title(&v, 80);
        assert!(
            t.ends_with("mapper 2  mode roll-pitch   E-STOP  HOLD"),
            "{t}"
        );
        let t = title(&v, 86);
        assert!(t.contains("mode roll-pitch (123 sw)   E-STOP  HOLD"), "{t}");
        // No mode (a map without modes, or no active mapper): a dash.
        v.mode = None;
        v.mode_switches = None;
        assert!(title(&v, 80).contains("mapper 2  mode -   E-STOP  HOLD"));
    }

    #[test]
    fn keys_map_to_actions_on_press_only() {
        use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
        let press = |code| KeyEvent::new(code, KeyModifiers::NONE);
        for (code, want) in [
            (KeyCode::Char('e'), Some(Action::Estop)),
            (KeyCode::Char(' '), Some(Action::Estop)),
            (KeyCode::Char('r'), Some(Action::Reset)),
            (KeyCode::Char('q'), Some(Action::Quit)),
            (KeyCode::Esc, Some(Action::Quit)),
            (KeyCode::Char('c'), None),
            (KeyCode::Char('x'), None),
            (KeyCode::Enter, None),
        ] {
            assert_eq!(key_action(&press(code)), want, "{code:?}");
        }
        assert_eq!(
            key_action(&KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL)),
            Some(Action::Quit)
        );
        // A held key's repeats and its release send nothing more.
        for kind in [KeyEventKind::Repeat, KeyEventKind::Release] {
            for code in [KeyCode::Char('e'), KeyCode::Char('r'), KeyCode::Char('q')] {
                let mut k = press(code);
                k.kind = kind;
                assert_eq!(key_action(&k), None, "{code:?} {kind:?}");
            }
        }
    }

    #[test]
    fn joint_bars_place_the_angle() {
        assert_eq!(joint_bar(0.0, -1.0, 1.0, 9), "────●────");
        assert_eq!(joint_bar(-1.0, -1.0, 1.0, 5), "●─┼──");
        assert_eq!(joint_bar(1.0, -1.0, 1.0, 5), "──┼─●");
        assert_eq!(joint_bar(2.0, -1.0, 1.0, 5), "──┼─▶");
        assert_eq!(joint_bar(-3.0, -1.0, 1.0, 5), "◀─┼──");
        assert_eq!(
            joint_bar(f64::NAN, -1.0, 1.0, 5)
                .chars()
                .filter(|c| *c == '?')
                .count(),
            1
        );
        assert_eq!(
            joint_bar(0.5, 0.0, 1.0, 4),
            "──●─",
            "no zero mark outside the range"
        );
        assert_eq!(joint_bar(0.0, 1.0, 1.0, 4), "");
    }

    fn hb(role: NodeRole, pid: u32, t_ms: u64, handled: u64) -> NodeStatus {
        let mut s = NodeStatus::new(role, phase::RUNNING, t_ms * 1_000_000);
        s.pid = pid;
        s.handled = handled;
        s.tick = handled;
        s
    }

    #[test]
    fn the_model_measures_rates_latency_misses_and_liveness() {
        let mut m = Model::new("g", kinematics::gen3_lite::limits());
        for k in 0..80u64 {
            let t = 1000 + k * 25;
            let mut b = hb(NodeRole::Bridge, 10, t, k);
            b.latency_ns = if k % 10 == 0 { 900_000 } else { 100_000 };
            b.faults = k / 40; // one miss at tick 40
            m.take_status(&b);
            let mut s = hb(NodeRole::Safety, 11, t, k);
            s.mapper_id = 3;
            s.safety_state = safety_state::ESTOP;
            s.rule_counts[4] = k as u32;
            m.take_status(&s);
        }
        // A node that stopped sending two seconds ago.
        m.take_status(&hb(NodeRole::Joystick, 12, 1000, 5));
        let mut st = RobotState::at_rest(79, 2_975_000_000, 6);
        st.q_rad[0] = 1.0;
        m.take_state(&st);
        let v = m.view(3_000_000_000);
        assert_eq!(v.tick, Some(79));
        assert_eq!(v.active_mapper, Some(3));
        assert!(v.estop && !v.hold);
        assert_eq!(v.rule_counts[4], 79);
        let bridge = v.nodes.iter().find(|n| n.role == "bridge").unwrap();
        assert!(bridge.alive);
        let r = bridge.rate_hz.unwrap();
        assert!((r - 40.0).abs() < 0.5, "{r}");
        let joy = v.nodes.iter().find(|n| n.role == "joystick").unwrap();
        assert!(!joy.alive && joy.rate_hz.is_none());
        let lat = v.latency_us.unwrap();
        assert_eq!(lat.p50, 100.0);
        assert_eq!(lat.p99, 900.0);
        assert_eq!((v.missed_total, v.missed_recent), (1, 1));
        assert_eq!(v.joints.len(), 6);
        assert_eq!(v.joints[0].q_rad, 1.0);
        assert_eq!(v.joints[0].upper_rad, 2.68);
        // A process that the graph no longer lists is gone even with a fresh heartbeat.
        m.set_alive(vec![11]);
        let v = m.view(3_000_000_000);
        assert!(!v.nodes.iter().find(|n| n.role == "bridge").unwrap().alive);
        assert_eq!(v.active_mapper, Some(3));
        // Misses older than the window are no longer recent.
        let mut b = hb(NodeRole::Bridge, 10, 14_000, 500);
        b.faults = 1;
        m.take_status(&b);
        let mut b = hb(NodeRole::Bridge, 10, 14_025, 501);
        b.faults = 1;
        m.take_status(&b);
        let v = m.view(14_030_000_000);
        assert_eq!((v.missed_total, v.missed_recent), (1, 0));
    }

    #[test]
    fn the_title_shows_the_active_mappers_mode_from_its_heartbeat() {
        let mut m = Model::new("g", kinematics::gen3_lite::limits());
        let mapper = |id: u32, pid: u32, mode: u32, switches: u32, t_ms: u64| {
            let mut s = hb(NodeRole::Mapper, pid, t_ms, 10);
            s.mapper_id = id;
            s.mode = mode;
            s.mode_switches = switches;
            s
        };
        let safety = |active: u32, t_ms: u64| {
            let mut s = hb(NodeRole::Safety, 30, t_ms, 10);
            s.mapper_id = active;
            s
        };
        // A mode-switching mapper in z-yaw after two switches, and a second one (a swap in
        // progress) in roll-pitch; no safety yet: no active mapper, so no mode.
        m.take_status(&mapper(1, 20, 2, 2, 1000));
        m.take_status(&mapper(2, 21, 3, 5, 1000));
        let v = m.view(1_010_000_000);
        assert_eq!((v.mode.as_deref(), v.mode_switches), (None, None));
        // Safety forwards mapper 1: its mode.
        m.take_status(&safety(1, 1000));
        let v = m.view(1_010_000_000);
        assert_eq!(
            (v.mode.as_deref(), v.mode_switches),
            (Some("z-yaw"), Some(2))
        );
        let lines = render_text(&v, 100, 24).unwrap();
        assert!(
            lines[0].contains("mapper 1  mode z-yaw (2 switches)  e-stop off"),
            "{}",
            lines[0]
        );
        // A press of the mode button: the next heartbeat says so.
        m.take_status(&mapper(1, 20, 3, 3, 1025));
        let v = m.view(1_030_000_000);
        assert_eq!(
            (v.mode.as_deref(), v.mode_switches),
            (Some("roll-pitch"), Some(3))
        );
        // Swapped to mapper 2: its own mode and count.
        m.take_status(&safety(2, 1050));
        m.take_status(&mapper(2, 21, 1, 6, 1050));
        let v = m.view(1_060_000_000);
        assert_eq!((v.mode.as_deref(), v.mode_switches), (Some("x-y"), Some(6)));
        let lines = render_text(&v, 80, 24).unwrap();
        assert!(
            lines[0].contains("mapper 2  mode x-y (6 switches)"),
            "{}",
            lines[0]
        );
        // A map without modes (mode 0) shows a dash.
        m.take_status(&mapper(2, 21, 0, 0, 1075));
        let v = m.view(1_080_000_000);
        assert_eq!(v.mode, None);
        assert!(render_text(&v, 80, 24).unwrap()[0].contains("mode -"));
        // The active mapper's heartbeat gone stale: its mode is no longer claimed.
        m.take_status(&mapper(2, 21, 2, 7, 1100));
        m.take_status(&safety(2, 1500));
        let v = m.view(1_500_000_000);
        assert_eq!(v.active_mapper, Some(2));
        assert_eq!(v.mode, None);
    }

    #[test]
    fn the_closest_pair_comes_from_the_newest_command_with_the_boxes_named() {
        let mut m = Model::new("g", kinematics::gen3_lite::limits())
            .with_box_names(vec!["mount".into(), "fixture".into()]);
        assert_eq!(m.view(0).closest, None);
        let lines = render_text(&m.view(0), 80, 24).unwrap();
        assert!(row_with(&lines, "closest: -").starts_with("closest: -"));
        let mut c = SafeCommand {
            tick: 7,
            mapper_id: 1,
            n_joints: 6,
            flags: safe_flags::CLEARANCE_LIMITED,
            clearance_m: 0.0216,
            tcp_speed_m_s: 0.01,
            // upper_wrist_link[0] against box 1.
            closest_pair: [0x0500, 0xFE01],
            ..SafeCommand::zeroed()
        };
        m.take_safe(&c);
        let v = m.view(0);
        let lines = render_text(&v, 80, 24).unwrap();
        assert!(
            row_with(&lines, "closest:")
                .starts_with("closest: upper_wrist-fixture 0.022 m  tool 0.010 m/s"),
            "{}",
            lines.join("\n")
        );
        // Safety checked nothing (no collision model): no pair.
        c.clearance_m = f64::INFINITY;
        c.closest_pair = [0xFFFF; 2];
        m.take_safe(&c);
        assert_eq!(m.view(0).closest, None);
    }
}
