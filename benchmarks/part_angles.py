"""The corner angles of the residual's part solids: numpy's ``arctan2`` against a compiled ``atan2``.

    python3 benchmarks/part_angles.py [SCENE.py] [--frames 13:17] [--passes 20]

A part solid (`pipeline.clearance.solid` with ``part``) weights its vertex pseudo-normals by its
corners' angles, ``arctan2(|e1 x e2|, e1 . e2)``, taken by numpy between its two compiled calls
(`acra.pseudonormals.welded_part`, `acra.bvh.part_tree`). Runs the scene's ``--frames`` (after a
free frame), keeping the sines and cosines of every part solid built, then takes their angles
both ways ``--passes`` times and prints the CPU milliseconds of the fastest pass of each (all
parts together), how many angles differ in their bits, and a digest of numpy's angles (the ones
the solids use): a compiled ``atan2`` in `part_tree` would join its two calls into one only if it
gave numpy's bits.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import hashlib
import math
import pathlib
import time

import numpy as np
from numba import njit

from pipeline import clearance, usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]


@njit(cache=False)
def _angles(sin, cos, out):
    for i in range(sin.shape[0]):
        for k in range(3):
            out[i, k] = math.atan2(sin[i, k], cos[i, k])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--passes", type=int, default=20)
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    kept = []
    real = clearance._compiled_part

    def keep(mesh, *more):
        kept.append((np.ascontiguousarray(mesh[5]), np.ascontiguousarray(mesh[6])))  # each corner's |e1 x e2| and e1 . e2
        return real(mesh, *more)

    clearance._compiled_part = keep
    F.run_frames(stage, scene, list(range(a, b + 1)))
    clearance._compiled_part = real
    outs = [np.empty_like(s) for s, _ in kept]
    for (s, c), out in zip(kept, outs):
        _angles(s, c, out)  # compiled before the timing
    best_numpy = best_compiled = np.inf
    for _ in range(args.passes):
        t = time.process_time()
        ref = [np.arctan2(s, c) for s, c in kept]
        best_numpy = min(best_numpy, time.process_time() - t)
        t = time.process_time()
        for (s, c), out in zip(kept, outs):
            _angles(s, c, out)
        best_compiled = min(best_compiled, time.process_time() - t)
    n = sum(x.size for x in ref)
    differ = sum(int(np.count_nonzero(x.view(np.uint64) != y.view(np.uint64))) for x, y in zip(ref, outs))
    h = hashlib.sha1()
    for x in ref:
        h.update(x.tobytes())
    print(f"{args.scene.name}, frames {a}-{b}: {len(kept)} part solids, {n} corner angles; numpy's arctan2 "
          f"{1e3 * best_numpy:.3f} ms, compiled atan2 {1e3 * best_compiled:.3f} ms (fastest of {args.passes} passes, "
          f"all parts); {differ} angles differ in their bits; numpy {np.__version__}; angles {h.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
