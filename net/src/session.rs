//! Zenoh sessions: the configuration from `[network]` (or a remote operator's endpoint) and
//! the opening, with errors that name the endpoints.

use scl_config::NetworkMode;
use zenoh::Wait as _;

use crate::credentials::{Credentials, CredentialsError};

/// What a session needs.
#[derive(Debug, Clone)]
pub struct SessionSpec<'a> {
    /// Peer or client.
    pub mode: NetworkMode,
    /// Endpoints to listen on (peer mode).
    pub listen: &'a [String],
    /// Endpoints to connect to.
    pub connect: &'a [String],
    /// The link lease (ms).
    pub lease_ms: u64,
    /// Multicast scouting.
    pub multicast_scouting: bool,
    /// The login this side presents (the file's first line), if any.
    pub credentials: Option<&'a Credentials>,
    /// Accept only the peers the credentials file lists (the gateway's side).
    pub accept_listed_only: bool,
}

/// Why a session could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// Zenoh refused the configuration.
    #[error("the Zenoh configuration was refused: {source}")]
    Config {
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
    /// The session did not open (an endpoint in use or unreachable, authentication refused).
    #[error("cannot open a Zenoh session (listen {listen:?}, connect {connect:?}): {source}")]
    Open {
        /// The listen endpoints.
        listen: Vec<String>,
        /// The connect endpoints.
        connect: Vec<String>,
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
    /// A publisher, subscriber or token could not be declared.
    #[error("cannot declare the {what} on `{key}`: {source}")]
    Declare {
        /// What.
        what: &'static str,
        /// The key expression.
        key: String,
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
}

/// The Zenoh configuration of `spec`, as JSON5 Zenoh reads.
pub fn config_json(spec: &SessionSpec<'_>) -> serde_json::Value {
    let mode = match spec.mode {
        NetworkMode::Peer => "peer",
        NetworkMode::Client => "client",
    };
    let listen: &[String] = match spec.mode {
        NetworkMode::Peer => spec.listen,
        NetworkMode::Client => &[],
    };
    let mut usrpwd = serde_json::Map::new();
    if let Some(c) = spec.credentials {
        let own = c.own();
        usrpwd.insert("user".into(), own.user.clone().into());
        usrpwd.insert("password".into(), own.password.clone().into());
        if spec.accept_listed_only {
            usrpwd.insert(
                "dictionary_file".into(),
                c.path.display().to_string().into(),
            );
        }
    }
    serde_json::json!({
        "mode": mode,
        "listen": { "endpoints": listen },
        "connect": { "endpoints": spec.connect },
        "scouting": {
            "multicast": { "enabled": spec.multicast_scouting },
        },
        "transport": {
            "link": { "tx": { "lease": spec.lease_ms } },
            "auth": { "usrpwd": usrpwd },
        },
    })
}

/// Opens a session for `spec`.
pub fn open(spec: &SessionSpec<'_>) -> Result<zenoh::Session, SessionError> {
    let json = config_json(spec).to_string();
    let config =
        zenoh::Config::from_json5(&json).map_err(|source| SessionError::Config { source })?;
    zenoh::open(config)
        .wait()
        .map_err(|source| SessionError::Open {
            listen: spec.listen.to_vec(),
            connect: spec.connect.to_vec(),
            source,
        })
}

/// Why a client session (`--remote ENDPOINT`) could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The endpoint is not one Zenoh can reach here (named as the `--remote` option).
    #[error(transparent)]
    Endpoint(scl_config::ConfigError),
    /// The credentials file is unusable.
    #[error(transparent)]
    Credentials(#[from] CredentialsError),
    /// The session did not open.
    #[error(transparent)]
    Session(#[from] SessionError),
}

/// A client session to the gateway at `endpoint` (a remote operator's, a remote observer's):
/// the endpoint checked first, then the login of `credentials` (if any) read, then the session
/// opened with it. Returns the session and the login it used.
pub fn open_client(
    endpoint: &str,
    credentials: Option<&std::path::Path>,
    lease_ms: u64,
) -> Result<(zenoh::Session, Option<Credentials>), ClientError> {
    scl_config::check_endpoint(endpoint).map_err(|reason| {
        ClientError::Endpoint(scl_config::ConfigError::Value {
            key: "--remote".into(),
            reason: format!("`{endpoint}`: {reason}"),
        })
    })?;
    let creds = credentials.map(Credentials::load).transpose()?;
    let connect = [endpoint.to_owned()];
    let session = open(&SessionSpec {
        mode: NetworkMode::Client,
        listen: &[],
        connect: &connect,
        lease_ms,
        multicast_scouting: false,
        credentials: creds.as_ref(),
        accept_listed_only: false,
    })?;
    Ok((session, creds))
}

/// The session's id as keys carry it (hex).
pub fn session_id(session: &zenoh::Session) -> String {
    session.zid().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gateway_accepts_listed_peers_and_a_client_listens_nowhere() {
        let dir = std::env::temp_dir();
        let creds = Credentials {
            path: dir.join("creds"),
            logins: vec![crate::credentials::Login {
                user: "robot".into(),
                password: "pw".into(),
            }],
        };
        let listen = vec!["tcp/127.0.0.1:7447".to_owned()];
        let spec = SessionSpec {
            mode: NetworkMode::Peer,
            listen: &listen,
            connect: &[],
            lease_ms: 1000,
            multicast_scouting: false,
            credentials: Some(&creds),
            accept_listed_only: true,
        };
        let j = config_json(&spec);
        assert_eq!(j["transport"]["auth"]["usrpwd"]["user"], "robot");
        assert!(j["transport"]["auth"]["usrpwd"]["dictionary_file"].is_string());
        assert_eq!(j["listen"]["endpoints"][0], "tcp/127.0.0.1:7447");
        assert_eq!(j["scouting"]["multicast"]["enabled"], false);
        zenoh::Config::from_json5(&j.to_string()).unwrap();
        let client = SessionSpec {
            mode: NetworkMode::Client,
            accept_listed_only: false,
            ..spec
        };
        let j = config_json(&client);
        assert!(j["listen"]["endpoints"].as_array().unwrap().is_empty());
        assert!(j["transport"]["auth"]["usrpwd"]["dictionary_file"].is_null());
        zenoh::Config::from_json5(&j.to_string()).unwrap();
    }
}
