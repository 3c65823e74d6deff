"""The quantile is the Rust side's (the cases of ``ipc_types::stats``)."""

import math

from scl_teleop.stats import percentiles_us, quantile


def test_interpolates_between_closest_ranks() -> None:
    s = [float(i) for i in range(1, 101)]
    assert quantile(s, 0.0) == 1.0
    assert quantile(s, 0.5) == 50.5
    assert abs(quantile(s, 0.99) - 99.01) < 1e-12
    assert quantile(s, 1.0) == 100.0
    assert quantile(s, 2.0) == 100.0
    assert quantile([7.0], 0.3) == 7.0
    assert quantile([0.0, 10.0], 0.25) == 2.5
    assert quantile([3.0, 1.0, 2.0], 0.5) == 2.0
    assert math.isnan(quantile([], 0.5))


def test_percentiles_in_microseconds() -> None:
    p = percentiles_us([1000.0, 3000.0])
    assert (p["p50"], p["max"], p["n"]) == (2.0, 3.0, 2)
