"""Cost of state across frames, and volume drift with and without preservation.

    python benchmarks/state_cost.py               # the tables in docs/performance.md
    python benchmarks/state_cost.py --repeat 5

1. ``scenes/soft_ball.py`` as authored (the dent carried and released over frames 5-12) against
   the same stage with ``acra:relax`` removed (stateless: the ball is the animator's at every free
   frame): per-frame milliseconds (``FrameStats.ms_total``), medians over the free frames 5-12 of
   ``--repeat`` cold runs, and their ratio. A free frame while relaxing builds the started surface
   (`acra.relax.begin`), detects on it (no shape data to reuse) and tessellates it for display; a
   stateless free frame reuses all three. The same for ``scenes/clay.py`` against the stage without
   ``acra:plasticity``/``acra:relax``, free frames 6-8 (the dents kept, nothing left to release).
2. ``scenes/balloon.py``: the display volume over the animator's at every frame, for the balloon
   (``acra:preserveVolume = 1``) and the same press without it; ``scenes/drum.py``: the same for
   the display area of an open sheet.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from pxr import Usd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from acra import volume  # noqa: E402
from acra.tessellate import evaluate_grid  # noqa: E402
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


def cost(tmp: Path, repeat: int, name: str = "soft_ball", first_free: int = 5) -> None:
    stateful = exported(name, tmp)
    stateless = tmp / f"{name}_stateless.usda"
    shutil.copy(stateful, stateless)  # edited as a copy: the stateful layer must stay as on disk
    stage = Usd.Stage.Open(str(stateless))
    for prim in stage.Traverse():
        for attr in ("acra:relax", "acra:plasticity"):
            prim.RemoveProperty(attr)
    stage.GetRootLayer().Save()
    assert not any(m.controls.stateful for m in usdio.read_scene(usdio.open_input(stateless)).deformables)
    assert all(m.controls.stateful for m in usdio.read_scene(usdio.open_input(stateful)).deformables)
    a, b = timings(stateful, repeat), timings(stateless, repeat)
    free = [f for f in a if f >= first_free]
    print(f"\n{name}, ms per frame (median of {repeat} runs)")
    print("| frame | carrying state | stateless | ratio |")
    print("|---:|---:|---:|---:|")
    for f in sorted(a):
        print(f"| {f} | {a[f]:.1f} | {b[f]:.1f} | {a[f] / b[f]:.2f} |")
    ma, mb = np.median([a[f] for f in free]), np.median([b[f] for f in free])
    print(f"| free frames {free[0]}-{free[-1]}, median | {ma:.1f} | {mb:.1f} | {ma / mb:.2f} |")


def parts(tmp: Path, repeat: int = 200) -> None:
    """What a relaxing free frame adds, timed alone (least of ``repeat`` calls, so other load on
    the machine does not count): `acra.relax.begin` and `acra.relax.absorb` on the soft ball's
    state carried out of frame 4, and the display tessellation of the started surface (a
    stateless free frame reuses the animator's)."""
    import time

    from acra import relax

    path = exported("soft_ball", tmp)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, _ = F.run_frames(stage, scene, [1, 2, 3, 4])
    model = scene.deformables[0]
    carried = result.frames[4][model.path].carried
    animator = usdio.state_at(stage, scene, 5.0)[0][0].surface
    rates, p = model.controls.relax_at(5.0), np.zeros(animator.depth)

    def least(fn) -> float:
        best = np.inf
        for _ in range(repeat):
            t = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t)
        return 1e3 * best

    started, released = relax.begin(animator, carried, rates)
    rows = [("relax.begin", least(lambda: relax.begin(animator, carried, rates))),
            ("relax.absorb (no response)", least(lambda: relax.absorb(released, started, started, p))),
            ("display tessellation of the started surface", least(lambda: evaluate_grid(started, model.topology)))]
    print(f"\nsoft_ball, a relaxing free frame's extra work (least of {repeat} calls, ms)")
    print("| part | ms |")
    print("|---|---:|")
    for name, ms in rows:
        print(f"| {name} | {ms:.3f} |")


def drift(tmp: Path, name: str = "balloon", measure: str = "volume") -> None:
    path = exported(name, tmp)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, list(range(scene.start, scene.end + 1)))
    print(f"\n{name}, display {measure} / the animator's")
    names = [m.path for m in scene.deformables]
    print("| frame | in collision | " + " | ".join(names) + " |")
    print("|---:|:---:|" + "---:|" * len(names))
    for s in stats:
        row = []
        for m in scene.deformables:
            topo = result.topology(m)  # the run's display; the animator's surface on it, as a USD client compares
            tris = volume.triangles(topo)
            rest = evaluate_grid(usdio.state_at(stage, scene, float(s.frame))[0][scene.deformables.index(m)].surface, topo)[0]
            size = volume.MEASURES[measure][0]
            row.append(size(result.frames[s.frame][m.path].points, tris) / size(rest, tris))
        print(f"| {s.frame} | {'yes' if s.in_collision else ''} | " + " | ".join(f"{r:.5f}" for r in row) + " |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        cost(Path(d), args.repeat)
        cost(Path(d), args.repeat, "clay", 6)
        parts(Path(d))
        drift(Path(d))
        drift(Path(d), "drum", "area")
    return 0


if __name__ == "__main__":
    sys.exit(main())
