//! ROS 2 without ROS: the gateway speaks rmw_zenoh's wire format (ros2/rmw_zenoh,
//! `docs/design.md`), so a ROS 2 graph on Zenoh sees the arm: `ros2 topic list` and `ros2
//! node list` read the liveliness tokens, RViz and rosbag2 take `/joint_states`.
//!
//! * A topic's key is `<domain>/<name>/<DDS type name>/<type hash>`; the hash is the one ROS 2
//!   computes from the type's description (REP-2016's `RIHS01_` form), written here and
//!   checked against an independent computation (`rosbags`, in `python/tests`).
//! * Liveliness tokens: `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/
//!   <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`, with `/` inside a name written `%`
//!   (kinds `NN` node, `MP` publisher, `MS` subscription).
//! * Payloads are CDR, little-endian, with the 4-byte encapsulation header (the `cdr`
//!   crate); every publication carries rmw_zenoh's attachment: sequence number and source
//!   timestamp (8 bytes each, little-endian), then the publisher's 16-byte id, length-prefixed.

use serde::{Deserialize, Serialize};

/// `sensor_msgs/msg/JointState`.
pub const JOINT_STATE: RosType = RosType {
    name: "sensor_msgs::msg::dds_::JointState_",
    hash: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
};

/// `sensor_msgs/msg/Joy`.
pub const JOY: RosType = RosType {
    name: "sensor_msgs::msg::dds_::Joy_",
    hash: "RIHS01_0d356c79cad3401e35ffeb75a96a96e08be3ef896b8b83841d73e890989372c5",
};

/// `std_msgs/msg/String` (the safety status, one line).
pub const STRING: RosType = RosType {
    name: "std_msgs::msg::dds_::String_",
    hash: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
};

/// The QoS of every endpoint here: ROS 2's default (reliable, volatile, keep last 10), in
/// the token's compact form (fields equal to the default left empty).
pub const DEFAULT_QOS: &str = "::,10:,:,:,,";

/// A ROS 2 message type as rmw_zenoh names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RosType {
    /// The DDS type name (`pkg::msg::dds_::Type_`).
    pub name: &'static str,
    /// The type hash.
    pub hash: &'static str,
}

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, below 1e9.
    pub nanosec: u32,
}

impl Time {
    /// The time `ns` nanoseconds after the epoch.
    pub fn from_ns(ns: u128) -> Self {
        Self {
            sec: i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX),
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// When.
    pub stamp: Time,
    /// The frame.
    pub frame_id: String,
}

/// `sensor_msgs/msg/JointState`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions (rad).
    pub position: Vec<f64>,
    /// Velocities (rad/s).
    pub velocity: Vec<f64>,
    /// Efforts (none here: empty).
    pub effort: Vec<f64>,
}

/// `sensor_msgs/msg/Joy`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Joy {
    /// Stamp and frame.
    pub header: Header,
    /// Axes, each in `[-1, 1]`.
    pub axes: Vec<f32>,
    /// Buttons, 1 pressed.
    pub buttons: Vec<i32>,
}

/// `std_msgs/msg/String`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RosString {
    /// The text.
    pub data: String,
}

/// The largest ROS 2 payload accepted (a `Joy` of a few dozen axes is under 1 KiB).
pub const MAX_PAYLOAD: u64 = 64 * 1024;

/// Why a ROS 2 payload was refused.
#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    /// Not CDR of the expected type, or over [`MAX_PAYLOAD`].
    #[error("not a {what} in CDR ({len} bytes): {source}")]
    Decode {
        /// The type.
        what: &'static str,
        /// The payload's length.
        len: usize,
        /// The decoder's error.
        #[source]
        source: cdr::Error,
    },
    /// The message could not be encoded.
    #[error("cannot encode a {what} in CDR: {source}")]
    Encode {
        /// The type.
        what: &'static str,
        /// The encoder's error.
        #[source]
        source: cdr::Error,
    },
}

/// `m` in CDR, little-endian, with its encapsulation header.
pub fn encode<T: Serialize>(m: &T, what: &'static str) -> Result<Vec<u8>, CdrError> {
    cdr::serialize::<_, _, cdr::CdrLe>(m, cdr::Infinite)
        .map_err(|source| CdrError::Encode { what, source })
}

/// A `Joy` from CDR (either byte order), at most [`MAX_PAYLOAD`] bytes.
pub fn decode_joy(bytes: &[u8]) -> Result<Joy, CdrError> {
    let err = |source| CdrError::Decode {
        what: "sensor_msgs/msg/Joy",
        len: bytes.len(),
        source,
    };
    if bytes.len() as u64 > MAX_PAYLOAD || !joy_lengths_fit(bytes) {
        return Err(err(cdr::Error::SizeLimit));
    }
    cdr::deserialize_from(bytes, cdr::Bounded(MAX_PAYLOAD)).map_err(err)
}

/// Every length prefix of a `Joy` in CDR (the frame id's, the axes' and the buttons' counts)
/// fits in what is left of `bytes`. The `cdr` crate allocates a string or sequence of the
/// length it reads before its size bound refuses it: a 17-byte message whose frame id
/// claimed 3.8 GB made the gateway allocate that much (found by the `joy_cdr` fuzz target,
/// `fuzz/regressions/joy_cdr-oom`). A message that fails this check is refused as too large.
fn joy_lengths_fit(bytes: &[u8]) -> bool {
    // The encapsulation header: representation (0x0000 big-endian, 0x0001 little-endian),
    // then two bytes of options; alignment counts from after it.
    let Some((head, body)) = bytes.split_first_chunk::<4>() else {
        return false;
    };
    let little = head[1] & 1 == 1;
    let u32_at = |at: usize| -> Option<usize> {
        let b: [u8; 4] = body.get(at..at + 4)?.try_into().ok()?;
        let v = if little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        };
        usize::try_from(v).ok()
    };
    let align4 = |at: usize| at.div_ceil(4) * 4;
    // header.stamp (sec, nanosec), then header.frame_id's length and bytes.
    let Some(id_len) = u32_at(8) else {
        return false;
    };
    let Some(mut at) = 12usize.checked_add(id_len) else {
        return false;
    };
    // axes (float32), then buttons (int32): a count and four bytes each.
    for _ in 0..2 {
        at = align4(at);
        let Some(count) = u32_at(at) else {
            return false;
        };
        let Some(end) = count.checked_mul(4).and_then(|n| n.checked_add(at + 4)) else {
            return false;
        };
        if end > body.len() {
            return false;
        }
        at = end;
    }
    at <= body.len()
}

/// How a `Joy` becomes the operator's input (`[network] ros2_joy_*`).
#[derive(Debug, Clone, PartialEq)]
pub struct JoyMapping {
    /// The axes that are x and y.
    pub axes: [usize; 2],
    /// Their factors.
    pub scale: [f32; 2],
    /// The deadman, mode and e-stop buttons, if any.
    pub deadman: Option<usize>,
    /// See `deadman`.
    pub mode: Option<usize>,
    /// See `deadman`.
    pub estop: Option<usize>,
}

impl JoyMapping {
    /// The mapping `[network]` describes.
    pub fn from_config(n: &scl_config::NetworkConfig) -> Self {
        let button = |b: i32| usize::try_from(b).ok();
        Self {
            axes: n.ros2_joy_axes.map(|a| a as usize),
            scale: n.ros2_joy_scale.map(|s| s as f32),
            deadman: button(n.ros2_joy_deadman),
            mode: button(n.ros2_joy_mode),
            estop: button(n.ros2_joy_estop),
        }
    }

    /// The stick's axes and the `ipc_types::buttons` bits of `joy`, or which index it lacks.
    pub fn apply(&self, joy: &Joy) -> Result<([f32; 2], u32), String> {
        let mut axes = [0.0; 2];
        for (i, (&a, s)) in self.axes.iter().zip(self.scale).enumerate() {
            axes[i] = joy
                .axes
                .get(a)
                .ok_or_else(|| format!("axis {a} missing ({} axes)", joy.axes.len()))?
                * s;
        }
        let mut bits = 0;
        for (b, bit) in [
            (self.deadman, ipc_types::buttons::DEADMAN),
            (self.mode, ipc_types::buttons::MODE),
            (self.estop, ipc_types::buttons::ESTOP),
        ] {
            if let Some(b) = b {
                let v = joy
                    .buttons
                    .get(b)
                    .ok_or_else(|| format!("button {b} missing ({} buttons)", joy.buttons.len()))?;
                if *v != 0 {
                    bits |= bit;
                }
            }
        }
        Ok((axes, bits))
    }
}

/// rmw_zenoh's attachment of a publication.
pub fn attachment(seq: u64, source_timestamp_ns: u64, gid: &[u8; 16]) -> Vec<u8> {
    let mut a = Vec::with_capacity(8 + 8 + 1 + 16);
    a.extend_from_slice(&seq.to_le_bytes());
    a.extend_from_slice(&source_timestamp_ns.to_le_bytes());
    a.push(16);
    a.extend_from_slice(gid);
    a
}

/// One node's names in a ROS 2 domain.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ros2Node {
    /// The domain id.
    pub domain: u32,
    /// The Zenoh session's id (hex).
    pub zid: String,
    /// The node's name (no namespace).
    pub name: String,
}

/// What an endpoint does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// A publisher (`MP`).
    Publisher,
    /// A subscription (`MS`).
    Subscription,
}

impl Ros2Node {
    /// The node's own id (0) and its entities' ids (from 1).
    const NODE_ID: u32 = 0;

    /// The data key of topic `topic` (`/joint_states`) of type `ty`.
    pub fn topic_key(&self, topic: &str, ty: RosType) -> String {
        format!(
            "{}/{}/{}/{}",
            self.domain,
            topic.trim_start_matches('/'),
            ty.name,
            ty.hash
        )
    }

    /// The node's liveliness token.
    pub fn node_token(&self) -> String {
        format!(
            "@ros2_lv/{}/{}/{id}/{id}/NN/%/%/{}",
            self.domain,
            self.zid,
            mangle(&self.name),
            id = Self::NODE_ID,
        )
    }

    /// The liveliness token of entity `id` (from 1) on `topic`.
    pub fn entity_token(&self, id: u32, kind: EntityKind, topic: &str, ty: RosType) -> String {
        let kind = match kind {
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        };
        format!(
            "@ros2_lv/{}/{}/{}/{id}/{kind}/%/%/{}/{}/{}/{}/{DEFAULT_QOS}",
            self.domain,
            self.zid,
            Self::NODE_ID,
            mangle(&self.name),
            mangle(topic),
            ty.name,
            ty.hash
        )
    }

    /// The publisher id of entity `id`: the session id's 16 bytes with the entity's in the
    /// last four, so every publisher of the session has its own.
    pub fn gid(&self, id: u32) -> [u8; 16] {
        let z = u128::from_str_radix(&self.zid, 16).unwrap_or_default();
        let mut g = z.to_le_bytes();
        g[12..].copy_from_slice(&id.to_le_bytes());
        g
    }
}

/// A name in a liveliness token: `/` written `%` (`%` alone for the root).
pub fn mangle(name: &str) -> String {
    if name.is_empty() || name == "/" {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fuzzer's out-of-memory input (a frame id claiming 3.8 GB in 17 bytes) and every
    /// truncation of a good message are refused without allocating what they claim; a good
    /// message in either byte order still decodes.
    #[test]
    fn a_joy_whose_lengths_do_not_fit_is_refused_before_decoding() {
        let oom = std::fs::read(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../fuzz/regressions/joy_cdr-oom"),
        )
        .expect("the regression input");
        assert!(matches!(
            decode_joy(&oom),
            Err(CdrError::Decode {
                source: cdr::Error::SizeLimit,
                ..
            })
        ));
        let joy = Joy {
            header: Header {
                stamp: Time { sec: 3, nanosec: 4 },
                frame_id: "pad".into(),
            },
            axes: vec![0.5, -0.25],
            buttons: vec![1, 0, 1],
        };
        let le = encode(&joy, "Joy").unwrap();
        assert_eq!(decode_joy(&le).unwrap(), joy);
        let be = cdr::serialize::<_, _, cdr::CdrBe>(&joy, cdr::Infinite).unwrap();
        assert_eq!(decode_joy(&be).unwrap(), joy);
        for n in 0..le.len() {
            assert!(decode_joy(&le[..n]).is_err(), "{n} bytes");
        }
    }

    #[test]
    fn a_joint_state_is_cdr_with_its_alignment() {
        let m = JointState {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: String::new(),
            },
            name: vec!["j1".into()],
            position: vec![0.5],
            velocity: vec![],
            effort: vec![],
        };
        let b = encode(&m, "JointState").unwrap();
        // Encapsulation (CDR_LE), sec, nanosec, frame_id "" (length 1: the NUL), names: one,
        // "j1\0" (length 3) + 1 byte of padding, positions: one, the f64 at body offset 32
        // (8-aligned as it is), velocity and effort: none.
        let mut want = vec![0, 1, 0, 0];
        want.extend_from_slice(&1i32.to_le_bytes());
        want.extend_from_slice(&2u32.to_le_bytes());
        want.extend_from_slice(&1u32.to_le_bytes());
        want.extend_from_slice(&[0, 0, 0, 0]);
        want.extend_from_slice(&1u32.to_le_bytes());
        want.extend_from_slice(&3u32.to_le_bytes());
        want.extend_from_slice(b"j1\0\0");
        want.extend_from_slice(&1u32.to_le_bytes());
        want.extend_from_slice(&0.5f64.to_le_bytes());
        want.extend_from_slice(&0u32.to_le_bytes());
        want.extend_from_slice(&0u32.to_le_bytes());
        assert_eq!(b, want);
    }

    #[test]
    fn a_joy_round_trips_and_garbage_or_a_huge_length_is_an_error() {
        let j = Joy {
            header: Header::default(),
            axes: vec![0.5, -1.0],
            buttons: vec![0, 1],
        };
        let b = encode(&j, "Joy").unwrap();
        assert_eq!(decode_joy(&b).unwrap(), j);
        assert!(decode_joy(&b[..b.len() - 3]).is_err());
        assert!(decode_joy(&[1, 2, 3]).is_err());
        let mut huge = vec![0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0];
        huge.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(
            decode_joy(&huge).is_err(),
            "a sequence longer than the payload"
        );
    }

    #[test]
    fn a_joy_maps_through_its_indices_and_a_missing_one_is_named() {
        let m = JoyMapping {
            axes: [1, 0],
            scale: [-1.0, 1.0],
            deadman: Some(2),
            mode: None,
            estop: Some(0),
        };
        let j = Joy {
            header: Header::default(),
            axes: vec![0.25, 0.5],
            buttons: vec![1, 0, 1],
        };
        let (a, b) = m.apply(&j).unwrap();
        assert_eq!(a, [-0.5, 0.25]);
        assert_eq!(b, ipc_types::buttons::DEADMAN | ipc_types::buttons::ESTOP);
        let short = Joy {
            buttons: vec![1],
            ..j
        };
        assert!(m.apply(&short).unwrap_err().contains("button 2"));
    }

    #[test]
    fn keys_and_tokens_follow_rmw_zenoh() {
        let n = Ros2Node {
            domain: 0,
            zid: "a1b2".into(),
            name: "scl_gateway".into(),
        };
        assert_eq!(
            n.topic_key("/joint_states", JOINT_STATE),
            format!(
                "0/joint_states/sensor_msgs::msg::dds_::JointState_/{}",
                JOINT_STATE.hash
            )
        );
        assert_eq!(n.node_token(), "@ros2_lv/0/a1b2/0/0/NN/%/%/scl_gateway");
        assert_eq!(
            n.entity_token(3, EntityKind::Subscription, "/joy", JOY),
            format!(
                "@ros2_lv/0/a1b2/0/3/MS/%/%/scl_gateway/%joy/sensor_msgs::msg::dds_::Joy_/{}/::,10:,:,:,,",
                JOY.hash
            )
        );
        let a = attachment(7, 9, &n.gid(1));
        assert_eq!(a.len(), 33);
        assert_eq!(&a[..8], &7u64.to_le_bytes());
        assert_eq!(a[16], 16);
        assert_ne!(n.gid(1), n.gid(2));
    }

    /// A `Joy` with the given frame id, axes and buttons, in CDR.
    fn joy_bytes(frame: &str, axes: &[f32], buttons: &[i32]) -> Vec<u8> {
        let j = Joy {
            header: Header {
                frame_id: frame.to_owned(),
                ..Header::default()
            },
            axes: axes.to_vec(),
            buttons: buttons.to_vec(),
        };
        encode(&j, "Joy").unwrap()
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 1024, ..Default::default() })]

        /// Any bytes: a `Joy` or an error, never a panic (the `joy_cdr` fuzz target's rule, on
        /// stable with every `cargo test`).
        #[test]
        fn any_bytes_are_a_joy_or_an_error(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..256)) {
            let _ = decode_joy(&bytes);
        }

        /// A real `Joy` with one byte changed, cut short, or four bytes overwritten with a large
        /// length anywhere: a `Joy` or an error; a length that does not fit what is left is an
        /// error before anything is allocated for it.
        #[test]
        fn a_damaged_joy_is_a_joy_or_an_error(
            frame in "[a-z_]{0,12}",
            axes in proptest::collection::vec(-1.0f32..1.0, 0..8),
            buttons in proptest::collection::vec(0i32..2, 0..12),
            at in proptest::prelude::any::<proptest::sample::Index>(),
            byte in proptest::prelude::any::<u8>(),
            cut in proptest::prelude::any::<proptest::sample::Index>(),
            huge in 1_000_000u32..,
        ) {
            let good = joy_bytes(&frame, &axes, &buttons);
            let mut flipped = good.clone();
            let i = at.index(flipped.len());
            flipped[i] = byte;
            let _ = decode_joy(&flipped);
            let _ = decode_joy(&good[..cut.index(good.len())]);
            let mut long = good.clone();
            let i = at.index(long.len().saturating_sub(4).max(1)).min(long.len().saturating_sub(4));
            long[i..i + 4].copy_from_slice(&huge.to_le_bytes());
            if let Ok(j) = decode_joy(&long) {
                let claimed = j.header.frame_id.len() + j.axes.len() * 4 + j.buttons.len() * 4;
                proptest::prop_assert!(claimed <= long.len(), "{} bytes decoded from {}", claimed, long.len());
            }
        }
    }
}
