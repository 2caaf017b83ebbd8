"""Arc-length tables for motion along a path: accuracy against cost (seed-systems.md §B).

Usage::

    python3 benchmarks/arclength.py [--repeats N]

Prints one markdown table: curve, method and its parameters, curve evaluations spent (points for
the chord methods, derivatives for Gauss, plus the node speeds every table stores), table nodes,
relative error of the total length, and build time in ms (median of ``N`` repeats).

Curves and references:

* *Bézier arc*: a 90-degree circular arc of radius 1 as one cubic Bézier (handles
  ``4/3 tan(theta/4)``).  It is not exactly circular, so the reference is its own length from
  scipy's adaptive quadrature of ``|p'(u)|`` at ``epsrel = 1e-13``.
* *Helix*: radius 1.5, rise 0.4 per radian, two turns; length ``2 turns 2 pi sqrt(r^2 + c^2)``.
* *Near-cusp Catmull-Rom* (extra): a uniform Catmull-Rom through unevenly spaced points, whose
  speed dips to 0.3% of its maximum inside one segment -- the arc and the helix have almost
  constant speed, which flatters every method; reference by segment-wise adaptive quadrature.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import quad

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.animation import curves as C  # noqa: E402
from pipeline.animation import paths as P  # noqa: E402


def bezier_arc(theta=np.pi / 2):
    k = 4 / 3 * np.tan(theta / 4)
    c, s = np.cos(theta), np.sin(theta)
    return C.bezier_polygon(np.array([[1, 0, 0], [1, k, 0], [c + k * s, s - k * c, 0], [c, s, 0]]))


def helix(r=1.5, c=0.4, turns=2.0):
    th = 2 * np.pi * turns
    curve = P.ParametricCurve(
        lambda u: np.stack([r * np.cos(u), r * np.sin(u), c * u], -1),
        lambda u: np.stack([-r * np.sin(u), r * np.cos(u), c * np.ones_like(u)], -1),
        (0.0, th))
    return curve, th * np.hypot(r, c)


def quad_length(curve):
    knots = getattr(curve, "times", np.array(curve.domain))
    sp = lambda u: np.linalg.norm(curve.derivative(np.array([u]))[0])  # noqa: E731
    return sum(quad(sp, a, b, epsabs=0, epsrel=1e-13, limit=500)[0] for a, b in zip(knots[:-1], knots[1:]))


SETTINGS = [
    ("forward", dict(n=100, supersample=1)),
    ("forward", dict(n=1000, supersample=1)),
    ("forward", dict(n=1000, supersample=10)),
    ("adaptive", dict(tol=1e-6)),
    ("adaptive", dict(tol=1e-8)),
    ("adaptive", dict(tol=1e-9)),
    ("gauss", dict(tol=1e-8)),
    ("gauss", dict(tol=1e-12)),
]

DEFAULTS = [("forward", dict(n=1000, supersample=10)), ("adaptive", dict(tol=1e-9)),
            ("gauss", dict(tol=1e-12))]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)

    arc = bezier_arc()
    hx, hx_len = helix()
    cusp = P.path_through(np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0.05, 0], [5, 4, 0], [6, 4, 0.0]]),
                          "catmull_rom", "uniform")
    cases = [("Bézier arc (90°)", arc, quad_length(arc)), ("helix (2 turns)", hx, hx_len),
             ("near-cusp Catmull-Rom", cusp, quad_length(cusp))]

    print("| curve | method | parameters | evaluations | nodes | relative error | time (ms) |")
    print("|---|---|---|---:|---:|---:|---:|")
    for name, curve, L in cases:
        for method, params in SETTINGS:
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                table = P.arc_length_table(curve, method, **params)
                times.append(time.perf_counter() - t0)
            err = abs(table.length - L) / L
            par = ", ".join(f"{k}={v:g}" for k, v in params.items())
            if (method, params) in DEFAULTS:
                par += " (default)"
            print(f"| {name} | {method} | {par} | {table.evaluations} | {table.u.size} | "
                  f"{err:.1e} | {1e3 * float(np.median(times)):.2f} |")


if __name__ == "__main__":
    main()
