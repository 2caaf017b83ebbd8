"""Collision detection for ACRA: what touches, what is inside, where it first touched (notes §4).

A pair is a deformable ``A`` (`SurfaceGeometry`: object-space H-spline + 4×4 matrix) and a
deformable or rigid collider ``B`` (`ColliderGeometry`: a run-constant `ColliderStatic` + matrix).
Broad phase on level-0 patch boxes (convex-hull property) → fcl narrow phase on the tessellated
candidate patches (`intersect`) → inside tests and depths from closest points, answered on the
patches near the query (`pipeline.shape.Shape`) or the collider's mesh (`regions`; an open ``B``
has no inside) → contact rewound along the input motion to the
first touch (`rewind`, fallback: the way out the whole region needs least, `exit_contact`, or
the deepest point, `deepest_contact`) → `detect_pair`, `residual`, `cast`.
docs/detection.md gives the definitions, the reasons and the timings. World units; arrays are
float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Union

import fcl
import numpy as np
import trimesh

from acra import hspline as H
from acra.hspline import HSpline
from pipeline.model import ColliderModel, apply_inverse, apply_xform
from pipeline.shape import Closest, Shape, bvh as _bvh, overlap as _overlap, shape_of

__all__ = [
    "ColliderStatic", "prepare_collider", "SurfaceGeometry", "ColliderGeometry", "Geometry",
    "Tessellation", "Intersections", "Region", "Projection", "Anchor", "PairContact",
    "Residual", "RewindCache", "patch_density", "candidate_patches", "tessellate", "tessellated",
    "is_closed", "intersect", "inside", "surface_distance", "surface_points", "project",
    "regions", "touching", "rewind", "depth_along", "deepest_contact", "exit_contact", "detect_pair", "residual",
    "cast", "default_tolerance", "face_samples",
]

_MAX_CONTACTS = 1_000_000
_PAD = 1e-7  # box padding, fraction of the pair's size: exactly touching boxes still overlap


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
    def index(self) -> Closest:
        return Closest(self.mesh.vertices, self.mesh.faces, self.bvh)


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

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """World points ``(k, 3)`` in object space."""
        return apply_inverse(self.xform, points)


Geometry = Union[SurfaceGeometry, ColliderGeometry]


def patch_density(geom: SurfaceGeometry) -> np.ndarray:
    """Steps per edge of each level-0 patch ``(P0u, P0v) int64``: ``max(density, 2 * 2**k)``, ``k``
    the finest level with an active patch inside it, capped at ``max_density``."""
    return geom.shape.density_map


def candidate_patches(geom: SurfaceGeometry, bounds: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` whose world box overlaps ``bounds (2, 3)``."""
    lo, hi = geom.boxes
    return np.argwhere(_overlap(lo, hi, bounds[0], bounds[1], pad)).astype(np.int64)


def tessellate(geom: SurfaceGeometry, patches: np.ndarray) -> Tessellation:
    """Collision grids over level-0 ``patches (m, 2) int64`` at their `patch_density`, cached per
    patch on ``geom`` (grids of different density meet at T-junctions, gaps ~ tessellation error)."""
    patches = np.unique(np.asarray(patches, np.int64).reshape(-1, 2), axis=0)
    if not len(patches):
        return Tessellation(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
    cache = geom._patch_cache
    todo = [(int(p[0]), int(p[1])) for p in patches if (p[0], p[1]) not in cache]
    if todo:
        obj = geom.shape.grids_for(np.array(todo, np.int64))
        world = apply_xform(geom.xform, np.concatenate([g.points for g in obj]))
        for p, g, w in zip(todo, obj, np.split(world, np.cumsum([len(g.points) for g in obj[:-1]]))):
            cache[p] = (w, g.uv, g.triangles)
    grids = [cache[(p[0], p[1])] for p in patches]
    base = np.cumsum([0] + [len(g[0]) for g in grids[:-1]])
    return Tessellation(
        np.concatenate([g[0] for g in grids]), np.concatenate([g[1] for g in grids]),
        np.concatenate([g[2] + b for g, b in zip(grids, base)]),
        np.repeat(patches, [len(g[2]) for g in grids], axis=0))


def tessellated(geom: SurfaceGeometry) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` tessellated so far on ``geom`` (broad-phase audit)."""
    return np.array(sorted(geom._patch_cache), np.int64).reshape(-1, 2)


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
    A collider: ray parity on its watertight mesh (embree); a deformable: behind the outward
    normal at the closest point of its collision grids (`Shape.signed`). Points on the surface
    may go either way."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(points) or not is_closed(geom):
        return np.zeros(len(points), bool)
    if isinstance(geom, SurfaceGeometry):
        return geom.shape.signed(geom.to_object(points))[0]
    # trimesh re-casts rays of points it finds ambiguous (on the surface, which every response
    # produces) in a random direction from a shared generator: reseed it, so a run is reproducible
    if hasattr(trimesh.util, "_RANDOM_DEFAULT"):
        trimesh.util._RANDOM_DEFAULT = np.random.default_rng(20260311)
    return geom.static.mesh.contains(apply_inverse(geom.xform, points))


def surface_distance(geom: Geometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances ``(k,)`` from world ``points (k, 3)`` to ``geom``'s tessellated surface, and the
    closest points ``(k, 3)``. Queried in object space: exact for a similarity matrix (rotation,
    uniform scale, translation), an upper bound under non-uniform scale."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        close = apply_xform(geom.xform, geom.static.index.query(apply_inverse(geom.xform, points))[1])
    else:
        close = apply_xform(geom.xform, geom.shape.nearest(geom.to_object(points)).points)
    return np.linalg.norm(points - close, axis=1), close


def _inside_depth(geom: Geometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`inside` ``(k,) bool`` and, for the points inside, their `surface_distance` ``(m,)``: one
    closest-point query on a deformable."""
    if isinstance(geom, SurfaceGeometry) and len(points) and geom.closed:
        m, near = geom.shape.signed(geom.to_object(points))
        return m, np.linalg.norm(points[m] - apply_xform(geom.xform, near.points), axis=1)
    m = inside(geom, points)
    return m, surface_distance(geom, points[m])[0]


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
    """Closest points on ``geom`` to world ``points (k, 3)``. On a deformable: the collision grids'
    closest point, its ``(u, v)`` from the face corners, then ``newton`` steps on the H-spline."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if isinstance(geom, ColliderGeometry):
        local = geom.static.index.query(apply_inverse(geom.xform, points))[1]
        world = apply_xform(geom.xform, local)
        return Projection(world, np.linalg.norm(world - points, axis=1), None, local)
    uv, world = _newton(geom, points, geom.shape.nearest(geom.to_object(points)).uv, newton)
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
        if depth:
            m, d = _inside_depth(y, pts)
        else:
            m = inside(y, pts)
            d = np.zeros(int(m.sum()))
        out.append(Region(None if uv is None else uv[m], pts[m], d))
    return out[0], out[1]


ON_SURFACE = 1e-6  # a vertex this close to the other surface (fraction of the pair's size) lies on it


def _on_surface(x: Geometry, y: Geometry, region: Region, pad: float) -> Region:
    """``region`` (``x``'s vertices inside ``y``) plus ``x``'s candidate vertices lying on a closed
    ``y``'s surface (within `ON_SURFACE` of the pair's size), at depth 0: what a motion that
    went through ``y`` up to its far face left touching (`detect_pair`)."""
    if not is_closed(y) or not _boxes_overlap(x, y, pad):
        return region
    pts, uv = _candidate_vertices(x, y.bounds, pad)
    near = surface_distance(y, pts)[0] <= ON_SURFACE * max(x.size, y.size)
    rows = lambda a: np.ascontiguousarray(a).view(np.dtype((np.void, 24))).ravel()  # noqa: E731 (exact rows)
    new = near & ~np.isin(rows(pts), rows(region.points))
    if not new.any():
        return region
    return Region(None if uv is None else np.concatenate([region.uv, uv[new]]),
                  np.concatenate([region.points, pts[new]]), np.concatenate([region.depth, np.zeros(int(new.sum()))]))


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


def face_samples(geom: ColliderGeometry, bounds: np.ndarray, spacing: float) -> np.ndarray:
    """World points ``(n, 3)`` on the collider's triangles within the world box ``bounds (2, 3)``,
    on a barycentric grid of each triangle whose box meets it, at most ``spacing`` apart along
    each edge (vertices included). A collider's region holds only its mesh's vertices, 8 for a
    box: too few to say which part of the other surface its faces need cleared
    (`frames.collider_points_for`).

    A triangle longer than the box's diagonal is first split in four, repeatedly, keeping the
    pieces whose box meets ``bounds``: the samples then cost the area inside the box, not the
    triangle's (a floor 1e3 across at a spacing of 1e-2 would be 5e9 points)."""
    mesh = geom.static.mesh
    tri = apply_xform(geom.xform, mesh.vertices[mesh.faces].reshape(-1, 3)).reshape(-1, 3, 3)
    limit = max(float(np.linalg.norm(bounds[1] - bounds[0])), spacing)
    while True:
        tri = tri[_overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0)]
        big = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1) > limit
        if not big.any():
            break
        a, b, c = (tri[big][:, k] for k in range(3))
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tri = np.concatenate([tri[~big], np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                              np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    if not len(tri):
        return np.zeros((0, 3))
    steps = np.maximum(np.ceil(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1) / spacing), 1).astype(np.int64)
    out = []
    for n in np.unique(steps):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        bary = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n  # (m, 3)
        out.append(np.einsum("mk,tkc->tmc", bary, tri[steps == n]).reshape(-1, 3))
    pts = np.unique(np.concatenate(out), axis=0)
    return pts[np.all((pts >= bounds[0]) & (pts <= bounds[1]), axis=1)]


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
    only cross); ``intersections``, the crossing triangle pairs at ``t``; ``depth_along``, for a
    rewound contact, how far the motion since the first touch carried the contact points past
    each other (`depth_along`, else 0)."""

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
    depth_along: float = 0.0

    @property
    def penetration(self) -> float:
        """What the frame loop must clear: the larger of the region ``depth`` and ``depth_along``."""
        return max(self.depth, self.depth_along)


def _deepest(region: Region, tol: float) -> int:
    """Row of the deepest vertex; among ties (within ``tol``) the one nearest their centroid."""
    tied = np.nonzero(region.depth >= region.max_depth - tol)[0]
    pts = region.points[tied]
    return int(tied[np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))])


def deepest_contact(ga: SurfaceGeometry, gb: Geometry, ra: Region, rb: Region, inter: Intersections):
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


EXIT_DIRECTIONS = 64  # candidate exit directions of the fallback, at most
_EXIT_COS = np.cos(np.radians(2.0))  # candidates closer than 2 degrees are one


def _exit_candidates(dirs: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Distinct unit directions ``(m, 3)`` from unit ``dirs (k, 3)`` with ``depth (k,)``: the
    deepest left, then every direction within 2 degrees of it dropped, at most `EXIT_DIRECTIONS`."""
    left, kept = dirs[np.argsort(-depth, kind="stable")], []
    while len(left) and len(kept) < EXIT_DIRECTIONS:
        kept.append(left[0])
        left = left[left @ left[0] < _EXIT_COS]
    return np.array(kept).reshape(-1, 3)


def _exit_lengths(geom: Geometry, points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """How far each of ``points (k, 3)`` inside ``geom`` travels along each of ``dirs (m, 3)`` to
    leave it: ``(m, k)``, ``nan`` where the ray found no exit (rounding at an edge)."""
    m, k = len(dirs), len(points)
    if not m or not k:
        return np.zeros((m, k))
    o, d = np.tile(points, (m, 1)), np.repeat(dirs, k, axis=0)
    hits, valid = cast(geom, o, d)
    return np.where(valid, np.einsum("ij,ij->i", hits - o, d), np.nan).reshape(m, k)


def _world_normals(geom: Geometry, n: np.ndarray) -> np.ndarray:
    """Object-space normals ``n (k, 3)`` of ``geom`` as world unit normals ``(k, 3)`` (normals map
    by the inverse transpose of the matrix, so a non-uniform scale keeps them perpendicular)."""
    n = np.asarray(n, np.float64).reshape(-1, 3) @ np.linalg.inv(geom.xform[:3, :3])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _own_normals(geom: Geometry, region: Region) -> tuple[np.ndarray, np.ndarray]:
    """World unit normals ``(n, 3)`` of ``geom``'s own surface at its region vertices and the
    region row of each ``(n,) int64``: the H-spline normal on a deformable, the normals of every
    face meeting the vertex on a collider (a box corner gives its three face normals)."""
    if isinstance(geom, ColliderGeometry):
        mesh = geom.static.mesh
        vert = mesh.kdtree.query(apply_inverse(geom.xform, region.points))[1]
        faces = mesh.vertex_faces[vert]  # (k, most faces at a vertex), -1 padded
        rows, col = np.nonzero(faces >= 0)
        n = mesh.face_normals[faces[rows, col]]
    else:
        rows = np.arange(len(region.points))
        n = H.surface_normals(geom.surface, region.uv[:, 0], region.uv[:, 1], det=geom.details)[1]
    return _world_normals(geom, n), rows


def exit_contact(ga: SurfaceGeometry, gb: Geometry, ra: Region, rb: Region, inter: Intersections):
    """The fallback contact ``uv_a, uv_b, local_b, P_A, P_B``: the way out that the whole
    interpenetration needs least, for contacts with no motion to rewind.

    A direction ``d`` (``A`` moves along ``d`` relative to ``B``) costs the farthest any region
    vertex must travel to leave: ``A``'s vertices inside ``B`` along ``d`` to ``B``'s surface,
    ``B``'s inside ``A`` along ``-d`` (ray casts from inside: the exit ahead; a ray that finds no
    exit is left out). Candidates are each vertex's nearest way out (to its closest point on the
    other surface) and ± its own surface's normals there (`_own_normals`: a sheet's two sides, a
    box corner's three faces), one per 2 degrees, deepest first, at most `EXIT_DIRECTIONS`; the
    cheapest wins, ties (within ``1e-9`` of the size) to the smaller mean travel, then to the
    deeper candidate. The contact is the vertex that must travel farthest that way (central among
    equals) and its exit point, so ``P_B - P_A`` is along ``d``. The nearest-point rule
    (`deepest_contact`) lets one vertex decide: for a unit cube centred on a sheet all six faces tie
    at 0.5 for the deepest vertex and a side face was chosen, which the sheet's far side can only
    reach by travelling 1.0 (and the sheet then slides sideways); here top and bottom cost 0.5,
    the sides about 1.0. Deterministic: no random choice, the same region gives the same contact.
    Both regions empty (the surfaces only cross): `deepest_contact`'s crossing centre."""
    tol = 1e-9 * max(ga.size, gb.size)
    if ra.empty and rb.empty:
        return deepest_contact(ga, gb, ra, rb, inter)
    dirs, depth = [], []
    for x, y, reg, sign in ((ga, gb, ra, 1.0), (gb, ga, rb, -1.0)):
        if reg.empty:
            continue
        close = surface_distance(y, reg.points)[1] - reg.points
        norm = np.linalg.norm(close, axis=1)
        ok = norm > tol
        dirs.append(sign * close[ok] / norm[ok, None])
        depth.append(reg.depth[ok])
        own, rows = _own_normals(x, reg)
        dirs += [own, -own]
        depth += [reg.depth[rows]] * 2
    cand = _exit_candidates(np.concatenate(dirs), np.concatenate(depth))
    if not len(cand):  # every region vertex on the other surface: the deepest-point rule
        return deepest_contact(ga, gb, ra, rb, inter)
    ea, eb = _exit_lengths(gb, ra.points, cand), _exit_lengths(ga, rb.points, -cand)
    travel = np.concatenate([ea, eb], axis=1)  # (m, |ra| + |rb|), nan: no exit found
    seen = np.isfinite(travel)
    count = seen.sum(axis=1)
    worst = np.where(count > 0, np.where(seen, travel, -np.inf).max(axis=1), np.inf)
    mean = np.where(seen, travel, 0.0).sum(axis=1) / np.maximum(count, 1)
    best = np.nonzero(worst <= worst.min() + tol)[0]
    j = int(best[np.argmin(mean[best])])
    row = np.where(seen[j], travel[j], -np.inf)
    tied = np.nonzero(row >= row.max() - tol)[0]
    pts = np.concatenate([ra.points, rb.points])
    i = int(tied[np.argmin(np.linalg.norm(pts[tied] - pts[tied].mean(axis=0), axis=1))])
    d = cand[j]
    if i < len(ra.points):  # A's vertex leaves B along d: P_B is its exit
        pa, pr = ra.points[i], project(gb, (ra.points[i] + row[i] * d)[None])
        return ra.uv[i], None if pr.uv is None else pr.uv[0], None if pr.local is None else pr.local[0], pa, pr.points[0]
    i -= len(ra.points)  # B's vertex leaves A along -d: P_A is its exit
    pb, pr = rb.points[i], project(ga, (rb.points[i] - row[i + len(ra.points)] * d)[None])
    local_b = apply_inverse(gb.xform, pb[None])[0] if isinstance(gb, ColliderGeometry) else None
    return pr.uv[0], None if rb.uv is None else rb.uv[i], local_b, pr.points[0], pb


def _outward(geom: Geometry, uv: np.ndarray | None, local: np.ndarray | None) -> np.ndarray | None:
    """World outward unit normal ``(3,)`` of a closed ``geom`` at a material point: ``uv (2,)`` on a
    deformable, object-space ``local (3,)`` on a collider (its nearest face's normal); ``None``
    for an open object, which has no outward side."""
    if not is_closed(geom):
        return None
    if isinstance(geom, ColliderGeometry):
        mesh = geom.static.mesh
        face = geom.static.index.query(np.asarray(local, np.float64).reshape(1, 3))[2][0]
        n = mesh.face_normals[face] * (1.0 if mesh.volume >= 0 else -1.0)
    else:
        uv = np.asarray(uv, np.float64).reshape(1, 2)
        n = geom.shape.outward * H.surface_normals(geom.surface, uv[:, 0], uv[:, 1], det=geom.details)[1][0]
    return _world_normals(geom, n)[0]


def depth_along(ga: SurfaceGeometry, gb: Geometry, anchor: Anchor, pa: np.ndarray, pb: np.ndarray) -> float:
    """Penetration along the motion at a rewound contact: how far ``P_A`` lies behind ``B``'s
    surface at ``P_B`` along ``B``'s outward normal there, ``(P_B - P_A) . n_B``, or ``P_B`` behind
    ``A``'s at ``P_A`` for an open ``B`` (the larger where both are closed); 0 if neither is closed
    or the points have not passed each other.

    The two material points coincided at the first touch. The region depth measures to the
    nearest surface, so a collider that went through up to its far face (a box whose top face
    lands on the sheet it entered by its bottom) has region depth 0 although the motion carried
    the sheet's contact point a whole box height behind the entry face: this is the depth the
    response must undo (docs/detection.md, bug D of docs/hard-cases.md)."""
    out = 0.0
    nb = _outward(gb, anchor.uv_b, anchor.local_b)
    if nb is not None:
        out = max(out, float((pb - pa) @ nb))
    na = _outward(ga, anchor.uv_a, None)
    if na is not None:
        out = max(out, float((pa - pb) @ na))
    return out


def detect_pair(ga: SurfaceGeometry, gb: Geometry, t: float = 0.0, geometry_at: GeometryAt | None = None, *,
                start: float | None = None, cache: RewindCache | None = None, max_back: int = 10_000,
                steps: int = 12, whole: bool = False) -> PairContact | None:
    """Detect a pair at time ``t``, ``None`` if it neither touches nor interpenetrates. ``ga``/``gb``:
    current geometry (possibly responded); ``geometry_at``: the input at any time, for `rewind`
    (else, or with no earlier free time, the fallback: `deepest_contact`, the deepest vertex's
    nearest way out, or with ``whole`` `exit_contact`, the way out the whole region needs least;
    the frame loop asks for ``whole`` in a frame's first round). ``P_A``/``P_B`` are the anchor's
    material points on the current geometry."""
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
        (uv_a, uv_b, local_b, pa, pb), t_c = (exit_contact if whole else deepest_contact)(ga, gb, ra, rb, inter), float(t)
    depth = max(ra.max_depth, rb.max_depth)
    along = 0.0 if anchor is None else depth_along(ga, gb, anchor, pa, pb)
    # the motion went farther than the nearest surface (by more than the default tolerance: the two
    # depths differ by the tessellation's error, 3e-4 of the size on dog_head_spike, where this
    # search of every candidate vertex cost 20 ms a frame): the touching vertices were swept too
    if along > depth + default_tolerance(ga, gb):
        pad = _pad(ga, gb)
        ra, rb = _on_surface(ga, gb, ra, pad), _on_surface(gb, ga, rb, pad)
    return PairContact(ga.name, gb.name, float(t), t_c, anchor is not None, uv_a, uv_b, local_b, pa, pb, ra, rb, depth, inter,
                       along)


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


def cast(geom: Geometry, origins: np.ndarray, directions: np.ndarray, behind: float | None = None,
         within: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First hits of world rays ``origins, directions (n, 3)`` on ``geom`` (thesis eq. 4.16):
    ``hits (n, 3)`` (the origin where none) and ``valid (n,) bool``. A hit may lie up to ``behind``
    (default ``1e-3`` of the object's size) behind its origin, for points pushed just past the
    surface, except from inside a closed ``geom``: there it must be ahead (the exit). ``within
    (n,) bool``: `inside` for the origins if the caller has it already (it is most of a cast's
    cost on a deformable)."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    hits, valid = origins.copy(), np.zeros(len(origins), bool)
    length = np.linalg.norm(directions, axis=1)
    rows = np.nonzero(length > 0)[0]
    if not len(rows):
        return hits, valid
    unit = directions[rows] / length[rows, None]
    behind = 1e-3 * geom.size if behind is None else float(behind)
    ins = inside(geom, origins[rows]) if within is None else np.asarray(within, bool).reshape(-1)[rows]
    start = origins[rows] - np.where(ins, 0.0, behind)[:, None] * unit
    found, ok = _first_hits(geom, start, unit)
    hits[rows[ok]], valid[rows[ok]] = found[ok], True
    # an origin on the surface whose ray goes in (just ahead of it is inside) counts as inside:
    # its hit is the exit ahead, not the surface it sits on
    eps = ON_SURFACE * geom.size
    on = ok & (np.linalg.norm(found - origins[rows], axis=1) <= eps)
    if on.any() and is_closed(geom):
        ahead = origins[rows[on]] + 2.0 * eps * unit[on]
        into = inside(geom, ahead)
        if into.any():
            sub = np.nonzero(on)[0][into]
            exit_, got = _first_hits(geom, ahead[into], unit[sub])
            hits[rows[sub[got]]] = exit_[got]
    return hits, valid


def _first_hits(geom: Geometry, start: np.ndarray, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits ``(n, 3)`` of world rays ``start, unit (n, 3)`` on ``geom`` (start where none)
    and which rays hit ``(n,) bool``."""
    o, d = apply_inverse(geom.xform, start), unit @ np.linalg.inv(geom.xform[:3, :3]).T
    if isinstance(geom, ColliderGeometry):
        loc, ray, _ = geom.static.mesh.ray.intersects_location(o, d, multiple_hits=False)
    else:
        loc, ray, _ = geom.shape.cast(o, d)
    hits, valid = start.copy(), np.zeros(len(start), bool)
    hits[ray], valid[ray] = apply_xform(geom.xform, loc), True
    return hits, valid
