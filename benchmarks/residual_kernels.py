"""One compiled kernel of the residual's calls in a run, replayed: what it costs apart from the frame.

    python3 benchmarks/residual_kernels.py [SCENE.py] [--kernel clearcells._clear_cells] [--frames 13:17] [--passes 30]

Runs the scene's ``--frames`` (after a free frame, as `residual_calls.py` does), keeping a copy of
the arguments of every call of ``--kernel`` (a compiled function of `acra`, named as
``MODULE.NAME``: `acra.clearcells._clear_cells`, the flooded grids of `residual._clear_depth`;
`acra.meshrows._faces_at`, the corners, box and shift of the triangles near the other object;
`acra.meshrows._face_chunks`, a display's chunk boxes; `acra.bvh._part_tree`, a part solid's
vertex normals and tree; `acra.depthbound._depth`, the branch and bound of one `pair_depth`
call whose answer no kept part answers), then replays them ``--passes`` times and
prints the CPU milliseconds of the fastest pass and a digest of every answer (each call's return
value and what it writes of its output arrays, `ANSWERS`): two checkouts answer alike when their
digests agree. Run it with ``PYTHONPATH`` at each checkout, alternating, for a comparison.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import hashlib
import importlib
import pathlib
import time

import numpy as np

from pipeline import usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]


# per kernel, what a call answers: its return value and the parts of its output arrays it writes
# (an output array is allocated empty, and the rest of it holds whatever memory it was given)
ANSWERS = {
    "clearcells._clear_cells": lambda m, a: (np.int64(m), a[12], a[13][:max(m, 0)]),  # count, keep, chosen rows
    "meshrows._faces_at": lambda plain, a: (np.bool_(plain), a[4], a[5]) + ((a[6],) if len(a[2]) else ()),
    "meshrows._face_chunks": lambda _, a: tuple(a[4:8]),  # the chunks' and groups' boxes
    # a part's vertex normals, box, corners (put back from the leaf corners), leaf order, the
    # filled nodes, their count, leaf corners
    "bvh._part_tree": lambda t, _: t[:2] + (_in_rows(t[10], t[2]), t[2]) + tuple(x[:t[9]] for x in t[3:9])
    + (np.int64(t[9]), t[10]),
    # the branch and bound's code, bound, depth found, completeness, points evaluated, level, points inside
    "depthbound._depth": lambda out, _: tuple(np.asarray(x) for x in out),
}


def _in_rows(leaf_tri: np.ndarray, order: np.ndarray) -> np.ndarray:
    """The corners ``(f, 3, 3)`` in the faces' rows, from a tree's ``leaf_tri`` and ``order``."""
    out = np.empty_like(leaf_tri)
    out[order] = leaf_tri
    return out


def _digest(h, value) -> None:
    """``value`` (a call's answer: arrays, numbers, tuples of them) into the hash ``h``."""
    if isinstance(value, tuple):
        for v in value:
            _digest(h, v)
    else:
        h.update(np.ascontiguousarray(value).tobytes())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--kernel", default="clearcells._clear_cells", help="MODULE.NAME in acra (default clearcells._clear_cells)")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--passes", type=int, default=30)
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    module_name, name = args.kernel.rsplit(".", 1)
    module = importlib.import_module(f"acra.{module_name}")
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    calls = []
    real = getattr(module, name)

    def keep(*arrays):
        calls.append([x.copy() if isinstance(x, np.ndarray) and x.flags.writeable else x for x in arrays])
        return real(*arrays)

    setattr(module, name, keep)
    F.run_frames(stage, scene, list(range(a, b + 1)))
    setattr(module, name, real)
    best, h = np.inf, hashlib.sha1()
    for n in range(args.passes):
        t0 = time.process_time()
        got = [real(*arrays) for arrays in calls]  # a call writes its output arrays in place
        best = min(best, time.process_time() - t0)
        if n == 0 and args.kernel in ANSWERS:
            for value, arrays in zip(got, calls):
                _digest(h, ANSWERS[args.kernel](value, arrays))
    print(f"{args.scene.name}, frames {a}-{b}: {len(calls)} {args.kernel} calls, fastest of {args.passes} passes "
          f"{1e3 * best:.3f} ms CPU; answers {h.hexdigest()[:12] if args.kernel in ANSWERS else '(no digest for this kernel)'}")


if __name__ == "__main__":
    main()
