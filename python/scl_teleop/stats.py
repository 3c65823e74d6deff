"""The project's one quantile (``ipc_types::stats::quantile``): linear interpolation between
the closest ranks, so Python's latency percentiles are computed as the Rust side's are."""

from __future__ import annotations

import math
from typing import Dict, Iterable


def quantile(values: Iterable[float], q: float) -> float:
    """The ``q`` quantile (``q`` in ``[0, 1]``, clamped) of ``values``; NaN when empty."""
    s = sorted(values)
    if not s:
        return math.nan
    h = min(max(q, 0.0), 1.0) * (len(s) - 1)
    lo = math.floor(h)
    frac = h - lo
    if frac == 0.0 or lo == len(s) - 1:
        return s[lo]
    return s[lo] + frac * (s[lo + 1] - s[lo])


def percentiles_us(ns: Iterable[float]) -> Dict[str, float]:
    """``{"p50", "p99", "max", "n"}`` of durations given in ns, in µs."""
    v = [x / 1e3 for x in ns]
    return {
        "p50": quantile(v, 0.5),
        "p99": quantile(v, 0.99),
        "max": max(v) if v else math.nan,
        "n": len(v),
    }
