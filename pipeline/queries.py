"""Closest points, inside tests and ray casts on a `Shape`'s collision grids, in object space.

Each query visits only the patches whose hull boxes can hold the answer, so a query near a contact
costs the same on a model of 200 patches as on one of 2,000. Inside tests use the sign of the
closest point's offset along the outward normal: for a closed surface the closest point of a point
inside lies on the surface with the point behind it. Unlike ray parity this needs no watertight
mesh of the whole object (docs/detection.md). Arrays are float64 unless stated.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from embreex import rtcore, rtcore_scene
from embreex.mesh_construction import TriangleMesh

from acra import hspline as H
from acra import meshops, raycast, sides
from acra.bvh import bounds
from acra.nearest import candidates
from acra.patch_boxes import rays_meet
from pipeline.grids import Nearest

if TYPE_CHECKING:
    from pipeline.shape import Shape

__all__ = ["nearest", "signed", "cast"]


def nearest(shape: Shape, q: np.ndarray) -> Nearest:
    """Closest points on the collision grids to object-space points ``q (k, 3)``.

    Only patches that can hold the answer are visited: the nearest point of a coarse sample
    of the surface bounds the distance; the patches whose hull boxes lie within that bound
    of some query are searched exactly, all queries at once (`GridSet`)."""
    q = np.asarray(q, np.float64).reshape(-1, 3)
    if not len(q):
        return _no_points()
    _, q, patches = _candidates(shape, q, None)
    return _search(shape, q, patches)


def _no_points() -> Nearest:
    return Nearest(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 2)))


def _candidates(shape: Shape, q: np.ndarray, hull: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``(m,) int64`` of object-space points ``q (k, 3)`` within ``hull``'s half-spaces
    (`Shape.cv_hull`, by 1e-9 of the size; ``None``: every row), those points ``(m, 3)`` and the
    rows ``(c,) int64`` of the patches whose hull boxes can hold their closest points: the
    coarse kd-tree bound and the box tests in one compiled pass (`acra.nearest.candidates`)."""
    lo, hi, _ = shape._boxes
    index = shape.coarse_index  # a surface point: the closest is no farther
    slack = 0.0 if hull is None else 1e-9 * shape.surface.size()
    return candidates(q, hull, slack, index.extra, index.tree, index.current, lo, hi)


def _search(shape: Shape, q: np.ndarray, patches: np.ndarray) -> Nearest:
    """Closest points to ``q (k, 3)`` on the grids of ``patches (c,) int64``: one search over
    the union of every query's candidates, which holds each query's closest point."""
    if not len(q):
        return _no_points()
    return shape.cache.gridset(tuple(patches.tolist())).nearest(q)


def signed(shape: Shape, q: np.ndarray, nearest: bool = True) -> tuple[np.ndarray, Nearest | None]:
    """Which object-space points ``q (k, 3)`` are inside ``(k,) bool`` (all False if the
    surface is open), and the `nearest` points of those inside (``None`` where ``nearest`` is
    false: an inside test alone, as a cast's origins ask). Inside: behind the outward
    normal at the closest point; points on the grids (distance 0) count as outside. Points
    outside `cv_hull` (by more than 1e-9 of the size) are outside without a closest-point
    search (`Shape.cv_hull`): a thin object's box holds many such points (on `dog_head_spike`, 484 head vertices
    in the spike's box took 95 ms a round).

    After the search, the closest points' parameters, normals and sides are one compiled pass
    (`acra.sides.behind`); a closest point where ``du × dv`` has no direction (a pole, a
    collapsed edge) takes its normal from `hspline.surface_normals`' limit, as every point's
    normal is that function's answer."""
    q = np.asarray(q, np.float64).reshape(-1, 3)
    inside = np.zeros(len(q), bool)
    if not shape.closed or not len(q):
        return inside, _no_points() if nearest else None
    hull = shape.cv_hull
    if hull is not None and len(hull) > shape.cv_index.DIRECT:  # a large hull's test goes through its cones
        cand = np.nonzero(shape.cv_index.within(q, 1e-9 * shape.surface.size()))[0]
        _, qc, patches = _candidates(shape, q[cand], None)
    else:
        cand, qc, patches = _candidates(shape, q, hull)
    if not len(qc):
        return inside, _no_points() if nearest else None
    grid = shape.cache.gridset(tuple(patches.tolist()))
    dist, close, face = grid.closest(qc)
    outward = shape.outward
    uv, flag = sides.behind(grid.points, grid.uv, grid.triangles, grid.face_lo, grid.face_hi, face, close, qc, outward,
                            shape.surface.size(), shape.eval_args)
    undecided = np.flatnonzero(flag < 0)
    if len(undecided):
        _, n = H.surface_normals(shape.surface, uv[undecided, 0], uv[undecided, 1], det=shape.details)
        flag[undecided] = outward * np.einsum("ij,ij->i", qc[undecided] - close[undecided], n) < 0
    # the rows behind, taken by index: numpy's boolean mask of an (m, 3) array walks it element
    # by element (16 against 3 us for 450 rows)
    side = np.flatnonzero(flag > 0)
    inside[cand[side]] = True
    if not nearest:
        return inside, None
    return inside, Nearest(np.take(dist, side), np.take(close, side, axis=0), np.take(uv, side, axis=0))


_DEVICE = None  # the embree device every scene shares: a scene of its own would start one (50-200 us CPU)


class RayMesh:
    """A merged triangle mesh cast on as trimesh's embree intersector (``trimesh.ray.ray_pyembree``,
    first hits with locations) casts, without a `trimesh.Trimesh`: the vertices merged to 1e-8
    (`acra.raycast.merged`, trimesh's rule), moved to the box's low corner and scaled to a diagonal of
    100 in float32 for embree, which reports the first triangle a ray meets; the hit is where the
    float64 ray meets that triangle's plane (its first corner, unit normal). The same bits as
    trimesh's (tests/test_meshops.py).

    The triangle is embree's answer, found without embree where it is sure
    (`acra.raycast.sure_first_hits`: every triangle near the ray tested on embree's float32
    numbers, clear of its rounding); an embree scene is built only for the rays it leaves (through
    an edge or a vertex, nearly tied hits): a scene costs about 0.5 us a triangle to fill and
    0.2-0.8 ms to build, 30 times a cast of 70 rays."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices, self.faces = raycast.merged(vertices, faces)
        self.box = bounds(self.vertices) if len(self.vertices) else None  # (2, 3): min and max corners
        self.scale = meshops.scale(self.vertices, self.box)
        self._scene = None
        self._ready = False

    def _prepare(self) -> None:
        """embree's float32 vertices ``(v, 3)`` and the boxes of the faces, at the first cast."""
        self.origin = self.box[0]
        self.factor = float(100.0 / self.scale)
        self.scaled = ((self.vertices - self.origin) * self.factor).astype(np.float32)
        self.boxes = raycast.group_boxes(self.scaled, self.faces)
        self._ready = True

    @property
    def scene(self) -> rtcore_scene.EmbreeScene:
        """The embree scene, built at the first cast that needs it."""
        if self._scene is None:
            global _DEVICE
            if _DEVICE is None:
                _DEVICE = rtcore.EmbreeDevice()
            self._scene = rtcore_scene.EmbreeScene(_DEVICE)
            TriangleMesh(scene=self._scene, vertices=self.scaled, indices=self.faces.astype(np.int32))
        return self._scene

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits ``(m, 3)`` of rays ``origins, directions (n, 3)`` and the row ``(m,) int64``
        of each ray that hit (trimesh's ``intersects_location(..., multiple_hits=False)``)."""
        if not self._ready:
            self._prepare()
        origins = np.ascontiguousarray(origins, dtype=np.float64)  # read, not written
        directions = meshops.unitize(np.ascontiguousarray(directions, dtype=np.float64))[0]
        scaled = ((origins - self.origin) * self.factor).astype(np.float32)
        unit = directions.astype(np.float32)
        # the sure rays' hits come with their triangles (`raycast.sure_hits`); embree's answers for
        # the others take the same arithmetic in numpy. The hit faces' normals alone: each row is
        # the same bits as in the whole mesh's (`Trimesh.face_normals`), every step being row by row
        query, sure, loc, has = raycast.sure_hits(self.scaled, self.faces, self.boxes, scaled, unit,
                                                  (self.vertices, origins, directions))
        if not sure.all():
            ask = np.nonzero(~sure)[0]
            query[ask] = self.scene.run(np.ascontiguousarray(scaled[ask]), np.ascontiguousarray(unit[ask]))
            rows = ask[query[ask] != -1]
            faces = self.faces[query[rows]]
            normals = meshops.face_normals(self.vertices, faces)
            at, valid = meshops.planes_lines(self.vertices[faces[:, 0]], normals, origins[rows], directions[rows])
            loc[rows[valid]], has[rows[valid]] = at, True
        rays = np.nonzero(has)[0]
        return loc[rays], rays

    def trimesh(self):
        """This mesh as a `trimesh.Trimesh` (imported here: only the rare float64 retry of
        `cast` needs it)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def _ray_mesh(shape: Shape, patches: np.ndarray, hit: np.ndarray) -> RayMesh:
    """The merged mesh of the collision grids of flattened patch rows ``hit (m,) int64``
    (``patches (P, 2) int64``: their (row, column)), with its embree scene once a ray is cast;
    the last few are kept on ``shape`` (`Shape.ray_meshes`): the rays of a frame's data points
    and of the next round's often meet the same patches of the same surface, and a kept mesh
    answers as the same mesh built again would."""
    key = hit.tobytes()
    mesh = shape.ray_meshes.pop(key, None)
    if mesh is None:
        grids = shape.grids_for(patches[hit])
        # patch borders are evaluated twice: merge them, or rays slip through float32 cracks
        mesh = RayMesh(np.concatenate([g.points for g in grids]), _grid_faces(grids))
    shape.ray_meshes[key] = mesh
    while len(shape.ray_meshes) > 4:
        del shape.ray_meshes[next(iter(shape.ray_meshes))]
    return mesh


def _grid_faces(grids: list) -> np.ndarray:
    """The solid triangles ``(f, 3) int64`` of ``grids`` (`PatchGrid`) one grid after another,
    each moved past the points of the grids before it. Grids built together at one density share
    their triangle list (`GridCache.build`); where every grid shares it and keeps all of it (no
    pole row's slivers), the list moved by every grid's offset in one sum is the same faces.
    Otherwise each grid's rows are gathered only where it drops slivers, and the lists joined
    are moved by one repeated sum, as `GridSet` joins them: integer sums, the same faces."""
    sizes = [len(g.points) for g in grids]
    base = np.cumsum([0] + sizes[:-1])
    tri = grids[0].triangles
    if all(g.triangles is tri and len(g.solid) == len(tri) for g in grids):
        return (tri[None] + base[:, None, None]).reshape(-1, 3)
    # a pole grid drops its sliver rows (the demo's spike: 8 of 128), the others keep their list
    # whole: one sum over the joined lists, not one a grid (`benchmarks/ray_mesh_calls.py`)
    counts = [len(g.solid) for g in grids]
    faces = np.concatenate([g.triangles if c == len(g.triangles) else g.triangles[g.solid] for g, c in zip(grids, counts)])
    faces += np.repeat(base, counts)[:, None]
    return faces


def cast(shape: Shape, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits ``(m, 3)`` of object-space rays ``origins, directions (n, 3)`` on the
    collision grids and the row of each hit ray ``(m,) int64`` (in increasing order but for the
    float64 retries, which follow). Only patches whose boxes the rays meet are tessellated."""
    lo, hi, patches = shape._boxes
    box_hit, ray_hit = rays_meet(lo, hi, origins, directions)
    hit = np.flatnonzero(box_hit)
    if not len(hit):
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    mesh = _ray_mesh(shape, patches, hit)
    loc, ray = mesh.first_hits(origins, directions)
    # embree works in float32 and can let a ray through an edge it meets exactly: retry the
    # rays that met a box but no triangle in float64 (rare, so the slower intersector is fine)
    ray_hit[ray] = False
    miss = np.flatnonzero(ray_hit)
    if len(miss):
        from trimesh.ray.ray_triangle import RayMeshIntersector

        more, row, _ = RayMeshIntersector(mesh.trimesh()).intersects_location(origins[miss], directions[miss], multiple_hits=False)
        loc, ray = np.concatenate([loc, np.reshape(more, (-1, 3))]), np.concatenate([ray, miss[np.asarray(row, np.int64)]])
    return loc, ray
