//! `scl record`: a read-only observer that writes every message of a graph to an MCAP file
//! ([`recording`] is the format), and `scl record --recover`.
//!
//! Two threads, so that a slow disk never reaches the graph:
//!
//! * the subscriber thread (the process's main thread) wakes on each robot state, drains
//!   every topic and hands each message to the writer with a non-blocking `try_send` on a
//!   bounded crossbeam channel. A full channel drops the message and counts it. It also
//!   publishes the recorder's heartbeat (`NodeRole::Recorder`: `handled` = messages received,
//!   `faults` = messages dropped), which is how `scl up` knows it is listening.
//! * the writer thread (lower CPU priority) encodes JSON, writes chunks, and closes a chunk
//!   once a second, so a crash loses at most the last second. After a write error (a full
//!   disk) it stops writing and counts what it is handed as dropped.
//!
//! Shared-memory topics never block their publishers (safe overflow), and the recorder
//! publishes nothing but its heartbeat, so the control loop does not wait for it. Counts per
//! topic (received, written, dropped, lost robot states) are printed at the end and written
//! to the file's `scl.recording.end` metadata record.
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

/// Why the recorder stopped or could not start, each with the message a user sees.
#[derive(Debug, thiserror::Error)]
pub enum RecorderError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// A recording could not be written, read or recovered.
    #[error(transparent)]
    Record(#[from] recording::RecordError),
    /// The 3D view could not be built, or a recording not converted.
    #[error(transparent)]
    Viz(#[from] viz::VizError),
    /// The writer thread could not be started.
    #[error("cannot start the recorder's writer thread: {0}")]
    Thread(#[source] std::io::Error),
    /// `--json`: the report could not be encoded.
    #[error("cannot encode the report: {0}")]
    Report(#[source] serde_json::Error),
    /// `--remote`: the gateway could not be reached or did not answer (its clocks), so
    /// nothing was recorded.
    #[error(transparent)]
    Remote(#[from] scl_net::observe::ObserveError),
    /// `--remote`: a subscription to the gateway's topics could not be declared.
    #[error(transparent)]
    Session(#[from] scl_net::SessionError),
}

use graph_client::observe::Observers;
use graph_client::process;

mod remote;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use ipc_types::{NO_TICK, NodeRole, NodeStatus, Prefix, time::now_ns};
use node_rt::node::Heartbeat;
use serde::Serialize;
use transport::{Graph, TopicSubscriber};

use recording::{self, LogClock, LogWriter, Payload, RecordError, Topic};
use scl_net::observe::RemoteGraph;
use transport::signals;

/// How often the writer closes a chunk: the most a crash of the recorder loses.
pub const FLUSH_EVERY: Duration = Duration::from_secs(1);

/// A chunk is also closed once this much JSON is pending.
const FLUSH_BYTES: usize = 4 << 20;

/// Default capacity of the hand-off to the writer thread (messages): at the mock graph's
/// ~300 messages per second, about 13 s of a stalled disk before anything is dropped.
pub const DEFAULT_QUEUE: usize = 4096;

/// `scl record`'s arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    /// The MCAP file to write (never overwritten); with `--recover`, the recovered file.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Topics to record, comma-separated (default: every topic): joystick, robot_state,
    /// mapper_command, safe_command, status, safety_control, estop.
    #[arg(long, value_name = "TOPICS", value_delimiter = ',')]
    pub topics: Vec<String>,
    /// Rewrite the readable part of BROKEN (a recording cut by a crash) as a finished
    /// recording in --out, instead of recording.
    #[arg(long, value_name = "BROKEN")]
    pub recover: Option<PathBuf>,
    /// Copy OLD (a recording made before the 3D view was recorded) into --out with the 3D
    /// channels added (/tf, /scl/arm, /scl/map, /scl/world, /scl/tick), computed from its robot
    /// states with the model and configuration it embeds; OLD is never changed.
    #[arg(long, value_name = "OLD", conflicts_with = "recover")]
    pub convert: Option<PathBuf>,
    /// Messages the hand-off to the writer thread holds; beyond that, messages are dropped
    /// and counted, never waited for.
    #[arg(long, default_value_t = DEFAULT_QUEUE, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub queue: usize,
    /// A KEY=VALUE pair for the recording's `scl.trial` metadata record, written at the
    /// start (repeatable; `scl study run` names the participant, task, condition, attempt).
    #[arg(long = "meta", value_name = "KEY=VALUE", value_parser = parse_key_value)]
    pub meta: Vec<(String, String)>,
    /// A JSON object of strings read when the recording stops and written as its
    /// `scl.trial.outcome` metadata record (`scl study run` puts the attempt's outcome there
    /// before it stops the recorder); absent file: no record.
    #[arg(long, value_name = "FILE")]
    pub meta_at_stop: Option<PathBuf>,
    /// Print the report as one JSON object on stdout at the end.
    #[arg(long)]
    pub json: bool,
    /// Record a graph on another machine through its Zenoh gateway (`[network]` there): its
    /// endpoint, e.g. `tcp/192.0.2.10:7447`. The recording holds what a local one holds:
    /// every topic, and what each mapper and safety process runs (configuration, model
    /// files, every swap's model), as the gateway captured them; `scl replay` replays it.
    #[arg(long, value_name = "ENDPOINT", conflicts_with_all = ["recover", "convert"])]
    pub remote: Option<String>,
    /// With `--remote`: a credentials file (`user:password`, mode 0600; default `[network]
    /// credentials`, if any), for a gateway that requires authentication.
    #[arg(long, value_name = "FILE", requires = "remote")]
    pub credentials: Option<PathBuf>,
}

/// What a recording run is asked to do.
#[derive(Debug, Clone)]
pub struct RecordOptions {
    /// The file to write.
    pub out: PathBuf,
    /// The topics to record.
    pub topics: Vec<Topic>,
    /// Capacity of the hand-off to the writer thread.
    pub queue: usize,
    /// How often a chunk is closed.
    pub flush_every: Duration,
    /// The `scl.trial` metadata record written at the start (none if empty).
    pub trial: BTreeMap<String, String>,
    /// A JSON object of strings read at the stop, written as `scl.trial.outcome`.
    pub meta_at_stop: Option<PathBuf>,
    /// Record a graph on another machine through its gateway, not this machine's.
    pub remote: Option<RemoteGraph>,
}

/// The metadata record of a recording's trial (`scl record --meta`).
pub const TRIAL_METADATA: &str = "scl.trial";
/// The metadata record of a trial's outcome (`scl record --meta-at-stop`).
pub const TRIAL_OUTCOME_METADATA: &str = "scl.trial.outcome";

/// Counters shared by the two threads, per topic (indexed by [`Topic::index`]).
#[derive(Debug, Default)]
pub struct Tally {
    received: [AtomicU64; Topic::COUNT],
    queue_dropped: [AtomicU64; Topic::COUNT],
    written: [AtomicU64; Topic::COUNT],
    write_dropped: [AtomicU64; Topic::COUNT],
    json_bytes: AtomicU64,
    state_gaps: AtomicU64,
    /// Messages of the 3D channels in the file ([`View`]).
    view_written: AtomicU64,
}

fn load(a: &[AtomicU64; Topic::COUNT]) -> [u64; Topic::COUNT] {
    std::array::from_fn(|i| a[i].load(Ordering::SeqCst))
}

impl Tally {
    /// Messages dropped so far, for any reason.
    pub fn dropped(&self) -> u64 {
        load(&self.queue_dropped).iter().sum::<u64>()
            + load(&self.write_dropped).iter().sum::<u64>()
    }

    /// Messages received so far.
    pub fn received(&self) -> u64 {
        load(&self.received).iter().sum()
    }

    /// The counts per topic for `topics`.
    pub fn counts(&self, topics: &[Topic]) -> Vec<TopicCounts> {
        let (r, q, w, d) = (
            load(&self.received),
            load(&self.queue_dropped),
            load(&self.written),
            load(&self.write_dropped),
        );
        topics
            .iter()
            .map(|t| {
                let i = t.index();
                TopicCounts {
                    topic: t.name().to_owned(),
                    received: r[i],
                    written: w[i],
                    dropped: q[i] + d[i],
                }
            })
            .collect()
    }

    /// Messages of the 3D channels in the file.
    pub fn view_written(&self) -> u64 {
        self.view_written.load(Ordering::SeqCst)
    }

    /// Every message in the file: the graph's `topics` and the 3D channels (what the report
    /// calls written).
    pub fn written(&self, topics: &[Topic]) -> u64 {
        self.counts(topics).iter().map(|c| c.written).sum::<u64>() + self.view_written()
    }

    fn end_metadata(
        &self,
        topics: &[Topic],
        pending: &[u64; Topic::COUNT],
        pending_view: u64,
    ) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        let mut dropped = 0;
        for mut c in self.counts(topics) {
            if let Some(t) = Topic::from_name(&c.topic) {
                c.written += pending[t.index()];
            }
            m.insert(format!("received.{}", c.topic), c.received.to_string());
            m.insert(format!("written.{}", c.topic), c.written.to_string());
            m.insert(format!("dropped.{}", c.topic), c.dropped.to_string());
            dropped += c.dropped;
        }
        m.insert("dropped_total".into(), dropped.to_string());
        m.insert(
            "written.3d".into(),
            (self.view_written() + pending_view).to_string(),
        );
        m.insert(
            "robot_state_gaps".into(),
            self.state_gaps.load(Ordering::SeqCst).to_string(),
        );
        m.insert("stopped_monotonic_ns".into(), now_ns().to_string());
        m
    }
}

/// Counts of one topic.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TopicCounts {
    /// Topic name.
    pub topic: String,
    /// Messages received from shared memory.
    pub received: u64,
    /// Messages in the file.
    pub written: u64,
    /// Messages dropped (full hand-off, or a write error).
    pub dropped: u64,
}

/// The end-of-recording report.
#[derive(Debug, Clone, Serialize)]
pub struct RecordReport {
    /// The file written.
    pub file: String,
    /// How long the recorder ran (s).
    pub duration_s: f64,
    /// Counts per topic.
    pub topics: Vec<TopicCounts>,
    /// Messages received.
    pub received: u64,
    /// Messages written: the graph's topics and the 3D channels, every message in the file.
    pub written: u64,
    /// Of those, the messages of the 3D channels (`/tf`, `/scl/*`).
    pub view_written: u64,
    /// Messages dropped.
    pub dropped: u64,
    /// Robot states missing between consecutive ticks received (lost before the recorder saw
    /// them, e.g. a restarted bridge's gap).
    pub robot_state_gaps: u64,
    /// Size of the file (bytes).
    pub file_bytes: u64,
    /// The first write error, if writing failed (the file then ends at its last good chunk).
    pub write_error: Option<String>,
}

/// The subscriber side of the hand-off: never blocks.
pub struct Producer {
    tx: Sender<Payload>,
    tally: Arc<Tally>,
    last_tick: Option<u64>,
    /// Processes seen for the first time, to the writer thread (rare: unbounded).
    procs: Sender<ProcessItem>,
    /// `--remote`: processes seen for the first time, to the thread that asks the gateway
    /// what they run (rare: unbounded); `None`: read from this machine's `/proc`.
    remote_procs: Option<Sender<(NodeStatus, NodeRole)>>,
    /// Pids of the mapper and safety processes seen so far.
    seen: process::NewProcesses,
    /// Metadata records to the writer thread (rare: unbounded).
    metas: Sender<recording::Metadata>,
    /// The processes' own log records to the writer thread (`/scl/log`); a full hand-off
    /// drops them.
    logs: Sender<ipc_types::LogRecord>,
}

impl Producer {
    /// Hands `p` to the writer, or drops and counts it if the writer is behind (or gone).
    /// Returns whether it was handed over.
    pub fn offer(&mut self, p: Payload) -> bool {
        let i = p.topic().index();
        self.tally.received[i].fetch_add(1, Ordering::SeqCst);
        if let Payload::RobotState(s) = &p {
            if let Some(last) = self.last_tick
                && s.tick > last + 1
            {
                self.tally
                    .state_gaps
                    .fetch_add(s.tick - last - 1, Ordering::SeqCst);
            }
            self.last_tick = Some(s.tick);
        }
        match self.tx.try_send(p) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.tally.queue_dropped[i].fetch_add(1, Ordering::SeqCst);
                false
            }
        }
    }

    /// Hands a process's own log record to the writer (a `/scl/log` line of the 3D view);
    /// never waits: a full hand-off drops it.
    pub fn log(&mut self, r: &ipc_types::LogRecord) {
        let _ = self.logs.try_send(*r);
    }

    /// Hands a metadata record to the writer (written before the file is finished).
    pub fn metadata(&mut self, m: recording::Metadata) {
        let _ = self.metas.send(m);
    }

    /// The newest robot tick offered.
    pub fn last_tick(&self) -> Option<u64> {
        self.last_tick
    }

    /// Notes the process a heartbeat comes from: a mapper or safety process seen for the
    /// first time has its command line read now and what it runs embedded by the writer
    /// ([`process::capture`]).
    pub fn note_process(&mut self, st: &NodeStatus) {
        if let Some(role) = self.seen.first(st) {
            match &self.remote_procs {
                Some(tx) => {
                    let _ = tx.send((*st, role));
                }
                None => {
                    let _ = self
                        .procs
                        .send(ProcessItem::Seen(process::ProcessSeen::of(st, role)));
                }
            }
        }
    }
}

/// What the writer thread learns of a process, to embed in the recording.
#[derive(Debug)]
pub enum ProcessItem {
    /// A process of this machine: captured here ([`process::capture`]).
    Seen(process::ProcessSeen),
    /// A remote process, as its gateway captured it.
    Captured(Box<process::Captured>),
    /// A remote process whose capture could not be had: a record naming why.
    Missing {
        /// Its pid.
        pid: u32,
        /// Its role.
        role: NodeRole,
        /// Its heartbeat's time.
        t_ns: u64,
        /// Why.
        error: String,
    },
}

/// How the writer thread ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WriterOutcome {
    /// The first write error, if any.
    pub error: Option<String>,
}

/// The 3D view written beside the graph's topics ([`viz`]): Foxglove's frame transforms and
/// scene updates and the `/scl/tick` numbers, computed on the writer thread from each message
/// as it is written, with the robot, scene and models the graph's processes run.
pub struct View {
    viz: viz::Viz,
    ids: BTreeMap<viz::VizTopic, u16>,
    seq: BTreeMap<viz::VizTopic, u32>,
    out: Vec<viz::VizMessage>,
    errors: u64,
}

impl View {
    /// Adds the 3D channels to `w`; the view starts with the default robot and scene until
    /// the safety process is seen.
    pub fn add_to<W: Write>(
        w: &mut LogWriter<W>,
        metadata: &BTreeMap<String, String>,
    ) -> Result<Self, RecorderError> {
        let viz = viz::Viz::new(&scl_config::GraphConfig::default())?;
        let mut ids = BTreeMap::new();
        for t in viz::VizTopic::ALL {
            let id = w.add_channel(t.topic(), Some(&t.schema()), t.message_encoding(), metadata)?;
            ids.insert(t, id);
        }
        Ok(Self {
            viz,
            ids,
            seq: BTreeMap::new(),
            out: Vec::new(),
            errors: 0,
        })
    }

    /// Writes what `p` adds to the view; returns the messages and bytes written.
    fn write<W: Write>(
        &mut self,
        w: &mut LogWriter<W>,
        p: &Payload,
    ) -> Result<(u64, usize), RecordError> {
        self.out.clear();
        if let Err(e) = self.viz.observe(p, &mut self.out) {
            self.errors += 1;
            if self.errors == 1 {
                tracing::warn!("the 3D view: {e}");
            }
        }
        let mut n = 0;
        let clock = w.clock();
        for m in &self.out {
            let s = self.seq.entry(m.topic).or_default();
            *s = s.wrapping_add(1);
            let id = self.ids.get(&m.topic).copied().unwrap_or_default();
            w.write_raw(id, *s, clock.log_time(m.t_ns), m.t_ns, &m.data)?;
            n += m.data.len();
        }
        Ok((self.out.len() as u64, n))
    }

    /// Writes the `/scl/log` line of a process's own log record; returns the messages and
    /// bytes written.
    fn write_log<W: Write>(
        &mut self,
        w: &mut LogWriter<W>,
        r: &ipc_types::LogRecord,
    ) -> Result<(u64, usize), RecordError> {
        self.out.clear();
        if self.viz.observe_log(r, &mut self.out).is_err() {
            return Ok((0, 0));
        }
        let mut n = 0;
        let clock = w.clock();
        for m in &self.out {
            let s = self.seq.entry(m.topic).or_default();
            *s = s.wrapping_add(1);
            let id = self.ids.get(&m.topic).copied().unwrap_or_default();
            w.write_raw(id, *s, clock.log_time(m.t_ns), m.t_ns, &m.data)?;
            n += m.data.len();
        }
        Ok((self.out.len() as u64, n))
    }

    /// Takes what a remote mapper or safety process runs, as its gateway captured it.
    fn captured(&mut self, c: &process::Captured) {
        let mut notes = Vec::new();
        viz::convert::apply_process_record(
            &mut self.viz,
            &c.entries,
            &c.attachment_map(),
            &mut notes,
        );
        for n in notes {
            tracing::warn!("the 3D view: {n}");
        }
    }

    /// Takes what a newly seen mapper or safety process runs.
    fn process(&mut self, p: &process::ProcessSeen) {
        let (cfg, model) = process::runs(p);
        if let Err(e) = self
            .viz
            .take_process(p.role, p.mapper_id, cfg.as_ref(), model.as_deref())
        {
            tracing::warn!("{e}");
        }
    }
}

/// Starts the writer thread on `writer` with a hand-off of `queue` messages; returns the
/// producer end and the thread. The thread ends (finishing the file) once the producer is
/// dropped and the hand-off is drained.
pub fn start_pipeline<W: Write + Send + 'static>(
    writer: LogWriter<W>,
    topics: Vec<Topic>,
    queue: usize,
    flush_every: Duration,
    view: Option<View>,
) -> std::io::Result<(Producer, Arc<Tally>, JoinHandle<WriterOutcome>)> {
    let (tx, rx) = crossbeam_channel::bounded(queue.max(1));
    let (procs, procs_rx) = crossbeam_channel::unbounded();
    let (metas, metas_rx) = crossbeam_channel::unbounded();
    let (logs, logs_rx) = crossbeam_channel::bounded(256);
    let tally = Arc::new(Tally::default());
    let t2 = tally.clone();
    let handle = std::thread::Builder::new()
        .name("mcap-writer".into())
        .spawn(move || {
            // The writer thread yields the CPU to everything else in the process and on the
            // machine.
            node_rt::rt::lower_priority();
            let side = SideChannels {
                procs: procs_rx,
                metas: metas_rx,
                logs: logs_rx,
            };
            write_loop(writer, view, rx, &side, &t2, &topics, flush_every)
        })?;
    Ok((
        Producer {
            tx,
            tally: tally.clone(),
            last_tick: None,
            procs,
            remote_procs: None,
            seen: process::NewProcesses::default(),
            metas,
            logs,
        },
        tally,
        handle,
    ))
}

/// The writer thread's rare inputs beside the messages.
struct SideChannels {
    procs: Receiver<ProcessItem>,
    metas: Receiver<recording::Metadata>,
    logs: Receiver<ipc_types::LogRecord>,
}

fn write_loop<W: Write>(
    w: LogWriter<W>,
    view: Option<View>,
    rx: Receiver<Payload>,
    side: &SideChannels,
    tally: &Tally,
    topics: &[Topic],
    flush_every: Duration,
) -> WriterOutcome {
    let mut out = ChunkWriter {
        w,
        view,
        tally,
        pending: [0u64; Topic::COUNT],
        pending_view: 0,
        pending_bytes: 0,
        error: None,
        last_flush: Instant::now(),
    };
    loop {
        let wait = flush_every.saturating_sub(out.last_flush.elapsed());
        match rx.recv_timeout(wait) {
            Ok(p) => out.write(&p),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
        out.take_processes_and_metadata(side);
        out.take_logs(side);
        out.flush_if_due(flush_every);
    }
    // What was handed over while stopping.
    out.take_processes_and_metadata(side);
    out.finish(topics)
}

/// A write error: logged once (the first is kept in `error`); the open chunk's messages
/// (`pending`) are counted dropped.
fn chunk_failed(
    error: &mut Option<String>,
    pending: &mut [u64; Topic::COUNT],
    tally: &Tally,
    e: RecordError,
) {
    if error.is_none() {
        tracing::error!(
            "{e}; the recording ends at its last complete chunk, later messages are dropped"
        );
        *error = Some(e.to_string());
    }
    for (i, n) in pending.iter_mut().enumerate() {
        tally.write_dropped[i].fetch_add(*n, Ordering::SeqCst);
        *n = 0;
    }
}

/// The recording's writer with what its open chunk holds: messages (per topic) and 3D
/// messages counted once the chunk reaches the sink, and the first write error, after
/// which everything is dropped (and counted so).
struct ChunkWriter<'a, W: Write> {
    w: LogWriter<W>,
    view: Option<View>,
    tally: &'a Tally,
    /// Messages in the open chunk: written once the chunk reaches the sink.
    pending: [u64; Topic::COUNT],
    /// Messages of the 3D channels in the open chunk.
    pending_view: u64,
    pending_bytes: usize,
    error: Option<String>,
    last_flush: Instant,
}

impl<W: Write> ChunkWriter<'_, W> {
    /// A write error: logged once; the open chunk's messages are counted dropped.
    fn fail(&mut self, e: RecordError) {
        chunk_failed(&mut self.error, &mut self.pending, self.tally, e);
    }

    /// Writes a message (and its 3D view), or counts it dropped after an error.
    fn write(&mut self, p: &Payload) {
        let i = p.topic().index();
        if self.error.is_some() {
            self.tally.write_dropped[i].fetch_add(1, Ordering::SeqCst);
            return;
        }
        let w = &mut self.w;
        let written = w.write(p).and_then(|n| match self.view.as_mut() {
            Some(v) => v.write(w, p).map(|(k, m)| (k, n + m)),
            None => Ok((0, n)),
        });
        match written {
            Ok((k, n)) => {
                self.pending[i] += 1;
                self.pending_view += k;
                self.pending_bytes += n;
                self.tally.json_bytes.fetch_add(n as u64, Ordering::SeqCst);
            }
            Err(e) => {
                self.tally.write_dropped[i].fetch_add(1, Ordering::SeqCst);
                self.fail(e);
            }
        }
    }

    /// Writes the processes and the metadata handed over on the side channels.
    fn take_processes_and_metadata(&mut self, side: &SideChannels) {
        while let Ok(p) = side.procs.try_recv() {
            if self.error.is_none()
                && let Err(e) = write_process(&mut self.w, self.view.as_mut(), &p)
            {
                self.fail(e);
            }
        }
        while let Ok(m) = side.metas.try_recv() {
            if self.error.is_none()
                && let Err(e) = self.w.write_metadata(&m)
            {
                self.fail(e);
            }
        }
    }

    /// Writes the log lines handed over to the 3D view (if any).
    fn take_logs(&mut self, side: &SideChannels) {
        while let Ok(r) = side.logs.try_recv() {
            if self.error.is_none()
                && let Some(v) = self.view.as_mut()
            {
                match v.write_log(&mut self.w, &r) {
                    Ok((k, n)) => {
                        self.pending_view += k;
                        self.pending_bytes += n;
                    }
                    Err(e) => self.fail(e),
                }
            }
        }
    }

    /// Ends the open chunk when `flush_every` has passed or it holds enough bytes; its
    /// messages count as written.
    fn flush_if_due(&mut self, flush_every: Duration) {
        if self.error.is_none()
            && (self.last_flush.elapsed() >= flush_every || self.pending_bytes >= FLUSH_BYTES)
        {
            match self.w.flush() {
                Ok(()) => {
                    for (i, n) in self.pending.iter_mut().enumerate() {
                        self.tally.written[i].fetch_add(*n, Ordering::SeqCst);
                        *n = 0;
                    }
                    self.tally
                        .view_written
                        .fetch_add(self.pending_view, Ordering::SeqCst);
                }
                Err(e) => self.fail(e),
            }
            self.pending_view = 0;
            self.pending_bytes = 0;
            self.last_flush = Instant::now();
        }
    }

    /// Ends the recording with the end metadata (unless a write failed); the outcome.
    fn finish(mut self, topics: &[Topic]) -> WriterOutcome {
        if self.error.is_none() {
            let end = self
                .tally
                .end_metadata(topics, &self.pending, self.pending_view);
            match self
                .w
                .finish(Some(recording::metadata(recording::END_METADATA, end)))
            {
                Ok(_) => {
                    for (i, n) in self.pending.iter_mut().enumerate() {
                        self.tally.written[i].fetch_add(*n, Ordering::SeqCst);
                    }
                    self.tally
                        .view_written
                        .fetch_add(self.pending_view, Ordering::SeqCst);
                }
                Err(e) => chunk_failed(&mut self.error, &mut self.pending, self.tally, e),
            }
        }
        WriterOutcome { error: self.error }
    }
}

/// Writes what process item `p` says into `w` and tells the 3D view.
fn write_process<W: Write>(
    w: &mut LogWriter<W>,
    view: Option<&mut View>,
    p: &ProcessItem,
) -> Result<(), RecordError> {
    match p {
        ProcessItem::Seen(p) => {
            process::capture(w, p)?;
            if let Some(v) = view {
                v.process(p);
            }
        }
        ProcessItem::Captured(c) => {
            c.write_to(w)?;
            if let Some(v) = view {
                v.captured(c);
            }
        }
        ProcessItem::Missing {
            pid,
            role,
            t_ns,
            error,
        } => {
            tracing::warn!(pid, role = role.name(), "{error}");
            let mut m = BTreeMap::new();
            m.insert("role".to_owned(), role.name().to_owned());
            m.insert("pid".to_owned(), pid.to_string());
            m.insert("t_ns".to_owned(), t_ns.to_string());
            m.insert("error".to_owned(), error.clone());
            w.write_metadata(&recording::metadata(recording::PROCESS_METADATA, m))?;
        }
    }
    Ok(())
}

/// The subscriptions of the recorder.
struct Subscriptions {
    states: TopicSubscriber<ipc_types::RobotState>,
    record_states: bool,
    /// The recorded topics but the robot states.
    others: Observers,
    /// The processes' own log records (to the 3D view's `/scl/log`).
    logs: TopicSubscriber<ipc_types::LogRecord>,
}

impl Subscriptions {
    fn open(graph: &Graph, topics: &[Topic]) -> Result<Self, RecorderError> {
        let others: Vec<Topic> = topics
            .iter()
            .copied()
            .filter(|&t| t != Topic::RobotState)
            .collect();
        Ok(Self {
            // Always open: its event is the recorder's wake-up.
            states: graph.robot_state_subscriber(true)?,
            record_states: topics.contains(&Topic::RobotState),
            others: Observers::open(graph, &others)?,
            logs: graph.log_subscriber()?,
        })
    }

    /// Hands everything buffered to `p`, robot states first (they are the clock).
    fn drain(&self, p: &mut Producer) -> Result<(), RecorderError> {
        let record_states = self.record_states;
        self.states.drain(|m| {
            if record_states {
                p.offer(Payload::RobotState(*m));
            } else {
                p.last_tick = Some(m.tick);
            }
        })?;
        self.others.drain(|m| {
            if let Payload::Status(s) = &m {
                p.note_process(s);
            }
            p.offer(m);
        })?;
        self.logs.drain(|m| p.log(m))?;
        Ok(())
    }
}

/// The start record; `mono` and `wall` are the clocks read together ([`LogClock::wall_now`]).
fn start_metadata(
    prefix: &Prefix,
    topics: &[Topic],
    mono: u64,
    wall: u64,
) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    m.insert("prefix".into(), prefix.to_string());
    m.insert(
        "topics".into(),
        topics
            .iter()
            .map(|t| t.name())
            .collect::<Vec<_>>()
            .join(","),
    );
    m.insert(
        "clock".into(),
        "publish_time = the message's t_ns (CLOCK_MONOTONIC ns); log_time = the same instant on the wall clock (Unix ns: t_ns - started_monotonic_ns + started_unix_ns)".into(),
    );
    // Taken together: unix_ns(t) = t - started_monotonic_ns + started_unix_ns.
    m.insert("started_monotonic_ns".into(), mono.to_string());
    m.insert("started_unix_ns".into(), wall.to_string());
    m.insert("recorder_pid".into(), std::process::id().to_string());
    m.insert("scl_version".into(), env!("CARGO_PKG_VERSION").into());
    m
}

/// The recorder, set up and listening.
struct Running {
    subs: Subscriptions,
    heartbeat: transport::TopicPublisher<NodeStatus>,
    producer: Producer,
    tally: Arc<Tally>,
    writer: JoinHandle<WriterOutcome>,
    // Declared last: dropped after its ports.
    _graph: Graph,
}

/// Creates the file and writes its start: the start record (with the clocks `mono` and
/// `wall` read together, and `extra` entries), the trial record, the channels and the 3D
/// view's (on disk at once).
fn create(
    prefix: &Prefix,
    opts: &RecordOptions,
    (mono, wall): (u64, u64),
    extra: BTreeMap<String, String>,
) -> Result<(LogWriter<std::io::BufWriter<std::fs::File>>, Option<View>), RecorderError> {
    let file = recording::create_new(&opts.out)?;
    let mut start = start_metadata(prefix, &opts.topics, mono, wall);
    start.extend(extra);
    let mut w = LogWriter::new(
        std::io::BufWriter::new(file),
        &opts.out,
        Some(recording::metadata(recording::START_METADATA, start)),
    )?;
    w.set_clock(LogClock::from_pair(mono, wall));
    if !opts.trial.is_empty() {
        w.write_metadata(&recording::metadata(TRIAL_METADATA, opts.trial.clone()))?;
    }
    let mut channel_meta = BTreeMap::new();
    channel_meta.insert("prefix".to_owned(), prefix.to_string());
    for t in &opts.topics {
        w.add_topic(*t, &channel_meta)?;
    }
    // The 3D view needs the robot states it is drawn from.
    let view = if opts.topics.contains(&Topic::RobotState) {
        Some(View::add_to(&mut w, &channel_meta)?)
    } else {
        None
    };
    // The channel definitions reach the disk at once: a crash keeps them.
    w.flush()?;
    Ok((w, view))
}

/// Creates the file (channels on disk at once), joins the graph, subscribes and starts the
/// writer thread.
fn start(prefix: &Prefix, opts: &RecordOptions) -> Result<Running, RecorderError> {
    let (_, mono, wall) = LogClock::wall_now();
    let (w, view) = create(prefix, opts, (mono, wall), BTreeMap::new())?;
    let graph = Graph::join(prefix, "recorder")?;
    let subs = Subscriptions::open(&graph, &opts.topics)?;
    let heartbeat = graph.status_publisher()?;
    let (producer, tally, writer) =
        start_pipeline(w, opts.topics.clone(), opts.queue, opts.flush_every, view)
            .map_err(RecorderError::Thread)?;
    Ok(Running {
        subs,
        heartbeat,
        producer,
        tally,
        writer,
        _graph: graph,
    })
}

/// Nothing was recorded: leave no file that would block the next attempt (an existing file
/// is never ours to remove).
fn remove_unrecorded(out: &Path, e: &RecorderError) {
    if !matches!(e, RecorderError::Record(RecordError::Exists(_))) {
        let _ = std::fs::remove_file(out);
    }
}

/// The `--meta-at-stop` record, handed to the writer.
fn outcome_at_stop(opts: &RecordOptions, producer: &mut Producer) {
    if let Some(path) = &opts.meta_at_stop {
        match read_meta_file(path) {
            Ok(Some(m)) => producer.metadata(recording::metadata(TRIAL_OUTCOME_METADATA, m)),
            Ok(None) => {}
            Err(e) => tracing::warn!("--meta-at-stop {}: {e}; no outcome record", path.display()),
        }
    }
}

/// The report of a finished run.
fn report(
    opts: &RecordOptions,
    started: Instant,
    tally: &Tally,
    outcome: WriterOutcome,
) -> RecordReport {
    let topics = tally.counts(&opts.topics);
    let view_written = tally.view_written();
    RecordReport {
        file: opts.out.display().to_string(),
        duration_s: started.elapsed().as_secs_f64(),
        received: topics.iter().map(|c| c.received).sum(),
        written: tally.written(&opts.topics),
        view_written,
        dropped: topics.iter().map(|c| c.dropped).sum(),
        topics,
        robot_state_gaps: tally.state_gaps.load(Ordering::SeqCst),
        file_bytes: std::fs::metadata(&opts.out).map_or(0, |m| m.len()),
        write_error: outcome.error,
    }
}

/// Records graph `prefix` into `opts.out` until a shutdown is requested (Ctrl-C, SIGTERM).
/// With [`RecordOptions::remote`], the graph on another machine, through its gateway.
pub fn run(prefix: &Prefix, opts: &RecordOptions) -> Result<RecordReport, RecorderError> {
    if let Some(remote) = &opts.remote {
        return remote::run(prefix, opts, remote);
    }
    let started = Instant::now();
    let r = match start(prefix, opts) {
        Ok(r) => r,
        Err(e) => {
            remove_unrecorded(&opts.out, &e);
            return Err(e);
        }
    };
    let Running {
        subs,
        heartbeat,
        mut producer,
        tally,
        writer,
        _graph: graph,
    } = r;
    tracing::info!(
        file = %opts.out.display(),
        topics = opts.topics.len(),
        "recording graph `{prefix}`"
    );
    // The publisher is dropped with the other ports, after the writer finished.
    let mut hb = Heartbeat::new(&heartbeat, NodeRole::Recorder);
    let mut loop_result = hb.say_ready().map_err(RecorderError::from);
    while loop_result.is_ok() && !signals::stop_requested() {
        loop_result = subs
            .states
            .wait(Duration::from_millis(50))
            .map_err(RecorderError::from)
            .and_then(|_| subs.drain(&mut producer))
            .and_then(|()| {
                let st = hb.status_mut();
                st.t_ns = now_ns();
                st.tick = producer.last_tick().unwrap_or(NO_TICK);
                st.handled = tally.received();
                st.faults = tally.dropped();
                hb.beat().map_err(RecorderError::from)
            });
    }
    // What arrived while stopping (the bridge's last state) goes in too.
    let _ = subs.drain(&mut producer);
    outcome_at_stop(opts, &mut producer);
    let _ = hb.stop();
    // The writer finishes the file once the hand-off is closed and drained.
    drop(producer);
    let outcome = writer.join().unwrap_or_else(|_| WriterOutcome {
        error: Some("the writer thread panicked".into()),
    });
    drop((subs, heartbeat, graph));
    // If this was the last process of the graph, leave nothing in shared memory.
    let _ = transport::graph::release_domain(prefix);
    loop_result?;
    Ok(report(opts, started, &tally, outcome))
}

/// The human-readable end-of-recording lines.
pub fn render_report(r: &RecordReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let per: Vec<String> = r
        .topics
        .iter()
        .map(|c| {
            if c.dropped > 0 {
                format!("{} {} ({} dropped)", c.topic, c.written, c.dropped)
            } else {
                format!("{} {}", c.topic, c.written)
            }
        })
        .collect();
    let _ = writeln!(
        s,
        "scl record: {}: {} messages in {:.1} s ({:.1} MB), {} dropped, {} robot states lost before the recorder",
        r.file,
        r.written,
        r.duration_s,
        r.file_bytes as f64 / 1e6,
        r.dropped,
        r.robot_state_gaps
    );
    let _ = writeln!(s, "  {}, 3D channels {}", per.join(", "), r.view_written);
    if let Some(e) = &r.write_error {
        let _ = writeln!(s, "  write error: {e}");
    }
    s
}

/// `--meta KEY=VALUE`: the key (trimmed) and the value.
fn parse_key_value(kv: &str) -> Result<(String, String), String> {
    kv.split_once('=')
        .map(|(k, v)| (k.trim().to_owned(), v.to_owned()))
        .ok_or_else(|| format!("`{kv}`: write it as KEY=VALUE"))
}

/// `scl record`: records until Ctrl-C / SIGTERM, or recovers a cut recording.
/// `network` is the configuration's `[network]` (`--remote`: the namespace, the lease, the
/// default credentials).
pub fn cli(
    prefix: &Prefix,
    args: &RecordArgs,
    network: &scl_config::NetworkConfig,
) -> Result<std::process::ExitCode, RecorderError> {
    if let Some(broken) = &args.recover {
        let r = recording::recover(broken, &args.out)?;
        let how = if r.source_complete {
            "the source was complete".to_owned()
        } else {
            match &r.stopped {
                Some(s) => format!("the source stopped: {s}"),
                None => "the source stopped".to_owned(),
            }
        };
        println!(
            "recovered {} messages on {} channels from {} into {} ({how})",
            r.messages,
            r.channels,
            broken.display(),
            args.out.display()
        );
        return Ok(std::process::ExitCode::SUCCESS);
    }
    if let Some(old) = &args.convert {
        let r = viz::convert::convert(old, &args.out)?;
        println!(
            "converted {} into {}: {} messages copied, {} 3D-view messages added from {} robot states",
            old.display(),
            args.out.display(),
            r.copied,
            r.added,
            r.states
        );
        for n in &r.notes {
            println!("  note: {n}");
        }
        return Ok(std::process::ExitCode::SUCCESS);
    }
    let trial: BTreeMap<String, String> = args.meta.iter().cloned().collect();
    let opts = RecordOptions {
        out: args.out.clone(),
        topics: Topic::parse_list(&args.topics)?,
        queue: args.queue,
        flush_every: FLUSH_EVERY,
        trial,
        meta_at_stop: args.meta_at_stop.clone(),
        remote: args.remote.as_ref().map(|endpoint| {
            RemoteGraph::new(endpoint, args.credentials.clone(), network, prefix.as_str())
        }),
    };
    let r = run(prefix, &opts)?;
    eprint!("{}", render_report(&r));
    if args.json {
        let text = serde_json::to_string(&r).map_err(RecorderError::Report)?;
        println!("{text}");
    }
    Ok(if r.write_error.is_some() {
        std::process::ExitCode::from(1)
    } else {
        std::process::ExitCode::SUCCESS
    })
}

/// Reads a JSON object of strings (numbers and booleans are written as text); `None` if the
/// file does not exist.
fn read_meta_file(path: &Path) -> Result<Option<BTreeMap<String, String>>, String> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e.to_string()),
    };
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    let obj = v.as_object().ok_or("not a JSON object")?;
    Ok(Some(
        obj.iter()
            .map(|(k, v)| {
                let s = match v {
                    serde_json::Value::String(s) => s.clone(),
                    other => other.to_string(),
                };
                (k.clone(), s)
            })
            .collect(),
    ))
}

/// Absolute form of `p` (against the current directory), for a child with another one.
pub fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::{RobotState, phase};

    fn state(tick: u64) -> Payload {
        Payload::RobotState(RobotState::at_rest(tick, 1000 + tick, 6))
    }

    /// A sink that takes `delay` per write call.
    struct Slow {
        bytes: Arc<std::sync::Mutex<Vec<u8>>>,
        delay: Duration,
    }

    impl Write for Slow {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            std::thread::sleep(self.delay);
            self.bytes.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn slow_writer(delay: Duration) -> (LogWriter<Slow>, Arc<std::sync::Mutex<Vec<u8>>>) {
        let bytes = Arc::new(std::sync::Mutex::new(Vec::new()));
        let mut w = LogWriter::new(
            Slow {
                bytes: bytes.clone(),
                delay,
            },
            Path::new("slow.mcap"),
            None,
        )
        .unwrap();
        w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
        (w, bytes)
    }

    fn count_states(bytes: &[u8]) -> (u64, Option<BTreeMap<String, String>>) {
        let mut n = 0;
        let mut end = None;
        let s = recording::read(bytes, Path::new("slow.mcap"), |ev| {
            match ev {
                recording::Event::Message { .. } => n += 1,
                recording::Event::Metadata { name, entries } if name == recording::END_METADATA => {
                    end = Some(entries.clone());
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        assert!(s.complete, "{s:?}");
        (n, end)
    }

    #[test]
    fn a_slow_writer_drops_and_counts_instead_of_blocking() {
        // Each flush of the sink takes 30 ms; the hand-off holds 16 messages; 2000 are
        // offered as fast as possible.
        let (w, bytes) = slow_writer(Duration::from_millis(30));
        let (mut p, tally, h) = start_pipeline(
            w,
            vec![Topic::RobotState],
            16,
            Duration::from_millis(5),
            None,
        )
        .unwrap();
        let mut handed = 0;
        for k in 0..2000 {
            if p.offer(state(k)) {
                handed += 1;
            }
        }
        drop(p);
        let out = h.join().unwrap();
        assert_eq!(out.error, None);
        let c = &tally.counts(&[Topic::RobotState])[0];
        assert_eq!(c.received, 2000);
        assert!(c.dropped > 0, "nothing was dropped: {c:?}");
        assert_eq!(c.written, handed);
        assert_eq!(c.written + c.dropped, c.received, "{c:?}");
        let (in_file, end) = count_states(&bytes.lock().unwrap());
        assert_eq!(in_file, c.written);
        let end = end.unwrap();
        assert_eq!(end["dropped.robot_state"], c.dropped.to_string());
        assert_eq!(end["written.robot_state"], c.written.to_string());
        assert_eq!(end["received.robot_state"], "2000");
    }

    /// The report's total counts every message in the file, the 3D channels' too (it left
    /// them out: 3,620 reported, 4,862 in the file).
    #[test]
    fn the_written_total_is_every_message_in_the_file() {
        let sink = Arc::new(std::sync::Mutex::new(Vec::new()));
        let mut w = LogWriter::new(
            Slow {
                bytes: sink.clone(),
                delay: Duration::ZERO,
            },
            Path::new("all.mcap"),
            None,
        )
        .unwrap();
        for t in Topic::ALL {
            w.add_topic(t, &BTreeMap::new()).unwrap();
        }
        let view = View::add_to(&mut w, &BTreeMap::new()).unwrap();
        let (mut p, tally, h) = start_pipeline(
            w,
            Topic::ALL.to_vec(),
            100_000,
            Duration::from_millis(5),
            Some(view),
        )
        .unwrap();
        let mut st = NodeStatus::new(NodeRole::Safety, phase::RUNNING, 1);
        st.pid = 77;
        for k in 0..300u64 {
            let mut s = RobotState::at_rest(k, 1_000_000_000 + k * 25_000_000, 6);
            s.q_rad[1] = 0.3;
            assert!(p.offer(Payload::RobotState(s)));
            st.t_ns = s.t_ns;
            assert!(p.offer(Payload::Status(st)));
        }
        drop(p);
        assert_eq!(h.join().unwrap().error, None);
        let mut in_file = 0u64;
        let mut end = None;
        recording::read(&sink.lock().unwrap()[..], Path::new("all.mcap"), |ev| {
            match ev {
                recording::Event::Message { .. } => in_file += 1,
                recording::Event::Metadata { name, entries } if name == recording::END_METADATA => {
                    end = Some(entries.clone());
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        assert!(tally.view_written() > 300, "{}", tally.view_written());
        assert_eq!(tally.written(&Topic::ALL), in_file);
        assert_eq!(end.unwrap()["written.3d"], tally.view_written().to_string());
    }

    #[test]
    fn gaps_in_robot_ticks_are_counted() {
        let (w, _bytes) = slow_writer(Duration::ZERO);
        let (mut p, tally, h) = start_pipeline(
            w,
            vec![Topic::RobotState],
            64,
            Duration::from_millis(5),
            None,
        )
        .unwrap();
        for k in [0, 1, 2, 5, 6, 10] {
            p.offer(state(k));
        }
        drop(p);
        h.join().unwrap();
        assert_eq!(tally.state_gaps.load(Ordering::SeqCst), 2 + 3);
        assert_eq!(tally.counts(&[Topic::RobotState])[0].written, 6);
    }

    #[test]
    fn a_full_disk_drops_and_counts_everything_after_the_error() {
        let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
            return;
        };
        let mut w =
            LogWriter::new(std::io::BufWriter::new(full), Path::new("/dev/full"), None).unwrap();
        w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
        let (mut p, tally, h) = start_pipeline(
            w,
            vec![Topic::RobotState],
            1000,
            Duration::from_millis(1),
            None,
        )
        .unwrap();
        for k in 0..500 {
            p.offer(state(k));
            if k % 50 == 0 {
                std::thread::sleep(Duration::from_millis(3));
            }
        }
        drop(p);
        let out = h.join().unwrap();
        let err = out.error.expect("no write error on /dev/full");
        assert!(err.starts_with("/dev/full:"), "{err}");
        let c = &tally.counts(&[Topic::RobotState])[0];
        assert_eq!(c.received, 500);
        assert_eq!(c.written, 0, "{c:?}");
        assert_eq!(c.dropped, 500, "{c:?}");
    }

    #[test]
    fn report_names_drops_and_errors() {
        let r = RecordReport {
            file: "run.mcap".into(),
            duration_s: 60.0,
            topics: vec![TopicCounts {
                topic: "robot_state".into(),
                received: 2400,
                written: 2398,
                dropped: 2,
            }],
            received: 2400,
            written: 2398,
            view_written: 0,
            dropped: 2,
            robot_state_gaps: 0,
            file_bytes: 1_500_000,
            write_error: Some("run.mcap: disk full".into()),
        };
        let s = render_report(&r);
        assert!(
            s.contains("2398 messages in 60.0 s (1.5 MB), 2 dropped"),
            "{s}"
        );
        assert!(s.contains("robot_state 2398 (2 dropped)"), "{s}");
        assert!(s.contains("write error: run.mcap: disk full"), "{s}");
    }
}
