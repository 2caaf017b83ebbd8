"""How the spacing of additional points (`pipeline.datapoints.spread`) changes a scene's residuals.

    python3 benchmarks/spread_radius.py [SCENE.py] [--frames 13:17] [--factors 0,0.25,0.5,1,2,4]

Runs the frames once per factor, with additional points kept at least ``factor × MEET`` of the
deformable's size apart (0: no thinning), and prints per factor the wall-clock time and, per
frame, the rounds and the residual as a fraction of the size. Default: `dog_head_spike`, whose
spike tip is a pole where patch midpoints crowd (docs/algorithm.md, eq. 4.16 spacing).
"""

from __future__ import annotations

import argparse
import pathlib
import time

from pipeline import datapoints as P
from pipeline import frames as F
from pipeline import usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run(scene_file: pathlib.Path, frames: list[int], factor: float) -> tuple[float, list]:
    """Seconds and ``(frame, rounds, residual_rel)`` per frame with the spacing scaled by ``factor``."""
    spread = P.spread
    P.spread = lambda points, contact, radius: spread(points, contact, radius * factor)
    try:
        stage = usdio.open_input(usdio.load_scene_file(scene_file))
        scene = usdio.read_scene(stage)
        t = time.perf_counter()
        _, stats = F.run_frames(stage, scene, frames, F.RunOptions())
        return time.perf_counter() - t, [(s.frame, s.iterations, s.residual_rel) for s in stats]
    finally:
        P.spread = spread


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17", help="first:last, inclusive")
    ap.add_argument("--factors", default="0,0.25,0.5,1,2,4")
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    print("| spacing (× MEET) | seconds | " + " | ".join(f"frame {f}" for f in range(a, b + 1)) + " | worst |")
    print("|---:|---:|" + "---:|" * (b - a + 2))
    for factor in (float(x) for x in args.factors.split(",")):
        secs, stats = run(pathlib.Path(args.scene), list(range(a, b + 1)), factor)
        cells = " | ".join(f"{r:.2e} ({n})" for _, n, r in stats)
        print(f"| {factor:g} | {secs:.2f} | {cells} | {max(r for _, _, r in stats):.2e} |")


if __name__ == "__main__":
    main()
