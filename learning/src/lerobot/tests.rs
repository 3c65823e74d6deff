//! Round trip: a recording exported to LeRobot and read back by `scl train --data` gives
//! the tuples `scl dataset` gives, and the same model bit for bit.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use ipc_types::{RobotState, state_flags};
use kinematics::RobotProfile;
use recording::{LogWriter, Payload, Topic};

use super::import::{ImportOptions, load_training_data};
use crate::to_dataset::{self, Options};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("scl-lerobot-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// 40 Hz states of a 6-joint arm moving in waves, with a miss, a gap, a safety stop and a
/// rest, written as a recording.
fn recording(dir: &Path, name: &str, phase: f64) -> PathBuf {
    let path = dir.join(name);
    let mut states = Vec::new();
    let mut q = [0.0f64; 6];
    for k in 0..900u64 {
        if (300..305).contains(&k) {
            continue; // ticks not recorded
        }
        let mut s = RobotState::at_rest(k, 5_000_000_000 + k * 25_000_000 + (k % 3) * 1_000, 6);
        s.applied_tick = k.wrapping_sub(1);
        let resting = (500..600).contains(&k);
        for j in 0..6 {
            let v = if resting {
                0.0
            } else {
                0.3 * ((k as f64) * 0.01 * (j + 1) as f64 + phase).sin()
            };
            q[j] += v * 0.025;
            s.q_rad[j] = q[j];
            s.qdot_rad_s[j] = v;
        }
        s.gripper = (0.5 + 0.5 * (k as f64 * 0.003 + phase).sin()).clamp(0.0, 1.0);
        if k == 100 {
            s.flags |= state_flags::MISSED;
        }
        if (700..710).contains(&k) {
            s.flags |= state_flags::SAFETY_STOP;
        }
        states.push(s);
    }
    let file = std::fs::File::create(&path).unwrap();
    let mut w = LogWriter::new(std::io::BufWriter::new(file), &path, None).unwrap();
    w.add_topic(Topic::RobotState, &BTreeMap::new()).unwrap();
    for s in states {
        w.write(&Payload::RobotState(s)).unwrap();
    }
    w.finish(None).unwrap();
    path
}

#[test]
fn export_then_import_gives_scl_datasets_tuples_and_model() {
    let dir = tmp("roundtrip");
    let recs = vec![
        recording(&dir, "a.mcap", 0.0),
        recording(&dir, "b.mcap", 1.0),
    ];
    // scl dataset, CSV.
    let csv = dir.join("csv");
    to_dataset::convert(&recs, &csv, &Options::DEFAULT).unwrap();
    let via_csv = crate::dataset::load_dir(&csv).unwrap();
    // scl dataset --format lerobot, then scl train --data reads it.
    let lr = dir.join("lerobot");
    let report = to_dataset::export_lerobot(&recs, &lr, "gen3_lite", "wave").unwrap();
    assert_eq!(report.episodes, 2);
    assert_eq!(report.frames, 2 * 895, "every recorded tick is a frame");
    // Per recording: the tuple into the miss (tick 99), the gap's edge (299), the tuples
    // into the stop (699..=708), the last frame.
    assert_eq!(report.flagged, 2 * (1 + 1 + 10 + 1));
    let via_lr = load_training_data(&lr, &ImportOptions::default()).unwrap();
    assert!(via_csv.n_train() > 1000, "{}", via_csv.n_train());
    assert_eq!(via_lr, via_csv, "same trajectories, tuples and hash");

    // The same model bit for bit.
    let train = |data: &Path, out: &Path| {
        crate::tools::train_pca(&crate::tools::TrainOptions {
            data,
            out,
            latent_dim: 2,
            speed_scale: None,
            force: false,
            command: "scl train --kind pca".into(),
            lerobot: ImportOptions::default(),
        })
        .unwrap();
        std::fs::read(out).unwrap()
    };
    assert_eq!(
        train(&csv, &dir.join("csv.safetensors")),
        train(&lr, &dir.join("lr.safetensors"))
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn another_arms_dataset_is_refused_naming_both() {
    let dir = tmp("mismatch");
    let rec = recording(&dir, "a.mcap", 0.0);
    let lr = dir.join("lerobot");
    to_dataset::export_lerobot(std::slice::from_ref(&rec), &lr, "gen3_lite", "wave").unwrap();
    // Its robot_type is gen3_lite, so it trains for that arm without --robot.
    assert!(load_training_data(&lr, &ImportOptions::default()).is_ok());
    let e = load_training_data(
        &lr,
        &ImportOptions {
            robot: Some("gen3".into()),
            state_columns: None,
        },
    )
    .unwrap_err()
    .to_string();
    let gen3 = RobotProfile::by_name("gen3").unwrap();
    assert!(
        e.contains("profile gen3 ") && e.contains("observation.state has 7 columns"),
        "{e}"
    );
    assert!(
        e.contains(&format!("has {} joints", gen3.n_joints())),
        "{e}"
    );
    // The export refuses a recording of another arm, and an --out with files in it.
    let e = to_dataset::export_lerobot(std::slice::from_ref(&rec), &dir.join("x"), "gen3", "t")
        .unwrap_err()
        .to_string();
    assert!(e.contains("has 6 joints, but robot profile gen3 "), "{e}");
    let e = to_dataset::export_lerobot(&[rec], &lr, "gen3_lite", "t")
        .unwrap_err()
        .to_string();
    assert!(e.contains("already exists"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
