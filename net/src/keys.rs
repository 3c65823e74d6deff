//! The key expressions of one graph, all below its namespace (`[network] namespace`, by
//! default `scl/<graph prefix>`):
//!
//! | key | direction | payload |
//! |---|---|---|
//! | `NS/robot_state`, `NS/mapper_command`, `NS/safe_command`, `NS/status`, `NS/tick_report`, `NS/joystick`, `NS/safety_control`, `NS/estop` | out | the graph's messages |
//! | `NS/gateway` | out | [`crate::wire::GatewayStatus`] |
//! | `NS/process/<pid>` | queryable | what mapper or safety process `<pid>` runs: [`crate::wire::PROCESS_CAPTURE`] |
//! | `NS/clock` | queryable | [`crate::wire::ClockPair`]: the robot PC's monotonic and wall clocks, read together |
//! | `NS/in/joystick/<zid>` | in | `JoystickInput` of the operator whose session is `<zid>` |
//! | `NS/in/estop` | in | `EstopCommand` (e-stop; reset only where accepted) |
//! | `NS/in/operator/<zid>` | liveliness | an operator's session is alive |
//!
//! `<zid>` is the publishing session's Zenoh id in hex, so a sample names its session and a
//! session that ended cannot speak again under a new one's name.

/// The keys of one graph.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Keys {
    ns: String,
}

impl Keys {
    /// The keys below `namespace` (checked by `scl_config::check_namespace`).
    pub fn new(namespace: &str) -> Self {
        Self {
            ns: namespace.to_owned(),
        }
    }

    /// The namespace.
    pub fn namespace(&self) -> &str {
        &self.ns
    }

    /// An outbound topic of the graph (`ipc_types::topics::*.name`).
    pub fn topic(&self, name: &str) -> String {
        format!("{}/{name}", self.ns)
    }

    /// The gateway's own status.
    pub fn gateway(&self) -> String {
        format!("{}/gateway", self.ns)
    }

    /// What process `pid` runs (the gateway's queryable answers it).
    pub fn process(&self, pid: u32) -> String {
        format!("{}/process/{pid}", self.ns)
    }

    /// Every process's capture (the gateway's queryable).
    pub fn process_all(&self) -> String {
        format!("{}/process/*", self.ns)
    }

    /// The pid in a process key below this namespace, if it is one.
    pub fn pid_of(&self, key: &str) -> Option<u32> {
        let rest = key
            .strip_prefix(self.ns.as_str())?
            .strip_prefix("/process/")?;
        if rest.is_empty() || !rest.chars().all(|c| c.is_ascii_digit()) {
            return None;
        }
        rest.parse().ok()
    }

    /// The robot PC's clocks (the gateway's queryable).
    pub fn clock(&self) -> String {
        format!("{}/clock", self.ns)
    }

    /// The joystick samples of operator session `zid`.
    pub fn joystick(&self, zid: &str) -> String {
        format!("{}/in/joystick/{zid}", self.ns)
    }

    /// Every operator's joystick samples.
    pub fn joystick_all(&self) -> String {
        format!("{}/in/joystick/*", self.ns)
    }

    /// E-stop and reset requests.
    pub fn estop(&self) -> String {
        format!("{}/in/estop", self.ns)
    }

    /// The liveliness token of operator session `zid`.
    pub fn operator(&self, zid: &str) -> String {
        format!("{}/in/operator/{zid}", self.ns)
    }

    /// Every operator's liveliness token.
    pub fn operator_all(&self) -> String {
        format!("{}/in/operator/*", self.ns)
    }

    /// The session id in a joystick or operator key below this namespace, if it is one.
    pub fn session_of<'k>(&self, key: &'k str) -> Option<&'k str> {
        let rest = key.strip_prefix(self.ns.as_str())?.strip_prefix("/in/")?;
        let (kind, zid) = rest.split_once('/')?;
        ((kind == "joystick" || kind == "operator")
            && !zid.is_empty()
            && zid.chars().all(|c| c.is_ascii_hexdigit()))
        .then_some(zid)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sessions_are_read_back_from_their_keys_only() {
        let k = Keys::new("scl/lab2");
        assert_eq!(k.session_of(&k.joystick("a1b2")), Some("a1b2"));
        assert_eq!(k.session_of(&k.operator("ff")), Some("ff"));
        assert_eq!(k.session_of("scl/lab2/in/joystick/"), None);
        assert_eq!(k.session_of("scl/lab2/in/joystick/zz"), None);
        assert_eq!(k.session_of("scl/lab3/in/joystick/a1"), None);
        assert_eq!(k.session_of("scl/lab2/in/estop"), None);
        assert_eq!(k.session_of("scl/lab2/in/joystick/a1/b2"), None);
        assert_eq!(k.topic("robot_state"), "scl/lab2/robot_state");
    }

    #[test]
    fn process_keys_carry_their_pid_and_nothing_else() {
        let k = Keys::new("scl/lab2");
        assert_eq!(k.process(42), "scl/lab2/process/42");
        assert_eq!(k.pid_of(&k.process(42)), Some(42));
        assert_eq!(k.pid_of("scl/lab2/process/"), None);
        assert_eq!(k.pid_of("scl/lab2/process/4a"), None);
        assert_eq!(k.pid_of("scl/lab2/process/+1"), None);
        assert_eq!(k.pid_of("scl/lab2/process/99999999999"), None);
        assert_eq!(k.pid_of("scl/lab3/process/42"), None);
        assert_eq!(k.pid_of("scl/lab2/process/4/2"), None);
        assert_eq!(k.clock(), "scl/lab2/clock");
    }
}
