"""Collision detection for ACRA: what touches, what is inside, where it first touched (notes §4).

A pair is a deformable ``A`` (`SurfaceGeometry`: object-space H-spline + 4×4 matrix) and a
deformable or rigid collider ``B`` (`ColliderGeometry`: a run-constant `ColliderStatic` + matrix).
Broad phase on level-0 patch boxes (convex-hull property) → fcl narrow phase on the tessellated
candidate patches (`intersect`) → inside tests by ray parity on watertight meshes with exact
depths (`regions`; an open ``B`` has no inside) → contact rewound along the input motion to the
first touch (`rewind`, fallback: deepest point) → `detect_pair`, `residual`, `cast`.
docs/detection.md gives the definitions, the reasons and the timings. World units; arrays are
float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Callable, Union

import fcl
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from acra import hspline as H
from acra.basis import Direction
from acra.hspline import HSpline
from acra.tessellate import patch_grids, patch_hulls
from pipeline.model import ColliderModel, apply_inverse, apply_xform

__all__ = [
    "ColliderStatic", "prepare_collider", "SurfaceGeometry", "ColliderGeometry", "Geometry",
    "FullMesh", "Tessellation", "Intersections", "Region", "Projection", "Anchor", "PairContact",
    "Residual", "RewindCache", "patch_density", "candidate_patches", "tessellate", "tessellated",
    "full_mesh", "is_closed", "intersect", "inside", "surface_distance", "project", "regions",
    "touching", "rewind", "detect_pair", "residual", "cast", "default_tolerance",
]

_MAX_CONTACTS = 1_000_000
_COLLAPSE = 1e-12  # a grid line within this fraction of the object size is one point (a pole)
_PAD = 1e-7  # box padding, fraction of the pair's size: exactly touching boxes still overlap
# measured costs (µs) that choose between kd-tree candidates and an fcl BVH for closest points
_US_PAIR, _US_BVH_FACE, _US_FCL_QUERY = 0.8, 3.5, 20.0


# --------------------------------------------------------------------------------------------
# closest points on a triangle set


class _Closest:
    """Exact closest points on a triangle set.

    The closest point is no farther than the nearest vertex (``d_v``), so its triangle has its
    centroid within ``d_v + reach`` (``reach``: the largest centroid-to-corner distance) and lies
    in the box of the query points grown by ``max d_v``. Points near the surface test the
    triangles of that ball (kd-trees); deep points, whose ball holds much of a curved surface,
    query an fcl BVH (about 20 µs each) of the triangles in that box, whichever is cheaper by
    the measured costs. A collider passes its run-long BVH.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, bvh: fcl.CollisionObject | None = None) -> None:
        self.vertices, self.faces, self.bvh = vertices, faces, bvh
        self.tri = vertices[faces]  # (f, 3, 3)
        cen = self.tri.mean(axis=1)
        self.reach = float(np.linalg.norm(self.tri - cen[:, None], axis=2).max()) if len(cen) else 0.0
        self.vtree = cKDTree(vertices[np.unique(faces)])
        self._cen = cen

    @cached_property
    def ctree(self) -> cKDTree:
        return cKDTree(self._cen)

    @cached_property
    def tri_box(self) -> tuple[np.ndarray, np.ndarray]:
        return self.tri.min(axis=1), self.tri.max(axis=1)

    def query(self, points: np.ndarray):
        """Distances ``(k,)``, closest points ``(k, 3)`` and face rows ``(k,) int64``."""
        k = points.shape[0]
        dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
        if k == 0:
            return dist, close, face
        dv, _ = self.vtree.query(points)
        radius = dv + self.reach * (1 + 1e-9) + 1e-300
        ball = dv <= 2.0 * self.reach
        deep = np.nonzero(~ball)[0]
        bvh, rows = self.bvh, None
        if len(deep) and bvh is None:  # a BVH of the triangles in reach, if that is cheaper
            grow = dv[deep].max() * (1 + 1e-9)
            lo, hi = points[deep].min(axis=0) - grow, points[deep].max(axis=0) + grow
            rows = np.nonzero(_overlap(*self.tri_box, lo, hi, 0.0))[0]
            pairs = self.ctree.query_ball_point(points[deep], radius[deep], return_length=True).sum()
            ball[deep] = pairs * _US_PAIR < _US_BVH_FACE * len(rows) + _US_FCL_QUERY * len(deep)
            if not ball[deep].all():
                bvh = _bvh(self.vertices, self.faces[rows])
        near = np.nonzero(ball)[0]
        if len(near):
            lists = self.ctree.query_ball_point(points[near], radius[near])
            lens = np.fromiter((len(x) for x in lists), np.int64, len(near))
            idx = np.fromiter((i for x in lists for i in x), np.int64, int(lens.sum()))
            owner = np.repeat(np.arange(len(near)), lens)
            cp = trimesh.triangles.closest_point(self.tri[idx], points[near][owner])
            d = np.linalg.norm(cp - points[near][owner], axis=1)
            order = np.lexsort((d, owner))  # per owner, nearest first
            first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
            hit = near[owner[first]]
            dist[hit], close[hit], face[hit] = d[first], cp[first], idx[first]
        probe, req = fcl.Sphere(0.0), fcl.DistanceRequest(enable_nearest_points=True)
        for i in np.nonzero(~ball)[0]:
            res = fcl.DistanceResult()  # mesh first: b1 is its face, nearest_points[0] on it
            dist[i] = fcl.distance(bvh, fcl.CollisionObject(probe, fcl.Transform(points[i])), req, res)
            close[i], face[i] = res.nearest_points[0], res.b1 if rows is None else rows[res.b1]
        return dist, close, face


def _bvh(vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int32))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def _corners_box(xform: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World boxes of object-space boxes ``(..., 3)``: their 8 corners mapped by ``xform``."""
    sel = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], bool)  # (8, 3)
    corners = np.where(sel, hi[..., None, :], lo[..., None, :])  # (..., 8, 3)
    world = apply_xform(xform, corners.reshape(-1, 3)).reshape(corners.shape)
    return world.min(axis=-2), world.max(axis=-2)


def _overlap(lo_a, hi_a, lo_b, hi_b, pad: float) -> np.ndarray:
    """Whether boxes overlap (broadcast over leading axes)."""
    return np.all((lo_a <= hi_b + pad) & (lo_b <= hi_a + pad), axis=-1)


# --------------------------------------------------------------------------------------------
# static collider data (once per run) and per-time geometry


@dataclass(frozen=True, eq=False)
class ColliderStatic:
    """A collider's run-constant data in its object space: merged non-degenerate ``mesh`` (its
    embree ``ray`` intersector built once), its fcl ``bvh`` (identity transform), ``closed``
    (watertight, so it has an inside)."""

    path: str
    mesh: trimesh.Trimesh
    bvh: fcl.CollisionObject
    closed: bool

    @cached_property
    def index(self) -> _Closest:
        return _Closest(self.mesh.vertices, self.mesh.faces, self.bvh)


def prepare_collider(model: ColliderModel) -> ColliderStatic:
    """Build a collider's BVH, ray intersector and closest-point index once per run."""
    mesh = trimesh.Trimesh(np.asarray(model.vertices, np.float64), np.asarray(model.triangles, np.int64), process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    static = ColliderStatic(model.path, mesh, _bvh(mesh.vertices, mesh.faces), bool(mesh.is_watertight))
    static.mesh.ray.intersects_first(np.zeros((1, 3)), np.ones((1, 3)))  # build the embree scene now
    return static


@dataclass(frozen=True, eq=False)
class ColliderGeometry:
    """A collider at one time: its static data and object-to-world matrix ``xform (4, 4)``."""

    static: ColliderStatic
    xform: np.ndarray

    @property
    def name(self) -> str:
        return self.static.path

    @cached_property
    def vertices(self) -> np.ndarray:
        """World vertices ``(n, 3)``."""
        return apply_xform(self.xform, self.static.mesh.vertices)

    @cached_property
    def bounds(self) -> np.ndarray:
        """World box ``(2, 3)``: min and max corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @cached_property
    def size(self) -> float:
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))


@dataclass(frozen=True, eq=False)
class Tessellation:
    """Independent triangle grids over level-0 patches: world ``points (n, 3)``, their parameters
    ``uv (n, 2)`` (level-0 units), ``triangles (f, 3) int64``, level-0 patch of each triangle
    ``tri_patch (f, 2) int64``."""

    points: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray
    tri_patch: np.ndarray


@dataclass(frozen=True, eq=False)
class FullMesh:
    """A deformable's full-domain grid (`full_mesh`): ``mesh`` with vertices relative to ``origin
    (3,)`` (embree works in float32), degenerate faces removed; ``closed``; parameters of each
    face corner ``face_uv (f, 3, 2)``, unwrapped across a periodic seam."""

    mesh: trimesh.Trimesh
    origin: np.ndarray
    closed: bool
    face_uv: np.ndarray

    @cached_property
    def index(self) -> _Closest:
        return _Closest(self.mesh.vertices, self.mesh.faces)


@dataclass(frozen=True, eq=False)
class SurfaceGeometry:
    """A deformable at one time: object-space surface, ``xform (4, 4)``, collision density.

    Everything derived (details, world patch boxes, patch tessellations, the full mesh) is built
    lazily and kept on the instance, so several pairs sharing an object share the work.
    """

    surface: HSpline
    xform: np.ndarray
    name: str = ""
    density: int = 8
    max_density: int = 64

    @cached_property
    def details(self) -> H.Details | None:
        return H.details(self.surface) if self.surface.depth > 1 else None

    @cached_property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """World boxes of every level-0 patch: ``lo, hi`` each ``(P0u, P0v, 3)``."""
        lo, hi = patch_hulls(self.surface, self.details)
        return _corners_box(self.xform, lo, hi)

    @cached_property
    def bounds(self) -> np.ndarray:
        """World box ``(2, 3)`` of the whole surface (union of the patch boxes)."""
        lo, hi = self.boxes
        return np.stack([lo.reshape(-1, 3).min(axis=0), hi.reshape(-1, 3).max(axis=0)])

    @cached_property
    def size(self) -> float:
        return float(np.linalg.norm(self.bounds[1] - self.bounds[0]))

    @cached_property
    def _patch_cache(self) -> dict:
        return {}

    @cached_property
    def _full(self) -> FullMesh:
        return _build_full_mesh(self)

    @cached_property
    def closed(self) -> bool:
        """Periodic both ways, or one way with both ends of the other collapsed (poles).

        A cubic is fixed by 4 points per segment, so 4 coincident samples per patch along an end
        line mean the whole line collapses.
        """
        hs = self.surface
        if hs.u.periodic == hs.v.periodic:
            return hs.u.periodic
        per, end = (hs.u, hs.v) if hs.u.periodic else (hs.v, hs.u)
        run = np.arange(4 * per.patches0) / 4.0
        for e in (0.0, float(end.patches0)):
            uv = (run, np.full_like(run, e)) if hs.u.periodic else (np.full_like(run, e), run)
            line = H.evaluate(hs, *uv, det=self.details).points
            if np.ptp(line, axis=0).max() > _COLLAPSE * max(hs.size(), 1e-300):
                return False
        return True


Geometry = Union[SurfaceGeometry, ColliderGeometry]


def patch_density(geom: SurfaceGeometry) -> np.ndarray:
    """Steps per edge of each level-0 patch: ``(P0u, P0v) int64``.

    ``max(density, 2 * 2**k)`` with ``k`` the finest level that has an active patch inside the
    level-0 patch, capped at ``max_density``.
    """
    hs = geom.surface
    finest = np.zeros((hs.u.patches0, hs.v.patches0), np.int64)
    for lev in hs.fine:
        if lev.patches.size:
            npv = hs.v.patches(lev.k)
            finest[lev.patches // npv >> lev.k, lev.patches % npv >> lev.k] = lev.k
    return np.minimum(np.maximum(geom.density, 2 * (1 << finest)), geom.max_density)


def candidate_patches(geom: SurfaceGeometry, bounds: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` whose world box overlaps ``bounds (2, 3)``."""
    lo, hi = geom.boxes
    return np.argwhere(_overlap(lo, hi, bounds[0], bounds[1], pad)).astype(np.int64)


@lru_cache(maxsize=None)
def _grid_triangles(s: int) -> np.ndarray:
    i, j = np.arange(s)[:, None], np.arange(s)[None, :]
    a, b = i * (s + 1) + j, (i + 1) * (s + 1) + j
    return np.stack(np.broadcast_arrays(a, b, b + 1, a, b + 1, a + 1), axis=-1).reshape(-1, 3)


def tessellate(geom: SurfaceGeometry, patches: np.ndarray) -> Tessellation:
    """Collision grids over level-0 ``patches (m, 2) int64``, each at its `patch_density`.

    Grids are cached per patch on ``geom``; neighbouring grids of different density meet with
    T-junctions (gaps of the order of the tessellation error), which fcl tolerates.
    """
    patches = np.unique(np.asarray(patches, np.int64).reshape(-1, 2), axis=0)
    cache = geom._patch_cache
    dens = patch_density(geom)
    missing = np.array([p for p in patches if (p[0], p[1]) not in cache], np.int64).reshape(-1, 2)
    if len(missing):
        sm = dens[missing[:, 0], missing[:, 1]]
        for s in np.unique(sm):
            sel = missing[sm == s]
            pts, uv, _, _ = patch_grids(geom.surface, sel, int(s), det=geom.details)
            pts = apply_xform(geom.xform, pts)
            n = (int(s) + 1) ** 2
            for r, p in enumerate(sel):
                cache[(p[0], p[1])] = (pts[r * n:(r + 1) * n], uv[r * n:(r + 1) * n], int(s))
    pts, uvs, tris, tp, base = [], [], [], [], 0
    for p in patches:
        q, uv, s = cache[(p[0], p[1])]
        t = _grid_triangles(s)
        pts.append(q), uvs.append(uv), tris.append(t + base), tp.append(np.broadcast_to(p, (len(t), 2)))
        base += len(q)
    if not len(patches):
        return Tessellation(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
    return Tessellation(np.concatenate(pts), np.concatenate(uvs), np.concatenate(tris), np.concatenate(tp))


def tessellated(geom: SurfaceGeometry) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` tessellated so far on ``geom`` (broad-phase audit)."""
    return np.array(sorted(geom._patch_cache), np.int64).reshape(-1, 2)


def _axis(d: Direction, steps: np.ndarray) -> np.ndarray:
    """Vertex parameters along one direction with ``steps[p]`` steps in patch ``p``, end included."""
    return np.concatenate([p + np.arange(s) / s for p, s in enumerate(steps)] + [[float(d.patches0)]])


def full_mesh(geom: SurfaceGeometry) -> FullMesh:
    """The whole surface as one mesh (cached on ``geom``): watertight for a closed object.

    A rectilinear grid whose steps per patch column (row) are the largest `patch_density` in it,
    so it is as fine as the patch grids wherever they are used. Grid lines that collapse to one
    point (a pole) are merged into one vertex; the periodic seam is shared.
    """
    return geom._full


def _build_full_mesh(geom: SurfaceGeometry) -> FullMesh:
    hs, dens = geom.surface, patch_density(geom)
    au, av = _axis(hs.u, dens.max(axis=1)), _axis(hs.v, dens.max(axis=0))
    cu, cv = len(au) - hs.u.periodic, len(av) - hs.v.periodic  # distinct vertex lines
    uu, vv = np.meshgrid(au[:cu], av[:cv], indexing="ij")
    obj = H.evaluate(hs, uu.reshape(-1), vv.reshape(-1), det=geom.details).points
    rep = np.arange(cu * cv).reshape(cu, cv)
    tol = _COLLAPSE * max(hs.size(), 1e-300)
    grid = obj.reshape(cu, cv, 3)
    for j in np.nonzero(np.ptp(grid, axis=0).max(axis=-1) <= tol)[0]:  # a v-row collapsed (pole)
        rep[:, j] = rep[0, j]
    for i in np.nonzero(np.ptp(grid, axis=1).max(axis=-1) <= tol)[0]:
        rep[i, :] = rep[i, 0]
    i = np.arange(len(au) - 1)[:, None]
    j = np.arange(len(av) - 1)[None, :]
    idx = lambda a, b: rep[a % cu, b % cv]  # noqa: E731
    quads = np.stack(np.broadcast_arrays(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)), -1).reshape(-1, 4)
    u0, v0, u1, v1 = np.broadcast_arrays(au[i], av[j], au[i + 1], av[j + 1])
    quv = np.stack([np.stack(c, -1) for c in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))], 2).reshape(-1, 4, 2)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    face_uv = np.concatenate([quv[:, [0, 1, 2]], quv[:, [0, 2, 3]]])
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    world = apply_xform(geom.xform, obj)
    origin = geom.bounds.mean(axis=0)
    mesh = trimesh.Trimesh(world - origin, faces[keep], process=False)
    return FullMesh(mesh, origin, geom.closed, face_uv[keep])


def is_closed(geom: Geometry) -> bool:
    """Whether ``geom`` has an inside (`SurfaceGeometry.closed`, `ColliderStatic.closed`)."""
    return geom.static.closed if isinstance(geom, ColliderGeometry) else geom.closed


# --------------------------------------------------------------------------------------------
# narrow phase


@dataclass(frozen=True, eq=False)
class Intersections:
    """Crossing triangle pairs (fcl): world contact ``points (k, 3)``; level-0 patch of ``A``'s
    triangle ``patch_a (k, 2) int64`` and of ``B``'s ``patch_b`` (``None`` for a collider); the
    collider's face ``face_b (k,) int64`` (row of ``ColliderStatic.mesh.faces``, else ``-1``)."""

    points: np.ndarray
    patch_a: np.ndarray
    patch_b: np.ndarray | None
    face_b: np.ndarray

    @property
    def count(self) -> int:
        return int(self.points.shape[0])


def _pad(ga: Geometry, gb: Geometry) -> float:
    return _PAD * max(ga.size, gb.size)


def _no_intersections(collider: bool) -> Intersections:
    return Intersections(np.zeros((0, 3)), np.zeros((0, 2), np.int64), None if collider else np.zeros((0, 2), np.int64), np.zeros(0, np.int64))


def _boxes_overlap(ga: Geometry, gb: Geometry, pad: float) -> bool:
    return bool(_overlap(ga.bounds[0], ga.bounds[1], gb.bounds[0], gb.bounds[1], pad))


def _triangles_near(pa: np.ndarray, fa: np.ndarray, pb: np.ndarray, fb: np.ndarray, pad: float, rounds: int = 2):
    """Rows of ``fa``/``fb`` whose triangle boxes overlap the box of the other side's kept ones."""
    boxes = [(p[f].min(axis=1), p[f].max(axis=1)) for p, f in ((pa, fa), (pb, fb))]
    keep = [np.ones(len(fa), bool), np.ones(len(fb), bool)]
    for _ in range(rounds):
        for me, other in ((0, 1), (1, 0)):
            if not keep[other].any():
                keep[me][:] = False
                continue
            lo, hi = boxes[other][0][keep[other]].min(axis=0), boxes[other][1][keep[other]].max(axis=0)
            keep[me] &= _overlap(boxes[me][0], boxes[me][1], lo, hi, pad)
    return np.nonzero(keep[0])[0], np.nonzero(keep[1])[0]


def intersect(ga: SurfaceGeometry, gb: Geometry) -> Intersections:
    """Triangle pairs where the surfaces cross (touching and coplanar contact included).

    Tessellates only the patches of ``A`` (and ``B``) whose boxes overlap the other object's box,
    keeps those overlapping a patch box of the other side, and gives fcl only the triangles whose
    boxes overlap the box of the other side's remaining triangles (so BVHs stay small).
    """
    collider = isinstance(gb, ColliderGeometry)
    pad = _pad(ga, gb)
    if not _boxes_overlap(ga, gb, pad):
        return _no_intersections(collider)
    ca = candidate_patches(ga, gb.bounds, pad)
    if not collider:
        cb = candidate_patches(gb, ga.bounds, pad)
        (la, ha), (lb, hb) = ga.boxes, gb.boxes
        ov = _overlap(la[ca[:, 0], ca[:, 1]][:, None], ha[ca[:, 0], ca[:, 1]][:, None],
                      lb[cb[:, 0], cb[:, 1]][None], hb[cb[:, 0], cb[:, 1]][None], pad)
        ca, cb = ca[ov.any(axis=1)], cb[ov.any(axis=0)]
    if not len(ca):
        return _no_intersections(collider)
    ta = tessellate(ga, ca)
    if collider:  # in the collider's object space, where its BVH was built once
        pa, (pb, fb_all, ob) = apply_inverse(gb.xform, ta.points), (gb.static.mesh.vertices, gb.static.mesh.faces, gb.static.bvh)
    else:
        tb = tessellate(gb, cb)
        pa, pb, fb_all = ta.points, tb.points, tb.triangles
    ka, kb = _triangles_near(pa, ta.triangles, pb, fb_all, pad)
    if not len(ka):
        return _no_intersections(collider)
    oa = _bvh(pa, ta.triangles[ka])
    if not collider:
        ob = _bvh(pb, fb_all[kb])
    res = fcl.CollisionResult()
    fcl.collide(oa, ob, fcl.CollisionRequest(num_max_contacts=_MAX_CONTACTS, enable_contact=True), res)
    n = len(res.contacts)
    fa = ka[np.fromiter((c.b1 for c in res.contacts), np.int64, n)]
    fb = np.fromiter((c.b2 for c in res.contacts), np.int64, n)
    pos = np.array([c.pos for c in res.contacts], np.float64).reshape(-1, 3)
    if collider:
        return Intersections(apply_xform(gb.xform, pos), ta.tri_patch[fa], None, fb)
    return Intersections(pos, ta.tri_patch[fa], tb.tri_patch[kb[fb]], np.full(n, -1, np.int64))


# --------------------------------------------------------------------------------------------
# inside tests, distances, projections


def inside(geom: Geometry, points: np.ndarray) -> np.ndarray:
    """Which world ``points (k, 3)`` lie inside ``geom``: ``(k,) bool`` (all False if open).

    Ray parity on the watertight mesh (embree); points on the surface may go either way.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(points) or not is_closed(geom):
        return np.zeros(len(points), bool)
    if isinstance(geom, ColliderGeometry):
        return geom.static.mesh.contains(apply_inverse(geom.xform, points))
    fm = full_mesh(geom)
    return fm.mesh.contains(points - fm.origin)


def surface_distance(geom: Geometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``(k,)`` from world ``points (k, 3)`` to ``geom``'s surface, and the closest points.

    Exact on the tessellation. For a collider the closest point is found in object space and
    mapped to world: exact when the matrix is a similarity (rotation, uniform scale,
    translation), an upper bound under non-uniform scale or shear.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        _, close, _ = geom.static.index.query(apply_inverse(geom.xform, points))
        close = apply_xform(geom.xform, close)
    else:
        fm = full_mesh(geom)
        _, close, _ = fm.index.query(points - fm.origin)
        close = close + fm.origin
    return np.linalg.norm(points - close, axis=1), close


@dataclass(frozen=True, eq=False)
class Projection:
    """Closest surface points: world ``points (k, 3)``, ``distance (k,)``, parameters ``uv (k, 2)``
    on a deformable (else ``None``), object-space material points ``local (k, 3)`` on a collider
    (else ``None``)."""

    points: np.ndarray
    distance: np.ndarray
    uv: np.ndarray | None
    local: np.ndarray | None


def _wrap_uv(hs: HSpline, uv: np.ndarray) -> np.ndarray:
    out = uv.copy()
    for c, d in enumerate((hs.u, hs.v)):
        out[:, c] = np.mod(out[:, c], d.patches0) if d.periodic else np.clip(out[:, c], 0.0, d.patches0)
    return out


def surface_points(geom: SurfaceGeometry, uv: np.ndarray, order: int = 0) -> H.SurfaceEval:
    """World points (and world-space partial derivatives up to ``order``) at ``uv (k, 2)``."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    ev = H.evaluate(geom.surface, uv[:, 0], uv[:, 1], order=order, det=geom.details)
    L = geom.xform[:3, :3]
    lin = {k: None if x is None else x @ L.T for k, x in vars(ev).items() if k != "points"}
    return H.SurfaceEval(apply_xform(geom.xform, ev.points), **lin)


def _newton(geom: SurfaceGeometry, targets: np.ndarray, uv: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Newton on ``|S(u, v) - target|^2 / 2`` with full Hessian ``J^T J + r . S''``.

    Gauss–Newton alone converges only linearly (rate depth / curvature radius) for points deep on
    the concave side. The Hessian is shifted to stay positive; a step is kept if it gets closer,
    or, once the distance is flat to rounding, if it shrinks the gradient ``J^T r``.
    """
    hs = geom.surface
    uv = _wrap_uv(hs, uv)
    ev = surface_points(geom, uv, order=2)
    r = ev.points - targets
    dist = np.linalg.norm(r, axis=1)
    cap = 0.5 / geom.density  # stay within the tessellation cell the start came from

    def grad(e, res):
        return np.stack([np.einsum("ka,ka->k", res, e.du), np.einsum("ka,ka->k", res, e.dv)], axis=1)

    g = grad(ev, r)
    for _ in range(iters):
        Hs = np.einsum("kai,kaj->kij", np.stack([ev.du, ev.dv], 2), np.stack([ev.du, ev.dv], 2))
        Hs += np.stack([np.einsum("ka,ka->k", r, x) for x in (ev.duu, ev.duv, ev.dvv)], axis=1)[:, [[0, 1], [1, 2]]]
        lo = np.linalg.eigvalsh(Hs)[:, 0]
        Hs += np.maximum(1e-9 * np.trace(Hs, axis1=1, axis2=2) + 1e-300 - lo, 0.0)[:, None, None] * np.eye(2)
        step = -np.linalg.solve(Hs, g[..., None])[..., 0]
        step *= np.minimum(1.0, cap / np.maximum(np.linalg.norm(step, axis=1), 1e-300))[:, None]
        cand = _wrap_uv(hs, uv + step)
        ec = surface_points(geom, cand, order=2)
        rc = ec.points - targets
        dc, gc = np.linalg.norm(rc, axis=1), grad(ec, rc)
        flat = dc <= dist + 1e-14 * (np.abs(targets).max(axis=1) + geom.size)  # rounding of |r|
        ok = np.isfinite(dc) & ((dc < dist) | (flat & (np.abs(gc).max(axis=1) < np.abs(g).max(axis=1))))
        if not ok.any():
            break
        uv[ok], dist[ok], r[ok], g[ok] = cand[ok], dc[ok], rc[ok], gc[ok]
        for name in ("points", "du", "dv", "duu", "duv", "dvv"):
            getattr(ev, name)[ok] = getattr(ec, name)[ok]
    return uv, ev.points


def project(geom: Geometry, points: np.ndarray, newton: int = 8) -> Projection:
    """Closest points on ``geom`` to world ``points (k, 3)``.

    On a deformable: the closest point of the full mesh, its ``(u, v)`` interpolated from the
    face corners, then ``newton`` Gauss–Newton steps on the H-spline itself.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        _, local, _ = geom.static.index.query(apply_inverse(geom.xform, points))
        world = apply_xform(geom.xform, local)
        return Projection(world, np.linalg.norm(world - points, axis=1), None, local)
    fm = full_mesh(geom)
    _, close, face = fm.index.query(points - fm.origin)
    bary = trimesh.triangles.points_to_barycentric(fm.mesh.triangles[face], close)
    uv0 = np.einsum("kj,kjc->kc", bary, fm.face_uv[face])
    uv, world = _newton(geom, points, uv0, newton)
    return Projection(world, np.linalg.norm(world - points, axis=1), uv, None)


# --------------------------------------------------------------------------------------------
# interpenetration regions


@dataclass(frozen=True, eq=False)
class Region:
    """Tessellation vertices of one object inside the other: parameters ``uv (k, 2)`` (``None``
    on a collider), world ``points (k, 3)``, ``depth (k,)`` = distance to the other surface."""

    uv: np.ndarray | None
    points: np.ndarray
    depth: np.ndarray

    @property
    def empty(self) -> bool:
        return self.points.shape[0] == 0

    @property
    def max_depth(self) -> float:
        return float(self.depth.max()) if self.depth.size else 0.0


def _candidate_vertices(geom: Geometry, bounds: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Distinct tessellation vertices of ``geom`` within ``bounds``: world ``(k, 3)``, uv or None."""
    if isinstance(geom, ColliderGeometry):
        pts, uv = geom.vertices, None
    else:
        tess = tessellate(geom, candidate_patches(geom, bounds, pad))
        _, first = np.unique(_wrap_uv(geom.surface, tess.uv), axis=0, return_index=True)
        pts, uv = tess.points[first], tess.uv[first]
    keep = np.all((pts >= bounds[0] - pad) & (pts <= bounds[1] + pad), axis=1)
    return pts[keep], None if uv is None else uv[keep]


def _empty_region(geom: Geometry) -> Region:
    return Region(None if isinstance(geom, ColliderGeometry) else np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0))


def regions(ga: SurfaceGeometry, gb: Geometry, depth: bool = True) -> tuple[Region, Region]:
    """The interpenetration regions: ``A``'s vertices inside ``B`` and ``B``'s inside ``A``.

    A region is empty when the other object is open (no inside). ``depth=False`` skips the
    distances (zeros), for yes/no questions.
    """
    pad = _pad(ga, gb)
    out = []
    for x, y in ((ga, gb), (gb, ga)):
        if not is_closed(y) or not _boxes_overlap(x, y, pad):
            out.append(_empty_region(x))
            continue
        pts, uv = _candidate_vertices(x, y.bounds, pad)
        m = inside(y, pts)
        d = surface_distance(y, pts[m])[0] if depth else np.zeros(int(m.sum()))
        out.append(Region(None if uv is None else uv[m], pts[m], d))
    return out[0], out[1]


def touching(ga: SurfaceGeometry, gb: Geometry) -> bool:
    """Whether the pair touches or interpenetrates.

    Without crossing triangles each surface lies wholly inside or wholly outside the other: it
    is outside if any of it is outside the other's box (a patch box or a collider vertex), else
    a few vertices decide (majority, in case one sits on the other surface).
    """
    pad = _pad(ga, gb)
    if not _boxes_overlap(ga, gb, pad):
        return False
    if intersect(ga, gb).count:
        return True
    for x, y in ((ga, gb), (gb, ga)):
        if is_closed(y):
            if isinstance(x, SurfaceGeometry):
                if len(candidate_patches(x, y.bounds, pad)) < x.surface.u.patches0 * x.surface.v.patches0:
                    continue
            elif not np.all((x.vertices >= y.bounds[0] - pad) & (x.vertices <= y.bounds[1] + pad)):
                continue
            pts, _ = _candidate_vertices(x, y.bounds, pad)
            if len(pts):
                sample = pts[np.linspace(0, len(pts) - 1, min(5, len(pts))).astype(np.int64)]
                if 2 * inside(y, sample).sum() > len(sample):
                    return True
    return False


# --------------------------------------------------------------------------------------------
# contact rewinding


@dataclass(frozen=True, eq=False)
class Anchor:
    """Where a pair first touched: the first touching time ``t_contact`` (at most ``2**-steps``
    frames late), the contact's parameters ``uv_a (2,)`` on ``A`` and ``uv_b (2,)`` on a deformable
    ``B`` (else ``None``), its object-space point ``local_b (3,)`` on a collider (else ``None``),
    and the world centre ``point (3,)`` of the intersection at ``t_contact``."""

    t_contact: float
    uv_a: np.ndarray
    uv_b: np.ndarray | None
    local_b: np.ndarray | None
    point: np.ndarray


@dataclass
class RewindCache:
    """Per pair and run, so frames share the search: `touching` of the input by time
    (``dict[float, bool]``) and the `Anchor` of each ``(free frame, touching frame)`` interval."""

    touching: dict = field(default_factory=dict)
    anchors: dict = field(default_factory=dict)


GeometryAt = Callable[[float], "tuple[SurfaceGeometry, Geometry]"]


def _anchor_at(ga: SurfaceGeometry, gb: Geometry, t: float) -> Anchor | None:
    """The central point of a (tiny) intersection and its material points on both surfaces."""
    inter = intersect(ga, gb)
    if inter.count:
        centre = inter.points.mean(axis=0)
    else:
        ra, rb = regions(ga, gb, depth=False)
        pts = np.concatenate([ra.points, rb.points])
        if not len(pts):
            return None
        centre = pts.mean(axis=0)
    pa, pb = project(ga, centre[None]), project(gb, centre[None])
    return Anchor(float(t), pa.uv[0], None if pb.uv is None else pb.uv[0], None if pb.local is None else pb.local[0], centre)


def rewind(
    geometry_at: GeometryAt,
    t: float,
    start: float | None = None,
    cache: RewindCache | None = None,
    max_back: int = 8,
    steps: int = 12,
) -> Anchor | None:
    """First contact of the input motion before ``t``, or ``None`` if there is no earlier free time.

    Steps back whole frames (at most ``max_back``, never before ``start``) to the last time the
    pair did not touch, bisects ``steps`` times between it and the next frame, and anchors the
    contact at the first touching time (`_anchor_at`). ``geometry_at(time)`` returns the pair's
    geometry (the animator's, before any response) at any time code.
    """
    cache = RewindCache() if cache is None else cache

    def hit(x: float) -> bool:
        if x not in cache.touching:
            cache.touching[x] = touching(*geometry_at(x))
        return cache.touching[x]

    if not hit(t):
        return None  # the input is free at t: the contact is the response's doing
    lo, hi = None, float(t)
    for k in range(1, max_back + 1):
        x = float(t - k)
        if start is not None and x < start:
            break
        if not hit(x):
            lo = x
            break
        hi = x
    if lo is None:
        return None
    if (lo, hi) not in cache.anchors:
        a, b = lo, hi
        for _ in range(steps):
            mid = 0.5 * (a + b)
            if touching(*geometry_at(mid)):
                b = mid
            else:
                a = mid
        cache.anchors[(lo, hi)] = _anchor_at(*geometry_at(b), b)
    return cache.anchors[(lo, hi)]


# --------------------------------------------------------------------------------------------
# the frame loop's entry points


@dataclass(frozen=True, eq=False)
class PairContact:
    """Detection of one pair at time ``t`` (world units).

    Attributes
    ----------
    a, b : str — names (prim paths) of ``A`` (deformable) and ``B``
    t_contact : float — first touching time if ``rewound``, else ``t``
    rewound : bool — contact from rewinding (else the deepest-point fallback)
    uv_a : (2,) float64 — contact parameters on ``A``
    uv_b : (2,) float64 or None — contact parameters on a deformable ``B``
    local_b : (3,) float64 or None — contact material point (object space) on a collider ``B``
    point_a, point_b : (3,) float64 — ``P_A``, ``P_B``: those material points at time ``t``
    region_a, region_b : Region — ``A``'s vertices inside ``B``, ``B``'s inside ``A``, at ``t``
    depth : float — largest region depth (``0`` when the surfaces only cross)
    intersections : Intersections — crossing triangle pairs at ``t``
    """

    a: str
    b: str
    t: float
    t_contact: float
    rewound: bool
    uv_a: np.ndarray
    uv_b: np.ndarray | None
    local_b: np.ndarray | None
    point_a: np.ndarray
    point_b: np.ndarray
    region_a: Region
    region_b: Region
    depth: float
    intersections: Intersections


def _deepest(region: Region, tol: float) -> int:
    """Row of the deepest vertex; among ties (within ``tol``) the one nearest their centroid."""
    tied = np.nonzero(region.depth >= region.max_depth - tol)[0]
    pts = region.points[tied]
    return int(tied[np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))])


def _fallback(ga: SurfaceGeometry, gb: Geometry, ra: Region, rb: Region, inter: Intersections):
    """Deepest region vertex and its closest point on the other surface (or the crossing centre)."""
    collider = isinstance(gb, ColliderGeometry)
    tol = 1e-9 * max(ga.size, gb.size)
    if not ra.empty and ra.max_depth >= rb.max_depth:
        i = _deepest(ra, tol)
        pb = project(gb, ra.points[i][None])
        uv_b = None if pb.uv is None else pb.uv[0]
        local_b = None if pb.local is None else pb.local[0]
        return ra.uv[i], uv_b, local_b, ra.points[i], pb.points[0]
    if not rb.empty:
        i = _deepest(rb, tol)
        pa = project(ga, rb.points[i][None])
        local_b = apply_inverse(gb.xform, rb.points[i][None])[0] if collider else None
        return pa.uv[0], None if collider else rb.uv[i], local_b, pa.points[0], rb.points[i]
    centre = inter.points.mean(axis=0)[None]
    pa, pb = project(ga, centre), project(gb, centre)
    return pa.uv[0], None if pb.uv is None else pb.uv[0], None if pb.local is None else pb.local[0], pa.points[0], pb.points[0]


def detect_pair(
    ga: SurfaceGeometry,
    gb: Geometry,
    t: float = 0.0,
    geometry_at: GeometryAt | None = None,
    *,
    start: float | None = None,
    cache: RewindCache | None = None,
    max_back: int = 8,
    steps: int = 12,
) -> PairContact | None:
    """Detect a pair at time ``t``: ``None`` if it neither touches nor interpenetrates.

    ``ga``/``gb`` are the pair's current geometry (possibly already responded); ``geometry_at``
    gives the animator's input at any time for `rewind` (omit it to use the deepest-point
    fallback). ``P_A``/``P_B`` are the rewound material points evaluated on the current geometry.
    """
    if not isinstance(ga, SurfaceGeometry):
        raise TypeError("A must be a deformable SurfaceGeometry (collider–collider pairs are never tested)")
    inter = intersect(ga, gb)
    ra, rb = regions(ga, gb)
    if inter.count == 0 and ra.empty and rb.empty:
        return None
    anchor = None if geometry_at is None else rewind(geometry_at, t, start, cache, max_back, steps)
    if anchor is not None:
        uv_a, uv_b, local_b = anchor.uv_a, anchor.uv_b, anchor.local_b
        pa = surface_points(ga, uv_a).points[0]
        if isinstance(gb, ColliderGeometry):
            pb = apply_xform(gb.xform, local_b[None])[0]
        else:
            pb = surface_points(gb, uv_b).points[0]
        t_c = anchor.t_contact
    else:
        uv_a, uv_b, local_b, pa, pb = _fallback(ga, gb, ra, rb, inter)
        t_c = float(t)
    depth = max(ra.max_depth, rb.max_depth)
    return PairContact(ga.name, gb.name, float(t), t_c, anchor is not None, uv_a, uv_b, local_b, pa, pb, ra, rb, depth, inter)


@dataclass(frozen=True)
class Residual:
    """Remaining penetration of a pair: largest and mean region depth, and the vertex count."""

    max: float
    mean: float
    count: int


def residual(ga: SurfaceGeometry, gb: Geometry) -> Residual:
    """Penetration left: depths of ``A``'s vertices inside ``B`` and ``B``'s inside ``A``."""
    ra, rb = regions(ga, gb)
    d = np.concatenate([ra.depth, rb.depth])
    return Residual(float(d.max()) if d.size else 0.0, float(d.mean()) if d.size else 0.0, int(d.size))


def default_tolerance(ga: Geometry, gb: Geometry, fraction: float = 1e-3) -> float:
    """Residual tolerance: ``fraction`` of the smaller object's size (box diagonal)."""
    return fraction * min(ga.size, gb.size)


def cast(
    geom: Geometry, origins: np.ndarray, directions: np.ndarray, behind: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """First hits of world rays ``origins, directions (n, 3)`` on ``geom`` (thesis eq. 4.16).

    A hit may lie up to ``behind`` (default ``1e-3`` of the object's size) behind its origin, for
    points pushed just past the surface, except from inside a closed ``geom``, where it must be
    ahead (the exit, not the entry behind). Returns ``hits (n, 3)`` (the origin where none) and
    ``valid (n,) bool``.
    """
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    hits, valid = origins.copy(), np.zeros(len(origins), bool)
    length = np.linalg.norm(directions, axis=1)
    ok = length > 0
    if not ok.any():
        return hits, valid
    unit = np.zeros_like(directions)
    unit[ok] = directions[ok] / length[ok, None]
    behind = 1e-3 * geom.size if behind is None else float(behind)
    back = np.where(inside(geom, origins), 0.0, behind)
    start = origins - back[:, None] * unit
    if isinstance(geom, ColliderGeometry):
        mesh, o, d = geom.static.mesh, apply_inverse(geom.xform, start), unit @ np.linalg.inv(geom.xform[:3, :3]).T
    else:
        fm = full_mesh(geom)
        mesh, o, d = fm.mesh, start - fm.origin, unit
    rows = np.nonzero(ok)[0]
    loc, ray, _ = mesh.ray.intersects_location(o[rows], d[rows], multiple_hits=False)
    rays = rows[ray]
    hits[rays] = apply_xform(geom.xform, loc) if isinstance(geom, ColliderGeometry) else loc + fm.origin
    valid[rays] = True
    return hits, valid
