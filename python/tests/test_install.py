"""The package installs from a read-only checkout and writes nothing into its source tree (the
build backend builds the wheel into pip's own directory: no ``build/``, no ``*.egg-info``)."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path
from typing import Dict, Tuple

from .conftest import REPO


def tree(root: Path) -> Dict[str, Tuple[int, int]]:
    """Every path under ``root`` with its size and modification time."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(dirpath, name)
            st = p.lstat()
            out[str(p.relative_to(root))] = (st.st_size, st.st_mtime_ns)
    return out


def set_writable(root: Path, writable: bool) -> None:
    for dirpath, dirs, files in os.walk(root):
        for name in [*dirs, *files, "."]:
            p = Path(dirpath, name)
            mode = p.lstat().st_mode
            w = stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH
            os.chmod(p, (mode | stat.S_IWUSR) if writable else (mode & ~w))


def test_installs_from_a_read_only_checkout(tmp_path: Path) -> None:
    src = tmp_path / "python"
    shutil.copytree(
        REPO / "python",
        src,
        ignore=shutil.ignore_patterns("__pycache__", ".pytest_cache", "build", "*.egg-info"),
    )
    before = tree(src)
    set_writable(src, False)
    target = tmp_path / "site"
    try:
        # Without build isolation or an index: the build backend comes from the test extra.
        out = subprocess.run(
            [
                sys.executable, "-m", "pip", "install", "--disable-pip-version-check",
                "--no-deps", "--no-build-isolation", "--no-index", "--target", str(target),
                str(src),
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        after = tree(src)
    finally:
        set_writable(src, True)
    assert out.returncode == 0, f"{out.stdout}\n{out.stderr}"
    # (Run as root, the read-only bits do not stop a write: the tree's listing does.)
    assert after == before, sorted(set(after.items()) ^ set(before.items()))
    installed = {p.name for p in (target / "scl_teleop").iterdir()}
    assert {"__init__.py", "graph.py", "msg.py", "stats.py", "py.typed"} <= installed, installed
    assert list(target.glob("scl_teleop-*.dist-info")), sorted(p.name for p in target.iterdir())
