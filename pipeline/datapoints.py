"""Data points of a pair's contact (thesis eq. 4.15–4.16) and of what the user sees.

The contact's first-touch points meet on a target placed by relative rigidity (eq. 4.15,
`data_points_for`); every patch of the finest absorbing level that holds part of an
interpenetration region gets one additional point, cast along the push to where it leaves the
other object (eq. 4.16). A collider wholly or partly inside a closed deformable pushes the wall in
front of it past it (`collider_points_for`); where a surface must drop along a collider's side
face, points on the crossing keep it there (`pipeline.rim`); where the display the user sees is
still inside the other object, a corrective round moves a grid of samples out (`visible_points`); a
frame's later round holds the contact points of its earlier rounds where a dent's bottom must not
be dragged past the other object (`pinned`).
Every function takes the geometry of one round (`pipeline.detect`) and returns parameters,
world targets and world starts; the frame loop (`pipeline.frames`) assembles them per deformable.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from acra import hspline as H
from acra.controls import Controls
from acra.targets import DataPoints, additional_targets, contact_targets, patch_keys, region_groups
from acra.kdtree import thin_greedy
from pipeline import geometry
from pipeline import contact as C
from pipeline import detect as D
from pipeline import residual
from pipeline import rim
from pipeline.model import apply_xform
from pipeline.spatial import cKDTree

__all__ = ["data_points_for", "collider_points_for", "visible_points", "deepest_shown", "corrects",
           "with_shown", "spread", "deepest_instead", "group_level", "pinned", "CLEAR", "MEET", "THIN_GAP", "PIN_GAP",
           "HOLD_GAP", "CORRECTIVE_RCOND", "LATER_AMPLIFY"]


def group_level(controls: Controls, depth: int) -> int:
    """Level whose patches get one additional point each: the finest absorbing level."""
    levels = np.nonzero(controls.absorption > 0)[0]
    return int(min(levels.max() if levels.size else 0, depth - 1))


def corrects(controls: Controls, depth: int) -> bool:
    """Whether a round from the display alone corrects this surface with a fit of samples
    (`visible_points`, `corrective`): its finest absorbing level only deforms. A
    translation or a rotation of a patch's detail cannot follow a grid of samples (measured:
    `rotate_and_deform` frames 7-8 1.29e-3 after 4 rounds), so such a surface keeps the
    display's deepest point per patch (`deepest_shown`) and the animator's levels."""
    return bool(controls.deform[group_level(controls, depth)] >= 1.0 - 1e-9)


STALLED = 0.1  # a patch's middle asking a move of at most this fraction of the patch's depth has stalled


def data_points_for(
    ga: geometry.SurfaceGeometry,
    gb: geometry.Geometry,
    uv: np.ndarray,
    p_self: np.ndarray,
    p_other: np.ndarray,
    region_uv: np.ndarray | None,
    share: float,
    group_level: int,
    direction: np.ndarray | None = None,
    region_depth: np.ndarray | None = None,
    settled: float = 0.0,
) -> tuple[DataPoints, np.ndarray]:
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
        instead (`region_deepest`). Without this, a later round whose region is a sliver
        along the other object's edge pins middles already on their targets and moves nothing,
        however many rounds run (docs/hard-cases.md, case 7).
    settled : float
        See ``region_depth``.

    Against a collider, the patches at the region's rim take `rim.rim_points` instead of
    their middles: eq. 4.16's middles all lie inside the region's outline, and a C2 surface
    pinned only there begins to rise back inside a box's outline and curls up inside the box
    between detection's samples.

    Returns
    -------
    DataPoints (object space of ``ga``), the world targets ``(K, 3)`` and the world points
    ``(K, 3)`` they move from (the surface before the response), for the preview's arrows.
    """
    target_p = contact_targets(p_self, p_other, share)
    uvs = [np.asarray(uv, float).reshape(1, 2)]
    targets = [target_p[None]]
    origins = [np.asarray(p_self, float).reshape(1, 3)]
    direction = p_other - p_self if direction is None else np.asarray(direction, float)
    size = ga.size
    if region_uv is not None and len(region_uv) and np.linalg.norm(direction) > 1e-9 * size:
        # `region_midpoints` and `region_deepest` in one pass over the samples
        mids, _, rows, _ = region_groups(ga.surface, region_uv, group_level, region_depth)
        a_world = apply_xform(ga.xform, H.evaluate(ga.surface, mids[:, 0], mids[:, 1], det=ga.details).points)
        # `spread` keeps none of the middles whatever their casts answer where they all lie on the
        # contact point (a region around a pole): no cast, no additional point
        if not _all_meet(ga, gb, a_world, p_self, region_uv, region_depth, rows, settled):
            hits, valid = D.cast(gb, a_world, np.broadcast_to(direction, a_world.shape))
            if region_depth is not None:
                deep = np.asarray(region_uv, np.float64).reshape(-1, 2)[rows]
                depth = np.asarray(region_depth, np.float64).reshape(-1)[rows]
                stalled = np.nonzero(valid & (depth > settled) & (np.linalg.norm(hits - a_world, axis=1) <= STALLED * depth))[0]
                if stalled.size:
                    d_world = apply_xform(ga.xform, H.evaluate(ga.surface, deep[stalled, 0], deep[stalled, 1], det=ga.details).points)
                    d_hits, d_valid = D.cast(gb, d_world, np.broadcast_to(direction, d_world.shape))
                    use = stalled[d_valid]
                    mids[use], a_world[use], hits[use] = deep[use], d_world[d_valid], d_hits[d_valid]
            wanted = additional_targets(a_world, hits, share)
            if isinstance(gb, geometry.ColliderGeometry):
                r_uv, r_world, r_goal = rim.rim_points(ga, gb, region_uv, direction, group_level)
                if len(r_uv):  # a rim patch's point is its rim point, not its middle
                    valid &= ~member(patch_keys(ga.surface, mids, group_level), patch_keys(ga.surface, r_uv, group_level))
                    mids, a_world = np.concatenate([mids, r_uv]), np.concatenate([a_world, r_world])
                    wanted = np.concatenate([wanted, additional_targets(r_world, r_goal, share)])
                    valid = np.concatenate([valid, np.ones(len(r_uv), bool)])
            valid &= spread(a_world, np.asarray(p_self, float), MEET * size)
            if np.any(valid):
                uvs.append(mids[valid])
                targets.append(wanted[valid])
                origins.append(a_world[valid])
    uv_all = np.concatenate(uvs)
    world = np.concatenate(targets)
    is_contact = np.zeros(len(uv_all), bool)
    is_contact[0] = True
    return DataPoints(uv_all, ga.to_object(world), is_contact), world, np.concatenate(origins)  # `apply_inverse`'s bits


def _all_meet(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, a_world: np.ndarray, p_self: np.ndarray,
              region_uv: np.ndarray, region_depth: np.ndarray | None, rows: np.ndarray, settled: float) -> bool:
    """Whether `spread` drops every one of a region's patch middles ``a_world (g, 3) float64``
    (world) whatever their casts onto ``gb`` answer, so that `data_points_for` gives no additional
    point with or without them. It drops a point within ``MEET`` of the size of the contact point
    ``p_self (3,) float64``, and a middle's row keeps its point unless the middle stalls
    (`data_points_for`'s ``region_depth (k,) float64`` of the samples ``region_uv (k, 2) float64``):
    only a patch deeper than ``settled`` can stall, and it then takes its deepest sample (row
    ``rows (g,) int64`` of the samples), so such a patch's sample must lie within ``MEET`` too, by
    a margin above any rounding of its evaluation in another batch. A collider's rim adds points
    of its own: never all dropped here."""
    if isinstance(gb, geometry.ColliderGeometry):
        return False
    contact = np.asarray(p_self, float)
    radius = MEET * ga.size
    if not (np.linalg.norm(a_world - contact, axis=1) <= radius).all():  # `spread`'s own test, the same bits
        return False
    if region_depth is None:
        return True
    could = np.flatnonzero(np.asarray(region_depth, np.float64).reshape(-1)[rows] > settled)
    if not len(could):
        return True
    deep = np.asarray(region_uv, np.float64).reshape(-1, 2)[rows[could]]
    d_world = apply_xform(ga.xform, H.evaluate(ga.surface, deep[:, 0], deep[:, 1], det=ga.details).points)
    slack = 1e-12 * (np.abs(d_world).max() + np.abs(contact).max() + ga.size)  # thousands of roundings
    return bool((np.linalg.norm(d_world - contact, axis=1) <= radius - slack).all())


def member(keys: np.ndarray, among: np.ndarray) -> np.ndarray:
    """``np.isin(keys, among)`` of integer keys ``(n,)`` and ``(m,)``: ``(n,) bool``. A region's
    patch middles against its rim's patches, or a round's points' patches against detection's, a
    few dozen each: each key's place in the sorted
    ``among`` (the first not below it) holds it or no place does, four numpy steps where
    `np.isin`'s set-up costs several times as much."""
    if not len(among):
        return np.zeros(len(keys), bool)
    ordered = np.sort(among)
    at = np.searchsorted(ordered, keys)
    np.minimum(at, len(ordered) - 1, out=at)
    return ordered[at] == keys


WRAP_RING = 1  # patches around the ones a collider's outline covers that a new pocket pushes too


def collider_points_for(
    ga: geometry.SurfaceGeometry,
    gb: geometry.ColliderGeometry,
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

    * the collider's faces inside ``ga`` (`geometry.face_samples`, at most half a group-level
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
    from scipy.ndimage import maximum_filter  # here: a run that never wraps skips importing scipy.ndimage

    none = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))
    length = np.linalg.norm(direction)
    pts = np.concatenate([region_a.points, region_b.points])
    if not len(pts) or not ga.closed or length <= 1e-9 * ga.size:
        return none
    unit = np.asarray(direction, float) / length
    hs = ga.surface
    spacing = 0.5 * ga.size / (max(hs.u.patches0, hs.v.patches0) << group_level)
    s = geometry.face_samples(gb, np.stack([pts.min(axis=0) - spacing, pts.max(axis=0) + spacing]), spacing)
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
    su, sv = np.divmod(patch_keys(hs, uv, group_level), hs.v.patches(group_level))
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
    return mid[go], additional_targets(a[go], b, share), a[go]


def visible_points(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, inside: residual.Inside, direction: np.ndarray | None,
                   share: float, group_level: int, clear: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points of a corrective round, from what the user sees: where the display's own points
    lie inside the other object (`residual.Inside`), samples of the limit surface on a regular
    grid are moved out of it.

    A display triangle is a chord of the surface: where a response wraps a convex part of the
    other object (a dent around a tip), the chords lie on the concave side, inside the other
    object, while the limit surface on detection's samples is out; and between eq. 4.16's
    points, one per finest patch, the least-change surface sags back toward where it was. The
    samples are the corners and edge middles of every finest-absorbing-level patch holding a
    display point inside (`GRID` intervals per patch edge, shared between neighbours). Along
    ``direction`` (the pair's push; ``None``: each point's nearest way out), a sample's *lag* is
    how far it must go to leave the other object: its own (the limit surface, measured where it
    is now), and that of every display point inside whose parameters are nearest to it (the
    chord it holds), less how far the sample already stands ahead of the limit surface at the
    chord's parameters (the lesser of that along the push and along the sample's own normal
    turned to the push; never more than the chord's lag). A sample with a lag is asked to move by
    its largest lag, at least 0, plus ``clear`` (a world length: what counts as done); the others
    give no point.

    Why the limit surface at the chord's parameters: where the chords lie on the concave side of
    a wrapped part, the limit surface there is out and level with the sample, and the sample
    takes the chord's whole lag (the chord moves out with the surface). Where the limit surface
    itself bulges in between the samples (a flattened tip, whose display vertices lie on the
    limit surface), the sample next to the bulge stands ahead of it by the bulge's height;
    taking the chord's whole lag moved `deform_vs_translate`'s tip sample 5.9e-3 past the plane
    (its tolerance 4.3e-3). Why the lesser of two measures: along the push alone, a sample on a
    flank parallel to it (a sheet dropping along a box's side) stands ahead by the flank's drop,
    not by a bulge (the hard cases' `half_ball` and `jumps_through` stayed 1.09e-3 and 1.23e-3
    inside after 4 rounds); along the normal alone, a sample on a curved dent stands ahead by
    the dent's curvature (`clay` frame 4 stayed 2.36e-3 inside). Subtracting how far the sample
    is ahead of the chord itself (the chord's sag included) left `rotate_and_deform` over the
    tolerance and moved `turning_press`'s dent.

    Why a grid: the display's deepest points lie on patch edges, so one point per patch at the
    deepest display point (the rule before) put neighbouring patches' points a few millimetres
    apart, whose nearly dependent rows in the interpolation moved `absorb_levels`' sheet 0.02
    past the ball between them; a grid keeps the points apart by half a patch. Holding the
    samples already out where they are was measured too: it left `box_into_sheet`'s sheet over
    the tolerance after 4 rounds at frames 11-16 (docs/algorithm.md).

    Returns
    -------
    uv : (g, 2) float64
        Parameters on ``ga`` (level-0 units).
    target : (g, 3) float64
        World targets, ``R A + (1 - R) B`` of eq. 4.16 with ``B`` the sample moved as above.
    origin : (g, 3) float64
        World surface points before the move.
    """
    empty = np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3))
    if inside.uv is None or not len(inside.uv):
        return empty
    hs = ga.surface
    shown_uv = geometry.wrap_uv(hs, inside.uv)
    su, sv = np.divmod(np.unique(patch_keys(hs, shown_uv, group_level)), hs.v.patches(group_level))
    steps = np.linspace(0.0, 1.0, GRID + 1)
    offs = np.stack(np.meshgrid(steps, steps, indexing="ij"), axis=-1).reshape(-1, 2)
    uv = ((np.stack([su, sv], axis=1)[:, None, :] + offs[None]) / (1 << group_level)).reshape(-1, 2)
    uv = np.unique(np.round(geometry.wrap_uv(hs, uv), 9), axis=0)
    at = geometry.surface_points(ga, uv).points

    def units(p):
        if direction is None or np.linalg.norm(direction) <= 1e-12 * ga.size:
            u = D.surface_distance(gb, p)[1] - p
            return u / np.maximum(np.linalg.norm(u, axis=1), 1e-300)[:, None]
        return np.broadcast_to(np.asarray(direction, float) / np.linalg.norm(direction), p.shape)

    unit = np.array(units(at))
    lag = np.full(len(uv), -np.inf)
    within = D.inside(gb, at)
    if within.any():
        rows = np.nonzero(within)[0]
        hits, valid = D.cast(gb, at[rows], unit[rows], within=np.ones(len(rows), bool))
        lag[rows[valid]] = np.einsum("ij,ij->i", hits[valid] - at[rows[valid]], unit[rows[valid]])
    pu = units(inside.points)
    hits, valid = D.cast(gb, inside.points, pu, within=np.ones(len(inside.points), bool))
    shown_lag = np.einsum("ij,ij->i", hits - inside.points, pu)
    ok = valid & (shown_lag > 0)
    near = _nearest_uv(hs, uv, shown_uv[ok])
    # how far the sample stands ahead of the limit surface at the chord's parameters, the lesser
    # of that along the push and along its normal turned to the push: where the limit surface
    # itself bulges in between samples (a flattened tip) both are the bulge's height and the
    # sample asks only the rest of the chord's lag; on a flank parallel to the push (the normal)
    # or a curved dent (the push) one of them is level
    q = geometry.surface_points(ga, shown_uv[ok]).points
    ev = geometry.surface_points(ga, uv, order=1)
    n = np.cross(ev.du, ev.dv)[near]
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    n *= np.sign(np.einsum("ij,ij->i", n, pu[ok]))[:, None]
    ahead = np.maximum(np.einsum("ij,ij->i", q - at[near], n), np.einsum("ij,ij->i", q - at[near], pu[ok]))
    np.maximum.at(lag, near, shown_lag[ok] + np.minimum(ahead, 0.0))
    go = lag > -np.inf
    goal = at[go] + (np.maximum(lag[go], 0.0) + clear)[:, None] * unit[go]
    return uv[go], additional_targets(at[go], goal, share), at[go]


GRID = 2  # intervals per patch edge of `visible_points`' samples: corners and edge middles


def _nearest_uv(hs, grid: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Index into ``grid (g, 2)`` of the nearest point to each of ``uv (k, 2)`` in parameter space
    (across the seam of a periodic direction)."""
    tiles, base = [grid], np.arange(len(grid))
    for c, d in enumerate((hs.u, hs.v)):
        if d.periodic:
            shifted = []
            for t in tiles:
                for k in (-1, 1):
                    m = t.copy()
                    m[:, c] += k * d.patches0
                    shifted.append(m)
            tiles = tiles + shifted
    reps = len(tiles)
    _, idx = cKDTree(np.concatenate(tiles)).query(uv)
    return np.tile(base, reps)[idx]


def deepest_shown(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, inside: residual.Inside, direction: np.ndarray | None,
                   share: float, group_level: int, clear: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Additional points (eq. 4.16) from what the user sees, for a surface whose finest absorbing
    level translates or rotates (`visible_points` is a fit, which only a deformation makes): the
    display's own points inside the other object (`residual.Inside`), where the limit surface may
    already be clear.

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
    uv = geometry.wrap_uv(hs, inside.uv)
    keys = patch_keys(hs, uv, group_level)
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
    origin = geometry.surface_points(ga, uv[valid]).points
    goal = origin + move[valid, None] * unit[valid]
    return uv[valid], additional_targets(origin, goal, share), origin


def with_shown(region: D.Region, shown) -> tuple[np.ndarray | None, np.ndarray]:
    """A region's parameters ``(k, 2)`` and depths ``(k,)`` joined by the display's own points
    inside the other object (``shown``, a `residual.PairDepth` or ``None``): eq. 4.16's region as
    detection's samples of the limit surface and the user's display see it together, so a part
    that sinks between detection's samples still gets its patch's point."""
    if shown is None or shown.inside.uv is None or not len(shown.inside.uv):
        return region.uv, region.depth
    return (np.concatenate([region.uv.reshape(-1, 2), shown.inside.uv]),
            np.concatenate([region.depth, shown.inside.deep]))


def spread(points: np.ndarray, contact: np.ndarray, radius: float) -> np.ndarray:
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
    if len(points) > SPREAD_DIRECT:
        for i, j in sorted(cKDTree(points).query_pairs(radius)):
            if keep[i]:
                keep[j] = False
        return keep
    # the same greedy pass over every pair, compiled (`acra.kdtree.thin_greedy`), a small
    # fraction of the tree's cost on a frame's few dozen points: a row drops its later neighbours
    # if it is itself kept, rows in order
    return thin_greedy(np.asarray(points, np.float64), radius, keep)


SPREAD_DIRECT = 256  # up to this many points `spread` compares every pair instead of building a kd-tree


CLEAR = 0.25  # display points are moved this fraction of the tolerance past the other surface (`visible_points`)
MEET = 1e-3  # rewound contact points this close (fraction of the size) meet, whatever the run's tolerance


def deepest_instead(ga: geometry.SurfaceGeometry, gb: geometry.Geometry, c: C.PairContact) -> C.PairContact:
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


def pinned(hs: H.HSpline, new: DataPoints, old: DataPoints | None, level: int,
           shared: bool = False, slack: float = 0.0) -> tuple[DataPoints, DataPoints | None]:
    """A later round's data points and the points it holds: ``(new's kept points, held)``.

    ``old`` are the frame's earlier data points. Their contact points (eq. 4.15's first-touch
    targets: a dent's bottom, between two deformables their rigidity split) are held at the
    targets they asked (`respond.respond`'s ``held``): the surface passes through them already
    (the direct solve interpolates), so the round corrects what is left without moving what the
    first round placed. Distances are in patches of the finest absorbing level ``level``: two
    targets close together fight in the interpolation and the surface rings between them, so the
    round's additional points are first thinned to `THIN_GAP` (`_thinned`); an earlier contact
    gives way to a contact of the round within `PIN_GAP`; the round's additional points within
    `HOLD_GAP` of a held contact give way to it (within `THIN_GAP` between two deformables,
    ``shared``, so the split stands).

    An earlier contact is held only where it is a bottom the round's points must not drag past:
    * Between two deformables (``shared``), a contact of the round anywhere releases every
      earlier one: detection still finds the pair, and the round's contact asks eq. 4.15's split
      between the surfaces as they are now; an earlier split held elsewhere on the finest level
      pulls against it. The earlier split is held only while the pair's later rounds come from
      the display alone.
    * An additional point of the round within `PIN_GAP` asking a target at least as deep along
      its own move as the contact's, to within ``slack`` (object units), releases it: the contact
      is then one point of a face pressed flat (a tip under a plane), not the bottom of a dent
      around which the other object's surface rises, and holding it keeps the tip up while the
      face around it is pushed down."""
    scale = 2.0**-level  # a patch of the level, in level-0 parameters
    new = _thinned(hs, new, THIN_GAP * scale)
    if old is None or not np.any(old.is_contact):
        return new, None
    old = _take(old, np.asarray(old.is_contact, bool))
    dist = _uv_distance(hs, new.uv, old.uv)  # (new, old)
    new_contact = np.asarray(new.is_contact, bool)
    holds = ~(dist[new_contact] < PIN_GAP * scale).any(axis=0)
    if shared and new_contact.any():
        holds[:] = False
    extra = ~new_contact
    if extra.any() and holds.any():
        move = new.target[extra] - H.evaluate(hs, new.uv[extra, 0], new.uv[extra, 1]).points
        move /= np.maximum(np.linalg.norm(move, axis=1, keepdims=True), np.finfo(float).tiny)
        ahead = np.einsum("nmk,nk->nm", new.target[extra][:, None, :] - old.target[None, :, :], move)  # (extra, old)
        holds &= ~((ahead >= -slack) & (dist[extra] < PIN_GAP * scale)).any(axis=0)
    drop = extra & (dist[:, holds] < (THIN_GAP if shared else HOLD_GAP) * scale).any(axis=1)
    return _take(new, ~drop), _take(old, holds)


# In patches of the finest absorbing level. Measured on the 18 scenes: with a thinning gap of
# 0.65 or 0.75 more of the look tests hold (absorb_levels, elbow_contact, drum's area), but the
# fewer points leave drum frame 5 (2.1e-3) or closed_objects frames 5-7 (1.3e-3) over the
# tolerance after 4 rounds; 0.25 clears every scene.
THIN_GAP = 0.25  # a later round's additional points at least this far apart
PIN_GAP = 0.75  # an earlier contact gives way to a later round's contact this close
HOLD_GAP = 0.1  # a later round's additional point this close to a held contact gives way to it


# A corrective round's solve (`respond.respond`'s ``rcond``) drops the modes of its samples' Gram
# matrix below this fraction of its largest eigenvalue, where a response from detection drops those
# below 1e-4. A mode of relative eigenvalue λ multiplies the points' disagreement along it by 1/√λ:
# up to 100 times at 1e-4, 32 at 1e-3. The samples lie half a finest patch apart, each asking a few
# millimetres that differ from the next one's by about as much (the chords' lags), so their exact
# fit swung the CVs ten times as far as any sample asked and the surface with them: elbow_contact
# frame 15's corrective round asked at most 0.011 and moved CVs 0.112, a display point a patch away
# from every sample 0.045, and the dent's tip from 1.23 to 1.34 times the depth the arm went in
# (1.3 asserted); at 1e-3, CVs 0.043, that point 0.015 and the tip 1.27. The same cut-off in
# every later round is too blunt (docs/design-decisions.md): `LATER_AMPLIFY` drops only the weak
# modes that amplify.
CORRECTIVE_RCOND = 1e-3

# Every later round's solves (`respond.respond`'s ``amplify``) also drop a Gram mode below 1e-3 of
# the largest eigenvalue whose CV move exceeds this many times the largest point move asked. An
# exact fit of one point moves a bicubic's CVs at most 16/9 of its ask (weights 4/9 of a norm² 1/4
# at a knot), so a weak mode moving them further fits the disagreement of neighbouring asks, not a
# move any of them asks: a later round asks each level millimetres (what the rounds before left)
# and that mode swings the level's CVs ten times as far, which the next level has to undo. Weak
# modes the asks do need stay, unlike with the blanket 1e-3 cut-off (see above). The last level
# that deforms keeps them where finer absorbing levels only turn or translate (rotate_and_deform:
# its level-1 solve asked 0.044 and needs the CVs' 1.07 swing, the level-2 turn cannot fit what it
# leaves; with the rule there frames 10-11 stayed 1.48e-3 inside after 4 rounds).
LATER_AMPLIFY = 2.0


def _take(dp: DataPoints, rows: np.ndarray) -> DataPoints:
    return DataPoints(dp.uv[rows], dp.target[rows], np.asarray(dp.is_contact, bool)[rows], per_patch=dp.per_patch)


def _thinned(hs: H.HSpline, dp: DataPoints, gap: float) -> DataPoints:
    """``dp`` without the additional points closer than ``gap`` (level-0 parameters) to a contact
    point or to an additional point asking a larger move (greedy, largest move first).

    The display's points (`datapoints.visible_points`) are the deepest per patch, often on a
    patch's edge beside the next patch's: nearly equal rows asking different moves."""
    contact = np.asarray(dp.is_contact, bool)
    move = np.linalg.norm(dp.target - H.evaluate(hs, dp.uv[:, 0], dp.uv[:, 1]).points, axis=1)
    order = np.concatenate([np.nonzero(contact)[0], np.nonzero(~contact)[0][np.argsort(-move[~contact], kind="stable")]])
    near = np.packbits(_uv_distance(hs, dp.uv, dp.uv) < gap, axis=1)
    # each row's neighbours as the bits of one integer (column j at bit `top - j`), the kept
    # points as another: a point's test is one `&`, not a pass over every point
    width, top = near.shape[1], 8 * near.shape[1] - 1
    rows = near.tobytes()
    keep, kept, held = np.zeros(len(dp.uv), bool), 0, contact.tolist()
    for k in order.tolist():
        if held[k] or not int.from_bytes(rows[k * width:(k + 1) * width], "big") & kept:
            keep[k] = True
            kept |= 1 << (top - k)
    return _take(dp, keep)


def _uv_distance(hs: H.HSpline, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance in level-0 parameters between each of ``a (n, 2)`` and each of ``b (m, 2)``:
    ``(n, m)``, across the seam of a periodic direction."""
    d = [np.abs(a[:, None, col] - b[None, :, col]) for col in (0, 1)]
    for col, dim in ((0, hs.u), (1, hs.v)):
        if dim.periodic:
            d[col] = np.minimum(d[col], dim.patches0 - d[col])
    # `np.linalg.norm(..., axis=-1)` of the (n, m, 2) differences, the same sum of two squares
    return np.sqrt(d[0] * d[0] + d[1] * d[1])
