"""The rim of a region a collider pushes a surface along (thesis eq. 4.16's interpretation at a
collider's outline, `docs/algorithm.md`).

Eq. 4.16's additional points pin the surface only inside a collider's outline, and the C2 surface
curls back up inside the collider before its side face. Where the push makes the surface drop
along a side face (a box pressed into a sheet), `rim_points` puts a point one detection step
outside each crossing of the outline, aimed at the face the region is pushed onto, so the rise
happens outside: the region samples whose neighbour one step away is missing
(`_missing_neighbours`) are bisected to where the segment leaves the collider (`_bisected`,
`RIM_BISECT` halvings, the collider's inside test answering each side), and each crossing on a
face that counts (`_on_counted_faces`: steep to the push or facing it) is cast along the push.
A curved collider's flank gives none. Answers are kept by the pair's content, the region and the
direction (`rim.points`, `RIMS_KEPT`).
"""

from __future__ import annotations

import numpy as np

from acra import hspline as H
from acra import kdtree
from acra import memo
from acra import meshrows
from acra.targets import patch_groups
from pipeline import geometry
from pipeline import detect as D
from pipeline.model import apply_xform

__all__ = ["rim_points", "RIM_STEEP", "RIM_FACING", "RIM_BISECT", "RIM_PATHS", "RIMS_KEPT"]


RIM_STEEP = 0.5  # |n·d| at most this: a collider face the surface must drop along (a box's side)
RIM_FACING = 0.95  # |n·d| at least this: the face the region is pushed onto (a later round's sliver)
RIM_BISECT = 6  # bisection steps locating a crossing between two samples (1/64 of the step)


RIMS_KEPT = 4
_RIMS = memo.Table("rim.points", RIMS_KEPT)  # `rim_points`' answers by content, most recent last


def rim_points(ga: geometry.SurfaceGeometry, gb: geometry.ColliderGeometry, region_uv: np.ndarray, direction: np.ndarray,
               level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_rim_points`, kept by content: the pair's (`SurfaceGeometry.content`,
    `ColliderGeometry.content`), the region's parameters, the direction and the level. A contact
    held still over frames asks for the same rim again (`box_into_sheet`'s frames 12-16: 1,100
    crossings bisected in 7 inside tests, about 10 ms a frame); the `RIMS_KEPT` most recent are
    kept, and each call gets its own arrays."""
    region_uv = np.asarray(region_uv, float).reshape(-1, 2)
    key = (ga.content, gb.content, region_uv.tobytes(), np.asarray(direction, np.float64).tobytes(), int(level))
    return tuple(a.copy() for a in _RIMS.kept(key, lambda: _rim_points(ga, gb, region_uv, direction, level)))


def _rim_points(ga: geometry.SurfaceGeometry, gb: geometry.ColliderGeometry, region_uv: np.ndarray, direction: np.ndarray,
                level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Additional points at the rim of a surface's region in a collider, one sample step outside it
    (an interpretation of thesis eq. 4.16, docs/algorithm.md).

    Eq. 4.16 pins the middle of each finest-level patch's inside part. Under a box the surface
    must drop to the face it is pushed onto and rise again outside the box's outline; a C2 spline
    pinned at patch middles inside the outline starts rising before it, so it curls up inside
    the box between the last middle and the side face (case 2a: 2.85e-3 of the size deep between
    detection's samples while they report 5.3e-4). These points move that transition outside.

    Rim samples are region samples ``region_uv`` whose neighbour one grid step away (the
    detection density of their level-0 patch, `geometry.patch_density`) lies outside the collider;
    the crossing on that step is found by bisection, and the point is the crossing moved one more
    step outward. Its goal is on the plane through the rim samples' cast hits (along
    ``direction``, as for the middles) normal to ``direction``: the face the region is pushed
    onto, extended past the outline. Only crossings through a face steep to the push (a box's
    side face, ``|n·d| <= RIM_STEEP``) or facing it (``>= RIM_FACING``: a later round's sliver on
    that face, whose points hold the surface there) count: past a curved collider's flank the
    extended plane lies inside what the collider needs (measured: `elbow_contact`'s dent 1.34
    times the ball's depth, bound 1.3). Points already past the plane ask nothing and are
    dropped. The points are grouped per level-``level`` patch (mean parameters and hits).

    Parameters
    ----------
    region_uv : (k, 2) float64
        Parameters of ``ga``'s samples inside ``gb``.
    direction : (3,) float64
        The push direction (world).

    Returns
    -------
    uv : (r, 2) float64
        One rim point per patch that holds crossings.
    points : (r, 3) float64
        Their world positions on the surface now.
    goals : (r, 3) float64
        World goals, to blend by eq. 4.15's share like the middles' hits.
    """
    hs = ga.surface
    region_uv = np.asarray(region_uv, float).reshape(-1, 2)
    empty = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))
    unit = np.asarray(direction, float) / np.linalg.norm(direction)
    if not len(region_uv):
        return empty
    # A sample on an edge two patches share is a region sample twice, and each of its crossings
    # would be bisected twice: the distinct samples' crossings are found, and every row of the
    # region takes its sample's. Each answer is a function of its row's bits alone (evaluation,
    # inside test and cast go point by point), so a row keeps the bits it would get asked alone,
    # and the grouping below sums every region row's crossing, repeats included, in their order.
    first, at = meshrows.first_rows(_in_plane(region_uv))
    uv = region_uv[first]
    dens = geometry.patch_density(ga)
    pu = np.clip(np.floor(uv[:, 0]).astype(np.int64) % hs.u.patches0, 0, hs.u.patches0 - 1)
    pv = np.clip(np.floor(uv[:, 1]).astype(np.int64) % hs.v.patches0, 0, hs.v.patches0 - 1)
    miss, n = _missing_neighbours(hs, uv, 1.0 / dens[pu, pv])
    k = len(uv)
    src, hi = np.tile(np.arange(k), 4)[miss.reshape(-1)], n[miss]
    # the region's rows of `_missing_neighbours`' order (by direction, then the region's order),
    # each as its distinct sample's crossing
    row = (np.cumsum(miss.reshape(-1)) - 1).reshape(4, k)[:, at][miss[:, at]]
    if not len(src):
        return empty

    def world(uv):
        return apply_xform(ga.xform, H.evaluate(hs, *geometry.wrap_uv(hs, uv).T, det=ga.details).points)

    outside, crossed = _bisected(gb, world, uv[src], hi)  # a neighbour missing from the region may just be untessellated
    row = (np.cumsum(outside) - 1)[row[outside[row]]]
    step = hi[outside] - uv[src[outside]]
    src, hi = src[outside], crossed
    if not len(src):
        return empty
    use = _on_counted_faces(gb, unit, len(hi), lambda: world(hi))
    cast, slot = np.unique(src[use], return_inverse=True)  # each sample cast once, for each of its crossings
    s_hit, hit = D.cast(gb, world(uv[cast]), np.broadcast_to(unit, (len(cast), 3)))
    which = np.full(len(src), -1)
    which[use] = slot
    row = row[use[row]]  # every region row's counted crossing, its sample's cast
    s_hit, hit = s_hit[which[row]], hit[which[row]]
    cross = geometry.wrap_uv(hs, (hi + step)[row][hit])
    if not len(cross):
        return empty
    mids, _, inv = patch_groups(hs, cross, level)
    g = len(mids)
    plane = np.stack([np.bincount(inv, s_hit[hit, c], g) for c in range(3)], axis=1)
    plane /= np.bincount(inv, minlength=g)[:, None]  # mean hit of each patch's rim samples
    points = world(mids)
    ahead = (plane - points) @ unit
    keep = ahead > 0
    return mids[keep], points[keep], points[keep] + ahead[keep, None] * unit


RIM_PATHS = 2  # paths `_bisected` follows at most, per segment, before it asks a round's near points at once


def _bisected(gb: geometry.ColliderGeometry, world, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where segments from region samples ``lo (n, 2)`` (inside ``gb``) to their missing
    neighbours ``hi (n, 2)`` cross ``gb``'s surface: which neighbours lie outside ``(n,) bool``
    and, for those, the outer end ``(m, 2)`` after `RIM_BISECT` halvings, each keeping the half
    whose ends lie on either side (``world(uv)`` maps parameters to world points): the answer of
    asking `detect.inside` of the neighbours and of each halving's midpoints in turn.

    A point's side is `detect.collider_sides`' unless it lies within `detect.SIDE_SURE` of the
    mesh, where it is embree's ray parity (`detect.near_inside`), one trimesh call of about 0.1 ms
    whatever its points. A segment whose point is near is followed both ways, its path as if the
    point were outside and a copy as if inside, and every near point's parity is asked in one
    call at the end: each segment keeps the one path whose assumptions it confirms (the copies'
    arithmetic is the segment's own, so the same bits). A near point lies within 1e-6 of the size
    from a face and the next midpoint half a step farther, so a path meets another only at
    another face; beyond `RIM_PATHS` paths a segment, a round's near points are asked at once."""
    n = len(hi)
    local, inside, near = D.collider_sides(gb, world(hi))
    asked = [local[near]]  # the near points' object-space points, in the order asked
    count = int(near.sum())
    # per path: its segment, ends, and per round the near point it assumed the side of (-1 none)
    # and the side assumed (inside)
    ask = np.full((n, RIM_BISECT + 1), -1, np.int64)
    want = np.zeros((n, RIM_BISECT + 1), bool)
    ask[near, 0] = np.arange(count)
    go = near | ~inside
    seg, lo, hi, ask, want = np.flatnonzero(go), lo[go], hi[go], ask[go], want[go]
    for r in range(1, RIM_BISECT + 1):
        if not len(seg):
            break
        mid = 0.5 * (lo + hi)
        local, inside, near = D.collider_sides(gb, world(mid))
        if near.any() and len(seg) + int(near.sum()) > RIM_PATHS * n:
            inside[near] = D.near_inside(gb.static, local[near])
            near[:] = False
        k = np.flatnonzero(near)
        copy_hi = hi[k]  # a near point's copy: as if inside, from its midpoint to the path's outer end
        lo, hi = np.where((inside & ~near)[:, None], mid, lo), np.where((inside & ~near)[:, None], hi, mid)
        if len(k):
            ask[k, r] = count + np.arange(len(k))
            asked.append(local[k])
            count += len(k)
            copy_ask, copy_want = ask[k].copy(), want[k].copy()
            copy_want[:, r] = True
            seg, ask, want = np.concatenate([seg, seg[k]]), np.concatenate([ask, copy_ask]), np.concatenate([want, copy_want])
            lo, hi = np.concatenate([lo, mid[k]]), np.concatenate([hi, copy_hi])
    answer = D.near_inside(gb.static, np.concatenate(asked)) if count else np.zeros(0, bool)
    holds = np.all((ask < 0) | (answer[np.maximum(ask, 0)] == want), axis=1) if count else np.ones(len(seg), bool)
    outside = np.zeros(n, bool)
    outside[seg[holds]] = True
    end = np.empty((n, 2))
    end[seg[holds]] = hi[holds]
    return outside, end[outside]


def _on_counted_faces(gb: geometry.ColliderGeometry, unit: np.ndarray, n: int, points) -> np.ndarray:
    """Which of ``n`` crossings lie on a face of ``gb`` that counts for `_rim_points`, steep to the
    push ``unit (3,)`` (``|n·d| <= RIM_STEEP``) or facing it (``>= RIM_FACING``): ``(n,) bool``,
    by the face of each one's closest point; ``points()`` gives their world points ``(n, 3)``.
    A collider of at most `geometry.PLANES_MAX` faces that all count, each clear of both bounds by
    1e-9 (a box pushed along one of its axes), counts every crossing without finding its face."""
    normals = gb.static.mesh.face_normals
    if len(normals) <= geometry.PLANES_MAX:
        every = np.abs(geometry.world_normals(gb, normals) @ unit)
        if np.all((every <= RIM_STEEP - 1e-9) | (every >= RIM_FACING + 1e-9)):
            return np.ones(n, bool)
    face = gb.static.index.query(gb.to_object(points()))[2]
    nd = np.abs(geometry.world_normals(gb, normals[face]) @ unit)
    return (nd <= RIM_STEEP) | (nd >= RIM_FACING)


def _missing_neighbours(hs: H.HSpline, uv: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbours one step ``h (k,)`` away along ``+u, -u, +v, -v`` (in that order) of
    samples ``uv (k, 2)`` that are not samples themselves: ``miss (4, k) bool``, which of each
    direction's neighbours are missing, and the neighbours' parameters ``(4, k, 2)``, unwrapped.
    A neighbour past an open edge of the domain is none; one is a sample where a sample lies
    within ``1e-3 h`` of it, both wrapped into the domain.

    The distance to the nearest sample is `acra.kdtree`'s, scipy's arithmetic (in the plane ``z
    = 0`` the sum ``(du² + dv²) + 0`` is a 2-d tree's), so the answer is that of
    ``scipy.spatial.cKDTree.query``; the search passes over what lies beyond twice the largest
    such distance, where the answer (that bound) misses as the true distance would."""
    n = np.stack([uv + np.stack([du * h, dv * h], axis=1) for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1))])
    flat = n.reshape(-1, 2)
    ok = np.ones(len(flat), bool)
    for c, d in enumerate((hs.u, hs.v)):
        if not d.periodic:
            ok &= (flat[:, c] >= -1e-9) & (flat[:, c] <= d.patches0 + 1e-9)
    bound = 2e-3 * float(h.max())
    tree = kdtree.build(_in_plane(geometry.wrap_uv(hs, uv)))
    dist = np.sqrt(kdtree.nearest_squares(tree, _in_plane(geometry.wrap_uv(hs, flat)), best=np.full(len(flat), bound * bound)))
    return (ok & (dist > 1e-3 * np.tile(h, 4))).reshape(4, -1), n


def _in_plane(uv: np.ndarray) -> np.ndarray:
    """Parameters ``uv (k, 2)`` as points ``(k, 3)`` of the plane ``z = 0``."""
    out = np.zeros((len(uv), 3))
    out[:, :2] = uv
    return out
