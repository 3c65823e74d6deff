//! `scl study run`: the experimenter's screen for one participant of a study, on a running
//! graph (`scl up`).
//!
//! For each task, the participant meets the conditions in their Latin-square order. For each
//! condition: the arm goes to the task's start pose (the go-to map, swapped in live), the
//! condition's map is swapped in (shown by its blind label only), practice runs with a
//! countdown, then each attempt: to the start pose, the map back in, start on the
//! experimenter's key, a running clock, stop on the success key, the failure key or the time
//! limit; the attempt may be kept or repeated (the first is kept, marked `repeated`). After
//! each condition the questionnaire. Every attempt is recorded to its own MCAP file (`scl
//! record` with the trial's metadata) and one row of `trials.csv`; answers go to
//! `questionnaire.csv`. The graph never stops between trials.
//!
//! Input is a line at a time (Enter alone continues), from the terminal or, for a scripted
//! operator, a keys file (`--keys`; blank lines and `#` comments are skipped): `go` (Enter), `s` success, `f` failure, `r` repeat,
//! `p` pause/resume, `skip` (practice), `a` abort, a number (completion %, answers), `wait S`
//! (the script pauses S seconds). Abort, Ctrl-C or the end of a keys file leave everything
//! written so far; the same command resumes at the first unfinished attempt.

#![cfg_attr(test, allow(clippy::unwrap_used))]

use std::collections::BTreeMap;
use std::io::{BufRead, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender};
use ipc_types::{NodeRole, NodeStatus, Prefix, RobotState};
use study::data::{self, AnswerRow, Appender, Outcome, Progress, TrialRow};
use study::plan::{Participant, Question, Study};
use transport::{Graph, TopicSubscriber};

pub mod simlive;
pub mod simrecord;

/// Why a study run stopped, each with the message the experimenter sees.
#[derive(Debug, thiserror::Error)]
pub enum StudyRunError {
    /// The study file or the participant's data.
    #[error(transparent)]
    Study(#[from] study::StudyError),
    /// The graph's shared memory.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// A swap or the graph refused.
    #[error(transparent)]
    Control(#[from] graph_client::ControlError),
    /// The graph did not do what the protocol needs (no graph, a refused swap, the arm not
    /// at the start pose in time, the recorder not starting).
    #[error("{0}")]
    Graph(String),
    /// A file of the run.
    #[error("{path}: {source}", path = path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

/// What `scl study run` is asked to do.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// The study file.
    pub study: PathBuf,
    /// The participant (`P03`).
    pub participant: String,
    /// The participant's directory.
    pub out: PathBuf,
    /// A keys file (a scripted operator) instead of the terminal.
    pub keys: Option<PathBuf>,
    /// How long the arm may take to reach a start pose.
    pub arrive_timeout: Duration,
    /// How long a swap may take.
    pub swap_timeout: Duration,
}

/// How a run ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// Every attempt and questionnaire of the plan is done.
    Finished,
    /// Aborted (key, Ctrl-C, the keys file ended): the same command resumes.
    Aborted,
}

/// An experimenter's input.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Key {
    Go,
    Success,
    Failure,
    Repeat,
    Pause,
    Skip,
    Abort,
    Number(u32),
    Other(String),
}

fn parse_key(line: &str) -> Key {
    match line.trim() {
        "" | "go" => Key::Go,
        "s" => Key::Success,
        "f" => Key::Failure,
        "r" => Key::Repeat,
        "p" => Key::Pause,
        "skip" => Key::Skip,
        "a" | "abort" => Key::Abort,
        other => other
            .parse()
            .map_or_else(|_| Key::Other(other.to_owned()), Key::Number),
    }
}

/// Starts the thread that reads the experimenter's lines (the terminal, or the keys file
/// with its `wait S` pauses); the channel closes when the input ends. A keys file goes in
/// lockstep with the protocol: its next line is read only once the protocol took the
/// previous key (an acknowledgement on the returned sender), so `wait S` counts from the
/// moment the key before it acted, as an operator's pause would.
fn input(keys: Option<&Path>) -> Result<(Receiver<Key>, Option<Sender<()>>), StudyRunError> {
    let (tx, rx) = crossbeam_channel::unbounded();
    let mut acks = None;
    match keys {
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|source| StudyRunError::Io {
                path: path.to_owned(),
                source,
            })?;
            let (ack_tx, ack_rx) = crossbeam_channel::unbounded::<()>();
            acks = Some(ack_tx);
            std::thread::spawn(move || {
                for line in text.lines() {
                    let line = line.split('#').next().unwrap_or("").trim();
                    if line.is_empty() {
                        // Blank lines and comments; Enter is `go` in a keys file.
                        continue;
                    }
                    if let Some(s) = line.strip_prefix("wait ") {
                        let secs: f64 = s.trim().parse().unwrap_or(0.0);
                        std::thread::sleep(Duration::from_secs_f64(secs.clamp(0.0, 3600.0)));
                    } else if tx.send(parse_key(line)).is_err() || ack_rx.recv().is_err() {
                        return;
                    }
                }
            });
        }
        None => {
            std::thread::spawn(move || {
                for line in std::io::stdin().lock().lines() {
                    let Ok(line) = line else { return };
                    if tx.send(parse_key(&line)).is_err() {
                        return;
                    }
                }
            });
        }
    }
    Ok((rx, acks))
}

/// The experimenter's screen: a header and a few lines, redrawn on a terminal (80x24), or
/// appended as plain lines otherwise (a scripted run's log).
struct Screen {
    tty: bool,
    header: String,
}

impl Screen {
    fn show(&mut self, lines: &[String]) {
        let mut out = std::io::stdout().lock();
        if self.tty {
            let _ = write!(out, "\x1b[2J\x1b[H{}\n{}\n", self.header, "-".repeat(78));
        }
        for l in lines {
            let _ = writeln!(out, "{l}");
        }
        let _ = out.flush();
    }

    /// One updating line (a clock); on a terminal it overwrites itself.
    fn tick(&self, line: &str) {
        if self.tty {
            let mut out = std::io::stdout().lock();
            let _ = write!(out, "\r{line:<78}");
            let _ = out.flush();
        }
    }
}

/// The graph as the protocol sees it.
struct Live {
    prefix: Prefix,
    robot: &'static kinematics::RobotProfile,
    states: TopicSubscriber<RobotState>,
    status: TopicSubscriber<NodeStatus>,
    estops: TopicSubscriber<ipc_types::control::EstopCommand>,
    state: Option<RobotState>,
    /// Mode switches per mapper id (the mapper's heartbeat).
    mode_switches: BTreeMap<u32, u32>,
    /// Recorder heartbeats seen, by pid.
    recorders: Vec<u32>,
    estops_seen: u32,
    /// Safety's state bits (`ipc_types::safety_state`), from its heartbeat.
    safety_state: u32,
    active: u32,
    swap_timeout: Duration,
    // Declared last: dropped after its ports.
    _graph: Graph,
}

impl Live {
    fn join(
        prefix: &Prefix,
        robot: &'static kinematics::RobotProfile,
        swap_timeout: Duration,
    ) -> Result<Self, StudyRunError> {
        let graph = Graph::join(prefix, &format!("study-{}", std::process::id()))?;
        let mut live = Self {
            prefix: prefix.clone(),
            robot,
            states: graph.robot_state_subscriber(false)?,
            status: graph.status_subscriber()?,
            estops: graph.estop_observer()?,
            state: None,
            mode_switches: BTreeMap::new(),
            recorders: Vec::new(),
            estops_seen: 0,
            safety_state: 0,
            active: 0,
            swap_timeout,
            _graph: graph,
        };
        let t0 = Instant::now();
        while live.state.is_none() {
            live.poll()?;
            if t0.elapsed() > Duration::from_secs(5) {
                return Err(StudyRunError::Graph(format!(
                    "no robot state from graph `{prefix}` in 5 s: start the graph first \
                     (`scl up`, with the same --prefix)"
                )));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(live)
    }

    fn poll(&mut self) -> Result<(), StudyRunError> {
        if let Some(s) = self.states.latest()? {
            self.state = Some(s);
        }
        let (ms, recs, safety) = (
            &mut self.mode_switches,
            &mut self.recorders,
            &mut self.safety_state,
        );
        self.status.drain(|s| match NodeRole::from_u32(s.role) {
            Some(NodeRole::Safety) => *safety = s.safety_state,
            Some(NodeRole::Mapper) => {
                ms.insert(s.mapper_id, s.mode_switches);
            }
            Some(NodeRole::Recorder) if !recs.contains(&s.pid) => recs.push(s.pid),
            _ => {}
        })?;
        let n = &mut self.estops_seen;
        self.estops.drain(|e| {
            if e.action == ipc_types::control::estop_action::ESTOP {
                *n += 1;
            }
        })?;
        Ok(())
    }

    /// Swaps the active mapper for one serving `spec`; the new mapper's id.
    fn swap(&mut self, spec: &str) -> Result<u32, StudyRunError> {
        let r = graph_client::control::swap(&self.prefix, spec, self.swap_timeout)?;
        if r.ok != 1 {
            return Err(StudyRunError::Graph(format!(
                "the graph refused a swap: {}",
                r.message.as_string()
            )));
        }
        self.active = r.new_mapper;
        Ok(r.new_mapper)
    }

    fn mode_switches(&self) -> u32 {
        self.mode_switches.get(&self.active).copied().unwrap_or(0)
    }
}

/// The arm is at rest at the start pose when no joint moves faster than this (rad/s).
const AT_REST_RAD_S: f64 = 0.01;

/// Where the protocol goes after an input.
enum Flow<T> {
    Go(T),
    Abort,
}

/// Runs the protocol for one participant.
pub fn run(
    prefix: &Prefix,
    robot: &'static kinematics::RobotProfile,
    opts: &RunOptions,
) -> Result<RunEnd, StudyRunError> {
    let study = Study::load(&opts.study, robot)?;
    let participant = study.participant(&opts.participant)?;
    let pid = participant.to_string();
    let dir = &opts.out;
    let recordings = dir.join("recordings");
    std::fs::create_dir_all(&recordings).map_err(|source| StudyRunError::Io {
        path: recordings.clone(),
        source,
    })?;
    keep_study_copy(&study, &opts.study, dir, &pid)?;
    let mut progress = Progress::load(dir, &pid)?;
    let (keys, acks) = input(opts.keys.as_deref())?;
    let mut screen = Screen {
        tty: opts.keys.is_none() && std::io::stdout().is_terminal(),
        header: format!("{}  |  participant {pid}", study.file.name),
    };
    let mut live = Live::join(prefix, robot, opts.swap_timeout)?;
    let mut trials = Appender::open(&dir.join(data::TRIALS))?;
    let mut answers = Appender::open(&dir.join(data::QUESTIONNAIRE))?;
    let order = study.order(participant);
    let labels: Vec<&str> = order
        .iter()
        .map(|&i| study.file.conditions[i].label.as_str())
        .collect();
    screen.show(&[format!("order: {}", labels.join(" "))]);
    let mut p = Protocol {
        study: &study,
        participant,
        dir,
        recordings: &recordings,
        keys: &keys,
        live: &mut live,
        screen: &mut screen,
        arrive_timeout: opts.arrive_timeout,
        front: None,
        acks,
    };
    for (ti, task) in study.file.tasks.iter().enumerate() {
        for (pos, &ci) in order.iter().enumerate() {
            let cond = &study.file.conditions[ci];
            let all_done = (1..=task.attempts)
                .all(|a| progress.attempt_done(&task.name, &cond.label, a))
                && (study.file.questionnaire.questions().is_empty()
                    || progress.answered(&task.name, &cond.label));
            if all_done {
                continue;
            }
            let fresh =
                !(1..=task.attempts).any(|a| progress.attempt_done(&task.name, &cond.label, a));
            p.screen.header = format!(
                "{}  |  {pid}  |  task {}  |  condition {} ({}/{})",
                study.file.name,
                task.name,
                cond.label,
                pos + 1,
                order.len()
            );
            if fresh && task.practice_s > 0.0 {
                if let Flow::Abort = p.go_to_start(task)? {
                    return Ok(RunEnd::Aborted);
                }
                p.live.swap(&study.models[ci][ti])?;
                if let Flow::Abort = p.practice(task, &cond.label)? {
                    return Ok(RunEnd::Aborted);
                }
            }
            if let Flow::Abort = p.attempts(ti, ci, pos as u32 + 1, &mut progress, &mut trials)? {
                return Ok(RunEnd::Aborted);
            }
            if !progress.answered(&task.name, &cond.label) {
                let qs = study.file.questionnaire.questions();
                if !qs.is_empty() {
                    let rows = match p.questionnaire(task, ci, &qs)? {
                        Flow::Go(rows) => rows,
                        Flow::Abort => return Ok(RunEnd::Aborted),
                    };
                    answers.push_all(&rows)?;
                    progress.answers.extend(rows);
                }
            }
        }
    }
    p.screen.header = format!("{}  |  participant {pid}", study.file.name);
    p.screen.show(&[format!(
        "study finished: {} attempts in {}",
        progress.trials.len(),
        dir.join(data::TRIALS).display()
    )]);
    Ok(RunEnd::Finished)
}

/// The study file this participant runs under, kept beside the data (`dir`); a changed file
/// is refused (the plan and the data would no longer agree).
fn keep_study_copy(study: &Study, file: &Path, dir: &Path, pid: &str) -> Result<(), StudyRunError> {
    let copy = dir.join(data::STUDY_COPY);
    match std::fs::read_to_string(&copy) {
        Ok(old) if old != study.text => {
            return Err(StudyRunError::Graph(format!(
                "{} changed since {pid} started (their copy: {}); finish them with the \
                 copy, or give the new study a new directory",
                file.display(),
                copy.display()
            )));
        }
        Ok(_) => {}
        Err(_) => std::fs::write(&copy, &study.text).map_err(|source| StudyRunError::Io {
            path: copy.clone(),
            source,
        })?,
    }
    Ok(())
}

struct Protocol<'a> {
    study: &'a Study,
    participant: Participant,
    dir: &'a Path,
    recordings: &'a Path,
    keys: &'a Receiver<Key>,
    live: &'a mut Live,
    screen: &'a mut Screen,
    arrive_timeout: Duration,
    /// The next key, read but not taken.
    front: Option<Key>,
    /// Tells a keys file that its key was taken.
    acks: Option<Sender<()>>,
}

impl Protocol<'_> {
    /// The next key without taking it, polling the graph (up to 100 ms when none is
    /// waiting); `Abort` on Ctrl-C or the end of the input. Keys are taken strictly in order:
    /// a phase that does not handle the next key (the arm moving, the clock running) leaves
    /// it for the prompt that does.
    fn peek(&mut self) -> Result<Option<Key>, StudyRunError> {
        self.live.poll()?;
        if transport::signals::stop_requested() {
            return Ok(Some(Key::Abort));
        }
        if self.front.is_some() {
            std::thread::sleep(Duration::from_millis(20));
        } else {
            match self.keys.recv_timeout(Duration::from_millis(100)) {
                Ok(k) => self.front = Some(k),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return Ok(Some(Key::Abort)),
            }
        }
        Ok(self.front.clone())
    }

    /// Takes the key [`Protocol::peek`] returned.
    fn take(&mut self) {
        if self.front.take().is_some()
            && let Some(a) = &self.acks
        {
            let _ = a.send(());
        }
    }

    /// Shows `prompt` and waits for one of `accept` (or abort).
    fn ask(&mut self, prompt: &str, accept: &[Key]) -> Result<Flow<Key>, StudyRunError> {
        self.screen.show(&[prompt.to_owned()]);
        loop {
            match self.peek()? {
                None => {}
                Some(Key::Abort) => return Ok(Flow::Abort),
                Some(k) => {
                    self.take();
                    if accept.contains(&k) {
                        return Ok(Flow::Go(k));
                    }
                    self.screen
                        .show(&[format!("  ({k:?} is not an answer here) {prompt}")]);
                }
            }
        }
    }

    /// Asks for a number in `lo..=hi` until one comes (or abort).
    fn ask_number(
        &mut self,
        prompt: &str,
        check: impl Fn(u32) -> Result<(), String>,
    ) -> Result<Flow<u32>, StudyRunError> {
        self.screen.show(&[prompt.to_owned()]);
        loop {
            let k = self.peek()?;
            if k.is_some() && k != Some(Key::Abort) {
                self.take();
            }
            match k {
                None => {}
                Some(Key::Abort) => return Ok(Flow::Abort),
                Some(Key::Number(n)) => match check(n) {
                    Ok(()) => return Ok(Flow::Go(n)),
                    Err(e) => self.screen.show(&[format!("  {e}; again: {prompt}")]),
                },
                Some(k) => self
                    .screen
                    .show(&[format!("  ({k:?} is not a number) {prompt}")]),
            }
        }
    }

    /// Drives the arm to `task`'s start pose with the go-to map and waits until it is there.
    fn go_to_start(&mut self, task: &study::plan::Task) -> Result<Flow<()>, StudyRunError> {
        let spec = task.goto_spec();
        let (_, goal) = mapper::goto::GotoMap::from_spec_for(self.live.robot, &spec)
            .map_err(|e| StudyRunError::Graph(e.to_string()))?;
        self.live.swap(&spec)?;
        self.screen.show(&[
            "moving to the start pose (the deadman must be held if it is required)".to_owned(),
        ]);
        let t0 = Instant::now();
        loop {
            if let Some(Key::Abort) = self.peek()? {
                return Ok(Flow::Abort);
            }
            let Some(s) = self.live.state else { continue };
            let n = (s.n_joints as usize).min(s.q_rad.len());
            let q = &s.q_rad[..n];
            // At the pose and at rest: an arm still coasting from the previous map (braking
            // within the acceleration limits) may pass through the pose.
            let resting = s.qdot_rad_s[..n].iter().all(|v| v.abs() <= AT_REST_RAD_S);
            if goal.is_at(q) && resting {
                self.screen.show(&["at the start pose".to_owned()]);
                return Ok(Flow::Go(()));
            }
            let left = goal
                .goal()
                .iter()
                .zip(q)
                .map(|(g, q)| (g - q).abs())
                .fold(0.0, f64::max);
            let st = self.live.safety_state;
            let why = if st & ipc_types::safety_state::ESTOP != 0 {
                "  (e-stop latched: `scl reset`)"
            } else if st & ipc_types::safety_state::AWAITING_NEUTRAL != 0 {
                "  (safety waits for the stick at rest)"
            } else if st & ipc_types::safety_state::HOLD != 0 {
                "  (the graph holds the arm)"
            } else {
                ""
            };
            self.screen
                .tick(&format!("to the start pose: {left:.3} rad to go{why}"));
            if t0.elapsed() > self.arrive_timeout {
                return Err(StudyRunError::Graph(format!(
                    "the arm did not reach the start pose of task {} within {:.0} s ({left:.3} rad \
                     to go{why}): is the deadman held, the stick released, an e-stop latched?",
                    task.name,
                    self.arrive_timeout.as_secs_f64()
                )));
            }
        }
    }

    fn practice(
        &mut self,
        task: &study::plan::Task,
        label: &str,
    ) -> Result<Flow<()>, StudyRunError> {
        if let Flow::Abort = self.ask(
            &format!(
                "practice with {label} ({:.0} s): Enter to start, `skip` to skip",
                task.practice_s
            ),
            &[Key::Go, Key::Skip],
        )? {
            return Ok(Flow::Abort);
        }
        let t0 = Instant::now();
        loop {
            let left = task.practice_s - t0.elapsed().as_secs_f64();
            if left <= 0.0 {
                break;
            }
            self.screen.tick(&format!(
                "practice {label}: {left:5.1} s left (Enter or `skip` ends it)"
            ));
            match self.peek()? {
                Some(Key::Abort) => return Ok(Flow::Abort),
                Some(Key::Go | Key::Skip) => {
                    self.take();
                    break;
                }
                _ => {}
            }
        }
        self.screen.show(&[format!("practice with {label} over")]);
        Ok(Flow::Go(()))
    }

    /// The attempts of task `ti` under condition `ci` (at `position` in the order) not done
    /// yet, each run again while the experimenter repeats it; each row kept.
    fn attempts(
        &mut self,
        ti: usize,
        ci: usize,
        position: u32,
        progress: &mut Progress,
        trials: &mut Appender,
    ) -> Result<Flow<()>, StudyRunError> {
        let task = &self.study.file.tasks[ti];
        let cond = &self.study.file.conditions[ci];
        for attempt in 1..=task.attempts {
            if progress.attempt_done(&task.name, &cond.label, attempt) {
                continue;
            }
            loop {
                let row = match self.attempt(ti, ci, position, attempt)? {
                    Flow::Go(row) => row,
                    Flow::Abort => return Ok(Flow::Abort),
                };
                trials.push(&row)?;
                let repeated = row.repeated;
                progress.trials.push(row);
                if !repeated {
                    break;
                }
            }
        }
        Ok(Flow::Go(()))
    }

    /// One attempt, from the start pose to the kept-or-repeated decision; its row.
    fn attempt(
        &mut self,
        ti: usize,
        ci: usize,
        position: u32,
        attempt: u32,
    ) -> Result<Flow<TrialRow>, StudyRunError> {
        let study = self.study;
        let task = &study.file.tasks[ti];
        let cond = &study.file.conditions[ci];
        if let Flow::Abort = self.go_to_start(task)? {
            return Ok(Flow::Abort);
        }
        self.live.swap(&study.models[ci][ti])?;
        if let Flow::Abort = self.ask(
            &format!(
                "{} attempt {attempt} of {}: Enter starts the clock",
                cond.label, task.attempts
            ),
            &[Key::Go],
        )? {
            return Ok(Flow::Abort);
        }
        let (mut rec, mcap) = self.start_recording(ti, ci, position, attempt)?;
        let started_unix_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let switches0 = self.live.mode_switches();
        let estops0 = self.live.estops_seen;
        let Flow::Go((outcome, duration)) =
            self.run_clock(task, &cond.label, attempt, &mut rec, &mcap)?
        else {
            return Ok(Flow::Abort);
        };
        // Milliseconds are all a stopwatch of the protocol's keys can claim.
        let duration_s = (duration.as_secs_f64().min(task.time_limit_s) * 1e3).round() / 1e3;
        let completion = match self.ask_completion(outcome, &cond.label)? {
            Flow::Go(n) => n,
            Flow::Abort => {
                rec.stop(None)?;
                return Ok(Flow::Abort);
            }
        };
        let repeated = match self.ask(
            &format!(
                "{} attempt {attempt}: {}; Enter keeps it, `r` repeats it",
                cond.label,
                outcome.name()
            ),
            &[Key::Go, Key::Repeat],
        )? {
            Flow::Go(k) => k == Key::Repeat,
            Flow::Abort => {
                rec.stop(None)?;
                return Ok(Flow::Abort);
            }
        };
        self.live.poll()?;
        let row = TrialRow {
            study: study.file.name.clone(),
            participant: self.participant.to_string(),
            task: task.name.clone(),
            label: cond.label.clone(),
            condition: cond.name.clone(),
            model: study.models[ci][ti].clone(),
            position,
            attempt,
            repeated,
            outcome,
            completion_pct: f64::from(completion),
            duration_s,
            mode_switches: self.live.mode_switches().saturating_sub(switches0),
            estops: self.live.estops_seen - estops0,
            recording: mcap
                .strip_prefix(self.dir)
                .unwrap_or(&mcap)
                .display()
                .to_string(),
            started_unix_s,
        };
        rec.stop(Some(&row))?;
        Ok(Flow::Go(row))
    }

    /// Starts the attempt's recorder (its metadata: the study, the participant, the task,
    /// the condition, the model and the attempt) and waits up to 10 s for it to join.
    fn start_recording(
        &mut self,
        ti: usize,
        ci: usize,
        position: u32,
        attempt: u32,
    ) -> Result<(Recording, PathBuf), StudyRunError> {
        let study = self.study;
        let task = &study.file.tasks[ti];
        let cond = &study.file.conditions[ci];
        let stem = format!(
            "{}-{}-{}-{attempt}",
            self.participant, task.name, cond.label
        );
        let mcap = data::fresh_name(self.recordings, &stem, "mcap");
        let outcome_file = mcap.with_extension("outcome.json");
        let meta = [
            ("study", study.file.name.clone()),
            ("participant", self.participant.to_string()),
            ("task", task.name.clone()),
            (
                "goals",
                task.goals.clone().unwrap_or_else(|| task.name.clone()),
            ),
            ("label", cond.label.clone()),
            ("condition", cond.name.clone()),
            ("model", study.models[ci][ti].clone()),
            ("position", position.to_string()),
            ("attempt", attempt.to_string()),
        ];
        let mut rec = Recording::start(&self.live.prefix, &mcap, &outcome_file, &meta)?;
        let t_wait = Instant::now();
        while !self.live.recorders.contains(&rec.pid()) {
            self.live.poll()?;
            if let Some(status) = rec.exited() {
                return Err(StudyRunError::Graph(format!(
                    "the recorder for {} exited ({status}); see {}",
                    mcap.display(),
                    rec.log.display()
                )));
            }
            if t_wait.elapsed() > Duration::from_secs(10) {
                return Err(StudyRunError::Graph(format!(
                    "the recorder for {} did not start in 10 s; see {}",
                    mcap.display(),
                    rec.log.display()
                )));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok((rec, mcap))
    }

    /// The attempt's clock, with pauses, until the success or failure key or the time
    /// limit: its outcome and active time. An abort stops the recording (kept).
    fn run_clock(
        &mut self,
        task: &study::plan::Task,
        label: &str,
        attempt: u32,
        rec: &mut Recording,
        mcap: &Path,
    ) -> Result<Flow<(Outcome, Duration)>, StudyRunError> {
        self.screen.show(&[format!(
            "{} attempt {attempt}: running. `s` success, `f` failure, `p` pause, `a` abort",
            label
        )]);
        let mut active = Duration::ZERO;
        let mut since = Some(Instant::now());
        let limit = Duration::from_secs_f64(task.time_limit_s);
        let outcome = loop {
            let now = active + since.map_or(Duration::ZERO, |s| s.elapsed());
            if now >= limit {
                break Outcome::Timeout;
            }
            self.screen.tick(&format!(
                "{} attempt {attempt}: {:6.1} s of {:.0} s{}",
                label,
                now.as_secs_f64(),
                task.time_limit_s,
                if since.is_none() {
                    "  PAUSED (`p` resumes)"
                } else {
                    ""
                }
            ));
            match self.peek()? {
                Some(Key::Success) => {
                    self.take();
                    break Outcome::Success;
                }
                Some(Key::Failure) => {
                    self.take();
                    break Outcome::Failure;
                }
                Some(Key::Pause) => {
                    self.take();
                    match since.take() {
                        Some(s) => active += s.elapsed(),
                        None => since = Some(Instant::now()),
                    }
                }
                Some(Key::Abort) => {
                    rec.stop(None)?;
                    self.screen.show(&[format!(
                        "aborted during {} attempt {attempt}: its recording {} is kept; the \
                         attempt is run again on resume",
                        label,
                        mcap.display()
                    )]);
                    return Ok(Flow::Abort);
                }
                _ => {}
            }
        };
        Ok(Flow::Go((
            outcome,
            active + since.map_or(Duration::ZERO, |s| s.elapsed()),
        )))
    }

    /// The completion in % of an attempt: 100 for a success, else asked.
    fn ask_completion(
        &mut self,
        outcome: Outcome,
        label: &str,
    ) -> Result<Flow<u32>, StudyRunError> {
        if outcome == Outcome::Success {
            return Ok(Flow::Go(100));
        }
        self.ask_number(
            &format!("{} ({label}): completion in % (0-100)?", outcome.name()),
            |n| {
                if n <= 100 {
                    Ok(())
                } else {
                    Err(format!("{n} is not a percentage"))
                }
            },
        )
    }

    fn questionnaire(
        &mut self,
        task: &study::plan::Task,
        ci: usize,
        qs: &[Question],
    ) -> Result<Flow<Vec<AnswerRow>>, StudyRunError> {
        let cond = &self.study.file.conditions[ci];
        self.screen
            .show(&[format!("questionnaire for {} on {}", cond.label, task.name)]);
        let mut rows = Vec::new();
        for q in qs {
            let prompt = format!(
                "[{}] {} ({}-{}{})",
                cond.label,
                q.item,
                q.min,
                q.max,
                if q.step > 1 {
                    format!(", steps of {}", q.step)
                } else {
                    String::new()
                }
            );
            let v = match self.ask_number(&prompt, |n| q.check(n))? {
                Flow::Go(v) => v,
                Flow::Abort => return Ok(Flow::Abort),
            };
            rows.push(AnswerRow {
                study: self.study.file.name.clone(),
                participant: self.participant.to_string(),
                task: task.name.clone(),
                label: cond.label.clone(),
                condition: cond.name.clone(),
                kind: q.kind.to_owned(),
                item: q.item.clone(),
                value: v,
            });
        }
        Ok(Flow::Go(rows))
    }
}

/// One attempt's recorder: `scl record` as a child with the trial's metadata.
struct Recording {
    child: Child,
    outcome_file: PathBuf,
    log: PathBuf,
}

impl Recording {
    fn start(
        prefix: &Prefix,
        mcap: &Path,
        outcome_file: &Path,
        meta: &[(&str, String)],
    ) -> Result<Self, StudyRunError> {
        let exe = std::env::current_exe().map_err(|source| StudyRunError::Io {
            path: PathBuf::from("/proc/self/exe"),
            source,
        })?;
        let log = mcap.with_extension("log");
        let log_file = std::fs::File::create(&log).map_err(|source| StudyRunError::Io {
            path: log.clone(),
            source,
        })?;
        let mut c = Command::new(exe);
        c.arg("record")
            .arg("--out")
            .arg(mcap)
            .arg("--meta-at-stop")
            .arg(outcome_file)
            .env("SCL_PREFIX", prefix.as_str())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log_file);
        for (k, v) in meta {
            c.arg("--meta").arg(format!("{k}={v}"));
        }
        let child = c.spawn().map_err(|source| StudyRunError::Io {
            path: mcap.to_owned(),
            source,
        })?;
        Ok(Self {
            child,
            outcome_file: outcome_file.to_owned(),
            log,
        })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }

    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// Writes the outcome (if any) for the recorder to embed, stops it (SIGINT) and waits.
    fn stop(&mut self, row: Option<&TrialRow>) -> Result<(), StudyRunError> {
        if let Some(row) = row {
            let v = serde_json::json!({
                "outcome": row.outcome.name(),
                "completion_pct": row.completion_pct,
                "duration_s": row.duration_s,
                "mode_switches": row.mode_switches,
                "estops": row.estops,
                "repeated": row.repeated,
            });
            std::fs::write(&self.outcome_file, v.to_string()).map_err(|source| {
                StudyRunError::Io {
                    path: self.outcome_file.clone(),
                    source,
                }
            })?;
        }
        let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT);
        let t0 = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(_)) => return Ok(()),
                Ok(None) if t0.elapsed() < Duration::from_secs(10) => {
                    std::thread::sleep(Duration::from_millis(10));
                }
                _ => {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    return Err(StudyRunError::Graph(format!(
                        "the recorder did not stop in 10 s; see {}",
                        self.log.display()
                    )));
                }
            }
        }
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let pid = nix::unistd::Pid::from_raw(self.child.id() as i32);
            let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT);
            let _ = self.child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_keys_file_goes_in_lockstep_and_skips_comments() {
        let path = std::env::temp_dir().join(format!("scl-keys-{}", std::process::id()));
        std::fs::write(&path, "# a comment\n\ngo  # Enter\nwait 0.01\n55\n").unwrap();
        let (rx, acks) = input(Some(&path)).unwrap();
        let acks = acks.unwrap();
        assert_eq!(rx.recv_timeout(Duration::from_secs(5)), Ok(Key::Go));
        // The next key only once this one was taken.
        assert!(rx.recv_timeout(Duration::from_millis(100)).is_err());
        acks.send(()).unwrap();
        assert_eq!(rx.recv_timeout(Duration::from_secs(5)), Ok(Key::Number(55)));
        acks.send(()).unwrap();
        // The file ended: the channel closes.
        assert!(matches!(
            rx.recv_timeout(Duration::from_secs(5)),
            Err(RecvTimeoutError::Disconnected)
        ));
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn keys_parse() {
        assert_eq!(parse_key(""), Key::Go);
        assert_eq!(parse_key(" go "), Key::Go);
        assert_eq!(parse_key("s"), Key::Success);
        assert_eq!(parse_key("75"), Key::Number(75));
        assert_eq!(parse_key("x"), Key::Other("x".into()));
    }
}

/// `scl study`'s subcommands.
#[derive(Debug, Clone, clap::Subcommand)]
pub enum StudyCmd {
    /// Walk one participant through the study on the running graph (`scl up` first, same
    /// --prefix): start poses, blind live swaps, practice, attempts (one MCAP and one row of
    /// trials.csv each), questionnaires. Interrupted (abort, Ctrl-C, a crash), the same
    /// command resumes at the first unfinished attempt; nothing is overwritten.
    Run {
        /// The study file (see examples/study/).
        study: PathBuf,
        /// The participant: P01 to P<participants> of the study file.
        #[arg(long)]
        participant: String,
        /// The participant's directory (trials.csv, questionnaire.csv, recordings/).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Read the experimenter's keys from FILE (a scripted operator) instead of the
        /// terminal: one per line, `go`, `s`, `f`, `r`, `p`, `skip`, `a`, numbers, `wait S`;
        /// blank lines and `#` comments are skipped.
        #[arg(long, value_name = "FILE")]
        keys: Option<PathBuf>,
        /// How long the arm may take to reach a start pose.
        #[arg(long, default_value = "120", value_name = "SECONDS")]
        arrive_timeout_s: f64,
    },
    /// Merge participants' directories into the paper's figures (PNG and SVG), tables (CSV)
    /// and summary.md (Kruskal-Wallis, then Dunn with Holm where significant).
    Report {
        /// Participants' directories (as `scl study run --out` wrote them).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Where to write the report (created; existing files of the report are replaced,
        /// the data never is).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// The condition the Likert radar's stars compare against (default: the first by
        /// label).
        #[arg(long)]
        reference: Option<String>,
    },
    /// Run the study with simulated participants instead of people: the same protocol
    /// (Latin-square order, attempts, time limits; questionnaires left out; practice only for
    /// the practiced operator, which learns the map in it) through the served maps, the graph's safety filter (--config) and the mock arm, faster
    /// than real time and deterministic for a seed. Writes DIR/P01/trials.csv ... and the
    /// report (DIR/report, with the paper's claims checked in summary.md). With --live, each
    /// attempt runs through the real process graph instead, in real time.
    Simulate {
        /// The study file (its `[simulation]` section sets the operator: greedy, practiced or
        /// expert; see examples/study/ and docs/simulated-participants.md).
        study: PathBuf,
        /// How many simulated participants (P01 ..; orders by the Latin square).
        #[arg(long, default_value = "13")]
        participants: u32,
        /// Where to write the participants' directories and the report (refused if a
        /// participant's trials.csv is there already).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// The random seed (the same seed gives the same files).
        #[arg(long, default_value = "1")]
        seed: u64,
        /// Participants simulated at once (default: the cores available; with --live one at
        /// a time).
        #[arg(long)]
        jobs: Option<usize>,
        /// Run every attempt through the real process graph at the graph's rate instead of in
        /// process: a fresh `scl up` per attempt (mock arm at the start pose, the condition's
        /// model, the `external` joystick source, under the prefix PREFIX-sim) with the
        /// operator publishing its samples on the joystick topic. For checking that both
        /// paths agree; takes the attempts' real time. Each attempt's graph configuration and
        /// log are kept in DIR/Pnn/live/.
        #[arg(long)]
        live: bool,
        /// Only this task (by name); the plan's order is kept.
        #[arg(long)]
        task: Option<String>,
        /// Only this condition (by label or name); the Latin-square positions are kept.
        #[arg(long)]
        condition: Option<String>,
        /// Record each attempt as DIR/Pnn/recordings/Pnn-tT-cC-aA.mcap, in the format `scl up
        /// --record` writes (`scl replay` re-executes it bit for bit; Foxglove shows it in 3D),
        /// with what the goal tracker and the operator saw each tick on /scl/sim/operator.
        /// Not with --live.
        #[arg(long)]
        record: bool,
    },
    /// Print the plan: each participant's order of the conditions (blind labels), checking
    /// the study file on the way.
    Plan {
        /// The study file.
        study: PathBuf,
        /// Only this participant.
        #[arg(long)]
        participant: Option<String>,
    },
}

/// Runs `scl study ...` for graph `prefix` on robot `robot`.
pub fn cli(
    prefix: &Prefix,
    robot: &'static kinematics::RobotProfile,
    cmd: &StudyCmd,
    graph: &scl_config::GraphConfig,
) -> Result<std::process::ExitCode, StudyRunError> {
    match cmd {
        StudyCmd::Simulate {
            study,
            participants,
            out,
            seed,
            jobs,
            live,
            task,
            condition,
            record,
        } => {
            let only = study::simulate::Selection {
                task: task.clone(),
                condition: condition.clone(),
            };
            let how = if *live {
                Run::Live(prefix)
            } else {
                Run::InProcess { jobs: *jobs }
            };
            if *live && *record {
                return Err(StudyRunError::Graph(
                    "--record with --live: the live graph's attempts are recorded by `scl                      record` beside it; --record records the in-process attempts"
                        .into(),
                ));
            }
            if *live && jobs.is_some_and(|j| j != 1) {
                return Err(StudyRunError::Graph(
                    "--jobs with --live: the live graphs run one at a time (each takes the \
                     machine's real time); leave --jobs out"
                        .into(),
                ));
            }
            let req = SimulateRequest {
                study,
                participants: *participants,
                out,
                seed: *seed,
                only,
                how,
                record: *record,
            };
            simulate(robot, graph, &req)?;
            Ok(std::process::ExitCode::SUCCESS)
        }
        StudyCmd::Run {
            study,
            participant,
            out,
            keys,
            arrive_timeout_s,
        } => {
            if !(arrive_timeout_s.is_finite() && *arrive_timeout_s > 0.0) {
                return Err(StudyRunError::Graph(format!(
                    "--arrive-timeout-s {arrive_timeout_s}: must be a positive number of seconds"
                )));
            }
            let opts = RunOptions {
                study: study.clone(),
                participant: participant.clone(),
                out: out.clone(),
                keys: keys.clone(),
                arrive_timeout: Duration::from_secs_f64(*arrive_timeout_s),
                swap_timeout: Duration::from_secs(30),
            };
            Ok(match run(prefix, robot, &opts)? {
                RunEnd::Finished => std::process::ExitCode::SUCCESS,
                RunEnd::Aborted => {
                    eprintln!(
                        "scl study: stopped; everything so far is in {}; run the same command \
                         to resume",
                        out.display()
                    );
                    std::process::ExitCode::from(3)
                }
            })
        }
        StudyCmd::Report {
            dirs,
            out,
            reference,
        } => {
            let data = study::report::Data::load(dirs)?;
            let r = study::report::analyse(&data, reference.as_deref())?;
            let files = study::report::write(&r, out)?;
            for f in files {
                println!("{}", f.display());
            }
            Ok(std::process::ExitCode::SUCCESS)
        }
        StudyCmd::Plan { study, participant } => {
            let s = Study::load(study, robot)?;
            let ids: Vec<Participant> = match participant {
                Some(p) => vec![s.participant(p)?],
                None => (1..=s.file.participants).map(Participant).collect(),
            };
            for p in ids {
                let labels: Vec<&str> = s
                    .order(p)
                    .iter()
                    .map(|&i| s.file.conditions[i].label.as_str())
                    .collect();
                println!("{p}: {}", labels.join(" "));
            }
            Ok(std::process::ExitCode::SUCCESS)
        }
    }
}

/// How `scl study simulate` runs the attempts.
#[derive(Debug, Clone, Copy)]
pub enum Run<'a> {
    /// In process on simulated time, `jobs` participants at once (default: the cores).
    InProcess {
        /// Participants at once.
        jobs: Option<usize>,
    },
    /// Through the real process graph (`--live`), one attempt at a time, graphs under
    /// [`simlive::live_prefix`] of this prefix.
    Live(&'a Prefix),
}

/// What `scl study simulate` is asked for.
#[derive(Debug, Clone)]
pub struct SimulateRequest<'a> {
    /// The study file.
    pub study: &'a Path,
    /// How many simulated participants (P01 ..).
    pub participants: u32,
    /// Where their directories and the report go.
    pub out: &'a Path,
    /// The random seed.
    pub seed: u64,
    /// Part of the protocol (`--task`, `--condition`).
    pub only: study::simulate::Selection,
    /// In process or through the live graph.
    pub how: Run<'a>,
    /// Record each in-process attempt ([`simrecord`]).
    pub record: bool,
}

/// `scl study simulate`: the request's simulated participants into its `out` (one directory
/// each), then the report into `out/report`.
pub fn simulate(
    robot: &'static kinematics::RobotProfile,
    graph: &scl_config::GraphConfig,
    req: &SimulateRequest<'_>,
) -> Result<(), StudyRunError> {
    use rayon::prelude::*;
    let SimulateRequest {
        study: study_path,
        participants,
        out,
        seed,
        ref only,
        how,
        record,
    } = *req;
    if participants == 0 {
        return Err(StudyRunError::Graph(
            "--participants 0: simulate at least one".into(),
        ));
    }
    let s = Study::load(study_path, robot)?;
    let sim = study::simulate::Loop {
        robot,
        safety: graph.safety.clone(),
        period_s: graph.period_s(),
    };
    // Refuse a bad task before anything runs.
    study::simulate::study_goals(&s, robot).map_err(study::StudyError::from)?;
    only.check(&s)?;
    let attempts = only.attempts(&s) * u64::from(participants);
    let bar = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        let b = indicatif::ProgressBar::new(attempts);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} attempts, {eta} left",
        ) {
            b.set_style(style.progress_chars("=> "));
        }
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let started = Instant::now();
    let dirs: Vec<PathBuf> = (1..=participants)
        .map(|n| out.join(Participant(n).to_string()))
        .collect();
    let results: Vec<Result<Vec<study::data::TrialRow>, study::StudyError>> = match how {
        Run::InProcess { jobs } => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(jobs.unwrap_or(0))
                .build()
                .map_err(|e| StudyRunError::Graph(format!("--jobs: {e}")))?;
            pool.install(|| {
                dirs.par_iter()
                    .enumerate()
                    .map(|(i, dir)| {
                        study::simulate::simulate_participant_with(
                            &s,
                            &sim,
                            Participant(i as u32 + 1),
                            seed,
                            dir,
                            only,
                            &|| bar.inc(1),
                            &transport::signals::stop_requested,
                            &|setup, info| {
                                if record {
                                    let mut trial = BTreeMap::new();
                                    trial.insert("attempt".to_owned(), info.name.clone());
                                    trial.insert("model".to_owned(), info.spec.to_owned());
                                    trial.insert("seed".to_owned(), setup.seed.to_string());
                                    trial.insert("task".to_owned(), info.task.to_owned());
                                    trial.insert("goals".to_owned(), info.goals.to_owned());
                                    simrecord::run_recorded(setup, info, dir, graph, trial)
                                } else {
                                    study::simulate::run_attempt(setup)
                                }
                            },
                        )
                    })
                    .collect()
            })
        }
        Run::Live(prefix) => {
            let mut results = Vec::new();
            for (i, dir) in dirs.iter().enumerate() {
                let runner = simlive::LiveSim::new(graph, prefix, &dir.join("live"))
                    .map_err(study::StudyError::from)?;
                let r = study::simulate::simulate_participant_with(
                    &s,
                    &sim,
                    Participant(i as u32 + 1),
                    seed,
                    dir,
                    only,
                    &|| bar.inc(1),
                    &transport::signals::stop_requested,
                    &|setup, info| runner.attempt(setup, info),
                );
                let failed = r.is_err();
                results.push(r);
                if failed {
                    break;
                }
            }
            results
        }
    };
    bar.finish_and_clear();
    let mut rows = 0;
    for r in results {
        rows += r?.len();
    }
    let wall = started.elapsed().as_secs_f64();
    let data = study::report::Data::load(&dirs)?;
    let r = study::report::analyse(&data, None)?;
    let report = out.join("report");
    study::report::write(&r, &report)?;
    println!(
        "{participants} simulated participants ({} operator), {rows} attempts in {wall:.1} s \
         (seed {seed}); data in {}/P*, report in {}",
        s.file.simulation.operator.name(),
        out.display(),
        report.display()
    );
    for t in &r.successes {
        println!(
            "  {:<16} {:<16} {:>3} / {} successes",
            t.task, t.condition, t.successes, t.attempts
        );
    }
    println!("summary: {}", report.join("summary.md").display());
    Ok(())
}

/// `scl eval capability`: whether a map can do one of the paper's tasks before a person sits
/// down ([`study::capability`]).
#[derive(clap::Args, Debug, Clone)]
pub struct CapabilityArgs {
    /// The model file (`*.safetensors`), a built-in map (`modeswitch`), or
    /// `nearest-demonstration` with `--operator follower`: the task's training
    /// demonstrations themselves as the map (the best any map learned from them could do
    /// along them), so a failure there is the demonstrations' or the loop's (safety, the
    /// hand), not the learned map's.
    pub model: String,
    /// The task: table-cleaning, pick-and-place or pouring.
    #[arg(long)]
    pub task: String,
    /// `expert` (plans with the map from the study's start: the success rate) or `follower`
    /// (reproduces each of the task's training demonstrations from its start, in its scene:
    /// the share tracked to the end); `greedy` and `practiced` run from the start too.
    #[arg(long, default_value = "expert")]
    pub operator: String,
    /// Attempts from the study's start, each with its own seed (the follower makes one per
    /// training demonstration instead).
    #[arg(long, default_value = "10")]
    pub seeds: u64,
    /// A study file whose `[simulation]` section sets the operator's hand and planner
    /// (default: the defaults in docs/simulated-participants.md).
    #[arg(long, value_name = "FILE")]
    pub study: Option<PathBuf>,
    /// Attempts run at once (default: the cores available).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Print one JSON object (task, operator, successes, attempts, rate, each attempt).
    #[arg(long)]
    pub json: bool,
}

/// Runs `scl eval capability` on `robot` with `graph`'s safety configuration and period;
/// prints the result.
pub fn capability(
    robot: &'static kinematics::RobotProfile,
    graph: &scl_config::GraphConfig,
    args: &CapabilityArgs,
) -> Result<study::capability::Capability, StudyRunError> {
    let task = learning::tasks::Task::from_name(&args.task)
        .map_err(|e| StudyRunError::Graph(format!("--task: {e}")))?;
    let operator = study::operator::OperatorKind::from_name(&args.operator).ok_or_else(|| {
        StudyRunError::Graph(format!(
            "--operator: no operator `{}`; the operators: {}",
            args.operator,
            study::operator::OperatorKind::NAMES.join(", ")
        ))
    })?;
    if args.seeds == 0 {
        return Err(StudyRunError::Graph("--seeds 0: run at least one".into()));
    }
    let mut params = match &args.study {
        Some(path) => Study::load(path, robot)?.file.simulation,
        None => study::simulate::SimParams::default(),
    };
    params.operator = operator;
    let sim = study::simulate::Loop {
        robot,
        safety: graph.safety.clone(),
        period_s: graph.period_s(),
    };
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(0)
    } else {
        indicatif::ProgressBar::hidden()
    };
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{elapsed_precise} [{bar:40}] {pos}/{len} attempts, {eta} left",
    ) {
        bar.set_style(style.progress_chars("=> "));
    }
    let progress = || bar.inc(1);
    let check = study::capability::CapabilityCheck {
        sim: &sim,
        spec: &args.model,
        task,
        params: &params,
        seeds: args.seeds,
        progress: &progress,
    };
    bar.set_length(check.attempts());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.jobs.unwrap_or(0))
        .build()
        .map_err(|e| StudyRunError::Graph(format!("--jobs: {e}")))?;
    let c = pool
        .install(|| check.run())
        .map_err(study::StudyError::from)?;
    bar.finish_and_clear();
    if args.json {
        let attempts: Vec<_> = c
            .attempts
            .iter()
            .map(|a| {
                serde_json::json!({
                    "name": a.name,
                    "outcome": a.result.outcome.name(),
                    "completion_pct": a.result.completion_pct,
                    "duration_s": a.result.duration_s,
                    "mode_switches": a.result.mode_switches,
                    "followed_pct": a.followed_pct,
                })
            })
            .collect();
        println!(
            "{}",
            serde_json::json!({
                "model": args.model,
                "task": task.name(),
                "operator": operator.name(),
                "successes": c.successes(),
                "attempts": c.attempts.len(),
                "rate": c.rate(),
                "each": attempts,
            })
        );
    } else {
        for a in &c.attempts {
            let followed = a
                .followed_pct
                .map(|f| format!(", followed {f:.0} % of it"))
                .unwrap_or_default();
            let d = a.result.diagnosis.as_ref();
            let failed = a.result.outcome != study::data::Outcome::Success;
            let stuck = d
                .filter(|_| failed)
                .and_then(|d| Some((d.next.as_ref()?, d.closest_m?)))
                .map(|(next, m)| format!("; {next} never done, closest {:.1} cm", m * 100.0))
                .unwrap_or_default();
            let safety = d
                .map(|d| d.safety_summary())
                .filter(|s| !s.is_empty())
                .map(|s| format!("{stuck}; safety acted (ticks): {s}"))
                .unwrap_or(stuck);
            println!(
                "  {:<14} {:<8} {:>5.1} s, {:>3.0} % of the subgoals{followed}{safety}",
                a.name,
                a.result.outcome.name(),
                a.result.duration_s,
                a.result.completion_pct
            );
        }
        println!("{}", c.summary());
    }
    Ok(c)
}
