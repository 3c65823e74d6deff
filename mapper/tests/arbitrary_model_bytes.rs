//! Any bytes as a model file: a model or an error naming the file, never a panic. The
//! `model_file` fuzz target's rule (`fuzz/`), on stable with every `cargo test`: on arbitrary
//! bytes, and on the bundled model damaged (a byte changed, in its header or its weights; cut
//! short; its header's length rewritten).
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::Path;

use mapper::model::LoadedModel;
use proptest::prelude::*;

fn bundled() -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/default.safetensors"))
        .unwrap()
}

fn check(bytes: &[u8]) -> Result<(), TestCaseError> {
    if let Err(e) = LoadedModel::from_bytes(bytes, Path::new("prop.safetensors")) {
        let msg = e.to_string();
        prop_assert!(msg.contains("prop.safetensors"), "{}", msg);
    }
    Ok(())
}

#[test]
fn the_bundled_model_reads() {
    LoadedModel::from_bytes(&bundled(), Path::new("default.safetensors")).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn any_bytes_are_a_model_or_an_error_naming_the_file(
        bytes in prop::collection::vec(any::<u8>(), 0..512),
        header_len in prop::option::of(any::<u64>()),
    ) {
        // With a plausible or absurd header length first, as safetensors begins.
        let mut b = header_len.map(|n| n.to_le_bytes().to_vec()).unwrap_or_default();
        b.extend(bytes);
        check(&b)?;
    }

    #[test]
    fn a_damaged_bundled_model_is_a_model_or_an_error_naming_the_file(
        in_header in any::<prop::sample::Index>(),
        anywhere in any::<prop::sample::Index>(),
        byte in any::<u8>(),
        cut in any::<prop::sample::Index>(),
        header_len in any::<u64>(),
    ) {
        let good = bundled();
        let n = u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
        let mut b = good.clone();
        b[8 + in_header.index(n)] = byte;
        check(&b)?;
        let mut b = good.clone();
        b[anywhere.index(good.len())] = byte;
        check(&b)?;
        check(&good[..cut.index(good.len())])?;
        let mut b = good;
        b[..8].copy_from_slice(&header_len.to_le_bytes());
        check(&b)?;
    }
}
