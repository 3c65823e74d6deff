//! `[graph] wait = "predictive"`: the whole graph on the mock arm at 40 Hz and at 1 kHz with
//! the mapper, safety and the bridge polling in the windows they learn. Logic, not timing:
//! every executed command is its own tick's, no miss is the graph's own (only those the
//! machine held up, by the bridge's own rule), and each polling process found its input by
//! polling and says so at its end.
#![allow(clippy::unwrap_used, missing_docs)]

use std::process::{Command, Stdio};
use std::time::Duration;

use ipc_types::state_flags;
use scl_tests::{ChildGuard, DomainGuard, Recorder, scl_binary, serial, unique_prefix, wait_clean};

/// `polled=N` of `process`'s `wait strategy` line in the log.
fn polled(log: &str, process: &str) -> Option<u64> {
    let line = log
        .lines()
        .find(|l| l.contains("wait strategy") && l.contains(&format!("process={process}")))?;
    line.split_whitespace()
        .find_map(|t| t.strip_prefix("polled="))?
        .parse()
        .ok()
}

/// Runs the graph at `rate_hz` with `wait = "predictive"` for `secs`, and checks it.
fn predictive_graph(rate_hz: f64, secs: u32, tag: &str, unclassified: u64) {
    let _serial = serial();
    let prefix = unique_prefix(tag);
    let _domain = DomainGuard(prefix.clone());
    let dir = scl_tests::temp_dir(tag);
    let cfg = dir.join("graph.toml");
    // Without SCHED_FIFO all three processes poll (with it on this small machine only the
    // mapper would: `scl_config::placement`). The step script comes back to rest often, as
    // in the 500 Hz test, so a stale-state stop of a debug build at 1 kHz ends at neutral.
    std::fs::write(
        &cfg,
        format!(
            "[graph]\nrate_hz = {rate_hz}\nwait = \"predictive\"\nrealtime = false\n\
             [joystick]\nscript = \"step\"\nstep_hold_s = 0.2\nstep_rest_s = 0.1\n"
        ),
    )
    .unwrap();
    let mut rec = Recorder::join(&prefix);
    let log = dir.join("up.log");
    let mut guard = ChildGuard(Some(
        Command::new(scl_binary())
            .arg("--config")
            .arg(&cfg)
            .args(["up", "--for", &format!("{secs}s"), "--json"])
            .env("SCL_PREFIX", prefix.as_str())
            .env("SCL_LOG", "info")
            .env("NO_COLOR", "1")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    ));
    let out = rec.record_until_exit(&mut guard);
    let log_text = std::fs::read_to_string(&log).unwrap();
    assert!(out.status.success(), "scl up failed: {log_text}");
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let what = format!("{rate_hz} Hz predictive graph");

    // No miss is the graph's own: a polling process whose input does not come in its window
    // waits for the event, and the bridge never executes a command after its deadline. At
    // 1 kHz on a shared 2-CPU machine the chain can be starved for more than
    // `late::SKIP_MAX` ticks while the bridge runs on time, which the bridge's rule leaves
    // unclassified; `event` shows the same there (4 s runs under a load of 6: 894 missed,
    // 881 held up), so up to `unclassified` such misses pass.
    let missed = summary["missed"].as_u64().unwrap();
    let held_up = summary["held_up"].as_u64().unwrap();
    assert!(
        missed >= held_up && missed - held_up <= unclassified,
        "{what}: {missed} missed, {held_up} taken by the machine:\n{}",
        scl_tests::miss_report(&log_text)
    );
    assert_eq!(scl_tests::held_up_skips(&log_text), held_up);
    if missed > 0 {
        eprintln!("{what}: the machine held it up, {missed} tick(s) lost");
    }

    // Every executed command is its own tick's.
    let states: Vec<_> = rec
        .robot_states
        .iter()
        .filter(|s| s.flags & state_flags::SHUTDOWN == 0)
        .copied()
        .collect();
    // The graph's own count says it ran; the test's recorder (a 64-message buffer polled
    // every 2 ms by a process the machine may hold up for longer at 1 kHz) checks the ticks it
    // saw, at least a tenth of them.
    let min_ticks = (rate_hz * f64::from(secs) / 2.0) as usize;
    let ticks = summary["ticks"].as_u64().unwrap_or(0) as usize;
    assert!(
        ticks.saturating_sub(missed as usize) > min_ticks,
        "{what}: {ticks} ticks, {missed} missed"
    );
    let seen = ticks / 10;
    assert!(states.len() > seen, "{what}: {} states", states.len());
    let mut executed = 0;
    for w in states.windows(2).filter(|w| w[1].tick == w[0].tick + 1) {
        if w[1].applied_tick == w[0].tick {
            executed += 1;
            assert!(
                rec.safe_commands.iter().any(|c| c.tick == w[0].tick),
                "{what}: tick {} executed without its command recorded",
                w[0].tick
            );
        } else {
            assert_eq!(
                w[1].applied_tick,
                u64::MAX,
                "{what}: tick {} executed tick {}'s command",
                w[1].tick,
                w[1].applied_tick
            );
        }
    }
    assert!(executed > seen / 2, "{what}: {executed} ticks executed");

    // Each of the three polled: its input came in its window at least once.
    for p in ["mapper", "safety", "bridge"] {
        let n = polled(&log_text, p);
        assert!(
            n.is_some_and(|n| n > 0),
            "{what}: {p} found nothing by polling ({n:?}):\n{}",
            log_text
                .lines()
                .filter(|l| l.contains("wait"))
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
    drop(rec);
    assert!(wait_clean(&prefix, Duration::from_secs(5)).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn predictive_at_40_hz_executes_every_tick_in_its_own_tick() {
    predictive_graph(40.0, 6, "wait40", 0);
}

#[test]
fn predictive_at_1_khz_executes_every_tick_in_its_own_tick() {
    // Up to 1 % of the ticks (see above).
    predictive_graph(1000.0, 4, "wait1k", 40);
}
