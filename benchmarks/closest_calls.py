"""Detection's closest-point searches of a run, replayed: what `acra.nearest.query` costs apart from the frame.

    python3 benchmarks/closest_calls.py [SCENE.py] [--frames 13:17] [--passes 40]

Runs the scene's ``--frames`` after a free frame (frame 5), keeping every `pipeline.grids.Closest`
query's index, points and bound (the regions' inside tests, the casts' origins, the projections),
then replays the compiled search on them ``--passes`` times (the indexes already built: the
search alone) and prints the CPU milliseconds a collision frame of the median and fastest pass
and a digest of every answer (distances, closest points, faces): two checkouts answer alike
when their digests agree. Run it with ``PYTHONPATH`` at each checkout, alternating, for a
comparison.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other, so
# the calls recorded come in one order and their digest is the same from run to run
# (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import numpy as np

from _replay import arguments, recorded, report, timed
from acra import nearest
from pipeline import grids


def main() -> None:
    args = arguments(__doc__.split("\n")[0])
    calls = recorded(args.scene, args.frames, grids.Closest, "query",
                     lambda index, points, bound=None: (index, np.array(points, np.float64).reshape(-1, 3),
                                                        None if bound is None else np.array(bound, np.float64)))
    # a collider's index answers deep points through fcl (`Closest.query`): only the compiled
    # search of the deformables' grids is replayed
    calls = [c for c in calls if c[0].bvh is None]
    answers, times = timed(lambda: [nearest.query(index.index, points, bound) for index, points, bound in calls], args.passes)
    report(args, f"{len(calls)} searches of {sum(len(p) for _, p, _ in calls)} points", times,
           (a for answer in answers for a in answer))


if __name__ == "__main__":
    main()
