//! The one place that opens every service of a graph, with its settings.
//!
//! Each topic is a publish-subscribe service for the data plus an event service of the same
//! name with `/event` appended, which wakes the processes that react to the topic. Settings
//! (history, buffer sizes, how many publishers may exist) live in [`TopicSettings`] constants
//! next to the topic names, so every process opens every service identically.
//!
//! The graph's [`Prefix`] is used twice: in every service name (`lab2/robot_state`) and as the
//! file-name prefix of every shared-memory resource (`scl_lab2_…`), so two graphs never see
//! each other and a test can check that it left nothing behind.

use core::time::Duration;

use iceoryx2::config::Config;
use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::{event, publish_subscribe};

use crate::msg::{JoystickInput, MapperCommand, NodeStatus, RobotState, SafeCommand, TickReport};
use crate::prefix::Prefix;
use crate::uds::Datagram;

/// The iceoryx2 service variant of every graph: inter-process.
pub type Ipc = iceoryx2::service::ipc::Service;

/// Errors of opening or using the graph's shared-memory services.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// The iceoryx2 node of this process could not be created.
    #[error("cannot create the iceoryx2 node `{node}`: {reason}")]
    Node {
        /// Node name.
        node: String,
        /// What iceoryx2 said.
        reason: String,
    },
    /// A service could not be opened or created, e.g. because another graph opened it with
    /// other message types or settings.
    #[error("cannot open service `{service}`: {reason}")]
    Open {
        /// Full service name.
        service: String,
        /// What iceoryx2 said.
        reason: String,
    },
    /// A publisher, subscriber, notifier or listener could not be created. For the
    /// `safe_command` publisher this is how a second safety process is refused.
    #[error("cannot create a {port} on `{service}`: {reason}")]
    Port {
        /// Full service name.
        service: String,
        /// Which port.
        port: &'static str,
        /// What iceoryx2 said.
        reason: String,
    },
    /// Sending, receiving or notifying failed.
    #[error("{op} failed on `{service}`: {reason}")]
    Io {
        /// Full service name.
        service: String,
        /// The operation.
        op: &'static str,
        /// What iceoryx2 said.
        reason: String,
    },
}

/// Quality-of-service settings of one topic.
#[derive(Debug, Clone, Copy)]
pub struct TopicSettings {
    /// Topic name below the prefix.
    pub name: &'static str,
    /// Samples a late-joining subscriber receives at once.
    pub history: usize,
    /// Samples a subscriber buffers; the oldest is overwritten (safe overflow), so a slow
    /// reader never blocks a writer. Control-path readers take the newest sample; the depth
    /// (64 ticks = 1.6 s) is for observers (recorder, tests) that want every sample.
    pub buffer: usize,
    /// Publishers the service admits.
    pub max_publishers: usize,
    /// Subscribers the service admits.
    pub max_subscribers: usize,
}

/// Joystick samples: newest wins; a late mapper gets the last sample at once. One publisher
/// at a time: the joystick process, or with `[joystick] source = "external"` whoever
/// publishes first (a second is refused with [`IpcError::Port`]).
pub const JOYSTICK: TopicSettings = TopicSettings {
    name: "joystick",
    history: 1,
    buffer: 64,
    max_publishers: 1,
    max_subscribers: 16,
};
/// Robot state, one per tick, from the bridge.
pub const ROBOT_STATE: TopicSettings = TopicSettings {
    name: "robot_state",
    history: 1,
    buffer: 64,
    max_publishers: 1,
    max_subscribers: 16,
};
/// Mapper commands; several mappers may publish at once during a live swap.
pub const MAPPER_COMMAND: TopicSettings = TopicSettings {
    name: "mapper_command",
    history: 0,
    buffer: 64,
    max_publishers: 4,
    max_subscribers: 8,
};
/// The command the arm executes. Exactly one publisher: the safety process.
pub const SAFE_COMMAND: TopicSettings = TopicSettings {
    name: "safe_command",
    history: 0,
    buffer: 64,
    max_publishers: 1,
    max_subscribers: 8,
};
/// Heartbeats of every node; buffered deep enough for a reader that polls a few times a second.
pub const STATUS: TopicSettings = TopicSettings {
    name: "status",
    history: 0,
    buffer: 512,
    max_publishers: 16,
    max_subscribers: 8,
};

/// How the data-plane topics travel. The control plane (swaps, e-stop, safety control)
/// always uses iceoryx2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// iceoryx2 zero-copy shared memory with event wake-ups (the product).
    #[default]
    Iceoryx2,
    /// Unix-domain datagram sockets (for latency comparisons; see [`crate::uds`]).
    Uds,
}

impl std::fmt::Display for Transport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Iceoryx2 => "iceoryx2",
            Self::Uds => "uds",
        })
    }
}

/// The bridge's timing report of every tick; deep enough for a reader that polls a few
/// times a second.
pub const TICK_REPORT: TopicSettings = TopicSettings {
    name: "tick_report",
    history: 0,
    buffer: 256,
    max_publishers: 2,
    max_subscribers: 8,
};

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
            reason: format!("prefix is not a valid file name: {e:?}"),
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
        let node_err = |reason: String| IpcError::Node {
            node: name.to_owned(),
            reason,
        };
        let node_name = NodeName::new(name).map_err(|e| node_err(format!("{e:?}")))?;
        let node = NodeBuilder::new()
            .config(&config)
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| node_err(e.to_string()))?;
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
            reason: e.to_string(),
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
            reason: format!("{e:?}"),
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
                reason: e.to_string(),
            })?;
        Ok((full, factory))
    }

    fn event(&self, s: &TopicSettings) -> Result<(String, event::PortFactory<Ipc>), IpcError> {
        let full = format!("{}/event", self.prefix.service(s.name));
        let name = ServiceName::new(&full).map_err(|e| IpcError::Open {
            service: full.clone(),
            reason: format!("{e:?}"),
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
                reason: e.to_string(),
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
        let (service, data) = self.pubsub::<T>(s)?;
        let publisher = data
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "publisher",
                reason: e.to_string(),
            })?;
        let (_, ev) = self.event(s)?;
        let notifier = ev.notifier_builder().create().map_err(|e| IpcError::Port {
            service: service.clone(),
            port: "notifier",
            reason: e.to_string(),
        })?;
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
        let (service, data) = self.pubsub::<T>(s)?;
        let subscriber = data
            .subscriber_builder()
            .create()
            .map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "subscriber",
                reason: e.to_string(),
            })?;
        let listener = if wake {
            let (_, ev) = self.event(s)?;
            Some(ev.listener_builder().create().map_err(|e| IpcError::Port {
                service: service.clone(),
                port: "listener",
                reason: e.to_string(),
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

    /// Publisher of joystick samples. Fails with [`IpcError::Port`] if another process
    /// already publishes them: the topic admits one operator.
    pub fn joystick_publisher(&self) -> Result<TopicPublisher<JoystickInput>, IpcError> {
        self.publisher(&JOYSTICK)
    }
    /// Subscriber of joystick samples; `wake` attaches a listener (the mapper takes samples
    /// as they arrive).
    pub fn joystick_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<JoystickInput>, IpcError> {
        self.subscriber(&JOYSTICK, wake)
    }
    /// Publisher of robot states (the bridge).
    pub fn robot_state_publisher(&self) -> Result<TopicPublisher<RobotState>, IpcError> {
        self.publisher(&ROBOT_STATE)
    }
    /// Subscriber of robot states; `wake` attaches a listener so the caller can block until
    /// the next tick.
    pub fn robot_state_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<RobotState>, IpcError> {
        self.subscriber(&ROBOT_STATE, wake)
    }
    /// Publisher of mapper commands.
    pub fn mapper_command_publisher(&self) -> Result<TopicPublisher<MapperCommand>, IpcError> {
        self.publisher(&MAPPER_COMMAND)
    }
    /// Subscriber of mapper commands (safety wakes on them).
    pub fn mapper_command_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<MapperCommand>, IpcError> {
        self.subscriber(&MAPPER_COMMAND, wake)
    }
    /// Publisher of the executed command. Fails with [`IpcError::Port`] if another process
    /// already publishes it: the arm listens to one safety process only.
    pub fn safe_command_publisher(&self) -> Result<TopicPublisher<SafeCommand>, IpcError> {
        self.publisher(&SAFE_COMMAND)
    }
    /// Subscriber of executed commands (the bridge wakes on them).
    pub fn safe_command_subscriber(
        &self,
        wake: bool,
    ) -> Result<TopicSubscriber<SafeCommand>, IpcError> {
        self.subscriber(&SAFE_COMMAND, wake)
    }
    /// Publisher of the bridge's per-tick timing report.
    pub fn tick_report_publisher(&self) -> Result<TopicPublisher<TickReport>, IpcError> {
        self.publisher(&TICK_REPORT)
    }
    /// Subscriber of the bridge's per-tick timing reports (benchmarks, recorders).
    pub fn tick_report_subscriber(&self) -> Result<TopicSubscriber<TickReport>, IpcError> {
        self.subscriber(&TICK_REPORT, false)
    }
    /// Publisher of this node's heartbeat.
    pub fn status_publisher(&self) -> Result<TopicPublisher<NodeStatus>, IpcError> {
        self.publisher(&STATUS)
    }
    /// Subscriber of every node's heartbeat.
    pub fn status_subscriber(&self) -> Result<TopicSubscriber<NodeStatus>, IpcError> {
        self.subscriber(&STATUS, false)
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
            reason: format!("{e:?}"),
        }
    })
}

// One per port, made once per process: the size of the variants does not matter.
#[allow(clippy::large_enum_variant)]
enum PubInner<T: ZeroCopySend + core::fmt::Debug + Datagram + 'static> {
    Iox {
        publisher: Publisher<Ipc, T, ()>,
        notifier: Notifier<Ipc>,
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
        let io = |op: &'static str, reason: String| IpcError::Io {
            service: self.service.clone(),
            op,
            reason,
        };
        match &self.inner {
            PubInner::Iox {
                publisher,
                notifier,
            } => {
                let sample = publisher
                    .loan_uninit()
                    .map_err(|e| io("loan", e.to_string()))?;
                let n = sample
                    .write_payload(msg)
                    .send()
                    .map_err(|e| io("send", e.to_string()))?;
                notifier.notify().map_err(|e| io("notify", e.to_string()))?;
                Ok(n)
            }
            PubInner::Uds(p) => Ok(p.borrow_mut().send(&msg)),
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
    /// Wraps a subscriber of a topic opened elsewhere in this crate (the control topics),
    /// without a wake-up listener.
    pub(crate) fn without_listener(service: String, subscriber: Subscriber<Ipc, T, ()>) -> Self {
        Self {
            service,
            inner: SubInner::Iox {
                subscriber,
                listener: None,
            },
        }
    }

    /// Calls `f` with every buffered message, oldest first.
    pub fn drain(&self, mut f: impl FnMut(&T)) -> Result<usize, IpcError> {
        let err = |reason: String| IpcError::Io {
            service: self.service.clone(),
            op: "receive",
            reason,
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
                        Err(e) => return Err(err(e.to_string())),
                    }
                }
            }
            SubInner::Uds(sub) => sub.drain(f).map_err(|e| err(e.to_string())),
        }
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
                    reason: e.to_string(),
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
    use crate::msg::*;
    use crate::time::now_ns;

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
