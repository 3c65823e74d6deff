//! The JSON form of the recorded messages (feature `json`): the message types derive
//! `serde::Serialize`, `serde::Deserialize` and `schemars::JsonSchema` directly, so a message,
//! its JSON and its JSON schema are one definition. This module holds the few field helpers
//! the derives name:
//!
//! * [`tick`]: a tick field is `null` for [`NO_TICK`] (`u64::MAX` is not exact in a JSON reader
//!   that keeps numbers as doubles, as Foxglove's does);
//! * the `x-value-names` schema annotations (`{"1": "joystick", ...}`), so a viewer of the
//!   schema knows what the codes of a role or phase mean (an e-stop action's are
//!   [`crate::control::estop_action::names`]); flag fields carry
//!   `x-bit-names` (the names of bits 0, 1, ..., the `NAMES` tables of the flag modules).
//!
//! Joint arrays are written whole (`MAX_JOINTS` entries, the count beside them), as the struct
//! holds them: the schema says `minItems` = `maxItems` = `MAX_JOINTS`.

use std::collections::BTreeMap;

use super::{NO_TICK, NodeRole, phase};

/// `#[serde(with = "crate::msg::json::tick")]`: a tick, `null` for [`NO_TICK`]. Its schema is
/// [`tick::Schema`] (always present, an integer or `null`).
pub mod tick {
    use std::borrow::Cow;

    use super::NO_TICK;

    /// `#[schemars(with = "crate::msg::json::tick::Schema")]`: the schema of a tick field, that of
    /// an `Option<u64>`, but required: the field is always written.
    pub struct Schema;

    impl schemars::JsonSchema for Schema {
        fn inline_schema() -> bool {
            true
        }

        fn schema_name() -> Cow<'static, str> {
            "Tick".into()
        }

        fn json_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
            <Option<u64> as schemars::JsonSchema>::json_schema(generator)
        }
    }

    /// Writes `None` for [`NO_TICK`].
    pub fn serialize<S: serde::Serializer>(t: &u64, s: S) -> Result<S::Ok, S::Error> {
        let t = (*t != NO_TICK).then_some(*t);
        serde::Serialize::serialize(&t, s)
    }

    /// Reads `null` as [`NO_TICK`].
    pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        let t: Option<u64> = serde::Deserialize::deserialize(d)?;
        Ok(t.unwrap_or(NO_TICK))
    }
}

/// The codes of [`NodeRole`] for an `x-value-names` annotation.
pub fn role_names() -> BTreeMap<String, String> {
    (0..=u8::MAX as u32)
        .filter_map(|v| NodeRole::from_u32(v).map(|r| (v.to_string(), r.name().to_owned())))
        .collect()
}

/// The codes of [`phase`] for an `x-value-names` annotation.
pub fn phase_names() -> BTreeMap<String, String> {
    [
        (phase::READY, "ready"),
        (phase::RUNNING, "running"),
        (phase::STOPPING, "stopping"),
    ]
    .into_iter()
    .map(|(v, n)| (v.to_string(), n.to_owned()))
    .collect()
}

#[cfg(test)]
mod tests {
    use crate::msg::{NO_TICK, NodeRole, NodeStatus, RobotState, phase};

    #[test]
    fn a_tick_of_none_is_null_both_ways() {
        let mut s = RobotState::at_rest(4, 5, 6);
        let v = serde_json::to_value(s).unwrap();
        assert!(v["applied_tick"].is_null(), "{v}");
        assert_eq!(serde_json::from_value::<RobotState>(v).unwrap(), s);
        s.applied_tick = 3;
        let v = serde_json::to_value(s).unwrap();
        assert_eq!(v["applied_tick"], 3);
        assert_eq!(serde_json::from_value::<RobotState>(v).unwrap(), s);
        // Required, although it may be null: the field is always written.
        let schema = schemars::schema_for!(NodeStatus).to_value();
        let required = schema["required"].as_array().unwrap();
        assert!(required.contains(&"tick".into()), "{schema}");
        assert_eq!(
            schema["properties"]["tick"]["type"],
            serde_json::json!(["integer", "null"])
        );
        let st = NodeStatus::new(NodeRole::Mapper, phase::READY, 1);
        assert_eq!(st.tick, NO_TICK);
        assert!(serde_json::to_value(st).unwrap()["tick"].is_null());
    }
}
