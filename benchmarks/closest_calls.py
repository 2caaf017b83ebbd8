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

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from acra import nearest
from pipeline import frames as F
from pipeline import grids, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17", help="first:last, inclusive")
    ap.add_argument("--passes", type=int, default=40)
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))
    frames = list(range(first, last + 1))

    calls = []
    query = grids.Closest.query

    def recorded(index, points, bound=None):
        calls.append((index, np.array(points, np.float64).reshape(-1, 3), None if bound is None else np.array(bound, np.float64)))
        return query(index, points, bound)

    with threadpool_limits(1):
        stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        grids.Closest.query = recorded
        try:
            F.run_frames(stage, scene, frames)
        finally:
            grids.Closest.query = query
        # a collider's index answers deep points through fcl (`Closest.query`): only the compiled
        # search of the deformables' grids is replayed
        calls = [c for c in calls if c[0].bvh is None]

        def replay():
            return [nearest.query(index.index, points, bound) for index, points, bound in calls]

        answers = replay()
        times = []
        for _ in range(args.passes):
            t = time.process_time()
            replay()
            times.append(time.process_time() - t)
    digest = hashlib.sha1()
    for dist, close, face in answers:
        for a in (dist, close, face):
            digest.update(np.ascontiguousarray(a).tobytes())
    ms = [1e3 * t / len(frames) for t in times]
    print(f"{pathlib.Path(args.scene).stem} frames {first}-{last}: {len(calls)} searches of {sum(len(p) for _, p, _ in calls)} points; "
          f"CPU ms a frame, median {statistics.median(ms):.3f}, fastest {min(ms):.3f} (of {args.passes} passes); "
          f"answers {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
