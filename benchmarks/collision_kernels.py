"""The collision frame's inner kernels, each against the numpy route it replaces, in one process.

    python3 benchmarks/collision_kernels.py [--repeat 9]

Prints a Markdown table (docs/performance.md, "Kernels"): median ms over ``--repeat`` calls of

* **world patch boxes** of the ×16 dog head (2,496 level-0 patches, `benchmarks/scale_curve.py`'s
  refinement): the box of each hull box's 8 corners mapped (the numpy route) against
  `geometry.SurfaceGeometry.boxes` (centre and half-extents mapped);
* **a collider's faces near a box**, a 200,000-triangle box collider under a rotation: every
  face's world box from its gathered corners (the numpy route) against
  `geometry.ColliderStatic.faces_near` (object-space face boxes built once);
* **closest points on collision grids**: the 84 `grids.Closest.query` calls of `dog_head_spike`'s
  collision frames 13–17 (recorded from one `run_frames`), per collision frame, each index built
  with its queries: the kd-tree route `Closest.query` took up to `23b1368` (`KdTreeClosest`:
  kd-tree balls, a box test, trimesh's ``closest_point`` over the (point, triangle) pairs)
  against the compiled BVH in trimesh's arithmetic (`Closest.query`, `acra.nearest`), the two
  routes alternating.

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
from itertools import chain
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from pipeline import geometry
from pipeline import grids, usdio  # noqa: E402
from pipeline.model import ColliderModel, apply_xform  # noqa: E402


def median_ms(fn, repeat: int) -> float:
    return 1e3 * float(np.median(timeit.repeat(fn, number=1, repeat=repeat)))


def corner_boxes(geom: geometry.SurfaceGeometry) -> tuple[np.ndarray, np.ndarray]:
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
        geom = geometry.SurfaceGeometry(head.surface, head.xform)
        geom.shape.hulls  # object-space data is built once per run
        old = corner_boxes(geom)
        new = geometry.SurfaceGeometry(head.surface, head.xform).boxes
        diff = max(float(np.abs(a - b).max()) for a, b in zip(old, new)) / float(np.abs(old[1]).max())
        n = int(np.prod(old[0].shape[:2]))
        return [(f"world patch boxes, {n} patches: 8 corners mapped", median_ms(lambda: corner_boxes(geom), repeat), ""),
                ("world patch boxes: centre ± |M| half-extents (`SurfaceGeometry.boxes`)",
                 median_ms(lambda: geometry.SurfaceGeometry(head.surface, head.xform).boxes, repeat),
                 f"max difference {diff:.1e} of the coordinates")]


def collider_faces(repeat: int) -> list[tuple[str, float, str]]:
    import stress

    verts, quads = stress.subdivided_box(200_000)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    static = geometry.prepare_collider(ColliderModel("/box", verts, tris))
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


class KdTreeClosest:
    """The kd-tree route `grids.Closest` replaced (at `23b1368`): each point's candidate
    triangles are the centroids within its nearest vertex's distance plus the largest reach
    (`cKDTree` balls), those whose box lies farther than that distance dropped, and trimesh's
    ``closest_point`` over the remaining (point, triangle) pairs, the nearest kept per point
    (lowest face row among equal distances). Grid sets only (no fcl route for deep points: the
    bundled scenes' grid queries never took it)."""

    def __init__(self, vertices, faces):
        self.vertices, self.faces = vertices, faces
        self.tri = vertices[faces]
        self.unit = grids.extent(vertices)
        self._cen = (self.tri[:, 0] + self.tri[:, 1] + self.tri[:, 2]) / 3.0
        self.reach = float(np.linalg.norm(self.tri - self._cen[:, None], axis=2).max())
        self.vtree = cKDTree(vertices[np.unique(faces)])
        self.ctree = cKDTree(self._cen)
        self.boxes = grids.triangle_boxes(self.tri)

    def query(self, points, bound=None):
        k = points.shape[0]
        dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
        if k == 0:
            return dist, close, face
        dv, _ = self.vtree.query(points)
        if bound is not None:
            dv = np.minimum(dv, bound)
        radius = dv + self.reach * (1 + 1e-9) + 1e-300
        lists = self.ctree.query_ball_point(points, radius, return_sorted=False)
        lens = np.fromiter(map(len, lists), np.int64, k)
        idx = np.fromiter(chain.from_iterable(lists), np.int64, int(lens.sum()))
        owner = np.repeat(np.arange(k), lens)
        at = points[owner]
        lo, hi = self.boxes
        gap = np.maximum(np.maximum(lo[idx] - at, at - hi[idx]), 0.0)
        limit = dv[owner] * (1 + 1e-9) + 1e-12 * self.unit
        keep = np.nonzero(np.einsum("ij,ij->i", gap, gap) <= limit * limit)[0]
        idx, owner, at = idx[keep], owner[keep], at[keep]
        if len(idx):
            cp = self.unit * trimesh.triangles.closest_point(self.tri[idx] / self.unit, at / self.unit)
            d = np.linalg.norm(cp - at, axis=1)
            order = np.lexsort((idx, d, owner))
            first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
            hit = owner[first]
            dist[hit], close[hit], face[hit] = d[first], cp[first], idx[first]
        return dist, close, face


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

    def indexes(kind):
        return [kind(vertices, faces) for vertices, faces, _, _ in calls]

    def answers(made):
        return [index.query(points, bound) for index, (_, _, points, bound) in zip(made, calls)]

    def same(x, y):
        """Equal answers wherever both find a triangle; where one alone does (a bounded query),
        the kd-tree route's is beyond the bound, which `GridSet.nearest` does not take."""
        for (da, ca, fa), (db, cb, fb), (*_, bound) in zip(x, y, calls):
            both = np.isfinite(da) & np.isfinite(db)
            if not all(np.array_equal(u[both], v[both]) for u, v in ((da, db), (ca, cb), (fa, fb))):
                return False
            one = np.isfinite(da) != np.isfinite(db)
            if one.any() and (bound is None or np.any(np.minimum(da, db)[one] <= bound[one])):
                return False
        return True

    kd, bvh = indexes(KdTreeClosest), indexes(grids.Closest)
    agree = same(answers(kd), answers(bvh))
    # the two routes alternate, so a change in the shared machine's load reaches both alike;
    # the indexes' build (kd-trees, or the BVH) is timed with their queries, once per index
    times = np.array([[timeit.timeit(lambda: answers(indexes(kind)), number=1) for kind in (KdTreeClosest, grids.Closest)]
                      for _ in range(repeat)])
    ms = 1e3 / 5 * np.median(times, axis=0)
    return [(f"closest points on grids, {len(calls)} queries of 5 collision frames, per frame, indexes built: kd-tree balls, "
             "boxes, trimesh `closest_point`", float(ms[0]), ""),
            ("closest points on grids: compiled BVH in trimesh's arithmetic (`Closest.query`, `acra.nearest`)",
             float(ms[1]), f"same answers: {agree}")]


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
