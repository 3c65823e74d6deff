//! A process's own log records on the graph's `log` topic ([`ipc_types::LogRecord`]), so an
//! observer (`scl live`: Foxglove's `/scl/log`) shows what the supervisor, the mapper, safety,
//! the bridge, the joystick and the recorder logged, with the process's name and the level.
//!
//! Two pieces:
//!
//! * [`GraphLogLayer`], a `tracing_subscriber` layer installed with the process's logging. On
//!   each event (the caller's thread) it writes the level, the monotonic time and the text
//!   (`message key=value ...`, cut at [`ipc_types::LOG_TEXT_BYTES`]) into a fixed-size record
//!   on the stack, without allocating, and hands it over with a non-blocking `try_send` on a
//!   bounded channel ([`QUEUE`] records); a full channel drops the record and counts it. It
//!   never waits, so a control loop that logs is never held up by the graph or an observer.
//! * [`publish`], a thread at low priority that joins the graph as a node of its own
//!   (`<process>-log`) and publishes the records on the topic, with the number dropped so
//!   far. Records logged before it starts (start-up warnings) wait in the channel. Its own
//!   logs (iceoryx2's, say) are not forwarded, so a failing topic cannot feed itself. The
//!   returned [`LogPublisher`] stops it when dropped: it publishes what is queued, leaves the
//!   graph and releases the graph's domain if it was the last node.
//!
//! A process that never calls [`publish`] (an offline command) keeps at most [`QUEUE`]
//! records, then drops and counts the rest.

use std::cell::Cell;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;

use ipc_types::{LogRecord, Prefix, log_level};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, Layer};

/// Records the hand-off holds until the publisher thread takes them.
pub const QUEUE: usize = 256;

/// The hand-off between the layer (any thread) and the publisher thread.
struct Sink {
    tx: mpsc::SyncSender<LogRecord>,
    rx: std::sync::Mutex<Option<mpsc::Receiver<LogRecord>>>,
    dropped: AtomicU32,
}

fn sink() -> &'static Sink {
    static SINK: OnceLock<Sink> = OnceLock::new();
    SINK.get_or_init(|| {
        let (tx, rx) = mpsc::sync_channel(QUEUE);
        Sink {
            tx,
            rx: std::sync::Mutex::new(Some(rx)),
            dropped: AtomicU32::new(0),
        }
    })
}

thread_local! {
    /// Set on the publisher thread: its own events are not forwarded.
    static PUBLISHING: Cell<bool> = const { Cell::new(false) };
}

/// Records the process dropped so far (the hand-off was full, or the topic refused them).
pub fn dropped() -> u32 {
    sink().dropped.load(Ordering::Relaxed)
}

/// The `tracing_subscriber` layer that copies each event into a [`LogRecord`] for
/// [`publish`]. Filter it to the levels wanted (the `scl` binary: INFO and above).
#[derive(Debug, Default, Clone, Copy)]
pub struct GraphLogLayer;

/// The level as a [`log_level`] value.
pub fn level_value(l: &Level) -> u32 {
    match *l {
        Level::ERROR => log_level::ERROR,
        Level::WARN => log_level::WARN,
        Level::INFO => log_level::INFO,
        Level::DEBUG => log_level::DEBUG,
        Level::TRACE => log_level::TRACE,
    }
}

/// Writes an event's fields into a record: the message, then ` key=value` for the others.
struct Text<'a>(&'a mut LogRecord);

impl std::fmt::Write for Text<'_> {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        // Cut at the record's end; the rest is left out, not an error.
        self.0.push_text(s);
        Ok(())
    }
}

impl Visit for Text<'_> {
    fn record_str(&mut self, field: &Field, value: &str) {
        use std::fmt::Write;
        if field.name() == "message" {
            self.0.push_text(value);
        } else {
            let _ = write!(self, " {}={value}", field.name());
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        use std::fmt::Write;
        if field.name() == "message" {
            let _ = write!(self, "{value:?}");
        } else {
            let _ = write!(self, " {}={value:?}", field.name());
        }
    }
}

/// The record of `event` at monotonic time `t_ns`.
pub fn record_of(event: &Event<'_>, t_ns: u64) -> LogRecord {
    let mut r = LogRecord::zeroed();
    r.t_ns = t_ns;
    r.pid = std::process::id();
    r.level = level_value(event.metadata().level());
    event.record(&mut Text(&mut r));
    r
}

impl<S: Subscriber> Layer<S> for GraphLogLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        if PUBLISHING.with(Cell::get) {
            return;
        }
        let r = record_of(event, ipc_types::time::now_ns());
        let s = sink();
        if s.tx.try_send(r).is_err() {
            s.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The running publisher thread; dropping it stops the thread (see the module's doc).
#[derive(Debug)]
pub struct LogPublisher {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// Starts publishing this process's records on graph `prefix`'s `log` topic as `process`
/// (`supervisor`, `mapper-2`, ...). `None` if it runs already or its thread did not start
/// (the records are then kept in the hand-off, at most [`QUEUE`], and counted as dropped).
pub fn publish(prefix: &Prefix, process: &str) -> Option<LogPublisher> {
    let rx = sink().rx.lock().ok()?.take()?;
    let stop = Arc::new(AtomicBool::new(false));
    let (p, name, stop2) = (prefix.clone(), process.to_owned(), stop.clone());
    let thread = std::thread::Builder::new()
        .name("log-publish".into())
        .spawn(move || publish_loop(&p, &name, &rx, &stop2))
        .ok()?;
    Some(LogPublisher {
        stop,
        thread: Some(thread),
    })
}

fn publish_loop(prefix: &Prefix, process: &str, rx: &mpsc::Receiver<LogRecord>, stop: &AtomicBool) {
    PUBLISHING.with(|p| p.set(true));
    crate::rt::lower_priority();
    let s = sink();
    let port = transport::Graph::join(prefix, &format!("{process}-log"))
        .and_then(|g| g.log_publisher().map(|p| (g, p)));
    // Without the topic the records are taken and counted as dropped, so the channel never
    // holds anyone up.
    let port = port.ok();
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(mut r) => {
                r.set_process(process);
                r.dropped = s.dropped.load(Ordering::Relaxed);
                let sent = port.as_ref().is_some_and(|(_, p)| p.send(r).is_ok());
                if !sent {
                    s.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                // A reader that came since the last record gets the last few now.
                if let Some((_, p)) = &port {
                    p.update_connections();
                }
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
    }
    drop(port);
    let _ = transport::graph::release_domain(prefix);
}

impl Drop for LogPublisher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tracing_subscriber::layer::SubscriberExt;

    /// The layer writes the message and its fields, cut at the record's size, and never
    /// waits: beyond the hand-off's capacity records are dropped and counted.
    #[test]
    fn records_carry_the_text_and_a_full_hand_off_drops_and_counts() {
        let subscriber = tracing_subscriber::registry().with(GraphLogLayer);
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!(tick = 7, "stopping the arm");
            let long = "x".repeat(2 * ipc_types::LOG_TEXT_BYTES);
            tracing::error!("{long}");
            for i in 0..QUEUE {
                tracing::info!(i, "filler");
            }
        });
        let rx = sink().rx.lock().unwrap().take().unwrap();
        let first = rx.try_recv().unwrap();
        assert_eq!(first.level, log_level::WARN);
        assert_eq!(first.text(), "stopping the arm tick=7");
        assert_eq!(first.pid, std::process::id());
        let second = rx.try_recv().unwrap();
        assert_eq!(second.level, log_level::ERROR);
        assert_eq!(second.text_len as usize, ipc_types::LOG_TEXT_BYTES);
        let mut n = 2;
        while rx.try_recv().is_ok() {
            n += 1;
        }
        assert_eq!(n, QUEUE);
        assert_eq!(dropped(), 2, "the two records beyond the capacity");
    }
}
