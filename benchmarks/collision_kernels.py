"""The collision frame's inner kernels, each against the numpy route it replaces, in one process.

    python3 benchmarks/collision_kernels.py [--repeat 9]

Prints a Markdown table (docs/performance.md, "Kernels"): median ms over ``--repeat`` calls of

* **world patch boxes** of the ×16 dog head (2,496 level-0 patches, `benchmarks/scale_curve.py`'s
  refinement): the box of each hull box's 8 corners mapped (the numpy route) against
  `detect.SurfaceGeometry.boxes` (centre and half-extents mapped);
* **closest points on candidate triangles**, for the query points and candidate lists of the
  largest `grids.Closest.query` call on `dog_head_spike` frames 13–17: trimesh's
  `closest_point` over every (point, triangle) pair plus a lexsort per point (the numpy route)
  against `acra.closest.nearest_in_lists` (compiled; loaded from its cache by the frames run
  first);
* **a collider's faces near a box**, a 200,000-triangle box collider under a rotation: every
  face's world box from its gathered corners (the numpy route) against
  `detect.ColliderStatic.faces_near` (object-space face boxes built once).

Each pair of rows times the same inputs and checks the two give the same answer. One invocation
on a shared machine: compare the ratios within it.
"""

from __future__ import annotations

import argparse
import sys
import timeit
from pathlib import Path

import numpy as np
import threadpoolctl
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from pipeline import detect, frames, grids, usdio  # noqa: E402
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


def closest_lists(repeat: int) -> list[tuple[str, float, str]]:
    from acra import closest

    captured = []
    original = grids.Closest.query

    def spy(self, points, bound=None):
        captured.append((self, np.array(points), None if bound is None else np.array(bound)))
        return original(self, points, bound)

    grids.Closest.query = spy
    try:
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
        frames.run_frames(stage, usdio.read_scene(stage), [13, 14, 15, 16, 17])
    finally:
        grids.Closest.query = original
    # the candidate lists of the call with the most (point, triangle) pairs
    best = None
    for index, points, bound in captured:
        dv = index.vtree.query(points)[0]
        if bound is not None:
            dv = np.minimum(dv, bound)
        near = dv <= 2.0 * index.reach
        if not near.any():
            continue
        radius = dv[near] + index.reach * (1 + 1e-9) + 1e-300
        lists = index.ctree.query_ball_point(points[near], radius)
        lens = np.array([len(x) for x in lists], np.int64)
        if best is None or lens.sum() > best[3].sum():
            idx = np.concatenate([np.asarray(x, np.int64) for x in lists]) if lens.sum() else np.zeros(0, np.int64)
            best = (index, points[near], idx, lens)
    index, pts, idx, lens = best
    starts = np.r_[0, np.cumsum(lens)]
    owner = np.repeat(np.arange(len(pts)), lens)

    def numpy_route():
        cp = index.unit * trimesh.triangles.closest_point(index.tri[idx] / index.unit, pts[owner] / index.unit)
        d = np.linalg.norm(cp - pts[owner], axis=1)
        order = np.lexsort((d, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        return d[first], idx[first]

    d, _, f = closest.nearest_in_lists(index.tri, pts, starts, idx, index.unit)
    rd, rf = numpy_route()
    hit = lens > 0
    same = f"max distance difference {float(np.abs(d[hit] - rd).max()):.1e}, faces equal: {bool(np.array_equal(f[hit], rf))}"
    label = f"{len(pts)} points × {int(lens.sum())} candidate triangles"
    return [(f"closest points, {label}: trimesh `closest_point` + lexsort", median_ms(numpy_route, repeat), ""),
            ("closest points: `acra.closest.nearest_in_lists` (compiled)",
             median_ms(lambda: closest.nearest_in_lists(index.tri, pts, starts, idx, index.unit), repeat), same)]


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    with threadpoolctl.threadpool_limits(1):  # as the frame loop runs: BLAS on one thread
        rows = patch_boxes(args.repeat) + closest_lists(args.repeat) + collider_faces(args.repeat)
    print("| kernel | median ms | |\n|---|---:|---|")
    for name, ms, note in rows:
        print(f"| {name} | {ms:.3f} | {note} |")


if __name__ == "__main__":
    main()
