//! The recording format: every topic of a graph as one MCAP channel of JSON messages.
//!
//! * One channel per service, named `/<topic>` (`/robot_state`, `/safe_command`, ...), with
//!   message encoding `json` and a JSON schema (schema encoding `jsonschema`), so a recording
//!   opens in Foxglove and any MCAP reader with named, typed fields.
//! * `publish_time` is the message's own `t_ns` (`CLOCK_MONOTONIC`, the one clock of the graph,
//!   also in the message itself); `log_time` is the same instant on the wall clock (the
//!   writer's [`LogClock`]: `t_ns` plus the offset of the two clocks read together when the
//!   recording started), so Foxglove shows the date of the run. Older recordings have
//!   `log_time == publish_time`. The `scl.recording` metadata record holds the two readings.
//! * Chunks are zstd-compressed and written whole, each with its CRC: a file cut anywhere reads
//!   back up to its last complete chunk ([`read`] tolerates the cut, [`recover`] rewrites the
//!   readable prefix as a finished file). No length in a file is trusted: a damaged or foreign
//!   file is an early stop or an error naming the file and the byte offset, never a panic.
//!
//! [`Payload`] is a message as it came off shared memory. Its JSON form and the channel's
//! schema are derived from the message type itself (`serde` and `schemars` derives in
//! `ipc-types`, feature `json`): the struct's fields, joint arrays whole with their count, a
//! tick of "none" as `null`; the schema is `schemars::schema_for!(T)`. Channels carry their
//! format in the [`FORMAT_KEY`] metadata; recordings made before (format 1, hand-written
//! mirror structs, no such key) still read, and their robot states still decode
//! ([`decode_robot_state`]).
#![cfg_attr(test, allow(clippy::unwrap_used, clippy::needless_range_loop))]

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use ipc_types::{MAX_JOINTS, NO_TICK, RobotState};
use mcap::records::MessageHeader;
/// A metadata record (name and string pairs), as [`metadata`] builds it.
pub use mcap::records::Metadata;
use mcap::write::NoSeek;
use serde_json::Value;

mod lengths;

/// The SHA-256 digest of `bytes` in lower-case hex: how a recording names the files it embeds
/// (models, the graph configuration).
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    use std::fmt::Write as _;
    let mut out = String::with_capacity(64);
    for b in sha2::Sha256::digest(bytes) {
        let _ = write!(out, "{b:02x}");
    }
    out
}

/// Metadata record written when a recording starts.
pub const START_METADATA: &str = "scl.recording";
/// Metadata record written when a recording is closed cleanly: counts per topic.
pub const END_METADATA: &str = "scl.recording.end";
/// Metadata record [`recover`] adds to the file it writes.
pub const RECOVERED_METADATA: &str = "scl.recovered";
/// Metadata record name of one process of the graph as the recorder found it (its role, pid,
/// mapper id, command line; for a mapper the model it serves, for safety the configuration it
/// runs), written when the process is first seen: at start and at every swap or restart.
pub const PROCESS_METADATA: &str = "scl.process";
/// Channel metadata key of the JSON format of a graph topic's channel ([`FORMAT`]); a channel
/// without it is format 1 (recordings made before the JSON was derived from the types).
pub const FORMAT_KEY: &str = "scl.format";
/// The JSON format [`LogWriter::add_topic`] writes: 2, the message types' serde / schemars
/// derives. Format 1 had mirror structs (joint arrays cut to the valid joints, flag names).
pub const FORMAT: u32 = 2;

/// Why a recording could not be written, read or recovered.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// A file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The output file exists; recordings are never overwritten.
    #[error("{0} already exists; choose another --out or remove it first")]
    Exists(PathBuf),
    /// The file does not start like an MCAP file.
    #[error("{path}: not an MCAP file ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the reader said.
        reason: String,
    },
    /// The MCAP writer refused a record.
    #[error("{path}: cannot write the recording: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the writer said.
        reason: String,
    },
    /// A `--topics` entry is not a topic of the graph.
    #[error("unknown topic `{0}` in --topics; known topics: {known}", known = Topic::known())]
    UnknownTopic(String),
    /// A channel in a format this build does not decode as message types: format 1 (recorded
    /// before the JSON was derived from the message types; its robot states decode with
    /// [`decode_robot_state`]) or a newer one.
    #[error(
        "{path}: channel {topic} is in recording format {format}; this scl decodes format {FORMAT} (and the robot states of format 1)"
    )]
    Format {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The channel's format.
        format: u32,
    },
    /// A message does not decode as the type its channel names.
    #[error("{path}: message {sequence} on {topic} does not decode: {reason}")]
    Decode {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: String,
        /// The message's sequence number.
        sequence: u32,
        /// What serde said.
        reason: String,
    },
}

/// Declares [`Topic`] and [`Payload`] from `ipc_types::recorded_topics!` (the graph's
/// one topic table): a topic added there is recorded, with its channel, schema and JSON form,
/// with no edit here.
macro_rules! recorded {
    ($($(#[$doc:meta])* $variant:ident: $msg:ident => $ty:path, $topic:path;)*) => {
        /// A topic of the graph, as the recorder subscribes to it and names its channel.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum Topic {
            $(
                $(#[$doc])*
                $variant,
            )*
        }

        impl Topic {
            /// Every topic, in channel order.
            pub const ALL: [Topic; Self::COUNT] = [$(Topic::$variant),*];
            /// Number of topics.
            pub const COUNT: usize = [$(stringify!($variant)),*].len();

            /// The topic's service name below the graph prefix (`robot_state`).
            pub fn name(self) -> &'static str {
                match self {
                    $(Topic::$variant => $topic.name,)*
                }
            }

            /// The schema name (`scl.RobotState`).
            pub fn schema_name(self) -> &'static str {
                match self {
                    $(Topic::$variant => concat!("scl.", stringify!($msg)),)*
                }
            }

            /// The JSON schema (draft 2020-12) of the topic's messages: `schemars::schema_for!`
            /// of the message type.
            pub fn schema(self) -> Value {
                match self {
                    $(Topic::$variant => schemars::schema_for!($ty),)*
                }
                .to_value()
            }
        }

        /// One message as it came off shared memory.
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub enum Payload {
            $(
                #[doc = concat!("A `", stringify!($msg), "`.")]
                $variant($ty),
            )*
        }

        impl Payload {
            /// The topic it was published on.
            pub fn topic(&self) -> Topic {
                match self {
                    $(Payload::$variant(_) => Topic::$variant,)*
                }
            }

            /// When it was produced (monotonic ns): its log and publish time in the recording.
            pub fn t_ns(&self) -> u64 {
                match self {
                    $(Payload::$variant(m) => m.t_ns,)*
                }
            }

            /// Appends its JSON form to `out`.
            pub fn write_json(&self, out: &mut Vec<u8>) -> serde_json::Result<()> {
                match self {
                    $(Payload::$variant(m) => serde_json::to_writer(out, m),)*
                }
            }

            /// A message of `topic` from its JSON form.
            pub fn from_json(topic: Topic, json: &[u8]) -> serde_json::Result<Payload> {
                match topic {
                    $(Topic::$variant => serde_json::from_slice::<$ty>(json).map(Payload::$variant),)*
                }
            }
        }
    };
}

ipc_types::recorded_topics!(recorded);

impl Topic {
    /// The MCAP channel topic (`/robot_state`).
    pub fn channel(self) -> String {
        format!("/{}", self.name())
    }

    /// Position in [`Topic::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The topic named `s` (`robot_state` or `/robot_state`).
    pub fn from_name(s: &str) -> Option<Topic> {
        let s = s.trim().trim_start_matches('/');
        Self::ALL.into_iter().find(|t| t.name() == s)
    }

    /// The topic of MCAP channel `channel`, if it is one of the graph's.
    pub fn from_channel(channel: &str) -> Option<Topic> {
        channel.strip_prefix('/').and_then(Self::from_name)
    }

    /// Parses a `--topics` list (names separated by commas); empty means every topic.
    pub fn parse_list(list: &[String]) -> Result<Vec<Topic>, RecordError> {
        let mut out = Vec::new();
        for item in list.iter().flat_map(|s| s.split(',')) {
            if item.trim().is_empty() {
                continue;
            }
            let t = Topic::from_name(item).ok_or_else(|| RecordError::UnknownTopic(item.into()))?;
            if !out.contains(&t) {
                out.push(t);
            }
        }
        if out.is_empty() {
            out = Self::ALL.to_vec();
        }
        out.sort();
        Ok(out)
    }

    fn known() -> String {
        Self::ALL.map(Topic::name).join(", ")
    }
}

/// A channel of a recording, as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// Channel id in the file.
    pub id: u16,
    /// Topic (`/robot_state`).
    pub topic: String,
    /// Message encoding (`json`).
    pub message_encoding: String,
    /// Channel metadata.
    pub metadata: BTreeMap<String, String>,
    /// Its schema, if it has one.
    pub schema: Option<SchemaInfo>,
}

impl ChannelInfo {
    /// The JSON format of its messages: the [`FORMAT_KEY`] metadata, 1 without it.
    pub fn format(&self) -> u32 {
        self.metadata
            .get(FORMAT_KEY)
            .and_then(|f| f.parse().ok())
            .unwrap_or(1)
    }
}

/// A schema of a recording, as read back.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemaInfo {
    /// Schema name.
    pub name: String,
    /// Schema encoding (`jsonschema`).
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
}

/// How a writer turns a message's monotonic `t_ns` into its MCAP `log_time`: plus the offset
/// of the wall clock from the monotonic clock ([`LogClock::wall_now`]), or unchanged
/// ([`LogClock::MONOTONIC`], the default, and what recordings made before used).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LogClock {
    /// Wall-clock time minus monotonic time (ns).
    offset_ns: i64,
}

impl LogClock {
    /// `log_time` is `t_ns`.
    pub const MONOTONIC: LogClock = LogClock { offset_ns: 0 };

    /// The wall clock (`CLOCK_REALTIME`) and the monotonic clock read now, together; also
    /// returns the two readings (monotonic ns, Unix ns) for the recording's metadata.
    pub fn wall_now() -> (Self, u64, u64) {
        let mono = ipc_types::time::now_ns();
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
        (Self::from_pair(mono, unix), mono, unix)
    }

    /// The clock that maps monotonic `mono_ns` to `unix_ns`.
    pub fn from_pair(mono_ns: u64, unix_ns: u64) -> Self {
        let d = i128::from(unix_ns) - i128::from(mono_ns);
        Self {
            offset_ns: i64::try_from(d).unwrap_or(0),
        }
    }

    /// The clock a message was written with: its `log_time` against its `publish_time` (its
    /// monotonic time). For the messages a copy derives from a recorded one.
    pub fn of_message(log_time: u64, publish_time: u64) -> Self {
        Self::from_pair(publish_time, log_time)
    }

    /// The `log_time` of a message of monotonic time `t_ns`.
    pub fn log_time(self, t_ns: u64) -> u64 {
        t_ns.saturating_add_signed(self.offset_ns)
    }
}

/// Writes a recording: channels, JSON messages, metadata, in whole CRC-checked zstd chunks
/// that are closed by [`LogWriter::flush`] (the recorder flushes once a second), at
/// [`CHUNK_BYTES`], or by [`LogWriter::finish`]. Generic over the sink so tests write to
/// memory or `/dev/full`.
pub struct LogWriter<W: Write> {
    mcap: mcap::Writer<NoSeek<W>>,
    topics: [Option<u16>; Topic::COUNT],
    sequence: [u32; Topic::COUNT],
    json: Vec<u8>,
    path: PathBuf,
    clock: LogClock,
    /// Channel ids of a source recording -> their copies' ([`LogWriter::copy_event`]).
    copied: BTreeMap<u16, u16>,
}

impl<W: Write> std::fmt::Debug for LogWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogWriter")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

/// Metadata `name` with the given entries.
pub fn metadata(name: &str, entries: BTreeMap<String, String>) -> Metadata {
    Metadata {
        name: name.to_owned(),
        metadata: entries,
    }
}

impl<W: Write> LogWriter<W> {
    /// Starts a recording into `sink` (named `path` in errors): the header and the `start`
    /// metadata. Channels are added with [`LogWriter::add_topic`] or [`LogWriter::add_channel`].
    pub fn new(sink: W, path: &Path, start: Option<Metadata>) -> Result<Self, RecordError> {
        let opts = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            // One thread: the writer's own (compression runs in the recorder's writer thread,
            // at low priority, never beside the loop).
            .compression_threads(0)
            .profile("")
            .library(format!("scl-teleop {}", env!("CARGO_PKG_VERSION")))
            // A chunk is buffered and written whole: when the recorder flushes (once a second)
            // or at CHUNK_BYTES, so a chunk on disk is always whole and never larger than a
            // reader accepts (MAX_CHUNK_BYTES).
            .chunk_size(Some(CHUNK_BYTES))
            .disable_seeking(true);
        let werr = |e: mcap::McapError| RecordError::Write {
            path: path.to_owned(),
            reason: e.to_string(),
        };
        let mut mcap = opts.create(NoSeek::new(sink)).map_err(werr)?;
        if let Some(m) = start {
            mcap.write_metadata(&m).map_err(werr)?;
        }
        Ok(Self {
            mcap,
            topics: [None; Topic::COUNT],
            sequence: [0; Topic::COUNT],
            json: Vec::with_capacity(1024),
            path: path.to_owned(),
            clock: LogClock::MONOTONIC,
            copied: BTreeMap::new(),
        })
    }

    /// Sets how [`LogWriter::write`] stamps `log_time` (from now on).
    pub fn set_clock(&mut self, clock: LogClock) {
        self.clock = clock;
    }

    /// How [`LogWriter::write`] stamps `log_time`.
    pub fn clock(&self) -> LogClock {
        self.clock
    }

    /// Copies one event of a recording being read ([`read`]) as it is: a channel (with its
    /// schema and metadata), a message (on the copy of its channel, with its times), a metadata
    /// record, an attachment. Returns the id of the copy of a channel (for a channel event).
    pub fn copy_event(&mut self, ev: &Event<'_>) -> Result<Option<u16>, RecordError> {
        match *ev {
            Event::Channel(c) => {
                let id = self.add_channel(
                    &c.topic,
                    c.schema.as_ref(),
                    &c.message_encoding,
                    &c.metadata,
                )?;
                self.copied.insert(c.id, id);
                return Ok(Some(id));
            }
            Event::Message {
                channel,
                sequence,
                log_time,
                publish_time,
                data,
            } => {
                let Some(id) = self.copied.get(&channel.id).copied() else {
                    return Err(RecordError::Write {
                        path: self.path.clone(),
                        reason: format!(
                            "channel {} ({}) was not copied",
                            channel.id, channel.topic
                        ),
                    });
                };
                self.write_raw(id, sequence, log_time, publish_time, data)?;
            }
            Event::Metadata { name, entries } => {
                self.write_metadata(&metadata(name, entries.clone()))?;
            }
            Event::Attachment {
                name,
                log_time,
                media_type,
                data,
            } => self.attach(name, log_time, media_type, data)?,
        }
        Ok(None)
    }

    fn werr(&self, e: mcap::McapError) -> RecordError {
        RecordError::Write {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    /// Adds a channel with its schema; returns its id.
    pub fn add_channel(
        &mut self,
        topic: &str,
        schema: Option<&SchemaInfo>,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> Result<u16, RecordError> {
        let schema_id = match schema {
            Some(s) => self
                .mcap
                .add_schema(&s.name, &s.encoding, &s.data)
                .map_err(|e| self.werr(e))?,
            None => 0,
        };
        self.mcap
            .add_channel(schema_id, topic, message_encoding, metadata)
            .map_err(|e| self.werr(e))
    }

    /// Adds the channel of a graph topic (JSON messages with the topic's JSON schema);
    /// `metadata` goes on the channel (e.g. the graph prefix), with [`FORMAT_KEY`].
    pub fn add_topic(
        &mut self,
        topic: Topic,
        metadata: &BTreeMap<String, String>,
    ) -> Result<u16, RecordError> {
        let schema = SchemaInfo {
            name: topic.schema_name().to_owned(),
            encoding: "jsonschema".to_owned(),
            data: topic.schema().to_string().into_bytes(),
        };
        let mut metadata = metadata.clone();
        metadata.insert(FORMAT_KEY.to_owned(), FORMAT.to_string());
        let id = self.add_channel(&topic.channel(), Some(&schema), "json", &metadata)?;
        self.topics[topic.index()] = Some(id);
        Ok(id)
    }

    /// Writes raw message bytes on channel `channel_id`.
    pub fn write_raw(
        &mut self,
        channel_id: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<(), RecordError> {
        let header = MessageHeader {
            channel_id,
            sequence,
            log_time,
            publish_time,
        };
        self.mcap
            .write_to_known_channel(&header, data)
            .map_err(|e| self.werr(e))
    }

    /// Writes a message of the graph as JSON on its topic's channel (added with
    /// [`LogWriter::add_topic`]), `publish_time` its `t_ns` and `log_time` that on the
    /// writer's [`LogClock`]; returns the bytes of JSON written.
    pub fn write(&mut self, p: &Payload) -> Result<usize, RecordError> {
        let topic = p.topic();
        let Some(channel_id) = self.topics[topic.index()] else {
            return Err(RecordError::Write {
                path: self.path.clone(),
                reason: format!("no channel for topic {}", topic.name()),
            });
        };
        self.json.clear();
        p.write_json(&mut self.json)
            .map_err(|e| RecordError::Write {
                path: self.path.clone(),
                reason: format!("cannot encode a {} message: {e}", topic.name()),
            })?;
        let seq = &mut self.sequence[topic.index()];
        *seq = seq.wrapping_add(1);
        let header = MessageHeader {
            channel_id,
            sequence: *seq,
            log_time: self.clock.log_time(p.t_ns()),
            publish_time: p.t_ns(),
        };
        let n = self.json.len();
        self.mcap
            .write_to_known_channel(&header, &self.json)
            .map_err(|e| RecordError::Write {
                path: self.path.clone(),
                reason: e.to_string(),
            })?;
        Ok(n)
    }

    /// Writes an attachment (a file the run used: a model, the configuration) at `log_time`.
    pub fn attach(
        &mut self,
        name: &str,
        log_time: u64,
        media_type: &str,
        data: &[u8],
    ) -> Result<(), RecordError> {
        let a = mcap::Attachment {
            log_time,
            create_time: log_time,
            name: name.to_owned(),
            media_type: media_type.to_owned(),
            data: std::borrow::Cow::Borrowed(data),
        };
        self.mcap.attach(&a).map_err(|e| self.werr(e))
    }

    /// Writes a metadata record.
    pub fn write_metadata(&mut self, m: &Metadata) -> Result<(), RecordError> {
        self.mcap.write_metadata(m).map_err(|e| self.werr(e))
    }

    /// Closes the current chunk (if any) and pushes everything to the sink: what was written
    /// so far survives a crash of the process.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.mcap.flush().map_err(|e| self.werr(e))
    }

    /// Writes `end` metadata (if any), the summary (statistics, indexes) and the footer;
    /// returns the sink, flushed.
    pub fn finish(mut self, end: Option<Metadata>) -> Result<W, RecordError> {
        if let Some(m) = end {
            self.mcap.write_metadata(&m).map_err(|e| self.werr(e))?;
        }
        self.mcap.finish().map_err(|e| self.werr(e))?;
        let path = self.path.clone();
        let mut sink = self.mcap.into_inner().into_inner();
        sink.flush()
            .map_err(|source| RecordError::Io { path, source })?;
        Ok(sink)
    }
}

/// One event of a recording, in file order.
#[derive(Debug)]
pub enum Event<'a> {
    /// A channel was defined.
    Channel(&'a ChannelInfo),
    /// A message.
    Message {
        /// Its channel.
        channel: &'a ChannelInfo,
        /// Sequence number.
        sequence: u32,
        /// Log time (ns).
        log_time: u64,
        /// Publish time (ns).
        publish_time: u64,
        /// The message bytes (JSON for the graph's topics).
        data: &'a [u8],
    },
    /// A metadata record.
    Metadata {
        /// Its name.
        name: &'a str,
        /// Its entries.
        entries: &'a BTreeMap<String, String>,
    },
    /// An attachment (a file the run used).
    Attachment {
        /// Its name.
        name: &'a str,
        /// Log time (ns).
        log_time: u64,
        /// Its media type.
        media_type: &'a str,
        /// Its bytes (CRC-checked by the reader when the file has a CRC).
        data: &'a [u8],
    },
}

/// Where and why reading stopped before a recording's data-end record.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stopped {
    /// Byte offset in the file of the record that could not be read (or of the end of the
    /// file, for [`StopCause::NoDataEnd`]).
    pub offset: u64,
    /// Why.
    pub cause: StopCause,
}

/// Why reading stopped early: see [`Stopped`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StopCause {
    /// The file ends inside a record: cut while that record was being written (a crash), or a
    /// record's length field is damaged and points past the end of the file.
    Cut {
        /// The record's length as its header gives it (with its 9-byte header).
        length: u64,
        /// The bytes the file has from the record's start.
        left: u64,
    },
    /// The file ends after a whole record but without the data-end record (the recorder did
    /// not finish it).
    NoDataEnd,
    /// A record that does not read: a chunk whose CRC does not match, a length or field out of
    /// bounds, a message on a channel never defined. The text is the MCAP reader's.
    Damaged(String),
}

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let at = self.offset;
        match &self.cause {
            StopCause::Cut { length, left } => write!(
                f,
                "the file ends inside the record at byte {at} ({length} bytes long, {left} in the file: cut off by a crash, or a damaged length)"
            ),
            StopCause::NoDataEnd => write!(
                f,
                "the file ends at byte {at} without its data-end record (not finished)"
            ),
            StopCause::Damaged(why) => write!(f, "damaged record at byte {at}: {why}"),
        }
    }
}

/// How far a recording could be read.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ReadSummary {
    /// Messages read.
    pub messages: u64,
    /// Whether the data section ended properly (a clean stop). A recording cut by a crash is
    /// read up to its last complete chunk and is not complete.
    pub complete: bool,
    /// Where and why reading stopped before the end of the data, for an incomplete recording.
    pub stopped: Option<Stopped>,
}

/// The largest a compressed chunk may say it expands to. The writer closes a chunk at
/// [`CHUNK_BYTES`] (plus one message), so a chunk claiming more is damaged; the reader never
/// allocates more than this for one chunk, whatever its header says.
pub const MAX_CHUNK_BYTES: u64 = 64 << 20;

/// The uncompressed size at which [`LogWriter`] closes a chunk (it also closes one at every
/// [`LogWriter::flush`]).
pub const CHUNK_BYTES: u64 = 4 << 20;

/// The MCAP magic that starts (and ends) a file.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// A source of bytes that counts where it is, and reads a record only as far as the file
/// really goes: a length field is never trusted for an allocation.
struct Source<'p, R> {
    inner: R,
    offset: u64,
    path: &'p Path,
}

impl<R: Read> Source<'_, R> {
    /// Up to `n` bytes (fewer at the end of the file); the buffer grows with the bytes read,
    /// not with `n`.
    fn take(&mut self, n: u64, into: &mut Vec<u8>) -> Result<(), RecordError> {
        into.clear();
        (&mut self.inner)
            .take(n)
            .read_to_end(into)
            .map_err(|source| RecordError::Io {
                path: self.path.to_owned(),
                source,
            })?;
        self.offset += into.len() as u64;
        Ok(())
    }
}

/// What [`read`] keeps while walking a file: the schemas and channels so far, and the caller.
struct Walk<F> {
    schemas: BTreeMap<u16, SchemaInfo>,
    channels: BTreeMap<u16, ChannelInfo>,
    summary: ReadSummary,
    on: F,
}

/// A record [`Walk::record`] could not take: damage in the file (reading stops there), or
/// the caller's error (returned as it is).
enum RecordStop {
    Damaged(String),
    Caller(RecordError),
}

impl<F: FnMut(Event<'_>) -> Result<(), RecordError>> Walk<F> {
    /// One record (top level or from a chunk); `Ok(true)` at the data-end record.
    fn record(&mut self, opcode: u8, body: &[u8]) -> Result<bool, RecordStop> {
        use mcap::records::{Record, op};
        // Before the crate parses it: it reserves what a length field says (`lengths`).
        lengths::check(opcode, body).map_err(|e| RecordStop::Damaged(e.to_string()))?;
        if opcode == op::CHUNK {
            return self.chunk(body).map(|()| false);
        }
        let record =
            mcap::parse_record(opcode, body).map_err(|e| RecordStop::Damaged(e.to_string()))?;
        let on = &mut self.on;
        match record {
            Record::Schema { header, data } => {
                self.schemas.insert(
                    header.id,
                    SchemaInfo {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    },
                );
            }
            Record::Channel(c) if !self.channels.contains_key(&c.id) => {
                let info = ChannelInfo {
                    id: c.id,
                    topic: c.topic,
                    message_encoding: c.message_encoding,
                    metadata: c.metadata,
                    schema: self.schemas.get(&c.schema_id).cloned(),
                };
                on(Event::Channel(&info)).map_err(RecordStop::Caller)?;
                self.channels.insert(c.id, info);
            }
            Record::Message { header, data } => {
                let Some(channel) = self.channels.get(&header.channel_id) else {
                    return Err(RecordStop::Damaged(format!(
                        "message {} names channel {}, which was not defined",
                        header.sequence, header.channel_id
                    )));
                };
                self.summary.messages += 1;
                on(Event::Message {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data: &data,
                })
                .map_err(RecordStop::Caller)?;
            }
            Record::Metadata(m) => on(Event::Metadata {
                name: &m.name,
                entries: &m.metadata,
            })
            .map_err(RecordStop::Caller)?,
            Record::Attachment { header, data, .. } => on(Event::Attachment {
                name: &header.name,
                log_time: header.log_time,
                media_type: &header.media_type,
                data: &data,
            })
            .map_err(RecordStop::Caller)?,
            Record::DataEnd(_) => return Ok(true),
            _ => {}
        }
        Ok(false)
    }

    /// The records of a chunk (its body in memory), once its sizes are checked against the
    /// body and [`MAX_CHUNK_BYTES`] and its CRC against its contents (the mcap crate's linear
    /// reader decompresses and checks it, under a record length limit of the chunk's size).
    fn chunk(&mut self, body: &[u8]) -> Result<(), RecordStop> {
        use mcap::records::{Record, op};
        use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
        let damaged = |why: String| RecordStop::Damaged(why);
        let header = match mcap::parse_record(op::CHUNK, body) {
            Ok(Record::Chunk { header, .. }) => header,
            Ok(_) => return Err(damaged("not a chunk".into())),
            Err(e) => return Err(damaged(e.to_string())),
        };
        let limit = if header.compression.is_empty() {
            if header.uncompressed_size != header.compressed_size {
                return Err(damaged(format!(
                    "an uncompressed chunk of {} bytes says it holds {}",
                    header.compressed_size, header.uncompressed_size
                )));
            }
            header.compressed_size
        } else {
            if header.uncompressed_size > MAX_CHUNK_BYTES {
                return Err(damaged(format!(
                    "a chunk says it expands to {} bytes (at most {MAX_CHUNK_BYTES})",
                    header.uncompressed_size
                )));
            }
            header.uncompressed_size.max(header.compressed_size)
        };
        let limit = usize::try_from(limit).map_err(|_| damaged("chunk too large".into()))?;
        let mut reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_skip_start_magic(true)
                .with_skip_end_magic(true)
                .with_emit_chunks(false)
                // A chunk yields its records only once its whole body checked out.
                .with_prevalidate_chunk_crcs(true)
                .with_record_length_limit(limit.max(64)),
        );
        // The record as it is in the file: opcode, length, body.
        let len = (body.len() as u64).to_le_bytes();
        let mut parts = [&[op::CHUNK][..], &len[..], body];
        while let Some(event) = reader.next_event() {
            match event.map_err(|e| damaged(e.to_string()))? {
                LinearReadEvent::ReadRequest(need) => {
                    let part = parts.iter_mut().find(|p| !p.is_empty());
                    let n = match part {
                        Some(p) => {
                            let n = need.min(p.len());
                            reader.insert(n).copy_from_slice(&p[..n]);
                            *p = &p[n..];
                            n
                        }
                        None => 0,
                    };
                    reader.notify_read(n);
                }
                LinearReadEvent::Record { opcode, data } => {
                    if opcode == op::CHUNK || opcode == op::DATA_END {
                        return Err(damaged(format!("record {opcode:#04x} inside a chunk")));
                    }
                    self.record(opcode, data)?;
                }
            }
        }
        Ok(())
    }
}

/// Reads the recording from `src` (named `path` in errors) in file order, calling `on` for
/// every channel, message and metadata record. Tolerates a cut or damaged tail: whole chunks
/// before it are read, the summary tells where and why it stopped ([`Stopped`]). No length in
/// the file is trusted: a record is read only as far as the file goes, a chunk expands to at
/// most [`MAX_CHUNK_BYTES`], so a corrupt file is never more than an early stop or an error.
/// Fails only if the source is not an MCAP file, cannot be read from the start, or `on`
/// fails.
pub fn read<R: Read>(
    src: R,
    path: &Path,
    on: impl FnMut(Event<'_>) -> Result<(), RecordError>,
) -> Result<ReadSummary, RecordError> {
    const HEADER: u64 = 9; // opcode and length
    let mut src = Source {
        inner: src,
        offset: 0,
        path,
    };
    let not_mcap = |reason: String| RecordError::NotMcap {
        path: path.to_owned(),
        reason,
    };
    let mut buf = Vec::new();
    src.take(MAGIC.len() as u64, &mut buf)?;
    if buf != MAGIC {
        return Err(not_mcap("it does not start with the MCAP magic".into()));
    }
    let mut walk = Walk {
        schemas: BTreeMap::new(),
        channels: BTreeMap::new(),
        summary: ReadSummary::default(),
        on,
    };
    let mut started = false;
    let mut head = Vec::with_capacity(HEADER as usize);
    loop {
        let offset = src.offset;
        let stop = |cause: StopCause| Stopped { offset, cause };
        src.take(HEADER, &mut head)?;
        let left = head.len() as u64;
        if left < HEADER {
            walk.summary.stopped = Some(stop(if left == 0 {
                StopCause::NoDataEnd
            } else {
                StopCause::Cut {
                    length: HEADER,
                    left,
                }
            }));
            break;
        }
        let opcode = head[0];
        let mut len = [0; 8];
        len.copy_from_slice(&head[1..]);
        let len = u64::from_le_bytes(len);
        src.take(len, &mut buf)?;
        if (buf.len() as u64) < len {
            walk.summary.stopped = Some(stop(StopCause::Cut {
                length: HEADER.saturating_add(len),
                left: HEADER + buf.len() as u64,
            }));
            break;
        }
        if !started && opcode != mcap::records::op::HEADER {
            return Err(not_mcap(format!(
                "byte {offset}: record {opcode:#04x} where the header record belongs"
            )));
        }
        match walk.record(opcode, &buf) {
            Ok(true) => {
                walk.summary.complete = true;
                break;
            }
            Ok(false) => started = true,
            Err(RecordStop::Caller(e)) => return Err(e),
            Err(RecordStop::Damaged(why)) if !started => {
                return Err(not_mcap(format!("byte {offset}: {why}")));
            }
            Err(RecordStop::Damaged(why)) => {
                walk.summary.stopped = Some(stop(StopCause::Damaged(why)));
                break;
            }
        }
    }
    if !started && let Some(s) = &walk.summary.stopped {
        return Err(not_mcap(s.to_string()));
    }
    Ok(walk.summary)
}

/// Opens `path` and [`read`]s it.
pub fn read_file(
    path: &Path,
    on: impl FnMut(Event<'_>) -> Result<(), RecordError>,
) -> Result<ReadSummary, RecordError> {
    let f = std::fs::File::open(path).map_err(|source| RecordError::Io {
        path: path.to_owned(),
        source,
    })?;
    read(std::io::BufReader::new(f), path, on)
}

/// Decodes a message of `channel` (of recording `path`) from its JSON, as the message type
/// `T` of the channel's topic. A channel of another format is refused ([`RecordError::Format`]);
/// use [`decode_robot_state`] for robot states of any format.
pub fn decode<T: serde::de::DeserializeOwned>(
    path: &Path,
    channel: &ChannelInfo,
    sequence: u32,
    data: &[u8],
) -> Result<T, RecordError> {
    let format = channel.format();
    if format != FORMAT {
        return Err(RecordError::Format {
            path: path.to_owned(),
            topic: channel.topic.clone(),
            format,
        });
    }
    from_json(path, channel, sequence, data)
}

fn from_json<T: serde::de::DeserializeOwned>(
    path: &Path,
    channel: &ChannelInfo,
    sequence: u32,
    data: &[u8],
) -> Result<T, RecordError> {
    serde_json::from_slice(data).map_err(|e| RecordError::Decode {
        path: path.to_owned(),
        topic: channel.topic.clone(),
        sequence,
        reason: e.to_string(),
    })
}

/// A robot state as format 1 wrote it: joint arrays cut to the valid joints (their length is
/// the joint count), a stop's `applied_tick` `null`; its other fields (`flag_names`) are
/// ignored. Only for reading old recordings.
#[derive(serde::Deserialize)]
struct RobotStateV1 {
    tick: u64,
    t_ns: u64,
    applied_tick: Option<u64>,
    missed: u64,
    flags: u32,
    q_rad: Vec<f64>,
    qdot_rad_s: Vec<f64>,
    gripper: f64,
}

/// Decodes a message of the `/robot_state` channel `channel` of recording `path`, in the
/// current format or in format 1.
pub fn decode_robot_state(
    path: &Path,
    channel: &ChannelInfo,
    sequence: u32,
    data: &[u8],
) -> Result<RobotState, RecordError> {
    match channel.format() {
        1 => {
            let v: RobotStateV1 = from_json(path, channel, sequence, data)?;
            let n = v.q_rad.len();
            if n > MAX_JOINTS || v.qdot_rad_s.len() != n {
                return Err(RecordError::Decode {
                    path: path.to_owned(),
                    topic: channel.topic.clone(),
                    sequence,
                    reason: format!(
                        "{n} joint angles and {} velocities (at most {MAX_JOINTS}, as many of each)",
                        v.qdot_rad_s.len()
                    ),
                });
            }
            let mut s = RobotState::at_rest(v.tick, v.t_ns, n as u32);
            s.applied_tick = v.applied_tick.unwrap_or(NO_TICK);
            s.missed = v.missed;
            s.flags = v.flags;
            s.q_rad[..n].copy_from_slice(&v.q_rad);
            s.qdot_rad_s[..n].copy_from_slice(&v.qdot_rad_s);
            s.gripper = v.gripper;
            Ok(s)
        }
        _ => decode(path, channel, sequence, data),
    }
}

/// Opens `path` for a new file, refusing to replace an existing one.
pub fn create_new(path: &Path) -> Result<std::fs::File, RecordError> {
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map_err(|source| {
            if source.kind() == std::io::ErrorKind::AlreadyExists {
                RecordError::Exists(path.to_owned())
            } else {
                RecordError::Io {
                    path: path.to_owned(),
                    source,
                }
            }
        })
}

/// What [`recover`] did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoverReport {
    /// Messages copied.
    pub messages: u64,
    /// Channels copied.
    pub channels: usize,
    /// Whether the source was complete already.
    pub source_complete: bool,
    /// Where and why reading the source stopped early.
    pub stopped: Option<Stopped>,
}

/// Rewrites the readable part of recording `from` (cut by a crash) as a finished recording
/// `to`: the same channels, schemas, metadata and messages, plus a [`RECOVERED_METADATA`]
/// record. Refuses to replace `to`.
pub fn recover(from: &Path, to: &Path) -> Result<RecoverReport, RecordError> {
    let src = std::fs::File::open(from).map_err(|source| RecordError::Io {
        path: from.to_owned(),
        source,
    })?;
    let out = create_new(to)?;
    let result = recover_into(
        std::io::BufReader::new(src),
        from,
        std::io::BufWriter::new(out),
        to,
    );
    if result.is_err() {
        // Leave no half-written output behind; the source is untouched.
        let _ = std::fs::remove_file(to);
    }
    result.map(|(r, _)| r)
}

/// [`recover`] between streams; returns the report and the sink.
pub fn recover_into<R: Read, W: Write>(
    src: R,
    from: &Path,
    sink: W,
    to: &Path,
) -> Result<(RecoverReport, W), RecordError> {
    let mut w = LogWriter::new(sink, to, None)?;
    let mut channels = 0;
    let summary = read(src, from, |ev| {
        if w.copy_event(&ev)?.is_some() {
            channels += 1;
        }
        Ok(())
    })?;
    let mut entries = BTreeMap::new();
    entries.insert("source".to_owned(), from.display().to_string());
    entries.insert("messages".to_owned(), summary.messages.to_string());
    entries.insert("source_complete".to_owned(), summary.complete.to_string());
    if let Some(s) = &summary.stopped {
        entries.insert("source_stopped".to_owned(), s.to_string());
    }
    let sink = w.finish(Some(metadata(RECOVERED_METADATA, entries)))?;
    Ok((
        RecoverReport {
            messages: summary.messages,
            channels,
            source_complete: summary.complete,
            stopped: summary.stopped,
        },
        sink,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ipc_types::control::estop_action;
    use ipc_types::{
        EstopCommand, JoystickInput, MapperCommand, NodeRole, NodeStatus, SafeCommand,
        SafetyControl, buttons, mapper_flags, phase, safe_flags, safety_state, state_flags,
    };

    fn state(tick: u64) -> RobotState {
        let mut s = RobotState::at_rest(tick, 1_000_000 + tick * 25_000_000, 6);
        s.applied_tick = tick.wrapping_sub(1);
        for j in 0..6 {
            s.q_rad[j] = 0.1 * j as f64 + 1e-3 * tick as f64;
            s.qdot_rad_s[j] = 0.04;
        }
        s.gripper = 0.25;
        s.flags = state_flags::MOCK;
        s
    }

    /// One message per topic, every field set to a value of its own (no zeros, no defaults),
    /// so a field the JSON lost or renamed shows.
    pub(crate) fn samples() -> Vec<Payload> {
        let mut status = NodeStatus::new(NodeRole::Safety, phase::RUNNING, 7);
        status.tick = 11;
        status.handled = 12;
        status.faults = 13;
        status.latency_ns = 14;
        status.lateness_ns = 15;
        status.joint_travel_rad = 1.5;
        status.mapper_id = 2;
        status.safety_state = safety_state::HOLD;
        status.rule_counts = std::array::from_fn(|i| 100 + i as u32);
        status.mode = 3;
        status.mode_switches = 4;
        let safe = SafeCommand {
            tick: 3,
            t_ns: 9,
            state_t_ns: 8,
            state_rx_ns: 18,
            joystick_t_ns: 5,
            joystick_rx_ns: 6,
            mapper_t_ns: 28,
            mapper_rx_ns: 29,
            mapper_compute_ns: 100,
            compute_ns: 200,
            mapper_id: 1,
            n_joints: 6,
            flags: safe_flags::VELOCITY_SCALED | safe_flags::ACCEL_LIMITED,
            control: 0,
            qdot_rad_s: std::array::from_fn(|j| 0.5 - 0.1 * j as f64),
            gripper_rate: -0.75,
            clearance_m: 0.125,
            tcp_speed_m_s: 0.05,
            closest_pair: [0x0300, 0xFF00],
            reserved_tail: 0,
        };
        let mapper = MapperCommand {
            tick: 3,
            t_ns: 8,
            state_t_ns: 7,
            state_rx_ns: 17,
            joystick_t_ns: 5,
            joystick_rx_ns: 6,
            joystick_seq: 2,
            compute_ns: 100,
            mapper_id: 1,
            n_joints: 6,
            flags: mapper_flags::INPUT_CLAMPED,
            buttons: buttons::DEADMAN,
            action: [0.6, -0.8],
            qdot_rad_s: std::array::from_fn(|j| 0.1 * j as f64 - 0.3),
            gripper_rate: 0.5,
        };
        let joy = JoystickInput {
            tick: 4,
            t_ns: 5,
            seq: 6,
            axes: [0.6, -0.8],
            gripper: -0.25,
            buttons: buttons::DEADMAN | buttons::ESTOP,
        };
        let mut robot = state(3);
        robot.missed = 2;
        robot.q_rad[7] = 9.0; // beyond n_joints: recorded as the struct holds it
        vec![
            Payload::Joystick(joy),
            Payload::RobotState(robot),
            Payload::MapperCommand(mapper),
            Payload::SafeCommand(safe),
            Payload::Status(status),
            Payload::SafetyControl(SafetyControl {
                seq: 1,
                t_ns: 2,
                from_tick: 10,
                active_mapper: 1,
                hold: 1,
                estop_seq: 3,
                estop: 1,
            }),
            Payload::Estop(EstopCommand {
                t_ns: 4,
                action: estop_action::ESTOP,
                source_pid: 42,
            }),
        ]
    }

    fn json_of(p: &Payload) -> Value {
        let mut buf = Vec::new();
        p.write_json(&mut buf).unwrap();
        serde_json::from_slice(&buf).unwrap()
    }

    /// The message `v` decodes to, as a payload of `topic`.
    fn payload_of(topic: Topic, v: Value) -> Payload {
        Payload::from_json(topic, &serde_json::to_vec(&v).unwrap()).unwrap()
    }

    #[test]
    fn every_message_matches_its_schema_and_keeps_its_values() {
        let mut all = samples();
        assert_eq!(all.len(), Topic::COUNT);
        // The "no tick" forms as well.
        all.push(Payload::RobotState(RobotState::at_rest(0, 1, 6)));
        all.push(Payload::Status(NodeStatus::new(
            NodeRole::Recorder,
            phase::READY,
            1,
        )));
        all.push(Payload::Joystick(JoystickInput::neutral(1)));
        for p in &all {
            let topic = p.topic();
            let schema = topic.schema();
            assert_eq!(
                schema["$schema"], "https://json-schema.org/draft/2020-12/schema",
                "{topic:?}"
            );
            let v = json_of(p);
            let errs = test_support::json_schema::validate(&v, &schema);
            assert!(errs.is_empty(), "{topic:?}: {errs:#?}\n{v}\n{schema:#}");
            // Every field of the schema is in the data, and required but for the fields added
            // after recordings existed, which read with a default from older files
            // (`SafeCommand.control`, formerly padding) ...
            let props = schema["properties"].as_object().unwrap();
            let required = schema["required"].as_array().unwrap();
            let optional: Vec<&str> = props
                .keys()
                .map(String::as_str)
                .filter(|k| !required.iter().any(|r| r == k))
                .collect();
            let added_later: &[&str] = match topic {
                Topic::SafeCommand => &["control"],
                Topic::Status => &["held_up"],
                _ => &[],
            };
            assert_eq!(optional, added_later, "{topic:?}");
            assert_eq!(v.as_object().unwrap().len(), props.len(), "{topic:?}");
            // ... and the data is the message, exactly.
            assert_eq!(payload_of(topic, v), *p, "{topic:?}");
        }
    }

    #[test]
    fn the_json_is_the_struct_with_none_ticks_null() {
        let v = json_of(&Payload::RobotState(RobotState::at_rest(0, 1, 6)));
        assert!(v["applied_tick"].is_null(), "NO_TICK is null: {v}");
        assert_eq!(v["n_joints"], 6);
        let v = json_of(&samples()[1]);
        assert_eq!(v["applied_tick"], 2);
        // Joint arrays whole, as the struct holds them; the count says which are valid.
        assert_eq!(v["q_rad"].as_array().unwrap().len(), MAX_JOINTS);
        assert_eq!(v["q_rad"][7], 9.0);
        // Padding is not data.
        let v = json_of(&samples()[3]);
        assert!(v.get("reserved").is_none(), "{v}");
        assert_eq!(v["flags"], 16 | 128);
        // The schema names the bits and codes.
        let s = Topic::SafeCommand.schema();
        assert_eq!(s["properties"]["flags"]["x-bit-names"][4], "velocity");
        let s = Topic::Status.schema();
        assert_eq!(s["properties"]["role"]["x-value-names"]["5"], "recorder");
        assert_eq!(s["properties"]["phase"]["x-value-names"]["2"], "running");
        assert_eq!(s["properties"]["rule_counts"]["x-item-names"][12], "e-stop");
        let s = Topic::Joystick.schema();
        assert_eq!(s["properties"]["buttons"]["x-bit-names"][4], "no-device");
        assert_eq!(
            Topic::Estop.schema()["properties"]["action"]["x-value-names"]["2"],
            "reset"
        );
    }

    #[test]
    fn topic_names_parse() {
        assert_eq!(Topic::from_name("/robot_state"), Some(Topic::RobotState));
        assert_eq!(Topic::from_channel("/estop"), Some(Topic::Estop));
        assert_eq!(Topic::from_channel("estop"), None);
        assert_eq!(Topic::parse_list(&[]).unwrap(), Topic::ALL.to_vec());
        assert_eq!(
            Topic::parse_list(&["safe_command,robot_state".into()]).unwrap(),
            vec![Topic::RobotState, Topic::SafeCommand]
        );
        let e = Topic::parse_list(&["robot_states".into()]).unwrap_err();
        assert!(e.to_string().contains("`robot_states`"), "{e}");
        for t in Topic::ALL {
            assert_eq!(Topic::ALL[t.index()], t);
        }
    }

    /// A sink the test can look into while the writer owns it.
    #[derive(Clone, Default)]
    struct Shared(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Shared {
        fn len(&self) -> usize {
            self.0.lock().unwrap().len()
        }
        fn bytes(&self) -> Vec<u8> {
            self.0.lock().unwrap().clone()
        }
    }

    /// A recording of `n` robot states, flushed (a chunk closed) every `per_chunk` messages,
    /// finished or left as a crash leaves it; the file length after each flush; the bytes.
    fn recording(n: u64, per_chunk: u64, finish: bool) -> (Vec<usize>, Vec<u8>) {
        let path = Path::new("mem.mcap");
        let sink = Shared::default();
        let mut start = BTreeMap::new();
        start.insert("prefix".to_owned(), "unit".to_owned());
        let mut w =
            LogWriter::new(sink.clone(), path, Some(metadata(START_METADATA, start))).unwrap();
        for t in Topic::ALL {
            w.add_topic(t, &BTreeMap::new()).unwrap();
        }
        w.flush().unwrap();
        let mut ends = Vec::new();
        for k in 0..n {
            w.write(&Payload::RobotState(state(k))).unwrap();
            if (k + 1) % per_chunk == 0 {
                w.flush().unwrap();
                ends.push(sink.len());
            }
        }
        if finish {
            w.finish(None).unwrap();
        } else {
            w.flush().unwrap();
            // A crash: the process is gone without finishing (no summary, no footer).
            std::mem::forget(w);
        }
        (ends, sink.bytes())
    }

    fn states_in(bytes: &[u8]) -> (ReadSummary, Vec<u64>) {
        let mut ticks = Vec::new();
        let s = read(bytes, Path::new("mem.mcap"), |ev| {
            if let Event::Message {
                channel,
                data,
                sequence,
                ..
            } = ev
                && channel.topic == "/robot_state"
            {
                let m = decode_robot_state(Path::new("mem.mcap"), channel, sequence, data)?;
                ticks.push(m.tick);
            }
            Ok(())
        })
        .unwrap();
        (s, ticks)
    }

    #[test]
    fn a_finished_recording_reads_whole_and_opens_with_the_mcap_crate() {
        let (_, bytes) = recording(100, 10, true);
        let (s, ticks) = states_in(&bytes);
        assert!(s.complete, "{s:?}");
        assert_eq!(ticks, (0..100).collect::<Vec<_>>());
        // The strict reader of the mcap crate and its summary agree.
        let n = mcap::MessageStream::new(&bytes).unwrap().count();
        assert_eq!(n, 100);
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let stats = summary.stats.unwrap();
        assert_eq!(stats.message_count, 100);
        assert_eq!(stats.channel_count, Topic::COUNT as u32);
        let schemas: std::collections::BTreeSet<_> = Topic::ALL.map(Topic::schema_name).into();
        assert_eq!(summary.schemas.len(), schemas.len());
        let ch = summary
            .channels
            .values()
            .find(|c| c.topic == "/robot_state")
            .unwrap();
        assert_eq!(ch.message_encoding, "json");
        assert_eq!(ch.schema.as_ref().unwrap().encoding, "jsonschema");
        assert_eq!(stats.message_start_time, state(0).t_ns);
        assert_eq!(stats.message_end_time, state(99).t_ns);
    }

    #[test]
    fn a_cut_recording_reads_up_to_its_last_complete_chunk() {
        let (ends, bytes) = recording(60, 10, false);
        assert_eq!(ends.len(), 6);
        let (whole, ticks) = states_in(&bytes);
        assert!(!whole.complete);
        assert_eq!(
            ticks.len(),
            60,
            "every flushed chunk is readable: {whole:?}"
        );
        let mut last = 0;
        for cut in (0..=bytes.len()).step_by(7) {
            let mut n = 0;
            match read(&bytes[..cut], Path::new("cut.mcap"), |ev| {
                if matches!(ev, Event::Message { .. }) {
                    n += 1;
                }
                Ok(())
            }) {
                Err(RecordError::NotMcap { .. }) => {
                    assert!(cut < 64, "cut at {cut} refused as not MCAP");
                    continue;
                }
                Err(e) => panic!("cut at {cut}: {e}"),
                Ok(s) => {
                    assert_eq!(s.messages, n);
                    assert!(!s.complete && s.stopped.is_some(), "cut at {cut}: {s:?}");
                }
            }
            let whole_chunks = ends.iter().filter(|e| **e <= cut).count() as u64;
            // Whole chunks only, and at least every chunk that ended before the cut (a cut
            // in the message indexes after a chunk keeps that chunk too).
            assert_eq!(n % 10, 0, "cut at {cut}: {n} messages, a partial chunk");
            assert!(
                n >= 10 * whole_chunks && n <= 10 * whole_chunks + 10,
                "cut at {cut}: {n}"
            );
            assert!(n >= last, "cut at {cut}: fewer messages than a shorter cut");
            last = n;
        }
        assert_eq!(last, 60);
    }

    #[test]
    fn a_damaged_chunk_is_not_read() {
        let (ends, mut bytes) = recording(30, 10, false);
        // Flip a byte inside the second chunk of states: its CRC no longer matches.
        let at = (ends[0] + ends[1]) / 2;
        bytes[at] ^= 0x55;
        let (s, ticks) = states_in(&bytes);
        assert_eq!(ticks, (0..10).collect::<Vec<_>>(), "{s:?}");
        assert!(s.stopped.is_some());
    }

    #[test]
    fn recover_writes_a_finished_file_of_the_readable_prefix() {
        let (ends, bytes) = recording(40, 10, false);
        let cut = &bytes[..ends[2] + 5];
        let (report, fixed) = recover_into(
            cut,
            Path::new("cut.mcap"),
            Vec::new(),
            Path::new("fixed.mcap"),
        )
        .unwrap();
        assert_eq!(report.messages, 30);
        assert_eq!(report.channels, Topic::COUNT);
        assert!(!report.source_complete);
        let (s, ticks) = states_in(&fixed);
        assert!(s.complete, "{s:?}");
        assert_eq!(ticks, (0..30).collect::<Vec<_>>());
        // A strict reader accepts it, and its summary has the channels and schemas.
        assert_eq!(mcap::MessageStream::new(&fixed).unwrap().count(), 30);
        let summary = mcap::Summary::read(&fixed).unwrap().unwrap();
        assert_eq!(summary.channels.len(), Topic::COUNT);
        let mut names = Vec::new();
        read(fixed.as_slice(), Path::new("fixed.mcap"), |ev| {
            if let Event::Metadata { name, .. } = ev {
                names.push(name.to_owned());
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(names, vec![START_METADATA, RECOVERED_METADATA]);
    }

    #[test]
    fn not_an_mcap_file_is_refused() {
        let e = read(&b"t,q0\n0,1\n"[..], Path::new("x.csv"), |_| Ok(())).unwrap_err();
        assert!(matches!(e, RecordError::NotMcap { .. }), "{e}");
        assert!(e.to_string().starts_with("x.csv: not an MCAP file"), "{e}");
    }

    #[test]
    fn a_full_disk_is_an_error_not_a_panic() {
        let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
            return; // no /dev/full on this system
        };
        let path = Path::new("/dev/full");
        let mut w = LogWriter::new(std::io::BufWriter::new(full), path, None).unwrap();
        w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
        for k in 0..10 {
            w.write(&Payload::RobotState(state(k))).unwrap();
        }
        let e = w.flush().unwrap_err();
        assert!(e.to_string().starts_with("/dev/full: cannot write"), "{e}");
        // Later flushes fail the same way; finishing fails without a panic.
        let _ = w.write(&Payload::RobotState(state(11)));
        assert!(w.flush().is_err());
        assert!(w.finish(None).is_err());
    }

    /// Messages as format 1 wrote them (from a recording of the mock graph made before the
    /// JSON was derived from the message types).
    const V1_STATES: [&str; 2] = [
        r#"{"tick":0,"t_ns":3317184494774,"applied_tick":null,"missed":0,"flags":16,"flag_names":["mock"],"q_rad":[0.0,-0.28,1.309,0.0,-1.047,0.0],"qdot_rad_s":[0.0,0.0,0.0,0.0,0.0,0.0],"gripper":0.0}"#,
        r#"{"tick":1,"t_ns":3317209503637,"applied_tick":0,"missed":0,"flags":16,"flag_names":["mock"],"q_rad":[0.0,-0.28,1.309,0.0,-1.047,0.5],"qdot_rad_s":[0.0,0.0,0.0,0.0,0.0,0.25],"gripper":0.0}"#,
    ];
    const V1_STATUS: &str = r#"{"t_ns":3317022825666,"tick":null,"handled":0,"faults":0,"latency_ns":0,"lateness_ns":0,"joint_travel_rad":0.0,"pid":23402,"role":"recorder","phase":"ready","mapper_id":0,"safety_state":0,"rule_counts":{"acceleration":0,"bad-shape":0,"deadman":0,"e-stop":0,"hold":0,"non-finite":0,"position":0,"stale-command":0,"stale-joystick":0,"stale-state":0,"stop":0,"velocity":0,"workspace":0}}"#;

    /// A finished format-1 recording: its channels have no format key.
    fn v1_recording() -> Vec<u8> {
        let mut w = LogWriter::new(Vec::new(), Path::new("old.mcap"), None).unwrap();
        let schema = |name: &str| SchemaInfo {
            name: name.to_owned(),
            encoding: "jsonschema".to_owned(),
            data: br#"{"type":"object"}"#.to_vec(),
        };
        let meta = BTreeMap::from([("prefix".to_owned(), "old".to_owned())]);
        let states = w
            .add_channel(
                "/robot_state",
                Some(&schema("scl.RobotState")),
                "json",
                &meta,
            )
            .unwrap();
        let status = w
            .add_channel("/status", Some(&schema("scl.NodeStatus")), "json", &meta)
            .unwrap();
        w.write_raw(status, 1, 1, 1, V1_STATUS.as_bytes()).unwrap();
        for (i, m) in V1_STATES.iter().enumerate() {
            w.write_raw(states, i as u32 + 1, 2, 2, m.as_bytes())
                .unwrap();
        }
        w.finish(None).unwrap()
    }

    /// Robot states decoded from `bytes`, and the first error another topic's decode gave.
    fn v1_contents(bytes: &[u8]) -> (Vec<RobotState>, Option<RecordError>) {
        let path = Path::new("old.mcap");
        let (mut states, mut other) = (Vec::new(), None);
        read(bytes, path, |ev| {
            if let Event::Message {
                channel,
                sequence,
                data,
                ..
            } = ev
            {
                if channel.topic == "/robot_state" {
                    states.push(decode_robot_state(path, channel, sequence, data)?);
                } else if other.is_none() {
                    other = decode::<NodeStatus>(path, channel, sequence, data).err();
                }
            }
            Ok(())
        })
        .unwrap();
        (states, other)
    }

    #[test]
    fn recordings_of_format_1_still_read_and_recover() {
        let old = v1_recording();
        let (states, other) = v1_contents(&old);
        assert_eq!(states.len(), 2);
        let s = &states[1];
        assert_eq!(
            (s.tick, s.t_ns, s.applied_tick, s.flags),
            (1, 3317209503637, 0, 16)
        );
        assert_eq!(s.q(), &[0.0, -0.28, 1.309, 0.0, -1.047, 0.5]);
        assert_eq!(s.qdot()[5], 0.25);
        assert_eq!(states[0].applied_tick, NO_TICK);
        // Other topics are refused, naming the file and the format.
        let e = other.unwrap();
        assert!(
            e.to_string()
                .starts_with("old.mcap: channel /status is in recording format 1"),
            "{e}"
        );
        // --recover keeps the channels as they were: the copy reads the same.
        let (report, fixed) = recover_into(
            old.as_slice(),
            Path::new("old.mcap"),
            Vec::new(),
            Path::new("f.mcap"),
        )
        .unwrap();
        assert_eq!(report.messages, 3);
        assert_eq!(v1_contents(&fixed).0, states);
        // A cut-off format-1 robot state is a decode error naming the file, not a panic.
        let bad = br#"{"tick":1,"t_ns":1,"applied_tick":0,"missed":0,"flags":0,"q_rad":[0.0],"qdot_rad_s":[],"gripper":0.0}"#;
        let ch = ChannelInfo {
            id: 1,
            topic: "/robot_state".into(),
            message_encoding: "json".into(),
            metadata: BTreeMap::new(),
            schema: None,
        };
        let e = decode_robot_state(Path::new("old.mcap"), &ch, 7, bad).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("old.mcap: message 7 on /robot_state"),
            "{e}"
        );
    }

    #[test]
    fn new_channels_say_their_format() {
        let (_, bytes) = recording(1, 1, true);
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        for c in summary.channels.values() {
            assert_eq!(c.metadata[FORMAT_KEY], FORMAT.to_string(), "{}", c.topic);
        }
    }

    #[test]
    fn attachments_read_back_and_survive_recovery() {
        let path = Path::new("att.mcap");
        let mut w = LogWriter::new(Vec::new(), path, None).unwrap();
        w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
        w.write(&Payload::RobotState(RobotState::at_rest(1, 10, 6)))
            .unwrap();
        w.attach(
            "model/mapper-1/m.safetensors",
            20,
            "application/octet-stream",
            b"weights",
        )
        .unwrap();
        w.write_metadata(&metadata(PROCESS_METADATA, BTreeMap::new()))
            .unwrap();
        let bytes = w.finish(None).unwrap();
        let collect = |bytes: &[u8]| {
            let mut got = Vec::new();
            read(bytes, path, |ev| {
                if let Event::Attachment {
                    name,
                    log_time,
                    media_type,
                    data,
                } = ev
                {
                    got.push((
                        name.to_owned(),
                        log_time,
                        media_type.to_owned(),
                        data.to_vec(),
                    ));
                }
                Ok(())
            })
            .unwrap();
            got
        };
        let want = vec![(
            "model/mapper-1/m.safetensors".to_owned(),
            20,
            "application/octet-stream".to_owned(),
            b"weights".to_vec(),
        )];
        assert_eq!(collect(&bytes), want);
        let (_, recovered) = recover_into(&bytes[..], path, Vec::new(), path).unwrap();
        assert_eq!(collect(&recovered), want);
    }
}
