//! `scl study simulate --live`: the simulated operator on the real process graph. Each attempt
//! starts its own `scl up` (the mock arm exactly at the task's start pose, `[bridge.mock]
//! initial_q`; the condition's model; the `external` joystick source), and the operator of
//! [`study::simulate::AttemptDriver`] answers every robot state with a joystick sample on the
//! graph's joystick topic, as a person's joystick would. The in-process simulation models the
//! same pipeline, so both paths can be compared (the test `study::simulate_live_agrees`).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ipc_types::time::now_ns;
use ipc_types::{NodeRole, Prefix};
use scl_config::GraphConfig;
use study::data::Outcome;
use study::simulate::{Answer, AttemptDriver, AttemptInfo, AttemptResult, AttemptSetup, SimError};
use transport::graph::Graph;
use transport::signals;

/// What disturbed one live attempt, counted in the graph's messages: the in-process path and
/// the live one agree tick for tick only while all of these stay 0. A row of
/// `DIR/Pnn/live/attempts.csv`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LiveCounts {
    /// The attempt (`P01-t1-c2-a1`).
    pub attempt: String,
    /// Success or timeout.
    pub outcome: Outcome,
    /// Time to the success, else the time limit (s).
    pub duration_s: f64,
    /// Subgoals done (%).
    pub completion_pct: f64,
    /// Robot states the operator answered.
    pub answered: u64,
    /// Robot states that came and went while the operator was busy (never answered).
    pub unanswered: u64,
    /// Mapper commands of the attempt that did not map the operator's answer to the previous
    /// state (the sample came too late for the mapper).
    pub late_samples: u64,
    /// Mapper commands of the attempt that mapped the operator's answer to their own state:
    /// the answer beat the mapper's wake-up (the in-process loop never does).
    pub early_samples: u64,
    /// Ticks the bridge missed during the attempt.
    pub missed: u64,
    /// Of those, the ones the bridge counted the machine's.
    pub held_up: u64,
}

impl LiveCounts {
    /// Whether the attempt ran undisturbed.
    pub fn undisturbed(&self) -> bool {
        self.unanswered == 0
            && self.late_samples == 0
            && self.early_samples == 0
            && self.missed == 0
    }
}

/// The file of [`LiveCounts`] rows in a participant's `live/` directory.
pub const ATTEMPTS: &str = "attempts.csv";

/// How the live path runs its graphs.
pub struct LiveSim {
    exe: PathBuf,
    base: GraphConfig,
    prefix: Prefix,
    dir: PathBuf,
}

/// The graphs of `--live` run under this prefix: the command's own with `-sim`, so a graph of
/// the command's prefix (a person's session) is never touched.
pub fn live_prefix(prefix: &Prefix) -> Result<Prefix, SimError> {
    let mut s = prefix.as_str().to_owned();
    s.truncate(ipc_types::prefix::MAX_PREFIX_LEN - 4);
    Prefix::new(&format!("{s}-sim")).map_err(|e| SimError::Live(e.to_string()))
}

/// States the operator lets pass before an attempt starts: the mapper has sent its heartbeat
/// (the screen's mode) and the graph has settled at rest.
const WARM_UP_STATES: u32 = 3;

impl LiveSim {
    /// Graphs configured as `base` (its safety, rate and transport), under the prefix of
    /// [`live_prefix`], their configurations and logs in `dir`. Refuses when a graph of that
    /// prefix runs already.
    pub fn new(base: &GraphConfig, prefix: &Prefix, dir: &Path) -> Result<Self, SimError> {
        let prefix = live_prefix(prefix)?;
        let (alive, _) = transport::graph::census(&prefix)
            .map_err(|e| SimError::Live(format!("graph `{prefix}`: {e}")))?;
        if alive > 0 {
            return Err(SimError::Live(format!(
                "graph `{prefix}` is running already ({alive} processes); another `scl study \
                 simulate --live` with the same --prefix? Use another --prefix"
            )));
        }
        std::fs::create_dir_all(dir)
            .map_err(|e| SimError::Live(format!("{}: {e}", dir.display())))?;
        let exe = std::env::current_exe()
            .map_err(|e| SimError::Live(format!("cannot find the scl executable: {e}")))?;
        Ok(Self {
            exe,
            base: base.clone(),
            prefix,
            dir: dir.to_owned(),
        })
    }

    /// The graph configuration of one attempt.
    fn config(&self, s: &AttemptSetup<'_>, spec: &str) -> GraphConfig {
        let mut cfg = self.base.clone();
        cfg.graph.prefix = self.prefix.to_string();
        // Always the mock arm: a simulated operator never drives a real one.
        cfg.bridge.robot = "mock".to_owned();
        cfg.bridge.mock.initial_q = Some(s.start_q.to_vec());
        cfg.bridge.mock.initial_gripper = 0.0;
        cfg.joystick.source = scl_config::EXTERNAL_JOYSTICK.to_owned();
        cfg.mapper.model = spec.to_owned();
        cfg
    }

    /// Runs attempt `s` through a fresh graph.
    pub fn attempt(
        &self,
        s: &AttemptSetup<'_>,
        info: &AttemptInfo<'_>,
    ) -> Result<AttemptResult, SimError> {
        let mut driver = AttemptDriver::new(s)?;
        let cfg = self.config(s, info.spec);
        let cfg_path = self.dir.join(format!("{}.toml", info.name));
        let log_path = self.dir.join(format!("{}.log", info.name));
        let text = toml::to_string(&cfg)
            .map_err(|e| live(format!("cannot write the attempt's configuration: {e}")))?;
        std::fs::write(&cfg_path, text)
            .map_err(|e| live(format!("{}: {e}", cfg_path.display())))?;
        let log = std::fs::File::create(&log_path)
            .map_err(|e| live(format!("{}: {e}", log_path.display())))?;
        let io = LiveIo::join(&self.prefix)?;
        // The prefix on the command line: it overrides an SCL_PREFIX this process inherited.
        let child = Command::new(&self.exe)
            .args(["up", "--prefix", self.prefix.as_str(), "--config"])
            .arg(&cfg_path)
            .env("SCL_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| live(format!("cannot start `scl up`: {e}")))?;
        let mut up = Up {
            child,
            log: log_path.clone(),
        };
        let start_limit = Duration::from_secs_f64(cfg.graph.start_timeout_s + 10.0);
        let mut run = LiveRun::new(info.name.clone());
        // Every way out of the loop comes back here, so the graph is always stopped and its
        // shared memory released.
        let result = run.drive(&io, &mut up, &mut driver, start_limit);
        let stopped = up.stop();
        drop(io);
        let _ = transport::graph::release_domain(&self.prefix);
        transport::uds::remove_graph(self.prefix.as_str());
        let r = result?;
        stopped?;
        let counts = run.finish(&r);
        tracing::info!(
            attempt = %info.name,
            outcome = counts.outcome.name(),
            duration_s = r.duration_s,
            completion_pct = r.completion_pct,
            answered = counts.answered,
            unanswered = counts.unanswered,
            late_samples = counts.late_samples,
            early_samples = counts.early_samples,
            missed = counts.missed,
            held_up = counts.held_up,
            "live attempt"
        );
        self.append(&counts)?;
        Ok(r)
    }

    /// Appends `c` to the participant's `live/attempts.csv` (the header first in a new file).
    fn append(&self, c: &LiveCounts) -> Result<(), SimError> {
        let path = self.dir.join(ATTEMPTS);
        let fresh = !path.exists();
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| SimError::Live(format!("{}: {e}", path.display())))?;
        let mut w = csv::WriterBuilder::new()
            .has_headers(fresh)
            .from_writer(file);
        w.serialize(c)
            .and_then(|()| w.flush().map_err(csv::Error::from))
            .map_err(|e| SimError::Live(format!("{}: {e}", path.display())))
    }
}

/// The longest the operator waits for the mapper to map a state before answering it.
const MAPPER_WAIT: Duration = Duration::from_millis(10);

/// A live-graph error with its message.
fn live(m: String) -> SimError {
    SimError::Live(m)
}

/// The simulated operator's ends of an attempt's graph: the robot states, the heartbeats and
/// the mapper's commands in, the joystick samples out (dropped in this order, the graph last).
struct LiveIo {
    states: transport::TopicSubscriber<ipc_types::RobotState>,
    status: transport::TopicSubscriber<ipc_types::NodeStatus>,
    commands: transport::TopicSubscriber<ipc_types::MapperCommand>,
    joystick: transport::TopicPublisher<ipc_types::JoystickInput>,
    /// The simulated operator's node, held while the topics are open.
    _graph: Graph,
}

impl LiveIo {
    /// Joins the graph under `prefix` and opens the topics.
    fn join(prefix: &Prefix) -> Result<Self, SimError> {
        let graph = Graph::join(prefix, &format!("simlive-{}", std::process::id()))
            .map_err(|e| live(e.to_string()))?;
        let states = graph
            .robot_state_subscriber(true)
            .map_err(|e| live(e.to_string()))?;
        let status = graph.status_subscriber().map_err(|e| live(e.to_string()))?;
        let commands = graph
            .mapper_command_subscriber(false)
            .map_err(|e| live(e.to_string()))?;
        let joystick = graph
            .joystick_publisher()
            .map_err(|e| live(e.to_string()))?;
        Ok(Self {
            states,
            status,
            commands,
            joystick,
            _graph: graph,
        })
    }
}

/// One live attempt as it goes: the mapper's recent modes, the states seen, the counts,
/// the bridge's counts and the pipeline.
struct LiveRun {
    /// (tick, mode + 1) of the mapper's newest heartbeats.
    modes: VecDeque<(u64, u32)>,
    seen: u32,
    counts: LiveCounts,
    /// The bridge's (missed, held up) counts now and when the attempt started.
    bridge: (u64, u64),
    bridge_at_start: Option<(u64, u64)>,
    pipeline: Pipeline,
}

impl LiveRun {
    /// A run of attempt `name`, nothing seen yet.
    fn new(name: String) -> Self {
        Self {
            modes: VecDeque::new(),
            seen: 0,
            counts: LiveCounts {
                attempt: name,
                outcome: Outcome::Timeout,
                duration_s: 0.0,
                completion_pct: 0.0,
                answered: 0,
                unanswered: 0,
                late_samples: 0,
                early_samples: 0,
                missed: 0,
                held_up: 0,
            },
            bridge: (0, 0),
            bridge_at_start: None,
            pipeline: Pipeline::default(),
        }
    }

    /// Answers each new robot state (after the warm-up) with the driver's sample until the
    /// attempt is done, `scl up` ends, a stop is asked for, or no state comes in time.
    fn drive(
        &mut self,
        io: &LiveIo,
        up: &mut Up,
        driver: &mut AttemptDriver<'_>,
        start_limit: Duration,
    ) -> Result<AttemptResult, SimError> {
        let t0 = Instant::now();
        loop {
            if signals::stop_requested() {
                return Err(live("stopped (Ctrl-C)".into()));
            }
            if let Some(e) = up.exited() {
                return Err(live(e));
            }
            io.states
                .wait(Duration::from_millis(100))
                .map_err(|e| live(e.to_string()))?;
            self.read_heartbeats(io)?;
            self.read_commands(io)?;
            let mut newest = None;
            let n = io
                .states
                .drain(|st| newest = Some(*st))
                .map_err(|e| live(e.to_string()))?;
            let Some(state) = newest else {
                if self.seen == 0 && t0.elapsed() > start_limit {
                    return Err(live(format!(
                        "no robot state in {:.0} s; see {}",
                        start_limit.as_secs_f64(),
                        up.log.display()
                    )));
                }
                continue;
            };
            // The screen's mode: the mapper's heartbeat of an earlier tick.
            let Some(&(_, mode)) = self.modes.iter().rev().find(|(t, _)| *t < state.tick) else {
                continue;
            };
            self.seen += 1;
            if self.seen <= WARM_UP_STATES {
                continue;
            }
            if self.pipeline.first_tick.is_some() {
                self.counts.unanswered += n.saturating_sub(1) as u64;
            }
            self.pipeline.first_tick.get_or_insert(state.tick);
            self.bridge_at_start.get_or_insert(self.bridge);
            match driver.on_state(&state, mode.checked_sub(1).map(|m| m as usize), now_ns())? {
                Answer::Done(r) => return Ok(r),
                Answer::Sample(j) => self.answer(io, state.tick, j)?,
            }
        }
    }

    /// The heartbeats: the mapper's mode by tick, the running bridge's counts.
    fn read_heartbeats(&mut self, io: &LiveIo) -> Result<(), SimError> {
        let (modes, bridge) = (&mut self.modes, &mut self.bridge);
        io.status
            .drain(|h| match NodeRole::from_u32(h.role) {
                Some(NodeRole::Mapper) => {
                    modes.push_back((h.tick, h.mode));
                    if modes.len() > 16 {
                        modes.pop_front();
                    }
                }
                Some(NodeRole::Bridge) if h.phase == ipc_types::phase::RUNNING => {
                    *bridge = (h.faults, u64::from(h.held_up));
                }
                _ => {}
            })
            .map_err(|e| live(e.to_string()))?;
        Ok(())
    }

    /// The mapper's commands: which sample each mapped.
    fn read_commands(&mut self, io: &LiveIo) -> Result<(), SimError> {
        let (pipeline, counts) = (&mut self.pipeline, &mut self.counts);
        io.commands
            .drain(|c| pipeline.take(c, counts))
            .map_err(|e| live(e.to_string()))?;
        Ok(())
    }

    /// Sends the answer `j` to the state of `tick`. As in the in-process loop, the answer is
    /// for the next tick: it waits (at most 10 ms) until the mapper has mapped this one, so
    /// it cannot take the answer early.
    fn answer(
        &mut self,
        io: &LiveIo,
        tick: u64,
        j: ipc_types::JoystickInput,
    ) -> Result<(), SimError> {
        let until = Instant::now() + MAPPER_WAIT;
        while self.pipeline.mapped.is_none_or(|t| t < tick) && Instant::now() < until {
            std::thread::sleep(Duration::from_micros(100));
            self.read_commands(io)?;
        }
        io.joystick.send(j).map_err(|e| live(e.to_string()))?;
        self.counts.answered += 1;
        self.pipeline.sent.push_back((tick, j.seq));
        if self.pipeline.sent.len() > 16 {
            self.pipeline.sent.pop_front();
        }
        Ok(())
    }

    /// The attempt's counts, with the bridge's misses and hold-ups since it started and the
    /// result's outcome, duration and completion.
    fn finish(mut self, r: &AttemptResult) -> LiveCounts {
        let (b0, b1) = self.bridge_at_start.unwrap_or_default();
        self.counts.missed = self.bridge.0.saturating_sub(b0);
        self.counts.held_up = self.bridge.1.saturating_sub(b1);
        self.counts.outcome = r.outcome;
        self.counts.duration_s = r.duration_s;
        self.counts.completion_pct = r.completion_pct;
        self.counts
    }
}

/// What the operator knows of the graph's pipeline: which sample each mapper command mapped.
#[derive(Default)]
struct Pipeline {
    /// The attempt's first tick.
    first_tick: Option<u64>,
    /// The sample (seq) that answered each recent state, by tick.
    sent: VecDeque<(u64, u64)>,
    /// The newest tick the mapper has mapped.
    mapped: Option<u64>,
}

impl Pipeline {
    /// Takes mapper command `c`: each command of the attempt maps the answer to the previous
    /// state; else the answer to its own state beat the mapper to it (early) or the answer to
    /// the previous one came too late.
    fn take(&mut self, c: &ipc_types::MapperCommand, counts: &mut LiveCounts) {
        self.mapped = Some(self.mapped.map_or(c.tick, |t| t.max(c.tick)));
        if self.first_tick.is_none_or(|f| c.tick <= f) {
            return;
        }
        let answer = |t: u64| self.sent.iter().find(|x| x.0 == t).map(|x| x.1);
        if answer(c.tick - 1) != Some(c.joystick_seq) {
            if answer(c.tick) == Some(c.joystick_seq) {
                counts.early_samples += 1;
            } else {
                counts.late_samples += 1;
            }
        }
    }
}

/// The attempt's `scl up`.
struct Up {
    child: Child,
    log: PathBuf,
}

impl Up {
    /// Why the graph ended on its own, if it did.
    fn exited(&mut self) -> Option<String> {
        match self.child.try_wait() {
            Ok(None) => None,
            Ok(Some(st)) => Some(format!(
                "`scl up` ended on its own ({st}); see {}",
                self.log.display()
            )),
            Err(e) => Some(format!("`scl up`: {e}")),
        }
    }

    /// Stops the graph as Ctrl-C would and waits for it (killed after 20 s).
    fn stop(&mut self) -> Result<(), SimError> {
        if self.child.try_wait().ok().flatten().is_none() {
            // Our own child; an error means it has exited, which the wait below sees.
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(self.child.id() as i32),
                nix::sys::signal::Signal::SIGTERM,
            );
        }
        let t0 = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(st)) if st.success() => return Ok(()),
                Ok(Some(st)) => {
                    return Err(SimError::Live(format!(
                        "`scl up` stopped with {st}; see {}",
                        self.log.display()
                    )));
                }
                Ok(None) if t0.elapsed() > Duration::from_secs(20) => {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    return Err(SimError::Live(format!(
                        "`scl up` did not stop within 20 s and was killed; see {}",
                        self.log.display()
                    )));
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(20)),
                Err(e) => return Err(SimError::Live(format!("`scl up`: {e}"))),
            }
        }
    }
}

impl Drop for Up {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
