//! The workspace's dependency rules, read from `cargo metadata` (in the spirit of
//! rust-analyzer's tidy tests): a forbidden edge fails this test, naming it.
//!
//! The crates fall in four groups, by where their manifest lies:
//!
//! * **the command line**: `cli/` (package `scl`, the `scl` binary): the top. It may depend
//!   on every crate.
//! * **services**: the crates under `services/`, one per process or tool of the `scl`
//!   command (`scl-joystick`, `scl-mapper-node`, `scl-safety-node`, `scl-bridge-node`,
//!   `scl-supervisor`, `scl-recorder`, `scl-live`, `scl-dashboard`, `scl-bench`,
//!   `scl-study`, `scl-gateway`).
//! * **the whole-graph tests**: `tests/` (package `scl-tests`): beside the top; it runs the
//!   `scl` binary and links libraries only.
//! * **libraries**: every other crate (`ipc-types`, `transport`, `scl-config`, `node-rt`,
//!   `graph-client`, `scl-net`, `kinematics`, `mapper`, `safety`, `hw-bridge`, `recording`,
//!   `replay`, `viz`, `learning`, `study`, `test-support`).
//!
//! The rules (every kind of dependency counts: normal, build and dev):
//!
//! 1. No crate depends on the command line, and none on the whole-graph tests.
//! 2. No service depends on another service: what two services share moves down into a
//!    library.
//! 3. No library depends on a service (nor the whole-graph tests on one).
//! 4. `ipc-types` (the messages) depends on no other crate of the workspace except
//!    `test-support` for its tests, and not on `iceoryx2`: the messages are apart from the
//!    transport.
//! 5. `ipc-types`, `recording` and `viz` do not link `iceoryx2`: no crate they depend on
//!    (directly or not, normal dependencies) depends on it or on `transport`.
//! 6. The control path's crates (`mapper`, `safety`, `hw-bridge` and their three loops) do
//!    not link `zenoh`: the network reaches the graph through the gateway only.
//! 7. The research crates (`learning`, `study`) do not link `transport` or `iceoryx2`: they
//!    build without shared memory (the stop flag they poll is `scl-signals`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Where a crate sits in the workspace.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Group {
    Cli,
    Service,
    Tests,
    Library,
}

/// One workspace crate and its dependencies on crates of the workspace or `iceoryx2`.
#[derive(Debug)]
struct Krate {
    group: Group,
    /// (dependency, kind: "normal", "dev" or "build").
    deps: Vec<(String, String)>,
}

/// The crates that must not link iceoryx2 (nor `transport`).
const NO_ICEORYX2: &[&str] = &["ipc-types", "recording", "viz", "learning", "study"];

/// The control path's crates, which must not link the network (zenoh): only the gateway, a
/// remote joystick and what starts them reach another machine.
const NO_ZENOH: &[&str] = &[
    "mapper",
    "safety",
    "hw-bridge",
    "scl-mapper-node",
    "scl-safety-node",
    "scl-bridge-node",
];

fn workspace() -> BTreeMap<String, Krate> {
    scl_tests::workspace::packages(&["iceoryx2", "zenoh"])
        .into_iter()
        .map(|p| {
            let group = if p.dir == Path::new("cli") {
                Group::Cli
            } else if p.dir == Path::new("tests") {
                Group::Tests
            } else if p.dir.starts_with("services") {
                Group::Service
            } else {
                Group::Library
            };
            (
                p.name,
                Krate {
                    group,
                    deps: p.deps,
                },
            )
        })
        .collect()
}

/// Every edge that breaks rules 1 to 4.
fn forbidden_edges(crates: &BTreeMap<String, Krate>) -> Vec<String> {
    let mut bad = Vec::new();
    for (name, k) in crates {
        for (dep, kind) in &k.deps {
            let edge = format!("{name} -> {dep} ({kind})");
            if dep == "zenoh" {
                continue;
            }
            if dep == "iceoryx2" {
                if name == "ipc-types" {
                    bad.push(format!(
                        "{edge}: the messages do not depend on the transport"
                    ));
                }
                continue;
            }
            let to = crates[dep].group;
            match (k.group, to) {
                (_, Group::Cli) => bad.push(format!("{edge}: nothing depends on the command line")),
                (_, Group::Tests) => bad.push(format!("{edge}: nothing depends on the tests")),
                (Group::Service, Group::Service) => bad.push(format!(
                    "{edge}: a service depends on no other service; move what they share into a library"
                )),
                (Group::Library | Group::Tests, Group::Service) => {
                    bad.push(format!("{edge}: a library depends on no service"));
                }
                _ => {}
            }
            if name == "ipc-types" && dep != "test-support" {
                bad.push(format!(
                    "{edge}: the messages depend on no other crate of the workspace"
                ));
            }
        }
    }
    bad
}

/// The crates `name` links (normal dependencies, transitively), `name` included.
fn links(crates: &BTreeMap<String, Krate>, name: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut stack = vec![name.to_owned()];
    while let Some(n) = stack.pop() {
        if !seen.insert(n.clone()) {
            continue;
        }
        if let Some(k) = crates.get(&n) {
            stack.extend(
                k.deps
                    .iter()
                    .filter(|(_, kind)| kind == "normal")
                    .map(|(d, _)| d.clone()),
            );
        }
    }
    seen
}

#[test]
fn dependencies_point_down() {
    let crates = workspace();
    assert!(
        crates
            .values()
            .filter(|k| k.group == Group::Service)
            .count()
            >= 8,
        "the services were not found under services/: {:?}",
        crates.keys().collect::<Vec<_>>()
    );
    assert_eq!(
        crates.values().filter(|k| k.group == Group::Cli).count(),
        1,
        "the command line crate was not found at cli/"
    );
    let bad = forbidden_edges(&crates);
    assert!(
        bad.is_empty(),
        "forbidden dependencies:\n{}",
        bad.join("\n")
    );
}

#[test]
fn messages_recording_viz_and_research_do_not_link_iceoryx2() {
    let crates = workspace();
    for name in NO_ICEORYX2 {
        assert!(crates.contains_key(*name), "no crate {name}");
        let linked = links(&crates, name);
        assert!(
            !linked.contains("iceoryx2") && !linked.contains("transport"),
            "{name} links iceoryx2 (through {:?})",
            linked
                .iter()
                .filter(|c| crates
                    .get(*c)
                    .is_some_and(|k| k.deps.iter().any(|(d, _)| d == "iceoryx2")))
                .collect::<Vec<_>>()
        );
    }
}

#[test]
fn the_control_path_does_not_link_the_network() {
    let crates = workspace();
    for name in NO_ZENOH {
        assert!(crates.contains_key(*name), "no crate {name}");
        let through: Vec<_> = links(&crates, name)
            .into_iter()
            .filter(|c| {
                crates.get(c).is_some_and(|k| {
                    k.deps
                        .iter()
                        .any(|(d, kind)| d == "zenoh" && kind == "normal")
                })
            })
            .collect();
        assert!(through.is_empty(), "{name} links zenoh through {through:?}");
    }
    assert!(
        links(&crates, "scl-gateway").contains("scl-net"),
        "the rule looks at the crates that do link zenoh"
    );
}

#[test]
fn the_rules_catch_a_forbidden_edge() {
    let k = |group, deps: &[&str]| Krate {
        group,
        deps: deps
            .iter()
            .map(|d| ((*d).to_owned(), "normal".to_owned()))
            .collect(),
    };
    let mut crates = BTreeMap::new();
    crates.insert("scl".to_owned(), k(Group::Cli, &["a", "lib"]));
    crates.insert("a".to_owned(), k(Group::Service, &["b", "lib"]));
    crates.insert("b".to_owned(), k(Group::Service, &[]));
    crates.insert("lib".to_owned(), k(Group::Library, &["b", "scl"]));
    crates.insert(
        "ipc-types".to_owned(),
        k(Group::Library, &["iceoryx2", "lib"]),
    );
    let bad = forbidden_edges(&crates);
    assert_eq!(bad.len(), 5, "{bad:#?}");
    for edge in [
        "a -> b",
        "lib -> b",
        "lib -> scl",
        "ipc-types -> iceoryx2",
        "ipc-types -> lib",
    ] {
        assert!(
            bad.iter().any(|e| e.starts_with(edge)),
            "{edge} not caught: {bad:#?}"
        );
    }
    assert!(links(&crates, "ipc-types").contains("iceoryx2"));
    assert!(!links(&crates, "b").contains("iceoryx2"));
}

/// One way to poll for an input: `node_rt::poller::Poller`, which every control-path loop
/// owns; a second `Poller` type anywhere in the workspace fails here.
#[test]
fn there_is_one_poller_type() {
    let root = scl_tests::workspace::root();
    let mut found = Vec::new();
    for p in scl_tests::workspace::packages(&[]) {
        for f in scl_tests::workspace::rust_files(&root.join(&p.dir).join("src")) {
            let text = std::fs::read_to_string(&f).unwrap_or_default();
            if text.contains("struct Poller") {
                found.push(f.strip_prefix(&root).unwrap_or(&f).display().to_string());
            }
        }
    }
    assert_eq!(found, ["node-rt/src/poller.rs"], "Poller types: {found:?}");
}

/// One node contract: a graph process says `READY` and `STOPPING` on the status topic through
/// `node_rt::node::Heartbeat`, which stamps and sends them; no service's own code writes
/// those phases.
#[test]
fn nodes_say_ready_and_stopping_through_the_node_contract() {
    let root = scl_tests::workspace::root();
    let mut found = Vec::new();
    for p in scl_tests::workspace::packages(&[]) {
        if !p.dir.starts_with("services") {
            continue;
        }
        for f in scl_tests::workspace::rust_files(&root.join(&p.dir).join("src")) {
            let text = std::fs::read_to_string(&f).unwrap_or_default();
            let writes = text.lines().any(|l| {
                (l.contains("phase = phase::") || l.contains("NodeStatus::new("))
                    && (l.contains("phase::READY") || l.contains("phase::STOPPING"))
            });
            if writes {
                found.push(f.strip_prefix(&root).unwrap_or(&f).display().to_string());
            }
        }
    }
    assert!(
        found.is_empty(),
        "services writing READY / STOPPING themselves: {found:?}"
    );
}

/// A topic's name is written once, in the table of `ipc_types::for_each_topic!`
/// (`ipc-types/src/topics.rs`); every crate takes it from there. No other non-test Rust code
/// (test modules and `tests.rs` files left out) spells a topic's channel (`"/robot_state"`),
/// nor a name that is only a topic's (`"robot_state"`; `joystick`, `status`, `estop` and
/// `log` are also the names of roles, commands and fields, so only their channel form counts).
#[test]
fn a_topic_is_named_once() {
    let root = scl_tests::workspace::root();
    let table = Path::new("ipc-types/src/topics.rs");
    let mut needles = Vec::new();
    for (s, _) in ipc_types::topics::ALL {
        needles.push(format!("\"/{}\"", s.name));
        if s.name.contains('_') {
            needles.push(format!("\"{}\"", s.name));
        }
    }
    assert!(needles.len() > ipc_types::topics::ALL.len(), "{needles:?}");
    let mut found = Vec::new();
    for p in scl_tests::workspace::packages(&[]) {
        for f in scl_tests::workspace::rust_files(&root.join(&p.dir).join("src")) {
            let rel = f.strip_prefix(&root).unwrap_or(&f).to_path_buf();
            if rel == table || rel.file_name().is_some_and(|n| n == "tests.rs") {
                continue;
            }
            let text = std::fs::read_to_string(&f).unwrap_or_default();
            // Up to the first test module (they close each file); a test-only item before
            // it is read like the rest.
            let lines: Vec<&str> = text.lines().collect();
            let end = lines
                .windows(2)
                .position(|w| {
                    w[0].trim() == "#[cfg(test)]" && w[1].trim_start().starts_with("mod ")
                })
                .unwrap_or(lines.len());
            for (i, line) in lines[..end].iter().enumerate() {
                let line = line.trim_start();
                if line.starts_with("//") {
                    continue;
                }
                for n in needles.iter().filter(|n| line.contains(n.as_str())) {
                    found.push(format!("{}:{}: {n}", rel.display(), i + 1));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "topic names written outside the table: {found:#?}"
    );
}

/// ARCHITECTURE.md names every crate of the workspace (in backquotes) and the ROS 2 bridge.
#[test]
fn the_architecture_names_every_crate_and_the_ros2_bridge() {
    let root = scl_tests::workspace::root();
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap_or_default();
    let missing: Vec<_> = scl_tests::workspace::packages(&[])
        .into_iter()
        .map(|p| p.name)
        .filter(|n| !text.contains(&format!("`{n}`")))
        .collect();
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md does not name {missing:?}"
    );
    assert!(
        text.contains("ROS 2 bridge (`ros2`"),
        "ARCHITECTURE.md does not name the ROS 2 bridge (net/src/ros2.rs)"
    );
}

/// Issue 39: no non-test function over 150 lines, and at most 15 over 100, as
/// `scripts/long-functions.py` counts them (from the `fn` line to the closing brace, test
/// modules and `tests.rs` files left out). A longer function is split into named phases.
#[test]
fn functions_stay_short() {
    let root = scl_tests::workspace::root();
    let out = std::process::Command::new("python3")
        .arg(root.join("scripts/long-functions.py"))
        .arg("--root")
        .arg(&root)
        .args([
            "--over",
            "100",
            "--max-over-100",
            "15",
            "--max-over-150",
            "0",
        ])
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3 scripts/long-functions.py: {e}"));
    assert!(
        out.status.success(),
        "functions too long (split them into named phases):\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
