"""Small valid scenes at exact alignments, run end to end: does every one finish, and where does
it stay over the tolerance?

    PYTHONPATH=$PWD python3 benchmarks/small_scenes.py [--sheets N] [--closed N] [--seed S]

Two families, each case a 5-frame stage whose mover is keyed from clear above at frame 1 to its
lowest at frame 3 and held there (frames 4-5 hold frame 3):

* **sheets**: an open ``n`` x ``n``-CV sheet 2 units wide (``n`` 4, 5 or 7; 1 or 2 levels, all
  absorption on the finest) under a unit box whose bottom ends ``low`` - 0.5 from the sheet's
  rest height (``low`` 0, 0.05, 0.5 or 0.6: 0.5 touches a still sheet exactly, 0.6 stays
  clear), at the centre, a corner or off centre, turned 0 or 45 degrees about z; the sheet's CVs
  still or keyed to rise 0.05 by frame 3.
* **closed**: a sphere, torus or tube (8 x 8 or 12 x 8 CVs, 1 or 2 levels) pressed from above by
  a unit box, a 0.4-radius collider ball or a soft 0.4-radius sphere, 0, 0.02 or 0.3 below the
  top of its CVs, tilted 0 or 30 degrees, centred or 0.2/0.1 off.

Each case runs `pipeline.frames.run_frames` over frames 1-5 and prints its largest reported
residual (`FrameStats.residual_rel`, the display's certified bound) and its holds; a case that
raises prints the exception's last frames. ``--sheets`` and ``--closed`` take that many cases of
each family in a seeded shuffled order (all: 288 and 108). Ends with the counts: finished,
raised, over 1e-3.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
import traceback
from pathlib import Path

import numpy as np


def sheet_case(path: Path, n, levels, low, keyed, xy, turn) -> Path:
    from acra import shapes
    from pipeline import authoring as A

    stage = A.new_stage(1, 5, fps=24, up_axis="Z")
    cvs, _, _ = shapes.sheet(n, n, width=2.0, depth=2.0)
    prim = A.add_deformable(stage, "/World/Sheet", cvs, levels=levels, samples=2, absorption=[0.0] * (levels - 1) + [1.0])
    if keyed:
        A.key_cvs(prim, 1, cvs)
        A.key_cvs(prim, 3, cvs + np.array([0.0, 0.0, 0.05]))
    mover = A.add_xform(stage, "/World/Mover")
    A.add_collider(stage, "/World/Mover/Box", *A.box(1.0))
    A.key_transform(mover, 1, translate=(xy[0], xy[1], 1.0), rotate_xyz=(0, 0, 0))
    A.key_transform(mover, 3, translate=(xy[0], xy[1], low), rotate_xyz=(0, 0, turn))
    return A.save(stage, path)


def closed_case(path: Path, shape, levels, other, depth, tilt, xy) -> Path:
    from pipeline import authoring as A

    stage = A.new_stage(1, 5, fps=24, up_axis="Z")
    surface = {"sphere": lambda: A.sphere(8, 8, levels=levels), "torus": lambda: A.torus(12, 8, levels=levels),
               "tube": lambda: A.tube(8, 8, levels=levels)}[shape]()
    A.add_surface(stage, "/World/Soft", surface, absorption=[0.0] * (levels - 1) + [1.0], samples=2)
    top = float(surface.cvs[..., 2].max())
    mover = A.add_xform(stage, "/World/Mover")
    if other == "box":
        A.add_collider(stage, "/World/Mover/Box", *A.box(1.0))
        half = 0.5
    elif other == "ball":
        A.add_collider(stage, "/World/Mover/Ball", *A.uv_sphere(0.4, 24, 12))
        half = 0.4
    else:
        A.add_surface(stage, "/World/Mover/Other", A.sphere(8, 8, radii=(0.4, 0.4, 0.4), levels=1), absorption=[1.0],
                      samples=2, rigidity=10)
        half = 0.4
    A.key_transform(mover, 1, translate=(xy[0], xy[1], top + half + 0.5), rotate_xyz=(0, 0, 0))
    A.key_transform(mover, 3, translate=(xy[0], xy[1], top + half - depth), rotate_xyz=(tilt, 0, 0))
    return A.save(stage, path)


def run_case(path: Path) -> tuple[float, int]:
    """The largest reported residual of frames 1-5 and how many of them are holds."""
    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    forget()
    stage = usdio.open_input(path)
    _, stats = F.run_frames(stage, usdio.read_scene(stage), [1, 2, 3, 4, 5])
    return max(s.residual_rel for s in stats), sum(s.hold for s in stats)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sheets", type=int, default=100)
    ap.add_argument("--closed", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    sheets = list(itertools.product([4, 5, 7], [1, 2], [0.0, 0.05, 0.5, 0.6], [False, True],
                                    [(0.0, 0.0), (1.0, 1.0), (0.3, -0.2)], [0.0, 45.0]))
    closed = list(itertools.product(["sphere", "torus", "tube"], [1, 2], ["box", "ball", "deformable"],
                                    [0.0, 0.02, 0.3], [0.0, 30.0], [(0.0, 0.0), (0.2, 0.1)]))
    rng.shuffle(sheets)
    rng.shuffle(closed)
    cases = [("sheet", c, sheet_case) for c in sheets[:args.sheets]] + [("closed", c, closed_case) for c in closed[:args.closed]]
    raised, over = 0, 0
    print("| family | case | largest residual | holds |\n|---|---|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (family, case, make) in enumerate(cases):
            try:
                worst, holds = run_case(make(Path(tmp) / f"case{k}.usda", *case))
            except Exception as exc:  # a valid scene must never raise: report it and go on
                raised += 1
                print(f"| {family} | {case} | raised {type(exc).__name__}: {' '.join(str(exc).split())[:120]} | |")
                traceback.print_exc(limit=-4)
                continue
            over += not worst <= 1e-3
            print(f"| {family} | {case} | {worst:.2e}{' over' if not worst <= 1e-3 else ''} | {holds} |", flush=True)
    print(f"\n{len(cases)} cases: {len(cases) - raised} finished, {raised} raised, {over} over 1e-3")


if __name__ == "__main__":
    main()
