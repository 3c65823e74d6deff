//! Whole-graph tests of the 3D view: the Foxglove channels of a recording read back with the
//! `mcap` crate and decoded with Foxglove's schema definitions (frames of every link at every
//! tick, agreeing with the kinematics; the map's arrows equal to `J·s·H·e_i`), `scl record
//! --convert`, and `scl up --live` with a WebSocket client connecting, subscribing and coming
//! and going while the graph runs without a miss. Each test runs its own graph under its own
//! prefix, one at a time, and checks that nothing is left behind.
#![allow(clippy::unwrap_used, clippy::needless_range_loop, missing_docs)]

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use foxglove::messages::{FrameTransforms, SceneUpdate};
use ipc_types::RobotState;
use kinematics::RobotProfile;
use mapper::LoadedModel;
use nalgebra::{DVector, Quaternion, UnitQuaternion, Vector3};
use prost::Message;
use scl_tests::{
    DomainGuard, Recorder, assert_misses_only_held_up, run_polling, scl, serial, temp_dir,
    unique_prefix, wait_clean,
};
use viz::client::Client;

/// One message of a recording: channel topic, schema name, encoding, log and publish
/// times, bytes.
struct Msg {
    topic: String,
    schema: String,
    encoding: String,
    log_time: u64,
    publish_time: u64,
    data: Vec<u8>,
}

/// 2020-01-01 in Unix ns: a wall-clock time is after it, a monotonic one (the machine's
/// uptime) far before.
const WALL_2020_NS: u64 = 1_577_836_800_000_000_000;

/// The pose of frame `name` in the base frame, composing the transforms of `tf` up its
/// parents.
fn in_base(tf: &FrameTransforms, base: &str, name: &str) -> nalgebra::Isometry3<f64> {
    let mut pose = nalgebra::Isometry3::identity();
    let mut at = name.to_owned();
    while at != base {
        let t = tf
            .transforms
            .iter()
            .find(|t| t.child_frame_id == at)
            .unwrap_or_else(|| panic!("no frame {at}"));
        let p = t.translation.unwrap();
        let iso = nalgebra::Isometry3::from_parts(
            nalgebra::Translation3::new(p.x, p.y, p.z),
            unit(&t.rotation.unwrap()),
        );
        pose = iso * pose;
        at = t.parent_frame_id.clone();
    }
    pose
}

/// Every message of `path`, read with the `mcap` crate (not the project's reader).
fn read_mcap(path: &Path) -> Vec<Msg> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            Msg {
                topic: m.channel.topic.clone(),
                schema: m
                    .channel
                    .schema
                    .as_ref()
                    .map_or(String::new(), |s| s.name.clone()),
                encoding: m.channel.message_encoding.clone(),
                log_time: m.log_time,
                publish_time: m.publish_time,
                data: m.data.into_owned(),
            }
        })
        .collect()
}

fn unit(q: &foxglove::messages::Quaternion) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q.w, q.x, q.y, q.z))
}

/// Checks the 3D channels of a recording of the default graph (the bundled SCL model, mapper
/// 1): returns the number of robot states checked.
fn check_view(path: &Path) -> usize {
    let msgs = read_mcap(path);
    let robot = RobotProfile::default_robot();
    let chain = robot.arm();
    let links: Vec<&str> = chain.link_names().filter(|n| *n != chain.base()).collect();
    let mut model = LoadedModel::load("bundled").unwrap();
    let s = model.header.speed_scale_rad_s;
    let mut by_time: BTreeMap<(String, u64), &Msg> = BTreeMap::new();
    for m in &msgs {
        by_time.insert((m.topic.clone(), m.log_time), m);
    }
    for (topic, schema) in [
        ("/tf", "foxglove.FrameTransforms"),
        ("/scl/arm", "foxglove.SceneUpdate"),
        ("/scl/map", "foxglove.SceneUpdate"),
        ("/scl/world", "foxglove.SceneUpdate"),
    ] {
        let m = msgs.iter().find(|m| m.topic == topic).unwrap();
        assert_eq!(
            (m.schema.as_str(), m.encoding.as_str()),
            (schema, "protobuf")
        );
    }
    // Every message: log time on the wall clock, publish time the monotonic one.
    for m in &msgs {
        assert!(
            m.log_time > WALL_2020_NS,
            "{}: log time {}",
            m.topic,
            m.log_time
        );
        assert!(m.publish_time < WALL_2020_NS, "{}", m.topic);
    }
    // What the processes said, on `/scl/log`.
    let log: Vec<foxglove::messages::Log> = msgs
        .iter()
        .filter(|m| m.topic == "/scl/log")
        .map(|m| {
            assert_eq!(m.schema, "foxglove.Log");
            foxglove::messages::Log::decode(m.data.as_slice()).unwrap()
        })
        .collect();
    assert!(
        log.iter()
            .any(|l| l.name == "safety" && l.message.contains("is running")),
        "{:?}",
        log.iter().map(|l| &l.message).collect::<Vec<_>>()
    );
    let states: Vec<(u64, RobotState)> = msgs
        .iter()
        .filter(|m| m.topic == "/robot_state")
        .map(|m| (m.log_time, serde_json::from_slice(&m.data).unwrap()))
        .collect();
    let mut jac = kinematics::Jacobian::zeros(6);
    let mut with_arrows = 0;
    for (k, (log_time, st)) in states.iter().enumerate() {
        let q = st.q();
        // Frames of every link and the tool, at the state's time.
        let tf = by_time
            .get(&("/tf".to_owned(), *log_time))
            .unwrap_or_else(|| panic!("no /tf for tick {}", st.tick));
        let tf = FrameTransforms::decode(tf.data.as_slice()).unwrap();
        for name in &links {
            let t = tf
                .transforms
                .iter()
                .find(|t| t.child_frame_id == *name)
                .unwrap_or_else(|| panic!("tick {}: no frame {name}", st.tick));
            let want = chain.link_pose(q, chain.link_id(name).unwrap()).unwrap();
            let got = in_base(&tf, chain.base(), &t.child_frame_id);
            assert!((got.translation.vector - want.translation.vector).norm() < 1e-9);
            assert!(got.rotation.angle_to(&want.rotation) < 1e-9);
        }
        let want = chain.fk_jacobian(q, &mut jac).unwrap();
        let got = in_base(&tf, chain.base(), "tool");
        assert!((got.translation.vector - want.translation.vector).norm() < 1e-9);
        // The map's arrows: J·s·H·e_i, linear part 1 m per m/s (LINEAR_ARROW_S), from the tool.
        let map = by_time.get(&("/scl/map".to_owned(), *log_time)).unwrap();
        let map = SceneUpdate::decode(map.data.as_slice()).unwrap();
        let axes: Vec<_> = map
            .entities
            .iter()
            .filter(|e| e.id.starts_with("map/axis"))
            .collect();
        if axes.is_empty() {
            // Only while the recorder has not yet loaded the mapper's model.
            assert!(k < 5, "tick {}: no map arrows", st.tick);
            continue;
        }
        with_arrows += 1;
        for i in 0..2 {
            let mut a = [0.0; 2];
            a[i] = 1.0;
            let mut qd = [0.0; 6];
            model.map.eval(q, st.gripper, &a, &mut qd);
            let tw = jac.matrix() * DVector::from_iterator(6, qd.iter().map(|v| v * s));
            let e = axes
                .iter()
                .find(|e| e.id == format!("map/axis{}", i + 1))
                .unwrap();
            let arrow = &e.arrows[0];
            let pose = arrow.pose.unwrap();
            let v = unit(&pose.orientation.unwrap())
                * Vector3::x()
                * (arrow.shaft_length + arrow.head_length)
                / viz::LINEAR_ARROW_S;
            let want = Vector3::new(tw[0], tw[1], tw[2]);
            assert!(
                (v - want).norm() < 1e-9,
                "tick {} axis {}: {v} vs {want}",
                st.tick,
                i + 1
            );
            let o = pose.position.unwrap();
            assert!((Vector3::new(o.x, o.y, o.z) - want_tool(&jac, chain, q)).norm() < 1e-9);
        }
    }
    assert!(
        with_arrows + 5 >= states.len(),
        "{with_arrows} of {}",
        states.len()
    );
    states.len()
}

fn want_tool(_: &kinematics::Jacobian, chain: &kinematics::Chain, q: &[f64]) -> Vector3<f64> {
    chain.fk(q).unwrap().translation.vector
}

#[test]
fn a_recordings_foxglove_channels_hold_every_frame_and_the_maps_directions() {
    let _serial = serial();
    let prefix = unique_prefix("live-rec");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("live-rec");
    let file = dir.join("run.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "4s", "--json", "--record"])
        .arg(&file);
    let out = run_polling(up, &mut rec);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let n = check_view(&file);
    assert!(n >= 80, "only {n} states");

    // The same channels added to a copy of the file without them (`--convert`).
    let old = dir.join("old.mcap");
    strip_view(&file, &old);
    let new = dir.join("new.mcap");
    let out = scl(&prefix)
        .args(["record", "--convert"])
        .arg(&old)
        .arg("--out")
        .arg(&new)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(check_view(&new), n);
    // Never over an existing file, never over the input.
    let out = scl(&prefix)
        .args(["record", "--convert"])
        .arg(&old)
        .arg("--out")
        .arg(&old)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("already exists"),
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

/// A copy of recording `from` without the 3D channels: what a recording made before them is.
fn strip_view(from: &Path, to: &Path) {
    let mut w = recording::LogWriter::new(
        std::io::BufWriter::new(std::fs::File::create(to).unwrap()),
        to,
        None,
    )
    .unwrap();
    let mut ids = BTreeMap::new();
    recording::read_file(from, |ev| {
        match ev {
            recording::Event::Channel(c)
                if c.message_encoding == "json" && c.topic != "/scl/tick" =>
            {
                let id = w.add_channel(
                    &c.topic,
                    c.schema.as_ref(),
                    &c.message_encoding,
                    &c.metadata,
                )?;
                ids.insert(c.id, id);
            }
            recording::Event::Message {
                channel,
                sequence,
                log_time,
                publish_time,
                data,
            } => {
                if let Some(id) = ids.get(&channel.id) {
                    w.write_raw(*id, sequence, log_time, publish_time, data)?;
                }
            }
            recording::Event::Metadata { name, entries } => {
                w.write_metadata(&recording::metadata(name, entries.clone()))?;
            }
            recording::Event::Attachment {
                name,
                log_time,
                media_type,
                data,
            } => w.attach(name, log_time, media_type, data)?,
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    w.finish(None).unwrap();
}

/// A free TCP port on loopback.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn a_live_client_gets_the_frames_at_40_hz_and_never_disturbs_the_graph() {
    let _serial = serial();
    let prefix = unique_prefix("live-ws");
    let _domain = DomainGuard(prefix.clone());
    let addr = format!("127.0.0.1:{}", free_port());
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "14s", "--json", "--live", &addr]);
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(AtomicU64::new(0));
    let connects = Arc::new(AtomicU64::new(0));
    let (s2, f2, c2, a2) = (stop.clone(), frames.clone(), connects.clone(), addr.clone());
    let client = std::thread::spawn(move || {
        // Wait for the server (scl up starts it before the bridge).
        let t0 = Instant::now();
        let mut c = loop {
            match Client::connect(&a2, Duration::from_secs(2)) {
                Ok(c) if !c.channels.is_empty() => break c,
                _ if t0.elapsed() > Duration::from_secs(20) => panic!("no Foxglove server"),
                _ => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        // The advertised channels: the graph's topics and the 3D view.
        let topics: Vec<String> = c.channels.values().map(|a| a.topic.clone()).collect();
        for t in [
            "/tf",
            "/scl/arm",
            "/scl/map",
            "/scl/world",
            "/scl/tick",
            "/scl/log",
            "/robot_state",
            "/safe_command",
        ] {
            assert!(
                topics.iter().any(|x| x == t),
                "{t} not advertised: {topics:?}"
            );
        }
        let tf = c.channel("/tf").unwrap();
        assert_eq!(c.channels[&tf].schema_name, "foxglove.FrameTransforms");
        let log = c.channel("/scl/log").unwrap();
        assert_eq!(c.channels[&log].schema_name, "foxglove.Log");
        c.subscribe(&[tf]).unwrap();
        // Wait for the first frame (the bridge starts after the server), then count 4 s.
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(20) {
            if let Some(f) = c.next_frame().unwrap() {
                // Stamped on the wall clock (Foxglove shows the date of the run).
                assert!(f.t_ns > WALL_2020_NS, "log time {}", f.t_ns);
                break;
            }
        }
        let t0 = Instant::now();
        let mut n = 0u64;
        let mut last_links = 0;
        while t0.elapsed() < Duration::from_secs(4) {
            if let Some(f) = c.next_frame().unwrap() {
                assert_eq!(u64::from(f.subscription), tf);
                last_links = FrameTransforms::decode(f.data.as_slice())
                    .unwrap()
                    .transforms
                    .len();
                n += 1;
            }
        }
        f2.store(n, Ordering::SeqCst);
        assert!(last_links >= 7, "{last_links} frames");
        c.close();
        // Clients come and go (some leave without closing) while the graph runs.
        while !s2.load(Ordering::SeqCst) {
            if let Ok(mut c) = Client::connect(&a2, Duration::from_millis(500)) {
                c2.fetch_add(1, Ordering::SeqCst);
                let ids: Vec<u64> = c.channels.keys().copied().collect();
                let _ = c.subscribe(&ids);
                for _ in 0..3 {
                    let _ = c.next_frame();
                }
                if c2.load(Ordering::SeqCst) % 2 == 0 {
                    c.close();
                } else {
                    drop(c);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    let out = run_polling(up, &mut rec);
    stop.store(true, Ordering::SeqCst);
    client.join().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up failed: {stderr}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // ~40 Hz: 160 frames in 4 s, give or take the machine.
    let n = frames.load(Ordering::SeqCst);
    assert!((140..=180).contains(&n), "{n} frame transforms in 4 s");
    assert!(
        connects.load(Ordering::SeqCst) >= 10,
        "only {} reconnects",
        connects.load(Ordering::SeqCst)
    );
    assert_misses_only_held_up(
        &summary,
        &stderr,
        "scl up --live with clients coming and going",
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

/// `scl live --client`, the Foxglove client the soak attaches: subscribed to every channel of
/// `scl up --live`, it reports each second on stdout (one JSON object a line), counting the
/// frames of each topic at the graph's rate, and on SIGINT (once it has read 2 s of robot
/// states) ends with one connection made and exit code 0.
#[test]
fn scl_live_client_reads_every_channel_and_reports_each_second() {
    use std::io::BufRead as _;
    let _serial = serial();
    let prefix = unique_prefix("live-cl");
    let _domain = DomainGuard(prefix.clone());
    let addr = format!("127.0.0.1:{}", free_port());
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.args(["up", "--for", "15s", "--json", "--live", &addr]);
    let mut client = scl(&prefix)
        .args(["live", "--client", &addr, "--json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = client.id();
    let stdout = client.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let t0 = Instant::now();
        let mut sent = false;
        let mut lines = Vec::new();
        for line in std::io::BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            let v: serde_json::Value = serde_json::from_str(&line).unwrap();
            let states = v["per_topic"]["/robot_state"].as_u64().unwrap_or(0);
            // Stopped while the graph serves: 80 robot states (2 s at 40 Hz), or a deadline.
            if !sent && (states >= 80 || t0.elapsed() > Duration::from_secs(40)) {
                scl_tests::send_signal(pid, nix::sys::signal::Signal::SIGINT);
                sent = true;
            }
            lines.push(v);
        }
        lines
    });
    let out = run_polling(up, &mut rec);
    let lines = reader.join().unwrap();
    let client = client.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&client.stderr);
    assert!(out.status.success(), "scl up failed");
    assert!(client.status.success(), "scl live --client: {stderr}");
    let last = lines
        .last()
        .unwrap_or_else(|| panic!("no report: {stderr}"));
    assert_eq!(last["connects"], 1, "{last}");
    assert!(last["channels"].as_u64().unwrap() >= 8, "{last}");
    // At 40 Hz: one frame a tick on each of the state's topics.
    let states = last["per_topic"]["/robot_state"].as_u64().unwrap();
    assert!(states >= 80, "{states} robot states: {last}");
    let tf = last["per_topic"]["/tf"].as_u64().unwrap();
    assert!(tf.abs_diff(states) <= 2, "{tf} frame transforms: {last}");
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
