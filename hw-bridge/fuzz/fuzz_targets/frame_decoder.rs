//! Arbitrary bytes, cut into arbitrary chunks, into the Kortex frame decoder: it must never
//! panic, always make progress, hold at most one frame's worth, and every frame it returns must
//! survive an encode / decode round trip.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../src/kortex/wire.rs"]
#[allow(dead_code)]
mod wire;

use wire::{Decoded, FrameDecoder, MAX_FRAME_LEN, PREFIX_LEN};

fuzz_target!(|data: &[u8]| {
    let Some((first, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(*first % 64) + 1;
    let mut d = FrameDecoder::new();
    for c in bytes.chunks(chunk) {
        d.push(c);
        let before = d.buffered();
        let mut steps = 0;
        while let Some(r) = d.next_frame() {
            steps += 1;
            assert!(steps <= before + 1, "no progress");
            match r {
                Ok(Decoded::Frame(f)) => {
                    let h = f.header();
                    let _ = (h.frame_type(), h.message_id(), h.function_uid(), f.error());
                    let mut out = Vec::new();
                    if f.encode_tcp(&mut out).is_ok() {
                        let mut again = FrameDecoder::new();
                        again.push(&out);
                        match again.next_frame() {
                            Some(Ok(Decoded::Frame(g))) => assert_eq!(f, g),
                            other => panic!("re-encoded frame does not decode: {other:?}"),
                        }
                    }
                }
                Ok(Decoded::Skipped(n)) => assert!(n > 0),
                Err(_) => {}
            }
        }
        assert!(d.buffered() < PREFIX_LEN + MAX_FRAME_LEN);
    }
    let _ = d.truncated();
});
