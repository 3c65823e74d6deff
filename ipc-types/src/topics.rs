//! The graph's topics as data: each topic's name below the graph prefix and its
//! quality-of-service settings ([`TopicSettings`]), and which transport the data-plane topics
//! travel on ([`Transport`]). The `transport` crate opens every service from these, so every
//! process opens every service identically; the layout ([`crate::layout`]) lists them for
//! bindings.

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
/// publishes first (a second is refused: `transport::IpcError::Port`).
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

/// The processes' own log records ([`crate::LogRecord`]): every process of the graph may
/// publish (a swap runs two mappers); a late reader (`scl live` restarted) gets the last few.
pub const LOG: TopicSettings = TopicSettings {
    name: "log",
    history: 16,
    buffer: 256,
    max_publishers: 16,
    max_subscribers: 4,
};

/// How the data-plane topics travel. The control plane (swaps, e-stop, safety control)
/// always uses iceoryx2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Transport {
    /// iceoryx2 zero-copy shared memory with event wake-ups (the product).
    #[default]
    Iceoryx2,
    /// Unix-domain datagram sockets (for latency comparisons; see `transport::uds`).
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
