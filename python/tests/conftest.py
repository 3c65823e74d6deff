"""Fixtures: the ``scl`` binary and real graphs under unique prefixes, checked for leftovers.

The tests run the ``scl`` binary named by ``SCL_BIN`` (``.ci/run`` builds it and sets it);
each graph runs under its own prefix, is stopped with SIGTERM (bridge first) after the test's
Python side has left, and must leave nothing named ``scl_<prefix>_*`` in ``/dev/shm`` or
iceoryx2's directory.
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Iterator, List, Optional

import pytest

from scl_teleop import Graph, GraphNotRunning

REPO = Path(__file__).resolve().parents[2]
_COUNTER = itertools.count()


def scl_bin() -> str:
    """The ``scl`` binary under test, from ``SCL_BIN``; fails the test run with what to do
    when it is missing."""
    path = os.environ.get("SCL_BIN", "")
    if not path:
        pytest.exit(
            "SCL_BIN is not set: build the binary (`cargo build -p scl --bin scl`) and run "
            "`SCL_BIN=$CARGO_TARGET_DIR/debug/scl pytest python/tests` (.ci/run does both)",
            returncode=2,
        )
    if not os.access(path, os.X_OK):
        pytest.exit(f"SCL_BIN={path} is not an executable `scl` binary", returncode=2)
    return path


def unique_prefix(tag: str) -> str:
    """A prefix no other test or test run uses."""
    return f"py{tag}{os.getpid()}x{next(_COUNTER)}"


def leftovers(prefix: str) -> List[str]:
    """Files of graph ``prefix`` left in ``/dev/shm`` or iceoryx2's directory."""
    needle = f"scl_{prefix}_"
    found = []
    for root in ("/dev/shm", "/tmp/iceoryx2"):
        for dirpath, _dirs, files in os.walk(root):
            found += [os.path.join(dirpath, f) for f in files if needle in f]
    return found


class RunningGraph:
    """A ``scl up`` child under its own prefix."""

    def __init__(self, prefix: str, proc: subprocess.Popen, log: Path) -> None:
        self.prefix = prefix
        self.proc = proc
        self.log = log
        self.graphs: List[Graph] = []

    def join(self) -> Graph:
        """A Python member of the graph, closed before the graph stops."""
        g = Graph(self.prefix)
        self.graphs.append(g)
        return g

    def stop(self) -> int:
        """Closes the Python members, stops ``scl up`` (SIGTERM) and returns its exit code."""
        for g in self.graphs:
            g.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


def start_graph(tmp_path: Path, tag: str, *args: str, joystick: Optional[str] = "external") -> RunningGraph:
    """Starts ``scl up --prefix <unique> [--joystick external] ARGS`` and waits until the
    first robot state is published."""
    prefix = unique_prefix(tag)
    log = tmp_path / f"scl-up-{prefix}.log"
    cmd = [scl_bin(), "up", "--prefix", prefix, "--for", "300s", *args]
    if joystick:
        cmd += ["--joystick", joystick]
    env = dict(os.environ, SCL_LOG="warn")
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=REPO)
    running = RunningGraph(prefix, proc, log)
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"`{' '.join(cmd)}` exited: {log.read_text()}")
        try:
            with Graph(prefix) as g:
                if g.robot_states().next(0.5) is not None:
                    return running
        except GraphNotRunning:
            pass
        if time.monotonic() > deadline:
            running.stop()
            raise RuntimeError(f"graph `{prefix}` published no robot state in 60 s: {log.read_text()}")
        time.sleep(0.1)


def finish(running: RunningGraph) -> None:
    """Stops the graph and checks it left nothing behind."""
    code = running.stop()
    assert code == 0, f"scl up exited with {code}: {running.log.read_text()}"
    deadline = time.monotonic() + 5
    while leftovers(running.prefix) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert leftovers(running.prefix) == [], leftovers(running.prefix)


@pytest.fixture
def graph(tmp_path: Path) -> Iterator[RunningGraph]:
    """A mock-arm graph with the bundled model and an external operator."""
    running = start_graph(tmp_path, "g")
    try:
        yield running
    finally:
        finish(running)
