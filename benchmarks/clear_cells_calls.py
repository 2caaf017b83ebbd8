"""The residual's flooded grids of a run, replayed: what `acra.clearcells` costs apart from the frame.

    python3 benchmarks/clear_cells_calls.py [SCENE.py] [--frames 13:17] [--passes 30]

Runs the scene's ``--frames`` (after a free frame, as `residual_calls.py` does), keeping a copy of
every `acra.clearcells._clear_cells` call's arguments (`residual._clear_depth`'s grids: the
triangles proven clear of the other object and the part's rows near the others), then replays
them ``--passes`` times and prints the CPU milliseconds of the fastest pass and a digest of every
answer (the count of chosen rows or the refusal, the triangles kept, the rows chosen): two
checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at each checkout,
alternating, for a comparison.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import time

import numpy as np

from acra import clearcells
from pipeline import usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--passes", type=int, default=30)
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    calls = []
    real = clearcells._clear_cells

    def keep(*arrays):
        calls.append([x.copy() if isinstance(x, np.ndarray) and x.flags.writeable else x for x in arrays])
        return real(*arrays)

    clearcells._clear_cells = keep
    F.run_frames(stage, scene, list(range(a, b + 1)))
    clearcells._clear_cells = real
    best, h = np.inf, hashlib.sha1()
    for n in range(args.passes):
        t0 = time.process_time()
        got = [real(*args_) for args_ in calls]  # each call writes its ``keep`` and ``chosen`` in place
        best = min(best, time.process_time() - t0)
        if n == 0:
            for m, args_ in zip(got, calls):
                h.update(np.int64(m).tobytes() + args_[-2].tobytes() + args_[-1][:max(m, 0)].tobytes())
    print(f"{args.scene.name}, frames {a}-{b}: {len(calls)} _clear_cells calls, fastest of {args.passes} passes "
          f"{1e3 * best:.3f} ms CPU; answers {h.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
