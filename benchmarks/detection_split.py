"""Detection and set-up of a collision frame in CPU time, stage by stage and function by function.

    PYTHONPATH=$PWD python3 benchmarks/detection_split.py [--repeat 3] [--wall] [--stages] [--per-frame]

Runs `dog_head_spike` frames 13-17 after frame 5 (``--repeat`` times, a fresh stage each time, so
every run builds the input shapes again) with the frame loop's clock read as the process's CPU
time (``time.process_time``): on a shared machine other processes' load then counts far less
than in wall-clock figures (``--wall`` keeps the wall clock). Prints the frame loop's own split
(`FrameStats`: set-up, detection, conversion, response, residual where the user looks; ms per
collision frame) and the nested time inside the detection functions (and the kept round's content
keys, `residual.known`), medians over the runs.
``--stages`` times no function (no wrapper's overhead) and prints each stage's median and range
over the runs (the sum of set-up, detection and conversion as ``three``), to two decimals: one
line to compare checkouts by (another checkout: this file with ``PYTHONPATH`` at it).
``--per-frame`` times no function either and prints each collision frame's set-up, detection and
conversion, medians over the runs: the first frame in contact builds the input shapes and rewinds
to the first touch, the later ones look both up.
"""

from __future__ import annotations

import argparse
import collections
import functools
import pathlib
import statistics
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--wall", action="store_true", help="wall-clock time instead of CPU time")
    ap.add_argument("--stages", action="store_true", help="the stages alone, median (range), two decimals")
    ap.add_argument("--per-frame", action="store_true", help="set-up, detection and conversion of each frame, medians")
    args = ap.parse_args()
    if not args.wall:
        time.perf_counter = time.process_time  # the frame loop's and the wrappers' clock

    from pipeline import contact as C
    from pipeline import detect as D
    from pipeline import frames as F
    from pipeline import grids, usdio
    from pipeline import queries as Q
    from pipeline import shape as S
    from pipeline import tessellation as T

    spent: dict = collections.defaultdict(lambda: [0, 0.0])

    def timed(label, f):
        @functools.wraps(f)
        def wrapper(*a, **k):
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                spent[label][0] += 1
                spent[label][1] += time.perf_counter() - t
        return wrapper

    if args.stages or args.per_frame:
        _stages(args.repeat, args.per_frame)
        return
    for name in ("intersect", "regions", "touching", "cast", "project", "_inside_rows", "_triangles_near", "_face_boxes"):
        setattr(D, name, timed(f"detect.{name}", getattr(D, name)))
    for name in ("tessellate", "tessellate_sorted", "vertices_in_box"):
        setattr(T, name, timed(f"tessellation.{name}", getattr(T, name)))
    for name in ("rewind", "deepest_contact", "detect_pair"):
        setattr(C, name, timed(f"contact.{name}", getattr(C, name)))
    for name in ("nearest", "signed", "cast"):
        setattr(Q, name, timed(f"queries.{name}", getattr(Q, name)))
    grids.GridCache.build = timed("GridCache.build", grids.GridCache.build)
    grids.GridCache.gridset = timed("GridCache.gridset", grids.GridCache.gridset)
    grids.GridSet.nearest = timed("GridSet.nearest", grids.GridSet.nearest)
    grids.Closest.query = timed("Closest.query", grids.Closest.query)
    grids.BvhCache.get = timed("BvhCache.get", grids.BvhCache.get)
    from acra import nearest  # a grid set's closest-point index, built at its first query (`grids.Closest.index`)

    nearest.index = timed("nearest.index", nearest.index)
    import fcl  # detect imports it where a pair needs its BVH; the patched name is the module's
    fcl.collide = timed("fcl.collide", fcl.collide)
    for name in ("hulls", "_coarse", "cv_hull", "_stale"):
        prop = getattr(S.Shape, name)
        prop.func = timed(f"Shape.{name}", prop.func)
    F._Run.detect = timed("frames._Run.detect", F._Run.detect)
    from pipeline import residual as R  # the end of a frame's content keys of its kept round (`residual.known`)

    R.known = timed("residual.known", R.known)

    stages = ("ms_setup", "ms_detect", "ms_convert", "ms_respond", "ms_visible", "ms_total")
    runs, splits = [], []
    from pipeline.run import forget

    for _ in range(args.repeat):
        # a repeat asks what the one before asked, on the same content: it must not be served
        # that run's answers (shapes, detection, casts, rims, ...), as a fresh run is not
        forget()
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        spent.clear()
        _, stats = F.respond_frames(stage, scene, list(range(13, 18)))
        hit = [s for s in stats if s.ms_respond > 0]
        runs.append({a: sum(getattr(s, a) for s in hit) / len(hit) for a in stages})
        splits.append({k: (n, 1e3 * s / len(hit)) for k, (n, s) in spent.items()})
    clock = "wall" if args.wall else "CPU"
    print(f"dog_head_spike frames 13-17, {clock} ms per collision frame, median of {args.repeat}\n")
    print("| stage (`FrameStats`) | ms |\n|---|---:|")
    for a in stages:
        print(f"| {a[3:]} | {statistics.median(r[a] for r in runs):.1f} |")
    print("\n| function | calls | ms |\n|---|---:|---:|")
    for k in sorted(splits[0], key=lambda k: -splits[0][k][1]):
        print(f"| `{k}` | {splits[0][k][0]} | {statistics.median(s.get(k, (0, 0.0))[1] for s in splits):.1f} |")


def _stages(repeat: int, per_frame: bool = False) -> None:
    """`main` with ``--stages``: each run's mean over the collision frames, median (range) over runs;
    with ``per_frame``, each collision frame's set-up, detection and conversion, medians over runs."""
    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    runs, frames = [], []
    for _ in range(repeat):
        forget()
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        _, stats = F.respond_frames(stage, scene, list(range(13, 18)))
        hit = [s for s in stats if s.ms_respond > 0]
        row = {a: sum(getattr(s, "ms_" + a) for s in hit) / len(hit) for a in ("setup", "detect", "convert", "respond", "visible", "total")}
        row["three"] = row["setup"] + row["detect"] + row["convert"]
        runs.append(row)
        frames.append([(s.frame, s.ms_setup, s.ms_detect, s.ms_convert) for s in hit])
    if per_frame:
        print("| frame | set-up | detection | conversion |\n|---:|---:|---:|---:|")
        for i, (frame, *_) in enumerate(frames[0]):
            cells = " | ".join(f"{statistics.median(run[i][j] for run in frames):.2f}" for j in (1, 2, 3))
            print(f"| {frame} | {cells} |")
        return
    print(" ".join(f"{k} {statistics.median(r[k] for r in runs):.2f} ({min(r[k] for r in runs):.2f}-{max(r[k] for r in runs):.2f})"
                   for k in ("setup", "detect", "convert", "three", "respond", "visible", "total")))


if __name__ == "__main__":
    main()
