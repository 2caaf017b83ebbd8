"""The collision frame's inner kernels, each against the numpy route it replaces, in one process.

    python3 benchmarks/collision_kernels.py [--repeat 9]

Prints a Markdown table (docs/performance.md, "Kernels"): median ms over ``--repeat`` calls of

* **world patch boxes** of the ×16 dog head (2,496 level-0 patches, `benchmarks/scale_curve.py`'s
  refinement): the box of each hull box's 8 corners mapped (the numpy route) against
  `detect.SurfaceGeometry.boxes` (centre and half-extents mapped);
* **a collider's faces near a box**, a 200,000-triangle box collider under a rotation: every
  face's world box from its gathered corners (the numpy route) against
  `detect.ColliderStatic.faces_near` (object-space face boxes built once);
* **closest points on collision grids**: the 84 `grids.Closest.query` calls of `dog_head_spike`'s
  collision frames 13–17 (recorded from one `run_frames`, answered by indexes built beforehand),
  per collision frame: every (point, triangle) pair of the kd-tree ball tested exactly (the
  triangle boxes made infinite, so none is dropped) against the pairs whose triangle box lies
  within the nearest vertex's distance (`Closest.query`), the two routes alternating.

Each pair of rows times the same inputs and checks the two give the same answer. One invocation
on a shared machine: compare the ratios within it.
"""

from __future__ import annotations

import argparse
import functools
import sys
import timeit
from pathlib import Path

import numpy as np
import threadpoolctl

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from pipeline import detect, grids, usdio  # noqa: E402
from pipeline.model import ColliderModel, apply_xform  # noqa: E402


def median_ms(fn, repeat: int) -> float:
    return 1e3 * float(np.median(timeit.repeat(fn, number=1, repeat=repeat)))


def corner_boxes(geom: detect.SurfaceGeometry) -> tuple[np.ndarray, np.ndarray]:
    """World patch boxes by mapping each hull box's 8 corners (the numpy route)."""
    lo, hi = geom.shape.hulls
    sel = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], bool)
    corners = np.where(sel, hi[..., None, :], lo[..., None, :])
    world = apply_xform(geom.xform, corners.reshape(-1, 3)).reshape(corners.shape)
    return world.min(axis=-2), world.max(axis=-2)


def patch_boxes(repeat: int) -> list[tuple[str, float, str]]:
    import scale_curve

    with scale_curve.tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "scale2.usda"
        scale_curve.A.save(scale_curve.build_stage(2, scale_curve.head_grids()[2]), src)
        stage = usdio.open_input(src)
        (head, _), _ = usdio.state_at(stage, usdio.read_scene(stage), 1.0)
        geom = detect.SurfaceGeometry(head.surface, head.xform)
        geom.shape.hulls  # object-space data is built once per run
        old = corner_boxes(geom)
        new = detect.SurfaceGeometry(head.surface, head.xform).boxes
        diff = max(float(np.abs(a - b).max()) for a, b in zip(old, new)) / float(np.abs(old[1]).max())
        n = int(np.prod(old[0].shape[:2]))
        return [(f"world patch boxes, {n} patches: 8 corners mapped", median_ms(lambda: corner_boxes(geom), repeat), ""),
                ("world patch boxes: centre ± |M| half-extents (`SurfaceGeometry.boxes`)",
                 median_ms(lambda: detect.SurfaceGeometry(head.surface, head.xform).boxes, repeat),
                 f"max difference {diff:.1e} of the coordinates")]


def collider_faces(repeat: int) -> list[tuple[str, float, str]]:
    import stress

    verts, quads = stress.subdivided_box(200_000)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    static = detect.prepare_collider(ColliderModel("/box", verts, tris))
    rng = np.random.default_rng(7)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    xform = np.eye(4)
    xform[:3, :3], xform[:3, 3] = q * 2.0, (0.5, -1.0, 3.0)
    bounds = np.stack([xform[:3, 3] + (0.6, -0.3, -0.3), xform[:3, 3] + (1.2, 0.3, 0.3)])
    mesh = static.mesh

    def numpy_route():
        tri = apply_xform(xform, mesh.vertices[mesh.faces].reshape(-1, 3)).reshape(-1, 3, 3)
        return np.nonzero(grids.overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0))[0]

    static.faces_near(xform, bounds)  # the object-space face boxes are built once per run
    want, got = numpy_route(), static.faces_near(xform, bounds)
    note = f"{len(got)} faces kept, {len(want)} meet the box, all kept: {bool(np.isin(want, got).all())}"
    return [(f"collider faces near a box, {len(mesh.faces)} faces: every face's corners mapped", median_ms(numpy_route, repeat), ""),
            ("collider faces near a box: `ColliderStatic.faces_near`", median_ms(lambda: static.faces_near(xform, bounds), repeat), note)]


def closest_points(repeat: int) -> list[tuple[str, float, str]]:
    from pipeline import frames

    calls = []
    record = grids.Closest.query

    def recorded(index, points, bound=None):
        calls.append((index.vertices, index.faces, points, bound))
        return record(index, points, bound)

    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    frames.run_frames(stage, scene, [5])
    grids.Closest.query = recorded
    try:
        frames.run_frames(stage, scene, list(range(13, 18)))
    finally:
        grids.Closest.query = record

    class EveryPair(grids.Closest):
        """`grids.Closest` whose triangle boxes hold everything: no pair is dropped."""

        @functools.cached_property
        def boxes(self):
            return np.full((len(self.faces), 3), -np.inf), np.full((len(self.faces), 3), np.inf)

    def answers(kind):
        indexes = [kind(vertices, faces) for vertices, faces, _, _ in calls]
        for index, (_, _, points, bound) in zip(indexes, calls):
            index.query(points, bound)  # kd-trees and boxes are built once per index
        return lambda: [index.query(points, bound) for index, (_, _, points, bound) in zip(indexes, calls)]

    every, pruned = answers(EveryPair), answers(grids.Closest)
    same = all(np.array_equal(a, b) for x, y in zip(every(), pruned()) for a, b in zip(x, y))
    # the two routes alternate, so a change in the shared machine's load reaches both alike
    times = np.array([[timeit.timeit(route, number=1) for route in (every, pruned)] for _ in range(repeat)])
    ms = 1e3 / 5 * np.median(times, axis=0)
    return [(f"closest points on grids, {len(calls)} queries of 5 collision frames, per frame: every ball pair tested",
             float(ms[0]), ""),
            ("closest points on grids: pairs within the nearest vertex's distance by box (`Closest.query`)",
             float(ms[1]), f"bit-identical answers: {same}")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    with threadpoolctl.threadpool_limits(1):  # as the frame loop runs: BLAS on one thread
        rows = patch_boxes(args.repeat) + collider_faces(args.repeat) + closest_points(args.repeat)
    print("| kernel | median ms | |\n|---|---:|---|")
    for name, ms, note in rows:
        print(f"| {name} | {ms:.3f} | {note} |")


if __name__ == "__main__":
    main()
