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

import time
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
    "FullMesh", "Shape", "SetupClock", "shape_of", "seed_details", "changed_patches", "Tessellation", "Intersections", "Region", "Projection", "Anchor", "PairContact",
    "Residual", "RewindCache", "patch_density", "candidate_patches", "tessellate", "tessellated",
    "full_mesh", "is_closed", "intersect", "inside", "surface_distance", "surface_points", "project",
    "regions", "touching", "rewind", "detect_pair", "residual", "cast", "default_tolerance",
]

_MAX_CONTACTS = 1_000_000
_COLLAPSE = 1e-6  # a grid line within this fraction of the object size is one point (a pole); float32 `acra:cvs` round at ~1e-7
_PAD = 1e-7  # box padding, fraction of the pair's size: exactly touching boxes still overlap
_US_PAIR, _US_BVH_FACE, _US_FCL_QUERY = 0.8, 3.5, 20.0  # measured costs (µs), see _Closest


# --- closest points on a triangle set ---------------------------------------------------------
class _Closest:
    """Exact closest points on triangles. The closest point is no farther than the nearest vertex
    (``d_v``), so its triangle's centroid is within ``d_v + reach`` (the largest centroid-corner
    distance): near points test that ball's triangles (kd-trees); deep points, whose ball covers
    much of a curved surface, query an fcl BVH of the triangles within ``d_v``, if cheaper."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, bvh: fcl.CollisionObject | None = None) -> None:
        self.vertices, self.faces, self.bvh = vertices, faces, bvh
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
        if len(deep) and bvh is None:  # a BVH of the triangles in reach, if cheaper than balls
            grow = dv[deep].max() * (1 + 1e-9)
            lo, hi = points[deep].min(axis=0) - grow, points[deep].max(axis=0) + grow
            rows = np.nonzero(_overlap(self.tri.min(axis=1), self.tri.max(axis=1), lo, hi, 0.0))[0]
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
            cp = self.unit * trimesh.triangles.closest_point(self.tri[idx] / self.unit, points[near][owner] / self.unit)
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


def _overlap(lo_a, hi_a, lo_b, hi_b, pad: float) -> np.ndarray:
    """Whether boxes overlap (broadcast over leading axes)."""
    return np.all((lo_a <= hi_b + pad) & (lo_b <= hi_a + pad), axis=-1)


# --- static collider data (once per run) and per-time geometry --------------------------------
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
    """A deformable's full-domain grid (`full_mesh`), in object space: ``mesh`` with vertices
    relative to ``origin (3,)`` (embree works in float32), degenerate faces removed; ``closed``;
    parameters of each face corner ``face_uv (f, 3, 2)``, unwrapped across a periodic seam. Map
    world points in and out with `SurfaceGeometry.to_mesh` / `SurfaceGeometry.from_mesh`."""

    mesh: trimesh.Trimesh
    origin: np.ndarray
    closed: bool
    face_uv: np.ndarray
    grid: np.ndarray | None = None  # (cu * cv, 3) object-space grid points, for `Shape` derivation
    grid_uv: np.ndarray | None = None  # (cu * cv, 2)

    @cached_property
    def index(self) -> _Closest:
        return _Closest(self.mesh.vertices, self.mesh.faces)


def changed_patches(old: HSpline, new: HSpline, margin: int = 2) -> np.ndarray:
    """Level-0 patches ``(P0u, P0v) bool`` where ``new`` may differ from ``old`` (same grid).

    A changed level-``k`` CV ``j`` (level-0 row, or an offset that differs or is new and non-zero)
    moves level-``k`` patches ``j-3 .. j``, i.e. level-0 patches ``(j-3)>>k .. j>>k``; ``margin``
    more patches cover finer details whose frames follow the moved surface (their support reaches
    less than one level-0 patch beyond) and grid vertices on patch borders."""
    mask = np.zeros((new.u.patches0, new.v.patches0), bool)
    hits = [(0, *np.nonzero(np.any(old.cvs != new.cvs, axis=-1)))]
    for k in range(1, new.depth):
        a, b = old.level(k), new.level(k)
        rows, found = H._lookup(a.cv_keys, b.cv_keys)
        same = np.zeros(b.cv_keys.size, bool)
        same[found] = np.all(a.offsets[rows[found]] == b.offsets[found], axis=-1)
        moved = ~same & (found | np.any(b.offsets != 0, axis=-1))
        hits.append((k, *H._split_cv(new, k, b.cv_keys[moved])))
    for k, ju, jv in hits:
        if not len(ju):
            continue
        lo_u, hi_u = ((ju - 3) >> k) - margin, (ju >> k) + margin
        lo_v, hi_v = ((jv - 3) >> k) - margin, (jv >> k) + margin
        for du in range(int((hi_u - lo_u).max()) + 1):
            for dv in range(int((hi_v - lo_v).max()) + 1):
                qu, qv = lo_u + du, lo_v + dv
                ok = (qu <= hi_u) & (qv <= hi_v)
                qu = np.mod(qu, new.u.patches0) if new.u.periodic else np.clip(qu, 0, new.u.patches0 - 1)
                qv = np.mod(qv, new.v.patches0) if new.v.periodic else np.clip(qv, 0, new.v.patches0 - 1)
                mask[qu[ok], qv[ok]] = True
    return mask


class SetupClock:
    """Milliseconds spent building `Shape` data (the thesis's "initial setup" of RAPID, Fig. 5.2):
    the frame loop reads it around detection to report set-up apart from the queries."""

    ms: float = 0.0


def _timed_setup(build):
    """Decorate a `Shape` builder so its time goes to `SetupClock`."""

    def timed(self):
        t = time.perf_counter()
        try:
            return build(self)
        finally:
            SetupClock.ms += 1e3 * (time.perf_counter() - t)

    timed.__name__, timed.__doc__ = build.__name__, build.__doc__
    return timed


class Shape:
    """Everything about a surface that does not depend on where it is: level details, patch hull
    boxes, collision grids and the full mesh with its ray and closest-point indices, all in object
    space. A deformable's input shape is the same at every time code unless its ``acra:cvs`` are
    keyed, so one `Shape` serves every frame and every rewinding step (`shape_of`); only the
    matrix changes. Built lazily, so what is never needed is never computed."""

    def __init__(self, surface: HSpline, density: int = 8, max_density: int = 64, parent: "Shape | None" = None) -> None:
        self.surface, self.density, self.max_density = surface, density, max_density
        self.grids: dict = {}  # (pu, pv) -> object points (n, 3), uv (n, 2), triangles (f, 3)
        self.parent = parent  # a shape this one differs from locally (a response of it)

    @cached_property
    @_timed_setup
    def details(self) -> H.Details | None:
        return H.details(self.surface) if self.surface.depth > 1 else None

    @cached_property
    @_timed_setup
    def hulls(self) -> tuple[np.ndarray, np.ndarray]:
        """Object-space boxes ``lo, hi (P0u, P0v, 3)`` of the level-0 patches' control hulls."""
        return patch_hulls(self.surface, self.details)

    @cached_property
    def density_map(self) -> np.ndarray:
        return _patch_density(self.surface, self.density, self.max_density)

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
            if np.ptp(H.evaluate(hs, *uv, det=self.details).points, axis=0).max() > _COLLAPSE * hs.size():
                return False
        return True

    def _reuse(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The parent's full-mesh grid and which of its points to re-evaluate, if the parent's
        full mesh exists and the grid is the same (same densities)."""
        p = self.parent
        if p is None or "full" not in p.__dict__ or p.full.grid is None:
            return None
        if p.density_map.shape != self.density_map.shape or np.any(p.density_map != self.density_map):
            return None
        mask = changed_patches(p.surface, self.surface)
        uv = p.full.grid_uv
        iu = np.clip(np.floor(uv[:, 0]).astype(np.int64), 0, mask.shape[0] - 1)
        iv = np.clip(np.floor(uv[:, 1]).astype(np.int64), 0, mask.shape[1] - 1)
        return p.full.grid, mask[iu, iv]

    @cached_property
    @_timed_setup
    def full(self) -> FullMesh:
        """The full mesh with its ray intersector and closest-point index built."""
        fm = _build_full_mesh(self, self._reuse())
        self.parent = None  # do not keep a chain of responded shapes alive
        if len(fm.mesh.faces):
            fm.mesh.ray.intersects_first(np.zeros((1, 3)), np.ones((1, 3)))  # build the embree scene now
            fm.index.vtree
        return fm


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
    shape it was responded from, whose full mesh it then updates only where it changed."""
    shape = shape_of(surface, density, max_density)
    if details is not None and "details" not in shape.__dict__:
        shape.__dict__["details"] = details
    if parent is not None and shape.parent is None and "full" not in shape.__dict__:
        shape.parent = shape_of(parent, density, max_density)


@dataclass(frozen=True, eq=False)
class SurfaceGeometry:
    """A deformable at one time: object-space ``surface``, ``xform (4, 4)``, collision density.
    Object-space data lives in its `Shape` (shared across times); world data is derived lazily
    and kept here, so pairs sharing an object share the work."""

    surface: HSpline
    xform: np.ndarray
    name: str = ""
    density: int = 8
    max_density: int = 64
    _patch_cache: dict = field(default_factory=dict, init=False, repr=False)

    @cached_property
    def shape(self) -> Shape:
        return shape_of(self.surface, self.density, self.max_density)

    @property
    def details(self) -> H.Details | None:
        return self.shape.details

    @cached_property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """World boxes ``lo, hi`` ``(P0u, P0v, 3)`` of the level-0 patches: hull boxes' 8 corners mapped."""
        lo, hi = self.shape.hulls
        sel = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], bool)  # (8, 3)
        corners = np.where(sel, hi[..., None, :], lo[..., None, :])  # (P0u, P0v, 8, 3)
        world = apply_xform(self.xform, corners.reshape(-1, 3)).reshape(corners.shape)
        return world.min(axis=-2), world.max(axis=-2)

    @cached_property
    def bounds(self) -> np.ndarray:
        """World box ``(2, 3)`` of the whole surface (union of the patch boxes)."""
        lo, hi = self.boxes
        return np.stack([lo.reshape(-1, 3).min(axis=0), hi.reshape(-1, 3).max(axis=0)])

    @cached_property
    def size(self) -> float:
        return float(np.linalg.norm(self.bounds[1] - self.bounds[0]))

    @property
    def closed(self) -> bool:
        return self.shape.closed

    @property
    def _full(self) -> FullMesh:
        return self.shape.full

    @cached_property
    def _inverse(self) -> np.ndarray:
        return np.linalg.inv(self.xform)

    def to_mesh(self, points: np.ndarray) -> np.ndarray:
        """World points ``(k, 3)`` in the full mesh's frame (object space less its origin)."""
        return apply_xform(self._inverse, points) - self.shape.full.origin

    def from_mesh(self, points: np.ndarray) -> np.ndarray:
        """Full-mesh-frame points ``(k, 3)`` in world space."""
        return apply_xform(self.xform, points + self.shape.full.origin)


Geometry = Union[SurfaceGeometry, ColliderGeometry]


def patch_density(geom: SurfaceGeometry) -> np.ndarray:
    """Steps per edge of each level-0 patch ``(P0u, P0v) int64``: ``max(density, 2 * 2**k)``, ``k``
    the finest level with an active patch inside it, capped at ``max_density``."""
    return geom.shape.density_map


def _patch_density(hs: HSpline, density: int, max_density: int) -> np.ndarray:
    finest = np.zeros((hs.u.patches0, hs.v.patches0), np.int64)
    for lev in hs.fine:
        if lev.patches.size:
            npv = hs.v.patches(lev.k)
            finest[(lev.patches // npv) >> lev.k, (lev.patches % npv) >> lev.k] = lev.k
    return np.minimum(np.maximum(density, 2 * (1 << finest)), max_density)


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
    """Collision grids over level-0 ``patches (m, 2) int64`` at their `patch_density`, cached per
    patch on ``geom`` (grids of different density meet at T-junctions, gaps ~ tessellation error)."""
    patches = np.unique(np.asarray(patches, np.int64).reshape(-1, 2), axis=0)
    cache, shape = geom._patch_cache, geom.shape
    grids, dens = shape.grids, shape.density_map
    missing = np.array([p for p in patches if (p[0], p[1]) not in grids], np.int64).reshape(-1, 2)
    steps = dens[missing[:, 0], missing[:, 1]]
    for s in np.unique(steps):
        sel, n = missing[steps == s], (int(s) + 1) ** 2
        pts, uv, _, _ = patch_grids(geom.surface, sel, int(s), det=shape.details)
        for r, p in enumerate(sel):
            grids[(p[0], p[1])] = (pts[r * n:(r + 1) * n], uv[r * n:(r + 1) * n], _grid_triangles(int(s)))
    todo = [(p[0], p[1]) for p in patches if (p[0], p[1]) not in cache]
    if todo:
        obj = [grids[p] for p in todo]
        world = apply_xform(geom.xform, np.concatenate([g[0] for g in obj]))
        for p, g, w in zip(todo, obj, np.split(world, np.cumsum([len(g[0]) for g in obj[:-1]]))):
            cache[p] = (w, g[1], g[2])
    if not len(patches):
        return Tessellation(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
    grids = [cache[(p[0], p[1])] for p in patches]
    base = np.cumsum([0] + [len(g[0]) for g in grids[:-1]])
    return Tessellation(
        np.concatenate([g[0] for g in grids]), np.concatenate([g[1] for g in grids]),
        np.concatenate([g[2] + b for g, b in zip(grids, base)]),
        np.repeat(patches, [len(g[2]) for g in grids], axis=0))


def tessellated(geom: SurfaceGeometry) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` tessellated so far on ``geom`` (broad-phase audit)."""
    return np.array(sorted(geom._patch_cache), np.int64).reshape(-1, 2)


def full_mesh(geom: SurfaceGeometry) -> FullMesh:
    """The whole surface as one mesh (cached), watertight if closed: a rectilinear grid as fine as
    the densest patch of each patch column (row); poles merged into one vertex, seams shared."""
    return geom._full


def _axis(d: Direction, steps: np.ndarray) -> np.ndarray:
    """Vertex parameters along one direction with ``steps[p]`` steps in patch ``p``, end included."""
    return np.concatenate([p + np.arange(s) / s for p, s in enumerate(steps)] + [[float(d.patches0)]])


def _build_full_mesh(shape: Shape, reuse: tuple[np.ndarray, np.ndarray] | None = None) -> FullMesh:
    """``reuse = (grid (n, 3), stale (n,) bool)``: a parent's grid points, of which only the stale
    ones are evaluated again (a response changes a surface locally)."""
    hs, dens = shape.surface, shape.density_map
    au, av = _axis(hs.u, dens.max(axis=1)), _axis(hs.v, dens.max(axis=0))
    cu, cv = len(au) - hs.u.periodic, len(av) - hs.v.periodic  # distinct vertex lines
    uu, vv = np.meshgrid(au[:cu], av[:cv], indexing="ij")
    grid_uv = np.stack([uu.reshape(-1), vv.reshape(-1)], axis=1)
    if reuse is None:
        obj = H.evaluate(hs, grid_uv[:, 0], grid_uv[:, 1], det=shape.details).points
    else:
        obj, stale = reuse[0].copy(), reuse[1]
        obj[stale] = H.evaluate(hs, grid_uv[stale, 0], grid_uv[stale, 1], det=shape.details).points
    grid, rep = obj.reshape(cu, cv, 3), np.arange(cu * cv).reshape(cu, cv)
    tol = _COLLAPSE * hs.size()
    for j in np.nonzero(np.ptp(grid, axis=0).max(axis=-1) <= tol)[0]:  # a line of constant v is a pole
        rep[:, j] = rep[0, j]
    for i in np.nonzero(np.ptp(grid, axis=1).max(axis=-1) <= tol)[0]:
        rep[i, :] = rep[i, 0]
    i, j = np.arange(len(au) - 1)[:, None], np.arange(len(av) - 1)[None, :]
    quads = np.stack(np.broadcast_arrays(*(rep[a % cu, b % cv] for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)))), -1)
    u0, v0, u1, v1 = np.broadcast_arrays(au[i], av[j], au[i + 1], av[j + 1])
    quv = np.stack([np.stack(c, -1) for c in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))], 2)
    quads, quv = quads.reshape(-1, 4), quv.reshape(-1, 4, 2)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    face_uv = np.concatenate([quv[:, [0, 1, 2]], quv[:, [0, 2, 3]]])
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    origin = 0.5 * (obj.min(axis=0) + obj.max(axis=0))
    mesh = trimesh.Trimesh(obj - origin, faces[keep], process=False)
    return FullMesh(mesh, origin, shape.closed, face_uv[keep], obj, grid_uv)


def is_closed(geom: Geometry) -> bool:
    """Whether ``geom`` has an inside (`SurfaceGeometry.closed`, `ColliderStatic.closed`)."""
    return geom.static.closed if isinstance(geom, ColliderGeometry) else geom.closed


# --- narrow phase -------------------------------------------------------------------------------
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


def _boxes_overlap(ga: Geometry, gb: Geometry, pad: float) -> bool:
    return bool(_overlap(ga.bounds[0], ga.bounds[1], gb.bounds[0], gb.bounds[1], pad))


def _triangles_near(pa: np.ndarray, fa: np.ndarray, pb: np.ndarray, fb: np.ndarray, pad: float, rounds: int = 2):
    """Rows of ``fa``/``fb`` whose triangle boxes overlap the box of the other side's kept ones."""
    boxes = [(p[f].min(axis=1), p[f].max(axis=1)) for p, f in ((pa, fa), (pb, fb))]
    keep = [np.ones(len(fa), bool), np.ones(len(fb), bool)]
    for _ in range(rounds):
        for me, other in ((0, 1), (1, 0)):
            if keep[other].any():
                lo, hi = boxes[other][0][keep[other]].min(axis=0), boxes[other][1][keep[other]].max(axis=0)
                keep[me] &= _overlap(boxes[me][0], boxes[me][1], lo, hi, pad)
            else:
                keep[me][:] = False
    return np.nonzero(keep[0])[0], np.nonzero(keep[1])[0]


def intersect(ga: SurfaceGeometry, gb: Geometry) -> Intersections:
    """Triangle pairs where the surfaces cross or touch. Tessellates only patches whose boxes meet
    the other object's box; ``A``'s triangles go into a collider's object space (crossing is
    affine-invariant), where its BVH was built once."""
    collider = isinstance(gb, ColliderGeometry)
    pad = _pad(ga, gb)
    empty = np.zeros((0, 2), np.int64)
    none = Intersections(np.zeros((0, 3)), empty, None if collider else empty, np.zeros(0, np.int64))
    if not _boxes_overlap(ga, gb, pad):
        return none
    ca = candidate_patches(ga, gb.bounds, pad)
    if not collider:
        cb = candidate_patches(gb, ga.bounds, pad)
        (la, ha), (lb, hb) = ga.boxes, gb.boxes
        ov = _overlap(la[ca[:, 0], ca[:, 1]][:, None], ha[ca[:, 0], ca[:, 1]][:, None],
                      lb[cb[:, 0], cb[:, 1]][None], hb[cb[:, 0], cb[:, 1]][None], pad)
        ca, cb = ca[ov.any(axis=1)], cb[ov.any(axis=0)]
    if not len(ca):
        return none
    ta = tessellate(ga, ca)
    if collider:
        pa, pb, fb_all, ob = apply_inverse(gb.xform, ta.points), gb.static.mesh.vertices, gb.static.mesh.faces, gb.static.bvh
    else:
        tb = tessellate(gb, cb)
        pa, pb, fb_all = ta.points, tb.points, tb.triangles
    ka, kb = _triangles_near(pa, ta.triangles, pb, fb_all, pad)
    if not len(ka):
        return none
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


# --- inside tests, distances, projections -------------------------------------------------------
def inside(geom: Geometry, points: np.ndarray) -> np.ndarray:
    """Which world ``points (k, 3)`` lie inside ``geom``: ``(k,) bool``, all False if it is open.
    Ray parity on the watertight mesh (embree); points on the surface may go either way."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(points) or not is_closed(geom):
        return np.zeros(len(points), bool)
    # trimesh re-casts rays of points it finds ambiguous (on the surface, which every response
    # produces) in a random direction from a shared generator: reseed it, so a run is reproducible
    if hasattr(trimesh.util, "_RANDOM_DEFAULT"):
        trimesh.util._RANDOM_DEFAULT = np.random.default_rng(20260311)
    if isinstance(geom, ColliderGeometry):
        return geom.static.mesh.contains(apply_inverse(geom.xform, points))
    return full_mesh(geom).mesh.contains(geom.to_mesh(points))


def surface_distance(geom: Geometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances ``(k,)`` from world ``points (k, 3)`` to ``geom``'s tessellated surface, and the
    closest points ``(k, 3)``. A collider is queried in object space: exact for a similarity
    matrix (rotation, uniform scale, translation), an upper bound under non-uniform scale. A
    deformable is queried the same way, in its `Shape`'s object space."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        close = apply_xform(geom.xform, geom.static.index.query(apply_inverse(geom.xform, points))[1])
    else:
        close = geom.from_mesh(full_mesh(geom).index.query(geom.to_mesh(points))[1])
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
    """World points and world-space partial derivatives up to ``order`` at ``uv (k, 2)``."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    ev = H.evaluate(geom.surface, uv[:, 0], uv[:, 1], order=order, det=geom.details)
    lin = {k: None if x is None else x @ geom.xform[:3, :3].T for k, x in vars(ev).items() if k != "points"}
    return H.SurfaceEval(apply_xform(geom.xform, ev.points), **lin)


def _newton(geom: SurfaceGeometry, targets: np.ndarray, uv: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Newton on ``|S(u, v) - target|^2 / 2`` with the full Hessian ``J^T J + r . S''`` (Gauss–Newton
    is only linear, rate depth / curvature radius, deep on the concave side), shifted positive; a
    step is kept if it gets closer or, the distance flat to rounding, shrinks the gradient."""
    hs, uv = geom.surface, _wrap_uv(geom.surface, uv)
    ev = surface_points(geom, uv, order=2)
    r = ev.points - targets
    dist = np.linalg.norm(r, axis=1)
    cap = 0.5 / geom.density  # stay near the tessellation cell the start came from
    flat_tol = 1e-14 * (np.abs(targets).max(axis=1) + geom.size)  # rounding of |r|

    def grad(e, res):
        return np.stack([np.einsum("ka,ka->k", res, e.du), np.einsum("ka,ka->k", res, e.dv)], axis=1)

    g = grad(ev, r)
    for _ in range(iters):
        J = np.stack([ev.du, ev.dv], 2)
        Hs = np.einsum("kai,kaj->kij", J, J)
        Hs += np.stack([np.einsum("ka,ka->k", r, x) for x in (ev.duu, ev.duv, ev.dvv)], axis=1)[:, [[0, 1], [1, 2]]]
        lo = np.linalg.eigvalsh(Hs)[:, 0]
        Hs += np.maximum(1e-9 * np.trace(Hs, axis1=1, axis2=2) + 1e-300 - lo, 0.0)[:, None, None] * np.eye(2)
        step = -np.linalg.solve(Hs, g[..., None])[..., 0]
        step *= np.minimum(1.0, cap / np.maximum(np.linalg.norm(step, axis=1), 1e-300))[:, None]
        cand = _wrap_uv(hs, uv + step)
        ec = surface_points(geom, cand, order=2)
        rc = ec.points - targets
        dc, gc = np.linalg.norm(rc, axis=1), grad(ec, rc)
        shrinks = (dc <= dist + flat_tol) & (np.abs(gc).max(axis=1) < np.abs(g).max(axis=1))
        ok = np.isfinite(dc) & ((dc < dist) | shrinks)
        if not ok.any():
            break
        uv[ok], dist[ok], r[ok], g[ok] = cand[ok], dc[ok], rc[ok], gc[ok]
        for name in ("points", "du", "dv", "duu", "duv", "dvv"):
            getattr(ev, name)[ok] = getattr(ec, name)[ok]
    return uv, ev.points


def project(geom: Geometry, points: np.ndarray, newton: int = 8) -> Projection:
    """Closest points on ``geom`` to world ``points (k, 3)``. On a deformable: the full mesh's
    closest point, its ``(u, v)`` from the face corners, then ``newton`` steps on the H-spline."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        local = geom.static.index.query(apply_inverse(geom.xform, points))[1]
        world = apply_xform(geom.xform, local)
        return Projection(world, np.linalg.norm(world - points, axis=1), None, local)
    fm = full_mesh(geom)
    _, close, face = fm.index.query(geom.to_mesh(points))
    bary = trimesh.triangles.points_to_barycentric(fm.mesh.triangles[face], close)
    uv, world = _newton(geom, points, np.einsum("kj,kjc->kc", bary, fm.face_uv[face]), newton)
    return Projection(world, np.linalg.norm(world - points, axis=1), uv, None)


# --- interpenetration regions -------------------------------------------------------------------
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


def regions(ga: SurfaceGeometry, gb: Geometry, depth: bool = True) -> tuple[Region, Region]:
    """The interpenetration regions: ``A``'s vertices inside ``B`` and ``B``'s inside ``A`` (empty
    when the other object is open). ``depth=False`` leaves depths at zero."""
    pad, out = _pad(ga, gb), []
    for x, y in ((ga, gb), (gb, ga)):
        if not is_closed(y) or not _boxes_overlap(x, y, pad):
            out.append(Region(None if isinstance(x, ColliderGeometry) else np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0)))
            continue
        pts, uv = _candidate_vertices(x, y.bounds, pad)
        m = inside(y, pts)
        d = surface_distance(y, pts[m])[0] if depth else np.zeros(int(m.sum()))
        out.append(Region(None if uv is None else uv[m], pts[m], d))
    return out[0], out[1]


def touching(ga: SurfaceGeometry, gb: Geometry) -> bool:
    """Whether the pair touches or interpenetrates. Without crossing triangles each surface is wholly
    inside or outside the other: outside if any of it leaves the other's box, else 5 vertices vote."""
    pad = _pad(ga, gb)
    if not _boxes_overlap(ga, gb, pad):
        return False
    if intersect(ga, gb).count:
        return True
    for x, y in ((ga, gb), (gb, ga)):
        if not is_closed(y):
            continue
        if isinstance(x, SurfaceGeometry):
            if len(candidate_patches(x, y.bounds, pad)) < x.surface.u.patches0 * x.surface.v.patches0:
                continue
        elif not np.all((x.vertices >= y.bounds[0] - pad) & (x.vertices <= y.bounds[1] + pad)):
            continue
        pts, _ = _candidate_vertices(x, y.bounds, pad)
        sample = pts[np.linspace(0, len(pts) - 1, min(5, len(pts))).astype(np.int64)]
        if len(sample) and 2 * inside(y, sample).sum() > len(sample):
            return True
    return False


# --- contact rewinding --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Anchor:
    """Where a pair first touched: the first touching time ``t_contact`` (at most ``2**-steps``
    frames late), the contact's parameters ``uv_a (2,)`` on ``A`` and ``uv_b (2,)`` on a deformable
    ``B`` (else ``None``), its object-space point ``local_b (3,)`` on a collider (else ``None``),
    and the world ``point (3,)`` it was anchored at (at ``t_contact``)."""

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
    """The deepest (central among equals) vertex of a (tiny) interpenetration, else the centre of
    the crossing triangles' contacts, projected onto both surfaces."""
    ra, rb = regions(ga, gb)
    if not (ra.empty and rb.empty):
        deeper = rb if ra.empty or rb.max_depth > ra.max_depth else ra
        centre = deeper.points[_deepest(deeper, 1e-9 * max(ga.size, gb.size))]
    else:
        inter = intersect(ga, gb)
        if not inter.count:
            return None
        centre = inter.points.mean(axis=0)
    pa, pb = project(ga, centre[None]), project(gb, centre[None])
    return Anchor(float(t), pa.uv[0], None if pb.uv is None else pb.uv[0], None if pb.local is None else pb.local[0], centre)


def rewind(geometry_at: GeometryAt, t: float, start: float | None = None, cache: RewindCache | None = None,
           max_back: int = 10_000, steps: int = 12) -> Anchor | None:
    """First contact of the input motion before ``t`` (``None`` without an earlier free time):
    ``geometry_at(time)`` gives the input geometry (no response) at any time. Steps back whole
    frames (``max_back``, not before ``start``) to the last free time, bisects ``steps`` times up
    to the next frame and anchors the contact at the first touching time."""
    cache = RewindCache() if cache is None else cache

    def hit(x: float) -> bool:
        if x not in cache.touching:
            cache.touching[x] = touching(*geometry_at(x))
        return cache.touching[x]

    if not hit(float(t)):
        return None  # the input is free at t: the contact is the response's doing
    lo, hi = None, float(t)
    for k in range(1, max_back + 1):
        if start is not None and t - k < start:
            break
        if not hit(float(t - k)):
            lo = float(t - k)
            break
        hi = float(t - k)
    if lo is None:
        return None
    if (lo, hi) not in cache.anchors:
        a, b = lo, hi
        for _ in range(steps):
            mid = 0.5 * (a + b)
            a, b = (a, mid) if touching(*geometry_at(mid)) else (mid, b)
        cache.anchors[(lo, hi)] = _anchor_at(*geometry_at(b), b)
    return cache.anchors[(lo, hi)]


# --- the frame loop's entry points --------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PairContact:
    """Detection of one pair at time ``t`` (world units): names ``a``, ``b`` (``A`` deformable);
    ``t_contact``, the first touching time if ``rewound`` (else ``t``, deepest-point fallback);
    contact parameters ``uv_a (2,)`` and ``uv_b (2,)`` (``None`` for a collider ``B``); the
    collider's contact material point ``local_b (3,)`` (object space, else ``None``); ``P_A``,
    ``P_B`` = ``point_a, point_b (3,)``, those material points at time ``t``; ``region_a`` (``A``'s
    vertices inside ``B``), ``region_b``; ``depth``, the largest region depth (0 if the surfaces
    only cross); ``intersections``, the crossing triangle pairs at ``t``."""

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
    """``uv_a, uv_b, local_b, P_A, P_B`` from the deepest (central among equals) region vertex and
    its closest point on the other surface, or the crossing centre's when both regions are empty."""
    tol = 1e-9 * max(ga.size, gb.size)
    if not rb.empty and (ra.empty or rb.max_depth > ra.max_depth):
        i = _deepest(rb, tol)
        pa, pb = project(ga, rb.points[i][None]), rb.points[i]
        local_b = apply_inverse(gb.xform, pb[None])[0] if isinstance(gb, ColliderGeometry) else None
        return pa.uv[0], None if rb.uv is None else rb.uv[i], local_b, pa.points[0], pb
    if not ra.empty:
        i = _deepest(ra, tol)
        uv_a, pa, pb = ra.uv[i], ra.points[i], project(gb, ra.points[i][None])
    else:
        centre = inter.points.mean(axis=0)[None]
        pr = project(ga, centre)
        uv_a, pa, pb = pr.uv[0], pr.points[0], project(gb, centre)
    return uv_a, None if pb.uv is None else pb.uv[0], None if pb.local is None else pb.local[0], pa, pb.points[0]


def detect_pair(ga: SurfaceGeometry, gb: Geometry, t: float = 0.0, geometry_at: GeometryAt | None = None, *,
                start: float | None = None, cache: RewindCache | None = None, max_back: int = 10_000,
                steps: int = 12) -> PairContact | None:
    """Detect a pair at time ``t``, ``None`` if it neither touches nor interpenetrates. ``ga``/``gb``:
    current geometry (possibly responded); ``geometry_at``: the input at any time, for `rewind`
    (else, or with no earlier free time, the deepest-point fallback). ``P_A``/``P_B`` are the
    anchor's material points on the current geometry."""
    if not isinstance(ga, SurfaceGeometry):
        raise TypeError("A must be a deformable SurfaceGeometry (collider–collider pairs are never tested)")
    inter = intersect(ga, gb)
    ra, rb = regions(ga, gb)
    if inter.count == 0 and ra.empty and rb.empty:
        return None
    anchor = None if geometry_at is None else rewind(geometry_at, t, start, cache, max_back, steps)
    if anchor is not None:
        uv_a, uv_b, local_b, t_c = anchor.uv_a, anchor.uv_b, anchor.local_b, anchor.t_contact
        pa = surface_points(ga, uv_a).points[0]
        pb = apply_xform(gb.xform, local_b[None])[0] if local_b is not None else surface_points(gb, uv_b).points[0]
    else:
        (uv_a, uv_b, local_b, pa, pb), t_c = _fallback(ga, gb, ra, rb, inter), float(t)
    depth = max(ra.max_depth, rb.max_depth)
    return PairContact(ga.name, gb.name, float(t), t_c, anchor is not None, uv_a, uv_b, local_b, pa, pb, ra, rb, depth, inter)


@dataclass(frozen=True)
class Residual:
    """Penetration left in a pair: largest and mean region depth, and the region vertex count."""

    max: float
    mean: float
    count: int


def residual(ga: SurfaceGeometry, gb: Geometry) -> Residual:
    """Depths of ``A``'s vertices inside ``B`` and ``B``'s inside ``A`` (0 for a free pair)."""
    ra, rb = regions(ga, gb)
    d = np.concatenate([ra.depth, rb.depth])
    return Residual(float(d.max()) if d.size else 0.0, float(d.mean()) if d.size else 0.0, int(d.size))


def default_tolerance(ga: Geometry, gb: Geometry, fraction: float = 1e-3) -> float:
    """Residual tolerance: ``fraction`` of the smaller object's size (box diagonal)."""
    return fraction * min(ga.size, gb.size)


def cast(geom: Geometry, origins: np.ndarray, directions: np.ndarray, behind: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First hits of world rays ``origins, directions (n, 3)`` on ``geom`` (thesis eq. 4.16):
    ``hits (n, 3)`` (the origin where none) and ``valid (n,) bool``. A hit may lie up to ``behind``
    (default ``1e-3`` of the object's size) behind its origin, for points pushed just past the
    surface, except from inside a closed ``geom``: there it must be ahead (the exit)."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    hits, valid = origins.copy(), np.zeros(len(origins), bool)
    length = np.linalg.norm(directions, axis=1)
    rows = np.nonzero(length > 0)[0]
    if not len(rows):
        return hits, valid
    unit = directions[rows] / length[rows, None]
    behind = 1e-3 * geom.size if behind is None else float(behind)
    start = origins[rows] - np.where(inside(geom, origins[rows]), 0.0, behind)[:, None] * unit
    if isinstance(geom, ColliderGeometry):
        mesh, o, d, back = geom.static.mesh, apply_inverse(geom.xform, start), unit @ np.linalg.inv(geom.xform[:3, :3]).T, geom.xform
    else:
        fm = full_mesh(geom)
        back = geom.xform.copy()
        back[:3, 3] += geom.xform[:3, :3] @ fm.origin
        mesh, o, d = fm.mesh, geom.to_mesh(start), unit @ np.linalg.inv(geom.xform[:3, :3]).T
    loc, ray, _ = mesh.ray.intersects_location(o, d, multiple_hits=False)
    hits[rows[ray]], valid[rows[ray]] = apply_xform(back, loc), True
    return hits, valid
