"""What two threads could take off detection's regions at most, from CPU time alone.

    PYTHONPATH=$PWD python3 benchmarks/regions_bound.py [SCENE.py] [--frames 13:17] [--passes 7]

Runs the scene's ``--frames`` after frame 5 on one thread (``NUMBA_NUM_THREADS`` set to 1 for the
run), ``--passes`` cold runs after a first (`pipeline.run.forget` and a fresh stage each), and
times, in every `detect.regions` call of two deformables, each side whole (`detect._region_of`:
its candidate vertices, its inside test and its depths) and its inside test (`queries.signed`:
the candidate filter, the grid set of the candidate patches, built where new, its closest
points and the side pass), each whole (``a``, ``b``) and inside the compiled kernels it calls
from Python (``ka``, ``kb``: every numba dispatcher of an ``acra`` module, timed where a
module's Python calls it by its module attribute; numpy's loops count as holding the GIL). Two
threads sharing one GIL take at least ``max(a, b, (a - ka) + (b - kb))`` of wall time for a
pair, against ``a + b`` on one: the difference is the bound (as `benchmarks/second_core.py
--bound` for the residual's pairs). Prints the fastest pass's sums, CPU ms a collision frame,
for the sides and for their inside tests. CPU time, so a loaded machine gives it too.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17")
    ap.add_argument("--passes", type=int, default=7)
    args = ap.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = "1"  # read at numba's import, below
    from _replay import kernels_clocked
    from threadpoolctl import threadpool_limits

    from pipeline import detect as D
    from pipeline import frames as F
    from pipeline import queries, usdio
    from pipeline.run import forget

    inside = [0.0]
    kernels_clocked(inside)
    searches, wholes, calls = [], [], []

    def clocked(real, out):
        def call(*a, **k):
            k0, t0 = inside[0], time.process_time()
            try:
                return real(*a, **k)
            finally:
                out.append((time.process_time() - t0, inside[0] - k0))
        return call

    queries.signed = clocked(queries.signed, searches)
    D._region_of = clocked(D._region_of, wholes)
    real_regions = D.regions

    def regions(ga, gb, *a, **k):
        s, w = len(searches), len(wholes)
        out = real_regions(ga, gb, *a, **k)
        if isinstance(gb, D.SurfaceGeometry):
            calls.append((searches[s:], wholes[w:]))
        return out

    D.regions = regions
    first, last = (int(x) for x in args.frames.split(":"))
    frames = list(range(first, last + 1))
    best = None
    with threadpool_limits(limits=1, user_api="blas"):
        for n in range(args.passes + 1):
            forget()
            stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
            scene = usdio.read_scene(stage)
            F.run_frames(stage, scene, [5])
            calls.clear()
            F.respond_frames(stage, scene, frames)
            pairs = [(s, w) for s, w in calls if len(s) == 2 and len(w) == 2]
            sums = [_sums([p[0] for p in pairs]), _sums([p[1] for p in pairs])]
            if n and (best is None or sums[1][0] < best[1][0]):  # the first pass loads the kernels
                best = sums
    for name, (seq, least, kern) in zip(("their inside tests", "the sides whole"), best):
        print(f"{name}: {seq / len(frames) * 1e3:.3f} ms CPU a collision frame on one thread, in kernels "
              f"{kern / len(frames) * 1e3:.3f}; two threads at least {least / len(frames) * 1e3:.3f}: "
              f"bound {(seq - least) / len(frames) * 1e3:.3f}")
    print(f"({len(pairs)} regions calls of two deformables over {len(frames)} frames, fastest of {args.passes} passes)")


def _sums(pairs: list) -> tuple[float, float, float]:
    """One thread's CPU seconds of ``pairs`` (``((a, ka), (b, kb))`` each), the least wall time
    two threads sharing the GIL could take, and the CPU seconds inside the kernels."""
    return (sum(a[0] + b[0] for a, b in pairs), sum(max(a[0], b[0], (a[0] - a[1]) + (b[0] - b[1])) for a, b in pairs),
            sum(a[1] + b[1] for a, b in pairs))

if __name__ == "__main__":
    main()
