//! The graph's control plane's messages: requests to the supervisor (`scl swap`, carried by
//! an iceoryx2 request-response service that `transport::control` opens), the e-stop
//! commands, and the active-mapper switch that the supervisor sends to safety.
//!
//! Messages are fixed-size like every other message; text (a model path, a refusal reason)
//! travels in fixed byte arrays with an explicit length.

use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use zerocopy::{FromBytes, Immutable, IntoBytes, KnownLayout};

use crate::fields::message;

/// Capacity of the text fields of control messages (bytes).
pub const TEXT_CAP: usize = 512;

message! {
    /// A short UTF-8 text in a fixed array.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
    #[type_name("scl::Text")]
    #[repr(C)]
    pub struct Text {
        /// Used bytes.
        pub len: u32,
        /// The bytes.
        pub bytes: [u8; TEXT_CAP],
    }
}

impl Text {
    /// `s`, cut at a character boundary to fit.
    pub fn new(s: &str) -> Self {
        let mut end = s.len().min(TEXT_CAP);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0u8; TEXT_CAP];
        bytes[..end].copy_from_slice(&s.as_bytes()[..end]);
        Self {
            len: end as u32,
            bytes,
        }
    }

    /// The text (lossy if the bytes are not UTF-8, which only a corrupt message can cause).
    pub fn as_string(&self) -> String {
        let n = (self.len as usize).min(TEXT_CAP);
        String::from_utf8_lossy(&self.bytes[..n]).into_owned()
    }
}

message! {
    /// Tells safety which mapper's commands reach the arm, from which tick on, and whether to
    /// hold the arm (stop it until released) because a process of the input side is down. The
    /// topic keeps the newest message as history, so a restarted safety learns both.
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::SafetyControl")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct SafetyControl {
        /// Counter of the publishing supervisor.
        pub seq: u64,
        /// When it was published (monotonic ns).
        pub t_ns: u64,
        /// The first tick whose command comes from `active_mapper`.
        pub from_tick: u64,
        /// The mapper id to forward.
        pub active_mapper: u32,
        /// 1: hold the arm (controlled stop) until a message with 0 arrives.
        pub hold: u32,
        /// Counter of e-stop changes relayed by the supervisor; safety applies `estop` only when
        /// it changes (so a swap message never releases an e-stop latched by a joystick button).
        pub estop_seq: u32,
        /// With a new `estop_seq`: 1 latch the e-stop, 0 release it.
        pub estop: u32,
    }
}

/// What an [`EstopCommand`] does.
pub mod estop_action {
    /// Latch the e-stop: safety commands zero until a reset.
    pub const ESTOP: u32 = 1;
    /// Release a latched e-stop.
    pub const RESET: u32 = 2;

    /// The codes for an `x-value-names` annotation of the JSON schema.
    #[cfg(feature = "json")]
    pub fn names() -> std::collections::BTreeMap<String, String> {
        [(ESTOP, "estop"), (RESET, "reset")]
            .into_iter()
            .map(|(v, n)| (v.to_string(), n.to_owned()))
            .collect()
    }
}

message! {
    /// `scl estop` / `scl reset`: latches or releases safety's e-stop. The supervisor relays the
    /// state into [`SafetyControl`], so a restarted safety comes up still latched.
    #[cfg_attr(
        feature = "json",
        derive(serde::Serialize, serde::Deserialize, schemars::JsonSchema)
    )]
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::EstopCommand")]
    #[repr(C)]
    #[derive(IntoBytes, FromBytes, Immutable, KnownLayout)]
    pub struct EstopCommand {
        /// When it was sent (monotonic ns).
        pub t_ns: u64,
        /// [`estop_action`] value.
        #[cfg_attr(feature = "json", schemars(extend("x-value-names" = estop_action::names())))]
        pub action: u32,
        /// Process id of the sender.
        pub source_pid: u32,
    }
}

/// What a [`ControlRequest`] asks for.
pub mod request_kind {
    /// Swap the active mapper for a new one serving the model at `path`.
    pub const SWAP: u32 = 1;
}

message! {
    /// A request to the supervisor of a running graph.
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::ControlRequest")]
    #[repr(C)]
    pub struct ControlRequest {
        /// [`request_kind`] value.
        pub kind: u32,
        /// Padding, always 0.
        pub reserved: u32,
        /// The model file (absolute path) for a swap.
        pub path: Text,
    }
}

message! {
    /// The supervisor's answer.
    #[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
    #[type_name("scl::ControlResponse")]
    #[repr(C)]
    pub struct ControlResponse {
        /// 1 if done, 0 if refused.
        pub ok: u32,
        /// The new active mapper id (swap).
        pub new_mapper: u32,
        /// The mapper it replaced (swap).
        pub old_mapper: u32,
        /// How many of `missed_during` the machine took (swap): periods the bridge was not run
        /// through and commands that came late although the mapper's and safety's work fitted
        /// the deadline (`NodeStatus::held_up`, as `scl up --json` reports `held_up`). The
        /// graph's own misses are `missed_during - held_up_during`.
        pub held_up_during: u32,
        /// The first tick executed from the new mapper (swap).
        pub switch_tick: u64,
        /// From the request's arrival to the switch-over (ns).
        pub elapsed_ns: u64,
        /// Ticks the bridge missed between the request and the switch-over.
        pub missed_during: u64,
        /// Why it was refused, or a summary.
        pub message: Text,
    }
}

impl ControlResponse {
    /// A refusal with a reason.
    pub fn refused(reason: &str) -> Self {
        Self {
            ok: 0,
            new_mapper: 0,
            old_mapper: 0,
            held_up_during: 0,
            switch_tick: 0,
            elapsed_ns: 0,
            missed_during: 0,
            message: Text::new(reason),
        }
    }
}

/// Service name of the supervisor's request-response service.
pub const SUPERVISOR: &str = "supervisor";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_fits_and_cuts_at_char_boundaries() {
        assert_eq!(Text::new("hello").as_string(), "hello");
        let long = "é".repeat(400); // 800 bytes
        let t = Text::new(&long);
        assert!(t.len as usize <= TEXT_CAP);
        assert_eq!(t.as_string(), "é".repeat(256));
    }
}
