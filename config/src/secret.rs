//! The graph's credentials files and the one rule they follow: only their owner may read or
//! change them (mode 0600 or 0400), else they are refused, naming the file and its mode. Two
//! files follow it: `[network] credentials` (Zenoh's `user:password` lines, read by
//! `scl_net::Credentials`) and `[bridge.kortex] credentials_file` (the Kortex user name and
//! password, [`read_kortex_credentials`]). `scl up` reads both before it starts anything.

use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};

use serde::Deserialize;

/// Why a credentials file may not be used.
#[derive(Debug, thiserror::Error)]
pub enum SecretFileError {
    /// It could not be read.
    #[error("credentials file {}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Others may read or write it.
    #[error(
        "credentials file {} has mode {mode:04o}: others than its owner may read or change it; run `chmod 600 {}`",
        path.display(),
        path.display()
    )]
    Mode {
        /// The file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
}

/// Reads a credentials file that only its owner may read or change (the one rule of every
/// credentials file); its text.
pub fn read_owner_only(path: &Path) -> Result<String, SecretFileError> {
    let io = |source| SecretFileError::Io {
        path: path.to_owned(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(io)?;
    let mode = meta.permissions().mode() & 0o7777;
    if mode & 0o077 != 0 {
        return Err(SecretFileError::Mode {
            path: path.to_owned(),
            mode,
        });
    }
    std::fs::read_to_string(path).map_err(io)
}

/// Why the Kortex credentials file could not be used. No variant holds or shows a secret.
#[derive(Debug, thiserror::Error)]
pub enum KortexCredentialsError {
    /// It could not be read, or others may read it.
    #[error(transparent)]
    File(#[from] SecretFileError),
    /// It is not the expected TOML. The parser's own error is left out on purpose: it quotes
    /// the offending line, which may hold the password.
    #[error(
        "credentials file {}{}: expected `username = \"...\"` and `password = \"...\"` (TOML strings) and nothing else",
        path.display(),
        line.map_or(String::new(), |l| format!(", line {l}"))
    )]
    Parse {
        /// `[bridge.kortex] credentials_file`.
        path: PathBuf,
        /// The line the parser stopped at, if it said.
        line: Option<usize>,
    },
}

/// `[bridge.kortex] credentials_file`: a user name and a password, each optional (the
/// command line or the environment may give the other). Never shown in `Debug`.
#[derive(Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KortexCredentialsFile {
    /// `username`.
    pub username: Option<String>,
    /// `password`.
    pub password: Option<String>,
}

impl std::fmt::Debug for KortexCredentialsFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KortexCredentialsFile(<redacted>)")
    }
}

/// Reads and checks the Kortex credentials file at `path`.
pub fn read_kortex_credentials(
    path: &Path,
) -> Result<KortexCredentialsFile, KortexCredentialsError> {
    parse_kortex_credentials(&read_owner_only(path)?, path)
}

/// Parses the text of the Kortex credentials file `path` (its mode checked by the caller).
pub fn parse_kortex_credentials(
    text: &str,
    path: &Path,
) -> Result<KortexCredentialsFile, KortexCredentialsError> {
    toml::from_str(text).map_err(|e| KortexCredentialsError::Parse {
        path: path.to_owned(),
        line: e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str, mode: u32) -> PathBuf {
        let d = std::env::temp_dir().join(format!("scl-secret-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
        p
    }

    /// The one rule: 0600 and 0400 are read, anything others may read or change is refused
    /// naming the file and the mode, for the Kortex file as for any.
    #[test]
    fn only_files_of_their_owner_alone_are_read() {
        let text = "username = \"u\"\npassword = \"pw-xq\"\n";
        for mode in [0o600, 0o400] {
            let p = write(&format!("ok{mode:o}"), text, mode);
            let c = read_kortex_credentials(&p).unwrap();
            assert_eq!(c.password.as_deref(), Some("pw-xq"));
            assert!(!format!("{c:?}").contains("pw-xq"));
        }
        for mode in [0o644, 0o640, 0o604, 0o660] {
            let p = write(&format!("open{mode:o}"), text, mode);
            let e = read_kortex_credentials(&p).unwrap_err().to_string();
            assert!(
                e.contains(&format!("{mode:04o}")) && e.contains("chmod 600"),
                "{e}"
            );
            assert!(matches!(
                read_owner_only(&p),
                Err(SecretFileError::Mode { mode: m, .. }) if m == mode
            ));
        }
        let e = read_owner_only(Path::new("/nonexistent/creds"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/creds"), "{e}");
    }
}
