"""Collision detection for ACRA: what touches and what is inside (notes §4).

A pair is a deformable ``A`` (`pipeline.geometry.SurfaceGeometry`: object-space H-spline + 4×4
matrix) and a deformable or rigid collider ``B`` (`pipeline.geometry.ColliderGeometry`: a
run-constant `ColliderStatic` + matrix). Broad phase on level-0 patch boxes (convex-hull property)
→ fcl narrow phase on the tessellated candidate patches (`intersect`) → inside tests and depths
from closest points, answered on the patches near the query (`pipeline.shape.Shape`) or the
collider's mesh (`regions`; an open ``B`` has no inside) → `residual`, ray casts (`cast`). Where
the pair first touched and the contact the frame loop responds to are `pipeline.contact`'s.
docs/detection.md gives the definitions, the reasons and the timings. World units; arrays are
float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acra import halfspaces, memo, meshops, narrow
from pipeline import tessellation as T
from pipeline.geometry import (ColliderGeometry, ColliderStatic, Geometry, SurfaceGeometry, _face_boxes, candidate_patches,
                               is_closed, surface_points, wrap_uv)
from pipeline.model import apply_inverse, apply_xform

__all__ = [
    "Intersections", "Region", "Projection", "Residual", "intersect", "inside",
    "surface_distance", "project", "regions", "touching", "with_on_surface", "pair_pad", "residual", "cast",
    "default_tolerance", "apart",
]

_MAX_CONTACTS = 1_000_000
_PAD = 1e-7  # box padding, fraction of the pair's size: exactly touching boxes still overlap
ON_MESH = 1e-9  # a point this close to a collider's mesh (fraction of the mesh's size) lies on it: not inside
SIDE_SURE = 1e-6  # farther than this from a collider's mesh (fraction of its size), a point's side is its pseudo-normal's


def apart(ga: Geometry, gb: Geometry) -> bool:
    """Whether the pair's world boxes surely miss each other by more than the pair's padding
    (`pair_pad`), from the object-level boxes (`outer`) alone: their boxes hold the exact ones
    and their diagonals bound the exact sizes from above, so ``apart`` implies that
    `_boxes_overlap` is False. A free frame's pairs then cost a few products whatever the
    model's size; pairs not apart take the exact test."""
    (la, ha, da), (lb, hb, db) = ga._outer, gb._outer
    pad = _PAD * max(da, db)
    return not all(la[k] <= hb[k] + pad and lb[k] <= ha[k] + pad for k in range(3))


def apart_all(geoms: list) -> np.ndarray:
    """`apart` of every two of ``geoms`` at once: ``(n, n) bool``, symmetric, from the same
    object-level boxes (`outer`) and in the same float64 arithmetic (the larger diagonal times
    ``_PAD``, each upper side plus that pad, compared), so each entry is `apart`'s answer. A frame
    of many objects then tests its pairs' boxes in a few array operations instead of one call a
    pair (4,950 pairs of 100 deformables)."""
    outer = [g._outer for g in geoms]
    lo = np.array([o[0] for o in outer], np.float64).reshape(-1, 3)
    hi = np.array([o[1] for o in outer], np.float64).reshape(-1, 3)
    diag = np.array([o[2] for o in outer], np.float64)
    pad = _PAD * np.maximum(diag[:, None], diag[None, :])
    meet = np.ones(pad.shape, bool)
    for k in range(3):
        meet &= (lo[:, None, k] <= hi[None, :, k] + pad) & (lo[None, :, k] <= hi[:, None, k] + pad)
    return ~meet


# --- narrow phase -------------------------------------------------------------------------------
class Intersections:
    """Crossing triangle pairs (fcl): world contact ``points (k, 3)``; level-0 patch of ``A``'s
    triangle ``patch_a (k, 2) int64`` and of ``B``'s ``patch_b`` (``None`` for a collider); the
    collider's face ``face_b (k,) int64`` (row of ``ColliderStatic.mesh.faces``, else ``-1``);
    ``count`` of them, ``crosses``: whether there is one.

    Made by `Intersections.later`, the arrays wait until one is read (or ``count`` where it is
    not known): detection mostly asks only whether a pair crosses, which
    `acra.narrow.crossings` answers without fcl's BVHs."""

    def __init__(self, points: np.ndarray, patch_a: np.ndarray, patch_b: np.ndarray | None, face_b: np.ndarray) -> None:
        self._arrays = (points, patch_a, patch_b, face_b)
        self._count = int(points.shape[0])
        self._make = None

    @classmethod
    def later(cls, make, count: int | None, crosses: bool) -> "Intersections":
        """The arrays from ``make()`` when first read; ``count`` (``None``: not known) and
        ``crosses`` known now."""
        out = cls.__new__(cls)
        out._arrays, out._count, out._make, out._crosses = None, count, make, bool(crosses)
        return out

    def _get(self, i: int):
        if self._arrays is None:
            self._arrays = self._make()
            self._make = None
        return self._arrays[i]

    points = property(lambda self: self._get(0))
    patch_a = property(lambda self: self._get(1))
    patch_b = property(lambda self: self._get(2))
    face_b = property(lambda self: self._get(3))

    @property
    def count(self) -> int:
        if self._count is None:
            self._count = int(self.points.shape[0])
        return self._count

    @property
    def crosses(self) -> bool:
        return self._crosses if self._arrays is None else self.count > 0


def pair_pad(ga: Geometry, gb: Geometry) -> float:
    return _PAD * max(ga.size, gb.size)


def _boxes_overlap(ga: Geometry, gb: Geometry, pad: float) -> bool:
    """`pipeline.grids.overlap` of the two world boxes, in Python floats (the same sums and
    comparisons): on three coordinates numpy's per-call cost is the whole work."""
    (la, ha), (lb, hb) = ga.bounds.tolist(), gb.bounds.tolist()
    return all(la[k] <= hb[k] + pad and lb[k] <= ha[k] + pad for k in range(3))


def _box_meets(a: np.ndarray, b: np.ndarray, pad: float) -> bool:
    """`pipeline.grids.overlap` of two boxes ``(2, 3)`` (low and high corners), in Python floats
    (the same sums and comparisons): on three coordinates numpy's per-call cost is the whole work."""
    (la, ha), (lb, hb) = a.tolist(), b.tolist()
    return all(la[k] <= hb[k] + pad and lb[k] <= ha[k] + pad for k in range(3))


def _every_box_meets(geom: SurfaceGeometry, bounds: np.ndarray, pad: float) -> bool:
    """Whether every level-0 patch box of ``geom`` overlaps the box ``bounds (2, 3)`` (within
    ``pad``): ``grids.overlap(lo, hi, *bounds, pad).all()``, from the boxes' highest low and
    lowest high corner alone, kept in the content's world data (a still object's are found once
    for a whole rewinding search). Every box passes ``lo <= b_hi + pad`` iff the highest ``lo``
    does, and ``b_lo <= hi + pad`` iff the lowest ``hi`` does (adding ``pad`` rounds monotonically),
    so this is the same answer, a NaN corner failing both."""
    world = geom._world
    if world.inner is None:
        lo, hi = geom.boxes
        world.inner = (lo.reshape(-1, 3).max(axis=0).tolist(), hi.reshape(-1, 3).min(axis=0).tolist())
    (top, bottom), (lb, hb) = world.inner, bounds.tolist()
    return all(top[k] <= hb[k] + pad and lb[k] <= bottom[k] + pad for k in range(3))


def _triangles_near(box_a: tuple[np.ndarray, np.ndarray], box_b: tuple[np.ndarray, np.ndarray], pad: float, rounds: int = 2):
    """Rows of side ``a``'s and side ``b``'s triangles, given by their boxes ``lo, hi (f, 3)``,
    whose boxes overlap the box of the other side's kept ones (compiled:
    `acra.narrow.triangles_near`)."""
    return narrow.triangles_near(box_a, box_b, pad, rounds)


ANSWERS_KEPT = 8
_ANSWERS = memo.Table("detect.answers", ANSWERS_KEPT)  # `intersect`'s answers by the pair's content, most recent last


def intersect(ga: SurfaceGeometry, gb: Geometry) -> Intersections:
    """Triangle pairs where the surfaces cross or touch. Tessellates only patches whose boxes meet
    the other object's box; ``A``'s triangles go into a collider's object space (crossing is
    affine-invariant), where its BVH was built once.

    The answer is one of the two geometries' content (`SurfaceGeometry.content`,
    `ColliderGeometry.content`): a pair asked again with the same surfaces, matrices and
    densities (a frame's detection and its rewinding at the same time, a still object) gets the
    kept answer; the `ANSWERS_KEPT` most recent are kept."""
    return _ANSWERS.kept((ga.content, gb.content), lambda: _intersect(ga, gb))


def _no_intersections(collider: bool) -> Intersections:
    """No crossing triangle pair (``patch_b`` ``None`` against a collider)."""
    empty = np.zeros((0, 2), np.int64)
    return Intersections(np.zeros((0, 3)), empty, None if collider else empty, np.zeros(0, np.int64))


def _intersect(ga: SurfaceGeometry, gb: Geometry, pad: float | None = None, first: bool = False) -> Intersections | None:
    """`intersect`, computed. ``pad``: the pair's `pair_pad`, given by a caller that found the
    pair neither `apart` nor outside each other's box (`_boxes_overlap`) already. With
    ``first``, ``None`` as soon as one triangle pair surely gives a contact (the surfaces cross;
    how many contacts is not counted): `touching` asks no more."""
    collider = isinstance(gb, ColliderGeometry)
    if pad is None:
        if apart(ga, gb):
            return _no_intersections(collider)
        pad = pair_pad(ga, gb)
        if not _boxes_overlap(ga, gb, pad):
            return _no_intersections(collider)
    if collider:
        ca = candidate_patches(ga, gb.bounds, pad)
    else:
        # each side's `candidate_patches` in the other's box, of those the ones whose box meets
        # one of the other side's, and the box of B's: one compiled pass over the patch boxes
        ca, cb, box_b = narrow.patch_rows_near(ga.boxes, ga.bounds, gb.boxes, gb.bounds, pad)
    if not len(ca):
        return _no_intersections(collider)
    ta = T.tessellate_sorted(ga, ca)
    if collider:  # the collider's face boxes are the run's (`ColliderStatic.face_boxes`)
        pa = apply_inverse(gb.xform, ta.points)
        ka, kb = _triangles_near(_face_boxes(pa, ta.triangles), gb.static.face_boxes, pad)
    else:
        # B's triangles lie in its candidate patches' boxes: if A's grid points all lie outside
        # their union (a concave or thin pair whose hull boxes overlap), no triangle pair can
        # meet and B is not tessellated
        if box_b is None or not _box_meets(ta.bounds, box_b, pad):
            return _no_intersections(collider)
        tb = T.tessellate_sorted(gb, cb)
        pa, pb, fb_all = ta.points, tb.points, tb.triangles
        ka, kb = _triangles_near(ta.face_boxes, tb.face_boxes, pad)
    if not len(ka):
        return _no_intersections(collider)

    def contacts():
        import fcl  # here: a run whose pairs `acra.narrow.crossings` settles never imports fcl

        oa = ga.shape.bvhs.get(pa, ta.triangles[ka])
        ob = gb.static.bvh if collider else gb.shape.bvhs.get(pb, fb_all[kb])
        res = fcl.CollisionResult()
        fcl.collide(oa, ob, fcl.CollisionRequest(num_max_contacts=_MAX_CONTACTS, enable_contact=True), res)
        n = len(res.contacts)
        fa = ka[np.fromiter((c.b1 for c in res.contacts), np.int64, n)]
        fb = np.fromiter((c.b2 for c in res.contacts), np.int64, n)
        pos = np.array([c.pos for c in res.contacts], np.float64).reshape(-1, 3)
        if collider:
            return apply_xform(gb.xform, pos), ta.tri_patch[fa], None, fb
        return pos, ta.tri_patch[fa], tb.tri_patch[kb[fb]], np.full(n, -1, np.int64)

    # fcl's contact count by its own triangle test on the pairs whose boxes overlap, without its
    # BVHs (`acra.narrow.crossings`); the contacts themselves only when read. Where pairs with a
    # degenerate or thin triangle leave the count unknown and the others give none, fcl answers
    # now.
    if collider:
        count, unsure = (0, True) if gb.static.thin else narrow.crossings(pa, ta.triangles, ka, gb.static.mesh.vertices,
                                                                         gb.static.mesh.faces, kb, pad, first)
    else:
        count, unsure = narrow.crossings(pa, ta.triangles, ka, pb, fb_all, kb, pad, first)
    if first and count:
        return None
    if not unsure:
        return Intersections.later(contacts, count, count > 0)
    if count:  # fcl reports these and the unknown pairs' contacts: how many is read from it later
        return Intersections.later(contacts, None, True)
    return Intersections(*contacts())


# --- inside tests, distances, projections -------------------------------------------------------
def _collider_inside(geom: ColliderGeometry, points: np.ndarray, depth: bool = False):
    """`inside` of a collider ``(k,) bool`` and, with ``depth``, the world distances ``(m,)`` of
    the points inside to its mesh.

    Ray parity (trimesh ``contains``, embree) has no answer for a point on the mesh: whether a
    ray from it meets the face it sits on depends on the last bits of its coordinates, and
    trimesh re-casts the rays of a point whose two directions disagree in a random direction.
    Those bits are rounding, and rounding does not scale with the scene: a rim bisection's
    midpoint exactly on a box's side face at one scale lies a rounding error inside it at
    another, and the two runs then bisect to different crossings. So a point within `ON_MESH`
    of the mesh's size (object space, where the parity test runs) lies on the mesh and is not
    inside, whatever the parity says: its depth would be rounding, and `with_on_surface` is what
    adds on-surface points to a region. Farther points keep the parity answer. Only points the
    parity calls inside need the distance, which `regions` needs for their depth anyway."""
    static = geom.static
    local, m, near = collider_sides(geom, points)
    if not depth:
        if near.any():
            m[near] = near_inside(static, local[near])
        return m
    if near.any():
        m[near] = _parity(static, local[near])
    rows = np.nonzero(m)[0]
    if not len(rows):
        return m, np.zeros(0)
    dist, close, _ = static.index.query(local[rows])
    on = dist <= ON_MESH * static.scale
    m[rows[on]] = False
    return m, np.linalg.norm(points[rows[~on]] - apply_xform(geom.xform, close[~on]), axis=1)


def collider_sides(geom: ColliderGeometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The part of `inside` on a collider that needs no ray parity: world ``points (k, 3)`` in
    object space ``(k, 3)``, the side ``(k,) bool`` (inside) of each point farther than
    `SIDE_SURE` of the mesh's size from it, and which points are nearer ``near (k,) bool``, whose
    answer is `near_inside`'s of their object-space points (their entries of the side are unset).
    Each point's answers are its own: a caller may ask the near points of several calls at once."""
    from pipeline import clearance

    static = geom.static
    local = geom.to_object(points)
    # A point farther than `SIDE_SURE` of the mesh's size from it takes the side of the
    # angle-weighted pseudo-normal at its closest point (eq. (1) of `pipeline.clearance`, exact in
    # float64 off the surface), where embree's float32 parity agrees; nearer points keep the parity.
    sure = SIDE_SURE * static.scale
    planes = static.planes
    if planes is None:
        sd = clearance.signed_depth(static.solid, local)[0]
        near = np.abs(sd) <= sure
        m = sd > 0
    else:
        # a convex collider: a point higher than twice `SIDE_SURE` over a face plane or deeper
        # than it under all is far, on the side of its height (`_convex_planes`); the closest
        # points answer the rest, and a point with a coordinate not finite as they always have
        h = halfspaces.heights(planes, local)
        m, near = h < 0, np.zeros(len(local), bool)
        rows = np.flatnonzero((np.abs(h) <= 2.0 * sure) | ~np.isfinite(h))
        if len(rows):
            sd = clearance.signed_depth(static.solid, local[rows])[0]
            near[rows], m[rows] = np.abs(sd) <= sure, sd > 0
    return local, m, near


def near_inside(static: ColliderStatic, local: np.ndarray) -> np.ndarray:
    """`inside` ``(k,) bool`` of object-space points ``local (k, 3)`` that `collider_sides` finds
    within `SIDE_SURE` of the collider's mesh: the ray parity, and a point within `ON_MESH` of the
    mesh's size from it lies on it, not inside. (A point farther than `SIDE_SURE` from the solid,
    its faces within its weld, 1e-7 of the size, of the mesh's, is farther than `ON_MESH` from the
    mesh: only near points can lie on it.)"""
    m = _parity(static, local)
    rows = np.nonzero(m)[0]
    if len(rows):
        m[rows[static.index.within(local[rows], ON_MESH * static.scale)]] = False
    return m


def _parity(static: ColliderStatic, local: np.ndarray) -> np.ndarray:
    """trimesh's ray parity (``Trimesh.contains``) ``(k,) bool`` of object-space points ``local
    (k, 3)``. trimesh re-casts the rays of a point whose two rays disagree (on the surface, which
    every response produces) in a random direction from a shared generator: it is set back to its
    seed first (`_reseeded`), so a run is reproducible and every call's re-casts take the same
    direction, whichever points it asks."""
    import trimesh  # imported by `prepare_collider` already

    if hasattr(trimesh.util, "_RANDOM_DEFAULT"):
        trimesh.util._RANDOM_DEFAULT = _reseeded()
    return static.mesh.contains(local)


_RECAST_SEED = 20260311
_RECAST = np.random.default_rng(_RECAST_SEED)  # the generator of trimesh's re-casts (`_reseeded`)
_RECAST_START = _RECAST.bit_generator.state


def _reseeded() -> np.random.Generator:
    """``np.random.default_rng(_RECAST_SEED)``'s stream from its start: one kept generator whose
    state is set back to the seed's, the same draws for a tenth of a new generator's set-up (the
    rim's bisection sets it before each of its inside tests near a face)."""
    _RECAST.bit_generator.state = _RECAST_START
    return _RECAST


def inside(geom: Geometry, points: np.ndarray) -> np.ndarray:
    """Which world ``points (k, 3)`` lie inside ``geom``: ``(k,) bool``, all False if it is open.
    A collider: ray parity on its watertight mesh (embree), a point within `ON_MESH` of the
    mesh's size from it lying on it, not inside (`_collider_inside`); a deformable: behind the
    outward normal at the closest point of its collision grids (`Shape.signed`)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(points) or not is_closed(geom):
        return np.zeros(len(points), bool)
    if isinstance(geom, SurfaceGeometry):
        return geom.shape.signed(geom.to_object(points), False)[0]
    return _collider_inside(geom, points)


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


def _inside_rows(geom: Geometry, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`inside` ``(k,) bool`` and, for the points inside, their rows ``(m,) int64`` (increasing),
    the points ``(m, 3)`` and their `surface_distance` ``(m,)``, gathered once for both the depth
    and the region: one closest-point query on a deformable. Rows are taken by index: a boolean
    mask of an ``(n, 3)`` array goes element by element."""
    if isinstance(geom, SurfaceGeometry) and len(points) and geom.closed:
        m, near = geom.shape.signed(geom.to_object(points))
        rows = np.flatnonzero(m)
        ins = np.take(points, rows, axis=0)
        return m, rows, ins, np.linalg.norm(ins - apply_xform(geom.xform, near.points), axis=1)
    if isinstance(geom, ColliderGeometry) and len(points) and geom.static.closed:
        m, depth = _collider_inside(geom, points, depth=True)
        rows = np.flatnonzero(m)
        return m, rows, np.take(points, rows, axis=0), depth
    m = inside(geom, points)
    rows = np.flatnonzero(m)
    ins = np.take(points, rows, axis=0)
    return m, rows, ins, surface_distance(geom, ins)[0]


@dataclass(frozen=True, eq=False)
class Projection:
    """Closest surface points: world ``points (k, 3)``, ``distance (k,)``, parameters ``uv (k, 2)``
    on a deformable (else ``None``), object-space material points ``local (k, 3)`` on a collider
    (else ``None``)."""

    points: np.ndarray
    distance: np.ndarray
    uv: np.ndarray | None
    local: np.ndarray | None


def _newton(geom: SurfaceGeometry, targets: np.ndarray, uv: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Newton on ``|S(u, v) - target|^2 / 2`` with the full Hessian ``J^T J + r . S''`` (Gauss–Newton
    is only linear, rate depth / curvature radius, deep on the concave side), shifted positive; a
    step is kept if it gets closer or, the distance flat to rounding, shrinks the gradient."""
    hs, uv = geom.surface, wrap_uv(geom.surface, uv)
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
        cand = wrap_uv(hs, uv + step)
        ec = surface_points(geom, cand, order=2)
        rc = ec.points - targets
        dc, gc = np.linalg.norm(rc, axis=1), grad(ec, rc)
        shrinks = (dc <= dist + flat_tol) & (np.abs(gc).max(axis=1) < np.abs(g).max(axis=1))
        ok = np.isfinite(dc) & ((dc < dist) | shrinks)
        if not ok.any():
            break
        if ok.all():  # every point steps (a single point, the anchor's): the new arrays whole
            uv, dist, r, g, ev = cand, dc, rc, gc, ec
            continue
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


def _empty_region(x: Geometry) -> Region:
    """No vertices of ``x``."""
    return Region(None if isinstance(x, ColliderGeometry) else np.zeros((0, 2)), np.zeros((0, 3)), np.zeros(0))


def regions(ga: SurfaceGeometry, gb: Geometry, depth: bool = True) -> tuple[Region, Region]:
    """The interpenetration regions: ``A``'s vertices inside ``B`` and ``B``'s inside ``A`` (empty
    when the other object is open). ``depth=False`` leaves depths at zero."""
    if apart(ga, gb):
        return _empty_region(ga), _empty_region(gb)
    pad = pair_pad(ga, gb)
    return _region_of(ga, gb, pad, depth), _region_of(gb, ga, pad, depth)


def _region_of(x: Geometry, y: Geometry, pad: float, depth: bool = True) -> Region:
    """One side of `regions`: ``x``'s vertices inside ``y`` (empty when ``y`` is open or the two
    boxes miss within ``pad``)."""
    if not is_closed(y) or not _boxes_overlap(x, y, pad):
        return _empty_region(x)
    pts, uv = T.vertices_in_box(x, y.bounds, pad)
    if depth:
        _, rows, ins, d = _inside_rows(y, pts)
    else:
        rows = np.flatnonzero(inside(y, pts))  # taken by index: a boolean mask of an (n, 3) array goes element by element
        ins, d = np.take(pts, rows, axis=0), np.zeros(len(rows))
    return Region(None if uv is None else np.take(uv, rows, axis=0), ins, d)


ON_SURFACE = 1e-6  # a vertex this close to the other surface (fraction of the pair's size) lies on it


def with_on_surface(x: Geometry, y: Geometry, region: Region, pad: float) -> Region:
    """``region`` (``x``'s vertices inside ``y``) plus ``x``'s candidate vertices lying on a closed
    ``y``'s surface (within `ON_SURFACE` of the pair's size), at depth 0: what a motion that
    went through ``y`` up to its far face left touching (`contact.detect_pair`)."""
    if not is_closed(y) or not _boxes_overlap(x, y, pad):
        return region
    pts, uv = T.vertices_in_box(x, y.bounds, pad)
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
    if apart(ga, gb):
        return False
    pad = pair_pad(ga, gb)
    if not _boxes_overlap(ga, gb, pad):
        return False
    # `intersect`'s answer where it is kept; else its pass with the box tests above, stopped at the
    # first triangle pair with a contact (a rewinding step's crossing pair is all it asks for):
    # that partial answer is not kept, a whole pass's is
    key = (ga.content, gb.content)
    inter = _ANSWERS.get(key)
    if inter is None:
        inter = _intersect(ga, gb, pad, first=True)
        if inter is None:
            return True
    if _ANSWERS.kept(key, lambda: inter).crosses:
        return True
    for x, y in ((ga, gb), (gb, ga)):
        if not is_closed(y):
            continue
        if isinstance(x, SurfaceGeometry):
            if not _every_box_meets(x, y.bounds, pad):  # every patch a candidate (`candidate_patches`)
                continue
        elif not np.all((x.vertices >= y.bounds[0] - pad) & (x.vertices <= y.bounds[1] + pad)):
            continue
        pts, _ = T.vertices_in_box(x, y.bounds, pad)
        sample = pts[np.linspace(0, len(pts) - 1, min(5, len(pts))).astype(np.int64)]
        if len(sample) and 2 * inside(y, sample).sum() > len(sample):
            return True
    return False


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


CASTS_KEPT = 8
_CASTS = memo.Table("detect.casts", CASTS_KEPT)  # `cast`'s answers by content and rays, most recent last


def cast(geom: Geometry, origins: np.ndarray, directions: np.ndarray, behind: float | None = None,
         within: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First hits of world rays ``origins, directions (n, 3)`` on ``geom`` (thesis eq. 4.16):
    ``hits (n, 3)`` (the origin where none) and ``valid (n,) bool``. A hit may lie up to ``behind``
    (default ``1e-3`` of the object's size) behind its origin, for points pushed just past the
    surface, except from inside a closed ``geom``: there it must be ahead (the exit). ``within
    (n,) bool``: `inside` for the origins if the caller has it already (it is most of a cast's
    cost on a deformable).

    The answer is one of ``geom``'s content (`SurfaceGeometry.content`, `ColliderGeometry.content`)
    and the rays' bytes: a contact held still over frames casts the same rays on the same
    surfaces again (`box_into_sheet`'s frames 12-16), and the `CASTS_KEPT` most recent answers
    are kept; each call gets its own arrays."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    key = (geom.content, origins.tobytes(), directions.tobytes(), None if behind is None else float(behind),
           None if within is None else np.asarray(within, bool).reshape(-1).tobytes())
    hits, valid = _CASTS.kept(key, lambda: _cast(geom, origins, directions, behind, within))
    return hits.copy(), valid.copy()


def _cast(geom: Geometry, origins: np.ndarray, directions: np.ndarray, behind: float | None,
          within: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """`cast`, computed."""
    hits, valid = origins.copy(), np.zeros(len(origins), bool)
    length = np.linalg.norm(directions, axis=1)
    if (length > 0).all():  # every ray has a direction: the rows as they are, without gathering them
        rows, at, unit = None, origins, directions / length[:, None]
    else:
        rows = np.nonzero(length > 0)[0]
        if not len(rows):
            return hits, valid
        at, unit = origins[rows], directions[rows] / length[rows, None]
    behind = 1e-3 * geom.size if behind is None else float(behind)
    if within is None:
        ins = inside(geom, at)
    else:
        ins = np.asarray(within, bool).reshape(-1)
        ins = ins if rows is None else ins[rows]
    start = at - np.where(ins, 0.0, behind)[:, None] * unit
    found, ray = _first_hits(geom, start, unit)  # the rays that hit, in order
    dest = ray if rows is None else rows[ray]
    hits[dest], valid[dest] = found, True
    # an origin on the surface whose ray goes in (just ahead of it is inside) counts as inside:
    # its hit is the exit ahead, not the surface it sits on
    eps = ON_SURFACE * geom.size
    on = np.linalg.norm(found - at[ray], axis=1) <= eps
    if on.any() and is_closed(geom):
        ahead = origins[dest[on]] + 2.0 * eps * unit[ray[on]]
        into = inside(geom, ahead)
        if into.any():
            exit_, got = _first_hits(geom, ahead[into], unit[ray[on][into]])
            hits[dest[on][into][got]] = exit_
    return hits, valid


def _first_hits(geom: Geometry, start: np.ndarray, unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hits ``(m, 3)`` of world rays ``start, unit (n, 3)`` on ``geom`` and the row of
    each ray that hits ``(m,) int64``, in increasing order."""
    # the linear part's inverse found once per geometry (`to_object`): `apply_inverse`'s bits
    o, d = geom.to_object(start), unit @ geom._inverse_t
    if isinstance(geom, ColliderGeometry):
        loc, ray = _collider_first_hits(geom.static, o, d)
    else:
        loc, ray = geom.shape.cast(o, d)
    # mapped in the intersector's order (a matrix product's rows in the order it is given them), then
    # put in the rays' order
    found, ray = apply_xform(geom.xform, loc), np.asarray(ray, np.int64)
    if len(ray) > 1 and (ray[1:] < ray[:-1]).any():
        order = np.argsort(ray, kind="stable")
        found, ray = found[order], ray[order]
    return found, ray


_RAY_SCENES = memo.Table("detect.ray_scenes", 4)  # a collider mesh's embree scene and face planes, by its content


def _collider_first_hits(static: ColliderStatic, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """trimesh's ``mesh.ray.intersects_location(origins, directions, multiple_hits=False)`` on a
    collider's mesh (object-space rays ``(n, 3)``): the first hits ``(m, 3)`` and the row of each
    ray that hits ``(m,) int64``, in increasing order. Its steps for a first hit: the unit
    directions (`acra.meshops.unitize`), embree's triangle from trimesh's own scene of the mesh
    (its float32 scaling), the float64 ray on that triangle's plane (`acra.meshops.planes_lines`
    on the mesh's first corners and face normals). The scene and the planes are taken once per
    mesh content: trimesh checks its mesh's hash at every reach into its caches (the intersector,
    its scene, the triangles, the normals), a dozen array hashes a cast of a 12-face box."""
    from trimesh.ray import ray_pyembree

    mesh = static.mesh
    if not isinstance(mesh.ray, ray_pyembree.RayMeshIntersector):  # trimesh without embree: its own
        loc, ray, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
        return loc, np.asarray(ray, np.int64)
    scene, corners, normals = _RAY_SCENES.kept(static.digest, lambda: (
        mesh.ray._scene, np.asarray(mesh.triangles[:, 0, :]), np.asarray(mesh.face_normals)))
    origins = np.array(origins, dtype=np.float64)
    directions = meshops.unitize(np.array(directions, dtype=np.float64))[0]
    query = scene.run(origins, directions)
    rays = np.flatnonzero(query != -1)
    tris = query[rays]
    loc, valid = meshops.planes_lines(corners[tris], normals[tris], origins[rays], directions[rays])
    return loc, rays[valid]
