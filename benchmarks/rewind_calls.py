"""The rewinding search to first touch of a run, replayed: what `pipeline.contact.rewind` costs apart from the frame.

    python3 benchmarks/rewind_calls.py [SCENE.py] [--frames 13:17] [--passes 40]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every call of
`contact.rewind` (its input geometry at any time, the frame's time and the search's bounds), then
replays them ``--passes`` times in order, each pass with a fresh `contact.RewindCache` per pair and
without the geometries' kept world data, intersections and anchor points (the memo tables
``detect.worlds``, ``detect.answers`` and ``contact.at``), as the run's first frame in contact
meets them: the bisection's touch tests on new matrices and the anchor at the first touching
time. The shapes, their grids and grid sets stay built. Prints the CPU milliseconds a collision
frame of the median and fastest pass and a digest of every anchor (time, parameters, point): two
checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at each checkout,
alternating, for a comparison (this file runs on a checkout that lacks it).
"""

from __future__ import annotations

import numpy as np

from _replay import arguments, recorded, report, timed
from acra import memo
from pipeline import contact

FRESH = ("detect.worlds", "detect.answers", "contact.at")  # what a new matrix finds computed in the run: nothing


def main() -> None:
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


if __name__ == "__main__":
    main()
