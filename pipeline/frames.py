"""The frame loop: detect → respond → detect again, per frame, from the animator's shape.

Each frame starts from the animator's input at that time code (`usdio.state_at`), so frames are
independent and the run is stateless (thesis §2.5 "animator override"), except for a deformable
that carries state across frames (``acra:relax``, ``acra:plasticity``): it starts from the
animator's shape plus what it carried out of the previous frame (`pipeline.state`). Within a
frame the loop iterates: detect every pair, turn each contact into data points (thesis eq. 4.15–4.16), respond
every deformable (`acra.respond.respond`), and detect again, until the residual penetration of
every pair is within tolerance or the iteration cap is reached. Transforms are only read.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from pxr import Usd
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from acra import hspline as H
from acra import respond as R
from acra.interpolate import SystemTooLarge
from pipeline import contact as C
from pipeline import detect as D
from pipeline import display
from pipeline import residual
from pipeline import shape as S
from pipeline import state
from pipeline import usdio
from pipeline import output_layer
from pipeline.guard import format_size
from pipeline.model import InputError, SceneModel, apply_inverse, apply_xform

__all__ = ["FrameStats", "RunOptions", "run_frames", "respond_frames", "data_points_for", "collider_points_for", "rim_points",
           "visible_points"]


@dataclass(frozen=True)
class RunOptions:
    """Frame-loop settings.

    Attributes
    ----------
    iterations : int
        Cap on detect → respond rounds per frame.
    tolerance : float
        Residual penetration accepted, as a fraction of the deformable's size (the smaller of two deformables; contract: 1e-3).
    method : str
        Interpolation solver, ``"direct"`` or ``"blend"`` (iterated Bartels–Beatty).
    density : int
        Collision tessellation: least steps per level-0 patch edge (`detect.patch_density`).
    memory_budget : int, optional
        Bytes a response's direct solve may hold (`interpolate.dense_bytes`); ``None``: unbounded.
    """

    iterations: int = 4
    tolerance: float = 1e-3
    method: str = "direct"
    density: int = 8
    memory_budget: int | None = None


@dataclass
class FrameStats:
    """What one frame did (for the summary, the plots and the benchmark).

    Times are milliseconds (thesis Fig. 5.2's split): ``ms_setup`` building object-space shape data
    (`shape.Shape`, the analogue of RAPID's initial set-up), ``ms_detect`` detection queries less
    set-up, ``ms_convert`` contacts to data points, ``ms_respond`` the responses (``ms_respond_by``
    per deformable path), ``ms_visible`` measuring each round's residual where the user looks
    (`_Run.visible`), ``ms_output`` the run's display and its residual (`display.finish`);
    ``residual`` is the largest depth of a deformable's display inside another object in world
    units and ``residual_rel`` the largest over that deformable's display diagonal (docs/cli.md,
    *Residual penetration*): the kept round's on its own display during the loop, then the run's
    display's (`display.finish`).
    """

    frame: int
    in_collision: bool = False
    iterations: int = 0
    residual: float = 0.0
    residual_rel: float = 0.0
    ms_setup: float = 0.0
    ms_detect: float = 0.0
    ms_convert: float = 0.0
    ms_respond: float = 0.0
    ms_respond_by: dict = field(default_factory=dict)
    ms_output: float = 0.0
    ms_visible: float = 0.0
    ms_total: float = 0.0
    contacts: list = field(default_factory=list)
    data_points: dict = field(default_factory=dict)  # path -> (from (K, 3), target (K, 3)), world
    xforms: dict = field(default_factory=dict)  # path -> (4, 4) object-to-world, every object
    regions: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    volume_targets: dict = field(default_factory=dict)  # path -> ("volume" | "area", the animator's display measure)
    pair_residual_rel: dict = field(default_factory=dict)  # (path, other path) -> residual_rel of that pair


def _group_level(controls: R.Controls, depth: int) -> int:
    """Level whose patches get one additional point each: the finest absorbing level."""
    levels = np.nonzero(controls.absorption > 0)[0]
    return int(min(levels.max() if levels.size else 0, depth - 1))


STALLED = 0.1  # a patch's middle asking a move of at most this fraction of the patch's depth has stalled


def data_points_for(
    ga: D.SurfaceGeometry,
    gb: D.Geometry,
    uv: np.ndarray,
    p_self: np.ndarray,
    p_other: np.ndarray,
    region_uv: np.ndarray | None,
    share: float,
    group_level: int,
    direction: np.ndarray | None = None,
    region_depth: np.ndarray | None = None,
    settled: float = 0.0,
) -> tuple[R.DataPoints, np.ndarray]:
    """Data points of one surface of a pair, in its object space (thesis eq. 4.15–4.16).

    Parameters
    ----------
    uv : (2,) float64
        The contact's parameters on this surface.
    p_self, p_other : (3,) float64
        World contact points on this surface and on the other.
    region_uv : (k, 2) float64 or None
        Parameters of this surface's vertices inside the other object.
    share : float
        ``R`` of eq. 4.15 for this surface (0 moves it all the way to the other).
    direction : (3,) float64, optional
        Cast direction for the additional points; default ``p_other - p_self``. Later rounds of a
        frame pass the first round's direction: once a response has closed the gap between the
        contact points, their difference no longer says which way is out.
    region_depth : (k,) float64, optional
        Depths of the ``region_uv`` samples. With them, a patch whose middle has *stalled* (its
        cast asks a move of at most `STALLED` of the patch's depth, and that depth is more than
        ``settled``, a world length that counts as done) takes its deepest sample as its point
        instead (`respond.region_deepest`). Without this, a later round whose region is a sliver
        along the other object's edge pins middles already on their targets and moves nothing,
        however many rounds run (docs/hard-cases.md, case 7).
    settled : float
        See ``region_depth``.

    Against a collider, the patches at the region's rim take `rim_points` instead of
    their middles: eq. 4.16's middles all lie inside the region's outline, and a C2 surface
    pinned only there begins to rise back inside a box's outline and curls up inside the box
    between detection's samples.

    Returns
    -------
    DataPoints (object space of ``ga``), the world targets ``(K, 3)`` and the world points
    ``(K, 3)`` they move from (the surface before the response), for the preview's arrows.
    """
    target_p = R.contact_targets(p_self, p_other, share)
    uvs = [np.asarray(uv, float).reshape(1, 2)]
    targets = [target_p[None]]
    origins = [np.asarray(p_self, float).reshape(1, 3)]
    direction = p_other - p_self if direction is None else np.asarray(direction, float)
    size = ga.size
    if region_uv is not None and len(region_uv) and np.linalg.norm(direction) > 1e-9 * size:
        mids, _ = R.region_midpoints(ga.surface, region_uv, group_level)
        a_world = apply_xform(ga.xform, H.evaluate(ga.surface, mids[:, 0], mids[:, 1], det=ga.details).points)
        hits, valid = D.cast(gb, a_world, np.broadcast_to(direction, a_world.shape))
        if region_depth is not None:
            deep, depth = R.region_deepest(ga.surface, region_uv, region_depth, group_level)
            stalled = np.nonzero(valid & (depth > settled) & (np.linalg.norm(hits - a_world, axis=1) <= STALLED * depth))[0]
            if stalled.size:
                d_world = apply_xform(ga.xform, H.evaluate(ga.surface, deep[stalled, 0], deep[stalled, 1], det=ga.details).points)
                d_hits, d_valid = D.cast(gb, d_world, np.broadcast_to(direction, d_world.shape))
                use = stalled[d_valid]
                mids[use], a_world[use], hits[use] = deep[use], d_world[d_valid], d_hits[d_valid]
        wanted = R.additional_targets(a_world, hits, share)
        if isinstance(gb, D.ColliderGeometry):
            r_uv, r_world, r_goal = rim_points(ga, gb, region_uv, direction, group_level)
            if len(r_uv):  # a rim patch's point is its rim point, not its middle
                valid &= ~np.isin(R.patch_keys(ga.surface, mids, group_level), R.patch_keys(ga.surface, r_uv, group_level))
                mids, a_world = np.concatenate([mids, r_uv]), np.concatenate([a_world, r_world])
                wanted = np.concatenate([wanted, R.additional_targets(r_world, r_goal, share)])
                valid = np.concatenate([valid, np.ones(len(r_uv), bool)])
        valid &= _spread(a_world, np.asarray(p_self, float), MEET * size)
        if np.any(valid):
            uvs.append(mids[valid])
            targets.append(wanted[valid])
            origins.append(a_world[valid])
    uv_all = np.concatenate(uvs)
    world = np.concatenate(targets)
    is_contact = np.zeros(len(uv_all), bool)
    is_contact[0] = True
    return R.DataPoints(uv_all, apply_inverse(ga.xform, world), is_contact), world, np.concatenate(origins)


WRAP_RING = 1  # patches around the ones a collider's outline covers that a new pocket pushes too


def collider_points_for(
    ga: D.SurfaceGeometry,
    gb: D.ColliderGeometry,
    region_a: D.Region,
    region_b: D.Region,
    direction: np.ndarray,
    share: float,
    group_level: int,
    clear: float = 0.0,
    first: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Additional points (eq. 4.16) of a closed surface ``ga`` with a collider ``gb`` inside it:
    the wall in front of the collider, pushed along ``direction`` past it (a pocket).

    Eq. 4.16 takes additional points from a surface's own region, its samples inside the other
    object. A collider wholly inside a closed surface leaves that region empty (no sample of a
    sphere lies inside a box inside it), so the wall would get the contact point alone, which
    pulls a thin finger that neither wraps the box nor clears it (docs/hard-cases.md, case 3).
    Here both sides give the wall's samples:

    * the collider's faces inside ``ga`` (`detect.face_samples`, at most half a group-level
      patch's size apart, near the regions), cast along ``-direction`` onto the wall in front of them
      (`detect.cast`: from inside, the exit ahead); such a wall point must get, along
      ``direction``, to where the line through the sample leaves the collider (its far side);
    * ``ga``'s own vertices inside the collider (``region_a``), which must get to where their
      line along ``direction`` leaves it (eq. 4.16's own cast).

    Each sample's *lag* is how far along ``direction`` it must still go. The points are one per
    group-level patch holding samples, at the patch's parametric centre, moved along ``direction``
    by the patch's largest lag plus ``clear`` (a world length; the frame loop passes what counts
    as done, so a wall between two points that sags by up to that much still clears the collider).
    Patch centres on a regular grid keep the interpolation well conditioned, where the samples
    crowd; and the largest lag lets no sample of the patch lag behind the point's move. A first
    round (``first``, the pocket being made) also pushes the patches within `WRAP_RING` of those,
    each centre to the farthest plane along ``direction`` its neighbours must reach: a C2
    surface through points of the covered patches alone falls off before the collider's outline.
    Later rounds move only patches with lagging samples, by their lag: measured, re-deciding the
    ring from a pocket's rim made a round push patches outside the box by a third of the size.

    Parameters
    ----------
    region_a, region_b : Region
        ``ga``'s vertices inside the collider and the collider's inside ``ga`` (`detect.regions`).
    direction : (3,) float64
        The push: ``ga`` moves along it relative to the collider (the frame's first ``P_B - P_A``).
    share : float
        ``R`` of eq. 4.15 (0 against a collider: all the way).
    group_level : int
        The finest absorbing level: one point per patch of it.
    clear : float
        World length the points go past the collider.
    first : bool
        The pair's first round of the frame (the ring).

    Returns
    -------
    uv : (g, 2) float64
        Parameters of the points on ``ga`` (patch centres, level-0 units).
    target : (g, 3) float64
        World targets, ``R A + (1 - R) B`` of eq. 4.16 with ``B`` the point moved as above.
    origin : (g, 3) float64
        World points before the move.
    """
    none = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))
    length = np.linalg.norm(direction)
    pts = np.concatenate([region_a.points, region_b.points])
    if not len(pts) or not ga.closed or length <= 1e-9 * ga.size:
        return none
    unit = np.asarray(direction, float) / length
    hs = ga.surface
    spacing = 0.5 * ga.size / (max(hs.u.patches0, hs.v.patches0) << group_level)
    s = D.face_samples(gb, np.stack([pts.min(axis=0) - spacing, pts.max(axis=0) + spacing]), spacing)
    s = s[D.inside(ga, s)]
    wall, ok = D.cast(ga, s, np.broadcast_to(-unit, s.shape), within=np.ones(len(s), bool))
    # where the line through each sample leaves the collider along the push (the sample itself if
    # the push takes it straight out)
    ahead = s + 2.0 * D.ON_SURFACE * max(ga.size, gb.size) * unit
    far = s.copy()
    into = D.inside(gb, ahead)
    if into.any():
        exit_, got = D.cast(gb, ahead[into], np.broadcast_to(unit, ahead[into].shape), within=np.ones(int(into.sum()), bool))
        far[np.nonzero(into)[0][got]] = exit_[got]
    uv = np.full((len(s), 2), np.nan)
    if ok.any():
        uv[ok] = D.project(ga, wall[ok]).uv
    if not region_a.empty:
        exit_, got = D.cast(gb, region_a.points, np.broadcast_to(unit, region_a.points.shape),
                            within=np.ones(len(region_a.points), bool))
        wall, far = np.concatenate([wall, region_a.points]), np.concatenate([far, exit_])
        uv, ok = np.concatenate([uv, region_a.uv]), np.concatenate([ok, got])
    lag = (far - wall) @ unit
    ok &= lag > 0
    if not ok.any():
        return none
    uv, lag, plane = uv[ok], lag[ok], far[ok] @ unit
    su, sv = np.divmod(R.patch_keys(hs, uv, group_level), hs.v.patches(group_level))
    shape = (hs.u.patches(group_level), hs.v.patches(group_level))
    most, need = np.full(shape, -np.inf), np.full(shape, -np.inf)
    np.maximum.at(most, (su, sv), lag)
    np.maximum.at(need, (su, sv), plane)
    # each patch takes the farthest plane within WRAP_RING of it (a periodic direction wraps,
    # nothing lies past an open edge)
    need = maximum_filter(need, size=2 * (WRAP_RING if first else 0) + 1, cval=-np.inf,
                          mode=["wrap" if d.periodic else "constant" for d in (hs.u, hs.v)])
    pp = np.argwhere(np.isfinite(need))
    mid = (pp + 0.5) / (1 << group_level)
    a = apply_xform(ga.xform, H.evaluate(hs, mid[:, 0], mid[:, 1], det=ga.details).points)
    move = most[pp[:, 0], pp[:, 1]]
    if first:
        move = np.maximum(move, need[pp[:, 0], pp[:, 1]] - a @ unit)
    go = move > 0
    b = a[go] + (move[go, None] + clear) * unit
    return mid[go], R.additional_targets(a[go], b, share), a[go]


RIM_STEEP = 0.5  # |n·d| at most this: a collider face the surface must drop along (a box's side)
RIM_FACING = 0.95  # |n·d| at least this: the face the region is pushed onto (a later round's sliver)
RIM_BISECT = 6  # bisection steps locating a crossing between two samples (1/64 of the step)


def rim_points(ga: D.SurfaceGeometry, gb: D.ColliderGeometry, region_uv: np.ndarray, direction: np.ndarray,
               level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Additional points at the rim of a surface's region in a collider, one sample step outside it
    (an interpretation of thesis eq. 4.16, docs/algorithm.md).

    Eq. 4.16 pins the middle of each finest-level patch's inside part. Under a box the surface
    must drop to the face it is pushed onto and rise again outside the box's outline; a C2 spline
    pinned at patch middles inside the outline starts rising before it, so it curls up inside
    the box between the last middle and the side face (case 2a: 2.85e-3 of the size deep between
    detection's samples while they report 5.3e-4). These points move that transition outside.

    Rim samples are region samples ``region_uv`` whose neighbour one grid step away (the
    detection density of their level-0 patch, `detect.patch_density`) lies outside the collider;
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
    dens = D.patch_density(ga)
    pu = np.clip(np.floor(region_uv[:, 0]).astype(np.int64) % hs.u.patches0, 0, hs.u.patches0 - 1)
    pv = np.clip(np.floor(region_uv[:, 1]).astype(np.int64) % hs.v.patches0, 0, hs.v.patches0 - 1)
    h = 1.0 / dens[pu, pv]
    tree = cKDTree(D.wrap_uv(hs, region_uv))
    src, out = [], []
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        n = region_uv + np.stack([du * h, dv * h], axis=1)
        ok = np.ones(len(n), bool)
        for c, d in enumerate((hs.u, hs.v)):
            if not d.periodic:  # no neighbour past an open edge of the domain
                ok &= (n[:, c] >= -1e-9) & (n[:, c] <= d.patches0 + 1e-9)
        dist, _ = tree.query(D.wrap_uv(hs, n))
        miss = ok & (dist > 1e-3 * h)
        src.append(np.nonzero(miss)[0])
        out.append(n[miss])
    src, hi = np.concatenate(src), np.concatenate(out)
    if not len(src):
        return empty

    def world(uv):
        return apply_xform(ga.xform, H.evaluate(hs, *D.wrap_uv(hs, uv).T, det=ga.details).points)

    outside = ~D.inside(gb, world(hi))  # a neighbour missing from the region may just be untessellated
    src, hi = src[outside], hi[outside]
    lo = region_uv[src]
    if not len(src):
        return empty
    step = hi - lo
    for _ in range(RIM_BISECT):
        mid = 0.5 * (lo + hi)
        m_in = D.inside(gb, world(mid))[:, None]
        lo, hi = np.where(m_in, mid, lo), np.where(m_in, hi, mid)
    face = gb.static.index.query(apply_inverse(gb.xform, world(hi)))[2]
    nd = np.abs(D.world_normals(gb, gb.static.mesh.face_normals[face]) @ unit)
    use = (nd <= RIM_STEEP) | (nd >= RIM_FACING)
    s_hit, hit = D.cast(gb, world(region_uv[src[use]]), np.broadcast_to(unit, (int(use.sum()), 3)))
    cross = D.wrap_uv(hs, (hi + step)[use][hit])
    if not len(cross):
        return empty
    mids, _, inv = R.patch_groups(hs, cross, level)
    g = len(mids)
    plane = np.stack([np.bincount(inv, s_hit[hit, c], g) for c in range(3)], axis=1)
    plane /= np.bincount(inv, minlength=g)[:, None]  # mean hit of each patch's rim samples
    points = world(mids)
    ahead = (plane - points) @ unit
    keep = ahead > 0
    return mids[keep], points[keep], points[keep] + ahead[keep, None] * unit


def visible_points(ga: D.SurfaceGeometry, gb: D.Geometry, inside: residual.Inside, direction: np.ndarray | None,
                   share: float, group_level: int, clear: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Additional points (eq. 4.16) from what the user sees: the display's own points inside the
    other object (`residual.Inside`), where the limit surface may already be clear.

    A display triangle is a chord of the surface: where a response wraps a convex part of the
    other object (a dent around a tip), the chords lie on the concave side, inside the other
    object, while the limit surface on detection's samples is out. Eq. 4.16 on the display's
    samples: per patch of the finest absorbing level, the deepest display point inside is cast
    along ``direction`` (the pair's push; ``None``: its nearest way out) to where it leaves the
    other object, and the surface point at the same parameters is asked to move as far, plus
    ``clear`` (a world length: what counts as done), so the chord that holds the display point
    moves out with its corners.

    Returns
    -------
    uv : (g, 2) float64
        Parameters on ``ga`` (level-0 units).
    target : (g, 3) float64
        World targets, ``R A + (1 - R) B`` of eq. 4.16 with ``B`` the surface point moved as above.
    origin : (g, 3) float64
        World surface points before the move.
    """
    empty = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))
    if inside.uv is None or not len(inside.uv):
        return empty
    hs = ga.surface
    uv = D.wrap_uv(hs, inside.uv)
    keys = R.patch_keys(hs, uv, group_level)
    order = np.lexsort((inside.deep, keys))  # by patch, deepest last
    rows = order[np.r_[keys[order][1:] != keys[order][:-1], True]]
    uv, shown = uv[rows], inside.points[rows]
    if direction is None or np.linalg.norm(direction) <= 1e-12 * ga.size:
        unit = D.surface_distance(gb, shown)[1] - shown
        length = np.linalg.norm(unit, axis=1)
        ok = length > 0
        uv, shown, unit = uv[ok], shown[ok], unit[ok] / length[ok, None]
    else:
        unit = np.broadcast_to(np.asarray(direction, float) / np.linalg.norm(direction), shown.shape)
    if not len(uv):
        return empty
    hits, valid = D.cast(gb, shown, unit, within=np.ones(len(shown), bool))
    move = np.einsum("ij,ij->i", hits - shown, unit) + clear
    valid &= move > 0
    origin = D.surface_points(ga, uv[valid]).points
    goal = origin + move[valid, None] * unit[valid]
    return uv[valid], R.additional_targets(origin, goal, share), origin


def _with_shown(region: D.Region, shown) -> tuple[np.ndarray | None, np.ndarray]:
    """A region's parameters ``(k, 2)`` and depths ``(k,)`` joined by the display's own points
    inside the other object (``shown``, a `residual.PairDepth` or ``None``): eq. 4.16's region as
    detection's samples of the limit surface and the user's display see it together, so a part
    that sinks between detection's samples still gets its patch's point."""
    if shown is None or shown.inside.uv is None or not len(shown.inside.uv):
        return region.uv, region.depth
    return (np.concatenate([region.uv.reshape(-1, 2), shown.inside.uv]),
            np.concatenate([region.depth, shown.inside.deep]))


def _spread(points: np.ndarray, contact: np.ndarray, radius: float) -> np.ndarray:
    """Which additional points ``points (g, 3)`` to keep so no two kept points, and no kept point
    and the contact point ``contact (3,)``, are within ``radius`` (greedy, in order).

    Near a pole or a collapsed edge many patch midpoints crowd into one spot (at a pole, exactly
    one point under many parameters). Closer than the tolerance they cannot ask the surface for
    anything the tolerance could see, but their nearly equal rows make the interpolation
    ill-conditioned: measured on `dog_head_spike`'s spike tip, 46 points within 0.04 of each
    other moved the tip 2.6e-3 of the size where no point asked more than 4e-4."""
    keep = np.ones(len(points), bool)
    if len(points) == 0:
        return keep
    keep &= np.linalg.norm(points - contact, axis=1) > radius
    tree = cKDTree(points)
    for i, j in sorted(tree.query_pairs(radius)):
        if keep[i]:
            keep[j] = False
    return keep


CLEAR = 0.25  # display points are moved this fraction of the tolerance past the other surface (`visible_points`)
MEET = 1e-3  # rewound contact points this close (fraction of the size) meet, whatever the run's tolerance


def _deepest_instead(ga: D.SurfaceGeometry, gb: D.Geometry, c: C.PairContact) -> C.PairContact:
    """The contact of a later round between two deformables whose rewound contact points
    already meet while only one side has vertices inside the other: the deepest region vertex
    and its closest point on the other surface (`contact.deepest_contact`).

    The first round moves the first-touch points onto a common target (eq. 4.15); once they
    meet (closer than the larger of the run's tolerance and `MEET`, so a run asked for 1e-9
    keeps the rule), their data point only pins the surface there. If the other side has no
    vertex inside (a sharp tip in a smooth dent: eq. 4.16 gives it no additional point), nothing
    moves it further and the tip stays inside: measured on `dog_head_spike`, later rounds never lowered
    the largest residual (docs/speed-vs-error.md). With both regions present the additional
    points of both sides carry the rest, and the first-touch pair keeps the rigidity split; a
    collider does not move, so the deformable's own additional points carry the rest (measured:
    the deepest pair there pushes sheets toward a box's side faces and slows convergence)."""
    uv_a, uv_b, local_b, pa, pb = C.deepest_contact(ga, gb, c.region_a, c.region_b, c.intersections)
    return replace(c, uv_a=uv_a, uv_b=uv_b, local_b=local_b, point_a=pa, point_b=pb)


def _respond_bounded(path: str, frame: int, parent: H.HSpline, dp: R.DataPoints, controls: R.Controls,
                     options: RunOptions):
    """`respond.respond` with each direct solve's dense arrays bounded by the run's memory budget.

    How many CVs a contact moves on an absorbing level is known only once the contact is found
    (a fine absorbing level under a wide contact gives thousands), so this bound is checked at the
    solve, before it allocates; going over it refuses the deformable's absorption in one line.
    """
    try:
        return R.respond(parent, dp, controls, method=options.method,
                         det=S.shape_of(parent, options.density).details, max_bytes=options.memory_budget)
    except SystemTooLarge as err:
        raise InputError(path, "acra:absorption", (
            f"at frame {frame} the response's solve of {err.points} data points on {err.cvs} CVs would need "
            f"{format_size(err.nbytes)}, over the memory budget of {format_size(err.limit)}; absorb on a coarser "
            f"level or raise --memory-budget")) from None


def _pairs(n_def: int, n_col: int):
    """Every deformable–deformable pair once and every deformable–collider pair."""
    for i in range(n_def):
        for j in range(i + 1, n_def):
            yield i, ("d", j)
        for j in range(n_col):
            yield i, ("c", j)


def run_frames(
    stage: Usd.Stage,
    scene: SceneModel,
    frames: list[int],
    options: RunOptions = RunOptions(),
    on_frame: Callable[[FrameStats, output_layer.FramesResult], None] | None = None,
    initial: list | None = None,
) -> tuple[output_layer.FramesResult, list[FrameStats]]:
    """Process ``frames`` and return the per-frame results to write and their statistics:
    `respond_frames`, then the run's display and every frame's residual on it
    (`display.finish`). ``on_frame(stats, result)`` is called as each frame's responses are done
    (its display and final residual come after the last frame)."""
    result, stats = respond_frames(stage, scene, frames, options, on_frame, initial)
    display.finish(stage, scene, result, stats, options)
    return result, stats


def respond_frames(
    stage: Usd.Stage,
    scene: SceneModel,
    frames: list[int],
    options: RunOptions = RunOptions(),
    on_frame: Callable[[FrameStats, output_layer.FramesResult], None] | None = None,
    initial: list | None = None,
) -> tuple[output_layer.FramesResult, list[FrameStats]]:
    """Respond every frame of ``frames``: the results' surfaces (points left ``None``, the display
    is chosen from all of them, `display.finish`) and their statistics, whose residual is measured
    on each surface's own display.

    A deformable that carries state across frames (`pipeline.state`) starts each frame from the
    animator's shape plus what it carried out of the previous one: ``initial`` (per deformable,
    `acra.relax.Carried` or ``None``) is what it carries into ``frames[0]``; without it, that is
    recomputed from the stage's start (`state.carried_at`).

    BLAS runs single-threaded here: ACRA's systems are small (a Gram matrix per object, K ≲ a few
    hundred), and a threaded OpenBLAS on a busy 2-core machine made a 100×100 ``eigh`` take
    272 ms instead of 1.8 ms (measured; `docs/performance.md`).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _run_frames(stage, scene, frames, options, on_frame, initial)


@dataclass
class _Round:
    """One detection pass over every pair (`_Run.detect`).

    ``found`` holds ``(i, other, PairContact)`` of the pairs to respond to, ``settled`` per pair the
    world move that counts as done (the tolerance or `MEET` times the pair's size), ``pair_rel``
    each pair's residual over its size, ``worst`` and ``worst_rel`` the largest residual in world
    units and over size."""

    found: list
    settled: dict
    pair_rel: dict
    worst: float
    worst_rel: float


class _Run:
    """What a run keeps across frames and the steps of one frame.

    Kept across frames: each collider's prepared mesh, the input states by time code (an
    unchanged input surface handed back as the same object, so its object-space `shape.Shape` is
    reused), the display of each distinct surface, each pair's rewinding cache, and the carried
    state (`pipeline.state`). A frame (`frame`) is rounds of `detect` → `data_points` (eq.
    4.15–4.16) → `respond` until the residual is within tolerance or the cap is reached; the
    round with the least residual where the user looks (`visible`) is kept.
    """

    def __init__(self, stage: Usd.Stage, scene: SceneModel, options: RunOptions, carry) -> None:
        self.stage, self.scene, self.options, self.carry = stage, scene, options, carry
        self.statics = [D.prepare_collider(c) for c in scene.colliders]
        self.defs = scene.deformables
        self.controls = [m.controls for m in self.defs]
        self.caches: dict = {}  # (i, other) -> contact.RewindCache
        self.state_memo: dict = {}
        self.canonical: list = [None] * len(self.defs)  # last input surface of each deformable
        self.displays = display.Displays(options.density, 4 * len(self.defs) + 4)
        self._shown: dict = {}  # (id(surface), world matrix) -> (surface, residual.Shown), most recent last
        self._collider_solids: dict = {}  # collider row -> its inside (`residual.collider_solid`)

    def states(self, t: float):
        """``(deformable states, collider states)`` at time code ``t`` (`usdio.state_at`)."""
        if t not in self.state_memo:
            if len(self.state_memo) > 64:
                self.state_memo.clear()
            dstates, cstates = usdio.state_at(self.stage, self.scene, t)
            for i, s in enumerate(dstates):  # unchanged input CVs: hand back the same surface, so
                c = self.canonical[i]        # its object-space Shape (shape.shape_of) is reused
                if c is not None and np.array_equal(c.cvs, s.surface.cvs):
                    dstates[i] = replace(s, surface=c)
                else:
                    self.canonical[i] = s.surface
            self.state_memo[t] = (dstates, cstates)
        return self.state_memo[t]

    def geometry(self, kind_j, t):
        """The input geometry of a deformable (``("d", j)``) or a collider (``("c", j)``) at ``t``,
        for rewinding the motion."""
        dstates, cstates = self.states(t)
        kind, j = kind_j
        if kind == "d":
            return D.SurfaceGeometry(dstates[j].surface, dstates[j].xform, name=self.defs[j].path, density=self.options.density)
        return D.ColliderGeometry(self.statics[j], cstates[j].xform)

    def detect(self, frame: int, it: int, geoms: list, cgeoms: list, sizes: list, enabled: list) -> _Round:
        """Detect every pair with an enabled deformable (round ``it`` of ``frame``)."""
        defs, options = self.defs, self.options
        rnd = _Round([], {}, {}, 0.0, 0.0)
        for i, other in _pairs(len(defs), len(self.statics)):
            if not enabled[i] and (other[0] == "c" or not enabled[other[1]]):
                continue
            gb = geoms[other[1]] if other[0] == "d" else cgeoms[other[1]]
            key = (i, other)
            cache = self.caches.setdefault(key, C.RewindCache())
            at = lambda t, i=i, other=other: (self.geometry(("d", i), t), self.geometry(other, t))  # noqa: E731
            # without motion to rewind, the first round picks the way out the whole region
            # needs least; later rounds clear what the response left, each vertex its nearest way
            c = C.detect_pair(geoms[i], gb, float(frame), at, start=float(self.scene.start), cache=cache, whole=it == 0)
            if c is None:
                continue
            # the contract's "object size": the deformable's own (the smaller one of two deformables)
            size = sizes[i] if other[0] == "c" else min(sizes[i], sizes[other[1]])
            rnd.worst = max(rnd.worst, c.penetration)
            rnd.worst_rel = max(rnd.worst_rel, c.penetration / size)
            other_path = defs[other[1]].path if other[0] == "d" else self.scene.colliders[other[1]].path
            rnd.pair_rel[defs[i].path, other_path] = c.penetration / size
            meet = rnd.settled[key] = max(options.tolerance, MEET) * size
            if it > 0 and other[0] == "d" and c.region_a.empty != c.region_b.empty and np.linalg.norm(c.push) <= meet:
                c = _deepest_instead(geoms[i], gb, c)
            if c.penetration > options.tolerance * size or it == 0:
                rnd.found.append((i, other, c))
        return rnd

    def collider_solid(self, j: int):
        """Collider ``j``'s inside in its object space, built on first use (`residual.collider_solid`)."""
        if j not in self._collider_solids:
            c = self.scene.colliders[j]
            self._collider_solids[j] = residual.collider_solid(c.vertices, c.triangles)
        return self._collider_solids[j]



    def visible(self, geoms: list, cgeoms: list, enabled: list) -> tuple[residual.FrameResidual, dict]:
        """The round's residual where the user looks (`pipeline.residual`): each deformable's own
        adaptive display (`display.Displays`) in every other closed object whose box meets its
        own, for the pairs `detect` tests. Returns it and, per pair ``(i, other)``, the
        `residual.Inside` of ``i`` in ``other`` and (a deformable ``other``) of ``other`` in ``i``."""
        shown: dict = {}

        def obj(kind: str, j: int) -> residual.Shown:
            if (kind, j) not in shown:
                if kind == "d":
                    g, m = geoms[j], self.defs[j]
                    key = (id(g.surface), g.xform.tobytes())
                    hit = self._shown.pop(key, None)
                    if hit is None or hit[0] is not g.surface:  # a surface shown at this place is reused
                        sd = self.displays.of(g.surface, m.controls.samples)
                        hit = (g.surface, residual.shown(m.path, sd.points, sd.triangles, g.xform, sd.uv, g.closed,
                                                         g.shape.outward if g.closed else 1.0, sd.solid))
                    self._shown[key] = hit
                    while len(self._shown) > 4 * len(self.defs) + 4:
                        del self._shown[next(iter(self._shown))]
                    shown[kind, j] = hit[1]
                else:
                    g = cgeoms[j]
                    shown[kind, j] = residual.collider_shown(g.name, g.bounds, g.size, self.collider_solid(j), g.xform)
            return shown[kind, j]

        objects, index, pairs, keys = [], {}, [], []
        for i, other in _pairs(len(self.defs), len(self.statics)):
            if not enabled[i] and (other[0] == "c" or not enabled[other[1]]):
                continue
            ga, gb = geoms[i], (geoms[other[1]] if other[0] == "d" else cgeoms[other[1]])
            if not D._boxes_overlap(ga, gb, D.pair_pad(ga, gb)):
                continue
            for kind_j in (("d", i), other):
                if kind_j not in index:
                    index[kind_j] = len(objects)
                    objects.append(obj(*kind_j))
            pairs.append((index["d", i], index[other]))
            keys.append(((i, other), "a"))
            if other[0] == "d":
                pairs.append((index[other], index["d", i]))
                keys.append(((i, other), "b"))
        fr = residual.measure_frame(objects, self.options.tolerance, pairs)
        by_pair: dict = {}
        measured = {(p.a, p.b): p for p in fr.pairs}
        for (ia, ib), (key, side) in zip(pairs, keys):
            p = measured.get((objects[ia].path, objects[ib].path))
            if p is not None:
                by_pair.setdefault(key, {})[side] = p
        return fr, by_pair

    def data_points(self, rnd: _Round, geoms: list, cgeoms: list, sizes: list, enabled: list, surfaces: list,
                    directions: dict, wrapping: set, over: dict | None = None, seen: dict | None = None) -> dict:
        """Eq. 4.15–4.16: each responding deformable's data points for this round's contacts, as
        ``{i: [(DataPoints, world targets (k, 3), world starts (k, 3)), ...]}``. ``directions`` keeps
        each pair's first push of the frame, ``wrapping`` the collider pairs pushed by
        `collider_points_for` (both updated). ``over`` holds, per pair whose display is still over
        the tolerance where the user looks, its `residual.PairDepth` per side (``"a"``: the
        deformable in the other, ``"b"``: the other deformable in it): those sides get
        `visible_points` too."""
        controls = self.controls
        points: dict[int, list] = {}
        seen = {} if seen is None else seen
        for i, other, c in rnd.found:
            gb = geoms[other[1]] if other[0] == "d" else cgeoms[other[1]]
            r_other = None if other[0] == "c" or not enabled[other[1]] else controls[other[1]].rigidity
            if enabled[i]:
                share = R.rigidity_share(controls[i].rigidity, r_other)
                push = directions.setdefault((i, other), c.push)
                # a collider with vertices inside a closed surface: the wall in front of it is pushed
                # past it along the push, its own region included (`collider_points_for`); every
                # later round of the frame does the same, so the pocket keeps its direction
                wrap = other[0] == "c" and (not c.region_b.empty or (i, other) in wrapping)
                clear = rnd.settled[(i, other)] if wrap else 0.0
                p_other = (c.point_b + c.slide) + clear * push / max(np.linalg.norm(push), 1e-300)
                r_uv, r_depth = _with_shown(c.region_a, seen.get((i, other), {}).get("a"))
                dp, world, start = data_points_for(geoms[i], gb, c.uv_a, c.point_a, p_other, None if wrap else r_uv,
                                                   share, _group_level(controls[i], surfaces[i].depth), push,
                                                   r_depth, rnd.settled[(i, other)])
                points.setdefault(i, []).append((dp, world, start))
                if wrap:
                    uv, world, start = collider_points_for(geoms[i], gb, c.region_a, c.region_b, push, share,
                                                           _group_level(controls[i], surfaces[i].depth), clear,
                                                           (i, other) not in wrapping)
                    wrapping.add((i, other))
                    keep = _spread(start, c.point_a, MEET * sizes[i])
                    if keep.any():
                        dp = R.DataPoints(uv[keep], apply_inverse(geoms[i].xform, world[keep]), np.zeros(int(keep.sum()), bool))
                        points[i].append((dp, world[keep], start[keep]))
            if other[0] == "d" and enabled[other[1]]:
                j = other[1]
                share = R.rigidity_share(controls[j].rigidity, controls[i].rigidity if enabled[i] else None)
                push = -directions.setdefault((i, other), c.push)
                r_uv, r_depth = _with_shown(c.region_b, seen.get((i, other), {}).get("b"))
                dp, world, start = data_points_for(geoms[j], geoms[i], c.uv_b, c.point_b, c.point_a - c.slide, r_uv, share,
                                                   _group_level(controls[j], surfaces[j].depth), push,
                                                   r_depth, rnd.settled[(i, other)])
                points.setdefault(j, []).append((dp, world, start))
        for (i, other), sides in (over or {}).items():
            for side, pd in sides.items():
                me, them = (("d", i), other) if side == "a" else (other, ("d", i))
                j = me[1]
                if not enabled[j]:
                    continue
                gm, gt = geoms[j], (geoms[them[1]] if them[0] == "d" else cgeoms[them[1]])
                r_them = controls[them[1]].rigidity if them[0] == "d" and enabled[them[1]] else None
                push = directions.get((i, other))
                push = None if push is None else (push if side == "a" else -push)
                clear = CLEAR * self.options.tolerance * gm.size
                uv, world, start = visible_points(gm, gt, pd.inside, push, R.rigidity_share(controls[j].rigidity, r_them),
                                                  _group_level(controls[j], surfaces[j].depth), clear)
                if not len(uv):
                    continue
                # eq. 4.16 gives a patch of the finest absorbing level one point: a patch already
                # holding one of detection's keeps it (two targets in one patch fight in the
                # interpolation, and the surface swings between them from round to round)
                level = _group_level(controls[j], surfaces[j].depth)
                taken = np.concatenate([d.uv for d, _, _ in points.get(j, [])] or [np.zeros((0, 2))])
                keep = ~np.isin(R.patch_keys(gm.surface, uv, level), R.patch_keys(gm.surface, taken, level))
                keep &= _spread(start, np.full(3, np.inf), MEET * gm.size)
                if keep.any():
                    dp = R.DataPoints(uv[keep], apply_inverse(gm.xform, world[keep]), np.zeros(int(keep.sum()), bool))
                    points.setdefault(j, []).append((dp, world[keep], start[keep]))
        return points

    def respond(self, frame: int, it: int, st: FrameStats, points: dict, surfaces: list) -> None:
        """Respond every deformable with data points (thesis §4.3), replacing its surface in
        ``surfaces``; the first round's data points go to ``st`` for the preview."""
        for i, lst in points.items():
            t_i = time.perf_counter()
            dp = R.DataPoints(
                np.concatenate([d.uv for d, _, _ in lst]),
                np.concatenate([d.target for d, _, _ in lst]),
                np.concatenate([d.is_contact for d, _, _ in lst]),
            )
            parent = surfaces[i]
            path = self.defs[i].path
            surfaces[i], rep = _respond_bounded(path, frame, parent, dp, self.controls[i], self.options)
            S.seed_details(surfaces[i], rep.details, self.options.density, parent=parent)
            surfaces[i] = self.carry.after_response(i, parent, surfaces[i])
            if it == 0:
                st.data_points[path] = (np.concatenate([o for _, _, o in lst]), np.concatenate([w for _, w, _ in lst]))
            ms = 1e3 * (time.perf_counter() - t_i)
            st.ms_respond += ms
            st.ms_respond_by[path] = st.ms_respond_by.get(path, 0.0) + ms

    def frame(self, frame: int, result: output_layer.FramesResult) -> FrameStats:
        """Process ``frame``: rounds of detect → data points → respond from the animator's shape
        (plus what is carried), keep the round with the least residual, add its display to
        ``result``; return the frame's statistics."""
        defs, options = self.defs, self.options
        t0 = time.perf_counter()
        st = FrameStats(frame)
        dstates, cstates = self.states(float(frame))
        st.xforms = {m.path: s.xform for m, s in zip(defs, dstates)}
        st.xforms.update({c.path: s.xform for c, s in zip(self.scene.colliders, cstates)})
        surfaces = self.carry.begin(frame, [s.surface for s in dstates])
        enabled = [s.enabled for s in dstates]
        directions: dict = {}
        wrapping: set = set()  # collider pairs pushed by `collider_points_for` this frame
        best = (np.inf, list(surfaces))
        rounds = max(1, options.iterations)
        for it in range(rounds + 1):
            geoms = [D.SurfaceGeometry(surfaces[i], dstates[i].xform, name=defs[i].path, density=options.density) for i in range(len(defs))]
            cgeoms = [D.ColliderGeometry(self.statics[j], cstates[j].xform) for j in range(len(self.statics))]
            if it == 0:  # the animator's surfaces: detection's scale stays fixed while rounds reshape them
                sizes = [g.size for g in geoms]
            td, setup0 = time.perf_counter(), S.SetupClock.ms
            rnd = self.detect(frame, it, geoms, cgeoms, sizes, enabled)
            st.ms_setup += S.SetupClock.ms - setup0
            st.ms_detect += 1e3 * (time.perf_counter() - td) - (S.SetupClock.ms - setup0)
            tv = time.perf_counter()
            vis, by_pair = self.visible(geoms, cgeoms, enabled)
            st.ms_visible += 1e3 * (time.perf_counter() - tv)
            if it == 0:
                st.in_collision = bool(rnd.found) or vis.worst_rel > options.tolerance  # a pair to respond to
                st.contacts = [(c.point_a, c.point_b) for _, _, c in rnd.found]
                st.regions = {defs[i].path: c.region_a.points for i, _, c in rnd.found}
            # a round is judged by what the user sees and by what detection still finds (a
            # collider wholly inside a closed deformable shows nothing of itself, yet is inside)
            score = max(vis.worst_rel, rnd.worst_rel)
            if score < best[0]:
                best = (score, list(surfaces))
                st.residual, st.residual_rel = vis.worst, vis.worst_rel
                st.pair_residual_rel = {(defs[i].path, self._name(other)): vis.pair_rel(defs[i].path, self._name(other))
                                        for i, other in _pairs(len(defs), len(self.statics))}
            # what the user would see still over the tolerance, per pair and side
            over = {key: {side: p for side, p in sides.items() if p.rel > options.tolerance}
                    for key, sides in by_pair.items()}
            over = {key: sides for key, sides in over.items() if sides}
            if (not rnd.found and not over) or score <= options.tolerance or it == rounds:
                break
            tr, setup0 = time.perf_counter(), S.SetupClock.ms
            # The first round is eq. 4.15-4.16 on detection's regions alone: it gives the
            # response its look. Where the display is still over the tolerance afterwards, a
            # later round joins the display's own points inside the other object to the pair's
            # regions (`_with_shown`); a pair detection finds clear, or misses, while its display
            # is over gets points from the display alone (`visible_points`).
            found = {(i, other) for i, other, _ in rnd.found}
            seen = {key: by_pair[key] for key in over if it > 0 and key in found}
            over = {key: sides for key, sides in over.items() if key not in found}
            points = self.data_points(rnd, geoms, cgeoms, sizes, enabled, surfaces, directions, wrapping, over, seen)
            st.ms_setup += S.SetupClock.ms - setup0
            st.ms_convert += 1e3 * (time.perf_counter() - tr) - (S.SetupClock.ms - setup0)
            self.respond(frame, it, st, points, surfaces)
            st.iterations = it + 1
        surfaces = best[1]
        carried = self.carry.end(frame, surfaces)
        st.volume_targets = self.carry.volume_targets()
        for i, model in enumerate(defs):  # the display is the run's, chosen after every frame (`display.finish`)
            result.add(frame, model.path, output_layer.DeformableResult(None, None, surfaces[i], st.residual, st.in_collision, carried[i]))
        st.ms_total = 1e3 * (time.perf_counter() - t0)
        return st

    def _name(self, other: tuple) -> str:
        """Prim path of ``("d", j)`` or ``("c", j)``."""
        return self.defs[other[1]].path if other[0] == "d" else self.scene.colliders[other[1]].path


def _run_frames(stage, scene, frames, options, on_frame, initial=None):
    run = _Run(stage, scene, options, state.for_run(stage, scene, frames, options, initial))
    result = output_layer.FramesResult()
    stats: list[FrameStats] = []
    for frame in frames:
        stats.append(run.frame(frame, result))
        if on_frame is not None:
            on_frame(stats[-1], result)
    return result, stats
