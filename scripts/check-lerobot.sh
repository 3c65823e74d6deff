#!/usr/bin/env bash
# The LeRobot conformance check (python/tests/test_lerobot.py): a `scl up --record` run
# exported with `scl dataset --format lerobot` loads with LeRobot's own LeRobotDataset frame
# for frame equal to the recording, and a dataset written by LeRobot's writer trains with
# `scl train --data`. It needs the `lerobot` package, which brings torch and its CUDA
# libraries from PyPI: 8.3 GB and 55 minutes to install on a 2-core machine (measured
# 2026-11-28), so it runs in its own virtual environment (.venv-lerobot, kept between runs)
# and not in scripts/test-all. See docs/lerobot.md.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build -q -p scl --bin scl
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
venv=.venv-lerobot
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check "./python[test,lerobot]"
SCL_BIN="$target_dir/debug/scl" "$venv/bin/python" -m pytest python/tests/test_lerobot.py
