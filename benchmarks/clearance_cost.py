"""What a certified residual (`pipeline.clearance.triangle_depth`) costs in light contact.

    python3 benchmarks/clearance_cost.py [--triangles 5000] [--subdivisions 5] [--amplitudes 5e-4,1.5e-3,5e-3] [--target 5e-4]

The solid is an icosphere (5 subdivisions: 20,480 faces, radius 1). The triangles are a grid over
a cap of it (about 1 x 1), at radius ``1 + amplitude sin(2 pi 3u) sin(2 pi 3v)`` (u, v in [-1/2, 1/2]):
every triangle lies within ``amplitude`` of the sphere, half of them dipping in. The target is
``target`` x the solid's bounding-box diagonal. Prints the time to build the `Solid`, then per
amplitude and ``max_split``: milliseconds per call (median of the repeats), points evaluated and
microseconds per point, the split depth reached, the bound and the lower bound (as fractions of
the diagonal), and whether it is complete (the default point budget, 200,000, applies).
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import time

import numpy as np
import trimesh

from pipeline import clearance as C


def cap(triangles: int, amplitude: float) -> np.ndarray:
    """About ``triangles`` triangles ``(t, 3, 3)`` of a bumpy grid over the unit sphere's cap around +z."""
    n = max(int(round(np.sqrt(triangles / 2))), 1)
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, n + 1), np.linspace(-0.5, 0.5, n + 1), indexing="ij")
    d = np.stack([u, v, np.ones_like(u)], axis=-1)
    r = 1 + amplitude * np.sin(6 * np.pi * u) * np.sin(6 * np.pi * v)
    pts = (d / np.linalg.norm(d, axis=-1, keepdims=True) * r[..., None]).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, e = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, e], -1).reshape(-1, 3)])
    return pts[faces]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=5000)
    ap.add_argument("--subdivisions", type=int, default=5)
    ap.add_argument("--amplitudes", default="5e-4,1.5e-3,5e-3", help="comma-separated, in units of the radius")
    ap.add_argument("--target", type=float, default=5e-4, help="as a fraction of the solid's diagonal")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    mesh = trimesh.creation.icosphere(subdivisions=args.subdivisions)
    t = time.perf_counter()
    s = C.solid(mesh.vertices, mesh.faces)
    build = 1e3 * (time.perf_counter() - t)
    diag = float(np.linalg.norm(np.ptp(s.vertices, axis=0)))
    target = args.target * diag
    print(f"solid: {len(s.faces)} faces, built in {build:.1f} ms; target {target:.3g} "
          f"({args.target:g} of the diagonal {diag:.3f})")
    print(f"{'amplitude':>9} {'triangles':>9} {'max_split':>9} {'ms/call':>8} {'evaluated':>9} {'us/point':>8} {'split':>5} "
          f"{'bound/diag':>10} {'lower/diag':>10} complete")
    for amplitude in map(float, args.amplitudes.split(",")):
        tri = cap(args.triangles, amplitude)
        for max_split in (4, 6):
            times = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                d = C.triangle_depth(s, tri, target, max_split=max_split)
                times.append(1e3 * (time.perf_counter() - t))
            ms = float(np.median(times))
            print(f"{amplitude:9.2g} {len(tri):>9} {max_split:>9} {ms:8.1f} {d.evaluated:>9} {1e3 * ms / max(d.evaluated, 1):8.1f} "
                  f"{d.split:>5} {d.bound / diag:10.3g} {d.lower / diag:10.3g} {d.complete}")


if __name__ == "__main__":
    main()
