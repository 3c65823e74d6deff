//! Corrupt and foreign files through every reader entry point ([`recording::read`],
//! [`recording::read_file`], [`recording::recover_into`], [`recording::recover`]): random
//! bytes after the MCAP magic, and real recordings (zstd chunks as written now, uncompressed
//! chunks as written before) with bytes flipped, length fields changed and tails cut. Each is
//! an error or an early stop naming the byte offset, never a panic or an allocation the file
//! does not justify.
#![allow(clippy::unwrap_used, missing_docs)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use ipc_types::RobotState;
use proptest::prelude::*;
use recording::{Event, LogWriter, Payload, ReadSummary, RecordError, StopCause, Topic};

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// The allocator of this test binary: the system's, counting every allocation larger than
/// anything a reader may justify ([`recording::MAX_CHUNK_BYTES`], a chunk's expansion, plus a
/// margin). The inputs here are kilobytes, so any such allocation came from a length field
/// that was trusted; [`every_reader`] fails on it.
struct Counting;

/// Allocations above [`HUGE_BYTES`] so far, in any test of this binary.
static HUGE: AtomicUsize = AtomicUsize::new(0);
const HUGE_BYTES: usize = (recording::MAX_CHUNK_BYTES as usize) + (1 << 20);

// SAFETY: every call is passed on to `System` unchanged; the counter has no effect on memory.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > HUGE_BYTES {
            HUGE.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: the caller's contract for `alloc` is `System::alloc`'s.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System` with this layout (every allocation above does).
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > HUGE_BYTES {
            HUGE.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: as for `dealloc`, and the caller's contract for `realloc` is `System`'s.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// A finished recording of `n` robot states in chunks of 10, zstd-compressed as the writer
/// makes them now.
fn recording_zstd(n: u64) -> Vec<u8> {
    let mut w = LogWriter::new(Vec::new(), Path::new("mem.mcap"), None).unwrap();
    for t in Topic::ALL {
        w.add_topic(t, &BTreeMap::new()).unwrap();
    }
    w.write_metadata(&recording::metadata("scl.test", BTreeMap::new()))
        .unwrap();
    w.attach("model/x", 1, "application/octet-stream", &[7; 300])
        .unwrap();
    for k in 0..n {
        let s = RobotState::at_rest(k, 1_000 + k * 25_000_000, 6);
        w.write(&Payload::RobotState(s)).unwrap();
        if (k + 1) % 10 == 0 {
            w.flush().unwrap();
        }
    }
    w.finish(None).unwrap()
}

/// The same with uncompressed chunks, as recordings made before zstd were written (by the
/// `mcap` crate directly).
fn recording_plain(n: u64) -> Vec<u8> {
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .chunk_size(Some(2000))
        .create(std::io::Cursor::new(Vec::new()))
        .unwrap();
    let schema = w.add_schema("scl.RobotState", "jsonschema", b"{}").unwrap();
    let ch = w
        .add_channel(schema, "/robot_state", "json", &BTreeMap::new())
        .unwrap();
    for k in 0..n {
        let s = RobotState::at_rest(k, 1_000 + k, 6);
        let json = serde_json::to_vec(&s).unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: k as u32,
                log_time: s.t_ns,
                publish_time: s.t_ns,
            },
            &json,
        )
        .unwrap();
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

/// The start offsets of the top-level records (after the magic, up to the data end).
fn record_offsets(bytes: &[u8]) -> Vec<usize> {
    let mut at = MAGIC.len();
    let mut out = Vec::new();
    while at + 9 <= bytes.len() {
        out.push(at);
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        if op == 0x0F {
            break;
        }
        match usize::try_from(len)
            .ok()
            .and_then(|l| (at + 9).checked_add(l))
        {
            Some(next) => at = next,
            None => break,
        }
    }
    out
}

/// Every entry point on `bytes`; panics if a reader panics or any test of this binary has
/// allocated more than a reader may justify ([`HUGE`]). Returns what [`recording::read`] said.
fn every_reader(bytes: &[u8]) -> Result<ReadSummary, RecordError> {
    let path = Path::new("fuzz.mcap");
    let mut n = 0u64;
    let r = recording::read(bytes, path, |ev| {
        if let Event::Message { data, .. } = ev {
            n += 1;
            let _ = data.len();
        }
        Ok(())
    });
    if let Ok(s) = &r {
        assert_eq!(s.messages, n);
    }
    // One byte at a time: the reader never needs more than the source gives.
    let slow = recording::read(OneByte(bytes), path, |_| Ok(()));
    assert_eq!(slow.is_ok(), r.is_ok(), "{slow:?} / {r:?}");
    let _ = recording::recover_into(bytes, path, Vec::new(), Path::new("out.mcap"));
    assert_eq!(
        HUGE.load(Ordering::Relaxed),
        0,
        "an allocation above {HUGE_BYTES} bytes: a length field was trusted"
    );
    r
}

/// A reader that hands out one byte per call.
struct OneByte<'a>(&'a [u8]);

impl std::io::Read for OneByte<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match (self.0.split_first(), buf.first_mut()) {
            (Some((b, rest)), Some(out)) => {
                *out = *b;
                self.0 = rest;
                Ok(1)
            }
            _ => Ok(0),
        }
    }
}

/// An error names the file; an early stop names a byte offset inside the file.
fn check_names_the_place(bytes: &[u8], r: &Result<ReadSummary, RecordError>) {
    match r {
        Err(e) => assert!(e.to_string().starts_with("fuzz.mcap: "), "{e}"),
        Ok(s) => {
            if let Some(st) = &s.stopped {
                assert!(
                    st.offset <= bytes.len() as u64,
                    "{st} in {} bytes",
                    bytes.len()
                );
                assert!(
                    st.to_string().contains(&format!("byte {}", st.offset)),
                    "{st}"
                );
            } else {
                assert!(s.complete);
            }
        }
    }
}

#[test]
fn the_issue_file_magic_then_garbage_is_refused_naming_the_file() {
    // `(printf '\x89MCAP0\r\n'; head -c 100000 /dev/urandom) > bad.mcap`: an allocation of
    // 7,678,800,631,491,587,527 bytes before the fix. Here the garbage starts with that length.
    let mut bytes = MAGIC.to_vec();
    bytes.push(0x01);
    bytes.extend_from_slice(&7_678_800_631_491_587_527u64.to_le_bytes());
    bytes.extend((0..100_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
    let e = every_reader(&bytes).unwrap_err();
    assert!(matches!(e, RecordError::NotMcap { .. }), "{e}");
    assert!(e.to_string().contains("byte 8"), "{e}");
    // A huge length in the middle of a real recording: an early stop at that record.
    let mut bytes = recording_zstd(50);
    let at = record_offsets(&bytes)[4];
    bytes[at + 1..at + 9].copy_from_slice(&u64::MAX.to_le_bytes());
    let s = every_reader(&bytes).unwrap();
    let st = s.stopped.unwrap();
    assert_eq!(st.offset, at as u64);
    assert!(matches!(st.cause, StopCause::Cut { .. }), "{st}");
}

#[test]
fn a_chunk_that_claims_a_huge_expansion_is_damage_not_an_allocation() {
    let mut bytes = recording_zstd(30);
    let chunk = *record_offsets(&bytes)
        .iter()
        .find(|&&at| bytes[at] == 0x06)
        .unwrap();
    // uncompressed_size: after opcode, length, start and end times.
    let f = chunk + 9 + 16;
    bytes[f..f + 8].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    let s = every_reader(&bytes).unwrap();
    let st = s.stopped.unwrap();
    assert_eq!(st.offset, chunk as u64);
    assert!(matches!(st.cause, StopCause::Damaged(_)), "{st}");
}

/// The fuzz target's first find (`recording/fuzz/regressions/`): a Header record of 5 bytes
/// whose profile string says 0xa0000000 bytes. The mcap crate reserved the 2.68 GB before
/// reading; now the file is refused, naming the record and the field.
#[test]
fn the_fuzzers_header_with_a_huge_string_length_is_damage_not_an_allocation() {
    let input = include_bytes!("../fuzz/regressions/oom-207e5fbb83e862d520c291b6084ff001b95c053b");
    // The fuzz target puts the magic in front when the first byte's top bit is clear.
    assert_eq!(input[0] & 0x80, 0);
    let mut bytes = MAGIC.to_vec();
    bytes.extend_from_slice(&input[1..]);
    // A header that cannot be read: not an MCAP file, and the error says why.
    match every_reader(&bytes) {
        Err(RecordError::NotMcap { reason, .. }) => {
            assert!(reason.contains("a string at byte 4"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
}

/// A `uint32`-prefixed string.
fn mcap_string(s: &str) -> Vec<u8> {
    let mut v = (s.len() as u32).to_le_bytes().to_vec();
    v.extend_from_slice(s.as_bytes());
    v
}

/// A record: opcode, `uint64` length, body.
fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
    let mut v = vec![opcode];
    v.extend_from_slice(&(body.len() as u64).to_le_bytes());
    v.extend_from_slice(body);
    v
}

/// A file: the magic, a header, then `rest`.
fn file_with(rest: &[u8]) -> Vec<u8> {
    let mut header = mcap_string("");
    header.extend(mcap_string("test"));
    let mut bytes = MAGIC.to_vec();
    bytes.extend(record(0x01, &header));
    bytes.extend_from_slice(rest);
    bytes
}

/// An uncompressed chunk holding `records` (CRC 0: not checked).
fn chunk_of(records: &[u8]) -> Vec<u8> {
    let mut body = vec![0; 16];
    body.extend_from_slice(&(records.len() as u64).to_le_bytes());
    body.extend_from_slice(&0u32.to_le_bytes());
    body.extend(mcap_string(""));
    body.extend_from_slice(&(records.len() as u64).to_le_bytes());
    body.extend_from_slice(records);
    record(0x06, &body)
}

#[test]
fn the_files_as_written_read_whole() {
    for bytes in [recording_zstd(100), recording_plain(100)] {
        let s = every_reader(&bytes).unwrap();
        assert!(s.complete, "{s:?}");
        assert_eq!(s.messages, 100);
    }
}

#[test]
fn read_file_and_recover_name_the_file() {
    let dir = std::env::temp_dir().join(format!("scl-corrupt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.mcap");
    let mut bytes = MAGIC.to_vec();
    bytes.extend([0xAB; 64]);
    std::fs::write(&bad, &bytes).unwrap();
    let e = recording::read_file(&bad, |_| Ok(())).unwrap_err();
    assert!(
        e.to_string().starts_with(&format!("{}: ", bad.display())),
        "{e}"
    );
    let out = dir.join("fixed.mcap");
    let e = recording::recover(&bad, &out).unwrap_err();
    assert!(e.to_string().contains("bad.mcap"), "{e}");
    assert!(!out.exists(), "no half-written output");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A mutation of a real recording.
#[derive(Debug, Clone)]
enum Mutation {
    /// XOR the byte at (position modulo the length) with a non-zero value.
    Flip(usize, u8),
    /// Set the length field of a top-level record (index modulo their number).
    Length(usize, u64),
    /// Overwrite 8 bytes at a position with a value (a field of a record header).
    Field(usize, u64),
    /// Cut the file at a position.
    Cut(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let len = prop_oneof![
        any::<u64>(),
        0u64..64,
        Just(u64::MAX),
        (1u64 << 30)..(1u64 << 40),
    ];
    prop_oneof![
        (any::<usize>(), 1u8..=255).prop_map(|(a, b)| Mutation::Flip(a, b)),
        (any::<usize>(), len.clone()).prop_map(|(a, b)| Mutation::Length(a, b)),
        (any::<usize>(), len).prop_map(|(a, b)| Mutation::Field(a, b)),
        any::<usize>().prop_map(Mutation::Cut),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let n = bytes.len();
    match *m {
        Mutation::Flip(at, x) => bytes[at % n] ^= x,
        Mutation::Length(i, v) => {
            let offs = record_offsets(bytes);
            let at = offs[i % offs.len()];
            bytes[at + 1..at + 9].copy_from_slice(&v.to_le_bytes());
        }
        Mutation::Field(at, v) => {
            let at = at % (n - 8);
            bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
        }
        Mutation::Cut(at) => bytes.truncate(at % n),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_after_the_magic_are_an_error_never_a_panic(
        tail in proptest::collection::vec(any::<u8>(), 0..2048),
        head in proptest::option::of((0u8..=0x10, any::<u64>())),
    ) {
        let mut bytes = MAGIC.to_vec();
        if let Some((op, len)) = head {
            bytes.push(op);
            bytes.extend_from_slice(&len.to_le_bytes());
        }
        bytes.extend(tail);
        let r = every_reader(&bytes);
        check_names_the_place(&bytes, &r);
        prop_assert!(!r.as_ref().is_ok_and(|s| s.complete));
    }

    /// Any record the mcap crate parses field by field (top level, and inside a chunk), its
    /// body small random bytes with a large length written somewhere: read without allocating
    /// what the length says.
    #[test]
    fn records_whose_length_fields_lie_are_read_without_trusting_them(
        opcode in 0x01u8..=0x0f,
        mut body in proptest::collection::vec(any::<u8>(), 0..96),
        lie in (any::<usize>(), 0x0100_0000u64..=u64::MAX, any::<bool>()),
        in_chunk in any::<bool>(),
    ) {
        let (at, big, wide) = lie;
        let width = if wide { 8 } else { 4 };
        if body.len() >= width {
            let at = at % (body.len() - width + 1);
            body[at..at + width].copy_from_slice(&big.to_le_bytes()[..width]);
        }
        let rec = record(opcode, &body);
        let bytes = if in_chunk { file_with(&chunk_of(&rec)) } else { file_with(&rec) };
        let r = every_reader(&bytes);
        check_names_the_place(&bytes, &r);
    }

    #[test]
    fn mutated_recordings_are_an_error_or_an_early_stop_never_a_panic(
        zstd in any::<bool>(),
        ms in proptest::collection::vec(mutation(), 1..4),
    ) {
        let mut bytes = if zstd { recording_zstd(40) } else { recording_plain(40) };
        for m in &ms {
            if bytes.len() > 16 {
                apply(&mut bytes, m);
            }
        }
        let r = every_reader(&bytes);
        check_names_the_place(&bytes, &r);
    }
}
