//! Any bytes as a ROS 2 `sensor_msgs/msg/Joy` in CDR (the gateway's `/joy`): a message or an
//! error, never a panic nor an allocation beyond the payload's bound.
#![no_main]

use libfuzzer_sys::fuzz_target;

#[path = "../../net/src/ros2.rs"]
#[allow(dead_code)]
mod ros2;

fuzz_target!(|data: &[u8]| {
    let _ = ros2::decode_joy(data);
});
