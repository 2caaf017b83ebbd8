"""What the residual's part solids might carry between displays, counted and replayed.

    python3 benchmarks/part_reuse.py [--passes 30]

Runs `dog_head_spike` frames 13-17 (after a free frame) on one thread, keeping every
`residual._part` call's display and face rows, then prints per call how many of its faces an
earlier call on the same topology (the same triangles array) held with every corner's bits (all
of them: the part is taken already, `residual._part`'s kept parts or `residual._like`), and,
alternated three times, the CPU milliseconds (fastest of ``--passes``) of
`acra.pseudonormals.weld` over the parts' faces and over their displays' whole faces (a weld
kept per display or topology). At `8eddf99` it also timed the chunk boxes carried from the last
display on the same triangles (`docs/design-decisions.md`).
"""

from __future__ import annotations

import os

os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import pathlib
import time

import numpy as np
from threadpoolctl import threadpool_limits

from acra import pseudonormals
from pipeline import frames as F
from pipeline import residual, usdio
from pipeline.run import forget

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _best(fn, passes: int) -> float:
    best = np.inf
    for _ in range(passes):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return 1e3 * best


def _alike(parts: list, i: int) -> int:
    """The most faces of call ``i``'s part an earlier call on the same triangles held with every
    corner's bits."""
    path, v, t, _, rows = parts[i]
    most = 0
    for path0, v0, t0, _, rows0 in parts[:i]:
        if t0 is t and path0 == path:
            faces = t[np.intersect1d(rows, rows0)]
            most = max(most, int((v[faces].view(np.uint64) == v0[faces].view(np.uint64)).all(axis=(1, 2)).sum()))
    return most


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--passes", type=int, default=30)
    args = ap.parse_args()
    parts = []
    real = residual._part

    def keep(b, rows):
        parts.append((b.path, b.local, b.triangles, b.diagonal_local, rows))
        return real(b, rows)

    forget()
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    with threadpool_limits(limits=1, user_api="blas"):
        F.run_frames(stage, scene, [5])
        residual._part = keep
        F.run_frames(stage, scene, list(range(13, 18)))
        residual._part = real
        print(f"{len(parts)} residual._part calls; faces alike an earlier part's on the same topology / faces:")
        print("  " + ", ".join(f"{p[0].rsplit('/', 1)[-1]} {_alike(parts, i)}/{len(p[4])}" for i, p in enumerate(parts)))
        displays = {id(v): (v, t, d) for _, v, t, d, _ in parts}
        for _ in range(3):
            welds = _best(lambda: [pseudonormals.weld(v, np.ascontiguousarray(t[r]), 1e-7 * d) for _, v, t, d, r in parts],
                          args.passes)
            whole = _best(lambda: [pseudonormals.weld(v, t, 1e-7 * d) for v, t, d in displays.values()], args.passes)
            print(f"weld of the parts {welds:.3f} ms, of their {len(displays)} displays whole {whole:.3f} ms")


if __name__ == "__main__":
    main()
