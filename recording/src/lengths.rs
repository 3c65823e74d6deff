//! The length fields inside a record's body, checked against the body before the mcap crate
//! parses it.
//!
//! The mcap crate (0.26) reads a string field by reserving its stated length first: a 5-byte
//! Header record whose profile says 0xa0000000 bytes made it reserve 2.68 GB (found by the
//! fuzz target `recording/fuzz`, kept in `recording/fuzz/regressions/`). Its Attachment parser
//! also slices the body at `len - 4` before it knows the body holds the CRC. So every length
//! prefix of the records it parses with `binrw` (strings, the string and integer maps, the
//! attachment's data) is walked here first, by the layouts of the MCAP specification
//! (<https://mcap.dev/spec>), and a length past the body's end is damage: the reader stops
//! there without asking for the memory.

use mcap::records::op;

/// One field of a record's layout, in file order.
#[derive(Clone, Copy)]
enum Field {
    /// A fixed-size integer of this many bytes.
    Fixed(usize),
    /// `uint32` length, then that many bytes of UTF-8.
    Str,
    /// `uint32` length in bytes, then (string, string) pairs filling it.
    StrMap,
    /// `uint32` length in bytes, then fixed-size entries filling it.
    Entries,
    /// `uint64` length, then that many bytes, then a `uint32` CRC ending the record.
    AttachmentData,
    /// The rest of the body, whatever it holds (the crate checks these itself).
    Rest,
}

use Field::{AttachmentData, Entries, Fixed, Rest, Str, StrMap};

/// The layout of the records the crate parses field by field (`None`: nothing inside is
/// allocated from a stated length, or the opcode is not one the crate parses).
fn layout(opcode: u8) -> Option<&'static [Field]> {
    Some(match opcode {
        op::HEADER => &[Str, Str],
        op::SCHEMA => &[Fixed(2), Str, Str, Rest],
        op::CHANNEL => &[Fixed(2), Fixed(2), Str, Str, StrMap],
        op::CHUNK => &[Fixed(8), Fixed(8), Fixed(8), Fixed(4), Str, Rest],
        op::MESSAGE_INDEX => &[Fixed(2), Entries],
        op::CHUNK_INDEX => &[
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Fixed(8),
            Entries,
            Fixed(8),
            Str,
            Fixed(8),
            Fixed(8),
        ],
        op::ATTACHMENT => &[Fixed(8), Fixed(8), Str, Str, AttachmentData],
        op::ATTACHMENT_INDEX => &[Fixed(8), Fixed(8), Fixed(8), Fixed(8), Fixed(8), Str, Str],
        op::STATISTICS => &[
            Fixed(8),
            Fixed(2),
            Fixed(4),
            Fixed(4),
            Fixed(4),
            Fixed(4),
            Fixed(8),
            Fixed(8),
            Entries,
        ],
        op::METADATA => &[Str, StrMap],
        op::METADATA_INDEX => &[Fixed(8), Fixed(8), Str],
        _ => return None,
    })
}

/// Why a record's body cannot hold what its length fields say.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "record {opcode:#04x}: {what} at byte {at} of its {body}-byte body says {stated} bytes, {left} are left"
)]
pub struct LengthError {
    /// The record's opcode.
    pub opcode: u8,
    /// The field (`a string`, `a map`, ...).
    pub what: &'static str,
    /// Where in the body the field starts.
    pub at: usize,
    /// The body's length.
    pub body: usize,
    /// The length the field states (or, for a field cut short, its own size).
    pub stated: u64,
    /// The bytes left in the body (or the map) where it starts.
    pub left: usize,
}

/// A cursor over `body` that checks each read against the bytes left.
struct Cursor<'a> {
    opcode: u8,
    body: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn error(&self, what: &'static str, stated: u64, end: usize) -> LengthError {
        LengthError {
            opcode: self.opcode,
            what,
            at: self.at,
            body: self.body.len(),
            stated,
            left: end.saturating_sub(self.at),
        }
    }

    /// Skips `n` bytes that must end by `end`.
    fn skip(&mut self, what: &'static str, n: u64, end: usize) -> Result<(), LengthError> {
        match usize::try_from(n).ok().and_then(|n| self.at.checked_add(n)) {
            Some(next) if next <= end => {
                self.at = next;
                Ok(())
            }
            _ => Err(self.error(what, n, end)),
        }
    }

    /// A little-endian length of `N` bytes, ending by `end`.
    fn length<const N: usize>(
        &mut self,
        what: &'static str,
        end: usize,
    ) -> Result<u64, LengthError> {
        let start = self.at;
        self.skip(what, N as u64, end)?;
        let mut b = [0u8; 8];
        b[..N].copy_from_slice(&self.body[start..self.at]);
        Ok(u64::from_le_bytes(b))
    }

    /// A `uint32`-prefixed string ending by `end`.
    fn string(&mut self, end: usize) -> Result<(), LengthError> {
        let n = self.length::<4>("a string's length", end)?;
        self.skip("a string", n, end)
    }

    /// A `uint32` byte length and the region it states; returns the region's end.
    fn region(&mut self, what: &'static str, end: usize) -> Result<usize, LengthError> {
        let n = self.length::<4>(what, end)?;
        self.skip(what, n, end)?;
        Ok(self.at)
    }
}

/// Checks every length prefix of a record's body against the body (see the module's
/// documentation); `Ok` for records the crate does not parse field by field.
pub fn check(opcode: u8, body: &[u8]) -> Result<(), LengthError> {
    let Some(fields) = layout(opcode) else {
        return Ok(());
    };
    let end = body.len();
    let mut c = Cursor {
        opcode,
        body,
        at: 0,
    };
    for field in fields {
        match *field {
            Fixed(n) => c.skip("a fixed field", n as u64, end)?,
            Str => c.string(end)?,
            StrMap => {
                let start = c.at + 4;
                let map_end = c.region("a map", end)?;
                c.at = start;
                // The crate reads pairs while it is inside the map; each string must end
                // inside the map too.
                while c.at < map_end {
                    c.string(map_end)?;
                    c.string(map_end)?;
                }
            }
            Entries => {
                c.region("a list", end)?;
            }
            AttachmentData => {
                let n = c.length::<8>("the attachment's length", end)?;
                c.skip("the attachment's data and CRC", n.saturating_add(4), end)?;
            }
            Rest => return Ok(()),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &str) -> Vec<u8> {
        let mut v = (s.len() as u32).to_le_bytes().to_vec();
        v.extend_from_slice(s.as_bytes());
        v
    }

    #[test]
    fn the_fuzzers_header_is_refused_naming_the_string() {
        // The body of `recording/fuzz/regressions/oom-207e5f...`: 5 bytes, a string of
        // 0xa0000000.
        let e = check(op::HEADER, &[0, 0, 0, 0xa0, 0]).unwrap_err();
        assert_eq!(
            (e.what, e.at, e.stated, e.left),
            ("a string", 4, 0xa000_0000, 1)
        );
        assert!(
            e.to_string().contains("2684354560 bytes, 1 are left"),
            "{e}"
        );
    }

    #[test]
    fn records_the_writer_makes_pass() {
        let mut header = string("scl");
        header.extend(string("scl 0.1"));
        assert_eq!(check(op::HEADER, &header), Ok(()));
        let mut meta = string("scl.recording");
        let mut map = string("k");
        map.extend(string("value"));
        meta.extend((map.len() as u32).to_le_bytes());
        meta.extend(&map);
        assert_eq!(check(op::METADATA, &meta), Ok(()));
        let mut att = vec![0; 16];
        att.extend(string("model.json"));
        att.extend(string("application/json"));
        att.extend(3u64.to_le_bytes());
        att.extend(b"abc");
        att.extend(0u32.to_le_bytes());
        assert_eq!(check(op::ATTACHMENT, &att), Ok(()));
        // A message's data is the rest of the body: nothing to check.
        assert_eq!(check(op::MESSAGE, &[1, 2, 3]), Ok(()));
    }

    #[test]
    fn a_string_inside_a_map_must_end_inside_the_map() {
        let mut meta = string("m");
        let mut map = string("k");
        map.extend(string("v"));
        // The map says 6 bytes: the key, and the value's length cut.
        meta.extend(6u32.to_le_bytes());
        meta.extend(&map);
        let e = check(op::METADATA, &meta).unwrap_err();
        assert_eq!(e.what, "a string's length");
    }

    #[test]
    fn an_attachment_without_room_for_its_crc_is_refused() {
        let mut att = vec![0; 16];
        att.extend(string("a"));
        att.extend(string("b"));
        att.extend(3u64.to_le_bytes());
        att.extend(b"abc");
        let e = check(op::ATTACHMENT, &att).unwrap_err();
        assert_eq!(e.what, "the attachment's data and CRC");
        let cut = check(op::ATTACHMENT, &att[..att.len() - 5]).unwrap_err();
        assert_eq!(cut.what, "the attachment's length");
    }
}
