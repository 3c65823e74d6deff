//! `scl study run` on the live mock graph with a scripted operator (keys from a file) and a
//! scripted joystick: the arm is driven to the start pose before every practice and attempt,
//! the live swaps miss no tick, the files hold the expected rows, the screen never shows a
//! condition's name, and a run interrupted (its keys end) resumes without repeating a
//! finished attempt.
#![allow(clippy::unwrap_used, missing_docs)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use ipc_types::{NodeRole, phase};
use scl_tests::{
    ChildGuard, DomainGuard, Recorder, Signal, run_polling, scl, serial, unique_prefix,
};

/// The start pose: home with the base turned 0.25 rad, so the arm must move to get there.
const START: [f64; 6] = [0.25, -0.28, 1.309, 0.0, -1.047, 0.0];

fn study_file(dir: &Path, pca: &Path) -> std::path::PathBuf {
    let q: Vec<String> = START.iter().map(f64::to_string).collect();
    let text = format!(
        r#"name = "scripted study"
participants = 2
[[tasks]]
name = "reach"
start = [{}]
approach_speed_rad_s = 0.6
time_limit_s = 1.5
practice_s = 30
attempts = 1
[[conditions]]
label = "A"
name = "SECRET-SCL"
model = "bundled"
[[conditions]]
label = "B"
name = "SECRET-PCA"
model = "{}"
[questionnaire]
likert = ["I felt in control"]
"#,
        q.join(", "),
        pca.display()
    );
    let p = dir.join("study.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn run_study(
    prefix: &ipc_types::Prefix,
    rec: &mut Recorder,
    study: &Path,
    out: &Path,
    keys: &str,
) -> (Option<i32>, String, String) {
    let kf = out.with_extension("keys");
    std::fs::write(&kf, keys).unwrap();
    let mut c = scl(prefix);
    c.args(["study", "run"])
        .arg(study)
        .args(["--participant", "P01", "--out"])
        .arg(out)
        .arg("--keys")
        .arg(&kf)
        .args(["--arrive-timeout-s", "60"]);
    let o = run_polling(c, rec);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn trials(out: &Path) -> Vec<BTreeMap<String, String>> {
    let mut r = csv::Reader::from_path(out.join("trials.csv")).unwrap();
    r.deserialize().map(Result::unwrap).collect()
}

#[test]
fn a_scripted_study_runs_on_the_live_graph_and_resumes_after_an_interruption() {
    let _serial = serial();
    let prefix = unique_prefix("study");
    let _domain = DomainGuard(prefix.clone());
    let dir = scl_tests::temp_dir("study");
    let pca = scl_tests::joint_reach_pca(&dir, None);
    let study = study_file(&dir, &pca);
    let out = dir.join("P01");

    // The plan: P01 meets A then B, P02 B then A.
    let mut c = scl(&prefix);
    c.args(["study", "plan"]).arg(&study);
    let o = c.output().unwrap();
    assert_eq!(String::from_utf8_lossy(&o.stdout), "P01: A B\nP02: B A\n");

    let mut rec = Recorder::join(&prefix);
    let log = dir.join("up.log");
    // The step script rests the stick between steps: after a stop (a hold-up of the
    // machine's), safety lets the arm move again once the input passed through neutral.
    let mut up = scl(&prefix);
    up.args(["up", "--for", "300s", "--json", "--script", "step"])
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log).unwrap());
    let mut guard = ChildGuard(Some(up.spawn().unwrap()));
    assert!(rec.poll_until(Duration::from_secs(30), |r| r.robot_states.len() > 20));

    // First run: practice and one attempt with A (a success), the questionnaire, then the
    // keys end: the run stops, resumable.
    let keys1 = "go\nwait 0.5\nskip\ngo\nwait 0.5\ns\ngo\n6\n";
    let (code, stdout1, stderr) = run_study(&prefix, &mut rec, &study, &out, keys1);
    assert_eq!(code, Some(3), "{stdout1}\n{stderr}");
    assert!(
        stderr.contains("run the same command to resume"),
        "{stderr}"
    );
    let t = trials(&out);
    assert_eq!(t.len(), 1, "{t:?}");
    assert_eq!(
        (t[0]["label"].as_str(), t[0]["outcome"].as_str()),
        ("A", "success")
    );

    // Second run: A is not repeated; B: practice, a failure at 40 % that is repeated, the
    // repetition runs into the time limit (30 %), kept; the questionnaire (an answer out of
    // range is asked again).
    let keys2 = "go\nwait 0.5\nskip\ngo\nwait 0.3\nf\n40\nr\ngo\nwait 3\n30\ngo\n9\n5\n";
    let (code, stdout2, stderr) = run_study(&prefix, &mut rec, &study, &out, keys2);
    assert_eq!(code, Some(0), "{stdout2}\n{stderr}");
    assert!(stdout2.contains("study finished"), "{stdout2}");
    assert!(stdout2.contains("9 is not an answer"), "{stdout2}");

    // Third run: nothing left to do, nothing written.
    let (code, stdout3, stderr) = run_study(&prefix, &mut rec, &study, &out, "");
    assert_eq!(code, Some(0), "{stdout3}\n{stderr}");

    // The graph: no tick missed but those the machine took.
    let summary = stop_up(&mut guard, &mut rec);
    let log_text = std::fs::read_to_string(&log).unwrap();
    scl_tests::assert_misses_only_held_up(&summary, &log_text, "study");
    // Before every practice and attempt the arm was at the start pose: each go-to map
    // (a mapper reporting a mode, `moving` or `arrived`) that a condition's map followed
    // left the arm within the go-to map's tolerance of the pose at its last command. (The
    // go-to map the interrupted run left behind was followed by another one.)
    let goto: BTreeSet<u32> = rec
        .statuses
        .iter()
        .filter(|s| s.role == NodeRole::Mapper as u32 && s.phase == phase::RUNNING && s.mode != 0)
        .map(|s| s.mapper_id)
        .collect();
    assert_eq!(goto.len(), 6, "{goto:?}");
    let mut followed = 0;
    for &g in &goto {
        if goto.contains(&(g + 1)) {
            continue;
        }
        let last = rec
            .safe_commands
            .iter()
            .filter(|c| c.mapper_id == g)
            .map(|c| c.tick)
            .max()
            .unwrap();
        let state = rec.robot_states.iter().find(|s| s.tick == last).unwrap();
        let d = START
            .iter()
            .zip(&state.q_rad)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            d <= mapper::goto::ARRIVED_RAD + 1e-3,
            "go-to map {g}: {d} rad from the pose"
        );
        followed += 1;
    }
    assert_eq!(followed, 5, "two practices and three attempts");

    // The files.
    let t = trials(&out);
    let cols: Vec<(&str, &str, &str, &str)> = t
        .iter()
        .map(|r| {
            (
                r["label"].as_str(),
                r["outcome"].as_str(),
                r["repeated"].as_str(),
                r["completion_pct"].as_str(),
            )
        })
        .collect();
    assert_eq!(
        cols,
        [
            ("A", "success", "false", "100.0"),
            ("B", "failure", "true", "40.0"),
            ("B", "timeout", "false", "30.0")
        ]
    );
    assert_eq!(t[1]["condition"], "SECRET-PCA");
    assert_eq!(t[2]["position"], "2");
    let d: f64 = t[2]["duration_s"].parse().unwrap();
    assert!((d - 1.5).abs() < 1e-9, "a timeout lasts the limit: {d}");
    let mut q = csv::Reader::from_path(out.join("questionnaire.csv")).unwrap();
    let answers: Vec<BTreeMap<String, String>> = q.deserialize().map(Result::unwrap).collect();
    let av: Vec<(&str, &str)> = answers
        .iter()
        .map(|a| (a["label"].as_str(), a["value"].as_str()))
        .collect();
    assert_eq!(av, [("A", "6"), ("B", "5")]);
    // Each attempt's recording holds the trial's metadata and its outcome.
    for row in &t {
        let mut meta: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
        let mut states = 0;
        let s = recording::read_file(&out.join(&row["recording"]), |e| {
            match e {
                recording::Event::Metadata { name, entries } => {
                    meta.insert(name.to_owned(), entries.clone());
                }
                recording::Event::Message { channel, .. } if channel.topic == "/robot_state" => {
                    states += 1;
                }
                _ => {}
            }
            Ok(())
        })
        .unwrap();
        assert!(s.complete, "{row:?}");
        // The recorder runs from before the attempt to after it: every tick of the attempt
        // is in it (a scripted failure can end an attempt in a tenth of a second).
        let duration_s: f64 = row["duration_s"].parse().unwrap();
        let ticks = (duration_s / 0.025).floor() as usize;
        assert!(
            states > 0 && states >= ticks,
            "{row:?}: {states} states for {ticks} ticks"
        );
        assert_eq!(meta["scl.trial"]["label"], row["label"]);
        assert_eq!(meta["scl.trial"]["participant"], "P01");
        assert_eq!(meta["scl.trial.outcome"]["outcome"], row["outcome"]);
        assert_eq!(meta["scl.trial.outcome"]["repeated"], row["repeated"]);
    }
    // Blind: the screen showed labels only.
    for text in [&stdout1, &stdout2, &stdout3] {
        assert!(
            !text.contains("SECRET") && !text.contains("safetensors"),
            "{text}"
        );
    }

    // The report over the participant's directory.
    let report = dir.join("report");
    let mut c = scl(&prefix);
    c.args(["study", "report"])
        .arg(&out)
        .arg("--out")
        .arg(&report);
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(md.contains("| reach | 1 / 1 | 0 / 1 |"), "{md}");
    assert!(report.join("completion.png").exists() && report.join("likert-reach.svg").exists());

    drop(rec);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(
        scl_tests::wait_clean(&prefix, Duration::from_secs(5)),
        Vec::<String>::new()
    );
}

fn stop_up(guard: &mut ChildGuard, rec: &mut Recorder) -> serde_json::Value {
    scl_tests::send_signal(guard.child().id(), Signal::SIGTERM);
    let out = rec.record_until_exit(guard);
    assert!(out.status.success(), "scl up: {:?}", out.status);
    serde_json::from_slice(&out.stdout).unwrap()
}

/// A study for the sim-versus-live check: table cleaning from its demonstrations' start with
/// the mode-switching map (no trained model needed), about 5 s. Short on purpose: a live run
/// with one sample the mapper got late is no comparison, and pick-and-place's 67-90 s live
/// (over 3000 samples) had one to eleven in each of four runs on a loaded 2-core machine.
const SIM_VS_LIVE: &str = r#"name = "sim versus live"
participants = 1
[[tasks]]
name = "table-cleaning"
start = [-0.124, -0.724, 1.52, 1.571, 0.897, -0.124]
time_limit_s = 60
attempts = 1
[[conditions]]
label = "A"
name = "bundled"
model = "bundled"
[[conditions]]
label = "B"
name = "mode switching"
model = "modeswitch"
"#;

fn simulate(prefix: &ipc_types::Prefix, study: &Path, out: &Path, live: bool) {
    let mut c = scl(prefix);
    c.args(["study", "simulate"])
        .arg(study)
        .args(["--participants", "1", "--seed", "1", "--condition", "B"])
        .arg("--out")
        .arg(out);
    if live {
        c.arg("--live");
    }
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "scl study simulate{}: {}",
        if live { " --live" } else { "" },
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The in-process simulation and `--live` (the same operator on the real 40 Hz graph: its own
/// `scl up` per attempt, samples published on the joystick topic) give the same outcome and a
/// completion time within 5 % for one participant and one condition. A live run the machine
/// disturbed (a missed tick, a state the operator could not answer in time, a sample the
/// mapper got late: counted in the graph's messages, `live/attempts.csv`) is no comparison
/// and is run again, at most four times.
///
/// The greedy operator: on pick-and-place, since the lift and the carry became zones
/// (`learning::goals::Zone`), it carries the bottle 11 cm past the mark in x with seed 1 and
/// stays there (it never backs off), so the check uses table cleaning (about 3 s).
#[test]
fn the_simulated_and_live_paths_agree() {
    sim_and_live_agree(SIM_VS_LIVE, "simlive");
}

/// The same check with the practiced operator (`[simulation] operator = "practiced"`): it
/// practises in process (a minute, with the condition's map), then makes the attempt in
/// process and live with what it learned, learning on from what it sees in both.
#[test]
fn the_simulated_and_live_paths_agree_for_the_practiced_operator() {
    let study = SIM_VS_LIVE.replace("attempts = 1\n", "attempts = 1\npractice_s = 60\n")
        + "[simulation]\noperator = \"practiced\"\n";
    sim_and_live_agree(&study, "simlivep");
}

fn sim_and_live_agree(study_text: &str, name: &str) {
    let _serial = serial();
    let prefix = unique_prefix(name);
    let live_prefix = ipc_types::Prefix::new(&format!("{prefix}-sim")).unwrap();
    let _domain = DomainGuard(live_prefix.clone());
    let dir = scl_tests::temp_dir(name);
    let study = dir.join("study.toml");
    std::fs::write(&study, study_text).unwrap();

    let sim = dir.join("sim");
    simulate(&prefix, &study, &sim, false);
    let s = trials(&sim.join("P01"));
    assert_eq!(s.len(), 1, "one attempt of one condition: {s:?}");
    assert_eq!(s[0]["condition"], "mode switching");
    assert_eq!(
        s[0]["outcome"], "success",
        "the check needs a success: {s:?}"
    );
    let sim_s: f64 = s[0]["duration_s"].parse().unwrap();

    let mut disturbed = Vec::new();
    for run in 1..=4 {
        let out = dir.join(format!("live{run}"));
        simulate(&prefix, &study, &out, true);
        let l = trials(&out.join("P01"));
        let mut r = csv::Reader::from_path(out.join("P01/live/attempts.csv")).unwrap();
        let counts: Vec<BTreeMap<String, String>> = r.deserialize().map(Result::unwrap).collect();
        assert_eq!((l.len(), counts.len()), (1, 1), "{l:?} {counts:?}");
        let c = &counts[0];
        let n = |k: &str| c[k].parse::<u64>().unwrap();
        // The operator answered the graph's states for about the live attempt's length (40
        // Hz). The live attempt's own length: an operator that learns on (the practiced one)
        // may finish sooner live than in process.
        let live_attempt_s: f64 = c["duration_s"].parse().unwrap();
        assert!(
            n("answered") as f64 >= 0.9 * live_attempt_s * 40.0,
            "the operator answered the graph: {c:?}"
        );
        if n("unanswered") + n("late_samples") + n("early_samples") + n("missed") > 0 {
            disturbed.push(format!("run {run}: {c:?}"));
            continue;
        }
        assert_eq!(l[0]["outcome"], s[0]["outcome"], "live {l:?}\nsim {s:?}");
        let live_s: f64 = l[0]["duration_s"].parse().unwrap();
        assert!(
            (live_s - sim_s).abs() <= 0.05 * sim_s,
            "completion time: live {live_s} s, in process {sim_s} s"
        );
        assert_eq!(l[0]["mode_switches"], s[0]["mode_switches"], "{l:?}\n{s:?}");
        eprintln!(
            "live run {run} agrees: {live_s} s against {sim_s} s; disturbed before: {disturbed:?}"
        );
        assert!(
            scl_tests::wait_clean(&live_prefix, Duration::from_secs(5)).is_empty(),
            "the live graphs left files behind"
        );
        std::fs::remove_dir_all(&dir).unwrap();
        return;
    }
    panic!("the machine disturbed every live run: {disturbed:#?}");
}
