//! Every recorded topic of a graph, read-only, handed over as [`Payload`]s in one call: the
//! recorder, `scl live` and the gateway read the graph through [`Observers`], so a topic added
//! to `ipc_types::for_each_topic!` is recorded, shown and forwarded with no edit in them.

use recording::{Payload, Topic};
use transport::{Graph, IpcError, TopicSubscriber};

macro_rules! observed {
    ($($(#[$doc:meta])* $variant:ident: $msg:ident => $ty:path, $topic:path;)*) => {
        /// A subscriber of one recorded topic.
        enum Port {
            $($variant(TopicSubscriber<$ty>),)*
        }

        impl Port {
            fn open(graph: &Graph, topic: Topic) -> Result<Self, IpcError> {
                Ok(match topic {
                    $(Topic::$variant => Port::$variant(graph.subscriber_of(&$topic, false)?),)*
                })
            }

            fn drain(&self, f: &mut impl FnMut(Payload)) -> Result<usize, IpcError> {
                match self {
                    $(Port::$variant(s) => s.drain(|m| f(Payload::$variant(*m))),)*
                }
            }
        }
    };
}

ipc_types::recorded_topics!(observed);

/// Read-only subscribers of some recorded topics (no wake-up events: the caller wakes on
/// something else, the robot states as a rule, and drains these each time).
pub struct Observers {
    ports: Vec<Port>,
}

impl Observers {
    /// Opens a subscriber of each of `topics`; [`Observers::drain`] drains them in this order.
    pub fn open(graph: &Graph, topics: &[Topic]) -> Result<Self, IpcError> {
        let ports = topics
            .iter()
            .map(|&t| Port::open(graph, t))
            .collect::<Result<_, _>>()?;
        Ok(Self { ports })
    }

    /// Hands everything buffered to `f`, topic by topic in the order they were opened in;
    /// returns how many messages it handed over.
    pub fn drain(&self, mut f: impl FnMut(Payload)) -> Result<usize, IpcError> {
        let mut n = 0;
        for p in &self.ports {
            n += p.drain(&mut f)?;
        }
        Ok(n)
    }
}
