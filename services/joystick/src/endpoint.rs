//! Where the joystick's samples go and its robot states come from: the graph's shared memory
//! on the robot PC ([`Local`]), or a graph's gateway on another machine through Zenoh
//! ([`Remote`], `scl joystick --remote ENDPOINT`). The loop ([`crate::run`]) is the same
//! for both, so every rule of a local joystick holds for a remote one: a sample answers the
//! newest robot tick this side has seen, one goes out on every tick and on every change, and
//! an e-stop press goes out on its own channel too.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use ipc_types::control::EstopCommand;
use ipc_types::{JoystickInput, NodeStatus, RobotState};
use scl_net::ports::{self, Out, Urgency};
use scl_net::session;
use scl_net::wire::link_state;
use scl_net::{GatewayStatus, Keys};
use transport::Waker;
use transport::graph::Wakeable;

use crate::JoystickError;

/// What the loop needs from where it publishes.
pub(crate) trait Endpoint {
    /// Waits for a robot state or the source thread's `waker`, at most `timeout`.
    fn wait(&self, waker: Option<&Waker>, timeout: Duration) -> Result<(), JoystickError>;
    /// The newest robot state that arrived since the last call.
    fn latest_state(&mut self) -> Result<Option<RobotState>, JoystickError>;
    /// Publishes a sample.
    fn send_sample(&mut self, s: JoystickInput) -> Result<(), JoystickError>;
    /// Publishes an e-stop press.
    fn send_estop(&mut self, c: EstopCommand) -> Result<(), JoystickError>;
    /// The other nodes' heartbeats that arrived, if this endpoint reads them.
    fn heartbeats(&mut self, f: &mut dyn FnMut(&NodeStatus)) -> Result<(), JoystickError>;
    /// Where the samples go, for the log.
    fn describe(&self) -> String;
    /// A line for the operator's screen, if this endpoint has one to show.
    fn status_line(&mut self) -> Option<String> {
        None
    }
    /// Logs what the endpoint measured, at the end of the run.
    fn finish(&self) {}
}

/// The graph on this machine.
pub(crate) struct Local {
    pub(crate) samples: transport::TopicPublisher<JoystickInput>,
    /// Kept for the process's life: a sample of a publisher that is gone is not delivered.
    pub(crate) estop: transport::control::EstopPublisher,
    pub(crate) states: transport::TopicSubscriber<RobotState>,
    pub(crate) heartbeats: Option<transport::TopicSubscriber<NodeStatus>>,
}

impl Endpoint for Local {
    fn wait(&self, waker: Option<&Waker>, timeout: Duration) -> Result<(), JoystickError> {
        // `wait_any` keeps the timeout's nanoseconds: a late sample is due at its time.
        match waker {
            Some(w) => {
                let wakes: [&dyn Wakeable; 2] = [&self.states, w];
                transport::wait_any(&wakes, timeout);
            }
            None => {
                transport::wait_any(&[&self.states as &dyn Wakeable], timeout);
            }
        }
        Ok(())
    }

    fn latest_state(&mut self) -> Result<Option<RobotState>, JoystickError> {
        Ok(self.states.latest()?)
    }

    fn send_sample(&mut self, s: JoystickInput) -> Result<(), JoystickError> {
        self.samples.send(s)?;
        Ok(())
    }

    fn send_estop(&mut self, c: EstopCommand) -> Result<(), JoystickError> {
        self.estop.send(c)?;
        Ok(())
    }

    fn heartbeats(&mut self, f: &mut dyn FnMut(&NodeStatus)) -> Result<(), JoystickError> {
        if let Some(h) = &self.heartbeats {
            h.drain(|s| f(s))?;
        }
        Ok(())
    }

    fn describe(&self) -> String {
        self.samples.service().to_owned()
    }
}

/// `scl joystick --remote`: where the graph is and how to log in.
#[derive(Debug, Clone)]
pub struct RemoteOptions {
    /// The gateway's endpoint (`tcp/HOST:PORT`).
    pub endpoint: String,
    /// The credentials file (`user:password`, mode 0600).
    pub credentials: PathBuf,
    /// The graph's namespace.
    pub namespace: String,
    /// Zenoh's lease (ms).
    pub lease_ms: u64,
}

/// What arrives from the network, in the callbacks' order.
enum Arrival {
    State(RobotState),
    Gateway(GatewayStatus),
}

/// Samples sent recently, for the round trip: `(seq, when)`.
const SENT_KEPT: usize = 256;

/// Round trips kept for the figures at the end (an hour at 40 Hz).
const RTT_KEPT: usize = 144_000;

/// A graph's gateway on another machine.
pub(crate) struct Remote {
    endpoint: String,
    samples: Out<JoystickInput>,
    estop: Out<EstopCommand>,
    rx: Receiver<Arrival>,
    waker: Arc<Waker>,
    sent: std::collections::VecDeque<(u64, Instant)>,
    rtt: Option<Duration>,
    /// Every round trip measured (ns), for the figures at the end (at most `RTT_KEPT`).
    rtts: Vec<u64>,
    gateway: Option<GatewayStatus>,
    state: Option<RobotState>,
    /// Kept for the process's life: the token says this operator is here, the subscribers
    /// feed `rx`; the session must outlive them all (dropped last).
    _token: scl_net::zenoh::liveliness::LivelinessToken,
    _subscribers: Vec<scl_net::zenoh::pubsub::Subscriber<()>>,
    _session: scl_net::zenoh::Session,
}

impl Remote {
    /// Opens a client session to `opts.endpoint` (authenticated), declares the operator's
    /// liveliness token, subscribes to the robot states and the gateway's status.
    pub(crate) fn open(opts: &RemoteOptions) -> Result<Self, JoystickError> {
        let (s, creds) =
            session::open_client(&opts.endpoint, Some(&opts.credentials), opts.lease_ms)?;
        let user = creds.map(|c| c.own().user.clone()).unwrap_or_default();
        let zid = session::session_id(&s);
        let keys = Keys::new(&opts.namespace);
        let waker = Arc::new(Waker::new().map_err(|source| JoystickError::Thread {
            what: "network wake-up",
            source,
        })?);
        let (tx, rx) = crossbeam_channel::bounded(256);
        let hand = |tx: Sender<Arrival>, waker: Arc<Waker>| {
            move |a: Arrival| {
                if tx.try_send(a).is_ok() {
                    waker.notify();
                }
            }
        };
        let on_state = hand(tx.clone(), Arc::clone(&waker));
        let on_gateway = hand(tx, Arc::clone(&waker));
        let subscribers = vec![
            ports::subscribe::<RobotState, _>(
                &s,
                keys.topic(ipc_types::topics::ROBOT_STATE.name),
                move |_, m| {
                    if let Ok(m) = m {
                        on_state(Arrival::State(m));
                    }
                },
            )?,
            ports::subscribe::<GatewayStatus, _>(&s, keys.gateway(), move |_, m| {
                if let Ok(m) = m {
                    on_gateway(Arrival::Gateway(m));
                }
            })?,
        ];
        let samples = ports::publisher(&s, keys.joystick(&zid), Urgency::Control)?;
        let estop = ports::publisher(&s, keys.estop(), Urgency::Control)?;
        let token = ports::token(&s, keys.operator(&zid))?;
        tracing::info!(
            endpoint = %opts.endpoint,
            namespace = keys.namespace(),
            session = %zid,
            user = %user,
            "joined the graph's gateway"
        );
        Ok(Self {
            endpoint: opts.endpoint.clone(),
            samples,
            estop,
            rx,
            waker,
            sent: std::collections::VecDeque::with_capacity(SENT_KEPT),
            rtt: None,
            rtts: Vec::new(),
            gateway: None,
            state: None,
            _token: token,
            _subscribers: subscribers,
            _session: s,
        })
    }

    fn take_gateway(&mut self, g: GatewayStatus) {
        let fresh = self.gateway.is_none_or(|old| old.acked_seq != g.acked_seq);
        if let Some(&(_, at)) = self.sent.iter().find(|(seq, _)| *seq == g.acked_seq)
            && fresh
        {
            let rtt = at.elapsed();
            self.rtt = Some(rtt);
            if self.rtts.len() < RTT_KEPT {
                self.rtts
                    .push(u64::try_from(rtt.as_nanos()).unwrap_or(u64::MAX));
            }
        }
        self.gateway = Some(g);
    }
}

impl Endpoint for Remote {
    fn wait(&self, waker: Option<&Waker>, timeout: Duration) -> Result<(), JoystickError> {
        match waker {
            Some(w) => {
                let wakes: [&dyn Wakeable; 2] = [&*self.waker, w];
                transport::wait_any(&wakes, timeout);
            }
            None => {
                let wakes: [&dyn Wakeable; 1] = [&*self.waker];
                transport::wait_any(&wakes, timeout);
            }
        }
        Ok(())
    }

    fn latest_state(&mut self) -> Result<Option<RobotState>, JoystickError> {
        let mut newest = None;
        while let Ok(a) = self.rx.try_recv() {
            match a {
                Arrival::State(s) => newest = Some(s),
                Arrival::Gateway(g) => self.take_gateway(g),
            }
        }
        if newest.is_some() {
            self.state = newest;
        }
        Ok(newest)
    }

    fn send_sample(&mut self, s: JoystickInput) -> Result<(), JoystickError> {
        if self.sent.len() == SENT_KEPT {
            self.sent.pop_front();
        }
        self.sent.push_back((s.seq, Instant::now()));
        self.samples
            .put(&s)
            .map_err(|source| JoystickError::Network {
                key: self.samples.key().to_owned(),
                source,
            })
    }

    fn send_estop(&mut self, c: EstopCommand) -> Result<(), JoystickError> {
        self.estop.put(&c).map_err(|source| JoystickError::Network {
            key: self.estop.key().to_owned(),
            source,
        })
    }

    fn heartbeats(&mut self, _: &mut dyn FnMut(&NodeStatus)) -> Result<(), JoystickError> {
        Ok(())
    }

    fn describe(&self) -> String {
        format!("{} (remote)", self.samples.key())
    }

    fn finish(&self) {
        let p = node_rt::stats::percentiles_us(&self.rtts);
        tracing::info!(
            acknowledged = self.rtts.len(),
            p50_us = format!("{:.0}", p.p50),
            p99_us = format!("{:.0}", p.p99),
            max_us = format!("{:.0}", p.max),
            "round trip to the gateway (sample sent -> its acknowledgement)"
        );
    }

    fn status_line(&mut self) -> Option<String> {
        Some(remote_line(
            &self.endpoint,
            self.gateway.as_ref(),
            self.rtt,
            self.state.as_ref(),
        ))
    }
}

/// The remote operator's line: the link as the gateway judges it, the round trip of the last
/// acknowledged sample, and the arm.
pub(crate) fn remote_line(
    endpoint: &str,
    g: Option<&GatewayStatus>,
    rtt: Option<Duration>,
    s: Option<&RobotState>,
) -> String {
    let link = g.map_or("no word from the gateway", |g| {
        link_state::NAMES
            .get(g.link as usize)
            .copied()
            .unwrap_or("unknown")
    });
    let rtt = rtt.map_or("-".to_owned(), |d| {
        format!("{:.1} ms", d.as_secs_f64() * 1e3)
    });
    let arm = s.map_or("no state yet".to_owned(), |s| {
        let moving = s.qdot().iter().any(|v| v.abs() > 1e-3);
        format!(
            "tick {} {}",
            s.tick,
            if moving { "moving" } else { "at rest" }
        )
    });
    format!("{endpoint}: link {link}, round trip {rtt}, arm {arm}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_operators_line_says_link_round_trip_and_arm() {
        let g = GatewayStatus {
            link: link_state::LIVE,
            ..GatewayStatus::default()
        };
        let s = RobotState::at_rest(12, 0, 6);
        let line = remote_line(
            "tcp/10.0.0.2:7447",
            Some(&g),
            Some(Duration::from_micros(1500)),
            Some(&s),
        );
        assert_eq!(
            line,
            "tcp/10.0.0.2:7447: link live, round trip 1.5 ms, arm tick 12 at rest"
        );
        assert!(remote_line("e", None, None, None).contains("no word from the gateway"));
    }
}
