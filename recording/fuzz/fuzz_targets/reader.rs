//! Arbitrary bytes (after the MCAP magic, most of the time) into the recording reader, as
//! `scl replay`, `scl dataset` and `scl record --recover` read a file: whole, and in reads of
//! 1..64 bytes. It must never panic or allocate what the file does not hold; a read that
//! succeeds counts every message it handed out, and an early stop names an offset inside the
//! input.
#![no_main]

use std::io::Read;
use std::path::Path;

use libfuzzer_sys::fuzz_target;

/// Hands out at most `n` bytes per read.
struct Chunked<'a>(&'a [u8], usize);

impl Read for Chunked<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.0.len().min(buf.len()).min(self.1);
        buf[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        Ok(n)
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((first, rest)) = data.split_first() else {
        return;
    };
    // Mostly a file that passes the magic check, so the fuzzer explores the records.
    let mut bytes = Vec::with_capacity(rest.len() + 8);
    if first & 0x80 == 0 {
        bytes.extend_from_slice(b"\x89MCAP0\r\n");
    }
    bytes.extend_from_slice(rest);
    let path = Path::new("fuzz.mcap");
    let mut messages = 0u64;
    let whole = recording::read(bytes.as_slice(), path, |ev| {
        if let recording::Event::Message { .. } = ev {
            messages += 1;
        }
        Ok(())
    });
    if let Ok(s) = &whole {
        assert_eq!(s.messages, messages);
        if let Some(st) = &s.stopped {
            assert!(st.offset <= bytes.len() as u64);
        }
    }
    let step = usize::from(*first % 64) + 1;
    let chunked = recording::read(Chunked(&bytes, step), path, |_| Ok(()));
    assert_eq!(whole.is_ok(), chunked.is_ok());
    let _ = recording::recover_into(bytes.as_slice(), path, Vec::new(), Path::new("out.mcap"));
});
