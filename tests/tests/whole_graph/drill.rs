//! `scl drill` on the mock arm: a short drill of the default graph keeps every promise (a
//! stick reading far outside the disc is mapped on its edge and stops nothing; a killed
//! recorder ends the graph, its stop seen by the drill itself after the file's end), and a
//! graph whose configured stop is slower than documented (`[safety] max_acceleration_rad_s2`
//! at a fifth of the profile's) fails the row of a stop safety ramps down (a silent
//! joystick), naming the distance; the command exits 1 then. Each drill run leaves nothing in
//! shared memory (a row checks it). With a remote operator (`[network] accept_joystick`), the
//! gateway's `kill -9` and a cut link stop the arm within their promises.

use std::process::Output;

use scl_tests::{scl_binary, serial, temp_dir};

/// `scl drill --json --repeat 1 --only DRILLS` with the configuration `toml` (none: the
/// defaults; `@CREDS@` in it names a credentials file of the run, mode 0600); its exit status
/// and report.
fn drill(tag: &str, toml: Option<&str>, drills: &str) -> (Output, serde_json::Value) {
    use std::os::unix::fs::PermissionsExt as _;
    let dir = temp_dir(tag);
    let creds = dir.join("net.creds");
    std::fs::write(&creds, "operator:drill-only\n").unwrap();
    std::fs::set_permissions(&creds, std::fs::Permissions::from_mode(0o600)).unwrap();
    let mut cmd = std::process::Command::new(scl_binary());
    cmd.env("SCL_LOG", "warn")
        .args([
            "drill", "--json", "--repeat", "1", "--only", drills, "--out",
        ])
        .arg(dir.join("runs"));
    if let Some(t) = toml {
        let cfg = dir.join("graph.toml");
        std::fs::write(&cfg, t.replace("@CREDS@", &creds.display().to_string())).unwrap();
        cmd.arg("--config").arg(&cfg);
    }
    let out = cmd.output().unwrap();
    let report = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "no report ({e}): {:?}\n{}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        )
    });
    std::fs::remove_dir_all(&dir).unwrap();
    (out, report)
}

fn row<'a>(report: &'a serde_json::Value, fault: &str) -> &'a serde_json::Value {
    report["rows"]
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["fault"] == fault)
        .unwrap_or_else(|| panic!("no row {fault}: {report}"))
}

#[test]
fn a_short_drill_of_the_default_graph_passes() {
    let _serial = serial();
    let (out, report) = drill(
        "drillok",
        None,
        "estop,kill-mapper,kill-recorder,out-of-range",
    );
    assert!(out.status.success(), "{report:#}");
    // A reading far outside the stick's disc was mapped on its edge, and nothing stopped.
    let r = row(&report, "out-of-range");
    assert_eq!(r["result"], "PASS", "{r:#}");
    let f = &r["runs"][0]["figures"];
    assert!(f["max_input"].as_f64().unwrap() > 40.0, "{f}");
    assert!(f["max_action"].as_f64().unwrap() <= 1.0 + 1e-6, "{f}");
    assert_eq!(f["stop_commands"], 0, "{f}");
    // The recorder killed: its file ends before the kill, the drill's own view fills in the
    // stop (the graph ends, bridge first).
    for fault in ["estop", "kill-mapper", "kill-recorder"] {
        let r = row(&report, fault);
        assert_eq!(r["result"], "PASS", "{r:#}");
        let f = &r["runs"][0]["figures"];
        // The arm was moving at the fault and stopped within the promise.
        assert!(f["speed_at_fault_rad_s"].as_f64().unwrap() > 0.01, "{f}");
        assert!(f["stop_ticks"].as_u64().unwrap() <= r["promise"]["stop_ticks"].as_u64().unwrap());
        assert_eq!(r["runs"][0]["leftovers"], 0);
    }
}

#[test]
fn a_slower_stop_than_documented_fails_its_row() {
    let _serial = serial();
    // The Gen3 lite's documented accelerations [1.0, 0.5, 0.4, 1.0, 10.0, 10.0], a fifth.
    let slow = "[safety]\nmax_acceleration_rad_s2 = [0.2, 0.1, 0.08, 0.2, 2.0, 2.0]\n";
    let (out, report) = drill("drillslow", Some(slow), "stale-joystick");
    assert_eq!(out.status.code(), Some(1), "{report:#}");
    let r = row(&report, "stale-joystick");
    assert_eq!(r["result"], "FAIL", "{r:#}");
    let broken = r["runs"][0]["broken"].to_string();
    assert!(broken.contains("promised stop distance"), "{broken}");
    assert_eq!(report["passed"], false);
}

#[test]
fn a_remote_operators_lost_gateway_or_cut_link_stops_the_arm() {
    let _serial = serial();
    let net = "[network]\nenabled = true\naccept_joystick = true\nlease_ms = 500\n\
               credentials = \"@CREDS@\"\n";
    let (out, report) = drill("drillnet", Some(net), "kill-gateway,link-cut");
    assert!(out.status.success(), "{report:#}");
    for fault in ["kill-gateway", "link-cut"] {
        let r = row(&report, fault);
        assert_eq!(r["result"], "PASS", "{r:#}");
        let f = &r["runs"][0]["figures"];
        // The remote operator drove the arm to the fault, and the stop came within the
        // promise: the gateway's staleness rule (2 ticks) for the cut, the joystick's age
        // limit for the gateway's death.
        assert!(f["speed_at_fault_rad_s"].as_f64().unwrap() > 0.01, "{f}");
        assert!(f["stop_ticks"].as_u64().unwrap() <= r["promise"]["stop_ticks"].as_u64().unwrap());
        assert_ne!(f["resumed"], "before-neutral", "{f}");
        assert_eq!(r["runs"][0]["leftovers"], 0);
    }
    assert_eq!(row(&report, "link-cut")["promise"]["stop_ticks"], 4);
}

#[test]
fn the_network_drills_need_a_gateway_and_a_remote_operator() {
    let _serial = serial();
    // No network: the default drill leaves both out, saying why; asking for one is an error.
    let out = std::process::Command::new(scl_binary())
        .env("SCL_LOG", "warn")
        .args(["drill", "--only", "link-cut"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("link-cut") && err.contains("accept_joystick"),
        "{err}"
    );
    // A gateway that serves observers only: its death must not disturb the loop.
    let (out, report) = drill(
        "drillobs",
        Some("[network]\nenabled = true\n"),
        "kill-gateway",
    );
    assert!(out.status.success(), "{report:#}");
    let r = row(&report, "kill-gateway");
    assert_eq!(r["promise"]["stops"], false, "{r:#}");
    assert_eq!(r["runs"][0]["figures"]["stop_commands"], 0, "{r:#}");
}
