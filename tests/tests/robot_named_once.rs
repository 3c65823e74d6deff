//! The robot is named in one place: the graph's crates take the arm from the robot profile the
//! graph config names (`[graph] robot`, `kinematics::RobotProfile::by_name`), never from a
//! robot module of their own. This test reads their sources (tests excluded) and refuses any
//! mention of the Gen3 lite's module or type outside `kinematics`.
//!
//! Not checked: `kinematics` (where the robots and their profiles live) and `learning` (the
//! paper's tasks and data sets are the Gen3 lite's by design, offline). The fake Kortex robot
//! plays the arm of any profile, so it names none either.

use std::path::{Path, PathBuf};

/// The graph's crates, relative to the workspace root: their `src/` folders are read.
const GRAPH_CRATES: &[&str] = &[
    "ipc-types",
    "safety",
    "hw-bridge",
    "mapper",
    "recording",
    "cli",
    "config",
    "node-rt",
    "graph-client",
    "net",
    "services/joystick",
    "services/gateway",
    "services/mapper-node",
    "services/safety-node",
    "services/bridge-node",
    "services/supervisor",
    "services/recorder",
    "services/dashboard",
    "services/bench",
];

/// Files allowed to name the robot, with the reason (none now).
const ALLOWED: &[(&str, &str)] = &[];

/// What names the robot in code.
const NAMES: &[&str] = &["gen3_lite", "Gen3Lite"];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The part of a source file before its inline test module.
fn without_tests(text: &str) -> &str {
    let mut at = 0;
    while let Some(i) = text[at..].find("#[cfg(test)]") {
        let start = at + i;
        let mut rest = text[start + "#[cfg(test)]".len()..].trim_start();
        // Further attributes of the same item (`#[allow(...)]`).
        while rest.starts_with("#[") {
            rest = rest.find('\n').map_or("", |n| rest[n..].trim_start());
        }
        if rest.starts_with("mod ") {
            return &text[..start];
        }
        at = start + 1;
    }
    text
}

#[test]
fn the_graphs_crates_name_no_robot() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut found = Vec::new();
    let mut read = 0;
    for krate in GRAPH_CRATES {
        let mut files = Vec::new();
        rust_files(&root.join(krate).join("src"), &mut files);
        for f in files {
            let rel = f.strip_prefix(&root).unwrap_or(&f).display().to_string();
            if ALLOWED.iter().any(|(p, _)| *p == rel) {
                continue;
            }
            let text = std::fs::read_to_string(&f).unwrap_or_default();
            read += 1;
            for (n, line) in without_tests(&text).lines().enumerate() {
                if NAMES.iter().any(|name| line.contains(name)) {
                    found.push(format!("{rel}:{}: {}", n + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        read > 30,
        "only {read} source files found under {}",
        root.display()
    );
    assert!(
        found.is_empty(),
        "the robot is named outside kinematics; take it from the graph's robot profile \
         (kinematics::RobotProfile):\n{}",
        found.join("\n")
    );
}

#[test]
fn test_modules_are_cut_off() {
    let text =
        "fn a() {}\n#[cfg(test)]\nfn helper() {}\n#[cfg(test)]\nmod tests {\n gen3_lite\n}\n";
    assert_eq!(
        without_tests(text),
        "fn a() {}\n#[cfg(test)]\nfn helper() {}\n"
    );
    let with_attribute = "fn a() {}\n#[cfg(test)]\n#[allow(clippy::unwrap_used)]\nmod tests {}\n";
    assert_eq!(without_tests(with_attribute), "fn a() {}\n");
}
