"""LeRobot datasets checked with LeRobot itself: `scl dataset --format lerobot` output loads
with ``LeRobotDataset`` frame for frame equal to the recording, and a dataset written by
LeRobot's own writer trains with `scl train --data`. Needs the ``lerobot`` extra
(``scripts/check-lerobot.sh`` installs it in ``.venv-lerobot`` and runs this file; it is not
part of scripts/test-all: see docs/lerobot.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from .conftest import leftovers, scl_bin, unique_prefix

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

# Fails (not skips) where lerobot is missing: the test environment must have it.
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402



def _record(tmp_path: Path) -> Path:
    prefix = unique_prefix("lr")
    rec = tmp_path / "run.mcap"
    up = subprocess.run(
        [scl_bin(), "up", "--prefix", prefix, "--for", "3s", "--record", str(rec)],
        capture_output=True,
        text=True,
        env=dict(os.environ, SCL_LOG="warn"),
        timeout=120,
    )
    assert up.returncode == 0, up.stderr
    assert leftovers(prefix) == []
    return rec


def _load(rec: Path) -> dict:
    sys.path.insert(0, str(EXAMPLES))
    try:
        from load_recording import load  # type: ignore[import-not-found]
    finally:
        sys.path.remove(str(EXAMPLES))
    return load(rec)


def _states(rec: Path) -> dict:
    return _load(rec)["robot_state"]


def _operator_side(rec: Path, ticks: np.ndarray) -> tuple:
    """The stick, mode and safety flags docs/lerobot.md says each tick gets: the mapper
    command of the mapper safety forwarded (at the tick, else last before it), that
    mapper's heartbeat's mode latest at or before the tick, the tick's safe command's
    flags; 0,0 / -1 / 0 where nothing was recorded."""
    msgs = _load(rec)
    safe: dict = {}
    sc = msgs["safe_command"]
    for t, m, f in zip(sc["tick"], sc["mapper_id"], sc["flags"]):
        safe.setdefault(int(t), (int(m), int(f)))
    sticks: dict = {}
    mc = msgs["mapper_command"]
    for t, m, a in zip(mc["tick"], mc["mapper_id"], mc["action"]):
        sticks.setdefault((int(t), int(m)), (float(a[0]), float(a[1])))
    beats: dict = {}
    st = msgs["status"]
    for t, m, role, mode in zip(st["tick"], st["mapper_id"], st["role"], st["mode"]):
        if int(role) == 2 and int(t) >= 0:
            beats.setdefault(int(m), {})[int(t)] = int(mode)
    stick, mode, flags = [], [], []
    for k in (int(t) for t in ticks):
        before = [t for t in safe if t <= k]
        active = safe[max(before)][0] if before else None
        if active is None:
            ids = sorted(m for (t, m) in sticks if t == k)
            active = ids[0] if ids else None
        stick.append(sticks.get((k, active), (0.0, 0.0)))
        hb = beats.get(active, {})
        at = [t for t in hb if t <= k]
        mode.append(hb[max(at)] if at else -1)
        flags.append(safe[k][1] if k in safe else 0)
    return np.array(stick), np.array(mode), np.array(flags)


def test_export_loads_in_lerobot_frame_for_frame(tmp_path: Path) -> None:
    rec = _record(tmp_path)
    out = tmp_path / "lerobot"
    r = subprocess.run(
        [scl_bin(), "dataset", "--format", "lerobot", "--task", "reach the cube",
         "--out", str(out), str(rec)],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 0, r.stderr
    ds = LeRobotDataset("local/scl-run", root=out)
    assert ds.meta.robot_type == "gen3_lite"
    assert ds.fps == 40
    assert ds.num_episodes == 1
    assert ds.meta.tasks.index.tolist() == ["reach the cube"]
    names = ds.meta.features["observation.state"]["names"]
    assert names[-1] == "gripper" and len(names) == 7, names

    rs = _states(rec)
    # One frame per recorded tick (the shutdown state repeats the last tick: kept once).
    ticks = rs["tick"]
    keep = np.concatenate([[True], np.diff(ticks) != 0])
    n = int(keep.sum())
    assert len(ds) == n, (len(ds), n)
    q = rs["q_rad"][keep][:, :6]
    qd = rs["qdot_rad_s"][keep][:, :6]
    c = rs["gripper"][keep]
    t_ns = rs["t_ns"][keep]
    for k in range(n):
        f = ds[k]
        assert f["task"] == "reach the cube"
        assert int(f["episode_index"]) == 0 and int(f["frame_index"]) == k
        assert int(f["scl.tick"]) == int(ticks[keep][k])
        assert int(f["scl.t_ns"]) == int(t_ns[k])
        # LeRobot's loader hands float tensors out as float32; the file holds float64
        # (checked exactly by the Rust round-trip test).
        state = f["observation.state"].numpy()
        assert np.array_equal(state, np.append(q[k], c[k]).astype(state.dtype)), k
        action = f["action"].numpy()
        if k + 1 < n:
            dt = (t_ns[k + 1] - t_ns[k]) / 1e9
            assert np.array_equal(action[:6], qd[k + 1].astype(action.dtype)), k
            assert action[6] == pytest.approx((c[k + 1] - c[k]) / dt, rel=1e-6, abs=1e-6)
        else:
            assert not action.any() and int(f["scl.demonstration"]) == 0
    # The operator's side, frame for frame as the recording has it.
    assert ds.meta.features["scl.stick"]["names"] == ["x", "y"]
    stick, mode, flags = _operator_side(rec, ticks[keep])
    assert (mode >= 0).any(), mode  # the mapper's heartbeats were recorded
    for k in range(n):
        f = ds[k]
        got = f["scl.stick"].numpy()
        assert np.array_equal(got, stick[k].astype(got.dtype)), (k, got, stick[k])
        assert int(f["scl.mode"]) == int(mode[k]), k
        assert int(f["scl.safety_flags"]) == int(flags[k]), k
    ep = ds.meta.episodes[0]
    assert ep["dataset_from_index"] == 0 and ep["dataset_to_index"] == n
    assert ep["length"] == n and ep["tasks"] == ["reach the cube"]
    # The served map: the default graph serves the bundled model, embedded in the recording.
    assert ep["scl/map_kind"] in ("scl", "pca", "cae"), ep["scl/map_kind"]
    assert len(ep["scl/model_sha256"]) == 64, ep["scl/model_sha256"]
    stats = json.loads((out / "meta/stats.json").read_text())
    assert np.allclose(stats["observation.state"]["max"], np.append(q.max(0), c.max()))


def test_lerobots_own_dataset_trains(tmp_path: Path) -> None:
    joints = [f"joint_{i}" for i in range(1, 7)]
    features = {
        "observation.state": {"dtype": "float32", "shape": (7,), "names": [*joints, "gripper"]},
        "action": {"dtype": "float32", "shape": (7,), "names": [f"{j}.pos" for j in joints] + ["gripper.pos"]},
    }
    root = tmp_path / "theirs"
    ds = LeRobotDataset.create("local/theirs", fps=40, features=features, root=root,
                               robot_type="gen3_lite", use_videos=False)
    rng = np.random.default_rng(1)
    for ep in range(4):
        q = rng.uniform(-0.5, 0.5, 6)
        v = rng.uniform(-0.4, 0.4, 6)
        for k in range(120):
            q = q + v * np.sin(0.05 * k + ep) / 40
            state = np.append(q, 0.5).astype(np.float32)
            ds.add_frame({"observation.state": state, "action": state, "task": "wave"})
        ds.save_episode()
    ds.finalize()
    model = tmp_path / "theirs.safetensors"
    r = subprocess.run(
        [scl_bin(), "train", "--kind", "pca", "--data", str(root), "--out", str(model)],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert model.stat().st_size > 0
    # Another arm's profile is refused, naming both.
    r = subprocess.run(
        [scl_bin(), "train", "--kind", "pca", "--data", str(root), "--robot", "gen3",
         "--out", str(tmp_path / "x.safetensors")],
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode != 0
    assert "robot profile gen3 has 7 joints" in r.stderr and "joint_7" in r.stderr, r.stderr
