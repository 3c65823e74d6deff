//! A remote observer's side of the gateway (`scl record --remote`, `scl live --remote`): the
//! graph's messages as the gateway publishes them (every topic a local recording holds), and
//! its queryables: what each mapper and safety process runs ([`crate::wire::PROCESS_CAPTURE`])
//! and the robot PC's clocks ([`ClockPair`]).

use std::path::PathBuf;
use std::time::Duration;

use recording::{Payload, Topic};

use crate::keys::Keys;
use crate::ports::{self, Got, Urgency};
use crate::session::{ClientError, SessionError};
use crate::wire::{ClockPair, DecodeError, PROCESS_CAPTURE};

/// How long an observer waits for the gateway's first answer (its clocks).
pub const GATEWAY_TIMEOUT: Duration = Duration::from_secs(10);
/// How long one question to the gateway about a process waits.
pub const CAPTURE_TIMEOUT: Duration = Duration::from_secs(1);
/// How often an observer asks what a process runs before it gives up on it (the gateway
/// captures a process when its first heartbeat arrives, within milliseconds): see
/// [`until_answered`].
pub const CAPTURE_ATTEMPTS: u32 = 20;
/// Between two questions about the same process.
pub const CAPTURE_RETRY: Duration = Duration::from_millis(250);

/// `--remote`: where a graph's gateway is and how to reach it, for an observer (`scl record
/// --remote`, `scl live --remote`).
#[derive(Debug, Clone)]
pub struct RemoteGraph {
    /// The gateway's endpoint.
    pub endpoint: String,
    /// The credentials file, if any.
    pub credentials: Option<PathBuf>,
    /// The graph's namespace (`[network] namespace`, by default `scl/<prefix>`).
    pub namespace: String,
    /// Zenoh's lease (ms).
    pub lease_ms: u64,
}

/// Why an observer could not join a remote graph.
#[derive(Debug, thiserror::Error)]
pub enum ObserveError {
    /// The session to the gateway could not be opened.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The gateway did not answer (its clocks).
    #[error("--remote {endpoint}: {source}")]
    Gateway {
        /// The endpoint.
        endpoint: String,
        /// Why.
        #[source]
        source: FetchError,
    },
}

/// An observer joined to a remote graph: its session, the graph's keys and the robot PC's
/// clocks at joining.
pub struct Observer {
    /// The session to the gateway.
    pub session: zenoh::Session,
    /// The graph's keys.
    pub keys: Keys,
    /// The robot PC's clocks.
    pub clock: ClockPair,
}

impl RemoteGraph {
    /// The gateway at `endpoint` of graph `prefix` as `network` (`[network]`) reaches it;
    /// `credentials` (the command's `--credentials`) before the configuration's file.
    pub fn new(
        endpoint: &str,
        credentials: Option<PathBuf>,
        network: &scl_config::NetworkConfig,
        prefix: &str,
    ) -> Self {
        Self {
            endpoint: endpoint.to_owned(),
            credentials: credentials.or_else(|| {
                (!network.credentials.is_empty()).then(|| PathBuf::from(&network.credentials))
            }),
            namespace: network.namespace_for(prefix),
            lease_ms: network.lease_ms,
        }
    }

    /// Opens a session to the gateway and asks it the robot PC's clocks (waiting at most
    /// [`GATEWAY_TIMEOUT`]).
    pub fn connect(&self) -> Result<Observer, ObserveError> {
        let (session, _) = crate::session::open_client(
            &self.endpoint,
            self.credentials.as_deref(),
            self.lease_ms,
        )?;
        let keys = Keys::new(&self.namespace);
        let clock = fetch_clock(&session, &keys, GATEWAY_TIMEOUT).map_err(|source| {
            ObserveError::Gateway {
                endpoint: self.endpoint.clone(),
                source,
            }
        })?;
        Ok(Observer {
            session,
            keys,
            clock,
        })
    }
}

/// `subscribe_graph` and [`GraphPublishers`], one subscriber and one publisher per recorded
/// topic of `ipc_types::recorded_topics!`: a topic added there travels to a remote observer
/// with no edit here.
macro_rules! graph_ports {
    ($($(#[$doc:meta])* $variant:ident: $msg:ident => $ty:path, $topic:path;)*) => {
        /// Subscribes to every recorded topic of the graph below `keys` (the keys the
        /// gateway's [`GraphPublishers`] publish on); `f` gets each message (as a local
        /// recorder takes it off shared memory), or why one was refused (with its key), on
        /// Zenoh's threads: it must not block.
        pub fn subscribe_graph<F>(
            session: &zenoh::Session,
            keys: &Keys,
            f: F,
        ) -> Result<Vec<zenoh::pubsub::Subscriber<()>>, SessionError>
        where
            F: Fn(Result<Payload, (String, DecodeError)>) + Clone + Send + Sync + 'static,
        {
            Ok(vec![$({
                let f = f.clone();
                ports::subscribe::<$ty, _>(session, keys.topic($topic.name), move |key, m| {
                    f(m.map(Payload::$variant).map_err(|e| (key.to_owned(), e)))
                })?
            }),*])
        }

        /// The gateway's publishers of the recorded topics, one per topic below the
        /// namespace, each at the urgency its declaration gave it.
        #[allow(non_snake_case)]
        pub struct GraphPublishers {
            $($variant: ports::Out<$ty>,)*
        }

        impl GraphPublishers {
            /// Declares a publisher per recorded topic below `keys`, `urgency(topic)` each.
            pub fn declare(
                session: &zenoh::Session,
                keys: &Keys,
                urgency: impl Fn(Topic) -> Urgency,
            ) -> Result<Self, SessionError> {
                Ok(Self {
                    $($variant: ports::publisher(
                        session,
                        keys.topic($topic.name),
                        urgency(Topic::$variant),
                    )?,)*
                })
            }

            /// Publishes `m` on its topic's key.
            pub fn put(&self, m: &Payload) -> Result<(), zenoh::Error> {
                match m {
                    $(Payload::$variant(m) => self.$variant.put(m),)*
                }
            }
        }
    };
}

ipc_types::recorded_topics!(graph_ports);

/// Why the gateway's queryables did not give what was asked.
#[derive(Debug, thiserror::Error)]
pub enum FetchError {
    /// The query itself failed.
    #[error(transparent)]
    Session(#[from] SessionError),
    /// Nobody answered (no gateway of this namespace is reachable, or it has not seen it).
    #[error(
        "no answer on `{key}` within {timeout:?} (is the graph's gateway running, under this namespace?)"
    )]
    NoAnswer {
        /// The key asked.
        key: String,
        /// How long the query waited.
        timeout: Duration,
    },
    /// The answer is not what the key serves.
    #[error("the answer on `{key}` was refused: {source}")]
    Decode {
        /// The key asked.
        key: String,
        /// Why.
        #[source]
        source: DecodeError,
    },
}

/// The robot PC's clocks, from the gateway below `keys`.
pub fn fetch_clock(
    session: &zenoh::Session,
    keys: &Keys,
    timeout: Duration,
) -> Result<ClockPair, FetchError> {
    let key = keys.clock();
    match ports::fetch_one::<ClockPair>(session, key.clone(), timeout)? {
        Some(Ok(c)) => Ok(c),
        Some(Err(source)) => Err(FetchError::Decode { key, source }),
        None => Err(FetchError::NoAnswer { key, timeout }),
    }
}

/// What process `pid` runs, as the gateway below `keys` captured it (an MCAP file's bytes,
/// [`PROCESS_CAPTURE`]).
pub fn fetch_process(
    session: &zenoh::Session,
    keys: &Keys,
    pid: u32,
    timeout: Duration,
) -> Result<Vec<u8>, FetchError> {
    let key = keys.process(pid);
    let got = ports::fetch(session, key.clone(), timeout)?;
    process_answer(&key, got).ok_or(FetchError::NoAnswer { key, timeout })?
}

/// Asks (`ask`) until it is answered: at most `attempts` times, `pause` apart, once only
/// when `stopping` is set; an answer of the wrong kind or a failed query is not asked again.
/// The gateway captures a process when its first heartbeat arrives, so an observer that saw
/// the same heartbeat may ask a moment before the capture is there.
pub fn until_answered<T>(
    mut ask: impl FnMut() -> Result<T, FetchError>,
    attempts: u32,
    pause: Duration,
    stopping: &std::sync::atomic::AtomicBool,
) -> Result<T, FetchError> {
    let mut n = 0;
    loop {
        n += 1;
        match ask() {
            Err(FetchError::NoAnswer { .. })
                if n < attempts && !stopping.load(std::sync::atomic::Ordering::Relaxed) =>
            {
                std::thread::sleep(pause);
            }
            r => return r,
        }
    }
}

/// The capture among the answers to `key`: the first of the right encoding, or why the
/// first answer was refused; `None` if there was none.
fn process_answer(key: &str, got: Vec<Got>) -> Option<Result<Vec<u8>, FetchError>> {
    let mut refused = None;
    for g in got {
        if g.encoding == PROCESS_CAPTURE && g.key == key {
            return Some(Ok(g.bytes));
        }
        refused.get_or_insert(FetchError::Decode {
            key: key.to_owned(),
            source: DecodeError::Type {
                want: PROCESS_CAPTURE,
                got: g.encoding,
            },
        });
    }
    refused.map(Err)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn got(key: &str, encoding: &str) -> Got {
        Got {
            key: key.into(),
            encoding: encoding.into(),
            bytes: vec![1, 2, 3],
        }
    }

    #[test]
    fn a_question_is_asked_again_only_while_unanswered() {
        use std::sync::atomic::AtomicBool;
        let no_answer = || FetchError::NoAnswer {
            key: "k".into(),
            timeout: Duration::ZERO,
        };
        let (go, stop) = (AtomicBool::new(false), AtomicBool::new(true));
        let mut n = 0;
        let r = until_answered(
            || {
                n += 1;
                if n < 3 { Err(no_answer()) } else { Ok(n) }
            },
            5,
            Duration::ZERO,
            &go,
        );
        assert_eq!(r.unwrap(), 3);
        let mut n = 0;
        let r: Result<u32, _> = until_answered(
            || {
                n += 1;
                Err(no_answer())
            },
            5,
            Duration::ZERO,
            &go,
        );
        assert!(matches!(r, Err(FetchError::NoAnswer { .. })) && n == 5);
        let mut n = 0;
        let _ = until_answered::<u32>(
            || {
                n += 1;
                Err(no_answer())
            },
            5,
            Duration::ZERO,
            &stop,
        );
        assert_eq!(n, 1);
        let mut n = 0;
        let r = until_answered::<u32>(
            || {
                n += 1;
                Err(FetchError::Decode {
                    key: "k".into(),
                    source: DecodeError::Size {
                        want: "x",
                        size: 1,
                        got: 2,
                    },
                })
            },
            5,
            Duration::ZERO,
            &go,
        );
        assert!(matches!(r, Err(FetchError::Decode { .. })) && n == 1);
    }

    #[test]
    fn a_capture_is_taken_only_with_its_encoding_and_key() {
        let k = "scl/g/process/7";
        assert!(process_answer(k, vec![]).is_none());
        assert_eq!(
            process_answer(k, vec![got(k, PROCESS_CAPTURE)])
                .unwrap()
                .unwrap(),
            vec![1, 2, 3]
        );
        let e = process_answer(k, vec![got(k, "application/octet-stream")])
            .unwrap()
            .unwrap_err()
            .to_string();
        assert!(e.contains(k) && e.contains("ProcessCapture"), "{e}");
        // Another process's answer is not this one's.
        assert!(
            process_answer(k, vec![got("scl/g/process/8", PROCESS_CAPTURE)])
                .unwrap()
                .is_err()
        );
        assert_eq!(
            process_answer(k, vec![got(k, "text/plain"), got(k, PROCESS_CAPTURE)])
                .unwrap()
                .unwrap(),
            vec![1, 2, 3]
        );
    }
}
