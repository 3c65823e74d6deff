//! The gateway process (`scl gateway`; `scl up` starts it when `[network] enabled`): the
//! graph's link to other machines through Zenoh ([`scl_net`]).
//!
//! * **Out**, for observers, read-only: every robot state, joystick sample, mapper and
//!   executed command, heartbeat, tick report, safety control and e-stop command (every topic
//!   `scl record` writes), handed from the loop to a network thread through a bounded
//!   queue: when the network is behind, the newest messages are dropped and counted
//!   ([`ipc_types::gateway_counts::OUTBOUND_DROPPED`]); the loop never waits on the network.
//! * **Served**, read-only queryables: what each mapper and safety process runs, captured as
//!   the local recorder captures it (`graph_client::process::capture`, on a capture thread
//!   when the process's first heartbeat arrives: the configuration, the model file's bytes,
//!   every swap's model), and the robot PC's clocks, so that `scl record --remote` writes
//!   what a local recording holds.
//! * **In**, only with `[network] accept_joystick` / `accept_reset` and only from peers the
//!   credentials file lists (Zenoh's user/password authentication refuses the others before
//!   they can publish anything): a remote operator's joystick samples, which the gateway
//!   publishes as the graph's one joystick, and e-stop (and, if accepted, reset) requests,
//!   which go straight to safety's e-stop topic, so they act while a mapper is dead.
//!
//! The remote operator's link is judged by [`scl_net::OperatorLink`]: it drives only with a
//! live liveliness token, after neutral input; a lost session or stale input stops the arm
//! at once (the gateway stands in with a neutral sample flagged `NO_DEVICE`, as an unplugged
//! joystick, so safety's restart prevention then waits for neutral input).
#![cfg_attr(test, allow(clippy::unwrap_used))]

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TrySendError};
use graph_client::observe::Observers;
use ipc_types::control::{EstopCommand, estop_action};
use ipc_types::{
    JoystickInput, NodeRole, NodeStatus, Prefix, RobotState, SafeCommand, TickReport,
    gateway_counts, time::now_ns,
};
use node_rt::node::Heartbeat;
use recording::{Payload, Topic};
use scl_config::GraphConfig;
use scl_net::link::{Refusal, Stop};
use scl_net::observe::GraphPublishers;
use scl_net::ports::{self, Out, Urgency};
use scl_net::session::{self, SessionSpec};
use scl_net::wire::DecodeError;
use scl_net::{Credentials, GatewayStatus, Keys, OperatorLink};
use transport::graph::Wakeable;
use transport::{Graph, Waker, signals};

/// Inbound messages queued for the loop before the newest are dropped (and counted).
const INBOUND_QUEUE: usize = 256;

/// Captures of processes kept for remote recorders, newest last; beyond that the oldest go
/// (a recorder asks for a process when it first sees its heartbeat, so only the processes of
/// long-past swaps are lost).
const KEPT_CAPTURES: usize = 64;

/// Why the gateway could not run.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    /// The configuration is unusable.
    #[error(transparent)]
    Config(#[from] scl_config::ConfigError),
    /// The credentials file is unusable.
    #[error(transparent)]
    Credentials(#[from] scl_net::CredentialsError),
    /// The Zenoh session or one of its ports.
    #[error(transparent)]
    Session(#[from] scl_net::SessionError),
    /// Shared memory.
    #[error(transparent)]
    Ipc(#[from] transport::IpcError),
    /// The wake-up or the network thread could not be created.
    #[error("cannot start the {what}: {source}")]
    Thread {
        /// Which.
        what: &'static str,
        /// The OS error.
        source: std::io::Error,
    },
}

/// A message for the network thread.
#[derive(Debug, Clone, Copy)]
enum Outbound {
    /// A message of a recorded topic.
    Graph(Payload),
    Report(TickReport),
    Gateway(GatewayStatus),
}

/// A message from the network callbacks.
#[derive(Debug)]
enum Inbound {
    Sample(String, Result<JoystickInput, DecodeError>),
    Token(String, bool),
    Estop(Result<EstopCommand, DecodeError>),
    /// A ROS 2 `/joy` message, or why it was refused.
    Joy(Result<scl_net::ros2::Joy, String>),
    /// A ROS 2 publisher of `/joy` appeared (`true`) or went.
    JoyPublisher(bool),
}

/// A ROS 2 `/joy` operator: its publishers' liveliness is its session (a new one after the
/// last publisher went), its last input answers every tick while younger than the timeout.
struct JoyOperator {
    map: scl_net::ros2::JoyMapping,
    timeout: Duration,
    publishers: usize,
    generation: u64,
    last: Option<(std::time::Instant, JoystickInput)>,
    estop_held: bool,
    seq: u64,
}

impl JoyOperator {
    /// The ROS 2 joy operator as `net` configures it, nothing heard yet.
    fn new(net: &scl_config::NetworkConfig) -> Self {
        Self {
            map: scl_net::ros2::JoyMapping::from_config(net),
            timeout: Duration::from_millis(net.ros2_joy_timeout_ms),
            publishers: 0,
            generation: 0,
            last: None,
            estop_held: false,
            seq: 0,
        }
    }

    /// The session name the link knows the current `/joy` publishers by.
    fn session(&self) -> String {
        format!("ros2-joy-{}", self.generation)
    }
}

/// The callbacks' side of the inbound queue.
#[derive(Clone)]
struct InboundTx {
    tx: Sender<Inbound>,
    waker: Arc<Waker>,
    dropped: Arc<AtomicU64>,
}

impl InboundTx {
    fn send(&self, m: Inbound) {
        match self.tx.try_send(m) {
            Ok(()) => self.waker.notify(),
            Err(_) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// The Zenoh side: the session, its inbound subscribers and the network thread's queue.
struct Network {
    /// Kept for the process's life (the subscribers and the thread's publishers use it).
    _session: scl_net::zenoh::Session,
    _subscribers: Vec<scl_net::zenoh::pubsub::Subscriber<()>>,
    _tokens: Vec<scl_net::zenoh::liveliness::LivelinessToken>,
    _queryables: Vec<scl_net::zenoh::query::Queryable<()>>,
    out: Sender<Outbound>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Network {
    fn open(
        cfg: &GraphConfig,
        keys: &Keys,
        creds: Option<&Credentials>,
        inbound: &InboundTx,
        captures: &Captures,
    ) -> Result<Self, GatewayError> {
        let net = &cfg.network;
        let spec = SessionSpec {
            mode: net.mode,
            listen: &net.listen,
            connect: &net.connect,
            lease_ms: net.lease_ms,
            multicast_scouting: net.multicast_scouting,
            credentials: creds,
            accept_listed_only: creds.is_some(),
        };
        let session = session::open(&spec)?;
        let mut subscribers = Vec::new();
        if net.accept_joystick {
            subscribers.extend(operator_subscribers(&session, keys, inbound)?);
        }
        if net.inbound() {
            let tx = inbound.clone();
            subscribers.push(ports::subscribe::<EstopCommand, _>(
                &session,
                keys.estop(),
                move |_, c| tx.send(Inbound::Estop(c)),
            )?);
        }
        let mut tokens = Vec::new();
        if net.ros2_joy {
            let (subscriber, watch, token) = ros2_joy(&session, net, inbound)?;
            subscribers.extend([subscriber, watch]);
            tokens.push(token);
        }
        let queryables = vec![captures.serve(&session, keys)?, {
            let key = keys.clock();
            ports::serve(&session, key.clone(), move |_| {
                let (_, mono_ns, unix_ns) = recording::LogClock::wall_now();
                let c = scl_net::wire::ClockPair { mono_ns, unix_ns };
                vec![ports::Answer {
                    key: key.clone(),
                    encoding: scl_net::wire::encoding_of::<scl_net::wire::ClockPair>(),
                    bytes: Arc::new(scl_net::wire::encode(&c).to_vec()),
                }]
            })?
        }];
        let (out, rx) = crossbeam_channel::bounded(net.outbound_queue);
        let publishers = Publishers::declare(&session, keys, cfg)?;
        let thread = std::thread::Builder::new()
            .name("gateway-out".into())
            .spawn(move || publishers.run(&rx))
            .map_err(|source| GatewayError::Thread {
                what: "network thread",
                source,
            })?;
        Ok(Self {
            _session: session,
            _subscribers: subscribers,
            _tokens: tokens,
            _queryables: queryables,
            out,
            thread: Some(thread),
        })
    }
}

/// The subscribers an operator's joystick needs: its samples (by session) and its
/// liveliness token.
fn operator_subscribers(
    session: &scl_net::zenoh::Session,
    keys: &Keys,
    inbound: &InboundTx,
) -> Result<[scl_net::zenoh::pubsub::Subscriber<()>; 2], GatewayError> {
    let (tx, k) = (inbound.clone(), keys.clone());
    let samples =
        ports::subscribe::<JoystickInput, _>(session, keys.joystick_all(), move |key, s| {
            if let Some(zid) = k.session_of(key) {
                tx.send(Inbound::Sample(zid.to_owned(), s));
            }
        })?;
    let (tx, k) = (inbound.clone(), keys.clone());
    let tokens = ports::watch_liveliness(session, keys.operator_all(), move |key, alive| {
        if let Some(zid) = k.session_of(key) {
            tx.send(Inbound::Token(zid.to_owned(), alive));
        }
    })?;
    Ok([samples, tokens])
}

/// The ROS 2 joy input's subscription, its watch on the publishers and its token.
type Ros2Joy = (
    scl_net::zenoh::pubsub::Subscriber<()>,
    scl_net::zenoh::pubsub::Subscriber<()>,
    scl_net::zenoh::liveliness::LivelinessToken,
);

/// The ROS 2 `sensor_msgs/Joy` input: the subscription to the joy topic, the watch on its
/// publishers' liveliness, and this node's subscription token (so ROS 2 tools see it).
fn ros2_joy(
    session: &scl_net::zenoh::Session,
    net: &scl_config::NetworkConfig,
    inbound: &InboundTx,
) -> Result<Ros2Joy, GatewayError> {
    use scl_net::ros2::{EntityKind, JOY, Ros2Node};
    use scl_net::zenoh::Wait as _;
    let node = Ros2Node {
        domain: net.ros2_domain_id,
        zid: session::session_id(session),
        name: net.ros2_node.clone(),
    };
    let key = node.topic_key(JOY_TOPIC, JOY);
    let tx = inbound.clone();
    let subscriber = session
        .declare_subscriber(key.clone())
        .callback(move |s| {
            let bytes = s.payload().to_bytes();
            let joy = scl_net::ros2::decode_joy(&bytes).map_err(|e| e.to_string());
            tx.send(Inbound::Joy(joy));
        })
        .wait()
        .map_err(|source| scl_net::SessionError::Declare {
            what: "ROS 2 subscription",
            key,
            source,
        })?;
    let tx = inbound.clone();
    let watch = ports::watch_liveliness(
        session,
        format!(
            "@ros2_lv/{}/*/*/*/MP/*/*/*/{}/{}/{}/*",
            net.ros2_domain_id,
            scl_net::ros2::mangle(JOY_TOPIC),
            JOY.name,
            JOY.hash
        ),
        move |_, alive| tx.send(Inbound::JoyPublisher(alive)),
    )?;
    let token = ports::token(
        session,
        node.entity_token(3, EntityKind::Subscription, JOY_TOPIC, JOY),
    )?;
    Ok((subscriber, watch, token))
}

impl Drop for Network {
    fn drop(&mut self) {
        // Closing the queue ends the thread once it has sent what is queued.
        let (closed, _) = crossbeam_channel::bounded(0);
        self.out = closed;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The network thread's publishers, one per outbound key.
struct Publishers {
    graph: GraphPublishers,
    report: Out<TickReport>,
    gateway: Out<GatewayStatus>,
    ros2: Option<Ros2Out>,
}

/// The ROS 2 side ([`scl_net::ros2`]): `/joint_states` every tick, `/scl/safety_status` when
/// safety's flags change, and the liveliness tokens that make the node and its publishers
/// visible to `ros2 node list` / `ros2 topic list`.
struct Ros2Out {
    joint_states: scl_net::zenoh::pubsub::Publisher<'static>,
    safety: scl_net::zenoh::pubsub::Publisher<'static>,
    names: Vec<String>,
    gids: [[u8; 16]; 2],
    seq: u64,
    last_flags: Option<u32>,
    _tokens: Vec<scl_net::zenoh::liveliness::LivelinessToken>,
}

/// The ROS 2 topics the gateway publishes, and the one it takes.
const JOINT_STATES: &str = "/joint_states";
const JOY_TOPIC: &str = "/joy";
const SAFETY_STATUS: &str = "/scl/safety_status";

impl Ros2Out {
    fn declare(session: &scl_net::zenoh::Session, cfg: &GraphConfig) -> Result<Self, GatewayError> {
        use scl_net::ros2::{EntityKind, JOINT_STATE, Ros2Node, STRING};
        use scl_net::zenoh::Wait as _;
        let node = Ros2Node {
            domain: cfg.network.ros2_domain_id,
            zid: session::session_id(session),
            name: cfg.network.ros2_node.clone(),
        };
        let declare = |key: String| {
            session
                .declare_publisher(key.clone())
                .wait()
                .map_err(|source| scl_net::SessionError::Declare {
                    what: "ROS 2 publisher",
                    key,
                    source,
                })
        };
        let joint_states = declare(node.topic_key(JOINT_STATES, JOINT_STATE))?;
        let safety = declare(node.topic_key(SAFETY_STATUS, STRING))?;
        let tokens = vec![
            ports::token(session, node.node_token())?,
            ports::token(
                session,
                node.entity_token(1, EntityKind::Publisher, JOINT_STATES, JOINT_STATE),
            )?,
            ports::token(
                session,
                node.entity_token(2, EntityKind::Publisher, SAFETY_STATUS, STRING),
            )?,
        ];
        Ok(Self {
            joint_states,
            safety,
            names: cfg.profile()?.joint_names().to_vec(),
            gids: [node.gid(1), node.gid(2)],
            seq: 0,
            last_flags: None,
            _tokens: tokens,
        })
    }

    fn put(&mut self, which: usize, bytes: Vec<u8>) -> Result<(), scl_net::zenoh::Error> {
        use scl_net::zenoh::Wait as _;
        self.seq += 1;
        let now = wall_ns();
        let att = scl_net::ros2::attachment(self.seq, now as u64, &self.gids[which]);
        let p = if which == 0 {
            &self.joint_states
        } else {
            &self.safety
        };
        p.put(bytes).attachment(att).wait()
    }

    fn state(&mut self, s: &RobotState) -> Result<(), scl_net::zenoh::Error> {
        use scl_net::ros2::{Header, JointState, Time};
        let n = self.names.len().min(s.q().len());
        let m = JointState {
            header: Header {
                stamp: Time::from_ns(wall_ns()),
                frame_id: String::new(),
            },
            name: self.names[..n].to_vec(),
            position: s.q()[..n].to_vec(),
            velocity: s.qdot()[..n].to_vec(),
            effort: Vec::new(),
        };
        let bytes = scl_net::ros2::encode(&m, "sensor_msgs/msg/JointState")?;
        self.put(0, bytes)
    }

    fn safe(&mut self, c: &SafeCommand) -> Result<(), scl_net::zenoh::Error> {
        if self.last_flags == Some(c.flags) {
            return Ok(());
        }
        self.last_flags = Some(c.flags);
        let rules: Vec<&str> = ipc_types::safe_flags::NAMES
            .iter()
            .enumerate()
            .filter(|(i, _)| c.flags & (1 << i) != 0)
            .map(|(_, n)| *n)
            .collect();
        let data = format!(
            "tick {}: {}",
            c.tick,
            if rules.is_empty() {
                "ok".to_owned()
            } else {
                rules.join(", ")
            }
        );
        let bytes =
            scl_net::ros2::encode(&scl_net::ros2::RosString { data }, "std_msgs/msg/String")?;
        self.put(1, bytes)
    }
}

/// The wall clock (ns since the epoch): ROS 2's header stamps.
fn wall_ns() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

impl Publishers {
    fn declare(
        session: &scl_net::zenoh::Session,
        keys: &Keys,
        cfg: &GraphConfig,
    ) -> Result<Self, GatewayError> {
        use ipc_types::topics;
        let o = Urgency::Observe;
        let ros2 = if cfg.network.ros2 {
            Some(Ros2Out::declare(session, cfg)?)
        } else {
            None
        };
        Ok(Self {
            ros2,
            // Robot states reach a remote operator, whose samples answer them.
            graph: GraphPublishers::declare(session, keys, |t| match t {
                Topic::RobotState => Urgency::Control,
                _ => o,
            })?,
            report: ports::publisher(session, keys.topic(topics::TICK_REPORT.name), o)?,
            gateway: ports::publisher(session, keys.gateway(), Urgency::Control)?,
        })
    }

    fn run(mut self, rx: &Receiver<Outbound>) {
        let mut failures = 0u64;
        while let Ok(m) = rx.recv() {
            let ros2 = match (&mut self.ros2, &m) {
                (Some(r), Outbound::Graph(Payload::RobotState(s))) => r.state(s),
                (Some(r), Outbound::Graph(Payload::SafeCommand(c))) => r.safe(c),
                _ => Ok(()),
            };
            if let Err(e) = ros2 {
                failures += 1;
                if failures.is_power_of_two() {
                    tracing::warn!(failures, "cannot publish to ROS 2: {e}");
                }
            }
            let r = match &m {
                Outbound::Graph(m) => self.graph.put(m),
                Outbound::Report(r) => self.report.put(r),
                Outbound::Gateway(g) => self.gateway.put(g),
            };
            if let Err(e) = r {
                failures += 1;
                if failures.is_power_of_two() {
                    tracing::warn!(failures, "cannot publish to the network: {e}");
                }
            }
        }
    }
}

/// The loop's state: the link, the counts, the graph's ports.
struct Gateway<'a> {
    cfg: &'a GraphConfig,
    link: OperatorLink,
    joystick: Option<transport::TopicPublisher<JoystickInput>>,
    estop: Option<transport::control::EstopPublisher>,
    seq: u64,
    /// The heartbeat: the link's counts and refusals.
    hb: Heartbeat<&'a transport::TopicPublisher<NodeStatus>>,
    outbound_dropped: u64,
    inbound_dropped: Arc<AtomicU64>,
    joy: Option<JoyOperator>,
}

impl Gateway<'_> {
    fn count(&mut self, index: usize) {
        let c = &mut self.hb.status_mut().rule_counts[index];
        *c = c.saturating_add(1);
    }

    fn publish_sample(&mut self, mut s: JoystickInput) -> Result<(), GatewayError> {
        if let Some(p) = &self.joystick {
            // The operator's clock is not this machine's: the sample is stamped on arrival,
            // so safety's age check measures from here. A benchmark whose operator shares
            // this machine's clock keeps the operator's stamp (never one from the future).
            s.t_ns = forwarded_stamp(self.cfg.network.keep_operator_stamps, s.t_ns, now_ns());
            s.seq = self.seq;
            self.seq += 1;
            p.send(s)?;
        }
        Ok(())
    }

    fn inbound(&mut self, m: Inbound, net: &Network) -> Result<(), GatewayError> {
        match m {
            Inbound::Token(zid, alive) => {
                tracing::info!(operator = %zid, "operator session {}", if alive { "joined" } else { "ended" });
                if let Some(stop) = self.link.token(&zid, alive) {
                    self.stopped(stop, &zid)?;
                }
            }
            Inbound::Sample(zid, Err(e)) => {
                self.hb.status_mut().faults += 1;
                tracing::warn!(operator = %zid, "operator sample refused: {e}");
            }
            Inbound::Sample(zid, Ok(s)) => {
                self.operator_sample(&zid, &s, net)?;
            }
            Inbound::Estop(c) => self.estop_request(c)?,
            Inbound::JoyPublisher(alive) => self.joy_publisher(alive)?,
            Inbound::Joy(Err(e)) => {
                self.hb.status_mut().faults += 1;
                tracing::warn!("/joy message refused: {e}");
            }
            Inbound::Joy(Ok(joy)) => self.joy(&joy, net)?,
        }
        Ok(())
    }

    fn joy_publisher(&mut self, alive: bool) -> Result<(), GatewayError> {
        let Some(j) = self.joy.as_mut() else {
            return Ok(());
        };
        if alive {
            if j.publishers == 0 {
                j.generation += 1;
                j.last = None;
                let id = j.session();
                tracing::info!("a ROS 2 /joy publisher joined ({id})");
                self.link.token(&id, true);
            }
            j.publishers += 1;
        } else if j.publishers > 0 {
            j.publishers -= 1;
            if j.publishers == 0 {
                j.last = None;
                let id = j.session();
                if let Some(stop) = self.link.token(&id, false) {
                    self.stopped(stop, &id)?;
                }
            }
        }
        Ok(())
    }

    /// A `/joy` message: the operator's input now, answering the newest tick.
    fn joy(&mut self, joy: &scl_net::ros2::Joy, net: &Network) -> Result<(), GatewayError> {
        let Some(j) = self.joy.as_mut() else {
            return Ok(());
        };
        let (axes, bits) = match j.map.apply(joy) {
            Ok(m) => m,
            Err(e) => {
                self.hb.status_mut().faults += 1;
                tracing::warn!("/joy message refused: {e}");
                return Ok(());
            }
        };
        let sample = JoystickInput {
            tick: self.hb.status().tick,
            t_ns: 0,
            seq: j.seq,
            axes,
            gripper: 0.0,
            buttons: bits,
        };
        j.seq += 1;
        j.last = Some((std::time::Instant::now(), sample));
        let press = bits & ipc_types::buttons::ESTOP != 0 && !j.estop_held;
        j.estop_held = bits & ipc_types::buttons::ESTOP != 0;
        let id = j.session();
        if press {
            self.estop_request(Ok(EstopCommand {
                t_ns: now_ns(),
                action: estop_action::ESTOP,
                source_pid: 0,
            }))?;
        }
        self.operator_sample(&id, &sample, net)?;
        Ok(())
    }

    /// Judges and, if it passes, forwards an operator's sample; true if forwarded.
    fn operator_sample(
        &mut self,
        zid: &str,
        s: &JoystickInput,
        net: &Network,
    ) -> Result<bool, GatewayError> {
        match self.link.sample(zid, s) {
            Ok(s) => {
                self.publish_sample(s)?;
                self.count(gateway_counts::FORWARDED);
                self.send_out(net, Outbound::Gateway(self.gateway_status()));
                Ok(true)
            }
            Err(r) => {
                self.hb.status_mut().faults += 1;
                self.refused(zid, r);
                Ok(false)
            }
        }
    }

    fn refused(&self, zid: &str, r: Refusal) {
        // Refusals come at the sample rate: log the first of each kind in a run of them.
        let n = self.hb.status().faults;
        if n.is_power_of_two() {
            tracing::warn!(operator = %zid, refused = n, "operator sample refused: {}", r.name());
        }
    }

    fn stopped(&mut self, stop: Stop, zid: &str) -> Result<(), GatewayError> {
        match stop {
            Stop::LinkLost => {
                tracing::warn!(operator = %zid, "operator link lost: the arm stops; a new session and neutral input resume");
                self.count(gateway_counts::LINK_LOSSES);
                // Stand in at once, answering the newest tick: the arm stops at the next one.
                let tick = self.hb.status().tick;
                if tick != ipc_types::NO_TICK {
                    self.publish_sample(OperatorLink::placeholder(tick, 0))?;
                }
            }
            Stop::Stale => {
                tracing::warn!(operator = %zid, "operator input stale: the arm stops; neutral input resumes");
                self.count(gateway_counts::STALE_STOPS);
            }
        }
        Ok(())
    }

    fn estop_request(&mut self, c: Result<EstopCommand, DecodeError>) -> Result<(), GatewayError> {
        let c = match c {
            Ok(c) => c,
            Err(e) => {
                tracing::warn!("e-stop request refused: {e}");
                return Ok(());
            }
        };
        let refusal = match c.action {
            estop_action::ESTOP => None,
            estop_action::RESET if self.cfg.network.accept_reset => None,
            estop_action::RESET => Some(Refusal::ResetNotAccepted),
            _ => Some(Refusal::UnknownAction),
        };
        if let Some(r) = refusal {
            tracing::warn!("network e-stop request refused: {}", r.name());
            return Ok(());
        }
        let Some(p) = &self.estop else {
            return Ok(());
        };
        let reset = c.action == estop_action::RESET;
        tracing::warn!(
            "{} from the network: sent to safety",
            if reset { "reset" } else { "E-STOP" }
        );
        p.send(EstopCommand {
            t_ns: now_ns(),
            action: c.action,
            source_pid: std::process::id(),
        })?;
        self.count(if reset {
            gateway_counts::RESETS
        } else {
            gateway_counts::ESTOPS
        });
        Ok(())
    }

    fn tick(&mut self, s: &RobotState, net: &Network) -> Result<(), GatewayError> {
        self.hb.status_mut().tick = s.tick;
        if self.cfg.network.accept_joystick {
            let (stop, mut stand_in) = self.link.tick(s.tick);
            if let Some(stop) = stop {
                self.stopped(stop, "driving")?;
            }
            // A `/joy` operator's last input answers this tick while it is fresh.
            let fresh = self.joy.as_ref().and_then(|j| {
                j.last
                    .filter(|(at, _)| at.elapsed() <= j.timeout)
                    .map(|(_, last)| (j.session(), last))
            });
            if let Some((id, last)) = fresh {
                let answer = JoystickInput {
                    tick: s.tick,
                    ..last
                };
                if self.operator_sample(&id, &answer, net)? {
                    stand_in = false;
                }
            }
            if stand_in {
                self.publish_sample(OperatorLink::placeholder(s.tick, 0))?;
                self.count(gateway_counts::STOOD_IN);
            }
        }
        let st = self.hb.status_mut();
        st.handled += 1;
        st.t_ns = now_ns();
        st.rule_counts[gateway_counts::OUTBOUND_DROPPED] =
            u32::try_from(self.outbound_dropped).unwrap_or(u32::MAX);
        st.rule_counts[gateway_counts::INBOUND_DROPPED] =
            u32::try_from(self.inbound_dropped.load(Ordering::Relaxed)).unwrap_or(u32::MAX);
        st.rule_counts[gateway_counts::LINK] = self.link.status().link;
        self.send_out(net, Outbound::Gateway(self.gateway_status()));
        Ok(())
    }

    fn gateway_status(&self) -> GatewayStatus {
        GatewayStatus {
            t_ns: now_ns(),
            outbound_dropped: self.outbound_dropped,
            ..self.link.status()
        }
    }

    fn send_out(&mut self, net: &Network, m: Outbound) {
        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) = net.out.try_send(m) {
            self.outbound_dropped += 1;
        }
    }
}

/// The captures of what each mapper and safety process runs, made on a capture thread (at a
/// low priority: it reads the model files) when the process's first heartbeat arrives, and
/// served on `NS/process/<pid>`.
struct Captures {
    /// Processes seen, to the capture thread (rare: unbounded; never waits).
    tx: Option<Sender<(NodeStatus, ipc_types::NodeRole)>>,
    seen: graph_client::process::NewProcesses,
    kept: Arc<std::sync::Mutex<Kept>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// The captures kept, newest last, and the keys they answer.
#[derive(Default)]
struct Kept {
    captures: std::collections::VecDeque<(String, Arc<Vec<u8>>)>,
}

impl Kept {
    /// Keeps `bytes` for `key`, the oldest going beyond [`KEPT_CAPTURES`].
    fn keep(&mut self, key: String, bytes: Arc<Vec<u8>>) {
        self.captures.retain(|(k, _)| *k != key);
        self.captures.push_back((key, bytes));
        while self.captures.len() > KEPT_CAPTURES {
            self.captures.pop_front();
        }
    }

    /// The captures whose key `query` matches.
    fn answers(&self, query: &scl_net::zenoh::key_expr::KeyExpr<'_>) -> Vec<ports::Answer> {
        self.captures
            .iter()
            .filter(|(k, _)| {
                scl_net::zenoh::key_expr::KeyExpr::try_from(k.as_str())
                    .is_ok_and(|k| query.intersects(&k))
            })
            .map(|(k, b)| ports::Answer {
                key: k.clone(),
                encoding: scl_net::wire::PROCESS_CAPTURE.to_owned(),
                bytes: Arc::clone(b),
            })
            .collect()
    }
}

impl Captures {
    fn start(keys: &Keys) -> Result<Self, GatewayError> {
        let (tx, rx) = crossbeam_channel::unbounded::<(NodeStatus, ipc_types::NodeRole)>();
        let kept = Arc::new(std::sync::Mutex::new(Kept::default()));
        let (k2, keys) = (Arc::clone(&kept), keys.clone());
        let thread = std::thread::Builder::new()
            .name("gateway-capture".into())
            .spawn(move || {
                node_rt::rt::lower_priority();
                while let Ok((st, role)) = rx.recv() {
                    let seen = graph_client::process::ProcessSeen::of(&st, role);
                    match graph_client::process::capture_bytes(&seen) {
                        Ok(bytes) => {
                            tracing::debug!(
                                pid = st.pid,
                                role = role.name(),
                                bytes = bytes.len(),
                                "process captured"
                            );
                            if let Ok(mut k) = k2.lock() {
                                k.keep(keys.process(st.pid), Arc::new(bytes));
                            }
                        }
                        Err(e) => tracing::warn!(
                            pid = st.pid,
                            "cannot capture what process {} runs: {e}",
                            st.pid
                        ),
                    }
                }
            })
            .map_err(|source| GatewayError::Thread {
                what: "capture thread",
                source,
            })?;
        Ok(Self {
            tx: Some(tx),
            seen: graph_client::process::NewProcesses::default(),
            kept,
            thread: Some(thread),
        })
    }

    /// Notes the process a heartbeat comes from; a mapper or safety process seen for the
    /// first time is captured.
    fn note(&mut self, st: &NodeStatus) {
        if let Some(role) = self.seen.first(st)
            && let Some(tx) = &self.tx
        {
            let _ = tx.send((*st, role));
        }
    }

    /// The queryable on `NS/process/*`.
    fn serve(
        &self,
        session: &scl_net::zenoh::Session,
        keys: &Keys,
    ) -> Result<scl_net::zenoh::query::Queryable<()>, GatewayError> {
        let kept = Arc::clone(&self.kept);
        Ok(ports::serve(session, keys.process_all(), move |q| {
            kept.lock().map(|k| k.answers(q)).unwrap_or_default()
        })?)
    }
}

impl Drop for Captures {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Runs the gateway of graph `prefix` until a shutdown is requested.
pub fn run(prefix: &Prefix, cfg: &GraphConfig) -> Result<(), GatewayError> {
    cfg.network.validate()?;
    let net_cfg = &cfg.network;
    let creds = if net_cfg.credentials.is_empty() {
        None
    } else {
        Some(Credentials::load(Path::new(&net_cfg.credentials))?)
    };
    let keys = Keys::new(&net_cfg.namespace_for(prefix.as_str()));
    let graph = Graph::join_with(prefix, "gateway", cfg.graph.transport)?;
    let states = graph.robot_state_subscriber(true)?;
    let others: Vec<Topic> = Topic::ALL
        .into_iter()
        .filter(|&t| t != Topic::RobotState)
        .collect();
    let others = Observers::open(&graph, &others)?;
    let reports = graph.tick_report_subscriber()?;
    let heartbeat = graph.status_publisher()?;
    let joystick = if net_cfg.accept_joystick {
        Some(graph.joystick_publisher()?)
    } else {
        None
    };
    let estop = if net_cfg.inbound() {
        Some(graph.estop_publisher()?)
    } else {
        None
    };
    let waker = Arc::new(Waker::new().map_err(|source| GatewayError::Thread {
        what: "inbound wake-up",
        source,
    })?);
    let (in_tx, in_rx) = crossbeam_channel::bounded(INBOUND_QUEUE);
    let inbound_dropped = Arc::new(AtomicU64::new(0));
    let inbound = InboundTx {
        tx: in_tx,
        waker: Arc::clone(&waker),
        dropped: Arc::clone(&inbound_dropped),
    };
    let mut captures = Captures::start(&keys)?;
    let net = Network::open(cfg, &keys, creds.as_ref(), &inbound, &captures)?;
    let mut gw = Gateway {
        cfg,
        link: OperatorLink::new(),
        joystick,
        estop,
        seq: 0,
        hb: Heartbeat::ready(&heartbeat, NodeRole::Gateway, |_| {})?,
        outbound_dropped: 0,
        inbound_dropped,
        joy: net_cfg.ros2_joy.then(|| JoyOperator::new(net_cfg)),
    };
    tracing::info!(
        namespace = keys.namespace(),
        listen = ?net_cfg.listen,
        connect = ?net_cfg.connect,
        joystick = net_cfg.accept_joystick,
        reset = net_cfg.accept_reset,
        "gateway up"
    );
    while !signals::stop_requested() {
        let wakes: [&dyn Wakeable; 2] = [&states, &*waker];
        transport::wait_any(&wakes, Duration::from_millis(100));
        let mut newest = None;
        states.drain(|s| {
            newest = Some(*s);
            gw.send_out(&net, Outbound::Graph(Payload::RobotState(*s)));
        })?;
        if let Some(s) = newest {
            gw.tick(&s, &net)?;
            gw.hb.beat()?;
        }
        while let Ok(m) = in_rx.try_recv() {
            gw.inbound(m, &net)?;
        }
        others.drain(|m| {
            if let Payload::Status(s) = &m {
                captures.note(s);
            }
            gw.send_out(&net, Outbound::Graph(m));
        })?;
        reports.drain(|r| gw.send_out(&net, Outbound::Report(*r)))?;
    }
    let handled = gw.hb.status().handled;
    let _ = gw.hb.stop();
    drop(net);
    drop(captures);
    log_cpu_time(handled);
    Ok(())
}

/// Logs the process's CPU time over the `ticks` it handled.
fn log_cpu_time(ticks: u64) {
    if let Some(cpu) = process_cpu_s()
        && ticks > 0
    {
        tracing::info!(
            ticks,
            cpu_s = format!("{cpu:.2}"),
            per_tick_us = format!("{:.0}", cpu * 1e6 / ticks as f64),
            "gateway CPU time (every thread, Zenoh's included)"
        );
    }
}

/// The stamp a forwarded sample carries: the arrival time `now`, or with `keep` (the operator
/// shares this machine's clock: `[network] keep_operator_stamps`) its own `t_ns`, unless that
/// is missing (0: a stand-in) or from the future.
fn forwarded_stamp(keep: bool, t_ns: u64, now: u64) -> u64 {
    if keep && t_ns != 0 && t_ns <= now {
        t_ns
    } else {
        now
    }
}

/// The process's CPU time so far (s), every thread: its CPU-time clock, as `scl bench`
/// reads the graph's processes.
fn process_cpu_s() -> Option<f64> {
    use nix::time::{ClockId, clock_gettime};
    let t = clock_gettime(ClockId::CLOCK_PROCESS_CPUTIME_ID).ok()?;
    Some(t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn captures_answer_the_keys_a_query_matches_and_the_oldest_go() {
        let keys = Keys::new("scl/g");
        let mut k = Kept::default();
        for pid in 0..(KEPT_CAPTURES as u32 + 2) {
            k.keep(keys.process(pid), Arc::new(vec![pid as u8]));
        }
        let q = |s: &str| scl_net::zenoh::key_expr::KeyExpr::try_from(s.to_owned()).unwrap();
        assert!(k.answers(&q(&keys.process(0))).is_empty());
        assert!(k.answers(&q(&keys.process(1))).is_empty());
        let a = k.answers(&q(&keys.process(5)));
        assert_eq!(a.len(), 1);
        assert_eq!(
            (a[0].key.as_str(), a[0].bytes.as_slice()),
            ("scl/g/process/5", &[5u8][..])
        );
        assert_eq!(a[0].encoding, scl_net::wire::PROCESS_CAPTURE);
        assert_eq!(k.answers(&q(&keys.process_all())).len(), KEPT_CAPTURES);
        assert!(k.answers(&q("scl/h/process/5")).is_empty());
        // Kept again: one capture per key, now the newest.
        k.keep(keys.process(5), Arc::new(vec![9]));
        assert_eq!(k.answers(&q(&keys.process_all())).len(), KEPT_CAPTURES);
        assert_eq!(
            k.answers(&q(&keys.process(5)))[0].bytes.as_slice(),
            &[9u8][..]
        );
    }

    #[test]
    fn a_sample_is_stamped_on_arrival_unless_its_own_stamp_is_kept() {
        assert_eq!(forwarded_stamp(false, 90, 100), 100);
        assert_eq!(forwarded_stamp(true, 90, 100), 90);
        // A stand-in (no stamp) and a stamp from the future take the arrival time.
        assert_eq!(forwarded_stamp(true, 0, 100), 100);
        assert_eq!(forwarded_stamp(true, 101, 100), 100);
    }

    #[test]
    fn neutral_is_safetys_neutral() {
        assert_eq!(
            scl_net::link::NEUTRAL_MAX_ACTION,
            safety::restart::NEUTRAL_MAX_ACTION
        );
    }
}
