//! The workspace's crates as `cargo metadata` lists them, for the tidy tests (dependency
//! rules, the robot named once): where each lies and what it depends on.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

/// One crate of the workspace.
#[derive(Debug, Clone)]
pub struct Package {
    /// The package name.
    pub name: String,
    /// Its folder, relative to the workspace root (`services/joystick`).
    pub dir: PathBuf,
    /// Its dependencies on crates of the workspace or on `extra`, with their kind
    /// (`normal`, `dev` or `build`).
    pub deps: Vec<(String, String)>,
}

/// The workspace root (the folder above this crate).
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Every crate of the workspace, from `cargo metadata --no-deps`; dependencies are kept when
/// they are workspace crates or named in `extra` (`iceoryx2`, `zenoh`).
pub fn packages(extra: &[&str]) -> Vec<Package> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(root())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cargo metadata failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let ws_root = PathBuf::from(meta["workspace_root"].as_str().unwrap());
    let packages = meta["packages"].as_array().unwrap();
    let names: BTreeSet<&str> = packages.iter().filter_map(|p| p["name"].as_str()).collect();
    packages
        .iter()
        .map(|p| {
            let manifest = PathBuf::from(p["manifest_path"].as_str().unwrap());
            let dir = manifest
                .parent()
                .and_then(|d| d.strip_prefix(&ws_root).ok())
                .map(Path::to_path_buf)
                .unwrap_or_default();
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter_map(|d| {
                    let dep = d["name"].as_str()?;
                    (names.contains(dep) || extra.contains(&dep)).then(|| {
                        let kind = d["kind"].as_str().unwrap_or("normal").to_owned();
                        (dep.to_owned(), kind)
                    })
                })
                .collect();
            Package {
                name: p["name"].as_str().unwrap().to_owned(),
                dir,
                deps,
            }
        })
        .collect()
}

/// The Rust sources under `dir`, recursively (none if it cannot be read).
pub fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![dir.to_path_buf()];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    out
}
