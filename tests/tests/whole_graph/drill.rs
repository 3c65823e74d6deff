//! `scl drill` on the mock arm: a short drill of the default graph keeps every promise (a
//! stick reading far outside the disc is mapped on its edge and stops nothing; a killed
//! recorder ends the graph, its stop seen by the drill itself after the file's end), and a
//! graph whose configured stop is slower than documented (`[safety] max_acceleration_rad_s2`
//! at a fifth of the profile's) fails the row of a stop safety ramps down (a silent
//! joystick), naming the distance; the command exits 1 then. Each drill run leaves nothing in
//! shared memory (a row checks it).

use std::process::Output;

use scl_tests::{scl_binary, serial, temp_dir};

/// `scl drill --json --repeat 1 --only DRILLS` with the configuration `toml` (none: the
/// defaults); its exit status and report.
fn drill(tag: &str, toml: Option<&str>, drills: &str) -> (Output, serde_json::Value) {
    let dir = temp_dir(tag);
    let mut cmd = std::process::Command::new(scl_binary());
    cmd.env("SCL_LOG", "warn")
        .args([
            "drill", "--json", "--repeat", "1", "--only", drills, "--out",
        ])
        .arg(dir.join("runs"));
    if let Some(t) = toml {
        let cfg = dir.join("graph.toml");
        std::fs::write(&cfg, t).unwrap();
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
