"""Detection's inside tests on deformables of a run, replayed: what `pipeline.queries.signed` costs apart from the frame.

    python3 benchmarks/signed_calls.py [SCENE.py] [--frames 13:17] [--passes 40]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every inside test's shape and
object-space points (`Shape.signed`: the regions' vertices, the casts' origins), then replays
them ``--passes`` times, the shapes' grid sets and indexes already built (the candidate filter,
the closest-point search, the normals and the side test, and the Python between them), and
prints the CPU milliseconds a collision frame of the median and fastest pass and a digest of
every answer (inside flags, distances, closest points, parameters; a call asking for the inside
flags alone gives its flags): two checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at each checkout, alternating, for a
comparison (this file runs on a checkout that lacks it).
"""

from __future__ import annotations

import numpy as np

from _replay import arguments, recorded, report, timed
from pipeline import queries


def _kept(shape, q, nearest=True):
    """A call's shape, points and whether it asks for the nearest points (an inside test alone,
    as a cast's origins ask, does not)."""
    return shape, np.array(q, np.float64).reshape(-1, 3), bool(nearest)


def main() -> None:
    args = arguments(__doc__.split("\n")[0])
    # `Shape.signed` reads `queries.signed` from the module at each call
    calls = recorded(args.scene, args.frames, queries, "signed", _kept)
    signed = queries.signed
    # a call asking for the nearest points passes no flag, so a checkout without it replays too
    answers, times = timed(lambda: [signed(shape, q) if nearest else signed(shape, q, False) for shape, q, nearest in calls],
                           args.passes)
    report(args, f"{len(calls)} inside tests of {sum(len(q) for _, q, _ in calls)} points "
                 f"({sum(not n for _, _, n in calls)} without the nearest points)", times,
           (a for inside, near in answers for a in ((inside,) if near is None else (inside, near.distance, near.points, near.uv))))

if __name__ == "__main__":
    main()
