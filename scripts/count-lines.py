#!/usr/bin/env python3
"""Non-test Rust lines per workspace crate, and each crate's share of the total.

Counts every line of the crate's `src/` (blank lines and comments included), less inline test
modules: from a `#[cfg(test)]` line to the end of the file (the project keeps them last), and
files that are only compiled for tests (`src/**/tests.rs`). `tests/`, `benches/`, `examples/`
and `fuzz/` are not counted. Usage: scripts/count-lines.py [WORKSPACE_DIR]
"""
import pathlib
import sys
import tomllib

root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".")
members = tomllib.loads((root / "Cargo.toml").read_text())["workspace"]["members"]
rows = []
for m in members:
    src = root / m / "src"
    name = tomllib.loads((root / m / "Cargo.toml").read_text())["package"]["name"]
    n = 0
    for f in sorted(src.rglob("*.rs")):
        # Another member's sources (a crate nested in this one's folder) are not this crate's.
        if any((p / "Cargo.toml").exists() for p in f.parents if p != root / m and (root / m) in p.parents):
            continue
        if f.name == "tests.rs":
            continue
        for line in f.read_text().splitlines():
            if line.strip() == "#[cfg(test)]":
                break
            n += 1
    rows.append((name, m, n))
total = sum(n for _, _, n in rows)
print(f"{'crate':<18} {'folder':<22} {'lines':>7} {'share':>6}")
for name, m, n in sorted(rows, key=lambda r: -r[2]):
    print(f"{name:<18} {m:<22} {n:>7} {100 * n / total:>5.1f}%")
print(f"{'total':<18} {'':<22} {total:>7}")
