"""The merged meshes a run's casts build (`pipeline.queries._ray_mesh`), replayed: the faces' assembly in three forms, timed.

    PYTHONPATH=$PWD python3 benchmarks/ray_mesh_calls.py [SCENE.py] [--frames 13:17] [--repeat 300]

Runs the scene's ``--frames`` after frame 5 and records the patch set of every merged mesh a cast
builds, then times, in CPU time, on each recorded set (its grids taken from the shape):

* ``per grid``: each grid's solid triangles moved past the points before it, one grid at a time;
* ``gathered``: every grid's triangles concatenated, their solid rows gathered at once and moved
  by one repeated sum;
* ``shared``: `queries._grid_faces`, what `_ray_mesh` does: the triangle list grids built together
  share, moved by every grid's offset in one broadcast sum where no grid has a pole row's slivers;
  otherwise each grid's list, its solid rows gathered only where it drops slivers, joined and
  moved by one repeated sum;
* ``build``: `_ray_mesh` whole, with `RayMesh._prepare` (the float32 copy and the face groups'
  boxes), the mesh dropped from the shape before each call.

Prints the microseconds of each (median of ``--repeat`` calls) per recorded set, and a digest of
the faces: the three forms give the same faces.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _timed(f, repeat: int) -> float:
    runs = []
    for _ in range(repeat):
        t = time.process_time()
        f()
        runs.append(time.process_time() - t)
    return 1e6 * statistics.median(runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17")
    ap.add_argument("--repeat", type=int, default=300)
    args = ap.parse_args()

    from pipeline import frames as F
    from pipeline import queries as Q
    from pipeline import usdio
    from pipeline.run import forget

    built = []
    ray_mesh = Q._ray_mesh

    def recorded(shape, patches, hit):
        if hit.tobytes() not in shape.ray_meshes:
            built.append((shape, patches, hit.copy()))
        return ray_mesh(shape, patches, hit)
    Q._ray_mesh = recorded
    forget()
    stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    first, last = (int(x) for x in args.frames.split(":"))
    F.respond_frames(stage, scene, list(range(first, last + 1)))
    Q._ray_mesh = ray_mesh

    digest = hashlib.sha256()
    print("| patches | grids | faces | per grid us | gathered us | shared us | build us |\n|---:|---:|---:|---:|---:|---:|---:|")
    for shape, patches, hit in built:
        grids = shape.grids_for(patches[hit])

        def per_grid():
            base = np.cumsum([0] + [len(g.points) for g in grids[:-1]])
            return np.concatenate([g.triangles[g.solid] + b for g, b in zip(grids, base)])

        def gathered():
            solid = [g.solid for g in grids]
            kept = [len(r) for r in solid]
            before = np.cumsum([0] + [len(g.triangles) for g in grids[:-1]])
            base = np.cumsum([0] + [len(g.points) for g in grids[:-1]])
            rows = np.concatenate(solid) + np.repeat(before, kept)
            return np.concatenate([g.triangles for g in grids])[rows] + np.repeat(base, kept)[:, None]

        def shared():
            return Q._grid_faces(grids)

        def build():
            shape.ray_meshes.pop(hit.tobytes(), None)
            ray_mesh(shape, patches, hit)._prepare()

        want = per_grid()
        assert np.array_equal(gathered(), want) and np.array_equal(shared(), want)
        digest.update(want.tobytes())
        cells = [_timed(per_grid, args.repeat), _timed(gathered, args.repeat),
                 _timed(shared, args.repeat), _timed(build, max(args.repeat // 10, 3))]
        text = " | ".join(f"{c:.1f}" for c in cells)
        print(f"| {len(hit)} | {len(grids)} | {len(want)} | {text} |")
    print(f"\nfaces digest {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
