//! Any bytes as a model file: a model or an error naming the file, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = std::path::Path::new("fuzz.safetensors");
    if let Err(e) = mapper::model::LoadedModel::from_bytes(data, p) {
        assert!(e.to_string().contains("fuzz.safetensors"), "{e}");
    }
});
