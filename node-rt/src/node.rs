//! The one node contract: how a graph process says it is alive and stops. A node publishes
//! its [`NodeStatus`] on the graph's status topic: `READY` once its ports are open,
//! `RUNNING` with its counts as its loop handles ticks, `STOPPING` as its last word. The
//! [`Heartbeat`] holds that status and its phase; [`run`] turns a [`Node`]'s step until a
//! stop is requested (SIGINT / SIGTERM: `transport::signals`), sends the heartbeat when the
//! step asks for one, and ends with the node's [`Node::finish`] and the `STOPPING` heartbeat.
//! A node's own code holds its topics and its step, nothing of the lifecycle.
//!
//! ```
//! use ipc_types::{NodeRole, NodeStatus, phase};
//! use node_rt::node::{Heartbeat, Node, Turn, run_until};
//!
//! /// Counts three ticks, then its stop flag is raised.
//! struct Counter(u64);
//!
//! impl Node for Counter {
//!     type Error = std::convert::Infallible;
//!     fn step(&mut self, st: &mut NodeStatus) -> Result<Turn, Self::Error> {
//!         self.0 += 1;
//!         st.tick = self.0;
//!         st.handled += 1;
//!         Ok(Turn::Beat)
//!     }
//! }
//!
//! let mut sent: Vec<NodeStatus> = Vec::new();
//! let hb = Heartbeat::ready(&mut sent, NodeRole::Mapper, |_| {}).unwrap();
//! let mut node = Counter(0);
//! let last = run_until(&mut node, hb, |n: &Counter| n.0 == 3).unwrap();
//! assert_eq!(last.phase, phase::STOPPING);
//! let phases: Vec<u32> = sent.iter().map(|s| s.phase).collect();
//! assert_eq!(phases, [phase::READY, phase::RUNNING, phase::RUNNING, phase::RUNNING, phase::STOPPING]);
//! ```

use ipc_types::{NodeRole, NodeStatus, phase, time::now_ns};
use transport::{IpcError, TopicPublisher, signals};

/// Where a node's heartbeats go: the graph's status topic, or what a test reads back.
pub trait StatusSink {
    /// Why a heartbeat could not be sent.
    type Error;
    /// Sends one heartbeat.
    fn send_status(&mut self, st: NodeStatus) -> Result<(), Self::Error>;
}

impl StatusSink for TopicPublisher<NodeStatus> {
    type Error = IpcError;

    fn send_status(&mut self, st: NodeStatus) -> Result<(), IpcError> {
        self.send(st).map(|_| ())
    }
}

/// A list of the heartbeats sent, in order (a test's sink).
impl StatusSink for Vec<NodeStatus> {
    type Error = std::convert::Infallible;

    fn send_status(&mut self, st: NodeStatus) -> Result<(), Self::Error> {
        self.push(st);
        Ok(())
    }
}

/// A publisher the node shares with its own code (e.g. to drop it last).
impl StatusSink for &TopicPublisher<NodeStatus> {
    type Error = IpcError;

    fn send_status(&mut self, st: NodeStatus) -> Result<(), IpcError> {
        self.send(st).map(|_| ())
    }
}

/// Heartbeats for a node that has a status topic (`Some`), or none for one that has not (a
/// remote operator's joystick: the gateway is its node in the graph).
impl<S: StatusSink> StatusSink for Option<S> {
    type Error = S::Error;

    fn send_status(&mut self, st: NodeStatus) -> Result<(), Self::Error> {
        match self {
            Some(s) => s.send_status(st),
            None => Ok(()),
        }
    }
}

impl<S: StatusSink + ?Sized> StatusSink for &mut S {
    type Error = S::Error;

    fn send_status(&mut self, st: NodeStatus) -> Result<(), Self::Error> {
        (**self).send_status(st)
    }
}

/// A node's status and where it goes. Made by [`Heartbeat::ready`] (the `READY` heartbeat
/// sent, the status `RUNNING` from then on), or by [`Heartbeat::new`] and
/// [`Heartbeat::say_ready`] where a node goes on to its end even when the `READY` heartbeat
/// could not be sent; ended by [`Heartbeat::stop`] (the `STOPPING` one).
#[derive(Debug)]
pub struct Heartbeat<S> {
    sink: S,
    st: NodeStatus,
}

impl<S: StatusSink> Heartbeat<S> {
    /// Sends the `READY` heartbeat of a `role` node, stamped now, with the fields `init` fills
    /// in (e.g. a mapper's id and mode); the status is `RUNNING` from here on.
    pub fn ready(
        sink: S,
        role: NodeRole,
        init: impl FnOnce(&mut NodeStatus),
    ) -> Result<Self, S::Error> {
        let mut hb = Self::new(sink, role);
        init(&mut hb.st);
        hb.say_ready()?;
        Ok(hb)
    }

    /// The `READY` status of a `role` node, stamped now, not yet sent.
    pub fn new(sink: S, role: NodeRole) -> Self {
        Self {
            sink,
            st: NodeStatus::new(role, phase::READY, now_ns()),
        }
    }

    /// Sends the `READY` heartbeat (the status as [`Heartbeat::new`] made it, with what the
    /// node filled in); the status is `RUNNING` from here on, whether it could be sent or not.
    pub fn say_ready(&mut self) -> Result<(), S::Error> {
        self.st.phase = phase::READY;
        let sent = self.sink.send_status(self.st);
        self.st.phase = phase::RUNNING;
        sent
    }

    /// The status the next heartbeat carries.
    pub fn status(&self) -> &NodeStatus {
        &self.st
    }

    /// The status the next heartbeat carries, for the node to count in.
    pub fn status_mut(&mut self) -> &mut NodeStatus {
        &mut self.st
    }

    /// Sends the status as it is (the node stamps its `t_ns` and counts).
    pub fn beat(&mut self) -> Result<(), S::Error> {
        self.sink.send_status(self.st)
    }

    /// Sends the last heartbeat: `STOPPING`, stamped now, with the counts so far. Returns
    /// that status (e.g. for the node's closing log).
    pub fn stop(mut self) -> Result<NodeStatus, S::Error> {
        self.st.phase = phase::STOPPING;
        self.st.t_ns = now_ns();
        self.sink.send_status(self.st)?;
        Ok(self.st)
    }
}

/// What a turn of a node's loop asks of the runner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Turn {
    /// Send the heartbeat (the step counted in it).
    Beat,
    /// Nothing to say this turn.
    Quiet,
}

/// A graph process's loop: its step, run by [`run`] between its `READY` and its `STOPPING`
/// heartbeats.
pub trait Node {
    /// Why the node stopped (a heartbeat that could not be sent among it).
    type Error;

    /// One turn: waits for the node's input (with a timeout, so a stop request is seen) and
    /// handles it, counting in `st` what the heartbeat reports.
    fn step(&mut self, st: &mut NodeStatus) -> Result<Turn, Self::Error>;

    /// After the last turn, before the `STOPPING` heartbeat (e.g. the node's closing log).
    fn finish(&mut self, st: &mut NodeStatus) -> Result<(), Self::Error> {
        let _ = st;
        Ok(())
    }
}

/// Turns `node` until a stop is requested (`transport::signals`), then finishes it and sends
/// the `STOPPING` heartbeat, whose status it returns. An error of a step ends the node at
/// once, with no `STOPPING` heartbeat.
pub fn run<N, S>(node: &mut N, heartbeat: Heartbeat<S>) -> Result<NodeStatus, N::Error>
where
    N: Node,
    S: StatusSink,
    N::Error: From<S::Error>,
{
    run_until(node, heartbeat, |_: &N| signals::stop_requested())
}

/// [`run`], stopping when `stop` says so (checked before each turn).
pub fn run_until<N, S>(
    node: &mut N,
    mut heartbeat: Heartbeat<S>,
    stop: impl Fn(&N) -> bool,
) -> Result<NodeStatus, N::Error>
where
    N: Node,
    S: StatusSink,
    N::Error: From<S::Error>,
{
    while !stop(node) {
        if node.step(heartbeat.status_mut())? == Turn::Beat {
            heartbeat.beat()?;
        }
    }
    node.finish(heartbeat.status_mut())?;
    Ok(heartbeat.stop()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::NO_TICK;

    /// Handles a tick on every other turn (a heartbeat then), fails on turn `fail_at`.
    struct Fake {
        turns: u64,
        fail_at: u64,
        finished: bool,
    }

    #[derive(Debug, PartialEq)]
    enum FakeError {
        Step(u64),
    }

    impl From<std::convert::Infallible> for FakeError {
        fn from(e: std::convert::Infallible) -> Self {
            match e {}
        }
    }

    impl Node for Fake {
        type Error = FakeError;

        fn step(&mut self, st: &mut NodeStatus) -> Result<Turn, FakeError> {
            self.turns += 1;
            if self.turns == self.fail_at {
                return Err(FakeError::Step(self.turns));
            }
            if self.turns % 2 == 1 {
                return Ok(Turn::Quiet);
            }
            st.t_ns = now_ns();
            st.tick = self.turns / 2;
            st.handled += 1;
            Ok(Turn::Beat)
        }

        fn finish(&mut self, st: &mut NodeStatus) -> Result<(), FakeError> {
            self.finished = true;
            st.faults = 7;
            Ok(())
        }
    }

    fn fake(fail_at: u64) -> Fake {
        Fake {
            turns: 0,
            fail_at,
            finished: false,
        }
    }

    #[test]
    fn ready_running_stopping_with_the_steps_counts() {
        let mut sent = Vec::new();
        let before = now_ns();
        let hb = Heartbeat::ready(&mut sent, NodeRole::Safety, |st| st.mapper_id = 3).unwrap();
        assert_eq!(hb.status().phase, phase::RUNNING);
        let mut node = fake(0);
        let last = run_until(&mut node, hb, |n: &Fake| n.turns == 6).unwrap();
        assert!(node.finished);
        let phases: Vec<u32> = sent.iter().map(|s| s.phase).collect();
        assert_eq!(
            phases,
            [
                phase::READY,
                phase::RUNNING,
                phase::RUNNING,
                phase::RUNNING,
                phase::STOPPING
            ]
        );
        // READY: stamped, the init's fields, nothing handled yet.
        assert!(sent[0].t_ns >= before);
        assert_eq!(
            (sent[0].tick, sent[0].handled, sent[0].mapper_id),
            (NO_TICK, 0, 3)
        );
        assert_eq!(sent[0].role, NodeRole::Safety as u32);
        // One heartbeat per handled tick, with its counts.
        let counts: Vec<(u64, u64)> = sent[1..4].iter().map(|s| (s.tick, s.handled)).collect();
        assert_eq!(counts, [(1, 1), (2, 2), (3, 3)]);
        // STOPPING: the counts so far, what `finish` added, stamped after the last tick.
        assert_eq!(last, sent[4]);
        assert_eq!((last.tick, last.handled, last.faults), (3, 3, 7));
        assert!(last.t_ns >= sent[3].t_ns);
        assert!(sent.iter().all(|s| s.pid == std::process::id()));
    }

    #[test]
    fn a_failed_step_ends_the_node_without_stopping() {
        let mut sent = Vec::new();
        let hb = Heartbeat::ready(&mut sent, NodeRole::Mapper, |_| {}).unwrap();
        let mut node = fake(4);
        let r = run_until(&mut node, hb, |_: &Fake| false);
        assert_eq!(r, Err(FakeError::Step(4)));
        assert!(!node.finished);
        let phases: Vec<u32> = sent.iter().map(|s| s.phase).collect();
        assert_eq!(phases, [phase::READY, phase::RUNNING]);
    }

    #[test]
    fn a_stop_before_the_first_turn_says_ready_then_stopping() {
        let mut sent = Vec::new();
        let hb = Heartbeat::ready(&mut sent, NodeRole::Gateway, |_| {}).unwrap();
        let mut node = fake(0);
        run_until(&mut node, hb, |_: &Fake| true).unwrap();
        assert_eq!(node.turns, 0);
        let phases: Vec<u32> = sent.iter().map(|s| s.phase).collect();
        assert_eq!(phases, [phase::READY, phase::STOPPING]);
    }

    /// Fails the first send, then keeps what it is sent.
    struct FirstFails(Vec<NodeStatus>, bool);

    impl StatusSink for FirstFails {
        type Error = &'static str;

        fn send_status(&mut self, st: NodeStatus) -> Result<(), &'static str> {
            if !self.1 {
                self.1 = true;
                return Err("full");
            }
            self.0.push(st);
            Ok(())
        }
    }

    #[test]
    fn a_ready_that_could_not_be_sent_leaves_the_status_running_to_its_stop() {
        let mut sink = FirstFails(Vec::new(), false);
        let mut hb = Heartbeat::new(&mut sink, NodeRole::Recorder);
        assert_eq!(hb.status().phase, phase::READY);
        assert_eq!(hb.say_ready(), Err("full"));
        assert_eq!(hb.status().phase, phase::RUNNING);
        hb.status_mut().handled = 2;
        hb.beat().unwrap();
        let last = hb.stop().unwrap();
        let sent: Vec<(u32, u64)> = sink.0.iter().map(|s| (s.phase, s.handled)).collect();
        assert_eq!(sent, [(phase::RUNNING, 2), (phase::STOPPING, 2)]);
        assert_eq!(last, sink.0[1]);
    }
}
