"""The H-spline evaluations of a run's collision frames, replayed and timed.

    python3 benchmarks/evaluate_calls.py [SCENE.py] [--frames 13:17] [--repeat 5]

Runs the scene's ``--frames`` (after a free frame, as `benchmarks/stage_split.py` does) and
records every `acra.hspline.evaluate` call with its arguments, then calls `evaluate` again on each
recorded argument set ``--repeat`` times and prints, per kind of call (up to 1,000 points or more;
derivative order), the calls, the points and the median CPU milliseconds (``time.process_time``)
per collision frame, and a digest of every replayed call's output (the first 16 hex digits of a
SHA-256 over its arrays, call by call), so two checkouts can be shown to agree bit for bit. Run it
with ``PYTHONPATH`` set to two checkouts to compare their evaluators on the same calls (the calls
are the same when the two give the same surfaces). The frames' calls are many and small: the
fixed cost of a call matters there, the cost per point in the display-size ones.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import pathlib
import time

import numpy as np

from acra import hspline, tessellate
from pipeline import frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def record(scene: pathlib.Path, first: int, last: int, warm: int) -> list[tuple]:
    """The argument tuples ``(hs, u, v, order, det, upto, side)`` of every `evaluate` call of
    frames ``first..last`` (module attribute replaced, so calls inside `acra.hspline` count, and
    `acra.tessellate`'s name for it, so the displays' evaluations do)."""
    calls: list[tuple] = []
    evaluate = hspline.evaluate

    def recording(hs, u, v, order=0, det=None, upto=None, side=0):
        calls.append((hs, np.array(u, np.float64, copy=True), np.array(v, np.float64, copy=True), order, det, upto, side))
        return evaluate(hs, u, v, order, det, upto, side)

    stage = usdio.open_input(usdio.load_scene_file(scene))
    parsed = usdio.read_scene(stage)
    frames.run_frames(stage, parsed, [warm])
    hspline.evaluate = tessellate.evaluate = recording
    try:
        frames.run_frames(stage, parsed, list(range(first, last + 1)))
    finally:
        hspline.evaluate = tessellate.evaluate = evaluate
    return calls[:]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="collision frames START:END (default 13:17)")
    ap.add_argument("--warm", type=int, default=5, help="a free frame run first (default 5)")
    ap.add_argument("--repeat", type=int, default=5, help="replays to take the median over (default 5)")
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))
    calls = record(args.scene, first, last, args.warm)
    kinds = collections.defaultdict(list)
    for call in calls:
        kinds[(call[1].size > 1000, call[3])].append(call)
    frames_n = last - first + 1
    print(f"{args.scene.name}, frames {first}-{last}: {len(calls)} evaluate calls\n")
    print("| calls of | order | calls | points | CPU ms per frame (median of {}) |\n|---|---:|---:|---:|---:|".format(args.repeat))
    digest = hashlib.sha256()
    for call in calls:
        ev = hspline.evaluate(*call)
        for a in (ev.points, ev.du, ev.dv, ev.duu, ev.duv, ev.dvv):
            if a is not None:
                digest.update(np.ascontiguousarray(a).tobytes())
    for (large, order), group in sorted(kinds.items()):
        spent = []
        for _ in range(args.repeat):
            t = time.process_time()
            for call in group:
                hspline.evaluate(*call)
            spent.append(time.process_time() - t)
        points = sum(call[1].size for call in group)
        label = "more than 1,000 points" if large else "up to 1,000 points"
        print(f"| {label} | {order} | {len(group)} | {points} | {1e3 * float(np.median(spent)) / frames_n:.2f} |")
    print(f"\noutputs' digest: {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
