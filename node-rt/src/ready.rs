//! How a child process tells the process that started it whether it is ready: one line on its
//! standard output, [`READY`] and what it serves (e.g. the address a server listens on), or
//! [`FAILED`] and why it could not start. `scl up --live` starts `scl live --announce` with its
//! standard output on a pipe and waits for that line, so it knows that *its own* server
//! listens (not another program on the same port) and, when the server could not start, why.
//!
//! ```
//! use node_rt::ready::{Announcement, parse};
//!
//! assert_eq!(
//!     parse("scl-ready 127.0.0.1:8765"),
//!     Some(Announcement::Ready("127.0.0.1:8765".into()))
//! );
//! assert_eq!(parse("something else"), None);
//! ```

use std::io::Write;

/// The first word of the line a ready child prints.
pub const READY: &str = "scl-ready";
/// The first word of the line a child that could not start prints.
pub const FAILED: &str = "scl-failed";

/// What a child announced.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Announcement {
    /// It is ready; what it serves.
    Ready(String),
    /// It could not start; why.
    Failed(String),
}

/// The announcement `line` carries, if it is one.
pub fn parse(line: &str) -> Option<Announcement> {
    let line = line.trim_end();
    let (word, rest) = line.split_once(' ').unwrap_or((line, ""));
    match word {
        READY => Some(Announcement::Ready(rest.to_owned())),
        FAILED => Some(Announcement::Failed(rest.to_owned())),
        _ => None,
    }
}

/// The line announcing `a` (one line: line breaks in the text become spaces).
pub fn line(a: &Announcement) -> String {
    let (word, text) = match a {
        Announcement::Ready(t) => (READY, t),
        Announcement::Failed(t) => (FAILED, t),
    };
    format!("{word} {}", text.replace(['\n', '\r'], " "))
}

/// Prints `a` on standard output and flushes it. A parent that stopped reading is not an
/// error here: the announcement is for it alone.
pub fn announce(a: &Announcement) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{}", line(a));
    let _ = out.flush();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn announcements_read_back_as_written_on_one_line() {
        for a in [
            Announcement::Ready("[::1]:40000".into()),
            Announcement::Failed("cannot serve on 127.0.0.1:1: address in use".into()),
        ] {
            assert_eq!(parse(&line(&a)), Some(a));
        }
        let multi = line(&Announcement::Failed("a\nb".into()));
        assert_eq!(multi, "scl-failed a b");
        assert_eq!(parse("scl-live: something"), None);
        assert_eq!(parse(""), None);
    }
}
