"""Evaluation throughput of an H-spline with 7 levels and detail in one region.

    python benchmarks/eval_throughput.py

Prints points per second (median of repeats, one run) for the display tessellation and for a
collision tessellation of the refined region, plus the stored CV count.
"""

from __future__ import annotations

import time

import numpy as np

from acra import hspline as H
from acra import shapes
from acra import tessellate as T


def build(seed: int = 0) -> H.HSpline:
    """A 16×14 sphere, 7 levels, detail made movable and offset around one spot."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(16, 14), depth=7)
    for k, centre in ((2, 18), (4, 74), (6, 300)):
        hs = H.make_movable(hs, k, np.array([[centre, centre], [centre + 1, centre + 1]]))
    for k in range(1, 7):
        idx, off = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, idx, 0.01 / k * rng.normal(size=off.shape))
    return hs


def _median_time(fn, repeats: int = 7) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    hs = build()
    det = H.details(hs)
    t_det = _median_time(lambda: H.details(hs))
    topo = T.display_topology(hs.u, hs.v, 4)
    t_disp = _median_time(lambda: T.evaluate_grid(hs, topo, det))
    region = np.array([[pu, pv] for pu in range(3, 7) for pv in range(3, 7)])
    t_coll = _median_time(lambda: T.patch_grids(hs, region, 32, det))
    n_coll = region.shape[0] * 33 * 33
    print(f"stored CVs: {H.storage_size(hs)} over {hs.depth} levels (dense level 6 would be "
          f"{hs.u.cvs(6) * hs.v.cvs(6)})")
    print("| tessellation | points | median ms | points/s |")
    print("|---|---:|---:|---:|")
    print(f"| frames and detail vectors (all levels) | {sum(int(l.movable.sum()) for l in hs.fine)} CVs | {t_det * 1e3:.2f} | - |")
    print(f"| display (samples 4, points + normals) | {topo.u.size} | {t_disp * 1e3:.2f} | {topo.u.size / t_disp:,.0f} |")
    print(f"| collision (16 patches x 32x32) | {n_coll} | {t_coll * 1e3:.2f} | {n_coll / t_coll:,.0f} |")


if __name__ == "__main__":
    main()
