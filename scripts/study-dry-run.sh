#!/usr/bin/env bash
# A dry run of the paper's first study (examples/study/study1.toml) with one scripted
# participant on the mock arm: starts the graph, runs P01 with the keys in
# examples/study/dry-run-P01.keys, stops the graph and writes the report.
#
#   scripts/study-dry-run.sh [OUT_DIR]      # default out/study-dry-run (must not exist)
#
# Serves the study's models, shipped in models/study/ (scripts/study-models.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out/study-dry-run}"
if [ -e "$out" ]; then echo "$out exists: nothing is overwritten; give another directory" >&2; exit 2; fi
cargo build --release -q -p scl --bin scl
scl=target/release/scl
export SCL_PREFIX="dryrun$$"
mkdir -p "$out"
"$scl" up --script step --json > "$out/up.json" 2> "$out/up.log" &
up=$!
trap 'kill -TERM $up 2>/dev/null || true' EXIT
sleep 2
start=$(date +%s)
"$scl" study run examples/study/study1.toml --participant P01 --out "$out/P01" \
    --keys examples/study/dry-run-P01.keys | tee "$out/screen.txt"
echo "P01 took $(( $(date +%s) - start )) s"
kill -TERM $up; wait $up || true; trap - EXIT
"$scl" study report "$out/P01" --out "$out/report"
echo "graph: $(cat "$out/up.json")"
