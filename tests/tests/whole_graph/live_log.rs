//! Whole-graph tests of the processes' own logs on Foxglove: a process's `tracing` warning
//! reaches a Foxglove client of `scl up --live` on `/scl/log` (`foxglove.Log`), named after
//! the process, at its level, with its text; and a recording's `/scl/log` holds it too.

use std::io::BufRead;
use std::process::Stdio;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use foxglove::messages::Log;
use foxglove::messages::log::Level;
use prost::Message;
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, run_polling, scl, serial, temp_dir, unique_prefix,
    wait_clean,
};
use viz::client::Client;

/// Safety's own warning of the stale-joystick drill (`stopping the arm ...`), not the line the
/// observers derive from its commands (`safety, tick N: ...`).
fn is_safetys_stop_warning(l: &Log) -> bool {
    l.name == "safety"
        && l.level == Level::Warning as i32
        && l.message.starts_with("stopping the arm")
        && l.message.contains("stale-joystick")
}

/// The documented stale-joystick drill: the joystick goes silent after `ticks` (its process
/// lives on), so safety stops the arm and logs `stopping the arm ... stale-joystick`.
fn silent_joystick_config(dir: &std::path::Path, ticks: u32) -> std::path::PathBuf {
    let cfg = dir.join("graph.toml");
    std::fs::write(
        &cfg,
        format!("[faults]\njoystick_silent_after_ticks = {ticks}\n"),
    )
    .unwrap();
    cfg
}

#[test]
fn a_recordings_scl_log_holds_the_processes_own_warnings() {
    let _serial = serial();
    let prefix = unique_prefix("log-rec");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("log-rec");
    let cfg = silent_joystick_config(&dir, 40);
    let path = dir.join("run.mcap");
    let mut rec = Recorder::join(&prefix);
    let mut up = scl(&prefix);
    up.arg("up")
        .arg("--config")
        .arg(&cfg)
        .args(["--for", "4s", "--record"])
        .arg(&path);
    let out = run_polling(up, &mut rec);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up failed: {stderr}");
    let bytes = std::fs::read(&path).unwrap();
    let lines: Vec<Log> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == "/scl/log")
        .map(|m| Log::decode(&*m.data).unwrap())
        .collect();
    assert!(
        lines.iter().any(is_safetys_stop_warning),
        "{:?}",
        lines
            .iter()
            .map(|l| (l.name.as_str(), l.message.as_str()))
            .collect::<Vec<_>>()
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_process_warning_reaches_foxglove_on_scl_log_with_the_process_name() {
    let _serial = serial();
    let prefix = unique_prefix("live-log");
    let _domain = DomainGuard(prefix.clone());
    let dir = temp_dir("live-log");
    // The joystick goes silent after 3 s, once the client listens.
    let cfg = silent_joystick_config(&dir, 120);
    let mut up = scl(&prefix);
    up.env("SCL_LOG", "info")
        .arg("up")
        .arg("--config")
        .arg(&cfg)
        .args(["--for", "8s", "--live", "127.0.0.1:0"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut guard = ChildGuard(Some(up.spawn().unwrap()));
    // stderr: the address the live server serves on, then everything else kept.
    let stderr = guard.child().stderr.take().unwrap();
    let (addr_tx, addr_rx) = mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in std::io::BufReader::new(stderr).lines() {
            let line = line.unwrap();
            if let Some((_, rest)) = line.split_once("Foxglove: open a connection to ws://") {
                let _ = addr_tx.send(rest.split_whitespace().next().unwrap().to_owned());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let addr = addr_rx
        .recv_timeout(Duration::from_secs(30))
        .expect("scl up did not say where Foxglove connects");
    let mut c = Client::connect(&addr, Duration::from_secs(5)).unwrap();
    let log = c.channel("/scl/log").unwrap();
    assert_eq!(c.channels[&log].schema_name, "foxglove.Log");
    c.subscribe(&[log]).unwrap();
    let mut lines: Vec<Log> = Vec::new();
    let seen = |lines: &[Log]| lines.iter().any(is_safetys_stop_warning);
    let t0 = Instant::now();
    while !seen(&lines) && t0.elapsed() < Duration::from_secs(20) {
        if let Some(f) = c.next_frame().unwrap() {
            lines.push(Log::decode(f.data.as_slice()).unwrap());
        }
    }
    c.close();
    let status = guard.take().wait().unwrap();
    let stderr = reader.join().unwrap();
    assert!(
        seen(&lines),
        "no `stopping the arm` warning of safety on /scl/log: {:?}\nscl up's log:\n{stderr}",
        lines
            .iter()
            .map(|l| (l.name.as_str(), l.level, l.message.as_str()))
            .collect::<Vec<_>>()
    );
    assert!(status.success(), "scl up failed: {stderr}");
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
