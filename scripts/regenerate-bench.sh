#!/usr/bin/env bash
# Regenerates the latency figures in docs/bench/ (docs/benchmarks.md quotes them): the default
# graph (scripted joystick, the bundled SCL model, safety, mock Gen3 lite) on both transports
# without and with --rt and --load 2, then ten minutes of --rt --load 2 on iceoryx2.
# About 16 minutes; run it on a machine that is otherwise idle, as root (or with CAP_SYS_NICE
# and a memlock limit) for --rt. Keeps report.json and latency.png of each run.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p scl --bin scl
scl=target/release/scl
run() {
    local name=$1; shift
    local dir=docs/bench/$name
    local tmp
    tmp=$(mktemp -d)
    "$scl" bench latency "$@" --out "$tmp"
    mkdir -p "$dir"
    cp "$tmp/report.json" "$tmp/latency.png" "$dir/"
    rm -rf "$tmp"
}
run 60s-plain --for 60s --transport both
run 60s-rt --for 60s --transport both --rt
run 60s-rt-load2 --for 60s --transport both --rt --load 2
run 600s-rt-load2 --for 600s --rt --load 2
