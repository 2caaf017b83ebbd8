"""Conversion (regions to data points, thesis eq. 4.15-4.16) of a collision frame in CPU time, by part.

    PYTHONPATH=$PWD python3 benchmarks/convert_split.py [--repeat 6] [SCENE.py] [--frames 13:17]

Runs the scene's ``--frames`` after frame 5, ``--repeat`` times (each a cold run: a fresh stage
after `pipeline.run.forget`, as `benchmarks/detection_split.py` does), with the frame loop's clock
read as the process's CPU time (``time.process_time``), and prints the conversion's parts in
microseconds per collision frame, each the median over the repeats after the first (the first
also loads the compiled kernels): `pipeline.frames._Run.data_points` (the stage, as
``FrameStats.ms_convert`` counts it, less set-up), `datapoints.data_points_for` and, nested in it,
the region bookkeeping (`acra.targets.region_groups`; in a checkout without it,
`patch_groups` and `region_deepest`), the casts (`detect.cast`) with their inside
tests of the origins (`detect.inside`), their first hits (`detect._first_hits`), the ray meshes
(`queries._ray_mesh`) and the sure hits (`queries.RayMesh.first_hits`). A part's time includes
the parts nested in it and about a microsecond of its wrapper a call.

Prints a digest of every data point the first run's conversion hands to the response (parameters, targets,
starts, contact flags), so two checkouts can be shown to give the same answers.

``--again`` calls each cast (`detect._cast`) twice more with the same arguments right after it and
prints the casts' CPU time as the frame loop meets them against the second repeat's, in
microseconds per collision frame (medians over the runs after the first): what a cast costs with
its data and code in the caches, against what it costs between the frame's other stages. The
repeats answer as the first call (the kept meshes and grid sets are found again), but their time
counts in the other rows, which are then not the stage's.
"""

from __future__ import annotations

import argparse
import collections
import functools
import hashlib
import pathlib
import statistics
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--repeat", type=int, default=6)
    ap.add_argument("--frames", default="13:17")
    ap.add_argument("--again", action="store_true", help="each cast timed again at once, warm")
    args = ap.parse_args()
    time.perf_counter = time.process_time  # the frame loop's clock

    from pipeline import datapoints as P
    from pipeline import detect as D
    from pipeline import frames as F
    from pipeline import queries as Q
    from pipeline import usdio
    from pipeline.run import forget

    spent: dict = collections.defaultdict(float)
    calls: dict = collections.defaultdict(int)
    digest = hashlib.sha256()

    def timed(label, owner, name):
        f = getattr(owner, name)

        @functools.wraps(f)
        def wrapper(*a, **k):
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[label] += time.process_time() - t
                calls[label] += 1
        setattr(owner, name, wrapper)

    parts = [("data_points", F._Run, "data_points"), ("data_points_for", P, "data_points_for"),
             ("region_groups", P, "region_groups"), ("patch_groups", P, "patch_groups"),
             ("region_deepest", P, "region_deepest"), ("detect.cast", D, "cast"), ("detect.inside", D, "inside"),
             ("detect._first_hits", D, "_first_hits"), ("queries._ray_mesh", Q, "_ray_mesh"),
             ("RayMesh.first_hits", Q.RayMesh, "first_hits")]
    for label, owner, name in parts:
        if hasattr(owner, name):  # a checkout without a part leaves its row empty
            timed(label, owner, name)
    if args.again:
        cast = D._cast

        def twice(*a):
            t = time.process_time()
            out = cast(*a)
            spent["cast in the frame loop"] += time.process_time() - t
            cast(*a)
            t = time.process_time()
            cast(*a)
            spent["the same cast again"] += time.process_time() - t
            return out
        D._cast = twice
    points = F._Run.data_points

    def recorded(self, *a, **k):
        out = points(self, *a, **k)
        if runs:  # the first run's points: every run asks the same
            return out
        for i in sorted(out):
            for dp, world, start in out[i]:
                for arr in (dp.uv, dp.target, dp.is_contact, world, start):
                    digest.update(memoryview(np.ascontiguousarray(arr)).cast("B"))
        return out
    F._Run.data_points = recorded

    first, last = (int(x) for x in args.frames.split(":"))
    runs = []
    for rep in range(args.repeat):
        forget()
        stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        spent.clear()
        calls.clear()
        _, stats = F.respond_frames(stage, scene, list(range(first, last + 1)))
        hit = [s for s in stats if s.ms_respond > 0 and not s.hold]
        row = {k: 1e6 * v / len(hit) for k, v in spent.items()}
        row["ms_convert"] = 1e3 * sum(s.ms_convert for s in hit) / len(hit)
        row["calls"] = dict(calls)
        runs.append(row)
    keep = runs[1:] or runs
    print(f"{pathlib.Path(args.scene).stem} frames {first}-{last}, CPU us per collision frame, median of {len(keep)}"
          f" (range), calls of one run\n")
    print("| part | calls | us |\n|---|---:|---:|")
    extra = ["cast in the frame loop", "the same cast again"] if args.again else []
    for label in ["ms_convert"] + [p[0] for p in parts] + extra:
        vals = [r[label] for r in keep if label in r]
        if vals:
            n = keep[0]["calls"].get(label, "")
            print(f"| {label} | {n} | {statistics.median(vals):.1f} ({min(vals):.1f}-{max(vals):.1f}) |")
    print(f"\ndata points digest {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
