"""The residual's pairs of a run, replayed: what `residual.pair_depth` costs apart from the frame.

    python3 benchmarks/residual_calls.py [SCENE.py] [--frames 13:17] [--passes 7]

Runs the scene's ``--frames`` (after a free frame, as `stage_split.py` does), keeping every
`residual.pair_depth` call's arguments (the frame loop's rounds and the run's display), then
replays them ``--passes`` times, each pass with empty part caches (every part solid built again,
as the first query of a display builds it) and one fresh copy of each recorded `Shown`, shared by
its calls as the run shares it (what it keeps: fingerprint, boxes, face chunks), and prints the CPU milliseconds of the fastest pass,
its split (closest-point searches, part solids, eq. (6), eq. (3), the triangles near a box, the
boxes of points `acra.bvh.bounds` takes as a module's attribute; where
the branch and bound is one compiled call, `acra.depthbound.depth`, its searches and eq. (6) are inside it) and a digest of every answer (depths,
completeness, the points, parameters and depths found inside): two checkouts answer alike when
their digests agree. Run it with ``PYTHONPATH`` at each checkout, alternating, for a comparison.
A call's ``stop`` (the first round's pairs detection found, searched only until a point deeper
than the tolerance: `residual.measure_frame`'s ``settle``) is kept and replayed with it; a
checkout whose frame loop makes such calls makes fewer calls, and its digest differs from one
whose loop measures every pair in full. The calls with a stop are also given apart: their whole
time, and their compiled search's.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import collections
import dataclasses
import hashlib
import pathlib
import time

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline import clearance, residual, usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPENT: dict = collections.defaultdict(float)
DEPTH = "the branch and bound, compiled (depth)"
WITH_STOP = "of all, the calls with a stop"  # not part of the split: the calls' whole time
WITH_STOP_DEPTH = "of those, the branch and bound"


def _timed(label: str, f):
    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            SPENT[label] += time.process_time() - t
    return wrapper


def _fresh(s, parts: dict, made: dict):
    """``s`` with empty part caches, one per display (``parts``: by the recorded cache's id),
    and so the display it may take parts from (``like``, where a checkout has it); one fresh
    object per recorded one (``made``: by its id), so the calls of a pass share them as the run did."""
    if id(s) in made:
        return made[id(s)][1]
    like = getattr(s, "like", None)
    more = {} if like is None else {"like": _fresh(like, parts, made)}
    out = dataclasses.replace(s, parts=None if s.parts is None else parts.setdefault(id(s.parts), {}), **more)
    made[id(s)] = (s, out)
    return out


def _kernel_modules() -> list:
    """`acra.meshrows`, `acra.depthbound` (where this checkout has them) and `acra.bvh`."""
    import importlib

    out = []
    for name in ("meshrows", "depthbound", "bvh"):
        try:
            out.append(importlib.import_module(f"acra.{name}"))
        except ImportError:
            continue
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--passes", type=int, default=7)
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    calls = []
    real = residual.pair_depth

    def keep(x, y, target, decide=np.inf, **more):  # ``stop`` where the checkout's frame loop gives one
        calls.append((x, y, target, decide, more))
        return real(x, y, target, decide, **more)

    residual.pair_depth = keep
    F.run_frames(stage, scene, list(range(a, b + 1)))
    residual.pair_depth = real
    # each kernel in the module that holds it in this checkout (`acra.meshrows` and
    # `acra.depthbound`, or `acra.bvh` in a checkout that keeps them there), where it has it
    for name, label in (("closest", "closest-point searches (closest)"),
                        ("facet_bound", "eq. (6) (facet_bound)"),
                        ("faces_meet", "triangles near a box (faces_meet)"),  # its mask form
                        ("face_chunks", "triangles near a box (faces_meet_rows)"),  # boxes of a display's faces in chunks
                        ("faces_meet_rows", "triangles near a box (faces_meet_rows)"),  # its form giving the rows
                        ("depth", DEPTH),  # in one compiled call
                        ("covering_radii", "covering radii (eq. (3))"),  # its compiled form
                        ("bounds", "boxes of points (bounds)")):  # `acra.bvh.bounds` as a module's attribute (`Shown.box_local`)
        for module in _kernel_modules():
            if hasattr(module, name):
                setattr(module, name, _timed(label, getattr(module, name)))
                break
    clearance.solid = _timed("part solids (clearance.solid)", clearance.solid)
    clearance.covering_radius = _timed("covering radii (eq. (3))", clearance.covering_radius)
    best, split, digest = np.inf, {}, None
    for _ in range(args.passes):
        with threadpool_limits(limits=1, user_api="blas"):  # as the frame loop runs
            parts: dict = {}  # a fresh cache per display, as a new display starts
            made: dict = {}  # id of a recorded `Shown` -> (it, its fresh copy)
            fresh = [tuple(_fresh(s, parts, made) for s in (x, y)) + (t, d, more) for x, y, t, d, more in calls]
            SPENT.clear()
            h = hashlib.sha1()
            t0 = time.process_time()
            for x, y, t, d, more in fresh:
                t1, inside = time.process_time(), SPENT.get(DEPTH, 0.0)
                ins = residual.pair_depth(x, y, t, d, **more)
                if more:  # a call with a stop: its whole time and its compiled search's
                    SPENT[WITH_STOP] += time.process_time() - t1
                    SPENT[WITH_STOP_DEPTH] += SPENT.get(DEPTH, 0.0) - inside
                h.update(np.float64([ins.depth, ins.lower, ins.complete]).tobytes())
                for arr in (ins.points, ins.uv, ins.deep):
                    if arr is not None:
                        h.update(np.ascontiguousarray(arr).tobytes())
            spent = time.process_time() - t0
            if spent < best:
                best, split, digest = spent, dict(SPENT), h.hexdigest()
    n = b - a + 1
    stopped = sum(bool(more) for *_, more in calls)
    print(f"{args.scene.name}, frames {a}-{b}: {len(calls)} pair_depth calls ({stopped} with a stop), fastest of {args.passes} passes "
          f"{1e3 * best:.1f} ms CPU ({1e3 * best / n:.2f} a frame); answers {digest}")
    for label, sec in sorted(split.items(), key=lambda kv: -kv[1]):
        print(f"  {label}: {1e3 * sec:.1f} ms")


if __name__ == "__main__":
    main()
