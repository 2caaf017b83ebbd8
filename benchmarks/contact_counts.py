"""What a collision frame works on, counted, and what the compiled kernels cost per item.

    python3 benchmarks/contact_counts.py [SCENE.py] [--frames 13:17] [--warm 5]

Runs the ``--warm`` frame, then ``--frames`` in one `run_frames` call (as `stage_split.py`), with
counters on the functions that take the contact's items: detection's regions (the tessellation
vertices of one object inside the other), the closest-point queries on collision grids
(`acra.nearest.query`) and their index builds, the rays cast, the fcl BVHs built, the data points
of each response, the H-spline points evaluated by the compiled kernel (`acra.kernels.eval_points`),
the display triangles whose depth is bounded (`clearance.triangle_depth`) and the closest-point
searches of the residual (`acra.bvh.closest`) with its part BVHs (`acra.bvh.build_linear`). Prints per
collision frame each count, the CPU ms spent inside it (``time.process_time``, nested) and the
CPU µs per item: the measured per-item cost a floor estimate multiplies (`docs/performance.md`).
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import collections
import functools
import pathlib
import time

from acra import bvh, kernels, nearest
from acra import respond as R
from pipeline import clearance, grids, usdio
from pipeline import detect as D
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]
SEEN: dict = collections.defaultdict(lambda: [0, 0, 0.0])  # label -> [calls, items, CPU seconds]


def _counted(label: str, f, items):
    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            out = f(*args, **kwargs)
        finally:
            SEEN[label][2] += time.process_time() - t
            SEEN[label][0] += 1
        SEEN[label][1] += items(args, kwargs, out)
        return out
    return wrapper


def instrument() -> None:
    """Wrap module attributes, so the callers' own lookups see the counters."""
    D.regions = _counted("detect.regions: region vertices (both sides)", D.regions,
                         lambda a, k, out: sum(len(r.points) for r in out))
    D.cast = _counted("detect.cast: rays", D.cast, lambda a, k, out: len(a[1]))
    nearest.query = _counted("acra.nearest.query: closest points on collision grids", nearest.query,
                             lambda a, k, out: len(a[1]))
    nearest.index = _counted("acra.nearest.index: grid triangles indexed", nearest.index,
                             lambda a, k, out: len(a[0]))
    grids._build = _counted("grids._build: triangles in fcl BVHs built", grids._build,
                            lambda a, k, out: len(a[1]))
    R.respond = _counted("respond.respond: data points", R.respond, lambda a, k, out: len(a[1].uv))
    evaluate = kernels.eval_points
    small = _counted("acra.kernels.eval_points: surface points, calls up to 1,000", evaluate, lambda a, k, out: len(a[0]))
    large = _counted("acra.kernels.eval_points: surface points, larger calls", evaluate, lambda a, k, out: len(a[0]))
    kernels.eval_points = lambda *a, **k: (small if len(a[0]) <= 1000 else large)(*a, **k)
    clearance.triangle_depth = _counted("clearance.triangle_depth: display triangles bounded",
                                        clearance.triangle_depth, lambda a, k, out: len(a[1]))
    bvh.closest = _counted("acra.bvh.closest: residual closest points", bvh.closest, lambda a, k, out: len(a[1]))
    bvh.build = _counted("acra.bvh.build: part triangles in BVHs built", bvh.build, lambda a, k, out: len(a[0]))
    if hasattr(bvh, "build_linear"):  # the part BVH's linear build, where a checkout has it
        bvh.build_linear = _counted("acra.bvh.build: part triangles in BVHs built", bvh.build_linear,
                                    lambda a, k, out: len(a[1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="collision frames START:END (default 13:17)")
    ap.add_argument("--warm", type=int, default=5, help="a free frame run first (default 5)")
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    instrument()
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [args.warm])
    SEEN.clear()
    t = time.process_time()
    _, stats = F.run_frames(stage, scene, list(range(a, b + 1)))
    per = 1.0 / len(stats)
    total = (time.process_time() - t) * 1e3 * per
    print(f"{args.scene.name}, frames {a}-{b}: {total:.1f} ms CPU per frame, rounds {[s.iterations for s in stats]}\n")
    print("| counted | calls | items per frame | CPU ms per frame | CPU µs per item |\n|---|---:|---:|---:|---:|")
    for label, (calls, items, sec) in SEEN.items():
        each = f"{sec * 1e6 / items:.2f}" if items else "—"
        print(f"| `{label}` | {calls} | {items * per:,.0f} | {sec * 1e3 * per:.1f} | {each} |")


if __name__ == "__main__":
    main()
