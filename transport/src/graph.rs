//! The one place that opens every service of a graph, with its settings.
//!
//! Each topic is a publish-subscribe service for the data plus, on the data plane and for the
//! log records, an event service of the same name with `/event` appended, which wakes the
//! processes that react to the topic (the control plane's topics have none: their readers
//! drain them each tick). Each topic's settings (history, buffer sizes, how many publishers
//! may exist) and plane are its [`TopicDef`] constant, from the one table
//! `ipc_types::for_each_topic!`, so every process opens every service identically.
//!
//! The graph's [`Prefix`] is used twice: in every service name (`lab2/robot_state`) and as the
//! file-name prefix of every shared-memory resource (`scl_lab2_…`), so two graphs never see
//! each other and a test can check that it left nothing behind.

use core::time::Duration;

use iceoryx2::config::Config;
use iceoryx2::node::{NodeCreationFailure, NodeState, NodeView};
use iceoryx2::port::client::RequestSendError;
use iceoryx2::port::listener::{Listener, ListenerCreateError, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::{Subscriber, SubscriberCreateError};
use iceoryx2::port::{LoanError, ReceiveError, SendError};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError;
use iceoryx2::service::builder::request_response::RequestResponseOpenOrCreateError;
use iceoryx2::service::port_factory::client::ClientCreateError;
use iceoryx2::service::port_factory::server::ServerCreateError;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use iceoryx2::service::service_name::ServiceNameError;
use iceoryx2_cal::named_concept::NamedConceptRemoveError;
use ipc_types::topics::{
    JOYSTICK, LOG, MAPPER_COMMAND, ROBOT_STATE, SAFE_COMMAND, STATUS, TICK_REPORT,
};
use ipc_types::{
    JoystickInput, LogRecord, MapperCommand, NodeStatus, Prefix, RobotState, SafeCommand,
    TickReport, Transport,
};
use ipc_types::{Plane, TopicDef, TopicSettings};

use crate::uds::Datagram;

/// The iceoryx2 service variant of every graph: inter-process.
pub type Ipc = iceoryx2::service::ipc::Service;

/// Errors of opening or using the graph's shared-memory services. Each keeps the error of
/// iceoryx2 (or of the socket transport) as its typed source, so a caller can tell the cases
/// apart (a second publisher refused: [`IpcError::Port`] with
/// [`PortError::Publisher`]`(`[`PublisherCreateError::ExceedsMaxSupportedPublishers`]`)`).
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// The iceoryx2 node of this process could not be created.
    #[error("cannot create the iceoryx2 node `{node}`: {source}")]
    Node {
        /// Node name.
        node: String,
        /// What iceoryx2 said.
        source: NodeError,
    },
    /// A service could not be opened or created, e.g. because another graph opened it with
    /// other message types or settings.
    #[error("cannot open service `{service}`: {source}")]
    Open {
        /// Full service name.
        service: String,
        /// What iceoryx2 said.
        source: OpenError,
    },
    /// A publisher, subscriber, notifier or listener could not be created. For the
    /// `safe_command` publisher this is how a second safety process is refused.
    #[error("cannot create a {port} on `{service}`: {source}")]
    Port {
        /// Full service name.
        service: String,
        /// Which port.
        port: &'static str,
        /// What iceoryx2 or the socket transport said.
        source: PortError,
    },
    /// Sending, receiving or notifying failed.
    #[error("{op} failed on `{service}`: {source}")]
    Io {
        /// Full service name.
        service: String,
        /// The operation.
        op: &'static str,
        /// What went wrong.
        source: IoError,
    },
}

/// Why this process's iceoryx2 node could not be created ([`IpcError::Node`]).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// The graph prefix is not a valid file name.
    #[error("prefix is not a valid file name: {0:?}")]
    Prefix(#[source] SemanticStringError),
    /// The node name is not valid.
    #[error("{0:?}")]
    Name(#[source] SemanticStringError),
    /// iceoryx2 refused the node.
    #[error(transparent)]
    Create(#[from] NodeCreationFailure),
}

/// Why a service could not be opened or created ([`IpcError::Open`]).
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The service name is not valid.
    #[error("{0:?}")]
    Name(#[source] ServiceNameError),
    /// A publish-subscribe service.
    #[error(transparent)]
    PublishSubscribe(#[from] PublishSubscribeOpenOrCreateError),
    /// An event service.
    #[error(transparent)]
    Event(#[from] EventOpenOrCreateError),
    /// A request-response service.
    #[error(transparent)]
    RequestResponse(#[from] RequestResponseOpenOrCreateError),
}

/// Why a port could not be created ([`IpcError::Port`]).
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    /// A publisher (`ExceedsMaxSupportedPublishers`: the topic's publishers are all taken).
    #[error(transparent)]
    Publisher(#[from] PublisherCreateError),
    /// A subscriber.
    #[error(transparent)]
    Subscriber(#[from] SubscriberCreateError),
    /// A notifier.
    #[error(transparent)]
    Notifier(#[from] NotifierCreateError),
    /// A listener.
    #[error(transparent)]
    Listener(#[from] ListenerCreateError),
    /// A request-response server.
    #[error(transparent)]
    Server(#[from] ServerCreateError),
    /// A request-response client.
    #[error(transparent)]
    Client(#[from] ClientCreateError),
    /// A socket of the socket transport.
    #[error(transparent)]
    Socket(#[from] crate::uds::UdsError),
}

/// Why sending, receiving, notifying or waiting failed ([`IpcError::Io`]).
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A sample could not be loaned.
    #[error(transparent)]
    Loan(#[from] LoanError),
    /// A sample could not be sent.
    #[error(transparent)]
    Send(#[from] SendError),
    /// A sample could not be received.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// The listeners could not be notified.
    #[error(transparent)]
    Notify(#[from] NotifierNotifyError),
    /// Waiting for the topic's event failed.
    #[error(transparent)]
    Wait(#[from] ListenerWaitError),
    /// A request could not be sent.
    #[error(transparent)]
    Request(#[from] RequestSendError),
    /// The socket transport failed.
    #[error(transparent)]
    Socket(#[from] crate::uds::UdsError),
    /// The domain's management segment could not be removed.
    #[error("{0:?}")]
    Release(#[source] NamedConceptRemoveError),
    /// No supervisor serves the graph.
    #[error("no supervisor is serving this graph (is `scl up` running with this prefix?)")]
    NoServer,
    /// The supervisor did not answer in time.
    #[error("no answer within {0:?}")]
    NoAnswer(Duration),
}

/// A process's membership in one graph: its iceoryx2 node, the graph prefix and the
/// transport of its data-plane topics.
pub struct Graph {
    node: Node<Ipc>,
    prefix: Prefix,
    config: Config,
    transport: Transport,
}

impl std::fmt::Debug for Graph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Graph")
            .field("prefix", &self.prefix)
            .finish()
    }
}

/// The iceoryx2 configuration of the graph with prefix `prefix`: defaults, with every file
/// name prefixed by [`Prefix::file_prefix`].
pub fn config_for(prefix: &Prefix) -> Result<Config, IpcError> {
    let mut config = Config::default();
    config.global.prefix =
        FileName::new(prefix.file_prefix().as_bytes()).map_err(|e| IpcError::Node {
            node: prefix.to_string(),
            source: NodeError::Prefix(e),
        })?;
    Ok(config)
}

impl Graph {
    /// Joins the graph `prefix` as a node called `name` (e.g. `mapper-1`), with iceoryx2 for
    /// every topic. Signal handling is left to the process (iceoryx2's own handlers are
    /// disabled).
    pub fn join(prefix: &Prefix, name: &str) -> Result<Self, IpcError> {
        Self::join_with(prefix, name, Transport::Iceoryx2)
    }

    /// Joins the graph with the data-plane topics on `transport`.
    pub fn join_with(prefix: &Prefix, name: &str, transport: Transport) -> Result<Self, IpcError> {
        let config = config_for(prefix)?;
        let node_err = |source: NodeError| IpcError::Node {
            node: name.to_owned(),
            source,
        };
        let node_name = NodeName::new(name).map_err(|e| node_err(NodeError::Name(e)))?;
        let node = NodeBuilder::new()
            .config(&config)
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| node_err(e.into()))?;
        Ok(Self {
            node,
            prefix: prefix.clone(),
            config,
            transport,
        })
    }

    /// The transport of the data-plane topics.
    pub fn transport(&self) -> Transport {
        self.transport
    }

    fn uds_dir(&self, s: &TopicSettings) -> std::path::PathBuf {
        crate::uds::topic_dir(self.prefix.as_str(), s.name)
    }

    fn uds_err(&self, s: &TopicSettings, port: &'static str, e: crate::uds::UdsError) -> IpcError {
        IpcError::Port {
            service: self.prefix.service(s.name),
            port,
            source: e.into(),
        }
    }

    /// The graph prefix.
    pub fn prefix(&self) -> &Prefix {
        &self.prefix
    }

    /// The iceoryx2 node (for the control plane in this crate).
    pub(crate) fn node(&self) -> &Node<Ipc> {
        &self.node
    }

    pub(crate) fn pubsub<T: ZeroCopySend + core::fmt::Debug + Copy>(
        &self,
        s: &TopicSettings,
    ) -> Result<(String, publish_subscribe::PortFactory<Ipc, T, ()>), IpcError> {
        let full = self.prefix.service(s.name);
        let name = ServiceName::new(&full).map_err(|e| IpcError::Open {
            service: full.clone(),
            source: OpenError::Name(e),
        })?;
        let factory = self
            .node
            .service_builder(&name)
            .publish_subscribe::<T>()
            .history_size(s.history)
            .subscriber_max_buffer_size(s.buffer.max(s.history))
            .enable_safe_overflow(true)
            .max_publishers(s.max_publishers)
            .max_subscribers(s.max_subscribers)
            .open_or_create()
            .map_err(|e| IpcError::Open {
                service: full.clone(),
                source: e.into(),
            })?;
        Ok((full, factory))
    }

    fn event(&self, s: &TopicSettings) -> Result<(String, event::PortFactory<Ipc>), IpcError> {
        let full = format!("{}/event", self.prefix.service(s.name));
        let name = ServiceName::new(&full).map_err(|e| IpcError::Open {
            service: full.clone(),
            source: OpenError::Name(e),
        })?;
        let factory = self
            .node
            .service_builder(&name)
            .event()
            .max_notifiers(s.max_publishers)
            .max_listeners(s.max_subscribers)
            .open_or_create()
            .map_err(|e| IpcError::Open {
                service: full.clone(),
                source: e.into(),
            })?;
        Ok((full, factory))
    }

    fn publisher<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        s: &TopicSettings,
    ) -> Result<TopicPublisher<T>, IpcError> {
        if self.transport == Transport::Uds {
            let p = crate::uds::UdsPublisher::new(&self.uds_dir(s))
                .map_err(|e| self.uds_err(s, "publisher", e))?;
            return Ok(TopicPublisher {
                service: self.prefix.service(s.name),
                inner: PubInner::Uds(std::cell::RefCell::new(p)),
            });
        }
        self.iox_publisher(s, true)
    }

    /// An iceoryx2 publisher; `notify` adds a notifier on the topic's event (the control
    /// topics have none: nobody waits on them).
    fn iox_publisher<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        s: &TopicSettings,
        notify: bool,
    ) -> Result<TopicPublisher<T>, IpcError> {
        let (service, data) = self.pubsub::<T>(s)?;
        let publisher = data
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "publisher",
                source: e.into(),
            })?;
        let notifier = if notify {
            let (_, ev) = self.event(s)?;
            Some(ev.notifier_builder().create().map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "notifier",
                source: e.into(),
            })?)
        } else {
            None
        };
        Ok(TopicPublisher {
            service,
            inner: PubInner::Iox {
                publisher,
                notifier,
            },
        })
    }

    fn subscriber<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        s: &TopicSettings,
        wake: bool,
    ) -> Result<TopicSubscriber<T>, IpcError> {
        if self.transport == Transport::Uds {
            let sub = crate::uds::UdsSubscriber::new(&self.uds_dir(s))
                .map_err(|e| self.uds_err(s, "subscriber", e))?;
            return Ok(TopicSubscriber {
                service: self.prefix.service(s.name),
                inner: SubInner::Uds(sub),
            });
        }
        self.iox_subscriber(s, wake)
    }

    fn iox_subscriber<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        s: &TopicSettings,
        wake: bool,
    ) -> Result<TopicSubscriber<T>, IpcError> {
        let (service, data) = self.pubsub::<T>(s)?;
        let subscriber = data
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "subscriber",
                source: e.into(),
            })?;
        let listener = if wake {
            let (_, ev) = self.event(s)?;
            Some(ev.listener_builder().create().map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "listener",
                source: e.into(),
            })?)
        } else {
            None
        };
        Ok(TopicSubscriber {
            service,
            inner: SubInner::Iox {
                subscriber,
                listener,
            },
        })
    }

    /// A publisher on `topic`, on the plane it travels: the data plane's transport (with a
    /// wake-up notifier on iceoryx2), or iceoryx2 (the log records with a notifier, the
    /// control plane without). Every topic of [`ipc_types::for_each_topic!`] opens through
    /// this and [`Graph::subscriber_of`]; the named constructors below are these for one
    /// topic.
    pub fn publisher_of<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        topic: &TopicDef<T>,
    ) -> Result<TopicPublisher<T>, IpcError> {
        match topic.plane {
            Plane::Data => self.publisher(topic),
            Plane::Iceoryx2 => self.iox_publisher(topic, true),
            Plane::Control => self.iox_publisher(topic, false),
        }
    }

    /// A subscriber of `topic`; `wake` attaches a listener to its event so the caller can
    /// block until the next sample (ignored on the control plane, which has none).
    pub fn subscriber_of<T: ZeroCopySend + core::fmt::Debug + Datagram>(
        &self,
        topic: &TopicDef<T>,
        wake: bool,
    ) -> Result<TopicSubscriber<T>, IpcError> {
        match topic.plane {
            Plane::Data => self.subscriber(topic, wake),
            Plane::Iceoryx2 => self.iox_subscriber(topic, wake),
            Plane::Control => self.iox_subscriber(topic, false),
        }
    }

    /// Publisher of joystick samples. Fails with [`IpcError::Port`] if another process
    /// already publishes them: the topic admits one operator.
    pub fn joystick_publisher(&self) -> Result<TopicPublisher<JoystickInput>, IpcError> {
        self.publisher_of(&JOYSTICK)
    }
    /// Subscriber of joystick samples; `wake` attaches a listener (the mapper takes samples
    /// as they arrive).
    pub fn joystick_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<JoystickInput>, IpcError> {
        self.subscriber_of(&JOYSTICK, wake)
    }
    /// Publisher of robot states (the bridge).
    pub fn robot_state_publisher(&self) -> Result<TopicPublisher<RobotState>, IpcError> {
        self.publisher_of(&ROBOT_STATE)
    }
    /// Subscriber of robot states; `wake` attaches a listener so the caller can block until
    /// the next tick.
    pub fn robot_state_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<RobotState>, IpcError> {
        self.subscriber_of(&ROBOT_STATE, wake)
    }
    /// How many processes wait on robot states (listeners of the topic's event): each is a
    /// wake-up the bridge pays on every tick. Always 0 over [`Transport::Uds`], whose
    /// subscribers are woken by the datagram itself.
    pub fn robot_state_listeners(&self) -> Result<usize, IpcError> {
        if self.transport == Transport::Uds {
            return Ok(0);
        }
        use iceoryx2::service::port_factory::PortFactory;
        let (_, ev) = self.event(&ROBOT_STATE)?;
        Ok(ev.dynamic_config().number_of_listeners())
    }
    /// Publisher of mapper commands.
    pub fn mapper_command_publisher(&self) -> Result<TopicPublisher<MapperCommand>, IpcError> {
        self.publisher_of(&MAPPER_COMMAND)
    }
    /// Subscriber of mapper commands (safety wakes on them).
    pub fn mapper_command_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<MapperCommand>, IpcError> {
        self.subscriber_of(&MAPPER_COMMAND, wake)
    }
    /// Publisher of the executed command. Fails with [`IpcError::Port`] if another process
    /// already publishes it: the arm listens to one safety process only.
    pub fn safe_command_publisher(&self) -> Result<TopicPublisher<SafeCommand>, IpcError> {
        self.publisher_of(&SAFE_COMMAND)
    }
    /// Subscriber of executed commands (the bridge wakes on them).
    pub fn safe_command_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<SafeCommand>, IpcError> {
        self.subscriber_of(&SAFE_COMMAND, wake)
    }
    /// Publisher of the bridge's per-tick timing report.
    pub fn tick_report_publisher(&self) -> Result<TopicPublisher<TickReport>, IpcError> {
        self.publisher_of(&TICK_REPORT)
    }
    /// Subscriber of the bridge's per-tick timing reports (benchmarks, recorders).
    pub fn tick_report_subscriber(&self) -> Result<TopicSubscriber<TickReport>, IpcError> {
        self.subscriber_of(&TICK_REPORT, false)
    }
    /// Publisher of this node's heartbeat.
    pub fn status_publisher(&self) -> Result<TopicPublisher<NodeStatus>, IpcError> {
        self.publisher_of(&STATUS)
    }
    /// Subscriber of every node's heartbeat.
    pub fn status_subscriber(&self) -> Result<TopicSubscriber<NodeStatus>, IpcError> {
        self.subscriber_of(&STATUS, false)
    }

    /// Publisher of this process's log records (always iceoryx2, whatever the data plane's
    /// transport). Fails with [`IpcError::Port`] when the topic has all the publishers it
    /// admits.
    pub fn log_publisher(&self) -> Result<TopicPublisher<LogRecord>, IpcError> {
        self.publisher_of(&LOG)
    }
    /// Subscriber of every process's log records (`scl live`), with the last few at once.
    pub fn log_subscriber(&self) -> Result<TopicSubscriber<LogRecord>, IpcError> {
        self.subscriber_of(&LOG, false)
    }

    /// Removes the resources that dead processes of this graph left behind (a SIGKILLed
    /// child cannot clean up after itself). Returns how many dead nodes were cleaned.
    pub fn cleanup_dead_nodes(&self) -> usize {
        self.node.try_cleanup_dead_nodes().cleanups as usize
    }

    /// Names and process ids of the live nodes of this graph.
    pub fn alive_nodes(&self) -> Vec<(String, u32)> {
        let mut out = Vec::new();
        let _ = Node::<Ipc>::list(&self.config, |state| {
            if let NodeState::Alive(view) = state
                && let Some(d) = view.details().as_ref()
            {
                out.push((d.name().to_string(), d.process_id().value() as u32));
            }
            CallbackProgression::Continue
        });
        out
    }
}

/// Removes the resources of every dead node of graph `prefix` without joining it.
pub fn cleanup_dead_nodes(prefix: &Prefix) -> Result<usize, IpcError> {
    let config = config_for(prefix)?;
    let mut cleaned = 0;
    let _ = Node::<Ipc>::list(&config, |state| {
        if let NodeState::Dead(view) = state
            && view.try_remove_stale_resources().is_ok()
        {
            cleaned += 1;
        }
        CallbackProgression::Continue
    });
    Ok(cleaned)
}

/// How many processes of graph `prefix` are alive and how many are dead (left resources
/// behind), without joining it or changing anything.
pub fn census(prefix: &Prefix) -> Result<(usize, usize), IpcError> {
    let config = config_for(prefix)?;
    let (mut alive, mut dead) = (0, 0);
    let _ = Node::<Ipc>::list(&config, |state| {
        match state {
            NodeState::Alive(_) => alive += 1,
            NodeState::Dead(_) => dead += 1,
            _ => {}
        }
        CallbackProgression::Continue
    });
    Ok((alive, dead))
}

/// Releases graph `prefix`'s domain once no process of it is alive: removes what dead
/// processes left behind and the domain's global management segment (a node counter that
/// iceoryx2 keeps for the life of a domain). Returns whether the domain was released; it is
/// not while any node of the graph is alive.
pub fn release_domain(prefix: &Prefix) -> Result<bool, IpcError> {
    cleanup_dead_nodes(prefix)?;
    let config = config_for(prefix)?;
    let mut alive = 0;
    let _ = Node::<Ipc>::list(&config, |state| {
        if let NodeState::Alive(_) = state {
            alive += 1;
        }
        CallbackProgression::Continue
    });
    if alive > 0 {
        return Ok(false);
    }
    // SAFETY: no node of this domain is alive (checked just above), and every process of the
    // graph joins through `Graph::join`; the segment is recreated by the next node.
    unsafe { iceoryx2::testing::remove_global_mgmt_segment::<Ipc>(&config) }.map_err(|e| {
        IpcError::Io {
            service: prefix.to_string(),
            op: "release domain",
            source: IoError::Release(e),
        }
    })
}

/// Files under `/dev/shm` and iceoryx2's directory (`/tmp/iceoryx2`) whose name holds
/// `needle`: a graph's [`Prefix::file_prefix`] finds what the graph left behind.
pub fn files_named(needle: &str) -> Vec<std::path::PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![
        std::path::PathBuf::from("/dev/shm"),
        std::path::PathBuf::from("/tmp/iceoryx2"),
    ];
    while let Some(dir) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p.clone());
            }
            if e.file_name().to_string_lossy().contains(needle) {
                found.push(p);
            }
        }
    }
    found
}

// One per port, made once per process: the size of the variants does not matter.
#[allow(clippy::large_enum_variant)]
enum PubInner<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> {
    Iox {
        publisher: Publisher<Ipc, T, ()>,
        /// The topic's event; none on the control topics, which nobody waits on.
        notifier: Option<Notifier<Ipc>>,
    },
    Uds(std::cell::RefCell<crate::uds::UdsPublisher<T>>),
}

/// A publisher that wakes the topic's listeners after each send. Its message type is also a
/// [`Datagram`], since either transport may carry it.
pub struct TopicPublisher<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> {
    service: String,
    inner: PubInner<T>,
}

impl<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> TopicPublisher<T> {
    /// Sends `msg` (iceoryx2: loan, write, send through shared memory, then notify) and
    /// returns the number of subscribers that received it.
    pub fn send(&self, msg: T) -> Result<usize, IpcError> {
        let io = |op: &'static str, source: IoError| IpcError::Io {
            service: self.service.clone(),
            op,
            source,
        };
        match &self.inner {
            PubInner::Iox {
                publisher,
                notifier,
            } => {
                let sample = publisher.loan_uninit().map_err(|e| io("loan", e.into()))?;
                let n = sample
                    .write_payload(msg)
                    .send()
                    .map_err(|e| io("send", e.into()))?;
                if let Some(notifier) = notifier {
                    notifier.notify().map_err(|e| io("notify", e.into()))?;
                }
                Ok(n)
            }
            PubInner::Uds(p) => Ok(p.borrow_mut().send(&msg)),
        }
    }

    /// Connects the subscribers that came since the last send and hands them the topic's
    /// history (iceoryx2 does so on a send, or here); best effort: a failure shows on the
    /// next send.
    pub fn update_connections(&self) {
        use iceoryx2::port::update_connections::UpdateConnections;
        if let PubInner::Iox { publisher, .. } = &self.inner {
            let _ = publisher.update_connections();
        }
    }

    /// The full service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

// One per port, made once per process: the size of the variants does not matter.
#[allow(clippy::large_enum_variant)]
enum SubInner<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> {
    Iox {
        subscriber: Subscriber<Ipc, T, ()>,
        listener: Option<Listener<Ipc>>,
    },
    Uds(crate::uds::UdsSubscriber<T>),
}

/// A subscriber with an optional wake-up listener. Its message type is also a [`Datagram`],
/// since either transport may carry it.
pub struct TopicSubscriber<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> {
    service: String,
    inner: SubInner<T>,
}

impl<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> TopicSubscriber<T> {
    /// Calls `f` with every buffered message, oldest first.
    pub fn drain(&self, mut f: impl FnMut(&T)) -> Result<usize, IpcError> {
        let err = |source: IoError| IpcError::Io {
            service: self.service.clone(),
            op: "receive",
            source,
        };
        match &self.inner {
            SubInner::Iox { subscriber, .. } => {
                let mut n = 0;
                loop {
                    match subscriber.receive() {
                        Ok(Some(sample)) => {
                            n += 1;
                            f(sample.payload());
                        }
                        Ok(None) => return Ok(n),
                        Err(e) => return Err(err(e.into())),
                    }
                }
            }
            SubInner::Uds(sub) => sub.drain(f).map_err(|e| err(e.into())),
        }
    }

    /// Whether a message is waiting, without taking it: a poll of shared memory on iceoryx2,
    /// a `ppoll` with no timeout on a socket. An error counts as `true`, so the caller's
    /// receive that follows reports it.
    pub fn has_pending(&self) -> bool {
        match &self.inner {
            SubInner::Iox { subscriber, .. } => subscriber.has_samples().unwrap_or(true),
            SubInner::Uds(sub) => crate::uds::poll_readable(&[sub.raw_fd()], Duration::ZERO) != 0,
        }
    }

    /// Blocks until the topic's event fires or the monotonic clock reaches `until_ns`, with
    /// nanosecond precision (a `ppoll` on the event's descriptor; without one, a sleep);
    /// returns whether it fired.
    pub fn wait_until(&self, until_ns: u64) -> bool {
        let d = Duration::from_nanos(until_ns.saturating_sub(ipc_types::time::now_ns()));
        wait_any(&[self as &dyn Wakeable], d) != 0
    }

    /// Drops the pending notifications of the topic's event (after an input taken by
    /// polling, so the next event wait does not wake for it).
    pub fn consume_notifications(&self) {
        self.consume();
    }

    /// The newest buffered message, discarding older ones.
    pub fn latest(&self) -> Result<Option<T>, IpcError> {
        let mut last = None;
        self.drain(|m| last = Some(*m))?;
        Ok(last)
    }

    /// Blocks until the topic's event fires or `timeout` passes; returns whether it fired.
    /// Consumes every pending notification. A signal ends the wait early (returning `false`)
    /// so the caller can check its shutdown flag. Without a listener this sleeps for
    /// `timeout`.
    pub fn wait(&self, timeout: Duration) -> Result<bool, IpcError> {
        match &self.inner {
            SubInner::Iox {
                listener: Some(l), ..
            } => match l.timed_wait(|_| {}, timeout) {
                Ok(n) => Ok(n > 0),
                Err(ListenerWaitError::InterruptSignal) => Ok(false),
                Err(e) => Err(IpcError::Io {
                    service: self.service.clone(),
                    op: "wait",
                    source: e.into(),
                }),
            },
            SubInner::Iox { listener: None, .. } => {
                std::thread::sleep(timeout);
                Ok(false)
            }
            SubInner::Uds(sub) => Ok(crate::uds::poll_readable(&[sub.raw_fd()], timeout) != 0),
        }
    }

    /// The descriptor that becomes readable when the topic's event fires, if it has one.
    fn wake_fd(&self) -> Option<i32> {
        match &self.inner {
            SubInner::Iox {
                listener: Some(l), ..
            } => {
                use iceoryx2::prelude::FileDescriptorBased;
                // SAFETY: the descriptor stays owned by the listener; it is only polled.
                Some(unsafe { l.file_descriptor().native_handle() })
            }
            SubInner::Iox { listener: None, .. } => None,
            SubInner::Uds(sub) => Some(sub.raw_fd()),
        }
    }

    /// Consumes the pending notifications of the topic's event (iceoryx2).
    fn consume(&self) {
        if let SubInner::Iox {
            listener: Some(l), ..
        } = &self.inner
        {
            let _ = l.try_wait(|_| {});
        }
    }

    /// The full service name.
    pub fn service(&self) -> &str {
        &self.service
    }
}

/// A subscriber that [`wait_any`] can wait on.
pub trait Wakeable {
    /// The descriptor to poll.
    fn fd(&self) -> Option<i32>;
    /// Consumes the pending notifications after a wake-up.
    fn consume_wake(&self);
}

impl<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> Wakeable for TopicSubscriber<T> {
    fn fd(&self) -> Option<i32> {
        self.wake_fd()
    }
    fn consume_wake(&self) {
        self.consume();
    }
}

/// An input a control-path loop polls before its event wait (`node_rt::poller::Poller`).
pub trait Pollable {
    /// Whether a message is waiting, without taking it.
    fn has_pending(&self) -> bool;
    /// Blocks until the input's event fires or the monotonic clock reaches `until_ns`;
    /// returns whether it fired.
    fn wait_until(&self, until_ns: u64) -> bool;
    /// Drops the pending notifications of the input's event.
    fn consume_notifications(&self);
}

impl<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> Pollable for TopicSubscriber<T> {
    fn has_pending(&self) -> bool {
        TopicSubscriber::has_pending(self)
    }
    fn wait_until(&self, until_ns: u64) -> bool {
        TopicSubscriber::wait_until(self, until_ns)
    }
    fn consume_notifications(&self) {
        TopicSubscriber::consume_notifications(self)
    }
}

/// An eventfd that a thread rings after handing something over (through a channel) to a loop
/// that waits on it beside its subscribers ([`wait_any`]): the joystick's reader threads, the
/// gateway's network callbacks.
#[derive(Debug)]
pub struct Waker {
    fd: nix::sys::eventfd::EventFd,
}

impl Waker {
    /// A new, unsignalled waker.
    pub fn new() -> std::io::Result<Self> {
        use nix::sys::eventfd::{EfdFlags, EventFd};
        let fd = EventFd::from_value_and_flags(0, EfdFlags::EFD_NONBLOCK | EfdFlags::EFD_CLOEXEC)?;
        Ok(Self { fd })
    }

    /// Wakes the loop.
    pub fn notify(&self) {
        // A full counter (never in practice) only means the loop is already due to wake.
        let _ = self.fd.arm();
    }
}

impl Wakeable for Waker {
    fn fd(&self) -> Option<i32> {
        use std::os::fd::AsRawFd as _;
        Some(self.fd.as_raw_fd())
    }

    fn consume_wake(&self) {
        // Non-blocking: nothing pending (EAGAIN) is fine.
        let _ = self.fd.read();
    }
}

/// Waits until one of `subs` fires or `timeout` passes; returns a bit per subscriber (bit
/// `i` for `subs[i]`) that fired, consuming their notifications. Subscribers without a
/// wake-up never fire. A signal ends the wait early with no bit set.
pub fn wait_any(subs: &[&dyn Wakeable], timeout: Duration) -> u64 {
    let mut fds = Vec::with_capacity(subs.len());
    let mut index = Vec::with_capacity(subs.len());
    for (i, s) in subs.iter().enumerate() {
        if let Some(fd) = s.fd() {
            fds.push(fd);
            index.push(i);
        }
    }
    let ready = crate::uds::poll_readable(&fds, timeout);
    let mut bits = 0;
    for (k, i) in index.iter().enumerate() {
        if ready & (1 << k) != 0 {
            subs[*i].consume_wake();
            bits |= 1 << i;
        }
    }
    bits
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::time::now_ns;

    fn unique_prefix(tag: &str) -> Prefix {
        Prefix::new(&format!("ut{}{}", tag, std::process::id())).unwrap()
    }

    #[test]
    fn publish_wake_receive_in_one_process() {
        let p = unique_prefix("a");
        let g = Graph::join(&p, "unit").unwrap();
        let sub = g.robot_state_subscriber(true).unwrap();
        let publ = g.robot_state_publisher().unwrap();
        let mut s = RobotState::at_rest(7, now_ns(), 6);
        assert_eq!(publ.send(s).unwrap(), 1);
        s.tick = 8;
        publ.send(s).unwrap();
        assert!(sub.wait(Duration::from_millis(100)).unwrap());
        assert_eq!(sub.latest().unwrap().map(|m| m.tick), Some(8));
        assert_eq!(sub.latest().unwrap(), None);
        // While a node lives the domain stays; once the last is gone nothing is left.
        assert!(!release_domain(&p).unwrap());
        drop((sub, publ, g));
        assert!(release_domain(&p).unwrap());
        assert!(leftovers(&p).is_empty(), "{:?}", leftovers(&p));
    }

    /// Log records travel on iceoryx2 whatever the data plane's transport, from several
    /// publishers, and a reader that comes late gets the last few.
    #[test]
    fn log_records_reach_a_late_reader_from_several_processes() {
        let p = unique_prefix("log");
        let a = Graph::join_with(&p, "a", Transport::Uds).unwrap();
        let b = Graph::join(&p, "b").unwrap();
        let (pa, pb) = (a.log_publisher().unwrap(), b.log_publisher().unwrap());
        let mut r = LogRecord::zeroed();
        r.set_process("safety");
        r.push_text("first");
        pa.send(r).unwrap();
        let mut r2 = LogRecord::zeroed();
        r2.set_process("bridge");
        r2.push_text("second");
        pb.send(r2).unwrap();
        let sub = b.log_subscriber().unwrap();
        pa.update_connections();
        pb.update_connections();
        let mut got = Vec::new();
        sub.drain(|m| got.push((m.process().into_owned(), m.text().into_owned())))
            .unwrap();
        got.sort();
        assert_eq!(
            got,
            [
                ("bridge".to_owned(), "second".to_owned()),
                ("safety".to_owned(), "first".to_owned())
            ]
        );
        drop((sub, pa, pb, a, b));
        assert!(release_domain(&p).unwrap());
    }

    fn leftovers(p: &Prefix) -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&p.file_prefix()))
            .collect()
    }

    #[test]
    fn joystick_admits_one_publisher() {
        let p = unique_prefix("c");
        let g = Graph::join(&p, "unit").unwrap();
        let first = g.joystick_publisher().unwrap();
        assert!(matches!(
            g.joystick_publisher(),
            Err(IpcError::Port {
                port: "publisher",
                ..
            })
        ));
        // Once the first is gone, another operator may publish.
        drop(first);
        let again = g.joystick_publisher().unwrap();
        drop((again, g));
        assert!(release_domain(&p).unwrap());
        assert!(leftovers(&p).is_empty(), "{:?}", leftovers(&p));
    }

    #[test]
    fn a_second_joystick_publisher_is_refused_by_iceoryx2_as_one_too_many() {
        let p = unique_prefix("d");
        let g = Graph::join(&p, "unit").unwrap();
        let first = g.joystick_publisher().unwrap();
        let second = g.joystick_publisher();
        assert!(
            matches!(
                &second,
                Err(IpcError::Port {
                    port: "publisher",
                    source: PortError::Publisher(
                        PublisherCreateError::ExceedsMaxSupportedPublishers
                    ),
                    ..
                })
            ),
            "{:?}",
            second.as_ref().err()
        );
        // The message still names the service and what iceoryx2 said.
        let text = second.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(
            text.contains("joystick") && text.contains("ExceedsMaxSupportedPublishers"),
            "{text}"
        );
        drop((first, g));
        assert!(release_domain(&p).unwrap());
        assert!(leftovers(&p).is_empty(), "{:?}", leftovers(&p));
    }

    #[test]
    fn safe_command_admits_one_publisher() {
        let p = unique_prefix("b");
        let g = Graph::join(&p, "unit").unwrap();
        let _first = g.safe_command_publisher().unwrap();
        let second = g.safe_command_publisher();
        assert!(matches!(
            second,
            Err(IpcError::Port {
                port: "publisher",
                ..
            })
        ));
        drop((second, _first, g));
        assert!(release_domain(&p).unwrap());
        assert!(leftovers(&p).is_empty(), "{:?}", leftovers(&p));
    }
}
