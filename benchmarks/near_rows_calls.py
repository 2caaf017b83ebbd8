"""The residual's faces near a box through a display's chunk boxes, replayed: what
`acra.meshrows.faces_meet_rows` with ``chunks`` costs apart from the frame.

    python3 benchmarks/near_rows_calls.py [SCENE.py] [--frames 13:17] [--passes 40]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every call of
`meshrows.faces_meet_rows` that passes a display's chunk boxes (`residual.Shown.near_rows`: the
inner display near the other object's box, the other display near the triangles' region), then
replays them ``--passes`` times with the chunk boxes already built, and prints the CPU
milliseconds a collision frame of the median and fastest pass and a digest of every answer (the
rows): two checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at each
checkout, alternating, for a comparison (this file runs on a checkout that lacks it).
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

from _replay import arguments, recorded, report, timed
from acra import meshrows


def main() -> None:
    args = arguments(__doc__.split("\n")[0])
    # `Shown.near_rows` reads `meshrows.faces_meet_rows` from the module at each call
    calls = recorded(args.scene, args.frames, meshrows, "faces_meet_rows", lambda *a, **k: (a, k))
    calls = [(a, k) for a, k in calls if (a[5] if len(a) > 5 else k.get("chunks")) is not None]
    near = meshrows.faces_meet_rows
    answers, times = timed(lambda: [near(*a, **k) for a, k in calls], args.passes)
    report(args, f"{len(calls)} calls through chunk boxes, {sum(len(a[1]) for a, _ in calls)} faces", times, answers)


if __name__ == "__main__":
    main()
