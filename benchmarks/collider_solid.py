"""What a run's first collision frame pays once for each rigid collider: its solid
(`pipeline.clearance.solid`, the pseudo-normals, convex facets and tree `ColliderStatic.solid`
builds) and its face planes (`geometry._convex_planes`), for every collider of the scenes.

    PYTHONPATH=$PWD python3 benchmarks/collider_solid.py [--repeat 200] [--base DIR]

Each collider is read from its scene and merged as a run merges it (`geometry.prepare_collider`);
its solid and planes are built ``--repeat`` times and timed in CPU time (``time.process_time``),
medians in µs. With ``--base DIR`` another checkout's `pipeline.clearance` (loaded from its file
under another module name) is timed in the same process, the two alternated call by call (the
planes of each solid by this checkout's `geometry._convex_planes`), and every array of the two
solids and their planes is compared: ``same`` where all are the same bits.
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import statistics
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
FIELDS = ("vertices", "faces", "normals", "edge_normals", "vertex_normals", "bounds", "facet", "facet_start",
          "facet_faces", "convex")


def _load(path: pathlib.Path, name: str):
    """The module in the file ``path`` under the name ``name``."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _same(a, b) -> bool:
    """Whether two solids hold the same bits in every field."""
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in FIELDS)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=200)
    ap.add_argument("--base", type=pathlib.Path)
    args = ap.parse_args()

    from pipeline import clearance, geometry, usdio

    impls = [("this checkout", clearance)]
    if args.base is not None:
        impls.append(("base", _load(args.base / "pipeline" / "clearance.py", "base_clearance")))
    meshes = {}
    for scene in sorted((ROOT / "scenes").glob("*.py")):
        if scene.name == "__init__.py":
            continue
        model = usdio.read_scene(usdio.open_input(usdio.load_scene_file(scene)))
        for c in model.colliders:
            static = geometry.prepare_collider(c)
            v, f = np.asarray(static.mesh.vertices, np.float64), np.asarray(static.mesh.faces, np.int64)
            meshes.setdefault((v.tobytes(), f.tobytes()), (f"{scene.stem}:{c.path}", v, f))
    head = " | ".join(f"{label} solid µs | planes µs" for label, _ in impls)
    print(f"| collider | faces | {head} |" + (" answers |" if len(impls) > 1 else ""))
    print("|---|---:|" + "---:|---:|" * len(impls) + ("---|" if len(impls) > 1 else ""))
    for name, v, f in meshes.values():
        times = [([], []) for _ in impls]
        for _ in range(args.repeat):
            for (label, C), (ts, tp) in zip(impls, times):
                t = time.process_time()
                s = C.solid(v, f)
                t1 = time.process_time()
                geometry._convex_planes(s)
                ts.append(time.process_time() - t)
                tp.append(time.process_time() - t1)
        cells = " | ".join(f"{1e6 * statistics.median(ts):.0f} | {1e6 * statistics.median(tp):.0f}" for ts, tp in times)
        answers = ""
        if len(impls) > 1:
            a, b = (C.solid(v, f) for _, C in impls)
            pa, pb = geometry._convex_planes(a), geometry._convex_planes(b)
            same = _same(a, b) and ((pa is None and pb is None) or (pa is not None and pb is not None and np.array_equal(pa, pb)))
            answers = f" {'same' if same else 'DIFFERENT'} |"
        print(f"| {name} | {len(f)} | {cells} |{answers}")


if __name__ == "__main__":
    main()
