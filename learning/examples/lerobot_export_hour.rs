//! How long `scl dataset --format lerobot` takes on one hour of a 40 Hz run (144 000 ticks of
//! a 6-joint arm, written as a recording first, with what `scl up --record` records per tick
//! for the export: the robot state, the mapper's command, safety's command and the mapper's
//! heartbeat): `cargo run --release -p learning --example lerobot_export_hour [DIR]`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use ipc_types::{MapperCommand, NodeRole, NodeStatus, RobotState, SafeCommand};
use recording::{LogWriter, Payload, Topic};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args().nth(1).map_or_else(
        || std::env::temp_dir().join("scl-lerobot-hour"),
        PathBuf::from,
    );
    std::fs::create_dir_all(&dir)?;
    let rec = dir.join("hour.mcap");
    let out = dir.join("hour-lerobot");
    let _ = std::fs::remove_file(&rec);
    let _ = std::fs::remove_dir_all(&out);
    let ticks = 40 * 3600u64;
    let mut w = LogWriter::new(
        std::io::BufWriter::new(std::fs::File::create(&rec)?),
        &rec,
        None,
    )?;
    for t in [
        Topic::RobotState,
        Topic::MapperCommand,
        Topic::SafeCommand,
        Topic::Status,
    ] {
        w.add_topic(t, &BTreeMap::new())?;
    }
    for k in 0..ticks {
        let t_ns = 1_000_000_000 + k * 25_000_000;
        let mut s = RobotState::at_rest(k, t_ns, 6);
        for j in 0..6 {
            s.qdot_rad_s[j] = 0.3 * (k as f64 * 0.01 * (j + 1) as f64).sin();
            s.q_rad[j] = (k as f64 * 0.01 * (j + 1) as f64).cos();
        }
        s.gripper = 0.5 + 0.5 * (k as f64 * 0.003).sin();
        w.write(&Payload::RobotState(s))?;
        let stick = [(k as f32 * 0.01).sin(), (k as f32 * 0.007).cos()];
        w.write(&Payload::MapperCommand(MapperCommand {
            tick: k,
            t_ns: t_ns + 150_000,
            state_t_ns: t_ns,
            state_rx_ns: t_ns + 20_000,
            joystick_t_ns: t_ns - 1_000_000,
            joystick_rx_ns: t_ns - 990_000,
            joystick_seq: k,
            compute_ns: 12_000,
            mapper_id: 1,
            n_joints: 6,
            flags: 0,
            buttons: 0,
            action: stick,
            qdot_rad_s: [0.0; ipc_types::MAX_JOINTS],
            gripper_rate: 0.0,
        }))?;
        w.write(&Payload::SafeCommand(SafeCommand {
            tick: k,
            t_ns: t_ns + 200_000,
            mapper_id: 1,
            n_joints: 6,
            ..SafeCommand::zeroed()
        }))?;
        let mut st = NodeStatus::new(NodeRole::Mapper, ipc_types::phase::RUNNING, t_ns + 300_000);
        st.tick = k;
        st.mapper_id = 1;
        st.mode = 1 + (k / 400 % 3) as u32;
        w.write(&Payload::Status(st))?;
    }
    w.finish(None)?;
    let t0 = Instant::now();
    let r = learning::to_dataset::export_lerobot(
        std::slice::from_ref(&rec),
        &out,
        "gen3_lite",
        Some("hour"),
    )?;
    let s = t0.elapsed().as_secs_f64();
    println!(
        "exported {} frames ({} MB recording) in {s:.2} s to {}",
        r.frames,
        std::fs::metadata(&rec)?.len() / 1_000_000,
        out.display()
    );
    Ok(())
}
