//! Credentials for Zenoh's user/password authentication: a file of `user:password` lines
//! (blank lines skipped, no comments: Zenoh reads the same file as its dictionary) that only
//! its owner may read (mode 0600 or 0400; anything else is refused, naming the mode: the rule
//! of every credentials file, `scl_config::secret`). The gateway accepts the peers it lists and
//! names itself with the first line; a remote operator names itself with the first line.
//! Never on the command line, never in a log (`Debug` hides the passwords).

use std::path::{Path, PathBuf};

/// One `user:password` pair.
#[derive(Clone, PartialEq, Eq)]
pub struct Login {
    /// The user name.
    pub user: String,
    /// The password.
    pub password: String,
}

impl std::fmt::Debug for Login {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Login")
            .field("user", &self.user)
            .field("password", &"<hidden>")
            .finish()
    }
}

/// A credentials file, read and checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Credentials {
    /// The file (Zenoh reads it again as its dictionary).
    pub path: PathBuf,
    /// Its logins, in order; at least one.
    pub logins: Vec<Login>,
}

/// Why a credentials file was refused.
#[derive(Debug, thiserror::Error)]
pub enum CredentialsError {
    /// It could not be read, or others than its owner may read or change it (the one rule of
    /// the graph's credentials files, `scl_config::secret`).
    #[error(transparent)]
    File(#[from] scl_config::secret::SecretFileError),
    /// A line is not `user:password`.
    #[error("credentials file {path}, line {line}: {reason}")]
    Line {
        /// The file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// What is wrong.
        reason: &'static str,
    },
    /// No login at all.
    #[error("credentials file {path} holds no `user:password` line")]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

impl Credentials {
    /// Reads and checks `path`.
    pub fn load(path: &Path) -> Result<Self, CredentialsError> {
        let text = scl_config::secret::read_owner_only(path)?;
        Self::parse(path, &text)
    }

    /// Parses the text of the file `path` (its mode checked by the caller).
    pub(crate) fn parse(path: &Path, text: &str) -> Result<Self, CredentialsError> {
        let mut logins = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            let bad = |reason| CredentialsError::Line {
                path: path.to_owned(),
                line: i + 1,
                reason,
            };
            let (user, password) = line
                .split_once(':')
                .ok_or_else(|| bad("is not `user:password`"))?;
            let (user, password) = (user.trim(), password.trim());
            if user.is_empty() || password.is_empty() {
                return Err(bad("has an empty user or password"));
            }
            if user.contains(char::is_whitespace) {
                return Err(bad("has white space in the user name"));
            }
            logins.push(Login {
                user: user.to_owned(),
                password: password.to_owned(),
            });
        }
        if logins.is_empty() {
            return Err(CredentialsError::Empty {
                path: path.to_owned(),
            });
        }
        Ok(Self {
            path: path.to_owned(),
            logins,
        })
    }

    /// The login this side presents: the first line's.
    pub fn own(&self) -> &Login {
        &self.logins[0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt as _;

    fn write(dir: &Path, name: &str, text: &str, mode: u32) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
        p
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("scl-net-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_private_file_is_read_and_others_are_refused_naming_the_mode() {
        let d = tmp("mode");
        let ok = write(&d, "ok", "operator:s3cret\n\nrobot:pc\n", 0o600);
        let c = Credentials::load(&ok).unwrap();
        assert_eq!(c.own().user, "operator");
        assert_eq!(c.logins.len(), 2);
        assert!(!format!("{c:?}").contains("s3cret"));
        let open = write(&d, "open", "operator:s3cret\n", 0o644);
        let e = Credentials::load(&open).unwrap_err().to_string();
        assert!(e.contains("0644") && e.contains("chmod 600"), "{e}");
        std::fs::remove_dir_all(d).unwrap();
    }

    #[test]
    fn malformed_lines_and_empty_files_are_named() {
        let p = Path::new("creds");
        for (text, want) in [
            ("operator\n", "line 1"),
            ("a:b\n:pw\n", "line 2"),
            ("us er:pw\n", "white space"),
            ("\n\n", "no `user:password`"),
            ("# a comment\n", "line 1"),
        ] {
            let e = Credentials::parse(p, text).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 512, ..Default::default() })]

        /// Any text (well-formed logins among arbitrary lines): its logins, or an error that
        /// names the file and quotes none of the passwords (the `credentials` fuzz target's
        /// rule, on stable with every `cargo test`).
        #[test]
        fn any_text_is_logins_or_an_error_naming_the_file_without_a_secret(
            lines in proptest::collection::vec(
                proptest::prop_oneof![
                    "[a-z]{1,8}:pw[A-Za-z0-9]{6,12}",
                    ".{0,40}",
                    "[ \t:#a-z]{0,12}",
                ],
                0..8,
            ),
        ) {
            let text = lines.join("\n");
            match Credentials::parse(Path::new("prop.creds"), &text) {
                Ok(c) => proptest::prop_assert!(!c.logins.is_empty()),
                Err(e) => {
                    let msg = e.to_string();
                    proptest::prop_assert!(msg.contains("prop.creds"), "{}", msg);
                    for l in text.lines() {
                        if let Some((_, pw)) = l.trim().split_once(':')
                            && pw.len() >= 4
                        {
                            proptest::prop_assert!(!msg.contains(pw), "{} quotes {}", msg, pw);
                        }
                    }
                }
            }
        }
    }
}
