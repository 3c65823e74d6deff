//! A recording made in memory by the real steps (the bundled model, the default filter, an
//! e-stop and its reset, a hold) replays bit for bit; the same recording with one weight of
//! its embedded model changed diverges at the first tick the map moves, in the mapper.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use ipc_types::{JoystickInput, NodeRole, NodeStatus, RobotState, buttons, phase};
use recording::{LogWriter, Payload, Topic};

use super::*;

/// The default robot's bundled model (the Gen3 lite's).
fn bundled() -> &'static [u8] {
    mapper::model::bundled(kinematics::RobotProfile::default_robot()).unwrap()
}

const DT_NS: u64 = 25_000_000;

/// A file in this process's temporary directory, removed (with the directory once empty)
/// when dropped.
struct Temp(PathBuf);

impl std::ops::Deref for Temp {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Temp {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Temp {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
        if let Some(d) = self.0.parent() {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// Each file gets a directory of its own: tests run in parallel, and one removing its
/// emptied directory must not pull it from under another's file.
fn temp(name: &str) -> Temp {
    static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("scl-replay-unit-{}-{n}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    let _ = std::fs::remove_file(&p);
    Temp(p)
}

/// Runs the steps as the processes do for `ticks` ticks and records everything, with the
/// model attachment's bytes `model`.
fn make(path: &Path, ticks: u64, model: &[u8]) {
    make_as(path, ticks, model, false);
}

/// [`make`], or with `old` as a recording made before models, configurations and control
/// bits were recorded.
fn make_as(path: &Path, ticks: u64, model: &[u8], old: bool) {
    let robot = kinematics::RobotProfile::default_robot();
    let cfg = scl_config::GraphConfig::default();
    let file = recording::create_new(path).unwrap();
    let mut w = LogWriter::new(std::io::BufWriter::new(file), path, None).unwrap();
    for t in Topic::ALL {
        w.add_topic(t, &BTreeMap::new()).unwrap();
    }
    let toml = toml_text(&cfg);
    if !old {
        w.attach(
            "config/safety/200/graph.toml",
            1,
            "application/toml",
            toml.as_bytes(),
        )
        .unwrap();
        w.attach(
            "model/mapper-1/100/bundled",
            1,
            "application/octet-stream",
            model,
        )
        .unwrap();
        let meta = |pairs: &[(&str, String)]| {
            recording::metadata(
                recording::PROCESS_METADATA,
                pairs
                    .iter()
                    .map(|(k, v)| ((*k).to_owned(), v.clone()))
                    .collect(),
            )
        };
        w.write_metadata(&meta(&[
            ("role", "safety".into()),
            ("pid", "200".into()),
            ("t_ns", "1".into()),
            ("config_attachment", "config/safety/200/graph.toml".into()),
            ("config_sha256", recording::sha256_hex(toml.as_bytes())),
        ]))
        .unwrap();
        w.write_metadata(&meta(&[
            ("role", "mapper".into()),
            ("pid", "100".into()),
            ("mapper_id", "1".into()),
            ("t_ns", "1".into()),
            ("model_spec", "bundled".into()),
            ("model_attachment", "model/mapper-1/100/bundled".into()),
            ("model_sha256", recording::sha256_hex(bundled())),
        ]))
        .unwrap();
    }
    for (role, pid) in [(NodeRole::Mapper, 100), (NodeRole::Safety, 200)] {
        let mut st = NodeStatus::new(role, phase::READY, 1);
        st.pid = pid;
        st.mapper_id = 1;
        w.write(&Payload::Status(st)).unwrap();
    }
    let model = LoadedModel::load_for(mapper::model::BUNDLED_NAME, robot).unwrap();
    let mut step = MapperStep::new(1, model, 6).unwrap();
    let mut filter = SafetyFilter::for_graph(cfg.safety.clone(), robot, cfg.period_s()).unwrap();
    let home = robot.named_pose("home").map(<[f64]>::to_vec);
    let mut state = RobotState::at_rest(0, 1_000_000_000, 6);
    if let Some(h) = home {
        state.q_rad[..6].copy_from_slice(&h[..6]);
    }
    for k in 0..ticks {
        state.tick = k;
        state.t_ns = 1_000_000_000 + k * DT_NS;
        // The stick at rest for half a second (restart prevention), then circling.
        let phase = k as f32 * 0.05;
        let axes = if k < 20 {
            [0.0, 0.0]
        } else {
            [0.8 * phase.cos(), 0.8 * phase.sin()]
        };
        let joy = JoystickInput {
            tick: k.saturating_sub(1),
            t_ns: state.t_ns - 3_000_000,
            seq: k,
            axes,
            gripper: 0.0,
            buttons: if (80..82).contains(&k) {
                buttons::ESTOP
            } else {
                0
            },
        };
        w.write(&Payload::Joystick(joy)).unwrap();
        w.write(&Payload::RobotState(state)).unwrap();
        let mut cmd = step.step(&state, Some(&joy));
        cmd.state_rx_ns = state.t_ns + 10_000;
        cmd.joystick_rx_ns = joy.t_ns + 10_000;
        cmd.compute_ns = 5_000;
        cmd.t_ns = state.t_ns + 20_000;
        w.write(&Payload::MapperCommand(cmd)).unwrap();
        if k == 100 {
            filter.reset();
        }
        filter.set_hold((120..125).contains(&k));
        let now = cmd.t_ns + 7_000;
        let mut safe = filter.step(&cmd, &state, now);
        safe.mapper_rx_ns = cmd.t_ns + 3_000;
        safe.compute_ns = 9_000;
        safe.t_ns = now + safe.compute_ns;
        if old {
            safe.control = 0;
        }
        w.write(&Payload::SafeCommand(safe)).unwrap();
        // The arm does what it was told.
        for j in 0..6 {
            state.q_rad[j] += safe.qdot_rad_s[j] * 0.025;
            state.qdot_rad_s[j] = safe.qdot_rad_s[j];
        }
        state.applied_tick = k;
        // A chunk every 40 ticks, as the recorder closes one every second.
        if (k + 1) % 40 == 0 {
            w.flush().unwrap();
        }
    }
    w.finish(None).unwrap();
}

fn toml_text(cfg: &scl_config::GraphConfig) -> String {
    // The recorder writes the resolved configuration the same way.
    toml::to_string(cfg).unwrap()
}

#[test]
fn a_recording_of_the_real_steps_replays_bit_for_bit() {
    let path = temp("same.mcap");
    make(&path, 200, bundled());
    let rec = Recording::read(&path).unwrap();
    let (r, _) = replay(&rec, None).unwrap();
    assert_eq!(r.ticks, 200, "{r:?}");
    assert_eq!(r.identical, 200, "{}", render(&path, &r));
    assert_eq!(r.diverged, 0);
    assert!(r.first_divergence.is_none());
    assert_eq!(r.mapper_identical, 200);
    assert!(r.notes.is_empty(), "{:?}", r.notes);
    // The e-stop latched by the button at tick 80 and reset before tick 100, the hold at 120.
    let (_, t) = replay(&rec, Some(90)).unwrap();
    let t = t.unwrap();
    assert_ne!(t.safe_replayed.flags & safe_flags::ESTOP, 0);
    assert_ne!(t.control & safe_control::ESTOP, 0);
    let text = explain::render(&t);
    assert!(text.contains("e-stop"), "{text}");
    let (_, t) = replay(&rec, Some(121)).unwrap();
    assert_ne!(t.unwrap().control & safe_control::HOLD, 0);
    assert!(matches!(
        replay(&rec, Some(5000)),
        Err(ReplayError::NoSuchTick { tick: 5000, .. })
    ));
}

#[test]
fn an_altered_model_diverges_in_the_mapper_at_the_first_tick_it_moves() {
    let path = temp("altered.mcap");
    let altered = edit::alter_one_weight(bundled()).unwrap();
    assert_ne!(altered, bundled());
    make(&path, 60, &altered);
    let rec = Recording::read(&path).unwrap();
    let (r, _) = replay(&rec, None).unwrap();
    let d = r.first_divergence.clone().unwrap();
    assert_eq!(d.stage, "mapper");
    assert_eq!(d.mapper_id, 1);
    // The stick is at rest (zero command whatever the weights) until tick 20.
    assert_eq!(d.tick, 20, "{}", render(&path, &r));
    assert!(d.fields.iter().any(|f| f.field.starts_with("qdot_rad_s")));
    assert_eq!(r.identical, 20);
    assert!(
        r.notes.iter().any(|n| n.contains("SHA-256")),
        "{:?}",
        r.notes
    );
}

#[test]
fn a_truncated_or_foreign_file_is_a_clear_error() {
    let path = temp("whole.mcap");
    make(&path, 40, bundled());
    let bytes = std::fs::read(&path).unwrap();
    let cut = temp("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    // A cut file replays what it holds, and says so.
    if let Ok(rec) = Recording::read(&cut) {
        let (r, _) = replay(&rec, None).unwrap();
        assert!(
            r.notes.iter().any(|n| n.contains("incomplete")),
            "{:?}",
            r.notes
        );
    }
    let junk = temp("junk.mcap");
    std::fs::write(&junk, b"not an mcap file at all").unwrap();
    let e = Recording::read(&junk).unwrap_err().to_string();
    assert!(e.contains("junk.mcap") && e.contains("not an MCAP"), "{e}");
    let e = Recording::read(&temp("missing.mcap"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.mcap"), "{e}");
}

#[test]
fn the_counterfactual_with_the_recorded_model_differs_nowhere() {
    let path = temp("whatif-src.mcap");
    make(&path, 120, bundled());
    let rec = Recording::read(&path).unwrap();
    let out = temp("whatif-same.mcap");
    let what = whatif::WhatIf {
        model: Some(mapper::model::BUNDLED_NAME.into()),
        safety: None,
        closed_loop: false,
    };
    let s = whatif::run(&rec, &what, &out).unwrap();
    assert_eq!(s.ticks, 120);
    assert_eq!(s.ticks_differing, 0, "{}", whatif::render(&s));
    assert_eq!((s.first_difference, s.first_map_difference), (None, None));
    assert_eq!((s.joint_rad_s_max, s.tool_m_s_max), (0.0, 0.0));
    // Never over an existing file.
    assert!(whatif::run(&rec, &what, &out).is_err());
    // The drill map moves from the first tick the filter lets it (it ignores the stick, so
    // its output differs from the start).
    let out = temp("whatif-drill.mcap");
    let what = whatif::WhatIf {
        model: Some("constant:qdot=0,0.2,0,0,0,0".into()),
        safety: None,
        closed_loop: false,
    };
    let s = whatif::run(&rec, &what, &out).unwrap();
    assert_eq!(s.first_map_difference, Some(0), "{}", whatif::render(&s));
    assert!(s.joint_rad_s_max > 0.0);
    // The output holds the recorded commands and the what-if ones.
    let mut counts = BTreeMap::new();
    recording::read_file(&out, |ev| {
        if let Event::Message { channel, .. } = ev {
            *counts.entry(channel.topic.clone()).or_insert(0) += 1;
        }
        Ok(())
    })
    .unwrap();
    assert_eq!(counts["/safe_command"], 120);
    assert_eq!(counts["/whatif/safe_command"], 120);
    assert_eq!(counts["/whatif/mapper_command"], 120);
}

#[test]
fn the_closed_loop_counterfactual_drives_a_mock_arm() {
    let path = temp("closed-src.mcap");
    make(&path, 120, bundled());
    let rec = Recording::read(&path).unwrap();
    // The same model on a mock arm retraces the recorded run (up to the rounding of the
    // mock's integration).
    let s = whatif::run(
        &rec,
        &whatif::WhatIf {
            model: Some(mapper::model::BUNDLED_NAME.into()),
            safety: None,
            closed_loop: true,
        },
        &temp("closed-same.mcap"),
    )
    .unwrap();
    assert!(
        s.tool_position_m_max.unwrap() < 1e-9,
        "{}",
        whatif::render(&s)
    );
    // The drill map goes elsewhere.
    let s = whatif::run(
        &rec,
        &whatif::WhatIf {
            model: Some("constant:qdot=0,0.2,0,0,0,0".into()),
            safety: None,
            closed_loop: true,
        },
        &temp("closed-drill.mcap"),
    )
    .unwrap();
    assert!(
        s.tool_position_m_final.unwrap() > 0.01,
        "{}",
        whatif::render(&s)
    );
}

#[test]
fn an_older_recording_replays_what_it_can_and_says_so() {
    let path = temp("old.mcap");
    make_as(&path, 150, bundled(), true);
    let rec = Recording::read(&path).unwrap();
    let (r, _) = replay(&rec, None).unwrap();
    let notes = r.notes.join("\n");
    for want in [
        "no safety process record",
        "no process record",
        "no control bits",
    ] {
        assert!(notes.contains(want), "`{want}` not in {notes}");
    }
    // No model: the mapper is not re-executed; safety replays on the recorded commands, with
    // the defaults (what the run used) and the e-stop and hold from the flags.
    assert_eq!((r.mapper_commands, r.skipped), (0, 150));
    assert_eq!((r.ticks, r.identical), (150, 150), "{}", render(&path, &r));
}

/// The byte offsets of the chunk records of an MCAP file.
fn chunk_offsets(bytes: &[u8]) -> Vec<usize> {
    let mut at = 8;
    let mut out = Vec::new();
    while at + 9 <= bytes.len() && bytes[at] != 0x0F {
        if bytes[at] == 0x06 {
            out.push(at);
        }
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        at += 9 + len as usize;
    }
    out
}

fn args(file: &Path, partial: bool) -> ReplayArgs {
    ReplayArgs {
        file: file.to_owned(),
        json: true,
        tick: None,
        explain: false,
        model: None,
        safety: None,
        closed_loop: false,
        out: None,
        partial,
    }
}

#[test]
fn a_corrupt_chunk_in_the_middle_fails_the_replay_unless_partial() {
    let path = temp("corrupt-middle.mcap");
    make(&path, 200, bundled());
    assert_eq!(
        cli(&args(&path, false)).unwrap(),
        std::process::ExitCode::SUCCESS
    );
    let mut bytes = std::fs::read(&path).unwrap();
    let chunks = chunk_offsets(&bytes);
    assert!(chunks.len() >= 5, "{} chunks", chunks.len());
    let middle = chunks[chunks.len() / 2];
    // A byte of the compressed data (past the chunk's header): its CRC no longer matches.
    bytes[middle + 9 + 80] ^= 0x55;
    std::fs::write(&path, &bytes).unwrap();

    let e = cli(&args(&path, false)).unwrap_err();
    assert!(matches!(e, ReplayError::Incomplete { .. }), "{e}");
    let text = e.to_string();
    assert!(
        text.starts_with(&path.display().to_string())
            && text.contains(&format!("damaged record at byte {middle}"))
            && text.contains("--partial"),
        "{text}"
    );
    // Asked to, it replays what can be read, and says where reading stopped.
    assert_eq!(
        cli(&args(&path, true)).unwrap(),
        std::process::ExitCode::SUCCESS
    );
    let rec = Recording::read(&path).unwrap();
    let (r, _) = replay(&rec, None).unwrap();
    assert!(r.ticks > 0 && r.ticks < 200, "{} ticks", r.ticks);
    assert_eq!(r.diverged, 0);
    assert!(
        r.notes
            .iter()
            .any(|n| n.contains("incomplete") && n.contains(&format!("byte {middle}"))),
        "{:?}",
        r.notes
    );
}

/// The field names a diff of two messages that differ in every byte must report: every
/// field but those not replayed, arrays of floats element by element.
fn every_field_but_not_replayed<T: Fields>(skip: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    for f in T::layout().fields {
        if T::NOT_REPLAYED.contains(&f.name) || skip.contains(&f.name) {
            continue;
        }
        match f.ty.strip_prefix("[f").and_then(|t| t.split_once("; ")) {
            Some((_, n)) => {
                let n: usize = n.trim_end_matches(']').parse().unwrap();
                out.extend((0..n).map(|i| format!("{}[{i}]", f.name)));
            }
            None => out.push(f.name.to_owned()),
        }
    }
    out
}

fn names(d: &[FieldDiff]) -> Vec<String> {
    d.iter().map(|f| f.field.clone()).collect()
}

#[test]
fn every_field_is_compared_unless_declared_not_replayed() {
    use zerocopy::{FromZeros, IntoBytes};
    // Two commands that differ in every byte, every float bit pattern, every array element.
    let mut rec = MapperCommand::new_zeroed();
    let mut rep = MapperCommand::new_zeroed();
    rec.as_mut_bytes().fill(0xAA);
    rep.as_mut_bytes().fill(0x55);
    assert_eq!(
        names(&mapper_diff(&rec, &rep)),
        every_field_but_not_replayed::<MapperCommand>(&[])
    );
    assert!(mapper_diff(&rec, &rec).is_empty());

    let mut rec = SafeCommand::zeroed();
    let mut rep = SafeCommand::zeroed();
    rec.as_mut_bytes().fill(0xAA);
    rep.as_mut_bytes().fill(0x55);
    assert_ne!(rec.control & safe_control::RECORDED, 0);
    assert_eq!(
        names(&safe_diff(&rec, &rep)),
        every_field_but_not_replayed::<SafeCommand>(&[])
    );
    // `control` is compared only where the recording has it.
    rec.control &= !safe_control::RECORDED;
    assert_eq!(
        names(&safe_diff(&rec, &rep)),
        every_field_but_not_replayed::<SafeCommand>(&["control"])
    );
    assert!(safe_diff(&rec, &rec).is_empty());
    // What is not compared: the processes' own stamps and padding.
    assert_eq!(
        SafeCommand::NOT_REPLAYED,
        [
            "t_ns",
            "state_rx_ns",
            "joystick_rx_ns",
            "mapper_t_ns",
            "mapper_rx_ns",
            "mapper_compute_ns",
            "compute_ns",
            "reserved_tail"
        ]
    );
}

#[test]
fn a_diff_names_each_field_and_shows_both_values() {
    use zerocopy::FromZeros;
    let rec = MapperCommand {
        flags: 3,
        action: [1.0, 0.0],
        t_ns: 1,
        ..MapperCommand::new_zeroed()
    };
    let mut rep = MapperCommand {
        flags: 1,
        action: [0.5, 0.0],
        t_ns: 2,
        ..rec
    };
    rep.qdot_rad_s[3] = 0.25;
    let d = |field: &str, recorded: &str, replayed: &str| FieldDiff {
        field: field.to_owned(),
        recorded: recorded.to_owned(),
        replayed: replayed.to_owned(),
    };
    assert_eq!(
        mapper_diff(&rec, &rep),
        [
            d("flags", "3", "1"),
            d("action[0]", "1065353216", "1056964608"),
            d("qdot_rad_s[3]", "0.0", "0.25"),
        ]
    );
    let rec = SafeCommand {
        closest_pair: [1, 2],
        clearance_m: f64::INFINITY,
        control: 5,
        ..SafeCommand::zeroed()
    };
    let rep = SafeCommand {
        closest_pair: [1, 3],
        clearance_m: 0.5,
        control: 4,
        ..rec
    };
    assert_eq!(
        safe_diff(&rec, &rep),
        [
            d("clearance_m", "inf", "0.5"),
            d("closest_pair", "[1, 2]", "[1, 3]"),
        ]
    );
}
