//! Whole-graph tests of deterministic replay: a 20 s run of the real graph recorded with
//! `scl up --record`, with a live swap to a model file, an e-stop and its reset, replays bit
//! for bit with `scl replay`; the same recording with one weight of its embedded model
//! changed diverges, and the report names the first tick the map moved and the mapper. The
//! run's mappers warm their maps before each tick (`[graph] rt_prewarm_us`), which must change
//! no command. Both
//! tests share the one recorded run (made once, under its own prefix, cleaned up). The
//! counterfactual runs on a second, plain run (the bundled SCL model throughout); a third run
//! has its mapper and safety processes killed and restarted by their policies.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use ipc_types::{MapperCommand, NodeRole, SafeCommand, mapper_flags, safe_flags};
use recording::Event;
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, Signal, joint_reach_pca, pulses, run_polling, scl,
    send_signal, serial, temp_dir, unique_prefix, wait_clean, write_replay,
};

/// A recorded run: its directory and file, and how many of the tests sharing it are done
/// (the last removes the directory).
struct Run {
    dir: PathBuf,
    file: PathBuf,
    done: AtomicUsize,
    users: usize,
}

impl Run {
    /// One test of the run's users is done with it; the last removes its directory.
    fn release(&self) {
        if self.done.fetch_add(1, Ordering::SeqCst) + 1 == self.users {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

fn recorded_run() -> &'static Run {
    static RUN: OnceLock<Run> = OnceLock::new();
    RUN.get_or_init(|| {
        let _serial = serial();
        let prefix = unique_prefix("replay");
        let _domain = DomainGuard(prefix.clone());
        let dir = temp_dir("replay");
        let pca = joint_reach_pca(&dir, None);
        write_replay(&dir.join("input.csv"), &pulses([0.5, 0.4], 1.2, 0.4, 20.0));
        let cfg = dir.join("graph.toml");
        std::fs::write(
            &cfg,
            // The mappers warm their maps 5 ms before each tick (`rt_prewarm_us`): the replay,
            // which never warms, must still match bit for bit.
            "[graph]\nrt_prewarm_us = 5000\n[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n",
        )
        .unwrap();
        let file = dir.join("run.mcap");
        let mut rec = Recorder::join(&prefix);
        let mut up = scl(&prefix);
        up.arg("--config")
            .arg(&cfg)
            .args(["up", "--for", "20s", "--record"])
            .arg(&file)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("up.log")).unwrap());
        let mut guard = ChildGuard(Some(up.spawn().unwrap()));
        assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 160));

        // A live swap to the PCA file, an e-stop, its reset.
        let mut swap = scl(&prefix);
        swap.arg("swap").arg(&pca);
        let out = run_polling(swap, &mut rec);
        assert!(
            out.status.success(),
            "swap: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        rec.poll_for(Duration::from_secs(2));
        let out = run_polling(
            {
                let mut c = scl(&prefix);
                c.arg("estop");
                c
            },
            &mut rec,
        );
        assert!(out.status.success(), "estop");
        rec.poll_for(Duration::from_secs(1));
        let out = run_polling(
            {
                let mut c = scl(&prefix);
                c.arg("reset");
                c
            },
            &mut rec,
        );
        assert!(out.status.success(), "reset");
        let status = loop {
            rec.poll_for(Duration::from_millis(50));
            if let Some(s) = guard.child().try_wait().unwrap() {
                break s;
            }
        };
        let log = std::fs::read_to_string(dir.join("up.log")).unwrap_or_default();
        assert!(status.success(), "scl up: {log}");
        drop(rec);
        let left = wait_clean(&prefix, Duration::from_secs(10));
        assert!(left.is_empty(), "left in /dev/shm: {left:?}");
        Run {
            dir,
            file,
            done: AtomicUsize::new(0),
            users: 3,
        }
    })
}

/// The recording's safety and mapper commands, and its attachments' names.
fn contents(path: &Path) -> (Vec<SafeCommand>, Vec<MapperCommand>, Vec<String>) {
    let (mut safe, mut mapper, mut att) = (Vec::new(), Vec::new(), Vec::new());
    recording::read_file(path, |ev| {
        match ev {
            Event::Message {
                channel,
                sequence,
                data,
                ..
            } => match channel.topic.as_str() {
                "/safe_command" => safe.push(recording::decode(path, channel, sequence, data)?),
                "/mapper_command" => mapper.push(recording::decode(path, channel, sequence, data)?),
                _ => {}
            },
            Event::Attachment { name, .. } => att.push(name.to_owned()),
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    (safe, mapper, att)
}

fn replay_json(path: &Path) -> (Option<i32>, serde_json::Value, String) {
    let out = std::process::Command::new(scl_tests::scl_binary())
        .env("SCL_LOG", "warn")
        .args(["replay", "--json"])
        .arg(path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let v = serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"));
    (
        out.status.code(),
        v,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_recorded_run_with_a_swap_an_estop_and_its_reset_replays_bit_for_bit() {
    let run = recorded_run();
    // Its `scl replay` runs are not to overlap another test's graph (one test binary).
    let _serial = serial();
    let (safe, _, att) = contents(&run.file);
    // What the run went through is in the recording: both models, safety's configuration,
    // the swap (mapper 2 reached the arm), the e-stop and the motion after its reset.
    assert!(
        att.iter().any(|a| a.starts_with("model/mapper-1/")),
        "{att:?}"
    );
    assert!(
        att.iter()
            .any(|a| a.starts_with("model/mapper-2/") && a.ends_with("pca.safetensors")),
        "{att:?}"
    );
    assert!(
        att.iter().any(|a| a.starts_with("config/safety/")),
        "{att:?}"
    );
    let estop_at = safe
        .iter()
        .position(|c| c.flags & safe_flags::ESTOP != 0)
        .expect("an e-stopped tick");
    assert!(safe[..estop_at].iter().any(|c| c.mapper_id == 2));
    assert!(
        safe[estop_at..]
            .iter()
            .any(|c| c.flags & safe_flags::ESTOP == 0 && c.qdot_rad_s.iter().any(|v| *v != 0.0)),
        "the arm never moved after the reset"
    );

    let (code, v, err) = replay_json(&run.file);
    assert_eq!(code, Some(0), "{v} {err}");
    let ticks = v["ticks"].as_u64().unwrap();
    assert!(ticks >= 700, "{v}");
    assert_eq!(v["identical"].as_u64(), Some(ticks), "{v}");
    assert_eq!(v["diverged"].as_u64(), Some(0), "{v}");
    assert!(v["first_divergence"].is_null(), "{v}");
    assert_eq!(v["mapper_identical"], v["mapper_commands"], "{v}");
    assert_eq!(v["skipped"].as_u64(), Some(0), "{v}");
    assert_eq!(v["notes"].as_array().map(Vec::len), Some(0), "{v}");
    // The control events, at their ticks: the swap, then the e-stop, then its reset.
    let events: Vec<(u64, String)> = v["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["tick"].as_u64().unwrap(),
                e["event"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    let at = |name: &str| events.iter().find(|e| e.1 == name).map(|e| e.0);
    assert_eq!(at("estop"), Some(safe[estop_at].tick), "{events:?}");
    assert!(at("swap").unwrap() < at("estop").unwrap(), "{events:?}");
    assert!(at("reset").unwrap() > at("estop").unwrap(), "{events:?}");

    // One tick spelled out: the e-stopped one.
    let out = std::process::Command::new(scl_tests::scl_binary())
        .env("SCL_LOG", "warn")
        .args([
            "replay",
            "--tick",
            &safe[estop_at].tick.to_string(),
            "--explain",
        ])
        .arg(&run.file)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    for want in [
        "inputs",
        "robot state",
        "joystick",
        "e-stop",
        "command",
        "identical",
    ] {
        assert!(text.contains(want), "`{want}` not in:\n{text}");
    }
    run.release();
}

#[test]
fn a_recording_with_an_altered_model_diverges_at_the_first_tick_the_map_moves() {
    let run = recorded_run();
    // Its `scl replay` runs are not to overlap another test's graph (one test binary).
    let _serial = serial();
    let altered = run.dir.join("altered.mcap");
    let _ = std::fs::remove_file(&altered);
    let n = replay::edit::rewrite_attachments(&run.file, &altered, |name, data| {
        name.starts_with("model/mapper-1/")
            .then(|| replay::edit::alter_one_weight(data))
            .flatten()
    })
    .unwrap();
    assert_eq!(n, 1);
    // By hand: the map's output is zero for a zero action whatever its weights, so the first
    // command that can differ is mapper 1's first with a usable, non-zero action.
    let (_, mapper, _) = contents(&run.file);
    let unusable = mapper_flags::NO_INPUT
        | mapper_flags::INPUT_NON_FINITE
        | mapper_flags::INPUT_STALE
        | mapper_flags::STATE_INVALID;
    let expected = mapper
        .iter()
        .filter(|c| c.mapper_id == 1 && c.flags & unusable == 0)
        .find(|c| c.action.iter().any(|a| *a != 0.0))
        .expect("mapper 1 moved")
        .tick;

    let (code, v, err) = replay_json(&altered);
    assert_eq!(code, Some(1), "{v} {err}");
    let d = &v["first_divergence"];
    assert_eq!(d["tick"].as_u64(), Some(expected), "{v}");
    assert_eq!(d["stage"], "mapper", "{v}");
    assert_eq!(d["mapper_id"], 1, "{v}");
    assert!(d["input"].as_str().unwrap().starts_with("the model"), "{v}");
    assert!(v["diverged"].as_u64().unwrap() > 0, "{v}");
    assert!(
        v["notes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|n| n.as_str().unwrap().contains("SHA-256")),
        "{v}"
    );
    // The text report says the same.
    let out = std::process::Command::new(scl_tests::scl_binary())
        .env("SCL_LOG", "warn")
        .arg("replay")
        .arg(&altered)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text.contains(&format!(
            "first divergence at tick {expected} in the mapper (mapper 1)"
        )),
        "{text}"
    );
    run.release();
}

/// A recording that lacks some joystick samples (as a remote recorder's, whose network path
/// drops and counts what it cannot carry): the replay rebuilds each from its command, and
/// every tick that then diverges is counted as one on a lost input, not as the graph's.
#[test]
fn joystick_samples_lost_before_the_recorder_are_the_only_divergences_counted_as_lost_input() {
    let run = recorded_run();
    let _serial = serial();
    let lossy = run.dir.join("lossy.mcap");
    let _ = std::fs::remove_file(&lossy);
    {
        let out = recording::create_new(&lossy).unwrap();
        let mut w = recording::LogWriter::new(std::io::BufWriter::new(out), &lossy, None).unwrap();
        let mut n = 0u64;
        recording::read_file(&run.file, |ev| {
            if let Event::Message { channel, .. } = &ev
                && channel.topic == "/joystick"
            {
                n += 1;
                // Every 25th sample past the first second: lost on the way.
                if n > 40 && n.is_multiple_of(25) {
                    return Ok(());
                }
            }
            w.copy_event(&ev).map(|_| ())
        })
        .unwrap();
        w.finish(None).unwrap();
    }
    let (code, v, err) = replay_json(&lossy);
    assert_eq!(code, Some(1), "{v} {err}");
    let diverged = v["diverged"].as_u64().unwrap();
    assert!(diverged > 0, "{v}");
    assert_eq!(v["diverged_on_lost_input"].as_u64(), Some(diverged), "{v}");
    // The recording as made replays with none.
    let (code, v, err) = replay_json(&run.file);
    assert_eq!(code, Some(0), "{v} {err}");
    assert_eq!(v["diverged_on_lost_input"], 0, "{v}");
    std::fs::remove_file(&lossy).unwrap();
    run.release();
}

/// An 8 s run with the bundled model throughout, recorded; its directory and file.
fn plain_run() -> &'static Run {
    static RUN: OnceLock<Run> = OnceLock::new();
    RUN.get_or_init(|| {
        let _serial = serial();
        let prefix = unique_prefix("whatif");
        let _domain = DomainGuard(prefix.clone());
        let dir = temp_dir("whatif");
        write_replay(&dir.join("input.csv"), &pulses([0.5, 0.4], 1.2, 0.4, 8.0));
        let cfg = dir.join("graph.toml");
        std::fs::write(
            &cfg,
            // The mappers warm their maps 5 ms before each tick (`rt_prewarm_us`): the replay,
            // which never warms, must still match bit for bit.
            "[graph]\nrt_prewarm_us = 5000\n[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n",
        )
        .unwrap();
        let file = dir.join("run.mcap");
        let mut up = scl(&prefix);
        up.arg("--config")
            .arg(&cfg)
            .args(["up", "--for", "8s", "--record"])
            .arg(&file)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("up.log")).unwrap());
        let status = up.status().unwrap();
        let log = std::fs::read_to_string(dir.join("up.log")).unwrap_or_default();
        assert!(status.success(), "scl up: {log}");
        let left = wait_clean(&prefix, Duration::from_secs(10));
        assert!(left.is_empty(), "left in /dev/shm: {left:?}");
        Run {
            dir,
            file,
            done: AtomicUsize::new(0),
            users: 1,
        }
    })
}

fn whatif_json(run: &Run, model: &str, out: &str) -> serde_json::Value {
    let out = run.dir.join(out);
    let _ = std::fs::remove_file(&out);
    let o = std::process::Command::new(scl_tests::scl_binary())
        .env("SCL_LOG", "warn")
        .args(["replay", "--json", "--model", model, "--out"])
        .arg(&out)
        .arg(&run.file)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{text} {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

#[test]
fn the_counterfactual_is_zero_with_the_same_model_and_differs_from_the_first_move_with_pca() {
    let run = plain_run();
    // Its `scl replay` runs are not to overlap another test's graph (one test binary).
    let _serial = serial();
    let v = whatif_json(run, "bundled", "same.mcap");
    assert!(v["ticks"].as_u64().unwrap() >= 250, "{v}");
    assert_eq!(v["ticks_differing"], 0, "{v}");
    assert!(v["first_difference"].is_null(), "{v}");
    assert!(v["first_map_difference"].is_null(), "{v}");
    assert_eq!(v["joint_rad_s_max"].as_f64(), Some(0.0), "{v}");
    assert_eq!(v["tool_m_s_max"].as_f64(), Some(0.0), "{v}");

    // By hand: PCA and SCL both command zero for a zero action and differ for any other, so
    // the first map difference is the first forwarded command with a usable non-zero action.
    let (safe, mapper, _) = contents(&run.file);
    let unusable = mapper_flags::NO_INPUT
        | mapper_flags::INPUT_NON_FINITE
        | mapper_flags::INPUT_STALE
        | mapper_flags::STATE_INVALID;
    let expected = safe
        .iter()
        .find(|s| {
            mapper.iter().any(|m| {
                m.tick == s.tick
                    && m.t_ns == s.mapper_t_ns
                    && m.flags & unusable == 0
                    && m.action.iter().any(|a| *a != 0.0)
            })
        })
        .expect("the stick moved")
        .tick;
    let pca = joint_reach_pca(&run.dir, None);
    let v = whatif_json(run, pca.to_str().unwrap(), "pca.mcap");
    assert_eq!(v["first_map_difference"].as_u64(), Some(expected), "{v}");
    assert!(v["first_difference"].as_u64().unwrap() >= expected, "{v}");
    assert!(v["joint_rad_s_max"].as_f64().unwrap() > 0.0, "{v}");
    assert!(v["tool_m_s_max"].as_f64().unwrap() > 0.0, "{v}");
    assert!(!v["largest"].as_array().unwrap().is_empty(), "{v}");
    run.release();
}

#[test]
fn a_run_whose_mapper_and_safety_were_killed_and_restarted_replays_bit_for_bit() {
    let _serial = serial();
    let prefix = unique_prefix("replayrestart");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("replayrestart");
    write_replay(&dir.join("input.csv"), &pulses([0.5, 0.4], 1.0, 0.4, 12.0));
    let cfg = dir.join("graph.toml");
    std::fs::write(
        &cfg,
        "[joystick]\nsource = \"replay\"\nreplay_file = \"input.csv\"\n\n\
         [supervisor.restart]\nmapper = \"on-failure\"\nsafety = \"on-failure\"\n",
    )
    .unwrap();
    let file = dir.join("run.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.arg("--config")
        .arg(&cfg)
        .args(["up", "--for", "12s", "--record"])
        .arg(&file)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("up.log")).unwrap());
    let mut guard = ChildGuard(Some(up.spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 120));
    // Each killed process is restarted by its policy: a fresh mapper (its map's memory
    // starts over) and a fresh filter (restart prevention, the ticks it missed).
    for role in [NodeRole::Mapper, NodeRole::Safety] {
        let old = rec.pid_of(role).unwrap();
        send_signal(old, Signal::SIGKILL);
        assert!(
            rec.poll_until(Duration::from_secs(10), |r| r
                .pid_of(role)
                .is_some_and(|p| p != old)),
            "{} not restarted",
            role.name()
        );
        rec.poll_for(Duration::from_secs(2));
    }
    let status = loop {
        rec.poll_for(Duration::from_millis(50));
        if let Some(s) = guard.child().try_wait().unwrap() {
            break s;
        }
    };
    let log = std::fs::read_to_string(dir.join("up.log")).unwrap_or_default();
    assert!(status.success(), "scl up: {log}");
    drop(rec);
    let left = wait_clean(&prefix, Duration::from_secs(10));
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");

    let (code, v, err) = replay_json(&file);
    assert_eq!(code, Some(0), "{v} {err}");
    let ticks = v["ticks"].as_u64().unwrap();
    assert!(ticks >= 300, "{v}");
    assert_eq!(v["identical"].as_u64(), Some(ticks), "{v}");
    assert_eq!(v["skipped"].as_u64(), Some(0), "{v}");
    assert_eq!(v["notes"].as_array().map(Vec::len), Some(0), "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}
