//! The Kortex envelope: TCP framing (magic, big-endian length, protobuf `Frame`), the four
//! header words and their bit fields, and a streaming decoder that resynchronises on a wrong
//! magic.
//!
//! ```text
//! bytes 0..7    07 78 45 74 52 6F 4B 07     magic
//! bytes 8..11   u32 big-endian              N = length of the serialized Frame
//! bytes 12..    N bytes                     protobuf Frame { Header header = 1; bytes payload = 2; }
//! ```
//!
//! This file depends on `prost` and `thiserror` only, so the fuzz target
//! (`hw-bridge/fuzz`) compiles it on its own.
//!
//! ```
//! use hw_bridge::kortex::wire::{Decoded, Frame, FrameDecoder, FrameType};
//!
//! // Base.Stop (function uid 0x20070), message id 5 of session 0x1234, empty payload.
//! let stop = Frame::new(FrameType::Request, 0x1234, 5, 0x2_0070, Vec::new())?;
//! let mut bytes = Vec::new();
//! stop.encode_tcp(&mut bytes)?;
//! assert_eq!(bytes[..12], [0x07, 0x78, 0x45, 0x74, 0x52, 0x6F, 0x4B, 0x07, 0, 0, 0, 0x11]);
//!
//! // Bytes that do not start with the magic are skipped up to the next frame.
//! let mut d = FrameDecoder::new();
//! d.push(b"noise");
//! d.push(&bytes);
//! assert_eq!(d.next_frame(), Some(Ok(Decoded::Skipped(5))));
//! assert_eq!(d.next_frame(), Some(Ok(Decoded::Frame(stop))));
//! assert_eq!(d.next_frame(), None);
//! # Ok::<(), hw_bridge::kortex::wire::WireError>(())
//! ```

use prost::Message as _;

/// The eight bytes that start every frame on the TCP stream.
pub const MAGIC: [u8; 8] = [0x07, 0x78, 0x45, 0x74, 0x52, 0x6F, 0x4B, 0x07];

/// Magic plus the length word.
pub const PREFIX_LEN: usize = 12;

/// The longest serialized `Frame` the decoder accepts (bytes). The header's payload length has
/// 24 bits; the bridge's largest reply (Feedback) is well under a kilobyte.
pub const MAX_FRAME_LEN: usize = 1 << 20;

/// Largest payload the header's 24-bit length field can describe.
pub const MAX_PAYLOAD_LEN: usize = 0x00FF_FFFF;

/// Header version written in `frame_info` bits 31..28.
pub const HEADER_VERSION: u32 = 1;

/// Service version written in `service_info` bits 31..28.
pub const SERVICE_VERSION: u32 = 1;

/// `Frame { Header header = 1; bytes payload = 2; }`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Frame {
    /// The four header words.
    #[prost(message, optional, tag = "1")]
    pub header: Option<Header>,
    /// The serialized message of the call (empty for `Empty`).
    #[prost(bytes = "vec", tag = "2")]
    pub payload: Vec<u8>,
}

/// `Header`: four fixed32 words (little-endian on the wire, as protobuf writes fixed32).
#[derive(Clone, Copy, PartialEq, Eq, prost::Message)]
pub struct Header {
    /// 31..28 header version, 27..24 frame type, 23..16 device id, 15..12 error code,
    /// 11..0 error sub-code.
    #[prost(fixed32, tag = "1")]
    pub frame_info: u32,
    /// 31..16 session id, 15..0 message id.
    #[prost(fixed32, tag = "2")]
    pub message_info: u32,
    /// 31..28 service version, 27..16 service id, 15..0 function id.
    #[prost(fixed32, tag = "3")]
    pub service_info: u32,
    /// 31..24 reserved, 23..0 payload length.
    #[prost(fixed32, tag = "4")]
    pub payload_info: u32,
}

/// `Error { enum error_code = 1; uint32 error_sub_code = 2; string error_sub_string = 3; }`:
/// the payload of a frame whose header carries an error code.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ErrorPayload {
    /// The error code (see [`error_code_name`]).
    #[prost(int32, tag = "1")]
    pub error_code: i32,
    /// The sub-code (see [`sub_code_name`]).
    #[prost(uint32, tag = "2")]
    pub error_sub_code: u32,
    /// The robot's own words.
    #[prost(string, tag = "3")]
    pub error_sub_string: String,
}

/// The frame types of `frame_info` bits 27..24.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FrameType {
    /// A call.
    Request = 1,
    /// Raw bytes.
    Raw = 2,
    /// The answer to a call.
    Response = 3,
    /// An unsolicited notification.
    Notification = 5,
    /// Ping.
    Ping = 7,
    /// Pong.
    Pong = 8,
}

impl FrameType {
    /// Decodes the four-bit frame type.
    pub fn from_bits(v: u8) -> Option<Self> {
        match v {
            1 => Some(Self::Request),
            2 => Some(Self::Raw),
            3 => Some(Self::Response),
            5 => Some(Self::Notification),
            7 => Some(Self::Ping),
            8 => Some(Self::Pong),
            _ => None,
        }
    }
}

/// The name of an error code of `frame_info` bits 15..12.
pub fn error_code_name(code: u8) -> &'static str {
    match code {
        0 => "no error",
        1 => "protocol server error",
        2 => "protocol client error",
        3 => "device error",
        4 => "internal error",
        _ => "unknown error code",
    }
}

/// The name of an error sub-code, where it is known.
pub fn sub_code_name(sub_code: u32) -> Option<&'static str> {
    match sub_code {
        12 => Some("invalid session"),
        15 => Some("invalid password"),
        22 => Some("robot in fault"),
        _ => None,
    }
}

impl Header {
    /// A header for a frame of type `frame_type` from the base (device 0), no error.
    /// `function_uid` is `(service id << 16) | function id`.
    pub fn new(
        frame_type: FrameType,
        session_id: u16,
        message_id: u16,
        function_uid: u32,
        payload_len: usize,
    ) -> Result<Self, WireError> {
        if payload_len > MAX_PAYLOAD_LEN {
            return Err(WireError::PayloadTooLong { len: payload_len });
        }
        if function_uid > 0x0FFF_FFFF {
            return Err(WireError::BadFunction { uid: function_uid });
        }
        Ok(Self {
            frame_info: (HEADER_VERSION << 28) | ((frame_type as u32) << 24),
            message_info: (u32::from(session_id) << 16) | u32::from(message_id),
            service_info: (SERVICE_VERSION << 28) | function_uid,
            payload_info: payload_len as u32,
        })
    }

    /// The same header carrying an error code (4 bits) and sub-code (12 bits).
    pub fn with_error(mut self, code: u8, sub_code: u16) -> Self {
        self.frame_info = (self.frame_info & 0xFFFF_0000)
            | (u32::from(code & 0x0F) << 12)
            | u32::from(sub_code & 0x0FFF);
        self
    }

    /// Header version (bits 31..28 of `frame_info`).
    pub fn version(&self) -> u8 {
        (self.frame_info >> 28) as u8
    }

    /// The raw frame type (bits 27..24 of `frame_info`).
    pub fn frame_type_bits(&self) -> u8 {
        ((self.frame_info >> 24) & 0x0F) as u8
    }

    /// The frame type, if it is one the protocol defines.
    pub fn frame_type(&self) -> Option<FrameType> {
        FrameType::from_bits(self.frame_type_bits())
    }

    /// Device id (bits 23..16 of `frame_info`; 0 = base).
    pub fn device_id(&self) -> u8 {
        ((self.frame_info >> 16) & 0xFF) as u8
    }

    /// Error code (bits 15..12 of `frame_info`; 0 = none).
    pub fn error_code(&self) -> u8 {
        ((self.frame_info >> 12) & 0x0F) as u8
    }

    /// Error sub-code (bits 11..0 of `frame_info`).
    pub fn error_sub_code(&self) -> u16 {
        (self.frame_info & 0x0FFF) as u16
    }

    /// Session id (bits 31..16 of `message_info`).
    pub fn session_id(&self) -> u16 {
        (self.message_info >> 16) as u16
    }

    /// Message id (bits 15..0 of `message_info`).
    pub fn message_id(&self) -> u16 {
        (self.message_info & 0xFFFF) as u16
    }

    /// Service version (bits 31..28 of `service_info`).
    pub fn service_version(&self) -> u8 {
        (self.service_info >> 28) as u8
    }

    /// Function UID, `(service id << 16) | function id` (bits 27..0 of `service_info`).
    pub fn function_uid(&self) -> u32 {
        self.service_info & 0x0FFF_FFFF
    }

    /// Payload length (bits 23..0 of `payload_info`).
    pub fn payload_len(&self) -> usize {
        (self.payload_info & 0x00FF_FFFF) as usize
    }
}

impl Frame {
    /// A frame of `frame_type` around `payload`, its length written in the header.
    pub fn new(
        frame_type: FrameType,
        session_id: u16,
        message_id: u16,
        function_uid: u32,
        payload: Vec<u8>,
    ) -> Result<Self, WireError> {
        let header = Header::new(
            frame_type,
            session_id,
            message_id,
            function_uid,
            payload.len(),
        )?;
        Ok(Self {
            header: Some(header),
            payload,
        })
    }

    /// The header, all zero if the frame had none (proto3 omits what is zero).
    pub fn header(&self) -> Header {
        self.header.unwrap_or_default()
    }

    /// The frame alone, as a UDP datagram carries it (no magic, no length).
    pub fn encode_bare(&self) -> Vec<u8> {
        self.encode_to_vec()
    }

    /// Appends the frame to `out` as the TCP stream carries it: magic, big-endian length,
    /// serialized frame.
    pub fn encode_tcp(&self, out: &mut Vec<u8>) -> Result<(), WireError> {
        let n = self.encoded_len();
        if n > MAX_FRAME_LEN {
            return Err(WireError::FrameTooLong {
                len: n,
                max: MAX_FRAME_LEN,
            });
        }
        out.reserve(PREFIX_LEN + n);
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&(n as u32).to_be_bytes());
        self.encode(out).map_err(|e| WireError::Encode {
            reason: e.to_string(),
        })
    }

    /// The error this frame carries: `None` if its header's error code is 0. The payload's
    /// `Error` message, when it decodes, adds the robot's own words.
    pub fn error(&self) -> Option<RobotFault> {
        let h = self.header();
        let code = h.error_code();
        if code == 0 {
            return None;
        }
        let mut fault = RobotFault {
            code,
            sub_code: u32::from(h.error_sub_code()),
            detail: String::new(),
        };
        if let Ok(e) = ErrorPayload::decode(self.payload.as_slice()) {
            if fault.sub_code == 0 {
                fault.sub_code = e.error_sub_code;
            }
            fault.detail = e.error_sub_string;
        }
        Some(fault)
    }
}

/// An error reported by the robot in a frame header (and its `Error` payload).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotFault {
    /// Error code (1 protocol server, 2 protocol client, 3 device, 4 internal).
    pub code: u8,
    /// Error sub-code (12 invalid session, 15 invalid password, 22 robot in fault, ...).
    pub sub_code: u32,
    /// The robot's own words (`error_sub_string`), possibly empty.
    pub detail: String,
}

impl std::fmt::Display for RobotFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} (code {}), ", error_code_name(self.code), self.code)?;
        match sub_code_name(self.sub_code) {
            Some(name) => write!(f, "{name} (sub-code {})", self.sub_code)?,
            None => write!(f, "sub-code {}", self.sub_code)?,
        }
        if !self.detail.is_empty() {
            write!(f, ": {}", self.detail)?;
        }
        Ok(())
    }
}

/// What went wrong encoding or decoding a frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WireError {
    /// The length word announces more than the decoder accepts.
    #[error("frame length {len} in the header exceeds the {max}-byte limit")]
    FrameTooLong {
        /// The announced length.
        len: usize,
        /// The limit, [`MAX_FRAME_LEN`].
        max: usize,
    },
    /// A complete frame whose bytes are not a protobuf `Frame`.
    #[error("a {len}-byte frame is not a valid Kortex Frame: {reason}")]
    Decode {
        /// Length of the frame.
        len: usize,
        /// The protobuf decoder's message.
        reason: String,
    },
    /// A payload too long for the header's 24-bit length.
    #[error("a payload of {len} bytes does not fit the header's 24-bit length field")]
    PayloadTooLong {
        /// The payload's length.
        len: usize,
    },
    /// A function UID wider than the 28 bits of `service_info`.
    #[error("function uid {uid:#x} does not fit the 28 bits of service_info")]
    BadFunction {
        /// The UID.
        uid: u32,
    },
    /// Serialising failed.
    #[error("cannot encode a frame: {reason}")]
    Encode {
        /// The protobuf encoder's message.
        reason: String,
    },
}

/// One step of [`FrameDecoder::next_frame`].
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    /// A complete frame.
    Frame(Frame),
    /// This many bytes did not start with the magic and were dropped to resynchronise.
    Skipped(usize),
}

/// A streaming decoder of the TCP framing: push bytes as they arrive, take frames out.
///
/// On a wrong magic it drops bytes up to the next possible magic (reported as
/// [`Decoded::Skipped`]); a length above [`MAX_FRAME_LEN`] is an error after which the
/// decoder resynchronises in the same way; a frame whose body is not a protobuf `Frame` is an
/// error and is consumed. The buffer never holds more than one frame's worth plus one read.
#[derive(Debug, Default, Clone)]
pub struct FrameDecoder {
    buf: Vec<u8>,
}

impl FrameDecoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends bytes received from the stream.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held, waiting for the rest of a frame.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// If the stream ended now, the incomplete frame it would cut: `(have, need)` bytes.
    pub fn truncated(&self) -> Option<(usize, usize)> {
        if self.buf.is_empty() {
            return None;
        }
        let need = if self.buf.len() >= PREFIX_LEN {
            PREFIX_LEN + self.announced_len()
        } else {
            PREFIX_LEN
        };
        Some((self.buf.len(), need))
    }

    fn announced_len(&self) -> usize {
        u32::from_be_bytes([self.buf[8], self.buf[9], self.buf[10], self.buf[11]]) as usize
    }

    /// Where the next possible frame starts after position 0: the first position whose bytes
    /// match the magic as far as they go.
    fn resync_point(&self) -> usize {
        (1..self.buf.len())
            .find(|&i| {
                let rest = &self.buf[i..];
                let n = rest.len().min(MAGIC.len());
                rest[..n] == MAGIC[..n]
            })
            .unwrap_or(self.buf.len())
    }

    /// The next frame or resynchronisation step, `None` until more bytes are needed.
    pub fn next_frame(&mut self) -> Option<Result<Decoded, WireError>> {
        if self.buf.is_empty() {
            return None;
        }
        let n = self.buf.len().min(MAGIC.len());
        if self.buf[..n] != MAGIC[..n] {
            let skip = self.resync_point();
            self.buf.drain(..skip);
            return Some(Ok(Decoded::Skipped(skip)));
        }
        if self.buf.len() < PREFIX_LEN {
            return None;
        }
        let len = self.announced_len();
        if len > MAX_FRAME_LEN {
            // Not a frame we take: drop the magic's first byte so the next call resynchronises.
            self.buf.drain(..1);
            return Some(Err(WireError::FrameTooLong {
                len,
                max: MAX_FRAME_LEN,
            }));
        }
        if self.buf.len() < PREFIX_LEN + len {
            return None;
        }
        let result = Frame::decode(&self.buf[PREFIX_LEN..PREFIX_LEN + len])
            .map(Decoded::Frame)
            .map_err(|e| WireError::Decode {
                len,
                reason: e.to_string(),
            });
        self.buf.drain(..PREFIX_LEN + len);
        Some(result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame(message_id: u16, payload: &[u8]) -> Frame {
        Frame::new(
            FrameType::Response,
            0x1234,
            message_id,
            0x2_0084,
            payload.to_vec(),
        )
        .unwrap()
    }

    fn tcp(f: &Frame) -> Vec<u8> {
        let mut v = Vec::new();
        f.encode_tcp(&mut v).unwrap();
        v
    }

    fn drain(d: &mut FrameDecoder) -> (Vec<Frame>, usize, Vec<WireError>) {
        let (mut frames, mut skipped, mut errors) = (Vec::new(), 0, Vec::new());
        while let Some(r) = d.next_frame() {
            match r {
                Ok(Decoded::Frame(f)) => frames.push(f),
                Ok(Decoded::Skipped(n)) => skipped += n,
                Err(e) => errors.push(e),
            }
        }
        (frames, skipped, errors)
    }

    #[test]
    fn header_bits_round_trip() {
        let h = Header::new(FrameType::Response, 0xBEEF, 0xCAFE, 0x10_0012, 300)
            .unwrap()
            .with_error(3, 22);
        assert_eq!(h.version(), 1);
        assert_eq!(h.frame_type(), Some(FrameType::Response));
        assert_eq!(h.device_id(), 0);
        assert_eq!((h.error_code(), h.error_sub_code()), (3, 22));
        assert_eq!((h.session_id(), h.message_id()), (0xBEEF, 0xCAFE));
        assert_eq!((h.service_version(), h.function_uid()), (1, 0x10_0012));
        assert_eq!(h.payload_len(), 300);
        assert!(Header::new(FrameType::Request, 0, 0, 0x1000_0000, 0).is_err());
        assert!(Header::new(FrameType::Request, 0, 0, 1, MAX_PAYLOAD_LEN + 1).is_err());
    }

    #[test]
    fn error_frames_are_named() {
        let payload = ErrorPayload {
            error_code: 3,
            error_sub_code: 22,
            error_sub_string: "joint 3 over current".into(),
        }
        .encode_to_vec();
        let mut f = frame(9, &payload);
        assert_eq!(f.error(), None, "no error code in the header: no error");
        f.header = Some(f.header().with_error(3, 22));
        let e = f.error().unwrap();
        assert_eq!(
            e.to_string(),
            "device error (code 3), robot in fault (sub-code 22): joint 3 over current"
        );
        let f = Frame {
            header: Some(frame(1, &[]).header().with_error(1, 99)),
            payload: vec![0xFF],
        };
        assert_eq!(
            f.error().unwrap().to_string(),
            "protocol server error (code 1), sub-code 99"
        );
    }

    #[test]
    fn frames_split_at_every_byte_are_reassembled() {
        let mut bytes = tcp(&frame(1, b"\x08\x02"));
        bytes.extend(tcp(&frame(2, &[])));
        for cut in 0..=bytes.len() {
            let mut d = FrameDecoder::new();
            d.push(&bytes[..cut]);
            let (mut frames, skipped, errors) = drain(&mut d);
            d.push(&bytes[cut..]);
            let (more, skipped2, errors2) = drain(&mut d);
            frames.extend(more);
            assert_eq!((skipped + skipped2, errors.len() + errors2.len()), (0, 0));
            let ids: Vec<u16> = frames.iter().map(|f| f.header().message_id()).collect();
            assert_eq!(ids, [1, 2], "cut at {cut}");
            assert_eq!(d.truncated(), None);
        }
    }

    #[test]
    fn a_wrong_magic_is_skipped_up_to_the_next_frame() {
        let good = tcp(&frame(7, b"\x08\x02"));
        // Garbage that itself contains the magic's first bytes, then a frame whose magic is
        // damaged, then a good frame.
        let mut bytes = b"\x00\x07\x78\x45junk".to_vec();
        let mut damaged = tcp(&frame(6, &[]));
        damaged[3] ^= 0xFF;
        bytes.extend(&damaged);
        bytes.extend(&good);
        let mut d = FrameDecoder::new();
        d.push(&bytes);
        let (frames, skipped, errors) = drain(&mut d);
        assert!(errors.is_empty(), "{errors:?}");
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].header().message_id(), 7);
        assert_eq!(skipped, bytes.len() - good.len());
    }

    #[test]
    fn too_long_and_undecodable_frames_are_errors_and_the_stream_goes_on() {
        let mut bytes = MAGIC.to_vec();
        bytes.extend(0xFFFF_FFF0u32.to_be_bytes());
        // A frame whose body is not protobuf (field 1 with wire type 7 does not exist).
        bytes.extend(MAGIC);
        bytes.extend(2u32.to_be_bytes());
        bytes.extend([0x0F, 0x00]);
        bytes.extend(tcp(&frame(3, &[])));
        let mut d = FrameDecoder::new();
        d.push(&bytes);
        let (frames, skipped, errors) = drain(&mut d);
        assert_eq!(frames.len(), 1);
        assert!(
            matches!(
                errors[0],
                WireError::FrameTooLong {
                    len: 0xFFFF_FFF0,
                    ..
                }
            ),
            "{errors:?}"
        );
        assert!(matches!(errors[1], WireError::Decode { len: 2, .. }));
        assert_eq!(skipped, 11, "the rest of the bad prefix");
    }

    #[test]
    fn a_cut_frame_is_reported_as_truncated() {
        let bytes = tcp(&frame(4, b"\x08\x02"));
        let mut d = FrameDecoder::new();
        d.push(&bytes[..5]);
        assert!(d.next_frame().is_none());
        assert_eq!(d.truncated(), Some((5, PREFIX_LEN)));
        d.push(&bytes[5..bytes.len() - 1]);
        assert!(d.next_frame().is_none());
        assert_eq!(d.truncated(), Some((bytes.len() - 1, bytes.len())));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic_and_the_decoder_only_waits_on_a_plausible_frame(
            chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..64), 0..16),
        ) {
            let mut d = FrameDecoder::new();
            for c in &chunks {
                d.push(c);
                let before = d.buffered();
                let mut steps = 0;
                while let Some(r) = d.next_frame() {
                    steps += 1;
                    prop_assert!(steps <= before + 1, "the decoder does not make progress");
                    if let Ok(Decoded::Skipped(n)) = r {
                        prop_assert!(n > 0);
                    }
                }
                // What is left is the start of a frame: the magic as far as it goes, and a
                // length the decoder accepts.
                let n = d.buf.len().min(MAGIC.len());
                prop_assert_eq!(&d.buf[..n], &MAGIC[..n]);
                if d.buf.len() >= PREFIX_LEN {
                    prop_assert!(d.announced_len() <= MAX_FRAME_LEN);
                    prop_assert!(d.buf.len() < PREFIX_LEN + d.announced_len());
                }
            }
        }

        #[test]
        fn frames_between_garbage_are_all_recovered(
            ids in proptest::collection::vec(any::<u16>(), 1..8),
            garbage in proptest::collection::vec(proptest::collection::vec(0u8..0x07, 0..20), 8),
            split in 1usize..40,
        ) {
            let mut bytes = Vec::new();
            for (i, id) in ids.iter().enumerate() {
                bytes.extend(&garbage[i]);
                bytes.extend(tcp(&frame(*id, &id.to_le_bytes())));
            }
            let mut d = FrameDecoder::new();
            let mut got = Vec::new();
            for c in bytes.chunks(split) {
                d.push(c);
                let (frames, _, errors) = drain(&mut d);
                prop_assert!(errors.is_empty());
                got.extend(frames.iter().map(|f| f.header().message_id()));
            }
            prop_assert_eq!(got, ids);
        }
    }
}
