//! `scl live`: a read-only observer that serves a running graph to Foxglove over its
//! WebSocket protocol (Foxglove's own server, the `foxglove` crate): the recording's JSON
//! topics (`/robot_state`, `/safe_command`, ...) and the 3D view of [`viz`] (`/tf`,
//! `/scl/arm`, `/scl/map`, `/scl/world`, `/scl/tick`), the same channels a recording holds;
//! `/scl/log` adds the processes' own log records (the graph's `log` topic), which a
//! recording does not hold.
//!
//! Like the recorder it never slows the control loop:
//!
//! * the subscriber thread (the main thread) wakes on each robot state, drains every topic
//!   (shared-memory subscribers with safe overflow: a slow reader loses its oldest samples,
//!   publishers never wait) and hands each message to the view thread with a non-blocking
//!   `try_send` on a bounded channel; a full hand-off drops the message and counts it;
//! * the view thread (lower CPU priority) computes the 3D view and logs every message to the
//!   server, whose per-client queues are bounded too (a slow client loses messages);
//! * the server's tokio runtime runs one worker thread, at the view thread's priority.
//!
//! It publishes nothing into the graph. It binds to the loopback address unless told
//! otherwise, and warns when it is not loopback: a robot PC's view is not for the network
//! by accident.
#![cfg_attr(test, allow(clippy::unwrap_used))]

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema};
use graph_client::observe::Observers;
use graph_client::process::{self, ProcessSeen};
use ipc_types::{NodeRole, NodeStatus, Prefix};
use recording::{LogClock, Payload, SchemaInfo, Topic};
use scl_config::GraphConfig;
use scl_net::observe::RemoteGraph;
use transport::{Graph, TopicSubscriber, signals};
use viz::{Viz, VizMessage, VizTopic};

pub mod client;

/// The address `scl live` and `scl up --live` listen on by default.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8765";

/// Default capacity of the hand-off to the view thread (messages): about 13 s of the mock
/// graph's messages.
pub const DEFAULT_QUEUE: usize = 4096;

/// Why the live observer stopped or could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The graph configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// Shared-memory transport failure.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The 3D view could not be set up.
    #[error(transparent)]
    Viz(#[from] viz::VizError),
    /// `--listen` is not an address.
    #[error("--listen {0}: expected ADDR:PORT, e.g. 127.0.0.1:8765 ({1})")]
    Listen(String, String),
    /// The WebSocket server could not start (the port is taken, ...).
    #[error("cannot serve Foxglove on {addr}: {source}")]
    Server {
        /// The address.
        addr: String,
        /// Why.
        source: foxglove::FoxgloveError,
    },
    /// A channel of the server could not be made.
    #[error("cannot create channel {topic}: {source}")]
    Channel {
        /// The channel's topic.
        topic: String,
        /// Why.
        source: foxglove::FoxgloveError,
    },
    /// `--remote`: the gateway could not be reached or did not answer (its clocks).
    #[error(transparent)]
    Remote(#[from] scl_net::observe::ObserveError),
    /// `--remote`: a subscription to the gateway's topics could not be declared.
    #[error(transparent)]
    Session(#[from] scl_net::SessionError),
    /// `--client`: no server to be a client of.
    #[error(transparent)]
    Client(#[from] client::ClientRunError),
    /// A thread did not start (`what`: the server's runtime, the view thread).
    #[error("cannot start {what}: {source}")]
    Thread {
        /// Which.
        what: &'static str,
        /// Why.
        source: std::io::Error,
    },
}

/// `scl live`'s arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct LiveArgs {
    /// Address and port of the Foxglove WebSocket server. Loopback by default; any other
    /// address exposes the robot's state to that network (a warning says so).
    #[arg(long, value_name = "ADDR:PORT", default_value = DEFAULT_LISTEN)]
    pub listen: String,
    /// Messages the hand-off to the view thread holds; beyond that, messages are dropped and
    /// counted, never waited for.
    #[arg(long, default_value_t = DEFAULT_QUEUE, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
    pub queue: usize,
    /// Print the end report as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
    /// Announce on stdout, as one line (`node_rt::ready`), that the server listens and the
    /// graph is joined (with the address bound), or why it could not start: how `scl up
    /// --live` knows that its own server serves.
    #[arg(long, hide = true)]
    pub announce: bool,
    /// Serve a graph on another machine, through its Zenoh gateway (`[network]` there): its
    /// endpoint, e.g. `tcp/192.0.2.10:7447`. The same channels as for a local graph, the
    /// models and configuration as the gateway captured them; `/scl/log` stays empty (the
    /// gateway does not forward log records).
    #[arg(long, value_name = "ENDPOINT")]
    pub remote: Option<String>,
    /// With `--remote`: a credentials file (`user:password`, mode 0600; default `[network]
    /// credentials`, if any), for a gateway that requires authentication.
    #[arg(long, value_name = "FILE", requires = "remote")]
    pub credentials: Option<std::path::PathBuf>,
    /// Serve nothing: be a Foxglove client of the server at ADDR:PORT (another `scl live`,
    /// `scl up --live`, any Foxglove WebSocket server), subscribed to every channel it
    /// advertises, reading every frame until Ctrl-C, as Foxglove does. Reports the frames
    /// received each second (`--json`: one JSON object a line on stdout; otherwise a line on
    /// stderr every 5 s), reconnecting a lost server. For soaks (scripts/soak.sh) and to check
    /// from another machine that a robot PC's server serves.
    #[arg(long, value_name = "ADDR:PORT", conflicts_with_all = ["remote", "listen", "announce"])]
    pub client: Option<String>,
}

/// Parses `ADDR:PORT`; says whether it is a loopback address.
pub fn parse_listen(s: &str) -> Result<(SocketAddr, bool), LiveError> {
    let a: SocketAddr = s
        .parse()
        .map_err(|e: std::net::AddrParseError| LiveError::Listen(s.to_owned(), e.to_string()))?;
    Ok((a, a.ip().is_loopback()))
}

/// The end report of a live session.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct LiveReport {
    /// The address served.
    pub listen: String,
    /// How long it ran (s).
    pub duration_s: f64,
    /// Messages received from the graph.
    pub received: u64,
    /// Messages dropped at the hand-off to the view thread (it was behind).
    pub dropped: u64,
    /// Messages logged to the server (graph topics and 3D view).
    pub logged: u64,
    /// 3D view messages that could not be built (logged as warnings).
    pub view_errors: u64,
}

#[derive(Debug, Default)]
struct Counters {
    received: AtomicU64,
    dropped: AtomicU64,
    logged: AtomicU64,
    view_errors: AtomicU64,
}

/// What goes to the view thread.
enum Item {
    Message(Payload),
    /// A process's own log record (boxed: 512 bytes, and rare).
    Log(Box<ipc_types::LogRecord>),
    Process(Box<ProcessSeen>),
    /// A remote process, as its gateway captured it.
    Captured(Box<process::Captured>),
}

/// The server's channels: one per graph topic and one per 3D-view topic.
struct Channels {
    topics: BTreeMap<Topic, Arc<RawChannel>>,
    view: BTreeMap<VizTopic, Arc<RawChannel>>,
}

fn channel(
    ctx: &Arc<Context>,
    topic: &str,
    s: SchemaInfo,
    encoding: &str,
) -> Result<Arc<RawChannel>, LiveError> {
    ChannelBuilder::new(topic)
        .context(ctx)
        .schema(Schema::new(s.name, s.encoding, s.data))
        .message_encoding(encoding)
        .build_raw()
        .map_err(|source| LiveError::Channel {
            topic: topic.to_owned(),
            source,
        })
}

impl Channels {
    fn new(ctx: &Arc<Context>) -> Result<Self, LiveError> {
        let mut topics = BTreeMap::new();
        for t in Topic::ALL {
            let schema = SchemaInfo {
                name: t.schema_name().to_owned(),
                encoding: "jsonschema".to_owned(),
                data: t.schema().to_string().into_bytes(),
            };
            topics.insert(t, channel(ctx, &t.channel(), schema, "json")?);
        }
        let mut view = BTreeMap::new();
        for t in VizTopic::ALL {
            view.insert(
                t,
                channel(ctx, t.topic(), t.schema(), t.message_encoding())?,
            );
        }
        Ok(Self { topics, view })
    }
}

/// The view thread: 3D view and logging to the server.
/// Every message is logged at the wall-clock time of its monotonic `t_ns` (`clock`), as in a
/// recording: Foxglove shows the date of the run.
fn view_loop(
    rx: Receiver<Item>,
    mut viz: Viz,
    channels: Channels,
    counters: Arc<Counters>,
    clock: LogClock,
) {
    node_rt::rt::lower_priority();
    let mut out: Vec<VizMessage> = Vec::new();
    let mut json = Vec::with_capacity(1024);
    loop {
        let item = match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(i) => i,
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => break,
        };
        match item {
            Item::Log(r) => {
                out.clear();
                if viz.observe_log(&r, &mut out).is_ok() {
                    for m in &out {
                        if let Some(c) = channels.view.get(&m.topic) {
                            let at = PartialMetadata::with_log_time(clock.log_time(m.t_ns));
                            c.log_with_meta(&m.data, at);
                            counters.logged.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
            }
            Item::Process(p) => {
                let (cfg, model) = process::runs(&p);
                if let Err(e) =
                    viz.take_process(p.role, p.mapper_id, cfg.as_ref(), model.as_deref())
                {
                    tracing::warn!("{e}");
                }
            }
            Item::Captured(c) => {
                let mut notes = Vec::new();
                viz::convert::apply_process_record(
                    &mut viz,
                    &c.entries,
                    &c.attachment_map(),
                    &mut notes,
                );
                for n in notes {
                    tracing::warn!("the 3D view: {n}");
                }
            }
            Item::Message(p) => {
                let t_ns = p.t_ns();
                json.clear();
                if p.write_json(&mut json).is_ok()
                    && let Some(c) = channels.topics.get(&p.topic())
                {
                    c.log_with_meta(&json, PartialMetadata::with_log_time(clock.log_time(t_ns)));
                    counters.logged.fetch_add(1, Ordering::Relaxed);
                }
                out.clear();
                if let Err(e) = viz.observe(&p, &mut out)
                    && counters.view_errors.fetch_add(1, Ordering::Relaxed) == 0
                {
                    tracing::warn!("the 3D view: {e}");
                }
                for m in &out {
                    if let Some(c) = channels.view.get(&m.topic) {
                        let at = PartialMetadata::with_log_time(clock.log_time(m.t_ns));
                        c.log_with_meta(&m.data, at);
                        counters.logged.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }
}

/// The subscriptions of the live observer.
struct Subscriptions {
    /// The heartbeats, drained first: a new mapper's model or mode reaches the view before
    /// the states and commands it applies to.
    status: Observers,
    /// The robot states: the observer's wake-up.
    states: TopicSubscriber<ipc_types::RobotState>,
    /// The other recorded topics.
    others: Observers,
    logs: TopicSubscriber<ipc_types::LogRecord>,
}

/// The subscriber side of the hand-off: never blocks.
struct Producer {
    tx: Sender<Item>,
    counters: Arc<Counters>,
    seen: process::NewProcesses,
    /// `--remote`: processes seen for the first time, to the thread that asks the gateway
    /// what they run; `None`: read from this machine's `/proc`.
    remote_procs: Option<Sender<(NodeStatus, NodeRole)>>,
}

impl Producer {
    fn offer(&self, p: Payload) {
        self.counters.received.fetch_add(1, Ordering::Relaxed);
        match self.tx.try_send(Item::Message(p)) {
            Ok(()) => {}
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    fn offer_log(&self, r: &ipc_types::LogRecord) {
        self.counters.received.fetch_add(1, Ordering::Relaxed);
        if self.tx.try_send(Item::Log(Box::new(*r))).is_err() {
            self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    fn note_process(&mut self, st: &NodeStatus) {
        if let Some(role) = self.seen.first(st) {
            if let Some(tx) = &self.remote_procs {
                let _ = tx.send((*st, role));
                return;
            }
            // Rare (a start, a swap, a restart); /proc only, no disk. Dropped if full.
            let _ = self
                .tx
                .try_send(Item::Process(Box::new(ProcessSeen::of(st, role))));
        }
    }
}

impl Subscriptions {
    fn open(graph: &Graph) -> Result<Self, LiveError> {
        let others: Vec<Topic> = Topic::ALL
            .into_iter()
            .filter(|&t| t != Topic::Status && t != Topic::RobotState)
            .collect();
        Ok(Self {
            status: Observers::open(graph, &[Topic::Status])?,
            states: graph.robot_state_subscriber(true)?,
            others: Observers::open(graph, &others)?,
            logs: graph.log_subscriber()?,
        })
    }

    fn drain(&self, p: &mut Producer) -> Result<(), LiveError> {
        self.status.drain(|m| {
            if let Payload::Status(s) = &m {
                p.note_process(s);
            }
            p.offer(m);
        })?;
        self.states.drain(|m| p.offer(Payload::RobotState(*m)))?;
        self.others.drain(|m| p.offer(m))?;
        self.logs.drain(|m| p.offer_log(m))?;
        Ok(())
    }
}

/// What `scl live` is asked to do.
#[derive(Debug, Clone)]
pub struct LiveOptions {
    /// Where to listen.
    pub listen: String,
    /// The hand-off's capacity.
    pub queue: usize,
    /// The graph configuration (the robot and scene until the safety process is seen).
    pub config: GraphConfig,
    /// Announce readiness on stdout (`node_rt::ready`) once serving, with the address bound.
    pub announce: bool,
    /// Serve a graph on another machine through its gateway, not this machine's.
    pub remote: Option<RemoteGraph>,
}

/// Starts the view thread, mapping the messages' monotonic stamps with `clock`.
fn start_view(
    rx: Receiver<Item>,
    viz: Viz,
    channels: Channels,
    counters: Arc<Counters>,
    clock: LogClock,
) -> Result<std::thread::JoinHandle<()>, LiveError> {
    std::thread::Builder::new()
        .name("live-view".into())
        .spawn(move || view_loop(rx, viz, channels, counters, clock))
        .map_err(|source| LiveError::Thread {
            what: "the view thread",
            source,
        })
}

/// Serves this machine's graph `prefix` until a shutdown is requested.
fn serve_local(
    prefix: &Prefix,
    opts: &LiveOptions,
    mut producer: Producer,
    rx: Receiver<Item>,
    viz: Viz,
    channels: Channels,
    addr: SocketAddr,
) -> Result<(), LiveError> {
    let graph = Graph::join(prefix, "live")?;
    let subs = Subscriptions::open(&graph)?;
    let (clock, _, _) = LogClock::wall_now();
    let view = start_view(rx, viz, channels, producer.counters.clone(), clock)?;
    if opts.announce {
        node_rt::ready::announce(&node_rt::ready::Announcement::Ready(addr.to_string()));
    }
    let mut result = Ok(());
    while result.is_ok() && !signals::stop_requested() {
        result = subs
            .states
            .wait(Duration::from_millis(50))
            .map_err(LiveError::from)
            .and_then(|_| subs.drain(&mut producer));
    }
    drop(producer);
    let _ = view.join();
    drop(subs);
    drop(graph);
    let _ = transport::graph::release_domain(prefix);
    result
}

/// `--remote`: the session to the gateway, the robot PC's clocks, the fetcher of what each
/// process runs.
struct Remote {
    session: scl_net::zenoh::Session,
    keys: scl_net::Keys,
    endpoint: String,
    clock: LogClock,
    fetcher: std::thread::JoinHandle<()>,
    stopping: Arc<std::sync::atomic::AtomicBool>,
}

impl Remote {
    fn open(r: &RemoteGraph, producer: &mut Producer) -> Result<Self, LiveError> {
        let scl_net::observe::Observer {
            session,
            keys,
            clock: c,
        } = r.connect()?;
        let (seen_tx, seen_rx) = crossbeam_channel::unbounded::<(NodeStatus, NodeRole)>();
        producer.remote_procs = Some(seen_tx);
        let stopping = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let fetcher = {
            let (session, keys, tx, stopping) = (
                session.clone(),
                keys.clone(),
                producer.tx.clone(),
                Arc::clone(&stopping),
            );
            let from = r.endpoint.clone();
            std::thread::Builder::new()
                .name("remote-processes".into())
                .spawn(move || {
                    node_rt::rt::lower_priority();
                    while let Ok((st, role)) = seen_rx.recv() {
                        let got = scl_net::observe::until_answered(
                            || {
                                scl_net::observe::fetch_process(
                                    &session,
                                    &keys,
                                    st.pid,
                                    scl_net::observe::CAPTURE_TIMEOUT,
                                )
                            },
                            scl_net::observe::CAPTURE_ATTEMPTS,
                            scl_net::observe::CAPTURE_RETRY,
                            &stopping,
                        );
                        let captured = got.map_err(|e| e.to_string()).and_then(|b| {
                            process::Captured::read(&b, st.pid, &from).map_err(|e| e.to_string())
                        });
                        match captured {
                            Ok(c) => {
                                let _ = tx.send(Item::Captured(Box::new(c)));
                            }
                            Err(e) => tracing::warn!(
                                "{} process {}: what it runs is not known here: {e}",
                                role.name(),
                                st.pid
                            ),
                        }
                    }
                })
                .map_err(|source| LiveError::Thread {
                    what: "the process fetcher",
                    source,
                })?
        };
        Ok(Self {
            session,
            keys,
            endpoint: r.endpoint.clone(),
            clock: LogClock::from_pair(c.mono_ns, c.unix_ns),
            fetcher,
            stopping,
        })
    }

    /// Serves the remote graph until a shutdown is requested.
    fn serve(
        self,
        opts: &LiveOptions,
        producer: Producer,
        rx: Receiver<Item>,
        viz: Viz,
        channels: Channels,
        addr: SocketAddr,
    ) -> Result<(), LiveError> {
        let view = start_view(rx, viz, channels, producer.counters.clone(), self.clock)?;
        let shared = Arc::new(std::sync::Mutex::new(Some(producer)));
        let s2 = Arc::clone(&shared);
        let subs = scl_net::observe::subscribe_graph(&self.session, &self.keys, move |m| {
            if let Ok(m) = m
                && let Ok(mut g) = s2.lock()
                && let Some(p) = g.as_mut()
            {
                if let Payload::Status(st) = &m {
                    p.note_process(st);
                }
                p.offer(m);
            }
        });
        let result = subs.map(|subs| {
            tracing::info!(endpoint = %self.endpoint, "serving the remote graph");
            if opts.announce {
                node_rt::ready::announce(&node_rt::ready::Announcement::Ready(addr.to_string()));
            }
            while !signals::stop_requested() {
                std::thread::sleep(Duration::from_millis(50));
            }
            drop(subs);
        });
        self.stopping
            .store(true, std::sync::atomic::Ordering::Relaxed);
        let mut producer = shared.lock().ok().and_then(|mut g| g.take());
        if let Some(p) = producer.as_mut() {
            p.remote_procs = None;
        }
        let _ = self.fetcher.join();
        drop(producer);
        let _ = view.join();
        Ok(result?)
    }
}

/// Serves graph `prefix` until a shutdown is requested (Ctrl-C, SIGTERM); with
/// [`LiveOptions::remote`], the graph on another machine, through its gateway.
pub fn run(prefix: &Prefix, opts: &LiveOptions) -> Result<LiveReport, LiveError> {
    let started = Instant::now();
    let (addr, loopback) = parse_listen(&opts.listen)?;
    if !loopback {
        tracing::warn!(
            "serving the graph on {addr}, not a loopback address: anyone who can reach it sees \
             the robot's state (read-only)"
        );
    }
    let viz = Viz::new(&opts.config)?;
    // One worker thread at low priority; the observer's runtime only.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("foxglove-ws")
        .on_thread_start(node_rt::rt::lower_priority)
        .enable_all()
        .build()
        .map_err(|source| LiveError::Thread {
            what: "the server's runtime",
            source,
        })?;
    let counters = Arc::new(Counters::default());
    let (tx, rx) = crossbeam_channel::bounded(opts.queue.max(1));
    let mut producer = Producer {
        tx,
        counters: counters.clone(),
        seen: process::NewProcesses::default(),
        remote_procs: None,
    };
    // A remote graph's gateway first: a wrong endpoint or login starts no server.
    let remote = opts
        .remote
        .as_ref()
        .map(|r| Remote::open(r, &mut producer))
        .transpose()?;
    let ctx = Context::new();
    let channels = Channels::new(&ctx)?;
    let server = ctx
        .websocket_server()
        .name(format!("scl {prefix}"))
        .bind(addr.ip().to_string(), addr.port())
        .tokio_runtime(rt.handle())
        .start_blocking()
        .map_err(|source| LiveError::Server {
            addr: addr.to_string(),
            source,
        })?;
    // The port bound (the one asked for, or the one the system chose for port 0).
    let addr = SocketAddr::new(addr.ip(), server.port());
    tracing::info!(
        "serving graph `{prefix}` to Foxglove on ws://{addr} (open connection: Foxglove WebSocket)"
    );
    let result = match remote {
        None => serve_local(prefix, opts, producer, rx, viz, channels, addr),
        Some(remote) => remote.serve(opts, producer, rx, viz, channels, addr),
    };
    let _ = server.stop();
    rt.shutdown_timeout(Duration::from_secs(1));
    result?;
    Ok(LiveReport {
        listen: addr.to_string(),
        duration_s: started.elapsed().as_secs_f64(),
        received: counters.received.load(Ordering::Relaxed),
        dropped: counters.dropped.load(Ordering::Relaxed),
        logged: counters.logged.load(Ordering::Relaxed),
        view_errors: counters.view_errors.load(Ordering::Relaxed),
    })
}

/// `scl live`: serves until Ctrl-C / SIGTERM, then reports.
pub fn cli(
    prefix: &Prefix,
    config: GraphConfig,
    args: &LiveArgs,
) -> Result<std::process::ExitCode, LiveError> {
    if let Some(addr) = &args.client {
        return client_cli(addr, args.json);
    }
    let r = run(
        prefix,
        &LiveOptions {
            listen: args.listen.clone(),
            queue: args.queue,
            announce: args.announce,
            remote: args.remote.as_ref().map(|endpoint| {
                RemoteGraph::new(
                    endpoint,
                    args.credentials.clone(),
                    &config.network,
                    prefix.as_str(),
                )
            }),
            config,
        },
    )
    .inspect_err(|e| {
        if args.announce {
            node_rt::ready::announce(&node_rt::ready::Announcement::Failed(e.to_string()));
        }
    })?;
    eprintln!(
        "scl live: {}: {} messages in {:.1} s, {} logged, {} dropped at the hand-off",
        r.listen, r.received, r.duration_s, r.logged, r.dropped
    );
    if args.json
        && let Ok(text) = serde_json::to_string(&r)
    {
        println!("{text}");
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// `scl live --client`: reads until Ctrl-C / SIGTERM, reporting as it goes.
fn client_cli(addr: &str, json: bool) -> Result<std::process::ExitCode, LiveError> {
    let line = |r: &client::ClientReport| match serde_json::to_string(r) {
        Ok(text) => println!("{text}"),
        Err(e) => tracing::warn!(error = %e, "cannot write the report"),
    };
    let r = client::run(addr, |r| {
        if json {
            line(r);
        } else if (r.t_s.round() as u64).is_multiple_of(5) {
            eprintln!(
                "scl live --client: {addr}: {:.0} s, {} channels, {} frames, {}",
                r.t_s,
                r.channels,
                r.frames,
                if r.connected {
                    "connected"
                } else {
                    "not connected"
                }
            );
        }
    })?;
    eprintln!(
        "scl live --client: {addr}: {} frames on {} channels in {:.1} s, {} connection(s)",
        r.frames, r.channels, r.t_s, r.connects
    );
    if json {
        line(&r);
    }
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listen_addresses() {
        assert!(parse_listen("127.0.0.1:8765").unwrap().1);
        assert!(parse_listen("[::1]:9000").unwrap().1);
        assert!(!parse_listen("0.0.0.0:8765").unwrap().1);
        let e = parse_listen("localhost").unwrap_err().to_string();
        assert!(e.contains("--listen localhost: expected ADDR:PORT"), "{e}");
    }

    /// The WebSocket handshake of a client offering `protocol`: the HTTP status and the
    /// subprotocol the server chose.
    fn handshake(port: u16, protocol: &str) -> (u16, Option<String>) {
        use tungstenite::client::IntoClientRequest;
        let stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        let mut req = format!("ws://127.0.0.1:{port}/")
            .into_client_request()
            .unwrap();
        req.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            tungstenite::http::HeaderValue::from_str(protocol).unwrap(),
        );
        match tungstenite::client(req, stream) {
            Ok((_, res)) => (
                res.status().as_u16(),
                res.headers()
                    .get("sec-websocket-protocol")
                    .and_then(|v| v.to_str().ok())
                    .map(str::to_owned),
            ),
            Err(tungstenite::HandshakeError::Failure(tungstenite::Error::Http(res))) => {
                (res.status().as_u16(), None)
            }
            Err(e) => panic!("{protocol}: {e}"),
        }
    }

    /// What docs/foxglove.md says of the subprotocols: `foxglove.sdk.v1` (what our client
    /// offers) is accepted; a client offering only the older `foxglove.websocket.v1` gets an
    /// HTTP 400.
    #[test]
    fn the_server_speaks_foxglove_sdk_v1_and_refuses_the_older_protocol() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        let ctx = Context::new();
        let server = ctx
            .websocket_server()
            .bind("127.0.0.1", 0)
            .tokio_runtime(rt.handle())
            .start_blocking()
            .unwrap();
        let port = server.port();
        assert_eq!(
            handshake(port, viz::client::SUBPROTOCOL),
            (101, Some("foxglove.sdk.v1".to_owned()))
        );
        assert_eq!(handshake(port, "foxglove.websocket.v1"), (400, None));
        let _ = server.stop();
        rt.shutdown_timeout(Duration::from_secs(1));
    }
}
