//! The graph prefix: one name that isolates one graph's services and shared-memory files from
//! every other graph on the machine (tests run each graph under its own prefix).

use std::fmt;

/// Environment variable that sets the prefix when no `--prefix` flag is given.
pub const PREFIX_ENV: &str = "SCL_PREFIX";

/// The prefix used when neither the flag nor [`PREFIX_ENV`] is set.
pub const DEFAULT_PREFIX: &str = "scl";

/// Longest accepted prefix. Shared-memory file names are limited in length, and the prefix is
/// part of every one of them.
pub const MAX_PREFIX_LEN: usize = 32;

/// A validated graph prefix: 1 to [`MAX_PREFIX_LEN`] characters of `[A-Za-z0-9_-]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Prefix(String);

/// Why a prefix was refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum PrefixError {
    /// The prefix was empty.
    #[error("the graph prefix is empty; give a name such as `scl` or `lab2`")]
    Empty,
    /// The prefix was longer than [`MAX_PREFIX_LEN`].
    #[error("the graph prefix `{0}` is longer than {MAX_PREFIX_LEN} characters")]
    TooLong(String),
    /// The prefix had a character outside `[A-Za-z0-9_-]`.
    #[error(
        "the graph prefix `{0}` has the character {1:?}; use only letters, digits, `_` and `-`"
    )]
    BadChar(String, char),
}

impl Prefix {
    /// Validates `s` as a prefix.
    pub fn new(s: &str) -> Result<Self, PrefixError> {
        if s.is_empty() {
            return Err(PrefixError::Empty);
        }
        if s.len() > MAX_PREFIX_LEN {
            return Err(PrefixError::TooLong(s.to_owned()));
        }
        if let Some(c) = s
            .chars()
            .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
        {
            return Err(PrefixError::BadChar(s.to_owned(), c));
        }
        Ok(Self(s.to_owned()))
    }

    /// The prefix as given.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The full service name of `topic` in this graph, e.g. `lab2/robot_state`.
    pub fn service(&self, topic: &str) -> String {
        format!("{}/{}", self.0, topic)
    }

    /// The file-name prefix of every shared-memory and lock file of this graph, so that
    /// `ls /dev/shm | grep scl_lab2_` shows exactly this graph's resources.
    pub fn file_prefix(&self) -> String {
        format!("scl_{}_", self.0)
    }
}

impl Default for Prefix {
    fn default() -> Self {
        Self(DEFAULT_PREFIX.to_owned())
    }
}

impl fmt::Display for Prefix {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::str::FromStr for Prefix {
    type Err = PrefixError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::new(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_and_names() {
        let p = Prefix::new("lab-2_a").unwrap();
        assert_eq!(p.service("robot_state"), "lab-2_a/robot_state");
        assert_eq!(p.file_prefix(), "scl_lab-2_a_");
    }

    #[test]
    fn refuses_bad_prefixes() {
        assert_eq!(Prefix::new(""), Err(PrefixError::Empty));
        assert!(matches!(
            Prefix::new("a/b"),
            Err(PrefixError::BadChar(_, '/'))
        ));
        assert!(matches!(
            Prefix::new(&"x".repeat(33)),
            Err(PrefixError::TooLong(_))
        ));
    }
}
