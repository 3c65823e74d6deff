//! The robot is named in one place: the graph's crates take the arm from the robot profile the
//! graph config names (`[graph] robot`, `kinematics::RobotProfile::by_name`), never from a
//! robot module of their own. This test reads their sources (tests excluded) and refuses any
//! mention of the Gen3 lite's module or type outside `kinematics`.
//!
//! The crates come from `cargo metadata`; those not checked are named in [`NOT_READ`] with the
//! reason. The fake Kortex robot plays the arm of any profile, so it names none either.

/// The crates not read, with the reason; every other crate of the workspace (from `cargo
/// metadata`) is.
const NOT_READ: &[(&str, &str)] = &[
    ("kinematics", "where the robots and their profiles live"),
    (
        "learning",
        "the paper's tasks and data sets are the Gen3 lite's by design, offline",
    ),
    ("scl-tests", "tests name the arm they run"),
    ("test-support", "test helpers"),
];

/// Files allowed to name the robot, with the reason (none now).
const ALLOWED: &[(&str, &str)] = &[];

/// What names the robot in code.
const NAMES: &[&str] = &["gen3_lite", "Gen3Lite"];

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
    let root = scl_tests::workspace::root();
    let mut found = Vec::new();
    let mut read = 0;
    let packages = scl_tests::workspace::packages(&[]);
    for name in NOT_READ.iter().map(|(n, _)| n) {
        assert!(
            packages.iter().any(|p| p.name == *name),
            "{name} is not a crate of the workspace: drop it from NOT_READ"
        );
    }
    for p in packages
        .iter()
        .filter(|p| !NOT_READ.iter().any(|(n, _)| *n == p.name))
    {
        for f in scl_tests::workspace::rust_files(&root.join(&p.dir).join("src")) {
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
