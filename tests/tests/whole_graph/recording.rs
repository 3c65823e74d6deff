//! Whole-graph tests of recording and watching: `scl up --record` into MCAP and back out as a
//! training data set, a recorder killed mid-run, and `scl top` / `scl record` attached to a
//! running graph. Each test runs its own graph under its own prefix, one at a time, and checks
//! that nothing is left behind.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use ipc_types::{NodeRole, RobotState, state_flags};
use recording::{self, Event, ReadSummary};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, Signal, run_polling, scl, serial, temp_dir, unique_prefix,
    wait_clean,
};

/// What a recording holds.
#[derive(Default)]
struct Contents {
    summary: ReadSummary,
    /// Channel topic -> (message encoding, schema encoding).
    channels: BTreeMap<String, (String, String)>,
    /// Messages per channel topic.
    counts: BTreeMap<String, u64>,
    states: Vec<RobotState>,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Messages that do not agree with their channel's schema, with what is wrong.
    disagreements: Vec<String>,
}

/// Every message of `path` read, every message checked against its channel's schema (as
/// stored in the file), the robot states decoded.
fn contents(path: &Path) -> Contents {
    let mut c = Contents::default();
    let mut schemas: BTreeMap<String, serde_json::Value> = BTreeMap::new();
    c.summary = recording::read_file(path, |ev| {
        match ev {
            Event::Channel(ch) => {
                let schema = ch
                    .schema
                    .as_ref()
                    .map_or(String::new(), |s| s.encoding.clone());
                c.channels
                    .insert(ch.topic.clone(), (ch.message_encoding.clone(), schema));
                if let Some(s) = ch.schema.as_ref().filter(|s| s.encoding == "jsonschema") {
                    schemas.insert(ch.topic.clone(), serde_json::from_slice(&s.data).unwrap());
                }
            }
            Event::Message {
                channel,
                sequence,
                data,
                ..
            } => {
                *c.counts.entry(channel.topic.clone()).or_default() += 1;
                if channel.message_encoding != "json" {
                    // The 3D view's protobuf channels: decoded in tests/tests/whole_graph/live.rs.
                    return Ok(());
                }
                let value: serde_json::Value = serde_json::from_slice(data).unwrap();
                for e in test_support::json_schema::validate(&value, &schemas[&channel.topic]) {
                    c.disagreements
                        .push(format!("{} #{sequence}: {e}", channel.topic));
                }
                if channel.topic == "/robot_state" {
                    c.states.push(
                        recording::decode_robot_state(path, channel, sequence, data).unwrap(),
                    );
                }
            }
            Event::Metadata { name, entries } => {
                c.metadata.insert(name.to_owned(), entries.clone());
            }
            Event::Attachment { .. } => {}
        }
        Ok(())
    })
    .unwrap();
    c
}

/// The recorded states match the test's own recorder's, tick for tick.
/// The ticks of `states` (a run's robot states, in order) that `scl dataset` turns into
/// tuples: each but the last, unless the next state reports a miss or a stop. In these runs
/// the only stops are the graph's first ticks (before the joystick's first sample has reached
/// the mapper, safety stops the arm: no sample at all is a stale one) and those from a tick
/// the machine held up on (restart prevention then holds the arm until the stick rests);
/// checked here.
fn demonstration_ticks(states: &[(u64, u32)]) -> Vec<u64> {
    let stop = state_flags::MISSED | state_flags::STOPPING | state_flags::SAFETY_STOP;
    let mut ticks = Vec::new();
    let mut missed = false;
    for w in states.windows(2) {
        missed |= w[1].1 & state_flags::MISSED != 0;
        if w[1].1 & stop == 0 {
            ticks.push(w[0].0);
        } else {
            assert!(
                w[0].0 < states[0].0 + 5 || missed,
                "tick {}: a stop after the start-up with no miss before it ({:#x})",
                w[0].0,
                w[1].1
            );
        }
    }
    ticks
}

fn assert_same_states(file: &[RobotState], seen: &[RobotState], what: &str) {
    for s in file {
        // The bridge's shutdown state repeats its last tick: match the publication time too.
        let r = seen
            .iter()
            .find(|r| r.tick == s.tick && r.t_ns == s.t_ns)
            .unwrap_or_else(|| {
                panic!(
                    "{what}: tick {} at {} ns is not a state the graph published",
                    s.tick, s.t_ns
                )
            });
        // The recording keeps the message exactly, every field of it.
        assert_eq!(s, r, "{what}: tick {}", s.tick);
    }
}

fn first_tick(name: &str) -> u64 {
    let at = name.rfind("-tick").unwrap();
    name[at + 5..].trim_end_matches(".csv").parse().unwrap()
}

#[test]
fn a_recorded_run_becomes_a_dataset_of_what_the_graph_did() {
    let _serial = serial();
    let prefix = unique_prefix("recds");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("rec-dataset");
    let file = dir.join("run.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args([
        "up", "--for", "6s", "--json", "--script", "step", "--record",
    ])
    .arg(&file);
    let out = run_polling(up, &mut rec);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up failed: {stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ticks = summary["ticks"].as_u64().unwrap();
    assert!(ticks >= 120, "only {ticks} ticks");

    // The file: finished, every topic a JSON channel with a JSON schema (the 3D view's
    // Foxglove channels and /scl/log protobuf, /scl/tick JSON), and the robot
    // states exactly those the graph published, the bridge's last (shutdown) state included:
    // the recorder started before the bridge and stopped after it.
    let c = contents(&file);
    assert!(c.summary.complete, "{:?}", c.summary);
    assert_eq!(
        c.channels.len(),
        recording::Topic::COUNT + 6,
        "{:?}",
        c.channels
    );
    for (topic, (enc, schema)) in &c.channels {
        let want = if ["/tf", "/scl/arm", "/scl/map", "/scl/world", "/scl/log"]
            .contains(&topic.as_str())
        {
            ("protobuf", "protobuf")
        } else {
            ("json", "jsonschema")
        };
        assert_eq!((enc.as_str(), schema.as_str()), want, "{topic}");
    }
    // Every message of every topic agrees with its channel's schema.
    assert_eq!(c.disagreements, Vec::<String>::new());
    let running: Vec<RobotState> = rec
        .robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .collect();
    assert_eq!(
        running.len() as u64,
        ticks,
        "the test's recorder missed states"
    );
    assert_eq!(c.states.len(), rec.robot_states.len());
    assert_same_states(&c.states, &rec.robot_states, "recording");
    assert!(c.states.last().unwrap().flags & state_flags::SHUTDOWN != 0);
    assert_eq!(c.counts["/safe_command"], rec.safe_commands.len() as u64);
    assert!(c.counts["/mapper_command"] >= ticks && c.counts["/joystick"] >= ticks);
    // Heartbeats of the four nodes and of the recorder itself.
    assert!(c.counts["/status"] >= 4 * ticks, "{:?}", c.counts);
    // Clean stop: the end metadata counts everything, nothing dropped.
    let start = &c.metadata[recording::START_METADATA];
    assert_eq!(start["prefix"], prefix.as_str());
    let end = &c.metadata[recording::END_METADATA];
    assert_eq!(end["dropped_total"], "0", "{end:?}");
    assert_eq!(end["robot_state_gaps"], "0", "{end:?}");
    assert_eq!(end["written.robot_state"], c.states.len().to_string());
    assert!(
        stderr.contains("scl record:") && stderr.contains(" 0 dropped"),
        "no recorder report: {stderr}"
    );

    // Into a data set: every tick's tuple once, in 1 s trajectories, a quarter of them in
    // val/, each row the state of its tick and the velocity of the next.
    let data = dir.join("data");
    let out = scl(&prefix)
        .arg("dataset")
        .arg(&file)
        .arg("--out")
        .arg(&data)
        .args([
            "--val-fraction",
            "0.25",
            "--max-length-s",
            "1",
            "--rest-s",
            "0",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ds = learning::dataset::load_dir(&data).unwrap();
    let n_traj = ds.train.len() + ds.val.len();
    assert!(n_traj >= 4, "{n_traj} trajectories");
    assert_eq!(ds.val.len(), n_traj / 4, "val gets a quarter");
    let by_tick: BTreeMap<u64, &RobotState> = running.iter().map(|s| (s.tick, s)).collect();
    let mut covered = Vec::new();
    for t in ds.train.iter().chain(&ds.val) {
        let k0 = first_tick(&t.name);
        assert_eq!(t.n_joints(), 6);
        for r in 0..t.len() {
            let k = k0 + r as u64;
            covered.push(k);
            let (now, next) = (by_tick[&k], by_tick[&(k + 1)]);
            let t_s = (now.t_ns - by_tick[&k0].t_ns) as f64 / 1e9;
            assert!((t.t[r] - t_s).abs() < 1e-4, "{}: row {r}", t.name);
            for j in 0..6 {
                assert!(
                    (t.q[r][j] - now.q_rad[j]).abs() < 1e-6,
                    "{}: row {r}",
                    t.name
                );
                assert!(
                    (t.qdot[r][j] - next.qdot_rad_s[j]).abs() < 1e-6,
                    "{}: row {r}",
                    t.name
                );
            }
            assert!((t.c[r] - now.gripper).abs() < 1e-6);
        }
    }
    covered.sort_unstable();
    // Every tick but the last running one (it has no successor) exactly once, but the
    // start-up's stops.
    let expected = demonstration_ticks(
        &running
            .iter()
            .map(|s| (s.tick, s.flags))
            .collect::<Vec<_>>(),
    );
    // All of them on an undisturbed run; with a tick the machine held up, the step script's
    // next rest re-arms the arm (at most one 2.5 s stroke lost per miss).
    let missed = summary["missed"].as_u64().unwrap() as usize;
    assert!(
        expected.len() + missed * 100 >= ticks as usize - 5,
        "{} of {ticks} ticks, {missed} missed",
        expected.len()
    );
    assert_eq!(covered, expected);
    assert_eq!(ds.n_train() + ds.n_val(), expected.len());

    // Never overwritten: a second conversion into the same place is refused and changes
    // nothing.
    let before = learning::dataset::load_dir(&data).unwrap().hash;
    let again = scl(&prefix)
        .arg("dataset")
        .arg(&file)
        .arg("--out")
        .arg(&data)
        .args(["--max-length-s", "1", "--rest-s", "0"])
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("already exists"));
    assert_eq!(learning::dataset::load_dir(&data).unwrap().hash, before);
    // Nor is a recording.
    let out = scl(&prefix)
        .args(["up", "--for", "1s", "--record"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("already exists"));

    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_killed_recorder_leaves_a_readable_recording() {
    let _serial = serial();
    let prefix = unique_prefix("reckill");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("rec-kill");
    let file = dir.join("cut.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut guard = ChildGuard(Some(
        scl(&prefix)
            .args(["up", "--record"])
            .arg(&file)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    ));
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() >= 40
            && r.pid_of(NodeRole::Recorder).is_some()),
        "the graph did not run with a recorder"
    );
    // Wait until the recorder has put a few seconds on disk (it closes a chunk a second).
    let t0 = Instant::now();
    let on_disk = loop {
        rec.poll();
        let n = contents(&file).states.len();
        if n >= 80 {
            break n;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "only {n} states on disk"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let pid = rec.pid_of(NodeRole::Recorder).unwrap();
    scl_tests::send_signal(pid, Signal::SIGKILL);
    // The recorder's restart policy is `never`: the graph stops, bridge first, naming it.
    let t0 = Instant::now();
    while guard.child().try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "scl up did not exit"
        );
    }
    rec.poll();
    let out = guard.take().wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(&format!("the recorder process (pid {pid})")) && stderr.contains("SIGKILL"),
        "{stderr}"
    );

    // The cut file reads up to its last complete chunk (the writer closes one a second).
    let cut = contents(&file);
    assert!(!cut.summary.complete, "{:?}", cut.summary);
    assert!(cut.summary.stopped.is_some());
    assert!(!cut.metadata.contains_key(recording::END_METADATA));
    assert!(
        cut.states.len() >= on_disk,
        "only {} of the {on_disk} states on disk before the kill are readable",
        cut.states.len()
    );
    // What is there is the start of what the graph did, without a gap.
    let first = rec.robot_states[0].tick;
    let ticks: Vec<u64> = cut.states.iter().map(|s| s.tick).collect();
    assert_eq!(
        ticks,
        (first..first + ticks.len() as u64).collect::<Vec<_>>()
    );
    assert_same_states(&cut.states, &rec.robot_states, "cut recording");

    // `scl record --recover` makes a finished copy of exactly that prefix.
    let fixed = dir.join("fixed.mcap");
    let out = scl(&prefix)
        .args(["record", "--recover"])
        .arg(&file)
        .arg("--out")
        .arg(&fixed)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains(&format!("recovered {} messages", cut.summary.messages)),
        "{stdout}"
    );
    let rec_fixed = contents(&fixed);
    assert!(rec_fixed.summary.complete, "{:?}", rec_fixed.summary);
    assert_eq!(rec_fixed.summary.messages, cut.summary.messages);
    assert_eq!(rec_fixed.channels, cut.channels);
    assert_eq!(rec_fixed.counts, cut.counts);
    assert_eq!(rec_fixed.states, cut.states);
    assert!(
        rec_fixed
            .metadata
            .contains_key(recording::RECOVERED_METADATA)
    );
    assert!(rec_fixed.metadata.contains_key(recording::START_METADATA));
    // Recovering again over the result is refused.
    let again = scl(&prefix)
        .args(["record", "--recover"])
        .arg(&file)
        .arg("--out")
        .arg(&fixed)
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2));

    // `scl dataset` reads the cut file as it is, saying so.
    let out = scl(&prefix)
        .arg("dataset")
        .arg(&file)
        .arg("--out")
        .arg(dir.join("data"))
        .args(["--rest-s", "0", "--max-length-s", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("the recording is cut"), "{stderr}");
    let ds = learning::dataset::load_dir(&dir.join("data")).unwrap();
    let expected = demonstration_ticks(
        &cut.states
            .iter()
            .map(|s| (s.tick, s.flags))
            .collect::<Vec<_>>(),
    );
    assert_eq!(ds.n_train() + ds.n_val(), expected.len());

    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn top_and_a_standalone_recorder_attach_to_a_running_graph() {
    let _serial = serial();
    let prefix = unique_prefix("rectop");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("rec-top");
    let file = dir.join("two-topics.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut graph = ChildGuard(Some(
        scl(&prefix)
            .args(["up", "--for", "30s"])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    ));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() >= 40));
    // A recorder of two topics, started by hand beside the graph.
    let mut recorder = ChildGuard(Some(
        scl(&prefix)
            .args([
                "record",
                "--json",
                "--topics",
                "robot_state,safe_command",
                "--out",
            ])
            .arg(&file)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    ));
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| r
            .pid_of(NodeRole::Recorder)
            .is_some()),
        "the recorder sent no heartbeat"
    );

    // One dashboard frame, as text.
    let n = rec.robot_states.len();
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() >= n + 40));
    let out = scl(&prefix).args(["top", "--once"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 24, "{text}");
    assert!(lines.iter().all(|l| l.chars().count() <= 80), "{text}");
    assert!(lines[0].contains(&format!("graph `{prefix}`")), "{text}");
    assert!(lines[0].contains("mapper 1"), "{text}");
    for role in ["joystick", "mapper", "safety", "bridge", "recorder"] {
        let row = lines
            .iter()
            .find(|l| l.starts_with(role))
            .unwrap_or_else(|| panic!("no {role} row:\n{text}"));
        let cols: Vec<&str> = row.split_whitespace().collect();
        assert_eq!(cols[3], "yes", "{role} not alive:\n{text}");
        let hz: f64 = cols[4]
            .parse()
            .unwrap_or_else(|_| panic!("{role} has no rate:\n{text}"));
        assert!(hz > 0.0, "{text}");
    }
    let timing = lines.iter().find(|l| l.starts_with("e2e p50 ")).unwrap();
    assert!(timing.contains(" µs") || timing.contains(" ms"), "{text}");
    let joint_rows = lines
        .iter()
        .filter(|l| l.starts_with('j') && l[1..].starts_with(|c: char| c.is_ascii_digit()))
        .filter(|l| l.contains('●'))
        .count();
    assert_eq!(joint_rows, 6, "{text}");

    // Stop the recorder (SIGTERM, as Ctrl-C would): it finishes the file and reports.
    let mut child = recorder.take();
    scl_tests::send_signal(child.id(), Signal::SIGTERM);
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "scl record did not stop"
        );
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["dropped"], 0, "{report}");
    // Written: every message in the file, the graph's (all received, none dropped) and the
    // 3D view's.
    let view_written = report["view_written"].as_u64().unwrap();
    assert!(view_written > 0, "{report}");
    assert_eq!(
        report["written"].as_u64().unwrap(),
        report["received"].as_u64().unwrap() + view_written,
        "{report}"
    );
    let topics: Vec<&str> = report["topics"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["topic"].as_str().unwrap())
        .collect();
    assert_eq!(topics, vec!["robot_state", "safe_command"]);
    let c = contents(&file);
    assert!(c.summary.complete);
    // The 3D view comes with the robot states.
    assert_eq!(
        c.channels.keys().collect::<Vec<_>>(),
        vec![
            "/robot_state",
            "/safe_command",
            "/scl/arm",
            "/scl/log",
            "/scl/map",
            "/scl/tick",
            "/scl/world",
            "/tf"
        ]
    );
    // The reported total is the number of messages in the file.
    let in_file: u64 = c.counts.values().sum();
    assert_eq!(in_file, report["written"].as_u64().unwrap(), "{report}");
    let graph_messages: u64 = ["/robot_state", "/safe_command"]
        .iter()
        .map(|t| c.counts.get(*t).copied().unwrap_or(0))
        .sum();
    assert_eq!(graph_messages + view_written, in_file, "{report}");
    assert_eq!(
        report["topics"][0]["written"].as_u64().unwrap(),
        c.states.len() as u64
    );
    assert!(c.states.len() >= 40);
    assert_same_states(&c.states, &rec.robot_states, "standalone recording");
    // A late joiner starts where it joined and then misses nothing.
    let ticks: Vec<u64> = c.states.iter().map(|s| s.tick).collect();
    assert_eq!(
        ticks,
        (ticks[0]..ticks[0] + ticks.len() as u64).collect::<Vec<_>>()
    );

    // The graph goes on until stopped; it stops cleanly.
    scl_tests::send_signal(graph.child().id(), Signal::SIGTERM);
    let out = graph.take().wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
