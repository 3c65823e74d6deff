//! Any text as a graph TOML or a Kortex credentials file: read, or an error naming the file
//! (and, for credentials, never quoting the secret); never a panic. The `graph_toml` and
//! `credentials` fuzz targets' rules (`fuzz/`), on stable with every `cargo test`, on
//! arbitrary text and on the example graph damaged a line at a time.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::Path;

use proptest::prelude::*;
use scl_config::GraphConfig;

/// The example graph the README starts from.
fn example() -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/graph.toml");
    std::fs::read_to_string(p).unwrap()
}

/// Parses and validates `text` as `prop.toml`: whatever it says of it must name the file.
fn check_graph(text: &str) -> Result<(), TestCaseError> {
    let p = Path::new("prop.toml");
    let msg = match GraphConfig::parse(text, p) {
        Ok(cfg) => match cfg.validate_file(Some(p)) {
            Ok(()) => return Ok(()),
            Err(e) => e.to_string(),
        },
        Err(e) => e.to_string(),
    };
    prop_assert!(msg.contains("prop.toml"), "{}", msg);
    Ok(())
}

/// A line a person might type into a graph file: a table, a key with a value of some kind,
/// or noise.
fn a_line() -> impl Strategy<Value = String> {
    prop_oneof![
        "\\[[a-z_.]{1,16}\\]",
        (
            "[a-z_]{1,16}",
            prop_oneof![
                any::<f64>().prop_map(|v| v.to_string()),
                any::<i64>().prop_map(|v| v.to_string()),
                "\"[ -~]{0,16}\"",
                Just("true".to_owned()),
                "\\[[0-9., -]{0,24}\\]",
            ]
        )
            .prop_map(|(k, v)| format!("{k} = {v}")),
        ".{0,40}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn any_text_is_a_graph_or_an_error_naming_the_file(text in ".{0,200}") {
        check_graph(&text)?;
    }

    /// The example graph with one line replaced, one inserted, or a value changed.
    #[test]
    fn a_damaged_example_graph_is_a_graph_or_an_error_naming_the_file(
        at in any::<prop::sample::Index>(),
        line in a_line(),
        how in 0u8..3,
    ) {
        let text = example();
        let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
        let i = at.index(lines.len());
        match how {
            0 => lines[i] = line,
            1 => lines.insert(i, line),
            _ => {
                if let Some((k, _)) = lines[i].split_once('=') {
                    let value = line.split_once('=').map_or(line.as_str(), |(_, v)| v);
                    lines[i] = format!("{k}={value}");
                }
            }
        }
        check_graph(&lines.join("\n"))?;
    }

    /// A Kortex credentials file with a line damaged: read, or the fixed message naming the
    /// file with at most a line number, never the password.
    #[test]
    fn a_damaged_kortex_credentials_file_never_quotes_the_secret(
        secret in "[A-Za-z0-9]{8,16}",
        line in a_line(),
        where_ in 0usize..3,
    ) {
        let mut lines = vec![
            "username = \"admin\"".to_owned(),
            format!("password = \"{secret}\""),
        ];
        lines.insert(where_.min(lines.len()), format!("{line} {secret}"));
        let p = Path::new("prop.creds");
        if let Err(e) = scl_config::secret::parse_kortex_credentials(&lines.join("\n"), p) {
            let msg = e.to_string();
            prop_assert!(msg.starts_with("credentials file prop.creds"), "{}", msg);
            prop_assert!(!msg.contains(&secret), "{} quotes the secret", msg);
        }
    }
}
