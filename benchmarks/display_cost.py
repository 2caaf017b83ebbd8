"""What the display that shows every level costs, against the uniform grid it replaced.

    python3 benchmarks/display_cost.py [--repeat 3] [--samples 2 3 4 6]

For `scenes/dog_head_spike.py` and the same contact on the head refined to x16 level-0 CVs
(`benchmarks/scale_curve.py`'s stage), one run's responses (`frames.respond_frames`) are displayed
twice on the same surfaces: on the uniform grid of ``acra:samples`` steps per level-0 patch edge
(`acra.tessellate.display_topology`, the display before the adaptive one) and on the run's
adaptive topology (`pipeline.display`: ``acra:samples`` steps per edge of the finest patch present,
the union of every frame's refinement). Per display: vertices and faces of each deformable, the
display evaluation's milliseconds per frame (`display.evaluate_run`: each distinct surface
evaluated where it differs from the one before it), and writing the output layer per frame as
``.usda`` and ``.usdc`` (`output_layer.write_output`). Medians of ``--repeat`` passes, one process.

``--samples`` then runs the demo with every deformable's ``acra:samples`` set to each value in
turn (the whole run, `pipeline.run.run_file`): the run's display vertices, its largest residual,
the frame loop's and the output's seconds, the number the default is chosen from.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acra.basis import Direction  # noqa: E402
from acra.tessellate import display_topology  # noqa: E402
from pipeline import display, output_layer, usdio  # noqa: E402
from pipeline import frames as F  # noqa: E402


def uniform(scene) -> dict:
    """Per deformable path, the uniform grid of its ``acra:samples`` per level-0 patch edge."""
    return {m.path: display_topology(Direction(m.nu, m.u_periodic), Direction(m.nv, m.v_periodic), m.controls.samples)
            for m in scene.deformables}


def measure(stage_path: Path, tmp: Path, repeat: int) -> list[tuple]:
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    frames = list(range(scene.start, scene.end + 1))
    result, _ = F.respond_frames(stage, scene, frames)
    rows = []
    for name, topologies in (("uniform grid (before)", uniform(scene)), ("adaptive (run's)", display.run_topologies(scene, result))):
        evaluate, writes = [], {"usda": [], "usdc": []}
        for _ in range(repeat):
            fresh = output_layer.FramesResult({f: {p: replace(r, points=None, normals=None) for p, r in per.items()}
                                               for f, per in result.frames.items()})
            t = time.perf_counter()
            display.evaluate_run(scene, fresh, topologies)
            evaluate.append(1e3 * (time.perf_counter() - t) / len(frames))
            for fmt in writes:
                t = time.perf_counter()
                output_layer.write_output(stage_path, tmp / f"out.{fmt}", scene, fresh)
                writes[fmt].append(1e3 * (time.perf_counter() - t) / len(frames))
        sizes = ", ".join(f"{m.path.rsplit('/', 1)[-1]} {topologies[m.path].u.size} / {len(topologies[m.path].counts)}"
                          for m in scene.deformables)
        rows.append((name, sizes, float(np.median(evaluate)), float(np.median(writes["usda"])), float(np.median(writes["usdc"]))))
    return rows


def by_samples(src: Path, tmp: Path, values: list[int]) -> None:
    """The demo with every deformable's ``acra:samples`` set to each of ``values``."""
    from pxr import Usd

    from pipeline.run import run_file

    print("\n| acra:samples | display vertices (run's) | largest residual | frames s | write s |")
    print("|---:|---|---:|---:|---:|")
    for n in values:
        stage = Usd.Stage.Open(str(src))
        for prim in stage.Traverse():
            if prim.HasAttribute("acra:samples"):
                prim.GetAttribute("acra:samples").Set(int(n))
        path = tmp / f"demo_s{n}.usda"
        stage.GetRootLayer().Export(str(path))
        report = run_file(path, output=tmp / f"demo_s{n}.acra.usda")
        verts = ", ".join(f"{m.path.rsplit('/', 1)[-1]} {report.result.topology(m).u.size}" for m in report.scene.deformables)
        worst = max(s.residual_rel for s in report.stats)
        print(f"| {n} | {verts} | {worst:.2e} | {report.phases['frames']:.2f} | {report.phases['write']:.2f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--samples", type=int, nargs="*", default=[])
    args = parser.parse_args()
    from benchmarks.scale_curve import build_stage, head_grids
    from pipeline import authoring

    print(f"`python3 benchmarks/display_cost.py --repeat {args.repeat}` (medians; ms per frame over the scene's frames)\n")
    print("| stage | display | vertices / faces | evaluation ms | write .usda ms | write .usdc ms |")
    print("|---|---|---|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copy(ROOT / "scenes" / "dog_head_spike.py", tmp / "dog_head_spike.py")
        stages = [("dog_head_spike", usdio.load_scene_file(tmp / "dog_head_spike.py"))]
        x16 = authoring.save(build_stage(2, head_grids()[2]), tmp / "x16.usda")
        stages.append(("head x16 (scale_curve)", x16))
        for label, path in stages:
            for name, sizes, ev, usda, usdc in measure(path, tmp, args.repeat):
                print(f"| {label} | {name} | {sizes} | {ev:.2f} | {usda:.2f} | {usdc:.2f} |", flush=True)
        if args.samples:
            by_samples(stages[0][1], tmp, args.samples)


if __name__ == "__main__":
    main()
