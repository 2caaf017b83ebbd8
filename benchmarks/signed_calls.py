"""Detection's inside tests on deformables of a run, replayed: what `pipeline.queries.signed` costs apart from the frame.

    python3 benchmarks/signed_calls.py [SCENE.py] [--frames 13:17] [--passes 40]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every inside test's shape and
object-space points (`Shape.signed`: the regions' vertices, the casts' origins), then replays
them ``--passes`` times, the shapes' grid sets and indexes already built (the candidate filter,
the closest-point search, the normals and the side test, and the Python between them), and
prints the CPU milliseconds a collision frame of the median and fastest pass and a digest of
every answer (inside flags, distances, closest points, parameters): two checkouts answer alike
when their digests agree. Run it with ``PYTHONPATH`` at each checkout, alternating, for a
comparison (this file runs on a checkout that lacks it).
"""

from __future__ import annotations

import numpy as np

from _replay import arguments, recorded, report, timed
from pipeline import queries


def main() -> None:
    args = arguments(__doc__.split("\n")[0])
    # `Shape.signed` reads `queries.signed` from the module at each call
    calls = recorded(args.scene, args.frames, queries, "signed", lambda shape, q: (shape, np.array(q, np.float64).reshape(-1, 3)))
    signed = queries.signed
    answers, times = timed(lambda: [signed(shape, q) for shape, q in calls], args.passes)
    report(args, f"{len(calls)} inside tests of {sum(len(q) for _, q in calls)} points", times,
           (a for inside, near in answers for a in (inside, near.distance, near.points, near.uv)))


if __name__ == "__main__":
    main()
