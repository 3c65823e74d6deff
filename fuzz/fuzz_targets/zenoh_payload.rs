//! Any bytes, under any encoding, as the gateway's Zenoh payloads: read only at the type's
//! encoding and exact size (and then the same bytes), else an error; never a panic.
#![no_main]

use ipc_types::control::{EstopCommand, SafetyControl};
use ipc_types::{JoystickInput, NodeStatus, RobotState};
use libfuzzer_sys::fuzz_target;

#[path = "../../net/src/wire.rs"]
#[allow(dead_code)]
mod wire;

fn check<T: wire::Wire>(bytes: &[u8], encoding: &str) {
    if let Ok(m) = wire::decode::<T>(bytes, encoding) {
        assert_eq!(encoding, wire::encoding_of::<T>());
        assert_eq!(wire::encode(&m), bytes);
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((pick, bytes)) = data.split_first() else {
        return;
    };
    let encodings = [
        wire::encoding_of::<JoystickInput>(),
        wire::encoding_of::<RobotState>(),
        wire::encoding_of::<EstopCommand>(),
        wire::encoding_of::<SafetyControl>(),
        wire::encoding_of::<NodeStatus>(),
    ];
    let e = &encodings[usize::from(*pick) % encodings.len()];
    check::<JoystickInput>(bytes, e);
    check::<RobotState>(bytes, e);
    check::<EstopCommand>(bytes, e);
    check::<SafetyControl>(bytes, e);
    check::<NodeStatus>(bytes, e);
});
