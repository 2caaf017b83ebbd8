"""Data points of a contact and of what the user sees (`pipeline.datapoints`): spacing, stalled
middles, a collider inside a closed sheet, rim points on a box's side face, earlier contacts a later round holds (`pinned`)."""

import numpy as np
import pytest

from pipeline import geometry
from acra.controls import check_controls
from acra.targets import DataPoints
from pipeline import datapoints as P


def test_spread_keeps_additional_points_apart_and_covers_the_rest():
    """`datapoints.spread`: kept points are pairwise farther than the radius and farther from the
    contact; every dropped point is within the radius of a kept one or of the contact, so thinning
    leaves no part of the region without a point (seeded clusters, as at a pole)."""
    rng = np.random.default_rng(7)
    for n in (0, 1, 5, 60):
        pts = np.concatenate([rng.normal(0, 0.002, (n // 2, 3)), rng.uniform(-0.05, 0.05, (n - n // 2, 3))])
        contact, radius = np.array([0.001, 0.0, 0.0]), 4e-3
        keep = P.spread(pts, contact, radius)
        kept = pts[keep]
        if len(kept) > 1:
            d = np.linalg.norm(kept[:, None] - kept[None], axis=2) + np.eye(len(kept))
            assert d.min() > radius
        assert np.all(np.linalg.norm(kept - contact, axis=1) > radius)
        anchors = np.concatenate([kept, contact[None]])
        for p in pts[~keep]:
            assert np.linalg.norm(anchors - p, axis=1).min() <= radius
        if n == 60:
            assert 0 < keep.sum() < n  # the cluster was thinned, the spread points kept


def test_spread_thins_as_the_kd_tree_greedy_does():
    """`datapoints.spread` compares every pair of a frame's few dozen points itself; its answer is
    the kd-tree's greedy pass (``sorted(cKDTree(points).query_pairs(radius))``) on seeded points,
    crowds of nearly equal points (a pole) and sets past `SPREAD_DIRECT`."""
    from pipeline.spatial import cKDTree

    def tree_greedy(points, contact, radius):
        keep = np.linalg.norm(points - contact, axis=1) > radius
        for i, j in sorted(cKDTree(points).query_pairs(radius)):
            if keep[i]:
                keep[j] = False
        return keep

    rng = np.random.default_rng(11)
    for trial in range(300):
        n = int(rng.integers(1, P.SPREAD_DIRECT + 40))
        pts = rng.random((n, 3)) * rng.choice([1e-3, 1.0, 1e3])
        if trial % 3 == 0:
            pts[: n // 2] = pts[0] + rng.random((n // 2, 3)) * 1e-9
        radius = float(rng.random() * pts.std() * 0.5)
        contact = pts[rng.integers(n)] + 1e-3
        np.testing.assert_array_equal(P.spread(pts, contact, radius), tree_greedy(pts, contact, radius))


@pytest.mark.parametrize("u_low, settled, took", [
    (2.14, 0.005, "deepest"),  # middle x = 0.02: 0.002 inside, 1/20 of the patch's depth 0.04
    (2.3, 0.005, "middle"),  # middle x = 0.1: 0.01 inside, 1/4 of it: not stalled
    (2.14, 0.05, "middle"),  # the patch's depth 0.04 counts as done
])
def test_a_patch_whose_middle_has_stalled_takes_its_deepest_sample(u_low, settled, took):
    """Eq. 4.16's point of a patch is the middle of its inside part; where that middle asks a
    move of at most `datapoints.STALLED` of the patch's depth (the stall of docs/hard-cases.md case 7:
    the middle on the box's face, the patch's corner sample still inside), the sample is taken
    instead. A sheet tilted as z = 0.1 x, a box whose bottom is z = 0, and two samples of
    level-0 patch (2, 2): x = 0.4 (0.04 inside) and x = u_low - 2.5 (below the box)."""
    from acra import hspline as H
    from acra import shapes
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(8, 8, width=5.0, depth=5.0)
    cvs[..., 2] = 0.1 * cvs[..., 0]
    sheet = geometry.SurfaceGeometry(H.from_grid(cvs), np.eye(4), "/sheet")
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (0.0, 2.0)])
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", corners, tris)), np.eye(4))
    region_uv = np.array([[2.9, 2.5], [u_low, 2.5]])
    contact = np.array([0.3, 0.0, 0.03])  # apart from both samples (`_spread` drops points on the contact)
    args = (sheet, box, np.array([2.8, 2.5]), contact, contact * [1, 1, 0], region_uv, 0.0, 0, np.array([0.0, 0.0, -1.0]))
    mid_u = (2.9 + u_low) / 2
    mean, _, _ = P.data_points_for(*args)  # without depths: the middle, as eq. 4.16 says
    np.testing.assert_allclose(mean.uv[1], [mid_u, 2.5])
    np.testing.assert_allclose(mean.target[1], [mid_u - 2.5, 0.0, 0.0], atol=1e-9)
    dp, _, _ = P.data_points_for(*args, region_depth=np.array([0.04, 0.0]), settled=settled)
    u = 2.9 if took == "deepest" else mid_u
    np.testing.assert_allclose(dp.uv[1], [u, 2.5])
    np.testing.assert_allclose(dp.target[1], [u - 2.5, 0.0, 0.0], atol=1e-9)


def _ball_and_box(lo, hi):
    """The 8 × 8-CV unit sphere with 3 levels (group level 2) and an axis-aligned box collider
    ``[lo, hi]`` (world ``(3,)`` each), as detection geometry at the identity matrix."""
    from acra import hspline as H
    from acra import shapes
    from pipeline.model import ColliderModel

    ball = geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(8, 8), depth=3), np.eye(4), "/ball")
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", corners, tris)), np.eye(4))
    return ball, box


def test_a_box_inside_a_sphere_gets_the_wall_in_front_pushed_past_it():
    """`datapoints.collider_points_for` (docs/hard-cases.md, case 3): a 0.3 box wholly inside the unit
    sphere has no sphere vertex inside it, so eq. 4.16's own-region points are none; the box's
    faces give them instead. Pushed along -x, the wall in front (x near 1) gets one point per
    level-2 patch, at the patch centre, moved along -x only, past the box's far face by the
    clearance; in the pocket's first round the points reach beyond the box's outline on every
    side (the ring), in a later round only the patches the box covers move, by their lag."""
    from acra.basis import locate
    from pipeline import detect as D

    ball, box = _ball_and_box([-0.15] * 3, [0.15] * 3)
    ra, rb = D.regions(ball, box)
    assert ra.empty and len(rb.points) == 8
    push, clear = np.array([-1.15, 0.0, 0.0]), 0.004
    hs = ball.surface
    for first in (True, False):
        uv, target, origin = P.collider_points_for(ball, box, ra, rb, push, 0.0, 2, clear, first)
        patches = np.stack([locate(hs.u, uv[:, 0], 2)[0], locate(hs.v, uv[:, 1], 2)[0]], axis=1)
        assert len(np.unique(patches, axis=0)) == len(uv) > 0  # one point per level-2 patch
        np.testing.assert_allclose(uv, (patches + 0.5) / 4)  # at its centre
        assert np.all(origin[:, 0] > 0.85)  # on the wall in front
        np.testing.assert_allclose(target[:, 1:], origin[:, 1:], atol=1e-12)  # along the push only
        assert np.all(target[:, 0] <= -0.15 - clear + 1e-12)  # past the far face
        y, z = origin[:, 1], origin[:, 2]
        if first:  # the ring: beyond the outline on every side
            assert y.min() < -0.15 and y.max() > 0.15 and z.min() < -0.15 and z.max() > 0.15
            n_first = len(uv)
        else:  # the covered patches alone, each by its largest lag (to the far face) + clear
            assert len(uv) < n_first
            assert np.all(np.abs(y) < 0.15 + 0.2) and np.all(np.abs(z) < 0.15 + 0.2)
            assert np.all(origin[:, 0] - target[:, 0] <= 1.15 + clear + 1e-9)


def test_a_box_through_a_sphere_wall_takes_both_regions_to_its_inner_face():
    """A box [0.85, 1.15] × [-0.1, 0.1]² through the +x wall of the unit sphere, pushed along
    -x: the sphere's vertices inside the box (its own region) and the box's inner corners inside
    the sphere (the collider's) give one set of points, all aiming at the box's inner face
    x = 0.85 less the clearance."""
    from pipeline import detect as D

    ball, box = _ball_and_box([0.85, -0.1, -0.1], [1.15, 0.1, 0.1])
    ra, rb = D.regions(ball, box)
    assert not ra.empty and len(rb.points) == 4
    uv, target, origin = P.collider_points_for(ball, box, ra, rb, np.array([-0.3, 0.0, 0.0]), 0.0, 2, 0.004, False)
    assert len(uv) > 0
    np.testing.assert_allclose(target[:, 1:], origin[:, 1:], atol=1e-12)
    assert np.all(target[:, 0] <= 0.85 - 0.004 + 1e-12)
    # a patch centre moves by the largest lag of its samples: at most the wall's bulge past 0.85
    assert np.all(origin[:, 0] - target[:, 0] <= 1.0 - 0.85 + 0.004 + 1e-9)


def test_a_later_round_holds_the_earlier_contact_while_it_clears_a_display_point():
    """The pin rule (`datapoints.pinned`, `respond.respond`'s ``held``): a later round asked to move
    one point of the display on a dent's flank leaves the first round's contact point (the dent's
    bottom) where it was asked, to 1e-9 of the sheet's size, and meets its own point; without
    the pin the same round moves the bottom."""
    from acra import hspline as H
    from acra import respond as R
    from acra import shapes

    hs = H.from_grid(*shapes.sheet(10, 10, 7.0, 7.0), depth=3)
    controls = check_controls(3, [0.0, 0.5, 0.5])
    # the first round: a dent's contact and its additional points, one per level-2 patch around it
    uv = np.array([[3.5, 3.5], [3.125, 3.5], [3.875, 3.5], [3.5, 3.125], [3.5, 3.875]])
    depth = np.array([0.3, 0.2, 0.2, 0.2, 0.2])
    first = DataPoints(uv, H.evaluate(hs, uv[:, 0], uv[:, 1]).points - depth[:, None] * [0.0, 0.0, 1.0],
                         np.array([True, False, False, False, False]))
    one, _ = R.respond(hs, first, controls)
    # a later round: one point of the display on the dent's flank, a patch and a half away
    at = np.array([[4.25, 3.5]])
    later = DataPoints(at, H.evaluate(one, at[:, 0], at[:, 1]).points - [0.0, 0.0, 0.02], np.array([False]))
    size = one.size()
    new, held = P.pinned(one, later, first, P.group_level(controls, one.depth))
    np.testing.assert_array_equal(held.uv, uv[:1])  # the contact is held, the additional points are not
    two, _ = R.respond(one, new, controls, held=held)
    assert np.abs(H.evaluate(two, uv[:1, 0], uv[:1, 1]).points - first.target[:1]).max() <= 1e-9 * size
    assert np.abs(H.evaluate(two, at[:, 0], at[:, 1]).points - later.target).max() <= 1e-9 * size
    free, _ = R.respond(one, later, controls)
    assert np.abs(H.evaluate(free, uv[:1, 0], uv[:1, 1]).points - first.target[:1]).max() > 1e-4 * size


def test_an_earlier_contact_holds_against_additional_points_and_gives_way_to_a_contact():
    """`datapoints.pinned` on level 1 (patches of 0.5): a later additional point within `HOLD_GAP`
    of an earlier contact gives way to it, one farther stays; a later contact within `PIN_GAP`
    replaces the earlier contact; additional points are thinned to `THIN_GAP`."""
    from acra import hspline as H
    from acra import shapes

    hs = H.from_grid(*shapes.sheet(10, 10, 7.0, 7.0), depth=2)
    down = np.array([0.0, 0.0, -1.0])
    ouv = np.array([[2.0, 2.0], [4.0, 4.0], [5.0, 2.0]])
    old = DataPoints(ouv, _on(hs, ouv) + 0.3 * down, np.array([True, True, False]))  # dents' bottoms 0.3 deep
    nuv = np.array([[2.02, 2.0], [2.3, 2.0], [4.1, 4.0], [5.5, 5.5], [5.55, 5.5]])
    depth = np.array([0.1, 0.1, 0.3, 0.2, 0.1])  # (5.5, 5.5) asks more; the flank's points less than the bottom
    new = DataPoints(nuv, _on(hs, nuv) + depth[:, None] * down, np.array([False, False, True, False, False]))
    kept, held = P.pinned(hs, new, old, 1)
    np.testing.assert_array_equal(kept.uv, [[2.3, 2.0], [4.1, 4.0], [5.5, 5.5]])
    np.testing.assert_array_equal(held.uv, [[2.0, 2.0]])


def _on(hs, uv):
    from acra import hspline as H

    return H.evaluate(hs, uv[:, 0], uv[:, 1]).points


def test_an_earlier_contact_gives_way_on_a_flat_face_and_to_a_later_split():
    """`datapoints.pinned` releases an earlier contact (a) when an additional point of the round
    within `PIN_GAP` asks as deep as it along its own move, to within ``slack`` (a tip under a
    plane: the face around it is pushed down to the same depth), and (b) between two deformables
    (``shared``) when the round has a contact of its own anywhere; with the flank shallower, or
    between two deformables with display points alone, the contact is held."""
    from acra import hspline as H
    from acra import shapes

    hs = H.from_grid(*shapes.sheet(10, 10, 7.0, 7.0), depth=2)
    down = np.array([0.0, 0.0, -1.0])
    ouv = np.array([[2.0, 2.0]])
    old = DataPoints(ouv, _on(hs, ouv) + 0.3 * down, np.array([True]))
    nuv = np.array([[2.25, 2.0]])  # half a level-1 patch away
    for depth, slack, is_held in ((0.3, 0.0, False), (0.31, 0.0, False), (0.29, 0.0, True), (0.29, 0.02, False)):
        new = DataPoints(nuv, _on(hs, nuv) + depth * down, np.array([False]))
        _, held = P.pinned(hs, new, old, 1, slack=slack)
        assert (len(held.uv) == 1) == is_held, (depth, slack)
    far = np.array([[6.0, 6.0], [2.25, 2.0]])  # a contact of the round far away, the flank shallower
    new = DataPoints(far, _on(hs, far) + np.array([[0.3], [0.1]]) * down, np.array([True, False]))
    assert len(P.pinned(hs, new, old, 1)[1].uv) == 1
    assert len(P.pinned(hs, new, old, 1, shared=True)[1].uv) == 0
    flank = DataPoints(nuv, _on(hs, nuv) + 0.1 * down, np.array([False]))
    assert len(P.pinned(hs, flank, old, 1, shared=True)[1].uv) == 1


def _thinned_array_form(hs, dp, gap):
    """`datapoints._thinned` as one numpy pass per point over a (n, n, 2) distance array."""
    from acra import hspline as H

    contact = np.asarray(dp.is_contact, bool)
    move = np.linalg.norm(dp.target - H.evaluate(hs, dp.uv[:, 0], dp.uv[:, 1]).points, axis=1)
    order = np.concatenate([np.nonzero(contact)[0], np.nonzero(~contact)[0][np.argsort(-move[~contact], kind="stable")]])
    d = np.abs(dp.uv[:, None, :] - dp.uv[None, :, :])
    for col, dim in ((0, hs.u), (1, hs.v)):
        if dim.periodic:
            d[..., col] = np.minimum(d[..., col], dim.patches0 - d[..., col])
    near = np.linalg.norm(d, axis=2) < gap
    keep = np.zeros(len(dp.uv), bool)
    for k in order:
        keep[k] = contact[k] or not (near[k] & keep).any()
    return keep, np.linalg.norm(d, axis=2)


@pytest.mark.parametrize("surface", ["sphere", "sheet"])
def test_thinning_keeps_the_points_the_array_form_keeps(surface):
    """`datapoints._thinned` (neighbours as bits) and `_uv_distance` give the array form's
    answers bit for bit, across a periodic seam and with points on a grid (distances equal to
    the gap), for up to 300 points."""
    from acra import hspline as H
    from acra import shapes

    hs = H.from_grid(*(shapes.sphere(8, 8) if surface == "sphere" else shapes.sheet(10, 10, 7.0, 7.0)), depth=3)
    rng = np.random.default_rng(3)
    for trial in range(12):
        n = int(rng.integers(1, 300))
        uv = rng.random((n, 2)) * [hs.u.patches0, hs.v.patches0]
        if trial % 3 == 0:
            uv = np.round(uv * 4) / 4
        dp = DataPoints(uv, _on(hs, uv) + rng.standard_normal((n, 3)), rng.random(n) < 0.1)
        for gap in (0.05, 0.25, 0.5):
            keep, dist = _thinned_array_form(hs, dp, gap)
            got = P._thinned(hs, dp, gap)
            np.testing.assert_array_equal(got.uv, uv[keep])
            assert P._uv_distance(hs, uv, uv).tobytes() == dist.tobytes()


@pytest.mark.parametrize("seed", range(5))
def test_member_is_numpys_isin(seed):
    """`datapoints.member` (the patch keys of a region's middles among its rim's) is
    ``np.isin``: keys below, between and above the others, repeats, negative keys (a NaN
    parameter's least int64), either side empty."""
    rng = np.random.default_rng(seed)
    for n, m in ((90, 38), (1, 1), (0, 5), (7, 0), (300, 300)):
        keys = rng.integers(-3, 60, n).astype(np.int64)
        among = rng.integers(0, 50, m).astype(np.int64)
        if n > 2:
            keys[0] = np.iinfo(np.int64).min
        got = P.member(keys, among)
        assert got.dtype == bool and np.array_equal(got, np.isin(keys, among))


def _two_sheets():
    """A sheet z = 0 (level-0 patches of about 0.7) and one above it at z = 0.05, both deformable."""
    from acra import hspline as H
    from acra import shapes

    cvs, _, _ = shapes.sheet(8, 8, width=5.0, depth=5.0)
    low = geometry.SurfaceGeometry(H.from_grid(cvs), np.eye(4), "/low")
    up = np.eye(4)
    up[2, 3] = 0.05
    return low, geometry.SurfaceGeometry(H.from_grid(cvs.copy()), up, "/high")


@pytest.mark.parametrize("at, region_uv, depth, casts", [
    (2.0, [[1.9995, 2.0], [2.0005, 2.0]], None, 0),  # two patches' middles on the contact point
    (2.0, [[1.9995, 2.0], [2.0005, 2.0]], [0.04, 0.04], 0),  # deep enough to stall: their samples meet too
    (2.5, [[2.2, 2.5], [2.8, 2.5]], None, 0),  # one patch, its middle on the contact point
    (2.5, [[2.2, 2.5], [2.8, 2.5]], [0.001, 0.002], 0),  # ... too shallow to stall
    (2.5, [[2.2, 2.5], [2.8, 2.5]], [0.04, 0.01], 1),  # ... deep enough, and its deepest sample 0.2 away
    (2.5, [[2.2, 2.5], [2.3, 2.5]], None, 1),  # a middle 0.05 away
])
def test_middles_that_all_meet_the_contact_point_are_not_cast(monkeypatch, at, region_uv, depth, casts):
    """`spread` drops every additional point within `MEET` of the size of the contact point, so a
    region whose patch middles (and, where a patch may stall, its deepest sample) all lie there
    asks no cast: the data points are those of the casts and `spread` (`_all_meet` held false),
    bit for bit, and the contact's alone."""
    from acra import hspline as H

    low, high = _two_sheets()
    uv = np.array([at, at])
    p_self = H.evaluate(low.surface, uv[:1], uv[1:]).points[0]
    args = (low, high, uv, p_self, p_self + [0.0, 0.0, 0.05], np.array(region_uv), 0.5, 0, np.array([0.0, 0.0, 1.0]))
    kw = {} if depth is None else {"region_depth": np.array(depth), "settled": 0.005}
    cast, calls = P.D.cast, []
    monkeypatch.setattr(P.D, "cast", lambda *a, **k: calls.append(1) or cast(*a, **k))
    got = P.data_points_for(*args, **kw)
    assert len(calls) == casts
    monkeypatch.setattr(P, "_all_meet", lambda *a: False)
    want = P.data_points_for(*args, **kw)
    assert len(calls) == casts + 1
    for g, w in zip((got[0].uv, got[0].target, got[0].is_contact, got[1], got[2]),
                    (want[0].uv, want[0].target, want[0].is_contact, want[1], want[2])):
        assert g.dtype == w.dtype and g.shape == w.shape and g.tobytes() == w.tobytes()
    if casts == 0:
        assert len(got[0].uv) == 1  # the contact alone
