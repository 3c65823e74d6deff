#!/usr/bin/env python3
"""The same training as `scl train --kind scl|cae`, in PyTorch eager, for timing comparisons.

Reads a data set directory in the project's CSV format (train/*.csv, val/*.csv with header
t,q0..,c,qd0..,cd), builds the same networks (encoder and decoder MLPs with two hidden tanh
layers of 256, SCL decoder output reshaped row-major to m x d, guarded modified Gram-Schmidt,
Lipschitz projection of the decoder after every Adam step by one power iteration per layer with
the input normalisation folded into the first layer), and trains with the same settings (Adam
lr 1e-3, batch 256 reshuffled each epoch, validation MSE after every epoch, best epoch kept).

Prints one JSON object: {"framework", "kind", "seconds" (training of all seeds, data loading
excluded), "val_loss" (best, (rad/s)^2), "threads", "seeds", "epochs", "tuples"}.
"""
import argparse
import glob
import json
import math
import os
import time

import torch


def load_split(path):
    obs, qdot = [], []
    for f in sorted(glob.glob(os.path.join(path, "*.csv"))):
        with open(f) as fh:
            head = fh.readline().strip().split(",")
            m = (len(head) - 3) // 2
            for line in fh:
                if not line.strip():
                    continue
                v = [float(x) for x in line.split(",")]
                obs.append(v[1 : m + 2])  # q, c
                qdot.append(v[m + 2 : 2 * m + 2])
    return obs, qdot


def mlp(sizes):
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(torch.nn.Linear(sizes[i], sizes[i + 1]))
        if i + 2 < len(sizes):
            layers.append(torch.nn.Tanh())
    return torch.nn.Sequential(*layers)


def gram_schmidt(h, eps=1e-8):
    # h: (B, m, d); modified Gram-Schmidt on the columns with the guarded normalisation.
    cols = []
    for k in range(h.shape[2]):
        w = h[:, :, k]
        for u in cols:
            w = w - (u * w).sum(1, keepdim=True) * u
        cols.append(w / torch.sqrt((w * w).sum(1, keepdim=True) + eps))
    return torch.stack(cols, dim=2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--kind", default="scl", choices=["scl", "cae"])
    ap.add_argument("--epochs", type=int, default=200)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--seed-offset", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--latent-dim", type=int, default=2)
    ap.add_argument("--lipschitz", type=float, default=1.0)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    tr_obs, tr_qd = load_split(os.path.join(args.data, "train"))
    va_obs, va_qd = load_split(os.path.join(args.data, "val"))
    m, d = len(tr_qd[0]), args.latent_dim
    norms = sorted(math.sqrt(sum(x * x for x in r)) for r in tr_qd)
    s = norms[min(int(len(norms) * 0.95), len(norms) - 1)]

    def stats(rows):
        t = torch.tensor(rows, dtype=torch.float64)
        mean, std = t.mean(0), t.std(0, unbiased=False)
        std[std < 1e-6] = 1.0
        return mean.float(), std.float()

    o_mean, o_std = stats(tr_obs)
    e_mean, e_std = stats([a + b for a, b in zip(tr_obs, tr_qd)])

    def prep(obs, qd):
        o = torch.tensor(obs, dtype=torch.float32)
        v = torch.tensor(qd, dtype=torch.float32)
        return (o - o_mean) / o_std, (torch.cat([o, v], 1) - e_mean) / e_std, v / s

    xo, xe, y = prep(tr_obs, tr_qd)
    vxo, vxe, vy = prep(va_obs, va_qd)
    n_obs = xo.shape[1]
    inv_std = 1.0 / o_std

    def run(seed):
        torch.manual_seed(seed)
        enc = mlp([n_obs + m, 256, 256, d])
        dec = mlp([n_obs + d if args.kind == "cae" else n_obs, 256, 256, m if args.kind == "cae" else m * d])
        opt = torch.optim.Adam(list(enc.parameters()) + list(dec.parameters()), lr=1e-3)
        lin = [l for l in dec if isinstance(l, torch.nn.Linear)]
        per = args.lipschitz ** (1.0 / len(lin))
        us = [torch.randn(l.weight.shape[1]) for l in lin]

        def forward(xo_, xe_, y_):
            a = enc(xe_)
            if args.kind == "cae":
                return dec(torch.cat([xo_, a], 1))
            h = gram_schmidt(dec(xo_).view(-1, m, d))
            return torch.bmm(h, a.unsqueeze(2)).squeeze(2)

        best = float("inf")
        for epoch in range(args.epochs):
            perm = torch.randperm(xo.shape[0])
            for i in range(0, xo.shape[0], 256):
                idx = perm[i : i + 256]
                loss = torch.nn.functional.mse_loss(forward(xo[idx], xe[idx], y[idx]), y[idx])
                opt.zero_grad()
                loss.backward()
                opt.step()
                if args.kind == "scl" and args.lipschitz > 0:
                    with torch.no_grad():
                        for li, (l, u) in enumerate(zip(lin, us)):
                            w = l.weight * inv_std if li == 0 else l.weight  # (out, in)
                            v = w @ u
                            v = v / v.norm()
                            u2 = w.t() @ v
                            sigma = u2.norm()
                            u.copy_(u2 / sigma)
                            if sigma > per:
                                l.weight.mul_(per / sigma)
            with torch.no_grad():
                val = torch.nn.functional.mse_loss(forward(vxo, vxe, vy), vy).item() * s * s
            best = min(best, val)
        return best

    # Warm-up outside the timing: the first optimiser step imports and initialises lazily
    # (about 2 s), which is not training work.
    warm = mlp([n_obs, 8, 2])
    wopt = torch.optim.Adam(warm.parameters(), lr=1e-3)
    wloss = warm(xo[:4]).pow(2).mean()
    wloss.backward()
    wopt.step()

    start = time.perf_counter()
    losses = [run(args.seed_offset + i) for i in range(args.seeds)]
    seconds = time.perf_counter() - start
    print(json.dumps({
        "framework": "pytorch " + torch.__version__,
        "kind": args.kind,
        "seconds": seconds,
        "val_loss": min(losses),
        "threads": args.threads,
        "seeds": args.seeds,
        "epochs": args.epochs,
        "tuples": xo.shape[0],
    }))


if __name__ == "__main__":
    main()
