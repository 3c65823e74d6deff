//! `[network]`: the graph's link to other machines through Zenoh (off by default). The
//! gateway process (`scl gateway`, started by `scl up` when `enabled`) reads it; the
//! `scl-net` crate turns it into a Zenoh session. The control path never waits on it.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::ConfigError;

/// How the gateway joins Zenoh.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NetworkMode {
    /// A peer: listens on `listen` and connects to `connect` directly.
    #[default]
    Peer,
    /// A client of a Zenoh router (`connect` names it); listens on nothing.
    Client,
}

/// `[network]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Start the gateway with the graph.
    pub enabled: bool,
    /// `peer` or `client`.
    pub mode: NetworkMode,
    /// Zenoh endpoints the gateway listens on (peer mode); loopback only by default.
    pub listen: Vec<String>,
    /// Zenoh endpoints (peers or a router) the gateway connects to.
    pub connect: Vec<String>,
    /// The first chunks of every key expression; empty: `scl/<graph prefix>`.
    pub namespace: String,
    /// Accept a remote operator's joystick samples and e-stop presses (the gateway becomes
    /// the graph's one joystick publisher: `scl up` starts no local joystick). Needs
    /// `credentials`.
    pub accept_joystick: bool,
    /// Accept e-stop resets from the network (besides `scl reset` on the robot PC). Needs
    /// `credentials`.
    pub accept_reset: bool,
    /// A file of `user:password` lines, mode 0600 (refused otherwise): the peers the gateway
    /// accepts, and its own name (the first line) where it connects. Relative to the
    /// configuration file.
    pub credentials: String,
    /// Zenoh's lease (ms): a peer silent this long is gone and its liveliness token with it.
    pub lease_ms: u64,
    /// Observer messages queued for the network before the newest are dropped (and counted).
    pub outbound_queue: usize,
    /// Zenoh's multicast scouting (finding peers on the LAN by themselves); off, so a graph
    /// joins only the endpoints named here.
    pub multicast_scouting: bool,
    /// Also speak rmw_zenoh's wire format: `/joint_states` and `/scl/safety_status` for a
    /// ROS 2 graph on Zenoh, with liveliness tokens so `ros2 topic list` sees them.
    pub ros2: bool,
    /// The ROS 2 domain id (`ROS_DOMAIN_ID`).
    pub ros2_domain_id: u32,
    /// The ROS 2 node name the gateway appears as.
    pub ros2_node: String,
    /// Take `/joy` (`sensor_msgs/msg/Joy`, e.g. ROS 2's `joy` node) as the joystick; needs
    /// `ros2` and `accept_joystick`.
    pub ros2_joy: bool,
    /// The `/joy` axes that are the stick's x and y.
    pub ros2_joy_axes: [u32; 2],
    /// Each axis's factor (`-1.0` turns it round).
    pub ros2_joy_scale: [f64; 2],
    /// The `/joy` buttons that are the deadman, the mode switch and the e-stop (`-1`: none).
    pub ros2_joy_deadman: i32,
    /// See `ros2_joy_deadman`.
    pub ros2_joy_mode: i32,
    /// See `ros2_joy_deadman`.
    pub ros2_joy_estop: i32,
    /// A `/joy` input older than this (ms) is stale and stops the arm (the `joy` node repeats
    /// its last message at `autorepeat_rate`, 20 Hz by default).
    pub ros2_joy_timeout_ms: u64,
    /// Forward a remote operator's samples with their own stamp (`t_ns`, the operator's
    /// monotonic clock) instead of the arrival stamp. Only where the operator shares this
    /// machine's clock: `scl bench latency --remote` sets it so that the graph's figures run
    /// from the sample's creation. A stamp from the future is replaced by the arrival stamp.
    pub keep_operator_stamps: bool,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            mode: NetworkMode::Peer,
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: Vec::new(),
            namespace: String::new(),
            accept_joystick: false,
            accept_reset: false,
            credentials: String::new(),
            lease_ms: 1000,
            outbound_queue: 256,
            multicast_scouting: false,
            ros2: false,
            ros2_domain_id: 0,
            ros2_node: "scl_gateway".into(),
            ros2_joy: false,
            ros2_joy_axes: [0, 1],
            ros2_joy_scale: [1.0, 1.0],
            ros2_joy_deadman: -1,
            ros2_joy_mode: -1,
            ros2_joy_estop: -1,
            ros2_joy_timeout_ms: 150,
            keep_operator_stamps: false,
        }
    }
}

impl NetworkConfig {
    /// Whether anything from the network can move or release the arm.
    pub fn inbound(&self) -> bool {
        self.accept_joystick || self.accept_reset
    }

    /// The namespace for a graph `prefix`: `namespace`, or `scl/<prefix>`.
    pub fn namespace_for(&self, prefix: &str) -> String {
        if self.namespace.is_empty() {
            format!("scl/{prefix}")
        } else {
            self.namespace.clone()
        }
    }

    /// Checks `[network]` (only when enabled: a disabled section is never read). The
    /// credentials file's mode is checked where it is read (`scl_net::Credentials::load`).
    pub fn validate(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: format!("network.{key}"),
            reason,
        };
        if !self.enabled {
            return Ok(());
        }
        if self.inbound() && self.credentials.is_empty() {
            let key = if self.accept_joystick {
                "accept_joystick"
            } else {
                "accept_reset"
            };
            return Err(err(
                "credentials",
                format!(
                    "is empty while network.{key} is on: input that moves or releases the arm \
                     is accepted only from authenticated peers; name a file of \
                     `user:password` lines with mode 0600"
                ),
            ));
        }
        if self.mode == NetworkMode::Client && self.connect.is_empty() {
            return Err(err(
                "connect",
                "is empty in client mode: name the router (e.g. `tcp/192.0.2.1:7447`)".into(),
            ));
        }
        if self.mode == NetworkMode::Peer && self.listen.is_empty() && self.connect.is_empty() {
            return Err(err(
                "listen",
                "and network.connect are both empty: the gateway would reach no one".into(),
            ));
        }
        for (key, list) in [("listen", &self.listen), ("connect", &self.connect)] {
            for e in list {
                check_endpoint(e).map_err(|r| err(key, format!("`{e}`: {r}")))?;
            }
        }
        if !self.namespace.is_empty() {
            check_namespace(&self.namespace).map_err(|r| err("namespace", r))?;
        }
        if !(100..=60_000).contains(&self.lease_ms) {
            return Err(err(
                "lease_ms",
                format!("{} is outside 100..=60000", self.lease_ms),
            ));
        }
        self.validate_ros2()?;
        if !(1..=65_536).contains(&self.outbound_queue) {
            return Err(err(
                "outbound_queue",
                format!("{} is outside 1..=65536", self.outbound_queue),
            ));
        }
        Ok(())
    }

    /// The ROS 2 bridge's keys: the domain id, the node name and the `/joy` input's
    /// settings.
    fn validate_ros2(&self) -> Result<(), ConfigError> {
        let err = |key: &str, reason: String| ConfigError::Value {
            key: format!("network.{key}"),
            reason,
        };
        if self.ros2_domain_id > 232 {
            return Err(err(
                "ros2_domain_id",
                format!(
                    "{} is outside 0..=232 (ROS 2's domain ids)",
                    self.ros2_domain_id
                ),
            ));
        }
        if self.ros2_node.is_empty()
            || !self
                .ros2_node
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_')
            || self.ros2_node.starts_with(|c: char| c.is_ascii_digit())
        {
            return Err(err(
                "ros2_node",
                format!(
                    "`{}` is not a ROS 2 node name (letters, digits and `_`, not starting with a digit)",
                    self.ros2_node
                ),
            ));
        }
        if self.ros2_joy && !(self.ros2 && self.accept_joystick) {
            return Err(err(
                "ros2_joy",
                "needs network.ros2 and network.accept_joystick (with its credentials)".into(),
            ));
        }
        if !self
            .ros2_joy_scale
            .iter()
            .all(|s| s.is_finite() && *s != 0.0)
        {
            return Err(err(
                "ros2_joy_scale",
                format!(
                    "{:?}: each must be a finite number other than 0",
                    self.ros2_joy_scale
                ),
            ));
        }
        for (key, b) in [
            ("ros2_joy_deadman", self.ros2_joy_deadman),
            ("ros2_joy_mode", self.ros2_joy_mode),
            ("ros2_joy_estop", self.ros2_joy_estop),
        ] {
            if b < -1 {
                return Err(err(key, format!("{b}: a button index, or -1 for none")));
            }
        }
        if !(20..=1000).contains(&self.ros2_joy_timeout_ms) {
            return Err(err(
                "ros2_joy_timeout_ms",
                format!("{} is outside 20..=1000", self.ros2_joy_timeout_ms),
            ));
        }
        Ok(())
    }

    /// Resolves a relative `credentials` path against the configuration file's directory.
    pub fn resolve_paths(&mut self, dir: &Path) {
        if !self.credentials.is_empty() {
            let p = Path::new(&self.credentials);
            if p.is_relative() {
                self.credentials = dir.join(p).display().to_string();
            }
        }
    }
}

/// A Zenoh endpoint `PROTOCOL/ADDRESS[?CONFIG]`; only TCP is built in.
pub fn check_endpoint(e: &str) -> Result<(), String> {
    let Some((proto, addr)) = e.split_once('/') else {
        return Err("is not PROTOCOL/ADDRESS (e.g. `tcp/127.0.0.1:7447`)".into());
    };
    if proto != "tcp" {
        return Err(format!(
            "protocol `{proto}` is not built in; use `tcp` (e.g. `tcp/127.0.0.1:7447`)"
        ));
    }
    let host = addr.split('?').next().unwrap_or_default();
    match host.rsplit_once(':') {
        Some((h, port)) if !h.is_empty() && port.parse::<u16>().is_ok() => Ok(()),
        _ => Err("needs HOST:PORT after `tcp/`".into()),
    }
}

/// A key-expression prefix: `/`-separated chunks, none empty, none with a wildcard or `$`.
pub fn check_namespace(ns: &str) -> Result<(), String> {
    for chunk in ns.split('/') {
        if chunk.is_empty() {
            return Err(format!(
                "`{ns}` has an empty chunk (a leading, trailing or double `/`)"
            ));
        }
        if chunk.contains(['*', '$', '?', '#']) {
            return Err(format!(
                "`{ns}`: chunk `{chunk}` holds one of `* $ ? #`, which Zenoh reserves"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn on() -> NetworkConfig {
        NetworkConfig {
            enabled: true,
            ..NetworkConfig::default()
        }
    }

    fn key_of(r: Result<(), ConfigError>) -> String {
        match r {
            Err(ConfigError::Value { key, .. }) => key,
            other => panic!("expected a value error, got {other:?}"),
        }
    }

    #[test]
    fn the_defaults_are_valid_and_loopback_only() {
        on().validate().unwrap();
        assert!(
            NetworkConfig::default()
                .listen
                .iter()
                .all(|e| e.contains("127.0.0.1"))
        );
    }

    #[test]
    fn inbound_without_credentials_is_refused_naming_the_key() {
        let c = NetworkConfig {
            accept_joystick: true,
            ..on()
        };
        let e = c.validate().unwrap_err().to_string();
        assert!(
            e.contains("network.credentials") && e.contains("accept_joystick"),
            "{e}"
        );
        let c = NetworkConfig {
            accept_reset: true,
            ..on()
        };
        assert_eq!(key_of(c.validate()), "network.credentials");
    }

    #[test]
    fn bad_values_are_named() {
        let cases: [(NetworkConfig, &str); 6] = [
            (
                NetworkConfig {
                    listen: vec!["127.0.0.1:7447".into()],
                    ..on()
                },
                "network.listen",
            ),
            (
                NetworkConfig {
                    connect: vec!["udp/127.0.0.1:7447".into()],
                    ..on()
                },
                "network.connect",
            ),
            (
                NetworkConfig {
                    mode: NetworkMode::Client,
                    ..on()
                },
                "network.connect",
            ),
            (
                NetworkConfig {
                    namespace: "lab//arm".into(),
                    ..on()
                },
                "network.namespace",
            ),
            (
                NetworkConfig {
                    lease_ms: 5,
                    ..on()
                },
                "network.lease_ms",
            ),
            (
                NetworkConfig {
                    outbound_queue: 0,
                    ..on()
                },
                "network.outbound_queue",
            ),
        ];
        for (c, key) in cases {
            assert_eq!(key_of(c.validate()), key);
        }
    }

    #[test]
    fn a_disabled_section_is_not_checked() {
        let c = NetworkConfig {
            listen: vec!["nonsense".into()],
            accept_joystick: true,
            ..NetworkConfig::default()
        };
        c.validate().unwrap();
    }

    #[test]
    fn the_namespace_defaults_to_the_prefix() {
        assert_eq!(on().namespace_for("lab2"), "scl/lab2");
        let c = NetworkConfig {
            namespace: "lab/arm1".into(),
            ..on()
        };
        assert_eq!(c.namespace_for("x"), "lab/arm1");
    }
}
