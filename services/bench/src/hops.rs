//! `scl bench hops`: the floor under the graph's figures. One hop, publish to receive, on
//! each transport, with the receiver polling its subscriber (iceoryx2: reading shared
//! memory; sockets: a non-blocking read's `ppoll`) and with the receiver waiting for the
//! event, all in one run on the same machine.
//!
//! The publisher and the receiver are two threads, each its own node of a fresh graph (the
//! same shared memory and sockets two processes would use). The publisher stamps each
//! `RobotState` with the monotonic clock just before the send; the receiver takes the clock
//! as soon as it has the message.

use std::time::Duration;

use ipc_types::time::now_ns;
use ipc_types::{Prefix, RobotState, Transport};
use serde::Serialize;
use transport::Graph;

use crate::{BenchError, Dist};

/// What `scl bench hops` was asked to do.
#[derive(Debug, Clone)]
pub struct HopsOptions {
    /// Messages per transport and mode.
    pub count: usize,
    /// Time between two messages.
    pub interval: Duration,
    /// The transports.
    pub transports: Vec<Transport>,
}

/// How the receiver waits.
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// A busy loop over the subscriber.
    Polled,
    /// The topic's event (iceoryx2) or the socket's readiness (`ppoll`).
    Event,
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Polled => "polled",
            Self::Event => "event",
        })
    }
}

/// One transport in one mode.
#[derive(Debug, Clone, Serialize)]
pub struct HopRow {
    /// The transport.
    pub transport: Transport,
    /// How the receiver waited.
    pub mode: Mode,
    /// Publish to receive (µs).
    pub us: Dist,
    /// Messages sent.
    pub sent: usize,
    /// Messages the transport took: a socket refuses a datagram its reader's queue has no
    /// room for (`net.unix.max_dgram_qlen`, 10 by default, when the reader is descheduled);
    /// shared memory takes every one (its buffer holds 64).
    pub accepted: usize,
}

/// The whole result (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct HopsReport {
    /// The machine.
    pub machine: crate::Machine,
    /// Time between messages (µs).
    pub interval_us: f64,
    /// One row per transport and mode.
    pub rows: Vec<HopRow>,
    /// Per mode: iceoryx2 / uds of p50, p99, max, when both ran.
    pub ratios: Vec<(Mode, f64, f64, f64)>,
}

/// Runs one hop `count` times on `transport` in `mode`; returns the latencies (ns) and how
/// many messages the transport took.
fn one(
    opts: &HopsOptions,
    transport: Transport,
    mode: Mode,
) -> Result<(Vec<u64>, usize), BenchError> {
    let prefix = Prefix::new(&format!("hops{}{transport}{mode}", std::process::id()))
        .map_err(|e| BenchError::Graph(e.to_string()))?;
    let count = opts.count;
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
    let rx_prefix = prefix.clone();
    // The receiver gives up this long after the last message was due (lost datagrams).
    let give_up = Duration::from_secs(2) + opts.interval * count as u32;
    let receiver = std::thread::spawn(move || -> Result<Vec<u64>, String> {
        let graph =
            Graph::join_with(&rx_prefix, "hops-rx", transport).map_err(|e| e.to_string())?;
        let sub = graph
            .robot_state_subscriber(mode == Mode::Event)
            .map_err(|e| e.to_string())?;
        let _ = ready_tx.send(Ok(()));
        let mut out = Vec::with_capacity(count);
        let end = std::time::Instant::now() + give_up;
        while out.len() < count && std::time::Instant::now() < end {
            let mut take = |m: &RobotState| {
                let t = now_ns();
                if m.tick != u64::MAX {
                    out.push(t.saturating_sub(m.t_ns));
                }
            };
            match mode {
                Mode::Polled => {
                    if sub.has_pending() {
                        sub.drain(&mut take).map_err(|e| e.to_string())?;
                    } else {
                        std::hint::spin_loop();
                    }
                }
                Mode::Event => {
                    sub.wait(Duration::from_millis(100))
                        .map_err(|e| e.to_string())?;
                    sub.drain(&mut take).map_err(|e| e.to_string())?;
                }
            }
        }
        Ok(out)
    });
    let publish = || -> Result<usize, BenchError> {
        let graph = Graph::join_with(&prefix, "hops-tx", transport)?;
        let publ = graph.robot_state_publisher()?;
        match ready_rx.recv_timeout(Duration::from_secs(10)) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(BenchError::Graph(e)),
            Err(_) => return Err(BenchError::Graph("the receiver did not start".into())),
        }
        // Connect the subscriber, then a warm-up message the receiver does not count.
        publ.update_connections();
        publ.send(RobotState::at_rest(u64::MAX, now_ns(), 6))?;
        std::thread::sleep(Duration::from_millis(20));
        let mut next = now_ns();
        let mut accepted = 0;
        for i in 0..count {
            next += opts.interval.as_nanos() as u64;
            while now_ns() < next {
                std::thread::sleep(Duration::from_micros(50).min(opts.interval));
            }
            let mut s = RobotState::at_rest(i as u64, 0, 6);
            s.t_ns = now_ns();
            accepted += publ.send(s)?.min(1);
        }
        // Keep the publisher until the receiver is done (sockets: its files).
        Ok(accepted)
    };
    let sent = publish();
    let got = receiver
        .join()
        .map_err(|_| BenchError::Graph("the receiver panicked".into()))?;
    let _ = transport::graph::release_domain(&prefix);
    transport::uds::remove_graph(prefix.as_str());
    let accepted = sent?;
    Ok((got.map_err(BenchError::Graph)?, accepted))
}

/// Runs every transport in both modes.
pub fn hops(opts: &HopsOptions) -> Result<HopsReport, BenchError> {
    let mut rows = Vec::new();
    for t in &opts.transports {
        for mode in [Mode::Polled, Mode::Event] {
            if transport::signals::stop_requested() {
                break;
            }
            eprintln!("bench: hops, {t}, {mode}, {} messages", opts.count);
            let (lat, accepted) = one(opts, *t, mode)?;
            rows.push(HopRow {
                transport: *t,
                mode,
                us: Dist::of(&lat),
                sent: opts.count,
                accepted,
            });
        }
    }
    let mut ratios = Vec::new();
    for mode in [Mode::Polled, Mode::Event] {
        let find = |t| rows.iter().find(|r| r.transport == t && r.mode == mode);
        if let (Some(i), Some(u)) = (find(Transport::Iceoryx2), find(Transport::Uds)) {
            let r = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
            ratios.push((
                mode,
                r(i.us.p50, u.us.p50),
                r(i.us.p99, u.us.p99),
                r(i.us.max, u.us.max),
            ));
        }
    }
    Ok(HopsReport {
        machine: crate::Machine::detect(),
        interval_us: opts.interval.as_secs_f64() * 1e6,
        rows,
        ratios,
    })
}

/// The report as a table.
pub fn render(r: &HopsReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{}; one message every {:.0} µs",
        r.machine, r.interval_us
    );
    let _ = writeln!(
        s,
        "\none hop, publish -> receive (µs)\n  {:<9} {:<7} {:>9} {:>9} {:>9} {:>9}",
        "transport", "wait", "received", "p50", "p99", "max"
    );
    for row in &r.rows {
        let _ = writeln!(
            s,
            "  {:<9} {:<7} {:>9} {:>9.1} {:>9.1} {:>9.1}",
            row.transport.to_string(),
            row.mode.to_string(),
            format!("{}/{}", row.us.n, row.sent),
            row.us.p50,
            row.us.p99,
            row.us.max
        );
    }
    if !r.ratios.is_empty() {
        let _ = writeln!(
            s,
            "\niceoryx2 / uds (below 1: iceoryx2 faster)\n  {:<7} {:>7} {:>7} {:>7}",
            "", "p50", "p99", "max"
        );
        for (mode, a, b, c) in &r.ratios {
            let _ = writeln!(s, "  {:<7} {a:>7.2} {b:>7.2} {c:>7.2}", mode.to_string());
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A short run of both transports in both modes: every message arrives, each latency is
    /// positive, and nothing is left in shared memory.
    #[test]
    fn a_short_run_measures_every_transport_in_both_modes() {
        let opts = HopsOptions {
            count: 50,
            interval: Duration::from_micros(500),
            transports: vec![Transport::Iceoryx2, Transport::Uds],
        };
        let r = hops(&opts).unwrap();
        assert_eq!(r.rows.len(), 4);
        for row in &r.rows {
            // Every message the transport took arrives. A socket refuses a datagram its
            // reader has no room for (counted, not hidden: the table shows received / sent),
            // as many as the machine's scheduling makes; shared memory takes every one here.
            assert_eq!(row.us.n, row.accepted, "{row:?}");
            assert!(row.accepted > 0, "{row:?}");
            if row.transport == Transport::Iceoryx2 {
                assert_eq!(row.accepted, 50, "{row:?}");
            }
            assert!(row.us.p50 > 0.0, "{row:?}");
        }
        assert_eq!(r.ratios.len(), 2);
        let t = render(&r);
        assert!(t.contains("polled") && t.contains("event"), "{t}");
        let pid = std::process::id().to_string();
        let left: Vec<String> = std::fs::read_dir("/dev/shm")
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.contains("hops") && n.contains(&pid))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }
}
