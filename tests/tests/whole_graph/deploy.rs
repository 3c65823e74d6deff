//! `scl up` as a systemd `Type=notify` service, with a notification socket this test owns in
//! place of systemd's: `READY=1` once, after the first executed tick; `WATCHDOG=1` while the
//! graph runs; none once the bridge is SIGSTOPped (a wedged graph, which systemd then
//! restarts); again once it runs; `STOPPING=1` at the end.
#![allow(clippy::unwrap_used, missing_docs)]

use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ipc_types::{NodeRole, state_flags};
use scl_tests::{ChildGuard, DomainGuard, Recorder, Signal, scl_binary, serial, unique_prefix};

type Log = Arc<Mutex<Vec<(Instant, String)>>>;

fn count(log: &Log, word: &str, since: Instant) -> usize {
    log.lock()
        .unwrap()
        .iter()
        .filter(|(t, m)| *t >= since && m == word)
        .count()
}

#[test]
fn scl_up_tells_systemd_it_is_ready_and_pets_the_watchdog_only_while_the_bridge_beats() {
    let _serial = serial();
    let prefix = unique_prefix("notify");
    let _domain = DomainGuard(prefix.clone());
    let dir = scl_tests::temp_dir("notify");
    let path = dir.join("notify.sock");
    let sock = UnixDatagram::bind(&path).unwrap();
    sock.set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let log: Log = Arc::default();
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reader = {
        let (log, stop) = (log.clone(), stop.clone());
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(n) = sock.recv(&mut buf) {
                    let text = String::from_utf8_lossy(&buf[..n]).into_owned();
                    log.lock().unwrap().push((Instant::now(), text));
                }
            }
        })
    };
    let mut rec = Recorder::join(&prefix);
    // A one-second watchdog: a pet every half second while the graph is alive.
    let mut guard = ChildGuard(Some(
        Command::new(scl_binary())
            .args(["up", "--for", "60s", "--json"])
            .env("SCL_PREFIX", prefix.as_str())
            .env("SCL_LOG", "info")
            .env("NOTIFY_SOCKET", &path)
            .env("WATCHDOG_USEC", "1000000")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(dir.join("up.log")).unwrap())
            .spawn()
            .unwrap(),
    ));
    let t0 = Instant::now();
    let messages =
        |log: &Log| -> Vec<String> { log.lock().unwrap().iter().map(|(_, m)| m.clone()).collect() };
    assert!(
        rec.poll_until(Duration::from_secs(30), |_| count(&log, "WATCHDOG=1", t0)
            >= 2)
    );
    let first = messages(&log);
    assert_eq!(first[0], "READY=1", "{first:?}");
    // Ready came after the bridge executed a tick: the recorder saw a running state by now.
    assert!(
        rec.robot_states
            .iter()
            .any(|s| s.flags & state_flags::SHUTDOWN == 0)
    );

    // The bridge wedged: no pet once its last heartbeat is older than ten periods (250 ms;
    // 400 ms more for this test's own reading of the socket).
    let pid = rec.pid_of(NodeRole::Bridge).unwrap();
    let stopped = Instant::now();
    scl_tests::send_signal(pid, Signal::SIGSTOP);
    rec.poll_for(Duration::from_millis(2500));
    let pets_while_stopped = count(&log, "WATCHDOG=1", stopped + Duration::from_millis(650));
    scl_tests::send_signal(pid, Signal::SIGCONT);
    let resumed = Instant::now();
    assert!(
        rec.poll_until(Duration::from_secs(10), |_| count(
            &log,
            "WATCHDOG=1",
            resumed
        ) >= 1),
        "no pet after the bridge ran again: {:?}",
        messages(&log)
    );
    assert_eq!(
        pets_while_stopped,
        0,
        "petted while the bridge was stopped: {:?}",
        log.lock().unwrap()
    );

    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    while guard.child().try_wait().unwrap().is_none() {
        rec.poll();
        std::thread::sleep(Duration::from_millis(2));
    }
    let out = guard.take().wait_with_output().unwrap();
    assert!(out.status.success(), "scl up failed: {:?}", out.status);
    std::thread::sleep(Duration::from_millis(100));
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    reader.join().unwrap();
    let all = messages(&log);
    assert_eq!(all.iter().filter(|m| *m == "READY=1").count(), 1, "{all:?}");
    assert_eq!(
        all.last().map(String::as_str),
        Some("STOPPING=1"),
        "{all:?}"
    );
    println!(
        "notifications: {} (READY=1 once, {} WATCHDOG=1, STOPPING=1)",
        all.len(),
        count(&log, "WATCHDOG=1", t0)
    );
    // What the journal gets: every process's log without terminal colours.
    let text = std::fs::read_to_string(dir.join("up.log")).unwrap();
    assert!(text.lines().count() > 5, "{text}");
    assert!(
        !text.contains('\u{1b}'),
        "colour codes in a log that is not a terminal"
    );
    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        scl_tests::wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
