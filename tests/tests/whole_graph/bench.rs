//! `scl bench latency` end to end: the real command runs the whole graph on both transports
//! (iceoryx2, then Unix datagram sockets), and its report carries every figure the issue
//! names, the machine, the settings and the ratios, with a histogram PNG. No latency figure is
//! asserted (the machine is shared); that each figure was measured, is.
#![allow(clippy::unwrap_used, missing_docs)]

use std::process::Stdio;

use scl_tests::{scl_binary, serial, temp_dir, unique_prefix};

/// Every distribution in the report: measured (samples taken) and ordered.
fn check_dist(name: &str, d: &serde_json::Value, min_samples: u64) {
    let n = d["n"].as_u64().unwrap_or(0);
    assert!(n >= min_samples, "{name}: {n} samples: {d}");
    let q: Vec<f64> = ["p50", "p90", "p99", "p999", "max"]
        .iter()
        .map(|k| d[*k].as_f64().unwrap())
        .collect();
    assert!(q[0] > 0.0, "{name}: p50 {}", q[0]);
    for w in q.windows(2) {
        assert!(w[0] <= w[1], "{name}: quantiles out of order: {d}");
    }
}

#[test]
fn bench_latency_measures_both_transports() {
    let _serial = serial();
    let dir = temp_dir("bench");
    let out_dir = dir.join("out");
    // A base config that names a Kortex robot: the benchmark must still run the mock arm.
    let cfg = dir.join("graph.toml");
    std::fs::write(
        &cfg,
        "[bridge]\nrobot = \"kortex\"\n[bridge.kortex]\naddress = \"127.0.0.1\"\n",
    )
    .unwrap();
    let out = std::process::Command::new(scl_binary())
        .args(["--config"])
        .arg(&cfg)
        .args([
            "bench",
            "latency",
            "--for",
            "3s",
            "--transport",
            "both",
            "--json",
            "--out",
        ])
        .arg(&out_dir)
        .env("SCL_LOG", "warn")
        // A prefix in the environment (a lab's shell, the service's unit) must not move the
        // benchmark's graphs away from what it observes.
        .env("SCL_PREFIX", unique_prefix("bench-env").as_str())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl bench latency failed: {stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let saved: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report, saved, "report.json differs from the printed report");

    // The machine and the settings.
    assert!(report["machine"]["cores"].as_u64().unwrap() >= 1);
    assert!(
        report["machine"]["kernel"]
            .as_str()
            .is_some_and(|k| !k.is_empty())
    );
    assert_eq!(report["settings"]["model"], "bundled");
    assert_eq!(report["settings"]["rate_hz"], 40.0);
    assert_eq!(report["duration_s"], 3.0);

    // One run per transport, in order, each with every figure measured.
    let runs = report["runs"].as_array().unwrap();
    let transports: Vec<&str> = runs
        .iter()
        .map(|r| r["transport"].as_str().unwrap())
        .collect();
    assert_eq!(transports, ["iceoryx2", "uds"]);
    for run in runs {
        let t = run["transport"].as_str().unwrap();
        let ticks = run["ticks"].as_u64().unwrap();
        // 3 s at 40 Hz: 120 ticks, less start-up and shutdown.
        assert!(ticks >= 80, "{t}: {ticks} ticks");
        // Most ticks give a sample of each figure (a missed tick gives none of its hops).
        let min = ticks / 2;
        check_dist(&format!("{t} e2e"), &run["e2e_us"], min);
        for hop in [
            "joystick_mapper",
            "bridge_mapper",
            "mapper_safety",
            "safety_bridge",
        ] {
            check_dist(&format!("{t} {hop}"), &run["hops_us"][hop], min);
        }
        check_dist(&format!("{t} sample age"), &run["joystick_age_us"], min);
        // What the operator feels, the report's first row.
        check_dist(
            &format!("{t} joystick -> executed"),
            &run["joystick_executed_us"],
            min,
        );
        check_dist(
            &format!("{t} compute mapper"),
            &run["compute_us"]["mapper"],
            min,
        );
        check_dist(
            &format!("{t} compute safety"),
            &run["compute_us"]["safety"],
            min,
        );
        // Lateness can be 0 µs at p50 on an idle machine; only that it was sampled.
        assert!(run["tick_lateness_us"]["n"].as_u64().unwrap() >= min);
        // The hops of one tick add up to no more than its end-to-end time (same clock).
        let e2e = run["e2e_us"]["p50"].as_f64().unwrap();
        let hop = run["hops_us"]["bridge_mapper"]["p50"].as_f64().unwrap();
        assert!(
            hop <= e2e,
            "{t}: bridge -> mapper p50 {hop} > e2e p50 {e2e}"
        );
    }
    // A ratio (iceoryx2 / uds) of p50, p99 and max for every figure.
    let ratios = report["ratios"].as_array().unwrap();
    assert!(ratios.len() >= 9, "{} ratios", ratios.len());
    for r in ratios {
        let name = r[0].as_str().unwrap();
        for k in 1..=3 {
            let v = r[k].as_f64().unwrap_or(f64::NAN);
            assert!(v.is_finite() && v > 0.0, "ratio of {name}: {r}");
        }
    }
    // The histograms.
    let png = std::fs::read(out_dir.join("latency.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "latency.png is not a PNG");
    assert!(png.len() > 10_000, "latency.png is {} bytes", png.len());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `scl bench headroom` end to end, shortened: two rates on both transports, each row with
/// its misses, end to end, lateness and every process's CPU time per tick; the ratios per
/// rate; the plot. `--rt-only` asks for one setting: the graph's config says so.
#[test]
fn bench_headroom_reports_every_rate_and_transport() {
    let _serial = serial();
    let dir = temp_dir("headroom");
    let out_dir = dir.join("out");
    let out = std::process::Command::new(scl_binary())
        .args([
            "bench",
            "headroom",
            "--secs",
            "2",
            "--rates",
            "40,250",
            "--transport",
            "both",
            "--rt-only",
            "mlock",
            "--json",
            "--out",
        ])
        .arg(&out_dir)
        .env("SCL_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "scl bench headroom failed: {stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["rt_settings"]["mlock"], true);
    assert_eq!(report["rt_settings"]["fifo"], false);
    let rows = report["rows"].as_array().unwrap();
    let order: Vec<(f64, &str)> = rows
        .iter()
        .map(|r| {
            (
                r["rate_hz"].as_f64().unwrap(),
                r["transport"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        order,
        [
            (40.0, "iceoryx2"),
            (40.0, "uds"),
            (250.0, "iceoryx2"),
            (250.0, "uds")
        ]
    );
    for r in rows {
        let what = format!("{} Hz {}", r["rate_hz"], r["transport"]);
        let ticks = r["ticks"].as_u64().unwrap();
        // 2 s: 80 ticks at 40 Hz, 500 at 250 Hz, less start-up and shutdown.
        let rate = r["rate_hz"].as_f64().unwrap();
        assert!(ticks as f64 >= rate, "{what}: {ticks} ticks");
        assert!(r["held_up"].as_u64().unwrap() <= r["missed"].as_u64().unwrap());
        check_dist(&format!("{what} e2e"), &r["e2e_us"], ticks / 2);
        let cpu: Vec<&str> = r["cpu_per_tick_us"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p[0].as_str().unwrap())
            .collect();
        assert_eq!(
            cpu,
            ["bridge", "safety", "mapper", "joystick", "supervisor"],
            "{what}"
        );
        for p in r["cpu_per_tick_us"].as_array().unwrap() {
            assert!(p[1].as_f64().unwrap() > 0.0, "{what}: {p}");
        }
    }
    // The run's config asked for mlock alone.
    let cfg = std::fs::read_to_string(out_dir.join("graph-iceoryx2-250hz.toml")).unwrap();
    for line in [
        "rate_hz = 250.0",
        "realtime = true",
        "rt_fifo = false",
        "rt_mlock = true",
        "rt_cpu = -1",
        "rt_cpu_dma_latency_us = -1",
    ] {
        assert!(cfg.contains(line), "{line} not in:\n{cfg}");
    }
    assert_eq!(report["ratios"].as_array().unwrap().len(), 2);
    let png = std::fs::read(out_dir.join("headroom.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "headroom.png is not a PNG");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `scl bench latency --remote` end to end, shortened: the control path with the gateway off
/// and on, then the remote operator (`scl joystick --remote`) over loopback, a veth pair
/// between two namespaces (CI runs as root) and the pair with 5 ms each way. Each link's row
/// carries its counts (samples forwarded, commands they drove), its figures measured (positive,
/// finite, ordered) and the clock check; the 5 ms relay shows in the sample's way to the
/// mapper. No wall-clock limit is asserted. Nothing is left behind: no namespace, no
/// shared memory.
#[test]
fn bench_latency_remote_measures_the_operator_over_each_link() {
    let _serial = serial();
    let dir = temp_dir("benchremote");
    let out_dir = dir.join("out");
    let child = std::process::Command::new(scl_binary())
        .args([
            "bench",
            "latency",
            "--remote",
            "loopback,veth,veth+5ms",
            "--for",
            "6s",
            "--json",
            "--out",
        ])
        .arg(&out_dir)
        .env("SCL_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "scl bench latency --remote failed: {stderr}"
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["duration_s"], 6.0);
    assert!(
        report["clock"]
            .as_str()
            .is_some_and(|c| c.contains("CLOCK_MONOTONIC")),
        "{}",
        report["clock"]
    );

    // The gateway off and on, in the same run, each measured.
    for key in ["gateway_off", "gateway_on"] {
        let run = &report[key];
        let ticks = run["ticks"].as_u64().unwrap();
        assert!(ticks >= 120, "{key}: {ticks} ticks");
        check_dist(key, &run["e2e_us"], ticks / 2);
    }
    let on_off = report["gateway_on_off_e2e"].as_array().unwrap();
    for v in on_off {
        let v = v.as_f64().unwrap_or(f64::NAN);
        assert!(v.is_finite() && v > 0.0, "on / off: {on_off:?}");
    }

    let rows = report["links"].as_array().unwrap();
    let links: Vec<&str> = rows.iter().map(|r| r["link"].as_str().unwrap()).collect();
    assert_eq!(links, ["loopback", "veth", "veth+5ms"]);
    for row in rows {
        let link = row["link"].as_str().unwrap();
        assert!(row["error"].is_null(), "{link}: {}", row["error"]);
        let op = &row["run"]["operator"];
        assert_eq!(op["same_clock"], true, "{link}: {op}");
        let forwarded = op["forwarded"].as_u64().unwrap();
        // About 4 s of driving at 40 Hz, one sample per robot state.
        assert!(forwarded >= 20, "{link}: {forwarded} samples forwarded");
        let executed = &row["joystick_executed_us"];
        let n = executed["n"].as_u64().unwrap();
        // Each command an operator's sample drove; no more than the samples forwarded allow
        // (a sample drives the ticks until the next one arrives).
        assert!(n >= 20, "{link}: {n} commands from the operator");
        check_dist(&format!("{link} joystick -> executed"), executed, 20);
        check_dist(
            &format!("{link} joystick -> mapper"),
            &row["joystick_mapper_us"],
            20,
        );
        for k in ["p50", "p99", "max"] {
            let (to_mapper, to_bridge) = (
                row["joystick_mapper_us"][k].as_f64().unwrap(),
                executed[k].as_f64().unwrap(),
            );
            assert!(
                to_mapper.is_finite() && to_bridge.is_finite() && to_mapper <= to_bridge,
                "{link} {k}: joystick -> mapper {to_mapper} µs, -> executed {to_bridge} µs"
            );
        }
        let ticks = row["ticks"].as_u64().unwrap();
        check_dist(&format!("{link} e2e"), &row["e2e_us"], ticks / 2);
        let cpu = row["gateway_cpu_per_tick_us"].as_f64().unwrap();
        assert!(cpu.is_finite() && cpu > 0.0, "{link}: gateway CPU {cpu}");
        assert!(row["held_up"].as_u64().unwrap() <= row["missed"].as_u64().unwrap());
    }
    // The relay holds every chunk 5 ms: no sample reaches the mapper sooner.
    let delayed = rows[2]["joystick_mapper_us"]["p50"].as_f64().unwrap();
    assert!(
        delayed >= 5_000.0,
        "veth+5ms: joystick -> mapper p50 {delayed} µs"
    );

    // Nothing left behind: the namespaces and every run's shared memory.
    let netns = std::process::Command::new("ip")
        .args(["netns", "list"])
        .output()
        .unwrap();
    let netns = String::from_utf8_lossy(&netns.stdout);
    let left: Vec<&str> = netns
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .filter(|n| scl_net::netns::made_by(n, pid))
        .collect();
    assert!(left.is_empty(), "namespaces left: {left:?}");
    // Every run's prefix starts `bench<pid>` (`bench<pid>iceoryx2-lo`, ...).
    let needle = format!("scl_bench{pid}");
    let t0 = std::time::Instant::now();
    let left = loop {
        let left = scl_tests::files_named(&needle);
        if left.is_empty() || t0.elapsed() > std::time::Duration::from_secs(5) {
            break left;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    assert!(left.is_empty(), "left behind: {left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A link that is not one is refused, naming it, before anything runs.
#[test]
fn bench_latency_remote_refuses_a_bad_link_naming_it() {
    let out = std::process::Command::new(scl_binary())
        .args([
            "bench",
            "latency",
            "--remote",
            "loopback,wifi",
            "--for",
            "1s",
        ])
        .env("SCL_LOG", "warn")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("`wifi`"), "{stderr}");
}
