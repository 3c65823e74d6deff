//! How long `scl dataset --format lerobot` takes on one hour of 40 Hz robot states
//! (144 000 ticks of a 6-joint arm, written as a recording first):
//! `cargo run --release -p learning --example lerobot_export_hour [DIR]`.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use ipc_types::RobotState;
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
    w.add_topic(Topic::RobotState, &BTreeMap::new())?;
    for k in 0..ticks {
        let mut s = RobotState::at_rest(k, 1_000_000_000 + k * 25_000_000, 6);
        for j in 0..6 {
            s.qdot_rad_s[j] = 0.3 * (k as f64 * 0.01 * (j + 1) as f64).sin();
            s.q_rad[j] = (k as f64 * 0.01 * (j + 1) as f64).cos();
        }
        s.gripper = 0.5 + 0.5 * (k as f64 * 0.003).sin();
        w.write(&Payload::RobotState(s))?;
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
