//! The messages' memory layout as data, for bindings in other languages.
//!
//! [`describe`] lists every message and control type of the graph with its size, alignment,
//! iceoryx2 type name and every field's name, offset, size and type, together with the
//! constants, bit names and topic settings a binding must agree on. `scl layout` prints it as
//! JSON; the Python package's drift test (`python/tests/test_layout.py`) compares its
//! `ctypes.Structure` classes against it, so a Rust message changed without the Python side
//! fails CI.
//!
//! Nothing here is written by hand twice: each type's layout is [`Fields::layout`], which
//! the type's one declaration (`crate::fields`) derives from its field list: each field's
//! offset is `offset_of!`, its size and type name come from the field's own Rust type
//! ([`FieldType`]), so a field added to or removed from a message is described with no edit
//! here.

use serde::Serialize;

pub use crate::fields::FieldType;
use crate::fields::Fields;

use crate::control::{
    ControlRequest, ControlResponse, EstopCommand, SUPERVISOR, SafetyControl, TEXT_CAP, Text,
};
use crate::msg::{
    ACTION_DIM, JoystickInput, MAX_JOINTS, MapperCommand, NO_TICK, NodeStatus, RobotState,
    SafeCommand, TickReport, buttons, mapper_flags, safe_flags, safety_state, state_flags,
};
use crate::topics::{self, TopicSettings};

/// One field of a message.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct FieldLayout {
    /// The field's name.
    pub name: &'static str,
    /// Its offset from the start of the struct (bytes).
    pub offset: usize,
    /// Its size (bytes).
    pub size: usize,
    /// Its type ([`FieldType::describe`]).
    #[serde(rename = "type")]
    pub ty: String,
}

/// One `#[repr(C)]` type of the graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TypeLayout {
    /// The Rust type's name (`RobotState`).
    pub name: &'static str,
    /// The iceoryx2 type name services are opened with (`scl::RobotState`).
    pub type_name: &'static str,
    /// `size_of` (bytes).
    pub size: usize,
    /// `align_of` (bytes).
    pub align: usize,
    /// The fields in declaration order.
    pub fields: Vec<FieldLayout>,
}

/// A topic's quality-of-service settings ([`TopicSettings`]), which every process opening
/// the topic must repeat.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TopicLayout {
    /// Topic name below the prefix (`robot_state`; the service is `PREFIX/robot_state`, its
    /// wake-up event `PREFIX/robot_state/event`).
    pub name: &'static str,
    /// The message type's Rust name.
    pub message: &'static str,
    /// History size.
    pub history: usize,
    /// Subscriber buffer size.
    pub buffer: usize,
    /// Publishers admitted.
    pub max_publishers: usize,
    /// Subscribers admitted.
    pub max_subscribers: usize,
}

/// The constants a binding needs.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Constants {
    /// [`MAX_JOINTS`].
    pub max_joints: usize,
    /// [`ACTION_DIM`].
    pub action_dim: usize,
    /// [`NO_TICK`].
    pub no_tick: u64,
    /// [`TEXT_CAP`].
    pub text_cap: usize,
    /// The supervisor's request-response service name below the prefix.
    pub supervisor_service: &'static str,
}

/// Everything a binding must agree on with this build.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Layout {
    /// The crate version of the build that describes itself.
    pub version: &'static str,
    /// Every message and control type.
    pub types: Vec<TypeLayout>,
    /// Every topic's settings.
    pub topics: Vec<TopicLayout>,
    /// Constants.
    pub constants: Constants,
    /// The names of each bit set, in bit order (`buttons`, `state_flags`, `mapper_flags`,
    /// `safe_flags`, `safety_state`).
    pub bits: Vec<(&'static str, Vec<&'static str>)>,
}

fn topic(s: &TopicSettings, message: &'static str) -> TopicLayout {
    TopicLayout {
        name: s.name,
        message,
        history: s.history,
        buffer: s.buffer,
        max_publishers: s.max_publishers,
        max_subscribers: s.max_subscribers,
    }
}

/// The layout of every message and control type of this build, with the topics' settings,
/// the constants and the bit names.
pub fn describe() -> Layout {
    let mut types = message_types();
    types.extend(control_types());
    // Every topic but the processes' log records, which no binding reads or writes.
    let topics = topics::ALL
        .iter()
        .filter(|(s, _)| s.name != topics::LOG.name)
        .map(|&(s, message)| topic(s, message))
        .collect();
    Layout {
        version: env!("CARGO_PKG_VERSION"),
        types,
        topics,
        constants: Constants {
            max_joints: MAX_JOINTS,
            action_dim: ACTION_DIM,
            no_tick: NO_TICK,
            text_cap: TEXT_CAP,
            supervisor_service: SUPERVISOR,
        },
        bits: vec![
            ("buttons", buttons::NAMES.to_vec()),
            ("state_flags", state_flags::NAMES.to_vec()),
            ("mapper_flags", mapper_flags::NAMES.to_vec()),
            ("safe_flags", safe_flags::NAMES.to_vec()),
            ("safety_state", safety_state::NAMES.to_vec()),
        ],
    }
}

/// The layouts of the messages on the topics, the joystick's to the nodes' status.
fn message_types() -> Vec<TypeLayout> {
    vec![
        JoystickInput::layout(),
        RobotState::layout(),
        MapperCommand::layout(),
        SafeCommand::layout(),
        TickReport::layout(),
        NodeStatus::layout(),
    ]
}

/// The layouts of the control types: the safety control, the e-stop, the supervisor's
/// requests and responses.
fn control_types() -> Vec<TypeLayout> {
    vec![
        SafetyControl::layout(),
        EstopCommand::layout(),
        Text::layout(),
        ControlRequest::layout(),
        ControlResponse::layout(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_tile_each_struct_in_order() {
        // Fields follow each other without gaps (the messages have no padding; a gap is an
        // explicit `reserved` field) and end within the struct's tail alignment.
        for t in describe().types {
            let mut end = 0;
            for f in &t.fields {
                assert_eq!(
                    f.offset, end,
                    "{}.{} does not follow its predecessor",
                    t.name, f.name
                );
                end = f.offset + f.size;
            }
            assert!(
                end <= t.size && t.size - end < t.align,
                "{}: tail {}",
                t.name,
                t.size - end
            );
        }
    }

    #[test]
    fn describes_the_messages_as_declared() {
        let l = describe();
        let rs = l.types.iter().find(|t| t.name == "RobotState").unwrap();
        assert_eq!(rs.type_name, "scl::RobotState");
        assert_eq!((rs.size, rs.align), (176, 8));
        let q = rs.fields.iter().find(|f| f.name == "q_rad").unwrap();
        assert_eq!((q.offset, q.size, q.ty.as_str()), (40, 64, "[f64; 8]"));
        let req = l.types.iter().find(|t| t.name == "ControlRequest").unwrap();
        assert_eq!(req.fields[2].ty, "Text");
        // Every topic's message is described.
        for topic in &l.topics {
            assert!(
                l.types.iter().any(|t| t.name == topic.message),
                "{}",
                topic.name
            );
        }
        let json = serde_json::to_value(&l).unwrap();
        assert_eq!(json["constants"]["no_tick"], serde_json::json!(u64::MAX));
        assert_eq!(json["types"][0]["fields"][0]["type"], "u64");
    }
}
