"""Iterated Bartels–Beatty (blend) against the direct minimum-norm solve: residual and time.

    python benchmarks/solvers.py

For the thesis's cases (an 8-CV curve through 4 points, an 11×11 surface through 3 points) and
contact-sized cases (12 and 40 points of a smooth dent on a 20×20 sheet; 40 points over ~9
patches is more than the CVs can fit exactly, so both solvers settle at the least-squares error) prints, per iteration cap, the max
remaining point error and the median time of one solve, beside the direct solve's.
"""

from __future__ import annotations

import time

import numpy as np

from acra import hspline as H
from acra import shapes
from acra.basis import Direction, basis, locate
from acra.interpolate import PointWeights, iterate_blend, min_norm_solve, point_weights


def _curve_case():
    d = Direction(8, False)
    seg, t = locate(d, np.array([0.4, 1.3, 2.2, 4.1]), 0)
    pw = PointWeights(0, np.repeat(np.arange(4), 4), (seg[:, None] + np.arange(4)).reshape(-1), basis(t).reshape(-1), np.arange(8), 4, np.ones(4, bool))
    return "curve 8 CVs, 4 points", pw, np.random.default_rng(1).normal(size=(4, 3))


def _surface_case(n, k, seed):
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sheet(n, n), depth=1)
    c = (n - 3) / 2
    u = c + rng.uniform(-1.5, 1.5, k)
    v = c + rng.uniform(-1.5, 1.5, k)
    # a contact-like, smooth wanted move: a dent of Gaussian profile along -z
    dq = np.zeros((k, 3))
    dq[:, 2] = -0.1 * np.exp(-((u - c) ** 2 + (v - c) ** 2))
    if k <= 3:
        dq = rng.normal(size=(k, 3)) * 0.1
    return f"surface {n}x{n}, {k} points", point_weights(hs, 0, u, v), dq


def _median_ms(fn, repeats=25):
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def main() -> None:
    cases = [_curve_case(), _surface_case(11, 3, 2), _surface_case(20, 40, 3), _surface_case(20, 12, 4)]
    print("| case | solver | iterations | max remaining / max move | median ms |")
    print("|---|---|---:|---:|---:|")
    for name, pw, dq in cases:
        scale = np.abs(dq).max()
        for it in (1, 2, 3, 4, 5, 8, 20):
            dv, hist = iterate_blend(pw, dq, it)
            print(f"| {name} | blend | {it} | {hist[-1] / scale:.2e} | {_median_ms(lambda: iterate_blend(pw, dq, it)):.3f} |")
        dv = min_norm_solve(pw, dq)
        err = np.abs(pw.apply(dv) - dq).max() / scale
        print(f"| {name} | direct | - | {err:.2e} | {_median_ms(lambda: min_norm_solve(pw, dq)):.3f} |")


if __name__ == "__main__":
    main()
