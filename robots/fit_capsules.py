#!/usr/bin/env python3
"""Fits one enclosing capsule to each mesh given (binary STL, metres, in its link's frame).

Used to measure robots/gen3_collision.toml from Kinova's collision meshes; standard library
only. For each file: the axis-aligned box of all vertices, then the smallest capsule found
along the vertices' principal axis (the axis through the centre of the box across it) that
encloses every vertex, searched over radii from the smallest possible to 1.6 times it; the
script checks that every vertex lies inside and prints the fit.

    python3 robots/fit_capsules.py MESH.stl[:x|y|z] [MESH.stl[:x|y|z] ...]

A `:z` (or `:x`, `:y`) after a file name fixes the capsule's axis to that axis of the link
frame instead of the principal axis (for squat, round links such as a base).
"""

import math
import struct
import sys


def read_stl(path):
    data = open(path, "rb").read()
    n = struct.unpack_from("<I", data, 80)[0]
    if 84 + 50 * n != len(data):
        raise SystemExit(f"{path}: not a binary STL")
    pts = set()
    for i in range(n):
        off = 84 + 50 * i + 12
        for k in range(3):
            pts.add(struct.unpack_from("<3f", data, off + 12 * k))
    return [tuple(float(c) for c in p) for p in pts]


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def principal_axis(pts):
    c = [sum(p[i] for p in pts) / len(pts) for i in range(3)]
    m = [[0.0] * 3 for _ in range(3)]
    for p in pts:
        d = sub(p, c)
        for i in range(3):
            for j in range(3):
                m[i][j] += d[i] * d[j]
    v = (1.0, 0.7, 0.3)
    for _ in range(200):
        w = tuple(sum(m[i][j] * v[j] for j in range(3)) for i in range(3))
        norm = math.sqrt(dot(w, w))
        v = tuple(x / norm for x in w)
    return v


def fit(pts, axis=None):
    u = axis or principal_axis(pts)
    # Two directions across the axis.
    t = (1.0, 0.0, 0.0) if abs(u[0]) < 0.9 else (0.0, 1.0, 0.0)
    v = sub(t, tuple(dot(t, u) * x for x in u))
    nv = math.sqrt(dot(v, v))
    v = tuple(x / nv for x in v)
    w = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    # The axis passes through the middle of the extents across it.
    pv = [dot(p, v) for p in pts]
    pw = [dot(p, w) for p in pts]
    cv, cw = (min(pv) + max(pv)) / 2, (min(pw) + max(pw)) / 2
    ts = [dot(p, u) for p in pts]
    rs = [math.hypot(a - cv, b - cw) for a, b in zip(pv, pw)]
    rmin = max(rs)
    best = None
    for k in range(61):
        r = rmin * (1 + 0.01 * k)
        lo = min(ti + math.sqrt(max(r * r - ri * ri, 0.0)) for ti, ri in zip(ts, rs))
        hi = max(ti - math.sqrt(max(r * r - ri * ri, 0.0)) for ti, ri in zip(ts, rs))
        if lo > hi:
            lo = hi = (lo + hi) / 2
        length = hi - lo
        vol = math.pi * r * r * length + 4 / 3 * math.pi * r ** 3
        if best is None or vol < best[0]:
            best = (vol, r, lo, hi)
    vol, r, lo, hi = best
    point = lambda s: tuple(s * u[i] + cv * v[i] + cw * w[i] for i in range(3))
    a, b = point(lo), point(hi)
    return a, b, r, vol


def inside(p, a, b, r):
    ab = sub(b, a)
    den = dot(ab, ab)
    s = 0.0 if den == 0 else max(0.0, min(1.0, dot(sub(p, a), ab) / den))
    q = tuple(a[i] + s * ab[i] for i in range(3))
    d = sub(p, q)
    return math.sqrt(dot(d, d)) <= r + 1e-9


def main():
    axes = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
    for arg in sys.argv[1:]:
        path, _, name = arg.partition(":")
        pts = read_stl(path)
        box_lo = [min(p[i] for p in pts) for i in range(3)]
        box_hi = [max(p[i] for p in pts) for i in range(3)]
        a, b, r, vol = fit(pts, axes.get(name))
        ok = all(inside(p, a, b, r) for p in pts)
        f = lambda p: "[" + ", ".join(f"{x:+.4f}" for x in p) + "]"
        print(f"{arg}: {len(pts)} vertices")
        print(f"  box min {f(box_lo)} max {f(box_hi)}")
        print(f"  capsule a {f(a)} b {f(b)} r {r:.4f} ({vol * 1e6:.0f} cm3); encloses all: {ok}")


main()
