#!/usr/bin/env python3
"""An MCAP recording of a graph (``scl up --record``, ``scl record``) into numpy arrays, one
dict of arrays per topic, with the ``mcap`` package.

    scl up --prefix lab --for 10s --record run.mcap
    python python/examples/load_recording.py run.mcap            # what is in it
    python python/examples/load_recording.py run.mcap --npz run.npz

Each channel (``/robot_state``, ``/safe_command``, ...) holds JSON messages whose fields are
the message type's (``scl_teleop.msg``): a number becomes a 1-D array over the messages, a
joint array a 2-D array (messages x entries). A tick of "none" (``null`` in JSON) becomes -1.
``log_time_ns`` is each message's MCAP log time: the wall-clock time of the run (Unix ns;
recordings made before 2026-11 have the monotonic clock there). The graph's own monotonic
clock is each message's ``t_ns`` field. Recordings are in zstd-compressed chunks, which the ``mcap``
package reads (it depends on ``zstandard``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
from mcap.reader import make_reader

Arrays = Dict[str, Dict[str, np.ndarray]]


def load(path: Path, topics: Optional[List[str]] = None) -> Arrays:
    """Every message of the recording at ``path`` as ``{topic: {field: array}}``, topics
    named without the leading ``/`` (``robot_state``); only ``topics`` if given."""
    rows: Dict[str, List[dict]] = {}
    times: Dict[str, List[int]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages():
            topic = channel.topic.lstrip("/")
            if topics and topic not in topics:
                continue
            if channel.message_encoding != "json":
                continue
            rows.setdefault(topic, []).append(json.loads(message.data))
            times.setdefault(topic, []).append(message.log_time)
    out: Arrays = {}
    for topic, msgs in rows.items():
        fields: Dict[str, np.ndarray] = {"log_time_ns": np.array(times[topic], dtype=np.int64)}
        for name in msgs[0]:
            values = [m.get(name) for m in msgs]
            if any(isinstance(v, (dict, str)) for v in values):
                continue  # nested or text fields (control messages): left as JSON
            if all(v is None or isinstance(v, (int, float, bool)) for v in values):
                ints = all(v is None or isinstance(v, int) for v in values)
                if ints:
                    fields[name] = np.array([-1 if v is None else v for v in values], dtype=np.int64)
                else:
                    fields[name] = np.array(
                        [np.nan if v is None else v for v in values], dtype=np.float64
                    )
            else:
                try:
                    fields[name] = np.array(values, dtype=np.float64)
                except (TypeError, ValueError):
                    continue  # lists of names, arrays missing at some ticks: left as JSON
        out[topic] = fields
    return out


def joint_travel_rad(q: np.ndarray) -> float:
    """The joint-space path length of the joint angles ``q`` (states x joints, rad): the
    Euclidean norm of each state-to-state change, summed. The definition ``scl up --json``'s
    ``joint_travel_rad`` and the bridge's heartbeat (``NodeStatus.joint_travel_rad``) use, so
    the two agree on one run. It is the arc length of the arm's path in joint space (the
    speed scale of a map is a speed in the same norm); the sum of every joint's absolute
    change (the L1 length) is up to ``sqrt(n_joints)`` times larger."""
    q = np.asarray(q, dtype=np.float64)
    if len(q) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum())


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", type=Path, help="an MCAP file written by scl")
    ap.add_argument("--topics", help="comma-separated topics (default: all)")
    ap.add_argument("--npz", type=Path, help="also save the arrays as TOPIC/FIELD in this .npz")
    args = ap.parse_args(argv)
    if not args.recording.exists():
        print(f"load_recording: {args.recording}: no such file", file=sys.stderr)
        return 2
    data = load(args.recording, args.topics.split(",") if args.topics else None)
    for topic, fields in sorted(data.items()):
        n = len(fields["log_time_ns"])
        shapes = ", ".join(f"{k}{list(v.shape[1:]) if v.ndim > 1 else ''}" for k, v in fields.items())
        print(f"{topic}: {n} messages: {shapes}")
    if "robot_state" in data:
        rs = data["robot_state"]
        q = rs["q_rad"][:, : int(rs["n_joints"][0])]
        span = (rs["log_time_ns"][-1] - rs["log_time_ns"][0]) / 1e9
        print(
            f"robot_state: ticks {rs['tick'][0]}..{rs['tick'][-1]} over {span:.2f} s; "
            f"joint travel {joint_travel_rad(q):.3f} rad"
        )
    if args.npz:
        if args.npz.exists():
            print(f"load_recording: {args.npz} exists; not overwritten", file=sys.stderr)
            return 2
        np.savez(args.npz, **{f"{t}/{k}": v for t, fs in data.items() for k, v in fs.items()})
        print(f"saved {args.npz}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
