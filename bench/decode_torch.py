#!/usr/bin/env python3
"""One SCL decode in PyTorch eager, timed call by call: the same computation as
mapper/benches/decode_latency.rs (m = 6, d = 2: normalise (q, c), h = 7 -> 256 -> 256 -> 12
with tanh, reshape to 6 x 2, guarded Gram-Schmidt, H a), one thread, no autograd.

Every call builds its input tensors from Python floats, as a mapper process written in Python
would. Prints one JSON object with p50/p90/p99/max in microseconds.
"""
import argparse
import json
import math
import time

import torch


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--warmup", type=int, default=2000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(42)
    m, d = 6, 2
    h = torch.nn.Sequential(
        torch.nn.Linear(m + 1, 256), torch.nn.Tanh(),
        torch.nn.Linear(256, 256), torch.nn.Tanh(),
        torch.nn.Linear(256, m * d),
    )
    mean = torch.full((m + 1,), 0.1)
    std = torch.full((m + 1,), 0.7)

    def decode(q, c, a):
        x = (torch.tensor(q + [c]) - mean) / std
        H = h(x).view(m, d)
        cols = []
        for k in range(d):
            w = H[:, k]
            for u in cols:
                w = w - (u @ w) * u
            cols.append(w / torch.sqrt(w @ w + 1e-8))
        return torch.stack(cols, 1) @ torch.tensor(a)

    def inputs(i):
        t = i * 0.001
        q = [0.1 + math.sin(t), -0.3 + 0.5 * math.cos(t), 0.7, -0.2 * math.sin(t), 0.4, (0.05 * t) % 1.0]
        return q, 0.5, [0.6 * math.cos(t), 0.6 * math.sin(t)]

    with torch.inference_mode():
        for i in range(args.warmup):
            decode(*inputs(i))
        us = []
        for i in range(args.calls):
            q, c, a = inputs(i)
            t0 = time.perf_counter_ns()
            out = decode(q, c, a)
            us.append((time.perf_counter_ns() - t0) / 1000.0)
            assert out.shape == (m,)
    us.sort()
    pick = lambda p: us[round((len(us) - 1) * p)]
    print(json.dumps({
        "bench": "scl_decode_m6_d2",
        "framework": "pytorch " + torch.__version__ + " eager",
        "calls": args.calls,
        "p50_us": pick(0.5),
        "p90_us": pick(0.9),
        "p99_us": pick(0.99),
        "max_us": us[-1],
    }))


if __name__ == "__main__":
    main()
