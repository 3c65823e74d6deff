//! The project's own definitions of the Kortex messages the bridge exchanges (package
//! `Kinova.Api`, proto3), written from the field numbers in
//! `shared/reference/kortex-protocol.md` as prost derive structs: no `.proto` compiler needed.
//!
//! Only the fields the bridge reads or writes are declared; prost skips the others when
//! decoding, so a robot that sends more still decodes. Enums are declared as `int32` (the
//! same varint on the wire) with the values the bridge uses as constants.

/// `Session.CreateSession` request.
#[derive(Clone, PartialEq, prost::Message)]
#[prost(skip_debug)]
pub struct CreateSessionInfo {
    /// User name.
    #[prost(string, tag = "1")]
    pub username: String,
    /// The session ends after this long without a frame (ms).
    #[prost(uint32, tag = "2")]
    pub session_inactivity_timeout: u32,
    /// Password.
    #[prost(string, tag = "3")]
    pub password: String,
    /// The robot stops any movement started from this session after this long without a
    /// frame (ms): the only robot-side watchdog.
    #[prost(uint32, tag = "4")]
    pub connection_inactivity_timeout: u32,
}

impl std::fmt::Debug for CreateSessionInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CreateSessionInfo")
            .field("username", &"<redacted>")
            .field(
                "session_inactivity_timeout",
                &self.session_inactivity_timeout,
            )
            .field("password", &"<redacted>")
            .field(
                "connection_inactivity_timeout",
                &self.connection_inactivity_timeout,
            )
            .finish()
    }
}

/// `Base.SendJointSpeedsCommand` request.
#[derive(Clone, PartialEq, prost::Message)]
pub struct JointSpeeds {
    /// One entry per joint; every joint must be named.
    #[prost(message, repeated, tag = "1")]
    pub joint_speeds: Vec<JointSpeed>,
    /// Not implemented by the robot.
    #[prost(uint32, tag = "2")]
    pub duration: u32,
}

/// One joint's speed.
#[derive(Clone, PartialEq, prost::Message)]
pub struct JointSpeed {
    /// Joint index, 0-based.
    #[prost(uint32, tag = "1")]
    pub joint_identifier: u32,
    /// Speed (deg/s).
    #[prost(float, tag = "2")]
    pub value: f32,
    /// Not implemented by the robot.
    #[prost(uint32, tag = "3")]
    pub duration: u32,
}

/// `Base.GetMeasuredJointAngles` reply.
#[derive(Clone, PartialEq, prost::Message)]
pub struct JointAngles {
    /// One entry per joint.
    #[prost(message, repeated, tag = "1")]
    pub joint_angles: Vec<JointAngle>,
}

/// One joint's angle.
#[derive(Clone, PartialEq, prost::Message)]
pub struct JointAngle {
    /// Joint index, 0-based.
    #[prost(uint32, tag = "1")]
    pub joint_identifier: u32,
    /// Angle (deg, in [0, 360)).
    #[prost(float, tag = "2")]
    pub value: f32,
}

/// `ServoingModeInformation.servoing_mode` values.
pub mod servoing_mode {
    /// Single-level servoing: the high-level API drives the arm.
    pub const SINGLE_LEVEL: i32 = 2;
    /// Low-level servoing (the 1 kHz cyclic channel).
    pub const LOW_LEVEL: i32 = 3;
    /// Bypass.
    pub const BYPASS: i32 = 4;
}

/// `Base.SetServoingMode` request.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ServoingModeInformation {
    /// See [`servoing_mode`].
    #[prost(int32, tag = "1")]
    pub servoing_mode: i32,
}

/// `GripperCommand.mode` values.
pub mod gripper_mode {
    /// Force control.
    pub const FORCE: i32 = 1;
    /// Speed control.
    pub const SPEED: i32 = 2;
    /// Position control: 0 open .. 1 closed.
    pub const POSITION: i32 = 3;
}

/// The finger id of the Gen3 lite's one actuated finger joint.
pub const GRIPPER_FINGER_ID: u32 = 1;

/// `Base.SendGripperCommand` request.
#[derive(Clone, PartialEq, prost::Message)]
pub struct GripperCommand {
    /// See [`gripper_mode`].
    #[prost(int32, tag = "1")]
    pub mode: i32,
    /// The fingers' targets.
    #[prost(message, optional, tag = "2")]
    pub gripper: Option<Gripper>,
    /// Duration (unused).
    #[prost(uint32, tag = "3")]
    pub duration: u32,
}

/// The gripper's fingers.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Gripper {
    /// One entry per finger.
    #[prost(message, repeated, tag = "1")]
    pub finger: Vec<Finger>,
}

/// One finger's target.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Finger {
    /// Finger id ([`GRIPPER_FINGER_ID`]).
    #[prost(uint32, tag = "1")]
    pub finger_identifier: u32,
    /// Position mode: 0 open .. 1 closed.
    #[prost(float, tag = "2")]
    pub value: f32,
}

/// `DeviceConfig.GetFirmwareVersion` reply (function UID 0x90004, Empty -> FirmwareVersion).
#[derive(Clone, PartialEq, prost::Message)]
pub struct FirmwareVersion {
    /// The version, one byte each for major, minor and patch (bits 23..16, 15..8, 7..0).
    #[prost(uint32, tag = "1")]
    pub firmware_version: u32,
}

/// `Base.GetActuatorCount` reply.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ActuatorInformation {
    /// Number of actuators (6 on a Gen3 lite).
    #[prost(uint32, tag = "1")]
    pub count: u32,
}

// `Base.GetProductConfiguration` (Empty -> `ProductConfiguration.CompleteProductConfiguration`):
// not in the protocol reference. The field numbers and the `ModelId` values below are those of
// Kinova's published `ProductConfiguration.proto` (KortexAPI 2.x), as its generated C++ header
// states them (`kortex_api/include/messages/ProductConfiguration.pb.h` in Kinova's ros2_kortex
// repository: `string kin = 1`, `ModelId model = 2`, `uint32 degree_of_freedom = 6`), and
// Kinova's API reference (`api_cpp/doc/markdown/enums/ProductConfiguration/ModelId.md` in
// Kinova-kortex2_Gen3_G3L: L53 the Gen3, L31 the Gen3 lite, called PICO there; Kinova's
// examples test `MODEL_ID_L31` to detect a Gen3 lite).

/// `CompleteProductConfiguration.model` values ([`CompleteProductConfiguration`]).
pub mod model_id {
    /// Not reported (older firmware, or a robot that does not say).
    pub const UNSPECIFIED: i32 = 0;
    /// `MODEL_ID_L53`: the Gen3 (6 or 7 actuators).
    pub const L53: i32 = 1;
    /// `MODEL_ID_L31`: the Gen3 lite.
    pub const L31: i32 = 2;
    /// `MODEL_ID_HDK`: the hardware development kit.
    pub const HDK: i32 = 3;
}

/// `Base.GetProductConfiguration` reply: what the robot says it is. Only the fields the bridge
/// reads are declared.
#[derive(Clone, PartialEq, prost::Message)]
pub struct CompleteProductConfiguration {
    /// Kinova Identification Number of the device.
    #[prost(string, tag = "1")]
    pub kin: String,
    /// The model, see [`model_id`].
    #[prost(int32, tag = "2")]
    pub model: i32,
    /// Degrees of freedom of the device.
    #[prost(uint32, tag = "6")]
    pub degree_of_freedom: u32,
}
/// `ArmStateInformation.active_state` and `BaseFeedback.active_state` values the bridge uses.
pub mod arm_state {
    /// Idle.
    pub const IDLE: i32 = 2;
    /// In fault.
    pub const IN_FAULT: i32 = 4;
    /// Ready for servoing.
    pub const SERVOING_READY: i32 = 7;
}

/// `Base.GetArmState` reply.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ArmStateInformation {
    /// See [`arm_state`].
    #[prost(int32, tag = "1")]
    pub active_state: i32,
}

/// `ControlConfig.GetKinematicHardLimits` reply.
#[derive(Clone, PartialEq, prost::Message)]
pub struct KinematicLimits {
    /// The control mode the limits are for.
    #[prost(int32, tag = "1")]
    pub control_mode: i32,
    /// Cartesian linear speed limit (m/s).
    #[prost(float, tag = "2")]
    pub twist_linear: f32,
    /// Cartesian angular speed limit (deg/s).
    #[prost(float, tag = "3")]
    pub twist_angular: f32,
    /// Joint speed limits (deg/s), one per joint.
    #[prost(float, repeated, tag = "4")]
    pub joint_speed_limits: Vec<f32>,
    /// Joint acceleration limits (deg/s²), one per joint.
    #[prost(float, repeated, tag = "5")]
    pub joint_acceleration_limits: Vec<f32>,
}

/// `BaseCyclic.RefreshFeedback` reply.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Feedback {
    /// Frame counter of the cyclic feedback.
    #[prost(fixed32, tag = "1")]
    pub frame_id: u32,
    /// The base's state.
    #[prost(message, optional, tag = "2")]
    pub base: Option<BaseFeedback>,
    /// One entry per actuator, in joint order.
    #[prost(message, repeated, tag = "3")]
    pub actuators: Vec<ActuatorFeedback>,
    /// The tool interconnect (and the gripper behind it).
    #[prost(message, optional, tag = "4")]
    pub interconnect: Option<InterconnectFeedback>,
}

/// The base's part of the feedback (the fields the bridge reads).
#[derive(Clone, PartialEq, prost::Message)]
pub struct BaseFeedback {
    /// Connection that owns the active state.
    #[prost(uint32, tag = "1")]
    pub active_state_connection_identifier: u32,
    /// See [`arm_state`].
    #[prost(int32, tag = "2")]
    pub active_state: i32,
    /// Fault bank A.
    #[prost(fixed32, tag = "31")]
    pub fault_bank_a: u32,
    /// Fault bank B.
    #[prost(fixed32, tag = "32")]
    pub fault_bank_b: u32,
}

/// One actuator's feedback.
#[derive(Clone, PartialEq, prost::Message)]
pub struct ActuatorFeedback {
    /// Id of the last command.
    #[prost(fixed32, tag = "1")]
    pub command_id: u32,
    /// Status flags.
    #[prost(fixed32, tag = "2")]
    pub status_flags: u32,
    /// Communication jitter.
    #[prost(fixed32, tag = "3")]
    pub jitter_comm: u32,
    /// Angle (deg, in [0, 360)).
    #[prost(float, tag = "4")]
    pub position: f32,
    /// Speed (deg/s).
    #[prost(float, tag = "5")]
    pub velocity: f32,
    /// Torque (N·m).
    #[prost(float, tag = "6")]
    pub torque: f32,
    /// Motor current (A).
    #[prost(float, tag = "7")]
    pub current_motor: f32,
    /// Voltage (V).
    #[prost(float, tag = "8")]
    pub voltage: f32,
    /// Motor temperature (°C).
    #[prost(float, tag = "9")]
    pub temperature_motor: f32,
    /// Core temperature (°C).
    #[prost(float, tag = "10")]
    pub temperature_core: f32,
    /// Fault bank A.
    #[prost(fixed32, tag = "11")]
    pub fault_bank_a: u32,
    /// Fault bank B.
    #[prost(fixed32, tag = "12")]
    pub fault_bank_b: u32,
}

/// The tool interconnect's feedback (the gripper part).
#[derive(Clone, PartialEq, prost::Message)]
pub struct InterconnectFeedback {
    /// The gripper (a member of a oneof on the robot's side; the same bytes on the wire).
    #[prost(message, optional, tag = "18")]
    pub gripper_feedback: Option<GripperFeedback>,
}

/// The gripper's feedback.
#[derive(Clone, PartialEq, prost::Message)]
pub struct GripperFeedback {
    /// One entry per gripper motor.
    #[prost(message, repeated, tag = "7")]
    pub motor: Vec<MotorFeedback>,
}

/// One gripper motor's feedback.
#[derive(Clone, PartialEq, prost::Message)]
pub struct MotorFeedback {
    /// Motor id.
    #[prost(fixed32, tag = "1")]
    pub motor_id: u32,
    /// Position (0 open .. 100 closed, %).
    #[prost(float, tag = "4")]
    pub position: f32,
    /// Speed (%/s).
    #[prost(float, tag = "5")]
    pub velocity: f32,
}

// ---------------------------------------------------------------------------------------------
// BaseCyclic command (low-level servoing).
//
// Source. `shared/reference/kortex-protocol.md` numbers the fields of Feedback and
// ActuatorFeedback and gives `BaseCyclic.RefreshFeedback` (0x30003), but not the cyclic command.
// Kinova's published Kortex API documentation (the BaseCyclic service page and its message
// pages) lists the service's RPCs as Refresh, RefreshCommand, RefreshFeedback,
// RefreshCustomData, and each message's members in field order, without numbers. Read against
// the reference, that documentation agrees where both speak: RefreshFeedback is the third RPC
// (function 3), and the members of Feedback and ActuatorFeedback are listed in the order of
// their field numbers. So Refresh is function 1 (UID 0x30001), Command's members are
// frame_id = 1, actuators = 2 (repeated), interconnect = 3, and ActuatorCommand's are
// command_id = 1, flags = 2, position = 3 (deg), velocity = 4 (deg/s), torque_joint = 5,
// current_motor = 6.
//
// Wire types. The documentation writes "uint32" for fields the reference declares fixed32
// (ActuatorFeedback.command_id, status_flags, Feedback.frame_id), so "uint32" there does not
// tell varint from fixed32; the command's frame_id, command_id and flags are taken as fixed32,
// like their feedback counterparts. The floats are unambiguous. Should the robot expect varints
// there, a protobuf parser skips those fields as unknown (read as 0): flags are 0 anyway (left
// out of the encoding), and the positions (float, tag 3) are still read as meant. The
// documentation describes command_id as a device id (upper 16 bits) and a sequence number
// (lower 16 bits); the bridge sends device id 0, as Kinova's examples do, and its frame
// counter's lower 16 bits as the sequence number (see `cyclic::command_msg`).
//
// Status: this layout has not yet been run on an arm by this project. The first use on an arm
// is guarded by the entry check (`cyclic::EntryHold`): the bridge holds the measured position
// for `entry_hold_ms` and stops if any joint moves further than `entry_hold_tolerance_rad`.
// ---------------------------------------------------------------------------------------------

/// `BaseCyclic.Refresh` request: one command per actuator (the interconnect command, field 3,
/// is not sent: the bridge does not command the gripper in low-level mode).
#[derive(Clone, PartialEq, prost::Message)]
pub struct Command {
    /// Frame counter of the cyclic command.
    #[prost(fixed32, tag = "1")]
    pub frame_id: u32,
    /// One entry per actuator, in joint order.
    #[prost(message, repeated, tag = "2")]
    pub actuators: Vec<ActuatorCommand>,
}

/// One actuator's cyclic command (layout: see above).
#[derive(Clone, PartialEq, prost::Message)]
pub struct ActuatorCommand {
    /// Id of the command (echoed in [`ActuatorFeedback::command_id`]).
    #[prost(fixed32, tag = "1")]
    pub command_id: u32,
    /// Flags (0: none; the bridge sets none).
    #[prost(fixed32, tag = "2")]
    pub flags: u32,
    /// Position target (deg, in [0, 360)).
    #[prost(float, tag = "3")]
    pub position: f32,
    /// Velocity (deg/s; 0: the bridge commands positions only).
    #[prost(float, tag = "4")]
    pub velocity: f32,
    /// Joint torque (N·m; 0: not used in position servoing, left out of the encoding).
    #[prost(float, tag = "5")]
    pub torque_joint: f32,
    /// Motor current (A; 0: not used in position servoing, left out of the encoding).
    #[prost(float, tag = "6")]
    pub current_motor: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn create_session_info_debug_hides_the_credentials() {
        let info = CreateSessionInfo {
            username: "operator-name".into(),
            session_inactivity_timeout: 60_000,
            password: "hunter2-secret".into(),
            connection_inactivity_timeout: 200,
        };
        let text = format!("{info:?} {info:#?}");
        assert!(
            !text.contains("operator-name") && !text.contains("hunter2"),
            "{text}"
        );
        assert!(text.contains("60000") && text.contains("200"), "{text}");
    }

    /// The cyclic command's bytes, worked out by hand from the field numbers and wire types
    /// above: a change of layout must change this test too.
    #[test]
    fn cyclic_command_encoding() {
        use prost::Message as _;
        let m = Command {
            frame_id: 7,
            actuators: vec![
                ActuatorCommand {
                    command_id: 7,
                    flags: 0,
                    position: 90.0,
                    velocity: 0.0,
                    torque_joint: 0.0,
                    current_motor: 0.0,
                },
                ActuatorCommand {
                    command_id: 7,
                    flags: 1,
                    position: 1.5,
                    velocity: -2.0,
                    torque_joint: 0.0,
                    current_motor: 0.0,
                },
            ],
        };
        let expected: Vec<u8> = [
            // frame_id: field 1, fixed32 (tag byte 0x0d), 7 little-endian.
            &[0x0d, 0x07, 0x00, 0x00, 0x00][..],
            // actuators[0]: field 2, length-delimited (0x12), 10 bytes.
            &[0x12, 0x0a],
            &[0x0d, 0x07, 0x00, 0x00, 0x00], // command_id: field 1, fixed32
            &[0x1d, 0x00, 0x00, 0xb4, 0x42], // position: field 3, float 90.0
            // actuators[1]: 20 bytes.
            &[0x12, 0x14],
            &[0x0d, 0x07, 0x00, 0x00, 0x00], // command_id
            &[0x15, 0x01, 0x00, 0x00, 0x00], // flags: field 2, fixed32
            &[0x1d, 0x00, 0x00, 0xc0, 0x3f], // position 1.5
            &[0x25, 0x00, 0x00, 0x00, 0xc0], // velocity: field 4, float -2.0
        ]
        .concat();
        assert_eq!(m.encode_to_vec(), expected);
        let t = ActuatorCommand {
            torque_joint: 1.0,
            current_motor: 2.0,
            ..Default::default()
        };
        // torque_joint: field 5 (0x2d), current_motor: field 6 (0x35), both float.
        assert_eq!(
            t.encode_to_vec(),
            [0x2d, 0x00, 0x00, 0x80, 0x3f, 0x35, 0x00, 0x00, 0x00, 0x40]
        );
    }
}
