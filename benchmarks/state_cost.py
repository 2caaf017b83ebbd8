"""Cost of state across frames, and volume drift with and without preservation.

    python benchmarks/state_cost.py               # the tables in docs/performance.md
    python benchmarks/state_cost.py --repeat 5

1. ``scenes/soft_ball.py`` as authored (the dent carried and released over frames 5-12) against
   the same stage with ``acra:relax`` removed (stateless: the ball is the animator's at every free
   frame): per-frame milliseconds (``FrameStats.ms_total``), medians over the free frames 5-12 of
   ``--repeat`` cold runs, and their ratio. A free frame while relaxing builds the started surface
   (`acra.relax.begin`), detects on it (no shape data to reuse) and tessellates it for display; a
   stateless free frame reuses all three.
2. ``scenes/balloon.py``: the display volume over the animator's at every frame, for the balloon
   (``acra:preserveVolume = 1``) and the same press without it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from acra import volume  # noqa: E402
from pipeline import frames as F  # noqa: E402
from pipeline import usdio  # noqa: E402

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def exported(name: str, tmp: Path) -> Path:
    shutil.copy(SCENES / f"{name}.py", tmp / f"{name}.py")
    return usdio.load_scene_file(tmp / f"{name}.py")


def timings(path: Path, repeat: int) -> dict[int, float]:
    """Median ``ms_total`` per frame over ``repeat`` runs, each on a freshly read stage."""
    runs = []
    for _ in range(repeat):
        stage = usdio.open_input(path)
        scene = usdio.read_scene(stage)
        _, stats = F.run_frames(stage, scene, list(range(scene.start, scene.end + 1)))
        runs.append({s.frame: s.ms_total for s in stats})
    return {f: float(np.median([r[f] for r in runs])) for f in runs[0]}


def cost(tmp: Path, repeat: int) -> None:
    stateful = exported("soft_ball", tmp)
    stage = Usd.Stage.Open(str(stateful))
    stage.GetPrimAtPath("/World/Ball").RemoveProperty("acra:relax")
    stateless = tmp / "soft_ball_stateless.usda"
    stage.GetRootLayer().Export(str(stateless))
    a, b = timings(stateful, repeat), timings(stateless, repeat)
    free = [f for f in a if f >= 5]
    print(f"\nsoft_ball, ms per frame (median of {repeat} runs)")
    print("| frame | carrying state | stateless | ratio |")
    print("|---:|---:|---:|---:|")
    for f in sorted(a):
        print(f"| {f} | {a[f]:.1f} | {b[f]:.1f} | {a[f] / b[f]:.2f} |")
    ma, mb = np.median([a[f] for f in free]), np.median([b[f] for f in free])
    print(f"| free frames 5-12, median | {ma:.1f} | {mb:.1f} | {ma / mb:.2f} |")


def drift(tmp: Path) -> None:
    path = exported("balloon", tmp)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, list(range(scene.start, scene.end + 1)))
    inp = Usd.Stage.Open(str(path))
    print("\nballoon, display volume / the animator's")
    names = [m.path for m in scene.deformables]
    print("| frame | in collision | " + " | ".join(names) + " |")
    print("|---:|:---:|" + "---:|" * len(names))
    for s in stats:
        row = []
        for m in scene.deformables:
            tris = volume.triangles(m.topology)
            rest = np.asarray(UsdGeom.Mesh(inp.GetPrimAtPath(m.path)).GetPointsAttr().Get(), dtype=np.float64)
            row.append(volume.enclosed_volume(result.frames[s.frame][m.path].points, tris) / volume.enclosed_volume(rest, tris))
        print(f"| {s.frame} | {'yes' if s.in_collision else ''} | " + " | ".join(f"{r:.5f}" for r in row) + " |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        cost(Path(d), args.repeat)
        drift(Path(d))
    return 0


if __name__ == "__main__":
    sys.exit(main())
