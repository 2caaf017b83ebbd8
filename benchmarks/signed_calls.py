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

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline import frames as F
from pipeline import queries, usdio

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
    signed = queries.signed

    def recorded(shape, q):
        calls.append((shape, np.array(q, np.float64).reshape(-1, 3)))
        return signed(shape, q)

    with threadpool_limits(1):
        stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        queries.signed = recorded  # `Shape.signed` reads it from the module at each call
        try:
            F.run_frames(stage, scene, frames)
        finally:
            queries.signed = signed

        def replay():
            return [signed(shape, q) for shape, q in calls]

        answers = replay()
        times = []
        for _ in range(args.passes):
            t = time.process_time()
            replay()
            times.append(time.process_time() - t)
    digest = hashlib.sha1()
    for inside, near in answers:
        for a in (inside, near.distance, near.points, near.uv):
            digest.update(np.ascontiguousarray(a).tobytes())
    ms = [1e3 * t / len(frames) for t in times]
    print(f"{pathlib.Path(args.scene).stem} frames {first}-{last}: {len(calls)} inside tests of {sum(len(q) for _, q in calls)} points; "
          f"CPU ms a frame, median {statistics.median(ms):.3f}, fastest {min(ms):.3f} (of {args.passes} passes); "
          f"answers {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
