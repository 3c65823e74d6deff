#!/usr/bin/env bash
# Regenerates the demonstration figures in docs/ (docs/demos.md lists them with their counts):
#   docs/demos-<task>.png   TCP paths of the generated demonstrations of each task (seed 1)
# The demonstrations themselves go to out/demos/<task>/ (not shipped: the same seed gives the
# same data). Old figures and data are moved aside (to *.old) rather than overwritten.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p scl --bin scl
scl=target/release/scl
mkdir -p out/demos docs
for task in table-cleaning pick-and-place pouring planar-reach; do
  png="docs/demos-$task.png"
  data="out/demos/$task"
  if [ -e "$png" ]; then mv "$png" "$png.old"; fi
  if [ -e "$data" ]; then rm -rf "$data.old"; mv "$data" "$data.old"; fi
  "$scl" demos --task "$task" --seed 1 --out "$data" --plot "$png"
done
