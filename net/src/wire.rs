//! The messages on the wire: each graph message travels as its own bytes (the `#[repr(C)]`
//! layout `scl layout` prints, little-endian on every machine this runs on), tagged with its
//! stable type name as the Zenoh encoding's schema, so a reader checks what it got before it
//! reads a field. [`GatewayStatus`] and [`ClockPair`] are the gateway's own messages;
//! [`PROCESS_CAPTURE`] is the encoding of what a process runs.

use ipc_types::control::{EstopCommand, SafetyControl};
use ipc_types::{JoystickInput, MapperCommand, NodeStatus, RobotState, SafeCommand, TickReport};
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout};

/// A message that travels through Zenoh: fixed size, every bit pattern valid, a stable name.
pub trait Wire: IntoBytes + FromBytes + Immutable + KnownLayout + Copy {
    /// The type name, as the graph's services and `scl layout` spell it.
    const TYPE_NAME: &'static str;
}

macro_rules! wire {
    ($($t:ty => $name:literal),* $(,)?) => {
        $(impl Wire for $t {
            const TYPE_NAME: &'static str = $name;
        })*
    };
}

wire! {
    JoystickInput => "scl::JoystickInput",
    RobotState => "scl::RobotState",
    MapperCommand => "scl::MapperCommand",
    SafeCommand => "scl::SafeCommand",
    NodeStatus => "scl::NodeStatus",
    TickReport => "scl::TickReport",
    EstopCommand => "scl::EstopCommand",
    SafetyControl => "scl::SafetyControl",
    GatewayStatus => "scl::GatewayStatus",
    ClockPair => "scl::ClockPair",
}

/// The encoding of the gateway's answer on `NS/process/<pid>`: a small MCAP file holding
/// exactly what a local `scl record` writes when it first sees that process (the
/// `scl.process` metadata record and its attachments: the graph configuration, the model
/// file's bytes), as `graph_client::process::capture` writes them.
pub const PROCESS_CAPTURE: &str = "application/mcap;scl::ProcessCapture";

/// The robot PC's two clocks read together (the gateway's answer on `NS/clock`): an
/// observer on another machine maps the messages' `t_ns` (the robot PC's `CLOCK_MONOTONIC`)
/// to wall-clock time with it, as a local recorder does with its own pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
#[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
pub struct ClockPair {
    /// `CLOCK_MONOTONIC` (ns).
    pub mono_ns: u64,
    /// The wall clock at the same instant (ns since the Unix epoch).
    pub unix_ns: u64,
}

/// Why a payload was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecodeError {
    /// The encoding names another type (or none).
    #[error("a payload of type `{got}` where `{want}` was expected")]
    Type {
        /// The expected type name.
        want: &'static str,
        /// The encoding the sample carried.
        got: String,
    },
    /// The payload's length is not the type's size.
    #[error("a {want} payload of {got} bytes; it has {size}")]
    Size {
        /// The type name.
        want: &'static str,
        /// The type's size.
        size: usize,
        /// The payload's length.
        got: usize,
    },
}

/// The message's bytes.
pub fn encode<T: Wire>(m: &T) -> &[u8] {
    m.as_bytes()
}

/// The encoding every message travels with: `application/octet-stream;<type name>`.
pub fn encoding_of<T: Wire>() -> String {
    format!("{OCTET_STREAM};{}", T::TYPE_NAME)
}

const OCTET_STREAM: &str = "application/octet-stream";

/// Reads a `T` from `bytes` whose encoding (as Zenoh writes it) is `encoding`.
pub fn decode<T: Wire>(bytes: &[u8], encoding: &str) -> Result<T, DecodeError> {
    let schema = encoding
        .split_once(';')
        .filter(|(id, _)| *id == OCTET_STREAM)
        .map(|(_, s)| s);
    if schema != Some(T::TYPE_NAME) {
        return Err(DecodeError::Type {
            want: T::TYPE_NAME,
            got: encoding.to_owned(),
        });
    }
    T::read_from_bytes(bytes).map_err(|_| DecodeError::Size {
        want: T::TYPE_NAME,
        size: std::mem::size_of::<T>(),
        got: bytes.len(),
    })
}

/// [`GatewayStatus::link`] values: where the remote operator's link stands.
pub mod link_state {
    /// No operator has joined (or the gateway takes no joystick).
    pub const NONE: u32 = 0;
    /// An operator is joined; its input is held until it passes through neutral.
    pub const AWAITING_NEUTRAL: u32 = 1;
    /// The operator's input drives the graph.
    pub const LIVE: u32 = 2;
    /// The operator's session ended (its liveliness token went) or its input went stale:
    /// the arm was stopped; a new session (after an ended one) and neutral input resume.
    pub const LOST: u32 = 3;
    /// Names, by value.
    pub const NAMES: [&str; 4] = ["none", "awaiting-neutral", "live", "lost"];
}

/// The gateway's account, published on `<namespace>/gateway` at every tick and on every
/// forwarded operator sample (its acknowledgement: the operator's round trip).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[repr(C)]
#[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
pub struct GatewayStatus {
    /// When it was published (the robot PC's monotonic ns).
    pub t_ns: u64,
    /// Newest robot tick the gateway saw.
    pub tick: u64,
    /// `seq` of the operator's newest forwarded sample (`u64::MAX`: none).
    pub acked_seq: u64,
    /// Operator samples forwarded to the graph.
    pub forwarded: u64,
    /// Operator samples refused (stale, from the future, not neutral when it had to be,
    /// non-finite, from an ended session or a second operator, undecodable).
    pub refused: u64,
    /// Times the operator's link was lost (its liveliness token went while it drove).
    pub link_losses: u64,
    /// Times the operator's input went stale (older than one tick) while it drove.
    pub stale_stops: u64,
    /// Observer messages dropped because the network side was behind.
    pub outbound_dropped: u64,
    /// [`link_state`] value.
    pub link: u32,
    /// Padding, always 0.
    pub reserved: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_round_trips_and_a_wrong_type_or_size_is_refused() {
        let s = JoystickInput {
            tick: 7,
            t_ns: 9,
            seq: 3,
            axes: [0.5, -0.25],
            gripper: 0.0,
            buttons: 1,
        };
        let b = encode(&s);
        let enc = encoding_of::<JoystickInput>();
        assert_eq!(enc, "application/octet-stream;scl::JoystickInput");
        assert_eq!(decode::<JoystickInput>(b, &enc), Ok(s));
        for other in [
            "application/octet-stream;scl::RobotState",
            "application/octet-stream",
            "text/plain;scl::JoystickInput",
        ] {
            assert!(matches!(
                decode::<JoystickInput>(b, other),
                Err(DecodeError::Type { .. })
            ));
        }
        let e = decode::<JoystickInput>(&b[..b.len() - 1], &enc);
        assert!(matches!(e, Err(DecodeError::Size { .. })), "{e:?}");
    }

    #[test]
    fn the_type_names_are_the_graphs() {
        use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
        // SAFETY: `type_name` only returns the name the derive attached.
        let names = unsafe {
            [
                (JoystickInput::type_name(), JoystickInput::TYPE_NAME),
                (RobotState::type_name(), RobotState::TYPE_NAME),
                (MapperCommand::type_name(), MapperCommand::TYPE_NAME),
                (SafeCommand::type_name(), SafeCommand::TYPE_NAME),
                (NodeStatus::type_name(), NodeStatus::TYPE_NAME),
                (TickReport::type_name(), TickReport::TYPE_NAME),
                (EstopCommand::type_name(), EstopCommand::TYPE_NAME),
                (SafetyControl::type_name(), SafetyControl::TYPE_NAME),
            ]
        };
        for (graph, wire) in names {
            assert_eq!(graph, wire);
        }
    }

    /// `bytes` read as a `T` under `encoding`: only at `T`'s own encoding and exact size, and
    /// then the same bytes.
    fn read_only_as_itself<T: Wire>(bytes: &[u8], encoding: &str) -> Result<(), String> {
        if let Ok(m) = decode::<T>(bytes, encoding) {
            if encoding != encoding_of::<T>() {
                return Err(format!("read under {encoding}"));
            }
            if encode(&m) != bytes {
                return Err("not the same bytes".into());
            }
        }
        Ok(())
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 1024, ..Default::default() })]

        /// Any bytes under any of the gateway's encodings, as each of its types (the
        /// `zenoh_payload` fuzz target's rule, on stable with every `cargo test`); the sizes
        /// drawn around the types' own.
        #[test]
        fn any_payload_is_read_only_at_its_types_encoding_and_size(
            pick in 0usize..5,
            len in proptest::prop_oneof![0usize..64, 64usize..2048],
            fill in proptest::collection::vec(proptest::prelude::any::<u8>(), 2048),
        ) {
            // Each of the gateway's types: its encoding and size.
            let kinds = [
                (encoding_of::<JoystickInput>(), size_of::<JoystickInput>()),
                (encoding_of::<RobotState>(), size_of::<RobotState>()),
                (encoding_of::<EstopCommand>(), size_of::<EstopCommand>()),
                (encoding_of::<SafetyControl>(), size_of::<SafetyControl>()),
                (encoding_of::<NodeStatus>(), size_of::<NodeStatus>()),
            ];
            proptest::prop_assert!(kinds.iter().all(|(_, s)| *s <= fill.len()));
            let (e, size) = &kinds[pick];
            for n in [len, *size] {
                let bytes = &fill[..n.min(fill.len())];
                for read in [
                    read_only_as_itself::<JoystickInput>,
                    read_only_as_itself::<RobotState>,
                    read_only_as_itself::<EstopCommand>,
                    read_only_as_itself::<SafetyControl>,
                    read_only_as_itself::<NodeStatus>,
                ] {
                    proptest::prop_assert_eq!(read(bytes, e), Ok(()));
                }
            }
        }
    }
}
