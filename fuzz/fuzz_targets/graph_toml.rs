//! Any text as a graph TOML: parsed, validated, or an error naming the file; never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let p = std::path::Path::new("fuzz.toml");
    match scl_config::GraphConfig::parse(text, p) {
        Ok(cfg) => {
            if let Err(e) = cfg.validate_file(Some(p)) {
                assert!(e.to_string().contains("fuzz.toml"), "{e}");
            }
        }
        Err(e) => assert!(e.to_string().contains("fuzz.toml"), "{e}"),
    }
});
