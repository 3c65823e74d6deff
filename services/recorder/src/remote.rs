//! `scl record --remote ENDPOINT`: the graph on another machine, through its gateway.
//!
//! The gateway publishes every topic a local recording holds ([`scl_net::observe`]); Zenoh's
//! callbacks hand each message to the same [`Producer`] a local recording uses (non-blocking:
//! a full hand-off drops and counts). The first heartbeat of a mapper or safety process sends
//! its pid to a fetcher thread, which asks the gateway what the process runs (the capture the
//! gateway made with `graph_client::process::capture` on the robot PC) and hands it to the
//! writer, which writes exactly those records. The robot PC's clocks, asked first, map the
//! messages' monotonic stamps to wall-clock time as the robot PC's own recorder would.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use graph_client::process::Captured;
use ipc_types::{NodeRole, NodeStatus, Prefix};
use recording::{Payload, Topic};
use scl_net::Keys;
use scl_net::observe::{self, FetchError, RemoteGraph};
use transport::signals;

use crate::{
    ProcessItem, RecordOptions, RecordReport, RecorderError, WriterOutcome, create,
    outcome_at_stop, remove_unrecorded, report, start_pipeline,
};

/// Ticks between the newest first tick of the topics a command depends on and the first
/// command a remote recording keeps: a mapper command at tick `k` may use a joystick sample
/// answering `k - 1` (two behind is stale), so from there on each one's inputs are in.
const START_MARGIN: u64 = 3;

/// Robot states after which a remote recording keeps commands even if a topic they depend
/// on was never heard (a graph without a joystick): about a second at 40 Hz.
const START_AT_THE_LATEST: u64 = 40;

/// Which commands a remote recording keeps. Its subscriptions reach the gateway one by one,
/// so the first ticks may bring a mapper command without the joystick sample it used: a
/// replay would find its input missing. Every message is kept, but mapper and executed
/// commands only from the first tick at which the joystick, robot state and mapper command
/// topics (those recorded) have all been heard, plus [`START_MARGIN`]: from then on each
/// command's inputs are in the recording (Zenoh keeps one key's samples in order).
#[derive(Debug, Clone, Default)]
pub(crate) struct StartGate {
    /// The first tick heard on the joystick, robot state and mapper command topics; `None`
    /// for one not recorded is filled in as heard at tick 0.
    first: [Option<u64>; 3],
    /// The first command tick kept, once known.
    start: Option<u64>,
}

impl StartGate {
    /// A gate for a recording of `topics`.
    pub(crate) fn new(topics: &[Topic]) -> Self {
        let mut g = Self::default();
        for (i, t) in [Topic::Joystick, Topic::RobotState, Topic::MapperCommand]
            .into_iter()
            .enumerate()
        {
            if !topics.contains(&t) {
                g.first[i] = Some(0);
            }
        }
        if !topics.contains(&Topic::RobotState) {
            g.start = Some(0);
        }
        g
    }

    /// Whether to keep `p` (every message but a command before the start).
    pub(crate) fn keep(&mut self, p: &Payload) -> bool {
        let heard = match p {
            Payload::Joystick(j) => Some((0, j.tick)),
            Payload::RobotState(s) => Some((1, s.tick)),
            Payload::MapperCommand(c) => Some((2, c.tick)),
            _ => None,
        };
        if let Some((i, tick)) = heard
            && tick != ipc_types::NO_TICK
            && self.start.is_none()
        {
            let first = *self.first[i].get_or_insert(tick);
            if let [Some(a), Some(b), Some(c)] = self.first {
                self.start = Some(a.max(b).max(c) + START_MARGIN);
            } else if i == 1 && tick >= first + START_AT_THE_LATEST {
                self.start = Some(tick + START_MARGIN);
            }
        }
        let tick = match p {
            Payload::MapperCommand(c) => c.tick,
            Payload::SafeCommand(c) => c.tick,
            _ => return true,
        };
        self.start.is_some_and(|s| tick >= s)
    }
}

/// Records the graph behind `remote` into `opts.out` until a shutdown is requested.
pub(crate) fn run(
    prefix: &Prefix,
    opts: &RecordOptions,
    remote: &RemoteGraph,
) -> Result<RecordReport, RecorderError> {
    let started = Instant::now();
    // The gateway first: when it cannot be reached, no file is made.
    let observe::Observer {
        session,
        keys,
        clock,
    } = remote.connect()?;
    let mut extra = BTreeMap::new();
    extra.insert("remote".to_owned(), remote.endpoint.clone());
    extra.insert("namespace".to_owned(), remote.namespace.clone());
    let (w, view) = create(prefix, opts, (clock.mono_ns, clock.unix_ns), extra)
        .inspect_err(|e| remove_unrecorded(&opts.out, e))?;
    let (mut producer, tally, writer) =
        start_pipeline(w, opts.topics.clone(), opts.queue, opts.flush_every, view)
            .map_err(RecorderError::Thread)?;
    let (seen_tx, seen_rx) = crossbeam_channel::unbounded();
    producer.remote_procs = Some(seen_tx);
    let stopping = Arc::new(AtomicBool::new(false));
    let fetcher = {
        let (session, keys, procs, stopping) = (
            session.clone(),
            keys.clone(),
            producer.procs.clone(),
            Arc::clone(&stopping),
        );
        let from = remote.endpoint.clone();
        std::thread::Builder::new()
            .name("remote-processes".into())
            .spawn(move || fetch_loop(&session, &keys, &from, &seen_rx, &procs, &stopping))
            .map_err(RecorderError::Thread)?
    };
    let shared = Arc::new(Mutex::new(Some((producer, StartGate::new(&opts.topics)))));
    let refused = Arc::new(AtomicU64::new(0));
    let subscribed = {
        let (shared, refused, topics) = (
            Arc::clone(&shared),
            Arc::clone(&refused),
            opts.topics.clone(),
        );
        observe::subscribe_graph(&session, &keys, move |m| match m {
            Ok(p) => {
                if !topics.contains(&p.topic()) {
                    return;
                }
                if let Ok(mut guard) = shared.lock()
                    && let Some((producer, gate)) = guard.as_mut()
                    && gate.keep(&p)
                {
                    if let Payload::Status(st) = &p {
                        producer.note_process(st);
                    }
                    producer.offer(p);
                }
            }
            Err((key, e)) => {
                let n = refused.fetch_add(1, Ordering::Relaxed) + 1;
                if n.is_power_of_two() {
                    tracing::warn!(refused = n, "a message on `{key}` was refused: {e}");
                }
            }
        })
    };
    let subs = match subscribed {
        Ok(s) => s,
        Err(e) => {
            stop(&shared, &stopping, fetcher, writer);
            let e = RecorderError::from(e);
            remove_unrecorded(&opts.out, &e);
            return Err(e);
        }
    };
    tracing::info!(
        file = %opts.out.display(),
        endpoint = %remote.endpoint,
        namespace = %remote.namespace,
        "recording graph `{prefix}` through its gateway"
    );
    while !signals::stop_requested() {
        std::thread::sleep(Duration::from_millis(50));
    }
    // No message after this: the subscriptions go first.
    drop(subs);
    if let Ok(mut guard) = shared.lock()
        && let Some((p, _)) = guard.as_mut()
    {
        outcome_at_stop(opts, p);
    }
    let outcome = stop(&shared, &stopping, fetcher, writer);
    drop(session);
    let n = refused.load(Ordering::Relaxed);
    if n > 0 {
        tracing::warn!("{n} messages from the gateway were refused (not the graph's types)");
    }
    Ok(report(opts, started, &tally, outcome))
}

/// Ends the run: the fetcher answers what it was asked (once each), then the hand-off
/// closes and the writer finishes the file.
fn stop(
    shared: &Mutex<Option<(crate::Producer, StartGate)>>,
    stopping: &AtomicBool,
    fetcher: std::thread::JoinHandle<()>,
    writer: std::thread::JoinHandle<WriterOutcome>,
) -> WriterOutcome {
    stopping.store(true, Ordering::Relaxed);
    let mut producer = shared
        .lock()
        .ok()
        .and_then(|mut g| g.take())
        .map(|(p, _)| p);
    if let Some(p) = producer.as_mut() {
        p.remote_procs = None;
    }
    let _ = fetcher.join();
    drop(producer);
    writer.join().unwrap_or_else(|_| WriterOutcome {
        error: Some("the writer thread panicked".into()),
    })
}

/// The fetcher thread: for each process seen, what it runs, to the writer.
fn fetch_loop(
    session: &scl_net::zenoh::Session,
    keys: &Keys,
    from: &str,
    seen: &Receiver<(NodeStatus, NodeRole)>,
    procs: &Sender<ProcessItem>,
    stopping: &AtomicBool,
) {
    node_rt::rt::lower_priority();
    while let Ok((st, role)) = seen.recv() {
        let item = fetch_capture(
            |pid| observe::fetch_process(session, keys, pid, observe::CAPTURE_TIMEOUT),
            from,
            &st,
            role,
            stopping,
        );
        let _ = procs.send(item);
    }
}

/// Asks (`ask`) what process `st.pid` runs until it is answered, at most
/// [`observe::CAPTURE_ATTEMPTS`] times (once when `stopping`): the capture, or a record naming why not.
pub(crate) fn fetch_capture(
    ask: impl Fn(u32) -> Result<Vec<u8>, FetchError>,
    from: &str,
    st: &NodeStatus,
    role: NodeRole,
    stopping: &AtomicBool,
) -> ProcessItem {
    let missing = |error: String| ProcessItem::Missing {
        pid: st.pid,
        role,
        t_ns: st.t_ns,
        error,
    };
    let r = observe::until_answered(
        || ask(st.pid),
        observe::CAPTURE_ATTEMPTS,
        observe::CAPTURE_RETRY,
        stopping,
    );
    match r {
        Ok(bytes) => match Captured::read(&bytes, st.pid, from) {
            Ok(c) => ProcessItem::Captured(Box::new(c)),
            Err(e) => missing(e.to_string()),
        },
        Err(e) => missing(format!(
            "the gateway at {from} did not serve what {} process {} runs: {e}",
            role.name(),
            st.pid
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The name a capture came from.
    const FROM: &str = "tcp/192.0.2.10:7447";
    use graph_client::process::{ProcessSeen, capture_bytes};
    use ipc_types::{JoystickInput, MapperCommand, SafeCommand, phase};

    fn joystick(tick: u64) -> Payload {
        Payload::Joystick(JoystickInput {
            tick,
            ..zerocopy::FromZeros::new_zeroed()
        })
    }

    fn state(tick: u64) -> Payload {
        Payload::RobotState(ipc_types::RobotState::at_rest(tick, 1, 6))
    }

    fn mapper(tick: u64) -> Payload {
        Payload::MapperCommand(MapperCommand {
            tick,
            ..zerocopy::FromZeros::new_zeroed()
        })
    }

    fn safe(tick: u64) -> Payload {
        Payload::SafeCommand(SafeCommand {
            tick,
            ..SafeCommand::zeroed()
        })
    }

    #[test]
    fn commands_are_kept_once_every_input_is_heard_and_other_messages_always() {
        let mut g = StartGate::new(&Topic::ALL);
        // The mapper's topic is heard first (tick 10), the joystick at 11, states at 12.
        assert!(!g.keep(&mapper(10)));
        assert!(!g.keep(&safe(10)));
        assert!(g.keep(&joystick(11)));
        assert!(!g.keep(&mapper(11)));
        assert!(g.keep(&state(12)));
        assert!(g.keep(&Payload::Status(mapper_status(1))));
        // From 12 + 3 on.
        assert!(!g.keep(&mapper(14)));
        assert!(!g.keep(&safe(14)));
        assert!(g.keep(&mapper(15)));
        assert!(g.keep(&safe(15)));
        assert!(g.keep(&mapper(16)));
        // A joystick sample that answers no tick says nothing.
        let mut g = StartGate::new(&Topic::ALL);
        g.keep(&joystick(ipc_types::NO_TICK));
        g.keep(&mapper(3));
        g.keep(&state(3));
        assert!(!g.keep(&mapper(100)));
    }

    #[test]
    fn a_topic_not_recorded_or_never_heard_holds_nothing_back_for_long() {
        let mut g = StartGate::new(&[Topic::RobotState, Topic::SafeCommand]);
        g.keep(&state(5));
        assert!(g.keep(&safe(8)));
        assert!(!g.keep(&safe(7)));
        // No joystick at all: states for a second, then the commands.
        let mut g = StartGate::new(&Topic::ALL);
        for k in 0..START_AT_THE_LATEST {
            g.keep(&state(k));
            g.keep(&mapper(k));
            assert!(!g.keep(&safe(k)), "{k}");
        }
        g.keep(&state(START_AT_THE_LATEST));
        assert!(g.keep(&safe(START_AT_THE_LATEST + START_MARGIN)));
        // Without robot states, nothing to wait for.
        let mut g = StartGate::new(&[Topic::SafeCommand]);
        assert!(g.keep(&safe(0)));
    }

    fn mapper_status(pid: u32) -> NodeStatus {
        let mut st = NodeStatus::new(NodeRole::Mapper, phase::RUNNING, 5);
        st.pid = pid;
        st.mapper_id = 1;
        st
    }

    fn bundled(pid: u32) -> Vec<u8> {
        capture_bytes(&ProcessSeen {
            role: NodeRole::Mapper,
            pid,
            mapper_id: 1,
            t_ns: 5,
            argv: Ok(vec![
                "scl".into(),
                "mapper".into(),
                "--model".into(),
                "bundled".into(),
            ]),
            cwd: None,
        })
        .unwrap()
    }

    #[test]
    fn a_capture_not_there_yet_is_asked_again_and_taken() {
        let asked = std::sync::atomic::AtomicU32::new(0);
        let no = AtomicBool::new(false);
        let item = fetch_capture(
            |pid| {
                if asked.fetch_add(1, Ordering::Relaxed) < 2 {
                    Err(FetchError::NoAnswer {
                        key: format!("scl/g/process/{pid}"),
                        timeout: observe::CAPTURE_TIMEOUT,
                    })
                } else {
                    Ok(bundled(pid))
                }
            },
            FROM,
            &mapper_status(9),
            NodeRole::Mapper,
            &no,
        );
        assert_eq!(asked.load(Ordering::Relaxed), 3);
        let ProcessItem::Captured(c) = item else {
            panic!("not captured: {item:?}")
        };
        assert_eq!(c.entries["pid"], "9");
    }

    #[test]
    fn a_capture_never_served_or_corrupt_is_a_record_naming_it() {
        let stopping = AtomicBool::new(true);
        let asked = std::sync::atomic::AtomicU32::new(0);
        let item = fetch_capture(
            |pid| {
                asked.fetch_add(1, Ordering::Relaxed);
                Err(FetchError::NoAnswer {
                    key: format!("scl/g/process/{pid}"),
                    timeout: observe::CAPTURE_TIMEOUT,
                })
            },
            FROM,
            &mapper_status(9),
            NodeRole::Mapper,
            &stopping,
        );
        // Stopping: asked once.
        assert_eq!(asked.load(Ordering::Relaxed), 1);
        let ProcessItem::Missing { pid, error, .. } = item else {
            panic!("{item:?}")
        };
        assert_eq!(pid, 9);
        assert!(
            error.contains(FROM) && error.contains("mapper process 9"),
            "{error}"
        );
        let no = AtomicBool::new(false);
        let item = fetch_capture(
            |pid| {
                let mut b = bundled(pid);
                b.truncate(b.len() / 2);
                Ok(b)
            },
            FROM,
            &mapper_status(9),
            NodeRole::Mapper,
            &no,
        );
        let ProcessItem::Missing { error, .. } = item else {
            panic!("{item:?}")
        };
        assert!(
            error.contains("process 9 from tcp/192.0.2.10:7447"),
            "{error}"
        );
        // Another process's capture is refused too.
        let item = fetch_capture(
            |_| Ok(bundled(10)),
            FROM,
            &mapper_status(9),
            NodeRole::Mapper,
            &no,
        );
        assert!(matches!(item, ProcessItem::Missing { .. }), "{item:?}");
    }
}
