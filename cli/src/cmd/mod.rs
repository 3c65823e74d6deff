//! The subcommands of `scl` that are implemented here, one module each, their options beside
//! their implementation; the processes and tools themselves are the service crates'.

use std::process::ExitCode;
use std::time::Duration;

use scl::SclError;

pub(crate) mod bench;
pub(crate) mod control;
pub(crate) mod learn;
pub(crate) mod nodes;
pub(crate) mod up;

/// A duration on the command line: `60s`, `2m`, `500ms`, `1h`, or seconds without a unit.
pub(crate) fn parse_duration(s: &str) -> Result<Duration, String> {
    let s = s.trim();
    if s.starts_with('-') {
        return Err(format!(
            "`{s}` is negative; a duration must be positive, e.g. 60s, 2m or 500ms"
        ));
    }
    let (num, unit) = s
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map_or((s, "s"), |i| (&s[..i], &s[i..]));
    let v: f64 = num
        .parse()
        .map_err(|_| format!("`{s}` is not a duration; write e.g. 60s, 2m or 500ms"))?;
    let secs = match unit {
        "ms" => v / 1000.0,
        "s" => v,
        "m" | "min" => v * 60.0,
        "h" => v * 3600.0,
        _ => return Err(format!("unknown unit `{unit}` in `{s}`; use ms, s, m or h")),
    };
    if !(secs.is_finite() && secs > 0.0) {
        return Err(format!("`{s}` must be a positive duration"));
    }
    Ok(Duration::from_secs_f64(secs))
}

/// `scl layout`: the messages' memory layout as JSON on stdout.
pub(crate) fn layout() -> Result<ExitCode, SclError> {
    let text = serde_json::to_string_pretty(&ipc_types::layout::describe()).map_err(|source| {
        SclError::Encode {
            what: "layout",
            source,
        }
    })?;
    println!("{text}");
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations() {
        assert_eq!(parse_duration("60s"), Ok(Duration::from_secs(60)));
        assert_eq!(parse_duration("2m"), Ok(Duration::from_secs(120)));
        assert_eq!(parse_duration("500ms"), Ok(Duration::from_millis(500)));
        assert_eq!(parse_duration("5"), Ok(Duration::from_secs(5)));
        assert!(parse_duration("5 parsecs").is_err());
        let e = parse_duration("-1s").err().unwrap_or_default();
        assert!(e.contains("`-1s` is negative"), "{e}");
        assert!(parse_duration("0s").is_err());
    }
}
