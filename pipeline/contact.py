"""Where a pair first touched, and the contact the frame loop responds to (notes §4).

Detection (`pipeline.detect`) says what touches and what is inside; this module turns that into
one contact per pair: the input motion rewound to the first touch (`rewind`), with the depth the
motion carried the contact points past each other (`depth_along`); without motion to rewind, a
fallback, the way out the whole region needs least (`exit_contact`) or the deepest point
(`deepest_contact`); and `detect_pair`, which the frame loop calls each round. docs/detection.md
gives the definitions and the reasons. World units; arrays are float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from acra import hspline as H
from acra import memo
from pipeline import geometry
from pipeline import detect as D
from pipeline.model import apply_inverse, apply_xform

__all__ = [
    "Anchor", "RewindCache", "PairContact", "rewind", "depth_along", "slide_since", "deepest_contact",
    "exit_contact", "detect_pair",
]


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
    (``dict[float, bool]``), the `Anchor` of each ``(free frame, touching frame)`` interval, and
    each frame's `slide_since` (it reads the input alone, so every round of a frame shares it)."""

    touching: dict = field(default_factory=dict)
    anchors: dict = field(default_factory=dict)
    slides: dict = field(default_factory=dict)


GeometryAt = Callable[[float], "tuple[geometry.SurfaceGeometry, geometry.Geometry]"]


def _anchor_at(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, t: float) -> Anchor | None:
    """The deepest (central among equals) vertex of a (tiny) interpenetration, else the centre of
    the crossing triangles' contacts, projected onto both surfaces."""
    ra, rb = D.regions(ga, gb)
    if not (ra.empty and rb.empty):
        deeper = rb if ra.empty or rb.max_depth > ra.max_depth else ra
        centre = deeper.points[_deepest(deeper, 1e-9 * max(ga.size, gb.size))]
    else:
        inter = D.intersect(ga, gb)
        if not inter.crosses:
            return None
        centre = inter.points.mean(axis=0)
    pa, pb = D.project(ga, centre[None]), D.project(gb, centre[None])
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
            cache.touching[x] = D.touching(*geometry_at(x))
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
            a, b = (a, mid) if D.touching(*geometry_at(mid)) else (mid, b)
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
    region_a: D.Region
    region_b: D.Region
    depth: float
    intersections: D.Intersections
    depth_along: float = 0.0
    slide: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def penetration(self) -> float:
        """What the frame loop must clear: the larger of the region ``depth`` and ``depth_along``."""
        return max(self.depth, self.depth_along)

    @property
    def push(self) -> np.ndarray:
        """``(3,) float64``, eq. 4.15's ``P_B - P_A`` less the contact's slide: the world move that
        takes ``P_A`` to its partner, ``B``'s contact point moved by ``slide`` (`slide_since`)."""
        return (self.point_b + self.slide) - self.point_a


def _deepest(region: D.Region, tol: float) -> int:
    """Row of the deepest vertex; among ties (within ``tol``) the one nearest their centroid."""
    tied = np.nonzero(region.depth >= region.max_depth - tol)[0]
    pts = region.points[tied]
    return int(tied[np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))])


def deepest_contact(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, ra: D.Region, rb: D.Region, inter: D.Intersections):
    """``uv_a, uv_b, local_b, P_A, P_B`` from the deepest (central among equals) region vertex and
    its closest point on the other surface, or the crossing centre's when both regions are empty."""
    tol = 1e-9 * max(ga.size, gb.size)
    if not rb.empty and (ra.empty or rb.max_depth > ra.max_depth):
        i = _deepest(rb, tol)
        pa, pb = D.project(ga, rb.points[i][None]), rb.points[i]
        local_b = apply_inverse(gb.xform, pb[None])[0] if isinstance(gb, geometry.ColliderGeometry) else None
        return pa.uv[0], None if rb.uv is None else rb.uv[i], local_b, pa.points[0], pb
    if not ra.empty:
        i = _deepest(ra, tol)
        uv_a, pa, pb = ra.uv[i], ra.points[i], D.project(gb, ra.points[i][None])
    else:
        centre = inter.points.mean(axis=0)[None]
        pr = D.project(ga, centre)
        uv_a, pa, pb = pr.uv[0], pr.points[0], D.project(gb, centre)
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


def _exit_lengths(geom: geometry.Geometry, points: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """How far each of ``points (k, 3)`` inside ``geom`` travels along each of ``dirs (m, 3)`` to
    leave it: ``(m, k)``, ``nan`` where the ray found no exit (rounding at an edge)."""
    m, k = len(dirs), len(points)
    if not m or not k:
        return np.zeros((m, k))
    o, d = np.tile(points, (m, 1)), np.repeat(dirs, k, axis=0)
    hits, valid = D.cast(geom, o, d)
    return np.where(valid, np.einsum("ij,ij->i", hits - o, d), np.nan).reshape(m, k)


def _own_normals(geom: geometry.Geometry, region: D.Region) -> tuple[np.ndarray, np.ndarray]:
    """World unit normals ``(n, 3)`` of ``geom``'s own surface at its region vertices and the
    region row of each ``(n,) int64``: the H-spline normal on a deformable, the normals of every
    face meeting the vertex on a collider (a box corner gives its three face normals)."""
    if isinstance(geom, geometry.ColliderGeometry):
        mesh = geom.static.mesh
        vert = mesh.kdtree.query(apply_inverse(geom.xform, region.points))[1]
        faces = mesh.vertex_faces[vert]  # (k, most faces at a vertex), -1 padded
        rows, col = np.nonzero(faces >= 0)
        n = mesh.face_normals[faces[rows, col]]
    else:
        rows = np.arange(len(region.points))
        n = H.surface_normals(geom.surface, region.uv[:, 0], region.uv[:, 1], det=geom.details)[1]
    return geometry.world_normals(geom, n), rows


def exit_contact(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, ra: D.Region, rb: D.Region, inter: D.Intersections):
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
        close = D.surface_distance(y, reg.points)[1] - reg.points
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
        pa, pr = ra.points[i], D.project(gb, (ra.points[i] + row[i] * d)[None])
        return ra.uv[i], None if pr.uv is None else pr.uv[0], None if pr.local is None else pr.local[0], pa, pr.points[0]
    i -= len(ra.points)  # B's vertex leaves A along -d: P_A is its exit
    pb, pr = rb.points[i], D.project(ga, (rb.points[i] - row[i + len(ra.points)] * d)[None])
    local_b = apply_inverse(gb.xform, pb[None])[0] if isinstance(gb, geometry.ColliderGeometry) else None
    return pr.uv[0], None if rb.uv is None else rb.uv[i], local_b, pr.points[0], pb


AT_KEPT = 32
_AT = memo.Table("contact.at", AT_KEPT)  # `_point_at`, `_normal_at` and `_outward` answers by content, most recent last


def _at(kind: str, geom: geometry.Geometry, where: np.ndarray, make) -> np.ndarray:
    """``make()``, kept by ``kind``, the geometry's content (`SurfaceGeometry.content`,
    `ColliderGeometry.content`) and the material point ``where`` (its bytes): a frame's detection
    and its rewinding at the same time, and every frame's look at the first touch, ask for the
    same anchor points on the same input (`AT_KEPT` most recent kept). Read-only: callers share it."""
    def made():
        out = make()
        out.setflags(write=False)
        return out
    where = np.ascontiguousarray(where, np.float64)
    return _AT.kept((kind, geom.content, where.tobytes()), made)


def _on_surface(kind: str, geom: geometry.SurfaceGeometry, uv: np.ndarray) -> np.ndarray:
    """Object-space ``(1, 3)`` answer at ``uv (2,)`` of a deformable's surface alone, kept by the
    surface's content (`Shape.digest`) and ``uv`` in `_AT`: ``"object point"``, the point
    `geometry.surface_points` maps, or ``"object normal"``, `acra.hspline.surface_normals`'s unit
    normal. A rigidly moving or still input has one surface at every time, so every frame's
    contact points, normals and outward sides on it map these by that frame's matrix (a pole's
    normal takes several evaluations)."""
    def made():
        u = np.asarray(uv, np.float64).reshape(1, 2)
        if kind == "object point":
            out = H.evaluate(geom.surface, u[:, 0], u[:, 1], order=0, det=geom.details).points
        else:
            out = H.surface_normals(geom.surface, u[:, 0], u[:, 1], det=geom.details)[1]
        out.setflags(write=False)
        return out
    where = np.ascontiguousarray(uv, np.float64)
    return _AT.kept((kind, geom.shape.digest, where.tobytes()), made)


def _point_at(geom: geometry.SurfaceGeometry, uv: np.ndarray) -> np.ndarray:
    """World point ``(3,)`` of a deformable at ``uv (2,)`` (`geometry.surface_points`'s)."""
    return _at("point", geom, uv, lambda: apply_xform(geom.xform, _on_surface("object point", geom, uv))[0])


def _normal_at(geom: geometry.SurfaceGeometry, uv: np.ndarray) -> np.ndarray:
    """World unit normal ``(3,)`` along ``du × dv`` of a deformable at ``uv (2,)``."""
    return _at("normal", geom, uv, lambda: geometry.world_normals(geom, _on_surface("object normal", geom, uv))[0])


def _outward(geom: geometry.Geometry, uv: np.ndarray | None, local: np.ndarray | None) -> np.ndarray | None:
    """World outward unit normal ``(3,)`` of a closed ``geom`` at a material point: ``uv (2,)`` on a
    deformable, object-space ``local (3,)`` on a collider (its nearest face's normal); ``None``
    for an open object, which has no outward side."""
    if not geometry.is_closed(geom):
        return None
    if isinstance(geom, geometry.ColliderGeometry):
        def make():
            mesh = geom.static.mesh
            face = geom.static.index.query(np.asarray(local, np.float64).reshape(1, 3))[2][0]
            n = mesh.face_normals[face] * (1.0 if mesh.volume >= 0 else -1.0)
            return geometry.world_normals(geom, n)[0]
        return _at("outward", geom, local, make)

    def make():
        return geometry.world_normals(geom, geom.shape.outward * _on_surface("object normal", geom, uv)[0])[0]
    return _at("outward", geom, uv, make)


def depth_along(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, anchor: Anchor, pa: np.ndarray, pb: np.ndarray) -> float:
    """Penetration along the motion at a rewound contact: how far ``P_A`` lies behind ``B``'s
    surface at ``P_B`` along ``B``'s outward normal there, ``(P_B - P_A) . n_B``, or ``P_B`` behind
    ``A``'s at ``P_A`` for an open ``B`` (the larger where both are closed); 0 if neither is closed
    or the points have not passed each other.

    The two material points coincided at the first touch. The region depth measures to the
    nearest surface, so a collider that went through up to its far face (a box whose top face
    lands on the sheet it entered by its bottom) has region depth 0 although the motion carried
    the sheet's contact point a whole box height behind the entry face: this is the depth the
    response must undo, and the frame loop's stop test uses it (docs/detection.md)."""
    out = 0.0
    nb = _outward(gb, anchor.uv_b, anchor.local_b)
    if nb is not None:
        out = max(out, float((pb - pa) @ nb))
    na = _outward(ga, anchor.uv_a, None)
    if na is not None:
        out = max(out, float((pa - pb) @ na))
    return out


def _own_slide(now: geometry.SurfaceGeometry, then: geometry.SurfaceGeometry, uv: np.ndarray) -> np.ndarray:
    """How far the material point at ``uv (2,)`` of a deformable's input moved from ``then`` to
    ``now`` within its own tangent plane at ``now``: ``(3,) float64``, world."""
    move = _point_at(now, uv) - _point_at(then, uv)
    if not np.any(move):
        return np.zeros(3)
    n = _normal_at(now, uv)
    return move - (move @ n) * n


def slide_since(geometry_at: GeometryAt, anchor: Anchor, t: float) -> np.ndarray:
    """The part of the motion since the first touch that slid the surfaces along each other:
    ``(3,) float64``, world, to add to ``P_B`` (eq. 4.15's partner of ``P_A``).

    Rewinding pairs the material points that touched first (thesis §4.2.1); the frame then asks
    ``P_A`` to go to ``P_B``. A deformable whose input motion carries its contact point along its
    own surface (a sheet on a turntable that turns about its normal under a box that does not)
    brings no penetration by that part of its motion: the surfaces slide. Asking ``P_A`` to follow
    ``P_B`` along the slide shears the sheet under the box, and eq. 4.16's additional points, cast
    along that slanted ``P_A P_B``, reach the box's side faces rather than the face that presses;
    the frame stalls (`turning_press`: 6.8e-3 of the size left after the 4-round cap). So each
    deformable's input motion of its contact point since ``t_contact`` is split along its own
    normal at ``t``, and the tangential part is taken out of the pair's relative motion:
    ``A``'s added to ``P_B``, a deformable ``B``'s subtracted. A collider's motion is kept whole
    (the way it came: a tip or an edge has no normal to split by).

    Only a contact that slid farther than the input's motion carried its points into each other
    (``|slide|`` over the input's `depth_along` at ``t``) counts as sliding; otherwise the result
    is exactly 0 and the first-touch pairing stands. A pointed deformable coming in at a slant
    moves along its own tip's tangent plane too (`dog_head_spike`'s spike: 0.013 against 0.082
    along the motion), and there the way it came is the way out: taking that part out left
    5.6e-3 of the size after the cap. The test uses the input alone, so every round of a frame
    decides the same."""
    ga_now, gb_now = geometry_at(t)
    ga_then, gb_then = geometry_at(anchor.t_contact)
    slide = _own_slide(ga_now, ga_then, anchor.uv_a)
    deformable_b = anchor.uv_b is not None and isinstance(gb_now, geometry.SurfaceGeometry)
    if deformable_b:
        slide = slide - _own_slide(gb_now, gb_then, anchor.uv_b)
    if not np.any(slide):
        return slide
    pa = _point_at(ga_now, anchor.uv_a)
    pb = _point_at(gb_now, anchor.uv_b) if deformable_b else apply_xform(gb_now.xform, anchor.local_b[None])[0]
    return slide if np.linalg.norm(slide) > depth_along(ga_now, gb_now, anchor, pa, pb) else np.zeros(3)


def _slide(geometry_at: GeometryAt, anchor: Anchor, t: float, cache: RewindCache | None) -> np.ndarray:
    """`slide_since`, once per frame and anchor when a ``cache`` is kept."""
    if cache is None:
        return slide_since(geometry_at, anchor, t)
    key = (t, anchor.t_contact, *(None if x is None else np.asarray(x).tobytes() for x in (anchor.uv_a, anchor.uv_b, anchor.local_b)))
    if key not in cache.slides:
        cache.slides[key] = slide_since(geometry_at, anchor, t)
    return cache.slides[key]


def detect_pair(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, t: float = 0.0, geometry_at: GeometryAt | None = None, *,
                start: float | None = None, cache: RewindCache | None = None, max_back: int = 10_000,
                steps: int = 12, whole: bool = False) -> PairContact | None:
    """Detect a pair at time ``t``, ``None`` if it neither touches nor interpenetrates. ``ga``/``gb``:
    current geometry (possibly responded); ``geometry_at``: the input at any time, for `rewind`
    (else, or with no earlier free time, the fallback: `deepest_contact`, the deepest vertex's
    nearest way out, or with ``whole`` `exit_contact`, the way out the whole region needs least;
    the frame loop asks for ``whole`` in a frame's first round). ``P_A``/``P_B`` are the anchor's
    material points on the current geometry."""
    if not isinstance(ga, geometry.SurfaceGeometry):
        raise TypeError("A must be a deformable geometry.SurfaceGeometry (collider–collider pairs are never tested)")
    inter = D.intersect(ga, gb)
    ra, rb = D.regions(ga, gb)
    if not inter.crosses and ra.empty and rb.empty:
        return None
    anchor = None if geometry_at is None else rewind(geometry_at, t, start, cache, max_back, steps)
    if anchor is not None:
        uv_a, uv_b, local_b, t_c = anchor.uv_a, anchor.uv_b, anchor.local_b, anchor.t_contact
        pa = _point_at(ga, uv_a)
        pb = apply_xform(gb.xform, local_b[None])[0] if local_b is not None else _point_at(gb, uv_b)
    else:
        (uv_a, uv_b, local_b, pa, pb), t_c = (exit_contact if whole else deepest_contact)(ga, gb, ra, rb, inter), float(t)
    depth = max(ra.max_depth, rb.max_depth)
    along = 0.0 if anchor is None else depth_along(ga, gb, anchor, pa, pb)
    # the motion went farther than the nearest surface (by more than the default tolerance: the two
    # depths differ by the tessellation's error, 3e-4 of the size on dog_head_spike, where this
    # search of every candidate vertex cost 20 ms a frame): the touching vertices were swept too
    if along > depth + D.default_tolerance(ga, gb):
        pad = D.pair_pad(ga, gb)
        ra, rb = D.with_on_surface(ga, gb, ra, pad), D.with_on_surface(gb, ga, rb, pad)
    slide = np.zeros(3) if anchor is None else _slide(geometry_at, anchor, float(t), cache)
    return PairContact(ga.name, gb.name, float(t), t_c, anchor is not None, uv_a, uv_b, local_b, pa, pb, ra, rb, depth, inter,
                       along, slide)
