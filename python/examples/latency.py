#!/usr/bin/env python3
"""Sample latency of a Python subscriber against a Rust subscriber's, in the same run.

Both wait on the robot state's event and stamp the time they received the state:
this script for itself (``now_ns()`` after ``receive``), the mapper process (Rust) in every
command it publishes (``MapperCommand.state_rx_ns``). Latency is the state's ``t_ns`` (when
the bridge published it) to that receive time, on the one monotonic clock.

    scl up --prefix lat --for 40s &
    python python/examples/latency.py --prefix lat --for 30
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Dict, List, Optional

from scl_teleop import Graph, now_ns
from scl_teleop.stats import percentiles_us


def measure(prefix: str, duration_s: float) -> Dict[str, Dict[str, float]]:
    """Python's and the Rust mapper's receive latencies (µs) over ``duration_s``."""
    with Graph(prefix, wait_s=10.0) as g:
        states = g.robot_states(wake=True)
        commands = g.mapper_commands()
        beats = g.heartbeats()
        states.drain()
        python: Dict[int, int] = {}
        rust: Dict[int, int] = {}
        active: Optional[int] = None
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            # Block on the event exactly as the mapper does, then take the sample.
            states.wait(0.1)
            while True:
                s = states.receive()
                if s is None:
                    break
                python[s.tick] = now_ns() - s.t_ns
            for b in beats.drain():
                if b.role == 3:
                    active = b.mapper_id
            for c in commands.drain():
                if c.mapper_id == active and c.state_rx_ns:
                    rust[c.tick] = c.state_rx_ns - c.state_t_ns
        for c in commands.drain():
            if c.mapper_id == active and c.state_rx_ns:
                rust[c.tick] = c.state_rx_ns - c.state_t_ns
    both = sorted(set(python) & set(rust))
    return {
        "python": percentiles_us(python[t] for t in both),
        "rust": percentiles_us(rust[t] for t in both),
    }


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prefix", default="scl", help="the graph's prefix (scl up --prefix)")
    ap.add_argument("--for", dest="duration", type=float, default=30.0, help="seconds to measure")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    r = measure(args.prefix, args.duration)
    if args.json:
        print(json.dumps(r))
    else:
        for who, p in r.items():
            print(
                f"{who:>6} subscriber: robot state published -> received: p50 {p['p50']:7.1f} µs  "
                f"p99 {p['p99']:7.1f} µs  max {p['max']:7.1f} µs  ({p['n']} ticks)"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
