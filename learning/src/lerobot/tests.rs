//! Round trip: a recording exported to LeRobot and read back by `scl train --data` gives
//! the tuples `scl dataset` gives, and the same model bit for bit.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use ipc_types::{MapperCommand, NodeRole, NodeStatus, RobotState, SafeCommand, state_flags};
use kinematics::RobotProfile;
use recording::{LogWriter, Payload, Topic};

use super::import::{ImportOptions, load_training_data};
use super::run;
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
    let report = to_dataset::export_lerobot(&recs, &lr, "gen3_lite", Some("wave")).unwrap();
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
    to_dataset::export_lerobot(std::slice::from_ref(&rec), &lr, "gen3_lite", Some("wave")).unwrap();
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
    let e = to_dataset::export_lerobot(
        std::slice::from_ref(&rec),
        &dir.join("x"),
        "gen3",
        Some("t"),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("has 6 joints, but robot profile gen3 "), "{e}");
    let e = to_dataset::export_lerobot(&[rec], &lr, "gen3_lite", Some("t"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("already exists"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A mapper command for `tick` from mapper `id` with stick `action`.
fn mapper_command(tick: u64, id: u32, action: [f32; 2]) -> MapperCommand {
    MapperCommand {
        tick,
        t_ns: 5_000_000_000 + tick * 25_000_000 + 1_000,
        state_t_ns: 0,
        state_rx_ns: 0,
        joystick_t_ns: 0,
        joystick_rx_ns: 0,
        joystick_seq: 0,
        compute_ns: 0,
        mapper_id: id,
        n_joints: 6,
        flags: 0,
        buttons: 0,
        action,
        qdot_rad_s: [0.0; ipc_types::MAX_JOINTS],
        gripper_rate: 0.0,
    }
}

/// A recording of a mode-switching run's operator side, as `scl up --record` writes one:
/// 40 ticks of states; mapper 1's commands (stick `(k/100, -k/50)`), heartbeats (mode 1,
/// then 2 from tick 20, heartbeats only every other tick) and process record with its model
/// embedded; safety's commands (flags `k`) forwarding mapper 1, while a second mapper's
/// commands (never forwarded) are recorded too. Tick 10 has no mapper command, tick 11 no
/// safe command, tick 12 neither; ticks 30..33 are not recorded at all. `trial`: a study
/// attempt's `scl.trial` record.
fn operator_recording(
    dir: &Path,
    name: &str,
    model: &[u8],
    trial: Option<BTreeMap<String, String>>,
) -> PathBuf {
    let path = dir.join(name);
    let file = std::fs::File::create(&path).unwrap();
    let mut w = LogWriter::new(std::io::BufWriter::new(file), &path, None).unwrap();
    if let Some(t) = trial {
        w.write_metadata(&recording::metadata(run::TRIAL_METADATA, t))
            .unwrap();
    }
    for t in [
        Topic::RobotState,
        Topic::MapperCommand,
        Topic::SafeCommand,
        Topic::Status,
    ] {
        w.add_topic(t, &BTreeMap::new()).unwrap();
    }
    w.attach(
        "model/mapper-1/77/m.safetensors",
        1,
        "application/octet-stream",
        model,
    )
    .unwrap();
    let process = BTreeMap::from([
        ("role".to_owned(), "mapper".to_owned()),
        ("mapper_id".to_owned(), "1".to_owned()),
        (
            "model_attachment".to_owned(),
            "model/mapper-1/77/m.safetensors".to_owned(),
        ),
        ("model_sha256".to_owned(), recording::sha256_hex(model)),
    ]);
    w.write_metadata(&recording::metadata(recording::PROCESS_METADATA, process))
        .unwrap();
    // The ready heartbeat answers no tick: it does not count.
    let mut ready = NodeStatus::new(NodeRole::Mapper, ipc_types::phase::READY, 1);
    ready.mapper_id = 1;
    ready.mode = 3;
    w.write(&Payload::Status(ready)).unwrap();
    for k in 0..40u64 {
        if (30..33).contains(&k) {
            continue;
        }
        let t = 5_000_000_000 + k * 25_000_000;
        let mut s = RobotState::at_rest(k, t, 6);
        s.q_rad[0] = 0.01 * k as f64;
        w.write(&Payload::RobotState(s)).unwrap();
        if k != 10 && k != 12 {
            let a = [k as f32 / 100.0, -(k as f32) / 50.0];
            w.write(&Payload::MapperCommand(mapper_command(k, 1, a)))
                .unwrap();
        }
        w.write(&Payload::MapperCommand(mapper_command(k, 2, [0.9, 0.9])))
            .unwrap();
        if k != 11 && k != 12 {
            let safe = SafeCommand {
                tick: k,
                t_ns: t + 2_000,
                mapper_id: 1,
                n_joints: 6,
                flags: k as u32,
                ..SafeCommand::zeroed()
            };
            w.write(&Payload::SafeCommand(safe)).unwrap();
        }
        if k % 2 == 1 {
            let mut st = NodeStatus::new(NodeRole::Mapper, ipc_types::phase::RUNNING, t + 3_000);
            st.tick = k;
            st.mapper_id = 1;
            st.mode = if k < 20 { 1 } else { 2 };
            w.write(&Payload::Status(st)).unwrap();
        }
    }
    w.finish(None).unwrap();
    path
}

/// The rows of parquet file `path`.
fn read_parquet(path: &Path) -> Vec<arrow_array::RecordBatch> {
    let f = std::fs::File::open(path).unwrap();
    parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(f)
        .unwrap()
        .build()
        .unwrap()
        .map(Result::unwrap)
        .collect()
}

fn int_column(b: &arrow_array::RecordBatch, name: &str) -> Vec<i64> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::Int64Array>()
        .unwrap()
        .values()
        .to_vec()
}

fn string_column(b: &arrow_array::RecordBatch, name: &str) -> Vec<String> {
    let a = b
        .column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::StringArray>()
        .unwrap();
    (0..arrow_array::Array::len(a))
        .map(|i| a.value(i).to_owned())
        .collect()
}

/// A list column of float64 (`observation.state`, `action`, `scl.stick`), its frames' values
/// one after the other.
fn list_column(b: &arrow_array::RecordBatch, name: &str) -> Vec<f64> {
    b.column_by_name(name)
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::FixedSizeListArray>()
        .unwrap()
        .values()
        .as_any()
        .downcast_ref::<arrow_array::Float64Array>()
        .unwrap()
        .values()
        .to_vec()
}

fn stick_column(b: &arrow_array::RecordBatch) -> Vec<[f64; 2]> {
    let l = b
        .column_by_name(super::column::STICK)
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::FixedSizeListArray>()
        .unwrap();
    assert_eq!(l.value_length(), 2);
    list_column(b, super::column::STICK)
        .chunks_exact(2)
        .map(|c| [c[0], c[1]])
        .collect()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

#[test]
fn the_operators_side_is_exported_per_frame_with_fills_where_nothing_was_recorded() {
    let dir = tmp("operator");
    let model = mapper::model::bundled(RobotProfile::default_robot()).unwrap();
    let rec = operator_recording(&dir, "op.mcap", model, None);
    let lr = dir.join("lerobot");
    let r = to_dataset::export_lerobot(&[rec], &lr, "gen3_lite", None).unwrap();
    assert_eq!(r.frames, 37);
    let data = read_parquet(&lr.join(super::DATA_PATH));
    let b = &data[0];
    let ticks = int_column(b, super::column::TICK);
    let stick = stick_column(b);
    let mode = int_column(b, super::column::MODE);
    let flags = int_column(b, super::column::SAFETY_FLAGS);
    assert_eq!(ticks.len(), 37);
    for (i, &k) in ticks.iter().enumerate() {
        let k = k as u64;
        // Mapper 1's stick, never mapper 2's (safety did not forward it).
        let want_stick = if k == 10 || k == 12 {
            [0.0, 0.0]
        } else {
            [f64::from(k as f32 / 100.0), f64::from(-(k as f32) / 50.0)]
        };
        assert_eq!(stick[i], want_stick, "tick {k}");
        // Heartbeats on odd ticks: tick 0 has none at or before it.
        let want_mode = match k {
            0 => -1,
            1..=20 => 1,
            _ => 2,
        };
        assert_eq!(mode[i], want_mode, "tick {k}");
        let want_flags = if k == 11 || k == 12 { 0 } else { k as i64 };
        assert_eq!(flags[i], want_flags, "tick {k}");
    }
    // Declared as the other scl. features are, with stats.
    let info = json(&lr.join(super::INFO_PATH));
    let f = &info["features"];
    assert_eq!(
        f[super::column::STICK],
        serde_json::json!({"dtype": "float64", "shape": [2], "names": ["x", "y"]})
    );
    assert_eq!(f[super::column::MODE], f[super::column::STATE_FLAGS]);
    assert_eq!(f[super::column::SAFETY_FLAGS], f[super::column::TICK]);
    let stats = json(&lr.join(super::STATS_PATH));
    assert_eq!(stats[super::column::MODE]["min"], serde_json::json!([-1.0]));
    assert_eq!(
        stats[super::column::SAFETY_FLAGS]["max"],
        serde_json::json!([39.0])
    );
    assert_eq!(
        stats[super::column::STICK]["count"],
        serde_json::json!([37])
    );
    assert_eq!(
        stats[super::column::STICK]["max"],
        serde_json::json!([f64::from(39.0f32 / 100.0), 0.0])
    );
    // The episode names the served map and its file's digest; the default task.
    let ep = &read_parquet(&lr.join(super::EPISODES_PATH))[0];
    let kind = mapper::model::read_header(model, Path::new("bundled"))
        .unwrap()
        .kind
        .to_string();
    assert_eq!(string_column(ep, super::column::MAP_KIND), vec![kind]);
    assert_eq!(
        string_column(ep, super::column::MODEL_SHA256),
        vec![recording::sha256_hex(model)]
    );
    assert_eq!(string_column(ep, super::column::SOURCE), vec!["op"]);
    let tasks = read_parquet(&lr.join(super::TASKS_PATH));
    assert_eq!(
        string_column(&tasks[0], "__index_level_0__"),
        vec![to_dataset::DEFAULT_TASK]
    );
    // The import still reads it.
    assert!(load_training_data(&lr, &ImportOptions::default()).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recording_without_an_operator_side_gets_the_fills_and_empty_model_columns() {
    let dir = tmp("no-operator");
    let rec = recording(&dir, "states.mcap", 0.0);
    let lr = dir.join("lerobot");
    to_dataset::export_lerobot(&[rec], &lr, "gen3_lite", Some("wave")).unwrap();
    let b = &read_parquet(&lr.join(super::DATA_PATH))[0];
    assert!(stick_column(b).iter().all(|s| *s == [0.0, 0.0]));
    assert!(int_column(b, super::column::MODE).iter().all(|m| *m == -1));
    assert!(
        int_column(b, super::column::SAFETY_FLAGS)
            .iter()
            .all(|f| *f == 0)
    );
    let ep = &read_parquet(&lr.join(super::EPISODES_PATH))[0];
    assert_eq!(string_column(ep, super::column::MAP_KIND), vec![""]);
    assert_eq!(string_column(ep, super::column::MODEL_SHA256), vec![""]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_study_attempt_is_an_episode_of_its_study_task() {
    let dir = tmp("study");
    let model = mapper::model::bundled(RobotProfile::default_robot()).unwrap();
    let trial = |task: &str, goals: Option<&str>| {
        let mut t = BTreeMap::from([
            ("attempt".to_owned(), "P01-t1-c1-a1".to_owned()),
            ("task".to_owned(), task.to_owned()),
        ]);
        if let Some(g) = goals {
            t.insert("goals".to_owned(), g.to_owned());
        }
        Some(t)
    };
    let recs = vec![
        operator_recording(&dir, "a.mcap", model, trial("pick-and-place", None)),
        operator_recording(&dir, "b.mcap", model, trial("pour-it", Some("pouring"))),
        operator_recording(&dir, "c.mcap", model, trial("free-play", None)),
        operator_recording(&dir, "d.mcap", model, None),
    ];
    let lr = dir.join("lerobot");
    to_dataset::export_lerobot(&recs, &lr, "gen3_lite", None).unwrap();
    let pick = format!(
        "pick-and-place: {}",
        crate::tasks::Task::PickAndPlace.instructions()
    );
    let pour = format!("pour-it: {}", crate::tasks::Task::Pouring.instructions());
    let ep = &read_parquet(&lr.join(super::EPISODES_PATH))[0];
    let tasks = ep
        .column_by_name("tasks")
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::ListArray>()
        .unwrap()
        .iter()
        .map(|l| {
            let l = l.unwrap();
            let s = l
                .as_any()
                .downcast_ref::<arrow_array::StringArray>()
                .unwrap();
            s.value(0).to_owned()
        })
        .collect::<Vec<_>>();
    assert_eq!(
        tasks,
        vec![
            pick.clone(),
            pour.clone(),
            "free-play".to_owned(),
            to_dataset::DEFAULT_TASK.to_owned()
        ]
    );
    let t = &read_parquet(&lr.join(super::TASKS_PATH))[0];
    assert_eq!(
        string_column(t, "__index_level_0__"),
        vec![
            pick,
            pour,
            "free-play".to_owned(),
            "teleoperation".to_owned()
        ]
    );
    let info = json(&lr.join(super::INFO_PATH));
    assert_eq!(info["total_tasks"], 4);
    // A simulated attempt recorded before its scl.trial named the task: from the
    // participant's trials.csv (the row naming the file).
    let p01 = dir.join("P01");
    std::fs::create_dir_all(p01.join("recordings")).unwrap();
    let old = operator_recording(
        &p01.join("recordings"),
        "P01-t2-c1-a1.mcap",
        model,
        Some(BTreeMap::from([(
            "attempt".to_owned(),
            "P01-t2-c1-a1".to_owned(),
        )])),
    );
    std::fs::write(
        p01.join("trials.csv"),
        "study,participant,task,label,recording\n\
         s,P01,table-cleaning,A,recordings/P01-t1-c1-a1.mcap\n\
         s,P01,pouring,A,recordings/P01-t2-c1-a1.mcap\n",
    )
    .unwrap();
    let lr3 = dir.join("lerobot3");
    to_dataset::export_lerobot(&[old], &lr3, "gen3_lite", None).unwrap();
    let t = &read_parquet(&lr3.join(super::TASKS_PATH))[0];
    assert_eq!(
        string_column(t, "__index_level_0__"),
        vec![format!(
            "pouring: {}",
            crate::tasks::Task::Pouring.instructions()
        )]
    );
    // --task names every episode's.
    let lr2 = dir.join("lerobot2");
    to_dataset::export_lerobot(&recs[..1], &lr2, "gen3_lite", Some("given")).unwrap();
    let t = &read_parquet(&lr2.join(super::TASKS_PATH))[0];
    assert_eq!(string_column(t, "__index_level_0__"), vec!["given"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn scl_demos_output_exports_one_episode_per_trajectory_of_its_task() {
    let dir = tmp("demos");
    let demos = dir.join("reach");
    let ds = crate::tools::demos(
        "joint-reach",
        RobotProfile::default_robot(),
        &demos,
        3,
        (Some(2), Some(1)),
        None,
    )
    .unwrap();
    let lr = dir.join("lerobot");
    let r =
        to_dataset::export_lerobot(std::slice::from_ref(&demos), &lr, "gen3_lite", None).unwrap();
    assert_eq!(r.episodes, 3);
    let n: usize = ds.train.iter().chain(&ds.val).map(|t| t.len()).sum();
    assert_eq!(r.frames, n);
    assert_eq!(r.flagged, 0, "every tuple is a demonstration");
    let b = &read_parquet(&lr.join(super::DATA_PATH))[0];
    let state = list_column(b, super::column::STATE);
    let action = list_column(b, super::column::ACTION);
    // The values as the CSV files hold them.
    let on_disk = crate::dataset::load_dir(&demos).unwrap();
    let t0 = &on_disk.train[0];
    for k in 0..t0.len() {
        let mut s = t0.q[k].clone();
        s.push(t0.c[k]);
        assert_eq!(state[k * 7..k * 7 + 7], s[..], "tuple {k}");
        let mut a = t0.qdot[k].clone();
        a.push(t0.cdot[k]);
        assert_eq!(action[k * 7..k * 7 + 7], a[..], "tuple {k}");
    }
    assert!(int_column(b, super::column::MODE).iter().all(|m| *m == -1));
    let ep = &read_parquet(&lr.join(super::EPISODES_PATH))[0];
    assert_eq!(
        string_column(ep, super::column::SOURCE),
        vec![
            format!("reach/train/{}", ds.train[0].name),
            format!("reach/train/{}", ds.train[1].name),
            format!("reach/val/{}", ds.val[0].name),
        ]
    );
    let t = &read_parquet(&lr.join(super::TASKS_PATH))[0];
    assert_eq!(string_column(t, "__index_level_0__"), vec!["joint-reach"]);
    // A set of the paper's tasks gets its instructions; the description is never written
    // over.
    let e = crate::tools::demos(
        "joint-reach",
        RobotProfile::default_robot(),
        &demos,
        3,
        (Some(2), Some(1)),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("demos.json") && e.contains("already exists"),
        "{e}"
    );
    let meta = crate::demos::DemosMeta {
        task: "pouring".into(),
        robot: "gen3_lite".into(),
        seed: 1,
    };
    let other = dir.join("pour");
    crate::dataset::write_dir(&other, &ds).unwrap();
    meta.write(&other).unwrap();
    let lr3 = dir.join("lerobot3");
    to_dataset::export_lerobot(&[other], &lr3, "gen3_lite", None).unwrap();
    let t = &read_parquet(&lr3.join(super::TASKS_PATH))[0];
    assert_eq!(
        string_column(t, "__index_level_0__"),
        vec![format!(
            "pouring: {}",
            crate::tasks::Task::Pouring.instructions()
        )]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_recording_cut_into_trajectories_is_an_episode_per_trajectory_of_scl_dataset() {
    let dir = tmp("trajectories");
    let rec = recording(&dir, "a.mcap", 0.0);
    let (states, _) = to_dataset::robot_states(&rec).unwrap();
    let (trajs, _) = to_dataset::trajectories(&states, "a", &Options::DEFAULT);
    assert!(trajs.len() >= 3, "{}", trajs.len());
    let lr = dir.join("lerobot");
    let r = to_dataset::export_lerobot_with(
        std::slice::from_ref(&rec),
        &lr,
        "gen3_lite",
        Some("wave"),
        to_dataset::Episodes::Trajectory(Options::DEFAULT),
    )
    .unwrap();
    assert_eq!(r.episodes, trajs.len());
    assert_eq!(r.frames, trajs.iter().map(|t| t.len()).sum::<usize>());
    assert_eq!(r.flagged, 0, "every frame is a demonstration tuple");
    let b = &read_parquet(&lr.join(super::DATA_PATH))[0];
    let ticks = int_column(b, super::column::TICK);
    let t_ns = int_column(b, super::column::T_NS);
    let state = list_column(b, super::column::STATE);
    // Frame by frame the CSV trajectories' tuples, at the recording's own ticks and times.
    let by_tick: BTreeMap<u64, &RobotState> = states.iter().map(|s| (s.tick, s)).collect();
    let mut f = 0;
    for t in &trajs {
        let first: u64 = t
            .name
            .rsplit("tick")
            .next()
            .unwrap()
            .trim_end_matches(".csv")
            .parse()
            .unwrap();
        for k in 0..t.len() {
            let tick = first + k as u64;
            assert_eq!(ticks[f], tick as i64, "{} tuple {k}", t.name);
            assert_eq!(t_ns[f], by_tick[&tick].t_ns as i64, "{} tuple {k}", t.name);
            let mut s = t.q[k].clone();
            s.push(t.c[k]);
            assert_eq!(state[f * 7..f * 7 + 7], s[..], "{} tuple {k}", t.name);
            f += 1;
        }
    }
    let ep = &read_parquet(&lr.join(super::EPISODES_PATH))[0];
    let names: Vec<String> = trajs
        .iter()
        .map(|t| t.name.trim_end_matches(".csv").to_owned())
        .collect();
    assert_eq!(string_column(ep, super::column::SOURCE), names);
    let _ = std::fs::remove_dir_all(&dir);
}
