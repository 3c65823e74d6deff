//! `scl live --client ADDR:PORT`: a Foxglove client of a Foxglove WebSocket server (an `scl
//! live`, `scl up --live`, or any other), doing what Foxglove does when it opens a connection:
//! it subscribes to every channel the server advertises (channels advertised later too) and
//! reads every frame, until Ctrl-C / SIGTERM. Each second it reports the frames received so
//! far, so a soak (`scripts/soak.sh`) can show that a client stayed attached and served for
//! the whole run, and a lab can check from another machine that the robot PC's server serves.
//!
//! A lost connection is reconnected (and counted): a server that restarts is served again.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use transport::signals;
use viz::client::{Client, ClientError};

/// How long the client waits for the first connection before it gives up.
const FIRST_CONNECT_TIMEOUT: Duration = Duration::from_secs(30);
/// Between reports.
const REPORT_EVERY: Duration = Duration::from_secs(1);

/// Why `scl live --client` stopped.
#[derive(Debug, thiserror::Error)]
pub enum ClientRunError {
    /// No connection within [`FIRST_CONNECT_TIMEOUT`] (the last attempt's error).
    #[error("no Foxglove server at {addr} within {timeout_s} s: {source}")]
    NoServer {
        /// The address.
        addr: String,
        /// Seconds waited.
        timeout_s: u64,
        /// The last attempt's error.
        source: ClientError,
    },
}

/// What a client session received: the end report, and each second's progress line.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ClientReport {
    /// The server's address.
    pub addr: String,
    /// Seconds since the client started.
    pub t_s: f64,
    /// Connections made (1 for a session that never lost its server).
    pub connects: u64,
    /// Channels subscribed to, over every connection.
    pub channels: usize,
    /// Message frames received, over every connection.
    pub frames: u64,
    /// Frames per topic.
    pub per_topic: BTreeMap<String, u64>,
    /// Whether the client is connected at the time of the report.
    pub connected: bool,
}

/// Connects to `addr` and reads until a stop is requested; calls `progress` each second with
/// the counts so far. Returns the end report.
pub fn run(
    addr: &str,
    mut progress: impl FnMut(&ClientReport),
) -> Result<ClientReport, ClientRunError> {
    let started = Instant::now();
    let mut report = ClientReport {
        addr: addr.to_owned(),
        ..ClientReport::default()
    };
    let mut topics: BTreeSet<String> = BTreeSet::new();
    let mut next_report = started + REPORT_EVERY;
    let mut client: Option<(Client, BTreeSet<u64>)> = None;
    while !signals::stop_requested() {
        let now = Instant::now();
        if now >= next_report {
            report.t_s = started.elapsed().as_secs_f64();
            report.connected = client.is_some();
            report.channels = topics.len();
            progress(&report);
            next_report += REPORT_EVERY;
        }
        let Some((c, subscribed)) = client.as_mut() else {
            match Client::connect(addr, Duration::from_secs(1)) {
                Ok(c) => {
                    report.connects += 1;
                    tracing::info!(addr, channels = c.channels.len(), "connected");
                    client = Some((c, BTreeSet::new()));
                }
                Err(e) => {
                    if report.connects == 0 && started.elapsed() > FIRST_CONNECT_TIMEOUT {
                        return Err(ClientRunError::NoServer {
                            addr: addr.to_owned(),
                            timeout_s: FIRST_CONNECT_TIMEOUT.as_secs(),
                            source: e,
                        });
                    }
                    tracing::debug!(addr, error = %e, "no server yet");
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
            continue;
        };
        // Channels advertised since the last look (all of them on a new connection).
        let new: Vec<u64> = c
            .channels
            .keys()
            .filter(|id| !subscribed.contains(id))
            .copied()
            .collect();
        let read = if new.is_empty() {
            c.next_frame()
        } else {
            c.subscribe(&new).map(|()| None)
        };
        match read {
            Ok(Some(frame)) => {
                report.frames += 1;
                let id = u64::from(frame.subscription);
                if let Some(ch) = c.channels.get(&id) {
                    *report.per_topic.entry(ch.topic.clone()).or_default() += 1;
                }
            }
            Ok(None) => {
                for id in new {
                    subscribed.insert(id);
                    if let Some(ch) = c.channels.get(&id) {
                        topics.insert(ch.topic.clone());
                    }
                }
            }
            // A read that a stop's signal interrupted is not a lost server.
            Err(_) if signals::stop_requested() => break,
            Err(e) => {
                tracing::warn!(addr, error = %e, "connection lost; reconnecting");
                client = None;
            }
        }
    }
    if let Some((c, _)) = client.take() {
        c.close();
        report.connected = true;
    }
    report.t_s = started.elapsed().as_secs_f64();
    report.channels = topics.len();
    Ok(report)
}
