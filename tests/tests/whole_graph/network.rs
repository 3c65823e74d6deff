//! The graph reached from another machine through its Zenoh gateway, on real network stacks:
//! two network namespaces (the robot PC and the operator's laptop) joined by a veth pair
//! (`scl_net::netns::VethPair`, the bench's too). CI runs as root; a test that cannot make its
//! namespaces fails, it does not skip.
//!
//! This project's machines run a kernel built without `netem` (`CONFIG_NET_SCH_NETEM` is not
//! set: `tc qdisc ... netem` answers "Specified qdisc kind is unknown"), so a cut is the
//! operator's interface taken down (`ip link set down`: the same loss of every packet), and
//! added delay is a TCP relay in the operator's namespace (`scl_net::relay::Relay`, the
//! bench's too) that holds every chunk, both ways, for a set time before passing it on.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use ipc_types::{JoystickInput, NodeRole, NodeStatus, buttons, gateway_counts, safe_flags};
use scl_net::netns::{Side, VethPair};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, assert_misses_only_held_up, assert_stop_within_two_ticks,
    scl_binary, serial, temp_dir, unique_prefix, wait_clean,
};

/// The robot PC and the operator's machine: [`VethPair`], with the graph's helpers.
struct Netns {
    pair: VethPair,
    op: String,
    robot_ip: std::net::Ipv4Addr,
}

impl Netns {
    fn new(tag: &str) -> Self {
        let pair = VethPair::new(tag).unwrap_or_else(|e| {
            panic!("the network tests need two namespaces (CI runs as root with iproute2): {e}")
        });
        Self {
            op: pair.netns(Side::Operator).to_owned(),
            robot_ip: pair.addr(Side::Robot),
            pair,
        }
    }

    /// `scl ARGS` on `side`, for graph `prefix`.
    fn scl(&self, side: Side, prefix: &ipc_types::Prefix) -> Command {
        let mut c = self.pair.command(side, scl_binary());
        c.env("SCL_PREFIX", prefix.as_str()).env("SCL_LOG", "warn");
        c
    }

    /// Cuts the link (`up == false`: the operator's interface down) or restores it.
    fn link(&self, up: bool) {
        self.pair.set_operator_link(up).unwrap();
    }

    fn endpoint(&self) -> String {
        format!("tcp/{}:7447", self.robot_ip)
    }
}

fn credentials(dir: &Path, name: &str, text: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt as _;
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
    p
}

/// The robot PC's configuration: the gateway on the veth address, taking the joystick.
fn graph_config(dir: &Path, ns: &Netns, script: &str) -> PathBuf {
    let creds = credentials(dir, "robot.creds", "operator:right-one\n");
    let p = dir.join("graph.toml");
    std::fs::write(
        &p,
        format!(
            "[joystick]\nscript = \"{script}\"\nstep_hold_s = 1.0\nstep_rest_s = 0.5\n\
             [network]\nenabled = true\naccept_joystick = true\nlease_ms = 500\n\
             listen = [\"{}\"]\ncredentials = \"{}\"\n",
            ns.endpoint(),
            creds.display()
        ),
    )
    .unwrap();
    p
}

/// The gateway's newest heartbeat.
fn gateway(rec: &Recorder) -> Option<NodeStatus> {
    rec.statuses
        .iter()
        .rev()
        .find(|s| s.role == NodeRole::Gateway as u32)
        .copied()
}

fn count(rec: &Recorder, i: usize) -> u32 {
    gateway(rec).map_or(0, |g| g.rule_counts[i])
}

/// Whether the arm moved in the newest state.
fn moving(rec: &Recorder) -> bool {
    rec.robot_states
        .last()
        .is_some_and(|s| s.qdot().iter().any(|v| v.abs() > 1e-6))
}

/// No command changed a joint's speed by more than its acceleration limit allows in one
/// period (the default robot's limits, 40 Hz; [`scl_tests::assert_acceleration_limited`]).
fn assert_acceleration_limited(rec: &Recorder, what: &str) {
    let robot = kinematics::RobotProfile::default_robot();
    let limits = &robot.limits().max_acceleration_rad_s2;
    let checked = scl_tests::assert_acceleration_limited(
        &rec.robot_states,
        &rec.safe_commands,
        limits,
        0.025,
        what,
    );
    assert!(checked > 20, "{what}: {checked} commands checked");
}

/// Starts `scl joystick --remote` in the operator's namespace.
fn remote_operator(
    ns: &Netns,
    endpoint: &str,
    prefix: &ipc_types::Prefix,
    cfg: &Path,
    creds: &Path,
    script: &str,
    stderr: Stdio,
) -> ChildGuard {
    let mut c = ns.scl(Side::Operator, prefix);
    c.args(["joystick", "--config"])
        .arg(cfg)
        .args([
            "--source", "script", "--script", script, "--remote", endpoint,
        ])
        .arg("--credentials")
        .arg(creds)
        .stdout(Stdio::null())
        .stderr(stderr);
    ChildGuard(Some(c.spawn().unwrap()))
}

/// `scl up` in the robot's namespace, until [`finish`] stops it (at most two minutes).
fn up(ns: &Netns, prefix: &ipc_types::Prefix, cfg: &Path) -> ChildGuard {
    let mut c = ns.scl(Side::Robot, prefix);
    c.args(["up", "--json", "--config"])
        .arg(cfg)
        .args(["--for", "120s"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    ChildGuard(Some(c.spawn().unwrap()))
}

/// Stops `scl up` (SIGTERM: bridge first), returns its JSON summary and log.
fn finish(mut g: ChildGuard) -> (serde_json::Value, String) {
    let child = g.take();
    scl_tests::send_signal(child.id(), nix::sys::signal::Signal::SIGTERM);
    let out = child.wait_with_output().unwrap();
    let log = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "scl up failed:\n{log}");
    let summary =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("scl up --json: {e}\n{log}"));
    (summary, log)
}

/// The first forwarded operator sample (not the gateway's stand-in) after tick `t`.
fn first_forwarded_after(samples: &[JoystickInput], t: u64) -> Option<JoystickInput> {
    samples
        .iter()
        .find(|s| s.tick > t && s.buttons & buttons::NO_DEVICE == 0)
        .copied()
}

/// The robot PC's side of a namespace test: graph `tag` (its domain released last, when the
/// guard drops), its configuration with the joystick script `script`, a recorder, and `scl
/// up` in the robot's namespace, once it publishes robot states.
fn start_graph(
    ns: &Netns,
    tag: &str,
    script: &str,
) -> (
    ipc_types::Prefix,
    DomainGuard,
    PathBuf,
    PathBuf,
    Recorder,
    ChildGuard,
) {
    let prefix = unique_prefix(tag);
    let domain = DomainGuard(prefix.clone());
    let dir = temp_dir(tag);
    let cfg = graph_config(&dir, ns, script);
    let mut rec = Recorder::join(&prefix);
    let graph = up(ns, &prefix, &cfg);
    assert!(
        rec.poll_until(Duration::from_secs(15), |r| r.robot_states.len() > 5),
        "the graph did not start"
    );
    (prefix, domain, dir, cfg, rec, graph)
}

/// After [`finish`]: the recorder leaves, the graph must have left nothing, the run's
/// directory goes.
fn clean_up(rec: Recorder, prefix: &ipc_types::Prefix, dir: PathBuf) {
    drop(rec);
    assert_eq!(
        wait_clean(prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_remote_operator_drives_over_the_veth_and_a_cut_stops_the_arm_until_a_new_session() {
    let _serial = serial();
    let ns = Netns::new("c");
    let (prefix, _domain, dir, cfg, mut rec, graph) = start_graph(&ns, "netcut", "circle");
    let op_creds = credentials(&dir, "op.creds", "operator:right-one\n");
    let op = remote_operator(
        &ns,
        &ns.endpoint(),
        &prefix,
        &cfg,
        &op_creds,
        "circle",
        Stdio::null(),
    );
    // Generous: a loaded machine takes seconds to start a debug binary and its session.
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| moving(r)
            && count(r, gateway_counts::FORWARDED) > 40),
        "the remote operator never drove the arm: gateway {:?}",
        gateway(&rec)
    );
    // Cut the link: samples stop reaching the robot PC. A stale stop the loaded machine
    // caused before the cut is not this one: the event is the first heartbeat that counts
    // one more than before the cut (not the newest heartbeat, which may be several ticks on).
    let stale_before = count(&rec, gateway_counts::STALE_STOPS);
    ns.link(false);
    assert!(
        rec.poll_until(Duration::from_secs(5), |r| count(
            r,
            gateway_counts::STALE_STOPS
        ) > stale_before),
        "the gateway never found the input stale"
    );
    let detected = rec
        .statuses
        .iter()
        .find(|s| {
            s.role == NodeRole::Gateway as u32
                && s.rule_counts[gateway_counts::STALE_STOPS] > stale_before
        })
        .unwrap()
        .tick;
    let last_forwarded = rec
        .joystick_samples
        .iter()
        .rfind(|s| s.buttons & buttons::NO_DEVICE == 0)
        .unwrap()
        .tick;
    rec.poll_for(Duration::from_millis(200));
    let after: Vec<_> = rec
        .robot_states
        .iter()
        .filter(|s| s.tick >= detected)
        .copied()
        .collect();
    assert_stop_within_two_ticks(&after, "a cut link");
    eprintln!(
        "cut: the last forwarded sample answered tick {last_forwarded}; the gateway found the \
         input stale at tick {detected} ({} ticks later)",
        detected - last_forwarded
    );
    // Past the lease (500 ms) the session is gone: its liveliness token with it.
    assert!(
        rec.poll_until(Duration::from_secs(5), |r| count(
            r,
            gateway_counts::LINK_LOSSES
        ) >= 1),
        "the gateway never declared the link lost"
    );
    assert!(
        rec.poll_until(Duration::from_secs(5), |r| !moving(r)),
        "the arm did not come to rest"
    );
    // Restored: the old session's samples are refused, the arm stays at rest.
    ns.link(true);
    let restored = rec.robot_states.last().unwrap().tick;
    rec.poll_for(Duration::from_secs(2));
    assert!(
        rec.robot_states
            .iter()
            .filter(|s| s.tick > restored)
            .all(|s| s.qdot().iter().all(|v| v.abs() < 1e-9)),
        "the arm moved on the ended session's input"
    );
    drop(op);
    // A new session (its script starts at rest: neutral first) drives again.
    let op2 = remote_operator(
        &ns,
        &ns.endpoint(),
        &prefix,
        &cfg,
        &op_creds,
        "circle",
        Stdio::null(),
    );
    let rejoined = rec.robot_states.last().unwrap().tick;
    assert!(
        rec.poll_until(Duration::from_secs(30), moving),
        "a new session never drove the arm: gateway {:?}",
        gateway(&rec)
    );
    let first = first_forwarded_after(&rec.joystick_samples, rejoined).unwrap();
    assert!(
        first.axes.iter().all(|a| a.abs() <= 0.05),
        "the first forwarded sample of the new session was not neutral: {first:?}"
    );
    assert_acceleration_limited(&rec, "cut and rejoin");
    drop(op2);
    let (summary, log) = finish(graph);
    assert_misses_only_held_up(&summary, &log, "a cut link");
    clean_up(rec, &prefix, dir);
}

#[test]
fn fifty_ms_of_delay_makes_the_input_stale_and_the_arm_stops_without_a_jerk() {
    let _serial = serial();
    let ns = Netns::new("d");
    let (prefix, _domain, dir, cfg, mut rec, graph) = start_graph(&ns, "netdelay", "step");
    let op_creds = credentials(&dir, "op.creds", "operator:right-one\n");
    let line =
        scl_net::relay::Relay::start(&ns.op, format!("{}:7447", ns.robot_ip), Duration::ZERO)
            .unwrap();
    let _op = remote_operator(
        &ns,
        &line.endpoint(),
        &prefix,
        &cfg,
        &op_creds,
        "step",
        Stdio::null(),
    );
    assert!(
        rec.poll_until(Duration::from_secs(30), moving),
        "the remote operator never drove the arm: gateway {:?}",
        gateway(&rec)
    );
    line.set_delay(Duration::from_millis(50));
    assert!(
        rec.poll_until(Duration::from_secs(5), |r| count(
            r,
            gateway_counts::STALE_STOPS
        ) >= 1),
        "50 ms of delay did not make the input stale"
    );
    let stale_at = gateway(&rec).unwrap().tick;
    rec.poll_for(Duration::from_secs(3));
    assert!(!moving(&rec), "the arm still moves with 50 ms of delay");
    assert!(
        rec.safe_commands
            .iter()
            .any(|c| c.tick >= stale_at && c.flags & safe_flags::STOP != 0)
    );
    // Back to a fast link: the first sample the gateway passes on is neutral.
    line.set_delay(Duration::ZERO);
    let restored = rec.robot_states.last().unwrap().tick;
    assert!(
        rec.poll_until(Duration::from_secs(30), moving),
        "the arm never moved again after the link recovered: gateway {:?}",
        gateway(&rec)
    );
    let first = first_forwarded_after(&rec.joystick_samples, restored).unwrap();
    assert!(
        first.axes.iter().all(|a| a.abs() <= 0.05),
        "motion resumed without neutral input: {first:?}"
    );
    assert_acceleration_limited(&rec, "50 ms delay");
    let (summary, log) = finish(graph);
    assert_misses_only_held_up(&summary, &log, "50 ms delay");
    clean_up(rec, &prefix, dir);
}

#[test]
fn an_operator_with_the_wrong_password_is_refused_and_never_moves_the_arm() {
    let _serial = serial();
    let ns = Netns::new("a");
    let (prefix, _domain, dir, cfg, mut rec, graph) = start_graph(&ns, "netauth", "circle");
    let wrong = credentials(&dir, "wrong.creds", "operator:wrong-one\n");
    let mut op = remote_operator(
        &ns,
        &ns.endpoint(),
        &prefix,
        &cfg,
        &wrong,
        "circle",
        Stdio::piped(),
    );
    let out = op.take().wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the wrong password was let in");
    assert!(err.contains("cannot open a Zenoh session"), "{err}");
    // A world-readable credentials file is refused before any connection, naming its mode.
    let open = dir.join("open.creds");
    std::fs::write(&open, "operator:right-one\n").unwrap();
    let mut c = ns.scl(Side::Operator, &prefix);
    let out = c
        .args(["joystick", "--source", "script", "--remote"])
        .arg(ns.endpoint())
        .arg("--credentials")
        .arg(&open)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("chmod 600"), "{err}");
    rec.poll_for(Duration::from_secs(1));
    let (summary, log) = finish(graph);
    rec.poll();
    assert_eq!(count(&rec, gateway_counts::FORWARDED), 0);
    assert!(
        rec.robot_states
            .iter()
            .all(|s| s.qdot().iter().all(|v| *v == 0.0)),
        "the arm moved"
    );
    assert_eq!(summary["missed"], summary["held_up"], "{log}");
    clean_up(rec, &prefix, dir);
}

#[test]
fn inbound_without_credentials_or_with_an_open_file_refuses_the_graph_naming_it() {
    let dir = temp_dir("netrefuse");
    let prefix = unique_prefix("netrefuse");
    // Released last, after the graph and the recorder (the domain's own file).
    let _domain = DomainGuard(prefix.clone());
    let p = dir.join("graph.toml");
    std::fs::write(&p, "[network]\nenabled = true\naccept_joystick = true\n").unwrap();
    let out = scl_tests::scl(&prefix)
        .args(["up", "--for", "1s", "--config"])
        .arg(&p)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("network.credentials"),
        "{err}"
    );
    let creds = dir.join("open.creds");
    std::fs::write(&creds, "operator:pw\n").unwrap();
    std::fs::write(
        &p,
        format!(
            "[network]\nenabled = true\naccept_joystick = true\ncredentials = \"{}\"\n",
            creds.display()
        ),
    )
    .unwrap();
    let out = scl_tests::scl(&prefix)
        .args(["up", "--for", "1s", "--config"])
        .arg(&p)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("mode 0644"), "{err}");
    assert!(wait_clean(&prefix, Duration::from_secs(5)).is_empty());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn scl_top_watches_a_graph_through_its_gateway() {
    let _serial = serial();
    let dir = temp_dir("nettop");
    let prefix = unique_prefix("nettop");
    // Released last, after the graph and the recorder (the domain's own file).
    let _domain = DomainGuard(prefix.clone());
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let cfg = dir.join("graph.toml");
    std::fs::write(
        &cfg,
        format!("[network]\nenabled = true\nlisten = [\"tcp/127.0.0.1:{port}\"]\n"),
    )
    .unwrap();
    let mut rec = Recorder::join(&prefix);
    let mut c = scl_tests::scl(&prefix);
    c.args(["up", "--json", "--for", "120s", "--config"])
        .arg(&cfg)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let graph = ChildGuard(Some(c.spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(15), |r| r.robot_states.len() > 5));
    let out = scl_tests::scl(&prefix)
        .args(["top", "--once", "--config"])
        .arg(&cfg)
        .arg("--remote")
        .arg(format!("tcp/127.0.0.1:{port}"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for node in ["joystick", "mapper", "safety", "bridge", "gateway"] {
        assert!(
            text.lines()
                .any(|l| l.starts_with(node) && l.contains(" yes ")),
            "{node} is not shown live:\n{text}"
        );
    }
    assert!(text.contains(&format!("graph `{prefix}`")), "{text}");
    let (summary, log) = finish(graph);
    assert_misses_only_held_up(&summary, &log, "scl top --remote");
    clean_up(rec, &prefix, dir);
}

/// What a recording says each mapper and safety process ran: its `scl.process` records by
/// pid (less `t_ns`, when that recorder first saw the process) and its attachments by name.
type Processes = (
    std::collections::BTreeMap<String, std::collections::BTreeMap<String, String>>,
    std::collections::BTreeMap<String, Vec<u8>>,
);

fn processes_of(path: &Path) -> Processes {
    let (mut records, mut files) = (
        std::collections::BTreeMap::new(),
        std::collections::BTreeMap::new(),
    );
    recording::read_file(path, |ev| {
        match ev {
            recording::Event::Metadata { name, entries } if name == recording::PROCESS_METADATA => {
                let mut e = entries.clone();
                e.remove("t_ns");
                records.insert(e["pid"].clone(), e);
            }
            recording::Event::Attachment { name, data, .. } => {
                files.insert(name.to_owned(), data.to_vec());
            }
            _ => {}
        }
        Ok(())
    })
    .unwrap();
    (records, files)
}

/// Robot states in `path` so far (a recording being written: read up to its last chunk).
fn states_in(path: &Path) -> usize {
    let mut n = 0;
    let _ = recording::read_file(path, |ev| {
        if let recording::Event::Message { channel, .. } = ev
            && channel.topic == "/robot_state"
        {
            n += 1;
        }
        Ok(())
    });
    n
}

/// `scl replay --json` of `path`: its exit code and report.
fn replay(path: &Path) -> (Option<i32>, serde_json::Value) {
    let out = Command::new(scl_binary())
        .env("SCL_LOG", "warn")
        .args(["replay", "--json"])
        .arg(path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let v = serde_json::from_str(text.trim())
        .unwrap_or_else(|e| panic!("{e}: {text} {}", String::from_utf8_lossy(&out.stderr)));
    (out.status.code(), v)
}

/// Stops a recorder (SIGINT, as Ctrl-C) and returns its output, checking it succeeded.
fn stop_recorder(mut g: ChildGuard, what: &str) -> std::process::Output {
    let child = g.take();
    scl_tests::send_signal(child.id(), nix::sys::signal::Signal::SIGINT);
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `scl` run to completion on this machine's graph while `rec` polls; it must succeed.
fn scl_ok(prefix: &ipc_types::Prefix, args: &[&std::ffi::OsStr], rec: &mut Recorder) {
    let mut c = scl_tests::scl(prefix);
    c.args(args);
    let out = scl_tests::run_polling(c, rec);
    assert!(
        out.status.success(),
        "scl {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_remote_recording_holds_what_a_local_one_holds_and_replays_bit_for_bit() {
    let _serial = serial();
    let ns = Netns::new("r");
    let (prefix, _domain, dir, cfg, mut rec, graph) = start_graph(&ns, "netrec", "circle");
    let op_creds = credentials(&dir, "op.creds", "operator:right-one\n");
    let pca = scl_tests::joint_reach_pca(&dir, None);
    let (local_file, remote_file) = (dir.join("local.mcap"), dir.join("remote.mcap"));
    // A wrong password is refused during the handshake, and no file is made.
    let wrong = credentials(&dir, "wrong.creds", "operator:wrong-one\n");
    let refused = dir.join("refused.mcap");
    let out = ns
        .scl(Side::Operator, &prefix)
        .args(["record", "--remote", &ns.endpoint(), "--credentials"])
        .arg(&wrong)
        .arg("--out")
        .arg(&refused)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("cannot open a Zenoh session"),
        "{err}"
    );
    assert!(!refused.exists());
    // This machine's recorder (shared memory), and the operator's through the gateway, which
    // requires the login.
    let mut c = scl_tests::scl(&prefix);
    c.args(["record", "--out"])
        .arg(&local_file)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let local = ChildGuard(Some(c.spawn().unwrap()));
    let mut c = ns.scl(Side::Operator, &prefix);
    c.args([
        "record",
        "--json",
        "--remote",
        &ns.endpoint(),
        "--credentials",
    ])
    .arg(&op_creds)
    .arg("--out")
    .arg(&remote_file)
    .stdout(Stdio::piped())
    .stderr(Stdio::piped());
    let remote = ChildGuard(Some(c.spawn().unwrap()));
    // Both record before anyone drives: the replay's filter starts from rest and neutral
    // input, where safety was when each recording began.
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| r
            .statuses
            .iter()
            .any(|s| s.role == NodeRole::Recorder as u32)),
        "the local recorder never started"
    );
    let mut remote_states = 0;
    for _ in 0..600 {
        rec.poll_for(Duration::from_millis(100));
        remote_states = states_in(&remote_file);
        if remote_states > 0 {
            break;
        }
    }
    assert!(remote_states > 0, "the remote recording got no robot state");
    let op = remote_operator(
        &ns,
        &ns.endpoint(),
        &prefix,
        &cfg,
        &op_creds,
        "circle",
        Stdio::null(),
    );
    assert!(
        rec.poll_until(Duration::from_secs(60), |r| moving(r)
            && count(r, gateway_counts::FORWARDED) > 40),
        "the remote operator never drove the arm: gateway {:?}",
        gateway(&rec)
    );
    // A live swap to a model file: its model reaches the remote recording as it happens.
    scl_ok(&prefix, &["swap".as_ref(), pca.as_os_str()], &mut rec);
    assert!(
        rec.poll_until(Duration::from_secs(30), |r| r
            .safe_commands
            .iter()
            .any(|c| c.mapper_id == 2)),
        "the swapped-in mapper never drove"
    );
    rec.poll_for(Duration::from_secs(1));
    // An e-stop and its reset: the safety controls travel too.
    scl_ok(&prefix, &["estop".as_ref()], &mut rec);
    rec.poll_for(Duration::from_millis(500));
    scl_ok(&prefix, &["reset".as_ref()], &mut rec);
    rec.poll_for(Duration::from_millis(500));
    drop(op);
    let out = stop_recorder(remote, "scl record --remote");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!("{e}: {}", String::from_utf8_lossy(&out.stderr));
    });
    assert_eq!(report["dropped"], 0, "{report}");
    stop_recorder(local, "scl record");
    let (summary, log) = finish(graph);
    assert_misses_only_held_up(&summary, &log, "a remote recording");

    // The same models and configuration, from the same processes.
    let (local_procs, local_files) = processes_of(&local_file);
    let (remote_procs, remote_files) = processes_of(&remote_file);
    assert_eq!(remote_procs, local_procs);
    assert_eq!(
        remote_files.keys().collect::<Vec<_>>(),
        local_files.keys().collect::<Vec<_>>()
    );
    assert_eq!(remote_files, local_files);
    let names: Vec<&String> = remote_files.keys().collect();
    for want in ["model/mapper-1/", "model/mapper-2/", "config/safety/"] {
        assert!(
            names.iter().any(|n| n.starts_with(want)),
            "{want}: {names:?}"
        );
    }
    assert!(
        names.iter().any(|n| n.ends_with("pca.safetensors")),
        "{names:?}"
    );
    assert_eq!(
        remote_procs
            .values()
            .filter(|e| e.contains_key("error"))
            .count(),
        0,
        "{remote_procs:?}"
    );
    // Both replay bit for bit, through the swap, the e-stop and its reset.
    for f in [&remote_file, &local_file] {
        let (code, v) = replay(f);
        assert_eq!(code, Some(0), "{}: {v}", f.display());
        let ticks = v["ticks"].as_u64().unwrap();
        assert!(ticks >= 100, "{}: {v}", f.display());
        assert_eq!(v["identical"].as_u64(), Some(ticks), "{}: {v}", f.display());
        assert_eq!(v["diverged"].as_u64(), Some(0), "{}: {v}", f.display());
        assert_eq!(v["skipped"].as_u64(), Some(0), "{}: {v}", f.display());
        assert_eq!(v["mapper_identical"], v["mapper_commands"], "{v}");
        let events: Vec<&str> = v["events"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|e| e["event"].as_str())
            .collect();
        for e in ["swap", "estop", "reset"] {
            assert!(
                events.contains(&e),
                "{}: {e} not in {events:?}",
                f.display()
            );
        }
    }
    clean_up(rec, &prefix, dir);
}

#[test]
fn scl_live_serves_a_graph_through_its_gateway() {
    let _serial = serial();
    let ns = Netns::new("l");
    let (prefix, _domain, dir, _cfg, mut rec, graph) = start_graph(&ns, "netlive", "circle");
    let op_creds = credentials(&dir, "op.creds", "operator:right-one\n");
    let mut c = ns.scl(Side::Operator, &prefix);
    c.args([
        "live",
        "--announce",
        "--listen",
        "127.0.0.1:0",
        "--remote",
        &ns.endpoint(),
        "--credentials",
    ])
    .arg(&op_creds)
    .stdout(Stdio::piped())
    .stderr(Stdio::piped());
    let mut live = ChildGuard(Some(c.spawn().unwrap()));
    // Its announcement names the address it serves (in the operator's namespace).
    let mut line = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(live.child().stdout.take().unwrap()),
        &mut line,
    )
    .unwrap();
    let addr = line
        .trim()
        .strip_prefix("scl-ready ")
        .unwrap_or_else(|| panic!("scl live --remote did not start: {line}"))
        .to_owned();
    // A Foxglove client on the operator's machine: the channels a local `scl live` serves,
    // robot states with the graph's ticks, and the map's arrows (the mapper's model, as the
    // gateway captured it).
    let netns = ns.op.clone();
    let client = std::thread::spawn(move || {
        let f = std::fs::File::open(format!("/var/run/netns/{netns}")).unwrap();
        nix::sched::setns(f, nix::sched::CloneFlags::CLONE_NEWNET).unwrap();
        let mut c = viz::client::Client::connect(&addr, Duration::from_secs(30)).unwrap();
        let topics: Vec<String> = c.channels.values().map(|a| a.topic.clone()).collect();
        let (state, tick) = (
            c.channel("/robot_state").unwrap(),
            c.channel("/scl/tick").unwrap(),
        );
        c.subscribe(&[state, tick]).unwrap();
        let (mut ticks, mut with_map) = (Vec::new(), 0);
        // Frames counted, not timed: a loaded machine only takes longer.
        for _ in 0..100_000 {
            if ticks.len() >= 80 && with_map >= 20 {
                break;
            }
            let Some(fr) = c.next_frame().unwrap() else {
                continue;
            };
            let v: serde_json::Value = serde_json::from_slice(&fr.data).unwrap();
            if u64::from(fr.subscription) == state {
                ticks.push(v["tick"].as_u64().unwrap());
            } else if !v["axis1_m_s"].is_null() {
                with_map += 1;
            }
        }
        c.close();
        (topics, ticks, with_map)
    });
    while !client.is_finished() {
        rec.poll_for(Duration::from_millis(100));
    }
    let (topics, ticks, with_map) = client.join().unwrap();
    for t in [
        "/robot_state",
        "/joystick",
        "/mapper_command",
        "/safe_command",
        "/status",
        "/safety_control",
        "/estop",
        "/tf",
        "/scl/arm",
        "/scl/map",
        "/scl/world",
        "/scl/tick",
    ] {
        assert!(topics.iter().any(|x| x == t), "{t} not served: {topics:?}");
    }
    assert!(ticks.len() >= 80, "{} robot states", ticks.len());
    assert!(with_map >= 20, "the map's arrows in {with_map} ticks");
    assert!(ticks.windows(2).all(|w| w[1] > w[0]), "{ticks:?}");
    rec.poll();
    let newest = rec.robot_states.last().unwrap().tick;
    assert!(
        ticks.iter().all(|t| *t <= newest),
        "ticks the graph did not publish (newest {newest}): {ticks:?}"
    );
    stop_recorder(live, "scl live --remote");
    let (summary, log) = finish(graph);
    assert_misses_only_held_up(&summary, &log, "scl live --remote");
    clean_up(rec, &prefix, dir);
}
