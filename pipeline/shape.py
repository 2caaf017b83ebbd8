"""A deformable's object-space shape data and the local queries answered on it.

Everything about a surface that does not depend on where it is lives in a `Shape`: level details,
level-0 patch hull boxes, and per-patch collision grids (`PatchGrid`) with their closest-point
indices, built lazily per patch. Closest points, inside tests and ray casts (`Shape.nearest`,
`Shape.inside`, `Shape.cast`) visit only the patches whose hull boxes can hold the answer, so a
query near a contact costs the same on a model of 200 patches as on one of 2,000, and a response,
which changes a surface locally, re-tessellates only the patches it changed (`changed_patches`).

Inside tests use the sign of the closest point's offset along the outward normal: for a closed
surface the closest point of a point inside lies on the surface with the point behind it. Unlike
ray parity this needs no watertight mesh of the whole object (docs/detection.md). Object space
throughout; arrays are float64 unless stated.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property
from itertools import chain

import fcl
import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError, cKDTree
from trimesh.ray.ray_triangle import RayMeshIntersector

from acra import hspline as H
from acra.hspline import HSpline, changed_patches
from acra.tessellate import patch_grids, patch_hulls

__all__ = ["PatchGrid", "GridSet", "Shape", "SetupClock", "shape_of", "seed_details", "Nearest", "Closest", "bvh", "overlap"]

COLLAPSE = 1e-6  # a grid line within this fraction of the object size is one point (a pole); float32 `acra:cvs` round at ~1e-7
_US_PAIR, _US_BVH_FACE, _US_FCL_QUERY = 0.8, 3.5, 20.0  # measured costs (µs), see Closest


# --- closest points on a triangle set ---------------------------------------------------------
def overlap(lo_a, hi_a, lo_b, hi_b, pad: float) -> np.ndarray:
    """Whether boxes overlap (broadcast over leading axes)."""
    return np.all((lo_a <= hi_b + pad) & (lo_b <= hi_a + pad), axis=-1)


def bvh(vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    """An fcl BVH of a triangle set at the identity transform; face rows are kept, so fcl's
    ``b1``/``b2`` are rows of ``faces``. Only the vertices the faces use go in: fcl's build costs
    per vertex too (3,009 vertices for 39 faces: 2.4 ms, compacted 0.2 ms)."""
    used, tri = np.unique(faces, return_inverse=True)
    model = fcl.BVHModel()
    model.beginModel(len(used), len(faces))
    model.addSubModel(np.ascontiguousarray(vertices[used], np.float64), np.ascontiguousarray(tri.reshape(-1, 3), np.int32))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


class Closest:
    """Exact closest points on triangles. The closest point is no farther than the nearest vertex
    (``d_v``), so its triangle's centroid is within ``d_v + reach`` (the largest centroid-corner
    distance): near points test that ball's triangles (kd-trees); deep points, whose ball covers
    much of a curved surface, query an fcl BVH of the triangles within ``d_v``, if cheaper."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, bvh_: fcl.CollisionObject | None = None) -> None:
        self.vertices, self.faces, self.bvh = vertices, faces, bvh_
        self.tri = vertices[faces]  # (f, 3, 3)
        # trimesh's closest_point has absolute tolerances (1e-13): work in units of the mesh's size
        self.unit = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
        self.unit = self.unit if self.unit > 0 else 1.0
        self._cen = self.tri.mean(axis=1)
        self.reach = float(np.linalg.norm(self.tri - self._cen[:, None], axis=2).max()) if len(faces) else 0.0
        self.vtree = cKDTree(vertices[np.unique(faces)])

    @cached_property
    def ctree(self) -> cKDTree:
        return cKDTree(self._cen)

    def query(self, points: np.ndarray, bound: np.ndarray | None = None):
        """Distances ``(k,)``, closest points ``(k, 3)`` and face rows ``(k,) int64``. With
        ``bound (k,)``, only closest points nearer than it are sought (else distance ``inf``)."""
        k = points.shape[0]
        dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
        if k == 0:
            return dist, close, face
        dv, _ = self.vtree.query(points)
        if bound is not None:
            dv = np.minimum(dv, bound)
        radius = dv + self.reach * (1 + 1e-9) + 1e-300
        ball = dv <= 2.0 * self.reach
        deep = np.nonzero(~ball)[0]
        tree, rows = self.bvh, None
        if len(deep) and tree is None:  # a BVH of the triangles in reach, if cheaper than balls
            grow = dv[deep].max() * (1 + 1e-9)
            lo, hi = points[deep].min(axis=0) - grow, points[deep].max(axis=0) + grow
            rows = np.nonzero(overlap(self.tri.min(axis=1), self.tri.max(axis=1), lo, hi, 0.0))[0]
            pairs = self.ctree.query_ball_point(points[deep], radius[deep], return_length=True).sum()
            ball[deep] = pairs * _US_PAIR < _US_BVH_FACE * len(rows) + _US_FCL_QUERY * len(deep)
            if not ball[deep].all():
                tree = bvh(self.vertices, self.faces[rows])
        near = np.nonzero(ball)[0]
        if len(near):
            lists = self.ctree.query_ball_point(points[near], radius[near])
            lens = np.fromiter(map(len, lists), np.int64, len(near))
            idx = np.fromiter(chain.from_iterable(lists), np.int64, int(lens.sum()))
        if len(near) and len(idx):
            # one compiled pass over the (point, triangle) pairs keeps each point's nearest; loaded
            # on the first contact, so a run without one never imports the compiler
            from acra import closest

            d, cp, f = closest.nearest_in_lists(self.tri, points[near], np.r_[0, np.cumsum(lens)], idx, self.unit)
            hit = np.nonzero(lens)[0]
            dist[near[hit]], close[near[hit]], face[near[hit]] = d[hit], cp[hit], f[hit]
        probe, req = fcl.Sphere(0.0), fcl.DistanceRequest(enable_nearest_points=True)
        for i in np.nonzero(~ball)[0]:
            res = fcl.DistanceResult()  # mesh first: b1 is its face, nearest_points[0] on it
            dist[i] = fcl.distance(tree, fcl.CollisionObject(probe, fcl.Transform(points[i])), req, res)
            close[i], face[i] = res.nearest_points[0], res.b1 if rows is None else rows[res.b1]
        return dist, close, face


# --- set-up time ---------------------------------------------------------------------------------
class SetupClock:
    """Milliseconds spent building `Shape` data (the thesis's "initial setup" of RAPID, Fig. 5.2):
    the frame loop reads it around detection to report set-up apart from the queries."""

    ms: float = 0.0


def _timed(build):
    """Decorate a `Shape` builder so its time goes to `SetupClock`."""

    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return build(*args, **kwargs)
        finally:
            SetupClock.ms += 1e3 * (time.perf_counter() - t)

    timed.__name__, timed.__doc__ = build.__name__, build.__doc__
    return timed


# --- per-patch collision grids --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PatchGrid:
    """One level-0 patch's collision grid in object space: ``points (n, 3)``, their parameters
    ``uv (n, 2)`` (level-0 units, continuous within the patch), ``triangles (f, 3) int64`` wound
    so that their normals follow ``du × dv``."""

    points: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray

    @cached_property
    def solid(self) -> np.ndarray:
        """Rows of ``triangles`` with three distinct corners (a pole row's slivers dropped)."""
        tri = self.points[self.triangles]
        tol = COLLAPSE * max(float(np.ptp(self.points, axis=0).max()), 1e-300)
        edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
        return np.nonzero(edges.min(axis=1) > tol)[0]



class GridSet:
    """Several patch grids as one triangle set, so a batch of queries near a contact is answered
    by one kd-tree pass and one exact closest-point call per grid density instead of one of each
    per patch grid. Grids of one density share a `Closest` index (its search radius grows with
    the largest triangle, so a coarse grid must not widen a fine one's). ``face_lo, face_hi
    (f, 2)``: the parameter box of each solid face's patch (closest points' parameters are kept
    inside their patch)."""

    def __init__(self, grids: list[PatchGrid]) -> None:
        grids = sorted(grids, key=lambda g: len(g.points), reverse=True)  # finest first
        base = np.cumsum([0] + [len(g.points) for g in grids[:-1]])
        self.points = np.concatenate([g.points for g in grids])
        self.uv = np.concatenate([g.uv for g in grids])
        self.triangles = np.concatenate([g.triangles[g.solid] + b for g, b in zip(grids, base)])
        count = np.array([len(g.solid) for g in grids])
        self.face_lo = np.repeat(np.array([g.uv[0] for g in grids]), count, axis=0)
        self.face_hi = np.repeat(np.array([g.uv[-1] for g in grids]), count, axis=0)
        size = np.array([len(g.points) for g in grids])
        first = np.cumsum(np.r_[0, count])
        self.indices = []  # (first face row, Closest) per density
        for n in np.unique(size)[::-1]:
            a, b = np.nonzero(size == n)[0][[0, -1]]
            self.indices.append((first[a], Closest(self.points, self.triangles[first[a]:first[b + 1]])))

    def nearest(self, q: np.ndarray) -> Nearest:
        """Closest points to ``q (k, 3)`` and their parameters, interpolated from the face
        corners."""
        dist, close, face = np.full(len(q), np.inf), np.zeros((len(q), 3)), np.zeros(len(q), np.int64)
        for start, index in self.indices:
            d, cp, f = index.query(q, dist * (1 + 1e-9) + 1e-300)  # only what beats a finer density's
            better = d < dist
            dist[better], close[better], face[better] = d[better], cp[better], f[better] + start
        tri = self.triangles[face]
        bary = trimesh.triangles.points_to_barycentric(self.points[tri], close)
        uv = np.clip(np.einsum("kj,kjc->kc", bary, self.uv[tri]), self.face_lo[face], self.face_hi[face])
        return Nearest(dist, close, uv)


@dataclass(frozen=True, eq=False)
class Nearest:
    """Closest points on a shape's collision grids: ``distance (k,)``, object-space ``points
    (k, 3)``, parameters ``uv (k, 2)``."""

    distance: np.ndarray
    points: np.ndarray
    uv: np.ndarray


class Shape:
    """Everything about a surface that does not depend on where it is, in object space. A
    deformable's input shape is the same at every time code unless its ``acra:cvs`` are keyed, so
    one `Shape` serves every frame and every rewinding step (`shape_of`); only the matrix changes.
    Built lazily, so what is never needed is never computed. ``parent``: the shape this one was
    responded from, whose grids it reuses where the response did not reach."""

    def __init__(self, surface: HSpline, density: int = 8, max_density: int = 64, parent: "Shape | None" = None) -> None:
        self.surface, self.density, self.max_density = surface, density, max_density
        self.grids: dict[tuple[int, int], PatchGrid] = {}
        self._gridsets: dict[tuple[int, ...], GridSet] = {}
        self.parent = parent

    @cached_property
    @_timed
    def details(self) -> H.Details | None:
        return H.details(self.surface) if self.surface.depth > 1 else None

    @cached_property
    @_timed
    def hulls(self) -> tuple[np.ndarray, np.ndarray]:
        """Object-space boxes ``lo, hi (P0u, P0v, 3)`` of the level-0 patches' control hulls;
        the parent's where the response did not reach."""
        stale = self._stale
        if stale is None or stale.all():
            return patch_hulls(self.surface, self.details)
        lo, hi = (x.copy() for x in self.parent.hulls)
        if stale.any():
            new = patch_hulls(self.surface, self.details, only=stale)
            lo[stale], hi[stale] = new[0][stale], new[1][stale]
        return lo, hi

    @cached_property
    def density_map(self) -> np.ndarray:
        """Steps per edge of each level-0 patch ``(P0u, P0v) int64``: ``max(density, 2 * 2**k)``,
        ``k`` the finest level with an active patch inside it, capped at ``max_density``."""
        hs = self.surface
        finest = np.zeros((hs.u.patches0, hs.v.patches0), np.int64)
        for lev in hs.fine:
            if lev.patches.size:
                npv = hs.v.patches(lev.k)
                finest[(lev.patches // npv) >> lev.k, (lev.patches % npv) >> lev.k] = lev.k
        return np.minimum(np.maximum(self.density, 2 * (1 << finest)), self.max_density)

    @cached_property
    def closed(self) -> bool:
        """Periodic both ways, or one way with both ends of the other collapsed (poles); a cubic is
        fixed by 4 points per segment, so 4 coincident samples per patch make an end one point."""
        hs = self.surface
        if hs.u.periodic == hs.v.periodic:
            return hs.u.periodic
        per, end = (hs.u, hs.v) if hs.u.periodic else (hs.v, hs.u)
        run = np.arange(4 * per.patches0) / 4.0
        for e in (0.0, float(end.patches0)):
            uv = (run, np.full_like(run, e)) if hs.u.periodic else (np.full_like(run, e), run)
            if np.ptp(H.evaluate(hs, *uv, det=self.details).points, axis=0).max() > COLLAPSE * hs.size():
                return False
        return True

    @cached_property
    @_timed
    def _coarse(self) -> tuple[np.ndarray, np.ndarray, cKDTree]:
        """A 2-step grid of every level-0 patch: surface ``points (9 P, 3)``, ``triangles
        (8 P, 3) int64`` and a kd-tree of the points (their distance bounds a query's); the
        parent's points where the response did not reach."""
        stale = self._stale
        if stale is None or stale.all():
            p = np.argwhere(np.ones((self.surface.u.patches0, self.surface.v.patches0), bool))
            pts, _, tris, _ = patch_grids(self.surface, p, 2, det=self.details)
            return pts, tris, cKDTree(pts)
        pts, tris, _ = self.parent._coarse
        pts = pts.copy()
        if stale.any():  # 9 points per patch, patches in row-major order
            new = patch_grids(self.surface, np.argwhere(stale), 2, det=self.details)[0]
            pts.reshape(stale.size, 9, 3)[stale.reshape(-1)] = new.reshape(-1, 9, 3)
        return pts, tris, cKDTree(pts)

    @cached_property
    def outward(self) -> float:
        """``+1`` if ``du × dv`` points out of a closed surface, else ``-1``: the sign of the
        volume enclosed by the coarse grid (divergence theorem)."""
        pts, tris, _ = self._coarse
        a, b, c = (pts[tris[:, i]] - pts.mean(axis=0) for i in range(3))
        return 1.0 if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() >= 0 else -1.0

    @cached_property
    def _boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flattened hull boxes ``lo, hi (P, 3)`` and their patches ``(P, 2) int64``."""
        lo, hi = (x.reshape(-1, 3) for x in self.hulls)
        return lo, hi, np.argwhere(np.ones(self.hulls[0].shape[:2], bool)).astype(np.int64)

    @cached_property
    def _stale(self) -> np.ndarray | None:
        """Patches ``(P0u, P0v) bool`` where the parent's grids, hull boxes, coarse points and
        display samples cannot serve (``None``: no parent)."""
        p = self.parent
        if p is None:
            return None
        return changed_patches(p.surface, self.surface) | (p.density_map != self.density_map)

    @_timed
    def _build(self, missing: list[tuple[int, int]]) -> None:
        stale = self._stale
        todo = []
        for key in missing:
            old = None if stale is None or stale[key] else self.parent.grids.get(key)
            if old is not None:
                self.grids[key] = old
            else:
                todo.append(key)
        todo_arr = np.array(todo, np.int64).reshape(-1, 2)
        steps = self.density_map[todo_arr[:, 0], todo_arr[:, 1]]
        for s in np.unique(steps):
            sel, n = todo_arr[steps == s], (int(s) + 1) ** 2
            pts, uv, tris, _ = patch_grids(self.surface, sel, int(s), det=self.details)
            tri = tris[: 2 * int(s) ** 2]
            for r, p in enumerate(sel):
                self.grids[(int(p[0]), int(p[1]))] = PatchGrid(pts[r * n:(r + 1) * n], uv[r * n:(r + 1) * n], tri)

    def grids_for(self, patches: np.ndarray) -> list[PatchGrid]:
        """Collision grids of level-0 ``patches (m, 2) int64`` at their density (cached)."""
        keys = [(int(a), int(b)) for a, b in np.asarray(patches, np.int64).reshape(-1, 2)]
        missing = list(dict.fromkeys(k for k in keys if k not in self.grids))
        if missing:
            self._build(missing)
        return [self.grids[k] for k in keys]

    def nearest(self, q: np.ndarray) -> Nearest:
        """Closest points on the collision grids to object-space points ``q (k, 3)``.

        Only patches that can hold the answer are visited: the nearest point of a coarse sample
        of the surface bounds the distance; the patches whose hull boxes lie within that bound
        of some query are searched exactly, all queries at once (`GridSet`)."""
        q = np.asarray(q, np.float64).reshape(-1, 3)
        if not len(q):
            return Nearest(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 2)))
        lo, hi, _ = self._boxes
        upper = self._coarse[2].query(q)[0]  # a surface point: the closest is no farther
        reach = upper.max() * (1 + 1e-9) + 1e-300
        pre = np.nonzero(overlap(lo, hi, q.min(axis=0) - reach, q.max(axis=0) + reach, 0.0))[0]
        gap = np.linalg.norm(np.maximum(np.maximum(lo[pre][None] - q[:, None], q[:, None] - hi[pre][None]), 0.0), axis=2)
        cand = pre[np.nonzero(gap <= upper[:, None] * (1 + 1e-9) + 1e-300)[1]]
        # one search over the union of every query's candidates: it holds each query's closest
        # point, and the union's nearest vertex bounds the distance to a grid step
        return self._gridset(tuple(int(p) for p in np.unique(cand))).nearest(q)

    def _gridset(self, found: tuple[int, ...]) -> GridSet:
        """The `GridSet` of flattened patch rows ``found`` (the last few are kept: consecutive
        rounds and frames query the same contact)."""
        hit = self._gridsets.pop(found, None)
        if hit is None:
            hit = GridSet(self.grids_for(self._boxes[2][list(found)]))
        self._gridsets[found] = hit
        while len(self._gridsets) > 16:
            del self._gridsets[next(iter(self._gridsets))]
        return hit

    @cached_property
    @_timed
    def cv_hull(self) -> np.ndarray | None:
        """Half-spaces ``(m, 4) float64`` of the convex hull of every level's CV positions, a point
        ``x`` within it iff ``n · x + d <= 0`` for every row ``(n, d)``; ``None`` if the CVs are
        flat. The surface lies in it (B-spline convex hull property: a fine level's net is the
        refined coarser net plus details, and refinement takes convex combinations), so do its
        collision grids and, for a closed surface, everything they enclose."""
        try:
            return ConvexHull(np.concatenate(H.all_cv_positions(self.surface, self.details))).equations
        except QhullError:
            return None

    def signed(self, q: np.ndarray) -> tuple[np.ndarray, Nearest]:
        """Which object-space points ``q (k, 3)`` are inside ``(k,) bool`` (all False if the
        surface is open), and the `nearest` points of those inside. Inside: behind the outward
        normal at the closest point; points on the grids (distance 0) count as outside. Points
        outside `cv_hull` (by more than 1e-9 of the size) are outside without a closest-point
        search: a thin object's box holds many such points (on `dog_head_spike`, 484 head vertices
        in the spike's box took 95 ms a round)."""
        q = np.asarray(q, np.float64).reshape(-1, 3)
        inside = np.zeros(len(q), bool)
        if not self.closed or not len(q):
            return inside, self.nearest(q[:0])
        cand = np.arange(len(q))
        if self.cv_hull is not None:
            slack = 1e-9 * self.surface.size()
            cand = np.nonzero((q @ self.cv_hull[:, :3].T + self.cv_hull[:, 3]).max(axis=1) <= slack)[0]
        near = self.nearest(q[cand])
        _, n = H.surface_normals(self.surface, near.uv[:, 0], near.uv[:, 1], det=self.details)
        side = self.outward * np.einsum("ij,ij->i", q[cand] - near.points, n) < 0
        inside[cand[side]] = True
        return inside, Nearest(near.distance[side], near.points[side], near.uv[side])

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hits ``(m, 3)`` of object-space rays ``origins, directions (n, 3)`` on the
        collision grids, the row of each hit ray ``(m,) int64``, and its distance along the
        (unnormalised) direction ``(m,)``. Only patches whose boxes the rays meet are tessellated."""
        lo, hi, patches = self._boxes
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / directions[:, None, :]
            t0, t1 = (lo[None] - origins[:, None]) * inv, (hi[None] - origins[:, None]) * inv
        t0, t1 = np.nan_to_num(t0, nan=-np.inf), np.nan_to_num(t1, nan=np.inf)  # 0/0: on the slab's plane
        near, far = np.minimum(t0, t1).max(axis=2), np.maximum(t0, t1).min(axis=2)
        meets = (far >= near) & (far >= 0)  # (n, P)
        hit = np.nonzero(meets.any(axis=0))[0]
        empty = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0)
        if not len(hit):
            return empty
        grids = self.grids_for(patches[hit])
        base = np.cumsum([0] + [len(g.points) for g in grids[:-1]])
        mesh = trimesh.Trimesh(np.concatenate([g.points for g in grids]),
                               np.concatenate([g.triangles[g.solid] + b for g, b in zip(grids, base)]), process=False)
        mesh.merge_vertices()  # patch borders are evaluated twice: share them, or rays slip through float32 cracks
        loc, ray, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
        # embree works in float32 and can let a ray through an edge it meets exactly: retry the
        # rays that met a box but no triangle in float64 (rare, so the slower intersector is fine)
        miss = np.setdiff1d(np.nonzero(meets.any(axis=1))[0], ray)
        if len(miss):
            more, row, _ = RayMeshIntersector(mesh).intersects_location(origins[miss], directions[miss], multiple_hits=False)
            loc, ray = np.concatenate([loc, np.reshape(more, (-1, 3))]), np.concatenate([ray, miss[np.asarray(row, np.int64)]])
        along = np.einsum("ij,ij->i", loc - origins[ray], directions[ray]) / np.einsum("ij,ij->i", directions[ray], directions[ray])
        return loc, ray, along


_SHAPES: dict = {}  # id(surface) -> (surface, density, max_density, Shape), most recent last
_SHAPES_KEPT = 64


def shape_of(surface: HSpline, density: int = 8, max_density: int = 64) -> Shape:
    """The `Shape` of ``surface`` (the same object for the same surface object and densities).

    Keyed by identity: surfaces are immutable, and the frame loop hands the same object back for
    unchanged input CVs. The most recent ``_SHAPES_KEPT`` shapes are kept."""
    key = id(surface)
    hit = _SHAPES.pop(key, None)
    if hit is None or hit[0] is not surface or hit[1:3] != (density, max_density):
        hit = (surface, density, max_density, Shape(surface, density, max_density))
    _SHAPES[key] = hit
    while len(_SHAPES) > _SHAPES_KEPT:
        del _SHAPES[next(iter(_SHAPES))]
    return hit[3]


def seed_details(surface: HSpline, details: H.Details | None, density: int = 8, max_density: int = 64,
                 parent: HSpline | None = None) -> None:
    """Give ``surface``'s `Shape` details computed elsewhere (by `acra.respond.respond`) and the
    shape it was responded from, whose grids it then reuses where it did not change."""
    shape = shape_of(surface, density, max_density)
    if details is not None and "details" not in shape.__dict__:
        shape.__dict__["details"] = details
    if parent is not None and shape.parent is None and not shape.grids:
        shape.parent = shape_of(parent, density, max_density)
