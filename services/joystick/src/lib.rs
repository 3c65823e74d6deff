//! The joystick process: the operator's input device in, [`JoystickInput`] samples out.
//!
//! Sources (`[joystick] source`):
//! * `script` ([`script`]): a circle, steps or a constant, evaluated at the tick the sample
//!   answers, so a scripted run is deterministic;
//! * `evdev` ([`device`], [`mapping`], [`pad`]): a joystick or gamepad through Linux evdev,
//!   read on its own thread and handed over through a channel; a mapping file says which axis
//!   and button is which; an unplugged device makes the input neutral and flagged
//!   ([`buttons::NO_DEVICE`]) until it returns;
//! * `keyboard` ([`keyboard`]): arrow keys or WASD with a ramp, for a person at a terminal;
//! * `replay` ([`replay`]): a recorded input file with its original timing;
//! * `external` ([`EXTERNAL`]): no joystick process at all; `scl up` starts none and the
//!   samples come from whoever publishes them (a Python agent through the `python/`
//!   package), under the same rules downstream.
//!
//! Whatever the source, the process publishes one sample at start, one on every change of the
//! input, and one on every robot tick, answering it (`JoystickInput::tick` is the newest robot
//! tick seen), so the sample's age is always known downstream and a dead joystick stops the
//! arm within two ticks. A press of the e-stop button also goes out on the e-stop topic
//! ([`EstopButton`]), so it latches with safety alone, whatever the mappers are doing.
//! `--record-input FILE` writes every change to a file [`replay`] reads.
//!
//! With `[graph] wait = "predictive"` or `"spin"` the answer to a state goes out late instead,
//! a margin (`[joystick] sample_margin_us`) before the next tick, read from the device then
//! ([`sampling`]): the sample the mapper takes at tick `k` was read about a millisecond
//! before it, not a period. A remote operator (`scl joystick --remote`) answers each state on
//! its arrival: its clock is not the graph's, and its sample crosses the link after.
//!
//! The loop waits on the robot state's event and, for the threaded sources, on an eventfd
//! ([`Waker`]) their threads ring after handing something over, with a timeout at the next
//! sample due: it never polls and never blocks on a device or the terminal.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

pub mod device;
mod endpoint;
pub mod keyboard;
pub mod mapping;
pub mod pad;
pub mod replay;
pub mod sampling;
pub mod script;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Receiver;
use ipc_types::{JoystickInput, NO_TICK, NodeRole, NodeStatus, Prefix, buttons, time::now_ns};
use node_rt::node::Heartbeat;
use transport::Graph;

use scl_config::{ConfigError, FaultConfig, GraphConfig, GraphSection, JoystickConfig, RtRole};
use transport::signals;

use endpoint::Endpoint;
pub use endpoint::RemoteOptions;
pub use script::Script;

/// The sources `[joystick] source` accepts.
pub const SOURCES: [&str; 5] = ["script", "evdev", "keyboard", "replay", EXTERNAL];

/// The source of a graph whose operator is outside it ([`scl_config::EXTERNAL_JOYSTICK`]):
/// `scl up` starts no joystick process.
pub use scl_config::EXTERNAL_JOYSTICK as EXTERNAL;

/// The operator's input at one moment: what a [`JoystickInput`] carries besides its stamps.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Input {
    /// The two axes, `|a| <= 1`.
    pub axes: [f32; 2],
    /// Gripper rate in `[-1, 1]`, positive closes.
    pub gripper: f32,
    /// [`buttons`] bits.
    pub buttons: u32,
}

impl Input {
    /// Axes at rest, no button.
    pub const NEUTRAL: Input = Input {
        axes: [0.0, 0.0],
        gripper: 0.0,
        buttons: 0,
    };
}

/// Why an input source could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum JoystickError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The remote operator's session to the graph's gateway.
    #[error(transparent)]
    Session(#[from] scl_net::SessionError),
    /// The remote operator's client session (its endpoint, credentials or Zenoh).
    #[error(transparent)]
    Client(#[from] scl_net::session::ClientError),
    /// A sample could not be handed to the network.
    #[error("cannot publish on `{key}`: {source}")]
    Network {
        /// The key expression.
        key: String,
        /// Zenoh's error.
        #[source]
        source: scl_net::zenoh::Error,
    },
    /// A file could not be read or written.
    #[error("{action} {path}: {source}")]
    File {
        /// What was being done.
        action: &'static str,
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A mapping is unusable.
    #[error("mapping {file}: {key}: {reason}")]
    Mapping {
        /// The mapping's file or built-in name.
        file: PathBuf,
        /// The key (`axes.x.code`, `buttons.mode`, ...).
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// A recorded input file is unusable.
    #[error("recorded input {path}, line {line}: {reason}")]
    Replay {
        /// The file.
        path: PathBuf,
        /// The line (1-based; 0 for the file as a whole).
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// A joystick process was asked for with the `external` source, which has none.
    #[error(
        "the `external` joystick source has no joystick process: the samples come from whoever publishes them on the graph's joystick topic (the Python package's `Graph.publish_joystick`); start the graph with `scl up --joystick external`"
    )]
    External,
    /// The keyboard source was asked for without a terminal.
    #[error(
        "the keyboard source needs a terminal on standard input; run `scl joystick --source keyboard` (or `scl up` with it) in a terminal"
    )]
    NoTerminal,
    /// The terminal refused a setting.
    #[error("cannot {what} of the terminal: {source}")]
    Terminal {
        /// What was being done.
        what: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
    /// A reader thread or its wake-up could not be created.
    #[error("cannot start the {what}: {source}")]
    Thread {
        /// Which.
        what: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
}

/// The eventfd the source threads ring after handing something over; the loop waits on it
/// beside the robot state's event ([`transport::wait_any`]).
pub use transport::Waker;

/// Decides what the process publishes: a sample on every new robot tick (answering it) and on
/// every change of the input in between; numbers them.
#[derive(Debug, Default)]
pub struct Outbox {
    seq: u64,
    last: Option<Input>,
}

impl Outbox {
    /// The sample to publish now, if any, for `input` with `tick` the newest robot tick seen
    /// (`due`: a sample is due whatever the input: a new tick arrived since the last call,
    /// or [`sampling::SampleClock`] says so). The first call always publishes.
    pub fn next(&mut self, input: Input, tick: u64, due: bool, t_ns: u64) -> Option<JoystickInput> {
        if !due && self.last == Some(input) {
            return None;
        }
        let s = JoystickInput {
            tick,
            t_ns,
            seq: self.seq,
            axes: input.axes,
            gripper: input.gripper,
            buttons: input.buttons,
        };
        self.seq += 1;
        self.last = Some(input);
        Some(s)
    }
}

/// The e-stop button's presses: the process publishes each on the e-stop topic itself
/// ([`ipc_types::control::EstopCommand`], as `scl estop` does), so a press latches safety's
/// e-stop even while no mapper carries the button's bit (dead, restarting, being swapped).
#[derive(Debug, Default)]
pub struct EstopButton {
    held: bool,
}

impl EstopButton {
    /// Whether `buttons` presses the e-stop: a rising edge of [`buttons::ESTOP`]; held at the
    /// first sample counts as a press.
    pub fn pressed(&mut self, buttons: u32) -> bool {
        let held = buttons & buttons::ESTOP != 0;
        let pressed = held && !self.held;
        self.held = held;
        pressed
    }
}

/// A reader thread and the flag that stops it.
#[derive(Debug)]
struct Reader {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Reader {
    /// Asks the thread to stop (it notices within its 100 ms wait) without waiting for it.
    fn signal_stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.signal_stop();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The evdev source.
#[derive(Debug)]
struct DeviceSource {
    pad: pad::Pad,
    rx: Receiver<device::DeviceMsg>,
    waker: Arc<Waker>,
    /// Stops and joins the reading thread when the source is dropped.
    _reader: Reader,
}

impl DeviceSource {
    fn open(cfg: &JoystickConfig) -> Result<Self, JoystickError> {
        let mapping = mapping::Mapping::load(&cfg.mapping)?;
        let waker = Arc::new(Waker::new().map_err(|source| JoystickError::Thread {
            what: "device reader's wake-up",
            source,
        })?);
        let (tx, rx) = crossbeam_channel::unbounded();
        let stop = Arc::new(AtomicBool::new(false));
        let thread = device::spawn_reader(
            cfg.device.clone(),
            mapping.clone(),
            Duration::from_millis(cfg.reconnect_interval_ms),
            tx,
            Arc::clone(&waker),
            Arc::clone(&stop),
        )
        .map_err(|source| JoystickError::Thread {
            what: "device reader",
            source,
        })?;
        tracing::info!(mapping = %mapping.source, device = %cfg.device, "evdev source");
        Ok(Self {
            pad: pad::Pad::new(mapping),
            rx,
            waker,
            _reader: Reader {
                stop,
                thread: Some(thread),
            },
        })
    }

    fn input(&mut self) -> Input {
        while let Ok(m) = self.rx.try_recv() {
            match m {
                device::DeviceMsg::Connected(snap) => {
                    let missing = self.pad.connect(&snap);
                    tracing::info!(path = %snap.path, "device connected: {}", snap.name);
                    if !missing.is_empty() {
                        tracing::warn!(
                            "{} has no {}: those inputs stay neutral (mapping {})",
                            snap.name,
                            device::describe_missing(&missing),
                            self.pad.mapping().source
                        );
                    }
                }
                device::DeviceMsg::Event(e) => {
                    self.pad.event(e);
                }
                device::DeviceMsg::Lost(reason) => {
                    self.pad.disconnect();
                    tracing::warn!("device lost ({reason}): the input is neutral until it returns");
                }
                device::DeviceMsg::Missing(reason) => {
                    self.pad.disconnect();
                    tracing::warn!("{reason}; waiting for it, the input is neutral meanwhile");
                }
            }
        }
        self.pad.input()
    }
}

/// The keyboard source.
struct KeyboardSource {
    keys: keyboard::Keys,
    rx: Receiver<(keyboard::Key, keyboard::KeyAction)>,
    waker: Arc<Waker>,
    reader: Reader,
    terminal: keyboard::Terminal,
    t0: Instant,
    /// The mapper safety forwards (from safety's heartbeat), and each mapper's mode.
    active_mapper: u32,
    modes: Vec<(u32, u32, u32)>,
    draw: bool,
    last_line: String,
    last_draw: Instant,
    handed_back: bool,
}

impl KeyboardSource {
    fn open(cfg: &JoystickConfig) -> Result<Self, JoystickError> {
        let terminal = keyboard::Terminal::take()?;
        let waker = Arc::new(Waker::new().map_err(|source| JoystickError::Thread {
            what: "keyboard reader's wake-up",
            source,
        })?);
        let (tx, rx) = crossbeam_channel::unbounded();
        let stop = Arc::new(AtomicBool::new(false));
        let thread = keyboard::spawn_reader(tx, Arc::clone(&waker), Arc::clone(&stop)).map_err(
            |source| JoystickError::Thread {
                what: "keyboard reader",
                source,
            },
        )?;
        let settings = keyboard::KeyboardSettings {
            ramp_s: cfg.keyboard_ramp_s,
            first_hold_s: cfg.keyboard_first_hold_ms as f64 / 1000.0,
            repeat_hold_s: cfg.keyboard_repeat_hold_ms as f64 / 1000.0,
            ..keyboard::KeyboardSettings::default()
        };
        Ok(Self {
            keys: keyboard::Keys::new(settings),
            rx,
            waker,
            reader: Reader {
                stop,
                thread: Some(thread),
            },
            terminal,
            t0: Instant::now(),
            active_mapper: 0,
            modes: Vec::new(),
            draw: std::io::IsTerminal::is_terminal(&std::io::stderr()),
            last_line: String::new(),
            last_draw: Instant::now(),
            handed_back: false,
        })
    }

    fn input(&mut self, now: Instant, gripper: Option<f64>) -> Input {
        let t = now.duration_since(self.t0).as_secs_f64();
        while let Ok((key, action)) = self.rx.try_recv() {
            self.keys.key(key, action, t);
        }
        if self.handed_back {
            return Input::NEUTRAL;
        }
        self.keys.input(t, gripper)
    }

    /// Whether the process should end: `q` or Ctrl-C at a terminal of its own. Under `scl up`
    /// (the terminal borrowed), the terminal goes back to the supervisor with an interrupt,
    /// which then stops the graph in order; this process goes on with a neutral input until
    /// it is told to stop.
    fn quit(&mut self) -> bool {
        if !self.keys.quit_requested() || self.handed_back {
            return false;
        }
        if self.terminal.borrowed() {
            self.handed_back = true;
            self.reader.signal_stop();
            self.terminal.restore(true);
            tracing::info!("keyboard: quit; the terminal goes back to `scl up`");
            false
        } else {
            true
        }
    }

    fn heartbeat(&mut self, s: &NodeStatus) {
        if s.role == NodeRole::Safety as u32 {
            self.active_mapper = s.mapper_id;
        } else if s.role == NodeRole::Mapper as u32 {
            match self.modes.iter_mut().find(|m| m.0 == s.mapper_id) {
                Some(m) => *m = (s.mapper_id, s.mode, s.mode_switches),
                None => self.modes.push((s.mapper_id, s.mode, s.mode_switches)),
            }
        }
    }

    fn mode_text(&self) -> String {
        keyboard::mode_text(self.active_mapper, &self.modes)
    }

    fn show(&mut self, input: &Input) {
        if !self.draw || self.handed_back {
            return;
        }
        let line = keyboard::status_line(input, self.keys.gripper_closed(), &self.mode_text());
        if line != self.last_line || self.last_draw.elapsed() > Duration::from_millis(500) {
            use std::io::Write as _;
            let mut e = std::io::stderr().lock();
            let _ = write!(e, "\r\x1b[2K{line}");
            let _ = e.flush();
            self.last_line = line;
            self.last_draw = Instant::now();
        }
    }
}

/// The replay source.
#[derive(Debug)]
struct ReplaySource {
    rec: replay::Recording,
    start: Option<Instant>,
    said_finished: bool,
}

impl ReplaySource {
    fn elapsed(&self, now: Instant) -> f64 {
        self.start
            .map_or(0.0, |s| now.duration_since(s).as_secs_f64())
    }

    fn input(&mut self, now: Instant, tick: u64) -> Input {
        if tick == NO_TICK {
            return Input::NEUTRAL;
        }
        let start = *self.start.get_or_insert(now);
        let t = now.duration_since(start).as_secs_f64();
        if self.rec.finished(t) && !self.said_finished {
            self.said_finished = true;
            tracing::info!(
                file = %self.rec.path.display(),
                "replay finished; the input is neutral from here on"
            );
        }
        self.rec.at(t)
    }

    fn timeout(&self, now: Instant) -> Duration {
        let t = self.elapsed(now);
        match (self.start, self.rec.next_change(t)) {
            (Some(_), Some(next)) => Duration::from_secs_f64((next - t).clamp(0.0005, 0.1)),
            _ => Duration::from_millis(100),
        }
    }
}

/// Where a script's time starts. A script whose time starts at the first tick seen rests for
/// [`script::START_REST_S`] from there; one on the graph's time does not (see
/// [`Origin::resting`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Origin {
    /// At the graph's tick 0 (the first tick seen, `None` before it, starts the rest).
    Graph(Option<u64>),
    /// At the first tick seen (`None` before it).
    FirstSeen(Option<u64>),
}

impl Origin {
    /// `tick` counted from the origin (fixing the first tick seen).
    fn relative(&mut self, tick: u64) -> u64 {
        if tick == NO_TICK {
            return NO_TICK;
        }
        match self {
            Self::Graph(first) => {
                first.get_or_insert(tick);
                tick
            }
            Self::FirstSeen(first) => tick.saturating_sub(*first.get_or_insert(tick)),
        }
    }

    /// Whether `tick` falls in the rest that starts at the first tick seen. Only for a script
    /// whose time starts there: one on the graph's time (a joystick restarted in a running
    /// graph) goes on with the script and no rest, so the restart itself never passes the
    /// stick through neutral and re-arms the arm
    /// (`restart::a_restarted_scripted_joystick_does_not_rearm_the_arm`).
    fn resting(&self, tick: u64, period_s: f64) -> bool {
        let Self::FirstSeen(Some(first)) = *self else {
            return false;
        };
        tick != NO_TICK && (tick.saturating_sub(first) as f64 * period_s) < script::START_REST_S
    }
}

/// The configured source.
enum Source {
    Script {
        script: Script,
        period_s: f64,
        /// The script's tick 0: 0 on the graph's own machine (a scripted run is a function
        /// of the graph's tick), the first tick seen for a remote operator, who joins a
        /// running graph and must start from the script's neutral rest like a local one.
        origin: Origin,
    },
    Device(Box<DeviceSource>),
    Keyboard(Box<KeyboardSource>),
    Replay(ReplaySource),
}

impl Source {
    fn open(cfg: &JoystickConfig, period_s: f64) -> Result<Self, JoystickError> {
        Ok(match cfg.source.as_str() {
            EXTERNAL => return Err(JoystickError::External),
            "evdev" => Self::Device(Box::new(DeviceSource::open(cfg)?)),
            "keyboard" => Self::Keyboard(Box::new(KeyboardSource::open(cfg)?)),
            "replay" => Self::Replay(ReplaySource {
                rec: replay::Recording::load(Path::new(&cfg.replay_file))?,
                start: None,
                said_finished: false,
            }),
            _ => Self::Script {
                script: Script::from_config(cfg).ok_or_else(|| {
                    JoystickError::Config(ConfigError::Value {
                        key: "joystick.script".into(),
                        reason: format!(
                            "`{}` is not a script; use `circle`, `step` or `constant`",
                            cfg.script
                        ),
                    })
                })?,
                period_s,
                origin: Origin::Graph(None),
            },
        })
    }

    fn waker(&self) -> Option<&Waker> {
        match self {
            Self::Device(d) => Some(&d.waker),
            Self::Keyboard(k) => Some(&k.waker),
            _ => None,
        }
    }

    fn timeout(&self, now: Instant) -> Duration {
        match self {
            Self::Replay(r) => r.timeout(now),
            _ => Duration::from_millis(100),
        }
    }

    /// Whether the source has input of its own before the first robot tick: a device or
    /// the keyboard does (the operator's), a script or a replay does not (each is a function
    /// of the tick), so they publish nothing until the first tick: a neutral sample made up
    /// before it would be taken for the operator's.
    fn has_input_before_a_tick(&self) -> bool {
        matches!(self, Self::Device(_) | Self::Keyboard(_))
    }

    /// Whether the operator asked to quit (the keyboard source's quit key).
    fn quit(&mut self) -> bool {
        match self {
            Self::Keyboard(k) => k.quit(),
            _ => false,
        }
    }

    fn input(&mut self, now: Instant, tick: u64, gripper: Option<f64>) -> Input {
        match self {
            Self::Script {
                script,
                period_s,
                origin,
            } => {
                let at = origin.relative(tick);
                let axes = if origin.resting(tick, *period_s) {
                    [0.0, 0.0]
                } else {
                    script.sample(at, *period_s, 0, 0).axes
                };
                Input {
                    axes,
                    ..Input::NEUTRAL
                }
            }
            Self::Device(d) => d.input(),
            Self::Keyboard(k) => k.input(now, gripper),
            Self::Replay(r) => r.input(now, tick),
        }
    }
}

/// Runs the joystick process until a shutdown is requested (or, at a terminal of its own,
/// the keyboard source's quit key), publishing on the graph `prefix` on this machine.
pub fn run(
    prefix: &Prefix,
    graph_cfg: &GraphSection,
    cfg: &JoystickConfig,
    faults: &FaultConfig,
    period_s: f64,
) -> Result<(), JoystickError> {
    let source = Source::open(cfg, period_s)?;
    let graph = Graph::join_with(prefix, "joystick", graph_cfg.transport)?;
    let heartbeats = if matches!(source, Source::Keyboard(_)) {
        Some(graph.status_subscriber()?)
    } else {
        None
    };
    let samples = graph.joystick_publisher()?;
    let estop = graph.estop_publisher()?;
    let states = graph.robot_state_subscriber(true)?;
    let status = graph.status_publisher()?;
    let mut local = endpoint::Local {
        samples,
        estop,
        states,
        heartbeats,
    };
    node_rt::rt::elevate(graph_cfg, RtRole::Joystick);
    let clock = graph_cfg.wait.polls().then(|| {
        let period_ns = graph_cfg.period_ns();
        let margin_ns = sampling::margin_ns(cfg.sample_margin_us, period_ns);
        tracing::info!(
            margin_us = margin_ns / 1000,
            "sampling the input late, a margin before each tick"
        );
        sampling::SampleClock::new(period_ns, margin_ns)
    });
    drive(source, &mut local, Some(&status), cfg, faults, clock)
}

/// Runs the joystick as a remote operator of a graph on another machine, through its gateway
/// (`scl joystick --remote`): the same loop as [`run`], over Zenoh.
pub fn run_remote(
    remote: &RemoteOptions,
    cfg: &JoystickConfig,
    faults: &FaultConfig,
    period_s: f64,
) -> Result<(), JoystickError> {
    let mut source = Source::open(cfg, period_s)?;
    if let Source::Script { origin, .. } = &mut source {
        *origin = Origin::FirstSeen(None);
    }
    let mut ep = endpoint::Remote::open(remote)?;
    // Heartbeats are the graph's: the gateway is this operator's node there.
    drive(source, &mut ep, None, cfg, faults, None)
}

/// The loop. Each turn: wait for a robot state, the source's thread or the next sample due
/// on `clock`, take the newest state, read the source, send an e-stop press and the sample
/// (unless a fault injection silenced the joystick), show the input, and on a new state send
/// the heartbeat. Without `clock` (or until it knows the grid) a sample answers each state on
/// its arrival; with it, at the times it says. The heartbeats go to `status` (none for a remote
/// operator).
fn drive(
    mut source: Source,
    ep: &mut dyn Endpoint,
    status: Option<&transport::TopicPublisher<NodeStatus>>,
    cfg: &JoystickConfig,
    faults: &FaultConfig,
    mut clock: Option<sampling::SampleClock>,
) -> Result<(), JoystickError> {
    let recorder = if cfg.record_input.is_empty() {
        None
    } else {
        Some(replay::InputRecorder::create(Path::new(&cfg.record_input))?)
    };
    let t0 = Instant::now();
    let mut out = Outputs {
        estop_button: EstopButton::default(),
        outbox: Outbox::default(),
        recorder,
        t0,
    };
    let mut tick = NO_TICK;
    let mut gripper = None;
    let input = source.input(t0, tick, gripper);
    out.send_estop(ep, &input)?;
    if source.has_input_before_a_tick() {
        out.publish(ep, input, tick, true, t0)?;
    }
    let mut hb = Heartbeat::ready(status, NodeRole::Joystick, |_| {})?;
    tracing::info!(source = %cfg.source, "publishing on {}", ep.describe());
    let mut screen = StatusScreen::new(matches!(source, Source::Keyboard(_)));
    while !signals::stop_requested() && !source.quit() {
        let mut timeout = source.timeout(Instant::now());
        if let Some(at) = clock.as_ref().and_then(sampling::SampleClock::next_due_ns) {
            timeout = timeout.min(Duration::from_nanos(at.saturating_sub(now_ns())));
        }
        ep.wait(source.waker(), timeout)?;
        let new_state = ep.latest_state()?;
        if let Some(s) = &new_state {
            tick = s.tick;
            gripper = Some(s.gripper);
            if let Some(c) = &mut clock {
                c.state(s.tick, s.t_ns);
            }
        }
        // On the grid, what the clock says is due; otherwise an answer to each new state.
        let due = match &clock {
            Some(c) if c.learnt() => c.due(now_ns()),
            _ => None,
        };
        let on_grid = clock.as_ref().is_some_and(sampling::SampleClock::learnt);
        let answer = if on_grid {
            due.is_some()
        } else {
            new_state.is_some()
        };
        // On the grid nothing goes out as a state arrives, not even a change: a script's
        // input changes with the tick, and its answer would race the mapper for this tick's
        // sample, which the late one before the state already is.
        let hold = on_grid && new_state.is_some() && due.is_none();
        if let Source::Keyboard(k) = &mut source {
            ep.heartbeats(&mut |s| k.heartbeat(s))?;
        }
        let now = Instant::now();
        let mut input = source.input(now, tick, gripper);
        inject_bad_axes(faults, tick, new_state.is_some(), &mut input);
        let silent = faults.joystick_silent_after_ticks;
        let handled = hb.status().handled;
        if silent == 0 || handled < silent {
            out.send_estop(ep, &input)?;
            if (tick != NO_TICK || source.has_input_before_a_tick()) && !hold {
                out.publish(ep, input, tick, answer, now)?;
            }
        } else if handled == silent && new_state.is_some() {
            tracing::warn!(tick, "fault injection: the joystick goes silent");
        }
        // (Silenced too: the sample is done with, and the loop sleeps until the next.)
        if let (Some(c), Some(d)) = (&mut clock, due) {
            c.sent(d, now_ns());
        }
        if let Source::Keyboard(k) = &mut source {
            k.show(&input);
        }
        screen.show(ep, now);
        if let Some(s) = new_state {
            let st = hb.status_mut();
            count_tick(st, s.tick, &input);
            st.held_up = clock.as_ref().map_or(0, sampling::SampleClock::missed);
            hb.beat()?;
        }
    }
    drop(source);
    screen.finish();
    ep.finish();
    if let Some(r) = out.recorder.take() {
        finish_recording(r, cfg, t0)?;
    }
    hb.stop()?;
    Ok(())
}

/// Fault injection: from `joystick_nan_at_tick`, for a few ticks, the axes are NaN; from
/// `joystick_out_of_range_at_tick`, far outside the stick's disc (said once per new state).
fn inject_bad_axes(faults: &FaultConfig, tick: u64, new_state: bool, input: &mut Input) {
    let during = |from: u64| {
        from != 0 && tick != NO_TICK && (from..from + scl_config::NAN_INPUT_TICKS).contains(&tick)
    };
    let (axes, what) = if during(faults.joystick_nan_at_tick) {
        ([f32::NAN, f32::NAN], "NaN axes")
    } else if during(faults.joystick_out_of_range_at_tick) {
        (
            scl_config::OUT_OF_RANGE_AXES,
            "axes outside the stick's disc",
        )
    } else {
        return;
    };
    if new_state {
        tracing::warn!(tick, "fault injection: the joystick sends {what}");
    }
    input.axes = axes;
}

/// Ends the input recording (`[joystick] record_input`) started at `t0`.
fn finish_recording(
    r: replay::InputRecorder,
    cfg: &JoystickConfig,
    t0: Instant,
) -> Result<(), JoystickError> {
    let file = cfg.record_input.clone();
    let rows = r.finish(t0.elapsed().as_secs_f64())?;
    tracing::info!(rows, file, "input recorded");
    Ok(())
}

/// The endpoint's own line (a remote operator's link): on a terminal redrawn in place twice a
/// second, otherwise logged every five seconds; not beside the keyboard source, which draws
/// its own.
struct StatusScreen {
    terminal: bool,
    off: bool,
    last: Option<Instant>,
    drawn: bool,
}

impl StatusScreen {
    fn new(keyboard: bool) -> Self {
        Self {
            terminal: std::io::IsTerminal::is_terminal(&std::io::stderr()),
            off: keyboard,
            last: None,
            drawn: false,
        }
    }

    fn show(&mut self, ep: &mut dyn Endpoint, now: Instant) {
        let every = if self.terminal {
            Duration::from_millis(500)
        } else {
            Duration::from_secs(5)
        };
        if self.off || self.last.is_some_and(|t| now.duration_since(t) < every) {
            return;
        }
        let Some(line) = ep.status_line() else {
            self.off = true;
            return;
        };
        self.last = Some(now);
        if self.terminal {
            use std::io::Write as _;
            let mut e = std::io::stderr().lock();
            let _ = write!(e, "\r\x1b[2K{line}");
            let _ = e.flush();
            self.drawn = true;
        } else {
            tracing::info!("{line}");
        }
    }

    fn finish(&self) {
        if self.drawn {
            eprintln!();
        }
    }
}

/// What the joystick decides to send: e-stop presses, samples when due, the input file.
struct Outputs {
    estop_button: EstopButton,
    outbox: Outbox,
    recorder: Option<replay::InputRecorder>,
    /// When the process started (the input file's time 0).
    t0: Instant,
}

impl Outputs {
    /// Sends an E-STOP to safety when `input` presses the e-stop button.
    fn send_estop(&mut self, ep: &mut dyn Endpoint, input: &Input) -> Result<(), JoystickError> {
        if self.estop_button.pressed(input.buttons) {
            tracing::warn!("e-stop button pressed: E-STOP sent to safety");
            ep.send_estop(ipc_types::control::EstopCommand {
                t_ns: now_ns(),
                action: ipc_types::control::estop_action::ESTOP,
                source_pid: std::process::id(),
            })?;
        }
        Ok(())
    }

    /// Publishes `input` as the answer to `tick` when the [`Outbox`] says a sample is due
    /// (a change, or `due`: a state to answer), and records it as read at `at`.
    fn publish(
        &mut self,
        ep: &mut dyn Endpoint,
        input: Input,
        tick: u64,
        due: bool,
        at: Instant,
    ) -> Result<(), JoystickError> {
        if let Some(sample) = self.outbox.next(input, tick, due, now_ns()) {
            ep.send_sample(sample)?;
            if let Some(r) = self.recorder.as_mut() {
                r.record(at.duration_since(self.t0).as_secs_f64(), &input);
            }
        }
        Ok(())
    }
}

/// Counts the answer to robot tick `tick` in the heartbeat `st` (a fault while the device is
/// gone).
fn count_tick(st: &mut NodeStatus, tick: u64, input: &Input) {
    st.t_ns = now_ns();
    st.tick = tick;
    st.handled += 1;
    if input.buttons & buttons::NO_DEVICE != 0 {
        st.faults += 1;
    }
}

/// Checks `[joystick]`: every key, and the files the chosen source needs (the mapping, the
/// recorded input), so a bad one is refused at start-up naming the key and the file.
pub fn validate(j: &JoystickConfig) -> Result<(), ConfigError> {
    let err = |key: &str, reason: String| ConfigError::Value {
        key: format!("joystick.{key}"),
        reason,
    };
    if !SOURCES.contains(&j.source.as_str()) {
        return Err(err(
            "source",
            format!(
                "`{}` is not a source; use {}",
                j.source,
                SOURCES.map(|s| format!("`{s}`")).join(", ")
            ),
        ));
    }
    if Script::from_config(j).is_none() {
        return Err(err(
            "script",
            format!(
                "`{}` is not a script; use `circle`, `step` or `constant`",
                j.script
            ),
        ));
    }
    if !(j.amplitude > 0.0 && j.amplitude <= 1.0) {
        return Err(err(
            "amplitude",
            format!("{} is outside (0, 1]", j.amplitude),
        ));
    }
    script::check_constant_axes(j.constant_axes).map_err(|reason| err("constant_axes", reason))?;
    for (key, v) in [
        ("circle_period_s", j.circle_period_s),
        ("step_hold_s", j.step_hold_s),
        ("keyboard_ramp_s", j.keyboard_ramp_s),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(err(
                key,
                format!("is {v}; it must be a finite number above 0"),
            ));
        }
    }
    if !(j.step_rest_s.is_finite() && j.step_rest_s >= 0.0) {
        return Err(err(
            "step_rest_s",
            format!(
                "is {}; it must be a finite number, 0 or more",
                j.step_rest_s
            ),
        ));
    }
    for (key, v, lo) in [
        ("reconnect_interval_ms", j.reconnect_interval_ms, 10),
        ("keyboard_first_hold_ms", j.keyboard_first_hold_ms, 50),
        ("keyboard_repeat_hold_ms", j.keyboard_repeat_hold_ms, 50),
    ] {
        if v < lo {
            return Err(err(key, format!("{v} is below {lo} ms")));
        }
    }
    if j.source == "evdev" {
        mapping::Mapping::load(&j.mapping).map_err(|e| err("mapping", e.to_string()))?;
    }
    if j.source == "replay" {
        if j.replay_file.is_empty() {
            return Err(err(
                "replay_file",
                "the replay source needs a recorded input file".into(),
            ));
        }
        replay::Recording::load(Path::new(&j.replay_file))
            .map_err(|e| err("replay_file", e.to_string()))?;
    }
    if j.source == EXTERNAL && !j.record_input.is_empty() {
        return Err(err(
            "record_input",
            "the external source has no joystick process to record its input; record the graph with `scl record` or `scl up --record` instead".into(),
        ));
    }
    // (An existing `record_input` is refused when the joystick creates it, not here: every
    // process of the graph validates the config, some after the joystick has started.)
    Ok(())
}

/// `scl joystick`'s options.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct JoystickArgs {
    /// List the input devices attached (evdev) and exit.
    #[arg(long)]
    pub list: bool,
    /// Input source: `script`, `evdev` (a joystick or gamepad), `keyboard` or `replay`
    /// (`external` has no joystick process and is refused here).
    #[arg(long)]
    pub source: Option<String>,
    /// Script: `circle`, `step` or `constant`.
    #[arg(long)]
    pub script: Option<String>,
    /// evdev device: a path (`/dev/input/event5`) or part of its name; default: the first
    /// joystick or gamepad.
    #[arg(long, value_name = "PATH|NAME")]
    pub device: Option<String>,
    /// evdev mapping: `xbox`, `generic` or a mapping file (TOML).
    #[arg(long, value_name = "NAME|FILE")]
    pub mapping: Option<String>,
    /// Replay this recorded input file with its original timing (sets the source to
    /// `replay`).
    #[arg(long, value_name = "FILE")]
    pub replay: Option<PathBuf>,
    /// Record the published input to FILE (CSV `t_s,a0,a1,gripper,buttons`; refused if it
    /// exists), from any source.
    #[arg(long, value_name = "FILE")]
    pub record_input: Option<PathBuf>,
    /// Drive a graph on another machine through its gateway (`[network] accept_joystick` on
    /// the robot PC): its Zenoh endpoint, e.g. `tcp/192.0.2.10:7447`. The samples answer the
    /// robot states that arrive from there; a lost link or late samples stop the arm, which
    /// moves again only after a new session and neutral input.
    #[arg(long, value_name = "ENDPOINT")]
    pub remote: Option<String>,
    /// With `--remote`: the credentials file (`user:password`, mode 0600; default
    /// `[network] credentials`). Never a password on the command line.
    #[arg(long, value_name = "FILE", requires = "remote")]
    pub credentials: Option<PathBuf>,
    /// With `--remote`: the graph's namespace (default `[network] namespace`, else
    /// `scl/<prefix>`).
    #[arg(long, value_name = "KEY", requires = "remote")]
    pub namespace: Option<String>,
}

/// `scl joystick`: lists the devices, or runs the process with the options applied over the
/// config's `[joystick]`.
pub fn main(
    prefix: &Prefix,
    cfg: &mut GraphConfig,
    args: &JoystickArgs,
) -> Result<(), JoystickError> {
    if args.list {
        let (rows, refused) = device::list();
        print!("{}", device::render_list(&rows, &refused));
        return Ok(());
    }
    let j = &mut cfg.joystick;
    if let Some(s) = &args.source {
        j.source.clone_from(s);
    }
    if let Some(s) = &args.script {
        j.script.clone_from(s);
    }
    if let Some(s) = &args.device {
        j.device.clone_from(s);
        if args.source.is_none() {
            j.source = "evdev".into();
        }
    }
    if let Some(s) = &args.mapping {
        j.mapping.clone_from(s);
    }
    if let Some(p) = &args.replay {
        j.replay_file = p.display().to_string();
        j.source = "replay".into();
    }
    if let Some(p) = &args.record_input {
        j.record_input = p.display().to_string();
    }
    validate(j)?;
    let period_s = cfg.period_s();
    if let Some(endpoint) = &args.remote {
        let credentials = match &args.credentials {
            Some(p) => p.clone(),
            None if !cfg.network.credentials.is_empty() => PathBuf::from(&cfg.network.credentials),
            None => {
                return Err(JoystickError::Config(ConfigError::Value {
                    key: "--credentials".into(),
                    reason: "a remote operator must log in: give --credentials FILE (or \
                             [network] credentials), a file of `user:password` with mode 0600"
                        .into(),
                }));
            }
        };
        let namespace = args
            .namespace
            .clone()
            .unwrap_or_else(|| cfg.network.namespace_for(prefix.as_str()));
        scl_config::check_namespace(&namespace).map_err(|reason| {
            JoystickError::Config(ConfigError::Value {
                key: "--namespace".into(),
                reason,
            })
        })?;
        let opts = RemoteOptions {
            endpoint: endpoint.clone(),
            credentials,
            namespace,
            lease_ms: cfg.network.lease_ms,
        };
        return run_remote(&opts, &cfg.joystick, &cfg.faults, period_s);
    }
    run(prefix, &cfg.graph, &cfg.joystick, &cfg.faults, period_s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use pad::tests::{parse_evtest, xbox_snapshot};

    #[test]
    fn a_remote_script_starts_at_the_first_tick_it_sees() {
        let mut graph = Origin::Graph(None);
        assert_eq!(graph.relative(120), 120);
        let mut remote = Origin::FirstSeen(None);
        assert_eq!(remote.relative(NO_TICK), NO_TICK);
        assert_eq!(remote.relative(120), 0);
        assert_eq!(remote.relative(125), 5);
    }

    /// A scripted joystick on the graph's time follows the script from the first tick it
    /// sees: started with the graph, the script's own rest comes first; restarted in a
    /// running graph it takes no rest of its own, so the restart never passes the stick
    /// through neutral and re-arms the arm (safety still waits for neutral:
    /// `restart::a_restarted_scripted_joystick_does_not_rearm_the_arm`).
    #[test]
    fn a_restarted_script_follows_the_graph_time_without_a_rest_of_its_own() {
        let cfg = JoystickConfig {
            script: "circle".into(),
            ..JoystickConfig::default()
        };
        let period_s = 0.025;
        let rest_ticks = (script::START_REST_S / period_s).round() as u64;
        let script = Script::from_config(&cfg).unwrap();
        let now = Instant::now();
        for first in [0, 400] {
            let mut src = Source::open(&cfg, period_s).unwrap();
            assert_eq!(src.input(now, NO_TICK, None).axes, [0.0, 0.0]);
            for k in first..first + rest_ticks + 8 {
                let want = script.sample(k, period_s, 0, 0).axes;
                assert_eq!(src.input(now, k, None).axes, want, "{first}: {k}");
                if first == 0 && k < rest_ticks {
                    assert_eq!(want, [0.0, 0.0], "the script's own rest: {k}");
                }
            }
            assert_ne!(
                src.input(now, first + rest_ticks + 9, None).axes,
                [0.0, 0.0]
            );
        }
    }

    /// A synthetic session in `evtest`'s output format (written for this test, not captured
    /// from hardware): an Xbox pad's stick pushed right then up-left with jitter inside the
    /// deadzone, the mode button tapped, the right trigger pulled, everything released.
    const SESSION: &str = "\
Event: time 1700000000.000000, type 3 (EV_ABS), code 0 (ABS_X), value 1500
Event: time 1700000000.000000, type 3 (EV_ABS), code 1 (ABS_Y), value -900
Event: time 1700000000.000000, -------------- SYN_REPORT ------------
Event: time 1700000000.012000, type 3 (EV_ABS), code 0 (ABS_X), value 16384
Event: time 1700000000.012000, -------------- SYN_REPORT ------------
Event: time 1700000000.020000, type 3 (EV_ABS), code 0 (ABS_X), value 32767
Event: time 1700000000.020000, -------------- SYN_REPORT ------------
Event: time 1700000000.140000, type 1 (EV_KEY), code 304 (BTN_SOUTH), value 1
Event: time 1700000000.140000, -------------- SYN_REPORT ------------
Event: time 1700000000.230000, type 1 (EV_KEY), code 304 (BTN_SOUTH), value 0
Event: time 1700000000.230000, -------------- SYN_REPORT ------------
Event: time 1700000000.300000, type 3 (EV_ABS), code 0 (ABS_X), value -23170
Event: time 1700000000.300000, type 3 (EV_ABS), code 1 (ABS_Y), value -23170
Event: time 1700000000.300000, type 3 (EV_ABS), code 5 (ABS_RZ), value 1023
Event: time 1700000000.300000, -------------- SYN_REPORT ------------
Event: time 1700000000.400000, type 3 (EV_ABS), code 0 (ABS_X), value 0
Event: time 1700000000.400000, type 3 (EV_ABS), code 1 (ABS_Y), value 0
Event: time 1700000000.400000, type 3 (EV_ABS), code 5 (ABS_RZ), value 0
Event: time 1700000000.400000, -------------- SYN_REPORT ------------
";

    /// Plays `events` (time-stamped) through a pad and the outbox as the process loop does,
    /// with a robot tick every 25 ms from `t_first`: returns the published samples and the
    /// time each was published at.
    fn play(
        pad: &mut pad::Pad,
        events: &[(f64, pad::RawEvent)],
        t_first: f64,
        t_end: f64,
    ) -> Vec<(f64, JoystickInput)> {
        let mut out = Outbox::default();
        let mut published = Vec::new();
        let mut tick = NO_TICK;
        let mut next_tick = (t_first, 0u64);
        let mut i = 0;
        let mut t = t_first;
        if let Some(s) = out.next(pad.input(), tick, true, 0) {
            published.push((t, s));
        }
        while t < t_end {
            // Whichever comes first: the next event or the next tick.
            let t_ev = events.get(i).map_or(f64::INFINITY, |e| e.0);
            let new_tick = next_tick.0 <= t_ev;
            if new_tick {
                t = next_tick.0;
                tick = next_tick.1;
                next_tick = (t + 0.025, tick + 1);
            } else {
                t = t_ev;
                // The reader hands over a batch; the loop drains it all before publishing.
                while i < events.len() && events[i].0 == t_ev {
                    pad.event(events[i].1);
                    i += 1;
                }
            }
            if let Some(s) = out.next(pad.input(), tick, new_tick, (t * 1e9) as u64) {
                published.push((t, s));
            }
        }
        published
    }

    #[test]
    fn a_recorded_session_gives_the_expected_samples() {
        let events: Vec<(f64, pad::RawEvent)> = SESSION
            .lines()
            .filter_map(parse_evtest)
            .map(|(t, e)| (t - 1_700_000_000.0, e))
            .collect();
        assert_eq!(events.len(), 19);
        let mut pad = pad::Pad::new(mapping::Mapping::load("xbox").unwrap());
        pad.connect(&xbox_snapshot());
        // Ticks at -7 ms, 18 ms, 43 ms, ...
        let samples = play(&mut pad, &events, -0.007, 0.5);
        let at = |t: f64| {
            samples
                .iter()
                .rev()
                .find(|(ts, _)| *ts <= t + 1e-9)
                .map(|(_, s)| *s)
                .unwrap()
        };
        // Every robot tick is answered with its own number, in order, with no gap.
        let ticks: Vec<u64> = samples
            .iter()
            .map(|(_, s)| s.tick)
            .filter(|t| *t != NO_TICK)
            .collect();
        let mut answered = ticks.clone();
        answered.dedup();
        assert_eq!(answered, (0..=21).collect::<Vec<_>>());
        assert!(samples.windows(2).all(|w| w[1].1.seq == w[0].1.seq + 1));
        // Jitter inside the deadzone (|a| = 0.05): neutral, so nothing extra is published.
        assert_eq!(at(0.0).axes, [0.0, 0.0]);
        let near = |t: f64| {
            samples
                .iter()
                .find(|(ts, _)| (ts - t).abs() < 1e-5)
                .map(|s| s.1)
        };
        assert_eq!(near(0.0), None);
        // Half-way right, then full right, each published at once (on change), not at the
        // next tick.
        let half = near(0.012).unwrap();
        assert!((half.axes[0] - (0.5 - 0.1) / 0.9).abs() < 1e-3, "{half:?}");
        assert_eq!(half.tick, 0);
        // (y stays where the jitter left it: 900 of 32768, outside the radial deadzone once x
        // is pushed.)
        let full = near(0.020).unwrap();
        assert!(
            full.axes[0] > 0.999 && (full.axes[1] - 900.0 / 32768.0).abs() < 1e-3,
            "{full:?}"
        );
        assert_eq!(full.tick, 1);
        // The mode button: held from 0.14 to 0.23 s, over several ticks: the mapper sees one
        // rising edge.
        let mode_ticks: Vec<u64> = samples
            .iter()
            .filter(|(_, s)| s.buttons & buttons::MODE != 0)
            .map(|(_, s)| s.tick)
            .collect();
        assert_eq!(mode_ticks, [5, 6, 7, 8, 9]);
        // Every sample between them carries the button, so the published sequence has a
        // single rising edge (one press for the mapper), however many samples it spans.
        let rising = samples
            .windows(2)
            .filter(|w| w[1].1.buttons & buttons::MODE != 0 && w[0].1.buttons & buttons::MODE == 0)
            .count();
        assert_eq!(rising, 1);
        // Up-left at full deflection with the gripper closing, then all released.
        let s = at(0.35);
        assert!(s.axes[0] < -0.7 && s.axes[1] > 0.7, "{s:?}");
        assert!((f64::from(s.axes[0]).hypot(f64::from(s.axes[1])) - 1.0).abs() < 1e-3);
        assert_eq!((s.gripper, s.buttons), (1.0, buttons::GRIPPER));
        let s = at(0.45);
        assert_eq!((s.axes, s.gripper, s.buttons), ([0.0, 0.0], 0.0, 0));
    }

    #[test]
    fn an_unplugged_device_publishes_neutral_flagged_samples_every_tick() {
        let mut pad = pad::Pad::new(mapping::Mapping::load("xbox").unwrap());
        pad.connect(&xbox_snapshot());
        let held = [
            (
                0.0,
                pad::RawEvent {
                    kind: pad::EV_ABS,
                    code: 0,
                    value: 32767,
                },
            ),
            (
                0.0,
                pad::RawEvent {
                    kind: pad::EV_SYN,
                    code: pad::SYN_REPORT,
                    value: 0,
                },
            ),
        ];
        let before = play(&mut pad, &held, -0.001, 0.1);
        assert_eq!(before.last().unwrap().1.axes, [1.0, 0.0]);
        pad.disconnect();
        let after = play(&mut pad, &[], 0.2, 0.3);
        // One sample per tick keeps coming (the process is alive), all neutral and flagged.
        assert!(after.len() >= 4);
        for (_, s) in &after {
            assert_eq!(s.axes, [0.0, 0.0]);
            assert_eq!(s.buttons, buttons::NO_DEVICE);
        }
    }

    #[test]
    fn the_outbox_publishes_on_ticks_and_on_changes_only() {
        let mut o = Outbox::default();
        let a = Input {
            axes: [0.5, 0.0],
            ..Input::NEUTRAL
        };
        let first = o.next(Input::NEUTRAL, NO_TICK, false, 1).unwrap();
        assert_eq!((first.seq, first.tick), (0, NO_TICK));
        assert!(o.next(Input::NEUTRAL, NO_TICK, false, 2).is_none());
        let s = o.next(Input::NEUTRAL, 7, true, 3).unwrap();
        assert_eq!((s.seq, s.tick), (1, 7));
        let s = o.next(a, 7, false, 4).unwrap();
        assert_eq!((s.seq, s.tick, s.axes), (2, 7, [0.5, 0.0]));
        assert!(o.next(a, 7, false, 5).is_none());
        assert_eq!(o.next(a, 8, true, 6).unwrap().tick, 8);
    }

    #[test]
    fn the_estop_button_sends_one_command_per_press() {
        let mut b = EstopButton::default();
        let e = buttons::ESTOP;
        assert!(!b.pressed(0));
        assert!(b.pressed(e | buttons::DEADMAN));
        // Held: no second command; other buttons do not matter.
        assert!(!b.pressed(e));
        assert!(!b.pressed(e | buttons::MODE));
        assert!(!b.pressed(buttons::DEADMAN));
        assert!(b.pressed(e));
        // Held from the first sample on is a press.
        assert!(EstopButton::default().pressed(e));
    }

    #[test]
    fn the_waker_wakes_a_wait() {
        let w = Waker::new().unwrap();
        assert_eq!(transport::wait_any(&[&w], Duration::from_millis(1)), 0);
        w.notify();
        w.notify();
        assert_eq!(transport::wait_any(&[&w], Duration::from_secs(5)), 1);
        // Consumed: quiet again.
        assert_eq!(transport::wait_any(&[&w], Duration::from_millis(1)), 0);
    }

    #[test]
    fn config_checks_name_the_key_and_file() {
        let ok = JoystickConfig::default();
        validate(&ok).unwrap();
        let mut j = ok.clone();
        j.source = "wii".into();
        assert!(
            validate(&j)
                .unwrap_err()
                .to_string()
                .contains("joystick.source")
        );
        let mut j = ok.clone();
        j.source = "evdev".into();
        j.mapping = "/nonexistent/pad.toml".into();
        let e = validate(&j).unwrap_err().to_string();
        assert!(
            e.contains("joystick.mapping") && e.contains("/nonexistent/pad.toml"),
            "{e}"
        );
        j.mapping = "generic".into();
        validate(&j).unwrap();
        let mut j = ok.clone();
        j.source = "replay".into();
        assert!(
            validate(&j)
                .unwrap_err()
                .to_string()
                .contains("joystick.replay_file")
        );
        let mut j = ok.clone();
        j.source = EXTERNAL.into();
        validate(&j).unwrap();
        j.record_input = "in.csv".into();
        assert!(
            validate(&j)
                .unwrap_err()
                .to_string()
                .contains("joystick.record_input")
        );
        let mut j = ok;
        j.keyboard_repeat_hold_ms = 1;
        assert!(
            validate(&j)
                .unwrap_err()
                .to_string()
                .contains("joystick.keyboard_repeat_hold_ms")
        );
        // Relative names are taken from the config's directory; built-in mappings are not.
        let mut j = JoystickConfig {
            mapping: "pads/mine.toml".into(),
            replay_file: "in.csv".into(),
            ..JoystickConfig::default()
        };
        scl_config::resolve_joystick_paths(&mut j, Path::new("/etc/scl"));
        assert_eq!(j.mapping, "/etc/scl/pads/mine.toml");
        assert_eq!(j.replay_file, "/etc/scl/in.csv");
        assert_eq!(j.record_input, "");
        let mut j = JoystickConfig::default();
        scl_config::resolve_joystick_paths(&mut j, Path::new("/etc/scl"));
        assert_eq!(j.mapping, "xbox");
    }

    #[test]
    fn the_external_source_starts_no_process() {
        let cfg = JoystickConfig {
            source: EXTERNAL.into(),
            ..JoystickConfig::default()
        };
        let e = Source::open(&cfg, 0.025).err().unwrap();
        assert!(matches!(e, JoystickError::External), "{e}");
        assert!(e.to_string().contains("scl up --joystick external"), "{e}");
    }

    #[test]
    fn the_config_knows_the_builtin_mappings() {
        let names: Vec<&str> = mapping::BUILTIN.iter().map(|(n, _)| *n).collect();
        assert_eq!(names, scl_config::BUILTIN_MAPPINGS);
    }

    #[test]
    fn the_shipped_graph_configs_load() {
        let dir = Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../examples/joystick"
        ));
        for (name, source) in [
            ("gamepad-graph.toml", "evdev"),
            ("keyboard-graph.toml", "keyboard"),
        ] {
            let cfg = GraphConfig::load(Some(&dir.join(name))).unwrap();
            cfg.validate().unwrap();
            validate(&cfg.joystick).unwrap();
            assert_eq!(cfg.joystick.source, source);
            assert_eq!(cfg.mapper.model, "modeswitch");
        }
    }
}
