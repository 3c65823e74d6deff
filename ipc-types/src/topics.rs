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

/// Which way a topic travels, and whether it carries a wake-up event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// The data plane: the graph's [`Transport`] (iceoryx2 or Unix-domain sockets), with a
    /// wake-up event per sample for subscribers that ask for one.
    Data,
    /// Always iceoryx2, with a wake-up event (the processes' log records: the same whatever
    /// the data plane's transport).
    Iceoryx2,
    /// The control plane: always iceoryx2, no wake-up event (readers drain it each tick).
    Control,
}

/// One topic: its settings, the plane it travels on, and (as a type) the message it carries,
/// so a port of the wrong message type cannot be opened on it. Derefs to its settings
/// (`topics::ROBOT_STATE.name`).
#[derive(Debug)]
pub struct TopicDef<T> {
    /// The quality-of-service settings every process opening the topic repeats.
    pub settings: TopicSettings,
    /// How it travels.
    pub plane: Plane,
    message: core::marker::PhantomData<fn() -> T>,
}

impl<T> TopicDef<T> {
    const fn new(plane: Plane, settings: TopicSettings) -> Self {
        Self {
            settings,
            plane,
            message: core::marker::PhantomData,
        }
    }
}

impl<T> core::ops::Deref for TopicDef<T> {
    type Target = TopicSettings;
    fn deref(&self) -> &TopicSettings {
        &self.settings
    }
}

/// Every topic of the graph, one row each: the only place a topic is written down. A row is
/// its doc, the constant's name, the message type (a type at the crate's root), the plane,
/// its settings (name, history, buffer, publishers, subscribers) and, for the topics a
/// recording and a remote observer carry, the name of its variant in `recording::Topic` and
/// `recording::Payload`. Everything else is derived: the constants below, [`Layout`]'s topic
/// list, the recording's topics and payloads, the recorder's, `scl live`'s and the gateway's
/// subscriptions and the network's keys (through [`recorded_topics!`]).
///
/// `for_each_topic!(cb)` calls macro `cb` with `{}` and the rows; `for_each_topic!(cb {
/// ARGS })` passes `{ ARGS }` first.
///
/// [`Layout`]: crate::layout::Layout
#[macro_export]
macro_rules! for_each_topic {
    ($($cb:tt)::+ $({ $($args:tt)* })?) => {
        $($cb)::+! {
            { $($($args)*)? }
            /// Joystick samples: newest wins; a late mapper gets the last sample at once. One
            /// publisher at a time: the joystick process, or with `[joystick] source =
            /// "external"` whoever publishes first (a second is refused:
            /// `transport::IpcError::Port`).
            JOYSTICK: JoystickInput on Data("joystick", 1, 64, 1, 16) recorded Joystick;
            /// Robot state, one per tick, from the bridge.
            ROBOT_STATE: RobotState on Data("robot_state", 1, 64, 1, 16) recorded RobotState;
            /// Mapper commands; several mappers may publish at once during a live swap.
            MAPPER_COMMAND: MapperCommand on Data("mapper_command", 0, 64, 4, 8) recorded MapperCommand;
            /// The command the arm executes. Exactly one publisher: the safety process.
            SAFE_COMMAND: SafeCommand on Data("safe_command", 0, 64, 1, 8) recorded SafeCommand;
            /// Heartbeats of every node; buffered deep enough for a reader that polls a few
            /// times a second.
            STATUS: NodeStatus on Data("status", 0, 512, 16, 8) recorded Status;
            /// The bridge's timing report of every tick; deep enough for a reader that polls a
            /// few times a second.
            TICK_REPORT: TickReport on Data("tick_report", 0, 256, 2, 8);
            /// The supervisor's active-mapper switches, holds and relayed e-stops to safety: the
            /// newest switch is kept for a restarted safety.
            SAFETY_CONTROL: SafetyControl on Control("safety_control", 1, 8, 2, 8) recorded SafetyControl;
            /// E-stop and reset commands.
            ESTOP: EstopCommand on Control("estop", 1, 8, 8, 8) recorded Estop;
            /// The processes' own log records ([`crate::LogRecord`]): every process of the graph
            /// may publish (a swap runs two mappers); a late reader (`scl live` restarted) gets
            /// the last few. Not part of the bindings' layout.
            LOG: LogRecord on Iceoryx2("log", 16, 256, 16, 4);
        }
    };
}

/// The topics a recording carries (and a remote observer receives), in channel order:
/// calls macro `cb` with one `#[doc] Variant: Message => $crate::Message,
/// $crate::topics::CONST;` line per recorded row of [`for_each_topic!`].
#[macro_export]
macro_rules! recorded_topics {
    ($($cb:tt)::+) => {
        $crate::for_each_topic! { $crate::__recorded_rows { @rows $($cb)::+ } }
    };
}

#[doc(hidden)]
#[macro_export]
macro_rules! __recorded_rows {
    // All rows seen: call back with the recorded ones.
    ({ $($cb:tt)::+ } [$($out:tt)*]) => {
        $($cb)::+! { $($out)* }
    };
    // A recorded row.
    ({ $($cb:tt)::+ } [$($out:tt)*]
        $(#[$doc:meta])*
        $konst:ident: $msg:ident on $plane:ident($($settings:tt)*) recorded $variant:ident;
        $($rest:tt)*
    ) => {
        $crate::__recorded_rows! {
            { $($cb)::+ }
            [$($out)* $(#[$doc])* $variant: $msg => $crate::$msg, $crate::topics::$konst;]
            $($rest)*
        }
    };
    // A row the recording leaves out.
    ({ $($cb:tt)::+ } [$($out:tt)*]
        $(#[$doc:meta])*
        $konst:ident: $msg:ident on $plane:ident($($settings:tt)*);
        $($rest:tt)*
    ) => {
        $crate::__recorded_rows! { { $($cb)::+ } [$($out)*] $($rest)* }
    };
    // From `for_each_topic!` (the marker keeps a malformed row from landing here again).
    ({ @rows $($cb:tt)::+ } $($rows:tt)*) => {
        $crate::__recorded_rows! { { $($cb)::+ } [] $($rows)* }
    };
}

macro_rules! define_topics {
    ({} $(
        $(#[$doc:meta])*
        $konst:ident: $msg:ident on $plane:ident(
            $name:literal, $history:literal, $buffer:literal, $publishers:literal,
            $subscribers:literal
        ) $(recorded $variant:ident)?;
    )*) => {
        $(
            $(#[$doc])*
            pub const $konst: TopicDef<crate::$msg> = TopicDef::new(Plane::$plane, TopicSettings {
                name: $name,
                history: $history,
                buffer: $buffer,
                max_publishers: $publishers,
                max_subscribers: $subscribers,
            });
        )*

        /// Every topic's settings and the name of its message type, in table order.
        pub const ALL: &[(&TopicSettings, &str)] = &[$((&$konst.settings, stringify!($msg))),*];
    };
}

for_each_topic!(define_topics);

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
