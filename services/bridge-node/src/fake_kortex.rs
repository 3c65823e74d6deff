//! `scl fake-kortex`: a fake Kinova arm (the Gen3 lite, or the arm of the robot profile
//! `--robot` names) speaking the Kortex protocol on 127.0.0.1, for trying the bridge without
//! an arm ([`hw_bridge::kortex::FakeKortex`]). It accepts the robot's
//! default credentials (admin / admin), simulates the arm, and stops it when the bridge's
//! connection inactivity timeout passes without a frame. It also serves the low-level cyclic
//! channel over UDP on the same port number (`[bridge.kortex] mode = "low-level"`,
//! `cyclic_port` = that port), and faults the arm when no cyclic command arrives in time. With
//! a misread (`--misread-cyclic`) it reads the cyclic command wrongly, for trying the bridge's
//! low-level entry check.
//!
//! Several sessions may be open at once (the bridge's and observing ones, such as Kinova's own
//! tools reading the arm); what it serves and what it does not is listed in
//! [`hw_bridge::kortex::fake`] and in `scl fake-kortex --help`.

use std::io::Write;
use std::time::Duration;

use hw_bridge::kortex::{FakeConfig, FakeKortex};

use crate::BridgeNodeError;
use transport::signals;

/// Runs the fake robot of `cfg` (its arm [`FakeConfig::robot`], on `127.0.0.1:cfg.port`, 0: a
/// free port) until SIGINT / SIGTERM, reading the cyclic command wrongly if
/// `cfg.cyclic_misread` says how. The first line on stdout is `listening on 127.0.0.1:PORT`.
pub fn run(cfg: FakeConfig) -> Result<(), BridgeNodeError> {
    let robot = cfg.robot;
    let misread = cfg.cyclic_misread;
    let fake = FakeKortex::start(cfg)?;
    let mut out = std::io::stdout();
    let _ = writeln!(out, "listening on {}", fake.addr());
    let _ = out.flush();
    eprintln!(
        "scl fake-kortex: a fake {desc} (robot profile {name}, {n} actuators) on {addr} (user \
         admin, password admin). Try, with [graph] robot = \"{name}\":\n  \
         SCL_KORTEX_USER=admin SCL_KORTEX_PASSWORD=admin scl bridge --robot kortex \
         --address 127.0.0.1 --port {port}",
        desc = robot.description(),
        name = robot.name(),
        n = robot.n_joints(),
        addr = fake.addr(),
        port = fake.addr().port()
    );
    eprintln!(
        "scl fake-kortex: up to {} sessions at once (observing ones beside the bridge's); \
         calls it does not serve are answered with an error naming them (see --help)",
        hw_bridge::kortex::fake::MAX_SESSIONS
    );
    eprintln!(
        "scl fake-kortex: low-level cyclic channel on udp {} ([bridge.kortex] mode = \"low-level\", \
         cyclic_port = {})",
        fake.cyclic_addr(),
        fake.cyclic_addr().port()
    );
    if let Some(m) = misread {
        eprintln!(
            "scl fake-kortex: misreading the cyclic command ({m:?}): the bridge's low-level entry \
             check should stop the arm"
        );
    }
    let mut last = fake.snapshot().stats;
    while !signals::stop_requested() {
        std::thread::sleep(Duration::from_millis(50));
        let s = fake.snapshot();
        if s.stats.joint_speed_commands / 400 != last.joint_speed_commands / 400 {
            tracing::info!(
                joint_speed_commands = s.stats.joint_speed_commands,
                q_rad = ?s.q_rad,
                gripper = s.gripper,
                "fake Kortex arm"
            );
        }
        last = s.stats;
    }
    let s = fake.snapshot();
    tracing::info!(
        frames = s.stats.frames,
        sessions = s.stats.sessions_opened,
        refreshes = s.stats.refreshes,
        cyclic_timeouts = s.stats.cyclic_timeouts,
        connection_timeouts = s.stats.connection_timeouts,
        "fake Kortex robot stopping"
    );
    fake.shutdown();
    Ok(())
}
