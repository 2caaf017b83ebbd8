"""Work the residual's parts and chunk boxes might carry between displays, replayed.

    python3 benchmarks/part_reuse.py [--passes 30]

Runs `dog_head_spike` frames 13-17 (after a free frame) on one thread, keeping every
`meshrows.face_chunks` call (with the ``since`` this checkout gives: the last display's on the
same triangles) and every `residual._part` call's display, then prints, alternated three times,
the CPU milliseconds (fastest of ``--passes``) of the chunk boxes taken afresh and since the last
display, and of `acra.pseudonormals.weld` over the parts' faces and over their displays' whole
faces (a weld kept per display or topology).
"""

from __future__ import annotations

import os

os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import pathlib
import time

import numpy as np
from threadpoolctl import threadpool_limits

from acra import meshrows, pseudonormals
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--passes", type=int, default=30)
    args = ap.parse_args()
    chunks, parts = [], []
    real_chunks, real_part = meshrows.face_chunks, residual._part

    def keep_chunks(points, used, since=None):
        chunks.append((points, used, since))
        return real_chunks(points, used, since)

    def keep_part(b, rows):
        parts.append((b.local, b.triangles, b.diagonal_local, rows))
        return real_part(b, rows)

    forget()
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    with threadpool_limits(limits=1, user_api="blas"):
        F.run_frames(stage, scene, [5])
        meshrows.face_chunks, residual._part = keep_chunks, keep_part
        F.run_frames(stage, scene, list(range(13, 18)))
        meshrows.face_chunks, residual._part = real_chunks, real_part
        since = sum(s is not None for *_, s in chunks)
        print(f"{len(chunks)} chunk builds ({since} since a display on the same triangles), {len(parts)} parts")
        displays = {id(v): (v, t, d) for v, t, d, _ in parts}
        for _ in range(3):
            afresh = _best(lambda: [real_chunks(p, u) for p, u, _ in chunks], args.passes)
            carried = _best(lambda: [real_chunks(p, u, s) for p, u, s in chunks], args.passes)
            welds = _best(lambda: [pseudonormals.weld(v, np.ascontiguousarray(t[r]), 1e-7 * d) for v, t, d, r in parts],
                          args.passes)
            whole = _best(lambda: [pseudonormals.weld(v, t, 1e-7 * d) for v, t, d in displays.values()], args.passes)
            print(f"chunk boxes afresh {afresh:.3f} ms, since {carried:.3f} ms; weld of the parts {welds:.3f} ms, "
                  f"of their {len(displays)} displays whole {whole:.3f} ms")


if __name__ == "__main__":
    main()
