//! Any bytes as either credentials file: the network's `user:password` lines and the Kortex
//! TOML; read, or an error naming the file, never a panic and never the secret in the error.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../net/src/credentials.rs"]
#[allow(dead_code)]
mod credentials;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let p = std::path::Path::new("fuzz.creds");
    match credentials::Credentials::parse(p, text) {
        Ok(c) => assert!(!c.logins.is_empty()),
        Err(e) => assert!(e.to_string().contains("fuzz.creds"), "{e}"),
    }
    if let Err(e) = scl_config::secret::parse_kortex_credentials(text, p) {
        // The fixed message, with at most a line number: never the parser's, which would
        // quote the line (and a password on it).
        let msg = e.to_string();
        assert!(msg.starts_with("credentials file fuzz.creds"), "{msg}");
        assert!(
            msg.ends_with("expected `username = \"...\"` and `password = \"...\"` (TOML strings) and nothing else"),
            "{msg}"
        );
    }
});
