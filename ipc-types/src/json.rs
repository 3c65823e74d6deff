//! The JSON form of the recorded messages (feature `json`): the message types derive
//! `serde::Serialize`, `serde::Deserialize` and `schemars::JsonSchema` directly, so a message,
//! its JSON and its JSON schema are one definition. The field helpers the derives name live
//! beside the types ([`crate::msg::json`], [`crate::control::estop_action::names`]); this
//! module gathers them.

pub use crate::control::estop_action::names as estop_action_names;
pub use crate::msg::json::{phase_names, role_names, tick};
