//! Whole-graph tests of `scl up --live`'s start: a port another program holds refuses the
//! graph with the live server's own error (nothing starts, nothing is left behind), and a
//! normal start logs no error (the supervisor does not probe the server with a connection of
//! its own; the live child announces that it serves, and on which port).

use std::net::TcpListener;
use std::process::{Output, Stdio};
use std::time::Duration;

use ipc_types::{NodeRole, Prefix};
use scl_tests::{
    DomainGuard, Recorder, leftovers, run_polling, scl, serial, unique_prefix, wait_clean,
};

/// A plain TCP server on an ephemeral loopback port (another program on the port `scl up
/// --live` is asked for, as ROS's `foxglove_bridge` on 8765): accepts connections and says
/// nothing. Returns it with its address.
fn occupied_port() -> (TcpListener, String) {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = l.local_addr().unwrap().to_string();
    let l2 = l.try_clone().unwrap();
    std::thread::spawn(move || {
        // Each connection held open a moment, then dropped: a server that does not speak
        // Foxglove.
        for c in l2.incoming().flatten() {
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(200));
                drop(c);
            });
        }
    });
    (l, addr)
}

/// `scl up --live ADDR --for 2s --json` on graph `prefix`, logging at `level`.
fn up_live(prefix: &Prefix, addr: &str, level: &str) -> std::process::Command {
    let mut up = scl(prefix);
    up.env("SCL_LOG", level)
        .args(["up", "--for", "2s", "--json", "--live", addr]);
    up
}

fn refused(out: &Output, addr: &str) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        !out.status.success(),
        "scl up --live on a port in use exited {}: {stderr}",
        out.status
    );
    assert!(
        out.stdout.is_empty(),
        "a summary of a graph that ran: {}",
        String::from_utf8_lossy(&out.stdout)
    );
    let error = stderr
        .lines()
        .find(|l| l.starts_with("scl up: error:"))
        .unwrap_or_else(|| panic!("no error line: {stderr}"));
    assert!(
        error.contains(addr) && error.contains("live server"),
        "the error does not name the live server and {addr}: {error}"
    );
    stderr
}

#[test]
fn a_live_port_in_use_refuses_the_graph_and_no_bridge_runs() {
    let _serial = serial();
    let prefix = unique_prefix("lport-busy");
    let _domain = DomainGuard(prefix.clone());
    let (_listener, addr) = occupied_port();
    let mut rec = Recorder::join(&prefix);
    let out = run_polling(up_live(&prefix, &addr, "warn"), &mut rec);
    let stderr = refused(&out, &addr);
    assert!(
        stderr.to_lowercase().contains("in use"),
        "the live server's own error (address in use) is not shown: {stderr}"
    );
    // No arm motion: no bridge, no state, no process of the graph ever said it was there.
    assert!(
        rec.robot_states.is_empty(),
        "{} robot states",
        rec.robot_states.len()
    );
    let roles: Vec<u32> = rec.statuses.iter().map(|s| s.role).collect();
    assert!(
        !roles.contains(&(NodeRole::Bridge as u32)),
        "a bridge ran: {roles:?}"
    );
    drop(rec);
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_live_port_in_use_leaves_nothing_in_shared_memory() {
    let _serial = serial();
    let prefix = unique_prefix("lport-shm");
    let _domain = DomainGuard(prefix.clone());
    let (_listener, addr) = occupied_port();
    let out = up_live(&prefix, &addr, "warn")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    refused(&out, &addr);
    // Nothing of the graph is left, without anyone releasing it after `scl up`.
    assert_eq!(leftovers(&prefix), Vec::<String>::new());
}

/// The address `scl up` says Foxglove should connect to (its info line).
fn announced(stderr: &str) -> Option<String> {
    let (_, rest) = stderr.split_once("Foxglove: open a connection to ws://")?;
    Some(rest.split_whitespace().next()?.to_owned())
}

#[test]
fn a_normal_live_start_logs_no_error_and_names_the_port_it_serves() {
    let _serial = serial();
    let prefix = unique_prefix("lport-ok");
    let _domain = DomainGuard(prefix.clone());
    // Port 0: the live child binds a port the system chooses and says which.
    let out = up_live(&prefix, "127.0.0.1:0", "info")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up --live failed: {stderr}");
    for bad in ["handshake failed", "ERROR", "error:"] {
        assert!(
            !stderr.contains(bad),
            "a normal live start logged `{bad}`: {stderr}"
        );
    }
    let at = announced(&stderr).unwrap_or_else(|| panic!("no Foxglove address: {stderr}"));
    let port: u16 = at.rsplit_once(':').unwrap().1.parse().unwrap();
    assert!(at.starts_with("127.0.0.1:") && port != 0, "{at}");
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

#[test]
fn a_normal_live_start_on_a_free_port_logs_no_error() {
    let _serial = serial();
    let prefix = unique_prefix("lport-free");
    let _domain = DomainGuard(prefix.clone());
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr = format!("127.0.0.1:{port}");
    let out = up_live(&prefix, &addr, "warn")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl up --live failed: {stderr}");
    assert!(
        !stderr.contains("handshake failed") && !stderr.contains("ERROR"),
        "a normal live start logged an error: {stderr}"
    );
    assert_eq!(
        wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}
