"""Where a collision frame's wall-clock time goes, function by function (no profiler overhead).

    python3 benchmarks/stage_split.py [SCENE.py] [--frames 13:17] [--warm 5]

Wraps the detection, response, shape-building and residual functions the frame loop calls with
``time.perf_counter`` and prints, per function, the calls and the milliseconds per collision frame
spent inside it (nested: `regions` includes the `Shape.nearest` calls it makes). The scene runs
the ``--warm`` frame first in the same process, then ``--frames`` in one `run_frames` call, which
builds the input shapes again (a run of every frame would have built them at its first frame).
cProfile's per-call overhead inflates Python-heavy functions; this split does not.
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

from acra import details as LD
from acra import hspline as H
from acra import respond as R
from pipeline import clearance
from pipeline import contact as C
from pipeline import detect as D
from pipeline import display
from pipeline import datapoints as P
from pipeline import frames as F
from pipeline import grids
from pipeline import residual
from pipeline import shape as S
from pipeline import tessellation as T
from pipeline import usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPENT: dict = collections.defaultdict(lambda: [0, 0.0])  # label -> [calls, seconds]


def _timed(label: str, f):
    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return f(*args, **kwargs)
        finally:
            SPENT[label][0] += 1
            SPENT[label][1] += time.perf_counter() - t
    return wrapper


def instrument() -> None:
    """Wrap the functions named in the table (module attributes, so internal calls are seen)."""
    for name in ("intersect", "regions", "touching", "cast", "project"):
        setattr(D, name, _timed(f"detect.{name}", getattr(D, name)))
    T.tessellate = _timed("tessellation.tessellate", T.tessellate)
    for name in ("rewind", "deepest_contact"):
        setattr(C, name, _timed(f"contact.{name}", getattr(C, name)))
    P.data_points_for = _timed("datapoints.data_points_for", P.data_points_for)
    display.grid_samples = _timed("display: tessellate.grid_samples", display.grid_samples)
    R.respond = _timed("respond.respond", R.respond)
    LD.details = _timed("details.details", LD.details)
    H.evaluate = _timed("hspline.evaluate", H.evaluate)
    for name in ("nearest", "cast"):
        setattr(S.Shape, name, _timed(f"Shape.{name}", getattr(S.Shape, name)))
    grids.GridCache.build = _timed("GridCache.build", grids.GridCache.build)
    grids.BvhCache.get = _timed("BvhCache.get (fcl BVHs asked for)", grids.BvhCache.get)
    grids._build = _timed("grids._build (fcl BVHs built)", grids._build)
    for name in ("hulls", "_coarse"):
        prop = getattr(S.Shape, name)
        prop.func = _timed(f"Shape.{name}", prop.func)
    # the residual where the user looks: each round's (`_Run.visible`) and the run's display's
    # (`display.finish`), whose pairs both go through `residual.pair_depth`
    F._Run.visible = _timed("frames._Run.visible", F._Run.visible)
    display.finish = _timed("display.finish", display.finish)
    # `Displays.build` (which `of` calls, and the frame loop for a round's two displays at once)
    # where the checkout has it
    built = "build" if hasattr(display.Displays, "build") else "of"
    setattr(display.Displays, built, _timed("display.Displays.of", getattr(display.Displays, built)))
    residual.pair_depth = _timed("residual.pair_depth", residual.pair_depth)
    for name in ("solid", "triangle_depth", "_signed"):
        setattr(clearance, name, _timed(f"clearance.{name}", getattr(clearance, name)))


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
    SPENT.clear()
    t = time.perf_counter()
    _, stats = F.run_frames(stage, scene, list(range(a, b + 1)))
    per = 1e3 / len(stats)
    total = (time.perf_counter() - t) * per
    print(f"{args.scene.name}, frames {a}-{b}: {total:.1f} ms per frame, rounds {[s.iterations for s in stats]}\n")
    print("| function | calls | ms per frame | share |\n|---|---:|---:|---:|")
    for label, (calls, sec) in sorted(SPENT.items(), key=lambda kv: -kv[1][1]):
        print(f"| `{label}` | {calls} | {sec * per:.1f} | {100 * sec * per / total:.0f} % |")


if __name__ == "__main__":
    main()
