#!/usr/bin/env python3
"""A live printout of a running graph: once a second, the ticks and misses, the end-to-end
latency (robot state published -> executed command received by the bridge), this Python
subscriber's own sample latency, the active mapper, and the safety rules that acted.

    scl up --prefix lab &
    python python/examples/watch.py --prefix lab            # Ctrl-C to stop
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from typing import List, Optional

from scl_teleop import Graph, now_ns, safe_flags, safety_state, state_flags
from scl_teleop.stats import percentiles_us


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prefix", default="scl", help="the graph's prefix (scl up --prefix)")
    ap.add_argument("--for", dest="duration", type=float, help="stop after this many seconds")
    args = ap.parse_args(argv)
    with Graph(args.prefix, wait_s=10.0) as g:
        states = g.robot_states()
        commands = g.safe_commands()
        beats = g.heartbeats()
        start = time.monotonic()
        next_line = start + 1.0
        e2e: List[int] = []
        mine: List[int] = []
        rules: Counter = Counter()
        ticks = missed = 0
        last_missed: Optional[int] = None
        active: Optional[int] = None
        holds: List[str] = []
        try:
            while args.duration is None or time.monotonic() - start < args.duration:
                s = states.next(max(next_line - time.monotonic(), 0.0))
                if s is not None:
                    mine.append(now_ns() - s.t_ns)
                    ticks += 1
                    if last_missed is not None:
                        missed += s.missed - last_missed
                    last_missed = s.missed
                    if s.flags & state_flags.SHUTDOWN:
                        print("watch: the bridge shut down")
                        break
                for c in commands.drain():
                    rules.update(safe_flags.names_of(c.flags))
                for b in beats.drain():
                    if b.role == 4 and b.latency_ns:  # the bridge: state -> command received
                        e2e.append(b.latency_ns)
                    elif b.role == 3:
                        active = b.mapper_id
                        holds = safety_state.names_of(b.safety_state)
                if time.monotonic() >= next_line:
                    next_line += 1.0
                    p, m = percentiles_us(e2e), percentiles_us(mine)
                    acted = " ".join(f"{k}:{v}" for k, v in sorted(rules.items())) or "none"
                    print(
                        f"{time.monotonic() - start:5.0f}s  ticks {ticks:3d}  missed {missed}  "
                        f"e2e p50 {p['p50']:6.1f} µs p99 {p['p99']:7.1f}  python rx p50 "
                        f"{m['p50']:6.1f} µs p99 {m['p99']:7.1f}  mapper {active}  "
                        f"holds [{', '.join(holds)}]  rules {acted}",
                        flush=True,
                    )
                    e2e, mine, rules, ticks, missed = [], [], Counter(), 0, 0
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
