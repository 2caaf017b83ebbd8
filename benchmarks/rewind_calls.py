"""The rewinding search to first touch of a run, replayed: what `pipeline.contact.rewind` costs apart from the frame.

    python3 benchmarks/rewind_calls.py [SCENE.py] [--frames 13:17] [--passes 40] [--nested]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every call of
`contact.rewind` (its input geometry at any time, the frame's time and the search's bounds), then
replays them ``--passes`` times in order, each pass with a fresh `contact.RewindCache` per pair and
without the geometries' kept world data, intersections and anchor points (the memo tables
``detect.worlds``, ``detect.answers`` and ``contact.at``), as the run's first frame in contact
meets them: the bisection's touch tests on new matrices and the anchor at the first touching
time. The shapes, their grids and grid sets stay built. Prints the CPU milliseconds a collision
frame of the median and fastest pass and a digest of every anchor (time, parameters, point): two
checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at each checkout,
alternating, for a comparison (this file runs on a checkout that lacks it). ``--nested`` then
replays ``--passes`` more times with the search's functions and compiled passes (`NESTED`)
wrapped in process-time clocks and prints each one's calls and CPU milliseconds a run (nested:
a function's time holds its callees' and their wrappers').
"""

from __future__ import annotations

import sys
import time

import numpy as np

from _replay import arguments, recorded, report, timed
from acra import memo
from pipeline import contact

FRESH = ("detect.worlds", "detect.answers", "contact.at")  # what a new matrix finds computed in the run: nothing
# (module, name) timed by ``--nested``: the touch test and its narrow phase, the new geometry's
# world boxes and sizes (`pair_pad`, `apart`, the object-level box `_mapped_box`), the anchor and
# its parts, the compiled passes and the Python wrappers that call them (`patch_rows_near`,
# `face_boxes`, `triangles_near`, `crossings`)
NESTED = (("pipeline.detect", "touching"), ("pipeline.detect", "_intersect"), ("pipeline.detect", "pair_pad"),
          ("pipeline.detect", "apart"), ("pipeline.geometry", "_mapped_box"),
          ("pipeline.tessellation", "tessellate_sorted"), ("pipeline.contact", "_anchor_at"),
          ("pipeline.detect", "regions"), ("pipeline.detect", "project"), ("pipeline.detect", "_newton"),
          ("acra.narrow", "patch_rows_near"), ("acra.narrow", "face_boxes"), ("acra.narrow", "triangles_near"),
          ("acra.narrow", "crossings"), ("acra.narrow", "_patches_near"), ("acra.narrow", "_face_boxes"),
          ("acra.narrow", "_near"), ("acra.narrow", "_crossings"), ("pipeline.model", "_translated"))


def main() -> None:
    nested = "--nested" in sys.argv
    if nested:
        sys.argv.remove("--nested")
    args = arguments(__doc__.split("\n")[0])
    calls = recorded(args.scene, args.frames, contact, "rewind",
                     lambda geometry_at, t, start=None, cache=None, max_back=10_000, steps=12:
                     (geometry_at, t, start, id(cache), max_back, steps))
    rewind = contact.rewind

    def replay():
        tables = memo.current().tables
        for name in FRESH:
            tables.get(name, {}).clear()
        caches: dict = {}
        return [rewind(at, t, start, caches.setdefault(pair, contact.RewindCache()), back, steps)
                for at, t, start, pair, back, steps in calls]

    answers, times = timed(replay, args.passes)
    found = [a for a in answers if a is not None]
    report(args, f"{len(calls)} searches, {len(found)} anchors", times,
           (np.asarray(x, np.float64) for a in found for x in (a.t_contact, a.uv_a, a.uv_b, a.local_b, a.point)
            if x is not None))
    if nested:
        _nested(replay, args.passes)


def _nested(replay, passes: int) -> None:
    """Replay ``passes`` times with each of `NESTED` wrapped in a process-time clock; print each
    one's calls and CPU ms a run (a pass)."""
    import importlib

    spent: dict = {}
    for module, name in NESTED:
        owner = importlib.import_module(module)
        real = getattr(owner, name)

        def clocked(*a, real=real, key=f"{module}.{name}", **k):
            t = time.process_time_ns()
            try:
                return real(*a, **k)
            finally:
                n, ns = spent.get(key, (0, 0))
                spent[key] = (n + 1, ns + time.process_time_ns() - t)
        setattr(owner, name, clocked)
    timed(replay, passes)
    print("| function | calls a run | CPU ms a run |\n|---|---:|---:|")
    for key, (n, ns) in sorted(spent.items(), key=lambda kv: -kv[1][1]):
        print(f"| `{key}` | {n / (passes + 1):.1f} | {ns / 1e6 / (passes + 1):.3f} |")


if __name__ == "__main__":
    main()
