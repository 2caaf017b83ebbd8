"""Set-up of a collision frame in CPU time, builder by builder and the library calls inside them.

    PYTHONPATH=$PWD python3 benchmarks/setup_split.py [--repeat 3]

Runs `dog_head_spike` frames 13-17 after frame 5 (``--repeat`` times, a fresh stage each time)
and prints, per collision frame, the CPU ms (``time.process_time``) of each `pipeline.shape.Shape`
builder (nested: ``hulls`` holds ``_stale`` and ``cv_positions``), `GridCache.build`, and the
calls they make (`all_cv_positions`, `changed_patches`, `patch_boxes`, `coarse_points`,
`patch_grids`, scipy's ``ConvexHull`` and ``cKDTree``), medians over the runs.
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
    args = ap.parse_args()

    from pipeline import frames as F
    from pipeline import grids, usdio
    from pipeline import shape as S

    from acra import details as LD

    spent: dict = collections.defaultdict(lambda: [0, 0.0])

    def timed(label, f):
        @functools.wraps(f)
        def wrapper(*a, **k):
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                spent[label][0] += 1
                spent[label][1] += time.process_time() - t
        return wrapper

    # defined in `acra.details`; `S.H.all_cv_positions` (the `acra.hspline` re-export) looks it up there on each call
    LD.all_cv_positions = timed("all_cv_positions", LD.all_cv_positions)
    for name, label in (("changed_patches", "changed_patches"), ("patch_boxes", "patch_boxes"),
                        ("coarse_points", "coarse_points (Shape._coarse)"), ("ConvexHull", "ConvexHull"),
                        ("cKDTree", "cKDTree"), ("volume_sign_about_mean", "volume_sign_about_mean")):
        setattr(S, name, timed(label, getattr(S, name)))
    for name in ("hulls", "_coarse", "cv_hull", "_stale", "density_map", "details", "outward", "cv_positions"):
        prop = getattr(S.Shape, name)
        prop.func = timed(f"Shape.{name}", prop.func)
    grids.GridCache.build = timed("GridCache.build", grids.GridCache.build)
    grids.patch_grids = timed("patch_grids (GridCache.build)", grids.patch_grids)
    grids.solid_rows = timed("solid_rows", grids.solid_rows)

    runs = []
    for _ in range(args.repeat):
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        spent.clear()
        _, stats = F.respond_frames(stage, scene, list(range(13, 18)))
        n = sum(1 for s in stats if s.ms_respond > 0)
        runs.append({k: (c, 1e3 * s / n) for k, (c, s) in spent.items()})
    print(f"dog_head_spike frames 13-17, CPU ms per collision frame, median of {args.repeat}\n")
    print("| function | calls | ms |\n|---|---:|---:|")
    for k in sorted(runs[0], key=lambda k: -runs[0][k][1]):
        print(f"| `{k}` | {runs[0][k][0]} | {statistics.median(r.get(k, (0, 0.0))[1] for r in runs):.2f} |")


if __name__ == "__main__":
    main()
